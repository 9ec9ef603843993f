"""The first frame (plan: the decomposition, with and without the sharp split) and the next, on a fresh scene each
(docs/performance.md, "Depth-map sampling"). python bench/results/depthmap_sharp/plan_time.py SCENE.toml"""
import time, os, sys
from penumbra import Context, GBuffer, Image, Renderer
from penumbra.render import build_scene
from penumbra.scenefile import load_scene
desc = load_scene(sys.argv[1]); ctx = Context()
print("load", os.getloadavg())
for rep in range(2):
    for sharp in (0, 1):
        built = build_scene(desc, ctx)
        w, h = desc.camera.resolution
        gb, img = GBuffer(ctx, w, h), Image(ctx, w, h)
        built.scene.render_gbuffer(gb)
        r = Renderer(ctx, "depthmap", directions=16, resolution=16, strong_resolution=64, sharp=sharp)
        t0 = time.perf_counter(); r.execute(built.scene, gb, img); ctx.finish(); t1 = time.perf_counter()
        r.execute(built.scene, gb, img); ctx.finish(); t2 = time.perf_counter()
        print(f"sharp {sharp}: first frame (plan + decomposition) {t1 - t0:.2f} s, next {1000 * (t2 - t1):.0f} ms", flush=True)
print("load", os.getloadavg())
