"""The `heightfield` kernels against the float64 twin (tests/heightfield64.py):
pyramid horizons, exact horizons, normals, SH visibility, the environment
pass in the seed's all-SH form and with penumbra's additions (the exact
unoccluded split, sun texels as directional lights), and the spherical-light
pass with SH wedges and with the horizon test. Small odd, non-square fields
and every quality knob (level step, level offset, azimuths, bands).

Tolerances (float32 kernels against float64): horizons 3e-5 rad (atan of
B-spline differences of heights ~1 summed in float32 over 16 taps);
visibility 2e-5 of its l = 0 coefficient; irradiance 2e-4 of the largest
value (float32 sums over the SH matrix and table interpolation) except where
the kernel reads the upper-hemisphere irradiance map (bilinear between its
vertex-grid samples) instead of summing the texels: 3e-3 there, the map's
interpolation error at face 32 measured 1.1e-3."""

from __future__ import annotations

import heightfield64 as hf64
import numpy as np
import pytest

import penumbra as pn
from penumbra import procedural
from penumbra.methods.heightfield import HeightFieldHandle
from penumbra.heightfield import make_terrain

HORIZON_ATOL = 3e-5
VIS_RTOL = 2e-5
DEFAULT_BANDS = 6  # the renderer's default `bands` (capi/src/methods/heightfield.c)
DEFAULT_AZIMUTHS = 32  # and its default `azimuths`
E_RTOL = 2e-4
E_MAP_RTOL = 3e-3


class Case:
    def __init__(self, ctx, env, heights, size, height_scale, lights=(), origin=(-1.0, 0.2, -0.5)):
        self.heights = np.asarray(heights, np.float32)
        d, w = self.heights.shape
        self.size, self.height_scale, self.origin = size, height_scale, origin
        self.sx, self.sz = size[0] / (w - 1), size[1] / (d - 1)
        self.field = HeightFieldHandle(ctx, self.heights, origin=origin, size=size, height_scale=height_scale)
        self.scene = pn.Scene(ctx)
        self.scene.set_envmap(env)
        self.instance = self.scene.add(self.field.mesh())
        self.scene.attach(self.instance, self.field)
        if lights:
            self.scene.set_lights([[*c, r, *le] for c, r, le in lights])
        self.scene.commit()
        self.ctx, self.env, self.lights = ctx, env, list(lights)
        self.H = height_scale * self.heights.astype(np.float64)

    def read(self, what, light=0, **params):
        return pn.Renderer(self.ctx, "heightfield", **params).read_output(self.scene, what, self.instance, light)

    def light_xz(self, k):
        c = self.lights[k][0]
        return (c[0] - self.origin[0], c[2] - self.origin[2])

    def twin_horizons(self, ls=4, lo=4.0, n_phi=DEFAULT_AZIMUTHS, light=None, exact=False, interpolating=False):
        lxz = None if light is None else self.light_xz(light)
        if exact:
            return hf64.exact_horizons(self.H, self.sx, self.sz, n_phi, lxz)
        levels = hf64.pyramid(self.H, ls, interpolating)
        return hf64.horizons(self.H, self.sx, self.sz, ls, lo, n_phi, lxz, levels)

    def env_records(self, sun_threshold=0.0):
        dirs, omega = self.env.cube_directions()
        rad = self.env.cube_radiance().reshape(-1, 3).astype(np.float64)
        dirs, omega = dirs.reshape(-1, 3).astype(np.float64), omega.reshape(-1).astype(np.float64)
        sun = np.zeros(len(rad), bool)
        if sun_threshold > 0:
            lum = rad.mean(1)
            sun = lum >= sun_threshold * (lum * omega).sum() / omega.sum()
        return dirs, omega, rad, sun


@pytest.fixture(scope="module")
def sky(ctx):
    return pn.EnvMap(ctx, procedural.sky(128, 64, sun_direction=(0.5, 0.45, -0.3)), face_size=32,
                     irradiance_face_size=32)


@pytest.fixture(scope="module")
def case(ctx, sky):
    h = make_terrain("fbm", 19, 14, seed=5, frequency=2.0)
    lights = [((0.3, 1.2, 0.4), 0.15, (4.0, 3.0, 2.0)), ((-0.8, 0.95, 1.1), 0.05, (30.0, 30.0, 30.0))]
    return Case(ctx, sky, h, size=(2.6, 2.0), height_scale=0.9, lights=lights)


@pytest.fixture(scope="module")
def cliff_case(ctx, sky):
    h = make_terrain("city_blocks", 15, 17, blocks=3, seed=2)
    return Case(ctx, sky, h, size=(2.0, 2.3), height_scale=0.8, lights=[((0.1, 0.9, 0.6), 0.1, (5.0, 5.0, 5.0))])


# ------------------------------------------------------------------ horizons


@pytest.mark.parametrize("ls,lo,n_phi,interp", [(4, 2.0, 32, 0), (4, 2.0, 32, 1), (1, 0.0, 8, 1), (2, 1.0, 16, 0),
                                                (3, 2.5, 12, 1), (4, 4.0, 24, 0)])
def test_pyramid_horizons(case, ls, lo, n_phi, interp):
    """Both reconstructions: the seed's approximating B-spline (0, default)
    and the interpolating one (1: control points solved per level)."""
    got = case.read("env_horizons", level_step=ls, level_offset=lo, azimuths=n_phi, reconstruction=interp)
    want = case.twin_horizons(ls, lo, n_phi, interpolating=bool(interp))
    np.testing.assert_allclose(got, want, atol=HORIZON_ATOL, rtol=0)
    assert want.max() > 0.2  # the terrain does shadow


@pytest.mark.parametrize("interp", [0, 1])
def test_pyramid_horizons_wide_field(ctx, sky, interp):
    """The environment's search runs 8 vertices of a row per work-item and
    loads each tap row as one 16-value window where the window lies inside
    the level (column by column near its border): 61 columns (7 full groups
    and one of 5) make most fine-level samples take the window path, which
    the 19-column case above reaches only at its first columns."""
    h = make_terrain("fbm", 61, 9, seed=3, frequency=3.0)
    c = Case(ctx, sky, h, size=(6.0, 0.9), height_scale=0.6)
    got = c.read("env_horizons", reconstruction=interp)
    want = c.twin_horizons(interpolating=bool(interp))
    np.testing.assert_allclose(got, want, atol=HORIZON_ATOL, rtol=0)
    assert want.max() > 0.2


@pytest.mark.parametrize("light", [0, 1])
def test_pyramid_light_horizons(case, light):
    got = case.read("light_horizons", light=light)
    want = case.twin_horizons(light=light)
    np.testing.assert_allclose(got, want, atol=HORIZON_ATOL, rtol=0)
    assert (want < 0).any()  # negative elevations are kept for lights


def test_exact_horizons(case, cliff_case):
    for c in (case, cliff_case):
        got = c.read("env_horizons", exact_horizon=1, azimuths=48)
        np.testing.assert_allclose(got, c.twin_horizons(n_phi=48, exact=True), atol=HORIZON_ATOL, rtol=0)
    got = case.read("light_horizons", light=0, exact_horizon=1, azimuths=48)
    np.testing.assert_allclose(got, case.twin_horizons(n_phi=48, light=0, exact=True), atol=HORIZON_ATOL, rtol=0)


def test_cliff_horizons(cliff_case):
    """Vertical walls: the pyramid search follows the twin there too (the
    interpolating B-spline overshoots beside steps; same in both)."""
    for interp in (0, 1):
        got = cliff_case.read("env_horizons", reconstruction=interp)
        np.testing.assert_allclose(got, cliff_case.twin_horizons(interpolating=bool(interp)), atol=HORIZON_ATOL, rtol=0)


def test_normals(case):
    got = case.read("normals")[..., :3]
    np.testing.assert_allclose(got, hf64.vertex_normals(case.H, case.sx, case.sz), atol=2e-6)


# ------------------------------------------------------------------ visibility


# (6, 256): the most azimuths the kernel takes; its wedge angles come from a
# rotation recurrence over the azimuths, so rounding accumulates along them.
@pytest.mark.parametrize("nb,n_phi", [(3, 8), (4, 32), (5, 16), (6, 32), (6, 256)])
def test_env_visibility(case, nb, n_phi):
    got = case.read("env_visibility", bands=nb, azimuths=n_phi)
    want = hf64.visibility(case.twin_horizons(n_phi=n_phi), hf64.wedge_table(n_phi, nb, "env"), n_phi, nb, "env")
    np.testing.assert_allclose(got, want, atol=VIS_RTOL * np.abs(want[..., 0]).max(), rtol=0)


def test_light_visibility(case):
    got = case.read("light_visibility", light=1)  # the default bands
    nb = DEFAULT_BANDS
    n_phi = DEFAULT_AZIMUTHS
    want = hf64.visibility(case.twin_horizons(light=1), hf64.wedge_table(n_phi, nb, "light"), n_phi, nb, "light")
    np.testing.assert_allclose(got, want, atol=VIS_RTOL * np.abs(want[..., 0]).max(), rtol=0)


# ------------------------------------------------------------------ environment pass


def twin_env_paper(c, nb=4, n_phi=DEFAULT_AZIMUTHS, exact=False, sun_threshold=0.0):
    dirs, omega, rad, sun = c.env_records(sun_threshold)
    hz = c.twin_horizons(n_phi=n_phi, exact=exact)
    V = hf64.visibility(hz, hf64.wedge_table(n_phi, nb, "env"), n_phi, nb, "env")
    normals = hf64.vertex_normals(c.H, c.sx, c.sz)
    L = hf64.env_sh(dirs, omega, np.where(sun[:, None], 0.0, rad), nb)  # sun texels are lit apart
    return hf64.shade_env(V, normals, L, nb), V, normals, L, hz, (dirs, omega, rad, sun)


@pytest.mark.parametrize("nb,n_phi,exact", [(4, 32, False), (3, 16, False), (6, 24, False), (4, 32, True)])
def test_env_pass_all_sh(case, nb, n_phi, exact):
    """exact_unoccluded = 0, sun_threshold = 0: the seed's formula."""
    got = case.read("env", bands=nb, azimuths=n_phi, exact_horizon=int(exact), exact_unoccluded=0,
                    sun_threshold=0)[..., :3]
    want = twin_env_paper(case, nb, n_phi, exact)[0] / np.pi  # white albedo
    np.testing.assert_allclose(got, want, atol=E_RTOL * want.max(), rtol=0)


def disc_above(e, h, r):
    x = np.clip((e - h) / np.maximum(r, 1e-6), -1.0, 1.0)
    return np.clip(0.5 + (x * np.sqrt(1 - x * x) + np.arcsin(x)) / np.pi, 0.0, 1.0)


def horizon_cubic(hz, k, t):
    """The Catmull-Rom cubic through the horizons at azimuths k - 1 .. k + 2
    (wrapping; hz's last axis) at k + t, k and t of equal shape."""
    n_phi = hz.shape[-1]
    p0, p1, p2, p3 = (hz[..., (k + j) % n_phi] for j in (-1, 0, 1, 2))
    return p1 + 0.5 * t * (p2 - p0 + t * (2 * p0 - 5 * p1 + 4 * p2 - p3 + t * (3 * (p1 - p2) + p3 - p0)))


def twin_env_split(c, sun_threshold):
    """E = clamp(E_paper + E_up(n) - H^T M C, 0, E_up(n)) + the sun texels
    (disc share above the horizon, the Catmull-Rom cubic through the four
    nearest azimuths, times n.s), with
    E_up the exact sum over the non-sun texels above the horizontal plane."""
    nb, n_phi = DEFAULT_BANDS, DEFAULT_AZIMUTHS
    e_paper, V, normals, L, hz, (dirs, omega, rad, sun) = twin_env_paper(c, nb, n_phi, sun_threshold=sun_threshold)
    table = hf64.wedge_table(n_phi, nb, "env")
    Hup = hf64.zrotate(np.broadcast_to(table[0, 0], (n_phi, nb * nb)), 2 * np.pi * np.arange(n_phi) / n_phi,
                       nb).sum(0)
    M = np.einsum("ic,ijk->cjk", L, hf64.triple_product(nb))
    C = hf64.cosine_lobes(normals, nb)
    uc = np.einsum("j,cjk,...k->...c", Hup, M, C)
    sky_rad = np.where((sun | (dirs[:, 1] <= 0))[:, None], 0.0, rad)
    e_up = np.maximum(normals @ dirs.T, 0.0) @ (sky_rad * omega[:, None])
    V_sum = np.einsum("...j,cjk,...k->...c", V, M, C)
    e = np.clip(np.minimum(V_sum + e_up - uc, e_up), 0.0, None)
    if sun.any():
        sd, so, sr = dirs[sun], omega[sun], rad[sun]
        phi = np.mod(np.arctan2(-sd[:, 2], sd[:, 0]), 2 * np.pi) * n_phi / (2 * np.pi)
        k = np.minimum(phi.astype(int), n_phi - 1)
        t = phi - k
        horizon = horizon_cubic(hz, k, t)
        vis = disc_above(np.arcsin(sd[:, 1]), horizon, np.sqrt(so / np.pi))
        e = e + np.einsum("...s,...s,sc->...c", np.maximum(normals @ sd.T, 0.0), vis, sr * so[:, None])
    return e, sun.sum()


@pytest.mark.parametrize("sun_threshold", [0.0, 50.0])
def test_env_pass_default(case, sun_threshold):
    """The default environment pass: exact unoccluded part, sun texels as
    directional lights (none with sun_threshold = 0)."""
    got = case.read("env", sun_threshold=sun_threshold)[..., :3]
    want, suns = twin_env_split(case, sun_threshold)
    want /= np.pi
    assert (suns > 0) == (sun_threshold > 0)
    np.testing.assert_allclose(got, want, atol=E_MAP_RTOL * want.max(), rtol=0)


# ------------------------------------------------------------------ light pass


@pytest.mark.parametrize("light,nb", [(0, 4), (1, 4), (0, 6)])
def test_light_pass_sh(case, light, nb):
    """light_visibility = 0: the seed's SH wedges and cap, threshold 0."""
    got = case.read("light", light=light, bands=nb, light_visibility=0, light_threshold=0)[..., :3]
    centre, radius, le = case.lights[light]
    n_phi = DEFAULT_AZIMUTHS
    V = hf64.visibility(case.twin_horizons(light=light), hf64.wedge_table(n_phi, nb, "light"), n_phi, nb, "light")
    normals = hf64.vertex_normals(case.H, case.sx, case.sz)
    points = hf64.vertex_points(case.H, case.origin, case.sx, case.sz)
    want = hf64.shade_light(V, normals, points, centre, radius, le, nb)
    # The kernel skips vertices whose cap lies wholly below the tangent plane (exactly 0 there).
    vec = np.asarray(centre) - points
    dist = np.linalg.norm(vec, axis=-1)
    below = (normals * vec).sum(-1) / dist <= -radius / dist
    want[below] = 0.0
    want /= np.pi
    np.testing.assert_allclose(got, want, atol=E_RTOL * want.max(), rtol=0)


def sphere_irradiance(c, sin2):
    """Lagarde and de Rousiers' clipped sphere-light irradiance (unit radiance)."""
    c = np.asarray(c, np.float64)
    full = np.where(c > 0, np.pi * sin2 * c, 0.0)
    sn = np.sqrt(np.maximum(1 - c * c, 0.0))
    x = np.sqrt(np.maximum(1 / sin2 - 1, 0.0))
    y = np.clip(-x * c / np.maximum(sn, 1e-7), -1, 1)
    sy = sn * np.sqrt(1 - y * y)
    part = np.maximum((c * np.arccos(y) - x * sy) * sin2 + np.arctan2(sy, x), 0.0)
    return np.where(c * c > sin2, full, part)


def horizon_along(c, phi, limit, ls=4, lo=4.0):
    """Pyramid horizons of every vertex at per-vertex azimuths phi (D, W), only d_m < limit."""
    D, W = c.H.shape
    levels = hf64.pyramid(c.H, ls)
    d, L = hf64.sample_plan(len(levels), ls, lo, min(c.sx, c.sz))
    j, i = np.mgrid[0:D, 0:W].astype(np.float64)
    du, dv = np.cos(phi) / c.sx, -np.sin(phi) / c.sz
    omega = np.empty((D, W, len(d)))
    for m in range(len(d)):
        k = L[m]
        h = hf64.level_sample(levels[k], W, D, i + d[m] * du, j + d[m] * dv)
        omega[..., m] = np.arctan((h - hf64.level_sample(levels[k], W, D, i, j)) / d[m])
    count = (d[None, None, :] < limit[..., None]).sum(-1)
    return hf64.spline_max(omega, count)


@pytest.mark.parametrize("light", [0, 1])
def test_light_pass_horizon_test(case, light):
    """light_visibility = 1 (default): exact clipped cap irradiance times the
    disc share above the horizon at three azimuths across the disc."""
    got = case.read("light", light=light, light_threshold=0)[..., :3]
    centre, radius, le = case.lights[light]
    normals = hf64.vertex_normals(case.H, case.sx, case.sz)
    points = hf64.vertex_points(case.H, case.origin, case.sx, case.sz)
    rel = np.asarray(centre) - points
    dist = np.linalg.norm(rel, axis=-1)
    sin2 = (radius / dist) ** 2
    alpha = np.arcsin(np.sqrt(sin2))
    irr = sphere_irradiance((normals * rel).sum(-1) / dist, sin2)
    limit = np.hypot(rel[..., 0], rel[..., 2])
    elev = np.arcsin(rel[..., 1] / dist)
    phi = np.arctan2(-rel[..., 2], rel[..., 0])
    spread = np.minimum(alpha / np.maximum(np.cos(elev), 1e-3), np.pi)
    vis = sum(disc_above(elev, horizon_along(case, phi + 0.5 * spread * q, limit), alpha) for q in (-1, 0, 1)) / 3
    want = (irr * vis)[..., None] * np.asarray(le) / np.pi
    assert (dist > radius).all() and (vis < 0.5).any() and (vis > 0.99).any()
    np.testing.assert_allclose(got, want, atol=E_RTOL * want.max(), rtol=0)


def test_total_is_env_plus_lights(case):
    r = pn.Renderer(case.ctx, "heightfield")
    total = r.read_output(case.scene, "total", case.instance)[..., :3]
    parts = r.read_output(case.scene, "env", case.instance)[..., :3] + sum(
        r.read_output(case.scene, "light", case.instance, k)[..., :3] for k in range(2))
    np.testing.assert_allclose(total, parts, rtol=1e-6, atol=1e-7)
