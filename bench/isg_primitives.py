#!/usr/bin/env python3
"""Time against error of `[isg] exact_primitives` and `shared_light` (docs/isg.md
section 9, "exact primitives and the env's irradiance"), and where a frame's
time goes, on bench/scenes/indoor_contact.toml, bunny_sunny.toml and
teapot_overcast.toml. Ground truth: `reference` at face_size 64, sun
supersampling 4; errors over the surface pixels (relative RMS, NRMSE, bias:
mean error over the truth's range). Time: the process's CPU ms of one shading
frame (PoCL's threads included), median of `--rounds` interleaved rounds after
a warm-up round; the ratio is the median of per-round ratios of the first
setting ("main": exact_primitives off, shared_light 0) to each.

    python bench/isg_primitives.py [--res 64x48] [--rounds 7] [--scenes ...] [--profile]
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import harness  # noqa: E402
from isg_shared import scene_desc  # noqa: E402

from penumbra import Context, GBuffer, Image, Renderer  # noqa: E402
from penumbra.methods.isg import IsgTable, attach_sphere_sets  # noqa: E402
from penumbra.render import build_scene, render  # noqa: E402

SCENES = "indoor_contact,bunny_sunny,teapot_overcast"
# (label, exact_primitives, renderer parameters, spheres)
VARIANTS = [("main (exact_primitives off, shared_light 0)", False, {"shared_light": 0}, 64),
            ("exact_primitives on, shared_light 0", True, {"shared_light": 0}, 64),
            ("both (the defaults)", True, {}, 64),
            ("defaults, K = 64", True, {"lobes": 64}, 64),
            ("defaults, N = 128", True, {}, 128)]
# Parts of a frame switched off by parameters (label, sphere sets attached, method, parameters).
PARTS = [("whole frame (defaults)", True, "isg", {}),
         ("no occluders (lobes, both cubes, the env path's lookups, the launch)", False, "isg", {}),
         ("without the sun's own window (shared_sharpness 1e9)", True, "isg", {"shared_sharpness": 1e9}),
         ("without the specular lobe's shadows", True, "isg", {"specular_shadows": 0}),
         ("the shared grid's marking only (both off)", True, "isg", {"shared_sharpness": 1e9, "specular_shadows": 0}),
         ("unshadowed (a launch of the same size)", True, "unshadowed", {})]


def built_scene(ctx, name, res, exact, spheres, attach=True):
    desc = scene_desc(name, res)
    desc.isg = dataclasses.replace(desc.isg, exact_primitives=exact) if desc.isg else IsgTable(exact_primitives=exact)
    built = build_scene(desc, ctx)
    if attach:
        attach_sphere_sets(built, {"spheres": spheres})
    gb = GBuffer(ctx, *res)
    built.scene.render_gbuffer(gb)
    return built, gb, gb.read("instance") != 0xFFFFFFFF


def timed(ctx, runs, rounds):
    for rnd in range(rounds + 1):
        for built, gb, r, img, t in runs:
            c0 = time.process_time()
            r.execute(built.scene, gb, img)
            ctx.finish()
            if rnd:
                t.append(1e3 * (time.process_time() - c0))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--res", default="64x48")
    ap.add_argument("--rounds", type=int, default=7)
    ap.add_argument("--scenes", default=SCENES)
    ap.add_argument("--profile", action="store_true", help="the parts of a frame instead of the A/B")
    a = ap.parse_args()
    ctx = Context()
    res = [int(x) for x in a.res.split("x")]
    for name in a.scenes.split(","):
        load0 = os.getloadavg()[0]
        if a.profile:
            runs = []
            for label, attach, method, kw in PARTS:
                built, gb, _ = built_scene(ctx, name, res, True, 64, attach)
                runs.append((built, gb, Renderer(ctx, method, **kw), Image(ctx, *res), []))
            timed(ctx, runs, a.rounds)
            print(f"\n{name}, {res[0]} x {res[1]}: CPU ms, medians of {a.rounds} interleaved rounds; loaded: load "
                  f"average {load0:.1f} -> {os.getloadavg()[0]:.1f}\n\n| part | CPU ms |\n|---|---|")
            for (label, *_), (*_, t) in zip(PARTS, runs):
                print(f"| {label} | {np.median(t):.1f} |", flush=True)
            continue
        ref = None
        runs = []
        for label, exact, kw, spheres in VARIANTS:
            built, gb, mask = built_scene(ctx, name, res, exact, spheres)
            if ref is None:
                ref = render(built, "reference", frames=1, warmup=False, face_size=64,
                             sun_supersampling=4).image[..., :3]
            runs.append((built, gb, Renderer(ctx, "isg", **kw), Image(ctx, *res), []))
        timed(ctx, runs, a.rounds)
        print(f"\n{name}, {res[0]} x {res[1]}, {int(mask.sum())} surface pixels; {a.rounds} interleaved rounds; "
              f"loaded: load average {load0:.1f} -> {os.getloadavg()[0]:.1f}\n")
        print("| setting | CPU ms | CPU ratio (main / this) | rel RMS | NRMSE | bias |\n|---|---|---|---|---|---|")
        first = runs[0][4]
        for (label, *_), (built, gb, r, img, t) in zip(VARIANTS, runs):
            m = harness.metrics(ref, img.read()[..., :3], mask, ("rel_rms", "nrmse", "bias"))
            ratio = float(np.median([f / x for f, x in zip(first, t)]))
            print(f"| {label} | {np.median(t):.1f} | {ratio:.2f} | {100 * m['rel_rms']:.2f} % | "
                  f"{100 * m['nrmse']:.2f} % | {m['bias']:+.4f} |", flush=True)


if __name__ == "__main__":
    main()
