"""The early exit's reach, modelled in float64 (tests/heightfield64.py) on the two terrain bench
fields: per lane and per row group (16 columns x 2 rows), the share of samples searched before
every later candidate is bounded below the running maximum. GLOBAL = 1: the bound from max H;
0: from each level's maximum. Run from the repository root."""
GLOBAL = 1
import os, sys, numpy as np
sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))  # hf_setup.py
from hf_setup import TERRAIN_SCENES, elevations, model
for scene in TERRAIN_SCENES:
    m = model(scene)
    levels, n, d, L = m.levels, m.n, m.d, m.L
    j, i = np.mgrid[96:128, 0:256].astype(np.float64)
    e = elevations(m, i, j, 32)
    at_p, omega, knots, mids = e.at_p, e.omega, e.knots, e.mids
    U = np.empty(i.shape + (n,))
    for mm in range(n):
        k = L[mm]
        U[..., mm] = np.arctan((levels[0 if GLOBAL else k].max() - at_p[k][..., 0]) / d[mm])
    Urem = np.maximum.accumulate(U[..., ::-1], axis=-1)[..., ::-1]
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
