"""The anisotropic Ashikhmin-Shirley lobe (docs/brdf.md): the kernel BRDF and
the tangent angle against float64 (penumbra.brdf), the tangent carried from
the material to the G-buffer, validation of bad materials and G-buffers, the
`reference` method against its float64 sum on a scene with the lobe, and a
white-furnace check of the reference against numpy quadrature."""

from __future__ import annotations

import numpy as np
import pyopencl as cl
import pytest
from geometry64 import rotation, unit
from test_reference import BRDF_SOURCE, gbuffer_of, make_scene, random_unit, reference64, shade, upper, xform
from tolerances import BRDF_RTOL, REFERENCE_RTOL

from penumbra import BACKGROUND, Camera, EnvMap, GBuffer, InputError, Material, procedural
from penumbra.brdf import ashikhmin_shirley, brdf, frame, tangent_angle, tangent_from_angle

AS = "ashikhmin_shirley"
AS_INDEX = 3
EXPONENTS = [(1.0, 1.0), (10.0, 100.0), (100.0, 10.0), (0.0, 50.0), (1000.0, 50.0), (0.0, 0.0)]

# The BRDF kernel of test_reference, and the tangent angle.
KERNEL_SOURCE = BRDF_SOURCE + """
kernel void angle(global const float4 *n, global const float4 *a, global float *out)
{
    int i = get_global_id(0);
    out[i] = pn_tangent_angle(n[i].xyz, a[i].xyz);
}
"""


def _buffers(ctx, *arrays):
    mf = cl.mem_flags
    return [cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=np.ascontiguousarray(a)) for a in arrays]


def _pad(a):
    return np.hstack([a, np.zeros((len(a), 1), np.float32)]).astype(np.float32)


# --------------------------------------------------------------------------- float64 model


def test_swapping_exponents_turns_the_lobe_by_a_right_angle():
    """n_u along u is n_v along w = n x u: (n_u, n_v, phi) equals (n_v, n_u, phi + pi/2)."""
    rng = np.random.default_rng(1)
    n = random_unit(rng, 2000)
    v, l = random_unit(rng, 2000), random_unit(rng, 2000)
    v = upper(v, n)
    l = upper(l, n)
    phi = rng.uniform(-np.pi, np.pi, 2000)
    a = ashikhmin_shirley(n, v, l, tangent_from_angle(n, phi), 10.0, 200.0)
    b = ashikhmin_shirley(n, v, l, tangent_from_angle(n, phi + np.pi / 2), 200.0, 10.0)
    np.testing.assert_allclose(a, b, rtol=1e-12)
    c = ashikhmin_shirley(n, v, l, tangent_from_angle(n, phi), 200.0, 10.0)
    assert np.abs(a - c).max() > 0.1 * a.max()  # and the lobe is anisotropic


def test_isotropic_lobe_is_the_exponent_of_blinn_phong():
    """n_u = n_v = n: the exponent is n whatever the tangent, the Blinn-Phong shape."""
    rng = np.random.default_rng(2)
    n = random_unit(rng, 500)
    v, l = random_unit(rng, 500), random_unit(rng, 500)
    v = upper(v, n)
    l = upper(l, n)
    h = unit(v + l)
    f = ashikhmin_shirley(n, v, l, tangent_from_angle(n, rng.uniform(0, 6, 500)), 40.0, 40.0)
    want = 41.0 / (8 * np.pi) * np.sum(n * h, 1) ** 40 / (np.sum(h * l, 1) * np.maximum(np.sum(n * l, 1),
                                                                                          np.sum(n * v, 1)))
    np.testing.assert_allclose(f, want, rtol=1e-10)


def test_frame_is_orthonormal_and_matches_the_angle():
    rng = np.random.default_rng(3)
    n = random_unit(rng, 1000)
    n[0] = (0, 0, -1)
    n[1] = (0, 0, 1)
    t, b = frame(n)
    for x, y in ((t, t), (b, b), (n, n)):
        np.testing.assert_allclose(np.sum(x * y, 1), 1.0, atol=1e-12)
    for x, y in ((t, b), (t, n), (b, n)):
        np.testing.assert_allclose(np.sum(x * y, 1), 0.0, atol=1e-12)
    phi = rng.uniform(-np.pi, np.pi, 1000)
    np.testing.assert_allclose(tangent_angle(n, 3.0 * tangent_from_angle(n, phi) + 0.5 * n), phi, atol=1e-12)


# --------------------------------------------------------------------------- kernel vs float64


@pytest.mark.parametrize("n_u,n_v", EXPONENTS)
def test_as_kernel_matches_float64(cl_pair, build_test_kernel, n_u, n_v):
    ctx, queue = cl_pair
    rng = np.random.default_rng(7)
    count = 4096
    n = random_unit(rng, count)
    v = random_unit(rng, count)
    v = upper(v, n)
    r = 2 * np.sum(n * v, 1)[:, None] * n - v
    l = unit(r + rng.normal(scale=0.15, size=(count, 3)))  # near the mirror direction, where the lobe is large
    l[::3] = random_unit(rng, len(l[::3]))
    phi = rng.uniform(-np.pi, np.pi, count).astype(np.float32)
    n, v, l = (x.astype(np.float32) for x in (n, v, l))
    albedo = np.tile(np.float32([0.6, 0.3, 0.1, 0.4]), (count, 1))
    material = np.column_stack([np.full(count, n_u), np.full(count, n_v), np.full(count, AS_INDEX), phi])
    bufs = _buffers(ctx, _pad(n), _pad(v), _pad(l), albedo, material.astype(np.float32))
    out = np.empty((count, 4), np.float32)
    obuf = cl.Buffer(ctx, cl.mem_flags.WRITE_ONLY, out.nbytes)
    cl.Kernel(build_test_kernel(KERNEL_SOURCE), "eval")(queue, (count,), None, *bufs, obuf)
    cl.enqueue_copy(queue, out, obuf)
    n64, v64, l64 = (x.astype(np.float64) for x in (n, v, l))
    u = tangent_from_angle(n64, phi.astype(np.float64))
    want = brdf(n64, v64, l64, albedo[0, :3].astype(np.float64), 0.4, AS, n_u, 0.3, n_v, u)
    np.testing.assert_allclose(out[:, :3], want, rtol=BRDF_RTOL, atol=1e-6)
    assert (want > 0).any() and (out[:, :3] == 0).any()  # both sides of the horizon were exercised


def test_tangent_angle_kernel_matches_float64(cl_pair, build_test_kernel):
    ctx, queue = cl_pair
    rng = np.random.default_rng(8)
    count = 4096
    n = random_unit(rng, count).astype(np.float32)
    n[:4] = [(0, 0, 1), (0, 0, -1), (1, 0, 0), (0, -1, 0)]  # both branches of the frame, poles included
    a = (rng.normal(size=(count, 3)) * rng.uniform(0.1, 10, (count, 1))).astype(np.float32)
    a[4] = 2.0 * n[4]  # along the normal: angle 0 (t)
    out = np.empty(count, np.float32)
    obuf = cl.Buffer(ctx, cl.mem_flags.WRITE_ONLY, out.nbytes)
    cl.Kernel(build_test_kernel(KERNEL_SOURCE), "angle")(queue, (count,), None, *_buffers(ctx, _pad(n), _pad(a)),
                                                         obuf)
    cl.enqueue_copy(queue, out, obuf)
    n64, a64 = n.astype(np.float64), a.astype(np.float64)
    want = tangent_angle(n64, a64)
    # Compared as directions (the angle wraps at +-pi); float32 frames and atan2: a few ulps.
    got_u, want_u = tangent_from_angle(n64, out.astype(np.float64)), tangent_from_angle(n64, want)
    grazing = np.linalg.norm(a64 - np.sum(a64 * n64, 1)[:, None] * n64, axis=1) < 1e-3 * np.linalg.norm(a64, axis=1)
    assert np.abs(got_u - want_u)[~grazing].max() < 1e-5
    assert out[4] == pytest.approx(0.0, abs=1e-3)


# --------------------------------------------------------------------------- material -> G-buffer


def _as_material(**kw):
    base = dict(albedo=(0.3, 0.3, 0.3), specular=0.6, shininess=20.0, shininess_v=400.0, lobe=AS,
                tangent=(1.0, 0.0, 0.3))
    base.update(kw)
    return Material(**base)


@pytest.fixture(scope="module")
def aniso_scene(ctx, shared_data):
    """A smooth sphere and a rotated box with the anisotropic lobe (tangents in
    their own frames) on a Blinn-Phong plane, lit by a real env map."""
    from penumbra.imageio import read_envmap
    env = EnvMap(ctx, read_envmap(shared_data / "envmaps" / "pisa_probulator_256x128.hdr"), face_size=8)
    rot = rotation((1, 1, 0), 0.7)
    objects = [
        (procedural.plane((4.0, 4.0)), xform(), Material(albedo=(0.7, 0.7, 0.7), specular=0.2, shininess=20.0,
                                                         lobe="blinn_phong")),
        (procedural.sphere(0.5, 3), xform(translate=(-0.6, 0.5, 0.0)),
         _as_material(tangent=(0.0, 1.0, 0.0))),
        (procedural.box((0.6, 0.6, 0.6)), xform(rot, (0.7, 0.6, 0.2)), _as_material(shininess=300.0, shininess_v=5.0)),
    ]
    camera = Camera(position=(1.0, 2.2, 3.5), look_at=(0.0, 0.4, 0.0), fov_deg=50.0, resolution=(32, 24))
    scene, tris, keep = make_scene(ctx, objects, env, camera)
    gb, planes = gbuffer_of(ctx, scene, camera)
    return dict(env=env, scene=scene, tris=tris, keep=keep, camera=camera, gb=gb, planes=planes, rot=rot)


def test_gbuffer_carries_exponents_and_tangent(aniso_scene):
    planes, rot = aniso_scene["planes"], aniso_scene["rot"]
    inst, mat = planes["instance"], planes["material"]
    with np.errstate(invalid="ignore"):  # background normals are zero
        n = unit(planes["normal"][..., :3].astype(np.float64))
    plane, sphere, box = inst == 0, inst == 1, inst == 2
    assert plane.sum() > 50 and sphere.sum() > 50 and box.sum() > 50
    assert (mat[plane] == np.float32([20.0, 0.3, 1.0, 0.0])).all()
    for px, n_u, n_v, axis in ((sphere, 20.0, 400.0, np.array([0.0, 1.0, 0.0])),
                               (box, 300.0, 5.0, rot @ np.array([1.0, 0.0, 0.3]))):
        assert (mat[px][:, :3] == np.float32([n_u, n_v, AS_INDEX])).all()
        got = tangent_from_angle(n[px], mat[px][:, 3].astype(np.float64))
        want = unit(axis - np.sum(n[px] * axis, 1)[:, None] * n[px])  # the axis projected onto the tangent plane
        assert np.abs(got - want).max() < 1e-4


def test_material_errors_name_the_field(ctx):
    from penumbra import Mesh, Scene
    scene = Scene(ctx)
    mesh = procedural.box((1.0, 1.0, 1.0))
    m = Mesh(ctx, mesh.vertices, mesh.faces, mesh.normals)
    with pytest.raises(InputError, match="tangent"):
        scene.add(m, None, _as_material(tangent=(0.0, 0.0, 0.0)))
    with pytest.raises(InputError, match="shininess_v"):
        scene.add(m, None, _as_material(shininess_v=-1.0))
    with pytest.raises(InputError, match="tangent must be 3 numbers"):
        scene.add(m, None, _as_material(tangent=(1.0, 0.0)))
    # Other lobes ignore the tangent (a zero one from C's positional initialisers is fine).
    scene.add(m, None, Material(specular=0.5, lobe="ggx", tangent=(0.0, 0.0, 0.0)))


def _gbuffer_with_material(ctx, material):
    gb = GBuffer(ctx, 2, 1)
    gb.write("position", np.float32([[[0, 0, 0, 1], [0, 0, 0, 1]]]))
    gb.write("normal", np.float32([[[0, 1, 0, 0], [0, 1, 0, 0]]]))
    gb.write("albedo", np.float32([[[0.5, 0.5, 0.5, 0.5]] * 2]))
    gb.write("material", np.float32([[[20, 0.3, 0, 0], material]]))
    gb.write("instance", np.uint32([[0, 0]]))
    return gb


def test_gbuffer_validation_knows_the_lobe(ctx):
    _gbuffer_with_material(ctx, [20.0, 500.0, 3.0, 2.5]).validate()  # n_v > 1 is fine for this lobe
    for bad, field in (([20.0, 500.0, 3.0, np.nan], "tangent angle"), ([20.0, -1.0, 3.0, 0.0], "n_v"),
                       ([20.0, 500.0, 2.0, 0.0], "roughness"), ([20.0, 0.3, 4.0, 0.0], "lobe")):
        with pytest.raises(InputError, match=field):
            _gbuffer_with_material(ctx, bad).validate()


# --------------------------------------------------------------------------- reference vs float64


def test_reference_matches_float64_with_the_lobe(ctx, aniso_scene):
    s = aniso_scene
    got = shade(ctx, s["scene"], s["gb"], face_size=8)[..., :3]
    lo, hi = reference64(s["planes"], s["camera"], s["env"], s["tris"])
    fg = s["planes"]["instance"] != BACKGROUND
    scale = np.maximum(hi, 1e-3)
    ok = (got >= lo - REFERENCE_RTOL * scale) & (got <= hi + REFERENCE_RTOL * scale)
    assert ok[fg].all(), f"{(~ok[fg]).sum()} values outside the float64 bounds"
    # The tangent matters: the same scene with the exponents swapped differs.
    mat = s["planes"]["material"].copy()
    aniso = mat[..., 2] == AS_INDEX
    mat[aniso, 0], mat[aniso, 1] = mat[aniso, 1].copy(), mat[aniso, 0].copy()
    s["gb"].write("material", mat)
    try:
        swapped = shade(ctx, s["scene"], s["gb"], face_size=8)[..., :3]
    finally:
        s["gb"].write("material", s["planes"]["material"])
    assert np.abs(swapped - got)[aniso].max() > 0.05 * got[aniso].max()


# --------------------------------------------------------------------------- white furnace


def directional_albedo(n_u, n_v, theta_v, phi_v=0.3, nodes=400):
    """int f_lobe(V, L) (N.L) dL over the hemisphere for N = +z, u = +x, by a
    product rule in (cos theta, phi) graded towards the mirror direction."""
    n = np.array([0.0, 0.0, 1.0])
    v = np.array([np.sin(theta_v) * np.cos(phi_v), np.sin(theta_v) * np.sin(phi_v), np.cos(theta_v)])
    # Gauss-Legendre in mu = cos theta_l on [0, 1] and in phi on [0, 2 pi], split into panels.
    x, w = np.polynomial.legendre.leggauss(16)
    mu_edges = np.linspace(0.0, 1.0, nodes // 16 + 1)
    phi_edges = np.linspace(0.0, 2 * np.pi, 2 * nodes // 16 + 1)

    def rule(edges):
        a, b = edges[:-1, None], edges[1:, None]
        return ((a + b) / 2 + (b - a) / 2 * x).ravel(), ((b - a) / 2 * w).ravel()

    mu, wmu = rule(mu_edges)
    ph, wph = rule(phi_edges)
    st = np.sqrt(1 - mu ** 2)
    l = np.stack([st[:, None] * np.cos(ph), st[:, None] * np.sin(ph), np.broadcast_to(mu[:, None], (len(mu), len(ph)))],
                 axis=-1)
    f = ashikhmin_shirley(n, v, l, np.array([1.0, 0.0, 0.0]), n_u, n_v)
    return float(np.sum(f * mu[:, None] * wmu[:, None] * wph[None, :]))


def test_quadrature_converges():
    a, b = directional_albedo(10.0, 100.0, 0.6, nodes=400), directional_albedo(10.0, 100.0, 0.6, nodes=800)
    assert abs(a - b) < 1e-4 * b


@pytest.mark.parametrize("n_u,n_v", [(1.0, 1.0), (10.0, 50.0), (50.0, 10.0)])
def test_white_furnace_matches_quadrature(ctx, n_u, n_v):
    """A lone plane under a white env (radiance 1), k_s = 1, no albedo: each
    pixel is the lobe's directional albedo at its view angle. The reference
    (cube texels, face size 64) agrees with numpy quadrature of the float64
    lobe to the texel discretisation (< 1%; a lobe of the wrong width or
    normalisation, or a tangent turned by 90 degrees, is off by > 5%)."""
    env = EnvMap(ctx, np.ones((64, 128, 3), np.float32), face_size=64)
    camera = Camera(position=(0.0, 1.2, 2.0), look_at=(0.0, 0.0, 0.0), fov_deg=60.0, resolution=(9, 7))
    mat = Material(albedo=(0.0, 0.0, 0.0), specular=1.0, shininess=n_u, shininess_v=n_v, lobe=AS,
                   tangent=(1.0, 0.0, 0.0))
    scene, tris, keep = make_scene(ctx, [(procedural.plane((40.0, 40.0)), xform(), mat)], env, camera)
    gb, planes = gbuffer_of(ctx, scene, camera)
    got = shade(ctx, scene, gb, face_size=64, visibility=0)[..., 0]
    cam = np.asarray(camera.position, np.float64)
    checked = 0
    for y, x in [(0, 0), (3, 4), (6, 8), (6, 0), (2, 7)]:
        assert planes["instance"][y, x] != BACKGROUND
        p = planes["position"][y, x, :3].astype(np.float64)
        vw = unit(cam - p)  # world: plane normal +y, tangent +x, w = n x u = -z
        theta = np.arccos(vw[1])
        phi = np.arctan2(-vw[2], vw[0])
        want = directional_albedo(n_u, n_v, theta, phi)
        assert got[y, x] == pytest.approx(want, rel=0.01), (y, x, theta, phi)
        checked += 1
    assert checked == 5


# --------------------------------------------------------------------------- depthmap with the lobe


@pytest.mark.parametrize("specular", [0, 2])
def test_depthmap_shades_the_lobe_like_float64(ctx, specular):
    """`depthmap` evaluates the lobe through pn_brdf_lobe (point or cap quadrature,
    every cap sampled: the anisotropic lobe is never culled by its distance to R)."""
    import depthmap64 as d64
    from test_depthmap import domains_of, render as dm_render
    from tolerances import DEPTHMAP_DEPTH_ATOL, DEPTHMAP_SHADE_RTOL

    sky = procedural.sky(64, 32)
    env = EnvMap(ctx, sky, face_size=16)
    objects = [
        (procedural.plane((4.0, 4.0)), xform(),
         _as_material(shininess=5.0, shininess_v=300.0, tangent=(1.0, 0.0, 1.0))),
        (procedural.box((0.8, 0.8, 0.8)), xform(rotation((0, 1, 0), 0.5), (0.0, 0.4, 0.0)), _as_material()),
    ]
    camera = Camera(position=(1.5, 2.5, 4.0), look_at=(0.0, 0.3, 0.0), fov_deg=50.0, resolution=(24, 18))
    scene, tris, keep = make_scene(ctx, objects, env, camera)
    gb, planes = gbuffer_of(ctx, scene, camera)
    domains = domains_of(sky, 16)
    got, r = dm_render(ctx, scene, gb, domains, resolution=64, specular=specular)
    frames = r.read_output(scene, "map_frames", 0).astype(np.float64)
    maps = np.stack([r.read_output(scene, "depth_map", 0, i) for i in range(len(domains))]).astype(np.float64)
    lo, hi = d64.shade(planes, camera.position, domains, frames, maps,
                       margin=DEPTHMAP_DEPTH_ATOL * frames[:, 14].max(), bias=1.0, slope_bias=1.0, pcf=0,
                       specular=specular, cap_samples=16, receiver_plane=1)
    fg = planes["instance"] != BACKGROUND
    scale = np.maximum(hi, 1e-3)
    got = got[..., :3]
    ok = (got >= lo - DEPTHMAP_SHADE_RTOL * scale) & (got <= hi + DEPTHMAP_SHADE_RTOL * scale)
    assert ok[fg].all(), f"{(~ok[fg]).sum()} values off"


# --------------------------------------------------------------------------- scene files


def test_scene_file_keys_of_the_lobe():
    from penumbra.scenefile import parse_scene
    base = {"name": "pot", "primitive": "sphere", "specular": 0.5, "lobe": AS, "shininess": 8.0}
    desc = parse_scene({"object": [dict(base, shininess_v=120.0, tangent=[0.0, 2.0, 0.0])]})
    o = desc.objects[0]
    assert (o.lobe, o.shininess, o.shininess_v, o.tangent) == (AS, 8.0, 120.0, (0.0, 2.0, 0.0))
    assert parse_scene({"object": [base]}).objects[0].tangent == (1.0, 0.0, 0.0)
    with pytest.raises(InputError, match="tangent.*must not be zero"):
        parse_scene({"object": [dict(base, tangent=[0, 0, 0])]})
    with pytest.raises(InputError, match="shininess_v"):
        parse_scene({"object": [dict(base, shininess_v=-2.0)]})
