"""Mitsuba 3 export and the pixel-centre Mitsuba renderer (penumbra.mitsuba).

The plugin BSDF is checked against the float64 BRDF of docs/brdf.md, the
resampled environment map against penumbra's nearest-texel lookup, and whole
renders against penumbra's ``unshadowed`` method on a convex object (no
shadowing, so both compute albedo / pi * E(n)). An off-centre object under a
rotated real environment makes a mirrored camera or a wrong rotation sign
fail, which the test confirms by rendering the wrong sign too.
"""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

mi = pytest.importorskip("mitsuba")
dr = pytest.importorskip("drjit")

import penumbra  # noqa: E402
from penumbra import mitsuba as pm  # noqa: E402
from penumbra.brdf import brdf  # noqa: E402
from penumbra.methods.heightfield import fields as heightfield_fields  # noqa: E402
from penumbra.cli import main  # noqa: E402
from penumbra.errors import InputError  # noqa: E402
from penumbra.imageio import read_envmap  # noqa: E402
from penumbra.render import build_scene  # noqa: E402
from penumbra.render import render as penumbra_render  # noqa: E402
from penumbra.scenefile import parse_scene  # noqa: E402

PISA = "envmaps/pisa_probulator_256x128.hdr"
BUNNY = "meshes/bunny_odedstein_3k.obj"
# Agreement with penumbra: NRMSE = RMSE / (max - min of penumbra's image) on
# foreground pixels. With SPP x EMITTER_SAMPLES = 16384 light samples per pixel
# the Monte Carlo noise alone is about 0.006 on these scenes; the converged
# difference (measured at 65536 samples) is below 0.001.
NRMSE_MAX = 0.01
SPP, EMITTER_SAMPLES = 2048, 8
# Float32 rounding in the plugin against the float64 BRDF.
BSDF_RTOL = 1e-5
# The renders need the vectorised variant; scalar_rgb would take minutes.
needs_llvm = pytest.mark.skipif(not dr.has_backend(dr.JitBackend.LLVM),
                                reason="Dr.Jit has no LLVM backend (set DRJIT_LIBLLVM_PATH)")


@pytest.fixture(autouse=True)
def _restore_variant():
    # Tests switch Mitsuba's global variant; leave it as found.
    before = mi.variant()
    yield
    if before is not None:
        mi.set_variant(before)


def sphere_scene(shared_data, translate=(0.0, 0.0, 0.0), look_at=(0.0, 0.0, 0.0), rotation_deg=0.0,
                 resolution=(32, 24), **extra):
    data = {
        "environment": {"map": str(shared_data / PISA), "rotation_deg": rotation_deg, "face_size": 64,
                        "irradiance_face_size": 32},
        "camera": {"position": [0.0, 0.0, 3.2], "look_at": list(look_at), "fov_deg": 40,
                   "resolution": list(resolution)},
        "object": [{"name": "ball", "primitive": "sphere", "params": {"subdivisions": 4},
                    "translate": list(translate), "albedo": 0.8}],
    }
    for key, value in extra.items():
        data[key] = value
    return parse_scene(data)


def nrmse(image, ref, mask):
    return float(np.sqrt(np.mean((image[mask] - ref[mask]) ** 2)) / (ref[mask].max() - ref[mask].min()))


# --------------------------------------------------------------------------- plugin BSDF


def _eval_plugin(props, v, l, frame=None):
    """The plugin's eval (f N.L) for local directions v, l (N = +z), one at a time."""
    bsdf = mi.load_dict({"type": pm.PLUGIN_NAME, **props})
    ctx = mi.BSDFContext()
    got = np.empty((len(v), 3))
    for i in range(len(v)):
        si = mi.SurfaceInteraction3f()
        if frame is not None:
            si.sh_frame = frame
        si.wi = mi.Vector3f(v[i])
        got[i] = np.array(bsdf.eval(ctx, si, mi.Vector3f(l[i])))
    return got


def _directions(rng, n):
    v = rng.normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


AS_WORLD_TANGENT = np.array([1.0, 0.5, 0.2])
AS_FRAME_TURN = 0.4  # the shading frame's s axis turned about N: the tangent goes through to_local


@pytest.mark.parametrize("lobe,shininess,roughness,shininess_v", [
    ("phong", 100.0, 0.3, None), ("phong", 0.0, 0.3, None), ("blinn_phong", 50.0, 0.3, None),
    ("ggx", 100.0, 0.3, None), ("ggx", 100.0, 0.05, None), ("ashikhmin_shirley", 10.0, 0.3, 200.0),
    ("ashikhmin_shirley", 300.0, 0.3, 3.0), ("ashikhmin_shirley", 0.0, 0.3, 0.0)])
def test_plugin_eval_matches_numpy_brdf(lobe, shininess, roughness, shininess_v):
    pm.select_variant("scalar_rgb")
    pm.register_plugin()
    albedo, ks = [0.2, 0.5, 0.7], 0.6
    props = {"albedo": {"type": "rgb", "value": albedo}, "specular": ks, "lobe": lobe, "shininess": shininess,
             "roughness": roughness}
    frame, aniso = None, {}
    if shininess_v is not None:
        c, s = math.cos(AS_FRAME_TURN), math.sin(AS_FRAME_TURN)
        frame = mi.Frame3f(mi.Vector3f(c, s, 0.0), mi.Vector3f(-s, c, 0.0), mi.Vector3f(0.0, 0.0, 1.0))
        props.update(shininess_v=shininess_v, tangent=AS_WORLD_TANGENT.tolist())
        a = AS_WORLD_TANGENT
        u = np.array([a[0] * c + a[1] * s, -a[0] * s + a[1] * c, 0.0])  # to local, projected
        aniso = dict(shininess_v=shininess_v, tangent=u / np.linalg.norm(u))
    rng = np.random.default_rng(7)
    n = 160
    v = _directions(rng, n)  # both hemispheres: the back side must mirror
    mirror = v * np.array([-1.0, -1.0, 1.0])
    near = mirror + 0.15 * rng.normal(size=(n, 3)) * rng.random((n, 1))  # around the lobe peaks
    l = np.concatenate([_directions(rng, n // 2), (near / np.linalg.norm(near, axis=1, keepdims=True))[n // 2:]])
    v, l = (x.astype(np.float32).astype(np.float64) for x in (v, l))  # what the plugin sees
    got = _eval_plugin(props, v, l, frame)
    normal = np.where(v[:, 2:3] < 0, [0.0, 0.0, -1.0], [0.0, 0.0, 1.0])  # the normal faces the viewer
    cos_l = np.maximum(np.sum(normal * l, axis=1), 0.0)[:, None]
    ref = brdf(normal, v, l, albedo, ks, lobe, shininess, roughness, **aniso) * cos_l  # Mitsuba's eval has N.L
    lit = cos_l[:, 0] > 0
    assert lit.sum() > n // 4 and (~lit).sum() > n // 8
    np.testing.assert_allclose(got[lit], ref[lit], rtol=BSDF_RTOL, atol=0)
    assert np.all(got[~lit] == 0)
    peak = ref[lit].max() / ref[lit].min()
    assert peak > 3  # the near-peak directions really sample the lobe


def test_plugin_sampling_is_cosine_weighted_and_consistent():
    pm.select_variant("scalar_rgb")
    pm.register_plugin()
    bsdf = mi.load_dict({"type": pm.PLUGIN_NAME, "albedo": {"type": "rgb", "value": [0.5, 0.4, 0.3]},
                         "specular": 0.3, "lobe": "blinn_phong", "shininess": 20.0})
    ctx = mi.BSDFContext()
    rng = np.random.default_rng(3)
    for wi in _directions(rng, 12):
        si = mi.SurfaceInteraction3f()
        si.wi = mi.Vector3f(wi)
        bs, weight = bsdf.sample(ctx, si, 0.5, mi.Point2f(*rng.random(2)))
        wo = np.array(bs.wo)
        assert wo[2] * wi[2] > 0  # sampled on the viewer's side
        assert bs.pdf == pytest.approx(abs(wo[2]) / math.pi, rel=1e-5)
        assert bsdf.pdf(ctx, si, bs.wo) == pytest.approx(bs.pdf, rel=1e-6)
        value, pdf = bsdf.eval_pdf(ctx, si, bs.wo)
        np.testing.assert_allclose(np.array(weight), np.array(value) / pdf, rtol=1e-5)


# --------------------------------------------------------------------------- environment map


def test_envmap_resampling_reproduces_nearest_texels(shared_data):
    env = read_envmap(shared_data / PISA)
    h, w = env.shape[:2]
    pm.select_variant("scalar_rgb")
    k = 8
    rng = np.random.default_rng(5)
    # Directions at least 1/k texel away from every texel edge, where the
    # resampled map must equal penumbra's piecewise-constant lookup exactly.
    i, j = rng.integers(0, w, 300), rng.integers(0, h, 300)
    fu, fv = rng.uniform(1.5 / k, 1 - 1.5 / k, (2, 300))
    u, v = (i + fu) / w, (j + fv) / h
    phi, theta = 2 * np.pi * u, np.pi * v
    dirs = np.stack([np.sin(phi) * np.sin(theta), np.cos(theta), -np.cos(phi) * np.sin(theta)], axis=1)
    ref = env[j, i].astype(np.float64)

    def lookup(bitmap):
        emitter = mi.load_dict({"type": "envmap", "bitmap": mi.Bitmap(bitmap)})
        out = np.empty((len(dirs), 3))
        for n, d in enumerate(dirs):
            si = mi.SurfaceInteraction3f()
            si.wi = mi.Vector3f(-d)
            out[n] = np.array(emitter.eval(si))
        return out

    resampled = pm.envmap_for_mitsuba(env, k)
    assert resampled.shape == (k * h + 1, k * w, 3)
    np.testing.assert_allclose(lookup(resampled), ref, rtol=1e-5, atol=1e-7)
    # Mitsuba's envmap puts rows on v = j / (H - 1) and interpolates, so the
    # original map handed over as it is reads noticeably differently.
    raw = lookup(env)
    lit = ref.sum(1) > 0
    assert np.median(np.abs(raw - ref).sum(1)[lit] / ref.sum(1)[lit]) > 3e-3


# --------------------------------------------------------------------------- agreement with penumbra


@needs_llvm
@pytest.mark.parametrize("case", ["centred", "asymmetric"])
def test_matches_penumbra_unshadowed(shared_data, ctx, case):
    if case == "centred":
        desc = sphere_scene(shared_data)
    else:  # off-centre object, camera aimed elsewhere, rotated environment
        desc = sphere_scene(shared_data, translate=(0.9, 0.3, 0.0), look_at=(0.4, 0.0, 0.0), rotation_deg=70.0)
    result = penumbra_render(build_scene(desc, ctx), "unshadowed", frames=1)
    ref = result.image[..., :3].astype(np.float64)
    fg = result.gbuffer["instance"] != penumbra.BACKGROUND
    assert 0.2 < fg.mean() < 0.8
    image = pm.render(desc, SPP, emitter_samples=EMITTER_SAMPLES)
    assert image.shape == ref.shape and image.dtype == np.float64
    assert nrmse(image, ref, fg) <= NRMSE_MAX
    # Background pixels are black (hidden environment), except where
    # rounding lets Mitsuba hit the silhouette that penumbra just missed.
    assert np.mean(image[~fg].max(axis=1) > 0) < 0.02
    if case == "asymmetric":
        # The comparison can tell orientation errors apart: a mirrored image or
        # the opposite rotation is far off even with few samples.
        assert nrmse(image[:, ::-1], ref, fg) > 0.1
        wrong = sphere_scene(shared_data, translate=(0.9, 0.3, 0.0), look_at=(0.4, 0.0, 0.0), rotation_deg=-70.0)
        assert nrmse(pm.render(wrong, 32, emitter_samples=EMITTER_SAMPLES), ref, fg) > 0.1


# --------------------------------------------------------------------------- export


def export_scene(shared_data, **render_extra):
    return parse_scene({
        "environment": {"map": str(shared_data / PISA), "rotation_deg": 30.0, "intensity": 1.5},
        "camera": {"position": [0.3, 1.6, 4.5], "look_at": [0.0, 0.3, 0.0], "fov_deg": 45, "resolution": [32, 24]},
        "object": [
            {"name": "ground", "primitive": "plane", "params": {"size": [6.0, 6.0]}, "albedo": 0.5},
            {"name": "ball", "primitive": "sphere", "translate": [-1.0, 0.5, 0.0], "scale": 0.5},
            {"name": "box", "primitive": "box", "translate": [0.6, 0.4, -0.3], "rotate_deg": [10.0, 35.0, 0.0],
             "specular": 0.4, "lobe": "ggx", "roughness": 0.2, "albedo": [0.3, 0.5, 0.8]},
            {"name": "mirrored ball", "primitive": "sphere", "translate": [1.2, 0.3, 1.0],
             "scale": [-0.3, 0.3, 0.3], "specular": 0.5, "lobe": "phong", "shininess": 40.0},
            {"name": "bunny", "mesh": str(shared_data / BUNNY), "translate": [0.0, 0.5, 1.2], "scale": 0.5,
             "rotate_deg": [0.0, 30.0, 0.0], "specular": 0.3, "lobe": "ashikhmin_shirley", "shininess": 10.0,
             "shininess_v": 200.0, "tangent": [1.0, 1.0, 0.0]},
        ],
    })


@needs_llvm
def test_export_loads_and_renders_like_scene_dict(shared_data, tmp_path):
    desc = export_scene(shared_data)
    out = tmp_path / "mitsuba"
    written = pm.export(desc, out, spp=8)
    names = sorted(str(p.relative_to(out)) for p in written)
    # One PLY per distinct geometry, reversed for a mirroring transform.
    assert names == ["envmap.exr", "meshes/mesh000_ground.ply", "meshes/mesh001_ball.ply",
                     "meshes/mesh002_box.ply", "meshes/mesh003_mirrored_ball_mirrored.ply",
                     "meshes/mesh004_bunny.ply", "scene.xml"]
    assert not [p for p in out.rglob("*") if p.name.startswith(".")]  # no temporary files left
    text = (out / "scene.xml").read_text()
    assert 'type="penumbra"' in text and 'name="fov_axis" value="x"' in text
    # The anisotropic lobe's tangent goes out in world space (the bunny's axis turned by its rotation).
    bunny = desc.objects[-1]
    world = bunny.transform()[:3, :3] @ np.array([1.0, 1.0, 0.0])
    assert f'<vector name="tangent" value="{pm._vec(world)}"/>' in text and 'name="shininess_v"' in text

    scene = pm.load_file(out / "scene.xml")
    # Every exported triangle is in the loaded scene. (Not a count of shapes:
    # Mitsuba merges meshes that share an identical BSDF, here the two grey
    # diffuse objects once both carry vertex normals.)
    ply_faces = sum(mi.load_dict({"type": "ply", "filename": str(out / n)}).face_count()
                    for n in names if n.endswith(".ply"))
    assert sum(sh.face_count() for sh in scene.shapes()) == ply_faces and len(scene.shapes()) >= 4
    exported = pm.PixelCentreRenderer.from_scene(scene).render(64, seed=3)
    direct = pm.render(desc, 64, seed=3)
    assert np.isfinite(exported).all() and exported.max() > 0
    # The same sampler seed gives the same samples; only float32 rounding of
    # the object-space meshes placed by to_world can differ.
    assert np.mean(np.abs(exported - direct)) < 1e-4 * np.mean(direct)
    # mi.render works on the exported file too (jittered and box-filtered, so only roughly equal).
    assert float(np.mean(mi.render(scene, spp=16))) == pytest.approx(float(np.mean(direct)), rel=0.05)


def test_export_replaces_only_its_own_files(shared_data, tmp_path):
    desc = sphere_scene(shared_data, resolution=(8, 6))
    out = tmp_path / "x"
    first = pm.export(desc, out)
    (out / "notes.txt").write_text("mine")
    second = pm.export(desc, out)  # a re-export replaces what the first one wrote
    assert first == second
    assert (out / "notes.txt").read_text() == "mine"

    foreign = tmp_path / "foreign"
    foreign.mkdir()
    (foreign / "scene.xml").write_text("<scene/>")
    with pytest.raises(InputError, match="no earlier penumbra export wrote"):
        pm.export(desc, foreign)
    assert (foreign / "scene.xml").read_text() == "<scene/>"
    assert sorted(p.name for p in foreign.iterdir()) == ["scene.xml"]  # nothing written before the check
    pm.export(desc, foreign, overwrite=True)
    assert (foreign / "scene.xml").read_text().startswith(f"<!-- {pm.EXPORT_MARKER}")


@needs_llvm
def test_spherical_light_irradiance(tmp_path):
    # A sphere of radiance L and radius r at distance D straight above a
    # Lambertian plane gives E = pi L (r/D)^2, so L_o = albedo L (r/D)^2.
    desc = parse_scene({
        "environment": {"map": "constant", "params": {"value": 0.0}},
        "camera": {"position": [0.0, 3.0, 3.0], "look_at": [0.0, 0.0, 0.0], "fov_deg": 10, "resolution": [5, 5]},
        "object": [{"name": "ground", "primitive": "plane", "albedo": 0.5}],
    })
    desc.lights = [SimpleNamespace(position=(0.0, 2.0, 0.0), radius=0.2, radiance=(10.0, 5.0, 2.0))]
    image = pm.render(desc, 1024)
    expected = 0.5 * np.array([10.0, 5.0, 2.0]) * (0.2 / 2.0) ** 2
    np.testing.assert_allclose(image[2, 2], expected, rtol=0.02)
    # The exported XML carries the light as well.
    pm.export(desc, tmp_path)
    text = (tmp_path / "scene.xml").read_text()
    assert 'type="sphere"' in text and 'type="area"' in text and not (tmp_path / "envmap.exr").exists()
    exported = pm.PixelCentreRenderer.from_scene(pm.load_file(tmp_path / "scene.xml")).render(1024)
    np.testing.assert_allclose(exported[2, 2], expected, rtol=0.02)


@needs_llvm
def test_heightfields_export_as_meshes(shared_data, tmp_path):
    # Height fields go to Mitsuba as their triangle meshes: a constant albedo
    # as the diffuse reflectance, an albedo map as per-vertex colour.
    rgb = [0.2, 0.5, 0.8]
    np.save(tmp_path / "albedo.npy", np.broadcast_to(np.float32(rgb), (9, 9, 3)))
    data = {"environment": {"map": str(shared_data / PISA), "face_size": 64},
            "camera": {"position": [0.0, 4.0, 5.0], "look_at": [0.0, 0.0, 0.0], "fov_deg": 60,
                       "resolution": [32, 24]},
            "heightfield": [{"name": "bumps", "terrain": "egg_tray", "params": {"period": 0.5}, "size_px": [33, 33],
                             "size": [4.0, 4.0], "height_scale": 1.5, "albedo": [0.6, 0.5, 0.4]},
                            {"name": "mapped", "terrain": "flat", "size_px": [9, 9], "size": [2.0, 2.0],
                             "origin": [2.2, 0.0, -1.0], "albedo_map": str(tmp_path / "albedo.npy")}]}
    desc = parse_scene(data)
    image = pm.render(desc, 1024, emitter_samples=4, seed=5)
    built = build_scene(desc, penumbra.Context())
    ref = penumbra_render(built, "reference", frames=1, warmup=False, background=0, face_size=16)
    _, bumps_id = heightfield_fields(built)["bumps"]
    mask = ref.gbuffer["instance"] == bumps_id
    # Smooth bumps: Monte Carlo noise (about 0.011) and the reference's face 16 (0.005).
    assert mask.sum() > 200 and nrmse(image, ref.image[..., :3], mask) < 0.025
    # The map: the same render as a constant albedo of its colour (same samples).
    data["heightfield"][1].pop("albedo_map")
    data["heightfield"][1]["albedo"] = rgb
    plain = pm.render(parse_scene(data), 1024, emitter_samples=4, seed=5)
    _, mapped_id = heightfield_fields(built)["mapped"]
    mapped = ref.gbuffer["instance"] == mapped_id
    assert mapped.sum() > 10
    np.testing.assert_allclose(image[mapped], plain[mapped], rtol=1e-4, atol=1e-6)
    # The export: one world-space PLY per field (the map as vertex r g b), rendering as scene_dict does.
    written = pm.export(desc, tmp_path / "x", spp=8)
    assert sorted(str(p.relative_to(tmp_path / "x")) for p in written) == [
        "envmap.exr", "meshes/heightfield000_bumps.ply", "meshes/heightfield001_mapped.ply", "scene.xml"]
    assert b"property float r" in (tmp_path / "x" / "meshes" / "heightfield001_mapped.ply").read_bytes()[:400]
    exported = pm.PixelCentreRenderer.from_scene(pm.load_file(tmp_path / "x" / "scene.xml")).render(64, seed=3)
    direct = pm.render(desc, 64, seed=3)
    assert np.mean(np.abs(exported - direct)) < 1e-4 * np.mean(direct)


# --------------------------------------------------------------------------- errors and CLI


def test_bad_input_raises_input_error(shared_data, tmp_path):
    desc = sphere_scene(shared_data, resolution=(4, 3))
    with pytest.raises(InputError, match="spp"):
        pm.render(desc, 0)
    with pytest.raises(InputError, match="unknown Mitsuba variant"):
        pm.render(desc, 1, variant="no_such_variant")
    with pytest.raises(InputError, match="not an RGB variant"):
        pm.render(desc, 1, variant="scalar_spectral")
    with pytest.raises(InputError, match="max_wavefront"):
        pm.render(desc, 1, max_wavefront=0)
    with pytest.raises(InputError, match="supersample"):
        pm.envmap_for_mitsuba(np.ones((4, 8, 3), np.float32), 0)
    with pytest.raises(InputError, match="spp"):
        pm.export(desc, tmp_path / "a", spp=0)
    desc.lights = [SimpleNamespace(position=(0.0, 1.0, 0.0), radius=-1.0, radiance=(1.0, 1.0, 1.0))]
    with pytest.raises(InputError, match="radius"):
        pm.export(desc, tmp_path / "b")
    (tmp_path / "file").write_text("")
    with pytest.raises(InputError, match="not a directory"):
        pm.export(sphere_scene(shared_data), tmp_path / "file")


@needs_llvm
def test_render_splits_wavefronts(shared_data):
    desc = sphere_scene(shared_data, resolution=(6, 4))
    one = pm.PixelCentreRenderer(desc, max_wavefront=1 << 20, emitter_samples=EMITTER_SAMPLES)
    split = pm.PixelCentreRenderer(desc, max_wavefront=10, emitter_samples=EMITTER_SAMPLES)
    assert one.batches(16) == [(0, 24, 0, 16)]
    assert split.batches(3)[:4] == [(0, 10, 0, 1), (0, 10, 1, 1), (0, 10, 2, 1), (10, 10, 0, 1)]
    assert max(count * per for _, count, _, per in split.batches(3)) <= 10
    assert pm.PixelCentreRenderer(desc, max_wavefront=100).batches(10) == [(0, 24, 0, 4), (0, 24, 4, 4),
                                                                           (0, 24, 8, 2)]
    a, b = one.render(512, seed=1), split.render(32, seed=2)
    assert a.shape == b.shape == (4, 6, 3)
    mask = a.max(axis=2) > 0
    assert np.mean(np.abs(a - b)[mask]) < 0.1 * np.mean(a[mask])  # independent samples, same estimate
    image, seconds = one.render_timed(4)
    assert image.shape == (4, 6, 3) and seconds > 0


@needs_llvm
def test_scalar_variant_agrees_with_llvm(shared_data):
    desc = sphere_scene(shared_data, resolution=(8, 6))
    desc.objects[0].specular, desc.objects[0].lobe = 0.3, "ggx"  # through the plugin, in both variants
    scalar, seconds = pm.render_timed(desc, 256, variant="scalar_rgb", emitter_samples=4)
    assert seconds > 0
    llvm = pm.render(desc, 2048, variant="llvm_ad_rgb", emitter_samples=4)
    mask = llvm.max(axis=2) > 0
    assert np.mean(np.abs(scalar - llvm)[mask]) < 0.08 * np.mean(llvm[mask])


def test_cli_export_mitsuba(shared_data, tmp_path, capsys):
    scene = tmp_path / "scene.toml"
    scene.write_text(f"""
[environment]
map = "{(shared_data / PISA).as_posix()}"

[camera]
resolution = [16, 12]

[[object]]
name = "ball"
primitive = "sphere"
specular = 0.2
""")
    out = tmp_path / "out"
    assert main(["export-mitsuba", str(scene), "-o", str(out), "--set", "camera.fov_deg=30", "--spp", "4"]) == 0
    printed = capsys.readouterr().out
    assert str(out / "scene.xml") in printed and "penumbra.mitsuba.load_file" in printed
    text = (out / "scene.xml").read_text()
    assert 'name="fov" value="30.0"' in text and '<default name="spp" value="4"/>' in text
    (out / "meshes" / "mesh000_ball.ply").unlink()
    (out / "meshes" / "mesh000_ball.ply").write_text("not ours")
    (out / "scene.xml").write_text("<scene/>")  # no longer an export: its files are not ours
    assert main(["export-mitsuba", str(scene), "-o", str(out)]) == 2
    assert "no earlier penumbra export wrote" in capsys.readouterr().err
    assert main(["export-mitsuba", str(scene), "-o", str(out), "--force"]) == 0
