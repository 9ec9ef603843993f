/* Occlusion fields (docs/fiv.md): the pn_fiv asset — its bake options as a
 * parameter table, the object, half-float storage — and where it attaches:
 * to instances of the mesh it was baked for. The bake is in fiv_bake.c, the
 * file format in io/fiv_file.c, the shading in methods/fiv.c. */
#include "assets/assets.h"

#include <float.h>

#include <math.h>
#include <stddef.h>
#include <stdlib.h>
#include <string.h>

/* The bake options, in the order of pn_fiv_options' fields. Open bounds of
 * the formulas are stated as the nearest values that are still useful. */
const pn_param_desc pn_fiv_bake_params[PN_FIV_BAKE_PARAM_COUNT] = {
    {"theta", PN_PARAM_INT, PN_PARAM_BAKE, 17, 3, 1025, "samples",
     "Grid samples from pole to pole, poles included (the paper's 32x17x15 has theta 17)."},
    {"phi", PN_PARAM_INT, PN_PARAM_BAKE, 32, 4, 2048, "samples", "Grid samples around the axis, periodic."},
    {"radii", PN_PARAM_INT, PN_PARAM_BAKE, 15, 2, 256, "spheres", "Concentric sample spheres."},
    {"inner_radius", PN_PARAM_FLOAT, PN_PARAM_BAKE, 0.2, 1e-4, 0.9999, "bounding radii",
     "Radius of the innermost sphere."},
    {"error_target", PN_PARAM_FLOAT, PN_PARAM_BAKE, 0.01, 1e-6, 0.5, "",
     "The outermost sphere sits at R / sqrt(error_target) (0.01: 10 R)."},
    {"face_size", PN_PARAM_INT, PN_PARAM_BAKE, 32, 1, 256, "texels",
     "Env directions of the bake: a cube of face_size^2 x 6 texels."},
    {"sun_supersampling", PN_PARAM_INT, PN_PARAM_BAKE, 4, 1, 16, "",
     "Bright texels are split into s x s sub-texels (face_size x s at most 2048)."},
    {"sun_threshold", PN_PARAM_FLOAT, PN_PARAM_BAKE, 0.1, 1e-6, 1, "",
     "A texel is bright when its power reaches this share of the brightest texel's."},
    {"precision", PN_PARAM_INT, PN_PARAM_BAKE, 1, 0, 1, "",
     "Storage of the samples: 0 float32, 1 float16 scaled by the env's power."},
};

/* Where each option lives in pn_fiv_options (all 4-byte: uint32_t or float). */
static const size_t option_offsets[] = {
    offsetof(pn_fiv_options, theta), offsetof(pn_fiv_options, phi), offsetof(pn_fiv_options, radii),
    offsetof(pn_fiv_options, inner_radius), offsetof(pn_fiv_options, error_target),
    offsetof(pn_fiv_options, face_size), offsetof(pn_fiv_options, sun_supersampling),
    offsetof(pn_fiv_options, sun_threshold), offsetof(pn_fiv_options, precision),
};

_Static_assert(sizeof option_offsets / sizeof option_offsets[0] == PN_FIV_BAKE_PARAM_COUNT,
               "one offset per bake option");

static double option_get(const pn_fiv_options *o, int i)
{
    const char *p = (const char *)o + option_offsets[i];
    if (pn_fiv_bake_params[i].type == PN_PARAM_INT) {
        uint32_t u;
        memcpy(&u, p, sizeof u);
        return (double)u;
    }
    float f;
    memcpy(&f, p, sizeof f);
    return (double)f;
}

pn_fiv_options pn_fiv_default_options(void)
{
    pn_fiv_options o;
    memset(&o, 0, sizeof o);
    for (int i = 0; i < PN_FIV_BAKE_PARAM_COUNT; ++i) {
        char *p = (char *)&o + option_offsets[i];
        if (pn_fiv_bake_params[i].type == PN_PARAM_INT) {
            const uint32_t u = (uint32_t)pn_fiv_bake_params[i].fallback;
            memcpy(p, &u, sizeof u);
        } else {
            const float f = (float)pn_fiv_bake_params[i].fallback;
            memcpy(p, &f, sizeof f);
        }
    }
    return o;
}

pn_status pn_fiv_check_options(pn_context ctx, const pn_fiv_options *o)
{
    pn_status st;
    for (int i = 0; i < PN_FIV_BAKE_PARAM_COUNT; ++i)
        if ((st = pn_param_check(ctx, "FIV option", &pn_fiv_bake_params[i], option_get(o, i))))
            return st;
    if ((uint64_t)o->theta * o->phi * o->radii > (1ull << 28))
        return pn_fail(ctx, PN_ERROR_INVALID_SIZE, "FIV grid %ux%ux%u has more than 2^28 samples", o->theta, o->phi,
                       o->radii);
    if (o->face_size * o->sun_supersampling > 2048)
        return pn_fail(ctx, PN_ERROR_INVALID_ARGUMENT,
                       "FIV options face_size %u x sun_supersampling %u exceed 2048 sub-texels per face side",
                       o->face_size, o->sun_supersampling);
    return PN_SUCCESS;
}

/* A field attaches to instances of the mesh it was baked for. */
static pn_status check_attach(const pn_object *asset, pn_scene scene, uint32_t instance)
{
    const struct pn_fiv_impl *f = (const struct pn_fiv_impl *)asset;
    pn_context ctx = scene->obj.ctx;
    if (instance == PN_WHOLE_SCENE)
        return pn_fail(ctx, PN_ERROR_INVALID_ARGUMENT,
                       "pn_scene_attach: an occlusion field attaches to an instance of its mesh, not to the whole "
                       "scene");
    if (f->radii_done != f->options.radii)
        return pn_fail(ctx, PN_ERROR_INVALID_ARGUMENT, "pn_scene_attach: the occlusion field is not finished baking");
    const pn_mesh mesh = pn_scene_instance(scene, instance)->mesh;
    if (!mesh->committed)
        return pn_fail(ctx, PN_ERROR_NOT_COMMITTED, "pn_scene_attach: instance %u's mesh is not committed", instance);
    if (mesh->content_hash != f->mesh_hash)
        return pn_fail(ctx, PN_ERROR_INVALID_ARGUMENT,
                       "pn_scene_attach: the occlusion field was baked for mesh %016llx but instance %u's mesh is "
                       "%016llx: bake a field for that mesh",
                       (unsigned long long)f->mesh_hash, instance, (unsigned long long)mesh->content_hash);
    return PN_SUCCESS;
}

static void destroy_fiv(pn_object *o);
static const pn_object_type fiv_type = {PN_MAGIC_FIV, "occlusion field", destroy_fiv, check_attach};

pn_status pn_fiv_new(pn_context ctx, const pn_fiv_options *options, pn_fiv *out)
{
    size_t n = pn_mul_size((size_t)options->theta * options->phi, options->radii, 9 * sizeof(float));
    pn_status st = pn_check_bytes(ctx, n, "the samples of an occlusion field");
    if (st)
        return st;
    float *samples = malloc(n);
    if (!samples)
        return pn_fail(ctx, PN_ERROR_OUT_OF_MEMORY, "out of memory for an occlusion field of %ux%ux%u samples",
                       options->theta, options->phi, options->radii);
    pn_fiv f = pn_object_new(ctx, sizeof *f, &fiv_type, "an occlusion field");
    if (!f) {
        free(samples);
        return PN_ERROR_OUT_OF_MEMORY;
    }
    f->options = *options;
    f->samples = samples;
    f->value_scale = 1.0f;
    *out = f;
    return PN_SUCCESS;
}

static void destroy_fiv(pn_object *o)
{
    pn_fiv f = (pn_fiv)o;
    free(f->samples);
}

const char *pn_fiv_geometry_problem(const struct pn_fiv_impl *f)
{
    for (int c = 0; c < 3; ++c)
        if (!isfinite(f->centre[c]))
            return "its bounding-sphere centre is not finite";
    if (!(isfinite(f->radius) && f->radius > 0.0f))
        return "its bounding radius is not a positive finite number (the mesh's extent overflows float)";
    if (!(isfinite(f->inner) && f->inner > 0.0f))
        return "its innermost sphere radius is not a positive finite number";
    if (!(isfinite(f->outer) && f->outer > f->inner))
        return "its outermost sphere radius (R / sqrt(error_target)) overflows float or is not above the innermost";
    for (int c = 0; c < 3; ++c)
        if (!isfinite(fabs((double)f->centre[c]) + (double)f->outer) ||
            fabs((double)f->centre[c]) + (double)f->outer > (double)FLT_MAX)
            return "points of its outermost sphere overflow float (the mesh is too large or too far from the origin)";
    if (!(isfinite(f->value_scale) && f->value_scale > 0.0f))
        return "its value scale is not a positive finite number";
    if (!(isfinite(f->outer_max) && f->outer_max >= 0.0f))
        return "its largest outer value is not a finite number >= 0";
    return NULL;
}

uint64_t pn_fiv_sample_count(const pn_fiv_options *o)
{
    return (uint64_t)o->theta * o->phi * o->radii;
}

float pn_fiv_radius(pn_fiv f, uint32_t k)
{
    const double t = (double)k / (double)(f->options.radii - 1);
    return (float)((double)f->inner * pow((double)f->outer / (double)f->inner, t));
}

/* float -> IEEE half, round to nearest even; overflow gives infinity. */
uint16_t pn_half_from_float(float value)
{
    uint32_t x;
    memcpy(&x, &value, sizeof x);
    const uint32_t sign = (x >> 16) & 0x8000u, mant = x & 0x7fffffu;
    const int exp = (int)((x >> 23) & 0xffu);
    if (exp == 255)
        return (uint16_t)(sign | 0x7c00u | (mant ? 0x200u : 0u));
    const int e = exp - 127 + 15;
    if (e >= 31)
        return (uint16_t)(sign | 0x7c00u);
    if (e <= 0) { /* subnormal half (or zero) */
        if (e < -10)
            return (uint16_t)sign;
        const uint32_t m = mant | 0x800000u, shift = (uint32_t)(14 - e);
        uint32_t h = m >> shift;
        const uint32_t rem = m & ((1u << shift) - 1u), halfway = 1u << (shift - 1u);
        if (rem > halfway || (rem == halfway && (h & 1u)))
            ++h;
        return (uint16_t)(sign | h);
    }
    uint32_t h = ((uint32_t)e << 10) | (mant >> 13);
    const uint32_t rem = mant & 0x1fffu;
    if (rem > 0x1000u || (rem == 0x1000u && (h & 1u)))
        ++h; /* a carry into the exponent is still the right rounding */
    return (uint16_t)(sign | h);
}

float pn_float_from_half(uint16_t h)
{
    const uint32_t sign = (uint32_t)(h & 0x8000u) << 16, exp = (h >> 10) & 0x1fu, mant = h & 0x3ffu;
    float f;
    if (exp == 0)
        f = ldexpf((float)mant, -24);
    else if (exp == 31)
        f = mant ? NAN : INFINITY;
    else
        f = ldexpf((float)(mant | 0x400u), (int)exp - 25);
    uint32_t bits;
    memcpy(&bits, &f, sizeof bits);
    bits |= sign;
    memcpy(&f, &bits, sizeof f);
    return f;
}

void pn_fiv_fill_info(pn_fiv f, pn_fiv_info *info)
{
    memset(info, 0, sizeof *info);
    info->options = f->options;
    memcpy(info->centre, f->centre, sizeof f->centre);
    info->radius = f->radius;
    info->inner = f->inner;
    info->outer = f->outer;
    info->mesh_hash = f->mesh_hash;
    info->env_hash = f->env_hash;
    info->sample_count = pn_fiv_sample_count(&f->options);
    info->inside_count = f->inside_count;
    info->stored_bytes = info->sample_count * 9u * (f->options.precision == PN_PRECISION_FLOAT16 ? 2u : 4u);
    info->rays = f->rays;
    info->bake_seconds = f->bake_seconds;
    info->radii_done = f->radii_done;
}

pn_status pn_fiv_do_read(pn_fiv f, float *host, size_t bytes)
{
    const size_t need = (size_t)pn_fiv_sample_count(&f->options) * 9u * sizeof(float);
    if (bytes != need)
        return pn_fail(f->obj.ctx, PN_ERROR_INVALID_SIZE, "reading an occlusion field needs exactly %zu bytes, got %zu",
                       need, bytes);
    memcpy(host, f->samples, need);
    return PN_SUCCESS;
}
