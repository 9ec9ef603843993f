"""The "oracle" diagnostics of bench/fiv_experiments.py: fiv's formulas
evaluated in Python with the exact occlusion at each pixel (ray casting
against the occluders over the bake's own directions) instead of the
interpolated grid, which splits an experiment's error into the grid's part
and the formula's part.

An oracle is a function (G-buffer planes, evaluated mask, unshadowed
irradiance) -> [(label, image)], given to the runner's evaluate(), whose rows
it adds (marked * in the report, no renderer output).

Penumbra functions used: penumbra.core.EnvMap (cube_directions,
cube_radiance), penumbra.core.Scene (add, commit, occluded) and
penumbra.methods.fiv.FivField.info.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from penumbra.core import Context, EnvMap, Mesh, Scene
from penumbra.methods.fiv import FivField

if TYPE_CHECKING:
    from fiv_experiments import Built, Runner

LUMA = np.array([0.2126, 0.7152, 0.0722])


def bake_directions(ctx: Context, latlong: np.ndarray, face: int = 32, ss: int = 4, threshold: float = 0.1):
    """The bake's direction records (pn_envmap_direction_records): the cube of
    `face` with exact solid angles; texels whose power reaches `threshold` of
    the brightest split into ss x ss sub-texels of the cube of face*ss; black
    texels dropped. Returns (M, 3) directions and (M, 3) radiance x solid angle."""
    coarse = EnvMap(ctx, latlong, face_size=face)
    d1, w1 = coarse.cube_directions()
    l1 = coarse.cube_radiance()
    fine = EnvMap(ctx, latlong, face_size=face * ss)
    d2, w2 = fine.cube_directions()
    l2 = fine.cube_radiance()
    power = (l1 @ LUMA) * w1
    split = power >= threshold * power.max()
    keep = ~split & np.any(l1 != 0, axis=-1)
    dirs, weights = [d1[keep]], [l1[keep] * w1[keep][:, None]]
    for f, j, i in zip(*np.nonzero(split)):
        sl = (f, slice(j * ss, (j + 1) * ss), slice(i * ss, (i + 1) * ss))
        dd, ww, ll = d2[sl].reshape(-1, 3), w2[sl].reshape(-1), l2[sl].reshape(-1, 3)
        nz = np.any(ll != 0, axis=1)
        dirs.append(dd[nz])
        weights.append(ll[nz] * ww[nz][:, None])
    return np.concatenate(dirs).astype(np.float64), np.concatenate(weights).astype(np.float64)


def oracle_irradiance(ctx: Context, occluders: list[tuple[Mesh, np.ndarray]], spheres: list[tuple], P: np.ndarray,
                      N: np.ndarray, dirs: np.ndarray, weights: np.ndarray, offset: float, self_mode: bool = False,
                      batch: int = 1024) -> dict:
    """Exact occluded irradiance at points P (normals N) from ray casting
    against `occluders` only, over the bake's directions:

      signed[c]   = sum over hit directions of w_c (N . w)        (N . FIV_occ exactly)
      positive[c] = the same over hit directions with N . w > 0  (FIV+ of the paper)
      visible[c]  = sum over unhit directions with N . w > 0     (self mode: the lower
                    hemisphere counts as occluded, as in the fullsphere identity)

    Only directions inside some occluder's bounding cone are traced (as in the bake)."""
    scene = Scene(ctx)
    for mesh, T in occluders:
        scene.add(mesh, T)
    scene.commit()
    n = len(P)
    signed, positive, upper, full = (np.zeros((n, 3)) for _ in range(4))
    for b0 in range(0, n, batch):
        p, nn = P[b0:b0 + batch], N[b0:b0 + batch]
        cos = nn @ dirs.T                                   # (B, M)
        cone = np.zeros(cos.shape, bool)
        for c, R in spheres:
            v = np.asarray(c) - p
            rho = np.linalg.norm(v, axis=1)
            sr = R * 1.0001 / np.maximum(rho, 1e-30)
            cc = np.where(sr < 1.0, np.sqrt(np.maximum(0.0, 1.0 - sr * sr)), -2.0)
            cone |= (v / rho[:, None]) @ dirs.T >= cc[:, None]
        if self_mode:
            cone &= cos > 0.0
        pi, di = np.nonzero(cone)
        hit = np.zeros(len(pi), bool)
        for s0 in range(0, len(pi), 4_000_000):
            q, e = pi[s0:s0 + 4_000_000], di[s0:s0 + 4_000_000]
            hit[s0:s0 + 4_000_000] = scene.occluded(p[q] + offset * nn[q], dirs[e])
        c_hit = weights[di[hit]] * cos[pi[hit], di[hit]][:, None]
        np.add.at(signed, b0 + pi[hit], c_hit)
        up = cos[pi[hit], di[hit]] > 0
        np.add.at(positive, b0 + pi[hit][up], c_hit[up])
        upper[b0:b0 + batch] = np.clip(cos, 0.0, None) @ weights   # unoccluded irradiance, upper hemisphere
        full[b0:b0 + batch] = cos @ weights                          # fullsphere irradiance N . FIV(Env)
    visible = upper - positive
    return {"signed": signed, "positive": positive, "visible": visible, "upper": upper, "full": full}


def lens_area(a, b, dist):
    """Area of the lens of two discs (radii a, b, centres dist apart), as pn_lens_area in kernels/fiv.cl."""
    a, b, dist = np.broadcast_arrays(np.asarray(a, float), np.asarray(b, float), np.asarray(dist, float))
    out = np.zeros(a.shape)
    inside = dist <= np.abs(a - b)
    out[inside] = math.pi * np.minimum(a, b)[inside] ** 2
    part = ~inside & (dist < a + b)
    a, b, d = a[part], b[part], np.maximum(dist[part], 1e-30)
    ca = np.clip((d * d + a * a - b * b) / (2 * d * a), -1, 1)
    cb = np.clip((d * d + b * b - a * a) / (2 * d * b), -1, 1)
    k = (-d + a + b) * (d + a - b) * (d - a + b) * (d + a + b)
    out[part] = a * a * np.arccos(ca) + b * b * np.arccos(cb) - 0.5 * np.sqrt(np.maximum(k, 0))
    return out


class OracleSetup:
    """What the oracles need about a built scene: occluders' world bounding spheres and the bake's directions."""

    def __init__(self, r: Runner, built: Built, names: list[str], field: FivField):
        info = field.info()
        self.r, self.built, self.names = r, built, names
        self.T = {n: next(o for o in built.desc.objects if o.name == n).transform() for n in names}
        self.spheres = {n: (self.T[n][:3, :3] @ np.asarray(info["centre"]) + self.T[n][:3, 3], info["radius"])
                        for n in names}
        self.offset = 1e-4 * info["radius"]
        self.dirs, self.weights = r.directions(built.env_name)

    def run(self, names: list[str], P, N, self_mode=False) -> dict:
        return oracle_irradiance(self.r.ctx, [(self.built.meshes[n], self.T[n]) for n in names],
                                 [self.spheres[n] for n in names], P, N, self.dirs, self.weights, self.offset,
                                 self_mode)


def pixels(gbuf, mask):
    P = gbuf["position"][..., :3][mask].astype(np.float64)
    N = gbuf["normal"][..., :3][mask].astype(np.float64)
    N /= np.linalg.norm(N, axis=1, keepdims=True)
    alb = gbuf["albedo"][..., :3][mask].astype(np.float64)
    return P, N, alb


def to_image(mask, alb, E):
    img = np.zeros(mask.shape + (3,))
    img[mask] = alb / math.pi * np.maximum(E, 0.0)
    return img


def case_b_scale(setup: OracleSetup, name: str, P, N) -> np.ndarray:
    """fiv's partial-occluder factor per pixel: (d + R) / 2R for -R < d < R, d = (c - p) . N."""
    c, R = setup.spheres[name]
    d = np.sum((np.asarray(c) - P) * N, axis=1)
    return np.where(d >= R, 1.0, np.where(d <= -R, 0.0, (d + R) / (2 * R)))[:, None]


def plane_oracle(setup: OracleSetup):
    """One occluder over a receiver: fiv's formula with the exact N . FIV_occ at each pixel,
    without and with the partial-occluder factor ('exact field partial=0/1'), and DifMap
    minus the exact occluded irradiance of the positive hemisphere ('exact FIV+', what the
    paper's partial correction approximates)."""
    def fn(gbuf, mask, e_dif):
        P, N, alb = pixels(gbuf, mask)
        o = setup.run(setup.names, P, N)
        E0 = e_dif[mask]
        occ = np.maximum(o["signed"], 0.0)
        scale = case_b_scale(setup, setup.names[0], P, N)
        return [("exact field partial=1", to_image(mask, alb, E0 - scale * occ)),
                ("exact field partial=0", to_image(mask, alb, E0 - occ)),
                ("exact FIV+", to_image(mask, alb, E0 - o["positive"]))]
    return fn


def overlap_oracle(setup: OracleSetup):
    """Several occluders: each one's exact N . FIV_occ, combined by fiv's three rules
    (sum, disc correction, multiplied visibility), and the exact joint occlusion."""
    def fn(gbuf, mask, e_dif):
        P, N, alb = pixels(gbuf, mask)
        E0 = e_dif[mask]
        raw = [np.maximum(setup.run([n], P, N)["signed"], 0.0) for n in setup.names]
        scales = [case_b_scale(setup, n, P, N) for n in setup.names]
        joint = setup.run(setup.names, P, N)
        disc = []
        for n in setup.names:
            c, R = setup.spheres[n]
            v = c - P
            rho = np.linalg.norm(v, axis=1)
            disc.append((v / rho[:, None], np.minimum(R / rho, 1.0)))
        out = []
        for partial in (1, 0):
            I = [i * s if partial else i for i, s in zip(raw, scales)]
            total = sum(I)
            largest = np.maximum.reduce(I)
            corr = total.copy()
            for a in range(len(I)):
                for b in range(a + 1, len(I)):
                    (da, ra), (db, rb) = disc[a], disc[b]
                    lens = lens_area(ra, rb, np.linalg.norm(da - db, axis=1))
                    corr -= (lens / (math.pi * (ra * ra + rb * rb)))[:, None] * (I[a] + I[b])
            corr = np.clip(corr, largest, total)
            vis = np.ones_like(E0)
            for i in I:
                vis *= np.clip(1.0 - i / np.maximum(E0, 1e-30), 0.0, 1.0)
            out += [(f"exact fields overlap=0 partial={partial}", to_image(mask, alb, E0 - total)),
                    (f"exact fields overlap=1 partial={partial}", to_image(mask, alb, E0 - corr)),
                    (f"exact fields overlap=2 partial={partial}", to_image(mask, alb, E0 * vis))]
        return out + [("exact joint FIV+", to_image(mask, alb, E0 - joint["positive"]))]
    return fn


def self_oracle(setup: OracleSetup, offsets=(0.02, 0.05, 0.1)):
    """Self-shadowing with the exact FIV_occ at the pixel: by the fullsphere identity
    N . (FIV(Env) - FIV_occ) is the visible irradiance (bake directions)."""
    def fn(gbuf, mask, e_dif):
        P, N, alb = pixels(gbuf, mask)
        o = setup.run(setup.names, P, N, self_mode=True)
        out = [("exact field", to_image(mask, alb, o["visible"]))]
        # The field looked up a little off the surface (where the grid's valid samples are):
        # N . (FIV(Env) - FIV_occ(p + h N)) with the exact FIV_occ there.
        R = setup.spheres[setup.names[0]][1]
        for h in offsets:
            q = setup.run(setup.names, P + h * R * N, N)
            out.append((f"exact field at p+{h:g}R N", to_image(mask, alb, q["full"] - q["signed"])))
        return out
    return fn
