"""What fitting the maps to the receivers the G-buffer sees would gain (docs/depthmap.md, "Fit to the receivers").

Per seed scene and map (N 64, fit 1, the maps' frames from the `map_frames` output): the rectangle of the
G-buffer's visible points (the receivers) projected on the map's plane, clipped to the map's fit-1
rectangle (outside it a point is lit anyway), against that rectangle: the ratio of the sides (u and v) and of
the areas. A receiver fit would shrink the map's texels by the side ratio at equal resolution (or draw that
area ratio of the rays at equal texel size). Prints the medians and quartiles over the maps drawn.

  python bench/depthmap_receiver_fit.py [--scenes ...] [--directions 64]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from depthmap_experiments import gbuffer, load  # noqa: E402

import penumbra  # noqa: E402
from penumbra import Image, Renderer  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", default="armadillo_uffizi,two_armadillos_sunny,phong_spheres_uffizi")
    ap.add_argument("--directions", type=int, default=64)
    args = ap.parse_args()
    ctx = penumbra.Context()
    for name in args.scenes.split(","):
        built = load(name, ctx)
        gb = gbuffer(built)
        img = Image(ctx, gb.width, gb.height)
        r = Renderer(ctx, "depthmap", directions=args.directions)
        r.execute(built.scene, gb, img)
        f = np.asarray(r.read_output(built.scene, "map_frames", 0), np.float64).reshape(-1, 16)
        sides = r.read_output(built.scene, "map_resolutions", 0)
        pos = gb.read("position")[..., :3].reshape(-1, 3).astype(np.float64)
        pos = pos[gb.read("instance").reshape(-1) != 0xFFFFFFFF]
        su, sv, sa = [], [], []
        for m in np.flatnonzero(f[:, 15] != 0):
            e1, e2 = f[m, 0:3], f[m, 4:7]
            u0, v0, du, dv = f[m, 3], f[m, 7], f[m, 12], f[m, 13]
            res = sides[m]
            u1, v1 = u0 + du * res, v0 + dv * res  # texel centres at u0 + (i + 0.5) du
            u, v = pos @ e1, pos @ e2
            inside = (u >= u0) & (u <= u1) & (v >= v0) & (v <= v1)
            if not inside.any():
                su.append(0.0), sv.append(0.0), sa.append(0.0)
                continue
            ru = (u[inside].max() - u[inside].min()) / (u1 - u0)
            rv = (v[inside].max() - v[inside].min()) / (v1 - v0)
            su.append(ru), sv.append(rv), sa.append(ru * rv)
        q = lambda a: "median %.2f (quartiles %.2f-%.2f, min %.2f)" % (np.median(a), *np.percentile(a, [25, 75]),
                                                                       np.min(a))
        print(f"{name} N {args.directions}, {len(sa)} maps: u side {q(su)}; v side {q(sv)}; area {q(sa)}",
              flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
