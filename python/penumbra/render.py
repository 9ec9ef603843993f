"""From a scene description to an image: load or make the content, build the
native scene, cast the G-buffer and run a shading method, timing the frames
by the measuring protocol (kernel builds excluded, 0.3 s of warm-up frames, median
and minimum of N frames)."""

from __future__ import annotations

import statistics
import time
import weakref
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

from . import _native, procedural
from .core import (Camera, Context, EnvMap, GBuffer, HeightFieldHandle, Image, Material, Mesh, Renderer, Scene,
                   set_scene_heightfields)
from .errors import InputError
from .imageio import read_envmap
from .meshio import load_mesh
from .scenefile import EnvironmentDesc, ObjectDesc, SceneDescription

METHODS = _native.methods()
# Methods meant for per-frame use (the demo renders each with full timing:
# unshadowed, fiv, ...); `reference` is the slow ground truth and `floor` a
# timing yardstick (docs/benchmarks.md).
INTERACTIVE_METHODS = tuple(m for m in METHODS if m not in ("reference", "floor"))
# Keys of render(built, "fiv", ...) that are bake options (they override the
# scene's [fiv] table; samples in the paper's [phi, theta, radii] order), not
# renderer parameters.
FIV_BAKE_KEYS = ("samples", "precision", "inner_radius", "error_target", "face_size", "sun_supersampling",
                 "sun_threshold")
# bake_progress(label, samples done, samples total): called after each baked sphere.
BakeProgress = Callable[[str, int, int], Any]
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
    desc: SceneDescription | None = None
    object_meshes: dict[str, Mesh] = field(default_factory=dict)
    materials: dict[str, Material] = field(default_factory=dict)
    # The fiv method's occlusion fields, attached on first use (attach_fiv_fields).
    fiv_options: Any = None                                   # the FivOptions of the attached fields
    fiv_fields: list = field(default_factory=list)
    fiv_records: list[dict] = field(default_factory=list)     # per field: objects, baked, bake_s, rays, ...
    _flattened: dict[str, Mesh] = field(default_factory=dict)  # occluders whose rotation is baked into a mesh
    _flat_meshes: dict[tuple, Mesh] = field(default_factory=dict)
    # Height fields ([[heightfield]]): name -> (native field, instance id).
    heightfields: dict[str, tuple[HeightFieldHandle, int]] = field(default_factory=dict)


def add_heightfields(ctx: Context, scene: Scene, desc: SceneDescription,
                     meshes: list[Mesh]) -> dict[str, tuple[HeightFieldHandle, int]]:
    """Adds each [[heightfield]] as a native height field and as triangles
    (an instance, so the G-buffer and the reference renderer see it), and
    declares them to the scene for the ``heightfield`` method. An albedo map
    goes to the field (per vertex) and the instance gets a white material; a
    constant albedo goes to the material."""
    out = {}
    for d in desc.heightfields:
        data = d.load()
        albedo = data.albedo
        has_map = albedo is not None and np.ndim(albedo) == 3
        native = HeightFieldHandle(ctx, data.heights, origin=data.origin, size=data.size,
                                   height_scale=data.height_scale, albedo=albedo if has_map else None)
        mesh = native.mesh()
        meshes.append(mesh)
        material = Material(albedo=(1.0, 1.0, 1.0) if has_map else (albedo if albedo is not None else (0.8, 0.8, 0.8)))
        out[d.name] = (native, scene.add(mesh, None, material))
    if out:
        set_scene_heightfields(scene, list(out.values()))
    return out


def build_scene(desc: SceneDescription, ctx: Context) -> BuiltScene:
    e = desc.environment
    envmap = EnvMap(ctx, environment_latlong(e), face_size=e.face_size, irradiance_face_size=e.irradiance_face_size,
                    rotation_deg=e.rotation_deg, intensity=e.intensity)
    scene = Scene(ctx)
    scene.set_envmap(envmap)
    meshes, ids, by_object, materials = [], {}, {}, {}
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
        by_object[obj.name], materials[obj.name] = cache[key], material
    heightfields = add_heightfields(ctx, scene, desc, meshes)
    c = desc.camera
    camera = Camera(position=c.position, look_at=c.look_at, up=c.up, fov_deg=c.fov_deg, resolution=c.resolution)
    scene.set_camera(camera)
    if desc.lights:
        scene.set_lights([light.row() for light in desc.lights])
    scene.commit()
    return BuiltScene(ctx, envmap, meshes, scene, ids, camera, desc=desc, object_meshes=by_object, materials=materials,
                      heightfields=heightfields)


# ------------------------------------------------------------------ fiv fields


def _uniform_scale(transform: np.ndarray) -> float:
    """s when the linear part is s * I with s > 0 (as the library tests it, in
    float32), else 0: the fiv method takes translations and uniform scales."""
    m = np.asarray(transform, np.float32)[:3, :3]
    s = float(m[0, 0])
    if not s > 0.0:
        return 0.0
    return s if np.all(np.abs(m - np.float32(s) * np.eye(3, dtype=np.float32)) <= np.float32(1e-5 * abs(s))) else 0.0


def _flatten_occluder(built: BuiltScene, obj: ObjectDesc) -> Mesh:
    """Re-adds a rotated (sheared, mirrored or unevenly scaled) occluder as a
    mesh with its linear transform applied to the vertices, placed by a
    translation: the same geometry, whose field is baked for that orientation.
    Objects with the same geometry and linear transform share the mesh."""
    if obj.name in built._flattened:
        return built._flattened[obj.name]
    m = obj.transform()
    lin = m[:3, :3]
    key = (obj.mesh, obj.primitive, repr(sorted(obj.params.items())), np.round(lin, 12).tobytes())
    mesh = built._flat_meshes.get(key)
    if mesh is None:
        v, f, n = object_geometry(obj)
        v = np.asarray(v, np.float64) @ lin.T
        f = np.asarray(f)
        if n is not None:
            n = np.asarray(n, np.float64) @ np.linalg.inv(lin)  # normals by the inverse transpose
            n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-30)
        if np.linalg.det(lin) < 0:
            f = f[:, ::-1]  # a mirror turns the winding inside out
        mesh = built._flat_meshes[key] = Mesh(built.ctx, v, np.ascontiguousarray(f), n)
        built.meshes.append(mesh)
    t = np.eye(4)
    t[:3, 3] = m[:3, 3]
    built.scene.remove(built.instance_ids[obj.name])
    built.instance_ids[obj.name] = built.scene.add(mesh, t, built.materials[obj.name])
    built.object_meshes[obj.name] = built._flattened[obj.name] = mesh
    return mesh


def fiv_options(desc: SceneDescription, overrides: dict | None = None):
    """The FivOptions of the scene's [fiv] table, with bake keys of `overrides`
    (samples as [phi, theta, radii]) replacing its values."""
    from .fiv import FivOptions
    from .scenefile import parse_scene

    kw = desc.fiv.bake_options()
    if overrides:
        # Checked like the [fiv] table itself (same messages and ranges).
        checked = parse_scene({"fiv": {**{k: v for k, v in kw.items() if k != "samples"},
                                       "samples": list(desc.fiv.samples), **overrides}}).fiv
        kw = checked.bake_options()
    return FivOptions(**kw)


# Fields already in memory, by context, mesh, env map, options and cache folder:
# scenes built again in one process (the demo, benchmarks) reuse them instead of
# reading (and checking) the cache file again.
_FIELDS: "weakref.WeakValueDictionary[tuple, Any]" = weakref.WeakValueDictionary()


def attach_fiv_fields(built: BuiltScene, overrides: dict | None = None,
                      bake_progress: BakeProgress | None = None) -> list[dict]:
    """Bakes, or loads from the cache, one occlusion field per distinct
    occluder mesh of the scene (objects with ``occluder``, docs/scene-format.md)
    and attaches them to the scene for the ``fiv`` method. Fields already
    attached with the same options are kept. Occluders that rotate, shear,
    mirror or scale unevenly are re-added with that transform baked into their
    mesh (a field of its own, for that orientation). Returns one record per
    field: objects, mesh_hash, baked (False: loaded from the cache), bake_s,
    rays, stored_bytes, samples (phi, theta, radii)."""
    from .fiv import FivField, cached_field, envmap_hash, mesh_hash, set_scene_fields

    desc = built.desc
    if desc is None:
        raise InputError("the fiv method needs a scene built by build_scene from a description (its occluders)")
    options = fiv_options(desc, overrides)
    if built.fiv_options == options:
        return built.fiv_records
    groups: dict[str, tuple[Mesh, list[str]]] = {}
    changed = False
    for obj in desc.objects:
        if not obj.is_occluder:
            continue
        mesh = built.object_meshes[obj.name]
        if _uniform_scale(obj.transform()) == 0.0:
            changed |= obj.name not in built._flattened
            mesh = _flatten_occluder(built, obj)
        h = mesh_hash(mesh)
        groups.setdefault(h, (mesh, []))[1].append(obj.name)
    for obj in desc.objects:  # a field applies to every instance of a mesh with its hash
        if not obj.is_occluder and mesh_hash(built.object_meshes[obj.name]) in groups:
            raise InputError(f"[object '{obj.name}'] has occluder = false but the same geometry as occluder "
                             f"'{groups[mesh_hash(built.object_meshes[obj.name])][1][0]}': a field applies to every "
                             "instance of its mesh")
    if changed:
        built.scene.commit()
    fields: list[FivField] = []
    records = []
    env_key = (built.ctx._h.value, envmap_hash(built.envmap), options, str(desc.fiv.cache))
    for h, (mesh, names) in groups.items():
        label = names[0] if len(names) == 1 else f"{names[0]} (+{len(names) - 1})"
        cb = None if bake_progress is None else (lambda done, total, label=label: bake_progress(label, done, total))
        t0 = time.perf_counter()
        f = _FIELDS.get((h, *env_key))
        fresh = f is None
        if fresh:
            f = cached_field(built.envmap, mesh, options, progress=cb, directory=desc.fiv.cache)
            _FIELDS[(h, *env_key)] = f
        info = f.info()
        fields.append(f)
        theta, phi, radii = info["samples"]
        baked = fresh and info["rays"] > 0
        records.append({"objects": names, "mesh_hash": h, "baked": baked,
                        "bake_s": info["bake_seconds"] if baked else 0.0,
                        "load_s": time.perf_counter() - t0, "rays": info["rays"] if baked else 0,
                        "stored_bytes": info["stored_bytes"], "samples": [phi, theta, radii]})
    set_scene_fields(built.scene, fields)
    built.fiv_options, built.fiv_fields, built.fiv_records = options, fields, records
    return records


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


# Untimed frames before the timed ones, by time: on a 2-core CPU under PoCL
# the first ~0.1 s of frames after a pause ran 2x slower (the same frames,
# in the same process), which one warm-up frame did not absorb.
WARMUP_SECONDS = 0.3


def _timed(fn, ctx: Context) -> float:
    t0 = time.perf_counter()
    fn()
    ctx.finish()
    return 1000.0 * (time.perf_counter() - t0)


def render(built: BuiltScene, method: str = "unshadowed", frames: int = 5, progress=None, warmup: bool = True,
           bake_progress: BakeProgress | None = None, **params) -> RenderResult:
    """Renders `built` with `method`. Kernel builds happen before timing; then
    warm-up frames for at least WARMUP_SECONDS (at least one; none when
    `warmup` is False: for one-off slow renders whose time is not a
    measurement), then `frames` timed frames (G-buffer + shading each). For ``fiv`` the occlusion fields are baked or loaded first
    (attach_fiv_fields, not timed); its params may include bake options
    (FIV_BAKE_KEYS) that override the scene's [fiv] table."""
    if method not in METHODS:
        raise InputError(f"unknown method '{method}' (available: {', '.join(METHODS)})")
    if frames < 1:
        raise InputError(f"frames = {frames} must be >= 1")
    shown = dict(params)
    if method == "fiv":
        bake = {k: params.pop(k) for k in FIV_BAKE_KEYS if k in params}
        attach_fiv_fields(built, bake, bake_progress)
    ctx = built.ctx
    for stage in ("raycast", method):
        ctx.build(stage)
    w, h = built.camera.resolution
    gbuffer, image = GBuffer(ctx, w, h), Image(ctx, w, h)
    renderer = Renderer(ctx, method, **params)
    gtimes, stimes = [], []
    warm_until = time.perf_counter() + WARMUP_SECONDS
    while warmup:  # caches, and an OpenCL CPU runtime's idle worker threads
        built.scene.render_gbuffer(gbuffer)
        renderer.execute(built.scene, gbuffer, image)
        ctx.finish()
        warmup = time.perf_counter() < warm_until
    for _ in range(frames):
        gtimes.append(_timed(lambda: built.scene.render_gbuffer(gbuffer), ctx))
        stimes.append(_timed(lambda: renderer.execute(built.scene, gbuffer, image), ctx))
        if progress is not None:
            progress.update(1)
    planes = {p: gbuffer.read(p) for p in ("position", "normal", "albedo", "material", "instance")}
    totals = [a + b for a, b in zip(gtimes, stimes)]
    timings = {"frame_median": statistics.median(totals), "frame_min": min(totals),
               "gbuffer_median": statistics.median(gtimes), "shade_median": statistics.median(stimes),
               "shade_min": min(stimes), "frames": frames}
    return RenderResult(method=method, image=image.read(), gbuffer=planes, timings_ms=timings, params=shown,
                        device=ctx.device_name)
