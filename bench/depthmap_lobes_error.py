"""Error of the depthmap method's specular 3 (the tables of cap averages) and
of its 16-point cap quadrature against each lobe's true cap average, by view
angle (docs/depthmap.md, "Blinn-Phong and GGX: a table with the view angle").

One domain (+z) and a G-buffer of chosen normals and views (the tests'
helpers, tests/test_depthmap.py and tests/test_depthmap_lobes.py): caps 0.02,
0.1, 0.3 and 0.8 rad, R from the cap's centre to 8 lobe widths s beyond its
edge in 17 steps at 2 azimuths, N turned about R to 3 angles; the truth by
cap points spaced s/6 (at most 2^18). Prints the largest error over the
largest true value per lobe and view angle. Runs with any build's package
(main's for a before/after comparison), table_min_exponent 1:

  PYOPENCL_CTX=0 python bench/depthmap_lobes_error.py blinn_phong:400:0.1 ggx:0:0.1 [--views 0,30,60,75,85]
"""
from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tests"))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("lobes", nargs="+", help="lobe:shininess:roughness")
    ap.add_argument("--views", default="0,30,60,75,85")
    args = ap.parse_args()
    import depthmap_lobes64 as lt
    from test_depthmap import LOBE_INDEX, lobe_render, make_scene, xform
    from test_depthmap_lobes import true_average, truth_points, view_pixels

    import penumbra
    from penumbra import Camera, EnvMap, Material, procedural

    ctx = penumbra.Context()
    camera = Camera(position=(0.0, 0.0, 0.0), look_at=(0.0, 0.0, -1.0), fov_deg=50.0, resolution=(8, 8))
    scene, _, keep = make_scene(ctx, [(procedural.plane((1.0, 1.0)), xform(translate=(0, -5, 0)), Material())],
                                EnvMap(ctx, procedural.sky(64, 32), face_size=8), camera)
    for spec in args.lobes:
        lobe, shin, rough = spec.split(":")
        shin, rough = float(shin), float(rough)
        _, s = lt.lobe_family_scale(lobe, shin, rough)
        for tv in (float(x) for x in args.views.split(",")):
            wt = wq = 0.0
            for r in (0.02, 0.1, 0.3, 0.8):
                psis = np.linspace(0.0, min(r + 8 * s, 1.2), 17)
                normals, views = view_pixels(math.radians(tv), psis, (0.3, 2.0), (0.0, 0.8, 1.6))
                mat = (shin, rough, LOBE_INDEX[lobe])
                got, v64, n64, r32 = lobe_render(ctx, scene, normals, views, mat, r, specular=3, table_min_exponent=1)
                quad, *_ = lobe_render(ctx, scene, normals, views, mat, r, specular=2, cap_samples=16)
                want = true_average(n64, v64, r32, lobe, shin, rough, truth_points(r32, s))
                wt = max(wt, float(np.abs(got - want).max() / want.max()))
                wq = max(wq, float(np.abs(quad - want).max() / want.max()))
            print(f"{lobe} n={shin} alpha={rough} theta_v={tv}: table {wt:.4f} quadrature {wq:.4f}", flush=True)
    del keep
    return 0


if __name__ == "__main__":
    sys.exit(main())
