"""The material model of docs/brdf.md in float64 numpy: the reference the
kernels (kernels/common/brdf.cl) and the Mitsuba plugin are tested against.

All direction arguments are arrays of unit vectors (..., 3) that broadcast
together; the result is f(V, L) per colour channel (..., 3).

The anisotropic ``ashikhmin_shirley`` lobe also takes ``tangent``, its u
direction (unit, in the tangent plane): ``tangent_from_angle`` turns a
G-buffer tangent angle into it, ``tangent_angle`` a direction into the angle."""

from __future__ import annotations

import numpy as np

LOBES = ("phong", "blinn_phong", "ggx", "ashikhmin_shirley")
MIN_ROUGHNESS = 1e-3
MIN_COS_VIEW = 1e-4


def _dot(a, b):
    return np.sum(np.asarray(a, np.float64) * np.asarray(b, np.float64), axis=-1)


def _pow(base, exponent):
    # 0^0 = 1: a shininess-0 lobe is constant (docs/brdf.md).
    base = np.maximum(base, 0.0)
    return np.where(exponent == 0, 1.0, np.power(base, exponent))


def frame(n):
    """Unit t, b completing unit normals n (..., 3) to an orthonormal frame: the
    branch-free frame of Duff et al. (2017) that kernels/common/math.cl (pn_frame) uses."""
    n = np.asarray(n, np.float64)
    x, y, z = n[..., 0], n[..., 1], n[..., 2]
    s = np.where(z >= 0.0, 1.0, -1.0)
    a = -1.0 / (s + z)
    c = x * y * a
    t = np.stack([1.0 + s * x * x * a, s * c, -s * x], axis=-1)
    b = np.stack([c, s + y * y * a, -y], axis=-1)
    return t, b


def tangent_angle(n, axis):
    """The G-buffer tangent angle (docs/brdf.md) of direction ``axis`` at normals n:
    its angle from t towards b, (t, b) = frame(n); 0 where axis is along n."""
    t, b = frame(n)
    x, y = _dot(axis, t), _dot(axis, b)
    return np.where((x == 0.0) & (y == 0.0), 0.0, np.arctan2(y, x))


def tangent_from_angle(n, angle):
    """The unit u direction cos(angle) t + sin(angle) b, (t, b) = frame(n)."""
    t, b = frame(n)
    angle = np.asarray(angle, np.float64)[..., None]
    return np.cos(angle) * t + np.sin(angle) * b


def _half(n, v, l):
    h = v + l
    hn = np.linalg.norm(h, axis=-1, keepdims=True)
    return np.where(hn > 0, h / np.where(hn > 0, hn, 1.0), n)


def ashikhmin_shirley(n, v, l, tangent, n_u: float, n_v: float):
    """The Ashikhmin-Shirley (2000) specular lobe without Fresnel (k_s is the
    constant reflectance): sqrt((n_u+1)(n_v+1))/(8 pi) (N.H)^e / ((H.L) max(N.L, N.V)),
    e = (n_u (H.u)^2 + n_v (H.w)^2) / (1 - (N.H)^2), u = tangent, w = n x u;
    H.L and N.V at least MIN_COS_VIEW. Not masked by N.L (lobe() does that)."""
    n, v, l, u = (np.asarray(x, np.float64) for x in (n, v, l, tangent))
    h = _half(n, v, l)
    nh = np.maximum(_dot(n, h), 0.0)
    w = np.cross(n, u)
    hu, hw = _dot(h, u), _dot(h, w)
    den = hu * hu + hw * hw
    e = np.where(den > 0.0, (n_u * hu * hu + n_v * hw * hw) / np.where(den > 0.0, den, 1.0), n_u)
    hl = np.maximum(_dot(h, l), MIN_COS_VIEW)
    cv = np.maximum(_dot(n, v), MIN_COS_VIEW)
    cl = _dot(n, l)
    return np.sqrt((n_u + 1.0) * (n_v + 1.0)) / (8.0 * np.pi) * _pow(nh, e) / (hl * np.maximum(cl, cv))


def lobe(n, v, l, lobe: str = "phong", shininess: float = 100.0, roughness: float = 0.3,
         shininess_v: float = 100.0, tangent=None):
    """f_lobe(V, L) without k_s, zero where N.L <= 0; shape (...). ``shininess_v``
    and ``tangent`` (unit u directions) are the ashikhmin_shirley lobe's."""
    n, v, l = (np.asarray(x, np.float64) for x in (n, v, l))
    nl = _dot(n, l)
    nv = _dot(n, v)
    if lobe == "phong":
        r = 2.0 * nv[..., None] * n - v
        f = (shininess + 2.0) / (2.0 * np.pi) * _pow(_dot(r, l), shininess)
    elif lobe == "blinn_phong":
        h = _half(n, v, l)
        f = (shininess + 8.0) / (8.0 * np.pi) * _pow(_dot(n, h), shininess)
    elif lobe == "ggx":
        a2 = np.clip(roughness, MIN_ROUGHNESS, 1.0) ** 2
        h = _half(n, v, l)
        nh = np.maximum(_dot(n, h), 0.0)
        d = a2 / (np.pi * (nh * nh * (a2 - 1.0) + 1.0) ** 2)
        cv = np.maximum(nv, MIN_COS_VIEW)
        cl = np.maximum(nl, 1e-30)

        def g1(c):
            return 2.0 * c / (c + np.sqrt(a2 + (1.0 - a2) * c * c))

        f = d * g1(cv) * g1(cl) / (4.0 * cl * cv)
    elif lobe == "ashikhmin_shirley":
        if tangent is None:
            raise ValueError("the ashikhmin_shirley lobe needs a tangent")
        f = ashikhmin_shirley(n, v, l, tangent, shininess, shininess_v)
    else:
        raise ValueError(f"unknown lobe '{lobe}' (one of {', '.join(LOBES)})")
    return np.where(nl > 0.0, f, 0.0)


def lobe_args(n, material) -> dict:
    """The keyword arguments of lobe() for one G-buffer MATERIAL value (docs/gbuffer.md)
    at unit normal n: (n, alpha, lobe, 0), or (n_u, n_v, 3, tangent angle)."""
    x, y, z, w = (float(c) for c in material)
    name = LOBES[int(z)]
    if name == "ashikhmin_shirley":
        return dict(lobe=name, shininess=x, roughness=1.0, shininess_v=y, tangent=tangent_from_angle(n, w))
    return dict(lobe=name, shininess=x, roughness=float(np.clip(y, MIN_ROUGHNESS, 1.0)))


def brdf(n, v, l, albedo, specular=0.0, lobe_name: str = "phong", shininess: float = 100.0,
         roughness: float = 0.3, shininess_v: float = 100.0, tangent=None):
    """f(V, L) = albedo / pi + k_s f_lobe, zero where N.L <= 0; shape (..., 3)."""
    n, l = np.asarray(n, np.float64), np.asarray(l, np.float64)
    nl = _dot(n, l)
    diffuse = np.where(nl > 0.0, 1.0 / np.pi, 0.0)[..., None] * np.asarray(albedo, np.float64)
    if specular == 0.0:
        return diffuse
    return diffuse + specular * lobe(n, v, l, lobe_name, shininess, roughness, shininess_v, tangent)[..., None]
