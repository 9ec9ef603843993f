"""The hot texels of every env map in ../shared/data as connected lights (docs/depthmap.md, "Several lights:
the rule per connected light"): per map the hot texels (luminance > 100 x the mean, tests/env_sharp64.py), their
8-connected components joined across the seam, each one's share of the map's power (excess over T) and its
spread (angle of the excess-weighted mean resultant) against the cap radius of its solid angle.

  python bench/env_hot_lights.py
"""
import sys
from pathlib import Path
import numpy as np
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
import depthmap64 as dm
from penumbra.imageio import read_envmap as read_image
from scipy import ndimage
import glob, os
from pathlib import Path
for f in sorted(glob.glob(str(Path(__file__).resolve().parents[2] / "shared/data/envmaps/*"))):
    try:
        env = read_image(f)
    except Exception as e:
        print(f, e); continue
    env = np.asarray(env)[..., :3].astype(np.float64)
    tex = dm.texels(env)
    h, w = env.shape[:2]
    lum = (tex.radiance @ dm.LUMINANCE).reshape(h, w)
    omega = tex.omega.reshape(h, w)
    limit = 100 * tex.weight.sum() / (4 * np.pi)
    hot = lum > limit
    # wrap in u: label on a padded map
    lab, n = ndimage.label(hot, structure=np.ones((3, 3)))
    # merge labels across the seam
    for j in range(h):
        for dj in (-1, 0, 1):
            jj = j + dj
            if 0 <= jj < h and lab[j, w-1] and lab[jj, 0] and lab[j, w-1] != lab[jj, 0]:
                a, b = lab[j, w-1], lab[jj, 0]
                lab[lab == b] = a
    ids = [i for i in np.unique(lab) if i]
    dirs = tex.dirs.reshape(h, w, 3)
    tot_e = ((lum - limit) * omega)[hot].sum()
    total = tex.weight.sum()
    rows = []
    for i in ids:
        m = lab == i
        e = ((lum - limit) * omega)[m]
        mv = (dirs[m] * e[:, None]).sum(0)
        spread = np.degrees(np.arccos(min(np.linalg.norm(mv) / e.sum(), 1)))
        om = omega[m].sum()
        cap = np.degrees(2 * np.arcsin(np.sqrt(om / (4 * np.pi))))
        rows.append((e.sum() / tot_e, m.sum(), spread, cap, e.sum()/total))
    rows.sort(reverse=True)
    # whole
    e = ((lum - limit) * omega)[hot]
    mv = (dirs[hot] * e[:, None]).sum(0) if hot.any() else np.zeros(3)
    ws = np.degrees(np.arccos(min(np.linalg.norm(mv) / max(e.sum(), 1e-300), 1))) if hot.any() else 0
    wc = np.degrees(2 * np.arcsin(np.sqrt(omega[hot].sum() / (4 * np.pi))))
    print(f"{os.path.basename(f)} {w}x{h} hot {hot.sum()} comps {len(ids)} whole spread {ws:.1f} cap {wc:.1f} excess/total {tot_e/total:.3f}")
    for r in rows[:8]:
        print("   share %.3f texels %d spread %.2f cap %.2f  ratio %.2f  of-map %.3f" % (r[0], r[1], r[2], r[3], r[2]/max(r[3],1e-9), r[4]))
