"""The env horizons, env and total radiance and the image of the two terrain bench scenes for
builds given as arguments (PENUMBRA_CL_BUILD_OPTIONS), compared bit for bit with the first."""
import os, sys, numpy as np
sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))  # hf_setup.py
from hf_setup import TERRAIN_SCENES, terrain
from penumbra import Renderer

for scene in TERRAIN_SCENES:
    outs = []
    for opts in sys.argv[1:]:
        t = terrain(scene, opts)
        r = Renderer(t.ctx, "heightfield")
        r.execute(t.built.scene, t.gb, t.img)
        o = {"image": np.array(t.img.read())}
        for what in ("env_horizons", "env", "total"):
            o[what] = np.array(r.read_output(t.built.scene, what, t.inst))
        outs.append(o)
    for opts, o in zip(sys.argv[2:], outs[1:]):
        for what in o:
            same = np.array_equal(o[what].view(np.uint32), outs[0][what].view(np.uint32))
            print(scene.split("/")[-1], repr(opts), what, "bit for bit" if same else
                  f"DIFFERS max {np.abs(o[what] - outs[0][what]).max():.3g}")
