"""Mean samples taken per row-group lane and azimuth of the env search (a build with
-DHF_COUNT_SAMPLES, which returns the count instead of the horizon; groups only, the row's last
vertex excluded), for the build options given as arguments."""
import os, sys, numpy as np
from penumbra import Renderer
from penumbra.core import Context
from penumbra.methods.heightfield import fields
from penumbra.render import build_scene
from penumbra.scenefile import load_scene

for scene in ["bench/scenes/terrain_sunny.toml", "bench/scenes/terrain_overcast_light.toml"]:
    for opts in sys.argv[1:]:
        os.environ["PENUMBRA_CL_BUILD_OPTIONS"] = opts + " -DHF_COUNT_SAMPLES"
        ctx = Context()
        built = build_scene(load_scene(scene), ctx)
        field, inst = next(iter(fields(built).values()))
        n = np.array(Renderer(ctx, "heightfield").read_output(built.scene, "env_horizons", inst))
        n = n.reshape(257, 257, -1)[:, :256]
        print(scene.split("/")[-1], repr(opts), f"mean samples {n.mean():.2f} of 34", flush=True)
