import json, os, shutil, sys
from pathlib import Path
from penumbra import bench
grid = [{"azimuths": a} for a in (16, 32)]
tag = sys.argv[1]
os.environ["PENUMBRA_CL_BUILD_OPTIONS"] = sys.argv[2]
for scene in sys.argv[3:]:
    o = Path("bench/results/heightfield_speed/speed10_sun_cubic/out") / (scene + tag)
    o.mkdir(parents=True, exist_ok=True)
    if not (o / "cache").exists():
        shutil.copytree(Path("bench/results") / scene / "cache", o / "cache")
    opts = bench.BenchOptions(methods=("heightfield",), sweeps={"heightfield": grid}, spp=(1,), rays=False)
    bench.run(f"bench/scenes/{scene}.toml", o, opts)
