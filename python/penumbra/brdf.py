"""The material model of docs/brdf.md in float64 numpy: the reference the
kernels (kernels/common/brdf.cl) and the Mitsuba plugin are tested against.

All direction arguments are arrays of unit vectors (..., 3) that broadcast
together; the result is f(V, L) per colour channel (..., 3)."""

from __future__ import annotations

import numpy as np

LOBES = ("phong", "blinn_phong", "ggx")
MIN_ROUGHNESS = 1e-3
MIN_COS_VIEW = 1e-4


def _dot(a, b):
    return np.sum(np.asarray(a, np.float64) * np.asarray(b, np.float64), axis=-1)


def _pow(base, exponent):
    # 0^0 = 1: a shininess-0 lobe is constant (docs/brdf.md).
    base = np.maximum(base, 0.0)
    return np.where(exponent == 0, 1.0, np.power(base, exponent))


def lobe(n, v, l, lobe: str = "phong", shininess: float = 100.0, roughness: float = 0.3):
    """f_lobe(V, L) without k_s, zero where N.L <= 0; shape (...)."""
    n, v, l = (np.asarray(x, np.float64) for x in (n, v, l))
    nl = _dot(n, l)
    nv = _dot(n, v)
    if lobe == "phong":
        r = 2.0 * nv[..., None] * n - v
        f = (shininess + 2.0) / (2.0 * np.pi) * _pow(_dot(r, l), shininess)
    elif lobe == "blinn_phong":
        h = v + l
        hn = np.linalg.norm(h, axis=-1, keepdims=True)
        h = np.where(hn > 0, h / np.where(hn > 0, hn, 1.0), n)
        f = (shininess + 8.0) / (8.0 * np.pi) * _pow(_dot(n, h), shininess)
    elif lobe == "ggx":
        a2 = np.clip(roughness, MIN_ROUGHNESS, 1.0) ** 2
        h = v + l
        hn = np.linalg.norm(h, axis=-1, keepdims=True)
        h = np.where(hn > 0, h / np.where(hn > 0, hn, 1.0), n)
        nh = np.maximum(_dot(n, h), 0.0)
        d = a2 / (np.pi * (nh * nh * (a2 - 1.0) + 1.0) ** 2)
        cv = np.maximum(nv, MIN_COS_VIEW)
        cl = np.maximum(nl, 1e-30)

        def g1(c):
            return 2.0 * c / (c + np.sqrt(a2 + (1.0 - a2) * c * c))

        f = d * g1(cv) * g1(cl) / (4.0 * cl * cv)
    else:
        raise ValueError(f"unknown lobe '{lobe}' (one of {', '.join(LOBES)})")
    return np.where(nl > 0.0, f, 0.0)


def brdf(n, v, l, albedo, specular=0.0, lobe_name: str = "phong", shininess: float = 100.0,
         roughness: float = 0.3):
    """f(V, L) = albedo / pi + k_s f_lobe, zero where N.L <= 0; shape (..., 3)."""
    n, l = np.asarray(n, np.float64), np.asarray(l, np.float64)
    nl = _dot(n, l)
    diffuse = np.where(nl > 0.0, 1.0 / np.pi, 0.0)[..., None] * np.asarray(albedo, np.float64)
    if specular == 0.0:
        return diffuse
    return diffuse + specular * lobe(n, v, l, lobe_name, shininess, roughness)[..., None]
