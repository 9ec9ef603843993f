"""From a scene description to an image: load or make the content, build the
native scene, cast the G-buffer and run a shading method, timing the frames
by the measuring protocol (kernel builds excluded, one warm-up frame, median
and minimum of N frames)."""

from __future__ import annotations

import statistics
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from . import _native, procedural
from .core import Camera, Context, EnvMap, GBuffer, Image, Material, Mesh, Renderer, Scene
from .errors import InputError
from .imageio import read_envmap
from .meshio import load_mesh
from .scenefile import EnvironmentDesc, ObjectDesc, SceneDescription

METHODS = _native.methods()
# Methods meant for per-frame use; `reference` is the slow ground truth and
# `floor` a timing yardstick (docs/benchmarks.md).
INTERACTIVE_METHODS = tuple(m for m in METHODS if m not in ("reference", "floor"))
# G-buffer views the CLI and demo can write next to shaded images.
GBUFFER_VIEWS = ("normals", "albedo", "depth")


def environment_latlong(env: EnvironmentDesc) -> np.ndarray:
    """The lat-long radiance map of an environment description (H, W, 3)."""
    makers = {"sky": procedural.sky, "constant": procedural.constant, "directional": procedural.directional,
              "area_lights": procedural.two_area_lights}
    if env.map in makers:
        try:
            return makers[env.map](**env.params)
        except TypeError as exc:
            raise InputError(f"[environment] params do not fit map '{env.map}': {exc}") from None
    return read_envmap(env.map)


def object_geometry(obj: ObjectDesc):
    """(vertices, faces, normals) of an object description."""
    if obj.mesh is not None:
        m = load_mesh(obj.mesh)
    else:
        try:
            m = getattr(procedural, obj.primitive)(**obj.params)
        except TypeError as exc:
            raise InputError(f"[object '{obj.name}'] params do not fit primitive '{obj.primitive}': {exc}") from None
    return m.vertices, m.faces, m.normals


@dataclass
class BuiltScene:
    """Native objects of a scene, kept together so they stay alive."""

    ctx: Context
    envmap: EnvMap
    meshes: list[Mesh]
    scene: Scene
    instance_ids: dict[str, int]
    camera: Camera


def build_scene(desc: SceneDescription, ctx: Context) -> BuiltScene:
    e = desc.environment
    envmap = EnvMap(ctx, environment_latlong(e), face_size=e.face_size, irradiance_face_size=e.irradiance_face_size,
                    rotation_deg=e.rotation_deg, intensity=e.intensity)
    scene = Scene(ctx)
    scene.set_envmap(envmap)
    meshes, ids = [], {}
    cache: dict[tuple, Mesh] = {}
    for obj in desc.objects:
        key = (obj.mesh, obj.primitive, repr(sorted(obj.params.items())))
        if key not in cache:  # instances of the same geometry share one mesh and BVH
            v, f, n = object_geometry(obj)
            cache[key] = Mesh(ctx, v, f, n)
            meshes.append(cache[key])
        material = Material(albedo=obj.albedo, specular=obj.specular, shininess=obj.shininess,
                            roughness=obj.roughness, lobe=obj.lobe)
        ids[obj.name] = scene.add(cache[key], obj.transform(), material)
    c = desc.camera
    camera = Camera(position=c.position, look_at=c.look_at, up=c.up, fov_deg=c.fov_deg, resolution=c.resolution)
    scene.set_camera(camera)
    if desc.lights:
        scene.set_lights([light.row() for light in desc.lights])
    scene.commit()
    return BuiltScene(ctx, envmap, meshes, scene, ids, camera)


@dataclass
class RenderResult:
    method: str
    image: np.ndarray                     # (H, W, 4) linear RGBA
    gbuffer: dict[str, np.ndarray]        # planes read back from the device
    timings_ms: dict[str, float]
    params: dict[str, Any] = field(default_factory=dict)
    device: str = ""

    def view(self, name: str) -> np.ndarray:
        """A G-buffer view as an RGB image: normals (0.5 + 0.5 n), albedo, depth."""
        inst = self.gbuffer["instance"]
        fg = (inst != 0xFFFFFFFF)[..., None]
        if name == "normals":
            return np.where(fg, 0.5 + 0.5 * self.gbuffer["normal"][..., :3], 0.0).astype(np.float32)
        if name == "albedo":
            return np.where(fg, self.gbuffer["albedo"][..., :3], 0.0).astype(np.float32)
        if name == "depth":
            d = self.gbuffer["position"][..., 3]
            finite = np.isfinite(d)
            out = np.zeros(d.shape, np.float32)
            if finite.any():
                lo, hi = d[finite].min(), d[finite].max()
                out[finite] = 1.0 - (d[finite] - lo) / max(hi - lo, 1e-12)
            return np.repeat(out[..., None], 3, axis=2)
        raise InputError(f"unknown G-buffer view '{name}' ({', '.join(GBUFFER_VIEWS)})")


def _timed(fn, ctx: Context) -> float:
    t0 = time.perf_counter()
    fn()
    ctx.finish()
    return 1000.0 * (time.perf_counter() - t0)


def render(built: BuiltScene, method: str = "unshadowed", frames: int = 5, progress=None, warmup: bool = True,
           **params) -> RenderResult:
    """Renders `built` with `method`. Kernel builds happen before timing; one
    warm-up frame (unless `warmup` is False: for one-off slow renders whose
    time is not a measurement), then `frames` timed frames (G-buffer +
    shading each)."""
    if method not in METHODS:
        raise InputError(f"unknown method '{method}' (available: {', '.join(METHODS)})")
    if frames < 1:
        raise InputError(f"frames = {frames} must be >= 1")
    ctx = built.ctx
    for stage in ("raycast", method):
        ctx.build(stage)
    w, h = built.camera.resolution
    gbuffer, image = GBuffer(ctx, w, h), Image(ctx, w, h)
    renderer = Renderer(ctx, method, **params)
    gtimes, stimes = [], []
    first = 1 if warmup else 0
    for i in range(1 - first, frames + 1):
        g = _timed(lambda: built.scene.render_gbuffer(gbuffer), ctx)
        s = _timed(lambda: renderer.execute(built.scene, gbuffer, image), ctx)
        if i > 0:  # frame 0 warms caches up
            gtimes.append(g)
            stimes.append(s)
        if progress is not None:
            progress.update(1)
    planes = {p: gbuffer.read(p) for p in ("position", "normal", "albedo", "material", "instance")}
    totals = [a + b for a, b in zip(gtimes, stimes)]
    timings = {"frame_median": statistics.median(totals), "frame_min": min(totals),
               "gbuffer_median": statistics.median(gtimes), "shade_median": statistics.median(stimes),
               "shade_min": min(stimes), "frames": frames}
    return RenderResult(method=method, image=image.read(), gbuffer=planes, timings_ms=timings, params=dict(params),
                        device=ctx.device_name)
