"""Sphere sets of the isg method (capi/src/assets/sphere_set.c, docs/isg.md
section 7): the builder on shapes with known solids (a sphere, a box, a
torus) and on the Stanford bunny, its reported error against an independent
numpy measurement, the cache, N = 1, degenerate meshes, the caller's
spheres (NaN/Inf/negative radii refused) and where sets may attach."""

from __future__ import annotations

import math

import numpy as np
import pytest

from penumbra import Mesh, PenumbraError, Scene, procedural
from penumbra.meshio import load_mesh
from penumbra.methods.isg import SphereSet


@pytest.fixture(scope="module")
def shapes(ctx):
    out = {"sphere": procedural.sphere(1.0, 4), "box": procedural.box((2.0, 1.0, 0.5)),
           "torus": procedural.torus(1.0, 0.3, segments=48, tube_segments=24)}
    return {k: (v, Mesh(ctx, v.vertices, v.faces)) for k, v in out.items()}


@pytest.fixture(scope="module")
def bunny(ctx, shared_data):
    d = load_mesh(shared_data / "meshes" / "bunny_odedstein_3k.obj")
    return d, Mesh(ctx, d.vertices, d.faces)


def covered(points, spheres):
    s = np.asarray(spheres, np.float64)
    d2 = ((points[:, None, :] - s[None, :, :3]) ** 2).sum(-1)
    return (d2 <= s[None, :, 3] ** 2).any(1)


def union_shares(inside_fn, lo, hi, spheres, n=200_000, seed=1):
    """(outside, missed) shares of the solid's volume by Monte Carlo in the box."""
    rng = np.random.default_rng(seed)
    p = rng.uniform(lo, hi, (n, 3))
    inside = inside_fn(p)
    cov = covered(p, spheres)
    return (cov & ~inside).sum() / inside.sum(), (inside & ~cov).sum() / inside.sum()


def test_one_sphere_of_a_sphere_is_that_sphere(shapes):
    _, mesh = shapes["sphere"]
    s = SphereSet.build(mesh, 1)
    (x, y, z, r), = s.spheres()
    assert math.dist((x, y, z), (0, 0, 0)) < 0.03
    assert abs(r - 1.0) < 0.04  # the icosphere's solid is slightly inside the unit sphere; one voxel is 0.03
    info = s.info()
    assert info["count"] == 1 and info["outside_share"] < 0.05 and info["missed_share"] < 0.05
    assert abs(info["mesh_volume"] - 4.0 / 3.0 * math.pi) < 0.05 * 4.0 / 3.0 * math.pi


@pytest.mark.parametrize("name,inside", [
    ("box", lambda p: (np.abs(p[:, 0]) <= 1.0) & (np.abs(p[:, 1]) <= 0.5) & (np.abs(p[:, 2]) <= 0.25)),
    ("torus", lambda p: (np.hypot(p[:, 0], p[:, 2]) - 1.0) ** 2 + p[:, 1] ** 2 <= 0.09),
])
def test_reported_error_matches_an_independent_measurement(shapes, name, inside):
    """The library's grid estimate of the union's outside / missed volume
    agrees with Monte Carlo against the analytic solid (within the voxel
    discretisation: about one cell layer over the surface, ~0.03)."""
    _, mesh = shapes[name]
    s = SphereSet.build(mesh, 32)
    sp = s.spheres()
    out, miss = union_shares(inside, (-1.4, -0.6, -1.4), (1.4, 0.6, 1.4), sp)
    info = s.info()
    assert abs(info["outside_share"] - out) < 0.04, (info, out)
    assert abs(info["missed_share"] - miss) < 0.04, (info, miss)


def test_built_sets_stay_near_the_solid(shapes):
    """The builder's balls are inscribed and then grown by at most 2 cells:
    no sphere reaches past the analytic surface of the box or the torus by
    more than 3 cells (the 2, half a cell of the distance estimate, half a
    cell of the voxelised surface), and the union's outside volume
    (Monte Carlo) stays small (the variational sets this builder replaced
    had 15-25 % of the solid outside at every N)."""
    box, torus = shapes["box"][1], shapes["torus"][1]
    for mesh, lo, hi, depth, inside in (
            (box, (-1.4, -0.6, -1.4), (1.4, 0.6, 1.4),
             lambda c: np.min([1.0 - np.abs(c[:, 0]), 0.5 - np.abs(c[:, 1]), 0.25 - np.abs(c[:, 2])], axis=0),
             lambda p: (np.abs(p[:, 0]) <= 1.0) & (np.abs(p[:, 1]) <= 0.5) & (np.abs(p[:, 2]) <= 0.25)),
            (torus, (-1.4, -0.6, -1.4), (1.4, 0.6, 1.4),
             lambda c: 0.3 - np.hypot(np.hypot(c[:, 0], c[:, 2]) - 1.0, c[:, 1]),
             lambda p: (np.hypot(p[:, 0], p[:, 2]) - 1.0) ** 2 + p[:, 1] ** 2 <= 0.09)):
        for n in (8, 32, 128):
            s = SphereSet.build(mesh, n)
            sp = s.spheres().astype(np.float64)
            cell = (2.6 if mesh is torus else 2.0) / 64.0  # the longest side over 64
            poke = sp[:, 3] - depth(sp[:, :3])
            assert poke.max() <= 3.0 * cell, (n, poke.max() / cell)
            # The skin, (g + 1/2) cells of the build grid (the isg method's self_push): -1/4 <= g <= 2, on
            # a grid of at least 64 cells along the longest side; the same from the set cache.
            skin = s.info()["skin"]
            assert 0.0 < skin <= 2.5 * cell and skin == SphereSet.build(mesh, n).info()["skin"], (n, skin / cell)
            out, miss = union_shares(inside, lo, hi, sp)
            assert out < 0.08, (n, out, miss)


def test_tight_bunny_sets_keep_little_outside(bunny):
    """On the bunny the union's outside volume stays under 5 % of the solid
    at every N (the variational sets: 14-18 % from N = 16 up) while the
    missed share still falls with N."""
    _, mesh = bunny
    info = {n: SphereSet.build(mesh, n).info() for n in (16, 64, 256)}
    for n, i in info.items():
        assert i["outside_share"] < 0.05, (n, i)
    assert info[16]["missed_share"] > info[64]["missed_share"] > info[256]["missed_share"]


def test_bunny_error_falls_with_more_spheres(bunny):
    _, mesh = bunny
    missed = [SphereSet.build(mesh, n).info()["missed_share"] for n in (8, 32, 128)]
    assert missed[0] > missed[1] > missed[2]
    assert missed[2] < 0.05


def test_build_is_cached_by_mesh_and_count(ctx, bunny):
    d, mesh = bunny
    a = SphereSet.build(mesh, 24).spheres()
    again = Mesh(ctx, d.vertices, d.faces)  # another mesh object, same content hash
    b = SphereSet.build(again, 24)
    np.testing.assert_array_equal(a, b.spheres())
    assert SphereSet.build(mesh, 25).info()["count"] == 25


def test_degenerate_meshes_are_refused(ctx):
    flat = procedural.plane((2.0, 2.0), 2)
    with pytest.raises(PenumbraError, match="flat"):
        SphereSet.build(Mesh(ctx, flat.vertices, flat.faces), 8)
    # a closed surface folded onto itself: every triangle twice, opposite windings: no inside
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], np.float32)
    f = np.array([[0, 1, 2], [0, 2, 1]], np.uint32)
    with pytest.raises(PenumbraError, match="encloses"):
        SphereSet.build(Mesh(ctx, v, f), 4)
    box = procedural.box((1, 1, 1))
    with pytest.raises(PenumbraError, match="1 to 4096"):
        SphereSet.build(Mesh(ctx, box.vertices, box.faces), 5000)


@pytest.mark.parametrize("bad,what", [
    ([[0, 0, 0, -1.0]], "radius"), ([[0, 0, 0, 0.0]], "radius"), ([[np.nan, 0, 0, 1.0]], "non-finite"),
    ([[0, 0, 0, np.inf]], "radius"), ([[0, 0, 1, 1], [0, np.inf, 0, 1.0]], "sphere 1"),
])
def test_bad_caller_spheres_are_refused(ctx, bad, what):
    with pytest.raises(PenumbraError, match=what):
        SphereSet.from_spheres(ctx, bad)


def test_caller_spheres_round_trip_and_empty_is_refused(ctx):
    sp = np.array([[0, 1, 2, 0.5], [3, 4, 5, 1.5]], np.float32)
    s = SphereSet.from_spheres(ctx, sp)
    np.testing.assert_array_equal(s.spheres(), sp)
    info = s.info()
    assert info["mesh_hash"] is None and math.isnan(info["outside_share"]) and info["skin"] == 0.0
    with pytest.raises(PenumbraError, match="0 spheres"):
        SphereSet.from_spheres(ctx, np.zeros((0, 4), np.float32))


def test_where_sets_attach(ctx, shapes):
    (_, sphere_mesh), (_, box_mesh) = shapes["sphere"], shapes["box"]
    scene = Scene(ctx)
    a = scene.add(sphere_mesh, np.eye(4))
    b = scene.add(box_mesh, np.eye(4))
    built = SphereSet.build(sphere_mesh, 4)
    scene.attach(a, built)
    with pytest.raises(PenumbraError, match="built for mesh"):
        scene.attach(b, built)
    mine = SphereSet.from_spheres(ctx, [[0, 0, 0, 1.0]])
    scene.attach(b, mine)
    with pytest.raises(PenumbraError, match="whole scene"):
        scene.attach(0xFFFFFFFF, mine)


def test_deform_follows_an_affine_motion_exactly(ctx, bunny):
    """Centres are affine combinations of vertices (weights summing to 1) and
    radii scale with the vertices' spread: a scale + rotation + translation
    of the mesh moves the spheres exactly so."""
    d, mesh = bunny
    s = SphereSet.build(mesh, 32)
    rest = s.spheres().astype(np.float64)
    a = math.radians(30.0)
    rot = np.array([[math.cos(a), 0, math.sin(a)], [0, 1, 0], [-math.sin(a), 0, math.cos(a)]])
    moved = (1.7 * np.asarray(d.vertices, np.float64) @ rot.T + [0.3, -1.0, 2.0]).astype(np.float32)
    target = Mesh(ctx, moved, d.faces)
    s.deform(target)
    got = s.spheres().astype(np.float64)
    np.testing.assert_allclose(got[:, :3], 1.7 * rest[:, :3] @ rot.T + [0.3, -1.0, 2.0], atol=2e-4)
    np.testing.assert_allclose(got[:, 3], 1.7 * rest[:, 3], rtol=1e-4)
    # the set now belongs to the deformed mesh: it attaches there
    scene = Scene(ctx)
    scene.attach(scene.add(target, np.eye(4)), s)


def test_deform_of_a_bend_keeps_covering_the_solid(ctx, shapes):
    """A torus bent out of its plane: the deformed set misses little more of the
    bent solid than a set rebuilt for it (both measured on the rebuilt grid by
    Monte Carlo of points inside the bent tube)."""
    t, mesh = shapes["torus"]
    s = SphereSet.build(mesh, 48)
    v = np.asarray(t.vertices, np.float64).copy()
    v[:, 1] += 0.4 * v[:, 0] ** 2  # a parabolic bend
    bent = Mesh(ctx, v.astype(np.float32), t.faces)
    s.deform(bent)
    rebuilt = SphereSet.build(bent, 48)

    def inside(p):  # the bent tube: undo the bend, then the torus test
        q = p.copy()
        q[:, 1] -= 0.4 * q[:, 0] ** 2
        return (np.hypot(q[:, 0], q[:, 2]) - 1.0) ** 2 + q[:, 1] ** 2 <= 0.09

    _, miss_deformed = union_shares(inside, (-1.4, -0.4, -1.4), (1.4, 1.2, 1.4), s.spheres())
    _, miss_rebuilt = union_shares(inside, (-1.4, -0.4, -1.4), (1.4, 1.2, 1.4), rebuilt.spheres())
    assert miss_deformed < miss_rebuilt + 0.05, (miss_deformed, miss_rebuilt)


def test_deform_refuses_what_it_cannot_follow(ctx, shapes, bunny):
    _, mesh = bunny
    s = SphereSet.build(mesh, 8)
    _, box = shapes["box"]
    with pytest.raises(PenumbraError, match="vertices"):
        s.deform(box)
    mine = SphereSet.from_spheres(ctx, [[0, 0, 0, 1.0]])
    with pytest.raises(PenumbraError, match="anchors"):
        mine.deform(mesh)
