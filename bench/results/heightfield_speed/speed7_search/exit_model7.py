"""The early exit's reach by bound, modelled in float64 (tests/heightfield64.py) on the two
terrain bench fields, per row group (16 columns x 2 rows) and azimuth: the share of samples
searched (and weighted by cost: coarse samples 1.9x) before every later candidate is bounded
below the running maximum. Bounds on sample m's level value: 'global' max H (the sixth round);
'box' the maximum of the level's values over the group's taps at that sample; 'tileT' the
same box rounded out to T x T tiles of the level (what a max-pyramid gives); 'oracle' the
later elevations themselves (the limit of any bound). Run from the repository root."""
import os, sys, numpy as np
sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))  # hf_setup.py
from hf_setup import TERRAIN_SCENES, elevations, model

R0, R1 = int(sys.argv[1]) if len(sys.argv) > 1 else 96, int(sys.argv[2]) if len(sys.argv) > 2 else 128
for scene in TERRAIN_SCENES:
    m = model(scene)
    D, W, sx, sz, levels, n, d, L = m.D, m.W, m.sx, m.sz, m.levels, m.n, m.d, m.L
    j, i = np.mgrid[R0:R1, 0:256].astype(np.float64)
    NA = 32
    e = elevations(m, i, j, NA)
    du, dv, at_p, omega, knots, mids = e.du, e.dv, e.at_p, e.omega, e.knots, e.mids
    G0, G1 = (R1 - R0) // 2, 16
    # per group (g0, g1), azimuth a, sample m: max of level L_m over the group's tap box (exact, tiles)
    tiles = {}
    for T in (4, 8, 16):
        tm = []
        for lv in levels:
            E, C = lv.shape
            pad = np.full((-(-E // T) * T, -(-C // T) * T), -np.inf)
            pad[:E, :C] = lv
            tm.append(pad.reshape(pad.shape[0] // T, T, pad.shape[1] // T, T).max(axis=(1, 3)))
        tiles[T] = tm
    boxmax = {"box": np.empty((G0, G1, NA, n)), "square": np.empty((G0, G1, NA, n))}
    for T in tiles:
        boxmax[f"tile{T}"] = np.empty((G0, G1, NA, n))
    for g0 in range(G0):
        jv = np.array([R0 + 2 * g0, R0 + 2 * g0 + 1], np.float64)
        for g1 in range(G1):
            iu = np.minimum(np.arange(16 * g1, 16 * g1 + 16), W - 1).astype(np.float64)
            sq = np.empty(n)
            for a in range(NA):
                for mm in range(n):
                    lv = levels[L[mm]]
                    E, C = lv.shape[0] - 1, lv.shape[1] - 1
                    uu = (iu + d[mm] * du[a]) * C / (W - 1)
                    vv = (jv + d[mm] * dv[a]) * E / (D - 1)
                    a0, a1 = int(np.clip(np.floor(uu.min()) - 1, 0, C)), int(np.clip(np.floor(uu.max()) + 2, 0, C))
                    b0, b1 = int(np.clip(np.floor(vv.min()) - 1, 0, E)), int(np.clip(np.floor(vv.max()) + 2, 0, E))
                    boxmax["box"][g0, g1, a, mm] = lv[b0:b1 + 1, a0:a1 + 1].max()
                    if a == 0:  # the square of every azimuth's boxes at this distance
                        ru, rv = d[mm] / sx * C / (W - 1), d[mm] / sz * E / (D - 1)
                        u0, u1 = iu.min() * C / (W - 1), iu.max() * C / (W - 1)
                        v0, v1 = jv.min() * E / (D - 1), jv.max() * E / (D - 1)
                        sq[mm] = lv[int(np.clip(np.floor(v0 - rv) - 1, 0, E)):int(np.clip(np.floor(v1 + rv) + 2, 0, E)) + 1,
                                int(np.clip(np.floor(u0 - ru) - 1, 0, C)):int(np.clip(np.floor(u1 + ru) + 2, 0, C)) + 1].max()
                    boxmax["square"][g0, g1, a, mm] = sq[mm]
                    for T in tiles:
                        boxmax[f"tile{T}"][g0, g1, a, mm] = tiles[T][L[mm]][b0 // T:b1 // T + 1, a0 // T:a1 // T + 1].max()
    out = {}
    wgt = np.where(np.arange(n) >= 17, 1.9, 1.0); cw = np.concatenate([[0], np.cumsum(wgt)])
    for name in (sys.argv[3].split(",") if len(sys.argv) > 3 else ["global", "box", "tile4", "tile8", "tile16", "square", "oracle"]):
        if name == "global":
            U = np.arctan((levels[0].max() - np.stack([at_p[L[mm]][..., 0] for mm in range(n)], -1)) / d)[..., None, :]
            U = np.broadcast_to(U, omega.shape)
        elif name == "oracle":
            U = omega
        else:
            bm = boxmax[name]  # (G0, G1, NA, n) -> per vertex
            bmv = bm[(np.arange(R1 - R0) // 2)[:, None], (np.arange(256) // 16)[None, :]]  # (rows, 256, NA, n)
            hp = np.stack([at_p[L[mm]][..., 0] for mm in range(n)], -1)[..., None, :]
            U = np.arctan((bmv - hp) / d)
        Urem = np.maximum.accumulate(U[..., ::-1], axis=-1)[..., ::-1]
        stop = np.full(omega.shape[:-1], n)
        for m in range(2, n - 1):
            best = np.maximum(np.maximum(knots[..., :m].max(-1), mids[..., :m - 1].max(-1)), 0)
            bound = np.maximum(np.maximum(omega[..., m - 2], np.maximum(omega[..., m - 1], omega[..., m])), Urem[..., m + 1])
            ok = (bound < best * (1 - 1e-5) - 1e-6) & (stop == n) | ((bound <= 0) & (stop == n))
            stop[ok] = m + 1
        g = stop.reshape(G0, 2, 16, 16, NA).max(axis=(1, 3))
        g4 = np.minimum(n, ((g + 3) // 4) * 4)  # tested every 4 samples
        print(f"{scene.split('/')[-1]:28s} {name:7s} lane {stop.mean() / n:.3f} group {g.mean() / n:.3f} "
              f"cost-weighted {cw[g].mean() / cw[n]:.3f} every-4 cost-weighted {cw[g4].mean() / cw[n]:.3f}", flush=True)
