"""The `isg` method end to end (capi/src/methods/isg.c): the C method with its
lobe fit, the ISG table and attached sphere sets, against closed forms and
the reference renderer on scenes of our own making: the floor under a
sphere in a constant env (analytic irradiance), an occluder that moves
(the spheres follow the instance), K = 1, N = 1, k_s = 0 against k_s > 0,
a black env, parameters and scene files."""

from __future__ import annotations

import math

import numpy as np
import pytest

from penumbra import BACKGROUND, Camera, Context, EnvMap, GBuffer, Image, Material, Mesh, PenumbraError, Renderer, Scene, procedural
from penumbra.methods.isg import SphereSet
from penumbra.metrics import rel_rms

W, H = 40, 30


def build(ctx, env_rgb, occluder_xf, spheres=None, material=None, face_size=16, build_count=None):
    """A floor (y = 0) and a unit-sphere occluder; its sphere set: the caller's
    ``spheres`` or ``build_count`` spheres built from the mesh."""
    env = EnvMap(ctx, env_rgb, face_size=face_size, irradiance_face_size=8)
    scene = Scene(ctx)
    scene.set_envmap(env)
    floor = procedural.plane((8.0, 8.0), 1)
    ball = procedural.sphere(1.0, 3)
    fm, bm = Mesh(ctx, floor.vertices, floor.faces), Mesh(ctx, ball.vertices, ball.faces, ball.normals)
    floor_id = scene.add(fm, np.eye(4), material or Material(albedo=(0.6, 0.6, 0.6)))
    ball_id = scene.add(bm, occluder_xf, Material(albedo=(0.7, 0.5, 0.4)))
    sset = SphereSet.build(bm, build_count) if build_count else SphereSet.from_spheres(ctx, spheres or [[0, 0, 0, 1.0]])
    scene.attach(ball_id, sset)
    scene.set_camera(Camera(position=(0.0, 5.0, 5.0), look_at=(0.0, 0.0, 0.0), fov_deg=60.0, resolution=(W, H)))
    scene.commit()
    gb = GBuffer(ctx, W, H)
    scene.render_gbuffer(gb)
    return {"env": env, "scene": scene, "gb": gb, "meshes": (fm, bm), "set": sset, "ids": (floor_id, ball_id)}


def render(ctx, s, method="isg", **params):
    img = Image(ctx, W, H)
    Renderer(ctx, method, **params).execute(s["scene"], s["gb"], img)
    return img.read()[..., :3].astype(np.float64)


def translate(x, y, z, scale=1.0):
    m = np.eye(4) * scale
    m[3, 3] = 1.0
    m[:3, 3] = (x, y, z)
    return m


def test_floor_under_a_sphere_in_a_constant_env_is_analytic(ctx):
    """E(p) = pi L (1 - sin^2(alpha) cos(theta)) on the floor when the sphere's
    cap is above the horizon (alpha its angular radius, theta its angle from
    the normal)."""
    s = build(ctx, procedural.constant(1.0, 64, 32), translate(0.0, 1.6, 0.0, 0.5))
    got = render(ctx, s, lobes=32, patch_grid=16)
    pos = s["gb"].read("position")[..., :3].astype(np.float64)
    ids = s["gb"].read("instance")
    floor = ids == s["ids"][0]
    v = np.array([0.0, 1.6, 0.0]) - pos[floor]
    d = np.linalg.norm(v, axis=1)
    e = math.pi * (1.0 - (0.5 / d) ** 2 * (v[:, 1] / d))
    want = 0.6 / math.pi * e
    near = d < 3.0  # the shadowed part of the floor
    assert near.sum() > 50
    err = np.abs(got[floor][:, 0] - want)
    assert np.max(err[near]) < 0.05 * want.max(), np.max(err[near])
    assert rel_rms(want[near, None], got[floor][near, :1]) < 0.02


@pytest.mark.parametrize("grid", [16, 31])
def test_shared_grid_through_the_library(ctx, grid):
    """shared_grid through the C method (its host-built lobe cube): the floor under a sphere in a constant env
    against the closed form, as the per-lobe windows are checked above; with a sunny sky, close to the
    per-lobe image and to the reference; out-of-range values refused."""
    s = build(ctx, procedural.constant(1.0, 64, 32), translate(0.0, 1.6, 0.0, 0.5))
    got = render(ctx, s, lobes=32, patch_grid=16, shared_grid=grid)
    pos = s["gb"].read("position")[..., :3].astype(np.float64)
    floor = s["gb"].read("instance") == s["ids"][0]
    v = np.array([0.0, 1.6, 0.0]) - pos[floor]
    d = np.linalg.norm(v, axis=1)
    want = 0.6 / math.pi * math.pi * (1.0 - (0.5 / d) ** 2 * (v[:, 1] / d))
    near = d < 3.0
    assert np.max(np.abs(got[floor][near, 0] - want[near])) < 0.05 * want.max()
    assert rel_rms(want[near, None], got[floor][near, :1]) < 0.02
    sky = build(ctx, procedural.sky(64, 32, sun_radiance=20.0, sun_angular_radius_deg=6.0),
                translate(0.3, 1.2, 0.0, 0.6))
    fl = sky["gb"].read("instance") == sky["ids"][0]
    shared, per_lobe = render(ctx, sky, shared_grid=grid), render(ctx, sky, shared_grid=0)
    ref = render(ctx, sky, "reference", face_size=16)
    assert rel_rms(ref[fl], shared[fl]) < 0.08
    assert rel_rms(per_lobe[fl], shared[fl]) < 0.03
    assert not np.array_equal(shared, per_lobe)  # the switch does reach the kernel
    for bad in (-1, 32):
        with pytest.raises(PenumbraError, match="shared_grid"):
            Renderer(ctx, "isg", shared_grid=bad)


def test_moving_the_occluder_moves_the_shadow_and_isg_tracks_the_reference(ctx):
    env = procedural.sky(64, 32, sun_radiance=20.0, sun_angular_radius_deg=6.0)
    a = build(ctx, env, translate(-0.8, 1.2, 0.0, 0.6))
    b = build(ctx, env, translate(0.8, 1.2, 0.0, 0.6))
    ia, ib = render(ctx, a), render(ctx, b)
    floor = a["gb"].read("instance") == a["ids"][0]
    assert np.abs(ia[floor] - ib[floor]).max() > 0.05 * ia[floor].max()
    ref = render(ctx, b, "reference", face_size=16)
    fb = b["gb"].read("instance") == b["ids"][0]
    assert rel_rms(ref[fb], ib[fb]) < 0.08  # K = 32 lobes of a sky with a sun, 64 x 32 map


def test_k1_n1_black_env_and_specular_switch(ctx):
    s = build(ctx, procedural.sky(64, 32), translate(0.0, 1.3, 0.0, 0.7), build_count=1,
              material=Material(albedo=(0.5, 0.5, 0.5), specular=0.4, shininess=200.0))
    one = render(ctx, s, lobes=1)
    assert np.isfinite(one).all() and (one >= 0).all()
    assert s["set"].info()["count"] == 1
    spec = render(ctx, s)
    diffuse_only = build(ctx, procedural.sky(64, 32), translate(0.0, 1.3, 0.0, 0.7), build_count=1)
    floor = s["gb"].read("instance") == s["ids"][0]
    assert (spec[floor] >= render(ctx, diffuse_only)[floor] * (0.5 / 0.6) - 1e-6).all()  # specular only adds
    black = build(ctx, procedural.constant(0.0, 16, 8), translate(0.0, 1.3, 0.0, 0.7))
    assert not render(ctx, black).any()


def test_background_and_parameters(ctx):
    s = build(ctx, procedural.constant(0.5, 32, 16), translate(0.0, 1.3, 0.0, 0.7))
    bg = s["gb"].read("instance") == BACKGROUND
    assert bg.any()
    np.testing.assert_allclose(render(ctx, s, background=1)[bg], 0.5, rtol=1e-5)
    assert not render(ctx, s, background=0)[bg].any()
    with pytest.raises(PenumbraError, match="patch_grid"):
        Renderer(ctx, "isg", patch_grid=25)
    with pytest.raises(PenumbraError, match="lobes"):
        Renderer(ctx, "isg", lobes=0)


def test_sphere_tree_gives_the_flat_loops_image(ctx):
    """The method's sphere tree (built in C every frame, sphere_tree = 1) against the
    flat loop (sphere_tree = 0): the same image, bit for bit, with 200 spheres spread
    over the floor (the tree culls most of them for most lobes), attached to a moved
    and scaled instance; and again after the instance moves (the tree is rebuilt)."""
    rng = np.random.default_rng(11)
    c = np.c_[rng.uniform(-3, 3, 200), rng.uniform(-0.5, 1.5, 200), rng.uniform(-3, 3, 200)]
    spheres = np.c_[c, rng.uniform(0.03, 0.25, 200)].tolist()
    s = build(ctx, procedural.sky(64, 32, sun_radiance=20.0, sun_angular_radius_deg=6.0),
              translate(0.2, 0.6, -0.3, 0.8), spheres=spheres,
              material=Material(albedo=(0.5, 0.5, 0.5), specular=0.3, shininess=300.0))
    tree, flat = render(ctx, s, sphere_tree=1), render(ctx, s, sphere_tree=0)
    np.testing.assert_array_equal(tree, flat)
    floor = s["gb"].read("instance") == s["ids"][0]
    assert tree[floor].min() < 0.7 * np.median(tree[floor])  # the spheres do cast shadows
    s["scene"].set_transform(s["ids"][1], translate(-0.5, 0.7, 0.4, 0.9))
    s["scene"].commit()
    np.testing.assert_array_equal(render(ctx, s, sphere_tree=1), render(ctx, s, sphere_tree=0))



def test_lod_cut_through_the_library(ctx):
    """The `lod` parameter through the C method: lod 0 (the default) is the exact
    walk's image bit for bit (the flat loop's); a cut only removes visible
    patches (a node's cap holds its spheres' caps), so it only darkens; against
    the reference its error stays within 0.3 points of the exact walk's at
    lod 4 (measured: 7.96 % exact, 7.97 % at lod 4, 8.26 % at lod 8, 9.18 % at
    16; the bound is 3x the lod-4 change; docs/isg.md section 9), with the per-lobe windows
    (shared_grid 0); the shared hemisphere grid's marking takes no cut (the flat loop's image with the
    cut at 16); out-of-range values are refused."""
    rng = np.random.default_rng(11)
    c = np.repeat(np.c_[rng.uniform(-3, 3, 25), rng.uniform(0.2, 1.5, 25), rng.uniform(-3, 3, 25)], 8, axis=0)
    spheres = np.c_[c + rng.uniform(-0.2, 0.2, c.shape), rng.uniform(0.03, 0.1, len(c))].tolist()
    s = build(ctx, procedural.sky(64, 32, sun_radiance=20.0, sun_angular_radius_deg=6.0),
              translate(0.0, 0.0, 0.0, 1.0), spheres=spheres,
              material=Material(albedo=(0.5, 0.5, 0.5), specular=0.3, shininess=300.0))
    exact = render(ctx, s, shared_grid=0)  # the cut acts on the per-lobe windows only
    np.testing.assert_array_equal(render(ctx, s, lod=0.0, shared_grid=0), exact)
    np.testing.assert_array_equal(render(ctx, s, sphere_tree=0, shared_grid=0), exact)
    np.testing.assert_array_equal(render(ctx, s, lod=16.0, sphere_tree=1), render(ctx, s, lod=16.0, sphere_tree=0))
    floor = s["gb"].read("instance") == s["ids"][0]
    cut = {lod: render(ctx, s, lod=lod, shared_grid=0) for lod in (2.0, 4.0, 16.0)}
    for img in cut.values():
        assert (img <= exact * (1 + 1e-5) + 1e-6).all()
    assert (cut[4.0] != exact).any() and rel_rms(exact[floor], cut[16.0][floor]) > 0.01  # the cut is taken
    ref = render(ctx, s, "reference", face_size=16)
    assert rel_rms(ref[floor], cut[4.0][floor]) < rel_rms(ref[floor], exact[floor]) + 0.003
    with pytest.raises(PenumbraError, match="lod"):
        Renderer(ctx, "isg", lod=-1.0)


GLOSSY = Material(albedo=(0.4, 0.4, 0.4), specular=0.5, shininess=1000.0)


def test_specular_modes_agree_on_a_constant_env(ctx):
    """Gamma_L of a constant env is the constant, so specular_mode 1 (prefiltered, built by the library at
    plan) shades a glossy floor as specular_mode 0 (the cube on the lobe's patches) does."""
    s = build(ctx, procedural.constant(1.5, 64, 32), translate(0.0, 1.2, 0.0, 0.6), material=GLOSSY)
    a, b = render(ctx, s, specular_mode=0), render(ctx, s, specular_mode=1)
    assert a.max() > 0.1
    np.testing.assert_allclose(b, a, rtol=1e-4, atol=1e-5 * a.max())


def test_prefiltered_env_is_rebuilt_when_the_env_changes(ctx):
    """The renderer's Gamma_L follows the scene's env map: after a new map, its frame is that of a new
    context's renderer."""
    rng = np.random.default_rng(2)
    maps = [np.ascontiguousarray(rng.uniform(0.1, 2.0, (32, 64, 3)).astype(np.float32)) for _ in range(2)]
    s = build(ctx, maps[0], translate(0.0, 1.2, 0.0, 0.6), material=GLOSSY)
    r = Renderer(ctx, "isg", specular_mode=1)
    img = Image(ctx, W, H)
    r.execute(s["scene"], s["gb"], img)
    first = img.read()[..., :3].astype(np.float64)
    s["scene"].set_envmap(EnvMap(ctx, maps[1], face_size=16, irradiance_face_size=8))
    s["scene"].commit()
    r.execute(s["scene"], s["gb"], img)
    again = img.read()[..., :3].astype(np.float64)
    ctx2 = Context()  # a context of its own: no Gamma_L of the first map to reuse
    fresh = render(ctx2, build(ctx2, maps[1], translate(0.0, 1.2, 0.0, 0.6), material=GLOSSY), specular_mode=1)
    assert np.abs(again - first).max() > 0.05 * first.max()
    np.testing.assert_array_equal(again, fresh)
    with pytest.raises(PenumbraError, match="specular_mode"):
        Renderer(ctx, "isg", specular_mode=2)


def test_a_diffuse_scene_builds_no_prefiltered_env(ctx):
    """specular_mode 1 on a scene without specular lobes skips Gamma_L (its frame is mode 0's)."""
    s = build(ctx, procedural.constant(1.0, 64, 32), translate(0.0, 1.2, 0.0, 0.6))
    np.testing.assert_array_equal(render(ctx, s, specular_mode=1), render(ctx, s, specular_mode=0))


def test_thin_shell_sheet_and_leaves_against_the_reference(ctx):
    """Thin shells through the C method (pn_sphere_set_create_shell): a draped open
    sheet and a set of small quads over a floor, sunny and overcast, against the
    reference renderer, and against a sphere set standing for the same geometry
    (bench/isg_shells.py; docs/isg.md section 9 "Thin shells"). Bounds: the
    triangles' NRMSE measured 0.4-1.4 % at 48 x 36 and face 64; here at face 16,
    40 x 30: under 3 %, and under half the sphere set's. Also: more than 4096
    triangles on a shell is refused naming the instance; a shell ignores deform."""
    import sys
    from pathlib import Path
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))
    from isg_shells import build as build_shell
    from penumbra.metrics import nrmse

    for shell in ("sheet", "leaves"):
        for env_rgb in (procedural.sky(64, 32, sun_radiance=2000.0, sun_angular_radius_deg=3.0),
                        procedural.sky(64, 32, sun_radiance=0.0)):
            s = build_shell(ctx, env_rgb, shell, (W, H), face_size=16)
            s["scene"].commit()
            gb = GBuffer(ctx, W, H)
            s["scene"].render_gbuffer(gb)
            s["gb"] = gb
            mask = gb.read("instance") != BACKGROUND
            ref = render(ctx, s, "reference", face_size=16)
            free = render(ctx, s)  # nothing attached: unshadowed
            s["scene"].attach(s["ids"][1], s["shell"])
            s["scene"].commit()
            tri = render(ctx, s)
            s["scene"].attach(s["ids"][1], s["spheres"])
            s["scene"].commit()
            sph = render(ctx, s)
            e_tri, e_sph = nrmse(ref, tri, mask), nrmse(ref, sph, mask)
            assert e_tri < 0.03 and e_tri < 0.5 * e_sph, (shell, e_tri, e_sph)
            assert nrmse(ref, free, mask) > 2 * e_tri  # the shell does cast the shadow
    s["shell"].deform(s["meshes"][1])
    big = procedural.plane((2.0, 2.0), 46)  # 2 x 46 x 46 = 4232 triangles
    bm = Mesh(ctx, big.vertices, big.faces)
    big_id = s["scene"].add(bm, translate(0.0, 1.0, 0.0), Material(albedo=(0.5, 0.5, 0.5)))
    s["scene"].attach(big_id, SphereSet.shell(ctx))
    s["scene"].commit()
    with pytest.raises(PenumbraError, match=f"instance {big_id} is a thin shell of 4232 triangles"):
        render(ctx, s)


def test_thin_shells_scene_key(ctx):
    """`[isg] thin_shells` (docs/scene-format.md): the example scene renders with its
    open planes as thin shells (no sphere set could be built for them: they enclose
    no volume) and they shadow the ground; a name that is not an object, or an
    object with occluder = false, is refused naming it."""
    import copy
    from pathlib import Path

    from penumbra.errors import InputError
    from penumbra.render import build_scene, render as render_scene
    from penumbra.scenefile import load_scene, parse_scene
    import tomllib

    path = Path(__file__).resolve().parents[1] / "examples" / "scenes" / "isg_thin_shells.toml"
    over = ["camera.resolution=[32,24]"]
    built = build_scene(load_scene(path, over), ctx)
    render_scene(built, "isg", frames=1, warmup=False)  # as the file stands (the ground a shell too)
    data = tomllib.loads(path.read_text())
    data["isg"]["exact_primitives"] = False  # else every plane would be a thin shell anyway, and the ball exact
    data["camera"]["resolution"] = [32, 24]
    shells = render_scene(build_scene(parse_scene(copy.deepcopy(data), path.parent), ctx), "isg", frames=1,
                          warmup=False).image[..., :3]
    data["isg"]["thin_shells"] = []
    plain = render_scene(build_scene(parse_scene(copy.deepcopy(data), path.parent), ctx), "isg", frames=1,
                         warmup=False).image[..., :3]
    assert (shells <= plain + 1e-4).all() and (shells < 0.8 * plain).any()
    data["isg"]["thin_shells"] = ["awning", "nothing"]
    with pytest.raises(InputError, match="'nothing', which is not an object"):
        parse_scene(copy.deepcopy(data), path.parent)
    data["isg"]["thin_shells"] = ["ground"]
    with pytest.raises(InputError, match="'ground', which has occluder = false"):
        parse_scene(copy.deepcopy(data), path.parent)


def test_exact_primitives_scene_key(ctx):
    """`[isg] exact_primitives` (default true; docs/isg.md section 9, "exact primitives and the env's
    irradiance"): a sphere primitive is one exact sphere, a box and a plane their triangles as thin shells, whatever their `occluder`; the
    floor then cuts the light from below the horizon off the objects on it, as the reference's rays do.
    Against the reference the image is much closer than with the 64-sphere sets of the box and the sphere
    and no floor occluder (false: the rule before); a bad value is refused."""
    import copy

    from penumbra.errors import InputError
    from penumbra.methods.isg import state
    from penumbra.metrics import compare
    from penumbra.render import build_scene, render as render_scene
    from penumbra.scenefile import parse_scene

    data = {"environment": {"map": "sky", "face_size": 32, "irradiance_face_size": 16},
            "camera": {"position": [0.0, 1.4, 3.2], "look_at": [0.0, 0.4, 0.0], "fov_deg": 45,
                       "resolution": [40, 30]},
            "object": [{"name": "box", "primitive": "box", "occluder": True, "translate": [0.6, 0.3, -0.3],
                        "rotate_deg": [0.0, 25.0, 0.0], "scale": 0.6, "albedo": [0.3, 0.5, 0.7]},
                       {"name": "ball", "primitive": "sphere", "occluder": True, "translate": [-0.6, 0.3, 0.25],
                        "scale": 0.3, "albedo": [0.7, 0.35, 0.3]},
                       {"name": "floor", "primitive": "plane", "params": {"size": [8.0, 8.0]},
                        "albedo": [0.5, 0.5, 0.5]}]}
    errors, recs = {}, {}
    ref = mask = None
    for exact in (True, False):
        d = copy.deepcopy(data)
        d["isg"] = {"exact_primitives": exact}
        built = build_scene(parse_scene(d, "."), ctx)
        img = render_scene(built, "isg", frames=1, warmup=False).image[..., :3]
        recs[exact] = {name: s.info()["count"] for name, s in state(built).sets.items()}
        if ref is None:
            res = render_scene(built, "reference", frames=1, warmup=False, face_size=16)
            ref = res.image[..., :3]
            mask = np.ones(ref.shape[:2], bool)  # the background is the same env in both
        errors[exact] = compare(ref, img, mask)["nrmse"]
    assert recs[True] == {"box": 0, "floor": 0, "ball": 1}  # shells have no spheres
    assert recs[False] == {"box": 64, "ball": 64}
    assert errors[True] < 0.6 * errors[False], errors
    d = copy.deepcopy(data)
    d["isg"] = {"exact_primitives": "yes"}
    with pytest.raises(InputError, match="exact_primitives must be true or false"):
        parse_scene(d, ".")
