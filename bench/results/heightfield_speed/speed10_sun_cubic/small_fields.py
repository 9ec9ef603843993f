import os, sys
sys.path.insert(0, "tests")
import numpy as np
import penumbra as pn
from penumbra.heightfield import make_terrain
import test_heightfield as th
from pathlib import Path
data = Path("../shared/data")
def ctx_with(opts):
    os.environ["PENUMBRA_CL_BUILD_OPTIONS"] = opts
    c = pn.Context()
    del os.environ["PENUMBRA_CL_BUILD_OPTIONS"]
    return c
cases = [("fbm", dict(seed=2, frequency=2.0), 5.0), ("egg_tray", {}, 1.5), ("cones", {}, 2.0), ("fbm", dict(seed=7, frequency=3.0), 3.0)]
for envname in ("immenstadter_horn_1k_polyhaven.hdr", "rooitou_park_1k_polyhaven.hdr"):
    for name, kw, scale in cases:
        row = []
        for opts in ("", "-DHF_SUN_LINEAR"):
            ctx = ctx_with(opts)
            env = pn.EnvMap(ctx, th.read_envmap(data / "envmaps" / envname), face_size=64, irradiance_face_size=32)
            h = make_terrain(name, 49, 49, **kw)
            for az in (16, 32):
                err, base = th.terrain_scene_error(ctx, env, h, scale, azimuths=az)
                row.append(f"{'lin' if opts else 'cub'}{az} {err:.4f}")
        print(envname[:10], name, kw, scale, " ".join(row), f"unsh {base:.4f}", flush=True)
