"""The C example (examples/render_scene.c) against the Python API.

Builds libpenumbra from this checkout, installs it into a temporary prefix,
builds examples/ against the installed CMake package, renders a deterministic
env map with the example, then renders the same scene through penumbra.core
(loaded as usual: PENUMBRA_LIBRARY or the installed package) and requires the
two images to agree to 1e-6: same kernels, same inputs. The env map goes in
as a Radiance .hdr file (read by the example through stb_image; written here
with values that RGBE represents exactly, so both sides get the same floats)
and the image comes out as a PFM file (rows bottom-to-top), so this also pins
the example's row order. Needs cmake and stb (Debian's libstb-dev)."""

from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from penumbra import Camera, EnvMap, GBuffer, Image, Material, Mesh, Renderer, Scene

REPO = Path(__file__).resolve().parents[1]

pytestmark = [pytest.mark.skipif(shutil.which("cmake") is None, reason="cmake is not installed"),
              pytest.mark.skipif(subprocess.run(["pkg-config", "--exists", "stb"]).returncode != 0
                                 if shutil.which("pkg-config") else True,
                                 reason="stb is not installed (apt-get install libstb-dev)")]

# The scene of examples/render_scene.c, vertex for vertex.
BOX_VERTICES = np.array([
    [-0.5, 0.0, -0.5], [0.5, 0.0, -0.5], [0.5, 1.0, -0.5], [-0.5, 1.0, -0.5],
    [-0.5, 0.0, 0.5], [0.5, 0.0, 0.5], [0.5, 1.0, 0.5], [-0.5, 1.0, 0.5],
], np.float32)
BOX_FACES = np.array([
    [0, 3, 2], [0, 2, 1],  # -z
    [4, 5, 6], [4, 6, 7],  # +z
    [0, 4, 7], [0, 7, 3],  # -x
    [1, 2, 6], [1, 6, 5],  # +x
    [0, 1, 5], [0, 5, 4],  # -y
    [3, 7, 6], [3, 6, 2],  # +y
], np.uint32)
GROUND_VERTICES = np.array([[-3, 0, -3], [3, 0, -3], [3, 0, 3], [-3, 0, 3]], np.float32)
GROUND_FACES = np.array([[0, 3, 2], [0, 2, 1]], np.uint32)
CAMERA = dict(position=(2.5, 2.0, 3.5), look_at=(0.0, 0.4, 0.0), up=(0.0, 1.0, 0.0), fov_deg=45.0)
WIDTH, HEIGHT = 96, 72


def sky_envmap(width: int = 64, height: int = 32) -> np.ndarray:
    """(height, width, 3), top row first: a smooth sky-to-ground gradient with a bright disc."""
    v = (np.arange(height) + 0.5) / height
    u = (np.arange(width) + 0.5) / width
    uu, vv = np.meshgrid(u, v)
    up = np.clip(1.0 - 2.0 * vv, 0.0, 1.0)  # 1 at the zenith, 0 at and below the horizon
    down = np.clip(2.0 * vv - 1.0, 0.0, 1.0)
    rgb = np.stack([0.35 + 0.25 * up - 0.15 * down, 0.45 + 0.35 * up - 0.2 * down, 0.6 + 0.6 * up - 0.3 * down], -1)
    # A sun-like disc at azimuth u = 0.3, 40 degrees above the horizon: 30x brighter.
    d2 = ((uu - 0.3) * 2.0) ** 2 + (vv - (0.5 - 40 / 180)) ** 2
    rgb += (d2 < 0.06**2)[..., None] * np.array([30.0, 27.0, 22.0])
    return rgb.astype(np.float32)


def write_pfm(path: Path, rgb: np.ndarray) -> None:
    h, w, _ = rgb.shape
    with open(path, "wb") as f:
        f.write(b"PF\n%d %d\n-1.0\n" % (w, h))
        f.write(np.ascontiguousarray(rgb[::-1], dtype="<f4").tobytes())  # bottom row first


def write_hdr(path: Path, rgb: np.ndarray) -> np.ndarray:
    """Writes (H, W, 3) radiance as a Radiance .hdr file (flat RGBE scanlines,
    top row first) and returns the floats a reader decodes from it: byte x
    2^(E - 136) per channel (the RGBE definition; stb_image's decoding)."""
    h, w, _ = rgb.shape
    rgb = np.asarray(rgb, np.float64)
    peak = rgb.max(axis=-1)
    mant, exp = np.frexp(np.where(peak > 1e-32, peak, 1.0))  # peak = mant 2^exp, mant in [0.5, 1)
    scale = np.ldexp(256.0, -exp)[..., None]
    rgbe = np.zeros((h, w, 4), np.uint8)
    rgbe[..., :3] = np.clip(np.floor(rgb * scale), 0, 255)
    rgbe[..., 3] = np.where(peak > 1e-32, exp + 128, 0)
    rgbe[peak <= 1e-32] = 0
    # A first pixel (2, 2, <128, .) would read as a run-length scanline header.
    assert not (rgbe[0, 0, 0] == 2 and rgbe[0, 0, 1] == 2 and rgbe[0, 0, 2] < 128)
    with open(path, "wb") as f:
        f.write(b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y %d +X %d\n" % (h, w))
        f.write(rgbe.tobytes())
    e = rgbe[..., 3:].astype(np.int64)
    return np.where(e > 0, rgbe[..., :3] * np.ldexp(1.0, e - 136), 0.0).astype(np.float32)


def read_pfm(path: Path) -> np.ndarray:
    """(height, width, channels), top row first."""
    data = path.read_bytes()
    tokens, pos = [], 0
    while len(tokens) < 4:  # magic, width, height, scale; one whitespace byte ends each
        while data[pos:pos + 1].isspace():
            pos += 1
        end = pos
        while not data[end:end + 1].isspace():
            end += 1
        tokens.append(data[pos:end].decode())
        pos = end + 1
    magic, w, h, scale = tokens[0], int(tokens[1]), int(tokens[2]), float(tokens[3])
    channels = {"PF": 3, "Pf": 1}[magic]
    pixels = np.frombuffer(data, "<f4" if scale < 0 else ">f4", count=w * h * channels, offset=pos)
    return pixels.reshape(h, w, channels)[::-1].astype(np.float32)


def run(cmd: list, **kw) -> subprocess.CompletedProcess:
    result = subprocess.run([str(c) for c in cmd], capture_output=True, text=True, timeout=900, **kw)
    assert result.returncode == 0, f"{' '.join(map(str, cmd))} failed:\n{result.stdout}\n{result.stderr}"
    return result


@pytest.fixture(scope="module")
def render_scene_exe(tmp_path_factory) -> Path:
    """examples/render_scene built against a fresh build of this checkout, installed in a temporary prefix."""
    tmp = tmp_path_factory.mktemp("c_example")
    generator = ["-G", "Ninja"] if shutil.which("ninja") else []
    build, prefix, examples = tmp / "build", tmp / "prefix", tmp / "examples"
    run(["cmake", "-S", REPO, "-B", build, *generator, "-DCMAKE_BUILD_TYPE=Release", "-DPENUMBRA_TESTS=OFF",
         "-DPENUMBRA_WERROR=ON"])
    run(["cmake", "--build", build, "--parallel"])
    run(["cmake", "--install", build, "--prefix", prefix])
    run(["cmake", "-S", REPO / "examples", "-B", examples, *generator, f"-DCMAKE_PREFIX_PATH={prefix}",
         "-DPENUMBRA_EXAMPLES_WERROR=ON"])
    run(["cmake", "--build", examples])
    exe = examples / "render_scene"
    assert exe.is_file()
    return exe


def python_render(ctx, latlong: np.ndarray, width: int, height: int) -> np.ndarray:
    env = EnvMap(ctx, latlong)
    box = Mesh(ctx, BOX_VERTICES, BOX_FACES)
    ground = Mesh(ctx, GROUND_VERTICES, GROUND_FACES)
    scene = Scene(ctx)
    scene.set_envmap(env)
    assert scene.add(box, None, Material(albedo=(0.7, 0.5, 0.3))) == 0
    assert scene.add(ground, None, Material(albedo=(0.8, 0.8, 0.8))) == 1
    scene.set_camera(Camera(resolution=(width, height), **CAMERA))
    scene.commit()
    gbuffer = GBuffer(ctx, width, height)
    image = Image(ctx, width, height)
    scene.render_gbuffer(gbuffer)
    Renderer(ctx, "unshadowed").execute(scene, gbuffer, image)
    return image.read()


def test_pfm_helpers_round_trip(tmp_path):
    rgb = sky_envmap()
    write_pfm(tmp_path / "a.pfm", rgb)
    assert np.array_equal(read_pfm(tmp_path / "a.pfm"), rgb)


def test_hdr_writer_round_trips_through_read_envmap(tmp_path):
    """The test's .hdr files read back with penumbra.imageio as what write_hdr
    says they hold (another decoder than the example's)."""
    from penumbra.imageio import read_envmap

    decoded = write_hdr(tmp_path / "a.hdr", sky_envmap())
    got = read_envmap(tmp_path / "a.hdr")
    # Decoders differ by at most half an RGBE step (some add 0.5 to the byte).
    np.testing.assert_allclose(got, decoded, rtol=1 / 128, atol=1e-6)
    assert np.abs(decoded - sky_envmap()).max() <= sky_envmap().max() / 128


def test_c_example_matches_python(render_scene_exe, ctx, tmp_path):
    latlong = write_hdr(tmp_path / "env.hdr", sky_envmap())
    out = tmp_path / "out.pfm"
    result = run([render_scene_exe, tmp_path / "env.hdr", out, WIDTH, HEIGHT], env=os.environ.copy())
    assert "wrote" in result.stdout
    assert not list(tmp_path.glob("*.tmp")), "the example left its temporary file"
    c_image = read_pfm(out)
    assert c_image.shape == (HEIGHT, WIDTH, 3)

    py_image = python_render(ctx, latlong, WIDTH, HEIGHT)
    assert py_image.shape == (HEIGHT, WIDTH, 4)
    alpha = py_image[..., 3]
    # The scene is in view: box and ground in front of a visible sky.
    assert (alpha == 1).mean() > 0.3 and (alpha == 0).mean() > 0.05
    assert np.isfinite(c_image).all()

    diff = np.abs(c_image - py_image[..., :3])
    worst = np.unravel_index(np.argmax(diff), diff.shape)
    assert diff.max() <= 1e-6, (f"C and Python renders differ by {diff.max():g} at (y, x, c) = {worst}: "
                                f"C {c_image[worst[:2]]} vs Python {py_image[worst[:2]][:3]}")


def test_c_example_default_size_and_errors(render_scene_exe, tmp_path):
    write_hdr(tmp_path / "env.hdr", sky_envmap(16, 8))
    run([render_scene_exe, tmp_path / "env.hdr", tmp_path / "default.pfm"])
    assert read_pfm(tmp_path / "default.pfm").shape == (120, 160, 3)

    def refused(env_path, *words):
        failed = subprocess.run([str(render_scene_exe), str(env_path), str(tmp_path / "bad.pfm")],
                                capture_output=True, text=True, timeout=300)
        assert failed.returncode != 0
        assert all(w in failed.stderr for w in words), failed.stderr
        assert not (tmp_path / "bad.pfm").exists()

    # Not an HDR file (a PFM), a .hdr cut inside its header (stb_image's reason),
    # a missing file. (stb_image reads pixels missing at the end of a flat
    # file as black: docs/api.md says so.)
    write_pfm(tmp_path / "env.pfm", sky_envmap(16, 8))
    refused(tmp_path / "env.pfm", "not a Radiance .hdr file")
    data = (tmp_path / "env.hdr").read_bytes()
    (tmp_path / "short.hdr").write_bytes(data[:30])
    refused(tmp_path / "short.hdr", "cannot read", "short.hdr")
    refused(tmp_path / "missing.hdr", "cannot open", "No such file")
    # A map of zero radiance reaches penumbra (all black is valid) and renders black.
    write_hdr(tmp_path / "black.hdr", np.zeros((8, 16, 3), np.float32))
    run([render_scene_exe, tmp_path / "black.hdr", tmp_path / "black.pfm", 8, 6])
    assert (read_pfm(tmp_path / "black.pfm") == 0).all()

    usage = subprocess.run([str(render_scene_exe)], capture_output=True, text=True, timeout=60)
    assert usage.returncode != 0 and "usage" in usage.stderr


def test_c_example_reads_openexr(render_scene_exe, ctx, tmp_path):
    """With OpenEXR's development files (Debian's libopenexr-dev, in the
    Makefile's packages) the example reads .exr env maps through OpenEXR's C
    API: a ZIP-compressed RGBA file of several chunks (16 lines each) renders
    exactly as Python renders the same floats; a cut file is refused."""
    from penumbra.imageio import write_exr

    latlong = sky_envmap(64, 40)   # 40 rows: three chunks, the last one short
    rgba = np.concatenate([latlong, np.full(latlong.shape[:2] + (1,), 0.25, np.float32)], axis=2)
    write_exr(tmp_path / "env.exr", rgba)
    out = tmp_path / "out.pfm"
    result = subprocess.run([str(render_scene_exe), str(tmp_path / "env.exr"), str(out), str(WIDTH), str(HEIGHT)],
                            capture_output=True, text=True, timeout=600)
    if "this build has no OpenEXR" in result.stderr:
        pytest.skip("OpenEXR's development files were not found when the example was configured")
    assert result.returncode == 0, result.stderr
    c_image = read_pfm(out)
    py_image = python_render(ctx, latlong, WIDTH, HEIGHT)
    assert np.abs(c_image - py_image[..., :3]).max() <= 1e-6

    data = (tmp_path / "env.exr").read_bytes()
    (tmp_path / "cut.exr").write_bytes(data[: len(data) // 2])
    failed = subprocess.run([str(render_scene_exe), str(tmp_path / "cut.exr"), str(tmp_path / "bad.pfm")],
                            capture_output=True, text=True, timeout=300)
    assert failed.returncode != 0 and "cannot read" in failed.stderr and "cut.exr" in failed.stderr
    assert not (tmp_path / "bad.pfm").exists()
