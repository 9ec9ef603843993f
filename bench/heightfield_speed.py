"""A/B speed of the `heightfield` method against a pinned commit, in one run.

The pinned commit (default 9b774a1, the main branch before the height-field
speed work) is exported with `git archive` into a cache folder and its
libpenumbra built there with CMake (once); its python/ is used through
PYTHONPATH and its library through PENUMBRA_LIBRARY (python/penumbra/_native.py
honours it; the kernels are embedded in the library). Both versions then time
the same scenes in alternating subprocess rounds (A, B, A, B, ...), so the
load of a shared machine falls on both alike; per phase the median over
rounds is reported and the ratio A / B.

Phases per scene (defaults of the method unless --params), medians of
--frames frames after one warm-up frame:
  frame      renderer.execute: every per-vertex pass (env, lights) + shading
  frame_bands4  the same with 4 SH bands (the same settings on both sides: A's default)
  no_sun     the same with sun_threshold = 0 (the sun texels' share is the difference)
  azimuths16 the frame with 16 azimuths on both sides (a knob that trades error for time,
             docs/heightfield.md, Speed); the report also gives A's default frame / B's azimuths16
  horizons   the env horizons alone (hf_probe) with their read-back
  pyramid    new heights: upload, pyramid, normals (read-back of the normals subtracted)
  floor      the floor kernel (reads the G-buffer, writes the image)

    python bench/heightfield_speed.py [--rounds 2] [--frames 3] [--baseline 9b774a1]
        [--scenes bench/scenes/terrain_sunny.toml ...] [--out bench/results/heightfield_speed]
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

REPO = Path(__file__).resolve().parents[1]
DEFAULT_SCENES = ["bench/scenes/terrain_sunny.toml", "bench/scenes/terrain_overcast_light.toml"]
PHASES = ("frame", "frame_bands4", "no_sun", "azimuths16", "horizons", "pyramid", "floor")
CPU_PHASES = ("frame", "frame_bands4", "no_sun", "azimuths16", "horizons")


def baseline_build(commit: str, cache: Path) -> Path:
    """The pinned commit's tree and libpenumbra under cache/<sha>; built once."""
    sha = subprocess.run(["git", "-C", str(REPO), "rev-parse", commit], check=True, capture_output=True,
                         text=True).stdout.strip()
    root = cache / sha[:12]
    lib = root / "build" / "libpenumbra.so"
    if lib.is_file():
        return root
    src = root / "src"
    src.mkdir(parents=True, exist_ok=True)
    archive = subprocess.run(["git", "-C", str(REPO), "archive", sha], check=True, capture_output=True).stdout
    subprocess.run(["tar", "-x", "-C", str(src)], input=archive, check=True)
    subprocess.run(["cmake", "-S", str(src), "-B", str(root / "build"), "-G", "Ninja", "-DCMAKE_BUILD_TYPE=Release",
                    "-DPENUMBRA_TESTS=OFF"], check=True, stdout=subprocess.DEVNULL)
    subprocess.run(["cmake", "--build", str(root / "build"), "--target", "penumbra"], check=True,
                   stdout=subprocess.DEVNULL)
    if not lib.is_file():
        raise SystemExit(f"the baseline build made no {lib}")
    return root


def worker(scene_path: str, frames: int, params: dict) -> dict:
    """Times the phases in this process (the penumbra on sys.path / PENUMBRA_LIBRARY)."""
    import numpy as np
    from penumbra import GBuffer, Image, Renderer
    from penumbra.core import Context
    from penumbra.methods.heightfield import fields
    from penumbra.render import build_scene
    from penumbra.scenefile import load_scene

    ctx = Context()
    desc = load_scene(scene_path)
    built = build_scene(desc, ctx)
    w, h = desc.camera.resolution
    gb, img = GBuffer(ctx, w, h), Image(ctx, w, h)
    built.scene.render_gbuffer(gb)
    ctx.finish()
    field, instance = next(iter(fields(built).values()))

    cpu = {}

    def med(fn, n=frames, phase=None):
        fn()
        ctx.finish()  # warm-up: kernel builds, tables, env SH
        ts, cs = [], []
        for _ in range(n):
            t0, c0 = time.perf_counter(), time.process_time()
            fn()
            ctx.finish()
            ts.append(1000.0 * (time.perf_counter() - t0))
            cs.append(1000.0 * (time.process_time() - c0))
        if phase:
            cpu[phase] = statistics.median(cs)
        return statistics.median(ts)

    out = {}
    floor = Renderer(ctx, "floor")
    out["floor"] = med(lambda: floor.execute(built.scene, gb, img), 5)
    r = Renderer(ctx, "heightfield", **params)
    out["frame"] = med(lambda: r.execute(built.scene, gb, img), phase="frame")
    r4 = Renderer(ctx, "heightfield", **{**params, "bands": 4})
    out["frame_bands4"] = med(lambda: r4.execute(built.scene, gb, img), phase="frame_bands4")
    r0 = Renderer(ctx, "heightfield", **{**params, "sun_threshold": 0})
    out["no_sun"] = med(lambda: r0.execute(built.scene, gb, img), phase="no_sun")
    r16 = Renderer(ctx, "heightfield", **{**params, "azimuths": 16})
    out["azimuths16"] = med(lambda: r16.execute(built.scene, gb, img), phase="azimuths16")
    out["horizons"] = med(lambda: r.read_output(built.scene, "env_horizons", instance), phase="horizons")
    h0 = field_heights = np.asarray(built.desc.heightfields[0].load().heights, np.float32)
    h1 = (field_heights * np.float32(0.999)).astype(np.float32)
    read = lambda: r.read_output(built.scene, "normals", instance)  # noqa: E731
    read_ms = med(read)
    ts = []
    for k in range(frames + 1):
        t0 = time.perf_counter()
        field.set_heights(h1 if k % 2 == 0 else h0)
        read()
        ctx.finish()
        if k:
            ts.append(1000.0 * (time.perf_counter() - t0))
    out["pyramid"] = max(statistics.median(ts) - read_ms, 0.0)
    out["load"] = os.getloadavg()[0]
    out["cpu"] = cpu  # CPU time of the process (every PoCL thread): what the work costs, less moved by load
    return out


def run_worker(side: str, root: Path | None, scene: str, frames: int, params: dict) -> dict:
    env = dict(os.environ)
    if root is not None:
        env["PYTHONPATH"] = str(root / "src" / "python")
        env["PENUMBRA_LIBRARY"] = str(root / "build" / "libpenumbra.so")
    else:  # this tree as installed in the interpreter (make install)
        env.pop("PENUMBRA_LIBRARY", None)
    cmd = [sys.executable, __file__, "--worker", scene, "--frames", str(frames), "--params", json.dumps(params)]
    res = subprocess.run(cmd, env=env, capture_output=True, text=True, cwd=REPO)
    if res.returncode:
        raise SystemExit(f"{side} worker failed on {scene}:\n{res.stderr[-3000:]}")
    return json.loads(res.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--worker", help=argparse.SUPPRESS)
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--frames", type=int, default=3)
    ap.add_argument("--baseline", default="9b774a1")
    ap.add_argument("--cache", default=str(REPO / "build" / "bench-baseline"))
    ap.add_argument("--scenes", nargs="*", default=DEFAULT_SCENES)
    ap.add_argument("--params", default="{}", help="heightfield renderer parameters, JSON")
    ap.add_argument("--out", default=str(REPO / "bench" / "results" / "heightfield_speed"))
    args = ap.parse_args()
    params = json.loads(args.params)
    if args.worker:
        print(json.dumps(worker(args.worker, args.frames, params)))
        return
    root = baseline_build(args.baseline, Path(args.cache))
    head = subprocess.run(["git", "-C", str(REPO), "rev-parse", "--short", "HEAD"], capture_output=True,
                          text=True).stdout.strip()
    dirty = bool(subprocess.run(["git", "-C", str(REPO), "status", "--porcelain", "--untracked-files=no"],
                                capture_output=True, text=True).stdout.strip())
    results = {"baseline": args.baseline, "head": head + ("+changes" if dirty else ""), "params": params,
               "rounds": args.rounds, "frames": args.frames, "load_start": os.getloadavg()[0], "scenes": {}}
    for scene in args.scenes:
        runs = {"A": [], "B": []}
        for k in range(args.rounds):
            for side in (("A", "B") if k % 2 == 0 else ("B", "A")):  # alternate which goes first
                runs[side].append(run_worker(side, root if side == "A" else None, scene, args.frames, params))
                print(f"{Path(scene).stem} round {k} {side}: " +
                      ", ".join(f"{p} {runs[side][-1][p]:.1f}" for p in PHASES), flush=True)
        med = {s: {p: statistics.median(r[p] for r in runs[s]) for p in PHASES} for s in runs}
        loads = [r["load"] for s in runs for r in runs[s]]
        cpu = {s: {p: statistics.median(r["cpu"][p] for r in runs[s]) for p in CPU_PHASES} for s in runs}
        results["scenes"][Path(scene).stem] = {"A": med["A"], "B": med["B"], "runs": runs,
                                               "ratio": {p: med["A"][p] / max(med["B"][p], 1e-9) for p in PHASES},
                                               "cpu": cpu,
                                               "cpu_ratio": {p: cpu["A"][p] / max(cpu["B"][p], 1e-9)
                                                             for p in CPU_PHASES},
                                               "load": [min(loads), max(loads)]}
    results["load_end"] = os.getloadavg()[0]
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "results.json").write_text(json.dumps(results, indent=1))
    (out / "report.md").write_text(report(results))
    print(report(results))


def report(res: dict) -> str:
    L = ["# Height fields: A/B speed against a pinned commit", "",
         f"Generated by `bench/heightfield_speed.py`: A = {res['baseline']} (built in a cache folder), "
         f"B = {res['head']}; renderer parameters {res['params'] or 'the defaults'}; {res['rounds']} alternating "
         f"rounds of subprocesses, medians of {res['frames']} frames after a warm-up per round, medians over "
         f"rounds. Load average {res['load_start']:.1f} at the start, {res['load_end']:.1f} at the end "
         "(2 cores, shared).", ""]
    L.append("| scene | phase | A ms | B ms | A / B | A CPU ms | B CPU ms | A / B (CPU) |")
    L.append("|---|---|---|---|---|---|---|---|")
    for name, s in res["scenes"].items():
        for p in PHASES:
            c = (f"{s['cpu']['A'][p]:.1f} | {s['cpu']['B'][p]:.1f} | {s['cpu_ratio'][p]:.2f}" if p in CPU_PHASES
                 else "– | – | –")
            L.append(f"| {name} | {p} | {s['A'][p]:.2f} | {s['B'][p]:.2f} | {s['ratio'][p]:.2f} | {c} |")
    L += ["", "The trade `azimuths = 16` (B) against A's default frame (not the same settings: up to 4 % more error "
          "on the bench terrains, 20–23 % on small sharp fields, docs/heightfield.md, Speed):", ""]
    for name, s in res["scenes"].items():
        L.append(f"- {name}: {s['A']['frame'] / max(s['B']['azimuths16'], 1e-9):.2f}× wall, "
                 f"{s['cpu']['A']['frame'] / max(s['cpu']['B']['azimuths16'], 1e-9):.2f}× CPU")
    L += ["", "frame = every per-vertex pass + shading (each side's defaults); frame_bands4 = the same with 4 SH "
          "bands on both sides (A's default, so the same settings); no_sun = frame with sun_threshold 0; "
          "azimuths16 = frame with 16 azimuths on both sides; horizons = the env "
          "horizons alone (hf_probe, read-back included); pyramid = new heights to normals; floor = the floor "
          "kernel. CPU ms = the process's CPU time over every PoCL thread (the work's cost; on a loaded machine "
          "wall time also counts the waits for a core).", ""]
    return "\n".join(L)


if __name__ == "__main__":
    main()
