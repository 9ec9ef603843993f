"""float64 twin of the Blinn-Phong and GGX cap-average tables of the
`depthmap` method (capi/src/methods/depthmap_table.c, pn_depthmap_lobe_table_fill;
kernels/depthmap.cl, dm_lobe_ratio; docs/depthmap.md, "Blinn-Phong and GGX: a
table with the view angle").

Around the reflection direction R, the tangent offset (x, y) of a direction
L (x in the plane of N and R, y across it) puts the half vector at
theta_h = |(x, y / c)| / 2 from N, c = N.V. Both lobes are then functions of
u = |(x, y / c)| / s: Blinn-Phong exp(-u^2 / 2) with s = 2 / sqrt(n) (family
0), GGX (1 + u^2)^-2 with s = 2 alpha (family 1). ``log_ratio`` is the
table's entry: log of the average of that lobe over a disk of radius rho
(units of s) over its value at the disk's point nearest R, computed here by
adaptive quadrature over x of the chord integrals (closed forms in y),
independently of the C code's fixed panels."""
from __future__ import annotations

import math

import numpy as np
from scipy import integrate, special

BLINN_PHONG, GGX = 0, 1
C_MIN = 0.01  # PN_DM_LOBE_C_MIN: the smallest N.V tabulated
LOBE_CULL = 1e-3  # DM_LOBE_CULL
# dm_lobe_average skips caps this many lobe widths s from R: the profile there is LOBE_CULL of its peak
CULL_U = (3.717, 5.535)  # DM_LOBE_CULL_U_*: sqrt(-2 log LOBE_CULL), sqrt(LOBE_CULL^-1/2 - 1), rounded up


def log_lobe(family: int, u: float) -> float:
    return -0.5 * u * u if family == BLINN_PHONG else -2.0 * math.log1p(u * u)


def _log_phi_diff(a: float, b: float) -> float:
    """log(Phi(b) - Phi(a)), a < b, Phi the standard normal CDF."""
    if a > 0:  # both in the upper tail: Phi(-a) - Phi(-b)
        a, b = -b, -a
    lb, la = special.log_ndtr(b), special.log_ndtr(a)
    return lb + math.log(-math.expm1(la - lb))


def _ggx_chord(z1: float, z2: float, a: float) -> float:
    """int_{z1}^{z2} dz / (a^2 + z^2)^2 by quadrature in the angle z = a tan(t)."""
    t1, t2 = math.atan2(z1, a), math.atan2(z2, a)
    val, _ = integrate.quad(lambda t: math.cos(t) ** 2, t1, t2, epsabs=0.0, epsrel=1e-12)
    return val / a ** 3


def log_chord(family: int, x: float, y1: float, y2: float, c: float) -> float:
    """log of the lobe integrated over y in [y1, y2] at x (unit scale s)."""
    if not y2 > y1:
        return -math.inf
    if family == BLINN_PHONG:  # exp(-x^2/2) int exp(-y^2 / (2 c^2)) dy
        return -0.5 * x * x + math.log(c * math.sqrt(2.0 * math.pi)) + _log_phi_diff(y1 / c, y2 / c)
    a = math.sqrt(1.0 + x * x)  # (a^2 + (y/c)^2)^-2, dy = c dz
    return math.log(c * _ggx_chord(y1 / c, y2 / c, a))


def disk_offset(rho: float, c: float, delta_u: float, phi_s: float):
    """(x0, y0, gamma): the disk's centre from R and the lobe-metric length of
    the offset's unit direction, for the table's coordinates."""
    ux, uy = math.cos(phi_s), c * math.sin(phi_s)
    un = math.hypot(ux, uy)
    cx, cy = ux / un, uy / un
    gamma = math.hypot(cx, cy / c)
    dist = max(rho + delta_u / gamma, 0.0)
    return dist * cx, dist * cy, gamma


def least_u2(x0: float, y0: float, rho: float, c: float) -> float:
    """The least x^2 + (y / c)^2 over the circle of radius rho around (x0, y0) (scipy, bounded)."""
    from scipy import optimize

    f = lambda t: (x0 + rho * math.cos(t)) ** 2 + ((y0 + rho * math.sin(t)) / c) ** 2  # noqa: E731
    best = min(optimize.minimize_scalar(f, bounds=(a, a + 0.5 * math.pi), method="bounded",
                                        options=dict(xatol=1e-12)).fun for a in (0.0, 0.5 * math.pi, math.pi, 1.5 * math.pi))
    return best


def log_ratio(family: int, rho: float, c: float, delta_u: float, phi_s: float) -> float:
    """log G: the lobe's average over the disk over its value at the disk's point of least u."""
    if rho <= 0:
        return 0.0
    x0, y0, _ = disk_offset(rho, c, delta_u, phi_s)
    ref = log_lobe(family, math.sqrt(least_u2(x0, y0, rho, c))) if math.hypot(x0, y0) > rho else 0.0
    lo, hi = x0 - rho, x0 + rho
    if family == BLINN_PHONG:
        xm = min(max(0.0, lo), hi)
        lim = math.sqrt(120.0 + xm * xm)
        lo, hi = max(lo, -lim), min(hi, lim)

    def lv(x):
        h = math.sqrt(max(rho * rho - (x - x0) ** 2, 0.0))
        return log_chord(family, x, y0 - h, y0 + h, c) - ref

    pts = [min(max(0.0, lo), hi), x0]
    if abs(y0) < rho:
        hx = math.sqrt(rho * rho - y0 * y0)
        pts += [x0 - hx, x0 + hx]
    pts = sorted(p for p in set(pts) if lo < p < hi)
    probe = np.linspace(lo, hi, 401)[1:-1]
    best = max(lv(float(x)) for x in list(probe) + pts)
    edges = [lo] + pts + [hi]
    total = 0.0
    for a, b in zip(edges[:-1], edges[1:]):
        if b <= a:
            continue
        val, _ = integrate.quad(lambda x: math.exp(lv(x) - best), a, b, epsabs=0.0, epsrel=1e-9, limit=400)
        total += val
    return best + math.log(total) - math.log(math.pi * rho * rho)


def lobe_family_scale(lobe: str, shininess: float, roughness: float):
    """(family, s) of dm_lobe_ratio; roughness clamped as in the kernels."""
    if lobe == "blinn_phong":
        return BLINN_PHONG, 2.0 / math.sqrt(shininess)
    return GGX, 2.0 * min(max(roughness, 1e-3), 1.0)


def frame(n, v, refl, d, r: float, s: float):
    """dm_lobe_average's geometry of a cap (d, r) for the lobe at (n, v):
    (rho, c, delta_u, phi_s, l) with c clamped to [C_MIN, 1] and l the cap's
    point of least u (R when R is inside the cap)."""
    c = min(max(float(n @ v), C_MIN), 1.0)
    cd = float(refl @ d)
    psi_c = math.atan2(float(np.linalg.norm(refl - cd * d)), cd)
    ey = np.cross(n, refl)
    ly = float(np.linalg.norm(ey))
    if ly > 1e-6:
        ey = ey / ly
        ex = np.cross(ey, refl)
    else:  # N along R: a round lobe, any tangent frame
        ex = np.cross(refl, [0.0, 1.0, 0.0] if abs(refl[1]) < 0.9 else [1.0, 0.0, 0.0])
        ex /= np.linalg.norm(ex)
        ey = np.cross(refl, ex)
    bx, by = float(d @ ex), float(d @ ey)  # d's tangent components at R
    bl = math.hypot(bx, by)
    ax, ay = (abs(bx) / bl, abs(by) / bl) if bl > 0 else (1.0, 0.0)
    gamma = math.hypot(ax, ay / c)
    rho = r / s
    l = refl
    if psi_c > r:
        from scipy import optimize

        x0, y0 = psi_c / s * ax, psi_c / s * ay
        res = optimize.minimize_scalar(lambda t: (x0 + rho * math.cos(t)) ** 2 + ((y0 + rho * math.sin(t)) / c) ** 2,
                                       bounds=(math.pi, 1.5 * math.pi), method="bounded", options=dict(xatol=1e-12))
        px, py = (x0 + rho * math.cos(res.x)) * s, (y0 + rho * math.sin(res.x)) * s
        t = math.copysign(px, bx) * ex + math.copysign(py, by) * ey
        tl = float(np.linalg.norm(t))
        if tl > 0:
            l = math.cos(tl) * refl + math.sin(tl) * t / tl
    return rho, c, (psi_c - r) / s * gamma, math.atan2(ay, c * ax), l


def coordinates(n, v, refl, d, r: float, s: float):
    """(rho, c, delta_u, phi_s): the table's coordinates of the cap (frame)."""
    return frame(n, v, refl, d, r, s)[:4]


def cap_factor(r: float) -> float:
    """pi r^2 over the cap's solid angle 2 pi (1 - cos r): the flat disk's area to the cap's."""
    h = 0.5 * r
    return 1.0 if h == 0 else (h / math.sin(h)) ** 2


def average(n, v, d, r: float, lobe: str, shininess: float, roughness: float, f) -> float:
    """The float64 value of dm_lobe_average: f(l*) (n.l*) G cap_factor(r), with G
    by this module's quadrature instead of the table; f the lobe at (n, v)."""
    family, s = lobe_family_scale(lobe, shininess, roughness)
    refl = 2.0 * (n @ v) * n - v
    cd = float(refl @ d)
    if math.atan2(float(np.linalg.norm(refl - cd * d)), cd) - r > CULL_U[family] * s:
        return 0.0  # the kernel's cull: u is at least the plain distance over s
    rho, c, delta_u, phi_s, l = frame(n, v, refl, d, r, s)
    nl = float(n @ l)
    if not nl > 0:
        return 0.0
    fl = f(l) * nl
    if not fl > 0:
        return 0.0
    return fl * math.exp(min(log_ratio(family, rho, c, delta_u, phi_s), 0.0)) * cap_factor(r)
