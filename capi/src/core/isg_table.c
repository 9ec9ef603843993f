/* The ISG table of docs/isg.md 3, in float64 on the host: the four marginal
 * CDFs of the normalised ISG (front theta, front phi, back theta, back phi)
 * at 57 sharpnesses x 33 warped angles, which kernels/common/sg.cl's pn_isg
 * interpolates. Its float64 twin is tests/isg64.py's isg_table() (the same
 * values by 2-D quadrature; tests/test_sg_kernels.py compares them).
 *
 * Each marginal is symmetric about pi/2 in both angles, so with u, w the
 * offsets from pi/2 (sin(pi/2 + u) = cos u) it is a nested 1-D integral over
 * [0, pi/2]^2 of f = exp(lam (cos u cos w - 1)) (front) or
 * exp(-lam cos u cos w) (back, normalised by its own total):
 *   theta: T(x) = int_0^x cos u int_0^(pi/2) f dw du / (2 int_0^(pi/2) ...),
 *   phi:   T(x) = int_0^x int_0^(pi/2) f cos u du dw / (2 ...). */
#include "core/sg.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#define PI 3.14159265358979323846
#define HALF_PI (0.5 * PI)
#define NODES 12
#define MAX_BREAKS 96

static int cmp_double(const void *a, const void *b)
{
    const double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

/* Panel breakpoints on [0, pi/2]: 8 uniform panels, 2^k / sqrt(lam) (the
 * front's peak at 0) and pi/2 - 2^k / lam (the back's slope at the edge),
 * k = -3..11, and `extra` points; sorted, unique. */
static int breaks(double lam, const double *extra, int n_extra, double *out)
{
    int n = 0;
    for (int i = 0; i <= 8; ++i)
        out[n++] = HALF_PI * i / 8.0;
    for (int k = -3; k <= 11; ++k) {
        const double a = ldexp(1.0, k) / sqrt(lam), b = HALF_PI - ldexp(1.0, k) / lam;
        if (a > 0.0 && a < HALF_PI)
            out[n++] = a;
        if (b > 0.0 && b < HALF_PI)
            out[n++] = b;
    }
    for (int i = 0; i < n_extra; ++i)
        out[n++] = extra[i];
    qsort(out, (size_t)n, sizeof *out, cmp_double);
    int m = 0;
    for (int i = 0; i < n; ++i)
        if (m == 0 || out[i] != out[m - 1])
            out[m++] = out[i];
    return m;
}

typedef struct rule {
    int count;
    double x[MAX_BREAKS * NODES], w[MAX_BREAKS * NODES];
} rule;

static void panel_rule(const double *b, int nb, const double *gx, const double *gw, rule *r)
{
    r->count = 0;
    for (int p = 0; p + 1 < nb; ++p) {
        const double h = 0.5 * (b[p + 1] - b[p]), m = 0.5 * (b[p + 1] + b[p]);
        for (int i = 0; i < NODES; ++i) {
            r->x[r->count] = m + h * gx[i];
            r->w[r->count++] = h * gw[i];
        }
    }
}

static double integrand(double lam, bool back, double cu, double cw)
{
    return back ? exp(-lam * cu * cw) : exp(lam * (cu * cw - 1.0));
}

/* T at the n offsets xs (ascending, in [0, pi/2]) of one marginal. */
static void marginal(double lam, bool back, bool phi, const double *xs, int n, const double *gx, const double *gw,
                     double *out)
{
    static _Thread_local rule inner;
    double b[MAX_BREAKS];
    int nb = breaks(lam, NULL, 0, b);
    panel_rule(b, nb, gx, gw, &inner);
    nb = breaks(lam, xs, n, b);
    double cum[MAX_BREAKS];
    cum[0] = 0.0;
    for (int p = 0; p + 1 < nb; ++p) {
        const double h = 0.5 * (b[p + 1] - b[p]), m = 0.5 * (b[p + 1] + b[p]);
        double panel = 0.0;
        for (int i = 0; i < NODES; ++i) {
            const double a = m + h * gx[i], ca = cos(a);
            double s = 0.0;
            for (int j = 0; j < inner.count; ++j) {
                const double cj = cos(inner.x[j]);
                /* theta: the outer angle carries the sin-theta weight; phi: the inner one */
                s += inner.w[j] * integrand(lam, back, ca, cj) * (phi ? cj : 1.0);
            }
            panel += h * gw[i] * s * (phi ? 1.0 : ca);
        }
        cum[p + 1] = cum[p] + panel;
    }
    const double total = cum[nb - 1];
    for (int k = 0, p = 0; k < n; ++k) {
        while (b[p] != xs[k])
            ++p;
        out[k] = total > 0.0 ? 0.5 * cum[p] / total : 0.0;
    }
}

/* x with erf(k x) / erf(k pi/2) = rho (bisection, as the twin's _front_x). */
static double front_x(double rho, double lam)
{
    const double k = sqrt(lam / 2.0), e = erf(k * HALF_PI);
    double lo = 0.0, hi = HALF_PI;
    for (int it = 0; it < 60; ++it) {
        const double mid = 0.5 * (lo + hi);
        if (erf(k * mid) / e < rho)
            lo = mid;
        else
            hi = mid;
    }
    return 0.5 * (lo + hi);
}

void pn_isg_table_fill(float *out)
{
    double gx[NODES], gw[NODES], xf[PN_ISG_RHO], xb[PN_ISG_RHO], t[PN_ISG_RHO];
    pn_gauss_legendre(NODES, gx, gw);
    const size_t block = (size_t)PN_ISG_LAMBDAS * PN_ISG_RHO;
    memset(out, 0, 4 * block * sizeof *out);
    for (int i = 0; i < PN_ISG_LAMBDAS; ++i) {
        const double lam = PN_ISG_LAMBDA_MIN * pow(10.0, (double)i / PN_ISG_PER_DECADE);
        for (int j = 0; j < PN_ISG_RHO; ++j) {
            const double rho = (double)j / (PN_ISG_RHO - 1);
            xf[j] = j == 0 ? 0.0 : j == PN_ISG_RHO - 1 ? HALF_PI : front_x(rho, lam);
            xb[j] = rho * HALF_PI;
        }
        for (int m = 0; m < 4; ++m) {
            const bool back = m >= 2, phi = m % 2 == 1;
            if (back && lam > PN_ISG_BACK_MAX)
                continue;
            marginal(lam, back, phi, back ? xb : xf, PN_ISG_RHO, gx, gw, t);
            for (int j = 0; j < PN_ISG_RHO; ++j)
                out[m * block + (size_t)i * PN_ISG_RHO + j] = (float)t[j];
        }
    }
}

static const char cache_key = 0;

pn_status pn_isg_table_buffer(pn_context ctx, cl_mem *out)
{
    return pn_context_table(ctx, &cache_key, PN_ISG_TABLE_FLOATS, pn_isg_table_fill, "the ISG table", out);
}
