/* Real spherical harmonics on the device (docs/heightfield.md): orthonormal
 * y_lm, index l*l + l + m, Condon–Shortley phase, up to 6 bands; evaluation,
 * rotation about Z, and the zonal integrals of a spherical cap. The float64
 * host versions are in capi/src/sh_tables.c, the numpy twin in
 * tests/heightfield64.py. */
#ifndef PN_SH_CL
#define PN_SH_CL

#define PN_SH_MAX_BANDS 6
#define PN_SH_MAX_COEFFS 36

/* K_l^m (times sqrt 2 for m > 0), index l(l+1)/2 + m. */
constant float pn_sh_norm[21] = {
    2.820947918e-01f, 4.886025119e-01f, 4.886025119e-01f, 6.307831305e-01f, 3.641828102e-01f,
    1.820914051e-01f, 7.463526652e-01f, 3.046971996e-01f, 9.635371475e-02f, 3.933623933e-02f,
    8.462843753e-01f, 2.676186174e-01f, 6.307831305e-02f, 1.685838828e-02f, 5.960340338e-03f,
    9.356025796e-01f, 2.415715473e-01f, 4.565273129e-02f, 9.318824751e-03f, 2.196468058e-03f,
    6.945841871e-04f};

/* y[0 .. nb*nb) at the unit direction d (SH frame). P_l^m(cos) / sin^m is
 * a polynomial in d.z (the recurrences below), and sin^m (cos mφ, sin mφ) is
 * (d.x + i d.y)^m, so nothing divides by sin at the poles. */
inline void pn_sh_store(float *y, int l, int m, float q, float re, float im)
{
    const float k = pn_sh_norm[l * (l + 1) / 2 + m] * q;
    if (m == 0) {
        y[l * l + l] = k;
    } else {
        y[l * l + l + m] = k * re;
        y[l * l + l - m] = k * im;
    }
}

inline void pn_sh_eval(float3 d, int nb, float *y)
{
    float re = 1.0f, im = 0.0f; /* (x + iy)^m */
    float qmm = 1.0f;           /* Q_m^m = (-1)^m (2m - 1)!! */
    for (int m = 0; m < nb; ++m) {
        pn_sh_store(y, m, m, qmm, re, im);
        float qa = qmm, qb = (2.0f * m + 1.0f) * d.z * qmm;
        if (m + 1 < nb)
            pn_sh_store(y, m + 1, m, qb, re, im);
        for (int l = m + 2; l < nb; ++l) {
            const float qc = ((2.0f * l - 1.0f) * d.z * qb - (l + m - 1.0f) * qa) / (float)(l - m);
            pn_sh_store(y, l, m, qc, re, im);
            qa = qb;
            qb = qc;
        }
        const float nre = re * d.x - im * d.y, nim = re * d.y + im * d.x;
        re = nre;
        im = nim;
        qmm *= -(2.0f * m + 1.0f);
    }
}

/* Turns the function of c about Z by the angle whose cosine and sine are
 * (ca, sa): g(φ) = f(φ - α). */
inline void pn_sh_zrotate(float *c, int nb, float ca, float sa)
{
    float cm = ca, sm = sa; /* cos mα, sin mα */
    for (int m = 1; m < nb; ++m) {
        for (int l = m; l < nb; ++l) {
            const float a = c[l * l + l + m], b = c[l * l + l - m];
            c[l * l + l + m] = a * cm - b * sm;
            c[l * l + l - m] = a * sm + b * cm;
        }
        const float ncm = cm * ca - sm * sa, nsm = sm * ca + cm * sa;
        cm = ncm;
        sm = nsm;
    }
}

/* 2π ∫_{1-s}^1 P_l(t) dt for l < nb, stable for small caps: with
 * P_l(1 - σ) = Σ_k (-1)^k (l+k)! / ((l-k)! (k!)^2 2^k) σ^k the integral is a
 * polynomial in s = 1 - cos α with no cancellation. */
inline void pn_sh_cap(float s, int nb, float *z)
{
    for (int l = 0; l < nb; ++l) {
        float coef = 1.0f, sum = 0.0f, sp = s; /* coef: term k of P_l(1 - σ); sp = s^(k+1) */
        for (int k = 0; k <= l; ++k) {
            sum += coef * sp / (float)(k + 1);
            /* ratio of term k+1 to term k: -(l+k+1)(l-k) / (2 (k+1)^2) */
            coef *= -(float)((l + k + 1) * (l - k)) / (2.0f * (float)((k + 1) * (k + 1)));
            sp *= s;
        }
        z[l] = 2.0f * M_PI_F * sum;
    }
}

#endif
