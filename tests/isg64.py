"""float64 reference for the ISG technique (docs/isg.md): spherical Gaussians
(SGs), their integrals and products, SG x clamped cosine (the seed's single-SG
cosine and a closed form derived here), the exact normalised Integral
Spherical Gaussian over a lat-long rectangle by quadrature, the seed's
published sigmoid fit, and a table evaluation accurate to 0.005 everywhere.

Plain numpy (no scipy). No kernel uses it yet: it is the twin the kernels
will be written against.

Conventions (docs/isg.md section 1):
  G(v; xi, lam, mu) = mu exp(lam (v.xi - 1)), |xi| = 1, lam >= 0.
  ISG frame: lobe axis z; Omega(theta, phi) = (sin t cos p, cos t, sin t sin p),
  theta from +y in [0, pi], phi from +x towards +z in [0, 2 pi); the lobe
  axis sits at (pi/2, pi/2), phi in [0, pi] is the lobe's front hemisphere.
  S(theta, phi; lam) = int_0^theta int_0^phi exp(lam (sin t sin p - 1)) sin t dp dt,
  S_hat = S / H(lam), H = S(pi, pi) = (2 pi / lam)(1 - e^-lam) (front hemisphere).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

TWO_PI = 2.0 * math.pi
HALF_PI = 0.5 * math.pi

# --------------------------------------------------------------------------- stable scalar helpers


def one_minus_exp_over(x) -> np.ndarray:
    """(1 - e^-x) / x for x >= 0, by expm1 (no cancellation as x -> 0; 1 at x = 0)."""
    x = np.asarray(x, np.float64)
    safe = np.where(x > 0, x, 1.0)
    return np.where(x > 0, -np.expm1(-safe) / safe, 1.0)


def exp_moment(x) -> np.ndarray:
    """J(x) = int_0^1 e^(x u) u du: series for |x| < 1 (25 terms: converged in
    double), (e^x (x - 1) + 1) / x^2 beyond. Only called with x <= 0 here, so
    e^x never overflows."""
    x = np.asarray(x, np.float64)
    small = np.abs(x) < 1.0
    xs = np.where(small, x, 0.0)
    series = np.zeros_like(x)
    term = np.ones_like(x)  # x^k / k!
    for k in range(25):
        series = series + term / (k + 2)
        term = term * xs / (k + 1)
    xl = np.where(small, 1.0, x)
    closed = (np.exp(xl) * (xl - 1.0) + 1.0) / (xl * xl)
    return np.where(small, series, closed)


def bessel_i1e(x) -> np.ndarray:
    """e^-x I_1(x), x >= 0: the power series below 3.75 (exact in double), the
    Abramowitz & Stegun 9.8.4 polynomial in 3.75 / x above (relative error
    < 6e-7, measured): the form a float32 kernel can use."""
    x = np.asarray(x, np.float64)
    small = x < 3.75
    xs = np.where(small, x, 0.0)
    h = 0.5 * xs
    term = h.copy()  # (x/2)^(2k+1) / (k! (k+1)!)
    series = np.zeros_like(x)
    for k in range(30):
        series = series + term
        term = term * h * h / ((k + 1) * (k + 2))
    xl = np.where(small, 3.75, x)
    y = 3.75 / xl
    p = 0.02282967 + y * (-0.02895312 + y * (0.01787654 - y * 0.00420059))
    p = 0.39894228 + y * (-0.03988024 + y * (-0.00362018 + y * (0.00163801 + y * (-0.01031555 + y * p))))
    return np.where(small, series * np.exp(-xs), p / np.sqrt(xl))


def bessel_i0e(x) -> np.ndarray:
    """e^-x I_0(x), x >= 0, to double precision: numpy's Cephes i0 below 700,
    the asymptotic series (6 terms, relative error < 1e-15) above."""
    x = np.asarray(x, np.float64)
    small = x < 700.0
    xs = np.where(small, x, 0.0)
    xl = np.where(small, 700.0, x)
    s, term = np.ones_like(xl), np.ones_like(xl)
    for k in range(1, 7):
        term = term * (2 * k - 1) ** 2 / (8.0 * k * xl)
        s = s + term
    return np.where(small, np.i0(xs) * np.exp(-xs), s / np.sqrt(TWO_PI * xl))


# --------------------------------------------------------------------------- spherical Gaussians


def sg(v, axis, lam, mu=1.0) -> np.ndarray:
    """G(v; xi, lam, mu) = mu exp(lam (v.xi - 1)) for unit v (..., 3)."""
    v, axis = np.asarray(v, np.float64), np.asarray(axis, np.float64)
    return np.asarray(mu, np.float64) * np.exp(np.asarray(lam, np.float64) * (np.sum(v * axis, -1) - 1.0))


def sg_integral(lam, mu=1.0) -> np.ndarray:
    """int_S2 G = mu (2 pi / lam)(1 - e^-2lam) = 4 pi mu (1 - e^-2lam) / (2 lam), 4 pi mu at lam = 0."""
    return 4.0 * math.pi * np.asarray(mu, np.float64) * one_minus_exp_over(2.0 * np.asarray(lam, np.float64))


def sg_hemisphere_integral(lam, mu=1.0) -> np.ndarray:
    """H(lam) = int over the lobe's own hemisphere (v.xi >= 0) = mu (2 pi / lam)(1 - e^-lam):
    the ISG normaliser S(pi, pi)."""
    return TWO_PI * np.asarray(mu, np.float64) * one_minus_exp_over(np.asarray(lam, np.float64))


def sg_product(axis1, lam1, mu1, axis2, lam2, mu2):
    """G1 G2 = G(v; xi_m, lam_m, mu_m): (axis, lam, mu).

    lam1 (v.xi1 - 1) + lam2 (v.xi2 - 1) = v.(lam1 xi1 + lam2 xi2) - lam1 - lam2,
    so lam_m = |lam1 xi1 + lam2 xi2|, xi_m = (lam1 xi1 + lam2 xi2) / lam_m and
    mu_m = mu1 mu2 exp(lam_m - lam1 - lam2). Computed without cancellation:
      lam_m^2 = (lam1 - lam2)^2 + lam1 lam2 |xi1 + xi2|^2  (nearly opposite lobes),
      lam_m - lam1 - lam2 = -lam1 lam2 |xi1 - xi2|^2 / (lam1 + lam2 + lam_m) <= 0
    (nearly aligned lobes; never positive, so exp never overflows). Exactly
    opposite equal lobes give a constant: lam_m = 0, axis xi1."""
    a1, a2 = np.asarray(axis1, np.float64), np.asarray(axis2, np.float64)
    l1, l2 = np.asarray(lam1, np.float64), np.asarray(lam2, np.float64)
    plus = np.sum((a1 + a2) ** 2, -1)
    minus = np.sum((a1 - a2) ** 2, -1)
    lam_m = np.sqrt((l1 - l2) ** 2 + l1 * l2 * plus)
    denom = l1 + l2 + lam_m
    expo = np.where(denom > 0, -l1 * l2 * minus / np.where(denom > 0, denom, 1.0), 0.0)
    # v = lam1 xi1 + lam2 xi2 from the sum and difference of the axes (each exact to
    # rounding even when the lobes nearly cancel), normalised by its own length
    v = (0.5 * (l1 + l2))[..., None] * (a1 + a2) + (0.5 * (l1 - l2))[..., None] * (a1 - a2)
    norm = np.linalg.norm(v, axis=-1)
    safe = np.where(norm > 0, norm, 1.0)[..., None]
    axis = np.where((norm > 0)[..., None], v / safe, np.broadcast_to(a1, v.shape))
    return axis, lam_m, np.asarray(mu1, np.float64) * np.asarray(mu2, np.float64) * np.exp(expo)


def sg_inner_product(axis1, lam1, mu1, axis2, lam2, mu2) -> np.ndarray:
    """int_S2 G1 G2 = mu_m (2 pi / lam_m)(1 - e^-2 lam_m) with the product's parameters."""
    _, lam_m, mu_m = sg_product(axis1, lam1, mu1, axis2, lam2, mu2)
    return sg_integral(lam_m, mu_m)


# --------------------------------------------------------------------------- SG x clamped cosine
#
# E(t; lam) = int_S2 exp(lam (v.xi - 1)) max(v.n, 0) dv, t = xi.n (mu = 1).

# The seed's single-SG cosine (its eq. 5 loses the constants; they are those
# of [WRG*09]): max(v.n, 0) ~ G(v; n, 2.133, 1.170).
COSINE_SG_LAMBDA = 2.133
COSINE_SG_MU = 1.170


def sg_cosine_exact(t, lam, nodes: int = 24) -> np.ndarray:
    """E(t; lam) to ~1e-13 relative. In the frame of n (v.n = z), the azimuthal
    integral is exact: int_0^2pi exp(lam s cos b) db = 2 pi I_0(lam s),
    s = sqrt(1 - t^2) sqrt(1 - z^2), so
      E = 2 pi int_0^1 z exp(lam (t z + s - 1)) i0e(lam s) dz,
    with t z + s = cos(angle(z) - angle(t)) <= 1 (no overflow); the peak at
    z = t (width 1/sqrt(lam)) gets graded Gauss-Legendre panels."""
    t, lam = np.broadcast_arrays(np.asarray(t, np.float64), np.asarray(lam, np.float64))
    out = np.empty(t.shape)
    for idx in np.ndindex(t.shape):
        ti, li = float(t[idx]), float(lam[idx])
        b = graded_breaks(0.0, 1.0, min(max(ti, 0.0), 1.0), 1.0 / math.sqrt(max(li, 1e-300)))
        z, w = panel_rule(b, nodes)
        s = math.sqrt(max(0.0, 1.0 - ti * ti)) * np.sqrt(np.maximum(0.0, 1.0 - z * z))
        f = z * np.exp(li * (ti * z + s - 1.0)) * bessel_i0e(li * s)
        out[idx] = TWO_PI * np.dot(w, f)
    return out


def sg_cosine_seed(t, lam) -> np.ndarray:
    """(a) The seed: the inner product of the lobe with G(v; n, 2.133, 1.170)."""
    t, lam = np.broadcast_arrays(np.asarray(t, np.float64), np.asarray(lam, np.float64))
    n = np.array([0.0, 0.0, 1.0])
    xi = np.stack([np.sqrt(np.maximum(0.0, 1.0 - t * t)), np.zeros_like(t), t], -1)
    return sg_inner_product(xi, lam, 1.0, n, np.full_like(lam, COSINE_SG_LAMBDA), COSINE_SG_MU)


def sg_cosine_odd(t, lam) -> np.ndarray:
    """The odd part (E(t) - E(-t)) / 2 = (1/2) int G (v.n) dv = t C1(lam) / 2, exact:
    C1 = 2 pi e^-lam int_-1^1 e^(lam u) u du = 2 pi (e^-lam J(lam) - e^-lam J(-lam)), with
    e^-lam J(lam) = int_0^1 e^(-lam w)(1 - w) dw = (1 - e^-lam) / lam - J(-lam) (no overflow)."""
    lam = np.asarray(lam, np.float64)
    up = one_minus_exp_over(lam) - exp_moment(-lam)  # int_0^1 e^(-lam w)(1 - w) dw = e^-lam J(lam)
    down = np.exp(-lam) * exp_moment(-lam)  # e^-lam J(-lam)
    return 0.5 * np.asarray(t, np.float64) * TWO_PI * (up - down)


def sg_cosine_ends(lam):
    """Exact E(1), E(-1) and E(0):
      E(+-1) = 2 pi e^-lam int_0^1 e^(+-lam u) u du,
      E(0)   = 2 pi e^-lam I_1(lam) / lam  (lobe axis on the horizon)."""
    lam = np.asarray(lam, np.float64)
    e_up = TWO_PI * (one_minus_exp_over(lam) - exp_moment(-lam))
    e_down = TWO_PI * np.exp(-lam) * exp_moment(-lam)
    safe = np.where(lam > 0, lam, 1.0)
    e_zero = np.where(lam > 0, TWO_PI * bessel_i1e(safe) / safe, math.pi)
    return e_up, e_down, e_zero


# Width factor of the shape function in sg_cosine_closed (docs/isg.md 3.3):
# 1 is the large-lam (Gaussian) limit; 0.9 minimises the measured max
# error (relative to E(1)) over lam in [1e-3, 1e4]: 0.40 % (0.6 % at k = 1).
COSINE_SHAPE_K = 0.9


def sg_cosine_closed(t, lam, k_factor: float = COSINE_SHAPE_K) -> np.ndarray:
    """(b) Closed form derived in docs/isg.md 3.3: E = t C1 / 2 + O(t) with the
    odd part exact and the even part O(t) = (E(t) + E(-t)) / 2 interpolated
    between its exact values O(0) = E(0) and O(1) = (E(1) + E(-1)) / 2 by the
    even shape of the large-lam limit,
      q(t) = t erf(k t) + (exp(-k^2 t^2) - 1) / (k sqrt(pi)),  k = k_factor sqrt(lam / 2),
      O(t) = O(0) + (O(1) - O(0)) q(t) / q(1), clamped at 0."""
    t = np.asarray(t, np.float64)
    lam = np.asarray(lam, np.float64)
    e_up, e_down, e_zero = sg_cosine_ends(lam)
    o1 = 0.5 * (e_up + e_down)
    k = k_factor * np.sqrt(np.maximum(lam, 1e-300) / 2.0)
    erf = np.vectorize(math.erf, otypes=[np.float64])

    def q(x):
        kx = k * x
        # (exp(-k^2 x^2) - 1) / (k sqrt(pi)) = x * expm1(-kx^2)/(kx sqrt(pi)); series-free at small kx
        safe = np.where(kx > 0, kx, 1.0)
        tail = np.where(kx > 0, x * np.expm1(-kx * kx) / (safe * math.sqrt(math.pi)), 0.0)
        return x * erf(kx) + tail

    ta = np.abs(t)
    shape = q(ta) / q(np.ones_like(ta))
    # E >= 0; the interpolation can dip a hair below 0 (1e-4 of E(1)) for a sharp lobe
    # far below the horizon, where E is ~0
    return np.maximum(sg_cosine_odd(t, lam) + e_zero + (o1 - e_zero) * shape, 0.0)


# --------------------------------------------------------------------------- quadrature helpers


def graded_breaks(lo: float, hi: float, centre: float, width: float, extra=()) -> np.ndarray:
    """Panel breakpoints on [lo, hi]: 8 uniform panels, points centre +- width 2^k
    (k = -3..11) that resolve a peak of that width, and any extra points."""
    g = centre + width * np.concatenate([[0.0], 2.0 ** np.arange(-3, 12)])
    g = np.concatenate([g, 2 * centre - g])
    pts = np.concatenate([[lo, hi], np.linspace(lo, hi, 9), g[(g > lo) & (g < hi)], np.asarray(extra, np.float64)])
    return np.unique(np.clip(pts, lo, hi))


def panel_rule(breaks: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Composite n-point Gauss-Legendre nodes and weights over the panels."""
    x, w = np.polynomial.legendre.leggauss(n)
    h = 0.5 * np.diff(breaks)
    m = 0.5 * (breaks[1:] + breaks[:-1])
    return (m[:, None] + h[:, None] * x).ravel(), (h[:, None] * w).ravel()


# --------------------------------------------------------------------------- the ISG


def isg_direction(theta, phi) -> np.ndarray:
    """Omega(theta, phi) = (sin t cos p, cos t, sin t sin p); the lobe axis z is (pi/2, pi/2)."""
    theta, phi = np.broadcast_arrays(np.asarray(theta, np.float64), np.asarray(phi, np.float64))
    st = np.sin(theta)
    return np.stack([st * np.cos(phi), np.cos(theta), st * np.sin(phi)], -1)


def isg_exact_grid(lam: float, thetas, phis, nodes: int = 12) -> np.ndarray:
    """S_hat(theta_i, phi_j; lam) on the tensor grid (thetas in [0, pi], phis in
    [0, 2 pi]): composite Gauss-Legendre with the grid values as breakpoints
    (2-D cumulative sums of panel integrals) and panels graded on the lobe's
    width 1/sqrt(lam) around pi/2 in both angles. Converged to ~1e-15 at
    nodes = 12 (the test compares with nodes = 20)."""
    lam = float(lam)
    thetas, phis = np.asarray(thetas, np.float64), np.asarray(phis, np.float64)
    w = 1.0 / math.sqrt(lam)
    bt = graded_breaks(0.0, math.pi, HALF_PI, w, thetas.ravel())
    bp = graded_breaks(0.0, TWO_PI, HALF_PI, w, phis.ravel())
    t, wt = panel_rule(bt, nodes)
    p, wp = panel_rule(bp, nodes)
    f = np.exp(lam * (np.outer(np.sin(t), np.sin(p)) - 1.0)) * (np.sin(t) * wt)[:, None] * wp[None, :]
    panels = f.reshape(len(bt) - 1, nodes, len(bp) - 1, nodes).sum(axis=(1, 3))
    cum = np.zeros((len(bt), len(bp)))
    cum[1:, 1:] = panels.cumsum(0).cumsum(1)
    it = np.searchsorted(bt, np.clip(thetas, 0.0, math.pi))
    ip = np.searchsorted(bp, np.clip(phis, 0.0, TWO_PI))
    return cum[np.ix_(it.ravel(), ip.ravel())].reshape(thetas.shape + phis.shape) / float(sg_hemisphere_integral(lam))


def isg_exact(theta, phi, lam) -> float:
    """S_hat at one (theta, phi, lam)."""
    return float(isg_exact_grid(lam, np.array([theta]), np.array([phi]))[0, 0])


def patch_integral(s_hat, theta0, theta1, phi0, phi1, lam) -> np.ndarray:
    """int over the patch [theta0, theta1] x [phi0, phi1] of G(.; z, lam, 1) = H(lam) times the
    four-corner difference of s_hat(theta, phi, lam) (the seed's eq. after (14), with the
    corner signs S(1,1) - S(0,1) - S(1,0) + S(0,0))."""
    d = s_hat(theta1, phi1, lam) - s_hat(theta0, phi1, lam) - s_hat(theta1, phi0, lam) + s_hat(theta0, phi0, lam)
    return sg_hemisphere_integral(lam) * d


# The seed's appendix: g, h = quartic polynomials in lam / 100.
SEED_G = (-2.6856e-6, 7e-4, -0.0571, 3.9529, 17.6028)  # (g4, g3, g2, g1, g0)
SEED_H = (-2.6875e-6, 7e-4, -0.0592, 3.9900, 17.5003)


def seed_poly(coeffs, lam) -> np.ndarray:
    x = np.asarray(lam, np.float64) / 100.0
    out = np.zeros_like(x)
    for c in coeffs:
        out = out * x + c
    return out


def isg_seed_fit(theta, phi, lam) -> np.ndarray:
    """The seed's eq. 14 as it must read: f = sigma(g(lam)(theta - pi/2)) sigma(h(lam)(phi - pi/2)),
    sigma(x) = 1 / (1 + e^-x). Defined by the seed on (theta, phi) in [0, pi]^2."""
    theta, phi, lam = (np.asarray(a, np.float64) for a in (theta, phi, lam))

    def sigma(x):
        return 0.5 * (1.0 + np.tanh(0.5 * x))  # = 1 / (1 + e^-x), no overflow

    return sigma(seed_poly(SEED_G, lam) * (theta - HALF_PI)) * sigma(seed_poly(SEED_H, lam) * (phi - HALF_PI))


# --------------------------------------------------------------------------- the accurate evaluation
#
# S_hat(theta, phi) ~ A(theta) B(phi)                                   phi in [0, pi]
# S_hat(theta, phi) ~ A(theta) + e^-lam Ab(theta) Bb(phi - pi)          phi in (pi, 2 pi]
# with the exact marginals A(theta) = S_hat(theta, pi), B(phi) = S_hat(pi, phi) of the front
# hemisphere and Ab, Bb those of the back hemisphere normalised to 1 (its weight relative to
# the front is exactly e^-lam). All four are CDFs on [0, pi], odd about pi/2
# (F(pi - x) = 1 - F(x)), so each is tabulated as T(rho; lam) = F(pi/2 + x) - 1/2 for
# x in [0, pi/2] at uniform rho, linear in rho and in log(lam):
#   front: rho = erf(k x) / erf(k pi/2), k = sqrt(lam / 2) (T -> rho / 2 as lam -> inf);
#   back:  rho = x / (pi/2) (the back only matters for lam <= BACK_LAMBDA_MAX).

TABLE_LAMBDA_MIN, TABLE_LAMBDA_MAX = 1e-3, 1e4
TABLE_LAMBDAS_PER_DECADE = 8
TABLE_RHO_NODES = 33
BACK_LAMBDA_MAX = 40.0  # e^-40 ~ 4e-18: the back hemisphere is nothing beyond


def _erf(x) -> np.ndarray:
    return np.vectorize(math.erf, otypes=[np.float64])(x)


def front_rho(x, lam) -> np.ndarray:
    k = np.sqrt(np.asarray(lam, np.float64) / 2.0)
    return _erf(k * x) / _erf(k * HALF_PI)


def _front_x(rho, lam: float) -> np.ndarray:
    """Inverse of front_rho by bisection (table construction only)."""
    lo, hi = np.zeros_like(rho), np.full_like(rho, HALF_PI)
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        below = front_rho(mid, lam) < rho
        lo, hi = np.where(below, mid, lo), np.where(below, hi, mid)
    return 0.5 * (lo + hi)


@dataclass(frozen=True)
class IsgTable:
    log_lambdas: np.ndarray  # (L,) natural log of the rows' lam
    front_theta: np.ndarray  # (L, R) T of A at uniform rho
    front_phi: np.ndarray  # (L, R) T of B
    back_theta: np.ndarray  # (L, R) T of Ab (rows with lam > BACK_LAMBDA_MAX unused)
    back_phi: np.ndarray  # (L, R) T of Bb

    @property
    def floats(self) -> int:
        return 4 * self.front_theta.size + self.log_lambdas.size


@lru_cache(maxsize=None)
def isg_table() -> IsgTable:
    """Build the four (lam, rho) tables from isg_exact_grid (about a second)."""
    decades = math.log10(TABLE_LAMBDA_MAX / TABLE_LAMBDA_MIN)
    lams = TABLE_LAMBDA_MIN * 10.0 ** (np.arange(int(round(decades * TABLE_LAMBDAS_PER_DECADE)) + 1) / TABLE_LAMBDAS_PER_DECADE)
    rho = np.linspace(0.0, 1.0, TABLE_RHO_NODES)
    ft, fp, bt, bp = (np.zeros((len(lams), len(rho))) for _ in range(4))
    for i, lam in enumerate(lams):
        xf = _front_x(rho, lam)
        xb = rho * HALF_PI
        ths = np.concatenate([HALF_PI + xf, HALF_PI + xb, [math.pi]])
        phs = np.concatenate([HALF_PI + xf, math.pi + HALF_PI + xb, [math.pi, TWO_PI]])
        s = isg_exact_grid(lam, ths, phs)
        n = len(rho)
        ft[i] = s[:n, -2] - 0.5
        fp[i] = s[-1, :n] - 0.5
        if lam <= BACK_LAMBDA_MAX:
            back = (s[:, -1] - s[:, -2]) * math.exp(lam)  # theta-marginal of the back, normalised
            bt[i] = back[n : 2 * n] - 0.5
            bp[i] = (s[-1, n : 2 * n] - s[-1, -2]) * math.exp(lam) - 0.5
    return IsgTable(np.log(lams), ft, fp, bt, bp)


def _lookup(table: np.ndarray, log_lams: np.ndarray, lam, rho) -> np.ndarray:
    """Bilinear in (log lam, rho), lam clamped to the table's range."""
    u = np.interp(np.log(lam), log_lams, np.arange(len(log_lams), dtype=np.float64))
    i0 = np.minimum(np.floor(u).astype(int), len(log_lams) - 2)
    fu = u - i0
    v = np.clip(rho, 0.0, 1.0) * (table.shape[1] - 1)
    j0 = np.minimum(np.floor(v).astype(int), table.shape[1] - 2)
    fv = v - j0
    row0 = table[i0, j0] * (1 - fv) + table[i0, j0 + 1] * fv
    row1 = table[i0 + 1, j0] * (1 - fv) + table[i0 + 1, j0 + 1] * fv
    return row0 * (1 - fu) + row1 * fu


def _cdf(table, log_lams, lam, angle, rho_of_x) -> np.ndarray:
    """F(angle) on [0, pi] from its tabulated odd part about pi/2."""
    x = angle - HALF_PI
    return 0.5 + np.sign(x) * _lookup(table, log_lams, lam, rho_of_x(np.abs(x)))


def isg_eval(theta, phi, lam, table: IsgTable | None = None) -> np.ndarray:
    """S_hat(theta, phi; lam) from the tables, theta in [0, pi], phi in [0, 2 pi], lam > 0.
    Max abs error <= 0.005 against isg_exact for lam in [1e-3, 1e4] (tests/test_isg64.py)."""
    tb = table or isg_table()
    theta, phi, lam = np.broadcast_arrays(*(np.asarray(a, np.float64) for a in (theta, phi, lam)))
    theta = np.clip(theta, 0.0, math.pi)
    phi = np.clip(phi, 0.0, TWO_PI)
    ll = tb.log_lambdas

    def front(x):
        return front_rho(x, lam)

    def back(x):
        return x / HALF_PI

    a = _cdf(tb.front_theta, ll, lam, theta, front)
    b = _cdf(tb.front_phi, ll, lam, np.minimum(phi, math.pi), front)
    out = a * b
    behind = (phi > math.pi) & (lam <= BACK_LAMBDA_MAX)
    if behind.any():
        ab = _cdf(tb.back_theta, ll, lam, theta, back)
        bb = _cdf(tb.back_phi, ll, lam, np.clip(phi - math.pi, 0.0, math.pi), back)
        out = out + np.where(behind, np.exp(-np.minimum(lam, BACK_LAMBDA_MAX)) * ab * bb, 0.0)
    return out


# --------------------------------------------------------------------------- SG lighting (the env fit)


def sg_lobes_radiance(axes, sharpness, amplitudes, dirs) -> np.ndarray:
    """sum_k amplitude_k exp(lam_k (d.axis_k - 1)) at unit directions dirs (n, 3): (n, 3) RGB."""
    axes, lam, amp = (np.asarray(a, np.float64) for a in (axes, sharpness, amplitudes))
    g = np.exp(lam[None, :] * (np.asarray(dirs, np.float64) @ axes.T - 1.0))
    return g @ amp


def sg_lobes_irradiance(axes, sharpness, amplitudes, normals) -> np.ndarray:
    """sum_k amplitude_k E(axis_k . n; lam_k) at unit normals (n, 3) by the closed form of 3.3: (n, 3) RGB."""
    axes, lam, amp = (np.asarray(a, np.float64) for a in (axes, sharpness, amplitudes))
    t = np.clip(np.asarray(normals, np.float64) @ axes.T, -1.0, 1.0)
    return sg_cosine_closed(t, np.broadcast_to(lam[None, :], t.shape)) @ amp


def relative_rms(approx, exact, weights=None) -> float:
    """sqrt(sum w |approx - exact|^2 / sum w |exact|^2) over rows of RGB (weights: per row, default 1)."""
    approx, exact = np.asarray(approx, np.float64), np.asarray(exact, np.float64)
    w = np.ones(len(exact)) if weights is None else np.asarray(weights, np.float64)
    den = np.sum(w[:, None] * exact**2)
    return float(np.sqrt(np.sum(w[:, None] * (approx - exact) ** 2) / den)) if den > 0 else float(np.abs(approx).max())


# --------------------------------------------------------------------------- BRDF lobes as SGs (docs/isg.md 6)
#
# Each specular lobe of docs/brdf.md as one SG in the light direction l, G_f(l) = mu exp(lam (l.axis - 1)),
# so that f_lobe(v, l) ~ G_f(l) (the clamped cosine kept apart, exactly, by sg_cosine_closed):
#   phong:        axis R = 2 (n.v) n - v, lam = n_s, mu = (n_s + 2) / 2 pi (cos^n ~ e^(n (cos - 1)));
#   blinn_phong:  the half-vector lobe (n_s + 8)/8 pi exp(n_s (h.n - 1)) warped to l [WRG*09]:
#                 axis R, lam = n_s / (4 max(n.v, eps)) (dw_l = 4 (h.v) dw_h at h = n), mu unchanged;
#   ggx:          D(h) ~ 1/(pi a^2) exp(2/a^2 (h.n - 1)) (equal curvature at h = n) warped likewise,
#                 mu times the masking and 1 / (4 (n.l)(n.v)) at the warped axis, with
#                 G1(c) / c = 2 / (c + sqrt(a^2 + (1 - a^2) c^2)) finite as c -> 0.
MIN_COS_VIEW = 1e-4


def brdf_sg(n, v, lobe: str, shininess: float = 100.0, roughness: float = 0.3):
    """The SG (axis, lam, mu) of f_lobe(v, .) for unit n, v (3,)."""
    n, v = np.asarray(n, np.float64), np.asarray(v, np.float64)
    nv = float(n @ v)
    r = 2.0 * nv * n - v
    r = r / np.linalg.norm(r)
    cv = max(nv, MIN_COS_VIEW)
    if lobe == "phong":
        return r, float(shininess), (shininess + 2.0) / TWO_PI
    if lobe == "blinn_phong":
        return r, shininess / (4.0 * cv), (shininess + 8.0) / (8.0 * math.pi)
    if lobe == "ggx":
        a2 = min(max(roughness, 1e-3), 1.0) ** 2
        nl = max(float(n @ r), 0.0)

        def g1_over_c(c):
            return 2.0 / (c + math.sqrt(a2 + (1.0 - a2) * c * c))

        mu = 1.0 / (math.pi * a2) * g1_over_c(cv) * g1_over_c(nl) / 4.0
        return r, 2.0 / a2 / (4.0 * cv), mu
    raise ValueError(f"unknown lobe '{lobe}'")


# ashikhmin_shirley: 7 SGs (pn_as_sgs, docs/isg.md 6): the half-vector lobe ~ the anisotropic Gaussian
#                 exp(-(n_u x^2 + n_v y^2) / 2), a row of isotropic SGs along its long axis
#                 with Gaussian weights, each warped to l like Blinn-Phong, times the lobe's other factors.
AS_MAX_SGS = 7
AS_MIN_EXPONENT = 1.0


def as_sgs(n, v, n_u: float, n_v: float, tangent):
    """The SGs [(axis, lam, mu), ...] (7, or 1 for a nearly isotropic lobe) of the
    Ashikhmin-Shirley f_lobe(v, .) for unit n, v and unit tangent u (3,)."""
    n, v, u = (np.asarray(x, np.float64) for x in (n, v, tangent))
    nv = float(n @ v)
    cv = max(nv, MIN_COS_VIEW)
    nu, nw = max(n_u, AS_MIN_EXPONENT), max(n_v, AS_MIN_EXPONENT)
    a = u if nu <= nw else np.cross(n, u)
    var_t, var_s = 1.0 / min(nu, nw), 1.0 / max(nu, nw)
    r = math.sqrt(var_t / var_s)
    var_c = var_s * max(1.0, r / 4.3)
    s_c, s_w = math.sqrt(var_c), math.sqrt(max(var_t - var_c, 0.0))
    count = AS_MAX_SGS if s_w > 0.05 * s_c else 1
    d = min(0.8 * s_w, 2.4 * s_c)
    x = (np.arange(count) - 0.5 * (count - 1)) * d
    w = np.exp(-0.5 * x * x / (s_w * s_w)) if count > 1 else np.ones(1)
    norm = math.sqrt((n_u + 1.0) * (n_v + 1.0)) / (8.0 * math.pi)
    scale = norm * math.sqrt(var_t * var_s) / (var_c * float(w.sum()))
    out = []
    for xk, wk in zip(x, w):
        h = math.cos(xk) * n + math.sin(xk) * a
        hv_raw = float(h @ v)
        hv = max(hv_raw, MIN_COS_VIEW)
        axis = 2.0 * hv_raw * h - v
        axis = axis / np.linalg.norm(axis)
        out.append((axis, 1.0 / var_c / (4.0 * hv), scale * wk / (hv * max(float(n @ axis), cv))))
    return out


def brdf_sgs(n, v, lobe: str, shininess: float = 100.0, roughness: float = 0.3, shininess_v: float = 100.0,
             tangent=None):
    """pn_brdf_sgs: the lobe as a list of SGs (one, or the Ashikhmin-Shirley seven)."""
    if lobe == "ashikhmin_shirley":
        return as_sgs(n, v, shininess, shininess_v, tangent)
    return [brdf_sg(n, v, lobe, shininess, roughness)]


def sg_reflected(light_axis, light_lam, n, brdf_lobe) -> float:
    """int G_light(l) G_f(l) max(n.l, 0) dl for a unit-amplitude light lobe: the product lobe's
    clamped-cosine integral by the closed form (what the shading does per light lobe)."""
    axis, lam, mu = brdf_lobe
    pa, pl, pm = sg_product(np.asarray(light_axis, np.float64), light_lam, 1.0, axis, lam, mu)
    return float(pm * sg_cosine_closed(float(np.asarray(n) @ pa), float(pl)))


def reflected_exact(light_axis, light_lam, n, v, lobe: str, shininess=100.0, roughness=0.3, nodes=24,
                    n_beta=512, shininess_v=100.0, tangent=None) -> float:
    """int G_light(l) f_lobe(v, l) max(n.l, 0) dl by quadrature (f_lobe: penumbra.brdf, docs/brdf.md),
    on a rule graded around the axis of the light x SG-lobe product (where the integrand lives; for
    the Ashikhmin-Shirley lobe its widest component and the light, at the width of the sharper)."""
    from penumbra import brdf as b

    lobes = brdf_sgs(n, v, lobe, shininess, roughness, shininess_v, tangent)
    axis, lam, _ = lobes[len(lobes) // 2]
    if len(lobes) > 1:
        lam = min(x[1] for x in lobes) / 9.0  # the row spans several widths: grade around a wider lobe
    pa, pl, _ = sg_product(np.asarray(light_axis, np.float64), light_lam, 1.0, axis, lam, 1.0)
    pa = pa / np.linalg.norm(pa)
    width = 1.0 / max(float(pl), 1e-3)
    u, wu = panel_rule(graded_breaks(-1.0, 1.0, 1.0, width), nodes)
    beta = TWO_PI * (np.arange(n_beta) + 0.5) / n_beta
    helper = np.array([1.0, 0.0, 0.0]) if abs(pa[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = np.cross(pa, helper)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(pa, e1)
    s = np.sqrt(np.maximum(0.0, 1.0 - u * u))
    d = (u[:, None, None] * pa + (s[:, None] * np.cos(beta))[..., None] * e1
         + (s[:, None] * np.sin(beta))[..., None] * e2).reshape(-1, 3)
    w = (wu[:, None] * np.full(n_beta, TWO_PI / n_beta)).ravel()
    f = b.lobe(np.asarray(n, np.float64), np.asarray(v, np.float64), d, lobe, shininess, roughness, shininess_v,
               tangent)
    g = sg(d, light_axis, light_lam)
    return float(np.sum(w * g * f * np.maximum(d @ np.asarray(n, np.float64), 0.0)))
