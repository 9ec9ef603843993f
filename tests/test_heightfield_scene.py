"""Height fields on the Python side (penumbra.heightfield) and their scene-file
tables (``[[heightfield]]`` in penumbra.scenefile): validation, the mesh and its
winding, normals (docs/heightfield.md), bilinear lookup, file loaders,
procedural terrains and scene parsing. Pure Python: no device is needed."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from penumbra.errors import InputError
from penumbra.heightfield import (
    TERRAINS,
    HeightField,
    city_blocks,
    cones,
    cones_circle,
    cones_circle_light,
    egg_tray,
    fbm,
    flat,
    load_albedo,
    load_heights,
    make_terrain,
    sine_grating,
    terrain_parameters,
)
from heightfield64 import vertex_normals
from penumbra.meshio import Mesh
from penumbra.methods.heightfield import HeightfieldDesc, HeightFieldHandle
from penumbra.scenefile import apply_overrides, load_scene, parse_scene

RNG = np.random.default_rng(1234)


def random_field(width=5, depth=3, **kw) -> HeightField:
    return HeightField(RNG.random((depth, width)), **kw)


def library_mesh(ctx, hf: HeightField) -> Mesh:
    """The library's triangle mesh of ``hf`` (pn_heightfield_build_mesh), read back."""
    native = HeightFieldHandle(ctx, hf.heights, origin=hf.origin, size=hf.size, height_scale=hf.height_scale)
    return Mesh(*native.mesh().geometry())


def library_normals(ctx, hf: HeightField) -> np.ndarray:
    return library_mesh(ctx, hf).normals


def triangle_normals(mesh) -> np.ndarray:
    v = mesh.vertices.astype(np.float64)
    f = mesh.faces.astype(np.int64)
    return np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])


# ---------------------------------------------------------------- validation


def test_heights_are_stored_as_contiguous_float32():
    h = np.arange(12, dtype=np.float64).reshape(3, 4)[:, ::-1]  # not contiguous
    hf = HeightField(h, origin=[1, 2, 3], size=[3, 2], height_scale=2)
    assert hf.heights.dtype == np.float32 and hf.heights.flags.c_contiguous
    np.testing.assert_array_equal(hf.heights, h)
    assert (hf.width, hf.depth) == (4, 3)
    assert hf.origin == (1.0, 2.0, 3.0) and hf.size == (3.0, 2.0) and hf.height_scale == 2.0
    assert hf.albedo is None


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf, 1e39])
def test_non_finite_heights_name_count_and_first_position(bad):
    h = np.zeros((4, 6))
    h[1, 2] = bad
    h[3, 0] = bad
    with pytest.raises(InputError, match=r"heights contain 2 NaN/Inf.*first at row 1, column 2"):
        HeightField(h)


@pytest.mark.parametrize("shape", [(5,), (3, 4, 1), (2, 2, 2), ()])
def test_heights_must_be_2d(shape):
    with pytest.raises(InputError, match="2D array"):
        HeightField(np.zeros(shape))


@pytest.mark.parametrize("shape, text", [((3, 1), "3 rows x 1 columns"), ((1, 3), "1 rows x 3 columns"),
                                         ((1, 1), "1 rows x 1 columns"), ((0, 4), "0 rows x 4 columns")])
def test_heights_need_two_samples_per_axis(shape, text):
    with pytest.raises(InputError, match=rf"at least 2 rows and 2 columns.*{text}"):
        HeightField(np.zeros(shape))


@pytest.mark.parametrize("heights", [np.array([["a", "b"], ["c", "d"]]), np.ones((2, 2), dtype=bool),
                                     np.ones((2, 2), dtype=complex)])
def test_heights_must_be_real_numbers(heights):
    with pytest.raises(InputError, match="real numeric"):
        HeightField(heights)


@pytest.mark.parametrize("size", [(0, 1), (1, -2), (np.nan, 1), (1, np.inf), (1,), (1, 2, 3), "ab"])
def test_sizes_must_be_two_positive_finite_numbers(size):
    with pytest.raises(InputError, match="size"):
        HeightField(np.zeros((2, 2)), size=size)


@pytest.mark.parametrize("origin", [(0, 0), (0, np.nan, 0), (np.inf, 0, 0)])
def test_origin_must_be_three_finite_numbers(origin):
    with pytest.raises(InputError, match="origin"):
        HeightField(np.zeros((2, 2)), origin=origin)


@pytest.mark.parametrize("scale", [np.nan, np.inf, True, "1", None])
def test_height_scale_must_be_finite(scale):
    with pytest.raises(InputError, match="height_scale"):
        HeightField(np.zeros((2, 2)), height_scale=scale)


def test_albedo_constant_and_map():
    hf = HeightField(np.zeros((3, 4)), albedo=(0.1, 0.2, 0.3))
    assert hf.albedo.dtype == np.float32 and hf.albedo.shape == (3,)
    np.testing.assert_allclose(hf.vertex_albedo(), np.tile([0.1, 0.2, 0.3], (12, 1)), rtol=1e-6)
    amap = RNG.random((3, 4, 3))
    hf = HeightField(np.zeros((3, 4)), albedo=amap)
    np.testing.assert_allclose(hf.vertex_albedo(), amap.reshape(-1, 3), rtol=1e-6)
    np.testing.assert_allclose(HeightField(np.zeros((3, 4))).vertex_albedo((0.5, 0.5, 0.5)), 0.5)


def test_albedo_errors():
    amap = np.full((3, 4, 3), 0.5)
    amap[2, 1, 0] = np.nan
    with pytest.raises(InputError, match=r"albedo contains 1 NaN/Inf.*row 2, column 1"):
        HeightField(np.zeros((3, 4)), albedo=amap)
    with pytest.raises(InputError, match=r"\(D, W, 3\) = \(3, 4, 3\).*\(4, 3, 3\)"):
        HeightField(np.zeros((3, 4)), albedo=np.zeros((4, 3, 3)))
    with pytest.raises(InputError, match=r"\[0, 1\]"):
        HeightField(np.zeros((3, 4)), albedo=(0.5, 1.5, 0.5))
    with pytest.raises(InputError, match="shape"):
        HeightField(np.zeros((3, 4)), albedo=(0.5, 0.5))


# ---------------------------------------------------------------- placement and mesh


def test_spacing_world_heights_and_bounds():
    h = np.array([[0.0, 1.0, 0.5], [0.25, -0.5, 0.0]])
    hf = HeightField(h, origin=(1, 2, 3), size=(4, 5), height_scale=-2)
    assert hf.spacing == (2.0, 5.0)
    np.testing.assert_array_equal(hf.world_heights, -2 * h)
    lo, hi = hf.bounds
    assert lo == (1.0, 2.0 - 2.0, 3.0) and hi == (5.0, 2.0 + 1.0, 8.0)


@pytest.mark.parametrize("width, depth", [(5, 3), (2, 2), (3, 7), (8, 8)])
def test_mesh_vertices_follow_the_placement(ctx, width, depth):
    hf = random_field(width, depth, origin=(-1.5, 0.25, 2.0), size=(3.0, 4.5), height_scale=1.7)
    mesh = library_mesh(ctx, hf)
    assert mesh.num_vertices == width * depth
    sx, sz = 3.0 / (width - 1), 4.5 / (depth - 1)
    for j in range(depth):
        for i in range(width):
            expected = (-1.5 + i * sx, 0.25 + 1.7 * hf.heights[j, i], 2.0 + j * sz)
            np.testing.assert_allclose(mesh.vertices[j * width + i], expected, rtol=1e-6, atol=1e-6)


@pytest.mark.parametrize("width, depth", [(5, 3), (2, 2), (3, 7)])
def test_mesh_triangles_tile_the_grid_facing_up(ctx, width, depth):
    hf = random_field(width, depth, size=(2.0, 3.0), height_scale=3.0)
    mesh = library_mesh(ctx, hf)
    assert mesh.num_faces == 2 * (width - 1) * (depth - 1)
    assert set(mesh.faces.ravel().tolist()) == set(range(width * depth))
    n = triangle_normals(mesh)
    # Seen from +y every triangle is counter-clockwise, whatever the heights ...
    assert (n[:, 1] > 0).all()
    # ... and their footprints cover the rectangle exactly once (the y component is twice the projected area).
    np.testing.assert_allclose(n[:, 1].sum() / 2, 2.0 * 3.0, rtol=1e-6)
    # Each cell's two triangles use exactly its four corners.
    f = mesh.faces.astype(np.int64).reshape(-1, 2, 3)
    for cell, tris in enumerate(f):
        j, i = divmod(cell, width - 1)
        corners = {j * width + i, j * width + i + 1, (j + 1) * width + i, (j + 1) * width + i + 1}
        assert set(tris.ravel().tolist()) == corners


def test_flat_field_triangles_and_vertex_normals_point_up(ctx):
    hf = HeightField(np.full((4, 7), 0.3), origin=(0, -1, 0), size=(6, 3), height_scale=5)
    mesh = library_mesh(ctx, hf)
    n = triangle_normals(mesh)
    np.testing.assert_allclose(n / np.linalg.norm(n, axis=1, keepdims=True), np.tile([0, 1, 0], (len(n), 1)),
                               atol=1e-7)
    np.testing.assert_array_equal(mesh.normals, np.tile(np.float32([0, 1, 0]), (28, 1)))
    np.testing.assert_allclose(mesh.vertices[:, 1], -1 + 5 * 0.3, rtol=1e-6)


def test_mesh_normals_are_the_vertex_normals_and_agree_with_the_triangles(ctx):
    hf = HeightField(make_terrain("fbm", 21, 13, seed=3), size=(4, 2.4), height_scale=0.3)
    mesh = library_mesh(ctx, hf)
    # The normals are normalize(-dH/dx, 1, -dH/dz) by central differences (tests/heightfield64.py).
    want = vertex_normals(hf.world_heights, *hf.spacing).reshape(-1, 3)
    np.testing.assert_allclose(mesh.normals, want, atol=2e-6)
    np.testing.assert_allclose(np.linalg.norm(mesh.normals, axis=1), 1, rtol=1e-6)
    # The area-weighted triangle normals around an interior vertex lean the same way as its normal.
    n = triangle_normals(mesh)
    acc = np.zeros((mesh.num_vertices, 3))
    for k in range(3):
        np.add.at(acc, mesh.faces[:, k].astype(np.int64), n)
    acc /= np.linalg.norm(acc, axis=1, keepdims=True)
    assert (np.einsum("ij,ij->i", acc, mesh.normals) > 0.9).all()


@pytest.mark.parametrize("axis", ["x", "z"])
def test_normals_on_a_plane_slope_account_for_spacing_and_scale(ctx, axis):
    width, depth, a, scale = 6, 4, 0.3, 2.5
    size = (7.5, 1.5)  # sx = 1.5, sz = 0.5
    i = np.arange(width)[None, :] * np.ones((depth, 1))
    j = np.arange(depth)[:, None] * np.ones((1, width))
    hf = HeightField(a * (i if axis == "x" else j), size=size, height_scale=scale)
    sx, sz = hf.spacing
    slope = a * scale / (sx if axis == "x" else sz)  # dH/dx or dH/dz in world units
    expected = np.array([-slope, 1.0, 0.0] if axis == "x" else [0.0, 1.0, -slope])
    expected /= np.linalg.norm(expected)
    np.testing.assert_allclose(library_normals(ctx, hf), np.tile(expected, (width * depth, 1)), atol=1e-6)
    # And the triangles of the mesh lie in that plane.
    n = triangle_normals(library_mesh(ctx, hf))
    np.testing.assert_allclose(n / np.linalg.norm(n, axis=1, keepdims=True), np.tile(expected, (len(n), 1)),
                               atol=1e-6)


def test_normals_use_central_differences_inside_and_one_sided_on_the_border(ctx):
    width, depth = 5, 3
    i = np.arange(width, dtype=np.float64)
    hf = HeightField(np.tile(i**2, (depth, 1)), size=(width - 1, 2.0))  # sx = 1, H = i^2
    dhdx = np.array([1.0, 2.0, 4.0, 6.0, 7.0])  # (1-0), central 2i, (16-9)
    expected = np.stack([-dhdx, np.ones(width), np.zeros(width)], axis=1)
    expected /= np.linalg.norm(expected, axis=1, keepdims=True)
    for row in library_normals(ctx, hf).reshape(depth, width, 3):
        np.testing.assert_allclose(row, expected, atol=1e-6)


# ---------------------------------------------------------------- bilinear lookup


def test_height_at_vertices_cells_and_bilinear_functions():
    width, depth = 5, 4
    i = np.arange(width)[None, :]
    j = np.arange(depth)[:, None]
    h = 0.2 + 0.1 * i - 0.05 * j + 0.03 * i * j  # bilinear in (i, j): reproduced exactly
    hf = HeightField(h, origin=(1.0, -2.0, 3.0), size=(8.0, 1.5), height_scale=2.0)
    sx, sz = hf.spacing
    assert hf.height_at(1.0 + 2 * sx, 3.0 + 1 * sz) == pytest.approx(-2.0 + 2.0 * h[1, 2], rel=1e-6)
    fi = RNG.uniform(0, width - 1, 50)
    fj = RNG.uniform(0, depth - 1, 50)
    y = hf.height_at(1.0 + fi * sx, 3.0 + fj * sz)
    assert y.shape == (50,)
    np.testing.assert_allclose(y, -2.0 + 2.0 * (0.2 + 0.1 * fi - 0.05 * fj + 0.03 * fi * fj), rtol=1e-6,
                               atol=1e-6)


def test_height_at_cell_centre_and_outside():
    hf = HeightField(np.array([[0.0, 1.0], [2.0, 5.0]]), size=(2.0, 2.0))
    assert hf.height_at(1.0, 1.0) == pytest.approx(2.0)  # mean of the four corners
    assert hf.height_at(0.5, 0.0) == pytest.approx(0.25)
    # Outside, the border continues (clamp to edge).
    assert hf.height_at(-3.0, -3.0) == pytest.approx(0.0)
    assert hf.height_at(9.0, 1.0) == pytest.approx(3.0)
    assert hf.height_at(1.0, 9.0) == pytest.approx(3.5)
    assert hf.height_at(np.zeros((2, 3)), 2.0).shape == (2, 3)


# ---------------------------------------------------------------- loaders


def test_npy_round_trip(tmp_path):
    h = RNG.random((5, 7))
    np.save(tmp_path / "h.npy", h)
    out = load_heights(tmp_path / "h.npy")
    assert out.dtype == np.float32 and out.shape == (5, 7)
    np.testing.assert_array_equal(out, h.astype(np.float32))
    np.save(tmp_path / "h1.npy", h[..., None])
    np.testing.assert_array_equal(load_heights(tmp_path / "h1.npy"), out)


def test_npy_errors_name_the_file(tmp_path):
    np.save(tmp_path / "flat.npy", np.zeros(6))
    with pytest.raises(InputError, match=r"flat\.npy.*2D"):
        load_heights(tmp_path / "flat.npy")
    bad = np.zeros((3, 3))
    bad[2, 1] = np.nan
    np.save(tmp_path / "nan.npy", bad)
    with pytest.raises(InputError, match=r"nan\.npy.*1 NaN/Inf.*row 2, column 1"):
        load_heights(tmp_path / "nan.npy")
    (tmp_path / "junk.npy").write_bytes(b"not a numpy file")
    with pytest.raises(InputError, match=r"junk\.npy"):
        load_heights(tmp_path / "junk.npy")


def test_png_16_bit_round_trip(tmp_path):
    from PIL import Image

    raw = RNG.integers(0, 65536, size=(6, 9), dtype=np.uint16)
    raw[0, 0], raw[-1, -1] = 0, 65535
    Image.fromarray(raw).save(tmp_path / "h16.png")
    out = load_heights(tmp_path / "h16.png")
    assert out.shape == (6, 9) and out.dtype == np.float32
    np.testing.assert_allclose(out, raw / 65535.0, rtol=1e-6, atol=1e-7)
    assert out[0, 0] == 0.0 and out[-1, -1] == 1.0


def test_png_8_bit_is_accepted_and_colour_refused(tmp_path):
    from PIL import Image

    raw = RNG.integers(0, 256, size=(4, 5), dtype=np.uint8)
    Image.fromarray(raw, "L").save(tmp_path / "h8.png")
    np.testing.assert_allclose(load_heights(tmp_path / "h8.png"), raw / 255.0, rtol=1e-6)
    Image.fromarray(np.repeat(raw[..., None], 3, axis=2), "RGB").save(tmp_path / "rgb.png")
    with pytest.raises(InputError, match=r"rgb\.png.*greyscale.*mode RGB"):
        load_heights(tmp_path / "rgb.png")


def test_exr_single_channel_round_trip(tmp_path):
    import OpenEXR

    h = RNG.random((5, 6)).astype(np.float32)
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    OpenEXR.File(header, {"height": h}).write(str(tmp_path / "h.exr"))
    np.testing.assert_array_equal(load_heights(tmp_path / "h.exr"), h)


def test_exr_rgb_takes_the_red_channel(tmp_path):
    from penumbra.imageio import write_exr

    h = RNG.random((4, 7)).astype(np.float32)
    write_exr(tmp_path / "rgb.exr", np.stack([h, 1 - h, np.zeros_like(h)], axis=2))
    np.testing.assert_array_equal(load_heights(tmp_path / "rgb.exr"), h)


def test_loader_errors_name_the_file(tmp_path):
    with pytest.raises(InputError, match=r"missing\.png: file not found"):
        load_heights(tmp_path / "missing.png")
    with pytest.raises(InputError, match=r"h\.tif.*unsupported.*\.npy, \.exr, \.png"):
        load_heights(tmp_path / "h.tif")
    (tmp_path / "broken.png").write_bytes(b"\x89PNG garbage")
    with pytest.raises(InputError, match=r"broken\.png"):
        load_heights(tmp_path / "broken.png")
    (tmp_path / "broken.exr").write_bytes(b"garbage")
    with pytest.raises(InputError, match=r"broken\.exr"):
        load_heights(tmp_path / "broken.exr")
    (tmp_path / "dir.npy").mkdir()
    with pytest.raises(InputError, match=r"dir\.npy: not a regular file"):
        load_heights(tmp_path / "dir.npy")


def test_albedo_maps_png_is_srgb_npy_is_linear(tmp_path):
    from PIL import Image

    rgb = np.array([[[0, 128, 255], [255, 255, 255]]], dtype=np.uint8)
    Image.fromarray(rgb, "RGB").save(tmp_path / "a.png")
    a = load_albedo(tmp_path / "a.png")
    assert a.shape == (1, 2, 3) and a.dtype == np.float32
    np.testing.assert_allclose(a[0, 0], [0.0, 0.2158605, 1.0], rtol=1e-5)
    grey = RNG.random((3, 2))
    np.save(tmp_path / "g.npy", grey)
    np.testing.assert_allclose(load_albedo(tmp_path / "g.npy"), np.repeat(grey[..., None], 3, axis=2), rtol=1e-6)
    with pytest.raises(InputError, match=r"a\.jpg.*unsupported"):
        load_albedo(tmp_path / "a.jpg")


# ---------------------------------------------------------------- procedural terrains

SIZES = [(17, 10), (10, 17), (9, 9), (2, 3), (3, 2), (2, 2)]


@pytest.mark.parametrize("name", sorted(TERRAINS))
@pytest.mark.parametrize("width, depth", SIZES)
def test_every_terrain_any_size(name, width, depth):
    h = make_terrain(name, width, depth)
    assert h.shape == (depth, width) and h.dtype == np.float32
    assert np.isfinite(h).all() and h.min() >= 0.0 and h.max() <= 1.0
    np.testing.assert_array_equal(h, make_terrain(name, width, depth))  # deterministic
    HeightField(h)  # a valid height field


@pytest.mark.parametrize("name", sorted(set(TERRAINS) - {"flat"}))
def test_terrains_have_relief(name):
    h = make_terrain(name, 65, 47)
    assert h.max() - h.min() > 0.3


@pytest.mark.parametrize("name", ["fbm", "city_blocks"])
def test_random_terrains_follow_their_seed(name):
    a = make_terrain(name, 41, 33, seed=1)
    np.testing.assert_array_equal(a, make_terrain(name, 41, 33, seed=1))
    assert not np.array_equal(a, make_terrain(name, 41, 33, seed=2))


@pytest.mark.parametrize("name", sorted(set(TERRAINS) - {"fbm"}))
@pytest.mark.parametrize("width, depth", [(9, 9), (17, 9), (9, 13)])
def test_terrains_are_the_same_shape_at_a_finer_resolution(name, width, depth):
    # Positions are in units of the shorter side, so doubling the cells samples the same terrain.
    coarse = make_terrain(name, width, depth)
    fine = make_terrain(name, 2 * width - 1, 2 * depth - 1)
    np.testing.assert_allclose(fine[::2, ::2], coarse, atol=1e-6)


def test_flat_level():
    np.testing.assert_array_equal(flat(4, 3, level=0.25), np.full((3, 4), 0.25, np.float32))


def test_cones_grid_apexes_and_ground():
    h = cones(9, 9, count=2, radius=0.5)  # centres at u, v = 0.25, 0.75 = vertices 2 and 6
    for j in (2, 6):
        for i in (2, 6):
            assert h[j, i] == 1.0
    assert h[0, 0] == 0.0 and h[4, 4] == 0.0
    assert h[2, 3] == pytest.approx(0.5)  # a quarter cell (1/8) from the apex, base radius 1/4
    # Along the longer side the grid is centred: a 17 x 9 field holds 4 x 2 cones.
    h = cones(17, 9, count=2, radius=0.5, height=0.5)
    assert (h == 0.5).sum() == 8


def test_cones_circle_layout_and_light():
    h = cones_circle(65, 65, count=4, circle_radius=0.25, min_radius=0.05, max_radius=0.1)
    assert h[32, 32] == 0.0  # the centre is ground
    # Cone k at azimuth 90 k degrees, 0.25 from the centre (16 vertices); heights r / max_radius.
    assert h[32, 48] == pytest.approx(0.5)        # k = 0 at +x, r = 0.05
    assert h[48, 32] == pytest.approx(2 / 3)      # k = 1 at +z
    assert h[32, 16] == pytest.approx(5 / 6)      # k = 2 at -x
    assert h[16, 32] == pytest.approx(1.0)        # k = 3 at -z, the largest
    hf = HeightField(h, origin=(-5.0, 1.0, -4.0), size=(10.0, 8.0), height_scale=2.0)
    (x, y, z), r = cones_circle_light(hf, elevation=0.1, radius=0.02)
    assert (x, z) == (0.0, 0.0)
    # 0.02 x 8 = 0.16 would reach below the ground 0.2 down: capped at half the lift.
    assert y == pytest.approx(1.0 + 0.2) and r == pytest.approx(0.1)
    (x, y, z), r = cones_circle_light(hf, elevation=0.1, radius=0.005)
    assert r == pytest.approx(0.04)


def test_sine_grating_period_and_direction():
    h = sine_grating(33, 17, period=0.25)  # m = 16: a period is 4 vertices
    np.testing.assert_allclose(h[:, :-4], h[:, 4:], atol=1e-6)
    np.testing.assert_allclose(h, np.broadcast_to(h[0], h.shape))  # ridges along z
    assert h[0, 0] == pytest.approx(0.5) and h[0, 1] == pytest.approx(1.0) and h[0, 3] == pytest.approx(0.0)
    h90 = sine_grating(17, 33, period=0.25, angle_deg=90)
    np.testing.assert_allclose(h90, np.broadcast_to(h90[:, :1], h90.shape), atol=1e-6)  # ridges along x


def test_egg_tray_bumps_and_cups():
    h = egg_tray(17, 17, period=0.25)  # a period is 4 vertices
    assert h[0, 0] == pytest.approx(1.0) and h[4, 4] == pytest.approx(1.0) and h[2, 2] == pytest.approx(1.0)
    assert h[0, 2] == pytest.approx(0.0) and h[2, 0] == pytest.approx(0.0)
    np.testing.assert_allclose(h, h.T, atol=1e-6)


def test_fbm_is_procedural_terrain_heights_mapped_to_unit_range():
    from penumbra.procedural import terrain_heights

    h = fbm(20, 11, seed=5, octaves=3, frequency=2.0)
    base = terrain_heights(20, 11, seed=5, octaves=3, frequency=2.0 * 20 / 10)
    np.testing.assert_allclose(h, (base + 1) / 2, atol=1e-6)


def test_city_blocks_streets_and_roofs():
    h = city_blocks(33, 17, blocks=2, street=0.25, min_height=0.2, max_height=0.9, seed=7)
    # Cells of 8 vertices; streets on the cell borders, flat roofs inside.
    assert (h[:, ::8] == 0).all() and (h[::8, :] == 0).all()
    roofs = h[2:7, 2:7]
    assert (roofs == roofs[0, 0]).all() and 0.2 <= roofs[0, 0] <= 0.9
    heights = {float(h[4 + 8 * b, 4 + 8 * a]) for a in range(4) for b in range(2)}
    assert len(heights) > 1  # blocks differ
    assert ((h == 0) | ((h >= 0.2) & (h <= 0.9))).all()


def test_make_terrain_errors_list_the_valid_choices():
    with pytest.raises(InputError, match=r"unknown terrain 'hills'.*valid terrains: .*cones_circle.*city_blocks"):
        make_terrain("hills", 8, 8)
    with pytest.raises(InputError, match=r"terrain 'cones' has no parameter\(s\) size; valid: count, radius, height"):
        make_terrain("cones", 8, 8, size=3)
    assert terrain_parameters("fbm") == ("seed", "octaves", "frequency", "persistence", "lacunarity")


@pytest.mark.parametrize("name, params, text", [
    ("cones", {"count": 0}, "count"),
    ("cones", {"radius": 0.6}, "radius"),
    ("cones", {"count": 2.0}, "count"),
    ("cones_circle", {"min_radius": 0.2, "max_radius": 0.1}, "min_radius"),
    ("sine_grating", {"period": 0}, "period"),
    ("sine_grating", {"angle_deg": float("nan")}, "angle_deg"),
    ("egg_tray", {"period": -1}, "period"),
    ("fbm", {"seed": 1.5}, "seed"),
    ("fbm", {"octaves": 0}, "octaves"),
    ("city_blocks", {"street": 1.0}, "street"),
    ("city_blocks", {"min_height": 0.5, "max_height": 0.4}, "min_height"),
    ("flat", {"level": 2}, "level"),
])
def test_bad_terrain_values(name, params, text):
    with pytest.raises(InputError, match=rf"terrain '{name}': {text}"):
        make_terrain(name, 8, 8, **params)


@pytest.mark.parametrize("width, depth", [(1, 8), (8, 1), (2.0, 8), (True, 8), ("8", 8)])
def test_terrain_sizes(width, depth):
    with pytest.raises(InputError, match="(width|depth) must be an integer >= 2"):
        make_terrain("flat", width, depth)


# ---------------------------------------------------------------- scene files


def write_scene(path: Path, text: str) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text, encoding="utf-8")
    return path


def parse_error(data: dict) -> str:
    with pytest.raises(InputError) as info:
        parse_scene(data)
    return str(info.value)


TERRAIN_TOML = """
[[heightfield]]
name = "hills"
terrain = "cones"
size_px = [33, 17]
params = { count = 3, radius = 0.3 }
origin = [-4.0, 0.5, -2.0]
size = [8.0, 4.0]
height_scale = 1.5
albedo = [0.5, 0.6, 0.7]
"""


def test_terrain_table_every_key(tmp_path):
    s = load_scene(write_scene(tmp_path / "s.toml", TERRAIN_TOML))
    (h,) = s.heightfields
    assert h == HeightfieldDesc(name="hills", terrain="cones", size_px=(33, 17), params={"count": 3, "radius": 0.3},
                                origin=(-4.0, 0.5, -2.0), size=(8.0, 4.0), height_scale=1.5, albedo=(0.5, 0.6, 0.7))
    hf = h.load()
    assert isinstance(hf, HeightField) and hf.heights.shape == (17, 33)
    np.testing.assert_array_equal(hf.heights, cones(33, 17, count=3, radius=0.3))
    assert hf.origin == (-4.0, 0.5, -2.0) and hf.size == (8.0, 4.0) and hf.height_scale == 1.5
    np.testing.assert_allclose(hf.albedo, [0.5, 0.6, 0.7], rtol=1e-6)


def test_terrain_table_defaults():
    s = parse_scene({"heightfield": [{"terrain": "flat"}, {"terrain": "egg_tray", "size": [4, 2]}]})
    a, b = s.heightfields
    assert a.name == "heightfield0" and b.name == "heightfield1"
    assert a.size_px == (256, 256) and a.size == (10.0, 10.0) and a.height_scale == 1.0
    assert a.origin == (-5.0, 0.0, -5.0)  # centred on x = z = 0
    assert b.origin == (-2.0, 0.0, -1.0)
    assert a.albedo == (0.8, 0.8, 0.8) and a.albedo_map is None and a.file is None and a.params == {}


def test_scenes_without_height_fields_are_unchanged():
    s = parse_scene({"object": [{"primitive": "box"}]})
    assert s.heightfields == [] and len(s.objects) == 1


def test_file_table_resolves_against_the_scene_file(tmp_path, monkeypatch):
    heights = RNG.random((5, 4))
    (tmp_path / "data").mkdir()
    np.save(tmp_path / "data" / "h.npy", heights)
    albedo = RNG.random((5, 4, 3))
    np.save(tmp_path / "data" / "a.npy", albedo)
    path = write_scene(tmp_path / "scenes" / "s.toml", """
[[heightfield]]
file = "../data/h.npy"
albedo_map = "../data/a.npy"
size = [3.0, 4.0]
""")
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)  # the working directory must not matter
    (h,) = load_scene(path).heightfields
    assert h.file == str(tmp_path / "data" / "h.npy") and Path(h.file).is_absolute()
    assert h.albedo_map == str(tmp_path / "data" / "a.npy") and h.size_px is None and h.terrain is None
    hf = h.load()
    np.testing.assert_array_equal(hf.heights, heights.astype(np.float32))
    np.testing.assert_allclose(hf.albedo, albedo, rtol=1e-6)
    assert hf.spacing == (1.0, 1.0)


def test_missing_files_are_reported_when_loading_not_parsing(tmp_path):
    s = parse_scene({"heightfield": [{"name": "t", "file": "nowhere.png"}]}, base_dir=tmp_path)
    with pytest.raises(InputError, match=r"\[heightfield 't'\] .*nowhere\.png: file not found"):
        s.heightfields[0].load()


def test_albedo_map_must_match_the_heights(tmp_path):
    np.save(tmp_path / "a.npy", np.zeros((4, 4, 3)))
    s = parse_scene({"heightfield": [{"name": "t", "terrain": "flat", "size_px": [5, 4], "albedo_map": "a.npy"}]},
                    base_dir=tmp_path)
    with pytest.raises(InputError, match=r"\[heightfield 't'\] albedo_map .* 4 x 4 pixels but the heights are 5 x 4"):
        s.heightfields[0].load()


def test_bad_terrain_values_are_reported_at_load_with_the_table():
    s = parse_scene({"heightfield": [{"name": "t", "terrain": "cones", "params": {"count": 0}}]})
    with pytest.raises(InputError, match=r"\[heightfield 't'\] params: terrain 'cones': count"):
        s.heightfields[0].load()


@pytest.mark.parametrize("table, text", [
    ({"name": "t"}, "needs exactly one of 'file'"),
    ({"name": "t", "file": "h.npy", "terrain": "flat"}, "needs exactly one of 'file'"),
    ({"name": "t", "terrain": "flat", "colour": 1}, "has unknown key(s) colour"),
    ({"name": "t", "terrain": "hills"}, "terrain = 'hills' is not one of flat, cones"),
    ({"name": "t", "terrain": "cones", "params": {"size": 2}}, "params: terrain 'cones' has no parameter(s) size"),
    ({"name": "t", "terrain": "cones", "params": 3}, "params must be a table"),
    ({"name": "t", "file": "h.npy", "size_px": [4, 4]}, "size_px only applies to a 'terrain'"),
    ({"name": "t", "file": "h.npy", "params": {}}, "params only applies to a 'terrain'"),
    ({"name": "t", "file": "h.tif"}, "file = 'h.tif' must be a .npy, .exr, .png file"),
    ({"name": "t", "file": 3}, "file must be a string"),
    ({"name": "t", "terrain": "flat", "size_px": [1, 4]}, "size_px[0] must be an integer in [2, 8192]"),
    ({"name": "t", "terrain": "flat", "size_px": [4, 4.0]}, "size_px[1] must be an integer"),
    ({"name": "t", "terrain": "flat", "size_px": 64}, "size_px must be [W, D]"),
    ({"name": "t", "terrain": "flat", "size": [0, 1]}, "size[0] = 0 must be > 0"),
    ({"name": "t", "terrain": "flat", "size": [1, 2, 3]}, "size must be [size_x, size_z]"),
    ({"name": "t", "terrain": "flat", "origin": [0, 0]}, "origin must be a list of 3 numbers"),
    ({"name": "t", "terrain": "flat", "height_scale": "big"}, "height_scale must be a finite number"),
    ({"name": "t", "terrain": "flat", "albedo": [0.5, 1.5, 0]}, "albedo[1] = 1.5 must be <= 1"),
    ({"name": "t", "terrain": "flat", "albedo": 0.5, "albedo_map": "a.png"}, "both 'albedo' and 'albedo_map'"),
    ({"name": "t", "terrain": "flat", "albedo_map": "a.hdr"}, "albedo_map = 'a.hdr' must be a"),
    ({"name": 5, "terrain": "flat"}, "name must be a string"),
])
def test_heightfield_table_errors_name_table_and_key(table, text):
    msg = parse_error({"heightfield": [table]})
    assert "heightfield" in msg and text in msg, msg


def test_heightfield_list_errors():
    assert "[[heightfield]] tables" in parse_error({"heightfield": {"terrain": "flat"}})
    assert "#0 must be a table" in parse_error({"heightfield": [3]})
    msg = parse_error({"heightfield": [{"name": "a", "terrain": "flat"}, {"name": "a", "terrain": "cones"}]})
    assert "height field names must be unique; repeated: a" in msg
    assert "heightfields" in parse_error({"heightfields": []})  # a typo of the table name


def test_set_overrides_address_height_fields_by_name_or_index(tmp_path):
    path = write_scene(tmp_path / "s.toml", TERRAIN_TOML)
    s = load_scene(path, ["heightfield.hills.height_scale=3", "heightfield.0.terrain=egg_tray",
                          "heightfield.0.params={ period = 0.5 }"])
    (h,) = s.heightfields
    assert h.height_scale == 3.0 and h.terrain == "egg_tray" and h.params == {"period": 0.5}
    with pytest.raises(InputError, match="no heightfield named or numbered 'dunes'"):
        apply_overrides({"heightfield": [{"terrain": "flat"}]}, ["heightfield.dunes.size=[1,1]"])
    with pytest.raises(InputError, match="heightfield.NAME_OR_INDEX.key"):
        apply_overrides({"heightfield": [{"terrain": "flat"}]}, ["heightfield.0=1"])
