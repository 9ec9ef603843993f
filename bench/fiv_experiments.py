#!/usr/bin/env python3
"""Accuracy and bake-cost experiments of the `fiv` method after Section 5 of
Michael and Chrysanthou, "Fullsphere Irradiance Factorization ..."
(../shared/seeds/000_3e0b59c4aedb41ad.txt; Figures 12-18, Tables 1-2).

Every scene is built here in code (penumbra.scenefile.parse_scene on a dict,
env maps as arrays). For each experiment the occluders' fields are baked
(cached), and `fiv`, `reference` (face_size 64, sun_supersampling 4: the
ground truth of docs/reference.md) and `unshadowed` are rendered; the error is
the paper's NRMSE (penumbra.metrics.compare: RMSE / (max - min of the
reference) over the evaluated pixels, all three channels).

  a  bunny (35,947 vertices) on a plane, sunny map, grids 32x17x15, 64x33x30,
     128x65x30 (256x129x30 with --big), a float32 and an inner_radius 0.9
     variant; NRMSE over the plane's pixels
  b  env maps: one directional light (1 degree disc; also 256x129x30 with
     --big), two area lights (green, red), outdoor HDR (sunny), and a softer
     outdoor map (forest); plane pixels
  c  two bunnies with overlapping shadows: overlap = 0, 1, 2 (x partial = 1, 0),
     plus a check that the kernel combines occluders as docs/fiv.md says
  d  chess queen sunk 1/5 of its height below the plane: partial = 0, 1
  e  self-shadowing on the bunny (no plane): self_shadow = 1, 0; bunny pixels
  f  bake time, rays and stored bytes against the paper's Table 1; the same
     bakes under the directional map (almost no rays) give the non-ray time
  g  the bake's ray throughput against Embree (embreex) on the same rays

a-e also evaluate "oracle" diagnostics (bench/fiv_oracle.py): fiv's formulas with the exact
occlusion at each pixel (Python ray casting over the bake's own directions)
instead of the grid, which splits the error into grid and formula parts.

Run from the repository root:

  PYTHONPATH=python PENUMBRA_LIBRARY=build/dev/libpenumbra.so \\
      python bench/fiv_experiments.py [--quick] [--only a,b] [--big] [--out bench/results/fiv]

The experiments are defined here (SUITE) and run on bench/harness.py, which
writes OUT/results.json (merged: --only updates its experiments), OUT/report.md
(from results.json; --report-only rewrites it) and small PNGs (fiv result,
reference, error heat map). --quick writes to OUT/quick/. Bakes and reference
images are cached in OUT/cache or $PENUMBRA_CACHE/fiv-experiments (never
committed: OUT/.gitignore), so a rerun only renders. A full run from an empty
cache takes about an hour on 2 cores (--big: the 256x129x30 bakes, ~20 min more).
Data files are read from the test data folder (penumbra.data: $PENUMBRA_DATA, default
../shared/data beside the checkout), never copied.
"""

from __future__ import annotations

import datetime as _dt
import json
import math
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import harness  # noqa: E402
from harness import (HEAT_FRACTION, REPO, Experiment, Suite, Variant, f4, kernel_hash, log,  # noqa: E402
                     median_ms, settings)

from penumbra import data as test_data, procedural  # noqa: E402
from penumbra.core import Camera, Context, EnvMap, GBuffer, Image, Material, Mesh, Renderer, Scene  # noqa: E402
from penumbra.fileutil import atomic_write_text  # noqa: E402
from penumbra.methods.fiv import FivField, FivOptions, attach_by_mesh, envmap_hash, mesh_hash  # noqa: E402
from penumbra.imageio import read_envmap  # noqa: E402
from penumbra.render import object_geometry  # noqa: E402
from penumbra.scenefile import parse_scene  # noqa: E402

from fiv_oracle import (OracleSetup, bake_directions, lens_area, overlap_oracle, pixels,  # noqa: E402
                        plane_oracle, self_oracle)

# The test data (penumbra.data: $PENUMBRA_DATA, default ../shared/data beside the checkout; never copied).
DATA = test_data.data_dir().as_posix()
BUNNY = f"{DATA}/meshes/bunny_stanford_full_ajacobson.obj"   # 35,947 vertices, 69,451 triangles
QUEEN = f"{DATA}/meshes/chess_queen_scenevr.obj"
SUNNY = f"{DATA}/envmaps/immenstadter_horn_1k_polyhaven.hdr"   # stands in for the paper's Eucalyptus Grove
FOREST = f"{DATA}/envmaps/forest_slope_1k_polyhaven.hdr"       # a softer outdoor map (trees, a hazy sun)
# Light probes of the paper's era (Debevec), for Fig. 12 under lighting without a sun: Uffizi
# is soft (its brightest 0.01 sr give 2 % of the irradiance of an upward plane), Grace
# Cathedral has small bright lamps (87 %; the sunny map's sun: 29 %).
PROBES = ("uffizi", "grace")
PROBE_SUPERSAMPLING = 32
UFFIZI = f"{DATA}/envmaps/uffizi_probulator_256x128.hdr"
GRACE = f"{DATA}/envmaps/grace_probulator_256x128.hdr"
ENV_FILES = {"sunny": SUNNY, "forest": FOREST, "uffizi": UFFIZI, "grace": GRACE}

PAPER_TABLE1 = {  # samples (phi x theta x rho) -> (minutes, MB), Bunny, 35,947 vertices
    "32x17x15": (3, 0.28), "64x33x15": (12, 1.08), "64x33x30": (24, 2.17), "128x65x30": (99, 8.56),
    "256x129x30": (397, 34.0),
}
ALBEDO = (0.8, 0.8, 0.8)
FOV = 40.0
MIB = float(1 << 20)
SCRIPT = "bench/fiv_experiments.py"
# fiv with its defaults (partial = 1) and with partial = 0: the variants of most experiments
PARTIAL = (Variant("fiv", {"partial": 1}), Variant("fiv partial=0", {"partial": 0}))
METRICS = ("nrmse", "rel_rms", "max_abs", "rmse", "mean_error")   # per variant in results.json


def grid_name(g: tuple[int, int, int]) -> str:
    return "x".join(str(v) for v in g)


def bake_hash() -> str:
    """The kernel sources a bake depends on: fiv_bake.cl and common/."""
    return kernel_hash(lambda rel: rel == "fiv_bake.cl" or rel.startswith("common/"))


def reference_hash() -> str:
    """The kernel sources a reference image depends on: everything but fiv*.cl."""
    return kernel_hash(lambda rel: not rel.rsplit("/", 1)[-1].startswith("fiv"))


# --------------------------------------------------------------------------- #
# Environment maps
# --------------------------------------------------------------------------- #

def unit(v) -> np.ndarray:
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v)


def direction(elevation_deg: float, azimuth_deg: float) -> np.ndarray:
    """Unit direction towards a light at elevation/azimuth (azimuth from +z towards +x)."""
    e, a = math.radians(elevation_deg), math.radians(azimuth_deg)
    return np.array([math.cos(e) * math.sin(a), math.sin(e), math.cos(e) * math.cos(a)])


DIRECTIONAL_DIR = direction(50.0, -40.0)   # the directional light: a disc of 1 degree (0.5 degree radius)
DIRECTIONAL_RADIUS_DEG = 0.5
DIRECTIONAL_IRRADIANCE = 4.0               # irradiance at normal incidence (RGB white)
# Two area lights, (theta range, phi range) in degrees and RGB radiance: green and red, as in the paper's Fig. 13/14.
AREA_LIGHTS = (((40.0, 60.0), (20.0, 50.0), (0.3, 6.0, 0.3)),     # green
               ((35.0, 55.0), (110.0, 140.0), (6.0, 0.3, 0.3)))   # red


def area_light_dirs() -> list[np.ndarray]:
    out = []
    for (t0, t1), (p0, p1), _ in AREA_LIGHTS:
        t, p = math.radians(0.5 * (t0 + t1)), math.radians(0.5 * (p0 + p1))
        out.append(np.array([math.sin(p) * math.sin(t), math.cos(t), -math.cos(p) * math.sin(t)]))
    return out


_ENV_CACHE: dict[str, np.ndarray] = {}


def env_latlong(name: str) -> np.ndarray:
    if name in _ENV_CACHE:
        return _ENV_CACHE[name]
    w, h = 1024, 512
    if name in ENV_FILES:
        env = read_envmap(REPO / ENV_FILES[name])
    elif name == "directional":
        r = math.radians(DIRECTIONAL_RADIUS_DEG)
        cov = procedural._disc_coverage(w, h, unit(DIRECTIONAL_DIR), r)
        radiance = DIRECTIONAL_IRRADIANCE / (2 * math.pi * (1 - math.cos(r)))
        env = np.repeat((cov * radiance)[..., None], 3, axis=2).astype(np.float32)
    elif name == "area":
        e = np.zeros((h, w, 3), np.float64)
        for theta, phi, rgb in AREA_LIGHTS:
            procedural._add_patch(e, tuple(np.radians(theta)), tuple(np.radians(phi)), rgb)
        env = e.astype(np.float32)
    else:
        raise ValueError(name)
    _ENV_CACHE[name] = env
    return env


def key_light_dirs(name: str) -> list[np.ndarray]:
    """Directions of the lights that cast the visible shadows (for framing the camera)."""
    if name in PROBES:
        # no dominant light: frame the contact shadow all around the occluder
        return [direction(45.0, a) for a in (0.0, 90.0, 180.0, 270.0)]
    if name in ("sunny", "forest"):
        env = env_latlong(name)
        lum = env @ np.array([0.2126, 0.7152, 0.0722])
        j, i = np.unravel_index(np.argmax(lum), lum.shape)
        return [procedural.latlong_directions(env.shape[1], env.shape[0])[j, i]]
    if name == "directional":
        return [unit(DIRECTIONAL_DIR)]
    return area_light_dirs()


# --------------------------------------------------------------------------- #
# Scenes
# --------------------------------------------------------------------------- #

_MESH_BOUNDS: dict[str, tuple[np.ndarray, np.ndarray]] = {}


def mesh_bounds(path: str) -> tuple[np.ndarray, np.ndarray]:
    if path not in _MESH_BOUNDS:
        from penumbra.meshio import load_mesh
        v = load_mesh(REPO / path).vertices
        _MESH_BOUNDS[path] = (v.min(axis=0), v.max(axis=0))
    return _MESH_BOUNDS[path]


def standing(path: str, name: str, at=(0.0, 0.0), sink: float = 0.0) -> dict:
    """An object dict: the mesh with its bounds' centre at `at` (x, z) and its
    lowest point `sink` x its height below y = 0."""
    lo, hi = mesh_bounds(path)
    c = 0.5 * (lo + hi)
    height = float(hi[1] - lo[1])
    return {"name": name, "mesh": path, "albedo": list(ALBEDO),
            "translate": [float(at[0] - c[0]), float(-lo[1] - sink * height), float(at[1] - c[2])]}


def shadow_region(objects: list[dict], lights: list[np.ndarray]) -> tuple[np.ndarray, float, np.ndarray]:
    """(centre xz, half extent, mean shadow direction xz) of the occluders and
    the shadows their tops cast on y = 0 from the key lights."""
    pts = []
    for o in objects:
        lo, hi = mesh_bounds(o["mesh"])
        t = np.asarray(o["translate"])
        lo, hi = lo + t, hi + t
        top = hi[1]
        for x in (lo[0], hi[0]):
            for z in (lo[2], hi[2]):
                pts.append((x, z))
                for L in lights:
                    L = unit(L)
                    pts.append((x - top * L[0] / L[1], z - top * L[2] / L[1]))
    pts = np.asarray(pts)
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    centre = 0.5 * (lo + hi)
    half = float(np.max(np.linalg.norm(pts - centre, axis=1)))   # any orientation of the frame fits
    sdir = -np.mean([unit(L)[[0, 2]] for L in lights], axis=0)
    sdir = sdir / np.linalg.norm(sdir) if np.linalg.norm(sdir) > 1e-6 else np.array([1.0, 0.0])
    return centre, half, sdir


def plane_camera(centre_xz, half: float, sdir, resolution: int, elevation_deg: float = 60.0,
                 margin: float = 1.05) -> dict:
    """Looks down at (centre, y = 0) from `elevation_deg`, from the side across
    the shadow direction, so that the occluder hides little of its shadow."""
    side = np.array([sdir[1], -sdir[0]])   # perpendicular to the shadow direction, in xz
    e = math.radians(elevation_deg)
    dist = margin * half / math.tan(math.radians(FOV / 2))
    look = np.array([centre_xz[0], 0.0, centre_xz[1]])
    pos = look + dist * np.array([math.cos(e) * side[0], math.sin(e), math.cos(e) * side[1]])
    return {"position": pos.tolist(), "look_at": look.tolist(), "fov_deg": FOV, "resolution": [resolution, resolution]}


def ground(size: float) -> dict:
    return {"name": "ground", "primitive": "plane", "params": {"size": [size, size]}, "albedo": list(ALBEDO)}


def plane_scene(objects: list[dict], env: str, resolution: int, elevation_deg: float = 60.0) -> dict:
    centre, half, sdir = shadow_region(objects, key_light_dirs(env))
    cam = plane_camera(centre, half, sdir, resolution, elevation_deg)
    return {"camera": cam, "object": objects + [ground(40.0 * half)]}


class Built:
    """A scene built from a dict and an env map given as an array."""

    def __init__(self, ctx: Context, data: dict, env_name: str):
        desc = parse_scene({"camera": data["camera"], "object": data["object"]}, REPO, "fiv_experiments")
        self.ctx, self.desc, self.env_name = ctx, desc, env_name
        # The light probes' lamps are single texels of a 256x128 map: the automatic resampling
        # (sub-texels a quarter of a lat-long texel) moves their power by 1-3 % (DifMap and the
        # reference in opposite directions); 32 x 32 sub-samples keep it to 0.1 %.
        self.envmap = EnvMap(ctx, env_latlong(env_name), face_size=64, irradiance_face_size=32,
                             supersampling=PROBE_SUPERSAMPLING if env_name in PROBES else 0)
        self.scene = Scene(ctx)
        self.scene.set_envmap(self.envmap)
        self.meshes: dict[str, Mesh] = {}     # object name -> mesh (instances of one file share it)
        self.instance_ids: dict[str, int] = {}
        by_file: dict[tuple, Mesh] = {}
        for obj in desc.objects:
            key = (obj.mesh, obj.primitive, repr(sorted(obj.params.items())))
            if key not in by_file:
                v, f, n = object_geometry(obj)
                by_file[key] = Mesh(ctx, v, f, n)
            self.meshes[obj.name] = by_file[key]
            self.instance_ids[obj.name] = self.scene.add(by_file[key], obj.transform(), Material(albedo=obj.albedo))
        c = desc.camera
        self.camera = Camera(position=c.position, look_at=c.look_at, up=c.up, fov_deg=c.fov_deg,
                             resolution=c.resolution)
        self.scene.set_camera(self.camera)
        self.scene.commit()
        self.data = data

    def key(self) -> str:
        return harness.key_of(json.dumps(self.data, sort_keys=True) + envmap_hash(self.envmap))


# --------------------------------------------------------------------------- #
# Bakes, references, renders
# --------------------------------------------------------------------------- #

class Runner(harness.Runner):
    cached = "bakes and reference images (large, machine-made)"
    cache_env = "fiv-experiments"

    def __init__(self, args):
        super().__init__(args)
        self.res = args.resolution or (96 if args.quick else 256)
        self.ref_params = ({"face_size": 32, "sun_supersampling": 2} if args.quick
                           else {"face_size": 64, "sun_supersampling": 4})
        self.main_grid = (32, 17, 15) if args.quick else (128, 65, 30)
        self.prefix = ""
        self._dirs: dict[str, tuple] = {}

    # ---- bakes
    def field(self, built: Built, obj_name: str, grid, precision: str = "float16", fresh: bool = False,
              **options) -> tuple:
        """(FivField, bake record). Cached under cache/; the record of the bake
        that produced the file (rays, seconds) is kept beside it."""
        mesh = built.meshes[obj_name]
        opts = FivOptions.from_paper(grid, precision=precision, **options)
        name = f"{mesh_hash(mesh)}-{envmap_hash(built.envmap)}-{opts.key()}-k{bake_hash()}"
        path = self.cache / f"{name}.pnfiv"
        side = self.cache / f"{name}.json"
        existed = path.exists()
        if fresh and existed:
            path.unlink()
            side.unlink(missing_ok=True)
            existed = False
        t0 = time.perf_counter()
        load0 = os.getloadavg()[0]
        last = [0.0]

        def progress(done, total):
            now = time.perf_counter()
            if now - last[0] > 30:
                last[0] = now
                log(f"  bake {built.env_name} {obj_name} {grid_name(grid)} {precision}: {100 * done / total:.0f} %")
            return False

        f = FivField.bake(built.envmap, mesh, opts, path, progress, quiet=True)   # its cache of bakes
        info = f.info()
        if info["rays"] > 0:  # baked (or resumed) now
            rec = {"grid": grid_name(grid), "precision": precision, "rays": info["rays"],
                   "bake_seconds": info["bake_seconds"], "resumed": existed, "sample_count": info["sample_count"],
                   "inside_count": info["inside_count"], "stored_bytes": info["stored_bytes"],
                   "loadavg_before": load0, "loadavg_after": os.getloadavg()[0],
                   "date": _dt.datetime.now().isoformat(timespec="seconds")}
            atomic_write_text(side, json.dumps(rec, indent=1))
            log(f"  baked {obj_name} {grid_name(grid)} {precision} under {built.env_name}: "
                f"{info['bake_seconds']:.1f} s, {info['rays'] / 1e6:.1f} M rays"
                f" ({info['rays'] / info['bake_seconds'] / 1e6:.2f} M rays/s)")
        else:
            rec = json.loads(side.read_text()) if side.exists() else {"grid": grid_name(grid), "precision": precision}
            rec.update(sample_count=info["sample_count"], stored_bytes=info["stored_bytes"],
                       inside_count=info["inside_count"])
            log(f"  cached field {obj_name} {grid_name(grid)} {precision} ({time.perf_counter() - t0:.1f} s)")
        return f, rec

    # ---- the bake's directions per env (for the oracles)
    def directions(self, env_name: str):
        if env_name not in self._dirs:
            self._dirs[env_name] = bake_directions(self.ctx, env_latlong(env_name))
        return self._dirs[env_name]

    # ---- references
    def reference(self, built: Built) -> tuple[np.ndarray, float]:
        key = f"{built.key()}-{json.dumps(self.ref_params, sort_keys=True)}-{reference_hash()}"

        def render():
            t0 = time.perf_counter()
            image, _, _ = shade(built, "reference", background=0, **self.ref_params)
            log(f"  reference {self.ref_params} in {time.perf_counter() - t0:.1f} s")
            return image[..., :3]
        return self.references.get(key, render, {"params": self.ref_params})

    # ---- one experiment scene: renders and metrics
    def evaluate(self, exp: str, built: Built, fields: list, variants: tuple[Variant, ...], mask_of: str,
                 extra_masks: dict[str, str] | None = None, oracle=None, scene_stem: str | None = None) -> dict:
        """Renders `fiv` for each variant, plus `unshadowed` and
        the reference; NRMSE etc. over the pixels of object `mask_of`.
        `oracle(gbuffer planes, mask, unshadowed irradiance)` may add
        (label, image) variants computed with the exact occlusion per pixel."""
        attach_by_mesh(built.scene, fields)
        built.scene.commit()
        ref, ref_s = self.reference(built)
        uns_img, gbuf, uns_ms = shade(built, "unshadowed", background=0, planes=True)
        inst = gbuf["instance"]
        masks = {mask_of: inst == built.instance_ids[mask_of]}
        for label, obj in (extra_masks or {}).items():
            masks[label] = inst == built.instance_ids[obj]
        mask = masks[mask_of]
        span = float(ref[mask].max() - ref[mask].min())
        exposure = harness.exposure(ref, inst != 0xFFFFFFFF)
        stem = f"{self.prefix}{exp}"
        sstem = f"{self.prefix}{scene_stem or exp}"   # the reference and unshadowed images, once per scene
        self.pictures.image(f"{sstem}_reference.png", ref, exposure)
        heat = HEAT_FRACTION * span
        out = {"pixels": int(mask.sum()), "evaluated": mask_of, "reference_seconds": ref_s,
               "reference_range": span, "heat_scale": heat, "exposure": exposure,
               "reference_png": f"{sstem}_reference.png", "variants": {}}
        runs = [("unshadowed", {}, uns_img, uns_ms)] + [(v.label, v.params, *self._fiv(built, v.params))
                                                        for v in variants]
        if oracle is not None and not self.args.no_oracle:
            t0 = time.perf_counter()
            alb = gbuf["albedo"][..., :3]
            e_dif = np.where(alb > 0, uns_img[..., :3] * math.pi / np.maximum(alb, 1e-30), 0.0)
            for lab, img in oracle(gbuf, mask, e_dif):
                full = np.zeros_like(uns_img)
                full[..., :3] = img
                runs.append((lab, {"oracle": True}, full, float("nan")))
            log(f"  oracle in {time.perf_counter() - t0:.1f} s")
        for label, params, img, ms in runs:
            v = {"params": params, **harness.metrics(ref, img[..., :3], mask, METRICS), "shade_ms": ms}
            for extra, em in masks.items():
                if extra != mask_of and em.any():
                    v[f"nrmse_{extra}"] = harness.metrics(ref, img[..., :3], em, ("nrmse",))["nrmse"]
            # diagnostics (oracle rows): the error map only
            v["png"], v["error_png"] = self.pictures.result(sstem if label == "unshadowed" else stem, label, ref,
                                                            img[..., :3], mask, exposure, heat,
                                                            error_only=bool(params.get("oracle")))
            out["variants"][label] = v
            log(f"  {exp} {label}: NRMSE {v['nrmse']:.4f} (rel RMS {v['rel_rms']:.4f}, "
                f"mean err {v['mean_error']:+.4g})")
        return out

    def _fiv(self, built, params):
        image, _, ms = shade(built, "fiv", frames=3, warmup=True, background=0, **params)
        return image, ms


def shade(b: Built, method: str, frames: int = 1, warmup: bool = False, planes: bool = False, **params):
    """(RGBA image, instance ids, median shading ms) of `method` on the scene's
    camera: the core API directly (kernel builds untimed, optional warm-up
    frame, median of `frames` shading passes on one G-buffer)."""
    ctx = b.ctx
    for stage in ("raycast", method):
        ctx.build(stage)
    w, h = b.camera.resolution
    gb, img = GBuffer(ctx, w, h), Image(ctx, w, h)
    renderer = Renderer(ctx, method, **params)
    b.scene.render_gbuffer(gb)
    ctx.finish()
    ms, _ = median_ms(lambda: renderer.execute(b.scene, gb, img), frames, ctx.finish, warmup=int(warmup))
    if planes:
        return img.read(), {p: gb.read(p) for p in ("position", "normal", "albedo", "instance")}, ms
    return img.read(), gb.read("instance"), ms


# --------------------------------------------------------------------------- #
# Experiments
# --------------------------------------------------------------------------- #

def exp_a(r: Runner) -> dict:
    grids = [(32, 17, 15)] if r.quick else [(32, 17, 15), (64, 33, 30), (128, 65, 30)]
    if r.args.big and not r.quick:
        grids.append((256, 129, 30))
    data = plane_scene([standing(BUNNY, "bunny")], "sunny", r.res)
    b = Built(r.ctx, data, "sunny")
    res = {"env": "sunny", "scene": data, "grids": {}}
    for g in grids:
        f, rec = r.field(b, "bunny", g)
        oracle = plane_oracle(OracleSetup(r, b, ["bunny"], f)) if g == grids[0] else None
        ev = r.evaluate(f"a_{grid_name(g)}", b, [f], PARTIAL, "ground",
                        {"bunny": "bunny"}, oracle, scene_stem="a")
        ev["bake"] = rec
        res["grids"][grid_name(g)] = ev
    # The paper does not name Fig. 12's map; its errors there (0.008 at 64x33x30) are below all of
    # Fig. 13's and 14's (Eucalyptus Grove 0.022, area lights 0.019-0.035, one light 0.1), so its
    # lighting was softer than those. The same bunny and plane under two light probes without a sun,
    # the camera centred on the bunny (its shadow lies all around it).
    res["soft"] = {}
    for env in ("uffizi", "grace"):
        bs = Built(r.ctx, plane_scene([standing(BUNNY, "bunny")], env, r.res), env)
        res["soft"][env] = {}
        for g in grids:
            f, rec = r.field(bs, "bunny", g)
            oracle = plane_oracle(OracleSetup(r, bs, ["bunny"], f)) if g == grids[0] else None
            ev = r.evaluate(f"a_{env}_{grid_name(g)}", bs, [f], PARTIAL,
                            "ground", {"bunny": "bunny"}, oracle, scene_stem=f"a_{env}")
            ev["bake"] = rec
            res["soft"][env][grid_name(g)] = ev
        if env == "grace" and not r.quick:
            # Diagnostic: the bake's directions as fine as the reference's (face 64), for the lamps.
            g = (64, 33, 30)
            f, rec = r.field(bs, "bunny", g, face_size=64)
            ev = r.evaluate(f"a_{env}_{grid_name(g)}_face64", bs, [f], PARTIAL[1:], "ground",
                            {"bunny": "bunny"}, scene_stem=f"a_{env}")
            ev.update(bake=rec, face_size=64)
            res["soft"][env][grid_name(g) + " face_size=64"] = ev
    # Diagnostic: the same grid with every sphere outside the bounding sphere (inner_radius 0.9
    # instead of 0.2), i.e. finer radial steps where the plane's receivers are.
    g = grids[-1] if r.quick else (128, 65, 30)
    f, rec = r.field(b, "bunny", g, inner_radius=0.9)
    ev = r.evaluate(f"a_{grid_name(g)}_inner09", b, [f], PARTIAL, "ground",
                    {"bunny": "bunny"}, scene_stem="a")
    ev["bake"] = rec
    ev["inner_radius"] = 0.9
    res["grids"][grid_name(g) + " inner_radius=0.9"] = ev
    # float32 storage at the smallest grid: is half precision costing accuracy?
    f, rec = r.field(b, "bunny", grids[0], precision="float32")
    ev = r.evaluate(f"a_{grid_name(grids[0])}_f32", b, [f], PARTIAL,
                    "ground", {"bunny": "bunny"}, scene_stem="a")
    ev["bake"] = rec
    res["grids"][grid_name(grids[0]) + " float32"] = ev
    return res


def exp_b(r: Runner) -> dict:
    res = {"grid": grid_name(r.main_grid), "envs": {}}
    for env in ("directional", "area", "sunny", "forest"):
        data = plane_scene([standing(BUNNY, "bunny")], env, r.res)
        b = Built(r.ctx, data, env)
        f, rec = r.field(b, "bunny", r.main_grid)
        ev = r.evaluate(f"b_{env}", b, [f], PARTIAL, "ground",
                        oracle=plane_oracle(OracleSetup(r, b, ["bunny"], f)))
        ev["bake"] = rec
        ev["scene"] = data
        res["envs"][env] = ev
        if env == "directional" and r.args.big and not r.quick:
            # the hard shadow at the paper's finest grid (a cheap bake: almost no rays)
            g = (256, 129, 30)
            f2, rec2 = r.field(b, "bunny", g)
            ev2 = r.evaluate(f"b_{env}_{grid_name(g)}", b, [f2], PARTIAL,
                             "ground", scene_stem=f"b_{env}")
            ev2.update(bake=rec2, scene=data, grid=grid_name(g))
            res["envs"][f"{env} {grid_name(g)}"] = ev2
    return res


def two_bunnies(env: str) -> list[dict]:
    L = unit(key_light_dirs(env)[0])
    s = -unit(np.array([L[0], L[2]]))            # shadow direction on the ground
    lo, hi = mesh_bounds(BUNNY)
    width = float(np.max(hi - lo))
    side = np.array([s[1], -s[0]])
    b = 0.85 * width * s + 0.2 * width * side    # the second bunny inside the first one's shadow
    return [standing(BUNNY, "bunny_a", (0.0, 0.0)), standing(BUNNY, "bunny_b", (float(b[0]), float(b[1])))]


def overlap_kernel_check(r: Runner, data: dict, env: str, field: FivField, both: Built) -> dict:
    """Does the kernel combine occluders as docs/fiv.md says? Renders each bunny alone
    (same camera and plane) to get its I_i = E_dif - E_i from the kernel, combines them in
    Python by the documented sum / disc / multiplied rules, and compares with the kernel's
    two-bunny image, over plane pixels that no bunny hides in any of the three renders."""
    setup = OracleSetup(r, both, ["bunny_a", "bunny_b"], field)
    out = {}
    for partial in (1, 0):
        imgs, masks = {}, {}
        for name in ("bunny_a", "bunny_b"):
            one = {"camera": data["camera"], "object": [o for o in data["object"] if o["name"] in (name, "ground")]}
            b1 = Built(r.ctx, one, env)
            attach_by_mesh(b1.scene, [field])
            b1.scene.commit()
            img, g, _ = shade(b1, "fiv", background=0, partial=partial, planes=True)
            imgs[name], masks[name] = img[..., :3].astype(np.float64), g["instance"] == b1.instance_ids["ground"]
            uns, _, _ = shade(b1, "unshadowed", background=0)
        g2 = None
        res = {}
        for overlap in (0, 1, 2):
            img2, g2, _ = shade(both, "fiv", background=0, partial=partial, overlap=overlap, planes=True)
            m = (g2["instance"] == both.instance_ids["ground"]) & masks["bunny_a"] & masks["bunny_b"]
            alb = g2["albedo"][..., :3][m].astype(np.float64) / math.pi
            E0 = uns[..., :3][m] / alb
            I = [np.maximum(E0 - imgs[n][m] / alb, 0.0) for n in ("bunny_a", "bunny_b")]
            P, N, _ = pixels(g2, m)
            total = I[0] + I[1]
            if overlap == 0:
                E = E0 - total
            elif overlap == 1:
                disc = []
                for n in ("bunny_a", "bunny_b"):
                    c, R = setup.spheres[n]
                    v = c - P
                    rho = np.linalg.norm(v, axis=1)
                    disc.append((v / rho[:, None], np.minimum(R / rho, 1.0)))
                (da, ra), (db, rb) = disc
                lens = lens_area(ra, rb, np.linalg.norm(da - db, axis=1))
                corr = total - (lens / (math.pi * (ra * ra + rb * rb)))[:, None] * total
                E = E0 - np.clip(corr, np.maximum(I[0], I[1]), total)
            else:
                E = E0 * np.clip(1 - I[0] / E0, 0, 1) * np.clip(1 - I[1] / E0, 0, 1)
            pred = alb * np.maximum(E, 0.0)
            # pixels where a single-bunny render was clamped at 0 cannot be inverted exactly
            ok = np.all(imgs["bunny_a"][m] > 0, axis=1) & np.all(imgs["bunny_b"][m] > 0, axis=1)
            diff = np.abs(pred - img2[..., :3][m])[ok]
            res[f"overlap={overlap}"] = {"max_abs": float(diff.max()), "mean_abs": float(diff.mean()),
                                         "ref_range": float(img2[..., :3][m].max() - img2[..., :3][m].min()),
                                         "pixels": int(ok.sum())}
        out[f"partial={partial}"] = res
    log(f"  kernel check {env}: " + ", ".join(f"{p} {k} max {v['max_abs']:.2e}" for p, d in out.items()
                                               for k, v in d.items()))
    return out


def exp_c(r: Runner) -> dict:
    res = {"grid": grid_name(r.main_grid), "envs": {}}
    for env in ("sunny", "area"):
        data = plane_scene(two_bunnies(env), env, r.res)
        b = Built(r.ctx, data, env)
        f, rec = r.field(b, "bunny_a", r.main_grid)
        variants = tuple(Variant(f"overlap={o}" + ("" if p else " partial=0"), {"overlap": o, "partial": p})
                         for p in (1, 0) for o in (0, 1, 2))
        ev = r.evaluate(f"c_{env}", b, [f], variants, "ground",
                        oracle=overlap_oracle(OracleSetup(r, b, ["bunny_a", "bunny_b"], f)))
        ev["scene"] = data
        ev["kernel_check"] = overlap_kernel_check(r, data, env, f, b)
        # where the two shadows overlap: both bunnies' bounding cones hold the key light(s)
        res["envs"][env] = ev
    res["most_accurate"] = {env: min(((k, v["nrmse"]) for k, v in e["variants"].items()
                                      if k.startswith("overlap") and "partial" not in k),
                                     key=lambda kv: kv[1])[0] for env, e in res["envs"].items()}
    res["most_accurate_partial0"] = {env: min(((k, v["nrmse"]) for k, v in e["variants"].items()
                                               if k.startswith("overlap") and "partial=0" in k),
                                              key=lambda kv: kv[1])[0] for env, e in res["envs"].items()}
    return res


def exp_d(r: Runner) -> dict:
    data = plane_scene([standing(QUEEN, "queen", sink=0.2)], "sunny", r.res)
    b = Built(r.ctx, data, "sunny")
    f, rec = r.field(b, "queen", r.main_grid)
    info = f.info()
    lo, hi = mesh_bounds(QUEEN)
    t = data["object"][0]["translate"]
    d_plane = info["centre"][1] + t[1]
    scale = (d_plane + info["radius"]) / (2 * info["radius"])
    ev = r.evaluate("d_queen", b, [f], settings("partial", (0, 1)), "ground",
                    oracle=plane_oracle(OracleSetup(r, b, ["queen"], f)))
    ev.update(scene=data, bake=rec, grid=grid_name(r.main_grid), centre_height=d_plane, radius=info["radius"],
              case_b_scale=(d_plane + info["radius"]) / (2 * info["radius"]), sink_fraction=0.2,
              queen_height=float(hi[1] - lo[1]))
    return ev


def exp_e(r: Runner) -> dict:
    obj = standing(BUNNY, "bunny")
    lo, hi = mesh_bounds(BUNNY)
    L = unit(key_light_dirs("sunny")[0])
    sun_az = math.degrees(math.atan2(L[0], L[2]))
    cam_dir = direction(25.0, sun_az + 110.0)
    centre = np.array([0.0, 0.5 * float(hi[1] - lo[1]), 0.0])
    half = 0.55 * float(np.max(hi - lo))
    dist = half / math.tan(math.radians(FOV / 2))
    data = {"camera": {"position": (centre + dist * cam_dir).tolist(), "look_at": centre.tolist(), "fov_deg": FOV,
                       "resolution": [r.res, r.res]}, "object": [obj]}
    b = Built(r.ctx, data, "sunny")
    f, rec = r.field(b, "bunny", r.main_grid)
    ev = r.evaluate("e_self", b, [f], settings("self_shadow", (1, 0)),
                    "bunny", oracle=self_oracle(OracleSetup(r, b, ["bunny"], f)))
    ev.update(scene=data, bake=rec, grid=grid_name(r.main_grid))
    return ev


def exp_f(r: Runner) -> dict:
    """Bake cost: fresh bakes (not from the cache) of the 35,947-vertex bunny under the sunny map."""
    grids = [(32, 17, 15)] if r.quick else [(32, 17, 15), (64, 33, 30), (128, 65, 30)]
    if r.args.big and not r.quick:
        grids.append((256, 129, 30))
    data = {"camera": {"position": [0, 0, 1], "look_at": [0, 0, 0], "resolution": [8, 8]},
            "object": [standing(BUNNY, "bunny")]}
    b = Built(r.ctx, data, "sunny")
    rows = {}
    for g in grids:
        f, rec = r.field(b, "bunny", g, fresh=r.args.fresh_bakes)
        if "rays" not in rec:
            log(f"  no bake record for {grid_name(g)}: rebaking")
            f, rec = r.field(b, "bunny", g, fresh=True)
        rec = dict(rec)
        rec["float32_bytes"] = rec["sample_count"] * 9 * 4
        rec["float16_bytes"] = rec["sample_count"] * 9 * 2
        rec["mrays_per_s"] = rec["rays"] / rec["bake_seconds"] / 1e6
        rec["rays_per_sample"] = rec["rays"] / rec["sample_count"]
        rec["paper"] = PAPER_TABLE1.get(grid_name(g))
        rows[grid_name(g)] = rec
    # The same grids under the directional map (a 1 degree disc: almost no rays traced): the bake's
    # time outside ray tracing (inside tests by winding number, env records, read-back, checkpoints).
    bd = Built(r.ctx, data, "directional")
    for g in grids:
        _, recd = r.field(bd, "bunny", g, fresh=r.args.fresh_bakes)
        if "rays" in recd and "bake_seconds" in recd:
            row = rows[grid_name(g)]
            row["nontrace_seconds"] = recd["bake_seconds"]
            row["nontrace_rays"] = recd["rays"]
            row["trace_mrays_per_s"] = row["rays"] / max(row["bake_seconds"] - recd["bake_seconds"], 1e-9) / 1e6
    # float32 check of stored_bytes at the smallest grid
    f32, rec32 = r.field(b, "bunny", grids[0], precision="float32")
    check = {"grid": grid_name(grids[0]), "stored_bytes_float32": rec32["stored_bytes"],
             "expected": rec32["sample_count"] * 36}
    out = {"env": "sunny", "face_size": 32, "sun_supersampling": 4, "rows": rows, "float32_check": check}
    if "256x129x30" not in rows and not r.quick:
        base = rows["128x65x30"]
        samples = 256 * 129 * 30
        rays = base["rays_per_sample"] * samples
        out["extrapolated"] = {"grid": "256x129x30", "sample_count": samples, "rays": rays,
                               "bake_seconds": base["bake_seconds"] * samples / base["sample_count"],
                               "float16_bytes": samples * 18, "float32_bytes": samples * 36,
                               "from": "128x65x30: rays and seconds per sample (the inside tests scale with the "
                                       "samples too)"}
    return out


def exp_g(r: Runner) -> dict:
    """Embree (embreex, one thread) on a subset of the bake's own rays."""
    from penumbra.raybench import embree_scene

    grid = (32, 17, 15) if r.quick else (128, 65, 30)
    data = {"camera": {"position": [0, 0, 1], "look_at": [0, 0, 0], "resolution": [8, 8]},
            "object": [{"name": "bunny", "mesh": BUNNY, "albedo": list(ALBEDO)}]}   # object space, as baked
    b = Built(r.ctx, data, "sunny")
    f, rec = r.field(b, "bunny", grid)
    info = f.info()
    nt, nphi, nr = info["samples"]
    radii = f.radii()
    inside = np.isnan(f.samples()[..., 0, 0])           # (radii, theta, phi)
    env32 = EnvMap(r.ctx, env_latlong("sunny"), face_size=32)
    dirs, _ = env32.cube_directions()
    rad = env32.cube_radiance().reshape(-1, 3)
    dirs = dirs.reshape(-1, 3)[np.any(rad > 0, axis=1)].astype(np.float64)
    c = np.asarray(info["centre"], np.float64)
    R = info["radius"]
    rng = np.random.default_rng(1)
    target = 500_000 if r.quick else 4_000_000
    origins, directions, samples_used = [], [], 0
    n = 0
    while n < target:
        k, i, j = int(rng.integers(nr)), int(rng.integers(nt)), int(rng.integers(nphi))
        if inside[k, i, j]:
            continue
        th, ph = math.pi * i / (nt - 1), 2 * math.pi * j / nphi
        d = np.array([math.sin(th) * math.cos(ph), math.cos(th), math.sin(th) * math.sin(ph)])
        rho = radii[k]
        p = c - rho * d
        s = R * 1.0001 / rho
        cos_cone = math.sqrt(1 - s * s) if s < 1 else -2.0
        sel = dirs[dirs @ d >= cos_cone]
        origins.append(np.broadcast_to(p, sel.shape))
        directions.append(sel)
        n += len(sel)
        samples_used += 1
    o = np.ascontiguousarray(np.concatenate(origins), np.float32)
    d = np.ascontiguousarray(np.concatenate(directions), np.float32)
    from penumbra.meshio import load_mesh
    m = load_mesh(REPO / BUNNY)
    tris = np.ascontiguousarray(m.vertices[m.faces], np.float32)
    em, _keep = embree_scene(tris)

    em_s = median_ms(lambda: em.run(o, d, query="OCCLUDED"), 3, warmup=1)[0] / 1000.0
    pn_s = median_ms(lambda: b.scene.occluded(o, d), 3, warmup=1)[0] / 1000.0
    em_occ = em.run(o, d, query="OCCLUDED") != -1
    pn_occ = b.scene.occluded(o, d).astype(bool)
    bake_rate = rec["rays"] / rec["bake_seconds"] / 1e6 if rec.get("rays") else float("nan")
    _, recd = r.field(Built(r.ctx, data, "directional"), "bunny", grid)
    trace_rate = (rec["rays"] / max(rec["bake_seconds"] - recd["bake_seconds"], 1e-9) / 1e6
                  if rec.get("rays") and recd.get("bake_seconds") else float("nan"))
    out = {"grid": grid_name(grid), "rays": int(len(o)), "samples": samples_used,
           "occluded_fraction": float(em_occ.mean()), "mismatch_fraction": float((em_occ != pn_occ).mean()),
           "embree_s": em_s, "embree_mrays_per_s": len(o) / em_s / 1e6, "embree_threads": 1,
           "penumbra_occluded_s": pn_s, "penumbra_occluded_mrays_per_s": len(o) / pn_s / 1e6,
           "bake_mrays_per_s": bake_rate, "bake_record": rec, "bake_trace_mrays_per_s": trace_rate,
           "bake_nontrace_seconds": recd.get("bake_seconds"),
           "bake_trace_over_embree": trace_rate / (len(o) / em_s / 1e6),
           "bake_over_embree": bake_rate / (len(o) / em_s / 1e6),
           "note": "Embree: embreex EmbreeScene.run, one rtcOccluded1 per ray on one thread; bake: PoCL on all "
                   "cores, its rate includes the inside tests, cone culling and read-back"}
    log(f"  Embree {out['embree_mrays_per_s']:.2f} M rays/s (1 thread), penumbra occluded() "
        f"{out['penumbra_occluded_mrays_per_s']:.2f}, bake {bake_rate:.2f} M rays/s; mismatches "
        f"{out['mismatch_fraction']:.2e}")
    return out


# --------------------------------------------------------------------------- #
# Report
# --------------------------------------------------------------------------- #

ORACLE_NOTE = ("Rows marked * are diagnostics, not renderer output: fiv's formulas evaluated in Python with the "
               "*exact* occlusion at each pixel (ray casting against the occluders over the bake's own directions, "
               "6x32x32 + 4x4 sun sub-texels) instead of the interpolated grid. 'exact field' = fiv's formula with a "
               "perfect field (no grid error); 'exact FIV+' = DifMap minus the exact occluded irradiance of the "
               "positive hemisphere (what the paper's partial-occluder correction approximates); 'exact joint' = "
               "both occluders traced together (no overlap approximation). The gap between a fiv row and its "
               "exact-field row is the error of the grid (sampling and interpolation); the exact rows' own error is "
               "the direction discretisation (face 32 against the reference's face 64) and the formula.")


def variant_table(e: dict, paper: dict | None = None, bar: dict | None = None) -> list[str]:
    paper, bar = paper or {}, bar or {}
    L = ["| variant | paper NRMSE | fiv NRMSE | rel. RMS | mean error / range | shade ms | images |",
         "|---|---|---|---|---|---|---|"]
    for k, v in e["variants"].items():
        star = "*" if v["params"].get("oracle") else ""
        ms = "-" if not math.isfinite(v.get("shade_ms", float("nan"))) else f"{v['shade_ms']:.1f}"
        L.append(f"| {k}{star} | {paper.get(k, '-')} | {f4(v['nrmse'])} | {f4(v['rel_rms'])} | "
                 f"{v['mean_error'] / e['reference_range']:+.4f} | {ms} | "
                 f"{'' if not v.get('png') else '[img](' + v['png'] + '), '}[error]({v['error_png']}) |")
    L.append(f"\nReference: [{e['reference_png']}]({e['reference_png']}) ({e['pixels']} evaluated pixels, "
             f"{e['reference_seconds']:.0f} s to render).")
    return L


def report(results: dict) -> str:
    meta = results["meta"]
    ex = results["experiments"]
    L = ["# FIV experiments (after Michael and Chrysanthou, Section 5)", ""]
    L.append(harness.generated_by(meta, SCRIPT, "the cores are shared with other work, so timings are noisy")
             + f" plus the working tree (kernels/fiv.cl sha256 {meta['fiv_cl_sha']}..., fiv_bake.cl "
             f"{meta['fiv_bake_cl_sha']}...).")
    L.append("")
    L.append(f"Images {meta['resolution']}x{meta['resolution']} (the paper: 512x512), camera looking down at the "
             f"receiver plane at 60 degrees. Ground truth: `reference` with {meta['reference']} (docs/reference.md). "
             f"NRMSE = RMSE / (max - min of the reference) over the evaluated pixels, all three channels "
             f"(penumbra.metrics.compare); 'mean error / range' is the signed mean error (negative: too dark) over "
             f"the same range. Heat maps saturate at {HEAT_FRACTION:g} x the reference's range; grey = not "
             f"evaluated. Env maps: `sunny` = immenstadter_horn_1k (Poly Haven; stands in for the paper's "
             f"Eucalyptus Grove), `directional` = black with one {2 * DIRECTIONAL_RADIUS_DEG:g} degree disc, "
             f"`area` = black with a green and a red rectangular area light, `forest` = forest_slope_1k. "
             f"Fields: grids phi x theta x rho (the paper's notation), env directions 6x32x32 with 4x4 "
             f"sub-texels for the sun, float16 unless noted.")
    L += ["", ORACLE_NOTE, ""]
    if "a" in ex:
        a = ex["a"]
        paper = {"32x17x15": 0.023, "64x33x30": 0.008, "256x129x30": 0.007}
        ex_p1 = ex_p0 = None
        for e in a["grids"].values():
            if "exact field partial=1" in e["variants"]:
                ex_p1 = e["variants"]["exact field partial=1"]["nrmse"]
                ex_p0 = e["variants"]["exact field partial=0"]["nrmse"]
        L += [f"## a. {TITLES['a']}", "", "Bunny (35,947 vertices) resting on a plane under the sunny map; NRMSE over "
              "the plane's pixels (the bunny's own pixels excluded). `fiv` with its defaults (partial = 1) and with "
              "partial = 0: the bunny's bounding sphere (centre 0.077 above the plane, R = 0.105) straddles the "
              "plane, so every plane pixel is case B and partial = 1 scales the whole shadow by "
              "(d + R) / 2R = 0.87.", "",
              f"Exact field* (grid-independent): partial=1 {f4(ex_p1)}, partial=0 {f4(ex_p0)}.", "",
              "| samples | paper NRMSE | fiv NRMSE | fiv partial=0 | unshadowed | bake s | images |",
              "|---|---|---|---|---|---|---|"]
        for g, e in a["grids"].items():
            v = e["variants"]["fiv"]
            v0 = e["variants"].get("fiv partial=0", {})
            u = e["variants"]["unshadowed"]
            bake = e.get("bake", {}).get("bake_seconds")
            L.append(f"| {g} | {paper.get(g, '-')} | {f4(v['nrmse'])} | {f4(v0.get('nrmse'))} | {f4(u['nrmse'])} | "
                     f"{'-' if bake is None else f'{bake:.0f}'} | [fiv]({v['png']}), "
                     f"[partial=0]({v0.get('png')}), [ref]({e['reference_png']}), [error]({v['error_png']}), "
                     f"[error partial=0]({v0.get('error_png')}) |")
        L += ["", "The same renders over the bunny's own pixels (self-shadowing; the ground plane is no occluder "
              "for `fiv`, so the light from below the horizon that the plane hides in the reference is not removed "
              "there):", "", "| samples | fiv NRMSE (bunny pixels) | unshadowed |", "|---|---|---|"]
        for g, e in a["grids"].items():
            L.append(f"| {g} | {f4(e['variants']['fiv'].get('nrmse_bunny'))} | "
                     f"{f4(e['variants']['unshadowed'].get('nrmse_bunny'))} |")
        L.append("")
        first = next(iter(a["grids"].values()))
        L += [f"### a. all variants at {next(iter(a['grids']))}", ""] + variant_table(first, paper) + [""]
        if a.get("soft"):
            L += ["### a. the same scene under light probes without a sun", "",
                  "The paper does not name Fig. 12's map. Its errors there (0.008 at 64x33x30) are below every "
                  "error of its Figs. 13, 14 and 16 (Eucalyptus Grove 0.022 and 0.015, area lights 0.019-0.035, one "
                  "light 0.1), so its lighting was softer than those. The same bunny and plane, the camera centred on the "
                  "bunny (its shadow lies all around it), under Uffizi "
                  "(soft: the brightest 0.01 sr give 2 % of an upward plane's irradiance) and Grace Cathedral "
                  "(small bright lamps: 87 %; the sunny map's sun: 29 %).", "",
                  "| map | samples | paper NRMSE | fiv NRMSE (partial=1) | fiv partial=0 (default) | exact field* "
                  "partial=0 | unshadowed | images |", "|---|---|---|---|---|---|---|---|"]
            for env, grids_ in a["soft"].items():
                for g, e in grids_.items():
                    v, u = e["variants"].get("fiv", {"nrmse": None}), e["variants"]["unshadowed"]
                    v0 = e["variants"].get("fiv partial=0", {})
                    x0 = e["variants"].get("exact field partial=0", {}).get("nrmse")
                    L.append(f"| {env} | {g} | {paper.get(g, '-')} | {f4(v['nrmse'])} | {f4(v0.get('nrmse'))} | "
                             f"{'-' if x0 is None else f4(x0)} | {f4(u['nrmse'])} | [fiv partial=0]({v0.get('png')}), "
                             f"[ref]({e['reference_png']}), [error partial=0]({v0.get('error_png')}) |")
            L.append("")
    if "b" in ex:
        b = ex["b"]
        paper = {"directional": 0.1, "area": 0.035, "sunny": 0.022, "forest": 0.022}
        bar = {"directional": 0.05, "area": 0.035, "sunny": 0.022, "forest": 0.022}
        L += [f"## b. {TITLES['b']}", "", f"Bunny on the plane, grid {b['grid']}, NRMSE over the plane's pixels. "
              "`forest` (forest_slope_1k, a softer outdoor map with a hazy sun) is an extra row: the paper's "
              "Eucalyptus Grove has no hard sun, and neither Poly Haven map is it.", "",
              "| env map | paper NRMSE | bar | fiv NRMSE | met | fiv partial=0 | exact field* partial=1 / 0 | "
              "unshadowed | images |", "|---|---|---|---|---|---|---|---|---|"]
        for env, e in b["envs"].items():
            vs = e["variants"]
            v = vs["fiv"]
            v0 = vs.get("fiv partial=0", {}).get("nrmse")
            exs = f"{f4(vs.get('exact field partial=1', {}).get('nrmse'))} / " \
                  f"{f4(vs.get('exact field partial=0', {}).get('nrmse'))}"
            base = env.split()[0]
            L.append(f"| {env} | {paper[base]} | {bar[base]} | {f4(v['nrmse'])} | "
                     f"{'yes' if v['nrmse'] <= bar[base] else 'no'} | {f4(v0)} | {exs} | "
                     f"{f4(vs['unshadowed']['nrmse'])} | [fiv]({v['png']}), "
                     f"[ref]({e['reference_png']}), [error]({v['error_png']}) |")
        L.append("")
        for env, e in b["envs"].items():
            L += [f"### b. {env}", ""] + variant_table(e) + [""]
    if "c" in ex:
        c = ex["c"]
        L += [f"## c. {TITLES['c']}", "", f"Two bunnies, the second inside the first one's shadow; grid {c['grid']}, "
              "NRMSE over the plane's pixels. Paper (Fig. 15): correction off 0.027, on 0.019.", "",
              "| env map | partial | overlap=0 (sum) | overlap=1 (disc correction) | overlap=2 (multiplied) | "
              "most accurate | exact fields* sum / disc / multiplied | exact joint* |",
              "|---|---|---|---|---|---|---|---|"]
        for env, e in c["envs"].items():
            vs = e["variants"]
            for p in (1, 0):
                suf = "" if p else " partial=0"
                exs = " / ".join(f4(vs.get(f"exact fields overlap={o} partial={p}", {}).get("nrmse")) for o in range(3))
                best = c["most_accurate"][env] if p else c.get("most_accurate_partial0", {}).get(env, "-")
                L.append(f"| {env} | {p} | {f4(vs.get('overlap=0' + suf, {}).get('nrmse'))} | "
                         f"{f4(vs.get('overlap=1' + suf, {}).get('nrmse'))} | "
                         f"{f4(vs.get('overlap=2' + suf, {}).get('nrmse'))} | {best} | {exs} | "
                         f"{f4(vs.get('exact joint FIV+', {}).get('nrmse'))} |")
        L.append("")
        checks = [f"{env} {p} {k}: {v['max_abs']:.1e}" for env, e in c["envs"].items()
                  for p, d in e.get("kernel_check", {}).items() for k, v in d.items()]
        if checks:
            worst = max(v["max_abs"] / max(v["ref_range"], 1e-30) for e in c["envs"].values()
                        for d in e.get("kernel_check", {}).values() for v in d.values())
            L += ["Kernel check: each bunny rendered alone gives the kernel's own I_i; combining them in Python by "
                  "the rules of docs/fiv.md (sum, disc lens correction with its clamp, multiplied visibilities) "
                  "reproduces the kernel's two-bunny images to a largest difference of "
                  f"{worst:.1e} of the image range ({'; '.join(checks)}).", ""]
        for env, e in c["envs"].items():
            L += [f"### c. {env}", ""] + variant_table(e, {"overlap=0": 0.027, "overlap=1": 0.019}) + [""]
    if "d" in ex:
        d = ex["d"]
        L += [f"## d. {TITLES['d']}", "",
              f"Chess queen sunk {d['sink_fraction']:g} of its height below the plane, sunny map, grid "
              f"{d['grid']}. Bounding-sphere centre {d['centre_height']:.3f} above the plane, R = {d['radius']:.3f}: "
              f"every plane pixel is case B, and partial = 1 scales the queen's whole shadow by (d + R) / 2R = "
              f"{d['case_b_scale']:.3f}. NRMSE over the plane's pixels.", ""]
        L += variant_table(d, {"partial=0": 0.026, "partial=1": 0.019}) + [""]
    if "e" in ex:
        e = ex["e"]
        L += [f"## e. {TITLES['e']}", "", "The bunny alone (no plane) under the sunny map, NRMSE over the bunny's "
              f"pixels, grid {e.get('grid', '')}. The paper gives no NRMSE for self-shadowing. 'exact field at "
              "p+hR N': fiv's self-shadow formula N . (FIV(Env) - FIV_occ(q)) with the exact FIV_occ at a point q "
              "lifted h bounding radii off the surface, as the grid's nearest valid samples are.", ""]
        L += variant_table(e) + [""]
    if "f" in ex:
        f = ex["f"]
        L += [f"## f. {TITLES['f']}", "", "Bakes of the 35,947-vertex bunny (69,451 triangles) under the sunny map, "
              "env directions 6x32x32 plus 4x4 sub-texels for the sun, on this machine's 2 cores (PoCL). The paper: "
              "a 2.4 GHz Core 2 Duo (2 cores) in 2008, memory in float32. 'non-ray s': the same bake under the "
              "directional map, which traces almost no rays (inside tests by winding number, env records, "
              "read-back, checkpoints); 'trace M rays/s' = rays / (bake s - non-ray s).", "",
              "| samples | paper min | paper MiB | bake s | bake min | rays | M rays/s | non-ray s | trace M rays/s "
              "| rays/sample | inside samples | float16 MiB | float32 MiB |",
              "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
        for g, row in f["rows"].items():
            p = row.get("paper") or ("-", "-")
            nt = row.get("nontrace_seconds")
            tr = row.get("trace_mrays_per_s")
            L.append(f"| {g} | {p[0]} | {p[1]} | {row['bake_seconds']:.1f} | {row['bake_seconds'] / 60:.2f} | "
                     f"{row['rays'] / 1e6:.1f} M | {row['mrays_per_s']:.2f} | {'-' if nt is None else f'{nt:.1f}'} | "
                     f"{'-' if tr is None else f'{tr:.2f}'} | {row['rays_per_sample']:.0f} | "
                     f"{row['inside_count']} | {row['float16_bytes'] / MIB:.3f} | {row['float32_bytes'] / MIB:.3f} |")
        if "extrapolated" in f:
            x = f["extrapolated"]
            p = PAPER_TABLE1["256x129x30"]
            L.append(f"| 256x129x30 (extrapolated) | {p[0]} | {p[1]} | {x['bake_seconds']:.0f} | "
                     f"{x['bake_seconds'] / 60:.1f} | {x['rays'] / 1e6:.0f} M | - | - | - | - | - | "
                     f"{x['float16_bytes'] / MIB:.3f} | {x['float32_bytes'] / MIB:.3f} |")
        ck = f["float32_check"]
        L += ["", f"stored_bytes of a float32 bake at {ck['grid']}: {ck['stored_bytes_float32']} "
              f"(9 x 4 bytes x samples = {ck['expected']}). MiB = 2^20 bytes: the paper's 'MB' (its 0.28 / 2.17 / "
              f"8.56 / 34.0 are 9 float32 per sample in MiB). Bake times are wall clock of one bake each; the "
              f"cores are shared with other work.", ""]
    if "g" in ex:
        g = ex["g"]
        L += [f"## g. {TITLES['g']}", "",
              f"{g['rays'] / 1e6:.1f} M rays regenerated from {g['samples']} random samples of the {g['grid']} grid "
              "(sample point c - rho d(theta, phi), the directions of the 6x32x32 cube inside the bounding cone; "
              "the sun's sub-texels left out), any-hit against the bunny.", "",
              "| tracer | M rays/s |", "|---|---|",
              f"| Embree 4 (embreex, rtcOccluded1 per ray, 1 thread) | {g['embree_mrays_per_s']:.2f} |",
              f"| penumbra Scene.occluded, same rays (PoCL, 2 cores, host arrays in and out) | "
              f"{g['penumbra_occluded_mrays_per_s']:.2f} |",
              f"| penumbra bake, {g['grid']}: rays / bake seconds (2 cores) | {g['bake_mrays_per_s']:.2f} |",
              f"| penumbra bake, ray tracing only (bake seconds minus the non-ray part) | "
              f"{g.get('bake_trace_mrays_per_s', float('nan')):.2f} |", "",
              f"Bake / Embree = {g['bake_over_embree']:.2f} (tracing only: "
              f"{g.get('bake_trace_over_embree', float('nan')):.2f}). "
              f"Occluded fraction {g['occluded_fraction']:.3f}; penumbra and Embree disagree on "
              f"{g['mismatch_fraction']:.2e} of the rays.", ""]
    return "\n".join(L) + "\n"


EXPERIMENTS = (
    Experiment("a", "bunny shadow on a plane, FIV sampling rates (paper Fig. 12)", exp_a),
    Experiment("b", "environment maps (paper Fig. 13)", exp_b),
    Experiment("c", "two occluders with overlapping shadows (paper Fig. 15)", exp_c),
    Experiment("d", "occluder straddling the receiver plane (paper Fig. 17)", exp_d),
    Experiment("e", "self-shadowing on the bunny (paper Fig. 18)", exp_e),
    Experiment("f", "bake cost (paper Table 1)", exp_f),
    Experiment("g", "bake ray throughput against Embree", exp_g),
)
TITLES = {e.key: e.title for e in EXPERIMENTS}


def add_arguments(ap) -> None:
    ap.add_argument("--resolution", type=int, default=0, help="image side in pixels (default 256, quick 96)")
    ap.add_argument("--big", action="store_true", help="also bake 256x129x30 (about 20 min on 2 cores)")
    ap.add_argument("--no-oracle", action="store_true", help="skip the exact-occlusion oracle variants")
    ap.add_argument("--fresh-bakes", action="store_true", help="experiment f: rebake even when cached")


def meta(r: Runner) -> dict:
    return {"resolution": r.res, "quick": r.quick, "reference": ", ".join(f"{k} {v}" for k, v in r.ref_params.items()),
            "fiv_cl_sha": harness.sha(REPO / "kernels" / "fiv.cl"),
            "fiv_bake_cl_sha": harness.sha(REPO / "kernels" / "fiv_bake.cl"), "main_grid": grid_name(r.main_grid)}


SUITE = Suite(script=SCRIPT, description=__doc__, experiments=EXPERIMENTS, runner=Runner,
              report=report, default_out="bench/results/fiv", meta=meta,
              stamp=lambda m: {"fiv_cl_sha": m["fiv_cl_sha"]}, add_arguments=add_arguments,
              quick_help="smoke run: 96 px, 32x17x15 grids, reference face 32")

if __name__ == "__main__":
    sys.exit(harness.main(SUITE))
