"""The `heightfield` method (docs/heightfield.md) through the library: the
hard cases of the method (flat fields, cliffs, lights below, inside, above
and far from the terrain, borders, odd and non-square sizes, NaN heights, SH
rotation invariance, dynamic heights) and the method against the reference
renderer on real env maps from ../shared/data. The kernels against the float64
twin are in test_heightfield_kernels.py."""

from __future__ import annotations

import numpy as np
import pytest

import penumbra as pn
from penumbra import procedural
from penumbra.methods.heightfield import HeightFieldHandle
from penumbra.errors import InputError
from penumbra.heightfield import make_terrain
from penumbra.imageio import read_envmap
from penumbra.metrics import compare


class Rig:
    """A scene with one height field (as triangles too), an env map and lights."""

    def __init__(self, ctx, heights, env, size=None, origin=None, height_scale=1.0, lights=(), camera=None,
                 albedo=None):
        d, w = heights.shape
        size = size or (float(w - 1), float(d - 1))
        origin = origin or (-0.5 * size[0], 0.0, -0.5 * size[1])
        self.ctx, self.env = ctx, env
        self.field = HeightFieldHandle(ctx, heights, origin=origin, size=size, height_scale=height_scale,
                                       albedo=albedo)
        self.mesh = self.field.mesh()
        self.scene = pn.Scene(ctx)
        self.scene.set_envmap(env)
        self.instance = self.scene.add(self.mesh, None, pn.Material(albedo=(1.0, 1.0, 1.0)))
        self.scene.attach(self.instance, self.field)
        if lights:
            self.scene.set_lights(lights)
        self.camera = camera
        if camera is not None:
            self.scene.set_camera(camera)
        self.scene.commit()

    def read(self, what="env", light=0, **params):
        return pn.Renderer(self.ctx, "heightfield", **params).read_output(self.scene, what, self.instance, light)

    def image(self, method, **params):
        w, h = self.camera.resolution
        gb, img = pn.GBuffer(self.ctx, w, h), pn.Image(self.ctx, w, h)
        self.scene.render_gbuffer(gb)
        pn.Renderer(self.ctx, method, **params).execute(self.scene, gb, img)
        return img.read()[..., :3], gb.read("instance") == self.instance


@pytest.fixture(scope="module")
def constant_env(ctx):
    return pn.EnvMap(ctx, procedural.constant((1.0, 0.8, 0.6)), face_size=16, irradiance_face_size=16)


@pytest.fixture(scope="module")
def sky_env(ctx):
    return pn.EnvMap(ctx, procedural.sky(128, 64, sun_direction=(0.5, 0.5, 0.3)), face_size=32,
                     irradiance_face_size=32)


@pytest.fixture(scope="module")
def sunny_env(ctx, shared_data):
    return pn.EnvMap(ctx, read_envmap(shared_data / "envmaps" / "immenstadter_horn_1k_polyhaven.hdr"), face_size=64,
                     irradiance_face_size=32)


@pytest.fixture(scope="module")
def overcast_env(ctx, shared_data):
    return pn.EnvMap(ctx, read_envmap(shared_data / "envmaps" / "kiara_1_dawn_1k_polyhaven.hdr"), face_size=64,
                     irradiance_face_size=32)


def top_camera(extent: float, res: int = 48) -> pn.Camera:
    return pn.Camera(position=(0.0, 3.0 * extent, 0.35 * extent), look_at=(0.0, 0.0, 0.0), fov_deg=28.0,
                     resolution=(res, res))


# ------------------------------------------------------------------ flat fields


@pytest.mark.parametrize("exact", [0, 1])
def test_flat_field_has_zero_horizons_and_equals_unshadowed(ctx, sky_env, exact):
    """A perfectly flat field (at any altitude): every horizon is exactly 0
    and the image equals the unshadowed method's (the unoccluded part is the
    exact irradiance). With the sun texels lit as directional lights (the
    default) the sun is exact too, where the irradiance map interpolates it:
    measured 0.09% apart; bound 0.2%."""
    rig = Rig(ctx, np.full((21, 26), 0.3, np.float32), sky_env, size=(5.0, 4.0), camera=top_camera(4.0))
    assert (rig.read("env_horizons", exact_horizon=exact) == 0.0).all()
    ref, fg = rig.image("unshadowed")
    assert fg.sum() > 500
    img, _ = rig.image("heightfield", exact_horizon=exact, sun_threshold=0)
    np.testing.assert_allclose(img[fg], ref[fg], rtol=2e-5, atol=1e-6)
    img, _ = rig.image("heightfield", exact_horizon=exact)
    np.testing.assert_allclose(img[fg], ref[fg], rtol=2e-3)


def test_flat_field_all_sh_product_is_within_sh_truncation(ctx, sky_env):
    """The seed's all-SH product (exact_unoccluded = 0, no sun split) on a
    flat field differs from the exact irradiance only by SH truncation:
    measured 0.6% / 4.7% / 0.6% of the largest irradiance at 3 / 4 / 6 bands
    under a sky with a sun (4 bands is the worst: the clamped cosine's l = 3
    term is 0 while the hemisphere's is not); bounds 1.5x those."""
    rig = Rig(ctx, np.zeros((9, 9), np.float32), sky_env)
    exact = rig.read("env", sun_threshold=0)[..., :3]
    errs = []
    for bands in (3, 4, 6):
        sh = rig.read("env", exact_unoccluded=0, sun_threshold=0, bands=bands)[..., :3]
        errs.append(np.abs(sh - exact).max() / exact.max())
    assert errs[0] < 0.009 and errs[1] < 0.07 and errs[2] < 0.009, errs
    assert errs[1] > 0.01, errs  # the split (default) is what makes flat fields exact


# ------------------------------------------------------------------ cliffs


def test_cliffs_and_vertical_walls(ctx, sky_env):
    """City blocks (vertical walls between streets and roofs): every vertex
    finite and non-negative; street vertices are darker than roofs; no
    vertex brighter than the unoccluded upper-hemisphere irradiance (terrain
    only takes light away; the kernel clamps SH ringing of the blocked part,
    which lifted street vertices up to 17% above it before)."""
    h = make_terrain("city_blocks", 41, 37, seed=3)
    rig = Rig(ctx, h, sky_env, size=(8.0, 7.2), height_scale=3.0)
    env = rig.read("env")[..., :3]
    flat = Rig(ctx, np.zeros_like(h), sky_env, size=(8.0, 7.2)).read("env")[..., :3]
    n = rig.read("normals")[..., :3]
    assert np.isfinite(env).all() and (env >= 0).all()
    up = n[..., 1] > 0.999  # roofs and streets (flat tops), not the wall vertices
    low = (h < 0.05) & up
    high = (h > 0.7) & up
    assert low.any() and high.any()
    assert env[low].mean() < 0.9 * env[high].mean()
    assert (env[up] <= flat[up] * (1 + 1e-5) + 1e-6).all(), (env[up] / flat[up]).max()


# ------------------------------------------------------------------ lights


def light_row(pos, radius=0.2, radiance=(20.0, 20.0, 20.0)):
    return [*pos, radius, *radiance]


def test_light_below_the_surface_gives_nothing(ctx, constant_env):
    rig = Rig(ctx, np.zeros((15, 15), np.float32), constant_env, lights=[light_row((0.0, -2.0, 0.0))])
    assert (rig.read("light")[..., :3] == 0.0).all()


def test_light_inside_the_terrain(ctx, constant_env):
    """A light buried in a hill (1 unit up inside a cone 3 units high): the
    flat ground around the cone cannot see it. All outputs are finite and
    >= 0. With the horizon test (light_visibility = 1, the default) the
    ground gets nothing (measured 5e-9 of what the same light gives it
    without the cone; bound 1e-4); with the seed's SH wedges it gets 32%
    (bound 45%): 4 bands smear the small cap over azimuths and elevations
    the horizon does not block."""
    h = make_terrain("cones", 33, 33, count=1, radius=0.45, height=1.0)
    lights = [light_row((0.0, 1.0, 0.0), 0.1)]
    rig = Rig(ctx, h, constant_env, size=(8.0, 8.0), height_scale=3.0, lights=lights)
    open_rig = Rig(ctx, np.zeros_like(h), constant_env, size=(8.0, 8.0), lights=lights)
    far = h == 0.0
    assert far.sum() > 100
    for mode, bound in ((1, 1e-4), (0, 0.45)):
        light = rig.read("light", light_visibility=mode)[..., 0]
        assert np.isfinite(light).all() and (light >= 0).all()
        open_ground = open_rig.read("light", light_visibility=mode)[..., 0]
        ratio = light[far].sum() / open_ground[far].sum()
        assert ratio < bound, (mode, ratio)


def test_light_exactly_over_a_vertex(ctx, constant_env):
    """Light straight above vertex (8, 8) of a flat field: no azimuth is
    defined there, nothing blocks, the result is finite and largest there,
    and matches the irradiance of a small spherical light, Le π (r/d)²:
    exactly with the horizon test (bound 1e-4), within SH truncation with the
    seed's SH wedges (measured 6.2% high at 4 bands, 3.1% low at 6; bounds
    8% and 4%)."""
    r, height, le = 0.2, 3.0, 20.0
    rig = Rig(ctx, np.zeros((17, 17), np.float32), constant_env, lights=[light_row((0.0, height, 0.0), r, (le,) * 3)])
    want = le * (r / height) ** 2  # albedo 1: L_o = E / π = Le (r/d)^2 at normal incidence
    for mode, bands, bound in ((1, 4, 1e-4), (0, 4, 0.08), (0, 6, 0.04)):
        light = rig.read("light", bands=bands, light_visibility=mode)[..., 0]
        assert np.isfinite(light).all()
        assert np.unravel_index(np.argmax(light), light.shape) == (8, 8)
        assert abs(light[8, 8] - want) < bound * want, (mode, bands, light[8, 8] / want)


def test_very_far_and_very_near_lights(ctx, constant_env):
    """A light 10^4 units away is negligible and culled (exact zeros, no
    NaN). Receivers inside a light's sphere get nothing from it (its surface
    emits outwards only, as in the reference renderer and Mitsuba), in both
    light modes; receivers just outside it are lit, finitely."""
    flat = np.zeros((9, 9), np.float32)
    far = Rig(ctx, flat, constant_env, lights=[light_row((1e4, 1e4, 0.0), 0.2, (1.0, 1.0, 1.0))])
    assert (far.read("light")[..., :3] == 0.0).all()
    near = Rig(ctx, flat, constant_env, lights=[light_row((0.0, 0.5, 0.0), 2.5, (1.0, 1.0, 1.0))])
    d = np.hypot(*np.meshgrid(np.arange(9) - 4.0, np.arange(9) - 4.0))
    inside = np.hypot(d, 0.5) < 2.5
    assert inside.any() and (~inside).any()
    for mode in (0, 1):
        lit = near.read("light", light_visibility=mode)[..., 0]
        assert np.isfinite(lit).all()
        assert (lit[inside] == 0).all() and (lit[~inside] > 0).all(), mode


def test_far_light_not_culled_without_threshold(ctx, constant_env):
    """light_threshold = 0 keeps a distant light: tiny but positive."""
    rig = Rig(ctx, np.zeros((9, 9), np.float32), constant_env,
              lights=[light_row((30.0, 40.0, 0.0), 0.2, (1.0, 1.0, 1.0))])
    lit = rig.read("light", light_threshold=0.0)[..., 0]
    assert (lit > 0).all() and lit.max() < 1e-4


# ------------------------------------------------------------------ borders, sizes


def test_border_policy_terrain_continues_at_border_height(ctx, constant_env):
    """A uniform slope rising along +x: beyond the high border the terrain
    continues flat at the border's height, so a vertex on that border sees
    an uphill horizon of 0 in the exact mode; the pyramid's B-spline
    (approximating, clamped) lowers the border vertex itself a little, which
    leaves it a small horizon (measured 0.081 rad = 17% of the slope's angle;
    bound 25%). A vertex a few steps inside sees the slope."""
    w, d = 24, 9
    slope = 0.5
    h = np.tile(slope * np.arange(w, dtype=np.float32), (d, 1))
    rig = Rig(ctx, h, constant_env)
    for exact, border in ((1, 1e-6), (0, 0.25 * np.arctan(slope))):
        hz = rig.read("env_horizons", exact_horizon=exact, azimuths=8)  # azimuth 0 = +x
        assert (np.abs(hz[:, -1, 0]) <= border).all(), (exact, hz[:, -1, 0])
        inner = hz[4, w - 6, 0]
        assert 0.6 * np.arctan(slope) < inner <= np.arctan(slope) + 1e-3, (exact, inner)


@pytest.mark.parametrize("shape", [(2, 2), (2, 9), (13, 3), (31, 17)])
def test_non_square_and_odd_sizes(ctx, sky_env, shape):
    h = make_terrain("fbm", shape[1], shape[0], seed=1)
    rig = Rig(ctx, h, sky_env, height_scale=2.0, lights=[light_row((0.0, 3.0, 0.0))])
    for what in ("env", "light", "total"):
        out = rig.read(what)
        assert out.shape == (*shape, 4) and np.isfinite(out).all() and (out[..., :3] >= 0).all()
    np.testing.assert_allclose(rig.read("total")[..., :3], rig.read("env")[..., :3] + rig.read("light")[..., :3],
                               rtol=1e-5, atol=1e-7)


def test_nan_heights_are_refused(ctx):
    h = np.zeros((5, 6), np.float32)
    h[2, 3] = np.nan
    with pytest.raises(InputError, match=r"non-finite.*row 2, column 3"):
        HeightFieldHandle(ctx, h)
    field = HeightFieldHandle(ctx, np.zeros((5, 6), np.float32))
    with pytest.raises(InputError, match="non-finite"):
        field.set_heights(h)


def test_method_without_height_fields_is_an_error(ctx, sky_env):
    scene = pn.Scene(ctx)
    scene.set_envmap(sky_env)
    scene.set_camera(top_camera(1.0, 8))
    box = procedural.box()
    scene.add(pn.Mesh(ctx, box.vertices, box.faces, box.normals))
    scene.commit()
    gb, img = pn.GBuffer(ctx, 8, 8), pn.Image(ctx, 8, 8)
    scene.render_gbuffer(gb)
    with pytest.raises(pn.PenumbraError, match="no height field"):
        pn.Renderer(ctx, "heightfield").execute(scene, gb, img)


# ------------------------------------------------------------------ invariance, dynamics


def test_rotating_env_and_terrain_together_changes_nothing(ctx):
    """Terrain turned by 90 degrees about +y (h' = h.T[::-1]) under the env
    map turned the same way (rotation_deg = 90): per-vertex results map onto
    each other. The azimuths (a multiple of 4) and the grid map exactly; what
    differs is the env's cube resampling (measured 0.4% of the largest value;
    bound 2%)."""
    sky = procedural.sky(128, 64, sun_direction=(0.6, 0.45, 0.2))
    h = make_terrain("fbm", 25, 25, seed=4)
    out = []
    for heights, rot in ((h, 0.0), (np.ascontiguousarray(h.T[::-1]), 90.0)):
        env = pn.EnvMap(ctx, sky, face_size=32, irradiance_face_size=32, rotation_deg=rot)
        rig = Rig(ctx, heights, env, size=(6.0, 6.0), height_scale=2.0)
        out.append(rig.read("env", azimuths=32)[..., :3])
    turned = out[0].transpose(1, 0, 2)[::-1]
    err = np.abs(out[1] - turned).max() / out[0].max()
    assert err < 0.02, err


def test_new_heights_rebuild_the_pyramid(ctx, sky_env):
    """Fully dynamic: new heights change the result at once, the old heights
    give back the old result exactly (nothing baked, nothing stale)."""
    a = make_terrain("sine_grating", 20, 20)
    b = make_terrain("egg_tray", 20, 20)
    rig = Rig(ctx, a, sky_env, height_scale=3.0)
    renderer = pn.Renderer(ctx, "heightfield")
    first = renderer.read_output(rig.scene, "env", rig.instance)
    rig.field.set_heights(b)
    second = renderer.read_output(rig.scene, "env", rig.instance)
    rig.field.set_heights(a)
    third = renderer.read_output(rig.scene, "env", rig.instance)
    assert np.abs(first - second).max() > 0.05 * first.max()
    np.testing.assert_array_equal(first, third)


# ------------------------------------------------------------------ against the reference


def terrain_scene_error(ctx, env, heights, height_scale, lights=(), res=64, **params):
    size = (8.0, 8.0)
    rig = Rig(ctx, heights, env, size=size, height_scale=height_scale, lights=lights,
              camera=pn.Camera(position=(0.0, 7.0, 7.5), look_at=(0.0, 0.3, 0.0), fov_deg=50.0,
                               resolution=(res, res)))
    ref, fg = rig.image("reference", face_size=32, sun_supersampling=4, light_samples=12, background=0)
    img, _ = rig.image("heightfield", background=0, **params)
    unsh, _ = rig.image("unshadowed", background=0)
    return compare(ref, img, fg)["nrmse"], compare(ref, unsh, fg)["nrmse"]


def test_against_reference_sunny_fbm(ctx, sunny_env):
    """fBm mountains under a sunny sky (immenstadter_horn) against the
    ray-cast reference, 64x64 terrain pixels: measured NRMSE 0.032
    (unshadowed 0.070); bound 1.2x measured."""
    err, base = terrain_scene_error(ctx, sunny_env, make_terrain("fbm", 49, 49, seed=2, frequency=2.0), 5.0)
    assert err < 0.038 and err < 0.5 * base, (err, base)


def test_against_reference_dawn_grating_with_light(ctx, overcast_env):
    """A sine grating under a soft dawn sky (kiara_1_dawn) plus one spherical
    light above it: measured NRMSE 0.040 (unshadowed, which has no lights:
    0.120); bound 1.3x measured."""
    h = make_terrain("sine_grating", 49, 49, period=0.25)
    err, base = terrain_scene_error(ctx, overcast_env, h, 1.5, lights=[light_row((0.0, 1.5, 0.0), 0.15, (30,) * 3)])
    assert err < 0.052 and err < 0.5 * base, (err, base)


@pytest.mark.parametrize("terrain,scale", [("fbm", 2.0), ("city_blocks", 3.0)])
def test_mesh_normals_are_the_method_normals(ctx, constant_env, terrain, scale):
    """The triangle mesh the library builds for a height field (G-buffer,
    reference, Mitsuba export) and the heightfield method's own per-vertex
    normals come from one rule, central differences of the world heights
    (host C for the mesh, the hf_normals kernel for the method): they agree
    to float rounding, so the two cannot drift apart. The mesh's vertices are
    the placed heights."""
    h = make_terrain(terrain, 33, 29, seed=5)
    rig = Rig(ctx, h, constant_env, size=(6.0, 5.0), height_scale=scale)
    v, f, n = rig.mesh.geometry()
    assert n is not None and f.shape == (2 * 32 * 28, 3)
    method = rig.read("normals")[..., :3].reshape(-1, 3)
    np.testing.assert_allclose(n, method, atol=2e-6)
    np.testing.assert_allclose(v[:, 1].reshape(29, 33), scale * h, rtol=1e-6, atol=1e-6)


def early_exit_outputs(build_options, heights, env, lights):
    """Every per-vertex output of a frame on `heights` built with `build_options`."""
    ctx = pn.Context(f"build_options={build_options}") if build_options else pn.Context()
    env = pn.EnvMap(ctx, env, face_size=32, irradiance_face_size=32)
    rig = Rig(ctx, heights, env, size=(6.0, 5.0), height_scale=1.5, lights=lights)
    out = {what: rig.read(what) for what in ("env_horizons", "env", "total")}
    out["light"] = rig.read("light", 0)
    out["interpolating"] = rig.read("env_horizons", reconstruction=1)  # control points overshoot: no bound, no exit
    out["interpolating_light"] = rig.read("light", 0, reconstruction=1)
    return out


def test_early_exits_change_no_bit():
    """The searches' early exits (env: no later candidate can raise the clamped maximum; lights:
    the disc already hidden or certainly clear) give the same floats as searching every sample,
    also with the interpolating reconstruction (whose levels overshoot the heights); with the
    bound on the heights lowered by a build option they do not."""
    heights = make_terrain("fbm", 53, 45, seed=5)
    env = procedural.sky(128, 64, sun_direction=(0.5, 0.5, 0.3))
    lights = [light_row((0.4, 1.2, -0.3), radius=0.2)]
    full = early_exit_outputs("-DHF_EARLY_EXIT=0", heights, env, lights)
    fast = early_exit_outputs("", heights, env, lights)
    wrong = early_exit_outputs("-DHF_EXIT_BOUND=-1.0f", heights, env, lights)
    for what in full:
        np.testing.assert_array_equal(fast[what].view(np.uint32), full[what].view(np.uint32), err_msg=what)
    assert not np.array_equal(wrong["env_horizons"], full["env_horizons"])
    assert not np.array_equal(wrong["light"], full["light"])


def test_border_paths_change_no_bit():
    """The row sampler's paths for taps clamped at the border (every lane's taps at one border
    column; taps clamped at one border only, as a shifted window) give the same floats as the
    column-by-column path; a build that reads the outside column one value in, or lets a spread
    of 16 columns (lane 0 rounding down, lane 15 not) take the window, does not."""
    heights = make_terrain("fbm", 61, 47, seed=9)
    env = procedural.sky(128, 64, sun_direction=(0.5, 0.5, 0.3))
    lights = [light_row((0.4, 1.2, -0.3), radius=0.2)]
    slow = early_exit_outputs("-DHF_OUTSIDE_FAST=0 -DHF_STRADDLE_FAST=0", heights, env, lights)
    fast = early_exit_outputs("", heights, env, lights)
    for what in slow:
        np.testing.assert_array_equal(fast[what].view(np.uint32), slow[what].view(np.uint32), err_msg=what)
    for wrong in ("-DHF_BORDER_TEST=1", "-DHF_BORDER_TEST=2"):
        assert not np.array_equal(early_exit_outputs(wrong, heights, env, lights)["env_horizons"],
                                  slow["env_horizons"]), wrong


def test_sun_shortcuts_change_only_rounding():
    """The sun texels' shortcuts (every disc below the horizon bound: nothing; every disc above
    it: the texels without a horizon, or S n) agree with the texel-by-texel loop on sharp cones,
    where the Catmull-Rom horizon between azimuths overshoots its four points (the bound widens
    their range by 1/8 of it); a build whose margin lets the shortcuts cut into the discs does not."""
    heights = make_terrain("cones", 45, 41)
    env = procedural.sky(128, 64, sun_direction=(0.6, 0.12, -0.2))
    lights = [light_row((0.4, 1.2, -0.3), radius=0.2)]
    loop = early_exit_outputs("-DHF_SUN_MARGIN=1e30f", heights, env, lights)
    fast = early_exit_outputs("", heights, env, lights)
    wrong = early_exit_outputs("-DHF_SUN_MARGIN=-0.2f", heights, env, lights)
    np.testing.assert_array_equal(fast["env_horizons"], loop["env_horizons"])
    scale = loop["env"].max()
    np.testing.assert_allclose(fast["env"], loop["env"], rtol=1e-5, atol=1e-6 * scale)
    assert np.abs(wrong["env"] - loop["env"]).max() > 1e-3 * scale


def sun_scene_error(shared_data, build_options, azimuths):
    """NRMSE against the reference of cones under the sunny sky (immenstadter_horn, sun 35
    degrees up), kernels built with `build_options`."""
    ctx = pn.Context(f"build_options={build_options}") if build_options else pn.Context()
    env = pn.EnvMap(ctx, read_envmap(shared_data / "envmaps" / "immenstadter_horn_1k_polyhaven.hdr"), face_size=64,
                    irradiance_face_size=32)
    return terrain_scene_error(ctx, env, make_terrain("cones", 49, 49), 2.0, azimuths=azimuths)[0]


@pytest.mark.parametrize("azimuths", [16, 32])
def test_sun_horizon_cubic_beats_linear(shared_data, azimuths):
    """The sun texels' horizon between azimuths as the Catmull-Rom cubic through four of them
    against the linear interpolation of two (a build option), on cones whose horizons change
    quickly with the azimuth: measured NRMSE cubic / linear 0.0620 / 0.0658 at 16 azimuths,
    0.0518 / 0.0539 at 32 (docs/heightfield.md, Sun texels); bound: the cubic at most 0.98x."""
    cubic = sun_scene_error(shared_data, "", azimuths)
    linear = sun_scene_error(shared_data, "-DHF_SUN_LINEAR=1", azimuths)
    assert cubic < 0.98 * linear, (cubic, linear)
