"""The ``penumbra`` command (penumbra.cli): ``info``, ``render``, ``demo``,
``bake-fiv`` and ``fiv-info`` (and ``render --method fiv`` with its bake
cache), run in-process through ``main([...])`` and once as a subprocess for the exit
codes. Scenes use the real shared data (the Stanford bunny, the Pisa probe)."""

from __future__ import annotations

import json
import os
import stat
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

import penumbra
from penumbra._native import library_path
from penumbra.cli import main
from penumbra.errors import InputError
from penumbra.imageio import read_exr
from penumbra.methods.fiv import read_header
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
    code, out, err = run_cli(capsys, "render", bunny_scene, "--set", "render.method=photonmap", "--frames", "1")
    assert code == 2 and "photonmap" in err and "unshadowed" in err


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


def test_demo_writes_every_image_and_a_table(capsys, tmp_path, monkeypatch):
    monkeypatch.setenv("PENUMBRA_CACHE", str(tmp_path / "cache"))
    out_dir = tmp_path / "demo"
    # A tiny fiv grid: the demo bakes the four shapes of the built-in scene.
    code, out, err = run_cli(capsys, "demo", "--out", out_dir, "--frames", "1", "--set", "camera.resolution=[64,48]",
                             "--set", "fiv.samples=[8,5,4]", "--set", "fiv.face_size=8")
    assert code == 0, err
    assert "fiv: 4 occlusion field(s)" in out and "8x5x4" in out
    assert len(list((tmp_path / "cache" / "fiv").glob("*.pnfiv"))) == 4
    rows = [line for line in out.splitlines() if line.startswith("fiv ")]
    assert len(rows) == 1 and all(float(x) > 0 for x in rows[0].split()[1:])
    assert "isg sphere sets: " in out and "64 spheres" in out  # one set per occluder shape
    names = ["unshadowed", "fiv", "heightfield", "isg"] + [f"gbuffer_{v}" for v in ("normals", "albedo", "depth")]
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


# ---------------------------------------------------------------- fiv: bake-fiv, fiv-info, render --method fiv

TINY_FIV = ["--samples", "8,5,4", "--face-size", "8"]


def test_bake_fiv_writes_a_loadable_file(capsys, shared_data, tmp_path, ctx):
    out_file = tmp_path / "bunny.pnfiv"
    code, out, err = run_cli(capsys, "bake-fiv", shared_data / BUNNY, "--env", shared_data / PISA, *TINY_FIV,
                             "--precision", "float32", "-o", out_file)
    assert code == 0, err
    assert "8x5x4" in out and "rays" in out and str(out_file) in out
    field = penumbra.FivField.load(ctx, out_file)
    info = field.info()
    assert info["samples"] == (5, 8, 4) and info["precision"] == "float32" and info["face_size"] == 8
    assert f"memory: {info['stored_bytes']} bytes" in out
    assert info["stored_bytes"] == 8 * 5 * 4 * 9 * 4
    # Again to the same file: the finished bake is found and kept.
    mtime = out_file.stat().st_mtime_ns
    code, out, err = run_cli(capsys, "bake-fiv", shared_data / BUNNY, "--env", shared_data / PISA, *TINY_FIV,
                             "--precision", "float32", "-o", out_file)
    assert code == 0, err
    assert "already holds this finished bake" in out and out_file.stat().st_mtime_ns == mtime


@pytest.fixture(scope="module")
def tiny_fiv_file(tmp_path_factory, shared_data) -> Path:
    """The bunny's 8x5x4 field under the Pisa probe, baked once by bake-fiv."""
    out_file = tmp_path_factory.mktemp("fiv") / "bunny.pnfiv"
    assert main([str(a) for a in ("bake-fiv", shared_data / BUNNY, "--env", shared_data / PISA, *TINY_FIV,
                                  "-o", out_file)]) == 0
    return out_file


def test_fiv_info_prints_the_grid(capsys, tiny_fiv_file):
    out_file = tiny_fiv_file
    capsys.readouterr()
    code, out, err = run_cli(capsys, "fiv-info", out_file)
    assert code == 0, err
    assert "grid:        8x5x4 (phi x theta x radii) = 160 samples" in out
    assert "float16" in out and "face_size 8" in out and "mesh hash" in out and "env hash" in out
    code, out, err = run_cli(capsys, "fiv-info", out_file, "--json")
    assert code == 0, err
    data = json.loads(out)
    assert data["samples_phi_theta_radii"] == [8, 5, 4] and data["sample_count"] == 160
    assert data["file_bytes"] == out_file.stat().st_size


def test_bake_fiv_resumes_an_interrupted_bake(capsys, shared_data, tmp_path, ctx, monkeypatch):
    import penumbra.cli as cli

    class StopAfterOneSphere(cli._BakeBars):
        def __call__(self, label, done, total):
            super().__call__(label, done, total)
            return True  # as Ctrl-C does: stop after this sphere (with a checkpoint)

    out_file = tmp_path / "r.pnfiv"
    argv = ["bake-fiv", shared_data / BUNNY, "--env", shared_data / PISA, *TINY_FIV, "-o", out_file]
    monkeypatch.setattr(cli, "_BakeBars", StopAfterOneSphere)
    code, out, err = run_cli(capsys, *argv)
    assert code == 130 and "interrupted" in err and "1 of 4 spheres" in err
    assert read_header(out_file)["radii_done"] == 1  # pn_fiv_read_header: unfinished bakes too
    code, out, err = run_cli(capsys, "fiv-info", out_file)
    assert code == 2 and "unfinished" in err and "1 of 4" in err
    monkeypatch.undo()
    code, out, err = run_cli(capsys, *argv)
    assert code == 0, err
    assert "resuming" in out and "1 of 4 spheres" in out and "finished" in out
    # The resumed bake equals one baked in one go.
    whole = tmp_path / "whole.pnfiv"
    assert run_cli(capsys, "bake-fiv", shared_data / BUNNY, "--env", shared_data / PISA, *TINY_FIV, "-o", whole)[0] == 0
    a = penumbra.FivField.load(ctx, out_file).samples()
    b = penumbra.FivField.load(ctx, whole).samples()
    np.testing.assert_array_equal(np.isnan(a), np.isnan(b))
    np.testing.assert_array_equal(np.nan_to_num(a), np.nan_to_num(b))


@pytest.mark.parametrize("extra, words", [
    (["--samples", "8,5,1"], ["--samples[2] (radii)"]),
    (["--samples", "8,5,4", "--inner-radius", "1.5"], ["--inner-radius"]),
    (["--samples", "8,5,4", "--env-intensity", "-1"], ["--env-intensity"]),
])
def test_bake_fiv_bad_options_exit_2(capsys, shared_data, tmp_path, extra, words):
    code, out, err = run_cli(capsys, "bake-fiv", shared_data / BUNNY, "--env", shared_data / PISA, *extra,
                             "-o", tmp_path / "x.pnfiv")
    assert code == 2 and err.startswith("penumbra: error:")
    for w in words:
        assert w in err, err
    assert not (tmp_path / "x.pnfiv").exists()


def test_bake_fiv_refuses_a_file_of_another_bake(capsys, shared_data, tmp_path, tiny_fiv_file):
    out_file = tmp_path / "b.pnfiv"
    out_file.write_bytes(tiny_fiv_file.read_bytes())  # a bake under the Pisa probe
    before = out_file.read_bytes()
    code, out, err = run_cli(capsys, "bake-fiv", shared_data / BUNNY, "--env", "sky", *TINY_FIV, "-o", out_file)
    assert code == 2 and "another env map" in err
    assert out_file.read_bytes() == before
    with pytest.raises(SystemExit):
        main(["bake-fiv", str(shared_data / BUNNY), "--env", "sky", "--samples", "8,5", "-o", "x"])
    assert "PHI,THETA,RADII" in capsys.readouterr().err


FIV_SCENE = """
[environment]
map = "{envmap}"
face_size = 16
irradiance_face_size = 8

[camera]
position = [0.0, 1.6, 3.2]
look_at = [0.0, 0.0, 0.0]
fov_deg = 50
resolution = [32, 24]

[render]
method = "fiv"
background = 0

[fiv]
samples = [8, 5, 4]
face_size = 8
{cache}

[[object]]
name = "bunny"
mesh = "{mesh}"
translate = [0.0, 0.769, 0.0]

[[object]]
name = "ground"
primitive = "plane"
params = {{ size = [6.0, 6.0] }}
"""


def fiv_scene(tmp_path: Path, shared_data: Path, cache: str = "") -> Path:
    path = tmp_path / "fiv.toml"
    path.write_text(FIV_SCENE.format(envmap=(shared_data / PISA).as_posix(), mesh=(shared_data / BUNNY).as_posix(),
                                     cache=cache))
    return path


def test_render_fiv_bakes_on_demand_then_reuses_the_cache(capsys, shared_data, tmp_path, monkeypatch):
    monkeypatch.setenv("PENUMBRA_CACHE", str(tmp_path / "cache"))
    scene = fiv_scene(tmp_path, shared_data)
    code, out, err = run_cli(capsys, "render", scene, "-o", tmp_path / "a.exr", "--json", tmp_path / "a.json",
                             "--frames", "1")
    assert code == 0, err
    assert "fiv: 1 occlusion field(s): bunny: 8x5x4" in out and "baked in" in out
    files = list((tmp_path / "cache" / "fiv").glob("*.pnfiv"))
    assert len(files) == 1  # the ground plane is no occluder
    mtime = files[0].stat().st_mtime_ns
    code, out, err = run_cli(capsys, "render", scene, "-o", tmp_path / "b.exr", "--frames", "1")
    assert code == 0, err
    assert "from the cache" in out and "baked in" not in out
    assert files[0].stat().st_mtime_ns == mtime and len(list((tmp_path / "cache" / "fiv").glob("*"))) == 1
    a, b = read_exr(tmp_path / "a.exr"), read_exr(tmp_path / "b.exr")
    np.testing.assert_array_equal(a, b)
    assert json.loads((tmp_path / "a.json").read_text())["method"] == "fiv"
    # The bunny's shadow darkens the ground against unshadowed.
    code, _, err = run_cli(capsys, "render", scene, "--method", "unshadowed", "-o", tmp_path / "u.exr",
                           "--frames", "1")
    assert code == 0, err
    u = read_exr(tmp_path / "u.exr")
    assert np.isfinite(a).all() and a.min() >= 0 and a.max() > 0
    assert a.sum() < 0.97 * u.sum()


def test_render_fiv_uses_the_scenes_cache_folder(capsys, shared_data, tmp_path, monkeypatch):
    monkeypatch.setenv("PENUMBRA_CACHE", str(tmp_path / "unused"))
    scene = fiv_scene(tmp_path, shared_data, cache='cache = "bakes"')
    code, out, err = run_cli(capsys, "render", scene, "-o", tmp_path / "a.exr", "--frames", "1",
                             "--set", "fiv.precision=float32")
    assert code == 0, err
    assert len(list((tmp_path / "bakes").glob("*float32.pnfiv"))) == 1  # beside the scene file
    assert not (tmp_path / "unused").exists()


def test_render_fiv_rotated_occluder_gets_its_own_field(capsys, shared_data, tmp_path, monkeypatch):
    monkeypatch.setenv("PENUMBRA_CACHE", str(tmp_path / "cache"))
    scene = fiv_scene(tmp_path, shared_data)
    code, out, err = run_cli(capsys, "render", scene, "-o", tmp_path / "r.exr", "--frames", "1",
                             "--set", "object.bunny.rotate_deg=[0,40,0]")
    assert code == 0, err
    assert "fiv: 1 occlusion field(s)" in out
    code, out, err = run_cli(capsys, "render", scene, "-o", tmp_path / "s.exr", "--frames", "1")
    assert code == 0, err
    assert len(list((tmp_path / "cache" / "fiv").glob("*.pnfiv"))) == 2  # one per orientation


def test_render_fiv_bad_fiv_table_exits_2(capsys, shared_data, tmp_path):
    scene = fiv_scene(tmp_path, shared_data)
    code, out, err = run_cli(capsys, "render", scene, "--set", "fiv.samples=[8,5]", "--frames", "1")
    assert code == 2 and "[fiv] samples" in err


# ---------------------------------------------------------------- the example scene


def test_example_scene_refers_to_the_shared_data(shared_data):
    s = load_scene(EXAMPLE_SCENE)
    assert Path(s.environment.map) == (shared_data / PISA).resolve()
    bunny = next(o for o in s.objects if o.name == "bunny")
    assert Path(bunny.mesh) == (shared_data / BUNNY).resolve()
    assert Path(s.environment.map).is_file() and Path(bunny.mesh).is_file()


def test_example_scene_renders(capsys, tmp_path, monkeypatch, shared_data):
    monkeypatch.chdir(tmp_path)
    code, out, err = run_cli(capsys, "render", EXAMPLE_SCENE, "--set", "camera.resolution=[48,36]",
                             "-o", "bunny.exr", "--png", "bunny.png", "--frames", "1")
    assert code == 0, err
    img = read_exr(tmp_path / "bunny.exr")
    assert img.shape == (36, 48, 3)
    assert np.isfinite(img).all() and img.min() >= 0
    assert img[18, 24].max() > 0.05  # the bunny in the middle is lit
    assert png_size(tmp_path / "bunny.png") == (48, 36)


CONES_SCENE = Path(__file__).resolve().parents[1] / "examples" / "scenes" / "cones_dawn_lights.toml"


def test_heightfield_example_renders_with_its_lights(capsys, tmp_path, monkeypatch, shared_data):
    """The cones example with --method heightfield: terrain pixels lit by the
    dawn sky and both lights (the centre light makes the middle bright), the
    same scene without lights darker there."""
    monkeypatch.chdir(tmp_path)
    small = ["--set", "camera.resolution=[48,36]", "--set", "heightfield.cones.size_px=[65,65]", "--frames", "1"]
    code, out, err = run_cli(capsys, "render", CONES_SCENE, "--method", "heightfield", "-o", "lit.exr", *small)
    assert code == 0, err
    assert "heightfield on" in out
    lit = read_exr(tmp_path / "lit.exr")
    assert lit.shape == (36, 48, 3) and np.isfinite(lit).all() and lit.min() >= 0
    code, out, err = run_cli(capsys, "render", CONES_SCENE, "--method", "heightfield", "-o", "dark.exr", *small,
                             "--set", "light.0.radiance=[0,0,0]", "--set", "light.1.radiance=[0,0,0]")
    assert code == 0, err
    dark = read_exr(tmp_path / "dark.exr")
    assert lit[18, 24].mean() > 1.5 * dark[18, 24].mean()


def test_heightfield_bad_terrain_parameter_exits_2(capsys, tmp_path, shared_data):
    code, out, err = run_cli(capsys, "render", CONES_SCENE, "--method", "heightfield", "-o", tmp_path / "x.exr",
                             "--set", "heightfield.cones.params={height=1}")
    assert code == 2
    assert "cones_circle" in err and "height" in err


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

    # python -m penumbra is the same command.
    version = subprocess.run([sys.executable, "-m", "penumbra", "--version"], capture_output=True, text=True,
                             env=env, timeout=120)
    assert version.returncode == 0 and version.stdout.startswith("penumbra ")


# ---------------------------------------------------------------- a newcomer's time (procedural: no data needed)

PROCEDURAL_SCENE = """
[environment]
map = "sky"
face_size = 16
irradiance_face_size = 8

[camera]
position = [0.0, 1.2, 3.5]
look_at = [0.0, 0.3, 0.0]
fov_deg = 45
resolution = [40, 30]

[fiv]
samples = [8, 5, 4]

[[object]]
name = "ground"
primitive = "plane"
params = { size = [6.0, 6.0] }

[[object]]
name = "ball"
primitive = "sphere"
occluder = true
translate = [0.0, 0.5, 0.0]
scale = 0.5
"""


@pytest.fixture()
def sky_scene(tmp_path, monkeypatch) -> Path:
    monkeypatch.setenv("PENUMBRA_CACHE", str(tmp_path / "cache"))
    path = tmp_path / "sky.toml"
    path.write_text(PROCEDURAL_SCENE)
    return path


def _count_executes(monkeypatch) -> list:
    calls = []
    real = penumbra.core.Renderer.execute
    monkeypatch.setattr(penumbra.core.Renderer, "execute", lambda self, *a: (calls.append(self.method), real(self, *a)))
    return calls


def test_render_renders_one_frame_unless_frames_asks_for_timing(capsys, sky_scene, tmp_path, monkeypatch):
    calls = _count_executes(monkeypatch)
    code, out, err = run_cli(capsys, "render", sky_scene, "-o", tmp_path / "a.exr", "--json", tmp_path / "a.json")
    assert code == 0, err
    assert calls == ["unshadowed"]   # no warm-up frame, no timed frames
    t = json.loads((tmp_path / "a.json").read_text())["timings_ms"]
    assert t["frames"] == 1 and t["warmup"] is False
    assert "one frame" in out and "untimed" in out
    calls.clear()
    code, out, err = run_cli(capsys, "render", sky_scene, "-o", tmp_path / "b.exr", "--json", tmp_path / "b.json",
                             "--frames", "3")
    assert code == 0, err
    assert len(calls) >= 4           # warm-up frames (at least one), then 3 timed ones
    t = json.loads((tmp_path / "b.json").read_text())["timings_ms"]
    assert t["frames"] == 3 and t["warmup"] is True
    assert "frame median" in out and "of 3 after warm-up" in out
    assert run_cli(capsys, "render", sky_scene, "--frames", "0")[0] == 2
    # The slow reference: one frame, shaded in row bands (progress).
    calls.clear()
    code, out, err = run_cli(capsys, "render", sky_scene, "--method", "reference", "--set", "render.face_size=4",
                             "-o", tmp_path / "c.exr", "--json", tmp_path / "c.json")
    assert code == 0, err
    t = json.loads((tmp_path / "c.json").read_text())["timings_ms"]
    assert t["frames"] == 1 and t["warmup"] is False and t["banded"] is True and len(calls) > 1


def test_long_frames_render_in_bands_with_progress_and_the_same_image(ctx, sky_scene):
    """A reference frame shaded in row bands (sub-G-buffers) equals the one-pass frame; the
    progress is monotone in foreground pixels and ends at its total."""
    from penumbra.render import build_scene, render

    built = build_scene(load_scene(sky_scene), ctx)
    whole = render(built, "reference", frames=1, warmup=False, face_size=4)
    seen = []
    banded = render(built, "reference", frames=1, warmup=False, face_size=4,
                    band_progress=lambda done, total: seen.append((done, total)))
    assert banded.timings_ms["banded"] and not whole.timings_ms["banded"]
    np.testing.assert_array_equal(banded.image, whole.image)
    assert len(seen) >= 4
    done = [d for d, _ in seen]
    assert done == sorted(done) and len(set(t for _, t in seen)) == 1 and done[-1] == seen[-1][1]
    fg = int((whole.gbuffer["instance"] != 0xFFFFFFFF).sum())
    assert fg <= seen[-1][1] <= fg + len(seen)   # weights: foreground pixels plus one per band


def test_render_png_auto_exposes_unless_exposure_is_given(capsys, sky_scene, tmp_path):
    from penumbra.imageio import auto_exposure

    code, out, err = run_cli(capsys, "render", sky_scene, "-o", tmp_path / "x.exr", "--png", tmp_path / "auto.png",
                             "--json", tmp_path / "r.json")
    assert code == 0, err
    rep = json.loads((tmp_path / "r.json").read_text())
    assert rep["png_exposure"] < -0.5 and "(auto)" in out   # the sky's sun needs darkening, not exposure 0
    lit = np.asarray(Image.open(tmp_path / "auto.png"))[..., :3]
    assert (lit.max(axis=2) == 255).mean() < 0.1            # not blown out
    code, out, err = run_cli(capsys, "render", sky_scene, "--png", tmp_path / "zero.png", "--exposure", "0")
    assert code == 0, err
    assert "(auto)" not in out and "exposure +0.00 stops" in out
    zero = np.asarray(Image.open(tmp_path / "zero.png"))[..., :3]
    assert (zero.max(axis=2) == 255).mean() > 2 * (lit.max(axis=2) == 255).mean()
    # The auto exposure maps the 97th percentile of the lit pixels' luminance to 0.9.
    img = np.zeros((1, 100, 4), np.float32)
    img[0, :, :3], img[0, :50, 3] = np.linspace(0.01, 4.0, 100)[:, None], 1.0
    level = np.percentile(img[0, :50, 0], 97)
    assert auto_exposure(img) == pytest.approx(np.log2(0.9 / level))


def test_render_json_report_has_the_parameters_in_effect_and_the_bake(capsys, sky_scene, tmp_path, ctx):
    from penumbra.methods import spec

    code, out, err = run_cli(capsys, "render", sky_scene, "--method", "fiv", "-o", tmp_path / "x.exr",
                             "--json", tmp_path / "r.json", "--set", "render.overlap=0")
    assert code == 0, err
    rep = json.loads((tmp_path / "r.json").read_text())
    want = {p.name: p.default for p in spec("fiv").params_of("frame", "plan")}
    want["overlap"] = 0
    assert rep["params"] == want
    assert rep["device"] == ctx.device_name
    fields = rep["bake"]["fields"]
    assert len(fields) == 1 and fields[0]["objects"] == ["ball"] and fields[0]["samples"] == [8, 5, 4]
    assert fields[0]["baked"] and fields[0]["bake_s"] > 0 and rep["bake"]["prepare_s"] >= fields[0]["bake_s"]
    assert "preparation (bakes, loads)" in out and "not in the frame" in out


def test_render_help_lists_every_method_on_one_line(capsys):
    from penumbra.methods import catalog

    with pytest.raises(SystemExit):
        main(["render", "--help"])
    lines = capsys.readouterr().out.splitlines()
    for name, m in catalog().items():
        assert any(line.split() and line.split()[0] == f"{name}:" and line.endswith(m.summary) for line in lines), name


@pytest.mark.parametrize("module", ["mitsuba", "matplotlib", "embreex"])
def test_bench_reports_a_missing_dependency_before_any_work(capsys, sky_scene, tmp_path, monkeypatch, module):
    monkeypatch.setitem(sys.modules, module, None)   # import fails, find_spec says absent
    calls = _count_executes(monkeypatch)
    code, out, err = run_cli(capsys, "bench", sky_scene, "--out", tmp_path / "out")
    assert code == 2
    assert "not installed" in err and "-m pip install" in err and f"'{module}>=" in err
    assert calls == [] and not (tmp_path / "out").exists()   # no ground truth, no output folder
    if module == "embreex":   # the ray comparison can be skipped instead
        assert "--no-rays" in err


# ------------------------------------------------------------- hostile input and faults (docs/reliability.md)


def _no_temporaries(folder: Path) -> bool:
    return not [p for p in folder.iterdir() if ".tmp" in p.name]


@pytest.mark.parametrize("bad", [["--exposure", "nan"], ["--exposure", "1100"], ["--json", "DIR"], ["--png", "DIR"],
                                 ["--json", "FILE/r.json"]], ids=["exposure-nan", "exposure-1100", "json-dir",
                                                                  "png-dir", "json-under-file"])
def test_a_failed_render_leaves_every_output_alone(capsys, sky_scene, tmp_path, bad):
    keep_exr, keep_png = tmp_path / "keep.exr", tmp_path / "keep.png"
    keep_exr.write_bytes(b"old exr")
    keep_png.write_bytes(b"old png")
    (tmp_path / "DIR").mkdir()
    bad = [str(tmp_path / a) if a in ("DIR", "FILE/r.json") else a for a in bad]
    (tmp_path / "FILE").write_text("a file")
    extra = [] if "--png" in bad else ["--png", keep_png]
    code, out, err = run_cli(capsys, "render", sky_scene, "-o", keep_exr, *extra, *bad)
    assert code == 2 and err.startswith("penumbra: error: ") and "Traceback" not in err
    assert keep_exr.read_bytes() == b"old exr" and keep_png.read_bytes() == b"old png"
    assert _no_temporaries(tmp_path)


@pytest.mark.parametrize("fault", [InputError("the PNG writer failed"), OSError(28, "No space left on device")],
                         ids=["input-error", "disk-full"])
def test_outputs_appear_together_or_not_at_all(capsys, sky_scene, tmp_path, monkeypatch, fault):
    import penumbra.imageio

    keep_exr = tmp_path / "keep.exr"
    keep_exr.write_bytes(b"old exr")

    def failing(path, *a, **k):
        raise fault

    monkeypatch.setattr(penumbra.imageio, "write_png", failing)   # the EXR is written first, then this fails
    code, out, err = run_cli(capsys, "render", sky_scene, "-o", keep_exr, "--png", tmp_path / "k.png",
                             "--json", tmp_path / "k.json")
    assert code == 2 and err.startswith("penumbra: error: ") and str(fault.args[-1]) in err
    assert keep_exr.read_bytes() == b"old exr"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["keep.exr", "sky.toml"]


@pytest.mark.parametrize("kind", ["fifo", "folder", "link to /dev/null", "under a file"])
def test_render_refuses_outputs_that_are_not_regular_files(capsys, sky_scene, tmp_path, kind):
    target = tmp_path / "out.exr"
    if kind == "fifo":
        os.mkfifo(target)
    elif kind == "folder":
        target.mkdir()
    elif kind == "link to /dev/null":
        target.symlink_to(os.devnull)
    else:
        target.write_text("a file")
        target = target / "x.exr"
    before = os.lstat(tmp_path / "out.exr")
    code, out, err = run_cli(capsys, "render", sky_scene, "-o", target)
    assert code == 2 and err.startswith("penumbra: error: -o ") and "Traceback" not in err
    assert "replaces only regular files" in err or "is a file, not a folder" in err
    after = os.lstat(tmp_path / "out.exr")
    assert (after.st_mode, after.st_ino, after.st_mtime_ns) == (before.st_mode, before.st_ino, before.st_mtime_ns)
    assert out == ""                                                   # refused before rendering


def test_render_follows_an_output_link_and_refuses_one_file_twice(capsys, sky_scene, tmp_path):
    link = tmp_path / "latest.exr"
    link.symlink_to("render-1.exr")
    code, out, err = run_cli(capsys, "render", sky_scene, "-o", link)
    assert code == 0, err
    assert link.is_symlink() and read_exr(tmp_path / "render-1.exr").shape == (30, 40, 3)
    code, out, err = run_cli(capsys, "render", sky_scene, "-o", tmp_path / "render-1.exr", "--png", link)
    assert code == 2 and "name the same file" in err


DEEP = "a = " + "[" * 3000 + "]" * 3000 + "\n"


@pytest.mark.parametrize("scene, args, words", [
    (b"\xff\xfe[camera]\n", [], "is not UTF-8 text"),
    (DEEP.encode(), [], "nests arrays or tables too deeply"),
    (("[camera]\nfov_deg = " + "9" * 5000 + "\n").encode(), [], "cannot be read"),
    (None, ["--set", 'environment.params={width="abc"}'],
     "[environment] params of map 'sky': width must be an integer"),
    (None, ["--set", "environment.params={sun_radiance=[1,2]}"], "sun_radiance must be one number or 3 numbers"),
    (None, ["--set", "environment.params={width=inf}"], "width must be an integer, got inf"),
    (None, ["--set", "object.ball.params={subdivisions=12}"], "subdivisions = 12 is above 8, the limit"),
    (None, ["--set", "object.ground.params={size=[1,2,3]}"], "size must be 2 positive finite numbers"),
    (None, ["--exposure", "1100", "--png", "OUT/x.png"], "--exposure 1100.0 must be a finite number of stops"),
    (None, ["-o", "OUT"], "-o OUT"),
    (None, ["-o", "OUT/scene.toml/x.exr"], "is a file, not a folder"),
    (None, ["--method", "reference", "--set", "render.face_size=4294967328"],
     "[render] face_size = 4294967328 is outside [0, 256]"),
], ids=["non-utf8", "deep-nesting", "5000-digits", "width-abc", "rgb-of-2", "width-inf", "subdivisions-12",
        "plane-size-3", "exposure-1100", "o-folder", "o-under-file", "face-size-2**32+32"])
def test_hostile_input_is_an_error_line_and_exit_2(capsys, sky_scene, tmp_path, scene, args, words):
    if scene is not None:
        sky_scene = tmp_path / "hostile.toml"
        sky_scene.write_bytes(scene)
    else:
        (tmp_path / "OUT").mkdir()
        (tmp_path / "OUT" / "scene.toml").write_text("")
    args = [a.replace("OUT", str(tmp_path / "OUT")) for a in args]
    code, out, err = run_cli(capsys, "render", sky_scene, *args)
    assert code == 2, err
    assert err.startswith("penumbra: error: ") and "Traceback" not in err
    assert words.replace("OUT", str(tmp_path / "OUT")) in err


@pytest.mark.parametrize("fault, words", [(OSError(13, "Permission denied", "/x/y.exr"), "/x/y.exr: Permission denied"),
                                          (MemoryError(), "out of memory"),
                                          (RecursionError(), "nested too deeply"),
                                          (UnicodeDecodeError("utf-8", b"\xff", 0, 1, "invalid start byte"),
                                           "not valid UTF-8")])
def test_faults_of_the_input_or_machine_are_error_lines(capsys, monkeypatch, fault, words):
    import penumbra.cli

    def failing(args):
        raise fault

    monkeypatch.setattr(penumbra.cli, "cmd_info", failing)
    code, out, err = run_cli(capsys, "info")
    assert code == 2 and err == f"penumbra: error: {err[len('penumbra: error: '):]}" and words in err


def test_demo_refuses_an_out_that_is_a_file(capsys, tmp_path):
    (tmp_path / "demo").write_text("a file")
    code, out, err = run_cli(capsys, "demo", "--out", tmp_path / "demo")
    assert code == 2 and "--out" in err and "is not a folder" in err
    assert (tmp_path / "demo").read_text() == "a file"


def test_bake_fiv_follows_a_dangling_link_and_refuses_a_fifo(capsys, shared_data, tmp_path):
    link = tmp_path / "b.pnfiv"
    link.symlink_to("baked.pnfiv")
    code, out, err = run_cli(capsys, "bake-fiv", shared_data / BUNNY, "--env", "sky", *TINY_FIV, "-o", link)
    assert code == 0, err
    assert link.is_symlink() and read_header(tmp_path / "baked.pnfiv")["radii_done"] == 4
    fifo = tmp_path / "f.pnfiv"
    os.mkfifo(fifo)
    code, out, err = run_cli(capsys, "bake-fiv", shared_data / BUNNY, "--env", "sky", *TINY_FIV, "-o", fifo)
    assert code == 2 and "is a FIFO" in err and stat.S_ISFIFO(os.lstat(fifo).st_mode)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["b.pnfiv", "baked.pnfiv", "f.pnfiv"]


def test_fiv_info_refuses_a_fifo(capsys, tmp_path):
    fifo = tmp_path / "f.pnfiv"
    os.mkfifo(fifo)                  # the library's read would block for ever
    code, out, err = run_cli(capsys, "fiv-info", fifo)
    assert code == 2 and "is not a regular file" in err
