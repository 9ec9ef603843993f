"""Profile and A/B timing of the ray caster (kernels/common/raytrace.cl) on
the rays of penumbra.raybench: primary (closest hit) and shadow (any hit)
rays of the bench scenes, docs/performance.md "Ray casting".

For every scene, in one process:

* work per ray: box tests and triangle tests per query, from a profiling
  build of the kernels (-DPN_RAY_STATS, which reports the counts in place
  of the hit ids);
* time per ray: penumbra with each BVH layout (PENUMBRA_BVH_WIDTH=2, the
  binary BVH, =4 the 4-wide one, and =8 the default 8-wide one; plain and
  plain8: 4- and 8-wide with PENUMBRA_TRI_SOA=0) and Embree (embreex, 1 thread) on
  the same rays, in interleaved rounds (per round and query, one timed
  call of each tracer back to back, each after an untimed one; order
  rotated; warm-up round excluded), medians; plus the fixed cost of a call (the same number
  of rays, all missing the scene's bounds);
* checks that every layout gives Embree's hit/miss answers and the binary
  layout's hit distances.

  With --packed LAYOUT, that layout is also timed through the 8-float ray
  entry points (pn_scene_intersect / pn_scene_occluded on rays Scene packs),
  the host path Scene.intersect / occluded took before the ray-array entry
  points, and its answers are compared with the arrays path's.

    python bench/ray_profile.py [--scenes bunny_sunny,...] [--rounds 7] [--json out.json] [--packed wide8]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

import penumbra
from penumbra import raybench
from penumbra.render import build_scene
from penumbra.scenefile import load_scene

REPO = Path(__file__).resolve().parents[1]
SCENES = {
    "bunny_sunny": REPO / "bench/scenes/bunny_sunny.toml",
    "teapot_overcast": REPO / "bench/scenes/teapot_overcast.toml",
    "armadillo": REPO / "bench/scenes/depthmap/armadillo_uffizi.toml",
    "indoor_contact": REPO / "bench/scenes/indoor_contact.toml",
}
# Layouts compared; each gets its own context, built with these variables set.
LAYOUTS = {"binary": {"PENUMBRA_BVH_WIDTH": "2"}, "wide": {"PENUMBRA_BVH_WIDTH": "4"},
           "wide8": {"PENUMBRA_BVH_WIDTH": "8"},
           "plain": {"PENUMBRA_BVH_WIDTH": "4", "PENUMBRA_TRI_SOA": "0"},
           "plain8": {"PENUMBRA_BVH_WIDTH": "8", "PENUMBRA_TRI_SOA": "0"}}


def context(env: dict) -> penumbra.Context:
    """A context created with `env` added to the environment (read at creation)."""
    saved = {k: os.environ.get(k) for k in env}
    os.environ.update(env)
    try:
        return penumbra.Context()
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


def work_counts(desc, env: dict, rays: dict) -> dict:
    """Mean box and triangle tests per ray, per workload, in the layout of `env`."""
    out = {}
    for kind, mode in (("primary", "1"), ("shadow", "2")):
        opts = (os.environ.get("PENUMBRA_CL_BUILD_OPTIONS", "") + f" -DPN_RAY_STATS={mode}").strip()
        ctx = context({**env, "PENUMBRA_CL_BUILD_OPTIONS": opts})
        built = build_scene(desc, ctx)
        nodes, boxes, tests = built.scene.intersect(*rays[kind])
        out[kind] = {"nodes_per_ray": float(nodes.mean()), "boxes_per_ray": float(boxes.mean()),
                     "triangles_per_ray": float(tests.mean()),
                     "boxes_p99": float(np.percentile(boxes, 99)), "triangles_p99": float(np.percentile(tests, 99))}
    return out


def timed(fn, calls: int = 1) -> float:
    """Seconds per call of `calls` back-to-back calls."""
    t0 = time.perf_counter()
    for _ in range(calls):
        fn()
    return (time.perf_counter() - t0) / calls


def packed_query(scene, o, d, any_hit: bool):
    """Scene.intersect / Scene.occluded as they were before the ray-array entry
    points: rays packed into 8 floats (origin, tmin, direction, tmax) for
    pn_scene_intersect / pn_scene_occluded."""
    from penumbra.core import Scene

    rays = Scene._rays(o, d, 0.0, np.inf)
    n = len(rays)
    if any_hit:
        out = np.empty(n, np.uint8)
        scene._call("pn_scene_occluded", scene._h, rays.ctypes.data, n, out.ctypes.data)
        return out.view(bool)
    t, inst, tri = np.empty(n, np.float32), np.empty(n, np.uint32), np.empty(n, np.uint32)
    scene._call("pn_scene_intersect", scene._h, rays.ctypes.data, n, t.ctypes.data, inst.ctypes.data, tri.ctypes.data)
    return t, inst, tri


def profile_scene(name: str, rounds: int, layouts: dict, packed: str = "") -> dict:
    desc = load_scene(str(SCENES[name]))
    builts = {k: build_scene(desc, context(env)) for k, env in layouts.items()}
    first = next(iter(builts.values()))
    rays = raybench.workload(desc, first)
    tris = raybench.world_triangles(desc)
    em, _mesh = raybench.embree_scene(tris)
    res = {"scene": name, "triangles": int(len(tris)), "layouts": {}}

    # Answers: every layout against Embree (hit/miss) and the first layout (t).
    po, pd = rays["primary"]
    so, sd = rays["shadow"]
    em_hit = em.run(po, pd, query="INTERSECT", output=1)["primID"] != -1
    em_occ = em.run(so, sd, query="OCCLUDED") != -1
    t_ref = first.scene.intersect(po, pd)[0]
    if packed:
        pt, pi, ptri = packed_query(builts[packed].scene, po, pd, False)
        ct, ci, ctri = builts[packed].scene.intersect(po, pd)
        res["packed_differs"] = {"primary": int(((pt != ct) | (pi != ci) | (ptri != ctri)).sum()),
                                 "shadow": int((packed_query(builts[packed].scene, so, sd, True)
                                                != builts[packed].scene.occluded(so, sd)).sum())}
    for k, b in builts.items():
        t = b.scene.intersect(po, pd)[0]
        occ = b.scene.occluded(so, sd)
        res["layouts"][k] = {
            "primary_mismatches_vs_embree": int((np.isfinite(t) != em_hit).sum()),
            "shadow_mismatches_vs_embree": int((occ != em_occ).sum()),
            "primary_t_differs_from_first_layout": int((t != t_ref).sum()),
            "work": work_counts(desc, layouts[k], rays),
        }

    # Fixed cost of a call: as many rays, all missing the root box.
    n_p, n_s = len(po), len(so)
    far = lambda n: np.full((n, 3), 1e4, np.float32)  # noqa: E731
    away = lambda n: np.tile(np.float32([[0.577, 0.577, 0.577]]), (n, 1))  # noqa: E731
    jobs = {"embree": {"primary": lambda: em.run(po, pd, query="INTERSECT"),
                       "shadow": lambda: em.run(so, sd, query="OCCLUDED")}}
    for k, b in builts.items():
        s = b.scene
        jobs[k] = {"primary": (lambda s=s: s.intersect(po, pd)), "shadow": (lambda s=s: s.occluded(so, sd)),
                   "primary_miss": (lambda s=s, o=far(n_p), d=away(n_p): s.intersect(o, d)),
                   "shadow_miss": (lambda s=s, o=far(n_s), d=away(n_s): s.occluded(o, d))}
    if packed:
        # The same layout through the 8-float ray entry points (Scene packs
        # origins, directions and bounds first): the host path before the
        # ray-array entry points, for A/B in this run.
        s = builts[packed].scene
        jobs["packed"] = {"primary": (lambda s=s: packed_query(s, po, pd, False)),
                          "shadow": (lambda s=s: packed_query(s, so, sd, True)),
                          "primary_miss": (lambda s=s, o=far(n_p), d=away(n_p): packed_query(s, o, d, False)),
                          "shadow_miss": (lambda s=s, o=far(n_s), d=away(n_s): packed_query(s, o, d, True))}
    times = {k: {q: [] for q in v} for k, v in jobs.items()}
    order = list(jobs)
    queries = ["primary", "shadow", "primary_miss", "shadow_miss"]
    for r in range(rounds + 1):  # round 0 warms up
        # One query at a time, its tracers back to back (so a change of load
        # hits the samples that are compared alike), in an order rotated
        # each round; each timed call right after an untimed one of the same
        # job: the first call after another tracer ran pays for waking
        # PoCL's threads (measured: up to 4x on a 2 ms call).
        for q in queries:
            for k in order[r % len(order):] + order[:r % len(order)]:
                fn = jobs[k].get(q)
                if fn is None:
                    continue
                fn()
                # A primary call takes milliseconds: several per sample, so one
                # descheduling of a PoCL thread does not decide the sample.
                dt = timed(fn, 1 if q.startswith("shadow") else 8)
                if r:
                    times[k][q].append(dt)
    med = {k: {q: statistics.median(ts) for q, ts in v.items()} for k, v in times.items()}
    rays_n = {"primary": n_p, "shadow": n_s}
    res["rays"] = rays_n
    res["embree_mrays_per_s"] = {q: rays_n[q] / med["embree"][q] / 1e6 for q in rays_n}
    for k in builts:
        L = res["layouts"][k]
        for q in rays_n:
            L[f"{q}_ms"] = med[k][q] * 1e3
            L[f"{q}_miss_ms"] = med[k][f"{q}_miss"] * 1e3
            L[f"{q}_mrays_per_s"] = rays_n[q] / med[k][q] / 1e6
            L[f"{q}_vs_embree"] = med["embree"][q] / med[k][q]
            # Per-round ratios, then their median: robust to load changing between rounds.
            L[f"{q}_vs_embree_rounds"] = statistics.median(
                e / p for e, p in zip(times["embree"][q], times[k][q]))
    if packed:
        res["packed"] = {q: {"ms": med["packed"][q] * 1e3, "miss_ms": med["packed"][f"{q}_miss"] * 1e3,
                             "vs_embree_rounds": statistics.median(
                                 e / p for e, p in zip(times["embree"][q], times["packed"][q])),
                             "arrays_over_packed": statistics.median(
                                 p / a for p, a in zip(times["packed"][q], times[packed][q]))} for q in rays_n}
    if len(builts) > 1:
        # The last layout against each other one: medians of per-round time ratios.
        *others, last = list(builts)
        res["speedup"] = {a: {q: statistics.median(x / y for x, y in zip(times[a][q], times[last][q])) for q in rays_n}
                          for a in others}
    return res


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenes", default=",".join(SCENES))
    ap.add_argument("--rounds", type=int, default=7)
    ap.add_argument("--layouts", default="binary,wide,wide8", help="subset of " + ",".join(LAYOUTS))
    ap.add_argument("--json", default="")
    ap.add_argument("--packed", default="", help="also time this layout through the 8-float ray entry points")
    args = ap.parse_args(argv)
    layouts = {}
    for k in args.layouts.split(","):
        # name, or name=-DDEFINE... (the default layout built with extra options)
        name, _, opts = k.partition("=")
        layouts[name] = {"PENUMBRA_CL_BUILD_OPTIONS": opts} if opts else LAYOUTS[name]
    load = subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip()
    print(f"load: {load}")
    out = {"load_before": load, "scenes": []}
    for name in args.scenes.split(","):
        r = profile_scene(name, args.rounds, layouts, args.packed)
        out["scenes"].append(r)
        print(f"\n{name}: {r['triangles']} triangles, {r['rays']['primary']} primary, {r['rays']['shadow']} shadow rays;"
              f" Embree {r['embree_mrays_per_s']['primary']:.2f} / {r['embree_mrays_per_s']['shadow']:.2f} Mrays/s")
        for k, L in r["layouts"].items():
            w = L["work"]
            print(f"  {k:7s} primary {L['primary_mrays_per_s']:6.2f} Mrays/s ({L['primary_ms']:.2f} ms, miss-only"
                  f" {L['primary_miss_ms']:.2f}) x{L['primary_vs_embree_rounds']:.2f} Embree,"
                  f" {w['primary']['nodes_per_ray']:.1f} nodes {w['primary']['boxes_per_ray']:.1f} boxes"
                  f" {w['primary']['triangles_per_ray']:.1f} tris/ray |"
                  f" shadow {L['shadow_mrays_per_s']:6.2f} Mrays/s ({L['shadow_ms']:.2f} ms, miss-only"
                  f" {L['shadow_miss_ms']:.2f}) x{L['shadow_vs_embree_rounds']:.2f} Embree,"
                  f" {w['shadow']['nodes_per_ray']:.1f} nodes {w['shadow']['boxes_per_ray']:.1f} boxes"
                  f" {w['shadow']['triangles_per_ray']:.1f} tris/ray |"
                  f" mismatches {L['primary_mismatches_vs_embree']}/{L['shadow_mismatches_vs_embree']},"
                  f" t differs {L['primary_t_differs_from_first_layout']}")
        if args.packed:
            P = r["packed"]
            print(f"  packed  primary {P['primary']['ms']:.2f} ms (miss-only {P['primary']['miss_ms']:.2f})"
                  f" x{P['primary']['vs_embree_rounds']:.2f} Embree | shadow {P['shadow']['ms']:.2f} ms (miss-only"
                  f" {P['shadow']['miss_ms']:.2f}) x{P['shadow']['vs_embree_rounds']:.2f} Embree | arrays/packed"
                  f" speed-up primary {P['primary']['arrays_over_packed']:.2f}x shadow"
                  f" {P['shadow']['arrays_over_packed']:.2f}x | answers differ {r['packed_differs']}")
        for a, sp in r.get("speedup", {}).items():
            print(f"  {list(layouts)[-1]}/{a} speed-up (per-round median): primary {sp['primary']:.2f}x,"
                  f" shadow {sp['shadow']:.2f}x")
    out["load_after"] = subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip()
    print(f"\nload: {out['load_after']}")
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
