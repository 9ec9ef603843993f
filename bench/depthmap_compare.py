"""depthmap against fiv and isg on one shared scene, and depthmap's
skip_power, in one run (docs/depthmap.md "Against fiv and isg" and
"Skipping weak domains"):

  the bunny on a floor (bench/scenes/bunny_sunny.toml: the 3k bunny, an 8 m
  plane) at a small size, under a light probe (Uffizi) and under the scene's
  own sunny map; every method's NRMSE against `reference` (face 64, sun split
  4 x 4, background excluded), its frame time (G-buffer + shading, median of
  5 after warm-up, penumbra.render) and its precomputation (fiv's bake,
  isg's sphere sets); then depthmap by skip_power: error, frame time, maps
  drawn.

  python bench/depthmap_compare.py [--size 64x48] [--out bench/results/depthmap_compare]

Uses bench/harness.py (reference cache, metrics, machine record, log).
Writes results.json and report.md into --out; references and bakes are
cached in --out/cache/ (ignored by git).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import harness  # noqa: E402
from harness import REPO, ReferenceCache, log, machine, metrics  # noqa: E402

from penumbra import Context, GBuffer, Image, Renderer  # noqa: E402
from penumbra import methods as registry  # noqa: E402
from penumbra.fileutil import atomic_write_text  # noqa: E402
from penumbra.methods import depthmap as dm  # noqa: E402
from penumbra.render import build_scene, render  # noqa: E402
from penumbra.scenefile import load_scene  # noqa: E402

SCENE = REPO / "bench" / "scenes" / "bunny_sunny.toml"
MAPS = {"uffizi": "data:envmaps/uffizi_probulator_256x128.hdr", "sunny": None}  # None: the scene's own map
METHODS = [("unshadowed", {}), ("fiv", {"samples": [32, 17, 15]}), ("fiv", {"samples": [64, 33, 30]}),
           ("isg", {}), ("isg", {"spheres": 128, "lobes": 64, "patch_grid": 20}),
           ("depthmap", {"directions": 16, "resolution": 128}), ("depthmap", {}),
           ("depthmap", {"directions": 128, "resolution": 512})]
SKIP = (0.0, 0.003, 0.01, 0.03, 0.1, 0.3)


def load_avg() -> str:
    return " / ".join(f"{x:.1f}" for x in os.getloadavg())


def skip_rows(name, built, truth, mask, rounds=7) -> list[dict]:
    """depthmap by skip_power at its other defaults: maps drawn, NRMSE, and
    the frame's time (maps + shading) and the shading alone (reuse_maps 1)
    in interleaved rounds (every setting once per round, medians over the
    rounds), so that the machine's load drifts over all settings alike."""
    ctx = built.ctx
    w, h = built.camera.resolution
    gb = GBuffer(ctx, w, h)
    built.scene.render_gbuffer(gb)
    img = Image(ctx, w, h)
    rs = {sp: Renderer(ctx, "depthmap", skip_power=sp, background=0) for sp in SKIP}
    rows = {}
    for sp, r in rs.items():
        r.execute(built.scene, gb, img)  # plan: the decomposition, the buffers
        rows[sp] = {"map": name, "skip_power": sp, "maps": dm.maps_drawn(r, built.scene),
                    **metrics(truth, img.read()[..., :3], mask, ("nrmse",)), "frame": [], "shading": []}
    for _ in range(rounds):
        for sp, r in rs.items():
            for key, reuse in (("frame", 0), ("shading", 1)):
                r.set(reuse_maps=reuse)
                ms, _ = harness.median_ms(lambda: r.execute(built.scene, gb, img), 1, ctx.finish)
                rows[sp][key].append(ms)
    out = []
    for sp, row in rows.items():
        f, sh = float(np.median(row.pop("frame"))), float(np.median(row.pop("shading")))
        row.update(frame_ms=f, shading_ms=sh, maps_ms=max(f - sh, 0.0), load=load_avg())
        out.append(row)
        log(json.dumps(row))
    return out


def half_rows(name, built, truth, mask, rounds=15) -> list[dict]:
    """half_maps 0 / 1 at the other defaults: NRMSE against the reference
    and the largest change between the two images at this size; the shading
    alone (reuse_maps 1) at this size and at 4x and 8x the side (the lookups' cost
    grows with the pixels), in interleaved rounds."""
    ctx = built.ctx
    w, h = built.camera.resolution
    out = []
    imgs = {}
    for scale in (1, 4, 8):
        gb = GBuffer(ctx, w * scale, h * scale)
        if scale != 1:
            built.scene.set_camera(dataclasses.replace(built.camera, resolution=(w * scale, h * scale)))
        built.scene.render_gbuffer(gb)
        img = Image(ctx, w * scale, h * scale)
        rs = {half: Renderer(ctx, "depthmap", half_maps=half, background=0) for half in (0, 1)}
        times = {half: [] for half in rs}
        for half, r in rs.items():
            r.execute(built.scene, gb, img)
            if scale == 1:
                imgs[half] = img.read()[..., :3]
            r.set(reuse_maps=1)
        for _ in range(rounds):
            for half, r in rs.items():
                ms, _ = harness.median_ms(lambda: r.execute(built.scene, gb, img), 1, ctx.finish)
                times[half].append(ms)
        for half in rs:
            row = {"map": name, "half_maps": half, "size": f"{w * scale}x{h * scale}",
                   "shading_ms": float(np.median(times[half])), "load": load_avg()}
            if scale == 1:
                row.update(metrics(truth, imgs[half], mask, ("nrmse",)),
                           max_change=float(np.abs(imgs[half] - imgs[0])[mask].max()))
            out.append(row)
            log(json.dumps(row))
        if scale != 1:
            built.scene.set_camera(built.camera)
    return out


def run_map(name: str, env: str | None, size: tuple[int, int], cache: Path, parts=("methods", "skip")) -> dict:
    over = [f"camera.resolution=[{size[0]},{size[1]}]"]
    if env:
        over.append(f'environment.map="{env}"')
    desc = load_scene(SCENE, over)
    for technique in registry.techniques():
        technique.use_cache_folder(desc, cache)
    ctx = Context()
    built = build_scene(desc, ctx)
    t0 = time.perf_counter()
    refs = ReferenceCache(cache)
    truth, ref_s = refs.get({"scene": str(SCENE), "over": over, "face": 64, "sun": 4},
                            lambda: render(built, "reference", frames=1, warmup=False, face_size=64,
                                           sun_supersampling=4, background=0).image[..., :3])
    log(f"{name}: reference {ref_s:.1f} s ({time.perf_counter() - t0:.1f} s now), load {load_avg()}")
    floor = render(built, "floor", frames=5)
    mask = floor.gbuffer["instance"] != 0xFFFFFFFF
    rows = []
    for method, params in (METHODS if "methods" in parts else []):
        res = render(built, method, frames=5, background=0, **params)
        m = metrics(truth, res.image[..., :3], mask, ("nrmse", "rel_rms", "max_abs"))
        row = {"map": name, "method": method, "params": params, "frame_ms": res.timings_ms["frame_median"],
               "shade_ms": res.timings_ms["shade_median"], "prepare_s": res.prepare_s, **m, "load": load_avg()}
        rows.append(row)
        log(json.dumps(row))
    skip = skip_rows(name, built, truth, mask) if "skip" in parts else []
    half = half_rows(name, built, truth, mask) if "half" in parts else []
    return {"pixels": int(mask.sum()), "reference_s": ref_s, "floor_ms": floor.timings_ms["shade_median"],
            "rows": rows, "skip": skip, "half": half}


def fmt(p: dict) -> str:
    return harness.fmt_params({k: ("x".join(map(str, v)) if isinstance(v, list) else v) for k, v in p.items()})


def report(res: dict) -> str:
    meta = res["meta"]
    out = [f"# depthmap against fiv and isg; skip_power\n",
           f"Generated by `bench/depthmap_compare.py` on {meta['date']}: {meta['machine']['cpu']}, "
           f"{meta['machine']['cores']} cores, PoCL, git {meta['machine']['git_head']}; load average at start "
           f"{meta['load_start']}, at end {meta['load_end']} (shared machine). Scene: the 3k bunny on an 8 m floor "
           f"(bench/scenes/bunny_sunny.toml) at {meta['size']}; NRMSE against `reference` (face 64, sun 4 x 4) over "
           "the non-background pixels; frame = G-buffer + shading, median of 5 after warm-up; prepare = bake / "
           "sphere-set build (0 when cached).\n"]
    for name, r in res["maps"].items():
        out.append(f"\n## {name} ({r['pixels']} pixels, reference {r['reference_s']:.1f} s)\n")
        out.append("| method | params | NRMSE | rel. RMS | frame ms | prepare s | load |")
        out.append("|---|---|---|---|---|---|---|")
        for row in r["rows"]:
            prep = f"{row['prepare_s']:.2f}"
            if "prepare_s_uncached" in row:  # this run loaded the bake from the cache
                prep += f" (cached; baked in {row['prepare_s_uncached']:.1f})"
            out.append(f"| {row['method']} | {fmt(row['params'])} | {row['nrmse']:.4f} | {row['rel_rms']:.4f} | "
                       f"{row['frame_ms']:.1f} | {prep} | {row['load']} |")
        if r.get("half"):
            out.append("\nhalf_maps (other parameters at their defaults; shading alone, reuse_maps 1, medians of 15 "
                       "interleaved rounds; max change: largest |image - the 32-bit image| over the pixels):\n")
            out.append("| half_maps | size | NRMSE | max change | shading ms | load |")
            out.append("|---|---|---|---|---|---|")
            for row in r["half"]:
                err = f"{row['nrmse']:.5f} | {row['max_change']:.2g}" if "nrmse" in row else "- | -"
                out.append(f"| {row['half_maps']} | {row['size']} | {err} | {row['shading_ms']:.1f} | {row['load']} |")
        if not r["skip"]:
            continue
        out.append("\nskip_power (other parameters at their defaults; times: medians of 7 interleaved rounds; maps = "
                   "frame - shading with reuse_maps 1):\n")
        out.append("| skip_power | maps drawn | NRMSE | frame ms | maps ms | shading ms | load |")
        out.append("|---|---|---|---|---|---|---|")
        for row in r["skip"]:
            out.append(f"| {row['skip_power']:g} | {row['maps']} | {row['nrmse']:.4f} | {row['frame_ms']:.1f} | "
                       f"{row['maps_ms']:.1f} | {row['shading_ms']:.1f} | {row['load']} |")
    return "\n".join(out) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--size", default="64x48")
    ap.add_argument("--maps", default=",".join(MAPS))
    ap.add_argument("--only", default="methods,skip,half",
                    help="methods (the comparison), skip (skip_power), half (half_maps)")
    ap.add_argument("--out", default=str(REPO / "bench" / "results" / "depthmap_compare"))
    args = ap.parse_args(argv)
    size = tuple(int(x) for x in args.size.split("x"))
    out = Path(args.out)
    (out / "cache").mkdir(parents=True, exist_ok=True)
    (out / ".gitignore").write_text("cache/\n")
    parts = tuple(args.only.split(","))
    old = json.loads((out / "results.json").read_text()) if (out / "results.json").is_file() else None
    res = {"meta": {"date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()), "machine": machine(),
                    "size": f"{size[0]} x {size[1]}", "load_start": load_avg()}, "maps": {}}
    for name in args.maps.split(","):
        res["maps"][name] = run_map(name, MAPS[name], size, out / "cache", parts)
        if old and name in old["maps"]:  # keep the parts not rerun
            for part, key in (("methods", "rows"), ("skip", "skip"), ("half", "half")):
                if part not in parts:
                    res["maps"][name][key] = old["maps"][name].get(key, [])
            # A bake loaded from the cache: keep the time it took when it was made.
            before = {(r["method"], json.dumps(r["params"])): r for r in old["maps"][name].get("rows", [])}
            for row in res["maps"][name]["rows"]:
                prev = before.get((row["method"], json.dumps(row["params"])))
                if prev and row["prepare_s"] < 0.5 and prev["prepare_s"] >= 1.0:
                    row["prepare_s_uncached"] = prev.get("prepare_s_uncached", prev["prepare_s"])
        res["meta"]["load_end"] = load_avg()
        atomic_write_text(out / "results.json", json.dumps(res, indent=1, default=str))
        atomic_write_text(out / "report.md", report(res))
    return 0


if __name__ == "__main__":
    sys.exit(main())
