"""Mean samples taken per row-group lane and azimuth of the env search (a build with
-DHF_COUNT_SAMPLES, which returns the count instead of the horizon; groups only, the row's last
vertex excluded), for the build options given as arguments."""
import os, sys, numpy as np
sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))  # hf_setup.py
from hf_setup import TERRAIN_SCENES, terrain
from penumbra import Renderer

for scene in TERRAIN_SCENES:
    for opts in sys.argv[1:]:
        t = terrain(scene, opts + " -DHF_COUNT_SAMPLES", gbuffer=False)
        n = np.array(Renderer(t.ctx, "heightfield").read_output(t.built.scene, "env_horizons", t.inst))
        n = n.reshape(257, 257, -1)[:, :256]
        print(scene.split("/")[-1], repr(opts), f"mean samples {n.mean():.2f} of 34", flush=True)
