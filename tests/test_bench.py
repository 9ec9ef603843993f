"""The benchmark harness (penumbra.bench, `penumbra bench`): a tiny run writes
every promised file with the documented schema, the speed-up interpolation
along Mitsuba's curve, the README table refresh, and bad options."""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import numpy as np
import pytest

from penumbra import methods
from penumbra.bench import (README_BEGIN, README_END, RESULT_KEYS, BenchOptions, _mitsuba_time_at, default_sweeps,
                            readme_header, readme_row, run, update_readme)
from penumbra.cli import main
from penumbra.errors import InputError
from penumbra.scenefile import parse_scene
from penumbra.methods.fiv import (PAPER_FPS, fiv_scaling, fiv_scaling_scene, fiv_spread_scene, per_lookup_costs,
                                  per_lookup_ratios)

README_FIV = methods.technique("fiv").readme_setting
SWEEPS = default_sweeps()
README_HEADER = readme_header()

REPO = Path(__file__).resolve().parents[1]
SCENE = REPO / "bench" / "scenes" / "bunny_sunny.toml"
TINY = ["camera.resolution=[24,18]"]


@pytest.fixture(scope="module")
def tiny_bench(tmp_path_factory, shared_data):
    pytest.importorskip("mitsuba")
    out = tmp_path_factory.mktemp("bench")
    opts = BenchOptions(frames=5, reference_face_size=8, reference_sun_supersampling=1, spp=(1, 4),
                        sweeps={"unshadowed": [{}], "reference": [{"face_size": 4, "sun_supersampling": 1},
                                              {"face_size": 8, "sun_supersampling": 1}],
                                "fiv": [{"samples": [8, 5, 4], "face_size": 8},
                                        {"samples": [8, 5, 4], "face_size": 8, "overlap": 0}],
                                "depthmap": [{"directions": 8, "resolution": 32}],
                                "isg": [{"spheres": 8, "lobes": 4, "patch_grid": 4}]})
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
    assert methods.count("fiv") == 2
    for r in rows:
        for key in ("method", "params", "time_ms", "nrmse", "rel_rms", "max_abs"):
            assert key in r, key
        assert r["time_ms"] > 0 and math.isfinite(r["nrmse"]) and r["nrmse"] >= 0
    for r in rows:
        if r["method"] != "mitsuba":
            assert set(RESULT_KEYS) <= set(r)
            assert r["floor_ratio"] > 0
    # The reference at the ground truth's own face size is the ground truth.
    ref8 = next(r for r in rows if r["method"] == "reference" and r["params"] == {"face_size": 8, "sun_supersampling": 1})
    assert ref8["nrmse"] < 1e-6
    ref4 = next(r for r in rows if r["method"] == "reference" and r["params"] == {"face_size": 4, "sun_supersampling": 1})
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


def test_bench_sweeps_fiv(tiny_bench):
    out, _ = tiny_bench
    rows = [r for r in json.loads((out / "results.json").read_text())["results"] if r["method"] == "fiv"]
    assert [r["params"] for r in rows] == [{"samples": [8, 5, 4], "face_size": 8},
                                           {"samples": [8, 5, 4], "face_size": 8, "overlap": 0}]
    for r in rows:
        assert r["fiv_fields"] == 1 and r["fiv_bytes"] == 8 * 5 * 4 * 9 * 2  # the bunny; the ground is no occluder
        assert r["floor_ratio"] > 0 and math.isfinite(r["mitsuba_speedup"])
    assert rows[0]["bake_s"] > 0  # baked in this run, into the bench's cache folder
    assert len(list((out / "cache" / "fiv").glob("*.pnfiv"))) == 1
    text = (out / "report.md").read_text()
    assert "| fiv | samples=8x5x4, face_size=8 |" in text and "fiv precomputation" in text
    assert (out / "fiv.png").is_file() and (out / "fiv_error.png").is_file()


def test_default_sweeps_include_fiv():
    assert "fiv" in methods.applicable(parse_scene({"object": [{"mesh": "m.obj"}]})) and "fiv" in SWEEPS
    assert "fiv" not in methods.applicable(parse_scene({})) and "floor" not in SWEEPS
    grids = [p["samples"] for p in SWEEPS["fiv"]]
    assert [32, 17, 15] in grids and [64, 33, 30] in grids and README_FIV in SWEEPS["fiv"]
    assert {p.get("overlap", 1) for p in SWEEPS["fiv"]} == {0, 1, 2}


def test_readme_settings_are_swept():
    """Each README column's setting is one the technique's sweep runs, spelled as the sweep spells it: the
    row picks the result whose params equal it, so any other spelling leaves the column at '-'."""
    for t in methods.techniques():
        if t.readme_setting is not None:
            assert t.readme_setting in t.sweep(), (t.name, t.readme_setting)


def test_readme_row_has_fiv_columns(tiny_bench):
    _, res = tiny_bench
    fake = [dict(r) for r in res["results"] if r["method"] != "fiv"] + [
        {"method": "fiv", "params": dict(README_FIV), "time_ms": 2.5, "shade_ms": 1.0, "floor_ratio": 12.0,
         "nrmse": 0.0123, "mitsuba_speedup": 40.0, "mitsuba_speedup_bound": ""},
        {"method": "fiv", "params": {**README_FIV, "overlap": 0}, "time_ms": 9.9, "shade_ms": 9.0,
         "floor_ratio": 99.0, "nrmse": 0.5, "mitsuba_speedup": 1.0}]
    row = readme_row(res["summary"], fake)
    cells = [c.strip() for c in row.split("|")[1:-1]]
    header = [c.strip() for c in README_HEADER.splitlines()[0].split("|")[1:-1]]
    assert len(cells) == len(header)
    # Columns by name: one per technique with a README setting, so their positions follow the registry.
    col = {h.split(" (")[0].split(" ms")[0]: i for i, h in enumerate(header)}
    assert header[col["fiv"]].startswith("fiv (64x33x30)") and cells[col["fiv"]] == "2.50 / 0.0123 / 12.0"
    assert "fiv samples=64x33x30 40x" in cells[col["speed-up over Mitsuba at equal error"]]


def test_fiv_scaling_scene_nests_and_shares_one_mesh():
    a, b = fiv_scaling_scene(10, "m.obj", "e.hdr"), fiv_scaling_scene(30, "m.obj", "e.hdr")
    assert b["object"][:11] == a["object"]  # the ground and the first ten bunnies
    bunnies = [o for o in b["object"] if o.get("mesh")]
    assert len(bunnies) == 30 and {o["mesh"] for o in bunnies} == {"m.obj"}
    assert all(isinstance(o["scale"], float) and "rotate_deg" not in o for o in bunnies)  # one field serves all
    xz = np.array([[o["translate"][0], o["translate"][2]] for o in bunnies])
    d = np.linalg.norm(xz[:, None] - xz[None], axis=-1) + np.eye(30) * 9
    assert d.min() > 1.2  # no two bunnies intersect
    with pytest.raises(InputError, match="1 to 64"):
        fiv_scaling_scene(65, "m.obj", "e.hdr")


def test_fiv_spread_scene_spreads_one_mesh():
    sc = fiv_spread_scene(60, "m.obj", "e.hdr", spacing=100.0)
    bunnies = [o for o in sc["object"] if o.get("mesh")]
    assert len(bunnies) == 60 and {o["mesh"] for o in bunnies} == {"m.obj"}
    assert sc["object"][0]["params"]["size"] == [800.0, 800.0]
    xz = np.array([[o["translate"][0], o["translate"][2]] for o in bunnies])
    assert np.abs(xz).max() <= 400 and (np.linalg.norm(xz[:, None] - xz[None], axis=-1) + np.eye(60) * 1e9).min() > 30
    cam = sc["camera"]  # 6 units behind the first bunny, looking at it
    assert cam["look_at"][0] == bunnies[0]["translate"][0] and cam["position"][2] - cam["look_at"][2] == 6.0
    with pytest.raises(InputError, match="1 to 64"):
        fiv_spread_scene(0, "m.obj", "e.hdr")


def test_fiv_scaling_writes_results(tmp_path, shared_data):
    res = fiv_scaling(tmp_path, counts=(1, 3), samples=(8, 5, 4), resolution=24, frames=5, data_dir=shared_data,
                      mitsuba_count=None, overrides=["environment.face_size=16", "fiv.face_size=8"],
                      spread=4, spread_spacing=100.0, log=lambda m: None)
    data = json.loads((tmp_path / "results.json").read_text())
    assert [(r["occluders"], r["layout"]) for r in data["results"]] == [(1, "clustered"), (3, "clustered"),
                                                                         (4, "spread")]
    for r in data["results"]:
        assert r["fields"] == 1  # every bunny shares the one field
        assert r["fiv_shade_ms"] > 0 and r["floor_ms"] > 0 and r["fiv_unculled_shade_ms"] > 0
        assert r["ratio_to_floor"] == pytest.approx(r["fiv_shade_ms"] / r["floor_ms"])
        assert r["fiv_cpu_ms"] > 0 and r["floor_cpu_ms"] > 0
        assert r["ratio_to_floor_cpu"] == pytest.approx(r["fiv_cpu_ms"] / r["floor_cpu_ms"])
        assert r["tile_cull_speedup_cpu"] > 0 and r["per_lookup_cpu_ns"] is not None
        # the loop's cost per lookup: fiv less the same kernel built without its occluder loop
        assert r["fiv_noloop_shade_ms"] > 0 and r["fiv_noloop_cpu_ms"] > 0 and r["fiv_sum_noloop_cpu_ms"] > 0
        assert r["noloop_same_gbuffer"] is True
        lookups = r["tiles_lookups_per_pixel"] * r["tiles_receiver_pixels"]
        assert r["loop_per_lookup_cpu_ns"] == pytest.approx(r["loop_cpu_ms"] * 1e6 / lookups)
        assert r["loop_cpu_ms"] == pytest.approx(r["fiv_cpu_ms"] - r["fiv_noloop_cpu_ms"], abs=0.5)  # paired rounds
        assert r["per_lookup_cpu_ns"] == pytest.approx((r["fiv_cpu_ms"] - r["unshadowed_cpu_ms"]) * 1e6 / lookups)
        assert r["tile_cull_speedup"] == pytest.approx(r["fiv_unculled_shade_ms"] / r["fiv_shade_ms"])
        assert r["fps_shading"] == pytest.approx(1000 / r["fiv_shade_ms"])
        assert 0 <= r["tiles_per_tile_min"] <= r["tiles_per_tile_max"] <= r["occluders"]
        assert sum(r["tiles_per_tile_histogram"]) == r["tiles_tiles"] > 0
    for key in ("per_lookup_ratio", "per_lookup_cpu_ratio", "loop_per_lookup_ratio", "loop_per_lookup_cpu_ratio",
                "loop_per_lookup_sum_cpu_ratio"):
        # the single occluder's against itself; none where its loop time is lost in the noise (<= 0)
        base = data["results"][0][key.replace("_ratio", "_ns")]
        assert data["results"][0][key] == (pytest.approx(1.0) if base > 0 else None)
    assert data["results"][2]["tiles_per_tile_mean"] < 4  # 100 units apart: no tile sees all four
    assert data["results"][0]["paper_fps"] == PAPER_FPS[1] == 112 and data["results"][1]["paper_fps"] is None
    assert data["summary"]["samples_phi_theta_radii"] == [8, 5, 4] and data["summary"]["bake"]["baked_now"]
    assert data["equal_error"] is None and res["results"] == data["results"]
    text = (tmp_path / "report.md").read_text()
    assert "fiv / floor" in text and "fiv / floor (CPU time)" in text and "paper fps" in text and "| 3 |" in text and "tile culling speed-up" in text
    assert "## Goals (issue 15)" in text and "Tile culling, 4 bunnies over a 800 x 800 floor" in text
    assert "fiv without the occluder loop ms" in text and "earlier measure, (fiv - unshadowed)" in text
    # The scenes are real scene files (paths relative to them, the bake cache beside them).
    from penumbra.scenefile import load_scene

    desc = load_scene(tmp_path / "scenes" / "bunnies_3.toml")
    assert sum(o.is_occluder for o in desc.objects) == 3
    assert Path(desc.objects[1].mesh) == (shared_data / "meshes" / "bunny_odedstein_3k.obj").resolve()
    assert len(list((tmp_path / "cache" / "fiv").glob("*.pnfiv"))) == 1


def _scaling_ms(fiv, noloop, unshadowed, sum_extra=0.0):
    """_interleaved_ms's medians for one scene, the CPU times equal to the wall clock's."""
    ms = {"fiv": fiv, "fiv_sum": fiv - sum_extra, "unshadowed": unshadowed, "fiv_noloop": noloop,
          "fiv_sum_noloop": noloop}
    ms.update({"cpu:" + k: v for k, v in list(ms.items())})
    return ms


def _ratios(scenes):
    rows = [{"occluders": n, "layout": "clustered", **per_lookup_costs(_scaling_ms(*t), lookups)}
            for n, lookups, t in scenes]
    per_lookup_ratios(rows)
    return rows


def test_per_lookup_measure_subtracts_fivs_own_pixel_work():
    # 1 occluder: 1e5 lookups; 60: 6e6. Times in ms: (fiv, fiv without the loop, unshadowed).
    before = _ratios([(1, 1e5, (4.0, 2.0, 1.0)), (60, 6e6, (242.0, 2.0, 1.0, 80.0))])
    assert before[0]["loop_per_lookup_cpu_ns"] == pytest.approx(20.0)  # (4 - 2) ms / 1e5
    assert before[0]["per_lookup_cpu_ns"] == pytest.approx(30.0)  # (4 - 1) ms / 1e5
    assert before[1]["loop_per_lookup_cpu_ns"] == pytest.approx(40.0)
    assert before[1]["loop_per_lookup_sum_cpu_ns"] == pytest.approx(160.0 / 6e6 * 1e6)
    assert before[1]["loop_per_lookup_cpu_ratio"] == pytest.approx(2.0)
    assert before[1]["loop_per_lookup_ratio"] == pytest.approx(2.0)  # the wall clock's, the same times
    assert before[1]["per_lookup_cpu_ratio"] == pytest.approx((241 / 6) / 30)
    assert before[0]["loop_per_lookup_cpu_ratio"] == before[0]["per_lookup_cpu_ratio"] == 1.0
    # fiv's pixel work 0.7 ms cheaper in every frame, the loop as it was: the loop measure
    # does not move, the earlier one (over unshadowed's whole kernel) does.
    after = _ratios([(1, 1e5, (3.3, 1.3, 1.0)), (60, 6e6, (241.3, 1.3, 1.0, 80.0))])
    assert after[1]["loop_per_lookup_cpu_ratio"] == pytest.approx(before[1]["loop_per_lookup_cpu_ratio"])
    assert after[1]["per_lookup_cpu_ratio"] > 1.1 * before[1]["per_lookup_cpu_ratio"]
    # a dearer lookup with 60 occluders moves it
    dearer = _ratios([(1, 1e5, (4.0, 2.0, 1.0)), (60, 6e6, (302.0, 2.0, 1.0, 80.0))])
    assert dearer[1]["loop_per_lookup_cpu_ratio"] == pytest.approx(2.5)


def test_per_lookup_measure_of_max_overlap_32_uses_fivs_no_loop_kernel():
    # max_overlap 32 (fiv_pairs32) forms no pair without the loop: its loop time is
    # fiv_pairs32 - fiv_noloop; scenes timed without it get no such keys.
    ms = _scaling_ms(6.0, 2.0, 1.0)
    ms.update({"fiv_pairs32": 9.0, "cpu:fiv_pairs32": 10.0})
    c = per_lookup_costs(ms, 1e5)
    assert c["loop_per_lookup_pairs32_ns"] == pytest.approx(70.0)
    assert c["loop_per_lookup_pairs32_cpu_ns"] == pytest.approx(80.0)
    assert c["loop_per_lookup_cpu_ns"] == pytest.approx(40.0)
    assert "loop_per_lookup_pairs32_ns" not in per_lookup_costs(_scaling_ms(6.0, 2.0, 1.0), 1e5)
    rows = [{"occluders": 1, "layout": "clustered", **per_lookup_costs(_scaling_ms(4.0, 2.0, 1.0), 1e5)},
            {"occluders": 60, "layout": "clustered", **c}]
    per_lookup_ratios(rows)
    assert rows[1]["loop_per_lookup_pairs32_cpu_ratio"] is None  # the single scene was not timed with it
    rows[0].update(per_lookup_costs({**_scaling_ms(4.0, 2.0, 1.0), "fiv_pairs32": 4.0, "cpu:fiv_pairs32": 4.0}, 1e5))
    per_lookup_ratios(rows)
    assert rows[1]["loop_per_lookup_pairs32_cpu_ratio"] == pytest.approx(4.0)
    # A single occluder's loop time lost in the noise (the loop-less build no faster): no ratio,
    # where dividing would give a negative one.
    rows[0].update(per_lookup_costs(_scaling_ms(1.9, 2.0, 1.0), 1e5))
    per_lookup_ratios(rows)
    assert rows[0]["loop_per_lookup_ns"] < 0 and rows[1]["loop_per_lookup_ratio"] is None


def test_per_lookup_measure_pairs_the_rounds():
    # The load rose after round 2: each round's fiv less the same round's no-loop build is 2 ms
    # (2.1 in round 4), the medians alone would give 8.0 - 2.2.
    ms = _scaling_ms(8.0, 2.2, 1.0)
    ms["rounds"] = {"cpu:fiv": [4.0, 4.1, 8.0, 8.1, 8.2], "cpu:fiv_noloop": [2.0, 2.1, 6.0, 6.0, 6.1]}
    c = per_lookup_costs(ms, 1e5)
    assert c["loop_cpu_ms"] == pytest.approx(2.0) and c["loop_per_lookup_cpu_ns"] == pytest.approx(20.0)
    assert c["loop_ms"] == pytest.approx(5.8)  # no rounds of the wall clock's: the medians' difference
    assert c["per_lookup_cpu_ns"] == pytest.approx(70.0)  # the earlier measure: medians, as it always was
    ms["rounds"]["cpu:fiv_noloop"].pop()
    with pytest.raises(ValueError):
        per_lookup_costs(ms, 1e5)


def test_per_lookup_measure_without_lookups_or_timings():
    ms = _scaling_ms(4.0, 2.0, 1.0)
    assert all(v is None for k, v in per_lookup_costs(ms, 0).items() if k.endswith("_ns"))
    del ms["fiv_noloop"], ms["cpu:fiv_noloop"]
    c = per_lookup_costs(ms, 1e5)
    assert c["loop_per_lookup_ns"] is None and c["loop_per_lookup_cpu_ns"] is None
    assert c["per_lookup_ns"] == pytest.approx(30.0) and c["loop_per_lookup_sum_ns"] == pytest.approx(20.0)
    # no single clustered occluder, or a loop that timed at nothing there: no ratio
    rows = _ratios([(10, 1e6, (20.0, 2.0, 1.0))])
    assert rows[0]["loop_per_lookup_cpu_ratio"] is None and rows[0]["per_lookup_cpu_ratio"] is None
    rows = _ratios([(1, 1e5, (2.0, 2.0, 1.0)), (10, 1e6, (20.0, 2.0, 1.0))])
    assert rows[1]["loop_per_lookup_cpu_ratio"] is None and rows[1]["per_lookup_cpu_ratio"] == pytest.approx(1.9)


def test_cli_bench_needs_a_scene_or_fiv_scaling(capsys, tmp_path):
    assert main(["bench", "--out", str(tmp_path)]) == 2
    assert "needs a scene file" in capsys.readouterr().err
    assert main(["bench", str(SCENE), "--fiv-scaling", "--out", str(tmp_path)]) == 2
    assert "no scene file" in capsys.readouterr().err


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


SHAPES = REPO / "examples" / "scenes" / "shapes_sky.toml"   # procedural: no test data needed
TINY_CLI = ["--set", "camera.resolution=[24,18]", "--spp", "1,2", "--reference-face-size", "8",
            "--reference-sun-supersampling", "1", "--methods", "unshadowed,reference", "--face-sizes", "4",
            "--no-rays"]


def test_bench_scenes_on_a_local_dask_cluster_match_a_serial_run(tmp_path, capsys):
    """`penumbra bench A B --workers 2`: each scene a job on a 2-worker
    LocalCluster, its report in <out>/<stem>/, the same errors as a serial
    run in this process (only times differ), the README rows of both."""
    pytest.importorskip("distributed")
    pytest.importorskip("mitsuba")
    a, b = tmp_path / "a.toml", tmp_path / "b.toml"
    a.write_text(SHAPES.read_text())
    b.write_text(SHAPES.read_text().replace("fov_deg = 45", "fov_deg = 30"))
    readme = tmp_path / "README.md"
    readme.write_text(f"# x\n\n{README_BEGIN}\n{README_HEADER}\n{README_END}\n")
    assert main(["bench", str(a), str(b), "--out", str(tmp_path / "farm"), "--workers", "2",
                 "--readme", str(readme), *TINY_CLI]) == 0
    assert main(["bench", str(a), str(b), "--out", str(tmp_path / "serial"), *TINY_CLI]) == 0
    errors = {}
    for run_name in ("farm", "serial"):
        for stem in ("a", "b"):
            rows = json.loads((tmp_path / run_name / stem / "results.json").read_text())["results"]
            errors[run_name, stem] = [(r["method"], r["params"], r["nrmse"]) for r in rows if r["method"] != "mitsuba"]
            assert (tmp_path / run_name / stem / "report.md").is_file()
    for stem in ("a", "b"):
        assert [(m, p) for m, p, _ in errors["farm", stem]] == [(m, p) for m, p, _ in errors["serial", stem]]
        for (_, _, f), (_, _, s) in zip(errors["farm", stem], errors["serial", stem]):
            assert f == pytest.approx(s, rel=1e-6, abs=1e-9)
    assert errors["farm", "a"] != errors["farm", "b"]   # two scenes, not one twice
    text = readme.read_text()
    assert "| a | 24x18 |" in text and "| b | 24x18 |" in text


@pytest.mark.parametrize("extra,message", [
    (["--workers", "0"], "--workers 0 must be >= 1"),
    (["--workers", "2", "--scheduler", "tcp://127.0.0.1:1"], "not both"),
])
def test_cli_bench_cluster_argument_errors(tmp_path, capsys, extra, message):
    assert main(["bench", str(SHAPES), "--out", str(tmp_path / "o"), "--no-rays", *extra]) == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_cli_bench_two_scenes_of_one_name_refused(tmp_path, capsys):
    (tmp_path / "x").mkdir()
    (tmp_path / "x" / "shapes_sky.toml").write_text(SHAPES.read_text())
    assert main(["bench", str(SHAPES), str(tmp_path / "x" / "shapes_sky.toml"), "--out", str(tmp_path / "o"),
                 "--no-rays"]) == 2
    assert "same name" in capsys.readouterr().err
