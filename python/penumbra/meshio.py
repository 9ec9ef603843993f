"""Loading and saving triangle meshes.

:func:`load_mesh` reads OBJ, PLY, OFF and STL files (chosen by extension,
case-insensitive) into a :class:`Mesh`: float32 vertices (n, 3), uint32
triangles (m, 3) and optional float32 per-vertex normals (n, 3).

* Polygons (quads, n-gons) are triangulated as fans around their first vertex.
* Vertices are kept exactly as in the file, including ones no face uses, so
  indices stay meaningful to the user. The one exception is STL, which stores
  three separate corners per triangle: exactly equal positions are merged.
* Normals are returned only when every vertex has exactly one normal
  (a true per-vertex normal). OBJ files often carry one flat normal per face
  corner instead; using those as vertex normals would smooth or distort the
  shading, so such normals are dropped (``normals is None``) and the renderer
  uses geometric normals.

Readers: OBJ goes through libigl when every face index is a plain positive
integer within the file's record counts, otherwise (and when libigl rejects a
valid file) through a small strict parser here (see :func:`_load_obj`). OFF,
PLY and STL are parsed here; the reasons are given in :func:`_load_off`,
:func:`_load_ply` and :func:`_load_stl`. Indices are read as strict integers:
a fraction, trailing characters or a value out of range is an error, never
truncated or wrapped (docs/reliability.md). Allocations sized by a
header are checked against the file's size and ``PENUMBRA_MAX_BYTES``
(:mod:`penumbra.limits`).

Every problem raises :class:`~penumbra.errors.InputError` naming the file:
missing/unreadable file, unknown extension, malformed or truncated data, no
faces, face indices out of range, NaN/Inf coordinates.

:func:`save_obj` writes a mesh as OBJ, atomically.
"""

from __future__ import annotations

import os
import re
import sys
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .errors import InputError
from .fileutil import atomic_write, captured_native_output
from .limits import UINT32, check_bytes, check_data, parse_int

__all__ = ["DEFAULT_CREASE_ANGLE_DEG", "Mesh", "load_mesh", "save_obj", "smooth_normals"]


@dataclass
class Mesh:
    """A triangle mesh.

    ``vertices``: float32 (n, 3); ``faces``: uint32 (m, 3), counter-clockwise
    seen from the front; ``normals``: float32 (n, 3) per-vertex normals (unit
    length when they come from this package; not renormalised here), or None.
    Construction converts array-likes to these types and validates shapes,
    index range and finiteness (raising :class:`InputError`).
    """

    vertices: np.ndarray
    faces: np.ndarray
    normals: np.ndarray | None = None

    def __post_init__(self) -> None:
        self.vertices, self.faces, self.normals = _validated(self.vertices, self.faces, self.normals, "mesh")

    @property
    def num_vertices(self) -> int:
        return int(self.vertices.shape[0])

    @property
    def num_faces(self) -> int:
        return int(self.faces.shape[0])


# --------------------------------------------------------------------------- #
# Public API
# --------------------------------------------------------------------------- #


def load_mesh(path: str | os.PathLike) -> Mesh:
    """Load a triangle mesh from an .obj, .ply, .off or .stl file (see the module docstring)."""
    path = Path(path)
    loaders = {".obj": _load_obj, ".ply": _load_ply, ".off": _load_off, ".stl": _load_stl}
    loader = loaders.get(path.suffix.lower())
    if loader is None:
        raise InputError(f"{path}: unsupported mesh extension {path.suffix!r} (expected .obj, .ply, .off or .stl)")
    if not path.exists():
        raise InputError(f"{path}: file not found")
    if not path.is_file():
        raise InputError(f"{path}: not a regular file")
    try:
        with open(path, "rb") as f:
            size = os.fstat(f.fileno()).st_size
    except OSError as exc:
        raise InputError(f"{path}: cannot read file: {exc.strerror or exc}") from exc
    check_bytes(size, "reading the mesh file", str(path))  # the parsers hold the whole file
    vertices, faces, normals = loader(path)
    vertices, faces, normals = _validated(vertices, faces, normals, str(path))
    return Mesh(vertices, faces, normals)


def save_obj(path: str | os.PathLike, mesh: Mesh) -> None:
    """Write ``mesh`` as a Wavefront OBJ file (atomically).

    Coordinates are written with 9 significant digits, which round-trips
    float32 exactly. With normals, faces are written as ``f v//v ...``.
    """
    path = Path(path)
    vertices, faces, normals = _validated(mesh.vertices, mesh.faces, mesh.normals, str(path))

    def write(tmp: str) -> None:
        with open(tmp, "w", encoding="ascii", newline="\n") as f:
            f.write(f"# penumbra mesh: {len(vertices)} vertices, {len(faces)} triangles\n")
            np.savetxt(f, vertices.astype(np.float64), fmt="v %.9g %.9g %.9g")
            one_based = faces.astype(np.int64) + 1
            if normals is not None:
                np.savetxt(f, normals.astype(np.float64), fmt="vn %.9g %.9g %.9g")
                np.savetxt(f, np.repeat(one_based, 2, axis=1), fmt="f %d//%d %d//%d %d//%d")
            else:
                np.savetxt(f, one_based, fmt="f %d %d %d")

    atomic_write(path, write)


# --------------------------------------------------------------------------- #
# Smooth vertex normals for meshes that come without them
# --------------------------------------------------------------------------- #

# Scanned meshes (the bunny, the dragon) carry no normals; shaded with the
# geometric normal they look faceted. 60 degrees keeps a box's or a
# cylinder's edges sharp (90 degrees) while smoothing every fold a scan or a
# tessellated curved surface has (docs/scene-format.md).
DEFAULT_CREASE_ANGLE_DEG = 60.0


def smooth_normals(mesh: Mesh, crease_angle_deg: float = DEFAULT_CREASE_ANGLE_DEG) -> Mesh:
    """The mesh with angle-weighted smooth vertex normals, sharp across creases.

    Each triangle corner gets the sum, over the triangles around its vertex
    whose face normal is within ``crease_angle_deg`` of the corner's own
    triangle's, of their unit face normals weighted by their angle at the
    vertex (Thürmer and Wüthrich 1998), normalised. Vertices are matched by
    position (so meshes stored as separate triangles, as STL files are, are
    smoothed too), and a vertex whose corners get different normals (at a
    crease) is split into one vertex per distinct normal. 0 degrees gives
    every triangle its face normal; 180 smooths across every edge.
    Zero-area triangles contribute nothing (rays never hit them; their own
    corners get the smooth normal of their vertex without the crease test).
    The positions and the triangles' shapes are unchanged; vertex order is by
    first use.
    """
    angle = float(crease_angle_deg)
    if not (0.0 <= angle <= 180.0):
        raise InputError(f"crease_angle_deg must be in [0, 180], got {crease_angle_deg!r}")
    faces = mesh.faces.astype(np.int64)
    p = mesh.vertices.astype(np.float64)[faces]  # (m, 3 corners, 3)
    cross = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    length = np.linalg.norm(cross, axis=1)
    face_n = np.divide(cross, length[:, None], out=np.zeros_like(cross), where=length[:, None] > 0)
    # Interior angle of every corner.
    e1 = np.roll(p, -1, axis=1) - p
    e2 = np.roll(p, -2, axis=1) - p
    corner_angle = np.arctan2(np.linalg.norm(np.cross(e1, e2), axis=2), np.einsum("ijk,ijk->ij", e1, e2)).ravel()
    # Corners grouped by vertex position; every pair of corners in a group.
    _, position_id = np.unique(mesh.vertices, axis=0, return_inverse=True)
    corner_vertex = position_id.reshape(-1)[faces.ravel()]
    corner_face = np.repeat(np.arange(len(faces)), 3)
    order = np.argsort(corner_vertex, kind="stable")
    starts = np.flatnonzero(np.r_[True, np.diff(corner_vertex[order]) != 0])
    sizes = np.diff(np.r_[starts, len(order)])
    group_size = np.repeat(sizes, sizes)
    group_start = np.repeat(starts, sizes)
    total = int(group_size.sum())
    first_pair = np.repeat(np.cumsum(group_size) - group_size, group_size)
    me = np.repeat(order, group_size)
    other = order[np.repeat(group_start, group_size) + (np.arange(total) - first_pair)]
    fa, fb = face_n[corner_face[me]], face_n[corner_face[other]]
    cos_limit = np.cos(np.radians(angle))
    own_degenerate = length[corner_face[me]] == 0
    keep = (np.einsum("ij,ij->i", fa, fb) >= cos_limit - 1e-12) | own_degenerate
    weighted = fb[keep] * corner_angle[other[keep]][:, None]
    normal = np.zeros((len(corner_vertex), 3))
    for c in range(3):
        normal[:, c] = np.bincount(me[keep], weights=weighted[:, c], minlength=len(corner_vertex))
    norm = np.linalg.norm(normal, axis=1)
    # Only corners of zero-area triangles at an isolated vertex stay zero; any unit vector will do.
    normal = np.where(norm[:, None] > 0, normal / np.where(norm > 0, norm, 1.0)[:, None], [0.0, 1.0, 0.0])
    n32 = normal.astype(np.float32)
    # One output vertex per (position, normal), in order of first use.
    key = np.concatenate([corner_vertex[:, None].astype(np.float64), n32.astype(np.float64)], axis=1)
    _, first, inverse = np.unique(key, axis=0, return_index=True, return_inverse=True)
    rank = np.empty(len(first), np.int64)
    rank[np.argsort(first, kind="stable")] = np.arange(len(first))
    new_index = rank[inverse.reshape(-1)]
    by_rank = first[np.argsort(first, kind="stable")]
    vertices = mesh.vertices[faces.ravel()[by_rank]]
    return Mesh(vertices, new_index.reshape(-1, 3).astype(np.uint32), n32[by_rank])


# --------------------------------------------------------------------------- #
# Validation and shared helpers
# --------------------------------------------------------------------------- #


def _validated(vertices, faces, normals, where: str):
    """Convert to (float32 (n,3), uint32 (m,3), float32 (n,3) | None) and check consistency."""
    v = np.asarray(vertices)
    f = np.asarray(faces)
    if v.ndim != 2 or v.shape[1] != 3 or v.dtype.kind not in "fiu":
        raise InputError(f"{where}: vertices must be a real array of shape (n, 3), got {v.dtype} {v.shape}")
    if f.ndim != 2 or f.shape[1] != 3 or f.dtype.kind not in "iu":
        raise InputError(f"{where}: faces must be an integer array of shape (m, 3), got {f.dtype} {f.shape}")
    if len(f) == 0:
        raise InputError(f"{where}: the mesh has no faces")
    with np.errstate(over="ignore"):  # out-of-range values become Inf and are reported just below
        v32 = np.ascontiguousarray(v, dtype=np.float32)
    bad = ~np.isfinite(v32)
    if bad.any():
        first = int(np.argwhere(bad)[0, 0])
        raise InputError(f"{where}: {int(bad.any(axis=1).sum())} vertices have NaN/Inf (or out-of-float32-range) "
                         f"coordinates (first: vertex {first})")
    low, high = int(f.min()), int(f.max())
    if low < 0 or high >= len(v32):
        bad_face = int(np.argwhere((f < 0) | (f >= len(v32)))[0, 0])
        raise InputError(f"{where}: face indices out of range (triangle {bad_face} has 0-based vertex indices "
                         f"{f[bad_face].tolist()}; valid indices are 0..{len(v32) - 1})")
    f32 = np.ascontiguousarray(f, dtype=np.uint32)
    n32 = None
    if normals is not None:
        n = np.asarray(normals)
        if n.shape != v32.shape or n.dtype.kind not in "fiu":
            raise InputError(f"{where}: normals must be a real array of shape {v32.shape}, got {n.dtype} {n.shape}")
        n32 = np.ascontiguousarray(n, dtype=np.float32)
        if not np.isfinite(n32).all():
            raise InputError(f"{where}: normals contain NaN/Inf")
    return v32, f32, n32


def _fan_triangulate(polygons: np.ndarray) -> np.ndarray:
    """Triangulate an (m, k) array of k-gons as fans: (a,b,c,d) -> (a,b,c), (a,c,d)."""
    k = polygons.shape[1]
    if k == 3:
        return polygons
    tris = [polygons[:, [0, i, i + 1]] for i in range(1, k - 1)]
    # Keep each polygon's triangles together, in file order.
    return np.stack(tris, axis=1).reshape(-1, 3)


def _fan_triangulate_lists(polygons: list[list[int]], where: str) -> np.ndarray:
    """Fan-triangulate a list of polygons of mixed sizes, keeping file order."""
    out: list[tuple[int, int, int]] = []
    for number, poly in enumerate(polygons):
        if len(poly) < 3:
            raise InputError(f"{where}: face {number} has {len(poly)} vertices; a face needs at least 3")
        first = poly[0]
        out.extend((first, poly[i], poly[i + 1]) for i in range(1, len(poly) - 1))
    return np.array(out, dtype=np.int64).reshape(-1, 3)


def _vertex_normals(num_vertices: int, tri_vertex: np.ndarray, tri_normal: np.ndarray,
                    normals: np.ndarray, where: str) -> np.ndarray | None:
    """Per-vertex normals from per-corner normal indices, or None if they are not per-vertex.

    ``tri_vertex``/``tri_normal`` are matching (m, 3) corner index arrays
    (normal index -1: the corner has none). Normals are kept only if all
    corners of a vertex carry the same normal vector, i.e. the file's normals
    really are one per vertex, whatever their numbering, and every vertex gets
    one. Flat or split (per-face-corner) normals give None.
    """
    if len(normals) == 0 or tri_normal.size == 0 or tri_normal.shape != tri_vertex.shape:
        return None
    corners_v = tri_vertex.ravel()
    corners_n = tri_normal.ravel()
    if corners_n.min() < -1 or corners_n.max() >= len(normals):
        raise InputError(f"{where}: normal indices out of range (valid indices are 0..{len(normals) - 1})")
    if corners_n.min() == -1:
        return None  # some corners have no normal
    chosen = np.full(num_vertices, -1, dtype=np.int64)
    chosen[corners_v] = corners_n
    unreferenced = chosen < 0
    if unreferenced.any():
        # A vertex no face uses gets a normal only in the common "normal i belongs
        # to vertex i" layout (as save_obj writes); otherwise it has none to give.
        if len(normals) != num_vertices or not np.array_equal(corners_v, corners_n):
            return None
        chosen[unreferenced] = np.nonzero(unreferenced)[0]
    if not np.array_equal(normals[chosen[corners_v]], normals[corners_n]):
        return None  # some vertex has different normals at different corners
    result = np.asarray(normals[chosen], dtype=np.float64)
    if not np.isfinite(result).all():
        raise InputError(f"{where}: normals contain NaN/Inf")
    length = np.linalg.norm(result, axis=1)
    if (length < 1e-12).any():
        warnings.warn(f"{where}: some vertex normals have zero length; ignoring the file's normals", stacklevel=4)
        return None
    return (result / length[:, None]).astype(np.float32)


# libigl prints these remarks about lines it skips or files it rejects; they are
# either irrelevant to us ('o' object names) or superseded by our own diagnosis.
_IGL_CHATTER = re.compile(r"^(Warning: readOBJ\(\) ignored non-comment line \d+:|  .*|"
                          r"Error: read(OBJ|OFF)\(\).*|Failed to cast F to matrix.*|IOError: .*|Error: bad line.*)$")


def _call_igl(function, path: Path, faces_at: int):
    """Call a libigl reader, keeping its console chatter out of the user's terminal.

    Returns the reader's result, or None if libigl raised or found no faces
    (``result[faces_at]`` is empty); the caller then uses its own parser, whose
    diagnosis replaces libigl's. When libigl's result is used, captured output
    that is not libigl's known chatter (e.g. another thread's) is passed on to
    stderr.
    """
    with captured_native_output() as native:
        try:
            result = function(str(path))
        except (RuntimeError, ValueError):
            result = None
    if result is None or result[faces_at].size == 0:
        return None
    leftover = [line for line in native.text.splitlines() if line and not _IGL_CHATTER.match(line)]
    if leftover:
        sys.stderr.write("\n".join(leftover) + "\n")
    return result


def _read_text(path: Path) -> str:
    try:
        return path.read_bytes().decode("latin-1")
    except OSError as exc:
        raise InputError(f"{path}: cannot read file: {exc.strerror or exc}") from exc


def _parse_float(token: str, where: str, line_no: int) -> float:
    try:
        return float(token)
    except ValueError:
        raise InputError(f"{where}: bad number {token!r} on line {line_no}") from None


# --------------------------------------------------------------------------- #
# OBJ
# --------------------------------------------------------------------------- #


def _load_obj(path: Path):
    # libigl's readOBJ is fast, but it only returns a rectangular face matrix:
    # files mixing polygon sizes (the Quaternius trees: quads and n-gons) make
    # it fail with "Failed to cast F to matrix". It also rejects vertex lines
    # it cannot parse as three numbers (e.g. 'nan'), where our parser gives a
    # precise message. In both cases, and when libigl finds no faces (it skips
    # lines it does not understand), we parse the file ourselves.
    import igl

    if not _obj_faces_plain(path):
        return _parse_obj(path)  # strict, and names the line of any bad index
    result = _call_igl(igl.readOBJ, path, faces_at=3)
    if result is None:
        return _parse_obj(path)
    vertices, _tc, normals, faces, _ftc, face_normals = result
    if faces.shape[1] < 3:
        raise InputError(f"{path}: faces have {faces.shape[1]} vertices; a face needs at least 3")
    tri_v = _fan_triangulate(faces)
    _validated(vertices, tri_v, None, str(path))  # index range and NaN checks before using the indices
    tri_n = _fan_triangulate(face_normals) if face_normals.shape == faces.shape else np.empty((0, 3), np.int64)
    return vertices, tri_v, _vertex_normals(len(vertices), tri_v, tri_n, normals, str(path))


# libigl reads face indices with sscanf, which stops at the first non-digit
# ('4.9' -> 4, '3x' -> 3) and wraps large values (4294967299 -> 3). It is given
# a file only when every face corner is v, v/t, v//n or v/t/n with plain
# positive indices of at most 10 digits within the file's record counts; any
# other file goes to _parse_obj, which is strict and names the bad line.
_OBJ_FACE_LINE = re.compile(rb"^[ \t]*f[ \t]([^\r\n]*)", re.M)
_OBJ_BAD_SLASHES = re.compile(rb"(?:^|\s)/|/(?:\s|$)|/[0-9]*/[0-9]*/|[0-9]{11}")
_OBJ_RECORD = re.compile(rb"^[ \t]*(?:v|vt|vn)[ \t]", re.M)


def _obj_faces_plain(path: Path) -> bool:
    """Whether every face corner holds only plain positive indices within the
    file's record counts (see above), so that libigl reads them exactly."""
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise InputError(f"{path}: cannot read file: {exc.strerror or exc}") from exc
    if b"\\" in data:
        return False  # line continuations: only _parse_obj joins them
    faces = b" ".join(_OBJ_FACE_LINE.findall(data))
    if faces.translate(None, b"0123456789/ \t") or _OBJ_BAD_SLASHES.search(faces):
        return False
    numbers = np.array(faces.replace(b"/", b" ").split()).astype(np.int64)
    return numbers.size == 0 or (int(numbers.min()) >= 1 and int(numbers.max()) <= len(_OBJ_RECORD.findall(data)))


def _parse_obj(path: Path):
    """Minimal OBJ parser: v, vn and f records (any polygon size, a, a/b, a//c, a/b/c, negative indices)."""
    where = str(path)
    text = _read_text(path).replace("\\\r\n", " ").replace("\\\n", " ")  # line continuations
    vertices: list[list[float]] = []
    normals: list[list[float]] = []
    faces_v: list[list[int]] = []
    faces_n: list[list[int]] = []
    for line_no, line in enumerate(text.splitlines(), start=1):
        tokens = line.split()
        if not tokens:
            continue
        tag = tokens[0]
        if tag == "v":
            if len(tokens) < 4:
                raise InputError(f"{where}: vertex on line {line_no} has fewer than 3 coordinates")
            # Extra values (w, or the r g b of the vertex-colour extension) are ignored.
            vertices.append([_parse_float(t, where, line_no) for t in tokens[1:4]])
        elif tag == "vn":
            if len(tokens) < 4:
                raise InputError(f"{where}: normal on line {line_no} has fewer than 3 coordinates")
            normals.append([_parse_float(t, where, line_no) for t in tokens[1:4]])
        elif tag == "f":
            if len(tokens) < 4:
                raise InputError(f"{where}: face on line {line_no} has {len(tokens) - 1} vertices; "
                                 "a face needs at least 3")
            fv, fn = [], []
            for token in tokens[1:]:
                parts = token.split("/")
                fv.append(_obj_index(parts[0], len(vertices), where, line_no))
                has_normal = len(parts) >= 3 and parts[2] != ""
                fn.append(_obj_index(parts[2], len(normals), where, line_no) if has_normal else -1)
            faces_v.append(fv)
            faces_n.append(fn)
        # Everything else (vt, o, g, s, usemtl, mtllib, l, p, comments) does not affect the triangles.
    if not faces_v:
        raise InputError(f"{where}: the mesh has no faces")
    tri_v = _fan_triangulate_lists(faces_v, where)
    tri_n = _fan_triangulate_lists(faces_n, where)
    vertex_array = np.array(vertices, dtype=np.float64).reshape(-1, 3)
    normal_array = np.array(normals, dtype=np.float64).reshape(-1, 3)
    _validated(vertex_array, tri_v, None, where)  # index range and NaN checks before using the indices
    return vertex_array, tri_v, _vertex_normals(len(vertex_array), tri_v, tri_n, normal_array, where)


def _obj_index(token: str, count_so_far: int, where: str, line_no: int) -> int:
    """Convert a 1-based (or negative, relative) OBJ index to 0-based."""
    index = parse_int(token, f"{where}: bad index on line {line_no}", -UINT32[1], UINT32[1])
    if index > 0:
        return index - 1  # checked against the final vertex count later (forward references are legal)
    if index < 0 and -index <= count_so_far:
        return count_so_far + index
    raise InputError(f"{where}: face index {index} on line {line_no} is out of range")


# --------------------------------------------------------------------------- #
# OFF
# --------------------------------------------------------------------------- #


def _load_off(path: Path):
    # Always parsed here: libigl's readOFF reads a face line's vertex count and
    # then as many integers as it wants, wherever they are ('5 0 1 2' became
    # three triangles, '99999 0 1 2' 99,997 degenerate ones), and wraps large
    # indices. OFF files are small in practice; strictness matters more.
    return _parse_off(path)


def _parse_off(path: Path):
    """Minimal OFF parser: [C][N]OFF, one vertex or face per line, polygons of any size.

    Parsed by line because colours (COFF vertices, and optional per-face
    colours after the indices) have 3 or 4 components, so a token stream would
    be ambiguous; anything after the coordinates or indices is ignored.
    """
    where = str(path)
    lines = [line.split("#", 1)[0].split() for line in _read_text(path).splitlines()]
    lines = [tokens for tokens in lines if tokens]
    if not lines or not re.fullmatch(r"C?N?OFF", lines[0][0]):
        first = lines[0][0][:20] if lines else ""
        raise InputError(f"{where}: not a supported OFF file (header {first!r}; expected OFF, COFF, NOFF or CNOFF)")
    has_normals = "N" in lines[0][0]
    counts = lines[0][1:] if len(lines[0]) > 1 else (lines[1] if len(lines) > 1 else [])
    body = 1 if len(lines[0]) > 1 else 2
    if len(counts) < 2:
        raise InputError(f"{where}: bad OFF counts line")
    num_v = parse_int(counts[0], f"{where}: OFF vertex count", 0, UINT32[1])
    num_f = parse_int(counts[1], f"{where}: OFF face count", 0, UINT32[1])
    width = 6 if has_normals else 3
    vertex_lines = lines[body:body + num_v]
    face_lines = lines[body + num_v:body + num_v + num_f]
    if len(vertex_lines) < num_v or len(face_lines) < num_f:
        raise InputError(f"{where}: truncated OFF file (expected {num_v} vertices and {num_f} faces, found "
                         f"{len(vertex_lines)} and {len(face_lines)})")
    if any(len(tokens) < width for tokens in vertex_lines):
        raise InputError(f"{where}: an OFF vertex line has fewer than {width} numbers")
    try:
        data = np.array([tokens[:width] for tokens in vertex_lines], dtype=np.float64).reshape(-1, width)
    except ValueError:
        raise InputError(f"{where}: bad number in an OFF vertex line") from None
    polygons = []
    for i, tokens in enumerate(face_lines):
        k = parse_int(tokens[0], f"{where}: OFF face {i}: vertex count", 0, UINT32[1])
        polygons.append([parse_int(t, f"{where}: OFF face {i}: vertex index", 0, UINT32[1])
                         for t in tokens[1:1 + k]])
        if len(polygons[-1]) != k:
            raise InputError(f"{where}: OFF face {i} lists fewer than its {k} indices")
    tri = _fan_triangulate_lists(polygons, where)
    if len(tri) == 0:
        raise InputError(f"{where}: the mesh has no faces")
    _validated(data[:, :3], tri, None, where)
    normals = _vertex_normals(len(data), tri, tri, data[:, 3:6], where) if has_normals else None
    return data[:, :3], tri, normals


# --------------------------------------------------------------------------- #
# PLY
# --------------------------------------------------------------------------- #

_PLY_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
    "short": "i2", "int16": "i2", "ushort": "u2", "uint16": "u2",
    "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}


def _load_ply(path: Path):
    # Parsed here, not by libigl: libigl 2.6's PLY reader aborts the whole
    # process (a double free) on an ASCII file mixing triangles and quads,
    # returns uninitialised face indices for a truncated binary file, and its
    # Python binding does not return per-vertex normals.
    where = str(path)
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise InputError(f"{where}: cannot read file: {exc.strerror or exc}") from exc
    fmt, elements, body = _parse_ply_header(data, where)
    if fmt == "ascii":
        values = _read_ply_ascii(data[body:], elements, where)
    else:
        values = _read_ply_binary(data, body, elements, "<" if fmt == "binary_little_endian" else ">", where)

    vertex = values.get("vertex")
    if vertex is None or not all(isinstance(vertex.get(name), np.ndarray) and vertex[name].ndim == 1
                                 for name in ("x", "y", "z")):
        raise InputError(f"{where}: PLY file has no vertex element with x, y, z (scalar) properties")
    vertices = np.stack([vertex["x"], vertex["y"], vertex["z"]], axis=1).astype(np.float64)
    face = values.get("face")
    lists = None
    if face is not None:
        lists = face.get("vertex_indices", face.get("vertex_index"))
    if lists is None:
        raise InputError(f"{where}: the mesh has no faces (no face element with vertex_indices)")
    if isinstance(lists, np.ndarray):  # all faces have the same size
        if lists.ndim != 2 or lists.shape[1] < 3:
            raise InputError(f"{where}: PLY faces have fewer than 3 vertices")
        tri = _fan_triangulate(lists)
    else:
        tri = _fan_triangulate_lists(lists, where)
    if len(tri) == 0:
        raise InputError(f"{where}: the mesh has no faces")
    _validated(vertices, tri, None, where)  # index range and NaN checks before using the indices
    normals = None
    if all(isinstance(vertex.get(name), np.ndarray) and vertex[name].ndim == 1 for name in ("nx", "ny", "nz")):
        stacked = np.stack([vertex["nx"], vertex["ny"], vertex["nz"]], axis=1).astype(np.float64)
        normals = _vertex_normals(len(vertices), tri, tri, stacked, where)
    return vertices, tri, normals


def _parse_ply_header(data: bytes, where: str):
    """Return (format, elements, offset of the body); elements: [(name, count, [(prop, type | (count_t, item_t))])]."""
    if not data.startswith(b"ply"):
        raise InputError(f"{where}: not a PLY file (missing 'ply' magic)")
    end = data.find(b"end_header")
    if end < 0:
        raise InputError(f"{where}: truncated or corrupt PLY header (no end_header)")
    newline = data.find(b"\n", end)
    if newline < 0:
        raise InputError(f"{where}: truncated PLY file (nothing after end_header)")
    body = newline + 1
    fmt = None
    elements: list[tuple[str, int, list]] = []
    for line in data[:end].decode("latin-1").splitlines()[1:]:
        tokens = line.split()
        if not tokens or tokens[0] in ("comment", "obj_info"):
            continue
        try:
            if tokens[0] == "format":
                fmt = tokens[1]
                if fmt not in ("ascii", "binary_little_endian", "binary_big_endian"):
                    raise InputError(f"{where}: unknown PLY format {fmt!r}")
            elif tokens[0] == "element":
                count = parse_int(tokens[2], f"{where}: PLY element {tokens[1][:40]!r} count", 0, UINT32[1])
                elements.append((tokens[1], count, []))
            elif tokens[0] == "property":
                if not elements:
                    raise InputError(f"{where}: PLY property before any element")
                if tokens[1] == "list":
                    kind = (_ply_type(tokens[2], where), _ply_type(tokens[3], where))
                    if kind[0][0] == "f" or (tokens[4] in ("vertex_indices", "vertex_index") and kind[1][0] == "f"):
                        raise InputError(f"{where}: PLY list property {tokens[4]!r} must have integer types")
                    prop = (tokens[4], kind)
                else:
                    prop = (tokens[2], _ply_type(tokens[1], where))
                if any(prop[0] == other for other, _ in elements[-1][2]):
                    raise InputError(f"{where}: PLY element {elements[-1][0]!r} declares property "
                                     f"{prop[0][:40]!r} twice")
                elements[-1][2].append(prop)
            else:
                raise InputError(f"{where}: unexpected PLY header line {line.strip()[:40]!r}")
        except InputError:
            raise
        except (IndexError, ValueError):
            raise InputError(f"{where}: malformed PLY header line {line.strip()[:40]!r}") from None
    if fmt is None:
        raise InputError(f"{where}: PLY header has no format line")
    # Every element takes at least one token (ASCII) or its scalars' and list
    # counts' bytes (binary): a header may not promise more elements than the file holds.
    available = len(data[body:].split()) if fmt == "ascii" else len(data) - body
    needed = 0
    for name, count, props in elements:
        if count and not props:
            raise InputError(f"{where}: PLY element {name[:40]!r} has {count} items but no properties")
        per_item = len(props) if fmt == "ascii" else sum(
            np.dtype(kind if isinstance(kind, str) else kind[0]).itemsize for _, kind in props)
        needed += count * per_item
    check_data(needed, available, "the PLY header's element counts", where)
    return fmt, elements, body


def _ply_type(name: str, where: str) -> str:
    try:
        return _PLY_TYPES[name]
    except KeyError:
        raise InputError(f"{where}: unknown PLY property type {name!r}") from None


def _read_ply_binary(data: bytes, pos: int, elements, endian: str, where: str) -> dict:
    values: dict[str, dict] = {}
    for name, count, props in elements:
        scalar = all(isinstance(kind, str) for _, kind in props)
        if scalar:
            dtype = np.dtype([(p, endian + kind) for p, kind in props])
            nbytes = dtype.itemsize * count
            if pos + nbytes > len(data):
                raise InputError(f"{where}: truncated PLY file (element {name!r} needs {nbytes} bytes, "
                                 f"{max(len(data) - pos, 0)} left)")
            table = np.frombuffer(data, dtype=dtype, count=count, offset=pos)
            values[name] = {p: table[p] for p, _ in props}
            pos += nbytes
            continue
        fast = _read_ply_uniform_lists(data, pos, count, props, endian)
        if fast is not None:
            values[name], pos = fast
            continue
        values[name], pos = _read_ply_binary_slow(data, pos, count, props, endian, name, where)
    return values


def _read_ply_uniform_lists(data: bytes, pos: int, count: int, props, endian: str):
    """Fast path: every list in the element has the same length as the first one (e.g. all triangles)."""
    lengths = []
    offset = pos
    for _, kind in props:
        if isinstance(kind, str):
            offset += np.dtype(kind).itemsize
            continue
        count_type, _item = kind
        if offset + np.dtype(count_type).itemsize > len(data) or count == 0:
            return None
        length = int(np.frombuffer(data, dtype=endian + count_type, count=1, offset=offset)[0])
        if not 0 <= length <= len(data):
            return None  # the slow path reports it
        lengths.append(length)
        offset += np.dtype(count_type).itemsize + length * np.dtype(_item).itemsize
    fields = []
    list_iter = iter(lengths)
    for prop, kind in props:
        if isinstance(kind, str):
            fields.append((prop, endian + kind))
        else:
            length = next(list_iter)
            fields.append((prop + "#count", endian + kind[0]))
            fields.append((prop, endian + kind[1], (length,)))
    try:
        dtype = np.dtype(fields)
    except ValueError:  # e.g. a property named like the count field added here
        return None
    if pos + dtype.itemsize * count > len(data):
        return None  # let the slow path report where the data ends
    table = np.frombuffer(data, dtype=dtype, count=count, offset=pos)
    list_iter = iter(lengths)
    for prop, kind in props:
        if not isinstance(kind, str) and not np.all(table[prop + "#count"] == next(list_iter)):
            return None
    result = {prop: table[prop] if isinstance(kind, str) else table[prop].astype(np.int64) for prop, kind in props}
    return result, pos + dtype.itemsize * count


def _read_ply_binary_slow(data: bytes, pos: int, count: int, props, endian: str, name: str, where: str):
    columns: dict[str, list] = {p: [] for p, _ in props}
    size = len(data)
    for i in range(count):
        for prop, kind in props:
            if isinstance(kind, str):
                item = np.dtype(endian + kind)
                if pos + item.itemsize > size:
                    raise InputError(f"{where}: truncated PLY file (element {name!r} {i} of {count} is incomplete)")
                columns[prop].append(np.frombuffer(data, dtype=item, count=1, offset=pos)[0])
                pos += item.itemsize
            else:
                count_type, item_type = np.dtype(endian + kind[0]), np.dtype(endian + kind[1])
                if pos + count_type.itemsize > size:
                    raise InputError(f"{where}: truncated PLY file (element {name!r} {i} of {count} is incomplete)")
                length = int(np.frombuffer(data, dtype=count_type, count=1, offset=pos)[0])
                pos += count_type.itemsize
                if length < 0:
                    raise InputError(f"{where}: corrupt PLY file (element {name!r} {i} has a list of "
                                     f"length {length})")
                if pos + length * item_type.itemsize > size:
                    raise InputError(f"{where}: truncated PLY file (element {name!r} {i} of {count} is incomplete)")
                items = np.frombuffer(data, dtype=item_type, count=length, offset=pos)
                columns[prop].append(items.astype(np.int64).tolist())
                pos += length * item_type.itemsize
    result = {p: (np.array(columns[p]) if isinstance(kind, str) else columns[p]) for p, kind in props}
    return result, pos


def _read_ply_ascii(body: bytes, elements, where: str) -> dict:
    # PLY ASCII data is a stream of whitespace-separated tokens; element rows
    # need not be one per line, so parse the token stream.
    tokens = body.decode("latin-1").split()
    pos = 0
    values: dict[str, dict] = {}
    for name, count, props in elements:
        if all(isinstance(kind, str) for _, kind in props):
            n = count * len(props)
            if pos + n > len(tokens):
                raise InputError(f"{where}: truncated PLY file (expected {count} {name!r} elements)")
            try:
                table = np.array(tokens[pos:pos + n], dtype=np.float64).reshape(count, len(props))
            except ValueError:
                raise InputError(f"{where}: bad number in PLY element {name!r}") from None
            values[name] = {p: table[:, k] for k, (p, _) in enumerate(props)}
            pos += n
            continue
        columns: dict[str, list] = {p: [] for p, _ in props}
        try:
            for i in range(count):
                for prop, kind in props:
                    if pos >= len(tokens):
                        raise InputError(f"{where}: truncated PLY file (element {name!r} {i} of {count} is incomplete)")
                    if isinstance(kind, str):
                        columns[prop].append(float(tokens[pos]))
                        pos += 1
                    else:
                        length = parse_int(tokens[pos], f"{where}: PLY element {name!r} {i}: list length",
                                           0, UINT32[1])
                        items = tokens[pos + 1:pos + 1 + length]
                        if len(items) != length:
                            raise InputError(f"{where}: truncated PLY file (element {name!r} {i} of {count} "
                                             "is incomplete)")
                        columns[prop].append([parse_int(t, f"{where}: PLY element {name!r} {i}: list item")
                                              for t in items])
                        pos += 1 + length
        except ValueError:
            raise InputError(f"{where}: bad number in PLY element {name!r}") from None
        values[name] = {p: (np.array(columns[p]) if isinstance(kind, str) else columns[p]) for p, kind in props}
    return values


# --------------------------------------------------------------------------- #
# STL
# --------------------------------------------------------------------------- #

_STL_VERTEX = re.compile(rb"vertex\s+(\S+)\s+(\S+)\s+(\S+)")


def _load_stl(path: Path):
    # Parsed here, not by libigl: libigl's readSTL silently returns an empty
    # mesh for a truncated binary file and a partial mesh for a truncated ASCII
    # file, and a renderer must not silently drop geometry. Both variants are
    # simple enough to read and validate in a few lines.
    where = str(path)
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise InputError(f"{where}: cannot read file: {exc.strerror or exc}") from exc
    corners = _read_stl_binary(data, where) if _is_binary_stl(data) else _read_stl_ascii(data, where)
    if len(corners) == 0:
        raise InputError(f"{where}: the mesh has no faces")
    # STL repeats each corner per triangle: merge exactly equal positions so the
    # mesh is connected. (+0.0 turns -0.0 into 0.0, which compares equal anyway,
    # but keeps the merged vertex's bits canonical.) Vertices are numbered in
    # order of first appearance.
    positions = corners.astype(np.float32) + np.float32(0.0)
    unique, first, inverse = np.unique(positions, axis=0, return_index=True, return_inverse=True)
    order = np.argsort(first, kind="stable")
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    vertices = unique[order]
    faces = rank[inverse.reshape(-1)].reshape(-1, 3)
    return vertices, faces, None


def _is_binary_stl(data: bytes) -> bool:
    """Binary when the size matches the triangle count in the header (some binary
    files' 80-byte header starts with 'solid' too), or when it does not start with 'solid'."""
    if len(data) >= 84 and len(data) == 84 + 50 * int.from_bytes(data[80:84], "little"):
        return True
    return data.lstrip()[:5].lower() != b"solid"


def _read_stl_binary(data: bytes, where: str) -> np.ndarray:
    count = int.from_bytes(data[80:84], "little") if len(data) >= 84 else None
    if count is None or len(data) != 84 + 50 * count:
        expected = "" if count is None else f"; the header announces {count} triangles = {84 + 50 * count} bytes"
        raise InputError(f"{where}: not a valid STL file (does not start with 'solid' and is not a complete binary "
                         f"STL: {len(data)} bytes{expected})")
    record = np.dtype([("normal", "<f4", (3,)), ("corners", "<f4", (3, 3)), ("attribute", "<u2")])
    table = np.frombuffer(data, dtype=record, count=count, offset=84)
    return table["corners"].reshape(-1, 3).astype(np.float32)


def _read_stl_ascii(data: bytes, where: str) -> np.ndarray:
    if b"endsolid" not in data:
        raise InputError(f"{where}: truncated ASCII STL file (no 'endsolid')")
    matches = _STL_VERTEX.findall(data)
    if len(matches) % 3 or len(matches) != 3 * data.count(b"endfacet"):
        raise InputError(f"{where}: corrupt ASCII STL file ({len(matches)} vertices for "
                         f"{data.count(b'endfacet')} facets)")
    try:
        return np.array(matches, dtype=np.float64).reshape(-1, 3)
    except ValueError:
        raise InputError(f"{where}: bad number in ASCII STL file") from None

