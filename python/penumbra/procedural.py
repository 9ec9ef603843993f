"""Procedural content: environment maps, shapes and terrain for the default scene and tests.

Everything here is deterministic (no global random state).

Lat-long convention (project-wide, as in Mitsuba 3; right-handed, y up):
pixel (i = column, j = row) of a W x H map has its centre at
u = (i + 0.5) / W, v = (j + 0.5) / H, and the direction of (u, v) is

    phi = 2 pi u,  theta = pi v,
    d = (sin(phi) sin(theta), cos(theta), -cos(phi) sin(theta)),

so row 0 is the +y (top) side, u = 0 is -z, 0.25 is +x, 0.5 is +z, 0.75 is -x.
A pixel in row j covers the solid angle (2 pi / W) (cos(theta_top) - cos(theta_bottom)).
:func:`latlong_directions`, :func:`latlong_row_solid_angles`,
:func:`direction_to_pixel` and :func:`envmap_integral` implement it.

Environment maps are float32 arrays (H, W, 3) of linear RGB radiance:
:func:`sky`, :func:`constant`, :func:`directional`, :func:`two_area_lights`.
Emitters that are small compared with a pixel are rasterised with
area-correct coverage, so the power they carry does not depend on the resolution.

Shapes are :class:`~penumbra.meshio.Mesh` objects centred at the origin (the
torus knot by its centroid), with counter-clockwise winding seen from outside
(``cross(v1 - v0, v2 - v0)`` points outward) and unit per-vertex normals:
:func:`sphere`, :func:`box`, :func:`plane`, :func:`torus`, :func:`cylinder`,
:func:`cone`, :func:`torus_knot`, :func:`rounded_cube`.

:func:`terrain_heights` returns a fractal (fBm) height field.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from .errors import InputError
from .meshio import Mesh

__all__ = [
    "latlong_directions", "latlong_row_solid_angles", "direction_to_pixel", "envmap_integral",
    "sky", "constant", "directional", "two_area_lights",
    "sphere", "box", "plane", "torus", "cylinder", "cone", "torus_knot", "rounded_cube",
    "terrain_heights",
]


# --------------------------------------------------------------------------- #
# Lat-long convention helpers
# --------------------------------------------------------------------------- #


# Resource limits (docs/reliability.md): procedural content is made in
# memory, in float64, so every size is bounded before anything is allocated.
# A request beyond a limit is an InputError that names it.
MAX_ENV_WIDTH = 8192            # lat-long map columns
MAX_ENV_HEIGHT = 4096           # lat-long map rows
MAX_ENV_PIXELS = 1 << 22        # width x height (about 0.5 GB of float64 temporaries for the sky)
MAX_TRIANGLES = 1 << 22         # triangles of one shape (a sphere: subdivisions <= 8)
MAX_SEGMENTS = 1 << 16          # one count of a shape (segments, tube_segments, p, q)
MAX_TERRAIN_SIDE = 16384        # terrain_heights nx, ny
MAX_TERRAIN_SAMPLES = 1 << 24   # nx x ny
MAX_OCTAVES = 32


def _integer(value, name: str, minimum: int, maximum: int) -> int:
    """``value`` as an int in [minimum, maximum] (an integral float is accepted), else InputError naming ``name``."""
    ok = False
    if isinstance(value, (int, np.integer)) and not isinstance(value, (bool, np.bool_)):
        ok = True
    elif isinstance(value, (float, np.floating)) and math.isfinite(value) and float(value).is_integer():
        ok = True
    if not ok:
        raise InputError(f"{name} must be an integer, got {_shown(value)}")
    if not minimum <= value <= maximum:
        raise InputError(f"{name} = {_shown(value)} is above {maximum}, the limit of penumbra.procedural "
                         "(docs/reliability.md)" if value > maximum else
                         f"{name} must be an integer >= {minimum}, got {_shown(value)}")
    return int(value)


def _shown(value) -> str:
    text = repr(value)
    return text if len(text) <= 60 else f"{text[:40]}... ({len(text)} characters)"


def _check_triangles(count: int, what: str) -> None:
    if count > MAX_TRIANGLES:
        raise InputError(f"{what} gives {count} triangles, more than the limit of {MAX_TRIANGLES} "
                         "(penumbra.procedural.MAX_TRIANGLES)")


def _check_size(width: int, height: int) -> tuple[int, int]:
    width = _integer(width, "width", 1, MAX_ENV_WIDTH)
    height = _integer(height, "height", 1, MAX_ENV_HEIGHT)
    if width * height > MAX_ENV_PIXELS:
        raise InputError(f"an environment map of {width}x{height} has more than {MAX_ENV_PIXELS} pixels, the limit "
                         "(penumbra.procedural.MAX_ENV_PIXELS)")
    return width, height


def _direction(phi: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """Unit direction for lat-long angles (broadcasting), last axis xyz."""
    sin_theta = np.sin(theta)
    return np.stack(np.broadcast_arrays(np.sin(phi) * sin_theta, np.cos(theta), -np.cos(phi) * sin_theta), axis=-1)


def latlong_directions(width: int, height: int) -> np.ndarray:
    """Unit directions of the pixel centres of a W x H lat-long map, float64 (H, W, 3)."""
    width, height = _check_size(width, height)
    phi = 2.0 * np.pi * (np.arange(width) + 0.5) / width
    theta = np.pi * (np.arange(height) + 0.5) / height
    return _direction(phi[None, :], theta[:, None])


def latlong_row_solid_angles(width: int, height: int) -> np.ndarray:
    """Solid angle of one pixel in each row of a W x H lat-long map, float64 (H,).

    They sum (times W) to exactly 4 pi up to rounding.
    """
    width, height = _check_size(width, height)
    cos_edges = np.cos(np.pi * np.arange(height + 1) / height)
    return (2.0 * np.pi / width) * (cos_edges[:-1] - cos_edges[1:])


def direction_to_pixel(direction: Sequence[float], width: int, height: int) -> tuple[int, int]:
    """(column i, row j) of the lat-long pixel containing ``direction`` (need not be normalised)."""
    width, height = _check_size(width, height)
    d = _unit(direction, "direction")
    u = math.atan2(d[0], -d[2]) / (2.0 * math.pi)
    u = u - math.floor(u)  # wrap to [0, 1)
    v = math.acos(min(1.0, max(-1.0, d[1]))) / math.pi
    return min(int(u * width), width - 1), min(int(v * height), height - 1)


def envmap_integral(envmap: np.ndarray) -> np.ndarray:
    """Integral of radiance over the sphere, sum of L * pixel solid angle, float64 per channel."""
    envmap = np.asarray(envmap)
    if envmap.ndim != 3:
        raise InputError(f"expected an environment map of shape (H, W, C), got {envmap.shape}")
    omega = latlong_row_solid_angles(envmap.shape[1], envmap.shape[0])
    return np.einsum("hwc,h->c", envmap.astype(np.float64), omega)


def _floats(value, name: str, what: str) -> np.ndarray:
    """``value`` as a float64 array, or InputError naming ``name`` (``what``: what it must be)."""
    if isinstance(value, (str, bytes, dict)):
        raise InputError(f"{name} must be {what}, got {_shown(value)}")
    try:
        return np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError, OverflowError):
        raise InputError(f"{name} must be {what}, got {_shown(value)}") from None


def _unit(vector: Sequence[float], name: str) -> np.ndarray:
    v = _floats(vector, name, "3 finite numbers")
    if v.shape != (3,) or not np.isfinite(v).all():
        raise InputError(f"{name} must be 3 finite numbers, got {vector!r}")
    length = float(np.linalg.norm(v))
    if length == 0.0:
        raise InputError(f"{name} must not be the zero vector")
    return v / length


def _rgb(value: float | Sequence[float], name: str) -> np.ndarray:
    v = _floats(value, name, "one number or 3 numbers (RGB)")
    if v.shape not in ((), (1,), (3,)):
        raise InputError(f"{name} must be one number or 3 numbers (RGB), got {_shown(value)}")
    rgb = np.broadcast_to(v, (3,)).copy()
    if not np.isfinite(rgb).all() or (rgb < 0).any():
        raise InputError(f"{name} must be finite and non-negative, got {value!r}")
    return rgb


# --------------------------------------------------------------------------- #
# Environment maps
# --------------------------------------------------------------------------- #

# Sky palette (linear RGB radiance, order of magnitude 1).
_ZENITH = np.array([0.16, 0.32, 0.80])
_HORIZON = np.array([0.85, 0.90, 1.00])
_GROUND = np.array([0.10, 0.085, 0.065])
_GLOW = np.array([1.00, 0.85, 0.60])


def sky(width: int = 512, height: int = 256, sun_direction: Sequence[float] = (0.4, 0.6, 0.3),
        sun_angular_radius_deg: float = 1.5,
        sun_radiance: float | Sequence[float] = (10000.0, 9600.0, 8800.0)) -> np.ndarray:
    """A clear sky with a sun: a smooth analytic gradient plus a small, very bright disc.

    The sky goes from a whitish horizon to a blue zenith, with a warm glow
    around the sun; below the horizon is a dim grey-brown ground, blended over
    +-3 degrees so the map stays smooth. Sky radiance is of order 1, the
    sun's (``sun_radiance``, RGB or scalar) about 1e4 times that, so the map
    has both low- and very high-frequency lighting.

    The sun is a disc of angular radius ``sun_angular_radius_deg`` around
    ``sun_direction`` (normalised here), added on top of the sky. Its pixels get
    ``sun_radiance`` times the fraction of their solid angle that the disc
    covers (area-correct coverage, see :func:`_disc_coverage`), so the integral
    of the sun's radiance over the sphere is ``sun_radiance * 2 pi (1 - cos r)``
    (to about 1e-4) at any resolution, even when the sun is smaller than a pixel.
    """
    width, height = _check_size(width, height)
    sun = _unit(sun_direction, "sun_direction")
    radius = math.radians(_finite(sun_angular_radius_deg, "sun_angular_radius_deg"))
    if not (0.0 < radius < math.pi / 2):
        raise InputError(f"sun_angular_radius_deg must be in (0, 90), got {sun_angular_radius_deg!r}")
    sun_rgb = _rgb(sun_radiance, "sun_radiance")

    d = latlong_directions(width, height)
    elevation = d[..., 1]  # sine of the elevation angle
    cos_gamma = d @ sun  # cosine of the angle to the sun

    t = np.clip(elevation, 0.0, 1.0)[..., None]
    upper = _HORIZON + (_ZENITH - _HORIZON) * np.sqrt(t)
    # Circumsolar glow: a broad halo (~20 degrees) and a tighter aureole (~5 degrees).
    glow = 1.5 * np.exp((cos_gamma - 1.0) / 0.06) + 4.0 * np.exp((cos_gamma - 1.0) / 0.004)
    upper = upper + glow[..., None] * _GLOW
    lower = _GROUND * (0.7 + 0.3 * np.exp(np.minimum(elevation, 0.0) / 0.15))[..., None]
    # Smoothstep across the horizon (+-3 degrees): a hard edge would put a
    # discontinuity into the lighting that no band-limited method could represent.
    s = np.clip((elevation + 0.05) / 0.1, 0.0, 1.0)[..., None]
    blend = s * s * (3.0 - 2.0 * s)
    env = lower + (upper - lower) * blend

    coverage = _disc_coverage(width, height, sun, radius)
    env += coverage[..., None] * sun_rgb
    return env.astype(np.float32)


def _disc_coverage(width: int, height: int, centre: np.ndarray, radius: float) -> np.ndarray:
    """Fraction of each pixel's solid angle inside a spherical cap (a disc on the sphere), float64 (H, W).

    Pixels entirely inside the disc get 1. Pixels on its rim (centre within a
    pixel's half-diagonal of the edge) are supersampled in phi, over the part
    of the pixel that lies within the disc's longitude range, and along each
    sub-column the covered range of theta is exact: at fixed phi,
    cos(angle to the centre) = A sin(theta) + B cos(theta) = C cos(theta - theta0),
    so the disc is the interval |theta - theta0| <= acos(cos(radius) / C), over
    which sin(theta) integrates in closed form. Only the midpoint rule in phi
    approximates, so the disc's total solid angle matches 2 pi (1 - cos radius)
    to about 1e-4 at any resolution, even for a disc far smaller than a pixel.
    """
    d_theta = math.pi / height
    d_phi = 2.0 * math.pi / width
    # Every point of a pixel lies within its half-diagonal of the pixel centre (sin(theta) <= 1 only shrinks it).
    margin = 0.5 * math.hypot(d_theta, d_phi) * 1.01
    angle = np.arccos(np.clip(latlong_directions(width, height) @ centre, -1.0, 1.0))
    coverage = (angle <= radius - margin).astype(np.float64)
    rows, cols = np.nonzero(np.abs(angle - radius) < margin)

    # Longitude range of the disc: all of it if the disc contains a pole, else phi_c +- asin(sin r / sin theta_c).
    theta_c = math.acos(min(1.0, max(-1.0, float(centre[1]))))
    phi_c = math.atan2(float(centre[0]), -float(centre[2]))
    contains_pole = math.sin(theta_c) <= math.sin(radius)
    half_width = math.pi if contains_pole else math.asin(math.sin(radius) / math.sin(theta_c))

    n = 128  # sub-columns per rim pixel
    cos_cap = math.cos(radius)
    omega_pixel = latlong_row_solid_angles(width, height)
    sub = (np.arange(n) + 0.5) / n
    top, bottom = rows * d_theta, (rows + 1) * d_theta
    solid = np.zeros(len(rows))
    # Intersect each pixel's phi range with the disc's range and its copies shifted by 2 pi.
    for copy in (-2.0 * math.pi, 0.0, 2.0 * math.pi):
        if contains_pole and copy != 0.0:
            continue  # the full range is handled once, by the unshifted copy
        lo = cols * d_phi if contains_pole else np.maximum(cols * d_phi, phi_c + copy - half_width)
        hi = (cols + 1) * d_phi if contains_pole else np.minimum((cols + 1) * d_phi, phi_c + copy + half_width)
        span = np.clip(hi - lo, 0.0, None)
        phi = lo[:, None] + sub[None, :] * span[:, None]
        a = np.sin(phi) * centre[0] - np.cos(phi) * centre[2]  # direction . centre = a sin(theta) + b cos(theta)
        b = float(centre[1])
        c = np.hypot(a, b)
        theta0 = np.arctan2(a, b)
        half = np.arccos(np.clip(cos_cap / np.maximum(c, 1e-300), -1.0, 1.0))
        covered = np.zeros_like(phi)
        # theta0 is in (-pi, pi]; the interval shifted by 2 pi can reach back into [0, pi] near theta = pi.
        for shift in (0.0, 2.0 * math.pi):
            t_lo = np.clip(theta0 - half + shift, top[:, None], bottom[:, None])
            t_hi = np.clip(theta0 + half + shift, top[:, None], bottom[:, None])
            covered += np.where((c > cos_cap) & (t_hi > t_lo), np.cos(t_lo) - np.cos(t_hi), 0.0)
        solid += covered.sum(axis=1) * span / n
    coverage[rows, cols] = solid / omega_pixel[rows]
    return coverage


def constant(value: float | Sequence[float] = (1.0, 1.0, 1.0), width: int = 64, height: int = 32) -> np.ndarray:
    """A uniform environment of radiance ``value`` (RGB or scalar); it integrates to 4 pi * value."""
    width, height = _check_size(width, height)
    rgb = _rgb(value, "value")
    return np.ascontiguousarray(np.broadcast_to(rgb.astype(np.float32), (height, width, 3)))


def directional(direction: Sequence[float], irradiance_rgb: float | Sequence[float],
                width: int = 512, height: int = 256) -> np.ndarray:
    """A single directional light (light arriving from ``direction``) as a lat-long map.

    All its power goes into the one pixel containing ``direction``, with
    radiance ``irradiance_rgb / (that pixel's solid angle)``, so that the map
    integrates to ``irradiance_rgb`` (exact in float64 arithmetic; the float32
    storage adds a relative error below 1e-7). Everything else is black.

    This is the finest directional light the discretisation can represent: a
    light of angular size one pixel. Renderers that sample the map see it as a
    tiny area light, so shadows get a penumbra of about one pixel's angle
    (360 / ``width`` degrees).
    """
    width, height = _check_size(width, height)
    rgb = _rgb(irradiance_rgb, "irradiance_rgb")
    i, j = direction_to_pixel(direction, width, height)
    env = np.zeros((height, width, 3), dtype=np.float32)
    env[j, i] = rgb / latlong_row_solid_angles(width, height)[j]
    return env


def _interval_overlap(lo: np.ndarray, hi: np.ndarray, a: float, b: float) -> np.ndarray:
    return np.clip(np.minimum(hi, b) - np.maximum(lo, a), 0.0, None)


def _add_patch(env: np.ndarray, theta_range: tuple[float, float], phi_range: tuple[float, float],
               radiance: Sequence[float]) -> None:
    """Add a patch bounded by two parallels and two meridians (radians), with exact edge coverage.

    A pixel's covered fraction is separable: the phi overlap over the pixel's
    phi width, times the overlap in cos(theta) (the solid-angle measure) over
    the pixel's cos(theta) range. So the patch integrates to exactly
    radiance * (phi1 - phi0) * (cos theta0 - cos theta1). Patches may cross the phi = 0 seam.
    """
    height, width = env.shape[:2]
    theta_edges = np.pi * np.arange(height + 1) / height
    cos_edges = np.cos(theta_edges)
    t0, t1 = theta_range
    cos_overlap = np.clip(np.minimum(cos_edges[:-1], math.cos(t0)) - np.maximum(cos_edges[1:], math.cos(t1)), 0.0, None)
    frac_theta = cos_overlap / (cos_edges[:-1] - cos_edges[1:])
    phi_edges = 2.0 * np.pi * np.arange(width + 1) / width
    p0, p1 = phi_range
    frac_phi = sum(_interval_overlap(phi_edges[:-1], phi_edges[1:], p0 + k * 2 * np.pi, p1 + k * 2 * np.pi)
                   for k in (-1, 0, 1)) / (2.0 * np.pi / width)
    env += frac_theta[:, None, None] * frac_phi[None, :, None] * np.asarray(radiance, dtype=np.float64)


# The two patches of two_area_lights: (theta range, phi range) in degrees, RGB radiance.
_AREA_LIGHTS = (
    ((30.0, 50.0), (40.0, 80.0), (24.0, 14.0, 5.0)),     # warm, upper, towards +x/-z
    ((55.0, 80.0), (200.0, 250.0), (4.0, 8.0, 18.0)),    # cool, lower, towards -x/+z
)


def two_area_lights(width: int = 512, height: int = 256) -> np.ndarray:
    """A black environment with two rectangular (in theta, phi) area lights, one warm and one cool.

    Warm: theta 30-50 degrees, phi 40-80 degrees, radiance (24, 14, 5).
    Cool: theta 55-80 degrees, phi 200-250 degrees, radiance (4, 8, 18).
    Edge pixels are partially covered with their exact solid-angle fraction,
    so each light integrates to radiance * (phi1 - phi0) * (cos theta0 - cos theta1).
    """
    width, height = _check_size(width, height)
    env = np.zeros((height, width, 3), dtype=np.float64)
    for theta_deg, phi_deg, radiance in _AREA_LIGHTS:
        _add_patch(env, tuple(np.radians(theta_deg)), tuple(np.radians(phi_deg)), radiance)
    return env.astype(np.float32)


# --------------------------------------------------------------------------- #
# Shapes
# --------------------------------------------------------------------------- #


def _finite(value: float, name: str) -> float:
    """``value`` as a finite float, or InputError naming ``name``."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise InputError(f"{name} must be a finite number, got {_shown(value)}")
    try:
        value = float(value)
    except OverflowError:
        value = math.inf
    if not math.isfinite(value):
        raise InputError(f"{name} must be a finite number, got {_shown(value)}")
    return value


def _positive(value: float, name: str) -> float:
    try:
        number = _finite(value, name)
    except InputError:
        number = None
    if number is None or not number > 0:
        raise InputError(f"{name} must be a positive finite number, got {_shown(value)}")
    return number


def _count(value: int, name: str, minimum: int, maximum: int = MAX_SEGMENTS) -> int:
    return _integer(value, name, minimum, maximum)


def _normalized(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


_ICOSAHEDRON_FACES = np.array([
    [0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11],
    [1, 5, 9], [5, 11, 4], [11, 10, 2], [10, 7, 6], [7, 1, 8],
    [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8], [3, 8, 9],
    [4, 9, 5], [2, 4, 11], [6, 2, 10], [8, 6, 7], [9, 8, 1],
])


def sphere(radius: float = 1.0, subdivisions: int = 4) -> Mesh:
    """An icosphere: an icosahedron whose triangles are split in four ``subdivisions`` times.

    Vertices lie on the sphere, normals are radial. 10 * 4**s + 2 vertices and
    20 * 4**s triangles; all triangles are nearly equal (no pole artefacts).
    The default (4) has 2562 vertices and a volume 0.2% below the sphere's.
    """
    radius = _positive(radius, "radius")
    # 20 * 4**s triangles: s = 8 is the largest within MAX_TRIANGLES.
    subdivisions = _count(subdivisions, "subdivisions", 0, int(math.log(MAX_TRIANGLES / 20, 4)))
    g = (1.0 + math.sqrt(5.0)) / 2.0
    vertices = _normalized(np.array([
        [-1, g, 0], [1, g, 0], [-1, -g, 0], [1, -g, 0],
        [0, -1, g], [0, 1, g], [0, -1, -g], [0, 1, -g],
        [g, 0, -1], [g, 0, 1], [-g, 0, -1], [-g, 0, 1],
    ], dtype=np.float64))
    faces = _ICOSAHEDRON_FACES.copy()
    for _ in range(subdivisions):
        edges = np.sort(faces[:, [[0, 1], [1, 2], [2, 0]]].reshape(-1, 2), axis=1)
        unique_edges, edge_id = np.unique(edges, axis=0, return_inverse=True)
        midpoints = _normalized(vertices[unique_edges[:, 0]] + vertices[unique_edges[:, 1]])
        mid = (len(vertices) + edge_id.reshape(-1, 3))  # (m, 3): midpoints of edges ab, bc, ca
        vertices = np.concatenate([vertices, midpoints])
        a, b, c = faces.T
        ab, bc, ca = mid.T
        faces = np.concatenate([np.stack(t, axis=1) for t in
                                ((a, ab, ca), (ab, b, bc), (ca, bc, c), (ab, bc, ca))])
    return Mesh(vertices * radius, faces, vertices)


def _cube_face_frames():
    """(n, u, v) for the six faces of an axis-aligned cube, with tangents
    u x v = n so the quad -u-v, +u-v, +u+v, -u+v is counter-clockwise from outside."""
    for axis in range(3):
        for sign in (1.0, -1.0):
            n = np.zeros(3)
            n[axis] = sign
            u = np.zeros(3)
            u[(axis + 1) % 3] = 1.0
            yield n, u, np.cross(n, u)


def box(size: Sequence[float] = (1.0, 1.0, 1.0)) -> Mesh:
    """An axis-aligned box with the given edge lengths: 24 vertices (4 per side) with flat normals."""
    half = _floats(size, "size", "3 positive finite numbers") / 2.0
    if half.shape != (3,) or not (np.isfinite(half).all() and (half > 0).all()):
        raise InputError(f"size must be 3 positive finite numbers, got {size!r}")
    vertices, normals, faces = [], [], []
    for n, u, v in _cube_face_frames():
        base = len(vertices)
        for cu, cv in ((-1, -1), (1, -1), (1, 1), (-1, 1)):
            vertices.append((n + cu * u + cv * v) * half)
            normals.append(n)
        faces += [[base, base + 1, base + 2], [base, base + 2, base + 3]]
    return Mesh(np.array(vertices), np.array(faces), np.array(normals))


def plane(size: Sequence[float] = (10.0, 10.0), subdivisions: int = 1) -> Mesh:
    """A rectangle in y = 0 facing +y, ``size`` = (extent in x, extent in z), split into
    ``subdivisions`` x ``subdivisions`` cells of two triangles each."""
    extent = _floats(size, "size", "2 positive finite numbers")
    if extent.shape != (2,) or not (np.isfinite(extent).all() and (extent > 0).all()):
        raise InputError(f"size must be 2 positive finite numbers, got {_shown(size)}")
    sx, sz = (float(x) for x in extent)
    n = _count(subdivisions, "subdivisions", 1, math.isqrt(MAX_TRIANGLES // 2))
    xs = np.linspace(-sx / 2, sx / 2, n + 1)
    zs = np.linspace(-sz / 2, sz / 2, n + 1)
    x, z = np.meshgrid(xs, zs, indexing="ij")  # vertex (i, j) = (xs[i], zs[j]) at index i * (n + 1) + j
    vertices = np.stack([x.ravel(), np.zeros(x.size), z.ravel()], axis=1)
    idx = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    p00, p01, p10, p11 = idx[:-1, :-1], idx[:-1, 1:], idx[1:, :-1], idx[1:, 1:]
    # cross(+z, +x) = +y: (p00, p01, p10) faces up, as does (p10, p01, p11).
    faces = np.concatenate([np.stack([p00, p01, p10], -1).reshape(-1, 3), np.stack([p10, p01, p11], -1).reshape(-1, 3)])
    normals = np.tile([0.0, 1.0, 0.0], (len(vertices), 1))
    return Mesh(vertices, faces, normals)


def _tube(centres: np.ndarray, frame_n: np.ndarray, frame_b: np.ndarray, tube_radius: float,
          tube_segments: int) -> Mesh:
    """A closed tube around a closed curve.

    ``centres`` (k, 3) are the curve points; ``frame_n``/``frame_b`` (k, 3) unit
    vectors such that (tangent, n, b) is a right-handed frame at each point. The
    curve and the frames wrap around (point k follows point k - 1).
    """
    k = len(centres)
    psi = 2.0 * np.pi * np.arange(tube_segments) / tube_segments
    normals = np.cos(psi)[None, :, None] * frame_n[:, None, :] + np.sin(psi)[None, :, None] * frame_b[:, None, :]
    vertices = centres[:, None, :] + tube_radius * normals
    idx = np.arange(k * tube_segments).reshape(k, tube_segments)
    a = idx
    b = np.roll(idx, -1, axis=1)  # next around the tube
    c = np.roll(idx, -1, axis=0)  # next along the curve
    d = np.roll(c, -1, axis=1)
    # Around the tube, d/dpsi = tangent x normal, so cross(d/dpsi, d/dt) = -tangent x (tangent x normal)
    # = +normal: the triangles (a, b, c) and (b, d, c) face outward.
    faces = np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3), np.stack([b, d, c], -1).reshape(-1, 3)])
    return Mesh(vertices.reshape(-1, 3), faces, normals.reshape(-1, 3))


def torus(R: float = 1.0, r: float = 0.3, segments: int = 64, tube_segments: int = 32) -> Mesh:  # noqa: N803
    """A torus around the y axis: tube radius ``r`` around a circle of radius ``R`` in y = 0.

    ``segments`` around the y axis, ``tube_segments`` around the tube. No seam:
    the mesh is closed with shared vertices. Normals are the analytic ones.
    """
    R = _positive(R, "R")
    r = _positive(r, "r")
    if r >= R:
        raise InputError(f"the tube radius r ({r}) must be smaller than R ({R})")
    segments = _count(segments, "segments", 3)
    tube_segments = _count(tube_segments, "tube_segments", 3)
    _check_triangles(2 * segments * tube_segments, f"a torus of {segments} x {tube_segments} segments")
    phi = 2.0 * np.pi * np.arange(segments) / segments
    radial = np.stack([np.cos(phi), np.zeros_like(phi), np.sin(phi)], axis=1)
    tangent = np.stack([-np.sin(phi), np.zeros_like(phi), np.cos(phi)], axis=1)
    return _tube(R * radial, radial, np.cross(tangent, radial), r, tube_segments)


def torus_knot(p: int = 2, q: int = 3, radius: float = 1.0, tube_radius: float = 0.12,
               segments: int = 256, tube_segments: int = 24) -> Mesh:
    """A (p, q) torus knot (default: the trefoil) made into a tube of radius ``tube_radius``.

    The curve ((2 + cos qt) cos pt, sin qt, (2 + cos qt) sin pt), scaled so its
    outer radius is ``radius``, winds p times around the y axis and q times
    through the hole. The tube's frame is transported along the curve without
    twisting (rotation-minimising), with the small remaining twist spread over
    the loop so the tube closes seamlessly. ``p`` and ``q`` must be coprime;
    keep ``tube_radius`` below about a quarter of ``radius`` for (2, 3), or the
    tube intersects itself. The knot's centroid is at the origin (it is
    q-fold symmetric about the y axis); its bounding box is not symmetric.
    """
    p = _count(p, "p", 1)
    q = _count(q, "q", 1)
    if math.gcd(p, q) != 1:
        raise InputError(f"p and q must be coprime for a knot, got ({p}, {q})")
    radius = _positive(radius, "radius")
    tube_radius = _positive(tube_radius, "tube_radius")
    segments = _count(segments, "segments", 8)
    tube_segments = _count(tube_segments, "tube_segments", 3)
    _check_triangles(2 * segments * tube_segments, f"a torus knot of {segments} x {tube_segments} segments")
    t = 2.0 * np.pi * np.arange(segments) / segments
    ring = 2.0 + np.cos(q * t)
    scale = radius / 3.0
    centres = scale * np.stack([ring * np.cos(p * t), np.sin(q * t), ring * np.sin(p * t)], axis=1)
    # Analytic tangent (derivative of the curve).
    d_ring = -q * np.sin(q * t)
    tangent = _normalized(np.stack([d_ring * np.cos(p * t) - ring * p * np.sin(p * t),
                                    q * np.cos(q * t),
                                    d_ring * np.sin(p * t) + ring * p * np.cos(p * t)], axis=1))
    # Parallel transport: project the previous normal onto the plane normal to the new tangent.
    normal = np.empty_like(tangent)
    seed = np.cross(tangent[0], [0.0, 1.0, 0.0] if abs(tangent[0, 1]) < 0.9 else [1.0, 0.0, 0.0])
    normal[0] = seed / np.linalg.norm(seed)
    for i in range(1, segments):
        n = normal[i - 1] - np.dot(normal[i - 1], tangent[i]) * tangent[i]
        normal[i] = n / np.linalg.norm(n)
    closing = normal[-1] - np.dot(normal[-1], tangent[0]) * tangent[0]  # transported back to the start
    closing /= np.linalg.norm(closing)
    # Twist left over after one loop, spread evenly so frame k and frame 0 meet.
    twist = math.atan2(np.dot(np.cross(normal[0], closing), tangent[0]), np.dot(normal[0], closing))
    angle = -twist * np.arange(segments) / segments
    binormal = np.cross(tangent, normal)
    normal, binormal = (np.cos(angle)[:, None] * normal + np.sin(angle)[:, None] * binormal,
                        -np.sin(angle)[:, None] * normal + np.cos(angle)[:, None] * binormal)
    return _tube(centres, normal, binormal, tube_radius, tube_segments)


def cylinder(radius: float = 1.0, height: float = 2.0, segments: int = 64) -> Mesh:
    """A closed cylinder around the y axis from y = -height/2 to +height/2.

    The side has smooth radial normals; the caps are separate vertices with
    flat normals (so rim vertices appear twice, once per normal).
    """
    radius = _positive(radius, "radius")
    height = _positive(height, "height")
    segments = _count(segments, "segments", 3)
    phi = 2.0 * np.pi * np.arange(segments) / segments
    # Winding direction of phi seen from +y: cos, -sin in x, z makes phi run counter-clockwise from above.
    radial = np.stack([np.cos(phi), np.zeros_like(phi), -np.sin(phi)], axis=1)
    lo, hi = -height / 2.0, height / 2.0
    up = np.array([0.0, 1.0, 0.0])
    k = np.arange(segments)
    nxt = (k + 1) % segments

    bottom = radius * radial + lo * up
    top = radius * radial + hi * up
    vertices = [bottom, top]                     # side: 0..s-1 bottom, s..2s-1 top
    normals = [radial, radial]
    faces = [np.stack([k, nxt, segments + k], 1), np.stack([nxt, segments + nxt, segments + k], 1)]

    base = 2 * segments                          # top cap ring + centre
    vertices += [top, hi * up[None, :]]
    normals += [np.tile(up, (segments, 1)), up[None, :]]
    faces.append(np.stack([np.full(segments, base + segments), base + k, base + nxt], 1))
    base += segments + 1                         # bottom cap ring + centre
    vertices += [bottom, lo * up[None, :]]
    normals += [np.tile(-up, (segments, 1)), -up[None, :]]
    faces.append(np.stack([np.full(segments, base + segments), base + nxt, base + k], 1))
    return Mesh(np.concatenate(vertices), np.concatenate(faces), np.concatenate(normals))


def cone(radius: float = 1.0, height: float = 2.0, segments: int = 64) -> Mesh:
    """A closed cone around the y axis: base disc at y = -height/2, apex at +height/2.

    The side has smooth normals. The apex has no single well-defined normal,
    so it is repeated once per side triangle with the normal of that
    triangle's middle direction; the base is flat with its own vertices.
    """
    radius = _positive(radius, "radius")
    height = _positive(height, "height")
    segments = _count(segments, "segments", 3)
    lo, hi = -height / 2.0, height / 2.0
    k = np.arange(segments)
    nxt = (k + 1) % segments

    def side_normal(phi: np.ndarray) -> np.ndarray:
        return _normalized(np.stack([height * np.cos(phi), np.full_like(phi, radius), -height * np.sin(phi)], 1))

    phi = 2.0 * np.pi * k / segments
    ring = np.stack([radius * np.cos(phi), np.full(segments, lo), -radius * np.sin(phi)], axis=1)
    apex = np.tile([0.0, hi, 0.0], (segments, 1))
    vertices = [ring, apex]                       # 0..s-1 ring, s..2s-1 apex copies
    normals = [side_normal(phi), side_normal(phi + np.pi / segments)]
    faces = [np.stack([k, nxt, segments + k], 1)]
    base = 2 * segments                           # base ring + centre
    vertices += [ring, np.array([[0.0, lo, 0.0]])]
    normals += [np.tile([0.0, -1.0, 0.0], (segments + 1, 1))]
    faces.append(np.stack([np.full(segments, base + segments), base + nxt, base + k], 1))
    return Mesh(np.concatenate(vertices), np.concatenate(faces), np.concatenate(normals))


def rounded_cube(size: float = 1.0, radius: float = 0.15, segments: int = 8) -> Mesh:
    """A cube of edge length ``size`` whose edges and corners are rounded with ``radius``.

    Built from a cube whose faces are gridded with lines at the start of the
    rounding and ``segments`` / 2 steps through it (``segments`` is the number
    of steps per quarter circle). Each grid point q is mapped to the rounded
    surface: with c = q clamped to the inner box (half-size - radius),
    the point is ``c + radius * (q - c) / |q - c|``, and that unit vector is the
    normal. Flat regions stay flat, edges become quarter cylinders and corners
    sphere octants; the mesh is closed with shared vertices.
    """
    size = _positive(size, "size")
    radius = _positive(radius, "radius")
    half = size / 2.0
    if radius > half:
        raise InputError(f"radius ({radius}) must be at most half the size ({half})")
    segments = _count(segments, "segments", 2)
    _check_triangles(12 * (2 * (segments // 2) + 1) ** 2, f"a rounded cube of {segments} segments")
    inner = half - radius
    band_steps = max(1, segments // 2)
    # On a face, a grid coordinate inner + radius*tan(alpha) maps to the angle alpha in [0, 45 deg]
    # of the rounded edge, so equal steps in alpha give equal arcs.
    alpha = (np.pi / 4.0) * np.arange(band_steps + 1) / band_steps
    band = inner + radius * np.tan(alpha)
    band[-1] = half  # tan(pi/4) is not exactly 1 in floating point
    coords = np.unique(np.concatenate([-band, band]))  # symmetric, so shared cube edges match exactly

    points, faces = [], []
    count = 0
    m = len(coords)
    idx = np.arange(m * m).reshape(m, m)
    quads = (idx[:-1, :-1], idx[1:, :-1], idx[1:, 1:], idx[:-1, 1:])
    for n, u, v in _cube_face_frames():
        cu, cv = np.meshgrid(coords, coords, indexing="ij")
        q = half * n + cu[..., None] * u + cv[..., None] * v
        points.append(q.reshape(-1, 3))
        p00, p10, p11, p01 = (x + count for x in quads)
        faces += [np.stack([p00, p10, p11], -1).reshape(-1, 3), np.stack([p00, p11, p01], -1).reshape(-1, 3)]
        count += m * m
    # Weld the six grids along the cube edges (their grid points are bit-identical there).
    cube_points, inverse = np.unique(np.concatenate(points), axis=0, return_inverse=True)
    faces = inverse.reshape(-1)[np.concatenate(faces)]
    centre = np.clip(cube_points, -inner, inner)
    normals = _normalized(cube_points - centre)
    return Mesh(centre + radius * normals, faces, normals)


# --------------------------------------------------------------------------- #
# Terrain
# --------------------------------------------------------------------------- #


def _hash_uniform(ix: np.ndarray, iy: np.ndarray, salt: int) -> np.ndarray:
    """Deterministic pseudo-random values in [-1, 1) for integer lattice points.

    An explicit integer hash (murmur3's finaliser) rather than numpy's random
    generators, whose streams are not guaranteed across numpy versions; it
    also makes the value at a lattice point independent of the grid size.
    """
    with np.errstate(over="ignore"):
        h = (ix.astype(np.uint32) * np.uint32(0x8DA6B343)) ^ (iy.astype(np.uint32) * np.uint32(0xD8163841))
        h ^= np.uint32(salt & 0xFFFFFFFF)
        h ^= h >> np.uint32(16)
        h *= np.uint32(0x85EBCA6B)
        h ^= h >> np.uint32(13)
        h *= np.uint32(0xC2B2AE35)
        h ^= h >> np.uint32(16)
    return h.astype(np.float64) * (2.0 / 2.0**32) - 1.0


def _value_noise(x: np.ndarray, y: np.ndarray, salt: int) -> np.ndarray:
    """Smoothly interpolated lattice noise in [-1, 1] (quintic fade, C2 continuous)."""
    x0 = np.floor(x)
    y0 = np.floor(y)
    fx = x - x0
    fy = y - y0
    ix = x0.astype(np.int64)
    iy = y0.astype(np.int64)
    sx = fx * fx * fx * (fx * (fx * 6.0 - 15.0) + 10.0)
    sy = fy * fy * fy * (fy * (fy * 6.0 - 15.0) + 10.0)
    v00 = _hash_uniform(ix, iy, salt)
    v10 = _hash_uniform(ix + 1, iy, salt)
    v01 = _hash_uniform(ix, iy + 1, salt)
    v11 = _hash_uniform(ix + 1, iy + 1, salt)
    return (v00 + (v10 - v00) * sx) + ((v01 + (v11 - v01) * sx) - (v00 + (v10 - v00) * sx)) * sy


def terrain_heights(nx: int, ny: int, seed: int = 0, octaves: int = 6, frequency: float = 4.0,
                    persistence: float = 0.5, lacunarity: float = 2.0) -> np.ndarray:
    """Fractal Brownian motion (summed octaves of value noise) heights, float32 (ny, nx).

    Sample (row j, column i) is taken at x = (i + 0.5) / nx, y = (j + 0.5) / nx
    (both in units of the x extent, so features are isotropic whatever the
    aspect ratio); octave k has ``frequency * lacunarity**k`` lattice cells per
    unit and amplitude ``persistence**k``. The sum is divided by the total
    amplitude, so heights lie in [-1, 1]. Deterministic for a given ``seed``.
    """
    nx = _count(nx, "nx", 1, MAX_TERRAIN_SIDE)
    ny = _count(ny, "ny", 1, MAX_TERRAIN_SIDE)
    if nx * ny > MAX_TERRAIN_SAMPLES:
        raise InputError(f"a terrain of {nx}x{ny} has more than {MAX_TERRAIN_SAMPLES} samples, the limit "
                         "(penumbra.procedural.MAX_TERRAIN_SAMPLES)")
    octaves = _count(octaves, "octaves", 1, MAX_OCTAVES)
    seed = _integer(seed, "seed", -(1 << 63), (1 << 63) - 1)
    for name, value in (("frequency", frequency), ("persistence", persistence), ("lacunarity", lacunarity)):
        _positive(value, name)
    x = ((np.arange(nx) + 0.5) / nx)[None, :]
    y = ((np.arange(ny) + 0.5) / nx)[:, None]
    total = np.zeros((ny, nx))
    amplitude_sum = 0.0
    for k in range(octaves):
        f = frequency * lacunarity**k
        amplitude = persistence**k
        # A per-octave salt decorrelates the octaves; the offset keeps their lattices from all aligning at 0.
        salt = (int(seed) * 0x9E3779B1 + k * 0x85EBCA77) & 0xFFFFFFFF
        offset = 0.37 * k + 0.11
        total += amplitude * _value_noise(x * f + offset, y * f + offset, salt)
        amplitude_sum += amplitude
    return (total / amplitude_sum).astype(np.float32)
