"""A/B timing of the isg shading kernel (kernels/isg.cl) on the bunny-on-a-floor
scene of bench/isg_experiments.py: the G-buffer, lobes and world spheres are
taken from the library once, then kernel variants (compile-time defines or
source patches) are timed on the same inputs in one process, against the
floor kernel. docs/isg.md section 9.

    python bench/isg_speed.py [--sizes 100x100,160x120] [--spheres 50,300] [--reps 2] [--old-kernels DIR]

Row mode (docs/isg.md section 9, "The issue's rows at today's defaults"): the
library's defaults on a scene file (or `fig12`, the scene above), at each size
and sphere count, in one process: frame time (G-buffer + shading; wall and the
process's CPU, floor frames interleaved with the isg frames round by round),
the ratio to the floor kernel, the error against the reference (face 64, sun
supersampling 4, cached under --out), the spheres in front of each receiver
(the shared hemisphere grid's cone) on a sample of pixels, and Mitsuba 3's
curve over --spp with the speed-up at equal error (penumbra.bench's rule):

    python bench/isg_speed.py --rows --scene bench/scenes/bunny_sunny.toml \
        --sizes 400x400,640x480 --spheres 50,300 --spp 128,256,512,1024
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

def world_spheres(built):
    """The attached sphere sets in world space: (spheres (N, 4) float64, owner instance ids)."""
    sph, own = [], []
    for name, sset in state(built).sets.items():
        s = sset.spheres().astype(np.float64) if hasattr(sset, "spheres") else None
        if s is None or len(s) == 0:
            continue
        m = built.desc.objects[[o.name for o in built.desc.objects].index(name)].transform()
        sc = max(np.linalg.norm(m[:3, c]) for c in range(3))
        sph.append(np.c_[s[:, :3] @ m[:3, :3].T + m[:3, 3], s[:, 3] * sc])
        own += [built.instance_ids[name]] * len(s)
    if not sph:
        return np.zeros((0, 4)), np.zeros(0, np.uint32)
    return np.vstack(sph), np.array(own, np.uint32)


def spheres_in_front(planes, spheres, owners, sample=2000, margin=0.02, seed=0):
    """Mean over a sample of surface pixels of the spheres the shared hemisphere grid marks with: not wholly
    behind the receiver plane, and not an own sphere skipped by self_occlusion 1 (within 1 + margin of its
    radius). The per-lobe windows' cones hold fewer."""
    inst = planes["instance"].reshape(-1)
    idx = np.flatnonzero(inst != 0xFFFFFFFF)
    if len(spheres) == 0 or len(idx) == 0:
        return 0.0
    idx = np.random.default_rng(seed).choice(idx, min(sample, len(idx)), replace=False)
    p = planes["position"].reshape(-1, 4)[idx, :3].astype(np.float64)
    n = planes["normal"].reshape(-1, 4)[idx, :3].astype(np.float64)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    v = spheres[None, :, :3] - p[:, None, :]
    r = spheres[None, :, 3]
    front = np.einsum("pso,po->ps", v, n) > -r
    own = owners[None, :] == inst[idx][:, None]
    skipped = own & (np.einsum("pso,pso->ps", v, v) <= (r * (1 + margin)) ** 2)
    return float((front & ~skipped).sum(axis=1).mean())


def rows_mode(a) -> None:
    """The issue's speed rows at the library's defaults (module docstring)."""
    from penumbra import Context
    from penumbra.bench import BenchOptions, _mitsuba_time_at, _run_mitsuba, ground_truth
    from penumbra.metrics import compare
    from penumbra.scenefile import load_scene

    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    counts = [int(x) for x in a.spheres.split(",")]
    spp = tuple(int(x) for x in a.spp.split(",")) if a.spp else ()
    rows = []
    log = lambda m: print(m, flush=True)  # noqa: E731
    log(f"load {' '.join(f'{x:.1f}' for x in os.getloadavg())} at the start")
    for size in a.sizes.split(","):
        res = tuple(int(x) for x in size.split("x"))
        if a.scene == "fig12":
            from isg_experiments import bunny_scene
            desc = parse_scene(copy.deepcopy(bunny_scene(res, ks_bunny=0.5, ks_floor=0.5)), ".")
        else:
            desc = load_scene(a.scene, [f"camera.resolution=[{res[0]},{res[1]}]"])
        ctx = Context()
        built = build_scene(desc, ctx)
        sets = {}
        for n in counts:
            attach_sphere_sets(built, {"spheres": n})
            sets[n] = (dict(state(built).sets), world_spheres(built))
        gb, img = GBuffer(ctx, *res), Image(ctx, *res)
        built.scene.render_gbuffer(gb)
        ctx.finish()
        planes = {p: gb.read(p) for p in ("position", "normal", "albedo", "material", "instance")}
        mask = planes["instance"] != 0xFFFFFFFF
        surf = int(mask.sum())
        floor, isg = Renderer(ctx, "floor"), Renderer(ctx, "isg")

        def attach(n):
            for name, sset in sets[n][0].items():
                built.scene.attach(built.instance_ids[name], sset)
            built.scene.commit()

        def frame(renderer):
            t0, c0 = time.perf_counter(), time.process_time()
            renderer.execute(built.scene, gb, img)
            ctx.finish()
            return 1e3 * (time.perf_counter() - t0), 1e3 * (time.process_time() - c0)

        gtimes = []
        for _ in range(5):
            t0 = time.perf_counter()
            built.scene.render_gbuffer(gb)
            ctx.finish()
            gtimes.append(1e3 * (time.perf_counter() - t0))
        g_ms = float(np.median(gtimes))
        images, wall, cpu, fl_wall, fl_cpu = {}, {n: [] for n in counts}, {n: [] for n in counts}, [], []
        frame(floor)
        for n in counts:  # warm-up and the image
            attach(n)
            frame(isg)
            images[n] = img.read()[..., :3].copy()
        loads = [os.getloadavg()[0]]
        for _ in range(a.rounds):
            for _ in range(3):
                w, c = frame(floor)
                fl_wall.append(w), fl_cpu.append(c)
            for n in counts:
                attach(n)
                frame(isg)  # the first frame after an attach builds the tree's buffers
                w, c = frame(isg)
                wall[n].append(w), cpu[n].append(c)
            loads.append(os.getloadavg()[0])
        fw, fc = float(np.median(fl_wall)), float(np.median(fl_cpu))
        log(f"{res}: {surf} surface pixels, G-buffer {g_ms:.2f} ms, floor {fw:.3f} ms wall, {fc:.3f} ms CPU; "
            f"load {min(loads):.1f}-{max(loads):.1f}")
        truth = curve = None
        if not a.no_truth:
            t0 = time.perf_counter()
            truth = ground_truth(built, desc, BenchOptions(), out / "cache", log)
            log(f"  truth {time.perf_counter() - t0:.0f} s")
        if truth is not None and spp:
            curve = _run_mitsuba(desc, BenchOptions(spp=spp), truth, mask, log)["curve"]
        for n in counts:
            sw, sc = float(np.median(wall[n])), float(np.median(cpu[n]))
            err = compare(truth, images[n], mask) if truth is not None else {"nrmse": float("nan"),
                                                                             "rel_rms": float("nan")}
            speed = ""
            if curve:
                t, bound = _mitsuba_time_at(curve, err["nrmse"])
                speed = f"{bound}{t / (g_ms + sw):.3g}"
            front = spheres_in_front(planes, *sets[n][1])
            row = dict(res=res, n=n, spheres=len(sets[n][1][0]), surf=surf, front=front, g_ms=g_ms, wall=sw,
                       cpu=sc, floor_wall=fw, floor_cpu=fc, nrmse=err["nrmse"], rel_rms=err["rel_rms"],
                       speed=speed, load=(min(loads), max(loads)))
            rows.append(row)
            log(f"  N {n} ({row['spheres']} spheres, {front:.1f} in front per pixel): wall {sw:.1f} ms, CPU "
                f"{sc:.1f} ms, x floor {sw / fw:.0f} (wall) {sc / max(fc, 1e-9):.0f} (CPU), NRMSE "
                f"{err['nrmse']:.4f}, rel RMS {err['rel_rms']:.4f}, over Mitsuba {speed or '-'}")
        if curve:
            log("  mitsuba: " + ", ".join(f"{c['params']['spp']} spp {c['time_ms']:.0f} ms NRMSE {c['nrmse']:.4f}"
                                          for c in curve))
    log(f"load {' '.join(f'{x:.1f}' for x in os.getloadavg())} at the end")
    print("\n| pixels | surface px | N | spheres in front per px | frame ms (G-buffer + shading, wall) | shading CPU ms "
          "| x floor (wall) | x floor (CPU) | CPU ns per px x sphere in front | NRMSE | rel RMS | over Mitsuba at "
          "equal error | load |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['res'][0]} x {r['res'][1]} | {r['surf']} | {r['n']} | {r['front']:.1f} | "
              f"{r['g_ms'] + r['wall']:.1f} | {r['cpu']:.1f} | {r['wall'] / r['floor_wall']:.0f} | "
              f"{r['cpu'] / max(r['floor_cpu'], 1e-9):.0f} | {1e6 * r['cpu'] / (r['surf'] * max(r['front'], 1e-9)):.0f} | "
              f"{r['nrmse']:.4f} | {r['rel_rms']:.4f} | {r['speed'] or '-'} | {r['load'][0]:.1f}-{r['load'][1]:.1f} |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sizes", default="100x100,160x120")
    ap.add_argument("--spheres", default="50,300")
    ap.add_argument("--reps", type=int, default=2)
    ap.add_argument("--old-kernels", default=None,
                    help="another version's kernels/ folder (git archive COMMIT kernels | tar -x -C DIR) timed too")
    ap.add_argument("--no-flat", action="store_true",
                    help="with --old-kernels: only the old kernel against the library's default, interleaved")
    ap.add_argument("--rows", action="store_true", help="the issue's rows at the library's defaults (docstring)")
    ap.add_argument("--scene", default="bench/scenes/bunny_sunny.toml", help="--rows: a scene file, or fig12")
    ap.add_argument("--rounds", type=int, default=3, help="--rows: interleaved rounds")
    ap.add_argument("--spp", default="128,256,512,1024", help="--rows: Mitsuba's spp ('' for none)")
    ap.add_argument("--no-truth", action="store_true", help="--rows: times only (no reference, no Mitsuba)")
    ap.add_argument("--out", default="bench/results/isg/rows_truth",
                    help="--rows: the truth is cached in OUT/cache (git-ignored)")
    a = ap.parse_args()
    if a.rows:
        return rows_mode(a)
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
