"""Occlusion fields for the ``fiv`` method (docs/fiv.md).

A :class:`FivField` holds the Fullsphere Irradiance Vectors of one occluder
mesh under one env map, baked by libpenumbra (``pn_fiv_bake``) on a
(theta, phi, rho) grid around the mesh's bounding sphere. Bakes are written
to versioned, checksummed files that record the mesh and env map they belong
to; :func:`cached_field` bakes on demand into a cache folder and reuses the
file when the same mesh, env map and options come back.
"""

from __future__ import annotations

import ctypes
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from . import _native
from ._native import call
from .core import Context, EnvMap, Mesh, Scene
from .errors import InputError, PenumbraError

PRECISIONS = {"float32": 0, "float16": 1}


@dataclass(frozen=True)
class FivOptions:
    """Bake options (``pn_fiv_options``); samples are (theta, phi, radii)."""

    samples: tuple[int, int, int] = (17, 32, 15)
    inner_radius: float = 0.2
    error_target: float = 0.01
    face_size: int = 32
    sun_supersampling: int = 4
    sun_threshold: float = 0.1
    precision: str = "float16"

    @staticmethod
    def from_paper(theta_phi_rho: Sequence[int], **kw) -> "FivOptions":
        """Options from the paper's (phi, theta, rho) notation, e.g. 32x17x15 -> phi 32, theta 17, 15 radii."""
        phi, theta, rho = (int(v) for v in theta_phi_rho)
        return FivOptions(samples=(theta, phi, rho), **kw)

    def native(self) -> _native.FivOptions:
        if self.precision not in PRECISIONS:
            raise InputError(f"FIV precision must be one of {', '.join(PRECISIONS)}, got {self.precision!r}")
        if len(self.samples) != 3:
            raise InputError(f"FIV samples must be (theta, phi, radii), got {self.samples!r}")
        theta, phi, radii = (int(v) for v in self.samples)
        return _native.FivOptions(theta, phi, radii, self.inner_radius, self.error_target, int(self.face_size),
                                  int(self.sun_supersampling), self.sun_threshold, PRECISIONS[self.precision])

    def key(self) -> str:
        t, p, r = self.samples
        return (f"{p}x{t}x{r}-i{self.inner_radius:g}-e{self.error_target:g}-f{self.face_size}"
                f"-s{self.sun_supersampling}-{self.sun_threshold:g}-{self.precision}")


class FivField:
    """An occlusion field: bake with :meth:`bake`, or :meth:`load` a bake file."""

    def __init__(self, ctx: Context, handle: ctypes.c_void_p):
        self._ctx = ctx
        self._h = handle

    @classmethod
    def bake(cls, env: EnvMap, mesh: Mesh, options: FivOptions | None = None, path: str | os.PathLike | None = None,
             progress: Callable[[int, int], bool | None] | None = None) -> "FivField":
        """Bakes ``mesh`` under ``env``. With ``path`` the bake checkpoints to that
        file, resumes an unfinished bake there, and loads a finished one of the
        same inputs; ``progress(done, total)`` returning True stops it."""
        opts = (options or FivOptions()).native()
        out = ctypes.c_void_p()

        def trampoline(_user, done, total):
            try:
                return 1 if progress(int(done), int(total)) else 0
            except BaseException:  # nothing (not even Ctrl-C) may cross the C boundary: stop the bake instead
                return 1

        cb = _native.PROGRESS(trampoline) if progress else _native.PROGRESS()
        call("pn_fiv_bake", env._ctx._h, env._h, mesh._h, ctypes.byref(opts),
             None if path is None else os.fsencode(path), cb, None, ctypes.byref(out))
        return cls(env._ctx, out)

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
        o = i.options
        return {"samples": (o.theta, o.phi, o.radii), "inner_radius": o.inner_radius, "error_target": o.error_target,
                "face_size": o.face_size, "sun_supersampling": o.sun_supersampling,
                "sun_threshold": o.sun_threshold,
                "precision": {v: k for k, v in PRECISIONS.items()}[o.precision],
                "centre": tuple(i.centre), "radius": i.radius, "inner": i.inner, "outer": i.outer,
                "mesh_hash": f"{i.mesh_hash:016x}", "env_hash": f"{i.env_hash:016x}",
                "sample_count": i.sample_count, "inside_count": i.inside_count, "stored_bytes": i.stored_bytes,
                "rays": i.rays, "bake_seconds": i.bake_seconds}

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


def set_scene_fields(scene: Scene, fields: Sequence[FivField]) -> None:
    """Makes ``fields`` the scene's occlusion fields (pn_scene_set_fivs)."""
    arr = (ctypes.c_void_p * max(len(fields), 1))(*[f._h.value for f in fields])
    call("pn_scene_set_fivs", scene._ctx._h, scene._h, arr if fields else None, len(fields))
    scene._fields = list(fields)  # keep them alive with the scene


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
    folder = Path(directory) if directory is not None else cache_dir()
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise PenumbraError(f"cannot create the FIV cache folder {folder}: {exc}") from exc
    path = folder / f"{mesh_hash(mesh)}-{envmap_hash(env)}-{options.key()}.pnfiv"
    return FivField.bake(env, mesh, options, path, progress)
