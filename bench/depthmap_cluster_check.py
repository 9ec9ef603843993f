"""The strong_cluster rule on the bench scenes (docs/depthmap.md, "Clusters of bright domains").

Per scene and N: the eight domains brightest per solid angle (their radiance per sr over the average, their
power over the mean domain power) and their map sides with the cluster rule (strong_cluster 32) and without
it (0), at resolution 64, strong_resolution 256, grade 0.5; then the texels over N x 64^2 and the sides'
histogram. Equal sides in the two columns: the rule changes no map there.

  python bench/depthmap_cluster_check.py [--scenes ...] > bench/results/depthmap_graded/cluster_check.txt
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

LUMA = np.array([0.2126, 0.7152, 0.0722])


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", default="two_armadillos_sunny,armadillo_uffizi,phong_spheres_outdoor")
    ap.add_argument("--directions", default="16,32,64,128")
    args = ap.parse_args()
    ctx = penumbra.Context()
    for name in args.scenes.split(","):
        built = load(name, ctx)
        gb = gbuffer(built)
        img = Image(ctx, gb.width, gb.height)
        for n in map(int, args.directions.split(",")):
            sides = {}
            for cut in (32.0, 0.0):
                r = Renderer(ctx, "depthmap", directions=n, resolution=64, strong_resolution=256, grade=0.5,
                             strong_cluster=cut)
                r.execute(built.scene, gb, img)
                sides[cut] = r.read_output(built.scene, "map_resolutions", 0).astype(np.int64)
            d = np.asarray(r.read_output(built.scene, "domains", 0)).reshape(-1, 8).astype(np.float64)
            p, om = d[:, 4:7] @ LUMA, d[:, 3]
            dens = (p / om) / (p.sum() / om.sum())
            o = np.argsort(-dens)[:8]
            s = sides[32.0]
            print(f"{name} N {n}: density/avg {np.round(dens[o], 1).tolist()} x mean {np.round(p[o] / p.mean(), 1).tolist()}"
                  f" sides (cluster 32) {s[o].tolist()} (off) {sides[0.0][o].tolist()}"
                  f" all equal {bool(np.array_equal(s, sides[0.0]))}; texels / (N 64^2) {(s ** 2).sum() / (n * 64 ** 2):.2f};"
                  f" sides {dict(zip(*[a.tolist() for a in np.unique(s, return_counts=True)]))}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
