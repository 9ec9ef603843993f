"""soft_shadows (docs/depthmap.md, "Penumbrae from the cap: soft_shadows"):
the lookups of a domain filtered by a percentage-closer soft shadow whose
width is the domain's cap radius times the receiver-to-blocker distance.
The kernel's filter against its float64 twin (below), the penumbra of a
plate over a floor against the analytic one of a cap, the modes and bad
input."""

from __future__ import annotations

import math

import numpy as np
import pytest
from test_depthmap import box_scene, render, sky  # noqa: F401  (fixtures)
from test_reference import gbuffer_of, make_scene, xform
from tolerances import DEPTHMAP_DEPTH_ATOL, DEPTHMAP_SHADE_RTOL

import depthmap64 as d64
from penumbra import BACKGROUND, Camera, EnvMap, InputError, Material, PenumbraError, procedural
from penumbra.methods import depthmap as dm

SOFT_MAX = 8.0  # DM_SOFT_MAX, texels
SOFT_STEPS = 3  # DM_SOFT_STEPS
Q_MAX = 65534.0


def _disc(k):
    return [(di, dj) for dj in range(-k, k + 1) for di in range(-k, k + 1) if di * di + dj * dj <= k * k]


def soft_visibility(frame, depth, p, bias, slope_bias, tan_theta, tan_r, margin):
    """float64 twin of dm_soft_visibility: (v, ambiguous). Ambiguous when a
    depth comparison is within `margin` of its threshold or a tap's
    coordinate within 1e-4 texel of a texel edge (float32 may go either way)."""
    f = np.asarray(frame, np.float64)
    res = depth.shape[0]
    tu, tv, z0 = d64.map_coordinates(f, p)
    texel = max(f[12], f[13])
    amb = False

    def tap(x, y):
        nonlocal amb
        for c in (x, y):
            if abs(c - round(c)) < 1e-4:
                amb = True
        i, j = math.floor(x), math.floor(y)
        if i < 0 or j < 0 or i >= res or j >= res:
            return math.inf
        return depth[j, i]

    zs = z0 - texel * (bias + slope_bias * tan_theta)
    ws = min(max(z0, 0.0) * tan_r / texel, SOFT_MAX)
    edge = ws + 1.0
    if not (-edge <= tu < res + edge and -edge <= tv < res + edge):
        return 1.0, False
    ks = min(max(math.ceil(ws), 1), SOFT_STEPS)
    hs = ws / ks
    found = []
    for di, dj in _disc(ks):
        d = tap(tu + di * hs, tv + dj * hs)
        if abs(d - zs) <= margin:
            amb = True
        if d < zs:
            found.append(d)
    if not found:
        return 1.0, amb
    w = min(max(zs - float(np.mean(found)), 0.0) * tan_r / texel, SOFT_MAX)
    if 0.5 < w < SOFT_STEPS + 0.5 and abs(w - round(w)) < 1e-4:
        amb = True  # ceil(w) may differ
    z = z0 - texel * (bias + slope_bias * (w + 1.0) * tan_theta)
    k = min(max(math.ceil(w), 1), SOFT_STEPS)
    h = w / k
    taps = _disc(k)
    lit = 0
    for di, dj in taps:
        d = tap(tu + di * h, tv + dj * h)
        if abs(d - z) <= margin:
            amb = True
        lit += z <= d
    return lit / len(taps), amb


def twin_image(planes, camera_position, domains, frames, maps, soft_count, margin, bias=1.0, slope_bias=1.0):
    """float64 L_o with the point-sample lobe (specular 0): the first soft_count
    domains by soft_visibility, the rest by depthmap64.visibility (pcf 0); and
    the mask of pixels whose value is ambiguous."""
    h, w = planes["instance"].shape
    out = np.zeros((h, w, 3))
    amb = np.zeros((h, w), bool)
    dom = np.asarray(domains, np.float64)
    dirs, rad, caps = dom[:, :3], dom[:, 4:7], dom[:, 7]
    for y, x, p, n, v, alb, mat in d64.shading_pixels(planes, camera_position):
        for i in np.flatnonzero(dirs @ n > 0):
            c = float(dirs[i] @ n)
            tan_theta = min(math.sqrt(max(1.0 - c * c, 0.0)) / c, d64.MAX_SLOPE)
            if i < soft_count:
                vis, a = soft_visibility(frames[i], maps[i], p, bias, slope_bias, tan_theta,
                                         math.tan(min(caps[i], 1.5)), margin)
            else:
                b = d64.map_bias(frames[i], c, bias, slope_bias, 0)
                lo, hi = d64.visibility(frames[i], maps[i], p, b, 0, margin)
                vis, a = lo, lo != hi
            amb[y, x] |= a
            if vis == 0:
                continue
            s = d64.specular_average(n, v, dirs[i], caps[i], mat, 0, 16) if alb[3] > 0 else 0.0
            out[y, x] += vis * rad[i] * (alb[:3] / math.pi * c + alb[3] * s)
    return out, amb


@pytest.mark.parametrize("params", [dict(), dict(half_maps=1), dict(resolution=24)])
def test_soft_lookup_matches_float64(ctx, box_scene, params):
    """Every domain filtered (soft_shadows 2) on the box scene under the sky's
    16 domains (caps of 0.02 to 0.8 rad: filters from sub-texel to the
    clamp): the image is the twin's wherever no comparison is ambiguous, and
    it differs from the hard lookup's."""
    s = box_scene
    params = dict(dict(resolution=64), **params)
    got, r = render(ctx, s["scene"], s["gb"], s["domains"], specular=0, soft_shadows=2, **params)
    got = got[..., :3]
    frames = r.read_output(s["scene"], "map_frames", 0).astype(np.float64)
    _, _, maps = dm.read_maps(r, s["scene"])
    if params.get("half_maps"):
        maps = [np.where(np.isinf(m), np.inf,
                         np.minimum(np.rint(np.where(np.isinf(m), 0, m) / frames[i, 14] * np.float32(Q_MAX)),
                                    np.float32(Q_MAX)) * (frames[i, 14] / np.float32(Q_MAX))).astype(np.float32)
                for i, m in enumerate(maps)]
    maps = [np.asarray(m, np.float64) for m in maps]
    margin = DEPTHMAP_DEPTH_ATOL * frames[:, 14].max()
    want, amb = twin_image(s["planes"], s["camera"].position, s["domains"], frames, maps, len(s["domains"]), margin)
    fg = s["planes"]["instance"] != BACKGROUND
    check = fg & ~amb
    assert check.sum() > 0.9 * fg.sum(), f"{(fg & amb).sum()} of {fg.sum()} pixels ambiguous"
    scale = np.maximum(want, 1e-3)
    err = np.abs(got - want)[check] / scale[check]
    assert err.max() <= DEPTHMAP_SHADE_RTOL, f"worst relative difference {err.max():.3g}"
    hard, _ = render(ctx, s["scene"], s["gb"], s["domains"], specular=0, **params)
    assert np.abs(hard[..., :3] - got)[fg].max() > 0.05 * got[fg].max()


def segment_lit(t):
    """The lit share of a disc of unit radius whose centre is t radii outside a straight edge (the rest is behind it)."""
    t = np.clip(t, -1.0, 1.0)
    return 1.0 - (np.arccos(t) - t * np.sqrt(1.0 - t * t)) / math.pi


@pytest.fixture(scope="module")
def plate_scene(ctx):
    """A 2 x 2 plate 1 above a floor, one domain straight down; a camera below
    the plate looking at the floor across the plate's edge at x = 1."""
    env = EnvMap(ctx, procedural.constant(1.0), face_size=8)
    grey = Material(albedo=(0.8, 0.8, 0.8))
    objects = [(procedural.plane((6.0, 6.0)), xform(), grey),
               (procedural.box((2.0, 0.02, 2.0)), xform(translate=(0.0, 1.0, 0.0)), grey)]
    camera = Camera(position=(2.2, 0.5, 0.0), look_at=(1.0, 0.0, 0.0), fov_deg=24.0, resolution=(64, 64))
    scene, tris, keep = make_scene(ctx, objects, env, camera)
    gb, planes = gbuffer_of(ctx, scene, camera)
    return dict(env=env, scene=scene, tris=tris, keep=keep, gb=gb, planes=planes)


def plate_profile(ctx, s, cap, **params):
    """The floor's visibility (image over the unshadowed image) and its pixels' signed distance outside the edge."""
    doms = dm.domain_array(np.array([[0.0, 1.0, 0.0]]), np.ones((1, 3)), cap_radius=[cap])
    got, _ = render(ctx, s["scene"], s["gb"], doms, resolution=256, specular=0, **params)
    free, _ = render(ctx, s["scene"], s["gb"], doms, resolution=256, specular=0, visibility=0)
    p = s["planes"]["position"][..., :3].astype(np.float64)
    floor = (s["planes"]["instance"] == 0) & (np.abs(p[..., 2]) < 0.6)
    vis = got[..., 0][floor] / free[..., 0][floor]
    return vis, p[..., 0][floor] - 1.0


@pytest.mark.parametrize("cap", [0.03, 0.05])
def test_penumbra_width_is_the_caps(ctx, plate_scene, cap):
    """The plate's edge 1.0 above the floor (its top 1.01) under a cap of radius
    r: the floor at signed distance s outside the edge sees the lit share of a
    disc of radius R = 1.01 tan r centred s from the edge (3 and 5 texels of
    the 256^2 map). The soft lookup follows that profile; the hard lookup, and
    the profiles of half and twice the width, do not."""
    vis, s = plate_profile(ctx, plate_scene, cap, soft_shadows=2)
    radius = 1.01 * math.tan(cap)
    near = np.abs(s) < 1.5 * radius
    assert near.sum() >= 40 and (np.abs(s) < 0.5 * radius).sum() >= 10
    err = lambda width: float(np.mean(np.abs(vis[near] - segment_lit(s[near] / width))))  # noqa: E731
    assert err(radius) < 0.06, err(radius)
    assert err(0.5 * radius) > 1.5 * err(radius) and err(2.0 * radius) > 1.5 * err(radius), \
        (err(0.5 * radius), err(radius), err(2.0 * radius))
    # a partial penumbra: the soft lookup has values strictly between 0 and 1 there
    assert ((vis[near] > 0.1) & (vis[near] < 0.9)).sum() >= 10
    hard, s_hard = plate_profile(ctx, plate_scene, cap, soft_shadows=0)
    err_hard = float(np.mean(np.abs(hard[near] - segment_lit(s_hard[near] / radius))))
    assert err_hard > 1.5 * err(radius), (err_hard, err(radius))
    # far from the edge: lit outside, dark under the plate
    assert (vis[s > 1.5 * radius] > 0.999).all() and (vis[s < -1.5 * radius] < 1e-3).all()


def test_modes(ctx, box_scene):
    """soft_shadows 1 filters only the env map's sharp domains: with caller
    domains there are none (the image is the hard one, bit for bit); with the
    library's decomposition of a map with a sun, 1 differs from 0, and 2
    from 1."""
    s = box_scene
    hard, _ = render(ctx, s["scene"], s["gb"], s["domains"], specular=0)
    one, _ = render(ctx, s["scene"], s["gb"], s["domains"], specular=0, soft_shadows=1)
    np.testing.assert_array_equal(one, hard)
    from penumbra import Image, Renderer

    images = []
    for mode in (0, 1, 2):
        r = Renderer(ctx, "depthmap", directions=16, sharp=1, soft_shadows=mode, specular=0, strong_resolution=128)
        img = Image(ctx, s["gb"].width, s["gb"].height)
        r.execute(s["scene"], s["gb"], img)
        images.append(img.read())
    assert not np.array_equal(images[0], images[1]) and not np.array_equal(images[1], images[2])


@pytest.mark.parametrize("value", [-1, 3])
def test_bad_mode_is_refused(ctx, box_scene, value):
    with pytest.raises((InputError, PenumbraError), match="soft_shadows"):
        render(ctx, box_scene["scene"], box_scene["gb"], box_scene["domains"], soft_shadows=value)
