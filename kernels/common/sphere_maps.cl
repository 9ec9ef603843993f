/* Direction <-> lat-long and cube-map addressing (docs/conventions.md).
 *
 * Lat-long: u = atan2(x, -z) / 2pi in [0, 1), v = acos(y) / pi, row 0 on top;
 * the same convention as Mitsuba 3's envmap emitter.
 * Cube: faces +X, -X, +Y, -Y, +Z, -Z (0..5); on face f the texel coordinates
 * (a, b) in [-1, 1]^2 (a along columns, b along rows) map to the directions
 *   +X ( 1, -b, -a)   -X (-1, -b,  a)   +Y ( a,  1,  b)
 *   -Y ( a, -1, -b)   +Z ( a, -b,  1)   -Z (-a, -b, -1)
 */
#ifndef PN_COMMON_SPHERE_MAPS_CL
#define PN_COMMON_SPHERE_MAPS_CL

#include "common/math.cl"

inline float3 pn_latlong_to_dir(float u, float v)
{
    float phi = PN_TWO_PI * u;
    float theta = PN_PI * v;
    float st = sin(theta);
    return (float3)(sin(phi) * st, cos(theta), -cos(phi) * st);
}

/* (u, v) of a unit direction; u in [0, 1), v in [0, 1]. */
inline float2 pn_dir_to_latlong(float3 d)
{
    float u = atan2(d.x, -d.z) * PN_INV_TWO_PI;
    if (u < 0.0f)
        u += 1.0f;
    if (u >= 1.0f)
        u = 0.0f;
    float v = acos(clamp(d.y, -1.0f, 1.0f)) * PN_INV_PI;
    return (float2)(u, v);
}

/* Bilinear lookup of a lat-long RGB map (width x height, 3 floats a texel)
 * in direction d: texel (x, y) holds the radiance at its centre
 * ((x + 0.5) / width, (y + 0.5) / height); u wraps around the seam, v is
 * clamped at the poles (the first and last rows' values extend to them).
 * The background of every image goes through here, one call per background
 * pixel: u and v come from the polynomial pn_atan2 (2.5e-7 rad, below an ulp
 * of the angle beyond 0.5 rad) instead of the library atan2 and acos, and
 * the floor from an integer conversion (x, y > -1), which made the
 * background pass 3-4x faster (docs/performance.md, FIV). v = atan2(|d.xz|,
 * d.y) is also more accurate than acos(d.y) near the poles. */
inline float3 pn_latlong_bilinear(global const float *latlong, int width, int height, float3 d)
{
    float u = pn_atan2(d.x, -d.z) * PN_INV_TWO_PI; /* [-1/2, 1/2] */
    u = u < 0.0f ? u + 1.0f : u; /* u = 1 is the seam, as u = 0 */
    /* atan2(+-0, -0) = +-pi (pn_atan2 returns 0 at the origin): the poles' u */
    u = d.x == 0.0f && !signbit(d.z) ? 0.5f : u;
    float v = pn_atan2(sqrt(d.x * d.x + d.z * d.z), d.y) * PN_INV_PI;
    float x = u * (float)width - 0.5f, y = v * (float)height - 0.5f; /* >= -0.5 */
    int x0 = (int)(x + 1.0f) - 1, y0 = (int)(y + 1.0f) - 1;          /* floor, in [-1, width - 1] */
    float fx = clamp(x - (float)x0, 0.0f, 1.0f), fy = clamp(y - (float)y0, 0.0f, 1.0f);
    int x1 = x0 + 1 >= width ? x0 + 1 - width : x0 + 1;
    x0 = x0 < 0 ? x0 + width : x0;
    int y1 = min(y0 + 1, height - 1);
    y0 = max(y0, 0);
    global const float *p00 = latlong + 3 * (y0 * width + x0), *p10 = latlong + 3 * (y0 * width + x1);
    global const float *p01 = latlong + 3 * (y1 * width + x0), *p11 = latlong + 3 * (y1 * width + x1);
    float3 top = mix(vload3(0, p00), vload3(0, p10), fx);
    float3 bottom = mix(vload3(0, p01), vload3(0, p11), fx);
    return mix(top, bottom, fy);
}

/* pn_latlong_bilinear for 8 unit directions, one per lane: the angles,
 * texel indices and weights in float8 lanes (each lane the scalar code's
 * operations in the same order), then per lane its 4 texels and the same
 * mixes as the scalar code. Lanes outside `live` are not read; their
 * directions may be anything. Writes lane l's radiance to rgb[3 l ..]. */
/* pn_latlong_bilinear8's angles, texel offsets (floats into `latlong`) and
 * weights, in lanes. */
PN_LANES_INLINE void pn_latlong_cell8(int width, int height, float8 dx, float8 dy, float8 dz, int8 *a00, int8 *a10,
                                      int8 *a01, int8 *a11, float8 *fx_out, float8 *fy_out)
{
    float8 u = pn_atan2_8(dx, -dz) * PN_INV_TWO_PI; /* [-1/2, 1/2] */
    u = select(u, u + 1.0f, u < 0.0f);
    u = select(u, (float8)(0.5f), (dx == 0.0f) & ~signbit(dz));
    float8 v = pn_atan2_8(sqrt(dx * dx + dz * dz), dy) * PN_INV_PI;
    float8 x = u * (float)width - 0.5f, y = v * (float)height - 0.5f;
    int8 x0 = convert_int8(x + 1.0f) - 1, y0 = convert_int8(y + 1.0f) - 1;
    *fx_out = clamp(x - convert_float8(x0), 0.0f, 1.0f), *fy_out = clamp(y - convert_float8(y0), 0.0f, 1.0f);
    int8 x1 = select(x0 + 1, x0 + 1 - width, x0 + 1 >= width);
    x0 = select(x0, x0 + width, x0 < 0);
    int8 y1 = min(y0 + 1, height - 1);
    y0 = max(y0, 0);
    *a00 = 3 * (y0 * width + x0);
    *a10 = 3 * (y0 * width + x1);
    *a01 = 3 * (y1 * width + x0);
    *a11 = 3 * (y1 * width + x1);
}

PN_LANES_INLINE void pn_latlong_bilinear8(global const float *latlong, int width, int height, float8 dx, float8 dy,
                                 float8 dz, const int *live, float *rgb)
{
    int8 i00, i10, i01, i11;
    float8 fx, fy;
    pn_latlong_cell8(width, height, dx, dy, dz, &i00, &i10, &i01, &i11, &fx, &fy);
    int a00[8], a10[8], a01[8], a11[8];
    float afx[8], afy[8];
    vstore8(i00, 0, a00);
    vstore8(i10, 0, a10);
    vstore8(i01, 0, a01);
    vstore8(i11, 0, a11);
    vstore8(fx, 0, afx);
    vstore8(fy, 0, afy);
    for (int l = 0; l < 8; ++l) {
        if (!live[l])
            continue;
        float3 top = mix(vload3(0, latlong + a00[l]), vload3(0, latlong + a10[l]), afx[l]);
        float3 bottom = mix(vload3(0, latlong + a01[l]), vload3(0, latlong + a11[l]), afx[l]);
        vstore3(mix(top, bottom, afy[l]), l, rgb);
    }
}

/* Unnormalised direction of face coordinates (a, b) in [-1, 1]. */
inline float3 pn_cube_to_dir(int face, float a, float b)
{
    switch (face) {
    case 0: return (float3)(1.0f, -b, -a);
    case 1: return (float3)(-1.0f, -b, a);
    case 2: return (float3)(a, 1.0f, b);
    case 3: return (float3)(a, -1.0f, -b);
    case 4: return (float3)(a, -b, 1.0f);
    default: return (float3)(-a, -b, -1.0f);
    }
}

/* Face and coordinates (a, b) in [-1, 1] of a nonzero direction. Ties between
 * axes go to x, then y, so every direction has exactly one face. */
inline int pn_dir_to_cube(float3 d, float *a, float *b)
{
    float ax = fabs(d.x), ay = fabs(d.y), az = fabs(d.z);
    if (ax >= ay && ax >= az) {
        float inv = 1.0f / ax;
        *b = -d.y * inv;
        if (d.x > 0.0f) { *a = -d.z * inv; return 0; }
        *a = d.z * inv;
        return 1;
    }
    if (ay >= az) {
        float inv = 1.0f / ay;
        *a = d.x * inv;
        if (d.y > 0.0f) { *b = d.z * inv; return 2; }
        *b = -d.z * inv;
        return 3;
    }
    float inv = 1.0f / az;
    *b = -d.y * inv;
    if (d.z > 0.0f) { *a = d.x * inv; return 4; }
    *a = -d.x * inv;
    return 5;
}

/* Solid angle subtended by [0, x] x [0, y] on the plane at distance 1. */
inline float pn_cube_area_element(float x, float y)
{
    return atan2(x * y, sqrt(x * x + y * y + 1.0f));
}

/* Solid angle of the face rectangle [a0, a1] x [b0, b1]. The closed form
 * (differences of the area element) cancels catastrophically in float32 for
 * small rectangles (0.4 % error at face size 64, 100 % at 2048), so small
 * rectangles integrate the density 1 / (1 + a^2 + b^2)^(3/2) with 3x3-point
 * Gauss-Legendre instead (relative error below 3e-7 for sides <= 0.25). */
inline float pn_cube_solid_angle(float a0, float b0, float a1, float b1)
{
    float sa = a1 - a0, sb = b1 - b0;
    if (sa > 0.25f || sb > 0.25f)
        return pn_cube_area_element(a0, b0) - pn_cube_area_element(a0, b1) - pn_cube_area_element(a1, b0) +
               pn_cube_area_element(a1, b1);
    const float x[3] = {-0.774596669241483f, 0.0f, 0.774596669241483f};
    const float w[3] = {0.555555555555556f, 0.888888888888889f, 0.555555555555556f};
    float ca = 0.5f * (a0 + a1), cb = 0.5f * (b0 + b1), sum = 0.0f;
    for (int j = 0; j < 3; ++j) {
        float b = cb + 0.5f * sb * x[j];
        for (int i = 0; i < 3; ++i) {
            float a = ca + 0.5f * sa * x[i];
            float r = 1.0f + a * a + b * b;
            sum += w[i] * w[j] * rsqrt(r * r * r);
        }
    }
    return 0.25f * sa * sb * sum;
}

/* Texel (i, j) centre of a face of size n in face coordinates. */
inline float pn_cube_texel_coord(int i, int n)
{
    return 2.0f * ((float)i + 0.5f) / (float)n - 1.0f;
}

/* Flat index of a texel of a cube map with faces of n x n texels. */
inline int pn_cube_index(int face, int i, int j, int n)
{
    return (face * n + j) * n + i;
}

/* Bilinear lookup of a vertex-grid cube map: face f holds n x n samples at
 * a_i = -1 + 2 i / (n - 1), so the samples on a face's edge are the same
 * directions as on its neighbour's and the lookup is continuous across seams. */
inline float3 pn_cube_grid_lookup(global const float4 *grid, int n, float3 d)
{
    float a, b;
    int face = pn_dir_to_cube(d, &a, &b);
    float x = clamp((a + 1.0f) * 0.5f * (float)(n - 1), 0.0f, (float)(n - 1));
    float y = clamp((b + 1.0f) * 0.5f * (float)(n - 1), 0.0f, (float)(n - 1));
    int x0 = min((int)x, n - 2), y0 = min((int)y, n - 2);
    float fx = x - (float)x0, fy = y - (float)y0;
    global const float4 *row0 = grid + (face * n + y0) * n + x0;
    global const float4 *row1 = row0 + n;
    float4 top = mix(row0[0], row0[1], fx);
    float4 bottom = mix(row1[0], row1[1], fx);
    return mix(top, bottom, fy).xyz;
}

/* pn_cube_grid_lookup (above) for 8 unit directions: the face and the cell
 * of each lane, as the index (face n + y0) n + x0 of its first sample, and
 * the fractions fx, fy, from the same operations as pn_dir_to_cube's
 * branches, as selects (their mispredictions were most of the lookup's
 * cost). */
PN_LANES_INLINE void pn_cube_grid_cell8(int n, float8 dx, float8 dy, float8 dz, int8 *cell, float8 *fx, float8 *fy)
{
    float8 ax = fabs(dx), ay = fabs(dy), az = fabs(dz);
    int8 xm = (ax >= ay) & (ax >= az), ym = ~xm & (ay >= az);
    float8 inv = 1.0f / select(select(az, ay, ym), ax, xm);
    float8 a = select(select(select(-dx, dx, dz > 0.0f), dx, ym), select(dz, -dz, dx > 0.0f), xm) * inv;
    float8 b = select(-dy, select(-dz, dz, dy > 0.0f), ym) * inv;
    int8 f = select(select(select((int8)(5), (int8)(4), dz > 0.0f), select((int8)(3), (int8)(2), dy > 0.0f), ym),
                    select((int8)(1), (int8)(0), dx > 0.0f), xm);
    float8 x = clamp((a + 1.0f) * 0.5f * (float)(n - 1), 0.0f, (float)(n - 1));
    float8 y = clamp((b + 1.0f) * 0.5f * (float)(n - 1), 0.0f, (float)(n - 1));
    int8 ix = min(convert_int8(x), n - 2), iy = min(convert_int8(y), n - 2);
    *cell = (f * n + iy) * n + ix;
    *fx = x - convert_float8(ix);
    *fy = y - convert_float8(iy);
}

/* The unshadowed irradiance (pn_cube_grid_lookup) of the lanes of `active`
 * (0 in the others), for the kernels that shade 8 pixels per work-item
 * (fiv.cl, unshadowed.cl). Lanes with one normal (`one_normal`: 8
 * neighbouring pixels of a flat surface, 99 % of the work-items with one
 * bunny on a floor) are one lookup, broadcast. Else the face and cell of each lane in
 * lanes (pn_cube_grid_cell8); when the active lanes' cells are one cell,
 * its 4 samples are read once and mixed in lanes, channel by channel with
 * each lane's fractions (mix on float8 does per element what mix on the
 * float4 samples does per lane: the same bits); else lane by lane, 4
 * samples each. */
PN_LANES_INLINE void pn_cube_grid_lookup8(global const float4 *irradiance, int m, float8 nx, float8 ny, float8 nz,
                                        int8 active, bool one_normal, float8 *out_r, float8 *out_g, float8 *out_b)
{
    if (one_normal) {
        const float3 e = pn_cube_grid_lookup(irradiance, m, (float3)(nx.s0, ny.s0, nz.s0));
        *out_r = select((float8)(0.0f), (float8)(e.x), active), *out_g = select((float8)(0.0f), (float8)(e.y), active);
        *out_b = select((float8)(0.0f), (float8)(e.z), active);
        return;
    }
    int8 cell;
    float8 fx, fy;
    pn_cube_grid_cell8(m, nx, ny, nz, &cell, &fx, &fy);
    int8 lo = select((int8)(INT_MAX), cell, active), hi = select((int8)(INT_MIN), cell, active);
    lo.s0123 = min(lo.s0123, lo.s4567), hi.s0123 = max(hi.s0123, hi.s4567);
    lo.s01 = min(lo.s01, lo.s23), hi.s01 = max(hi.s01, hi.s23);
    const int2 span = (int2)(min(lo.s0, lo.s1), max(hi.s0, hi.s1));
    float8 r = 0.0f, g = 0.0f, b = 0.0f;
    if (span.x == span.y) {
        global const float4 *row0 = irradiance + span.x, *row1 = row0 + m;
        const float4 s00 = row0[0], s01 = row0[1], s10 = row1[0], s11 = row1[1];
        r = mix(mix((float8)(s00.x), (float8)(s01.x), fx), mix((float8)(s10.x), (float8)(s11.x), fx), fy);
        g = mix(mix((float8)(s00.y), (float8)(s01.y), fx), mix((float8)(s10.y), (float8)(s11.y), fx), fy);
        b = mix(mix((float8)(s00.z), (float8)(s01.z), fx), mix((float8)(s10.z), (float8)(s11.z), fx), fy);
        *out_r = select((float8)(0.0f), r, active), *out_g = select((float8)(0.0f), g, active);
        *out_b = select((float8)(0.0f), b, active);
        return;
    }
#define PN_CUBE_GRID_LANE(l)                                                                         \
    if (active.s##l) {                                                                               \
        global const float4 *row0 = irradiance + cell.s##l, *row1 = row0 + m;                        \
        float4 e = mix(mix(row0[0], row0[1], fx.s##l), mix(row1[0], row1[1], fx.s##l), fy.s##l);     \
        r.s##l = e.x, g.s##l = e.y, b.s##l = e.z;                                                    \
    }
    PN_CUBE_GRID_LANE(0) PN_CUBE_GRID_LANE(1) PN_CUBE_GRID_LANE(2) PN_CUBE_GRID_LANE(3)
    PN_CUBE_GRID_LANE(4) PN_CUBE_GRID_LANE(5) PN_CUBE_GRID_LANE(6) PN_CUBE_GRID_LANE(7)
#undef PN_CUBE_GRID_LANE
    *out_r = r, *out_g = g, *out_b = b;
}

/* pn_background8's first half: the texel offsets and weights of each
 * lane's direction (the lanes outside `live` look at the pole). */
PN_LANES_INLINE void pn_background_cell8(int width, int height, float2 rot, float8 px, float8 py, float8 pz,
                                         int8 live, int8 *i00, int8 *i10, int8 *i01, int8 *i11, float8 *fx,
                                         float8 *fy)
{
    px = select((float8)(0.0f), px, live), py = select((float8)(1.0f), py, live), pz = select((float8)(0.0f), pz, live);
    pn_normalize8(&px, &py, &pz);
    /* pn_rotate_y(d, rot.x, -rot.y) */
    float8 dx = rot.x * px + -rot.y * pz, dz = rot.y * px + rot.x * pz;
    pn_latlong_cell8(width, height, dx, py, dz, i00, i10, i01, i11, fx, fy);
}

/* pn_background8's second half: each lane of `live` its 4 texels and the
 * scalar code's mixes, times `intensity`; 0 in the other lanes. */
PN_LANES_INLINE void pn_background_texels8(global const float *latlong, float intensity, int8 live, int8 i00,
                                           int8 i10, int8 i01, int8 i11, float8 fx, float8 fy, float8 *r, float8 *g,
                                           float8 *b)
{
    float8 cr = 0.0f, cg = 0.0f, cb = 0.0f;
#define PN_BACKGROUND_LANE8(l)                                                                            \
    if (live.s##l) {                                                                                      \
        float3 top = mix(vload3(0, latlong + i00.s##l), vload3(0, latlong + i10.s##l), fx.s##l);          \
        float3 bottom = mix(vload3(0, latlong + i01.s##l), vload3(0, latlong + i11.s##l), fx.s##l);       \
        float3 c = mix(top, bottom, fy.s##l);                                                             \
        cr.s##l = c.x, cg.s##l = c.y, cb.s##l = c.z;                                                      \
    }
    PN_BACKGROUND_LANE8(0) PN_BACKGROUND_LANE8(1) PN_BACKGROUND_LANE8(2) PN_BACKGROUND_LANE8(3)
    PN_BACKGROUND_LANE8(4) PN_BACKGROUND_LANE8(5) PN_BACKGROUND_LANE8(6) PN_BACKGROUND_LANE8(7)
#undef PN_BACKGROUND_LANE8
    *r = intensity * cr, *g = intensity * cg, *b = intensity * cb;
}

/* The env map's radiance (pn_latlong_bilinear, times `intensity`) in the
 * direction (x, y, z) of each lane of `live`, rotated by rot = (cos, sin) as
 * the background pass does (envmap_background: the direction normalised, the
 * same operations in the same order, so the same bits); 0 in the other
 * lanes, whose directions are not read. */
PN_LANES_INLINE void pn_background8(global const float *latlong, int width, int height, float2 rot, float intensity,
                                    float8 px, float8 py, float8 pz, int8 live, float8 *r, float8 *g, float8 *b)
{
    int8 i00, i10, i01, i11;
    float8 fx, fy;
    pn_background_cell8(width, height, rot, px, py, pz, live, &i00, &i10, &i01, &i11, &fx, &fy);
    pn_background_texels8(latlong, intensity, live, i00, i10, i01, i11, fx, fy, r, g, b);
}

/* Nearest-texel lookup of a texel-centred cube map. */
inline float3 pn_cube_texel_lookup(global const float4 *cube, int n, float3 d)
{
    float a, b;
    int face = pn_dir_to_cube(d, &a, &b);
    int i = clamp((int)((a + 1.0f) * 0.5f * (float)n), 0, n - 1);
    int j = clamp((int)((b + 1.0f) * 0.5f * (float)n), 0, n - 1);
    return cube[pn_cube_index(face, i, j, n)].xyz;
}

#endif
