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

/* G-buffer planes in lanes (8 consecutive pixels, one per lane): x, y, z of
 * 8 float4 by four 8-wide loads and shuffles, instead of 8 scalar loads each
 * put into 3 lanes (docs/performance.md, FIV, "The floor round"). No 16-wide
 * type: its 512-bit instructions slowed the whole kernel down on this CPU. */
PN_LANES_INLINE void pn_load_xyz8(global const float4 *p, float8 *x, float8 *y, float8 *z)
{
    global const float *f = (global const float *)p;
    const float8 a = vload8(0, f), b = vload8(1, f), c = vload8(2, f), d = vload8(3, f);
    const float8 ab_x = (float8)(a.s04, b.s04, a.s15, b.s15), cd_x = (float8)(c.s04, d.s04, c.s15, d.s15);
    const float8 ab_z = (float8)(a.s26, b.s26, a.s37, b.s37), cd_z = (float8)(c.s26, d.s26, c.s37, d.s37);
    *x = (float8)(ab_x.s0123, cd_x.s0123);
    *y = (float8)(ab_x.s4567, cd_x.s4567);
    *z = (float8)(ab_z.s0123, cd_z.s0123);
}

/* 8 float4 (r, g, b, a) stored from lanes, by shuffles and four 8-wide stores. */
PN_LANES_INLINE void pn_store_rgba8(global float4 *p, float8 r, float8 g, float8 b, float8 a)
{
    global float *f = (global float *)p;
    vstore8((float8)(r.s0, g.s0, b.s0, a.s0, r.s1, g.s1, b.s1, a.s1), 0, f);
    vstore8((float8)(r.s2, g.s2, b.s2, a.s2, r.s3, g.s3, b.s3, a.s3), 1, f);
    vstore8((float8)(r.s4, g.s4, b.s4, a.s4, r.s5, g.s5, b.s5, a.s5), 2, f);
    vstore8((float8)(r.s6, g.s6, b.s6, a.s6, r.s7, g.s7, b.s7, a.s7), 3, f);
}

/* x, y, z of a G-buffer plane's 8 pixels from index `row` on into lanes:
 * pn_load_xyz8 when all 8 are there (`full`), else lane by lane for the
 * lanes of `in_row` (0 in the others). */
PN_LANES_INLINE void pn_load_row8(global const float4 *plane, int row, bool full, int8 in_row, float8 *x, float8 *y,
                                  float8 *z)
{
    if (full) {
        pn_load_xyz8(plane + row, x, y, z);
        return;
    }
    float8 vx = 0.0f, vy = 0.0f, vz = 0.0f;
#define PN_LOAD_ROW_LANE(l)                              \
    if (in_row.s##l) {                                   \
        float4 v = plane[row + l];                       \
        vx.s##l = v.x, vy.s##l = v.y, vz.s##l = v.z;     \
    }
    PN_LOAD_ROW_LANE(0) PN_LOAD_ROW_LANE(1) PN_LOAD_ROW_LANE(2) PN_LOAD_ROW_LANE(3)
    PN_LOAD_ROW_LANE(4) PN_LOAD_ROW_LANE(5) PN_LOAD_ROW_LANE(6) PN_LOAD_ROW_LANE(7)
#undef PN_LOAD_ROW_LANE
    *x = vx, *y = vy, *z = vz;
}

/* The 8 pixels from index `row` on: (r, g, b, a) per lane, pn_store_rgba8
 * when all 8 are there (`full`), else lane by lane for the lanes of `in_row`. */
PN_LANES_INLINE void pn_store_row8(global float4 *image, int row, bool full, int8 in_row, float8 r, float8 g, float8 b,
                                  float8 a)
{
    if (full) {
        pn_store_rgba8(image + row, r, g, b, a);
        return;
    }
#define PN_STORE_ROW_LANE(l)                                              \
    if (in_row.s##l)                                                      \
        image[row + l] = (float4)(r.s##l, g.s##l, b.s##l, a.s##l);
    PN_STORE_ROW_LANE(0) PN_STORE_ROW_LANE(1) PN_STORE_ROW_LANE(2) PN_STORE_ROW_LANE(3)
    PN_STORE_ROW_LANE(4) PN_STORE_ROW_LANE(5) PN_STORE_ROW_LANE(6) PN_STORE_ROW_LANE(7)
#undef PN_STORE_ROW_LANE
}

/* The squared length x x + y y + z z of each lane, the products not fused
 * into the sums (as the built-in dot). */
PN_LANES_INLINE float8 pn_length2_8(float8 x, float8 y, float8 z)
{
#pragma OPENCL FP_CONTRACT OFF
    return x * x + y * y + z * z;
}

/* normalize() of each lane's (x, y, z), the same bits as the built-in on a
 * float3: PoCL's is p * (1 / sqrt(dot(p, p))) where dot(p, p) is a normal
 * float (checked bit for bit on 2^20 vectors of lengths 2^-31..2^31, and by
 * the images); lanes whose squared length lies outside [2^-60, 2^60] (zero,
 * tiny, huge, not finite: the built-in rescales those) go through the
 * built-in one by one. */
PN_LANES_INLINE void pn_normalize8(float8 *x, float8 *y, float8 *z)
{
    const float8 d = pn_length2_8(*x, *y, *z);
    const float8 r = 1.0f / sqrt(d);
    const int8 odd = ~((d >= 0x1p-60f) & (d <= 0x1p60f));
    float8 nx = *x * r, ny = *y * r, nz = *z * r;
    if (any(odd)) {
#define PN_NORMALIZE_LANE(l)                                                \
        if (odd.s##l) {                                                     \
            float3 n = normalize((float3)((*x).s##l, (*y).s##l, (*z).s##l)); \
            nx.s##l = n.x, ny.s##l = n.y, nz.s##l = n.z;                    \
        }
        PN_NORMALIZE_LANE(0) PN_NORMALIZE_LANE(1) PN_NORMALIZE_LANE(2) PN_NORMALIZE_LANE(3)
        PN_NORMALIZE_LANE(4) PN_NORMALIZE_LANE(5) PN_NORMALIZE_LANE(6) PN_NORMALIZE_LANE(7)
#undef PN_NORMALIZE_LANE
    }
    *x = nx, *y = ny, *z = nz;
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
