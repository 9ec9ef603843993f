"""The ``penumbra`` command (penumbra.cli): ``info``, ``render`` and ``demo``,
run in-process through ``main([...])`` and once as a subprocess for the exit
codes. Scenes use the real shared data (the Stanford bunny, the Pisa probe)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

import penumbra
from penumbra._native import library_path
from penumbra.cli import main
from penumbra.imageio import read_exr
from penumbra.scenefile import load_scene

REPO = Path(__file__).resolve().parents[1]
EXAMPLE_SCENE = REPO / "examples" / "scenes" / "bunny_pisa.toml"
BUNNY = "meshes/bunny_odedstein_3k.obj"
PISA = "envmaps/pisa_probulator_256x128.hdr"

# For the subprocess test, which runs in another directory: the package and the
# library this session uses, as absolute paths (computed at import, before any chdir).
PACKAGE_PARENT = str(Path(penumbra.__file__).resolve().parents[1])
LIBRARY = os.path.abspath(library_path) if os.sep in library_path else library_path

# The bunny mesh is centred at the origin and about 1.55 units across, so from
# (0, 0.2, 3) with a 40 degree field of view it fills the middle of the frame.
SCENE = """
[environment]
map = "{envmap}"
face_size = 32
irradiance_face_size = 16

[camera]
position = [0.0, 0.2, 3.0]
look_at = [0.0, 0.0, 0.0]
fov_deg = 40
resolution = [64, 48]

[render]
method = "unshadowed"
background = 0

[[object]]
name = "bunny"
mesh = "{mesh}"
albedo = [0.8, 0.8, 0.8]
"""


def write_scene(scene_dir: Path, envmap: Path | str, mesh: Path | str, name: str = "scene.toml") -> Path:
    """A scene file in scene_dir that refers to its files by paths relative to scene_dir."""
    scene_dir.mkdir(parents=True, exist_ok=True)
    rel = lambda p: os.path.relpath(p, scene_dir) if Path(p).is_absolute() else str(p)  # noqa: E731
    path = scene_dir / name
    path.write_text(SCENE.format(envmap=Path(rel(envmap)).as_posix(), mesh=Path(rel(mesh)).as_posix()))
    return path


@pytest.fixture()
def bunny_scene(tmp_path, shared_data, monkeypatch) -> Path:
    path = write_scene(tmp_path / "scenes", shared_data / PISA, shared_data / BUNNY)
    assert "../" in path.read_text()  # really relative
    run_dir = tmp_path / "run"  # run from elsewhere: paths resolve against the scene file, not the cwd
    run_dir.mkdir()
    monkeypatch.chdir(run_dir)
    return path


def run_cli(capsys, *argv) -> tuple[int, str, str]:
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def png_size(path: Path) -> tuple[int, int]:
    with Image.open(path) as im:
        im.load()  # decodes the whole file: a truncated PNG fails here
        assert im.format == "PNG"
        assert im.mode == "RGB"
        return im.size


# ---------------------------------------------------------------- info


def test_info_prints_the_device(capsys, ctx):
    code, out, err = run_cli(capsys, "info")
    assert code == 0, err
    assert out.startswith("penumbra ")
    assert f"default device: {ctx.device_name}" in out
    assert "platform '" in out and "compute units" in out
    assert "OpenCL C OpenCL C" not in out  # the version string already starts with "OpenCL C"


# ---------------------------------------------------------------- render


def test_render_writes_exr_png_and_json(capsys, bunny_scene, tmp_path, ctx):
    out_exr, out_png, report = tmp_path / "out.exr", tmp_path / "out.png", tmp_path / "report.json"
    code, out, err = run_cli(capsys, "render", bunny_scene, "-o", out_exr, "--png", out_png, "--json", report,
                             "--frames", "1")
    assert code == 0, err
    assert "unshadowed on" in out and "wrote" in out and str(out_exr) in out

    img = read_exr(out_exr)
    assert img.shape == (48, 64, 3) and img.dtype == np.float32
    assert np.isfinite(img).all()
    assert (img >= 0).all()
    # background = 0 in the scene: the bunny is exactly the lit pixels.
    lit = img.max(axis=2) > 0
    assert 0.15 < lit.mean() < 0.8, lit.mean()
    assert lit[20:28, 28:36].all()  # the middle of the frame is bunny
    assert not lit[0, 0] and not lit[-1, -1]  # the corners are background
    assert img[lit].mean() > 0.05  # lit by the Pisa probe, not just barely non-zero
    assert img[lit].std() > 0  # shaded, not flat

    assert png_size(out_png) == (64, 48)

    rep = json.loads(report.read_text())
    assert rep["method"] == "unshadowed"
    assert rep["device"] == ctx.device_name
    assert rep["resolution"] == [64, 48]
    assert rep["params"] == {"background": 0}
    t = rep["timings_ms"]
    for key in ("frame_median", "frame_min"):
        assert isinstance(t[key], float) and t[key] > 0
    assert t["frame_min"] <= t["frame_median"]


def test_render_set_overrides(capsys, bunny_scene, tmp_path):
    out_exr, report = tmp_path / "small.exr", tmp_path / "small.json"
    code, _, err = run_cli(capsys, "render", bunny_scene, "--set", "camera.resolution=[32,24]",
                           "--set", "render.background=1", "-o", out_exr, "--json", report, "--frames", "1")
    assert code == 0, err
    img = read_exr(out_exr)
    assert img.shape == (24, 32, 3)
    assert json.loads(report.read_text())["resolution"] == [32, 24]
    # background = 1: the env map shows behind the bunny, so no pixel is black.
    assert (img.max(axis=2) > 0).all()


def test_render_object_override_changes_the_colour(capsys, bunny_scene, tmp_path):
    out_exr = tmp_path / "red.exr"
    code, _, err = run_cli(capsys, "render", bunny_scene, "--set", "object.bunny.albedo=[1,0,0]", "-o", out_exr,
                           "--frames", "1")
    assert code == 0, err
    img = read_exr(out_exr)
    lit = img.max(axis=2) > 0
    assert lit.mean() > 0.15
    assert (img[lit, 0] > 0).all() and (img[lit, 1:] == 0).all()


def test_render_png_only_and_default_output(capsys, bunny_scene, tmp_path):
    code, _, err = run_cli(capsys, "render", bunny_scene, "--png", tmp_path / "only.png", "--frames", "1")
    assert code == 0, err
    assert png_size(tmp_path / "only.png") == (64, 48)
    assert not Path("out.exr").exists()  # --png alone writes no EXR
    code, _, err = run_cli(capsys, "render", bunny_scene, "--frames", "1")
    assert code == 0, err
    assert read_exr(Path("out.exr")).shape == (48, 64, 3)  # default output in the working directory


def test_render_scene_method_can_be_overridden_only_by_known_methods(capsys, bunny_scene, tmp_path):
    code, out, err = run_cli(capsys, "render", bunny_scene, "--method", "raytraced", "-o", tmp_path / "x.exr",
                             "--frames", "1")
    assert code == 2
    assert "raytraced" in err and "unshadowed" in err
    assert not (tmp_path / "x.exr").exists()
    code, out, err = run_cli(capsys, "render", bunny_scene, "--set", "render.method=depthmap", "--frames", "1")
    assert code == 2 and "depthmap" in err and "unshadowed" in err


def write_exr_raw(path: Path, rgb: np.ndarray) -> None:
    """Writes an EXR without penumbra's writer (which refuses NaN)."""
    import OpenEXR

    channels = {c: np.ascontiguousarray(rgb[..., k], dtype=np.float32) for k, c in enumerate("RGB")}
    OpenEXR.File({"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}, channels).write(str(path))


@pytest.mark.parametrize("ext", ["npy", "exr"])
def test_render_envmap_with_nan_exits_2(capsys, shared_data, tmp_path, monkeypatch, ext):
    env = np.full((8, 16, 3), 0.5, np.float32)
    env[3, 5, 1] = np.nan  # row 3, column 5
    path = tmp_path / f"nan.{ext}"
    if ext == "npy":
        np.save(path, env)
    else:
        write_exr_raw(path, env)
    scene = write_scene(tmp_path, path, shared_data / BUNNY)
    monkeypatch.chdir(tmp_path)
    code, out, err = run_cli(capsys, "render", scene, "-o", tmp_path / "nan_out.exr", "--frames", "1")
    assert code == 2
    assert "penumbra: error:" in err
    assert "NaN" in err
    assert "x=5" in err and "y=3" in err
    assert not (tmp_path / "nan_out.exr").exists()


def test_render_missing_mesh_exits_2(capsys, shared_data, tmp_path):
    scene = write_scene(tmp_path, shared_data / PISA, "meshes/no_such_bunny.obj")
    code, out, err = run_cli(capsys, "render", scene, "-o", tmp_path / "o.exr", "--frames", "1")
    assert code == 2
    assert "no_such_bunny.obj" in err
    assert str(tmp_path / "meshes" / "no_such_bunny.obj") in err  # resolved against the scene's directory
    assert not (tmp_path / "o.exr").exists()


@pytest.mark.parametrize("argv, words", [
    (["render", "{dir}/missing.toml"], ["missing.toml"]),
    (["render", "{scene}", "--set", "camera.fov_deg=0"], ["[camera] fov_deg"]),
    (["render", "{scene}", "--set", "nonsense"], ["--set", "nonsense"]),
    (["render", "{scene}", "--set", "object.teapot.albedo=1"], ["teapot"]),
    (["render", "{scene}", "--frames", "0"], ["frames"]),
])
def test_render_input_errors_exit_2(capsys, bunny_scene, tmp_path, argv, words):
    argv = [a.format(dir=tmp_path, scene=bunny_scene) for a in argv]
    code, out, err = run_cli(capsys, *argv)
    assert code == 2
    assert err.startswith("penumbra: error:")
    for w in words:
        assert w in err, err


# ---------------------------------------------------------------- demo


def test_demo_writes_every_image_and_a_table(capsys, tmp_path):
    out_dir = tmp_path / "demo"
    code, out, err = run_cli(capsys, "demo", "--out", out_dir, "--frames", "1", "--set", "camera.resolution=[64,48]")
    assert code == 0, err
    names = ["unshadowed"] + [f"gbuffer_{v}" for v in ("normals", "albedo", "depth")]
    for name in names:
        img = read_exr(out_dir / f"{name}.exr")
        assert img.shape == (48, 64, 3), name
        assert np.isfinite(img).all(), name
        assert img.max() > 0, name
        assert png_size(out_dir / f"{name}.png") == (64, 48), name
    rows = [line for line in out.splitlines() if line.startswith("unshadowed")]
    assert len(rows) == 1
    numbers = [float(x) for x in rows[0].split()[1:]]
    assert len(numbers) == 4 and all(x > 0 for x in numbers)
    assert "64x48" in out
    # The normals view maps n to 0.5 + 0.5 n: the ground plane (n = +y) is (0.5, 1, 0.5).
    normals = read_exr(out_dir / "gbuffer_normals.exr")
    np.testing.assert_allclose(normals[-1, 32], [0.5, 1.0, 0.5], atol=1e-5)


# ---------------------------------------------------------------- the example scene


def test_example_scene_refers_to_the_shared_data(shared_data):
    s = load_scene(EXAMPLE_SCENE)
    assert Path(s.environment.map) == (shared_data / PISA).resolve()
    bunny = next(o for o in s.objects if o.name == "bunny")
    assert Path(bunny.mesh) == (shared_data / BUNNY).resolve()
    assert Path(s.environment.map).is_file() and Path(bunny.mesh).is_file()


def test_example_scene_renders(capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    code, out, err = run_cli(capsys, "render", EXAMPLE_SCENE, "--set", "camera.resolution=[48,36]",
                             "-o", "bunny.exr", "--png", "bunny.png", "--frames", "1")
    assert code == 0, err
    img = read_exr(tmp_path / "bunny.exr")
    assert img.shape == (36, 48, 3)
    assert np.isfinite(img).all() and img.min() >= 0
    assert img[18, 24].max() > 0.05  # the bunny in the middle is lit
    assert png_size(tmp_path / "bunny.png") == (48, 36)


# ---------------------------------------------------------------- exit codes of the real command


def test_exit_codes_as_a_subprocess(bunny_scene, tmp_path):
    env = os.environ.copy()
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [PACKAGE_PARENT, env.get("PYTHONPATH")]))
    if "PENUMBRA_LIBRARY" in env:
        env["PENUMBRA_LIBRARY"] = LIBRARY

    def cli(*argv):
        return subprocess.run([sys.executable, "-m", "penumbra.cli", *map(str, argv)], capture_output=True, text=True,
                              env=env, timeout=120)

    ok = cli("render", bunny_scene, "-o", tmp_path / "sub.exr", "--frames", "1")
    assert ok.returncode == 0, ok.stderr
    assert read_exr(tmp_path / "sub.exr").shape == (48, 64, 3)

    bad = cli("render", bunny_scene, "--method", "nope", "--frames", "1")
    assert bad.returncode == 2
    assert "penumbra: error: unknown method 'nope'" in bad.stderr and "unshadowed" in bad.stderr
    assert "Traceback" not in bad.stderr

    usage = cli("render")  # argparse: the scene argument is missing
    assert usage.returncode == 2 and "usage:" in usage.stderr
