#!/usr/bin/env python3
"""Soak: many frames of a fully dynamic scene in one process, with the
process's memory measured after a warm-up and at the end (docs/reliability.md).

One Context; a height-field terrain and several mesh instances (spheres with
a baked occlusion field and a sphere set attached, a rotating box). Every
frame:

- the spheres and the box move, the camera orbits;
- one transient instance is removed and a new one added (two live at a time);
- the terrain gets new heights (pn_heightfield_set_heights + commit) and its
  triangle mesh is rebuilt (pn_heightfield_build_mesh), its instance swapped;
- one frame parameter of the method drawn this frame is set to a new value in
  its declared range (ranges from the library's method metadata,
  pn_method_get_param); every 10 frames a plan parameter of one method changes;
- the frame is rendered (G-buffer + execute + read back, pixels checked
  finite) with one of the cheap methods, in turn: unshadowed, floor,
  heightfield, fiv, depthmap, isg.

Every ENV_EVERY frames a new EnvMap object replaces the old one (one of three
skies in turn) and a new tiny occlusion field is baked under it, replacing the
old field on every sphere; every RENDERER_EVERY frames the renderers are
created anew; every TARGET_EVERY frames the G-buffer and image too.

Before the frames, every sky, plan-value combination and integer frame
parameter value is rendered once (prime): first uses are not counted as
growth. After the warm-up and at the end the renderers are created anew at
their starting values and each method renders once (settle), so both
measurements see the same state. Measured: RSS (/proc/self/statm) and the C
heap in use (glibc mallinfo2: what malloc handed out and did not get back,
free pages it keeps not counted), also half-way through the measured frames
(after a settle too). Growth per frame = the smaller of the two halves'
(memory at its end - at its start) / its frames: a leak grows memory in both
halves, a one-off first use in one only (the JSON also has the total,
(end - after warm-up) / frames after warm-up); above --bound-kib (RSS) or
--heap-bound-kib (heap) the script exits 1. Run: ``python tests/soak/soak.py --frames 10000``.
"""

from __future__ import annotations

import argparse
import ctypes
import gc
import json
import math
import os
import sys
import time

import numpy as np

import penumbra as pn
from penumbra import methods, procedural
from penumbra.methods.heightfield import HeightFieldHandle
from penumbra.methods.isg import SphereSet

METHODS = ("unshadowed", "floor", "heightfield", "fiv", "depthmap", "isg")
ENV_EVERY = 25
RENDERER_EVERY = 100
TARGET_EVERY = 250
PLAN_EVERY = 10
SAMPLE_EVERY = 10
GRID = 17  # terrain samples per side

# Plan-time parameters changed now and then, among values cheap at this size
# (the full ranges include planning work far beyond a soak's budget).
PLAN_VALUES = {
    "heightfield": {"azimuths": (8, 16), "level_step": (2, 4), "bands": (3, 4), "reconstruction": (0, 1),
                    "sun_threshold": (0.0, 50.0)},
    "depthmap": {"directions": (2, 4, 6), "resolution": (16, 32), "seed": (1, 2)},
    "isg": {"lobes": (4, 8)},
}
# Initial plan-time values (cheap).
PLAN_START = {"heightfield": {"azimuths": 8}, "depthmap": {"directions": 4, "resolution": 32}, "isg": {"lobes": 4}}
# Frame-time parameters whose cost grows with the value: capped here.
FRAME_CAPS = {"cap_samples": 32, "patch_grid": 8, "pcf": 2}

PAGE = os.sysconf("SC_PAGE_SIZE")


def rss_bytes() -> int:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * PAGE


class _MallInfo2(ctypes.Structure):
    _fields_ = [(n, ctypes.c_size_t) for n in ("arena", "ordblks", "smblks", "hblks", "hblkhd", "usmblks", "fsmblks",
                                                "uordblks", "fordblks", "keepcost")]


def _mallinfo2():
    try:
        f = ctypes.CDLL(None).mallinfo2
    except (OSError, AttributeError):  # not glibc (>= 2.33)
        return None
    f.restype = _MallInfo2
    return f


_MALLINFO2 = _mallinfo2()


def heap_in_use() -> int | None:
    """Bytes the C allocator has handed out and not had back, over all arenas
    (glibc's mallinfo2: uordblks + hblkhd), or None. Unlike RSS it does not
    count the free memory malloc keeps (fragmentation, per-thread arenas)."""
    if _MALLINFO2 is None:
        return None
    m = _MALLINFO2()
    return int(m.uordblks + m.hblkhd)


def skies():
    """Three small lat-long skies (sun in different places)."""
    out = []
    for k in range(3):
        a = 2.1 * k
        out.append(procedural.sky(64, 32, sun_direction=(0.6 * math.cos(a), 0.7, 0.6 * math.sin(a))))
    return out


def translate(x, y, z, s=1.0) -> np.ndarray:
    t = np.zeros((3, 4))
    t[:, :3] = s * np.eye(3)
    t[:, 3] = (x, y, z)
    return t


def rotate_y(angle, x, y, z) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    t = np.array([[c, 0, s, x], [0, 1, 0, y], [-s, 0, c, z]], dtype=np.float64)
    return t


class Soak:
    def __init__(self, width: int, height: int, seed: int, chosen: tuple[str, ...] = METHODS):
        self.methods = chosen
        self.rng = np.random.default_rng(seed)
        self.w, self.h = width, height
        self.ctx = pn.Context()
        self.skies = skies()
        self.sky_index = 0
        self.env = pn.EnvMap(self.ctx, self.skies[0], face_size=16)
        s = procedural.sphere(0.3, 2)
        b = procedural.box((0.4, 0.4, 0.4))
        self.sphere = pn.Mesh(self.ctx, s.vertices, s.faces, s.normals)
        self.box = pn.Mesh(self.ctx, b.vertices, b.faces, b.normals)
        self.fiv_options = pn.FivOptions(theta=5, phi=8, radii=3, face_size=4, sun_supersampling=1)
        self.field = pn.FivField.bake(self.env, self.sphere, self.fiv_options)
        self.spheres = SphereSet.build(self.sphere, 8)
        self.base_heights = procedural.terrain_heights(GRID, GRID, seed=seed)
        self.hf = HeightFieldHandle(self.ctx, self.base_heights, origin=(-2.5, 0.0, -2.5), size=(5.0, 5.0),
                                    height_scale=0.3)
        self.scene = pn.Scene(self.ctx)
        self.scene.set_envmap(self.env)
        self.terrain_mesh = self.hf.mesh()
        self.terrain = self.scene.add(self.terrain_mesh)
        self.scene.attach(self.terrain, self.hf)
        self.movers = [self._add_sphere(translate(k - 1.5, 0.6, 0.0)) for k in range(4)]
        self.spinner = self.scene.add(self.box, rotate_y(0.0, 0.0, 0.4, 1.2), pn.Material(albedo=(0.9, 0.3, 0.2)))
        self.transients: list[int] = []
        self.specs = {m: methods.spec(m) for m in chosen}
        self.plan = {m: dict(v) for m, v in PLAN_START.items()}
        self._new_renderers()
        self._new_targets()
        self.counts = {"env_changes": 0, "bakes": 1, "added": 0, "removed": 0, "param_sets": 0, "plan_sets": 0,
                       "renderers": 1, "targets": 1}

    # ------------------------------------------------------------- building blocks

    def _add_sphere(self, transform) -> int:
        i = self.scene.add(self.sphere, transform, pn.Material(albedo=(0.3, 0.5, 0.9)))
        self.scene.attach(i, self.field)
        self.scene.attach(i, self.spheres)
        return i

    def _new_renderers(self) -> None:
        old = getattr(self, "renderers", {})
        self.renderers = {m: pn.Renderer(self.ctx, m, **self.plan.get(m, {})) for m in self.methods}
        for r in old.values():
            r.close()

    def _new_targets(self) -> None:
        for t in (getattr(self, "gbuffer", None), getattr(self, "image", None)):
            if t is not None:
                t.close()
        self.gbuffer = pn.GBuffer(self.ctx, self.w, self.h)
        self.image = pn.Image(self.ctx, self.w, self.h)

    def _new_env(self) -> None:
        """A new EnvMap object (the next sky) and a new occlusion field baked under it."""
        self.sky_index = (self.sky_index + 1) % len(self.skies)
        env = pn.EnvMap(self.ctx, self.skies[self.sky_index], face_size=16)
        field = pn.FivField.bake(env, self.sphere, self.fiv_options)
        self.scene.set_envmap(env)
        for i in self.movers + [t for t in self.transients if self.scene.attachment(t, pn.FivField) is not None]:
            self.scene.attach(i, field)
        self.env.close()
        self.field.close()
        self.env, self.field = env, field
        self.counts["env_changes"] += 1
        self.counts["bakes"] += 1

    def _frame_param(self, method: str) -> None:
        params = self.specs[method].params_of("frame")
        if not params:
            return
        p = params[self.rng.integers(len(params))]
        hi = min(p.max, FRAME_CAPS.get(p.name, p.max))
        if p.type == "int":
            value = int(self.rng.integers(int(p.min), int(hi) + 1))
        else:
            top = min(hi, 2.0 * p.default if p.default > 0 else 1.0)
            value = float(self.rng.uniform(p.min, max(top, p.min)))
        self.renderers[method].set(**{p.name: value})
        self.counts["param_sets"] += 1

    def _plan_param(self, frame: int) -> None:
        planful = [m for m in PLAN_VALUES if m in self.renderers]
        if not planful:
            return
        method = planful[(frame // PLAN_EVERY) % len(planful)]
        name = tuple(PLAN_VALUES[method])[self.rng.integers(len(PLAN_VALUES[method]))]
        choices = PLAN_VALUES[method][name]
        value = choices[self.rng.integers(len(choices))]
        self.plan.setdefault(method, {})[name] = value
        self.renderers[method].set(**{name: value})
        self.counts["plan_sets"] += 1

    def prime(self) -> int:
        """Renders every plan-value combination of PLAN_VALUES and every value
        of every integer frame parameter (up to its cap) once, each sky once,
        then returns to the starting values: the library's (and PoCL's) first
        uses of each stage, kernel and work size happen here, before the
        warm-up, and not as steps in the measured frames. Returns the renders."""
        import itertools

        sc, n = self.scene, 0
        sc.set_camera(pn.Camera(position=(0.0, 3.0, 5.0), look_at=(0.0, 0.3, 0.0), fov_deg=45.0,
                                resolution=(self.w, self.h)))
        sc.commit()

        def render(method):
            nonlocal n
            sc.render_gbuffer(self.gbuffer)
            self.renderers[method].execute(sc, self.gbuffer, self.image)
            self.image.read()
            n += 1

        for _ in self.skies:
            self._new_env()
            sc.commit()
            for m in self.methods:
                render(m)
        for m in self.methods:
            r = self.renderers[m]
            plan = PLAN_VALUES.get(m, {})
            for combo in itertools.product(*plan.values()):
                r.set(**dict(zip(plan, combo)))
                render(m)
            for p in self.specs[m].params_of("frame"):
                if p.type == "int":
                    for v in range(int(p.min), int(min(p.max, FRAME_CAPS.get(p.name, p.max))) + 1):
                        r.set(**{p.name: v})
                        render(m)
                    r.set(**{p.name: p.default})
        self.counts["env_changes"] = self.counts["bakes"] = 0
        self._new_renderers()
        return n

    def settle(self) -> None:
        """New renderers at the starting parameter values, one render per
        method: the state RSS is measured in, after the warm-up and at the end.
        A renderer keeps what it grew for the values it was given (depthmap's
        rasteriser, map_renderer 0, keeps megabytes until it is released):
        comparing renderers of different histories would measure that, not
        growth."""
        self.plan = {m: dict(v) for m, v in PLAN_START.items()}
        self._new_renderers()
        for m in self.methods:
            self.scene.render_gbuffer(self.gbuffer)
            self.renderers[m].execute(self.scene, self.gbuffer, self.image)
            self.image.read()
        gc.collect()

    # ------------------------------------------------------------------ a frame

    def frame(self, f: int) -> str:
        t = 0.05 * f
        sc = self.scene
        for k, i in enumerate(self.movers):
            sc.set_transform(i, translate(k - 1.5 + 0.3 * math.sin(t + k), 0.6 + 0.2 * math.cos(1.3 * t + k),
                                          0.4 * math.sin(0.7 * t + 2 * k), 0.8 + 0.2 * math.sin(t + k)))
        sc.set_transform(self.spinner, rotate_y(t, 0.5 * math.cos(t), 0.4, 1.2))

        # One instance out, one in (alternately a sphere with its assets and a box).
        if len(self.transients) >= 2:
            sc.remove(self.transients.pop(0))
            self.counts["removed"] += 1
        x, z = self.rng.uniform(-2.0, 2.0, 2)
        if f % 2:
            self.transients.append(self._add_sphere(translate(x, 0.5, z, 0.7)))
        else:
            self.transients.append(sc.add(self.box, rotate_y(t, x, 0.4, z)))
        self.counts["added"] += 1

        # New heights; the terrain's triangles follow (a new mesh, the instance swapped).
        heights = self.base_heights * (1.0 + 0.5 * math.sin(0.1 * f)) + 0.05 * np.float32(math.cos(0.3 * f))
        self.hf.set_heights(heights)
        mesh = self.hf.mesh()
        sc.remove(self.terrain)
        self.terrain = sc.add(mesh)
        sc.attach(self.terrain, self.hf)
        self.terrain_mesh.close()
        self.terrain_mesh = mesh

        if f > 0 and f % ENV_EVERY == 0:
            self._new_env()
        if f > 0 and f % RENDERER_EVERY == 0:
            self._new_renderers()
            self.counts["renderers"] += 1
        if f > 0 and f % TARGET_EVERY == 0:
            self._new_targets()
            self.counts["targets"] += 1

        method = self.methods[f % len(self.methods)]
        self._frame_param(method)
        if f % PLAN_EVERY == PLAN_EVERY - 1:
            self._plan_param(f)

        a = 0.02 * f
        sc.set_camera(pn.Camera(position=(5.0 * math.sin(a), 3.0, 5.0 * math.cos(a)), look_at=(0.0, 0.3, 0.0),
                                fov_deg=45.0, resolution=(self.w, self.h)))
        sc.commit()
        sc.render_gbuffer(self.gbuffer)
        self.renderers[method].execute(sc, self.gbuffer, self.image)
        rgba = self.image.read()
        if not np.isfinite(rgba).all():
            raise RuntimeError(f"frame {f} ({method}): non-finite pixels")
        return method

    def close(self) -> None:
        for r in self.renderers.values():
            r.close()
        for o in (self.gbuffer, self.image, self.scene, self.terrain_mesh, self.hf, self.spheres, self.field,
                  self.sphere, self.box, self.env, self.ctx):
            o.close()


def run(frames: int, warmup: int, width: int, height: int, seed: int, bound_kib: float, progress: bool,
        chosen: tuple[str, ...] = METHODS, heap_bound_kib: float = 0.25) -> dict:
    start = time.monotonic()
    rss_start = rss_bytes()
    soak = Soak(width, height, seed, chosen)
    primed = soak.prime()
    prime_seconds = time.monotonic() - start
    samples: list[tuple[int, int, int]] = []  # (frame, RSS, heap in use)
    per_method: dict[str, float] = {m: 0.0 for m in chosen}
    rss_warm = objects_warm = None
    mid = warmup + (frames - warmup) // 2  # the measured frames in two halves
    rss_mid = heap_mid = None
    for f in range(frames):
        t0 = time.monotonic()
        method = soak.frame(f)
        per_method[method] += time.monotonic() - t0
        if f + 1 == warmup:
            soak.settle()
            rss_warm, heap_warm, objects_warm = rss_bytes(), heap_in_use(), len(gc.get_objects())
            warm_seconds = time.monotonic() - start
        if f + 1 == mid:
            soak.settle()
            rss_mid, heap_mid = rss_bytes(), heap_in_use()
        if f + 1 >= warmup and (f + 1 - warmup) % SAMPLE_EVERY == 0:
            samples.append((f + 1, rss_bytes(), heap_in_use() or 0))
        if progress and (f + 1) % 500 == 0:
            print(f"frame {f + 1}: RSS {rss_bytes() / 2**20:.1f} MiB, {time.monotonic() - start:.0f} s",
                  file=sys.stderr, flush=True)
    soak.settle()
    rss_end, heap_end, objects_end = rss_bytes(), heap_in_use(), len(gc.get_objects())
    seconds = time.monotonic() - start
    measured = frames - warmup

    def recurring(warm, middle, end):
        """Growth per frame that both halves of the measured frames show: a
        leak grows memory in each half, while a first use the priming did not
        reach (a kernel's first work size under a combination of plan and frame
        values drawn only now, or a first allocation of that size) is a one-off
        step in one half, which two points alone would count as growth."""
        if warm is None or end is None:
            return None
        if middle is None or mid in (warmup, frames):
            return (end - warm) / measured
        return min((middle - warm) / (mid - warmup), (end - middle) / (frames - mid))

    growth = recurring(rss_warm, rss_mid, rss_end)
    xs = np.array([s[0] for s in samples], np.float64)
    ys = np.array([s[1] for s in samples], np.float64)
    slope = float(np.polyfit(xs, ys, 1)[0]) if len(samples) >= 3 else float("nan")
    result = {
        "frames": frames, "warmup": warmup, "size": [width, height], "seconds": round(seconds, 2),
        "primed_renders": primed, "prime_seconds": round(prime_seconds, 2),
        "warmup_seconds": round(warm_seconds, 2),
        "ms_per_frame": {m: round(1000 * s / max(1, sum(1 for f in range(frames) if chosen[f % len(chosen)] == m)), 2)
                         for m, s in per_method.items()},
        "rss_start_kib": rss_start // 1024, "rss_warm_kib": rss_warm // 1024, "rss_end_kib": rss_end // 1024,
        "rss_max_sampled_kib": int(ys.max()) // 1024 if len(ys) else None,
        "heap_warm_kib": None if heap_warm is None else heap_warm // 1024,
        "heap_end_kib": None if heap_end is None else heap_end // 1024,
        "rss_mid_kib": None if rss_mid is None else rss_mid // 1024,
        "heap_mid_kib": None if heap_mid is None else heap_mid // 1024,
        "heap_growth_bytes_per_frame": None if heap_warm is None else round(recurring(heap_warm, heap_mid, heap_end), 1),
        "heap_total_growth_bytes_per_frame": None if heap_warm is None else round((heap_end - heap_warm) / measured, 1),
        "total_growth_bytes_per_frame": round((rss_end - rss_warm) / measured, 1),
        "growth_bytes_per_frame": round(growth, 1), "slope_bytes_per_frame": round(slope, 1),
        "bound_bytes_per_frame": bound_kib * 1024, "python_objects_warm": objects_warm,
        "python_objects_end": objects_end, "device": soak.ctx.device_name, **soak.counts,
    }
    result["trace_kib"] = [[int(x), int(y) // 1024, int(z) // 1024] for x, y, z in samples]
    soak.close()
    heap_growth = result["heap_growth_bytes_per_frame"]
    result["heap_bound_bytes_per_frame"] = heap_bound_kib * 1024
    result["ok"] = growth <= bound_kib * 1024 and (heap_growth is None or heap_growth <= heap_bound_kib * 1024)
    return result


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--frames", type=int, default=10000)
    ap.add_argument("--warmup", type=int, default=None,
                    help="frames before the RSS baseline (default: 10%% of the frames, 50 to 500)")
    ap.add_argument("--size", default="64x48", help="image WIDTHxHEIGHT (default 64x48)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--methods", default=",".join(METHODS),
                    help=f"methods rendered in turn (default {','.join(METHODS)})")
    ap.add_argument("--bound-kib", type=float, default=1.0, help="largest RSS growth allowed, KiB per frame (1)")
    ap.add_argument("--heap-bound-kib", type=float, default=0.25,
                    help="largest growth of the C heap in use (glibc mallinfo2) allowed, KiB per frame (0.25)")
    ap.add_argument("--json", help="also write the figures to this file")
    ap.add_argument("--progress", action="store_true", help="RSS and time every 500 frames on stderr")
    a = ap.parse_args(argv)
    warmup = a.warmup if a.warmup is not None else max(50, min(500, a.frames // 10))
    if not 0 < warmup < a.frames - SAMPLE_EVERY:
        ap.error(f"--warmup {warmup} must leave at least {SAMPLE_EVERY} measured frames of --frames {a.frames}")
    width, height = (int(v) for v in a.size.lower().split("x"))
    chosen = tuple(m for m in a.methods.split(",") if m)
    result = run(a.frames, warmup, width, height, a.seed, a.bound_kib, a.progress, chosen, a.heap_bound_kib)
    trace = result.pop("trace_kib")
    print(json.dumps(result, indent=1))
    if a.json:
        with open(a.json, "w") as f:
            json.dump({**result, "trace_kib (frame, RSS, heap in use)": trace}, f)
            f.write("\n")
    if not result["ok"]:
        print(f"FAIL: after the warm-up RSS grew {result['growth_bytes_per_frame']:.0f} bytes per frame (bound "
              f"{a.bound_kib:g} KiB), the heap in use {result['heap_growth_bytes_per_frame']} (bound "
              f"{a.heap_bound_kib:g} KiB)", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
