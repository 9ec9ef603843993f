"""G-buffers: primary rays from the scene's camera against a float64 numpy
ray cast with the same camera model; G-buffers built by the caller (the
embedding path) shaded by the "unshadowed" renderer against a float64
irradiance integral; pyopencl-owned planes and images; validation and sizes.

Tolerances (one place):
  POS_RTOL     depth and position, relative to the depth.
  DIR_ATOL     background view directions (unit vectors, float32 normalize).
  NORMAL_ATOL  normals (unit vectors; the library transforms with a float32
               inverse and interpolates in float32).
  SILHOUETTE   fraction of pixels whose instance may differ (rays within
               float rounding of a silhouette edge).
  E_GRID_RTOL  irradiance at the directions of the irradiance map's own
               vertex grid, where the bilinear lookup is exact (float32 sums
               over 6*64*64 texels: ~1e-6 relative).
  E_BILINEAR   irradiance anywhere else, relative to max E: the library
               interpolates E bilinearly between vertex-grid samples
               (irradiance_face_size M = 32). Measured against the exact
               float64 integral at 20000 random normals for the smooth sky
               used here (procedural.sky without its sun, 128x64 lat-long,
               face_size 64): max error 4.9e-4 of max E (99th percentile
               3.7e-4). For comparison, M = 16 gives 2.2e-3 (the error goes as
               1/M^2) and the default sun (1e4 x sky, a kink of max(0, n.s) at
               the terminator) 5e-3 at M = 32. 1e-3 leaves a 2x margin on the
               measured maximum and still fails for a grid half as fine or any
               misaddressed lookup (errors of 10% and more).
"""

from __future__ import annotations

import numpy as np
import pyopencl.array as cla
import pytest

from penumbra import (BACKGROUND, Camera, EnvMap, GBuffer, Image, InputError, Material, Mesh, Renderer, Scene,
                      procedural)
from penumbra import _native
from envmap64 import background64
from geometry64 import affine, camera_rays, cast, f32, rotation, unit
from tolerances import BACKGROUND_ATOL

POS_RTOL = 1e-4
DIR_ATOL = 1e-5
NORMAL_ATOL = 1e-3
SILHOUETTE = 0.01
E_GRID_RTOL = 1e-4
E_BILINEAR = 1e-3

LOBE_VALUE = {"phong": 0.0, "blinn_phong": 1.0, "ggx": 2.0}


# --------------------------------------------------------------------------- (a) scene G-buffer


@pytest.fixture(scope="module")
def gb_scene(ctx):
    sphere = procedural.sphere(1.0, 2)      # coarse: interpolated and geometric normals differ visibly
    box = procedural.box((1.0, 1.0, 1.0))
    plane = procedural.plane((8.0, 8.0), 2)
    meshes = {
        "sphere": (sphere, True),    # with vertex normals (interpolated)
        "box": (box, False),         # without: the geometric normal
        "plane": (plane, True),
    }
    handles = {k: Mesh(ctx, m.vertices, m.faces, m.normals if use else None) for k, (m, use) in meshes.items()}
    mirror = np.diag([-1.0, 1.0, 1.0])
    instances = [
        ("sphere", affine(mirror @ rotation([0, 1, 0], 0.3) @ np.diag([0.7, 0.9, 0.7]), [-1.2, 0.9, 0.0]),
         Material(albedo=(0.9, 0.2, 0.1), specular=0.3, shininess=50.0, roughness=0.3, lobe="phong")),
        ("box", affine(rotation([0, 1, 0], 0.6) @ rotation([1, 0, 0], 0.2) @ np.diag([1.2, 0.8, 1.0]),
                       [1.4, 0.45, 0.3]),
         Material(albedo=(0.1, 0.7, 0.3), specular=0.5, shininess=20.0, roughness=0.6, lobe="ggx")),
        ("plane", affine(np.eye(3), [0.0, -0.05, 0.0]),
         Material(albedo=(0.5, 0.45, 0.4), specular=0.0, shininess=100.0, roughness=1.0, lobe="blinn_phong")),
    ]
    scene = Scene(ctx)
    placed = {}
    for name, m, mat in instances:
        placed[scene.add(handles[name], m, mat)] = (name, m, mat)
    camera = Camera(position=(0.0, 2.2, 6.0), look_at=(0.0, 0.4, 0.0), up=(0.0, 1.0, 0.0), fov_deg=55.0,
                    resolution=(48, 36))
    scene.set_camera(camera)
    scene.commit()
    return {"scene": scene, "camera": camera, "placed": placed, "meshes": meshes}


@pytest.fixture(scope="module")
def gb_reference(gb_scene):
    """Per-pixel float64 reference: instance, t, position, normal, albedo/material planes, near-edge flag."""
    cam = gb_scene["camera"]
    w, h = cam.resolution
    origin, dirs = camera_rays(cam)
    dirs = dirs.reshape(-1, 3)
    v0s, v1s, v2s, n0s, n1s, n2s, ng, inst_of, has_n = [], [], [], [], [], [], [], [], []
    for iid, (name, m, _) in gb_scene["placed"].items():
        mesh, use_normals = gb_scene["meshes"][name]
        m = f32(m)
        lin, tr = m[:, :3], m[:, 3]
        inv_t = np.linalg.inv(lin).T  # normals transform by the inverse transpose
        vw = (f32(mesh.vertices) @ lin.T + tr)[mesh.faces.astype(np.int64)]
        vo = f32(mesh.vertices)[mesh.faces.astype(np.int64)]
        v0s.append(vw[:, 0]), v1s.append(vw[:, 1]), v2s.append(vw[:, 2])
        ng.append(np.cross(vo[:, 1] - vo[:, 0], vo[:, 2] - vo[:, 0]) @ inv_t.T)
        nrm = f32(mesh.normals)[mesh.faces.astype(np.int64)] @ inv_t.T if use_normals else np.zeros_like(vo)
        n0s.append(nrm[:, 0]), n1s.append(nrm[:, 1]), n2s.append(nrm[:, 2])
        inst_of.append(np.full(len(vw), iid))
        has_n.append(np.full(len(vw), use_normals))
    cat = np.concatenate
    t, tri, u, v, near = cast(origin, dirs, cat(v0s), cat(v1s), cat(v2s))
    hit = tri >= 0
    k = np.maximum(tri, 0)
    inst = np.where(hit, cat(inst_of)[k], BACKGROUND).astype(np.int64)
    g = unit(cat(ng)[k])
    s = (1 - u - v)[:, None] * cat(n0s)[k] + u[:, None] * cat(n1s)[k] + v[:, None] * cat(n2s)[k]
    with np.errstate(invalid="ignore", divide="ignore"):
        s = np.where((cat(has_n)[k] & (np.einsum("ij,ij->i", s, g) > 0))[:, None], unit(s), g)
    flip = np.einsum("ij,ij->i", g, dirs) > 0
    g[flip] *= -1
    s[flip] *= -1
    # A shading normal still facing away (silhouettes of coarse smooth meshes)
    # falls back to the geometric one: the G-buffer promises camera-facing normals.
    away = np.einsum("ij,ij->i", s, dirs) > 0
    s[away] = g[away]
    albedo = np.zeros((len(dirs), 4))
    material = np.zeros((len(dirs), 4))
    for iid, (_, _, mat) in gb_scene["placed"].items():
        sel = inst == iid
        albedo[sel] = [*f32(mat.albedo), f32(mat.specular)]
        material[sel] = [f32(mat.shininess), f32(mat.roughness), LOBE_VALUE[mat.lobe], 0.0]
    shape = (h, w)
    return {"inst": inst.reshape(shape), "t": t.reshape(shape), "dirs": dirs.reshape(h, w, 3),
            "pos": (origin + t[:, None] * dirs).reshape(h, w, 3), "normal": s.reshape(h, w, 3),
            "albedo": albedo.reshape(h, w, 4), "material": material.reshape(h, w, 4), "near": near.reshape(shape),
            "origin": origin}


@pytest.fixture(scope="module")
def gb_planes(ctx, gb_scene):
    w, h = gb_scene["camera"].resolution
    gb = GBuffer(ctx, w, h)
    gb_scene["scene"].render_gbuffer(gb)
    return {p: gb.read(p) for p in _native.GBUFFER_PLANES}


def test_gbuffer_instances(gb_scene, gb_reference, gb_planes):
    ref, inst = gb_reference, gb_planes["instance"].astype(np.int64)
    differ = inst != ref["inst"]
    assert differ.mean() <= SILHOUETTE, f"{differ.sum()} of {differ.size} pixels see another instance"
    # The scene must really exercise every instance and the background.
    for iid in list(gb_scene["placed"]) + [BACKGROUND]:
        assert (ref["inst"] == iid).sum() >= 40, f"instance {iid} covers too few pixels for a meaningful test"
        assert (inst == iid).sum() >= 40


def test_gbuffer_positions(gb_reference, gb_planes):
    ref, pos = gb_reference, gb_planes["position"].astype(np.float64)
    fg = (gb_planes["instance"].astype(np.int64) == ref["inst"]) & (ref["inst"] != BACKGROUND)
    pos, t, ref_pos = pos[fg], ref["t"][fg], ref["pos"][fg]
    depth_err = np.abs(pos[:, 3] - t) / t
    assert depth_err.max() < POS_RTOL, f"max relative depth error {depth_err.max():.3g}"
    xyz_err = np.linalg.norm(pos[:, :3] - ref_pos, axis=-1) / t
    assert xyz_err.max() < POS_RTOL, f"max position error {xyz_err.max():.3g} of the depth"
    # Position w is the distance from the camera: |xyz - camera| = w.
    dist = np.linalg.norm(pos[:, :3] - ref["origin"], axis=-1)
    assert (np.abs(dist - pos[:, 3]) / pos[:, 3]).max() < POS_RTOL


def test_gbuffer_normals(gb_reference, gb_planes):
    ref = gb_reference
    n = gb_planes["normal"].astype(np.float64)
    lib_fg = gb_planes["instance"] != BACKGROUND
    # Unit length, w = 0, and facing the camera on every foreground pixel.
    assert np.abs(np.linalg.norm(n[..., :3], axis=-1)[lib_fg] - 1.0).max() < 1e-5
    assert np.all(n[..., 3][lib_fg] == 0.0)
    facing = np.einsum("hwk,hwk->hw", n[..., :3], ref["dirs"])
    assert facing[lib_fg].max() <= 0.0, f"{(facing[lib_fg] > 0).sum()} normals face away from the camera"
    # Equal to the reference normal (geometric for the box, interpolated for
    # the sphere and plane) where the pixel's triangle is unambiguous.
    same = (gb_planes["instance"].astype(np.int64) == ref["inst"]) & (ref["inst"] != BACKGROUND) & ~ref["near"]
    assert (~ref["near"]).mean() > 0.99
    err = np.linalg.norm(n[..., :3] - ref["normal"], axis=-1)
    assert err[same].max() < NORMAL_ATOL, f"max normal error {err[same].max():.3g}"


def test_gbuffer_interpolated_normals_are_not_geometric(gb_scene, gb_reference, gb_planes):
    """Guard on the scene: the sphere's shading normals differ from its facets'
    (else the normal test could not tell interpolation from facets)."""
    sphere_id = next(i for i, (name, _, _) in gb_scene["placed"].items() if name == "sphere")
    on_sphere = (gb_planes["instance"] == sphere_id) & ~gb_reference["near"]
    n = gb_planes["normal"][..., :3].astype(np.float64)
    # Facet normals of a 320-triangle sphere are constant per triangle; the
    # interpolated ones vary within it: neighbouring pixels on the same facet differ.
    dx = np.linalg.norm(n[:, 1:] - n[:, :-1], axis=-1)[on_sphere[:, 1:] & on_sphere[:, :-1]]
    assert np.median(dx) > 1e-3


def test_gbuffer_material_planes(gb_reference, gb_planes):
    ref = gb_reference
    same = (gb_planes["instance"].astype(np.int64) == ref["inst"]) & (ref["inst"] != BACKGROUND)
    np.testing.assert_array_equal(gb_planes["albedo"][same], ref["albedo"][same].astype(np.float32))
    np.testing.assert_array_equal(gb_planes["material"][same], ref["material"][same].astype(np.float32))


def test_gbuffer_background(gb_reference, gb_planes):
    ref = gb_reference
    bg = gb_planes["instance"] == BACKGROUND
    pos = gb_planes["position"]
    assert np.all(np.isposinf(pos[..., 3][bg]))
    assert np.all(np.isfinite(pos[..., 3][~bg]))
    err = np.abs(pos[..., :3].astype(np.float64) - ref["dirs"]).max(axis=-1)
    assert err[bg].max() < DIR_ATOL, f"background direction error {err[bg].max():.3g}"
    assert np.abs(np.linalg.norm(pos[..., :3].astype(np.float64), axis=-1)[bg] - 1).max() < DIR_ATOL


# --------------------------------------------------------------------------- (b) embedding path


def cube_to_dir(face, a, b) -> np.ndarray:
    """Unnormalised direction of face coordinates (kernels/common/sphere_maps.cl)."""
    one = np.ones_like(a)
    table = [(one, -b, -a), (-one, -b, a), (a, one, b), (a, -one, -b), (a, -b, one), (-a, -b, -one)]
    return np.stack(table[face], axis=-1)


def exact_irradiance(env: EnvMap, normals: np.ndarray, chunk=256) -> np.ndarray:
    """E(n) = sum_k L_k max(0, n . w_k) dw_k over the env's own cube texels, float64."""
    L = env.cube_radiance().reshape(-1, 3).astype(np.float64)
    d, dw = env.cube_directions()
    w = d.reshape(-1, 3).astype(np.float64)
    Lw = L * dw.reshape(-1, 1).astype(np.float64)
    out = np.empty((len(normals), 3))
    for s in range(0, len(normals), chunk):
        out[s:s + chunk] = np.maximum(normals[s:s + chunk] @ w.T, 0.0) @ Lw
    return out


@pytest.fixture(scope="module")
def smooth_env(ctx):
    latlong = procedural.sky(128, 64, sun_radiance=0.0)
    env = EnvMap(ctx, latlong, face_size=64, irradiance_face_size=32)
    env.latlong_rgb = latlong  # kept for the float64 background lookup
    return env


def grid_directions(m: int, rng, count: int) -> np.ndarray:
    face = rng.integers(0, 6, count)
    i, j = rng.integers(0, m, count), rng.integers(0, m, count)
    a, b = -1.0 + 2.0 * i / (m - 1), -1.0 + 2.0 * j / (m - 1)
    return unit(np.stack([cube_to_dir(f, np.array(x), np.array(y)) for f, x, y in zip(face, a, b)]))


@pytest.fixture(scope="module")
def embedded(ctx, smooth_env):
    """A caller-built G-buffer (32 x 24): random unit normals, some exactly at
    irradiance grid directions, random albedo, ~20% background pixels looking
    at cube texel centres."""
    rng = np.random.default_rng(17)
    w, h = 32, 24
    n = w * h
    m = smooth_env.get("irradiance_face_size")
    normals = unit(rng.normal(size=(n, 3)))
    on_grid = rng.random(n) < 0.3
    normals[on_grid] = grid_directions(m, rng, on_grid.sum())
    normals = f32(normals)
    background = rng.random(n) < 0.2
    on_grid &= ~background
    texel_dirs, _ = smooth_env.cube_directions()
    texel_index = rng.integers(0, texel_dirs.reshape(-1, 3).shape[0], n)
    position = np.empty((n, 4), np.float32)
    position[:, :3] = rng.normal(scale=3.0, size=(n, 3))
    position[:, 3] = np.linalg.norm(position[:, :3], axis=1)
    position[background, :3] = texel_dirs.reshape(-1, 3)[texel_index[background]]
    position[background, 3] = np.inf
    normal = np.zeros((n, 4), np.float32)
    normal[:, :3] = normals
    albedo = np.zeros((n, 4), np.float32)
    albedo[:, :3] = rng.uniform(0.05, 1.0, size=(n, 3))
    material = np.tile(np.array([10.0, 0.5, 0.0, 0.0], np.float32), (n, 1))
    instance = rng.integers(0, 7, n).astype(np.uint32)
    instance[background] = BACKGROUND
    planes = {"position": position, "normal": normal, "albedo": albedo, "material": material, "instance": instance}
    planes = {k: v.reshape((h, w) + v.shape[1:]) for k, v in planes.items()}
    gb = GBuffer(ctx, w, h)
    for k, v in planes.items():
        gb.write(k, v)
    gb.validate()
    scene = Scene(ctx)
    scene.set_envmap(smooth_env)
    scene.commit()
    return {"gb": gb, "scene": scene, "planes": planes, "w": w, "h": h, "on_grid": on_grid.reshape(h, w),
            "background": background.reshape(h, w), "texel_index": texel_index.reshape(h, w)}


def render(ctx, scene, gb, **params) -> np.ndarray:
    image = Image(ctx, gb.width, gb.height)
    Renderer(ctx, "unshadowed", **params).execute(scene, gb, image)
    return image.read()


def test_embedded_gbuffer_roundtrip(embedded):
    for name, data in embedded["planes"].items():
        np.testing.assert_array_equal(embedded["gb"].read(name), data)


def test_unshadowed_on_embedded_gbuffer(ctx, smooth_env, embedded):
    img = render(ctx, embedded["scene"], embedded["gb"]).astype(np.float64)
    p = embedded["planes"]
    fg = ~embedded["background"]
    n = f32(p["normal"][..., :3])[fg]
    E = exact_irradiance(smooth_env, unit(n))
    expect = f32(p["albedo"][..., :3])[fg] * E / np.pi
    got = img[..., :3][fg]
    assert np.all(img[..., 3][fg] == 1.0)
    scale = E.max() * f32(p["albedo"][..., :3])[fg].max() / np.pi
    err = np.abs(got - expect).max(axis=1) / scale
    assert err.max() < E_BILINEAR, f"max error {err.max():.3g} of max radiance (bilinear lookup of E)"
    # At the irradiance map's own grid directions the lookup is exact.
    grid = embedded["on_grid"][fg]
    assert grid.sum() > 50
    rel = np.abs(got[grid] - expect[grid]) / expect[grid]
    assert rel.max() < E_GRID_RTOL, f"max relative error {rel.max():.3g} at grid directions"


def test_unshadowed_background(ctx, smooth_env, embedded):
    """Background pixels show the full-resolution env map in their view
    direction (bilinear lat-long lookup, float64 twin), not the cube map."""
    bg = embedded["background"]
    img = render(ctx, embedded["scene"], embedded["gb"])
    view = embedded["planes"]["position"][..., :3][bg].astype(np.float64)
    expect = background64(smooth_env.latlong_rgb, view)
    scale = smooth_env.latlong_rgb.max()
    err = np.abs(img[..., :3][bg] - expect).max() / scale
    assert err < BACKGROUND_ATOL, f"background differs from the bilinear lat-long lookup by {err:.3g} of the max"
    assert np.all(img[..., 3][bg] == 0.0)
    black = render(ctx, embedded["scene"], embedded["gb"], background=0)
    assert np.all(black[bg] == 0.0)
    np.testing.assert_array_equal(black[~bg], img[~bg])


# --------------------------------------------------------------------------- (c) pyopencl interop


def test_gbuffer_into_pyopencl_planes(ctx, cl_pair, gb_scene, gb_planes, smooth_env):
    cl_ctx, queue = cl_pair
    w, h = gb_scene["camera"].resolution
    arrays = {p: cla.empty(queue, (h, w, 4), np.float32) for p in ("position", "normal", "albedo", "material")}
    arrays["instance"] = cla.empty(queue, (h, w), np.uint32)
    for a in arrays.values():
        a.fill(7)  # stale contents that the G-buffer must overwrite
    gb = GBuffer(ctx, w, h, planes=arrays)
    gb_scene["scene"].render_gbuffer(gb)
    for p, a in arrays.items():
        np.testing.assert_array_equal(a.get(), gb_planes[p], err_msg=f"plane {p}")
        np.testing.assert_array_equal(gb.read(p), gb_planes[p], err_msg=f"plane {p} via GBuffer.read")

    # Shade into an image that wraps a pyopencl array; compare with a library-owned image.
    scene = Scene(ctx)
    scene.set_envmap(smooth_env)
    scene.commit()
    out = cla.empty(queue, (h, w, 4), np.float32)
    out.fill(-1.0)
    image = Image(ctx, w, h, buffer=out)
    renderer = Renderer(ctx, "unshadowed")
    renderer.execute(scene, gb, image)
    own = Image(ctx, w, h)
    renderer.execute(scene, gb, own)
    got = out.get()
    np.testing.assert_array_equal(got, own.read())
    np.testing.assert_array_equal(got, image.read())
    fg = gb_planes["instance"] != BACKGROUND
    assert np.all(got[..., 3][fg] == 1.0) and np.all(got[..., 3][~fg] == 0.0)
    assert np.all(got[..., :3] >= 0.0) and got[..., :3][fg].max() > 0.0


def test_pyopencl_planes_too_small_rejected(ctx, cl_pair):
    _, queue = cl_pair
    w, h = 16, 8
    arrays = {p: cla.empty(queue, (h, w, 4), np.float32) for p in ("position", "normal", "albedo", "material")}
    arrays["instance"] = cla.empty(queue, (h, w - 1), np.uint32)
    with pytest.raises(InputError):
        GBuffer(ctx, w, h, planes=arrays)


# --------------------------------------------------------------------------- (d) validation


def valid_planes(w, h, rng):
    n = w * h
    pos = np.zeros((n, 4), np.float32)
    pos[:, :3] = rng.normal(size=(n, 3))
    pos[:, 3] = 1.0
    nrm = np.zeros((n, 4), np.float32)
    nrm[:, :3] = unit(rng.normal(size=(n, 3)))
    inst = np.zeros(n, np.uint32)
    inst[::5] = BACKGROUND
    pos[::5, :3] = unit(rng.normal(size=(len(pos[::5]), 3)))
    pos[::5, 3] = np.inf
    return {"position": pos.reshape(h, w, 4), "normal": nrm.reshape(h, w, 4), "instance": inst.reshape(h, w),
            "albedo": np.full((h, w, 4), 0.5, np.float32), "material": np.zeros((h, w, 4), np.float32)}


@pytest.mark.parametrize("defect", ["nan_normal", "inf_position", "zero_normal", "nan_position"])
def test_validate_names_first_bad_pixel(ctx, defect):
    w, h = 20, 12
    planes = valid_planes(w, h, np.random.default_rng(4))
    gb = GBuffer(ctx, w, h)
    for k, v in planes.items():
        gb.write(k, v)
    gb.validate()
    # Two bad foreground pixels: (x=7, y=3) and a later one (x=2, y=9).
    for x, y in ((7, 3), (2, 9)):
        assert planes["instance"][y, x] != BACKGROUND
        if defect == "nan_normal":
            planes["normal"][y, x, 1] = np.nan
        elif defect == "inf_position":
            planes["position"][y, x, 0] = np.inf
        elif defect == "zero_normal":
            planes["normal"][y, x, :3] = 0.0
        else:
            planes["position"][y, x, 2] = np.nan
    gb.write("normal", planes["normal"])
    gb.write("position", planes["position"])
    with pytest.raises(InputError, match=r"\(x=7, y=3\)") as info:
        gb.validate()
    assert "2 foreground pixels" in str(info.value)


def test_validate_accepts_nan_on_background(ctx):
    w, h = 20, 12
    planes = valid_planes(w, h, np.random.default_rng(5))
    bg = planes["instance"] == BACKGROUND
    planes["normal"][bg] = np.nan
    planes["albedo"][bg] = np.nan
    gb = GBuffer(ctx, w, h)
    for k, v in planes.items():
        gb.write(k, v)
    gb.validate()
    # The same NaN on one foreground pixel is refused.
    y, x = np.argwhere(~bg)[-1]
    planes["normal"][y, x] = np.nan
    gb.write("normal", planes["normal"])
    with pytest.raises(InputError, match=rf"\(x={x}, y={y}\)"):
        gb.validate()


# --------------------------------------------------------------------------- (e) sizes


def test_write_wrong_shape_raises(ctx):
    w, h = 10, 6
    gb = GBuffer(ctx, w, h)
    for plane, shape in (("position", (h, w, 3)), ("normal", (w, h, 4)), ("instance", (h, w, 1)),
                         ("albedo", (h * w, 4)), ("material", (h, w + 1, 4)), ("instance", (h + 1, w))):
        with pytest.raises(InputError):
            gb.write(plane, np.zeros(shape))
    # The C API checks the byte count itself (the Python shape check aside).
    data = np.zeros((h, w, 4), np.float32)
    with pytest.raises(InputError, match="bytes"):
        _native.call("pn_gbuffer_write", ctx.handle, gb.handle, 0, data.ctypes.data, data.nbytes - 16)
    with pytest.raises(InputError, match="bytes"):
        _native.call("pn_gbuffer_read", ctx.handle, gb.handle, 4, data.ctypes.data, data.nbytes)


def test_unknown_plane_name_raises_input_error(ctx):
    gb = GBuffer(ctx, 4, 4)
    with pytest.raises(InputError, match="unknown G-buffer plane"):
        gb.write("depth", np.zeros((4, 4, 4)))
    with pytest.raises(InputError, match="unknown G-buffer plane"):
        gb.read("depth")


def test_render_gbuffer_size_mismatch_raises(ctx, gb_scene, smooth_env):
    w, h = gb_scene["camera"].resolution
    for size in ((w + 1, h), (w, h - 1), (h, w)):
        gb = GBuffer(ctx, *size)
        with pytest.raises(InputError, match=f"{w}x{h}"):
            gb_scene["scene"].render_gbuffer(gb)
    # Shading: the image must have the G-buffer's size.
    scene = Scene(ctx)
    scene.set_envmap(smooth_env)
    scene.commit()
    gb = GBuffer(ctx, w, h)
    gb_scene["scene"].render_gbuffer(gb)
    with pytest.raises(InputError):
        Renderer(ctx, "unshadowed").execute(scene, gb, Image(ctx, w, h + 1))


@pytest.mark.parametrize("defect", ["nan_position", "inf_position", "nan_normal"])
def test_unvalidated_bad_pixels_do_not_crash_any_method(ctx, defect):
    """A caller's G-buffer is checked only by validate(): a NaN or Inf in it
    must still not crash a method. The reference once traced rays from a NaN
    position straight into a stack overflow (the slab tests entered empty child
    slots); pn_trace now makes such a ray miss. The bad pixel's value is
    unspecified; every other pixel must be the one of the clean G-buffer."""
    scene = Scene(ctx)
    scene.set_envmap(EnvMap(ctx, np.ones((16, 32, 3), np.float32), face_size=4))
    plane, box = procedural.plane((8.0, 8.0)), procedural.box()
    keep = [Mesh(ctx, plane.vertices, plane.faces), Mesh(ctx, box.vertices, box.faces)]
    scene.add(keep[0], None, Material(albedo=(0.5, 0.5, 0.5)))
    scene.add(keep[1], np.float32([[1, 0, 0, 0], [0, 1, 0, 1], [0, 0, 1, 0]]), Material(albedo=(0.5, 0.5, 0.5)))
    scene.set_camera(Camera(position=(0.0, 6.0, 0.01), look_at=(0.0, 0.0, 0.0), fov_deg=30.0, resolution=(9, 9)))
    scene.commit()
    gb = GBuffer(ctx, 9, 9)
    scene.render_gbuffer(gb)
    planes = {p: gb.read(p) for p in ("position", "normal")}
    assert planes["normal"].shape[:2] == (9, 9)
    methods = ("reference", "depthmap", "fiv", "isg", "unshadowed")
    clean = {}
    for m in methods:
        img = Image(ctx, 9, 9)
        Renderer(ctx, m).execute(scene, gb, img)
        clean[m] = img.read()
    plane_name, channel, value = {"nan_position": ("position", 0, np.nan), "inf_position": ("position", 1, np.inf),
                                  "nan_normal": ("normal", 1, np.nan)}[defect]
    bad = planes[plane_name].copy()
    bad[4, 4, channel] = value
    gb.write(plane_name, bad)
    with pytest.raises(InputError, match=r"\(x=4, y=4\)"):
        gb.validate()
    others = np.ones((9, 9), bool)
    others[4, 4] = False
    for m in methods:
        img = Image(ctx, 9, 9)
        Renderer(ctx, m).execute(scene, gb, img)
        np.testing.assert_array_equal(img.read()[others], clean[m][others], err_msg=f"{m}, {defect}")
