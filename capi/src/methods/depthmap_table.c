/* The tabulated exact cap average of the `depthmap` method (docs/depthmap.md,
 * "Tabulated exact cap averages"), built once per context in float64 on the
 * host and read by kernels/depthmap.cl's dm_cap_ratio (specular 3). Its
 * float64 twin is tests/depthmap64.py's cap_ratio() (the exact average by the
 * twin's own quadrature, no table); tests/test_depthmap.py compares the
 * renderer's interpolated values with it.
 *
 * For a cap of angular radius r whose centre is psi_c from the lobe's axis R
 * and the lobe max(0, cos psi)^n (psi from R), the table holds
 *   H(r, psi_c, n) = A / cos^n(g),   A = (1/Omega_cap) int_cap max(0, cos psi)^n dw,
 * with g = max(psi_c - r, 0) the angle from R to the cap's nearest point:
 * the cap average over the lobe's value where it is largest in the cap. H is
 * in (0, 1], has no underflow far from R (the ratio is integrated as such),
 * and is 1 for a point cap. Stored: W = H (1 + (n + 1)(1 - cos r)), which is
 * near 1 both for small caps (H -> 1) and for caps much wider than the lobe
 * (A -> 1 / ((n + 1)(1 - cos r)) while R is inside), so linear interpolation
 * of W keeps its relative error small where A spans decades.
 *
 * Grid (sigma = 1 / sqrt(n + 1), the lobe's angular width):
 *   x = log(1 + r / sigma) / log(1 + pi / sigma)            r in [0, pi]
 *   y = (t((psi_c - r) / sigma) - t(-r / sigma)) / (t(pi/2 / sigma) - t(-r / sigma)),
 *       t(delta) = delta / (|delta| + 4)                   the cap's edge at the middle
 *   z = log(n) / log(10^6)                                  n in [1, 10^6]
 * The edge's transition (|delta| of a few lobe widths) gets most of y's
 * cells whatever the cap's size; x resolves caps from a tenth of a lobe
 * width to the whole sphere. */
#include "methods/depthmap_table.h"

#include <math.h>
#include <stdlib.h>

#define PI 3.14159265358979323846
#define HALF_PI (0.5 * PI)
#define NODES 12 /* Gauss-Legendre nodes per panel (after the cosine map): the table within 1e-5 of 48 nodes' */

static double edge_t(double delta) { return delta / (fabs(delta) + PN_DM_TABLE_SPREAD); }

/* A / cos^n(g) by 1-D quadrature over psi (docs/depthmap.md, "Exact, any
 * psi_c"): the circle of radius psi around R lies in the cap over an azimuth
 * 2 phi(psi); whole circles in closed form, the rest split at the kinks and
 * integrated after psi = a + (b - a)(1 - cos(pi s)) / 2. */
static double cap_ratio(double psi_c, double r, double n, const double *map, const double *gw)
{
    if (r <= 0.0)
        return 1.0;
    const double g = fmax(psi_c - r, 0.0);
    if (g >= HALF_PI)
        return 0.0; /* the cap is beyond the lobe's hemisphere */
    const double log_cg = log(cos(g)), cr = cos(r), cpc = cos(psi_c), spc = sin(psi_c);
    double total = 0.0, a;
    if (psi_c <= r) { /* R inside: whole circles up to r - psi_c (g = 0) */
        const double b = fmin(r - psi_c, HALF_PI);
        total += 2.0 * PI * (1.0 - pow(cos(b), n + 1.0)) / (n + 1.0);
        a = r - psi_c;
    } else {
        a = psi_c - r;
    }
    const double b = fmin(fmin(psi_c + r, PI), HALF_PI);
    /* Panels: from a, widths growing as len 2^k, len the length over which the
     * lobe falls by e from a (sigma near R, 1 / (n tan a) towards its
     * horizon), a cut at the antipode's kink, and no panel once the lobe has
     * fallen below 1e-30 of its value at the cap's nearest point. */
    const double len = 1.0 / (n * tan(a) + sqrt(n + 1.0)), antipode = 2.0 * PI - psi_c - r;
    double lo = a;
    for (int k = -2; lo < b && n * (log(cos(lo)) - log_cg) > -69.0; ++k) {
        double hi = fmin(a + ldexp(len, k), b);
        if (antipode > lo && antipode < hi)
            hi = antipode;
        for (int q = 0; q < NODES; ++q) {
            const double psi = lo + (hi - lo) * map[q], w = gw[q] * (hi - lo);
            const double sp = sin(psi), cp = cos(psi);
            if (!(cp > 0.0))
                continue;
            double c = 1.0;
            if (sp * spc > 0.0)
                c = fmin(fmax((cr - cp * cpc) / (sp * spc), -1.0), 1.0);
            total += w * exp(n * (log(cp) - log_cg)) * 2.0 * acos(c) * sp;
        }
        lo = hi;
    }
    return total / (4.0 * PI * sin(0.5 * r) * sin(0.5 * r));
}

void pn_depthmap_cap_table_fill(float *out)
{
    double gx[NODES], gw[NODES], map[NODES];
    pn_gauss_legendre(NODES, gx, gw);
    for (int k = 0; k < NODES; ++k) { /* the cosine map's node positions and weights on [0, 1] */
        const double s = 0.5 * (gx[k] + 1.0);
        map[k] = 0.5 * (1.0 - cos(PI * s));
        gw[k] *= 0.25 * PI * sin(PI * s);
    }
    for (int k = 0; k < PN_DM_TABLE_N; ++k) {
        const double n = pow(PN_DM_TABLE_N_MAX, (double)k / (PN_DM_TABLE_N - 1));
        const double sigma = 1.0 / sqrt(n + 1.0);
        for (int j = 0; j < PN_DM_TABLE_D; ++j)
            for (int i = 0; i < PN_DM_TABLE_R; ++i) {
                const double x = (double)i / (PN_DM_TABLE_R - 1), y = (double)j / (PN_DM_TABLE_D - 1);
                const double r = fmin(sigma * expm1(x * log1p(PI / sigma)), PI);
                const double t0 = edge_t(-r / sigma), t1 = edge_t(HALF_PI / sigma), t = t0 + y * (t1 - t0);
                const double delta = PN_DM_TABLE_SPREAD * t / (1.0 - fabs(t));
                const double psi_c = fmin(fmax(r + delta * sigma, 0.0), PI);
                const double h = cap_ratio(psi_c, r, n, map, gw);
                const double s = sin(0.5 * r);
                out[((size_t)k * PN_DM_TABLE_D + j) * PN_DM_TABLE_R + i] = (float)(h * (1.0 + (n + 1.0) * 2.0 * s * s));
            }
    }
}

static const char cache_key = 0;

pn_status pn_depthmap_cap_table(pn_context ctx, cl_mem *out)
{
    return pn_context_table(ctx, &cache_key, PN_DM_TABLE_FLOATS, pn_depthmap_cap_table_fill, "the cap-average table",
                            out);
}
