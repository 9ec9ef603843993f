"""sharp 0-3 per scene and N (docs/depthmap.md, "Several lights: the rule per connected light"): NRMSE against
the bench's reference, whether the domains are the plain decomposition's (sharp 0's), and how many caps are below
0.1 rad.

  python bench/depthmap_sharp_check.py SCENE.toml[,SCENE.toml...] 16,32,64,128 ['{"resolution": 64}'] [--cache DIR]
"""
import sys, json
from pathlib import Path
import numpy as np
from penumbra import Context, GBuffer, Image, Renderer
from penumbra.bench import BenchOptions, ground_truth
from penumbra.metrics import compare
from penumbra.render import build_scene
from penumbra.scenefile import load_scene
ns = [int(x) for x in sys.argv[2].split(",")]
extra = json.loads(sys.argv[3]) if len(sys.argv) > 3 and not sys.argv[3].startswith("--") else {}
cache = Path(sys.argv[sys.argv.index("--cache") + 1]) if "--cache" in sys.argv else Path("/tmp/depthmap_errors")
for scene in sys.argv[1].split(","):
    desc = load_scene(scene); ctx = Context(); built = build_scene(desc, ctx)
    truth = ground_truth(built, desc, BenchOptions(), cache / Path(scene).stem, lambda *a: None)
    w, h = desc.camera.resolution
    gb, img = GBuffer(ctx, w, h), Image(ctx, w, h)
    built.scene.render_gbuffer(gb)
    mask = gb.read("instance") != 0xFFFFFFFF
    for n in ns:
        row = []
        doms0 = None
        for sharp in (0, 1, 2, 3):
            r = Renderer(ctx, "depthmap", background=0, directions=n, sharp=sharp, **extra)
            r.execute(built.scene, gb, img); ctx.finish()
            d = np.asarray(r.read_output(built.scene, "domains", 0), np.float32).reshape(-1, 8)
            if sharp == 0:
                doms0 = d
            e = compare(truth, img.read()[..., :3], mask)["nrmse"]
            row.append(f"sharp {sharp}: {e:.5f} {'plain' if np.array_equal(d, doms0) else 'split'} caps<0.1: {int((d[:, 7] < 0.1).sum())}")
        print(Path(scene).stem, "N", n, " | ".join(row), flush=True)
