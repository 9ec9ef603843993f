"""penumbra.raybench: the workload generators and the agreement of penumbra
with Embree on the same rays. Correctness only: no timing asserts, because
machines are noisy; measure() is only checked to return positive numbers."""

from __future__ import annotations

import math

import numpy as np
import pytest

import penumbra
from penumbra import raybench
from penumbra.errors import InputError
from penumbra.render import build_scene
from penumbra.scenefile import CameraDesc, parse_scene

# Agreement demanded of two watertight-ish float32 tracers on identical rays:
# hit/miss may differ only for rays grazing an edge or silhouette, and t only
# by float32 rounding of the two different triangle tests (measured: 0 and
# ~3e-6 on the scenes below).
HIT_AGREEMENT = 0.999
T_RTOL = 1e-4

THROUGHPUT_KEYS = {"rays", "penumbra_s", "embree_s", "penumbra_mrays_per_s", "embree_mrays_per_s", "ratio"}


def _sphere_plane(resolution=(64, 48)) -> dict:
    return {
        "environment": {"map": "constant", "face_size": 8, "irradiance_face_size": 4},
        "camera": {"position": [0.0, 1.5, 4.0], "look_at": [0.0, 0.5, 0.0], "fov_deg": 45,
                   "resolution": list(resolution)},
        "object": [
            {"name": "ground", "primitive": "plane", "params": {"size": [6.0, 6.0], "subdivisions": 3}},
            {"name": "ball", "primitive": "sphere", "params": {"subdivisions": 3}, "translate": [0.3, 0.7, 0.0],
             "scale": 0.7},
            {"name": "box", "primitive": "box", "translate": [-1.2, 0.4, -0.5], "rotate_deg": [10.0, 35.0, 0.0],
             "scale": [0.8, 0.8, 0.5]},
        ],
    }


@pytest.fixture(scope="module")
def sphere_plane(ctx):
    desc = parse_scene(_sphere_plane())
    return desc, build_scene(desc, ctx)


# ------------------------------------------------------------------ workloads


def test_world_triangles_apply_each_object_transform():
    desc = parse_scene(_sphere_plane())
    tris = raybench.world_triangles(desc)
    assert tris.dtype == np.float32 and tris.ndim == 3 and tris.shape[1:] == (3, 3)
    # 3x3 cells of 2 triangles, 20 * 4**3 sphere triangles, 12 box triangles, in object order.
    assert len(tris) == 18 + 1280 + 12
    ball = tris[18:18 + 1280].reshape(-1, 3).astype(np.float64)
    np.testing.assert_allclose(np.linalg.norm(ball - [0.3, 0.7, 0.0], axis=1), 0.7, rtol=1e-6)
    ground = tris[:18].reshape(-1, 3)
    assert np.all(ground[:, 1] == 0.0) and ground[:, 0].min() == -3.0 and ground[:, 2].max() == 3.0
    # The box: scale, then rotate x, then y, then translate (ObjectDesc.transform).
    box = desc.objects[2]
    m = box.transform()
    corner = np.array([0.5, 0.5, 0.5])
    want = m[:3, :3] @ corner + m[:3, 3]
    got = tris[-12:].reshape(-1, 3).astype(np.float64)
    assert np.min(np.linalg.norm(got - want, axis=1)) < 1e-6


def test_world_triangles_of_an_empty_scene():
    desc = parse_scene({"object": []})
    with pytest.raises(InputError, match="no triangles"):
        raybench.world_triangles(desc)


def test_primary_rays_by_hand():
    cam = CameraDesc(position=(1.0, 2.0, 3.0), look_at=(1.0, 2.0, 0.0), up=(0.0, 1.0, 0.0), fov_deg=90.0,
                     resolution=(3, 2))
    o, d = raybench.primary_rays(cam)
    assert o.shape == d.shape == (6, 3) and o.dtype == d.dtype == np.float32
    assert np.all(o == np.float32([1.0, 2.0, 3.0]))
    # forward -z, right = cross(-z, +y) = +x, up' = +y; tan(45 deg) = 1, vertical extent 2/3.
    # Pixel (x, y) = (0, 0): sx = -2/3, sy = 1/2 * 2/3 = 1/3 (top-left, row 0 at the top).
    want = np.array([-2.0 / 3.0, 1.0 / 3.0, -1.0])
    np.testing.assert_allclose(d[0], want / np.linalg.norm(want), atol=1e-7)
    np.testing.assert_allclose(d[1], np.array([0.0, 1.0 / 3.0, -1.0]) / math.hypot(1.0 / 3.0, 1.0), atol=1e-7)
    want = np.array([2.0 / 3.0, -1.0 / 3.0, -1.0])  # pixel (2, 1): bottom right
    np.testing.assert_allclose(d[5], want / np.linalg.norm(want), atol=1e-7)
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-7)


def test_primary_rays_are_the_gbuffer_rays(ctx, sphere_plane):
    desc, built = sphere_plane
    w, h = built.camera.resolution
    g = penumbra.GBuffer(ctx, w, h)
    built.scene.render_gbuffer(g)
    pos, inst = g.read("position").reshape(-1, 4), g.read("instance").reshape(-1)
    o, d = raybench.primary_rays(desc.camera)
    t, hit_inst, _ = built.scene.intersect(o, d)
    assert np.mean(hit_inst == inst) >= HIT_AGREEMENT
    bg = inst == penumbra.BACKGROUND
    assert bg.any() and (~bg).any()
    np.testing.assert_allclose(pos[bg, :3], d[bg], atol=1e-6)  # the G-buffer stores a miss's direction
    both = ~bg & np.isfinite(t)
    np.testing.assert_allclose(t[both], pos[both, 3], rtol=T_RTOL)


def test_shadow_rays_are_deterministic_cosine_distributed_and_offset():
    rng = np.random.default_rng(1)
    p = rng.normal(size=(50, 3))
    n = rng.normal(size=(50, 3))
    n[0] = (0.0, 0.0, -2.0)  # the basis' special case (n.z < 0), and an unnormalised normal
    o, d = raybench.shadow_rays(p, n, 200, seed=7, offset=0.01)
    assert o.shape == d.shape == (50 * 200, 3) and o.dtype == d.dtype == np.float32
    o2, d2 = raybench.shadow_rays(p, n, 200, seed=7, offset=0.01)
    assert np.array_equal(o, o2) and np.array_equal(d, d2)
    assert not np.array_equal(d, raybench.shadow_rays(p, n, 200, seed=8, offset=0.01)[1])
    unit = n / np.linalg.norm(n, axis=1, keepdims=True)
    np.testing.assert_allclose(o.reshape(50, 200, 3), np.broadcast_to((p + 0.01 * unit)[:, None], (50, 200, 3)),
                               atol=1e-6)
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-6)
    cos = np.sum(d.reshape(50, 200, 3) * unit[:, None], axis=2)
    assert cos.min() > 0.0
    # Cosine-weighted: E[cos] = 2/3, E[cos^2] = 1/2 (10000 samples: standard error ~0.0024).
    assert abs(cos.mean() - 2.0 / 3.0) < 0.01
    assert abs(np.mean(cos ** 2) - 0.5) < 0.01
    # Azimuths are spread evenly: the mean direction is the normal.
    mean_dir = d.reshape(50, 200, 3).mean(axis=1)
    tangential = mean_dir - np.sum(mean_dir * unit, axis=1, keepdims=True) * unit
    assert np.abs(tangential).max() < 0.15


@pytest.mark.parametrize("kwargs, pattern", [
    ({"hit_points": np.zeros((2, 3)), "normals": np.zeros((3, 3))}, "shape"),
    ({"hit_points": np.zeros((2, 2)), "normals": np.zeros((2, 2))}, "shape"),
    ({"normals": np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 0.0]])}, r"1 zero vector.*row 1"),
    ({"n_dirs": 0}, "n_dirs"),
    ({"n_dirs": 2.0}, "n_dirs"),
    ({"offset": -1.0}, "offset"),
    ({"hit_points": np.array([[np.nan, 0.0, 0.0], [0.0, 0.0, 0.0]])}, "finite"),
])
def test_shadow_ray_errors(kwargs, pattern):
    args = {"hit_points": np.zeros((2, 3)), "normals": np.tile([0.0, 1.0, 0.0], (2, 1)), "n_dirs": 4}
    args.update(kwargs)
    with pytest.raises(InputError, match=pattern):
        raybench.shadow_rays(**args)


# ---------------------------------------------------------- against Embree


def _check_agreement(result: dict) -> None:
    for key in ("primary", "shadow"):
        r = result[key]
        assert THROUGHPUT_KEYS <= set(r)
        assert r["rays"] > 0
        assert r["penumbra_s"] > 0 and r["embree_s"] > 0
        assert r["penumbra_mrays_per_s"] > 0 and r["embree_mrays_per_s"] > 0 and r["ratio"] > 0
        assert r["ratio"] == pytest.approx(r["penumbra_mrays_per_s"] / r["embree_mrays_per_s"])
        assert r["mismatch_fraction"] <= 1.0 - HIT_AGREEMENT, (key, r)
        assert r["mismatch_fraction"] == r["mismatch_count"] / r["rays"]
    p, s = result["primary"], result["shadow"]
    assert 0.0 < p["hit_fraction"] < 1.0  # the scenes below have both hits and sky
    assert p["t_max_rel_diff"] <= T_RTOL
    assert p["same_triangle_fraction"] >= HIT_AGREEMENT
    assert 0.0 < s["occluded_fraction"] < 1.0
    assert s["rays"] == s["hits"] * s["dirs_per_hit"]
    assert s["hits"] == round(p["hit_fraction"] * p["rays"])
    assert result["triangles"] > 0 and result["embree_threads"] == 1 and isinstance(result["device"], str)


def test_measure_sphere_plane(sphere_plane):
    pytest.importorskip("embreex")
    desc, built = sphere_plane
    result = raybench.measure(desc, built, repeats=1, n_dirs=8)
    assert set(result) == {"device", "embree_version", "embree_threads", "triangles", "repeats", "primary",
                           "shadow"}
    assert result["primary"]["rays"] == 64 * 48
    assert result["triangles"] == 18 + 1280 + 12
    assert result["shadow"]["offset"] > 0
    _check_agreement(result)


def test_measure_bunny_on_a_plane(ctx, shared_data):
    pytest.importorskip("embreex")
    data = {
        "environment": {"map": "constant", "face_size": 8, "irradiance_face_size": 4},
        "camera": {"position": [0.0, 0.35, 3.4], "look_at": [0.0, -0.05, 0.0], "fov_deg": 40,
                   "resolution": [96, 72]},
        "object": [
            {"name": "bunny", "mesh": str(shared_data / "meshes" / "bunny_odedstein_3k.obj")},
            {"name": "ground", "primitive": "plane", "params": {"size": [8.0, 8.0]}, "translate": [0.0, -0.769, 0.0]},
        ],
    }
    desc = parse_scene(data)
    built = build_scene(desc, ctx)
    result = raybench.measure(desc, built, repeats=1, n_dirs=16, seed=3)
    _check_agreement(result)


def test_measure_rejects_bad_repeats(sphere_plane):
    pytest.importorskip("embreex")
    desc, built = sphere_plane
    with pytest.raises(InputError, match="repeats"):
        raybench.measure(desc, built, repeats=0)


def test_measure_rejects_a_scene_built_from_another_description(sphere_plane):
    pytest.importorskip("embreex")
    _, built = sphere_plane
    other = parse_scene({"object": [{"name": "lonely", "primitive": "box"}]})
    with pytest.raises(InputError, match="build_scene"):
        raybench.measure(other, built, repeats=1)
