"""The early exit's reach, modelled in float64 (tests/heightfield64.py) on the two terrain bench
fields: per lane and per row group (16 columns x 2 rows), the share of samples searched before
every later candidate is bounded below the running maximum. GLOBAL = 1: the bound from max H;
0: from each level's maximum. Run from the repository root."""
GLOBAL = 1
import sys, numpy as np
sys.path.insert(0, "tests")
import heightfield64 as t
from penumbra.scenefile import load_scene
for scene in ["bench/scenes/terrain_sunny.toml", "bench/scenes/terrain_overcast_light.toml"]:
    desc = load_scene(scene)
    hd = desc.heightfields[0]
    H = np.asarray(hd.load().heights, np.float64) * hd.height_scale
    D, W = H.shape
    sx, sz = hd.size[0] / (W - 1), hd.size[1] / (D - 1)
    levels = t.pyramid(H, 4)
    n = len(levels)
    d, L = t.sample_plan(n, 4, 4.0, min(sx, sz))
    j, i = np.mgrid[96:128, 0:256].astype(np.float64)
    _, du, dv = t.azimuth_steps(32, sx, sz)
    at_p = {k: t.level_sample(levels[k], W, D, i, j)[..., None] for k in set(L.tolist())}
    omega = np.empty(i.shape + (32, n))
    U = np.empty(i.shape + (n,))
    for mm in range(n):
        k = L[mm]
        h = t.level_sample(levels[k], W, D, i[..., None] + d[mm] * du, j[..., None] + d[mm] * dv)
        omega[..., mm] = np.arctan((h - at_p[k]) / d[mm])
        U[..., mm] = np.arctan((levels[0 if GLOBAL else k].max() - at_p[k][..., 0]) / d[mm])
    Urem = np.maximum.accumulate(U[..., ::-1], axis=-1)[..., ::-1]
    ext = np.concatenate([omega[..., :1], omega], axis=-1)
    knots = (ext[..., :-2] + 4 * ext[..., 1:-1] + ext[..., 2:]) / 6
    mids = (ext[..., :-3] + 23 * ext[..., 1:-2] + 23 * ext[..., 2:-1] + ext[..., 3:]) / 48
    stop = np.full(omega.shape[:-1], n)
    for m in range(2, n - 1):
        best = np.maximum(np.maximum(knots[..., :m].max(-1), mids[..., :m - 1].max(-1)), 0)
        bound = np.maximum(np.maximum(omega[..., m - 2], np.maximum(omega[..., m - 1], omega[..., m])), Urem[..., None, m + 1])
        ok = (bound < best * (1 - 1e-5) - 1e-6) & (stop == n) | ((bound <= 0) & (stop == n))
        stop[ok] = m + 1
    g = stop.reshape(16, 2, 16, 16, 32).max(axis=(1, 3))  # groups of 2 rows x 16 columns, per azimuth
    print(scene, "lane-level", stop.mean() / n, "group-level", g.mean() / n)
    # cost-weighted: samples >= 17 cost 1.9x
    wgt = np.where(np.arange(n) >= 17, 1.9, 1.0); cw = np.concatenate([[0], np.cumsum(wgt)])
    print("  cost-weighted group-level", cw[g].mean() / cw[n])
