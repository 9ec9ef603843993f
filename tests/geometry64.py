"""float64 geometry shared by the tests: camera rays of the documented camera
model and a Möller–Trumbore ray caster against world-space triangles."""

from __future__ import annotations

import math

import numpy as np

from penumbra import Camera

# Rays within this barycentric distance of an edge are flagged as ambiguous:
# float32 and float64 may legitimately disagree about them.
EDGE_EPS = 1e-5


def f32(a) -> np.ndarray:
    return np.asarray(a, dtype=np.float32).astype(np.float64)


def unit(v) -> np.ndarray:
    v = np.asarray(v, np.float64)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def rotation(axis, angle) -> np.ndarray:
    a = unit(axis)
    k = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k


def affine(linear, translation) -> np.ndarray:
    return np.hstack([np.asarray(linear, np.float64), np.asarray(translation, np.float64)[:, None]])


# --------------------------------------------------------------------------- float64 primary-ray cast


def camera_rays(cam: Camera) -> tuple[np.ndarray, np.ndarray]:
    """(origin, (h, w, 3) unit directions) of the camera model of pn_scene_render_gbuffer:
    forward f, right = normalize(f x up) tan(fov/2), up' = (right x f) tan(fov/2) h/w,
    pixel (x, y) through its centre, y = 0 the top row."""
    pos, look, up = f32(cam.position), f32(cam.look_at), f32(cam.up)
    w, h = cam.resolution
    f = unit(look - pos)
    r = unit(np.cross(f, up))
    u = np.cross(r, f)
    tx = np.tan(np.radians(float(np.float32(cam.fov_deg))) / 2.0)
    ty = tx * h / w
    sx = 2.0 * (np.arange(w) + 0.5) / w - 1.0
    sy = 1.0 - 2.0 * (np.arange(h) + 0.5) / h
    d = f + sx[None, :, None] * tx * r + sy[:, None, None] * ty * u
    return pos, unit(d)


def cast(origin, dirs, v0, v1, v2, chunk=256):
    """Closest hits of rays from one origin (float64 Möller–Trumbore): t, triangle
    index (-1 on a miss), barycentrics (u of v1, v of v2), near_edge flag."""
    n = len(dirs)
    e1, e2 = v1 - v0, v2 - v0
    good = np.linalg.norm(np.cross(e1, e2), axis=1) > 0
    t_out, tri_out = np.full(n, np.inf), np.full(n, -1)
    u_out, v_out, near = np.zeros(n), np.zeros(n), np.zeros(n, bool)
    s_vec = origin[None, :] - v0
    q = np.cross(s_vec, e1)
    for s in range(0, n, chunk):
        d = dirs[s:s + chunk]
        p = np.cross(d[:, None, :], e2[None])
        det = np.einsum("rtk,tk->rt", p, e1)
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = 1.0 / det
            u = np.einsum("tk,rtk->rt", s_vec, p) * inv
            v = np.einsum("rk,tk->rt", d, q) * inv
            t = np.einsum("tk,tk->t", e2, q)[None, :] * inv
        bmin = np.minimum(np.minimum(u, v), 1 - u - v)
        plane = good[None] & (det != 0) & np.isfinite(t) & (t > 0)
        hits = np.where(plane & (bmin >= 0), t, np.inf)
        k = hits.argmin(axis=1)
        rows = np.arange(len(d))
        t_out[s:s + chunk] = hits[rows, k]
        tri_out[s:s + chunk] = np.where(np.isfinite(hits[rows, k]), k, -1)
        u_out[s:s + chunk], v_out[s:s + chunk] = u[rows, k], v[rows, k]
        near[s:s + chunk] = (plane & (np.abs(bmin) < EDGE_EPS)).any(axis=1)
    return t_out, tri_out, u_out, v_out, near


def corner_normals64(vertices, faces, crease_angle_deg) -> np.ndarray:
    """float64 twin of penumbra.meshio.smooth_normals, written as plain loops:
    (m, 3, 3) unit normal of every triangle corner, the angle-weighted sum of
    the face normals around its vertex position within the crease angle of its
    own face (a zero-area face: of every face around it)."""
    v = np.asarray(vertices, np.float64)
    f = np.asarray(faces, np.int64)
    face_n, angles = [], []
    for t in f:
        p = v[t]
        c = np.cross(p[1] - p[0], p[2] - p[0])
        ln = np.linalg.norm(c)
        face_n.append(c / ln if ln > 0 else np.zeros(3))
        a = []
        for k in range(3):
            e1, e2 = p[(k + 1) % 3] - p[k], p[(k + 2) % 3] - p[k]
            a.append(math.atan2(np.linalg.norm(np.cross(e1, e2)), float(e1 @ e2)))
        angles.append(a)
    around: dict[tuple, list] = {}
    for ti, t in enumerate(f):
        for k in range(3):
            around.setdefault(tuple(v[t[k]]), []).append((ti, k))
    cos_limit = math.cos(math.radians(crease_angle_deg))
    out = np.zeros((len(f), 3, 3))
    for ti, t in enumerate(f):
        own = face_n[ti]
        for k in range(3):
            s = np.zeros(3)
            for tj, kj in around[tuple(v[t[k]])]:
                if not own.any() or own @ face_n[tj] >= cos_limit - 1e-12:
                    s += angles[tj][kj] * face_n[tj]
            ln = np.linalg.norm(s)
            out[ti, k] = s / ln if ln > 0 else (0.0, 1.0, 0.0)
    return out
