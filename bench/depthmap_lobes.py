"""Blinn-Phong and GGX under the depthmap method's cap-average tables, two
builds in one run (docs/depthmap.md, "Blinn-Phong and GGX: a table with the
view angle"): the NRMSE against the reference (face 32, sun 2 x 2; cached),
over all pixels and over those with N.V below 0.5 and 0.17 (60 and 80 degrees),
and the shading time (maps reused, `reuse_maps 1`, median of --frames) of
each build's default `specular 3`, alternating the builds round by round
(each round runs a fresh process per build) so that the load hits them alike.

  python bench/depthmap_lobes.py --before /work/main/.venv/bin/python [--rounds 3]
        [--scenes blinn_phong_spheres_uffizi,ggx_spheres_uffizi] [--out bench/results/depthmap_lobes]

The worker (--worker SCENE) prints one JSON line; with --png it writes the image.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
REF_FACE, REF_SUN = 32, 2  # the reference's cube face and sun supersampling (cheaper than the seed benches' 64 and 4)
sys.path.insert(0, str(Path(__file__).resolve().parent))


def worker(name: str, out: Path, frames: int, png: str | None) -> None:
    from depthmap_experiments import gbuffer, load, shade

    import penumbra
    from penumbra import Image, Renderer
    from penumbra.metrics import compare

    ctx = penumbra.Context()
    built = load(name, ctx)
    gb = gbuffer(built)
    w, h = built.camera.resolution
    cached = out / "cache" / f"reference-{name}-{w}x{h}-face{REF_FACE}.npy"
    if cached.is_file():
        ref = np.load(cached)
    else:  # the first worker draws it; the others read it
        ref, _, _ = shade(built, gb, "reference", face_size=REF_FACE, sun_supersampling=REF_SUN, background=0)
        np.save(cached, ref)
    mask = gb.read("instance") != 0xFFFFFFFF
    img = Image(ctx, gb.width, gb.height)
    t0 = time.process_time()
    r = Renderer(ctx, "depthmap", background=0)
    r.execute(built.scene, gb, img)
    ctx.finish()
    first_cpu = time.process_time() - t0  # includes the tables' build (once per context)
    got = img.read()[..., :3]
    err = compare(ref, got, mask)
    # the oblique and grazing pixels (N.V below cos 60 and cos 80 degrees): the spheres' rims
    pos, nrm = gb.read("position")[..., :3].astype(np.float64), gb.read("normal")[..., :3].astype(np.float64)
    view = np.asarray(built.camera.position, np.float64) - pos
    nv = np.sum(nrm * view, -1) / np.maximum(np.linalg.norm(nrm, axis=-1) * np.linalg.norm(view, axis=-1), 1e-30)
    rims = {f"nrmse_nv_below_{k}": compare(ref, got, mask & (nv < c))["nrmse"] for k, c in (("0.5", 0.5), ("0.17", 0.17))}
    shade = Renderer(ctx, "depthmap", background=0, reuse_maps=1)
    shade.execute(built.scene, gb, img)
    ctx.finish()
    times, cpu = [], []
    for _ in range(frames):
        t0, c0 = time.perf_counter(), time.process_time()
        shade.execute(built.scene, gb, img)
        ctx.finish()
        times.append(1000.0 * (time.perf_counter() - t0))
        cpu.append(1000.0 * (time.process_time() - c0))
    if png:
        from penumbra.imageio import write_png

        np.save(png + ".npy", got)
        write_png(png, got)
        write_png(str(Path(png).with_name(f"reference-{name}.png")), ref[..., :3])
    print(json.dumps(dict(scene=name, nrmse=err["nrmse"], rel_rms=err["rel_rms"], **rims, shade_ms=float(np.median(times)),
                          shade_cpu_ms=float(np.median(cpu)), first_frame_cpu_s=first_cpu)))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--worker")
    ap.add_argument("--png")
    ap.add_argument("--before", help="python of the build to compare with (its package)")
    ap.add_argument("--scenes", default="blinn_phong_spheres_uffizi,ggx_spheres_uffizi")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--frames", type=int, default=3)
    ap.add_argument("--out", default=str(REPO / "bench" / "results" / "depthmap_lobes"))
    args = ap.parse_args()
    out = Path(args.out)
    (out / "cache").mkdir(parents=True, exist_ok=True)
    if args.worker:
        worker(args.worker, out, args.frames, args.png)
        return 0
    builds = {"before": args.before, "after": sys.executable}
    rows = {}
    loads = []
    for k in range(args.rounds):
        for name in args.scenes.split(","):
            for build, py in builds.items():
                cmd = [py, __file__, "--worker", name, "--frames", str(args.frames), "--out", str(out)]
                if k == 0:
                    cmd += ["--png", str(out / f"{build}-{name}.png")]
                res = subprocess.run(cmd, capture_output=True, text=True, check=True)
                row = json.loads(res.stdout.strip().splitlines()[-1])
                rows.setdefault((name, build), []).append(row)
                loads.append(os.getloadavg()[0])
                print(build, json.dumps(row), "load", loads[-1], flush=True)
    summary = []
    for (name, build), rs in rows.items():
        summary.append(dict(scene=name, build=build, nrmse=rs[0]["nrmse"],
                            **{k: v for k, v in rs[0].items() if k.startswith("nrmse_nv")},
                            shade_ms=float(np.median([r["shade_ms"] for r in rs])),
                            shade_cpu_ms=float(np.median([r["shade_cpu_ms"] for r in rs])),
                            first_frame_cpu_s=float(np.median([r["first_frame_cpu_s"] for r in rs]))))
        print(json.dumps(summary[-1]))
    print("load (1 min) over the run:", min(loads), "-", max(loads))
    (out / "results.json").write_text(json.dumps(dict(summary=summary, load=[min(loads), max(loads)]), indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
