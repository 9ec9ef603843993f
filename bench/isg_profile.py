#!/usr/bin/env python3
"""Where an isg frame's work goes, in operations and bytes, and what rate the
kernel reaches (docs/performance.md "ISG"). On the bunny-on-a-floor scene of
bench/isg_speed.py (Fig. 12: k_s 0.5, glossiness 1000, K = 32, M = 16,
self_occlusion 1): the work per surface pixel is counted in float64 on a sample
of pixels, with the kernel's own culls (receiver plane, window cone) and patch
tests (tests/isg_shading64.py patch_mask), and the kernel is timed on the whole
frame, with parts switched off by source patches, in one process.

Counted per (pixel, lobe, sphere) pair past the culls, as the kernel does it:
~45 scalar flops (direction, cap, cone test, lobe-frame coordinates), the row
test (16 lanes x 3), the columns' azimuthal part (16 x 3) and 16 x 2 per row
that can hold marks (lanes of 16-wide vectors; grid <= 16). Per pair culled:
~12 (plane or cone). Bytes: a sphere and its owner (20 B) per pair tested,
from cache; DRAM traffic per pixel is the G-buffer (5 x 16 B) and the image
(16 B).

    python bench/isg_profile.py [--res 100x100] [--spheres 300] [--sample 300]
"""

from __future__ import annotations

import argparse
import math
import os
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "bench"))
sys.path.insert(0, str(REPO / "tests"))

import isg_speed as S  # noqa: E402
from isg_shading64 import COS_AMPLITUDE, COS_SHARPNESS, HALF_PI, TOUCH, frame, window  # noqa: E402
from isg64 import sg_product  # noqa: E402

FLOPS_PAIR_FIXED, FLOPS_PAIR_CULLED, LANES = 45, 12, 16


def pair_counts(p, n, own_id, lobes, spheres, owners, grid=16):
    """(pairs tested, pairs past the culls, flops) of one pixel over `lobes` ((axis, lam) list),
    as the flat loop sees them (the tree tests fewer pairs: nodes cull groups of 8)."""
    v = spheres[:, :3] - p
    r = spheres[:, 3]
    d = np.linalg.norm(v, axis=1)
    keep = (v @ n > -r) & ~((owners == own_id) & (d <= r * (1 + TOUCH)))
    u = v / d[:, None]
    ca = np.sqrt(np.maximum(1 - np.minimum(r / d, 1) ** 2, 0))
    sa = np.minimum(r / d, 1)
    tested = past = 0
    flops = 0.0
    for axis, lam in lobes:
        w = window(lam)
        cone = min(w * math.sqrt(2), math.pi)
        inc = keep & ~((math.cos(cone) > -ca) & (u @ axis < math.cos(cone) * ca - math.sin(cone) * sa))
        tested += int(keep.sum())
        m = int(inc.sum())
        past += m
        if m:
            x, y = frame(axis)
            cen = HALF_PI - w + (np.arange(grid) + 0.5) * (2 * w / grid)
            ul = np.c_[u[inc] @ x, u[inc] @ y, u[inc] @ axis]
            rho = np.hypot(ul[:, 0], ul[:, 2])
            rows = (np.sin(cen)[None] * rho[:, None] + np.cos(cen)[None] * ul[:, 1:2] >= ca[inc, None] - 1e-6).sum()
            flops += m * (FLOPS_PAIR_FIXED + 2 * 3 * LANES) + rows * 2 * LANES
        flops += (int(keep.sum()) - m) * FLOPS_PAIR_CULLED
    return tested, past, flops


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--res", default="100x100")
    ap.add_argument("--spheres", type=int, default=300)
    ap.add_argument("--sample", type=int, default=300)
    ap.add_argument("--reps", type=int, default=3)
    a = ap.parse_args()
    from penumbra import Context
    ctx = Context()
    res = tuple(int(x) for x in a.res.split("x"))
    built, gb, planes, sph, own = S.scene(ctx, res, a.spheres)
    k = S.Kernel(ctx, built, planes, sph, own)
    ids = planes["instance"].reshape(-1)
    surf = np.flatnonzero(ids != 0xFFFFFFFF)
    rng = np.random.default_rng(1)
    pick = rng.choice(surf, min(a.sample, surf.size), replace=False)
    pos = planes["position"].reshape(-1, 4)[:, :3].astype(np.float64)
    nrm = planes["normal"].reshape(-1, 4)[:, :3].astype(np.float64)
    import numpy.lib.recfunctions as rf
    lob = rf.structured_to_unstructured(built.envmap.fit_sgs(32)).astype(np.float64)
    cam = k.camera[:3].astype(np.float64)
    spheres, owners = sph.astype(np.float64), own
    tot = np.zeros(3)
    for q in pick:
        p, n = pos[q], nrm[q] / np.linalg.norm(nrm[q])
        lobes = []
        for L in lob:
            ax, lam, _ = sg_product(L[:3], L[3], 1.0, n, COS_SHARPNESS, COS_AMPLITUDE)
            lobes.append((np.asarray(ax), float(lam)))
        view = (cam - p) / np.linalg.norm(cam - p)
        lobes.append((2 * (n @ view) * n - view, 1000.0))  # the env path's Phong lobe (k_s > 0 everywhere here)
        tot += pair_counts(p, n, ids[q], lobes, spheres, owners)
    per = tot / len(pick)
    print(f"per surface pixel ({len(pick)} sampled of {surf.size}; K = 32 + 1 specular lobe, N = {len(sph)}): "
          f"{per[0]:.0f} sphere-lobe pairs past the plane cull (flat loop), {per[1]:.0f} past the cone cull, "
          f"{per[2] / 1e3:.1f} kflop")
    patch = {"base": None, "no spheres": "count0"}
    times = {}
    for rnd in range(a.reps + 1):
        for name, p in patch.items():
            r = k.run(count=0) if p == "count0" else k.run()
            if rnd:
                times.setdefault(name, []).append((r[0], r[2]))
    for name, v in times.items():
        wall, cpu = np.median([x[0] for x in v]), np.median([x[1] for x in v])
        print(f"{name}: wall {wall:.0f} ms, CPU {cpu:.0f} ms (median of {a.reps})")
    wall = np.median([x[0] for x in times["base"]])
    cpu = np.median([x[1] for x in times["base"]])
    flop = per[2] * surf.size
    print(f"frame: {flop / 1e9:.3f} Gflop counted; {flop / cpu / 1e6:.2f} GFLOP/s per CPU second, "
          f"{flop / wall / 1e6:.2f} GFLOP/s wall; bytes from cache {20 * per[0] * surf.size / 1e6:.0f} MB, "
          f"DRAM {96 * ids.size / 1e6:.2f} MB; load {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
