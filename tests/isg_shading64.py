"""float64 twin of the isg shading kernel (kernels/isg.cl, docs/isg.md section 8)
and the exact visible integrals it approximates.

The twin follows the kernel step by step (the same frame, window, patch grid,
culling, self-occlusion policy and patch marking by centre direction) with the
float64 pieces of tests/isg64.py in place of the float32 ones: the exact ISG
by quadrature for the patch integrals and the exact SG x clamped cosine.
``visible_exact`` integrates lobe x cosine x visibility by dense quadrature
with exact ray-sphere tests: the ground truth of the patch discretisation.
"""

from __future__ import annotations

import math

import numpy as np
from isg64 import HALF_PI, as_sgs, isg_exact_grid, sg_cosine_exact, sg_hemisphere_integral, sg_product

WINDOW_SIGMAS = 3.0
TOUCH = 1e-3
SELF_MARGIN = 0.02  # kernels/isg.cl PN_ISG_SELF_MARGIN: own spheres this near are skipped (policy 1)
COS_SHARPNESS, COS_AMPLITUDE = 2.133, 1.170
LOBE_PHONG, LOBE_BLINN_PHONG, LOBE_GGX, LOBE_ASHIKHMIN_SHIRLEY = 0, 1, 2, 3
MIN_COS_VIEW = 1e-4


def frame(z):
    """Duff et al. 2017, as pn_sg_frame: (x, y) completing the right-handed (x, y, z)."""
    z = np.asarray(z, np.float64)
    s = math.copysign(1.0, z[2])
    a = -1.0 / (s + z[2])
    b = z[0] * z[1] * a
    x = np.array([1.0 + s * z[0] * z[0] * a, s * b, -s * z[0]])
    y = np.array([b, s + z[1] * z[1] * a, -z[1]])
    return x, y


def window(lam: float) -> float:
    return min(HALF_PI, WINDOW_SIGMAS / math.sqrt(max(lam, 1e-30)))


TREE_FANOUT = 8


def tree_levels(sphere_count: int) -> list[tuple[int, int]]:
    """pn_isg_tree_init: (offset in the node array, node count) of tree levels 1 .. top (the host's
    sphere_tree, penumbra.methods.isg.sphere_tree, stores them one after the other)."""
    out, n, offset = [], sphere_count, 0
    while True:
        offset += out[-1][1] if out else 0
        n = (n + TREE_FANOUT - 1) // TREE_FANOUT
        out.append((offset, n))
        if n <= TREE_FANOUT:
            return out


def _cap_marks(dirs, v, r):
    """The patches whose centre direction lies in the cap of a sphere at v (from the receiver), radius r."""
    d = math.sqrt(v @ v)
    return dirs @ (v / d) >= math.cos(math.asin(min(r / d, 1.0)))


SHELL_FLAT, SHELL_OWN_FLAT = 1e-6, 1e-3


def triangle_marks(dirs, p, n, tri, own, self_occlusion):
    """pn_isg_mark_triangle: the patches whose centre direction d hits triangle ``tri`` (3, 3) from p,
    d = a positive combination of its vertices seen from p, None when the triangle is skipped (wholly
    behind the receiver plane, own under self_occlusion 0, or |det| <= tol |a||b||c|: degenerate, edge-on
    from p, or nearly in the receiver's plane; tol SHELL_OWN_FLAT for own triangles under self_occlusion
    1, else SHELL_FLAT). The cone cull of the kernel drops only triangles that mark nothing."""
    if own and self_occlusion == 0:
        return None
    a, b, c = (np.asarray(v, np.float64) - p for v in tri)
    if a @ n <= 0 and b @ n <= 0 and c @ n <= 0:
        return None
    det = a @ np.cross(b, c)
    tol = SHELL_OWN_FLAT if own and self_occlusion == 1 else SHELL_FLAT
    if not abs(det) > tol * np.linalg.norm(a) * np.linalg.norm(b) * np.linalg.norm(c):
        return None
    sg = 1.0 if det > 0 else -1.0
    return ((dirs @ (sg * np.cross(b, c)) >= 0) & (dirs @ (sg * np.cross(c, a)) >= 0)
            & (dirs @ (sg * np.cross(a, b)) >= 0))


def patch_mask(axis, lam, p, n, self_id, self_occlusion, spheres, owners, grid, tree=None, shells=None,
               skins=None, inside_other=0):
    """(mask (grid, grid) bool, inside): the patches whose centre direction
    meets a sphere, as the kernel marks them (inside: the receiver is inside
    another instance's sphere under inside_other 0, or its own with
    self_occlusion 2).

    skins: per sphere, how far the receiver is pushed out along n before that
    sphere is tested when it holds or nearly touches the receiver (an own
    sphere under self_occlusion 1 within SELF_MARGIN, another instance's under
    inside_other 2); 0 or None: such a sphere is skipped. inside_other 1:
    another instance's sphere holding the receiver is skipped.

    tree = (nodes, lod): the LOD cut (kernels/isg.cl pn_isg_mark; docs/isg.md
    section 8). ``spheres`` and ``owners`` are then in the order of
    penumbra.methods.isg.sphere_tree and ``nodes`` its nodes; walking the tree
    from the top, a node wholly in front of the receiver plane (c.n >= r from
    the receiver) whose angular radius is below half the cut's angle
    (r < d sin(min(lod step / 2, 1.5)), step the patch width) marks its own cap
    instead of its spheres'. Not with self_occlusion 0, nor with lod 0 (the
    exact marking).

    shells = (triangles (T, 3, 3), owners): thin-shell triangles, marked
    after the spheres into the same mask (triangle_marks)."""
    x, y = frame(axis)
    w = window(lam)
    lo, step = HALF_PI - w, 2.0 * w / grid
    centres = lo + (np.arange(grid) + 0.5) * step
    th, ph = np.meshgrid(centres, centres, indexing="ij")
    dirs = (np.sin(th) * np.cos(ph))[..., None] * x + np.cos(th)[..., None] * y + (np.sin(th) * np.sin(ph))[..., None] * axis
    mask = np.zeros((grid, grid), bool)
    spheres = np.asarray(spheres, np.float64).reshape(-1, 4)
    skins = np.zeros(len(spheres)) if skins is None else np.asarray(skins, np.float64)
    p, n = np.asarray(p, np.float64), np.asarray(n, np.float64)

    def mark_sphere(s, own_id, skin) -> bool:  # True: the receiver is inside an occluder
        v = s[:3] - p
        r = s[3]
        if v @ n <= -r:
            return False
        own = own_id == self_id
        if own and self_occlusion == 0:
            return False
        held = v @ v <= (r * (1.0 + TOUCH)) ** 2
        if (own and self_occlusion == 1 and v @ v <= (r * (1.0 + SELF_MARGIN)) ** 2) or (held and not own):
            if held and not own and inside_other == 0:
                return True
            if skin <= 0.0 or (not own and inside_other == 1):
                return False
            v = s[:3] - (p + skin * n)  # seen from the receiver pushed out along its normal
            if v @ n <= -r or v @ v <= (r * (1.0 + TOUCH)) ** 2:
                return False
        elif held:
            return True
        mask[...] |= _cap_marks(dirs, v, r)
        return False

    def mark_shells():
        for tri, own_id in zip(*(shells if shells is not None else ((), ()))):
            m = triangle_marks(dirs, p, n, np.asarray(tri, np.float64).reshape(3, 3), own_id == self_id,
                               self_occlusion)
            if m is not None:
                mask[...] |= m
        return mask, False

    lod = 0.0 if tree is None or self_occlusion == 0 or not len(spheres) else float(tree[1])
    if lod <= 0.0:
        for s, own_id, skin in zip(spheres, owners, skins):
            if mark_sphere(s, own_id, skin):
                return mask, True
        return mark_shells()
    nodes = np.asarray(tree[0], np.float64)
    levels = tree_levels(len(spheres))
    sin_lod = math.sin(min(0.5 * lod * step, 1.5))

    def walk(level, i) -> bool:
        b = nodes[levels[level - 1][0] + i]
        v = b[:3] - p
        if v @ n <= -b[3]:  # wholly behind the receiver plane: so are its spheres
            return False
        if v @ n >= b[3] and b[3] ** 2 < sin_lod ** 2 * (v @ v):
            mask[...] |= _cap_marks(dirs, v, b[3])
            return False
        if level > 1:
            return any(walk(level - 1, c) for c in range(TREE_FANOUT * i, min(TREE_FANOUT * (i + 1),
                                                                              levels[level - 2][1])))
        return any(mark_sphere(spheres[s], owners[s], skins[s])
                   for s in range(TREE_FANOUT * i, min(TREE_FANOUT * (i + 1), len(spheres))))

    if any(walk(len(levels), i) for i in range(levels[-1][1])):
        return mask, True
    return mark_shells()


def visibility(axis, lam, p, n, self_id, self_occlusion, spheres, owners, grid, tree=None, shells=None,
               skins=None, inside_other=0):
    """V = 1 - sum of occluded patches / window, by the exact ISG (tree: patch_mask's LOD cut; shells:
    its thin-shell triangles; skins, inside_other: patch_mask's)."""
    mask, inside = patch_mask(axis, lam, p, n, self_id, self_occlusion, spheres, owners, grid, tree, shells,
                              skins, inside_other)
    if inside:
        return 0.0
    if not mask.any():
        return 1.0
    w = window(lam)
    edges = HALF_PI - w + np.arange(grid + 1) * (2.0 * w / grid)
    s = isg_exact_grid(lam, edges, edges)
    patches = s[1:, 1:] - s[:-1, 1:] - s[1:, :-1] + s[:-1, :-1]
    total = s[-1, -1] - s[0, -1] - s[-1, 0] + s[0, 0]
    return float(np.clip(1.0 - patches[mask].sum() / total, 0.0, 1.0))


def irradiance(axis, lam, mu, n) -> np.ndarray:
    """mu * int exp(lam (v.axis - 1)) max(v.n, 0) dv, exact."""
    t = float(np.clip(np.dot(axis, n), -1.0, 1.0))
    return np.asarray(mu, np.float64) * float(sg_cosine_exact(np.array([t]), lam)[0])


def brdf_sg(n, view, shininess, roughness, lobe):
    """pn_brdf_sg (common/sg.cl): the BRDF lobe as an SG (axis, sharpness, amplitude)."""
    nv_raw = float(np.dot(n, view))
    nv = max(nv_raw, MIN_COS_VIEW)
    r = 2.0 * nv_raw * n - view
    if lobe == LOBE_PHONG:
        return r, shininess, (shininess + 2.0) / (2.0 * math.pi)
    if lobe == LOBE_BLINN_PHONG:
        return r, shininess / (4.0 * nv), (shininess + 8.0) / (8.0 * math.pi)
    a = min(max(roughness, 1e-3), 1.0)
    a2 = a * a
    nl = max(float(np.dot(n, r)), 0.0)
    g1c = lambda c: 2.0 / (c + math.sqrt(a2 + (1.0 - a2) * c * c))  # noqa: E731  G1(c) / c, finite at c = 0
    return r, 2.0 / (a2 * 4.0 * nv), g1c(nv) * g1c(nl) * 0.25 / (math.pi * a2)


def brdf_sgs(n, view, material):
    """pn_brdf_sgs: [(axis, sharpness, amplitude)], material (shininess, roughness, lobe) or the
    G-buffer's (n_u, n_v, 3, tangent angle) for the anisotropic lobe's 7 SGs."""
    if int(material[2]) == LOBE_ASHIKHMIN_SHIRLEY:
        from penumbra.brdf import tangent_from_angle
        return as_sgs(n, view, material[0], material[1], tangent_from_angle(n, material[3]))
    return [brdf_sg(n, view, *material[:3])]


def cube_face(d) -> int:
    """The face pn_dir_to_cube picks for direction d (+x, -x, +y, -y, +z, -z)."""
    ax, ay, az = abs(d[0]), abs(d[1]), abs(d[2])
    if ax >= ay and ax >= az:
        return 0 if d[0] > 0 else 1
    if ay >= az:
        return 2 if d[1] > 0 else 3
    return 4 if d[2] > 0 else 5


def cube_dir(face: int, a, b) -> np.ndarray:
    """pn_cube_to_dir: the unnormalised direction of face coordinates (a, b) (arrays broadcast)."""
    a, b = np.broadcast_arrays(np.asarray(a, np.float64), np.asarray(b, np.float64))
    one = np.ones_like(a)
    return np.stack({0: (one, -b, -a), 1: (-one, -b, a), 2: (a, one, b), 3: (a, -one, -b), 4: (a, -b, one),
                     5: (-a, -b, -one)}[face], -1)


def cube_directions(n: int) -> np.ndarray:
    """envmap_cube_directions: (6 n n, 4) unit texel-centre directions and exact solid angles, texel order
    pn_cube_index (face, row j, column i)."""
    e = -1.0 + 2.0 * np.arange(n + 1) / n
    c = 0.5 * (e[1:] + e[:-1])
    area = lambda x, y: np.arctan2(x * y, np.sqrt(x * x + y * y + 1.0))  # noqa: E731
    w = (area(e[None, :-1], e[:-1, None]) - area(e[None, :-1], e[1:, None]) - area(e[None, 1:], e[:-1, None])
         + area(e[None, 1:], e[1:, None]))  # [j, i]
    out = []
    for f in range(6):
        d = cube_dir(f, c[None, :], c[:, None])
        out.append(np.concatenate([d / np.linalg.norm(d, axis=-1, keepdims=True), w[..., None]], -1).reshape(-1, 4))
    return np.concatenate(out)


def cube_halve(cube: np.ndarray, dirs: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """isg_cube_halve: each texel of the n / 2 cube the solid-angle-weighted mean of its 2 x 2 children,
    its solid angle their sum, its direction their power centroid (directions weighted by solid angle x
    (sum of RGB + 1e-30), normalised). cube: (6 n n, 3)."""
    h = n // 2
    w = dirs[:, 3].reshape(6, h, 2, h, 2)
    lw = (cube[:, :3] * dirs[:, 3:]).reshape(6, h, 2, h, 2, 3).sum((2, 4))
    power = dirs[:, 3:] * (cube[:, :3].sum(-1, keepdims=True) + 1e-30)
    dw = (dirs[:, :3] * power).reshape(6, h, 2, h, 2, 3).sum((2, 4))
    ws = w.sum((2, 4))[..., None]
    out_dirs = np.concatenate([dw / np.linalg.norm(dw, axis=-1, keepdims=True), ws], -1).reshape(-1, 4)
    return np.where(ws > 0, lw / np.where(ws > 0, ws, 1.0), 0.0).reshape(-1, 3), out_dirs


def sky_cube(face: int, sun: float = 0.0, seed: int = 1) -> np.ndarray:
    """A test env: a smooth sky with a horizon, a coloured blob and ripples, optionally a one-texel sun
    sun:1 brighter than the sky's mean: (6 face face, 3) radiance in cube texel order."""
    d = cube_directions(face)[:, :3]
    rng = np.random.default_rng(seed)
    c = rng.uniform(-1, 1, 3)
    c /= np.linalg.norm(c)
    up = np.clip(d[:, 1], 0.0, None)
    rgb = np.stack([0.3 + up, 0.4 + 1.2 * up, 0.6 + 2.0 * up], -1)
    rgb += np.outer(np.exp(8.0 * (d @ c - 1.0)), [2.0, 1.0, 0.3])
    rgb += 0.2 * np.outer(np.sin(9.0 * d[:, 0]) * np.cos(7.0 * d[:, 2]) ** 2, [1.0, 1.0, 1.0])
    if sun:
        s = np.argmax(d @ np.array([0.3, 0.8, 0.52]) / np.linalg.norm([0.3, 0.8, 0.52]))
        rgb[s] = sun * rgb.mean()
    return rgb


GAMMA_CUT = 20.0  # PN_ISG_GAMMA_CUT: the lobe's tail below e^-20 is dropped


def gamma_vertices(n_out: int) -> np.ndarray:
    """The unit directions of a vertex-grid cube of n_out vertices a side, in pn_cube_index order."""
    t = -1.0 + 2.0 * np.arange(n_out) / (n_out - 1)
    d = np.concatenate([cube_dir(f, t[None, :], t[:, None]).reshape(-1, 3) for f in range(6)])
    return d / np.linalg.norm(d, axis=-1, keepdims=True)


def prefilter(cube: np.ndarray, dirs: np.ndarray, lam: float, directions: np.ndarray, cut: float | None = GAMMA_CUT):
    """isg_prefilter: Gamma_L(a, lam) = sum_t w_t L_t e^{lam (a.t - 1)} / sum_t w_t e^{lam (a.t - 1)} over the
    source texels t (every texel: no window), for each row a of ``directions``; cut: texels with
    lam (1 - a.t) > cut dropped from both sums (None: none dropped, the exact convolution of the texels)."""
    directions = np.asarray(directions, np.float64)
    out = np.zeros((len(directions), 3))
    for k in range(0, len(directions), 1024):  # in blocks: (directions x texels) matrices of at most ~50 MB
        c = directions[k:k + 1024] @ dirs[:, :3].T
        w = dirs[None, :, 3] * np.exp(lam * (c - 1.0))
        if cut is not None:
            w = np.where(c >= 1.0 - cut / lam, w, 0.0)
        s = w.sum(1, keepdims=True)
        out[k:k + 1024] = np.where(s > 0, (w @ cube[:, :3]) / np.where(s > 0, s, 1.0), 0.0)
    return out


def build_gamma(cube: np.ndarray, dirs: np.ndarray, face: int, levels) -> list[np.ndarray]:
    """Every level of Gamma_L (levels: penumbra.methods.isg.gamma_levels(face)), each (6 n n, 3)."""
    sources = {face: (np.asarray(cube, np.float64)[:, :3], np.asarray(dirs, np.float64))}
    m = face
    while m % 2 == 0 and m // 2 >= 2 and len(sources) < 12:
        sources[m // 2] = cube_halve(*sources[m], m)
        m //= 2
    return [prefilter(*sources[n_src], lam, gamma_vertices(n_out)) for lam, n_out, n_src in levels]


def grid_lookup(grid: np.ndarray, n: int, d) -> np.ndarray:
    """pn_cube_grid_lookup: bilinear in the vertex-grid cube (6 n n, 3) at direction d."""
    d = np.asarray(d, np.float64)
    f = cube_face(d)
    ax = [0, 0, 1, 1, 2, 2][f]
    de = abs(d[ax])
    u = cube_dir(f, 1.0, 0.0) - cube_dir(f, 0.0, 0.0)
    v = cube_dir(f, 0.0, 1.0) - cube_dir(f, 0.0, 0.0)
    x = min(max((float(d @ u) / de + 1.0) * 0.5 * (n - 1), 0.0), n - 1.0)
    y = min(max((float(d @ v) / de + 1.0) * 0.5 * (n - 1), 0.0), n - 1.0)
    x0, y0 = min(int(x), n - 2), min(int(y), n - 2)
    fx, fy = x - x0, y - y0
    g = grid.reshape(6, n, n, 3)[f]
    top = g[y0, x0] * (1 - fx) + g[y0, x0 + 1] * fx
    bottom = g[y0 + 1, x0] * (1 - fx) + g[y0 + 1, x0 + 1] * fx
    return top * (1 - fy) + bottom * fy


def gamma_lookup(levels, tables, d, lam: float) -> np.ndarray:
    """pn_isg_gamma: bilinear in direction on the levels around lam, linear in log2 lam, clamped to the ends."""
    count = len(levels)
    t = min(max(math.log2(max(lam, 1e-30) / levels[0][0]), 0.0), count - 1.0)
    l0 = min(int(t), max(count - 2, 0))
    l1 = min(l0 + 1, count - 1)
    g0 = grid_lookup(tables[l0], levels[l0][1], d)
    g1 = grid_lookup(tables[l1], levels[l1][1], d)
    return g0 + (g1 - g0) * (t - l0)


def env_specular(axis, lam, mu, p, n, self_id, self_occlusion, spheres, owners, grid, face_rgb,
                 gamma=None, tree=None, shells=None, skins=None, inside_other=0) -> np.ndarray:
    """pn_isg_env_specular with a cube of one texel per face (face_rgb (6, 3)):
    mu H(lam) sum over visible patches of ISG(patch) L(centre) max(n.centre, 0); with gamma = (levels,
    tables) (specular_mode 1) L(centre) is Gamma_L(axis, lam) for every patch."""
    mask, inside = patch_mask(axis, lam, p, n, self_id, self_occlusion, spheres, owners, grid, tree, shells,
                              skins, inside_other)
    if inside:
        return np.zeros(3)
    x, y = frame(axis)
    w = window(lam)
    edges = HALF_PI - w + np.arange(grid + 1) * (2.0 * w / grid)
    s = isg_exact_grid(lam, edges, edges)
    patches = s[1:, 1:] - s[:-1, 1:] - s[1:, :-1] + s[:-1, :-1]
    centres = HALF_PI - w + (np.arange(grid) + 0.5) * (2.0 * w / grid)
    light = None if gamma is None else gamma_lookup(*gamma, axis, lam)
    out = np.zeros(3)
    for i, th in enumerate(centres):
        for j, ph in enumerate(centres):
            if mask[i, j]:
                continue
            d = math.sin(th) * math.cos(ph) * x + math.cos(th) * y + math.sin(th) * math.sin(ph) * axis
            c = float(d @ n)
            if c > 0:
                out += patches[i, j] * c * (np.asarray(face_rgb[cube_face(d)], np.float64) if light is None
                                            else light)
    return np.asarray(mu, np.float64) * float(sg_hemisphere_integral(lam)) * out


LOBE_CUBE_N = 65  # capi/src/methods/isg.c LOBE_CUBE_N


def lobe_cube(lobes, sharpness: float, n: int = LOBE_CUBE_N) -> np.ndarray:
    """The host's lobe_cube: sum over the lobes (K, 7) with lambda <= sharpness of mu e^{lambda (d.axis - 1)}
    at every vertex d of a vertex-grid cube of n a side (6 n n, 3), in float64."""
    d = gamma_vertices(n)
    out = np.zeros((len(d), 3))
    for lobe in np.asarray(lobes, np.float64):
        if lobe[3] <= sharpness:
            out += np.exp(lobe[3] * (d @ lobe[:3] - 1.0))[:, None] * lobe[4:7]
    return out


def shared_occluded(p, n, self_id, self_occlusion, spheres, owners, grid, cube, cube_n=LOBE_CUBE_N, tree=None,
                    shells=None, light=None, skins=None, inside_other=0):
    """(O, inside) of pn_isg_shared_occluded: the receiver's hemisphere as the window of axis n with w = pi/2
    (patch_mask at lambda 0), O = sum over marked patches of L_b(d) (n.d) Omega, Omega the patch's solid angle
    (delta phi (cos theta0 - cos theta1), theta from the frame's y axis), L_b the bilinear lookup of ``cube``
    (grid_lookup), or ``light(d)`` when given (the exact lobe sum, for the cube's error)."""
    p, n = np.asarray(p, np.float64), np.asarray(n, np.float64)
    mask, inside = patch_mask(n, 0.0, p, n, self_id, self_occlusion, spheres, owners, grid, tree, shells,
                              skins, inside_other)
    if inside or not mask.any():
        return np.zeros(3), inside
    x, y = frame(n)
    step = math.pi / grid
    out = np.zeros(3)
    for i, j in zip(*np.nonzero(mask)):
        th, ph = (i + 0.5) * step, (j + 0.5) * step
        d = math.sin(th) * (math.cos(ph) * x + math.sin(ph) * n) + math.cos(th) * y
        omega = step * (math.cos(i * step) - math.cos((i + 1) * step))
        rad = light(d) if light is not None else grid_lookup(cube, cube_n, d)
        out += rad * float(d @ n) * omega
    return out, False


def shade(p, n, albedo, ks, material, camera, self_id, lobes, spheres, owners, grid, self_occlusion=1,
          specular_shadows=1, env_sharpness=math.inf, face_rgb=None, gamma=None, tree=None,
          shells=None, shared=None, skins=None, inside_other=0) -> np.ndarray:
    """One pixel of shade_isg. lobes: (K, 7) axis xyz, sharpness, amplitude rgb;
    face_rgb: the env cube as one RGB per face (used by the env specular path,
    for BRDF lobes at least env_sharpness sharp); gamma: (levels, tables) of
    Gamma_L for specular_mode 1 (None: specular_mode 0); tree: (nodes, lod) of the LOD cut, the spheres
    in penumbra.methods.isg.sphere_tree's order (patch_mask); shells: (triangles (T, 3, 3), owners) of
    the thin shells; shared: (M_s, shared_sharpness, cube[, env_irradiance]) of the shared hemisphere grid
    (shared_occluded; None: off), cube from lobe_cube(lobes, shared_sharpness); env_irradiance (shared_light
    1): a function of n giving the env's irradiance, from which the lobes with their own windows are
    subtracted to give the shared lobes' unshadowed irradiance (else their closed forms are summed);
    skins, inside_other: patch_mask's (the self_push skins per sphere and the inside_other policy)."""
    p, n = np.asarray(p, np.float64), np.asarray(n, np.float64)
    n = n / np.linalg.norm(n)
    diffuse, specular = np.zeros(3), np.zeros(3)
    env_path = False
    if ks > 0:
        view = np.asarray(camera, np.float64) - p
        sgs = brdf_sgs(n, view / np.linalg.norm(view), material)
        b_axis, b_lam, b_mu = sgs[0]
        env_path = len(sgs) == 1 and b_lam >= env_sharpness
        if env_path:
            specular = env_specular(b_axis, b_lam, b_mu, p, n, self_id, self_occlusion if specular_shadows else 0,
                                    spheres if specular_shadows else [], owners, grid, face_rgb, gamma,
                                    tree if specular_shadows else None, shells if specular_shadows else None,
                                    skins if specular_shadows else None, inside_other)
    shared_e, own_e = np.zeros(3), np.zeros(3)
    for lobe in np.asarray(lobes, np.float64):
        axis, lam, mu = lobe[:3], lobe[3], lobe[4:7]
        e = irradiance(axis, lam, mu, n)
        own_window = shared is None or lam > shared[1]
        if own_window:
            own_e += e
        else:
            shared_e += e
        if own_window and (e > 0).any():
            m_axis, m_lam, _ = sg_product(axis, lam, 1.0, n, COS_SHARPNESS, COS_AMPLITUDE)
            diffuse += e * visibility(m_axis, float(m_lam), p, n, self_id, self_occlusion, spheres, owners, grid,
                                      tree, shells, skins, inside_other)
        for b_axis, b_lam, b_mu in (sgs if ks > 0 and not env_path else []):
            g_axis, g_lam, g_mu = sg_product(axis, lam, 1.0, b_axis, b_lam, b_mu)
            s = irradiance(g_axis, float(g_lam), mu * g_mu, n)
            if (s > 0).any():
                v = visibility(g_axis, float(g_lam), p, n, self_id, self_occlusion, spheres, owners, grid, tree,
                               shells, skins, inside_other) \
                    if specular_shadows else 1.0
                specular += s * v
    if shared is not None and len(shared) > 3 and shared[3] is not None:
        shared_e = np.asarray(shared[3](n), np.float64) - own_e
    if shared is not None and (shared_e > 0).any():
        o, inside = shared_occluded(p, n, self_id, self_occlusion, spheres, owners, shared[0], shared[2], tree=tree,
                                    shells=shells, skins=skins, inside_other=inside_other)
        diffuse += 0.0 if inside else np.maximum(shared_e - o, 0.0)
    return np.maximum(np.asarray(albedo, np.float64) / math.pi * diffuse + ks * specular, 0.0)


def sphere_directions(count: int) -> tuple[np.ndarray, float]:
    """A Fibonacci set of unit directions and the solid angle of each."""
    i = np.arange(count) + 0.5
    z = 1.0 - 2.0 * i / count
    r = np.sqrt(1.0 - z * z)
    ang = math.pi * (3.0 - math.sqrt(5.0)) * i
    return np.stack([r * np.cos(ang), r * np.sin(ang), z], -1), 4.0 * math.pi / count


def visible_exact(axis, lam, mu, p, n, spheres, count: int = 400_000) -> np.ndarray:
    """int G(v) max(v.n, 0) V(v) dv with V by exact ray-sphere tests (every
    sphere counts), by a Fibonacci quadrature of ``count`` directions. With
    n = None: int over the lobe's front hemisphere of G V (what the patches
    discretise)."""
    d, dw = sphere_directions(count)
    p = np.asarray(p, np.float64)
    cos = np.maximum(d @ n, 0.0) if n is not None else (d @ np.asarray(axis, np.float64) >= 0.0).astype(float)
    g = np.exp(lam * (d @ np.asarray(axis, np.float64) - 1.0)) * cos
    visible = np.ones(len(d), bool)
    for s in np.asarray(spheres, np.float64):
        oc = p - s[:3]
        b = d @ oc
        c = oc @ oc - s[3] ** 2
        disc = b * b - c
        hit = disc >= 0
        t_far = -b + np.sqrt(np.maximum(disc, 0.0))
        visible &= ~(hit & (t_far > 0))
    return np.asarray(mu, np.float64) * float((g * visible).sum() * dw)
