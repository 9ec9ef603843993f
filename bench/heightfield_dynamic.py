"""Dynamic terrain: what a local edit can change, and what the partial update costs.

Two parts, both on a crater of radius 5 % of the field (a bowl, depth 0.4 x
the field's height range) dug into the fBm field of the terrain bench scene
(257², seed 3) at the centre, an edge and a corner:

``fractions`` (numpy, float64 twin of the pyramid, tests/heightfield64.py):
  per pyramid level the changed values, both exactly (the float64 pyramid
  before and after, diffed) and as the bounding box grown by the decimation
  tents' supports (what the library computes, capi/src/methods/heightfield.c);
  then, for the pyramid search with the defaults (ls 4, l_o 4, 32 azimuths),
  the fraction of (vertex, azimuth) lanes that can change — a lane can change
  when one of its samples (level L_m at p + d_m e_k) has a B-spline tap in
  level L_m's changed box, or when the receiver's own H_L(p) has one (then
  every lane of that vertex) — per vertex, per row group of ROW_GROUP = 16
  vertices (the kernel's unit, HF_ROW in kernels/heightfield.cl), and the fraction of vertices with at least one such lane.
  The level coordinate is taken 0.01 wider on each side, as the kernel does
  (it finds the taps in float). Also the share of the search's samples a
  partial update redoes when a lane resumes at its first changed sample (the
  earlier candidates' maximum kept), and with the kernel's granularity (row
  groups, checkpoints every ls samples, 3 samples to refill the spline
  window). The same for the exact mode (the bilinear march from the
  vertex to the border: a ray–box test against the changed heights grown by
  one cell).

``speed`` (the library, PoCL): a full frame (renderer.execute after
set_heights of the whole field) against the partial update (execute after
set_heights(region=...) of the crater's box) and a full frame without kept
horizons (partial_update = 0), interleaved in one process, medians of the
rounds, with the load; the lanes the partial update searched and the
vertices it shades again (those whose horizons or normal changed), measured.

    python bench/heightfield_dynamic.py [fractions|speed|all] [--size 257] [--rounds 5]
        [--out bench/results/heightfield_dynamic]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import sys
import time
from pathlib import Path

import numpy as np

ROW_GROUP = 16  # vertices per row group of the env search (HF_ROW, kernels/heightfield.cl)
REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tests"))
import heightfield64 as hf64  # noqa: E402

POSITIONS = {"centre": (0.5, 0.5), "edge": (0.5, 0.0), "corner": (0.0, 0.0)}
SIZE_WORLD = 12.0      # the terrain bench scene's field: 12 x 12 world units, height scale 5
HEIGHT_SCALE = 5.0
MARGIN = 0.01          # level coordinates: the kernel's float rounding (kernels/heightfield.cl, hf_lane_changed)


def terrain(n: int) -> np.ndarray:
    from penumbra.heightfield import make_terrain
    return make_terrain("fbm", n, n, seed=3, octaves=6, frequency=2.0)


def crater(h: np.ndarray, where: tuple[float, float], radius_share: float = 0.05, depth_share: float = 0.4):
    """h with a bowl dug at the relative position `where` (x, z in [0, 1]); returns (new
    heights, (x0, y0, w, hgt)) the bounding box of the changed texels."""
    D, W = h.shape
    r = radius_share * (W - 1)
    cx, cz = where[0] * (W - 1), where[1] * (D - 1)
    j, i = np.mgrid[0:D, 0:W].astype(np.float64)
    q = ((i - cx) ** 2 + (j - cz) ** 2) / (r * r)
    depth = depth_share * float(h.max() - h.min())
    out = h.astype(np.float64) - np.where(q < 1.0, depth * (1.0 - q) ** 2, 0.0)
    out = out.astype(np.float32)
    changed = np.argwhere(out != h)
    (y0, x0), (y1, x1) = changed.min(axis=0), changed.max(axis=0)
    return out, (int(x0), int(y0), int(x1 - x0 + 1), int(y1 - y0 + 1))


def level_rects(W: int, D: int, ls: int, rect) -> list[tuple[int, int, int, int]]:
    """Per level the box (a0, b0, a1, b1), inclusive, of the values a change of the base
    heights inside rect = (x0, y0, w, h) can reach: level k's value a averages the values q of
    level k-1 with |u_q - u_a| < ru (the tent's radius, level k's spacing), so the box grows by
    the tent's support (identity where the cell counts are equal). As in
    capi/src/methods/heightfield.c (hf_changed_levels)."""
    cells = hf64.level_cells(W, D, ls)
    x0, y0, w, h = rect
    out = [(x0, y0, x0 + w - 1, y0 + h - 1)]
    for k in range(1, len(cells)):
        a0, b0, a1, b1 = out[-1]
        (cp, ep), (c, e) = cells[k - 1], cells[k]

        def grow(lo, hi, n_prev, n_new, base):
            if n_new == n_prev:
                return lo, hi
            # a changes iff |a ru - q hu| < ru for a changed q: a in (lo hu / ru - 1, hi hu / ru + 1);
            # 0.01 of slack for the float kernel's weights at the support's edge
            hu, ru = base / n_prev, base / n_new
            return (max(0, math.ceil(lo * hu / ru - 1.0 - 1e-2)), min(n_new, math.floor(hi * hu / ru + 1.0 + 1e-2)))

        a0, a1 = grow(a0, a1, cp, c, W - 1)
        b0, b1 = grow(b0, b1, ep, e, D - 1)
        out.append((a0, b0, a1, b1))
    return out


def diff_rects(before, after):
    """Per level the exact box of the values that differ (None: none)."""
    out = []
    for a, b in zip(before, after):
        idx = np.argwhere(a != b)
        if not len(idx):
            out.append(None)
            continue
        (b0, a0), (b1, a1) = idx.min(axis=0), idx.max(axis=0)
        out.append((int(a0), int(b0), int(a1), int(b1)))
    return out


def _tap_hit(a, n_cells, lo, hi, margin):
    """Whether the B-spline taps floor(a) - 1 .. floor(a) + 2 (clamped to [0, n_cells]),
    a taken `margin` wider on each side (float rounding), meet [lo, hi]."""
    t0 = np.clip(np.floor(a - margin) - 1, 0, n_cells)
    t1 = np.clip(np.floor(a + margin) + 2, 0, n_cells)
    return (t0 <= hi) & (t1 >= lo)


def pyramid_lane_mask(W, D, ls, lo, n_phi, rects, sx, sz, margin=MARGIN):
    """(D, W, n_phi) lanes whose pyramid search can read a changed value (module doc), the
    (D, W) vertices whose own H_L(p) changed for some level used, and (D, W, n_phi) each lane's
    first sample that reads a changed value (n: none)."""
    cells = hf64.level_cells(W, D, ls)
    n = len(cells)
    d, L = hf64.sample_plan(n, ls, lo, min(sx, sz))
    _, du, dv = hf64.azimuth_steps(n_phi, sx, sz)
    j, i = np.mgrid[0:D, 0:W].astype(np.float64)
    recv = {}
    for k in sorted(set(L.tolist())):
        if rects[k] is None:
            recv[k] = np.zeros((D, W), bool)
            continue
        c, e = cells[k]
        a0, b0, a1, b1 = rects[k]
        recv[k] = _tap_hit(i * c / (W - 1), c, a0, a1, margin) & _tap_hit(j * e / (D - 1), e, b0, b1, margin)
    first_recv = np.full((D, W), n)
    for m in reversed(range(n)):
        first_recv = np.where(recv[L[m]], m, first_recv)
    receiver = first_recv < n
    first = np.empty((D, W, n_phi), np.int64)
    for q in range(n_phi):
        f = first_recv.copy()
        for m in reversed(range(n)):
            k = L[m]
            if rects[k] is None:
                continue
            c, e = cells[k]
            a0, b0, a1, b1 = rects[k]
            u, v = i + d[m] * du[q], j + d[m] * dv[q]
            hit = _tap_hit(u * c / (W - 1), c, a0, a1, margin) & _tap_hit(v * e / (D - 1), e, b0, b1, margin)
            f = np.where(hit, np.minimum(f, m), f)
        first[..., q] = f
    return first < n, receiver, first


def exact_lane_mask(W, D, n_phi, rect, sx, sz):
    """(D, W, n_phi) exact-mode lanes whose march can read a changed height: the segment from
    the vertex to the border (slab test) meets the changed box grown by one cell (a bilinear
    read at u touches floor(u) and floor(u) + 1); the receiver's own height changed: all."""
    x0, y0, w, h = rect
    bx0, bx1, by0, by1 = x0 - 1.0, x0 + w, y0 - 1.0, y0 + h
    j, i = np.mgrid[0:D, 0:W].astype(np.float64)
    _, du, dv = hf64.azimuth_steps(n_phi, sx, sz)
    own = (i >= x0) & (i < x0 + w) & (j >= y0) & (j < y0 + h)
    lanes = np.zeros((D, W, n_phi), bool)
    with np.errstate(divide="ignore", invalid="ignore"):
        for q in range(n_phi):
            cu, cv = du[q], dv[q]
            # the segment ends at the border
            tx = np.where(cu > 0, (W - 1 - i) / cu, np.where(cu < 0, -i / cu, np.inf))
            tz = np.where(cv > 0, (D - 1 - j) / cv, np.where(cv < 0, -j / cv, np.inf))
            tend = np.minimum(tx, tz)
            t0, t1 = np.zeros_like(i), tend
            for p, c, lo_, hi_ in ((i, cu, bx0, bx1), (j, cv, by0, by1)):
                if abs(c) < 1e-12:
                    inside = (p >= lo_) & (p <= hi_)
                    t1 = np.where(inside, t1, -1.0)
                    continue
                ta, tb = (lo_ - p) / c, (hi_ - p) / c
                t0 = np.maximum(t0, np.minimum(ta, tb))
                t1 = np.minimum(t1, np.maximum(ta, tb))
            lanes[..., q] = (t0 <= t1) | own
    return lanes


def fractions(n: int = 257, ls: int = 4, lo: float = 4.0, n_phi: int = 32) -> dict:
    h = terrain(n)
    D, W = h.shape
    sx = sz = SIZE_WORLD / (W - 1)
    before = hf64.pyramid(HEIGHT_SCALE * h.astype(np.float64), ls)
    out = {"field": f"{W}x{D} fbm seed 3", "ls": ls, "level_offset": lo, "azimuths": n_phi, "positions": {}}
    for name, where in POSITIONS.items():
        h2, rect = crater(h, where)
        after = hf64.pyramid(HEIGHT_SCALE * h2.astype(np.float64), ls)
        exact = diff_rects(before, after)
        grown = level_rects(W, D, ls, rect)
        cells = hf64.level_cells(W, D, ls)
        _, L = hf64.sample_plan(len(cells), ls, lo, sx)
        used = sorted(set(L.tolist()))

        def share(r, k):
            return 0.0 if r is None else (r[2] - r[0] + 1) * (r[3] - r[1] + 1) / ((cells[k][0] + 1) * (cells[k][1] + 1))

        for k in range(len(cells)):
            e, g = exact[k], grown[k]
            assert e is None or (g[0] <= e[0] and g[1] <= e[1] and g[2] >= e[2] and g[3] >= e[3]), (k, e, g)
        lanes, receiver, first = pyramid_lane_mask(W, D, ls, lo, n_phi, grown, sx, sz)
        lanes_exactbox, _, _ = pyramid_lane_mask(W, D, ls, lo, n_phi, exact, sx, sz, margin=0)
        # a search that restarts at a lane's first changed sample (3 earlier ones for the
        # spline's window, the maximum of the earlier candidates kept): the samples it redoes
        n_samples = len(cells)
        redo = np.where(first < n_samples, n_samples - np.maximum(first - 3, 0), 0)
        # what the kernel does: row groups of ROW_GROUP (their earliest first change), resumed at the
        # last checkpoint (every ls samples, >= 3) at or before it, 3 samples refill the window
        gfirst = first.copy()
        for g0 in range(0, W, ROW_GROUP):
            gfirst[:, g0:g0 + ROW_GROUP] = first[:, g0:g0 + ROW_GROUP].min(axis=1, keepdims=True)
        ncp = max((n_samples - 1) // ls, 1)
        ck = np.minimum(gfirst // ls, ncp)
        start = np.where(ck * ls >= 3, ck * ls, 0)
        redo_cp = np.where(gfirst < n_samples, n_samples - np.maximum(start - 3, 0), 0)
        groups = np.zeros_like(lanes)
        for g0 in range(0, W, ROW_GROUP):
            groups[:, g0:g0 + ROW_GROUP] = lanes[:, g0:g0 + ROW_GROUP].any(axis=1, keepdims=True)
        ex = exact_lane_mask(W, D, n_phi, rect, sx, sz)
        out["positions"][name] = {
            "edit_box": rect,
            "changed_share_per_used_level_grown": [round(share(grown[k], k), 4) for k in used],
            "changed_share_per_used_level_exact": [round(share(exact[k], k), 4) for k in used],
            "pyramid": {
                "lanes": float(lanes.mean()),
                "lanes_exact_boxes_no_margin": float(lanes_exactbox.mean()),
                "lanes_row_groups": float(groups.mean()),
                "vertices": float(lanes.any(axis=-1).mean()),
                "vertices_receiver_changed": float(receiver.mean()),
                "samples_if_restarted_at_first_change": float(redo.mean() / n_samples),
                "samples_row_groups_checkpoints": float(redo_cp.mean() / n_samples),
            },
            "exact_mode": {"lanes": float(ex.mean()), "vertices": float(ex.any(axis=-1).mean())},
        }
        print(name, json.dumps(out["positions"][name]["pyramid"]), json.dumps(out["positions"][name]["exact_mode"]),
              flush=True)
    return out


# --------------------------------------------------------------------------- speed


def speed(n: int = 257, rounds: int = 5, params: dict | None = None) -> dict:
    """Per crater position, interleaved rounds of: a full frame with partial_update = 1 (the
    whole field set: full pyramid, every lane searched and kept), the partial update (the
    crater's box set), and a full frame with partial_update = 0 (no horizons kept). Each is
    set_heights + commit + renderer.execute (env pass, shading) + finish, from the original
    heights rendered by that renderer; wall and process CPU time, medians."""
    import penumbra as pn
    from penumbra.imageio import read_envmap
    from penumbra.methods.heightfield import HeightFieldHandle

    ctx = pn.Context()
    h = terrain(n)
    D, W = h.shape
    env = pn.EnvMap(ctx, read_envmap(REPO / "../shared/data/envmaps/immenstadter_horn_1k_polyhaven.hdr"),
                    face_size=128, irradiance_face_size=32)
    field = HeightFieldHandle(ctx, h, origin=(-6.0, -3.0, -6.0), size=(SIZE_WORLD, SIZE_WORLD),
                              height_scale=HEIGHT_SCALE)
    mesh = field.mesh()
    scene = pn.Scene(ctx)
    scene.set_envmap(env)
    inst = scene.add(mesh, None, pn.Material(albedo=(0.55, 0.5, 0.42)))
    scene.attach(inst, field)
    scene.set_camera(pn.Camera(position=(0.0, 9.0, 6.0), look_at=(0.0, -1.5, 0.0), fov_deg=45.0,
                               resolution=(128, 96)))
    scene.commit()
    gb, img = pn.GBuffer(ctx, 128, 96), pn.Image(ctx, 128, 96)
    scene.render_gbuffer(gb)
    base = dict(params or {})
    keep = pn.Renderer(ctx, "heightfield", **base)
    plain = pn.Renderer(ctx, "heightfield", **{**base, "partial_update": 0})

    def frame(r):
        r.execute(scene, gb, img)
        ctx.finish()

    def timed(fn):
        w0, c0 = time.perf_counter(), time.process_time()
        fn()
        return time.perf_counter() - w0, time.process_time() - c0

    field.set_heights(h[:1, :1], region=(0, 0))  # a local edit: the field now keeps what partial updates need
    field.set_heights(h)
    frame(keep)
    frame(plain)
    res: dict = {"field": f"{W}x{D}", "rounds": rounds, "params": base or "defaults", "positions": {}}
    res["uptime_before"] = os.popen("uptime").read().strip()
    kinds = ("full", "partial", "full_no_keep")
    for name, where in POSITIONS.items():
        h2, (x0, y0, w, hh) = crater(h, where)
        t = {k: [] for k in kinds}
        searched = None
        for _ in range(rounds):
            for kind in kinds:
                r = plain if kind == "full_no_keep" else keep
                field.set_heights(h)
                frame(r)
                if kind == "partial":
                    t[kind].append(timed(lambda: (field.set_heights(h2[y0:y0 + hh, x0:x0 + w], region=(x0, y0)),
                                                  frame(r))))
                    searched = r.read_output(scene, "env_searched", inst)
                else:
                    t[kind].append(timed(lambda: (field.set_heights(h2), frame(r))))
        # the vertices the partial update shades again: horizons changed bit for bit (or normals)
        field.set_heights(h)
        before = (plain.read_output(scene, "env_horizons", inst), plain.read_output(scene, "normals", inst))
        field.set_heights(h2)
        after = (plain.read_output(scene, "env_horizons", inst), plain.read_output(scene, "normals", inst))
        shaded = ((before[0].view(np.uint32) != after[0].view(np.uint32)).any(axis=-1) |
                  (before[1] != after[1]).any(axis=-1))
        med = {k: (statistics.median(x[0] for x in v), statistics.median(x[1] for x in v)) for k, v in t.items()}
        res["positions"][name] = {
            "edit_box": [x0, y0, w, hh], "lanes_searched": float(searched.mean()),
            "vertices_searched": float((searched > 0).any(axis=-1).mean()),
            "vertices_shaded_again": float(shaded.mean()),
            **{f"{k}_wall_ms": 1e3 * med[k][0] for k in kinds}, **{f"{k}_cpu_ms": 1e3 * med[k][1] for k in kinds},
            "partial_over_full_wall": med["partial"][0] / med["full"][0],
            "partial_over_full_cpu": med["partial"][1] / med["full"][1],
            "full_over_no_keep_wall": med["full"][0] / med["full_no_keep"][0],
        }
        q = res["positions"][name]
        print(f"{name}: full {q['full_wall_ms']:.0f} ms wall ({q['full_cpu_ms']:.0f} cpu), partial "
              f"{q['partial_wall_ms']:.0f} ({q['partial_cpu_ms']:.0f}), no-keep full {q['full_no_keep_wall_ms']:.0f}: "
              f"partial/full {q['partial_over_full_wall']:.2f} wall, {q['partial_over_full_cpu']:.2f} cpu; "
              f"lanes searched {q['lanes_searched']:.3f}, uptime {os.popen('uptime').read().strip()}", flush=True)
    res["uptime_after"] = os.popen("uptime").read().strip()
    return res


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("part", nargs="?", default="all", choices=("fractions", "speed", "all"))
    ap.add_argument("--size", type=int, default=257)
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--exact", action="store_true", help="speed with exact_horizon = 1 as well")
    ap.add_argument("--out", default=str(REPO / "bench/results/heightfield_dynamic"))
    args = ap.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    print(os.popen("uptime").read().strip())
    if args.part in ("fractions", "all"):
        r = fractions(args.size)
        (out / f"fractions_{args.size}.json").write_text(json.dumps(r, indent=1))
    if args.part in ("speed", "all"):
        r = {"defaults": speed(args.size, args.rounds)}
        if args.exact:
            r["exact_horizon"] = speed(args.size, max(1, args.rounds // 2), {"exact_horizon": 1})
        (out / f"speed_{args.size}.json").write_text(json.dumps(r, indent=1))


if __name__ == "__main__":
    main()
