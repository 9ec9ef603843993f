"""What bounds depthmap's error on a scene (docs/depthmap.md, "What bounds two armadillos under the sunny map"):
the error of a base setting split by term (one part's maps made much finer at a time: the sun's, the sky's, N) and
by image region (the objects; the floor at the sun shadow's outline, inside it, sunlit; from the sharp domain's
own hard shadow at 1024^2), and the frame split by phase (process CPU time, median of 9 interleaved rounds).

  python bench/depthmap_error_split.py SCENE.toml ['{"directions": 32, "resolution": 32, "strong_resolution": 128}']
        [--cache DIR]
"""
import sys, json, os, time
from pathlib import Path
import numpy as np
from penumbra import Context, GBuffer, Image, Renderer
from penumbra.bench import BenchOptions, ground_truth
from penumbra.metrics import compare
from penumbra.render import build_scene
from penumbra.scenefile import load_scene
from penumbra.methods import depthmap as dmm
scene = sys.argv[1]
cache = Path(sys.argv[sys.argv.index("--cache") + 1]) if "--cache" in sys.argv else Path("/tmp/depthmap_errors")
base = json.loads(sys.argv[2]) if len(sys.argv) > 2 and not sys.argv[2].startswith("--") else {"directions": 32, "resolution": 32, "strong_resolution": 128}
desc = load_scene(scene); ctx = Context(); built = build_scene(desc, ctx)
truth = ground_truth(built, desc, BenchOptions(), cache / Path(scene).stem, print)[..., :3]
w, h = desc.camera.resolution
gb, img = GBuffer(ctx, w, h), Image(ctx, w, h)
built.scene.render_gbuffer(gb)
inst = gb.read("instance")
mask = inst != 0xFFFFFFFF
names = [o.name for o in desc.objects]
print("instances", names, [int((inst == i).sum()) for i in range(len(names))])
span = float(truth[mask].max() - truth[mask].min())
def render(p):
    r = Renderer(ctx, "depthmap", background=0, **p)
    r.execute(built.scene, gb, img); ctx.finish()
    return img.read()[..., :3].astype(np.float64), r
# the sun's shadow mask on the floor: the sharp domain alone, a 1024 map, hard lookup
_, r0 = render(dict(base, strong_resolution=1024))
doms = np.asarray(r0.read_output(built.scene, "domains", 0), np.float64).reshape(-1, 8)
sun = doms[:1].copy()
rs = Renderer(ctx, "depthmap", background=0, resolution=1024, soft_shadows=0, specular=0)
dmm.set_domains(rs, dmm.domain_array(sun[:, :3], sun[:, 4:7], sun[:, 7], sun[:, 3]))
rs.execute(built.scene, gb, img); ctx.finish(); sun_img = img.read()[..., :3].sum(-1)
rs2 = Renderer(ctx, "depthmap", background=0, resolution=1024, soft_shadows=0, specular=0, visibility=0)
dmm.set_domains(rs2, dmm.domain_array(sun[:, :3], sun[:, 4:7], sun[:, 7], sun[:, 3]))
rs2.execute(built.scene, gb, img); ctx.finish(); sun_un = img.read()[..., :3].sum(-1)
vis = np.where(sun_un > 0, sun_img / np.maximum(sun_un, 1e-30), 1.0)
floor = mask & (inst == names.index("ground"))
shadow = floor & (vis < 0.5)
# the outline: shadow pixels with a lit neighbour or lit with a shadowed neighbour
sh = vis < 0.5
edge = np.zeros_like(sh)
for dy in (-1, 0, 1):
    for dx in (-1, 0, 1):
        edge |= np.roll(np.roll(sh, dy, 0), dx, 1) != sh
regions = {"armadillos": mask & ~floor, "floor, sun outline (±1 px)": floor & edge,
           "floor, sun shadow (inside)": floor & sh & ~edge, "floor, sunlit": floor & ~sh & ~edge}
print("regions", {k: int(v.sum()) for k, v in regions.items()}, "span", span)
variants = {"base": {}, "sun map 1024": {"strong_resolution": 1024}, "sky maps 256 (sun 256)": {"resolution": 256, "strong_resolution": 256},
            "sky 256 + sun 1024": {"resolution": 256, "strong_resolution": 1024},
            "sun soft 0": {"soft_shadows": 0}, "every domain soft (2)": {"soft_shadows": 2},
            "N 128, sky 256, sun 1024": {"directions": 128, "resolution": 256, "strong_resolution": 1024},
            "N 256, sky 128, sun 1024": {"directions": 256, "resolution": 128, "strong_resolution": 1024},
            "visibility 0": {"visibility": 0}}
out = {}
for name, v in variants.items():
    p = dict(base, **v)
    im, _ = render(p)
    d = (im - truth)
    sse = (d[mask] ** 2).sum()
    e = compare(truth, im, mask)["nrmse"]
    parts = {k: float((d[m] ** 2).sum() / sse) for k, m in regions.items()}
    bias = {k: float(d[m].mean() / span) for k, m in regions.items()}
    out[name] = dict(nrmse=e, sse_share=parts, mean_err_over_span=bias)
    print(f"{name:28s} nrmse {e:.5f} | " + " ".join(f"{k}: {parts[k]:.2f} ({bias[k]:+.4f})" for k in regions), flush=True)
# frame phases at the base setting, interleaved, 9 rounds
rb = Renderer(ctx, "depthmap", background=0, **base)
rr = Renderer(ctx, "depthmap", background=0, reuse_maps=1, **base)
ru = Renderer(ctx, "depthmap", background=0, reuse_maps=1, visibility=0, **base)
for r in (rb, rr, ru):
    r.execute(built.scene, gb, img); ctx.finish()
t = {"gbuffer": [], "frame": [], "shading": [], "unlit shading": []}
for k in range(9):
    t0 = time.process_time(); built.scene.render_gbuffer(gb); ctx.finish(); t["gbuffer"].append(time.process_time() - t0)
    t0 = time.process_time(); rb.execute(built.scene, gb, img); ctx.finish(); t["frame"].append(time.process_time() - t0)
    t0 = time.process_time(); rr.execute(built.scene, gb, img); ctx.finish(); t["shading"].append(time.process_time() - t0)
    t0 = time.process_time(); ru.execute(built.scene, gb, img); ctx.finish(); t["unlit shading"].append(time.process_time() - t0)
med = {k: 1000 * float(np.median(v)) for k, v in t.items()}
print("CPU ms (median of 9, interleaved):", json.dumps(med), "load", os.getloadavg())
sides = rb.read_output(built.scene, "map_resolutions", 0).astype(int)
drawn = rb.read_output(built.scene, "map_frames", 0).reshape(-1, 16)[:, 15] != 0
print("texels", int((sides[drawn] ** 2).sum()), "sides", sides.tolist())
