"""Mitsuba 3 export and a like-for-like Mitsuba renderer (docs/mitsuba.md).

* :func:`scene_dict` turns a :class:`~penumbra.scenefile.SceneDescription`
  into a ``mi.load_dict`` dictionary: the same camera, environment, meshes,
  materials and spherical lights, rendered by Mitsuba's ``direct`` integrator
  (direct illumination only, like penumbra's reference).
* :func:`export` writes the same scene as a standalone XML file with the PLY
  meshes and the EXR environment map it references.
* Height fields (``[[heightfield]]``) go to Mitsuba as their triangle meshes
  (the library's mesh of the field, read back: one vertex per sample,
  world coordinates, the vertex normals penumbra uses) with a two-sided
  diffuse BSDF: a constant ``albedo`` as its reflectance, an ``albedo_map`` as
  per-vertex colour (the ``vertex_color`` mesh attribute, linear RGB,
  interpolated across each triangle and read by a ``mesh_attribute``
  texture; in the exported PLY as float ``r g b`` vertex properties).
  penumbra's own G-buffer gives an albedo-mapped field's pixels a white
  albedo (only the ``heightfield`` method applies the map, per vertex), so
  ``reference`` and the other methods do not see the map that Mitsuba renders.
* :class:`PixelCentreRenderer`, :func:`render` and :func:`render_timed` trace
  one ray through the centre of each pixel per sample, like penumbra's
  G-buffer, instead of ``mi.render``'s jittered, filtered film samples.

Materials with a specular lobe use the ``penumbra`` BSDF plugin defined here
(:func:`register_plugin`), which evaluates docs/brdf.md exactly.

Mitsuba's global variant is switched by every function that needs Mitsuba
objects; the default is ``llvm_ad_rgb``, or ``scalar_rgb`` where Dr.Jit has no
LLVM backend. :func:`export` itself does not need Mitsuba.
"""

from __future__ import annotations

import math
import os
import re
import time
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from .errors import InputError
from .fileutil import atomic_write, atomic_write_text
from .imageio import write_exr
from .brdf import LOBES
from .render import environment_latlong, object_geometry
from .scenefile import CameraDesc, ObjectDesc, SceneDescription

__all__ = ["DEFAULT_VARIANT", "FALLBACK_VARIANT", "PLUGIN_NAME", "select_variant", "register_plugin",
           "envmap_for_mitsuba", "scene_dict", "export", "load_file", "PixelCentreRenderer", "render",
           "render_timed"]

DEFAULT_VARIANT = "llvm_ad_rgb"
FALLBACK_VARIANT = "scalar_rgb"
PLUGIN_NAME = "penumbra"
MIN_ROUGHNESS = 1e-3      # as penumbra.brdf and kernels/common/brdf.cl
MIN_COS_VIEW = 1e-4
# The first line of every exported scene.xml: marks the files it lists as ours to replace.
EXPORT_MARKER = "written by penumbra.mitsuba.export"
# Upper bound on the texels of the resampled environment map (see envmap_for_mitsuba).
ENVMAP_MAX_TEXELS = 1 << 22


# --------------------------------------------------------------------------- #
# Variants and the BSDF plugin
# --------------------------------------------------------------------------- #


def _mitsuba():
    try:
        import mitsuba
    except ImportError as exc:  # pragma: no cover - exercised only without the bench extras
        raise ImportError("penumbra.mitsuba needs Mitsuba 3: pip install 'mitsuba>=3.5' "
                          "(or the package's [bench] extra)") from exc
    return mitsuba


def select_variant(variant: str | None = None) -> str:
    """Makes ``variant`` Mitsuba's current variant and returns its name.

    ``None`` picks :data:`DEFAULT_VARIANT`, or :data:`FALLBACK_VARIANT` when
    Dr.Jit has no LLVM backend (set ``DRJIT_LIBLLVM_PATH`` to a libLLVM to
    enable it). Only RGB variants are accepted: penumbra's radiance is RGB,
    which spectral variants would upsample and mono variants would discard.
    """
    mi = _mitsuba()
    import drjit as dr

    available = list(mi.variants())
    rgb = [v for v in available if v.endswith("_rgb")]

    def usable(v: str) -> bool:
        if v.startswith("llvm_"):
            return bool(dr.has_backend(dr.JitBackend.LLVM))
        if v.startswith("cuda_"):
            return bool(dr.has_backend(dr.JitBackend.CUDA))
        return True

    if variant is None:
        choice = next((v for v in (DEFAULT_VARIANT, FALLBACK_VARIANT) if v in available and usable(v)), None)
        if choice is None:
            raise InputError(f"neither Mitsuba variant {DEFAULT_VARIANT} nor {FALLBACK_VARIANT} is available "
                             f"(available: {', '.join(available)})")
    else:
        if not isinstance(variant, str) or variant not in available:
            raise InputError(f"unknown Mitsuba variant {variant!r} (available RGB variants: {', '.join(rgb)})")
        if variant not in rgb:
            raise InputError(f"Mitsuba variant {variant!r} is not an RGB variant; penumbra's radiance is linear "
                             f"RGB (use one of {', '.join(rgb)})")
        if not usable(variant):
            hint = " (set DRJIT_LIBLLVM_PATH to a libLLVM)" if variant.startswith("llvm_") else ""
            raise InputError(f"Mitsuba variant {variant!r} needs a Dr.Jit backend that is not available here{hint}")
        choice = variant
    mi.set_variant(choice)
    return choice


_PLUGIN_CLASSES: dict[str, type] = {}


def register_plugin(variant: str | None = None) -> type:
    """Registers the ``penumbra`` BSDF with the given (or current) variant; returns its class.

    The class derives from that variant's ``mi.BSDF``, so each variant gets
    its own class; registering twice is harmless.
    """
    mi = _mitsuba()
    if variant is not None:
        select_variant(variant)
    name = mi.variant()
    if name is None:
        name = select_variant(None)
    if name not in _PLUGIN_CLASSES:
        cls = _make_bsdf_class(name)
        mi.register_bsdf(PLUGIN_NAME, lambda props: cls(props))
        _PLUGIN_CLASSES[name] = cls
    return _PLUGIN_CLASSES[name]


def _make_bsdf_class(variant: str) -> type:
    """The plugin class for one variant: the BRDF of docs/brdf.md, two-sided, cosine-sampled."""
    import types

    import drjit as dr

    mi = _mitsuba()
    if mi.variant() != variant:
        mi.set_variant(variant)
    # This variant's types, bound now: methods must not pick up a variant selected later.
    mv = types.SimpleNamespace(**{name: getattr(mi, name) for name in (
        "BSDF", "BSDFFlags", "BSDFSample3f", "Color3f", "UInt32", "Vector3f", "warp")})
    flags_all = (mv.BSDFFlags.DiffuseReflection | mv.BSDFFlags.GlossyReflection
                 | mv.BSDFFlags.FrontSide | mv.BSDFFlags.BackSide)

    class PenumbraBSDF(mv.BSDF):
        """f(V, L) = albedo / pi + k_s f_lobe(V, L) for N.L > 0 (docs/brdf.md).

        Properties: ``albedo`` (rgb), ``specular`` (float), ``lobe`` (string:
        phong, blinn_phong, ggx, ashikhmin_shirley), ``shininess`` (float),
        ``roughness`` (float), and for ashikhmin_shirley ``shininess_v`` (n_v;
        ``shininess`` is n_u) and ``tangent`` (vector: the u axis in world
        space, projected onto the shading frame's tangent plane at each hit).
        """

        def __init__(self, props):
            mv.BSDF.__init__(self, props)
            albedo = props["albedo"] if "albedo" in props else (0.8, 0.8, 0.8)
            self.albedo_rgb = tuple(float(albedo[i]) for i in range(3))
            self.specular = float(props["specular"]) if "specular" in props else 0.0
            self.lobe = str(props["lobe"]) if "lobe" in props else "phong"
            self.shininess = float(props["shininess"]) if "shininess" in props else 100.0
            self.roughness = float(props["roughness"]) if "roughness" in props else 0.3
            self.shininess_v = float(props["shininess_v"]) if "shininess_v" in props else 100.0
            tangent = props["tangent"] if "tangent" in props else (1.0, 0.0, 0.0)
            self.tangent = tuple(float(tangent[i]) for i in range(3))
            if self.lobe not in LOBES:
                raise ValueError(f"penumbra BSDF: unknown lobe {self.lobe!r} ({', '.join(LOBES)})")
            if not (all(0.0 <= a <= 1.0 for a in self.albedo_rgb) and 0.0 <= self.specular <= 1.0
                    and self.shininess >= 0.0 and 0.0 < self.roughness <= 1.0 and self.shininess_v >= 0.0
                    and all(math.isfinite(t) for t in self.tangent) and any(self.tangent)):
                raise ValueError(f"penumbra BSDF: parameters out of range: {self.to_string()}")
            self.m_components = [flags_all]
            self.m_flags = flags_all

        # f(V, L) (N.L) for local directions (N = +z). A viewer below the
        # surface mirrors both directions: the surface has no back face.
        def _f_cos(self, si, wo):
            wi = si.wi
            flip = wi.z < 0.0
            vz = dr.select(flip, -wi.z, wi.z)
            lz = dr.select(flip, -wo.z, wo.z)
            value = mv.Color3f(self.albedo_rgb) * (dr.inv_pi * lz)
            if self.specular > 0.0:  # specular = 0 skips the lobe entirely (docs/brdf.md)
                value += self.specular * self._lobe_cos(si, wi.x, wi.y, vz, wo.x, wo.y, lz)
            return dr.select(lz > 0.0, value, 0.0)

        def _local_tangent(self, si):
            """(u_x, u_y): the world tangent axis projected onto the shading
            frame's tangent plane, unit; along the normal, the frame's s axis."""
            a = si.sh_frame.to_local(mv.Vector3f(self.tangent))
            length = dr.sqrt(a.x * a.x + a.y * a.y)
            ok = length > 0.0
            inv = 1.0 / dr.select(ok, length, 1.0)
            return dr.select(ok, a.x * inv, 1.0), dr.select(ok, a.y * inv, 0.0)

        def _ashikhmin_shirley_cos(self, si, hx, hy, hz, hn, lx, ly, vz, lz):
            """docs/brdf.md: sqrt((n_u+1)(n_v+1))/(8 pi) (N.H)^e / ((H.L) max(N.L, N.V)), times N.L."""
            n_u, n_v = self.shininess, self.shininess_v
            ux, uy = self._local_tangent(si)
            inv = 1.0 / dr.select(hn > 0.0, hn, 1.0)
            hu = dr.select(hn > 0.0, (hx * ux + hy * uy) * inv, 0.0)  # H = N when V + L = 0
            hw = dr.select(hn > 0.0, (hy * ux - hx * uy) * inv, 0.0)  # w = N x u = (-u_y, u_x, 0)
            nh = dr.maximum(dr.select(hn > 0.0, hz * inv, 1.0), 0.0)
            hl = dr.maximum(dr.select(hn > 0.0, (hx * lx + hy * ly + hz * lz) * inv, lz), MIN_COS_VIEW)
            den = hu * hu + hw * hw
            e = dr.select(den > 0.0, (n_u * hu * hu + n_v * hw * hw) / dr.select(den > 0.0, den, 1.0), n_u)
            power = dr.select(e == 0.0, 1.0, dr.power(nh, e))
            norm = math.sqrt((n_u + 1.0) * (n_v + 1.0)) / (8.0 * math.pi)
            return norm * power / (hl * dr.maximum(lz, dr.maximum(vz, MIN_COS_VIEW))) * lz

        def _lobe_cos(self, si, vx, vy, vz, lx, ly, lz):
            """f_lobe(V, L) (N.L), with V, L already on the viewer's side."""
            n = self.shininess
            if self.lobe == "phong":
                if n == 0.0:  # 0^0 = 1: a constant lobe
                    return dr.inv_pi * lz
                rl = vz * lz - vx * lx - vy * ly  # R = 2 (N.V) N - V = (-vx, -vy, vz)
                return (n + 2.0) / (2.0 * math.pi) * dr.power(dr.maximum(rl, 0.0), n) * lz
            hx, hy, hz = vx + lx, vy + ly, vz + lz
            hn = dr.sqrt(hx * hx + hy * hy + hz * hz)
            if self.lobe == "ashikhmin_shirley":
                return self._ashikhmin_shirley_cos(si, hx, hy, hz, hn, lx, ly, vz, lz)
            nh = dr.maximum(dr.select(hn > 0.0, hz / dr.select(hn > 0.0, hn, 1.0), 1.0), 0.0)
            if self.lobe == "blinn_phong":
                if n == 0.0:
                    return dr.inv_pi * lz
                return (n + 8.0) / (8.0 * math.pi) * dr.power(nh, n) * lz
            a2 = min(max(self.roughness, MIN_ROUGHNESS), 1.0) ** 2
            d = a2 / (math.pi * dr.square(nh * nh * (a2 - 1.0) + 1.0))
            cv = dr.maximum(vz, MIN_COS_VIEW)
            cl = dr.maximum(lz, 1e-30)

            def g1(c):
                return 2.0 * c / (c + dr.sqrt(a2 + (1.0 - a2) * c * c))

            return d * g1(cv) * g1(cl) / (4.0 * cv)  # D G / (4 (N.L)(N.V)) times N.L

        def _pdf(self, wi, wo):
            # Cosine-weighted hemisphere on the viewer's side.
            cos_o = dr.select(wi.z < 0.0, -wo.z, wo.z)
            return dr.maximum(cos_o, 0.0) * dr.inv_pi

        @staticmethod
        def _enabled(ctx) -> bool:
            return bool(ctx.is_enabled(mv.BSDFFlags.DiffuseReflection)
                        or ctx.is_enabled(mv.BSDFFlags.GlossyReflection))

        def sample(self, ctx, si, sample1, sample2, active=True):
            wi = si.wi
            local = mv.warp.square_to_cosine_hemisphere(sample2)
            wo = mv.Vector3f(local.x, local.y, dr.select(wi.z < 0.0, -local.z, local.z))
            pdf = self._pdf(wi, wo)
            bs = mv.BSDFSample3f()
            bs.wo = wo
            bs.pdf = pdf
            bs.eta = 1.0
            bs.sampled_type = mv.UInt32(+(mv.BSDFFlags.GlossyReflection if self.specular > 0.0
                                          else mv.BSDFFlags.DiffuseReflection))
            bs.sampled_component = mv.UInt32(0)
            ok = active & (pdf > 0.0) & self._enabled(ctx)
            weight = self._f_cos(si, wo) / dr.select(pdf > 0.0, pdf, 1.0)
            return bs, dr.select(ok, weight, 0.0)

        def eval(self, ctx, si, wo, active=True):
            return dr.select(active & self._enabled(ctx), self._f_cos(si, wo), 0.0)

        def pdf(self, ctx, si, wo, active=True):
            return dr.select(active & self._enabled(ctx), self._pdf(si.wi, wo), 0.0)

        def eval_pdf(self, ctx, si, wo, active=True):
            return self.eval(ctx, si, wo, active), self.pdf(ctx, si, wo, active)

        def to_string(self):
            return (f"PenumbraBSDF[albedo={list(self.albedo_rgb)}, specular={self.specular}, lobe={self.lobe}, "
                    f"shininess={self.shininess}, roughness={self.roughness}, shininess_v={self.shininess_v}, "
                    f"tangent={list(self.tangent)}]")

    return PenumbraBSDF


# --------------------------------------------------------------------------- #
# Scene content shared by scene_dict and export
# --------------------------------------------------------------------------- #


def envmap_for_mitsuba(latlong: np.ndarray, supersample: int | None = None) -> np.ndarray:
    """penumbra's lat-long map resampled so that Mitsuba's ``envmap`` returns the same radiance.

    penumbra reads texel (i, j) as constant over u in [i/W, (i+1)/W), v in
    [j/H, (j+1)/H). Mitsuba 3's envmap has no nearest filter: it interpolates
    bilinearly, with column centres at u = (i + 0.5)/W' but rows at
    v = j/(H' - 1) (row 0 on the +y pole, the last row on -y). The result has
    k W columns (k per texel) and k H + 1 rows, so every penumbra texel edge
    falls between two columns or on a row; rows on an edge hold the mean of
    the two texels. Mitsuba then reproduces the piecewise-constant map except
    in ramps one fine texel wide on each side of a texel edge, centred on it.

    ``supersample`` is k; by default the largest k <= 8 with at most
    :data:`ENVMAP_MAX_TEXELS` texels (at least 1, and enough for Mitsuba's
    2 x 3 minimum).
    """
    env = np.asarray(latlong, np.float32)
    if env.ndim != 3 or env.shape[2] != 3 or env.shape[0] < 1 or env.shape[1] < 1:
        raise InputError(f"environment map must have shape (H, W, 3), got {env.shape}")
    h, w = env.shape[:2]
    k_min = max(1, math.ceil(2 / w), math.ceil(2 / h))
    if supersample is None:
        k = max(k_min, min(8, int(math.isqrt(ENVMAP_MAX_TEXELS // (w * h + 1)))))
    else:
        if isinstance(supersample, bool) or not isinstance(supersample, int) or not 1 <= supersample <= 64:
            raise InputError(f"envmap supersample must be an integer in [1, 64], got {supersample!r}")
        k = max(k_min, supersample)
    cols = np.arange(k * w) // k
    rows = np.minimum(np.arange(k * h + 1) // k, h - 1)
    out = env[rows][:, cols]
    edges = np.arange(1, h)
    out[edges * k] = 0.5 * (env[edges - 1] + env[edges])[:, cols]
    return np.ascontiguousarray(out)


def _camera_frame(cam: CameraDesc) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(position, forward, up) after the checks the native library does."""
    p = np.asarray(cam.position, np.float64)
    f = np.asarray(cam.look_at, np.float64) - p
    up = np.asarray(cam.up, np.float64)
    if not np.linalg.norm(up) > 0:
        raise InputError("[camera] up must not be zero")
    if np.linalg.norm(np.cross(f / np.linalg.norm(f), up / np.linalg.norm(up))) < 1e-6:
        raise InputError("[camera] up is parallel to the view direction")
    return p, f / np.linalg.norm(f), up


@dataclass
class _Light:
    position: tuple[float, float, float]
    radius: float
    radiance: tuple[float, float, float]


def _lights(desc: SceneDescription) -> list[_Light]:
    """The scene's spherical lights (``desc.lights``, when the description has them), checked."""
    out = []
    for i, light in enumerate(getattr(desc, "lights", None) or []):
        where = f"[light {getattr(light, 'name', i)!r}]"
        try:
            pos = tuple(float(x) for x in light.position)
            radius = float(light.radius)
            radiance = light.radiance
            radiance = tuple(float(x) for x in (radiance if np.ndim(radiance) else [radiance] * 3))
        except (AttributeError, TypeError, ValueError) as exc:
            raise InputError(f"{where} needs position (3 numbers), radius and radiance (RGB): {exc}") from None
        if len(pos) != 3 or not all(map(math.isfinite, pos)):
            raise InputError(f"{where} position must be 3 finite numbers, got {light.position!r}")
        if not (math.isfinite(radius) and radius > 0):
            raise InputError(f"{where} radius must be > 0, got {light.radius!r}")
        if len(radiance) != 3 or not all(math.isfinite(c) and c >= 0 for c in radiance):
            raise InputError(f"{where} radiance must be 3 finite numbers >= 0, got {light.radiance!r}")
        out.append(_Light(pos, radius, radiance))
    return out


def _clip_range(desc: SceneDescription, meshes: dict[tuple, tuple]) -> tuple[float, float]:
    """Near and far clip distances that keep every object inside (penumbra has no clip planes)."""
    p, _, _ = _camera_frame(desc.camera)
    far = float(np.linalg.norm(np.asarray(desc.camera.look_at) - p))
    for obj in desc.objects:
        v = meshes[obj.geometry_key()][0].astype(np.float64)
        m = obj.transform()
        lo, hi = v.min(axis=0), v.max(axis=0)
        corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
        world = corners @ m[:3, :3].T + m[:3, 3]
        far = max(far, float(np.linalg.norm(world - p, axis=1).max()))
    for d in _heightfield_descs(desc):  # world-space vertices
        v = meshes[_heightfield_key(d)][0].astype(np.float64)
        lo, hi = v.min(axis=0), v.max(axis=0)
        corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
        far = max(far, float(np.linalg.norm(corners - p, axis=1).max()))
    for light in _lights(desc):
        far = max(far, float(np.linalg.norm(np.asarray(light.position) - p)) + light.radius)
    # Mitsuba starts camera rays on the near plane, penumbra at the eye: a
    # millionth of the scene's depth is as close to the eye as float32 depth
    # resolution makes meaningful.
    return 1e-6 * far, 4.0 * far


def _is_plugin_material(obj: ObjectDesc) -> bool:
    return obj.specular > 0.0


def _world_tangent(obj: ObjectDesc) -> list[float]:
    """The anisotropic lobe's tangent axis in world space: the object's axis
    through the linear part of its transform (a tangent vector), as penumbra's
    G-buffer carries it (docs/brdf.md)."""
    return (obj.transform()[:3, :3] @ np.asarray(obj.tangent, np.float64)).tolist()


def _bsdf_dict(obj: ObjectDesc) -> dict:
    if not _is_plugin_material(obj):
        return {"type": "twosided", "material": {"type": "diffuse",
                                                 "reflectance": {"type": "rgb", "value": list(obj.albedo)}}}
    d = {"type": PLUGIN_NAME, "albedo": {"type": "rgb", "value": list(obj.albedo)}, "specular": obj.specular,
         "lobe": obj.lobe, "shininess": obj.shininess, "roughness": obj.roughness}
    if obj.lobe == "ashikhmin_shirley":
        d.update(shininess_v=obj.shininess_v, tangent=_world_tangent(obj))
    return d


@dataclass
class _Heightfield:
    """A ``[[heightfield]]`` as Mitsuba gets it: its mesh (under ``key`` in the
    meshes dict, world coordinates) and its albedo, constant or per vertex."""

    name: str
    key: tuple
    albedo: tuple[float, float, float]        # the constant albedo (white with a map: unused)
    colors: np.ndarray | None = None          # albedo map: float32 (W * D, 3) linear RGB in vertex order


def _heightfield_descs(desc: SceneDescription) -> list:
    return list(getattr(desc, "heightfields", None) or [])


def _heightfield_key(d) -> tuple:
    # Not a (mesh, primitive, params) key of an object: the two never collide.
    return ("[[heightfield]]", d.name)


def _load_geometry(desc: SceneDescription) -> tuple[dict[tuple, tuple], list[_Heightfield]]:
    """(meshes, height fields): (vertices, faces, normals) per distinct object
    geometry (object space) and per height field (world space, identity
    transform), and each height field's albedo."""
    meshes: dict[tuple, tuple] = {}
    for obj in desc.objects:
        key = obj.geometry_key()
        if key not in meshes:
            meshes[key] = object_geometry(obj)
    fields = []
    descs = _heightfield_descs(desc)
    if descs:
        from .core import Context
        from .methods.heightfield import world_geometry

        ctx = Context()
    for d in descs:
        geometry, field = world_geometry(d, ctx)
        key = _heightfield_key(d)
        meshes[key] = geometry
        a = field.albedo
        if a is not None and np.ndim(a) == 3:  # an albedo map: per-vertex colour
            fields.append(_Heightfield(d.name, key, (1.0, 1.0, 1.0), field.vertex_albedo()))
        else:  # the description's numbers (the loaded field holds them as float32)
            rgb = np.broadcast_to(np.asarray(d.albedo if d.albedo is not None else 0.8, np.float64), (3,))
            fields.append(_Heightfield(d.name, key, tuple(float(x) for x in rgb)))
    return meshes, fields


def _load_meshes(desc: SceneDescription) -> dict[tuple, tuple]:
    return _load_geometry(desc)[0]


def _heightfield_bsdf_dict(hf: _Heightfield) -> dict:
    reflectance = ({"type": "mesh_attribute", "name": "vertex_color"} if hf.colors is not None
                   else {"type": "rgb", "value": list(hf.albedo)})
    return {"type": "twosided", "material": {"type": "diffuse", "reflectance": reflectance}}


# --------------------------------------------------------------------------- #
# scene_dict
# --------------------------------------------------------------------------- #


def scene_dict(desc: SceneDescription, *, variant: str | None = None, hide_emitters: bool = True,
               spp: int = 64, envmap_supersample: int | None = None, emitter_samples: int = 1,
               bsdf_samples: int = 1) -> dict:
    """The Mitsuba 3 scene of ``desc`` as a ``mi.load_dict`` dictionary.

    Selects ``variant`` (see :func:`select_variant`) and registers the
    ``penumbra`` plugin, because the meshes are built as ``mi.Mesh`` objects of
    that variant (world-space vertices and normals, as penumbra transforms
    them). ``spp`` is the sensor sampler's sample count (used by
    ``mi.render``, not by :class:`PixelCentreRenderer`); ``hide_emitters``
    makes background pixels black; ``envmap_supersample`` see
    :func:`envmap_for_mitsuba`; ``emitter_samples`` and ``bsdf_samples`` are
    the ``direct`` integrator's light and BSDF samples per camera ray (MIS).
    """
    _check_spp(spp)
    for name, value in (("emitter_samples", emitter_samples), ("bsdf_samples", bsdf_samples)):
        if isinstance(value, bool) or not isinstance(value, int) or value < 0:
            raise InputError(f"{name} = {value!r} must be an integer >= 0")
    select_variant(variant)
    register_plugin()
    mi = _mitsuba()

    meshes, fields = _load_geometry(desc)
    near, far = _clip_range(desc, meshes)
    c = desc.camera
    p, f, up = _camera_frame(c)
    w, h = c.resolution
    d: dict[str, Any] = {
        "type": "scene",
        "integrator": {"type": "direct", "hide_emitters": bool(hide_emitters),
                       "emitter_samples": emitter_samples, "bsdf_samples": bsdf_samples},
        "sensor": {
            "type": "perspective", "fov_axis": "x", "fov": float(c.fov_deg), "near_clip": near, "far_clip": far,
            "to_world": mi.ScalarTransform4f().look_at(origin=p.tolist(), target=(p + f).tolist(), up=up.tolist()),
            "sampler": {"type": "independent", "sample_count": int(spp)},
            "film": {"type": "hdrfilm", "width": int(w), "height": int(h), "pixel_format": "rgb",
                     "rfilter": {"type": "box"}},
        },
    }
    env = _environment(desc, envmap_supersample)
    if env is not None:
        d["environment"] = {"type": "envmap", "bitmap": mi.Bitmap(env), "scale": float(desc.environment.intensity),
                            "to_world": mi.ScalarTransform4f().rotate(axis=[0.0, 1.0, 0.0],
                                                                      angle=float(desc.environment.rotation_deg))}
    for i, obj in enumerate(desc.objects):
        v, faces, n = meshes[obj.geometry_key()]
        d[f"object{i}"] = _world_mesh(mi, f"object{i}:{obj.name}", obj.transform(), _bsdf_dict(obj), v, faces, n)
    for i, hf in enumerate(fields):
        v, faces, n = meshes[hf.key]
        d[f"heightfield{i}"] = _world_mesh(mi, f"heightfield{i}:{hf.name}", np.eye(4), _heightfield_bsdf_dict(hf),
                                           v, faces, n, hf.colors)
    for i, light in enumerate(_lights(desc)):
        d[f"light{i}"] = _light_dict(light)
    return d


def _environment(desc: SceneDescription, supersample: int | None) -> np.ndarray | None:
    """The resampled environment map, or None for a black one (Mitsuba cannot sample an all-zero map)."""
    latlong = environment_latlong(desc.environment)
    if desc.environment.intensity == 0.0 or not np.any(latlong > 0):
        return None
    return envmap_for_mitsuba(latlong, supersample)


def _world_mesh(mi, name: str, transform: np.ndarray, bsdf: dict, vertices, faces, normals, colors=None):
    """A ``mi.Mesh`` in world space: ``vertices`` placed by the 4x4 ``transform``,
    the ``bsdf`` dict, and ``colors`` ((N, 3) linear RGB) as its ``vertex_color`` attribute."""
    m = np.asarray(transform, np.float64)
    lin = m[:3, :3]
    v = vertices.astype(np.float64) @ lin.T + m[:3, 3]
    f = np.asarray(faces, np.uint32)
    if np.linalg.det(lin) < 0:
        # A mirroring transform turns the winding; keep the geometric normal
        # on the side of the transformed normal, as penumbra does.
        f = f[:, ::-1]
    props = mi.Properties()
    props["bsdf"] = mi.load_dict(bsdf)
    mesh = mi.Mesh(name, vertex_count=int(v.shape[0]), face_count=int(f.shape[0]), props=props,
                   has_vertex_normals=normals is not None, has_vertex_texcoords=False)
    params = mi.traverse(mesh)

    def put(key: str, array: np.ndarray) -> None:
        # The buffer's own type: a JIT array, or a dynamic scalar array in scalar variants.
        params[key] = type(params[key])(np.ascontiguousarray(array).ravel())

    put("vertex_positions", v.astype(np.float32))
    put("faces", f)
    if normals is not None:
        nw = normals.astype(np.float64) @ np.linalg.inv(lin)  # inverse transpose, on row vectors
        length = np.linalg.norm(nw, axis=1, keepdims=True)
        put("vertex_normals", np.where(length > 0, nw / np.where(length > 0, length, 1.0), 0.0).astype(np.float32))
    params.update()
    if colors is not None:
        c = np.ascontiguousarray(colors, np.float32)
        if c.shape != (v.shape[0], 3):
            raise InputError(f"{name}: vertex colours must have shape {(v.shape[0], 3)}, got {c.shape}")
        mesh.add_attribute("vertex_color", 3, type(params["vertex_positions"])(c.ravel()))
    return mesh


def _light_dict(light: _Light) -> dict:
    return {"type": "sphere", "center": list(light.position), "radius": light.radius,
            "emitter": {"type": "area", "radiance": {"type": "rgb", "value": list(light.radiance)}},
            # Black, so the light's surface only emits (and occludes), reflecting nothing.
            "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.0, 0.0, 0.0]}}}


# --------------------------------------------------------------------------- #
# export
# --------------------------------------------------------------------------- #


def _fmt(x: float) -> str:
    return repr(float(x))


def _vec(values) -> str:
    return ", ".join(_fmt(x) for x in values)


def _safe_name(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", name)[:48] or "mesh"


def _write_ply(path: Path, vertices: np.ndarray, faces: np.ndarray, normals: np.ndarray | None,
               colors: np.ndarray | None = None) -> None:
    """Binary little-endian PLY: float x y z (nx ny nz) (r g b), uchar/int vertex_indices.
    Mitsuba reads float r g b as the ``vertex_color`` attribute, unscaled (linear)."""
    props = (["x", "y", "z"] + (["nx", "ny", "nz"] if normals is not None else [])
             + (["r", "g", "b"] if colors is not None else []))
    header = ["ply", "format binary_little_endian 1.0", f"comment {EXPORT_MARKER}",
              f"element vertex {len(vertices)}", *[f"property float {p}" for p in props],
              f"element face {len(faces)}", "property list uchar int vertex_indices", "end_header"]
    vdata = np.ascontiguousarray(vertices, "<f4")
    if normals is not None:
        vdata = np.ascontiguousarray(np.concatenate([vdata, np.asarray(normals, "<f4")], axis=1))
    if colors is not None:
        vdata = np.ascontiguousarray(np.concatenate([vdata, np.asarray(colors, "<f4")], axis=1))
    fdata = np.empty(len(faces), dtype=[("n", "u1"), ("i", "<i4", (3,))])
    fdata["n"] = 3
    fdata["i"] = faces

    def write(tmp: str) -> None:
        with open(tmp, "wb") as fh:
            fh.write(("\n".join(header) + "\n").encode("ascii"))
            fh.write(vdata.tobytes())
            fh.write(fdata.tobytes())

    atomic_write(path, write)


def _previous_export_files(out_dir: Path) -> set[Path]:
    """Files that an earlier export into ``out_dir`` wrote (and may be replaced): its scene.xml and what it lists."""
    scene = out_dir / "scene.xml"
    try:
        text = scene.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError):
        return set()
    if not text.startswith(f"<!-- {EXPORT_MARKER}"):
        return set()
    try:
        root = ET.fromstring(text)
    except ET.ParseError:
        return set()
    owned = {scene.resolve()}
    for el in root.iter("string"):
        if el.get("name") == "filename" and el.get("value"):
            owned.add((out_dir / el.get("value")).resolve())
    return owned


def export(desc: SceneDescription, out_dir: str | os.PathLike, *, spp: int = 256, hide_emitters: bool = True,
           envmap_supersample: int | None = None, overwrite: bool = False) -> list[Path]:
    """Writes ``desc`` as a standalone Mitsuba 3 scene into ``out_dir``; returns the files written.

    ``out_dir/scene.xml`` references ``envmap.exr`` (the environment resampled
    by :func:`envmap_for_mitsuba`; absent for a black environment) and one
    binary PLY per distinct geometry in ``meshes/`` (object space, placed by
    each shape's ``to_world``). ``spp`` is the default of the XML's ``$spp``
    parameter (``mitsuba -D spp=1024 scene.xml``).

    Every file is written atomically (a temporary file, then a rename), data
    files first and scene.xml last. Existing files are replaced only when an
    earlier export into ``out_dir`` wrote them (its scene.xml lists them) or
    with ``overwrite=True``; otherwise :class:`InputError` names them.
    Materials with a specular lobe use the ``penumbra`` plugin, which the
    ``mitsuba`` executable does not have: load such scenes with
    :func:`load_file` (docs/mitsuba.md).
    """
    _check_spp(spp)
    out = Path(out_dir).expanduser()
    if out.exists() and not out.is_dir():
        raise InputError(f"{out} exists and is not a directory")
    meshes, fields = _load_geometry(desc)
    near, far = _clip_range(desc, meshes)
    p, f, up = _camera_frame(desc.camera)
    env = _environment(desc, envmap_supersample)

    # Plan the files first, so that a conflict is reported before anything is written.
    # One PLY per geometry, and one with reversed winding for mirroring
    # transforms (as in scene_dict: the geometric normal stays on the side of
    # the transformed normals, which only the winding decides in Mitsuba).
    mesh_files: dict[tuple, str] = {}
    for obj in desc.objects:
        key = _file_key(obj)
        if key not in mesh_files:
            suffix = "_mirrored" if key[1] else ""
            mesh_files[key] = f"meshes/mesh{len(mesh_files):03d}_{_safe_name(obj.name)}{suffix}.ply"
    # Height fields: one PLY each, in world coordinates (no to_world).
    field_files = [f"meshes/heightfield{i:03d}_{_safe_name(hf.name)}.ply" for i, hf in enumerate(fields)]
    targets = [out / "scene.xml"] + ([out / "envmap.exr"] if env is not None else [])
    targets += [out / rel for rel in mesh_files.values()] + [out / rel for rel in field_files]
    if not overwrite:
        owned = _previous_export_files(out)
        conflicts = [t for t in targets if (t.exists() or t.is_symlink()) and t.resolve() not in owned]
        if conflicts:
            raise InputError(f"{out}: would replace file(s) that no earlier penumbra export wrote: "
                             f"{', '.join(str(c) for c in conflicts)} (remove them, choose another directory "
                             "or pass overwrite=True / --force)")

    written: list[Path] = []
    if env is not None:
        write_exr(out / "envmap.exr", env)
        written.append(out / "envmap.exr")
    for (key, mirrored), rel in mesh_files.items():
        v, faces, n = meshes[key]
        _write_ply(out / rel, v, faces[:, ::-1] if mirrored else faces, n)
        written.append(out / rel)
    for hf, rel in zip(fields, field_files):
        v, faces, n = meshes[hf.key]
        _write_ply(out / rel, v, faces, n, hf.colors)
        written.append(out / rel)

    c = desc.camera
    w, h = c.resolution
    lines = [f"<!-- {EXPORT_MARKER} from {desc.source}; docs/mitsuba.md -->",
             '<scene version="3.0.0">',
             f'    <default name="spp" value="{int(spp)}"/>',
             '    <integrator type="direct">',
             f'        <boolean name="hide_emitters" value="{str(bool(hide_emitters)).lower()}"/>',
             '    </integrator>',
             '    <sensor type="perspective">',
             '        <string name="fov_axis" value="x"/>',
             f'        <float name="fov" value="{_fmt(c.fov_deg)}"/>',
             f'        <float name="near_clip" value="{_fmt(near)}"/>',
             f'        <float name="far_clip" value="{_fmt(far)}"/>',
             '        <transform name="to_world">',
             f'            <lookat origin="{_vec(p)}" target="{_vec(c.look_at)}" up="{_vec(up)}"/>',
             '        </transform>',
             '        <sampler type="independent">',
             '            <integer name="sample_count" value="$spp"/>',
             '        </sampler>',
             '        <film type="hdrfilm">',
             f'            <integer name="width" value="{int(w)}"/>',
             f'            <integer name="height" value="{int(h)}"/>',
             '            <string name="pixel_format" value="rgb"/>',
             '            <rfilter type="box"/>',
             '        </film>',
             '    </sensor>']
    if env is not None:
        e = desc.environment
        lines += ['    <emitter type="envmap">',
                  '        <string name="filename" value="envmap.exr"/>',
                  f'        <float name="scale" value="{_fmt(e.intensity)}"/>',
                  '        <transform name="to_world">',
                  f'            <rotate y="1" angle="{_fmt(e.rotation_deg)}"/>',
                  '        </transform>',
                  '    </emitter>']
    for i, obj in enumerate(desc.objects):
        normals = meshes[obj.geometry_key()][2]
        m = obj.transform()
        lines += [f'    <shape type="ply" id="object{i}">',
                  f'        <!-- {_xml_comment(obj.name)} -->',
                  f'        <string name="filename" value="{mesh_files[_file_key(obj)]}"/>',
                  f'        <boolean name="face_normals" value="{"false" if normals is not None else "true"}"/>',
                  '        <transform name="to_world">',
                  f'            <matrix value="{" ".join(_fmt(x) for x in m.ravel())}"/>',
                  '        </transform>',
                  *_bsdf_xml(obj),
                  '    </shape>']
    for i, (hf, rel) in enumerate(zip(fields, field_files)):
        normals = meshes[hf.key][2]
        lines += [f'    <shape type="ply" id="heightfield{i}">',
                  f'        <!-- heightfield {hf.name.replace("--", "- -")} -->',
                  f'        <string name="filename" value="{rel}"/>',
                  f'        <boolean name="face_normals" value="{"false" if normals is not None else "true"}"/>',
                  *_heightfield_bsdf_xml(hf),
                  '    </shape>']
    for i, light in enumerate(_lights(desc)):
        x, y, z = light.position
        lines += [f'    <shape type="sphere" id="light{i}">',
                  f'        <point name="center" x="{_fmt(x)}" y="{_fmt(y)}" z="{_fmt(z)}"/>',
                  f'        <float name="radius" value="{_fmt(light.radius)}"/>',
                  '        <emitter type="area">',
                  f'            <rgb name="radiance" value="{_vec(light.radiance)}"/>',
                  '        </emitter>',
                  '        <bsdf type="diffuse">',
                  '            <rgb name="reflectance" value="0, 0, 0"/>',
                  '        </bsdf>',
                  '    </shape>']
    lines.append("</scene>")
    atomic_write_text(out / "scene.xml", "\n".join(lines) + "\n")
    written.append(out / "scene.xml")
    return written


def _file_key(obj: ObjectDesc) -> tuple:
    return obj.geometry_key(), bool(np.linalg.det(obj.transform()[:3, :3]) < 0)


def _xml_comment(text: str) -> str:
    return "object " + text.replace("--", "- -")


def _bsdf_xml(obj: ObjectDesc) -> list[str]:
    if not _is_plugin_material(obj):
        return ['        <bsdf type="twosided">',
                '            <bsdf type="diffuse">',
                f'                <rgb name="reflectance" value="{_vec(obj.albedo)}"/>',
                '            </bsdf>',
                '        </bsdf>']
    return [f'        <bsdf type="{PLUGIN_NAME}">',
            f'            <rgb name="albedo" value="{_vec(obj.albedo)}"/>',
            f'            <float name="specular" value="{_fmt(obj.specular)}"/>',
            f'            <string name="lobe" value="{obj.lobe}"/>',
            f'            <float name="shininess" value="{_fmt(obj.shininess)}"/>',
            f'            <float name="roughness" value="{_fmt(obj.roughness)}"/>',
            *([f'            <float name="shininess_v" value="{_fmt(obj.shininess_v)}"/>',
               f'            <vector name="tangent" value="{_vec(_world_tangent(obj))}"/>']
              if obj.lobe == "ashikhmin_shirley" else []),
            '        </bsdf>']


def _heightfield_bsdf_xml(hf: _Heightfield) -> list[str]:
    if hf.colors is not None:  # the PLY's r g b: the vertex_color attribute
        reflectance = ['                <texture type="mesh_attribute" name="reflectance">',
                       '                    <string name="name" value="vertex_color"/>',
                       '                </texture>']
    else:
        reflectance = [f'                <rgb name="reflectance" value="{_vec(hf.albedo)}"/>']
    return ['        <bsdf type="twosided">', '            <bsdf type="diffuse">', *reflectance,
            '            </bsdf>', '        </bsdf>']


def load_file(path: str | os.PathLike, *, variant: str | None = None, **params):
    """``mi.load_file`` with the ``penumbra`` plugin registered (needed by exported specular materials).

    ``params`` are XML parameters, e.g. ``spp=1024``.
    """
    select_variant(variant)
    register_plugin()
    mi = _mitsuba()
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such scene file")
    return mi.load_file(str(path), **params)


# --------------------------------------------------------------------------- #
# Pixel-centre rendering
# --------------------------------------------------------------------------- #


def _check_spp(spp: Any) -> int:
    if isinstance(spp, bool) or not isinstance(spp, (int, np.integer)) or spp < 1:
        raise InputError(f"spp = {spp!r} must be an integer >= 1")
    return int(spp)


def _check_wavefront(max_wavefront: Any) -> None:
    if isinstance(max_wavefront, bool) or not isinstance(max_wavefront, (int, np.integer)) or max_wavefront < 1:
        raise InputError(f"max_wavefront = {max_wavefront!r} must be an integer >= 1")


class PixelCentreRenderer:
    """A loaded Mitsuba scene rendered with one ray through each pixel centre per sample.

    ``mi.render`` jitters each sample inside its pixel and reconstructs with a
    filter; penumbra's G-buffer casts exactly one ray through each pixel
    centre. Tracing the same centre rays (``sensor.sample_ray_differential``
    at film position ((x + 0.5)/W, (y + 0.5)/H)) keeps antialiasing out of the
    comparison: the spp samples of a pixel differ only in their lighting
    samples. Construct from a description (:meth:`__init__`) or from any
    loaded Mitsuba scene with a perspective sensor (:meth:`from_scene`).
    """

    def __init__(self, desc: SceneDescription, *, variant: str | None = None, max_wavefront: int = 1 << 22,
                 **scene_options):
        _check_wavefront(max_wavefront)
        self.variant = select_variant(variant)
        mi = _mitsuba()
        scene = mi.load_dict(scene_dict(desc, variant=self.variant, **scene_options))
        self._setup(scene, max_wavefront)

    @classmethod
    def from_scene(cls, scene, *, max_wavefront: int = 1 << 22) -> "PixelCentreRenderer":
        """Wraps an already loaded scene (e.g. from :func:`load_file`) of the current variant."""
        self = cls.__new__(cls)
        self.variant = _mitsuba().variant()
        self._setup(scene, max_wavefront)
        return self

    def _setup(self, scene, max_wavefront: int) -> None:
        _check_wavefront(max_wavefront)
        self.scene = scene
        self.max_wavefront = int(max_wavefront)
        self.sensor = scene.sensors()[0]
        self.integrator = scene.integrator()
        self.width, self.height = (int(x) for x in self.sensor.film().crop_size())
        self.jit = not self.variant.startswith("scalar")

    def batches(self, spp: int) -> list[tuple[int, int, int, int]]:
        """The wavefronts of a render: (first pixel, pixel count, first sample, samples per pixel)."""
        npix = self.width * self.height
        chunk = min(npix, self.max_wavefront)
        per = max(1, min(spp, self.max_wavefront // chunk))
        return [(p0, min(chunk, npix - p0), s0, min(per, spp - s0))
                for p0 in range(0, npix, chunk) for s0 in range(0, spp, per)]

    def render(self, spp: int, seed: int = 0) -> np.ndarray:
        """The (H, W, 3) float64 mean of ``spp`` samples per pixel centre."""
        spp = _check_spp(spp)
        if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
            raise InputError(f"seed = {seed!r} must be an integer >= 0")
        total = np.zeros((self.width * self.height, 3), np.float64)
        for index, (p0, count, _, per) in enumerate(self.batches(spp)):
            wave_seed = (int(seed) * 0x9E3779B1 + index) & 0xFFFFFFFF
            p = slice(p0, p0 + count)
            total[p] += (self._wavefront_jit if self.jit else self._wavefront_scalar)(p0, count, per, wave_seed)
        return (total / spp).reshape(self.height, self.width, 3)

    def _wavefront_jit(self, p0: int, count: int, per: int, seed: int) -> np.ndarray:
        """Sums of ``per`` samples for pixels p0 ... p0 + count - 1, as one wavefront."""
        import drjit as dr

        mi = _mitsuba()
        n = count * per
        # Opaque scalars: the traced kernels do not depend on them, so one warm-up compiles every wavefront.
        first, k, s = dr.opaque(mi.UInt32, p0), dr.opaque(mi.UInt32, per), dr.opaque(mi.UInt32, seed)
        pixel = first + dr.arange(mi.UInt32, n) // k
        x, y = pixel % self.width, pixel // self.width
        pos = mi.Point2f((mi.Float(x) + 0.5) / self.width, (mi.Float(y) + 0.5) / self.height)
        ray, weight = self.sensor.sample_ray_differential(mi.Float(0.0), mi.Float(0.5), pos, mi.Point2f(0.5))
        sampler = self.sensor.sampler().fork()
        sampler.seed(s, n)
        value, _, _ = self.integrator.sample(self.scene, sampler, ray, None, True)
        sums = dr.block_sum(mi.Color3f(value * weight), per)
        return np.array(sums, np.float64).T

    def _wavefront_scalar(self, p0: int, count: int, per: int, seed: int) -> np.ndarray:
        mi = _mitsuba()
        sampler = self.sensor.sampler().fork()
        sampler.seed(seed)
        out = np.zeros((count, 3), np.float64)
        for i in range(count):
            x, y = (p0 + i) % self.width, (p0 + i) // self.width
            pos = mi.Point2f((x + 0.5) / self.width, (y + 0.5) / self.height)
            ray, weight = self.sensor.sample_ray_differential(0.0, 0.5, pos, mi.Point2f(0.5))
            for _ in range(per):
                value, _, _ = self.integrator.sample(self.scene, sampler, ray, None, True)
                out[i] += np.array(value * weight, np.float64)
                sampler.advance()
        return out

    def render_timed(self, spp: int, seed: int = 0) -> tuple[np.ndarray, float]:
        """(image, seconds): small warm-up wavefronts first (JIT compilation), then the timed render."""
        spp = _check_spp(spp)
        if self.jit:
            # The kernels do not depend on the pixel range or the seed, but the
            # per-pixel reduction does depend on the samples per wavefront.
            for per in sorted({b[3] for b in self.batches(spp)}):
                self._wavefront_jit(0, min(16, self.width * self.height), per, seed)
        else:
            self._wavefront_scalar(0, 1, 1, seed)
        t0 = time.perf_counter()
        image = self.render(spp, seed)
        return image, time.perf_counter() - t0


def render(desc: SceneDescription, spp: int, *, variant: str | None = None, seed: int = 0,
           max_wavefront: int = 1 << 22, **scene_options) -> np.ndarray:
    """Renders ``desc`` with Mitsuba, ``spp`` samples per pixel centre; (H, W, 3) float64 radiance.

    ``variant`` defaults to ``llvm_ad_rgb`` (``scalar_rgb`` without LLVM; a
    per-ray Python loop, slow). At most ``max_wavefront`` rays are traced at
    once. ``scene_options`` go to :func:`scene_dict` (e.g. ``emitter_samples``).
    """
    _check_spp(spp)
    return PixelCentreRenderer(desc, variant=variant, max_wavefront=max_wavefront, **scene_options).render(spp, seed)


def render_timed(desc: SceneDescription, spp: int, *, variant: str | None = None, seed: int = 0,
                 max_wavefront: int = 1 << 22, **scene_options) -> tuple[np.ndarray, float]:
    """Like :func:`render`, also returning the seconds the render took, excluding
    scene loading and JIT compilation (one warm-up wavefront runs first)."""
    _check_spp(spp)
    r = PixelCentreRenderer(desc, variant=variant, max_wavefront=max_wavefront, **scene_options)
    return r.render_timed(spp, seed)

