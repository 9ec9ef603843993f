#!/usr/bin/env python3
"""The isg method's prefiltered env Gamma_L (docs/isg.md section 8, seed eq. 10)
and its two specular paths (`specular_mode` 0: the env cube on the BRDF lobe's
visible patches; 1: Gamma_L at the lobe's axis times the patches' visible share).

  a  the table: levels, memory, build time (the library's first frame after
     an env change with specular_mode 1 against 0, interleaved; and the build
     kernels alone through pyopencl), on Pisa (smooth) and rooitou park (a sun)
  b  images against `reference`: the seed's Fig. 12 (bunny and floor, Phong
     1000, k_s 0.5 on both; with --all-scenes also 0.01 on the bunny) and a
     GGX scene (roughness 0.05 and 0.15, k_s 0.5), both modes; frame times of both modes
     interleaved in one process (CPU ms of the process, minimum of 3)
  c  error of the lookup against the exact convolution of the env cube by
     lambda (at the levels and half-way between them in log lambda), on the
     same two maps

Run from the repository root (the same library as the package):

  python bench/isg_prefilter.py [--quick] [--only a,b] [--out bench/results/isg/prefilter]
"""

from __future__ import annotations

import copy
import sys
import time
from pathlib import Path

import numpy as np
import pyopencl as cl

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
import harness  # noqa: E402
from harness import Experiment, Suite, f4, generated_by, log  # noqa: E402
from isg_experiments import DATA, PISA, IsgRunner, bunny_scene  # noqa: E402
from isg_shading64 import cube_directions, gamma_lookup, prefilter  # noqa: E402  the float64 twin
from test_isg_prefilter import device_gamma as run_gamma_kernels  # noqa: E402

from penumbra import GBuffer, Image, Renderer  # noqa: E402
from penumbra.kernels import expand  # noqa: E402
from penumbra.render import render  # noqa: E402

ROOITOU = str(DATA / "envmaps" / "rooitou_park_1k_polyhaven.hdr")


def load() -> str:
    """uptime's load averages (the machine is shared: every number is taken under them)."""
    return " ".join(Path("/proc/loadavg").read_text().split()[:3])


class PrefilterRunner(IsgRunner):
    """48 x 36 pixels (a face-64 reference takes about 5 minutes of the loaded shared cores at this size);
    the reference at face 64 (the seed's 6 x 64 x 64 rays; a glossiness-1000 lobe is 0.03 rad wide), face
    32 with --quick."""

    def res(self, full=(48, 36)):
        return (48, 36) if self.quick else full

    def reference(self, table: dict, built):
        face = 32 if self.quick else 64
        key = ("isg", table, face, harness.kernel_hash(lambda n: n.startswith(("reference", "raycast", "common"))))
        ref, _ = self.references.get(key, lambda: render(built, "reference", frames=1, warmup=False, face_size=face,
                                                         sun_supersampling=4).image[..., :3])
        return ref, None


def device_gamma(queue_ctx, rgb: np.ndarray, face: int):
    """The build kernels as the library runs them (the tests' pyopencl driver of them): (levels, tables,
    seconds of the kernels, waited for)."""
    ctx = queue_ctx[0]
    build = lambda src: cl.Program(ctx, expand("common/math.cl", src)).build(options=["-cl-std=CL1.2"])  # noqa: E731
    seconds: list[float] = []
    levels, tables, _ = run_gamma_kernels(queue_ctx, build, rgb, face, seconds)
    return levels, [t.astype(np.float64) for t in tables], seconds[0]


def env_scene(env_map: str, res=(64, 48)) -> dict:
    t = bunny_scene(res, ks_bunny=0.5, ks_floor=0.5)
    t["environment"]["map"] = env_map
    return t


def first_frames(run, table: dict, reps: int = 3) -> dict:
    """The library's first frame after an env change (plan: the lobe fit, and Gamma_L for specular_mode 1,
    which the context keeps per env map: each frame here gets a new map, its intensity nudged by 1e-4)
    and a second frame, modes interleaved: the build is the difference of the two modes' differences."""
    built = run.build(table)
    w, h = table["camera"]["resolution"]
    gb = GBuffer(built.ctx, w, h)
    built.scene.render_gbuffer(gb)
    img = Image(built.ctx, w, h)
    Renderer(built.ctx, "isg", specular_mode=1).execute(built.scene, gb, img)  # compile once
    built.ctx.finish()
    out, nudge = {0: [], 1: []}, 0
    for _ in range(reps):
        for mode in (0, 1):
            nudge += 1
            built.envmap.set(intensity=1.0 + 1e-4 * nudge)
            built.envmap.commit()
            built.scene.commit()
            r = Renderer(built.ctx, "isg", specular_mode=mode)
            t0, c0 = time.perf_counter(), time.process_time()
            r.execute(built.scene, gb, img)
            built.ctx.finish()
            t1, c1 = time.perf_counter(), time.process_time()
            r.execute(built.scene, gb, img)
            built.ctx.finish()
            t2, c2 = time.perf_counter(), time.process_time()
            out[mode].append(((t1 - t0) - (t2 - t1), (c1 - c0) - (c2 - c1)))
    med = lambda mode, i: float(np.median([x[i] for x in out[mode]]))  # noqa: E731
    return {"build_wall_s": med(1, 0) - med(0, 0), "build_cpu_s": med(1, 1) - med(0, 1)}


MAPS = (("pisa", PISA), ("rooitou", ROOITOU))


def exp_a(run: PrefilterRunner) -> dict:
    """The table's memory and build time, per map."""
    out = {"load": load(), "maps": {}}
    for name, path in MAPS:
        table = env_scene(path)
        built = run.build(table)
        cube = built.envmap.cube_radiance()
        face = cube.shape[1]
        levels, _, kernel_s = device_gamma(run.ctx.cl_objects(), cube.reshape(-1, 3).astype(np.float64), face)
        mem = sum(16 * 6 * n * n for _, n, _ in levels)
        lib = first_frames(run, table)
        out["maps"][name] = {"face": face, "levels": len(levels), "bytes": mem, "kernels_s": kernel_s, **lib}
        log(f"  {name}: face {face}, {len(levels)} levels, {mem / 2**20:.2f} MiB, kernels {kernel_s:.2f} s, "
            f"library +{lib['build_wall_s']:.2f} s wall, +{lib['build_cpu_s']:.2f} s CPU")
    out["load_after"] = load()
    return out


def exp_c(run: PrefilterRunner) -> dict:
    """The lookup's error against the exact convolution, by lambda, per map."""
    out = {"load": load(), "maps": {}}
    rng = np.random.default_rng(5)
    q = rng.normal(size=(1000 if run.quick else 3000, 3))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    lum = lambda x: x @ np.array([0.2126, 0.7152, 0.0722])  # noqa: E731
    for name, path in MAPS:
        built = run.build(env_scene(path))
        cube = built.envmap.cube_radiance()
        face = cube.shape[1]
        rgb = cube.reshape(-1, 3).astype(np.float64)
        dirs = cube_directions(face)
        levels, tables, _ = device_gamma(run.ctx.cl_objects(), rgb, face)
        rows = []
        for lam, n, n_src in levels:
            for at in (lam, lam * 2 ** 0.5):
                if at > levels[-1][0]:
                    continue
                want = prefilter(rgb, dirs, at, q, cut=None)
                got = np.array([gamma_lookup(levels, tables, d, at) for d in q])
                err = np.sqrt(np.mean((got - want) ** 2)) / np.sqrt(np.mean(want ** 2))
                rel = np.abs(lum(got) - lum(want)) / np.maximum(lum(want), 1e-30)
                rows.append({"lambda": at, "level": at == lam, "vertices": n, "source": n_src, "rel_rms": err,
                             "p99_rel": float(np.quantile(rel, 0.99)), "max_rel": float(rel.max())})
        out["maps"][name] = {"face": face, "directions": len(q), "rows": rows}
        log(f"  {name}: " + ", ".join(f"{r['lambda']:.4g}: {r['rel_rms']:.2e}" for r in rows))
    return out


def ggx_scene(res, roughness: float) -> dict:
    t = bunny_scene(res, ks_bunny=0.5, ks_floor=0.5)
    for o in t["object"]:
        o.pop("shininess")
        o["lobe"], o["roughness"] = "ggx", roughness
    return t


def frame_cpu_ms(built, table, params_list, reps=3) -> list[float]:
    """CPU ms of the process for one frame of each params, interleaved, minimum of reps."""
    w, h = table["camera"]["resolution"]
    gb = GBuffer(built.ctx, w, h)
    built.scene.render_gbuffer(gb)
    img = Image(built.ctx, w, h)
    rs = [Renderer(built.ctx, "isg", **p) for p in params_list]
    for r in rs:
        r.execute(built.scene, gb, img)
    built.ctx.finish()
    best = [float("inf")] * len(rs)
    for _ in range(reps):
        for i, r in enumerate(rs):
            c0 = time.process_time()
            r.execute(built.scene, gb, img)
            built.ctx.finish()
            best[i] = min(best[i], 1e3 * (time.process_time() - c0))
    return best


def exp_b(run: PrefilterRunner) -> dict:
    res = run.res()
    scenes = {"fig12 ks=0.5": bunny_scene(res, ks_bunny=0.5, ks_floor=0.5),
              "ggx 0.05": ggx_scene(res, 0.05), "ggx 0.15": ggx_scene(res, 0.15)}
    if run.args.all_scenes:
        scenes["fig12 ks=0.01"] = bunny_scene(res, ks_bunny=0.01, ks_floor=0.5)
    variants = [("patches (0)", "isg", {"specular_mode": 0}), ("prefiltered (1)", "isg", {"specular_mode": 1}),
                ("patches (0), env_sharpness 10", "isg", {"specular_mode": 0, "env_sharpness": 10.0}),
                ("prefiltered (1), env_sharpness 10", "isg", {"specular_mode": 1, "env_sharpness": 10.0})]
    out = {"load_before": load(), "scenes": {}}
    for name, table in scenes.items():
        rows = run.evaluate(table, variants, name.replace(" ", "_").replace("=", ""))
        ms = frame_cpu_ms(run.build(table), table, [v[2] for v in variants])
        for r, m in zip(rows, ms):
            r["cpu_ms"] = m
        out["scenes"][name] = rows
    out["load_after"] = load()
    return out


def report(results: dict) -> str:
    meta = results["meta"]
    lines = ["# isg prefiltered lighting", "", generated_by(meta, "bench/isg_prefilter.py", "2 shared cores") + ".", ""]
    ex = results["experiments"]
    if "a" in ex:
        lines += ["## a. The table", "", f"load: {ex['a'].get('load')} before, {ex['a'].get('load_after')} after", ""]
        for name, m in ex["a"]["maps"].items():
            lines += [f"* {name}: face {m['face']}, {m['levels']} levels, {m['bytes'] / 2**20:.2f} MiB; build "
                      f"kernels {m['kernels_s']:.2f} s wall; library first frame +{m['build_wall_s']:.2f} s wall, "
                      f"+{m['build_cpu_s']:.2f} s CPU"]
        lines.append("")
    if "c" in ex:
        lines += ["## c. Lookup against the exact convolution", "", f"load: {ex['c'].get('load')}", ""]
        for name, m in ex["c"]["maps"].items():
            lines += [f"### {name}: face {m['face']}, {m['directions']} random directions", "",
                      "| lambda | at a level | vertices | source face | rel RMS | p99 rel (luminance) | max rel |",
                      "|---|---|---|---|---|---|---|"]
            for r in m["rows"]:
                lines.append(f"| {r['lambda']:.4g} | {'yes' if r['level'] else 'between'} | {r['vertices']} | "
                             f"{r['source']} | {f4(r['rel_rms'])} | {f4(r['p99_rel'])} | {f4(r['max_rel'])} |")
            lines.append("")
    if "b" in ex:
        lines += ["## b. Images against the reference; CPU ms a frame (min of 3, interleaved)", "",
                  f"load before {ex['b'].get('load_before')}, after {ex['b'].get('load_after')}", ""]
        for name, rows in ex["b"]["scenes"].items():
            lines += [f"### {name}", "", "| setting | rel RMS | bias | CPU ms |", "|---|---|---|---|"]
            for r in rows:
                lines.append(f"| {r['label']} | {f4(r['rel_rms'])} | {f4(r['bias'])} | {f4(r['cpu_ms'])} |")
            lines.append("")
    return "\n".join(lines) + "\n"


SUITE = Suite(
    script="bench/isg_prefilter.py", description=__doc__,
    experiments=(Experiment("a", "the table: memory, build time", exp_a),
                 Experiment("b", "images and frame times", exp_b),
                 Experiment("c", "lookup error by lambda", exp_c)),
    runner=PrefilterRunner, report=report, default_out="bench/results/isg/prefilter",
    add_arguments=lambda ap: ap.add_argument("--all-scenes", action="store_true",
                                             help="also Fig. 12 with k_s 0.01 on the bunny"),
    meta=lambda run: {"quick": run.quick})

if __name__ == "__main__":
    sys.exit(harness.main(SUITE))
