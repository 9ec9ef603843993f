"""CPU-time A/B of two BVH layouts of bench/ray_profile.py on the raybench
rays, in one process (docs/performance.md "Ray casting", item 7).

For each scene every layout named in the pairs gets its own context; in each
of `rounds` interleaved rounds (plus a warm-up round), per query, every
layout runs an untimed and then a timed call (primary: 8 calls of the
primary rays; shadow: one call), in an order rotated each round. Times are
process CPU time (PoCL's threads included); the speed-up of B over A is the
median over rounds of A's time / B's time.

    python bench/ray_cpu_ab.py [--rounds 25] [--scenes bunny_sunny,...] [--pairs plain/wide,plain8/wide8]
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import ray_profile as rp  # noqa: E402

from penumbra import raybench  # noqa: E402
from penumbra.render import build_scene  # noqa: E402
from penumbra.scenefile import load_scene  # noqa: E402


def uptime() -> str:
    return subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip()


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rounds", type=int, default=25)
    ap.add_argument("--scenes", default=",".join(rp.SCENES))
    ap.add_argument("--pairs", default="plain/wide,plain8/wide8", help="A/B pairs of " + ",".join(rp.LAYOUTS))
    args = ap.parse_args(argv)
    pairs = [p.split("/") for p in args.pairs.split(",")]
    names = list(dict.fromkeys(x for p in pairs for x in p))
    print("load before:", uptime(), flush=True)
    for name in args.scenes.split(","):
        desc = load_scene(str(rp.SCENES[name]))
        built = {k: build_scene(desc, rp.context(rp.LAYOUTS[k])) for k in names}
        rays = raybench.workload(desc, built[names[0]])
        po, pd = rays["primary"]
        so, sd = rays["shadow"]
        jobs = {k: {"primary": (lambda s=b.scene: [s.intersect(po, pd) for _ in range(8)]),
                    "shadow": (lambda s=b.scene: s.occluded(so, sd))} for k, b in built.items()}
        cpu = {k: {q: [] for q in ("primary", "shadow")} for k in names}
        for r in range(args.rounds + 1):  # round 0 warms up
            for q in ("primary", "shadow"):
                for k in names[r % len(names):] + names[:r % len(names)]:
                    jobs[k][q]()
                    c0 = time.process_time()
                    jobs[k][q]()
                    c1 = time.process_time()
                    if r:
                        cpu[k][q].append(c1 - c0)
        for a, b in pairs:
            sp = {q: statistics.median(x / y for x, y in zip(cpu[a][q], cpu[b][q])) for q in ("primary", "shadow")}
            ms = {k: "/".join(f"{1e3 * statistics.median(cpu[k][q]):.2f}" for q in ("primary", "shadow")) for k in (a, b)}
            print(f"{name}: {b} over {a}: primary {sp['primary']:.3f}x, shadow {sp['shadow']:.3f}x "
                  f"(median CPU ms primary/shadow: {a} {ms[a]}, {b} {ms[b]})", flush=True)
    print("load after:", uptime(), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
