"""Self-consistency of the float64 height-field twin (tests/heightfield64.py,
docs/heightfield.md): the SH machinery against closed forms and independent
quadrature, the wedge tables against dense integration, the pyramid against
hand-computed sizes and weights, the horizon search against walls and flat
ground, and the whole shading against rotated scenes and a brute-force
ray-marched visibility. The OpenCL kernels are compared with this twin
elsewhere; these tests make sure the twin itself is right.

Small sizes throughout (fields up to 25x25): the file runs in seconds.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

import heightfield64 as hf

RNG_SEED = 20240611


# --------------------------------------------------------------------------- helpers


def sphere_rule(nt=24, nphi=48, zmin=-1.0):
    """Directions (SH frame) and weights of Gauss-Legendre in cos(theta) on [zmin, 1] x uniform phi;
    exact for polynomials up to degree min(2 nt - 1, nphi - 1) restricted to Z > zmin."""
    x, w = np.polynomial.legendre.leggauss(nt)
    ct = zmin + (x + 1) * (1 - zmin) / 2
    wt = w * (1 - zmin) / 2
    phi = 2 * np.pi * (np.arange(nphi) + 0.5) / nphi
    st = np.sqrt(1 - ct * ct)
    d = np.stack([st[:, None] * np.cos(phi), st[:, None] * np.sin(phi), np.broadcast_to(ct[:, None], (nt, nphi))], -1)
    return d.reshape(-1, 3), (wt[:, None] * np.full(nphi, 2 * np.pi / nphi)).ravel()


def gl(n, lo, hi):
    x, w = np.polynomial.legendre.leggauss(n)
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    half = ((hi - lo) / 2)[..., None]
    return lo[..., None] + (x + 1) * half, w * half


def project_horizon(phi_nodes, phi_weights, horizon, nb, clamp):
    """SH projection of {elevation > horizon(phi)} given at azimuth quadrature nodes (SH frame),
    the elevation integral by Gauss-Legendre in elevation (smooth integrand: converged)."""
    lo = np.maximum(horizon, 0.0) if clamp else horizon
    e, we = gl(32, lo, np.full_like(lo, np.pi / 2))
    y = hf.sh_from_angles(np.sin(e), np.broadcast_to(phi_nodes[:, None], e.shape), nb)
    return np.einsum("pe,pei->i", we * np.cos(e) * phi_weights[:, None], y)


def table_error_bound(table, n_phi, nb):
    """Bound on |visibility() - exact projection of the piecewise-linear horizon| per coefficient:
    bilinear interpolation errs by at most (h^2/8)(max|v_aa| + max|v_bb|) = (max|D2_a v| + max|D2_b v|)/8
    in second differences of the table; a z-rotation mixes (l, m) with (l, -m), so a coefficient
    takes at most the sum of both errors; n_phi wedges add up."""
    d2a = np.abs(table[2:] - 2 * table[1:-1] + table[:-2]).max(axis=(0, 1))
    d2b = np.abs(table[:, 2:] - 2 * table[:, 1:-1] + table[:, :-2]).max(axis=(0, 1))
    per = (d2a + d2b) / 8
    out = np.empty(nb * nb)
    for l in range(nb):
        for m in range(-l, l + 1):
            out[hf.sh_index(l, m)] = per[hf.sh_index(l, m)] + per[hf.sh_index(l, -m)] if m else per[hf.sh_index(l, 0)]
    return n_phi * out


def bilinear_ref(H, u, v):
    D, W = H.shape
    i = np.clip(np.floor(u).astype(int), 0, W - 2)
    j = np.clip(np.floor(v).astype(int), 0, D - 2)
    fu, fv = u - i, v - j
    return (H[j, i] * (1 - fu) * (1 - fv) + H[j, i + 1] * fu * (1 - fv) + H[j + 1, i] * (1 - fu) * fv
            + H[j + 1, i + 1] * fu * fv)


# --------------------------------------------------------------------------- SH basics


def test_sh_orthonormal_by_quadrature():
    nb = 6
    d, w = sphere_rule(12, 24)  # degree 2 (nb - 1) = 10 exactly
    y = hf.sh_basis(d, nb)
    np.testing.assert_allclose(y.T @ (w[:, None] * y), np.eye(nb * nb), atol=1e-13)


def test_sh_basis_closed_forms():
    rng = np.random.default_rng(RNG_SEED)
    d = rng.normal(size=(50, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    X, Y, Z = d.T
    y = hf.sh_basis(d, 4)
    pi = np.pi
    # Standard real SH with the Condon-Shortley phase: odd m carry a minus sign.
    expected = {
        (0, 0): np.full_like(X, 0.5 / math.sqrt(pi)),
        (1, -1): -math.sqrt(3 / (4 * pi)) * Y,
        (1, 0): math.sqrt(3 / (4 * pi)) * Z,
        (1, 1): -math.sqrt(3 / (4 * pi)) * X,
        (2, -2): 0.5 * math.sqrt(15 / pi) * X * Y,
        (2, -1): -0.5 * math.sqrt(15 / pi) * Y * Z,
        (2, 0): 0.25 * math.sqrt(5 / pi) * (3 * Z * Z - 1),
        (2, 1): -0.5 * math.sqrt(15 / pi) * X * Z,
        (2, 2): 0.25 * math.sqrt(15 / pi) * (X * X - Y * Y),
        (3, -3): -0.25 * math.sqrt(35 / (2 * pi)) * (3 * X * X - Y * Y) * Y,
        (3, 0): 0.25 * math.sqrt(7 / pi) * (5 * Z ** 3 - 3 * Z),
        (3, 2): 0.25 * math.sqrt(105 / pi) * (X * X - Y * Y) * Z,
    }
    for (l, m), ref in expected.items():
        np.testing.assert_allclose(y[:, hf.sh_index(l, m)], ref, atol=1e-14, err_msg=f"y_{l},{m}")
    # scipy.special.lpmv convention
    x = np.linspace(-1, 1, 7)
    np.testing.assert_allclose(hf.assoc_legendre(1, 1, x), -np.sqrt(1 - x * x), atol=1e-15)
    np.testing.assert_allclose(hf.assoc_legendre(3, 2, x), 15 * x * (1 - x * x), atol=1e-14)
    np.testing.assert_allclose(hf.legendre_P(4, x), (35 * x ** 4 - 30 * x ** 2 + 3) / 8, atol=1e-15)


def test_sh_frame():
    # X = world x, Y = world -z, Z = world y: right-handed, azimuth phi is world (cos, 0, -sin)
    X, Y, Z = hf.sh_to_world(np.eye(3))  # the SH axes in world coordinates
    np.testing.assert_array_equal([X, Y, Z], [[1, 0, 0], [0, 0, -1], [0, 1, 0]])
    np.testing.assert_array_equal(np.cross(X, Y), Z)
    np.testing.assert_array_equal(hf.world_to_sh([1.0, 0, 0]), [1, 0, 0])
    np.testing.assert_array_equal(hf.world_to_sh([0, 0, -1.0]), [0, 1, 0])
    np.testing.assert_array_equal(hf.world_to_sh([0, 1.0, 0]), [0, 0, 1])
    v = np.random.default_rng(1).normal(size=(5, 3))
    np.testing.assert_array_equal(hf.sh_to_world(hf.world_to_sh(v)), v)


def test_zrotate_equals_projection_of_rotated_function():
    nb = 4
    rng = np.random.default_rng(RNG_SEED)
    c = rng.normal(size=nb * nb)
    d, w = sphere_rule(8, 16)
    alpha = 0.7
    cp, sp = np.cos(-alpha), np.sin(-alpha)
    back = np.stack([cp * d[:, 0] - sp * d[:, 1], sp * d[:, 0] + cp * d[:, 1], d[:, 2]], -1)  # R_z(-alpha) d
    f_rot = hf.sh_basis(back, nb) @ c  # f(phi - alpha)
    ref = hf.sh_basis(d, nb).T @ (w * f_rot)
    np.testing.assert_allclose(hf.zrotate(c, alpha, nb), ref, atol=1e-13)
    # broadcasting: one angle per row
    cs = np.stack([c, 2 * c])
    np.testing.assert_allclose(hf.zrotate(cs, np.array([alpha, 0.0]), nb), np.stack([ref, 2 * c]), atol=1e-13)


def test_zh_rotate_equals_projection_of_rotated_zonal_function():
    nb = 5
    rng = np.random.default_rng(RNG_SEED)
    z = rng.normal(size=nb)
    n = rng.normal(size=3)
    n /= np.linalg.norm(n)
    d, w = sphere_rule(8, 16)
    t = d @ n
    f = sum(z[l] * math.sqrt((2 * l + 1) / (4 * math.pi)) * hf.legendre_P(l, t) for l in range(nb))
    ref = hf.sh_basis(d, nb).T @ (w * f)
    np.testing.assert_allclose(hf.zh_rotate(z, n, nb), ref, atol=1e-13)


def test_clamped_cosine_zh():
    z = hf.clamped_cosine_zh(6)
    np.testing.assert_allclose(z[:4], [0.886227, 1.023327, 0.495416, 0.0], atol=5e-7)
    pi = math.pi
    closed = [math.sqrt(pi) / 2, math.sqrt(3 * pi) / 3, math.sqrt(5 * pi) / 8, 0.0]
    np.testing.assert_allclose(z[:4], closed, atol=1e-14)
    # numeric: project max(Z, 0) onto y_l0 over the upper hemisphere (exact rule there)
    d, w = sphere_rule(10, 4, zmin=0.0)
    y = hf.sh_basis(d, 6)
    ref = [np.sum(w * d[:, 2] * y[:, hf.sh_index(l, 0)]) for l in range(6)]
    np.testing.assert_allclose(z, ref, atol=1e-14)
    assert abs(z[5]) < 1e-14 and abs(z[4]) > 1e-3  # odd l >= 3 vanish, even ones do not


@pytest.mark.parametrize("alpha", [0.1, 0.7, np.pi / 2, 2.5, np.pi])
def test_cap_zh_equals_quadrature(alpha):
    nb = 6
    z = hf.cap_zh(np.cos(alpha), nb)
    # brute force: the cap indicator integrated against y_l0 (GL in cos(theta) on the cap, phi trivially 2 pi)
    d, w = sphere_rule(16, 2, zmin=np.cos(alpha))
    y = hf.sh_basis(d, nb)
    ref = [np.sum(w * y[:, hf.sh_index(l, 0)]) for l in range(nb)]
    np.testing.assert_allclose(z, ref, atol=1e-13)
    if alpha == np.pi:  # whole sphere: only l = 0, 4 pi y_00 = 2 sqrt(pi)
        np.testing.assert_allclose(z, [2 * math.sqrt(math.pi)] + [0.0] * (nb - 1), atol=1e-14)


def test_seed_appendix_a_closed_forms():
    # Seed (003_7ffde676d1c99e20.txt), Appendix A, eq. A.1, cap subtending Theta:
    #   k=0: -sqrt(pi) (-1 + cos)                         correct
    #   k=1: 1/2 sqrt(3 pi) sin^2                          correct
    #   k=2: -1/2 sqrt(5 pi) cos (-1 + cos)(1 + cos)       correct
    #   k=3: -1/8 sqrt(7 pi) (-1 + cos)(1 + cos)(-1 + 5 cos)^2    WRONG
    # The correct k=3 term is -1/8 sqrt(7 pi) (-1 + cos)(1 + cos)(-1 + 5 cos^2)
    # (int_x^1 P_3 = (P_2(x) - P_4(x)) / 7 = (1 - x^2)(5 x^2 - 1) / 8): the printed square
    # belongs on the cosine, not on the bracket. E.g. at Theta = pi/2 (a hemisphere) the
    # printed form gives +sqrt(7 pi)/8 where the true value is -sqrt(7 pi)/8.
    pi = math.pi
    th = np.linspace(0.0, np.pi, 13)
    c, s = np.cos(th), np.sin(th)
    printed = np.stack([-math.sqrt(pi) * (-1 + c), 0.5 * math.sqrt(3 * pi) * s ** 2,
                        -0.5 * math.sqrt(5 * pi) * c * (-1 + c) * (1 + c),
                        -1 / 8 * math.sqrt(7 * pi) * (-1 + c) * (1 + c) * (-1 + 5 * c) ** 2], -1)
    corrected_k3 = -1 / 8 * math.sqrt(7 * pi) * (-1 + c) * (1 + c) * (-1 + 5 * c * c)
    z = hf.cap_zh(c, 4)
    np.testing.assert_allclose(z[:, :3], printed[:, :3], atol=1e-14)
    np.testing.assert_allclose(z[:, 3], corrected_k3, atol=1e-14)
    assert abs(z[6, 3] - printed[6, 3]) > 1.0  # Theta = pi/2: -0.586 vs +0.586
    np.testing.assert_allclose(z[6, 3], -math.sqrt(7 * pi) / 8, atol=1e-15)


def test_triple_product_against_brute_force():
    nb = 4
    g = hf.triple_product(nb)
    d, w = sphere_rule(30, 61)  # far more than the degree 9 needs
    y = hf.sh_basis(d, nb)
    ref = np.einsum("q,qi,qj,qk->ijk", w, y, y, y)
    np.testing.assert_allclose(g, ref, atol=1e-12)
    np.testing.assert_allclose(g, g.transpose(1, 0, 2), atol=0)
    np.testing.assert_allclose(g, g.transpose(0, 2, 1), atol=0)
    np.testing.assert_allclose(g[0], np.eye(nb * nb) / math.sqrt(4 * math.pi), atol=1e-14)
    # selection rule: Gamma vanishes unless the three bands satisfy the triangle inequality
    l_of = np.array([int(math.isqrt(i)) for i in range(nb * nb)])
    li, lj, lk = np.meshgrid(l_of, l_of, l_of, indexing="ij")
    assert np.all(g[(li > lj + lk) | ((li + lj + lk) % 2 == 1)] == 0)


def test_env_sh_projects_a_known_function():
    nb = 4
    rng = np.random.default_rng(RNG_SEED)
    c = rng.normal(size=(nb * nb, 3))
    d, w = sphere_rule(8, 16)
    radiance = hf.sh_basis(d, nb) @ c
    np.testing.assert_allclose(hf.env_sh(hf.sh_to_world(d), w, radiance, nb), c, atol=1e-13)


# --------------------------------------------------------------------------- wedge tables


@pytest.mark.parametrize("n_phi", [8, 32])
def test_env_wedges_with_zero_horizons_sum_to_upper_hemisphere(n_phi):
    nb = 4
    V = hf.visibility(np.zeros((1, n_phi)), hf.wedge_table(n_phi, nb, "env"), n_phi, nb, "env")[0]
    ref = np.zeros(nb * nb)
    t, w = gl(8, 0.0, 1.0)
    for l in range(nb):  # zonal: 2 pi K_l int_0^1 P_l
        ref[hf.sh_index(l, 0)] = 2 * math.pi * hf.sh_norm(l, 0) * np.sum(w * hf.legendre_P(l, t))
    np.testing.assert_allclose(V, ref, atol=1e-13)


def test_light_wedges_with_lowest_horizons_sum_to_whole_sphere():
    nb, n_phi = 4, 16
    V = hf.visibility(np.full((1, n_phi), -np.pi / 2), hf.wedge_table(n_phi, nb, "light"), n_phi, nb, "light")[0]
    np.testing.assert_allclose(V, [math.sqrt(4 * math.pi)] + [0.0] * (nb * nb - 1), atol=1e-13)


@pytest.mark.parametrize("kind", ["env", "light"])
def test_bilinear_lookup_at_grid_angles_returns_entries(kind):
    table = hf.wedge_table(16, 4, kind)
    lo, hi = hf.table_range(kind)
    rng = np.random.default_rng(RNG_SEED)
    a, b = rng.integers(0, 64, size=(2, 40))
    a[:2], b[:2] = (0, 63), (63, 0)  # the table's corners
    got = hf.table_lookup(table, lo + a * (hi - lo) / 63, lo + b * (hi - lo) / 63, kind)
    np.testing.assert_allclose(got, table[a, b], atol=1e-14)
    # halfway between entries: the mean of the four
    mid = hf.table_lookup(table, lo + (a + 0.5).clip(0, 63) * (hi - lo) / 63, lo + b * (hi - lo) / 63, kind)
    keep = a < 63
    np.testing.assert_allclose(mid[keep], 0.5 * (table[a, b] + table[np.minimum(a + 1, 63), b])[keep], atol=1e-14)


@pytest.mark.parametrize("kind,a,b", [("env", 10, 40), ("env", 63, 0), ("light", 5, 50), ("light", 40, 12)])
def test_single_wedge_entry_against_dense_quadrature(kind, a, b):
    nb, n_phi = 4, 8
    table = hf.wedge_table(n_phi, nb, kind)
    lo, hi = hf.table_range(kind)
    wl, wr = lo + a * (hi - lo) / 63, lo + b * (hi - lo) / 63
    dphi = 2 * np.pi / n_phi
    # (1) midpoint rule on a dense grid: phi, and sin(elevation) from the horizon up
    nphi, ns = 200, 1000
    phi = (np.arange(nphi) + 0.5) * dphi / nphi
    horizon = wl + (phi / dphi) * (wr - wl)
    if kind == "env":
        horizon = np.maximum(horizon, 0)
    ds = (1 - np.sin(horizon)) / ns
    s = np.sin(horizon)[:, None] + (np.arange(ns) + 0.5) * ds[:, None]
    y = hf.sh_from_angles(s, phi[:, None], nb)
    dense = np.einsum("p,psi->i", ds, y) * (dphi / nphi)
    np.testing.assert_allclose(table[a, b], dense, atol=1e-5)  # midpoint error ~ ns^-1.5 at s = 1
    # (2) the spec's literal recipe, Gauss-Legendre in phi and in sin(elevation), with many nodes
    p, wp = gl(32, 0.0, dphi)
    h = wl + (p / dphi) * (wr - wl)
    if kind == "env":
        h = np.maximum(h, 0)
    ss, ws = gl(256, np.sin(h), np.ones_like(h))
    y = hf.sh_from_angles(ss, np.broadcast_to(p[:, None], ss.shape), nb)
    literal = np.einsum("ps,psi->i", ws * wp[:, None], y)
    np.testing.assert_allclose(table[a, b], literal, atol=2e-8)  # sqrt(1 - s^2) at s = 1: only N^-3


def test_wedge_table_converged():
    fine = hf.wedge_table(8, 4, "light", nodes=48)
    np.testing.assert_allclose(hf.wedge_table(8, 4, "light"), fine, atol=1e-13)


@pytest.mark.parametrize("kind", ["env", "light"])
def test_visibility_equals_projection_of_piecewise_linear_horizon(kind):
    """Random horizons: the sum of rotated wedges against the direct projection of the visible set
    under the piecewise-linear horizon; they differ only by the bilinear table lookup."""
    nb, n_phi = 4, 16
    rng = np.random.default_rng(RNG_SEED)
    lo, hi = (0.0, 1.3) if kind == "env" else (-1.5, 1.5)
    h = rng.uniform(lo, hi, n_phi)
    table = hf.wedge_table(n_phi, nb, kind)
    V = hf.visibility(h[None], table, n_phi, nb, kind)[0]
    dphi = 2 * np.pi / n_phi
    parts = []
    for k in range(n_phi):
        p, wp = gl(16, k * dphi, (k + 1) * dphi)
        hl = h[k] + (p - k * dphi) / dphi * (h[(k + 1) % n_phi] - h[k])
        parts.append(project_horizon(p, wp, hl, nb, clamp=(kind == "env")))
    ref = np.sum(parts, axis=0)
    bound = table_error_bound(table, n_phi, nb)
    assert np.all(np.abs(V - ref) <= bound), (np.abs(V - ref), bound)
    assert bound.max() < 5e-3


# --------------------------------------------------------------------------- pyramid


def test_pyramid_level_sizes():
    cells = hf.level_cells(33, 17, 4)
    assert len(cells) == 22  # ceil(4 log2 33) + 1 = ceil(20.18) + 1
    assert cells[0] == (32, 16)
    assert cells[1] == (27, 13)  # 32 / 2^0.25 = 26.91, 16 / 2^0.25 = 13.45
    assert cells[4] == (16, 8) and cells[8] == (8, 4)
    assert cells[20] == (1, 1)  # 16 / 32 = 0.5 rounds (half away from zero) to 1
    assert cells[21] == (1, 1)  # max(1, .)
    levels = hf.pyramid(np.zeros((17, 33)), 4)
    assert [lv.shape for lv in levels] == [(e + 1, c + 1) for c, e in cells]
    # C's round(): 33 / 2 = 16.5 -> 17 (Python's round would give 16)
    assert hf.level_cells(34, 34, 1)[1] == (17, 17) and len(hf.level_cells(34, 34, 1)) == 7
    assert hf.level_cells(64, 64, 4)[4] == (32, 32) and len(hf.level_cells(64, 64, 4)) == 25  # 4 log2 64 exact
    assert hf.level_cells(2, 2, 4) == [(1, 1)] * 5


@pytest.mark.parametrize("ls,ratio", [(4, 1 / (1 - 2 ** -0.5)), (1, 4 / 3)])
def test_pyramid_memory_formula(ls, ratio):
    W = D = 257
    floats = hf.pyramid_floats(W, D, ls)
    assert abs(floats / (W * D * ratio) - 1) < 0.03, floats / (W * D)


def test_decimation_by_two_is_the_121_filter():
    # ls = 1, 32 cells -> 16: the tent of radius 2 input cells weighs (1, 2, 1)/4 inside and
    # (2, 1)/3 at the borders (the truncated tent renormalised)
    rng = np.random.default_rng(RNG_SEED)
    H = rng.normal(size=(33, 33))
    A = np.zeros((17, 33))
    for a in range(1, 16):
        A[a, 2 * a - 1:2 * a + 2] = [0.25, 0.5, 0.25]
    A[0, :2], A[16, 31:] = [2 / 3, 1 / 3], [1 / 3, 2 / 3]
    np.testing.assert_allclose(hf.pyramid(H, 1)[1], A @ H @ A.T, atol=1e-14)


def test_decimation_preserves_constants_and_skips_unchanged_axes():
    levels = hf.pyramid(np.full((13, 29), 3.25), 4)
    for lv in levels:
        np.testing.assert_allclose(lv, 3.25, atol=1e-14)
    # D = 3: E stays 2 then 1; where it stays, that axis is copied, not filtered
    rng = np.random.default_rng(RNG_SEED)
    H = rng.normal(size=(3, 9))
    cells = hf.level_cells(9, 3, 4)
    k = next(k for k in range(1, len(cells)) if cells[k][1] == cells[k - 1][1] and cells[k][0] == cells[k - 1][0])
    levels = hf.pyramid(H, 4)
    np.testing.assert_array_equal(levels[k], levels[k - 1])


def test_bspline_reproduces_constants_and_linear_functions():
    E, C = 8, 12
    W, D = 2 * C + 1, 3 * E + 1  # base units: u = 2 a, v = 3 b
    b, a = np.mgrid[0:E + 1, 0:C + 1].astype(float)
    lin = 1.5 * a - 0.75 * b + 2.0
    rng = np.random.default_rng(RNG_SEED)
    # interior: all four control points in bounds (1 <= a <= C - 1, likewise b)
    ua, vb = rng.uniform(1, C - 1, 200), rng.uniform(1, E - 1, 200)
    np.testing.assert_allclose(hf.level_sample(lin, W, D, 2 * ua, 3 * vb), 1.5 * ua - 0.75 * vb + 2.0, atol=1e-12)
    # a constant anywhere, also far outside (clamped indices)
    u, v = rng.uniform(-50, 80, 200), rng.uniform(-50, 80, 200)
    np.testing.assert_allclose(hf.level_sample(np.full((E + 1, C + 1), 4.0), W, D, u, v), 4.0, atol=1e-13)
    # beyond the border the terrain continues at the border's heights
    far = hf.level_sample(lin, W, D, np.full(5, 1e4), 3 * np.array([2.0, 3, 4, 5, 6]))
    np.testing.assert_allclose(far, 1.5 * C - 0.75 * np.array([2.0, 3, 4, 5, 6]) + 2.0, atol=1e-12)
    # at a control point the spline is (1, 4, 1)/6 per axis, not the value itself
    pts = rng.normal(size=(E + 1, C + 1))
    got = hf.level_sample(pts, W, D, 2 * 5.0, 3 * 4.0)
    wgt = np.array([1, 4, 1]) / 6
    np.testing.assert_allclose(got, wgt @ pts[3:6, 4:7] @ wgt, atol=1e-14)


# --------------------------------------------------------------------------- horizons


def test_spline_max_by_hand():
    w = np.array([0.1, 0.5, 0.2, 0.0])
    # knots (w_{m-1} + 4 w_m + w_{m+1}) / 6 with w_{-1} = w_0, w_4 = w_3: 1/6, 0.38333, 0.21667, 0.03333;
    # midpoints /48: 0.29375, 0.3375, 0.10625
    assert hf.spline_max(w, 4) == pytest.approx(2.3 / 6, abs=1e-15)
    # truncated to 2: [0.1, 0.5] (ends repeated): knots 1/6, 2.6/6, midpoint 14.4/48
    assert hf.spline_max(w, 2) == pytest.approx(2.6 / 6, abs=1e-15)
    assert hf.spline_max(w, 1) == pytest.approx(0.1, abs=1e-15)
    assert hf.spline_max(w, 0) == -np.pi / 2
    # a spike: the midpoints matter: [0, 1, 1, 0] -> knots 5/6, midpoint (0 + 23 + 23 + 0) / 48
    assert hf.spline_max(np.array([0.0, 1.0, 1.0, 0.0]), 4) == pytest.approx(46 / 48, abs=1e-15)
    # vectorised counts
    got = hf.spline_max(np.stack([w, w, w]), np.array([4, 2, 0]))
    np.testing.assert_allclose(got, [2.3 / 6, 2.6 / 6, -np.pi / 2], atol=1e-15)


def test_sample_plan():
    d, L = hf.sample_plan(22, 4, 2.0, 0.5)
    np.testing.assert_array_equal(L, [0] * 9 + list(range(1, 14)))  # m - round(4 * 2) = m - 8
    np.testing.assert_allclose(d[[0, 4, 8, 21]], [0.5, 1.0, 2.0, 0.5 * 2 ** 5.25], rtol=1e-15)
    assert d[4] == 1.0 and d[8] == 2.0  # sr^(4j) is an exact power of two
    _, L = hf.sample_plan(10, 4, 0.625, 1.0)  # ls lo = 2.5 rounds (half away from zero) to 3
    np.testing.assert_array_equal(L, [0, 0, 0, 0, 1, 2, 3, 4, 5, 6])
    _, L = hf.sample_plan(6, 1, -2.0, 1.0)  # a negative offset takes coarser levels, clamped at n - 1
    np.testing.assert_array_equal(L, [2, 3, 4, 5, 5, 5])


def test_horizon_of_one_vertex_by_hand():
    """The spec's recipe spelt out for one vertex and azimuth of a random field (ls = 4, lo = 2):
    sample m at d_m = s0 2^(m/4) along (cos phi, -sin phi) / (sx, sz) in base units, on level
    max(0, m - 8), w_m = atan(dH / d_m), then the knot / midpoint maximum, clamped at 0."""
    rng = np.random.default_rng(RNG_SEED)
    H = rng.normal(size=(9, 12))
    sx, sz, n_phi, (j0, i0, k) = 0.75, 0.5, 8, (4, 4, 1)
    levels = hf.pyramid(H, 4)
    n = len(levels)
    assert n == 16  # ceil(4 log2 12) + 1
    phi = 2 * np.pi * k / n_phi
    w = []
    for m in range(n):
        d, lv = 0.5 * 2 ** (m / 4), levels[max(0, m - 8)]
        here = hf.level_sample(lv, 12, 9, i0, j0)
        there = hf.level_sample(lv, 12, 9, i0 + d * np.cos(phi) / sx, j0 - d * np.sin(phi) / sz)
        w.append(math.atan((there - here) / d))
    e = [w[0]] + w + [w[-1]]
    knots = [(e[m] + 4 * e[m + 1] + e[m + 2]) / 6 for m in range(n)]
    mids = [(e[m] + 23 * e[m + 1] + 23 * e[m + 2] + e[m + 3]) / 48 for m in range(n - 1)]
    ref = max(max(knots), max(mids), 0.0)
    assert ref > 0
    assert hf.horizons(H, sx, sz, n_phi=n_phi)[j0, i0, k] == pytest.approx(ref, abs=1e-14)
    # a light r = 2 = d_8 away horizontally keeps d_m < 2: m <= 7 (strictly closer than the light)
    r = 2.0
    count = sum(0.5 * 2 ** (m / 4) < r for m in range(n))
    assert count == 8
    e = [w[0]] + w[:count] + [w[count - 1]]
    ref = max(max((e[m] + 4 * e[m + 1] + e[m + 2]) / 6 for m in range(count)),
              max((e[m] + 23 * e[m + 1] + 23 * e[m + 2] + e[m + 3]) / 48 for m in range(count - 1)))
    got = hf.horizons(H, sx, sz, n_phi=n_phi, light_xz=(i0 * sx + r, j0 * sz))[j0, i0, k]
    assert got == pytest.approx(ref, abs=1e-14)


def test_exact_horizon_of_one_vertex_by_hand():
    """Exact mode spelt out: the bilinear field at t = s0/2, s0, 3 s0/2 ... while inside the grid."""
    rng = np.random.default_rng(RNG_SEED + 1)
    H = rng.normal(size=(9, 12))
    sx, sz, n_phi = 0.8, 0.6, 8
    hz = hf.exact_horizons(H, sx, sz, n_phi)
    for (j0, i0, k) in [(4, 3, 1), (2, 8, 3), (0, 0, 0), (8, 11, 5), (7, 5, 6)]:
        phi = 2 * np.pi * k / n_phi
        best = -np.inf
        for step in range(1, 200):
            t = 0.3 * step  # s0 / 2 with s0 = min(0.8, 0.6)
            u, v = i0 + t * np.cos(phi) / sx, j0 - t * np.sin(phi) / sz
            if not (-1e-9 <= u <= 11 + 1e-9 and -1e-9 <= v <= 8 + 1e-9):
                break
            best = max(best, math.atan((bilinear_ref(H, np.clip(u, 0, 11), np.clip(v, 0, 8)) - H[j0, i0]) / t))
        assert hz[j0, i0, k] == pytest.approx(max(best, 0.0), abs=1e-14)
    # a light exactly 2 = 4 steps east of a vertex: only t < 2 counts (t = 0.5, 1, 1.5), the spike
    # under the light (bilinear 1.5 at t = 1.5, 3 at t = 2) is seen at 45 degrees, not atan(3/2)
    S = np.zeros((7, 9))
    S[3, 5] = 3.0
    lh = hf.exact_horizons(S, 1.0, 1.0, 4, light_xz=(5.0, 3.0))
    assert lh[3, 3, 0] == pytest.approx(np.pi / 4, abs=1e-15)


def test_flat_field_horizons_are_zero():
    H = np.zeros((9, 13))
    assert np.all(hf.horizons(H, 0.5, 0.7, n_phi=16) == 0)
    assert np.all(hf.exact_horizons(H, 0.5, 0.7, n_phi=16) == 0)
    # raised and light-truncated: still 0 where any sample counts
    Hc = np.full((9, 13), 2.5)
    assert np.abs(hf.horizons(Hc, 0.5, 0.7, n_phi=16)).max() < 1e-14
    lh = hf.horizons(H, 0.5, 0.7, n_phi=16, light_xz=(100.0, 100.0))
    assert np.all(lh == 0)


def test_vertex_normals_of_a_plane():
    sx, sz = 0.5, 2.0
    j, i = np.mgrid[0:6, 0:9].astype(float)
    H = 0.3 * i * sx - 0.2 * j * sz
    n = hf.vertex_normals(H, sx, sz)
    ref = np.array([-0.3, 1.0, 0.2]) / np.linalg.norm([-0.3, 1.0, 0.2])
    np.testing.assert_allclose(n, np.broadcast_to(ref, n.shape), atol=1e-15)
    # one-sided on the border: a parabola in x has the secant slope there
    P = (i * sx) ** 2
    n = hf.vertex_normals(P, sx, sz)
    slope = -n[..., 0] / n[..., 1]
    np.testing.assert_allclose(slope[:, 0], (P[0, 1] - P[0, 0]) / sx)
    np.testing.assert_allclose(slope[:, 4], 2 * 4 * sx)  # central differences are exact on a parabola


def cliff(W=21, D=21, x_wall=14, height=5.0):
    H = np.zeros((D, W))
    H[:, x_wall:] = height
    return H


def test_cliff_exact_horizon():
    """A wall of height h whose top edge is 10 units east of the receiver (bilinear ramp over the cell
    before it). Along phi the wall top is at t* = 10 / cos(phi); H(t)/t grows over the ramp and falls
    after it, so the marched maximum lies in [atan(h / (t* + s0/2)), atan(h / t*)], exactly atan(h/10)
    at phi = 0 where a step lands on t*. West (phi = pi) is flat: 0."""
    n_phi, h = 16, 5.0
    hz = hf.exact_horizons(cliff(height=h), 1.0, 1.0, n_phi)[10, 4]
    assert hz[0] == pytest.approx(math.atan(0.5), abs=1e-15)
    for k in (1, n_phi - 1):  # +-22.5 degrees, the ray meets the wall inside the grid
        ts = 10 / math.cos(2 * np.pi * k / n_phi)
        assert math.atan(h / (ts + 0.5)) - 1e-15 <= hz[k] <= math.atan(h / ts) + 1e-15
    assert hz[n_phi // 2] == 0


def test_cliff_pyramid_horizon():
    """The pyramid sees the same wall blurred: heights by the levels' B-splines (spacing ~ d 2^-lo at
    distance d), elevations by the 1D B-spline over samples 19% apart in distance (ls = 4), both
    approximating, so an isolated step comes out lower than the exact 0.4636: 0.318 at lo = 2, rising
    with the level offset to the level-0 limit (0.382, every sample on level 0 for lo >= 4)."""
    exact = math.atan(0.5)
    got = [hf.horizons(cliff(), 1.0, 1.0, lo=lo, n_phi=16)[10, 4] for lo in range(6)]
    east = np.array([g[0] for g in got])
    assert np.all(np.diff(east) >= 0) and np.all(east <= exact)
    assert 0.6 * exact < east[2] < 0.75 * exact
    assert east[4] == east[5]  # no finer level than 0
    for g in got:
        assert g[8] == 0 and g[1] == pytest.approx(g[15], abs=1e-14)  # flat to the west; symmetric about x


def test_azimuth_frame_of_the_horizon_search():
    # phi = 0 is world +x, phi = pi/2 is world -z (SH Y): a wall along the low-z edge blocks pi/2
    H = np.zeros((21, 21))
    H[:3, :] = 6.0
    for hz in (hf.exact_horizons(H, 1.0, 1.0, 8), hf.horizons(H, 1.0, 1.0, n_phi=8)):
        k = hz[10, 10]
        assert k[2] > 0.3 and k[6] == 0 and k[0] < k[2] and k[4] < k[2]


def test_light_horizons():
    H = cliff()
    # light directly above a vertex: no sample is closer than r_L = 0, nothing blocks
    for lh in (hf.horizons(H, 1.0, 1.0, n_phi=16, light_xz=(4.0, 10.0)),
               hf.exact_horizons(H, 1.0, 1.0, 16, light_xz=(4.0, 10.0))):
        np.testing.assert_array_equal(lh[10, 4], -np.pi / 2)
    # light between the receiver and the wall (r_L = 4): the wall is ignored, the flat part counts
    for lh in (hf.horizons(H, 1.0, 1.0, n_phi=16, light_xz=(8.0, 10.0)),
               hf.exact_horizons(H, 1.0, 1.0, 16, light_xz=(8.0, 10.0))):
        np.testing.assert_array_equal(lh[10, 4], 0.0)
    # a receiver on top of the wall sees negative elevations down the cliff (not clamped for lights)
    # (from the wall's top edge i = 14, west, light at x = 0: steps t < 14, the last at 13.5 sees -5)
    lh = hf.exact_horizons(H, 1.0, 1.0, 16, light_xz=(0.0, 10.0))
    assert lh[10, 14, 8] == pytest.approx(math.atan(-5 / 13.5), abs=1e-15)
    # light far away: every sample counts; clamped at 0 it is the environment horizon
    for f in (lambda **kw: hf.horizons(H, 1.0, 1.0, n_phi=16, **kw),
              lambda **kw: hf.exact_horizons(H, 1.0, 1.0, 16, **kw)):
        np.testing.assert_array_equal(np.maximum(f(light_xz=(1e6, 1e6)), 0), f())


# --------------------------------------------------------------------------- shading


def random_env(n=300, seed=RNG_SEED):
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return d, np.full(n, 4 * np.pi / n), rng.uniform(0.2, 2.0, size=(n, 3)) * (1 + d[:, :1] + 0.5 * d[:, 1:2] ** 2)


@pytest.mark.parametrize("nb", [4, 6])
def test_flat_field_env_irradiance(nb):
    """Flat ground: every horizon is 0, V is the projection of the upper hemisphere, C the clamped
    cosine about Z, and E_env = sum_i L_i T_i with T_i = int y_i V_nb C_nb (V_nb, C_nb the nb-band
    truncations). The reference computes V_nb, C_nb and T by its own quadrature (upper hemisphere
    split exactly at Z = 0), independently of the tables, the rotation and Gamma."""
    env = random_env()
    E, _ = hf.shade(np.zeros((5, 7)), (1.0, -2.0, 3.0), (4.0, 6.0), 1.0, env, n_phi=16, nb=nb)
    up, wu = sphere_rule(12, 4 * nb, zmin=0.0)
    yu = hf.sh_basis(up, nb)
    Vnb = yu.T @ wu  # int over the upper hemisphere of y_j
    Cnb = yu.T @ (wu * up[:, 2])  # int max(Z, 0) y_k
    d, w = sphere_rule(2 * nb, 4 * nb)
    y = hf.sh_basis(d, nb)
    T = y.T @ (w * (y @ Vnb) * (y @ Cnb))
    L = hf.sh_basis(hf.world_to_sh(env[0]), nb).T @ (env[2] * env[1][:, None])
    ref = T @ L
    np.testing.assert_allclose(E, np.broadcast_to(ref, E.shape), rtol=1e-12)
    # constant radiance 1 given by an exact rule: E = pi exactly (sum_l v_l z_l = pi/2 + pi/2: the
    # hemisphere's even l >= 2 and the cosine's odd l >= 3 coefficients vanish)
    E1, _ = hf.shade(np.zeros((3, 3)), (0, 0, 0), (1.0, 1.0), 1.0, (hf.sh_to_world(d), w, np.ones((len(w), 3))),
                     n_phi=8, nb=nb)
    np.testing.assert_allclose(E1, np.pi, rtol=1e-12)


def test_flat_field_light_directly_above():
    """Light above the centre vertex: V^light is the whole sphere, T = C, E = Le sum_l z^cap_l z^cos_l
    (both zonal about Z) with cos(alpha) = sqrt(1 - (r / delta)^2)."""
    nb, Le = 4, np.array([3.0, 2.0, 1.0])
    centre, radius = np.array([5.0, 4.0, 5.0]), 1.0
    _, (E,) = hf.shade(np.zeros((11, 11)), (0, 0, 0), (10.0, 10.0), 1.0, None, [(centre, radius, Le)], n_phi=16, nb=nb)
    ref = Le * np.dot(hf.cap_zh(math.sqrt(1 - (radius / 4.0) ** 2), nb), hf.clamped_cosine_zh(nb))
    np.testing.assert_allclose(E[5, 5], ref, rtol=1e-12)
    # inside the light (its centre below the ground): its surface emits outwards only, as in the
    # reference renderer, so the receiver gets nothing; the vertices outside the sphere do get light
    inside = ((1.0, -0.2, 1.0), 0.5, Le)
    _, (E,) = hf.shade(np.zeros((3, 3)), (0, 0, 0), (2.0, 2.0), 1.0, None, [inside], n_phi=8, nb=nb)
    assert (E[1, 1] == 0).all() and (E[0, 0] > 0).all()


def smooth_field(n, seed=RNG_SEED):
    rng = np.random.default_rng(seed)
    j, i = np.mgrid[0:n, 0:n].astype(float)
    H = np.zeros((n, n))
    for _ in range(4):
        ci, cj, s, a = rng.uniform(0, n - 1), rng.uniform(0, n - 1), rng.uniform(1.5, 4), rng.uniform(-2, 4)
        H += a * np.exp(-((i - ci) ** 2 + (j - cj) ** 2) / (2 * s * s))
    return H


@pytest.mark.parametrize("exact", [False, True])
def test_rotation_by_90_degrees_commutes(exact):
    """Rotating a square field by +90 degrees about the SH Z axis (world (x, z) -> (z, -x) about the
    grid's centre, heights np.rot90, env directions and light centre alike) rotates E by np.rot90:
    the azimuth set maps to itself (n_phi divisible by 4), the tent and B-spline are symmetric."""
    n = 17
    H = smooth_field(n)
    d, w, rad = random_env(200)
    size, c0 = (8.0, 8.0), 4.0  # grid centre at (4, 4)
    light = (np.array([5.5, 3.0, 2.0]), 0.7, np.array([4.0, 3.0, 2.0]))

    def rot(p):  # world (x, y, z) -> (c0 + (z - c0), y, c0 - (x - c0)), or about the origin for directions
        p = np.asarray(p, float)
        return np.stack([p[..., 2], p[..., 1], -p[..., 0]], -1)

    lc = light[0] - [c0, 0, c0]
    light_r = (rot(lc) + [c0, 0, c0], light[1], light[2])
    kw = dict(n_phi=16 if not exact else 32, nb=4, exact=exact)
    E, (El,) = hf.shade(H, (0, 0, 0), size, 1.0, (d, w, rad), [light], **kw)
    Er, (Elr,) = hf.shade(np.rot90(H), (0, 0, 0), size, 1.0, (rot(d), w, rad), [light_r], **kw)
    np.testing.assert_allclose(Er, np.rot90(E), rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(Elr, np.rot90(El), rtol=1e-10, atol=1e-12)
    assert np.ptp(E) > 0.1 and np.ptp(El) > 0.01  # the scene is not trivially uniform


def test_single_direction_env_against_ray_marched_visibility():
    """One env texel (direction s, solid angle dw, radiance 1), exact horizons, n_phi = 64, nb = 4.
    Reference: the visibility found by marching rays through the bilinear field in world space (step
    s0/2 to the border, at a dense set of world azimuths), projected onto SH, then the same SH product:
    E_ref = dw sum_ij y_i(s) Gamma_ijk V_ref_j C_k. The twin differs from it only by (a) the horizon
    interpolated linearly between the 64 azimuths and (b) the bilinear table lookup. (a) moves V_j by at
    most max|y_j| times the solid angle between the two horizon curves (measured below, int |sin h_lin -
    sin h_true| dphi); (b) by table_error_bound. E then moves by at most dw sum_j |g_j| |dV_j| with
    g_j = sum_ik y_i(s) Gamma_ijk C_k. The comparison with the unprojected truth dw V(s) max(n.s, 0) is
    not made: nb = 4 blurs a single direction over the whole sphere."""
    nb, n_phi, n = 4, 64, 25
    j, i = np.mgrid[0:n, 0:n].astype(float)
    H = 6.0 * np.exp(-((i - 15) ** 2 + (j - 14) ** 2) / 18.0)  # a hill east (and a little +z) of the receiver
    pi_, pj = 8, 12
    e_sun, psi_sun = 0.45, 0.3  # elevation; world azimuth in the x-z plane, x = cos, z = sin
    s = np.array([math.cos(e_sun) * math.cos(psi_sun), math.sin(e_sun), math.cos(e_sun) * math.sin(psi_sun)])
    dw = 0.01
    E, _ = hf.shade(H, (0, 0, 0), (n - 1.0, n - 1.0), 1.0, (s[None], np.array([dw]), np.ones((1, 3))),
                    n_phi=n_phi, nb=nb, exact=True)

    # brute-force ray march at world azimuths psi: 16 Gauss nodes per 1/64 of the circle
    t = 0.5 * np.arange(1, 80)

    def march(psi):
        u, v = pi_ + t[None] * np.cos(psi)[:, None], pj + t[None] * np.sin(psi)[:, None]
        inside = (u >= -1e-9) & (u <= n - 1 + 1e-9) & (v >= -1e-9) & (v <= n - 1 + 1e-9)
        rise = np.where(inside, bilinear_ref(H, np.clip(u, 0, n - 1), np.clip(v, 0, n - 1)) - H[pj, pi_], -np.inf)
        return np.maximum(np.arctan(rise / t).max(axis=1), 0.0)  # env: the horizon is never below 0

    nodes = [gl(16, 2 * np.pi * k / n_phi, 2 * np.pi * (k + 1) / n_phi) for k in range(n_phi)]
    psi = np.concatenate([p for p, _ in nodes])
    wpsi = np.concatenate([q for _, q in nodes])
    h_true = march(psi)
    # world azimuth psi is SH azimuth -psi (SH Y = world -z)
    V_ref = project_horizon(-psi, wpsi, h_true, nb, clamp=True)

    # the twin's horizons equal the march at the 64 azimuths (world psi_k = -phi_k): frame check
    h_twin = hf.exact_horizons(H, 1.0, 1.0, n_phi)[pj, pi_]
    np.testing.assert_allclose(h_twin, march(-2 * np.pi * np.arange(n_phi) / n_phi), atol=1e-14)

    k_of = (psi // (2 * np.pi / n_phi)).astype(int)
    frac = psi / (2 * np.pi / n_phi) - k_of
    h_sample = march(2 * np.pi * np.arange(n_phi) / n_phi)  # at world psi_k
    h_lin = h_sample[k_of] + frac * (h_sample[(k_of + 1) % n_phi] - h_sample[k_of])
    area = np.sum(wpsi * np.abs(np.sin(h_lin) - np.sin(h_true)))
    ymax = np.abs(hf.sh_basis(sphere_rule(20, 40)[0], nb)).max(axis=0)
    dV = ymax * area + table_error_bound(hf.wedge_table(n_phi, nb, "env"), n_phi, nb)

    C = hf.cosine_lobes(hf.vertex_normals(H, 1.0, 1.0)[pj, pi_], nb)
    g = np.einsum("i,ijk,k->j", hf.sh_basis(hf.world_to_sh(s), nb), hf.triple_product(nb), C)
    E_ref = dw * g @ V_ref
    bound = dw * np.abs(g) @ dV
    assert abs(E[pj, pi_, 0] - E_ref) <= bound, (E[pj, pi_, 0], E_ref, bound)
    # and the check has teeth: the bound is small against the shadow's effect
    E_open = dw * g @ hf.visibility(np.zeros((1, n_phi)), hf.wedge_table(n_phi, nb, "env"), n_phi, nb, "env")[0]
    assert bound < 0.1 * abs(E_open - E_ref), (bound, E_open, E_ref)
    np.testing.assert_allclose(E[pj, pi_], E[pj, pi_, 0])
