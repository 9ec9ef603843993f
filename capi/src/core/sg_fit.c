/* Env map -> K spherical-Gaussian lobes (docs/isg.md 5), in float64 on the
 * host from the committed cube block-averaged to a small face (the commit's
 * area-averaging filter keeps a sun's power in its texel).
 *
 * 1. Power clustering (the default, alone): the texels' power (luminance x
 *    solid angle) split into K clusters on the sphere, farthest-point seeds
 *    weighted by power x distance^2 (a sun's neighbours seed no second
 *    lobe), then Lloyd iterations; each cluster becomes a lobe
 *    that keeps the cluster's RGB power exactly, with the sharpness of its
 *    spread. A sun is the first seed (the most power), and its cluster's
 *    power-weighted spread is the sun's: it gets a lobe of its own.
 * 2. Optional least-squares refinement (`iterations` sweeps) of
 *      sum_i w_i |sum_k a_k G_k(d_i) - L_i|^2,  a_k >= 0 per channel:
 *    each lobe in turn refitted to the residual of the others (mean-shift
 *    step of the axis, multiplicative steps of the sharpness, best
 *    non-negative amplitude; a lobe left unused is placed anew by matching
 *    pursuit), then a joint non-negative least squares of all amplitudes per
 *    channel (projected Gauss-Seidel on the K x K Gram matrix), then a
 *    per-channel rescale to the map's power. It lowers the error against the
 *    map's texels but raises it against the irradiance (docs/isg.md 5). */
#include "core/sg.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#define MIN_SHARPNESS 1e-3
#define AXIS_CANDIDATES 8
#define NNLS_SWEEPS 200
#define PI 3.14159265358979323846

typedef struct texels {
    size_t n;
    double *dir;  /* 3 per texel */
    double *w;    /* solid angle */
    double *rad;  /* RGB radiance */
} texels;

typedef struct lobe64 {
    double axis[3], lambda, amp[3];
} lobe64;

static double dot3(const double *a, const double *b)
{
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}

static double lum(const double *rgb)
{
    return 0.2126 * rgb[0] + 0.7152 * rgb[1] + 0.0722 * rgb[2];
}

/* G of unit amplitude at every texel into g. */
static void eval_lobe(const texels *t, const double *axis, double lambda, double *g)
{
    for (size_t i = 0; i < t->n; ++i) {
        const double x = lambda * (dot3(t->dir + 3 * i, axis) - 1.0);
        g[i] = x > -80.0 ? exp(x) : 0.0; /* e^-80 ~ 2e-35: nothing beside any texel's radiance */
    }
}

/* The best non-negative amplitude of g against residual r per channel and
 * the objective's reduction sum_c <r_c, g>^2 / <g, g> (channels clamped at 0). */
static double best_amplitude(const texels *t, const double *r, const double *g, double *amp)
{
    double gg = 0.0, rg[3] = {0.0, 0.0, 0.0};
    for (size_t i = 0; i < t->n; ++i) {
        const double wg = t->w[i] * g[i];
        gg += wg * g[i];
        for (int c = 0; c < 3; ++c)
            rg[c] += wg * r[3 * i + c];
    }
    double gain = 0.0;
    for (int c = 0; c < 3; ++c) {
        amp[c] = gg > 0.0 && rg[c] > 0.0 ? rg[c] / gg : 0.0;
        gain += amp[c] * rg[c];
    }
    return gain;
}

static void add_lobe(const texels *t, double *r, const double *g, const double *amp, double sign)
{
    for (size_t i = 0; i < t->n; ++i)
        for (int c = 0; c < 3; ++c)
            r[3 * i + c] += sign * amp[c] * g[i];
}

/* The AXIS_CANDIDATES texels of largest residual luminance (ties: lowest index). */
static int top_texels(const texels *t, const double *r, size_t *best)
{
    double val[AXIS_CANDIDATES];
    int count = 0;
    for (size_t i = 0; i < t->n; ++i) {
        const double v = lum(r + 3 * i);
        if (!(v > 0.0))
            continue;
        int pos = count < AXIS_CANDIDATES ? count : AXIS_CANDIDATES;
        while (pos > 0 && val[pos - 1] < v)
            --pos;
        if (pos >= AXIS_CANDIDATES)
            continue;
        for (int k = (count < AXIS_CANDIDATES ? count : AXIS_CANDIDATES - 1); k > pos; --k) {
            val[k] = val[k - 1];
            best[k] = best[k - 1];
        }
        val[pos] = v;
        best[pos] = i;
        if (count < AXIS_CANDIDATES)
            ++count;
    }
    return count;
}

/* Matching pursuit: adds a lobe to the residual's best explanation. */
static void pursue(const texels *t, double *r, double max_lambda, double *g, double *g_best, lobe64 *out)
{
    size_t cand[AXIS_CANDIDATES];
    const int nc = top_texels(t, r, cand);
    double best_gain = -1.0;
    memset(out, 0, sizeof *out);
    out->axis[1] = 1.0;
    out->lambda = 1.0;
    for (int a = 0; a < nc; ++a) {
        const double *axis = t->dir + 3 * cand[a];
        /* a near-constant lobe, then octaves from broad to the sharpest allowed */
        for (double lambda = MIN_SHARPNESS; lambda <= max_lambda * 1.0001; lambda = lambda < 0.0625 ? 0.0625 : 2.0 * lambda) {
            double amp[3];
            eval_lobe(t, axis, lambda, g);
            const double gain = best_amplitude(t, r, g, amp);
            if (gain > best_gain) {
                best_gain = gain;
                memcpy(out->axis, axis, sizeof out->axis);
                out->lambda = lambda;
                memcpy(out->amp, amp, sizeof out->amp);
                memcpy(g_best, g, t->n * sizeof *g);
            }
        }
    }
    if (nc > 0)
        add_lobe(t, r, g_best, out->amp, -1.0);
}

/* Step 2 for one lobe: r holds the residual with this lobe removed. */
static void refine(const texels *t, double *r, double max_lambda, double *g, lobe64 *lobe)
{
    double base_amp[3];
    eval_lobe(t, lobe->axis, lobe->lambda, g);
    double best = best_amplitude(t, r, g, base_amp);
    lobe64 keep = *lobe;
    memcpy(keep.amp, base_amp, sizeof base_amp);
    /* mean-shift: the residual's centre under the lobe's window */
    double m[3] = {0.0, 0.0, 0.0};
    for (size_t i = 0; i < t->n; ++i) {
        const double v = lum(r + 3 * i);
        if (v > 0.0)
            for (int c = 0; c < 3; ++c)
                m[c] += t->w[i] * v * g[i] * t->dir[3 * i + c];
    }
    const double mn = sqrt(dot3(m, m));
    const double scales[] = {1.0, 0.7, 1.0 / 0.7};
    for (int shifted = 0; shifted < 2; ++shifted) {
        if (shifted && !(mn > 0.0))
            break;
        double axis[3];
        for (int c = 0; c < 3; ++c)
            axis[c] = shifted ? m[c] / mn : lobe->axis[c];
        for (int s = shifted ? 0 : 1; s < 3; ++s) {
            const double lambda = fmin(fmax(lobe->lambda * scales[s], MIN_SHARPNESS), max_lambda);
            double amp[3];
            eval_lobe(t, axis, lambda, g);
            const double gain = best_amplitude(t, r, g, amp);
            if (gain > best) {
                best = gain;
                memcpy(keep.axis, axis, sizeof axis);
                keep.lambda = lambda;
                memcpy(keep.amp, amp, sizeof amp);
            }
        }
    }
    *lobe = keep;
}

/* Step 1, power clustering. A lobe's sharpness is the SG's whose mean of
 * 1 - cos is the cluster's, power-weighted, the texels' own extent included
 * (a cap of solid angle w adds w / 4 pi on average). */
#define LLOYD_ITERATIONS 16
#define DUPLICATE_ROUNDS 8

/* The sharpness of an SG whose mean of 1 - cos about its axis is s:
 * 1 - (coth l - 1/l) = s (-> 1/l for sharp lobes, -> 1 - l/3 for broad ones),
 * by bisection in log l on [MIN_SHARPNESS, 1e6]. */
static double sharpness_of_spread(double s)
{
    double lo = log(MIN_SHARPNESS), hi = log(1e6);
    for (int it = 0; it < 60; ++it) {
        const double mid = 0.5 * (lo + hi), l = exp(mid);
        /* coth l - 1/l: series below 1e-2 (cancellation), else exact; e^-2l from expm1 */
        const double m = l < 1e-2 ? l / 3.0 - l * l * l / 45.0 : (l > 20.0 ? 1.0 : -2.0 / expm1(-2.0 * l) - 1.0) - 1.0 / l;
        if (1.0 - m > s)
            lo = mid; /* too broad */
        else
            hi = mid;
    }
    return exp(0.5 * (lo + hi));
}

/* The next seed: the texel of largest power x (1 - cos to the nearest seed)^2
 * among those at least min_dist (in 1 - cos) from every seed. */
static void seed(const texels *t, const double *p, const double *dist, double min_dist, double *axis)
{
    size_t best = 0;
    double score = -1.0;
    for (size_t i = 0; i < t->n; ++i)
        if ((dist[i] >= min_dist || score < 0.0) && p[i] * dist[i] * dist[i] > score) {
            score = p[i] * dist[i] * dist[i];
            best = i;
        }
    memcpy(axis, t->dir + 3 * best, 3 * sizeof *axis);
}

/* Lloyd iterations: texels to the nearest centre, centres to their power-weighted mean. */
static void lloyd(const texels *t, const double *p, int k, lobe64 *out, int *label)
{
    for (int it = 0; it <= LLOYD_ITERATIONS; ++it) {
        for (size_t i = 0; i < t->n; ++i) {
            int best = 0;
            double c = -2.0;
            for (int a = 0; a < k; ++a) {
                const double ca = dot3(t->dir + 3 * i, out[a].axis);
                if (ca > c) {
                    c = ca;
                    best = a;
                }
            }
            label[i] = best;
        }
        if (it == LLOYD_ITERATIONS)
            break;
        for (int a = 0; a < k; ++a) {
            double v[3] = {0.0, 0.0, 0.0};
            for (size_t i = 0; i < t->n; ++i)
                if (label[i] == a)
                    for (int c = 0; c < 3; ++c)
                        v[c] += p[i] * t->dir[3 * i + c];
            const double len = sqrt(dot3(v, v));
            if (len > 0.0)
                for (int c = 0; c < 3; ++c)
                    out[a].axis[c] = v[c] / len;
        }
    }
}

static pn_status power_clusters(pn_context ctx, const texels *t, const double *target, int k, int face,
                                double max_lambda, lobe64 *out)
{
    int *label = pn_malloc(ctx, t->n * sizeof *label, "the SG fit's clusters");
    double *p = pn_malloc(ctx, t->n * sizeof *p, "the SG fit's texel powers");
    double *dist = pn_malloc(ctx, t->n * sizeof *dist, "the SG fit's seed distances");
    if (!label || !p || !dist) {
        free(label);
        free(p);
        free(dist);
        return PN_ERROR_OUT_OF_MEMORY;
    }
    for (size_t i = 0; i < t->n; ++i) {
        p[i] = t->w[i] * fmax(lum(target + 3 * i), 0.0);
        dist[i] = 2.0;
    }
    /* centres closer than two texels are one lobe split in two */
    const double cos_same = cos(2.0 * 2.0 / face);
    for (int a = 0; a < k; ++a) {
        memset(&out[a], 0, sizeof out[a]);
        seed(t, p, dist, 1.0 - cos_same, out[a].axis);
        for (size_t i = 0; i < t->n; ++i)
            dist[i] = fmin(dist[i], 1.0 - dot3(t->dir + 3 * i, out[a].axis));
    }
    /* Lloyd may pull two centres onto one sun (one of them through a few spill
     * texels): the lighter one is then seeded anew, up to DUPLICATE_ROUNDS times */
    for (int round = 0;; ++round) {
        lloyd(t, p, k, out, label);
        bool moved = false;
        for (int b = 1; b < k && round < DUPLICATE_ROUNDS; ++b)
            for (int a = 0; a < b; ++a) {
                if (dot3(out[a].axis, out[b].axis) <= cos_same)
                    continue;
                for (size_t i = 0; i < t->n; ++i) {
                    dist[i] = 2.0;
                    for (int c = 0; c < k; ++c)
                        if (c != b)
                            dist[i] = fmin(dist[i], 1.0 - dot3(t->dir + 3 * i, out[c].axis));
                }
                seed(t, p, dist, 1.0 - cos_same, out[b].axis);
                moved = true;
                break;
            }
        if (!moved)
            break;
    }
    for (int a = 0; a < k; ++a) {
        double power[3] = {0.0, 0.0, 0.0}, total = 0.0, spread = 0.0;
        for (size_t i = 0; i < t->n; ++i) {
            if (label[i] != a)
                continue;
            for (int c = 0; c < 3; ++c)
                power[c] += t->w[i] * target[3 * i + c];
            total += p[i];
            spread += p[i] * (1.0 - dot3(t->dir + 3 * i, out[a].axis) + t->w[i] / (4.0 * PI));
        }
        out[a].lambda = total > 0.0 ? fmin(sharpness_of_spread(spread / total), max_lambda) : 1.0;
        const double integral = 2.0 * PI * -expm1(-2.0 * out[a].lambda) / out[a].lambda;
        for (int c = 0; c < 3; ++c)
            out[a].amp[c] = total > 0.0 ? fmax(power[c], 0.0) / integral : 0.0;
    }
    free(label);
    free(p);
    free(dist);
    return PN_SUCCESS;
}

/* Step 2, last: amplitudes >= 0 minimising the objective for fixed axes and
 * sharpnesses, by projected Gauss-Seidel from the current ones. */
static pn_status joint_amplitudes(pn_context ctx, const texels *t, const double *target, lobe64 *lobes, int k)
{
    double *gram = pn_malloc(ctx, (size_t)k * k * sizeof *gram, "the SG fit's Gram matrix");
    double *rhs = pn_malloc(ctx, (size_t)k * 3 * sizeof *rhs, "the SG fit's projections");
    double *g = pn_malloc(ctx, pn_mul_size((size_t)k, t->n, sizeof *g), "the SG fit's lobe values");
    pn_status st = gram && rhs && g ? PN_SUCCESS : PN_ERROR_OUT_OF_MEMORY;
    if (!st) {
        for (int a = 0; a < k; ++a)
            eval_lobe(t, lobes[a].axis, lobes[a].lambda, g + (size_t)a * t->n);
        for (int a = 0; a < k; ++a) {
            const double *ga = g + (size_t)a * t->n;
            for (int b = a; b < k; ++b) {
                const double *gb = g + (size_t)b * t->n;
                double s = 0.0;
                for (size_t i = 0; i < t->n; ++i)
                    s += t->w[i] * ga[i] * gb[i];
                gram[a * k + b] = gram[b * k + a] = s;
            }
            for (int c = 0; c < 3; ++c) {
                double s = 0.0;
                for (size_t i = 0; i < t->n; ++i)
                    s += t->w[i] * ga[i] * target[3 * i + c];
                rhs[a * 3 + c] = s;
            }
        }
        for (int c = 0; c < 3; ++c)
            for (int it = 0; it < NNLS_SWEEPS; ++it)
                for (int a = 0; a < k; ++a) {
                    if (!(gram[a * k + a] > 0.0))
                        continue;
                    double s = rhs[a * 3 + c];
                    for (int b = 0; b < k; ++b)
                        if (b != a)
                            s -= gram[a * k + b] * lobes[b].amp[c];
                    lobes[a].amp[c] = fmax(s / gram[a * k + a], 0.0);
                }
    }
    free(gram);
    free(rhs);
    free(g);
    return st;
}

/* Scales the lobes' amplitudes per channel so that their power is the
 * target's (least squares lose a few % of it, which the irradiance shows). */
static void keep_power(const texels *t, const double *target, lobe64 *lobes, int k)
{
    double want[3] = {0.0, 0.0, 0.0}, have[3] = {0.0, 0.0, 0.0};
    for (size_t i = 0; i < t->n; ++i)
        for (int c = 0; c < 3; ++c)
            want[c] += t->w[i] * target[3 * i + c];
    for (int a = 0; a < k; ++a) {
        const double integral = 2.0 * PI * -expm1(-2.0 * lobes[a].lambda) / lobes[a].lambda;
        for (int c = 0; c < 3; ++c)
            have[c] += lobes[a].amp[c] * integral;
    }
    for (int c = 0; c < 3; ++c)
        if (have[c] > 0.0 && want[c] > 0.0)
            for (int a = 0; a < k; ++a)
                lobes[a].amp[c] *= want[c] / have[c];
}

static void free_texels(texels *t)
{
    free(t->dir);
    free(t->w);
    free(t->rad);
}

/* The fit's texels: the committed cube block-averaged down to `face` when
 * its face size is a multiple of it (texels nest; radiance averaged by solid
 * angle, directions the solid-angle-weighted mean), else a fresh resampling
 * of the lat-long map (slower: the commit's supersampled filter). */
static pn_status load_texels(pn_envmap env, int face, texels *t)
{
    pn_context ctx = env->obj.ctx;
    const int fine = env->committed_face_size;
    const bool nested = fine >= face && fine % face == 0;
    const int src = nested ? fine : face, s = src / face;
    const size_t ns = 6u * (size_t)src * src, n = 6u * (size_t)face * face;
    float *rad = pn_malloc(ctx, ns * 16, "the SG fit's cube");
    float *dirs = pn_malloc(ctx, ns * 16, "the SG fit's cube directions");
    t->n = n;
    t->dir = pn_malloc(ctx, n * 3 * sizeof(double), "the SG fit's texel directions");
    t->w = pn_malloc(ctx, n * sizeof(double), "the SG fit's solid angles");
    t->rad = pn_malloc(ctx, n * 3 * sizeof(double), "the SG fit's radiance");
    pn_status st = rad && dirs && t->dir && t->w && t->rad ? PN_SUCCESS : PN_ERROR_OUT_OF_MEMORY;
    if (!st && nested) {
        cl_int err = clEnqueueReadBuffer(ctx->queue, env->cube, CL_TRUE, 0, ns * 16, rad, 0, NULL, NULL);
        if (err == CL_SUCCESS)
            err = clEnqueueReadBuffer(ctx->queue, env->dirs, CL_TRUE, 0, ns * 16, dirs, 0, NULL, NULL);
        if (err != CL_SUCCESS)
            st = pn_fail_cl(ctx, err, "reading the env cube for the SG fit");
    } else if (!st) {
        st = pn_envmap_sample_cube(env, face, rad, dirs);
    }
    if (!st) {
        memset(t->dir, 0, n * 3 * sizeof(double));
        memset(t->w, 0, n * sizeof(double));
        memset(t->rad, 0, n * 3 * sizeof(double));
        for (size_t q = 0; q < ns; ++q) {
            const size_t f = q / ((size_t)src * src), j = (q / src) % src, i = q % src;
            const size_t k = f * face * face + (j / s) * face + i / s;
            const double w = dirs[4 * q + 3];
            for (int c = 0; c < 3; ++c) {
                t->dir[3 * k + c] += w * dirs[4 * q + c];
                t->rad[3 * k + c] += w * rad[4 * q + c];
            }
            t->w[k] += w;
        }
        for (size_t k = 0; k < n; ++k) {
            const double len = sqrt(dot3(t->dir + 3 * k, t->dir + 3 * k));
            for (int c = 0; c < 3; ++c) {
                t->dir[3 * k + c] /= len;
                t->rad[3 * k + c] /= t->w[k];
            }
        }
    }
    free(rad);
    free(dirs);
    return st;
}

pn_sg_fit_options pn_sg_fit_options_default(void)
{
    pn_sg_fit_options o = {32, 0, 0.0f};
    return o;
}

pn_status pn_envmap_do_fit_sgs(pn_envmap env, uint32_t count, const pn_sg_fit_options *options, pn_sg_lobe *out,
                               size_t capacity)
{
    pn_context ctx = env->obj.ctx;
    const pn_sg_fit_options o = options ? *options : pn_sg_fit_options_default();
    if (count < 1 || count > PN_SG_FIT_MAX_LOBES)
        return pn_fail(ctx, PN_ERROR_INVALID_ARGUMENT, "SG fit: lobe count %u is outside [1, %d]", count,
                       PN_SG_FIT_MAX_LOBES);
    if (capacity < count)
        return pn_fail(ctx, PN_ERROR_INVALID_SIZE, "SG fit: the output holds %zu lobes but %u were asked for", capacity,
                       count);
    if (o.face_size < 4 || o.face_size > 256)
        return pn_fail(ctx, PN_ERROR_INVALID_ARGUMENT, "SG fit: face_size %d is outside [4, 256]", o.face_size);
    if (o.iterations < 0 || o.iterations > 100)
        return pn_fail(ctx, PN_ERROR_INVALID_ARGUMENT, "SG fit: iterations %d is outside [0, 100]", o.iterations);
    if (!isfinite(o.max_sharpness) || o.max_sharpness < 0.0f || (o.max_sharpness > 0.0f && o.max_sharpness < 1.0f))
        return pn_fail(ctx, PN_ERROR_INVALID_ARGUMENT,
                       "SG fit: max_sharpness %g must be 0 (automatic) or a finite value >= 1", (double)o.max_sharpness);
    if (!env->committed)
        return pn_fail(ctx, PN_ERROR_NOT_COMMITTED, "env map changed since its last commit; call pn_envmap_commit");
    /* a lobe no narrower than half a texel: width 1/sqrt(lambda) >= a quarter of the 2/F texel angle */
    const double max_lambda = o.max_sharpness > 0.0f ? o.max_sharpness : 4.0 * o.face_size * o.face_size;
    const int k = (int)count;
    texels t = {0};
    lobe64 *lobes = pn_malloc(ctx, (size_t)k * sizeof *lobes, "the SG lobes");
    pn_status st = load_texels(env, o.face_size, &t);
    double *r = st ? NULL : pn_malloc(ctx, t.n * 3 * sizeof *r, "the SG fit's residual");
    double *g = st ? NULL : pn_malloc(ctx, t.n * sizeof *g, "the SG fit's lobe values");
    double *g2 = st ? NULL : pn_malloc(ctx, t.n * sizeof *g2, "the SG fit's lobe values");
    if (!st && (!lobes || !r || !g || !g2))
        st = PN_ERROR_OUT_OF_MEMORY;
    if (!st) {
        memcpy(r, t.rad, t.n * 3 * sizeof *r);
        st = power_clusters(ctx, &t, t.rad, k, o.face_size, max_lambda, lobes);
        for (int a = 0; !st && a < k; ++a) {
            eval_lobe(&t, lobes[a].axis, lobes[a].lambda, g);
            add_lobe(&t, r, g, lobes[a].amp, -1.0);
        }
        for (int it = 0; !st && it < o.iterations; ++it)
            for (int a = 0; a < k; ++a) {
                eval_lobe(&t, lobes[a].axis, lobes[a].lambda, g);
                add_lobe(&t, r, g, lobes[a].amp, 1.0);
                refine(&t, r, max_lambda, g, &lobes[a]);
                if (lobes[a].amp[0] == 0.0 && lobes[a].amp[1] == 0.0 && lobes[a].amp[2] == 0.0) {
                    /* unused: placed anew where the residual is now largest (adds itself to r) */
                    pursue(&t, r, max_lambda, g, g2, &lobes[a]);
                    continue;
                }
                eval_lobe(&t, lobes[a].axis, lobes[a].lambda, g);
                add_lobe(&t, r, g, lobes[a].amp, -1.0);
            }
        if (!st && o.iterations > 0) {
            st = joint_amplitudes(ctx, &t, t.rad, lobes, k);
            if (!st)
                keep_power(&t, t.rad, lobes, k);
        }
    }
    if (!st)
        for (int a = 0; a < k; ++a) {
            const double n = sqrt(dot3(lobes[a].axis, lobes[a].axis));
            for (int c = 0; c < 3; ++c) {
                out[a].axis[c] = (float)(lobes[a].axis[c] / n);
                out[a].amplitude[c] = (float)lobes[a].amp[c];
            }
            out[a].sharpness = (float)lobes[a].lambda;
            out[a].pad = 0.0f;
        }
    free_texels(&t);
    free(lobes);
    free(r);
    free(g);
    free(g2);
    return st;
}
