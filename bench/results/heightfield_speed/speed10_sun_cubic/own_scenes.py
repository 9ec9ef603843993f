import os, shutil, sys
from pathlib import Path
from penumbra import bench
scene, tag, bo = sys.argv[1], sys.argv[2], sys.argv[3]
os.environ["PENUMBRA_CL_BUILD_OPTIONS"] = bo
name = Path(scene).stem
o = Path("bench/results/heightfield_speed/speed10_sun_cubic/out") / (name + "_" + tag)
o.mkdir(parents=True, exist_ok=True)
src = Path("bench/results/heightfield_speed/speed10_sun_cubic/out") / (name + "_lin") / "cache"
if tag != "lin" and not (o / "cache").exists():
    shutil.copytree(src, o / "cache")
grid = [{"azimuths": a} for a in (16, 32)]
opts = bench.BenchOptions(methods=("heightfield",), sweeps={"heightfield": grid}, spp=(1,), rays=False)
bench.run(scene, o, opts)
