/* Occlusion fields (docs/fiv.md): the pn_fiv object, half-float storage, the
 * fields a scene uses, and the per-frame occluder records and field data the
 * `fiv` shading kernel reads (kernels/fiv.cl). The bake is in fiv_bake.c,
 * the file format in fiv_file.c. */
#include "internal.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

pn_fiv_options pn_fiv_options_default(void)
{
    pn_fiv_options o = {17, 32, 15, 0.2f, 0.01f, 32, 4, 0.1f, PN_PRECISION_FLOAT16};
    return o;
}

pn_status pn_fiv_check_options(pn_context ctx, const pn_fiv_options *o)
{
    struct { const char *name; uint32_t value, lo, hi; } ints[] = {
        {"theta", o->theta, 3, 1025}, {"phi", o->phi, 4, 2048}, {"radii", o->radii, 2, 256},
        {"face_size", o->face_size, 1, 256}, {"sun_supersampling", o->sun_supersampling, 1, 16},
        {"precision", o->precision, 0, 1},
    };
    for (size_t i = 0; i < sizeof ints / sizeof ints[0]; ++i)
        if (ints[i].value < ints[i].lo || ints[i].value > ints[i].hi)
            return pn_fail(ctx, PN_ERROR_INVALID_ARGUMENT, "FIV option %s = %u is outside [%u, %u]", ints[i].name,
                           ints[i].value, ints[i].lo, ints[i].hi);
    if (!(o->inner_radius > 0.0f && o->inner_radius < 1.0f))
        return pn_fail(ctx, PN_ERROR_INVALID_ARGUMENT, "FIV option inner_radius = %g must be in (0, 1) bounding radii",
                       (double)o->inner_radius);
    if (!(o->error_target > 0.0f && o->error_target <= 0.5f))
        return pn_fail(ctx, PN_ERROR_INVALID_ARGUMENT, "FIV option error_target = %g must be in (0, 0.5]",
                       (double)o->error_target);
    if (!(o->sun_threshold > 0.0f && o->sun_threshold <= 1.0f))
        return pn_fail(ctx, PN_ERROR_INVALID_ARGUMENT, "FIV option sun_threshold = %g must be in (0, 1]",
                       (double)o->sun_threshold);
    if ((uint64_t)o->theta * o->phi * o->radii > (1ull << 28))
        return pn_fail(ctx, PN_ERROR_INVALID_SIZE, "FIV grid %ux%ux%u has more than 2^28 samples", o->theta, o->phi,
                       o->radii);
    return PN_SUCCESS;
}

pn_status pn_fiv_new(pn_context ctx, const pn_fiv_options *options, pn_fiv *out)
{
    pn_fiv f = calloc(1, sizeof *f);
    size_t n = pn_mul_size((size_t)options->theta * options->phi, options->radii, 9 * sizeof(float));
    float *samples = n == SIZE_MAX ? NULL : malloc(n);
    if (!f || !samples) {
        free(f);
        free(samples);
        return pn_fail(ctx, PN_ERROR_OUT_OF_MEMORY, "out of memory for an occlusion field of %ux%ux%u samples",
                       options->theta, options->phi, options->radii);
    }
    f->obj.magic = PN_MAGIC_FIV;
    f->obj.refcount = 1;
    f->obj.ctx = ctx;
    f->options = *options;
    f->samples = samples;
    f->value_scale = 1.0f;
    *out = f;
    return PN_SUCCESS;
}

void pn_fiv_destroy(pn_fiv f)
{
    free(f->samples);
    f->obj.magic = PN_MAGIC_DEAD;
    free(f);
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

pn_status pn_fiv_do_get_info(pn_fiv f, pn_fiv_info *info)
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
    return PN_SUCCESS;
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

/* ------------------------------------------------------------- the scene */

pn_status pn_scene_do_set_fivs(pn_scene scene, const pn_fiv *fields, uint32_t count)
{
    pn_context ctx = scene->obj.ctx;
    for (uint32_t i = 0; i < count; ++i) {
        if (!fields[i] || fields[i]->obj.magic != PN_MAGIC_FIV) /* a handle argument: the global slot */
            return pn_fail(NULL, PN_ERROR_NULL_HANDLE,
                           "pn_scene_set_fivs: fields[%u] is NULL or not an occlusion field", i);
        if (fields[i]->obj.ctx != ctx)
            return pn_fail(ctx, PN_ERROR_INVALID_ARGUMENT, "pn_scene_set_fivs: fields[%u] belongs to another context", i);
        for (uint32_t j = 0; j < i; ++j)
            if (fields[j]->mesh_hash == fields[i]->mesh_hash)
                return pn_fail(ctx, PN_ERROR_INVALID_ARGUMENT,
                               "pn_scene_set_fivs: fields[%u] and fields[%u] are both for mesh %016llx; give one field "
                               "per mesh", j, i, (unsigned long long)fields[i]->mesh_hash);
    }
    pn_fiv *copy = NULL;
    if (count && !(copy = pn_malloc(ctx, pn_mul_size(count, 1, sizeof *copy), "the scene's occlusion fields")))
        return PN_ERROR_OUT_OF_MEMORY;
    for (uint32_t i = 0; i < count; ++i) {
        copy[i] = fields[i];
        fields[i]->obj.refcount++;
    }
    pn_scene_release_fivs(scene);
    scene->fivs = copy;
    scene->fiv_count = count;
    scene->fiv_version = pn_next_version();
    return PN_SUCCESS;
}

void pn_scene_release_fivs(pn_scene scene)
{
    for (uint32_t i = 0; i < scene->fiv_count; ++i)
        pn_fiv_release(scene->fivs[i]);
    free(scene->fivs);
    scene->fivs = NULL;
    scene->fiv_count = 0;
}

/* The uniform scale s of an object-to-world matrix s * I | t, or 0 when it
 * rotates, shears, mirrors or scales unevenly. */
static float uniform_scale(const float m[12])
{
    const float s = m[0];
    const float tol = 1e-5f * fabsf(s);
    if (!(s > 0.0f))
        return 0.0f;
    for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 3; ++c)
            if (fabsf(m[4 * r + c] - (r == c ? s : 0.0f)) > tol)
                return 0.0f;
    return s;
}

/* Concatenates the scene's fields as stored on the device (half or float),
 * each at a 16-byte aligned offset; rebuilt when the list changes. */
static pn_status upload_fields(pn_fiv_cache *cache, pn_scene scene)
{
    pn_context ctx = scene->obj.ctx;
    if (cache->data && cache->list_version == scene->fiv_version)
        return PN_SUCCESS;
    size_t total = 0;
    for (uint32_t i = 0; i < scene->fiv_count; ++i) {
        const pn_fiv f = scene->fivs[i];
        size_t elem = f->options.precision == PN_PRECISION_FLOAT16 ? 2u : 4u;
        total += ((size_t)pn_fiv_sample_count(&f->options) * 9u * elem + 15u) & ~(size_t)15u;
    }
    unsigned char *host = pn_malloc(ctx, total ? total : 16, "the occlusion fields");
    if (!host)
        return PN_ERROR_OUT_OF_MEMORY;
    memset(host, 0, total ? total : 16);
    free(cache->offsets);
    cache->offsets = pn_malloc(ctx, pn_mul_size(scene->fiv_count ? scene->fiv_count : 1, 1, sizeof(uint32_t)),
                               "field offsets");
    if (!cache->offsets) {
        free(host);
        return PN_ERROR_OUT_OF_MEMORY;
    }
    size_t at = 0;
    for (uint32_t i = 0; i < scene->fiv_count; ++i) {
        const pn_fiv f = scene->fivs[i];
        const size_t n = (size_t)pn_fiv_sample_count(&f->options) * 9u;
        cache->offsets[i] = (uint32_t)at;
        if (f->options.precision == PN_PRECISION_FLOAT16) {
            uint16_t *h = (uint16_t *)(void *)(host + at);
            for (size_t k = 0; k < n; ++k)
                h[k] = pn_half_from_float(f->samples[k] / f->value_scale);
            at += (n * 2u + 15u) & ~(size_t)15u;
        } else {
            memcpy(host + at, f->samples, n * 4u);
            at += (n * 4u + 15u) & ~(size_t)15u;
        }
    }
    if (total > UINT32_MAX) {
        free(host);
        return pn_fail(ctx, PN_ERROR_INVALID_SIZE, "the scene's occlusion fields take %zu bytes, more than 4 GiB", total);
    }
    pn_mem_release(&cache->data);
    pn_status st = pn_alloc(ctx, total ? total : 16, CL_MEM_READ_ONLY, host, &cache->data, "the occlusion fields");
    free(host);
    if (!st) {
        cache->list_version = scene->fiv_version;
    }
    return st;
}

/* FIV(Env) = sum L w dw and the reference irradiance E_ref = max over
 * channels of sum L dw / 4 (a constant env of the same power gives E = E_ref)
 * from the env's cube, in double; recomputed when the env map changes. */
static pn_status env_vectors(pn_fiv_cache *cache, pn_envmap env)
{
    pn_context ctx = env->obj.ctx;
    if (cache->env_version == env->version)
        return PN_SUCCESS;
    const size_t texels = 6u * (size_t)env->face_size * env->face_size;
    float *rad = pn_malloc(ctx, texels * 16, "the env cube"), *dirs = pn_malloc(ctx, texels * 16, "the env directions");
    pn_status st = (!rad || !dirs) ? PN_ERROR_OUT_OF_MEMORY : PN_SUCCESS;
    if (!st) {
        cl_int err = clEnqueueReadBuffer(ctx->queue, env->cube, CL_TRUE, 0, texels * 16, rad, 0, NULL, NULL);
        if (err == CL_SUCCESS)
            err = clEnqueueReadBuffer(ctx->queue, env->dirs, CL_TRUE, 0, texels * 16, dirs, 0, NULL, NULL);
        if (err != CL_SUCCESS)
            st = pn_fail_cl(ctx, err, "reading the env cube for FIV(Env)");
    }
    if (!st) {
        double fiv[9] = {0}, power[3] = {0};
        for (size_t k = 0; k < texels; ++k) {
            const float *d = dirs + 4 * k, *l = rad + 4 * k;
            for (int c = 0; c < 3; ++c) {
                double ldw = (double)l[c] * d[3];
                power[c] += ldw;
                for (int a = 0; a < 3; ++a)
                    fiv[3 * a + c] += ldw * d[a];
            }
        }
        for (int i = 0; i < 9; ++i)
            cache->env_fiv[i] = (float)fiv[i];
        cache->env_ref = (float)(fmax(power[0], fmax(power[1], power[2])) / 4.0);
        cache->env_version = env->version;
    }
    free(rad);
    free(dirs);
    return st;
}

pn_status pn_fiv_prepare(pn_fiv_cache *cache, pn_scene scene, float cull_threshold, pn_fiv_frame *frame)
{
    pn_context ctx = scene->obj.ctx;
    pn_envmap env = scene->env;
    pn_status st;
    for (uint32_t i = 0; i < scene->fiv_count; ++i)
        if (scene->fivs[i]->env_hash != env->content_hash)
            return pn_fail(ctx, PN_ERROR_INVALID_ARGUMENT,
                           "occlusion field %u was baked under env map %016llx but the scene's env map is %016llx "
                           "(another image, rotation, intensity or supersampling): bake it again for this env map",
                           i, (unsigned long long)scene->fivs[i]->env_hash, (unsigned long long)env->content_hash);
    if ((st = upload_fields(cache, scene)) || (st = env_vectors(cache, env)))
        return st;
    /* One record per instance whose mesh has a field. */
    uint32_t count = 0;
    for (int pass = 0; pass < 2; ++pass) {
        count = 0;
        for (uint32_t id = 0; id < scene->instance_count; ++id) {
            const pn_instance *inst = &scene->instances[id];
            if (!inst->mesh)
                continue;
            uint32_t fi = 0;
            while (fi < scene->fiv_count && scene->fivs[fi]->mesh_hash != inst->mesh->content_hash)
                ++fi;
            if (fi == scene->fiv_count)
                continue;
            const pn_fiv f = scene->fivs[fi];
            const float s = uniform_scale(inst->object_to_world);
            if (s == 0.0f)
                return pn_fail(ctx, PN_ERROR_UNSUPPORTED,
                               "instance %u is an occluder with an occlusion field but its transform rotates, shears, "
                               "mirrors or scales unevenly: a field encodes the fixed environment in the occluder's "
                               "frame, so the fiv method takes translations and uniform scales only",
                               id);
            if (pass == 1) {
                float *r = cache->records + (size_t)count * 16;
                const float *m = inst->object_to_world;
                for (int c = 0; c < 3; ++c)
                    r[c] = m[4 * c] * f->centre[0] + m[4 * c + 1] * f->centre[1] + m[4 * c + 2] * f->centre[2] +
                           m[4 * c + 3];
                r[3] = s * f->radius;
                r[4] = 1.0f / s;
                r[5] = f->inner;
                r[6] = (float)log((double)f->outer / (double)f->inner);
                /* Beyond the grid the contribution falls as (outer / rho)^2 from
                 * at most outer_max: cull where it drops below the threshold. */
                float cull = INFINITY;
                if (cull_threshold > 0.0f) {
                    const float floor_e = cull_threshold * cache->env_ref;
                    cull = f->outer * sqrtf(fmaxf(f->outer_max / fmaxf(floor_e, 1e-30f), 1.0f));
                }
                r[7] = s * cull;
                const uint32_t u[6] = {cache->offsets[fi], f->options.theta, f->options.phi, f->options.radii, id,
                                       f->options.precision == PN_PRECISION_FLOAT16 ? 1u : 0u};
                memcpy(r + 8, u, 4 * sizeof(uint32_t));
                memcpy(r + 12, u + 4, 2 * sizeof(uint32_t));
                r[14] = f->options.precision == PN_PRECISION_FLOAT16 ? f->value_scale : 1.0f;
                r[15] = 0.0f;
            }
            ++count;
        }
        if (pass == 0) {
            size_t bytes = (size_t)(count ? count : 1) * 16 * sizeof(float);
            if (bytes > cache->records_capacity) {
                free(cache->records);
                cache->records_capacity = 0;
                if (!(cache->records = pn_malloc(ctx, bytes, "occluder records")))
                    return PN_ERROR_OUT_OF_MEMORY;
                cache->records_capacity = bytes;
            }
        }
    }
    const size_t bytes = (size_t)(count ? count : 1) * 16 * sizeof(float);
    if (bytes > cache->device_capacity) {
        pn_mem_release(&cache->device_records);
        cache->device_capacity = 0;
        if ((st = pn_alloc(ctx, bytes, CL_MEM_READ_ONLY, NULL, &cache->device_records, "occluder records")))
            return st;
        cache->device_capacity = bytes;
    }
    if (count) {
        cl_int err = clEnqueueWriteBuffer(ctx->queue, cache->device_records, CL_TRUE, 0, (size_t)count * 64,
                                          cache->records, 0, NULL, NULL);
        if (err != CL_SUCCESS)
            return pn_fail_cl(ctx, err, "uploading occluder records");
    }
    frame->occluders = cache->device_records;
    frame->occluder_count = count;
    frame->fields = cache->data;
    return PN_SUCCESS;
}

void pn_fiv_cache_release(pn_fiv_cache *cache)
{
    pn_mem_release(&cache->data);
    pn_mem_release(&cache->device_records);
    free(cache->records);
    free(cache->offsets);
    memset(cache, 0, sizeof *cache);
    cache->env_version = UINT64_MAX;
}
