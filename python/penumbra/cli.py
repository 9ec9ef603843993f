"""The ``penumbra`` command: ``info``, ``methods``, ``render``, ``demo``,
``export-mitsuba``, ``bench``, and the techniques' own commands (e.g.
``bake-fiv`` and ``fiv-info``, from penumbra.methods.fiv)."""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import sys
from pathlib import Path

import numpy as np

from . import __version__
from .errors import InputError, PenumbraError


def _progress(total: int, desc: str):
    from tqdm import tqdm

    return tqdm(total=total, desc=desc, unit="frame", leave=False, disable=None, file=sys.stderr)


class _BakeBars:
    """bake_progress for render(): one progress bar per occlusion field baked
    (the first call of a bake comes after its first sphere). ``stop`` (set by
    Ctrl-C in bake-fiv) makes the callback ask the library to stop."""

    def __init__(self):
        self.bar = None
        self.label = None
        self.stop = False

    def __call__(self, label: str, done: int, total: int) -> bool:
        from tqdm import tqdm

        if label != self.label:
            self.close()
            self.bar = tqdm(total=total, desc=f"bake {label}", unit="sample", unit_scale=True, leave=False,
                            disable=None, file=sys.stderr)
            self.label = label
        self.bar.update(done - self.bar.n)
        if done >= total:
            self.close()
        return self.stop

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()
        self.bar, self.label = None, None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def cmd_info(args) -> int:
    import pyopencl as cl

    from ._native import library_path
    from .core import Context

    print(f"penumbra {__version__} ({library_path})")
    for p in cl.get_platforms():
        for i, d in enumerate(p.get_devices()):
            print(f"  platform '{p.name}' device {i}: {d.name} ({cl.device_type.to_string(d.type)}, "
                  f"{d.max_compute_units} compute units, {d.opencl_c_version})")
    ctx = Context(args.device)
    print(f"default device: {ctx.device_name}")
    return 0


def cmd_methods(args) -> int:
    from .methods import catalog, markdown_table, technique

    specs = catalog()
    if args.markdown:  # the tables of docs/api.md
        print("\n\n".join(f"#### {name} parameters\n\n{markdown_table(m.params)}" for name, m in specs.items()))
        return 0
    if args.json:
        print(json.dumps({"methods": [
            {**m.as_dict(), "interactive": technique(name).interactive} for name, m in specs.items()]}, indent=2))
        return 0
    for name, m in specs.items():
        print(f"{name}: {m.summary}")
        print(f"  inputs: {', '.join(sorted(m.inputs)) or 'none'}; kernels/{m.stage}.cl; {m.doc_page}")
        for p in m.params:
            unit = f" {p.unit}" if p.unit else ""
            print(f"  {p.name:<20} {p.type:<5} {p.stage:<5} default {p.default!s:<8} {p.range_text()}{unit}: {p.doc}")
        for o in m.outputs:
            print(f"  output {o.name}: {o.doc}")
    return 0


def _write_outputs(result, out: str | None, png: str | None, exposure: float) -> list[str]:
    from .imageio import write_exr, write_png

    written = []
    rgb = np.ascontiguousarray(result.image[..., :3])
    if out:
        write_exr(out, rgb)
        written.append(out)
    if png:
        write_png(png, rgb, exposure=exposure)
        written.append(png)
    return written


def report(result, scene_source: str, png_exposure: float | None = None) -> dict:
    """The JSON report of a render: the method with every renderer parameter in
    effect (defaults included), the bake parameters given and what the
    technique's preparation made (bake files, sizes, times), the device, the
    timings (frames and whether they were timed after warm-up)."""
    h, w = result.image.shape[:2]
    rep = {"method": result.method, "device": result.device, "resolution": [w, h], "params": result.params,
           "bake": {"params": result.bake_params, "prepare_s": result.prepare_s, **result.bake},
           "scene": scene_source, "timings_ms": result.timings_ms, "penumbra_version": __version__}
    if png_exposure is not None:
        rep["png_exposure"] = png_exposure
    return rep


class _BandBar:
    """band_progress for render(): a bar over the frame's foreground pixels, so
    its rate and ETA come from the work done, not from rows."""

    def __init__(self, desc: str):
        from tqdm import tqdm

        self.bar = tqdm(total=1, desc=desc, unit="px", unit_scale=True, leave=False, disable=None, file=sys.stderr)

    def __call__(self, done: int, total: int) -> None:
        self.bar.total = total
        self.bar.update(done - self.bar.n)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.bar.close()


# --exposure is limited to this many stops either way (2**1100 overflows a float;
# beyond 64 stops every lit pixel is black or white anyway).
MAX_EXPOSURE = 64.0


def check_outputs(named: dict[str, str | None]) -> None:
    """Checks a command's output paths before any work ({option: path}; None:
    not asked): each is one the output policy accepts (fileutil.output_target:
    not a folder, device or FIFO, not under a file), and no two name one file."""
    from .fileutil import output_target

    seen: dict[str, str] = {}
    for option, path in named.items():
        if path is None:
            continue
        target = os.path.abspath(output_target(path, option, create_dirs=False))
        if target in seen:
            raise InputError(f"{option} {path} and {seen[target]} name the same file")
        seen[target] = f"{option} {path}"


def cmd_render(args) -> int:
    from .core import Context
    from .fileutil import all_or_nothing, atomic_write_text
    from .imageio import auto_exposure
    from .render import build_scene, render
    from .methods import spec, technique
    from .scenefile import DEFAULT_METHOD, load_scene

    if args.frames is not None and args.frames < 1:
        raise InputError(f"--frames {args.frames} must be >= 1")
    if args.exposure is not None and not (math.isfinite(args.exposure) and abs(args.exposure) <= MAX_EXPOSURE):
        raise InputError(f"--exposure {args.exposure} must be a finite number of stops in "
                         f"[-{MAX_EXPOSURE:g}, {MAX_EXPOSURE:g}]")
    out = args.output if args.output or args.png else "out.exr"
    # Every output is checked before any work, and written only when all of it succeeded (all_or_nothing).
    check_outputs({"-o": out, "--png": args.png, "--json": args.json})
    if args.method:
        spec(args.method)   # unknown: InputError listing the methods
    # --method goes in as [render] method, so the file's [render] keys are checked against that method.
    desc = load_scene(args.scene, args.set + ([f"render.method={args.method}"] if args.method else []))
    method = desc.render.get("method", DEFAULT_METHOD)
    params = {k: v for k, v in desc.render.items() if k != "method"}
    ctx = Context(args.device)
    built = build_scene(desc, ctx)
    # One frame unless --frames asks for timing (then warm-up frames first, by the measuring protocol).
    timed = args.frames is not None
    frames = args.frames if timed else 1
    with contextlib.ExitStack() as stack:
        bakes = stack.enter_context(_BakeBars())
        # Timed frames: a bar over frames. One frame of a slow method (not interactive, e.g. the
        # reference): a bar over its pixels, shaded in row bands (Technique.per_pixel).
        bar = stack.enter_context(_progress(frames, f"render {method}")) if timed else None
        slow = not timed and not technique(method).interactive
        bands = stack.enter_context(_BandBar(f"render {method}")) if slow else None
        result = render(built, method, frames=frames, warmup=timed, progress=bar, bake_progress=bakes,
                        band_progress=bands, **params)
    for line in technique(method).summary_lines(built):
        print(line)
    exposure = args.exposure if args.exposure is not None else auto_exposure(result.image)
    rep = report(result, str(args.scene), exposure if args.png else None)
    with all_or_nothing():
        written = _write_outputs(result, out, args.png, exposure)
        if args.json:
            atomic_write_text(args.json, json.dumps(rep, indent=2) + "\n")
            written.append(args.json)
    t = result.timings_ms
    if timed:
        frame = (f"frame median {t['frame_median']:.2f} ms of {frames} after warm-up "
                 f"(G-buffer {t['gbuffer_median']:.2f} ms, shading {t['shade_median']:.2f} ms)")
    else:
        frame = (f"one frame {t['frame_median']:.2f} ms (G-buffer {t['gbuffer_median']:.2f} ms, shading "
                 f"{t['shade_median']:.2f} ms; untimed: --frames N to measure)")
    prep = f"; preparation (bakes, loads) {result.prepare_s:.2f} s, not in the frame" if result.prepare_s >= 0.01 else ""
    png = f"; PNG exposure {exposure:+.2f} stops{' (auto)' if args.exposure is None else ''}" if args.png else ""
    print(f"{method} on {result.device}: {frame}{prep}{png}; wrote {', '.join(written)}")
    return 0


def cmd_demo(args) -> int:
    from .core import Context
    from .fileutil import all_or_nothing
    from .imageio import auto_exposure, write_exr, write_png
    from .methods import interactive, technique
    from .render import GBUFFER_VIEWS, build_scene, render
    from .scenefile import default_scene_path, load_scene

    out = Path(args.out)
    if args.frames < 1:
        raise InputError(f"--frames {args.frames} must be >= 1")
    if args.reference_face_size < 0:
        raise InputError(f"--reference-face-size {args.reference_face_size} must be >= 0 (0: skip the reference)")
    if out.exists() and not out.is_dir():
        raise InputError(f"--out {out} is not a folder")
    desc = load_scene(default_scene_path(), args.set)
    ctx = Context(args.device)
    built = build_scene(desc, ctx)
    rows = []
    result = None
    # Interactive methods with full timing; the brute-force reference once, at a
    # coarse direction grid, so the demo also shows ground-truth soft shadows.
    runs = [(m, args.frames, {}) for m in interactive()]
    if args.reference_face_size > 0:
        runs.append(("reference", 1, {"face_size": args.reference_face_size}))
    # Warm-up frames only for methods that are timed frame after frame.
    warm = {m: technique(m).interactive for m, _, _ in runs}
    # The images appear together when every render succeeded (all_or_nothing), else none is replaced.
    with all_or_nothing(), _BakeBars() as bakes, _progress(sum(f + warm[m] for m, f, _ in runs), "demo") as bar:
        for method, frames, params in runs:
            result = render(built, method, frames=frames, progress=bar, warmup=warm[method],
                            bake_progress=bakes, **params)
            rgb = np.ascontiguousarray(result.image[..., :3])
            write_exr(out / f"{method}.exr", rgb)
            write_png(out / f"{method}.png", rgb, exposure=auto_exposure(result.image))
            rows.append((method, result.timings_ms))
        for view in GBUFFER_VIEWS:
            img = result.view(view)
            write_exr(out / f"gbuffer_{view}.exr", img)
            write_png(out / f"gbuffer_{view}.png", img)
    w, h = desc.camera.resolution
    print(f"penumbra demo: built-in scene, {w}x{h}, device {ctx.device_name}")
    print(f"{'method':<14}{'frame median ms':>17}{'frame min ms':>14}{'G-buffer ms':>13}{'shading ms':>12}")
    for method, t in rows:
        print(f"{method:<14}{t['frame_median']:>17.2f}{t['frame_min']:>14.2f}{t['gbuffer_median']:>13.2f}"
              f"{t['shade_median']:>12.2f}")
    for method, _, _ in runs:
        for line in technique(method).summary_lines(built):
            print(line)
    print(f"images in {out}/: " + ", ".join(f"{m}.exr/.png" for m, _, _ in runs) + ", "
          + ", ".join(f"gbuffer_{v}.exr/.png" for v in GBUFFER_VIEWS))
    return 0


def _samples_arg(text: str) -> tuple[int, int, int]:
    vals = _int_list(text.replace("x", ","))
    if len(vals) != 3:
        raise argparse.ArgumentTypeError(f"{text!r} is not PHI,THETA,RADII (e.g. 32,17,15)")
    return vals


def cmd_export_mitsuba(args) -> int:
    from .mitsuba import PLUGIN_NAME, export
    from .scenefile import load_scene

    desc = load_scene(args.scene, args.set)
    written = export(desc, args.output, spp=args.spp, overwrite=args.force)
    print(f"penumbra export-mitsuba: wrote {len(written)} file(s):")
    for path in written:
        print(f"  {path}")
    plugin = [o.name for o in desc.objects if o.specular > 0]
    if plugin:
        # The mitsuba executable cannot load Python plugins; say so instead of letting it fail later.
        print(f"note: {', '.join(plugin)} use(s) the '{PLUGIN_NAME}' BSDF plugin: render with "
              "penumbra.mitsuba.load_file (docs/mitsuba.md), not the mitsuba executable")
    return 0


def _int_list(text: str) -> tuple[int, ...]:
    try:
        return tuple(int(x) for x in text.split(",") if x.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a comma-separated list of integers") from None


# Optional dependencies (pyproject's "bench" extra): module -> (what needs it, pip requirement).
OPTIONAL = {"mitsuba": ("Mitsuba 3, the renderer the benchmark compares against", "mitsuba>=3.5"),
            "matplotlib": ("matplotlib, for the benchmark's plots", "matplotlib>=3.7"),
            "embreex": ("Embree (embreex), for the ray-throughput comparison (skip it with --no-rays)",
                        "embreex>=2.17")}


def require(command: str, modules: list[str]) -> None:
    """InputError naming each missing optional module and the pip command that
    installs it, before the command does any work."""
    import importlib.util

    missing = [m for m in modules if importlib.util.find_spec(m) is None]
    if missing:
        what = "; ".join(OPTIONAL[m][0] for m in missing)
        pip = " ".join(f"'{OPTIONAL[m][1]}'" for m in missing)
        raise InputError(f"{command} needs {what}, which is not installed: {sys.executable} -m pip install {pip} "
                         "(or pip install 'penumbra[bench]')")


def cmd_bench(args) -> int:
    from .bench import BenchOptions, run
    from .methods import techniques

    # fiv's scaling experiment runs the Mitsuba comparison (without rays) only with a --fiv-mitsuba-count.
    scaling = getattr(args, "fiv_scaling", False)
    compares = not scaling or bool(getattr(args, "fiv_mitsuba_count", 0))
    require("penumbra bench", (["mitsuba", "matplotlib"] if compares else [])
            + (["embreex"] if not scaling and not args.no_rays else []))
    for technique in techniques():  # a technique's own experiment, when its options ask for it
        code = technique.run_bench(args)
        if code is not None:
            return code
    if not args.scene:
        raise InputError("bench needs a scene file (or a technique's experiment option, e.g. --fiv-scaling)")
    on_cluster = args.workers is not None or args.scheduler is not None
    if on_cluster:
        from .farm import require_dask

        if args.workers is not None and args.scheduler is not None:
            raise InputError("--workers N starts a local cluster, --scheduler ADDRESS uses a running one: not both")
        if args.workers is not None and args.workers < 1:
            raise InputError(f"--workers {args.workers} must be >= 1")
        require_dask()
    # One scene: --out is its folder; several: one folder per scene under --out, named by the file.
    outs = [Path(args.out)] if len(args.scene) == 1 else [Path(args.out) / Path(s).stem for s in args.scene]
    if len(set(outs)) < len(outs):
        raise InputError("two scene files have the same name: their results would share one folder under --out")
    for scene in args.scene:
        if not Path(scene).is_file():
            raise InputError(f"scene file not found: {scene}")

    opts = BenchOptions(frames=args.frames, reference_face_size=args.reference_face_size,
                        reference_sun_supersampling=args.reference_sun_supersampling,
                        mitsuba_variant=args.mitsuba_variant, rays=not args.no_rays)
    if args.methods:
        opts.methods = tuple(m.strip() for m in args.methods.split(",") if m.strip())
    if args.spp:
        opts.spp = args.spp
    if args.face_sizes:
        opts.sweeps["reference"] = [{"face_size": f} for f in args.face_sizes]
    if on_cluster:
        from . import farm
        from .bench import bench_job

        jobs = [{"scene": str(Path(s).resolve()), "out": str(o.resolve()), "options": opts, "overrides": args.set}
                for s, o in zip(args.scene, outs)]
        with farm.client(args.scheduler, args.workers) as c:
            done = farm.run(c, bench_job, jobs, log=lambda msg: print(msg, file=sys.stderr),
                            describe=lambda r: f"{r['scene']} on {r['worker']}")
    else:
        done = []
        for scene, out in zip(args.scene, outs):
            res = run(scene, out, opts, overrides=args.set, log=lambda msg: print(msg, file=sys.stderr))
            done.append({"summary": res["summary"], "results": res["results"], "out": str(out)})
    for d in done:
        print(f"penumbra bench: wrote {d['out']}/results.json, results.csv, pareto.png, report.md")
    if args.readme:
        from .bench import readme_row, update_readme

        for d in done:
            update_readme(args.readme, readme_row(d["summary"], d["results"]))
        print(f"penumbra bench: updated the benchmark table in {args.readme}")
    return 0


def method_list(catalog: dict) -> str:
    """The methods, one line each (the library's summaries), for --help."""
    width = max(map(len, catalog)) + 3
    return "methods (--method; `penumbra methods` lists their parameters):\n" + "\n".join(
        f"  {name + ':':<{width}}{m.summary}" for name, m in catalog.items()) + "\n"


def build_parser() -> tuple[argparse.ArgumentParser, dict]:
    """The parser and the handlers of the techniques' own commands."""
    from .methods import catalog as read_catalog, techniques

    catalog = read_catalog()
    p = argparse.ArgumentParser(prog="penumbra", description="Environment lighting with soft shadows (OpenCL).")
    p.add_argument("--version", action="version", version=f"penumbra {__version__}")
    p.add_argument("--device", default=None, help="context config, e.g. 'device=gpu' (default: PENUMBRA_DEVICE or a CPU)")
    sub = p.add_subparsers(dest="command", required=True)

    sub.add_parser("info", help="list OpenCL devices and the library version")

    ms = sub.add_parser("methods", help="list the shading methods and their parameters (from the library)")
    ms.add_argument("--json", action="store_true", help="print every method, its inputs, parameters and outputs "
                    "as JSON")
    ms.add_argument("--markdown", action="store_true", help="print the parameter tables of docs/api.md")

    r = sub.add_parser("render", help="render a TOML scene file", formatter_class=argparse.RawDescriptionHelpFormatter,
                       epilog=method_list(catalog))
    r.add_argument("scene", help="scene file (docs/scene-format.md)")
    r.add_argument("--method", default=None, metavar="METHOD",
                   help=f"shading method, one of {', '.join(catalog)} (listed below; default: the scene's "
                   "[render] method)")
    r.add_argument("-o", "--output", default=None, help="EXR output (default out.exr)")
    r.add_argument("--png", default=None, help="also write a tone-mapped sRGB PNG")
    r.add_argument("--json", default=None, help="write a JSON report (method, every parameter in effect, bake, "
                   "device, resolution, timings_ms)")
    r.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override a scene value, e.g. camera.fov_deg=30 or object.bunny.albedo=[1,0,0]")
    r.add_argument("--frames", type=int, default=None, metavar="N",
                   help="time N frames after 0.3 s of warm-up frames (default: render one frame, untimed, "
                   "with progress)")
    r.add_argument("--exposure", type=float, default=None,
                   help="PNG exposure in stops (default: auto, the 97th percentile of the lit pixels to 0.9)")

    d = sub.add_parser("demo", help="render the built-in procedural scene with every method")
    d.add_argument("--out", default="out/demo", help="output directory (default out/demo)")
    d.add_argument("--frames", type=int, default=5)
    d.add_argument("--reference-face-size", type=int, default=8,
                   help="also render the brute-force reference with this face size (0: skip; default 8)")
    d.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="override a scene value")

    m = sub.add_parser("export-mitsuba", help="export a TOML scene as a Mitsuba 3 XML scene (docs/mitsuba.md)")
    m.add_argument("scene", help="scene file (docs/scene-format.md)")
    m.add_argument("-o", "--output", required=True, metavar="DIR",
                   help="output directory: scene.xml, envmap.exr, meshes/*.ply")
    m.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override a scene value, e.g. camera.fov_deg=30 or object.bunny.albedo=[1,0,0]")
    m.add_argument("--spp", type=int, default=256, help="default samples per pixel of the XML (default 256)")
    m.add_argument("--force", action="store_true",
                   help="replace files in DIR even if no earlier export wrote them")

    b = sub.add_parser("bench", help="speed against error of methods and Mitsuba 3 on scenes (docs/benchmarks.md)")
    b.add_argument("scene", nargs="*", help="scene files (docs/scene-format.md)")
    b.add_argument("--out", required=True, metavar="DIR", help="output directory for results.json/csv, pareto.png, "
                   "report.md and images; with several scenes, one folder per scene in it, named by the file")
    b.add_argument("--workers", type=int, default=None, metavar="N",
                   help="run the scenes on a local Dask cluster of N worker processes, one scene per job "
                        "(docs/farm.md; needs dask[distributed])")
    b.add_argument("--scheduler", default=None, metavar="ADDRESS",
                   help="run the scenes on the Dask cluster of this scheduler (a shared file system)")
    b.add_argument("--methods", default=None, help="comma-separated methods (default: those of "
                   f"{', '.join(t.name for t in techniques() if t.benchmarked)} "
                   "that apply to the scene)")
    b.add_argument("--frames", type=int, default=5, help="timed frames per setting after 0.3 s of warm-up frames (>= 5)")
    b.add_argument("--spp", type=_int_list, default=None, help="Mitsuba samples per pixel (default 1,2,4,...,1024)")
    b.add_argument("--face-sizes", type=_int_list, default=None,
                   help="reference face sizes to sweep (default 4,8,16,32)")
    b.add_argument("--reference-face-size", type=int, default=64, help="ground-truth face size (default 64)")
    b.add_argument("--reference-sun-supersampling", type=int, default=4,
                   help="ground-truth sub-texels per bright texel side (default 4)")
    b.add_argument("--mitsuba-variant", default=None, help="Mitsuba variant (default llvm_ad_rgb)")
    b.add_argument("--no-rays", action="store_true", help="skip the ray-throughput comparison with Embree")
    b.add_argument("--readme", default=None, help="also refresh this scene's row of the table in this README")
    b.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="override a scene value")
    for technique in techniques():
        technique.add_bench_arguments(b)

    commands = {}
    for technique in techniques():
        commands.update(technique.add_commands(sub))
    return p, commands


def main(argv: list[str] | None = None) -> int:
    try:
        parser, commands = build_parser()
    except PenumbraError as exc:
        return _error(str(exc))
    args = parser.parse_args(argv)
    handlers = {"info": cmd_info, "methods": cmd_methods, "render": cmd_render, "demo": cmd_demo,
                "export-mitsuba": cmd_export_mitsuba, "bench": cmd_bench, **commands}
    try:
        return handlers[args.command](args)
    except PenumbraError as exc:
        return _error(str(exc))
    # Failures that the input or the machine causes, not penumbra's code: an
    # error line, not a traceback (docs/reliability.md). Their causes
    # are checked at the source where we can; this is the net under them.
    except OSError as exc:
        where = f"{exc.filename}: " if exc.filename else ""
        return _error(f"{where}{exc.strerror or exc}")
    except MemoryError:
        return _error("out of memory (an input too large for this machine?)")
    except RecursionError:
        return _error("input nested too deeply")
    except UnicodeError as exc:
        return _error(f"text that is not valid UTF-8: {exc}")
    except KeyboardInterrupt:
        print("penumbra: interrupted", file=sys.stderr)
        return 130


def _error(message: str) -> int:
    """The command line's report of a failure it was given (exit status 2)."""
    print(f"penumbra: error: {message}", file=sys.stderr)
    return 2


if __name__ == "__main__":
    sys.exit(main())
