"""The isg shading kernel (kernels/isg.cl) against its float64 twin
(tests/isg_shading64.py), and the twin against the exact visible integral
(dense quadrature with exact ray-sphere tests).

Hard cases: a receiver inside a sphere, a sphere straddling the receiver
plane, grazing normals, overlapping spheres (a patch occluded once), the
self-occlusion policies, a lobe below the horizon, K = 1, no spheres, a
black env, k_s = 0 and a sharp Phong lobe (glossiness 1000). Small pixel
counts: the kernel is called directly with pyopencl.
"""

from __future__ import annotations

import functools
import math

import numpy as np
import pyopencl as cl
import pytest
from isg64 import isg_table, sg_cosine_exact
from isg_shading64 import (COS_AMPLITUDE, COS_SHARPNESS, LOBE_CUBE_N, build_gamma, cube_directions, lobe_cube,
                           grid_lookup, sg_product, shade, shared_occluded, sky_cube, visibility, visible_exact)
from tolerances import ISG_SHADE_ATOL, ISG_SHADE_RTOL, ISG_VISIBILITY_GRID_ATOL, ISG_VISIBILITY_PATCH_ATOL

from penumbra._native import call
from penumbra.methods.isg import gamma_levels, sphere_tree

BACKGROUND = 0xFFFFFFFF
SOURCE = '#include "isg.cl"\n'


def table32() -> np.ndarray:
    """The library's ISG table (pn_isg_table), as the method uploads it."""
    t = isg_table()
    out = np.empty(4 * t.front_theta.size, np.float32)
    call("pn_isg_table", None, out.ctypes.data, out.size)
    return out


def unit(v):
    v = np.asarray(v, np.float64)
    return v / np.linalg.norm(v)


def lobe(axis, lam, rgb):
    return [*unit(axis), lam, *rgb]


LOBES = np.array([lobe([0.3, 1.0, 0.2], 300.0, [20.0, 18.0, 15.0]),   # a sun
                  lobe([0.0, 1.0, 0.0], 1.5, [0.8, 0.9, 1.2]),        # the sky
                  lobe([-1.0, 0.4, 0.5], 12.0, [1.0, 0.6, 0.3]),      # a bright region low on the horizon
                  lobe([0.5, -0.6, 0.1], 5.0, [0.5, 0.5, 0.5])])      # a lobe below the horizon


FACES = np.array([[1.0, 0.9, 0.8], [0.2, 0.3, 0.4], [3.0, 2.8, 2.5], [0.1, 0.1, 0.1], [0.6, 0.7, 0.9],
                  [0.5, 0.4, 0.3]])  # the env cube of the env-specular path: one RGB per face


def shell_group_bounds(tris, group=8):
    """Writes into tris (T, 3, 4) float32 what capi/src/methods/isg.c shell_groups does (in the given order):
    for each `group` consecutive triangles (of two or more) the bounding sphere of their vertices, centre the
    middle of their box, radius padded by 1e-4 of itself plus 1e-5 of all the triangles' extent, in the w of
    the group's first four vertices (x, y, z of the first triangle's, the radius of the second's first)."""
    if len(tris) == 0:
        return tris
    v = tris[..., :3].reshape(-1, 3).astype(np.float64)
    diag = float(np.linalg.norm(v.max(axis=0) - v.min(axis=0)))
    for g in range(0, len(tris) - 1, group):
        w = tris[g:g + group, :, :3].reshape(-1, 3).astype(np.float64)
        c = 0.5 * (w.min(axis=0) + w.max(axis=0))
        r = float(np.linalg.norm(w - c, axis=1).max())
        tris[g, :, 3] = c
        tris[g + 1, 0, 3] = np.float32(r * (1 + 1e-4)) + np.float32(1e-5 * diag) + np.float32(1e-30)
    return tris


def run_kernel(cl_pair, build_test_kernel, pixels, lobes, spheres, owners, grid=16, self_occlusion=1,
               specular_shadows=1, camera=(0.0, 3.0, 6.0), env_sharpness=1e30, tree=1, gamma=None, lod=0.0,
               triangles=(), triangle_owners=(), shared=None, irradiance=None, skins=None, inside_other=0,
               shell_groups=True):
    """pixels: list of dicts p, n, albedo, ks, material (shininess, roughness, lobe), id. tree: 1 the
    spheres through the sphere tree (the method's default), 0 the flat loop over them. gamma: (levels,
    tables) of the prefiltered env (specular_mode 1; penumbra.methods.isg.gamma_levels layout), None:
    specular_mode 0. lod: the LOD cut (0: off). triangles: thin-shell triangles (T, 3, 3) world space,
    their owners triangle_owners. shared: (M_s, shared_sharpness) of the shared hemisphere grid (its two
    cubes built by isg_lobe_cubes, as the host does), None: off. irradiance: (map (6 m m, 3), m), the env's
    irradiance as a vertex-grid cube (shared_light 1), None: shared_light 0. skins: per sphere (input
    order), the push of self_push (None: all 0); inside_other: that policy (kernels/isg.cl). shell_groups:
    the triangles' groups' bounding spheres in their spare w (shell_group_bounds, as the host writes them),
    False: none (every triangle tested on its own)."""
    ctx, queue = cl_pair
    n = len(pixels)
    f4 = lambda rows: np.ascontiguousarray(np.array(rows, np.float32).reshape(n, 4))  # noqa: E731
    pos = f4([[*q["p"], 1.0] for q in pixels])
    nrm = f4([[*unit(q["n"]), 0.0] for q in pixels])
    alb = f4([[*q["albedo"], q["ks"]] for q in pixels])
    mat = f4([[*q["material"], 0.0][:4] for q in pixels])  # (n_u, n_v, 3, tangent angle) is 4 long already
    ids = np.array([q["id"] for q in pixels], np.uint32)
    mf = cl.mem_flags
    ro = lambda a: cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=a)  # noqa: E731
    sp, order, nodes = sphere_tree(spheres, np.arange(len(spheres)))  # the order carries owners and skins along
    ow = np.asarray(owners, np.uint32).reshape(-1)[order]
    sk = (np.zeros(len(spheres)) if skins is None else np.asarray(skins, np.float64))[order].astype(np.float32)
    sp = np.ascontiguousarray(sp) if len(spheres) else np.zeros((1, 4), np.float32)
    ow = np.ascontiguousarray(ow) if len(owners) else np.zeros(1, np.uint32)
    sk = np.ascontiguousarray(sk) if len(spheres) else np.zeros(1, np.float32)
    lb = np.zeros((len(lobes), 8), np.float32)
    lb[:, :4], lb[:, 4:7] = np.asarray(lobes)[:, :4], np.asarray(lobes)[:, 4:7]
    cube = np.zeros((6, 4), np.float32)
    cube[:, :3] = FACES
    if gamma is None:
        mode, gbuf, lv, count, lambda0 = 0, np.zeros((1, 4), np.float32), np.zeros(2, np.int32), 1, 1.0
    else:
        mode, (levels, tables), count, lambda0 = 1, gamma, len(gamma[0]), gamma[0][0][0]
        gbuf = np.concatenate([np.c_[t, np.zeros(len(t))] for t in tables]).astype(np.float32)
        offsets = np.cumsum([0] + [len(t) for t in tables])[:-1]
        lv = np.array([[o, lev[1]] for o, lev in zip(offsets, levels)], np.int32).ravel()
    tris = np.zeros((max(len(triangles), 1), 3, 4), np.float32)
    tris[:len(triangles), :, :3] = np.asarray(triangles, np.float32).reshape(-1, 3, 3)
    tri_ow = np.zeros(max(len(triangles), 1), np.uint32)
    tri_ow[:len(triangles)] = np.asarray(triangle_owners, np.uint32)
    if shell_groups:
        shell_group_bounds(tris[:len(triangles)])
    lcube = device_lobe_cubes(cl_pair, build_test_kernel, lb, shared[1]) if shared else \
        cl.Buffer(ctx, mf.READ_ONLY, 16)
    if irradiance is None:
        irr_buf, irr_n = cl.Buffer(ctx, mf.READ_ONLY, 16), 0
    else:
        irr = np.zeros((len(irradiance[0]), 4), np.float32)
        irr[:, :3] = irradiance[0]
        irr_buf, irr_n = ro(irr), irradiance[1]
    out = np.empty((n, 4), np.float32)
    obuf = cl.Buffer(ctx, mf.WRITE_ONLY, out.nbytes)
    k = cl.Kernel(build_test_kernel(SOURCE), "shade_isg")
    k(queue, (n,), None, ro(pos), ro(nrm), ro(alb), ro(mat), ro(ids), np.int32(n), ro(cube), np.int32(1),
      ro(lb), np.int32(len(lobes)), ro(sp), ro(ow), np.int32(len(spheres)), ro(nodes), np.int32(tree), np.float32(lod), ro(tris), ro(tri_ow), np.int32(len(triangles)), np.int32(grid),
      np.int32(self_occlusion), np.int32(specular_shadows), np.float32(env_sharpness),
      np.array([*camera, 0.0], np.float32), ro(table32()), np.int32(mode), ro(gbuf), ro(lv), np.int32(count),
      np.float32(lambda0), np.int32(shared[0] if shared else 0), np.float32(shared[1] if shared else 0.0),
      lcube, np.int32(LOBE_CUBE_N), irr_buf, np.int32(irr_n), ro(sk), np.int32(inside_other), obuf)
    cl.enqueue_copy(queue, out, obuf)
    return out


def device_lobe_cubes(cl_pair, build_test_kernel, lobes8, sharpness, n=LOBE_CUBE_N):
    """isg_lobe_cubes on the device: a buffer of 12 n^2 float4 (L_b, then E_b), as the method builds it.
    lobes8: (K, 8) float32, the device layout."""
    ctx, queue = cl_pair
    mf = cl.mem_flags
    out = cl.Buffer(ctx, mf.READ_WRITE, 12 * n * n * 16)
    k = cl.Kernel(build_test_kernel(SOURCE), "isg_lobe_cubes")
    k(queue, (6 * n * n,), None, cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=np.ascontiguousarray(lobes8)),
      np.int32(len(lobes8)), np.float32(sharpness), np.int32(n), out)
    return out


def twin(pixels, lobes, spheres, owners, grid=16, self_occlusion=1, specular_shadows=1, camera=(0.0, 3.0, 6.0),
         env_sharpness=1e30, gamma=None, shared=None, irradiance=None, skins=None, inside_other=0):
    env_e = None
    if irradiance is not None:  # the map as the kernel reads it: float32 vertices, bilinear
        irr32 = np.asarray(irradiance[0], np.float32).astype(np.float64)
        env_e = lambda d: grid_lookup(irr32, irradiance[1], d)  # noqa: E731
    sh = (*shared, lobe_cube(lobes, shared[1]), env_e) if shared else None
    return np.array([shade(q["p"], q["n"], q["albedo"], q["ks"], q["material"], camera, q["id"], lobes, spheres,
                           owners, grid, self_occlusion, specular_shadows, env_sharpness, FACES, gamma, shared=sh,
                           skins=skins, inside_other=inside_other)
                     for q in pixels])


def floor_pixels(ks=0.0, material=(0.0, 0.3, 0.0), xs=np.linspace(-1.6, 1.6, 9), zs=(-0.4, 0.0, 0.7)):
    return [{"p": (x, 0.0, z), "n": (0, 1, 0), "albedo": (0.7, 0.6, 0.5), "ks": ks, "material": material, "id": 0}
            for x in xs for z in zs]


SPHERES = [[0.0, 0.8, 0.0, 0.5], [0.6, 0.5, 0.3, 0.3], [-0.7, 0.3, -0.2, 0.25]]
OWNERS = [1, 1, 2]


def check(got, want):
    np.testing.assert_allclose(got[:, :3], want, rtol=ISG_SHADE_RTOL, atol=ISG_SHADE_ATOL * float(np.max(want)))


def test_diffuse_floor_matches_twin(cl_pair, build_test_kernel):
    px = floor_pixels()
    got = run_kernel(cl_pair, build_test_kernel, px, LOBES, SPHERES, OWNERS)
    want = twin(px, LOBES, SPHERES, OWNERS)
    check(got, want)
    free = twin(px, LOBES, [], [])
    assert (want <= free + 1e-12).all() and (want < 0.9 * free).any()  # the spheres do cast shadows


def test_no_spheres_is_the_unshadowed_closed_form(cl_pair, build_test_kernel):
    px = floor_pixels(xs=(0.0,), zs=(0.0,))
    got = run_kernel(cl_pair, build_test_kernel, px, LOBES[:1], [], [])
    t = float(unit([0.3, 1.0, 0.2])[1])
    e = np.array(LOBES[0][4:7]) * float(sg_cosine_exact(np.array([t]), 300.0)[0])
    np.testing.assert_allclose(got[0, :3], np.array([0.7, 0.6, 0.5]) / math.pi * e, rtol=5e-3)


def test_black_env_and_k1(cl_pair, build_test_kernel):
    px = floor_pixels(xs=(0.0, 0.5), zs=(0.0,), ks=0.5, material=(100.0, 0.3, 0.0))
    black = np.array([lobe([0, 1, 0], 3.0, [0.0, 0.0, 0.0])])
    assert not run_kernel(cl_pair, build_test_kernel, px, black, SPHERES, OWNERS)[:, :3].any()
    one = np.array([lobe([0.1, 1, 0], 3.0, [1.0, 1.0, 1.0])])
    check(run_kernel(cl_pair, build_test_kernel, px, one, SPHERES, OWNERS), twin(px, one, SPHERES, OWNERS))


@pytest.mark.parametrize("shininess,ks", [(1000.0, 0.5), (1000.0, 0.01), (50.0, 0.3)])
def test_phong_specular_matches_twin(cl_pair, build_test_kernel, shininess, ks):
    px = floor_pixels(ks=ks, material=(shininess, 0.3, 0.0))
    cam = (1.0, 2.5, 4.0)
    got = run_kernel(cl_pair, build_test_kernel, px, LOBES, SPHERES, OWNERS, camera=cam)
    check(got, twin(px, LOBES, SPHERES, OWNERS, camera=cam))


@pytest.mark.parametrize("shininess,ks,shadows", [(1000.0, 0.5, 1), (1000.0, 0.5, 0), (200.0, 0.3, 1)])
def test_env_specular_path_matches_twin(cl_pair, build_test_kernel, shininess, ks, shadows):
    """Sharp lobes integrate the env cube on their own visible patches."""
    px = floor_pixels(ks=ks, material=(shininess, 0.3, 0.0))
    cam = (1.0, 2.5, 4.0)
    got = run_kernel(cl_pair, build_test_kernel, px, LOBES, SPHERES, OWNERS, camera=cam, env_sharpness=100.0,
                     specular_shadows=shadows)
    want = twin(px, LOBES, SPHERES, OWNERS, camera=cam, env_sharpness=100.0, specular_shadows=shadows)
    check(got, want)
    lobes_only = twin(px, LOBES, SPHERES, OWNERS, camera=cam, specular_shadows=shadows)
    assert np.abs(want - lobes_only).max() > 0.01 * want.max()  # the env path is not the lobe path


@functools.lru_cache(maxsize=4)
def gamma_tables(face=16, sun=1e5, constant=None):
    """Gamma_L of the twin's test sky (a 1e5:1 sun) or of a constant env, as the kernel reads it."""
    rgb = sky_cube(face, sun) if constant is None else np.full((6 * face * face, 3), constant)
    levels = gamma_levels(face)
    return levels, [t.astype(np.float32).astype(np.float64) for t in build_gamma(rgb, cube_directions(face), face,
                                                                                  levels)]


@pytest.mark.parametrize("shininess,ks,shadows,lobe_kind,sharp", [(1000.0, 0.5, 1, 0, 100.0), (1000.0, 0.5, 0, 0, 100.0),
                                                                  (200.0, 0.3, 1, 0, 100.0), (40.0, 0.4, 1, 0, 10.0),
                                                                  (5000.0, 0.5, 1, 0, 100.0), (0.02, 0.4, 1, 2, 100.0)])
def test_prefiltered_specular_matches_twin(cl_pair, build_test_kernel, shininess, ks, shadows, lobe_kind, sharp):
    """specular_mode 1: Gamma_L at the lobe's axis times its visible patches' cosine-weighted share; lobes
    between the table's levels (Phong 40 and 200: levels 1 ... 256 of a face-16 cube), beyond its last
    (Phong 1000, 5000) and a GGX lobe."""
    mat = (shininess, shininess, float(lobe_kind))
    # and pixels whose mirror direction from the camera meets the test sky's sun
    px = floor_pixels(ks=ks, material=mat) + floor_pixels(ks=ks, material=mat, xs=(1.7, 1.94, 2.2), zs=(5.4, 5.6, 5.8))
    cam = (1.0, 2.5, 4.0)
    g = gamma_tables()
    got = run_kernel(cl_pair, build_test_kernel, px, LOBES, SPHERES, OWNERS, camera=cam, env_sharpness=sharp,
                     specular_shadows=shadows, gamma=g)
    want = twin(px, LOBES, SPHERES, OWNERS, camera=cam, env_sharpness=sharp, specular_shadows=shadows, gamma=g)
    check(got, want)
    patches = twin(px, LOBES, SPHERES, OWNERS, camera=cam, env_sharpness=sharp, specular_shadows=shadows)
    assert np.abs(want - patches).max() > 0.01 * want.max()  # the prefiltered path is not the patch path


def test_prefiltered_specular_of_a_constant_env_is_the_patch_paths(cl_pair, build_test_kernel):
    """Gamma_L of a constant env is the constant, so both specular modes shade alike (the cosine and the
    visibility are the same patch sums)."""
    px = floor_pixels(ks=0.5, material=(1000.0, 0.3, 0.0))
    cam = (1.0, 2.5, 4.0)
    g = gamma_tables(constant=0.75)
    got = run_kernel(cl_pair, build_test_kernel, px, LOBES, SPHERES, OWNERS, camera=cam, env_sharpness=100.0,
                     gamma=g)
    want = np.array([shade(q["p"], q["n"], q["albedo"], q["ks"], q["material"], cam, q["id"], LOBES, SPHERES,
                           OWNERS, 16, env_sharpness=100.0, face_rgb=np.full((6, 3), 0.75)) for q in px])
    check(got, want)


@pytest.mark.parametrize("lobe_kind,param", [(1, 200.0), (2, 0.2)])
def test_blinn_phong_and_ggx_specular_match_twin(cl_pair, build_test_kernel, lobe_kind, param):
    px = floor_pixels(ks=0.4, material=(param, param, float(lobe_kind)), xs=(-1.0, 0.2, 1.2))
    got = run_kernel(cl_pair, build_test_kernel, px, LOBES, SPHERES, OWNERS)
    check(got, twin(px, LOBES, SPHERES, OWNERS))


def spread_spheres(count, seed=3):
    """`count` spheres of radius 0.05-0.3 scattered over a 12 x 12 area up to 3 above
    the floor (most of them outside most lobes' cones from any one pixel), owners 1-3."""
    rng = np.random.default_rng(seed)
    c = np.c_[rng.uniform(-6, 6, count), rng.uniform(0.1, 3.0, count), rng.uniform(-6, 6, count)]
    return np.c_[c, rng.uniform(0.05, 0.3, count)].tolist(), (1 + np.arange(count) % 3).tolist()


@pytest.mark.parametrize("count", [7, 9, 300])
def test_sphere_tree_gives_the_flat_loops_image(cl_pair, build_test_kernel, count):
    """The tree's culling (kernels/isg.cl pn_isg_node_open) drops no sphere that marks a
    patch or holds the receiver: the same image as the flat loop, bit for bit, on spread
    spheres (one tree level, two, three) with receivers among them: on the floor, on
    spheres' surfaces with each self-occlusion policy, one inside a sphere, a sharp
    specular lobe (the env path) and broad ones (the lobe products)."""
    spheres, owners = spread_spheres(count)
    rng = np.random.default_rng(5)
    px = floor_pixels(ks=0.4, material=(1000.0, 0.3, 0.0), xs=np.linspace(-5.5, 5.5, 7), zs=(-5.0, -1.0, 0.3, 4.0))
    px += floor_pixels(ks=0.3, material=(30.0, 0.3, 0.0), xs=np.linspace(-5.0, 5.0, 5), zs=(2.0,))
    for s, o in list(zip(spheres, owners))[:12]:  # on a sphere's surface, facing out
        d = unit(rng.normal(size=3))
        px.append({"p": tuple(np.array(s[:3]) + s[3] * d), "n": tuple(d), "albedo": (0.6, 0.6, 0.6), "ks": 0.2,
                   "material": (200.0, 0.3, 0.0), "id": o})
    px.append({"p": tuple(spheres[0][:3]), "n": (0, 1, 0), "albedo": (1, 1, 1), "ks": 0.0, "material": (0, 0.3, 0),
               "id": 0})  # inside another instance's sphere
    cam = (0.5, 4.0, 8.0)
    skins = (0.02 + 0.1 * (np.arange(count) % 4)).tolist()  # self_push: own spheres seen from p + skin n
    for policy, extra in ((0, {}), (1, {}), (2, {}), (1, dict(skins=skins, inside_other=1)),
                          (1, dict(skins=skins, inside_other=2))):
        for env_sharpness in (100.0, 1e30):
            args = dict(self_occlusion=policy, camera=cam, env_sharpness=env_sharpness, **extra)
            flat = run_kernel(cl_pair, build_test_kernel, px, LOBES, spheres, owners, tree=0, **args)
            tree = run_kernel(cl_pair, build_test_kernel, px, LOBES, spheres, owners, tree=1, **args)
            np.testing.assert_array_equal(tree, flat)
            if not extra:
                plain = flat
    free = run_kernel(cl_pair, build_test_kernel, px, LOBES, [], [])
    assert (plain[:, :3] < 0.9 * free[:, :3]).any() and not plain[-1, :3].any()  # shadows, and the inside pixel
    assert flat[-1, :3].all()  # inside_other 2: that sphere is seen from the pushed receiver, or skipped


@pytest.mark.parametrize("grid", [2, 5, 16, 24])
def test_sphere_tree_gives_the_flat_loops_image_on_random_scenes(cl_pair, build_test_kernel, grid):
    """Random receivers (any normal), spheres of any size from tiny to ones holding or
    touching receivers, and lobes from broad to very sharp (lambda up to 1e4, the
    windows' rows and columns then 0.2 mrad apart): the tree path's patch walk marks
    what the flat loop's lat-long bounds do."""
    rng = np.random.default_rng(100 + grid)
    c = rng.uniform(-3, 3, (80, 3))
    spheres = np.c_[c, np.exp(rng.uniform(np.log(0.01), np.log(0.8), 80))].tolist()
    owners = rng.integers(1, 4, 80).tolist()
    lobes = np.array([lobe(rng.normal(size=3), lam, [1.0, 0.8, 0.6]) for lam in (0.5, 3.0, 30.0, 300.0, 1e4)])
    px = [{"p": tuple(rng.uniform(-2, 2, 3)), "n": tuple(unit(rng.normal(size=3))), "albedo": (0.6, 0.6, 0.6),
           "ks": 0.3, "material": (float(rng.choice([20.0, 2000.0])), 0.3, 0.0), "id": int(rng.integers(0, 4))}
          for _ in range(48)]
    px.append({"p": tuple(spheres[0][:3]), "n": (0, 1, 0), "albedo": (1, 1, 1), "ks": 0.0, "material": (0, 0.3, 0),
               "id": 0})  # inside another instance's sphere
    for policy in (1, 2):
        args = dict(grid=grid, self_occlusion=policy, env_sharpness=100.0)
        flat = run_kernel(cl_pair, build_test_kernel, px, lobes, spheres, owners, tree=0, **args)
        tree = run_kernel(cl_pair, build_test_kernel, px, lobes, spheres, owners, tree=1, **args)
        np.testing.assert_array_equal(tree, flat)
    free = run_kernel(cl_pair, build_test_kernel, px, lobes, [], [], grid=grid, env_sharpness=100.0)
    lit = (flat[:, :3] > 0).any(axis=1)
    assert lit.sum() > len(px) // 2 and (~lit).any()  # most receivers outside the spheres, some inside
    assert (flat[lit, :3] < 0.9 * free[lit, :3]).any(axis=1).sum() > len(px) // 4  # and shadowed


MARK_SOURCE = """#include "isg.cl"
kernel void mark_test(global const float4 *position, global const float4 *normal, global const uint *ids,
                      global const float4 *axis, int lobe_count, global const float4 *spheres,
                      global const uint *owners, int sphere_count, global const float4 *nodes, int grid,
                      int self_occlusion, global uint *out)
{
    const int gid = get_global_id(0), q = gid / lobe_count;
    pn_sg g;
    g.axis = axis[gid % lobe_count].xyz, g.sharpness = axis[gid % lobe_count].w, g.amplitude = (float3)(1.0f);
    pn_isg_grid pg;
    pn_isg_grid_init(g, grid, &pg);
    pn_isg_tree tree;
    pn_isg_tree_init(sphere_count, 1, &tree);
    uint mask[PN_ISG_MAX_GRID];
    const int m = pn_isg_mark(&pg, position[q].xyz, normal[q].xyz, ids[q], self_occlusion, spheres, owners,
                              sphere_count, nodes, &tree, mask);
    for (int i = 0; i < PN_ISG_MAX_GRID; ++i)
        out[gid * (PN_ISG_MAX_GRID + 1) + i] = mask[i];
    out[gid * (PN_ISG_MAX_GRID + 1) + PN_ISG_MAX_GRID] = (uint)m;
}
"""


def run_mark_kernel(ctx, queue, kernel, lead, pos, nrm, ids, axes, n_lams, tail):
    """Runs a patch-marking test kernel, one work-item per (receiver, lobe):
    kernel(*lead, pos, nrm, ids, axes, n_lams, *tail, out) with the arrays
    uploaded as read-only buffers (pos and nrm widened to float4); returns
    the (cases, 25) words it wrote (the mask rows, then the count)."""
    mf = cl.mem_flags
    ro = lambda a: cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=np.ascontiguousarray(a))  # noqa: E731
    f4 = lambda a: np.c_[a, np.zeros(len(a))].astype(np.float32)  # noqa: E731
    cases = len(pos) * n_lams
    out = np.empty((cases, 25), np.uint32)
    obuf = cl.Buffer(ctx, mf.WRITE_ONLY, out.nbytes)
    args = [ro(a) if isinstance(a, np.ndarray) and a.ndim > 0 else a for a in tail]
    kernel(queue, (cases,), None, *lead, ro(f4(pos)), ro(f4(nrm)), ro(ids), ro(axes), np.int32(n_lams), *args, obuf)
    cl.enqueue_copy(queue, out, obuf)
    return out


@pytest.mark.parametrize("grid", [2, 5, 16, 17, 24])
def test_patch_marks_match_twin(cl_pair, build_test_kernel, grid):
    """The kernel's patch marks (16 rows or columns per test, up to 24 of them) are the
    twin's, patch by patch, except where a patch centre lies on a cap's edge to
    rounding (|d.u - cos alpha| < 1e-5 in float64): random receivers, spheres from
    tiny to holding the receiver, lobes from broad to lambda = 1e4."""
    from isg_shading64 import patch_mask

    ctx, queue = cl_pair
    rng = np.random.default_rng(200 + grid)
    c = rng.uniform(-3, 3, (60, 3))
    spheres = np.c_[c, np.exp(rng.uniform(np.log(0.01), np.log(0.8), 60))]
    owners = rng.integers(1, 4, 60)
    lams = (0.5, 3.0, 30.0, 300.0, 1e4)
    axes = np.array([[*unit(rng.normal(size=3)), lam] for lam in lams], np.float32)
    pos = rng.uniform(-2, 2, (24, 3))
    nrm = np.array([unit(rng.normal(size=3)) for _ in range(24)])
    ids = rng.integers(0, 4, 24).astype(np.uint32)
    sp, ow, nodes = sphere_tree(spheres.tolist(), owners.tolist())
    cases = len(pos) * len(lams)
    k = cl.Kernel(build_test_kernel(MARK_SOURCE), "mark_test")
    out = run_mark_kernel(ctx, queue, k, (), pos, nrm, ids, axes, len(lams),
                          (sp, ow, np.int32(len(sp)), nodes, np.int32(grid), np.int32(1)))
    bits = (out[:, :grid, None] >> np.arange(grid, dtype=np.uint32)) & 1
    marked = ambiguous = 0
    for case in range(cases):
        q, li = divmod(case, len(lams))
        axis, lam = axes[li, :3].astype(np.float64), float(axes[li, 3])
        want, inside = patch_mask(axis, lam, pos[q], nrm[q], int(ids[q]), 1, spheres, owners, grid)
        assert (int(out[case, 24]) == 0xFFFFFFFF) == inside  # -1: the receiver inside an occluder
        if inside:
            continue
        from isg_shading64 import HALF_PI, frame, window
        x, y = frame(axis)
        w = window(lam)
        cen = HALF_PI - w + (np.arange(grid) + 0.5) * (2.0 * w / grid)
        th, ph = np.meshgrid(cen, cen, indexing="ij")
        dirs = (np.sin(th) * np.cos(ph))[..., None] * x + np.cos(th)[..., None] * y + \
            (np.sin(th) * np.sin(ph))[..., None] * axis
        edge = np.zeros((grid, grid), bool)
        for sph in spheres:
            v = sph[:3] - pos[q]
            d = np.linalg.norm(v)
            if d > sph[3]:
                edge |= np.abs(dirs @ (v / d) - math.sqrt(1.0 - (sph[3] / d) ** 2)) < 1e-5
        got = bits[case].astype(bool)
        assert (got == want)[~edge].all(), (case, np.argwhere((got != want) & ~edge))
        marked += int(want.sum())
        ambiguous += int(edge.sum())
    assert marked > 10 * grid and ambiguous < marked // 20 + 2  # shadows found; few edge patches


def test_sphere_tree_levels():
    """The Python twin of the host's tree: levels of ceil(previous / 8) nodes up to at
    most 8, each node's sphere holding its spheres (or child nodes)."""
    spheres, owners = spread_spheres(300)
    sp, ow, nodes = sphere_tree(spheres, owners)
    assert len(nodes) == 38 + 5 and sorted(map(tuple, sp.tolist())) == sorted(
        map(tuple, np.asarray(spheres, np.float32).tolist()))
    for i, node in enumerate(nodes[:38]):
        kids = sp[8 * i:8 * i + 8].astype(np.float64)
        assert (np.linalg.norm(kids[:, :3] - node[:3], axis=1) + kids[:, 3] <= node[3]).all()
    for i, node in enumerate(nodes[38:]):
        kids = nodes[8 * i:min(8 * i + 8, 38)].astype(np.float64)
        assert (np.linalg.norm(kids[:, :3] - node[:3], axis=1) + kids[:, 3] <= node[3]).all()


def test_overlapping_spheres_occlude_a_patch_once(cl_pair, build_test_kernel):
    px = floor_pixels()
    one = run_kernel(cl_pair, build_test_kernel, px, LOBES, SPHERES[:1], OWNERS[:1])
    doubled = run_kernel(cl_pair, build_test_kernel, px, LOBES, SPHERES[:1] * 3, OWNERS[:1] * 3)
    np.testing.assert_array_equal(one, doubled)


def test_receiver_inside_another_sphere_is_dark_and_straddling_sphere_matches(cl_pair, build_test_kernel):
    inside = [{"p": (0.0, 0.0, 0.0), "n": (0, 1, 0), "albedo": (1, 1, 1), "ks": 0.0, "material": (0, 0.3, 0), "id": 0}]
    got = run_kernel(cl_pair, build_test_kernel, inside, LOBES, [[0.0, 0.1, 0.0, 0.5]], [1])
    assert not got[0, :3].any()
    straddle = [[0.0, -0.2, 0.0, 0.6]]  # centre below the floor, cap above it
    px = floor_pixels(xs=np.linspace(0.7, 2.0, 6))
    got = run_kernel(cl_pair, build_test_kernel, px, LOBES, straddle, [1])
    want = twin(px, LOBES, straddle, [1])
    check(got, want)
    assert (want < twin(px, LOBES, [], [])).any()


def test_grazing_normals_match_twin(cl_pair, build_test_kernel):
    px = [{"p": (1.0, 0.0, 0.0), "n": (math.cos(a), math.sin(a), 0.0), "albedo": (0.8, 0.8, 0.8), "ks": 0.2,
           "material": (300.0, 0.3, 0.0), "id": 0} for a in (1e-4, 0.01, 0.05, math.pi - 0.02)]
    got = run_kernel(cl_pair, build_test_kernel, px, LOBES, SPHERES, OWNERS)
    assert np.isfinite(got).all() and (got >= 0).all()
    check(got, twin(px, LOBES, SPHERES, OWNERS))


@pytest.mark.parametrize("policy", [0, 1, 2])
def test_self_occlusion_policies(cl_pair, build_test_kernel, policy):
    """A receiver on its own object's surface, inside a neighbouring sphere of
    its own set (as on a sphere-set bunny): policy 1 drops that sphere (no
    dark disc) but keeps the object's other spheres; policy 2 makes it dark."""
    own = [[0.0, 1.0, 0.0, 1.0], [0.9, 1.0, 0.0, 0.5], [2.2, 1.6, 0.0, 0.5]]
    px = [{"p": (1.0, 1.0, 0.0), "n": (1, 0, 0), "albedo": (1, 1, 1), "ks": 0.0, "material": (0, 0.3, 0), "id": 1}]
    got = run_kernel(cl_pair, build_test_kernel, px, LOBES, own, [1, 1, 1], self_occlusion=policy)
    want = twin(px, LOBES, own, [1, 1, 1], self_occlusion=policy)
    check(got, want)
    free = twin(px, LOBES, [], [])
    if policy == 0:
        np.testing.assert_allclose(want, free)
    elif policy == 1:
        assert (want < 0.97 * free).all() and (want > 0.5 * free).all()  # shadowed by the third sphere only
    else:
        assert not want.any() and not got[:, :3].any()


@pytest.mark.parametrize("policy", [1, 2])
def test_self_occlusion_margin(cl_pair, build_test_kernel, policy):
    """A receiver just outside an own sphere that pokes out of the surface
    next to it (distance 1.015 r, the sphere beside it above the receiver
    plane): policy 1 skips it (no dark arc along the sphere's rim; margin
    0.02 r, kernels/isg.cl PN_ISG_SELF_MARGIN), while an own sphere beyond the
    margin (1.1 r) still shadows; policy 2 keeps both."""
    near = [[-1.015, 0.0, 0.0, 1.0]]
    far = [[-1.1, 0.0, 0.0, 1.0]]
    px = [{"p": (0.0, 0.0, 0.0), "n": (0, 1, 0), "albedo": (1, 1, 1), "ks": 0.0, "material": (0, 0.3, 0), "id": 1}]
    free = twin(px, LOBES, [], [])
    for spheres in (near, far):
        got = run_kernel(cl_pair, build_test_kernel, px, LOBES, spheres, [1], self_occlusion=policy)
        want = twin(px, LOBES, spheres, [1], self_occlusion=policy)
        check(got, want)
        if policy == 1 and spheres is near:
            np.testing.assert_allclose(got[:, :3], free, rtol=ISG_SHADE_RTOL, atol=ISG_SHADE_ATOL * float(free.max()))
        else:
            assert (got[:, :3].sum(-1) < 0.95 * free.sum(-1)).all()


def test_self_push_keeps_the_shadow_without_the_dark_disc(cl_pair, build_test_kernel):
    """A receiver on its own surface inside an own ball whose centre lies below
    its tangent plane and which reaches well above it beside the receiver (a
    crease: the ball fills the object rising next to it). Policy 2 is the dark
    disc (black); policy 1 used to skip the ball whole (unshadowed by it). With
    a skin (self_push) the ball is seen from p + skin n: it still shadows the
    sky on its side, and the pixel is far from black (the dark disc would fail
    the lower bound); a skin too short to leave the ball skips it."""
    ball = [[0.5, 0.0, 0.0, 0.52]]
    px = [{"p": (0.0, 0.0, 0.0), "n": (0, 1, 0), "albedo": (1, 1, 1), "ks": 0.3, "material": (200.0, 0.3, 0.0),
           "id": 1}]
    args = dict(camera=(-3.0, 3.0, 0.5), env_sharpness=100.0)
    free = twin(px, LOBES, [], [], **args)
    assert not run_kernel(cl_pair, build_test_kernel, px, LOBES, ball, [1], self_occlusion=2, **args)[:, :3].any()
    for skin, shadowed in ((0.0, False), (0.05, False), (0.2, True), (0.3, True)):
        got = run_kernel(cl_pair, build_test_kernel, px, LOBES, ball, [1], skins=[skin], **args)
        want = twin(px, LOBES, ball, [1], skins=[skin], **args)
        check(got, want)
        if shadowed:  # the higher p + skin n, the less of its sky the ball covers
            hi = 0.7 if skin == 0.2 else 0.99
            assert (want < hi * free).all() and (want > 0.4 * free).all(), (skin, want / free)
        else:  # still inside the ball from p + skin n: skipped, as without a skin
            np.testing.assert_allclose(want, free, rtol=1e-12)


def test_receiver_inside_another_instances_sphere(cl_pair, build_test_kernel):
    """A floor receiver inside a sphere of another instance that pokes through
    the floor: inside_other 0 makes it black (V = 0), 1 skips that sphere (the
    others still shadow it), 2 sees it from p + skin n with its own set's skin
    (skipped without a skin): between the two, matching the twin."""
    poking = [[0.45, -0.2, 0.0, 0.5], [-0.9, 0.5, 0.3, 0.3]]
    owners = [2, 3]
    px = [{"p": (0.0, 0.0, 0.0), "n": (0, 1, 0), "albedo": (0.8, 0.7, 0.6), "ks": 0.0, "material": (0, 0.3, 0),
           "id": 0}]
    got0 = run_kernel(cl_pair, build_test_kernel, px, LOBES, poking, owners, skins=[0.1, 0.1])
    assert not got0[:, :3].any()
    others = twin(px, LOBES, poking[1:], owners[1:])
    assert (others < 0.99 * twin(px, LOBES, [], [])).all()  # the other sphere shadows the receiver
    got1 = run_kernel(cl_pair, build_test_kernel, px, LOBES, poking, owners, skins=[0.1, 0.1], inside_other=1)
    check(got1, twin(px, LOBES, poking, owners, skins=[0.1, 0.1], inside_other=1))
    check(got1, others)
    no_skin = run_kernel(cl_pair, build_test_kernel, px, LOBES, poking, owners, inside_other=2)
    check(no_skin, others)
    got2 = run_kernel(cl_pair, build_test_kernel, px, LOBES, poking, owners, skins=[0.1, 0.1], inside_other=2)
    want2 = twin(px, LOBES, poking, owners, skins=[0.1, 0.1], inside_other=2)
    check(got2, want2)
    assert (want2 < 0.97 * others).all() and (want2 > 0.3 * others).all()


def test_background_pixels(cl_pair, build_test_kernel):
    px = [{"p": (0.0, 0.0, -1.0), "n": (0, 1, 0), "albedo": (1, 1, 1), "ks": 0, "material": (0, 0, 0),
           "id": BACKGROUND}]
    got = run_kernel(cl_pair, build_test_kernel, px, LOBES, SPHERES, OWNERS)
    assert not got.any()  # black, alpha 0: the renderer's background pass draws these pixels


@pytest.mark.parametrize("lam", [2.5, 40.0, 1000.0])
def test_patch_visibility_converges_to_the_exact_visible_integral(lam):
    """The twin's patch visibility of a lobe against dense quadrature with
    exact ray-sphere tests over the lobe's front hemisphere: the patch
    discretisation error shrinks with M. Then the product-lobe stand-in for
    lobe x clamped cosine against the exact share of lobe x cosine."""
    p, n = np.zeros(3), np.array([0.0, 1.0, 0.0])
    axis = unit([0.1, 1.0, 0.05])
    # one sphere whose cap edge crosses the lobe near its axis (at any lambda), one broad one aside
    width = min(1.0 / math.sqrt(lam), 0.5)
    c = unit(axis + width * unit(np.cross(axis, [0.0, 0.0, 1.0])))
    spheres = [[*(2.0 * c), 2.0 * math.sin(1.2 * width)], [-0.4, 0.7, 0.3, 0.2]]
    dense = 3_000_000 if lam > 100 else 400_000  # enough directions inside a sharp lobe
    exact = visible_exact(axis, lam, 1.0, p, None, spheres, dense) / visible_exact(axis, lam, 1.0, p, None, [], dense)
    errs = [abs(visibility(axis, lam, p, n, 0, 1, spheres, [1, 1], g) - exact) for g in (4, 8, 16, 24)]
    assert errs[-1] < ISG_VISIBILITY_GRID_ATOL and errs[-1] < errs[0], errs
    m_axis, m_lam, _ = sg_product(axis, lam, 1.0, n, COS_SHARPNESS, COS_AMPLITUDE)
    exact_cos = visible_exact(axis, lam, 1.0, p, n, spheres) / visible_exact(axis, lam, 1.0, p, n, [])
    assert abs(visibility(m_axis, float(m_lam), p, n, 0, 1, spheres, [1, 1], 24) - exact_cos) < \
        ISG_VISIBILITY_PATCH_ATOL


# ---------------------------------------------------------------- the LOD cut (docs/isg.md section 8)


def clustered_spheres(clusters=40, seed=11):
    """Clusters of 8 small spheres (radius 0.03-0.1 within 0.25 of the cluster's
    centre) spread over a 12 x 12 area up to 3 above the floor, as sphere sets
    of small objects: their tree nodes are compact, so far ones fall under the
    LOD cut. Owners 1-3 by cluster."""
    rng = np.random.default_rng(seed)
    c = np.c_[rng.uniform(-6, 6, clusters), rng.uniform(0.4, 3.0, clusters), rng.uniform(-6, 6, clusters)]
    s = np.repeat(c, 8, axis=0) + rng.uniform(-0.25, 0.25, (8 * clusters, 3))
    return np.c_[s, rng.uniform(0.03, 0.1, 8 * clusters)].tolist(), (1 + np.repeat(np.arange(clusters), 8) % 3).tolist()


def lod_pixels(spheres, owners):
    """Floor receivers among spread spheres, near and far from them, diffuse and
    specular (sharp: the env path; broad: the lobe products), and receivers on
    spheres' surfaces (self-occlusion)."""
    rng = np.random.default_rng(7)
    px = floor_pixels(ks=0.3, material=(1000.0, 0.3, 0.0), xs=np.linspace(-5.5, 5.5, 6), zs=(-5.0, -1.0, 3.0))
    px += floor_pixels(ks=0.3, material=(20.0, 0.3, 0.0), xs=np.linspace(-5.0, 5.0, 4), zs=(0.5, 5.5))
    for s, o in list(zip(spheres, owners))[:6]:
        d = unit(rng.normal(size=3) + [0.0, 1.0, 0.0])
        px.append({"p": tuple(np.array(s[:3]) + s[3] * d), "n": tuple(d), "albedo": (0.6, 0.6, 0.6), "ks": 0.2,
                   "material": (200.0, 0.3, 0.0), "id": o})
    return px


@pytest.mark.parametrize("lod", [1.0, 3.0])
def test_lod_cut_matches_twin(cl_pair, build_test_kernel, lod):
    """The kernel's LOD cut (a small node marks with its bounding sphere) against
    the twin's tree walk (isg_shading64.patch_mask with tree), which is not the
    exact marking: the cut changes the twin's image."""
    spheres, owners = clustered_spheres()
    sp, ow, nodes = sphere_tree(spheres, owners)
    px = lod_pixels(spheres, owners)
    args = dict(camera=(0.5, 4.0, 8.0), env_sharpness=100.0)
    got = run_kernel(cl_pair, build_test_kernel, px, LOBES, sp.tolist(), ow.tolist(), lod=lod, **args)
    want = np.array([shade(q["p"], q["n"], q["albedo"], q["ks"], q["material"], args["camera"], q["id"], LOBES,
                           sp, ow, 16, 1, 1, 100.0, FACES, None, (nodes, lod)) for q in px])
    check(got, want)
    exact = twin(px, LOBES, sp, ow, **args)
    assert np.abs(want - exact).max() > 1e-3 * exact.max()  # the cut took nodes for spheres


def test_lod_zero_is_the_exact_walk(cl_pair, build_test_kernel):
    """lod 0 is today's image bit for bit (the flat loop's); so is any lod with
    self_occlusion 0 (the cut is off there) or without the tree."""
    spheres, owners = clustered_spheres()
    px = lod_pixels(spheres, owners)
    for policy in (0, 1, 2):
        args = dict(self_occlusion=policy, camera=(0.5, 4.0, 8.0), env_sharpness=100.0)
        flat = run_kernel(cl_pair, build_test_kernel, px, LOBES, spheres, owners, tree=0, **args)
        np.testing.assert_array_equal(run_kernel(cl_pair, build_test_kernel, px, LOBES, spheres, owners, lod=0.0,
                                                 **args), flat)
        np.testing.assert_array_equal(run_kernel(cl_pair, build_test_kernel, px, LOBES, spheres, owners, tree=0,
                                                 lod=2.0, **args), flat)
        cut = run_kernel(cl_pair, build_test_kernel, px, LOBES, spheres, owners, lod=2.0, **args)
        assert (cut == flat).all() if policy == 0 else (cut != flat).any()


LOD_MARK_SOURCE = MARK_SOURCE.replace("kernel void mark_test(", "kernel void mark_lod_test(float lod, ").replace(
    "pn_isg_tree_init(sphere_count, 1, &tree);", "pn_isg_tree_init(sphere_count, 1, &tree);\n    tree.lod = lod;")


@pytest.mark.parametrize("lod", [0.5, 1.0, 3.0])
def test_lod_cut_marks_match_twin(cl_pair, build_test_kernel, lod):
    """The LOD cut's patch marks, patch by patch, against the twin's tree walk
    (patch_mask with tree): random receivers among clustered spheres, lobes from
    broad to lambda = 300. Excepted: patches within 1e-5 of a sphere's or node's
    cap edge, and cases where a node's angular size is within 1e-5 of the cut
    (float32 and float64 may decide it apart). The cut marks a superset of the
    exact marks (a node's cap holds its spheres' caps), and more in some cases."""
    from isg_shading64 import HALF_PI, frame, patch_mask, tree_levels, window

    ctx, queue = cl_pair
    rng = np.random.default_rng(300)
    spheres, owners = clustered_spheres()
    sp, ow, nodes = sphere_tree(spheres, owners)
    lams = (0.5, 3.0, 30.0, 300.0)
    axes = np.array([[*unit(rng.normal(size=3) + [0.0, 1.5, 0.0]), lam] for lam in lams], np.float32)
    pos = np.c_[rng.uniform(-6, 6, 32), np.zeros(32), rng.uniform(-6, 6, 32)]
    nrm = np.array([unit([*rng.normal(scale=0.3, size=1), 1.0, *rng.normal(scale=0.3, size=1)]) for _ in range(32)])
    ids = np.zeros(32, np.uint32)
    cases = len(pos) * len(lams)
    k = cl.Kernel(build_test_kernel(LOD_MARK_SOURCE), "mark_lod_test")
    out = run_mark_kernel(ctx, queue, k, (np.float32(lod),), pos, nrm, ids, axes, len(lams),
                          (sp, ow, np.int32(len(sp)), nodes, np.int32(16), np.int32(1)))
    bits = ((out[:, :16, None] >> np.arange(16, dtype=np.uint32)) & 1).astype(bool)
    spd, nd = sp.astype(np.float64), nodes.astype(np.float64)
    compared = extra = skipped = 0
    for case in range(cases):
        q, li = divmod(case, len(lams))
        axis, lam = axes[li, :3].astype(np.float64), float(axes[li, 3])
        w = window(lam)
        sin_lod = math.sin(min(0.5 * lod * 2.0 * w / 16, 1.5))
        v = nd[:, :3] - pos[q]
        d = np.linalg.norm(v, axis=1)
        if (np.abs(nd[:, 3] / d - sin_lod) < 1e-5).any() or (np.abs(v @ nrm[q] - nd[:, 3]) < 1e-5 * d).any():
            skipped += 1
            continue
        want, inside = patch_mask(axis, lam, pos[q], nrm[q], 0, 1, spd, ow, 16, (nodes, lod))
        exact, _ = patch_mask(axis, lam, pos[q], nrm[q], 0, 1, spd, ow, 16)
        assert not inside and int(out[case, 24]) != 0xFFFFFFFF
        x, y = frame(axis)
        cen = HALF_PI - w + (np.arange(16) + 0.5) * (2.0 * w / 16)
        th, ph = np.meshgrid(cen, cen, indexing="ij")
        dirs = (np.sin(th) * np.cos(ph))[..., None] * x + np.cos(th)[..., None] * y + \
            (np.sin(th) * np.sin(ph))[..., None] * axis
        edge = np.zeros((16, 16), bool)
        for b in np.r_[spd, nd]:
            vb = b[:3] - pos[q]
            db = np.linalg.norm(vb)
            edge |= np.abs(dirs @ (vb / db) - math.sqrt(max(1.0 - (b[3] / db) ** 2, 0.0))) < 1e-5
        assert (bits[case] == want)[~edge].all(), (case, np.argwhere((bits[case] != want) & ~edge))
        assert (want | ~exact).all()  # a superset of the exact marks
        compared += 1
        extra += int((want & ~exact).sum())
    assert compared > cases * 3 // 4 and extra > 0, (compared, skipped, extra)
    assert len(tree_levels(len(sp))) == 2


# ---------------------------------------------------------------- thin shells (docs/isg.md section 8)


SHELL_MARK_SOURCE = """#include "isg.cl"
kernel void mark_shell_test(global const float4 *position, global const float4 *normal, global const uint *ids,
                            global const float4 *axis, int lobe_count, global const float4 *tris,
                            global const uint *tri_owners, int tri_count, int grid, int self_occlusion,
                            global uint *out)
{
    const int gid = get_global_id(0), q = gid / lobe_count;
    pn_sg g;
    g.axis = axis[gid % lobe_count].xyz, g.sharpness = axis[gid % lobe_count].w, g.amplitude = (float3)(1.0f);
    pn_isg_grid pg;
    pn_isg_grid_init(g, grid, &pg);
    pn_isg_tree tree;
    pn_isg_tree_init(0, 1, &tree);
    tree.tris = tris, tree.tri_owners = tri_owners, tree.tri_count = tri_count;
    uint mask[PN_ISG_MAX_GRID];
    const int m = pn_isg_mark(&pg, position[q].xyz, normal[q].xyz, ids[q], self_occlusion, tris, tri_owners, 0,
                              tris, &tree, mask);
    for (int i = 0; i < PN_ISG_MAX_GRID; ++i)
        out[gid * (PN_ISG_MAX_GRID + 1) + i] = mask[i];
    out[gid * (PN_ISG_MAX_GRID + 1) + PN_ISG_MAX_GRID] = (uint)m;
}
"""


def hard_triangles(rng, count=60):
    """Random triangles around the origin, of sizes 0.02-2, plus the hard cases: ones
    crossing the plane y = 0 (the receivers' plane, roughly), edge-on ones (their
    plane through the origin), degenerate ones (collinear and coincident vertices)."""
    c = rng.uniform(-2.5, 2.5, (count, 3)) + [0.0, 1.0, 0.0]
    tris = c[:, None, :] + rng.normal(size=(count, 3, 3)) * np.exp(rng.uniform(np.log(0.02), np.log(1.0),
                                                                              (count, 1, 1)))
    crossing = np.array([[[-0.5, -0.4, 0.8], [0.6, 0.5, 0.9], [0.0, 0.6, 1.4]],
                         [[1.0, -1.0, -0.2], [1.2, 1.5, 0.1], [0.7, 1.0, -0.6]]])
    edge_on = np.array([[[0.5, 0.5, 0.0], [1.0, 1.0, 0.0], [0.3, 1.2, 0.0]]])  # plane z = 0 holds the origin
    degenerate = np.array([[[0.0, 1.0, 0.0], [0.5, 1.2, 0.1], [1.0, 1.4, 0.2]],   # collinear
                           [[0.2, 0.8, 0.2], [0.2, 0.8, 0.2], [0.6, 1.0, 0.1]]])  # two vertices equal
    return np.concatenate([tris, crossing, edge_on, degenerate])


def ray_hits(dirs, p, tri):
    """Exact float64 ray-triangle hits (t > 0) of rays p + t d, Moller-Trumbore."""
    a, b, c = (np.asarray(v, np.float64) for v in tri)
    e1, e2 = b - a, c - a
    h = np.cross(dirs, e2)
    det = h @ e1
    ok = np.abs(det) > 1e-300
    f = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
    s = p - a
    u = f * (h @ s)
    qv = np.cross(s, e1)
    v = f * (dirs @ qv)
    t = f * (qv @ e2)
    return ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 0)


@pytest.mark.parametrize("grid", [5, 16, 24])
def test_thin_shell_marks_match_twin_and_ray_hits(cl_pair, build_test_kernel, grid):
    """The kernel's triangle marks (pn_isg_mark_triangle, 16 columns per test) are the
    twin's patch by patch, and the twin's are the exact ray-triangle hits from the
    receiver through the patch centres for every triangle it does not skip
    (patches within 1e-5 of a triangle's edge plane excepted). Hard cases: triangles
    crossing the receiver plane, edge-on, degenerate (skipped), own triangles under
    each policy."""
    from isg_shading64 import HALF_PI, frame, patch_mask, triangle_marks, window

    ctx, queue = cl_pair
    rng = np.random.default_rng(400 + grid)
    tris = hard_triangles(rng)
    tri_ow = rng.integers(1, 4, len(tris)).astype(np.uint32)
    lams = (0.5, 3.0, 30.0, 300.0)
    axes = np.array([[*unit(rng.normal(size=3) + [0.0, 1.0, 0.0]), lam] for lam in lams], np.float32)
    pos = np.r_[np.zeros((1, 3)), rng.uniform(-1.5, 1.5, (15, 3)) * [1.0, 0.3, 1.0]]
    nrm = np.array([[0.0, 1.0, 0.0]] + [unit(rng.normal(size=3) + [0.0, 1.0, 0.0]) for _ in range(15)])
    ids = rng.integers(0, 4, len(pos)).astype(np.uint32)
    t4 = np.zeros((len(tris), 3, 4), np.float32)
    t4[..., :3] = tris
    tris32 = t4[..., :3].astype(np.float64)  # what the kernel sees
    cases = len(pos) * len(lams)
    checked = hits = 0
    for policy in (0, 1, 2):
        k = cl.Kernel(build_test_kernel(SHELL_MARK_SOURCE), "mark_shell_test")
        out = run_mark_kernel(ctx, queue, k, (), pos, nrm, ids, axes, len(lams),
                              (t4, tri_ow, np.int32(len(tris)), np.int32(grid), np.int32(policy)))
        bits = ((out[:, :grid, None] >> np.arange(grid, dtype=np.uint32)) & 1).astype(bool)
        for case in range(cases):
            q, li = divmod(case, len(lams))
            axis, lam = axes[li, :3].astype(np.float64), float(axes[li, 3])
            want, inside = patch_mask(axis, lam, pos[q], nrm[q], int(ids[q]), policy, [], [], grid,
                                      shells=(tris32, tri_ow))
            assert not inside and int(out[case, 24]) != 0xFFFFFFFF
            x, y = frame(axis)
            w = window(lam)
            cen = HALF_PI - w + (np.arange(grid) + 0.5) * (2.0 * w / grid)
            th, ph = np.meshgrid(cen, cen, indexing="ij")
            dirs = (np.sin(th) * np.cos(ph))[..., None] * x + np.cos(th)[..., None] * y + \
                (np.sin(th) * np.sin(ph))[..., None] * axis
            edge = np.zeros((grid, grid), bool)
            for tri, o in zip(tris32, tri_ow):
                a, b, c = tri - pos[q]
                for e in (np.cross(b, c), np.cross(c, a), np.cross(a, b)):
                    ne = np.linalg.norm(e)
                    if ne > 0:
                        edge |= np.abs(dirs @ (e / ne)) < 1e-5
                m = triangle_marks(dirs, pos[q], nrm[q], tri, o == ids[q], policy)
                if m is not None:  # the twin's marks are the exact ray hits
                    assert (m == ray_hits(dirs.reshape(-1, 3), pos[q], tri).reshape(grid, grid))[~edge].all()
                    hits += int(m.sum())
            assert (bits[case] == want)[~edge].all(), (policy, case, np.argwhere((bits[case] != want) & ~edge))
            checked += int((~edge).sum())
    assert hits > 20 * grid and checked > 0.9 * 3 * cases * grid * grid


def test_thin_shell_hard_cases_in_the_twin():
    """Degenerate triangles and edge-on ones (plane through the receiver) mark nothing;
    a triangle crossing the receiver plane marks only directions that hit it; the
    receiver on a flat sheet of its own instance is not shadowed by it (policy 1)."""
    from isg_shading64 import HALF_PI, frame, patch_mask, triangle_marks, window

    p, n = np.zeros(3), np.array([0.0, 1.0, 0.0])
    axis = unit([0.2, 1.0, 0.1])
    x, y = frame(axis)
    w = window(2.0)
    cen = HALF_PI - w + (np.arange(16) + 0.5) * (2.0 * w / 16)
    th, ph = np.meshgrid(cen, cen, indexing="ij")
    dirs = (np.sin(th) * np.cos(ph))[..., None] * x + np.cos(th)[..., None] * y + \
        (np.sin(th) * np.sin(ph))[..., None] * axis
    assert triangle_marks(dirs, p, n, np.array([[0, 1, 0], [0.5, 1.2, 0.1], [1.0, 1.4, 0.2]]), False, 1) is None
    assert triangle_marks(dirs, p, n, np.array([[0.5, 0.5, 0], [1, 1, 0], [0.3, 1.2, 0]]), False, 1) is None
    crossing = np.array([[-1.0, -0.5, 0.3], [1.0, -0.5, 0.3], [0.0, 2.0, 0.3]])
    m = triangle_marks(dirs, p, n, crossing, False, 1)
    assert m.any() and (m == ray_hits(dirs.reshape(-1, 3), p, crossing).reshape(16, 16)).all()
    sheet = np.array([[[-3, 0, -3], [3, 0, -3], [3, 0, 3]], [[-3, 0, -3], [3, 0, 3], [-3, 0, 3]]], np.float64)
    q = np.array([0.4, 0.0, -0.2])
    for policy in (0, 1):
        mask, _ = patch_mask(axis, 2.0, q, n, 5, policy, [], [], 16, shells=(sheet, [5, 5]))
        assert not mask.any()


def draped_sheet(n=8, half=1.0):
    """bench/isg_shells.py's draped sheet at n x n quads: (T, 3, 3) triangles."""
    t = np.linspace(-half, half, n + 1)
    x, z = np.meshgrid(t, t, indexing="ij")
    v = np.stack([x, 1.3 - 0.25 * (x * x + z * z) / (half * half), z], -1)
    tris = []
    for i in range(n):
        for j in range(n):
            tris += [[v[i, j], v[i + 1, j + 1], v[i + 1, j]], [v[i, j], v[i, j + 1], v[i + 1, j + 1]]]
    return np.array(tris)


@pytest.mark.parametrize("policy", [0, 1, 2])
def test_thin_shell_shading_matches_twin(cl_pair, build_test_kernel, policy):
    """Shaded pixels under a draped sheet (triangles of instance 7) and spheres, one
    of them overlapping the sheet (a patch covered by both counts once), against the
    twin (shade with shells): floor receivers, diffuse and specular (both paths), and
    receivers on the sheet itself (instance 7, normals up and down) under each
    self-occlusion policy. The sheet darkens the floor; a doubled sheet gives the
    same image (overlaps count once)."""
    tris = draped_sheet()
    owners = np.full(len(tris), 7)
    spheres, sph_owners = [[0.5, 1.25, 0.2, 0.3], [1.8, 0.5, 0.0, 0.3]], [1, 2]
    px = floor_pixels(ks=0.3, material=(1000.0, 0.3, 0.0), xs=np.linspace(-1.5, 2.0, 6), zs=(-0.5, 0.4))
    px += floor_pixels(ks=0.3, material=(30.0, 0.3, 0.0), xs=np.linspace(-1.0, 1.0, 3), zs=(0.0,))
    for x, z, up in ((0.1, 0.2, 1), (-0.6, 0.5, 1), (0.3, -0.4, -1), (0.8, 0.8, 1)):
        y = 1.3 - 0.25 * (x * x + z * z)
        nrm = unit([0.5 * x, 1.0, 0.5 * z]) * up
        px.append({"p": (x, y, z), "n": tuple(nrm), "albedo": (0.6, 0.6, 0.6), "ks": 0.0, "material": (0, 0.3, 0),
                   "id": 7})
    args = dict(self_occlusion=policy, camera=(0.5, 4.0, 5.0), env_sharpness=100.0)
    got = run_kernel(cl_pair, build_test_kernel, px, LOBES, spheres, sph_owners, triangles=tris,
                     triangle_owners=owners, **args)
    tris32 = tris.astype(np.float32).astype(np.float64)
    want = np.array([shade(q["p"], q["n"], q["albedo"], q["ks"], q["material"], args["camera"], q["id"], LOBES,
                           spheres, sph_owners, 16, policy, 1, 100.0, FACES, None, None, (tris32, owners))
                     for q in px])
    check(got, want)
    free = run_kernel(cl_pair, build_test_kernel, px, LOBES, spheres, sph_owners, **args)
    assert (got[:16, :3] < 0.7 * free[:16, :3]).any()  # the sheet shadows the floor
    # The triangles' groups (bounding spheres skipping what cannot mark) give the image of every triangle alone,
    # in the per-lobe windows and in the shared hemisphere grid (whose patches are larger than the triangles).
    alone = run_kernel(cl_pair, build_test_kernel, px, LOBES, spheres, sph_owners, triangles=tris,
                       triangle_owners=owners, shell_groups=False, **args)
    np.testing.assert_array_equal(alone, got)
    shared = [run_kernel(cl_pair, build_test_kernel, px, LOBES, spheres, sph_owners, triangles=tris,
                         triangle_owners=owners, shared=(16, 100.0), shell_groups=g, **args) for g in (True, False)]
    np.testing.assert_array_equal(shared[0], shared[1])
    check(shared[0], np.array([shade(q["p"], q["n"], q["albedo"], q["ks"], q["material"], args["camera"], q["id"],
                                     LOBES, spheres, sph_owners, 16, policy, 1, 100.0, FACES, None, None,
                                     (tris32, owners), shared=(16, 100.0, lobe_cube(LOBES, 100.0), None))
                               for q in px]))
    doubled = run_kernel(cl_pair, build_test_kernel, px, LOBES, spheres, sph_owners, triangles=np.r_[tris, tris],
                         triangle_owners=np.r_[owners, owners], **args)
    np.testing.assert_array_equal(doubled, got)


# ---------------------------------------------------------------- the shared hemisphere grid

def sphere_pixels():
    """Floor pixels and pixels just inside the spheres of SPHERES (their own instances: self-occlusion; on the
    surface itself float32 and float64 may decide "behind the receiver plane" apart)."""
    px = floor_pixels(xs=np.linspace(-1.4, 1.4, 8), zs=(-0.3, 0.2))
    for c, own in zip(SPHERES, OWNERS):
        for d in ([0.3, 1.0, 0.2], [-1.0, 0.2, 0.1], [0.2, -0.1, 1.0]):
            u = unit(d)
            px.append({"p": tuple(np.array(c[:3]) + 0.98 * c[3] * u), "n": tuple(u), "albedo": (0.5, 0.6, 0.7), "ks": 0.0,
                       "material": (0.0, 0.3, 0.0), "id": own})
    return px


@pytest.mark.parametrize("grid,sharpness,policy", [(16, 1e30, 1), (24, 100.0, 1), (31, 1e30, 1), (24, 100.0, 0),
                                                   (24, 100.0, 2), (2, 1e30, 1)])
def test_shared_grid_matches_twin(cl_pair, build_test_kernel, grid, sharpness, policy):
    """shared_grid > 0: the lobes up to shared_sharpness shadowed by one marking of the receiver's hemisphere
    (kernel against the float64 twin, both reading the same lobe cube), the sharper ones (the sun at 300)
    by their own windows; every self-occlusion policy, pixels on the floor and on the occluders."""
    px = sphere_pixels()
    got = run_kernel(cl_pair, build_test_kernel, px, LOBES, SPHERES, OWNERS, self_occlusion=policy,
                     shared=(grid, sharpness))
    want = twin(px, LOBES, SPHERES, OWNERS, self_occlusion=policy, shared=(grid, sharpness))
    check(got, want)
    if grid >= 16:  # it shadows, and differs from the per-lobe windows by the discretisation only
        per_lobe = twin(px, LOBES, SPHERES, OWNERS, self_occlusion=policy)
        free = twin(px, LOBES, [], [], self_occlusion=policy)
        assert (want < 0.9 * free).any()
        assert np.abs(want - per_lobe).max() < 0.1 * free.max()


def env_irradiance_map(lobes, m=9, extra=0.15):
    """A vertex-grid irradiance cube of m a side: the lobes' summed closed forms plus light that no lobe
    carries (extra (1 + d.y)), as an env's irradiance map would differ from its K-lobe fit."""
    from isg_shading64 import gamma_vertices, irradiance
    d = gamma_vertices(m)
    e = np.array([sum(irradiance(lobe[:3], lobe[3], lobe[4:7], v) for lobe in lobes) for v in d])
    return e + extra * (1.0 + d[:, 1:2]) * np.array([1.0, 0.9, 0.8]), m


@pytest.mark.parametrize("grid,sharpness,policy", [(16, 100.0, 1), (24, 1e30, 1), (16, 100.0, 2)])
def test_shared_light_env_irradiance_matches_twin(cl_pair, build_test_kernel, grid, sharpness, policy):
    """shared_light 1: the shared lobes' unshadowed irradiance is the env's irradiance map at n minus the
    closed forms of the lobes with their own windows (the sun at 300 when shared_sharpness is 100), the kernel
    against the twin. Fails when the own-window lobes are not subtracted (+ the sun's irradiance, counted
    twice) or the map is ignored (- the extra light)."""
    px = sphere_pixels()
    irr = env_irradiance_map(LOBES)
    got = run_kernel(cl_pair, build_test_kernel, px, LOBES, SPHERES, OWNERS, self_occlusion=policy,
                     shared=(grid, sharpness), irradiance=irr)
    want = twin(px, LOBES, SPHERES, OWNERS, self_occlusion=policy, shared=(grid, sharpness), irradiance=irr)
    check(got, want)
    lobes_only = twin(px, LOBES, SPHERES, OWNERS, self_occlusion=policy, shared=(grid, sharpness))
    assert (want > lobes_only + 0.02).any()  # the light no lobe carries shows
    # With a map of the lobes' own irradiance (no extra), shared_light 1 is shared_light 0 up to the map's
    # bilinear error and the closed form's bound.
    same = run_kernel(cl_pair, build_test_kernel, px, LOBES, SPHERES, OWNERS, self_occlusion=policy,
                      shared=(grid, sharpness), irradiance=env_irradiance_map(LOBES, m=33, extra=0.0))
    np.testing.assert_allclose(same[:, :3], lobes_only, rtol=0.02, atol=0.01 * float(lobes_only.max()))


@pytest.mark.parametrize("sharpness", [1e30, 100.0])
def test_lobe_cubes_match_twin(cl_pair, build_test_kernel, sharpness):
    """isg_lobe_cubes: L_b at every vertex against the twin's float64 lobe_cube, E_b at sampled vertices
    against the exact SG x clamped cosine summed over the same lobes (the closed form's 0.4 % and float32),
    and both read back through the twin's bilinear lookup off the vertices."""
    ctx, queue = cl_pair
    lb = np.zeros((len(LOBES), 8), np.float32)
    lb[:, :4], lb[:, 4:7] = LOBES[:, :4], LOBES[:, 4:7]
    buf = device_lobe_cubes(cl_pair, build_test_kernel, lb, sharpness)
    got = np.empty((12 * LOBE_CUBE_N ** 2, 4), np.float32)
    cl.enqueue_copy(queue, got, buf)
    want_l = lobe_cube(LOBES, sharpness)
    np.testing.assert_allclose(got[:len(want_l), :3], want_l, rtol=1e-4, atol=1e-6 * want_l.max())
    from isg_shading64 import gamma_vertices, grid_lookup, irradiance
    d = gamma_vertices(LOBE_CUBE_N)
    keep = [lobe for lobe in LOBES if lobe[3] <= sharpness]
    # The closed form's bound, 0.40 % of E(1) per lobe (docs/isg.md 3.3), summed over the lobes (+ float32).
    bound = 0.0041 * sum(np.asarray(lobe[4:7]) * irradiance(lobe[:3], lobe[3], 1.0, lobe[:3]) for lobe in keep)
    for v in np.random.default_rng(5).choice(len(d), 40, replace=False):
        want = sum(irradiance(lobe[:3], lobe[3], lobe[4:7], d[v]) for lobe in keep)
        assert (np.abs(got[len(want_l) + v, :3] - want) <= bound).all(), (got[len(want_l) + v, :3], want, bound)
    e_cube = got[len(want_l):, :3].astype(np.float64)
    for u in np.random.default_rng(6).normal(size=(30, 3)):  # between vertices: E_b is smooth, bilinear is close
        u = u / np.linalg.norm(u)
        want = sum(irradiance(lobe[:3], lobe[3], lobe[4:7], u) for lobe in keep)
        assert (np.abs(grid_lookup(e_cube, LOBE_CUBE_N, u) - want) <= bound + 2e-3 * want).all()


def test_shared_grid_wrong_solid_angle_or_cosine_fails():
    """The twin's occluded irradiance is the exact visible integral's complement: under a sphere in a
    constant-radiance sky (one lobe of sharpness ~0 through the grid) the occluded irradiance is
    L pi sin^2(alpha) cos(theta) (a cap above the horizon). The cells quantise the cap (measured: up to 7 %
    at M_s = 24-31 on these caps, 2.7 % at 64, 1 % at 128), so the bound is checked at M_s = 128 (the twin
    has no word-per-row limit). A wrong patch solid angle or cosine fails."""
    p, n = np.zeros(3), np.array([0.0, 1.0, 0.0])
    for c, r in (([0.0, 2.0, 0.0], 0.8), ([1.2, 1.5, 0.3], 0.6), ([-2.0, 1.0, 1.0], 0.9)):
        c = np.array(c)
        d = np.linalg.norm(c)
        want = math.pi * (r / d) ** 2 * (c[1] / d)
        o, inside = shared_occluded(p, n, 0, 1, [[*c, r]], [1], 128, None, light=lambda _: np.ones(3))
        assert not inside
        assert abs(o[0] - want) < 0.015 * want, (o[0], want)


def test_shared_grid_converges_to_the_exact_visible_integral():
    """The twin's shared-grid diffuse (exact lobe sum in place of the cube) against the dense quadrature with
    exact ray-sphere tests: the grid's error falls with M_s; the cube's lookup error is small."""
    p, n = np.array([0.2, 0.0, 0.1]), np.array([0.0, 1.0, 0.0])
    lobes = LOBES[1:3]  # the sky and the low bright region, both above the horizon
    exact = sum(visible_exact(lb[:3], lb[3], lb[4:7], p, n, SPHERES) for lb in lobes)
    light = lambda d: sum(lb[4:7] * math.exp(lb[3] * (d @ lb[:3] - 1.0)) for lb in lobes)  # noqa: E731
    from isg_shading64 import irradiance
    free = sum(irradiance(lb[:3], lb[3], lb[4:7], n) for lb in lobes)
    errs = []
    for grid in (8, 16, 31):
        o, _ = shared_occluded(p, n, 0, 1, SPHERES, [1, 1, 2], grid, None, light=light)
        errs.append(np.abs(free - o - exact).max() / exact.max())
    assert errs[-1] < 0.01 and errs[-1] < errs[0], errs
    cube = lobe_cube(lobes, 1e30)
    o_cube, _ = shared_occluded(p, n, 0, 1, SPHERES, [1, 1, 2], 31, cube)
    o_exact, _ = shared_occluded(p, n, 0, 1, SPHERES, [1, 1, 2], 31, None, light=light)
    np.testing.assert_allclose(o_cube, o_exact, rtol=2e-3)
