"""The benchmark harness (penumbra.bench, `penumbra bench`): a tiny run writes
every promised file with the documented schema, the speed-up interpolation
along Mitsuba's curve, the README table refresh, and bad options."""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import pytest

from penumbra.bench import (README_BEGIN, README_END, RESULT_KEYS, BenchOptions, _mitsuba_time_at, readme_row, run,
                            update_readme)
from penumbra.cli import main
from penumbra.errors import InputError

REPO = Path(__file__).resolve().parents[1]
SCENE = REPO / "bench" / "scenes" / "bunny_sunny.toml"
TINY = ["camera.resolution=[24,18]"]


@pytest.fixture(scope="module")
def tiny_bench(tmp_path_factory, shared_data):
    pytest.importorskip("mitsuba")
    out = tmp_path_factory.mktemp("bench")
    opts = BenchOptions(frames=5, reference_face_size=8, reference_sun_supersampling=1, spp=(1, 4),
                        sweeps={"unshadowed": [{}], "reference": [{"face_size": 4}, {"face_size": 8}]})
    res = run(SCENE, out, opts, overrides=TINY, log=lambda m: None)
    return out, res


def test_bench_writes_every_file(tiny_bench):
    out, _ = tiny_bench
    for name in ("results.json", "results.csv", "pareto.png", "report.md", "ground_truth.exr", "unshadowed.png",
                 "reference_error.png", "mitsuba_4spp.png"):
        assert (out / name).is_file() and (out / name).stat().st_size > 0, name
    assert (out / "pareto.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_results_json_schema(tiny_bench):
    out, _ = tiny_bench
    data = json.loads((out / "results.json").read_text())
    rows = data["results"]
    methods = [r["method"] for r in rows]
    assert methods.count("unshadowed") == 1 and methods.count("reference") == 2 and methods.count("mitsuba") == 2
    for r in rows:
        for key in ("method", "params", "time_ms", "nrmse", "rel_rms", "max_abs"):
            assert key in r, key
        assert r["time_ms"] > 0 and math.isfinite(r["nrmse"]) and r["nrmse"] >= 0
    for r in rows:
        if r["method"] != "mitsuba":
            assert set(RESULT_KEYS) <= set(r)
            assert r["floor_ratio"] > 0
    # The reference at the ground truth's own face size is the ground truth.
    ref8 = next(r for r in rows if r["method"] == "reference" and r["params"] == {"face_size": 8})
    assert ref8["nrmse"] < 1e-6
    ref4 = next(r for r in rows if r["method"] == "reference" and r["params"] == {"face_size": 4})
    assert ref4["nrmse"] > ref8["nrmse"]
    s = data["summary"]
    assert s["rays"]["primary"]["mismatch_fraction"] < 1e-3 and s["mitsuba"]["variant"]


def test_results_csv_matches_json(tiny_bench):
    out, _ = tiny_bench
    rows = list(csv.DictReader((out / "results.csv").open()))
    data = json.loads((out / "results.json").read_text())["results"]
    assert len(rows) == len(data)
    for a, b in zip(rows, data):
        assert a["method"] == b["method"] and float(a["nrmse"]) == pytest.approx(b["nrmse"], rel=1e-5)


def test_report_has_the_headline_ratios(tiny_bench):
    out, _ = tiny_bench
    text = (out / "report.md").read_text()
    assert "speed-up over Mitsuba at equal error" in text and "x floor" in text and "Mrays/s" in text


def test_readme_table_is_refreshed(tiny_bench, tmp_path):
    _, res = tiny_bench
    readme = tmp_path / "README.md"
    readme.write_text(f"# x\n\n{README_BEGIN}\n| scene | old |\n|---|---|\n| bunny_sunny | stale |\n"
                      f"| other | kept |\n{README_END}\n\nrest\n")
    update_readme(readme, readme_row(res["summary"], res["results"]))
    text = readme.read_text()
    assert "stale" not in text and "| other | kept |" in text and text.endswith("rest\n")
    assert text.count("| bunny_sunny |") == 1
    with pytest.raises(InputError, match="markers"):
        bad = tmp_path / "bad.md"
        bad.write_text("no table\n")
        update_readme(bad, "| a |")


def test_mitsuba_time_at_equal_error():
    curve = [{"nrmse": 0.4, "time_ms": 10.0}, {"nrmse": 0.2, "time_ms": 40.0}, {"nrmse": 0.1, "time_ms": 160.0}]
    # log-log interpolation: error halves when time quadruples.
    t, bound = _mitsuba_time_at(curve, 0.2 / math.sqrt(2))
    assert bound == "" and t == pytest.approx(80.0)
    assert _mitsuba_time_at(curve, 0.05) == (160.0, ">")
    assert _mitsuba_time_at(curve, 0.8) == (10.0, "<")


@pytest.mark.parametrize("opts,match", [
    (BenchOptions(methods=("nope",)), "unknown method"),
    (BenchOptions(methods=("floor",)), "no benchmark sweep"),
    (BenchOptions(frames=3), "at least 5"),
])
def test_bad_options(tmp_path, opts, match):
    with pytest.raises(InputError, match=match):
        run(SCENE, tmp_path, opts, overrides=TINY, log=lambda m: None)


def test_cli_bench_rejects_bad_lists(capsys):
    with pytest.raises(SystemExit):
        main(["bench", str(SCENE), "--out", "x", "--spp", "1,a"])
    assert "not a comma-separated list" in capsys.readouterr().err
