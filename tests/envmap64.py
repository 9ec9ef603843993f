"""float64 twins of the env map's per-pixel lookups (kernels/common/sphere_maps.cl,
kernels/envmap.cl): the conventions of docs/conventions.md written out in numpy."""

from __future__ import annotations

import numpy as np


def dir_to_latlong64(d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(u, v) of unit directions (..., 3): u = atan2(x, -z) / 2pi in [0, 1), v = acos(y) / pi."""
    d = np.asarray(d, np.float64)
    u = np.arctan2(d[..., 0], -d[..., 2]) / (2 * np.pi)
    u = np.where(u < 0, u + 1, u)
    u = np.where(u >= 1, 0.0, u)
    v = np.arccos(np.clip(d[..., 1], -1, 1)) / np.pi
    return u, v


def latlong_bilinear64(latlong: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Bilinear lookup of an (H, W, 3) lat-long map at unit directions (..., 3):
    texel (x, y) holds the value at ((x + 0.5) / W, (y + 0.5) / H); u wraps,
    v is clamped to the first and last rows."""
    lat = np.asarray(latlong, np.float64)
    h, w = lat.shape[:2]
    u, v = dir_to_latlong64(d)
    x, y = u * w - 0.5, v * h - 0.5
    x0, y0 = np.floor(x), np.floor(y)
    fx, fy = (x - x0)[..., None], (y - y0)[..., None]
    x0 = x0.astype(np.int64) % w
    x1 = (x0 + 1) % w
    y1 = np.clip(y0.astype(np.int64) + 1, 0, h - 1)
    y0 = np.clip(y0.astype(np.int64), 0, h - 1)
    top = lat[y0, x0] * (1 - fx) + lat[y0, x1] * fx
    bottom = lat[y1, x0] * (1 - fx) + lat[y1, x1] * fx
    return top * (1 - fy) + bottom * fy


def background64(latlong: np.ndarray, view_dirs: np.ndarray, rotation_deg: float = 0.0,
                 intensity: float = 1.0) -> np.ndarray:
    """What a background pixel looking along view_dirs (..., 3) shows: the map
    rotated about +y (world d sees the map at R_y(-angle) d) times intensity."""
    d = np.asarray(view_dirs, np.float64)
    d = d / np.linalg.norm(d, axis=-1, keepdims=True)
    a = np.radians(rotation_deg)
    c, s = np.cos(a), np.sin(a)
    # R_y(-a) d, with R_y(a) = [[c, 0, s], [0, 1, 0], [-s, 0, c]]
    local = np.stack([c * d[..., 0] - s * d[..., 2], d[..., 1], s * d[..., 0] + c * d[..., 2]], -1)
    return intensity * latlong_bilinear64(latlong, local)
