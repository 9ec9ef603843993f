"""The bake farm's speed-up (docs/farm.md, "Speed"): the same FIV bakes
serially in one process and on a LocalCluster of N workers, one after the
other in one run, on procedural meshes (no test data needed).

    .venv/bin/python bench/farm_speed.py [--workers 2] [--jobs 4] [--out bench/results/farm_speed]

A balanced set: one torus under the analytic sky turned by 360/jobs degrees
per job, so every bake does the same work and two idle cores can approach
2x. But PoCL already spreads one bake over every core of the machine, so on
one machine the farm can only win what a single bake leaves idle (kernel
builds, host work between spheres); its gain is more machines. The load
average before and after each half is recorded: on a shared machine the
ratio measures the contention as much as the farm.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import tempfile
import time
from pathlib import Path

from penumbra import farm, procedural
from penumbra.meshio import Mesh, save_obj
from penumbra.methods.fiv import bake_to_cache

OPTIONS = {"samples": [64, 33, 24], "face_size": 32, "sun_supersampling": 1, "precision": "float32"}


def jobs(folder: Path, count: int, cache: Path) -> list[dict]:
    torus = procedural.torus(1.0, 0.3, 48, 24)
    mesh = folder / "torus.obj"
    save_obj(mesh, Mesh(torus.vertices, torus.faces))
    return [{"mesh": str(mesh), "options": OPTIONS, "cache": str(cache), "device": None,
             "env": {"map": "sky", "rotation_deg": 360.0 * k / count, "intensity": 1.0}} for k in range(count)]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--jobs", type=int, default=4)
    ap.add_argument("--out", default="bench/results/farm_speed")
    args = ap.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="penumbra-farm-speed-") as tmp:
        tmp = Path(tmp)
        load = {"before": os.getloadavg()[0]}
        start = time.perf_counter()
        serial = [bake_to_cache(j) for j in jobs(tmp, args.jobs, tmp / "serial")]
        serial_s = time.perf_counter() - start
        load["between"] = os.getloadavg()[0]
        with farm.client(workers=args.workers) as c:
            c.run(lambda: None)   # workers up before the clock starts
            start = time.perf_counter()
            farmed = farm.run(c, bake_to_cache, jobs(tmp, args.jobs, tmp / "farm"))
            farm_s = time.perf_counter() - start
        load["after"] = os.getloadavg()[0]
    result = {"jobs": args.jobs, "workers": args.workers, "options": OPTIONS, "cpus": os.cpu_count(),
              "machine": platform.processor() or platform.machine(), "load_average_1min": load,
              "serial_s": serial_s, "farm_s": farm_s, "speedup": serial_s / farm_s,
              "serial_bake_s": [r["seconds"] for r in serial], "farm_bake_s": [r["seconds"] for r in farmed],
              "date": time.strftime("%Y-%m-%d")}
    (out / "results.json").write_text(json.dumps(result, indent=2) + "\n")
    lines = [f"# Bake farm speed-up ({result['date']})", "",
             f"{args.jobs} FIV bakes of a 2,304-triangle torus under the analytic sky (turned per job), "
             f"grid {'x'.join(map(str, OPTIONS['samples']))}, on {os.cpu_count()} cores; "
             f"load average {load['before']:.2f} / {load['between']:.2f} / {load['after']:.2f} "
             "(before, between, after).", "",
             "| | wall s | bake s each |", "|---|---|---|",
             f"| serial, one process | {serial_s:.1f} | {', '.join(f'{s:.1f}' for s in result['serial_bake_s'])} |",
             f"| LocalCluster, {args.workers} workers | {farm_s:.1f} | "
             f"{', '.join(f'{s:.1f}' for s in result['farm_bake_s'])} |", "",
             f"Speed-up: **{result['speedup']:.2f}x**.", ""]
    (out / "report.md").write_text("\n".join(lines))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
