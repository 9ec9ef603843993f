"""Interleaved CPU-time profile of heightfield variants in one process.
usage: prof.py scene rounds frames 'name|buildopts|json params|what' ...   (what: frame or horizons)"""
import json, os, statistics, sys, time
from penumbra import GBuffer, Image, Renderer
from penumbra.core import Context
from penumbra.methods.heightfield import fields
from penumbra.render import build_scene
from penumbra.scenefile import load_scene

scene, rounds, frames = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
vs = []
for spec in sys.argv[4:]:
    name, opts, params, what = spec.split("|")
    os.environ["PENUMBRA_CL_BUILD_OPTIONS"] = opts
    ctx = Context()
    desc = load_scene(scene)
    built = build_scene(desc, ctx)
    w, h = desc.camera.resolution
    gb, img = GBuffer(ctx, w, h), Image(ctx, w, h)
    built.scene.render_gbuffer(gb)
    field, inst = next(iter(fields(built).values()))
    r = Renderer(ctx, "heightfield", **json.loads(params or "{}"))
    if what == "frame":
        fn = lambda r=r, built=built, gb=gb, img=img: r.execute(built.scene, gb, img)
    else:
        fn = lambda r=r, built=built, inst=inst: r.read_output(built.scene, "env_horizons", inst)
    fn(); ctx.finish()
    vs.append(dict(name=name, fn=fn, ctx=ctx, cpu=[], wall=[]))
print("load", os.getloadavg())
for k in range(rounds):
    for v in (vs if k % 2 == 0 else vs[::-1]):
        for _ in range(frames):
            t0, c0 = time.perf_counter(), time.process_time()
            v["fn"](); v["ctx"].finish()
            v["cpu"].append(1000 * (time.process_time() - c0)); v["wall"].append(1000 * (time.perf_counter() - t0))
base = statistics.median(vs[0]["cpu"])
for v in vs:
    c = statistics.median(v["cpu"])
    print(f"{v['name']:30s} cpu {c:8.1f}  wall {statistics.median(v['wall']):8.1f}  base/this {base / c:5.2f}")
print("load", os.getloadavg())
