"""Environment maps on the device (kernels/envmap.cl via pn_envmap_commit)
against float64 numpy: cube directions and solid angles, area-correct
lat-long -> cube filtering, and the exact irradiance integral."""

import numpy as np
import pytest

import penumbra
import penumbra.methods
from penumbra import procedural
from tolerances import CUBE_RTOL, IRRADIANCE_RTOL, SOLID_ANGLE_SUM_RTOL
from test_sphere_maps import cube_to_dir64, latlong_to_dir64


def latlong_power(env):
    """float64 sum of L * dw over the lat-long pixels."""
    h, w, _ = env.shape
    theta = np.pi * np.arange(h + 1) / h
    dw = 2 * np.pi / w * (np.cos(theta[:-1]) - np.cos(theta[1:]))
    return np.einsum("hwc,h->c", env.astype(np.float64), dw)


def solid_angle64(a0, b0, a1, b1):
    f = lambda x, y: np.arctan2(x * y, np.sqrt(x * x + y * y + 1))  # noqa: E731
    return f(a0, b0) - f(a0, b1) - f(a1, b0) + f(a1, b1)


def cube_reference(env, n, s, rotation_deg=0.0, intensity=1.0):
    """float64 re-implementation of envmap_latlong_to_cube's filter."""
    h, w, _ = env.shape
    step, sub = 2.0 / n, 2.0 / n / s
    out = np.zeros((6, n, n, 3))
    grid = np.arange(n) * step - 1
    ang = np.radians(rotation_deg)
    for face in range(6):
        acc, wsum = np.zeros((n, n, 3)), np.zeros((n, n))
        for sj in range(s):
            for si in range(s):
                a = grid[None, :] + sub * si
                b = grid[:, None] + sub * sj
                a, b = np.broadcast_arrays(a, b)
                wgt = solid_angle64(a, b, a + sub, b + sub)
                d = cube_to_dir64(np.full(a.shape, face), a + sub / 2, b + sub / 2)
                d /= np.linalg.norm(d, axis=-1, keepdims=True)
                c, sn = np.cos(ang), np.sin(ang)  # the map is seen at R_y(-angle) d
                x, z = c * d[..., 0] - sn * d[..., 2], sn * d[..., 0] + c * d[..., 2]
                u = np.mod(np.arctan2(x, -z) / (2 * np.pi), 1.0)
                v = np.arccos(np.clip(d[..., 1], -1, 1)) / np.pi
                px = np.minimum((u * w).astype(int), w - 1)
                py = np.minimum((v * h).astype(int), h - 1)
                acc += wgt[..., None] * env[py, px]
                wsum += wgt
        out[face] = intensity * acc / wsum[..., None]
    return out


@pytest.fixture(scope="module")
def sky():
    return procedural.sky(width=128, height=64)


def test_directions_and_solid_angles(ctx, sky):
    env = penumbra.EnvMap(ctx, sky, face_size=24, irradiance_face_size=8)
    d, sa = env.cube_directions()
    assert d.shape == (6, 24, 24, 3) and sa.shape == (6, 24, 24)
    assert abs(sa.astype(np.float64).sum() - 4 * np.pi) < SOLID_ANGLE_SUM_RTOL * 4 * np.pi
    n = 24
    c = (np.arange(n) + 0.5) * 2 / n - 1
    a, b = np.meshgrid(c, c)
    for face in range(6):
        ref = cube_to_dir64(np.full(a.shape, face), a, b)
        ref /= np.linalg.norm(ref, axis=-1, keepdims=True)
        np.testing.assert_allclose(d[face], ref, atol=2e-6)
        np.testing.assert_allclose(sa[face], solid_angle64(a - 1 / n, b - 1 / n, a + 1 / n, b + 1 / n), rtol=1e-5)


@pytest.mark.parametrize("n,rotation,intensity", [(16, 0.0, 1.0), (9, 37.0, 2.5)])
def test_cube_matches_float64_filter(ctx, sky, n, rotation, intensity):
    s = 3
    env = penumbra.EnvMap(ctx, sky, face_size=n, supersampling=s, rotation_deg=rotation, intensity=intensity,
                          irradiance_face_size=4)
    got = env.cube_radiance()
    ref = cube_reference(sky, n, s, rotation, intensity)
    # A handful of sub-samples sit within float32 rounding of a lat-long pixel
    # border and pick its neighbour: compare with a per-texel rtol, then bound the outliers.
    rel = np.abs(got - ref) / np.maximum(ref, 1e-6)
    assert np.mean(rel > CUBE_RTOL * 10) < 0.01
    assert np.allclose(got.sum(), ref.sum(), rtol=1e-4)


@pytest.mark.parametrize("face_size,rtol", [(4, 0.02), (16, 0.005), (64, 0.005)])
def test_area_correct_filter_keeps_power(ctx, face_size, rtol):
    # An all-frequency map: the sun covers a few lat-long pixels. The filter
    # samples each cube texel on a grid of sub-texels weighted by their exact
    # solid angle; with the automatic rate (sub-texel <= 1/4 lat-long pixel) the
    # sun's power is kept to 1.6 % on 4x4 faces (one texel holds 1/16 of a
    # face) and to 0.3 % from 16x16 up (measured: 0.31 %, 0.11 %).
    env_ll = procedural.sky(width=256, height=128)
    env = penumbra.EnvMap(ctx, env_ll, face_size=face_size, irradiance_face_size=4)
    _, sa = env.cube_directions()
    power = np.einsum("fijc,fij->c", env.cube_radiance().astype(np.float64), sa.astype(np.float64))
    np.testing.assert_allclose(power, latlong_power(env_ll), rtol=rtol)


def test_constant_env_gives_constant_cube_and_pi_irradiance(ctx):
    env = penumbra.EnvMap(ctx, np.full((16, 32, 3), 0.5, np.float32), face_size=32, irradiance_face_size=9)
    np.testing.assert_allclose(env.cube_radiance(), 0.5, rtol=1e-6)
    # E = integral of 0.5 cos over the hemisphere = 0.5 pi, up to the cube discretisation of the cosine.
    np.testing.assert_allclose(env.irradiance(), 0.5 * np.pi, rtol=2e-3)


def test_irradiance_is_the_exact_sum_over_cube_texels(ctx, sky):
    m = 7
    env = penumbra.EnvMap(ctx, sky, face_size=16, irradiance_face_size=m)
    L = env.cube_radiance().reshape(-1, 3).astype(np.float64)
    d, sa = env.cube_directions()
    d = d.reshape(-1, 3).astype(np.float64)
    sa = sa.reshape(-1).astype(np.float64)
    g = -1 + 2 * np.arange(m) / (m - 1)
    a, b = np.meshgrid(g, g)
    got = env.irradiance()
    for face in range(6):
        nrm = cube_to_dir64(np.full(a.shape, face), a, b).reshape(-1, 3)
        nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
        ref = np.maximum(nrm @ d.T, 0) @ (L * sa[:, None])
        np.testing.assert_allclose(got[face].reshape(-1, 3), ref, rtol=IRRADIANCE_RTOL, atol=1e-6 * ref.max())


def test_rotation_by_quarter_turn_equals_shifting_the_map(ctx, sky):
    w = sky.shape[1]
    kw = dict(face_size=16, irradiance_face_size=8)
    rotated = penumbra.EnvMap(ctx, sky, rotation_deg=90.0, **kw).irradiance()
    # Rotating the map by +90 degrees about y: direction d sees the map at
    # R_y(-90) d, i.e. world +x (u = 1/4) sees u = 1/2: at u + 1/4. A map
    # shifted left by W/4 columns shows the same thing unrotated. Cube sub-samples fall exactly on lat-long pixel
    # borders here (the cube is symmetric under quarter turns), where float32
    # rounding picks either side, so the smooth irradiance is compared.
    shifted = penumbra.EnvMap(ctx, np.roll(sky, -w // 4, axis=1), **kw).irradiance()
    np.testing.assert_allclose(rotated, shifted, rtol=5e-3)
    # The opposite direction of rotation differs by far more than that.
    wrong = penumbra.EnvMap(ctx, np.roll(sky, w // 4, axis=1), **kw).irradiance()
    assert np.max(np.abs(rotated - wrong) / rotated) > 0.2


@pytest.mark.parametrize("value,word", [(np.nan, "NaN"), (np.inf, "infinite"), (-1.0, "negative")])
def test_bad_texels_are_refused_with_position(ctx, value, word):
    env = np.ones((50, 8, 3), np.float32)
    env[40, 3, 1] = value
    env[45, 5, 0] = value
    with pytest.raises(penumbra.InputError, match=rf"2 {word}.*\(x=3, y=40\)"):
        penumbra.EnvMap(ctx, env)


def test_parameters_are_checked(ctx):
    env = np.ones((4, 8, 3), np.float32)
    with pytest.raises(penumbra.InputError, match="face_size"):
        penumbra.EnvMap(ctx, env, face_size=0)
    with pytest.raises(penumbra.InputError, match="intensity"):
        penumbra.EnvMap(ctx, env, intensity=-1.0)
    with pytest.raises(penumbra.InputError, match="shape"):
        penumbra.EnvMap(ctx, np.ones((4, 8), np.float32))
    e = penumbra.EnvMap(ctx, env, face_size=5)
    assert e.get("face_size") == 5


# ---------------------------------------------------------------- background: the full-resolution lookup

BILINEAR_SOURCE = """
#include "common/sphere_maps.cl"
kernel void latlong_bilinear(global const float *map, int w, int h, global const float4 *d, global float4 *out)
{ int i = get_global_id(0); out[i] = (float4)(pn_latlong_bilinear(map, w, h, d[i].xyz), 0.0f); }
"""

# The 8-lane version (the background pass): 8 directions per work-item, every
# third lane left out (its output must stay untouched, -1).
BILINEAR8_SOURCE = """
#include "common/sphere_maps.cl"
kernel void latlong_bilinear(global const float *map, int w, int h, global const float4 *d, global float4 *out)
{
    int base = 8 * get_global_id(0), live[8];
    float x[8], y[8], z[8], rgb[24];
    for (int l = 0; l < 8; ++l) {
        live[l] = (base + l) % 3 != 2;
        x[l] = d[base + l].x, y[l] = d[base + l].y, z[l] = d[base + l].z;
    }
    pn_latlong_bilinear8(map, w, h, vload8(0, x), vload8(0, y), vload8(0, z), live, rgb);
    for (int l = 0; l < 8; ++l)
        out[base + l] = live[l] ? (float4)(vload3(l, rgb), 0.0f) : (float4)(-1.0f);
}
"""


def special_directions():
    """The u = 0 seam from both sides, the poles, texel centres and edges of a 16 x 8 map."""
    uv = [(0.0, 0.5), (1e-6, 0.5), (1 - 1e-6, 0.5), (0.5, 0.0), (0.5, 1.0), (0.3, 1e-4), (0.7, 1 - 1e-4),
          (0.5 / 16, 0.5 / 8), (1 / 16, 1 / 8), (15.5 / 16, 7.5 / 8), (0.25, 0.5), (0.5, 0.25)]
    u, v = np.array(uv).T
    return latlong_to_dir64(u, v)


@pytest.mark.parametrize("lanes", [1, 8])
def test_latlong_bilinear_matches_float64(cl_pair, build_test_kernel, lanes):
    """pn_latlong_bilinear (lanes = 1) and pn_latlong_bilinear8 (lanes = 8,
    some lanes left out) against the float64 twin on a map of random texels
    (so any addressing error shows), at random directions, the seam and the poles."""
    import pyopencl as cl
    from envmap64 import latlong_bilinear64
    from tolerances import BACKGROUND_ATOL

    cl_ctx, queue = cl_pair
    rng = np.random.default_rng(5)
    w, h = 16, 8
    latlong = rng.uniform(0.0, 1.0, (h, w, 3)).astype(np.float32)
    d = rng.normal(size=(4096, 3))
    d = np.concatenate([special_directions(), d / np.linalg.norm(d, axis=1, keepdims=True)])
    if lanes == 8:  # every special direction in a live lane (lanes 2, 5 of each 8 are left out)
        d = np.repeat(d, 3, axis=0)[:(3 * len(d)) // 8 * 8]
    d4 = np.zeros((len(d), 4), np.float32)
    d4[:, :3] = d
    mf = cl.mem_flags
    bmap = cl.Buffer(cl_ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=latlong)
    bd = cl.Buffer(cl_ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=d4)
    out = np.empty((len(d), 4), np.float32)
    bout = cl.Buffer(cl_ctx, mf.WRITE_ONLY, out.nbytes)
    src = BILINEAR_SOURCE if lanes == 1 else BILINEAR8_SOURCE
    cl.Kernel(build_test_kernel(src), "latlong_bilinear")(queue, (len(d) // lanes,), None, bmap, np.int32(w),
                                                          np.int32(h), bd, bout)
    cl.enqueue_copy(queue, out, bout)
    expect = latlong_bilinear64(latlong, d4[:, :3].astype(np.float64))
    if lanes == 8:
        live = np.arange(len(d)) % 3 != 2
        assert (out[~live] == -1.0).all(), "a lane left out was written"
        out, expect = out[live][::2], expect[live][::2]  # each direction once (in its first live copy)
    err = np.abs(out[:, :3] - expect).max()
    assert err < BACKGROUND_ATOL, f"max error {err:.3g}"
    # The documented points: the seam blends the last and first columns
    # equally; a texel centre is that texel; the poles take the edge rows.
    lat = latlong.astype(np.float64)
    np.testing.assert_allclose(out[0, :3], 0.5 * (lat[3, 15] + lat[3, 0] + lat[4, 15] + lat[4, 0]) / 2, atol=1e-5)
    np.testing.assert_allclose(out[7, :3], lat[0, 0], atol=1e-5)
    np.testing.assert_allclose(out[9, :3], lat[7, 15], atol=1e-5)
    np.testing.assert_allclose(out[3, :3], 0.5 * (lat[0, 7] + lat[0, 8]), atol=1e-4)
    np.testing.assert_allclose(out[4, :3], 0.5 * (lat[7, 7] + lat[7, 8]), atol=1e-4)


@pytest.mark.parametrize("method", [m for m in penumbra.methods.names() if penumbra.methods.spec(m).param("background")])
def test_background_is_the_bilinear_latlong_lookup(ctx, method):
    """Every method with the `background` parameter shows, on background
    pixels, the lat-long map at full resolution in the view direction (with the
    env map's rotation and intensity), not the cube map at its face size: the
    renderer draws it after the method (methods/renderer.c), or the method's
    own kernel (fiv: the same bits as the renderer's pass, which the others
    use, on an image whose width and pixel count are not multiples of 8). background = 0 leaves them black; alpha is 0 there
    either way."""
    from envmap64 import background64
    from penumbra.methods.heightfield import HeightFieldHandle
    from tolerances import BACKGROUND_ATOL

    rng = np.random.default_rng(11)
    latlong = rng.uniform(0.0, 1.0, (32, 64, 3)).astype(np.float32)
    env = penumbra.EnvMap(ctx, latlong, face_size=8, irradiance_face_size=4, rotation_deg=30.0, intensity=2.5)
    scene = penumbra.Scene(ctx)
    scene.set_envmap(env)
    # A small height field behind the camera, out of view (heightfield needs one).
    field = HeightFieldHandle(ctx, np.zeros((2, 2)), origin=(0.0, 0.0, 100.0), size=(1.0, 1.0))
    scene.attach(scene.add(field.mesh(), None, penumbra.Material()), field)
    scene.set_camera(penumbra.Camera(position=(0, 0, 0), look_at=(0.3, 0.4, -1), up=(0, 1, 0), fov_deg=100.0,
                                     resolution=(45, 31)))
    scene.commit()
    gbuffer, image = penumbra.GBuffer(ctx, 45, 31), penumbra.Image(ctx, 45, 31)
    scene.render_gbuffer(gbuffer)
    assert (gbuffer.read("instance") == penumbra.BACKGROUND).all()
    penumbra.Renderer(ctx, method, background=1).execute(scene, gbuffer, image)
    got = image.read()
    expect = background64(latlong, gbuffer.read("position")[..., :3].astype(np.float64), 30.0, 2.5)
    err = np.abs(got[..., :3] - expect).max() / (2.5 * latlong.max())
    assert err < BACKGROUND_ATOL, f"{method}: background differs from the bilinear lookup by {err:.3g} of the max"
    assert (got[..., 3] == 0).all()
    pass_image = penumbra.Image(ctx, 45, 31)
    penumbra.Renderer(ctx, "heightfield", background=1).execute(scene, gbuffer, pass_image)
    assert np.array_equal(got, pass_image.read()), method
    # The cube at face size 8 would be blocky: neighbouring pixels differ.
    assert len(np.unique(got[..., 0])) > 0.9 * got[..., 0].size
    penumbra.Renderer(ctx, method, background=0).execute(scene, gbuffer, image)
    assert (image.read() == 0).all()
