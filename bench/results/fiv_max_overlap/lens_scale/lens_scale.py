"""Measured, not built: every pair's lens scaled by a constant (build option PN_FIV_LENS_SCALE), as
a per-field fill factor would scale the lenses of occluders that fill only part of their bounding
disc (bunnies), on the 45 scenes of bench/fiv_max_overlap.py at max_overlap 6 and 32, against its
cached references. Run from the repository root: .venv/bin/python bench/results/fiv_max_overlap/lens_scale/lens_scale.py
(docs/fiv.md, Accuracy 6)."""
import sys, json
sys.path.insert(0, 'bench')
from pathlib import Path
import fiv_max_overlap as F
from penumbra.core import Context
from penumbra.render import build_scene, render
from penumbra.scenefile import parse_scene
from penumbra.metrics import nrmse
cache = str(Path('bench/results/fiv_scaling/cache/fiv').resolve())
scs = F.scenes(128, cache)
names = sys.argv[1].split(',') if len(sys.argv) > 1 and sys.argv[1] else list(scs)
scales = [1.0, 0.7, 0.5, 0.35]
ctxs = {f: Context(f"build_options=-DPN_FIV_LENS_SCALE={f}f") for f in scales}
out = {}
for name in names:
    sc = scs[name]
    row = {}
    for f, c in ctxs.items():
        built = build_scene(parse_scene(sc), c)
        ref = F.reference(built, sc, Path('bench/results/fiv_max_overlap/cache'))
        for k in (6, 32):
            r = render(built, "fiv", frames=1, warmup=False, background=0, overlap=1, max_overlap=k)
            row[f"{f}/{k}"] = float(nrmse(ref, r.image[..., :3]))
    out[name] = row
    print(name, " ".join(f"{k}:{v:.4f}" for k, v in row.items()), flush=True)
json.dump(out, open('bench/results/fiv_max_overlap/lens_scale/results.json', 'w'), indent=1)
