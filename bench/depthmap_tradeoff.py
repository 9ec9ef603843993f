"""Error against time of depthmap settings, in one run (docs/depthmap.md, "Speed").

For each seed scene at the bench size (bench/scenes/depthmap/*.toml, 128 x 96):
NRMSE against the reference (face 64, sun 4 x 4; penumbra.metrics.compare,
background excluded) and the frame time (maps + shading, one execute, the
G-buffer not included) and the texels drawn (the maps with a depth map,
their sides) of every setting in --grid; times are medians over
--rounds rounds in which every setting runs once (interleaved, a warm-up
round excluded), so that the machine's load hits them alike.

  python bench/depthmap_tradeoff.py [--scenes ...] [--grid 'fit=0,1;directions=16,32,64;resolution=64,128,256']
        [--out bench/results/depthmap_tradeoff]
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from depthmap_experiments import gbuffer, load, truth  # noqa: E402

import penumbra  # noqa: E402
from penumbra import Image, Renderer  # noqa: E402
from penumbra.fileutil import atomic_write_text  # noqa: E402
from penumbra.metrics import compare  # noqa: E402

REPO = Path(__file__).resolve().parents[1]


def grid(text: str) -> list[dict]:
    axes = []
    for part in filter(None, text.split(";")):
        k, _, vals = part.partition("=")
        axes.append([(k.strip(), float(v) if "." in v else int(v)) for v in vals.split(",")])
    return [dict(combo) for combo in itertools.product(*axes)]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", default="armadillo_uffizi,two_armadillos_sunny,phong_spheres_uffizi")
    ap.add_argument("--grid", default="fit=0,1;directions=16,32,64;resolution=64,128,256")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--out", default=str(REPO / "bench" / "results" / "depthmap_tradeoff"))
    args = ap.parse_args()
    out = Path(args.out)
    (out / "cache").mkdir(parents=True, exist_ok=True)
    if not (out / ".gitignore").exists():
        atomic_write_text(out / ".gitignore", "# reference images (machine-made, cached)\ncache/\n")
    ctx = penumbra.Context()
    rows = []
    for name in args.scenes.split(","):
        built = load(name, ctx)
        gb = gbuffer(built)
        t0 = time.perf_counter()
        ref = truth(built, gb, name, out)
        print(f"{name}: reference {time.perf_counter() - t0:.1f} s", file=sys.stderr, flush=True)
        mask = gb.read("instance") != 0xFFFFFFFF
        img = Image(ctx, gb.width, gb.height)
        settings = grid(args.grid)
        renderers = [Renderer(ctx, "depthmap", background=0, **p) for p in settings]
        times = [[] for _ in settings]
        errs = []
        for r in renderers:
            r.execute(built.scene, gb, img)
            errs.append(compare(ref, img.read()[..., :3], mask))
        for k in range(args.rounds + 1):  # round 0 warms up
            for i, r in enumerate(renderers):
                t0 = time.perf_counter()
                r.execute(built.scene, gb, img)
                ctx.finish()
                if k:
                    times[i].append(1000.0 * (time.perf_counter() - t0))
        for p, e, t, r in zip(settings, errs, times, renderers):
            sides = r.read_output(built.scene, "map_resolutions", 0).astype(np.int64)
            drawn = r.read_output(built.scene, "map_frames", 0).reshape(-1, 16)[:, 15] != 0
            row = dict(scene=name, params=p, nrmse=e["nrmse"], rel_rms=e["rel_rms"], frame_ms=float(np.median(t)),
                       texels=int((sides[drawn] ** 2).sum()), maps=int(drawn.sum()),
                       sides=sorted(set(sides[drawn].tolist())))
            rows.append(row)
            print(json.dumps(row), flush=True)
    load_avg = os.getloadavg()
    print("load:", load_avg)
    (out / "results.json").write_text(json.dumps(dict(rows=rows, load=load_avg, grid=args.grid), indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
