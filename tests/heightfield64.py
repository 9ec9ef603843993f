"""float64 twin of the height-field method (docs/heightfield.md): the
multi-resolution pyramid (tent decimation, cubic B-spline reconstruction with
clamped indices), the horizon search (multi-scale directional derivatives,
B-spline maximum over knots and midpoints, environment clamp, light
truncation, exact-horizon marching), the SH visibility wedges (tables with
bilinear lookup, z-rotation, sum over azimuths) and the shading (clamped
cosine ZH, triple product, environment SH, spherical-light cap ZH, per-pass
clamp at 0).

Plain numpy, everything in float64. Conventions, as in the spec:

* Heights are (D, W) arrays, rows j along world +z, columns i along world +x;
  H = height_scale * h in world units, vertex (i, j) at base coordinates
  (u, v) = (i, j).
* SH frame X = world x, Y = world -z, Z = world y (`world_to_sh`); azimuth
  phi is measured from X towards Y, so a horizontal step d along phi moves
  (du, dv) = (d cos phi / sx, -d sin phi / sz) in base coordinates.
* SH coefficient vectors are (..., nb*nb), index l*l + l + m (`sh_index`);
  real orthonormal y_lm with the Condon-Shortley phase (`sh_basis`).
* Horizon arrays are (D, W, n_phi) elevation angles in radians.
* Irradiances are (D, W, 3) RGB.

Functions:

  SH        sh_index(l, m), world_to_sh(v), sh_to_world(v), legendre_P(l, x),
            assoc_legendre(l, m, x), sh_norm(l, m), sh_from_angles(cos_theta, phi, nb),
            sh_basis(dirs, nb), zrotate(coeffs, alpha, nb), zh_rotate(z, direction, nb),
            clamped_cosine_zh(nb), cap_zh(cos_alpha, nb), sphere_quadrature(degree),
            triple_product(nb)
  wedges    table_range(kind), wedge_table(n_phi, nb, kind), table_lookup(table, wl, wr, kind),
            visibility(horizons, table, n_phi, nb, kind)
  pyramid   level_count(W, D, ls), level_scale(k, ls), level_cells(W, D, ls),
            tent_matrix(c_prev, c_new), pyramid(H, ls), pyramid_floats(W, D, ls),
            bspline_weights(t), level_sample(level, W, D, u, v), bilinear(H, u, v)
  horizons  sample_plan(n, ls, lo, s0), spline_max(omega, count),
            horizons(H, sx, sz, ls, lo, n_phi, light_xz, levels),
            exact_horizons(H, sx, sz, n_phi, light_xz)
  shading   vertex_normals(H, sx, sz), vertex_points(H, origin, sx, sz),
            env_sh(dirs, solid_angles, radiance, nb), cosine_lobes(normals, nb), transfer(V, C, nb),
            shade_env(V, normals, L_env, nb), light_sh(points, centre, radius, radiance, nb),
            shade_light(V_light, normals, points, centre, radius, radiance, nb),
            shade(heights, origin, size, height_scale, env, lights, ls, lo, n_phi, nb, exact),
            outgoing(albedo, E_env, E_lights)

Readings of the spec where it leaves a choice (see also the comments at each):
round() is C's (halves away from zero); sr^k is 2^(k/ls) (exact powers of two
at multiples of ls); a light whose sphere contains p (delta < r) fills the whole
sphere (cos alpha = -1); the exact march keeps a step on the border (up to
BORDER_SLACK); wedge integrals are taken in elevation rather than in
sin(elevation) (same integral, faster convergence).
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np

TABLE_SIZE = 64  # T angles per table axis
ENV_RANGE = (0.0, 0.5 * np.pi)
LIGHT_RANGE = (-0.5 * np.pi, 0.5 * np.pi)

# Gauss-Legendre nodes per axis of a wedge integral. The twin integrates in
# elevation (dw = cos(e) de dphi), where the integrand is analytic and 24
# nodes are converged to ~1e-15; in sin(elevation) the odd-m integrands carry
# sqrt(1 - s^2) and Gauss-Legendre converges only as N^-3 (~3e-7 at N = 64).
WEDGE_NODES = 24

# Exact-horizon marching keeps steps up to the border; this slack (in vertex
# units) keeps a step that lands on the border up to rounding of cos/sin.
BORDER_SLACK = 1e-9


def round_half_away(x: float) -> int:
    """C's round(): halves away from zero (Python's round() goes to even)."""
    return int(math.floor(x + 0.5)) if x >= 0 else -int(math.floor(-x + 0.5))


def leggauss(n, lo=-1.0, hi=1.0):
    """Gauss-Legendre nodes and weights on [lo, hi] (lo, hi may be arrays: nodes on the last axis)."""
    x, w = np.polynomial.legendre.leggauss(n)
    lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    half = 0.5 * (hi - lo)[..., None]
    return lo[..., None] + (x + 1.0) * half, w * half


# --------------------------------------------------------------------------- SH basics


def sh_index(l: int, m: int) -> int:
    return l * l + l + m


def world_to_sh(v) -> np.ndarray:
    """World (x, y, z) -> SH frame (X, Y, Z) = (x, -z, y)."""
    v = np.asarray(v, np.float64)
    return np.stack([v[..., 0], -v[..., 2], v[..., 1]], axis=-1)


def sh_to_world(v) -> np.ndarray:
    v = np.asarray(v, np.float64)
    return np.stack([v[..., 0], v[..., 2], -v[..., 1]], axis=-1)


def legendre_P(l: int, x) -> np.ndarray:
    """Legendre polynomial P_l(x) by Bonnet's recurrence (P_{-1} := 0 is not used)."""
    x = np.asarray(x, np.float64)
    p0, p1 = np.ones_like(x), x.copy()
    if l == 0:
        return p0
    for k in range(1, l):
        p0, p1 = p1, ((2 * k + 1) * x * p1 - k * p0) / (k + 1)
    return p1


def assoc_legendre(l: int, m: int, x) -> np.ndarray:
    """P_l^m(x), 0 <= m <= l, with the Condon-Shortley phase (scipy's lpmv):
    P_m^m = (-1)^m (2m-1)!! (1-x^2)^(m/2), then the upward recurrence in l."""
    x = np.asarray(x, np.float64)
    s = np.sqrt(np.maximum(0.0, 1.0 - x * x))
    pmm = np.ones_like(x)
    for k in range(1, m + 1):
        pmm = -pmm * (2 * k - 1) * s
    if l == m:
        return pmm
    p1 = x * (2 * m + 1) * pmm
    for ll in range(m + 2, l + 1):
        pmm, p1 = p1, ((2 * ll - 1) * x * p1 - (ll + m - 1) * pmm) / (ll - m)
    return p1


def sh_norm(l: int, m: int) -> float:
    """K_l^m = sqrt((2l+1)/(4 pi) (l-m)!/(l+m)!), m >= 0."""
    return math.sqrt((2 * l + 1) / (4 * math.pi) * math.factorial(l - m) / math.factorial(l + m))


def sh_from_angles(cos_theta, phi, nb: int) -> np.ndarray:
    """(..., nb*nb) real SH at polar cosine cos_theta (from Z) and azimuth phi (from X towards Y)."""
    cos_theta, phi = np.broadcast_arrays(np.asarray(cos_theta, np.float64), np.asarray(phi, np.float64))
    out = np.empty(cos_theta.shape + (nb * nb,))
    for l in range(nb):
        for m in range(l + 1):
            p = sh_norm(l, m) * assoc_legendre(l, m, cos_theta)
            if m == 0:
                out[..., sh_index(l, 0)] = p
            else:
                out[..., sh_index(l, m)] = math.sqrt(2.0) * p * np.cos(m * phi)
                out[..., sh_index(l, -m)] = math.sqrt(2.0) * p * np.sin(m * phi)
    return out


def sh_basis(dirs, nb: int) -> np.ndarray:
    """(..., nb*nb) real SH of unit vectors given in the SH frame."""
    d = np.asarray(dirs, np.float64)
    return sh_from_angles(np.clip(d[..., 2], -1.0, 1.0), np.arctan2(d[..., 1], d[..., 0]), nb)


def zrotate(coeffs, alpha, nb: int) -> np.ndarray:
    """Rotate SH coefficients about Z by alpha (the function f(phi) becomes f(phi - alpha)):
    c'_{l,m} = c_{l,m} cos(m a) - c_{l,-m} sin(m a), c'_{l,-m} = c_{l,-m} cos(m a) + c_{l,m} sin(m a).
    alpha broadcasts against coeffs[..., 0]."""
    c = np.asarray(coeffs, np.float64)
    alpha = np.asarray(alpha, np.float64)
    out = np.broadcast_to(c, np.broadcast_shapes(c.shape, alpha.shape + (c.shape[-1],))).copy()
    for m in range(1, nb):
        ca, sa = np.cos(m * alpha), np.sin(m * alpha)
        for l in range(m, nb):
            ip, im = sh_index(l, m), sh_index(l, -m)
            cp, cm = c[..., ip], c[..., im]
            out[..., ip] = cp * ca - cm * sa
            out[..., im] = cm * ca + cp * sa
    return out


def zh_rotate(z, direction, nb: int) -> np.ndarray:
    """Zonal coefficients z_l (about Z) rotated to a unit direction in the SH frame:
    c_lm = sqrt(4 pi / (2l+1)) z_l y_lm(direction). z is (nb,) or (..., nb)."""
    z = np.asarray(z, np.float64)
    y = sh_basis(direction, nb)
    scale = np.empty(z.shape[:-1] + (nb * nb,))
    for l in range(nb):
        scale[..., l * l:(l + 1) * (l + 1)] = math.sqrt(4 * math.pi / (2 * l + 1)) * z[..., l:l + 1]
    return scale * y


def clamped_cosine_zh(nb: int) -> np.ndarray:
    """z_l = 2 pi sqrt((2l+1)/(4 pi)) int_0^1 P_l(t) t dt (Gauss-Legendre, exact for these degrees)."""
    t, w = leggauss(nb + 2, 0.0, 1.0)
    return np.array([2 * math.pi * math.sqrt((2 * l + 1) / (4 * math.pi)) * np.sum(w * legendre_P(l, t) * t)
                     for l in range(nb)])


def cap_zh(cos_alpha, nb: int) -> np.ndarray:
    """(..., nb) zonal coefficients of the indicator of a cap of half-angle alpha about Z:
    z_l = 2 pi sqrt((2l+1)/(4 pi)) int_{cos a}^1 P_l, with int_x^1 P_0 = 1 - x and
    int_x^1 P_l = (P_{l-1}(x) - P_{l+1}(x)) / (2l+1)."""
    x = np.asarray(cos_alpha, np.float64)
    z = np.empty(x.shape + (nb,))
    for l in range(nb):
        integral = 1.0 - x if l == 0 else (legendre_P(l - 1, x) - legendre_P(l + 1, x)) / (2 * l + 1)
        z[..., l] = 2 * math.pi * math.sqrt((2 * l + 1) / (4 * math.pi)) * integral
    return z


def sphere_quadrature(degree: int) -> tuple[np.ndarray, np.ndarray]:
    """(N, 3) SH-frame directions and weights integrating every polynomial of the given
    degree on the sphere exactly: Gauss-Legendre in cos(theta) x uniform in phi."""
    nt = degree // 2 + 2
    nphi = degree + 2
    ct, wt = leggauss(nt)
    phi = 2 * math.pi * np.arange(nphi) / nphi
    st = np.sqrt(1 - ct * ct)
    dirs = np.stack([st[:, None] * np.cos(phi), st[:, None] * np.sin(phi),
                     np.broadcast_to(ct[:, None], (nt, nphi))], -1)
    w = wt[:, None] * np.full(nphi, 2 * math.pi / nphi)
    return dirs.reshape(-1, 3), w.ravel()


@lru_cache(maxsize=None)
def triple_product(nb: int) -> np.ndarray:
    """Dense (n, n, n) tensor Gamma_ijk = int y_i y_j y_k (n = nb*nb), exact quadrature; entries
    below 1e-12 (zero by symmetry, left as rounding noise by the quadrature) are set to 0."""
    dirs, w = sphere_quadrature(3 * (nb - 1))
    y = sh_basis(dirs, nb)
    g = np.einsum("q,qi,qj,qk->ijk", w, y, y, y)
    g[np.abs(g) < 1e-12] = 0.0
    g.setflags(write=False)
    return g


# --------------------------------------------------------------------------- wedge tables


def table_range(kind: str) -> tuple[float, float]:
    if kind == "env":
        return ENV_RANGE
    if kind == "light":
        return LIGHT_RANGE
    raise ValueError(f"wedge table kind must be 'env' or 'light', not {kind!r}")


@lru_cache(maxsize=None)
def wedge_table(n_phi: int, nb: int, kind: str, nodes: int = WEDGE_NODES) -> np.ndarray:
    """(T, T, nb*nb) table v[a][b] = int over the visible part of the wedge phi in [0, dphi],
    dphi = 2 pi / n_phi, of y_lm, horizon omega(phi) = w_a + (phi / dphi)(w_b - w_a), visible =
    elevation > omega(phi) (env: > max(omega(phi), 0)), w_a = lo + a (hi - lo) / (T - 1).
    Gauss-Legendre in phi and in elevation (see WEDGE_NODES). Read-only, cached."""
    lo, hi = table_range(kind)
    T = TABLE_SIZE
    omega = lo + np.arange(T) * (hi - lo) / (T - 1)
    dphi = 2 * math.pi / n_phi
    phi, wphi = leggauss(nodes, 0.0, dphi)
    frac = phi / dphi
    table = np.zeros((T, T, nb * nb))
    for a in range(T):
        horizon = omega[a] + frac[None, :] * (omega[:, None] - omega[a])  # (b, phi node)
        if kind == "env":
            horizon = np.maximum(horizon, 0.0)
        e, we = leggauss(nodes, horizon, np.full_like(horizon, 0.5 * math.pi))  # (b, phi, e)
        s, wde = np.sin(e), we * np.cos(e)  # dw = cos(e) de dphi; cos(theta) = sin(e)
        for l in range(nb):
            for m in range(l + 1):
                g = np.sum(wde * assoc_legendre(l, m, s), axis=-1) * sh_norm(l, m)  # (b, phi)
                if m == 0:
                    table[a, :, sh_index(l, 0)] = g @ wphi
                else:
                    table[a, :, sh_index(l, m)] = math.sqrt(2) * (g @ (wphi * np.cos(m * phi)))
                    table[a, :, sh_index(l, -m)] = math.sqrt(2) * (g @ (wphi * np.sin(m * phi)))
    table.setflags(write=False)
    return table


def table_lookup(table, wl, wr, kind: str) -> np.ndarray:
    """Bilinear lookup of a wedge table at horizon pairs (wl, wr) (angles, clamped to the
    table's range) -> (..., nb*nb)."""
    lo, hi = table_range(kind)
    T = table.shape[0]

    def coord(w):
        x = np.clip((np.asarray(w, np.float64) - lo) / (hi - lo) * (T - 1), 0.0, T - 1)
        i = np.minimum(np.floor(x).astype(np.int64), T - 2)
        return i, (x - i)[..., None]

    ia, fa = coord(wl)
    ib, fb = coord(wr)
    return ((1 - fa) * ((1 - fb) * table[ia, ib] + fb * table[ia, ib + 1])
            + fa * ((1 - fb) * table[ia + 1, ib] + fb * table[ia + 1, ib + 1]))


def visibility(horizons, table, n_phi: int, nb: int, kind: str) -> np.ndarray:
    """(..., nb*nb) visibility V: per azimuth k the table at (omega_k, omega_{k+1}) (k + 1 wraps),
    rotated about Z by phi_k = 2 pi k / n_phi, summed over k."""
    h = np.asarray(horizons, np.float64)
    v = table_lookup(table, h, np.roll(h, -1, axis=-1), kind)
    phi = 2 * math.pi * np.arange(n_phi) / n_phi
    return zrotate(v, phi, nb).sum(axis=-2)


# --------------------------------------------------------------------------- pyramid


def level_count(W: int, D: int, ls: int) -> int:
    """n = ceil(ls log2(max(W, D))) + 1 (math.log2 is exact on powers of two)."""
    return math.ceil(ls * math.log2(max(W, D))) + 1


def level_scale(k, ls) -> np.ndarray:
    """sr^k = 2^(k / ls), exactly 2^(k/ls) (so that sr^(j ls) is an exact power of two)."""
    return 2.0 ** (np.asarray(k, np.float64) / ls)


def level_cells(W: int, D: int, ls: int) -> list[tuple[int, int]]:
    """(Ck, Ek) per level: max(1, round((W-1) / sr^k)), max(1, round((D-1) / sr^k)), C's round."""
    out = []
    for k in range(level_count(W, D, ls)):
        s = float(level_scale(k, ls))
        out.append((max(1, round_half_away((W - 1) / s)), max(1, round_half_away((D - 1) / s))))
    return out


def tent_matrix(c_prev: int, c_new: int) -> np.ndarray:
    """(c_new+1, c_prev+1) normalised tent weights along one axis: value a of the new level
    averages the previous level's values q with |u_q - u_a| < ru, w = 1 - |u_q - u_a| / ru,
    ru the new spacing; in new-level units |u_q - u_a| / ru = |q c_new / c_prev - a|.
    Equal cell counts: identity (only the coinciding value has w > 0 anyway)."""
    if c_new == c_prev:
        return np.eye(c_new + 1)
    q = np.arange(c_prev + 1)
    a = np.arange(c_new + 1)
    w = np.maximum(0.0, 1.0 - np.abs(q[None, :] * (c_new / c_prev) - a[:, None]))
    return w / w.sum(axis=1, keepdims=True)


def pyramid(H, ls: int = 4, interpolating: bool = False) -> list[np.ndarray]:
    """Levels (Ek+1, Ck+1) (rows z, columns x); level 0 is H, level k the separable tent
    decimation of level k-1 (the product weight normalises as the product of the two axes).
    interpolating: every level (after all decimations) replaced by the control points whose
    clamped cubic B-spline passes through its values (`interpolating_points`)."""
    H = np.asarray(H, np.float64)
    D, W = H.shape
    cells = level_cells(W, D, ls)
    levels = [H.copy()]
    for k in range(1, len(cells)):
        (cp, ep), (c, e) = cells[k - 1], cells[k]
        levels.append(tent_matrix(ep, e) @ levels[-1] @ tent_matrix(cp, c).T)
    if interpolating:
        levels = [interpolating_points(level) for level in levels]
    return levels


def knot_matrix(n: int) -> np.ndarray:
    """(n, n) values of the clamped uniform cubic B-spline at its knots from its control
    points: (c_{i-1} + 4 c_i + c_{i+1}) / 6 with indices clamped, so (5, 1) / 6 at the ends."""
    B = np.zeros((n, n))
    for i in range(n):
        B[i, i] += 4 / 6
        B[i, max(i - 1, 0)] += 1 / 6
        B[i, min(i + 1, n - 1)] += 1 / 6
    return B


def interpolating_points(level) -> np.ndarray:
    """Control points c with knot_matrix(rows) c knot_matrix(cols)^T = level: the B-spline
    through the level's values (a single value along an axis stays as it is)."""
    level = np.asarray(level, np.float64)
    e1, c1 = level.shape
    out = np.linalg.solve(knot_matrix(e1), level)
    return np.linalg.solve(knot_matrix(c1), out.T).T


def pyramid_floats(W: int, D: int, ls: int) -> int:
    return sum((c + 1) * (e + 1) for c, e in level_cells(W, D, ls))


def bspline_weights(t) -> np.ndarray:
    """(4, ...) uniform cubic B-spline weights on values ia-1 .. ia+2."""
    t = np.asarray(t, np.float64)
    return np.stack([(1 - t) ** 3 / 6, (3 * t ** 3 - 6 * t ** 2 + 4) / 6, (-3 * t ** 3 + 3 * t ** 2 + 3 * t + 1) / 6,
                     t ** 3 / 6])


def level_sample(level, W: int, D: int, u, v) -> np.ndarray:
    """H_k(u, v) at base coordinates: cubic B-spline of the level's values (control points),
    a = u Ck / (W-1), b = v Ek / (D-1), indices clamped to the level (terrain continues at
    its border's heights)."""
    level = np.asarray(level, np.float64)
    E, C = level.shape[0] - 1, level.shape[1] - 1
    a = np.asarray(u, np.float64) * (C / (W - 1))
    b = np.asarray(v, np.float64) * (E / (D - 1))
    ia, ib = np.floor(a), np.floor(b)
    wa, wb = bspline_weights(a - ia), bspline_weights(b - ib)
    ia, ib = ia.astype(np.int64), ib.astype(np.int64)
    out = np.zeros(np.broadcast_shapes(a.shape, b.shape))
    for q in range(4):
        rows = np.clip(ib + q - 1, 0, E)
        acc = np.zeros_like(out)
        for p in range(4):
            acc = acc + wa[p] * level[rows, np.clip(ia + p - 1, 0, C)]
        out += wb[q] * acc
    return out


def bilinear(H, u, v) -> np.ndarray:
    """The base field between vertices (bilinear), coordinates clamped to the grid."""
    H = np.asarray(H, np.float64)
    D, W = H.shape
    u = np.clip(np.asarray(u, np.float64), 0.0, W - 1)
    v = np.clip(np.asarray(v, np.float64), 0.0, D - 1)
    i = np.minimum(np.floor(u).astype(np.int64), W - 2)
    j = np.minimum(np.floor(v).astype(np.int64), D - 2)
    fu, fv = u - i, v - j
    return ((1 - fv) * ((1 - fu) * H[j, i] + fu * H[j, i + 1]) + fv * ((1 - fu) * H[j + 1, i] + fu * H[j + 1, i + 1]))


# --------------------------------------------------------------------------- horizons


def spline_max(omega, count) -> np.ndarray:
    """Maximum of the uniform cubic B-spline through omega[..., :count] (ends extended by
    repetition) over its knots (w_{m-1} + 4 w_m + w_{m+1}) / 6, m < count, and midpoints
    (w_{m-1} + 23 w_m + 23 w_{m+1} + w_{m+2}) / 48, m < count - 1; -pi/2 where count = 0."""
    omega = np.asarray(omega, np.float64)
    n = omega.shape[-1]
    count = np.broadcast_to(np.asarray(count), omega.shape[:-1])
    last = np.clip(count - 1, 0, n - 1)[..., None]
    w_last = np.take_along_axis(omega, last, axis=-1)
    idx = np.arange(n)
    e = np.where(idx < count[..., None], omega, w_last)  # omega_m = omega_{count-1} beyond the truncation
    ext = np.concatenate([e[..., :1], e, w_last], axis=-1)  # omega_{-1} .. omega_n
    knots = (ext[..., :-2] + 4 * ext[..., 1:-1] + ext[..., 2:]) / 6
    mids = (ext[..., :-3] + 23 * ext[..., 1:-2] + 23 * ext[..., 2:-1] + ext[..., 3:]) / 48
    knots = np.where(idx < count[..., None], knots, -np.inf)
    mids = np.where(idx[:-1] < count[..., None] - 1, mids, -np.inf)
    best = np.maximum(knots.max(axis=-1), mids.max(axis=-1, initial=-np.inf))
    return np.where(count > 0, best, -0.5 * np.pi)


def azimuth_steps(n_phi: int, sx: float, sz: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """phi_k and the base-coordinate step (du, dv) per world unit along phi_k."""
    phi = 2 * np.pi * np.arange(n_phi) / n_phi
    return phi, np.cos(phi) / sx, -np.sin(phi) / sz


def light_distance(shape, sx, sz, light_xz) -> np.ndarray:
    """(D, W) horizontal distance from each vertex to the light centre; light_xz is the centre's
    (x - x0, z - z0) in world units."""
    D, W = shape
    j, i = np.mgrid[0:D, 0:W].astype(np.float64)
    return np.hypot(light_xz[0] - i * sx, light_xz[1] - j * sz)


def sample_plan(n: int, ls: int, lo: float, s0: float) -> tuple[np.ndarray, np.ndarray]:
    """Sample distances d_m = s0 sr^m and levels L_m = clamp(m - round(ls lo), 0, n-1), m < n."""
    m = np.arange(n)
    return s0 * level_scale(m, ls), np.clip(m - round_half_away(ls * lo), 0, n - 1)


def horizons(H, sx: float, sz: float, ls: int = 4, lo: float = 2.0, n_phi: int = 32, light_xz=None,
             levels=None) -> np.ndarray:
    """(D, W, n_phi) pyramid horizons. Sample m at d_m = s0 sr^m (s0 = min(sx, sz)) on level
    L_m = clamp(m - round(ls lo), 0, n-1), w_m = atan((H_L(p + d_m e_k) - H_L(p)) / d_m), then
    spline_max. Environment (light_xz None): clamped at 0. Light: only d_m < r_L count, -pi/2
    with none. levels: a prebuilt pyramid(H, ls) to reuse."""
    H = np.asarray(H, np.float64)
    D, W = H.shape
    levels = pyramid(H, ls) if levels is None else levels
    n = len(levels)
    d, L = sample_plan(n, ls, lo, min(sx, sz))
    j, i = np.mgrid[0:D, 0:W].astype(np.float64)
    _, du, dv = azimuth_steps(n_phi, sx, sz)
    at_p = {k: level_sample(levels[k], W, D, i, j)[..., None] for k in set(L.tolist())}
    omega = np.empty((D, W, n_phi, n))
    for mm in range(n):
        k = L[mm]
        h = level_sample(levels[k], W, D, i[..., None] + d[mm] * du, j[..., None] + d[mm] * dv)
        omega[..., mm] = np.arctan((h - at_p[k]) / d[mm])
    if light_xz is None:
        return np.maximum(spline_max(omega, n), 0.0)
    r = light_distance((D, W), sx, sz, light_xz)
    count = (d[None, None, :] < r[..., None]).sum(axis=-1)  # d_m increases: a prefix
    return spline_max(omega, count[..., None])


def exact_horizons(H, sx: float, sz: float, n_phi: int = 256, light_xz=None) -> np.ndarray:
    """(D, W, n_phi) exact-mode horizons: the bilinear base field marched from t = s0/2 in steps
    of s0/2 while inside the grid, w = max atan((H(p + t e) - H(p)) / t). Environment: clamped
    at 0 (0 with no step). Light: only t < r_L, -pi/2 with no step."""
    H = np.asarray(H, np.float64)
    D, W = H.shape
    step = 0.5 * min(sx, sz)
    t = step * np.arange(1, int(math.hypot((W - 1) * sx, (D - 1) * sz) / step) + 2)
    j, i = np.mgrid[0:D, 0:W].astype(np.float64)
    _, du, dv = azimuth_steps(n_phi, sx, sz)
    h0 = H[..., None]
    r = None if light_xz is None else light_distance((D, W), sx, sz, light_xz)[..., None]
    out = np.empty((D, W, n_phi))
    for k in range(n_phi):
        u = i[..., None] + t * du[k]
        v = j[..., None] + t * dv[k]
        ok = ((u >= -BORDER_SLACK) & (u <= W - 1 + BORDER_SLACK) & (v >= -BORDER_SLACK) & (v <= D - 1 + BORDER_SLACK))
        if r is not None:
            ok &= t < r
        el = np.where(ok, np.arctan((bilinear(H, u, v) - h0) / t), -np.inf)
        out[..., k] = el.max(axis=-1)
    if r is None:
        return np.maximum(out, 0.0)
    return np.where(np.isfinite(out), out, -0.5 * np.pi)


# --------------------------------------------------------------------------- shading


def vertex_normals(H, sx: float, sz: float) -> np.ndarray:
    """(D, W, 3) world normals normalize(-dH/dx, 1, -dH/dz): central differences, one-sided on the border."""
    dz, dx = np.gradient(np.asarray(H, np.float64), sz, sx)  # edge_order=1: one-sided first differences
    n = np.stack([-dx, np.ones_like(dx), -dz], axis=-1)
    return n / np.linalg.norm(n, axis=-1, keepdims=True)


def vertex_points(H, origin, sx: float, sz: float) -> np.ndarray:
    """(D, W, 3) world positions (x0 + i sx, y0 + H, z0 + j sz)."""
    H = np.asarray(H, np.float64)
    D, W = H.shape
    j, i = np.mgrid[0:D, 0:W].astype(np.float64)
    return np.stack([origin[0] + i * sx, origin[1] + H, origin[2] + j * sz], axis=-1)


def env_sh(dirs_world, solid_angles, radiance_rgb, nb: int) -> np.ndarray:
    """(nb*nb, 3) L_i = sum over texels L(w) y_i(w) dw (directions in world coordinates)."""
    y = sh_basis(world_to_sh(dirs_world), nb)
    return y.T @ (np.asarray(radiance_rgb, np.float64) * np.asarray(solid_angles, np.float64)[:, None])


def cosine_lobes(normals_world, nb: int) -> np.ndarray:
    """(..., nb*nb) C = clamped cosine ZH rotated to the normals."""
    return zh_rotate(clamped_cosine_zh(nb), world_to_sh(normals_world), nb)


def transfer(V, C, nb: int) -> np.ndarray:
    """T_i = sum_jk Gamma_ijk V_j C_k (i over nb bands)."""
    return np.einsum("ijk,...j,...k->...i", triple_product(nb), V, C)


def shade_env(V, normals_world, L_env, nb: int) -> np.ndarray:
    """(..., 3) E_env = V^T M C, M_jk = sum_i L_i Gamma_ijk per channel, clamped at 0."""
    M = np.einsum("ic,ijk->cjk", np.asarray(L_env, np.float64), triple_product(nb))
    E = np.einsum("...j,cjk,...k->...c", V, M, cosine_lobes(normals_world, nb))
    return np.maximum(E, 0.0)


def light_sh(points_world, centre, radius: float, radiance, nb: int) -> np.ndarray:
    """(..., nb*nb, 3) incident radiance of a spherical light: cap ZH of half-angle
    asin(r / delta) rotated to c - p; p inside the sphere (delta <= r): nothing (the
    sphere's surface emits outwards only, as in the reference renderer)."""
    vec = np.asarray(centre, np.float64) - np.asarray(points_world, np.float64)
    dist = np.linalg.norm(vec, axis=-1)
    inside = dist <= radius
    safe = np.where(inside, 1.0, dist)  # keeps 0/0 out; inside points are zeroed below
    cos_a = np.where(inside, 1.0, np.sqrt(np.maximum(0.0, 1.0 - (radius / safe) ** 2)))
    direction = np.where(inside[..., None], np.array([0.0, 1.0, 0.0]), vec / safe[..., None])
    L = zh_rotate(cap_zh(cos_a, nb), world_to_sh(direction), nb) * ~inside[..., None]
    return L[..., None] * np.broadcast_to(np.asarray(radiance, np.float64), (3,))


def shade_light(V_light, normals_world, points_world, centre, radius: float, radiance, nb: int) -> np.ndarray:
    """(..., 3) E_light = sum_i L^light_i T^light_i, clamped at 0."""
    T = transfer(V_light, cosine_lobes(normals_world, nb), nb)
    E = np.einsum("...ic,...i->...c", light_sh(points_world, centre, radius, radiance, nb), T)
    return np.maximum(E, 0.0)


def shade(heights, origin, size, height_scale: float, env=None, lights=(), ls: int = 4, lo: float = 2.0,
          n_phi: int = 32, nb: int = 4, exact: bool = False):
    """(E_env (D, W, 3), [E_light (D, W, 3) per light]) of a height field.

    env: (directions (N, 3) world, solid angles (N,), radiance (N, 3)) or None (zeros).
    lights: iterable of (centre (3,), radius, radiance (3,) or scalar).
    exact: exact-horizon mode (exact_horizons) instead of the pyramid."""
    H = height_scale * np.asarray(heights, np.float64)
    D, W = H.shape
    sx, sz = size[0] / (W - 1), size[1] / (D - 1)
    normals = vertex_normals(H, sx, sz)
    points = vertex_points(H, origin, sx, sz)
    levels = None if exact else pyramid(H, ls)

    def horizon_set(light_xz):
        if exact:
            return exact_horizons(H, sx, sz, n_phi, light_xz)
        return horizons(H, sx, sz, ls, lo, n_phi, light_xz, levels)

    if env is None:
        E_env = np.zeros((D, W, 3))
    else:
        V = visibility(horizon_set(None), wedge_table(n_phi, nb, "env"), n_phi, nb, "env")
        E_env = shade_env(V, normals, env_sh(*env, nb), nb)
    E_lights = []
    for centre, radius, radiance in lights:
        light_xz = (centre[0] - origin[0], centre[2] - origin[2])
        V = visibility(horizon_set(light_xz), wedge_table(n_phi, nb, "light"), n_phi, nb, "light")
        E_lights.append(shade_light(V, normals, points, centre, radius, radiance, nb))
    return E_env, E_lights


def outgoing(albedo, E_env, E_lights=()) -> np.ndarray:
    """Outgoing radiance albedo / pi (E_env + sum E_light)."""
    return np.asarray(albedo, np.float64) / np.pi * (E_env + sum(E_lights, np.zeros_like(E_env)))
