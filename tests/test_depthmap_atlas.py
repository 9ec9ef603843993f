"""Per-domain map sizes (strong_resolution: the maps of the strong domains
larger, every map in one atlas) and the caller's maps of any sizes, copied
or read in place from a pyopencl buffer (pn_renderer_set_depth_maps_sized /
_cl), against the float64 twin (tests/depthmap64.py) and the drawn maps;
hard cases and bad input (docs/depthmap.md, "Per-domain map sizes")."""

from __future__ import annotations

import depthmap64 as d64
import numpy as np
import pyopencl as cl
import pytest
from test_depthmap import (box_scene, domains_of, gbuffer_with_a_far_receiver, quantise16, render,  # noqa: F401
                           sky)  # (box_scene is a fixture)
from test_reference import make_scene, xform
from tolerances import DEPTHMAP_DEPTH_ATOL, DEPTHMAP_SHADE_RTOL

from penumbra import BACKGROUND, Image, InputError, Material, PenumbraError, Renderer, procedural
from penumbra.methods import depthmap as dm

LUMA = np.array([0.2126, 0.7152, 0.0722])


def strongest(domains, k):
    """strong_share that makes exactly the k most powerful domains strong."""
    p = np.asarray(domains, np.float64)[:, 4:7] @ LUMA
    share = np.sort(p / p.sum())[::-1]
    assert share[k - 1] > share[k] * (1 + 1e-4)  # no tie at the threshold
    return float(share[k - 1] * (1 - 1e-5)), np.argsort(-p)[:k]


def twin_check(s, r, got, **params):
    """The image against depthmap64.shade with the maps read back (each of its own size)."""
    frames = r.read_output(s["scene"], "map_frames", 0).astype(np.float64)
    _, _, maps = dm.read_maps(r, s["scene"])
    if params.get("half_maps"):
        maps = [quantise16(frames[i:i + 1], m[None])[0] for i, m in enumerate(maps)]
    maps = [np.asarray(m, np.float64) for m in maps]
    p = dict(bias=1.0, slope_bias=1.0, pcf=0, specular=3, cap_samples=16, receiver_plane=1)
    p.update({k: v for k, v in params.items() if k in p})
    p["specular"] = 0  # the lookup is under test: the point-sample lobe has no table error on top
    margin = DEPTHMAP_DEPTH_ATOL * frames[:, 14].max()
    lo, hi = d64.shade(s["planes"], s["camera"].position, s["domains"], frames, maps, margin=margin, **p)
    fg = s["planes"]["instance"] != BACKGROUND
    scale = np.maximum(hi, 1e-3)
    ok = (got >= lo - DEPTHMAP_SHADE_RTOL * scale) & (got <= hi + DEPTHMAP_SHADE_RTOL * scale)
    assert ok[fg].all(), f"{(~ok[fg]).sum()} values off the twin"
    return maps


@pytest.mark.parametrize("params", [dict(), dict(pcf=1), dict(map_renderer=0), dict(half_maps=1, pcf=1),
                                    dict(skip_power=0.05)])
def test_atlas_lookup_matches_float64(ctx, box_scene, params):
    """Three strong 80^2 maps beside 24^2 ones, in one atlas: the maps are the
    twin's rasterisation at their own size, and the shading reads each at its
    own offset and size (the twin shades with the maps as separate arrays)."""
    s = box_scene
    share, strong = strongest(s["domains"], 3)
    got, r = render(ctx, s["scene"], s["gb"], s["domains"], resolution=24, strong_resolution=80, strong_share=share,
                    specular=0, **params)
    sides = dm.map_resolutions(r, s["scene"])
    want = np.full(len(s["domains"]), 24)
    want[strong] = 80
    assert np.array_equal(sides, want)
    assert any(sides[i] != sides[i + 1] for i in range(len(sides) - 1))  # different sizes side by side
    maps = twin_check(s, r, got[..., :3], **params)
    frames = r.read_output(s["scene"], "map_frames", 0).astype(np.float64)
    for i in (int(strong[0]), int(np.flatnonzero(sides == 24)[0])):
        if frames[i, 15] == 0:
            continue  # skip_power: no map
        ref = d64.rasterise(frames[i], s["tris"], int(sides[i]))
        both = np.isfinite(maps[i]) & np.isfinite(ref)
        assert (np.isfinite(maps[i]) != np.isfinite(ref)).mean() <= 0.02 and both.mean() > 0.2
        assert np.mean(np.abs(maps[i][both] - ref[both]) <= DEPTHMAP_DEPTH_ATOL * frames[i, 14]) > 0.98


def test_strong_maps_sharpen_the_outline(ctx, box_scene):
    """The same domains with and without strong maps: only the strong domains'
    pixels change, and the twin holds for both (so the test fails if the atlas
    mixes maps up)."""
    s = box_scene
    share, _ = strongest(s["domains"], 2)
    base, _ = render(ctx, s["scene"], s["gb"], s["domains"], resolution=16, specular=0)
    got, r = render(ctx, s["scene"], s["gb"], s["domains"], resolution=16, strong_resolution=128, strong_share=share,
                    specular=0)
    assert not np.array_equal(base, got)
    twin_check(s, r, got[..., :3])


def test_one_domain_holds_all_the_power(ctx, box_scene):
    """One bright domain, the rest black: it alone is strong (and the only map
    drawn at the default skip_power); N = 1 alike."""
    s = box_scene
    doms = s["domains"].copy()
    doms[1:, 4:7] = 0.0
    got, r = render(ctx, s["scene"], s["gb"], doms, resolution=16, strong_resolution=64, specular=0)
    sides = dm.map_resolutions(r, s["scene"])
    assert sides[0] == 64 and (sides[1:] == 16).all()
    assert dm.maps_drawn(r, s["scene"]) == 1
    s1 = dict(s, domains=doms)
    twin_check(s1, r, got[..., :3])
    one = doms[:1]
    got, r = render(ctx, s["scene"], s["gb"], one, resolution=16, strong_resolution=64, specular=0)
    assert dm.map_resolutions(r, s["scene"]).tolist() == [64]
    twin_check(dict(s, domains=one), r, got[..., :3])


def split_sun_sky(width=128, height=64):
    """A blue gradient sky with a 4-texel sun (150 against ~0.5): the
    decomposition splits the sun across 4 domains at N = 128, each holding
    ~0.04 of the power (below strong_share 0.2) but ~5x the mean domain power
    (the rest ~1.2x); returns the map and the sun's texels."""
    img = np.empty((height, width, 3), np.float32)
    v = (np.arange(height) + 0.5) / height
    img[...] = (0.3 + 0.7 * (1 - v))[:, None, None] * np.array([0.5, 0.7, 1.0], np.float32)
    yy, xx = np.mgrid[0:height, 0:width]
    disk = (yy + 0.5 - 16) ** 2 + (xx + 0.5 - 40) ** 2 < 1.5**2
    img[disk] = 150.0
    return img, disk


def test_split_sun_gets_the_large_maps_at_n128(ctx, box_scene):
    """At N = 128 the sun's power is split across several domains, none of
    which holds strong_share of it: strong_ratio (x the mean domain power)
    still gives exactly the sun's domains the large maps, and the image is the
    twin's. strong_ratio 0 (the share alone, the rule before) gives none."""
    s = box_scene
    img, disk = split_sun_sky()
    dom = d64.decompose(img, 128, seed=1)
    doms = dm.domain_array(dom.centres, dom.radiance, cap_radius=dom.cap_radius, solid_angle=dom.solid_angle)
    sun = np.unique(dom.assign[disk.ravel()])  # the domains holding the sun's texels (twin's assignment)
    p = np.asarray(doms, np.float64)[:, 4:7] @ LUMA
    assert len(sun) >= 3 and (p[sun] < 0.2 * p.sum()).all()  # the case: split, each below the share
    got, r = render(ctx, s["scene"], s["gb"], doms, resolution=16, strong_resolution=48, specular=0)
    sides = dm.map_resolutions(r, s["scene"])
    want = np.full(128, 16)
    want[sun] = 48
    assert sides.tolist() == want.tolist()
    twin_check(dict(s, domains=doms), r, got[..., :3])
    _, r0 = render(ctx, s["scene"], s["gb"], doms, resolution=16, strong_resolution=48, strong_ratio=0.0)
    assert (dm.map_resolutions(r0, s["scene"]) == 16).all()


@pytest.mark.parametrize("n", [16, 128])
def test_constant_map_has_no_strong_domain(ctx, box_scene, n):
    """A constant map: every domain holds about the mean power, so none is
    strong at the defaults (strong_share 0.2, strong_ratio 4) for N >= 5."""
    s = box_scene
    doms = domains_of(procedural.constant(1.0, 64, 32), n)
    _, r = render(ctx, s["scene"], s["gb"], doms, resolution=16, strong_resolution=48)
    assert (dm.map_resolutions(r, s["scene"]) == 16).all()


def test_n1_map_is_strong(ctx, box_scene):
    """N = 1 (the mean is the total: strong_ratio alone never makes it
    strong): strong_share makes its one map strong, at any strong_ratio."""
    s = box_scene
    one = domains_of(procedural.constant(1.0, 64, 32), 1)
    for ratio in (0.0, 4.0, 1e6):
        got, r = render(ctx, s["scene"], s["gb"], one, resolution=16, strong_resolution=48, strong_ratio=ratio,
                        specular=0)
        assert dm.map_resolutions(r, s["scene"]).tolist() == [48]
    twin_check(dict(s, domains=one), r, got[..., :3])
    _, r = render(ctx, s["scene"], s["gb"], one, resolution=16, strong_resolution=48, strong_share=1.0, strong_ratio=0.0)
    assert dm.map_resolutions(r, s["scene"]).tolist() == [48]


@pytest.mark.parametrize("k", [1, 2, 3])
def test_strong_ratio_is_times_the_mean(ctx, box_scene, k):
    """strong_ratio set just below the k-th most powerful domain's power over
    the mean (strong_share 1: the share alone makes none strong) makes
    exactly the k most powerful domains strong."""
    s = box_scene
    p = np.asarray(s["domains"], np.float64)[:, 4:7] @ LUMA
    ratio = np.sort(p / p.mean())[::-1]
    assert ratio[k - 1] > ratio[k] * (1 + 1e-4)  # no tie at the threshold
    _, r = render(ctx, s["scene"], s["gb"], s["domains"], resolution=16, strong_resolution=48, strong_share=1.0,
                  strong_ratio=float(ratio[k - 1] * (1 - 1e-5)))
    want = np.full(len(p), 16)
    want[np.argsort(-p)[:k]] = 48
    assert dm.map_resolutions(r, s["scene"]).tolist() == want.tolist()


def test_receiver_outside_every_footprint_with_an_atlas(ctx, box_scene):
    """A caller's G-buffer pixel far outside the scene is lit by every domain
    above it, whatever the size of their maps."""
    s = box_scene
    gb = gbuffer_with_a_far_receiver(ctx, s["planes"])
    share, _ = strongest(s["domains"], 3)
    got, _ = render(ctx, s["scene"], gb, s["domains"], resolution=16, strong_resolution=96, strong_share=share)
    free, _ = render(ctx, s["scene"], gb, s["domains"], visibility=0)
    assert got[0, 0, 0] > 0 and np.allclose(got[0, 0], free[0, 0], rtol=1e-6)


def test_strong_resolution_is_checked(ctx, box_scene):
    s = box_scene
    r = Renderer(ctx, "depthmap", strong_resolution=4)
    dm.set_domains(r, s["domains"])
    img = Image(ctx, s["gb"].width, s["gb"].height)
    with pytest.raises(InputError, match="strong_resolution 4: 0 \\(off\\) or 8 to 4096"):
        r.execute(s["scene"], s["gb"], img)
    # 17 maps of 4096^2: above the cap of 2^28 texels (refused at plan, before any allocation)
    dm.set_domains(r, np.concatenate([s["domains"], s["domains"][:1]]))
    r.set(strong_resolution=4096, strong_share=0.0)
    with pytest.raises(InputError, match="more than 268435456 texels"):
        r.execute(s["scene"], s["gb"], img)
    with pytest.raises(PenumbraError, match="strong_resolution"):
        Renderer(ctx, "depthmap", strong_resolution=5000)


# --------------------------------------------------------------------------- grade and strong_cluster


def graded(p, base, cap, grade):
    """The sides `grade` gives (docs/depthmap.md, "Map sides graded by power"), in float64."""
    want = base * (p / p.mean()) ** grade
    side = 8 * np.floor(want / 8 + 0.5)
    return np.clip(side, 8, cap).astype(np.int64), want


@pytest.mark.parametrize("grade", [0.25, 0.33, 0.5])
def test_grade_sides_follow_the_power(ctx, box_scene, grade):
    """Every domain that is not strong gets resolution x (P / mean)^grade
    texels a side (a multiple of 8, within [8, strong_resolution]); the strong
    ones keep strong_resolution; the maps of all those sizes shade as the twin
    does. Fails if the power is taken as a share of the total (N times too
    small) or the exponent is ignored."""
    s = box_scene
    p = np.asarray(s["domains"], np.float64)[:, 4:7] @ LUMA
    share, strong = strongest(s["domains"], 1)
    want, raw = graded(p, 32, 96, grade)
    assert np.all(np.abs(raw / 8 - np.floor(raw / 8) - 0.5) > 1e-3)  # no rounding tie
    want[strong] = 96
    got, r = render(ctx, s["scene"], s["gb"], s["domains"], resolution=32, strong_resolution=96, strong_share=share,
                    strong_ratio=0.0, grade=grade, specular=0)
    sides = dm.map_resolutions(r, s["scene"])
    assert sides.tolist() == want.tolist()
    assert len(set(sides.tolist())) >= 3  # graded, not two sizes
    twin_check(s, r, got[..., :3])
    _, r0 = render(ctx, s["scene"], s["gb"], s["domains"], resolution=32, strong_resolution=96, strong_share=share,
                   strong_ratio=0.0)
    assert sorted(set(dm.map_resolutions(r0, s["scene"]).tolist())) == [32, 96]  # grade 0: the rule before


def test_grade_keeps_the_texel_budget_and_caps(ctx, box_scene):
    """grade 0.5 gives each map texels in proportion to its power, so the
    maps' texels stay about N x resolution^2 (up to the rounding to 8);
    without strong_resolution a map is never larger than resolution."""
    s = box_scene
    n = len(s["domains"])
    _, r = render(ctx, s["scene"], s["gb"], s["domains"], resolution=64, strong_resolution=4096, strong_share=1.0,
                  strong_ratio=0.0, grade=0.5)
    sides = dm.map_resolutions(r, s["scene"])
    assert abs((sides.astype(np.float64) ** 2).sum() / (n * 64**2) - 1) < 0.1
    _, r = render(ctx, s["scene"], s["gb"], s["domains"], resolution=32, grade=0.5)
    sides = dm.map_resolutions(r, s["scene"])
    assert sides.max() == 32 and sides.min() < 32


def test_grade_hard_cases(ctx, box_scene):
    """A 10^5 : 1 sun (one domain with nearly all the power): it is strong, the
    others get the smallest maps (8^2) and the image is the twin's; N = 1:
    its power is the mean, so its side is resolution (or strong_resolution by
    the share); black domains get 8^2."""
    s = box_scene
    doms = s["domains"].copy()
    doms[0, 4:7] = 1e5 * doms[1:, 4:7].sum(axis=0)
    got, r = render(ctx, s["scene"], s["gb"], doms, resolution=32, strong_resolution=64, grade=0.5, skip_power=0.0,
                    specular=0)
    sides = dm.map_resolutions(r, s["scene"])
    assert sides[0] == 64 and (sides[1:] == 8).all()
    twin_check(dict(s, domains=doms), r, got[..., :3])
    one = doms[:1]
    _, r = render(ctx, s["scene"], s["gb"], one, resolution=32, grade=0.5)
    assert dm.map_resolutions(r, s["scene"]).tolist() == [32]
    _, r = render(ctx, s["scene"], s["gb"], one, resolution=32, strong_resolution=64, grade=0.5)
    assert dm.map_resolutions(r, s["scene"]).tolist() == [64]
    black = s["domains"].copy()
    black[1:, 4:7] = 0.0
    _, r = render(ctx, s["scene"], s["gb"], black, resolution=32, strong_resolution=64, grade=0.5)
    assert dm.map_resolutions(r, s["scene"]).tolist() == [64] + [8] * (len(black) - 1)


def split_sun_domains(n):
    img, disk = split_sun_sky()
    dom = d64.decompose(img, n, seed=1)
    doms = dm.domain_array(dom.centres, dom.radiance, cap_radius=dom.cap_radius, solid_angle=dom.solid_angle)
    return doms, np.unique(dom.assign[disk.ravel()])


def tiny_sun_domains(spread_deg):
    """60 sky domains of equal power spread over the sphere and 4 tiny bright
    domains (10^-4 sr each, 2x the mean power: each below strong_ratio 4 and
    strong_share 0.2, together 8x the mean) around (0.3, 0.9, 0.3), their
    centres `spread_deg` apart: a sun split across domains at large N, where
    power-proportional draws give it several domains of about the mean power."""
    k = np.arange(60) + 0.5
    z = 1 - 2 * k / 60
    phi = np.pi * (3 - np.sqrt(5)) * k
    sky = np.stack([np.sqrt(1 - z * z) * np.cos(phi), z, np.sqrt(1 - z * z) * np.sin(phi)], 1)
    axis = np.array([0.3, 0.9, 0.3]) / np.linalg.norm([0.3, 0.9, 0.3])
    e1 = np.cross(axis, [0, 0, 1.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(axis, e1)
    t = np.radians(spread_deg)
    sun = [np.cos(t) * axis + np.sin(t) * (np.cos(a) * e1 + np.sin(a) * e2) for a in np.arange(4) * np.pi / 2]
    dirs = np.concatenate([sky, sun])
    rad = np.ones((64, 3))
    rad[60:] = 2.0 * 64 / (60 + 8)  # 2x the mean (the total is 60 + 4 x that)
    omega = np.concatenate([np.full(60, (4 * np.pi - 4e-4) / 60), np.full(4, 1e-4)])
    return dm.domain_array(dirs, rad, solid_angle=omega)


def test_split_sun_cluster(ctx, box_scene):
    """Four tiny neighbouring domains of twice the mean power each: neither
    strong_share nor strong_ratio makes one strong, the cluster rule (their
    summed power, 8x the mean, is strong) makes all four strong; the image is
    the twin's. Off (0), with a cut above their brightness, with their summed
    power below the threshold (strong_ratio 9) or with the four far apart (no
    neighbours) none is. Fails if the cluster's power is not summed or the
    neighbours are not required."""
    s = box_scene
    doms = tiny_sun_domains(0.5)
    p = np.asarray(doms, np.float64)[:, 4:7] @ LUMA
    assert (p[60:] < 4 * p.mean()).all() and (p[60:] < 0.2 * p.sum()).all() and p[60:].sum() > 4 * p.mean()
    want = np.full(64, 16)
    want[60:] = 48
    got, r = render(ctx, s["scene"], s["gb"], doms, resolution=16, strong_resolution=48, strong_cluster=32.0,
                    specular=0)
    assert dm.map_resolutions(r, s["scene"]).tolist() == want.tolist()
    twin_check(dict(s, domains=doms), r, got[..., :3])
    _, r = render(ctx, s["scene"], s["gb"], doms, resolution=16, strong_resolution=48)  # the defaults
    assert dm.map_resolutions(r, s["scene"]).tolist() == want.tolist()
    om = np.asarray(doms, np.float64)[:, 3]
    dens = (p / om) / (p.sum() / om.sum())
    for d, params in ((doms, dict(strong_cluster=0.0)), (doms, dict(strong_cluster=float(dens[60:].max() * 1.01))),
                      (doms, dict(strong_cluster=32.0, strong_ratio=9.0)),
                      (tiny_sun_domains(60.0), dict(strong_cluster=32.0))):
        _, r = render(ctx, s["scene"], s["gb"], d, resolution=16, strong_resolution=48, **params)
        assert (dm.map_resolutions(r, s["scene"]) == 16).all(), params


def test_split_sun_at_n64_is_not_a_cluster(ctx, box_scene):
    """The limit, stated: the 4-texel sun of split_sun_sky at N = 64 spreads
    over domains of 7-8 degree caps whose brightness (8-13x the average) is
    that of Uffizi's windows (up to 15x), so the default cut (32) leaves them
    weak; they are caught at N = 128 by strong_ratio."""
    s = box_scene
    doms, sun = split_sun_domains(64)
    p = np.asarray(doms, np.float64)[:, 4:7] @ LUMA
    om = np.asarray(doms, np.float64)[:, 3]
    dens = (p / om) / (p.sum() / om.sum())
    assert (dens[sun] < 32).all() and (dens[sun] > 4).all()
    _, r = render(ctx, s["scene"], s["gb"], doms, resolution=16, strong_resolution=48, strong_cluster=32.0)
    assert (dm.map_resolutions(r, s["scene"]) == 16).all()
    _, r = render(ctx, s["scene"], s["gb"], doms, resolution=16, strong_resolution=48, strong_cluster=4.0)
    assert (dm.map_resolutions(r, s["scene"])[sun] == 48).all()


@pytest.mark.parametrize("n", [16, 128])
def test_cluster_leaves_even_maps_alone(ctx, box_scene, n):
    """A constant map (every domain of about the average brightness): no
    domain reaches a cut of 2, so there is no cluster and no strong map."""
    s = box_scene
    doms = domains_of(procedural.constant(1.0, 64, 32), n)
    _, r = render(ctx, s["scene"], s["gb"], doms, resolution=16, strong_resolution=48, strong_cluster=2.0)
    assert (dm.map_resolutions(r, s["scene"]) == 16).all()


# --------------------------------------------------------------------------- the caller's maps, any sizes


@pytest.fixture(scope="module")
def supplied(ctx, box_scene):
    """Maps of three sizes read back from a renderer, and a scene without the boxes."""
    s = box_scene
    share, _ = strongest(s["domains"], 3)
    first, r1 = render(ctx, s["scene"], s["gb"], s["domains"], resolution=24, strong_resolution=80,
                       strong_share=share, skip_power=0.05)
    doms, frames, maps = dm.read_maps(r1, s["scene"])
    assert isinstance(maps, list) and len({m.shape for m in maps}) == 2
    floor_only, _, keep = make_scene(ctx, [(procedural.plane((4.0, 4.0)), xform(), Material())], s["env"],
                                     s["camera"])
    return dict(first=first, doms=doms, frames=frames, maps=maps, floor_only=floor_only, keep=keep,
                sides=np.array([m.shape[0] for m in maps], np.uint32))


def second(ctx, s, sup, **params):
    r = Renderer(ctx, "depthmap", resolution=24, skip_power=0.05, **params)
    dm.set_domains(r, sup["doms"])
    return r


def shade_with(ctx, s, sup, r):
    img = Image(ctx, s["gb"].width, s["gb"].height)
    r.execute(sup["floor_only"], s["gb"], img)
    return img.read()


def test_maps_of_any_sizes_copied_or_in_place_give_the_same_image(ctx, cl_pair, box_scene, supplied):
    """Maps of two sizes read back and supplied to a second renderer (which
    renders the scene without the boxes), as a list of arrays (copied) or in a
    pyopencl buffer (read in place): the first image bit for bit, both ways;
    the buffer's later contents are what the next execute reads (no copy)."""
    s, sup = box_scene, supplied
    _, queue = cl_pair
    r = second(ctx, s, sup)
    dm.set_maps(r, sup["frames"], sup["maps"])
    assert np.array_equal(shade_with(ctx, s, sup, r), sup["first"])
    packed = np.concatenate([m.reshape(-1) for m in sup["maps"]]).astype(np.float32)
    buf = cl.Buffer(queue.context, cl.mem_flags.READ_WRITE | cl.mem_flags.COPY_HOST_PTR, hostbuf=packed)
    rb = second(ctx, s, sup)
    dm.set_maps(rb, sup["frames"], buf, resolutions=sup["sides"])
    assert np.array_equal(shade_with(ctx, s, sup, rb), sup["first"])
    back = dm.read_maps(rb, sup["floor_only"])
    assert all(np.array_equal(a, b) for a, b in zip(back[2], sup["maps"]))
    assert np.array_equal(dm.map_resolutions(rb, sup["floor_only"]), sup["sides"])
    # The caller redraws its buffer (empty maps): the next execute sees it without a new set_maps.
    cl.enqueue_copy(queue, buf, np.full_like(packed, np.inf))
    queue.finish()
    free = shade_with(ctx, s, sup, second(ctx, s, sup, visibility=0))
    assert np.array_equal(shade_with(ctx, s, sup, rb), free)
    # With 16-bit lookups too (the copy packs from the caller's buffer).
    cl.enqueue_copy(queue, buf, packed)
    queue.finish()
    r16 = second(ctx, s, sup, half_maps=1)
    dm.set_maps(r16, sup["frames"], buf, resolutions=sup["sides"])
    r16c = second(ctx, s, sup, half_maps=1)
    dm.set_maps(r16c, sup["frames"], sup["maps"])
    assert np.array_equal(shade_with(ctx, s, sup, r16), shade_with(ctx, s, sup, r16c))
    # A pyopencl Array works as well; None returns to drawing (the floor alone: no shadows).
    import pyopencl.array as cla

    arr = cla.to_device(queue, packed)
    dm.set_maps(rb, sup["frames"], arr, resolutions=sup["sides"])
    assert np.array_equal(shade_with(ctx, s, sup, rb), sup["first"])
    dm.set_maps(rb, None, None)
    assert not np.array_equal(shade_with(ctx, s, sup, rb), sup["first"])


def test_the_callers_buffer_is_checked(ctx, cl_pair, box_scene, supplied):
    s, sup = box_scene, supplied
    _, queue = cl_pair
    packed = np.concatenate([m.reshape(-1) for m in sup["maps"]]).astype(np.float32)
    r = second(ctx, s, sup)
    small = cl.Buffer(queue.context, cl.mem_flags.READ_WRITE, packed.nbytes - 4)
    with pytest.raises(PenumbraError, match=f"buffer holds {packed.nbytes - 4} bytes but {packed.nbytes} are needed"):
        dm.set_maps(r, sup["frames"], small, resolutions=sup["sides"])
    other = cl.Context(queue.context.devices)
    foreign = cl.Buffer(other, cl.mem_flags.READ_WRITE, packed.nbytes)
    with pytest.raises(InputError, match="belongs to a different cl_context"):
        dm.set_maps(r, sup["frames"], foreign, resolutions=sup["sides"])
    buf = cl.Buffer(queue.context, cl.mem_flags.READ_WRITE, packed.nbytes)
    with pytest.raises(InputError, match="give resolutions"):
        dm.set_maps(r, sup["frames"], buf)
    with pytest.raises(InputError, match="resolutions must be an int or 16 ints"):
        dm.set_maps(r, sup["frames"], buf, resolutions=sup["sides"][:3])
    sides = sup["sides"].copy()
    sides[2] = 0
    with pytest.raises(PenumbraError, match="depth map 2 is 0 x 0 texels: the side must be 1 to 4096"):
        dm.set_maps(r, sup["frames"], buf, resolutions=sides)
    f = sup["frames"].copy()
    f[5, 1] = np.nan
    with pytest.raises(InputError, match="depth map 5's frame has a non-finite value at float 1"):
        dm.set_maps(r, f, buf, resolutions=sup["sides"])
    import pyopencl.array as cla

    with pytest.raises(InputError, match="float64 elements; it must hold float32"):
        dm.set_maps(r, sup["frames"], cla.zeros(queue, packed.size, np.float64), resolutions=sup["sides"])
    with pytest.raises(PenumbraError, match="15 depth maps but the renderer shades with 16 domains"):
        dm.set_maps(r, sup["frames"][:15], buf, resolutions=sup["sides"][:15])
    # Maps copied from the host, sizes from the arrays: a NaN names its map and texel; squares only.
    bad = [m.copy() for m in sup["maps"]]
    k = int(np.flatnonzero(sup["sides"] == 80)[0])
    bad[k][70, 3] = np.nan
    with pytest.raises(InputError, match=rf"depth map {k} has nan at texel \(3, 70\)"):
        dm.set_maps(r, sup["frames"], bad)
    with pytest.raises(InputError, match="square arrays"):
        dm.set_maps(r, sup["frames"], [m[:, :-1] for m in sup["maps"]])
    # None of these changed the renderer: it still draws its own maps.
    r.execute(sup["floor_only"], s["gb"], Image(ctx, s["gb"].width, s["gb"].height))
