"""depthmap against Mitsuba 3 at equal error, settings and Mitsuba interleaved (docs/depthmap.md, "Against Mitsuba 3").

`penumbra bench` times every setting and then Mitsuba's spp one after the other, so on a shared machine the
load moves between them (single rows by 2-5x, docs/depthmap.md). Here each round runs every depthmap setting
(one frame: G-buffer + maps + shading, as the bench times a frame) and then Mitsuba 3 (llvm_ad_rgb, `direct`,
the bench's renderer) at every spp, so the load hits both alike. Errors against the bench's ground truth
(reference, face 64, sun 4x4; cached in --cache, the bench's cache folder of the scene when given); Mitsuba's
error from its first round's image per spp. Reports per setting: median frame ms over the rounds, NRMSE,
Mitsuba's time at that error (log-log interpolated along its median curve, penumbra.bench._mitsuba_time_at)
and the speed-up, plus the speed-up's range over the rounds (each round's own Mitsuba curve against that
round's frame).

  python bench/depthmap_vs_mitsuba.py SCENE.toml --out DIR [--rounds 5] [--spp 16,64,256,1024]
        [--grid '{"directions": 32, "resolution": 32, "strong_resolution": 128};{}']
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

import penumbra  # noqa: F401
from penumbra import Context, GBuffer, Image, Renderer
from penumbra import mitsuba as mi_bridge
from penumbra.bench import BenchOptions, _mitsuba_time_at, ground_truth
from penumbra.fileutil import atomic_write_text
from penumbra.metrics import compare
from penumbra.render import build_scene
from penumbra.scenefile import load_scene

DEFAULT_GRID = ('{"directions": 8, "resolution": 16, "strong_resolution": 64};'
                '{"directions": 16, "resolution": 16, "strong_resolution": 64};'
                '{"directions": 32, "resolution": 32, "strong_resolution": 128, "sharp": 0};'
                '{"directions": 32, "resolution": 32, "strong_resolution": 128, "grade": 0.0, "sharp": 0};'
                '{"directions": 32, "resolution": 32, "strong_resolution": 128};'
                '{"directions": 64, "resolution": 64};{"sharp": 0};{}')


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scene")
    ap.add_argument("--out", required=True)
    ap.add_argument("--cache", default=None, help="folder of the cached ground truth (default OUT/cache)")
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--spp", default="16,64,256,1024")
    ap.add_argument("--grid", default=DEFAULT_GRID, help="';'-separated JSON objects of depthmap parameters")
    ap.add_argument("--cpu", action="store_true",
                    help="time both by the process's CPU time (all its threads: PoCL's and Mitsuba's) instead of "
                         "wall time, for a loaded machine")
    args = ap.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    settings = [json.loads(p) for p in args.grid.split(";") if p.strip()]
    spps = [int(s) for s in args.spp.split(",")]
    desc = load_scene(args.scene)
    ctx = Context()
    built = build_scene(desc, ctx)
    load0 = os.getloadavg()
    truth = ground_truth(built, desc, BenchOptions(), Path(args.cache) if args.cache else out / "cache", print)
    w, h = desc.camera.resolution
    gb, img = GBuffer(ctx, w, h), Image(ctx, w, h)
    built.scene.render_gbuffer(gb)
    mask = gb.read("instance") != 0xFFFFFFFF
    ctx.build("raycast")
    renderers = [Renderer(ctx, "depthmap", background=0, **p) for p in settings]
    errs = []
    for r in renderers:  # plan, kernel builds, first maps
        r.execute(built.scene, gb, img)
        ctx.finish()
        errs.append(compare(truth, img.read()[..., :3], mask)["nrmse"])
    mit = mi_bridge.PixelCentreRenderer(desc, variant=mi_bridge.select_variant(None))
    mit.render(min(spps), seed=0)
    m_err = []
    for spp in spps:
        image, _ = mit.render_timed(spp, seed=spp)
        m_err.append(compare(truth, image, mask)["nrmse"])
    clock = time.process_time if args.cpu else time.perf_counter
    ft = [[] for _ in settings]
    mt = [[] for _ in spps]
    for k in range(args.rounds + 1):  # round 0 warms up
        for i, r in enumerate(renderers):
            t0 = clock()
            built.scene.render_gbuffer(gb)
            r.execute(built.scene, gb, img)
            ctx.finish()
            if k:
                ft[i].append(1000.0 * (clock() - t0))
        for j, spp in enumerate(spps):
            t0 = clock()
            _, sec = mit.render_timed(spp, seed=spp + 7919 * k)
            if args.cpu:
                sec = clock() - t0
            if k:
                mt[j].append(1000.0 * sec)
        print(f"round {k}: load {os.getloadavg()[0]:.1f}", flush=True)
    curve = [{"nrmse": e, "time_ms": float(np.median(t))} for e, t in zip(m_err, mt)]
    rows = []
    for p, e, t in zip(settings, errs, ft):
        mt_at, bound = _mitsuba_time_at(curve, e)
        per_round = []
        for k in range(args.rounds):
            c = [{"nrmse": me, "time_ms": mt[j][k]} for j, me in enumerate(m_err)]
            per_round.append(_mitsuba_time_at(c, e)[0] / t[k])
        row = dict(params=p, nrmse=e, frame_ms=float(np.median(t)), mitsuba_ms=mt_at, bound=bound,
                   speedup=mt_at / float(np.median(t)), speedup_rounds=[min(per_round), max(per_round)])
        rows.append(row)
        print(json.dumps(row), flush=True)
    summary = dict(scene=args.scene, rounds=args.rounds, clock="process CPU time" if args.cpu else "wall", mitsuba=[dict(spp=s, nrmse=e, time_ms=c["time_ms"])
                                                                  for s, e, c in zip(spps, m_err, curve)],
                   rows=rows, load_start=load0, load_end=os.getloadavg(), date=time.strftime("%Y-%m-%d %H:%M UTC",
                                                                                            time.gmtime()))
    atomic_write_text(out / "results.json", json.dumps(summary, indent=1))
    lines = [f"# depthmap against Mitsuba, interleaved: {args.scene}", "",
             f"{summary['date']}, {args.rounds} rounds, {summary['clock']}, load {load0[0]:.1f} at the start, "
             f"{summary['load_end'][0]:.1f} at the end.", "", "| spp | NRMSE | ms (median) |", "|---|---|---|"]
    lines += [f"| {m['spp']} | {m['nrmse']:.4f} | {m['time_ms']:.0f} |" for m in summary["mitsuba"]]
    lines += ["", "| setting | frame ms | NRMSE | Mitsuba ms at that error | speed-up | over the rounds |",
              "|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {json.dumps(r['params'])} | {r['frame_ms']:.1f} | {r['nrmse']:.4f} | {r['mitsuba_ms']:.0f} | "
                     f"{r['bound']}{r['speedup']:.1f}x | {r['speedup_rounds'][0]:.1f}-{r['speedup_rounds'][1]:.1f}x |")
    atomic_write_text(out / "report.md", "\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
