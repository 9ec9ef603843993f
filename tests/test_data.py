"""Where the real test data is found (penumbra.data): PENUMBRA_DATA, the
``data:`` prefix of scene files, the skip (or, with PENUMBRA_REQUIRE_DATA,
the failure) of data tests on a clone without the data, and the example
scenes a newcomer runs first, which need no data."""

from __future__ import annotations

import os
import subprocess
import sys
import tomllib
from pathlib import Path

import numpy as np
import pytest

import penumbra
from penumbra import data
from penumbra.cli import main
from penumbra.errors import InputError
from penumbra.imageio import read_exr
from penumbra.scenefile import load_scene, parse_scene

REPO = Path(__file__).resolve().parents[1]
TESTS = Path(__file__).resolve().parent


def fake_data(folder: Path) -> Path:
    """A data folder as penumbra.data recognises one (its SHA256SUMS)."""
    (folder / "envmaps").mkdir(parents=True)
    (folder / data.MARKER).write_text("")
    return folder


def test_penumbra_data_moves_the_data_folder(tmp_path, monkeypatch):
    monkeypatch.setenv(data.ENV_VAR, str(tmp_path / "elsewhere"))
    assert data.data_dir() == (tmp_path / "elsewhere").resolve()
    assert not data.available()
    fake_data(tmp_path / "elsewhere")
    assert data.available()
    assert data.path("envmaps/x.hdr") == (tmp_path / "elsewhere" / "envmaps" / "x.hdr").resolve()


def test_default_is_shared_data_beside_the_checkout(monkeypatch):
    monkeypatch.delenv(data.ENV_VAR, raising=False)
    assert data.data_dir() == REPO.parent / "shared" / "data"


def test_data_prefix_in_a_scene_file_resolves_under_the_data_folder(tmp_path, monkeypatch):
    root = fake_data(tmp_path / "d")
    monkeypatch.setenv(data.ENV_VAR, str(root))
    desc = parse_scene({"environment": {"map": "data:envmaps/sky.hdr"},
                        "object": [{"name": "m", "mesh": "data:meshes/m.obj"}]}, tmp_path / "scenes")
    assert desc.environment.map == str(root.resolve() / "envmaps" / "sky.hdr")
    assert desc.objects[0].mesh == str(root.resolve() / "meshes" / "m.obj")
    # Other relative paths still resolve against the scene file's folder.
    desc = parse_scene({"environment": {"map": "maps/sky.hdr"}}, tmp_path / "scenes")
    assert desc.environment.map == str((tmp_path / "scenes" / "maps" / "sky.hdr").resolve())


def test_data_prefix_without_the_data_names_the_key_and_the_variable(tmp_path, monkeypatch):
    monkeypatch.setenv(data.ENV_VAR, str(tmp_path / "none"))
    with pytest.raises(InputError) as exc:
        parse_scene({"object": [{"name": "bunny", "mesh": "data:meshes/bunny.obj"}]})
    msg = str(exc.value)
    assert "[object 'bunny'] mesh" in msg and "data:meshes/bunny.obj" in msg
    assert data.ENV_VAR in msg and str(tmp_path / "none") in msg
    with pytest.raises(InputError, match="name a file after 'data:'"):
        parse_scene({"environment": {"map": "data:"}})


def test_every_scene_of_the_repository_names_its_data_through_the_prefix():
    """No scene file reaches the data by a path relative to the checkout (it breaks when the data moves)."""
    scenes = sorted(REPO.glob("examples/scenes/*.toml")) + sorted(REPO.glob("bench/scenes/*.toml")) + sorted(
        REPO.glob("python/penumbra/scenes/*.toml"))
    assert len(scenes) >= 8

    def strings(v):
        if isinstance(v, str):
            yield v
        elif isinstance(v, dict):
            for x in v.values():
                yield from strings(x)
        elif isinstance(v, list):
            for x in v:
                yield from strings(x)

    for path in scenes:
        for value in strings(tomllib.loads(path.read_text())):
            assert "shared/data" not in value, (path, value)


def _run_probe(tmp_path: Path, require: bool) -> subprocess.CompletedProcess:
    probe = tmp_path / "test_probe.py"
    probe.write_text("def test_uses_data(shared_data):\n    assert (shared_data / 'SHA256SUMS').is_file()\n")
    env = dict(os.environ, PENUMBRA_DATA=str(tmp_path / "no_data"),
               PYTHONPATH=os.pathsep.join([str(TESTS), str(Path(penumbra.__file__).resolve().parents[1]),
                                           os.environ.get("PYTHONPATH", "")]))
    env.pop(data.REQUIRE_VAR, None)
    if require:
        env[data.REQUIRE_VAR] = "1"
    return subprocess.run([sys.executable, "-m", "pytest", "-q", "-rs", "-p", "conftest", "-p", "no:cacheprovider",
                           str(probe)], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=120)


def test_data_tests_skip_with_one_reason_without_the_data(tmp_path):
    res = _run_probe(tmp_path, require=False)
    assert res.returncode == 0, res.stdout + res.stderr
    assert "1 skipped" in res.stdout
    assert "needs penumbra's test data" in res.stdout and "PENUMBRA_DATA" in res.stdout


def test_data_tests_fail_without_the_data_when_required(tmp_path):
    res = _run_probe(tmp_path, require=True)
    assert res.returncode == 1, res.stdout + res.stderr
    # A fixture that fails is reported as an error: the run fails either way.
    assert "1 error" in res.stdout and "PENUMBRA_REQUIRE_DATA" in res.stdout


def test_ci_requires_the_data():
    assert f"{data.REQUIRE_VAR}=1" in (REPO / ".ci" / "run").read_text()


@pytest.mark.parametrize("method", ["unshadowed", "fiv", "heightfield"])
def test_procedural_example_renders_without_the_data(capsys, tmp_path, monkeypatch, method):
    """examples/scenes/shapes_sky.toml, the README's first scene, on a machine without the data."""
    monkeypatch.setenv(data.ENV_VAR, str(tmp_path / "no_data"))
    monkeypatch.setenv("PENUMBRA_CACHE", str(tmp_path / "cache"))
    monkeypatch.chdir(tmp_path)
    code = main(["render", str(REPO / "examples" / "scenes" / "shapes_sky.toml"), "--method", method,
                 "--set", "camera.resolution=[40,30]", "--set", "fiv.samples=[8,5,4]",
                 "--set", "heightfield.hills.size_px=[33,13]", "-o", "x.exr"])
    assert code == 0, capsys.readouterr().err
    img = read_exr(tmp_path / "x.exr")
    assert img.shape == (30, 40, 3) and np.isfinite(img).all() and img[15:, :].mean() > 0.05


def test_data_examples_say_they_need_the_data(tmp_path, monkeypatch):
    """The examples that read real data fail before any work with the reason, not 'file not found'."""
    monkeypatch.setenv(data.ENV_VAR, str(tmp_path / "no_data"))
    for name in ("bunny_pisa", "cones_dawn_lights"):
        path = REPO / "examples" / "scenes" / f"{name}.toml"
        assert "needs the test data" in path.read_text()
        with pytest.raises(InputError, match="needs penumbra's test data"):
            load_scene(path)


def test_bake_fiv_takes_data_paths(capsys, tmp_path, monkeypatch):
    """bake-fiv's MESH and --env resolve data: as scene files do (no 'file not found' without the data)."""
    monkeypatch.setenv(data.ENV_VAR, str(tmp_path / "no_data"))
    code = main(["bake-fiv", "data:meshes/bunny_odedstein_3k.obj", "--env", "sky", "--samples", "8,5,4",
                 "-o", str(tmp_path / "b.pnfiv")])
    assert code == 2
    err = capsys.readouterr().err
    assert "MESH 'data:meshes/bunny_odedstein_3k.obj' needs penumbra's test data" in err
    assert not (tmp_path / "b.pnfiv").exists()
