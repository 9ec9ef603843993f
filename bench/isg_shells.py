#!/usr/bin/env python3
"""Thin shells in `isg` (docs/isg.md section 8): a draped open sheet (cloth-like,
two-sided, 2 x 16 x 16 triangles) and a set of 40 small quads (leaf-like, 80
triangles) over a floor, under a sunny and an overcast map, each rendered by
isg with the shell's triangles (pn_sphere_set_create_shell) and with a sphere
set standing for the same geometry (the sheet: 64 spheres over its cells,
radius 0.75 of a cell so the union has no holes; the leaves: one sphere per
leaf of the leaf's area), against the reference renderer (face 64, sun
supersampling 4). Errors: NRMSE and relative RMS over the surface pixels
(floor and shell alike); time: the process's CPU ms of one shading frame,
median of --frames interleaved rounds.

    python bench/isg_shells.py [--res 64x48] [--frames 3]

With --ab OPTIONS: the triangles only, in two contexts of one process, the
second's kernels built with OPTIONS (PENUMBRA_CL_BUILD_OPTIONS, e.g.
-DPN_ISG_SHELL_CAP_COLUMNS=0), frames interleaved: CPU ms of each, the ratio
(median of the per-round ratios) and the largest difference of the images.
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np

from penumbra import Camera, Context, EnvMap, GBuffer, Image, Material, Mesh, Renderer, Scene, procedural
from penumbra.methods.isg import SphereSet
from penumbra.metrics import nrmse, rel_rms


def sheet_mesh(n=16, half=1.0):
    """A draped open sheet: n x n quads over [-half, half]^2, height 1.3 in the middle drooping to 0.8 at
    the corners (vertices, faces)."""
    t = np.linspace(-half, half, n + 1)
    x, z = np.meshgrid(t, t, indexing="ij")
    y = 1.3 - 0.25 * (x * x + z * z) / (half * half)
    v = np.c_[x.ravel(), y.ravel(), z.ravel()]
    f = []
    for i in range(n):
        for j in range(n):
            a, b, c, d = i * (n + 1) + j, (i + 1) * (n + 1) + j, (i + 1) * (n + 1) + j + 1, i * (n + 1) + j + 1
            f += [[a, c, b], [a, d, c]]
    return v.astype(np.float32), np.array(f, np.uint32)


def sheet_spheres(k=8, half=1.0):
    """k x k spheres over the sheet's cells (centres on the surface, radius 0.75 of a cell)."""
    t = -half + (np.arange(k) + 0.5) * (2 * half / k)
    x, z = np.meshgrid(t, t, indexing="ij")
    y = 1.3 - 0.25 * (x * x + z * z) / (half * half)
    return np.c_[x.ravel(), y.ravel(), z.ravel(), np.full(k * k, 0.75 * 2 * half / k)]


def leaves(count=40, size=0.22, seed=3):
    """count small quads of side `size`, random orientations, in a canopy over the floor: (vertices, faces,
    spheres of the same area, one per leaf)."""
    rng = np.random.default_rng(seed)
    v, f, s = [], [], []
    for i in range(count):
        c = np.array([rng.uniform(-1.0, 1.0), rng.uniform(1.0, 1.7), rng.uniform(-1.0, 1.0)])
        nrm = rng.normal(size=3) + [0.0, 1.5, 0.0]
        nrm /= np.linalg.norm(nrm)
        u = np.cross(nrm, [1.0, 0.0, 0.0])
        u /= np.linalg.norm(u)
        w = np.cross(nrm, u)
        h = 0.5 * size
        v += [c - h * u - h * w, c + h * u - h * w, c + h * u + h * w, c - h * u + h * w]
        f += [[4 * i, 4 * i + 1, 4 * i + 2], [4 * i, 4 * i + 2, 4 * i + 3]]
        s.append([*c, size / np.sqrt(np.pi)])
    return np.array(v, np.float32), np.array(f, np.uint32), np.array(s)


def build(ctx, env_rgb, shell, res, face_size=64):
    """Floor and one shell object ("sheet" or "leaves"); returns the scene pieces and both occluder sets."""
    env = EnvMap(ctx, env_rgb, face_size=face_size, irradiance_face_size=16)
    scene = Scene(ctx)
    scene.set_envmap(env)
    floor = procedural.plane((8.0, 8.0), 1)
    fm = Mesh(ctx, floor.vertices, floor.faces)
    floor_id = scene.add(fm, np.eye(4), Material(albedo=(0.6, 0.6, 0.6)))
    if shell == "sheet":
        v, f = sheet_mesh()
        spheres = sheet_spheres()
    else:
        v, f, spheres = leaves()
    sm = Mesh(ctx, v, f)
    shell_id = scene.add(sm, np.eye(4), Material(albedo=(0.7, 0.5, 0.4)))
    scene.set_camera(Camera(position=(0.0, 3.2, 3.6), look_at=(0.0, 0.4, 0.0), fov_deg=55.0, resolution=tuple(res)))
    return {"env": env, "scene": scene, "meshes": (fm, sm), "ids": (floor_id, shell_id),
            "shell": SphereSet.shell(ctx), "spheres": SphereSet.from_spheres(ctx, spheres)}


def ab(a, res, maps) -> None:
    """--ab: this build against the same kernels built with a.ab, on the triangles, interleaved."""
    ctx = Context()
    os.environ["PENUMBRA_CL_BUILD_OPTIONS"] = a.ab
    ctx_b = Context()
    del os.environ["PENUMBRA_CL_BUILD_OPTIONS"]
    print(f"load: {' '.join(f'{x:.1f}' for x in os.getloadavg())} at the start")
    print(f"\n| shell | map | CPU ms: {a.ab} | CPU ms: this build | ratio | max abs image difference |")
    print("|---|---|---|---|---|---|")
    for shell in ("sheet", "leaves"):
        for name, env_rgb in maps.items():
            runs = {}
            for key, c in (("b", ctx_b), ("a", ctx)):
                s = build(c, env_rgb, shell, res)
                s["scene"].attach(s["ids"][1], s["shell"])
                s["scene"].commit()
                gb = GBuffer(c, *res)
                s["scene"].render_gbuffer(gb)
                runs[key] = (c, s, gb, Renderer(c, "isg"), Image(c, *res))
            times = {"a": [], "b": []}
            for rnd in range(a.frames + 1):
                for key in ("b", "a"):
                    c, s, gb, r, img = runs[key]
                    c0 = time.process_time()
                    r.execute(s["scene"], gb, img)
                    c.finish()
                    if rnd:
                        times[key].append(1e3 * (time.process_time() - c0))
            diff = float(np.abs(runs["a"][4].read() - runs["b"][4].read()).max())
            ratio = float(np.median(np.array(times["b"]) / np.array(times["a"])))
            print(f"| {shell} | {name} | {np.median(times['b']):.0f} | {np.median(times['a']):.0f} | {ratio:.2f} | "
                  f"{diff:.3g} |", flush=True)
    print(f"\nload: {' '.join(f'{x:.1f}' for x in os.getloadavg())} at the end (loaded)")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--res", default="64x48")
    ap.add_argument("--frames", type=int, default=3)
    ap.add_argument("--ab", default=None, help="kernel build options of the B side (see above)")
    a = ap.parse_args()
    res = [int(x) for x in a.res.split("x")]
    maps = {"sunny": procedural.sky(128, 64, sun_radiance=2000.0, sun_angular_radius_deg=3.0),
            "overcast": procedural.sky(128, 64, sun_radiance=0.0)}
    if a.ab:
        return ab(a, res, maps)
    ctx = Context()
    print(f"load: {os.getloadavg()[0]:.1f} (1-min average) at the start")
    print("\n| shell | map | occluder | NRMSE | rel RMS | CPU ms | CPU / spheres |")
    print("|---|---|---|---|---|---|---|")
    for shell in ("sheet", "leaves"):
        for name, env_rgb in maps.items():
            s = build(ctx, env_rgb, shell, res)
            gb = GBuffer(ctx, *res)
            s["scene"].commit()
            s["scene"].render_gbuffer(gb)
            mask = gb.read("instance") != 0xFFFFFFFF
            ref_img = Image(ctx, *res)
            Renderer(ctx, "reference", face_size=64, sun_supersampling=4).execute(s["scene"], gb, ref_img)
            ref = ref_img.read()[..., :3].astype(np.float64)
            rows, imgs, times = {}, {}, {"triangles": [], "spheres": []}
            r = Renderer(ctx, "isg")
            for rnd in range(a.frames + 1):
                for kind in ("triangles", "spheres"):
                    s["scene"].attach(s["ids"][1], s["shell"] if kind == "triangles" else s["spheres"])
                    s["scene"].commit()
                    img = Image(ctx, *res)
                    c0 = time.process_time()
                    r.execute(s["scene"], gb, img)
                    ctx.finish()
                    if rnd:
                        times[kind].append(1e3 * (time.process_time() - c0))
                    imgs[kind] = img.read()[..., :3].astype(np.float64)
            for kind in ("triangles", "spheres"):
                rows[kind] = (nrmse(ref, imgs[kind], mask), rel_rms(ref, imgs[kind], mask),
                              float(np.median(times[kind])),
                              float(np.median(np.array(times[kind]) / np.array(times["spheres"]))))
                e1, e2, ms, ratio = rows[kind]
                print(f"| {shell} | {name} | {kind} | {100 * e1:.2f} % | {100 * e2:.2f} % | {ms:.0f} | {ratio:.2f} |",
                      flush=True)
    print(f"\nload: {os.getloadavg()[0]:.1f} at the end (loaded)")


if __name__ == "__main__":
    main()
