"""The `depthmap` method (kernels/depthmap.cl, capi/src/methods/depthmap.c)
against its float64 twin (tests/depthmap64.py): the fitted frames, the
rasterised and ray-cast maps, the lookup with bias and PCF, the specular
rules and the per-pixel sum; against the `reference` renderer; the bias's
two failure modes (acne, contact leaks); hard cases and bad input."""

from __future__ import annotations

import math

import depthmap64 as d64
import numpy as np
import pytest
from geometry64 import rotation
from test_reference import gbuffer_of, make_scene, shade, xform
from tolerances import DEPTHMAP_DEPTH_ATOL, DEPTHMAP_SHADE_RTOL

from penumbra import BACKGROUND, Camera, EnvMap, GBuffer, Image, InputError, Material, PenumbraError, Renderer, procedural
from penumbra.methods import depthmap as dm


def domains_of(env_image, n, seed=1):
    dom = d64.decompose(env_image, n, seed=seed)
    return dm.domain_array(dom.centres, dom.radiance, cap_radius=dom.cap_radius, solid_angle=dom.solid_angle)


def render(ctx, scene, gb, domains, **params):
    # One map size unless a test asks for strong or graded maps (the sky's sun domain would get 256^2 and the
    # others sides by their power by default): these tests are of the maps at `resolution`;
    # tests/test_depthmap_atlas.py covers maps of several sizes.
    params.setdefault("strong_resolution", 0)
    params.setdefault("grade", 0.0)
    r = Renderer(ctx, "depthmap", **params)
    dm.set_domains(r, domains)
    img = Image(ctx, gb.width, gb.height)
    r.execute(scene, gb, img)
    return img.read(), r


def nrmse(got, ref, mask):
    return float(np.sqrt(np.mean((got[mask] - ref[mask]) ** 2)) / (ref[mask].max() - ref[mask].min()))


@pytest.fixture(scope="module")
def sky():
    return procedural.sky(64, 32)


@pytest.fixture(scope="module")
def box_scene(ctx, sky):
    """A rotated box resting on a plane, a floating box, Phong / GGX / Blinn-Phong lobes, under the procedural sky."""
    env = EnvMap(ctx, sky, face_size=16)
    objects = [
        (procedural.plane((4.0, 4.0)), xform(), Material(albedo=(0.7, 0.7, 0.7), specular=0.2, shininess=20.0,
                                                         lobe="blinn_phong")),
        (procedural.box((1.0, 0.8, 0.6)), xform(rotation((0, 1, 0), 0.5), (0.0, 0.4, 0.0)),
         Material(albedo=(0.8, 0.4, 0.2), specular=0.3, shininess=50.0, lobe="phong")),
        (procedural.box((0.4, 0.4, 0.4)), xform(rotation((1, 1, 0), 0.7), (0.9, 1.3, 0.4)),
         Material(albedo=(0.2, 0.5, 0.8), specular=0.5, roughness=0.2, lobe="ggx")),
    ]
    camera = Camera(position=(1.5, 2.5, 4.0), look_at=(0.0, 0.3, 0.0), fov_deg=50.0, resolution=(32, 24))
    scene, tris, keep = make_scene(ctx, objects, env, camera)
    gb, planes = gbuffer_of(ctx, scene, camera)
    return dict(env=env, scene=scene, tris=tris, keep=keep, camera=camera, gb=gb, planes=planes,
                domains=domains_of(sky, 16), instances=instances_of(objects))


def instances_of(objects):
    """(object box, transform) of each object as the library holds them (float32), for depthmap64.fit_frame."""
    out = []
    for mesh, xf, _ in objects:
        v = np.asarray(mesh.vertices, np.float32)
        out.append((v.min(0).astype(np.float64), v.max(0).astype(np.float64),
                    np.asarray(xf, np.float32).astype(np.float64)))
    return out


# --------------------------------------------------------------------------- maps


@pytest.mark.parametrize("fit", [0, 1])
def test_frames_fit_the_scene_tightly(ctx, box_scene, fit):
    s = box_scene
    _, r = render(ctx, s["scene"], s["gb"], s["domains"], resolution=32, fit=fit)
    frames = r.read_output(s["scene"], "map_frames", 0).astype(np.float64)
    # fit 0: every instance; fit 1: the two boxes (the floor is flat and nothing lies under it).
    tris = s["tris"] if fit == 0 else s["tris"][int(s["tris"].shape[0] - 24):]
    assert fit == 0 or len(tris) == 24  # the boxes' 12 + 12 triangles, after the floor's
    pts = tris.reshape(-1, 3)
    for f, d in zip(frames, s["domains"]):
        assert np.allclose(f[8:11], d[:3], atol=1e-6)
        basis = np.stack([f[0:3], f[4:7], f[8:11]])
        assert np.allclose(basis @ basis.T, np.eye(3), atol=1e-6)
        tu, tv, z = d64.map_coordinates(f, pts)
        # Every vertex inside the map, at least half a texel from its edges, depths within [0, extent].
        assert tu.min() >= 0.5 - 1e-3 and tu.max() <= 32 - 0.5 + 1e-3
        assert tv.min() >= 0.5 - 1e-3 and tv.max() <= 32 - 0.5 + 1e-3
        assert z.min() >= -1e-5 and z.max() <= f[14] + 1e-5
        # Tight: the boxes' corners are the vertices here, so the fit touches them on each axis.
        assert min(tu.min(), 32 - tu.max()) < 0.5 + 0.6
        if fit == 0:
            assert z.min() < 1e-4


@pytest.mark.parametrize("fit", [0, 1])
def test_frames_match_the_float64_fit(ctx, box_scene, fit):
    """The library's frames are the twin's fit_frame (float32 storage)."""
    s = box_scene
    _, r = render(ctx, s["scene"], s["gb"], s["domains"], resolution=32, fit=fit, skip_power=0.0)
    frames = r.read_output(s["scene"], "map_frames", 0).astype(np.float64)
    for f, d in zip(frames, s["domains"]):
        want = d64.fit_frame(d[:3].astype(np.float64), s["instances"], 32, fit)
        assert np.allclose(f, want, rtol=1e-5, atol=1e-5 * 4.0), (f, want)


def flat_caster_scene(ctx):
    """A box on a floor under a tilted flat roof, beside a flat wall: what the
    flat casters shadow is all that fit 1 may leave out of a map."""
    env = EnvMap(ctx, procedural.constant(1.0), face_size=8)
    objects = [(procedural.plane((6.0, 6.0)), xform(), Material()),
               (procedural.box((0.5, 0.5, 0.5)), xform(translate=(0.3, 0.25, 0.2)), Material()),
               (procedural.plane((1.5, 1.5)), xform(rotation((1, 0, 0), 0.3), (0.0, 1.5, 0.0)), Material()),
               (procedural.plane((2.0, 1.0)), xform(rotation((1, 0, 0), math.pi / 2), (0.0, 0.5, -1.2)), Material())]
    camera = Camera(position=(2.0, 3.0, 4.0), look_at=(0.0, 0.3, -0.3), fov_deg=55.0, resolution=(64, 48))
    scene, tris, keep = make_scene(ctx, objects, env, camera)
    gb, planes = gbuffer_of(ctx, scene, camera)
    return scene, gb, planes, instances_of(objects), keep


@pytest.mark.parametrize("direction", [(0.3, 0.9, 0.3), (0.8, 0.3, -0.2), (-0.3, 0.5, 0.8), (-0.2, -0.7, 0.5)])
def test_fit_keeps_every_shadow(ctx, direction):
    """fit 1 (where a shadow can fall) against fit 0 (every instance) under
    one directional domain: the roof's and the wall's shadows (flat casters),
    the box's, and from below the floor's are all kept; only outline pixels
    (texel size and bias differ) may change. The frames are the twin's."""
    scene, gb, planes, instances, keep = flat_caster_scene(ctx)
    d = np.asarray(direction, np.float64) / np.linalg.norm(direction)
    doms = dm.domain_array(d[None], np.ones((1, 3)), cap_radius=[0.0])
    fg = planes["instance"] != BACKGROUND
    lit_by = (np.einsum("hwc,c->hw", planes["normal"][..., :3].astype(np.float64), d) > 0) & fg
    img = {}
    for fit in (0, 1):
        got, r = render(ctx, scene, gb, doms, resolution=512, fit=fit, skip_power=0.0)
        img[fit] = got[..., 0]
        f = r.read_output(scene, "map_frames", 0).astype(np.float64)[0]
        assert np.allclose(f, d64.fit_frame(d, instances, 512, fit), rtol=1e-5, atol=1e-5 * 6.0)
    dark0, dark1 = lit_by & (img[0] == 0), lit_by & (img[1] == 0)
    assert dark0.sum() > 40  # the test has shadows to lose
    assert (dark0 & ~dark1).sum() <= 0.03 * dark0.sum() + 2
    assert (dark1 & ~dark0).sum() <= 0.03 * dark0.sum() + 2


@pytest.mark.parametrize("renderer", [0, 1])
def test_maps_match_the_float64_rasteriser(ctx, box_scene, renderer):
    s = box_scene
    res = 48
    # skip_power 0: every domain gets a map (at the default 0.01 some of this sky's have none: empty maps).
    _, r = render(ctx, s["scene"], s["gb"], s["domains"], resolution=res, map_renderer=renderer, skip_power=0.0)
    frames = r.read_output(s["scene"], "map_frames", 0).astype(np.float64)
    for i in (0, 5, 11):
        got = r.read_output(s["scene"], "depth_map", 0, i).astype(np.float64)
        want = d64.rasterise(frames[i], s["tris"], res)
        both = np.isfinite(got) & np.isfinite(want)
        # Coverage differs only at texel centres on a triangle edge (float32 vs float64 edge tests).
        assert (np.isfinite(got) != np.isfinite(want)).sum() <= 0.01 * res * res
        assert both.sum() > 0.3 * res * res
        err = np.abs(got[both] - want[both])
        # A texel centre on an edge between two faces at different depths may take either (a silhouette texel).
        assert np.mean(err <= DEPTHMAP_DEPTH_ATOL * frames[i][14]) > 0.99, (i, err.max())


def test_raycast_and_raster_maps_agree(ctx, box_scene):
    s = box_scene
    imgs = [render(ctx, s["scene"], s["gb"], s["domains"], map_renderer=k)[0] for k in (0, 1)]
    fg = s["planes"]["instance"] != BACKGROUND
    assert nrmse(imgs[1][..., :3], imgs[0][..., :3], fg) < 2e-3


# --------------------------------------------------------------------------- shading against the twin


def quantise16(frames, maps):
    """The 16-bit maps of half_maps as the shading reads them (kernels/depthmap.cl depthmap_pack16), in float32."""
    extent = frames[:, 14].astype(np.float32)[:, None, None]
    z = maps.astype(np.float32)
    q = np.minimum(np.rint(np.where(np.isinf(z), 0, z) / extent * np.float32(65534.0)), np.float32(65534.0))
    return np.where(np.isinf(z), np.inf, q * (extent / np.float32(65534.0))).astype(np.float32)


@pytest.mark.parametrize("params", [dict(), dict(pcf=1), dict(pcf=2, bias=0.5), dict(specular=0),
                                    dict(specular=1), dict(specular=2, cap_samples=5), dict(specular=2),
                                    dict(visibility=0),
                                    dict(half_maps=1), dict(half_maps=1, pcf=1),
                                    dict(receiver_plane=0), dict(receiver_plane=0, pcf=1),
                                    dict(receiver_plane=0, pcf=2, bias=0.5), dict(receiver_plane=0, half_maps=1)])
def test_shading_matches_float64(ctx, box_scene, params):
    s = box_scene
    res = 64
    got, r = render(ctx, s["scene"], s["gb"], s["domains"], resolution=res, **params)
    got = got[..., :3]
    p = dict(bias=1.0, slope_bias=1.0, pcf=0, specular=3, cap_samples=16, receiver_plane=1)  # the defaults
    p.update({k: v for k, v in params.items() if k in p})
    if params.get("visibility", 1):
        frames = r.read_output(s["scene"], "map_frames", 0).astype(np.float64)
        maps = np.stack([r.read_output(s["scene"], "depth_map", 0, i) for i in range(len(s["domains"]))])
        if params.get("half_maps"):
            maps = quantise16(frames, maps)
        maps = maps.astype(np.float64)
    else:
        frames = maps = None
    margin = DEPTHMAP_DEPTH_ATOL * (frames[:, 14].max() if frames is not None else 0.0)
    lo, hi = d64.shade(s["planes"], s["camera"].position, s["domains"], frames, maps, margin=margin, **p)
    fg = s["planes"]["instance"] != BACKGROUND
    scale = np.maximum(hi, 1e-3)
    # the twin's specular 3 uses the exact cap ratio: the table's interpolation error is allowed on top
    rtol = CAP_TABLE_SHADE_RTOL if p["specular"] == 3 else DEPTHMAP_SHADE_RTOL
    ok = (got >= lo - rtol * scale) & (got <= hi + rtol * scale)
    excess = np.maximum(lo - got, got - hi)[fg] / scale[fg]
    assert ok[fg].all(), (f"{(~ok[fg]).sum()} values off; worst {np.argwhere(~ok & fg[..., None])[:3].tolist()}, "
                          f"relative excess {excess.max():.3g}")
    assert (hi[fg] > lo[fg] * (1 + 1e-9) + 1e-12).sum() < 0.05 * fg.sum() * 3  # few ambiguous lookups
    if frames is not None:  # shadows matter in this scene
        free, _ = render(ctx, s["scene"], s["gb"], s["domains"], visibility=0, **params)
        assert (free[..., :3][fg] - got[fg]).max() > 0.2 * got[fg].max()


def test_background_shows_the_environment(ctx, box_scene):
    s = box_scene
    img, _ = render(ctx, s["scene"], s["gb"], s["domains"])
    ref = shade(ctx, s["scene"], s["gb"], "unshadowed")
    bg = s["planes"]["instance"] == BACKGROUND
    assert bg.sum() > 10 and np.array_equal(img[bg], ref[bg])
    dark, _ = render(ctx, s["scene"], s["gb"], s["domains"], background=0)
    assert (dark[bg] == 0).all()


def test_zero_specular_skips_the_lobe(ctx, sky):
    """k_s = 0: every specular rule gives the same image, bit for bit."""
    env = EnvMap(ctx, sky, face_size=8)
    objects = [(procedural.plane((4.0, 4.0)), xform(), Material(albedo=(0.6, 0.6, 0.6))),
               (procedural.sphere(0.5), xform(translate=(0, 0.5, 0)), Material(albedo=(0.5, 0.3, 0.2)))]
    camera = Camera(position=(0.0, 2.0, 3.0), look_at=(0.0, 0.3, 0.0), fov_deg=50.0, resolution=(16, 12))
    scene, _, keep = make_scene(ctx, objects, env, camera)
    gb, _ = gbuffer_of(ctx, scene, camera)
    doms = domains_of(sky, 8)
    imgs = [render(ctx, scene, gb, doms, specular=k)[0] for k in (0, 1, 2, 3)]
    assert np.array_equal(imgs[0], imgs[1]) and np.array_equal(imgs[0], imgs[2])


# --------------------------------------------------------------------------- against the reference


def test_close_to_the_reference(ctx, box_scene):
    s = box_scene
    # face 32 with the sun split 4 x 4: face 16 alone is 0.015 off this (the sun's texel).
    ref = shade(ctx, s["scene"], s["gb"], "reference", face_size=32, sun_supersampling=4)[..., :3]
    fg = s["planes"]["instance"] != BACKGROUND
    errs = {}
    for n in (16, 64):
        img, _ = render(ctx, s["scene"], s["gb"], domains_of(procedural.sky(64, 32), n), pcf=1)
        errs[n] = nrmse(img[..., :3], ref, fg)
    free, _ = render(ctx, s["scene"], s["gb"], domains_of(procedural.sky(64, 32), 64), visibility=0)
    plain, _ = render(ctx, s["scene"], s["gb"], domains_of(procedural.sky(64, 32), 64))
    # PCF 1: measured 0.0102 / 0.0091 at the defaults (fit 1, 128^2; 0.0082 / 0.0071 with fit 0 at 256^2,
    # whose larger texels blurred the sun's outline more; the rest: that outline on the 32 x 24 pixel grid);
    # the default PCF 0: 0.0108 (this scene's hard sun outlines favour the filter, the armadillo's do not:
    # docs/depthmap.md); unshadowed 0.077.
    assert errs[64] < 0.01 and errs[16] < 0.012 and errs[64] < errs[16]
    assert nrmse(plain[..., :3], ref, fg) < 0.013
    assert nrmse(free[..., :3], ref, fg) > 5 * errs[64]


# --------------------------------------------------------------------------- bias: acne and contact


def lit_plane(ctx, tilt=0.0, centre=(0.0, 0.0, 0.0), size=4.0):
    env_image = procedural.constant(1.0)
    env = EnvMap(ctx, env_image, face_size=8)
    rot = rotation((1, 0, 0), tilt)
    objects = [(procedural.plane((size, size), subdivisions=4), xform(rot, centre), Material(albedo=(0.8, 0.8, 0.8)))]
    up = rot @ np.array([0.0, 1.0, 0.0])
    c = np.asarray(centre, np.float64)
    camera = Camera(position=tuple(c + rot @ np.array([0.3, 0.6, 0.8]) * size), look_at=tuple(c), up=tuple(up),
                    fov_deg=60.0, resolution=(24, 24))
    scene, tris, keep = make_scene(ctx, objects, env, camera)
    gb, planes = gbuffer_of(ctx, scene, camera)
    return scene, gb, planes, keep, env_image


@pytest.mark.parametrize("tilt,centre,size", [(0.0, (0, 0, 0), 4.0), (0.6, (0, 0, 0), 4.0),
                                              (0.3, (3000.0, 1500.0, -900.0), 400.0)])
def test_no_acne_on_a_lit_plane(ctx, tilt, centre, size):
    """A plane alone casts no shadow: every lookup must find it lit, at every
    direction above it including grazing ones (down to 3 degrees)."""
    scene, gb, planes, keep, env_image = lit_plane(ctx, tilt, centre, size)
    up = rotation((1, 0, 0), tilt) @ np.array([0.0, 1.0, 0.0])
    # 64 directions from 3 to 87 degrees of elevation, all azimuths.
    k = np.arange(64)
    elev = np.radians(3.0 + 84.0 * (k % 16) / 15.0)
    az = 2.39996 * k
    local = np.stack([np.cos(elev) * np.cos(az), np.sin(elev), np.cos(elev) * np.sin(az)], 1)
    rot = rotation((1, 0, 0), tilt)
    dirs = local @ rot.T
    assert np.allclose(dirs @ up, np.sin(elev))
    doms = dm.domain_array(dirs, np.ones((64, 3)) * 0.05)
    fg = planes["instance"] != BACKGROUND
    free, _ = render(ctx, scene, gb, doms, visibility=0)
    # the default (receiver_plane 1: each tap's own depth on the plane, so no slope term is needed) and the
    # slope-scaled bias (receiver_plane 0); without the plane and without its slope term the lookup has acne:
    # the plane's depth is what keeps it lit
    for plane in (1, 0):
        for pcf in (0, 1, 2):
            got, _ = render(ctx, scene, gb, doms, pcf=pcf, receiver_plane=plane)
            assert np.abs(got[fg] - free[fg]).max() <= 1e-6 * free[fg].max(), (plane, pcf)
    flat, _ = render(ctx, scene, gb, doms, pcf=1, slope_bias=0.0, receiver_plane=0)
    assert (flat[fg][:, 0] < 0.95 * free[fg][:, 0]).mean() > 0.01
    # The test can fail: without bias the plane shadows itself.
    raw, _ = render(ctx, scene, gb, doms, bias=0.0, slope_bias=0.0, pcf=1, receiver_plane=0)
    assert (raw[fg][:, 0] < 0.95 * free[fg][:, 0]).mean() > 0.1


def test_no_light_leak_at_contact(ctx):
    """A box resting on the floor under a single overhead-ish light: floor
    pixels within a few texels of the box's footprint on the shadow side stay
    dark (no peter-panning), as ray-traced visibility says."""
    env = EnvMap(ctx, procedural.constant(1.0), face_size=8)
    objects = [(procedural.plane((4.0, 4.0)), xform(), Material(albedo=(0.8, 0.8, 0.8))),
               (procedural.box((1.0, 1.0, 1.0)), xform(translate=(0, 0.5, 0)), Material(albedo=(0.8, 0.8, 0.8)))]
    camera = Camera(position=(0.0, 4.0, 2.5), look_at=(0.0, 0.0, 0.0), fov_deg=60.0, resolution=(48, 48))
    scene, tris, keep = make_scene(ctx, objects, env, camera)
    gb, planes = gbuffer_of(ctx, scene, camera)
    d = np.array([0.4, 0.8, -0.8])  # the shadow falls towards +z, the camera's side
    d /= np.linalg.norm(d)
    doms = dm.domain_array(d[None], np.ones((1, 3)), cap_radius=[0.0])
    got, _ = render(ctx, scene, gb, doms, resolution=256)
    floor = planes["instance"] == 0
    p = planes["position"][..., :3].astype(np.float64)
    # Exact shadow of the unit box on the floor (y = 0): the ray from p towards d enters the box.
    hits = []
    for s_ in np.linspace(0.0, 1.0, 65):
        q = p + (s_ / d[1]) * d[None, None, :]
        hits.append((np.abs(q[..., 0]) < 0.5) & (np.abs(q[..., 2]) < 0.5) & (q[..., 1] <= 1.0))
    shadowed = np.any(hits, axis=0) & floor
    lit = floor & ~shadowed
    # Contact pixels: in the exact shadow and within 0.15 of the box's footprint.
    gap = np.maximum(np.abs(p[..., [0, 2]]) - 0.5, 0).max(-1)
    contact = shadowed & (gap < 0.15)
    assert contact.sum() >= 5 and lit.sum() > 100
    assert (got[contact][:, 0] == 0).all(), "light leaks under the box"
    # Away from the shadow's outline (2 texels of the 256 map) the lit floor is lit.
    assert np.mean(got[lit][:, 0] > 0) > 0.97


# --------------------------------------------------------------------------- hard cases


def test_strong_sun(ctx, box_scene):
    """A 10^5 : 1 sun: one domain holds nearly all the power; the image is
    the sun's hard shadow plus the sky, close to the reference."""
    s = box_scene
    sky = np.full((32, 64, 3), 0.2, np.float32)
    sky[8, 20] = 0.2 * 1e5
    env = EnvMap(ctx, sky, face_size=16)
    s["scene"].set_envmap(env)
    try:
        doms = domains_of(sky, 16)
        power = doms[:, 4:7].sum(1)
        assert power.max() > 0.9 * power.sum()
        got, _ = render(ctx, s["scene"], s["gb"], doms, pcf=1)
        hard, _ = render(ctx, s["scene"], s["gb"], doms)
        # Face 32 with the sun split 8 x 8 (face 16 spreads the 5.6-degree sun texel: 0.035 off).
        ref = shade(ctx, s["scene"], s["gb"], "reference", face_size=32, sun_supersampling=8)[..., :3]
        fg = s["planes"]["instance"] != BACKGROUND
        # PCF 1: measured 0.0148 (0.0094 of it unshadowed: the sun texel as one direction, its cube
        # resampling). The default PCF 0 gives the 5.6-degree sun a hard outline where the reference has
        # a penumbra: measured 0.0304.
        assert nrmse(got[..., :3], ref, fg) < 0.02
        assert nrmse(hard[..., :3], ref, fg) < 0.035
    finally:
        s["scene"].set_envmap(s["env"])


def test_black_and_constant_maps(ctx, box_scene):
    s = box_scene
    black = dm.domain_array(s["domains"][:, :3], np.zeros((16, 3)))
    img, _ = render(ctx, s["scene"], s["gb"], black)
    fg = s["planes"]["instance"] != BACKGROUND
    assert (img[fg][:, :3] == 0).all()
    const = domains_of(np.ones((32, 64, 3), np.float32), 32)
    got, _ = render(ctx, s["scene"], s["gb"], const)
    free, _ = render(ctx, s["scene"], s["gb"], const, visibility=0)
    # Unshadowed diffuse under a constant map of radiance 1: rho (up to the domains' quadrature error).
    plane = s["planes"]["instance"] == 0
    assert np.all(got[fg] <= free[fg] + 1e-6) and (got[plane] < free[plane]).any()


def test_one_domain(ctx, box_scene):
    s = box_scene
    doms = domains_of(procedural.sky(64, 32), 1)
    assert abs(doms[0, 7] - math.pi) < 1e-5
    img, _ = render(ctx, s["scene"], s["gb"], doms)
    assert np.isfinite(img).all() and img[..., :3].max() > 0


def tiny_box_scene(ctx, floor_size, centre):
    env = EnvMap(ctx, procedural.constant(1.0), face_size=8)
    c = np.asarray(centre, np.float64)
    objects = [(procedural.plane((floor_size, floor_size)), xform(translate=c), Material()),
               (procedural.box((0.01, 0.01, 0.01)), xform(translate=c + [0, 0.005, 0]), Material())]
    camera = Camera(position=tuple(c + [0.0, 0.03, 0.02]), look_at=tuple(c), fov_deg=60.0, resolution=(24, 24))
    scene, _, keep = make_scene(ctx, objects, env, camera)
    gb, planes = gbuffer_of(ctx, scene, camera)
    d = np.array([0.6, 0.8, 0.0])
    doms = dm.domain_array(d[None], np.ones((1, 3)), cap_radius=[0.0])
    p = planes["position"][..., :3].astype(np.float64) - c
    floor = planes["instance"] == 0
    # In the box's exact shadow (it reaches 0.0075 beyond the box towards -x), outside its footprint.
    shadow = floor & (p[..., 0] > -0.0115) & (p[..., 0] < -0.0065) & (np.abs(p[..., 2]) < 0.004)
    lit = floor & ((p[..., 0] > 0.007) | (np.abs(p[..., 2]) > 0.007))
    return scene, gb, doms, shadow, lit, keep


def test_tiny_object_far_from_the_origin(ctx):
    """A 1 cm box on a 10 cm floor 1 km from the origin (float32 positions
    there are ~6e-5 m, a sixth of the box): the fit is to the scene, so the
    map still resolves the box; its shadow is there and the rest is lit."""
    scene, gb, doms, shadow, lit, keep = tiny_box_scene(ctx, 0.1, (1000.0, 0.0, -1000.0))
    assert shadow.sum() > 3 and lit.sum() > 50
    got, _ = render(ctx, scene, gb, doms, resolution=256)
    assert (got[shadow][:, 0] == 0).all() and (got[lit][:, 0] > 0).all()


def test_tiny_object_on_a_huge_floor(ctx):
    """fit 0 (every instance) is the documented limit (docs/depthmap.md): a
    100 m floor makes 256 texels 39 cm wide and a 1 cm box's shadow is lost;
    fit 1 (the default) fits the maps to the box, since nothing lies under
    the floor, and keeps it; nothing else breaks."""
    scene, gb, doms, shadow, lit, keep = tiny_box_scene(ctx, 100.0, (0.0, 0.0, 0.0))
    assert shadow.sum() > 3
    got, _ = render(ctx, scene, gb, doms, resolution=256, fit=0)
    assert np.isfinite(got).all() and (got[shadow][:, 0] > 0).all() and (got[lit][:, 0] > 0).all()
    got, _ = render(ctx, scene, gb, doms, resolution=256)
    assert (got[shadow][:, 0] == 0).all() and (got[lit][:, 0] > 0).all()


def gbuffer_with_a_far_receiver(ctx, planes):
    """The scene's G-buffer with pixel (0, 0) moved far outside every map's
    footprint: an up-facing receiver at (50, -20, 30)."""
    from penumbra import GBuffer

    planes = {k: v.copy() for k, v in planes.items()}
    planes["position"][0, 0] = [50.0, -20.0, 30.0, 1.0]
    planes["normal"][0, 0] = [0.0, 1.0, 0.0, 0.0]
    planes["instance"][0, 0] = 0
    planes["albedo"][0, 0] = [0.5, 0.5, 0.5, 0.0]
    h, w = planes["instance"].shape
    gb = GBuffer(ctx, w, h)
    for name, plane in planes.items():
        gb.write(name, plane)
    return gb


def test_receiver_outside_every_footprint(ctx, box_scene):
    """A caller's G-buffer pixel far outside the scene is lit by every domain above it."""
    s = box_scene
    gb = gbuffer_with_a_far_receiver(ctx, s["planes"])
    got, _ = render(ctx, s["scene"], gb, s["domains"])
    free, _ = render(ctx, s["scene"], gb, s["domains"], visibility=0)
    assert got[0, 0, 0] > 0 and np.allclose(got[0, 0], free[0, 0], rtol=1e-6)


def test_empty_scene(ctx, sky):
    from penumbra import Scene, GBuffer

    env = EnvMap(ctx, sky, face_size=8)
    scene = Scene(ctx)
    scene.set_envmap(env)
    scene.set_camera(Camera(position=(0, 1, 3), look_at=(0, 0, 0), resolution=(8, 6)))
    scene.commit()
    gb = GBuffer(ctx, 8, 6)
    scene.render_gbuffer(gb)
    img, r = render(ctx, scene, gb, domains_of(sky, 4))
    assert np.isfinite(img).all()
    with pytest.raises(PenumbraError, match="no triangles"):
        r.read_output(scene, "depth_map", 0, 0)


@pytest.mark.parametrize("edit,match", [
    (lambda d: d.__setitem__((2, 0), np.nan), "domain 2 has a non-finite direction"),
    (lambda d: d.__setitem__((1, 5), np.inf), "domain 1 has a non-finite radiance"),
    (lambda d: d.__setitem__((0, 4), -1.0), "domain 0 has a negative radiance"),
    (lambda d: d.__setitem__((3, slice(0, 3)), [2.0, 0.0, 0.0]), "length 2: it must be unit"),
    (lambda d: d.__setitem__((3, 7), 4.0), "cap radius 4"),
])
def test_bad_caller_domains_are_refused(ctx, box_scene, edit, match):
    doms = box_scene["domains"].copy()
    edit(doms)
    r = Renderer(ctx, "depthmap")
    with pytest.raises(InputError, match=match):
        dm.set_domains(r, doms)


def test_domains_for_other_methods_and_sizes_are_refused(ctx, box_scene):
    with pytest.raises(PenumbraError, match="takes no env domains"):
        dm.set_domains(Renderer(ctx, "unshadowed"), box_scene["domains"])
    with pytest.raises(InputError, match=r"\(N, 8\)"):
        dm.set_domains(Renderer(ctx, "depthmap"), np.zeros((4, 7)))
    r = Renderer(ctx, "depthmap")
    dm.set_domains(r, box_scene["domains"])
    with pytest.raises(PenumbraError, match="depth map 16: the method has 16 domains"):
        r.read_output(box_scene["scene"], "depth_map", 0, 16)


def test_the_library_decomposition_is_used_without_caller_domains(ctx, box_scene):
    """No caller domains: the renderer decomposes the scene's env map with its
    `directions` and `seed`; returning to it after caller domains (count 0) works.
    (sharp 0: the whole map decomposed, as the twin's domains are; the sharp
    split is tests/test_depthmap_sharp.py's.)"""
    s = box_scene
    r = Renderer(ctx, "depthmap", directions=16, sharp=0)
    img = Image(ctx, s["gb"].width, s["gb"].height)
    r.execute(s["scene"], s["gb"], img)
    own = img.read()
    doms = r.read_output(s["scene"], "domains", 0)
    assert doms.shape == (16, 8)
    assert np.allclose(doms[:, 4:7].sum(0), s["domains"][:, 4:7].sum(0), rtol=1e-5)
    twin, _ = render(ctx, s["scene"], s["gb"], s["domains"])
    fg = s["planes"]["instance"] != BACKGROUND
    assert nrmse(own[..., :3], twin[..., :3], fg) < 1e-3
    dm.set_domains(r, s["domains"][:4])
    r.execute(s["scene"], s["gb"], img)
    assert r.read_output(s["scene"], "domains", 0).shape == (4, 8)
    dm.set_domains(r, None)
    r.execute(s["scene"], s["gb"], img)
    assert np.array_equal(img.read(), own)


@pytest.mark.parametrize("n,samples,pointwise", [(10, 4, 2e-3), (100, 16, 0.012), (1000, 64, 0.08)])
def test_cap_quadrature_against_the_exact_cap_average(n, samples, pointwise):
    """float64: the cap quadrature's average of cos^n over a cap of radius
    pi/8 against the exact cap average (depthmap64.phong_cap_average), R
    from the centre to twice the radius; unlike the seed's blend it keeps the
    specular energy (docs/depthmap.md gives the table)."""
    r = math.pi / 8
    centre = np.array([0.0, 0.0, 1.0])
    pts = d64.cap_points(centre, r, samples)

    def quad(cpc):
        s = math.sqrt(max(1.0 - cpc * cpc, 0.0))
        rs = [np.array([s * math.cos(a), s * math.sin(a), cpc]) for a in np.linspace(0, 2 * math.pi, 16, endpoint=False)]
        return float(np.mean([np.mean(np.maximum(pts @ rr, 0) ** n) for rr in rs]))

    psis = np.linspace(0, 2 * r, 21)
    exact = np.array([d64.phong_cap_average(math.cos(p), r, n) for p in psis])
    got = np.array([quad(math.cos(p)) for p in psis])
    assert np.abs(got - exact).max() <= pointwise * exact[0]
    assert abs(d64.phong_energy(quad, r, n, nodes=60) - 1.0) < 0.015
    blend = d64.phong_energy(lambda c: float(d64.seed_blend(c, r, n)), r, n, nodes=60)
    if n >= 100:
        assert blend < 0.7  # the seed's blend loses a third and more of the lobe here


# --------------------------------------------------------------------------- the table of exact cap averages

LOBE_INDEX = {"phong": 0, "blinn_phong": 1, "ggx": 2}
# The shaded box scene with the table (test_shading_matches_float64) against
# the twin's exact cap ratio, relative to the pixel: the table's interpolation
# error (CAP_TABLE_ATOL, of a domain's specular peak) diluted by the diffuse
# term and the other domains (measured: see the test's assertion message).
CAP_TABLE_SHADE_RTOL = 3e-3


@pytest.fixture(scope="module")
def lobe_scene(ctx, sky):
    """A scene whose only use is its camera at the origin: the lobe tests write their own G-buffers."""
    camera = Camera(position=(0.0, 0.0, 0.0), look_at=(0.0, 0.0, -1.0), fov_deg=50.0, resolution=(8, 8))
    scene, _, keep = make_scene(ctx, [(procedural.plane((1.0, 1.0)), xform(translate=(0, -5, 0)), Material())],
                                EnvMap(ctx, sky, face_size=8), camera)
    return scene, keep


def lobe_pixels(psis, azimuths, tilt):
    """Unit (normal, view) pairs whose reflection direction R is at each angle of
    ``psis`` from the domain's centre +z, at each azimuth; the normal leans from
    the bisector of R and +z by ``tilt`` (0: the bisector), so n.d > 0."""
    normals, views = [], []
    d = np.array([0.0, 0.0, 1.0])
    for psi in psis:
        for az in azimuths:
            refl = np.array([math.sin(psi) * math.cos(az), math.sin(psi) * math.sin(az), math.cos(psi)])
            n = refl + d
            n = n / np.linalg.norm(n) if np.linalg.norm(n) > 1e-9 else np.array([1.0, 0.0, 0.0])
            if tilt:
                side = np.cross(n, [math.cos(az + 1.0), math.sin(az + 1.0), 0.3])
                n = math.cos(tilt) * n + math.sin(tilt) * side / np.linalg.norm(side)
            normals.append(n)
            views.append(2.0 * (n @ refl) * n - refl)
    return np.array(normals), np.array(views)


def lobe_render(ctx, scene, normals, views, material, r, **params):
    """The renderer's a (per unit k_s, albedo 0) of one domain (+z, cap radius r,
    radiance 1) at every (normal, view), and the float32 inputs it saw."""
    count = len(normals)
    gb = GBuffer(ctx, count, 1)
    pos = np.zeros((1, count, 4), np.float32)
    pos[0, :, :3] = -views  # the camera is at the origin: the view direction is -position
    nrm = np.zeros((1, count, 4), np.float32)
    nrm[0, :, :3] = normals
    alb = np.zeros((1, count, 4), np.float32)
    alb[0, :, 3] = 1.0
    mat = np.zeros((1, count, 4), np.float32)
    mat[0, :, :3] = material
    for plane, data in (("position", pos), ("normal", nrm), ("albedo", alb), ("material", mat),
                        ("instance", np.zeros((1, count), np.uint32))):
        gb.write(plane, data)
    dom = dm.domain_array([[0.0, 0.0, 1.0]], [[1.0, 1.0, 1.0]], cap_radius=[r])
    params.setdefault("lobe_tables", 1)  # the scene's own material is diffuse: the G-buffer carries the lobes
    img, _ = render(ctx, scene, gb, dom, visibility=0, **params)
    p64 = pos[0, :, :3].astype(np.float64)
    n64 = nrm[0, :, :3].astype(np.float64)
    return img[0, :, 0].astype(np.float64), -p64 / np.linalg.norm(p64, axis=1)[:, None], \
        n64 / np.linalg.norm(n64, axis=1)[:, None], float(dom[0, 7])


@pytest.mark.parametrize("shininess", [1.0, 10.0, 100.0, 1000.0, 10000.0])
def test_cap_table_against_the_exact_cap_average(ctx, lobe_scene, shininess):
    """specular 3, Phong: the table's value against the float64 model it
    tabulates, (n + 2)/(2 pi) A(psi_c, r, n) (n.l) with A the exact cap average
    by quadrature (depthmap64.phong_cap_average) and l the cap's point nearest R,
    over caps from 1e-3 rad to the whole sphere and R from the cap's centre to
    six lobe widths beyond its edge. Error relative to the value at psi_c = 0
    (the domain's brightest highlight): docs/depthmap.md gives the table."""
    scene, _ = lobe_scene
    sigma = 1.0 / math.sqrt(shininess + 1.0)
    worst = 0.0
    for r in (1e-3, 0.01, 0.05, 0.2, 0.6, 1.5, math.pi):
        psis = np.unique(np.concatenate([np.linspace(0.0, min(r + 6 * sigma, math.pi - 1e-3), 41),
                                         np.clip(r + sigma * np.linspace(-3, 3, 13), 0.0, math.pi - 1e-3)]))
        normals, views = lobe_pixels(psis, (0.3, 2.5), 0.0)
        got, v64, n64, r32 = lobe_render(ctx, scene, normals, views, (shininess, 0.1, 0), r, specular=3,
                                         table_min_exponent=1)
        d = np.array([0.0, 0.0, 1.0])
        f = lambda l: (shininess + 2) / (2 * math.pi) * max(float(refl @ l), 0.0) ** shininess  # noqa: E731
        want = np.empty(len(got))
        for k in range(len(got)):
            refl = 2.0 * (n64[k] @ v64[k]) * n64[k] - v64[k]
            want[k] = d64.table_average(n64[k], v64[k], d, r32, "phong", shininess, 0.1, f, min_n=1)
        peak = (shininess + 2) / (2 * math.pi) * d64.phong_cap_average(1.0, r32, shininess, 400)
        worst = max(worst, float(np.abs(got - want).max() / peak))
    assert worst < CAP_TABLE_ATOL[shininess], worst


# Largest error of the table's value over the exact model, relative to the
# value at psi_c = 0 (measured 3.2e-3, 1.3e-3, 1.8e-3, 3.1e-3, 9.4e-3; the
# bounds round them up): trilinear interpolation of a 48 x 64 x 32 grid, whose
# n axis steps by a factor 1.56 (1 to 10^6) and float32 coordinates (psi_c
# from atan2, the grid position from logarithms).
CAP_TABLE_ATOL = {1.0: 5e-3, 10.0: 3e-3, 100.0: 3e-3, 1000.0: 5e-3, 10000.0: 1.5e-2}


@pytest.mark.parametrize("lobe, shininess, roughness", [("phong", 1.0, 0.1), ("phong", 100.0, 0.1),
                                                       ("phong", 1000.0, 0.1), ("blinn_phong", 40.0, 0.1),
                                                       ("blinn_phong", 400.0, 0.1), ("ggx", 0.0, 0.3),
                                                       ("ggx", 0.0, 0.1), ("ggx", 0.0, 0.03)])
def test_cap_table_against_the_lobes_cap_average(ctx, lobe_scene, lobe, shininess, roughness):
    """specular 3 against the true average of f_lobe(l) max(0, n.l) over the
    cap (4096 cap points, float64), for every lobe: what the table does not
    model (the cosine taken at one point; Blinn-Phong and GGX as a Phong lobe
    of the equivalent exponent) on top of its interpolation. Normals lean 0.3
    rad off the bisector of R and the cap's centre. Error relative to the
    largest true value of the sweep; CAP_LOBE_ATOL holds the measured bounds
    (docs/depthmap.md gives them), and the 16-point quadrature's error is
    asserted larger for the sharp lobes, where the table is meant to win."""
    from penumbra.brdf import lobe as brdf_lobe

    scene, _ = lobe_scene
    n_eq = d64.equivalent_exponent(lobe, shininess, roughness)
    sigma = 1.0 / math.sqrt(n_eq + 1.0)
    worst_table = worst_quad = 0.0
    for r in (0.02, 0.1, 0.3, 0.8):
        psis = np.linspace(0.0, min(r + 5 * sigma, 1.2), 25)
        normals, views = lobe_pixels(psis, (0.3, 2.5), 0.3)
        mat = (shininess, roughness, LOBE_INDEX[lobe])
        got, v64, n64, r32 = lobe_render(ctx, scene, normals, views, mat, r, specular=3, table_min_exponent=1)
        quad, *_ = lobe_render(ctx, scene, normals, views, mat, r, specular=2, cap_samples=16)
        pts = d64.cap_points(np.array([0.0, 0.0, 1.0]), r32, 4096)
        want = np.empty(len(got))
        for k in range(len(got)):
            nl = pts @ n64[k]
            up = nl > 0
            want[k] = np.sum(brdf_lobe(n64[k], v64[k], pts[up], lobe, shininess, roughness) * nl[up]) / len(pts)
        scale = want.max()
        worst_table = max(worst_table, float(np.abs(got - want).max() / scale))
        worst_quad = max(worst_quad, float(np.abs(quad - want).max() / scale))
    assert worst_table < CAP_LOBE_ATOL[(lobe, shininess, roughness)], (worst_table, worst_quad)
    if n_eq >= 250:
        assert worst_quad > 2 * worst_table, (worst_table, worst_quad)


# Measured largest errors of the table (table_min_exponent 1) against the
# lobe's true cap average (test above), rounded up: 0.166, 0.023, 0.015 (Phong
# n = 1, 100, 1000; n = 1 errs by the cosine over wide caps), 0.110, 0.028
# (Blinn-Phong n = 40, 400, from their own table with the view angle; n = 40,
# s = 0.32 rad, is broader than the table's flat model suits), 0.087, 0.030,
# 0.016 (GGX alpha = 0.3, 0.1, 0.03; tests/test_depthmap_lobes.py sweeps the
# view angle). As Phong lobes of the equivalent exponent (the former rule)
# Blinn-Phong and GGX erred by 0.100, 0.145, 0.201, 0.313, 0.316. The 16-point
# quadrature: 0.025, 0.86, 12.8, 0.045, 0.95, 0.043, 0.44, 6.3.
CAP_LOBE_ATOL = {("phong", 1.0, 0.1): 0.2, ("phong", 100.0, 0.1): 0.03, ("phong", 1000.0, 0.1): 0.02,
                 ("blinn_phong", 40.0, 0.1): 0.13, ("blinn_phong", 400.0, 0.1): 0.035, ("ggx", 0.0, 0.3): 0.11,
                 ("ggx", 0.0, 0.1): 0.04, ("ggx", 0.0, 0.03): 0.02}


# --------------------------------------------------------------------------- the caller's maps


@pytest.mark.parametrize("params", [dict(skip_power=0.0), dict(skip_power=0.05, pcf=1), dict(half_maps=1)])
def test_supplied_maps_give_the_same_image_bit_for_bit(ctx, box_scene, params):
    """Maps read back from one renderer (domains, map_frames, depth_map) and
    supplied to a second give its image bit for bit. The second renders a
    scene without the boxes (same G-buffer): had it drawn its own maps, the
    boxes' shadows would be gone."""
    s = box_scene
    first, r1 = render(ctx, s["scene"], s["gb"], s["domains"], resolution=64, **params)
    doms, frames, maps = dm.read_maps(r1, s["scene"])
    assert frames[:, 15].sum() == dm.maps_drawn(r1, s["scene"]) > 0
    floor_only, _, keep = make_scene(ctx, [(procedural.plane((4.0, 4.0)), xform(), Material())], s["env"],
                                     s["camera"])
    r2 = Renderer(ctx, "depthmap", resolution=64, **params)
    dm.set_domains(r2, doms)
    dm.set_maps(r2, frames, maps)
    img = Image(ctx, s["gb"].width, s["gb"].height)
    r2.execute(floor_only, s["gb"], img)
    assert np.array_equal(img.read(), first)
    back = dm.read_maps(r2, floor_only)
    assert np.array_equal(back[1], frames) and np.array_equal(back[2], maps)
    # Back to drawing: the floor alone casts no shadow, so the image changes.
    dm.set_maps(r2, None, None)
    r2.execute(floor_only, s["gb"], img)
    assert not np.array_equal(img.read(), first)


def test_supplied_maps_are_checked(ctx, box_scene):
    s = box_scene
    _, r1 = render(ctx, s["scene"], s["gb"], s["domains"], resolution=32)
    doms, frames, maps = dm.read_maps(r1, s["scene"])
    r = Renderer(ctx, "depthmap", resolution=32)
    with pytest.raises(PenumbraError, match="depth maps of 64 x 64 texels but the renderer's resolution is 32"):
        dm.set_maps(r, frames, np.zeros((16, 64, 64), np.float32))
    dm.set_domains(r, doms)
    with pytest.raises(PenumbraError, match="15 depth maps but the renderer shades with 16 domains"):
        dm.set_maps(r, frames[:15], maps[:15])
    bad = maps.copy()
    bad[3, 5, 7] = np.nan
    with pytest.raises(InputError, match=r"depth map 3 has nan at texel \(7, 5\)"):
        dm.set_maps(r, frames, bad)
    bad[3, 5, 7] = -1.0
    with pytest.raises(InputError, match=r"depth map 3 has -1 at texel \(7, 5\)"):
        dm.set_maps(r, frames, bad)
    f = frames.copy()
    f[2, 0:3] *= 2.0
    with pytest.raises(InputError, match="depth map 2's frame is not orthonormal"):
        dm.set_maps(r, f, maps)
    f = frames.copy()
    f[4, 13] = 0.0
    with pytest.raises(InputError, match="depth map 4's frame has texel sizes"):
        dm.set_maps(r, f, maps)
    f = frames.copy()
    f[1, 6] = np.inf
    with pytest.raises(InputError, match="depth map 1's frame has a non-finite value at float 6"):
        dm.set_maps(r, f, maps)
    with pytest.raises(PenumbraError, match="takes no depth maps"):
        dm.set_maps(Renderer(ctx, "unshadowed"), frames, maps)
    img = Image(ctx, s["gb"].width, s["gb"].height)
    # Without caller domains the count is checked at execute, against the decomposition's.
    r3 = Renderer(ctx, "depthmap", resolution=32, directions=8)
    dm.set_maps(r3, frames, maps)
    with pytest.raises(PenumbraError, match="16 depth maps were supplied but the renderer shades with 8 domains"):
        r3.execute(s["scene"], s["gb"], img)
    # A map that does not look along its domain.
    f = frames.copy()
    f[[0, 1]] = f[[1, 0]]
    dm.set_maps(r, f, maps)
    with pytest.raises(InputError, match="supplied depth map 0 looks along"):
        r.execute(s["scene"], s["gb"], img)
    # The resolution changed since.
    dm.set_maps(r, frames, maps)
    r.set(resolution=64)
    with pytest.raises(PenumbraError, match="maps are 32 x 32 texels but the renderer's resolution is now 64"):
        r.execute(s["scene"], s["gb"], img)


# --------------------------------------------------------------------------- skip_power


def test_skip_power_bounds_the_change_and_drops_maps(ctx, box_scene):
    """Domains whose powers add up to at most skip_power of the total get no
    map and are lit unshadowed: the image can only brighten, by at most the
    skipped domains' unshadowed light; fewer maps are drawn."""
    s = box_scene
    doms = domains_of(procedural.sky(64, 32), 64)
    full, r0 = render(ctx, s["scene"], s["gb"], doms, skip_power=0.0)
    assert dm.maps_drawn(r0, s["scene"]) == 64
    lum = doms[:, 4:7] @ np.array([0.2126, 0.7152, 0.0722], np.float32)
    fg = s["planes"]["instance"] != BACKGROUND
    drawn = []
    for fraction in (0.001, 0.01, 0.05, 0.2):
        got, r = render(ctx, s["scene"], s["gb"], doms, skip_power=fraction)
        frames = r.read_output(s["scene"], "map_frames", 0)
        skipped = frames[:, 15] == 0
        drawn.append(int((~skipped).sum()))
        assert drawn[-1] == dm.maps_drawn(r, s["scene"])
        assert lum[skipped].sum() <= fraction * lum.sum() * (1 + 1e-6)
        # The weakest go first: every skipped domain is weaker than every shadowed one, and as many as fit.
        assert not skipped.any() or lum[skipped].max() <= lum[~skipped].min()
        assert skipped.all() or lum[skipped].sum() + lum[~skipped].min() > fraction * lum.sum() * (1 - 1e-6)
        # The change: between 0 and the skipped domains' unshadowed light (their own image, visibility 0).
        if skipped.any():
            bound, _ = render(ctx, s["scene"], s["gb"], doms[skipped], visibility=0)
        else:
            bound = np.zeros_like(got)
        delta = got[..., :3] - full[..., :3]
        tol = 1e-5 * full[..., :3][fg].max()
        assert (delta[fg] >= -tol).all() and (delta[fg] <= bound[..., :3][fg] + tol).all(), fraction
        assert np.sqrt(np.mean(delta[fg] ** 2)) / (full[fg].max() - full[fg].min()) <= fraction
    # Measured: 64, 56, 36 and 2 maps (the sun's domains) at 0.001 / 0.01 / 0.05 / 0.2.
    assert drawn == sorted(drawn, reverse=True) and drawn[1] < 64 and drawn[-1] <= 4
    assert delta[fg].max() > 0  # at 0.2 some skipped light reaches a shadowed pixel
    # A skipped domain's map reads as empty; drawing none at all still shades (unshadowed).
    i = int(np.argmin(lum))
    assert np.isposinf(r.read_output(s["scene"], "depth_map", 0, i)).all()
    none, r = render(ctx, s["scene"], s["gb"], doms, skip_power=1.0)
    free, _ = render(ctx, s["scene"], s["gb"], doms, visibility=0)
    assert dm.maps_drawn(r, s["scene"]) == 0 and np.array_equal(none, free)


# --------------------------------------------------------------------------- 16-bit maps


def test_half_maps_are_close_and_keep_the_bias_policy(ctx, box_scene):
    """half_maps 1: the lookups read depths quantised to extent / 65534, far
    below the bias (a texel), so the image barely moves; the maps read back
    are the float ones; no acne appears on a lit plane (the bias holds)."""
    s = box_scene
    full, _ = render(ctx, s["scene"], s["gb"], s["domains"])
    half, r = render(ctx, s["scene"], s["gb"], s["domains"], half_maps=1)
    fg = s["planes"]["instance"] != BACKGROUND
    err = nrmse(half[..., :3], full[..., :3], fg)
    assert err < 2e-3, err
    # Without bias the surfaces compare against their own quantised depths: the lookups must differ (the 16-bit
    # copies are what is read).
    raw = dict(bias=0.0, slope_bias=0.0, receiver_plane=0)
    assert not np.array_equal(render(ctx, s["scene"], s["gb"], s["domains"], half_maps=1, **raw)[0],
                              render(ctx, s["scene"], s["gb"], s["domains"], **raw)[0])
    scene, gb, planes, keep, _ = lit_plane(ctx, 0.6)
    k = np.arange(32)
    elev = np.radians(3.0 + 84.0 * (k % 16) / 15.0)
    local = np.stack([np.cos(elev) * np.cos(2.39996 * k), np.sin(elev), np.cos(elev) * np.sin(2.39996 * k)], 1)
    doms = dm.domain_array(local @ rotation((1, 0, 0), 0.6).T, np.ones((32, 3)) * 0.05)
    plane_fg = planes["instance"] != BACKGROUND
    free, _ = render(ctx, scene, gb, doms, visibility=0)
    got, _ = render(ctx, scene, gb, doms, half_maps=1)
    assert np.abs(got[plane_fg] - free[plane_fg]).max() <= 1e-6 * free[plane_fg].max()
