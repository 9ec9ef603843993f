"""float64 twin of the sharp-part extraction (pn_envmap_extract_sharp,
capi/src/core/env_domains.c; docs/depthmap.md "The sharp part").

A texel is hot where its luminance exceeds T = threshold x the map's mean
luminance (sum lum d_omega / 4 pi); the residual keeps luminance T there
(L T / lum, colour unchanged), the sharp part gets the excess
L (1 - T / lum), so residual + sharp = the map. The sharp part is then split
by the decomposition of tests/depthmap64.py into min(max_count, hot texels)
domains, each with the excess radiance of its hot texels and their own solid
angle.
"""

from __future__ import annotations

import numpy as np

import depthmap64 as dm


def split(env, threshold: float = 100.0):
    """(residual, sharp, hot mask) of an (H, W, 3) map, float64."""
    tex = dm.texels(env)
    rad = tex.radiance.reshape(env.shape)
    lum = rad @ dm.LUMINANCE
    limit = threshold * tex.weight.sum() / (4.0 * np.pi)
    hot = (lum > limit) & (limit > 0)
    keep = np.where(hot, limit / np.where(hot, lum, 1.0), 1.0)
    residual = rad * keep[..., None]
    return residual, rad - residual, hot


def sharp_domains(sharp: np.ndarray, hot: np.ndarray, centres: np.ndarray):
    """Radiance (N, 3) and solid angle (N,) of the hot texels nearest each centre."""
    tex = dm.texels(sharp)
    assign = dm.nearest(tex.dirs, centres)
    m = hot.ravel()
    radiance = np.zeros((len(centres), 3))
    np.add.at(radiance, assign[m], tex.power[m])
    omega = np.bincount(assign[m], weights=tex.omega[m], minlength=len(centres))
    return radiance, omega
