#!/usr/bin/env python3
"""Measurements of the env map decomposition (pn_envmap_decompose,
docs/depthmap.md "Decomposition"; issue 14): its time, and the quadrature
error of the unshadowed irradiance by N next to median cut (Debevec 2005).

  time   decomposition time of the library (seed 1, the default cap of 100
         Lloyd iterations) on a 1k (1024 x 512) and a 2k (2048 x 1024) map,
         N = 16 ... 1024; a new EnvMap per run (no cache), after one warm-up
         that builds the kernel. The 2k map is the 1k one with every texel
         repeated 2 x 2 (../shared/data has no 2k maps; the texel count is
         what the cost depends on). "1 iteration" runs max_iterations = 1: the
         fixed cost (reading the map, the draw, the tile cones, two
         assignments) that the full run adds Lloyd iterations to.
  error  relative RMS error of the luminance of E_N(n) = sum_i L~_i max(0, n . c_i)
         against the exact irradiance of the discretised map over 512 normals
         of a spherical Fibonacci lattice (tests/depthmap64.py irradiance_error),
         N = 16, 32, 64, 128, 256: the library's Lloyd domains (seed 1) and the
         float64 twin's median cut, on the maps of ../shared/data/envmaps
         (sunny, overcast, indoor, light probes).

Run from the repository root:

  PENUMBRA_LIBRARY=build/libpenumbra.so PYTHONPATH=python \\
      python bench/env_domains_experiments.py [--quick] [--only time,error] [--out bench/results/env_domains]

Runs on bench/harness.py: OUT/results.json (merged per experiment),
OUT/report.md rewritten from it (--report-only). --quick (256 x 128 and
512 x 256 maps, fewer N and maps) writes to OUT/quick/.
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import harness  # noqa: E402
from harness import REPO, Experiment, Suite, log  # noqa: E402

sys.path.insert(0, str(REPO / "tests"))
import depthmap64 as dm  # noqa: E402

import penumbra  # noqa: E402
from penumbra.imageio import read_envmap  # noqa: E402

SCRIPT = "bench/env_domains_experiments.py"
ENVMAPS = REPO.parent / "shared" / "data" / "envmaps"
SEED = 1
TIME_MAP = "immenstadter_horn_1k_polyhaven.hdr"
TIME_NS = (16, 32, 64, 128, 256, 512, 1024)
ERROR_NS = (16, 32, 64, 128, 256)
# (kind, file) of the error table
ERROR_MAPS = (
    ("sunny", "immenstadter_horn_1k_polyhaven.hdr"),
    ("sunny", "venice_sunset_1k_polyhaven.hdr"),
    ("overcast", "potsdamer_platz_1k_polyhaven.hdr"),
    ("indoor", "st_fagans_interior_1k_polyhaven.hdr"),
    ("indoor", "studio_small_03_1k_polyhaven.hdr"),
    ("probe", "uffizi_probulator_256x128.hdr"),
    ("probe", "grace_probulator_256x128.hdr"),
)


def load(name: str, quick: bool) -> np.ndarray:
    env = read_envmap(ENVMAPS / name).astype(np.float32)
    if quick and env.shape[1] > 256:  # box-filter 1k maps down to 256 x 128
        f = env.shape[1] // 256
        env = env.reshape(env.shape[0] // f, f, env.shape[1] // f, f, 3).mean(axis=(1, 3))
    return env


def timed_decompose(ctx, env: np.ndarray, n: int, max_iterations: int = 0) -> float:
    em = penumbra.EnvMap(ctx, env, face_size=8, irradiance_face_size=4)  # small cubes: the commit is not timed
    t0 = time.perf_counter()
    em.decompose(n, seed=SEED, max_iterations=max_iterations)
    return time.perf_counter() - t0


def run_time(run) -> dict:
    base = load(TIME_MAP, run.quick)
    if run.quick:
        base = base[::2, ::2].copy()
    big = np.repeat(np.repeat(base, 2, axis=0), 2, axis=1)
    maps = {"quick": base, "quick 2x2": big} if run.quick else {"1k": base, "2k": big}
    ns = TIME_NS[:3] if run.quick else TIME_NS
    timed_decompose(run.ctx, base, 4, 1)  # kernel build
    rows = []
    for label, env in maps.items():
        for n in ns:
            one = timed_decompose(run.ctx, env, n, 1)
            full = timed_decompose(run.ctx, env, n)
            log(f"time {label} ({env.shape[1]}x{env.shape[0]}) N={n}: {full:.2f} s, 1 iteration {one:.2f} s")
            rows.append({"map": label, "width": env.shape[1], "height": env.shape[0], "n": n, "seconds": full,
                         "one_iteration_seconds": one, "loadavg": os.getloadavg()[0]})
    return {"map": TIME_MAP, "rows": rows}


def library_domains(ctx, env: np.ndarray, n: int) -> dm.Domains:
    d = penumbra.EnvMap(ctx, env, face_size=8, irradiance_face_size=4).decompose(n, seed=SEED)
    c = d.directions.astype(np.float64)
    return dm.Domains(c / np.linalg.norm(c, axis=1, keepdims=True), d.radiance.astype(np.float64),
                      d.solid_angle.astype(np.float64), d.cap_radius.astype(np.float64), assign=None)


def run_error(run) -> dict:
    maps = ERROR_MAPS[::3] if run.quick else ERROR_MAPS
    ns = ERROR_NS[:3] if run.quick else ERROR_NS
    normals = dm.fibonacci_sphere(512)
    rows = []
    for kind, name in maps:
        env = load(name, run.quick)
        tex = dm.texels(env)
        exact = dm.exact_irradiance(tex, normals)
        for n in ns:
            e_lloyd = dm.irradiance_error(tex, library_domains(run.ctx, env, n), normals, exact=exact)
            e_cut = dm.irradiance_error(tex, dm.median_cut(tex, n), normals, exact=exact)
            log(f"error {name} N={n}: Lloyd {e_lloyd:.3g}, median cut {e_cut:.3g}")
            rows.append({"kind": kind, "map": name, "width": env.shape[1], "height": env.shape[0], "n": n,
                         "lloyd": e_lloyd, "median_cut": e_cut})
    return {"rows": rows, "normals": len(normals)}


EXPERIMENTS = (
    Experiment("time", "decomposition time at 1k and 2k by N", run_time),
    Experiment("error", "irradiance quadrature error by N, Lloyd against median cut", run_error),
)


def report(results: dict) -> str:
    meta, ex = results["meta"], results["experiments"]
    L = ["# Env map decomposition: time and irradiance error", ""]
    L.append(harness.generated_by(meta, SCRIPT, "shared with other work, so timings are noisy") + ".")
    L.append("")
    if "time" in ex:
        t = ex["time"]
        L += [f"## Decomposition time (`{t['map']}`, seed {SEED}, at most 100 Lloyd iterations)", "",
              "| map | N | seconds | 1 iteration (fixed cost) | load average |", "|---|---|---|---|---|"]
        for r in t["rows"]:
            load = r.get("loadavg")
            L.append(f"| {r['map']} ({r['width']}x{r['height']}) | {r['n']} | {r['seconds']:.2f} | "
                     f"{r['one_iteration_seconds']:.2f} | {'-' if load is None else f'{load:.1f}'} |")
        if t.get("note"):
            L += ["", t["note"]]
        L.append("")
    if "error" in ex:
        rows = ex["error"]["rows"]
        ns = sorted({r["n"] for r in rows})
        L += [f"## Irradiance quadrature error ({ex['error']['normals']} normals; relative RMS of luminance)", "",
              "| kind | map | method | " + " | ".join(f"N = {n}" for n in ns) + " |",
              "|---|---|---|" + "---|" * len(ns)]
        for name in dict.fromkeys(r["map"] for r in rows):
            mine = {r["n"]: r for r in rows if r["map"] == name}
            kind = next(iter(mine.values()))["kind"]
            for method, key in (("Lloyd (library)", "lloyd"), ("median cut", "median_cut")):
                L.append(f"| {kind} | `{name}` | {method} | " + " | ".join(f"{mine[n][key]:.3g}" for n in ns) + " |")
        ratios = [r["median_cut"] / r["lloyd"] for r in rows]
        L += ["", f"Median cut over Lloyd: {min(ratios):.2f}-{max(ratios):.2f} (median {np.median(ratios):.2f}) "
              f"over {len(ratios)} (map, N) pairs; Lloyd is better in {sum(x > 1 for x in ratios)} of them.", ""]
    return "\n".join(L)


def meta(run) -> dict:
    return {"quick": run.quick, "library": str(run.library) if run.library else None}


class Runner(harness.Runner):
    cached = "nothing cached (no reference renders)"


SUITE = Suite(script=SCRIPT, description=__doc__, experiments=EXPERIMENTS, runner=Runner, report=report,
              default_out="bench/results/env_domains", meta=meta,
              quick_help="smoke run: 128 x 64 / 256 x 128 maps, N up to 64, three maps")

if __name__ == "__main__":
    sys.exit(harness.main(SUITE))
