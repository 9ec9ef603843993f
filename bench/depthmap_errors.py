"""NRMSE of depthmap settings against the bench's reference, one render each (errors only, no timing;
docs/depthmap.md, "The sun in its own domains").

  python bench/depthmap_errors.py SCENE.toml '{"directions": 32, "sharp": 1};{...}' [--cache DIR]

Prints per setting the NRMSE (penumbra.metrics.compare, background excluded), the texels of the maps drawn and
the maps drawn. The reference (face 64, sun 4 x 4, penumbra.bench.ground_truth) is cached in DIR
(default /tmp/depthmap_errors/<scene>).
"""
import sys, json, os
from pathlib import Path
import numpy as np
from penumbra import Context, GBuffer, Image, Renderer
from penumbra.bench import BenchOptions, ground_truth
from penumbra.metrics import compare
from penumbra.render import build_scene
from penumbra.scenefile import load_scene
scene = sys.argv[1]
desc = load_scene(scene); ctx = Context(); built = build_scene(desc, ctx)
cache = Path(sys.argv[sys.argv.index("--cache") + 1]) if "--cache" in sys.argv else Path("/tmp/depthmap_errors")
truth = ground_truth(built, desc, BenchOptions(), cache / Path(scene).stem, print)
w, h = desc.camera.resolution
gb, img = GBuffer(ctx, w, h), Image(ctx, w, h)
built.scene.render_gbuffer(gb)
mask = gb.read("instance") != 0xFFFFFFFF
for p in sys.argv[2].split(";"):
    p = json.loads(p)
    r = Renderer(ctx, "depthmap", background=0, **p)
    r.execute(built.scene, gb, img); ctx.finish()
    sides = r.read_output(built.scene, "map_resolutions", 0).astype(int)
    drawn = r.read_output(built.scene, "map_frames", 0).reshape(-1, 16)[:, 15] != 0
    print(json.dumps(p), "nrmse %.5f" % compare(truth, img.read()[..., :3], mask)["nrmse"], "texels",
          int((sides[drawn] ** 2).sum()), "maps", int(drawn.sum()), flush=True)
