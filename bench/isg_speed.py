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
            extra_args=(), count=None, use_tree=1, kernels=None):
        """kernels: another version's kernels/ folder, whose shade_isg has no tree arguments (before the tree)."""
        k = cl.Kernel(self.program(defines, patch, kernels), "shade_isg")
        b = self.bufs
        args = [b[0], b[1], b[2], b[3], b[4], np.int32(self.n), self.cube, np.int32(self.face), self.lobes,
                np.int32(self.k), self.spheres, self.owners, np.int32(self.count if count is None else count),
                *(() if kernels else (self.nodes, np.int32(use_tree))), np.int32(grid),
                np.int32(self_occlusion), np.int32(specular_shadows), np.float32(env_sharpness), self.camera,
                self.table, self.out, *extra_args]
        self.queue.finish()
        t0 = time.perf_counter()
        k(self.queue, (self.n,), (64,) if self.n % 64 == 0 else None, *args)
        self.queue.finish()
        dt = time.perf_counter() - t0
        img = np.empty((self.n, 4), np.float32)
        cl.enqueue_copy(self.queue, img, self.out)
        return 1e3 * dt, img
