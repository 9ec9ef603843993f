"""Power of the depthmap renderer's own domains (directions N) on the bench scenes.

Per scene and N: the six largest shares of the total power, their power over
the mean domain power, their radiance per solid angle over the average and
their solid angle over the mean, and the six largest radiances per solid angle
(docs/depthmap.md, "Per-domain map sizes": what strong_share and strong_ratio see).

  python bench/depthmap_strong_powers.py > bench/results/depthmap_strong_ratio/powers.txt
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from depthmap_experiments import gbuffer, load  # noqa: E402

import penumbra  # noqa: E402
from penumbra import Image, Renderer  # noqa: E402

LUMA = np.array([0.2126, 0.7152, 0.0722])


def main() -> int:
    ctx = penumbra.Context()
    for name in ("two_armadillos_sunny", "armadillo_uffizi", "chair_sunny"):
        built = load(name, ctx)
        gb = gbuffer(built)
        img = Image(ctx, gb.width, gb.height)
        for n in (1, 16, 32, 64, 128, 256):
            r = Renderer(ctx, "depthmap", directions=n, resolution=16, strong_resolution=0)
            r.execute(built.scene, gb, img)
            d = np.asarray(r.read_output(built.scene, "domains", 0)).reshape(-1, 8).astype(np.float64)
            p, om = d[:, 4:7] @ LUMA, d[:, 3]
            dens = (p / om) / (p.sum() / om.sum())
            o = np.argsort(-p)[:6]
            print(name, n, "share", np.round(p[o] / p.sum(), 3), "x mean", np.round(p[o] / p.mean(), 1),
                  "density/avg", np.round(dens[o], 1), "omega/avg", np.round(om[o] / om.mean(), 2),
                  "max density", np.round(np.sort(dens)[-6:][::-1], 1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
