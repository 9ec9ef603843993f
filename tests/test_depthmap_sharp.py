"""The env map's sharp part in domains of its own (depthmap's `sharp`,
pn_envmap_domains_split; docs/depthmap.md, "The sun in its own domains"):
the first k of the N domains are pn_envmap_extract_sharp's (the excess over
T at the light's own size), the other N - k the decomposition of the
residual map; they shade like any domains (the float64 twin), are strong,
and the hard cases keep their behaviour."""

from __future__ import annotations

import math

import env_sharp64 as sh
import numpy as np
import pytest
from test_depthmap import box_scene, sky  # noqa: F401  (fixtures)
from test_depthmap_atlas import twin_check

import depthmap64 as d64
from penumbra import EnvMap, Image, InputError, PenumbraError, Renderer, procedural
from penumbra.methods import depthmap as dm

LUMA = np.array([0.2126, 0.7152, 0.0722])


def run(ctx, s, **params):
    """The box scene lit by the library's own decomposition of its env map (no caller domains)."""
    params.setdefault("strong_resolution", 0)
    params.setdefault("grade", 0.0)
    # the hard lookup, which depthmap64.shade twins; the sharp domains' soft lookup (soft_shadows 1, the
    # default) has its own twin in tests/test_depthmap_soft.py
    params.setdefault("soft_shadows", 0)
    r = Renderer(ctx, "depthmap", **params)
    img = Image(ctx, s["gb"].width, s["gb"].height)
    r.execute(s["scene"], s["gb"], img)
    return img.read(), r


def domains(r, s):
    return np.asarray(r.read_output(s["scene"], "domains", 0), np.float32).reshape(-1, 8)


@pytest.mark.parametrize("k,n", [(1, 16), (2, 16), (4, 8)])
def test_sharp_domains_are_the_sharp_part_then_the_residuals(ctx, box_scene, sky, k, n):
    """The sky's 1e4 sun: the first domains are extract_sharp's (its excess,
    the hot texels' solid angle: a cap of the sun's size, not a Voronoi cell),
    the rest the library's decomposition of the residual into N - k, bit for
    bit; the power adds up to the map's (the twin's split) and the image is the
    twin's with those domains."""
    s = box_scene
    got, r = run(ctx, s, directions=n, sharp=k, specular=0)
    doms = domains(r, s)
    assert len(doms) == n
    sharp, residual = EnvMap(ctx, sky).extract_sharp(max_count=k, threshold=100.0)
    kk = len(sharp)
    assert kk == min(k, int(sh.split(sky, 100.0)[2].sum()))
    np.testing.assert_array_equal(doms[:kk, :3], sharp.directions)
    np.testing.assert_array_equal(doms[:kk, 4:7], sharp.radiance)
    np.testing.assert_array_equal(doms[:kk, 3], sharp.solid_angle)
    np.testing.assert_array_equal(doms[:kk, 7], sharp.cap_radius)
    rest = EnvMap(ctx, residual).decompose(n - kk)
    np.testing.assert_array_equal(doms[kk:, :3], rest.directions)
    np.testing.assert_array_equal(doms[kk:, 4:7], rest.radiance)
    # the sharp caps are the sun's size; the residual's cells tile the sphere
    assert doms[:kk, 7].max() < 0.1 and doms[kk:, 7].min() > doms[:kk, 7].max()
    np.testing.assert_allclose(doms[kk:, 3].astype(np.float64).sum(), 4 * math.pi, rtol=1e-5)
    res64, sharp64, _ = sh.split(sky, 100.0)
    np.testing.assert_allclose(doms[:kk, 4:7].astype(np.float64).sum(0), d64.texels(sharp64).power.sum(0), rtol=1e-5)
    np.testing.assert_allclose(doms[:, 4:7].astype(np.float64).sum(0), d64.texels(sky).power.sum(0), rtol=1e-5)
    twin_check(dict(s, domains=doms), r, got[..., :3])


def test_sharp_domains_are_strong(ctx, box_scene):
    """The sharp part's domains get strong_resolution even where neither the
    share nor the ratio rule makes them strong; the residual's keep theirs."""
    s = box_scene
    _, r = run(ctx, s, directions=16, sharp=2, strong_resolution=64, resolution=16, strong_share=1.0,
               strong_ratio=1e6, strong_cluster=0)
    sides = dm.map_resolutions(r, s["scene"])
    assert sides[:2].tolist() == [64, 64] and (sides[2:] == 16).all()
    _, r0 = run(ctx, s, directions=16, sharp=0, strong_resolution=64, resolution=16, strong_share=1.0,
                strong_ratio=1e6, strong_cluster=0)
    assert (dm.map_resolutions(r0, s["scene"]) == 16).all()


def test_sharp_changes_the_sun_and_keeps_n(ctx, box_scene):
    """sharp 0 is the plain decomposition (the library's pn_envmap_decompose),
    whatever the threshold; sharp 1, the default, moves the sun's light into a
    small domain of its own (a different image), and the count stays N."""
    s = box_scene
    a, r0 = run(ctx, s, directions=16, sharp=0)
    b, r1 = run(ctx, s, directions=16, sharp=0, sharp_threshold=50.0)
    np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(domains(r0, s), domains(r1, s))
    plain = s["env"].decompose(16)
    np.testing.assert_array_equal(domains(r0, s)[:, :3], plain.directions)
    c, r2 = run(ctx, s, directions=16)
    assert Renderer(ctx, "depthmap").get("sharp") == 1
    assert len(domains(r2, s)) == 16 and not np.array_equal(a, c)
    assert domains(r2, s)[0, 7] < 0.1 and domains(r0, s)[:, 7].min() > 0.1


def test_sharp_hard_cases(ctx, box_scene):
    """N = 1 keeps the whole sphere (sharp takes at most N - 1); N = 2 is the
    sun and the residual's one domain; the same seed gives the same domains."""
    s = box_scene
    one, r1 = run(ctx, s, directions=1, sharp=4)
    base, r0 = run(ctx, s, directions=1)
    np.testing.assert_array_equal(one, base)
    assert domains(r1, s)[0, 7] == pytest.approx(math.pi)
    _, r2 = run(ctx, s, directions=2, sharp=4)
    d2 = domains(r2, s)
    assert d2[0, 7] < 0.1 and d2[1, 7] == pytest.approx(math.pi, rel=1e-3)
    _, ra = run(ctx, s, directions=12, sharp=3, seed=7)
    _, rb = run(ctx, s, directions=12, sharp=3, seed=7)
    np.testing.assert_array_equal(domains(ra, s), domains(rb, s))


def test_sharp_of_a_1e5_sun_and_of_maps_without_one(ctx):
    """A one-texel 10^5 : 1 sun: its own domain, exactly that texel's excess at
    its solid angle; a constant map has no sharp part (the plain decomposition,
    bit for bit); a black map is refused as before; a threshold of 1 is refused
    with the parameter named."""
    from test_reference import gbuffer_of, make_scene, xform
    from penumbra import Camera, Material

    w, h = 64, 32
    sun = procedural.constant(1.0, w, h).astype(np.float32)
    i, j = procedural.direction_to_pixel((0.3, 0.7, -0.2), w, h)
    sun[j, i] = 1e5
    objects = [(procedural.plane((4.0, 4.0)), xform(), Material(albedo=(0.7, 0.7, 0.7))),
               (procedural.box((1.0, 0.8, 0.6)), xform(translate=(0.0, 0.4, 0.0)), Material(albedo=(0.8, 0.4, 0.2)))]
    camera = Camera(position=(1.5, 2.5, 4.0), look_at=(0.0, 0.3, 0.0), fov_deg=50.0, resolution=(16, 12))
    for env_img, n in ((sun, 16), (procedural.constant(1.0, w, h).astype(np.float32), 8)):
        env = EnvMap(ctx, env_img, face_size=16)
        scene, _, _ = make_scene(ctx, objects, env, camera)
        gb, _ = gbuffer_of(ctx, scene, camera)
        img = Image(ctx, gb.width, gb.height)
        r = Renderer(ctx, "depthmap", directions=n, sharp=1)
        r.execute(scene, gb, img)
        d = np.asarray(r.read_output(scene, "domains", 0), np.float64).reshape(-1, 8)
        tex = d64.texels(env_img)
        if env_img is sun:
            limit = 100.0 * tex.weight.sum() / (4 * math.pi)
            assert np.linalg.norm(d[0, :3] - tex.dirs[j * w + i]) < 1e-6
            np.testing.assert_allclose(d[0, 3], tex.omega[j * w + i], rtol=1e-6)
            np.testing.assert_allclose(d[0, 4:7], (1e5 - limit) * tex.omega[j * w + i], rtol=1e-5)
            np.testing.assert_allclose(d[1:, 4:7].sum(0), tex.power.sum(0) - (1e5 - limit) * tex.omega[j * w + i],
                                       rtol=1e-5)  # the residual: the sun's texel clipped to T
        else:
            r0 = Renderer(ctx, "depthmap", directions=n)
            r0.execute(scene, gb, img)
            np.testing.assert_array_equal(d, np.asarray(r0.read_output(scene, "domains", 0), np.float64).reshape(-1, 8))
    black = EnvMap(ctx, np.zeros((h, w, 3), np.float32), face_size=16)
    scene, _, _ = make_scene(ctx, objects, black, camera)
    gb, _ = gbuffer_of(ctx, scene, camera)
    with pytest.raises(PenumbraError, match="black"):
        Renderer(ctx, "depthmap", directions=8, sharp=1).execute(scene, gb, Image(ctx, gb.width, gb.height))
    scene, _, _ = make_scene(ctx, objects, EnvMap(ctx, sun, face_size=16), camera)
    with pytest.raises((PenumbraError, InputError), match="threshold"):
        Renderer(ctx, "depthmap", directions=8, sharp=1, sharp_threshold=1.0).execute(
            scene, gb, Image(ctx, gb.width, gb.height))


def lamp_scene(ctx, env_img):
    from test_reference import gbuffer_of, make_scene, xform
    from penumbra import Camera, Material

    objects = [(procedural.plane((4.0, 4.0)), xform(), Material(albedo=(0.7, 0.7, 0.7))),
               (procedural.box((1.0, 0.8, 0.6)), xform(translate=(0.0, 0.4, 0.0)), Material(albedo=(0.8, 0.4, 0.2)))]
    camera = Camera(position=(1.5, 2.5, 4.0), look_at=(0.0, 0.3, 0.0), fov_deg=50.0, resolution=(16, 12))
    scene, _, keep = make_scene(ctx, objects, EnvMap(ctx, env_img, face_size=16), camera)
    gb, planes = gbuffer_of(ctx, scene, camera)
    return dict(scene=scene, gb=gb, planes=planes, camera=camera, keep=keep)


def split_domains(ctx, s, n, sharp, **params):
    r = Renderer(ctx, "depthmap", directions=n, sharp=sharp, **params)
    img = Image(ctx, s["gb"].width, s["gb"].height)
    r.execute(s["scene"], s["gb"], img)
    return np.asarray(r.read_output(s["scene"], "domains", 0), np.float32).reshape(-1, 8), img.read(), r


LAMPS = [((0.1, 0.7, -0.7), 4e4), ((0.7, 0.6, 0.3), 2e4), ((-0.6, 0.5, 0.4), 1e4)]  # direction, radiance


def lamps_map(w=128, h=64, lamps=LAMPS):
    """A sky of 1 with 2 x 2-texel lamps: (map, the texels (row, column) of each lamp)."""
    env = procedural.constant(1.0, w, h).astype(np.float32)
    where = []
    for d, L in lamps:
        i, j = procedural.direction_to_pixel(d, w, h)
        idx = [(j + a, (i + b) % w) for a in (0, 1) for b in (0, 1)]
        for q in idx:
            env[q] = L
        where.append(idx)
    return env, where


def lamp_power(env, idx):
    """(excess radiance x solid angle summed over the lamp's texels (3,), their solid angle)."""
    _, sharp64, _ = sh.split(env.astype(np.float64), 100.0)
    tex = d64.texels(sharp64)
    rows, cols = zip(*idx)
    return (tex.power.reshape(env.shape)[rows, cols].sum(0),
            tex.omega.reshape(env.shape[:2])[rows, cols].sum())


def test_several_lamps_get_their_own_domains(ctx):
    """Three compact lamps far apart (their hot texels together are not one
    light, so the whole-map rule falls back): each connected light holding at
    least the mean domain power gets its own sharp domain, the strongest
    first; the domain holds its lamp's excess over T and its 4 texels' solid
    angle and sits on it; sharp 2 takes the two strongest, sharp 1 the
    strongest, sharp 5 gives the two extra domains to the lamps with the most
    power per domain; the image is the float64 twin's with those domains; a
    seed gives the same domains twice."""
    env, where = lamps_map()
    s = lamp_scene(ctx, env)
    hot = sh.split(env.astype(np.float64), 100.0)[2]
    n = 16
    doms, got, r = split_domains(ctx, s, n, 3, soft_shadows=0, strong_resolution=0, grade=0.0)
    assert len(doms) == n
    for k, idx in enumerate(where):  # strongest first: the order of LAMPS
        rows, cols = zip(*idx)
        assert hot[rows, cols].all()
        power, omega = lamp_power(env, idx)
        np.testing.assert_allclose(doms[k, 4:7], power, rtol=1e-5)
        np.testing.assert_allclose(doms[k, 3], omega, rtol=1e-5)
        centre = np.asarray(LAMPS[k][0]) / np.linalg.norm(LAMPS[k][0])
        assert math.degrees(math.acos(min(float(doms[k, :3] @ centre), 1.0))) < 3.0  # about a texel
        assert doms[k, 7] < 0.08
    assert doms[3:, 7].min() > 0.1  # the residual's cells
    np.testing.assert_allclose(doms[:, 4:7].astype(np.float64).sum(0), d64.texels(env).power.sum(0), rtol=1e-5)
    twin_check(dict(s, domains=doms), r, got[..., :3])
    again, _, _ = split_domains(ctx, s, n, 3, soft_shadows=0, strong_resolution=0, grade=0.0)
    np.testing.assert_array_equal(doms, again)
    two, _, _ = split_domains(ctx, s, n, 2)  # the third lamp stays in the residual
    np.testing.assert_array_equal(two[:2, 4:7], doms[:2, 4:7])
    assert two[2:, 7].min() > 0.1
    one, _, _ = split_domains(ctx, s, n, 1)  # the default: the strongest lamp alone
    np.testing.assert_array_equal(one[:1, 4:7], doms[:1, 4:7])
    assert one[1:, 7].min() > 0.1
    # sharp 5: one domain per lamp, then the extra two one at a time to the most excess per domain:
    # (4e4 - T) / 1, then (4e4 - T) / 2 against (2e4 - T) / 1: both to the strongest lamp
    five, _, _ = split_domains(ctx, s, n, 5)
    assert five[:5, 7].max() < 0.08 and five[5:, 7].min() > 0.1
    lamp_dirs = np.array([np.asarray(c) / np.linalg.norm(c) for c, _ in LAMPS])
    nearest = np.argmax(five[:5, :3].astype(np.float64) @ lamp_dirs.T, axis=1)
    assert np.bincount(nearest, minlength=3).tolist() == [3, 1, 1]
    np.testing.assert_allclose(five[:5, 4:7].astype(np.float64).sum(0), doms[:3, 4:7].astype(np.float64).sum(0),
                               rtol=1e-5)


def test_scattered_hot_texels_keep_the_plain_decomposition(ctx):
    """What is not a light keeps the plain decomposition bit for bit: hot
    texels scattered over the sky, none holding the mean domain power (an
    interior's bright spots), and a long thin band of hot texels (a window
    strip: connected, but its spread is 3x its cap). Beside a lamp the band
    stays in the residual as it is and the lamp alone is split off. A lamp
    below the mean domain power stays too (at N 4, not at N 16)."""
    w, h = 128, 64
    rng = np.random.default_rng(3)
    scattered = procedural.constant(1.0, w, h).astype(np.float32)
    for _ in range(12):
        scattered[rng.integers(8, h - 8), rng.integers(0, w)] = 600.0
    band = procedural.constant(1.0, w, h).astype(np.float32)
    band[20, 10:50] = 3000.0
    for env in (scattered, band):
        s = lamp_scene(ctx, env)
        assert sh.split(env.astype(np.float64), 100.0)[2].sum() >= 12
        a, ia, _ = split_domains(ctx, s, 16, 1)
        b, ib, _ = split_domains(ctx, s, 16, 0)
        np.testing.assert_array_equal(a, b)
        np.testing.assert_array_equal(ia, ib)
    env, where = lamps_map(lamps=LAMPS[:1])
    env[20, 10:50] = 3000.0
    s = lamp_scene(ctx, env)
    doms, _, _ = split_domains(ctx, s, 16, 2)
    power, _ = lamp_power(env, where[0])
    # sharp 2: the band is no light, so both sharp domains go to the lamp (as sharp 2 splits a sun)
    np.testing.assert_allclose(doms[:2, 4:7].astype(np.float64).sum(0), power, rtol=1e-5)
    assert doms[:2, 7].max() < 0.08 and doms[2:, 7].min() > 0.1
    # the band keeps its full radiance: the residual's power is the map's less the lamp's excess
    np.testing.assert_allclose(doms[2:, 4:7].astype(np.float64).sum(0), d64.texels(env).power.sum(0) - power,
                               rtol=1e-5)
    # two lamps of about 0.18 of the map's power each: below the mean domain power at N 4, above at N 16
    weak, where = lamps_map(lamps=[((0.1, 0.7, -0.7), 800.0), ((0.7, 0.6, 0.3), 800.0)])
    share = lamp_power(weak, where[0])[0].sum() / d64.texels(weak).power.sum()
    assert 1 / 16 < share < 1 / 4
    s = lamp_scene(ctx, weak)
    a, _, _ = split_domains(ctx, s, 4, 1)
    b, _, _ = split_domains(ctx, s, 4, 0)
    np.testing.assert_array_equal(a, b)
    c, _, _ = split_domains(ctx, s, 16, 1)
    assert c[0, 7] < 0.08 and c[1:, 7].min() > 0.1
