"""The `reference` method's automatic direction grid against converged
Mitsuba 3 on every env map of the shared data (docs/reference.md, "Choosing
the directions").

For each map in <data>/envmaps: the standard bunny scene (bench/scenes/
bunny_sunny.toml: the bunny on a ground plane) lit by that map at 32x24
pixels (as tests/test_crossval.py), rendered by

* Mitsuba 3 at the pixel centres, 1024 samples per pixel x 8 emitter samples
  (penumbra.mitsuba.render; its own noise is measured on one map with a second
  seed),
* `reference` with its old fixed defaults (face 32, no sun supersampling),
* `reference` with its defaults (face_size = sun_supersampling = 0: picked
  from the env map),

and the NRMSE of each against Mitsuba over the pixels that see geometry,
with the render times. The bunny is faceted (crease_angle_deg = 0) here: with
interpolated normals a few silhouette pixels differ between the two
renderers by convention (penumbra's G-buffer falls back to the geometric
normal where the interpolated one faces away from the camera, Mitsuba shades
them black), which is not what this measures.

Run: python bench/reference_auto.py [--out bench/results/reference_auto] [--maps a.hdr b.exr]
Data: $PENUMBRA_DATA, else ../shared/data beside the checkout. Takes about a
minute per map on two busy CPU cores (Mitsuba's llvm variant most of it).
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import numpy as np

from penumbra import mitsuba
from penumbra.core import Context
from penumbra.fileutil import atomic_write_text
from penumbra.methods.reference import directions
from penumbra.metrics import compare
from penumbra.render import build_scene, render
from penumbra.scenefile import load_scene

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "bench" / "scenes" / "bunny_sunny.toml"
RESOLUTION = "[32,24]"  # the cross-validation tests' size; Mitsuba at 1024 spp takes ~15 s per map
SPP, EMITTER_SAMPLES = 1024, 8
OLD_DEFAULTS = {"face_size": 32, "sun_supersampling": 1}
BAR = 0.01  # the agreement the defaults must reach


def data_dir() -> Path:
    return Path(os.environ.get("PENUMBRA_DATA", ROOT.parent / "shared" / "data"))


def one_map(ctx, path: Path, noise_seed: bool) -> dict:
    data = data_dir()
    desc = load_scene(SCENE, [f"camera.resolution={RESOLUTION}", f"environment.map={path}",
                              f"object.bunny.mesh={data / 'meshes' / 'bunny_odedstein_3k.obj'}",
                              "object.bunny.crease_angle_deg=0"])
    built = build_scene(desc, ctx)
    t = time.perf_counter()
    mi = mitsuba.render(desc, SPP, emitter_samples=EMITTER_SAMPLES, seed=3)
    row = {"map": path.name, "mitsuba_s": time.perf_counter() - t}
    if noise_seed:
        mi2 = mitsuba.render(desc, SPP, emitter_samples=EMITTER_SAMPLES, seed=4)
    for label, params in (("old", OLD_DEFAULTS), ("auto", {})):
        t = time.perf_counter()
        res = render(built, "reference", frames=1, warmup=False, background=0, **params)
        row[f"{label}_s"] = time.perf_counter() - t
        fg = res.gbuffer["instance"] != 0xFFFFFFFF
        row[f"{label}_nrmse"] = compare(mi, res.image[..., :3], fg)["nrmse"]
        if label == "auto":
            row.update(built.assets["reference"])
    if noise_seed:
        row["mitsuba_seed_nrmse"] = compare(mi, mi2, fg)["nrmse"]
    return row


def report(rows: list[dict]) -> str:
    lines = ["# `reference` defaults against converged Mitsuba 3", "",
             f"bench/reference_auto.py: bunny on a plane, {RESOLUTION} pixels, Mitsuba {SPP} spp x "
             f"{EMITTER_SAMPLES} emitter samples at the pixel centres; NRMSE over the pixels that see geometry, "
             "normalised by Mitsuba's range. Times on the shared 2-core CPU (noisy: compare within a row).", "",
             "| env map | picked face | picked sun ss | directions | NRMSE picked | NRMSE old (32, 1) | "
             "picked s | old s | Mitsuba s |", "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['map']} | {r['face_size']} | {r['sun_supersampling']} | {r['directions']} | "
                     f"{r['auto_nrmse']:.4f} | {r['old_nrmse']:.4f} | {r['auto_s']:.1f} | {r['old_s']:.1f} | "
                     f"{r['mitsuba_s']:.1f} |")
    worst = max(rows, key=lambda r: r["auto_nrmse"])
    old_worst = max(rows, key=lambda r: r["old_nrmse"])
    lines += ["", f"Worst with the picks: {worst['auto_nrmse']:.4f} ({worst['map']}); with the old defaults "
              f"{old_worst['old_nrmse']:.4f} ({old_worst['map']}). Bar: {BAR}. "
              f"{sum(r['auto_nrmse'] <= BAR for r in rows)} of {len(rows)} maps within it."]
    noise = [r for r in rows if "mitsuba_seed_nrmse" in r]
    for r in noise:
        lines.append(f"Mitsuba's own noise ({r['map']}): NRMSE {r['mitsuba_seed_nrmse']:.4f} between two seeds "
                     "(so about 0.7x that between one render and the converged image).")
    return "\n".join(lines) + "\n"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default=str(ROOT / "bench" / "results" / "reference_auto"))
    ap.add_argument("--maps", nargs="*", help="file names in <data>/envmaps (default: all)")
    args = ap.parse_args()
    maps_dir = data_dir() / "envmaps"
    names = args.maps or sorted(p.name for p in maps_dir.iterdir() if p.suffix in (".hdr", ".exr"))
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    ctx = Context()
    rows = []
    for i, name in enumerate(names):
        rows.append(one_map(ctx, maps_dir / name, noise_seed=name.startswith("studio_small_03")))
        r = rows[-1]
        print(f"[{i + 1}/{len(names)}] {name}: picked ({r['face_size']}, {r['sun_supersampling']}) "
              f"NRMSE {r['auto_nrmse']:.4f} (old {r['old_nrmse']:.4f}); {r['auto_s']:.1f} s / {r['old_s']:.1f} s, "
              f"Mitsuba {r['mitsuba_s']:.1f} s", flush=True)
        atomic_write_text(out / "results.json", json.dumps(rows, indent=1) + "\n")
        atomic_write_text(out / "report.md", report(rows))
    return 0 if all(r["auto_nrmse"] <= BAR for r in rows) else 1


if __name__ == "__main__":
    raise SystemExit(main())
