/* The `fiv` method (docs/fiv.md, kernels/fiv.cl): diffuse env lighting with
 * soft shadows from the occlusion fields attached to instances. Plan: the
 * attached fields concatenated on the device (when the attachments change)
 * and FIV(Env) from the env map (when it changes). Execute: one record per
 * occluder instance from its transform, uploaded without waiting, the
 * per-tile occluder masks (`tile_cull`) and the shading kernel. */
#include "methods/method.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

enum { P_BACKGROUND, P_OVERLAP, P_MAX_OVERLAP, P_PARTIAL, P_SELF_SHADOW, P_TRILINEAR, P_CULL_THRESHOLD, P_TILE_CULL };

static const pn_param_desc params[] = {
    PN_PARAM_BACKGROUND,
    {"overlap", PN_PARAM_INT, PN_PARAM_FRAME, 1, 0, 2, "",
     "Several occluders: 0 sum, 1 unit-bounding-disc correction, 2 multiplied visibility."},
    {"max_overlap", PN_PARAM_INT, PN_PARAM_FRAME, 6, 2, 32, "",
     "overlap 1: how many occluders a pixel pairs, those with the largest irradiance there, whatever the "
     "scene's order (docs/fiv.md, Accuracy 6)."},
    {"partial", PN_PARAM_INT, PN_PARAM_FRAME, 0, 0, 1, "",
     "1: occluders straddling the receiver plane scaled by (d + R) / 2R (the paper's factor; docs/fiv.md)."},
    {"self_shadow", PN_PARAM_INT, PN_PARAM_FRAME, 0, 0, 1, "",
     "1: pixels on an occluder use its own field (fullsphere equality; biased dark, off by default: docs/fiv.md)."},
    {"trilinear", PN_PARAM_INT, PN_PARAM_FRAME, 1, 0, 1, "",
     "1: trilinear interpolation of the 8 nearest samples, 0: the nearest sample."},
    {"cull_threshold", PN_PARAM_FLOAT, PN_PARAM_FRAME, 1e-3, 0, 1, "",
     "Skip occluders whose extrapolated contribution is below this share of the env's reference irradiance."},
    {"tile_cull", PN_PARAM_INT, PN_PARAM_FRAME, 1, 0, 1, "",
     "1: per 16x16 screen tile (2+ occluders), shade with only the occluders whose culling distance reaches it."},
};

typedef struct state {
    pn_fiv *fields;           /* the distinct attached fields (held by the scene) */
    uint32_t field_count;
    cl_mem data;              /* the fields concatenated as stored */
    uint32_t *offsets;        /* byte offset of each field in `data` */
    uint64_t list_version;    /* scene->attachment_version that `data` holds */
    uint64_t env_version;     /* env map that env_fiv / env_ref describe */
    float env_fiv[9];         /* FIV(Env): X rgb, Y rgb, Z rgb */
    float env_ref;            /* reference irradiance for culling */
    float *records;           /* host occluder records, 16 floats each */
    size_t records_capacity, device_capacity;
    cl_mem device_records;
    cl_mem tile_masks;        /* per tile, one bit per occluder (bin_fiv_tiles) */
    size_t tile_capacity;
} state;

static bool is_field(const pn_attachment *a)
{
    return a->asset->magic == PN_MAGIC_FIV;
}

/* The index of `f` in the state's distinct fields, or field_count. */
static uint32_t field_index(const state *s, const pn_object *f)
{
    uint32_t i = 0;
    while (i < s->field_count && &s->fields[i]->obj != f)
        ++i;
    return i;
}

static pn_status collect_fields(state *s, pn_scene scene)
{
    free(s->fields);
    s->fields = NULL;
    s->field_count = 0;
    if (!(s->fields = pn_malloc(scene->obj.ctx, pn_mul_size(scene->attachment_count + 1, 1, sizeof *s->fields),
                                "the attached occlusion fields")))
        return PN_ERROR_OUT_OF_MEMORY;
    for (uint32_t i = 0; i < scene->attachment_count; ++i) {
        const pn_attachment *a = &scene->attachments[i];
        if (is_field(a) && field_index(s, a->asset) == s->field_count)
            s->fields[s->field_count++] = (pn_fiv)a->asset;
    }
    return PN_SUCCESS;
}

/* Cells of the outermost sphere's (theta, phi) grid: (n_theta - 1) x n_phi. */
static size_t cell_bound_count(const struct pn_fiv_impl *f)
{
    return (size_t)(f->options.theta - 1) * f->options.phi;
}

/* The culling bound per direction: for each cell of the outermost sphere,
 * the largest |FIV| of a channel over its 4 corner samples (NaN ones left
 * out), widened by 1e-5 against rounding. Beyond the grid a lookup
 * interpolates only those 4 samples (renormalised), so its N . FIV is at
 * most this times the fall-off (kernels/fiv.cl, pn_fiv_lookup). */
static void cell_bounds(const struct pn_fiv_impl *f, float *out)
{
    const uint32_t nt = f->options.theta, np = f->options.phi;
    const float *outer = f->samples + (size_t)(f->options.radii - 1) * nt * np * 9u;
    for (uint32_t i = 0; i + 1 < nt; ++i)
        for (uint32_t j = 0; j < np; ++j) {
            float largest = 0.0f;
            for (uint32_t c = 0; c < 4; ++c) {
                const float *v = outer + ((size_t)(i + c / 2) * np + (j + c % 2) % np) * 9u;
                for (int ch = 0; ch < 3; ++ch) {
                    float norm = sqrtf(v[ch] * v[ch] + v[3 + ch] * v[3 + ch] + v[6 + ch] * v[6 + ch]);
                    if (norm > largest) /* NaN (inside) never compares greater */
                        largest = norm;
                }
            }
            out[(size_t)i * np + j] = largest * 1.00001f;
        }
}

/* Direction bins of the coarse culling test (kernels/fiv.cl, pn_fiv_dir_bin):
 * PN_FIV_BINS_Z in cos theta (= d.y) by PN_FIV_BINS_P in a pseudo-angle p of
 * phi in [0, 8] that needs no atan (p = t, 2 - t, ... by octant, t the ratio
 * of the smaller to the larger of |d.x|, |d.z|). Keep in step with fiv.cl. */
/* Groups of 8 pixels of a row per shade_fiv work-item (kernels/fiv.cl): a
 * work-item normalises and looks up a normal its groups share once, and
 * overlaps the work of neighbouring groups. 8 measured 0.98x the CPU time
 * of 4 and 16 1.02-1.03x of 8 (docs/performance.md, FIV, "The floor round 2"). */
#define PN_FIV_ROW_GROUPS 8
#define PN_FIV_BINS_Z 16
#define PN_FIV_BINS_P 32
#define PN_FIV_PI 3.14159265358979323846

/* phi of the pseudo-angle p in [0, 8] (the inverse of the kernel's p). */
static double pseudo_to_phi(double p)
{
    const int q = p >= 8.0 ? 3 : (int)(p / 2.0);
    double local = q % 2 == 0 ? p - 2.0 * q : 2.0 * (q + 1) - p; /* [0, 2], increasing away from the axis */
    double f = local <= 1.0 ? atan(local) : PN_FIV_PI / 2.0 - atan(2.0 - local);
    return q == 0 ? f : q == 1 ? PN_FIV_PI - f : q == 2 ? PN_FIV_PI + f : 2.0 * PN_FIV_PI - f;
}

/* Per direction bin, the largest cell bound (cell_bounds) over the cells its
 * theta and phi ranges overlap, widened by one cell on every side against
 * rounding of the kernel's bin and cell indices, and by 1e-4 in value. A
 * pair beyond the grid whose bin bound x fall-off is below the floor would
 * be culled by its cell's bound too: the test only saves the angles. */
static void bin_bounds(const struct pn_fiv_impl *f, const float *cells, float *out)
{
    const int nt = (int)f->options.theta, np = (int)f->options.phi;
    for (int bz = 0; bz < PN_FIV_BINS_Z; ++bz) {
        /* theta decreases with cos theta */
        const double th_lo = acos(fmin(1.0, -1.0 + 2.0 * (bz + 1) / PN_FIV_BINS_Z));
        const double th_hi = acos(fmax(-1.0, -1.0 + 2.0 * bz / PN_FIV_BINS_Z));
        const int i0 = (int)fmax(0.0, floor(th_lo * (nt - 1) / PN_FIV_PI) - 1.0);
        const int i1 = (int)fmin(nt - 2.0, floor(th_hi * (nt - 1) / PN_FIV_PI) + 1.0);
        for (int bp = 0; bp < PN_FIV_BINS_P; ++bp) {
            const double ph_lo = pseudo_to_phi(8.0 * bp / PN_FIV_BINS_P);
            const double ph_hi = pseudo_to_phi(8.0 * (bp + 1) / PN_FIV_BINS_P);
            const int j0 = (int)floor(ph_lo * np / (2.0 * PN_FIV_PI)) - 1;
            const int j1 = (int)floor(ph_hi * np / (2.0 * PN_FIV_PI)) + 1;
            float largest = 0.0f;
            for (int i = i0; i <= i1; ++i)
                for (int j = j0; j <= j1; ++j)
                    largest = fmaxf(largest, cells[(size_t)i * np + (size_t)((j % np + np) % np)]);
            out[bz * PN_FIV_BINS_P + bp] = largest * 1.0001f;
        }
    }
}

/* Concatenates the scene's fields as stored on the device, float32 whatever
 * the bake's precision (a half-float field's values, value / value_scale,
 * converted exactly: the lookup multiplies each tap's 9 values by its
 * weights straight from memory, kernels/fiv.cl, pn_fiv_add8_all), each at a
 * 16-byte aligned offset and followed by its cell bounds and its
 * direction-bin bounds (float, 16-byte aligned); rebuilt when the list
 * changes. */
static pn_status upload_fields(state *cache, pn_scene scene)
{
    pn_context ctx = scene->obj.ctx;
    if (cache->data && cache->list_version == scene->attachment_version)
        return PN_SUCCESS;
    pn_status st = collect_fields(cache, scene);
    if (st)
        return st;
    size_t total = 0;
    for (uint32_t i = 0; i < cache->field_count; ++i) {
        const pn_fiv f = cache->fields[i];
        total += ((size_t)pn_fiv_sample_count(&f->options) * 9u * sizeof(float) + 15u) & ~(size_t)15u;
        total += (cell_bound_count(f) * sizeof(float) + 15u) & ~(size_t)15u;
        total += PN_FIV_BINS_Z * PN_FIV_BINS_P * sizeof(float);
    }
    unsigned char *host = pn_malloc(ctx, total ? total : 16, "the occlusion fields");
    if (!host)
        return PN_ERROR_OUT_OF_MEMORY;
    memset(host, 0, total ? total : 16);
    free(cache->offsets);
    cache->offsets = pn_malloc(ctx, pn_mul_size(cache->field_count ? cache->field_count : 1, 1, sizeof(uint32_t)),
                               "field offsets");
    if (!cache->offsets) {
        free(host);
        return PN_ERROR_OUT_OF_MEMORY;
    }
    size_t at = 0;
    for (uint32_t i = 0; i < cache->field_count; ++i) {
        const pn_fiv f = cache->fields[i];
        const size_t n = (size_t)pn_fiv_sample_count(&f->options) * 9u;
        cache->offsets[i] = (uint32_t)at;
        if (f->options.precision == PN_PRECISION_FLOAT16) {
            float *h = (float *)(void *)(host + at);
            for (size_t k = 0; k < n; ++k)
                h[k] = pn_float_from_half(pn_half_from_float(f->samples[k] / f->value_scale));
        } else {
            memcpy(host + at, f->samples, n * 4u);
        }
        at += (n * 4u + 15u) & ~(size_t)15u;
        float *cells = (float *)(void *)(host + at);
        cell_bounds(f, cells);
        at += (cell_bound_count(f) * sizeof(float) + 15u) & ~(size_t)15u;
        bin_bounds(f, cells, (float *)(void *)(host + at));
        at += PN_FIV_BINS_Z * PN_FIV_BINS_P * sizeof(float);
    }
    if (total > UINT32_MAX) {
        free(host);
        return pn_fail(ctx, PN_ERROR_INVALID_SIZE, "the scene's occlusion fields take %zu bytes, more than 4 GiB", total);
    }
    pn_mem_release(&cache->data);
    st = pn_alloc(ctx, total ? total : 16, CL_MEM_READ_ONLY, host, &cache->data, "the occlusion fields");
    free(host);
    if (!st)
        cache->list_version = scene->attachment_version;
    return st;
}

/* FIV(Env) = sum L w dw and the reference irradiance E_ref = max over
 * channels of sum L dw / 4 (a constant env of the same power gives E = E_ref)
 * from the env's cube, in double; recomputed when the env map changes. */
static pn_status env_vectors(state *cache, pn_envmap env)
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

static pn_status plan(pn_renderer r, pn_scene scene)
{
    state *s = r->state;
    pn_envmap env = scene->env;
    pn_status st;
    if ((st = upload_fields(s, scene)) || (st = env_vectors(s, env)))
        return st;
    for (uint32_t i = 0; i < s->field_count; ++i)
        if (s->fields[i]->env_hash != env->content_hash)
            return pn_fail(r->obj.ctx, PN_ERROR_INVALID_ARGUMENT,
                           "occlusion field %u was baked under env map %016llx but the scene's env map is %016llx "
                           "(another image, rotation, intensity or supersampling): bake it again for this env map",
                           i, (unsigned long long)s->fields[i]->env_hash, (unsigned long long)env->content_hash);
    return PN_SUCCESS;
}

/* One record per occluder instance (instance order). */
static pn_status build_records(pn_renderer r, pn_scene scene, uint32_t *count_out)
{
    state *s = r->state;
    pn_context ctx = r->obj.ctx;
    const float cull_threshold = (float)r->params[P_CULL_THRESHOLD];
    const size_t bytes = (size_t)(scene->attachment_count ? scene->attachment_count : 1) * 16 * sizeof(float);
    if (bytes > s->records_capacity) {
        free(s->records);
        s->records_capacity = 0;
        if (!(s->records = pn_malloc(ctx, bytes, "occluder records")))
            return PN_ERROR_OUT_OF_MEMORY;
        s->records_capacity = bytes;
    }
    uint32_t count = 0;
    for (uint32_t ai = 0; ai < scene->attachment_count; ++ai) {
        const pn_attachment *a = &scene->attachments[ai];
        if (!is_field(a))
            continue;
        const uint32_t id = a->instance, fi = field_index(s, a->asset);
        const pn_fiv f = s->fields[fi];
        const pn_instance *inst = pn_scene_instance(scene, id);
        if (inst->mesh->content_hash != f->mesh_hash) /* the mesh was given new geometry after the attach */
            return pn_fail(ctx, PN_ERROR_INVALID_ARGUMENT,
                           "instance %u's mesh is now %016llx but its occlusion field was baked for %016llx: bake "
                           "the field again and attach it",
                           id, (unsigned long long)inst->mesh->content_hash, (unsigned long long)f->mesh_hash);
        const float sc = pn_uniform_scale(inst->object_to_world);
        if (sc == 0.0f)
            return pn_fail(ctx, PN_ERROR_UNSUPPORTED,
                           "instance %u is an occluder with an occlusion field but its transform rotates, shears, "
                           "mirrors or scales unevenly: a field encodes the fixed environment in the occluder's "
                           "frame, so the fiv method takes translations and uniform scales only",
                           id);
        float *rec = s->records + (size_t)count * 16;
        const float *m = inst->object_to_world;
        for (int c = 0; c < 3; ++c)
            rec[c] = m[4 * c] * f->centre[0] + m[4 * c + 1] * f->centre[1] + m[4 * c + 2] * f->centre[2] + m[4 * c + 3];
        rec[3] = sc * f->radius;
        rec[4] = 1.0f / sc;
        rec[5] = f->inner;
        rec[6] = (float)log((double)f->outer / (double)f->inner);
        /* Beyond the grid the contribution falls as (outer / rho)^2 from at
         * most outer_max: cull where it drops below the threshold. */
        float cull = INFINITY;
        if (cull_threshold > 0.0f) {
            const float floor_e = cull_threshold * s->env_ref;
            cull = f->outer * sqrtf(fmaxf(f->outer_max / fmaxf(floor_e, 1e-30f), 1.0f));
        }
        rec[7] = sc * cull;
        const uint32_t u[6] = {s->offsets[fi], f->options.theta, f->options.phi, f->options.radii, id, 0u};
        memcpy(rec + 8, u, 4 * sizeof(uint32_t));
        memcpy(rec + 12, u + 4, 2 * sizeof(uint32_t));
        rec[14] = f->options.precision == PN_PRECISION_FLOAT16 ? f->value_scale : 1.0f;
        rec[15] = f->outer; /* rho_max, object units */
        ++count;
    }
    *count_out = count;
    return PN_SUCCESS;
}

static pn_status execute(pn_renderer r, pn_scene scene, pn_gbuffer gb, pn_image image)
{
    pn_context ctx = r->obj.ctx;
    state *s = r->state;
    pn_envmap env = scene->env;
    cl_kernel k;
    uint32_t occluder_count = 0;
    pn_status st;
    if ((st = pn_context_kernel(ctx, "fiv", "shade_fiv", &k)) || (st = build_records(r, scene, &occluder_count)))
        return st;
    const size_t bytes = (size_t)(occluder_count ? occluder_count : 1) * 16 * sizeof(float);
    if (bytes > s->device_capacity) {
        pn_mem_release(&s->device_records);
        s->device_capacity = 0;
        if ((st = pn_alloc(ctx, bytes, CL_MEM_READ_ONLY, NULL, &s->device_records, "occluder records")))
            return st;
        s->device_capacity = bytes;
    }
    if (occluder_count &&
        (st = pn_upload_async(ctx, s->device_records, s->records, (size_t)occluder_count * 64, "uploading occluder records")))
        return st;
    const cl_int count = (cl_int)(gb->width * gb->height), m = env->irradiance_face_size;
    const cl_int occluders = (cl_int)occluder_count;
    const cl_int overlap = (cl_int)r->params[P_OVERLAP], partial = (cl_int)r->params[P_PARTIAL];
    const cl_int self_shadow = (cl_int)r->params[P_SELF_SHADOW], trilinear = (cl_int)r->params[P_TRILINEAR];
    const cl_int width = (cl_int)gb->width, height = (cl_int)gb->height;
    /* 16x16 tiles, a 32-bit word per 32 occluders each. */
    const size_t tiles = (size_t)((gb->width + 15) / 16) * ((gb->height + 15) / 16);
    const size_t mask_bytes = pn_mul_size(tiles, (occluder_count + 31u) / 32u, sizeof(cl_uint));
    /* One occluder: a tile's bit costs what the pixel's own distance test
     * does, and the binning pass is pure overhead. */
    const cl_int binned = r->params[P_TILE_CULL] != 0 && occluder_count > 1;
    if (mask_bytes == SIZE_MAX)
        return pn_fail(ctx, PN_ERROR_INVALID_SIZE,
                       "the per-tile occluder masks of %u occluders over %zu tiles overflow", occluder_count, tiles);
    if (binned && mask_bytes > s->tile_capacity) {
        pn_mem_release(&s->tile_masks);
        s->tile_capacity = 0;
        if ((st = pn_alloc(ctx, mask_bytes, CL_MEM_READ_WRITE, NULL, &s->tile_masks, "per-tile occluder masks")))
            return st;
        s->tile_capacity = mask_bytes;
    }
    if (!s->tile_masks) { /* a valid argument when unbinned; never read */
        if ((st = pn_alloc(ctx, 16, CL_MEM_READ_WRITE, NULL, &s->tile_masks, "per-tile occluder masks")))
            return st;
        s->tile_capacity = 16;
    }
    if (binned) {
        cl_kernel kb;
        size_t bsizes[] = {sizeof(cl_mem), sizeof(cl_mem), sizeof width, sizeof height,
                           sizeof(cl_mem), sizeof occluders, sizeof(cl_mem)};
        const void *bvals[] = {&gb->planes[PN_GBUFFER_POSITION], &gb->planes[PN_GBUFFER_INSTANCE], &width, &height,
                               &s->device_records, &occluders, &s->tile_masks};
        if ((st = pn_context_kernel(ctx, "fiv", "bin_fiv_tiles", &kb)) ||
            (st = pn_set_args(ctx, kb, "bin_fiv_tiles", 7, bsizes, bvals)) ||
            (st = pn_enqueue_1d(ctx, kb, "bin_fiv_tiles", tiles, 16)))
            return st;
    }
    /* Per-direction culling floor (pn_fiv_lookup): 0 culls nothing. */
    const cl_float cull_floor = (cl_float)(r->params[P_CULL_THRESHOLD] * s->env_ref);
    cl_float4 env_fiv[3];
    for (int a = 0; a < 3; ++a)
        for (int c = 0; c < 4; ++c)
            env_fiv[a].s[c] = c < 3 ? s->env_fiv[3 * a + c] : 0.0f;
    /* The background is drawn by shade_fiv itself, in the same visit of the
     * pixels (draws_background; the renderer runs no background pass). */
    const cl_int background = r->params[P_BACKGROUND] != 0.0;
    const cl_int lat_w = (cl_int)env->width, lat_h = (cl_int)env->height;
    const cl_float2 rot = pn_envmap_rotation(env);
    const cl_int row_groups = PN_FIV_ROW_GROUPS, max_overlap = (cl_int)r->params[P_MAX_OVERLAP];
    size_t sizes[] = {sizeof(cl_mem), sizeof(cl_mem), sizeof(cl_mem), sizeof(cl_mem), sizeof count, sizeof(cl_mem),
                      sizeof m, sizeof(cl_mem), sizeof occluders, sizeof(cl_mem), sizeof cull_floor,
                      sizeof env_fiv[0], sizeof env_fiv[1], sizeof env_fiv[2], sizeof overlap, sizeof partial,
                      sizeof self_shadow, sizeof trilinear, sizeof width, sizeof binned, sizeof(cl_mem),
                      sizeof(cl_mem), sizeof background, sizeof(cl_mem), sizeof lat_w, sizeof lat_h, sizeof rot,
                      sizeof env->intensity, sizeof row_groups, sizeof max_overlap};
    const void *vals[] = {&gb->planes[PN_GBUFFER_POSITION], &gb->planes[PN_GBUFFER_NORMAL],
                          &gb->planes[PN_GBUFFER_ALBEDO], &gb->planes[PN_GBUFFER_INSTANCE], &count, &env->irradiance,
                          &m, &s->device_records, &occluders, &s->data, &cull_floor, &env_fiv[0],
                          &env_fiv[1], &env_fiv[2], &overlap, &partial, &self_shadow, &trilinear, &width, &binned,
                          &s->tile_masks, &image->buffer, &background, &env->latlong, &lat_w, &lat_h, &rot,
                          &env->intensity, &row_groups, &max_overlap};
    if ((st = pn_set_args(ctx, k, "shade_fiv", 30, sizes, vals)))
        return st;
    /* PN_FIV_ROW_GROUPS groups of 8 pixels of a row per work-item (vector
     * lanes, kernels/fiv.cl), one work-item per work-group: PoCL then runs no
     * loop over work-items around the kernel's own loops, which measured 7 %
     * less CPU time than work-groups of 8 (docs/performance.md, FIV). */
    const size_t groups = (gb->width + 7) / 8;
    const size_t items = (groups + PN_FIV_ROW_GROUPS - 1) / PN_FIV_ROW_GROUPS * gb->height;
    return pn_enqueue_1d(ctx, k, "shade_fiv", items, 1);
}

static pn_status create(pn_renderer r)
{
    state *s = r->state;
    s->env_version = UINT64_MAX;
    return PN_SUCCESS;
}

static void destroy(pn_renderer r)
{
    state *s = r->state;
    pn_mem_release(&s->data);
    pn_mem_release(&s->device_records);
    pn_mem_release(&s->tile_masks);
    free(s->records);
    free(s->offsets);
    free(s->fields);
}

const pn_method_desc pn_method_fiv = {
    .name = "fiv",
    .summary = "Fullsphere Irradiance Vectors: diffuse env lighting with soft shadows and self-shadows from the "
               "occlusion fields attached to instances",
    .stage = "fiv",
    .doc_page = "docs/fiv.md",
    .params = params,
    .param_count = (int)(sizeof params / sizeof params[0]),
    .bake_params = pn_fiv_bake_params,
    .bake_param_count = PN_FIV_BAKE_PARAM_COUNT,
    .inputs = PN_INPUT_ENVMAP | PN_INPUT_FIV,
    .draws_background = true,
    .state_size = sizeof(state),
    .create = create,
    .destroy = destroy,
    .plan = plan,
    .execute = execute,
};
