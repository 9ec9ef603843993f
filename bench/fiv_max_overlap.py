"""fiv's disc correction against the number of occluders it pairs (`max_overlap`).

The correction (overlap = 1, docs/fiv.md) subtracts, for every pair of the
`max_overlap` occluders with the largest irradiance at a pixel, the lens of
their unit bounding discs as a share of their irradiance. This script
measures, against the reference renderer, the error of every `max_overlap`,
of the rule before (the first `max_overlap` occluders in the scene's order,
a build option), of the plain sum (overlap 0) and of multiplied
visibilities (overlap 2) on scenes where 2 to 60
bunnies shadow the same pixels, under a hard sun, a studio and a low dawn sun:
the scaling benchmark's clustered scenes (10, 30, 60 bunnies), its spread
scene, tight groups of 2-16 bunnies of our own, and blobs of 3-40 spheres
(occluders that fill their bounding discs, unlike the bunnies).

    python bench/fiv_max_overlap.py [--out bench/results/fiv_max_overlap] [--res 128]

Writes results.json and report.md (NRMSE over the whole image, the
background black, and fiv's shading time, median of 3 frames). The
reference images are kept in --reference-cache, so a rerun renders fiv only.
"""
from __future__ import annotations

import argparse
import hashlib
import json
import time
from pathlib import Path

import numpy as np

from penumbra import data
from penumbra.core import Context
from penumbra.fileutil import atomic_write_text
from penumbra.methods.fiv import fiv_scaling_scene, fiv_spread_scene
from penumbra.metrics import nrmse
from penumbra.render import build_scene, render
from penumbra.scenefile import parse_scene

ENVS = {"sunny": "immenstadter_horn_1k_polyhaven.hdr", "studio": "studio_small_03_1k_polyhaven.hdr",
        "dawn": "kiara_1_dawn_1k_polyhaven.hdr"}
CAPS = (2, 3, 4, 6, 8, 16, 32)


def group_scene(k: int, mesh: str, envmap: str, res: int, cache: str, seed: int) -> dict:
    """k bunnies (scales 0.7-1.0; fiv's fields hold the env's light, so no
    rotation) within a disc
    of radius 0.35 k^0.5 around the origin, seen from above at ~45 degrees:
    every bunny's shadow overlaps some other's."""
    rng = np.random.default_rng(seed)
    objects = [{"name": "ground", "primitive": "plane", "params": {"size": [12.0, 12.0]}, "albedo": 0.6}]
    for i in range(k):
        r, a = 0.35 * np.sqrt(k) * np.sqrt(rng.uniform()), rng.uniform(0, 2 * np.pi)
        s = round(float(rng.uniform(0.7, 1.0)), 3)
        objects.append({"name": f"bunny{i}", "mesh": mesh, "scale": s,
                        "translate": [round(r * np.cos(a), 3), round(0.769 * s, 4), round(r * np.sin(a), 3)], "albedo": [0.8, 0.78, 0.72]})
    return {"environment": {"map": envmap, "face_size": 128, "irradiance_face_size": 32},
            "camera": {"position": [0.0, 3.2 + 0.4 * k ** 0.5, 3.6 + 0.4 * k ** 0.5], "look_at": [0.0, 0.3, 0.0],
                       "fov_deg": 55, "resolution": [res, res]},
            "render": {"method": "fiv"}, "fiv": {"samples": [128, 65, 30], "cache": cache}, "object": objects}


def sphere_scene(k: int, envmap: str, res: int, cache: str, seed: int) -> dict:
    """k spheres of radius 0.25 in a blob of radius ~0.45 k^(1/3) above the
    ground: occluders that fill their bounding discs (the lens of two discs is
    the overlap of their silhouettes), unlike the bunnies."""
    rng = np.random.default_rng(seed)
    objects = [{"name": "ground", "primitive": "plane", "params": {"size": [12.0, 12.0]}, "albedo": 0.6}]
    s = k ** (1 / 3)
    for i in range(k):
        c = rng.normal(size=3) * [0.35 * s, 0.2 * s, 0.35 * s] + [0.0, 0.6 + 0.25 * s, 0.0]
        objects.append({"name": f"sphere{i}", "primitive": "sphere", "params": {"radius": 0.25}, "occluder": True,
                        "translate": [round(float(x), 3) for x in c], "albedo": [0.8, 0.78, 0.72]})
    return {"environment": {"map": envmap, "face_size": 128, "irradiance_face_size": 32},
            "camera": {"position": [0.0, 3.2 + 0.4 * s, 3.6 + 0.4 * s], "look_at": [0.0, 0.3, 0.0],
                       "fov_deg": 55, "resolution": [res, res]},
            "render": {"method": "fiv"}, "fiv": {"samples": [128, 65, 30], "cache": cache}, "object": objects}


def scenes(res: int, cache: str) -> dict[str, dict]:
    if not data.available():
        raise SystemExit(data.missing_reason())
    mesh = str(data.path("meshes/bunny_odedstein_3k.obj"))
    out = {}
    for env, name in ENVS.items():
        envmap = str(data.path(f"envmaps/{name}"))
        for k in (2, 3, 4, 6, 8, 12, 16):
            out[f"group{k}_{env}"] = group_scene(k, mesh, envmap, res, cache, seed=100 + k)
        for n in (10, 30, 60):
            out[f"clustered{n}_{env}"] = fiv_scaling_scene(n, mesh, envmap, res, cache=cache)
        out[f"spread60_{env}"] = fiv_spread_scene(60, mesh, envmap, res, cache=cache)
        for k in (3, 8, 20, 40):
            out[f"spheres{k}_{env}"] = sphere_scene(k, envmap, res, cache, seed=200 + k)
    return out


def reference(built, scene: dict, cache: Path) -> np.ndarray:
    """The reference image (face_size 64, sun_supersampling 4), kept in `cache` under a hash of
    the scene's description, so that a rerun renders only the fiv variants."""
    key = hashlib.sha256(json.dumps(scene, sort_keys=True).encode()).hexdigest()[:16]
    path = cache / f"{key}.npy"
    if path.is_file():
        return np.load(path)
    ref = render(built, "reference", frames=1, warmup=False, background=0, face_size=64,
                 sun_supersampling=4).image[..., :3]
    cache.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp.npy")
    np.save(tmp, ref)
    tmp.replace(path)
    return ref


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="bench/results/fiv_max_overlap")
    ap.add_argument("--res", type=int, default=128)
    ap.add_argument("--cache", default="bench/results/fiv_scaling/cache/fiv",
                    help="the fields' bake cache (shared with the scaling benchmark; one bake per env map)")
    ap.add_argument("--reference-cache", default="bench/results/fiv_max_overlap/cache",
                    help="where the reference images are kept between runs")
    ap.add_argument("--only", default="", help="comma-separated scene names (default: all)")
    ap.add_argument("--report-only", action="store_true", help="rewrite report.md from results.json")
    args = ap.parse_args()
    out = Path(args.out)
    if args.report_only:
        atomic_write_text(out / "report.md", report(json.loads((out / "results.json").read_text())))
        return
    cache = str(Path(args.cache).resolve())
    ctx = Context()
    ctx_order = Context("build_options=-DPN_FIV_PAIR_BY_ORDER=1")
    rows = []
    only = set(filter(None, args.only.split(",")))
    for name, scene in scenes(args.res, cache).items():
        if only and name not in only:
            continue
        built = build_scene(parse_scene(scene), ctx)
        t0 = time.perf_counter()
        ref = reference(built, scene, Path(args.reference_cache))
        row = {"scene": name, "reference_s": round(time.perf_counter() - t0, 1), "variants": {}}
        # The rule before, the first max_overlap occluders in the scene's order: a build of its own.
        built_order = build_scene(parse_scene(scene), ctx_order)
        variants = [("sum", built, {"overlap": 0}), ("multiply", built, {"overlap": 2})]
        variants += [(f"disc{c}", built, {"overlap": 1, "max_overlap": c}) for c in CAPS]
        variants += [(f"order{c}", built_order, {"overlap": 1, "max_overlap": c}) for c in CAPS]
        for label, where, params in variants:
            r = render(where, "fiv", frames=3, background=0, **params)
            row["variants"][label] = {"nrmse": float(nrmse(ref, r.image[..., :3])),
                                      "shade_ms": float(r.timings_ms["shade_median"])}
        rows.append(row)
        print(name, " ".join(f"{k} {v['nrmse']:.5f}" for k, v in row["variants"].items()), flush=True)
    if only and (out / "results.json").is_file():   # a partial run: replace its rows in the last full run's
        done = {r["scene"]: r for r in json.loads((out / "results.json").read_text())["rows"]}
        done.update({r["scene"]: r for r in rows})
        rows = list(done.values())
    result = {"resolution": args.res, "caps": list(CAPS), "device": ctx.device_name, "rows": rows,
              "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())}
    atomic_write_text(out / "results.json", json.dumps(result, indent=1))
    atomic_write_text(out / "report.md", report(result))
    print(f"wrote {out}/results.json, report.md")


def report(result: dict) -> str:
    labels = ["sum", "multiply"] + [f"disc{c}" for c in result["caps"]]
    head = ["scene"] + ["overlap 0", "overlap 2"] + [f"overlap 1, max_overlap {c}" for c in result["caps"]]
    if all(f"order{c}" in row["variants"] for row in result["rows"] for c in result["caps"]):
        labels += [f"order{c}" for c in result["caps"]]
        head += [f"first {c} in order" for c in result["caps"]]
    lines = ["# fiv: the disc correction against the occluders it pairs", "",
             f"NRMSE against the reference renderer (face_size 64, sun_supersampling 4), whole image at "
             f"{result['resolution']}², background black; {result['device']}, {result['date']}. "
             "`bench/fiv_max_overlap.py` (its docstring says what the scenes are). The lowest error of a row in bold. "
             "max_overlap k pairs the k occluders with the largest irradiance at a pixel; \"first k in order\" is the "
             "rule before (the first k in the scene's order, build option PN_FIV_PAIR_BY_ORDER=1).", "",
             "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    ratios = {k: [] for k in labels}
    for row in result["rows"]:
        v = row["variants"]
        best = min(v[k]["nrmse"] for k in labels)
        cells = [f"**{v[k]['nrmse']:.4f}**" if v[k]["nrmse"] == best else f"{v[k]['nrmse']:.4f}" for k in labels]
        lines.append(f"| {row['scene']} | " + " | ".join(cells) + " |")
        for k in labels:
            ratios[k].append((row["scene"], v[k]["nrmse"] / best))
    lines += ["", "Error against the row's lowest: geometric mean over the scenes (the worst scene's):", "",
              "| scenes | " + " | ".join(head[1:]) + " |", "|---|" + "---|" * (len(head) - 1)]
    for what, keep in (("all", lambda n: True), ("bunnies", lambda n: not n.startswith("spheres")),
                       ("spheres", lambda n: n.startswith("spheres"))):
        cells = []
        for k in labels:
            r = [x for n, x in ratios[k] if keep(n)]
            cells.append(f"{np.exp(np.mean(np.log(r))):.3f} ({max(r):.2f})" if r else "-")
        count = sum(keep(n) for n, _ in ratios[labels[0]])
        lines.append(f"| {what} ({count}) | " + " | ".join(cells) + " |")
    lines.append("")
    lines += ["Shading ms (median of 3 frames, including the occluder loop):", "",
              "| scene | " + " | ".join(head[1:]) + " |", "|---|" + "---|" * (len(head) - 1)]
    for row in result["rows"]:
        lines.append(f"| {row['scene']} | " + " | ".join(f"{row['variants'][k]['shade_ms']:.2f}" for k in labels) + " |")
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    main()
