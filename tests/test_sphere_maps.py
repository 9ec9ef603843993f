"""Device direction mappings (kernels/common/sphere_maps.cl) against float64 numpy."""

import numpy as np
import pyopencl as cl
import pytest

from tolerances import MAPPING_ATOL, ROUNDTRIP_ANGLE_ATOL, SOLID_ANGLE_SUM_RTOL

SOURCE = """
#include "common/sphere_maps.cl"
kernel void latlong_to_dir(global const float2 *uv, global float4 *out)
{ int i = get_global_id(0); out[i] = (float4)(pn_latlong_to_dir(uv[i].x, uv[i].y), 0.0f); }
kernel void dir_to_latlong(global const float4 *d, global float2 *out)
{ int i = get_global_id(0); out[i] = pn_dir_to_latlong(d[i].xyz); }
kernel void dir_to_cube(global const float4 *d, global float4 *out)
{ int i = get_global_id(0); float a, b; int f = pn_dir_to_cube(d[i].xyz, &a, &b); out[i] = (float4)(a, b, (float)f, 0.0f); }
kernel void cube_to_dir(global const float4 *fab, global float4 *out)
{ int i = get_global_id(0); out[i] = (float4)(pn_cube_to_dir((int)fab[i].z, fab[i].x, fab[i].y), 0.0f); }
kernel void texel_solid_angles(int n, global float *out)
{
    int gid = get_global_id(0); int face = gid / (n * n), j = (gid / n) % n, i = gid % n;
    float s = 2.0f / n, a0 = -1.0f + s * i, b0 = -1.0f + s * j;
    out[gid] = pn_cube_solid_angle(a0, b0, a0 + s, b0 + s);
}
"""

# float64 references of the documented conventions (docs/conventions.md).
CUBE = [lambda a, b: (np.ones_like(a), -b, -a), lambda a, b: (-np.ones_like(a), -b, a),
        lambda a, b: (a, np.ones_like(a), b), lambda a, b: (a, -np.ones_like(a), -b),
        lambda a, b: (a, -b, np.ones_like(a)), lambda a, b: (-a, -b, -np.ones_like(a))]


def latlong_to_dir64(u, v):
    phi, theta = 2 * np.pi * u, np.pi * v
    return np.stack([np.sin(phi) * np.sin(theta), np.cos(theta), -np.cos(phi) * np.sin(theta)], -1)


def cube_to_dir64(face, a, b):
    out = np.empty(a.shape + (3,))
    for f in range(6):
        m = face == f
        out[m] = np.stack(CUBE[f](a[m], b[m]), -1)
    return out


def run(cl_pair, build, name, inputs, out_shape, out_dtype, *scalars):
    ctx, queue = cl_pair
    prg = build(SOURCE)
    bufs = [cl.Buffer(ctx, cl.mem_flags.READ_ONLY | cl.mem_flags.COPY_HOST_PTR, hostbuf=np.ascontiguousarray(x))
            for x in inputs]
    out = np.empty(out_shape, out_dtype)
    obuf = cl.Buffer(ctx, cl.mem_flags.WRITE_ONLY, out.nbytes)
    cl.Kernel(prg, name)(queue, (out_shape[0],), None, *scalars, *bufs, obuf)
    cl.enqueue_copy(queue, out, obuf)
    return out


def random_dirs(n, seed=0):
    d = np.random.default_rng(seed).normal(size=(n, 3))
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def test_latlong_to_dir_matches_float64(cl_pair, build_test_kernel):
    rng = np.random.default_rng(1)
    uv = rng.random((4096, 2))
    uv[:8] = [[0, 0], [0, 1], [0.25, 0.5], [0.5, 0.5], [0.75, 0.5], [0.999999, 0.5], [0.5, 1e-7], [0.5, 1 - 1e-7]]
    got = run(cl_pair, build_test_kernel, "latlong_to_dir", [uv.astype(np.float32)], (len(uv), 4), np.float32)
    ref = latlong_to_dir64(uv[:, 0].astype(np.float32).astype(np.float64), uv[:, 1].astype(np.float32).astype(np.float64))
    np.testing.assert_allclose(got[:, :3], ref, atol=MAPPING_ATOL * 4)
    # The documented axes: u=0 -> -z, u=0.25 -> +x, u=0.5 -> +z, u=0.75 -> -x, v=0 -> +y.
    np.testing.assert_allclose(got[2, :3], [1, 0, 0], atol=1e-6)
    np.testing.assert_allclose(got[3, :3], [0, 0, 1], atol=1e-6)
    np.testing.assert_allclose(got[4, :3], [-1, 0, 0], atol=1e-6)
    np.testing.assert_allclose(got[0, :3], [0, 1, 0], atol=1e-6)


def test_dir_to_latlong_round_trip_including_seam_and_poles(cl_pair, build_test_kernel):
    d = random_dirs(4096, 2)
    # The u = 0 / 1 seam (direction -z, with tiny +-x), and the poles.
    d[:6] = [[1e-7, 0, -1], [-1e-7, 0, -1], [0, 0, -1], [0, 1, 0], [0, -1, 0], [1e-4, 1, 0]]
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    d4 = np.zeros((len(d), 4), np.float32)
    d4[:, :3] = d
    uv = run(cl_pair, build_test_kernel, "dir_to_latlong", [d4], (len(d), 2), np.float32)
    assert np.all((uv[:, 0] >= 0) & (uv[:, 0] < 1)) and np.all((uv[:, 1] >= 0) & (uv[:, 1] <= 1))
    back = latlong_to_dir64(uv[:, 0].astype(np.float64), uv[:, 1].astype(np.float64))
    angle = np.arccos(np.clip(np.sum(back * d, axis=1), -1, 1))
    assert angle.max() < ROUNDTRIP_ANGLE_ATOL
    # Seam: directions just either side of -z land next to the seam (u ~ 0 on the
    # +x side; u ~ 1 on the -x side, which float32 may round up to 1 and wrap to 0).
    seam_distance = np.minimum(uv[:2, 0], 1 - uv[:2, 0])
    assert np.all(seam_distance < 1e-5)
    assert uv[0, 0] < 1e-5


def test_cube_round_trip_faces_edges_and_corners(cl_pair, build_test_kernel):
    d = random_dirs(4096, 3)
    # Face centres, edge midpoints and corners: ties must resolve to one face.
    axes = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1],
                     [1, 1, 0], [1, 0, 1], [0, 1, 1], [-1, -1, 0], [1, 1, 1], [-1, 1, -1]], float)
    d[:len(axes)] = axes / np.linalg.norm(axes, axis=1, keepdims=True)
    d4 = np.zeros((len(d), 4), np.float32)
    d4[:, :3] = d
    fab = run(cl_pair, build_test_kernel, "dir_to_cube", [d4], (len(d), 4), np.float32)
    face = fab[:, 2].astype(int)
    np.testing.assert_array_equal(face[:6], np.arange(6))
    assert np.all(np.abs(fab[:, :2]) <= 1 + 1e-6)
    # Reference face: the axis of largest magnitude.
    major = np.argmax(np.abs(d), axis=1)
    ref_face = 2 * major + (np.take_along_axis(d, major[:, None], 1)[:, 0] < 0)
    tie = np.sort(np.abs(d), axis=1)
    clear = tie[:, 2] - tie[:, 1] > 1e-5
    np.testing.assert_array_equal(face[clear], ref_face[clear])
    back = cube_to_dir64(face, fab[:, 0].astype(np.float64), fab[:, 1].astype(np.float64))
    back /= np.linalg.norm(back, axis=1, keepdims=True)
    np.testing.assert_allclose(back, d, atol=MAPPING_ATOL * 2)
    # And the device's own cube -> direction agrees with the float64 table.
    dev = run(cl_pair, build_test_kernel, "cube_to_dir", [fab], (len(d), 4), np.float32)[:, :3]
    np.testing.assert_allclose(dev, cube_to_dir64(face, fab[:, 0].astype(np.float64), fab[:, 1].astype(np.float64)),
                               atol=MAPPING_ATOL)


@pytest.mark.parametrize("n", [1, 2, 7, 64, 256])
def test_texel_solid_angles_sum_to_4pi_and_match_quadrature(cl_pair, build_test_kernel, n):
    sa = run(cl_pair, build_test_kernel, "texel_solid_angles", [], (6 * n * n,), np.float32, np.int32(n))
    assert sa.min() > 0
    assert abs(sa.astype(np.float64).sum() - 4 * np.pi) < SOLID_ANGLE_SUM_RTOL * 4 * np.pi
    # Quadrature of the solid-angle density 1/(1+a^2+b^2)^(3/2) over a few texels.
    k = 64
    for j, i in [(0, 0), (n // 2, n // 3), (n - 1, n - 1)]:
        s = 2.0 / n
        t = (np.arange(k) + 0.5) / k * s
        a = -1 + s * i + t[None, :]
        b = -1 + s * j + t[:, None]
        ref = np.sum((s / k) ** 2 / (1 + a * a + b * b) ** 1.5)
        assert abs(sa[j * n + i] - ref) < 1e-4 * ref
