"""Experiments of the depthmap method (docs/depthmap.md), in one run each:

  maps    map rendering, rasteriser against ray caster, at 64 and 256 maps
          on a 29k- and a 100k-triangle mesh (time ratios in one process)
  error   NRMSE against the reference (face 64, sun split 4 x 4) on the seed's
          scenes (bench/scenes/depthmap/*.toml): by N, by map resolution, by PCF and
          by specular rule (point, seed blend, cap quadrature)
  speed   per-frame time at 512 x 512 with 64 and 128 directions for one and
          two armadillos, split into map rendering and shading, as ratios
          against the floor kernel measured in the same run; the defaults
          and those before the shadow-footprint fit (fit 0, 256^2 maps)

  python bench/depthmap_experiments.py [--only maps,error,speed] [--out bench/results/depthmap]

Writes results.json and report.md (atomically) and a few PNGs into --out.
Ground truths are cached in --out/cache/ as .npy by scene and resolution.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
try:
    import penumbra
except ImportError:  # a checkout without `pip install .` (bench/harness.py says why only then)
    sys.path.insert(0, str(REPO / "python"))
    import penumbra
from penumbra import GBuffer, Image, Renderer  # noqa: E402
from penumbra.fileutil import atomic_write, atomic_write_text  # noqa: E402
from penumbra.imageio import write_png  # noqa: E402
from penumbra.metrics import compare  # noqa: E402
from penumbra.render import build_scene  # noqa: E402
from penumbra.scenefile import apply_overrides, parse_scene, read_toml  # noqa: E402

SCENES = REPO / "bench" / "scenes" / "depthmap"  # not in `make bench`: its ground truths take minutes each
SEED_SCENES = ("armadillo_uffizi", "two_armadillos_sunny", "phong_spheres_uffizi", "phong_spheres_outdoor")


def load(name: str, ctx, overrides=()):
    path = SCENES / f"{name}.toml"
    data = apply_overrides(read_toml(path), list(overrides))
    desc = parse_scene(data, path.parent, str(path))
    return build_scene(desc, ctx)


def gbuffer(built):
    w, h = built.camera.resolution
    gb = GBuffer(built.ctx, w, h)
    built.scene.render_gbuffer(gb)
    return gb


def median_ms(fn, ctx, frames=5):
    fn()
    ctx.finish()
    times = []
    for _ in range(frames):
        t0 = time.perf_counter()
        fn()
        ctx.finish()
        times.append(1000.0 * (time.perf_counter() - t0))
    return float(np.median(times))


def shade(built, gb, method, **params):
    img = Image(built.ctx, gb.width, gb.height)
    r = Renderer(built.ctx, method, **params)
    r.execute(built.scene, gb, img)
    return img.read()[..., :3], r, img


def truth(built, gb, name, out: Path):
    w, h = built.camera.resolution
    path = out / "cache" / f"reference-{name}-{w}x{h}.npy"
    if path.is_file():
        return np.load(path)
    img, _, _ = shade(built, gb, "reference", face_size=64, sun_supersampling=4, background=0)
    def save(tmp: str) -> None:
        with open(tmp, "wb") as f:
            np.save(f, img)

    atomic_write(path, save)
    return img


# --------------------------------------------------------------------------- maps


def experiment_maps(ctx, out: Path, log) -> dict:
    rows = []
    for mesh, label in (("armadillo_odedstein", "armadillo 29k"), ("dragon_photon", "dragon 100k")):
        over = ["camera.resolution=[64,64]"]
        if mesh != "armadillo_odedstein":
            over += [f"object.armadillo.mesh=\"../../../../shared/data/meshes/{mesh}.obj\"",
                     "object.armadillo.scale=0.1", "object.armadillo.translate=[0,-0.5716,0]"]
        built = load("armadillo_uffizi", ctx, over)
        gb = gbuffer(built)
        img = Image(ctx, gb.width, gb.height)
        tris = sum(m.info["triangles"] for m in built.meshes)
        for n in (64, 256):
            times = {}
            for k, name in ((0, "raster"), (1, "raycast")):
                r = Renderer(ctx, "depthmap", directions=n, map_renderer=k)
                full = median_ms(lambda: r.execute(built.scene, gb, img), ctx)
                r.set(reuse_maps=1)
                shade_only = median_ms(lambda: r.execute(built.scene, gb, img), ctx)
                times[name] = max(full - shade_only, 1e-3)
            row = dict(mesh=label, triangles=tris, maps=n, resolution=256, raster_ms=times["raster"],
                       raycast_ms=times["raycast"], raycast_over_raster=times["raycast"] / times["raster"])
            log(json.dumps(row))
            rows.append(row)
    return {"rows": rows}


# --------------------------------------------------------------------------- error


def experiment_error(ctx, out: Path, log, scenes=SEED_SCENES, size=None, save=lambda rows: None) -> dict:
    rows = []
    for name in scenes:
        built = load(name, ctx, [f"camera.resolution=[{size[0]},{size[1]}]"] if size else [])
        gb = gbuffer(built)
        ref = truth(built, gb, name, out)
        mask = gb.read("instance") != 0xFFFFFFFF
        base = dict(background=0)
        settings = [("N", dict(directions=n)) for n in (16, 32, 64, 128, 256)]
        settings += [("resolution", dict(resolution=res)) for res in (64, 128, 512, 1024)]
        settings += [("pcf", dict(pcf=p)) for p in (0, 2)]
        settings += [("specular", dict(specular=k)) for k in (0, 1)]
        settings += [("specular", dict(specular=2, cap_samples=c)) for c in (4, 64)]
        settings += [("visibility", dict(visibility=0))]
        for knob, params in settings:
            img, _, _ = shade(built, gb, "depthmap", **base, **params)
            m = compare(ref, img, mask)
            row = dict(scene=name, size=list(built.camera.resolution), knob=knob, params=params, nrmse=m["nrmse"],
                       rel_rms=m["rel_rms"])
            log(json.dumps(row))
            rows.append(row)
        img, _, _ = shade(built, gb, "depthmap", **base)
        exposure = 1.0 / max(float(np.percentile(ref[mask], 99)), 1e-6)
        write_png(out / f"{name}_depthmap.png", img, exposure=exposure)
        write_png(out / f"{name}_reference.png", ref, exposure=exposure)
        m = compare(ref, img, mask)
        rows.append(dict(scene=name, size=list(built.camera.resolution), knob="default", params={}, nrmse=m["nrmse"],
                         rel_rms=m["rel_rms"]))
        save(rows)
    return {"rows": rows}


# --------------------------------------------------------------------------- speed


def experiment_speed(ctx, out: Path, log) -> dict:
    rows = []
    for name in ("armadillo_uffizi", "two_armadillos_sunny"):
        built = load(name, ctx, ["camera.resolution=[512,512]"])
        gb = gbuffer(built)
        img = Image(ctx, 512, 512)
        floor = Renderer(ctx, "floor")
        t_floor = median_ms(lambda: floor.execute(built.scene, gb, img), ctx, frames=11)
        # The defaults, and those before the shadow-footprint fit (fit 0, 256^2 maps), in the same process.
        for n, setting, extra in ((64, "before", dict(fit=0, resolution=256)), (64, "defaults", {}),
                                  (128, "before", dict(fit=0, resolution=256)), (128, "defaults", {})):
            r = Renderer(ctx, "depthmap", directions=n, **extra)
            full = median_ms(lambda: r.execute(built.scene, gb, img), ctx)
            r.set(reuse_maps=1)
            shade_ms = median_ms(lambda: r.execute(built.scene, gb, img), ctx)
            row = dict(scene=name, directions=n, setting=setting, floor_ms=t_floor, frame_ms=full,
                       maps_ms=full - shade_ms, shade_ms=shade_ms, frame_over_floor=full / t_floor,
                       shade_over_floor=shade_ms / t_floor)
            log(json.dumps(row))
            rows.append(row)
    return {"rows": rows}


EXPERIMENTS = {"maps": experiment_maps, "error": experiment_error, "speed": experiment_speed}


def report(results: dict) -> str:
    lines = ["# depthmap experiments", "", f"device: {results.get('device', '')}", ""]
    if "maps" in results:
        lines += ["## Map rendering: rasteriser vs ray caster (256 x 256 maps)", "",
                  "| mesh | maps | raster ms | ray cast ms | ray cast / raster |", "|---|---|---|---|---|"]
        lines += [f"| {r['mesh']} | {r['maps']} | {r['raster_ms']:.1f} | {r['raycast_ms']:.1f} | "
                  f"{r['raycast_over_raster']:.2f} |" for r in results["maps"]["rows"]]
        lines.append("")
    if "error" in results:
        lines += ["## NRMSE against the reference (face 64, sun 4 x 4), defaults except the knob", "",
                  "| scene | pixels | knob | setting | NRMSE | rel. RMS |", "|---|---|---|---|---|---|"]
        lines += [f"| {r['scene']} | {'x'.join(map(str, r.get('size', [])))} | {r['knob']} | {json.dumps(r['params'])} | "
                  f"{r['nrmse']:.4f} | "
                  f"{r.get('rel_rms', float('nan')):.4f} |" for r in results["error"]["rows"]]
        lines.append("")
    if "speed" in results:
        lines += ["## Per frame at 512 x 512 (ms, one run; ratios against the floor kernel)", "",
                  "| scene | N | setting | floor | frame | maps | shading | frame / floor | shading / floor |",
                  "|---|---|---|---|---|---|---|---|---|"]
        lines += [f"| {r['scene']} | {r['directions']} | {r.get('setting', '')} | {r['floor_ms']:.2f} | "
                  f"{r['frame_ms']:.0f} | "
                  f"{r['maps_ms']:.0f} | {r['shade_ms']:.0f} | {r['frame_over_floor']:.0f} | "
                  f"{r['shade_over_floor']:.0f} |" for r in results["speed"]["rows"]]
        lines.append("")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--only", default="maps,error,speed")
    ap.add_argument("--out", default=str(REPO / "bench" / "results" / "depthmap"))
    ap.add_argument("--scenes", default=",".join(SEED_SCENES), help="scenes of the error experiment")
    ap.add_argument("--size", default="", help="WxH: the error experiment's image size (default: the scenes')")
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    path = out / "results.json"
    results = json.loads(path.read_text()) if path.is_file() else {}
    ctx = penumbra.Context()
    results["device"] = ctx.device_name
    for key in args.only.split(","):
        t0 = time.perf_counter()
        kwargs = {}
        if key == "error":  # rows of other scenes from earlier runs stay; each scene's rows are saved when done
            scenes = tuple(args.scenes.split(","))
            earlier = [r for r in results.get("error", {}).get("rows", []) if r["scene"] not in scenes]

            def save(rows):
                results["error"] = {"rows": earlier + rows}
                atomic_write_text(path, json.dumps(results, indent=1))
                atomic_write_text(out / "report.md", report(results))

            kwargs = {"scenes": scenes, "save": save,
                      "size": tuple(int(x) for x in args.size.split("x")) if args.size else None}
        results[key] = EXPERIMENTS[key](ctx, out, lambda s: print(s, flush=True), **kwargs)
        if key == "error":
            results[key]["rows"] = earlier + results[key]["rows"]
        results[key]["seconds"] = time.perf_counter() - t0
        atomic_write_text(path, json.dumps(results, indent=1))
        atomic_write_text(out / "report.md", report(results))
    return 0


if __name__ == "__main__":
    sys.exit(main())
