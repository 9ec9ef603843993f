"""Speed against error (docs/benchmarks.md): for one scene, sweep each
method's quality knobs, time every setting by the measuring protocol, measure
its error against a cached high-quality reference, run Mitsuba 3 on the same
scene at 1, 2, 4 ... spp in the same process, measure ray throughput against
Embree, and write results.json, results.csv, pareto.png and report.md."""

from __future__ import annotations

import csv
import hashlib
import io
import json
import math
import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from . import __version__
from .core import Context
from .errors import InputError
from .fileutil import atomic_write, atomic_write_text
from .metrics import compare, write_heatmap
from .render import METHODS, build_scene, render
from .scenefile import SceneDescription

# Each method's quality knobs, cheapest first. `floor` is timed separately
# (every method's time is reported as a multiple of it).
SWEEPS: dict[str, list[dict[str, Any]]] = {
    "unshadowed": [{}],
    # fiv: bake grids in the paper's (phi, theta, radii) notation, then the
    # overlap modes at the finer grid (1, the pair correction, is the default).
    "fiv": [{"samples": [32, 17, 15]}, {"samples": [64, 33, 30]}, {"samples": [64, 33, 30], "overlap": 0},
            {"samples": [64, 33, 30], "overlap": 2}],
    # heightfield (docs/heightfield.md): azimuths, pyramid level step and SH
    # bands from the cheapest up to the defaults (32, 4, 4), then the seed's
    # all-SH product (exact_unoccluded 0) and 6 bands at the defaults.
    "heightfield": [{"azimuths": 8, "level_step": 1, "bands": 3}, {"azimuths": 8}, {"azimuths": 16, "level_step": 2},
                    {"azimuths": 16}, {}, {"exact_unoccluded": 0}, {"bands": 6}],
    "reference": [{"face_size": f} for f in (4, 8, 16, 32)],
}
# The methods of a run when none are given; run() keeps fiv only for scenes
# with occluders (without any it shades like unshadowed) and heightfield only
# for scenes with height fields (applicable_methods).
DEFAULT_METHODS = ("unshadowed", "fiv", "heightfield", "reference")
# The fiv setting the README table shows.
README_FIV = {"samples": [64, 33, 30]}
RESULT_KEYS = ("method", "params", "time_ms", "shade_ms", "floor_ratio", "nrmse", "rel_rms", "max_abs",
               "mitsuba_speedup")


@dataclass
class BenchOptions:
    methods: tuple[str, ...] = DEFAULT_METHODS   # the default is narrowed to the scene (applicable_methods)
    frames: int = 5
    reference_face_size: int = 64          # the ground truth the errors are measured against
    reference_sun_supersampling: int = 4
    spp: tuple[int, ...] = tuple(2 ** k for k in range(11))   # 1 ... 1024
    mitsuba_variant: str | None = None     # None: llvm_ad_rgb, scalar_rgb if LLVM is missing
    rays: bool = True                      # ray throughput against Embree
    sweeps: dict[str, list[dict[str, Any]]] = field(default_factory=lambda: dict(SWEEPS))


def applicable_methods(desc: SceneDescription, methods=DEFAULT_METHODS) -> tuple[str, ...]:
    """``methods`` without those that have nothing of their own to do in the
    scene: ``fiv`` without occluders (it would shade like ``unshadowed``) and
    ``heightfield`` without height fields."""
    skip = set()
    if not any(obj.is_occluder for obj in desc.objects):
        skip.add("fiv")
    if not getattr(desc, "heightfields", None):
        skip.add("heightfield")
    return tuple(m for m in methods if m not in skip)


def _reference_key(desc: SceneDescription, opts: BenchOptions) -> str:
    """Cache key of the ground truth: the scene (height fields with the
    contents of their height and albedo files), the reference settings and the
    kernel sources that compute it."""
    from .kernels import kernel_dir

    h = hashlib.sha256()
    heightfields = list(getattr(desc, "heightfields", None) or [])
    h.update(repr((desc.environment, desc.camera, desc.objects, desc.lights, heightfields)).encode())
    for d in heightfields:
        for path in (d.file, d.albedo_map):
            if path is not None and Path(path).is_file():
                h.update(Path(path).read_bytes())
    h.update(repr((opts.reference_face_size, opts.reference_sun_supersampling, __version__)).encode())
    for path in sorted(Path(kernel_dir()).rglob("*.cl")):
        h.update(path.read_bytes())
    return h.hexdigest()[:16]


def ground_truth(built, desc: SceneDescription, opts: BenchOptions, cache_dir: Path, log=print) -> np.ndarray:
    """The reference image at the ground-truth settings, cached in cache_dir."""
    path = cache_dir / f"reference-{_reference_key(desc, opts)}.npy"
    if path.is_file():
        log(f"ground truth: cached {path}")
        return np.load(path)
    t0 = time.perf_counter()
    res = render(built, "reference", frames=1, warmup=False, background=0, face_size=opts.reference_face_size,
                 sun_supersampling=opts.reference_sun_supersampling)
    image = res.image[..., :3].astype(np.float32)
    cache_dir.mkdir(parents=True, exist_ok=True)
    def save(tmp: str) -> None:
        with open(tmp, "wb") as f:
            np.save(f, image)

    atomic_write(path, save)
    log(f"ground truth: reference face_size={opts.reference_face_size} "
        f"sun_supersampling={opts.reference_sun_supersampling} in {time.perf_counter() - t0:.1f} s")
    return image


def _mitsuba_time_at(curve: list[dict], err: float) -> tuple[float, str]:
    """Mitsuba's time at error `err`, log-log interpolated along its spp curve;
    ('>' or '<', bound) when err lies outside the measured range."""
    pts = sorted((c["nrmse"], c["time_ms"]) for c in curve if c["nrmse"] > 0 and math.isfinite(c["nrmse"]))
    if not pts:
        return float("nan"), ""
    errs = np.log([p[0] for p in pts])
    times = np.log([p[1] for p in pts])
    if err < pts[0][0]:
        return pts[0][1], ">"   # Mitsuba never got this low: it needs more than its largest spp
    if err > pts[-1][0]:
        return pts[-1][1], "<"  # even 1 spp is more accurate
    # A larger error never needs more time (noise can make the curve wiggle).
    times = np.minimum.accumulate(times)
    return float(np.exp(np.interp(np.log(err), errs, times))), ""


def run(scene_path: str | Path, out_dir: str | Path, opts: BenchOptions | None = None, overrides=(),
        log=print) -> dict:
    """Runs the benchmark of one scene file and writes its report files into out_dir."""
    from .scenefile import load_scene

    opts = opts or BenchOptions()
    for m in opts.methods:
        if m not in METHODS:
            raise InputError(f"unknown method '{m}' (available: {', '.join(METHODS)})")
    if opts.frames < 5:
        raise InputError(f"frames = {opts.frames}: the measuring protocol takes the median of at least 5")
    desc = load_scene(scene_path, list(overrides))
    # The default list keeps only the methods that apply to this scene; methods given explicitly all run.
    methods = applicable_methods(desc, opts.methods) if tuple(opts.methods) == DEFAULT_METHODS else opts.methods
    for m in methods:
        if m not in opts.sweeps:
            raise InputError(f"method '{m}' has no benchmark sweep (swept: {', '.join(opts.sweeps)})")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    if desc.fiv.cache is None:  # fiv bakes beside the cached ground truth
        desc.fiv.cache = str(out / "cache" / "fiv")
    ctx = Context()
    built = build_scene(desc, ctx)
    truth = ground_truth(built, desc, opts, out / "cache", log)

    floor = render(built, "floor", frames=opts.frames)
    mask = floor.gbuffer["instance"] != 0xFFFFFFFF
    if not mask.any():
        raise InputError(f"{scene_path}: the camera sees no geometry, nothing to measure")
    floor_ms = floor.timings_ms["shade_median"]
    log(f"floor: {floor_ms:.3f} ms shading, G-buffer {floor.timings_ms['gbuffer_median']:.2f} ms")

    results = []
    for method in methods:
        for params in opts.sweeps[method]:
            res = render(built, method, frames=opts.frames, background=0, **params)
            err = compare(truth, res.image[..., :3], mask)
            t = res.timings_ms
            row = {"method": method, "params": params, "time_ms": t["frame_median"],
                   "shade_ms": t["shade_median"], "floor_ratio": t["shade_median"] / floor_ms,
                   "nrmse": err["nrmse"], "rel_rms": err["rel_rms"], "max_abs": err["max_abs"],
                   "image": res.image[..., :3]}
            if method == "fiv":  # the precomputation: fields, their memory, and the bake time when baked now
                recs = built.fiv_records
                row["fiv_fields"] = len(recs)
                row["fiv_bytes"] = sum(r["stored_bytes"] for r in recs)
                row["bake_s"] = sum(r["bake_s"] for r in recs) if all(r["baked"] for r in recs) else None
            results.append(row)
            log(f"{method} {_fmt_params(params)}: {t['frame_median']:.2f} ms, NRMSE {err['nrmse']:.4f}")

    mitsuba = _run_mitsuba(desc, opts, truth, mask, log)
    for r in results:
        t, bound = _mitsuba_time_at(mitsuba["curve"], r["nrmse"]) if mitsuba["curve"] else (float("nan"), "")
        r["mitsuba_speedup"] = t / r["time_ms"]
        r["mitsuba_speedup_bound"] = bound

    rays, rays_skipped = None, None
    if opts.rays and getattr(desc, "heightfields", None):
        # raybench builds Embree's scene from desc.objects only: it would miss the terrain.
        rays_skipped = "the Embree comparison (penumbra.raybench) does not cover height fields"
        log(f"rays: skipped ({rays_skipped})")
    elif opts.rays:
        from .raybench import measure

        rays = measure(desc, built, repeats=opts.frames)
        log(f"rays: primary {rays['primary']['ratio']:.2f}x Embree, shadow {rays['shadow']['ratio']:.2f}x Embree")

    summary = {"scene": str(scene_path), "device": ctx.device_name, "penumbra_version": __version__,
               "resolution": list(desc.camera.resolution), "pixels_measured": int(mask.sum()),
               "methods": list(methods),
               "frames": opts.frames, "floor_ms": floor_ms, "gbuffer_ms": floor.timings_ms["gbuffer_median"],
               "ground_truth": {"method": "reference", "face_size": opts.reference_face_size,
                                "sun_supersampling": opts.reference_sun_supersampling},
               "mitsuba": {k: v for k, v in mitsuba.items() if k != "images"}, "rays": rays,
               **({"rays_skipped": rays_skipped} if rays_skipped else {}),
               "date": time.strftime("%Y-%m-%d")}
    _write_outputs(out, summary, results, mitsuba, truth, mask)
    return {"summary": summary, "results": results}


def _run_mitsuba(desc, opts: BenchOptions, truth, mask, log) -> dict:
    from . import mitsuba as mi_bridge

    variant = mi_bridge.select_variant(opts.mitsuba_variant)
    renderer = mi_bridge.PixelCentreRenderer(desc, variant=variant)
    curve, images = [], {}
    renderer.render(min(opts.spp), seed=0)  # JIT compilation and first-touch costs stay out of the timings
    for spp in opts.spp:
        # Median of at least 5 runs while they are cheap; one run once a render takes seconds.
        times = []
        while len(times) < 5 and (not times or sum(times) < 2.0):
            image, seconds = renderer.render_timed(spp, seed=spp + 7919 * len(times))
            times.append(seconds)
        seconds = float(np.median(times))
        err = compare(truth, image, mask)
        curve.append({"method": "mitsuba", "params": {"spp": spp, "variant": variant}, "time_ms": 1000 * seconds,
                      "nrmse": err["nrmse"], "rel_rms": err["rel_rms"], "max_abs": err["max_abs"]})
        images[spp] = image
        log(f"mitsuba {variant} {spp} spp: {1000 * seconds:.1f} ms, NRMSE {err['nrmse']:.4f}")
    return {"variant": variant, "integrator": "direct", "curve": curve, "images": images}


# ------------------------------------------------------------------ outputs


def _public(r: dict) -> dict:
    return {k: r[k] for k in RESULT_KEYS if k in r} | (
        {"mitsuba_speedup_bound": r["mitsuba_speedup_bound"]} if r.get("mitsuba_speedup_bound") else {}) | {
        k: r[k] for k in ("fiv_fields", "fiv_bytes", "bake_s") if k in r}


def _fmt_value(v) -> str:
    if isinstance(v, (list, tuple)) and all(isinstance(x, int) for x in v):
        return "x".join(map(str, v))  # fiv samples, e.g. 64x33x30
    return str(v)


def _fmt_params(p: dict) -> str:
    return ", ".join(f"{k}={_fmt_value(v)}" for k, v in p.items()) or "-"


def _write_outputs(out: Path, summary: dict, results: list[dict], mitsuba: dict, truth, mask) -> None:
    from .imageio import write_exr, write_png

    rows = [_public(r) for r in results] + [dict(c, time_ms=c["time_ms"]) for c in mitsuba["curve"]]
    atomic_write_text(out / "results.json", json.dumps({"summary": summary, "results": rows}, indent=2) + "\n")
    buf = io.StringIO()
    writer = csv.writer(buf)
    writer.writerow(["method", "params", "time_ms", "shade_ms", "floor_ratio", "nrmse", "rel_rms", "max_abs",
                     "mitsuba_speedup"])
    for r in rows:
        writer.writerow([r["method"], _fmt_params(r["params"]), f"{r['time_ms']:.4f}",
                         f"{r['shade_ms']:.4f}" if "shade_ms" in r else "",
                         f"{r['floor_ratio']:.2f}" if "floor_ratio" in r else "", f"{r['nrmse']:.6g}",
                         f"{r['rel_rms']:.6g}", f"{r['max_abs']:.6g}",
                         f"{r['mitsuba_speedup']:.4g}" if "mitsuba_speedup" in r else ""])
    atomic_write_text(out / "results.csv", buf.getvalue())
    _plot(out / "pareto.png", results, mitsuba["curve"], summary)
    write_exr(out / "ground_truth.exr", truth)
    exposure = _exposure(truth, mask)
    write_png(out / "ground_truth.png", truth, exposure=exposure)
    for r in results:
        best = min((x for x in results if x["method"] == r["method"]), key=lambda x: x["nrmse"])
        if r is best:
            write_png(out / f"{r['method']}.png", r["image"], exposure=exposure)
            write_heatmap(out / f"{r['method']}_error.png", truth, r["image"], mask)
    top = max(mitsuba["images"])
    write_png(out / f"mitsuba_{top}spp.png", mitsuba["images"][top], exposure=exposure)
    atomic_write_text(out / "report.md", report_markdown(summary, results, mitsuba["curve"]))


def _exposure(image, mask) -> float:
    lum = image[mask].mean(axis=-1)
    p = float(np.percentile(lum, 95)) if lum.size else 1.0
    return -math.log2(p / 0.8) if p > 0 else 0.0


def _plot(path: Path, results: list[dict], curve: list[dict], summary: dict) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 4.6), dpi=120)
    for method in dict.fromkeys(r["method"] for r in results):
        pts = sorted((r["time_ms"], r["nrmse"], _fmt_params(r["params"])) for r in results if r["method"] == method)
        ax.plot([p[0] for p in pts], [max(p[1], 1e-6) for p in pts], "o-", label=method)
        for t, e, label in pts:
            ax.annotate(label, (t, max(e, 1e-6)), fontsize=6, xytext=(3, 3), textcoords="offset points")
    if curve:
        ax.plot([c["time_ms"] for c in curve], [c["nrmse"] for c in curve], "s--", color="grey",
                label=f"Mitsuba 3 ({curve[0]['params']['variant']}, 1-{curve[-1]['params']['spp']} spp)")
    ax.axvline(summary["floor_ms"] + summary["gbuffer_ms"], color="k", lw=0.8, ls=":", label="G-buffer + floor")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("frame time (ms, median)")
    ax.set_ylabel("NRMSE against the ground truth")
    ax.set_title(f"{Path(summary['scene']).stem}: {summary['resolution'][0]}x{summary['resolution'][1]}, "
                 f"{summary['device']}", fontsize=8)
    ax.grid(True, which="both", lw=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    atomic_write(path, lambda tmp: fig.savefig(tmp, format="png"))
    plt.close(fig)


def report_markdown(summary: dict, results: list[dict], curve: list[dict]) -> str:
    s = summary
    lines = [f"# Benchmark: {Path(s['scene']).stem}", "",
             f"{s['resolution'][0]}x{s['resolution'][1]} pixels ({s['pixels_measured']} measured: background "
             f"excluded), device {s['device']}, penumbra {s['penumbra_version']}, {s['date']}. Times: kernel builds "
             f"excluded, 0.3 s of warm-up frames, median of {s['frames']} frames; frame = G-buffer + shading. Errors "
             f"against `reference` with face_size {s['ground_truth']['face_size']} and sun_supersampling "
             f"{s['ground_truth']['sun_supersampling']} (docs/metrics.md).", "",
             f"Floor kernel (reads the G-buffer, writes the image): {s['floor_ms']:.3f} ms; G-buffer: "
             f"{s['gbuffer_ms']:.2f} ms.", "",
             "| method | params | frame ms | shading ms | x floor | NRMSE | rel. RMS | max abs | speed-up over "
             "Mitsuba at equal error |", "|---|---|---|---|---|---|---|---|---|"]
    for r in results:
        bound = r.get("mitsuba_speedup_bound", "")
        lines.append(f"| {r['method']} | {_fmt_params(r['params'])} | {r['time_ms']:.2f} | {r['shade_ms']:.2f} | "
                     f"{r['floor_ratio']:.1f} | {r['nrmse']:.4f} | {r['rel_rms']:.4f} | {r['max_abs']:.3g} | "
                     f"{bound}{r['mitsuba_speedup']:.3g}x |")
    fiv = [r for r in results if r["method"] == "fiv" and "fiv_bytes" in r]
    if fiv:
        lines += ["", "fiv precomputation (one occlusion field per occluder mesh, docs/fiv.md; not in the frame "
                  "times):", "", "| params | fields | memory | bake |", "|---|---|---|---|"]
        seen = set()
        for r in fiv:
            key = _fmt_value(r["params"].get("samples", "-"))
            if key in seen:
                continue
            seen.add(key)
            bake = f"{r['bake_s']:.1f} s" if r.get("bake_s") is not None else "cached"
            lines.append(f"| samples={key} | {r['fiv_fields']} | {r['fiv_bytes'] / 1024:.0f} KiB | {bake} |")
    if curve:
        m = s["mitsuba"]
        lines += ["", f"Mitsuba 3 `{m['variant']}`, `{m['integrator']}` integrator, one ray per pixel centre per "
                  "sample (docs/mitsuba.md), same process and CPU:", "", "| spp | ms | NRMSE | rel. RMS |",
                  "|---|---|---|---|"]
        lines += [f"| {c['params']['spp']} | {c['time_ms']:.1f} | {c['nrmse']:.4f} | {c['rel_rms']:.4f} |"
                  for c in curve]
        lines += ["", "A '>' speed-up is a lower bound (Mitsuba did not reach that error at its largest spp); "
                  "'<' an upper bound (Mitsuba at 1 spp is already more accurate)."]
    if s.get("rays"):
        r = s["rays"]
        lines += ["", f"Ray throughput on the same rays ({r['triangles']} triangles; penumbra on {s['device']}, "
                  f"Embree {r.get('embree_version', '')} through embreex on {r.get('embree_threads', 1)} thread):", "",
                  "| rays | count | penumbra Mrays/s | Embree Mrays/s | penumbra / Embree | mismatches |",
                  "|---|---|---|---|---|---|"]
        for kind in ("primary", "shadow"):
            k = r[kind]
            lines.append(f"| {kind} | {k['rays']} | {k['penumbra_mrays_per_s']:.2f} | {k['embree_mrays_per_s']:.2f} | "
                         f"{k['ratio']:.2f} | {k['mismatch_count']} |")
    elif s.get("rays_skipped"):
        lines += ["", f"Ray throughput against Embree: skipped ({s['rays_skipped']})."]
    lines += ["", "Files: results.json, results.csv, pareto.png, ground_truth.exr/png, <method>.png and "
              "<method>_error.png (best setting, error heat map), mitsuba_<spp>spp.png.", ""]
    return "\n".join(lines)


# ------------------------------------------------------------------ README table

README_BEGIN = "<!-- bench-table:begin (make bench rewrites this table) -->"
README_END = "<!-- bench-table:end -->"
README_HEADER = ("| scene | pixels | reference vs Mitsuba (NRMSE, max spp) | unshadowed ms / NRMSE / x floor | "
                 "fiv (64x33x30) ms / NRMSE / x floor | reference (face 32) ms / NRMSE | speed-up over Mitsuba at "
                 "equal error | rays vs Embree (primary / shadow) |\n|---|---|---|---|---|---|---|---|")


def readme_row(summary: dict, results: list[dict]) -> str:
    s = summary
    curve = s["mitsuba"]["curve"]
    top = curve[-1] if curve else None
    agree = f"{top['nrmse']:.4f} ({top['params']['spp']} spp)" if top else "-"

    def pick(method, **params):
        found = [r for r in results if r["method"] == method and r["params"] == params]
        return found[-1] if found else None

    un, fiv, ref = pick("unshadowed"), pick("fiv", **README_FIV), pick("reference", face_size=32)
    speed = "; ".join(f"{r['method']}{'' if not r['params'] else ' ' + _fmt_params(r['params'])} "
                      f"{r.get('mitsuba_speedup_bound', '')}{r['mitsuba_speedup']:.3g}x"
                      for r in (un, fiv, ref) if r is not None)
    rays = s.get("rays")
    return (f"| {Path(s['scene']).stem} | {s['resolution'][0]}x{s['resolution'][1]} | {agree} | "
            + (f"{un['time_ms']:.2f} / {un['nrmse']:.4f} / {un['floor_ratio']:.1f} | " if un else "- | ")
            + (f"{fiv['time_ms']:.2f} / {fiv['nrmse']:.4f} / {fiv['floor_ratio']:.1f} | " if fiv else "- | ")
            + (f"{ref['time_ms']:.0f} / {ref['nrmse']:.4f} | " if ref else "- | ")
            + f"{speed or '-'} | "
            + (f"{rays['primary']['ratio']:.2f} / {rays['shadow']['ratio']:.2f} |" if rays else "- |"))


def update_readme(readme: str | Path, row: str) -> None:
    """Replaces (or adds) this scene's row of the README's benchmark table."""
    path = Path(readme)
    text = path.read_text(encoding="utf-8")
    if README_BEGIN not in text or README_END not in text:
        raise InputError(f"{path} has no benchmark table markers ({README_BEGIN} ... {README_END})")
    head, rest = text.split(README_BEGIN, 1)
    body, tail = rest.split(README_END, 1)
    scene = row.split("|")[1].strip()
    rows = [line for line in body.strip().splitlines() if line.startswith("| ") and not line.startswith("| scene")]
    rows = [line for line in rows if line.split("|")[1].strip() != scene] + [row]
    rows.sort()
    atomic_write_text(path, f"{head}{README_BEGIN}\n{README_HEADER}\n" + "\n".join(rows) + f"\n{README_END}{tail}")


# ------------------------------------------------------------------ fiv: cost against occluder count

FIV_SCALING_COUNTS = (1, 10, 30, 60)
# Michael and Chrysanthou, Table 2: frames per second at 512x512 on a GeForce 8800
# with 1, 10, 30 and 60 moving occluders.
PAPER_FPS = {1: 112, 10: 68, 30: 35, 60: 22}
SCALING_MESH = "meshes/bunny_odedstein_3k.obj"
SCALING_ENV = "envmaps/immenstadter_horn_1k_polyhaven.hdr"


def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{ " + ", ".join(f"{k} = {_toml_value(x)}" for k, x in v.items()) + " }"
    return repr(float(v)) if isinstance(v, float) else str(v)


def scene_toml(data: dict, comment: str = "") -> str:
    """A scene dict (as parse_scene takes it) written as a TOML scene file."""
    lines = [f"# {line}" for line in comment.splitlines()]
    for table in ("environment", "camera", "render", "fiv"):
        if table in data:
            lines += ["", f"[{table}]"] + [f"{k} = {_toml_value(v)}" for k, v in data[table].items()]
    for o in data.get("object", []):
        lines += ["", "[[object]]"] + [f"{k} = {_toml_value(v)}" for k, v in o.items()]
    return "\n".join(lines) + "\n"


def fiv_scaling_scene(n: int, mesh: str, envmap: str, resolution: int = 512, samples=(128, 65, 30),
                      cache: str | None = None, seed: int = 7) -> dict:
    """The occluder-count scene: ``n`` bunnies (one mesh, so one field for all;
    uniform scales 0.7-0.85, no rotation) on a jittered 8x8 grid over a
    12x12 ground plane, seen from above at about 40 degrees. Counts nest: the first
    10 of 30 bunnies are the 10 of the 10-bunny scene. Paths as given."""
    if not 1 <= n <= 64:
        raise InputError(f"the scaling scene holds 1 to 64 bunnies, not {n}")
    rng = np.random.default_rng(seed)
    cells = rng.permutation(64)
    jitter = rng.uniform(-0.12, 0.12, (64, 2))
    scales = rng.uniform(0.7, 0.85, 64)
    objects = [{"name": "ground", "primitive": "plane", "params": {"size": [16.0, 16.0]}, "albedo": 0.6}]
    for k in range(n):
        c = int(cells[k])
        x, z = -5.25 + 1.5 * (c % 8) + jitter[c, 0], -5.25 + 1.5 * (c // 8) + jitter[c, 1]
        s = round(float(scales[c]), 3)
        objects.append({"name": f"bunny{k}", "mesh": mesh, "translate": [round(x, 3), round(0.769 * s, 4), round(z, 3)],
                        "scale": s, "albedo": [0.8, 0.78, 0.72]})
    fiv = {"samples": list(samples)}
    if cache:
        fiv["cache"] = cache
    return {"environment": {"map": envmap, "face_size": 128, "irradiance_face_size": 32},
            "camera": {"position": [0.0, 7.0, 9.0], "look_at": [0.0, 0.0, 0.2], "fov_deg": 62,
                       "resolution": [resolution, resolution]},
            "render": {"method": "fiv"}, "fiv": fiv, "object": objects}


def fiv_scaling(out_dir: str | Path, counts=FIV_SCALING_COUNTS, samples=(128, 65, 30), resolution: int = 512,
                frames: int = 5, data_dir: str | Path | None = None, mitsuba_count: int | None = 10,
                mitsuba_resolution: int = 128, mitsuba_opts: BenchOptions | None = None, overrides=(),
                log=print) -> dict:
    """Per-frame cost of ``fiv`` against the number of occluders: renders
    N = ``counts`` bunnies (one shared field of ``samples`` = (phi, theta,
    radii)) at ``resolution``², timing fiv shading and the floor kernel in the
    same run, next to the paper's frame rates. With ``mitsuba_count``, also
    runs the speed-against-error benchmark (run()) on that scene at
    ``mitsuba_resolution``² (fiv against the ground truth and Mitsuba 3).
    ``overrides``: ``--set`` strings applied to every scene. Writes
    scenes/*.toml, results.json and report.md into ``out_dir``."""
    from .scenefile import load_scene

    if frames < 5:
        raise InputError(f"frames = {frames}: the measuring protocol takes the median of at least 5")
    out = Path(out_dir)
    (out / "scenes").mkdir(parents=True, exist_ok=True)
    if data_dir is None:  # ../shared/data beside the checkout: from the working directory, or from this file
        data_dir = next((d for d in (Path.cwd().parent / "shared" / "data",
                                     Path(__file__).resolve().parents[3] / "shared" / "data") if d.is_dir()),
                        Path.cwd().parent / "shared" / "data")
    data = Path(data_dir)
    for rel in (SCALING_MESH, SCALING_ENV):
        if not (data / rel).is_file():
            raise InputError(f"{data / rel} not found (the scaling benchmark needs ../shared/data beside the checkout)")

    def rel(p: Path) -> str:
        return Path(os.path.relpath(p.resolve(), (out / "scenes").resolve())).as_posix()

    scenes = {}
    for n in sorted(set(counts) | ({mitsuba_count} if mitsuba_count else set())):
        data_n = fiv_scaling_scene(n, rel(data / SCALING_MESH), rel(data / SCALING_ENV), resolution, samples,
                                   cache="../cache/fiv")
        path = out / "scenes" / f"bunnies_{n}.toml"
        atomic_write_text(path, scene_toml(data_n, f"fiv occluder-count benchmark: {n} bunnies (penumbra.bench."
                                                   "fiv_scaling_scene)"))
        scenes[n] = path

    ctx = Context()
    load_start = os.getloadavg()[0]
    rows, bake = [], None
    for n in counts:
        desc = load_scene(scenes[n], list(overrides))
        built = build_scene(desc, ctx)
        t0 = time.perf_counter()
        render(built, "fiv", frames=1, warmup=False,
               bake_progress=lambda label, d, t: log(f"bake {label}: {d}/{t} samples") if d == t else None)
        if bake is None:
            rec = built.fiv_records[0]
            bake = {"samples": rec["samples"], "baked_now": rec["baked"], "bake_s": rec["bake_s"] if rec["baked"]
                    else None, "rays": rec["rays"], "stored_bytes": rec["stored_bytes"],
                    "first_use_s": time.perf_counter() - t0}
        floor = render(built, "floor", frames=frames)
        unsh = render(built, "unshadowed", frames=frames)
        fiv = render(built, "fiv", frames=frames)
        plain = render(built, "fiv", frames=frames, overlap=0)  # plain sum: no pair correction
        t = fiv.timings_ms
        fg = float((fiv.gbuffer["instance"] != 0xFFFFFFFF).mean())
        row = {"occluders": n, "fields": len(built.fiv_records), "fiv_shade_ms": t["shade_median"],
               "fiv_shade_min_ms": t["shade_min"], "floor_ms": floor.timings_ms["shade_median"],
               "ratio_to_floor": t["shade_median"] / floor.timings_ms["shade_median"],
               "fiv_sum_shade_ms": plain.timings_ms["shade_median"],
               "unshadowed_shade_ms": unsh.timings_ms["shade_median"], "gbuffer_ms": t["gbuffer_median"],
               "frame_ms": t["frame_median"], "fps_shading": 1000.0 / t["shade_median"],
               "fps_frame": 1000.0 / t["frame_median"], "paper_fps": PAPER_FPS.get(n), "geometry_fraction": fg}
        rows.append(row)
        log(f"{n} occluders: fiv {row['fiv_shade_ms']:.2f} ms ({row['ratio_to_floor']:.1f}x floor "
            f"{row['floor_ms']:.3f} ms), {row['fps_shading']:.1f} fps shading, {row['fps_frame']:.1f} fps frame")
        if n == max(counts):
            from .imageio import write_png

            write_png(out / f"fiv_{n}.png", fiv.image[..., :3], exposure=_exposure(fiv.image[..., :3],
                                                                                   fiv.gbuffer["instance"] != 0xFFFFFFFF))

    equal_error = None
    if mitsuba_count:
        mopts = mitsuba_opts or BenchOptions(methods=("unshadowed", "fiv"), rays=False,
                                             sweeps={"unshadowed": [{}], "fiv": [{"samples": list(samples)}]})
        res = run(scenes[mitsuba_count], out / f"mitsuba_{mitsuba_count}", mopts,
                  overrides=[*overrides, f"camera.resolution=[{mitsuba_resolution},{mitsuba_resolution}]"], log=log)
        equal_error = {"occluders": mitsuba_count, "resolution": [mitsuba_resolution] * 2,
                       "report": f"mitsuba_{mitsuba_count}/report.md",
                       "results": [{k: r.get(k) for k in ("method", "params", "time_ms", "shade_ms", "nrmse",
                                                          "mitsuba_speedup", "mitsuba_speedup_bound")}
                                   for r in res["results"]]}

    summary = {"device": ctx.device_name, "penumbra_version": __version__, "date": time.strftime("%Y-%m-%d"),
               "overrides": list(overrides), "cpus": os.cpu_count(),
               "load_average_1min": [round(load_start, 2), round(os.getloadavg()[0], 2)],
               "resolution": [resolution, resolution], "frames": frames, "mesh": SCALING_MESH, "envmap": SCALING_ENV,
               "samples_phi_theta_radii": list(samples), "bake": bake,
               "paper": "Michael and Chrysanthou, Table 2: GeForce 8800, 512x512, fps with 1/10/30/60 occluders"}
    atomic_write_text(out / "results.json", json.dumps({"summary": summary, "results": rows,
                                                        "equal_error": equal_error}, indent=2) + "\n")
    atomic_write_text(out / "report.md", scaling_markdown(summary, rows, equal_error))
    return {"summary": summary, "results": rows, "equal_error": equal_error}


def scaling_markdown(summary: dict, rows: list[dict], equal_error: dict | None) -> str:
    s = summary
    b = s["bake"] or {}
    phi, theta, radii = s["samples_phi_theta_radii"]
    bake = (f"baked in {b['bake_s']:.1f} s ({b['rays'] / 1e6:.0f} M rays)" if b.get("bake_s") is not None
            else "loaded from the cache (baked by an earlier run)")
    lines = ["# fiv: cost against the number of occluders", "",
             f"{s['resolution'][0]}x{s['resolution'][1]} pixels, N bunnies ({s['mesh']}) scattered on a ground plane "
             f"under {s['envmap']} (`scenes/bunnies_N.toml`), device {s['device']}, penumbra "
             f"{s['penumbra_version']}, {s['date']}. One occlusion field shared by every bunny: {phi}x{theta}x{radii} "
             f"(phi x theta x radii, as the paper's Table 2), {b.get('stored_bytes', 0) / 1024:.0f} KiB, {bake}. "
             f"Times: kernel builds excluded, 0.3 s of warm-up frames, median of {s['frames']} frames. The floor kernel "
             "(reads the G-buffer, writes the image) is timed in the same run; fps = 1000 / ms. System load "
             f"average (1 min) at the start / end of the timings: {s['load_average_1min'][0]} / "
             f"{s['load_average_1min'][1]} on {s['cpus']} CPUs.", "",
             "| occluders | fiv shading ms | floor ms | fiv / floor | fps (shading) | fps (G-buffer + shading) | "
             "paper fps (GeForce 8800) | fiv overlap=0 ms | unshadowed ms | G-buffer ms |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['occluders']} | {r['fiv_shade_ms']:.2f} | {r['floor_ms']:.3f} | {r['ratio_to_floor']:.0f} | "
                     f"{r['fps_shading']:.1f} | {r['fps_frame']:.1f} | "
                     f"{r['paper_fps'] if r['paper_fps'] is not None else '-'} | {r['fiv_sum_shade_ms']:.2f} | "
                     f"{r['unshadowed_shade_ms']:.2f} | {r['gbuffer_ms']:.1f} |")
    lines += ["", "fiv uses its default overlap = 1 (the pairwise unit-bounding-disc correction, docs/fiv.md); "
              "the overlap=0 column is the plain sum of the occluders' irradiance."]
    lines += ["", "The paper's frame rates are for its whole frame (rasterisation and shading) on a 2007 GPU; "
              "penumbra ray-casts its G-buffer on the same device as the shading. The shading columns measure the "
              "method itself; the x floor ratio (fiv shading over the memory-bound floor, same run) does not depend "
              "on the machine's speed."]
    if equal_error:
        e = equal_error
        lines += ["", f"## Against Mitsuba 3 at equal error ({e['occluders']} bunnies, {e['resolution'][0]}x"
                  f"{e['resolution'][1]})", "", f"From `{e['report']}` (penumbra bench on "
                  f"`scenes/bunnies_{e['occluders']}.toml` at {e['resolution'][0]}x{e['resolution'][1]}):", "",
                  "| method | params | frame ms | NRMSE | speed-up over Mitsuba at equal error |", "|---|---|---|---|---|"]
        for r in e["results"]:
            lines.append(f"| {r['method']} | {_fmt_params(r['params'])} | {r['time_ms']:.2f} | {r['nrmse']:.4f} | "
                         f"{r.get('mitsuba_speedup_bound') or ''}{r['mitsuba_speedup']:.3g}x |")
    lines += ["", "Files: results.json, report.md, scenes/bunnies_N.toml, fiv_<N>.png (the largest count)"
              + (f", mitsuba_{equal_error['occluders']}/ (the equal-error run)" if equal_error else "") + ".", ""]
    return "\n".join(lines)
