#!/usr/bin/env python3
"""Time against error of the shared hemisphere grid (`shared_grid`, docs/isg.md
sections 8 and 9): the diffuse lobes up to `shared_sharpness` shadowed by one
marking per pixel instead of one per lobe. On the four scenes of the speed work:
bench/scenes/bunny_sunny.toml, teapot_overcast.toml, indoor_contact.toml and the
seed's Fig. 12 bunny (Phong glossiness 1000, k_s 0.5; bench/isg_experiments.py).
Ground truth: `reference` at face_size 64, sun_supersampling 4; errors over the
surface pixels (relative RMS and NRMSE, docs/metrics.md). Time: the process's
CPU ms of one shading frame (Renderer.execute; PoCL's threads included: the
measure least moved by the other users of a shared machine), median of
`--frames` rounds that each run every setting once (interleaved), after a
warm-up round; the ratio is the median of the per-round ratios to the first
setting. Settings are renderer parameters, `;`-separated, each `k=v,k=v`.

    python bench/isg_shared.py [--res 64x48] [--frames 5] [--scenes bunny_sunny,...]
        [--settings "shared_grid=0;shared_grid=16;..."]
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

from penumbra import GBuffer, Image, Renderer  # noqa: E402
from penumbra.methods.isg import attach_sphere_sets  # noqa: E402
from penumbra.render import build_scene, render  # noqa: E402
from penumbra.scenefile import load_scene, parse_scene  # noqa: E402

SCENES = "bunny_sunny,teapot_overcast,indoor_contact,fig12"
SETTINGS = "shared_grid=0;shared_grid=16;shared_grid=24;shared_grid=31"


def scene_desc(name: str, res):
    if name == "fig12":
        from isg_experiments import bunny_scene
        return parse_scene(copy.deepcopy(bunny_scene(res, 0.5, 0.5)), ".")
    return load_scene(harness.REPO / "bench" / "scenes" / f"{name}.toml", [f"camera.resolution=[{res[0]},{res[1]}]"])


def parse_settings(text: str) -> list[dict]:
    out = []
    for item in text.split(";"):
        d = {}
        for kv in filter(None, item.split(",")):
            k, v = kv.split("=")
            d[k.strip()] = float(v) if "." in v or "e" in v else int(v)
        out.append(d)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--res", default="64x48")
    ap.add_argument("--frames", type=int, default=5)
    ap.add_argument("--scenes", default=SCENES)
    ap.add_argument("--settings", default=SETTINGS)
    a = ap.parse_args()
    from penumbra import Context
    ctx = Context()
    res = [int(x) for x in a.res.split("x")]
    settings = parse_settings(a.settings)
    for name in a.scenes.split(","):
        load0 = os.getloadavg()[0]
        built = build_scene(scene_desc(name, res), ctx)
        attach_sphere_sets(built, {})
        gb = GBuffer(ctx, *res)
        built.scene.render_gbuffer(gb)
        mask = gb.read("instance") != 0xFFFFFFFF
        ref = render(built, "reference", frames=1, warmup=False, face_size=64, sun_supersampling=4).image[..., :3]
        runs = [(s, Renderer(ctx, "isg", **s), Image(ctx, *res), []) for s in settings]
        for rnd in range(a.frames + 1):
            for s, r, img, t in runs:
                t0, c0 = time.perf_counter(), time.process_time()
                r.execute(built.scene, gb, img)
                ctx.finish()
                if rnd:
                    t.append((1e3 * (time.process_time() - c0), 1e3 * (time.perf_counter() - t0)))
        print(f"\n{name}, {res[0]} x {res[1]}, {int(mask.sum())} surface pixels; loaded: load average "
              f"{load0:.1f} at the start, {os.getloadavg()[0]:.1f} at the end; {a.frames} interleaved rounds\n")
        print("| setting | CPU ms | wall ms | CPU ratio to the first | rel RMS | NRMSE |")
        print("|---|---|---|---|---|---|")
        first = runs[0][3]
        for s, r, img, t in runs:
            m = harness.metrics(ref, img.read()[..., :3], mask, ("rel_rms", "nrmse"))
            ratio = float(np.median([f[0] / x[0] for f, x in zip(first, t)]))
            label = ", ".join(f"{k} {v}" for k, v in s.items()) or "defaults"
            print(f"| {label} | {np.median([x[0] for x in t]):.0f} | {np.median([x[1] for x in t]):.0f} | "
                  f"{ratio:.2f} | {100 * m['rel_rms']:.2f} % | {100 * m['nrmse']:.2f} % |", flush=True)


if __name__ == "__main__":
    main()
