"""penumbra.metrics: hand-computed values, masks, every documented error, and
the two ends of the heat map's colour map."""

from __future__ import annotations

import math

import numpy as np
import pytest

from penumbra import metrics
from penumbra.errors import InputError
from penumbra.imageio import srgb_encode

REF = np.array([[0.0, 1.0], [2.0, 3.0]])
IMG = np.array([[1.0, 1.0], [2.0, 2.0]])  # differences +1, 0, 0, -1


def test_grey_2x2_by_hand():
    m = metrics.compare(REF, IMG)
    # MSE = (1 + 0 + 0 + 1) / 4 = 0.5; range(ref) = 3; RMS(ref) = sqrt((0 + 1 + 4 + 9) / 4) = sqrt(3.5)
    assert m["rmse"] == pytest.approx(math.sqrt(0.5), rel=1e-15)
    assert m["nrmse"] == pytest.approx(math.sqrt(0.5) / 3.0, rel=1e-15)
    assert m["rel_rms"] == pytest.approx(math.sqrt(0.5 / 3.5), rel=1e-15)
    assert m["max_abs"] == 1.0
    assert m["pixels"] == 4
    assert set(m) == {"nrmse", "rel_rms", "max_abs", "rmse", "pixels"}
    assert all(type(m[k]) is float for k in ("nrmse", "rel_rms", "max_abs", "rmse"))
    assert type(m["pixels"]) is int


def test_rgb_rmse_runs_over_all_channels():
    ref = np.zeros((2, 2, 3))
    ref[..., 0] = 1.0          # R = 1 everywhere, G = B = 0: range 1, RMS(ref) = sqrt(4 / 12)
    img = ref.copy()
    img[0, 0] = (1.0, 1.0, 0.0)  # one sample (G) off by 1 ...
    img[1, 1, 2] = -2.0          # ... one by 2: MSE = (1 + 4) / 12
    m = metrics.compare(ref, img)
    assert m["rmse"] == pytest.approx(math.sqrt(5.0 / 12.0), rel=1e-15)
    assert m["nrmse"] == pytest.approx(math.sqrt(5.0 / 12.0), rel=1e-15)
    assert m["rel_rms"] == pytest.approx(math.sqrt(5.0 / 12.0) / math.sqrt(4.0 / 12.0), rel=1e-15)
    assert m["max_abs"] == 2.0
    assert m["pixels"] == 4


def test_mask_selects_pixels():
    mask = np.array([[True, False], [False, True]])  # samples (0,0): ref 0, d +1; (1,1): ref 3, d -1
    m = metrics.compare(REF, IMG, mask)
    assert m["pixels"] == 2
    assert m["rmse"] == pytest.approx(1.0)
    assert m["nrmse"] == pytest.approx(1.0 / 3.0)
    assert m["rel_rms"] == pytest.approx(1.0 / math.sqrt(4.5))
    assert m["max_abs"] == 1.0
    # Unselected pixels do not count, even when they hold NaN or Inf.
    img = IMG.copy()
    img[0, 1], img[1, 0] = np.nan, np.inf
    assert metrics.compare(REF, img, mask) == m
    only_equal = np.array([[False, True], [True, False]])
    assert metrics.compare(REF, IMG, only_equal)["rmse"] == 0.0


def test_float32_and_integer_inputs_are_computed_in_float64():
    ref = np.full((1, 2), 16777216.0, np.float32)  # 2**24: float32 cannot hold 2**24 + 1
    img = np.array([[16777216.0, 16777218.0]], np.float32)
    assert metrics.compare(ref, img)["rmse"] == pytest.approx(math.sqrt(2.0))
    a, b = np.array([[0, 255]], np.uint8), np.array([[255, 0]], np.uint8)  # no wrap-around
    assert metrics.compare(a, b)["max_abs"] == 255.0


def test_wrappers_match_compare():
    m = metrics.compare(REF, IMG)
    assert metrics.rmse(REF, IMG) == m["rmse"]
    assert metrics.nrmse(REF, IMG) == m["nrmse"]
    assert metrics.rel_rms(REF, IMG) == m["rel_rms"]
    assert metrics.max_abs(REF, IMG) == m["max_abs"]


def test_constant_or_zero_reference_gives_inf_or_zero_never_nan():
    ref = np.full((2, 2, 3), 0.5)
    m = metrics.compare(ref, ref + 0.1)
    assert m["nrmse"] == math.inf
    assert m["rel_rms"] == pytest.approx(0.2)
    m = metrics.compare(ref, ref)
    assert m["nrmse"] == 0.0 and m["rel_rms"] == 0.0 and m["rmse"] == 0.0
    zero = np.zeros((2, 2))
    m = metrics.compare(zero, zero + 1.0)
    assert m["nrmse"] == math.inf and m["rel_rms"] == math.inf and m["rmse"] == 1.0
    m = metrics.compare(zero, zero)
    assert m["nrmse"] == 0.0 and m["rel_rms"] == 0.0
    # Constant only on the selected pixels counts as constant.
    mask = np.array([[True, False], [False, False]])
    assert metrics.compare(REF, IMG, mask)["nrmse"] == math.inf


@pytest.mark.parametrize("ref, img, pattern", [
    (np.zeros((2, 2)), np.zeros((2, 3)), "same shape"),
    (np.zeros((2, 2, 3)), np.zeros((2, 2)), "same shape"),
    (np.zeros(4), np.zeros(4), r"\(H, W\)"),
    (np.zeros((2, 2, 3, 1)), np.zeros((2, 2, 3, 1)), r"\(H, W\)"),
    (np.zeros((0, 2)), np.zeros((0, 2)), "empty"),
    (np.array([["a", "b"]]), np.array([["a", "b"]]), "numeric"),
])
def test_shape_errors(ref, img, pattern):
    with pytest.raises(InputError, match=pattern):
        metrics.compare(ref, img)


def test_mask_errors():
    with pytest.raises(InputError, match="no pixels"):
        metrics.compare(REF, IMG, np.zeros((2, 2), bool))
    with pytest.raises(InputError, match="shape"):
        metrics.compare(REF, IMG, np.ones((2, 3), bool))
    with pytest.raises(InputError, match="boolean"):
        metrics.compare(REF, IMG, np.ones((2, 2), np.uint8))
    with pytest.raises(InputError, match="no pixels"):
        metrics.error_heatmap(REF, IMG, np.zeros((2, 2), bool))


def test_non_finite_errors_say_how_many_and_where():
    img = np.zeros((3, 4, 3))
    img[1, 2, 1] = np.nan
    img[2, 0, 0] = np.inf
    img[2, 3, 2] = -np.inf
    with pytest.raises(InputError, match=r"img has 3 non-finite value\(s\).*1 NaN, 2 Inf.*row 1, column 2, channel 1"):
        metrics.compare(np.zeros((3, 4, 3)), img)
    ref = np.zeros((3, 4))
    ref[0, 3] = np.nan
    with pytest.raises(InputError, match=r"ref has 1 non-finite.*row 0, column 3$"):
        metrics.compare(ref, np.zeros((3, 4)))
    with pytest.raises(InputError, match="non-finite"):
        metrics.error_heatmap(ref, np.zeros((3, 4)))


def test_error_magnitude_is_rms_over_channels():
    ref = np.zeros((1, 2, 3))
    img = np.array([[[3.0, 0.0, 0.0], [1.0, 1.0, 1.0]]])
    e = metrics.error_magnitude(ref, img)
    np.testing.assert_allclose(e, [[math.sqrt(3.0), 1.0]], rtol=1e-15)
    np.testing.assert_array_equal(metrics.error_magnitude(REF, IMG), [[1.0, 0.0], [0.0, 1.0]])


def _srgb(linear: np.ndarray) -> np.ndarray:
    return srgb_encode(linear)


def test_heatmap_colormap_ends_and_masked_grey():
    ref = np.zeros((2, 2, 3))
    img = ref.copy()
    img[0, 1] = 0.5    # magnitude 0.5: the largest, so the top of the map
    img[1, 0] = 0.25   # half of it: the middle
    mask = np.array([[True, True], [True, False]])
    h = metrics.error_heatmap(ref, img, mask)
    assert h.shape == (2, 2, 3) and h.dtype == np.float32
    # Viridis ends, in sRGB after encoding the linear result.
    np.testing.assert_allclose(_srgb(h[0, 0]), (0.267004, 0.004874, 0.329415), atol=1e-6)
    np.testing.assert_allclose(_srgb(h[0, 1]), (0.993248, 0.906157, 0.143936), atol=1e-6)
    np.testing.assert_allclose(_srgb(h[1, 0]), (0.127568, 0.566949, 0.550556), atol=1e-6)  # viridis(0.5)
    np.testing.assert_allclose(_srgb(h[1, 1]), metrics.MASKED_COLOR_SRGB, atol=1e-6)
    # An explicit scale: 0.5 / 1.0 lands in the middle; errors above the scale saturate.
    h = metrics.error_heatmap(ref, img, mask, scale=1.0)
    np.testing.assert_allclose(_srgb(h[0, 1]), (0.127568, 0.566949, 0.550556), atol=1e-6)
    h = metrics.error_heatmap(ref, img, mask, scale=0.1)
    np.testing.assert_allclose(_srgb(h[1, 0]), (0.993248, 0.906157, 0.143936), atol=1e-6)


def test_heatmap_of_identical_images_is_the_low_end():
    h = metrics.error_heatmap(REF, REF)
    np.testing.assert_allclose(_srgb(h.reshape(-1, 3)), np.tile((0.267004, 0.004874, 0.329415), (4, 1)), atol=1e-6)


def test_colormap_is_monotone_in_lightness():
    rgb = metrics.colormap(np.linspace(0.0, 1.0, 256))
    lum = _srgb_to_linear_luminance(rgb)
    assert np.all(np.diff(lum) > 0.0)


def _srgb_to_linear_luminance(srgb: np.ndarray) -> np.ndarray:
    lin = np.where(srgb <= 0.04045, srgb / 12.92, ((srgb + 0.055) / 1.055) ** 2.4)
    return lin @ np.array([0.2126, 0.7152, 0.0722])


@pytest.mark.parametrize("scale", [0.0, -1.0, math.inf, math.nan, "1", True])
def test_heatmap_bad_scale(scale):
    with pytest.raises(InputError, match="scale"):
        metrics.error_heatmap(REF, IMG, scale=scale)


def test_write_heatmap_png(tmp_path):
    from PIL import Image

    ref = np.zeros((2, 2, 3))
    img = ref.copy()
    img[0, 1] = 2.0
    path = tmp_path / "sub" / "err.png"
    used = metrics.write_heatmap(path, ref, img, mask=np.array([[True, True], [True, False]]))
    assert used == pytest.approx(2.0)
    px = np.asarray(Image.open(path))
    assert px.shape == (2, 2, 3) and px.dtype == np.uint8
    np.testing.assert_array_equal(px[0, 0], np.floor(np.array((0.267004, 0.004874, 0.329415)) * 255 + 0.5))
    np.testing.assert_array_equal(px[0, 1], np.floor(np.array((0.993248, 0.906157, 0.143936)) * 255 + 0.5))
    np.testing.assert_array_equal(px[1, 1], (51, 51, 51))
    assert [p.name for p in path.parent.iterdir()] == ["err.png"]  # no temporary file left behind
