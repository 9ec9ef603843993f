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


def map_resolutions(renderer, scene) -> np.ndarray:
    """Each domain's map side in texels (the ``map_resolutions`` output):
    ``resolution`` graded by ``grade``, ``strong_resolution`` for the strong domains, or the
    caller's sides."""
    return renderer.read_output(scene, "map_resolutions", 0).astype(np.int64)


def read_maps(renderer, scene):
    """The renderer's domains (N, 8), map frames (N, 16) and depth maps for
    ``scene`` as it is now (its ``domains``, ``map_frames`` and ``depth_map``
    outputs): what :func:`set_maps` takes back. The maps are an (N, res, res)
    array when they share one side, else a list of N square arrays (with
    ``strong_resolution``). A domain without a map (``skip_power``) reads as
    an empty map (+inf)."""
    doms = renderer.read_output(scene, "domains", 0)
    frames = renderer.read_output(scene, "map_frames", 0)
    sides = map_resolutions(renderer, scene)
    maps = [renderer.read_output(scene, "depth_map", 0, i, shape=(int(sides[i]), int(sides[i])))
            for i in range(len(doms))]
    return doms, frames, (np.stack(maps) if len(set(sides.tolist())) <= 1 else maps)


def _sides(resolutions, n: int) -> np.ndarray:
    r = np.asarray(resolutions)
    if r.ndim == 0:
        r = np.full(n, int(r))
    if r.ndim != 1 or len(r) != n or not np.issubdtype(r.dtype, np.integer):
        raise InputError(f"resolutions must be an int or {n} ints (one per map), got {resolutions!r}")
    return np.ascontiguousarray(r, np.uint32)


def set_maps(renderer, frames, depths, resolutions=None) -> None:
    """The caller's depth maps for ``renderer``, drawn by the caller instead
    of the library: ``frames`` (N, 16) in the layout of the ``map_frames``
    output, one per domain the renderer shades with (its ``domains`` output,
    or the caller's :func:`set_domains`), and ``depths``:

    * an (N, res, res) float32 array, res the renderer's ``resolution``
      (pn_renderer_set_depth_maps, copied);
    * a list of N square arrays of any sides (pn_renderer_set_depth_maps_sized,
      copied);
    * a ``pyopencl.Buffer`` or ``pyopencl.array.Array`` of float32 on the
      renderer's context holding the maps one after the other, with
      ``resolutions`` (an int, or N ints) their sides
      (pn_renderer_set_depth_maps_cl): read in place by every execute, no copy.

    None returns to drawing the maps. The library checks them (sizes, context,
    orthonormal frames; host depths >= 0 or +inf, no NaN)."""
    if frames is None or depths is None:
        renderer._call("pn_renderer_set_depth_maps", renderer._h, None, None, 0, 0)
        renderer._borrowed_maps = None
        return
    f = np.ascontiguousarray(frames, np.float32)
    if f.ndim != 2 or f.shape[1] != FRAME_FLOATS:
        raise InputError(f"frames must be an (N, {FRAME_FLOATS}) array, got shape {f.shape}")
    if not isinstance(depths, (np.ndarray, list, tuple)):  # a device buffer of the caller's
        from ..core import _mem_handle

        if resolutions is None:
            raise InputError("depths is a device buffer: give resolutions (the side of each map)")
        sides = _sides(resolutions, len(f))
        handle = _mem_handle(depths, "depths", np.float32)
        renderer._call("pn_renderer_set_depth_maps_cl", renderer._h, _ptr(f), handle, len(f), _ptr(sides))
        renderer._borrowed_maps = depths
        return
    if isinstance(depths, (list, tuple)):
        maps = [np.ascontiguousarray(m, np.float32) for m in depths]
        if len(maps) != len(f) or any(m.ndim != 2 or m.shape[0] != m.shape[1] for m in maps):
            raise InputError(f"depths must be {len(f)} square arrays (the frames' count), got shapes "
                             f"{[m.shape for m in maps]}")
        sides = np.array([m.shape[0] for m in maps], np.uint32)
        packed = np.concatenate([m.reshape(-1) for m in maps]) if maps else np.empty(0, np.float32)
        renderer._call("pn_renderer_set_depth_maps_sized", renderer._h, _ptr(f), _ptr(packed), len(f), _ptr(sides))
        renderer._borrowed_maps = None
        return
    d = np.ascontiguousarray(depths, np.float32)
    if d.ndim != 3 or d.shape[1] != d.shape[2] or len(d) != len(f):
        raise InputError(f"depths must be an (N, res, res) array with N = {len(f)} (the frames'), got shape {d.shape}")
    renderer._call("pn_renderer_set_depth_maps", renderer._h, _ptr(f), _ptr(d), len(f), d.shape[1])
    renderer._borrowed_maps = None


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

    def output_shape(self, renderer, scene, output: str, instance: int, index: int = 0) -> tuple[int, ...]:
        if output == "depth_map":  # each map its own side (strong_resolution, the caller's sizes)
            sides = renderer.read_output(scene, "map_resolutions", 0)
            res = int(sides[index]) if 0 <= index < len(sides) else renderer.get("resolution")
            return (res, res)
        if output == "map_resolutions":
            return (domain_count(renderer),)
        if output in ("domains", "map_frames"):
            n = domain_count(renderer)
            return (n, DOMAIN_FLOATS if output == "domains" else 16)
        raise InputError(f"method {NAME} has no output '{output}' (outputs: domains, map_frames, depth_map, "
                         "map_resolutions)")

    def sweep(self) -> list[dict]:
        # Directions and map resolution from the cheapest up to the defaults and beyond, each with and without
        # the weak domains' maps graded by power (grade 0: every weak map `resolution`, the rule before), and
        # small maps for the weak domains beside a 128^2 one for the strong (docs/depthmap.md).
        # The sun in its own domains (sharp 1, the default) lets few domains and tiny maps do outdoors; the
        # sunny map's fast settings were best without it (sharp 0 rows).
        fast = [{"directions": n, "resolution": 32, "strong_resolution": 128} for n in (16, 32, 64)]
        tiny = [{"directions": n, "resolution": 16, "strong_resolution": 64} for n in (8, 16, 32)]
        return [*tiny, dict(fast[1], sharp=0), dict(fast[1], sharp=0, grade=0.0),
                {"directions": 16, "resolution": 64, "strong_resolution": 0, "grade": 0.0},
                {"directions": 32, "resolution": 64, "grade": 0.0}, {"directions": 32, "resolution": 64},
                {"directions": 64, "resolution": 64, "grade": 0.0}, {"directions": 64, "resolution": 64},
                {"directions": 128, "resolution": 64},
                *[p for f in fast for p in (dict(f, grade=0.0), f)],
                {"directions": 32, "resolution": 32},
                {"directions": 32}, {"grade": 0.0}, {"sharp": 0}, {}, {"directions": 128}]


TECHNIQUE = Depthmap(NAME)
