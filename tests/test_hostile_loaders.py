"""Hostile input to the Python loaders and bindings (issue 17, loader half).

Each test here is a regression test for a defect found by fuzzing the loaders:
integers that wrapped or were truncated, small files that cost gigabytes, and
raw Python exceptions (ValueError, MemoryError, OverflowError, ...) where a
penumbra error (InputError) is the contract. docs/reliability.md.
"""

from __future__ import annotations

import struct
import time
import zlib
from pathlib import Path

import numpy as np
import pytest

from penumbra.errors import InputError
from penumbra.imageio import read_envmap
from penumbra.meshio import load_mesh

QUAD = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\n"


def write(path: Path, data: str | bytes) -> Path:
    path.write_bytes(data.encode() if isinstance(data, str) else data)
    return path


# --------------------------------------------------------------------------- #
# 1. Strict integers
# --------------------------------------------------------------------------- #


@pytest.mark.parametrize("token", ["4294967299", "4.9", "3x", "9223372036854775808", "18446744073709551619",
                                   "1e2", "0x3", "1_0"])
def test_obj_face_index_strict(tmp_path, token):
    """libigl read 4294967299 as 3 (wrapped), 4.9 as 4 and 3x as 3: now each is refused, naming the line."""
    path = write(tmp_path / "m.obj", QUAD + f"f 1 2 {token}\n")
    with pytest.raises(InputError, match="line 5"):
        load_mesh(path)


def test_obj_negative_index_beyond_relative_range(tmp_path):
    with pytest.raises(InputError, match="line 5"):
        load_mesh(write(tmp_path / "m.obj", QUAD + "f -1 -2 -5\n"))


def test_obj_plain_files_still_read(tmp_path):
    mesh = load_mesh(write(tmp_path / "m.obj", QUAD + "f 1 2 3 4\nf -1 -2 -3\nf 1//1 2//1 3//1\nvn 0 0 1\n"))
    assert mesh.faces.tolist() == [[0, 1, 2], [0, 2, 3], [3, 2, 1], [0, 1, 2]]


@pytest.mark.parametrize("line", ["5 0 1 2", "99999 0 1 2", "3 0 1 2.5", "3 0 1 2x", "3 0 1 4294967298",
                                  "3.0 0 1 2"])
def test_off_face_line_strict(tmp_path, line):
    """'5 0 1 2' gave three triangles and '99999 0 1 2' 99,997 degenerate ones (libigl reads on past the line)."""
    path = write(tmp_path / "m.off", f"OFF\n4 1 0\n0 0 0\n1 0 0\n0 1 0\n1 1 0\n{line}\n")
    with pytest.raises(InputError, match="OFF face 0"):
        load_mesh(path)


def test_off_counts_strict(tmp_path):
    with pytest.raises(InputError, match="count"):
        load_mesh(write(tmp_path / "m.off", "OFF\n4 1.5 0\n0 0 0\n1 0 0\n0 1 0\n1 1 0\n3 0 1 2\n"))


def test_ply_ascii_index_beyond_int64(tmp_path):
    """An index >= 2**63 raised OverflowError from numpy."""
    text = ("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
            "element face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n"
            "3 0 1 9223372036854775808\n")
    with pytest.raises(InputError):
        load_mesh(write(tmp_path / "m.ply", text))


def test_mesh_binding_index_beyond_uint32(ctx):
    """Mesh(ctx, v, [[0, 1, 2**32 + 3]]) used vertex 3 (the uint32 cast wrapped)."""
    from penumbra.core import Mesh

    v = np.eye(4, 3, dtype=np.float32)
    with pytest.raises(InputError, match="out of range"):
        Mesh(ctx, v, [[0, 1, 2**32 + 3]])
    with pytest.raises(InputError):
        Mesh(ctx, v, [[0, 1, 2**64 + 3]])


@pytest.mark.parametrize("size", [(2**32 + 1, 1), (1, 2**32 + 1), (-1, 4), (2.5, 4)])
def test_gbuffer_size_not_wrapped(ctx, size):
    """GBuffer(ctx, 2**32 + 1, 1) was a 1 x 1 G-buffer."""
    from penumbra.core import GBuffer

    with pytest.raises(InputError, match="width|height"):
        GBuffer(ctx, *size)


def test_envmap_int_parameter_not_wrapped(ctx):
    """face_size=2**32 + 8 was face size 8."""
    from penumbra.core import EnvMap

    with pytest.raises(InputError, match="face_size"):
        EnvMap(ctx, np.ones((8, 16, 3), np.float32), face_size=2**32 + 8)


def test_native_call_refuses_wrapping(ctx):
    """Every integer argument that reaches ctypes is checked against its C type (penumbra._native.call)."""
    import ctypes

    from penumbra import _native

    out = ctypes.c_void_p()
    with pytest.raises(InputError, match="pn_gbuffer_create: argument 2"):
        _native.call("pn_gbuffer_create", ctx._h, ctx._h, 2**32 + 1, 1, ctypes.byref(out))
    with pytest.raises(InputError, match="pn_image_create: argument 3"):
        _native.call("pn_image_create", ctx._h, ctx._h, 1, -1, ctypes.byref(out))


# --------------------------------------------------------------------------- #
# 2. Small files that cost gigabytes
# --------------------------------------------------------------------------- #


def old_rle_hdr(width: int, height: int) -> bytes:
    """A Radiance picture whose every scanline is one pixel and old-style run markers."""
    header = f"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y {height} +X {width}\n".encode()
    run = width - 1
    markers = b""
    while run:
        markers += bytes((1, 1, 1, run & 0xFF))
        run >>= 8
    return header + (bytes((128, 128, 128, 129)) + markers) * height


def test_hdr_old_rle_bomb_refused(tmp_path):
    """A 197 KB old-RLE .hdr of 16384 x 16384 decoded with 9.5 GB and 31 s: now refused at once."""
    path = write(tmp_path / "bomb.hdr", old_rle_hdr(16384, 16384))
    assert path.stat().st_size < 200_000
    start = time.perf_counter()
    with pytest.raises(InputError, match="PENUMBRA_MAX_BYTES"):
        read_envmap(path)
    assert time.perf_counter() - start < 5


def test_hdr_old_rle_small_still_read(tmp_path):
    image = read_envmap(write(tmp_path / "ok.hdr", old_rle_hdr(300, 4)))
    assert image.shape == (4, 300, 3) and np.all(image == 1.0)


def test_hdr_height_beyond_file(tmp_path):
    with pytest.raises(InputError, match="truncated"):
        read_envmap(write(tmp_path / "t.hdr", b"#?RADIANCE\n\n-Y 1000000 +X 8\n" + b"\x80" * 64))


def test_hdr_resolution_digits_bounded(tmp_path):
    """A 5000-digit height raised ValueError from int() (Python's digit limit)."""
    with pytest.raises(InputError, match="resolution"):
        read_envmap(write(tmp_path / "t.hdr", b"#?RADIANCE\n\n-Y " + b"9" * 5000 + b" +X 8\n"))


def npy_bytes(shape: tuple, dtype: str = "<f4", data: bytes = b"") -> bytes:
    header = repr({"descr": dtype, "fortran_order": False, "shape": shape}).encode()
    header += b" " * (-(10 + len(header) + 1) % 64) + b"\n"
    return b"\x93NUMPY\x01\x00" + struct.pack("<H", len(header)) + header + data


@pytest.mark.parametrize("shape", [(2**40, 2**40, 3), (2**62, 2**62, 3), (1000, 1000, 3)])
def test_npy_header_promising_too_much(tmp_path, shape):
    """Huge shapes raised ValueError/MemoryError tracebacks; a header may not promise more than the file holds."""
    with pytest.raises(InputError, match="PENUMBRA_MAX|truncated"):
        read_envmap(write(tmp_path / "big.npy", npy_bytes(shape, data=b"\0" * 64)))


def test_npy_object_array_refused(tmp_path):
    with pytest.raises(InputError):
        read_envmap(write(tmp_path / "o.npy", npy_bytes((1, 1, 3), "|O", b"\0" * 24)))


def test_npy_fortran_order_read(tmp_path):
    a = np.arange(2 * 5 * 3, dtype=np.float32).reshape(2, 5, 3)
    np.save(tmp_path / "f.npy", np.asfortranarray(a))
    assert np.array_equal(read_envmap(tmp_path / "f.npy"), a)


def test_max_bytes_variable(tmp_path, monkeypatch):
    """PENUMBRA_MAX_BYTES caps what one input may make the loaders allocate; the refusal names it."""
    np.save(tmp_path / "env.npy", np.ones((32, 64, 3), np.float32))
    assert read_envmap(tmp_path / "env.npy").shape == (32, 64, 3)
    monkeypatch.setenv("PENUMBRA_MAX_BYTES", "10000")
    with pytest.raises(InputError, match="PENUMBRA_MAX_BYTES"):
        read_envmap(tmp_path / "env.npy")
    monkeypatch.setenv("PENUMBRA_MAX_BYTES", "lots")
    with pytest.raises(InputError, match="PENUMBRA_MAX_BYTES"):
        read_envmap(tmp_path / "env.npy")


def test_max_pixels_variable_exr(tmp_path, monkeypatch):
    from penumbra.imageio import write_exr

    write_exr(tmp_path / "e.exr", np.ones((32, 64, 3), np.float32))
    monkeypatch.setenv("PENUMBRA_MAX_PIXELS", "1000")
    with pytest.raises(InputError, match="PENUMBRA_MAX_PIXELS"):
        read_envmap(tmp_path / "e.exr")


def png_bytes(width: int, height: int, idat: bytes, bit_depth: int = 8, colour: int = 0) -> bytes:
    def chunk(kind: bytes, body: bytes) -> bytes:
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))

    ihdr = struct.pack(">IIBBBBB", width, height, bit_depth, colour, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", idat) + chunk(b"IEND", b"")


def test_png_height_map_bomb_refused(tmp_path):
    """A PNG claiming 100000 x 100000 pixels raised Pillow's DecompressionBombError (a traceback)."""
    from penumbra.heightfield import load_heights

    path = write(tmp_path / "bomb.png", png_bytes(100_000, 100_000, zlib.compress(b"\0" * 100_001)))
    with pytest.raises(InputError, match="PENUMBRA_MAX_PIXELS"):
        load_heights(path)


def test_png_height_map_over_max_bytes(tmp_path, monkeypatch):
    """A zlib bomb: 4 MB of pixels in a few KB; with a 1 MB cap it is refused before decoding."""
    from penumbra.heightfield import load_heights

    rows = b"".join(b"\0" + b"\0" * 2000 for _ in range(2000))
    path = write(tmp_path / "zbomb.png", png_bytes(2000, 2000, zlib.compress(rows, 9)))
    assert path.stat().st_size < 20_000
    assert load_heights(path).shape == (2000, 2000)
    monkeypatch.setenv("PENUMBRA_MAX_BYTES", str(1 << 20))
    with pytest.raises(InputError, match="PENUMBRA_MAX_BYTES"):
        load_heights(path)


def test_height_map_npy_huge_shape(tmp_path):
    from penumbra.heightfield import load_heights

    with pytest.raises(InputError):
        load_heights(write(tmp_path / "h.npy", npy_bytes((2**31, 2**31), data=b"\0" * 64)))


def ply_binary_face_header(n_faces: int, count_type: str = "uint") -> bytes:
    return (f"ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
            f"property float z\nelement face {n_faces}\nproperty list {count_type} int vertex_indices\n"
            "end_header\n").encode()


def test_ply_huge_list_count(tmp_path):
    """A list count of 2**32 - 1 raised ValueError from numpy's dtype."""
    body = np.eye(3, dtype="<f4").tobytes() + struct.pack("<I", 2**32 - 1) + struct.pack("<3i", 0, 1, 2)
    with pytest.raises(InputError, match="truncated|corrupt"):
        load_mesh(write(tmp_path / "m.ply", ply_binary_face_header(1) + body))


def test_ply_negative_list_count(tmp_path):
    body = np.eye(3, dtype="<f4").tobytes() + struct.pack("<b", -1) + struct.pack("<3i", 0, 1, 2)
    with pytest.raises(InputError):
        load_mesh(write(tmp_path / "m.ply", ply_binary_face_header(1, "char") + body))


def test_ply_element_count_beyond_file(tmp_path):
    body = np.eye(3, dtype="<f4").tobytes() + struct.pack("<B3i", 3, 0, 1, 2)
    with pytest.raises(InputError, match="element counts"):
        load_mesh(write(tmp_path / "m.ply", ply_binary_face_header(2**32 - 1, "uchar") + body))


# --------------------------------------------------------------------------- #
# 3. Tracebacks instead of errors
# --------------------------------------------------------------------------- #


def test_ply_duplicate_property(tmp_path):
    """Duplicate properties raised numpy's ValueError ('field occurs more than once')."""
    text = ("ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\nproperty float x\n"
            "property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n")
    body = np.eye(3, dtype="<f4").tobytes() + struct.pack("<B3i", 3, 0, 1, 2)
    with pytest.raises(InputError, match="twice"):
        load_mesh(write(tmp_path / "m.ply", text.encode() + body))


def test_ply_list_coordinates(tmp_path):
    text = ("ply\nformat ascii 1.0\nelement vertex 3\nproperty list uchar float x\nproperty float y\n"
            "property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n"
            "2 0 0 0 0\n1 1 0 0\n1 0 1 0\n3 0 1 2\n")
    with pytest.raises(InputError, match="x, y, z"):
        load_mesh(write(tmp_path / "m.ply", text))


def test_npy_header_tokenizer_error(tmp_path):
    """Fuzz finding (the input as found): a header that does not tokenize raised
    tokenize.TokenError from numpy's header parser."""
    import base64

    data = base64.b64decode(
        "k05VTVBZAQB2AHsnZGVzY3InOiAnPGY0JywgJ2ZvcnRyYW5fb3JkZXInOiBGTExMTExMTExMTExMTExMTExMTExMTGFsc2Us"
        "ICAgICAgICAgIAoAAAAAAAAAPgAAgD4AAMA+AAAAPwAAID8AAEA/ACAnc2hhcGUnOiAoMywgMyksIH0gICAgICAgICAgICAg"
        "ICAgICAgICAgICAgICAgICAgICAgICAgICAgICAgICAgICAgICAgICAgICAgCgAAAAAAAAA+AACAPgAAwD4AAAA/AAAgPwAA"
        "QD8AAGA/AACAPw==")
    with pytest.raises(InputError, match="header"):
        read_envmap(write(tmp_path / "t.npy", data))


def test_npy_subarray_dtype(tmp_path):
    """Fuzz finding (the input as found): descr '4f2', a subarray type, made the height and albedo
    readers raise ValueError (cannot reshape)."""
    import base64

    from penumbra.heightfield import load_albedo, load_heights

    path = write(tmp_path / "t.npy", base64.b64decode(
        "k05VTVBZAQB2AHsnZGVzY3InOiAnNGYyJywgJ2ZvcnRyYW5fb3JkZXInOiBGYWxzZSwgJ3NoYXBlJzogKDIsIDIsIDMpLCB9"
        "ICAgICAgICAgICAgICAgICAgICAgICAgICAgICAgICAgICAgICAgICAgICAgICAgICAgICAgICAgICAgICAgICAgICAgICAg"
        "ICAgICAgICAgICAgICAgICAgICAgICAgICAgICAgIAoAAAAAAAAAAAAAAAAAABhAAAAAAAAAKEAAAAAAAAAIQAAAAAAAACJA"
        "AAAgICAgICAgIAoAPAA8ADwAPAA8ADwAPAA8AAA8"))
    for load in (read_envmap, load_heights, load_albedo):
        with pytest.raises(InputError, match="subarrays"):
            load(path)


@pytest.mark.parametrize("shape", [(0, 444444444444444444444444444444444444444444443), (0, 2**63), (-1, 4, 3)])
def test_npy_implausible_shape(tmp_path, shape):
    """Fuzz finding: a zero-size shape with a huge dimension raised ValueError (reshape) here,
    OverflowError from np.load before."""
    from penumbra.heightfield import load_heights

    path = write(tmp_path / "t.npy", npy_bytes(shape, data=b"\0" * 64))
    for load in (read_envmap, load_heights):
        with pytest.raises(InputError):
            load(path)


def test_scene_file_not_utf8(tmp_path):
    """Fuzz finding: scenefile.read_toml raised UnicodeDecodeError (fixed on main by the scene file work)."""
    from penumbra.scenefile import load_scene

    with pytest.raises(InputError):
        load_scene(write(tmp_path / "s.toml", b"[camera]\nresolution = [8, 8]\n# \x92\n"))


def test_file_size_over_max_bytes(tmp_path, monkeypatch):
    """The mesh and Radiance readers hold the whole file: its size counts against PENUMBRA_MAX_BYTES."""
    mesh = write(tmp_path / "m.obj", QUAD + "f 1 2 3\n" + "# padding\n" * 200)
    picture = write(tmp_path / "p.hdr", old_rle_hdr(300, 100))
    monkeypatch.setenv("PENUMBRA_MAX_BYTES", "1000")
    for path in (mesh, picture):
        assert path.stat().st_size > 1000
        with pytest.raises(InputError, match="PENUMBRA_MAX_BYTES"):
            (load_mesh if path.suffix == ".obj" else read_envmap)(path)


def test_scene_path_tilde_user(tmp_path):
    """A fuzz finding: '~name' of no such user raised RuntimeError from Path.expanduser."""
    from penumbra.scenefile import load_scene

    with pytest.raises(InputError, match="cannot expand"):
        load_scene(write(tmp_path / "s.toml", b'[environment]\nmap = "~{ky"\n'))


def test_sg_fit_option_not_wrapped(ctx):
    """face_size=2**32 + 16 in a ctypes int32 field was 16."""
    from penumbra.core import EnvMap

    env = EnvMap(ctx, np.ones((8, 16, 3), np.float32))
    with pytest.raises(InputError, match="face_size"):
        env.fit_sgs(1, face_size=2**32 + 16)


def test_native_structures_refuse_wrapping():
    """Every ctypes structure of the bindings checks its integer fields (FivOptions.theta = 2**32 + 4 was 4)."""
    from penumbra import _native

    with pytest.raises(InputError, match="FivOptions.theta"):
        _native.FivOptions(theta=2**32 + 4)
    options = _native.FivOptions(theta=8)
    with pytest.raises(InputError, match="FivOptions.phi"):
        options.phi = -1
    assert _native.FivOptions(theta=8.0).theta == 8
