"""Reading environment maps and writing rendered images.

Environment maps (:func:`read_envmap`) are returned as C-contiguous float32
arrays of shape (H, W, 3) holding linear RGB radiance, row 0 at the top, in
penumbra's lat-long convention (see the package documentation). Supported
inputs, chosen by file extension (case-insensitive):

``.exr``
    OpenEXR through the ``OpenEXR`` package: scanline or tiled files; for
    mip-mapped (multi-resolution) files the full-resolution level is returned.
    Half and float channels; R, G, B (an A channel is dropped) or a single
    luminance channel Y, which is replicated to grey RGB.
``.hdr`` / ``.pic``
    Radiance RGBE, decoded here in numpy (new-style run-length encoded, flat,
    and old-style run-length encoded scanlines). ``EXPOSURE=`` and
    ``COLORCORR=`` header values are divided out, so the result is the
    radiance the picture describes.
``.npy``
    A numpy array of shape (H, W, 3).

Values are returned faithfully, including NaN or Inf: validating them is the
native library's job, which reports counts and positions.

Writers (:func:`write_exr`, :func:`write_png`) write atomically (see
:mod:`penumbra.fileutil`) and refuse images containing NaN or Inf, so a bad
render never silently turns into a plausible-looking file.

Every problem with a file or an array raises :class:`~penumbra.errors.InputError`
naming the file and the problem. Before decoding, a header's resolution or
shape is checked against the file's size (where the format allows knowing how
much data it needs) and against the pixel and memory caps of
:mod:`penumbra.limits` (``PENUMBRA_MAX_PIXELS``, ``PENUMBRA_MAX_BYTES``).
"""

from __future__ import annotations

import math
import os
import re
import sys
import warnings
from pathlib import Path

import numpy as np

from .errors import InputError
from .fileutil import atomic_write, captured_native_output
from .limits import check_bytes, check_data, check_image

__all__ = ["read_envmap", "read_exr", "write_exr", "write_png", "srgb_encode"]

# Peak bytes per pixel while decoding, for the checks against PENUMBRA_MAX_BYTES
# (penumbra.limits): RGBE planes, exponents, factors, the float image and its
# transposed and scaled copies; an EXR's channels and their stack.
_RGBE_PEAK_BYTES = 48
_EXR_PEAK_BYTES = 40


# --------------------------------------------------------------------------- #
# Public API
# --------------------------------------------------------------------------- #


def read_envmap(path: str | os.PathLike) -> np.ndarray:
    """Read a lat-long environment map as float32 linear RGB of shape (H, W, 3).

    The format is chosen by extension: ``.exr``, ``.hdr``/``.pic`` (Radiance
    RGBE) or ``.npy``. Raises :class:`InputError` for a missing, unreadable,
    truncated or corrupt file, or an unsupported extension or layout.
    """
    path = Path(path)
    ext = path.suffix.lower()
    if ext == ".exr":
        image = _read_exr_file(path)[..., :3]
    elif ext in (".hdr", ".pic"):
        image = _read_rgbe(path)
    elif ext == ".npy":
        image = _read_npy(path)
    else:
        raise InputError(f"{path}: unsupported environment map extension {path.suffix!r} "
                         "(expected .exr, .hdr, .pic or .npy)")
    return np.ascontiguousarray(image, dtype=np.float32)


def read_exr(path: str | os.PathLike) -> np.ndarray:
    """Read an OpenEXR image as float32 (H, W, 3), or (H, W, 4) when it has an A channel.

    The counterpart of :func:`write_exr`; same channel rules as :func:`read_envmap`.
    """
    return np.ascontiguousarray(_read_exr_file(Path(path)), dtype=np.float32)


def write_exr(path: str | os.PathLike, image: np.ndarray) -> None:
    """Write a float32 RGB (H, W, 3) or RGBA (H, W, 4) image as a ZIP-compressed scanline EXR.

    The write is atomic. Raises :class:`InputError` if the array has the wrong
    shape or type or contains NaN/Inf (after conversion to float32).
    """
    import OpenEXR

    path = Path(path)
    pixels = _checked_image(path, image)
    names = "RGBA"[: pixels.shape[2]]
    channels = {name: np.ascontiguousarray(pixels[..., k]) for k, name in enumerate(names)}
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    atomic_write(path, lambda tmp: OpenEXR.File(header, channels).write(tmp))


def auto_exposure(image: np.ndarray, percentile: float = 97.0) -> float:
    """Exposure (stops) for :func:`write_png` that maps the given percentile of
    the lit pixels' luminance to 0.9 (an RGBA image: alpha > 0 marks the lit
    pixels; an RGB image: every pixel). 0 for an image without light."""
    lum = image[..., :3] @ np.array([0.2126, 0.7152, 0.0722], np.float32)
    lit = lum[image[..., 3] > 0] if image.shape[-1] == 4 else lum.ravel()
    level = float(np.percentile(lit, percentile)) if lit.size else 0.0
    return float(np.log2(0.9 / level)) if level > 0 and math.isfinite(level) else 0.0


def write_png(path: str | os.PathLike, image: np.ndarray, exposure: float = 0.0) -> None:
    """Write a linear RGB/RGBA image as an 8-bit sRGB PNG.

    Colour channels are multiplied by ``2**exposure``, clamped to [0, 1],
    encoded with the exact sRGB transfer function (:func:`srgb_encode`) and
    rounded to 8 bits. Alpha is clamped and stored linearly, as PNG requires.
    The write is atomic. Raises :class:`InputError` for a bad array shape, a
    non-finite exposure, or NaN/Inf pixels.
    """
    from PIL import Image

    path = Path(path)
    pixels = _checked_image(path, image)
    if not math.isfinite(exposure):
        raise InputError(f"{path}: exposure must be finite, got {exposure!r}")
    scale = 2.0 ** float(exposure)
    rgb = srgb_encode(np.clip(pixels[..., :3].astype(np.float64) * scale, 0.0, 1.0))
    channels = [rgb]
    if pixels.shape[2] == 4:
        channels.append(np.clip(pixels[..., 3:4].astype(np.float64), 0.0, 1.0))
    # floor(x + 0.5) rather than np.rint: round half up, so 0.5 * 255 -> 128 on every platform.
    out = np.floor(np.concatenate(channels, axis=2) * 255.0 + 0.5).astype(np.uint8)
    mode = "RGBA" if out.shape[2] == 4 else "RGB"
    atomic_write(path, lambda tmp: Image.fromarray(out, mode).save(tmp, format="PNG"))


def srgb_encode(x: np.ndarray | float) -> np.ndarray:
    """Apply the sRGB opto-electronic transfer function (IEC 61966-2-1) to linear values.

    ``12.92 * x`` for ``x <= 0.0031308``, else ``1.055 * x**(1/2.4) - 0.055``.
    No clamping is done (callers clamp to [0, 1] first). Returns float64.
    """
    x = np.asarray(x, dtype=np.float64)
    # np.where evaluates both branches; the maximum() keeps the power away from negatives.
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(np.maximum(x, 0.0031308), 1.0 / 2.4) - 0.055)


# --------------------------------------------------------------------------- #
# Shared helpers
# --------------------------------------------------------------------------- #


def _require_file(path: Path) -> None:
    if not path.exists():
        raise InputError(f"{path}: file not found")
    if not path.is_file():
        raise InputError(f"{path}: not a regular file")


def _read_bytes(path: Path) -> bytes:
    _require_file(path)
    try:
        check_bytes(path.stat().st_size, "reading the file", str(path))
        return path.read_bytes()
    except OSError as exc:
        raise InputError(f"{path}: cannot read file: {exc.strerror or exc}") from exc


def _checked_image(path: Path, image: np.ndarray) -> np.ndarray:
    """Validate an image to be written and return it as float32 (H, W, 3|4)."""
    array = np.asarray(image)
    if array.ndim != 3 or array.shape[2] not in (3, 4) or array.shape[0] == 0 or array.shape[1] == 0:
        raise InputError(f"{path}: image to write must have shape (H, W, 3) or (H, W, 4), got {array.shape}")
    if array.dtype.kind not in "fiu":
        raise InputError(f"{path}: image to write must be a real numeric array, got dtype {array.dtype}")
    # Check after the float32 conversion: a finite float64 beyond float32's range becomes Inf.
    with np.errstate(over="ignore"):
        pixels = np.ascontiguousarray(array, dtype=np.float32)
    bad = ~np.isfinite(pixels)
    if bad.any():
        row, col, chan = np.argwhere(bad)[0]
        raise InputError(f"{path}: refusing to write an image with {int(bad.sum())} non-finite values "
                         f"(first at row {row}, column {col}, channel {chan})")
    return pixels


def _forward_native_output(text: str) -> None:
    """Pass on native output captured around a successful call (nothing is lost)."""
    if text:
        sys.stderr.write(text)


# --------------------------------------------------------------------------- #
# OpenEXR
# --------------------------------------------------------------------------- #


def _read_exr_file(path: Path) -> np.ndarray:
    """Read an EXR's first part as float32 (H, W, 3) or (H, W, 4) with alpha."""
    import OpenEXR

    _require_file(path)
    check_exr_header(path, _EXR_PEAK_BYTES)
    error = None
    with captured_native_output() as native:
        try:
            # separate_channels: one array per named channel, so the file's channel
            # order (often A, B, G, R) cannot be confused with RGB order.
            exr = OpenEXR.File(str(path), separate_channels=True)
            channels = exr.channels()
        except Exception as exc:  # the bindings raise RuntimeError, ValueError, ...
            error = exc
    if error is not None:
        detail = " ".join(native.text.split()) or str(error)
        raise InputError(f"{path}: cannot read OpenEXR file: {detail}") from error
    _forward_native_output(native.text)

    names = set(channels)
    if {"R", "G", "B"} <= names:
        wanted = ["R", "G", "B"] + (["A"] if "A" in names else [])
    elif "Y" in names and not names & {"RY", "BY"}:
        wanted = ["Y", "Y", "Y"]
    else:
        raise InputError(f"{path}: no R, G, B or Y channels to read (channels: {', '.join(sorted(names)) or 'none'})")

    planes = []
    for name in wanted:
        channel = channels[name]
        if channel.xSampling != 1 or channel.ySampling != 1:
            raise InputError(f"{path}: channel {name} is subsampled ({channel.xSampling}x{channel.ySampling}), "
                             "which is not supported")
        pixels = np.asarray(channel.pixels)
        if pixels.dtype not in (np.float16, np.float32):
            raise InputError(f"{path}: channel {name} has pixel type {pixels.dtype}; expected half or float")
        planes.append(pixels.astype(np.float32))
    shapes = {p.shape for p in planes}
    if len(shapes) != 1 or len(planes[0].shape) != 2:
        raise InputError(f"{path}: channels have inconsistent shapes {sorted(shapes)}")
    return np.stack(planes, axis=-1)


def check_exr_header(path: Path, bytes_per_pixel: int) -> None:
    """Refuse an EXR whose data window is over the pixel or memory cap, reading only its header.
    (Compressed pixel data has no useful lower bound in bytes, so only the caps apply.)"""
    import OpenEXR

    error = None
    with captured_native_output() as native:
        try:
            header = OpenEXR.File(str(path), header_only=True).header()
            low, high = header["dataWindow"]
            width, height = int(high[0]) - int(low[0]) + 1, int(high[1]) - int(low[1]) + 1
        except Exception as exc:  # the bindings raise RuntimeError, ValueError, ...; a header may lack a key
            error = exc
    if error is not None:
        detail = " ".join(native.text.split()) or str(error)
        raise InputError(f"{path}: cannot read OpenEXR file: {detail}") from error
    _forward_native_output(native.text)
    if width <= 0 or height <= 0:
        raise InputError(f"{path}: OpenEXR data window is empty ({width} x {height})")
    channels = max(len(header.get("channels", ())), 1)
    check_image(width, height, bytes_per_pixel + 4 * channels, str(path), "the OpenEXR image")


# --------------------------------------------------------------------------- #
# numpy
# --------------------------------------------------------------------------- #


def read_npy(path: str | os.PathLike, check=None) -> np.ndarray:
    """Read a .npy file without trusting its header: the shape and dtype are read
    first; ``check(shape, dtype)`` (if given) may refuse them before any data is
    read; the data the header promises must be in the file and fit
    ``PENUMBRA_MAX_BYTES``. Pickled (object) arrays are refused. Every problem
    raises :class:`InputError`."""
    path = Path(path)
    _require_file(path)
    fmt = np.lib.format
    try:
        with open(path, "rb") as f:
            version = fmt.read_magic(f)
            if version == (1, 0):
                shape, fortran, dtype = fmt.read_array_header_1_0(f)
            elif version in ((2, 0), (3, 0)):
                shape, fortran, dtype = fmt.read_array_header_2_0(f)
            else:
                raise InputError(f"{path}: unsupported .npy format version {version}")
            offset = f.tell()
            size = os.fstat(f.fileno()).st_size
    except OSError as exc:
        raise InputError(f"{path}: cannot read .npy file: {exc.strerror or exc}") from exc
    except InputError:
        raise
    except Exception as exc:  # numpy's header parser raises ValueError, EOFError, SyntaxError, TokenError, ...
        raise InputError(f"{path}: cannot read .npy file: bad header ({type(exc).__name__}: {exc})") from exc
    if len(shape) > 32 or not all(0 <= d < 1 << 63 for d in shape):  # numpy indexes with int64
        raise InputError(f"{path}: implausible .npy shape {shape}"[:200])
    if dtype.hasobject or dtype.itemsize == 0 or dtype.subdtype is not None:
        raise InputError(f"{path}: .npy files holding {dtype} (objects, empty records or subarrays) are not "
                         "supported")
    if check is not None:
        check(shape, dtype)
    count = math.prod(shape)
    nbytes = count * dtype.itemsize
    check_data(nbytes, size - offset, f"an array of shape {shape} and dtype {dtype}", str(path))
    check_bytes(nbytes, f"an array of shape {shape} and dtype {dtype}", str(path))
    try:
        with open(path, "rb") as f:
            f.seek(offset)
            raw = f.read(nbytes)
    except OSError as exc:
        raise InputError(f"{path}: cannot read .npy file: {exc.strerror or exc}") from exc
    check_data(nbytes, len(raw), f"an array of shape {shape} and dtype {dtype}", str(path))
    array = np.frombuffer(raw, dtype=dtype, count=count)
    return array.reshape(shape[::-1]).transpose() if fortran else array.reshape(shape)


def _read_npy(path: Path) -> np.ndarray:
    def check(shape, dtype):
        if len(shape) != 3 or shape[2] != 3:
            raise InputError(f"{path}: expected an array of shape (H, W, 3), got {shape}")
        if shape[0] == 0 or shape[1] == 0:
            raise InputError(f"{path}: the environment map is empty (shape {shape})")
        if dtype.kind not in "fiu":
            raise InputError(f"{path}: expected a real numeric array, got dtype {dtype}")
        check_image(shape[1], shape[0], 12 + 3 * dtype.itemsize, str(path), "the environment map")

    return read_npy(path, check)


# --------------------------------------------------------------------------- #
# Radiance RGBE
# --------------------------------------------------------------------------- #

_RESOLUTION_RE = re.compile(rb"^\s*([-+])([XY])\s+([0-9]{1,10})\s+([-+])([XY])\s+([0-9]{1,10})\s*$")


def _read_rgbe(path: Path) -> np.ndarray:
    """Decode a Radiance picture into float32 (H, W, 3) radiance, top row first."""
    data = _read_bytes(path)
    pos, height, width, bottom_up, scale = _parse_rgbe_header(path, data)
    planes = _decode_rgbe_scanlines(path, data, pos, width, height)  # (H, 4, W) uint8

    # Decoding as mantissa * 2**(exponent - 136), without Radiance's +0.5 bucket
    # centre, matches Greg Ward/Bruce Walter's rgbe.c as used by Mitsuba, OpenCV
    # and stb_image, so maps read here agree bit for bit with those tools.
    exponent = planes[:, 3, :].astype(np.int32)
    factor = np.where(exponent == 0, np.float32(0.0), np.ldexp(np.float32(1.0), exponent - 136)).astype(np.float32)
    image = planes[:, :3, :].astype(np.float32) * factor[:, None, :]
    image = image.transpose(0, 2, 1)
    if bottom_up:
        image = image[::-1]
    if scale is not None:
        image = image * scale
    return np.ascontiguousarray(image, dtype=np.float32)


def _parse_rgbe_header(path: Path, data: bytes) -> tuple[int, int, int, bool, np.ndarray | None]:
    """Parse the header and resolution line.

    Returns (offset of the pixel data, height, width, bottom_up, per-channel
    scale that converts stored values to radiance or None when it is 1).
    """
    if not data.startswith(b"#?"):
        raise InputError(f"{path}: not a Radiance RGBE file (missing '#?' magic line)")
    exposure = 1.0
    colorcorr = np.ones(3)
    pos = 0
    while True:
        end = data.find(b"\n", pos)
        if end < 0:
            raise InputError(f"{path}: truncated or corrupt Radiance header (no blank line ends the header)")
        line = data[pos:end].rstrip(b"\r").decode("latin-1")
        pos = end + 1
        if not line.strip():
            break
        if line.startswith("#"):
            continue  # comments, and the '#?RADIANCE' magic that some writers repeat
        key, sep, value = line.partition("=")
        if not sep:
            continue  # Radiance puts command lines of its tools here; they carry no data
        key = key.strip().upper()
        value = value.strip()
        if key == "FORMAT":
            if value == "32-bit_rle_xyze":
                raise InputError(f"{path}: XYZE Radiance pictures are not supported (only 32-bit_rle_rgbe)")
            if value != "32-bit_rle_rgbe":
                raise InputError(f"{path}: unsupported Radiance FORMAT {value!r} (expected 32-bit_rle_rgbe)")
        elif key == "EXPOSURE":
            factor = _parse_header_floats(value, 1)
            if factor is None or not (math.isfinite(factor[0]) and factor[0] > 0):
                # Some writers emit EXPOSURE=0 (FreeImage) meaning "unset"; dividing
                # by it would turn the whole image into Inf/NaN, so it is ignored.
                warnings.warn(f"{path}: ignoring invalid header line {line.strip()!r} "
                              "(EXPOSURE must be a positive finite number)", stacklevel=4)
            else:
                exposure *= factor[0]
        elif key == "COLORCORR":
            factor = _parse_header_floats(value, 3)
            if factor is None or not all(math.isfinite(f) and f > 0 for f in factor):
                warnings.warn(f"{path}: ignoring invalid header line {line.strip()!r} "
                              "(COLORCORR must be three positive finite numbers)", stacklevel=4)
            else:
                colorcorr *= factor
        # Other variables (PRIMARIES, PIXASPECT, GAMMA, VIEW, SOFTWARE, ...) do not
        # change the stored radiance and are ignored.

    end = data.find(b"\n", pos)
    if end < 0:
        raise InputError(f"{path}: truncated Radiance file (no resolution line after the header)")
    match = _RESOLUTION_RE.match(data[pos:end])
    if match is None:
        raise InputError(f"{path}: bad Radiance resolution line {data[pos:end][:40]!r}")
    pos = end + 1
    sign1, axis1, n1, sign2, axis2, n2 = match.groups()
    if axis1 != b"Y" or axis2 != b"X" or sign2 != b"+":
        orientation = match.group(0).decode("latin-1").strip()
        raise InputError(f"{path}: unsupported Radiance image orientation {orientation!r} "
                         "(only '-Y H +X W' and '+Y H +X W' are supported)")
    height, width = int(n1), int(n2)
    if height == 0 or width == 0:
        raise InputError(f"{path}: implausible Radiance resolution {width}x{height}")
    # Every scanline takes at least 4 bytes (one pixel, or one run marker), so
    # the file bounds the height; old-style runs can repeat a pixel 2**48 times,
    # so only the caps bound the width.
    what = f"the Radiance resolution {width}x{height}"
    check_data(4 * height, len(data) - pos, f"{what} ({height} scanlines of at least 4 bytes)", str(path))
    check_image(width, height, _RGBE_PEAK_BYTES, str(path), what)
    # Radiance defines EXPOSURE and COLORCORR as multipliers already applied to the
    # stored pixels (cumulative), so radiance = stored / (product of them all).
    divisor = exposure * colorcorr
    scale = None if np.all(divisor == 1.0) else (1.0 / divisor).astype(np.float32)
    return pos, height, width, sign1 == b"+", scale


def _parse_header_floats(value: str, count: int) -> list[float] | None:
    parts = value.split()
    if len(parts) != count:
        return None
    try:
        return [float(p) for p in parts]
    except ValueError:
        return None


def _decode_rgbe_scanlines(path: Path, data: bytes, pos: int, width: int, height: int) -> np.ndarray:
    """Decode all scanlines into planar bytes of shape (H, 4, W): R, G, B, E planes per row.

    As in Radiance's ``freadcolrs``, each scanline is examined on its own: it is
    new-style run-length encoded if it starts with the bytes 2, 2 followed by
    its length, otherwise flat/old-style run-length encoded.
    """
    planes = np.empty((height, 4, width), dtype=np.uint8)
    size = len(data)
    # New-style RLE can only encode widths in [8, 0x7fff]; outside that range
    # every writer falls back to flat scanlines.
    rle_width_ok = 8 <= width <= 0x7FFF
    for y in range(height):
        if pos >= size:
            raise InputError(f"{path}: truncated Radiance file (pixel data ends before scanline {y} of {height})")
        if rle_width_ok and pos + 4 <= size and data[pos] == 2 and data[pos + 1] == 2 and data[pos + 2] < 128:
            length = (data[pos + 2] << 8) | data[pos + 3]
            if length != width:
                raise InputError(f"{path}: corrupt Radiance file (scanline {y} claims length {length}, "
                                 f"image width is {width})")
            pos = _decode_new_rle_scanline(path, data, pos + 4, width, planes[y], y)
        else:
            previous = planes[y - 1, :, -1] if y > 0 else None
            pos = _decode_old_scanline(path, data, pos, width, planes[y], previous, y)
    return planes


def _decode_new_rle_scanline(path: Path, data: bytes, pos: int, width: int, out: np.ndarray, y: int) -> int:
    """Decode one new-style RLE scanline (4 separately run-length coded channels) into out (4, W)."""
    size = len(data)
    for channel in range(4):
        buf = bytearray()
        while len(buf) < width:
            if pos >= size:
                raise InputError(f"{path}: truncated Radiance file (data ends inside scanline {y})")
            count = data[pos]
            if count > 128:  # a run: one byte repeated count-128 times
                if pos + 1 >= size:
                    raise InputError(f"{path}: truncated Radiance file (data ends inside scanline {y})")
                buf += bytes((data[pos + 1],)) * (count - 128)
                pos += 2
            else:  # a literal: count bytes copied as they are
                if count == 0:
                    raise InputError(f"{path}: corrupt Radiance file (zero-length run in scanline {y})")
                if pos + 1 + count > size:
                    raise InputError(f"{path}: truncated Radiance file (data ends inside scanline {y})")
                buf += data[pos + 1 : pos + 1 + count]
                pos += 1 + count
        if len(buf) != width:
            raise InputError(f"{path}: corrupt Radiance file (a run overruns scanline {y})")
        out[channel] = np.frombuffer(bytes(buf), dtype=np.uint8)
    return pos


def _decode_old_scanline(path: Path, data: bytes, pos: int, width: int, out: np.ndarray,
                         previous: np.ndarray | None, y: int) -> int:
    """Decode one flat or old-style RLE scanline into out (4, W), vectorised.

    The data is a sequence of 4-byte RGBE pixels; a pixel (1, 1, 1, n) means
    "repeat the previous pixel n times", and each further such marker in a row
    multiplies its count by 256 more (Radiance's ``oldreadcolrs``). A flat
    scanline is the special case without markers.
    """
    available = (len(data) - pos) // 4
    window = min(width, available)  # a scanline needs at most `width` groups ...
    while True:
        if window == 0:
            raise InputError(f"{path}: truncated Radiance file (data ends inside scanline {y})")
        groups = np.frombuffer(data, dtype=np.uint8, count=4 * window, offset=pos).reshape(window, 4)
        marker = (groups[:, 0] == 1) & (groups[:, 1] == 1) & (groups[:, 2] == 1)
        index = np.arange(window)
        last_pixel = np.maximum.accumulate(np.where(marker, -1, index))  # -1: no pixel yet in this line
        run_position = index - last_pixel - 1  # 0 for the first marker after a pixel
        shift = np.minimum(8 * run_position, 48)  # larger shifts overrun any width anyway
        counts = np.where(marker, groups[:, 3].astype(np.int64) << shift, 1)
        total = np.cumsum(counts)
        end = int(np.searchsorted(total, width))
        if end < window:
            break
        if window == available:
            raise InputError(f"{path}: truncated Radiance file (data ends inside scanline {y})")
        window = min(2 * window, available)  # ... unless zero-count markers padded it
    if total[end] != width:
        raise InputError(f"{path}: corrupt Radiance file (a run overruns scanline {y})")
    n = end + 1
    source = np.where(marker[:n], last_pixel[:n], index[:n])
    values = groups[np.maximum(source, 0)].copy()
    orphans = source < 0
    if orphans[counts[:n] > 0].any():
        if previous is None:
            raise InputError(f"{path}: corrupt Radiance file (a run repeats a pixel before the first one)")
        values[orphans] = previous  # a leading run continues the previous scanline's last pixel
    out[:] = np.repeat(values, counts[:n], axis=0).T
    return pos + 4 * n
