# The brightest domain of the plain decomposition of the outdoor map (Rooitou Park) at N 16, 32, 64: its share and cap radius (docs/depthmap.md, "The sun in its own domains"). Output: sun_caps_rooitou.txt
import numpy as np
from penumbra import Context, EnvMap
from penumbra.imageio import read_envmap
ctx = Context()
env = EnvMap(ctx, read_envmap("../shared/data/envmaps/rooitou_park_1k_polyhaven.hdr"))
for n in (16, 32, 64):
    d = env.decompose(n)
    p = d.radiance @ [0.2126, 0.7152, 0.0722]
    i = int(np.argmax(p))
    print(n, "sun domain share %.3f cap %.1f deg" % (p[i] / p.sum(), np.degrees(d.cap_radius[i])), flush=True)
