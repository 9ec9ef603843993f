"""The ``isg`` method's Python side (docs/isg.md): everything Python knows about
the Integral Spherical Gaussian technique.

* Sphere sets: a :class:`SphereSet` holds the occluder proxy of one mesh,
  built by libpenumbra (``pn_sphere_set_build``, cached per context by mesh
  hash and count) or given by the caller (``pn_sphere_set_create``).
"""

from __future__ import annotations

import ctypes

import numpy as np

from .. import _native
from .._native import call
from ..core import Context, Mesh
from ..errors import InputError

NAME = "isg"


class SphereSet:
    """Spheres (centre xyz, radius; object space) standing in for an occluder."""

    def __init__(self, ctx: Context, handle: ctypes.c_void_p):
        self._ctx = ctx
        self._h = handle

    @classmethod
    def build(cls, mesh: Mesh, count: int) -> "SphereSet":
        """``count`` spheres approximating the solid of ``mesh`` (committed)."""
        if isinstance(count, bool) or not isinstance(count, (int, np.integer)) or count < 1:
            raise InputError(f"sphere count must be a positive integer, got {count!r}")
        out = ctypes.c_void_p()
        call("pn_sphere_set_build", mesh._ctx._h, mesh._h, int(count), ctypes.byref(out))
        return cls(mesh._ctx, out)

    @classmethod
    def from_spheres(cls, ctx: Context, spheres) -> "SphereSet":
        """The caller's spheres: an (n, 4) array of centre xyz and radius."""
        a = np.ascontiguousarray(np.asarray(spheres, np.float32))
        if a.ndim != 2 or a.shape[1] != 4:
            raise InputError(f"spheres must be an (n, 4) array of centre xyz and radius, got shape {a.shape}")
        out = ctypes.c_void_p()
        call("pn_sphere_set_create", ctx._h, ctx._h, a.ctypes.data if len(a) else None, len(a), ctypes.byref(out))
        return cls(ctx, out)

    def info(self) -> dict:
        i = _native.SphereSetInfo()
        call("pn_sphere_set_get_info", self._ctx._h, self._h, ctypes.byref(i))
        return {"count": i.count, "grid": i.grid, "mesh_hash": f"{i.mesh_hash:016x}" if i.mesh_hash else None,
                "mesh_volume": i.mesh_volume, "outside_share": i.outside_share, "missed_share": i.missed_share,
                "build_seconds": i.build_seconds}

    def spheres(self) -> np.ndarray:
        """(count, 4) float32: centre xyz, radius."""
        out = np.empty((self.info()["count"], 4), np.float32)
        call("pn_sphere_set_read", self._ctx._h, self._h, out.ctypes.data, out.nbytes)
        return out

    def close(self) -> None:
        if self._h:
            _native.lib.pn_sphere_set_release(self._h)
            self._h = ctypes.c_void_p()

    def __del__(self):
        try:
            self.close()
        except Exception:
            pass
