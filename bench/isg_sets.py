#!/usr/bin/env python3
"""Sphere sets against their meshes, measured independently of the builder's
grid (docs/isg.md section 7, "The tighter set"): for each mesh and N,

  outside / missed   the union's volume outside the solid and the solid's volume
                     outside the union, shares of the solid (Monte Carlo,
                     200 000 points, inside by libigl's winding number);
  poke               how far the union's surface lies outside the mesh (64
                     points per sphere on its part of the union's surface,
                     libigl signed distance): mean and 95th percentile, share
                     of the bounding-box diagonal;
  uncovered          how far mesh surface points lie outside every sphere
                     (20 000 area-weighted points): mean and 95th percentile;
  rays               binary shadow error: 100 000 random lines through the
                     bounding sphere; of those the mesh blocks, the share the
                     union blocks and the mesh does not (false shadow) and the
                     share the mesh blocks and the union does not (missed).

The sets are the loaded library's (`pn_sphere_set_build`); for a before /
after table run it once per library (PENUMBRA_LIBRARY=...).

    python bench/isg_sets.py [--meshes bunny_odedstein_3k,...] [--counts 8,16,...]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import harness  # noqa: E402

MESHES = "bunny_odedstein_3k,teapot_ajacobson,armadillo_odedstein"
COUNTS = "8,16,32,64,128,256,512"


class MeshGeo:
    """One mesh's samples: volume points (inside by winding number), surface points, random lines."""

    def __init__(self, v, f, seed=7, nvol=200_000, nray=100_000, nsurf=20_000):
        import igl
        from embreex import rtcore_scene as rtcs
        from embreex.mesh_construction import TriangleMesh
        self.v = np.asarray(v, np.float64)
        self.f = np.asarray(f, np.int64)
        lo, hi = self.v.min(0), self.v.max(0)
        self.diag = float(np.linalg.norm(hi - lo))
        rng = np.random.default_rng(seed)
        pad = 0.15 * (hi - lo).max()
        self.p = rng.uniform(lo - pad, hi + pad, (nvol, 3))
        self.inside = igl.fast_winding_number(self.v, self.f, self.p) > 0.5
        a, b, c = (self.v[self.f[:, i]] for i in range(3))
        area = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)
        t = rng.choice(len(self.f), nsurf, p=area / area.sum())
        u, w = rng.random(nsurf), rng.random(nsurf)
        flip = u + w > 1
        u[flip], w[flip] = 1 - u[flip], 1 - w[flip]
        self.surf = a[t] + u[:, None] * (b[t] - a[t]) + w[:, None] * (c[t] - a[t])
        # random lines through the bounding sphere: uniform directions, offsets uniform in its disc
        cen, big = 0.5 * (lo + hi), 0.5 * self.diag * 1.05
        d = rng.normal(size=(nray, 3))
        d /= np.linalg.norm(d, axis=1)[:, None]
        e1 = np.cross(d, [0.3, 0.5, 0.81])
        e1 /= np.linalg.norm(e1, axis=1)[:, None]
        e2 = np.cross(d, e1)
        r, ph = big * np.sqrt(rng.random(nray)), 2 * np.pi * rng.random(nray)
        self.ro = cen - 2 * big * d + (r * np.cos(ph))[:, None] * e1 + (r * np.sin(ph))[:, None] * e2
        self.rd = d
        scene = rtcs.EmbreeScene()
        TriangleMesh(scene, self.v[self.f].astype(np.float32))
        self.hit = scene.run(self.ro.astype(np.float32), self.rd.astype(np.float32)) >= 0

    def measure(self, spheres) -> dict:
        import igl
        s = np.asarray(spheres, np.float64)
        chunks = [(k, s[k:k + 64]) for k in range(0, len(s), 64)]
        cov = np.zeros(len(self.p), bool)
        du = np.full(len(self.surf), np.inf)
        hit_s = np.zeros(len(self.ro), bool)
        for _, q in chunks:
            cov |= (((self.p[:, None, :] - q[None, :, :3]) ** 2).sum(-1) <= q[None, :, 3] ** 2).any(1)
            gap = np.sqrt(((self.surf[:, None, :] - q[None, :, :3]) ** 2).sum(-1)) - q[None, :, 3]
            du = np.minimum(du, gap.min(1))
            oc = self.ro[:, None, :] - q[None, :, :3]
            b = (oc * self.rd[:, None, :]).sum(-1)
            hit_s |= ((b * b - (oc ** 2).sum(-1) + q[None, :, 3] ** 2) >= 0).any(1)
        du = np.maximum(du, 0.0)
        # points of the union's surface: on a sphere, inside no other
        rng = np.random.default_rng(3)
        dirs = rng.normal(size=(len(s), 64, 3))
        dirs /= np.linalg.norm(dirs, axis=2)[..., None]
        pts = (s[:, None, :3] + s[:, None, 3:4] * dirs).reshape(-1, 3)
        owner = np.repeat(np.arange(len(s)), 64)
        on = np.ones(len(pts), bool)
        for k, q in chunks:
            d = np.sqrt(((pts[:, None, :] - q[None, :, :3]) ** 2).sum(-1)) - q[None, :, 3]
            d[owner[:, None] == np.arange(k, k + len(q))[None, :]] = 1.0
            on &= ~(d < -1e-9).any(1)
        poke = np.maximum(igl.signed_distance(pts[on], self.v, self.f)[0], 0.0)
        nin, nh = self.inside.sum(), self.hit.sum()
        return {"outside": (cov & ~self.inside).sum() / nin, "missed": (self.inside & ~cov).sum() / nin,
                "poke_mean": poke.mean() / self.diag, "poke_p95": np.percentile(poke, 95) / self.diag,
                "uncov_mean": du.mean() / self.diag, "uncov_p95": np.percentile(du, 95) / self.diag,
                "ray_false_block": (hit_s & ~self.hit).sum() / nh, "ray_false_pass": (self.hit & ~hit_s).sum() / nh}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--meshes", default=MESHES)
    ap.add_argument("--counts", default=COUNTS)
    a = ap.parse_args()
    from penumbra import Context, Mesh
    from penumbra.meshio import load_mesh
    from penumbra.methods.isg import SphereSet
    ctx = Context()
    print("| mesh | N | outside | missed | poke mean / p95 (% diag) | uncovered mean / p95 (% diag) "
          "| rays: false / missed shadow | build CPU s |")
    print("|---|---|---|---|---|---|---|---|")
    for name in a.meshes.split(","):
        d = load_mesh(harness.REPO.parent / "shared" / "data" / "meshes" / f"{name}.obj")
        geo = MeshGeo(d.vertices, d.faces)
        mesh = Mesh(ctx, d.vertices, d.faces)
        for n in (int(x) for x in a.counts.split(",")):
            s = SphereSet.build(mesh, n)
            m = geo.measure(s.spheres())
            p = {k: 100 * v for k, v in m.items()}
            print(f"| {name} | {n} | {p['outside']:.1f} % | {p['missed']:.1f} % | {p['poke_mean']:.2f} / "
                  f"{p['poke_p95']:.2f} | {p['uncov_mean']:.2f} / {p['uncov_p95']:.2f} | {p['ray_false_block']:.1f} / "
                  f"{p['ray_false_pass']:.1f} % | {s.info()['build_seconds']:.2f} |", flush=True)


if __name__ == "__main__":
    main()
