"""The ``heightfield`` method's Python side (docs/heightfield.md): the scene
file's ``[[heightfield]]`` tables, the native height fields (``pn_heightfield``)
and their instances, attached to each other when a scene is built, the
method's per-vertex outputs, its default benchmark sweep.

The grid itself (placement, file loaders, procedural terrains) is
:mod:`penumbra.heightfield`; the triangle mesh of a field is built by the
library only (:meth:`HeightFieldHandle.mesh`, also for the Mitsuba export).
"""

from __future__ import annotations

import ctypes
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .. import _native
from ..core import Context, Material, Mesh, _Handle, _ptr
from ..errors import InputError
from ..heightfield import (ALBEDO_EXTENSIONS, HEIGHT_EXTENSIONS, TERRAINS, HeightField, check_terrain_params,
                           load_albedo, load_heights, make_terrain)
from .base import SceneTable, Technique

NAME = "heightfield"


class HeightFieldHandle(_Handle):
    """A height field in the library (pn_heightfield, docs/heightfield.md):
    heights (D rows along +z, W columns along +x), placement and an optional
    per-vertex albedo map. ``set_heights`` each frame makes it dynamic."""

    _release = "pn_heightfield_release"

    def __init__(self, ctx: Context, heights, origin=(0.0, 0.0, 0.0), size=None, height_scale: float = 1.0,
                 albedo=None):
        super().__init__(ctx)
        _native.call("pn_heightfield_create", ctx._h, ctx._h, ctypes.byref(self._h))
        h = self._heights(heights)
        depth, width = h.shape
        self.shape = h.shape
        size = (width - 1.0, depth - 1.0) if size is None else size
        p = _native.HeightfieldPlacement((ctypes.c_float * 3)(*[float(x) for x in origin]),
                                         (ctypes.c_float * 2)(*[float(x) for x in size]), float(height_scale))
        self._call("pn_heightfield_set_placement", self._h, ctypes.byref(p))
        self._call("pn_heightfield_set_heights", self._h, _ptr(h), width, depth)
        if albedo is not None:
            a = np.ascontiguousarray(albedo, dtype=np.float32)
            if a.shape != (depth, width, 3):
                raise InputError(f"albedo map must have shape {(depth, width, 3)}, got {a.shape}")
            self._call("pn_heightfield_set_albedo", self._h, _ptr(a), a.size)
        self._call("pn_heightfield_commit", self._h)

    @staticmethod
    def _heights(heights) -> np.ndarray:
        h = np.ascontiguousarray(heights, dtype=np.float32)
        if h.ndim != 2:
            raise InputError(f"heights must be a 2D array (rows along z, columns along x), got shape {h.shape}")
        return h

    def set_heights(self, heights, region: tuple[int, int] | None = None) -> None:
        """New heights (a new frame of a dynamic terrain), committed. ``region=None``: the whole
        field, of the same size. ``region=(x0, y0)``: a local edit, ``heights`` (rows along z,
        columns along x) replaces columns x0 .. x0 + W' - 1 and rows y0 .. y0 + D' - 1; the next
        frame of a renderer that drew the field updates only what the edit can change
        (pn_heightfield_set_heights_region, docs/heightfield.md "Dynamic terrain")."""
        h = self._heights(heights)
        if region is None:
            if h.shape != self.shape:
                raise InputError(f"new heights have shape {h.shape}, the field is {self.shape}")
            self._call("pn_heightfield_set_heights", self._h, _ptr(h), h.shape[1], h.shape[0])
        else:
            x0, y0 = (int(v) for v in region)
            depth, width = self.shape
            if x0 < 0 or y0 < 0 or x0 + h.shape[1] > width or y0 + h.shape[0] > depth or not h.size:
                raise InputError(f"a region of {h.shape[1]} x {h.shape[0]} heights at column {x0}, row {y0} is "
                                 f"not inside the {width} x {depth} field")
            self._call("pn_heightfield_set_heights_region", self._h, x0, y0, h.shape[1], h.shape[0], _ptr(h))
        self._call("pn_heightfield_commit", self._h)

    def mesh(self) -> Mesh:
        """The committed heights as a triangle mesh in world space (the library's
        grid: vertex (i, j) at j * W + i, two triangles per cell, vertex normals)."""
        out = ctypes.c_void_p()
        self._call("pn_heightfield_build_mesh", self._h, ctypes.byref(out))
        return Mesh._adopt(self._ctx, out)


def output_shape(renderer, scene, output: str, instance: int) -> tuple[int, ...]:
    """The array shape of a per-vertex output of the height field attached to
    ``instance``: (D, W, k) float32 with k = 4 (radiance rgb and 1, or the
    normal), ``azimuths`` (horizon elevations, radians) or ``bands`` squared (SH
    visibility) as the renderer is set."""
    hf = scene.attachment(instance, HeightFieldHandle)
    if hf is None:
        raise InputError(f"instance {instance} has no height field attached")
    depth, width = hf.shape
    if output.endswith("_horizons") or output == "env_searched":
        k = renderer.get("azimuths")
    elif output.endswith("_visibility"):
        k = renderer.get("bands") ** 2
    else:
        k = 4
    return depth, width, k


# ---------------------------------------------------------------- the scene file's [[heightfield]] tables

HEIGHTFIELD_MAX_SIZE_PX = 8192
HEIGHTFIELD_DEFAULT_SIZE_PX = (256, 256)  # the seed's texture resolution
_KEYS = {"name", "file", "terrain", "size_px", "params", "origin", "size", "height_scale", "albedo", "albedo_map"}


@dataclass
class HeightfieldDesc:
    """``[[heightfield]]``: a height field from a file or a procedural terrain, placed in the
    world (docs/scene-format.md, docs/heightfield.md). :meth:`load` makes the :class:`HeightField`."""

    name: str
    file: str | None = None          # resolved height map path, or None for a terrain
    terrain: str | None = None       # one of heightfield.TERRAINS
    size_px: tuple[int, int] | None = None  # [W, D] of a terrain (parse default: (256, 256)); None for a file
    params: dict[str, Any] = field(default_factory=dict)  # arguments of the terrain
    origin: tuple[float, float, float] = (-5.0, 0.0, -5.0)  # vertex (0, 0); parse default: centred on x = z = 0
    size: tuple[float, float] = (10.0, 10.0)   # (size_x, size_z)
    height_scale: float = 1.0
    albedo: tuple[float, float, float] = (0.8, 0.8, 0.8)
    albedo_map: str | None = None    # resolved albedo map path (replaces albedo)

    def load(self) -> HeightField:
        """Reads or makes the heights (and albedo map); errors name this table."""
        t = f"[heightfield '{self.name}']"
        try:
            if self.file is not None:
                heights = load_heights(self.file)
            else:
                try:
                    heights = make_terrain(self.terrain, *(self.size_px or HEIGHTFIELD_DEFAULT_SIZE_PX), **self.params)
                except InputError as exc:
                    raise InputError(f"params: {exc}") from None
            albedo = self.albedo
            if self.albedo_map is not None:
                albedo = load_albedo(self.albedo_map)
                if albedo.shape[:2] != heights.shape:
                    raise InputError(f"albedo_map {self.albedo_map} is {albedo.shape[1]} x {albedo.shape[0]} "
                                     f"pixels but the heights are {heights.shape[1]} x {heights.shape[0]} "
                                     "(W x D): it needs one texel per height sample")
            return HeightField(heights, origin=self.origin, size=self.size, height_scale=self.height_scale,
                               albedo=albedo)
        except InputError as exc:
            raise InputError(f"{t} {exc}") from None


def _file_key(t: str, key: str, d: dict, base: Path, extensions: tuple[str, ...]) -> str:
    from ..scenefile import _resolve, _string, _where

    value = _string(t, key, d[key])
    if Path(value).suffix.lower() not in extensions:
        raise InputError(f"{_where(t, key)} = {value!r} must be a {', '.join(extensions)} file")
    return _resolve(base, value, _where(t, key))


def _parse_one(d: dict, index: int, base: Path) -> HeightfieldDesc:
    from ..scenefile import _integer, _named_entry, _number, _string, _vector, _where

    name, t = _named_entry(d, index, NAME, _KEYS)
    h = HeightfieldDesc(name=name)
    if ("file" in d) == ("terrain" in d):
        raise InputError(f"[{t}] needs exactly one of 'file' (a {', '.join(HEIGHT_EXTENSIONS)} height map) or "
                         f"'terrain' ({', '.join(TERRAINS)})")
    if "file" in d:
        for key in ("size_px", "params"):
            if key in d:
                raise InputError(f"{_where(t, key)} only applies to a 'terrain' (a file has its own size)")
        h.file = _file_key(t, "file", d, base, HEIGHT_EXTENSIONS)
    else:
        h.terrain = _string(t, "terrain", d["terrain"], tuple(TERRAINS))
        px = d.get("size_px", list(HEIGHTFIELD_DEFAULT_SIZE_PX))
        if not isinstance(px, (list, tuple)) or len(px) != 2:
            raise InputError(f"{_where(t, 'size_px')} must be [W, D] (samples along x and z), got {px!r}")
        h.size_px = tuple(_integer(t, f"size_px[{i}]", v, 2, HEIGHTFIELD_MAX_SIZE_PX) for i, v in enumerate(px))
        params = d.get("params", {})
        if not isinstance(params, dict):
            raise InputError(f"{_where(t, 'params')} must be a table")
        try:
            check_terrain_params(h.terrain, params)
        except InputError as exc:
            raise InputError(f"{_where(t, 'params')}: {exc}") from None
        h.params = dict(params)
    size = d.get("size", list(h.size))
    if not isinstance(size, (list, tuple)) or len(size) != 2:
        raise InputError(f"{_where(t, 'size')} must be [size_x, size_z], got {size!r}")
    h.size = tuple(_number(t, f"size[{i}]", v, lo=0.0, lo_open=True) for i, v in enumerate(size))
    h.origin = _vector(t, "origin", d.get("origin", [-h.size[0] / 2, 0.0, -h.size[1] / 2]))
    h.height_scale = _number(t, "height_scale", d.get("height_scale", h.height_scale))
    if "albedo" in d and "albedo_map" in d:
        raise InputError(f"[{t}] has both 'albedo' and 'albedo_map'; give one (the map replaces the constant)")
    h.albedo = _vector(t, "albedo", d.get("albedo", h.albedo), broadcast=True, lo=0.0, hi=1.0)
    if "albedo_map" in d:
        h.albedo_map = _file_key(t, "albedo_map", d, base, ALBEDO_EXTENSIONS)
    return h


def _parse_tables(value, base: Path, data: dict) -> list[HeightfieldDesc]:
    from ..scenefile import _named_entries

    return _named_entries(value, NAME, "height field", lambda x, i: _parse_one(x, i, base))


# ---------------------------------------------------------------- built scenes


def add_fields(ctx: Context, scene, descs: list[HeightfieldDesc],
               meshes: list[Mesh]) -> dict[str, tuple[HeightFieldHandle, int]]:
    """Adds each [[heightfield]] as a native height field and as its triangles
    (the library's mesh of it: an instance, so the G-buffer and the reference
    renderer see it) and attaches the field to that instance for the
    ``heightfield`` method. An albedo map goes to the field (per vertex) and
    the instance gets a white material; a constant albedo goes to the
    material. Returns name -> (field, instance id)."""
    out = {}
    for d in descs:
        data = d.load()
        albedo = data.albedo
        has_map = albedo is not None and np.ndim(albedo) == 3
        native = HeightFieldHandle(ctx, data.heights, origin=data.origin, size=data.size,
                                   height_scale=data.height_scale, albedo=albedo if has_map else None)
        mesh = native.mesh()
        meshes.append(mesh)
        material = Material(albedo=(1.0, 1.0, 1.0) if has_map else (albedo if albedo is not None else (0.8, 0.8, 0.8)))
        instance = scene.add(mesh, None, material)
        scene.attach(instance, native)
        out[d.name] = (native, instance)
    return out


def fields(built) -> dict[str, tuple[HeightFieldHandle, int]]:
    """The height fields of a built scene: name -> (field, instance id)."""
    return built.assets.get(NAME, {})


def world_geometry(d: HeightfieldDesc, ctx: Context | None = None):
    """(vertices, faces, normals) of a [[heightfield]] in world space, from the
    library's mesh of it (pn_heightfield_build_mesh), and the loaded field."""
    data = d.load()
    ctx = ctx or Context()
    native = HeightFieldHandle(ctx, data.heights, origin=data.origin, size=data.size, height_scale=data.height_scale)
    return native.mesh().geometry(), data


class Heightfield(Technique):
    scene_tables = (SceneTable(NAME, "heightfields", True, _parse_tables, content=True),)
    readme_setting: dict = {}           # the README's benchmark table shows the defaults
    readme_label = "defaults"
    per_pixel = False                   # its passes run over the height field's texels, not the image's pixels

    def applies_to(self, desc) -> bool:
        return bool(getattr(desc, "heightfields", None))

    def build(self, built) -> None:
        descs = getattr(built.desc, "heightfields", None) or []
        if descs:
            built.assets[NAME] = add_fields(built.ctx, built.scene, descs, built.meshes)

    def content_key(self, desc) -> bytes:
        # The tables and the contents of their height and albedo files.
        descs = list(getattr(desc, "heightfields", None) or [])
        out = [repr(descs).encode()]
        for d in descs:
            for path in (d.file, d.albedo_map):
                if path is not None and Path(path).is_file():
                    out.append(Path(path).read_bytes())
        return b"".join(out)

    def output_shape(self, renderer, scene, output: str, instance: int, index: int = 0) -> tuple[int, ...]:
        return output_shape(renderer, scene, output, instance)

    def sweep(self) -> list[dict]:
        # Azimuths, pyramid level step and SH bands from the cheapest up to the
        # defaults (6 bands), then the seed's all-SH product (exact_unoccluded 0) and its 4 bands.
        return [{"azimuths": 8, "level_step": 1, "bands": 3}, {"azimuths": 8}, {"azimuths": 16, "level_step": 2},
                {"azimuths": 16}, {}, {"exact_unoccluded": 0}, {"bands": 4}]


TECHNIQUE = Heightfield(NAME)
