"""The anisotropic Ashikhmin-Shirley lobe in `isg` against `reference` on
examples/scenes/brushed_teapot.toml (docs/isg.md 6): NRMSE and relative RMS
over the surface pixels, the images as PNGs, and the shading time of isg
with the 7-SG lobe against the same scene with a one-SG Blinn-Phong lobe of
the geometric-mean exponent (and that scene's error, for scale), frames
interleaved in one process.

    PYOPENCL_CTX=0 .venv/bin/python bench/aniso_scene.py [--size 96x72] [--out DIR]
"""

from __future__ import annotations

import argparse
import math
import os
import subprocess
from pathlib import Path

import numpy as np

from penumbra.core import Context
from penumbra.imageio import auto_exposure, write_png
from penumbra.metrics import compare
from penumbra.render import build_scene, render
from penumbra.scenefile import load_scene

SCENE = Path(__file__).resolve().parents[1] / "examples" / "scenes" / "brushed_teapot.toml"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", default="96x72")
    ap.add_argument("--out", default="docs/images")
    ap.add_argument("--frames", type=int, default=3)
    args = ap.parse_args()
    w, h = (int(x) for x in args.size.split("x"))
    over = [f"camera.resolution=[{w},{h}]"]
    ctx = Context()
    aniso = build_scene(load_scene(SCENE, over), ctx)
    n_iso = math.sqrt(8.0 * 120.0)
    iso = build_scene(load_scene(SCENE, over + ["object.teapot.lobe=blinn_phong",
                                                f"object.teapot.shininess={n_iso:.3f}"]), ctx)
    print("load:", subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip())
    ref = render(aniso, "reference", frames=1, warmup=False, background=0, face_size=64)
    fg = ref.gbuffer["instance"] != 0xFFFFFFFF
    teapot = ref.gbuffer["instance"] == aniso.instance_ids["teapot"]
    out = {}
    for name, built in (("isg_aniso", aniso), ("isg_blinn_phong", iso)):
        out[name] = render(built, "isg", frames=1, warmup=False, background=0)
    err = compare(ref.image[..., :3], out["isg_aniso"].image[..., :3], fg)
    err_pot = compare(ref.image[..., :3], out["isg_aniso"].image[..., :3], teapot)
    print(f"isg (7-SG lobe) vs reference face 64, {w}x{h}: all surface pixels {err}")
    print(f"  teapot pixels only: {err_pot}")
    # For scale: the one-SG Blinn-Phong teapot against its own reference.
    ref_iso = render(iso, "reference", frames=1, warmup=False, background=0, face_size=64)
    print(f"isg (Blinn-Phong n = {n_iso:.1f}, one SG) vs its reference: all surface pixels "
          f"{compare(ref_iso.image[..., :3], out['isg_blinn_phong'].image[..., :3], fg)}")
    print(f"  teapot pixels only: {compare(ref_iso.image[..., :3], out['isg_blinn_phong'].image[..., :3], teapot)}")
    # Time: frames alternating between the two materials in one process.
    times = {"isg_aniso": [], "isg_blinn_phong": []}
    for _ in range(args.frames):
        for name, built in (("isg_aniso", aniso), ("isg_blinn_phong", iso)):
            # Two frames, the faster kept: the first one also fits the env lobes (the plan).
            r = render(built, "isg", frames=2, warmup=False, background=0)
            times[name].append(r.timings_ms["shade_min"])
    med = {k: float(np.median(v)) for k, v in times.items()}
    print(f"isg shading ms (median of {args.frames}, interleaved): {med}; "
          f"ratio 7-SG / 1-SG = {med['isg_aniso'] / med['isg_blinn_phong']:.2f}")
    print("load:", subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip())
    dest = Path(args.out)
    os.makedirs(dest, exist_ok=True)
    # One strip: reference | isg | 4 x |isg - reference|, one exposure.
    exposure = auto_exposure(ref.image[..., :3])
    diff = 4.0 * np.abs(out["isg_aniso"].image[..., :3] - ref.image[..., :3])
    gap = np.zeros((h, 2, 3))
    strip = np.concatenate([ref.image[..., :3], gap, out["isg_aniso"].image[..., :3], gap, diff], axis=1)
    write_png(dest / "aniso_teapot_strip.png", strip, exposure)


if __name__ == "__main__":
    main()
