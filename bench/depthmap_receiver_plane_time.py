"""A depthmap frame (maps + shading) at the defaults with receiver_plane 0 and 1, interleaved, process CPU time
(docs/depthmap.md, "The bias from the receiver's plane").

  python bench/depthmap_receiver_plane_time.py SCENE.toml
"""
import sys, time, os, json
import numpy as np
from penumbra import Context, GBuffer, Image, Renderer
from penumbra.render import build_scene
from penumbra.scenefile import load_scene
desc = load_scene(sys.argv[1]); ctx = Context(); built = build_scene(desc, ctx)
w, h = desc.camera.resolution
gb, img = GBuffer(ctx, w, h), Image(ctx, w, h)
built.scene.render_gbuffer(gb)
rs = {k: Renderer(ctx, "depthmap", background=0, receiver_plane=k) for k in (0, 1)}
for r in rs.values():
    r.execute(built.scene, gb, img); ctx.finish()
t = {0: [], 1: []}
l0 = os.getloadavg()[0]
for k in range(7):
    for key, r in rs.items():
        t0 = time.process_time(); r.execute(built.scene, gb, img); ctx.finish(); t[key].append(1000 * (time.process_time() - t0))
print(sys.argv[1], "defaults, CPU ms median of 7 interleaved: receiver_plane 0 %.1f, 1 %.1f; load %.1f -> %.1f" % (np.median(t[0]), np.median(t[1]), l0, os.getloadavg()[0]))
