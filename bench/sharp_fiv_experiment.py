#!/usr/bin/env python3
"""The sharp-light path on FIV's hard-sun bunny (issue 14, "The sharp part of
any environment"; docs/depthmap.md): the sunny map split by
pn_envmap_extract_sharp into a few sharp domains and a residual map; the
residual lit by `fiv` (a field baked under the residual), the sharp domains
by `depthmap` (caller domains, depth-map shadows); the two images added.
Against plain `fiv` on the whole map (partial = 0, the variant of FIV's bars
0.038 / 0.021 / 0.013) and `depthmap` on the whole map, over the plane's
pixels, at the grids of bench/fiv_experiments.py experiment a.

The scene, camera, reference settings and field bakes are those of
bench/fiv_experiments.py (its Built, Runner.reference, Runner.field).

  PENUMBRA_LIBRARY=build/libpenumbra.so PYTHONPATH=python \\
      python bench/sharp_fiv_experiment.py [--quick] [--big] [--out bench/results/sharp_fiv]

Writes OUT/results.json and OUT/report.md (--report-only rewrites it), small
PNGs; bakes and the reference are cached in OUT/cache (never committed).
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import fiv_experiments as fx  # noqa: E402
import harness  # noqa: E402
from harness import Experiment, Suite, f4, log  # noqa: E402

from penumbra.core import GBuffer, Image, Renderer  # noqa: E402
from penumbra.methods import depthmap as dmethod  # noqa: E402
from penumbra.methods.fiv import attach_by_mesh  # noqa: E402

SCRIPT = "bench/sharp_fiv_experiment.py"
PAPER = {"32x17x15": 0.023, "64x33x30": 0.008, "256x129x30": 0.007}
SHARP = {"max_count": 4, "threshold": 100.0, "seed": 1}
# depth-map sides for the sharp domains: the maps are fitted to every instance's box, here the plane's
# 40 x the shadow region (fiv_experiments.ground), so the bunny covers few texels at the default 256
SHARP_RESOLUTIONS = (256, 1024, 4096)


def render(built: fx.Built, method: str, domains=None, **params) -> np.ndarray:
    ctx = built.ctx
    w, h = built.camera.resolution
    gb, img = GBuffer(ctx, w, h), Image(ctx, w, h)
    renderer = Renderer(ctx, method, background=0, **params)
    if domains is not None:
        dmethod.set_domains(renderer, domains)
    built.scene.render_gbuffer(gb)
    renderer.execute(built.scene, gb, img)
    ctx.finish()
    return img.read()[..., :3]


def records(dom) -> np.ndarray:
    return dmethod.domain_array(dom.directions, dom.radiance, cap_radius=dom.cap_radius, solid_angle=dom.solid_angle)


def run_sharp(r: fx.Runner) -> dict:
    grids = [(32, 17, 15)] if r.quick else [(32, 17, 15), (64, 33, 30)] + ([(256, 129, 30)] if r.args.big else [])
    data = fx.plane_scene([fx.standing(fx.BUNNY, "bunny")], "sunny", r.res)
    full = fx.Built(r.ctx, data, "sunny")
    sharp, residual = full.envmap.extract_sharp(**SHARP)
    fx._ENV_CACHE["sunny residual"] = residual  # fx.env_latlong serves it to Built by name
    rest = fx.Built(r.ctx, data, "sunny residual")
    ref, ref_s = r.reference(full)
    gb = GBuffer(r.ctx, *full.camera.resolution)
    full.scene.render_gbuffer(gb)
    mask = gb.read("instance") == full.instance_ids["ground"]
    total_power = float(np.sum(sharp.radiance)) if len(sharp) else 0.0
    out = {"sharp_options": SHARP, "sharp_domains": len(sharp), "reference_seconds": ref_s,
           "pixels": int(mask.sum()),
           "sharp_solid_angle_sr": [float(x) for x in sharp.solid_angle],
           "sharp_cap_radius_deg": [float(np.degrees(x)) for x in sharp.cap_radius],
           "sharp_power_rgb_sum": total_power, "rows": {}}
    exp = harness.exposure(ref, mask)
    heat = harness.heat_scale(ref, mask)
    r.pictures.image("reference.png", ref, exp)

    def score(label, img):
        m = harness.metrics(ref, img, mask, ("nrmse", "bias"))
        png, err = r.pictures.result("sharp", label, ref, img, mask, exp, heat)
        log(f"  {label}: NRMSE {m['nrmse']:.4f}")
        return {**m, "png": png, "error_png": err}

    sharp_imgs = {}
    for res in SHARP_RESOLUTIONS:
        t0 = time.perf_counter()
        sharp_imgs[res] = (render(full, "depthmap", records(sharp), resolution=res) if len(sharp)
                           else np.zeros_like(ref))
        out[f"sharp_render_seconds_{res}"] = time.perf_counter() - t0
    out["rows"]["depthmap (whole map, defaults)"] = {"grid": "-", **score("depthmap whole map", render(full, "depthmap"))}
    for g in grids:
        name = fx.grid_name(g)
        f_full, rec_full = r.field(full, "bunny", g)
        attach_by_mesh(full.scene, [f_full])
        full.scene.commit()
        plain = render(full, "fiv", partial=0)
        attach_by_mesh(full.scene, [])
        full.scene.commit()
        f_rest, rec_rest = r.field(rest, "bunny", g)
        attach_by_mesh(rest.scene, [f_rest])
        rest.scene.commit()
        residual_img = render(rest, "fiv", partial=0)
        out["rows"][f"fiv {name}"] = {"grid": name, "bake_seconds": rec_full.get("bake_seconds"),
                                      **score(f"fiv {name}", plain)}
        for res, sharp_img in sharp_imgs.items():
            out["rows"][f"fiv residual + depthmap sharp (maps {res}^2) {name}"] = {
                "grid": name, "bake_seconds": rec_rest.get("bake_seconds"),
                **score(f"split {res} {name}", residual_img + sharp_img)}
    return out


EXPERIMENTS = (Experiment("sharp", "sharp part by depth maps, residual by FIV, on the hard-sun bunny", run_sharp),)


def report(results: dict) -> str:
    meta, ex = results["meta"], results["experiments"]
    L = ["# The sharp-light path on FIV's hard-sun bunny", "",
         harness.generated_by(meta, SCRIPT, "shared with other work") + ".", ""]
    if "sharp" in ex:
        e = ex["sharp"]
        L += [f"Scene, camera ({meta['resolution']}^2), reference and bakes of bench/fiv_experiments.py experiment a "
              f"(bunny on a plane under immenstadter_horn_1k; NRMSE over the plane's {e['pixels']} pixels). Sharp "
              f"part: pn_envmap_extract_sharp {e['sharp_options']} gave {e['sharp_domains']} domains (solid angles "
              f"{', '.join(f'{x:.2e}' for x in e['sharp_solid_angle_sr'])} sr, cap radii "
              f"{', '.join(f'{x:.2f}' for x in e['sharp_cap_radius_deg'])} deg), rendered by `depthmap` with those "
              f"domains (default bias and PCF 1; depth-map side as labelled); the residual by `fiv` partial = 0 with a field baked under "
              f"the residual.", "",
              "| variant | samples | paper NRMSE | NRMSE | bias (mean error / range) | bake s | images |",
              "|---|---|---|---|---|---|---|"]
        for label, v in e["rows"].items():
            bake = v.get("bake_seconds")
            L.append(f"| {label} | {v['grid']} | {PAPER.get(v['grid'], '-')} | {f4(v['nrmse'])} | "
                     f"{v['bias']:+.4f} | {'-' if bake is None else f'{bake:.0f}'} | [img]({v['png']}), "
                     f"[error]({v['error_png']}) |")
        L += ["", "Reference: [reference.png](reference.png)."]
    return "\n".join(L) + "\n"


def meta(r) -> dict:
    return {"quick": r.quick, "resolution": r.res, "reference": r.ref_params}


class Runner(fx.Runner):
    cache_env = "sharp-fiv"


def add_arguments(ap) -> None:
    ap.add_argument("--resolution", type=int, default=0, help="image side (default 256, quick 96)")
    ap.add_argument("--big", action="store_true", help="also the 256x129x30 grid (bakes of minutes)")
    ap.set_defaults(no_oracle=True)


SUITE = Suite(script=SCRIPT, description=__doc__, experiments=EXPERIMENTS, runner=Runner, report=report,
              default_out="bench/results/sharp_fiv", meta=meta, add_arguments=add_arguments,
              quick_help="smoke run: 96^2 image, 32x17x15 only, quick reference")

if __name__ == "__main__":
    sys.exit(harness.main(SUITE))
