/* Shared constants and small helpers for every penumbra kernel (OpenCL C 1.2). */
#ifndef PN_COMMON_MATH_CL
#define PN_COMMON_MATH_CL

#define PN_PI 3.14159265358979323846f
#define PN_TWO_PI 6.28318530717958647692f
#define PN_INV_PI 0.31830988618379067154f
#define PN_INV_TWO_PI 0.15915494309189533577f

/* Forced inlining for the 8-lane helpers: PoCL leaves some inline
 * functions as calls, passing their lane arrays through the stack. */
#define PN_LANES_INLINE inline __attribute__((always_inline))

/* Marks background pixels and ray misses (matches PN_BACKGROUND in penumbra.h). */
#define PN_BACKGROUND 0xFFFFFFFFu

/* Rotation about +y by an angle given as (cos, sin). */
inline float3 pn_rotate_y(float3 d, float c, float s)
{
    return (float3)(c * d.x + s * d.z, d.y, -s * d.x + c * d.z);
}

/* atan to 2.5e-7 rad: an odd polynomial on [0, 1] (least-squares fit of
 * degree 13), atan(x) = pi/2 - atan(1/x) above. Per-sample angles (the
 * height-field horizon search, the FIV grid lookup) took a large part of
 * those kernels' time with the built-in atan/atan2/acos on CPUs. */
/* The odd polynomial of atan on [0, 1] in t2 = t * t, without the factor t;
 * a macro so that the scalar and the vector versions (heightfield.cl) share it. */
#define PN_ATAN_POLY(p, t2)                 \
    p = 6.814212410e-03f;                   \
    p = p * (t2) - 3.361149911e-02f;        \
    p = p * (t2) + 7.963201613e-02f;        \
    p = p * (t2) - 1.323379574e-01f;        \
    p = p * (t2) + 1.980793360e-01f;        \
    p = p * (t2) - 3.331738094e-01f;        \
    p = p * (t2) + 9.999961155e-01f

inline float pn_atan(float x)
{
    const float a = fabs(x), t = a > 1.0f ? 1.0f / a : a, t2 = t * t;
    float p;
    PN_ATAN_POLY(p, t2);
    const float r = t * p;
    return copysign(a > 1.0f ? M_PI_2_F - r : r, x);
}

/* atan2(y, x) in [-pi, pi] from pn_atan (2.5e-7 rad); 0 at the origin. */
inline float pn_atan2(float y, float x)
{
    const float ax = fabs(x), ay = fabs(y), hi = fmax(ax, ay), lo = fmin(ax, ay);
    const float t = hi > 0.0f ? lo / hi : 0.0f;
    float a = pn_atan(t);
    a = ay > ax ? M_PI_2_F - a : a;
    a = x < 0.0f ? PN_PI - a : a;
    return copysign(a, y);
}

/* pn_atan and pn_atan2 for 8 lanes, each lane doing the scalar code's
 * operations in the same order (the kernels that shade 8 pixels per
 * work-item: fiv.cl, unshadowed.cl, the background pass). */
PN_LANES_INLINE float8 pn_atan8(float8 x)
{
    const float8 a = fabs(x), t = select(a, 1.0f / a, a > 1.0f), t2 = t * t;
    float8 p;
    PN_ATAN_POLY(p, t2);
    const float8 r = t * p;
    return copysign(select(r, M_PI_2_F - r, a > 1.0f), x);
}

PN_LANES_INLINE float8 pn_atan2_8(float8 y, float8 x)
{
    const float8 ax = fabs(x), ay = fabs(y), hi = fmax(ax, ay), lo = fmin(ax, ay);
    const float8 t = select((float8)(0.0f), lo / hi, hi > 0.0f);
    /* pn_atan8(t) for t in [0, 1]: its branch for t > 1 (a divide in every
     * lane) is never taken, and t >= +0 needs no copysign */
    const float8 t2 = t * t;
    float8 a;
    PN_ATAN_POLY(a, t2);
    a = t * a;
    a = select(a, M_PI_2_F - a, ay > ax);
    a = select(a, PN_PI - a, x < 0.0f);
    return copysign(a, y);
}

/* Unit vectors t, b completing n to an orthonormal frame (Duff et al. 2017). */
inline void pn_frame(float3 n, float3 *t, float3 *b)
{
    float s = n.z >= 0.0f ? 1.0f : -1.0f;
    float a = -1.0f / (s + n.z);
    float c = n.x * n.y * a;
    *t = (float3)(1.0f + s * n.x * n.x * a, s * c, -s * n.x);
    *b = (float3)(c, s + n.y * n.y * a, -n.y);
}

inline float pn_luminance(float3 rgb)
{
    return 0.2126f * rgb.x + 0.7152f * rgb.y + 0.0722f * rgb.z;
}

#endif
