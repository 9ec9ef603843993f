"""The env horizons, env and total radiance and the image of the two terrain bench scenes for
builds given as arguments (PENUMBRA_CL_BUILD_OPTIONS), compared bit for bit with the first."""
import os, sys, numpy as np
from penumbra import GBuffer, Image, Renderer
from penumbra.core import Context
from penumbra.methods.heightfield import fields
from penumbra.render import build_scene
from penumbra.scenefile import load_scene

for scene in ["bench/scenes/terrain_sunny.toml", "bench/scenes/terrain_overcast_light.toml"]:
    outs = []
    for opts in sys.argv[1:]:
        os.environ["PENUMBRA_CL_BUILD_OPTIONS"] = opts
        ctx = Context()
        desc = load_scene(scene)
        built = build_scene(desc, ctx)
        w, h = desc.camera.resolution
        gb, img = GBuffer(ctx, w, h), Image(ctx, w, h)
        built.scene.render_gbuffer(gb)
        field, inst = next(iter(fields(built).values()))
        r = Renderer(ctx, "heightfield")
        r.execute(built.scene, gb, img)
        o = {"image": np.array(img.read())}
        for what in ("env_horizons", "env", "total"):
            o[what] = np.array(r.read_output(built.scene, what, inst))
        outs.append(o)
    for opts, o in zip(sys.argv[2:], outs[1:]):
        for what in o:
            same = np.array_equal(o[what].view(np.uint32), outs[0][what].view(np.uint32))
            print(scene.split("/")[-1], repr(opts), what, "bit for bit" if same else
                  f"DIFFERS max {np.abs(o[what] - outs[0][what]).max():.3g}")
