"""Tests for penumbra.procedural: the lat-long convention, emitters' power, and closed outward shapes."""

from __future__ import annotations

import math

import numpy as np
import pytest

from penumbra import procedural as P
from penumbra.errors import InputError
from penumbra.meshio import Mesh

# --------------------------------------------------------------------------- #
# Lat-long convention
# --------------------------------------------------------------------------- #


def test_axis_directions_land_in_the_documented_pixels():
    w, h = 64, 32
    assert P.direction_to_pixel((0, 0, -1), w, h) == (0, h // 2)  # u = 0 is -z
    assert P.direction_to_pixel((1, 0, 0), w, h) == (w // 4, h // 2)  # u = 0.25 is +x
    assert P.direction_to_pixel((0, 0, 1), w, h) == (w // 2, h // 2)  # u = 0.5 is +z
    assert P.direction_to_pixel((-1, 0, 0), w, h) == (3 * w // 4, h // 2)  # u = 0.75 is -x
    assert P.direction_to_pixel((0, 1, 0), w, h)[1] == 0  # top row is +y
    assert P.direction_to_pixel((0, -1, 0), w, h)[1] == h - 1
    assert P.direction_to_pixel((1e-9, 0, -1), w, h) == (0, h // 2)
    assert P.direction_to_pixel((-1e-9, 0, -1), w, h) == (w - 1, h // 2)  # wraps to u just below 1


def test_pixel_centre_directions_round_trip():
    w, h = 40, 20
    d = P.latlong_directions(w, h)
    assert d.shape == (h, w, 3)
    np.testing.assert_allclose(np.linalg.norm(d, axis=2), 1.0)
    # Pixel (i=0, j) centre: u = 0.5 / w, so phi is small and the direction is close to -z.
    phi, theta = 2 * math.pi * 0.5 / w, math.pi * 3.5 / h
    np.testing.assert_allclose(d[3, 0], [math.sin(phi) * math.sin(theta), math.cos(theta),
                                         -math.cos(phi) * math.sin(theta)])
    for j in range(h):
        for i in range(w):
            assert P.direction_to_pixel(d[j, i], w, h) == (i, j)


def test_solid_angles_cover_the_sphere():
    for w, h in [(1, 1), (8, 4), (512, 256), (1000, 500)]:
        omega = P.latlong_row_solid_angles(w, h)
        assert omega.shape == (h,) and (omega > 0).all()
        assert omega.sum() * w == pytest.approx(4 * math.pi, rel=1e-12)
    np.testing.assert_allclose(P.envmap_integral(P.constant((1, 2, 3), 32, 16)), 4 * math.pi * np.array([1, 2, 3]),
                               rtol=1e-6)


# --------------------------------------------------------------------------- #
# Environment maps
# --------------------------------------------------------------------------- #


def sun_integral(**kwargs) -> np.ndarray:
    """Integral of the sun alone: the sky with the sun minus the same sky without it."""
    with_sun = P.sky(**kwargs)
    without = P.sky(**{**kwargs, "sun_radiance": 0.0})
    return P.envmap_integral(with_sun.astype(np.float64) - without)


def test_sky_basic_properties():
    env = P.sky()
    assert env.shape == (256, 512, 3) and env.dtype == np.float32 and env.flags.c_contiguous
    assert np.isfinite(env).all() and env.min() > 0
    sky = P.sky(sun_radiance=0.0)
    top, horizon, bottom = sky[2].mean(axis=0), sky[125].mean(axis=0), sky[-3].mean(axis=0)
    assert top[2] / top[0] > horizon[2] / horizon[0] > 1  # zenith bluer than the horizon
    assert bottom.sum() < 0.3 * horizon.sum()  # dim ground
    assert bottom[0] > bottom[2]  # grey-brown, not blue
    # Smooth, including across the horizon, where a hard edge would be one step of ~90% of the range.
    rows = sky.mean(axis=1).sum(axis=1)
    assert np.max(np.abs(np.diff(rows))) < 0.3 * (rows.max() - rows.min())
    columns = sky[60].sum(axis=1)
    assert np.max(np.abs(np.diff(columns)) / columns[1:]) < 0.1
    # The sun is 1e4 to 1e5 times brighter than the typical sky.
    assert 1e4 <= env.max() / np.median(sky) <= 1e5


@pytest.mark.parametrize("sun_direction", [(0.4, 0.6, 0.3), (-0.7, 0.2, -0.1), (0.0, 0.3, -1.0), (0.1, -0.2, 0.9)])
def test_sky_is_brightest_at_the_sun(sun_direction):
    w, h = 256, 128
    i, j = P.direction_to_pixel(sun_direction, w, h)
    env = P.sky(w, h, sun_direction=sun_direction)
    assert np.unravel_index(np.argmax(env.sum(axis=2)), (h, w)) == (j, i)
    # Without the disc, the glow still makes the sky brightest near the sun (when it is above the horizon).
    if sun_direction[1] > 0:
        sky = P.sky(w, h, sun_direction=sun_direction, sun_radiance=0.0)
        jj, ii = np.unravel_index(np.argmax(sky.sum(axis=2)), (h, w))
        sun = np.asarray(sun_direction) / np.linalg.norm(sun_direction)
        assert math.degrees(math.acos(P.latlong_directions(w, h)[jj, ii] @ sun)) < 3.0


@pytest.mark.parametrize("width, height", [(512, 256), (256, 128), (64, 32), (16, 8)])
@pytest.mark.parametrize("radius_deg", [1.5, 0.2, 4.0])
@pytest.mark.parametrize("sun_direction", [(0.4, 0.6, 0.3), (0.0, 1.0, 0.0), (1e-3, 0.1, -1.0)])
def test_sun_power(width, height, radius_deg, sun_direction):
    """The sun's integral is radiance * 2 pi (1 - cos r), also when it is far smaller than a pixel,
    at the pole and on the u = 0 seam."""
    radiance = np.array([1.0e4, 2.0e4, 3.0e4])
    integral = sun_integral(width=width, height=height, sun_direction=sun_direction,
                            sun_angular_radius_deg=radius_deg, sun_radiance=radiance)
    expected = radiance * 2 * math.pi * (1 - math.cos(math.radians(radius_deg)))
    np.testing.assert_allclose(integral, expected, rtol=0.01)


def test_sun_disc_is_round_and_centred():
    w, h = 1024, 512
    direction = np.array([0.4, 0.6, 0.3]) / np.linalg.norm([0.4, 0.6, 0.3])
    env = P.sky(w, h, sun_direction=direction, sun_angular_radius_deg=3.0).astype(np.float64)
    sun = env - P.sky(w, h, sun_direction=direction, sun_angular_radius_deg=3.0, sun_radiance=0.0)
    weight = sun[..., 0] * P.latlong_row_solid_angles(w, h)[:, None]
    d = P.latlong_directions(w, h)
    centroid = (weight[..., None] * d).sum(axis=(0, 1))
    assert math.degrees(math.acos(centroid @ direction / np.linalg.norm(centroid))) < 0.05
    angle = np.degrees(np.arccos(np.clip(d @ direction, -1, 1)))
    assert (sun[angle < 2.6] > 0.999 * 1e4 * np.array([1.0, 0.96, 0.88])).all()  # full radiance inside
    assert (sun[angle > 3.4] == 0).all()  # nothing outside the rim pixels
    rim = sun[(angle > 2.9) & (angle < 3.1), 0]
    assert ((rim > 0) & (rim < 1e4)).any()  # partially covered pixels


@pytest.mark.parametrize("direction", [(0.3, 0.8, -0.2), (0, 1, 0), (0, -1, 0), (0, 0, -1), (-1, 0.001, 0)])
def test_directional_integrates_exactly(direction):
    irradiance = np.array([3.0, 2.0, 1.0])
    env = P.directional(direction, irradiance, 512, 256)
    assert env.dtype == np.float32 and env.shape == (256, 512, 3)
    nonzero = np.argwhere(env.sum(axis=2) > 0)
    i, j = P.direction_to_pixel(direction, 512, 256)
    assert nonzero.tolist() == [[j, i]]
    np.testing.assert_allclose(P.envmap_integral(env), irradiance, rtol=1e-6)


def test_two_area_lights():
    env = P.two_area_lights()
    assert env.shape == (256, 512, 3) and env.dtype == np.float32 and env.min() >= 0
    expected = np.zeros(3)
    for (t0, t1), (p0, p1), radiance in [((30, 50), (40, 80), (24, 14, 5)), ((55, 80), (200, 250), (4, 8, 18))]:
        solid = math.radians(p1 - p0) * (math.cos(math.radians(t0)) - math.cos(math.radians(t1)))
        expected += np.array(radiance) * solid
    for w, h in [(512, 256), (100, 50), (37, 19)]:
        np.testing.assert_allclose(P.envmap_integral(P.two_area_lights(w, h)), expected, rtol=1e-5)
    warm = env[int(40 / 180 * 256), int(60 / 360 * 512)]
    cool = env[int(67 / 180 * 256), int(225 / 360 * 512)]
    assert warm[0] > warm[2] and cool[2] > cool[0]
    # Edges are area-weighted: at a coarse size some pixels are partially covered.
    coarse = P.two_area_lights(37, 19)[..., 0]
    assert ((coarse > 0) & (coarse < 23.9)).any()


def test_constant():
    env = P.constant((0.5, 1.0, 2.0))
    assert env.shape == (32, 64, 3) and env.dtype == np.float32
    assert (env == np.float32([0.5, 1.0, 2.0])).all()
    assert P.constant(3.0, 8, 4).tolist() == np.full((4, 8, 3), 3.0).tolist()


def test_envmap_argument_errors():
    with pytest.raises(InputError):
        P.sky(sun_direction=(0, 0, 0))
    with pytest.raises(InputError):
        P.sky(sun_angular_radius_deg=0)
    with pytest.raises(InputError):
        P.directional((1, 0, 0), (-1, 0, 0))
    with pytest.raises(InputError):
        P.constant((1, 1, 1), width=0)
    with pytest.raises(InputError):
        P.constant((float("nan"), 1, 1))


# --------------------------------------------------------------------------- #
# Shapes
# --------------------------------------------------------------------------- #


def volume(mesh: Mesh) -> float:
    v = mesh.vertices.astype(np.float64)
    a, b, c = (v[mesh.faces[:, k]] for k in range(3))
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


def welded_faces(mesh: Mesh) -> np.ndarray:
    """Faces re-indexed so that vertices at exactly the same position share an index."""
    _, inverse = np.unique(mesh.vertices, axis=0, return_inverse=True)
    return inverse.reshape(-1)[mesh.faces.astype(np.int64)]


def assert_closed_and_consistent(faces: np.ndarray) -> None:
    """Every edge is shared by exactly two faces, traversed in opposite directions (closed, oriented)."""
    directed = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    assert len(np.unique(directed, axis=0)) == len(directed), "a directed edge is used twice"
    undirected, counts = np.unique(np.sort(directed, axis=1), axis=0, return_counts=True)
    assert (counts == 2).all(), f"{np.sum(counts != 2)} edges are not shared by exactly two faces"


def triangle_normals(mesh: Mesh) -> np.ndarray:
    v = mesh.vertices.astype(np.float64)
    a, b, c = (v[mesh.faces[:, k]] for k in range(3))
    return np.cross(b - a, c - a)


def torus_knot_length(mesh_kwargs: dict) -> float:
    p, q, radius = mesh_kwargs.get("p", 2), mesh_kwargs.get("q", 3), mesh_kwargs.get("radius", 1.0)
    t = np.linspace(0, 2 * math.pi, 200001)
    ring = 2 + np.cos(q * t)
    curve = radius / 3 * np.stack([ring * np.cos(p * t), np.sin(q * t), ring * np.sin(p * t)], axis=1)
    return float(np.linalg.norm(np.diff(curve, axis=0), axis=1).sum())


def polygon_area_factor(n: int) -> float:
    """Area of a regular n-gon inscribed in the unit circle, over pi."""
    return n / 2 * math.sin(2 * math.pi / n) / math.pi


# (factory, kwargs, expected volume, relative tolerance)
CLOSED_SHAPES = {
    "sphere": (P.sphere, {}, 4 / 3 * math.pi, 0.02),
    "sphere_r2_s3": (P.sphere, {"radius": 2.0, "subdivisions": 3}, 4 / 3 * math.pi * 8, 0.02),
    "box": (P.box, {"size": (1.0, 2.0, 3.0)}, 6.0, 1e-6),
    "torus": (P.torus, {}, 2 * math.pi**2 * 1.0 * 0.3**2, 0.02),
    "cylinder": (P.cylinder, {}, math.pi * 2 * polygon_area_factor(64), 1e-5),
    "cone": (P.cone, {}, math.pi * 2 / 3 * polygon_area_factor(64), 1e-5),
    "torus_knot": (P.torus_knot, {}, math.pi * 0.12**2 * torus_knot_length({}) * polygon_area_factor(24), 0.02),
    "rounded_cube": (P.rounded_cube, {}, 0.7**3 + 6 * 0.7**2 * 0.15 + 3 * math.pi * 0.7 * 0.15**2
                     + 4 / 3 * math.pi * 0.15**3, 0.01),
}


@pytest.mark.parametrize("name", sorted(CLOSED_SHAPES))
def test_closed_shapes(name):
    factory, kwargs, expected_volume, tolerance = CLOSED_SHAPES[name]
    mesh = factory(**kwargs)
    assert isinstance(mesh, Mesh)
    assert mesh.vertices.dtype == np.float32 and mesh.faces.dtype == np.uint32 and mesh.normals.dtype == np.float32
    assert_closed_and_consistent(welded_faces(mesh))
    # Outward winding: positive signed volume, close to the analytic one.
    assert volume(mesh) == pytest.approx(expected_volume, rel=tolerance)
    # No degenerate triangles.
    areas = np.linalg.norm(triangle_normals(mesh), axis=1) / 2
    assert areas.min() > 1e-6 * areas.mean()
    # Unit normals that agree with the winding of every triangle using them.
    np.testing.assert_allclose(np.linalg.norm(mesh.normals, axis=1), 1.0, atol=1e-6)
    unit_face = triangle_normals(mesh) / (2 * areas[:, None])
    for k in range(3):
        assert np.einsum("ij,ij->i", mesh.normals[mesh.faces[:, k]], unit_face).min() > 0.5
    # Centred at the origin (the torus knot is centred by symmetry, not by its bounding box).
    centre = mesh.vertices.mean(axis=0) if name == "torus_knot" else (mesh.vertices.min(0) + mesh.vertices.max(0)) / 2
    np.testing.assert_allclose(centre, 0.0, atol=1e-3)


def test_smooth_shapes_have_analytic_normals():
    sphere = P.sphere(radius=2.0)
    np.testing.assert_allclose(sphere.normals, sphere.vertices / 2.0, atol=1e-6)
    np.testing.assert_allclose(np.linalg.norm(sphere.vertices, axis=1), 2.0, rtol=1e-6)
    torus = P.torus(R=1.0, r=0.3)
    ring = torus.vertices.astype(np.float64).copy()
    ring[:, 1] = 0
    ring = ring / np.linalg.norm(ring, axis=1, keepdims=True)  # nearest point of the centre circle
    np.testing.assert_allclose(torus.normals, (torus.vertices - ring) / 0.3, atol=1e-5)


def test_sphere_counts():
    for s in range(4):
        mesh = P.sphere(subdivisions=s)
        assert (mesh.num_vertices, mesh.num_faces) == (10 * 4**s + 2, 20 * 4**s)


def test_box():
    mesh = P.box((2.0, 4.0, 6.0))
    assert mesh.num_vertices == 24 and mesh.num_faces == 12
    np.testing.assert_array_equal(mesh.vertices.min(axis=0), [-1, -2, -3])
    np.testing.assert_array_equal(mesh.vertices.max(axis=0), [1, 2, 3])
    # Flat normals: the three corners of every triangle share the normal, which is the face's.
    face = triangle_normals(mesh)
    face /= np.linalg.norm(face, axis=1, keepdims=True)
    for k in range(3):
        np.testing.assert_allclose(mesh.normals[mesh.faces[:, k]], face, atol=1e-7)
    assert sorted(map(tuple, np.unique(mesh.normals, axis=0).astype(int).tolist())) == sorted(
        [(1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0), (0, 0, 1), (0, 0, -1)])


@pytest.mark.parametrize("subdivisions", [1, 4])
def test_plane(subdivisions):
    mesh = P.plane((10.0, 6.0), subdivisions)
    assert mesh.num_vertices == (subdivisions + 1) ** 2 and mesh.num_faces == 2 * subdivisions**2
    assert (mesh.vertices[:, 1] == 0).all()
    np.testing.assert_array_equal(mesh.vertices.min(axis=0), [-5, 0, -3])
    np.testing.assert_array_equal(mesh.vertices.max(axis=0), [5, 0, 3])
    normals = triangle_normals(mesh)
    assert (normals[:, 1] > 0).all() and np.allclose(normals[:, [0, 2]], 0)
    assert (mesh.normals == np.float32([0, 1, 0])).all()
    assert np.linalg.norm(normals, axis=1).sum() / 2 == pytest.approx(60.0)
    # Open: the boundary edges are used once.
    directed = np.concatenate([mesh.faces[:, [0, 1]], mesh.faces[:, [1, 2]], mesh.faces[:, [2, 0]]])
    _, counts = np.unique(np.sort(directed, axis=1), axis=0, return_counts=True)
    assert (counts == 1).sum() == 4 * subdivisions


def test_shapes_are_deterministic():
    for factory in (P.sphere, P.torus, P.torus_knot, P.rounded_cube, P.cone, P.cylinder):
        a, b = factory(), factory()
        assert np.array_equal(a.vertices, b.vertices) and np.array_equal(a.faces, b.faces)


def test_shape_argument_errors():
    with pytest.raises(InputError):
        P.sphere(radius=-1)
    with pytest.raises(InputError):
        P.box((1, 0, 1))
    with pytest.raises(InputError):
        P.torus(R=1, r=2)
    with pytest.raises(InputError):
        P.torus_knot(p=2, q=4)
    with pytest.raises(InputError):
        P.rounded_cube(size=1, radius=0.6)
    with pytest.raises(InputError):
        P.plane(subdivisions=0)


# --------------------------------------------------------------------------- #
# Terrain
# --------------------------------------------------------------------------- #


def test_terrain_heights():
    heights = P.terrain_heights(128, 64, seed=3)
    assert heights.shape == (64, 128) and heights.dtype == np.float32
    assert np.isfinite(heights).all() and heights.min() >= -1 and heights.max() <= 1
    assert heights.std() > 0.05  # not flat
    assert np.array_equal(heights, P.terrain_heights(128, 64, seed=3))  # deterministic
    assert not np.allclose(heights, P.terrain_heights(128, 64, seed=4))  # the seed matters
    # Continuous: neighbouring samples differ much less than the overall range.
    assert np.abs(np.diff(heights, axis=1)).max() < 0.25 * (heights.max() - heights.min())
    assert np.abs(np.diff(heights, axis=0)).max() < 0.25 * (heights.max() - heights.min())
    # The same x extent sampled twice as densely agrees at shared positions' neighbourhood (fixed lattice).
    fine = P.terrain_heights(256, 128, seed=3)
    coarse_from_fine = fine.reshape(64, 2, 128, 2).mean(axis=(1, 3))
    assert np.abs(coarse_from_fine - heights).mean() < 0.05


# --------------------------------------------------------------------------- #
# Hostile arguments: types and resource limits (docs/reliability.md)
# --------------------------------------------------------------------------- #


@pytest.mark.parametrize("maker, kwargs, words", [
    (P.sky, {"width": "abc"}, "width must be an integer, got 'abc'"),
    (P.sky, {"width": math.inf}, "width must be an integer, got inf"),
    (P.sky, {"height": 1.5}, "height must be an integer"),
    (P.sky, {"width": True}, "width must be an integer"),
    (P.sky, {"sun_radiance": [1, 2]}, r"sun_radiance must be one number or 3 numbers \(RGB\), got \[1, 2\]"),
    (P.sky, {"sun_radiance": "bright"}, "sun_radiance must be one number or 3 numbers"),
    (P.sky, {"sun_direction": "up"}, "sun_direction must be 3 finite numbers"),
    (P.sky, {"sun_angular_radius_deg": "x"}, "sun_angular_radius_deg must be a finite number"),
    (P.constant, {"value": {"r": 1}}, "value must be one number or 3 numbers"),
    (P.directional, {"direction": [0, 1], "irradiance_rgb": 1}, "direction must be 3 finite numbers"),
    (P.sphere, {"radius": "big"}, "radius must be a positive finite number, got 'big'"),
    (P.sphere, {"subdivisions": 10**400}, r"subdivisions = 1000.*\(401 characters\) is above 8"),
    (P.box, {"size": ["a", 1, 1]}, "size must be 3 positive finite numbers"),
    (P.plane, {"size": 5}, "size must be 2 positive finite numbers"),
    (P.plane, {"size": "ab"}, "size must be 2 positive finite numbers"),
    (P.torus, {"segments": "many"}, "segments must be an integer"),
    (P.terrain_heights, {"nx": 8, "ny": 8, "seed": "s"}, "seed must be an integer"),
])
def test_wrong_types_are_input_errors_naming_the_argument(maker, kwargs, words):
    with pytest.raises(InputError, match=words):
        maker(**kwargs)


@pytest.mark.parametrize("maker, kwargs, limit", [
    (P.sphere, {"subdivisions": 12}, "above 8, the limit"),
    (P.sphere, {"subdivisions": 9}, "above 8, the limit"),
    (P.plane, {"subdivisions": 100000}, "above 1448, the limit"),
    (P.sky, {"width": 100000}, f"above {P.MAX_ENV_WIDTH}, the limit"),
    (P.sky, {"width": 4096, "height": 4096}, "MAX_ENV_PIXELS"),
    (P.constant, {"width": 1 << 40, "height": 1}, f"above {P.MAX_ENV_WIDTH}, the limit"),
    (P.two_area_lights, {"width": 8192, "height": 4096}, "MAX_ENV_PIXELS"),
    (P.torus, {"segments": 60000, "tube_segments": 60000}, "MAX_TRIANGLES"),
    (P.torus_knot, {"segments": 1 << 15, "tube_segments": 1 << 10}, "MAX_TRIANGLES"),
    (P.cylinder, {"segments": 1 << 30}, f"above {P.MAX_SEGMENTS}, the limit"),
    (P.cone, {"segments": 1 << 30}, f"above {P.MAX_SEGMENTS}, the limit"),
    (P.rounded_cube, {"segments": 2000}, "MAX_TRIANGLES"),
    (P.terrain_heights, {"nx": 100000, "ny": 1}, f"above {P.MAX_TERRAIN_SIDE}, the limit"),
    (P.terrain_heights, {"nx": 16384, "ny": 16384}, "MAX_TERRAIN_SAMPLES"),
    (P.terrain_heights, {"nx": 8, "ny": 8, "octaves": 1000}, f"above {P.MAX_OCTAVES}, the limit"),
])
def test_sizes_beyond_the_limits_are_refused_at_once(maker, kwargs, limit):
    import time

    t0 = time.perf_counter()
    with pytest.raises(InputError, match=limit):
        maker(**kwargs)
    assert time.perf_counter() - t0 < 1.0      # refused before any work


def test_sizes_at_the_limits_are_accepted():
    assert P.MAX_TRIANGLES >= 20 * 4**8
    assert len(P.sky(P.MAX_ENV_WIDTH, P.MAX_ENV_PIXELS // P.MAX_ENV_WIDTH, sun_radiance=1.0)) == \
        P.MAX_ENV_PIXELS // P.MAX_ENV_WIDTH
    assert len(P.plane(subdivisions=1448).faces) <= P.MAX_TRIANGLES
    assert P.terrain_heights(P.MAX_TERRAIN_SIDE, 4, octaves=P.MAX_OCTAVES).shape == (4, P.MAX_TERRAIN_SIDE)
