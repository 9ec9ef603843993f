"""(azimuths, level_step, bands) -> (frame ms, NRMSE) for the heightfield on both terrain bench scenes, one process.
Ground truth from the cache of the bench run before it (same reference settings)."""
import json, os, shutil, sys, itertools
from pathlib import Path
from penumbra import bench

src = Path("bench/results/heightfield_speed/rows16_vs_mitsuba_4096spp")
out = Path("bench/results/heightfield_speed/rows16_knobs")
grid = [{"azimuths": a, "level_step": l, "bands": b} for a, l, b in itertools.product((8, 16, 32), (1, 2, 4), (5, 6))]
res = {"load_start": os.getloadavg()[0], "scenes": {}}
for scene in ("terrain_sunny", "terrain_overcast_light"):
    o = out / scene
    o.mkdir(parents=True, exist_ok=True)
    import time
    while not (src / scene / "results.json").exists():  # the bench run before it: its ground truth
        time.sleep(5)
    if not (o / "cache").exists():
        shutil.copytree(src / scene / "cache", o / "cache")
    opts = bench.BenchOptions(methods=("heightfield",), sweeps={"heightfield": grid}, spp=(1,), rays=False)
    bench.run(f"bench/scenes/{scene}.toml", o, opts)
    r = json.loads((o / "results.json").read_text())
    res["scenes"][scene] = r
    shutil.rmtree(o / "cache")
res["load_end"] = os.getloadavg()[0]
(out / "all.json").write_text(json.dumps(res, indent=1, default=str))
print("load", res["load_start"], res["load_end"])
