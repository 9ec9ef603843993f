"""Scene files (TOML): the public contract documented in docs/scene-format.md.

:func:`load_scene` turns a file (or a dict) into a :class:`SceneDescription`
of plain values, checked key by key: an unknown key, a wrong type or a value
out of range raises :class:`~penumbra.errors.InputError` naming the table and
key. Relative paths resolve against the scene file's directory; ``data:REL``
names a file of the test data folder (:func:`penumbra.data.data_dir`).
"""

from __future__ import annotations

import copy
import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .core import LOBES
from .data import resolve as resolve_path
from .errors import InputError
from .meshio import DEFAULT_CREASE_ANGLE_DEG

PROCEDURAL_ENVS = ("sky", "constant", "directional", "area_lights")
PRIMITIVES = ("sphere", "box", "plane", "torus", "cylinder", "cone", "torus_knot")
DEFAULT_METHOD = "unshadowed"    # [render] method when the file names none


@dataclass
class EnvironmentDesc:
    map: str = "sky"                 # a file path (resolved) or one of PROCEDURAL_ENVS
    intensity: float = 1.0
    rotation_deg: float = 0.0
    face_size: int = 64
    irradiance_face_size: int = 32
    params: dict[str, Any] = field(default_factory=dict)  # arguments of the procedural map


@dataclass
class CameraDesc:
    position: tuple[float, float, float] = (0.0, 2.0, 6.0)
    look_at: tuple[float, float, float] = (0.0, 0.5, 0.0)
    up: tuple[float, float, float] = (0.0, 1.0, 0.0)
    fov_deg: float = 40.0
    resolution: tuple[int, int] = (512, 512)


@dataclass
class ObjectDesc:
    name: str
    mesh: str | None = None          # resolved file path, or None for a primitive
    primitive: str | None = None
    params: dict[str, Any] = field(default_factory=dict)  # arguments of the primitive
    translate: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rotate_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)
    scale: tuple[float, float, float] = (1.0, 1.0, 1.0)
    albedo: tuple[float, float, float] = (0.8, 0.8, 0.8)
    specular: float = 0.0
    shininess: float = 100.0
    roughness: float = 0.3
    lobe: str = "phong"
    shininess_v: float = 100.0       # ashikhmin_shirley: n_v (shininess is n_u)
    tangent: tuple[float, float, float] = (1.0, 0.0, 0.0)  # ashikhmin_shirley: u axis, object frame
    occluder: bool | None = None     # casts shadows in the methods that need occluders; None: True for a mesh file
    crease_angle_deg: float = DEFAULT_CREASE_ANGLE_DEG  # smooth normals of geometry that has none; 0: faceted

    @property
    def is_occluder(self) -> bool:
        """Whether methods that shadow from occluders' assets treat it as one (docs/scene-format.md)."""
        return self.mesh is not None if self.occluder is None else bool(self.occluder)

    def geometry_key(self) -> tuple:
        """Objects with equal keys have the same geometry (one mesh and BVH serve them)."""
        return (self.mesh, self.primitive, repr(sorted(self.params.items())), self.crease_angle_deg)

    def transform(self) -> np.ndarray:
        """4x4 object-to-world matrix: scale, then rotate about x, y, z (in that order), then translate."""
        rx, ry, rz = (math.radians(a) for a in self.rotate_deg)

        def rot(axis: int, a: float) -> np.ndarray:
            c, s = math.cos(a), math.sin(a)
            i, j = [(1, 2), (2, 0), (0, 1)][axis]
            m = np.eye(3)
            m[i, i], m[i, j], m[j, i], m[j, j] = c, -s, s, c
            return m

        m = np.eye(4)
        m[:3, :3] = rot(2, rz) @ rot(1, ry) @ rot(0, rx) @ np.diag(self.scale)
        m[:3, 3] = self.translate
        return m


@dataclass
class LightDesc:
    """A spherical light: a sphere of uniform radiance that lights surfaces
    but casts no shadow and is not seen by the camera (docs/reference.md)."""

    position: tuple = (0.0, 1.0, 0.0)
    radius: float = 0.1
    radiance: tuple = (10.0, 10.0, 10.0)

    def row(self) -> list[float]:
        return [*self.position, self.radius, *self.radiance]


@dataclass
class SceneDescription:
    environment: EnvironmentDesc
    camera: CameraDesc
    objects: list[ObjectDesc]
    lights: list[LightDesc] = field(default_factory=list)
    render: dict[str, Any] = field(default_factory=dict)  # method = "...", other keys: method parameters
    source: str = "<dict>"
    # The tables the techniques own (penumbra.methods: SceneTable), by attribute
    # name; desc.<attr> reads them (e.g. desc.fiv, desc.heightfields).
    tables: dict[str, Any] = field(default_factory=dict)

    def __getattr__(self, name: str):
        tables = self.__dict__.get("tables")
        if tables is not None and name in tables:
            return tables[name]
        raise AttributeError(f"{type(self).__name__} has no attribute {name!r}")


# ---------------------------------------------------------------- checking

def _where(table: str, key: str) -> str:
    return f"[{table}] {key}"


def _finite(v: int | float) -> bool:
    """Whether a number is finite as a float (an integer too large for a float is not)."""
    try:
        return math.isfinite(v)
    except OverflowError:
        return False


def _shown(v: Any) -> str:
    """``repr(v)``, shortened for messages (a 4000-digit integer)."""
    text = repr(v)
    return text if len(text) <= 60 else f"{text[:40]}... ({len(text)} characters)"


def _number(table: str, key: str, v: Any, lo: float | None = None, hi: float | None = None,
            lo_open: bool = False) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not _finite(v):
        raise InputError(f"{_where(table, key)} must be a finite number, got {_shown(v)}")
    if lo is not None and (v < lo or (lo_open and v == lo)):
        raise InputError(f"{_where(table, key)} = {v} must be {'>' if lo_open else '>='} {lo}")
    if hi is not None and v > hi:
        raise InputError(f"{_where(table, key)} = {v} must be <= {hi}")
    return float(v)


def _integer(table: str, key: str, v: Any, lo: int, hi: int) -> int:
    if isinstance(v, bool) or not isinstance(v, int) or not lo <= v <= hi:
        raise InputError(f"{_where(table, key)} must be an integer in [{lo}, {hi}], got {_shown(v)}")
    return v


def _vector(table: str, key: str, v: Any, n: int = 3, broadcast: bool = False, **limits) -> tuple:
    if broadcast and isinstance(v, (int, float)) and not isinstance(v, bool):
        v = [v] * n
    if not isinstance(v, (list, tuple)) or len(v) != n:
        raise InputError(f"{_where(table, key)} must be a list of {n} numbers{' or one number' if broadcast else ''}, "
                         f"got {v!r}")
    return tuple(_number(table, f"{key}[{i}]", x, **limits) for i, x in enumerate(v))


def _string(table: str, key: str, v: Any, choices: tuple[str, ...] | None = None) -> str:
    if not isinstance(v, str):
        raise InputError(f"{_where(table, key)} must be a string, got {v!r}")
    if choices is not None and v not in choices:
        raise InputError(f"{_where(table, key)} = {v!r} is not one of {', '.join(choices)}")
    return v


def _boolean(table: str, key: str, v: Any) -> bool:
    if not isinstance(v, bool):
        raise InputError(f"{_where(table, key)} must be true or false, got {v!r}")
    return v


def _check_keys(table: str, data: dict, allowed: set[str]) -> None:
    unknown = sorted(set(data) - allowed)
    if unknown:
        raise InputError(f"[{table}] has unknown key(s) {', '.join(unknown)}; known: {', '.join(sorted(allowed))}")


def _resolve(base: Path, p: str, where: str = "") -> str:
    """A file path of the scene: ``data:REL`` in the test data folder (penumbra.data), else against ``base``."""
    return resolve_path(p, base, where)


def _environment(d: dict, base: Path) -> EnvironmentDesc:
    t = "environment"
    _check_keys(t, d, {"map", "intensity", "rotation_deg", "face_size", "irradiance_face_size", "params"})
    e = EnvironmentDesc()
    m = _string(t, "map", d.get("map", "sky"))
    e.map = m if m in PROCEDURAL_ENVS else _resolve(base, m, _where(t, "map"))
    e.intensity = _number(t, "intensity", d.get("intensity", 1.0), lo=0.0)
    e.rotation_deg = _number(t, "rotation_deg", d.get("rotation_deg", 0.0))
    e.face_size = _integer(t, "face_size", d.get("face_size", 64), 1, 2048)
    e.irradiance_face_size = _integer(t, "irradiance_face_size", d.get("irradiance_face_size", 32), 2, 256)
    params = d.get("params", {})
    if not isinstance(params, dict):
        raise InputError(f"{_where(t, 'params')} must be a table")
    if params and m not in PROCEDURAL_ENVS:
        raise InputError(f"{_where(t, 'params')} only applies to procedural maps ({', '.join(PROCEDURAL_ENVS)})")
    e.params = dict(params)
    return e


def _camera(d: dict) -> CameraDesc:
    t = "camera"
    _check_keys(t, d, {"position", "look_at", "up", "fov_deg", "resolution"})
    c = CameraDesc()
    c.position = _vector(t, "position", d.get("position", c.position))
    c.look_at = _vector(t, "look_at", d.get("look_at", c.look_at))
    c.up = _vector(t, "up", d.get("up", c.up))
    c.fov_deg = _number(t, "fov_deg", d.get("fov_deg", c.fov_deg), lo=0.0, hi=179.9, lo_open=True)
    res = d.get("resolution", list(c.resolution))
    if not isinstance(res, (list, tuple)) or len(res) != 2:
        raise InputError(f"{_where(t, 'resolution')} must be [width, height], got {res!r}")
    c.resolution = (_integer(t, "resolution[0]", res[0], 1, 32768), _integer(t, "resolution[1]", res[1], 1, 32768))
    if np.allclose(c.position, c.look_at):
        raise InputError("[camera] look_at equals position")
    return c


_OBJECT_KEYS = {"name", "mesh", "primitive", "params", "translate", "rotate_deg", "scale", "albedo", "specular",
                "shininess", "roughness", "lobe", "shininess_v", "tangent", "occluder", "crease_angle_deg"}


def _named_entry(d: Any, index: int, array: str, keys: set[str]) -> tuple[str, str]:
    """(name, label for messages) of entry ``index`` of an array of tables
    ``[[array]]`` with a ``name`` key (default ``<array><index>``); its keys checked."""
    if not isinstance(d, dict):
        raise InputError(f"[[{array}]] #{index} must be a table")
    name = d.get("name", f"{array}{index}")
    t = f"{array} '{name}'"
    _check_keys(t, d, keys)
    return _string(t, "name", name), t


def _named_entries(value: Any, array: str, what: str, parse) -> list:
    """The entries of ``[[array]]`` (None: none), each ``parse(entry, index)``; their names unique."""
    value = [] if value is None else value
    if not isinstance(value, list):
        raise InputError(f"{what}s are given as [[{array}]] tables")
    descs = [parse(x, i) for i, x in enumerate(value)]
    names = [x.name for x in descs]
    dup = {n for n in names if names.count(n) > 1}
    if dup:
        raise InputError(f"{what} names must be unique; repeated: {', '.join(sorted(dup))}")
    return descs


def _object(d: dict, index: int, base: Path) -> ObjectDesc:
    name, t = _named_entry(d, index, "object", _OBJECT_KEYS)
    o = ObjectDesc(name=name)
    if ("mesh" in d) == ("primitive" in d):
        raise InputError(f"[{t}] needs exactly one of 'mesh' (a file) or 'primitive' ({', '.join(PRIMITIVES)})")
    if "mesh" in d:
        o.mesh = _resolve(base, _string(t, "mesh", d["mesh"]), _where(t, "mesh"))
    else:
        o.primitive = _string(t, "primitive", d["primitive"], PRIMITIVES)
    params = d.get("params", {})
    if not isinstance(params, dict):
        raise InputError(f"{_where(t, 'params')} must be a table")
    o.params = dict(params)
    o.translate = _vector(t, "translate", d.get("translate", o.translate))
    o.rotate_deg = _vector(t, "rotate_deg", d.get("rotate_deg", o.rotate_deg))
    o.scale = _vector(t, "scale", d.get("scale", 1.0), broadcast=True)
    if any(s == 0.0 for s in o.scale):
        raise InputError(f"{_where(t, 'scale')} must not contain 0 (the object would be flat)")
    o.albedo = _vector(t, "albedo", d.get("albedo", o.albedo), broadcast=True, lo=0.0, hi=1.0)
    o.specular = _number(t, "specular", d.get("specular", o.specular), lo=0.0, hi=1.0)
    o.shininess = _number(t, "shininess", d.get("shininess", o.shininess), lo=0.0)
    o.roughness = _number(t, "roughness", d.get("roughness", o.roughness), lo=0.0, hi=1.0, lo_open=True)
    o.lobe = _string(t, "lobe", d.get("lobe", o.lobe), LOBES)
    o.shininess_v = _number(t, "shininess_v", d.get("shininess_v", o.shininess_v), lo=0.0)
    o.tangent = _vector(t, "tangent", d.get("tangent", o.tangent))
    if not any(o.tangent):
        raise InputError(f"{_where(t, 'tangent')} must not be zero (it gives the anisotropic lobe's u direction)")
    o.occluder = _boolean(t, "occluder", d.get("occluder", o.mesh is not None))
    o.crease_angle_deg = _number(t, "crease_angle_deg", d.get("crease_angle_deg", o.crease_angle_deg), lo=0.0, hi=180.0)
    return o


def _light(d: dict, index: int) -> LightDesc:
    if not isinstance(d, dict):
        raise InputError(f"[[light]] #{index} must be a table")
    t = f"light #{index}"
    _check_keys(t, d, {"position", "radius", "radiance"})
    for key in ("position", "radius", "radiance"):
        if key not in d:
            raise InputError(f"[{t}] needs '{key}'")
    return LightDesc(position=_vector(t, "position", d["position"]),
                     radius=_number(t, "radius", d["radius"], lo=0.0, lo_open=True),
                     radiance=_vector(t, "radiance", d["radiance"], broadcast=True, lo=0.0))


def _render(d: dict) -> dict[str, Any]:
    """[render]: the method (a method of the library) and its renderer
    parameters, checked against the library's metadata (frame and plan
    parameters of that method; a bake option names the table it goes in)."""
    from .methods import names, technique

    render = dict(d)
    method = _string("render", "method", render.get("method", DEFAULT_METHOD), names())
    params = technique(method).check_render_table({k: v for k, v in render.items() if k != "method"})
    return {**({"method": method} if "method" in render else {}), **params}


def parse_scene(data: dict, base_dir: str | Path = ".", source: str = "<dict>") -> SceneDescription:
    """Checks a scene given as a dict (the parsed TOML) and returns its description."""
    from .methods import scene_tables

    base = Path(base_dir)
    owned = scene_tables()
    _check_keys("scene", data, {"environment", "camera", "object", "light", "render", *(t.key for t in owned)})
    for table in ("environment", "camera", "render", *(t.key for t in owned if not t.array)):
        if table in data and not isinstance(data[table], dict):
            raise InputError(f"[{table}] must be a table")
    descs = _named_entries(data.get("object"), "object", "object", lambda o, i: _object(o, i, base))
    lights = data.get("light", [])
    if not isinstance(lights, list):
        raise InputError("lights are given as [[light]] tables")
    return SceneDescription(environment=_environment(data.get("environment", {}), base),
                            camera=_camera(data.get("camera", {})), objects=descs,
                            lights=[_light(x, i) for i, x in enumerate(lights)], render=_render(data.get("render", {})),
                            source=source, tables={t.attr: t.parse(data.get(t.key), base, data) for t in owned})


def apply_overrides(data: dict, overrides: list[str]) -> dict:
    """Applies ``--set`` overrides ``table.key=value`` (value in TOML syntax, bare
    words taken as strings) to the parsed TOML. Objects are addressed by name or
    index: ``object.bunny.albedo=[1,0,0]``, ``object.0.translate=[0,1,0]``; the
    techniques' arrays of tables likewise (``heightfield.0.height_scale=2``);
    lights by index: ``light.0.radius=0.2``."""
    from .methods import scene_tables

    arrays = {"object": "object", "light": "light", **{t.key: t.key for t in scene_tables() if t.array}}
    data = copy.deepcopy(data)
    for item in overrides:
        if "=" not in item:
            raise InputError(f"--set {item!r} is not key=value")
        key, raw = item.split("=", 1)
        try:
            value = tomllib.loads(f"v = {raw}")["v"]
        except tomllib.TOMLDecodeError:
            value = raw
        except (RecursionError, ValueError):
            raise InputError(f"--set {key}: the value nests too deeply or cannot be read") from None
        parts = key.strip().split(".")
        if parts[0] in arrays:
            kind = arrays[parts[0]]
            if len(parts) != 3:
                raise InputError(f"--set {key}: {kind}s are set as {parts[0]}.NAME_OR_INDEX.key")
            objs = data.setdefault(parts[0], [])
            if not isinstance(objs, list):
                raise InputError(f"--set {key}: {parts[0]} is not a list of [[{parts[0]}]] tables")
            sel = parts[1]
            match = [o for i, o in enumerate(objs)
                     if isinstance(o, dict) and (o.get("name") == sel or str(i) == sel)]
            if not match:
                raise InputError(f"--set {key}: there is no {kind} named or numbered '{sel}'")
            match[0][parts[2]] = value
        elif len(parts) in (2, 3):
            table = data.setdefault(parts[0], {})
            if not isinstance(table, dict):
                raise InputError(f"--set {key}: {parts[0]} is not a table")
            if len(parts) == 3:
                table = table.setdefault(parts[1], {})
                if not isinstance(table, dict):
                    raise InputError(f"--set {key}: {parts[0]}.{parts[1]} is not a table")
            table[parts[-1]] = value
        else:
            raise InputError(f"--set {key}: expected table.key (e.g. camera.fov_deg=30)")
    return data


# A scene file larger than this is refused before it is parsed (scenes are a few KiB).
MAX_SCENE_BYTES = 16 << 20


def _parse_toml(text: str, what: str) -> dict:
    """tomllib.loads, with every way it fails on bad input as an InputError naming ``what``."""
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"{what} is not valid TOML: {exc}") from None
    except RecursionError:
        raise InputError(f"{what} nests arrays or tables too deeply") from None
    except ValueError as exc:   # e.g. an integer of more than 4300 digits
        raise InputError(f"{what} holds a value that cannot be read: {exc}") from None


def read_toml(path: str | Path) -> dict:
    p = Path(path)
    try:
        if p.exists() and not p.is_file():   # a FIFO would block the read, a device never end
            raise InputError(f"scene file {p} is {'a folder' if p.is_dir() else 'not a regular file'}")
        if p.is_file() and p.stat().st_size > MAX_SCENE_BYTES:
            raise InputError(f"scene file {p} is larger than {MAX_SCENE_BYTES >> 20} MiB")
        data = p.read_bytes()
    except OSError as exc:
        raise InputError(f"cannot read scene file {p}: {exc.strerror or exc}") from None
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise InputError(f"scene file {p} is not UTF-8 text (byte {exc.start}: {exc.reason})") from None
    return _parse_toml(text, f"scene file {p}")


def load_scene(path: str | Path, overrides: list[str] | None = None) -> SceneDescription:
    """Reads and checks a TOML scene file; ``overrides`` are ``--set`` strings."""
    p = Path(path)
    data = apply_overrides(read_toml(p), overrides or [])
    return parse_scene(data, p.resolve().parent, str(p))


def default_scene_path() -> Path:
    """The built-in procedural scene (no files outside the package)."""
    return Path(__file__).resolve().parent / "scenes" / "default.toml"
