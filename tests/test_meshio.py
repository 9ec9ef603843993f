"""Tests for penumbra.meshio: the real meshes in ../shared/data/meshes and small files written here."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest

from penumbra.errors import InputError
from penumbra.meshio import Mesh, load_mesh, save_obj

# (vertices, triangles after fan triangulation), from ../shared/data/SOURCES.md.
REAL_MESHES = {
    "armadillo_libigl.obj": (43243, 86482),
    "armadillo_odedstein.obj": (14587, 29170),
    "buddha_photon.obj": (49950, 100000),
    "bunny_odedstein_3k.obj": (3301, 6598),
    "bunny_stanford_full_ajacobson.obj": (35947, 69451),
    "chess_queen_scenevr.obj": (754, 1440),
    "dragon_photon.obj": (50000, 100000),
    "teapot_ajacobson.obj": (3644, 6320),
    "tree_quaternius_Birch_8.obj": (1581, 2506),
    "tree_quaternius_Tree_3.obj": (1273, 2088),
    "bunny_stanford_res2_trimesh.ply": (8171, 16301),
}

SQUARE = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 2 0 0\nv 2 1 0\n"


@pytest.fixture(scope="module")
def meshes(shared_data) -> Path:
    return shared_data / "meshes"


def write(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


def signed_volume(mesh: Mesh) -> float:
    v = mesh.vertices.astype(np.float64)
    a, b, c = (v[mesh.faces[:, k]] for k in range(3))
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


def face_normals(mesh: Mesh) -> np.ndarray:
    v = mesh.vertices.astype(np.float64)
    a, b, c = (v[mesh.faces[:, k]] for k in range(3))
    return np.cross(b - a, c - a)


# --------------------------------------------------------------------------- #
# Real meshes
# --------------------------------------------------------------------------- #


@pytest.mark.parametrize("name", sorted(REAL_MESHES))
def test_real_meshes(meshes, name):
    mesh = load_mesh(meshes / name)
    assert (mesh.num_vertices, mesh.num_faces) == REAL_MESHES[name]
    assert mesh.vertices.dtype == np.float32 and mesh.faces.dtype == np.uint32
    assert mesh.vertices.flags.c_contiguous and mesh.faces.flags.c_contiguous
    assert np.isfinite(mesh.vertices).all() and mesh.faces.max() < mesh.num_vertices
    extent = mesh.vertices.max(axis=0) - mesh.vertices.min(axis=0)
    assert (extent > 0).all()
    # Most triangles are non-degenerate (scans have a few slivers).
    assert np.mean(np.linalg.norm(face_normals(mesh), axis=1) > 0) > 0.99


def test_watertight_real_meshes_are_outward(meshes):
    for name in ("armadillo_odedstein.obj", "armadillo_libigl.obj", "dragon_photon.obj", "bunny_odedstein_3k.obj"):
        assert signed_volume(load_mesh(meshes / name)) > 0, name


def test_unreferenced_vertices_are_kept(meshes):
    mesh = load_mesh(meshes / "bunny_stanford_full_ajacobson.obj")
    assert len(np.unique(mesh.faces)) == 34834 < mesh.num_vertices == 35947


def test_obj_per_vertex_normals_kept(meshes):
    # The queen's normals use their own numbering but are one per vertex.
    mesh = load_mesh(meshes / "chess_queen_scenevr.obj")
    assert mesh.normals is not None and mesh.normals.shape == (754, 3) and mesh.normals.dtype == np.float32
    np.testing.assert_allclose(np.linalg.norm(mesh.normals, axis=1), 1.0, atol=1e-6)
    # They agree with the geometry: area-weighted face normals accumulated per vertex.
    accumulated = np.zeros((mesh.num_vertices, 3))
    fn = face_normals(mesh)
    for k in range(3):
        np.add.at(accumulated, mesh.faces[:, k], fn)
    agree = np.einsum("ij,ij->i", accumulated, mesh.normals) > 0
    assert agree.mean() > 0.95


def test_obj_flat_face_normals_dropped(meshes):
    # One normal per face corner (f v//vn with a flat normal per face): not vertex normals.
    assert load_mesh(meshes / "bunny_odedstein_3k.obj").normals is None


def test_polygon_obj_triangulated_quietly(meshes, capfd):
    mesh = load_mesh(meshes / "tree_quaternius_Tree_3.obj")  # libigl fails on it; our parser takes over
    assert mesh.num_faces == 2088
    load_mesh(meshes / "chess_queen_scenevr.obj")  # libigl warns about its 'o' line
    out, err = capfd.readouterr()
    assert out == "" and err == ""


def test_ply_extra_properties(meshes):
    mesh = load_mesh(meshes / "bunny_stanford_res2_trimesh.ply")
    assert mesh.normals is None
    # First vertex of bun_zipper_res2 as written in the file.
    header, body = (meshes / "bunny_stanford_res2_trimesh.ply").read_text().split("end_header\n")
    first = [float(t) for t in body.split("\n")[0].split()[:3]]
    np.testing.assert_array_equal(mesh.vertices[0], np.float32(first))


# --------------------------------------------------------------------------- #
# OBJ
# --------------------------------------------------------------------------- #


def test_obj_quads_triangulated(tmp_path):
    mesh = load_mesh(write(tmp_path / "q.obj", SQUARE + "f 1 2 3 4\nf 2 5 6 3\n"))
    assert mesh.num_vertices == 6 and mesh.num_faces == 4
    assert mesh.faces.tolist() == [[0, 1, 2], [0, 2, 3], [1, 4, 5], [1, 5, 2]]
    assert (face_normals(mesh)[:, 2] > 0).all()  # winding preserved


def test_obj_mixed_polygons_with_normals(tmp_path):
    text = (SQUARE + "v 3 0.5 0\nvn 0 0 1\n"
            "f 1//1 2//1 4//1\nf 2//1 5//1 6//1 3//1\nf 2//1 7//1 6//1 5//1 3//1\nf 3//1 4//1 2//1\n")
    mesh = load_mesh(write(tmp_path / "m.obj", text))
    assert mesh.num_faces == 1 + 2 + 3 + 1
    assert mesh.normals is not None and np.array_equal(mesh.normals, np.tile(np.float32([0, 0, 1]), (7, 1)))


def test_obj_inconsistent_normals_dropped(tmp_path):
    text = SQUARE + "vn 0 0 1\nvn 0 1 0\nf 1//1 2//1 3//1 4//1\nf 2//2 5//2 6//2 3//2\n"
    assert load_mesh(write(tmp_path / "n.obj", text)).normals is None


def test_obj_misc_syntax(tmp_path):
    text = ("# comment\nmtllib x.mtl\no thing\nv 0 0 0 1 0 0\nv 1 0 0 0 1 0\nv 0 1 0\nv 5 5 5\nvt 0 0\n"
            "usemtl red\ns off\nf -4/1 -3/1 -2/1\n")
    mesh = load_mesh(write(tmp_path / "misc.obj", text))
    assert mesh.faces.tolist() == [[0, 1, 2]] and mesh.num_vertices == 4  # unreferenced vertex kept


# --------------------------------------------------------------------------- #
# OFF, STL, PLY
# --------------------------------------------------------------------------- #

OFF_VERTICES = "0 0 0\n1 0 0\n1 1 0\n0 1 0\n2 0 0\n2 1 0\n"


def test_off(tmp_path):
    mesh = load_mesh(write(tmp_path / "a.off", "OFF\n# comment\n6 2 0\n" + OFF_VERTICES + "4 0 1 2 3\n4 1 4 5 2\n"))
    assert mesh.num_faces == 4 and mesh.normals is None
    mixed = load_mesh(write(tmp_path / "b.off", "OFF\n6 2 0\n" + OFF_VERTICES + "4 0 1 2 3\n3 1 4 5\n"))
    assert mixed.faces.tolist() == [[0, 1, 2], [0, 2, 3], [1, 4, 5]]
    colours = "".join(f"{line} 255 0 0 255\n" for line in OFF_VERTICES.splitlines())
    coff = load_mesh(write(tmp_path / "c.off", "COFF\n6 1 0\n" + colours + "3 0 1 2\n"))
    assert coff.normals is None and coff.num_faces == 1
    normals = "".join(f"{line} 0 0 2\n" for line in OFF_VERTICES.splitlines())
    noff = load_mesh(write(tmp_path / "n.off", "NOFF\n6 1 0\n" + normals + "3 0 1 2\n"))
    assert np.array_equal(noff.normals, np.tile(np.float32([0, 0, 1]), (6, 1)))


def cube_triangles() -> np.ndarray:
    """The 12 outward triangles of the unit cube as corner positions (12, 3, 3)."""
    corners = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], dtype=np.float32)
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    tris = [(q[0], q[1], q[2]) for q in quads] + [(q[0], q[2], q[3]) for q in quads]
    return corners[np.array(tris)]


def write_binary_stl(path: Path, triangles: np.ndarray, header: bytes = b"binary stl") -> Path:
    with open(path, "wb") as f:
        f.write(header.ljust(80, b" "))
        f.write(struct.pack("<I", len(triangles)))
        for tri in triangles:
            f.write(struct.pack("<12fH", 0, 0, 0, *tri.ravel(), 0))
    return path


def write_ascii_stl(path: Path, triangles: np.ndarray) -> Path:
    lines = ["solid cube"]
    for tri in triangles:
        lines += ["  facet normal 0 0 0", "    outer loop"]
        lines += [f"      vertex {x:.6e} {y:.6e} {z:.6e}" for x, y, z in tri]
        lines += ["    endloop", "  endfacet"]
    path.write_text("\n".join(lines + ["endsolid cube", ""]))
    return path


@pytest.mark.parametrize("kind", ["binary", "binary_solid_header", "ascii"])
def test_stl_merges_duplicates(tmp_path, kind):
    triangles = cube_triangles()
    if kind == "ascii":
        path = write_ascii_stl(tmp_path / "c.stl", triangles)
    else:
        header = b"solid looks like ascii" if kind == "binary_solid_header" else b"binary"
        path = write_binary_stl(tmp_path / "c.stl", triangles, header)
    mesh = load_mesh(path)
    assert mesh.num_vertices == 8 and mesh.num_faces == 12
    np.testing.assert_array_equal(mesh.vertices[mesh.faces], triangles)  # same triangles, same winding
    assert signed_volume(mesh) == pytest.approx(1.0)


def ply_header(fmt: str, n_vertices: int, n_faces: int, vertex_props: str, extra: str = "") -> bytes:
    return (f"ply\nformat {fmt} 1.0\ncomment test\nelement vertex {n_vertices}\n{vertex_props}"
            f"element face {n_faces}\nproperty list uchar int vertex_indices\n{extra}end_header\n").encode()


PLY_POSITIONS = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [2, 0, 0], [2, 1, 0]], dtype=np.float32)
PLY_PROPS = ("property float x\nproperty float y\nproperty float z\nproperty float nx\nproperty float ny\n"
             "property float nz\nproperty float confidence\nproperty uchar intensity\n")


@pytest.mark.parametrize("endian, fmt", [("<", "binary_little_endian"), (">", "binary_big_endian")])
@pytest.mark.parametrize("faces", [[[0, 1, 2, 3], [1, 4, 5, 2]], [[0, 1, 2], [1, 4, 5, 2]]])
def test_ply_binary(tmp_path, endian, fmt, faces):
    data = bytearray(ply_header(fmt, 6, len(faces), PLY_PROPS, "element edge 1\nproperty int a\nproperty int b\n"))
    for v in PLY_POSITIONS:
        data += struct.pack(endian + "7fB", *v, 0, 0, 1, 0.5, 7)
    for face in faces:
        data += struct.pack(endian + "B" + "i" * len(face), len(face), *face)
    data += struct.pack(endian + "ii", 0, 1)
    path = tmp_path / "b.ply"
    path.write_bytes(bytes(data))
    mesh = load_mesh(path)
    np.testing.assert_array_equal(mesh.vertices, PLY_POSITIONS)
    expected = sum(len(f) - 2 for f in faces)
    assert mesh.num_faces == expected
    assert np.array_equal(mesh.normals, np.tile(np.float32([0, 0, 1]), (6, 1)))
    path.write_bytes(bytes(data[:-20]))  # cut into the faces
    with pytest.raises(InputError, match="truncated"):
        load_mesh(path)


def test_ply_ascii_mixed_polygons(tmp_path):
    # libigl 2.6 aborts the interpreter on this file; our parser must handle it.
    body = "".join(f"{x} {y} {z} 0.5 9\n" for x, y, z in PLY_POSITIONS) + "4 0 1 2 3\n3 1 4 5\n"
    props = ("property float x\nproperty float y\nproperty float z\nproperty float confidence\n"
             "property float intensity\n")
    path = tmp_path / "a.ply"
    path.write_bytes(ply_header("ascii", 6, 2, props) + body.encode())
    mesh = load_mesh(path)
    assert mesh.faces.tolist() == [[0, 1, 2], [0, 2, 3], [1, 4, 5]] and mesh.normals is None


# --------------------------------------------------------------------------- #
# Errors
# --------------------------------------------------------------------------- #


@pytest.mark.parametrize("name, content, match", [
    ("none.obj", SQUARE, "no faces"),
    ("oor.obj", SQUARE + "f 1 2 9\n", "out of range"),
    ("zero.obj", SQUARE + "f 0 1 2\n", "out of range"),
    ("nan.obj", "v 0 0 nan\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", "NaN"),
    ("inf.obj", "v 0 0 1e40\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", "NaN/Inf"),
    ("short.obj", SQUARE + "f 1 2\n", "at least 3"),
    ("word.obj", "v 0 0 zero\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", "bad number"),
    ("oor.off", "OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 3\n", "out of range"),
    ("neg.off", "OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 -1 2\n", "out of range"),
    ("trunc.off", "OFF\n6 2 0\n0 0 0\n1 0 0\n", "truncated"),
    ("nan.off", "OFF\n3 1 0\n0 0 nan\n1 0 0\n0 1 0\n3 0 1 2\n", "NaN"),
    ("none.off", "OFF\n3 0 0\n0 0 0\n1 0 0\n0 1 0\n", "no faces"),
    ("bad.off", "HELLO\n", "not a supported OFF"),
    ("trunc.stl", "solid x\n facet normal 0 0 1\n  outer loop\n   vertex 0 0 0\n", "truncated"),
    ("empty.stl", "", "not a valid STL"),
    ("nofaces.ply", "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\n"
                    "property float z\nend_header\n0 0 0\n", "no faces"),
    ("oor.ply", "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
                "element face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 5\n",
     "out of range"),
    ("nan.ply", "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
                "element face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 nan\n1 0 0\n0 1 0\n3 0 1 2\n",
     "NaN"),
    ("trunc.ply", "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
                  "element face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n", "truncated"),
    ("header.ply", "ply\nformat ascii 1.0\nelement vertex 3\n", "end_header"),
    ("type.ply", "ply\nformat ascii 1.0\nelement vertex 1\nproperty quad x\nend_header\n", "type"),
])
def test_errors(tmp_path, name, content, match, capfd):
    path = write(tmp_path / name, content)
    with pytest.raises(InputError, match=match) as info:
        load_mesh(path)
    assert str(path) in str(info.value)
    assert capfd.readouterr().out == ""  # libigl's chatter stays captured


@pytest.mark.parametrize("suffix", [".obj", ".off", ".ply", ".stl"])
def test_garbage_files(tmp_path, suffix):
    path = tmp_path / f"garbage{suffix}"
    path.write_bytes(np.random.default_rng(7).integers(0, 256, 4000, dtype=np.uint8).tobytes())
    with pytest.raises(InputError, match="garbage"):
        load_mesh(path)


def test_truncated_binary_stl(tmp_path):
    path = write_binary_stl(tmp_path / "t.stl", cube_triangles())
    path.write_bytes(path.read_bytes()[:-30])
    with pytest.raises(InputError, match="not a complete binary STL"):
        load_mesh(path)


def test_missing_and_unknown(tmp_path):
    with pytest.raises(InputError, match="not found"):
        load_mesh(tmp_path / "missing.obj")
    with pytest.raises(InputError, match="unsupported mesh extension"):
        load_mesh(write(tmp_path / "x.fbx", "data"))
    (tmp_path / "d.obj").mkdir()
    with pytest.raises(InputError, match="not a regular file"):
        load_mesh(tmp_path / "d.obj")


# --------------------------------------------------------------------------- #
# Mesh and save_obj
# --------------------------------------------------------------------------- #


def test_mesh_validation():
    mesh = Mesh(np.zeros((3, 3)), [[0, 1, 2]])
    assert mesh.vertices.dtype == np.float32 and mesh.faces.dtype == np.uint32 and mesh.normals is None
    with pytest.raises(InputError, match="vertices"):
        Mesh(np.zeros((3, 2)), [[0, 1, 2]])
    with pytest.raises(InputError, match="faces"):
        Mesh(np.zeros((3, 3)), [[0.0, 1.0, 2.0]])
    with pytest.raises(InputError, match="out of range"):
        Mesh(np.zeros((3, 3)), [[0, 1, -1]])
    with pytest.raises(InputError, match="no faces"):
        Mesh(np.zeros((3, 3)), np.zeros((0, 3), int))
    with pytest.raises(InputError, match="normals"):
        Mesh(np.zeros((3, 3)), [[0, 1, 2]], np.zeros((2, 3)))


@pytest.mark.parametrize("with_normals", [False, True])
def test_save_obj_roundtrip(tmp_path, with_normals):
    rng = np.random.default_rng(8)
    vertices = rng.standard_normal((50, 3)).astype(np.float32) * np.float32(1e3)
    faces = rng.integers(0, 49, (80, 3))  # vertex 49 is unused and must survive, with its normal
    normals = None
    if with_normals:
        normals = rng.standard_normal((50, 3))
        normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    mesh = Mesh(vertices, faces, normals)
    path = tmp_path / "out" / "m.obj"
    save_obj(path, mesh)
    back = load_mesh(path)
    np.testing.assert_array_equal(back.vertices, mesh.vertices)
    np.testing.assert_array_equal(back.faces, mesh.faces)
    if with_normals:
        np.testing.assert_allclose(back.normals, mesh.normals, atol=1e-6)
    else:
        assert back.normals is None
    assert sorted(p.name for p in path.parent.iterdir()) == ["m.obj"]
