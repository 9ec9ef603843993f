"""Thin Python objects over libpenumbra's handles.

Each class owns one reference to its native handle and releases it when
closed or garbage collected. Arguments may be numpy arrays (host data, copied
by the library) or, where the C API borrows device memory, pyopencl buffers
and arrays: their ``int_ptr`` handles are passed straight through, so a
pyopencl user's buffers and queue are used without copies.
"""

from __future__ import annotations

import ctypes
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np

from . import _native
from ._native import call, lib
from .errors import InputError
from .limits import INT32, UINT32, checked_int

# Specular lobe names in the order of their pn_lobe values, from the library.
LOBES = _native.lobes()


def _ptr(array: np.ndarray) -> int:
    return array.ctypes.data


def _host(array, dtype, shape_tail: tuple[int, ...], what: str) -> np.ndarray:
    """A C-contiguous copy (or view) of `array` with the required dtype and trailing shape."""
    a = np.ascontiguousarray(np.asarray(array, dtype=dtype))
    if a.ndim != 1 + len(shape_tail) or a.shape[1:] != shape_tail:
        want = "(N, " + ", ".join(map(str, shape_tail)) + ")"
        raise InputError(f"{what} must have shape {want}, got {a.shape}")
    return a


def _holds(dtype: np.dtype, scalar: np.dtype) -> bool:
    """Whether an array dtype is ``scalar`` or a vector of it (pyopencl.cltypes.float4: fields of float32)."""
    if dtype.fields:
        return all(np.dtype(f[0]) == scalar for f in dtype.fields.values())
    return dtype == scalar


def _mem_handle(obj: Any, what: str, scalar: Any = None) -> int:
    """The cl_mem handle of a pyopencl Buffer or Array (offset 0), for the C API.
    An Array must be contiguous and hold ``scalar`` elements (e.g. float32, or
    cltypes.float4): the library reads its bytes as such, so a float64 array
    would be silently misread."""
    base = getattr(obj, "base_data", None)
    if base is not None:  # pyopencl.array.Array
        if getattr(obj, "offset", 0):
            raise InputError(f"{what}: pyopencl arrays with a nonzero offset are not supported")
        if scalar is not None and not _holds(np.dtype(obj.dtype), np.dtype(scalar)):
            raise InputError(f"{what}: a pyopencl array of {np.dtype(obj.dtype)} elements; it must hold "
                             f"{np.dtype(scalar).name} (convert it with .astype(numpy.{np.dtype(scalar).name}))")
        if not (obj.flags.c_contiguous or obj.flags.f_contiguous):
            raise InputError(f"{what}: the pyopencl array is not contiguous")
        return base.int_ptr
    ptr = getattr(obj, "int_ptr", None)
    if ptr is None:
        raise InputError(f"{what} must be a pyopencl Buffer or Array, got {type(obj).__name__}")
    return ptr


class _Handle:
    _release = ""

    def __init__(self, ctx: "Context | None"):
        self._h = ctypes.c_void_p()
        self._ctx = ctx

    @property
    def handle(self) -> int:
        """The native handle, for passing to other bindings of the C API."""
        return self._h.value or 0

    def _ctx_handle(self):
        return self._ctx._h if self._ctx is not None else None

    def _call(self, name: str, *args) -> None:
        call(name, self._ctx_handle(), *args)

    def close(self) -> None:
        if self._h.value:
            getattr(lib, self._release)(self._h)
            self._h = ctypes.c_void_p()

    def __del__(self):
        try:
            self.close()
        except Exception:  # interpreter shutdown: the library may already be gone
            pass

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


class Context(_Handle):
    """An OpenCL device and its queue, with penumbra's compiled programs.

    ``Context()`` picks a device (``config`` such as ``"device=gpu"``, or the
    ``PENUMBRA_DEVICE`` environment variable; a CPU by default).
    ``Context(queue=q)`` wraps a pyopencl command queue (and its context)."""

    _release = "pn_context_release"

    def __init__(self, config: str | None = None, *, queue=None):
        self._h = ctypes.c_void_p()
        cfg = config.encode() if config else None
        if queue is not None:
            call("pn_context_create_from_cl", None, queue.context.int_ptr, queue.int_ptr, cfg, ctypes.byref(self._h))
        else:
            call("pn_context_create", None, cfg, ctypes.byref(self._h))

    @property
    def _ctx(self) -> "Context":
        """A context is its own context; computed, not stored: a stored
        reference to itself would keep a released Context (and its device
        memory) alive until the cycle collector runs."""
        return self

    @property
    def device_name(self) -> str:
        buf = ctypes.create_string_buffer(512)
        self._call("pn_context_get_device_name", self._h, buf, 512)
        return buf.value.decode("utf-8", "replace")

    def cl_objects(self):
        """(pyopencl.Context, pyopencl.CommandQueue) sharing this context's OpenCL objects."""
        import pyopencl as cl

        c, q, d = ctypes.c_void_p(), ctypes.c_void_p(), ctypes.c_void_p()
        self._call("pn_context_get_cl", self._h, ctypes.byref(c), ctypes.byref(q), ctypes.byref(d))
        return (cl.Context.from_int_ptr(c.value, retain=True), cl.CommandQueue.from_int_ptr(q.value, retain=True))

    def finish(self) -> None:
        self._call("pn_context_finish", self._h)

    def build(self, stage: str) -> None:
        """Builds (and caches) a kernel stage now rather than on first use."""
        self._call("pn_context_build_program", self._h, stage.encode())


@dataclass
class EnvDomains:
    """N directional domains of an env map (pn_envmap_decompose): centre
    directions (N, 3), total radiance sum L dw (N, 3), solid angles (N,) and
    equivalent cap radii (N,), float32 as the library computes them."""

    directions: np.ndarray
    radiance: np.ndarray
    solid_angle: np.ndarray
    cap_radius: np.ndarray

    def __len__(self) -> int:
        return len(self.directions)


def _domains_from_records(records: np.ndarray) -> EnvDomains:
    """EnvDomains of an (N, 8) float32 array of pn_env_domain records."""
    return EnvDomains(records[:, 0:3].copy(), records[:, 4:7].copy(), records[:, 3].copy(), records[:, 7].copy())


class EnvMap(_Handle):
    """An environment map: lat-long RGB radiance converted on the device into
    a cube map and an irradiance map. Parameters: face_size,
    irradiance_face_size, supersampling, rotation_deg, intensity."""

    _release = "pn_envmap_release"
    _INT = ("face_size", "irradiance_face_size", "supersampling")
    _FLOAT = ("rotation_deg", "intensity")

    def __init__(self, ctx: Context, latlong, **params):
        super().__init__(ctx)
        call("pn_envmap_create", ctx._h, ctx._h, ctypes.byref(self._h))
        self.set_latlong(latlong)
        self.set(**params)
        self.commit()

    def set_latlong(self, latlong) -> None:
        a = np.ascontiguousarray(np.asarray(latlong, dtype=np.float32))
        if a.ndim != 3 or a.shape[2] != 3:
            raise InputError(f"env map must have shape (height, width, 3), got {a.shape}")
        self._call("pn_envmap_set_latlong", self._h, _ptr(a), a.shape[1], a.shape[0])
        self._shape = (a.shape[1], a.shape[0])

    def _size(self) -> tuple[int, int]:
        """(width, height) of the lat-long map last set."""
        return self._shape

    def set(self, **params) -> None:
        for name, value in params.items():
            if name in self._INT:
                self._call("pn_envmap_set_int", self._h, name.encode(), checked_int(value, name, *INT32))
            elif name in self._FLOAT:
                self._call("pn_envmap_set_float", self._h, name.encode(), float(value))
            else:
                raise InputError(f"env maps have no parameter '{name}' ({', '.join(self._INT + self._FLOAT)})")

    def get(self, name: str):
        if name in self._INT:
            v = ctypes.c_int32()
            self._call("pn_envmap_get_int", self._h, name.encode(), ctypes.byref(v))
        else:
            v = ctypes.c_float()
            self._call("pn_envmap_get_float", self._h, name.encode(), ctypes.byref(v))
        return v.value

    def commit(self) -> None:
        self._call("pn_envmap_commit", self._h)

    def _read(self, what: int, n: int) -> np.ndarray:
        out = np.empty((6, n, n, 4), np.float32)
        self._call("pn_envmap_read", self._h, what, _ptr(out), out.nbytes)
        return out

    def cube_radiance(self) -> np.ndarray:
        """(6, F, F, 3) radiance of the cube texels (faces +X -X +Y -Y +Z -Z)."""
        return self._read(0, self.get("face_size"))[..., :3]

    def cube_directions(self) -> tuple[np.ndarray, np.ndarray]:
        """(6, F, F, 3) unit texel-centre directions and (6, F, F) solid angles."""
        d = self._read(1, self.get("face_size"))
        return d[..., :3], d[..., 3]

    def irradiance(self) -> np.ndarray:
        """(6, M, M, 3) irradiance at the vertex-grid directions of each face."""
        return self._read(2, self.get("irradiance_face_size"))[..., :3]

    def decompose(self, n: int, seed: int = 1, max_iterations: int = 0) -> EnvDomains:
        """The committed map split into n directional domains (power sampling,
        weighted Lloyd relaxation; docs/depthmap.md). Deterministic for a seed
        (0 <= seed < 2**32); max_iterations 0 is the library's default (100)."""
        for name, v, hi in (("n", n, 1024), ("seed", seed, 2**32 - 1), ("max_iterations", max_iterations, 10000)):
            if int(v) != v or not 0 <= v <= hi:
                raise InputError(f"{name} must be an integer in [0, {hi}], got {v!r}")
        opts = _native.EnvDecomposeOptions(int(n), int(seed), int(max_iterations))
        out = np.empty((max(int(n), 1), 8), np.float32)
        self._call("pn_envmap_decompose", self._h, ctypes.byref(opts), _ptr(out), int(n))
        return _domains_from_records(out)

    def extract_sharp(self, max_count: int = 4, threshold: float = 100.0, seed: int = 1,
                      max_iterations: int = 0) -> tuple[EnvDomains, np.ndarray]:
        """The map's concentrated light as at most max_count domains (texels
        brighter than threshold x the mean luminance, their excess over that
        level) and the residual (H, W, 3) lat-long map, in the input's frame and
        units: residual + sharp part = the map (pn_envmap_extract_sharp)."""
        for name, v, hi in (("max_count", max_count, 64), ("seed", seed, 2**32 - 1),
                            ("max_iterations", max_iterations, 10000)):
            if int(v) != v or not 0 <= v <= hi:
                raise InputError(f"{name} must be an integer in [0, {hi}], got {v!r}")
        opts = _native.EnvSharpOptions(int(max_count), float(threshold), int(seed), int(max_iterations))
        out = np.empty((max(int(max_count), 1), 8), np.float32)
        count = ctypes.c_uint32()
        w, h = self._size()
        residual = np.empty((h, w, 3), np.float32)
        self._call("pn_envmap_extract_sharp", self._h, ctypes.byref(opts), _ptr(out), int(max_count),
                   ctypes.byref(count), _ptr(residual), residual.size)
        return _domains_from_records(out[:count.value]), residual
    def fit_sgs(self, count: int, **options) -> np.ndarray:
        """`count` (1..128) spherical-Gaussian lobes fitted to the committed map by the library
        (pn_envmap_fit_sgs; docs/isg.md 5): a structured array of penumbra.sg.SG_LOBE
        (axis, sharpness, amplitude, pad). Options (pn_sg_fit_options): face_size, iterations,
        max_sharpness; unset ones take the library's defaults."""
        from .sg import SG_LOBE

        opts = lib.pn_sg_fit_options_default()
        names = [f[0] for f in opts._fields_]
        for name, value in options.items():
            if name not in names:
                raise InputError(f"the SG fit has no option '{name}' ({', '.join(names)})")
            setattr(opts, name, value)  # integer fields are checked (_native._Checked)
        if int(count) != count or count < 0:
            raise InputError(f"the lobe count must be a whole number >= 1, got {count!r}")
        out = np.zeros(max(int(count), 1), SG_LOBE)
        self._call("pn_envmap_fit_sgs", self._h, int(count), ctypes.byref(opts), out.ctypes.data, len(out))
        return out


class Mesh(_Handle):
    """A triangle mesh with its BVH (built at construction)."""

    _release = "pn_mesh_release"

    def __init__(self, ctx: Context, vertices, faces, normals=None):
        super().__init__(ctx)
        call("pn_mesh_create", ctx._h, ctx._h, ctypes.byref(self._h))
        v = _host(vertices, np.float32, (3,), "vertices")
        f = np.asarray(faces)
        if f.size and (not np.issubdtype(f.dtype, np.integer) or f.min() < 0):
            raise InputError("faces must hold non-negative integer vertex indices")
        if f.size and int(f.max()) >= len(v):  # checked before the uint32 cast, which would wrap 2**32 + 3 to 3
            raise InputError(f"faces: vertex index {int(f.max())} out of range (there are {len(v)} vertices)")
        f = _host(f, np.uint32, (3,), "faces")
        n = None if normals is None else _host(normals, np.float32, (3,), "normals")
        if n is not None and len(n) != len(v):
            raise InputError(f"normals has {len(n)} rows but there are {len(v)} vertices")
        self._call("pn_mesh_set_geometry", self._h, _ptr(v) if v.size else None, len(v), _ptr(f) if f.size else None,
                   len(f), None if n is None else _ptr(n))
        self._call("pn_mesh_commit", self._h)

    @classmethod
    def _adopt(cls, ctx: Context, handle: ctypes.c_void_p) -> "Mesh":
        """Wraps a mesh handle the library created (its reference becomes ours)."""
        mesh = cls.__new__(cls)
        _Handle.__init__(mesh, ctx)
        mesh._h = handle
        return mesh

    @property
    def info(self) -> dict:
        i = _native.MeshInfo()
        self._call("pn_mesh_get_info", self._h, ctypes.byref(i))
        return {"vertices": i.vertex_count, "triangles": i.triangle_count, "bvh_nodes": i.bvh_node_count,
                "bvh_depth": i.bvh_depth, "bounds": (tuple(i.bounds_lo), tuple(i.bounds_hi)),
                "has_normals": bool(i.has_normals)}

    def geometry(self) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """(vertices (V, 3) float32, faces (T, 3) uint32, normals (V, 3) float32 or None)
        as the library holds them (pn_mesh_read_geometry)."""
        info = self.info
        v = np.empty((info["vertices"], 3), np.float32)
        f = np.empty((info["triangles"], 3), np.uint32)
        n = np.empty((info["vertices"], 3), np.float32) if info["has_normals"] else None
        self._call("pn_mesh_read_geometry", self._h, _ptr(v) if v.size else None, _ptr(f) if f.size else None,
                   None if n is None or not n.size else _ptr(n))
        return v, f, n


@dataclass
class Material:
    """Lambertian albedo plus an optional specular lobe (docs/api.md, pn_material)."""

    albedo: Sequence[float] = (0.8, 0.8, 0.8)
    specular: float = 0.0
    shininess: float = 100.0
    roughness: float = 0.3
    lobe: str = "phong"
    shininess_v: float = 100.0  # ashikhmin_shirley: n_v (shininess is n_u)
    tangent: Sequence[float] = (1.0, 0.0, 0.0)  # ashikhmin_shirley: u axis in the object's frame (docs/brdf.md)

    def native(self) -> _native.Material:
        if self.lobe not in LOBES:
            raise InputError(f"unknown lobe '{self.lobe}' (one of {', '.join(LOBES)})")
        albedo = np.broadcast_to(np.asarray(self.albedo, dtype=np.float64), (3,))
        tangent = np.asarray(self.tangent, dtype=np.float64)
        if tangent.shape != (3,):
            raise InputError(f"material tangent must be 3 numbers, got {self.tangent!r}")
        return _native.Material((ctypes.c_float * 3)(*albedo), self.specular, self.shininess, self.roughness,
                                LOBES.index(self.lobe), self.shininess_v, (ctypes.c_float * 3)(*tangent))


@dataclass
class Camera:
    position: Sequence[float] = (0.0, 2.0, 6.0)
    look_at: Sequence[float] = (0.0, 0.5, 0.0)
    up: Sequence[float] = (0.0, 1.0, 0.0)
    fov_deg: float = 40.0
    resolution: tuple[int, int] = (512, 512)  # (width, height)

    def native(self) -> _native.Camera:
        f3 = lambda v: (ctypes.c_float * 3)(*[float(x) for x in v])  # noqa: E731
        w, h = (checked_int(x, "camera resolution", 0, UINT32[1]) for x in self.resolution)
        if w <= 0 or h <= 0:
            raise InputError(f"camera resolution {self.resolution} must be positive")
        return _native.Camera(f3(self.position), f3(self.look_at), f3(self.up), float(self.fov_deg), w, h)


def _transform_3x4(transform) -> np.ndarray | None:
    if transform is None:
        return None
    t = np.asarray(transform, dtype=np.float64)
    if t.shape == (4, 4):
        t = t[:3]
    if t.shape != (3, 4):
        raise InputError(f"a transform must be a 3x4 or 4x4 matrix, got shape {t.shape}")
    return np.ascontiguousarray(t, dtype=np.float32)


def uniform_scale(transform) -> float:
    """s when the object-to-world ``transform`` (3x4 or 4x4) is a translation times
    s * identity, else 0 (pn_transform_uniform_scale: the library's test)."""
    t = _transform_3x4(transform)
    s = ctypes.c_float()
    call("pn_transform_uniform_scale", None, _ptr(t), ctypes.byref(s))
    return float(s.value)


class Scene(_Handle):
    """Instances of meshes (transform + material), a camera and an env map."""

    _release = "pn_scene_release"

    def __init__(self, ctx: Context):
        super().__init__(ctx)
        call("pn_scene_create", ctx._h, ctx._h, ctypes.byref(self._h))
        self._keep: dict[int, Any] = {}
        self._assets: dict[int, dict[type, Any]] = {}   # attachments by instance, one per kind (kept alive)
        self.envmap: EnvMap | None = None
        self.camera: Camera | None = None
        self.lights = np.zeros((0, 7), np.float32)

    def set_envmap(self, env: EnvMap) -> None:
        self._call("pn_scene_set_envmap", self._h, env._h)
        self.envmap = env

    def set_camera(self, camera: Camera) -> None:
        c = camera.native()
        self._call("pn_scene_set_camera", self._h, ctypes.byref(c))
        self.camera = camera

    def set_lights(self, lights) -> None:
        """Spherical lights as (N, 7) rows: position xyz, radius, radiance rgb
        (docs/reference.md); an empty list removes them. Takes effect at commit."""
        a = np.asarray(lights, dtype=np.float64)
        if a.size == 0:
            a = np.zeros((0, 7))
        if a.ndim != 2 or a.shape[1] != 7:
            raise InputError(f"lights must be rows of 7 numbers (position xyz, radius, radiance rgb), got shape {a.shape}")
        data = np.ascontiguousarray(a, dtype=np.float32)
        self._call("pn_scene_set_lights", self._h, _ptr(data) if len(data) else None, len(data))
        self.lights = data.copy()

    def add(self, mesh: Mesh, transform=None, material: Material | None = None) -> int:
        t = _transform_3x4(transform)
        m = (material or Material()).native()
        out = ctypes.c_uint32()
        self._call("pn_scene_add_instance", self._h, mesh._h, None if t is None else _ptr(t), ctypes.byref(m),
                   ctypes.byref(out))
        self._keep[out.value] = mesh
        return out.value

    def set_transform(self, instance: int, transform) -> None:
        t = _transform_3x4(transform)
        self._call("pn_scene_set_instance_transform", self._h, instance, None if t is None else _ptr(t))

    def set_material(self, instance: int, material: Material) -> None:
        m = material.native()
        self._call("pn_scene_set_instance_material", self._h, instance, ctypes.byref(m))

    def remove(self, instance: int) -> None:
        """Removes an instance (and its attachments)."""
        self._call("pn_scene_remove_instance", self._h, instance)
        self._keep.pop(instance, None)
        self._assets.pop(instance, None)

    def attach(self, instance: int, asset) -> None:
        """Attaches a technique's asset (an occlusion field, a height field, ...)
        to ``instance``, replacing what it had of the same kind (pn_scene_attach;
        takes effect at commit)."""
        self._call("pn_scene_attach", self._h, instance, asset._h)
        self._assets.setdefault(instance, {})[type(asset)] = asset

    def detach(self, instance: int, asset=None) -> None:
        """Drops ``asset`` from ``instance`` (None: all its attachments; pn_scene_detach)."""
        self._call("pn_scene_detach", self._h, instance, None if asset is None else asset._h)
        kept = self._assets.get(instance, {})
        for kind in [k for k, a in kept.items() if asset is None or a is asset]:
            del kept[kind]

    def attachment(self, instance: int, kind: type):
        """The asset of type ``kind`` attached to ``instance`` (through this object), or None."""
        return self._assets.get(instance, {}).get(kind)

    def commit(self) -> None:
        self._call("pn_scene_commit", self._h)

    @staticmethod
    def _rays(origins, directions, tmin, tmax) -> np.ndarray:
        o = _host(origins, np.float32, (3,), "origins")
        d = _host(directions, np.float32, (3,), "directions")
        if len(o) != len(d):
            raise InputError(f"{len(o)} origins but {len(d)} directions")
        rays = np.empty((len(o), 8), np.float32)
        rays[:, :3], rays[:, 3], rays[:, 4:7], rays[:, 7] = o, tmin, d, tmax
        return rays

    @staticmethod
    def _ray_arrays(origins, directions):
        """Origins and directions as (N, 3) float32 arrays, in place where they already are."""
        o = _host(origins, np.float32, (3,), "origins")
        d = _host(directions, np.float32, (3,), "directions")
        if len(o) != len(d):
            raise InputError(f"{len(o)} origins but {len(d)} directions")
        return o, d

    def intersect(self, origins, directions, tmin=0.0, tmax=np.inf):
        """Closest hits: (t, instance, triangle); t = inf and ids = BACKGROUND on a miss.
        tmin and tmax: one value for all rays, or one per ray."""
        if np.ndim(tmin) == 0 and np.ndim(tmax) == 0:
            # One bound for all: the arrays go to the C API as they are (pn_scene_intersect_arrays).
            o, d = self._ray_arrays(origins, directions)
            n = len(o)
            t = np.empty(n, np.float32)
            inst = np.empty(n, np.uint32)
            tri = np.empty(n, np.uint32)
            self._call("pn_scene_intersect_arrays", self._h, _ptr(o), _ptr(d), n, float(np.float32(tmin)),
                       float(np.float32(tmax)), _ptr(t), _ptr(inst), _ptr(tri))
            return t, inst, tri
        rays = self._rays(origins, directions, tmin, tmax)
        n = len(rays)
        t = np.empty(n, np.float32)
        inst = np.empty(n, np.uint32)
        tri = np.empty(n, np.uint32)
        self._call("pn_scene_intersect", self._h, _ptr(rays), n, _ptr(t), _ptr(inst), _ptr(tri))
        return t, inst, tri

    def occluded(self, origins, directions, tmin=0.0, tmax=np.inf) -> np.ndarray:
        """Whether anything is hit in (tmin, tmax), per ray (bounds as in intersect)."""
        if np.ndim(tmin) == 0 and np.ndim(tmax) == 0:
            o, d = self._ray_arrays(origins, directions)
            out = np.empty(len(o), np.uint8)
            self._call("pn_scene_occluded_arrays", self._h, _ptr(o), _ptr(d), len(o), float(np.float32(tmin)),
                       float(np.float32(tmax)), _ptr(out))
            return out.view(bool)  # the kernel writes 0 or 1
        rays = self._rays(origins, directions, tmin, tmax)
        out = np.empty(len(rays), np.uint8)
        self._call("pn_scene_occluded", self._h, _ptr(rays), len(rays), _ptr(out))
        return out.view(bool)  # the kernel writes 0 or 1

    def render_gbuffer(self, gbuffer: "GBuffer") -> None:
        self._call("pn_scene_render_gbuffer", self._h, gbuffer._h)


_PLANE_DTYPE = {"position": (np.float32, 4), "normal": (np.float32, 4), "albedo": (np.float32, 4),
                "material": (np.float32, 4), "instance": (np.uint32, 1)}


class GBuffer(_Handle):
    """Per-pixel surface data (docs/gbuffer.md). ``planes``: optional dict of
    pyopencl buffers/arrays by plane name to wrap instead of allocating."""

    _release = "pn_gbuffer_release"

    def __init__(self, ctx: Context, width: int, height: int, planes: dict | None = None):
        super().__init__(ctx)
        self.width, self.height = checked_int(width, "width"), checked_int(height, "height")
        if planes is None:
            call("pn_gbuffer_create", ctx._h, ctx._h, self.width, self.height, ctypes.byref(self._h))
        else:
            missing = [p for p in _native.GBUFFER_PLANES if p not in planes]
            if missing:
                raise InputError(f"G-buffer planes missing: {', '.join(missing)}")
            arr = (ctypes.c_void_p * 5)(*[_mem_handle(planes[p], f"G-buffer plane {p}", _PLANE_DTYPE[p][0])
                                          for p in _native.GBUFFER_PLANES])
            call("pn_gbuffer_create_from_cl", ctx._h, ctx._h, self.width, self.height, arr, ctypes.byref(self._h))
            self._borrowed = planes

    @staticmethod
    def _plane(name: str) -> int:
        if name not in _PLANE_DTYPE:
            raise InputError(f"unknown G-buffer plane '{name}' ({', '.join(_native.GBUFFER_PLANES)})")
        return _native.GBUFFER_PLANES.index(name)

    def read(self, plane: str) -> np.ndarray:
        idx = self._plane(plane)
        dtype, k = _PLANE_DTYPE[plane]
        out = np.empty((self.height, self.width, k) if k > 1 else (self.height, self.width), dtype)
        self._call("pn_gbuffer_read", self._h, idx, _ptr(out), out.nbytes)
        return out

    def write(self, plane: str, data) -> None:
        idx = self._plane(plane)
        dtype, k = _PLANE_DTYPE[plane]
        a = np.ascontiguousarray(np.asarray(data, dtype=dtype))
        want = (self.height, self.width, k) if k > 1 else (self.height, self.width)
        if a.shape != want:
            raise InputError(f"G-buffer plane {plane} must have shape {want}, got {a.shape}")
        self._call("pn_gbuffer_write", self._h, idx, _ptr(a), a.nbytes)

    def validate(self) -> None:
        self._call("pn_gbuffer_validate", self._h)

    def cl_buffer(self, plane: str):
        """The plane's buffer as a pyopencl Buffer (shares the device memory)."""
        import pyopencl as cl

        out = ctypes.c_void_p()
        self._call("pn_gbuffer_get_cl", self._h, self._plane(plane), ctypes.byref(out))
        return cl.Buffer.from_int_ptr(out.value, retain=True)


class Image(_Handle):
    """An RGBA float image (alpha 1 on surfaces, 0 on background)."""

    _release = "pn_image_release"

    def __init__(self, ctx: Context, width: int, height: int, buffer=None):
        super().__init__(ctx)
        self.width, self.height = checked_int(width, "width"), checked_int(height, "height")
        if buffer is None:
            call("pn_image_create", ctx._h, ctx._h, self.width, self.height, ctypes.byref(self._h))
        else:
            call("pn_image_create_from_cl", ctx._h, ctx._h, self.width, self.height,
                 _mem_handle(buffer, "image buffer", np.float32), ctypes.byref(self._h))
            self._borrowed = buffer

    def read(self) -> np.ndarray:
        out = np.empty((self.height, self.width, 4), np.float32)
        self._call("pn_image_read", self._h, _ptr(out), out.nbytes)
        return out

    def cl_buffer(self):
        """The image's buffer as a pyopencl Buffer (shares the device memory)."""
        import pyopencl as cl

        out = ctypes.c_void_p()
        self._call("pn_image_get_cl", self._h, ctypes.byref(out))
        return cl.Buffer.from_int_ptr(out.value, retain=True)


class Renderer(_Handle):
    """A shading method by name (``"unshadowed"``) with its parameters."""

    _release = "pn_renderer_release"

    def __init__(self, ctx: Context, method: str, **params):
        super().__init__(ctx)
        self.method = method
        call("pn_renderer_create", ctx._h, ctx._h, method.encode(), ctypes.byref(self._h))
        self.set(**params)
        self._call("pn_renderer_commit", self._h)

    def _param(self, name: str):
        from .methods import spec

        return spec(self.method).param(name)

    def set(self, **params) -> None:
        """Sets parameters by name, as the method declares them (int or float);
        the library checks names and ranges."""
        for name, value in params.items():
            if not isinstance(value, (bool, int, float, np.integer, np.floating)):
                raise InputError(f"renderer parameter {name} must be a number, got {value!r}")
            p = self._param(name)
            # A float parameter gets set_float; so does a fractional value (the library refuses it for an int).
            as_float = (p is not None and p.type == "float") or not float(value).is_integer() or (
                p is None and not isinstance(value, (bool, int, np.integer)))
            if as_float:
                self._call("pn_renderer_set_float", self._h, name.encode(), float(value))
            else:
                self._call("pn_renderer_set_int", self._h, name.encode(), int(value))
        self._call("pn_renderer_commit", self._h)

    def get(self, name: str) -> int | float:
        """A parameter's current value (int or float, as the method declares it)."""
        p = self._param(name)
        if p is not None and p.type == "float":
            f = ctypes.c_float()
            self._call("pn_renderer_get_float", self._h, name.encode(), ctypes.byref(f))
            return f.value
        v = ctypes.c_int32()
        self._call("pn_renderer_get_int", self._h, name.encode(), ctypes.byref(v))
        return v.value

    def execute(self, scene: Scene, gbuffer: GBuffer, image: Image) -> None:
        self._call("pn_renderer_execute", self._h, scene._h, gbuffer._h, image._h)

    def read_output(self, scene: Scene, name: str, instance: int, index: int = 0, shape=None) -> np.ndarray:
        """One of the method's outputs (pn_renderer_read_output, computed for the
        scene as it is now) of ``instance`` (e.g. a height field's), item
        ``index`` of it (e.g. a light), as a float32 array of ``shape``
        (default: the shape the method's Python module gives, e.g. (D, W, k)
        per vertex of a height field)."""
        from .methods import technique

        if shape is None:
            shape = technique(self.method).output_shape(self, scene, name, instance, index)
        out = np.empty(shape, np.float32)
        self._call("pn_renderer_read_output", self._h, scene._h, name.encode(), int(instance), int(index),
                   _ptr(out), out.nbytes)
        return out
