"""Renders the images of the documentation's gallery (docs/sphinx/gallery/):
examples/scenes/shapes_sky.toml with every method that applies, at 240x180,
and writes gallery/gallery.md, which docs/sphinx/gallery.md includes.

    PYTHONPATH=python PENUMBRA_LIBRARY=build/libpenumbra.so python docs/sphinx/make_gallery.py

Procedural content only (no test data); fiv's bakes go to a temporary cache.
Every shaded image uses one exposure (the reference's automatic one), so the
methods compare by brightness too."""

from __future__ import annotations

import os
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
try:
    import penumbra  # noqa: F401
except ImportError:  # a checkout without `pip install .` (PENUMBRA_LIBRARY set)
    sys.path.insert(0, str(ROOT / "python"))

import numpy as np  # noqa: E402

from penumbra import Context, methods  # noqa: E402
from penumbra.fileutil import atomic_write_text  # noqa: E402
from penumbra.imageio import auto_exposure, write_png  # noqa: E402
from penumbra.render import build_scene, render  # noqa: E402
from penumbra.scenefile import load_scene  # noqa: E402

SCENE = ROOT / "examples" / "scenes" / "shapes_sky.toml"
OUT = Path(__file__).resolve().parent / "gallery"
SIZE = "camera.resolution=[240,180]"
REFERENCE = {"face_size": 16}   # the ground truth at a coarse direction grid keeps this quick


def main() -> int:
    os.environ.setdefault("PENUMBRA_CACHE", tempfile.mkdtemp(prefix="penumbra-gallery-"))
    desc = load_scene(SCENE, [SIZE])
    built = build_scene(desc, Context())
    runs = [("reference", REFERENCE)] + [(m, {}) for m in methods.applicable(desc) if m != "reference"]
    results = {m: render(built, m, frames=1, warmup=False, **p) for m, p in runs}
    exposure = auto_exposure(results["reference"].image)
    rel = SCENE.relative_to(ROOT).as_posix()
    lines = [f"All at exposure {exposure:+.2f} stops. Frame times: one untimed frame on the machine that made "
             "them (CPU, PoCL), G-buffer included.", ""]
    for method, params in runs:
        res = results[method]
        write_png(OUT / f"{method}.png", np.ascontiguousarray(res.image[..., :3]), exposure=exposure)
        sets = " ".join(f"--set render.{k}={v}" for k, v in params.items())
        lines += [f"## {method}", "", methods.spec(method).summary + ".", "",
                  f"![{method}]({method}.png)", "", "```sh",
                  f"penumbra render {rel} --method {method} {sets} --set {SIZE} --png {method}.png".replace("  ", " "),
                  "```", "", f"One frame: {res.timings_ms['frame_median']:.0f} ms"
                  + (f"; preparation (bakes) {res.prepare_s:.1f} s." if res.prepare_s > 0.05 else "."), ""]
    normals = results["unshadowed"].view("normals")
    write_png(OUT / "gbuffer_normals.png", normals)
    lines += ["## The G-buffer", "", "Normals (0.5 + 0.5 n) of the same view, as `penumbra demo` writes them.", "",
              "![normals](gbuffer_normals.png)", ""]
    atomic_write_text(OUT / "gallery.md", "\n".join(lines))
    print(f"wrote {len(runs) + 1} images and gallery.md into {OUT}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
