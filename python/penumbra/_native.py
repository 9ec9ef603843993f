"""ctypes declarations of libpenumbra (capi/include/penumbra.h).

The library is found, in order: the ``PENUMBRA_LIBRARY`` environment variable
(a path), the copy installed beside this package, then the system loader.
Every call goes through :func:`call`, which raises the library's message as a
:class:`~penumbra.errors.PenumbraError` (or :class:`~penumbra.errors.InputError`
for invalid data) on a bad status.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import os
from pathlib import Path

from .errors import InputError, PenumbraError
from .limits import INT32, INT64, UINT32, UINT64, checked_int

SUCCESS = 0
ERROR_NULL_HANDLE = -1001
ERROR_INVALID_ARGUMENT = -1002
ERROR_INVALID_SIZE = -1003
ERROR_INVALID_VALUE = -1004
ERROR_OUT_OF_RANGE = -1005
ERROR_EMPTY_INPUT = -1006
ERROR_BAD_CONFIG = -1007
ERROR_BUILD_FAILED = -1008
ERROR_NOT_COMMITTED = -1009
ERROR_OUT_OF_MEMORY = -1010
ERROR_NO_DEVICE = -1011
ERROR_UNSUPPORTED = -1012
ERROR_CANCELLED = -1013
ERROR_FILE = -1014
ERROR_INVALID_HANDLE = -1015  # a released (or never created) handle

# Statuses that mean "the caller's data or arguments are wrong".
_INPUT_ERRORS = {ERROR_INVALID_ARGUMENT, ERROR_INVALID_SIZE, ERROR_INVALID_VALUE, ERROR_OUT_OF_RANGE, ERROR_FILE,
                 ERROR_EMPTY_INPUT, ERROR_BAD_CONFIG}

BACKGROUND = 0xFFFFFFFF
WHOLE_SCENE = 0xFFFFFFFF
GBUFFER_PLANES = ("position", "normal", "albedo", "material", "instance")

# pn_param_type, pn_param_stage and the PN_INPUT_* bits of pn_method_info.inputs, by name.
PARAM_TYPES = ("int", "float")
PARAM_STAGES = ("frame", "plan", "bake")
INPUTS = {"envmap": 1, "geometry": 2, "lights": 4, "camera": 8, "fiv": 16, "heightfield": 32, "spheres": 64}


_INT_RANGES = {ctypes.c_uint32: UINT32, ctypes.c_int32: INT32, ctypes.c_int: INT32, ctypes.c_uint64: UINT64,
               ctypes.c_int64: INT64, ctypes.c_size_t: UINT64}


class _Checked(ctypes.Structure):
    """A ctypes structure whose integer fields refuse values that do not fit their C type
    (ctypes itself wraps them: 2**32 + 16 in a uint32 field is 16)."""

    def __init__(self, *args, **kwargs):
        names = [f[0] for f in self._fields_]
        args = [self._checked(name, value) for name, value in zip(names, args)]
        kwargs = {name: self._checked(name, value) for name, value in kwargs.items()}
        super().__init__(*args, **kwargs)

    def __setattr__(self, name, value):
        super().__setattr__(name, self._checked(name, value))

    @classmethod
    def _checked(cls, name, value):
        kind = dict(cls._fields_).get(name)
        if kind in _INT_RANGES and not isinstance(value, ctypes._SimpleCData):
            return checked_int(value, f"{cls.__name__}.{name}", *_INT_RANGES[kind])
        return value


class Material(_Checked):
    _fields_ = [("albedo", ctypes.c_float * 3), ("specular", ctypes.c_float), ("shininess", ctypes.c_float),
                ("roughness", ctypes.c_float), ("lobe", ctypes.c_uint32), ("shininess_v", ctypes.c_float),
                ("tangent", ctypes.c_float * 3)]


class Camera(_Checked):
    _fields_ = [("position", ctypes.c_float * 3), ("look_at", ctypes.c_float * 3), ("up", ctypes.c_float * 3),
                ("fov_deg", ctypes.c_float), ("width", ctypes.c_uint32), ("height", ctypes.c_uint32)]


class MeshInfo(_Checked):
    _fields_ = [("vertex_count", ctypes.c_uint32), ("triangle_count", ctypes.c_uint32),
                ("bvh_node_count", ctypes.c_uint32), ("bvh_depth", ctypes.c_uint32),
                ("bounds_lo", ctypes.c_float * 3), ("bounds_hi", ctypes.c_float * 3),
                ("has_normals", ctypes.c_uint32)]


class FivOptions(_Checked):
    _fields_ = [("theta", ctypes.c_uint32), ("phi", ctypes.c_uint32), ("radii", ctypes.c_uint32),
                ("inner_radius", ctypes.c_float), ("error_target", ctypes.c_float), ("face_size", ctypes.c_uint32),
                ("sun_supersampling", ctypes.c_uint32), ("sun_threshold", ctypes.c_float),
                ("precision", ctypes.c_uint32)]


class SgFitOptions(_Checked):
    _fields_ = [("face_size", ctypes.c_int32), ("iterations", ctypes.c_int32), ("max_sharpness", ctypes.c_float)]


class FivInfo(_Checked):
    _fields_ = [("options", FivOptions), ("centre", ctypes.c_float * 3), ("radius", ctypes.c_float),
                ("inner", ctypes.c_float), ("outer", ctypes.c_float), ("mesh_hash", ctypes.c_uint64),
                ("env_hash", ctypes.c_uint64), ("sample_count", ctypes.c_uint64), ("inside_count", ctypes.c_uint64),
                ("stored_bytes", ctypes.c_uint64), ("rays", ctypes.c_uint64), ("bake_seconds", ctypes.c_double),
                ("radii_done", ctypes.c_uint32)]


class ParamInfo(_Checked):
    _fields_ = [("name", ctypes.c_char_p), ("type", ctypes.c_uint32), ("stage", ctypes.c_uint32),
                ("default_value", ctypes.c_double), ("min", ctypes.c_double), ("max", ctypes.c_double),
                ("unit", ctypes.c_char_p), ("doc", ctypes.c_char_p)]


class MethodInfo(_Checked):
    _fields_ = [("name", ctypes.c_char_p), ("summary", ctypes.c_char_p), ("stage", ctypes.c_char_p),
                ("doc_page", ctypes.c_char_p), ("param_count", ctypes.c_uint32), ("output_count", ctypes.c_uint32),
                ("inputs", ctypes.c_uint32)]


class OutputInfo(_Checked):
    _fields_ = [("name", ctypes.c_char_p), ("doc", ctypes.c_char_p)]


class SphereSetInfo(_Checked):
    _fields_ = [("count", ctypes.c_uint32), ("grid", ctypes.c_uint32), ("mesh_hash", ctypes.c_uint64),
                ("mesh_volume", ctypes.c_float), ("outside_share", ctypes.c_float), ("missed_share", ctypes.c_float),
                ("build_seconds", ctypes.c_double), ("skin", ctypes.c_float)]


class HeightfieldPlacement(_Checked):
    _fields_ = [("origin", ctypes.c_float * 3), ("size", ctypes.c_float * 2), ("height_scale", ctypes.c_float)]


class EnvDomain(_Checked):
    _fields_ = [("direction", ctypes.c_float * 3), ("solid_angle", ctypes.c_float), ("radiance", ctypes.c_float * 3),
                ("cap_radius", ctypes.c_float)]


class EnvDecomposeOptions(_Checked):
    _fields_ = [("count", ctypes.c_uint32), ("seed", ctypes.c_uint32), ("max_iterations", ctypes.c_uint32)]


class EnvSharpOptions(_Checked):
    _fields_ = [("max_count", ctypes.c_uint32), ("threshold", ctypes.c_float), ("seed", ctypes.c_uint32),
                ("max_iterations", ctypes.c_uint32)]


# int (*)(void *user, uint64_t done, uint64_t total): nonzero stops the bake.
PROGRESS = ctypes.CFUNCTYPE(ctypes.c_int, ctypes.c_void_p, ctypes.c_uint64, ctypes.c_uint64)

_H = ctypes.c_void_p          # every opaque handle
_P = ctypes.c_void_p          # host pointers
_OUT = ctypes.POINTER(ctypes.c_void_p)
_u32, _i32, _f32, _size = ctypes.c_uint32, ctypes.c_int32, ctypes.c_float, ctypes.c_size_t
_str = ctypes.c_char_p

_SIGNATURES = {
    "pn_get_error": [_H, ctypes.POINTER(ctypes.c_char_p)],
    "pn_context_create": [_str, _OUT],
    "pn_context_create_from_cl": [_H, _H, _str, _OUT],
    "pn_context_retain": [_H], "pn_context_release": [_H],
    "pn_context_get_cl": [_H, _OUT, _OUT, _OUT],
    "pn_context_get_device_name": [_H, ctypes.c_char_p, _size],
    "pn_context_finish": [_H],
    "pn_context_build_program": [_H, _str],
    "pn_envmap_create": [_H, _OUT], "pn_envmap_release": [_H],
    "pn_envmap_set_latlong": [_H, _P, _u32, _u32],
    "pn_envmap_set_int": [_H, _str, _i32], "pn_envmap_set_float": [_H, _str, _f32],
    "pn_envmap_get_int": [_H, _str, ctypes.POINTER(_i32)], "pn_envmap_get_float": [_H, _str, ctypes.POINTER(_f32)],
    "pn_envmap_commit": [_H],
    "pn_envmap_read": [_H, ctypes.c_int, _P, _size],
    "pn_envmap_decompose": [_H, ctypes.POINTER(EnvDecomposeOptions), _P, _u32],
    "pn_envmap_extract_sharp": [_H, ctypes.POINTER(EnvSharpOptions), _P, _u32, ctypes.POINTER(_u32), _P, _size],
    "pn_mesh_create": [_H, _OUT], "pn_mesh_release": [_H],
    "pn_mesh_set_geometry": [_H, _P, _u32, _P, _u32, _P],
    "pn_mesh_commit": [_H],
    "pn_mesh_get_info": [_H, ctypes.POINTER(MeshInfo)],
    "pn_mesh_read_geometry": [_H, _P, _P, _P],
    "pn_transform_uniform_scale": [_P, ctypes.POINTER(_f32)],
    "pn_scene_create": [_H, _OUT], "pn_scene_release": [_H],
    "pn_scene_set_envmap": [_H, _H],
    "pn_scene_add_instance": [_H, _H, _P, ctypes.POINTER(Material), ctypes.POINTER(_u32)],
    "pn_scene_set_instance_transform": [_H, _u32, _P],
    "pn_scene_set_instance_material": [_H, _u32, ctypes.POINTER(Material)],
    "pn_scene_remove_instance": [_H, _u32],
    "pn_scene_set_camera": [_H, ctypes.POINTER(Camera)],
    "pn_scene_set_lights": [_H, _P, _u32],
    "pn_scene_attach": [_H, _u32, _H], "pn_scene_detach": [_H, _u32, _H],
    "pn_scene_commit": [_H],
    "pn_scene_intersect": [_H, _P, _u32, _P, _P, _P],
    "pn_scene_occluded": [_H, _P, _u32, _P],
    "pn_scene_intersect_arrays": [_H, _P, _P, _u32, ctypes.c_float, ctypes.c_float, _P, _P, _P],
    "pn_scene_occluded_arrays": [_H, _P, _P, _u32, ctypes.c_float, ctypes.c_float, _P],
    "pn_scene_render_gbuffer": [_H, _H],
    "pn_gbuffer_create": [_H, _u32, _u32, _OUT],
    "pn_gbuffer_create_from_cl": [_H, _u32, _u32, ctypes.POINTER(ctypes.c_void_p), _OUT],
    "pn_gbuffer_release": [_H],
    "pn_gbuffer_get_cl": [_H, ctypes.c_int, _OUT],
    "pn_gbuffer_write": [_H, ctypes.c_int, _P, _size],
    "pn_gbuffer_read": [_H, ctypes.c_int, _P, _size],
    "pn_gbuffer_validate": [_H],
    "pn_image_create": [_H, _u32, _u32, _OUT],
    "pn_image_create_from_cl": [_H, _u32, _u32, _H, _OUT],
    "pn_image_release": [_H],
    "pn_image_get_cl": [_H, _OUT],
    "pn_image_read": [_H, _P, _size],
    "pn_renderer_create": [_H, _str, _OUT], "pn_renderer_release": [_H],
    "pn_renderer_set_int": [_H, _str, _i32], "pn_renderer_set_float": [_H, _str, _f32],
    "pn_renderer_get_int": [_H, _str, ctypes.POINTER(_i32)],
    "pn_renderer_get_float": [_H, _str, ctypes.POINTER(_f32)],
    "pn_renderer_commit": [_H],
    "pn_renderer_execute": [_H, _H, _H, _H],
    "pn_renderer_read_output": [_H, _H, _str, _u32, _u32, _P, _size],
    "pn_renderer_set_env_domains": [_H, _P, _u32],
    "pn_renderer_set_depth_maps": [_H, _P, _P, _u32, _u32],
    "pn_renderer_set_depth_maps_sized": [_H, _P, _P, _u32, _P],
    "pn_renderer_set_depth_maps_cl": [_H, _P, _H, _u32, _P],
    "pn_method_get_info": [_str, ctypes.POINTER(MethodInfo)],
    "pn_method_get_param": [_str, _u32, ctypes.POINTER(ParamInfo)],
    "pn_method_get_output": [_str, _u32, ctypes.POINTER(OutputInfo)],
    "pn_mesh_get_hash": [_H, ctypes.POINTER(ctypes.c_uint64)],
    "pn_envmap_get_hash": [_H, ctypes.POINTER(ctypes.c_uint64)],
    "pn_isg_table": [_P, _size],
    "pn_envmap_fit_sgs": [_H, _u32, ctypes.POINTER(SgFitOptions), _P, _size],
    "pn_fiv_bake": [_H, _H, ctypes.POINTER(FivOptions), _str, PROGRESS, _P, _OUT],
    "pn_fiv_load": [_H, _str, _OUT],
    "pn_fiv_save": [_H, _str],
    "pn_fiv_release": [_H],
    "pn_fiv_get_info": [_H, ctypes.POINTER(FivInfo)],
    "pn_fiv_read_header": [_str, ctypes.POINTER(FivInfo)],
    "pn_fiv_read": [_H, _P, _size],
    "pn_heightfield_create": [_H, _OUT], "pn_heightfield_release": [_H],
    "pn_heightfield_set_heights": [_H, _P, _u32, _u32],
    "pn_heightfield_set_heights_region": [_H, _u32, _u32, _u32, _u32, _P],
    "pn_heightfield_set_placement": [_H, ctypes.POINTER(HeightfieldPlacement)],
    "pn_heightfield_set_albedo": [_H, _P, _size],
    "pn_heightfield_commit": [_H],
    "pn_heightfield_build_mesh": [_H, _OUT],
    "pn_sphere_set_build": [_H, _u32, _OUT], "pn_sphere_set_create": [_H, _P, _u32, _OUT],
    "pn_sphere_set_create_shell": [_H, _OUT],
    "pn_sphere_set_release": [_H], "pn_sphere_set_get_info": [_H, ctypes.POINTER(SphereSetInfo)],
    "pn_sphere_set_read": [_H, _P, _size], "pn_sphere_set_deform": [_H, _H],
}


def _candidates():
    env = os.environ.get("PENUMBRA_LIBRARY")
    if env:
        yield env
        return
    here = Path(__file__).resolve().parent
    for name in ("libpenumbra.so", "libpenumbra.dylib", "penumbra.dll"):
        yield str(here / name)
    found = ctypes.util.find_library("penumbra")
    if found:
        yield found


def _load():
    errors = []
    for path in _candidates():
        if os.sep in path and not os.path.exists(path):
            errors.append(f"{path}: not found")
            continue
        try:
            lib = ctypes.CDLL(path)
            break
        except OSError as exc:
            errors.append(f"{path}: {exc}")
    else:
        raise PenumbraError("cannot load libpenumbra (install the package with `pip install .` or set "
                            "PENUMBRA_LIBRARY): " + "; ".join(errors))
    for name, argtypes in _SIGNATURES.items():
        fn = getattr(lib, name)
        fn.argtypes = argtypes
        fn.restype = ctypes.c_int32
    lib.pn_version.restype = ctypes.c_char_p
    lib.pn_version.argtypes = []
    lib.pn_status_name.restype = ctypes.c_char_p
    lib.pn_status_name.argtypes = [ctypes.c_int32]
    lib.pn_method_count.restype = ctypes.c_uint32
    lib.pn_method_count.argtypes = []
    lib.pn_method_name.restype = ctypes.c_char_p
    lib.pn_method_name.argtypes = [ctypes.c_uint32]
    lib.pn_lobe_name.restype = ctypes.c_char_p
    lib.pn_lobe_name.argtypes = [ctypes.c_uint32]
    lib.pn_fiv_options_default.restype = FivOptions
    lib.pn_fiv_options_default.argtypes = []
    lib.pn_sg_fit_options_default.restype = SgFitOptions
    lib.pn_sg_fit_options_default.argtypes = []
    return lib


lib = _load()
library_path = lib._name


def last_error(ctx_handle) -> tuple[int, str]:
    msg = ctypes.c_char_p()
    status = lib.pn_get_error(ctx_handle, ctypes.byref(msg))
    return status, (msg.value or b"").decode("utf-8", "replace")


def call(name: str, ctx_handle, *args) -> None:
    """Calls ``name``; on failure raises with the message recorded for ``ctx_handle``.

    Errors are recorded on the context of the object passed; a NULL handle or
    a failed context creation records on the global slot, so both are read."""
    fn = getattr(lib, name)
    for k, (arg, kind) in enumerate(zip(args, fn.argtypes)):
        if kind in _INT_RANGES and not isinstance(arg, ctypes._SimpleCData):
            # ctypes wraps an int that does not fit (2**32 + 1 -> 1); refuse it instead.
            lo, hi = _INT_RANGES[kind]
            checked_int(arg, f"{name}: argument {k + 1}", lo, hi)
    status = fn(*args)
    if status == SUCCESS:
        return
    _, message = last_error(ctx_handle)
    if not message:
        _, message = last_error(None)
    text = f"{name}: {message or lib.pn_status_name(status).decode()}"
    cls = InputError if status in _INPUT_ERRORS else PenumbraError
    raise cls(text, status)


def version() -> str:
    return lib.pn_version().decode()


def methods() -> tuple[str, ...]:
    """Names of the shading methods the library offers, in its own order."""
    return tuple(lib.pn_method_name(i).decode() for i in range(lib.pn_method_count()))


def lobes() -> tuple[str, ...]:
    """Names of the specular lobes (pn_lobe), in the order of their values."""
    names = []
    while (name := lib.pn_lobe_name(len(names))) is not None:
        names.append(name.decode())
    return tuple(names)
