/* The tabulated exact cap averages of the `depthmap` method (docs/depthmap.md,
 * "Tabulated exact cap averages"), built once per context in float64 on the
 * host into one buffer: Phong's, read by kernels/depthmap.cl's dm_cap_ratio
 * (specular 3), then Blinn-Phong's and GGX's with the view angle (below,
 * read by dm_lobe_average). Float64 twins: tests/depthmap64.py's cap_ratio()
 * and tests/depthmap_lobes64.py (their own quadratures, no table);
 * tests/test_depthmap.py and tests/test_depthmap_lobes.py compare the
 * renderer's interpolated values with them.
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
#include <string.h>

#define PI 3.14159265358979323846
#define HALF_PI (0.5 * PI)
#define SQRT2 1.41421356237309504880
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

static void phong_table_fill(float *out)
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

/* ---------------------------------------------------------------- Blinn-Phong and GGX
 * The lobes of the half vector (docs/depthmap.md, "Blinn-Phong and GGX: a table
 * with the view angle"). Near R, a direction L at the tangent offset (x, y) from
 * R (x in the plane of N and R, y across it) has the half vector at the angle
 * theta_h = |(x, y / c)| / 2 from N, c = N.V: a rotation of H by delta turns L by
 * 2 delta in the plane of incidence and by 2 (N.V) delta across it. So both
 * lobes are, about R, functions of one lobe-metric radius u = |(x, y / c)| / s:
 *   Blinn-Phong cos^n(theta_h) ~ exp(-u^2 / 2),  s = 2 / sqrt(n)       (family 0)
 *   GGX D(H) ~ D(N) (1 + u^2)^-2,                 s = 2 alpha           (family 1)
 * with no other parameter: the sharpness is the scale s, the view the
 * squash c. In units of s, a cap of radius r is a disk of radius rho = r / s
 * whose centre is (psi_c / s) (cos phi, sin phi) from R. Tabulated, per family:
 *   log G(rho, c, delta_u, phi_s),  G = (1 / (pi rho^2)) int_disk Lambda(u) dA / Lambda(u*),
 * the disk average over the lobe at the disk's point l* of least u (R when
 * inside; then u* = 0), so G is in (0, 1]; delta_u = (psi_c - r) / s * gamma is the signed distance of
 * R from the disk's edge in the lobe's metric along the offset, gamma = |(cos phi,
 * sin phi / c)|, and phi_s = atan2(sin phi / c, cos phi) the offset's angle in
 * the stretched plane, where the lobe is round. Axes:
 *   x = log(1 + rho / RHO_0) / log(1 + RHO_MAX / RHO_0),  y as the Phong table's (t(delta_u)
 *   from the disk's centre to DELTA_MAX),  phi_s / (pi / 2),  log c / log C_MIN.
 * Each entry also holds the lobe-weighted centroid of the disk in the round metric (x, y / c) from R and
 * the spreads of x and y / c (PN_DM_LOBE_V = 5 floats), from which the kernel averages the rest of the
 * integrand (the cosine, G1, the half vector's Jacobian) by four points (dm_lobe_average).
 * The disk integral: over x (Gauss-Legendre panels from the features: the
 * lobe's peak, the chord ends' crossings of y = 0, the disk's nearest row),
 * over y in closed form (erf for the Gaussian, the rational-arctangent
 * antiderivative for GGX), summed in logarithms. */

static double log_erfc_pos(double z) /* log erfc(z), z >= 0 */
{
    if (z < 20.0)
        return log(erfc(z));
    const double z2 = z * z;
    return -z2 - log(z) - 0.5 * log(PI) + log1p((-0.5 + (0.75 - 1.875 / z2) / z2) / z2);
}

/* log(erf(q) - erf(p)), p < q */
static double log_erf_diff(double p, double q)
{
    if (p < 0.0 && q > 0.0)
        return log(erf(q) - erf(p));
    if (q <= 0.0) {
        const double t = -p;
        p = -q;
        q = t;
    }
    const double lp = log_erfc_pos(p), lq = log_erfc_pos(q);
    return lp + log(-expm1(lq - lp));
}

/* int_{z1}^{z2} dz / (a^2 + z^2)^2 for 0 <= z1 <= z2, with z = a cot(beta):
 * ((D - sin D) + 2 sin^2((b1 + b2) / 2) sin D) / (2 a^3), D = b1 - b2, no cancellation. */
static double ggx_strip_pos(double z1, double z2, double a)
{
    const double b1 = atan2(a, z1), b2 = atan2(a, z2), d = b1 - b2;
    const double d3 = d < 1e-2 ? d * d * d / 6.0 * (1.0 - d * d / 20.0 * (1.0 - d * d / 42.0)) : d - sin(d);
    const double s = sin(0.5 * (b1 + b2));
    return (d3 + 2.0 * s * s * sin(d)) / (2.0 * a * a * a);
}

/* log of the lobe integrated over the chord x, y in [y1, y2] */
static double log_chord(int family, double x, double y1, double y2, double c)
{
    if (!(y2 > y1))
        return -INFINITY;
    if (family == 0)
        return -0.5 * x * x + log(c * sqrt(0.5 * PI)) + log_erf_diff(y1 / (c * SQRT2), y2 / (c * SQRT2));
    const double a = sqrt(1.0 + x * x), z1 = y1 / c, z2 = y2 / c;
    double k;
    if (z1 >= 0.0)
        k = ggx_strip_pos(z1, z2, a);
    else if (z2 <= 0.0)
        k = ggx_strip_pos(-z2, -z1, a);
    else
        k = ggx_strip_pos(0.0, -z1, a) + ggx_strip_pos(0.0, z2, a);
    return log(c * k);
}

/* The mean and mean square of z = y / c over the chord x, y in [y1, y2] under the lobe (moments over
 * the chord's integral, in closed form; tails in logarithms, so no 0 / 0). Blinn-Phong, the standard
 * normal on [z1, z2]: mean (phi(z1) - phi(z2)) / P, mean square 1 + (z1 phi(z1) - z2 phi(z2)) / P,
 * P = Phi(z2) - Phi(z1). GGX, (a^2 + z^2)^-2: mean (1/(a^2 + z1^2) - 1/(a^2 + z2^2)) / (2 k), mean square
 * from int z^2 / (a^2 + z^2)^2 = (atan(z / a) / a - z / (a^2 + z^2)) / 2 over k = int (a^2 + z^2)^-2. */
static double log_q(double z) { return log_erfc_pos(z / SQRT2) - log(2.0); } /* log of the normal's upper tail, z >= 0 */

static void chord_moments(int family, double x, double y1, double y2, double c, double *mean, double *square,
                          double *log_value)
{
    double z1 = y1 / c, z2 = y2 / c, sign = 1.0;
    *log_value = -INFINITY; /* GGX: log_chord's value, from the same integral (not set for Blinn-Phong) */
    if (!(z2 > z1)) {
        *mean = 0.5 * (z1 + z2);
        *square = *mean * *mean;
        return;
    }
    if (z2 <= 0.0) { /* mirror to z >= 0 */
        const double t = -z1;
        z1 = -z2;
        z2 = t;
        sign = -1.0;
    }
    if (family == 0) {
        if (z1 >= 0.0) { /* ratios to phi(z1): e = phi(z2) / phi(z1), P / phi(z1) = (Q(z1) - Q(z2)) / phi(z1) */
            const double e = exp(-0.5 * (z2 - z1) * (z2 + z1));
            const double lq1 = log_q(z1), lp = lq1 + log(-expm1(log_q(z2) - lq1));
            const double ratio = exp(-0.5 * z1 * z1 - 0.5 * log(2.0 * PI) - lp); /* phi(z1) / P */
            *mean = sign * (1.0 - e) * ratio;
            *square = 1.0 + (z1 - z2 * e) * ratio;
            return;
        }
        const double p1 = exp(-0.5 * z1 * z1) / sqrt(2.0 * PI), p2 = exp(-0.5 * z2 * z2) / sqrt(2.0 * PI);
        const double mass = 0.5 * (erf(z2 / SQRT2) - erf(z1 / SQRT2));
        *mean = sign * (p1 - p2) / mass;
        *square = 1.0 + (z1 * p1 - z2 * p2) / mass;
        return;
    }
    const double a = sqrt(1.0 + x * x), a2 = a * a;
    double k, m, q;
    if (z1 >= 0.0) {
        k = ggx_strip_pos(z1, z2, a);
        m = 0.5 * (z2 - z1) * (z2 + z1) / ((a2 + z1 * z1) * (a2 + z2 * z2));
        /* int z^2 / (a^2 + z^2)^2 = int dz / (a^2 + z^2) - a^2 k */
        q = (atan2(a * (z2 - z1), a2 + z1 * z2)) / a - a2 * k;
    } else {
        k = ggx_strip_pos(0.0, -z1, a) + ggx_strip_pos(0.0, z2, a);
        m = 0.5 * (1.0 / (a2 + z1 * z1) - 1.0 / (a2 + z2 * z2));
        q = (atan(z2 / a) - atan(z1 / a)) / a - a2 * k;
    }
    *mean = sign * m / k;
    *square = fmax(q / k, 0.0);
    *log_value = log(c * k);
}

static double log_lobe(int family, double u) { return family == 0 ? -0.5 * u * u : -2.0 * log1p(u * u); }

#define LOBE_NODES 6
#define LOBE_MAX_CUTS 160

static int add_cut(double *cut, int count, double x, double lo, double hi)
{
    if (x > lo && x < hi && count < LOBE_MAX_CUTS)
        cut[count++] = x;
    return count;
}

/* cuts from p outwards at p +- w 4^k */
static int add_feature(double *cut, int count, double p, double w, double lo, double hi)
{
    count = add_cut(cut, count, p, lo, hi);
    for (double step = w; step < hi - lo; step *= 8.0) {
        count = add_cut(cut, count, p - step, lo, hi);
        count = add_cut(cut, count, p + step, lo, hi);
    }
    return count;
}

static int cmp_double(const void *a, const void *b)
{
    const double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

/* The least x^2 + (y / c)^2 on the circle of radius rho around (x0, y0) >= 0
 * (outside the origin): bisection on the derivative over the edge's angle in
 * [pi, 3 pi / 2], the quarter facing the origin. */
static double edge_least_u2(double x0, double y0, double rho, double c)
{
    double lo = PI, hi = 1.5 * PI;
    for (int it = 0; it < 60; ++it) {
        const double tau = 0.5 * (lo + hi), ct = cos(tau), st = sin(tau);
        if (-(x0 + rho * ct) * st + (y0 + rho * st) * ct / (c * c) > 0.0)
            hi = tau;
        else
            lo = tau;
    }
    const double tau = 0.5 * (lo + hi), px = x0 + rho * cos(tau), py = (y0 + rho * sin(tau)) / c;
    return px * px + py * py;
}

/* log G for one table entry (the disk average over Lambda at the disk's point of least u), and in
 * (mx, my) the lobe-weighted centroid of the disk in the lobe's round metric (x, y / c) from R */
static double lobe_log_ratio(int family, double rho, double c, double delta_u, double phi_s, const double *map,
                             const double *gw, double *mx, double *my, double *sx, double *sy)
{
    *mx = *my = *sx = *sy = 0.0;
    if (rho <= 0.0)
        return 0.0;
    const double ux = cos(phi_s), uy = c * sin(phi_s), un = sqrt(ux * ux + uy * uy);
    const double cx = ux / un, cy = uy / un, gamma = sqrt(cx * cx + cy * cy / (c * c));
    const double dist = fmax(rho + delta_u / gamma, 0.0), x0 = dist * cx, y0 = dist * cy;
    const double ref = dist > rho ? log_lobe(family, sqrt(edge_least_u2(x0, y0, rho, c))) : 0.0;
    double lo = x0 - rho, hi = x0 + rho;
    if (family == 0) { /* the Gaussian's factor exp(-x^2 / 2): drop x where it is e^-60 below its best */
        const double xm = fmin(fmax(0.0, lo), hi), lim = sqrt(120.0 + xm * xm);
        lo = fmax(lo, -lim);
        hi = fmin(hi, lim);
    }
    double cut[LOBE_MAX_CUTS + 2];
    int count = 0;
    cut[count++] = lo;
    cut[count++] = hi;
    /* the lobe's peak row x = 0 (or the disk's row nearest it) */
    const double xm = fmin(fmax(0.0, lo), hi);
    count = add_feature(cut, count, xm, family == 0 ? fmin(1.0, 1.0 / fmax(fabs(xm), 1e-9)) : fmax(0.5, 0.25 * fabs(xm)),
                        lo, hi);
    /* where a chord's end crosses y = 0, over about c of y */
    if (fabs(y0) < rho) {
        const double hx = sqrt(rho * rho - y0 * y0);
        const double w = fmin(fmax(c * fabs(y0) / fmax(hx, 1e-12), 1e-6), 1.0);
        count = add_feature(cut, count, x0 - hx, w, lo, hi);
        count = add_feature(cut, count, x0 + hx, w, lo, hi);
    }
    /* the disk's row nearest y = 0: there the chord's end is Y + q^2 / (2 rho) from y = 0 (q = x - x0, Y =
     * ||y0| - rho|), and the Gaussian's exponent -(Y + ...)^2 / (2 c^2) falls by one over q^2 = 2 rho c^2 / Y
     * (over y of about c when Y < c); GGX's polynomial tail is slower */
    const double gap = fabs(fabs(y0) - rho);
    const double w_row = family == 0 ? c * sqrt(2.0 * rho / fmax(gap, c)) : sqrt(2.0 * rho * (c + gap));
    count = add_feature(cut, count, x0, fmin(rho, fmax(w_row, 1e-6)), lo, hi);
    qsort(cut, (size_t)count, sizeof cut[0], cmp_double);
    /* two passes: the largest log value, then the sum */
    double best = -INFINITY, sum = 0.0, sum_x = 0.0, sum_xx = 0.0, sum_z = 0.0, sum_zz = 0.0;
    for (int pass = 0; pass < 2; ++pass)
        for (int k = 0; k + 1 < count; ++k) {
            const double a = cut[k], b = cut[k + 1];
            if (!(b > a))
                continue;
            for (int q = 0; q < LOBE_NODES; ++q) {
                const double x = a + (b - a) * map[q], dx = x - x0;
                const double h = sqrt(fmax(rho * rho - dx * dx, 0.0));
                if (pass == 0) {
                    best = fmax(best, log_chord(family, x, y0 - h, y0 + h, c) - ref);
                    continue;
                }
                double mz, mzz, lg;
                chord_moments(family, x, y0 - h, y0 + h, c, &mz, &mzz, &lg); /* GGX: lg is log_chord's value */
                const double lv = (family == 1 ? lg : log_chord(family, x, y0 - h, y0 + h, c)) - ref;
                if (lv > -INFINITY) {
                    const double wv = gw[q] * (b - a) * exp(lv - best);
                    sum += wv;
                    sum_x += wv * x;
                    sum_xx += wv * x * x;
                    sum_z += wv * mz;
                    sum_zz += wv * mzz;
                }
            }
        }
    if (!(sum > 0.0)) { /* nothing of the lobe: the centroid is the disk's point of least u */
        *mx = x0;
        *my = y0 / c;
        return -1e30;
    }
    *mx = sum_x / sum;
    *my = sum_z / sum;
    *sx = sqrt(fmax(sum_xx / sum - *mx * *mx, 0.0));
    *sy = sqrt(fmax(sum_zz / sum - *my * *my, 0.0));
    return best + log(sum) - log(PI * rho * rho);
}

void pn_depthmap_lobe_table_fill(float *out)
{
    pn_depthmap_lobe_family_fill(0, out);
    pn_depthmap_lobe_family_fill(1, out + PN_DM_LOBE_FAMILY);
}

void pn_depthmap_lobe_family_fill(int family, float *out)
{
    double gx[LOBE_NODES], gw[LOBE_NODES], map[LOBE_NODES];
    pn_gauss_legendre(LOBE_NODES, gx, gw);
    for (int k = 0; k < LOBE_NODES; ++k) {
        const double s = 0.5 * (gx[k] + 1.0);
        map[k] = 0.5 * (1.0 - cos(PI * s));
        gw[k] *= 0.25 * PI * sin(PI * s);
    }
    size_t at = 0;
    for (int l = 0; l < PN_DM_LOBE_C; ++l) {
            const double c = pow(PN_DM_LOBE_C_MIN, (double)l / (PN_DM_LOBE_C - 1));
            for (int p = 0; p < PN_DM_LOBE_P; ++p) {
                const double phi_s = HALF_PI * p / (PN_DM_LOBE_P - 1);
                const double gamma = 1.0 / sqrt(cos(phi_s) * cos(phi_s) + c * c * sin(phi_s) * sin(phi_s));
                for (int j = 0; j < PN_DM_LOBE_D; ++j)
                    for (int i = 0; i < PN_DM_LOBE_R; ++i) {
                        const double x = (double)i / (PN_DM_LOBE_R - 1), y = (double)j / (PN_DM_LOBE_D - 1);
                        const double rho = PN_DM_LOBE_RHO_0 * expm1(x * log1p(PN_DM_LOBE_RHO_MAX / PN_DM_LOBE_RHO_0));
                        const double t0 = edge_t(-rho * gamma), t1 = edge_t(PN_DM_LOBE_DELTA_MAX);
                        const double t = t0 + y * (t1 - t0);
                        const double delta_u = PN_DM_TABLE_SPREAD * t / (1.0 - fabs(t));
                        double mx, my, sx, sy;
                        const double lg = lobe_log_ratio(family, rho, c, delta_u, phi_s, map, gw, &mx, &my, &sx, &sy);
                        out[at++] = (float)lg;
                        out[at++] = (float)mx;
                        out[at++] = (float)my;
                        out[at++] = (float)sx;
                        out[at++] = (float)sy;
                    }
            }
        }
}

void pn_depthmap_cap_table_fill(float *out)
{
    phong_table_fill(out);
    pn_depthmap_lobe_table_fill(out + PN_DM_TABLE_PHONG_FLOATS);
}

/* Phong's table and the families of a mask (the others zero) */
static void masked_fill(int lobes, float *out)
{
    phong_table_fill(out);
    for (int family = 0; family < 2; ++family) {
        float *f = out + PN_DM_TABLE_PHONG_FLOATS + (size_t)family * PN_DM_LOBE_FAMILY;
        if (lobes & (1 << family))
            pn_depthmap_lobe_family_fill(family, f);
        else
            memset(f, 0, PN_DM_LOBE_FAMILY * sizeof(float));
    }
}

static void fill_mask1(float *out) { masked_fill(1, out); }
static void fill_mask2(float *out) { masked_fill(2, out); }
static void fill_mask3(float *out) { masked_fill(3, out); }

static const char table_keys[4] = {0, 0, 0, 0};

pn_status pn_depthmap_cap_table(pn_context ctx, int lobes, cl_mem *out)
{
    /* One cache entry per set of families: Phong's table alone (0.4 s to build) or with the Blinn-Phong
       and/or GGX families after it, built only for a scene that has such a lobe. */
    static void (*const fills[4])(float *) = {phong_table_fill, fill_mask1, fill_mask2, fill_mask3};
    static const char *const what[4] = {"the cap-average table", "the cap-average tables with Blinn-Phong's",
                                        "the cap-average tables with GGX's",
                                        "the cap-average tables with Blinn-Phong's and GGX's"};
    lobes &= 3;
    return pn_context_table(ctx, &table_keys[lobes], lobes ? PN_DM_TABLE_FLOATS : PN_DM_TABLE_PHONG_FLOATS,
                            fills[lobes], what[lobes], out);
}
