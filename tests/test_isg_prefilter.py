"""The prefiltered env Gamma_L of the isg method (kernels/isg.cl isg_cube_halve,
isg_prefilter, pn_isg_gamma; docs/isg.md section 8) against its float64 twin
(tests/isg_shading64.py build_gamma, gamma_lookup), the twin against the exact
convolution, and the library's specular_mode through the C API.

Hard cases: a black env, a constant env (Gamma_L is the constant at every
sharpness), a 1e5:1 sun, sharpness below, at and beyond the table's ends.
"""

from __future__ import annotations

import math
import time

import numpy as np
import pyopencl as cl
import pytest
from isg_shading64 import build_gamma, cube_directions, gamma_lookup, gamma_vertices, grid_lookup, prefilter, sky_cube

from penumbra.methods.isg import gamma_levels

SOURCE = '#include "isg.cl"\n'
LOOKUP = SOURCE + """
kernel void gamma_at(global const float4 *gamma, global const int *levels, int count, float lambda0,
                     global const float4 *queries, global float4 *out)
{
    const int i = get_global_id(0);
    out[i] = (float4)(pn_isg_gamma(gamma, levels, count, lambda0, normalize(queries[i].xyz), queries[i].w), 0.0f);
}
"""
# float32 sums of up to 6 x 64^2 texel terms against float64 (relative to the level's largest value)
PREFILTER_RTOL = 2e-5
# float32 bilinear weights and log2 against float64
LOOKUP_RTOL = 2e-5
# a constant env: the ratio of two float32 sums of up to a few thousand terms each
CONSTANT_RTOL = 1e-5


def device_gamma(cl_pair, build_test_kernel, rgb: np.ndarray, face: int, seconds: list | None = None):
    """isg_cube_halve and isg_prefilter as the host runs them (build_gamma in capi/src/methods/isg.c), with
    the levels of penumbra.methods.isg.gamma_levels: (levels, per-level tables (6 n n, 3), the whole
    buffer). build_test_kernel: source -> pyopencl.Program; seconds: gets the kernels' wall time (waited
    for; bench/isg_prefilter.py)."""
    ctx, queue = cl_pair
    prg = build_test_kernel(SOURCE)
    halve, prefilter_k = cl.Kernel(prg, "isg_cube_halve"), cl.Kernel(prg, "isg_prefilter")
    mf = cl.mem_flags
    cube = np.zeros((len(rgb), 4), np.float32)
    cube[:, :3] = rgb
    dirs = cube_directions(face).astype(np.float32)
    queue.finish()
    t0 = time.perf_counter()
    src = {face: (cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=cube),
                  cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=dirs))}
    m = face
    while m % 2 == 0 and m // 2 >= 2 and len(src) < 12:
        t = 6 * (m // 2) ** 2
        out = (cl.Buffer(ctx, mf.READ_WRITE, 16 * t), cl.Buffer(ctx, mf.READ_WRITE, 16 * t))
        halve(queue, (t,), None, *src[m], np.int32(m), *out)
        src[m // 2] = out
        m //= 2
    levels = gamma_levels(face)
    offsets = np.cumsum([0] + [6 * n * n for _, n, _ in levels])
    gbuf = cl.Buffer(ctx, mf.READ_WRITE, 16 * int(offsets[-1]))
    for (lam, n, n_src), off in zip(levels, offsets):
        prefilter_k(queue, (6 * n * n,), None, *src[n_src], np.int32(n_src), np.float32(lam), np.int32(n),
                    np.int32(off), gbuf)
    queue.finish()
    if seconds is not None:
        seconds.append(time.perf_counter() - t0)
    whole = np.empty((int(offsets[-1]), 4), np.float32)
    cl.enqueue_copy(queue, whole, gbuf)
    tables = [whole[off:off + 6 * n * n, :3] for (_, n, _), off in zip(levels, offsets)]
    return levels, tables, whole


def device_lookup(cl_pair, build_test_kernel, levels, whole, queries) -> np.ndarray:
    ctx, queue = cl_pair
    mf = cl.mem_flags
    offsets = np.cumsum([0] + [6 * n * n for _, n, _ in levels])[:-1]
    lv = np.array([[o, n] for o, (_, n, _) in zip(offsets, levels)], np.int32).ravel()
    q = np.ascontiguousarray(np.asarray(queries, np.float32))
    out = np.empty((len(q), 4), np.float32)
    ro = lambda a: cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=a)  # noqa: E731
    obuf = cl.Buffer(ctx, mf.WRITE_ONLY, out.nbytes)
    k = cl.Kernel(build_test_kernel(LOOKUP), "gamma_at")
    k(queue, (len(q),), None, ro(whole), ro(lv), np.int32(len(levels)), np.float32(levels[0][0]), ro(q), obuf)
    cl.enqueue_copy(queue, out, obuf)
    return out[:, :3]


def test_levels_span_the_cube_resolution():
    lv = gamma_levels(64)
    assert [x[0] for x in lv] == [2.0 ** k for k in range(13)]  # 1 ... 4096 = 64^2
    assert lv[0][1] == 8 and lv[-1][1] == 129 and lv[0][2] == 4 and lv[-1][2] == 64
    assert gamma_levels(1) == [(1.0, 3, 1)]  # a one-texel cube: one level, the env's mean
    assert all(n_src >= min(4 * math.sqrt(lam), 64) for lam, _, n_src in lv)


@pytest.mark.parametrize("face,sun", [(8, 0.0), (16, 1e5), (12, 0.0)])
def test_prefilter_matches_twin(cl_pair, build_test_kernel, face, sun):
    """Every level (halved sources, the cube-face windows of sharp levels) against float64 over every
    texel of the same source."""
    rgb = sky_cube(face, sun)
    levels, got, _ = device_gamma(cl_pair, build_test_kernel, rgb, face)
    want = build_gamma(rgb, cube_directions(face), face, levels)
    for (lam, n, _), g, w in zip(levels, got, want):
        np.testing.assert_allclose(g, w, rtol=PREFILTER_RTOL, atol=PREFILTER_RTOL * w.max(), err_msg=f"lambda {lam}")


@pytest.mark.parametrize("value", [0.0, 2.5])
def test_black_and_constant_env(cl_pair, build_test_kernel, value):
    """Gamma_L of a constant env is the constant at every sharpness and direction (the cut and the halving
    keep the normalisation)."""
    face = 16
    levels, got, whole = device_gamma(cl_pair, build_test_kernel, np.full((6 * face * face, 3), value), face)
    for g in got:  # the constant to float32 rounding of the two sums (thousands of terms)
        np.testing.assert_allclose(g, value, rtol=CONSTANT_RTOL, atol=0.0)
    rng = np.random.default_rng(4)
    q = np.c_[rng.normal(size=(50, 3)), 10.0 ** rng.uniform(-3, 7, 50)]
    np.testing.assert_allclose(device_lookup(cl_pair, build_test_kernel, levels, whole, q), value,
                               rtol=CONSTANT_RTOL, atol=0)


def test_lookup_matches_twin_and_clamps_at_the_ends(cl_pair, build_test_kernel):
    face = 16
    levels, tables, whole = device_gamma(cl_pair, build_test_kernel, sky_cube(face, 1e5), face)
    t64 = [t.astype(np.float64) for t in tables]
    rng = np.random.default_rng(7)
    dirs = rng.normal(size=(40, 3))
    dirs[:6] = [[1, 0, 0], [0, -1, 0], [1, 1, 0], [1, 1, 1], [-1, 1e-7, -1], [0, 0, -1]]  # edges and corners
    top = levels[-1][0]
    lams = [1e-3, 0.5, 1.0, 1.5, 3.0, 77.0, top / 2 * 1.3, top, 2 * top, 1e9]
    q = np.array([[*d, lam] for d in dirs for lam in lams])
    got = device_lookup(cl_pair, build_test_kernel, levels, whole, q)
    want = np.array([gamma_lookup(levels, t64, x[:3] / np.linalg.norm(x[:3]), x[3]) for x in q])
    np.testing.assert_allclose(got, want, rtol=LOOKUP_RTOL, atol=LOOKUP_RTOL * want.max())
    # clamped: below the first level it is the first level, beyond the last the last
    d = dirs[7] / np.linalg.norm(dirs[7])
    np.testing.assert_allclose(gamma_lookup(levels, t64, d, 1e-3), grid_lookup(t64[0], levels[0][1], d))
    np.testing.assert_allclose(gamma_lookup(levels, t64, d, 1e9), grid_lookup(t64[-1], levels[-1][1], d))
    # at a level it is that level's bilinear lookup; between two, their log-linear mix
    mid = gamma_lookup(levels, t64, d, 2 ** 2.5)
    np.testing.assert_allclose(mid, 0.5 * (grid_lookup(t64[2], levels[2][1], d) + grid_lookup(t64[3], levels[3][1], d)))


def test_lookup_is_seamless_at_cube_edges(cl_pair, build_test_kernel):
    """Directions just either side of a cube edge read the same shared vertices."""
    face = 16
    levels, _, whole = device_gamma(cl_pair, build_test_kernel, sky_cube(face), face)
    eps = 1e-5
    q = []
    for y in np.linspace(-0.9, 0.9, 7):
        q += [[1.0, y, 1.0 + eps, 40.0], [1.0 + eps, y, 1.0, 40.0]]  # the +x / +z edge
    got = device_lookup(cl_pair, build_test_kernel, levels, whole, q)
    np.testing.assert_allclose(got[0::2], got[1::2], rtol=1e-4)


@pytest.mark.parametrize("face,lam,sun,bound", [(32, 1.0, 0.0, 5e-3), (32, 16.0, 0.0, 5e-3), (16, 256.0, 0.0, 5e-3),
                                                (32, 1.0, 1e5, 2e-2), (32, 16.0, 1e5, 2e-2)])
def test_levels_converge_to_the_exact_convolution(face, lam, sun, bound):
    """The twin's level (halved source, cut) at its own vertices against the exact convolution of the
    full cube's texels: the halving and the cut cost little (relative RMS; measured on face 32: 2.3e-3 at
    lambda = 1 and 7e-4 at 16 with the smooth sky, 9e-3 and 8e-3 with a 1e5:1 sun, whose direction the
    halving keeps by the power centroid; docs/isg.md gives the error by lambda)."""
    rgb = sky_cube(face, sun)
    dirs = cube_directions(face)
    level = [x for x in gamma_levels(face) if x[0] == lam]
    got = build_gamma(rgb, dirs, face, level)[0]
    want = prefilter(rgb, dirs, lam, gamma_vertices(level[0][1]), cut=None)
    assert np.sqrt(np.mean((got - want) ** 2)) / np.sqrt(np.mean(want ** 2)) < bound
