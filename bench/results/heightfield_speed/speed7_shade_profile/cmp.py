"""Per-vertex outputs and images of two libpenumbra builds (subprocesses), compared.
usage: cmp.py libA libB [json params]"""
import json, os, subprocess, sys
import numpy as np
sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))  # hf_setup.py
from hf_setup import TERRAIN_SCENES as SCENES, terrain
if sys.argv[1] == "--worker":
    out, params = sys.argv[2], json.loads(sys.argv[3])
    from penumbra import Renderer
    res = {}
    for s, sc in enumerate(SCENES):
        t = terrain(sc)
        ctx, desc, built, gb, img, inst = t.ctx, t.desc, t.built, t.gb, t.img, t.inst
        r = Renderer(ctx, "heightfield", **params)
        r.execute(built.scene, gb, img); ctx.finish()
        res[f"{s}_image"] = np.asarray(img.read())
        for what in ("env", "total", "env_horizons"):
            res[f"{s}_{what}"] = np.asarray(r.read_output(built.scene, what, inst))
        if built.scene_lights if hasattr(built, "scene_lights") else desc.lights:
            res[f"{s}_light"] = np.asarray(r.read_output(built.scene, "light", inst, 0))
    np.savez(out, **res)
    sys.exit(0)
libs = sys.argv[1:3]; params = sys.argv[3] if len(sys.argv) > 3 else "{}"
outs = []
for i, l in enumerate(libs):
    o = f"/tmp/hfshade_cmp_{i}.npz"
    subprocess.run([sys.executable, __file__, "--worker", o, params], env=dict(os.environ, PENUMBRA_LIBRARY=l), check=True)
    outs.append(np.load(o))
a, b = outs
for k in a.files:
    x, y = a[k].astype(np.float64), b[k].astype(np.float64)
    same = np.array_equal(a[k], b[k])
    d = np.abs(x - y).max()
    rel = (np.abs(x - y) / np.maximum(np.abs(x), 1e-30)).max()
    print(f"{k:20s} {'bit for bit' if same else 'differs'}  max abs {d:.3g}  max rel {rel:.3g}")
