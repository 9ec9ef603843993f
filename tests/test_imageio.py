"""Tests for penumbra.imageio and penumbra.fileutil.

Radiance files are built byte by byte here (flat, new-style RLE and old-style
RLE scanlines) from known RGBE bytes, so the expected radiance follows from the
format's definition (mantissa * 2**(exponent - 136)) rather than from the
decoder under test. The real maps come from ../shared/data/envmaps (the
``shared_data`` fixture).
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np
import OpenEXR
import pytest
from PIL import Image

from penumbra.errors import InputError
from penumbra.fileutil import atomic_write, atomic_write_text, captured_native_output
from penumbra.imageio import read_envmap, read_exr, srgb_encode, write_exr, write_png


@pytest.fixture(scope="module")
def envmaps(shared_data) -> Path:
    """The real environment maps (../shared/data/envmaps; the conftest fails clearly if absent)."""
    return shared_data / "envmaps"


# Maximum luminance (Rec. 709) of each real .hdr map, from /work/shared/data/SOURCES.md.
HDR_MAX_LUMINANCE = {
    "rooitou_park_1k_polyhaven.hdr": 64890, "immenstadter_horn_1k_polyhaven.hdr": 6704,
    "venice_sunset_1k_polyhaven.hdr": 2091, "potsdamer_platz_1k_polyhaven.hdr": 10.9,
    "kiara_1_dawn_1k_polyhaven.hdr": 46.2, "forest_slope_1k_polyhaven.hdr": 59.4,
    "st_fagans_interior_1k_polyhaven.hdr": 1111, "empty_warehouse_01_1k_polyhaven.hdr": 400,
    "studio_small_03_1k_polyhaven.hdr": 3352, "lebombo_1k_polyhaven.hdr": 23.3,
    "grace_probulator_256x128.hdr": 2177, "uffizi_probulator_256x128.hdr": 13.8,
    "pisa_probulator_256x128.hdr": 3.87, "ennis_probulator_256x128.hdr": 81.5,
    "wells_probulator_256x128.hdr": 5.11,
}
LUMA = np.array([0.2126, 0.7152, 0.0722])


# --------------------------------------------------------------------------- #
# Radiance test-file construction and an independent reference decoder
# --------------------------------------------------------------------------- #


def rgbe_to_float(rgbe: np.ndarray) -> np.ndarray:
    """Reference decode, pixel by pixel with math.ldexp (the format's definition)."""
    out = np.zeros(rgbe.shape[:-1] + (3,), dtype=np.float32)
    for index in np.ndindex(rgbe.shape[:-1]):
        r, g, b, e = (int(x) for x in rgbe[index])
        if e:
            out[index] = [math.ldexp(r, e - 136), math.ldexp(g, e - 136), math.ldexp(b, e - 136)]
    return out


def make_rgbe(height: int, width: int, seed: int = 0) -> np.ndarray:
    """Random RGBE pixels with long runs in some channels, so RLE has both runs and literals."""
    rng = np.random.default_rng(seed)
    rgbe = rng.integers(0, 256, size=(height, width, 4), dtype=np.uint8)
    rgbe[..., 3] = rng.integers(120, 140, size=(height, width))
    rgbe[:, width // 3 : width // 3 + 20, 3] = 130  # a run in the exponent channel
    rgbe[:, : width // 4, 0] = 77  # a run in red
    rgbe[0, :3, 3] = 0  # exponent 0 means black, whatever the mantissas
    return rgbe


def header(resolution: str, extra: str = "") -> bytes:
    return f"#?RADIANCE\n{extra}FORMAT=32-bit_rle_rgbe\n\n{resolution}\n".encode()


def encode_flat(rgbe: np.ndarray) -> bytes:
    return rgbe.astype(np.uint8).tobytes()


def encode_channel_rle(values: bytes) -> bytes:
    """New-style RLE of one channel: runs (128 + n, value) for repeats of >= 4, literals otherwise."""
    out = bytearray()
    i = 0
    n = len(values)
    while i < n:
        run = 1
        while i + run < n and run < 127 and values[i + run] == values[i]:
            run += 1
        if run >= 4:
            out += bytes((128 + run, values[i]))
            i += run
            continue
        start = i
        while i < n and i - start < 128:
            ahead = 1
            while i + ahead < n and ahead < 4 and values[i + ahead] == values[i]:
                ahead += 1
            if ahead >= 4:
                break
            i += 1
        out += bytes((i - start,)) + values[start:i]
    return bytes(out)


def encode_new_rle(rgbe: np.ndarray) -> bytes:
    height, width, _ = rgbe.shape
    out = bytearray()
    for y in range(height):
        out += bytes((2, 2, width >> 8, width & 0xFF))
        for c in range(4):
            out += encode_channel_rle(rgbe[y, :, c].tobytes())
    return bytes(out)


def encode_old_rle(rgbe: np.ndarray) -> bytes:
    """Old-style RLE: a repeat of n previous pixels is (1,1,1,n & 255), then (1,1,1,n >> 8) ..."""
    out = bytearray()
    for row in rgbe:
        x = 0
        while x < len(row):
            out += row[x].tobytes()
            repeat = 0
            while x + 1 + repeat < len(row) and np.array_equal(row[x + 1 + repeat], row[x]):
                repeat += 1
            count, shift_bytes = repeat, []
            while count:
                shift_bytes.append(count & 0xFF)
                count >>= 8
            for byte in shift_bytes:
                out += bytes((1, 1, 1, byte))
            x += 1 + repeat
    return bytes(out)


def write_hdr(path: Path, body: bytes, resolution: str, extra: str = "") -> Path:
    path.write_bytes(header(resolution, extra) + body)
    return path


# --------------------------------------------------------------------------- #
# Radiance RGBE
# --------------------------------------------------------------------------- #


@pytest.mark.parametrize("encoder", [encode_flat, encode_new_rle, encode_old_rle])
def test_rgbe_encodings_decode_exactly(tmp_path, encoder):
    rgbe = make_rgbe(5, 40)
    path = write_hdr(tmp_path / "x.hdr", encoder(rgbe), "-Y 5 +X 40")
    image = read_envmap(path)
    assert image.shape == (5, 40, 3) and image.dtype == np.float32 and image.flags.c_contiguous
    np.testing.assert_array_equal(image, rgbe_to_float(rgbe))
    assert (image[0, :3] == 0).all()


def test_rgbe_new_rle_really_uses_runs(tmp_path):
    rgbe = make_rgbe(3, 64)
    body = encode_new_rle(rgbe)
    assert len(body) < rgbe.size  # the encoder under test produced compressed data
    np.testing.assert_array_equal(read_envmap(write_hdr(tmp_path / "a.hdr", body, "-Y 3 +X 64")), rgbe_to_float(rgbe))


def test_rgbe_old_rle_multibyte_repeat(tmp_path):
    # A run of 300 repeats needs two markers: 300 = 44 + 1 * 256.
    rgbe = np.zeros((2, 400, 4), dtype=np.uint8)
    rgbe[..., :] = (10, 20, 30, 129)
    rgbe[:, 350:] = (200, 100, 50, 131)
    body = encode_old_rle(rgbe)
    assert bytes((1, 1, 1, 1)) in body and len(body) < 100
    np.testing.assert_array_equal(read_envmap(write_hdr(tmp_path / "o.hdr", body, "-Y 2 +X 400")), rgbe_to_float(rgbe))


def test_rgbe_small_width_is_flat(tmp_path):
    rgbe = make_rgbe(4, 5)  # widths below 8 cannot use new-style RLE
    np.testing.assert_array_equal(read_envmap(write_hdr(tmp_path / "s.pic", encode_flat(rgbe), "-Y 4 +X 5")),
                                  rgbe_to_float(rgbe))


def test_rgbe_header_quirks(tmp_path):
    rgbe = make_rgbe(3, 16)
    extra = ("#?RADIANCE\n# Made with Adobe Photoshop\nGAMMA=1\nPRIMARIES=0 0 0 0 0 0 0 0\n"
             "EXPOSURE=          1.0000000000000\n")
    image = read_envmap(write_hdr(tmp_path / "q.HDR", encode_new_rle(rgbe), "-Y 3 +X 16", extra))
    np.testing.assert_array_equal(image, rgbe_to_float(rgbe))


def test_rgbe_exposure_is_divided_out(tmp_path):
    rgbe = make_rgbe(3, 16)
    reference = rgbe_to_float(rgbe)
    image = read_envmap(write_hdr(tmp_path / "e2.hdr", encode_flat(rgbe), "-Y 3 +X 16", "EXPOSURE=2\n"))
    np.testing.assert_array_equal(image, reference / 2)
    # EXPOSURE values are cumulative.
    image = read_envmap(write_hdr(tmp_path / "e6.hdr", encode_flat(rgbe), "-Y 3 +X 16", "EXPOSURE=2\nEXPOSURE=3\n"))
    np.testing.assert_allclose(image, reference / 6, rtol=1e-6)


@pytest.mark.parametrize("value", ["0", "-1", "nan", "inf", "abc"])
def test_rgbe_invalid_exposure_warns_and_is_ignored(tmp_path, value):
    rgbe = make_rgbe(3, 16)
    path = write_hdr(tmp_path / "e0.hdr", encode_flat(rgbe), "-Y 3 +X 16", f"EXPOSURE={value}\n")
    with pytest.warns(UserWarning, match="EXPOSURE"):
        image = read_envmap(path)
    assert np.isfinite(image).all() and image.max() > 0
    np.testing.assert_array_equal(image, rgbe_to_float(rgbe))


def test_rgbe_colorcorr_is_divided_out(tmp_path):
    rgbe = make_rgbe(2, 16)
    path = write_hdr(tmp_path / "c.hdr", encode_flat(rgbe), "-Y 2 +X 16", "COLORCORR=2 4 0.5\n")
    np.testing.assert_allclose(read_envmap(path), rgbe_to_float(rgbe) / np.array([2, 4, 0.5], np.float32), rtol=1e-6)


def test_rgbe_bottom_up_is_flipped(tmp_path):
    rgbe = make_rgbe(4, 16)
    image = read_envmap(write_hdr(tmp_path / "up.hdr", encode_new_rle(rgbe), "+Y 4 +X 16"))
    np.testing.assert_array_equal(image, rgbe_to_float(rgbe)[::-1])


@pytest.mark.parametrize("resolution", ["-Y 4 -X 16", "+X 16 -Y 4", "-X 16 +Y 4"])
def test_rgbe_other_orientations_rejected(tmp_path, resolution):
    rgbe = make_rgbe(4, 16)
    with pytest.raises(InputError, match="orientation"):
        read_envmap(write_hdr(tmp_path / "o.hdr", encode_flat(rgbe), resolution))


@pytest.mark.parametrize("encoder", [encode_flat, encode_new_rle, encode_old_rle])
def test_rgbe_truncated(tmp_path, encoder):
    rgbe = make_rgbe(6, 40)
    body = encoder(rgbe)
    for cut in (1, len(body) // 2, len(body) - 1):
        path = write_hdr(tmp_path / f"t{cut}.hdr", body[:cut], "-Y 6 +X 40")
        with pytest.raises(InputError, match="truncated") as info:
            read_envmap(path)
        assert str(path) in str(info.value)


@pytest.mark.parametrize("content, match", [
    (os.urandom(2000), "magic"),
    (b"", "magic"),
    (b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n", "header"),
    (b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n", "resolution"),
    (b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\nhello world\n" + bytes(64), "resolution"),
    (b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 0 +X 4\n", "resolution"),
    (b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 100000 +X 100000\n", "resolution"),
    (b"#?RADIANCE\nFORMAT=32-bit_rle_xyze\n\n-Y 1 +X 1\n\x80\x80\x80\x80", "XYZE"),
    (b"#?RADIANCE\nFORMAT=16-bit\n\n-Y 1 +X 1\n\x80\x80\x80\x80", "FORMAT"),
    # New-RLE scanline header announcing the wrong width.
    (b"#?RADIANCE\n\n-Y 1 +X 8\n\x02\x02\x00\x09" + bytes(40), "length"),
    # A zero-length literal run.
    (b"#?RADIANCE\n\n-Y 1 +X 8\n\x02\x02\x00\x08\x00" + bytes(40), "zero-length"),
    # A run longer than the scanline.
    (b"#?RADIANCE\n\n-Y 1 +X 8\n\x02\x02\x00\x08\xff\x01" + bytes(40), "overruns"),
    # An old-style repeat marker before any pixel.
    (b"#?RADIANCE\n\n-Y 1 +X 4\n\x01\x01\x01\x04", "before the first"),
])
def test_rgbe_corrupt(tmp_path, content, match):
    path = tmp_path / "bad.hdr"
    path.write_bytes(content)
    with pytest.raises(InputError, match=match) as info:
        read_envmap(path)
    assert str(path) in str(info.value)


@pytest.mark.parametrize("name", sorted(HDR_MAX_LUMINANCE))
def test_real_hdr_files(envmaps, name):
    image = read_envmap(envmaps / name)
    expected_width = 256 if "probulator" in name else 1024
    assert image.shape == (expected_width // 2, expected_width, 3)
    assert image.dtype == np.float32 and image.flags.c_contiguous
    assert np.isfinite(image).all() and image.min() >= 0
    luminance = image @ LUMA.astype(np.float32)
    assert luminance.max() == pytest.approx(HDR_MAX_LUMINANCE[name], rel=0.01)
    assert 0.005 < np.median(luminance) < 1.0


@pytest.mark.parametrize("name", ["grace_probulator_256x128.hdr", "pisa_probulator_256x128.hdr"])
def test_real_hdr_matches_slow_reference_decoder(envmaps, name):
    """Decode a real file with a deliberately naive byte-by-byte decoder and compare bit for bit."""
    data = (envmaps / name).read_bytes()
    pos = data.index(b"\n\n") + 2
    end = data.index(b"\n", pos)
    _, height, _, width = data[pos:end].split()
    height, width = int(height), int(width)
    pos = end + 1
    rgbe = np.zeros((height, width, 4), dtype=np.uint8)
    for y in range(height):
        assert data[pos:pos + 2] == b"\x02\x02"
        pos += 4
        for c in range(4):
            x = 0
            while x < width:
                count = data[pos]
                if count > 128:
                    for _ in range(count - 128):
                        rgbe[y, x, c] = data[pos + 1]
                        x += 1
                    pos += 2
                else:
                    for k in range(count):
                        rgbe[y, x, c] = data[pos + 1 + k]
                        x += 1
                    pos += 1 + count
    np.testing.assert_array_equal(read_envmap(envmaps / name), rgbe_to_float(rgbe))


# --------------------------------------------------------------------------- #
# OpenEXR
# --------------------------------------------------------------------------- #


def write_raw_exr(path: Path, channels: dict) -> Path:
    OpenEXR.File({"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}, channels).write(str(path))
    return path


@pytest.mark.parametrize("channels", [3, 4])
def test_exr_roundtrip_is_float_exact(tmp_path, channels):
    rng = np.random.default_rng(1)
    scale = 10.0 ** rng.integers(-20, 20, (7, 11, channels))
    image = (rng.standard_normal((7, 11, channels)) * scale).astype(np.float32)
    path = tmp_path / "sub" / "rt.exr"  # the parent directory is created
    write_exr(path, image)
    back = read_exr(path)
    assert back.dtype == np.float32 and back.shape == image.shape
    np.testing.assert_array_equal(back, image)
    np.testing.assert_array_equal(read_envmap(path), image[..., :3])  # alpha dropped
    header_info = OpenEXR.File(str(path), header_only=True).header()
    assert header_info["compression"] == OpenEXR.ZIP_COMPRESSION
    assert not [p for p in path.parent.iterdir() if p.name != "rt.exr"]  # no temp files left


def test_exr_half_channels(tmp_path):
    rng = np.random.default_rng(2)
    half = (rng.random((6, 9, 3)) * 1000).astype(np.float16)
    path = write_raw_exr(tmp_path / "h.exr", {name: half[..., k].copy() for k, name in enumerate("RGB")})
    image = read_envmap(path)
    assert image.dtype == np.float32
    np.testing.assert_array_equal(image, half.astype(np.float32))


def test_exr_luminance_only_is_replicated(tmp_path):
    y = np.arange(12, dtype=np.float32).reshape(3, 4)
    image = read_envmap(write_raw_exr(tmp_path / "y.exr", {"Y": y}))
    np.testing.assert_array_equal(image, np.repeat(y[..., None], 3, axis=2))


def test_exr_without_colour_channels(tmp_path):
    path = write_raw_exr(tmp_path / "z.exr", {"Z": np.ones((2, 2), np.float32)})
    with pytest.raises(InputError, match="no R, G, B or Y"):
        read_envmap(path)


def test_exr_integer_channels_rejected(tmp_path):
    ones = np.ones((2, 2), np.uint32)
    path = write_raw_exr(tmp_path / "u.exr", {"R": ones, "G": ones, "B": ones})
    with pytest.raises(InputError, match="pixel type"):
        read_envmap(path)


def test_exr_tiled_mipmapped_kerner(envmaps):
    image = read_envmap(envmaps / "KernerEnvLatLong.exr")
    assert image.shape == (512, 1024, 3) and image.dtype == np.float32 and image.flags.c_contiguous
    assert np.isfinite(image).all() and image.min() > 0
    assert (image @ LUMA.astype(np.float32)).max() == pytest.approx(1678, rel=0.01)


def test_exr_real_files(envmaps):
    assert read_envmap(envmaps / "StageEnvLatLong.exr").shape == (500, 1000, 3)
    assert read_exr(envmaps / "OrientationLatLong.exr").shape == (512, 1024, 4)
    assert read_envmap(envmaps / "WavyLinesLatLong.exr").shape == (512, 1024, 3)


@pytest.mark.parametrize("damage", ["truncate", "garbage", "header_only", "corrupt_chunks"])
def test_exr_damaged(tmp_path, envmaps, damage):
    data = bytearray((envmaps / "StageEnvLatLong.exr").read_bytes())
    if damage == "truncate":
        data = data[: len(data) // 3]
    elif damage == "garbage":
        data = bytearray(np.random.default_rng(3).integers(0, 256, 5000, dtype=np.uint8).tobytes())
    elif damage == "header_only":
        data = data[:200]
    else:
        rng = np.random.default_rng(4)
        for pos in rng.integers(5000, len(data), 3000):
            data[pos] = int(rng.integers(0, 256))
    path = tmp_path / "damaged.exr"
    path.write_bytes(bytes(data))
    with pytest.raises(InputError) as info:
        read_envmap(path)
    assert str(path) in str(info.value)


# --------------------------------------------------------------------------- #
# .npy and general errors
# --------------------------------------------------------------------------- #


def test_npy(tmp_path):
    array = np.random.default_rng(5).random((4, 8, 3))
    np.save(tmp_path / "m.npy", array)
    image = read_envmap(tmp_path / "m.npy")
    assert image.dtype == np.float32 and image.flags.c_contiguous
    np.testing.assert_array_equal(image, array.astype(np.float32))
    nan = array.copy()
    nan[1, 2, 0] = np.nan
    np.save(tmp_path / "nan.npy", nan)
    assert np.isnan(read_envmap(tmp_path / "nan.npy")[1, 2, 0])  # returned faithfully, not validated here


@pytest.mark.parametrize("array", [np.zeros((4, 8)), np.zeros((4, 8, 4)), np.zeros((0, 8, 3)),
                                   np.zeros((4, 8, 3), dtype=complex), np.array([{"a": 1}], dtype=object)])
def test_npy_bad_arrays(tmp_path, array):
    np.save(tmp_path / "bad.npy", array, allow_pickle=True)
    with pytest.raises(InputError, match="bad.npy"):
        read_envmap(tmp_path / "bad.npy")


def test_missing_directory_and_unknown_extension(tmp_path):
    with pytest.raises(InputError, match="not found"):
        read_envmap(tmp_path / "missing.hdr")
    with pytest.raises(InputError, match="not found"):
        read_envmap(tmp_path / "missing.exr")
    (tmp_path / "dir.hdr").mkdir()
    with pytest.raises(InputError, match="not a regular file"):
        read_envmap(tmp_path / "dir.hdr")
    (tmp_path / "x.png").write_bytes(b"png")
    with pytest.raises(InputError, match="unsupported"):
        read_envmap(tmp_path / "x.png")


# --------------------------------------------------------------------------- #
# PNG and sRGB
# --------------------------------------------------------------------------- #


def test_srgb_encode_values():
    assert srgb_encode(0.0) == 0.0
    assert srgb_encode(1.0) == pytest.approx(1.0, abs=1e-12)
    assert srgb_encode(0.0031308) == pytest.approx(12.92 * 0.0031308)
    assert srgb_encode(0.5) == pytest.approx(1.055 * 0.5 ** (1 / 2.4) - 0.055)
    # The two pieces meet at the threshold (continuity of the official curve).
    assert 1.055 * 0.0031308 ** (1 / 2.4) - 0.055 == pytest.approx(12.92 * 0.0031308, abs=1e-7)
    assert srgb_encode(np.array([0.0031307, 0.0031309])).tolist() == pytest.approx(
        [12.92 * 0.0031307, 1.055 * 0.0031309 ** (1 / 2.4) - 0.055])
    x = np.linspace(0, 1, 1001)
    assert (np.diff(srgb_encode(x)) > 0).all()


def test_write_png_values(tmp_path):
    image = np.array([[[0.0, 1.0, 0.5], [0.0031308, 2.0, -1.0], [0.25, 0.001, 0.04]]], dtype=np.float32)
    path = tmp_path / "out" / "v.png"
    write_png(path, image)
    pixels = np.asarray(Image.open(path))
    assert pixels.shape == (1, 3, 3) and pixels.dtype == np.uint8
    assert pixels[0, 0].tolist() == [0, 255, 188]
    assert pixels[0, 1].tolist() == [10, 255, 0]  # 12.92 * 0.0031308 * 255 = 10.3; clamped above 1 and below 0
    expected = np.floor(srgb_encode(image[0, 2]) * 255 + 0.5)
    assert pixels[0, 2].tolist() == expected.tolist()


def test_write_png_exposure_and_alpha(tmp_path):
    image = np.array([[[0.25, 0.25, 0.25, 0.5], [1.0, 0.0, 0.0, 1.0]]], dtype=np.float32)
    write_png(tmp_path / "a.png", image, exposure=1.0)
    pixels = np.asarray(Image.open(tmp_path / "a.png"))
    assert Image.open(tmp_path / "a.png").mode == "RGBA"
    assert pixels[0, 0].tolist() == [188, 188, 188, 128]  # 0.25 * 2 = 0.5 -> 188; alpha stays linear
    write_png(tmp_path / "b.png", image, exposure=-1.0)
    assert np.asarray(Image.open(tmp_path / "b.png"))[0, 1].tolist() == [188, 0, 0, 255]


@pytest.mark.parametrize("writer", [write_png, write_exr])
@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf, 1e39])
def test_writers_refuse_non_finite(tmp_path, writer, bad):
    path = tmp_path / "img"
    path.write_bytes(b"old contents")
    image = np.ones((3, 4, 3), dtype=np.float64)
    image[2, 1, 0] = bad
    with pytest.raises(InputError, match="non-finite") as info:
        writer(path, image)
    assert "row 2, column 1" in str(info.value) and str(path) in str(info.value)
    assert path.read_bytes() == b"old contents"
    assert [p.name for p in tmp_path.iterdir()] == ["img"]


@pytest.mark.parametrize("writer", [write_png, write_exr])
@pytest.mark.parametrize("shape", [(4, 4), (4, 4, 2), (4, 4, 5), (0, 4, 3)])
def test_writers_refuse_bad_shapes(tmp_path, writer, shape):
    with pytest.raises(InputError, match="shape"):
        writer(tmp_path / "x", np.zeros(shape, np.float32))


def test_write_png_refuses_bad_exposure(tmp_path):
    with pytest.raises(InputError, match="exposure"):
        write_png(tmp_path / "x.png", np.zeros((2, 2, 3)), exposure=float("nan"))


# --------------------------------------------------------------------------- #
# fileutil
# --------------------------------------------------------------------------- #


def test_atomic_write_failure_keeps_old_file(tmp_path):
    target = tmp_path / "keep.txt"
    target.write_text("old")

    def failing(tmp: str) -> None:
        Path(tmp).write_text("partial new contents")
        raise RuntimeError("disk full")

    with pytest.raises(RuntimeError, match="disk full"):
        atomic_write(target, failing)
    assert target.read_text() == "old"
    assert [p.name for p in tmp_path.iterdir()] == ["keep.txt"]

    def interrupted(tmp: str) -> None:
        Path(tmp).write_text("partial")
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        atomic_write(target, interrupted)
    assert target.read_text() == "old"
    assert [p.name for p in tmp_path.iterdir()] == ["keep.txt"]


def test_atomic_write_replaces_and_creates_dirs(tmp_path):
    target = tmp_path / "a" / "b" / "new.bin"
    seen = []

    def write(tmp: str) -> None:
        seen.append(tmp)
        assert Path(tmp).parent == target.parent and Path(tmp).suffix == ".bin"
        Path(tmp).write_bytes(b"data")

    assert atomic_write(target, write) == target
    assert target.read_bytes() == b"data"
    assert not Path(seen[0]).exists()
    atomic_write(target, lambda tmp: Path(tmp).write_bytes(b"newer"), suffix=".tmpx")
    assert target.read_bytes() == b"newer"
    assert sorted(p.name for p in target.parent.iterdir()) == ["new.bin"]


def test_atomic_write_text_and_mode(tmp_path):
    target = tmp_path / "t.txt"
    atomic_write_text(target, "héllo\n")
    assert target.read_text(encoding="utf-8") == "héllo\n"
    reference = tmp_path / "ref.txt"
    reference.write_text("x")
    # The temporary file must not leave the result private (mkstemp's 0600).
    assert target.stat().st_mode & 0o777 == reference.stat().st_mode & 0o777


def test_captured_native_output():
    with captured_native_output() as native:
        os.write(1, b"to stdout\n")
        os.write(2, b"to stderr\n")
    assert native.text == "to stdout\nto stderr\n"
