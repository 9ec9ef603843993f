"""float64 twin of the decomposition and the average-reflectivity terms of the
depth-map method (docs/depthmap.md; seed: Barsi, Szirmay-Kalos, Szecsi,
"Image-based illumination on the GPU"), and of its depth maps, lookup and
shading kernel (kernels/depthmap.cl).

Plain numpy, float64 throughout. Conventions:

* Env maps are (H, W, 3) lat-long arrays in the project's convention
  (docs/conventions.md, penumbra.procedural): y up, row 0 at the top, texel
  k = j * W + i (row-major) with direction and solid angle from
  ``latlong_directions`` / ``latlong_row_solid_angles``.
* A texel's weight (its "power") is luminance(L) * d_omega with Rec. 709
  luminance (kernels/common/math.cl pn_luminance). Non-black means weight > 0.
* Directions are unit (.., 3) arrays; RGB quantities are (.., 3).

Functions:

  texels        texels(env) -> Texels
  sampling      texel_uniforms(seed, count), initial_samples(tex, n, seed)
  Lloyd         nearest(dirs, centres), spread(tex, centres, assign),
                lloyd(tex, centres, max_iter), decompose(env, n, seed, max_iter)
  median cut    median_cut(env, n)
  domains       domains_from_assignment(tex, centres, assign), cap_radius(solid_angle)
  irradiance    exact_irradiance(tex, normals), domain_irradiance(dom, normals, cap),
                clamped_cosine_cap(cos_theta, r), irradiance_error(env, dom, normals),
                fibonacci_sphere(n)
  Phong         phong_cap_average(cos_psi_c, r, n, nodes), phong_cap_average_centre(r, n),
                seed_blend(cos_psi_c, r, n), phong_energy(a, r, n)
  depth maps    map_coordinates(frame, p), rasterise(frame, tris, res), map_bias(...),
                visibility(frame, depth, p, b, pcf, margin)
  shading       cap_points(d, r, samples), lobe_reaches(...), specular_average(...),
                shade(planes, camera, domains, frames, maps, ...) (twins of kernels/depthmap.cl)

Readings where the seed leaves a choice (docs/depthmap.md says why):
initial samples are drawn without replacement (Efraimidis-Spirakis keys from a
splitmix64 hash of (seed, texel index), reproducible bit for bit in C); nearest
centre = largest dot product, ties to the lowest centre index; Lloyd stops
when no texel changes cell (or after max_iter); a cell holding no weight keeps
its centre; the spread minimised is sum_k w_k (1 - w_k . c_a(k)) (half the
weighted squared chord distance).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field

import numpy as np

from penumbra.procedural import latlong_directions, latlong_row_solid_angles

LUMINANCE = np.array([0.2126, 0.7152, 0.0722])
CHUNK = 1 << 16  # texels per block of the nearest-centre search (bounds memory to CHUNK x N)


class DecompositionError(ValueError):
    """Bad input to a decomposition: the message names what is wrong."""


# --------------------------------------------------------------------------- texels


@dataclass
class Texels:
    """The texels of a W x H lat-long map, flattened row-major."""

    width: int
    height: int
    dirs: np.ndarray      # (M, 3) unit directions of the texel centres
    omega: np.ndarray     # (M,) solid angles
    radiance: np.ndarray  # (M, 3) RGB radiance
    weight: np.ndarray    # (M,) luminance * solid angle

    @property
    def power(self) -> np.ndarray:
        """(M, 3) L * d_omega."""
        return self.radiance * self.omega[:, None]

    @property
    def nonblack(self) -> int:
        return int(np.count_nonzero(self.weight > 0))


def texels(env) -> Texels:
    env = np.asarray(env)
    if env.ndim != 3 or env.shape[2] != 3 or env.shape[0] < 1 or env.shape[1] < 1:
        raise DecompositionError(f"environment map must be an (H, W, 3) array, got shape {env.shape}")
    rad = env.astype(np.float64).reshape(-1, 3)
    if not np.isfinite(rad).all():
        raise DecompositionError("environment map holds NaN or Inf radiance")
    if (rad < 0).any():
        raise DecompositionError("environment map holds negative radiance")
    h, w = env.shape[:2]
    dirs = latlong_directions(w, h).reshape(-1, 3)
    omega = np.repeat(latlong_row_solid_angles(w, h), w)
    return Texels(w, h, dirs, omega, rad, (rad @ LUMINANCE) * omega)


# --------------------------------------------------------------------------- initial samples


def splitmix64(x: np.ndarray) -> np.ndarray:
    """splitmix64 finaliser of uint64 array x (wrapping arithmetic, as in C)."""
    z = np.asarray(x, dtype=np.uint64) + np.uint64(0x9E3779B97F4A7C15)
    z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return z ^ (z >> np.uint64(31))


def texel_uniforms(seed: int, count: int) -> np.ndarray:
    """u_k in (0, 1), k = 0..count-1: ((splitmix64(seed * 2^32 + k) >> 11) + 0.5) * 2^-53."""
    base = np.uint64((int(seed) & 0xFFFFFFFF) << 32)
    with np.errstate(over="ignore"):
        h = splitmix64(base + np.arange(count, dtype=np.uint64))
    return ((h >> np.uint64(11)).astype(np.float64) + 0.5) * 2.0 ** -53


def check_count(tex: Texels, n: int) -> int:
    if int(n) != n or n < 1:
        raise DecompositionError(f"number of directions must be a positive integer, got {n!r}")
    if n > tex.nonblack:
        raise DecompositionError(
            f"{int(n)} directions requested but the environment map has only {tex.nonblack} non-black texels"
            + (" (it is black)" if tex.nonblack == 0 else ""))
    return int(n)


def initial_samples(tex: Texels, n: int, seed: int = 0) -> np.ndarray:
    """Indices of n distinct texels drawn without replacement with probability
    proportional to weight: the n smallest keys -log(u_k) / w_k (Efraimidis &
    Spirakis; ties to the lower index). Black texels are never drawn."""
    n = check_count(tex, n)
    u = texel_uniforms(seed, tex.weight.size)
    with np.errstate(divide="ignore"):
        key = np.where(tex.weight > 0, -np.log(u) / tex.weight, np.inf)
    return np.argsort(key, kind="stable")[:n]


# --------------------------------------------------------------------------- Lloyd relaxation


def nearest(dirs: np.ndarray, centres: np.ndarray) -> np.ndarray:
    """Index of the centre with the largest dot product for each direction (ties to the lowest index)."""
    out = np.empty(len(dirs), dtype=np.int64)
    for s in range(0, len(dirs), CHUNK):
        out[s:s + CHUNK] = np.argmax(dirs[s:s + CHUNK] @ centres.T, axis=1)
    return out


def spread(tex: Texels, centres: np.ndarray, assign: np.ndarray) -> float:
    """sum_k w_k (1 - d_k . c_assign(k)): what weighted Lloyd minimises."""
    return float(np.sum(tex.weight * (1.0 - np.einsum("ka,ka->k", tex.dirs, centres[assign]))))


def weighted_means(tex: Texels, centres: np.ndarray, assign: np.ndarray) -> np.ndarray:
    """Normalised weighted mean direction of each cell; a cell whose weighted sum
    vanishes keeps its centre."""
    s = np.zeros_like(centres)
    np.add.at(s, assign, tex.weight[:, None] * tex.dirs)
    norm = np.linalg.norm(s, axis=1)
    ok = norm > 0
    new = centres.copy()
    new[ok] = s[ok] / norm[ok, None]
    return new


@dataclass
class Domains:
    """A decomposition of the sphere into N directional domains."""

    centres: np.ndarray      # (N, 3) unit sample directions
    radiance: np.ndarray     # (N, 3) total radiance sum L d_omega over the domain
    solid_angle: np.ndarray  # (N,) sum of d_omega
    cap_radius: np.ndarray   # (N,) radius of the cap with that solid angle
    assign: np.ndarray       # (M,) domain of each texel
    spreads: list = field(default_factory=list)  # spread after each assignment (Lloyd only)
    iterations: int = 0
    converged: bool = True


def cap_radius(solid_angle) -> np.ndarray:
    """r with 2 pi (1 - cos r) = Omega, i.e. r = 2 asin(sqrt(Omega / 4 pi)) (no cancellation at small Omega)."""
    return 2.0 * np.arcsin(np.sqrt(np.clip(np.asarray(solid_angle, np.float64) / (4.0 * np.pi), 0.0, 1.0)))


def domains_from_assignment(tex: Texels, centres: np.ndarray, assign: np.ndarray, **extra) -> Domains:
    n = len(centres)
    radiance = np.zeros((n, 3))
    np.add.at(radiance, assign, tex.power)
    omega = np.bincount(assign, weights=tex.omega, minlength=n).astype(np.float64)
    return Domains(centres, radiance, omega, cap_radius(omega), assign, **extra)


def lloyd(tex: Texels, centres: np.ndarray, max_iter: int = 100) -> Domains:
    """Weighted Lloyd relaxation from the given centres: assign every texel to its
    nearest centre, move each centre to its cell's weighted mean direction,
    until no texel changes cell. Each half-step cannot increase the spread."""
    centres = np.array(centres, dtype=np.float64)
    if centres.ndim != 2 or centres.shape[1] != 3 or not np.isfinite(centres).all():
        raise DecompositionError(f"centres must be finite (N, 3), got shape {centres.shape}")
    centres /= np.linalg.norm(centres, axis=1, keepdims=True)
    assign = nearest(tex.dirs, centres)
    spreads = [spread(tex, centres, assign)]
    converged = False
    it = 0
    while it < max_iter:
        it += 1
        centres = weighted_means(tex, centres, assign)
        spreads.append(spread(tex, centres, assign))
        new = nearest(tex.dirs, centres)
        spreads.append(spread(tex, centres, new))
        if np.array_equal(new, assign):
            converged = True
            break
        assign = new
    return domains_from_assignment(tex, centres, assign, spreads=spreads, iterations=it, converged=converged)


def decompose(env, n: int, seed: int = 0, max_iter: int = 100) -> Domains:
    """The seed's decomposition: n samples by power, weighted Lloyd relaxation,
    texels to the nearest centre, per-domain radiance, solid angle, cap radius."""
    tex = env if isinstance(env, Texels) else texels(env)
    start = initial_samples(tex, n, seed)
    return lloyd(tex, tex.dirs[start], max_iter)


# --------------------------------------------------------------------------- median cut (Debevec 2005)


def _split(tex: Texels, w2d: np.ndarray, region):
    """Cut a region (j0, j1, i0, i1) across its longer side (width measured at
    the region's middle latitude) where the cumulative weight is nearest half."""
    j0, j1, i0, i1 = region
    h, w = tex.height, tex.width
    theta_mid = math.pi * 0.5 * (j0 + j1) / h
    width_angle = (i1 - i0) * (2.0 * math.pi / w) * math.sin(theta_mid)
    height_angle = (j1 - j0) * math.pi / h
    sub = w2d[j0:j1, i0:i1]
    along_rows = (height_angle >= width_angle and j1 - j0 > 1) or i1 - i0 == 1
    profile = sub.sum(axis=1) if along_rows else sub.sum(axis=0)
    cum = np.cumsum(profile)[:-1]  # weight before each possible cut 1..len-1
    cut = 1 + int(np.argmin(np.abs(cum - 0.5 * profile.sum())))
    if along_rows:
        return (j0, j0 + cut, i0, i1), (j0 + cut, j1, i0, i1)
    return (j0, j1, i0, i0 + cut), (j0, j1, i0 + cut, i1)


def median_cut(env, n: int) -> Domains:
    """Debevec's median cut: split every region in two (across its longer side,
    at the weight median) level by level; when n is not a power of two the last
    level splits only the heaviest regions. A domain's centre is its weighted
    mean direction (the solid-angle mean where it holds no weight)."""
    tex = env if isinstance(env, Texels) else texels(env)
    n = check_count(tex, n)
    w2d = tex.weight.reshape(tex.height, tex.width)
    regions = [(0, tex.height, 0, tex.width)]
    while len(regions) < n:
        splittable = [r for r in regions if (r[1] - r[0]) * (r[3] - r[2]) > 1]
        order = sorted(splittable, key=lambda r: -w2d[r[0]:r[1], r[2]:r[3]].sum())
        chosen = set(order[:n - len(regions)])
        nxt = []
        for r in regions:
            nxt.extend(_split(tex, w2d, r) if r in chosen else [r])
        regions = nxt
    assign = np.empty((tex.height, tex.width), dtype=np.int64)
    for k, (j0, j1, i0, i1) in enumerate(regions):
        assign[j0:j1, i0:i1] = k
    assign = assign.ravel()
    s = np.zeros((n, 3))
    np.add.at(s, assign, tex.weight[:, None] * tex.dirs)
    g = np.zeros((n, 3))
    np.add.at(g, assign, tex.omega[:, None] * tex.dirs)
    s = np.where((np.linalg.norm(s, axis=1) > 0)[:, None], s, g)
    centres = s / np.linalg.norm(s, axis=1, keepdims=True)
    return domains_from_assignment(tex, centres, assign)


# --------------------------------------------------------------------------- irradiance


def fibonacci_sphere(n: int) -> np.ndarray:
    """n near-uniform unit directions (spherical Fibonacci lattice)."""
    k = np.arange(n) + 0.5
    y = 1.0 - 2.0 * k / n
    phi = math.pi * (3.0 - math.sqrt(5.0)) * k
    s = np.sqrt(1.0 - y * y)
    return np.stack([s * np.cos(phi), y, s * np.sin(phi)], axis=-1)


def exact_irradiance(tex: Texels, normals: np.ndarray) -> np.ndarray:
    """E(n) = sum_k L_k d_omega_k max(0, n . d_k), (P, 3): the unshadowed irradiance of the map."""
    out = np.zeros((len(normals), 3))
    p = tex.power
    for s in range(0, len(tex.dirs), CHUNK):
        out += np.maximum(normals @ tex.dirs[s:s + CHUNK].T, 0.0) @ p[s:s + CHUNK]
    return out


def _cap_inside(cos_theta, r):
    """int over the cap (radius r <= pi/2, centre at angle theta from n) of max(0, n . w) dw.
    Fully above the horizon (cos^2 theta > sin^2 r, theta < pi/2): pi sin^2 r cos theta; fully
    below: 0; straddling: Snyder's formula (as in Lagarde & de Rousiers 2014, eq. 21)."""
    ct = np.clip(cos_theta, -1.0, 1.0)
    st = np.sqrt(np.maximum(1.0 - ct * ct, 0.0))
    s2 = np.sin(r) ** 2
    whole = np.pi * s2 * np.maximum(ct, 0.0)
    straddle = ct * ct < s2
    with np.errstate(divide="ignore", invalid="ignore"):
        x = np.sqrt(np.maximum(1.0 / s2 - 1.0, 0.0))  # cot r
        y = np.clip(-x * ct / st, -1.0, 1.0)
        sy = st * np.sqrt(1.0 - y * y)
        part = (ct * np.arccos(y) - x * sy) * s2 + np.arctan2(sy, x)
    return np.where(straddle, np.maximum(part, 0.0), whole)


def clamped_cosine_cap(cos_theta, r) -> np.ndarray:
    """Average of max(0, n . w) over a cap of radius r in [0, pi] whose centre is at
    angle theta from n. For r > pi/2 the cap is the sphere minus the cap of radius
    pi - r around the opposite centre: integral = pi - inside(-cos theta, pi - r)."""
    ct, r = np.broadcast_arrays(np.asarray(cos_theta, np.float64), np.asarray(r, np.float64))
    big = r > 0.5 * np.pi
    integral = np.where(big, np.pi - _cap_inside(-ct, np.pi - r), _cap_inside(ct, np.minimum(r, 0.5 * np.pi)))
    area = 4.0 * np.pi * np.sin(0.5 * r) ** 2  # 2 pi (1 - cos r)
    with np.errstate(divide="ignore", invalid="ignore"):
        avg = integral / area
    return np.where(area > 0, avg, np.maximum(ct, 0.0))  # a point: the cosine itself


def domain_irradiance(dom: Domains, normals: np.ndarray, cap: bool = False) -> np.ndarray:
    """sum_i L~_i a_i(n), (P, 3): a_i = max(0, n . c_i) (the seed's diffuse term) or,
    with cap=True, the exact clamped-cosine average over the domain's equivalent cap."""
    cos_t = normals @ dom.centres.T
    a = clamped_cosine_cap(cos_t, dom.cap_radius[None, :]) if cap else np.maximum(cos_t, 0.0)
    return a @ dom.radiance


def irradiance_error(tex: Texels, dom: Domains, normals: np.ndarray, cap: bool = False,
                     exact: np.ndarray | None = None) -> float:
    """Relative RMS error of the luminance of the domain irradiance over the normals:
    RMS(E_dom - E) / RMS(E)."""
    e = (exact_irradiance(tex, normals) if exact is None else exact) @ LUMINANCE
    d = domain_irradiance(dom, normals, cap) @ LUMINANCE
    return float(np.sqrt(np.mean((d - e) ** 2) / np.mean(e ** 2)))


# --------------------------------------------------------------------------- Phong average reflectivity


@functools.lru_cache(maxsize=None)
def _leggauss(nodes: int):
    return np.polynomial.legendre.leggauss(nodes)  # an eigenproblem: tens of ms at 400 nodes


def _gl_mapped(a: float, b: float, nodes: int):
    """Gauss-Legendre nodes/weights on [a, b] after x = a + (b - a)(1 - cos(pi s))/2,
    which turns sqrt-type end-point behaviour into smooth behaviour in s."""
    t, w = _leggauss(nodes)
    s = 0.5 * (t + 1.0)
    x = a + (b - a) * 0.5 * (1.0 - np.cos(np.pi * s))
    return x, w * 0.5 * (b - a) * 0.5 * np.pi * np.sin(np.pi * s)


def phong_cap_average(cos_psi_c: float, r: float, n: float, nodes: int = 200) -> float:
    """Exact (1 / Omega_cap) int_cap max(0, R . w)^n dw for a cap of radius r whose
    centre is at angle psi_c from R, by quadrature over psi (angle from R): the circle
    of radius psi around R lies in the cap over an azimuth 2 phi(psi) with
    cos phi = (cos r - cos psi cos psi_c) / (sin psi sin psi_c), so
    average = int_0^{pi/2} cos^n psi 2 phi(psi) sin psi dpsi / (2 pi (1 - cos r)).
    The pieces are split at the kinks |psi_c - r| and psi_c + r. n = 0 counts the
    part of the cap in R's hemisphere."""
    cpc = min(1.0, max(-1.0, float(cos_psi_c)))
    psi_c = math.acos(cpc)
    lo, hi = abs(psi_c - r), min(psi_c + r, math.pi)
    if psi_c <= r:  # R inside the cap: whole circles up to r - psi_c
        lo_full = r - psi_c
    else:
        lo_full = 0.0
    top = 0.5 * math.pi
    total = 0.0
    if psi_c <= r and lo_full > 0:  # full circles: 2 pi int_0^{min(lo, pi/2)} cos^n sin
        b = min(lo_full, top)
        total += 2.0 * math.pi * (1.0 - math.cos(b) ** (n + 1)) / (n + 1)
    a, b = (lo_full if psi_c <= r else lo), min(hi, top)
    # a cap reaching past R's antipode (psi_c + r > pi) holds whole circles again beyond 2 pi - psi_c - r
    cuts = sorted({a, b, *[x for x in (2.0 * math.pi - psi_c - r,) if a < x < b]}) if b > a else []
    s_c = math.sqrt(max(1.0 - cpc * cpc, 0.0))
    for lo_p, hi_p in zip(cuts[:-1], cuts[1:]):
        psi, w = _gl_mapped(lo_p, hi_p, nodes)
        sp, cp = np.sin(psi), np.cos(psi)
        with np.errstate(divide="ignore", invalid="ignore"):
            c = (math.cos(r) - cp * cpc) / (sp * s_c)
        phi = np.arccos(np.clip(np.nan_to_num(c, nan=1.0), -1.0, 1.0))
        total += float(np.sum(w * cp ** n * 2.0 * phi * sp))
    return total / (4.0 * math.pi * math.sin(0.5 * r) ** 2)


def phong_cap_average_centre(r, n) -> np.ndarray:
    """Closed form at psi_c = 0: (1 - cos^{n+1} r) / ((n + 1)(1 - cos r)) for r <= pi/2
    (cos r clamped at 0 beyond: the lobe is cut at pi/2)."""
    r = np.asarray(r, np.float64)
    c = np.maximum(np.cos(r), 0.0)
    return (1.0 - c ** (n + 1)) / ((n + 1) * 2.0 * np.sin(0.5 * r) ** 2)


def seed_blend(cos_psi_c, r, n) -> np.ndarray:
    """The seed's average reflectivity (per unit k_s): for psi_c < r,
    A0 (cos psi_c - cos r)/(1 - cos r) + cos^n psi_c (1 - cos psi_c)/(1 - cos r) with A0 the
    psi_c = 0 closed form; for psi_c >= r the point sample cos^n psi_c (clamped at 0)."""
    cpc, r = np.broadcast_arrays(np.asarray(cos_psi_c, np.float64), np.asarray(r, np.float64))
    cr = np.cos(r)
    one_minus = 2.0 * np.sin(0.5 * r) ** 2
    t = (1.0 - cpc) / one_minus  # 0 at the centre, 1 at the cap's edge
    point = np.maximum(cpc, 0.0) ** n
    inside = cpc > cr
    return np.where(inside, phong_cap_average_centre(r, n) * (1.0 - t) + point * t, point)


def phong_energy(a, r: float, n: float, nodes: int = 400) -> float:
    """int over reflection directions R of a(cos psi_c) dR divided by its exact value
    2 pi / (n + 1) (which the exact cap average and the point sample both have):
    the fraction of the specular energy an approximation a keeps. a is a function of
    cos psi_c; the integral is split at psi_c = r and pi/2 + r."""
    total = 0.0
    for lo, hi in ((0.0, r), (r, min(0.5 * math.pi + r, math.pi))):
        psi, w = _gl_mapped(lo, hi, nodes)
        vals = np.array([a(math.cos(p)) for p in psi])
        total += float(np.sum(w * vals * 2.0 * math.pi * np.sin(psi)))
    return total / (2.0 * math.pi / (n + 1))


# --------------------------------------------------------------------------- depth maps and shading
#
# The float64 twins of kernels/depthmap.cl: the rasterised maps (given the
# map frames the library fitted, read back through the `map_frames` output),
# the depth-map lookup with its bias and PCF, the cap quadrature and the
# per-pixel sum. Frames are (16,) arrays: e1 | u_min, e2 | v_min, d | far,
# du, dv, depth extent, 0.

# The map fit (capi/src/methods/depthmap.c, fit_frames): instances are
# (lo, hi, xf) — the object box and the 3 x 4 object-to-world transform.


def complete_frame(d):
    """(e1, e2) completing the unit d (Duff et al. 2017, as pn_frame)."""
    sg = 1.0 if d[2] >= 0.0 else -1.0
    a = -1.0 / (sg + d[2])
    b = d[0] * d[1] * a
    return (np.array([1.0 + sg * d[0] * d[0] * a, sg * b, -sg * d[0]]),
            np.array([b, sg + d[1] * d[1] * a, -d[1]]))


def box_corners(lo, hi, xf) -> np.ndarray:
    """The 8 world corners of an object box (corner k: bit c = the high side on axis c)."""
    k = np.arange(8)
    o = np.stack([np.where((k >> c) & 1, hi[c], lo[c]) for c in range(3)], axis=1).astype(np.float64)
    xf = np.asarray(xf, np.float64)
    return o @ xf[:, :3].T + xf[:, 3]


def flat_plane(lo, hi, corners):
    """(unit normal, offset n.p) of a box with no thickness on one axis, else None."""
    ext = np.asarray(hi, np.float64) - np.asarray(lo, np.float64)
    size = ext.max()
    thin = [c for c in range(3) if ext[c] <= 1e-6 * size]
    if not thin or not size > 0.0:
        return None
    t = thin[-1]
    a, b = (t + 1) % 3, (t + 2) % 3
    n = np.cross(corners[1 << a] - corners[0], corners[1 << b] - corners[0])
    if not np.linalg.norm(n) > 0.0:
        return None
    n = n / np.linalg.norm(n)
    return n, float(n @ corners[0])


def clipped_vertices(corners, h, c) -> np.ndarray:
    """Vertices of the box (its corners) cut to p.h <= c: the corners inside
    and the crossings of its 12 edges with the plane."""
    side = corners @ h - c
    pts = [corners[k] for k in range(8) if side[k] <= 0.0]
    for k in range(8):
        for b in range(3):
            j = k | (1 << b)
            if j != k and (side[k] <= 0.0) != (side[j] <= 0.0):
                t = side[k] / (side[k] - side[j])
                pts.append(corners[k] + t * (corners[j] - corners[k]))
    return np.array(pts).reshape(-1, 3)


def shadow_footprint(d, e1, e2, instances, tol):
    """fit 1: the (u, v) range where a shadow can fall, or None (docs/depthmap.md)."""
    axes = np.stack([e1, e2])
    lo, hi = np.full(2, np.inf), np.full(2, -np.inf)
    any_ = False
    boxes = [box_corners(*inst) for inst in instances]
    for i, (inst, cc) in enumerate(zip(instances, boxes)):
        plane = flat_plane(inst[0], inst[1], cc)
        own = cc @ axes.T
        if plane is None:  # can shadow itself: all of it
            lo, hi, any_ = np.minimum(lo, own.min(0)), np.maximum(hi, own.max(0)), True
            continue
        n, offset = plane
        nd = float(n @ d)
        if abs(nd) < 1e-9:
            continue
        sg = 1.0 if nd > 0.0 else -1.0
        for j, rc in enumerate(boxes):
            if j == i:
                continue
            v = clipped_vertices(rc, sg * n, sg * offset - tol)
            if not len(v):
                continue
            q = v @ axes.T
            ilo, ihi = np.maximum(q.min(0), own.min(0)), np.minimum(q.max(0), own.max(0))
            if (ilo > ihi).any():
                continue
            lo, hi, any_ = np.minimum(lo, ilo), np.maximum(hi, ihi), True
    return (lo, hi) if any_ else None


def fit_frame(d, instances, res: int, fit: int = 1) -> np.ndarray:
    """The (16,) frame of the map along d (float64; the has-a-map flag 1)."""
    d = np.asarray(d, np.float64)
    d = d / np.linalg.norm(d)
    e1, e2 = complete_frame(d)
    corners = np.concatenate([box_corners(*inst) for inst in instances])
    proj = corners @ np.stack([e1, e2, d]).T
    lo, hi = proj.min(0), proj.max(0)
    floor_size = 1e-6 * max(np.abs(lo).max(), np.abs(hi).max(), 1e-30)
    if fit == 1:
        fp = shadow_footprint(d, e1, e2, instances, floor_size)
        if fp is not None:
            lo[:2], hi[:2] = fp
    du = max(hi[0] - lo[0], floor_size) / (res - 1)
    dv = max(hi[1] - lo[1], floor_size) / (res - 1)
    u0 = 0.5 * (lo[0] + hi[0]) - 0.5 * du * res
    v0 = 0.5 * (lo[1] + hi[1]) - 0.5 * dv * res
    return np.array([*e1, u0, *e2, v0, *d, hi[2], du, dv, max(hi[2] - lo[2], floor_size), 1.0])


GOLDEN_ANGLE = 2.39996322972865332
MAX_SLOPE = 32.0  # DM_MAX_SLOPE
LOBE_CULL = 1e-3  # DM_LOBE_CULL


def map_coordinates(frame, p):
    """(tu, tv, z) of points p (.., 3) in a map: texel coordinates and depth."""
    f = np.asarray(frame, np.float64)
    p = np.asarray(p, np.float64)
    return (p @ f[0:3] - f[3]) / f[12], (p @ f[4:7] - f[7]) / f[13], f[11] - p @ f[8:11]


def rasterise(frame, tris, res: int) -> np.ndarray:
    """(res, res) depths of world triangles (T, 3, 3) in one map: per texel
    centre covered (all barycentric weights >= 0), the least interpolated
    depth (clamped at 0); +inf where nothing covers it."""
    out = np.full((res, res), np.inf)
    for tri in np.asarray(tris, np.float64):
        tu, tv, z = map_coordinates(frame, tri)
        area = (tu[1] - tu[0]) * (tv[2] - tv[0]) - (tu[2] - tu[0]) * (tv[1] - tv[0])
        if not abs(area) > 0:
            continue
        i0, i1 = max(int(np.floor(tu.min() - 0.5)), 0), min(int(np.ceil(tu.max() - 0.5)), res - 1)
        j0, j1 = max(int(np.floor(tv.min() - 0.5)), 0), min(int(np.ceil(tv.max() - 0.5)), res - 1)
        if i1 < i0 or j1 < j0:
            continue
        x, y = np.meshgrid(np.arange(i0, i1 + 1) + 0.5, np.arange(j0, j1 + 1) + 0.5)
        w1 = ((x - tu[0]) * (tv[2] - tv[0]) - (tu[2] - tu[0]) * (y - tv[0])) / area
        w2 = ((tu[1] - tu[0]) * (y - tv[0]) - (x - tu[0]) * (tv[1] - tv[0])) / area
        w0 = 1.0 - w1 - w2
        inside = (w0 >= 0) & (w1 >= 0) & (w2 >= 0)
        depth = np.maximum(w0 * z[0] + w1 * z[1] + w2 * z[2], 0.0)
        block = out[j0:j1 + 1, i0:i1 + 1]
        np.minimum(block, np.where(inside, depth, np.inf), out=block)
    return out


def map_bias(frame, cos_theta, bias: float, slope_bias: float, pcf: int):
    """The depth bias of a lookup (world units): texel x (bias + slope_bias (sqrt(2) pcf + 1) min(tan theta, 32))."""
    c = np.asarray(cos_theta, np.float64)
    tan = np.minimum(np.sqrt(np.maximum(1.0 - c * c, 0.0)) / c, MAX_SLOPE)
    return max(frame[12], frame[13]) * (bias + slope_bias * (math.sqrt(2.0) * pcf + 1.0) * tan)


def visibility(frame, depth, p, b, pcf: int, margin: float = 0.0, grad=(0.0, 0.0)):
    """The share of the (2 pcf + 1)^2 texels around p's whose depth is not in
    front of p by more than the bias b (1 outside the map). With a margin m,
    (lo, hi): the share when comparisons within m of their threshold go dark /
    lit (the float32 kernel may decide those either way). ``grad``: the
    receiver's depth per texel along u and v (receiver_plane, plane_gradient):
    each tap compares the depth of p's tangent plane at its texel centre."""
    res = depth.shape[0]
    tu, tv, z0 = map_coordinates(frame, p)
    z0 = z0 - b
    if not (0 <= tu < res and 0 <= tv < res):
        return 1.0, 1.0
    ci, cj = int(tu), int(tv)
    lo = hi = taps = 0
    for dj in range(-pcf, pcf + 1):
        for di in range(-pcf, pcf + 1):
            i, j = ci + di, cj + dj
            taps += 1
            if i < 0 or j < 0 or i >= res or j >= res:
                lo += 1
                hi += 1
                continue
            stored = depth[j, i]
            z = z0 + grad[0] * (i + 0.5 - tu) + grad[1] * (j + 0.5 - tv)
            lo += z <= stored - margin
            hi += z <= stored + margin
    return lo / taps, hi / taps


def cap_points(d, r: float, samples: int) -> np.ndarray:
    """The cap quadrature's points (samples, 3): rings of equal solid angle
    around unit d within radius r, golden-angle azimuths (dm_cap_lobe)."""
    d = np.asarray(d, np.float64)
    s = 1.0 if d[2] >= 0 else -1.0
    a = -1.0 / (s + d[2])
    b = d[0] * d[1] * a
    t = np.array([1.0 + s * d[0] * d[0] * a, s * b, -s * d[0]])
    bb = np.array([b, s + d[1] * d[1] * a, -d[1]])
    k = np.arange(samples)
    u = (1.0 - math.cos(r)) * (k + 0.5) / samples
    sb = np.sqrt(np.maximum(u * (2.0 - u), 0.0))
    ang = GOLDEN_ANGLE * k
    return (sb * np.cos(ang))[:, None] * t + (sb * np.sin(ang))[:, None] * bb + (1.0 - u)[:, None] * d


def lobe_reaches(n, v, refl, d, r, lobe_fn) -> bool:
    """dm_lobe_reaches: whether the lobe at the cap point nearest to R is at
    least LOBE_CULL of its value at R (always when R is inside the cap or under the horizon)."""
    c = refl @ d
    if c >= math.cos(r):
        return True
    side = refl - c * d
    sl = np.linalg.norm(side)
    if not sl > 0:
        return True
    near = math.cos(r) * d + math.sin(r) * side / sl
    nl, nr = near @ n, refl @ n
    if not nr > 0:
        return True
    if not nl > 0:
        return False
    return lobe_fn(near) * nl >= LOBE_CULL * lobe_fn(refl) * nr


SPECULAR_POINT, SPECULAR_SEED, SPECULAR_CAP, SPECULAR_TABLE = 0, 1, 2, 3
TABLE_MIN_EXPONENT = 32.0  # the renderer's table_min_exponent default


def equivalent_exponent(name: str, shininess: float, roughness: float) -> float:
    """dm_table_lobe's n_eq: the Phong exponent standing for the lobe around R."""
    if name == "phong":
        return shininess
    if name == "blinn_phong":
        return 0.25 * shininess  # cos^n of the half angle ~ cos^(n/4) of the angle to R
    return 0.5 / roughness ** 2  # the Gaussian with GGX's integral (its peak's curvature gives 1 / alpha^2)


def nearest_cap_point(refl, d, r: float):
    """(psi_c, l): R's angle to the cap centre and the cap's point nearest R (R when inside)."""
    c = float(refl @ d)
    side = refl - c * d
    sl = float(np.linalg.norm(side))
    psi_c = math.atan2(sl, c)
    if psi_c <= r:
        return psi_c, refl
    return psi_c, math.cos(r) * d + math.sin(r) * side / sl


def cap_ratio(psi_c: float, r: float, n: float, nodes: int = 400) -> float:
    """The table's H (capi/src/methods/depthmap_table.c) by the exact cap average:
    A(psi_c, r, n) over cos^n of the angle from R to the cap's nearest point."""
    if r <= 0.0:
        return 1.0
    g = max(psi_c - r, 0.0)
    if g >= 0.5 * math.pi:
        return 0.0
    return phong_cap_average(math.cos(psi_c), r, n, nodes) / math.cos(g) ** n


def table_average(n, v, d, r, name, shin, rough, f, nodes: int = 400,
                  min_n: float = TABLE_MIN_EXPONENT, centroid: bool = False) -> float | None:
    """The float64 value the table approximates (dm_table_lobe with the exact
    H instead of the interpolated one); None when n_eq is below the table's range.
    centroid: Blinn-Phong and GGX by the four points about the lobe's centroid (lobe_centroid 1)."""
    if name == "ashikhmin_shirley":
        return None  # anisotropic: no equivalent exponent, the quadrature samples it
    n_eq = equivalent_exponent(name, shin, rough)
    if not n_eq >= max(min_n, 1.0):
        return None
    if name != "phong":  # Blinn-Phong and GGX: their own tables, with the view (depthmap_lobes64)
        import depthmap_lobes64

        rule = depthmap_lobes64.average if centroid else depthmap_lobes64.average_one_point
        return rule(n, v, d, r, name, shin, rough, f)
    refl = 2.0 * (n @ v) * n - v
    psi_c, l = nearest_cap_point(refl, d, r)
    nl = float(n @ l)
    if not nl > 0:
        return 0.0
    return f(l) * nl * cap_ratio(psi_c, r, n_eq, nodes)


def specular_average(n, v, d, r, mat, specular: int, cap_samples: int,
                     table_min_exponent: float = TABLE_MIN_EXPONENT, lobe_centroid: int = 0) -> float:
    """a_i per unit k_s: the lobe times the cosine over domain (d, r) by the chosen rule."""
    from penumbra.brdf import lobe as brdf_lobe, lobe_args

    args = lobe_args(n, mat)
    name, shin = args["lobe"], args["shininess"]
    f = lambda l: float(brdf_lobe(n, v, l, **args))  # noqa: E731
    c = float(n @ d)
    refl = 2.0 * (n @ v) * n - v
    if specular == SPECULAR_TABLE:
        a = table_average(n, v, d, r, name, shin, args.get("roughness", 1.0), f, min_n=table_min_exponent,
                          centroid=bool(lobe_centroid))
        if a is not None:
            return a
    if specular >= SPECULAR_CAP:
        if name != "ashikhmin_shirley" and not lobe_reaches(n, v, refl, d, r, f):  # anisotropic: always sampled
            return 0.0
        pts = cap_points(d, r, cap_samples)
        nl = pts @ n
        up = nl > 0
        vals = brdf_lobe(n, v, pts[up], **args) * nl[up] if up.any() else np.zeros(0)
        return float(np.sum(vals)) / cap_samples
    if specular == SPECULAR_SEED and name == "phong":
        return (shin + 2.0) / (2.0 * math.pi) * float(seed_blend(refl @ d, r, shin)) * c
    return f(d) * c


def plane_bias(frame, n, cos_theta, bias: float, slope_bias: float):
    """receiver_plane: (the constant bias texel x bias (slope_bias unused), the receiver's depth gradient per
    texel (n.e1 du, n.e2 dv) / max(n.d, 1/32)) of a lookup with unit normal n."""
    f = np.asarray(frame, np.float64)
    cd = max(float(cos_theta), 1.0 / MAX_SLOPE)
    return (max(f[12], f[13]) * bias,
            (float(n @ f[0:3]) * f[12] / cd, float(n @ f[4:7]) * f[13] / cd))


def shade(planes, camera_position, domains, frames=None, maps=None, bias=1.0, slope_bias=1.0, pcf=1,
          specular=SPECULAR_CAP, cap_samples=16, margin=0.0, receiver_plane=0):
    """float64 L_o of every foreground pixel, (lo, hi) as in ``visibility``:
    sum_i v_i L~_i (rho/pi max(0, n.d_i) + k_s a_i). ``domains``: (N, 8)
    pn_env_domain records; ``frames`` (N, 16) and ``maps`` (N, res, res) or
    None (every domain visible). Background pixels are left 0."""
    h, w = planes["instance"].shape
    lo, hi = np.zeros((h, w, 3)), np.zeros((h, w, 3))
    dom = np.asarray(domains, np.float64)
    dirs, rad, caps = dom[:, :3], dom[:, 4:7], dom[:, 7]
    for y, x, p, n, v, alb, mat in shading_pixels(planes, camera_position):
        for i in np.flatnonzero(dirs @ n > 0):
            c = float(dirs[i] @ n)
            v_lo = v_hi = 1.0
            if maps is not None:
                if receiver_plane:
                    b, g = plane_bias(frames[i], n, c, bias, slope_bias)
                    v_lo, v_hi = visibility(frames[i], maps[i], p, b, pcf, margin, g)
                else:
                    b = map_bias(frames[i], c, bias, slope_bias, pcf)
                    v_lo, v_hi = visibility(frames[i], maps[i], p, b, pcf, margin)
            if v_hi == 0:
                continue
            a = specular_average(n, v, dirs[i], caps[i], mat, specular, cap_samples) if alb[3] > 0 else 0.0
            term = rad[i] * (alb[:3] / math.pi * c + alb[3] * a)
            lo[y, x] += v_lo * term
            hi[y, x] += v_hi * term
    return lo, hi


def shading_pixels(planes, camera_position):
    """(y, x, position, unit normal, unit view, albedo, material) in float64 of
    every foreground pixel of the G-buffer ``planes``."""
    from penumbra import BACKGROUND

    h, w = planes["instance"].shape
    cam = np.asarray(camera_position, np.float32).astype(np.float64)
    for y in range(h):
        for x in range(w):
            if planes["instance"][y, x] == BACKGROUND:
                continue
            p = planes["position"][y, x, :3].astype(np.float64)
            n = planes["normal"][y, x, :3].astype(np.float64)
            n /= np.linalg.norm(n)
            v = cam - p
            v /= np.linalg.norm(v)
            yield y, x, p, n, v, planes["albedo"][y, x].astype(np.float64), planes["material"][y, x].astype(np.float64)


# --------------------------------------------------------------------------- docs table


def error_rows(env, ns=(16, 32, 64, 128, 256), seed: int = 1, n_normals: int = 512):
    """[(N, Lloyd error, median-cut error, Lloyd iterations)] for docs/depthmap.md."""
    tex = env if isinstance(env, Texels) else texels(env)
    normals = fibonacci_sphere(n_normals)
    exact = exact_irradiance(tex, normals)
    rows = []
    for n in ns:
        dom = decompose(tex, n, seed)
        rows.append((n, irradiance_error(tex, dom, normals, exact=exact),
                     irradiance_error(tex, median_cut(tex, n), normals, exact=exact), dom.iterations))
    return rows


if __name__ == "__main__":  # python tests/depthmap64.py [map.hdr ...]: the error-by-N table
    import sys

    from penumbra import procedural
    from penumbra.imageio import read_envmap

    maps = [("procedural sky 128x64", procedural.sky(128, 64)), ("procedural sky 512x256", procedural.sky(512, 256))]
    maps += [(p.rsplit("/", 1)[-1], read_envmap(p)) for p in sys.argv[1:]]
    for name, env in maps:
        print(f"\n{name} ({env.shape[1]}x{env.shape[0]})\n\n| N | Lloyd | median cut | ratio | Lloyd iterations |\n|---|---|---|---|---|")
        for n, e_l, e_c, it in error_rows(env):
            print(f"| {n} | {e_l:.3g} | {e_c:.3g} | {e_c / e_l:.1f} | {it} |", flush=True)
