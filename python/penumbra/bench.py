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
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from . import __version__, methods
from .core import Context
from .errors import InputError
from .fileutil import atomic_write, atomic_write_text
from .metrics import compare, write_heatmap
from .render import build_scene, render
from .scenefile import SceneDescription

RESULT_KEYS = ("method", "params", "time_ms", "shade_ms", "floor_ratio", "nrmse", "rel_rms", "max_abs",
               "mitsuba_speedup")


def default_sweeps() -> dict[str, list[dict[str, Any]]]:
    """Each method's quality settings, cheapest first (Technique.sweep). `floor`
    is timed separately (every method's time is reported as a multiple of it)."""
    return {t.name: t.sweep() for t in methods.techniques() if t.benchmarked}


@dataclass
class BenchOptions:
    methods: tuple[str, ...] | None = None       # None: the benchmarked methods that apply to the scene
    frames: int = 5
    reference_face_size: int = 64          # the ground truth the errors are measured against
    reference_sun_supersampling: int = 4
    spp: tuple[int, ...] = tuple(2 ** k for k in range(11))   # 1 ... 1024
    mitsuba_variant: str | None = None     # None: llvm_ad_rgb, scalar_rgb if LLVM is missing
    rays: bool = True                      # ray throughput against Embree
    sweeps: dict[str, list[dict[str, Any]]] = field(default_factory=default_sweeps)


def _reference_key(desc: SceneDescription, opts: BenchOptions) -> str:
    """Cache key of the ground truth: the scene (with the content the
    techniques' tables add, Technique.content_key), the reference settings and
    the kernel sources that compute it."""
    from .kernels import kernel_dir

    h = hashlib.sha256()
    h.update(repr((desc.environment, desc.camera, desc.objects, desc.lights)).encode())
    for technique in methods.techniques():
        h.update(technique.content_key(desc))
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
    for m in opts.methods or ():
        methods.spec(m)  # unknown: InputError listing the methods
        if m not in opts.sweeps:
            raise InputError(f"method '{m}' has no benchmark sweep (swept: {', '.join(opts.sweeps)})")
    if opts.frames < 5:
        raise InputError(f"frames = {opts.frames}: the measuring protocol takes the median of at least 5")
    desc = load_scene(scene_path, list(overrides))
    # The default list keeps only the methods that apply to this scene; methods given explicitly all run.
    chosen = methods.applicable(desc) if opts.methods is None else tuple(opts.methods)
    for m in chosen:
        if m not in opts.sweeps:
            raise InputError(f"method '{m}' has no benchmark sweep (swept: {', '.join(opts.sweeps)})")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    for technique in methods.techniques():  # assets bake beside the cached ground truth
        technique.use_cache_folder(desc, out / "cache")
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
    for method in chosen:
        for params in opts.sweeps[method]:
            res = render(built, method, frames=opts.frames, background=0, **params)
            err = compare(truth, res.image[..., :3], mask)
            t = res.timings_ms
            row = {"method": method, "params": params, "time_ms": t["frame_median"],
                   "shade_ms": t["shade_median"], "floor_ratio": t["shade_median"] / floor_ms,
                   "nrmse": err["nrmse"], "rel_rms": err["rel_rms"], "max_abs": err["max_abs"],
                   "image": res.image[..., :3], **methods.technique(method).bench_extras(built)}
            results.append(row)
            log(f"{method} {_fmt_params(params)}: {t['frame_median']:.2f} ms, NRMSE {err['nrmse']:.4f}")

    mitsuba = _run_mitsuba(desc, opts, truth, mask, log)
    for r in results:
        t, bound = _mitsuba_time_at(mitsuba["curve"], r["nrmse"]) if mitsuba["curve"] else (float("nan"), "")
        r["mitsuba_speedup"] = t / r["time_ms"]
        r["mitsuba_speedup_bound"] = bound

    rays, rays_skipped = None, None
    extra = [t.key for t in methods.scene_tables() if t.content and getattr(desc, t.attr, None)]
    if opts.rays and extra:
        # raybench builds Embree's scene from desc.objects only: it would miss that content.
        rays_skipped = f"the Embree comparison (penumbra.raybench) does not cover [[{']], [['.join(extra)}]] content"
        log(f"rays: skipped ({rays_skipped})")
    elif opts.rays:
        from .raybench import measure

        rays = measure(desc, built, repeats=opts.frames)
        log(f"rays: primary {rays['primary']['ratio']:.2f}x Embree, shadow {rays['shadow']['ratio']:.2f}x Embree")

    summary = {"scene": str(scene_path), "device": ctx.device_name, "penumbra_version": __version__,
               "resolution": list(desc.camera.resolution), "pixels_measured": int(mask.sum()),
               "methods": list(chosen),
               "frames": opts.frames, "floor_ms": floor_ms, "gbuffer_ms": floor.timings_ms["gbuffer_median"],
               "ground_truth": {"method": "reference", "face_size": opts.reference_face_size,
                                "sun_supersampling": opts.reference_sun_supersampling},
               "mitsuba": {k: v for k, v in mitsuba.items() if k != "images"}, "rays": rays,
               **({"rays_skipped": rays_skipped} if rays_skipped else {}),
               "date": time.strftime("%Y-%m-%d")}
    _write_outputs(out, summary, results, mitsuba, truth, mask)
    return {"summary": summary, "results": results}


def bench_job(job: dict) -> dict:
    """One scene's benchmark as a job of ``penumbra bench SCENE... --workers N
    / --scheduler ADDRESS`` (penumbra.farm): ``job`` = {"scene": file, "out":
    folder, "options": BenchOptions, "overrides": ["KEY=VALUE", ...]}. The
    whole scene runs on one worker, in its own context, so every ratio of its
    report is still measured in one run; the report files are written there
    (a shared file system). Returns the summary, the result rows without
    their images (results.json's) and the worker."""
    from .farm import worker_name

    res = run(job["scene"], job["out"], job["options"], overrides=job.get("overrides", ()), log=lambda _m: None)
    return {"scene": str(job["scene"]), "out": str(job["out"]), "summary": res["summary"],
            "results": [_public(r) for r in res["results"]], "worker": worker_name()}


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
    """A result row as results.json has it: the common keys, the bound when there
    is one, then the technique's extras (Technique.bench_extras)."""
    return {k: r[k] for k in RESULT_KEYS if k in r} | (
        {"mitsuba_speedup_bound": r["mitsuba_speedup_bound"]} if r.get("mitsuba_speedup_bound") else {}) | {
        k: v for k, v in r.items() if k not in RESULT_KEYS and k not in ("image", "mitsuba_speedup_bound")}


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
    for method in dict.fromkeys(r["method"] for r in results):
        lines += methods.technique(method).report_lines(results)
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


def _readme_columns() -> list:
    """The techniques the README table shows (Technique.readme_setting): the interactive ones, then the others."""
    shown = [t for t in methods.techniques() if t.readme_setting is not None]
    return [t for t in shown if t.interactive] + [t for t in shown if not t.interactive]


def readme_header() -> str:
    cols = "".join(f"{t.name}{f' ({t.readme_label})' if t.readme_label else ''} ms / NRMSE"
                   f"{' / x floor' if t.interactive else ''} | " for t in _readme_columns())
    return (f"| scene | pixels | reference vs Mitsuba (NRMSE, max spp) | {cols}speed-up over Mitsuba at equal error | "
            "rays vs Embree (primary / shadow) |\n" + "|---" * (5 + len(_readme_columns())) + "|")


def readme_row(summary: dict, results: list[dict]) -> str:
    s = summary
    curve = s["mitsuba"]["curve"]
    top = curve[-1] if curve else None
    agree = f"{top['nrmse']:.4f} ({top['params']['spp']} spp)" if top else "-"

    def pick(method, params):
        found = [r for r in results if r["method"] == method and r["params"] == params]
        return found[-1] if found else None

    picked = [(t, pick(t.name, t.readme_setting)) for t in _readme_columns()]
    speed = "; ".join(f"{r['method']}{'' if not r['params'] else ' ' + _fmt_params(r['params'])} "
                      f"{r.get('mitsuba_speedup_bound', '')}{r['mitsuba_speedup']:.3g}x"
                      for _, r in picked if r is not None)
    cells = []
    for t, r in picked:
        if r is None:
            cells.append("- | ")
        elif t.interactive:
            cells.append(f"{r['time_ms']:.2f} / {r['nrmse']:.4f} / {r['floor_ratio']:.1f} | ")
        else:
            cells.append(f"{r['time_ms']:.0f} / {r['nrmse']:.4f} | ")
    rays = s.get("rays")
    return (f"| {Path(s['scene']).stem} | {s['resolution'][0]}x{s['resolution'][1]} | {agree} | " + "".join(cells)
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
    atomic_write_text(path, f"{head}{README_BEGIN}\n{readme_header()}\n" + "\n".join(rows) + f"\n{README_END}{tail}")


# ------------------------------------------------------------------ scene files written by experiments


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
    arrays = {t.key for t in methods.scene_tables() if t.array}
    for table in [k for k, v in data.items() if isinstance(v, dict)]:
        lines += ["", f"[{table}]"] + [f"{k} = {_toml_value(v)}" for k, v in data[table].items()]
    for key in ["object", "light", *arrays]:
        for o in data.get(key, []):
            lines += ["", f"[[{key}]]"] + [f"{k} = {_toml_value(v)}" for k, v in o.items()]
    return "\n".join(lines) + "\n"
