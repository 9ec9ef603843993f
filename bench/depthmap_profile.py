"""Where a depthmap frame's time goes (docs/performance.md, "Depth-map sampling").

On the seed's scenes at the bench size (bench/scenes/depthmap/*.toml, 128 x 96),
one process, settings interleaved round by round (median of --rounds after a
warm-up round), each setting timed as one execute (+ ctx.finish):

  frame      maps + shading (the method's frame without the G-buffer)
  shade      shading alone (reuse_maps 1: the same maps)
  unlit      shading without lookups (visibility 0)
  gbuffer    the scene's G-buffer pass

and the work counted: rays (maps drawn x res^2), lookups (pixels x domains
above the horizon with a map). --set KEY=VALUE overrides a renderer parameter
for every setting; --variants gives named parameter sets to compare.

  python bench/depthmap_profile.py [--scenes armadillo_uffizi,...] [--rounds 5]
        [--variants 'old:fit=0;new:fit=1']
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


def parse_variants(text: str) -> list[tuple[str, dict]]:
    out = []
    for part in filter(None, text.split(";")):
        name, _, rest = part.partition(":")
        params = {}
        for kv in filter(None, rest.split(",")):
            k, _, v = kv.partition("=")
            params[k.strip()] = float(v) if "." in v else int(v)
        out.append((name.strip(), params))
    return out


def timed(fn, ctx) -> float:
    t0 = time.perf_counter()
    fn()
    ctx.finish()
    return 1000.0 * (time.perf_counter() - t0)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", default="armadillo_uffizi,two_armadillos_sunny,phong_spheres_uffizi")
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--variants", default="defaults:")
    ap.add_argument("--resolution", default="", help="camera resolution override, e.g. 512,512")
    ap.add_argument("--json", default="")
    args = ap.parse_args()
    ctx = penumbra.Context()
    rows = []
    for name in args.scenes.split(","):
        over = [f"camera.resolution=[{args.resolution}]"] if args.resolution else []
        built = load(name, ctx, over)
        gb = gbuffer(built)
        img = Image(ctx, gb.width, gb.height)
        variants = parse_variants(args.variants)
        rs = {}
        for vname, p in variants:
            full = Renderer(ctx, "depthmap", **p)
            shade = Renderer(ctx, "depthmap", **p)
            unlit = Renderer(ctx, "depthmap", **{**p, "visibility": 0})
            for r in (full, shade, unlit):
                r.execute(built.scene, gb, img)
            shade.set(reuse_maps=1)
            rs[vname] = (full, shade, unlit)
        times = {v: {"frame": [], "shade": [], "unlit": []} for v, _ in variants}
        gbt = []
        for k in range(args.rounds + 1):  # round 0: warm-up, excluded
            t = timed(lambda: built.scene.render_gbuffer(gb), ctx)
            if k:
                gbt.append(t)
            for vname, _ in variants:
                for key, r in zip(("frame", "shade", "unlit"), rs[vname]):
                    t = timed(lambda: r.execute(built.scene, gb, img), ctx)
                    if k:
                        times[vname][key].append(t)
        fg = int((gb.read("instance") != 0xFFFFFFFF).sum()) if hasattr(gb, "read") else gb.width * gb.height
        for vname, p in variants:
            full = rs[vname][0]
            res = full.get("resolution")
            drawn = dm.maps_drawn(full, built.scene)
            med = {k: float(np.median(v)) for k, v in times[vname].items()}
            row = dict(scene=name, variant=vname, params=p, pixels=gb.width * gb.height, resolution=res,
                       directions=dm.domain_count(full), maps_drawn=drawn, rays=drawn * res * res,
                       gbuffer_ms=float(np.median(gbt)), **{f"{k}_ms": v for k, v in med.items()},
                       maps_ms=med["frame"] - med["shade"], lookups_ms=med["shade"] - med["unlit"])
            rows.append(row)
            print(json.dumps(row), flush=True)
    print("load:", os.getloadavg())
    if args.json:
        Path(args.json).write_text(json.dumps(dict(rows=rows, load=os.getloadavg()), indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
