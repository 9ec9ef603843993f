/* Spherical Gaussians (SGs) on the device: evaluation, integrals, products,
 * SG x clamped cosine, and the Integral Spherical Gaussian (ISG) over lat-long
 * patches of a lobe's frame (docs/isg.md; float64 twin: tests/isg64.py).
 *
 * Interface (stable; every function is float32, OpenCL C 1.2):
 *
 *   pn_sg                                  axis (unit), sharpness lambda >= 0, RGB amplitude
 *   pn_sg pn_sg_load(global const float4 *lobes, int i)
 *                                          lobe i of an array of pn_sg_lobe (penumbra.h):
 *                                          2 float4 per lobe, (axis, lambda), (amplitude, 0)
 *   float  pn_sg_eval(float3 v, float3 axis, float lambda)   exp(lambda (v.axis - 1)), unit amplitude
 *   float3 pn_sg_eval_rgb(pn_sg g, float3 v)                 amplitude * pn_sg_eval
 *   float  pn_sg_integral(float lambda)            over the sphere: 4 pi (1 - e^-2l) / (2l), by expm1
 *   float  pn_sg_hemisphere_integral(float lambda) over the lobe's own hemisphere: H = 2 pi (1 - e^-l) / l
 *   pn_sg  pn_sg_product(pn_sg a, pn_sg b)         the product lobe (amplitudes multiply per channel)
 *   float3 pn_sg_inner_product(pn_sg a, pn_sg b)   integral of a * b over the sphere
 *   float  pn_sg_cosine(float t, float lambda)     integral of exp(lambda (v.axis - 1)) max(v.n, 0),
 *                                                  t = axis.n (closed form, docs/isg.md 3.3)
 *   float3 pn_sg_irradiance(pn_sg g, float3 n)     amplitude * pn_sg_cosine(axis.n, lambda)
 *   float  pn_sg_cosine_seed(float t, float lambda) the seed's single-SG cosine (for comparison)
 *
 *   ISG frame (the one place it is stated; docs/isg.md section 2): a lobe's
 *   local frame (x, y, z) has the lobe axis as z and
 *       Omega(theta, phi) = sin(theta) cos(phi) x + cos(theta) y + sin(theta) sin(phi) z,
 *   theta in [0, pi] from +y, phi in [0, 2 pi) from +x towards +z; the axis is
 *   at (pi/2, pi/2) and phi in [0, pi] is the lobe's front hemisphere.
 *   void   pn_sg_frame(float3 z, float3 *x, float3 *y)     a right-handed frame (x, y, z) around the axis
 *   float2 pn_isg_angles(float3 d, float3 x, float3 y, float3 z)   (theta, phi) of unit d, phi in [0, 2 pi)
 *   float3 pn_isg_direction(float theta, float phi, float3 x, float3 y, float3 z)   the inverse
 *
 *   ISG evaluation, normalised by H(lambda), from the table built by the host
 *   (capi/src/core/isg_table.c; pn_isg_table in penumbra.h; PN_ISG_TABLE_FLOATS
 *   floats, a read-only buffer):
 *   float pn_isg(float lambda, float theta, float phi, global const float *table)
 *         S_hat(theta, phi) = (1/H) int_0^theta int_0^phi exp(lambda (sin t sin p - 1)) sin t dp dt,
 *         theta in [0, pi], phi in [0, 2 pi] (clamped); S_hat(pi, pi) = 1, S_hat(pi, 2 pi) = 1 + e^-lambda.
 *         Max abs error 0.0040 against float64 quadrature for lambda in [1e-3, 1e4] (and beyond).
 *   float pn_isg_patch(float lambda, float theta0, float theta1, float phi0, float phi1, global const float *table)
 *         the patch [theta0, theta1] x [phi0, phi1] as a fraction of H: four-corner inclusion-exclusion
 *         (multiply by H(lambda) * amplitude for the integral of the lobe over the patch).
 *   float pn_isg_seed(float lambda, float theta, float phi)       the seed's sigmoid fit (eq. 14),
 *         defined on [0, pi]^2 (phi clamped to pi): error up to 0.59 at lambda = 1
 *   float pn_isg_patch_seed(float lambda, float theta0, float theta1, float phi0, float phi1)
 *
 *   BRDF lobes as SGs (docs/isg.md 6; twin isg64.brdf_sg):
 *   pn_sg  pn_brdf_sg(pn_material m, float3 n, float3 v)   the specular lobe f_lobe(v, l) ~ G(l), without
 *          k_s, white amplitude (Phong: axis R, lambda = n; Blinn-Phong and GGX: the half-vector lobe warped
 *          to l as in Wang et al. 2009, GGX with its masking and 1 / (4 n.l n.v) at the warped axis)
 *   int    pn_brdf_sgs(pn_material m, float3 n, float3 v, pn_sg *out)   the lobe as 1 SG (pn_brdf_sg) or,
 *          Ashikhmin-Shirley, as up to PN_BRDF_MAX_SGS = 7 SGs (pn_as_sgs; docs/isg.md 6): returns the count
 *   float3 pn_sg_reflected(pn_sg light, pn_sg lobe, float3 n)  int light(l) lobe(l) max(n.l, 0) dl
 *          (the product lobe's clamped-cosine integral); the diffuse term is pn_sg_irradiance * albedo / pi
 */
#ifndef PN_COMMON_SG_CL
#define PN_COMMON_SG_CL

#include "common/brdf.cl"
#include "common/math.cl"

typedef struct {
    float3 axis;
    float sharpness;
    float3 amplitude;
} pn_sg;

inline pn_sg pn_sg_load(global const float4 *lobes, int i)
{
    pn_sg g;
    const float4 a = lobes[2 * i], b = lobes[2 * i + 1];
    g.axis = a.xyz;
    g.sharpness = a.w;
    g.amplitude = b.xyz;
    return g;
}

inline float pn_sg_eval(float3 v, float3 axis, float lambda)
{
    return exp(lambda * (dot(v, axis) - 1.0f));
}

inline float3 pn_sg_eval_rgb(pn_sg g, float3 v)
{
    return g.amplitude * pn_sg_eval(v, g.axis, g.sharpness);
}

/* (1 - e^-x) / x for x >= 0 without cancellation; 1 at 0. */
inline float pn_one_minus_exp_over(float x)
{
    return x > 0.0f ? -expm1(-x) / x : 1.0f;
}

inline float pn_sg_integral(float lambda)
{
    /* 2 pi (1 - e^-2l) / l: 2l may overflow where l does not */
    return lambda > 0.0f ? PN_TWO_PI * -expm1(-2.0f * lambda) / lambda : 2.0f * PN_TWO_PI;
}

inline float pn_sg_hemisphere_integral(float lambda)
{
    return PN_TWO_PI * pn_one_minus_exp_over(lambda);
}

/* lam1 (v.a1 - 1) + lam2 (v.a2 - 1) = v.(lam1 a1 + lam2 a2) - lam1 - lam2, in the
 * cancellation-free forms of docs/isg.md 1: lam_m^2 = (l1 - l2)^2 + l1 l2 |a1 + a2|^2
 * (nearly opposite lobes), lam_m - l1 - l2 = -l1 l2 |a1 - a2|^2 / (l1 + l2 + lam_m) <= 0
 * (nearly aligned; never overflows). Exactly opposite equal lobes: lam_m = 0, axis a1. */
inline pn_sg pn_sg_product(pn_sg a, pn_sg b)
{
    const float l1 = a.sharpness, l2 = b.sharpness;
    const float3 sum = a.axis + b.axis, diff = a.axis - b.axis;
    const float lm = sqrt((l1 - l2) * (l1 - l2) + l1 * l2 * dot(sum, sum));
    const float denom = l1 + l2 + lm;
    const float expo = denom > 0.0f ? -l1 * l2 * dot(diff, diff) / denom : 0.0f;
    const float3 v = (0.5f * (l1 + l2)) * sum + (0.5f * (l1 - l2)) * diff;
    const float norm = length(v);
    pn_sg m;
    m.axis = norm > 0.0f ? v / norm : a.axis;
    m.sharpness = lm;
    m.amplitude = a.amplitude * b.amplitude * exp(expo);
    return m;
}

inline float3 pn_sg_inner_product(pn_sg a, pn_sg b)
{
    const pn_sg m = pn_sg_product(a, b);
    return m.amplitude * pn_sg_integral(m.sharpness);
}

/* ------------------------------------------------------------ SG x clamped cosine */

/* J(x) = int_0^1 e^(x u) u du for x <= 0: series below |x| = 1, closed form beyond. */
inline float pn_exp_moment(float x)
{
    if (fabs(x) < 1.0f) {
        float s = 0.0f, term = 1.0f;
        for (int k = 0; k < 12; ++k) {
            s += term / (float)(k + 2);
            term *= x / (float)(k + 1);
        }
        return s;
    }
    return (exp(x) * (x - 1.0f) + 1.0f) / (x * x);
}

/* e^-x I_1(x) / x, x >= 0: power series below 3.75, Abramowitz & Stegun 9.8.4 above. */
inline float pn_bessel_i1e_over_x(float x)
{
    if (x < 3.75f) {
        const float h2 = 0.25f * x * x;
        float s = 0.0f, term = 0.5f; /* (x/2)^(2k) / (2 k! (k+1)!) */
        for (int k = 0; k < 14; ++k) {
            s += term;
            term *= h2 / (float)((k + 1) * (k + 2));
        }
        return s * exp(-x);
    }
    const float y = 3.75f / x;
    float p = 0.02282967f + y * (-0.02895312f + y * (0.01787654f - y * 0.00420059f));
    p = 0.39894228f + y * (-0.03988024f + y * (-0.00362018f + y * (0.00163801f + y * (-0.01031555f + y * p))));
    return p / (x * sqrt(x));
}

#define PN_SG_COSINE_SHAPE_K 0.9f

/* docs/isg.md 3.3: E(t) = t C1 / 2 (odd part, exact) + O(t), the even part
 * interpolated between its exact values O(0) = E(0) = 2 pi e^-l I1(l) / l and
 * O(1) = (E(1) + E(-1)) / 2 by q(t) = t erf(k t) + (e^(-k^2 t^2) - 1) / (k sqrt pi),
 * k = 0.9 sqrt(l / 2). Max error 0.40 % of E(1) (tests/test_sg_kernels.py). */
inline float pn_sg_cosine(float t, float lambda)
{
    t = clamp(t, -1.0f, 1.0f);
    const float jm = pn_exp_moment(-lambda);
    const float up = pn_one_minus_exp_over(lambda) - jm; /* e^-l J(l) */
    const float down = exp(-lambda) * jm;                /* e^-l J(-l) */
    const float e_zero = PN_TWO_PI * pn_bessel_i1e_over_x(lambda);
    const float o1 = PN_PI * (up + down);
    const float odd = PN_PI * t * (up - down);
    const float k = PN_SG_COSINE_SHAPE_K * sqrt(0.5f * lambda);
    const float ta = fabs(t);
    float shape;
    if (k * ta > 1e-4f) {
        const float kt = k * ta;
        const float qt = ta * erf(kt) + ta * expm1(-kt * kt) / (kt * 1.7724538509f);
        const float q1 = erf(k) + expm1(-k * k) / (k * 1.7724538509f);
        shape = qt / q1;
    } else {
        shape = ta * ta; /* the small-k limit of q(t) / q(1) */
    }
    return fmax(odd + e_zero + (o1 - e_zero) * shape, 0.0f);
}

inline float3 pn_sg_irradiance(pn_sg g, float3 n)
{
    return g.amplitude * pn_sg_cosine(dot(g.axis, n), g.sharpness);
}

/* The seed's cosine lobe G(v; n, 2.133, 1.170) of [WRG*09], by the inner product. */
inline float pn_sg_cosine_seed(float t, float lambda)
{
    pn_sg a, c;
    a.axis = (float3)(sqrt(fmax(0.0f, 1.0f - t * t)), 0.0f, t);
    a.sharpness = lambda;
    a.amplitude = (float3)(1.0f);
    c.axis = (float3)(0.0f, 0.0f, 1.0f);
    c.sharpness = 2.133f;
    c.amplitude = (float3)(1.170f);
    return pn_sg_inner_product(a, c).x;
}

/* ------------------------------------------------------------------ BRDF lobes as SGs */

/* G1(c) / c for the GGX masking, finite as c -> 0. */
inline float pn_ggx_g1_over_c(float c, float a2)
{
    return 2.0f / (c + sqrt(a2 + (1.0f - a2) * c * c));
}

inline pn_sg pn_brdf_sg(pn_material m, float3 n, float3 v)
{
    const float nv = dot(n, v), cv = fmax(nv, PN_MIN_COS_VIEW);
    pn_sg g;
    g.axis = normalize(2.0f * nv * n - v);
    if (m.lobe == PN_LOBE_PHONG) {
        g.sharpness = m.shininess;
        g.amplitude = (float3)((m.shininess + 2.0f) * PN_INV_TWO_PI);
    } else if (m.lobe == PN_LOBE_BLINN_PHONG) {
        /* dw_l = 4 (h.v) dw_h at h = n */
        g.sharpness = m.shininess / (4.0f * cv);
        g.amplitude = (float3)((m.shininess + 8.0f) * (0.125f * PN_INV_PI));
    } else {
        /* D(h) ~ exp(2/a^2 (h.n - 1)) / (pi a^2): the same curvature at h = n */
        const float a2 = m.roughness * m.roughness, nl = fmax(dot(n, g.axis), 0.0f);
        g.sharpness = 2.0f / a2 / (4.0f * cv);
        g.amplitude = (float3)(PN_INV_PI / a2 * pn_ggx_g1_over_c(cv, a2) * pn_ggx_g1_over_c(nl, a2) * 0.25f);
    }
    return g;
}

/* The anisotropic Ashikhmin-Shirley lobe as 7 SGs (docs/isg.md 6). Its
 * half-vector distribution (N.H)^e is, to second order at H = N, the
 * anisotropic Gaussian exp(-(n_u x^2 + n_v y^2) / 2) in the tangent-plane
 * coordinates x = H.u, y = H.w: widths s_t = 1/sqrt(n_long) along the long
 * axis a (u when n_u <= n_v, else w) and s_s = 1/sqrt(n_short) across it.
 * Seven isotropic SGs of width s_c >= s_s on a row along a, spaced by d,
 * weighted by a Gaussian of variance s_t^2 - s_c^2 (the convolution of the
 * two has variance s_t^2), sum to it; the scale keeps its integral
 * 2 pi s_t s_s. s_c = s_s max(1, sqrt(r / 4.3)) and d = min(0.8 s_w, 2.4 s_c),
 * r = s_t / s_s, are the fitted rules of docs/isg.md 6. Each half-vector SG
 * is warped to l like Blinn-Phong's (axis the mirror of v about its centre
 * h_k, sharpness / (4 h_k.v)), times the lobe's other factors
 * sqrt((n_u+1)(n_v+1)) / (8 pi (H.L) max(N.L, N.V)) at h_k. A nearly
 * isotropic lobe (s_w <= 0.05 s_c) is one SG. Exponents below
 * PN_AS_SG_MIN_EXPONENT are taken as it: the Gaussian model needs a peak. */
#define PN_BRDF_MAX_SGS 7
#define PN_AS_SG_MIN_EXPONENT 1.0f

inline int pn_as_sgs(pn_material m, float3 n, float3 v, pn_sg *out)
{
    const float nv = dot(n, v), cv = fmax(nv, PN_MIN_COS_VIEW);
    float3 t, b;
    pn_frame(n, &t, &b);
    const float3 u = m.tangent.x * t + m.tangent.y * b;
    const float nu = fmax(m.shininess, PN_AS_SG_MIN_EXPONENT), nw = fmax(m.shininess_v, PN_AS_SG_MIN_EXPONENT);
    const float3 a = nu <= nw ? u : cross(n, u);
    const float var_t = 1.0f / fmin(nu, nw), var_s = 1.0f / fmax(nu, nw);
    const float r = sqrt(var_t / var_s);
    const float var_c = var_s * fmax(1.0f, r / 4.3f);
    const float s_c = sqrt(var_c), s_w = sqrt(fmax(var_t - var_c, 0.0f));
    const int count = s_w > 0.05f * s_c ? PN_BRDF_MAX_SGS : 1;
    const float d = fmin(0.8f * s_w, 2.4f * s_c);
    const float norm = sqrt((m.shininess + 1.0f) * (m.shininess_v + 1.0f)) * (0.125f * PN_INV_PI);
    float weights[PN_BRDF_MAX_SGS], total = 0.0f;
    for (int k = 0; k < count; ++k) {
        const float x = (k - 0.5f * (count - 1)) * d;
        weights[k] = count == 1 ? 1.0f : exp(-0.5f * x * x / (s_w * s_w));
        total += weights[k];
    }
    const float scale = norm * sqrt(var_t * var_s) / (var_c * total);
    for (int k = 0; k < count; ++k) {
        const float x = (k - 0.5f * (count - 1)) * d;
        float cx;
        const float sx = sincos(x, &cx);
        const float3 h = cx * n + sx * a;
        const float hv_raw = dot(h, v), hv = fmax(hv_raw, PN_MIN_COS_VIEW);
        out[k].axis = normalize(2.0f * hv_raw * h - v);
        out[k].sharpness = 1.0f / var_c / (4.0f * hv);
        out[k].amplitude = (float3)(scale * weights[k] / (hv * fmax(dot(n, out[k].axis), cv)));
    }
    return count;
}

inline int pn_brdf_sgs(pn_material m, float3 n, float3 v, pn_sg *out)
{
    if (m.lobe == PN_LOBE_ASHIKHMIN_SHIRLEY)
        return pn_as_sgs(m, n, v, out);
    out[0] = pn_brdf_sg(m, n, v);
    return 1;
}

inline float3 pn_sg_reflected(pn_sg light, pn_sg lobe, float3 n)
{
    const pn_sg m = pn_sg_product(light, lobe);
    return m.amplitude * pn_sg_cosine(dot(n, m.axis), m.sharpness);
}

/* ------------------------------------------------------------------ the ISG frame */

/* Duff et al. 2017 branchless orthonormal basis: (x, y, z) right-handed. */
inline void pn_sg_frame(float3 z, float3 *x, float3 *y)
{
    const float s = copysign(1.0f, z.z);
    const float a = -1.0f / (s + z.z), b = z.x * z.y * a;
    *x = (float3)(1.0f + s * z.x * z.x * a, s * b, -s * z.x);
    *y = (float3)(b, s + z.y * z.y * a, -z.y);
}

inline float2 pn_isg_angles(float3 d, float3 x, float3 y, float3 z)
{
    const float cy = clamp(dot(d, y), -1.0f, 1.0f);
    const float sy = sqrt(fmax(0.0f, 1.0f - cy * cy));
    float phi = pn_atan2(dot(d, z), dot(d, x));
    phi = phi < 0.0f ? phi + PN_TWO_PI : phi;
    return (float2)(pn_atan2(sy, cy), phi);
}

inline float3 pn_isg_direction(float theta, float phi, float3 x, float3 y, float3 z)
{
    const float st = sin(theta);
    return st * cos(phi) * x + cos(theta) * y + st * sin(phi) * z;
}

/* ------------------------------------------------------------------ the ISG table */

/* Layout of the table (docs/isg.md 3; built in float64 by capi/src/core/isg_table.c):
 * four blocks of PN_ISG_TABLE_LAMBDAS x PN_ISG_TABLE_RHO floats, row i at
 * lambda_i = 1e-3 * 10^(i / 8), each row T(rho) = F(pi/2 + x) - 1/2 of a marginal CDF F
 * at rho_j = j / 32: front theta, front phi (rho = erf(k x) / erf(k pi/2), k = sqrt(l/2)),
 * back theta, back phi (rho = x / (pi/2); rows with lambda > 40 are zero). */
#define PN_ISG_TABLE_LAMBDAS 57
#define PN_ISG_TABLE_RHO 33
#define PN_ISG_TABLE_PER_DECADE 8.0f
#define PN_ISG_TABLE_LAMBDA_MIN 1e-3f
#define PN_ISG_TABLE_BLOCK (PN_ISG_TABLE_LAMBDAS * PN_ISG_TABLE_RHO)
#define PN_ISG_TABLE_FLOATS (4 * PN_ISG_TABLE_BLOCK)
#define PN_ISG_BACK_LAMBDA_MAX 40.0f

/* Row position of lambda: u in [0, L - 1], clamped (the erf warp keeps lambda > 1e4 exact). */
inline float pn_isg_row(float lambda)
{
    const float u = log10(fmax(lambda, 1e-30f) / PN_ISG_TABLE_LAMBDA_MIN) * PN_ISG_TABLE_PER_DECADE;
    return clamp(u, 0.0f, (float)(PN_ISG_TABLE_LAMBDAS - 1));
}

/* Bilinear lookup of block `b` at row position u and rho in [0, 1]. */
inline float pn_isg_lookup(global const float *table, int b, float u, float rho)
{
    const int i0 = min((int)u, PN_ISG_TABLE_LAMBDAS - 2);
    const float fu = u - (float)i0;
    const float v = clamp(rho, 0.0f, 1.0f) * (float)(PN_ISG_TABLE_RHO - 1);
    const int j0 = min((int)v, PN_ISG_TABLE_RHO - 2);
    const float fv = v - (float)j0;
    global const float *r0 = table + b * PN_ISG_TABLE_BLOCK + i0 * PN_ISG_TABLE_RHO + j0;
    global const float *r1 = r0 + PN_ISG_TABLE_RHO;
    return mix(mix(r0[0], r0[1], fv), mix(r1[0], r1[1], fv), fu);
}

/* rho of the front marginals at |x| = |angle - pi/2|. */
inline float pn_isg_front_rho(float ax, float k, float inv_erf_half_pi)
{
    return erf(k * ax) * inv_erf_half_pi;
}

/* F(angle) on [0, pi] from its tabulated odd part about pi/2. */
inline float pn_isg_cdf(global const float *table, int b, float u, float angle, float k, float inv_erf_half_pi)
{
    const float x = angle - 0.5f * PN_PI, ax = fabs(x);
    const float rho = b < 2 ? pn_isg_front_rho(ax, k, inv_erf_half_pi) : ax * (2.0f * PN_INV_PI);
    return 0.5f + copysign(pn_isg_lookup(table, b, u, rho), x);
}

inline float pn_isg(float lambda, float theta, float phi, global const float *table)
{
    theta = clamp(theta, 0.0f, PN_PI);
    phi = clamp(phi, 0.0f, PN_TWO_PI);
    const float u = pn_isg_row(lambda);
    const float k = sqrt(0.5f * lambda);
    const float inv = 1.0f / erf(k * 0.5f * PN_PI);
    float s = pn_isg_cdf(table, 0, u, theta, k, inv) * pn_isg_cdf(table, 1, u, fmin(phi, PN_PI), k, inv);
    if (phi > PN_PI && lambda <= PN_ISG_BACK_LAMBDA_MAX)
        s += exp(-lambda) * pn_isg_cdf(table, 2, u, theta, k, inv) * pn_isg_cdf(table, 3, u, phi - PN_PI, k, inv);
    return s;
}

inline float pn_isg_patch(float lambda, float theta0, float theta1, float phi0, float phi1, global const float *table)
{
    return pn_isg(lambda, theta1, phi1, table) - pn_isg(lambda, theta0, phi1, table) -
           pn_isg(lambda, theta1, phi0, table) + pn_isg(lambda, theta0, phi0, table);
}

/* ------------------------------------------------------------------ the seed's fit */

inline float pn_isg_seed_poly(float x, float c4, float c3, float c2, float c1, float c0)
{
    return (((c4 * x + c3) * x + c2) * x + c1) * x + c0;
}

inline float pn_isg_sigmoid(float x)
{
    return 0.5f * (1.0f + tanh(0.5f * x));
}

inline float pn_isg_seed(float lambda, float theta, float phi)
{
    const float x = 0.01f * lambda;
    const float g = pn_isg_seed_poly(x, -2.6856e-6f, 7e-4f, -0.0571f, 3.9529f, 17.6028f);
    const float h = pn_isg_seed_poly(x, -2.6875e-6f, 7e-4f, -0.0592f, 3.9900f, 17.5003f);
    theta = clamp(theta, 0.0f, PN_PI);
    phi = clamp(phi, 0.0f, PN_PI);
    return pn_isg_sigmoid(g * (theta - 0.5f * PN_PI)) * pn_isg_sigmoid(h * (phi - 0.5f * PN_PI));
}

inline float pn_isg_patch_seed(float lambda, float theta0, float theta1, float phi0, float phi1)
{
    return pn_isg_seed(lambda, theta1, phi1) - pn_isg_seed(lambda, theta0, phi1) - pn_isg_seed(lambda, theta1, phi0) +
           pn_isg_seed(lambda, theta0, phi0);
}

#endif
