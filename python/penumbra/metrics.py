"""Image error metrics: the one definition used by tests, tools and reports.

Every number is computed in float64 over the *selected samples*: all pixels
(or only those where ``mask`` is True) and, for colour images, every channel
of each selected pixel. With ``n`` selected samples, ``d = img - ref``:

* ``rmse    = sqrt(sum(d**2) / n)``
* ``nrmse   = rmse / (max(ref) - min(ref))``  (range over the selected samples)
* ``rel_rms = rmse / sqrt(sum(ref**2) / n)``  (RMSE relative to RMS(ref))
* ``max_abs = max(|d|)``

A reference without range (``max == min``) or with ``RMS(ref) = 0`` makes the
normalised metric ``inf`` when the images differ and ``0.0`` when they are
identical on the selection; metrics never return NaN. docs/metrics.md has the
full contract (shapes, masks, errors) and the heat-map colour map.
"""

from __future__ import annotations

import math
import os

import numpy as np

from .errors import InputError

__all__ = ["compare", "rmse", "nrmse", "rel_rms", "max_abs", "error_magnitude", "error_heatmap", "write_heatmap",
           "colormap", "MASKED_COLOR_SRGB"]

# matplotlib's viridis (CC0, van der Walt & Smith), 17 of its 256 entries in
# sRGB at t = k/16 (entry round(255 k / 16)). Linear interpolation between
# them stays within 6/255 of the full table; no matplotlib needed.
_VIRIDIS_SRGB = np.array([
    (0.267004, 0.004874, 0.329415),
    (0.282327, 0.094955, 0.417331),
    (0.278826, 0.175490, 0.483397),
    (0.258965, 0.251537, 0.524736),
    (0.229739, 0.322361, 0.545706),
    (0.199430, 0.387607, 0.554642),
    (0.172719, 0.448791, 0.557885),
    (0.149039, 0.508051, 0.557250),
    (0.127568, 0.566949, 0.550556),
    (0.120081, 0.622161, 0.534946),
    (0.153894, 0.680203, 0.504172),
    (0.239374, 0.735588, 0.455688),
    (0.360741, 0.785964, 0.387814),
    (0.506271, 0.828786, 0.300362),
    (0.668054, 0.861999, 0.196293),
    (0.835270, 0.886029, 0.102646),
    (0.993248, 0.906157, 0.143936),
], dtype=np.float64)
_VIRIDIS_T = np.linspace(0.0, 1.0, len(_VIRIDIS_SRGB))

# Pixels outside the mask in a heat map: dark grey, sRGB 0.2 (51/255), darker
# than every colour of the map (viridis starts at a dark violet).
MASKED_COLOR_SRGB = (0.2, 0.2, 0.2)


# --------------------------------------------------------------------------- #
# Validation
# --------------------------------------------------------------------------- #


def _as_image(a, name: str) -> np.ndarray:
    arr = np.asarray(a)
    if arr.dtype.kind not in "fiub":
        raise InputError(f"{name} must be a real numeric array, got dtype {arr.dtype}")
    if arr.ndim not in (2, 3):
        raise InputError(f"{name} must have shape (H, W) or (H, W, C), got {arr.shape}")
    if arr.shape[0] == 0 or arr.shape[1] == 0 or (arr.ndim == 3 and arr.shape[2] == 0):
        raise InputError(f"{name} is empty (shape {arr.shape})")
    return arr.astype(np.float64)


def _check_finite(a: np.ndarray, sel: np.ndarray, name: str) -> None:
    """Raises if a selected sample of `a` is NaN or Inf: count and first (row, column[, channel])."""
    bad = ~np.isfinite(a)
    if a.ndim == 3:
        bad &= sel[..., None]
    else:
        bad &= sel
    count = int(bad.sum())
    if count:
        first = tuple(int(i) for i in np.argwhere(bad)[0])
        where = f"row {first[0]}, column {first[1]}" + (f", channel {first[2]}" if len(first) == 3 else "")
        nan = int(np.isnan(a[bad]).sum())
        raise InputError(f"{name} has {count} non-finite value(s) in the compared pixels ({nan} NaN, "
                         f"{count - nan} Inf); first at {where}")


def _prepare(ref, img, mask) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(ref, img) as float64 and the boolean (H, W) selection, all checked."""
    r = _as_image(ref, "ref")
    i = _as_image(img, "img")
    if r.shape != i.shape:
        raise InputError(f"ref and img must have the same shape, got {r.shape} and {i.shape}")
    if mask is None:
        sel = np.ones(r.shape[:2], dtype=bool)
    else:
        m = np.asarray(mask)
        if m.dtype != np.bool_:
            raise InputError(f"mask must be a boolean array, got dtype {m.dtype}")
        if m.shape != r.shape[:2]:
            raise InputError(f"mask must have shape (H, W) = {r.shape[:2]}, got {m.shape}")
        sel = m
    if not sel.any():
        raise InputError("mask selects no pixels")
    _check_finite(r, sel, "ref")
    _check_finite(i, sel, "img")
    return r, i, sel


def _ratio(num: float, den: float) -> float:
    """num / den where den = 0 gives inf for num > 0 and 0.0 for num = 0 (never NaN)."""
    if den > 0.0:
        return num / den
    return math.inf if num > 0.0 else 0.0


# --------------------------------------------------------------------------- #
# Metrics
# --------------------------------------------------------------------------- #


def compare(ref, img, mask=None) -> dict:
    """Error metrics of `img` against the reference `ref`.

    ``ref``, ``img``: arrays of the same shape, (H, W) or (H, W, C) (any real
    dtype; computed in float64). ``mask``: optional boolean (H, W); only
    pixels where it is True are compared (every channel of them).

    Returns ``{"nrmse", "rel_rms", "max_abs", "rmse", "pixels"}``: the four
    metrics as floats (see the module docstring) and the number of selected
    pixels (an int; samples = pixels * C).

    Raises :class:`InputError` for different shapes, a mask of the wrong
    shape or dtype, a mask selecting no pixel, and NaN or Inf in a selected
    sample of either image (message: how many, and the first one's position).
    """
    r, i, sel = _prepare(ref, img, mask)
    rs, is_ = r[sel], i[sel]  # (n_pixels,) or (n_pixels, C)
    d = is_ - rs
    mse = float(np.mean(d * d))
    rmse_ = math.sqrt(mse)
    span = float(rs.max() - rs.min())
    rms_ref = math.sqrt(float(np.mean(rs * rs)))
    return {"nrmse": _ratio(rmse_, span), "rel_rms": _ratio(rmse_, rms_ref), "max_abs": float(np.abs(d).max()),
            "rmse": rmse_, "pixels": int(sel.sum())}


def rmse(ref, img, mask=None) -> float:
    """Root-mean-square error over the selected pixels and all channels (see :func:`compare`)."""
    return compare(ref, img, mask)["rmse"]


def nrmse(ref, img, mask=None) -> float:
    """RMSE / (max(ref) - min(ref)) over the selection (see :func:`compare`)."""
    return compare(ref, img, mask)["nrmse"]


def rel_rms(ref, img, mask=None) -> float:
    """RMSE / RMS(ref) over the selection (see :func:`compare`)."""
    return compare(ref, img, mask)["rel_rms"]


def max_abs(ref, img, mask=None) -> float:
    """Largest absolute difference of one sample over the selection (see :func:`compare`)."""
    return compare(ref, img, mask)["max_abs"]


# --------------------------------------------------------------------------- #
# Heat maps
# --------------------------------------------------------------------------- #


def _srgb_decode(x: np.ndarray) -> np.ndarray:
    """Inverse of imageio.srgb_encode (IEC 61966-2-1), float64."""
    x = np.asarray(x, dtype=np.float64)
    return np.where(x <= 0.04045, x / 12.92, np.power((np.maximum(x, 0.04045) + 0.055) / 1.055, 2.4))


def colormap(values) -> np.ndarray:
    """The heat map's colour map: values in [0, 1] (clamped) -> (..., 3) float64 sRGB.

    Piecewise-linear in sRGB through 17 control points of viridis: 0 is dark
    violet (0.267, 0.005, 0.329), 1 is yellow (0.993, 0.906, 0.144).
    """
    v = np.clip(np.asarray(values, dtype=np.float64), 0.0, 1.0)
    return np.stack([np.interp(v, _VIRIDIS_T, _VIRIDIS_SRGB[:, c]) for c in range(3)], axis=-1)


def error_magnitude(ref, img, mask=None) -> np.ndarray:
    """Per-pixel error (H, W) float64: RMS over channels of ``img - ref`` (``|img - ref|`` for (H, W) images).

    Pixels outside the mask are 0. Same checks as :func:`compare`.
    """
    r, i, sel = _prepare(ref, img, mask)
    return _magnitude(r, i, sel)


def _magnitude(r: np.ndarray, i: np.ndarray, sel: np.ndarray) -> np.ndarray:
    with np.errstate(invalid="ignore", over="ignore"):  # masked-out NaN/Inf never reach the result
        d = np.where(sel[..., None] if r.ndim == 3 else sel, i - r, 0.0)
    return np.sqrt(np.mean(d * d, axis=2)) if d.ndim == 3 else np.abs(d)


def _heatmap(ref, img, mask, scale) -> tuple[np.ndarray, float]:
    r, i, sel = _prepare(ref, img, mask)
    e = _magnitude(r, i, sel)
    if scale is None:
        scale = float(e[sel].max())
    else:
        if isinstance(scale, bool) or not isinstance(scale, (int, float, np.integer, np.floating)):
            raise InputError(f"scale must be a number, got {scale!r}")
        scale = float(scale)
        if not (math.isfinite(scale) and scale > 0.0):
            raise InputError(f"scale must be a positive finite number, got {scale!r}")
    v = e / scale if scale > 0.0 else np.zeros_like(e)  # identical images: every pixel at the low end
    srgb = colormap(v)
    srgb[~sel] = MASKED_COLOR_SRGB
    return _srgb_decode(srgb).astype(np.float32), scale


def error_heatmap(ref, img, mask=None, scale=None) -> np.ndarray:
    """A picture of where `img` differs from `ref`: (H, W, 3) float32 *linear* RGB.

    Each selected pixel's error magnitude (:func:`error_magnitude`) divided by
    ``scale`` (default: the largest magnitude over the selection; values above
    ``scale`` saturate) goes through :func:`colormap`; pixels outside
    ``mask`` are dark grey (:data:`MASKED_COLOR_SRGB`). The colours are
    converted from sRGB to linear so that :func:`penumbra.imageio.write_png`
    (which encodes linear -> sRGB) writes exactly the colour map. When the
    images are identical on the selection (largest error 0 and no ``scale``
    given), every selected pixel has the colour of 0.

    Raises :class:`InputError` like :func:`compare`, and for a ``scale`` that
    is not a positive finite number.
    """
    return _heatmap(ref, img, mask, scale)[0]


def write_heatmap(path: str | os.PathLike, ref, img, mask=None, scale=None) -> float:
    """Writes :func:`error_heatmap` as an 8-bit sRGB PNG (atomically, via
    :func:`penumbra.imageio.write_png`) and returns the scale used (the error
    that maps to the top of the colour map)."""
    from .imageio import write_png

    image, used = _heatmap(ref, img, mask, scale)
    write_png(path, image)
    return used
