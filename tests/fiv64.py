"""float64 twin of the `fiv` method (docs/fiv.md): the bake of Fullsphere
Irradiance Vectors by ray casting (geometry64.cast), the generalised winding
number that marks samples inside the geometry, and the per-pixel shading
formula of kernels/fiv.cl (trilinear lookup with NaN samples skipped and
renormalised, outward search, (rho_max / rho)^2 extrapolation, cases A/B/C,
self-shadowing, the three overlap modes, culling).

Plain numpy. Arrays of FIVs are (n, 3 axes, 3 channels): FIV[a, c] =
sum over hit directions w of L_c(w) w_a dw, the layout of FivField.samples().
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from geometry64 import cast

# Sample-grid and culling indices closer than this (in index units, or
# relative for distances) to a place where the float32 kernel's result is
# discontinuous are "fragile": float32 and float64 may take different sides.
# acos loses ~3e-4 rad of precision at the poles (sqrt of float32 epsilon),
# which is 1e-3 index units on a 9-theta grid; 2e-3 covers it.
FRAGILE_INDEX = 2e-3
FRAGILE_RELATIVE = 1e-5
# The disc correction's choice of discs (the largest keys, none whose key is 0) flips where two
# keys lie closer than the float32 lookups' error, or a channel's dot N . FIV lies closer to 0 than
# its rounding: relative to the keys, and to the sum of the dot's terms' magnitudes.
KEY_FRAGILE_RELATIVE = 1e-4


def f32(a) -> np.ndarray:
    return np.asarray(a, dtype=np.float32).astype(np.float64)


# --------------------------------------------------------------------------- env directions


def env_records(env) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(directions, solid angles, radiance) of the env's cube texels, black
    ones dropped: pn_envmap_direction_records at the env's own face size with
    sun_supersampling = 1."""
    dirs, omega = env.cube_directions()
    rad = env.cube_radiance().reshape(-1, 3).astype(np.float64)
    dirs = dirs.reshape(-1, 3).astype(np.float64)
    omega = omega.ravel().astype(np.float64)
    keep = (rad != 0).any(axis=1)
    return dirs[keep], omega[keep], rad[keep]


def env_vectors(dirs, dw, radiance) -> tuple[np.ndarray, float, float]:
    """FIV(Env) = sum L w dw (3 axes, 3 channels), E_ref = max_c sum L_c dw / 4
    (the irradiance of a constant env of the same power) and value_scale =
    max_c sum L_c dw (fiv.c env_vectors, fiv_bake.c)."""
    ldw = radiance * dw[:, None]
    fiv = np.einsum("ra,rc->ac", dirs, ldw)
    power = ldw.sum(0).max()
    return fiv, power / 4.0, power


# --------------------------------------------------------------------------- the bake


def direction(theta, phi) -> np.ndarray:
    """d(theta, phi) = (sin t cos p, cos t, sin t sin p): receiver -> centre."""
    theta, phi = np.broadcast_arrays(np.asarray(theta, np.float64), np.asarray(phi, np.float64))
    st = np.sin(theta)
    return np.stack([st * np.cos(phi), np.cos(theta), st * np.sin(phi)], axis=-1)


def grid_points(centre, radii, n_theta, n_phi) -> np.ndarray:
    """(n_rho, n_theta, n_phi, 3) sample positions p = c - rho d(theta_i, phi_j)
    (float32-rounded, as the bake kernel holds them). Pole samples use j = 0 (the
    bake copies that one to every azimuth)."""
    i = np.arange(n_theta)[:, None]
    j = np.where((i == 0) | (i == n_theta - 1), 0, np.arange(n_phi)[None, :])
    d = direction(f32(np.float32(np.pi) * i / (n_theta - 1)), f32(np.float32(2 * np.pi) * j / n_phi))
    c = f32(centre)
    return f32(c - f32(radii)[:, None, None, None] * d[None])


def bake_samples(vertices, faces, dirs, dw, radiance, centre, radius, points, cone=True):
    """FIV at each receiver point (n, 3, 3) and a bound on what ambiguous rays
    (within geometry64.EDGE_EPS of a triangle edge, where float32 and float64
    may disagree) can change in it (n, 3, 3). With `cone`, only directions in
    the bounding cone (cos >= sqrt(1 - (1.0001 R / rho)^2), all when rho <= R)
    are cast, as the kernel does; without it every direction is cast."""
    v = np.asarray(vertices, np.float64)
    tri = v[np.asarray(faces)]
    v0, v1, v2 = tri[:, 0], tri[:, 1], tri[:, 2]
    points = np.asarray(points, np.float64).reshape(-1, 3)
    centre = np.asarray(centre, np.float64)
    contrib = (radiance * dw[:, None])[:, None, :] * dirs[:, :, None]  # (m, axis, channel)
    out = np.zeros((len(points), 3, 3))
    amb = np.zeros((len(points), 3, 3))
    for n, p in enumerate(points):
        w = centre - p
        rho = np.linalg.norm(w)
        sel = np.ones(len(dirs), bool)
        s = radius * 1.0001 / rho if rho > 0 else np.inf
        if cone and s < 1.0:
            sel = dirs @ (w / rho) >= np.sqrt(1.0 - s * s)
        if not sel.any():
            continue
        t, _, _, _, near = cast(p, dirs[sel], v0, v1, v2)
        c = contrib[sel]
        out[n] = c[np.isfinite(t)].sum(0)
        amb[n] = np.abs(c[near]).sum(0)
    return out, amb


def traced_rays(dirs, centre, radius, points) -> int:
    """Rays the bake traces from these points: the directions in each bounding cone."""
    n = 0
    for p in np.asarray(points, np.float64).reshape(-1, 3):
        w = np.asarray(centre, np.float64) - p
        rho = np.linalg.norm(w)
        s = radius * 1.0001 / rho
        n += int((dirs @ (w / rho) >= np.sqrt(1.0 - s * s)).sum()) if s < 1.0 else len(dirs)
    return n


def triangle_solid_angles(vertices, faces, points) -> np.ndarray:
    """(n points, triangles) signed solid angles (Van Oosterom and Strackee 1983)."""
    tri = np.asarray(vertices, np.float64)[np.asarray(faces)]
    p = np.asarray(points, np.float64).reshape(-1, 1, 1, 3)
    a, b, c = (tri[None, :, k] - p[:, :, 0] for k in range(3))
    la, lb, lc = (np.linalg.norm(x, axis=-1) for x in (a, b, c))
    num = np.einsum("ntk,ntk->nt", a, np.cross(b, c))
    den = (la * lb * lc + np.einsum("ntk,ntk->nt", a, b) * lc + np.einsum("ntk,ntk->nt", a, c) * lb
           + np.einsum("ntk,ntk->nt", b, c) * la)
    return 2.0 * np.arctan2(num, den)


def winding_number(vertices, faces, points, chunk=512) -> np.ndarray:
    """Generalised winding number (Jacobson et al. 2013) of the mesh around each point."""
    points = np.asarray(points, np.float64).reshape(-1, 3)
    out = np.empty(len(points))
    for s in range(0, len(points), chunk):
        out[s:s + chunk] = triangle_solid_angles(vertices, faces, points[s:s + chunk]).sum(1) / (4.0 * np.pi)
    return out


def distance_to_mesh(vertices, faces, points) -> np.ndarray:
    """Unsigned distance from each point to the closest triangle (float64)."""
    tri = np.asarray(vertices, np.float64)[np.asarray(faces)]
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    points = np.asarray(points, np.float64).reshape(-1, 3)
    out = np.empty(len(points))
    for n, p in enumerate(points):
        out[n] = np.sqrt(_closest_sq(p, a, b, c).min())
    return out


def _closest_sq(p, a, b, c):
    """Squared distance from p to each triangle (Ericson, Real-Time Collision Detection 5.1.5)."""
    ab, ac, ap = b - a, c - a, p - a
    d1, d2 = np.einsum("tk,tk->t", ab, ap), np.einsum("tk,tk->t", ac, ap)
    bp = p - b
    d3, d4 = np.einsum("tk,tk->t", ab, bp), np.einsum("tk,tk->t", ac, bp)
    cp = p - c
    d5, d6 = np.einsum("tk,tk->t", ab, cp), np.einsum("tk,tk->t", ac, cp)
    va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2
    with np.errstate(divide="ignore", invalid="ignore"):
        denom = 1.0 / (va + vb + vc)
        v, w = vb * denom, vc * denom
        q = a + ab * v[:, None] + ac * w[:, None]
        # Regions, last assignment wins in reverse priority order.
        t_bc = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        q = np.where(((va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0))[:, None], b + t_bc[:, None] * (c - b), q)
        t_ac = d2 / (d2 - d6)
        q = np.where(((vb <= 0) & (d2 >= 0) & (d6 <= 0))[:, None], a + t_ac[:, None] * ac, q)
        t_ab = d1 / (d1 - d3)
        q = np.where(((vc <= 0) & (d1 >= 0) & (d3 <= 0))[:, None], a + t_ab[:, None] * ab, q)
        q = np.where(((d6 >= 0) & (d5 <= d6))[:, None], c, q)
        q = np.where(((d3 >= 0) & (d4 <= d3))[:, None], b, q)
        q = np.where(((d1 <= 0) & (d2 <= 0))[:, None], a, q)
    return np.sum((p - q) ** 2, axis=1)


# --------------------------------------------------------------------------- shading


@dataclass
class Occluder:
    """One occluder record of fiv.c pn_fiv_prepare, in float64."""

    centre: np.ndarray     # bounding-sphere centre, world
    radius: float          # bounding radius, world (s R)
    scale: float           # uniform scale s of the instance
    samples: np.ndarray    # (n_rho, n_theta, n_phi, 3, 3), object units, NaN inside
    inner: float           # rho_min, object units
    outer: float           # rho_max, object units
    instance: int          # instance id
    cull: float = np.inf   # culling distance, world
    cull_floor: float = 0.0  # per-direction culling: bound x fall-off below this is skipped
    cell_bound: np.ndarray | None = None  # (n_theta - 1, n_phi): largest |FIV| at a cell's outer corners


def outer_max(samples) -> float:
    """Largest |FIV| of a channel on the outermost sphere (NaN samples ignored)."""
    s = np.asarray(samples[-1], np.float64)
    norm = np.sqrt((s ** 2).sum(axis=-2))  # over axes: (theta, phi, channel)
    return float(np.nanmax(norm)) if np.isfinite(norm).any() else 0.0


def cell_bounds(samples) -> np.ndarray:
    """Per (theta, phi) cell of the outermost sphere, the largest |FIV| of a
    channel over its 4 corner samples (NaN ones left out, 0 when all are)."""
    s = np.asarray(samples[-1], np.float64)
    norm = np.sqrt((s ** 2).sum(axis=-2)).max(axis=-1)  # (theta, phi), NaN inside
    corners = np.stack([norm[:-1], np.roll(norm[:-1], -1, axis=1), norm[1:], np.roll(norm[1:], -1, axis=1)])
    out = np.nanmax(np.where(np.isnan(corners), -np.inf, corners), axis=0)
    return np.maximum(out, 0.0)


def make_occluder(info: dict, samples, transform, instance: int, env_ref: float, cull_threshold: float) -> Occluder:
    """The record of an instance with object-to-world `transform` (3x4, s I | t)
    of the field described by FivField.info() / FivField.samples()."""
    m = f32(transform)
    s = m[0, 0]
    centre = m[:, :3] @ f32(info["centre"]) + m[:, 3]
    cull, floor_e = np.inf, 0.0
    if cull_threshold > 0:
        floor_e = cull_threshold * env_ref
        cull = info["outer"] * np.sqrt(max(outer_max(samples) / max(floor_e, 1e-30), 1.0))
    return Occluder(centre=centre, radius=s * info["radius"], scale=s, samples=np.asarray(samples, np.float64),
                    inner=float(info["inner"]), outer=float(info["outer"]), instance=int(instance), cull=s * cull,
                    cull_floor=floor_e, cell_bound=cell_bounds(samples))


def _round(x):
    """OpenCL round(): halfway cases away from zero (x >= 0 here)."""
    return np.floor(x + 0.5)


def lookup(occ: Occluder, v_world, trilinear=True, cull=True):
    """pn_fiv_lookup for receiver-to-centre vectors v_world (n, 3): FIV (n, 3, 3),
    valid (n,), fragile (n,) (near a discontinuity of the float32 lookup).
    With ``cull``, beyond the grid a direction whose cell bound times the
    fall-off is below occ.cull_floor is culled (not valid)."""
    v = np.asarray(v_world, np.float64) / occ.scale
    n = len(v)
    rho = np.linalg.norm(v, axis=1)
    safe = np.where(rho > 0, rho, 1.0)
    d = np.where((rho > 0)[:, None], v / safe[:, None], np.array([0.0, 1.0, 0.0]))
    # acos of the float32 d.y: near the poles that rounding (1 ulp of 1 is
    # 6e-8) moves theta by up to 3.5e-4 rad, far more than anything else.
    theta = np.arccos(np.clip(f32(d[:, 1]), -1.0, 1.0))
    phi = np.arctan2(d[:, 2], d[:, 0])
    phi = np.where(phi < 0, phi + 2 * np.pi, phi)
    nr, nt, nphi = occ.samples.shape[:3]
    fi = theta * (nt - 1) / np.pi
    fj = phi * nphi / (2 * np.pi)
    log_ratio = np.log(occ.outer / occ.inner)
    fk = np.where(rho > 0, np.log(safe / occ.inner) / log_ratio * (nr - 1), 0.0)
    beyond = fk > nr - 1
    falloff = np.where(beyond, (occ.outer / safe) ** 2, 1.0)
    fk = np.maximum(np.where(beyond, nr - 1.0, fk), 0.0)
    culled = np.zeros(n, bool)
    cull_fragile = np.zeros(n, bool)
    if cull and occ.cull_floor > 0:
        ci = np.minimum(np.floor(fi).astype(int), nt - 2)
        cj = np.minimum(np.floor(fj).astype(int), nphi - 1)
        bound = occ.cell_bound[ci, cj] * falloff
        culled = beyond & (bound < occ.cull_floor)
        # float32 rounding of the bound, the fall-off or the cell's edges
        near_edge = np.zeros(n, bool)
        for x in (fi, fj):
            frac = x - np.floor(x)
            near_edge |= (frac < FRAGILE_INDEX) | (frac > 1 - FRAGILE_INDEX)
        cull_fragile = beyond & ((np.abs(bound - occ.cull_floor) <= 1e-4 * occ.cull_floor) | near_edge)
    if not trilinear:
        fragile = np.zeros(n, bool)
        for x in (fi, fj, fk):
            frac = x - np.floor(x)
            fragile |= np.abs(frac - 0.5) < FRAGILE_INDEX
        fi, fj, fk = _round(fi), _round(fj), _round(fk)
    i0 = np.minimum(np.floor(fi).astype(int), nt - 2)
    k0 = np.minimum(np.floor(fk).astype(int), nr - 2)
    ti, tk = np.clip(fi - i0, 0, 1), np.clip(fk - k0, 0, 1)
    jf = np.floor(fj).astype(int)
    tj = fj - jf
    j0, j1 = jf % nphi, (jf + 1) % nphi
    acc = np.zeros((n, 3, 3))
    wsum = np.zeros(n)
    any_nan = np.zeros(n, bool)

    def shell(k, wk, mask):
        nonlocal any_nan
        for ii, jj, w in ((i0, j0, (1 - ti) * (1 - tj)), (i0, j1, (1 - ti) * tj), (i0 + 1, j0, ti * (1 - tj)),
                          (i0 + 1, j1, ti * tj)):
            w = wk * w
            s = occ.samples[k, ii, jj]
            nan = np.isnan(s[:, 0, 0])
            any_nan |= nan & mask
            use = mask & (w > 0) & ~nan
            acc[use] += w[use, None, None] * s[use]
            wsum[use] += w[use]

    everyone = np.ones(n, bool)
    shell(k0, 1 - tk, everyone)
    shell(k0 + 1, tk, everyone)
    for step in range(nr):
        k = k0 + 1 + step
        mask = (wsum <= 0) & (k < nr)
        if not mask.any():
            break
        shell(np.minimum(k, nr - 1), np.ones(n), mask)
    valid = (wsum > 0) & ~culled
    f = np.where(valid[:, None, None], acc * (falloff / np.where(wsum > 0, wsum, 1.0))[:, None, None], 0.0)
    if trilinear:
        # With invalid neighbours the set of samples used jumps when a weight reaches 0.
        t_all = np.stack([ti, 1 - ti, tj, 1 - tj, tk, 1 - tk], axis=1)
        fragile = any_nan & (np.abs(t_all).min(axis=1) < FRAGILE_INDEX)
    return f, valid, fragile | cull_fragile


def lens_area(a, b, dist):
    """Area of the lens of two discs of radii a, b, centres dist apart (planar)."""
    a, b, dist = np.broadcast_arrays(np.asarray(a, np.float64), np.asarray(b, np.float64),
                                     np.asarray(dist, np.float64))
    out = np.zeros(a.shape)
    inside = dist <= np.abs(a - b)
    out[inside] = np.pi * np.minimum(a, b)[inside] ** 2
    part = ~inside & (dist < a + b)
    aa, bb, dd = a[part], b[part], dist[part]
    ca = np.clip((dd ** 2 + aa ** 2 - bb ** 2) / (2 * dd * aa), -1, 1)
    cb = np.clip((dd ** 2 + bb ** 2 - aa ** 2) / (2 * dd * bb), -1, 1)
    k = (-dd + aa + bb) * (dd + aa - bb) * (dd - aa + bb) * (dd + aa + bb)
    out[part] = aa ** 2 * np.arccos(ca) + bb ** 2 * np.arccos(cb) - 0.5 * np.sqrt(np.maximum(k, 0))
    return out


def shade(position, normal, albedo, instance, e_unshadowed, occluders, env_fiv, overlap=1, partial=0, self_shadow=0,
          trilinear=1, max_overlap=6):
    """The shade_fiv formula per foreground pixel (arrays of n pixels: position
    (n, 3+), normal (n, 3+), albedo (n, 3+), instance (n,), the DifMap
    irradiance e_unshadowed (n, 3)). Returns the outgoing radiance (n, 3), E
    before the clamp (n, 3) and a fragile flag (n,): the pixel is within
    float32 rounding of a discontinuity (grid rounding, a culling distance,
    the case boundaries without `partial`)."""
    p = f32(np.asarray(position)[:, :3])
    nrm = f32(np.asarray(normal)[:, :3])
    nrm = nrm / np.linalg.norm(nrm, axis=1, keepdims=True)
    alb = f32(np.asarray(albedo)[:, :3])
    instance = np.asarray(instance)
    e_tot = np.asarray(e_unshadowed, np.float64)
    npx = len(p)
    e_base = e_tot.copy()
    total = np.zeros((npx, 3))
    largest = np.zeros((npx, 3))
    visible = np.ones((npx, 3))
    fragile = np.zeros(npx, bool)
    discs = []  # (active, i_occ, unit direction, radius)
    unsure_key = np.zeros(npx, bool)
    env = np.asarray(env_fiv, np.float64)
    for occ in occluders:
        v = f32(occ.centre)[None, :] - p
        own = instance == occ.instance
        if self_shadow and own.any():
            f, ok, frag = lookup(occ, v[own], trilinear, cull=False)
            idx = np.flatnonzero(own)[ok]
            # The fullsphere estimate, clamped to [0, DifMap] (a sample off the
            # surface also sees light behind the receiver plane: it errs low).
            e_self = np.einsum("na,ac->nc", nrm[idx], env) - np.einsum("na,nac->nc", nrm[idx], f[ok])
            e_base[idx] = np.minimum(np.maximum(e_self, 0.0), e_tot[idx])
            fragile[np.flatnonzero(own)] |= frag
        r = occ.radius
        dp = np.einsum("nk,nk->n", v, nrm)
        rho = np.linalg.norm(v, axis=1)
        active = ~own & (dp > -r) & (rho <= occ.cull)
        fragile |= ~own & (np.abs(rho - occ.cull) <= FRAGILE_RELATIVE * rho)
        if not partial:
            fragile |= ~own & ((np.abs(dp + r) <= FRAGILE_RELATIVE * r) | (np.abs(dp - r) <= FRAGILE_RELATIVE * r))
        f, ok, frag = lookup(occ, v, trilinear)
        fragile |= active & frag
        active &= ok
        dots = np.einsum("na,nac->nc", nrm, f)
        i_occ = np.maximum(dots, 0.0)
        if partial:
            b = dp < r
            i_occ = np.where(b[:, None], i_occ * ((dp + r) / (2 * r))[:, None], i_occ)
        i_occ = np.where(active[:, None], i_occ, 0.0)
        total += i_occ
        largest = np.maximum(largest, i_occ)
        if overlap == 2:
            visible *= np.clip(1.0 - i_occ / np.maximum(e_tot, 1e-30), 0.0, 1.0)
        elif overlap == 1:
            u = np.where((rho > 0)[:, None], v / np.where(rho > 0, rho, 1.0)[:, None], nrm)
            discs.append((active, i_occ, u, np.minimum(r / np.maximum(rho, 1e-30), 1.0)))
            # whether the key is positive (some channel's dot above 0) is a float32 rounding away
            tol = KEY_FRAGILE_RELATIVE * np.einsum("na,nac->nc", np.abs(nrm), np.abs(f))
            unsure_key |= active & ~(dots > tol).any(axis=1) & ((np.abs(dots) <= tol) & (tol > 0)).any(axis=1)
    if overlap == 2:
        e = e_base * visible
    else:
        s = total.copy()
        if overlap == 1 and discs:
            # Each pixel pairs the max_overlap discs with the largest keys (the irradiance summed
            # over the channels; none whose key is 0), whatever the occluders' order.
            keys = np.stack([np.where(d[0], d[1].sum(axis=1), 0.0) for d in discs], axis=1)
            ranked = -np.sort(-keys, axis=1)
            kth = ranked[:, max_overlap - 1] if keys.shape[1] >= max_overlap else np.zeros(npx)
            chosen = (keys > 0) & (keys >= kth[:, None])
            if keys.shape[1] > max_overlap:   # the k-th and the next within rounding: either may be chosen
                nxt = ranked[:, max_overlap]
                fragile |= (nxt > 0) & (kth - nxt <= KEY_FRAGILE_RELATIVE * kth)
            fragile |= unsure_key & (len(discs) > 1)
            discs = [(chosen[:, j],) + d[1:] for j, d in enumerate(discs)]
            for a in range(len(discs)):
                for b in range(a + 1, len(discs)):
                    ta, ia, ua, ra = discs[a]
                    tb, ib, ub, rb = discs[b]
                    both = ta & tb
                    lens = lens_area(ra, rb, np.linalg.norm(ua - ub, axis=1))
                    share = np.where(both & (lens > 0), lens / (np.pi * (ra ** 2 + rb ** 2)), 0.0)
                    s = s - share[:, None] * (ia + ib)
            s = np.minimum(np.maximum(s, largest), total)
        e = e_base - s
    return np.maximum(alb * e / np.pi, 0.0), e, fragile
