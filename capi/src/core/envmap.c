/* Environment maps: validation of the lat-long input, and at commit the
 * device conversion to a cube map, its texel directions and solid angles,
 * and the irradiance map (kernels/envmap.cl). */
#include "core/core.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

static void destroy_envmap(pn_object *o)
{
    pn_envmap env = (pn_envmap)o;
    pn_mem_release(&env->latlong);
    pn_mem_release(&env->cube);
    pn_mem_release(&env->dirs);
    pn_mem_release(&env->irradiance);
    pn_envmap_forget_domains(env);
}

static const pn_object_type envmap_type = {PN_MAGIC_ENVMAP, "env map", destroy_envmap, NULL};

pn_status pn_envmap_new(pn_context ctx, pn_envmap *out)
{
    pn_envmap env = pn_object_new(ctx, sizeof *env, &envmap_type, "an env map");
    if (!env)
        return PN_ERROR_OUT_OF_MEMORY;
    env->face_size = 64;
    env->irradiance_face_size = 32;
    env->intensity = 1.0f;
    *out = env;
    return PN_SUCCESS;
}

pn_status pn_envmap_do_set_latlong(pn_envmap env, const float *rgb, uint32_t width, uint32_t height)
{
    pn_context ctx = env->obj.ctx;
    if (width == 0 || height == 0)
        return pn_fail(ctx, PN_ERROR_EMPTY_INPUT, "env map size %ux%u is empty", width, height);
    size_t bytes = pn_mul_size(width, height, 3 * sizeof(float));
    if (bytes == SIZE_MAX || (uint64_t)width * height > (1u << 28))
        return pn_fail(ctx, PN_ERROR_INVALID_SIZE, "env map size %ux%u is too large (at most 2^28 texels)", width,
                       height);
    pn_status cap = pn_check_bytes(ctx, bytes, "the env map's texels");
    if (cap)
        return cap;
    size_t nan = 0, inf = 0, neg = 0, first = SIZE_MAX;
    const size_t n = (size_t)width * height;
    for (size_t i = 0; i < n; ++i) {
        bool bad = false;
        for (int c = 0; c < 3; ++c) {
            float v = rgb[3 * i + c];
            if (isnan(v)) { ++nan; bad = true; break; }
            if (isinf(v)) { ++inf; bad = true; break; }
            if (v < 0.0f) { ++neg; bad = true; break; }
        }
        if (bad && first == SIZE_MAX)
            first = i;
    }
    if (first != SIZE_MAX)
        return pn_fail(ctx, PN_ERROR_INVALID_VALUE,
                       "env map has %zu NaN, %zu infinite and %zu negative texels, first at (x=%zu, y=%zu)", nan, inf,
                       neg, first % width, first / width);
    cl_mem buf;
    pn_status st = pn_alloc(ctx, bytes, CL_MEM_READ_ONLY, rgb, &buf, "the lat-long env map");
    if (st)
        return st;
    pn_mem_release(&env->latlong);
    env->latlong = buf;
    env->width = width;
    env->height = height;
    const uint32_t dims[2] = {width, height};
    env->data_hash = pn_hash_bytes(pn_hash_bytes(PN_HASH_SEED, rgb, bytes), dims, sizeof dims);
    env->committed = false;
    return PN_SUCCESS;
}

pn_status pn_envmap_param_int(pn_envmap env, const char *name, int32_t *value, bool set)
{
    pn_context ctx = env->obj.ctx;
    struct { const char *name; int32_t *field; int32_t lo, hi; } params[] = {
        {"face_size", &env->face_size, 1, 2048},
        {"irradiance_face_size", &env->irradiance_face_size, 2, 256},
        {"supersampling", &env->supersampling, 0, 64},
    };
    for (size_t i = 0; i < sizeof params / sizeof params[0]; ++i) {
        if (strcmp(name, params[i].name))
            continue;
        if (!set) {
            *value = *params[i].field;
            return PN_SUCCESS;
        }
        if (*value < params[i].lo || *value > params[i].hi)
            return pn_fail(ctx, PN_ERROR_INVALID_ARGUMENT, "env map parameter %s = %d is outside [%d, %d]", name, *value,
                           params[i].lo, params[i].hi);
        *params[i].field = *value;
        env->committed = false;
        return PN_SUCCESS;
    }
    return pn_fail(ctx, PN_ERROR_BAD_CONFIG,
                   "env maps have no integer parameter '%s' (face_size, irradiance_face_size, supersampling)", name);
}

pn_status pn_envmap_param_float(pn_envmap env, const char *name, float *value, bool set)
{
    pn_context ctx = env->obj.ctx;
    float *field = !strcmp(name, "rotation_deg") ? &env->rotation_deg : !strcmp(name, "intensity") ? &env->intensity : NULL;
    if (!field)
        return pn_fail(ctx, PN_ERROR_BAD_CONFIG, "env maps have no float parameter '%s' (rotation_deg, intensity)", name);
    if (!set) {
        *value = *field;
        return PN_SUCCESS;
    }
    if (!isfinite(*value) || (field == &env->intensity && *value < 0.0f))
        return pn_fail(ctx, PN_ERROR_INVALID_ARGUMENT, "env map parameter %s = %g must be finite%s", name, (double)*value,
                       field == &env->intensity ? " and >= 0" : "");
    *field = *value;
    env->committed = false;
    return PN_SUCCESS;
}

/* Sub-samples per cube texel side so that each sub-texel is at most a
 * quarter of a lat-long texel (a face's centre texel is 2/F radians wide, a
 * lat-long row pi/H high): a bright texel (a sun) then keeps its power to
 * about 1 % (tests/test_envmap.py). The work is ~6 (2.5 H)^2 lookups
 * whatever F is; 64 caps it for tiny faces. */
static int auto_supersampling(uint32_t face, uint32_t height)
{
    double ratio = (2.0 / face) / (3.14159265358979 / height);
    int s = (int)ceil(4.0 * ratio);
    return s < 1 ? 1 : (s > 64 ? 64 : s);
}

/* (cos, sin) of the map's rotation about +y, as the kernels take it. */
cl_float2 pn_envmap_rotation(pn_envmap env)
{
    const double angle = (double)env->rotation_deg * 3.14159265358979323846 / 180.0;
    const cl_float2 rot = {{(float)cos(angle), (float)sin(angle)}};
    return rot;
}

/* Enqueues the lat-long -> cube resampling at face size `face` into `cube`
 * and the texel directions + solid angles into `dirs`. */
static pn_status fill_cube(pn_envmap env, int face, cl_mem cube, cl_mem dirs)
{
    pn_context ctx = env->obj.ctx;
    const size_t texels = 6u * (size_t)face * face;
    const cl_int w = (cl_int)env->width, h = (cl_int)env->height, cn = face;
    const cl_int cs = env->supersampling ? env->supersampling : auto_supersampling((uint32_t)face, env->height);
    const cl_float2 rot = pn_envmap_rotation(env);
    cl_kernel to_cube, to_dirs;
    pn_status st;
    if ((st = pn_context_kernel(ctx, "envmap", "envmap_latlong_to_cube", &to_cube)) ||
        (st = pn_context_kernel(ctx, "envmap", "envmap_cube_directions", &to_dirs)))
        return st;
    size_t sizes[] = {sizeof(cl_mem), sizeof w, sizeof h, sizeof cn, sizeof cs, sizeof rot, sizeof(float), sizeof(cl_mem)};
    const void *vals[] = {&env->latlong, &w, &h, &cn, &cs, &rot, &env->intensity, &cube};
    if ((st = pn_set_args(ctx, to_cube, "envmap_latlong_to_cube", 8, sizes, vals)) ||
        (st = pn_enqueue_1d(ctx, to_cube, "envmap_latlong_to_cube", texels, 0)))
        return st;
    size_t dsizes[] = {sizeof cn, sizeof(cl_mem)};
    const void *dvals[] = {&cn, &dirs};
    if ((st = pn_set_args(ctx, to_dirs, "envmap_cube_directions", 2, dsizes, dvals)))
        return st;
    return pn_enqueue_1d(ctx, to_dirs, "envmap_cube_directions", texels, 0);
}

pn_status pn_envmap_do_commit(pn_envmap env)
{
    pn_context ctx = env->obj.ctx;
    if (!env->latlong)
        return pn_fail(ctx, PN_ERROR_NOT_COMMITTED, "env map has no data: call pn_envmap_set_latlong before committing");
    const int n = env->face_size, m = env->irradiance_face_size;
    const size_t texels = 6u * (size_t)n * n, samples = 6u * (size_t)m * m;
    pn_status st = PN_SUCCESS;
    if (env->committed_face_size != n || !env->cube) {
        pn_mem_release(&env->cube);
        pn_mem_release(&env->dirs);
        if ((st = pn_alloc(ctx, texels * 16, CL_MEM_READ_WRITE, NULL, &env->cube, "the env cube map")) ||
            (st = pn_alloc(ctx, texels * 16, CL_MEM_READ_WRITE, NULL, &env->dirs, "the env cube directions")))
            return st;
        env->committed_face_size = n;
    }
    if (env->committed_irradiance_size != m || !env->irradiance) {
        pn_mem_release(&env->irradiance);
        if ((st = pn_alloc(ctx, samples * 16, CL_MEM_READ_WRITE, NULL, &env->irradiance, "the irradiance map")))
            return st;
        env->committed_irradiance_size = m;
    }
    cl_kernel irradiance;
    if ((st = fill_cube(env, n, env->cube, env->dirs)) ||
        (st = pn_context_kernel(ctx, "envmap", "envmap_irradiance", &irradiance)))
        return st;
    const cl_int cm = m, ctexels = (cl_int)texels;
    {
        size_t sizes[] = {sizeof(cl_mem), sizeof(cl_mem), sizeof ctexels, sizeof cm, sizeof(cl_mem)};
        const void *vals[] = {&env->cube, &env->dirs, &ctexels, &cm, &env->irradiance};
        if ((st = pn_set_args(ctx, irradiance, "envmap_irradiance", 5, sizes, vals)) ||
            (st = pn_enqueue_1d(ctx, irradiance, "envmap_irradiance", samples, 64)))
            return st;
    }
    const float lighting[2] = {env->rotation_deg, env->intensity};
    env->content_hash = pn_hash_bytes(pn_hash_bytes(env->data_hash, lighting, sizeof lighting), &env->supersampling,
                                      sizeof env->supersampling);
    env->committed = true;
    env->version = pn_next_version();
    return PN_SUCCESS;
}

pn_status pn_envmap_do_read(pn_envmap env, pn_envmap_data what, void *host, size_t bytes)
{
    pn_context ctx = env->obj.ctx;
    if (!env->committed)
        return pn_fail(ctx, PN_ERROR_NOT_COMMITTED, "env map changed since its last commit; call pn_envmap_commit");
    cl_mem src;
    size_t need;
    const size_t n = (size_t)env->face_size, m = (size_t)env->irradiance_face_size;
    switch (what) {
    case PN_ENVMAP_CUBE_RADIANCE: src = env->cube; need = 6 * n * n * 16; break;
    case PN_ENVMAP_CUBE_DIRECTIONS: src = env->dirs; need = 6 * n * n * 16; break;
    case PN_ENVMAP_IRRADIANCE: src = env->irradiance; need = 6 * m * m * 16; break;
    default: return pn_fail(ctx, PN_ERROR_INVALID_ARGUMENT, "unknown env map data %d", (int)what);
    }
    if (bytes != need)
        return pn_fail(ctx, PN_ERROR_INVALID_SIZE, "reading env map data %d needs exactly %zu bytes, got %zu", (int)what,
                       need, bytes);
    cl_int err = clEnqueueReadBuffer(ctx->queue, src, CL_TRUE, 0, need, host, 0, NULL, NULL);
    return err == CL_SUCCESS ? PN_SUCCESS : pn_fail_cl(ctx, err, "reading env map data");
}

pn_status pn_envmap_sample_cube(pn_envmap env, int face, float *radiance, float *directions)
{
    pn_context ctx = env->obj.ctx;
    if (!env->committed)
        return pn_fail(ctx, PN_ERROR_NOT_COMMITTED, "env map changed since its last commit; call pn_envmap_commit");
    const size_t bytes = 6u * (size_t)face * face * 16;
    cl_mem cube = NULL, dirs = NULL;
    pn_status st;
    if (!(st = pn_alloc(ctx, bytes, CL_MEM_READ_WRITE, NULL, &cube, "a resampled env cube")) &&
        !(st = pn_alloc(ctx, bytes, CL_MEM_READ_WRITE, NULL, &dirs, "resampled cube directions")) &&
        !(st = fill_cube(env, face, cube, dirs))) {
        cl_int err = CL_SUCCESS;
        if (radiance)
            err = clEnqueueReadBuffer(ctx->queue, cube, CL_TRUE, 0, bytes, radiance, 0, NULL, NULL);
        if (err == CL_SUCCESS && directions)
            err = clEnqueueReadBuffer(ctx->queue, dirs, CL_TRUE, 0, bytes, directions, 0, NULL, NULL);
        if (err != CL_SUCCESS)
            st = pn_fail_cl(ctx, err, "reading a resampled env cube");
    }
    pn_mem_release(&cube);
    pn_mem_release(&dirs);
    return st;
}

pn_status pn_envmap_enqueue_background(pn_envmap env, cl_mem position, cl_mem instance, uint32_t count, cl_mem image)
{
    pn_context ctx = env->obj.ctx;
    if (!env->committed)
        return pn_fail(ctx, PN_ERROR_NOT_COMMITTED, "env map changed since its last commit; call pn_envmap_commit");
    cl_kernel k;
    pn_status st = pn_context_kernel(ctx, "envmap", "envmap_background", &k);
    if (st)
        return st;
    const cl_int n = (cl_int)count, w = (cl_int)env->width, h = (cl_int)env->height;
    const cl_float2 rot = pn_envmap_rotation(env);
    size_t sizes[] = {sizeof(cl_mem), sizeof(cl_mem), sizeof n, sizeof(cl_mem), sizeof w, sizeof h, sizeof rot,
                      sizeof(float), sizeof(cl_mem)};
    const void *vals[] = {&position, &instance, &n, &env->latlong, &w, &h, &rot, &env->intensity, &image};
    if ((st = pn_set_args(ctx, k, "envmap_background", 9, sizes, vals)))
        return st;
    /* 8 consecutive pixels per work-item (vector lanes, kernels/envmap.cl). */
    return pn_enqueue_1d(ctx, k, "envmap_background", ((size_t)count + 7) / 8, 16);
}

static float luminance(const float *rgb)
{
    return 0.2126f * rgb[0] + 0.7152f * rgb[1] + 0.0722f * rgb[2];
}

static void put_record(float *out, const float *dir, const float *radiance)
{
    memcpy(out, dir, 4 * sizeof(float)); /* direction, solid angle */
    memcpy(out + 4, radiance, 3 * sizeof(float));
    out[7] = 0.0f;
}

/* Direction records of the env map: one per cube texel of face f with its
 * area-averaged radiance and exact solid angle (2 float4: direction, dw |
 * radiance, 0), black texels dropped, and texels whose power L*dw reaches
 * `threshold` of the brightest one split into s x s sub-texels (taken from
 * the cube of face f*s, whose texels nest inside the coarse ones). Used by
 * the reference renderer and the FIV bake. *out is malloc'ed. */
pn_status pn_envmap_direction_records(pn_envmap env, int f, int s, float threshold, float **result, size_t *result_count)
{
    pn_context ctx = env->obj.ctx;
    *result = NULL;
    *result_count = 0;
    if (f * s > 2048)
        return pn_fail(ctx, PN_ERROR_INVALID_ARGUMENT,
                       "face_size %d x sun_supersampling %d = %d exceeds the 2048 sub-texels per face side", f, s, f * s);
    const size_t texels = 6u * (size_t)f * f, fine_texels = texels * (size_t)s * s;
    float *rad = pn_malloc(ctx, texels * 16, "the direction cube");
    float *dirs = pn_malloc(ctx, texels * 16, "the cube directions");
    float *fine_rad = s > 1 ? pn_malloc(ctx, fine_texels * 16, "the supersampled cube") : NULL;
    float *fine_dirs = s > 1 ? pn_malloc(ctx, fine_texels * 16, "the supersampled cube directions") : NULL;
    float *records = NULL;
    pn_status st = PN_SUCCESS;
    if (!rad || !dirs || (s > 1 && (!fine_rad || !fine_dirs)))
        st = PN_ERROR_OUT_OF_MEMORY;
    if (!st)
        st = pn_envmap_sample_cube(env, f, rad, dirs);
    if (!st && s > 1)
        st = pn_envmap_sample_cube(env, f * s, fine_rad, fine_dirs);
    float max_power = 0.0f;
    for (size_t k = 0; !st && k < texels; ++k)
        max_power = fmaxf(max_power, luminance(rad + 4 * k) * dirs[4 * k + 3]);
    /* Pass 0 counts, pass 1 writes. */
    size_t count = 0;
    for (int pass = 0; !st && pass < 2; ++pass) {
        if (pass == 1 && !(records = pn_malloc(ctx, pn_mul_size(count ? count : 1, 8, sizeof(float)), "direction records")))
            st = PN_ERROR_OUT_OF_MEMORY;
        size_t out = 0;
        for (size_t k = 0; !st && k < texels; ++k) {
            const float *l = rad + 4 * k;
            if (l[0] == 0.0f && l[1] == 0.0f && l[2] == 0.0f)
                continue;
            const bool split = s > 1 && luminance(l) * dirs[4 * k + 3] >= threshold * max_power;
            if (!split) {
                if (pass)
                    put_record(records + 8 * out, dirs + 4 * k, l);
                ++out;
                continue;
            }
            const size_t face = k / ((size_t)f * f), j = (k / f) % f, i = k % f, fs = (size_t)f * s;
            for (int sj = 0; sj < s; ++sj)
                for (int si = 0; si < s; ++si) {
                    size_t q = face * fs * fs + (j * s + sj) * fs + (i * s + si);
                    const float *lq = fine_rad + 4 * q;
                    if (lq[0] == 0.0f && lq[1] == 0.0f && lq[2] == 0.0f)
                        continue;
                    if (pass)
                        put_record(records + 8 * out, fine_dirs + 4 * q, lq);
                    ++out;
                }
        }
        count = out;
    }
    if (!st && count > (size_t)INT32_MAX)
        st = pn_fail(ctx, PN_ERROR_INVALID_SIZE, "too many env directions (%zu)", count);
    free(rad);
    free(dirs);
    free(fine_rad);
    free(fine_dirs);
    if (st) {
        free(records);
        return st;
    }
    *result = records;
    *result_count = count;
    return PN_SUCCESS;
}
