"""Writes the fuzzers' seed corpus: a few tiny valid files per format (tests/fuzz/corpus/<target>/).

Everything is generated here (nothing copied from the test data), deterministically:
``python tests/fuzz/make_corpus.py`` rewrites the same bytes.
"""

from __future__ import annotations

import io
import shutil
import struct
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
CORPUS = HERE / "corpus"


def obj_files() -> dict[str, bytes]:
    quad = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\n"
    return {
        "triangle.obj": b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n",
        "quad_normals.obj": (quad + "vn 0 0 1\nvt 0 0\nf 1/1/1 2/1/1 3/1/1 4/1/1\n").encode(),
        "relative.obj": (quad + "o thing\ng part\ns 1\nf -4 -3 -2\nf 1//1 3//1 4//1\nvn 0 0 1\n").encode(),
        "mixed.obj": (quad + "v 0.5 2 0\nf 1 2 3 4\nf 4 3 5\n# comment\nusemtl m\n").encode(),
    }


def ply_files() -> dict[str, bytes]:
    head = "ply\nformat {fmt} 1.0\ncomment seed\nelement vertex 4\nproperty float x\nproperty float y\n" \
           "property float z\n{extra}element face 2\nproperty list uchar int vertex_indices\nend_header\n"
    xyz = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], np.float32)
    ascii_body = "".join(f"{x:g} {y:g} {z:g}\n" for x, y, z in xyz) + "3 0 1 2\n4 0 2 3 1\n"
    files = {"ascii.ply": (head.format(fmt="ascii", extra="") + ascii_body).encode()}
    for endian, fmt in (("<", "binary_little_endian"), (">", "binary_big_endian")):
        normals = "property float nx\nproperty float ny\nproperty float nz\n"
        rows = np.concatenate([xyz, np.tile([[0, 0, 1]], (4, 1))], axis=1).astype(endian + "f4")
        faces = struct.pack(endian + "B3i", 3, 0, 1, 2) + struct.pack(endian + "B3i", 3, 0, 2, 3)
        files[f"{fmt}.ply"] = head.format(fmt=fmt, extra=normals).encode() + rows.tobytes() + faces
    return files


def off_files() -> dict[str, bytes]:
    return {
        "triangle.off": b"OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n",
        "quad_colour.off": b"COFF\n# comment\n4 1 0\n0 0 0 1 1 1 1\n1 0 0 1 1 1 1\n1 1 0 1 1 1 1\n"
                           b"0 1 0 1 1 1 1\n4 0 1 2 3 255 0 0\n",
        "normals.off": b"NOFF 3 1 0\n0 0 0 0 0 1\n1 0 0 0 0 1\n0 1 0 0 0 1\n3 0 1 2\n",
    }


def stl_files() -> dict[str, bytes]:
    tris = np.array([[[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[1, 0, 0], [1, 1, 0], [0, 1, 0]]], np.float32)
    binary = b"seed binary stl".ljust(80, b"\0") + struct.pack("<I", len(tris))
    for t in tris:
        binary += struct.pack("<3f", 0, 0, 1) + t.astype("<f4").tobytes() + b"\0\0"
    text = "solid seed\n"
    for t in tris:
        text += "facet normal 0 0 1\nouter loop\n" + "".join(f"vertex {x:g} {y:g} {z:g}\n" for x, y, z in t)
        text += "endloop\nendfacet\n"
    return {"binary.stl": binary, "ascii.stl": (text + "endsolid seed\n").encode()}


def hdr_files() -> dict[str, bytes]:
    def header(width: int, height: int, extra: str = "", orientation: str = "-Y") -> bytes:
        return f"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n{extra}\n{orientation} {height} +X {width}\n".encode()

    flat = header(4, 2, "EXPOSURE=2\n") + bytes(range(100, 132))
    # New-style RLE, width 8: 2 2 0 8, then per channel one run (count > 128) or literals.
    line = bytes((2, 2, 0, 8)) + bytes((136, 128)) + bytes((8, *range(8))) + bytes((136, 100)) + bytes((136, 129))
    new_rle = header(8, 2, "COLORCORR=1 1 1\n") + line * 2
    old_rle = header(20, 2, orientation="+Y") + (bytes((128, 64, 32, 129)) + bytes((1, 1, 1, 19))) * 2
    return {"flat.hdr": flat, "new_rle.hdr": new_rle, "old_rle.hdr": old_rle}


def npy_files() -> dict[str, bytes]:
    out = {}
    arrays = {"f4.npy": np.linspace(0, 1, 4 * 2 * 3, dtype=np.float32).reshape(2, 4, 3),
              "f8_fortran.npy": np.asfortranarray(np.arange(3 * 2 * 3, dtype=np.float64).reshape(3, 2, 3)),
              "f2.npy": np.ones((2, 2, 3), np.float16),
              "height_2d.npy": np.linspace(0, 1, 9, dtype=np.float32).reshape(3, 3)}
    for name, a in arrays.items():
        buffer = io.BytesIO()
        np.save(buffer, a, allow_pickle=False)
        out[name] = buffer.getvalue()
    return out


def exr_files(folder: Path) -> dict[str, bytes]:
    import OpenEXR

    out = {}
    rgb = np.linspace(0, 1, 4 * 4 * 3, dtype=np.float32).reshape(4, 4, 3)
    for name, channels, compression in (
            ("rgb_zip.exr", {c: rgb[..., k].copy() for k, c in enumerate("RGB")}, OpenEXR.ZIP_COMPRESSION),
            ("rgb_half_none.exr", {c: rgb[..., k].astype(np.float16) for k, c in enumerate("RGB")},
             OpenEXR.NO_COMPRESSION),
            ("y_rle.exr", {"Y": rgb[..., 0].copy()}, OpenEXR.RLE_COMPRESSION)):
        path = folder / name
        OpenEXR.File({"compression": compression, "type": OpenEXR.scanlineimage}, channels).write(str(path))
        out[name] = path.read_bytes()
        path.unlink()
    return out


def png_files() -> dict[str, bytes]:
    from PIL import Image

    out = {}
    images = {"grey8.png": Image.fromarray(np.arange(16, dtype=np.uint8).reshape(4, 4) * 16, "L"),
              "grey16.png": Image.fromarray(np.arange(16, dtype=np.uint16).reshape(4, 4) * 4000),
              "rgb.png": Image.fromarray(np.arange(48, dtype=np.uint8).reshape(4, 4, 3) * 5, "RGB")}
    for name, image in images.items():
        buffer = io.BytesIO()
        image.save(buffer, format="PNG")
        out[name] = buffer.getvalue()
    return out


def scene_files() -> dict[str, bytes]:
    return {
        "procedural.toml": b"""[environment]
map = "sky"
intensity = 1.5
face_size = 32

[camera]
position = [0.0, 2.0, 6.0]
look_at = [0.0, 0.5, 0.0]
fov_deg = 40.0
resolution = [64, 48]

[[object]]
name = "ball"
primitive = "sphere"
translate = [0.0, 1.0, 0.0]
albedo = [0.8, 0.8, 0.8]

[[object]]
name = "floor"
primitive = "plane"
scale = [4.0, 1.0, 4.0]

[render]
method = "unshadowed"
""",
        "minimal.toml": b"[camera]\nresolution = [8, 8]\n",
    }


def main() -> int:
    tmp = CORPUS / ".tmp"
    tmp.mkdir(parents=True, exist_ok=True)
    sets = {"obj": obj_files(), "ply": ply_files(), "off": off_files(), "stl": stl_files(), "hdr": hdr_files(),
            "npy": npy_files(), "exr": exr_files(tmp), "png": png_files(), "scene": scene_files()}
    shutil.rmtree(tmp)
    for target, files in sets.items():
        folder = CORPUS / target
        shutil.rmtree(folder, ignore_errors=True)
        folder.mkdir(parents=True)
        for name, data in files.items():
            (folder / name).write_bytes(data)
    print(f"wrote {sum(map(len, sets.values()))} seed files under {CORPUS}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
