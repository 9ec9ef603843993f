"""The env map decomposition of the library (capi/src/core/env_domains.c,
kernels/env_domains.cl, EnvMap.decompose) against its float64 twin
tests/depthmap64.py (docs/depthmap.md):

* the assignment kernel against the twin's nearest(): equal except where the
  twin's two best dot products are within float rounding of each other;
* the whole decomposition against the twin's decompose() on maps without
  exact ties (the bit-for-bit initial draw, then the same Lloyd iterations);
* on dense procedural and real maps, where the lat-long grid's symmetries make
  exact ties that float and double break differently, the library's result is
  a fixed point of the twin's Lloyd step and its sums are the twin's sums for
  its centres, with the same irradiance error as the twin's own result;
* the hard cases (N = 1, black and constant maps, a 10^5:1 sun, N too large),
  rotation and intensity, determinism and the cache.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

import depthmap64 as dm
import penumbra
from penumbra import procedural as pr
from penumbra.errors import InputError, PenumbraError
from penumbra.imageio import read_envmap
from penumbra.kernels import kernel_dir

# Centres come back as float32 unit vectors: their rounding is ~6e-8 per
# coordinate (measured chord to the twin 4e-8 on tie-free maps).
CENTRE_CHORD = 2e-7
# Domain sums are accumulated in double on the host and returned as float32:
# relative rounding 6e-8 (measured 1.6e-8 of the map's power).
SUM_RTOL = 2e-7


def tie_free_map(k: int, w: int = 64, h: int = 512, seed: int = 5) -> np.ndarray:
    """k non-black texels of log-normal power, no two in one row and no two rows
    mirrored about the equator: no texel is then exactly equidistant from two
    texels or generic weighted means, so float and double Lloyd take the same steps."""
    rng = np.random.default_rng(seed)
    rows = rng.choice(h // 2, k, replace=False)
    rows = np.where(rng.random(k) < 0.5, rows, h - 1 - rows)
    env = np.zeros((h, w, 3), np.float32)
    env[rows, rng.integers(0, w, k)] = np.exp(rng.normal(0.0, 2.0, (k, 1))) * rng.uniform(0.2, 1.0, (k, 3))
    return env


def texel_omega(h: int, w: int) -> float:
    """The largest texel solid angle of a w x h lat-long map (at the equator)."""
    return float(pr.latlong_row_solid_angles(w, h).max())


# --------------------------------------------------------------------------- the assignment kernel


def tile_cones(tex: dm.Texels, tile: int):
    """Per tile x tile block (row-major tiles): unit axis and half-angle holding its texel directions."""
    d = tex.dirs.reshape(tex.height, tex.width, 3)
    cones = []
    for y0 in range(0, tex.height, tile):
        for x0 in range(0, tex.width, tile):
            b = d[y0:y0 + tile, x0:x0 + tile].reshape(-1, 3)
            a = b.sum(0)
            a /= np.linalg.norm(a)
            cones.append([*a, math.acos(min(1.0, (b @ a).min())) + 1e-6])
    return np.array(cones, np.float32)


def run_assign(build_test_kernel, cl_pair, tex: dm.Texels, centres: np.ndarray, tile: int = 8) -> np.ndarray:
    import pyopencl as cl

    cl_ctx, queue = cl_pair
    prg = build_test_kernel((kernel_dir() / "env_domains.cl").read_text())
    dirs = np.zeros((len(tex.dirs), 4), np.float32)
    dirs[:, :3] = tex.dirs
    cen = np.zeros((len(centres), 4), np.float32)
    cen[:, :3] = centres
    cones = tile_cones(tex, tile)
    mf = cl.mem_flags
    bufs = [cl.Buffer(cl_ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=a) for a in (dirs, cones, cen)]
    out = np.empty(len(tex.dirs), np.int32)
    obuf = cl.Buffer(cl_ctx, mf.WRITE_ONLY, out.nbytes)
    cl.Kernel(prg, "env_domains_assign")(queue, (len(cones) * 64,), (64,), bufs[0], np.int32(tex.width), np.int32(tex.height),
                           np.int32(tile), np.int32(tile), bufs[1], bufs[2], np.int32(len(centres)), obuf)
    cl.enqueue_copy(queue, out, obuf)
    return out


def random_centres(rng, n, around=None, spread=None):
    c = rng.normal(size=(n, 3))
    if around is not None:  # a dense cluster: every centre within ~spread rad of `around`
        c = np.asarray(around, float) + spread * c
    return c / np.linalg.norm(c, axis=1, keepdims=True)


@pytest.mark.parametrize("case", ["one", "seven", "64", "1024", "dense cluster", "texel centres"])
@pytest.mark.parametrize("tile", [8, 16])
def test_assign_kernel_is_the_twins_nearest(build_test_kernel, cl_pair, case, tile):
    """Every texel gets the twin's nearest centre, except where the twin's best and
    the kernel's choice are within 1e-6 in dot product (float32 rounding of unit
    dot products is ~2e-7): the culling never drops the nearest centre."""
    rng = np.random.default_rng(11)
    tex = dm.texels(pr.sky(200, 100))  # 200 is not a multiple of the tile: partial tiles
    centres = {
        "one": lambda: random_centres(rng, 1),
        "seven": lambda: random_centres(rng, 7),
        "64": lambda: random_centres(rng, 64),
        "1024": lambda: random_centres(rng, 1024),
        "dense cluster": lambda: random_centres(rng, 1024, around=(0.3, 0.9, 0.1), spread=0.03),
        "texel centres": lambda: tex.dirs[rng.choice(len(tex.dirs), 300, replace=False)],
    }[case]()
    got = run_assign(build_test_kernel, cl_pair, tex, centres.astype(np.float32).astype(np.float64), tile)
    c64 = centres.astype(np.float32).astype(np.float64)
    want = dm.nearest(tex.dirs, c64)
    assert got.min() >= 0 and got.max() < len(centres)
    diff = np.flatnonzero(got != want)
    if diff.size:
        dots = np.einsum("ka,ka->k", tex.dirs[diff], c64[want[diff]]) - np.einsum("ka,ka->k", tex.dirs[diff],
                                                                                    c64[got[diff]])
        assert dots.max() < 1e-6, f"{diff.size} texels off their nearest centre by up to {dots.max():.3g}"
    if case != "texel centres":  # generic centres: near-ties are rare (texel centres tie by the grid's symmetry)
        assert diff.size <= max(10, len(tex.dirs) // 1000)


# --------------------------------------------------------------------------- the decomposition against the twin


@pytest.mark.parametrize("k, n", [(200, 200), (200, 30), (200, 120)])
def test_decomposition_is_the_twins_on_tie_free_maps(ctx, k, n):
    """Same initial draw (N = k: every texel is drawn and the domains come in the
    twin's key order, so the draw's order is checked bit for bit), same Lloyd steps
    and iterations: centres, radiance and solid angles equal to float rounding
    (solid angles up to the few black texels that sit exactly between two centres,
    which float and double give to different cells)."""
    env = tie_free_map(k)
    tex = dm.texels(env)
    dom = penumbra.EnvMap(ctx, env).decompose(n, seed=3, max_iterations=1000)
    ref = dm.decompose(tex, n, 3, max_iter=1000)
    assert ref.converged
    assert np.linalg.norm(dom.directions - ref.centres, axis=1).max() < CENTRE_CHORD
    total = tex.power.sum(0)
    np.testing.assert_allclose(dom.radiance, ref.radiance, atol=SUM_RTOL * total.max())
    np.testing.assert_allclose(dom.solid_angle, ref.solid_angle, atol=3 * texel_omega(*env.shape[:2]))
    if n == k:  # the key order itself
        order = dm.initial_samples(tex, n, 3)
        assert np.linalg.norm(dom.directions - tex.dirs[order], axis=1).max() < CENTRE_CHORD


def dense_maps(shared_data):
    yield "procedural sky 256x128", pr.sky(256, 128)
    yield "uffizi probe", read_envmap(shared_data / "envmaps" / "uffizi_probulator_256x128.hdr")
    yield "venice sunset 1k", read_envmap(shared_data / "envmaps" / "venice_sunset_1k_polyhaven.hdr")


@pytest.mark.parametrize("which", [0, 1, 2])
def test_dense_maps_give_a_fixed_point_of_the_twins_lloyd(ctx, shared_data, which):
    """On dense maps exact ties (texels equidistant from two centres, by the grid's
    symmetry) are broken differently in float and double, so the runs part ways;
    what must hold: with the twin's nearest() of the library's centres, the twin's
    sums are the library's (1e-7 of the power; measured 9e-9) and, on the
    256 x 128 maps, each centre is its cell's weighted mean (measured chord 4e-8:
    Lloyd converged) and the irradiance error is the twin's own decomposition's to 10 %
    (measured within 4 %)."""
    name, env = list(dense_maps(shared_data))[which]
    env = env.astype(np.float32)
    tex = dm.texels(env)
    normals = dm.fibonacci_sphere(256)
    n = 32
    small = tex.width <= 256  # at 1k, Lloyd needs hundreds of iterations to converge (~40 s here): 20, no mean check
    dom = penumbra.EnvMap(ctx, env).decompose(n, seed=1, max_iterations=1000 if small else 20)
    c = dom.directions.astype(np.float64)
    c /= np.linalg.norm(c, axis=1, keepdims=True)
    assign = dm.nearest(tex.dirs, c)
    twin = dm.domains_from_assignment(tex, c, assign)
    total = tex.power.sum(0)
    np.testing.assert_allclose(dom.radiance, twin.radiance, atol=1e-7 * total.max(), err_msg=name)
    np.testing.assert_allclose(dom.solid_angle, twin.solid_angle, atol=1e-6, err_msg=name)
    np.testing.assert_allclose(dom.radiance.sum(0), total, rtol=1e-6)
    assert abs(dom.solid_angle.sum() - 4 * math.pi) < 1e-5
    if small:
        assert np.linalg.norm(dm.weighted_means(tex, c, assign) - c, axis=1).max() < 1e-6
    np.testing.assert_allclose(2 * math.pi * (1 - np.cos(dom.cap_radius.astype(np.float64))), dom.solid_angle,
                               rtol=1e-5)
    if small:  # the twin's own Lloyd takes ~90 s at 1k
        exact = dm.exact_irradiance(tex, normals)
        e_lib = dm.irradiance_error(tex, twin, normals, exact=exact)
        e_twin = dm.irradiance_error(tex, dm.decompose(tex, n, 1), normals, exact=exact)
        assert e_lib < 1.1 * e_twin, (name, e_lib, e_twin)


# --------------------------------------------------------------------------- hard cases


def test_one_domain_is_the_whole_sphere(ctx):
    env = pr.sky(128, 64)
    tex = dm.texels(env.astype(np.float32))
    dom = penumbra.EnvMap(ctx, env).decompose(1)
    assert abs(dom.solid_angle[0] - 4 * math.pi) < 1e-5
    assert abs(dom.cap_radius[0] - math.pi) < 1e-6
    np.testing.assert_allclose(dom.radiance[0], tex.power.sum(0), rtol=1e-6)
    s = (tex.weight[:, None] * tex.dirs).sum(0)
    assert np.linalg.norm(dom.directions[0] - s / np.linalg.norm(s)) < CENTRE_CHORD


def test_black_maps_and_too_many_directions_are_refused(ctx):
    black = penumbra.EnvMap(ctx, np.zeros((32, 64, 3), np.float32))
    with pytest.raises(PenumbraError, match="only 0 non-black texels.*black"):
        black.decompose(1)
    env = np.zeros((32, 64, 3), np.float32)
    env[5, 7] = env[20, 40] = env[30, 3] = 1.0
    three = penumbra.EnvMap(ctx, env)
    with pytest.raises(PenumbraError, match="4 directions requested but the env map has only 3 non-black"):
        three.decompose(4)
    assert len(three.decompose(3)) == 3
    with pytest.raises(PenumbraError, match="count must be 1..1024"):
        three.decompose(0)
    with pytest.raises(InputError, match="n must be"):
        three.decompose(1025)
    three.set(intensity=0.0)
    three.commit()
    with pytest.raises(PenumbraError, match="intensity is 0"):
        three.decompose(1)
    three.set(intensity=2.0)
    with pytest.raises(PenumbraError, match="pn_envmap_commit"):
        three.decompose(1)


@pytest.mark.parametrize("n", [8, 32, 128])
def test_a_1e5_sun_gets_a_domain_of_its_own(ctx, n):
    """The twin's hard case through the library: one texel 1e5 brighter than a
    constant sky; its domain's centre is within a hundredth of a texel of it and
    the sky adds under 2 % to that domain (measured 1.4 % at N = 8)."""
    w, h = 128, 64
    env = pr.constant(1.0, w, h).astype(np.float32)
    i, j = pr.direction_to_pixel((0.3, 0.7, -0.2), w, h)
    env[j, i] = 1e5
    tex = dm.texels(env)
    k = j * w + i
    dom = penumbra.EnvMap(ctx, env).decompose(n, seed=3)
    a = int(np.argmax(dom.radiance[:, 0]))
    chord = np.linalg.norm(dom.directions[a] - tex.dirs[k])
    assert chord < 0.01 * 2 * math.pi / w
    assert tex.power[k, 0] <= dom.radiance[a, 0] < 1.02 * tex.power[k, 0]
    assert np.delete(dom.radiance[:, 0], a).max() < 0.05 * tex.power[k, 0]


def test_constant_map_gets_domains_of_near_equal_size(ctx):
    env = pr.constant((2.0, 1.0, 0.5), 64, 32)
    dom = penumbra.EnvMap(ctx, env).decompose(16, seed=0)
    np.testing.assert_allclose(dom.radiance, dom.solid_angle[:, None] * [2.0, 1.0, 0.5], rtol=1e-6)
    np.testing.assert_allclose(dom.solid_angle, 4 * math.pi / 16, rtol=0.15)
    assert abs(dom.solid_angle.sum() - 4 * math.pi) < 1e-5


def test_rotation_turns_the_directions_and_intensity_scales_the_radiance(ctx):
    """rotation_deg turns the map about +y (envmap.cl: direction d sees the map at
    R_y(-angle) d), so the domains turn with it; intensity scales L~ only."""
    env = pr.sky(128, 64)
    em = penumbra.EnvMap(ctx, env)
    base = em.decompose(16, seed=2)
    em.set(rotation_deg=30.0, intensity=3.0)
    em.commit()
    turned = em.decompose(16, seed=2)
    a = math.radians(30.0)
    rot = np.array([[math.cos(a), 0, math.sin(a)], [0, 1, 0], [-math.sin(a), 0, math.cos(a)]])
    assert np.linalg.norm(turned.directions - base.directions @ rot.T, axis=1).max() < 1e-6
    np.testing.assert_allclose(turned.radiance, 3.0 * base.radiance, rtol=1e-6)
    np.testing.assert_array_equal(turned.solid_angle, base.solid_angle)
    # the sun of the rotated map is where the renderer's cube map has it
    cube = em.cube_radiance().reshape(-1, 3)
    dirs = em.cube_directions()[0].reshape(-1, 3)
    sun = dirs[np.argmax(cube[:, 0])]
    top = turned.directions[np.argmax(turned.radiance[:, 0] / turned.solid_angle)]
    assert sun @ top > math.cos(math.radians(5.0))


def test_deterministic_for_a_seed_and_cached(ctx):
    env = pr.sky(128, 64)
    a = penumbra.EnvMap(ctx, env).decompose(24, seed=7)
    b = penumbra.EnvMap(ctx, env).decompose(24, seed=7)  # a new map: no cache
    for f in ("directions", "radiance", "solid_angle", "cap_radius"):
        np.testing.assert_array_equal(getattr(a, f), getattr(b, f))
    c = penumbra.EnvMap(ctx, env).decompose(24, seed=8)
    assert not np.array_equal(a.directions, c.directions)
    em = penumbra.EnvMap(ctx, env)
    first = em.decompose(24, seed=7)
    em.set(face_size=32)  # another cube size: same lighting, the cached result stays right
    em.commit()
    np.testing.assert_array_equal(em.decompose(24, seed=7).directions, first.directions)
    em.set_latlong(env * 2.0)  # new content: recomputed
    em.commit()
    np.testing.assert_allclose(em.decompose(24, seed=7).radiance, 2.0 * first.radiance, rtol=1e-6)


# --------------------------------------------------------------------------- the sharp part


def lamps_map(w=128, h=64, level=1e4, where=((0.3, 0.7, -0.2), (-0.6, 0.2, 0.5), (0.1, -0.4, -0.9))):
    """A constant sky of radiance 1 with 3 x 3-texel lamps of radiance `level`; their pixels."""
    env = pr.constant((1.0, 0.9, 0.8), w, h).astype(np.float32)
    pixels = []
    for d in where:
        i, j = pr.direction_to_pixel(d, w, h)
        env[j - 1:j + 2, [(i - 1) % w, i, (i + 1) % w]] = level
        pixels.append((i, j))
    return env, pixels


def test_sharp_part_of_a_sunny_sky_is_its_sun(ctx):
    """pr.sky's 1e4 sun: one domain at the sun holding its excess over T; the
    residual is the twin's (float rounding), bounded by T, and residual + sharp
    part is the map's power to float rounding."""
    import env_sharp64 as sh

    env = pr.sky(256, 128).astype(np.float32)
    dom, residual = penumbra.EnvMap(ctx, env).extract_sharp(max_count=1, threshold=100.0)
    res64, sharp64, hot = sh.split(env, 100.0)
    assert hot.any() and len(dom) == 1
    np.testing.assert_allclose(residual, res64, rtol=1e-6, atol=0)
    tex = dm.texels(env)
    limit = 100.0 * tex.weight.sum() / (4 * math.pi)
    assert (residual.reshape(-1, 3).astype(np.float64) @ dm.LUMINANCE).max() <= limit * (1 + 1e-6)
    res_power = dm.texels(residual).power.sum(0)
    np.testing.assert_allclose(res_power + dom.radiance.sum(0), tex.power.sum(0), rtol=1e-6)
    rad, omega = sh.sharp_domains(sharp64, hot, dom.directions.astype(np.float64))
    np.testing.assert_allclose(dom.radiance, rad, rtol=1e-6)
    np.testing.assert_allclose(dom.solid_angle, omega, rtol=1e-6)
    sun = tex.dirs[np.argmax(tex.weight)]
    assert np.linalg.norm(dom.directions[0] - sun) < 2 * math.pi / 256  # within a texel


@pytest.mark.parametrize("max_count", [3, 8])
def test_sharp_part_of_three_lamps(ctx, max_count):
    """Three 3 x 3 lamps on a constant sky: max_count = 3 puts one domain on each
    lamp (their 9 texels' solid angle); 8 splits them further but every domain
    stays on a lamp, and the domains hold the lamps' excess in all."""
    import env_sharp64 as sh

    env, pixels = lamps_map()
    dom, residual = penumbra.EnvMap(ctx, env).extract_sharp(max_count=max_count, threshold=50.0)
    res64, sharp64, hot = sh.split(env, 50.0)
    assert hot.sum() == 27 and len(dom) == max_count
    np.testing.assert_allclose(residual, res64, rtol=1e-6)
    np.testing.assert_allclose(dom.radiance.sum(0), dm.texels(sharp64).power.sum(0), rtol=1e-6)
    lamp_dirs = np.array([pr.latlong_directions(128, 64)[j, i] for i, j in pixels])
    nearest_lamp = np.argmax(dom.directions @ lamp_dirs.T, axis=1)
    chord = np.linalg.norm(dom.directions - lamp_dirs[nearest_lamp], axis=1)
    assert chord.max() < 2.5 * 2 * math.pi / 128  # within the lamp's 3 x 3 texels
    if max_count == 3:
        assert sorted(nearest_lamp) == [0, 1, 2]
        omega9 = [9 * pr.latlong_row_solid_angles(128, 64)[j] for _, j in pixels]
        np.testing.assert_allclose(sorted(dom.solid_angle), sorted(omega9), rtol=2e-2)  # rows j-1..j+1 differ
        np.testing.assert_allclose(2 * math.pi * (1 - np.cos(dom.cap_radius.astype(float))), dom.solid_angle, rtol=1e-4)


def test_sharp_part_of_a_1e5_sun_is_one_small_domain(ctx):
    """The hard case: a one-texel 1e5:1 sun is the whole sharp part, its cap the texel's."""
    w, h = 128, 64
    env = pr.constant(1.0, w, h).astype(np.float32)
    i, j = pr.direction_to_pixel((0.3, 0.7, -0.2), w, h)
    env[j, i] = 1e5
    dom, residual = penumbra.EnvMap(ctx, env).extract_sharp()
    tex = dm.texels(env)
    assert len(dom) == 1
    assert np.linalg.norm(dom.directions[0] - tex.dirs[j * w + i]) < 1e-6
    np.testing.assert_allclose(dom.solid_angle[0], tex.omega[j * w + i], rtol=1e-6)
    limit = 100.0 * tex.weight.sum() / (4 * math.pi)
    np.testing.assert_allclose(dom.radiance[0], (1e5 - limit) * tex.omega[j * w + i], rtol=1e-5)
    np.testing.assert_allclose(residual[j, i], limit, rtol=1e-6)


@pytest.mark.parametrize("kind", ["constant", "black", "overcast"])
def test_maps_without_a_sharp_part_give_none(ctx, shared_data, kind):
    env = {"constant": lambda: pr.constant(2.0, 64, 32),
           "black": lambda: np.zeros((32, 64, 3)),
           "overcast": lambda: read_envmap(shared_data / "envmaps" / "potsdamer_platz_1k_polyhaven.hdr")}[kind]()
    env = np.asarray(env, np.float32)
    import env_sharp64 as sh

    if kind == "overcast":
        assert not sh.split(env, 100.0)[2].any()  # what makes it a case without sharp part
    dom, residual = penumbra.EnvMap(ctx, env).extract_sharp()
    assert len(dom) == 0
    np.testing.assert_array_equal(residual, env)


def test_sharp_part_refuses_bad_options(ctx):
    em = penumbra.EnvMap(ctx, pr.sky(64, 32))
    with pytest.raises(PenumbraError, match="threshold 1 must be"):
        em.extract_sharp(threshold=1.0)
    with pytest.raises(PenumbraError, match="threshold nan"):
        em.extract_sharp(threshold=float("nan"))
    with pytest.raises(PenumbraError, match="max_count 0 must be 1..64"):
        em.extract_sharp(max_count=0)
    with pytest.raises(InputError, match="max_count"):
        em.extract_sharp(max_count=65)
    em.set(intensity=2.0)
    with pytest.raises(PenumbraError, match="pn_envmap_commit"):
        em.extract_sharp()


@pytest.mark.parametrize("script,folder", [("env_domains_experiments", "env_domains"),
                                           ("sharp_fiv_experiment", "sharp_fiv")])
def test_committed_reports_regenerate_byte_for_byte(script, folder):
    """The numbers of docs/depthmap.md's decomposition and sharp-part tables come from these
    committed reports, which their suites rebuild exactly from the committed results.json."""
    import importlib
    import json
    import sys
    from pathlib import Path

    bench = Path(__file__).resolve().parents[1] / "bench"
    sys.path.insert(0, str(bench))
    mod = importlib.import_module(script)
    res = bench / "results" / folder
    assert mod.SUITE.report(json.loads((res / "results.json").read_text())) == (res / "report.md").read_text()
