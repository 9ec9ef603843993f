"""From a scene description to an image: load or make the content, build the
native scene, cast the G-buffer and run a shading method, timing the frames
by the measuring protocol (kernel builds excluded, 0.3 s of warm-up frames, median
and minimum of N frames)."""

from __future__ import annotations

import math
import statistics
import time
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

from . import methods, procedural
from .core import _PLANE_DTYPE, Camera, Context, EnvMap, GBuffer, Image, Material, Mesh, Renderer, Scene
from .errors import InputError
from .imageio import read_envmap
from .meshio import load_mesh, smooth_normals
from .scenefile import EnvironmentDesc, ObjectDesc, SceneDescription

METHODS = methods.names()
# bake_progress(label, samples done, samples total): called after each baked sphere.
BakeProgress = Callable[[str, int, int], Any]
# G-buffer views the CLI and demo can write next to shaded images.
GBUFFER_VIEWS = ("normals", "albedo", "depth")
# band_progress(weight done, weight total): called after each row band of a banded frame.
BandProgress = Callable[[int, int], Any]
# A banded frame is shaded in about this many row bands.
BANDS = 48
# Bytes per pixel of each G-buffer plane (docs/gbuffer.md).
_PLANE_BYTES = {p: np.dtype(t).itemsize * k for p, (t, k) in _PLANE_DTYPE.items()}
_IMAGE_BYTES = 16   # an image pixel: float4 RGBA


def environment_latlong(env: EnvironmentDesc) -> np.ndarray:
    """The lat-long radiance map of an environment description (H, W, 3)."""
    makers = {"sky": procedural.sky, "constant": procedural.constant, "directional": procedural.directional,
              "area_lights": procedural.two_area_lights}
    if env.map in makers:
        try:
            return makers[env.map](**env.params)
        except TypeError as exc:
            raise InputError(f"[environment] params do not fit map '{env.map}': {exc}") from None
        except InputError as exc:
            raise InputError(f"[environment] params of map '{env.map}': {exc}") from None
    return read_envmap(env.map)


def object_geometry(obj: ObjectDesc):
    """(vertices, faces, normals) of an object description; geometry without
    normals (most scanned meshes) gets smooth ones unless crease_angle_deg = 0."""
    if obj.mesh is not None:
        m = load_mesh(obj.mesh)
    else:
        try:
            m = getattr(procedural, obj.primitive)(**obj.params)
        except TypeError as exc:
            raise InputError(f"[object '{obj.name}'] params do not fit primitive '{obj.primitive}': {exc}") from None
        except InputError as exc:
            raise InputError(f"[object '{obj.name}'] params of primitive '{obj.primitive}': {exc}") from None
    if m.normals is None and obj.crease_angle_deg > 0:
        m = smooth_normals(m, obj.crease_angle_deg)
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
    desc: SceneDescription | None = None
    object_meshes: dict[str, Mesh] = field(default_factory=dict)
    materials: dict[str, Material] = field(default_factory=dict)
    # What each technique keeps on the scene (its native assets, records), by
    # method name: the technique's module reads and writes its own entry.
    assets: dict[str, Any] = field(default_factory=dict)


def build_scene(desc: SceneDescription, ctx: Context) -> BuiltScene:
    """The native scene of a description: its objects (instances of the same
    geometry share one mesh and BVH), what the techniques' scene tables add
    (Technique.build), the camera and the lights; committed."""
    e = desc.environment
    envmap = EnvMap(ctx, environment_latlong(e), face_size=e.face_size, irradiance_face_size=e.irradiance_face_size,
                    rotation_deg=e.rotation_deg, intensity=e.intensity)
    scene = Scene(ctx)
    scene.set_envmap(envmap)
    c = desc.camera
    camera = Camera(position=c.position, look_at=c.look_at, up=c.up, fov_deg=c.fov_deg, resolution=c.resolution)
    built = BuiltScene(ctx, envmap, [], scene, {}, camera, desc=desc)
    cache: dict[tuple, Mesh] = {}
    for obj in desc.objects:
        key = obj.geometry_key()
        if key not in cache:
            v, f, n = object_geometry(obj)
            cache[key] = Mesh(ctx, v, f, n)
            built.meshes.append(cache[key])
        material = Material(albedo=obj.albedo, specular=obj.specular, shininess=obj.shininess,
                            roughness=obj.roughness, lobe=obj.lobe, shininess_v=obj.shininess_v,
                            tangent=obj.tangent)
        built.instance_ids[obj.name] = scene.add(cache[key], obj.transform(), material)
        built.object_meshes[obj.name], built.materials[obj.name] = cache[key], material
    for technique in methods.techniques():
        technique.build(built)
    scene.set_camera(camera)
    if desc.lights:
        scene.set_lights([light.row() for light in desc.lights])
    scene.commit()
    return built


@dataclass
class RenderResult:
    method: str
    image: np.ndarray                     # (H, W, 4) linear RGBA
    gbuffer: dict[str, np.ndarray]        # planes read back from the device
    timings_ms: dict[str, float]
    params: dict[str, Any] = field(default_factory=dict)   # the renderer parameters in effect, defaults included
    device: str = ""
    bake_params: dict[str, Any] = field(default_factory=dict)  # bake parameters given (they override the scene's table)
    prepare_s: float = 0.0                # the technique's preparation (bakes, loads, attaches): not in timings_ms
    bake: dict[str, Any] = field(default_factory=dict)     # what the preparation made (Technique.bake_report)

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


# Untimed frames before the timed ones, by time: on a 2-core CPU under PoCL
# the first ~0.1 s of frames after a pause ran 2x slower (the same frames,
# in the same process), which one warm-up frame did not absorb.
WARMUP_SECONDS = 0.3


def _timed(fn, ctx: Context) -> float:
    t0 = time.perf_counter()
    fn()
    ctx.finish()
    return 1000.0 * (time.perf_counter() - t0)


def _shade_in_bands(ctx: Context, renderer: Renderer, scene: Scene, gbuffer: GBuffer, image: Image,
                    band_progress: BandProgress) -> None:
    """Shades one frame band by band: rows [y0, y0 + rows) as a G-buffer and an
    image over sub-buffers of the full ones (no copies), finishing each band
    and reporting ``band_progress(done, total)`` in foreground pixels (plus one
    per band): background pixels cost next to nothing, so the weights keep an
    ETA honest when the object fills only part of the frame."""
    import pyopencl as cl

    w, h = gbuffer.width, gbuffer.height
    _, queue = ctx.cl_objects()
    align = max(queue.device.mem_base_addr_align // 8, 1)    # sub-buffer origins must be aligned to this
    row = w * min(_PLANE_BYTES.values())                     # bytes per row of the narrowest plane (the instance ids)
    unit = align // math.gcd(align, row)                     # rows per aligned step: aligns every plane and the image
    rows = max(unit, -(-max(h // BANDS, 1) // unit) * unit)
    fg = (gbuffer.read("instance") != 0xFFFFFFFF).sum(axis=1)
    planes = {p: gbuffer.cl_buffer(p) for p in _PLANE_BYTES}
    image_buffer = image.cl_buffer()
    weights = [int(fg[y0:y0 + rows].sum()) + 1 for y0 in range(0, h, rows)]
    total, done = sum(weights), 0
    for band, y0 in enumerate(range(0, h, rows)):
        n = min(rows, h - y0)
        sub = {p: buf.get_sub_region(y0 * w * _PLANE_BYTES[p], n * w * _PLANE_BYTES[p], cl.mem_flags.READ_WRITE)
               for p, buf in planes.items()}
        band_image = Image(ctx, w, n, buffer=image_buffer.get_sub_region(y0 * w * _IMAGE_BYTES, n * w * _IMAGE_BYTES,
                                                                         cl.mem_flags.READ_WRITE))
        renderer.execute(scene, GBuffer(ctx, w, n, planes=sub), band_image)
        ctx.finish()
        done += weights[band]
        band_progress(done, total)


def render(built: BuiltScene, method: str = "unshadowed", frames: int = 5, progress=None, warmup: bool = True,
           bake_progress: BakeProgress | None = None, band_progress: BandProgress | None = None,
           **params) -> RenderResult:
    """Renders `built` with `method`. Kernel builds happen before timing; then
    warm-up frames for at least WARMUP_SECONDS (at least one; none when
    `warmup` is False: for one-off slow renders whose time is not a
    measurement), then `frames` timed frames (G-buffer + shading each).
    `params` are split by the library's metadata: renderer parameters, and
    bake parameters that override the technique's scene table (e.g. fiv's
    ``samples``); the technique prepares its assets first (bakes, loads,
    attaches; Technique.prepare, timed apart as ``prepare_s``).
    `band_progress(done, total)`: for a single frame without warm-up of a
    method whose pixels shade independently (Technique.per_pixel), shades it
    in row bands and reports after each (progress of long frames)."""
    technique = methods.technique(method)
    if frames < 1:
        raise InputError(f"frames = {frames} must be >= 1")
    params, bake = technique.split_params(params, f"render(..., {method!r})")
    t0 = time.perf_counter()
    technique.prepare(built, bake, bake_progress)
    prepare_s = time.perf_counter() - t0
    ctx = built.ctx
    for stage in ("raycast", technique.spec.stage):
        ctx.build(stage)
    w, h = built.camera.resolution
    gbuffer, image = GBuffer(ctx, w, h), Image(ctx, w, h)
    renderer = Renderer(ctx, method, **params)
    gtimes, stimes = [], []
    warm_until = time.perf_counter() + WARMUP_SECONDS
    warmed = warmup
    while warmup:  # caches, and an OpenCL CPU runtime's idle worker threads
        built.scene.render_gbuffer(gbuffer)
        renderer.execute(built.scene, gbuffer, image)
        ctx.finish()
        warmup = time.perf_counter() < warm_until
    banded = band_progress is not None and frames == 1 and not warmed and technique.per_pixel
    for _ in range(frames):
        gtimes.append(_timed(lambda: built.scene.render_gbuffer(gbuffer), ctx))
        if banded:
            stimes.append(_timed(lambda: _shade_in_bands(ctx, renderer, built.scene, gbuffer, image, band_progress),
                                 ctx))
        else:
            stimes.append(_timed(lambda: renderer.execute(built.scene, gbuffer, image), ctx))
        if progress is not None:
            progress.update(1)
    technique.after_render(built, renderer)
    planes = {p: gbuffer.read(p) for p in ("position", "normal", "albedo", "material", "instance")}
    totals = [a + b for a, b in zip(gtimes, stimes)]
    timings = {"frame_median": statistics.median(totals), "frame_min": min(totals),
               "gbuffer_median": statistics.median(gtimes), "shade_median": statistics.median(stimes),
               "shade_min": min(stimes), "frames": frames, "warmup": warmed, "banded": banded}
    effective = {**technique.spec.defaults(*methods.RENDERER_STAGES), **params}
    return RenderResult(method=method, image=image.read(), gbuffer=planes, timings_ms=timings, params=effective,
                        device=ctx.device_name, bake_params=bake, prepare_s=prepare_s,
                        bake=technique.bake_report(built))
