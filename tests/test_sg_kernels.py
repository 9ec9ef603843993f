"""Device spherical Gaussians (kernels/common/sg.cl) against their float64 twin
tests/isg64.py, and the library's ISG table (capi/src/core/isg_table.c)
against the twin's: evaluation, integrals at lambda -> 0 and 1e4, products of
nearly opposite and aligned lobes, SG x clamped cosine against exact
quadrature, the lobe frame, and the ISG (table and seed fit) against exact
quadrature for lambda in [1e-3, 1e4] over the whole sphere."""

from __future__ import annotations

import math

import numpy as np
import pyopencl as cl
import pytest

import isg64 as g
from penumbra.sg import ISG_TABLE_SHAPE, isg_table

SOURCE = """
#include "common/sg.cl"
kernel void isg_eval(global const float4 *q, global const float *table, global float *out)
{ int i = get_global_id(0); out[i] = pn_isg(q[i].x, q[i].y, q[i].z, table); }
kernel void isg_seed(global const float4 *q, global float *out)
{ int i = get_global_id(0); out[i] = pn_isg_seed(q[i].x, q[i].y, q[i].z); }
kernel void isg_patch(global const float8 *q, global const float *table, global float *out)
{ int i = get_global_id(0); float8 p = q[i];
  out[2 * i] = pn_isg_patch(p.s0, p.s1, p.s2, p.s3, p.s4, table);
  out[2 * i + 1] = pn_isg_patch_seed(p.s0, p.s1, p.s2, p.s3, p.s4); }
kernel void sg_scalars(global const float2 *q, global float8 *out)
{ int i = get_global_id(0); float t = q[i].x, l = q[i].y;
  out[i] = (float8)(pn_sg_integral(l), pn_sg_hemisphere_integral(l), pn_sg_cosine(t, l), pn_sg_cosine_seed(t, l),
                    pn_sg_eval((float3)(sqrt(fmax(0.0f, 1.0f - t * t)), 0.0f, t), (float3)(0.0f, 0.0f, 1.0f), l),
                    0.0f, 0.0f, 0.0f); }
kernel void sg_product(global const float8 *q, global float8 *out)
{ int i = get_global_id(0); float8 p = q[i]; pn_sg a, b;
  a.axis = p.s012; a.sharpness = p.s3; a.amplitude = (float3)(1.0f, 2.0f, 0.5f);
  b.axis = p.s456; b.sharpness = p.s7; b.amplitude = (float3)(1.0f);
  pn_sg m = pn_sg_product(a, b); float3 ip = pn_sg_inner_product(a, b);
  out[i] = (float8)(m.axis, m.sharpness, m.amplitude.x, m.amplitude.y / 2.0f, ip.x, 0.0f); }
kernel void brdf_sg(global const float8 *q, global const float4 *mat, global float8 *out)
{ int i = get_global_id(0); float8 p = q[i];
  pn_material m = pn_material_from_gbuffer((float4)(0.5f, 0.5f, 0.5f, 1.0f), mat[i]);
  pn_sg g = pn_brdf_sg(m, p.s012, p.s456);
  out[i] = (float8)(g.axis, g.sharpness, g.amplitude.x, g.amplitude.z, 0.0f, 0.0f); }
kernel void sg_reflected(global const float8 *light, global const float8 *lobe, global float *out)
{ int i = get_global_id(0); pn_sg a, b; float8 p = light[i], q = lobe[i];
  a.axis = p.s012; a.sharpness = p.s3; a.amplitude = (float3)(1.0f);
  b.axis = q.s012; b.sharpness = q.s3; b.amplitude = (float3)(q.s4);
  out[i] = pn_sg_reflected(a, b, p.s456).x; }
kernel void sg_frame(global const float4 *axes, global const float4 *dirs, global float16 *out)
{ int i = get_global_id(0); float3 z = axes[i].xyz, x, y; pn_sg_frame(z, &x, &y);
  float2 tp = pn_isg_angles(dirs[i].xyz, x, y, z); float3 back = pn_isg_direction(tp.x, tp.y, x, y, z);
  float2 ax = pn_isg_angles(z, x, y, z);
  out[i] = (float16)(x, y, back, tp, ax, 0.0f, 0.0f, 0.0f); }
"""


@pytest.fixture(scope="module")
def device(cl_pair, build_test_kernel):
    ctx, queue = cl_pair
    prg = build_test_kernel(SOURCE)
    table = isg_table()
    tbuf = cl.Buffer(ctx, cl.mem_flags.READ_ONLY | cl.mem_flags.COPY_HOST_PTR, hostbuf=table.ravel())

    def run(name, inputs, out_shape, with_table=False):
        bufs = [cl.Buffer(ctx, cl.mem_flags.READ_ONLY | cl.mem_flags.COPY_HOST_PTR,
                          hostbuf=np.ascontiguousarray(x, np.float32)) for x in inputs]
        if with_table:
            bufs.append(tbuf)
        out = np.empty(out_shape, np.float32)
        obuf = cl.Buffer(ctx, cl.mem_flags.WRITE_ONLY, out.nbytes)
        cl.Kernel(prg, name)(queue, (len(inputs[0]),), None, *bufs, obuf)
        cl.enqueue_copy(queue, out, obuf)
        return out.astype(np.float64)

    return run


def f32(x):
    return np.asarray(x, np.float64).astype(np.float32).astype(np.float64)


# --------------------------------------------------------------------------- the library's table


def back_marginals64(lam):
    """Independent float64 back-hemisphere marginals T at the 33 offsets x = j pi/64 from
    pi/2, by a tensor Gauss-Legendre rule on [0, pi/2]^2 of exp(-lam cos u cos w) sin(theta)
    (panels ending on the x's). The twin's table takes them as e^lam (S(theta, 2 pi) -
    S(theta, pi)), a difference of O(1) numbers that loses its digits once e^-lam nears
    1e-16 (lam > ~20), so it cannot check those rows."""
    per = 4  # panels per table interval
    nodes, weights = g.panel_rule(np.linspace(0.0, np.pi / 2, 32 * per + 1), 16)
    cu = np.cos(nodes)
    f = np.exp(-lam * np.outer(cu, cu)) * (weights * cu)[:, None] * weights[None, :]  # sin(theta) = cos(u)
    out = []
    for row in (f.sum(1), f.sum(0)):  # theta marginal (over w), phi marginal (over u)
        cum = np.concatenate([[0.0], np.cumsum(row.reshape(32, per * 16).sum(1))])
        out.append(0.5 * cum / cum[-1])
    return out


def test_library_table_matches_the_twin():
    c = isg_table().astype(np.float64)
    tb = g.isg_table()
    assert c.shape == ISG_TABLE_SHAPE
    lams = np.exp(tb.log_lambdas)
    # front marginals: every row, to float32 rounding
    assert np.abs(c[0] - tb.front_theta).max() < 1e-7
    assert np.abs(c[1] - tb.front_phi).max() < 1e-7
    # back marginals: the rows where the twin still has its digits
    ok = lams <= 10.0
    assert np.abs(c[2][ok] - tb.back_theta[ok]).max() < 1e-7
    assert np.abs(c[3][ok] - tb.back_phi[ok]).max() < 1e-7
    # every back row against an independent quadrature
    for i in np.flatnonzero(lams <= g.BACK_LAMBDA_MAX):
        bt, bp = back_marginals64(lams[i])
        assert np.abs(c[2, i] - bt).max() < 1e-7 and np.abs(c[3, i] - bp).max() < 1e-7, lams[i]
    assert np.all(c[2:, lams > g.BACK_LAMBDA_MAX] == 0)
    # marginals are CDF halves: 0 at the centre, 1/2 at the end, increasing
    assert np.all(c[:, :, 0] == 0) and np.allclose(c[:2, :, -1], 0.5, atol=1e-7)
    assert np.all(np.diff(c[:2], axis=2) >= 0)


def test_library_table_refuses_a_wrong_size():
    import ctypes

    from penumbra import PenumbraError
    from penumbra._native import call

    out = np.empty(100, np.float32)
    with pytest.raises(PenumbraError, match="7524"):
        call("pn_isg_table", None, out.ctypes.data, out.size)
    with pytest.raises(PenumbraError, match="NULL"):
        call("pn_isg_table", None, ctypes.c_void_p(), 7524)


# --------------------------------------------------------------------------- the ISG on the device

TH = np.linspace(0, np.pi, 91)
PH = np.linspace(0, 2 * np.pi, 121)
# 16 per decade over the requirement's range (on and between table rows) and beyond it
ISG_LAMBDAS = np.concatenate([10.0 ** (np.arange(-48, 65, 2) / 16), [10.0 ** (-47 / 16), 10.0 ** (33 / 16), 3e4, 1e6]])


def device_isg_grid(device, lam, kernel="isg_eval"):
    t, p = np.meshgrid(f32(TH), f32(PH), indexing="ij")
    q = np.stack([np.full(t.size, lam), t.ravel(), p.ravel(), np.zeros(t.size)], -1)
    if kernel == "isg_eval":
        return device("isg_eval", [q], t.size, with_table=True).reshape(t.shape)
    return device(kernel, [q], t.size).reshape(t.shape)


def test_device_isg_accurate_everywhere(device):
    """max |pn_isg - S_hat| over theta in [0, pi], phi in [0, 2 pi] (the back included) is
    <= 0.005 for every lambda in [1e-3, 1e4] and beyond (the requirement: 0.01; the table's
    own float64 error is 0.0040, float32 adds ~1e-6), and pn_isg agrees with the twin's
    isg_eval to 2e-5."""
    worst = 0.0
    for lam in ISG_LAMBDAS:
        lam = float(f32(lam))
        exact = g.isg_exact_grid(lam, f32(TH), f32(PH))
        got = device_isg_grid(device, lam)
        twin = g.isg_eval(f32(TH)[:, None], f32(PH)[None, :], lam)
        assert np.all(np.isfinite(got))
        assert np.abs(got - twin).max() < 2e-5, lam
        worst = max(worst, np.abs(got - exact).max())
    assert worst <= 5e-3, worst


def test_device_isg_identities(device):
    for lam in [1e-3, 2.0, 1e4]:
        q = np.array([[lam, np.pi, np.pi, 0], [lam, 0, 1, 0], [lam, 1, 0, 0], [lam, np.pi, 2 * np.pi, 0],
                      [lam, np.pi / 2, np.pi, 0], [lam, -1, 9, 0]])
        s = device("isg_eval", [q], len(q), with_table=True)
        assert s[0] == pytest.approx(1.0, abs=2e-6)
        assert s[1] == 0 and s[2] == 0
        assert s[3] == pytest.approx(1 + math.exp(-lam), abs=2e-6)
        assert s[4] == pytest.approx(0.5, abs=2e-6)
        assert s[5] == pytest.approx(0.0, abs=1e-7)  # clamped angles


def test_device_seed_fit_matches_the_twin(device):
    for lam in [1.0, 100.0, 1000.0]:
        got = device_isg_grid(device, lam, "isg_seed")
        twin = g.isg_seed_fit(f32(TH)[:, None], np.minimum(f32(PH), np.pi)[None, :], lam)
        assert np.abs(got - twin).max() < 2e-6
    # and it is the crude option: 0.59 off at lambda = 1
    exact = g.isg_exact_grid(1.0, f32(TH), f32(PH[:61]))
    assert np.abs(device_isg_grid(device, 1.0, "isg_seed")[:, :61] - exact).max() > 0.5


@pytest.mark.parametrize("lam", [1e-3, 0.7, 30.0, 2e3])
def test_device_isg_patch_against_direct_quadrature(device, lam):
    rng = np.random.default_rng(int(lam * 1000))
    w = min(1.0, 3 / math.sqrt(lam))
    rows, direct = [], []
    x, wx = np.polynomial.legendre.leggauss(60)
    for _ in range(12):
        t0, t1 = np.sort(np.clip(np.pi / 2 + w * rng.uniform(-2, 2, 2), 0, np.pi))
        p0, p1 = np.sort(np.clip(np.pi / 2 + w * rng.uniform(-2, 2, 2), 0, np.pi))
        t0, t1, p0, p1 = f32([t0, t1, p0, p1])
        t = t0 + (x + 1) * (t1 - t0) / 2
        p = p0 + (x + 1) * (p1 - p0) / 2
        f = np.exp(lam * (np.outer(np.sin(t), np.sin(p)) - 1)) * np.sin(t)[:, None]
        direct.append((t1 - t0) * (p1 - p0) / 4 * (wx @ f @ wx) / g.sg_hemisphere_integral(lam))
        rows.append([lam, t0, t1, p0, p1, 0, 0, 0])
    got = device("isg_patch", [np.array(rows)], (len(rows), 2), with_table=True)
    # four corners, each within the evaluation's 0.005
    assert np.abs(got[:, 0] - np.array(direct)).max() <= 4 * 5e-3
    twin = [g.patch_integral(g.isg_seed_fit, *r[1:5], lam) / g.sg_hemisphere_integral(lam) for r in rows]
    assert np.abs(got[:, 1] - np.array(twin)).max() < 1e-5


# --------------------------------------------------------------------------- SG integrals, products, cosine


def test_device_sg_integrals_no_overflow_or_cancellation(device):
    lams = np.array([0.0, 1e-7, 1e-3, 0.5, 1.0, 30.0, 1e4, 1e6, 1e30, 3e38])
    q = np.stack([np.zeros_like(lams), lams], -1)
    out = device("sg_scalars", [q], (len(q), 8))
    assert np.all(np.isfinite(out[:, :3])) and np.all(np.isfinite(out[:-1, :5]))
    np.testing.assert_allclose(out[:, 0], g.sg_integral(f32(lams)), rtol=2e-6)
    np.testing.assert_allclose(out[:, 1], g.sg_hemisphere_integral(f32(lams)), rtol=2e-6)


def test_device_sg_eval(device):
    t = np.linspace(-1, 1, 41)
    for lam in [1e-3, 1.0, 1e4]:
        out = device("sg_scalars", [np.stack([t, np.full_like(t, lam)], -1)], (len(t), 8))
        ref = np.exp(lam * (f32(t) - 1))
        np.testing.assert_allclose(out[:, 4], ref, rtol=2e-6 * max(1.0, lam), atol=1e-37)


def product_inputs():
    rows = []
    rng = np.random.default_rng(5)
    for angle in [0.0, 1e-4, 0.3, 1.5, 3.0, np.pi - 1e-3, np.pi]:
        for l1, l2 in [(1e-3, 1e-3), (1.0, 20.0), (1e3, 1e3), (1e4, 3.0)]:
            a1 = rng.normal(size=3)
            a1 /= np.linalg.norm(a1)
            e = np.cross(a1, [0.0, 0.0, 1.0])
            e /= np.linalg.norm(e)
            a2 = math.cos(angle) * a1 + math.sin(angle) * e
            rows.append([*f32(a1), l1, *f32(a2 / np.linalg.norm(a2)), l2])
    return np.array(rows)


def test_device_sg_product_matches_the_twin(device):
    q = product_inputs()
    out = device("sg_product", [q], (len(q), 8))
    axis, lam_m, mu_m = g.sg_product(q[:, :3], q[:, 3], 1.0, q[:, 4:7], q[:, 7], 1.0)
    assert np.all(np.isfinite(out))
    scale = q[:, 3] + q[:, 7]
    # float32: lam_m to 1e-6 relative of lam1 + lam2 (what the inputs' rounding allows)
    assert np.all(np.abs(out[:, 3] - lam_m) <= 2e-6 * scale)
    # exponent lam_m - lam1 - lam2: to the same absolute accuracy
    ok = mu_m > 1e-30
    assert np.all(np.abs(np.log(out[ok, 4]) - np.log(mu_m[ok])) <= 4e-6 * scale[ok] + 1e-6)
    np.testing.assert_allclose(out[:, 5], out[:, 4], rtol=1e-6)  # amplitudes multiply per channel
    has_axis = lam_m > 1e-3 * scale
    assert np.all(np.abs(np.sum(out[has_axis, :3] * axis[has_axis], -1) - 1) < 1e-5)
    ref = g.sg_integral(lam_m[ok], mu_m[ok])  # the inner product: mu_m's exponent error carries over
    assert np.all(np.abs(out[ok, 6] - ref) <= (4e-6 * scale[ok] + 1e-5) * ref)


def test_device_sg_product_of_exactly_opposite_equal_lobes_is_constant(device):
    a = np.array([0.6, 0.0, 0.8])
    q = np.array([[*a, 7.0, *-a, 7.0]])
    out = device("sg_product", [q], (1, 8))
    assert out[0, 3] == 0.0 and out[0, 4] == pytest.approx(math.exp(-14.0), rel=1e-5)
    assert out[0, 6] == pytest.approx(4 * math.pi * math.exp(-14.0), rel=1e-5)


COSINE_T = np.linspace(-1, 1, 81)
COSINE_LAMBDAS = 10.0 ** np.linspace(-3, 4, 22)


@pytest.fixture(scope="module")
def cosine_device(device):
    t, lam = np.meshgrid(COSINE_T, COSINE_LAMBDAS, indexing="ij")
    out = device("sg_scalars", [np.stack([t.ravel(), lam.ravel()], -1)], (t.size, 8))
    return out[:, 2].reshape(t.shape), out[:, 3].reshape(t.shape)


def test_device_sg_cosine_against_exact(cosine_device):
    """pn_sg_cosine against exact quadrature: max error 0.40 % of E(1) (the twin's
    closed form: 0.40 %; asserted <= 0.45 %), and against the twin's closed form to float32."""
    closed, seed = cosine_device
    exact = g.sg_cosine_exact(COSINE_T[:, None], COSINE_LAMBDAS[None, :])
    top = g.sg_cosine_exact(1.0, COSINE_LAMBDAS)
    assert np.all(np.isfinite(closed)) and np.all(closed >= 0)
    err = np.abs(closed - exact) / top
    assert err.max() <= 4.5e-3, err.max()
    twin = g.sg_cosine_closed(f32(COSINE_T)[:, None], f32(COSINE_LAMBDAS)[None, :])
    assert (np.abs(closed - twin) / top).max() < 2e-5
    seed_twin = g.sg_cosine_seed(f32(COSINE_T)[:, None], f32(COSINE_LAMBDAS)[None, :])
    assert (np.abs(seed - seed_twin) / top).max() < 2e-5
    assert (np.abs(seed - exact) / top).max() > 0.15  # the seed's single-SG cosine: 17 %


def test_device_sg_cosine_small_lambda_and_below_horizon(device):
    q = np.array([[0.0, 0.0], [0.5, 0.0], [-1.0, 1e-7], [1.0, 1e-7], [-0.9, 1e4], [-0.05, 3e3], [0.2, 1e6]])
    out = device("sg_scalars", [q], (len(q), 8))[:, 2]
    assert np.all(np.isfinite(out)) and np.all(out >= 0)
    assert out[0] == pytest.approx(math.pi, rel=1e-5) and out[1] == pytest.approx(math.pi, rel=1e-5)
    assert out[2] == pytest.approx(math.pi, rel=1e-5) and out[3] == pytest.approx(math.pi, rel=1e-5)
    assert out[4] < 1e-8
    for k in (5, 6):
        exact = float(g.sg_cosine_exact(q[k, 0], q[k, 1]))
        assert abs(out[k] - exact) <= 4.5e-3 * float(g.sg_cosine_exact(1.0, q[k, 1]))


# --------------------------------------------------------------------------- the lobe frame


def test_device_lobe_frame_and_angles(device):
    rng = np.random.default_rng(9)
    axes = rng.normal(size=(512, 3))
    axes[:4] = [[0, 0, 1], [0, 0, -1], [1, 0, 0], [0, 1e-7, -1]]
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    dirs = rng.normal(size=(512, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    pad = np.zeros((512, 1))
    out = device("sg_frame", [np.hstack([axes, pad]), np.hstack([dirs, pad])], (512, 16))
    x, y, back, tp, ax = out[:, 0:3], out[:, 3:6], out[:, 6:9], out[:, 9:11], out[:, 11:13]
    z = f32(axes)
    for a, b in [(x, y), (x, z), (y, z)]:
        assert np.abs(np.sum(a * b, -1)).max() < 1e-6
    assert np.abs(np.linalg.norm(x, axis=1) - 1).max() < 1e-6 and np.abs(np.linalg.norm(y, axis=1) - 1).max() < 1e-6
    assert np.abs(np.cross(x, y) - z).max() < 1e-5  # right-handed
    np.testing.assert_allclose(ax, np.pi / 2, atol=1e-3)  # the axis sits at (pi/2, pi/2)
    assert tp[:, 0].min() >= 0 and tp[:, 0].max() <= np.pi and tp[:, 1].min() >= 0 and tp[:, 1].max() < 2 * np.pi
    np.testing.assert_allclose(back, f32(dirs), atol=2e-6)
    # the documented convention: phi in [0, pi] is the lobe's front hemisphere
    front = np.sum(f32(dirs) * z, -1) > 1e-5
    assert np.all(tp[front, 1] <= np.pi) and np.all(tp[np.sum(f32(dirs) * z, -1) < -1e-5, 1] > np.pi)
    # and the twin's Omega(theta, phi) in that frame
    om = g.isg_direction(tp[:, 0], tp[:, 1])
    np.testing.assert_allclose(om[:, 0, None] * x + om[:, 1, None] * y + om[:, 2, None] * z, back, atol=2e-6)


# --------------------------------------------------------------------------- BRDF lobes as SGs

LOBE_INDEX = {"phong": 0, "blinn_phong": 1, "ggx": 2}


def brdf_cases(seed=11, count=48):
    rng = np.random.default_rng(seed)
    cases = []
    for i in range(count):
        n = rng.normal(size=3)
        n /= np.linalg.norm(n)
        v = rng.normal(size=3)
        v -= min(0.0, v @ n) * 2 * n  # the viewer on the normal's side
        v /= np.linalg.norm(v)
        lobe = list(LOBE_INDEX)[i % 3]
        cases.append((f32(n), f32(v), lobe, float(rng.choice([0.0, 10.0, 100.0, 1000.0])),
                      float(rng.choice([1e-4, 0.05, 0.3, 1.0]))))
    return cases


def test_device_brdf_sg_matches_the_twin(device):
    cases = brdf_cases()
    q = np.array([[*n, 0, *v, 0] for n, v, *_ in cases])
    mat = np.array([[shin, rough, LOBE_INDEX[lobe], 0] for _, _, lobe, shin, rough in cases])
    out = device("brdf_sg", [q, mat], (len(cases), 8))
    for (n, v, lobe, shin, rough), got in zip(cases, out):
        axis, lam, mu = g.brdf_sg(n, v, lobe, shin, rough)
        np.testing.assert_allclose(got[:3], axis, atol=2e-6)
        assert got[3] == pytest.approx(lam, rel=2e-6, abs=1e-6)
        # float32: the GGX amplitude at the clamped roughness 1e-3 (1/a^2 = 1e6) loses a few ulps
        assert got[4] == pytest.approx(mu, rel=1e-5) and got[5] == got[4]


def test_device_sg_reflected_matches_the_twin(device):
    cases = brdf_cases(seed=12, count=30)
    rng = np.random.default_rng(13)
    light, lobe_rows, twin = [], [], []
    for n, v, lobe, shin, rough in cases:
        axis, lam, mu = g.brdf_sg(n, v, lobe, shin, rough)
        a = f32(axis + 0.3 * rng.normal(size=3))
        a = f32(a / np.linalg.norm(a))
        ll = float(rng.choice([1.0, 30.0, 500.0]))
        light.append([*a, ll, *n, 0])
        lobe_rows.append([*f32(axis), float(f32(lam)), float(f32(mu)), 0, 0, 0])
        twin.append(g.sg_reflected(a, ll, n, (f32(axis), float(f32(lam)), float(f32(mu)))))
    got = device("sg_reflected", [np.array(light), np.array(lobe_rows)], len(cases))
    twin = np.array(twin)
    # the inner product (no cosine) bounds the value: float32 error relative to it
    scale = np.array([g.sg_inner_product(l[:3], l[3], 1.0, r[:3], r[3], r[4]) for l, r in zip(light, lobe_rows)])
    assert np.all(np.abs(got - twin) <= 1e-4 * np.maximum(scale, twin) + 1e-30)


# Measured max error of the SG shading of one light lobe against quadrature of the float64 BRDF
# (relative to the largest value at that view and light sharpness; docs/isg.md 6), view 30 deg.
BRDF_SG_CASES = [("phong", 100.0, 0.3, 0.02), ("blinn_phong", 100.0, 0.3, 0.30), ("ggx", 100.0, 0.2, 0.30)]


@pytest.mark.parametrize("lobe, shin, rough, bound", BRDF_SG_CASES)
def test_brdf_sg_twin_against_quadrature(lobe, shin, rough, bound):
    n = np.array([0.0, 0.0, 1.0])
    v = np.array([math.sin(math.radians(30)), 0.0, math.cos(math.radians(30))])
    bl = g.brdf_sg(n, v, lobe, shin, rough)
    for ll in (10.0, 300.0):
        w = 1 / math.sqrt(ll + bl[1])
        e1 = np.cross(bl[0], [0.0, 1.0, 0.0])
        e1 /= np.linalg.norm(e1)
        vals = []
        for off in (0.0, 1.0):
            a = math.cos(off * w) * bl[0] + math.sin(off * w) * e1
            vals.append((g.reflected_exact(a, ll, n, v, lobe, shin, rough, nodes=16, n_beta=256),
                         g.sg_reflected(a, ll, n, bl)))
        peak = max(x[0] for x in vals)
        assert peak > 0
        for exact, approx in vals:
            assert abs(approx - exact) <= bound * peak, (lobe, ll, exact, approx)
