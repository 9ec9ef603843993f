#!/usr/bin/env python3
"""Time against error of the `isg` knobs (K lobes, M patch grid, N spheres) on
two bunny scenes, to choose the defaults by measurement (docs/isg.md section 9):
the diffuse `bench/scenes/bunny_sunny.toml` and the seed's Fig. 12 bunny
(Phong glossiness 1000, k_s = 0.5 on bunny and floor; bench/isg_experiments.py).
Ground truth: `reference` at face_size 64, sun_supersampling 4. Errors: relative
RMS over the surface pixels. Time: the process's CPU ms of one shading frame
(Renderer.execute; PoCL's threads included: the measure least moved by the
other users of a shared machine), median of `--frames` rounds that each run
every setting once, after a warm-up round; wall ms beside it.

    python bench/isg_sweep.py [--res 64x48] [--frames 3] [--lobes 8,16,32] [--grids 8,12,16] [--spheres 32,64,128]
"""

from __future__ import annotations

import argparse
import copy
import itertools
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import harness  # noqa: E402
from isg_experiments import bunny_scene  # noqa: E402

from penumbra import GBuffer, Image, Renderer  # noqa: E402
from penumbra.methods.isg import attach_sphere_sets  # noqa: E402
from penumbra.render import build_scene, render  # noqa: E402
from penumbra.scenefile import load_scene, parse_scene  # noqa: E402


def scenes(res):
    sunny = load_scene(harness.REPO / "bench" / "scenes" / "bunny_sunny.toml",
                       [f"camera.resolution=[{res[0]},{res[1]}]"])
    yield "bunny_sunny (diffuse)", sunny
    yield "Fig. 12 (Phong 1000, k_s 0.5)", parse_scene(copy.deepcopy(bunny_scene(res, 0.5, 0.5)), ".")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--res", default="64x48")
    ap.add_argument("--frames", type=int, default=3)
    ap.add_argument("--lobes", default="8,16,32")
    ap.add_argument("--grids", default="8,12,16")
    ap.add_argument("--spheres", default="32,64,128")
    a = ap.parse_args()
    from penumbra import Context
    ctx = Context()
    res = [int(x) for x in a.res.split("x")]
    ints = lambda s: [int(x) for x in s.split(",")]  # noqa: E731
    print(f"load: {os.getloadavg()[0]:.1f} (1-min average) at the start")
    for name, desc in scenes(res):
        builts = {}
        for n in ints(a.spheres):  # one scene per N: its own sphere sets attached
            built = build_scene(desc, ctx)
            attach_sphere_sets(built, {"spheres": n})
            gb = GBuffer(ctx, *res)
            built.scene.render_gbuffer(gb)
            builts[n] = (built, gb)
        built0 = builts[ints(a.spheres)[0]][0]
        ref = render(built0, "reference", frames=1, warmup=False, face_size=64, sun_supersampling=4).image[..., :3]
        floor = render(built0, "floor", frames=5).timings_ms["shade_median"]
        mask = builts[ints(a.spheres)[0]][1].read("instance") != 0xFFFFFFFF
        settings = list(itertools.product(ints(a.lobes), ints(a.grids), ints(a.spheres)))
        runs = {}
        for k, m, n in settings:
            built, gb = builts[n]
            runs[k, m, n] = (Renderer(ctx, "isg", lobes=k, patch_grid=m), Image(ctx, *res), [])
        for rnd in range(a.frames + 1):
            for key in settings:
                r, img, times = runs[key]
                built, gb = builts[key[2]]
                t0, c0 = time.perf_counter(), time.process_time()
                r.execute(built.scene, gb, img)
                ctx.finish()
                if rnd:
                    times.append((1e3 * (time.process_time() - c0), 1e3 * (time.perf_counter() - t0)))
        rows = []
        for key in settings:
            r, img, times = runs[key]
            e = harness.metrics(ref, img.read()[..., :3], mask, ("rel_rms",))["rel_rms"]
            rows.append((*key, float(np.median([t[0] for t in times])), float(np.median([t[1] for t in times])), e))
        u = render(built0, "unshadowed", frames=5)
        ue = harness.metrics(ref, u.image[..., :3], mask, ("rel_rms",))["rel_rms"]
        print(f"\n{name}, {res[0]} x {res[1]}, {int(mask.sum())} surface pixels; floor {floor:.3f} ms; "
              f"unshadowed rel RMS {100 * ue:.2f} %; load {os.getloadavg()[0]:.1f} at the end\n")
        print("| K | M | N | CPU ms | wall ms | rel RMS | on the Pareto front (CPU ms, error) |")
        print("|---|---|---|---|---|---|---|")
        for row in sorted(rows, key=lambda x: x[3]):
            front = not any(o[3] <= row[3] and o[5] < row[5] for o in rows if o is not row)
            print(f"| {row[0]} | {row[1]} | {row[2]} | {row[3]:.0f} | {row[4]:.0f} | {100 * row[5]:.2f} % | "
                  f"{'yes' if front else ''} |")
        print(flush=True)


if __name__ == "__main__":
    main()
