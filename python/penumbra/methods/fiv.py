"""The ``fiv`` method's Python side (docs/fiv.md): everything Python knows about
Fullsphere Irradiance Vectors.

* Occlusion fields: a :class:`FivField` holds the FIV samples of one occluder
  mesh under one env map, baked by libpenumbra (``pn_fiv_bake``) on a
  (theta, phi, rho) grid around the mesh's bounding sphere, saved to
  versioned, checksummed files (:func:`read_header` reads one's header);
  :func:`cached_field` bakes on demand into a cache folder and reuses the file
  when the same mesh, env map and options come back.
* Bake options (:class:`FivOptions`) are the method's ``bake`` parameters in
  the library's metadata: names, defaults and ranges come from there.
* The scene file's ``[fiv]`` table, attaching a field to each occluder
  instance before rendering, the default benchmark sweep, the summary lines
  of ``penumbra render``, the ``bake-fiv`` and ``fiv-info`` commands and the
  occluder-count experiment (``penumbra bench --fiv-scaling``).
"""

from __future__ import annotations

import contextlib
import ctypes
import json
import os
import signal
import statistics
import sys
import time
import warnings
import weakref
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

from .. import _native
from .._native import call
from ..core import Context, EnvMap, Mesh, uniform_scale
from ..errors import InputError, PenumbraError
from . import spec
from .base import SceneTable, Technique

NAME = "fiv"
# pn_fiv_options.precision (the bake parameter `precision`, an int) by name.
PRECISIONS = {"float32": 0, "float16": 1}
# The grid's bake parameters in the paper's "32x17x15" order ([phi, theta, radii], the `samples` shorthand).
PAPER_ORDER = ("phi", "theta", "radii")


def _bake_params() -> dict:
    return {p.name: p for p in spec(NAME).params_of("bake")}


def bake_values(values: dict[str, Any], label: Callable[[str], str] = lambda k: k,
                base: dict[str, Any] | None = None) -> dict[str, int | float]:
    """Every bake parameter of ``fiv``, checked against the library's metadata:
    ``values`` (parameter names; ``samples`` = [phi, theta, radii] as
    shorthand; ``precision`` as "float16"/"float32" or the library's int) over
    ``base`` (default: the metadata defaults). ``label(key)`` names a key in
    messages (e.g. "[fiv] face_size")."""
    params = _bake_params()
    values = dict(values)
    where = {k: label(k) for k in values}
    if "samples" in values:
        samples = values.pop("samples")
        if not isinstance(samples, (list, tuple)) or len(samples) != 3:
            raise InputError(f"{label('samples')} must be [phi, theta, radii] (the paper's notation, e.g. "
                             f"[32, 17, 15]), got {samples!r}")
        for i, (name, v) in enumerate(zip(PAPER_ORDER, samples)):
            if name in values:
                raise InputError(f"{label('samples')} and {label(name)} both set {name}: give one")
            values[name], where[name] = v, f"{label('samples')}[{i}] ({name})"
    unknown = sorted(set(values) - set(params))
    if unknown:
        raise InputError(f"{', '.join(label(k) for k in unknown)}: not a bake option of fiv (known: samples, "
                         f"{', '.join(params)})")
    out = dict(base) if base is not None else {n: p.default for n, p in params.items()}
    for name, v in values.items():
        if name == "precision" and isinstance(v, str):
            if v not in PRECISIONS:
                raise InputError(f"{where[name]} = {v!r} is not one of {', '.join(PRECISIONS)}")
            v = PRECISIONS[v]
        out[name] = params[name].check(v, where[name])
    return out


class FivOptions:
    """Bake options of an occlusion field (``pn_fiv_options``): the ``fiv``
    method's bake parameters, by name, defaults and ranges from the library.
    ``samples`` = (theta, phi, radii) sets the grid in the order of
    pn_fiv_options; :meth:`from_paper` takes the paper's (phi, theta, radii)."""

    __slots__ = ("values",)

    def __init__(self, samples: Sequence[int] | None = None, **values):
        if samples is not None:
            if len(samples) != 3:
                raise InputError(f"FIV samples must be (theta, phi, radii), got {samples!r}")
            values.update({k: v for k, v in zip(("theta", "phi", "radii"), samples) if k not in values})
        self.values = bake_values(values, lambda k: f"FIV option {k}")

    @staticmethod
    def from_paper(phi_theta_rho: Sequence[int], **kw) -> "FivOptions":
        """Options from the paper's (phi, theta, rho) notation, e.g. 32x17x15 -> phi 32, theta 17, 15 radii."""
        return FivOptions(**dict(zip(PAPER_ORDER, (int(v) for v in phi_theta_rho))), **kw)

    @classmethod
    def checked(cls, values: dict[str, Any], label: Callable[[str], str], base: "FivOptions | None" = None):
        """Options from keys as a table or command line names them (bake_values),
        over ``base`` (default: the library's defaults); ``label`` names them in messages."""
        out = cls.__new__(cls)
        out.values = bake_values(values, label, None if base is None else base.values)
        return out

    def replace(self, **values) -> "FivOptions":
        return FivOptions.checked(values, lambda k: f"FIV option {k}", self)

    def __getattr__(self, name: str):
        try:
            return self.values[name]
        except KeyError:
            raise AttributeError(name) from None

    @property
    def samples(self) -> tuple[int, int, int]:
        """(theta, phi, radii), as pn_fiv_options."""
        return self.values["theta"], self.values["phi"], self.values["radii"]

    @property
    def paper_samples(self) -> tuple[int, int, int]:
        """(phi, theta, radii), the paper's notation and the scene file's ``samples``."""
        return tuple(self.values[k] for k in PAPER_ORDER)

    @property
    def precision_name(self) -> str:
        return {v: k for k, v in PRECISIONS.items()}[self.values["precision"]]

    def native(self) -> _native.FivOptions:
        return _native.FivOptions(**self.values)

    def key(self) -> str:
        v = self.values
        return (f"{v['phi']}x{v['theta']}x{v['radii']}-i{v['inner_radius']:g}-e{v['error_target']:g}"
                f"-f{v['face_size']}-s{v['sun_supersampling']}-{v['sun_threshold']:g}-{self.precision_name}")

    def __eq__(self, other) -> bool:
        return isinstance(other, FivOptions) and self.values == other.values

    def __hash__(self) -> int:
        return hash(tuple(sorted(self.values.items())))

    def __repr__(self) -> str:
        return "FivOptions(" + ", ".join(f"{k}={v!r}" for k, v in self.values.items()) + ")"


def _info_dict(i: _native.FivInfo) -> dict:
    o = i.options
    return {"samples": (o.theta, o.phi, o.radii), "inner_radius": o.inner_radius, "error_target": o.error_target,
            "face_size": o.face_size, "sun_supersampling": o.sun_supersampling, "sun_threshold": o.sun_threshold,
            "precision": {v: k for k, v in PRECISIONS.items()}.get(o.precision, str(o.precision)),
            "centre": tuple(i.centre), "radius": i.radius, "inner": i.inner, "outer": i.outer,
            "mesh_hash": f"{i.mesh_hash:016x}", "env_hash": f"{i.env_hash:016x}",
            "sample_count": i.sample_count, "inside_count": i.inside_count, "stored_bytes": i.stored_bytes,
            "rays": i.rays, "bake_seconds": i.bake_seconds, "radii_done": i.radii_done}


def read_header(path: str | os.PathLike) -> dict:
    """The header of a bake file, finished or not (pn_fiv_read_header, checksum
    checked): the keys of :meth:`FivField.info`, ``radii_done`` telling how far
    an unfinished bake got. InputError when it is not a readable bake file."""
    i = _native.FivInfo()
    call("pn_fiv_read_header", None, os.fsencode(path), ctypes.byref(i))
    return _info_dict(i)


def _holds_finished_bake(path) -> bool:
    """Whether ``path`` is a finished bake file (of any inputs)."""
    if path is None or not Path(path).is_file():
        return False
    try:
        head = read_header(path)
    except PenumbraError:
        return False
    return head["radii_done"] >= head["samples"][2]


class FivReuseWarning(UserWarning):
    """:meth:`FivField.bake` found a finished bake of the same inputs at its ``path`` and loaded it."""


class FivField:
    """An occlusion field: bake with :meth:`bake`, or :meth:`load` a bake file.
    ``baked_now``: whether :meth:`bake` traced its rays; ``reused``: whether it
    loaded a finished bake of the same inputs from its file instead."""

    baked_now = False
    reused = False

    def __init__(self, ctx: Context, handle: ctypes.c_void_p):
        self._ctx = ctx
        self._h = handle

    @classmethod
    def bake(cls, env: EnvMap, mesh: Mesh, options: FivOptions | None = None, path: str | os.PathLike | None = None,
             progress: Callable[[int, int], bool | None] | None = None, reuse: bool = True,
             quiet: bool = False) -> "FivField":
        """Bakes ``mesh`` under ``env``; ``progress(done, total)`` returning True stops it.

        With ``path`` the bake checkpoints to that file and resumes an
        unfinished bake of the same inputs there. A finished bake of the same
        inputs (the library compares the mesh hash, the env map hash and the
        options) is loaded instead of baked: ``reused`` is True and a
        :class:`FivReuseWarning` says so (not with ``quiet``, for caches). A
        file of other inputs is an :class:`~penumbra.errors.InputError` naming
        what differs, and is left alone. ``reuse=False`` replaces whatever is
        at ``path`` with a new bake.

        ``path`` follows the output policy (fileutil.output_target): a
        symbolic link is followed (the file it names is written), a target
        that is not a regular file is an InputError. Temporary files of
        earlier checkpoints of that file whose writer died are removed first
        (the library writes them; fileutil.remove_stale_temporaries)."""
        from ..fileutil import output_target, remove_stale_temporaries

        opts = (options or FivOptions()).native()
        out = ctypes.c_void_p()
        if path is not None:
            path = output_target(path, "FIV bake file", create_dirs=False)   # a missing folder: the library says so
            remove_stale_temporaries(path)
        if path is not None and not reuse:
            with contextlib.suppress(FileNotFoundError):
                os.unlink(path)
        finished_before = _holds_finished_bake(path)
        spheres = [0]   # spheres baked by this call: the library reports after each one it bakes

        def trampoline(_user, done, total):
            spheres[0] += 1
            if progress is None:
                return 0
            try:
                return 1 if progress(int(done), int(total)) else 0
            except BaseException:  # nothing (not even Ctrl-C) may cross the C boundary: stop the bake instead
                return 1

        cb = _native.PROGRESS(trampoline)
        call("pn_fiv_bake", env._ctx._h, env._h, mesh._h, ctypes.byref(opts),
             None if path is None else os.fsencode(path), cb, None, ctypes.byref(out))
        f = cls(env._ctx, out)
        # Reused: a finished file was there and the library baked no sphere in this call (it
        # loads a finished file of the same inputs; one of other inputs is an error). Comparing
        # the file's header before and after could not tell a fresh bake from a loaded one when
        # the two headers were equal.
        f.reused = finished_before and spheres[0] == 0
        f.baked_now = not f.reused
        if f.reused and not quiet:
            warnings.warn(f"{path} holds a finished bake of this mesh, env map and options: loaded it instead of "
                          "baking (reuse=False bakes anew)", FivReuseWarning, stacklevel=2)
        return f

    @classmethod
    def load(cls, ctx: Context, path: str | os.PathLike) -> "FivField":
        out = ctypes.c_void_p()
        call("pn_fiv_load", ctx._h, ctx._h, os.fsencode(path), ctypes.byref(out))
        return cls(ctx, out)

    def save(self, path: str | os.PathLike) -> None:
        call("pn_fiv_save", self._ctx._h, self._h, os.fsencode(path))

    def info(self) -> dict:
        i = _native.FivInfo()
        call("pn_fiv_get_info", self._ctx._h, self._h, ctypes.byref(i))
        return _info_dict(i)

    def samples(self) -> np.ndarray:
        """(radii, theta, phi, 3 axes, 3 channels) float32; NaN where the sample is inside the mesh."""
        theta, phi, radii = self.info()["samples"]
        out = np.empty((radii, theta, phi, 3, 3), np.float32)
        call("pn_fiv_read", self._ctx._h, self._h, out.ctypes.data, out.nbytes)
        return out

    def radii(self) -> np.ndarray:
        """Radii of the grid's spheres, object units (geometric from inner to outer)."""
        i = self.info()
        k = np.arange(i["samples"][2], dtype=np.float64)
        return i["inner"] * (i["outer"] / i["inner"]) ** (k / (len(k) - 1))

    def close(self) -> None:
        if self._h:
            _native.lib.pn_fiv_release(self._h)
            self._h = ctypes.c_void_p()

    def __del__(self):
        try:
            self.close()
        except Exception:
            pass


def mesh_hash(mesh: Mesh) -> str:
    h = ctypes.c_uint64()
    call("pn_mesh_get_hash", mesh._ctx._h, mesh._h, ctypes.byref(h))
    return f"{h.value:016x}"


def envmap_hash(env: EnvMap) -> str:
    h = ctypes.c_uint64()
    call("pn_envmap_get_hash", env._ctx._h, env._h, ctypes.byref(h))
    return f"{h.value:016x}"


def cache_dir() -> Path:
    """Where on-demand bakes go: $PENUMBRA_CACHE, else ~/.cache/penumbra."""
    base = os.environ.get("PENUMBRA_CACHE") or os.path.join(os.path.expanduser("~"), ".cache", "penumbra")
    return Path(base) / "fiv"


def cached_field(env: EnvMap, mesh: Mesh, options: FivOptions | None = None,
                 progress: Callable[[int, int], bool | None] | None = None,
                 directory: str | os.PathLike | None = None) -> FivField:
    """The field of (mesh, env, options) from the cache, baked (and cached) on a miss."""
    options = options or FivOptions()
    # a cache hit is the point of a cache: no reuse warning
    return FivField.bake(env, mesh, options, cache_path(env, mesh, options, directory), progress, quiet=True)


def cache_path(env: EnvMap, mesh: Mesh, options: FivOptions, directory: str | os.PathLike | None = None) -> Path:
    """The cache file of (mesh, env, options) in ``directory`` (default
    cache_dir()), created if needed: named by the mesh and env map hashes and
    the options, so every process that bakes or renders them finds one file."""
    folder = Path(directory) if directory is not None else cache_dir()
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise PenumbraError(f"cannot create the FIV cache folder {folder}: {exc}") from exc
    return folder / f"{mesh_hash(mesh)}-{envmap_hash(env)}-{options.key()}.pnfiv"


def bake_to_cache(job: dict, progress: Callable[[int, int], bool | None] | None = None) -> dict:
    """One bake of ``penumbra bake-fiv`` (serial or on a Dask worker, where
    it runs with the worker's own context): ``job`` = {"mesh": file,
    "env": {"map", "rotation_deg", "intensity"}, "options": bake options
    (FivOptions.checked), "cache": folder, "device": None or a device}.
    The field goes to its cache file (cache_path), checkpointed every few
    seconds and renamed into place atomically; an unfinished file there (a
    worker that died) is resumed, a finished one is loaded. Returns what
    happened: file, whether it baked now, the spheres it resumed from, the
    seconds and the worker. ``progress`` is FivField.bake's (True stops the
    bake after a checkpoint, PenumbraError ERROR_CANCELLED)."""
    from ..farm import worker_context, worker_name
    from ..meshio import load_mesh
    from ..render import environment_latlong
    from ..scenefile import EnvironmentDesc

    ctx = worker_context(job.get("device"))
    e = EnvironmentDesc(map=job["env"]["map"], rotation_deg=job["env"].get("rotation_deg", 0.0),
                        intensity=job["env"].get("intensity", 1.0))
    env = EnvMap(ctx, environment_latlong(e), rotation_deg=e.rotation_deg, intensity=e.intensity)
    m = load_mesh(job["mesh"])
    mesh = Mesh(ctx, m.vertices, m.faces, m.normals)
    options = FivOptions.checked(job["options"], lambda k: k)
    path = cache_path(env, mesh, options, job["cache"])
    try:
        head = read_header(path) if path.exists() else None
    except PenumbraError:
        head = None
    resumed_from = head["radii_done"] if head and head["radii_done"] < head["samples"][2] else 0
    start = time.perf_counter()
    f = FivField.bake(env, mesh, options, path, progress, quiet=True)   # a cache hit is the point of a cache
    return {"mesh": job["mesh"], "env": e.map, "path": str(path), "baked_now": f.baked_now,
            "resumed_from": resumed_from, "seconds": time.perf_counter() - start, "worker": worker_name()}


# ---------------------------------------------------------------- the scene file's [fiv] table


@dataclass
class FivTable:
    """``[fiv]``: how the method bakes occlusion fields (docs/scene-format.md):
    the bake options and the cache folder (resolved; None:
    $PENUMBRA_CACHE/fiv or ~/.cache/penumbra/fiv)."""

    options: FivOptions = field(default_factory=FivOptions)
    cache: str | None = None

    @property
    def samples(self) -> tuple[int, int, int]:
        """The grid as (phi, theta, radii), the table's ``samples``."""
        return self.options.paper_samples

    @property
    def precision(self) -> str:
        return self.options.precision_name

    def __getattr__(self, name: str):
        # The other bake options by name (face_size, inner_radius, ...).
        if name.startswith("__") or "options" not in self.__dict__:
            raise AttributeError(name)
        try:
            return self.options.values[name]
        except KeyError:
            raise AttributeError(name) from None


def _parse_table(d, base: Path, data: dict) -> FivTable:
    from ..scenefile import _check_keys, _resolve, _string

    d = {} if d is None else d
    if not isinstance(d, dict):
        raise InputError("[fiv] must be a table")
    _check_keys("fiv", d, {"samples", "cache", *_bake_params()})
    opts = FivOptions.checked({k: v for k, v in d.items() if k != "cache"}, lambda k: f"[fiv] {k}")
    cache = _resolve(base, _string("fiv", "cache", d["cache"])) if "cache" in d else None
    return FivTable(opts, cache)


def options_for(desc, overrides: dict | None = None) -> FivOptions:
    """The FivOptions of the scene's [fiv] table, bake parameters of
    ``overrides`` (``samples`` as [phi, theta, radii]) replacing its values."""
    table: FivTable = desc.fiv
    if not overrides:
        return table.options
    return FivOptions.checked(overrides, lambda k: f"fiv bake option {k}", table.options)


# ---------------------------------------------------------------- fields attached to a built scene


@dataclass
class FivState:
    """What the method keeps on a built scene (``built.assets["fiv"]``)."""

    options: FivOptions | None = None          # the options of the attached fields
    fields: list[FivField] = field(default_factory=list)
    records: list[dict] = field(default_factory=list)   # per field: objects, baked, bake_s, rays, ...
    flattened: dict[str, Mesh] = field(default_factory=dict)   # occluders whose rotation is baked into a mesh
    flat_meshes: dict[tuple, Mesh] = field(default_factory=dict)


def state(built) -> FivState:
    return built.assets.setdefault(NAME, FivState())


def _flatten_occluder(built, obj) -> Mesh:
    """Re-adds a rotated (sheared, mirrored or unevenly scaled) occluder as a
    mesh with its linear transform applied to the vertices, placed by a
    translation: the same geometry, whose field is baked for that orientation.
    Objects with the same geometry and linear transform share the mesh."""
    from ..render import object_geometry

    s = state(built)
    if obj.name in s.flattened:
        return s.flattened[obj.name]
    m = obj.transform()
    lin = m[:3, :3]
    key = (obj.geometry_key(), np.round(lin, 12).tobytes())
    mesh = s.flat_meshes.get(key)
    if mesh is None:
        v, f, n = object_geometry(obj)
        v = np.asarray(v, np.float64) @ lin.T
        f = np.asarray(f)
        if n is not None:
            n = np.asarray(n, np.float64) @ np.linalg.inv(lin)  # normals by the inverse transpose
            n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-30)
        if np.linalg.det(lin) < 0:
            f = f[:, ::-1]  # a mirror turns the winding inside out
        mesh = s.flat_meshes[key] = Mesh(built.ctx, v, np.ascontiguousarray(f), n)
        built.meshes.append(mesh)
    t = np.eye(4)
    t[:3, 3] = m[:3, 3]
    built.scene.remove(built.instance_ids[obj.name])
    built.instance_ids[obj.name] = built.scene.add(mesh, t, built.materials[obj.name])
    built.object_meshes[obj.name] = s.flattened[obj.name] = mesh
    return mesh


# Fields already in memory, by mesh, context, env map, options and cache folder:
# scenes built again in one process (the demo, benchmarks) reuse them instead of
# reading (and checking) the cache file again.
_FIELDS: "weakref.WeakValueDictionary[tuple, FivField]" = weakref.WeakValueDictionary()


def attach_fields(built, overrides: dict | None = None, bake_progress=None) -> list[dict]:
    """Bakes, or loads from the cache, one occlusion field per distinct
    occluder mesh of the scene (objects with ``occluder``, docs/scene-format.md)
    and attaches it to each occluder's instance. Fields already attached with
    the same options are kept. Occluders whose transform is not a uniform
    scale and a translation (pn_transform_uniform_scale) are re-added with that
    transform baked into their mesh (a field of its own, for that
    orientation). Returns one record per field: objects, mesh_hash, baked
    (False: loaded from the cache), bake_s, load_s, rays, stored_bytes,
    samples (phi, theta, radii)."""
    desc = built.desc
    if desc is None:
        raise InputError("the fiv method needs a scene built by build_scene from a description (its occluders)")
    options = options_for(desc, overrides)
    s = state(built)
    if s.options == options:
        return s.records
    groups: dict[str, tuple[Mesh, list[str]]] = {}
    for obj in desc.objects:
        if not obj.is_occluder:
            continue
        mesh = built.object_meshes[obj.name]
        if uniform_scale(obj.transform()) == 0.0:
            mesh = _flatten_occluder(built, obj)
        groups.setdefault(mesh_hash(mesh), (mesh, []))[1].append(obj.name)
    fields, records = [], []
    env_key = (built.ctx._h.value, envmap_hash(built.envmap), options, str(desc.fiv.cache))
    for h, (mesh, names) in groups.items():
        label = names[0] if len(names) == 1 else f"{names[0]} (+{len(names) - 1})"
        cb = None if bake_progress is None else (lambda done, total, label=label: bake_progress(label, done, total))
        t0 = time.perf_counter()
        f = _FIELDS.get((h, *env_key))
        baked = False
        if f is None:
            f = cached_field(built.envmap, mesh, options, progress=cb, directory=desc.fiv.cache)
            _FIELDS[(h, *env_key)] = f
            baked = f.baked_now
        info = f.info()
        for name in names:
            built.scene.attach(built.instance_ids[name], f)
        fields.append(f)
        theta, phi, radii = info["samples"]
        records.append({"objects": names, "mesh_hash": h, "baked": baked,
                        "bake_s": info["bake_seconds"] if baked else 0.0,
                        "load_s": time.perf_counter() - t0, "rays": info["rays"] if baked else 0,
                        "stored_bytes": info["stored_bytes"], "samples": [phi, theta, radii]})
    built.scene.commit()
    s.options, s.fields, s.records = options, fields, records
    return records


def attach_by_mesh(scene, fields: Sequence[FivField]) -> None:
    """Attaches each field to every instance of ``scene`` (added through it)
    whose mesh has the field's mesh hash, and detaches occlusion fields from
    the others: one call for scenes whose instances of a mesh all occlude.
    Takes effect at the next commit."""
    by_hash = {f.info()["mesh_hash"]: f for f in fields}
    for instance, mesh in list(scene._keep.items()):
        f = by_hash.get(mesh_hash(mesh))
        if f is not None:
            scene.attach(instance, f)
        elif scene.attachment(instance, FivField) is not None:
            scene.detach(instance, scene.attachment(instance, FivField))


def _kib(n: int) -> str:
    return f"{n / 1024:.1f} KiB" if n < 1 << 20 else f"{n / (1 << 20):.1f} MiB"


def summary(records: list[dict]) -> str:
    parts = []
    for r in records:
        what = ", ".join(r["objects"][:3]) + (f" and {len(r['objects']) - 3} more" if len(r["objects"]) > 3 else "")
        how = f"baked in {r['bake_s']:.1f} s ({r['rays'] / 1e6:.1f} M rays)" if r["baked"] else "from the cache"
        parts.append(f"{what}: {'x'.join(map(str, r['samples']))}, {_kib(r['stored_bytes'])}, {how}")
    return f"fiv: {len(records)} occlusion field(s): " + ("; ".join(parts) if parts else "no occluders in the scene")


# The finer grid of the sweep, also the setting the README's benchmark table shows.
FINE_SAMPLES = [64, 33, 30]


class Fiv(Technique):
    bake_table = NAME
    scene_tables = (SceneTable(NAME, NAME, False, _parse_table),)
    readme_setting = {"samples": FINE_SAMPLES}
    readme_label = "x".join(map(str, FINE_SAMPLES))

    def bake_aliases(self) -> tuple[str, ...]:
        return ("samples",)

    def applies_to(self, desc) -> bool:
        # Without occluders it would shade like unshadowed.
        return any(obj.is_occluder for obj in desc.objects)

    def prepare(self, built, bake, bake_progress=None) -> None:
        attach_fields(built, bake, bake_progress)

    def use_cache_folder(self, desc, folder: Path) -> None:
        if desc.fiv.cache is None:
            desc.fiv.cache = str(folder / NAME)

    def sweep(self) -> list[dict]:
        # Bake grids in the paper's (phi, theta, radii) notation, then the
        # overlap modes at the finer grid (1, the pair correction, is the default).
        coarse = list(FivOptions().paper_samples)
        return [{"samples": coarse}, {"samples": FINE_SAMPLES}, {"samples": FINE_SAMPLES, "overlap": 0},
                {"samples": FINE_SAMPLES, "overlap": 2}]

    def summary_lines(self, built) -> list[str]:
        return [summary(state(built).records)]

    def bake_report(self, built) -> dict:
        return {"fields": [dict(r) for r in state(built).records]}

    def bench_extras(self, built) -> dict:
        # The precomputation: fields, their memory, and the bake time when baked now.
        recs = state(built).records
        return {"fiv_fields": len(recs), "fiv_bytes": sum(r["stored_bytes"] for r in recs),
                "bake_s": sum(r["bake_s"] for r in recs) if all(r["baked"] for r in recs) else None}

    def report_lines(self, results: list[dict]) -> list[str]:
        from ..bench import _fmt_value

        rows = [r for r in results if r["method"] == NAME and "fiv_bytes" in r]
        if not rows:
            return []
        lines = ["", "fiv precomputation (one occlusion field per occluder mesh, docs/fiv.md; not in the frame "
                 "times):", "", "| params | fields | memory | bake |", "|---|---|---|---|"]
        seen = set()
        for r in rows:
            key = _fmt_value(r["params"].get("samples", "-"))
            if key in seen:
                continue
            seen.add(key)
            bake = f"{r['bake_s']:.1f} s" if r.get("bake_s") is not None else "cached"
            lines.append(f"| samples={key} | {r['fiv_fields']} | {r['fiv_bytes'] / 1024:.0f} KiB | {bake} |")
        return lines

    def add_commands(self, sub) -> dict:
        from ..cli import _samples_arg

        default = ",".join(map(str, FivOptions().paper_samples))
        f = sub.add_parser("bake-fiv", help="bake the FIV occlusion fields of meshes under env maps (docs/fiv.md), "
                                            "here or on a Dask cluster (docs/farm.md)")
        f.add_argument("mesh", nargs="+", help="occluder mesh files (.obj, .ply, .off, .stl)")
        f.add_argument("--env", required=True, action="append",
                       help="env map file, or a procedural map name (sky, constant, ...); repeat for several: "
                            "every mesh is baked under every env map")
        f.add_argument("--samples", type=_samples_arg, default=None, metavar="PHI,THETA,RADII",
                       help=f"grid in the paper's notation (default {default})")
        f.add_argument("-o", "--output", metavar="FILE",
                       help="bake file (.pnfiv) of one mesh under one env map; an unfinished bake there is resumed")
        f.add_argument("--cache", metavar="DIR",
                       help="without -o: the cache folder the fields go to, named as renders look them up "
                            "(default $PENUMBRA_CACHE/fiv or ~/.cache/penumbra/fiv); finished files are kept, "
                            "unfinished ones resumed")
        f.add_argument("--workers", type=int, metavar="N",
                       help="bake on a local Dask cluster of N worker processes (needs dask[distributed])")
        f.add_argument("--scheduler", metavar="ADDRESS",
                       help="bake on the Dask cluster of this scheduler (tcp://host:8786; docs/farm.md)")
        for p in _bake_params().values():  # the other bake options, as the library declares them
            if p.name in PAPER_ORDER:
                continue
            flag = "--" + p.name.replace("_", "-")
            if p.name == "precision":
                names = {v: k for k, v in PRECISIONS.items()}
                f.add_argument(flag, choices=tuple(PRECISIONS), default=None,
                               help=f"{p.doc} (default {names.get(p.default, p.default)})")
            else:
                f.add_argument(flag, type=int if p.type == "int" else float, default=None,
                               help=f"{p.doc} ({p.range_text()}{' ' + p.unit if p.unit else ''}, default {p.default})")
        f.add_argument("--env-rotation", type=float, default=0.0, metavar="DEG",
                       help="env map rotation about +y, as [environment] rotation_deg (default 0)")
        f.add_argument("--env-intensity", type=float, default=1.0, help="env radiance scale (default 1)")

        i = sub.add_parser("fiv-info", help="print the header of a FIV bake file")
        i.add_argument("file", help="bake file (.pnfiv)")
        i.add_argument("--json", action="store_true", help="print the info as JSON")
        return {"bake-fiv": cmd_bake_fiv, "fiv-info": cmd_fiv_info}

    def add_bench_arguments(self, b) -> None:
        from ..cli import _int_list, _samples_arg

        b.add_argument("--fiv-scaling", action="store_true",
                       help="instead of a scene: fiv's per-frame cost against the number of occluders (N bunnies)")
        b.add_argument("--fiv-counts", type=_int_list, default=FIV_SCALING_COUNTS,
                       help="occluder counts (default 1,10,30,60)")
        b.add_argument("--fiv-samples", type=_samples_arg, default=(128, 65, 30), metavar="PHI,THETA,RADII",
                       help="the bunny's field (default 128,65,30 as the paper's Table 2)")
        b.add_argument("--fiv-resolution", type=int, default=512, help="image side in pixels (default 512)")
        b.add_argument("--fiv-spread", type=int, default=60, metavar="N",
                       help="also N bunnies spread over a large floor, for tile culling (0: skip; default 60)")
        b.add_argument("--fiv-spread-spacing", type=float, default=120.0, metavar="UNITS",
                       help="their grid spacing; the floor is 8 spacings on a side (default 120)")
        b.add_argument("--fiv-mitsuba-count", type=int, default=10,
                       help="also compare with Mitsuba at equal error on this many bunnies (0: skip; default 10)")
        b.add_argument("--fiv-mitsuba-resolution", type=int, default=128,
                       help="image side of that comparison (default 128)")

    def run_bench(self, args) -> int | None:
        if not args.fiv_scaling:
            return None
        if args.scene:
            raise InputError("bench --fiv-scaling makes its own scenes: give no scene file")
        out = Path(args.out)
        res = fiv_scaling(out, counts=args.fiv_counts, samples=args.fiv_samples, resolution=args.fiv_resolution,
                          frames=args.frames, mitsuba_count=args.fiv_mitsuba_count or None,
                          mitsuba_resolution=args.fiv_mitsuba_resolution, overrides=args.set,
                          spread=args.fiv_spread or None, spread_spacing=args.fiv_spread_spacing,
                          log=lambda msg: print(msg, file=sys.stderr))
        # per lookup: the occluder loop's cost per lookup against one occluder's (the goal's measure);
        # "-unshad.": the earlier measure, (fiv - unshadowed) per lookup, by CPU time
        print(f"{'scene':>10}{'occluders':>10}{'fiv ms':>10}{'floor ms':>10}{'x floor':>9}{'(CPU)':>7}{'per lookup':>11}{'(CPU)':>7}"
              f"{'-unshad.':>9}{'unculled':>10}{'per tile':>9}{'paper fps':>11}")

        def x(v):
            return f"{v:.2f}x" if v is not None else "-"

        for r in res["results"]:
            print(f"{r['layout']:>10}{r['occluders']:>10}{r['fiv_shade_ms']:>10.2f}{r['floor_ms']:>10.3f}"
                  f"{r['ratio_to_floor']:>9.1f}{r['ratio_to_floor_cpu']:>7.1f}{x(r['loop_per_lookup_ratio']):>11}"
                  f"{x(r['loop_per_lookup_cpu_ratio']):>7}{x(r['per_lookup_cpu_ratio']):>9}"
                  f"{r['tile_cull_speedup']:>9.2f}x"
                  f"{r['tiles_per_tile_mean']:>9.1f}{r['paper_fps'] if r['paper_fps'] is not None else '-':>11}")
        print(f"penumbra bench: wrote {out}/results.json, report.md")
        return 0


TECHNIQUE = Fiv(NAME)


# ---------------------------------------------------------------- commands: bake-fiv, fiv-info


def cmd_bake_fiv(args) -> int:
    from .. import cli
    from ..fileutil import output_target
    from ..data import resolve as resolve_path
    from ..meshio import load_mesh
    from ..render import environment_latlong
    from ..scenefile import PROCEDURAL_ENVS, EnvironmentDesc

    # The options are checked against the library's bake parameters, named as flags.
    given = {p: getattr(args, p) for p in _bake_params() if p not in PAPER_ORDER and getattr(args, p) is not None}
    if args.samples is not None:
        given["samples"] = list(args.samples)
    options = FivOptions.checked(given, lambda k: "--" + k.replace("_", "-"))
    if args.env_intensity < 0:
        raise InputError(f"--env-intensity {args.env_intensity} must be >= 0")
    # Files as in scene files: data:REL in the test data folder, else relative to the working directory.
    envs = [e if e in PROCEDURAL_ENVS else str(resolve_path(e, Path.cwd(), "--env")) for e in args.env]
    args.mesh = [str(resolve_path(m, Path.cwd(), "MESH")) for m in args.mesh]
    farm = args.workers is not None or args.scheduler is not None
    if args.output is None or farm or len(args.mesh) > 1 or len(envs) > 1:
        if args.output is not None:
            raise InputError("-o FILE takes one mesh and one env map, baked here; for several, or with --workers / "
                             "--scheduler, give --cache DIR")
        return _bake_many(args, given, envs)
    args.mesh, args.env = args.mesh[0], args.env[0]
    output_target(args.output, "-o", create_dirs=False)   # before any work: not a folder, device or FIFO
    mesh_file = args.mesh
    env_desc = EnvironmentDesc(map=envs[0], rotation_deg=args.env_rotation, intensity=args.env_intensity)
    ctx = Context(args.device)
    env = EnvMap(ctx, environment_latlong(env_desc), rotation_deg=env_desc.rotation_deg,
                 intensity=env_desc.intensity)
    m = load_mesh(mesh_file)
    mesh = Mesh(ctx, m.vertices, m.faces, m.normals)
    out = Path(args.output)   # checked above; FivField.bake follows a symbolic link
    try:
        head = read_header(out) if out.exists() else None
    except PenumbraError:
        head = None
    resumed = bool(head and 0 < head["radii_done"] < head["samples"][2])
    if resumed:
        print(f"resuming {out}: {head['radii_done']} of {head['samples'][2]} spheres baked")
    bars = cli._BakeBars()
    previous = signal.getsignal(signal.SIGINT)

    def interrupt(*_):  # Ctrl-C: stop after the current sphere, with a checkpoint to resume from
        bars.stop = True

    if previous is signal.default_int_handler:
        signal.signal(signal.SIGINT, interrupt)
    label = Path(args.mesh).name
    try:
        with bars:
            fld = FivField.bake(env, mesh, options, out, progress=lambda d, t: bars(label, d, t), quiet=True)
    except PenumbraError as exc:
        if exc.status == _native.ERROR_CANCELLED:  # stopped by Ctrl-C after a checkpoint
            print(f"penumbra: interrupted: {exc} (the same command resumes it)", file=sys.stderr)
            return 130
        raise
    finally:
        if previous is signal.default_int_handler:
            signal.signal(signal.SIGINT, previous)
    info = fld.info()
    theta, phi, radii = info["samples"]
    grid = f"{phi}x{theta}x{radii} (phi x theta x radii)"
    if not fld.baked_now:
        print(f"{out} already holds this finished bake: {grid}, nothing to do")
    else:
        print(f"{'finished' if resumed else 'baked'} {label} under "
              f"{Path(args.env).name if args.env not in PROCEDURAL_ENVS else args.env} in "
              f"{info['bake_seconds']:.2f} s{' (all runs)' if resumed else ''}: {grid} = {info['sample_count']} "
              f"samples ({info['inside_count']} inside the mesh), {info['rays']} rays "
              f"({info['rays'] / max(info['bake_seconds'], 1e-9) / 1e6:.1f} M rays/s)")
    print(f"memory: {info['stored_bytes']} bytes of samples ({_kib(info['stored_bytes'])}, {info['precision']}); "
          f"{'wrote' if fld.baked_now else 'file'} {out} ({os.path.getsize(out)} bytes)")
    return 0


def _bake_many(args, given: dict, envs: list[str]) -> int:
    """bake-fiv over every mesh x env map into the cache folder: serially here,
    or on a Dask cluster (--workers N: a LocalCluster; --scheduler ADDRESS)."""
    from .. import farm
    from ..scenefile import PROCEDURAL_ENVS

    if args.workers is not None and args.scheduler is not None:
        raise InputError("give --workers N (a local cluster) or --scheduler ADDRESS, not both")
    if args.workers is not None and args.workers < 1:
        raise InputError(f"--workers {args.workers} must be >= 1")
    if args.workers is not None or args.scheduler is not None:
        farm.require_dask()  # before any work: the pip command when it is missing
    missing = [m for m in args.mesh if not Path(m).is_file()]
    missing += [e for e in envs if e not in PROCEDURAL_ENVS and not Path(e).is_file()]
    if missing:
        raise InputError(f"file not found: {', '.join(missing)}")
    cache = str(Path(args.cache).expanduser().resolve()) if args.cache else str(cache_dir())
    jobs = [{"mesh": str(Path(m).expanduser().resolve()), "options": given, "cache": cache, "device": args.device,
             "env": {"map": e, "rotation_deg": args.env_rotation, "intensity": args.env_intensity}}
            for m in dict.fromkeys(args.mesh) for e in dict.fromkeys(envs)]

    def describe(r):
        what = ("resumed from sphere %d and baked" % r["resumed_from"] if r["resumed_from"] else "baked") \
            if r["baked_now"] else "already cached"
        return f"{Path(r['mesh']).name} under {Path(r['env']).name}: {what} in {r['seconds']:.1f} s on " \
               f"{r['worker']} -> {r['path']}"

    start = time.perf_counter()
    if args.workers is None and args.scheduler is None:
        results = []
        for i, job in enumerate(jobs, 1):
            results.append(bake_to_cache(job))
            print(f"[{i}/{len(jobs)}, {time.perf_counter() - start:.1f} s] {describe(results[-1])}")
    else:
        where = args.scheduler or f"a local cluster of {args.workers} workers"
        print(f"bake-fiv: {len(jobs)} bakes on {where}, into {cache}")
        with farm.client(args.scheduler, args.workers) as c:
            results = farm.run(c, bake_to_cache, jobs, log=print, describe=describe)
    baked = sum(r["baked_now"] for r in results)
    print(f"bake-fiv: {len(results)} fields in {cache} ({baked} baked now, {len(results) - baked} already there) "
          f"in {time.perf_counter() - start:.1f} s")
    return 0


def cmd_fiv_info(args) -> int:
    if Path(args.file).exists() and not Path(args.file).is_file():   # a FIFO would block the library's read
        raise InputError(f"{args.file} is not a regular file")
    info = read_header(args.file)
    theta, phi, radii = info["samples"]
    if info["radii_done"] < radii:
        print(f"{args.file}: unfinished FIV bake, {phi}x{theta}x{radii} (phi x theta x radii), "
              f"{info['radii_done']} of {radii} spheres baked: run the same bake-fiv command again to resume",
              file=sys.stderr)
        return 2
    if args.json:
        print(json.dumps({**info, "samples_phi_theta_radii": [phi, theta, radii], "file_bytes":
                          os.path.getsize(args.file)}, indent=2))
        return 0
    c = info["centre"]
    print(f"{args.file}: FIV occlusion field (docs/fiv.md), {os.path.getsize(args.file)} bytes")
    print(f"  grid:        {phi}x{theta}x{radii} (phi x theta x radii) = {info['sample_count']} samples, "
          f"{info['inside_count']} inside the mesh")
    print(f"  storage:     {info['precision']}, {info['stored_bytes']} bytes of samples ({_kib(info['stored_bytes'])})")
    print(f"  radii:       {info['inner']:.4g} .. {info['outer']:.4g} object units, geometric "
          f"(inner_radius {info['inner_radius']:.3g} R, error_target {info['error_target']:.3g})")
    print(f"  bounds:      centre ({c[0]:.4g}, {c[1]:.4g}, {c[2]:.4g}), R = {info['radius']:.4g}")
    print(f"  directions:  face_size {info['face_size']}, sun_supersampling {info['sun_supersampling']} "
          f"(threshold {info['sun_threshold']:.3g})")
    print(f"  bake:        {info['rays']} rays in {info['bake_seconds']:.2f} s")
    print(f"  mesh hash:   {info['mesh_hash']}")
    print(f"  env hash:    {info['env_hash']}")
    return 0


# ---------------------------------------------------------------- experiment: cost against occluder count

FIV_SCALING_COUNTS = (1, 10, 30, 60)
# Michael and Chrysanthou, Table 2: frames per second at 512x512 on a GeForce 8800
# with 1, 10, 30 and 60 moving occluders.
PAPER_FPS = {1: 112, 10: 68, 30: 35, 60: 22}
SCALING_MESH = "meshes/bunny_odedstein_3k.obj"
SCALING_ENV = "envmaps/immenstadter_horn_1k_polyhaven.hdr"


def fiv_scaling_scene(n: int, mesh: str, envmap: str, resolution: int = 512, samples=(128, 65, 30),
                      cache: str | None = None, seed: int = 7) -> dict:
    """The occluder-count scene: ``n`` bunnies (one mesh, so one field for all;
    uniform scales 0.7-0.85, no rotation) on a jittered 8x8 grid over a
    12x12 ground plane, seen from above at about 40 degrees. Counts nest: the first
    10 of 30 bunnies are the 10 of the 10-bunny scene. Paths as given."""
    if not 1 <= n <= 64:
        raise InputError(f"the scaling scene holds 1 to 64 bunnies, not {n}")
    rng = np.random.default_rng(seed)
    cells = rng.permutation(64)
    jitter = rng.uniform(-0.12, 0.12, (64, 2))
    scales = rng.uniform(0.7, 0.85, 64)
    objects = [{"name": "ground", "primitive": "plane", "params": {"size": [16.0, 16.0]}, "albedo": 0.6}]
    for k in range(n):
        c = int(cells[k])
        x, z = -5.25 + 1.5 * (c % 8) + jitter[c, 0], -5.25 + 1.5 * (c // 8) + jitter[c, 1]
        s = round(float(scales[c]), 3)
        objects.append({"name": f"bunny{k}", "mesh": mesh, "translate": [round(x, 3), round(0.769 * s, 4), round(z, 3)],
                        "scale": s, "albedo": [0.8, 0.78, 0.72]})
    fiv = {"samples": list(samples)}
    if cache:
        fiv["cache"] = cache
    return {"environment": {"map": envmap, "face_size": 128, "irradiance_face_size": 32},
            "camera": {"position": [0.0, 7.0, 9.0], "look_at": [0.0, 0.0, 0.2], "fov_deg": 62,
                       "resolution": [resolution, resolution]},
            "render": {"method": "fiv"}, "fiv": fiv, "object": objects}


def fiv_spread_scene(n: int, mesh: str, envmap: str, resolution: int = 512, samples=(128, 65, 30),
                     cache: str | None = None, seed: int = 11, spacing: float = 60.0) -> dict:
    """The tile-culling scene: ``n`` bunnies (as fiv_scaling_scene) on a
    jittered 8x8 grid of ``spacing`` world units over a floor 8 x spacing on
    a side, seen from a low camera 6 units behind the first bunny, so that
    most tiles lie farther than the occluders' culling distance (a few
    hundred R under a hard sun) from most bunnies. Paths as given."""
    if not 1 <= n <= 64:
        raise InputError(f"the spread scene holds 1 to 64 bunnies, not {n}")
    rng = np.random.default_rng(seed)
    cells = rng.permutation(64)
    jitter = rng.uniform(-0.3, 0.3, (64, 2)) * spacing
    scales = rng.uniform(0.7, 0.85, 64)
    side = 8 * spacing
    objects = [{"name": "ground", "primitive": "plane", "params": {"size": [side, side]}, "albedo": 0.6}]
    first = None
    for k in range(n):
        c = int(cells[k])
        x = -3.5 * spacing + spacing * (c % 8) + jitter[c, 0]
        z = -3.5 * spacing + spacing * (c // 8) + jitter[c, 1]
        s = round(float(scales[c]), 3)
        objects.append({"name": f"bunny{k}", "mesh": mesh, "translate": [round(x, 3), round(0.769 * s, 4), round(z, 3)],
                        "scale": s, "albedo": [0.8, 0.78, 0.72]})
        first = first or (round(x, 3), round(z, 3))
    fiv = {"samples": list(samples)}
    if cache:
        fiv["cache"] = cache
    return {"environment": {"map": envmap, "face_size": 128, "irradiance_face_size": 32},
            "camera": {"position": [first[0], 2.5, first[1] + 6.0], "look_at": [first[0], 0.4, first[1]],
                       "fov_deg": 62, "resolution": [resolution, resolution]},
            "render": {"method": "fiv"}, "fiv": fiv, "object": objects}


def occluder_bounds(built, cull_threshold: float = 1e-3) -> dict:
    """Per occluder instance of a built scene (fields attached): world centre,
    bounding radius R and culling distance, as capi/src/methods/fiv.c
    build_records computes them (E_ref from the env's cube, the largest ``|FIV|``
    of a channel on the outermost sphere)."""
    env = built.envmap
    dirs, omega = env.cube_directions()
    power = (env.cube_radiance().reshape(-1, 3).astype(np.float64) * omega.reshape(-1, 1)).sum(0).max()
    env_ref = power / 4.0
    objects = {o.name: o for o in built.desc.objects}
    centres, radii, culls, outers, cells = [], [], [], [], []
    for f, rec in zip(state(built).fields, state(built).records):
        info = f.info()
        outer_sphere = np.asarray(f.samples()[-1], np.float64)
        norm = np.sqrt((outer_sphere ** 2).sum(axis=-2))
        outer_max = float(np.nanmax(norm)) if np.isfinite(norm).any() else 0.0
        cull = np.inf
        if cull_threshold > 0:
            cull = info["outer"] * np.sqrt(max(outer_max / max(cull_threshold * env_ref, 1e-30), 1.0))
        # The per-direction bound of capi/src/methods/fiv.c cell_bounds: per
        # (theta, phi) cell of the outer sphere, its 4 corners' largest |FIV|.
        top = np.where(np.isnan(norm), -np.inf, norm).max(axis=-1)
        corners = np.stack([top[:-1], np.roll(top[:-1], -1, 1), top[1:], np.roll(top[1:], -1, 1)]).max(0)
        for name in rec["objects"]:
            m = objects[name].transform()
            sc = uniform_scale(m)
            centres.append(m[:3, :3] @ np.asarray(info["centre"], np.float64) + m[:3, 3])
            radii.append(sc * info["radius"])
            culls.append(sc * cull)
            outers.append(sc * info["outer"])
            cells.append(np.maximum(corners, 0.0))
    return {"centre": np.array(centres).reshape(-1, 3), "radius": np.array(radii), "cull": np.array(culls),
            "outer": np.array(outers), "cell_bound": cells, "cull_floor": cull_threshold * env_ref}


def tile_occluder_counts(gbuffer: dict, bounds: dict, width: int, tile: int = 16) -> dict:
    """A float64 twin of kernels/fiv.cl bin_fiv_tiles: per tile with receivers,
    how many occluders' culling spheres reach the box of its receivers, and per
    receiver pixel how many occluders it looks up (not culled by distance,
    not wholly behind its plane: the "occluders that matter") and of those
    how many it fetches samples of (not culled per direction either)."""
    pos = gbuffer["position"][..., :3].reshape(-1, 3).astype(np.float64)
    nrm = gbuffer["normal"][..., :3].reshape(-1, 3).astype(np.float64)
    fg = (gbuffer["instance"].ravel() != 0xFFFFFFFF) & np.isfinite(pos).all(axis=1)
    height = pos.shape[0] // width
    c, r, cull = bounds["centre"], bounds["radius"], bounds["cull"]
    ty, tx = np.divmod(np.arange(pos.shape[0]), width)
    tid = (ty // tile) * ((width + tile - 1) // tile) + tx // tile
    tiles = ((width + tile - 1) // tile) * ((height + tile - 1) // tile)
    lo = np.full((tiles, 3), np.inf)
    hi = np.full((tiles, 3), -np.inf)
    np.minimum.at(lo, tid[fg], pos[fg])
    np.maximum.at(hi, tid[fg], pos[fg])
    used = np.isfinite(lo).all(axis=1)
    d = np.maximum(np.maximum(lo[used, None, :] - c[None], c[None] - hi[used, None, :]), 0.0)
    per_tile = ((d ** 2).sum(-1) <= cull[None] ** 2).sum(1)
    p, n = pos[fg], nrm[fg]
    per_pixel = np.zeros(len(p), np.int64)
    fetches = np.zeros(len(p), np.int64)
    for k in range(len(r)):  # one occluder at a time: memory linear in the pixels
        v = c[k] - p
        rho = np.linalg.norm(v, axis=1)
        looked_up = ((v * n).sum(1) > -r[k]) & (rho <= cull[k])
        per_pixel += looked_up
        if "cell_bound" in bounds and bounds["cull_floor"] > 0:
            # Beyond the grid, the direction's cell bound times the fall-off
            # (kernels/fiv.cl pn_fiv_lookup): below the floor, no fetch.
            cb = bounds["cell_bound"][k]
            nt, nphi = cb.shape[0] + 1, cb.shape[1]
            d = v / np.where(rho > 0, rho, 1.0)[:, None]
            phi = np.mod(np.arctan2(d[:, 2], d[:, 0]), 2 * np.pi)
            ci = np.minimum((np.arccos(np.clip(d[:, 1], -1, 1)) * (nt - 1) / np.pi).astype(int), nt - 2)
            cj = np.minimum((phi * nphi / (2 * np.pi)).astype(int), nphi - 1)
            outer = bounds["outer"][k]
            beyond = rho > outer
            falloff = (outer / np.where(beyond, rho, outer)) ** 2
            looked_up &= ~(beyond & (cb[ci, cj] * falloff < bounds["cull_floor"]))
        fetches += looked_up
    return {"tiles": int(used.sum()), "per_tile_mean": float(per_tile.mean()) if per_tile.size else 0.0,
            "per_tile_median": float(np.median(per_tile)) if per_tile.size else 0.0,
            "per_tile_max": int(per_tile.max()) if per_tile.size else 0,
            "per_tile_min": int(per_tile.min()) if per_tile.size else 0,
            "per_tile_histogram": np.bincount(per_tile, minlength=len(r) + 1).tolist(),
            "lookups_per_pixel": float(per_pixel.mean()) if per_pixel.size else 0.0,
            "fetches_per_pixel": float(fetches.mean()) if fetches.size else 0.0,
            "receiver_pixels": int(fg.sum())}


# The shading variants timed against each other, round-robin on one G-buffer.
SCALING_VARIANTS = {"floor": ("floor", {}), "unshadowed": ("unshadowed", {}), "fiv": ("fiv", {}),
                    "fiv_sum": ("fiv", {"overlap": 0}), "fiv_unculled": ("fiv", {"tile_cull": 0}),
                    # the disc correction pairing up to 32 occluders per pixel (the default before max_overlap 6)
                    "fiv_pairs32": ("fiv", {"max_overlap": 32})}
# shade_fiv without its occluder loop (kernels/fiv.cl, PN_FIV_PROFILE 4: the
# pixel set-up, the unshadowed part, self-shadowing, the background and the
# output; the tile binning runs as in fiv), built in a context of its own and
# timed in the same rounds: what the cost per occluder lookup is counted above.
NO_LOOP_BUILD = "build_options=-DPN_FIV_PROFILE=4"
NO_LOOP_VARIANTS = {"fiv_noloop": ("fiv", {}), "fiv_sum_noloop": ("fiv", {"overlap": 0})}


def per_lookup_costs(ms: dict, lookups: float) -> dict:
    """ns per occluder lookup of fiv (overlap 1) and its plain sum (overlap
    0), by the wall clock and by CPU time, from _interleaved_ms's medians
    ``ms`` and the (pixel, occluder) pairs the kernel interpolates. Two
    measures: ``loop_per_lookup*`` = (fiv - fiv without the occluder loop) /
    lookups, the occluder loop's own time, which the goal (cost per occluder
    that matters <= 2x the single occluder's) is read from (with the rounds'
    times in ``ms["rounds"]``, the median of each round's difference, so
    that a change in the machine's load between rounds cancels out; else
    the difference of the medians); and the earlier
    ``per_lookup*`` = (fiv - unshadowed) / lookups, kept for comparison,
    which also counts what fiv's pixel work costs above unshadowed's, so a
    change in either kernel's pixel work moves it although no lookup got
    cheaper or dearer. None without lookups (or without the no-loop
    timings, for the loop measure)."""
    out = {}
    rounds = ms.get("rounds", {})
    for suffix, col in (("", "fiv"), ("_sum", "fiv_sum"), ("_pairs32", "fiv_pairs32")):
        for clock in ("", "cpu:"):
            tag = suffix + ("_cpu" if clock else "")
            # without the loop no pair is formed: fiv's no-loop kernel serves max_overlap 32 too
            a, b = clock + col, clock + ("fiv_noloop" if col == "fiv_pairs32" else col + "_noloop")
            if a not in ms:
                continue
            if a in rounds and b in rounds:
                loop = statistics.median([x - y for x, y in zip(rounds[a], rounds[b], strict=True)])
            else:
                loop = ms[a] - ms[b] if b in ms else None
            out[f"loop{tag}_ms"] = loop
            out[f"per_lookup{tag}_ns"] = (ms[a] - ms[clock + "unshadowed"]) * 1e6 / lookups if lookups else None
            out[f"loop_per_lookup{tag}_ns"] = loop * 1e6 / lookups if lookups and loop is not None else None
    return out


PER_LOOKUP_KEYS = tuple(f"{m}per_lookup{s}{c}_ns" for m in ("loop_", "") for s in ("", "_sum", "_pairs32")
                        for c in ("", "_cpu"))


def per_lookup_ratios(rows: list[dict]) -> None:
    """Adds to each row, for every per-lookup cost (PER_LOOKUP_KEYS), its
    ratio to the single clustered occluder's (key ..._ratio; None where
    either is missing or the single occluder's is not above 0: a loop time
    lost in the wall clock's noise, which would give a negative ratio)."""
    single = next((r for r in rows if r["occluders"] == 1 and r["layout"] == "clustered"), None)
    for r in rows:
        for key in PER_LOOKUP_KEYS:
            base = single.get(key) if single else None
            r[key.replace("_ns", "_ratio")] = r[key] / base if base and base > 0 and r.get(key) is not None else None


def _cpu_timed(fn, ctx) -> float:
    """ms of the process's CPU time (the OpenCL runtime's worker threads
    included) for fn and the queue's finish."""
    t0 = time.process_time()
    fn()
    ctx.finish()
    return 1000.0 * (time.process_time() - t0)


def _interleaved_ms(built, variants: dict, frames: int, others=()) -> dict:
    """Median shading ms of each variant on one G-buffer, the variants
    executed in turn each round (so a change in the machine's load hits all
    alike); warm-up rounds for WARMUP_SECONDS excluded. Each variant is timed
    by the wall clock and, in a run of its own in the same round, by the
    process's CPU time (key "cpu:" + variant): the work done, however many
    of the runtime's threads a kernel got and whatever else the machine ran.
    On a CPU device the wall clock favours short kernels: PoCL's second worker
    thread often joins a sub-millisecond kernel (the floor) too late to take
    any of it, and a kernel that fits in a scheduler slice is not preempted
    by other jobs, while a kernel of several milliseconds is (docs/fiv.md,
    Speed). ``others``: (built, variants) pairs of the same scene built in
    other contexts (other kernel builds), each with a G-buffer and an image
    of its own, timed in the same rounds after the main build's variants
    (keys must not repeat); the returned image is the main build's last
    variant's. Also returns, per other build, whether its G-buffer planes
    equal the main one's (key "same_gbuffer:" + its first variant), and
    every round's times (key "rounds": variant -> list, in round order)."""
    from ..core import GBuffer, Image, Renderer
    from ..render import WARMUP_SECONDS, _timed

    ctx = built.ctx
    w, h = built.camera.resolution
    gbuffer, image = GBuffer(ctx, w, h), Image(ctx, w, h)
    gtimes = [_timed(lambda: built.scene.render_gbuffer(gbuffer), ctx)]
    # key -> (built, renderer, G-buffer, image), the main build's first
    runs = {k: (built, Renderer(ctx, m, **kw), gbuffer, image) for k, (m, kw) in variants.items()}
    extra = []
    for other, vs in others:
        c = other.ctx
        gb, im = GBuffer(c, w, h), Image(c, w, h)
        other.scene.render_gbuffer(gb)
        c.finish()
        extra.append((next(iter(vs)), gb))
        for k, (m, kw) in vs.items():
            if k in runs:
                raise ValueError(f"variant {k} given twice")
            runs[k] = (other, Renderer(c, m, **kw), gb, im)
    times = {k: [] for k in runs}
    times.update({"cpu:" + k: [] for k in runs})
    warm_until = time.perf_counter() + WARMUP_SECONDS
    rounds = 0
    while rounds < frames + 1:
        for k, (b, r, gb, im) in runs.items():
            t = _timed(lambda: r.execute(b.scene, gb, im), b.ctx)
            c = _cpu_timed(lambda: r.execute(b.scene, gb, im), b.ctx)
            if rounds >= 1:
                times[k].append(t)
                times["cpu:" + k].append(c)
        if rounds >= 1 or time.perf_counter() >= warm_until:
            rounds += 1
    for _ in range(frames - 1):
        gtimes.append(_timed(lambda: built.scene.render_gbuffer(gbuffer), ctx))
    planes = {p: gbuffer.read(p) for p in ("position", "normal", "instance")}
    out = {k: statistics.median(t) for k, t in times.items()}
    out["gbuffer"] = statistics.median(gtimes)
    out["rounds"] = times
    for k, gb in extra:
        out["same_gbuffer:" + k] = all(planes[p].tobytes() == gb.read(p).tobytes() for p in planes)
    last = next(reversed(variants))
    return out, planes, runs[last][3].read()


def fiv_scaling(out_dir: str | Path, counts=FIV_SCALING_COUNTS, samples=(128, 65, 30), resolution: int = 512,
                frames: int = 5, data_dir: str | Path | None = None, mitsuba_count: int | None = 10,
                mitsuba_resolution: int = 128, mitsuba_opts: BenchOptions | None = None, overrides=(),
                spread: int | None = 60, spread_spacing: float = 120.0, log=print) -> dict:
    """Per-frame cost of ``fiv`` against the number of occluders: renders
    N = ``counts`` bunnies (one shared field of ``samples`` = (phi, theta,
    radii)) at ``resolution`` x ``resolution`` pixels and, with ``spread``,
    that many bunnies spread over a large floor (fiv_spread_scene). Per
    scene, the floor kernel, unshadowed, fiv, fiv's plain sum (overlap 0)
    and fiv without tile culling (tile_cull 0), and in a second kernel build
    (NO_LOOP_BUILD) fiv and its plain sum without the occluder loop, are
    timed round-robin on one G-buffer each (_interleaved_ms): every ratio
    comes from one run. Also per scene: the per-tile occluder list lengths
    and the occluder lookups per pixel (tile_occluder_counts), hence the
    cost per occluder that matters (per_lookup_costs: the loop's time per
    lookup, and the earlier (fiv - unshadowed) per lookup beside it). With
    ``mitsuba_count``, also runs the speed-against-error benchmark (run())
    on that scene at ``mitsuba_resolution``² (fiv against the ground truth
    and Mitsuba 3). ``overrides``: ``--set`` strings applied to every scene.
    Writes ``scenes/*.toml``, results.json and report.md into ``out_dir``."""
    from .. import __version__
    from ..bench import BenchOptions, _exposure, run, scene_toml
    from ..fileutil import atomic_write_text
    from ..render import build_scene, render
    from ..scenefile import load_scene

    if frames < 5:
        raise InputError(f"frames = {frames}: the measuring protocol takes the median of at least 5")
    out = Path(out_dir)
    (out / "scenes").mkdir(parents=True, exist_ok=True)
    from .. import data as test_data

    if data_dir is None and not test_data.available():
        raise InputError(f"the fiv scaling benchmark {test_data.missing_reason()}")
    data = Path(data_dir) if data_dir is not None else test_data.data_dir()
    for rel in (SCALING_MESH, SCALING_ENV):
        if not (data / rel).is_file():
            raise InputError(f"{data / rel} not found (the fiv scaling benchmark reads it from the test data folder)")

    def rel(p: Path) -> str:
        return Path(os.path.relpath(p.resolve(), (out / "scenes").resolve())).as_posix()

    scenes = {}
    for n in sorted(set(counts) | ({mitsuba_count} if mitsuba_count else set())):
        data_n = fiv_scaling_scene(n, rel(data / SCALING_MESH), rel(data / SCALING_ENV), resolution, samples,
                                   cache="../cache/fiv")
        path = out / "scenes" / f"bunnies_{n}.toml"
        atomic_write_text(path, scene_toml(data_n, f"fiv occluder-count benchmark: {n} bunnies (penumbra.methods."
                                                   "fiv.fiv_scaling_scene)"))
        scenes[n] = path
    runs = [(n, "clustered", scenes[n]) for n in counts]
    if spread:
        data_s = fiv_spread_scene(spread, rel(data / SCALING_MESH), rel(data / SCALING_ENV), resolution, samples,
                                  cache="../cache/fiv", spacing=spread_spacing)
        path = out / "scenes" / f"spread_{spread}.toml"
        atomic_write_text(path, scene_toml(data_s, f"fiv tile-culling benchmark: {spread} bunnies over a "
                                                   f"{8 * spread_spacing:g} x {8 * spread_spacing:g} floor "
                                                   "(penumbra.methods.fiv.fiv_spread_scene)"))
        runs.append((spread, "spread", path))

    ctx = Context()
    no_loop_ctx = Context(NO_LOOP_BUILD)   # shade_fiv without the occluder loop (NO_LOOP_VARIANTS)
    load_start = os.getloadavg()[0]
    rows, bake = [], None
    for n, layout, scene_path in runs:
        desc = load_scene(scene_path, list(overrides))
        built = build_scene(desc, ctx)
        t0 = time.perf_counter()
        render(built, "fiv", frames=1, warmup=False,
               bake_progress=lambda label, d, t: log(f"bake {label}: {d}/{t} samples") if d == t else None)
        if bake is None:
            rec = state(built).records[0]
            bake = {"samples": rec["samples"], "baked_now": rec["baked"], "bake_s": rec["bake_s"] if rec["baked"]
                    else None, "rays": rec["rays"], "stored_bytes": rec["stored_bytes"],
                    "first_use_s": time.perf_counter() - t0}
        no_loop = build_scene(desc, no_loop_ctx)
        attach_fields(no_loop)   # from the cache the render above filled
        ms, planes, image = _interleaved_ms(built, SCALING_VARIANTS, frames, others=[(no_loop, NO_LOOP_VARIANTS)])
        del no_loop
        bins = tile_occluder_counts(planes, occluder_bounds(built), built.camera.resolution[0])
        fg = float((planes["instance"] != 0xFFFFFFFF).mean())
        row = {"occluders": n, "layout": layout, "fields": len(state(built).records), "fiv_shade_ms": ms["fiv"],
               "floor_ms": ms["floor"], "ratio_to_floor": ms["fiv"] / ms["floor"],
               "fiv_cpu_ms": ms["cpu:fiv"], "floor_cpu_ms": ms["cpu:floor"],
               "ratio_to_floor_cpu": ms["cpu:fiv"] / ms["cpu:floor"],
               "tile_cull_speedup_cpu": ms["cpu:fiv_unculled"] / ms["cpu:fiv"],
               "fiv_sum_shade_ms": ms["fiv_sum"], "fiv_unculled_shade_ms": ms["fiv_unculled"],
               "fiv_pairs32_shade_ms": ms["fiv_pairs32"], "fiv_pairs32_cpu_ms": ms["cpu:fiv_pairs32"],
               "tile_cull_speedup": ms["fiv_unculled"] / ms["fiv"],
               "unshadowed_shade_ms": ms["unshadowed"], "unshadowed_cpu_ms": ms["cpu:unshadowed"],
               "fiv_sum_cpu_ms": ms["cpu:fiv_sum"], "fiv_noloop_shade_ms": ms["fiv_noloop"],
               "fiv_noloop_cpu_ms": ms["cpu:fiv_noloop"], "fiv_sum_noloop_shade_ms": ms["fiv_sum_noloop"],
               "fiv_sum_noloop_cpu_ms": ms["cpu:fiv_sum_noloop"],
               "noloop_same_gbuffer": ms["same_gbuffer:fiv_noloop"], "gbuffer_ms": ms["gbuffer"],
               "frame_ms": ms["gbuffer"] + ms["fiv"], "fps_shading": 1000.0 / ms["fiv"],
               "fps_frame": 1000.0 / (ms["gbuffer"] + ms["fiv"]), "paper_fps": PAPER_FPS.get(n) if layout ==
               "clustered" else None, "geometry_fraction": fg, **{f"tiles_{k}": v for k, v in bins.items()}}
        # What one occluder lookup costs: the occluder loop's time (fiv
        # without the loop subtracted; earlier: unshadowed) over the
        # (pixel, occluder) pairs that pass the per-pixel culling.
        row.update(per_lookup_costs(ms, bins["lookups_per_pixel"] * bins["receiver_pixels"]))
        if not row["noloop_same_gbuffer"]:
            log(f"{n} occluders ({layout}): the no-loop build's G-buffer differs from the main one's")
        rows.append(row)
        log(f"{n} occluders ({layout}): fiv {row['fiv_shade_ms']:.2f} ms ({row['ratio_to_floor']:.1f}x floor "
            f"{row['floor_ms']:.3f} ms; by CPU time {row['ratio_to_floor_cpu']:.1f}x), unculled {row['fiv_unculled_shade_ms']:.2f} ms, "
            f"{bins['per_tile_mean']:.1f} occluders per tile, {bins['lookups_per_pixel']:.1f} lookups per pixel")
        if layout == "spread" or (not spread and n == max(counts)):
            from ..imageio import write_png

            write_png(out / f"fiv_{layout}_{n}.png", image[..., :3],
                      exposure=_exposure(image[..., :3], planes["instance"] != 0xFFFFFFFF))
    per_lookup_ratios(rows)

    equal_error = None
    if mitsuba_count:
        mopts = mitsuba_opts or BenchOptions(methods=("unshadowed", "fiv"), rays=False,
                                             sweeps={"unshadowed": [{}], "fiv": [{"samples": list(samples)}]})
        res = run(scenes[mitsuba_count], out / f"mitsuba_{mitsuba_count}", mopts,
                  overrides=[*overrides, f"camera.resolution=[{mitsuba_resolution},{mitsuba_resolution}]"], log=log)
        equal_error = {"occluders": mitsuba_count, "resolution": [mitsuba_resolution] * 2,
                       "report": f"mitsuba_{mitsuba_count}/report.md",
                       "results": [{k: r.get(k) for k in ("method", "params", "time_ms", "shade_ms", "nrmse",
                                                          "mitsuba_speedup", "mitsuba_speedup_bound")}
                                   for r in res["results"]]}

    summary = {"device": ctx.device_name, "penumbra_version": __version__, "date": time.strftime("%Y-%m-%d"),
               "overrides": list(overrides), "cpus": os.cpu_count(),
               "load_average_1min": [round(load_start, 2), round(os.getloadavg()[0], 2)],
               "resolution": [resolution, resolution], "frames": frames, "mesh": SCALING_MESH, "envmap": SCALING_ENV,
               "samples_phi_theta_radii": list(samples), "bake": bake, "spread_spacing": spread_spacing,
               "paper": "Michael and Chrysanthou, Table 2: GeForce 8800, 512x512, fps with 1/10/30/60 occluders"}
    atomic_write_text(out / "results.json", json.dumps({"summary": summary, "results": rows,
                                                        "equal_error": equal_error}, indent=2) + "\n")
    atomic_write_text(out / "report.md", scaling_markdown(summary, rows, equal_error))
    return {"summary": summary, "results": rows, "equal_error": equal_error}


def scaling_markdown(summary: dict, rows: list[dict], equal_error: dict | None) -> str:
    from ..bench import _fmt_params

    s = summary
    b = s["bake"] or {}
    phi, theta, radii = s["samples_phi_theta_radii"]
    bake = (f"baked in {b['bake_s']:.1f} s ({b['rays'] / 1e6:.0f} M rays)" if b.get("bake_s") is not None
            else "loaded from the cache (baked by an earlier run)")
    lines = ["# fiv: cost against the number of occluders", "",
             f"{s['resolution'][0]}x{s['resolution'][1]} pixels, N bunnies ({s['mesh']}) scattered on a ground plane "
             f"under {s['envmap']} (`scenes/bunnies_N.toml`), device {s['device']}, penumbra "
             f"{s['penumbra_version']}, {s['date']}. One occlusion field shared by every bunny: {phi}x{theta}x{radii} "
             f"(phi x theta x radii, as the paper's Table 2), {b.get('stored_bytes', 0) / 1024:.0f} KiB, {bake}. "
             f"Times: kernel builds excluded, 0.3 s of warm-up rounds, median of {s['frames']} rounds. The floor kernel "
             "(reads the G-buffer, writes the image) is timed in the same rounds; fps = 1000 / ms. System load "
             f"average (1 min) at the start / end of the timings: {s['load_average_1min'][0]} / "
             f"{s['load_average_1min'][1]} on {s['cpus']} CPUs.", "",
             "| scene | occluders | fiv shading ms | floor ms | fiv / floor | fiv / floor (CPU time) | fps (shading) | fps (G-buffer + shading) | "
             "paper fps (GeForce 8800) | fiv overlap=0 ms | unshadowed ms | fiv tile_cull=0 ms | tile culling speed-up | "
             "occluders per tile (mean / median / max) | lookups per pixel (fetching samples) | "
             "fiv without the occluder loop ms (wall / CPU) | ns per lookup, occluder loop (overlap 1 / 0) | "
             "per lookup / 1 occluder's (overlap 1 / 0) | the same by CPU time | "
             "earlier measure, (fiv - unshadowed) per lookup / 1 occluder's, CPU time (overlap 1 / 0) | "
             "fiv max_overlap=32 ms | its per lookup / 1 occluder's, CPU time | G-buffer ms |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]

    def f(x, fmt):
        return "-" if x is None else format(x, fmt)

    for r in rows:
        lines.append(f"| {r['layout']} | {r['occluders']} | {r['fiv_shade_ms']:.2f} | {r['floor_ms']:.3f} | "
                     f"{r['ratio_to_floor']:.1f} | {r['ratio_to_floor_cpu']:.1f} | {r['fps_shading']:.1f} | {r['fps_frame']:.1f} | "
                     f"{r['paper_fps'] if r['paper_fps'] is not None else '-'} | {r['fiv_sum_shade_ms']:.2f} | "
                     f"{r['unshadowed_shade_ms']:.2f} | {r['fiv_unculled_shade_ms']:.2f} | "
                     f"{r['tile_cull_speedup']:.2f} | {r['tiles_per_tile_mean']:.1f} / {r['tiles_per_tile_median']:g} / "
                     f"{r['tiles_per_tile_max']} | {r['tiles_lookups_per_pixel']:.2f} "
                     f"({r['tiles_fetches_per_pixel']:.2f}) | "
                     f"{r['fiv_noloop_shade_ms']:.2f} / {r['fiv_noloop_cpu_ms']:.2f} | "
                     f"{f(r['loop_per_lookup_ns'], '.1f')} / {f(r['loop_per_lookup_sum_ns'], '.1f')} | "
                     f"{f(r['loop_per_lookup_ratio'], '.2f')} / {f(r['loop_per_lookup_sum_ratio'], '.2f')} | "
                     f"{f(r['loop_per_lookup_cpu_ratio'], '.2f')} / {f(r['loop_per_lookup_sum_cpu_ratio'], '.2f')} | "
                     f"{f(r['per_lookup_cpu_ratio'], '.2f')} / {f(r['per_lookup_sum_cpu_ratio'], '.2f')} | "
                     f"{f(r.get('fiv_pairs32_shade_ms'), '.2f')} | {f(r.get('loop_per_lookup_pairs32_cpu_ratio'), '.2f')} | "
                     f"{r['gbuffer_ms']:.1f} |")
    lines += ["", "Every time in a row comes from one run: the floor kernel, unshadowed, fiv, its plain sum and fiv "
              "without tile culling, and fiv and its plain sum built without the occluder loop (on a G-buffer of "
              "their own, the same bits), are executed in turn on one G-buffer, the median of each taken "
              "(penumbra.methods.fiv._interleaved_ms). fiv uses its defaults: overlap = 1 (the pairwise "
              "unit-bounding-disc correction, docs/fiv.md) among the max_overlap = 6 occluders with the largest "
              "irradiance at a pixel (max_overlap=32 timed in the same rounds) and tile_cull = 1 (per 16x16 tile, only the occluders "
              "whose culling distance reaches the tile's receivers). Occluders per tile: over the tiles with "
              "receivers. Lookups per pixel: the (pixel, occluder) pairs the kernel interpolates (not culled by "
              "distance, not wholly behind the pixel's plane), per receiver pixel, and in brackets those that "
              "also pass the per-direction bound and fetch samples. ns per lookup = (fiv - fiv without the "
              "occluder loop, the median of the rounds' differences) / those pairs, against the 1-occluder "
              "scene's: the loop's own time, the "
              "without-loop kernel (build option PN_FIV_PROFILE=4, kernels/fiv.cl: the pixel set-up, the "
              "unshadowed part, the background and the output; the tile binning runs in both) timed in the "
              "same rounds on the same scene, so a change in fiv's pixel work does not move it. The earlier "
              "measure, (fiv - unshadowed) / those pairs, also counted what fiv's pixel work costs above "
              "unshadowed's whole kernel; it is kept for comparison (results.json: per_lookup_*, the loop's "
              "loop_per_lookup_*). fiv / floor (CPU time): the same "
              "ratio by the process's CPU time (medians of runs of their own in the same rounds): the work done, "
              "which the goal's ratio is read from; the wall clock lets the floor kernel, shorter than a "
              "scheduler slice, run without the waits that stretch a longer kernel, and it often leaves the "
              "runtime's second thread no share of the floor (docs/fiv.md, Speed)."]
    single = next((r for r in rows if r["occluders"] == 1 and r["layout"] == "clustered"), None)
    spread = next((r for r in rows if r["layout"] == "spread"), None)
    many = [r for r in rows if r["layout"] == "clustered" and r["occluders"] > 1 and r["loop_per_lookup_cpu_ratio"]]
    lines += ["", "## Goals (issue 15)", ""]
    if single:
        lines.append(f"* fiv / floor with one occluder: {single['ratio_to_floor_cpu']:.1f} by CPU time, "
                     f"{single['ratio_to_floor']:.1f} by the wall clock (goal <= 5 by CPU time: "
                     f"{'met' if single['ratio_to_floor_cpu'] <= 5 else 'missed'}).")
    if many:
        def most(key):
            return max((r[key] for r in many if r[key] is not None), default=None)

        worst = max(many, key=lambda r: r["loop_per_lookup_cpu_ratio"])
        lines.append(f"* Cost per occluder that matters against one occluder's (the occluder loop's time per "
                     f"lookup), by CPU time: at most {worst['loop_per_lookup_cpu_ratio']:.2f} "
                     f"({worst['occluders']} occluders, overlap 1), {f(most('loop_per_lookup_sum_cpu_ratio'), '.2f')} "
                     f"with overlap 0 (by the wall clock at most {f(most('loop_per_lookup_ratio'), '.2f')}; goal <= 2: "
                     f"{'met' if worst['loop_per_lookup_cpu_ratio'] <= 2 else 'missed'}); with max_overlap 32 at most "
                     f"{f(most('loop_per_lookup_pairs32_cpu_ratio'), '.2f')}. The earlier measure, "
                     f"(fiv - unshadowed) per lookup, by CPU time: at most {f(most('per_lookup_cpu_ratio'), '.2f')} "
                     f"(overlap 1), {f(most('per_lookup_sum_cpu_ratio'), '.2f')} (overlap 0).")
    if spread:
        lines.append(f"* Tile culling, {spread['occluders']} bunnies over a {8 * s.get('spread_spacing', 0):g} x "
                     f"{8 * s.get('spread_spacing', 0):g} floor: {spread['tiles_per_tile_mean']:.1f} occluders per "
                     f"tile on average (median {spread['tiles_per_tile_median']:g}, "
                     f"{spread['tiles_per_tile_min']}..{spread['tiles_per_tile_max']}) of {spread['occluders']}; "
                     f"culled {spread['fiv_shade_ms']:.1f} ms against unculled {spread['fiv_unculled_shade_ms']:.1f} ms "
                     f"({spread['tile_cull_speedup']:.2f}x; {spread['tile_cull_speedup_cpu']:.2f}x by CPU time).")
    lines += ["", "The paper's frame rates are for its whole frame (rasterisation and shading) on a 2007 GPU; "
              "penumbra ray-casts its G-buffer on the same device as the shading. The shading columns measure the "
              "method itself; the x floor ratio (fiv shading over the memory-bound floor, same run) does not depend "
              "on the machine's speed."]
    if equal_error:
        e = equal_error
        lines += ["", f"## Against Mitsuba 3 at equal error ({e['occluders']} bunnies, {e['resolution'][0]}x"
                  f"{e['resolution'][1]})", "", f"From `{e['report']}` (penumbra bench on "
                  f"`scenes/bunnies_{e['occluders']}.toml` at {e['resolution'][0]}x{e['resolution'][1]}):", "",
                  "| method | params | frame ms | NRMSE | speed-up over Mitsuba at equal error |", "|---|---|---|---|---|"]
        for r in e["results"]:
            lines.append(f"| {r['method']} | {_fmt_params(r['params'])} | {r['time_ms']:.2f} | {r['nrmse']:.4f} | "
                         f"{r.get('mitsuba_speedup_bound') or ''}{r['mitsuba_speedup']:.3g}x |")
    lines += ["", "Files: results.json, report.md, scenes/bunnies_N.toml, scenes/spread_N.toml, fiv_spread_N.png"
              + (f", mitsuba_{equal_error['occluders']}/ (the equal-error run)" if equal_error else "") + ".", ""]
    return "\n".join(lines)
