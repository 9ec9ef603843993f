"""The ``depthmap`` method's Python side (docs/depthmap.md): depth-map
environment sampling. The library splits the scene's env map into
``directions`` domains (or takes the caller's, :func:`set_domains`), draws one
depth map per domain every frame and shades with them. This module gives the
caller's-domains call, the shapes of the method's outputs (``domains``,
``map_frames``, ``depth_map``) and the default benchmark sweep.
"""

from __future__ import annotations

import numpy as np

from ..core import _ptr
from ..errors import InputError
from .base import Technique

NAME = "depthmap"
DOMAIN_FLOATS = 8  # pn_env_domain: direction[3], solid_angle, radiance[3], cap_radius


def domain_array(directions, radiance, cap_radius=None, solid_angle=None) -> np.ndarray:
    """(N, 8) float32 pn_env_domain records from unit ``directions`` (N, 3)
    towards the light, total radiance ``radiance`` (N, 3) (sum of L dw) and
    either ``cap_radius`` (N,) in radians or ``solid_angle`` (N,) in sr (the
    other follows from solid_angle = 2 pi (1 - cos r)); with neither, the N
    domains share the sphere equally."""
    d = np.asarray(directions, np.float64).reshape(-1, 3)
    l = np.asarray(radiance, np.float64).reshape(-1, 3)
    n = len(d)
    if len(l) != n:
        raise InputError(f"{n} directions but {len(l)} radiances")
    if cap_radius is None and solid_angle is None:
        solid_angle = np.full(n, 4.0 * np.pi / max(n, 1))
    if cap_radius is None:
        omega = np.asarray(solid_angle, np.float64).reshape(-1)
        cap_radius = 2.0 * np.arcsin(np.sqrt(np.clip(omega / (4.0 * np.pi), 0.0, 1.0)))
    r = np.asarray(cap_radius, np.float64).reshape(-1)
    if solid_angle is None:
        solid_angle = 4.0 * np.pi * np.sin(r / 2.0) ** 2
    omega = np.asarray(solid_angle, np.float64).reshape(-1)
    if len(r) != n or len(omega) != n:
        raise InputError(f"{n} directions but {len(r)} cap radii / {len(omega)} solid angles")
    out = np.empty((n, DOMAIN_FLOATS), np.float32)
    out[:, :3], out[:, 3], out[:, 4:7], out[:, 7] = d, omega, l, r
    return out


def set_domains(renderer, domains) -> None:
    """The caller's domains for ``renderer`` (pn_renderer_set_env_domains):
    an (N, 8) array as :func:`domain_array` makes, or None / an empty array to
    return to the decomposition of the scene's env map. The library checks
    them (finite, unit directions, non-negative radiance, radius in [0, pi])."""
    a = np.ascontiguousarray(domains if domains is not None else np.empty((0, DOMAIN_FLOATS)), np.float32)
    if a.size == 0:
        renderer._call("pn_renderer_set_env_domains", renderer._h, None, 0)
        renderer._caller_domains = 0
        return
    if a.ndim != 2 or a.shape[1] != DOMAIN_FLOATS:
        raise InputError(f"domains must be an (N, {DOMAIN_FLOATS}) array (pn_env_domain), got shape {a.shape}")
    renderer._call("pn_renderer_set_env_domains", renderer._h, _ptr(a), len(a))
    renderer._caller_domains = len(a)


FRAME_FLOATS = 16  # a map's frame: e1 | u_min, e2 | v_min, d | far, du, dv, depth extent, has a map


def read_maps(renderer, scene) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The renderer's domains (N, 8), map frames (N, 16) and depth maps
    (N, res, res) for ``scene`` as it is now (its ``domains``, ``map_frames``
    and ``depth_map`` outputs): what :func:`set_maps` takes back. A domain
    without a map (``skip_power``) reads as an empty map (+inf)."""
    doms = renderer.read_output(scene, "domains", 0)
    frames = renderer.read_output(scene, "map_frames", 0)
    maps = np.stack([renderer.read_output(scene, "depth_map", 0, i) for i in range(len(doms))])
    return doms, frames, maps


def set_maps(renderer, frames, depths) -> None:
    """The caller's depth maps for ``renderer`` (pn_renderer_set_depth_maps),
    drawn by the caller instead of the library: ``frames`` (N, 16) and
    ``depths`` (N, res, res) float32 in the layout of the ``map_frames`` and
    ``depth_map`` outputs, one per domain the renderer shades with (its
    ``domains`` output, or the caller's :func:`set_domains`), res its
    ``resolution``; None returns to drawing the maps. The library checks them
    (sizes, orthonormal frames, depths >= 0 or +inf, no NaN)."""
    if frames is None or depths is None:
        renderer._call("pn_renderer_set_depth_maps", renderer._h, None, None, 0, 0)
        return
    f = np.ascontiguousarray(frames, np.float32)
    d = np.ascontiguousarray(depths, np.float32)
    if f.ndim != 2 or f.shape[1] != FRAME_FLOATS:
        raise InputError(f"frames must be an (N, {FRAME_FLOATS}) array, got shape {f.shape}")
    if d.ndim != 3 or d.shape[1] != d.shape[2] or len(d) != len(f):
        raise InputError(f"depths must be an (N, res, res) array with N = {len(f)} (the frames'), got shape {d.shape}")
    renderer._call("pn_renderer_set_depth_maps", renderer._h, _ptr(f), _ptr(d), len(f), d.shape[1])


def maps_drawn(renderer, scene) -> int:
    """How many domains have a depth map this frame (the others are below
    ``skip_power`` and lit unshadowed): column 15 of ``map_frames`` (reading
    it computes the frame's maps for the scene as it is now, like any output)."""
    return int(renderer.read_output(scene, "map_frames", 0)[:, 15].sum())


def domain_count(renderer) -> int:
    """The number of domains the renderer shades with: the caller's (set
    through :func:`set_domains`), else its ``directions``."""
    n = getattr(renderer, "_caller_domains", 0)
    return n if n else renderer.get("directions")


class Depthmap(Technique):
    # Not in the README's benchmark table yet (its rows come from `make bench`); docs/depthmap.md has its results.

    def output_shape(self, renderer, scene, output: str, instance: int) -> tuple[int, ...]:
        if output == "depth_map":
            res = renderer.get("resolution")
            return (res, res)
        if output in ("domains", "map_frames"):
            n = domain_count(renderer)
            return (n, DOMAIN_FLOATS if output == "domains" else 16)
        raise InputError(f"method {NAME} has no output '{output}' (outputs: domains, map_frames, depth_map)")

    def sweep(self) -> list[dict]:
        # Directions and map resolution from the cheapest up to the defaults and beyond; the cap quadrature
        # (specular 2, the default before the table of cap averages) at 64^2 and at the defaults, for
        # comparison (docs/depthmap.md).
        return [{"directions": 16, "resolution": 64}, {"directions": 32, "resolution": 64},
                {"directions": 64, "resolution": 64}, {"directions": 128, "resolution": 64}, {"directions": 32},
                {}, {"directions": 128}, {"directions": 32, "resolution": 64, "specular": 2},
                {"directions": 64, "resolution": 64, "specular": 2}, {"specular": 2}]


TECHNIQUE = Depthmap(NAME)
