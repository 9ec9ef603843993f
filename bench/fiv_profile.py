"""Where `fiv`'s shading time goes, phase by phase (docs/performance.md, FIV).

The kernel is built three times (build option PN_FIV_PROFILE, kernels/fiv.cl):
0 = all, 1 = no lookup (the occluder loop, its culling tests and the sum of a
constant field), 2 = the lookup's angles, logarithm, per-direction culling
test and weights but no sample fetched. With the floor kernel, unshadowed
(with and without the env-map background pass, which every method with the
`background` parameter runs after its kernel and the floor kernel does not;
the other variants leave it out) and fiv's own switches (overlap, trilinear,
tile_cull) every phase is a difference of two times; all variants
run round-robin on one G-buffer per build (the load of a shared machine hits
them alike); the phases come from the fastest round of each variant after
a warm-up round (the least disturbed on a shared machine), the medians are
reported beside them.

    .venv/bin/python bench/fiv_profile.py [--counts 1,60] [--resolution 512] [--rounds 7]

Prints a table and writes bench/results/fiv_profile/results.json. Op counts
per lookup are counted from the kernel's source (PHASE_OPS), not measured.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import time
from pathlib import Path

from penumbra import data as test_data
from penumbra.bench import scene_toml
from penumbra.core import Context, GBuffer, Image, Renderer
from penumbra.methods.fiv import (SCALING_ENV, SCALING_MESH, attach_fields, fiv_scaling_scene, occluder_bounds,
                                  tile_occluder_counts)
from penumbra.render import build_scene
from penumbra.scenefile import load_scene

# (build, method, params): the timed variants. All but "background" leave
# the env-map background pass out (background = 0): the floor kernel draws
# none, and it is its own phase.
NO_BG = {"background": 0}
VARIANTS = {
    "floor": (0, "floor", {}),
    "unshadowed": (0, "unshadowed", NO_BG),
    "background": (0, "unshadowed", {}),
    "loop": (1, "fiv", {"overlap": 0, **NO_BG}),
    "indices": (2, "fiv", {"overlap": 0, **NO_BG}),
    "nearest": (0, "fiv", {"overlap": 0, "trilinear": 0, **NO_BG}),
    "sum": (0, "fiv", {"overlap": 0, **NO_BG}),
    "fiv": (0, "fiv", NO_BG),
    "unculled": (0, "fiv", {"tile_cull": 0, **NO_BG}),
}
# Phase = later variant minus earlier one.
PHASES = [("G-buffer read, image write (floor)", None, "floor"),
          ("env-map background pass (unshadowed with - without it)", "unshadowed", "background"),
          ("irradiance cube lookup (unshadowed - floor)", "floor", "unshadowed"),
          ("occluder loop: masks, case C and distance tests, sum (loop - unshadowed)", "unshadowed", "loop"),
          ("lookup indices: 2 atan2, ln, weights, per-direction cull (indices - loop)", "loop", "indices"),
          ("sample fetch + trilinear, 8 taps (sum - indices)", "indices", "sum"),
          ("  of which 7 of the 8 taps (sum - nearest)", "nearest", "sum"),
          ("overlap correction, disc pairs (fiv - sum)", "sum", "fiv"),
          ("tile binning saved (unculled - fiv)", "fiv", "unculled")]
# Floating-point operations per lookup, counted from kernels/fiv.cl (an atan2
# = 20: divide, 7-term polynomial, fix-ups; a log = 20; a sqrt or divide = 1).
PHASE_OPS = {"loop": 14 + 24, "indices": 92, "sum": 183}
# Bytes per lookup read from the field: 8 samples x 9 floats (float32 on the device).
FETCH_BYTES = 8 * 9 * 4
# Bytes per pixel to and from memory: position, normal, albedo (float4),
# instance id (uint), image (float4).
PIXEL_BYTES = 16 * 3 + 4 + 16


def interleaved(builds: dict, rounds: int) -> dict:
    """builds: build -> (built scene, G-buffer). Median ms per variant."""
    rs = {k: (builds[b], Renderer(builds[b][0].ctx, m, **kw)) for k, (b, m, kw) in VARIANTS.items()}
    images = {b: Image(built.ctx, gb.width, gb.height) for b, (built, gb) in builds.items()}
    times = {k: [] for k in rs}
    for r in range(rounds + 1):
        for k, ((built, gb), renderer) in rs.items():
            img = images[VARIANTS[k][0]]
            t0 = time.perf_counter()
            renderer.execute(built.scene, gb, img)
            built.ctx.finish()
            if r:
                times[k].append(1e3 * (time.perf_counter() - t0))
    return {k: statistics.median(t) for k, t in times.items()}, {k: min(t) for k, t in times.items()}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--counts", default="1,60")
    ap.add_argument("--resolution", type=int, default=512)
    ap.add_argument("--rounds", type=int, default=7)
    ap.add_argument("--samples", default="128,65,30")
    ap.add_argument("--out", default="bench/results/fiv_profile")
    args = ap.parse_args()
    out = Path(args.out)
    (out / "scenes").mkdir(parents=True, exist_ok=True)
    data = test_data.data_dir()
    samples = tuple(int(x) for x in args.samples.split(","))
    ctxs = {b: Context(f"build_options=-DPN_FIV_PROFILE={b}") for b in (0, 1, 2)}
    results = []
    for n in (int(x) for x in args.counts.split(",")):
        path = out / "scenes" / f"bunnies_{n}.toml"
        def rel(q: Path) -> str:  # paths relative to the scene file, as penumbra bench writes them
            return Path(os.path.relpath(q.resolve(), (out / "scenes").resolve())).as_posix()

        # The field cache of penumbra bench --fiv-scaling: one bake serves both.
        path.write_text(scene_toml(fiv_scaling_scene(n, rel(data / SCALING_MESH), rel(data / SCALING_ENV),
                                                     args.resolution, samples,
                                                     cache=rel(out.parent / "fiv_scaling" / "cache" / "fiv")),
                                   f"fiv phase profile: {n} bunnies (bench/fiv_profile.py)"))
        builds = {}
        for b, ctx in ctxs.items():
            built = build_scene(load_scene(path), ctx)
            attach_fields(built)
            gb = GBuffer(ctx, args.resolution, args.resolution)
            built.scene.render_gbuffer(gb)
            ctx.finish()
            builds[b] = (built, gb)
        built0, gb0 = builds[0]
        planes = {p: gb0.read(p) for p in ("position", "normal", "instance")}
        bins = tile_occluder_counts(planes, occluder_bounds(built0), args.resolution)
        load = os.getloadavg()[0]
        # Phases from the fastest round of each variant: on a loaded machine
        # the least disturbed one (the medians are kept beside them).
        medians, ms = interleaved(builds, args.rounds)
        lookups = bins["lookups_per_pixel"] * bins["receiver_pixels"]
        pixels = args.resolution ** 2
        rows = []
        for name, a, b in PHASES:
            dt = ms[b] - (ms[a] if a else 0.0)
            row = {"phase": name, "ms": dt, "ns_per_lookup": dt * 1e6 / lookups if lookups else None}
            if b in PHASE_OPS and a != "nearest" and lookups and dt > 0:
                row["flops_per_lookup"] = PHASE_OPS[b]
                row["gflops"] = PHASE_OPS[b] * lookups / (dt * 1e6)
            if b == "sum" and a == "indices" and dt > 0:
                row["bytes_per_lookup"] = FETCH_BYTES
                row["gbytes_per_s"] = FETCH_BYTES * lookups / (dt * 1e6)
            if b == "floor":
                row["gbytes_per_s"] = PIXEL_BYTES * pixels / (dt * 1e6)
            rows.append(row)
        res = {"occluders": n, "resolution": args.resolution, "load_average_1min": [round(load, 2),
                                                                                     round(os.getloadavg()[0], 2)],
               "lookups_per_pixel": bins["lookups_per_pixel"], "receiver_pixels": bins["receiver_pixels"],
               "per_tile_mean": bins["per_tile_mean"], "variants_min_ms": ms, "variants_median_ms": medians,
               "phases": rows}
        results.append(res)
        print(f"\n{n} occluders, {args.resolution}^2, {bins['lookups_per_pixel']:.2f} lookups per receiver pixel "
              f"({bins['receiver_pixels']} receivers), load {res['load_average_1min']}")
        print("  variants ms (min): " + ", ".join(f"{k} {v:.2f}" for k, v in ms.items()))
        print("  variants ms (median): " + ", ".join(f"{k} {v:.2f}" for k, v in medians.items()))
        for r in rows:
            extra = "".join(f", {k} {v:.3g}" for k, v in r.items() if k not in ("phase", "ms", "ns_per_lookup"))
            nsl = f"{r['ns_per_lookup']:.2f} ns/lookup" if r["ns_per_lookup"] is not None else ""
            print(f"  {r['phase']:<78} {r['ms']:8.2f} ms  {nsl}{extra}")
    (out / "results.json").write_text(json.dumps({"device": ctxs[0].device_name, "cpus": os.cpu_count(),
                                                  "date": time.strftime("%Y-%m-%d %H:%M"), "results": results},
                                                 indent=2) + "\n")


if __name__ == "__main__":
    main()
