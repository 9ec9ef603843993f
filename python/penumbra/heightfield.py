"""Height fields: a grid of heights placed in the world, file loaders and the
procedural terrains of the seed's test scenes. Its triangle mesh and normals
are the library's (penumbra.methods.heightfield.HeightFieldHandle.mesh).

Conventions (docs/heightfield.md, "Grid and frame"): heights ``h[j][i]``,
``W`` columns (i, along world +x) by ``D`` rows (j, along world +z),
``W, D >= 2``. Vertex (i, j) is the world point
``(x0 + i sx, y0 + height_scale h[j][i], z0 + j sz)`` with
``sx = size_x / (W - 1)``, ``sz = size_z / (D - 1)``; the world is y-up.
Vertex normals are ``normalize(-dH/dx, 1, -dH/dz)`` with ``H = height_scale h``,
central differences inside and one-sided differences on the border.

* :class:`HeightField` holds and validates a grid and its placement.
* :func:`load_heights` reads ``.npy``, OpenEXR and greyscale PNG height maps,
  :func:`load_albedo` an RGB albedo map.
* :data:`TERRAINS` / :func:`make_terrain`: procedural heights after the seed's
  test scenes (flat, cones, cones on a circle, sine grating, egg tray, fBm
  mountains, city blocks).

Every problem raises :class:`~penumbra.errors.InputError` naming what is wrong
and where (a file, a row and column, a parameter).
"""

from __future__ import annotations

import inspect
import math
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .errors import InputError

__all__ = [
    "HeightField", "load_heights", "load_albedo", "HEIGHT_EXTENSIONS", "ALBEDO_EXTENSIONS",
    "flat", "cones", "cones_circle", "cones_circle_light", "sine_grating", "egg_tray", "fbm", "city_blocks",
    "TERRAINS", "make_terrain", "terrain_parameters", "check_terrain_params",
]

HEIGHT_EXTENSIONS = (".npy", ".exr", ".png")
ALBEDO_EXTENSIONS = (".npy", ".exr", ".png")


# --------------------------------------------------------------------------- #
# Validation helpers
# --------------------------------------------------------------------------- #


def _first_bad(bad: np.ndarray) -> tuple[int, ...]:
    return tuple(int(k) for k in np.argwhere(bad)[0])


def _heights_array(heights, where: str) -> np.ndarray:
    """``heights`` as C-contiguous float32 (D, W), checked: 2D, W, D >= 2, finite."""
    a = np.asarray(heights)
    if a.dtype.kind not in "fiu":
        raise InputError(f"{where}: heights must be a real numeric array, got dtype {a.dtype}")
    if a.ndim != 2:
        raise InputError(f"{where}: heights must be a 2D array (D rows x W columns), got shape {a.shape}")
    depth, width = a.shape
    if width < 2 or depth < 2:
        raise InputError(f"{where}: heights need at least 2 rows and 2 columns (W, D >= 2), "
                         f"got {depth} rows x {width} columns")
    with np.errstate(over="ignore", invalid="ignore"):  # out-of-float32-range values become Inf, reported below
        h = np.ascontiguousarray(a, dtype=np.float32)
    bad = ~np.isfinite(h)
    if bad.any():
        row, col = _first_bad(bad)
        raise InputError(f"{where}: heights contain {int(bad.sum())} NaN/Inf (or out-of-float32-range) values "
                         f"(first at row {row}, column {col})")
    return h


def _finite_tuple(value, n: int, name: str, positive: bool = False) -> tuple[float, ...]:
    try:
        v = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(f"{name} must be {n} numbers, got {value!r}") from None
    if v.shape != (n,) or isinstance(value, (str, bytes)):
        raise InputError(f"{name} must be {n} numbers, got {value!r}")
    if not np.isfinite(v).all():
        raise InputError(f"{name} must be finite, got {value!r}")
    if positive and not (v > 0).all():
        raise InputError(f"{name} must be positive, got {value!r}")
    return tuple(float(x) for x in v)


def _finite_number(value, name: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)) \
            or not math.isfinite(value):
        raise InputError(f"{name} must be a finite number, got {value!r}")
    return float(value)


def _albedo_array(albedo, shape: tuple[int, int], where: str) -> np.ndarray | None:
    """None, an RGB triple (3,) or a per-vertex map (D, W, 3); float32, finite, in [0, 1]."""
    if albedo is None:
        return None
    a = np.asarray(albedo)
    if a.dtype.kind not in "fiu":
        raise InputError(f"{where}: albedo must be real numbers, got dtype {a.dtype}")
    if a.shape not in ((3,), (*shape, 3)):
        raise InputError(f"{where}: albedo must be an RGB triple or a map of shape (D, W, 3) = "
                         f"{(*shape, 3)} matching the heights, got shape {a.shape}")
    with np.errstate(over="ignore", invalid="ignore"):
        a = np.ascontiguousarray(a, dtype=np.float32)
    bad = ~np.isfinite(a)
    if bad.any():
        first = _first_bad(bad)
        at = f"(first at row {first[0]}, column {first[1]})" if a.ndim == 3 else f"(first: channel {first[0]})"
        raise InputError(f"{where}: albedo contains {int(bad.sum())} NaN/Inf values {at}")
    out = (a < 0) | (a > 1)
    if out.any():
        first = _first_bad(out)
        at = f"(first at row {first[0]}, column {first[1]})" if a.ndim == 3 else f"(first: channel {first[0]})"
        raise InputError(f"{where}: albedo must lie in [0, 1]; {int(out.sum())} values do not {at}")
    return a


# --------------------------------------------------------------------------- #
# HeightField
# --------------------------------------------------------------------------- #


@dataclass(eq=False)  # arrays: compare heights with numpy, not ==
class HeightField:
    """A height grid placed in the world (docs/heightfield.md, "Grid and frame").

    ``heights``: (D, W) real array, ``h[j][i]`` with columns along +x and rows
    along +z, W, D >= 2, finite (stored as C-contiguous float32).
    ``origin``: world position (x0, y0, z0) of vertex (0, 0).
    ``size``: (size_x, size_z) > 0, the world extent from the first to the last
    vertex. ``height_scale``: world units per height unit (any finite number;
    negative turns the terrain upside down). ``albedo``: None (not given; the
    renderer's default applies), an RGB triple, or a per-vertex map (D, W, 3);
    values in [0, 1] (stored as float32).
    """

    heights: np.ndarray
    origin: tuple[float, float, float] = (0.0, 0.0, 0.0)
    size: tuple[float, float] = (1.0, 1.0)
    height_scale: float = 1.0
    albedo: np.ndarray | None = None

    def __post_init__(self) -> None:
        self.heights = _heights_array(self.heights, "height field")
        self.origin = _finite_tuple(self.origin, 3, "height field origin")
        self.size = _finite_tuple(self.size, 2, "height field size (size_x, size_z)", positive=True)
        self.height_scale = _finite_number(self.height_scale, "height field height_scale")
        self.albedo = _albedo_array(self.albedo, self.heights.shape, "height field")

    @property
    def width(self) -> int:
        """W, the number of columns (samples along +x)."""
        return int(self.heights.shape[1])

    @property
    def depth(self) -> int:
        """D, the number of rows (samples along +z)."""
        return int(self.heights.shape[0])

    @property
    def spacing(self) -> tuple[float, float]:
        """(sx, sz): world distance between neighbouring vertices along x and z."""
        return self.size[0] / (self.width - 1), self.size[1] / (self.depth - 1)

    @property
    def world_heights(self) -> np.ndarray:
        """H = height_scale * h, float32 (D, W), relative to origin y."""
        return (self.heights.astype(np.float64) * self.height_scale).astype(np.float32)

    @property
    def bounds(self) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
        """Axis-aligned world bounds ((xmin, ymin, zmin), (xmax, ymax, zmax)) of the vertices."""
        x0, y0, z0 = self.origin
        h = self.heights.astype(np.float64) * self.height_scale
        return (x0, y0 + float(h.min()), z0), (x0 + self.size[0], y0 + float(h.max()), z0 + self.size[1])

    def vertex_albedo(self, default: Sequence[float] = (0.8, 0.8, 0.8)) -> np.ndarray:
        """Per-vertex albedo, float32 (D * W, 3): the map, the constant, or ``default`` when none is set."""
        a = self.albedo if self.albedo is not None else _albedo_array(default, self.heights.shape, "default albedo")
        return np.ascontiguousarray(np.broadcast_to(a, (self.depth, self.width, 3)).reshape(-1, 3))

    def height_at(self, x, z):
        """World y of the field at world (x, z), bilinear between the vertices; outside the grid
        the border continues (clamp to edge, as the pyramid's out-of-bounds policy).
        Scalars give a float, arrays an array (float64) of their broadcast shape."""
        x0, y0, z0 = self.origin
        sx, sz = self.spacing
        w, d = self.width, self.depth
        fx = np.clip((np.asarray(x, dtype=np.float64) - x0) / sx, 0.0, w - 1.0)
        fz = np.clip((np.asarray(z, dtype=np.float64) - z0) / sz, 0.0, d - 1.0)
        fx, fz = np.broadcast_arrays(fx, fz)
        i = np.minimum(np.floor(fx).astype(np.int64), w - 2)
        j = np.minimum(np.floor(fz).astype(np.int64), d - 2)
        tx, tz = fx - i, fz - j
        h = self.heights.astype(np.float64)
        top = h[j, i] * (1 - tx) + h[j, i + 1] * tx
        bottom = h[j + 1, i] * (1 - tx) + h[j + 1, i + 1] * tx
        y = y0 + self.height_scale * (top * (1 - tz) + bottom * tz)
        return float(y) if y.ndim == 0 else y


# --------------------------------------------------------------------------- #
# Loaders
# --------------------------------------------------------------------------- #


def _map_file(path: str | os.PathLike, extensions, what: str) -> tuple[Path, str]:
    """(path, lower-case extension) of a readable map file with one of `extensions`."""
    path = Path(path)
    ext = path.suffix.lower()
    if ext not in extensions:
        raise InputError(f"{path}: unsupported {what} extension {path.suffix!r} (expected {', '.join(extensions)})")
    _require_file(path)
    return path, ext


def _require_file(path: Path) -> None:
    if not path.exists():
        raise InputError(f"{path}: file not found")
    if not path.is_file():
        raise InputError(f"{path}: not a regular file")
    try:
        with open(path, "rb"):
            pass
    except OSError as exc:
        raise InputError(f"{path}: cannot read file: {exc.strerror or exc}") from exc


def _load_npy(path: Path) -> np.ndarray:
    from .imageio import read_npy
    from .limits import check_image

    def check(shape, dtype):  # before reading: a map is 2D or 3D, within the caps (float64 copies follow)
        if len(shape) in (2, 3):
            check_image(shape[1], shape[0], 8 * (shape[2] if len(shape) == 3 else 1) * 4, str(path), "the map")

    return read_npy(path, check)


def _exr_channels(path: Path) -> dict[str, np.ndarray]:
    """All full-resolution channels of an EXR's first part, float32 2D arrays by name."""
    import OpenEXR

    from .fileutil import captured_native_output

    from .imageio import check_exr_header

    check_exr_header(path, 16)
    error = None
    with captured_native_output() as native:
        try:
            channels = OpenEXR.File(str(path), separate_channels=True).channels()
        except Exception as exc:  # the bindings raise RuntimeError, ValueError, ...
            error = exc
    if error is not None:
        detail = " ".join(native.text.split()) or str(error)
        raise InputError(f"{path}: cannot read OpenEXR file: {detail}") from error
    out = {}
    for name, channel in channels.items():
        if channel.xSampling != 1 or channel.ySampling != 1:
            raise InputError(f"{path}: channel {name} is subsampled ({channel.xSampling}x{channel.ySampling}), "
                             "which is not supported")
        pixels = np.asarray(channel.pixels)
        if pixels.ndim != 2 or pixels.dtype not in (np.float16, np.float32):
            raise InputError(f"{path}: channel {name} has pixel type {pixels.dtype}, shape {pixels.shape}; "
                             "expected a 2D half or float channel")
        out[name] = pixels.astype(np.float32)
    return out


def _pick_height_channel(path: Path, channels: dict[str, np.ndarray]) -> np.ndarray:
    if len(channels) == 1:
        return next(iter(channels.values()))
    for name in ("Y", "R"):
        if name in channels:
            return channels[name]
    raise InputError(f"{path}: cannot tell which channel holds the heights (channels: "
                     f"{', '.join(sorted(channels)) or 'none'}); expected a single channel, Y or R")


def _open_png(path: Path):
    import struct
    import zlib

    from PIL import Image, UnidentifiedImageError

    from .limits import check_image

    # Refuse a decompression bomb from its IHDR before Pillow sees it (Pillow's own
    # limit raises an exception of its own at open); peak: float64 RGB copies of the
    # pixels (penumbra.limits).
    with open(path, "rb") as f:
        head = f.read(24)
    if head[:8] == b"\x89PNG\r\n\x1a\n" and head[12:16] == b"IHDR":
        check_image(int.from_bytes(head[16:20], "big"), int.from_bytes(head[20:24], "big"), 64, str(path),
                    "the PNG image")
    try:
        image = Image.open(path)
        check_image(image.size[0], image.size[1], 64, str(path), "the PNG image")
        image.load()
    except (OSError, UnidentifiedImageError, ValueError, SyntaxError, EOFError, struct.error, zlib.error,
            Image.DecompressionBombError) as exc:
        if isinstance(exc, InputError):
            raise
        raise InputError(f"{path}: cannot read PNG file: {exc}") from exc
    if image.format != "PNG":
        raise InputError(f"{path}: not a PNG file (Pillow reads it as {image.format})")
    return image


def _png_heights(path: Path) -> np.ndarray:
    image = _open_png(path)
    if image.mode in ("I;16", "I;16B", "I;16L", "I"):  # 16-bit greyscale (older Pillow: mode "I")
        return np.asarray(image, dtype=np.float64) / 65535.0
    if image.mode == "L":
        return np.asarray(image, dtype=np.float64) / 255.0
    raise InputError(f"{path}: height maps must be greyscale PNGs (16-bit recommended, 8-bit accepted), "
                     f"got mode {image.mode}")


def load_heights(path: str | os.PathLike) -> np.ndarray:
    """Read a height map as float32 (D, W), row 0 = j = 0 (the -z edge), column 0 the -x edge.

    ``.npy``: a 2D real array, values as stored (a trailing axis of 1 is dropped).
    ``.exr``: a single channel of any name, else Y, else R, values as stored.
    ``.png``: greyscale; 16-bit scaled by 1/65535, 8-bit by 1/255 (accepted, but
    256 levels show as terraces in the normals and shadows; prefer 16 bits);
    colour PNGs are refused. Raises :class:`InputError` naming the file for a
    missing, unreadable or corrupt file, another layout, W or D < 2, or NaN/Inf.
    """
    path, ext = _map_file(path, HEIGHT_EXTENSIONS, "height map")
    if ext == ".npy":
        a = _load_npy(path)
        if a.ndim == 3 and a.shape[2] == 1:
            a = a[..., 0]
    elif ext == ".exr":
        a = _pick_height_channel(path, _exr_channels(path))
    else:
        a = _png_heights(path)
    return _heights_array(a, str(path))


def _srgb_decode(x: np.ndarray) -> np.ndarray:
    """Inverse of imageio.srgb_encode (IEC 61966-2-1), for values in [0, 1]."""
    return np.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4)


def load_albedo(path: str | os.PathLike) -> np.ndarray:
    """Read an albedo map as float32 (D, W, 3), linear, one texel per height sample.

    ``.png``: 8- or 16-bit grey or RGB(A) (alpha dropped), **sRGB-encoded**, decoded
    to linear. ``.exr``: R, G, B (or Y), linear. ``.npy``: (D, W, 3) or (D, W)
    grey, linear. Range and finiteness are checked by :class:`HeightField`.
    """
    path, ext = _map_file(path, ALBEDO_EXTENSIONS, "albedo map")
    if ext == ".npy":
        a = _load_npy(path)
        if a.ndim == 2:
            a = np.repeat(a[..., None], 3, axis=2)
        if a.dtype.kind not in "fiu" or a.ndim != 3 or a.shape[2] != 3:
            raise InputError(f"{path}: expected a real array of shape (D, W, 3) or (D, W), got {a.dtype} {a.shape}")
    elif ext == ".exr":
        from .imageio import read_exr

        a = read_exr(path)[..., :3]
    else:
        image = _open_png(path)
        if image.mode in ("I;16", "I;16B", "I;16L", "I"):
            grey = np.asarray(image, dtype=np.float64) / 65535.0
        elif image.mode in ("L", "LA", "RGB", "RGBA"):
            grey = None
            rgb = np.asarray(image.convert("RGB"), dtype=np.float64) / 255.0
        else:
            raise InputError(f"{path}: albedo PNGs must be grey or RGB(A), got mode {image.mode}")
        a = _srgb_decode(np.repeat(grey[..., None], 3, axis=2) if grey is not None else rgb)
    return np.ascontiguousarray(a, dtype=np.float32)


# --------------------------------------------------------------------------- #
# Procedural terrains
# --------------------------------------------------------------------------- #
#
# Every terrain is a function (width, depth, **params) -> float32 (depth, width)
# with heights in [0, 1]. Positions are measured in units of the shorter side:
# vertex (i, j) sits at u = i / m, v = j / m with m = min(W, D) - 1, so the
# shorter side spans [0, 1] and the longer [0, (max(W, D) - 1) / m]. Features
# are round on the ground when the field's cells are square
# (size_x / (W - 1) = size_z / (D - 1)), and the same terrain at another
# resolution of the same extent is the same shape, sampled more finely.


def _grid_size(width, depth) -> tuple[int, int]:
    for name, value in (("width", width), ("depth", depth)):
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 2:
            raise InputError(f"terrain {name} must be an integer >= 2, got {value!r}")
    return int(width), int(depth)


def _uv(width: int, depth: int) -> tuple[np.ndarray, np.ndarray, float, float]:
    """u (1, W), v (D, 1) in units of the shorter side, and the extents (u_max, v_max)."""
    m = min(width, depth) - 1
    return (np.arange(width, dtype=np.float64)[None, :] / m, np.arange(depth, dtype=np.float64)[:, None] / m,
            (width - 1) / m, (depth - 1) / m)


def _param_number(terrain: str, name: str, value, lo: float | None = None, hi: float | None = None,
                  lo_open: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)) \
            or not math.isfinite(value):
        raise InputError(f"terrain '{terrain}': {name} must be a finite number, got {value!r}")
    if lo is not None and (value < lo or (lo_open and value == lo)):
        raise InputError(f"terrain '{terrain}': {name} = {value} must be {'>' if lo_open else '>='} {lo}")
    if hi is not None and value > hi:
        raise InputError(f"terrain '{terrain}': {name} = {value} must be <= {hi}")
    return float(value)


def _param_int(terrain: str, name: str, value, lo: int, hi: int = 1 << 20) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or not lo <= value <= hi:
        raise InputError(f"terrain '{terrain}': {name} must be an integer in [{lo}, {hi}], got {value!r}")
    return int(value)


def _seed(terrain: str, value) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise InputError(f"terrain '{terrain}': seed must be an integer, got {value!r}")
    return int(value)


def _lattice_centres(extent: float, cell: float) -> np.ndarray:
    """Centres of round(extent / cell) (at least 1) cells of size ``cell``, centred on [0, extent]."""
    n = max(1, round(extent / cell))
    return extent / 2 + (np.arange(n) - (n - 1) / 2) * cell


def flat(width: int, depth: int, level: float = 0.0) -> np.ndarray:
    """A flat field at ``level`` (in [0, 1])."""
    width, depth = _grid_size(width, depth)
    level = _param_number("flat", "level", level, 0.0, 1.0)
    return np.full((depth, width), level, dtype=np.float32)


def cones(width: int, depth: int, count: int = 4, radius: float = 0.4, height: float = 1.0) -> np.ndarray:
    """The seed's cones scene (version 1): equal cones on a square grid.

    ``count`` cones along the shorter side (cells of size 1 / count; along the
    longer side as many cells as fit, rounded, the grid centred); each cone
    stands at its cell's centre with base radius ``radius`` cell sizes
    (0 < radius <= 0.5: cones do not overlap) and apex height ``height``
    (0 < height <= 1); the ground is 0.
    """
    width, depth = _grid_size(width, depth)
    count = _param_int("cones", "count", count, 1, 4096)
    radius = _param_number("cones", "radius", radius, 0.0, 0.5, lo_open=True)
    height = _param_number("cones", "height", height, 0.0, 1.0, lo_open=True)
    u, v, umax, vmax = _uv(width, depth)
    cell = 1.0 / count
    cu, cv = _lattice_centres(umax, cell), _lattice_centres(vmax, cell)
    # With radius <= half a cell only the nearest centre can cover a point.
    ku = np.clip(np.rint((u - cu[0]) / cell), 0, len(cu) - 1).astype(np.int64)
    kv = np.clip(np.rint((v - cv[0]) / cell), 0, len(cv) - 1).astype(np.int64)
    dist = np.hypot(u - cu[ku], v - cv[kv])
    return (height * np.maximum(0.0, 1.0 - dist / (radius * cell))).astype(np.float32)


def _cones_circle_layout(count: int, circle_radius: float, min_radius: float, max_radius: float):
    """(angles, base radii, heights) of the cones of :func:`cones_circle`."""
    k = np.arange(count)
    angles = 2 * np.pi * k / count
    radii = np.full(count, max_radius) if count == 1 else min_radius + (max_radius - min_radius) * k / (count - 1)
    return angles, radii, radii / max_radius


def cones_circle(width: int, depth: int, count: int = 8, circle_radius: float = 0.3, min_radius: float = 0.04,
                 max_radius: float = 0.1) -> np.ndarray:
    """The seed's cones scene (version 2): cones of different sizes on a circle.

    ``count`` cones centred on a circle of radius ``circle_radius`` around the
    field's centre, cone k at azimuth 2 pi k / count from +x towards +z; base
    radii grow linearly from ``min_radius`` (k = 0) to ``max_radius``
    (k = count - 1) and all have the same slope, so heights are
    radius / max_radius (the largest is 1). Lengths in units of the shorter
    side; the ground (and the centre, where the seed puts a light just above
    the ground: :func:`cones_circle_light`) is 0.
    """
    width, depth = _grid_size(width, depth)
    count = _param_int("cones_circle", "count", count, 1, 4096)
    circle_radius = _param_number("cones_circle", "circle_radius", circle_radius, 0.0, lo_open=True)
    max_radius = _param_number("cones_circle", "max_radius", max_radius, 0.0, lo_open=True)
    min_radius = _param_number("cones_circle", "min_radius", min_radius, 0.0, max_radius, lo_open=True)
    u, v, umax, vmax = _uv(width, depth)
    angles, radii, heights = _cones_circle_layout(count, circle_radius, min_radius, max_radius)
    h = np.zeros((depth, width))
    for a, r, top in zip(angles, radii, heights):
        dist = np.hypot(u - (umax / 2 + circle_radius * math.cos(a)), v - (vmax / 2 + circle_radius * math.sin(a)))
        np.maximum(h, top * np.maximum(0.0, 1.0 - dist / r), out=h)
    return h.astype(np.float32)


def cones_circle_light(field: HeightField, elevation: float = 0.1,
                       radius: float = 0.02) -> tuple[tuple[float, float, float], float]:
    """The seed's light for the cones scene version 2: at the field's centre, just above the ground.

    Returns ``(position, light_radius)`` in world units: position = the centre
    of the field's x-z extent at the field's height there plus
    ``elevation * |height_scale|`` (0.1: a tenth of the tallest cone), and
    light_radius = ``radius`` times the shorter world side, but at most half
    the lift above the ground, so the sphere never cuts the terrain (a wide
    field would otherwise make it larger than its lift).
    """
    elevation = _param_number("cones_circle_light", "elevation", elevation, 0.0)
    radius = _param_number("cones_circle_light", "radius", radius, 0.0, lo_open=True)
    x = field.origin[0] + field.size[0] / 2
    z = field.origin[2] + field.size[1] / 2
    lift = elevation * abs(field.height_scale)
    y = field.height_at(x, z) + lift
    r = radius * min(field.size)
    return (x, y, z), min(r, 0.5 * lift) if lift > 0 else r


def sine_grating(width: int, depth: int, period: float = 0.125, angle_deg: float = 0.0) -> np.ndarray:
    """The seed's sine grating: parallel ridges h = 0.5 + 0.5 sin(2 pi s / period), s the distance
    along the direction ``angle_deg`` (from +x towards +z); ``period`` in units of the shorter side."""
    width, depth = _grid_size(width, depth)
    period = _param_number("sine_grating", "period", period, 0.0, lo_open=True)
    a = math.radians(_param_number("sine_grating", "angle_deg", angle_deg))
    u, v, _, _ = _uv(width, depth)
    s = u * math.cos(a) + v * math.sin(a)
    return (0.5 + 0.5 * np.sin(2 * np.pi * s / period)).astype(np.float32)


def egg_tray(width: int, depth: int, period: float = 0.125) -> np.ndarray:
    """The seed's egg tray: h = 0.5 + 0.5 cos(2 pi u / period) cos(2 pi v / period), a square lattice
    of bumps (height 1) and cups (height 0) on the diagonals; ``period`` in units of the shorter side."""
    width, depth = _grid_size(width, depth)
    period = _param_number("egg_tray", "period", period, 0.0, lo_open=True)
    u, v, _, _ = _uv(width, depth)
    return (0.5 + 0.5 * np.cos(2 * np.pi * u / period) * np.cos(2 * np.pi * v / period)).astype(np.float32)


def fbm(width: int, depth: int, seed: int = 0, octaves: int = 6, frequency: float = 4.0, persistence: float = 0.5,
        lacunarity: float = 2.0) -> np.ndarray:
    """The seed's mountains: fractal Brownian motion (:func:`penumbra.procedural.terrain_heights`)
    mapped from [-1, 1] to [0, 1] by (h + 1) / 2. ``frequency`` lattice cells per unit of the
    shorter side for the first octave; deterministic for a given ``seed``."""
    from .procedural import terrain_heights

    width, depth = _grid_size(width, depth)
    seed = _seed("fbm", seed)
    octaves = _param_int("fbm", "octaves", octaves, 1, 32)
    frequency = _param_number("fbm", "frequency", frequency, 0.0, lo_open=True)
    persistence = _param_number("fbm", "persistence", persistence, 0.0, lo_open=True)
    lacunarity = _param_number("fbm", "lacunarity", lacunarity, 0.0, lo_open=True)
    # terrain_heights samples at (i + 0.5) / width * frequency: rescale to units of the shorter side.
    f = frequency * width / (min(width, depth) - 1)
    h = terrain_heights(width, depth, seed=seed, octaves=octaves, frequency=f, persistence=persistence,
                        lacunarity=lacunarity)
    return np.clip(0.5 * (h.astype(np.float64) + 1.0), 0.0, 1.0).astype(np.float32)


def city_blocks(width: int, depth: int, blocks: int = 8, street: float = 0.3, min_height: float = 0.1,
                max_height: float = 1.0, seed: int = 0) -> np.ndarray:
    """The seed's city: square blocks on a street grid, one flat-roofed building per block.

    ``blocks`` blocks along the shorter side (cells of size 1 / blocks, the
    grid starting at u = v = 0); streets take the share ``street`` of each cell
    (0 <= street < 1; half a street on each side of a block); each building's
    height is uniform in [min_height, max_height] (0 <= min <= max <= 1),
    pseudo-random per block from ``seed`` (an integer hash, so a block's
    height does not depend on the resolution); streets are 0. Walls are
    vertical as far as the grid allows: one cell wide.
    """
    from .procedural import _hash_uniform

    width, depth = _grid_size(width, depth)
    blocks = _param_int("city_blocks", "blocks", blocks, 1, 1 << 16)
    street = _param_number("city_blocks", "street", street, 0.0)
    if street >= 1.0:
        raise InputError(f"terrain 'city_blocks': street = {street} must be < 1 (the share of a cell)")
    max_height = _param_number("city_blocks", "max_height", max_height, 0.0, 1.0)
    min_height = _param_number("city_blocks", "min_height", min_height, 0.0, max_height)
    seed = _seed("city_blocks", seed)
    u, v, _, _ = _uv(width, depth)
    su, sv = u * blocks, v * blocks
    ku, kv = np.floor(su), np.floor(sv)
    half = (1.0 - street) / 2
    inside = (np.abs(su - ku - 0.5) < half) & (np.abs(sv - kv - 0.5) < half)
    r = 0.5 * (_hash_uniform(ku.astype(np.int64), kv.astype(np.int64), seed * 0x9E3779B1 + 17) + 1.0)  # (D, W)
    return np.where(inside, min_height + (max_height - min_height) * r, 0.0).astype(np.float32)


TERRAINS: dict[str, Callable[..., np.ndarray]] = {
    "flat": flat,
    "cones": cones,
    "cones_circle": cones_circle,
    "sine_grating": sine_grating,
    "egg_tray": egg_tray,
    "fbm": fbm,
    "city_blocks": city_blocks,
}


def terrain_parameters(name: str) -> tuple[str, ...]:
    """The keyword parameters of terrain ``name`` (after width and depth)."""
    if name not in TERRAINS:
        raise InputError(f"unknown terrain {name!r}; valid terrains: {', '.join(TERRAINS)}")
    return tuple(list(inspect.signature(TERRAINS[name]).parameters)[2:])


def check_terrain_params(name: str, params: dict) -> None:
    """Raises :class:`InputError` for an unknown terrain or parameter names it does not take (values
    are checked when the terrain is made)."""
    valid = terrain_parameters(name)
    unknown = sorted(set(params) - set(valid))
    if unknown:
        raise InputError(f"terrain {name!r} has no parameter(s) {', '.join(unknown)}; "
                         f"valid: {', '.join(valid) or 'none'}")


def make_terrain(name: str, width: int, depth: int, **params) -> np.ndarray:
    """Heights of the procedural terrain ``name`` (a key of :data:`TERRAINS`): float32 (depth, width)."""
    check_terrain_params(name, params)
    return TERRAINS[name](width, depth, **params)
