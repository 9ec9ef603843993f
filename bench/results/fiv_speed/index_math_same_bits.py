"""fiv images of this build against the build with -DPN_FIV_GATHER_BRANCHES, bit for bit
(1, 10 clustered and 60 spread bunnies at 256^2, seven option sets each; run from the repository root)."""
import sys
from pathlib import Path
import numpy as np
sys.path.insert(0, "bench")
import fiv_speed
from penumbra.core import Context, GBuffer, Image, Renderer
from penumbra.methods.fiv import attach_fields
from penumbra.render import build_scene
from penumbra.scenefile import load_scene

out = Path("/tmp/fividx/bits"); res = 256
opts = ["", "-DPN_FIV_GATHER_BRANCHES"]
kws = [{}, {"overlap": 0}, {"overlap": 2}, {"overlap": 1, "self_shadow": 1}, {"partial": 0},
       {"trilinear": 0}, {"background": 0}]
bad = 0
for n, spread in ((1, False), (10, False), (60, True)):
    fiv_speed.measure(n, res, 0, out, spread=spread, variants={})
    path = out / "scenes" / f"{'spread' if spread else 'bunnies'}_{n}.toml"
    imgs = {}
    for o in opts:
        built = build_scene(load_scene(path), Context(f"build_options={o}") if o else Context())
        attach_fields(built)
        gb, img = GBuffer(built.ctx, res, res), Image(built.ctx, res, res)
        built.scene.render_gbuffer(gb)
        for i, kw in enumerate(kws):
            try:
                Renderer(built.ctx, "fiv", **kw).execute(built.scene, gb, img)
            except Exception as e:
                print("skip", kw, e); continue
            built.ctx.finish()
            imgs[(o, i)] = img.read().copy()
    for i, kw in enumerate(kws):
        if (opts[0], i) in imgs:
            same = np.array_equal(imgs[(opts[0], i)].view(np.uint32), imgs[(opts[1], i)].view(np.uint32))
            bad += not same
            print(n, "spread" if spread else "clustered", kw, "same bits" if same else "DIFFERENT")
print("all same" if not bad else f"{bad} differ")
