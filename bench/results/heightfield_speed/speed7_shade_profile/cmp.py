"""Per-vertex outputs and images of two libpenumbra builds (subprocesses), compared.
usage: cmp.py libA libB [json params]"""
import json, os, subprocess, sys
import numpy as np
SCENES = ["bench/scenes/terrain_sunny.toml", "bench/scenes/terrain_overcast_light.toml"]
if sys.argv[1] == "--worker":
    out, params = sys.argv[2], json.loads(sys.argv[3])
    from penumbra import GBuffer, Image, Renderer
    from penumbra.core import Context
    from penumbra.methods.heightfield import fields
    from penumbra.render import build_scene
    from penumbra.scenefile import load_scene
    res = {}
    for s, sc in enumerate(SCENES):
        ctx = Context(); desc = load_scene(sc); built = build_scene(desc, ctx)
        w, h = desc.camera.resolution
        gb, img = GBuffer(ctx, w, h), Image(ctx, w, h)
        built.scene.render_gbuffer(gb)
        field, inst = next(iter(fields(built).values()))
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
