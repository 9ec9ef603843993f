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
independently of the C code's fixed panels; ``moments`` the entry's other
four values (the lobe-weighted centroid and spreads), and ``average`` the
kernel's rule: the rest of the integrand by four points in the half vector."""
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


def least_point(x0: float, y0: float, rho: float, c: float) -> tuple[float, float]:
    """The point (x, y) of the circle of radius rho around (x0, y0) where x^2 + (y / c)^2 is least
    (scipy, bounded, on each quarter of the circle)."""
    from scipy import optimize

    f = lambda t: (x0 + rho * math.cos(t)) ** 2 + ((y0 + rho * math.sin(t)) / c) ** 2  # noqa: E731
    best = min((optimize.minimize_scalar(f, bounds=(a, a + 0.5 * math.pi), method="bounded", options=dict(xatol=1e-12))
                for a in (0.0, 0.5 * math.pi, math.pi, 1.5 * math.pi)), key=lambda res: res.fun)
    return x0 + rho * math.cos(best.x), y0 + rho * math.sin(best.x)


def least_u2(x0: float, y0: float, rho: float, c: float) -> float:
    """The least x^2 + (y / c)^2 over the circle of radius rho around (x0, y0)."""
    px, py = least_point(x0, y0, rho, c)
    return px * px + (py / c) ** 2


def x_range(family: int, rho: float, x0: float) -> tuple[float, float]:
    """The disk's x extent, for Blinn-Phong cut where the profile is below e^-60 of its value at the
    disk's nearest x (the quadratures' range)."""
    lo, hi = x0 - rho, x0 + rho
    if family == BLINN_PHONG:
        xm = min(max(0.0, lo), hi)
        lim = math.sqrt(120.0 + xm * xm)
        lo, hi = max(lo, -lim), min(hi, lim)
    return lo, hi


def log_ratio(family: int, rho: float, c: float, delta_u: float, phi_s: float) -> float:
    """log G: the lobe's average over the disk over its value at the disk's point of least u."""
    if rho <= 0:
        return 0.0
    x0, y0, _ = disk_offset(rho, c, delta_u, phi_s)
    ref = log_lobe(family, math.sqrt(least_u2(x0, y0, rho, c))) if math.hypot(x0, y0) > rho else 0.0
    lo, hi = x_range(family, rho, x0)

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


def _chord_moments(family: int, x: float, y1: float, y2: float, c: float):
    """(mean, mean square) of z = y / c over the chord x, y in [y1, y2] under the lobe: the standard
    normal truncated to [z1, z2] (scipy.stats.truncnorm) for Blinn-Phong; for GGX, (a^2 + z^2)^-2
    with z = a tan(t): int z^m (a^2 + z^2)^-2 dz = a^(m - 3) int tan^m(t) cos^2(t) dt in closed form."""
    z1, z2 = y1 / c, y2 / c
    if not z2 > z1:
        return 0.5 * (z1 + z2), (0.5 * (z1 + z2)) ** 2
    if family == BLINN_PHONG:  # P = Phi(z2) - Phi(z1); mean (phi(z1) - phi(z2)) / P; square 1 + (z1 phi(z1) - z2 phi(z2)) / P
        sign = 1.0
        if z2 <= 0.0:
            z1, z2, sign = -z2, -z1, -1.0
        lp = _log_phi_diff(z1, z2)
        r1 = math.exp(-0.5 * z1 * z1 - 0.5 * math.log(2 * math.pi) - lp)
        r2 = math.exp(-0.5 * z2 * z2 - 0.5 * math.log(2 * math.pi) - lp)
        return sign * (r1 - r2), 1.0 + z1 * r1 - z2 * r2
    a = math.sqrt(1.0 + x * x)
    t1, t2 = math.atan2(z1, a), math.atan2(z2, a)
    k0 = (t2 - t1) / 2 + (math.sin(2 * t2) - math.sin(2 * t1)) / 4
    k1 = (math.sin(t2) ** 2 - math.sin(t1) ** 2) / 2
    k2 = (t2 - t1) / 2 - (math.sin(2 * t2) - math.sin(2 * t1)) / 4
    return a * k1 / k0, a * a * max(k2, 0.0) / k0


def moments(family: int, rho: float, c: float, delta_u: float, phi_s: float):
    """(mx, my, sx, sy): the lobe-weighted centroid of the disk in the round metric (x, y / c) from R and
    the spreads of x and y / c (the table's entries after log G), by adaptive quadrature over x."""
    if rho <= 0:
        return 0.0, 0.0, 0.0, 0.0
    x0, y0, _ = disk_offset(rho, c, delta_u, phi_s)
    lo, hi = x_range(family, rho, x0)

    def half(x):
        return math.sqrt(max(rho * rho - (x - x0) ** 2, 0.0))

    def lv(x):
        h = half(x)
        return log_chord(family, x, y0 - h, y0 + h, c)

    probe = np.linspace(lo, hi, 401)[1:-1]
    best = max(lv(float(x)) for x in probe)
    pts = [min(max(0.0, lo), hi), x0]
    if abs(y0) < rho:
        hx = math.sqrt(rho * rho - y0 * y0)
        pts += [x0 - hx, x0 + hx]
    edges = [lo] + sorted(p for p in set(pts) if lo < p < hi) + [hi]
    def fn(x):
        w = math.exp(lv(x) - best)
        h = half(x)
        mz, mzz = _chord_moments(family, x, y0 - h, y0 + h, c)
        return np.array([w, w * x, w * x * x, w * mz, w * mzz])

    tot = np.zeros(5)
    for a, b in zip(edges[:-1], edges[1:]):
        if b > a:
            tot += integrate.quad_vec(fn, a, b, epsabs=0.0, epsrel=1e-7)[0]
    if not tot[0] > 0:
        return x0, y0 / c, 0.0, 0.0
    mx, mxx, my, myy = tot[1] / tot[0], tot[2] / tot[0], tot[3] / tot[0], tot[4] / tot[0]
    return mx, my, math.sqrt(max(mxx - mx * mx, 0.0)), math.sqrt(max(myy - my * my, 0.0))


def lobe_family_scale(lobe: str, shininess: float, roughness: float):
    """(family, s) of dm_lobe_ratio; roughness clamped as in the kernels."""
    if lobe == "blinn_phong":
        return BLINN_PHONG, 2.0 / math.sqrt(shininess)
    return GGX, 2.0 * min(max(roughness, 1e-3), 1.0)


def frame(n, v, refl, d, r: float, s: float):
    """dm_lobe_average's geometry of a cap (d, r) for the lobe at (n, v): (rho, c,
    delta_u, phi_s, log_ref, signs, (ex, ey)) with c clamped to [C_MIN, 1], log_ref the
    log of the profile at the disk's point of least u (0 when R is inside the cap),
    signs those of d's tangent components at R along ex (in the plane of N and R) and ey."""
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
    u2_ref = None
    if psi_c > r:
        x0, y0 = psi_c / s * ax, psi_c / s * ay
        u2_ref = least_u2(x0, y0, rho, c)
    signs = (-1.0 if bx < 0 else 1.0, -1.0 if by < 0 else 1.0)
    return rho, c, (psi_c - r) / s * gamma, math.atan2(ay, c * ax), u2_ref, signs, (ex, ey)


def coordinates(n, v, refl, d, r: float, s: float):
    """(rho, c, delta_u, phi_s): the table's coordinates of the cap (frame)."""
    return frame(n, v, refl, d, r, s)[:4]


def cap_factor(r: float) -> float:
    """pi r^2 over the cap's solid angle 2 pi (1 - cos r): the flat disk's area to the cap's."""
    h = 0.5 * r
    return 1.0 if h == 0 else (h / math.sin(h)) ** 2


J_MAX = 4.0  # DM_LOBE_J_MAX: the largest V.H / c taken
TILT_MAX = 0.35  # DM_LOBE_TILT_MAX: the largest tilt of H from N (rad) at which K is evaluated


def average_one_point(n, v, d, r: float, lobe: str, shininess: float, roughness: float, f) -> float:
    """The float64 value of dm_lobe_average at lobe_centroid 0 (the default): f(l*) (n.l*) G cap_factor(r),
    l* the cap's point of least u (R when R is inside), G by this module's quadrature instead of the table."""
    family, s = lobe_family_scale(lobe, shininess, roughness)
    refl = 2.0 * (n @ v) * n - v
    cd = float(refl @ d)
    psi_c = math.atan2(float(np.linalg.norm(refl - cd * d)), cd)
    if psi_c - r > CULL_U[family] * s:
        return 0.0  # the kernel's cull: u is at least the plain distance over s
    rho, c, delta_u, phi_s, _, (sgx, sgy), (ex, ey) = frame(n, v, refl, d, r, s)
    l = refl
    if psi_c > r:
        bx, by = float(d @ ex), float(d @ ey)
        bl = math.hypot(bx, by)
        ax, ay = (abs(bx) / bl, abs(by) / bl) if bl > 0 else (1.0, 0.0)
        px, py = least_point(psi_c / s * ax, psi_c / s * ay, rho, c)
        t = sgx * abs(px) * s * ex + sgy * abs(py) * s * ey
        tl = float(np.linalg.norm(t))
        if tl > 0:
            l = math.cos(tl) * refl + math.sin(tl) * t / tl
    nl = float(n @ l)
    if not nl > 0:
        return 0.0
    fl = f(l) * nl
    if not fl > 0:
        return 0.0
    return fl * math.exp(min(log_ratio(family, rho, c, delta_u, phi_s), 0.0)) * cap_factor(r)


def average(n, v, d, r: float, lobe: str, shininess: float, roughness: float, f) -> float:
    """The float64 value of dm_lobe_average at lobe_centroid 1, with the table's entries (log G, the centroid and
    spreads) by this module's quadrature instead of the table; f the lobe at (n, v).

    a = G Lambda(u*) pi r^2 / Omega * mean over four points P of K(P),
    K(P) = f(L) (n.L) min(V.H / c, J_MAX) / Lambda(|P|): H is N turned by s P / 2 (x in the
    plane of incidence, y across it), L = 2 (V.H) H - V; the points are the centroid +- the spreads
    (x's normal approximation truncated at the horizon x_h = c / (s sin theta_v), its mass p
    multiplying), each pulled in to a tilt of at most TILT_MAX."""
    family, s = lobe_family_scale(lobe, shininess, roughness)
    refl = 2.0 * (n @ v) * n - v
    cd = float(refl @ d)
    if math.atan2(float(np.linalg.norm(refl - cd * d)), cd) - r > CULL_U[family] * s:
        return 0.0  # the kernel's cull: u is at least the plain distance over s
    rho, c, delta_u, phi_s, u2_ref, (sgx, sgy), (ex, ey) = frame(n, v, refl, d, r, s)
    log_ref = 0.0 if u2_ref is None else log_lobe(family, math.sqrt(u2_ref))
    lg = min(log_ratio(family, rho, c, delta_u, phi_s), 0.0)
    mx, my, sx, sy = moments(family, rho, c, delta_u, phi_s)
    mx, my = sgx * mx, sgy * abs(my)
    sin_v = math.sqrt(max(1.0 - c * c, 0.0))
    p_mass = 1.0
    if sx > 0 and sin_v > 0:
        z = (c / (s * sin_v) - mx) / sx
        if z < 6.0:
            if z < -9.0:
                return 0.0
            p_mass = float(special.ndtr(z))
            lam = math.exp(-0.5 * z * z) / math.sqrt(2 * math.pi) / p_mass
            mx -= sx * lam
            sx *= math.sqrt(max(1.0 - z * lam - lam * lam, 0.0))
    ey_unit = np.cross(n, refl)
    if np.linalg.norm(ey_unit) > 1e-6:
        ey_unit = ey_unit / np.linalg.norm(ey_unit)
    else:
        ey_unit = ey
    hx = np.cross(ey_unit, n)
    total = 0.0
    for qx, qy in ((mx - sx, my - sy), (mx + sx, my - sy), (mx - sx, my + sy), (mx + sx, my + sy)):
        ql = math.hypot(qx, qy)
        if 0.5 * s * ql > TILT_MAX:
            k = TILT_MAX / (0.5 * s * ql)
            qx, qy, ql = qx * k, qy * k, ql * k
        th = 0.5 * s * ql
        h = math.cos(th) * n + math.sin(th) * (qx * hx + qy * ey_unit) / ql if ql > 0 else n
        vh = float(v @ h)
        if not vh > 0:
            continue
        l = 2.0 * vh * h - v
        nl = float(n @ l)
        if not nl > 0:
            continue
        fl = f(l) * nl
        if fl > 0:
            total += fl * min(vh / c, J_MAX) * math.exp(min(log_ref - log_lobe(family, ql), 80.0))
    return 0.25 * p_mass * total * math.exp(lg) * cap_factor(r)
