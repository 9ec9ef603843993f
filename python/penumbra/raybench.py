"""Ray throughput of penumbra against Embree on the same rays, in the same run.

Two workloads from one scene description (docs/metrics.md, "Ray throughput
against Embree"):

* **primary**: one closest-hit ray per pixel of the scene's camera, built
  exactly as ``gbuffer_primary`` in ``kernels/raycast.cl`` builds them
  (:func:`primary_rays`);
* **shadow**: ``n_dirs`` any-hit rays per primary hit, cosine-distributed
  over the hemisphere of the geometric normal, starting slightly above the
  surface (:func:`shadow_rays`): the visibility queries of ambient occlusion
  or environment-light shadows.

penumbra traces them with :meth:`penumbra.Scene.intersect` /
:meth:`~penumbra.Scene.occluded` (host arrays in and out), Embree with
embreex (``EmbreeScene.run``, one ``rtcIntersect1`` / ``rtcOccluded1`` per
ray) over the world-space triangles of the same objects
(:func:`world_triangles`). :func:`measure` times both and checks that they
agree.

embreex is an optional dependency (``pip install penumbra[bench]``); it is
imported only by :func:`embree_scene` and :func:`measure`.
"""

from __future__ import annotations

import math
import statistics
import time

import numpy as np

from .errors import InputError
from .render import BuiltScene, object_geometry
from .scenefile import SceneDescription

__all__ = ["world_triangles", "primary_rays", "shadow_rays", "embree_scene", "workload", "measure"]

# Shadow-ray origins are lifted off the surface by this fraction of the
# diagonal of the scene's bounding box (measure's default offset).
OFFSET_FRACTION = 1e-4


def _object_to_world(obj) -> np.ndarray:
    """The object's transform as a float64 3x4 matrix (ObjectDesc.transform() gives 4x4)."""
    m = np.asarray(obj.transform(), dtype=np.float64)
    if m.shape == (4, 4):
        m = m[:3]
    if m.shape != (3, 4):
        raise InputError(f"object '{obj.name}': transform must be 3x4 or 4x4, got shape {m.shape}")
    return m


def _world_geometry(desc: SceneDescription) -> tuple[np.ndarray, list[int]]:
    """(T, 3, 3) float32 world triangles and the triangle count of each object, in desc.objects order."""
    parts, counts = [], []
    cache: dict[tuple, tuple] = {}
    for obj in desc.objects:
        key = obj.geometry_key()
        if key not in cache:  # the same geometry is loaded once, as build_scene does
            v, f, _ = object_geometry(obj)
            cache[key] = (np.asarray(v, dtype=np.float64), np.asarray(f, dtype=np.int64))
        v, f = cache[key]
        m = _object_to_world(obj)
        world = v @ m[:, :3].T + m[:, 3]
        parts.append(world[f])
        counts.append(len(f))
    if not parts or sum(counts) == 0:
        raise InputError("the scene has no triangles")
    return np.ascontiguousarray(np.concatenate(parts), dtype=np.float32), counts


def world_triangles(desc: SceneDescription) -> np.ndarray:
    """(T, 3, 3) float32 world-space triangles of every object of `desc`.

    Objects in ``desc.objects`` order, each object's triangles in its mesh's
    order; vertices transformed by ``ObjectDesc.transform()`` in float64.
    """
    return _world_geometry(desc)[0]


def _camera_frame(camera) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, int, int]:
    """origin, forward, right * tan(fov/2), up * tan(fov/2) * H/W as float32, and (W, H):
    the four camera arguments of gbuffer_primary, as pn_scene_do_render_gbuffer computes them."""
    pos = np.asarray(camera.position, dtype=np.float32).astype(np.float64)  # the library stores floats
    look = np.asarray(camera.look_at, dtype=np.float32).astype(np.float64)
    up = np.asarray(camera.up, dtype=np.float32).astype(np.float64)
    w, h = (int(x) for x in camera.resolution)
    if w <= 0 or h <= 0:
        raise InputError(f"camera resolution {camera.resolution} must be positive")
    f = look - pos
    if not np.linalg.norm(f) > 0:
        raise InputError("camera look_at equals its position")
    f /= np.linalg.norm(f)
    r = np.cross(f, up)
    if not np.linalg.norm(r) > 1e-6 * np.linalg.norm(up):
        raise InputError("camera up vector is zero or parallel to the view direction")
    r /= np.linalg.norm(r)
    u = np.cross(r, f)
    tx = math.tan(float(np.float32(camera.fov_deg)) * math.pi / 360.0)
    ty = tx * h / w
    f32 = lambda a: np.asarray(a, dtype=np.float32)  # noqa: E731
    return f32(pos), f32(f), f32(r * tx), f32(u * ty), w, h


def primary_rays(camera) -> tuple[np.ndarray, np.ndarray]:
    """The primary rays of `camera` (a CameraDesc or a penumbra.Camera): (origins, directions),
    each (W*H, 3) float32, ray ``y * W + x`` through pixel (x, y), row 0 at the top.

    The same formula as ``gbuffer_primary`` (kernels/raycast.cl) with the
    frame of ``pn_scene_render_gbuffer``: forward ``f = normalize(look_at -
    position)``, ``right = normalize(cross(f, up))``, ``up' = cross(right, f)``
    (float64 on the host), then in float32 ``sx = 2 (x + 0.5) / W - 1``,
    ``sy = 1 - 2 (y + 0.5) / H`` and ``dir = normalize(f + sx right tan(fov/2)
    + sy up' tan(fov/2) H / W)``: fov is horizontal. Directions may differ
    from the kernel's by a few float32 ulps (fused multiply-adds, the
    device's normalize).
    """
    org, fwd, right, up, w, h = _camera_frame(camera)
    xs = np.arange(w, dtype=np.float32)
    ys = np.arange(h, dtype=np.float32)
    sx = np.float32(2.0) * (xs + np.float32(0.5)) / np.float32(w) - np.float32(1.0)
    sy = np.float32(1.0) - np.float32(2.0) * (ys + np.float32(0.5)) / np.float32(h)
    d = fwd[None, None, :] + sx[None, :, None] * right + sy[:, None, None] * up  # (H, W, 3) float32
    d = d.reshape(-1, 3)
    d /= np.sqrt(np.sum(d * d, axis=1, dtype=np.float32))[:, None]
    origins = np.broadcast_to(org, d.shape).copy()
    return origins, np.ascontiguousarray(d, dtype=np.float32)


def _orthonormal_basis(n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Tangents (t, b) with (t, b, n) right-handed orthonormal, for unit n (N, 3)
    (Duff et al. 2017, "Building an Orthonormal Basis, Revisited")."""
    sign = np.where(n[:, 2] >= 0.0, 1.0, -1.0)
    a = -1.0 / (sign + n[:, 2])
    b = n[:, 0] * n[:, 1] * a
    t = np.stack([1.0 + sign * n[:, 0] ** 2 * a, sign * b, -sign * n[:, 0]], axis=1)
    bt = np.stack([b, sign + n[:, 1] ** 2 * a, -n[:, 1]], axis=1)
    return t, bt


def shadow_rays(hit_points, normals, n_dirs: int, seed: int = 0,
                offset: float = 1e-4) -> tuple[np.ndarray, np.ndarray]:
    """Any-hit rays from surface points: (origins, directions), each (N * n_dirs, 3) float32.

    Ray ``k * n_dirs + j`` is the j-th ray of point k: it starts at
    ``hit_points[k] + offset * n_k`` (n_k the normalised ``normals[k]``) and
    goes in a cosine-distributed direction on n_k's hemisphere (the
    distribution of ambient-occlusion and diffuse environment shadow rays).
    Directions come from ``numpy.random.default_rng(seed)``, so equal inputs
    give equal rays. Computed in float64, returned as float32.
    """
    p = np.asarray(hit_points, dtype=np.float64)
    n = np.asarray(normals, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3 or n.shape != p.shape:
        raise InputError(f"hit_points and normals must both have shape (N, 3), got {p.shape} and {n.shape}")
    if isinstance(n_dirs, bool) or not isinstance(n_dirs, (int, np.integer)) or n_dirs < 1:
        raise InputError(f"n_dirs must be a positive integer, got {n_dirs!r}")
    if not (math.isfinite(offset) and offset >= 0.0):
        raise InputError(f"offset must be a finite number >= 0, got {offset!r}")
    if not (np.isfinite(p).all() and np.isfinite(n).all()):
        raise InputError("hit_points and normals must be finite")
    length = np.linalg.norm(n, axis=1)
    if (length == 0.0).any():
        raise InputError(f"normals has {int((length == 0).sum())} zero vector(s); first at row "
                         f"{int(np.argmax(length == 0))}")
    n = n / length[:, None]
    t, b = _orthonormal_basis(n)
    rng = np.random.default_rng(seed)
    u1, u2 = rng.random((2, len(p), n_dirs))
    r, phi = np.sqrt(u1), 2.0 * math.pi * u2   # Malley's method: disc -> hemisphere, pdf cos/pi
    x, y, z = r * np.cos(phi), r * np.sin(phi), np.sqrt(np.maximum(0.0, 1.0 - u1))
    d = x[..., None] * t[:, None, :] + y[..., None] * b[:, None, :] + z[..., None] * n[:, None, :]
    o = np.broadcast_to((p + offset * n)[:, None, :], d.shape)
    return (np.ascontiguousarray(o.reshape(-1, 3), dtype=np.float32),
            np.ascontiguousarray(d.reshape(-1, 3), dtype=np.float32))


def embree_scene(triangles: np.ndarray):
    """An embreex EmbreeScene holding `triangles` (T, 3, 3) as one triangle mesh
    (Embree's primitive id = index into `triangles`). Committed on its first run."""
    from embreex import mesh_construction, rtcore_scene

    tris = np.ascontiguousarray(triangles, dtype=np.float32)
    if tris.ndim != 3 or tris.shape[1:] != (3, 3) or len(tris) == 0:
        raise InputError(f"triangles must have shape (T, 3, 3) with T > 0, got {tris.shape}")
    scene = rtcore_scene.EmbreeScene()
    mesh = mesh_construction.TriangleMesh(scene, tris)
    return scene, mesh  # keep the mesh object alive with the scene


def _paired_medians(fn_a, fn_b, repeats: int) -> tuple[float, float]:
    """Median wall times of two calls timed in alternating rounds, so that a change of load, or
    the runtime's threads going to sleep between calls, falls on both alike (docs/metrics.md,
    "Before/after in one run"). A call of a millisecond is too short for one warm-up and five
    rounds to settle, so both are warmed up twice and timed at least 11 times."""
    for _ in range(2):  # warm-up: kernel/program caches, Embree's commit, page faults
        fn_a()
        fn_b()
    times_a, times_b = [], []
    for _ in range(max(repeats, 11)):
        t0 = time.perf_counter()
        fn_a()
        t1 = time.perf_counter()
        fn_b()
        t2 = time.perf_counter()
        times_a.append(t1 - t0)
        times_b.append(t2 - t1)
    return statistics.median(times_a), statistics.median(times_b)


def _throughput(rays: int, pn_s: float, em_s: float) -> dict:
    pn = rays / pn_s / 1e6 if pn_s > 0 else math.inf
    em = rays / em_s / 1e6 if em_s > 0 else math.inf
    return {"rays": rays, "penumbra_s": pn_s, "embree_s": em_s, "penumbra_mrays_per_s": pn,
            "embree_mrays_per_s": em, "ratio": pn / em}


def _shadow_from_hits(tris, first, o, d, t, inst, tri, n_dirs, seed, offset):
    """measure's shadow rays: n_dirs rays from every primary hit (t finite), over the hemisphere of
    the hit triangle's geometric normal turned to face the viewer. Returns (origins, directions, points)."""
    hit = np.flatnonzero(np.isfinite(t))
    idx = first[inst[hit]] + tri[hit].astype(np.int64)
    v = tris[idx].astype(np.float64)
    normal = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    dirs = d[hit].astype(np.float64)
    normal *= np.where(np.sum(normal * dirs, axis=1) > 0.0, -1.0, 1.0)[:, None]  # face the viewer (two-sided)
    points = o[hit].astype(np.float64) + t[hit, None].astype(np.float64) * dirs
    keep = np.linalg.norm(normal, axis=1) > 0.0  # a hit on a zero-area triangle cannot happen; be safe
    so, sd = shadow_rays(points[keep], normal[keep], n_dirs, seed=seed, offset=offset)
    return so, sd, int(keep.sum())


def _first_triangles(desc, built, counts):
    """instance id -> index of its object's first triangle in world_triangles(desc)."""
    if set(built.instance_ids) != {obj.name for obj in desc.objects}:
        raise InputError("built does not hold the objects of desc (pass render.build_scene(desc, ctx))")
    first = np.zeros(max(built.instance_ids.values()) + 1, np.int64)
    first[[built.instance_ids[obj.name] for obj in desc.objects]] = np.cumsum([0] + counts[:-1])
    return first


def workload(desc: SceneDescription, built: BuiltScene, n_dirs: int = 16, seed: int = 0,
             offset: float | None = None) -> dict:
    """The rays :func:`measure` times, without Embree: ``{"primary": (origins, directions),
    "shadow": (origins, directions)}``, the shadow rays starting from penumbra's primary hits."""
    tris, counts = _world_geometry(desc)
    first = _first_triangles(desc, built, counts)
    if offset is None:
        lo, hi = tris.reshape(-1, 3).min(axis=0), tris.reshape(-1, 3).max(axis=0)
        offset = OFFSET_FRACTION * float(np.linalg.norm(hi.astype(np.float64) - lo))
    o, d = primary_rays(built.camera)
    t, inst, tri = built.scene.intersect(o, d)
    if not np.isfinite(t).any():
        raise InputError("no primary ray hits the scene, so there are no shadow rays to trace")
    so, sd, _ = _shadow_from_hits(tris, first, o, d, t, inst, tri, n_dirs, seed, offset)
    return {"primary": (o, d), "shadow": (so, sd)}


def measure(desc: SceneDescription, built: BuiltScene, repeats: int = 5, n_dirs: int = 16, seed: int = 0,
            offset: float | None = None) -> dict:
    """Times closest-hit primary rays and any-hit shadow rays in penumbra and
    Embree on identical rays, and checks that both give the same answers.

    ``built`` must be ``render.build_scene(desc, ctx)`` (its instance ids map
    hits back to objects). Each query is called twice to warm up, then
    max(``repeats``, 11) times, penumbra's and Embree's calls alternating;
    times are medians in seconds, wall clock, including
    everything the call does (penumbra: ray packing, host validation, device
    buffers, upload, kernel, read-back; embreex: its Cython loop of one Embree call per ray,
    on one thread). ``offset``: how far shadow rays start above the surface
    (default 1e-4 of the scene's bounding-box diagonal).

    Returns a dict::

        device, embree_version, embree_threads (1), triangles, repeats,
        primary: rays, penumbra_s, embree_s, penumbra_mrays_per_s,
                 embree_mrays_per_s, ratio (penumbra / Embree throughput),
                 hit_fraction, mismatch_count, mismatch_fraction (rays where
                 one hits and the other misses), t_max_rel_diff (over rays
                 both hit; 0 when none), same_triangle_fraction,
        shadow:  the same throughput keys, occluded_fraction, mismatch_count,
                 mismatch_fraction, hits (primary hits they start from),
                 dirs_per_hit, offset
    """
    import embreex

    if isinstance(repeats, bool) or not isinstance(repeats, int) or repeats < 1:
        raise InputError(f"repeats must be a positive integer, got {repeats!r}")
    tris, counts = _world_geometry(desc)
    first = _first_triangles(desc, built, counts)
    lo, hi = tris.reshape(-1, 3).min(axis=0), tris.reshape(-1, 3).max(axis=0)
    if offset is None:
        offset = OFFSET_FRACTION * float(np.linalg.norm(hi.astype(np.float64) - lo))

    scene = built.scene
    built.ctx.build("raycast")
    em_scene, _mesh = embree_scene(tris)

    # ---- primary rays: closest hit
    o, d = primary_rays(built.camera)
    pn_s, em_s = _paired_medians(lambda: scene.intersect(o, d), lambda: em_scene.run(o, d, query="INTERSECT"),
                                 repeats)
    t, inst, tri = scene.intersect(o, d)
    em = em_scene.run(o, d, query="INTERSECT", output=1)
    pn_hit = np.isfinite(t)
    em_hit = em["primID"] != -1
    both = pn_hit & em_hit
    world_tri = np.full(len(t), -1, np.int64)
    if both.any():
        world_tri[both] = first[inst[both]] + tri[both].astype(np.int64)
    t_pn, t_em = t[both].astype(np.float64), em["tfar"][both].astype(np.float64)
    rel = np.abs(t_pn - t_em) / np.maximum(np.abs(t_em), 1e-30)
    mismatch = int((pn_hit != em_hit).sum())
    primary = _throughput(len(o), pn_s, em_s)
    primary.update(hit_fraction=float(pn_hit.mean()), mismatch_count=mismatch,
                   mismatch_fraction=mismatch / len(o), t_max_rel_diff=float(rel.max()) if rel.size else 0.0,
                   same_triangle_fraction=float((world_tri[both] == em["primID"][both]).mean()) if both.any()
                   else 1.0)

    # ---- shadow rays from penumbra's primary hits: any hit
    if not pn_hit.any():
        raise InputError("no primary ray hits the scene, so there are no shadow rays to trace")
    so, sd, n_points = _shadow_from_hits(tris, first, o, d, t, inst, tri, n_dirs, seed, offset)
    pn_s, em_s = _paired_medians(lambda: scene.occluded(so, sd), lambda: em_scene.run(so, sd, query="OCCLUDED"),
                                 repeats)
    pn_occ = scene.occluded(so, sd)
    em_occ = em_scene.run(so, sd, query="OCCLUDED") != -1
    mismatch = int((pn_occ != em_occ).sum())
    shadow = _throughput(len(so), pn_s, em_s)
    shadow.update(occluded_fraction=float(pn_occ.mean()), mismatch_count=mismatch,
                  mismatch_fraction=mismatch / len(so), hits=n_points,
                  dirs_per_hit=n_dirs, offset=offset)
    return {"device": built.ctx.device_name, "embree_version": getattr(embreex, "__version__", "unknown"),
            "embree_threads": 1, "triangles": int(len(tris)), "repeats": repeats, "primary": primary,
            "shadow": shadow}
