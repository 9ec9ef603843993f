/* Spherical-harmonic tables of the `heightfield` method, in float64
 * (docs/heightfield.md): visibility wedge tables, the triple-product tensor,
 * the clamped-cosine zonal harmonics and the env map's projection. Computed
 * on the host once per (n_phi, bands) and uploaded as float. */
#include "methods/sh_tables.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#define PI 3.14159265358979323846

/* All y_lm (l < nb) at polar cosine ct, sine st and azimuth phi; index l*l + l + m.
 * Associated Legendre with the Condon–Shortley phase, by the standard recurrences. */
void pn_sh_eval64(int nb, double ct, double st, double phi, double *out)
{
    double p[PN_SH_MAX_BANDS][PN_SH_MAX_BANDS]; /* p[l][m] */
    p[0][0] = 1.0;
    for (int m = 1; m < nb; ++m)
        p[m][m] = -(2.0 * m - 1.0) * st * p[m - 1][m - 1];
    for (int m = 0; m + 1 < nb; ++m)
        p[m + 1][m] = (2.0 * m + 1.0) * ct * p[m][m];
    for (int m = 0; m < nb; ++m)
        for (int l = m + 2; l < nb; ++l)
            p[l][m] = ((2.0 * l - 1.0) * ct * p[l - 1][m] - (l + m - 1.0) * p[l - 2][m]) / (l - m);
    for (int l = 0; l < nb; ++l) {
        for (int m = 0; m <= l; ++m) {
            double ratio = 1.0; /* (l - m)! / (l + m)! */
            for (int q = l - m + 1; q <= l + m; ++q)
                ratio /= q;
            double k = sqrt((2.0 * l + 1.0) / (4.0 * PI) * ratio);
            if (m == 0) {
                out[l * l + l] = k * p[l][0];
            } else {
                out[l * l + l + m] = sqrt(2.0) * k * p[l][m] * cos(m * phi);
                out[l * l + l - m] = sqrt(2.0) * k * p[l][m] * sin(m * phi);
            }
        }
    }
}

/* 2π ∫_0^1 P_l(t) t dt: the clamped cosine's zonal coefficient z_l times sqrt(4π/(2l+1)). */
void pn_sh_clamped_cosine64(int nb, double *a)
{
    double x[16], w[16];
    pn_gauss_legendre(16, x, w);
    for (int l = 0; l < nb; ++l) {
        double s = 0.0;
        for (int i = 0; i < 16; ++i) {
            double t = 0.5 * (x[i] + 1.0), p0 = 1.0, p1 = t, pl = l == 0 ? 1.0 : t;
            for (int k = 2; k <= l; ++k) {
                pl = ((2.0 * k - 1.0) * t * p1 - (k - 1.0) * p0) / k;
                p0 = p1;
                p1 = pl;
            }
            s += 0.5 * w[i] * pl * t;
        }
        a[l] = 2.0 * PI * s;
    }
}

/* Associated Legendre part of every y_lm at polar cosine ct, sine st: out[l*l + l + m]
 * (m >= 0) = K_l^m P_l^m (times sqrt 2 for m > 0); the azimuthal factor is applied apart. */
static void sh_polar64(int nb, double ct, double st, double *out)
{
    double y[PN_SH_MAX_BANDS * PN_SH_MAX_BANDS];
    pn_sh_eval64(nb, ct, st, 0.0, y); /* at phi = 0: cos(m phi) = 1 */
    for (int l = 0; l < nb; ++l)
        for (int m = 0; m <= l; ++m)
            out[l * l + l + m] = y[l * l + l + m];
}

static pn_status compute_wedge_table(pn_context ctx, int n_phi, int nb, bool light, float **out)
{
    const int nc = nb * nb, T = PN_SH_WEDGE_ANGLES, NP = 24, NT = 32;
    float *table = pn_malloc(ctx, (size_t)T * T * nc * sizeof(float), "a visibility wedge table");
    if (!table)
        return PN_ERROR_OUT_OF_MEMORY;
    const double lo = light ? -0.5 * PI : 0.0, hi = 0.5 * PI, dphi = 2.0 * PI / n_phi;
    double xp[24], wp[24], xt[32], wt[32], p[PN_SH_MAX_BANDS * PN_SH_MAX_BANDS], acc[PN_SH_MAX_BANDS * PN_SH_MAX_BANDS];
    double trig[24][2 * PN_SH_MAX_BANDS]; /* cos(m phi), sin(m phi) per azimuth node */
    pn_gauss_legendre(NP, xp, wp);
    pn_gauss_legendre(NT, xt, wt);
    for (int i = 0; i < NP; ++i)
        for (int m = 0; m < nb; ++m) {
            const double phi = 0.5 * dphi * (xp[i] + 1.0);
            trig[i][2 * m] = cos(m * phi);
            trig[i][2 * m + 1] = sin(m * phi);
        }
    for (int a = 0; a < T; ++a) {
        const double wl = lo + a * (hi - lo) / (T - 1);
        for (int b = 0; b < T; ++b) {
            const double wr = lo + b * (hi - lo) / (T - 1);
            memset(acc, 0, sizeof acc);
            for (int i = 0; i < NP; ++i) {
                double horizon = wl + 0.5 * (xp[i] + 1.0) * (wr - wl);
                if (!light && horizon < 0.0)
                    horizon = 0.0;
                /* Visible: elevation above the horizon = polar angle in [0, pi/2 - horizon];
                 * integrated in the polar angle, where the integrand is smooth. */
                const double top = 0.5 * PI - horizon;
                double polar[PN_SH_MAX_BANDS * PN_SH_MAX_BANDS] = {0};
                for (int j = 0; j < NT; ++j) {
                    const double th = 0.5 * top * (xt[j] + 1.0), wgt = 0.5 * top * wt[j] * sin(th);
                    sh_polar64(nb, cos(th), sin(th), p);
                    for (int l = 0; l < nb; ++l)
                        for (int m = 0; m <= l; ++m)
                            polar[l * l + l + m] += wgt * p[l * l + l + m];
                }
                const double wphi = 0.5 * dphi * wp[i];
                for (int l = 0; l < nb; ++l) {
                    acc[l * l + l] += wphi * polar[l * l + l];
                    for (int m = 1; m <= l; ++m) {
                        acc[l * l + l + m] += wphi * polar[l * l + l + m] * trig[i][2 * m];
                        acc[l * l + l - m] += wphi * polar[l * l + l + m] * trig[i][2 * m + 1];
                    }
                }
            }
            for (int c = 0; c < nc; ++c)
                table[((size_t)a * T + b) * nc + c] = (float)acc[c];
        }
    }
    *out = table;
    return PN_SUCCESS;
}

/* Γ_ijk = ∫ y_i y_j y_k dω, exact by Gauss–Legendre in cos ϑ (polynomial of
 * degree ≤ 3(nb-1) once the azimuthal integral is non-zero) and a uniform
 * azimuth rule with more nodes than the highest frequency. */
static pn_status compute_triple_product(pn_context ctx, int nb, double **out)
{
    const int nc = nb * nb, NZ = 3 * PN_SH_MAX_BANDS, NF = 6 * PN_SH_MAX_BANDS;
    double *g = calloc((size_t)nc * nc * nc, sizeof(double));
    double *y = malloc((size_t)NZ * NF * nc * sizeof(double));
    if (!g || !y) {
        free(g);
        free(y);
        return pn_fail(ctx, PN_ERROR_OUT_OF_MEMORY, "out of memory for the SH triple-product tensor");
    }
    double xz[3 * PN_SH_MAX_BANDS], wz[3 * PN_SH_MAX_BANDS];
    pn_gauss_legendre(NZ, xz, wz);
    for (int i = 0; i < NZ; ++i)
        for (int f = 0; f < NF; ++f)
            pn_sh_eval64(nb, xz[i], sqrt(1.0 - xz[i] * xz[i]), 2.0 * PI * (f + 0.5) / NF, y + ((size_t)i * NF + f) * nc);
    for (int q = 0; q < NZ * NF; ++q) {
        const double wq = wz[q / NF] * 2.0 * PI / NF;
        const double *yq = y + (size_t)q * nc;
        for (int i = 0; i < nc; ++i)
            for (int j = 0; j < nc; ++j) {
                const double yij = wq * yq[i] * yq[j];
                for (int k = 0; k < nc; ++k)
                    g[((size_t)i * nc + j) * nc + k] += yij * yq[k];
            }
    }
    for (size_t i = 0; i < (size_t)nc * nc * nc; ++i)
        if (fabs(g[i]) < 1e-12)
            g[i] = 0.0;
    free(y);
    *out = g;
    return PN_SUCCESS;
}

/* ------------------------------------------------------------------ cache */

/* The tables of one context, kept in its generic cache under `cache_key`:
 * computed once in float64, shared by every renderer of the context. */
#define SH_CACHE 16
typedef struct sh_entry {
    int n_phi, bands, kind;   /* kind: 0 env wedges, 1 light wedges, 2 triple product (n_phi 0) */
    void *data;               /* float table or double tensor */
    uint64_t stamp;           /* operation that last used it: never evicted during that operation */
} sh_entry;

typedef struct sh_cache {
    sh_entry entries[SH_CACHE];
    int next;                 /* round-robin slot to reuse when full */
    uint64_t operation;       /* pn_sh_cache_begin count */
} sh_cache;

static const char cache_key = 0;

static void free_cache(void *data)
{
    sh_cache *c = data;
    for (int i = 0; i < SH_CACHE; ++i)
        free(c->entries[i].data);
    free(c);
}

static sh_cache *context_cache(pn_context ctx)
{
    sh_cache *c = pn_context_cache(ctx, &cache_key);
    if (c)
        return c;
    if (!(c = pn_malloc(ctx, sizeof *c, "the SH table cache")))
        return NULL;
    memset(c, 0, sizeof *c);
    if (pn_context_set_cache(ctx, &cache_key, c, free_cache)) {
        free(c);
        return NULL;
    }
    return c;
}

pn_status pn_sh_cache_begin(pn_context ctx)
{
    sh_cache *c = context_cache(ctx);
    if (!c)
        return PN_ERROR_OUT_OF_MEMORY;
    c->operation++;
    return PN_SUCCESS;
}

static void *cached(sh_cache *c, int n_phi, int nb, int kind)
{
    for (int i = 0; i < SH_CACHE; ++i) {
        sh_entry *e = &c->entries[i];
        if (e->data && e->n_phi == n_phi && e->bands == nb && e->kind == kind) {
            e->stamp = c->operation;
            return e->data;
        }
    }
    return NULL;
}

/* Keeps `data` in the cache: a free slot, else round-robin over the entries
 * not used in the current operation (one operation uses at most 3). */
static void remember(sh_cache *c, int n_phi, int nb, int kind, void *data)
{
    int slot = -1;
    for (int i = 0; i < SH_CACHE && slot < 0; ++i)
        if (!c->entries[i].data)
            slot = i;
    while (slot < 0) {
        const int i = c->next;
        c->next = (c->next + 1) % SH_CACHE;
        if (c->entries[i].stamp != c->operation)
            slot = i;
    }
    free(c->entries[slot].data);
    sh_entry e = {n_phi, nb, kind, data, c->operation};
    c->entries[slot] = e;
}

pn_status pn_sh_wedge_table(pn_context ctx, int n_phi, int nb, bool light, const float **out)
{
    sh_cache *c = context_cache(ctx);
    if (!c)
        return PN_ERROR_OUT_OF_MEMORY;
    float *t = cached(c, n_phi, nb, light ? 1 : 0);
    if (!t) {
        pn_status st = compute_wedge_table(ctx, n_phi, nb, light, &t);
        if (st)
            return st;
        remember(c, n_phi, nb, light ? 1 : 0, t);
    }
    *out = t;
    return PN_SUCCESS;
}

pn_status pn_sh_triple_product(pn_context ctx, int nb, const double **out)
{
    sh_cache *c = context_cache(ctx);
    if (!c)
        return PN_ERROR_OUT_OF_MEMORY;
    double *g = cached(c, 0, nb, 2);
    if (!g) {
        pn_status st = compute_triple_product(ctx, nb, &g);
        if (st)
            return st;
        remember(c, 0, nb, 2, g);
    }
    *out = g;
    return PN_SUCCESS;
}
