#!/usr/bin/env python3
"""Accuracy and speed experiments of the `isg` method (docs/isg.md) after the
seed (../shared/seeds/001_7bc654ac36d25b83.txt: Fig. 12, Table 1, Fig. 11).

Scenes are built here in code from scene-file tables (penumbra.scenefile):
the Stanford bunny (Oded Stein's 3k version) on a floor under the Pisa light
probe, a camera at 112 x 84 (quick 64 x 48; the 2 shared cores of this machine set the size). Ground truth: `reference` at
face_size 64 (the seed's 6 x 64 x 64 rays per pixel), sun_supersampling 4.
Errors are relative RMS (docs/metrics.md: RMSE / RMS of the reference) over
the surface pixels (G-buffer instance != background). Experiment b has its
own truth: a diffuse and a specular part on their own grids (fig12_truth_parts).

  a  sphere sets of the bunny by N: outside / missed volume shares, build time
  b  the seed's Fig. 12: bunny and floor Phong (glossiness 1000), k_s = 0.5 on
     both, then k_s = 0.01 on the bunny (seed: 3.2 % and 4.6 %)
  c  error by K (lobes), N (spheres) and M (patch grid) on Fig. 12 (k_s = 0.5)
     and on the diffuse bunny; self-occlusion policy 0 / 1 / 2 on the bunny
  d  diffuse against `fiv` on the same scene (error and shading time)
  e  36 occluders (a 6 x 6 grid of spheres and boxes) on a floor, diffuse
  f  speed: 400 x 400 and 640 x 480 with 50 and 300 spheres, against the
     floor kernel in the same run (ratios; floor: median of 5 frames, isg: 1 frame
     after warm-up, as an isg frame takes about a minute on the shared cores)

Run from the repository root:

  PENUMBRA_LIBRARY=build/libpenumbra.so PYTHONPATH=python \\
      python bench/isg_experiments.py [--quick] [--only a,b] [--out bench/results/isg]
"""

from __future__ import annotations

import copy
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import harness  # noqa: E402
from harness import Experiment, Runner, Suite, f4, generated_by, log  # noqa: E402

from penumbra.imageio import write_png  # noqa: E402
from penumbra.render import build_scene, render  # noqa: E402
from penumbra.scenefile import parse_scene  # noqa: E402

DATA = harness.REPO.parent / "shared" / "data"
BUNNY = str(DATA / "meshes" / "bunny_odedstein_3k.obj")
PISA = str(DATA / "envmaps" / "pisa_probulator_256x128.hdr")
SEED_FIG12 = {"ks=0.5": 0.032, "ks=0.01": 0.046}


def bunny_scene(res, ks_bunny=0.0, ks_floor=0.0, shininess=1000.0) -> dict:
    albedo = lambda ks: [round(0.8 * (1.0 - ks), 4)] * 3  # noqa: E731  albedo + k_s <= 1
    return {"environment": {"map": PISA, "face_size": 64, "irradiance_face_size": 32},
            "camera": {"position": [0.0, 0.6, 3.2], "look_at": [0.0, -0.15, 0.0], "fov_deg": 40,
                       "resolution": list(res)},
            "object": [{"name": "bunny", "mesh": BUNNY, "albedo": albedo(ks_bunny), "specular": ks_bunny,
                        "shininess": shininess, "lobe": "phong"},
                       {"name": "floor", "primitive": "plane", "params": {"size": [8.0, 8.0]},
                        "translate": [0.0, -0.769, 0.0], "albedo": albedo(ks_floor), "specular": ks_floor,
                        "shininess": shininess, "lobe": "phong", "occluder": False}]}


def many_scene(res, count_side=6) -> dict:
    objs = [{"name": "floor", "primitive": "plane", "params": {"size": [12.0, 12.0]}, "albedo": [0.6] * 3,
             "occluder": False}]
    for i in range(count_side):
        for j in range(count_side):
            kind = "sphere" if (i + j) % 2 == 0 else "box"
            x, z = -2.5 + i, -2.5 + j
            o = {"name": f"o{i}{j}", "primitive": kind, "translate": [x, 0.45, z], "albedo": [0.7, 0.6, 0.5],
                 "occluder": True}
            o["params"] = {"radius": 0.35} if kind == "sphere" else {"size": [0.6, 0.9, 0.6]}
            objs.append(o)
    return {"environment": {"map": PISA, "face_size": 64, "irradiance_face_size": 32},
            "camera": {"position": [0.0, 5.5, 6.5], "look_at": [0.0, 0.0, 0.0], "fov_deg": 50,
                       "resolution": list(res)},
            "object": objs}


class IsgRunner(Runner):
    cache_env = "isg-experiments"  # references under $PENUMBRA_CACHE/isg-experiments when that is set

    def __init__(self, args):
        super().__init__(args)
        ints = lambda v: [int(x) for x in v.split(",")]  # noqa: E731
        self.faces_d = ints(args.faces_d or ("16,32" if args.quick else "32,64"))
        self.faces_s = ints(args.faces_s or ("32,64" if args.quick else "128,256"))
        self.unshadowed = not args.no_unshadowed

    def res(self, full=(112, 84)):
        return (64, 48) if self.quick else full

    def build(self, table: dict):
        return build_scene(parse_scene(copy.deepcopy(table), "."), self.ctx)

    def reference(self, table: dict, built) -> tuple[np.ndarray, np.ndarray]:
        face = 16 if self.quick else 64
        key = ("isg", table, face, harness.kernel_hash(lambda n: n.startswith(("reference", "raycast", "common"))))
        ref, _ = self.references.get(key, lambda: render(built, "reference", frames=1, warmup=False, face_size=face,
                                                         sun_supersampling=4).image[..., :3])
        return ref, None

    def evaluate(self, table: dict, variants: list[tuple[str, str, dict]], stem: str) -> list[dict]:
        """(label, method, params) rows: rel RMS over surface pixels against the reference."""
        built = self.build(table)
        ref, _ = self.reference(table, built)
        rows, images = [], {}
        for label, method, params in variants:
            t0 = time.perf_counter()
            r = render(built, method, frames=1, warmup=False, **params)
            mask = r.gbuffer["instance"] != 0xFFFFFFFF
            m = harness.metrics(ref, r.image[..., :3], mask, ("rel_rms", "nrmse", "max_abs", "bias"))
            rows.append({"label": label, "method": method, "params": params, **m,
                         "first_frame_s": time.perf_counter() - t0})
            images[label] = r.image[..., :3]
            log(f"  {stem} {label}: rel RMS {m['rel_rms']:.4f}")
        self.pictures.set(stem, ref, images, mask)
        return rows


def exp_a(run: IsgRunner) -> dict:
    from penumbra.core import Mesh
    from penumbra.meshio import load_mesh
    from penumbra.methods.isg import SphereSet

    d = load_mesh(BUNNY)
    rows = []
    for n in (8, 16, 32, 53, 64, 128, 256, 512):
        mesh = Mesh(run.ctx, d.vertices, d.faces)  # a fresh mesh each time; the library's cache still hits
        s = SphereSet.build(mesh, n)
        i = s.info()
        rows.append({"spheres": n, "outside_share": i["outside_share"], "missed_share": i["missed_share"],
                     "grid": i["grid"], "build_s": i["build_seconds"]})
    return {"rows": rows}


REF_CPU = {}  # reference part -> process CPU seconds of its render (kept in the cache's .json)


def fig12_truth_parts(run: IsgRunner, res, visibility: int = 1, coarse_only: bool = False) -> dict:
    """The Fig. 12 ground truth as two material-linear parts, each with its own
    direction grid (docs/isg.md section 9, "The seed's Fig. 12"):

      D  diffuse only (albedo 0.8, k_s 0) at cube faces run.faces_d (coarse, fine)
      S  specular only (albedo 0, k_s 0.5 Phong 1000) at faces run.faces_s

    The reference is linear in the material (f = albedo / pi + k_s f_lobe, one sum
    over directions), so any (albedo, k_s) per object is albedo / 0.8 D + k_s / 0.5 S
    per pixel. The diffuse part needs only the env's resolution; the glossiness-1000
    lobe (width 1 / sqrt(1000) = 0.032 rad) needs texels well below that (face 256:
    0.006-0.012 rad). sun_supersampling 1: Pisa is a broad map (the reference picks
    face 32 unsplit for it); with 4, 92 % of its texels count as bright and are split,
    16x the directions."""
    parts = {}
    for part, faces in (("D", run.faces_d), ("S", run.faces_s)):
        faces = faces[:1] if coarse_only else faces
        table = bunny_scene(res)
        for o in table["object"]:
            if part == "S":
                o["albedo"], o["specular"] = [0.0] * 3, 0.5
        built = run.build(table)
        for face in faces:
            key = ("isg-fig12-part", table, face, visibility,
                   harness.kernel_hash(lambda n: n.startswith(("reference", "raycast", "common"))))

            def draw(built=built, face=face):
                c0 = time.process_time()
                img = render(built, "reference", frames=1, warmup=False, face_size=face, sun_supersampling=1,
                             visibility=visibility).image[..., :3]
                REF_CPU[f"{part}{face}v{visibility}"] = time.process_time() - c0
                return img

            img, wall = run.references.get(key, draw)
            meta = run.references.path(key).with_suffix(".json")  # the render's CPU s kept beside the cached image
            rec = json.loads(meta.read_text()) if meta.exists() else {}
            tag = f"{part}{face}v{visibility}"
            if tag in REF_CPU and "cpu_s" not in rec:
                meta.write_text(json.dumps({**rec, "cpu_s": REF_CPU[tag]}))
            REF_CPU.setdefault(tag, rec.get("cpu_s", float("nan")))
            parts[(part, face)] = img
            log(f"  reference {part} face {face} visibility {visibility}: {wall:.0f} s wall"
                f" (load {os.getloadavg()[0]:.1f})")
    return parts


def fig12_combine(built, gbuffer, d: np.ndarray, s: np.ndarray, ks_bunny: float, ks_floor: float) -> dict:
    """Per-pixel truth of the scene (ks_bunny, ks_floor) from the parts: total, diffuse, specular."""
    inst = gbuffer["instance"]
    alb = np.zeros(inst.shape)
    ks = np.zeros(inst.shape)
    for name, k in (("bunny", ks_bunny), ("floor", ks_floor)):
        sel = inst == built.instance_ids[name]
        alb[sel], ks[sel] = 0.8 * (1.0 - k), k
    dd = d * (alb / 0.8)[..., None]
    ss = s * (ks / 0.5)[..., None]
    return {"total": dd + ss, "diffuse": dd, "specular": ss}


def fig12_table(res, ks_bunny: float, part: str = "total", occluder: bool = True, env_face: int = 64,
                exact: bool = True) -> dict:
    t = bunny_scene(res, ks_bunny=ks_bunny, ks_floor=0.5)
    t["environment"]["face_size"] = env_face
    if not exact:
        t["isg"] = {"exact_primitives": False}
    for o in t["object"]:
        if part == "diffuse":
            o["specular"] = 0.0
        elif part == "specular":
            o["albedo"] = [0.0] * 3
        if o["name"] == "bunny":
            o["occluder"] = occluder
    return t


# (label, isg params, scene options) for the k_s = 0.5 scene; the first is the defaults; k_s = 0.01 takes those
# named in FIG12_BOTH
FIG12_VARIANTS = [
    ("defaults (K 32, N 64, M 16)", {}, {}),
    ("N=53 (the seed's)", {"spheres": 53}, {}),
    ("N=128", {"spheres": 128}, {}),
    ("N=256", {"spheres": 256}, {}),
    ("N=512", {"spheres": 512}, {}),
    ("self_push 0, inside_other 0 (the rule before)", {"self_push": 0, "inside_other": 0}, {}),
    ("N=512, self_push 0, inside_other 0", {"spheres": 512, "self_push": 0, "inside_other": 0}, {}),
    ("exact_primitives off (light from below the floor)", {}, {"exact": False}),
    ("K=64", {"lobes": 64}, {}),
    ("K=128", {"lobes": 128}, {}),
    ("M=24", {"patch_grid": 24}, {}),
    ("specular_mode 0 (env at each patch, no Gamma_L)", {"specular_mode": 0}, {}),
    ("env cube face 128 (Gamma_L source)", {}, {"env_face": 128}),
]
FIG12_BOTH = {label for label, _, _ in FIG12_VARIANTS[:8]}


def exp_b(run: IsgRunner) -> dict:
    res = run.res()
    parts = fig12_truth_parts(run, res)
    fd, fs = run.faces_d[-1], run.faces_s[-1]
    strips = []
    out = {"res": list(res), "faces_d": run.faces_d, "faces_s": run.faces_s, "scenes": {}, "convergence": {}}
    for label, ks_bunny in (("ks=0.5", 0.5), ("ks=0.01", 0.01)):
        built = run.build(fig12_table(res, ks_bunny))
        c0 = time.process_time()
        base = render(built, "isg", frames=1, warmup=False)
        base_cpu = time.process_time() - c0
        gb = base.gbuffer
        mask = gb["instance"] != 0xFFFFFFFF
        truth = fig12_combine(built, gb, parts[("D", fd)], parts[("S", fs)], ks_bunny, 0.5)
        coarse = fig12_combine(built, gb, parts[("D", run.faces_d[0])], parts[("S", run.faces_s[0])], ks_bunny, 0.5)
        rms_t = float(np.sqrt(np.mean(truth["total"][mask] ** 2)))
        # The ground truth's own convergence: coarse grid against fine, per part, relative to the total's RMS.
        out["convergence"][label] = {
            p: float(np.sqrt(np.mean((coarse[p][mask] - truth[p][mask]) ** 2)) / rms_t) for p in truth}
        log(f"  {label}: truth coarse vs fine {out['convergence'][label]}")
        rows, images = [], {}
        variants = FIG12_VARIANTS if label == "ks=0.5" else [v for v in FIG12_VARIANTS if v[0] in FIG12_BOTH]
        for vlabel, params, opts in variants:
            b = built if not opts else run.build(fig12_table(res, ks_bunny, **opts))
            c0 = time.process_time()
            r = base if (not params and not opts) else render(b, "isg", frames=1, warmup=False, **params)
            cpu = time.process_time() - c0 if r is not base else base_cpu
            m = harness.metrics(truth["total"], r.image[..., :3], mask, ("rel_rms", "nrmse", "max_abs", "bias"))
            rows.append({"label": vlabel, "params": params, **opts, **m, "cpu_s": cpu})
            images[vlabel] = r.image[..., :3]
            log(f"  fig12 {label} {vlabel}: rel RMS {m['rel_rms']:.4f}")
        # Error breakdown at the defaults: each term against its part of the truth, shadowed and unshadowed.
        brk = {}
        for part in ("diffuse", "specular"):
            bp = run.build(fig12_table(res, ks_bunny, part))
            brk[part + "_share"] = float(np.sqrt(np.mean(truth[part][mask] ** 2)) / rms_t)
            for tag, params in (("", {}), (" N=256", {"spheres": 256})):
                img = render(bp, "isg", frames=1, warmup=False, **params).image[..., :3]
                brk[part + tag] = float(np.sqrt(np.mean((img[mask] - truth[part][mask]) ** 2)) / rms_t)
                if not tag:
                    images[f"isg {part} only"] = img
        rows_u = None
        if run.unshadowed:
            # unshadowed: the coarse grids (their shadowed twins' convergence is above)
            upar = fig12_truth_parts(run, res, visibility=0, coarse_only=True)
            utruth = fig12_combine(built, gb, upar[("D", run.faces_d[0])], upar[("S", run.faces_s[0])], ks_bunny, 0.5)
            ctruth = coarse
            for part in ("diffuse", "specular"):
                # no occluder at all, as the truth's visibility 0: not the floor's exact shell either
                bp = run.build(fig12_table(res, ks_bunny, part, occluder=False, exact=False))
                img = render(bp, "isg", frames=1, warmup=False, specular_shadows=0).image[..., :3]
                brk[part + "_unshadowed"] = float(np.sqrt(np.mean((img[mask] - utruth[part][mask]) ** 2)) / rms_t)
            rows_u = {"shadow_darkening": float(np.sqrt(np.mean((utruth["total"][mask] - ctruth["total"][mask]) ** 2))
                                                / rms_t)}
        log(f"  fig12 {label} breakdown: {brk}")
        unsh = render(built, "unshadowed", frames=1, warmup=False).image[..., :3]
        rows.append({"label": "unshadowed (no specular, no shadows)", "params": {},
                     **harness.metrics(truth["total"], unsh, mask, ("rel_rms", "nrmse", "max_abs", "bias")),
                     "cpu_s": float("nan")})
        parts_sum = images["isg diffuse only"] + images["isg specular only"]
        self_check = float(np.abs(parts_sum - base.image[..., :3])[mask].max())
        out["scenes"][label] = {"rows": rows, "breakdown": brk, "unshadowed_truth": rows_u,
                                "isg_parts_sum_max_abs": self_check}
        # The seed's layout: truth | isg defaults | isg N = 256 | 4 x |N = 256 - truth|, one row per k_s.
        shown = np.where(mask[..., None], truth["total"], images["defaults (K 32, N 64, M 16)"])
        best = images["N=256"]
        strips.append((np.concatenate([shown, images["defaults (K 32, N 64, M 16)"], best,
                                       4.0 * np.abs(best - truth["total"]) * mask[..., None]], axis=1),
                       harness.exposure(truth["total"], mask)))
        run.pictures.set(f"fig12_{label}", truth["total"], {k: images[k] for k in
                                                            ("defaults (K 32, N 64, M 16)",) if k in images}, mask)
    exp = strips[0][1]
    write_png(run.out / "fig12_strip.png", np.concatenate([st for st, _ in strips], axis=0), exp)
    out["reference_cpu_s"] = dict(REF_CPU)
    return out


def exp_c(run: IsgRunner) -> dict:
    res = run.res()
    spec = bunny_scene(res, ks_bunny=0.5, ks_floor=0.5)
    diffuse = bunny_scene(res)
    sweeps = []
    for k in (4, 8, 16, 32, 64):
        sweeps.append((f"K={k}", "isg", {"lobes": k}))
    for n in (16, 53, 128):
        sweeps.append((f"N={n}", "isg", {"spheres": n}))
    for m in (8, 12, 16, 24):
        sweeps.append((f"M={m}", "isg", {"patch_grid": m}))
    policies = [(f"self_occlusion={p}", "isg", {"self_occlusion": p}) for p in (0, 1, 2)]
    return {"specular": run.evaluate(spec, sweeps, "knobs_specular"),
            "diffuse": run.evaluate(diffuse, sweeps[:5] + policies, "knobs_diffuse")}


def exp_d(run: IsgRunner) -> dict:
    res = run.res()
    table = bunny_scene(res)
    rows = run.evaluate(table, [("isg", "isg", {}), ("fiv", "fiv", {}), ("fiv 64x33x30", "fiv", {"samples": [64, 33, 30]}),
                                ("unshadowed", "unshadowed", {})], "diffuse_vs_fiv")
    built = run.build(table)
    for r in rows:
        rr = render(built, r["method"], frames=1, **r["params"])
        r["shade_ms"] = rr.timings_ms["shade_median"]
    return {"rows": rows}


def exp_e(run: IsgRunner) -> dict:
    res = run.res()
    return {"rows": run.evaluate(many_scene(res), [("isg N=8", "isg", {"spheres": 8}),
                                                   ("unshadowed", "unshadowed", {})], "occluders36")}


def exp_f(run: IsgRunner) -> dict:
    rows = []
    sizes = ((100, 100), (160, 120)) if run.quick else ((400, 400), (640, 480))
    for res in sizes:
        for spheres in (50, 300):
            built = run.build(bunny_scene(res, ks_bunny=0.5, ks_floor=0.5))
            floor = render(built, "floor", frames=5).timings_ms["shade_median"]
            isg = render(built, "isg", frames=1, spheres=spheres).timings_ms["shade_median"]  # 1: ~1 min a frame here
            rows.append({"resolution": list(res), "spheres": spheres, "isg_ms": isg, "floor_ms": floor,
                         "ratio_to_floor": isg / floor})
            log(f"  {res} {spheres} spheres: isg {isg:.1f} ms, floor {floor:.3f} ms")
    return {"rows": rows}


def _table(rows: list[dict], cols: list[tuple[str, str]]) -> list[str]:
    out = ["| " + " | ".join(c[1] for c in cols) + " |", "|" + "---|" * len(cols)]
    for r in rows:
        out.append("| " + " | ".join(f4(r[c[0]]) if isinstance(r[c[0]], float) else str(r[c[0]]) for c in cols) + " |")
    return out


def report(results: dict) -> str:
    meta = results["meta"]
    lines = ["# isg experiments", "", generated_by(meta, "bench/isg_experiments.py", "2 shared cores") + ".", ""]
    ex = results["experiments"]
    err_cols = [("label", "setting"), ("rel_rms", "rel RMS"), ("nrmse", "NRMSE"), ("bias", "bias")]
    if "a" in ex:
        lines += ["## a. Sphere sets of the bunny by N", ""] + _table(
            ex["a"]["rows"], [("spheres", "N"), ("outside_share", "outside / solid"), ("missed_share", "missed / solid"),
                              ("grid", "grid"), ("build_s", "build s")]) + [""]
    if "b" in ex:
        b = ex["b"]
        lines += ["## b. Fig. 12 (Phong 1000; seed: 3.2 % and 4.6 %)", "",
                  f"{b['res'][0]} x {b['res'][1]} pixels; truth: diffuse part at cube faces {b['faces_d']}, "
                  f"specular part at {b['faces_s']} (the last of each is the truth); reference CPU s: "
                  f"{ {k: round(v) if v == v else None for k, v in b.get('reference_cpu_s', {}).items()} }", ""]
        for k, sc in b["scenes"].items():
            lines += [f"{k} (seed {100 * SEED_FIG12[k]:.1f} %):", ""] + _table(
                sc["rows"], err_cols + [("cpu_s", "CPU s")]) + [""]
            lines += [f"truth coarse against fine (share of the truth's RMS): {b['convergence'][k]}", "",
                      f"breakdown at the defaults (RMS error of each term / RMS of the truth): {sc['breakdown']}", "",
                      f"unshadowed truth: {sc['unshadowed_truth']}; isg diffuse + specular parts against the full "
                      f"image, max abs: {sc['isg_parts_sum_max_abs']:.3g}", ""]
    if "c" in ex:
        lines += ["## c. Error by K, N, M (defaults otherwise) and self-occlusion", ""]
        for k in ("specular", "diffuse"):
            lines += [f"{k}:", ""] + _table(ex["c"][k], err_cols) + [""]
    if "d" in ex:
        lines += ["## d. Diffuse: isg against fiv", ""] + _table(ex["d"]["rows"], err_cols + [("shade_ms", "shade ms")]) + [""]
    if "e" in ex:
        lines += ["## e. 36 occluders", ""] + _table(ex["e"]["rows"], err_cols) + [""]
    if "f" in ex:
        lines += ["## f. Speed against the floor kernel (same run)", ""] + _table(
            [{**r, "res": "x".join(map(str, r["resolution"]))} for r in ex["f"]["rows"]],
            [("res", "resolution"), ("spheres", "N"), ("isg_ms", "isg ms"), ("floor_ms", "floor ms"),
             ("ratio_to_floor", "x floor")]) + [""]
    return "\n".join(lines) + "\n"


def add_arguments(ap) -> None:
    ap.add_argument("--faces-d", default="", help="b: cube faces of the diffuse truth part, coarse,fine "
                    "(default 32,64; quick 16,32)")
    ap.add_argument("--faces-s", default="", help="b: cube faces of the specular truth part, coarse,fine "
                    "(default 128,256; quick 32,64)")
    ap.add_argument("--no-unshadowed", action="store_true", help="b: skip the unshadowed truth and its breakdown")


SUITE = Suite(
    script="bench/isg_experiments.py", description=__doc__,
    experiments=(Experiment("a", "sphere sets by N", exp_a), Experiment("b", "Fig. 12", exp_b),
                 Experiment("c", "error by knob", exp_c), Experiment("d", "diffuse vs fiv", exp_d),
                 Experiment("e", "36 occluders", exp_e), Experiment("f", "speed", exp_f)),
    runner=IsgRunner, report=report, default_out="bench/results/isg", add_arguments=add_arguments,
    meta=lambda run: {"quick": run.quick})

if __name__ == "__main__":
    sys.exit(harness.main(SUITE))
