#!/usr/bin/env python3
"""Time against error of the `isg` LOD cut (`lod`, docs/isg.md section 8) on the
sunny bunny (`bench/scenes/bunny_sunny.toml`) and the 36-occluder scene of
bench/isg_experiments.py (`many_scene`), to choose its default by measurement.
Ground truth: `reference` at face_size 64, sun_supersampling 4. Errors: relative
RMS over the surface pixels, against the reference and against lod 0 (the exact
walk). Time: the process's CPU ms of one shading frame (PoCL's threads included),
median of `--frames` interleaved rounds that each run every lod once, after a
warm-up round; wall ms beside it, and the ratio to lod 0 in the same rounds.

    python bench/isg_lod.py [--res 64x48] [--frames 5] [--lods 0,0.5,1,2,3,4] [--spheres 64] [--scenes bunny,many]
"""

from __future__ import annotations

import argparse
import copy
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import harness  # noqa: E402
from isg_experiments import many_scene  # noqa: E402

from penumbra import Context, GBuffer, Image, Renderer  # noqa: E402
from penumbra.methods.isg import attach_sphere_sets  # noqa: E402
from penumbra.render import build_scene, render  # noqa: E402
from penumbra.scenefile import load_scene, parse_scene  # noqa: E402


def scenes(res):
    yield "bunny_sunny (diffuse)", load_scene(harness.REPO / "bench" / "scenes" / "bunny_sunny.toml",
                                              [f"camera.resolution=[{res[0]},{res[1]}]"])
    yield "36 occluders (Pisa)", parse_scene(copy.deepcopy(many_scene(res)), ".")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--res", default="64x48")
    ap.add_argument("--frames", type=int, default=5)
    ap.add_argument("--lods", default="0,0.5,1,2,3,4")
    ap.add_argument("--spheres", type=int, default=64)
    ap.add_argument("--patch-grid", type=int, default=16)
    ap.add_argument("--scenes", default="bunny,many", help="bunny, many or both")
    a = ap.parse_args()
    ctx = Context()
    res = [int(x) for x in a.res.split("x")]
    lods = [float(x) for x in a.lods.split(",")]
    print(f"load: {os.getloadavg()[0]:.1f} (1-min average) at the start")
    for name, desc in scenes(res):
        if name.split()[0].split("_")[0] not in a.scenes.replace("many", "36").split(","):
            continue
        built = build_scene(desc, ctx)
        attach_sphere_sets(built, {"spheres": a.spheres})
        gb = GBuffer(ctx, *res)
        built.scene.render_gbuffer(gb)
        mask = gb.read("instance") != 0xFFFFFFFF
        ref = render(built, "reference", frames=1, warmup=False, face_size=64, sun_supersampling=4).image[..., :3]
        runs = {lod: (Renderer(ctx, "isg", lod=lod, patch_grid=a.patch_grid), Image(ctx, *res), []) for lod in lods}
        for rnd in range(a.frames + 1):
            for lod in lods:
                r, img, times = runs[lod]
                t0, c0 = time.perf_counter(), time.process_time()
                r.execute(built.scene, gb, img)
                ctx.finish()
                if rnd:
                    times.append((1e3 * (time.process_time() - c0), 1e3 * (time.perf_counter() - t0)))
        exact = runs[lods[0]][1].read()[..., :3]
        base = np.array([t[0] for t in runs[lods[0]][2]])
        print(f"\n{name}, {res[0]} x {res[1]}, N = {a.spheres} spheres per occluder mesh, M = {a.patch_grid}, "
              f"{int(mask.sum())} surface pixels; load {os.getloadavg()[0]:.1f} at the end (loaded)\n")
        print(f"| lod | CPU ms | wall ms | CPU / lod {lods[0]:g} (median of per-round ratios) | rel RMS vs reference "
              f"| rel RMS vs lod {lods[0]:g} |")
        print("|---|---|---|---|---|---|")
        for lod in lods:
            r, img, times = runs[lod]
            got = img.read()[..., :3]
            e_ref = harness.metrics(ref, got, mask, ("rel_rms",))["rel_rms"]
            e_exact = harness.metrics(exact, got, mask, ("rel_rms",))["rel_rms"]
            cpu = np.array([t[0] for t in times])
            print(f"| {lod:g} | {np.median(cpu):.0f} | {np.median([t[1] for t in times]):.0f} | "
                  f"{np.median(cpu / base):.2f} | {100 * e_ref:.2f} % | {100 * e_exact:.3f} % |")
        print(flush=True)


if __name__ == "__main__":
    main()
