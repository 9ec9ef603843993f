/* Decomposition of an env map into directional domains (docs/depthmap.md,
 * float64 twin tests/depthmap64.py): initial samples by power, weighted
 * Lloyd relaxation on the sphere, per-domain radiance, solid angle and cap
 * radius. Sampling and Lloyd's control loop run on the host in double; the
 * texel -> nearest-centre assignment, the costly part (texels x centres), on
 * the device (kernels/env_domains.cl).
 *
 * Texels: the lat-long texels of the map as given, not the committed cube.
 * They are the input itself (no resampling filter), so a one-texel sun keeps
 * its exact direction and power, the twin works on the same texels, and the
 * result does not depend on the face_size chosen for other stages. */
#include "core/core.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#define PI 3.14159265358979323846
#define TILE 8 /* texels per side of the assignment kernel's tiles */
#define MAX_ITERATIONS 10000

/* ------------------------------------------------------------- the texels */

/* Host view of the lat-long texels: directions from per-column and per-row
 * tables (d = (sin phi sin theta, cos theta, -cos phi sin theta), the twin's
 * latlong_directions), solid angle per row, weight = luminance x solid angle. */
typedef struct texels {
    uint32_t width, height;
    size_t count;
    float *rgb;                     /* count x 3, as stored */
    double *sin_phi, *cos_phi;      /* width */
    double *sin_theta, *cos_theta;  /* height */
    double *omega;                  /* height: solid angle of a texel of each row */
    double *weight;                 /* count */
    size_t nonblack;
} texels;

static void texels_free(texels *t)
{
    free(t->rgb);
    free(t->sin_phi);
    free(t->cos_phi);
    free(t->sin_theta);
    free(t->cos_theta);
    free(t->omega);
    free(t->weight);
    memset(t, 0, sizeof *t);
}

/* Rec. 709 luminance (pn_luminance), in double. */
static double luminance64(const float *l)
{
    return 0.2126 * l[0] + 0.7152 * l[1] + 0.0722 * l[2];
}

static void texel_dir(const texels *t, size_t k, double d[3])
{
    const size_t j = k / t->width, i = k % t->width;
    d[0] = t->sin_phi[i] * t->sin_theta[j];
    d[1] = t->cos_theta[j];
    d[2] = -t->cos_phi[i] * t->sin_theta[j];
}

/* The tables and weights of t->rgb (t->width, t->height, t->count set);
 * `dark` (an intensity of 0) makes every texel black as lit. */
static pn_status texels_init(pn_context ctx, texels *t, bool dark)
{
    t->sin_phi = pn_malloc(ctx, t->width * sizeof(double), "the texel column table");
    t->cos_phi = pn_malloc(ctx, t->width * sizeof(double), "the texel column table");
    t->sin_theta = pn_malloc(ctx, t->height * sizeof(double), "the texel row table");
    t->cos_theta = pn_malloc(ctx, t->height * sizeof(double), "the texel row table");
    t->omega = pn_malloc(ctx, t->height * sizeof(double), "the texel solid angles");
    t->weight = pn_malloc(ctx, t->count * sizeof(double), "the texel weights");
    if (!t->sin_phi || !t->cos_phi || !t->sin_theta || !t->cos_theta || !t->omega || !t->weight)
        return PN_ERROR_OUT_OF_MEMORY;
    for (uint32_t i = 0; i < t->width; ++i) {
        double phi = 2.0 * PI * (i + 0.5) / t->width;
        t->sin_phi[i] = sin(phi);
        t->cos_phi[i] = cos(phi);
    }
    for (uint32_t j = 0; j < t->height; ++j) {
        double theta = PI * (j + 0.5) / t->height;
        t->sin_theta[j] = sin(theta);
        t->cos_theta[j] = cos(theta);
        /* (2 pi / W)(cos theta_j - cos theta_j+1), the twin's latlong_row_solid_angles */
        t->omega[j] = (2.0 * PI / t->width) * (cos(PI * j / t->height) - cos(PI * (j + 1.0) / t->height));
    }
    t->nonblack = 0;
    for (size_t k = 0; k < t->count; ++k) {
        t->weight[k] = dark ? 0.0 : luminance64(t->rgb + 3 * k) * t->omega[k / t->width];
        t->nonblack += t->weight[k] > 0.0;
    }
    return PN_SUCCESS;
}

/* The env map's lat-long texels, read back from the device. */
static pn_status texels_read(pn_envmap env, texels *t)
{
    pn_context ctx = env->obj.ctx;
    memset(t, 0, sizeof *t);
    t->width = env->width;
    t->height = env->height;
    t->count = (size_t)env->width * env->height;
    t->rgb = pn_malloc(ctx, t->count * 3 * sizeof(float), "the lat-long texels");
    if (!t->rgb)
        return PN_ERROR_OUT_OF_MEMORY;
    cl_int err = clEnqueueReadBuffer(ctx->queue, env->latlong, CL_TRUE, 0, t->count * 3 * sizeof(float), t->rgb, 0,
                                     NULL, NULL);
    if (err != CL_SUCCESS)
        return pn_fail_cl(ctx, err, "reading the lat-long env map for its decomposition");
    return texels_init(ctx, t, env->intensity == 0.0f);
}

/* -------------------------------------------------------- initial samples */

static uint64_t splitmix64(uint64_t x)
{
    uint64_t z = x + 0x9E3779B97F4A7C15ull;
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
    return z ^ (z >> 31);
}

typedef struct sample_key {
    double key;
    size_t index;
} sample_key;

static bool key_less(const sample_key *a, const sample_key *b)
{
    return a->key < b->key || (a->key == b->key && a->index < b->index);
}

static int key_compare(const void *a, const void *b)
{
    const sample_key *x = a, *y = b;
    return key_less(x, y) ? -1 : key_less(y, x) ? 1 : 0;
}

/* Restores the max-heap of heap[0..n) below `at`. */
static void sift_down(sample_key *heap, size_t n, size_t at)
{
    for (;;) {
        size_t big = at, l = 2 * at + 1, r = l + 1;
        if (l < n && key_less(&heap[big], &heap[l]))
            big = l;
        if (r < n && key_less(&heap[big], &heap[r]))
            big = r;
        if (big == at)
            return;
        sample_key tmp = heap[at];
        heap[at] = heap[big];
        heap[big] = tmp;
        at = big;
    }
}

/* The n texels of smallest key -log(u_k) / w_k, u_k = ((splitmix64(seed 2^32 + k)
 * >> 11) + 0.5) 2^-53: a draw without replacement with probability
 * proportional to weight (Efraimidis-Spirakis), in increasing key order (ties
 * to the lower index) as the twin's initial_samples. Black texels never drawn. */
static void initial_samples(const texels *t, uint32_t n, uint32_t seed, sample_key *heap)
{
    const uint64_t base = (uint64_t)seed << 32;
    size_t used = 0;
    for (size_t k = 0; k < t->count; ++k) {
        if (!(t->weight[k] > 0.0))
            continue;
        const double u = ((double)(splitmix64(base + k) >> 11) + 0.5) * 0x1p-53;
        const sample_key s = {-log(u) / t->weight[k], k};
        if (used < n) {
            heap[used++] = s;
            for (size_t at = used - 1; at > 0 && key_less(&heap[(at - 1) / 2], &heap[at]); at = (at - 1) / 2) {
                sample_key tmp = heap[at];
                heap[at] = heap[(at - 1) / 2];
                heap[(at - 1) / 2] = tmp;
            }
        } else if (key_less(&s, &heap[0])) {
            heap[0] = s;
            sift_down(heap, n, 0);
        }
    }
    qsort(heap, n, sizeof *heap, key_compare);
}

/* ------------------------------------------------------------ Lloyd */

/* Device side of the assignment: texel directions, tile cones, centres, the
 * assignment, and the kernel. */
typedef struct assigner {
    cl_mem dirs, cones, centres, assignment;
    cl_kernel kernel;
    size_t tiles;
} assigner;

static void assigner_free(assigner *a)
{
    pn_mem_release(&a->dirs);
    pn_mem_release(&a->cones);
    pn_mem_release(&a->centres);
    pn_mem_release(&a->assignment);
}

/* Uploads the texel directions (float) and, per TILE x TILE tile, a cone
 * (unit axis, half-angle beta) holding them, for the kernel's culling. */
static pn_status assigner_new(pn_context ctx, const texels *t, assigner *a)
{
    memset(a, 0, sizeof *a);
    const size_t tiles_x = (t->width + TILE - 1) / TILE, tiles_y = (t->height + TILE - 1) / TILE;
    a->tiles = tiles_x * tiles_y;
    float *dirs = pn_malloc(ctx, pn_mul_size(t->count, 4, sizeof(float)), "the texel directions");
    float *cones = pn_malloc(ctx, pn_mul_size(a->tiles, 4, sizeof(float)), "the texel tile cones");
    pn_status st = dirs && cones ? PN_SUCCESS : PN_ERROR_OUT_OF_MEMORY;
    for (size_t k = 0; !st && k < t->count; ++k) {
        double d[3];
        texel_dir(t, k, d);
        for (int c = 0; c < 3; ++c)
            dirs[4 * k + c] = (float)d[c];
        dirs[4 * k + 3] = 0.0f;
    }
    for (size_t tile = 0; !st && tile < a->tiles; ++tile) {
        const size_t x0 = (tile % tiles_x) * TILE, y0 = (tile / tiles_x) * TILE;
        const size_t x1 = x0 + TILE < t->width ? x0 + TILE : t->width, y1 = y0 + TILE < t->height ? y0 + TILE : t->height;
        double axis[3] = {0, 0, 0}, d[3];
        for (size_t y = y0; y < y1; ++y)
            for (size_t x = x0; x < x1; ++x) {
                texel_dir(t, y * t->width + x, d);
                for (int c = 0; c < 3; ++c)
                    axis[c] += d[c];
            }
        double len = sqrt(axis[0] * axis[0] + axis[1] * axis[1] + axis[2] * axis[2]);
        double beta = PI; /* opposite texels (a 2-wide map): no culling */
        if (len > 1e-9) {
            double lo = 1.0;
            for (int c = 0; c < 3; ++c)
                axis[c] /= len;
            for (size_t y = y0; y < y1; ++y)
                for (size_t x = x0; x < x1; ++x) {
                    texel_dir(t, y * t->width + x, d);
                    lo = fmin(lo, axis[0] * d[0] + axis[1] * d[1] + axis[2] * d[2]);
                }
            /* + 1e-6: the float texel directions and axis are off by ~1e-7 */
            beta = acos(fmax(-1.0, fmin(1.0, lo))) + 1e-6;
        } else {
            axis[0] = 0.0, axis[1] = 1.0, axis[2] = 0.0;
        }
        for (int c = 0; c < 3; ++c)
            cones[4 * tile + c] = (float)axis[c];
        cones[4 * tile + 3] = (float)beta;
    }
    if (!st)
        st = pn_alloc(ctx, t->count * 16, CL_MEM_READ_ONLY, dirs, &a->dirs, "the texel directions");
    if (!st)
        st = pn_alloc(ctx, a->tiles * 16, CL_MEM_READ_ONLY, cones, &a->cones, "the texel tile cones");
    if (!st)
        st = pn_alloc(ctx, PN_ENV_DOMAINS_MAX * 16, CL_MEM_READ_ONLY, NULL, &a->centres, "the domain centres");
    if (!st)
        st = pn_alloc(ctx, t->count * sizeof(cl_int), CL_MEM_WRITE_ONLY, NULL, &a->assignment, "the texel assignment");
    if (!st)
        st = pn_context_kernel(ctx, "env_domains", "env_domains_assign", &a->kernel);
    free(dirs);
    free(cones);
    if (st)
        assigner_free(a);
    return st;
}

/* assignment[k] = the centre nearest texel k (largest dot, ties to the lowest index). */
static pn_status assign(pn_context ctx, const texels *t, assigner *a, const double *centres, uint32_t n,
                        int32_t *assignment)
{
    float c[4 * PN_ENV_DOMAINS_MAX];
    for (uint32_t i = 0; i < n; ++i) {
        for (int q = 0; q < 3; ++q)
            c[4 * i + q] = (float)centres[3 * i + q];
        c[4 * i + 3] = 0.0f;
    }
    cl_int err = clEnqueueWriteBuffer(ctx->queue, a->centres, CL_FALSE, 0, n * 16, c, 0, NULL, NULL);
    if (err != CL_SUCCESS)
        return pn_fail_cl(ctx, err, "uploading the domain centres");
    const cl_int w = (cl_int)t->width, h = (cl_int)t->height, tile = TILE, count = (cl_int)n;
    size_t sizes[] = {sizeof(cl_mem), sizeof w, sizeof h, sizeof tile, sizeof tile, sizeof(cl_mem), sizeof(cl_mem),
                      sizeof count, sizeof(cl_mem)};
    const void *vals[] = {&a->dirs, &w, &h, &tile, &tile, &a->cones, &a->centres, &count, &a->assignment};
    pn_status st;
    /* 64 work-items per tile: PN_ENV_GROUP in the kernel */
    if ((st = pn_set_args(ctx, a->kernel, "env_domains_assign", 9, sizes, vals)) ||
        (st = pn_enqueue_1d(ctx, a->kernel, "env_domains_assign", a->tiles * 64, 64)))
        return st;
    err = clEnqueueReadBuffer(ctx->queue, a->assignment, CL_TRUE, 0, t->count * sizeof(cl_int), assignment, 0, NULL,
                              NULL);
    return err == CL_SUCCESS ? PN_SUCCESS : pn_fail_cl(ctx, err, "reading the texel assignment");
}

/* Moves each centre to its cell's normalised weighted mean direction
 * sum w_k d_k / |sum w_k d_k|; a cell with no weight keeps its centre. */
static void weighted_means(const texels *t, const int32_t *assignment, uint32_t n, double *sums, double *centres)
{
    memset(sums, 0, 3 * n * sizeof(double));
    for (size_t k = 0; k < t->count; ++k) {
        const double w = t->weight[k];
        if (!(w > 0.0))
            continue;
        double d[3];
        texel_dir(t, k, d);
        double *s = sums + 3 * assignment[k];
        for (int c = 0; c < 3; ++c)
            s[c] += w * d[c];
    }
    for (uint32_t i = 0; i < n; ++i) {
        const double *s = sums + 3 * i;
        double len = sqrt(s[0] * s[0] + s[1] * s[1] + s[2] * s[2]);
        if (len > 0.0)
            for (int c = 0; c < 3; ++c)
                centres[3 * i + c] = s[c] / len;
    }
}

/* -------------------------------------------------------- the decomposition */

static void decomposition_free(pn_env_decomposition *d)
{
    if (!d)
        return;
    free(d->domains);
    free(d->assignment);
    free(d);
}

void pn_envmap_forget_domains(pn_envmap env)
{
    decomposition_free(env->decomposition);
    env->decomposition = NULL;
    decomposition_free(env->split);
    env->split = NULL;
}

static pn_status check_options(pn_envmap env, const pn_env_decompose_options *o)
{
    pn_context ctx = env->obj.ctx;
    if (!env->committed)
        return pn_fail(ctx, PN_ERROR_NOT_COMMITTED, "env map changed since its last commit; call pn_envmap_commit");
    if (o->count < 1 || o->count > PN_ENV_DOMAINS_MAX)
        return pn_fail(ctx, PN_ERROR_INVALID_ARGUMENT, "env map decomposition into %u domains: the count must be 1..%d",
                       o->count, PN_ENV_DOMAINS_MAX);
    if (o->max_iterations > MAX_ITERATIONS)
        return pn_fail(ctx, PN_ERROR_INVALID_ARGUMENT, "env map decomposition: max_iterations %u exceeds %d",
                       o->max_iterations, MAX_ITERATIONS);
    return PN_SUCCESS;
}

/* Everything after the texels are read: draw, relax, sum. */
static pn_status decompose(pn_envmap env, const texels *t, const pn_env_decompose_options *o,
                           pn_env_decomposition *out)
{
    pn_context ctx = env->obj.ctx;
    const uint32_t n = o->count, max_iter = o->max_iterations ? o->max_iterations : PN_ENV_LLOYD_DEFAULT_ITERATIONS;
    if (n > t->nonblack)
        return pn_fail(ctx, PN_ERROR_INVALID_ARGUMENT,
                       "%u directions requested but the env map has only %zu non-black texels%s", n, t->nonblack,
                       t->nonblack == 0 ? (env->intensity == 0.0f ? " (its intensity is 0)" : " (it is black)") : "");
    sample_key *heap = pn_malloc(ctx, n * sizeof *heap, "the initial samples");
    double *centres = pn_malloc(ctx, 3 * n * sizeof(double), "the domain centres");
    double *sums = pn_malloc(ctx, 3 * n * sizeof(double), "the domain sums");
    double *omega = pn_malloc(ctx, n * sizeof(double), "the domain solid angles");
    int32_t *next = pn_malloc(ctx, t->count * sizeof(int32_t), "the texel assignment");
    out->assignment = pn_malloc(ctx, t->count * sizeof(int32_t), "the texel assignment");
    out->domains = pn_malloc(ctx, n * sizeof(pn_env_domain), "the env domains");
    assigner a = {0};
    pn_status st = heap && centres && sums && omega && next && out->assignment && out->domains ? PN_SUCCESS
                                                                                                  : PN_ERROR_OUT_OF_MEMORY;
    if (!st) {
        initial_samples(t, n, o->seed, heap);
        for (uint32_t i = 0; i < n; ++i)
            texel_dir(t, heap[i].index, centres + 3 * i);
        st = assigner_new(ctx, t, &a);
    }
    if (!st)
        st = assign(ctx, t, &a, centres, n, out->assignment);
    /* The twin's lloyd(): means, reassign, stop when no texel changed cell;
     * the centres and the assignment kept always belong together. */
    out->iterations = 0;
    out->converged = false;
    while (!st && out->iterations < max_iter) {
        ++out->iterations;
        weighted_means(t, out->assignment, n, sums, centres);
        if ((st = assign(ctx, t, &a, centres, n, next)))
            break;
        if (!memcmp(next, out->assignment, t->count * sizeof(int32_t))) {
            out->converged = true;
            break;
        }
        int32_t *tmp = out->assignment;
        out->assignment = next;
        next = tmp;
    }
    if (!st) {
        /* Domain sums: radiance x solid angle and solid angle of every texel. */
        memset(sums, 0, 3 * n * sizeof(double));
        memset(omega, 0, n * sizeof(double));
        for (size_t k = 0; k < t->count; ++k) {
            const int32_t i = out->assignment[k];
            const double w = t->omega[k / t->width];
            for (int c = 0; c < 3; ++c)
                sums[3 * i + c] += t->rgb[3 * k + c] * w;
            omega[i] += w;
        }
        /* The map frame to the world: world d = R_y(angle) m (envmap.cl sees the map at R_y(-angle) d). */
        const double angle = (double)env->rotation_deg * PI / 180.0, cr = cos(angle), sr = sin(angle);
        for (uint32_t i = 0; i < n; ++i) {
            pn_env_domain *d = &out->domains[i];
            const double *c = centres + 3 * i;
            d->direction[0] = (float)(cr * c[0] + sr * c[2]);
            d->direction[1] = (float)c[1];
            d->direction[2] = (float)(-sr * c[0] + cr * c[2]);
            for (int q = 0; q < 3; ++q)
                d->radiance[q] = (float)(env->intensity * sums[3 * i + q]);
            d->solid_angle = (float)omega[i];
            d->cap_radius = (float)(2.0 * asin(sqrt(fmin(fmax(omega[i] / (4.0 * PI), 0.0), 1.0))));
        }
        out->count = n;
    }
    assigner_free(&a);
    free(heap);
    free(centres);
    free(sums);
    free(omega);
    free(next);
    return st;
}

pn_status pn_envmap_domains(pn_envmap env, const pn_env_decompose_options *options, const pn_env_decomposition **out)
{
    pn_context ctx = env->obj.ctx;
    pn_status st = check_options(env, options);
    if (st)
        return st;
    const pn_env_decomposition *cached = env->decomposition;
    if (cached && env->decomposition_hash == env->content_hash && cached->count == options->count &&
        env->decomposition_seed == options->seed && env->decomposition_iterations == options->max_iterations) {
        *out = cached;
        return PN_SUCCESS;
    }
    pn_envmap_forget_domains(env);
    pn_env_decomposition *d = pn_malloc(ctx, sizeof *d, "an env decomposition");
    if (!d)
        return PN_ERROR_OUT_OF_MEMORY;
    memset(d, 0, sizeof *d);
    texels t;
    if (!(st = texels_read(env, &t)))
        st = decompose(env, &t, options, d);
    texels_free(&t);
    if (st) {
        decomposition_free(d);
        return st;
    }
    env->decomposition = d;
    env->decomposition_hash = env->content_hash;
    env->decomposition_seed = options->seed;
    env->decomposition_iterations = options->max_iterations;
    *out = d;
    return PN_SUCCESS;
}

pn_status pn_envmap_do_decompose(pn_envmap env, const pn_env_decompose_options *options, pn_env_domain *domains,
                                 uint32_t capacity)
{
    pn_context ctx = env->obj.ctx;
    pn_status st = check_options(env, options);
    if (st)
        return st;
    if (capacity < options->count)
        return pn_fail(ctx, PN_ERROR_INVALID_SIZE, "env map decomposition into %u domains: capacity %u is too small",
                       options->count, capacity);
    const pn_env_decomposition *d;
    if ((st = pn_envmap_domains(env, options, &d)))
        return st;
    memcpy(domains, d->domains, d->count * sizeof *domains);
    return PN_SUCCESS;
}

/* ------------------------------------------------------ the sharp part */

/* A texel is hot above this luminance: threshold x the map's mean luminance
 * (sum lum dw / 4 pi); infinite for a black map (nothing is hot). */
static double hot_limit(const texels *t, float threshold)
{
    double mean = 0.0;
    for (size_t k = 0; k < t->count; ++k)
        mean += t->weight[k];
    mean /= 4.0 * PI;
    return mean > 0.0 ? threshold * mean : INFINITY;
}

/* The sharp part of the texels t (pn_envmap_extract_sharp, options checked):
 * at most o->max_count domains in `domains` (*count of them); the hot texels
 * are clipped to the limit in `residual` (3 x t->count floats, which the
 * caller filled with the map). With `label`, only the hot texels whose label
 * is `id` (one connected light, hot_lights) are taken; the others are left
 * as they are. */
static pn_status sharp_part(pn_envmap env, const texels *t, const pn_env_sharp_options *o, const int32_t *label,
                            int32_t id, pn_env_domain *domains, uint32_t *count, float *residual)
{
    pn_context ctx = env->obj.ctx;
    const size_t need = 3 * t->count;
    texels hot = {0};
    pn_env_decomposition d = {0};
    pn_status st = PN_SUCCESS;
    const double limit = hot_limit(t, o->threshold);
    size_t hot_count = 0;
    if (!st) {
        hot.width = t->width;
        hot.height = t->height;
        hot.count = t->count;
        if (!(hot.rgb = pn_malloc(ctx, need * sizeof(float), "the sharp part")))
            st = PN_ERROR_OUT_OF_MEMORY;
    }
    for (size_t k = 0; !st && k < t->count; ++k) {
        const double lum = t->weight[k] > 0.0 ? luminance64(t->rgb + 3 * k) : 0.0;
        for (int c = 0; c < 3; ++c)
            hot.rgb[3 * k + c] = 0.0f;
        if (!(lum > limit) || (label && label[k] != id))
            continue;
        ++hot_count;
        const double keep = limit / lum;
        for (int c = 0; c < 3; ++c) {
            residual[3 * k + c] = (float)(t->rgb[3 * k + c] * keep);
            hot.rgb[3 * k + c] = t->rgb[3 * k + c] - residual[3 * k + c]; /* sum = the map to float rounding */
        }
    }
    if (!st && hot_count > 0)
        st = texels_init(ctx, &hot, false);
    if (!st && hot_count > 0) {
        pn_env_decompose_options dopt = {o->max_count < hot.nonblack ? o->max_count : (uint32_t)hot.nonblack, o->seed,
                                         o->max_iterations};
        if (dopt.count > 0 && !(st = decompose(env, &hot, &dopt, &d))) {
            /* Radiance of each domain's excess, solid angle of its hot texels only. */
            double sums[4 * PN_ENV_SHARP_MAX] = {0};
            for (size_t k = 0; k < hot.count; ++k) {
                if (!(hot.weight[k] > 0.0))
                    continue;
                double *s = sums + 4 * d.assignment[k];
                const double w = hot.omega[k / hot.width];
                for (int c = 0; c < 3; ++c)
                    s[c] += hot.rgb[3 * k + c] * w;
                s[3] += w;
            }
            for (uint32_t i = 0; i < d.count; ++i) {
                domains[i] = d.domains[i]; /* the centre, turned to the world */
                for (int c = 0; c < 3; ++c)
                    domains[i].radiance[c] = (float)(env->intensity * sums[4 * i + c]);
                domains[i].solid_angle = (float)sums[4 * i + 3];
                domains[i].cap_radius = (float)(2.0 * asin(sqrt(fmin(sums[4 * i + 3] / (4.0 * PI), 1.0))));
            }
            *count = d.count;
        }
    }
    free(d.domains);
    free(d.assignment);
    texels_free(&hot);
    return st;
}

/* The map's concentrated light (a sun, lamps) as a few domains, and the rest
 * as a residual lat-long map (pn_envmap_extract_sharp; twin
 * tests/env_sharp64.py). A texel is hot where its luminance exceeds
 * T = threshold x the map's mean luminance (sum lum dw / 4 pi); its luminance
 * is clipped to T in the residual (colour kept: L T / lum) and the excess
 * L (1 - T / lum) goes to the sharp part, so residual + sharp part = the map
 * exactly and the residual's dynamic range is bounded by T. The hot excess is
 * split into at most max_count domains by the same decomposition (power
 * sampling, Lloyd); each domain's solid angle and cap radius are those of its
 * hot texels only (the light's own size, not its Voronoi cell). */
pn_status pn_envmap_do_extract_sharp(pn_envmap env, const pn_env_sharp_options *o, pn_env_domain *domains,
                                     uint32_t capacity, uint32_t *count, float *residual, size_t residual_floats)
{
    pn_context ctx = env->obj.ctx;
    *count = 0;
    if (!env->committed)
        return pn_fail(ctx, PN_ERROR_NOT_COMMITTED, "env map changed since its last commit; call pn_envmap_commit");
    if (o->max_count < 1 || o->max_count > PN_ENV_SHARP_MAX)
        return pn_fail(ctx, PN_ERROR_INVALID_ARGUMENT, "sharp part: max_count %u must be 1..%d", o->max_count,
                       PN_ENV_SHARP_MAX);
    if (!isfinite(o->threshold) || !(o->threshold > 1.0f))
        return pn_fail(ctx, PN_ERROR_INVALID_ARGUMENT,
                       "sharp part: threshold %g must be finite and > 1 (times the map's mean luminance)",
                       (double)o->threshold);
    if (o->max_iterations > MAX_ITERATIONS)
        return pn_fail(ctx, PN_ERROR_INVALID_ARGUMENT, "sharp part: max_iterations %u exceeds %d", o->max_iterations,
                       MAX_ITERATIONS);
    if (capacity < o->max_count)
        return pn_fail(ctx, PN_ERROR_INVALID_SIZE, "sharp part: capacity %u is below max_count %u", capacity,
                       o->max_count);
    const size_t need = 3 * (size_t)env->width * env->height;
    if (residual_floats != need)
        return pn_fail(ctx, PN_ERROR_INVALID_SIZE, "sharp part: the residual map needs %zu floats (%ux%ux3), got %zu",
                       need, env->width, env->height, residual_floats);
    texels t;
    pn_status st = texels_read(env, &t);
    if (!st) {
        memcpy(residual, t.rgb, need * sizeof(float));
        st = sharp_part(env, &t, o, NULL, 0, domains, count, residual);
    }
    texels_free(&t);
    return st;
}

/* Whether hot texels form one compact light: the angle of the mean resultant
 * of their excess-weighted directions is at most twice the cap radius of
 * their solid angle (m: the excess-weighted sum of directions, total: the
 * excess, omega: the solid angle). A sun (0.2-0.7 degrees against 0.5-1.9 on
 * the maps in ../shared/data) is; the windows of an interior taken together
 * are not (30-47 degrees against 3-5): one domain at their power centroid
 * would cast their shadows from between them. */
static bool compact_light(const double m[3], double total, double omega)
{
    const double len = sqrt(m[0] * m[0] + m[1] * m[1] + m[2] * m[2]) / total;
    const double cap = 2.0 * asin(sqrt(fmin(omega / (4.0 * PI), 1.0)));
    return acos(fmin(len, 1.0)) <= 2.0 * cap;
}

/* Whether the map's hot texels (luminance above threshold x the mean), all of
 * them together, form one compact light (compact_light). */
static bool sharp_compact(const texels *t, float threshold)
{
    double m[3] = {0.0, 0.0, 0.0}, total = 0.0, omega = 0.0;
    const double limit = hot_limit(t, threshold);
    for (size_t k = 0; k < t->count; ++k) {
        const double lum = t->weight[k] > 0.0 ? luminance64(t->rgb + 3 * k) : 0.0;
        if (!(lum > limit))
            continue;
        const double w = t->omega[k / t->width], e = (lum - limit) * w;
        double d[3];
        texel_dir(t, k, d);
        for (int c = 0; c < 3; ++c)
            m[c] += e * d[c];
        total += e, omega += w;
    }
    if (!(total > 0.0))
        return true; /* no hot texel: nothing is split off */
    return compact_light(m, total, omega);
}

/* One connected light of hot texels (hot_lights). */
typedef struct hot_light {
    double excess; /* sum (lum - limit) dw, in the map's units */
    int32_t id;    /* its label */
    uint32_t alloc; /* sharp domains given to it */
} hot_light;

static int light_order(const void *a, const void *b)
{
    const hot_light *x = a, *y = b;
    if (x->excess != y->excess)
        return x->excess > y->excess ? -1 : 1;
    return (x->id > y->id) - (x->id < y->id);
}

/* When the hot texels together are not one compact light (an interior's
 * windows, several lamps): their connected components (8-neighbours on the
 * lat-long grid, wrapping in longitude) that are each compact (compact_light)
 * and each hold at least the mean domain power (the map's power / n) are
 * lights of their own. label[k] (t->count) is set to the component of every
 * hot texel (1, 2, ...; 0 elsewhere); lights[] (capacity PN_ENV_SHARP_MAX)
 * gets the qualifying components, the strongest first, at most
 * PN_ENV_SHARP_MAX of them (*count). A component below the mean domain power
 * is left to the decomposition: its Lloyd cell holds it at least as finely as
 * its power deserves, and a sharp domain would cost a strong map. */
static pn_status hot_lights(pn_context ctx, const texels *t, double limit, uint32_t n, int32_t *label,
                            hot_light *lights, uint32_t *count)
{
    *count = 0;
    size_t *stack = pn_malloc(ctx, t->count * sizeof(size_t), "the hot texels' components");
    if (!stack)
        return PN_ERROR_OUT_OF_MEMORY;
    double power = 0.0;
    for (size_t k = 0; k < t->count; ++k) {
        power += t->weight[k];
        label[k] = t->weight[k] > 0.0 && luminance64(t->rgb + 3 * k) > limit ? -1 : 0; /* -1: hot, unlabelled */
    }
    const uint32_t w = t->width, h = t->height;
    hot_light found[PN_ENV_SHARP_MAX];
    uint32_t kept = 0;
    int32_t next = 0;
    for (size_t seed = 0; seed < t->count; ++seed) {
        if (label[seed] != -1)
            continue;
        const int32_t id = ++next;
        double m[3] = {0.0, 0.0, 0.0}, total = 0.0, omega = 0.0;
        size_t top = 0;
        label[seed] = id;
        stack[top++] = seed;
        while (top) {
            const size_t k = stack[--top];
            const uint32_t i = (uint32_t)(k % w), j = (uint32_t)(k / w);
            const double dw = t->omega[j], e = (luminance64(t->rgb + 3 * k) - limit) * dw;
            double d[3];
            texel_dir(t, k, d);
            for (int c = 0; c < 3; ++c)
                m[c] += e * d[c];
            total += e, omega += dw;
            for (int dj = -1; dj <= 1; ++dj) {
                if ((dj < 0 && j == 0) || (dj > 0 && j + 1 >= h))
                    continue;
                for (int di = -1; di <= 1; ++di) {
                    const size_t q = (size_t)(j + dj) * w + (i + w + (uint32_t)(di + 1) - 1) % w;
                    if (label[q] == -1) {
                        label[q] = id;
                        stack[top++] = q;
                    }
                }
            }
        }
        if (!(total > 0.0) || !compact_light(m, total, omega) || !(total >= power / n))
            continue;
        hot_light l = {total, id, 0};
        if (kept < PN_ENV_SHARP_MAX)
            found[kept++] = l;
        else if (light_order(&l, &found[kept - 1]) < 0)
            found[kept - 1] = l;
        qsort(found, kept, sizeof *found, light_order);
    }
    free(stack);
    memcpy(lights, found, kept * sizeof *found);
    *count = kept;
    return PN_SUCCESS;
}

pn_status pn_envmap_domains_split(pn_envmap env, const pn_env_decompose_options *options, uint32_t sharp_max,
                                  float threshold, const pn_env_decomposition **out)
{
    pn_context ctx = env->obj.ctx;
    pn_status st = check_options(env, options);
    if (st)
        return st;
    if (sharp_max < 1 || sharp_max > PN_ENV_SHARP_MAX || sharp_max >= options->count)
        return pn_fail(ctx, PN_ERROR_INVALID_ARGUMENT,
                       "sharp part of %u domains: at most %u sharp domains, 1..%d and below the count", options->count,
                       sharp_max, PN_ENV_SHARP_MAX);
    if (!isfinite(threshold) || !(threshold > 1.0f))
        return pn_fail(ctx, PN_ERROR_INVALID_ARGUMENT,
                       "sharp part: threshold %g must be finite and > 1 (times the map's mean luminance)",
                       (double)threshold);
    const pn_env_decomposition *cached = env->split;
    if (cached && env->split_hash == env->content_hash && env->split_count == options->count &&
        env->split_seed == options->seed && env->split_iterations == options->max_iterations &&
        env->split_sharp == sharp_max && env->split_threshold == threshold) {
        *out = cached;
        return PN_SUCCESS;
    }
    decomposition_free(env->split);
    env->split = NULL;
    pn_env_decomposition *d = pn_malloc(ctx, sizeof *d, "an env decomposition");
    if (!d)
        return PN_ERROR_OUT_OF_MEMORY;
    memset(d, 0, sizeof *d);
    texels t, rest = {0};
    pn_env_decomposition r = {0};
    pn_env_domain sharp[PN_ENV_SHARP_MAX];
    uint32_t k = 0;
    const pn_env_sharp_options so = {sharp_max, threshold, options->seed, options->max_iterations};
    st = texels_read(env, &t);
    if (!st) {
        rest.width = t.width;
        rest.height = t.height;
        rest.count = t.count;
        if (!(rest.rgb = pn_malloc(ctx, t.count * 3 * sizeof(float), "the residual map")))
            st = PN_ERROR_OUT_OF_MEMORY;
    }
    if (!st)
        memcpy(rest.rgb, t.rgb, t.count * 3 * sizeof(float));
    if (!st && sharp_compact(&t, threshold)) {
        st = sharp_part(env, &t, &so, NULL, 0, sharp, &k, rest.rgb);
    } else if (!st) {
        /* Not one light: the compact components that hold a domain's worth
         * each (hot_lights), the strongest first, one sharp domain each while
         * sharp_max lasts; sharp domains beyond one per light go to the light
         * with the most power per domain (as sharp_max > 1 splits a sun). The
         * other hot texels (scattered windows, a band, weak spots) stay in the
         * residual as they are; with no such light the map itself into N. */
        int32_t *label = pn_malloc(ctx, t.count * sizeof(int32_t), "the hot texels' labels");
        hot_light lights[PN_ENV_SHARP_MAX];
        uint32_t m = 0;
        if (!label)
            st = PN_ERROR_OUT_OF_MEMORY;
        if (!st)
            st = hot_lights(ctx, &t, hot_limit(&t, threshold), options->count, label, lights, &m);
        if (m > sharp_max)
            m = sharp_max;
        for (uint32_t i = 0; i < m; ++i)
            lights[i].alloc = 1;
        for (uint32_t extra = m ? sharp_max - m : 0; extra > 0; --extra) {
            uint32_t best = 0;
            for (uint32_t i = 1; i < m; ++i)
                if (lights[i].excess * lights[best].alloc > lights[best].excess * lights[i].alloc)
                    best = i;
            ++lights[best].alloc;
        }
        for (uint32_t i = 0; !st && i < m; ++i) {
            const pn_env_sharp_options lo = {lights[i].alloc, threshold, options->seed, options->max_iterations};
            uint32_t got = 0;
            st = sharp_part(env, &t, &lo, label, lights[i].id, sharp + k, &got, rest.rgb);
            k += got;
        }
        free(label);
    }
    if (!st)
        st = texels_init(ctx, &rest, env->intensity == 0.0f);
    if (!st) {
        /* The residual into the other N - k (no sharp texel: the map itself into N). */
        const pn_env_decompose_options ro = {options->count - k, options->seed, options->max_iterations};
        st = decompose(env, &rest, &ro, &r);
    }
    if (!st && !(d->domains = pn_malloc(ctx, options->count * sizeof *d->domains, "the env domains")))
        st = PN_ERROR_OUT_OF_MEMORY;
    if (!st) {
        memcpy(d->domains, sharp, k * sizeof *sharp);
        memcpy(d->domains + k, r.domains, r.count * sizeof *r.domains);
        d->count = k + r.count;
        d->sharp = k;
        d->iterations = r.iterations;
        d->converged = r.converged;
    }
    free(r.domains);
    free(r.assignment);
    texels_free(&rest);
    texels_free(&t);
    if (st) {
        decomposition_free(d);
        return st;
    }
    env->split = d;
    env->split_hash = env->content_hash;
    env->split_count = options->count;
    env->split_seed = options->seed;
    env->split_iterations = options->max_iterations;
    env->split_sharp = sharp_max;
    env->split_threshold = threshold;
    *out = d;
    return PN_SUCCESS;
}
