"""fiv against the floor kernel, as ratios in one run (docs/fiv.md, Speed).

On the occluder-count scene of the scaling benchmark (N bunnies sharing one
128x65x30 field, 512x512) the floor kernel, `unshadowed` and `fiv`, each with
the env-map background drawn (the default) and without it, run round-robin
on one G-buffer; the ratios to the floor come from the same rounds, so the
load of a shared machine hits them alike.

With ``--against PATH`` (a folder holding another build's ``penumbra``
package, e.g. a copy of an installed one from before a change) the script
alternates subprocesses of the two builds, round by round, and reports each
variant's time in this build over the other: an A/B of two kernel versions
in one run.

    .venv/bin/python bench/fiv_speed.py [--occluders 1] [--rounds 9] [--against /tmp/base]

Prints the table; ``--json PATH`` writes it.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

VARIANTS = {"floor": ("floor", {}),
            "unshadowed": ("unshadowed", {}), "unshadowed_nobg": ("unshadowed", {"background": 0}),
            "fiv": ("fiv", {}), "fiv_nobg": ("fiv", {"background": 0}),
            "fiv_sum_nobg": ("fiv", {"overlap": 0, "background": 0})}


def cpu_timed(fn, ctx) -> float:
    """ms of the process's CPU time (PoCL's worker threads included) for fn and
    the queue's finish: on a loaded machine less disturbed by the other jobs
    than the wall clock (waits for a core do not count)."""
    t0 = time.process_time()
    fn()
    ctx.finish()
    return 1000.0 * (time.process_time() - t0)


def measure(occluders: int, resolution: int, rounds: int, out: Path, build_options=("",), spread: bool = False,
            cpu: bool = False, variants: dict | None = None) -> dict:
    """ms of every variant, per round (round-robin, first round dropped); with
    several ``build_options`` (kernel build switches, e.g. -DPN_FIV_PROFILE=1)
    every variant runs under each of them in turn, keyed "variant[options]"."""
    from penumbra import data as test_data
    from penumbra.bench import scene_toml
    from penumbra.core import Context, GBuffer, Image, Renderer
    from penumbra.methods.fiv import SCALING_ENV, SCALING_MESH, attach_fields, fiv_scaling_scene, fiv_spread_scene
    from penumbra.render import _timed, build_scene
    from penumbra.scenefile import load_scene

    data = test_data.data_dir()
    (out / "scenes").mkdir(parents=True, exist_ok=True)
    path = out / "scenes" / f"{'spread' if spread else 'bunnies'}_{occluders}.toml"

    def rel(q: Path) -> str:
        return Path(os.path.relpath(q.resolve(), (out / "scenes").resolve())).as_posix()

    # The scenes and field cache of penumbra bench --fiv-scaling (spread: its 120-unit spacing).
    make = (lambda *a, **k: fiv_spread_scene(*a, spacing=120.0, **k)) if spread else fiv_scaling_scene
    path.write_text(scene_toml(make(occluders, rel(data / SCALING_MESH), rel(data / SCALING_ENV), resolution,
                                    cache=rel(out.parent / "fiv_scaling" / "cache" / "fiv")),
                               f"fiv speed: {occluders} bunnies (bench/fiv_speed.py)"))
    runs = {}
    variants = VARIANTS if variants is None else variants
    for opts in build_options if variants else ():
        built = build_scene(load_scene(path), Context(f"build_options={opts}") if opts else Context())
        attach_fields(built)
        ctx = built.ctx
        gb, img = GBuffer(ctx, resolution, resolution), Image(ctx, resolution, resolution)
        built.scene.render_gbuffer(gb)
        ctx.finish()
        for k, (m, kw) in variants.items():
            runs[f"{k}[{opts}]" if len(build_options) > 1 else k] = (built, gb, img, Renderer(ctx, m, **kw))
    times = {k: [] for k in runs}
    for r in range(rounds + 1):
        for k, (built, gb, img, rd) in runs.items():
            t = (cpu_timed if cpu else _timed)(lambda: rd.execute(built.scene, gb, img), built.ctx)
            if r:
                times[k].append(t)
    return times


def count_lane_by_lane(occluders: int, resolution: int, out: Path, spread: bool = False) -> dict:
    """The receiver pixels whose sample fetch goes lane by lane, not through
    the shared fetch of neighbouring lanes (pn_fiv_fetch8): the pixels whose
    image changes in a build with PN_FIV_PROFILE=3, which marks them."""
    import numpy as np

    from penumbra.core import Context, GBuffer, Image, Renderer
    from penumbra.methods.fiv import attach_fields
    from penumbra.render import build_scene
    from penumbra.scenefile import load_scene

    measure(occluders, resolution, 0, out, spread=spread, variants={})  # writes the scene file
    path = out / "scenes" / f"{'spread' if spread else 'bunnies'}_{occluders}.toml"
    images = []
    for opts in ("", "-DPN_FIV_PROFILE=3"):
        built = build_scene(load_scene(path), Context(f"build_options={opts}") if opts else Context())
        attach_fields(built)
        gb, img = GBuffer(built.ctx, resolution, resolution), Image(built.ctx, resolution, resolution)
        built.scene.render_gbuffer(gb)
        Renderer(built.ctx, "fiv", background=0, overlap=0).execute(built.scene, gb, img)
        built.ctx.finish()
        images.append(img.read()[..., :3])
    receivers = int((gb.read("instance") != 0xFFFFFFFF).sum())
    lane_by_lane = int((images[0] != images[1]).any(axis=-1).sum())
    return {"receiver_pixels": receivers, "lane_by_lane_pixels": lane_by_lane, "share": lane_by_lane / receivers}


def table(times: dict) -> list[str]:
    floor = statistics.median(next(t for k, t in times.items() if k.startswith("floor")))
    return [f"  {k:<16} {statistics.median(t):8.3f} ms  {statistics.median(t) / floor:6.2f}x floor" for k, t in
            times.items()]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--occluders", type=int, default=1)
    ap.add_argument("--spread", action="store_true", help="the scaling benchmark's spread scene")
    ap.add_argument("--resolution", type=int, default=512)
    ap.add_argument("--rounds", type=int, default=9)
    ap.add_argument("--against", help="folder holding another build's penumbra package (A/B by subprocesses)")
    ap.add_argument("--out", default="bench/results/fiv_speed")
    ap.add_argument("--json", help="write the results here")
    ap.add_argument("--variants", help="comma-separated subset of " + ", ".join(VARIANTS))
    ap.add_argument("--build-options", action="append", default=None,
                    help="kernel build switches; give it twice or more to time the builds against each other")
    ap.add_argument("--cpu", action="store_true", help="time by the process's CPU time, not the wall clock")
    ap.add_argument("--count-lane-by-lane", action="store_true",
                    help="count the pixels whose sample fetch goes lane by lane (PN_FIV_PROFILE=3) and stop")
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    out = Path(args.out)
    if args.variants:
        for k in set(VARIANTS) - set(args.variants.split(",")):
            del VARIANTS[k]
    if args.count_lane_by_lane:
        print(json.dumps(count_lane_by_lane(args.occluders, args.resolution, out, args.spread)))
        return
    if args.child:
        print(json.dumps(measure(args.occluders, args.resolution, args.rounds, out, spread=args.spread, cpu=args.cpu)))
        return
    load = [round(os.getloadavg()[0], 2)]
    if not args.against:
        times = measure(args.occluders, args.resolution, args.rounds, out, tuple(args.build_options or ("",)),
                        args.spread, args.cpu)
        load.append(round(os.getloadavg()[0], 2))
        print(f"{args.occluders} occluder(s), {args.resolution}^2, median of {args.rounds} rounds, load {load}")
        print("\n".join(table(times)))
        result = {"occluders": args.occluders, "load_average_1min": load, "ms": times}
    else:
        # Alternating subprocesses, each a few rounds, so both builds see the same load.
        builds = {"this": None, "against": args.against}
        times = {b: {k: [] for k in VARIANTS} for b in builds}
        for _ in range(args.rounds):
            for b, where in builds.items():
                env = dict(os.environ)
                if where:
                    env["PYTHONPATH"] = where + os.pathsep + env.get("PYTHONPATH", "")
                res = subprocess.run([sys.executable, __file__, "--child", "--occluders", str(args.occluders),
                                      "--resolution", str(args.resolution), "--rounds", "3", "--out", str(out)]
                                     + (["--variants", args.variants] if args.variants else [])
                                     + (["--spread"] if args.spread else []) + (["--cpu"] if args.cpu else []),
                                     env=env, check=True, capture_output=True, text=True)
                for k, t in json.loads(res.stdout.strip().splitlines()[-1]).items():
                    times[b][k] += t
        load.append(round(os.getloadavg()[0], 2))
        print(f"{args.occluders} occluder(s), {args.resolution}^2, {args.rounds} alternating subprocesses x 3 rounds, "
              f"load {load}")
        for b in builds:
            print(f" {b} ({builds[b] or 'installed'}):")
            print("\n".join(table(times[b])))
        print(" this / against (medians):")
        for k in VARIANTS:
            print(f"  {k:<16} {statistics.median(times['this'][k]) / statistics.median(times['against'][k]):6.3f}")
        result = {"occluders": args.occluders, "load_average_1min": load, "against": args.against, "ms": times,
                  "date": time.strftime("%Y-%m-%d %H:%M")}
    if args.json:
        Path(args.json).write_text(json.dumps(result, indent=2) + "\n")


if __name__ == "__main__":
    main()
