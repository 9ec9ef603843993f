"""A/B timing of the isg shading kernel (kernels/isg.cl) on the bunny-on-a-floor
scene of bench/isg_experiments.py: the G-buffer, lobes and world spheres are
taken from the library once, then kernel variants (compile-time defines or
source patches) are timed on the same inputs in one process, against the
floor kernel. docs/isg.md section 9.

    python bench/isg_speed.py [--res 64x48] [--spheres 50] [--variants a,b] [--reps 1]
"""

from __future__ import annotations

import argparse
import copy
import os
import sys
import time
from pathlib import Path

import numpy as np
import pyopencl as cl

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "bench"))

import penumbra.kernels as pk  # noqa: E402
from penumbra import GBuffer, Image, Renderer  # noqa: E402
from penumbra.render import build_scene  # noqa: E402
from penumbra.scenefile import parse_scene  # noqa: E402
from penumbra.methods.isg import attach_sphere_sets, sphere_tree, state  # noqa: E402

pk.kernel_dir = lambda: REPO / "kernels"  # the working tree's kernels, not the installed ones


def scene(ctx, res, spheres, ks=0.5):
    from isg_experiments import bunny_scene  # noqa: E402
    built = build_scene(parse_scene(copy.deepcopy(bunny_scene(res, ks_bunny=ks, ks_floor=ks)), "."), ctx)
    attach_sphere_sets(built, {"spheres": spheres})
    gb = GBuffer(ctx, *res)
    built.scene.render_gbuffer(gb)
    planes = {p: gb.read(p) for p in ("position", "normal", "albedo", "material", "instance")}
    sph, own = [], []
    for name, sset in state(built).sets.items():
        m = built.desc.objects[[o.name for o in built.desc.objects].index(name)].transform()
        sc = max(np.linalg.norm(m[:3, c]) for c in range(3))
        s = sset.spheres().astype(np.float64)
        w = s[:, :3] @ m[:3, :3].T + m[:3, 3]
        sph.append(np.c_[w, s[:, 3] * sc])
        own += [built.instance_ids[name]] * len(s)
    return built, gb, planes, np.vstack(sph).astype(np.float32), np.array(own, np.uint32)


def floor_ms(built, gb, res, reps=5):
    img = Image(built.ctx, *res)
    r = Renderer(built.ctx, "floor")
    r.execute(built.scene, gb, img)
    built.ctx.finish()
    ts = []
    for _ in range(reps):
        t0 = time.perf_counter()
        r.execute(built.scene, gb, img)
        built.ctx.finish()
        ts.append(time.perf_counter() - t0)
    return 1e3 * float(np.median(ts))


class Kernel:
    def __init__(self, ctx, built, planes, spheres, owners, lobes_k=32):
        self.cl_ctx, self.queue = ctx.cl_objects()
        mf = cl.mem_flags
        ro = lambda a: cl.Buffer(self.cl_ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=np.ascontiguousarray(a))  # noqa: E731
        self.n = planes["instance"].size
        self.bufs = [ro(planes[p].reshape(self.n, -1)) for p in ("position", "normal", "albedo", "material")]
        self.bufs.append(ro(planes["instance"].reshape(-1)))
        cube = built.envmap.cube_radiance()
        c4 = np.zeros(cube.shape[:3] + (4,), np.float32)
        c4[..., :3] = cube
        self.cube, self.face = ro(c4), cube.shape[1]
        lobes = built.envmap.fit_sgs(lobes_k)
        self.lobes, self.k = ro(lobes), len(lobes)
        spheres, owners, nodes = sphere_tree(spheres, owners)
        self.spheres, self.owners, self.count, self.nodes = ro(spheres), ro(owners), len(spheres), ro(nodes)
        self.host_spheres, self.host_owners = spheres, owners
        t = np.empty(4 * 57 * 33, np.float32)
        from penumbra._native import call
        call("pn_isg_table", None, t.ctypes.data, t.size)
        self.table = ro(t)
        self.out = cl.Buffer(self.cl_ctx, mf.WRITE_ONLY, 16 * self.n)
        self.camera = np.array([*built.desc.camera.position, 0.0], np.float32)
        self.programs = {}

    def program(self, defines=(), patch=None, kernels=None):
        key = (tuple(defines), patch, kernels)
        if key not in self.programs:
            if kernels:  # another version's kernels/ (e.g. git archive of a commit)
                pk.kernel_dir = lambda: Path(kernels)
            src = pk.expand("common/math.cl", '#include "isg.cl"\n')
            pk.kernel_dir = lambda: REPO / "kernels"
            if patch:
                src = patch(src)
            opts = ["-cl-std=CL1.2"] + [f"-D{d}" for d in defines]
            self.programs[key] = cl.Program(self.cl_ctx, src).build(options=opts)
        return self.programs[key]

    def run(self, defines=(), patch=None, grid=16, self_occlusion=1, specular_shadows=1, env_sharpness=100.0,
            extra_args=(), count=None, use_tree=1, kernels=None, tree_args=None, lod=0.0):
        """kernels: another version's kernels/ folder; tree_args: whether its shade_isg takes the tree's
        arguments (default: only the working tree's)."""
        k = cl.Kernel(self.program(defines, patch, kernels), "shade_isg")
        b = self.bufs
        args = [b[0], b[1], b[2], b[3], b[4], np.int32(self.n), self.cube, np.int32(self.face), self.lobes,
                np.int32(self.k), self.spheres, self.owners, np.int32(self.count if count is None else count),
                *((self.nodes, np.int32(use_tree)) if (tree_args if tree_args is not None else not kernels) else ()),
                # the LOD cut and no thin-shell triangles (this version's kernel only)
                *((np.float32(lod), self.table, self.table, np.int32(0)) if not kernels else ()),
                np.int32(grid),
                np.int32(self_occlusion), np.int32(specular_shadows), np.float32(env_sharpness), self.camera,
                self.table,
                # specular_mode 0 (the patches; Gamma_L unread: the table stands in for its buffers)
                *((np.int32(0), self.table, self.table, np.int32(1), np.float32(1.0)) if not kernels else ()),
                # shared_grid 0: the per-lobe windows (the lobe cubes unread: the table stands in for them)
                *((np.int32(0), np.float32(200.0), self.table, np.int32(2)) if not kernels else ()),
                self.out, *extra_args]
        self.queue.finish()
        t0, c0 = time.perf_counter(), time.process_time()
        k(self.queue, (self.n,), (64,) if self.n % 64 == 0 else None, *args)
        self.queue.finish()
        dt, dc = time.perf_counter() - t0, time.process_time() - c0
        img = np.empty((self.n, 4), np.float32)
        cl.enqueue_copy(self.queue, img, self.out)
        return 1e3 * dt, img, 1e3 * dc


def library_ms(built, gb, res, reps, **params):
    """One isg frame through the library (Renderer.execute: spheres to world space, the tree, the
    kernel), after a warm-up frame: (wall ms, CPU ms of the process, all its threads: PoCL's
    included; the A/B measure on a shared machine, where wall time depends on the others' load),
    each the minimum of `reps`, and the image."""
    img = Image(built.ctx, *res)
    r = Renderer(built.ctx, "isg", **params)
    r.execute(built.scene, gb, img)
    built.ctx.finish()
    ts, cpu = [], []
    for _ in range(reps):
        t0, c0 = time.perf_counter(), time.process_time()
        r.execute(built.scene, gb, img)
        built.ctx.finish()
        ts.append(time.perf_counter() - t0), cpu.append(time.process_time() - c0)
    return 1e3 * min(ts), 1e3 * min(cpu), img.read()


def interleaved(built, gb, res, k, reps, old_kernels, **params):
    """A/B in one process, rounds interleaved (A B A B ...) after a warm-up of each, medians of `reps`:
    A the kernel of another version (`old_kernels`) on the same inputs through pyopencl, B a library
    frame (Renderer.execute). Returns ((wall, CPU) of A, (wall, CPU) of B, B's image); CPU is the
    process's CPU time (PoCL's threads included), the measure least moved by others' load."""
    img = Image(built.ctx, *res)
    r = Renderer(built.ctx, "isg", **params)
    r.execute(built.scene, gb, img)
    built.ctx.finish()
    k.run(kernels=old_kernels, tree_args=True)
    a, b = [], []
    for _ in range(reps):
        t = k.run(kernels=old_kernels, tree_args=True)
        a.append((t[0], t[2]))
        t0, c0 = time.perf_counter(), time.process_time()
        r.execute(built.scene, gb, img)
        built.ctx.finish()
        b.append((1e3 * (time.perf_counter() - t0), 1e3 * (time.process_time() - c0)))
    med = lambda xs, i: float(np.median([x[i] for x in xs]))  # noqa: E731
    return (med(a, 0), med(a, 1)), (med(b, 0), med(b, 1)), img.read()



def cases(ctx, a):
    """(resolution, built, G-buffer, planes, spheres, owners, floor ms) for every
    --sizes x --spheres pair, the scene built and the floor timed once each."""
    for size in a.sizes.split(","):
        res = tuple(int(x) for x in size.split("x"))
        for n in (int(x) for x in a.spheres.split(",")):
            built, gb, planes, sph, own = scene(ctx, res, n)
            yield (res, built, gb, planes, sph, own, floor_ms(built, gb, res))

def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sizes", default="100x100,160x120")
    ap.add_argument("--spheres", default="50,300")
    ap.add_argument("--reps", type=int, default=2)
    ap.add_argument("--old-kernels", default=None,
                    help="another version's kernels/ folder (git archive COMMIT kernels | tar -x -C DIR) timed too")
    ap.add_argument("--no-flat", action="store_true",
                    help="with --old-kernels: only the old kernel against the library's default, interleaved")
    a = ap.parse_args()
    from penumbra import Context
    ctx = Context()
    rows = []
    if a.no_flat:
        print(f"load {os.getloadavg()[0]:.1f} at the start", flush=True)
        for res, built, gb, planes, sph, own, fl in cases(ctx, a):
            k = Kernel(ctx, built, planes, sph, own)
            (wa, ca), (wb, cb), img = interleaved(built, gb, res, k, a.reps, a.old_kernels)
            surf = int((planes["instance"] != 0xFFFFFFFF).sum())
            rows.append((res, len(sph), surf, ca, cb, wa, wb, fl))
            print(f"{res} {len(sph)} spheres: old wall {wa:.0f} CPU {ca:.0f} | new wall {wb:.0f} CPU {cb:.0f} | "
                  f"floor {fl:.3f} ms | load {os.getloadavg()[0]:.1f}", flush=True)
        print("\n| pixels | surface pixels | spheres | CPU ms: old | new | old / new | wall ms: new | floor ms | "
              "new x floor (wall) | new CPU us per surface pixel |")
        print("|---|---|---|---|---|---|---|---|---|---|")
        for res, n, surf, ca, cb, wa, wb, fl in rows:
            print(f"| {res[0]} x {res[1]} | {surf} | {n} | {ca:.0f} | {cb:.0f} | {ca / cb:.2f} | {wb:.0f} | {fl:.3f} | "
                  f"{wb / fl:.0f} | {1e3 * cb / surf:.1f} |")
        return
    for res, built, gb, planes, sph, own, fl in cases(ctx, a):
        t_old = c_old = None
        if a.old_kernels:
            k = Kernel(ctx, built, planes, sph, own)
            k.run(kernels=a.old_kernels)
            runs = [k.run(kernels=a.old_kernels) for _ in range(a.reps)]
            t_old, c_old = min(r[0] for r in runs), min(r[2] for r in runs)
        flat, c_flat, img_flat = library_ms(built, gb, res, a.reps, sphere_tree=0)
        tree, c_tree, img_tree = library_ms(built, gb, res, a.reps, sphere_tree=1)
        same = bool(np.array_equal(img_flat, img_tree))
        rows.append((res, len(sph), c_old, c_flat, c_tree, fl, tree, same))
        print(f"{res} {len(sph)} spheres: wall old {t_old} flat {flat:.1f} tree {tree:.1f} floor {fl:.3f} ms; "
              f"CPU old {c_old} flat {c_flat:.1f} tree {c_tree:.1f} ms; same image {same}", flush=True)
    print("\n| pixels | spheres | CPU ms: old kernel | flat | tree | old / tree | wall ms: tree | floor | "
          "tree x floor | same image |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for res, n, old, flat, tree, fl, wall, same in rows:
        o = f"{old:.0f}" if old else "-"
        sp = f"{old / tree:.2f}" if old else f"{flat / tree:.2f} (flat)"
        print(f"| {res[0]} x {res[1]} | {n} | {o} | {flat:.0f} | {tree:.0f} | {sp} | {wall:.0f} | {fl:.3f} | "
              f"{wall / fl:.0f} | {same} |")


if __name__ == "__main__":
    main()
