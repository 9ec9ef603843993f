"""The caller's depth maps per frame: copied from the host
(pn_renderer_set_depth_maps, a check of every depth and a blocking upload)
against read in place from the caller's pyopencl buffer
(pn_renderer_set_depth_maps_cl, the frames only), in one run with
interleaved rounds (docs/depthmap.md, "Maps of any sizes, and zero copy").

Per round and path: the supply (set_maps with the frames as a simulator would
each frame; timed alone) and one execute, timed to ctx.finish(); the maps are
those the library drew for the scene (the default sizes: 256^2 for the
strong domains). Prints one JSON row.

  python bench/depthmap_caller_maps.py [--scene two_armadillos_sunny] [--rounds 7]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from depthmap_experiments import gbuffer, load  # noqa: E402

import penumbra  # noqa: E402
from penumbra import Image, Renderer  # noqa: E402
from penumbra.methods import depthmap as dm  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="two_armadillos_sunny")
    ap.add_argument("--rounds", type=int, default=7)
    ap.add_argument("--directions", type=int, default=64)
    args = ap.parse_args()
    import pyopencl as cl

    ctx = penumbra.Context()
    built = load(args.scene, ctx)
    gb = gbuffer(built)
    img = Image(ctx, gb.width, gb.height)
    drawer = Renderer(ctx, "depthmap", directions=args.directions, skip_power=0.0)
    drawer.execute(built.scene, gb, img)
    doms, frames, maps = dm.read_maps(drawer, built.scene)
    maps = maps if isinstance(maps, list) else list(maps)
    sides = np.array([m.shape[0] for m in maps], np.uint32)
    packed = np.concatenate([m.reshape(-1) for m in maps]).astype(np.float32)
    clctx, queue = ctx.cl_objects()
    buf = cl.Buffer(clctx, cl.mem_flags.READ_WRITE | cl.mem_flags.COPY_HOST_PTR, hostbuf=packed)
    paths = {}
    for name in ("host copy", "in place"):
        r = Renderer(ctx, "depthmap", directions=args.directions, skip_power=0.0)
        dm.set_domains(r, doms)
        paths[name] = r
    images = {}

    def frame(name):
        """(supply ms, supply + execute ms)."""
        r = paths[name]
        t0 = time.perf_counter()
        if name == "host copy":
            dm.set_maps(r, frames, maps)
        else:
            dm.set_maps(r, frames, buf, resolutions=sides)
        t1 = time.perf_counter()
        r.execute(built.scene, gb, img)
        ctx.finish()
        t2 = time.perf_counter()
        images[name] = img.read()
        return 1000.0 * (t1 - t0), 1000.0 * (t2 - t0)

    supply = {k: [] for k in paths}
    times = {k: [] for k in paths}
    for k in range(args.rounds + 1):  # round 0 warms up
        for name in paths:
            s_ms, f_ms = frame(name)
            if k:
                supply[name].append(s_ms)
                times[name].append(f_ms)
    same = bool(np.array_equal(images["host copy"], images["in place"]))
    row = dict(scene=args.scene, directions=args.directions, maps_mb=packed.nbytes / 1e6,
               sides=sorted(set(sides.tolist())), same_image=same, load=os.getloadavg(),
               **{f"{k} supply ms": float(np.median(v)) for k, v in supply.items()},
               **{f"{k} supply + frame ms": float(np.median(v)) for k, v in times.items()})
    print(json.dumps(row))
    return 0


if __name__ == "__main__":
    sys.exit(main())
