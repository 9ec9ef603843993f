"""The ``penumbra`` command: ``info``, ``render``, ``demo``, ``export-mitsuba``,
``bench``, ``bake-fiv`` and ``fiv-info``."""

from __future__ import annotations

import argparse
import json
import os
import signal
import struct
import sys
from pathlib import Path

import numpy as np

from . import __version__
from .errors import PenumbraError


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


def _kib(n: int) -> str:
    return f"{n / 1024:.1f} KiB" if n < 1 << 20 else f"{n / (1 << 20):.1f} MiB"


def _fiv_summary(records: list[dict]) -> str:
    parts = []
    for r in records:
        what = ", ".join(r["objects"][:3]) + (f" and {len(r['objects']) - 3} more" if len(r["objects"]) > 3 else "")
        how = f"baked in {r['bake_s']:.1f} s ({r['rays'] / 1e6:.1f} M rays)" if r["baked"] else "from the cache"
        parts.append(f"{what}: {'x'.join(map(str, r['samples']))}, {_kib(r['stored_bytes'])}, {how}")
    return f"fiv: {len(records)} occlusion field(s): " + ("; ".join(parts) if parts else "no occluders in the scene")


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


def report(result, scene_source: str) -> dict:
    h, w = result.image.shape[:2]
    return {"method": result.method, "device": result.device, "resolution": [w, h], "params": result.params,
            "scene": scene_source, "timings_ms": result.timings_ms, "penumbra_version": __version__}


def cmd_render(args) -> int:
    from .core import Context
    from .fileutil import atomic_write_text
    from .render import build_scene, render
    from .scenefile import load_scene

    desc = load_scene(args.scene, args.set)
    method = args.method or desc.render.get("method", "unshadowed")
    params = {k: v for k, v in desc.render.items() if k != "method"}
    ctx = Context(args.device)
    built = build_scene(desc, ctx)
    with _BakeBars() as bakes, _progress(args.frames, f"render {method}") as bar:
        result = render(built, method, frames=args.frames, progress=bar, bake_progress=bakes, **params)
    if method == "fiv":
        print(_fiv_summary(built.fiv_records))
    out = args.output if args.output or args.png else "out.exr"
    written = _write_outputs(result, out, args.png, args.exposure)
    rep = report(result, str(args.scene))
    if args.json:
        atomic_write_text(args.json, json.dumps(rep, indent=2) + "\n")
        written.append(args.json)
    t = result.timings_ms
    print(f"{method} on {result.device}: frame median {t['frame_median']:.2f} ms "
          f"(G-buffer {t['gbuffer_median']:.2f} ms, shading {t['shade_median']:.2f} ms); wrote {', '.join(written)}")
    return 0


def auto_exposure(image: np.ndarray, percentile: float = 97.0) -> float:
    """Exposure (stops) that maps the given percentile of the lit pixels' luminance to 0.9."""
    lum = image[..., :3] @ np.array([0.2126, 0.7152, 0.0722], np.float32)
    lit = lum[image[..., 3] > 0]
    level = float(np.percentile(lit, percentile)) if lit.size else 0.0
    return float(np.log2(0.9 / level)) if level > 0 else 0.0


def cmd_demo(args) -> int:
    from .core import Context
    from .imageio import write_exr, write_png
    from .render import GBUFFER_VIEWS, INTERACTIVE_METHODS, build_scene, render
    from .scenefile import default_scene_path, load_scene

    out = Path(args.out)
    desc = load_scene(default_scene_path(), args.set)
    ctx = Context(args.device)
    built = build_scene(desc, ctx)
    rows = []
    result = None
    # Interactive methods with full timing; the brute-force reference once, at a
    # coarse direction grid, so the demo also shows ground-truth soft shadows.
    runs = [(m, args.frames, {}) for m in INTERACTIVE_METHODS]
    if args.reference_face_size > 0:
        runs.append(("reference", 1, {"face_size": args.reference_face_size}))
    with _BakeBars() as bakes, _progress(sum(f + (m != "reference") for m, f, _ in runs), "demo") as bar:
        for method, frames, params in runs:
            result = render(built, method, frames=frames, progress=bar, warmup=method != "reference",
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
    if "fiv" in (m for m, _, _ in runs):
        print(_fiv_summary(built.fiv_records))
    print(f"images in {out}/: " + ", ".join(f"{m}.exr/.png" for m, _, _ in runs) + ", "
          + ", ".join(f"gbuffer_{v}.exr/.png" for v in GBUFFER_VIEWS))
    return 0


# ---------------------------------------------------------------- FIV bakes


def _samples_arg(text: str) -> tuple[int, int, int]:
    vals = _int_list(text.replace("x", ","))
    if len(vals) != 3:
        raise argparse.ArgumentTypeError(f"{text!r} is not PHI,THETA,RADII (e.g. 32,17,15)")
    return vals


def fiv_file_header(path: str | Path) -> dict | None:
    """The grid and progress of a .pnfiv file from its header (docs/fiv.md),
    without checking it; None when it is not one."""
    try:
        with open(path, "rb") as f:
            head = f.read(32)
    except OSError:
        return None
    if len(head) < 32 or head[:8] != b"PNFIV\0\r\n":
        return None
    version, _, theta, phi, radii, done = struct.unpack_from("<6I", head, 8)
    return {"version": version, "samples": (phi, theta, radii), "spheres_done": done}


def cmd_bake_fiv(args) -> int:
    from ._native import ERROR_CANCELLED
    from .core import Context, EnvMap, Mesh
    from .errors import InputError, PenumbraError
    from .fiv import FivField, FivOptions
    from .meshio import load_mesh
    from .render import environment_latlong
    from .scenefile import PROCEDURAL_ENVS, EnvironmentDesc, parse_scene

    # The options are checked like a scene's [fiv] table (same ranges), named as flags.
    table = {"samples": list(args.samples), "precision": args.precision, "inner_radius": args.inner_radius,
             "error_target": args.error_target, "face_size": args.face_size,
             "sun_supersampling": args.sun_supersampling, "sun_threshold": args.sun_threshold}
    try:
        desc = parse_scene({"fiv": table}).fiv
    except InputError as exc:
        msg = str(exc)
        for key in table:
            msg = msg.replace(f"[fiv] {key}", f"--{key.replace('_', '-')}")
        raise InputError(msg.replace("[fiv] ", "")) from None
    options = FivOptions(**desc.bake_options())
    if args.env_intensity < 0:
        raise InputError(f"--env-intensity {args.env_intensity} must be >= 0")
    env_desc = EnvironmentDesc(map=args.env if args.env in PROCEDURAL_ENVS else str(Path(args.env).expanduser()),
                               rotation_deg=args.env_rotation, intensity=args.env_intensity)
    ctx = Context(args.device)
    env = EnvMap(ctx, environment_latlong(env_desc), rotation_deg=env_desc.rotation_deg,
                 intensity=env_desc.intensity)
    m = load_mesh(args.mesh)
    mesh = Mesh(ctx, m.vertices, m.faces, m.normals)
    out = Path(args.output)
    head = fiv_file_header(out) if out.exists() else None
    resumed = bool(head and 0 < head["spheres_done"] < head["samples"][2])
    if resumed:
        print(f"resuming {out}: {head['spheres_done']} of {head['samples'][2]} spheres baked")
    bars = _BakeBars()
    previous = signal.getsignal(signal.SIGINT)

    def interrupt(*_):  # Ctrl-C: stop after the current sphere, with a checkpoint to resume from
        bars.stop = True

    if previous is signal.default_int_handler:
        signal.signal(signal.SIGINT, interrupt)
    label = Path(args.mesh).name
    try:
        with bars:
            field = FivField.bake(env, mesh, options, out, progress=lambda d, t: bars(label, d, t))
    except PenumbraError as exc:
        if exc.status == ERROR_CANCELLED:  # stopped by Ctrl-C after a checkpoint
            print(f"penumbra: interrupted: {exc} (the same command resumes it)", file=sys.stderr)
            return 130
        raise
    finally:
        if previous is signal.default_int_handler:
            signal.signal(signal.SIGINT, previous)
    info = field.info()
    theta, phi, radii = info["samples"]
    grid = f"{phi}x{theta}x{radii} (phi x theta x radii)"
    if info["rays"] == 0:
        print(f"{out} already holds this finished bake: {grid}, nothing to do")
    else:
        print(f"{'finished' if resumed else 'baked'} {label} under "
              f"{Path(args.env).name if args.env not in PROCEDURAL_ENVS else args.env} in "
              f"{info['bake_seconds']:.2f} s{' (this run)' if resumed else ''}: {grid} = {info['sample_count']} samples "
              f"({info['inside_count']} inside the mesh), {info['rays']} rays "
              f"({info['rays'] / max(info['bake_seconds'], 1e-9) / 1e6:.1f} M rays/s)")
    print(f"memory: {info['stored_bytes']} bytes of samples ({_kib(info['stored_bytes'])}, {info['precision']}); "
          f"{'file' if info['rays'] == 0 else 'wrote'} {out} ({os.path.getsize(out)} bytes)")
    return 0


def cmd_fiv_info(args) -> int:
    from .core import Context
    from .errors import PenumbraError
    from .fiv import FivField

    ctx = Context(args.device)
    try:
        info = FivField.load(ctx, args.file).info()
    except PenumbraError:
        head = fiv_file_header(args.file)
        if head and head["spheres_done"] < head["samples"][2]:
            print(f"{args.file}: unfinished FIV bake, {'x'.join(map(str, head['samples']))} (phi x theta x radii), "
                  f"{head['spheres_done']} of {head['samples'][2]} spheres baked: run the same bake-fiv command "
                  "again to resume", file=sys.stderr)
            return 2
        raise
    theta, phi, radii = info["samples"]
    if args.json:
        print(json.dumps({**info, "samples_phi_theta_radii": [phi, theta, radii], "file_bytes":
                          os.path.getsize(args.file)}, indent=2))
        return 0
    c = info["centre"]
    print(f"{args.file}: FIV occlusion field (docs/fiv.md), {os.path.getsize(args.file)} bytes")
    print(f"  grid:        {phi}x{theta}x{radii} (phi x theta x radii) = {info['sample_count']} samples, "
          f"{info['inside_count']} inside the mesh")
    print(f"  storage:     {info['precision']}, {info['stored_bytes']} bytes of samples ({_kib(info['stored_bytes'])})")
    print(f"  radii:       {info['inner']:.4g} .. {info['outer']:.4g} object units, geometric "
          f"(inner_radius {info['inner_radius']:.3g} R, error_target {info['error_target']:.3g})")
    print(f"  bounds:      centre ({c[0]:.4g}, {c[1]:.4g}, {c[2]:.4g}), R = {info['radius']:.4g}")
    print(f"  directions:  face_size {info['face_size']}, sun_supersampling {info['sun_supersampling']} "
          f"(threshold {info['sun_threshold']:.3g})")
    print(f"  mesh hash:   {info['mesh_hash']}")
    print(f"  env hash:    {info['env_hash']}")
    return 0


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


def cmd_bench(args) -> int:
    from .bench import BenchOptions, fiv_scaling, run
    from .errors import InputError

    if args.fiv_scaling:
        if args.scene:
            raise InputError("bench --fiv-scaling makes its own scenes: give no scene file")
        out = Path(args.out)
        res = fiv_scaling(out, counts=args.fiv_counts, samples=args.fiv_samples, resolution=args.fiv_resolution,
                          frames=args.frames, mitsuba_count=args.fiv_mitsuba_count or None,
                          mitsuba_resolution=args.fiv_mitsuba_resolution, overrides=args.set,
                          log=lambda msg: print(msg, file=sys.stderr))
        print(f"{'occluders':>9}{'fiv ms':>10}{'floor ms':>10}{'x floor':>9}{'fps':>8}{'paper fps':>11}")
        for r in res["results"]:
            print(f"{r['occluders']:>9}{r['fiv_shade_ms']:>10.2f}{r['floor_ms']:>10.3f}{r['ratio_to_floor']:>9.0f}"
                  f"{r['fps_shading']:>8.1f}{r['paper_fps'] if r['paper_fps'] is not None else '-':>11}")
        print(f"penumbra bench: wrote {out}/results.json, report.md")
        return 0
    if not args.scene:
        raise InputError("bench needs a scene file (or --fiv-scaling)")

    opts = BenchOptions(frames=args.frames, reference_face_size=args.reference_face_size,
                        reference_sun_supersampling=args.reference_sun_supersampling,
                        mitsuba_variant=args.mitsuba_variant, rays=not args.no_rays)
    if args.methods:
        opts.methods = tuple(m.strip() for m in args.methods.split(",") if m.strip())
    if args.spp:
        opts.spp = args.spp
    if args.face_sizes:
        opts.sweeps["reference"] = [{"face_size": f} for f in args.face_sizes]
    out = Path(args.out)
    res = run(args.scene, out, opts, overrides=args.set, log=lambda msg: print(msg, file=sys.stderr))
    print(f"penumbra bench: wrote {out}/results.json, results.csv, pareto.png, report.md")
    if args.readme:
        from .bench import readme_row, update_readme

        update_readme(args.readme, readme_row(res["summary"], res["results"]))
        print(f"penumbra bench: updated the benchmark table in {args.readme}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="penumbra", description="Environment lighting with soft shadows (OpenCL).")
    p.add_argument("--version", action="version", version=f"penumbra {__version__}")
    p.add_argument("--device", default=None, help="context config, e.g. 'device=gpu' (default: PENUMBRA_DEVICE or a CPU)")
    sub = p.add_subparsers(dest="command", required=True)

    sub.add_parser("info", help="list OpenCL devices and the library version")

    r = sub.add_parser("render", help="render a TOML scene file")
    r.add_argument("scene", help="scene file (docs/scene-format.md)")
    r.add_argument("--method", default=None, help="shading method (default: the scene's [render] method)")
    r.add_argument("-o", "--output", default=None, help="EXR output (default out.exr)")
    r.add_argument("--png", default=None, help="also write a tone-mapped sRGB PNG")
    r.add_argument("--json", default=None, help="write a JSON report (method, device, resolution, params, timings_ms)")
    r.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override a scene value, e.g. camera.fov_deg=30 or object.bunny.albedo=[1,0,0]")
    r.add_argument("--frames", type=int, default=5, help="timed frames after 0.3 s of warm-up frames (default 5)")
    r.add_argument("--exposure", type=float, default=0.0, help="PNG exposure in stops")

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

    b = sub.add_parser("bench", help="speed against error of methods and Mitsuba 3 on one scene (docs/benchmarks.md)")
    b.add_argument("scene", nargs="?", help="scene file (docs/scene-format.md)")
    b.add_argument("--out", required=True, metavar="DIR", help="output directory for results.json/csv, pareto.png, "
                   "report.md and images")
    b.add_argument("--methods", default=None, help="comma-separated methods (default: unshadowed, fiv if the scene has occluders, heightfield if it "
                        "has height fields, reference)")
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
    b.add_argument("--fiv-scaling", action="store_true",
                   help="instead of a scene: fiv's per-frame cost against the number of occluders (N bunnies)")
    b.add_argument("--fiv-counts", type=_int_list, default=(1, 10, 30, 60), help="occluder counts (default 1,10,30,60)")
    b.add_argument("--fiv-samples", type=_samples_arg, default=(128, 65, 30), metavar="PHI,THETA,RADII",
                   help="the bunny's field (default 128,65,30 as the paper's Table 2)")
    b.add_argument("--fiv-resolution", type=int, default=512, help="image side in pixels (default 512)")
    b.add_argument("--fiv-mitsuba-count", type=int, default=10,
                   help="also compare with Mitsuba at equal error on this many bunnies (0: skip; default 10)")
    b.add_argument("--fiv-mitsuba-resolution", type=int, default=128,
                   help="image side of that comparison (default 128)")

    f = sub.add_parser("bake-fiv", help="bake the FIV occlusion field of a mesh under an env map (docs/fiv.md)")
    f.add_argument("mesh", help="occluder mesh file (.obj, .ply, .off, .stl)")
    f.add_argument("--env", required=True, help="env map file, or a procedural map name (sky, constant, ...)")
    f.add_argument("--samples", type=_samples_arg, default=(32, 17, 15), metavar="PHI,THETA,RADII",
                   help="grid in the paper's notation (default 32,17,15)")
    f.add_argument("-o", "--output", required=True, metavar="FILE",
                   help="bake file (.pnfiv); an unfinished bake there is resumed")
    f.add_argument("--precision", choices=("float16", "float32"), default="float16")
    f.add_argument("--face-size", type=int, default=32, help="env directions: cube face size (default 32)")
    f.add_argument("--sun-supersampling", type=int, default=4,
                   help="sub-texels per bright texel side (default 4)")
    f.add_argument("--sun-threshold", type=float, default=0.1,
                   help="share of the brightest texel's power that counts as bright (default 0.1)")
    f.add_argument("--inner-radius", type=float, default=0.2, help="innermost sphere, bounding radii (default 0.2)")
    f.add_argument("--error-target", type=float, default=0.01,
                   help="outermost sphere at R / sqrt(error_target) (default 0.01: 10 R)")
    f.add_argument("--env-rotation", type=float, default=0.0, metavar="DEG",
                   help="env map rotation about +y, as [environment] rotation_deg (default 0)")
    f.add_argument("--env-intensity", type=float, default=1.0, help="env radiance scale (default 1)")

    i = sub.add_parser("fiv-info", help="print the header of a FIV bake file")
    i.add_argument("file", help="bake file (.pnfiv)")
    i.add_argument("--json", action="store_true", help="print the info as JSON")
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    handlers = {"info": cmd_info, "render": cmd_render, "demo": cmd_demo, "export-mitsuba": cmd_export_mitsuba,
                "bench": cmd_bench, "bake-fiv": cmd_bake_fiv, "fiv-info": cmd_fiv_info}
    try:
        return handlers[args.command](args)
    except PenumbraError as exc:
        print(f"penumbra: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
