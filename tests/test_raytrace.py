"""Scene.intersect / Scene.occluded against a float64 numpy brute force.

The reference is a vectorised Möller–Trumbore test over all rays x all
triangles, in float64, on exactly the float32 inputs the library sees
(positions, transforms and rays are rounded to float32 before the reference
uses them), so the only differences are the library's own float32 rounding.

Tolerances (one place):
  EDGE_EPS  rays whose float64 crossing lies within this barycentric distance
            (relative to the triangle) of an edge of some triangle they cross
            the plane of are ambiguous: float32 rounding may legitimately put
            them on either side; they are excluded and counted.
  T_RTOL    relative tolerance on t.
  TIE_RTOL  the nearest hit is "unambiguous" when the second-nearest differs
            by more than this (relative), so the triangle/instance id is defined.
"""

from __future__ import annotations

import numpy as np
import pytest

from penumbra import BACKGROUND, InputError, Mesh, PenumbraError, Scene, procedural

EDGE_EPS = 1e-5
T_RTOL = 1e-4
TIE_RTOL = 1e-4


# --------------------------------------------------------------------------- float64 reference


def f32(a) -> np.ndarray:
    """float32-rounded copy as float64: the exact values the library receives."""
    return np.asarray(a, dtype=np.float32).astype(np.float64)


class Reference:
    """Brute-force closest hits of rays against a triangle list (float64).

    t: nearest t in (tmin, tmax) (inf on a miss); tri: index into the list of
    the nearest triangle (-1 on a miss); t2: second-nearest t (inf if none);
    near_edge: the ray crosses the plane of some triangle (t in range) within
    edge_eps (barycentric) of its boundary; near_bound: some hit (ignoring
    tmin/tmax) lies within T_RTOL of tmin or tmax."""

    def __init__(self, origins, directions, v0, v1, v2, tmin=0.0, tmax=np.inf, edge_eps=EDGE_EPS, chunk=128):
        o = f32(origins)
        d = f32(directions)
        v0, v1, v2 = f32(v0), f32(v1), f32(v2)
        n = len(o)
        tmin = np.broadcast_to(f32(tmin), (n,))
        tmax = np.broadcast_to(f32(tmax), (n,))
        e1, e2 = v1 - v0, v2 - v0
        nondegenerate = np.linalg.norm(np.cross(e1, e2), axis=1) > 0.0
        self.t = np.full(n, np.inf)
        self.t2 = np.full(n, np.inf)
        self.tri = np.full(n, -1, np.int64)
        self.near_edge = np.zeros(n, bool)
        self.near_bound = np.zeros(n, bool)
        for s in range(0, n, chunk):
            oo, dd = o[s:s + chunk], d[s:s + chunk]
            p = np.cross(dd[:, None, :], e2[None, :, :])
            det = np.einsum("rtk,tk->rt", p, e1)
            sv = oo[:, None, :] - v0[None, :, :]
            q = np.cross(sv, e1[None, :, :])
            with np.errstate(divide="ignore", invalid="ignore"):
                inv = 1.0 / det
                u = np.einsum("rtk,rtk->rt", sv, p) * inv
                v = np.einsum("rk,rtk->rt", dd, q) * inv
                t = np.einsum("tk,rtk->rt", e2, q) * inv
            w = 1.0 - u - v
            plane = nondegenerate[None, :] & (det != 0.0) & np.isfinite(t)
            bmin = np.minimum(np.minimum(u, v), w)
            inside_any = plane & (bmin >= 0.0)
            lo, hi = tmin[s:s + chunk, None], tmax[s:s + chunk, None]
            in_range = (t > lo) & (t < hi)
            hits = np.where(inside_any & in_range, t, np.inf)
            order = np.argsort(hits, axis=1)
            rows = np.arange(len(oo))
            first, second = order[:, 0], order[:, 1] if hits.shape[1] > 1 else order[:, 0]
            self.t[s:s + chunk] = hits[rows, first]
            self.tri[s:s + chunk] = np.where(np.isfinite(hits[rows, first]), first, -1)
            if hits.shape[1] > 1:
                self.t2[s:s + chunk] = hits[rows, second]
            self.near_edge[s:s + chunk] = (plane & in_range & (np.abs(bmin) < edge_eps)).any(axis=1)
            scale = np.maximum(np.abs(t), 1e-30)
            self.near_bound[s:s + chunk] = (inside_any & ((np.abs(t - lo) < T_RTOL * scale) |
                                                          (np.abs(t - hi) < T_RTOL * scale))).any(axis=1)

    @property
    def hit(self) -> np.ndarray:
        return np.isfinite(self.t)

    @property
    def unambiguous(self) -> np.ndarray:
        """Nearest hit clearly nearer than the second one (ids well defined)."""
        with np.errstate(invalid="ignore"):  # inf - inf on misses
            return self.hit & (self.t2 - self.t > TIE_RTOL * np.abs(self.t))


def rel_err(a, b) -> np.ndarray:
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    return np.abs(a - b) / np.maximum(np.abs(b), 1e-30)


def transform_points(m: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Rows p by the 3x4 (float32-rounded) matrix m, in float64."""
    m = f32(m)
    return p @ m[:, :3].T + m[:, 3]


def rotation(axis, angle) -> np.ndarray:
    a = np.asarray(axis, np.float64)
    a = a / np.linalg.norm(a)
    k = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k


def affine(linear, translation) -> np.ndarray:
    return np.hstack([np.asarray(linear, np.float64), np.asarray(translation, np.float64)[:, None]])


def unit(v) -> np.ndarray:
    v = np.asarray(v, np.float64)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def random_units(rng, n) -> np.ndarray:
    return unit(rng.normal(size=(n, 3)))


def single_instance_scene(ctx, vertices, faces, normals=None) -> Scene:
    scene = Scene(ctx)
    scene.add(Mesh(ctx, vertices, faces, normals))
    scene.commit()
    return scene


# --------------------------------------------------------------------------- (a) triangle soup


@pytest.fixture(scope="module")
def soup(ctx):
    rng = np.random.default_rng(1234)
    n_tri = 300
    centres = rng.uniform(-1.0, 1.0, size=(n_tri, 1, 3))
    tris = (centres + rng.normal(scale=0.25, size=(n_tri, 3, 3))).astype(np.float32)
    vertices = tris.reshape(-1, 3)
    faces = np.arange(3 * n_tri, dtype=np.uint32).reshape(-1, 3)
    n_rays = 3000
    # Two thirds of the rays from outside the cloud aimed into it, one third
    # starting inside it in random directions; lengths of the direction vary
    # (the API does not require unit directions: t is in their units).
    n_out = 2 * n_rays // 3
    origins = np.concatenate([4.0 * random_units(rng, n_out), rng.uniform(-1.2, 1.2, size=(n_rays - n_out, 3))])
    aims = rng.uniform(-1.2, 1.2, size=(n_out, 3))
    directions = np.concatenate([unit(aims - origins[:n_out]), random_units(rng, n_rays - n_out)])
    directions *= rng.uniform(0.3, 3.0, size=(n_rays, 1))
    origins, directions = origins.astype(np.float32), directions.astype(np.float32)
    scene = single_instance_scene(ctx, vertices, faces)
    return {"scene": scene, "tris": tris, "origins": origins, "directions": directions, "rng": rng}


def soup_reference(soup, **kw) -> Reference:
    t = soup["tris"]
    return Reference(soup["origins"], soup["directions"], t[:, 0], t[:, 1], t[:, 2], **kw)


@pytest.fixture(scope="module")
def soup_ref(soup):
    return soup_reference(soup)


def test_soup_hits_match_brute_force(soup, soup_ref):
    ref = soup_ref
    t, inst, tri = soup["scene"].intersect(soup["origins"], soup["directions"])
    n = len(t)
    clear = ~ref.near_edge
    excluded = n - clear.sum()
    # The ambiguous band is thin: only a few rays per thousand may fall into it.
    assert excluded <= 0.01 * n, f"{excluded} of {n} rays excluded as near an edge"
    assert 0.3 * n < ref.hit.sum() < 0.95 * n, "the ray set should mix hits and misses"

    lib_hit = np.isfinite(t)
    bad = clear & (lib_hit != ref.hit)
    assert not bad.any(), (f"{bad.sum()} rays disagree on hit/miss, e.g. ray {np.flatnonzero(bad)[:5]}: "
                           f"library t {t[bad][:5]}, reference t {ref.t[bad][:5]}")
    # Misses report inf and BACKGROUND ids.
    assert np.all(inst[~lib_hit] == BACKGROUND) and np.all(tri[~lib_hit] == BACKGROUND)
    assert np.all(inst[lib_hit] == 0)

    both = lib_hit & ref.hit
    err = rel_err(t[both], ref.t[both])
    assert err.max() < T_RTOL, f"max relative t error {err.max():.3g}"

    # Near-edge rays that both report as hits must still agree on t (a
    # neighbouring triangle would be at another distance only in a soup, so
    # only the t of the triangle actually reported is checked via ids below).
    ids = both & ref.unambiguous & clear
    assert ids.sum() > 0.25 * n
    wrong = ids & (tri.astype(np.int64) != ref.tri)
    assert not wrong.any(), f"{wrong.sum()} rays report another triangle, e.g. {np.flatnonzero(wrong)[:5]}"


def test_soup_occluded_matches_brute_force(soup, soup_ref):
    occ = soup["scene"].occluded(soup["origins"], soup["directions"])
    clear = ~soup_ref.near_edge
    bad = clear & (occ != soup_ref.hit)
    assert not bad.any(), f"{bad.sum()} rays: occluded disagrees with the reference"


# --------------------------------------------------------------------------- (e) tmin / tmax


def test_tmin_tmax_honoured(soup):
    rng = np.random.default_rng(99)
    o, d = soup["origins"], soup["directions"]
    n = len(o)
    full = soup_reference(soup)
    # Bounds around the unbounded nearest hit so that many rays have their
    # nearest hit cut off by tmin or beyond tmax; misses get random bounds.
    base = np.where(full.hit, full.t, rng.uniform(0.5, 5.0, n))
    tmin = (base * rng.uniform(0.0, 1.6, n)).astype(np.float32)
    tmax = (tmin + base * rng.uniform(0.05, 2.0, n)).astype(np.float32)
    tmin[: n // 10] = 0.0
    tmax[n // 10: n // 5] = np.inf
    ref = soup_reference(soup, tmin=tmin, tmax=tmax)
    t, inst, tri = soup["scene"].intersect(o, d, tmin=tmin, tmax=tmax)
    clear = ~ref.near_edge & ~ref.near_bound
    assert clear.sum() > 0.95 * n
    lib_hit = np.isfinite(t)
    # The bounds must actually matter: many unbounded hits are cut off.
    assert (full.hit & ~ref.hit & clear).sum() > 0.2 * n
    bad = clear & (lib_hit != ref.hit)
    assert not bad.any(), f"{bad.sum()} rays disagree on hit/miss with tmin/tmax"
    both = clear & lib_hit & ref.hit
    assert rel_err(t[both], ref.t[both]).max() < T_RTOL
    assert np.all(t[lib_hit] > tmin[lib_hit]) and np.all(t[lib_hit] < tmax[lib_hit])

    # occluded == (closest t beyond tmin) < tmax, for the same rays.
    occ = soup["scene"].occluded(o, d, tmin=tmin, tmax=tmax)
    t_from_tmin, _, _ = soup["scene"].intersect(o, d, tmin=tmin)
    expect = t_from_tmin < tmax
    bad = clear & (occ != expect)
    assert not bad.any(), f"{bad.sum()} rays: occluded != (closest t < tmax)"
    assert np.array_equal(occ[clear], ref.hit[clear])


# --------------------------------------------------------------------------- (b) watertightness


def incidence(mesh):
    """Unique positions, faces in unique-position ids, per-vertex and per-edge incident faces."""
    v = mesh.vertices.astype(np.float64)
    uniq, inv = np.unique(v, axis=0, return_inverse=True)
    fu = inv.reshape(-1)[mesh.faces.astype(np.int64)]
    edges = np.sort(fu[:, [[0, 1], [1, 2], [2, 0]]].reshape(-1, 2), axis=1)
    uedges, einv = np.unique(edges, axis=0, return_inverse=True)
    einv = einv.reshape(-1)
    edge_faces = [[] for _ in range(len(uedges))]
    for k, e in enumerate(einv):
        edge_faces[e].append(k // 3)
    vert_faces = [[] for _ in range(len(uniq))]
    for f, tri in enumerate(fu):
        for a in set(tri.tolist()):
            vert_faces[a].append(f)
    return uniq, fu, uedges, edge_faces, vert_faces


def aimed_rays(mesh, rng, closed: bool):
    """Rays from random outside origins aimed at every vertex and every edge
    midpoint, each from a side where the continuation of the ray enters the
    surface (origin strictly in front of all faces incident to the target), so
    a correct tracer must hit one of the incident faces at the target."""
    uniq, fu, uedges, edge_faces, vert_faces = incidence(mesh)
    p = uniq[fu]
    fn = unit(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]))
    boundary_edges = np.array([len(f) == 1 for f in edge_faces])
    if closed:
        assert not boundary_edges.any(), "mesh expected closed"
        assert all(len(f) == 2 for f in edge_faces)
    boundary_verts = set(uedges[boundary_edges].ravel().tolist())
    targets, incident = [], []
    for a, faces in enumerate(vert_faces):
        if a not in boundary_verts:
            targets.append(uniq[a])
            incident.append(faces)
    for (a, b), faces in zip(uedges, edge_faces):
        if len(faces) == 2:
            targets.append(0.5 * (uniq[a] + uniq[b]))
            incident.append(faces)
    origins, dirs = [], []
    for target, faces in zip(targets, incident):
        normals = fn[faces]
        mean = unit(normals.sum(axis=0))
        for _ in range(100):
            w = unit(mean + 0.6 * random_units(rng, 1)[0])
            if (normals @ w).min() > 0.1:
                break
        else:
            raise AssertionError("no origin direction found")
        origins.append(target + rng.uniform(1.5, 4.0) * w)
    origins = np.array(origins, np.float32)
    targets = np.array(targets)
    dirs = unit(targets - f32(origins)).astype(np.float32)
    return origins, dirs, targets, incident


@pytest.mark.parametrize("name", ["sphere", "box", "plane"])
def test_watertight_vertices_and_edges(ctx, name):
    rng = np.random.default_rng({"sphere": 1, "box": 2, "plane": 3}[name])
    mesh = {"sphere": lambda: procedural.sphere(1.0, 3), "box": lambda: procedural.box((1.0, 0.75, 1.5)),
            "plane": lambda: procedural.plane((10.0, 10.0), 8)}[name]()
    scene = single_instance_scene(ctx, mesh.vertices, mesh.faces, mesh.normals)
    origins, dirs, targets, incident = aimed_rays(mesh, rng, closed=name != "plane")
    t, inst, tri = scene.intersect(origins, dirs)
    miss = ~np.isfinite(t)
    assert not miss.any(), f"{miss.sum()} of {len(t)} rays aimed at a vertex/edge slipped through, e.g. targets " \
                           f"{targets[miss][:3]}"
    expect = np.linalg.norm(targets - f32(origins), axis=1)
    err = rel_err(t, expect)
    assert err.max() < T_RTOL, f"max relative t error {err.max():.3g} at target {targets[err.argmax()]}"
    # The reported triangle is one of those that meet at the target.
    not_incident = [i for i, faces in enumerate(incident) if tri[i] not in faces]
    assert not not_incident, f"{len(not_incident)} rays report a triangle not touching the target"
    assert np.all(inst == 0)


@pytest.mark.parametrize("name", ["box", "plane"])
def test_watertight_exact_rays(ctx, name):
    """Rays whose origin and direction are exact in float32 and pass exactly
    through a vertex or edge midpoint (the case a non-watertight test loses)."""
    mesh = procedural.box((1.0, 1.0, 1.0)) if name == "box" else procedural.plane((10.0, 10.0), 8)
    scene = single_instance_scene(ctx, mesh.vertices, mesh.faces)
    uniq, fu, uedges, edge_faces, vert_faces = incidence(mesh)
    p = uniq[fu]
    fn = unit(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]))
    boundary = set(uedges[[len(f) == 1 for f in edge_faces]].ravel().tolist())
    targets, incident = [], []
    for a, faces in enumerate(vert_faces):
        if a not in boundary:
            targets.append(uniq[a])
            incident.append(faces)
    for (a, b), faces in zip(uedges, edge_faces):
        if len(faces) == 2:
            targets.append(0.5 * (uniq[a] + uniq[b]))
            incident.append(faces)
    # Small integer directions (exact), origin = target + 2 w (exact: targets
    # are multiples of 1/8 here), direction -w: t = 2 exactly.
    cand = np.array([[a, b, c] for a in range(-2, 3) for b in range(-2, 3) for c in range(-2, 3)
                     if (a, b, c) != (0, 0, 0)], np.float64)
    origins, dirs = [], []
    for target, faces in zip(targets, incident):
        ok = cand[(fn[faces] @ unit(cand).T).min(axis=0) > 0.1]
        for w in ok:
            origins.append(target + 2.0 * w)
            dirs.append(-w)
    origins, dirs = np.array(origins), np.array(dirs)
    assert np.array_equal(f32(origins), origins) and len(origins) > 200
    t, _, _ = scene.intersect(origins, dirs)
    miss = ~np.isfinite(t)
    assert not miss.any(), f"{miss.sum()} of {len(t)} exact rays through vertices/edges missed, e.g. origin " \
                           f"{origins[miss][:2]} direction {dirs[miss][:2]}"
    assert rel_err(t, 2.0).max() < T_RTOL


# --------------------------------------------------------------------------- (c) grazing rays


@pytest.fixture(scope="module")
def plane_scene(ctx):
    mesh = procedural.plane((10.0, 10.0), 4)
    return single_instance_scene(ctx, mesh.vertices, mesh.faces), mesh


def horizontal_rays(rng, n, y):
    phi = rng.uniform(0, 2 * np.pi, n)
    d = np.stack([np.cos(phi), np.zeros(n), np.sin(phi)], axis=1)
    o = np.stack([rng.uniform(-4, 4, n), np.full(n, y), rng.uniform(-4, 4, n)], axis=1)
    # Half of them start outside the plane and run across it.
    o[: n // 2] -= 8.0 * d[: n // 2]
    return o.astype(np.float32), d.astype(np.float32)


def test_grazing_in_plane_no_hit_outside_triangle(plane_scene):
    scene, mesh = plane_scene
    o, d = horizontal_rays(np.random.default_rng(5), 2000, 0.0)
    t, inst, tri = scene.intersect(o, d)
    hit = np.isfinite(t)
    # A ray lying in the triangle's plane may or may not be reported, but a
    # reported hit must be a point of the reported triangle.
    if hit.any():
        pts = f32(o[hit]) + t[hit, None].astype(np.float64) * f32(d[hit])
        v = mesh.vertices[mesh.faces[tri[hit].astype(np.int64)]].astype(np.float64)
        lo, hi = v.min(axis=1) - 1e-4, v.max(axis=1) + 1e-4
        outside = ((pts < lo) | (pts > hi)).any(axis=1)
        assert not outside.any(), f"{outside.sum()} in-plane rays hit outside the reported triangle, e.g. t=" \
                                  f"{t[hit][outside][:3]}"
        assert np.all(t[hit] >= 0)
    # Occlusion answers must be consistent with the closest-hit answers.
    assert np.array_equal(scene.occluded(o, d), hit)


def test_grazing_parallel_above_misses(plane_scene):
    scene, _ = plane_scene
    o, d = horizontal_rays(np.random.default_rng(6), 2000, 1e-4)
    t, inst, _ = scene.intersect(o, d)
    hit = np.isfinite(t)
    assert not hit.any(), f"{hit.sum()} rays parallel at y=1e-4 hit the plane, t={t[hit][:5]}"
    assert np.all(inst == BACKGROUND)
    assert not scene.occluded(o, d).any()


@pytest.mark.parametrize("sign", [1.0, -1.0], ids=["from_above", "from_below"])
def test_grazing_small_elevation_hits_at_right_t(plane_scene, sign):
    scene, _ = plane_scene
    rng = np.random.default_rng(7)
    n = 2000
    elev = 1e-3
    phi = rng.uniform(0, 2 * np.pi, n)
    d = np.stack([np.cos(elev) * np.cos(phi), np.full(n, -sign * np.sin(elev)), np.cos(elev) * np.sin(phi)], axis=1)
    # Cross y = 0 at a point well inside the plane, 0.5 .. 3 units from the origin.
    cross = np.stack([rng.uniform(-4, 4, n), np.zeros(n), rng.uniform(-4, 4, n)], axis=1)
    dist = rng.uniform(0.5, 3.0, n)
    o = (cross - dist[:, None] * d).astype(np.float32)
    d = d.astype(np.float32)
    expect = -f32(o)[:, 1] / f32(d)[:, 1]
    t, inst, _ = scene.intersect(o, d)
    assert np.all(np.isfinite(t)), f"{np.isinf(t).sum()} rays at 1e-3 rad elevation missed the plane"
    err = rel_err(t, expect)
    assert err.max() < T_RTOL, f"max relative t error {err.max():.3g}"
    assert np.all(inst == 0)


# --------------------------------------------------------------------------- (d) two-level scenes


def two_level_setup(ctx):
    sphere = procedural.sphere(1.0, 2)
    torus = procedural.torus(1.0, 0.35, segments=16, tube_segments=8)
    meshes = {"sphere": (Mesh(ctx, sphere.vertices, sphere.faces, sphere.normals), sphere),
              "torus": (Mesh(ctx, torus.vertices, torus.faces, None), torus)}
    mirror = np.diag([-1.0, 1.0, 1.0])
    transforms = [
        ("sphere", affine(rotation([1, 2, 3], 0.7) @ np.diag([1.5, 0.5, 1.0]), [-2.0, 0.3, 0.0])),
        ("torus", affine(rotation([0, 1, 1], 1.1) @ np.diag([0.8, 1.2, 0.6]), [2.0, 0.5, 0.2])),
        ("sphere", affine(mirror @ rotation([1, 0, 0], 0.4) @ np.diag([0.7, 1.1, 0.9]), [0.0, 0.0, 2.0])),
        ("torus", affine(rotation([1, 1, 0], -0.5) @ mirror @ np.diag([1.3, 0.7, 1.0]), [0.0, -1.5, -1.2])),
        ("sphere", affine(np.diag([0.6, 0.6, 0.6]), [0.3, 1.6, -0.4])),
    ]
    # The mirrored instances must really have a negative determinant.
    assert np.linalg.det(transforms[2][1][:, :3]) < 0 and np.linalg.det(transforms[3][1][:, :3]) < 0
    return meshes, transforms


def world_triangles(meshes, placed):
    """placed: {instance id: (mesh name, 3x4)} -> (v0, v1, v2, instance of each, mesh triangle index of each)."""
    vs, insts, tris = [], [], []
    for iid, (name, m) in placed.items():
        mesh = meshes[name][1]
        w = transform_points(m, f32(mesh.vertices))[mesh.faces.astype(np.int64)]
        vs.append(w)
        insts.append(np.full(len(w), iid))
        tris.append(np.arange(len(w)))
    if not vs:
        return (np.zeros((0, 3)),) * 3 + (np.zeros(0, np.int64), np.zeros(0, np.int64))
    w = np.concatenate(vs)
    return w[:, 0], w[:, 1], w[:, 2], np.concatenate(insts), np.concatenate(tris)


def check_scene(scene, meshes, placed, origins, dirs):
    v0, v1, v2, inst_of, tri_of = world_triangles(meshes, placed)
    ref = Reference(origins, dirs, v0, v1, v2)
    t, inst, tri = scene.intersect(origins, dirs)
    n = len(t)
    clear = ~ref.near_edge
    assert n - clear.sum() <= 0.01 * n, f"{n - clear.sum()} rays excluded as near an edge"
    lib_hit = np.isfinite(t)
    bad = clear & (lib_hit != ref.hit)
    assert not bad.any(), f"{bad.sum()} rays disagree on hit/miss, e.g. {np.flatnonzero(bad)[:5]}"
    both = lib_hit & ref.hit
    if both.any():
        err = rel_err(t[both], ref.t[both])
        assert err.max() < T_RTOL, f"max relative t error {err.max():.3g}"
    ids = both & ref.unambiguous & clear
    ref_inst = np.where(ref.hit, inst_of[np.maximum(ref.tri, 0)], -1)
    ref_tri = np.where(ref.hit, tri_of[np.maximum(ref.tri, 0)], -1)
    wrong = ids & (inst.astype(np.int64) != ref_inst)
    assert not wrong.any(), f"{wrong.sum()} rays report the wrong instance, e.g. {np.flatnonzero(wrong)[:5]}"
    wrong = ids & (tri.astype(np.int64) != ref_tri)
    assert not wrong.any(), f"{wrong.sum()} rays report the wrong triangle"
    assert np.all(inst[~lib_hit] == BACKGROUND)
    assert set(np.unique(inst[lib_hit]).tolist()) <= set(placed)
    occ = scene.occluded(origins, dirs)
    assert not (clear & (occ != ref.hit)).any()
    return ref, inst


@pytest.fixture(scope="module")
def two_level_rays():
    rng = np.random.default_rng(11)
    n = 2000
    o = 8.0 * random_units(rng, n)
    aim = rng.uniform(-3.0, 3.0, size=(n, 3))
    return o.astype(np.float32), unit(aim - o).astype(np.float32)


def test_two_level_against_world_brute_force(ctx, two_level_rays):
    meshes, transforms = two_level_setup(ctx)
    scene = Scene(ctx)
    placed = {}
    for name, m in transforms:
        placed[scene.add(meshes[name][0], m)] = (name, m)
    scene.commit()
    o, d = two_level_rays
    ref, inst = check_scene(scene, meshes, placed, o, d)
    # Every instance, the mirrored ones included, is seen by some ray.
    assert set(np.unique(inst[np.isfinite(ref.t)]).tolist()) == set(placed)


def test_two_level_move_and_remove(ctx, two_level_rays):
    meshes, transforms = two_level_setup(ctx)
    scene = Scene(ctx)
    placed = {}
    for name, m in transforms:
        placed[scene.add(meshes[name][0], m)] = (name, m)
    scene.commit()
    o, d = two_level_rays
    ids = list(placed)

    # Move the mirrored sphere far to the side and turn it: rays that used to
    # hit it must now see what is behind, and it must show up at the new place.
    name, _ = placed[ids[2]]
    moved = affine(rotation([0, 0, 1], 2.0) @ np.diag([-0.9, 0.9, 0.9]), [0.5, 2.5, 0.5])
    before, _, _ = scene.intersect(o, d)
    scene.set_transform(ids[2], moved)
    scene.commit()
    placed[ids[2]] = (name, moved)
    ref, inst = check_scene(scene, meshes, placed, o, d)
    after, _, _ = scene.intersect(o, d)
    changed = np.isfinite(after) != np.isfinite(before)
    with np.errstate(invalid="ignore"):  # inf - inf where both miss
        changed |= np.isfinite(after) & np.isfinite(before) & (np.abs(after - before) > 1e-3)
    assert changed.sum() > 50, "moving an instance changed almost nothing"
    assert (inst == ids[2]).sum() > 10

    # Remove the torus: none of its hits remain, the rest agree with brute force.
    scene.remove(ids[1])
    scene.commit()
    del placed[ids[1]]
    _, inst = check_scene(scene, meshes, placed, o, d)
    assert not (inst == ids[1]).any()

    # Remove everything: every ray misses.
    for iid in list(placed):
        scene.remove(iid)
    scene.commit()
    t, inst, tri = scene.intersect(o, d)
    assert np.all(np.isinf(t)) and np.all(inst == BACKGROUND) and np.all(tri == BACKGROUND)
    assert not scene.occluded(o, d).any()


def test_empty_scene_misses_everything(ctx, two_level_rays):
    scene = Scene(ctx)
    scene.commit()
    o, d = two_level_rays
    t, inst, tri = scene.intersect(o, d)
    assert np.all(np.isinf(t)) and np.all(inst == BACKGROUND) and np.all(tri == BACKGROUND)
    assert not scene.occluded(o, d).any()


# --------------------------------------------------------------------------- (f) degenerate triangles


def test_degenerate_triangles_never_hit(ctx):
    # A quad at z = -1 (two triangles, ids 0 and 1) behind a set of zero-area
    # triangles around z = 0: collinear, a repeated vertex, a point. All
    # coordinates are dyadic, so the triangles are exactly degenerate in float32.
    quad = [[-2, -2, -1], [2, -2, -1], [2, 2, -1], [-2, 2, -1]]
    degenerate = [
        [[-1, -1, 0], [0, 0, 0], [1, 1, 0]],          # collinear, diagonal
        [[-1, 0.5, 0], [0.25, 0.5, 0], [1, 0.5, 0]],   # collinear, horizontal
        [[0.5, -1, 0], [0.5, 1, 0], [0.5, -1, 0]],     # repeated vertex
        [[-0.5, -0.5, 0]] * 3,                           # a point
        [[-0.5, -0.25, -0.5], [0.0, 0.25, 0.0], [0.5, 0.75, 0.5]],  # collinear, oblique
        [[0.75, -0.5, 0.25], [-0.25, 0.5, -0.25], [0.25, 0.0, 0.0]],  # collinear, middle vertex last
    ]
    vertices = np.array(quad + [p for tri in degenerate for p in tri], np.float32)
    faces = np.array([[0, 1, 2], [0, 2, 3]] + [[4 + 3 * k, 5 + 3 * k, 6 + 3 * k] for k in range(len(degenerate))])
    scene = single_instance_scene(ctx, vertices, faces)
    # Rays from z = 5 through points of the degenerate triangles (their
    # vertices, midpoints and interior points of their segments), in many directions.
    rng = np.random.default_rng(3)
    pts = []
    for tri in np.array(degenerate, np.float64):
        for w in [(1, 0, 0), (0, 1, 0), (0, 0, 1), (0.5, 0.5, 0), (0, 0.5, 0.5), (0.25, 0.25, 0.5), (0.3, 0.7, 0)]:
            pts.append(np.asarray(w) @ tri)
    pts = np.repeat(np.array(pts), 20, axis=0)
    # (|dx|, |dy| <= 0.4 per unit of z: every ray still lands on the quad.)
    dirs = unit(np.column_stack([np.clip(rng.normal(scale=0.2, size=(len(pts), 2)), -0.4, 0.4), -np.ones(len(pts))]))
    # Also directions exactly along -z and along the degenerate segments' own lines.
    dirs[::20] = [0, 0, -1]
    origins, dirs = (pts - 3.0 * dirs).astype(np.float32), dirs.astype(np.float32)
    t, inst, tri = scene.intersect(origins, dirs)
    assert np.all(np.isfinite(t)), "every ray should reach the quad behind"
    assert np.all(tri <= 1), f"degenerate triangles were hit: ids {np.unique(tri[tri > 1])}"
    expect = (f32(origins)[:, 2] + 1.0) / -f32(dirs)[:, 2]
    assert rel_err(t, expect).max() < T_RTOL

    # Rays lying in the line of a collinear triangle, and rays at its points
    # away from the quad, must miss entirely.
    only_degenerate = single_instance_scene(ctx, vertices[4:], faces[2:] - 4)
    along = np.array([[1, 1, 0], [1, 0, 0], [0, 1, 0], [1, 1, 1]], np.float64)
    starts = np.array([[-3, -3, 0], [-3, 0.5, 0], [0.5, -3, 0], [-1.5, -1.25, -1.5]], np.float64)
    o2 = np.concatenate([starts, origins])
    d2 = np.concatenate([unit(along), dirs])
    t2, inst2, _ = only_degenerate.intersect(o2.astype(np.float32), d2.astype(np.float32))
    assert np.all(np.isinf(t2)), f"{np.isfinite(t2).sum()} rays hit a zero-area triangle"
    assert np.all(inst2 == BACKGROUND)
    assert not only_degenerate.occluded(o2.astype(np.float32), d2.astype(np.float32)).any()


# --------------------------------------------------------------------------- (g) errors


@pytest.mark.parametrize("where", ["origin", "direction", "tmin", "tmax", "inf_origin"])
def test_nan_ray_input_raises(soup, where):
    o = soup["origins"][:10].copy()
    d = soup["directions"][:10].copy()
    tmin, tmax = np.zeros(10, np.float32), np.full(10, np.inf, np.float32)
    if where == "origin":
        o[3, 1] = np.nan
    elif where == "direction":
        d[7, 2] = np.nan
    elif where == "tmin":
        tmin[2] = np.nan
    elif where == "tmax":
        tmax[5] = np.nan
    else:
        o[4, 0] = np.inf
    with pytest.raises(InputError):
        soup["scene"].intersect(o, d, tmin=tmin, tmax=tmax)
    with pytest.raises(InputError):
        soup["scene"].occluded(o, d, tmin=tmin, tmax=tmax)


@pytest.mark.parametrize("bad", [0, 255, 256, 700, 999])
def test_bad_ray_named_in_any_block(soup, bad):
    """The host checks rays in blocks of 256: a bad ray anywhere, in the
    first or a later block and at a block's edges, is found and named."""
    rng = np.random.default_rng(bad)
    o = rng.uniform(-1, 1, (1000, 3)).astype(np.float32)
    d = unit(rng.normal(size=(1000, 3))).astype(np.float32)
    tmax = np.full(1000, np.inf, np.float32)
    for kind in ("nan_origin", "inf_direction", "nan_tmax"):
        oo, dd, tt = o.copy(), d.copy(), tmax.copy()
        if kind == "nan_origin":
            oo[bad, 2] = np.nan
        elif kind == "inf_direction":
            dd[bad, 0] = -np.inf
        else:
            tt[bad] = np.nan
        for query in (soup["scene"].intersect, soup["scene"].occluded):
            with pytest.raises(InputError, match=f"ray {bad} has a non-finite"):
                query(oo, dd, tmax=tt)
    soup["scene"].occluded(o, d, tmax=tmax)  # the unmodified rays pass


def test_uncommitted_scene_raises(ctx, soup):
    tris = soup["tris"]
    scene = single_instance_scene(ctx, tris.reshape(-1, 3), np.arange(3 * len(tris)).reshape(-1, 3))
    o, d = soup["origins"][:50], soup["directions"][:50]
    t_before, _, _ = scene.intersect(o, d)
    box = procedural.box()
    iid = scene.add(Mesh(ctx, box.vertices, box.faces))
    for query in (scene.intersect, scene.occluded):
        with pytest.raises(PenumbraError, match="commit") as info:
            query(o, d)
        assert info.value.status == -1009 and not isinstance(info.value, InputError)
    scene.commit()
    scene.intersect(o, d)
    scene.set_transform(iid, affine(np.eye(3), [0, 5, 0]))
    with pytest.raises(PenumbraError, match="commit"):
        scene.intersect(o, d)
    scene.commit()
    scene.remove(iid)
    with pytest.raises(PenumbraError, match="commit"):
        scene.occluded(o, d)
    scene.commit()
    t_after, _, _ = scene.intersect(o, d)
    assert np.array_equal(t_before, t_after)


# --------------------------------------------------------------------------- (e) BVH layouts


def layout_context(monkeypatch, width):
    """A context whose kernels walk the BVH layout `width` (read at creation);
    "4plain" / "8plain": that width with leaf triangles tested one by one
    (PENUMBRA_TRI_SOA=0) instead of four at a time from structure-of-arrays
    blocks (the wide layouts' default)."""
    import penumbra

    plain = width.endswith("plain")
    monkeypatch.setenv("PENUMBRA_BVH_WIDTH", width[0])
    if plain:
        monkeypatch.setenv("PENUMBRA_TRI_SOA", "0")
    try:
        return penumbra.Context()
    finally:
        monkeypatch.delenv("PENUMBRA_BVH_WIDTH")
        if plain:
            monkeypatch.delenv("PENUMBRA_TRI_SOA")


@pytest.mark.parametrize("width", ["2", "4", "4plain", "8plain"])
def test_bvh_layouts_give_identical_answers(ctx, monkeypatch, two_level_rays, width):
    """The 8-wide layout (default), the binary one (PENUMBRA_BVH_WIDTH=2) and
    the 4-wide one (PENUMBRA_BVH_WIDTH=4) have the same leaves and box tests,
    so every answer is bit-identical: t,
    instance and triangle of closest hits (these rays hit no exact tie),
    any-hit occlusion, and the G-buffer, on a scene of five instances (two
    of them mirrored) with tmax cutting some hits off."""
    from penumbra import Camera, GBuffer

    o, d = two_level_rays
    answers = []
    for c in (ctx, layout_context(monkeypatch, width)):
        meshes, transforms = two_level_setup(c)
        scene = Scene(c)
        for name, m in transforms:
            scene.add(meshes[name][0], m)
        scene.set_camera(Camera(position=(0.5, 1.0, 7.0), look_at=(0.0, 0.0, 0.0), fov_deg=50.0,
                                resolution=(48, 32)))
        scene.commit()
        gb = GBuffer(c, 48, 32)
        scene.render_gbuffer(gb)
        answers.append((*scene.intersect(o, d), scene.occluded(o, d), scene.occluded(o, d, tmax=8.0),
                        *(gb.read(p) for p in ("position", "normal", "instance"))))
    for wide, binary in zip(*answers):
        assert np.array_equal(wide, binary, equal_nan=True)
    t, _, _, occ, occ_short = answers[0][:5]
    assert np.isfinite(t).mean() > 0.2 and occ.any() and (occ & ~occ_short).any()  # not vacuous
    assert (answers[0][7] != BACKGROUND).mean() > 0.2  # the G-buffer sees the instances


@pytest.mark.parametrize("value", ["3", "wide", "16", "88"])
def test_bvh_width_variable_is_checked(monkeypatch, value):
    import penumbra

    monkeypatch.setenv("PENUMBRA_BVH_WIDTH", value)
    with pytest.raises(PenumbraError, match="PENUMBRA_BVH_WIDTH='.*' must be 2, 4 or 8"):
        penumbra.Context()


@pytest.mark.parametrize("value", ["2", "yes", "on"])
def test_tri_soa_variable_is_checked(monkeypatch, value):
    import penumbra

    monkeypatch.setenv("PENUMBRA_TRI_SOA", value)
    with pytest.raises(PenumbraError, match="PENUMBRA_TRI_SOA='.*' must be 0 or 1"):
        penumbra.Context()


# --------------------------------------------------------------------------- (h) translated instances, caller memory


def build_options_context(monkeypatch, options):
    """A context whose kernels are built with extra `options` (PENUMBRA_CL_BUILD_OPTIONS, read at creation)."""
    import penumbra

    monkeypatch.setenv("PENUMBRA_CL_BUILD_OPTIONS", options)
    try:
        return penumbra.Context()
    finally:
        monkeypatch.delenv("PENUMBRA_CL_BUILD_OPTIONS")


def translated_setup(ctx):
    """Instances whose transform is a pure translation (or none), which the
    walk traces with the world ray's direction, next to a rotated one."""
    meshes, _ = two_level_setup(ctx)
    transforms = [
        ("sphere", affine(np.eye(3), [0.0, 0.0, 0.0])),
        ("torus", affine(np.eye(3), [2.5, -0.25, 0.5])),
        ("sphere", affine(np.eye(3), [-2.0, 1.0, -1.5])),
        ("torus", affine(np.eye(3), [0.0, -2.0, 0.0])),  # origin-plane coordinates: zero translation lanes
        ("sphere", affine(rotation([1, 2, 0], 0.6), [1.0, 2.0, -2.0])),
    ]
    return meshes, transforms


def hard_rays(rng, n=1500):
    """Random rays plus edge-on ones: axis-parallel directions (zero
    components, so infinite reciprocals), rays starting inside the instances'
    boxes, and rays through box planes (origin coordinates on them)."""
    o = 6.0 * random_units(rng, n)
    d = unit(rng.uniform(-3.0, 3.0, size=(n, 3)) - o)
    axes = np.concatenate([np.eye(3), -np.eye(3)])
    k = 600
    o2 = rng.uniform(-3.0, 3.0, size=(k, 3))
    o2[::3, 1] = -2.0  # in the plane y = -2 (the lowered torus' centre plane)
    o2[1::3, 0] = 0.0
    d2 = axes[rng.integers(0, 6, k)]
    d3 = unit(np.where(rng.random((k, 3)) < 0.4, 0.0, rng.normal(size=(k, 3))) + 1e-30)
    return (np.concatenate([o, o2, o2]).astype(np.float32), np.concatenate([d, d2, d3]).astype(np.float32))


def test_translated_instances_identical_to_general_transform(ctx, monkeypatch):
    """Instances translated only (or not moved) reuse the world ray's
    direction and reciprocal (PN_INST_FLAG_TRANSLATION); the answers must be
    bit-identical to the general transform path (a build with
    -DPN_INSTANCE_GENERAL): t, instance, triangle, occlusion with and without
    a tmax cut, also for edge-on and axis-parallel rays and rays starting
    inside boxes; and right against the float64 brute force."""
    rng = np.random.default_rng(5)
    o, d = hard_rays(rng)
    general = build_options_context(monkeypatch, "-DPN_INSTANCE_GENERAL")
    answers = []
    for c in (ctx, general):
        meshes, transforms = translated_setup(c)
        scene = Scene(c)
        placed = {}
        for name, m in transforms:
            placed[scene.add(meshes[name][0], m)] = (name, m)
        scene.commit()
        answers.append((*scene.intersect(o, d), scene.occluded(o, d), scene.occluded(o, d, tmax=2.0),
                        *scene.intersect(o, d, tmin=0.5, tmax=4.0)))
        if c is ctx:
            check_scene(scene, meshes, placed, o[:1500], d[:1500])
    for fast, slow in zip(*answers):
        assert np.array_equal(fast, slow), f"{(fast != slow).sum()} answers differ"
    t, inst, _, occ, occ_short = answers[0][:5]
    hit = np.isfinite(t)
    assert hit.mean() > 0.2 and (occ & ~occ_short).any()  # not vacuous
    assert set(np.unique(inst[hit]).tolist()) == set(range(5))  # every instance seen
    assert hit[1500:].sum() > 100  # the axis-parallel and edge-on rays hit too


def at_offset(nbytes, misalign):
    """A zeroed uint8 array of nbytes whose address is misalign bytes past a 16-byte boundary."""
    raw = np.zeros(nbytes + 32, np.uint8)
    start = (-raw.ctypes.data) % 16 + misalign
    a = raw[start: start + nbytes]
    assert a.ctypes.data % 16 == misalign
    return a


def test_queries_on_unaligned_caller_memory(soup):
    """The C API uses the caller's ray and result arrays in place when they
    are aligned for the kernel's loads and copies them otherwise: answers
    from arrays at odd addresses equal those from aligned ones."""
    scene = soup["scene"]
    o, d = soup["origins"][:300], soup["directions"][:300]
    t_ref, inst_ref, tri_ref = scene.intersect(o, d)
    occ_ref = scene.occluded(o, d)
    n = len(o)
    rays = Scene._rays(o, d, 0.0, np.inf)
    for misalign in (4, 8, 2, 1):
        r = at_offset(32 * n, misalign if misalign % 4 == 0 else 12)
        r.view(np.float32)[:] = rays.reshape(-1)
        t, inst, tri, occ = (at_offset(4 * n, misalign), at_offset(4 * n, misalign), at_offset(4 * n, misalign),
                             at_offset(n, misalign))
        scene._call("pn_scene_intersect", scene._h, r.ctypes.data, n, t.ctypes.data, inst.ctypes.data,
                    tri.ctypes.data)
        scene._call("pn_scene_occluded", scene._h, r.ctypes.data, n, occ.ctypes.data)
        assert np.array_equal(t.copy().view(np.float32), t_ref)
        assert np.array_equal(inst.copy().view(np.uint32), inst_ref)
        assert np.array_equal(tri.copy().view(np.uint32), tri_ref)
        assert np.array_equal(occ.view(bool), occ_ref)
    assert np.isfinite(t_ref).any() and occ_ref.any()  # not vacuous


@pytest.mark.parametrize("width", ["2", "4", "4plain", "8plain"])
def test_bvh_layouts_identical_on_hard_rays(ctx, monkeypatch, soup, width):
    """Every layout gives the default (8-wide) one's answers bit for bit on
    the hard cases: edge-on and axis-parallel rays, rays starting inside
    boxes (inside the triangle cloud), directions of any length, tmin / tmax
    cutting hits off, meshes of zero-area triangles (never hit), translated
    instances; and a mesh deep enough for several levels of 8-wide nodes."""
    other = layout_context(monkeypatch, width)
    rng = np.random.default_rng(17)
    o, d = hard_rays(rng)
    so, sd = soup["origins"], soup["directions"]
    tris = soup["tris"]
    big = procedural.sphere(1.0, 5)  # 20 480 triangles
    degenerate = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0], [0, 1, 0], [0, 1, 0], [1, 1, 1]], np.float32)
    tmin = rng.uniform(0.0, 2.0, len(o)).astype(np.float32)
    tmax = (tmin + rng.uniform(0.0, 8.0, len(o))).astype(np.float32)
    answers = []
    for c in (ctx, other):
        meshes, transforms = translated_setup(c)
        scene = Scene(c)
        for name, m in transforms:
            scene.add(meshes[name][0], m)
        scene.add(Mesh(c, tris.reshape(-1, 3), np.arange(3 * len(tris)).reshape(-1, 3)),
                  affine(np.eye(3), [0.0, 0.0, 4.0]))
        scene.add(Mesh(c, big.vertices, big.faces), affine(np.diag([1.2, 0.8, 1.0]), [0.0, 3.0, 0.0]))
        scene.add(Mesh(c, degenerate, np.array([[0, 1, 2], [3, 4, 5]])), affine(np.eye(3), [0.5, 0.0, 0.5]))
        scene.commit()
        soup_scene = single_instance_scene(c, tris.reshape(-1, 3), np.arange(3 * len(tris)).reshape(-1, 3))
        answers.append((*scene.intersect(o, d), scene.occluded(o, d), *scene.intersect(o, d, tmin=tmin, tmax=tmax),
                        scene.occluded(o, d, tmin=tmin, tmax=tmax), *soup_scene.intersect(so, sd),
                        soup_scene.occluded(so, sd), soup_scene.occluded(so, sd, tmax=0.5)))
    for k, (a, b) in enumerate(zip(*answers)):
        if k in (2, 6):
            # Triangle ids: a ray through a shared edge or vertex hits both
            # triangles at exactly the same t, and the first one found wins,
            # which depends on the visiting order (docs/performance.md). The
            # grid-aligned rays (index >= 1500) cross the sphere's edges; a
            # tie keeps t and the instance equal (checked above and below).
            tie = (a != b) & (answers[0][k - 2] == answers[1][k - 2]) & (answers[0][k - 1] == answers[1][k - 1])
            if width == "8plain":
                # Same leaves visited in the same order, and within a leaf
                # the lowest lane wins a tie as the first triangle does.
                assert not tie.any(), f"{tie.sum()} tied rays report another triangle"
            assert np.all(np.flatnonzero(tie) >= 1500) and tie.sum() <= 0.02 * len(a), f"{tie.sum()} ties"
            a, b = a[~tie], b[~tie]
        assert np.array_equal(a, b), f"answer {k}: {(a != b).sum()} rays differ"
    t, inst = answers[0][0], answers[0][1]
    t_cut, soup_t = answers[0][4], answers[0][8]
    assert np.isfinite(t).mean() > 0.2 and np.isfinite(t_cut).any() and (np.isfinite(t) & ~np.isfinite(t_cut)).any()
    assert len(np.unique(inst[np.isfinite(t)])) >= 6  # the instances, the soup and the deep mesh are hit
    assert np.isfinite(soup_t).mean() > 0.3


# --------------------------------------------------------------------------- (h) ray arrays


def packed_query(scene, o, d, tmin, tmax):
    """The 8-float ray entry points (pn_scene_intersect / pn_scene_occluded) on (o, d, tmin, tmax)."""
    rays = Scene._rays(o, d, tmin, tmax)
    n = len(rays)
    t, inst, tri, occ = np.empty(n, np.float32), np.empty(n, np.uint32), np.empty(n, np.uint32), np.empty(n, np.uint8)
    scene._call("pn_scene_intersect", scene._h, rays.ctypes.data, n, t.ctypes.data, inst.ctypes.data, tri.ctypes.data)
    scene._call("pn_scene_occluded", scene._h, rays.ctypes.data, n, occ.ctypes.data)
    return t, inst, tri, occ.view(bool)


@pytest.mark.parametrize("bounds", [(0.0, np.inf), (1.5, 7.0), (0.0, 0.0), (-np.inf, np.inf)])
def test_ray_arrays_identical_to_packed_rays(ctx, bounds):
    """Scene.intersect / occluded with one tmin and tmax pass the origin and
    direction arrays as they are (pn_scene_intersect_arrays /
    pn_scene_occluded_arrays): answers equal the packed 8-float rays' bit
    for bit, on the hard rays and a scene of translated, rotated and scaled
    instances."""
    rng = np.random.default_rng(23)
    o, d = hard_rays(rng)
    o, d = o.astype(np.float32), d.astype(np.float32)
    meshes, transforms = translated_setup(ctx)
    scene = Scene(ctx)
    for name, m in transforms:
        scene.add(meshes[name][0], m)
    scene.add(meshes["sphere"][0], affine(np.diag([1.2, 0.8, 1.0]), [0.0, 3.0, 0.0]))
    scene.commit()
    tmin, tmax = bounds
    t, inst, tri = scene.intersect(o, d, tmin=tmin, tmax=tmax)
    occ = scene.occluded(o, d, tmin=tmin, tmax=tmax)
    t_ref, inst_ref, tri_ref, occ_ref = packed_query(scene, o, d, tmin, tmax)
    assert np.array_equal(t, t_ref) and np.array_equal(inst, inst_ref) and np.array_equal(tri, tri_ref)
    assert np.array_equal(occ, occ_ref)
    if tmax > tmin:
        assert np.isfinite(t).sum() > len(t) // 10 and (~occ).any()  # not vacuous
    else:
        assert not np.isfinite(t).any() and not occ.any()


def test_ray_arrays_on_unaligned_and_strided_memory(soup):
    """Arrays at odd addresses (copied by the library) and strided or
    float64 inputs (converted by Scene) give the aligned arrays' answers."""
    scene = soup["scene"]
    o, d = soup["origins"][:300].astype(np.float32), soup["directions"][:300].astype(np.float32)
    t_ref, inst_ref, tri_ref = scene.intersect(o, d)
    occ_ref = scene.occluded(o, d)
    n = len(o)
    for misalign in (4, 8, 2, 1):
        oa, da = at_offset(12 * n, misalign), at_offset(12 * n, (misalign * 3) % 16)
        oa[:] = o.reshape(-1).view(np.uint8)
        da[:] = d.reshape(-1).view(np.uint8)
        t, inst, tri, occ = (at_offset(4 * n, misalign), at_offset(4 * n, misalign), at_offset(4 * n, misalign),
                             at_offset(n, misalign))
        scene._call("pn_scene_intersect_arrays", scene._h, oa.ctypes.data, da.ctypes.data, n, 0.0, np.inf,
                    t.ctypes.data, inst.ctypes.data, tri.ctypes.data)
        scene._call("pn_scene_occluded_arrays", scene._h, oa.ctypes.data, da.ctypes.data, n, 0.0, np.inf,
                    occ.ctypes.data)
        assert np.array_equal(t.copy().view(np.float32), t_ref)
        assert np.array_equal(inst.copy().view(np.uint32), inst_ref)
        assert np.array_equal(tri.copy().view(np.uint32), tri_ref)
        assert np.array_equal(occ.view(bool), occ_ref)
    wide = np.zeros((n, 6), np.float32)
    wide[:, ::2] = o
    t, inst, tri = scene.intersect(wide[:, ::2], d.astype(np.float64))
    assert np.array_equal(t, t_ref) and np.array_equal(tri, tri_ref)
    assert np.isfinite(t_ref).any() and occ_ref.any()  # not vacuous


@pytest.mark.parametrize("bad", [0, 255, 256, 999])
def test_ray_arrays_bad_input_named(soup, bad):
    """The arrays path checks every origin and direction (in blocks of 256)
    and the two bounds: a bad ray is named, a NaN bound refused."""
    rng = np.random.default_rng(bad)
    o = rng.uniform(-1, 1, (1000, 3)).astype(np.float32)
    d = unit(rng.normal(size=(1000, 3))).astype(np.float32)
    for kind in ("nan_origin", "inf_origin", "inf_direction", "nan_direction"):
        oo, dd = o.copy(), d.copy()
        (oo if kind.endswith("origin") else dd)[bad, bad % 3] = np.nan if kind.startswith("nan") else -np.inf
        for query in (soup["scene"].intersect, soup["scene"].occluded):
            with pytest.raises(InputError, match=f"ray {bad} has a non-finite"):
                query(oo, dd)
    for tmin, tmax in ((np.nan, np.inf), (0.0, np.nan)):
        for query in (soup["scene"].intersect, soup["scene"].occluded):
            with pytest.raises(InputError, match="tmin or tmax is NaN"):
                query(o, d, tmin=tmin, tmax=tmax)
    soup["scene"].occluded(o, d)  # the unmodified rays pass


def test_nearest_child_without_the_stack_identical(ctx, monkeypatch, soup):
    """The 8-wide closest-hit walk visits the nearer of one or two entered
    children next without pushing it (pn_push8); a build that pushes it as
    well (-DPN_STACK_NEAREST) must give the same answers bit for bit,
    triangle ids of exact ties included (the order of visits is the same):
    hard rays over translated, rotated and scaled instances and a deep
    mesh, with and without bounds, and the triangle soup."""
    stacked = build_options_context(monkeypatch, "-DPN_STACK_NEAREST")
    rng = np.random.default_rng(29)
    o, d = hard_rays(rng)
    so, sd = soup["origins"], soup["directions"]
    tris = soup["tris"]
    big = procedural.sphere(1.0, 5)
    tmin = rng.uniform(0.0, 2.0, len(o)).astype(np.float32)
    tmax = (tmin + rng.uniform(0.0, 8.0, len(o))).astype(np.float32)
    answers = []
    for c in (ctx, stacked):
        meshes, transforms = two_level_setup(c)
        scene = Scene(c)
        for name, m in transforms:
            scene.add(meshes[name][0], m)
        scene.add(Mesh(c, big.vertices, big.faces), affine(np.diag([1.2, 0.8, 1.0]), [0.0, 3.0, 0.0]))
        scene.commit()
        soup_scene = single_instance_scene(c, tris.reshape(-1, 3), np.arange(3 * len(tris)).reshape(-1, 3))
        answers.append((*scene.intersect(o, d), *scene.intersect(o, d, tmin=tmin, tmax=tmax),
                        *soup_scene.intersect(so, sd), scene.occluded(o, d)))
    for k, (a, b) in enumerate(zip(*answers)):
        assert np.array_equal(a, b), f"answer {k}: {(a != b).sum()} rays differ"
    t, inst = answers[0][0], answers[0][1]
    assert np.isfinite(t).mean() > 0.2 and len(np.unique(inst[np.isfinite(t)])) >= 6  # not vacuous
    assert np.isfinite(answers[0][6]).mean() > 0.3
