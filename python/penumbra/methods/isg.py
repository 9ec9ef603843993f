"""The ``isg`` method's Python side (docs/isg.md): everything Python knows about
the Integral Spherical Gaussian technique.

* Sphere sets: a :class:`SphereSet` holds the occluder proxy of one mesh,
  built by libpenumbra (``pn_sphere_set_build``, cached per context by mesh
  hash and count) or given by the caller (``pn_sphere_set_create``).
* The scene file's ``[isg]`` table (``spheres``: N per occluder mesh, the
  method's bake parameter), attaching a set to each occluder instance before
  rendering, the benchmark sweep and the summary line of ``penumbra render``.
"""

from __future__ import annotations

import ctypes
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .. import _native
from .._native import call
from ..core import Context, Mesh, _Handle
from ..errors import InputError
from .base import SceneTable, Technique

NAME = "isg"


class SphereSet(_Handle):
    """Spheres (centre xyz, radius; object space) standing in for an occluder."""

    _release = "pn_sphere_set_release"

    def __init__(self, ctx: Context, handle: ctypes.c_void_p):
        super().__init__(ctx)
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

    @classmethod
    def shell(cls, ctx: Context) -> "SphereSet":
        """A thin shell (pn_sphere_set_create_shell): no spheres; attached to an
        instance, the isg method projects that instance's triangles (at most
        4096) into each lobe's patch grid (docs/isg.md section 8)."""
        out = ctypes.c_void_p()
        call("pn_sphere_set_create_shell", ctx._h, ctx._h, ctypes.byref(out))
        return cls(ctx, out)

    def info(self) -> dict:
        i = _native.SphereSetInfo()
        call("pn_sphere_set_get_info", self._ctx._h, self._h, ctypes.byref(i))
        return {"count": i.count, "grid": i.grid, "mesh_hash": f"{i.mesh_hash:016x}" if i.mesh_hash else None,
                "mesh_volume": i.mesh_volume, "outside_share": i.outside_share, "missed_share": i.missed_share,
                "build_seconds": i.build_seconds, "skin": i.skin}

    def spheres(self) -> np.ndarray:
        """(count, 4) float32: centre xyz, radius."""
        out = np.empty((self.info()["count"], 4), np.float32)
        call("pn_sphere_set_read", self._ctx._h, self._h, out.ctypes.data, out.nbytes)
        return out

    def deform(self, mesh: Mesh) -> None:
        """Follows ``mesh`` (the set's mesh with new vertex positions, committed)
        without a rebuild (pn_sphere_set_deform)."""
        call("pn_sphere_set_deform", self._ctx._h, self._h, mesh._h)


# ---------------------------------------------------------------- the technique


TREE_FANOUT = 8
SHELL_MAX_TRIANGLES = 4096   # a thin shell's bound (capi/src/methods/isg.c)


def _morton_keys(centres: np.ndarray) -> np.ndarray:
    """30-bit Morton codes of points quantised to 1024 cells per side of their bounds."""
    lo, hi = centres.min(axis=0), centres.max(axis=0)
    q = np.clip(((centres - lo) / np.maximum(hi - lo, 1e-30) * 1024.0).astype(np.int64), 0, 1023)
    keys = np.zeros(len(centres), np.int64)
    for bit in range(10):
        for axis in range(3):
            keys |= ((q[:, axis] >> bit) & 1) << (3 * bit + (2 - axis))
    return keys


def _bound(centres: np.ndarray, radii: np.ndarray, pad: float) -> np.ndarray:
    c = centres.mean(axis=0)
    r = float(np.max(np.linalg.norm(centres - c, axis=1) + radii))
    return np.array([*c, r * (1.0 + 1e-4) + pad])


def sphere_tree(spheres, owners) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The isg kernel's sphere tree, as the method builds it every frame
    (capi/src/methods/isg.c, docs/isg.md section 8): (spheres in Morton order
    (N, 4) float32, their owners uint32, the nodes (float4 bounding spheres of
    8 consecutive spheres, then of 8 consecutive nodes, up to a top level of at
    most 8 nodes) float32). The kernel's result does not depend on the order
    of the spheres, so tests may use this order with any kernel path."""
    s = np.asarray(spheres, np.float64).reshape(-1, 4)
    o = np.asarray(owners, np.uint32).reshape(-1)
    if not len(s):
        return np.zeros((0, 4), np.float32), o, np.zeros((1, 4), np.float32)
    order = np.argsort(_morton_keys(s[:, :3]), kind="stable")
    s, o = s[order], o[order]
    pad = 1e-5 * (float(np.linalg.norm(s[:, :3].max(axis=0) - s[:, :3].min(axis=0))) + float(s[:, 3].max()))
    levels, level = [], s
    while True:
        level = np.array([_bound(level[i:i + TREE_FANOUT, :3], level[i:i + TREE_FANOUT, 3], pad)
                          for i in range(0, len(level), TREE_FANOUT)])
        levels.append(level)
        if len(level) <= TREE_FANOUT:
            break
    return s.astype(np.float32), o, np.vstack(levels).astype(np.float32)


GAMMA_LAMBDA0 = 1.0


def gamma_levels(face: int) -> list[tuple[float, int, int]]:
    """The prefiltered env Gamma_L's levels for an env cube of ``face`` texels
    a side, as the library builds them (capi/src/methods/isg.c build_gamma):
    (sharpness, vertices a side of the level's vertex-grid cube, face of its
    source cube). Sharpness lambda_0 2^l up to the first at least face^2;
    clamp(ceil(6 sqrt(lambda)) + 1, 8, 2 face + 1) vertices; the env cube halved
    while it stays even, at least 2 and at least 4 sqrt(lambda) a side."""
    count = 1
    while count < 32 and GAMMA_LAMBDA0 * 2.0 ** (count - 1) < float(face) * face:
        count += 1
    mips = [face]
    while len(mips) < 12 and mips[-1] % 2 == 0 and mips[-1] // 2 >= 2:
        mips.append(mips[-1] // 2)
    out = []
    for level in range(count):
        lam = GAMMA_LAMBDA0 * 2.0 ** level
        n = min(max(int(np.ceil(6.0 * np.sqrt(lam))) + 1, 8), 2 * face + 1)
        m = len(mips) - 1
        while m > 0 and mips[m] < 4.0 * np.sqrt(lam):
            m -= 1
        out.append((lam, n, mips[m]))
    return out


def _sphere_count_param():
    from . import spec

    return spec(NAME).param("spheres")


@dataclass
class IsgTable:
    """``[isg]``: how the method builds sphere sets (docs/scene-format.md):
    ``spheres``, N per occluder mesh; ``thin_shells``, the names of occluder
    objects that occlude by their triangles instead (cloth, leaves, open
    meshes: pn_sphere_set_create_shell, at most 4096 triangles each); ``exact_primitives``, exact proxies
    for the sphere, box and plane primitives (attach_sphere_sets)."""

    spheres: int | None = None
    thin_shells: tuple[str, ...] = ()
    exact_primitives: bool = True

    @property
    def sphere_count(self) -> int:
        return int(self.spheres if self.spheres is not None else _sphere_count_param().default)


def _parse_table(d, base: Path, data: dict) -> IsgTable:
    from ..scenefile import _check_keys

    d = {} if d is None else d
    if not isinstance(d, dict):
        raise InputError("[isg] must be a table")
    _check_keys("isg", d, {"spheres", "thin_shells", "exact_primitives"})
    exact = d.get("exact_primitives", True)
    if not isinstance(exact, bool):
        raise InputError(f"[isg] exact_primitives must be true or false, got {exact!r}")
    shells = d.get("thin_shells", [])
    if not isinstance(shells, list) or not all(isinstance(x, str) for x in shells):
        raise InputError(f"[isg] thin_shells must be a list of object names, got {shells!r}")
    objects = {o.get("name"): o for o in data.get("object", []) if isinstance(o, dict)}
    for name in shells:
        if name not in objects:
            raise InputError(f"[isg] thin_shells names {name!r}, which is not an object of the scene "
                             f"(objects: {', '.join(map(str, objects)) or 'none'})")
        if objects[name].get("occluder", True) is False:
            raise InputError(f"[isg] thin_shells names {name!r}, which has occluder = false")
    count = int(_sphere_count_param().check(d["spheres"], "[isg] spheres")) if "spheres" in d else None
    return IsgTable(count, tuple(shells), exact)


@dataclass
class IsgState:
    """What the method keeps on a built scene (``built.assets["isg"]``)."""

    count: int | None = None                       # N of the attached sets
    sets: dict[str, SphereSet] = field(default_factory=dict)   # by object name
    records: list[dict] = field(default_factory=list)


def state(built) -> IsgState:
    return built.assets.setdefault(NAME, IsgState())


def attach_sphere_sets(built, overrides: dict | None = None) -> list[dict]:
    """Builds (the library caches by mesh hash and N) one sphere set per
    occluder mesh of the scene (objects with ``occluder``) and attaches it to
    each occluder's instance. Returns one record per mesh: objects, spheres,
    outside_share, missed_share, build_s."""
    desc = built.desc
    if desc is None:
        raise InputError("the isg method needs a scene built by build_scene from a description (its occluders)")
    count = desc.isg.sphere_count if desc.isg is not None else int(_sphere_count_param().default)
    if overrides and "spheres" in overrides:
        count = int(_sphere_count_param().check(overrides["spheres"], "isg spheres"))
    s = state(built)
    if s.count == count:
        return s.records
    groups: dict[int, tuple[Mesh, list[str]]] = {}
    shells = set(desc.isg.thin_shells) if desc.isg is not None else set()
    exact = desc.isg.exact_primitives if desc.isg is not None else True
    records = []
    exact_spheres = []
    if exact:
        # Exact proxies of the simple primitives (docs/isg.md section 9, "exact primitives and the env's
        # irradiance"), whatever their `occluder` (the reference's rays see every object, and these proxies cost
        # next to nothing): a sphere is one sphere, a box or a plane its own triangles as a thin shell (a floor
        # then cuts the light from below the horizon off the objects standing on it). A plane of more than
        # SHELL_MAX_TRIANGLES is left as before.
        for obj in desc.objects:
            if obj.name in shells:
                continue
            if obj.primitive in ("box", "plane"):
                if built.object_meshes[obj.name].info["triangles"] <= SHELL_MAX_TRIANGLES:
                    shells.add(obj.name)
            elif obj.primitive == "sphere" and len({abs(x) for x in obj.scale}) == 1:  # an ellipsoid: as before
                exact_spheres.append(obj.name)
    if shells:
        shell = SphereSet.shell(built.ctx)
        names = [obj.name for obj in desc.objects if obj.name in shells]
        for name in names:
            built.scene.attach(built.instance_ids[name], shell)
            s.sets[name] = shell
        records.append({"objects": names, "spheres": 0, "shell": True, "outside_share": float("nan"),
                        "missed_share": float("nan"), "build_s": 0.0})
    for obj in desc.objects:
        if obj.name in exact_spheres:
            radius = float(obj.params.get("radius", 1.0))
            sset = SphereSet.from_spheres(built.ctx, [[0.0, 0.0, 0.0, radius]])
            built.scene.attach(built.instance_ids[obj.name], sset)
            s.sets[obj.name] = sset
            records.append({"objects": [obj.name], "spheres": 1, "exact": True, "outside_share": 0.0,
                            "missed_share": 0.0, "build_s": 0.0})
    for obj in desc.objects:
        if obj.is_occluder and obj.name not in shells and obj.name not in exact_spheres:
            mesh = built.object_meshes[obj.name]
            groups.setdefault(id(mesh), (mesh, []))[1].append(obj.name)
    for mesh, names in groups.values():
        t0 = time.perf_counter()
        sset = SphereSet.build(mesh, count)
        info = sset.info()
        for name in names:
            built.scene.attach(built.instance_ids[name], sset)
            s.sets[name] = sset
        records.append({"objects": names, "spheres": info["count"], "outside_share": info["outside_share"],
                        "missed_share": info["missed_share"], "build_s": time.perf_counter() - t0})
    built.scene.commit()
    s.count, s.records = count, records
    return records


class Isg(Technique):
    bake_table = NAME
    scene_tables = (SceneTable(NAME, NAME, False, _parse_table),)
    # the defaults as the sweep spells them (the README's row picks the result whose params equal these)
    readme_setting = {"spheres": 64, "lobes": 32, "patch_grid": 16}
    readme_label = "defaults"

    def applies_to(self, desc) -> bool:
        # Without occluders (sphere sets or thin shells) it would shade like unshadowed SG lighting.
        return any(obj.is_occluder for obj in desc.objects) or bool(desc.isg is not None and desc.isg.thin_shells)

    def prepare(self, built, bake, bake_progress=None) -> None:
        attach_sphere_sets(built, bake)

    def sweep(self) -> list[dict]:
        # The defaults (the shared hemisphere grid, env_sharpness 10, shared_light 1), the shared lobes' light from
        # their closed forms (shared_light 0) and the defaults before the grid (every lobe its own window,
        # env_sharpness 100) for the A/B, and a cheaper and a finer point (docs/isg.md section 9).
        return [{"spheres": 32, "lobes": 16, "patch_grid": 8}, {"spheres": 64, "lobes": 32, "patch_grid": 16},
                {"spheres": 64, "lobes": 32, "patch_grid": 16, "shared_light": 0},
                {"spheres": 64, "lobes": 32, "patch_grid": 16, "shared_grid": 0, "env_sharpness": 100.0},
                {"spheres": 128, "lobes": 32, "patch_grid": 16, "shared_grid": 24}]

    def summary_lines(self, built) -> list[str]:
        recs = state(built).records
        if not recs:
            return []
        parts = [f"{len(r['objects'])} thin shell(s) ({', '.join(r['objects'])}: their triangles)" if r.get("shell")
                 else f"{', '.join(r['objects'])}: one exact sphere" if r.get("exact")
                 else f"{len(r['objects'])} x {r['spheres']} spheres (outside {100 * r['outside_share']:.1f} %, "
                 f"missed {100 * r['missed_share']:.1f} % of the solid)" for r in recs]
        return ["isg sphere sets: " + "; ".join(parts)]

    def bench_extras(self, built) -> dict:
        recs = state(built).records
        return {"isg_spheres": sum(r["spheres"] * len(r["objects"]) for r in recs)}


TECHNIQUE = Isg(NAME)
