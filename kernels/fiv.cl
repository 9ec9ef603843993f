/* `fiv` method: diffuse env lighting with soft shadows and self-shadows from
 * Fullsphere Irradiance Vectors (Michael and Chrysanthou; docs/fiv.md).
 *
 *   E = DifMap(N) - sum over occluders of I_occ,   I_occ = N . FIV_occ(c - p)
 *
 * FIV_occ is interpolated trilinearly from the occluder's baked field at the
 * receiver-to-centre vector (theta, phi, log rho). Occluders fully behind the
 * receiver plane (case C) or beyond their culling distance are skipped;
 * straddling ones (case B) are scaled by (d + R) / 2R. A pixel on an
 * occluder itself uses the fullsphere equality E = N . (FIV(Env) - FIV_occ).
 * Several occluders combine by a plain sum, the unit-bounding-disc overlap
 * correction (among each pixel's `max_overlap` largest shadows), or multiplied
 * visibilities (`overlap`).
 *
 * Screen-space binning (`bin_fiv_tiles`, before `shade_fiv`): per 16x16
 * tile, a bit mask of the occluders whose culling sphere reaches the tile's
 * receivers; the shading loop visits only those, in the same order.
 *
 * PN_FIV_PROFILE (a build option, bench/fiv_profile.py) stops the work early
 * to time the phases apart: 1 = no lookup (a constant field), 2 = the
 * lookup's indices and weights but no sample fetched, 3 = the lanes that the
 * shared fetch (pn_fiv_fetch8) does not serve get a huge FIV instead of
 * theirs (to count them), 4 = no occluder loop at all (the pixel setup, the
 * unshadowed part, the background and the output alone). 0 (default) = all.
 * PN_FIV_NO_NORMAL_CACHE, PN_FIV_NO_SKY_BATCH and PN_FIV_NO_PAIRS (build
 * options, for A/B timings in one process: bench/fiv_speed.py
 * --build-options) leave out the normal cache, the background-only batch and
 * the two groups side by side of shade_fiv, PN_FIV_PAIR_DISCS=0 the latter
 * only with the disc correction's pairs (the same images either way).
 * PN_FIV_PAIR_BY_ORDER=1 pairs the first `max_overlap` occluders in the
 * scene's order instead of the largest (the rule before), and
 * PN_FIV_LENS_SCALE scales every pair's lens (default 1): both for measuring
 * the correction's accuracy (bench/fiv_max_overlap.py, docs/fiv.md).
 *
 * Occluder record, 4 float4 (capi/src/fiv.c):
 *   [0] centre xyz (world), bounding radius R (world)
 *   [1] object units per world unit, rho_min, ln(rho_max / rho_min), culling distance (world)
 *   [2] uint bits: byte offset of the samples in `fields`, n_theta, n_phi, n_rho
 *   [3] uint bits: instance id, 0 (reserved); value scale, rho_max
 * `fields`: per field its samples (float32, 9 per sample: half-float bakes
 * are converted on upload, their values over the value scale), then (16-byte aligned) its per-direction
 * culling bounds, (n_theta - 1) x n_phi floats per cell and (16-byte
 * aligned) 16 x 32 per direction bin (pn_fiv_lookup). */
#include "common/fiv_grid.cl"
#include "common/sphere_maps.cl"

#ifndef PN_FIV_PROFILE
#define PN_FIV_PROFILE 0
#endif

#define PN_FIV_RECORD 4
#define PN_FIV_TILE 16
/* The disc correction's capacity: the `max_overlap` parameter is at most this. */
#define PN_FIV_MAX_OVERLAP 32
#define PN_FIV_SLOTS (PN_FIV_MAX_OVERLAP * PN_FIV_LANES)

#define PN_OVERLAP_SUM 0
#define PN_OVERLAP_DISC 1
#define PN_OVERLAP_MULTIPLY 2

/* The lookup's helpers are forced inline: PoCL left pn_fiv_lookup and
 * pn_fiv_shell as calls, passing the accumulators through the stack. */
#define PN_FIV_INLINE inline __attribute__((always_inline))

typedef struct {
    float3 x, y, z;
} pn_fiv3;

PN_FIV_INLINE bool pn_fiv_sample(global const uchar *fields, uint offset, int index, pn_fiv3 *s)
{
    /* An 8-wide load, X rgb, Y rgb, Z rg, and Z b. */
    global const float *f = (global const float *)(fields + offset) + PN_FIV_FLOATS * index;
    float8 a = vload8(0, f);
    s->x = a.s012;
    s->y = a.s345;
    s->z = (float3)(a.s67, f[8]);
    return !isnan(a.s0); /* samples inside the geometry are NaN */
}

/* ln x for finite x > 0, to 3 ulp (float64 check: tests/test_fiv.py).
 * The built-in log, a library call PoCL does not inline, was half the time
 * of a lookup's index math (docs/performance.md, FIV); this is a handful of
 * FMAs and one divide: x = m 2^e with m in [sqrt(1/2), sqrt(2)),
 * ln m = 2 atanh(s), s = (m - 1) / (m + 1), |s| < 0.172, by its series to s^9
 * (truncation below 1e-9). Subnormal x read as ~ -87.3 + ln of their
 * mantissa bits: far below any radius of a field, so clamped like them. */
inline float pn_fiv_ln(float x)
{
    int bits = as_int(x);
    int e = (bits >> 23) - 127;
    float m = as_float((bits & 0x007fffff) | 0x3f800000); /* [1, 2) */
    bool big = m > 1.41421356f;
    m = big ? 0.5f * m : m;
    e = big ? e + 1 : e;
    float f = m - 1.0f;
    float s = f / (2.0f + f), s2 = s * s;
    float p = 0.11111111f;
    p = p * s2 + 0.14285715f;
    p = p * s2 + 0.2f;
    p = p * s2 + 0.33333334f;
    p = p * s2 + 1.0f;
    return (float)e * 0.693147180559945f + 2.0f * s * p;
}

/* Direction bins of the coarse culling test: 16 in cos theta (v.y / rho) by
 * 32 in a pseudo-angle p in [0, 8] of phi, increasing with phi, that needs
 * one divide instead of an atan: per quadrant of (v.x, v.z), p' = t or
 * 2 - t (t = the smaller over the larger of |v.x|, |v.z|) and p = p', 4 - p',
 * 4 + p', 8 - p'. capi/src/methods/fiv.c (bin_bounds) inverts the bin edges
 * exactly; keep the counts in step with it. */
#define PN_FIV_BINS_Z 16
#define PN_FIV_BINS_P 32

PN_FIV_INLINE int pn_fiv_dir_bin(float3 v, float rho)
{
    float ax = fabs(v.x), az = fabs(v.z), hi = fmax(ax, az);
    float t = hi > 0.0f ? fmin(ax, az) / hi : 0.0f;
    float q = az > ax ? 2.0f - t : t; /* p in the first quadrant */
    float p = v.x < 0.0f ? (v.z < 0.0f ? 4.0f + q : 4.0f - q) : (v.z < 0.0f ? 8.0f - q : q);
    int bz = clamp((int)((v.y / rho + 1.0f) * (0.5f * PN_FIV_BINS_Z)), 0, PN_FIV_BINS_Z - 1);
    int bp = min((int)(p * (PN_FIV_BINS_P / 8.0f)), PN_FIV_BINS_P - 1);
    return bz * PN_FIV_BINS_P + bp;
}

/* Adds weight w times sample (k, i, j) to acc when the sample is valid;
 * without a branch (an invalid sample adds 0 to both sums, and so does a
 * valid one of weight 0: the same sums as skipping them). */
PN_FIV_INLINE void pn_fiv_add(global const uchar *fields, uint offset, int n_theta, int n_phi, int k, int i,
                              int j, float w, pn_fiv3 *acc, float *wsum)
{
    pn_fiv3 s;
    bool valid = pn_fiv_sample(fields, offset, (k * n_theta + i) * n_phi + j, &s);
    w = valid ? w : 0.0f;
    s.x = valid ? s.x : 0.0f;
    s.y = valid ? s.y : 0.0f;
    s.z = valid ? s.z : 0.0f;
    acc->x += w * s.x;
    acc->y += w * s.y;
    acc->z += w * s.z;
    *wsum += w;
}

/* Bilinear (theta, phi) interpolation on sphere k with total weight wk. */
PN_FIV_INLINE void pn_fiv_shell(global const uchar *fields, uint offset, int n_theta, int n_phi, int k,
                                float wk, int i0, float ti, int j0, int j1, float tj, pn_fiv3 *acc, float *wsum)
{
    if (wk <= 0.0f) /* beyond the grid the inner sphere's weight is 0: its taps are not read */
        return;
    pn_fiv_add(fields, offset, n_theta, n_phi, k, i0, j0, wk * (1.0f - ti) * (1.0f - tj), acc, wsum);
    pn_fiv_add(fields, offset, n_theta, n_phi, k, i0, j1, wk * (1.0f - ti) * tj, acc, wsum);
    pn_fiv_add(fields, offset, n_theta, n_phi, k, i0 + 1, j0, wk * ti * (1.0f - tj), acc, wsum);
    pn_fiv_add(fields, offset, n_theta, n_phi, k, i0 + 1, j1, wk * ti * tj, acc, wsum);
}

/* The lookup's second half: the samples around grid coordinates (fi, fj, fk)
 * (fk >= 0, clamped to the grid), trilinear over the valid ones of the 8
 * nearest, renormalised; with none valid, the nearest sphere farther out that
 * has one. Times the value scale and the fall-off; false when none is valid. */
PN_FIV_INLINE bool pn_fiv_fetch(global const float4 *occ, global const uchar *fields, float fi, float fj, float fk,
                                float falloff, int trilinear, pn_fiv3 *out)
{
    uint offset = as_uint(occ[2].x);
    int n_theta = as_int(occ[2].y), n_phi = as_int(occ[2].z), n_rho = as_int(occ[2].w);
    pn_fiv3 acc = {(float3)(0.0f), (float3)(0.0f), (float3)(0.0f)};
    float wsum = 0.0f;
    if (!trilinear) {
        fi = round(fi);
        fj = round(fj);
        fk = round(fk);
    }
    int i0 = min((int)fi, n_theta - 2), k0 = min((int)fk, n_rho - 2);
    float ti = clamp(fi - (float)i0, 0.0f, 1.0f), tk = clamp(fk - (float)k0, 0.0f, 1.0f);
    int jf = min((int)fj, n_phi - 1); /* phi = 2 pi after rounding is the seam */
    float tj = clamp(fj - (float)jf, 0.0f, 1.0f);
    int j0 = jf, j1 = jf + 1 < n_phi ? jf + 1 : 0; /* the phi seam wraps */
    pn_fiv_shell(fields, offset, n_theta, n_phi, k0, 1.0f - tk, i0, ti, j0, j1, tj, &acc, &wsum);
    pn_fiv_shell(fields, offset, n_theta, n_phi, k0 + 1, tk, i0, ti, j0, j1, tj, &acc, &wsum);
    for (int k = k0 + 1; wsum <= 0.0f && k < n_rho; ++k)
        pn_fiv_shell(fields, offset, n_theta, n_phi, k, 1.0f, i0, ti, j0, j1, tj, &acc, &wsum);
    if (wsum <= 0.0f)
        return false;
    float f = occ[3].z * falloff / wsum;
    out->x = acc.x * f;
    out->y = acc.y * f;
    out->z = acc.z * f;
    return true;
}

/* The occluded FIV at receiver-to-centre vector v (world units); false when
 * no valid sample is near (the receiver is deep inside the geometry).
 * Within the grid: trilinear over the valid ones of the 8 nearest samples,
 * renormalised; with none valid, the nearest sphere farther out that has
 * one. Inside rho_min: the innermost sphere. Beyond rho_max: the outermost
 * sphere times the solid-angle fall-off (rho_max / rho)^2. */
PN_FIV_INLINE bool pn_fiv_lookup(global const float4 *occ, global const uchar *fields, float3 v_world, int trilinear,
                                 float cull_floor, pn_fiv3 *out)
{
    float inv_scale = occ[1].x, rho_min = occ[1].y, log_ratio = occ[1].z;
    uint offset = as_uint(occ[2].x);
    int n_theta = as_int(occ[2].y), n_phi = as_int(occ[2].z), n_rho = as_int(occ[2].w);
    float3 v = v_world * inv_scale;
    float rho = length(v);
    if (!isfinite(rho)) /* a NaN/Inf position in an unvalidated G-buffer: no index from it */
        return false;
    /* Beyond the grid: per-direction bounds after the samples (cell_bounds,
     * bin_bounds in capi/src/methods/fiv.c). First the coarse direction bin,
     * before any angle: it bounds every cell the direction can fall in, so
     * it culls only what the cell test below would (rho_max widened by 1e-4
     * so that the cell test, too, sees the pair beyond the grid). */
    size_t samples = (size_t)n_rho * n_theta * n_phi * PN_FIV_FLOATS * sizeof(float);
    global const float *cell_bound = (global const float *)(fields + offset + ((samples + 15) & ~(size_t)15));
    float rho_max = occ[3].w; /* from the record: no exp per lookup beyond the grid */
    if (cull_floor > 0.0f && rho > rho_max * 1.0001f) {
        global const float *bin_bound = cell_bound + (((size_t)(n_theta - 1) * n_phi + 3) & ~(size_t)3);
        if (bin_bound[pn_fiv_dir_bin(v, rho)] * ((rho_max / rho) * (rho_max / rho)) < cull_floor)
            return false;
    }
    /* theta = acos(v.y / rho), phi = atan2(v.z, v.x), by the polynomial atan */
    float theta = pn_atan2(sqrt(v.x * v.x + v.z * v.z), v.y);
    float phi = pn_atan2(v.z, v.x);
    if (phi < 0.0f)
        phi += PN_TWO_PI;
    float fi = theta * (float)(n_theta - 1) * PN_INV_PI;
    float fj = phi * (float)n_phi * PN_INV_TWO_PI;
    float fk = rho > 0.0f ? pn_fiv_ln(rho / rho_min) / log_ratio * (float)(n_rho - 1) : 0.0f;
    float falloff = 1.0f;
    if (fk > (float)(n_rho - 1)) {
        falloff = (rho_max / rho) * (rho_max / rho);
        fk = (float)(n_rho - 1);
        /* Culling per direction: beyond the grid only the 4 outer-sphere
         * samples of this (theta, phi) cell take part; their largest |FIV|
         * times the fall-off bounds N . FIV. Under a sun that bound is large
         * only in the cells between the occluder and the sun. */
        int ci = min((int)fi, n_theta - 2), cj = min((int)fj, n_phi - 1);
        if (cell_bound[ci * n_phi + cj] * falloff < cull_floor)
            return false;
    }
    fk = fmax(fk, 0.0f);
#if PN_FIV_PROFILE == 2
    out->x = out->y = out->z = (float3)((fi + fj + fk) * falloff);
    return true;
#endif
    return pn_fiv_fetch(occ, fields, fi, fj, fk, falloff, trilinear, out);
}

inline float3 pn_fiv_dot(float3 n, pn_fiv3 f)
{
    return n.x * f.x + n.y * f.y + n.z * f.z;
}

/* Area of the lens where two discs of radii a, b with centres dist apart overlap. */
inline float pn_lens_area(float a, float b, float dist)
{
    if (dist >= a + b)
        return 0.0f;
    if (dist <= fabs(a - b)) {
        float r = fmin(a, b);
        return PN_PI * r * r;
    }
    float ca = clamp((dist * dist + a * a - b * b) / (2.0f * dist * a), -1.0f, 1.0f);
    float cb = clamp((dist * dist + b * b - a * a) / (2.0f * dist * b), -1.0f, 1.0f);
    float k = (-dist + a + b) * (dist + a - b) * (dist - a + b) * (dist + a + b);
    return a * a * acos(ca) + b * b * acos(cb) - 0.5f * sqrt(fmax(k, 0.0f));
}

/* Whether a sphere (centre c, radius r) reaches the box [lo, hi]. */
inline bool pn_sphere_meets_box(float3 c, float r, float3 lo, float3 hi)
{
    float3 d = fmax(fmax(lo - c, c - hi), 0.0f);
    return dot(d, d) <= r * r;
}

/* One work-item per 16x16 tile: the world-space box of the tile's receivers
 * (background and non-finite positions left out: no occluder shades them),
 * then bit o of the tile's mask (words of 32) is set when occluder o's
 * culling sphere reaches the box. A pixel culls an occluder farther than its
 * culling distance; the box holds the pixel, so the tile keeps every
 * occluder one of its pixels keeps (the radius is widened by 1e-5 against
 * rounding). Self-shadowing does not go by the masks (shade_fiv). */
kernel void bin_fiv_tiles(global const float4 *position, global const uint *instance_id, int width, int height,
                          global const float4 *occluders, int occluder_count, global uint *tile_masks)
{
    int tiles_x = (width + PN_FIV_TILE - 1) / PN_FIV_TILE, tiles_y = (height + PN_FIV_TILE - 1) / PN_FIV_TILE;
    int tile = get_global_id(0);
    if (tile >= tiles_x * tiles_y)
        return;
    int x0 = (tile % tiles_x) * PN_FIV_TILE, y0 = (tile / tiles_x) * PN_FIV_TILE;
    int x1 = min(x0 + PN_FIV_TILE, width), y1 = min(y0 + PN_FIV_TILE, height);
    float3 lo = (float3)(INFINITY), hi = (float3)(-INFINITY);
    for (int y = y0; y < y1; ++y)
        for (int x = x0; x < x1; ++x) {
            int i = y * width + x;
            float3 p = position[i].xyz;
            if (instance_id[i] != PN_BACKGROUND && all(isfinite(p))) {
                lo = fmin(lo, p);
                hi = fmax(hi, p);
            }
        }
    bool empty = lo.x > hi.x;
    int words = (occluder_count + 31) / 32;
    global uint *mask = tile_masks + (size_t)tile * words;
    for (int w = 0; w < words; ++w) {
        uint bits = 0u;
        for (int b = 0; b < 32 && 32 * w + b < occluder_count; ++b) {
            global const float4 *occ = occluders + PN_FIV_RECORD * (32 * w + b);
            if (!empty && pn_sphere_meets_box(occ[0].xyz, occ[1].w * 1.00001f, lo, hi))
                bits |= 1u << b;
        }
        mask[w] = bits;
    }
}

/* ---- Vector lanes across pixels ----------------------------------------
 * shade_fiv runs 8 pixels of a row per work-item (x0 a multiple of 8, so the
 * 8 lie in one 16x16 tile and share its occluder list): the occluder loop's
 * tests and the lookup's index math (angles, logarithm, culling) are float8
 * arithmetic, one lane per pixel, and only the lanes still in play fetch
 * samples (pn_fiv_fetch, lane by lane). PoCL 3.1 does not vectorise the
 * per-pixel code by itself: its loop over a work-group's work-items is never
 * the innermost loop when the kernel loops over occluders, and the SLP pass
 * turns scalar pairs (|x| against |z|, the colour channels) into 2- or
 * 4-wide vectors the work-item loop vectorizer then refuses
 * (docs/performance.md, FIV). Each lane does the scalar code's operations in
 * the same order. */
#define PN_FIV_LANES 8

/* pn_fiv_ln, lane by lane. */
PN_FIV_INLINE float8 pn_fiv_ln8(float8 x)
{
    int8 bits = as_int8(x);
    int8 e = (bits >> 23) - 127;
    float8 m = as_float8((bits & 0x007fffff) | 0x3f800000);
    int8 big = m > 1.41421356f;
    m = select(m, 0.5f * m, big);
    e = select(e, e + 1, big);
    float8 f = m - 1.0f;
    float8 s = f / (2.0f + f), s2 = s * s;
    float8 p = 0.11111111f;
    p = p * s2 + 0.14285715f;
    p = p * s2 + 0.2f;
    p = p * s2 + 0.33333334f;
    p = p * s2 + 1.0f;
    return convert_float8(e) * 0.693147180559945f + 2.0f * s * p;
}

/* pn_fiv_dir_bin, lane by lane. */
PN_FIV_INLINE int8 pn_fiv_dir_bin8(float8 vx, float8 vy, float8 vz, float8 rho)
{
    float8 ax = fabs(vx), az = fabs(vz), hi = fmax(ax, az);
    float8 t = select((float8)(0.0f), fmin(ax, az) / hi, hi > 0.0f);
    float8 q = select(t, 2.0f - t, az > ax);
    float8 p = select(select(q, 8.0f - q, vz < 0.0f), select(4.0f - q, 4.0f + q, vz < 0.0f), vx < 0.0f);
    int8 bz = clamp(convert_int8((vy / rho + 1.0f) * (0.5f * PN_FIV_BINS_Z)), 0, PN_FIV_BINS_Z - 1);
    int8 bp = min(convert_int8(p * (PN_FIV_BINS_P / 8.0f)), PN_FIV_BINS_P - 1);
    return bz * PN_FIV_BINS_P + bp;
}

/* base[idx] in the lanes of mask (-1), 0 in the others (whose idx may be anything).
 * Unrolled, each value put into its lane in registers (a lane array written
 * one lane at a time and read back as a vector stalls the load). Without a
 * branch per lane: every lane reads, base[0] in the lanes out of the mask,
 * and a select zeroes them (the lanes' masks vary from group to group, so
 * that the branches mispredicted; 0.95x the one-bunny frame,
 * docs/performance.md, FIV, "Index math"). PN_FIV_GATHER_BRANCHES (a build
 * option, for A/B timings) keeps a branch per lane; the same values. */
PN_FIV_INLINE float8 pn_fiv_gather8(global const float *base, int8 idx, int8 mask)
{
#ifndef PN_FIV_GATHER_BRANCHES
    idx = select((int8)(0), idx, mask);
    float8 g;
    g.s0 = base[idx.s0], g.s1 = base[idx.s1], g.s2 = base[idx.s2], g.s3 = base[idx.s3];
    g.s4 = base[idx.s4], g.s5 = base[idx.s5], g.s6 = base[idx.s6], g.s7 = base[idx.s7];
    return select((float8)(0.0f), g, mask);
#endif
    float8 v = 0.0f;
#define PN_FIV_GATHER_LANE(l)     \
    if (mask.s##l)                \
        v.s##l = base[idx.s##l];
    PN_FIV_GATHER_LANE(0) PN_FIV_GATHER_LANE(1) PN_FIV_GATHER_LANE(2) PN_FIV_GATHER_LANE(3)
    PN_FIV_GATHER_LANE(4) PN_FIV_GATHER_LANE(5) PN_FIV_GATHER_LANE(6) PN_FIV_GATHER_LANE(7)
#undef PN_FIV_GATHER_LANE
    return v;
}

/* pn_fiv_lookup's first half for 8 receivers (v_world per lane, the lanes
 * of `live` taken): the grid coordinates and fall-off of each lane, and the
 * lanes that go on to fetch samples (the others: not finite, or culled per
 * direction). */
PN_FIV_INLINE int8 pn_fiv_index8(global const float4 *occ, global const uchar *fields, float8 wx, float8 wy,
                                 float8 wz, int8 live, float cull_floor, float8 *fi_out, float8 *fj_out,
                                 float8 *fk_out, float8 *falloff_out)
{
    float inv_scale = occ[1].x, rho_min = occ[1].y, log_ratio = occ[1].z;
    uint offset = as_uint(occ[2].x);
    int n_theta = as_int(occ[2].y), n_phi = as_int(occ[2].z), n_rho = as_int(occ[2].w);
    float8 vx = wx * inv_scale, vy = wy * inv_scale, vz = wz * inv_scale;
    float8 rho = sqrt(vx * vx + vy * vy + vz * vz);
    live &= isfinite(rho);
    size_t samples = (size_t)n_rho * n_theta * n_phi * PN_FIV_FLOATS * sizeof(float);
    global const float *cell_bound = (global const float *)(fields + offset + ((samples + 15) & ~(size_t)15));
    float rho_max = occ[3].w;
    if (cull_floor > 0.0f) {
        int8 beyond = live & (rho > rho_max * 1.0001f);
        if (any(beyond)) {
            global const float *bin_bound = cell_bound + (((size_t)(n_theta - 1) * n_phi + 3) & ~(size_t)3);
            float8 bound = pn_fiv_gather8(bin_bound, pn_fiv_dir_bin8(vx, vy, vz, rho), beyond);
            live &= ~(beyond & (bound * ((rho_max / rho) * (rho_max / rho)) < cull_floor));
        }
    }
    float8 theta = pn_atan2_8(sqrt(vx * vx + vz * vz), vy);
    float8 phi = pn_atan2_8(vz, vx);
    phi = select(phi, phi + PN_TWO_PI, phi < 0.0f);
    float8 fi = theta * (float)(n_theta - 1) * PN_INV_PI;
    float8 fj = phi * (float)n_phi * PN_INV_TWO_PI;
    float8 fk = select((float8)(0.0f), pn_fiv_ln8(rho / rho_min) / log_ratio * (float)(n_rho - 1), rho > 0.0f);
    int8 out_of_grid = fk > (float)(n_rho - 1);
    float8 falloff = select((float8)(1.0f), (rho_max / rho) * (rho_max / rho), out_of_grid);
    fk = select(fk, (float8)(n_rho - 1), out_of_grid);
    int8 cull = live & out_of_grid;
    if (any(cull)) { /* the cell test (pn_fiv_lookup) */
        int8 ci = min(convert_int8(fi), n_theta - 2), cj = min(convert_int8(fj), n_phi - 1);
        float8 bound = pn_fiv_gather8(cell_bound, ci * n_phi + cj, cull);
        live &= ~(cull & (bound * falloff < cull_floor));
    }
    *fi_out = fi;
    *fj_out = fj;
    *fk_out = fmax(fk, 0.0f);
    *falloff_out = falloff;
    return live;
}

/* One sample for all lanes (pn_fiv_fetch8): weight w per lane times the
 * sample's 9 values, added when the sample is valid. Each value is read by
 * itself, so that its broadcast to the lanes is part of the multiply-add
 * (an embedded-broadcast memory operand) instead of a shuffle out of a
 * vector load. */
PN_FIV_INLINE void pn_fiv_add8_all(global const uchar *fields, uint offset, int index, float8 w, float8 *acc,
                                   float8 *wsum)
{
    global const float *s = (global const float *)(fields + offset) + PN_FIV_FLOATS * index;
    if (isnan(s[0])) /* inside the geometry */
        return;
    acc[0] += w * s[0], acc[1] += w * s[1], acc[2] += w * s[2];
    acc[3] += w * s[3], acc[4] += w * s[4], acc[5] += w * s[5];
    acc[6] += w * s[6], acc[7] += w * s[7], acc[8] += w * s[8];
    *wsum += w;
}

/* Smallest and largest of the lanes of `live` (at least one). */
PN_FIV_INLINE int2 pn_fiv_range8(int8 x, int8 live)
{
    int8 lo = select((int8)(INT_MAX), x, live), hi = select((int8)(INT_MIN), x, live);
    lo.s0123 = min(lo.s0123, lo.s4567), hi.s0123 = max(hi.s0123, hi.s4567);
    lo.s01 = min(lo.s01, lo.s23), hi.s01 = max(hi.s01, hi.s23);
    return (int2)(min(lo.s0, lo.s1), max(hi.s0, hi.s1));
}

/* The weight of the sample at offset d (0, 1, 2) from the block's corner
 * for a lane whose cell starts at offset o (0, 1) with fraction t: 1 - t at
 * o, t at o + 1, 0 elsewhere. */
PN_FIV_INLINE float8 pn_fiv_tap_weight8(int d, int8 o, float8 t)
{
    return select(select((float8)(0.0f), t, o + 1 == d), 1.0f - t, o == d);
}

/* How far apart (in cells, per index) the lanes' cells may lie for
 * pn_fiv_fetch8 to serve them all from one block of samples: 2, a block of
 * up to 4 x 4 x 4 samples. With 1 (3 x 3 x 3) 4.2 % of the receivers of the
 * one-bunny benchmark frame went lane by lane, with 2 1.2 %
 * (docs/performance.md, FIV, "The lookup"). */
#define PN_FIV_BLOCK_SPREAD 2
#define PN_FIV_BLOCK (PN_FIV_BLOCK_SPREAD + 2)
#if PN_FIV_BLOCK != 4
#error "pn_fiv_fetch8 writes out its loop over j for blocks of 4"
#endif

/* pn_fiv_fetch for the lanes of `live` when their cells lie within
 * PN_FIV_BLOCK_SPREAD cells of each other in each of i0, j0 and k0, which 8
 * neighbouring pixels mostly do: each sample of the block (at most
 * PN_FIV_BLOCK^3, 8 when the lanes share one cell) is read once and its 9
 * values go to every lane with that lane's trilinear weight, 0 where the
 * sample is not one of the lane's 8 (weights and sums in lanes; per lane the
 * scalar code's operations in its order, plus terms that add 0: a valid
 * sample of weight 0 adds +0 or -0 to sums that are never -0, the same
 * bits). Writes fr (0 in the other lanes) and returns true; returns false,
 * writing nothing, when the lanes spread wider or a lane would need the
 * search for a valid sphere farther out (pn_fiv_fetch then goes lane by
 * lane). */
PN_FIV_INLINE bool pn_fiv_fetch8(global const float4 *occ, global const uchar *fields, float8 fi, float8 fj,
                                 float8 fk, float8 falloff, int8 live, int trilinear, float fr[9][PN_FIV_LANES])
{
    uint offset = as_uint(occ[2].x);
    int n_theta = as_int(occ[2].y), n_phi = as_int(occ[2].z), n_rho = as_int(occ[2].w);
    /* the other lanes' coordinates may be anything: 0 instead, weight 0 below */
    fi = select((float8)(0.0f), fi, live), fj = select((float8)(0.0f), fj, live), fk = select((float8)(0.0f), fk, live);
    if (!trilinear) {
        fi = round(fi);
        fj = round(fj);
        fk = round(fk);
    }
    int8 i0 = min(convert_int8(fi), n_theta - 2), k0 = min(convert_int8(fk), n_rho - 2);
    int8 jf = min(convert_int8(fj), n_phi - 1);
    float8 ti = clamp(fi - convert_float8(i0), 0.0f, 1.0f), tk = clamp(fk - convert_float8(k0), 0.0f, 1.0f);
    float8 tj = clamp(fj - convert_float8(jf), 0.0f, 1.0f);
    int2 ri = pn_fiv_range8(i0, live), rk = pn_fiv_range8(k0, live), rj = pn_fiv_range8(jf, live);
    if (ri.y - ri.x > PN_FIV_BLOCK_SPREAD || rk.y - rk.x > PN_FIV_BLOCK_SPREAD)
        return false;
    int j_lo = rj.x;
    bool seam = rj.y - rj.x > PN_FIV_BLOCK_SPREAD;
    if (seam) { /* across the phi seam: the block from n_phi - 1 to 0 */
        if (rj.y != n_phi - 1 || rj.x != 0 || any(live & (jf != 0) & (jf != n_phi - 1)))
            return false;
        j_lo = n_phi - 1;
    }
    int8 oi = i0 - ri.x, ok = k0 - rk.x, oj = seam ? select((int8)(0), (int8)(1), jf != j_lo) : jf - j_lo;
    int ni = ri.y - ri.x + 2, nk = rk.y - rk.x + 2, nj = seam ? 3 : rj.y - rj.x + 2;
    float8 acc[9] = {0.0f, 0.0f, 0.0f, 0.0f, 0.0f, 0.0f, 0.0f, 0.0f, 0.0f};
    float8 wsum = 0.0f;
    if (ni == 2 && nj == 2 && nk == 2) {
        /* All lanes in one cell (most lookups): the loops below with every
         * offset 0, unrolled, each sample weighed as there; a sphere no lane
         * weighs (the inner one beyond the grid) is skipped whole. */
        int j1 = j_lo + 1 >= n_phi ? j_lo + 1 - n_phi : j_lo + 1;
        for (int dk = 0; dk < 2; ++dk) {
            float8 wk = dk ? tk : 1.0f - tk;
            wk = select((float8)(0.0f), wk, live & (wk > 0.0f));
            if (!any(wk != 0.0f))
                continue;
            int row = ((rk.x + dk) * n_theta + ri.x) * n_phi;
            float8 w0 = wk * (1.0f - ti), w1 = wk * ti;
            pn_fiv_add8_all(fields, offset, row + j_lo, w0 * (1.0f - tj), acc, &wsum);
            pn_fiv_add8_all(fields, offset, row + j1, w0 * tj, acc, &wsum);
            pn_fiv_add8_all(fields, offset, row + n_phi + j_lo, w1 * (1.0f - tj), acc, &wsum);
            pn_fiv_add8_all(fields, offset, row + n_phi + j1, w1 * tj, acc, &wsum);
        }
    } else {
        /* The lanes' tap weights per offset in i and j, once; every sample
         * of the block added without a test of its weights. */
        float8 wi[PN_FIV_BLOCK], wj[PN_FIV_BLOCK];
        int jj[PN_FIV_BLOCK];
        for (int d = 0; d < PN_FIV_BLOCK; ++d) {
            wi[d] = pn_fiv_tap_weight8(d, oi, ti);
            wj[d] = pn_fiv_tap_weight8(d, oj, tj);
            jj[d] = j_lo + d >= n_phi ? j_lo + d - n_phi : j_lo + d;
        }
        /* the loop over j written out (2 to 4 samples; as a loop of nj
         * iterations: 1.02-1.03x the frame, docs/performance.md, FIV) */
        for (int dk = 0; dk < nk; ++dk) {
            /* pn_fiv_shell skips a sphere of weight 0: here it adds 0 */
            float8 wk = pn_fiv_tap_weight8(dk, ok, tk);
            wk = select((float8)(0.0f), wk, live & (wk > 0.0f));
            for (int di = 0; di < ni; ++di) {
                float8 wki = wk * wi[di];
                int row = ((rk.x + dk) * n_theta + ri.x + di) * n_phi;
                pn_fiv_add8_all(fields, offset, row + jj[0], wki * wj[0], acc, &wsum);
                pn_fiv_add8_all(fields, offset, row + jj[1], wki * wj[1], acc, &wsum);
                if (nj > 2) {
                    pn_fiv_add8_all(fields, offset, row + jj[2], wki * wj[2], acc, &wsum);
                    if (nj > 3)
                        pn_fiv_add8_all(fields, offset, row + jj[3], wki * wj[3], acc, &wsum);
                }
            }
        }
    }
    if (any(live & (wsum <= 0.0f)))
        return false;
    float8 f = occ[3].z * falloff / wsum;
    for (int c = 0; c < 9; ++c)
        vstore8(select((float8)(0.0f), acc[c] * f, live), 0, fr[c]);
    return true;
}

/* pn_lens_area, lane by lane, without its divides and acos: with
 * k = (-d + a + b)(d + a - b)(d - a + b)(d + a + b) = (2 d a)^2 - (d^2 + a^2 - b^2)^2,
 * acos((d^2 + a^2 - b^2) / (2 d a)) = atan2(sqrt(k), d^2 + a^2 - b^2) (both
 * scaled by 2 d a > 0), and likewise for b; atan2 by the polynomial atan
 * (2.5e-7 rad; the library acos is an out-of-line call). k < 0 by rounding
 * reads as 0, the angle 0 or pi, as acos of the clamped cosine. */
PN_FIV_INLINE float8 pn_fiv_lens8(float8 a, float8 b, float8 dist)
{
    float8 r = fmin(a, b);
    float8 d2 = dist * dist, a2 = a * a, b2 = b * b;
    float8 k = (-dist + a + b) * (dist + a - b) * (dist - a + b) * (dist + a + b);
    float8 sk = sqrt(fmax(k, 0.0f));
    float8 lens = a2 * pn_atan2_8(sk, d2 + a2 - b2) + b2 * pn_atan2_8(sk, d2 + b2 - a2) - 0.5f * sk;
    return select(select(lens, PN_PI * r * r, dist <= fabs(a - b)), (float8)(0.0f), dist >= a + b);
}

/* any() of a lane mask without branches: PoCL's any tests the lanes one by
 * one, a branch each, which mispredicts in the disc pairs' loop. */
PN_FIV_INLINE int pn_fiv_any8(int8 m)
{
    int4 a = m.lo | m.hi;
    int2 b = a.lo | a.hi;
    return (b.x | b.y) < 0;
}

/* The last single normal a work-item looked up (shade_fiv): its raw bits
 * as read from the G-buffer, the normalised normal and its unshadowed
 * irradiance. */
typedef struct {
    uint3 raw;
    float3 n, e;
    bool valid;
} pn_fiv_normal_cache;

/* shade_fiv's arguments, for the functions below. */
typedef struct {
    global const float4 *position, *normal, *albedo;
    global const uint *instance_id;
    global const float4 *irradiance, *occluders;
    global const uchar *fields;
    global const uint *tile_masks;
    global float4 *image;
    global const float *latlong;
    float4 env_x, env_y, env_z;
    float2 rot;
    float cull_floor, intensity;
    int m, occluder_count, overlap, partial, self_shadow, trilinear, width, binned, background, latlong_width,
        latlong_height, max_overlap;
} pn_fiv_args;

/* A group of 8 pixels of a row in lanes, and its sums over the occluders. */
typedef struct {
    int y, x0, row;
    bool full;
    int8 in_row, active, sky;
    uint8 id8;
    float8 px, py, pz, nx, ny, nz;
    float8 tot_r, tot_g, tot_b, base_r, base_g, base_b;
    float8 sum_r, sum_g, sum_b, big_r, big_g, big_b, vis_r, vis_g, vis_b;
} pn_fiv_px8;

/* The 8 pixels of row y from x0 on, up to the occluder loop: false when
 * they are all background (then drawn and stored here). */
PN_FIV_INLINE bool pn_fiv_begin8(const pn_fiv_args *a, int y, int x0, pn_fiv_normal_cache *cache, pn_fiv_px8 *q)
{
    /* The 8 pixels in lanes: the G-buffer planes by 8-wide loads and
     * shuffles (pn_load_row8), the normals normalised in lanes (the
     * built-in's bits, pn_normalize8). Each lane's values go into the lane
     * vectors as elements or by shuffles, never through a lane array written
     * one lane at a time and read back as a vector (that stalls the load on
     * the 8 stores). The background pixels get the env map here
     * (pn_background8, the background pass's operations in the same order:
     * this kernel draws the background in the same visit of the pixels
     * instead of a second pass over them; black without `background`). */
    const int width = a->width;
    const int row = y * width + x0;
    const bool full = x0 + PN_FIV_LANES <= width;
    const int8 in_row = (int8)(0, 1, 2, 3, 4, 5, 6, 7) < width - x0;
    uint8 id8;
    if (full) {
        id8 = vload8(0, a->instance_id + row);
    } else {
#define PN_FIV_ID_LANE(l) id8.s##l = x0 + l < width ? a->instance_id[row + l] : PN_BACKGROUND;
        PN_FIV_ID_LANE(0) PN_FIV_ID_LANE(1) PN_FIV_ID_LANE(2) PN_FIV_ID_LANE(3)
        PN_FIV_ID_LANE(4) PN_FIV_ID_LANE(5) PN_FIV_ID_LANE(6) PN_FIV_ID_LANE(7)
#undef PN_FIV_ID_LANE
    }
    const int8 active = id8 != PN_BACKGROUND, sky = ~active & in_row;
    float8 px, py, pz, nx, ny, nz;
    pn_load_row8(a->position, row, full, in_row, &px, &py, &pz);
    if (!any(active)) { /* all background */
        float8 sky_r = 0.0f, sky_g = 0.0f, sky_b = 0.0f;
        if (a->background)
            pn_background8(a->latlong, a->latlong_width, a->latlong_height, a->rot, a->intensity, px, py, pz, sky,
                           &sky_r, &sky_g, &sky_b);
        pn_store_row8(a->image, row, full, in_row, sky_r, sky_g, sky_b, (float8)(0.0f));
        return false;
    }
    pn_load_row8(a->normal, row, full, in_row, &nx, &ny, &nz);
    px = select((float8)(0.0f), px, active), py = select((float8)(0.0f), py, active);
    pz = select((float8)(0.0f), pz, active);
    nx = select((float8)(0.0f), nx, active), ny = select((float8)(1.0f), ny, active);
    nz = select((float8)(0.0f), nz, active);
    /* 8 neighbouring pixels of a flat surface share one normal (most of a
     * floor): their irradiance is looked up once (pn_cube_grid_lookup8) */
    const bool one_normal = !pn_fiv_any8(~((nx == nx.s0) & (ny == ny.s0) & (nz == nz.s0)));
    float8 tot_r = 0.0f, tot_g = 0.0f, tot_b = 0.0f;
    const uint3 raw = (uint3)(as_uint(nx.s0), as_uint(ny.s0), as_uint(nz.s0));
#ifndef PN_FIV_NO_NORMAL_CACHE
    if (one_normal && cache->valid && raw.x == cache->raw.x && raw.y == cache->raw.y && raw.z == cache->raw.z) {
        /* the same normal bits as the last single normal: the same
         * normalised normal and irradiance (pn_cube_grid_lookup8's one-normal
         * path, computed once per work-item and normal) */
        nx = cache->n.x, ny = cache->n.y, nz = cache->n.z;
        const float3 e = cache->e;
        tot_r = select((float8)(0.0f), (float8)(e.x), active), tot_g = select((float8)(0.0f), (float8)(e.y), active);
        tot_b = select((float8)(0.0f), (float8)(e.z), active);
    } else
#endif
    {
        pn_normalize8(&nx, &ny, &nz);
        pn_cube_grid_lookup8(a->irradiance, a->m, nx, ny, nz, active, one_normal, &tot_r, &tot_g, &tot_b);
        if (one_normal) {
            const float3 n = (float3)(nx.s0, ny.s0, nz.s0);
            cache->raw = raw, cache->n = n, cache->e = pn_cube_grid_lookup(a->irradiance, a->m, n);
            cache->valid = true;
        }
    }
    float8 base_r = tot_r, base_g = tot_g, base_b = tot_b;
    if (a->self_shadow) {
        /* per-lane copies for the scalar code below (a vector store, read
         * back one lane at a time, forwards) */
        float lp[3][PN_FIV_LANES], ln[3][PN_FIV_LANES];
        uint lid[PN_FIV_LANES];
        int lactive[PN_FIV_LANES];
        vstore8(id8, 0, lid);
        vstore8(active, 0, lactive);
        vstore8(px, 0, lp[0]), vstore8(py, 0, lp[1]), vstore8(pz, 0, lp[2]);
        vstore8(nx, 0, ln[0]), vstore8(ny, 0, ln[1]), vstore8(nz, 0, ln[2]);
        const int8 lane = (int8)(0, 1, 2, 3, 4, 5, 6, 7);
        for (int l = 0; l < PN_FIV_LANES; ++l) {
            if (!lactive[l])
                continue;
            uint id = lid[l];
            /* Self-shadowing: the pixel's own occluder, found by its id among all
             * of them (a tile's mask may leave it out when a G-buffer puts the
             * pixel beyond its culling distance). All unoccluded light is in the
             * positive hemisphere. */
            for (int o = 0; o < a->occluder_count; ++o) {
                global const float4 *occ = a->occluders + PN_FIV_RECORD * o;
                pn_fiv3 f;
                if (as_uint(occ[3].x) != id)
                    continue;
                float3 p = (float3)(lp[0][l], lp[1][l], lp[2][l]), n = (float3)(ln[0][l], ln[1][l], ln[2][l]);
                if (pn_fiv_lookup(occ, a->fields, occ[0].xyz - p, a->trilinear, 0.0f, &f)) {
                    /* A sample off the surface also sees unoccluded light behind
                     * the receiver plane, which the fullsphere sum subtracts: the
                     * estimate errs low, never above the unoccluded irradiance. */
                    float at[3][PN_FIV_LANES];
                    vstore8(tot_r, 0, at[0]), vstore8(tot_g, 0, at[1]), vstore8(tot_b, 0, at[2]);
                    pn_fiv3 env = {a->env_x.xyz, a->env_y.xyz, a->env_z.xyz};
                    float3 e_base = clamp(pn_fiv_dot(n, env) - pn_fiv_dot(n, f), 0.0f,
                                          (float3)(at[0][l], at[1][l], at[2][l]));
                    int8 here = lane == l;
                    base_r = select(base_r, (float8)(e_base.x), here);
                    base_g = select(base_g, (float8)(e_base.y), here);
                    base_b = select(base_b, (float8)(e_base.z), here);
                }
                break; /* one field per instance */
            }
        }
    }
    q->y = y, q->x0 = x0, q->row = row, q->full = full, q->in_row = in_row, q->active = active, q->sky = sky;
    q->id8 = id8;
    q->px = px, q->py = py, q->pz = pz, q->nx = nx, q->ny = ny, q->nz = nz;
    q->tot_r = tot_r, q->tot_g = tot_g, q->tot_b = tot_b, q->base_r = base_r, q->base_g = base_g, q->base_b = base_b;
    q->sum_r = q->sum_g = q->sum_b = q->big_r = q->big_g = q->big_b = 0.0f;
    q->vis_r = q->vis_g = q->vis_b = 1.0f;
    return true;
}

/* The first word of the occluder mask of the pixels' 16x16 tile (all
 * occluders unbinned), `words` words a tile. */
PN_FIV_INLINE global const uint *pn_fiv_tile_mask(const pn_fiv_args *a, const pn_fiv_px8 *q, int words)
{
    if (!a->binned)
        return a->tile_masks;
    int tile = (q->y / PN_FIV_TILE) * ((a->width + PN_FIV_TILE - 1) / PN_FIV_TILE) + q->x0 / PN_FIV_TILE;
    return a->tile_masks + (size_t)tile * words;
}

/* An occluder's tests for the 8 pixels: not their own occluder (above), not
 * fully behind the receiver plane (case C), not beyond the culling distance. */
PN_FIV_INLINE int8 pn_fiv_take8(const pn_fiv_px8 *q, global const float4 *occ, float8 *vx, float8 *vy, float8 *vz,
                                float8 *dist_plane, float8 *rho)
{
    float4 sphere = occ[0];
    *vx = sphere.x - q->px, *vy = sphere.y - q->py, *vz = sphere.z - q->pz;
    float r = sphere.w;
    *dist_plane = *vx * q->nx + *vy * q->ny + *vz * q->nz;
    *rho = sqrt(*vx * *vx + *vy * *vy + *vz * *vz);
    return q->active & (q->id8 != as_uint(occ[3].x)) & ~(*dist_plane <= -r) & ~(*rho > occ[1].w);
}

/* The lookup's first half for the lanes of `take` (pn_fiv_index8): the
 * lanes still in play. */
PN_FIV_INLINE int8 pn_fiv_index_occ8(const pn_fiv_args *a, global const float4 *occ, float8 vx, float8 vy, float8 vz,
                                     int8 take, float8 *fi, float8 *fj, float8 *fk, float8 *falloff)
{
#if PN_FIV_PROFILE == 1
    *fi = *fj = *fk = *falloff = 0.0f;
    return take;
#else
    return pn_fiv_index8(occ, a->fields, vx, vy, vz, take, a->cull_floor, fi, fj, fk, falloff);
#endif
}

/* The lookup's second half: the lanes' FIVs into fr (pn_fiv_fetch8 for all
 * lanes at once, else lane by lane); the lanes still in play. */
PN_FIV_INLINE int8 pn_fiv_fetch_occ8(const pn_fiv_args *a, global const float4 *occ, float8 fi, float8 fj, float8 fk,
                                     float8 falloff, int8 take, float fr[9][PN_FIV_LANES])
{
#if PN_FIV_PROFILE == 1
    for (int c = 0; c < 9; ++c)
        vstore8((float8)(occ[3].z * 1e-3f), 0, fr[c]);
    return take;
#elif PN_FIV_PROFILE == 2
    for (int c = 0; c < 9; ++c)
        vstore8((fi + fj + fk) * falloff, 0, fr[c]);
    return take;
#else
    /* all lanes in one cell: its samples read once (pn_fiv_fetch8); else lane by lane */
    if (pn_fiv_fetch8(occ, a->fields, fi, fj, fk, falloff, take, a->trilinear, fr))
        return take;
#if PN_FIV_PROFILE == 3
    /* mark the lanes that would go lane by lane (counted by bench/fiv_profile.py) */
    for (int c = 0; c < 9; ++c)
        vstore8((float8)(1e6f), 0, fr[c]);
    return take;
#else
    float afi[PN_FIV_LANES], afj[PN_FIV_LANES], afk[PN_FIV_LANES], afo[PN_FIV_LANES];
    int at[PN_FIV_LANES];
    vstore8(fi, 0, afi);
    vstore8(fj, 0, afj);
    vstore8(fk, 0, afk);
    vstore8(falloff, 0, afo);
    vstore8(take, 0, at);
    for (int l = 0; l < PN_FIV_LANES; ++l) {
        pn_fiv3 f = {(float3)(0.0f), (float3)(0.0f), (float3)(0.0f)};
        if (at[l] && !pn_fiv_fetch(occ, a->fields, afi[l], afj[l], afk[l], afo[l], a->trilinear, &f))
            at[l] = 0;
        fr[0][l] = f.x.x, fr[1][l] = f.x.y, fr[2][l] = f.x.z;
        fr[3][l] = f.y.x, fr[4][l] = f.y.y, fr[5][l] = f.y.z;
        fr[6][l] = f.z.x, fr[7][l] = f.z.y, fr[8][l] = f.z.z;
    }
    return vload8(0, at);
#endif
#endif
}

/* The occluder's irradiance N . FIV in the lanes of `take` (0 in the
 * others) into the pixels' sums, largest and visibilities. */
PN_FIV_INLINE void pn_fiv_add_occ8(const pn_fiv_args *a, pn_fiv_px8 *q, int8 take, float fr[9][PN_FIV_LANES],
                                   float8 dist_plane, float r, float8 *i_r_out, float8 *i_g_out, float8 *i_b_out)
{
    /* An occluder only removes light (N . FIV per channel, as pn_fiv_dot). */
    const float8 nx = q->nx, ny = q->ny, nz = q->nz;
    float8 i_r = fmax(nx * vload8(0, fr[0]) + ny * vload8(0, fr[3]) + nz * vload8(0, fr[6]), 0.0f);
    float8 i_g = fmax(nx * vload8(0, fr[1]) + ny * vload8(0, fr[4]) + nz * vload8(0, fr[7]), 0.0f);
    float8 i_b = fmax(nx * vload8(0, fr[2]) + ny * vload8(0, fr[5]) + nz * vload8(0, fr[8]), 0.0f);
    if (a->partial) { /* case B: the share above the plane */
        int8 b = dist_plane < r;
        float8 share = select((float8)(1.0f), (dist_plane + r) / (2.0f * r), b);
        i_r = select(i_r, i_r * share, b);
        i_g = select(i_g, i_g * share, b);
        i_b = select(i_b, i_b * share, b);
    }
    i_r = select((float8)(0.0f), i_r, take);
    i_g = select((float8)(0.0f), i_g, take);
    i_b = select((float8)(0.0f), i_b, take);
    q->sum_r += i_r, q->sum_g += i_g, q->sum_b += i_b;
    q->big_r = fmax(q->big_r, i_r), q->big_g = fmax(q->big_g, i_g), q->big_b = fmax(q->big_b, i_b);
    if (a->overlap == PN_OVERLAP_MULTIPLY) {
        q->vis_r = select(q->vis_r, q->vis_r * clamp(1.0f - i_r / fmax(q->tot_r, 1e-30f), 0.0f, 1.0f), take);
        q->vis_g = select(q->vis_g, q->vis_g * clamp(1.0f - i_g / fmax(q->tot_g, 1e-30f), 0.0f, 1.0f), take);
        q->vis_b = select(q->vis_b, q->vis_b * clamp(1.0f - i_b / fmax(q->tot_b, 1e-30f), 0.0f, 1.0f), take);
    }
    *i_r_out = i_r, *i_g_out = i_g, *i_b_out = i_b;
}

/* The pixels: albedo in lanes times the irradiance e; background lanes as in
 * pn_fiv_begin8 (their directions read again here, so that nothing of
 * theirs is kept across the occluder loop). */
PN_FIV_INLINE void pn_fiv_end8(const pn_fiv_args *a, const pn_fiv_px8 *q, float8 e_r, float8 e_g, float8 e_b)
{
    float8 ar, ag, ab, sky_r = 0.0f, sky_g = 0.0f, sky_b = 0.0f;
    pn_load_row8(a->albedo, q->row, q->full, q->in_row, &ar, &ag, &ab);
    if (a->background && any(q->sky)) {
        float8 qx, qy, qz;
        pn_load_row8(a->position, q->row, q->full, q->in_row, &qx, &qy, &qz);
        pn_background8(a->latlong, a->latlong_width, a->latlong_height, a->rot, a->intensity, qx, qy, qz, q->sky,
                       &sky_r, &sky_g, &sky_b);
    }
    /* fmax(albedo.xyz * e * PN_INV_PI, 0) per lane, as the scalar code */
    const int8 active = q->active;
    float8 out_r = select(sky_r, fmax(ar * e_r * PN_INV_PI, 0.0f), active);
    float8 out_g = select(sky_g, fmax(ag * e_g * PN_INV_PI, 0.0f), active);
    float8 out_b = select(sky_b, fmax(ab * e_b * PN_INV_PI, 0.0f), active);
    pn_store_row8(a->image, q->row, q->full, q->in_row, out_r, out_g, out_b,
                  select((float8)(0.0f), (float8)(1.0f), active));
}

#ifndef PN_FIV_PAIR_BY_ORDER
#define PN_FIV_PAIR_BY_ORDER 0
#endif
#ifndef PN_FIV_LENS_SCALE
#define PN_FIV_LENS_SCALE 1.0f
#endif

/* An occluder's key for the disc correction's choice: its irradiance summed
 * over the channels (the same operations where it is read back from the
 * slots, so the same bits). */
PN_FIV_INLINE float8 pn_fiv_key8(float8 i_r, float8 i_g, float8 i_b)
{
    return i_r + i_g + i_b;
}

/* The disc slots (pn_fiv_run8) as the occluder loop leaves them: per lane
 * the receiver-to-centre vector (dd[0..2]), its length (dd[3]; -1 where
 * the lane stored nothing) and the occluder's irradiance (dd[4..6]); per
 * slot the occluder's radius (rr). Here the lanes' discs whose key is below
 * their threshold `thr` (or zero) are dropped and the slots every lane has
 * dropped removed, the others kept in their order; a dropped disc can never
 * come back, since the threshold only grows. With `discs`, the kept ones
 * become the unit discs the pairs read: unit direction (dd[0..2]; the normal
 * where the receiver is at the centre), radius min(R / rho, 1) (dd[3]), and
 * zeros in the lanes without one (a zero disc pairs with none). Their
 * divides are done here, for the few discs kept, not in the loop for every
 * one stored. */
PN_FIV_INLINE void pn_fiv_drop_slots8(const pn_fiv_px8 *q, float dd[7][PN_FIV_SLOTS * PN_FIV_LANES],
                                      float rr[PN_FIV_SLOTS], int *slots, float8 thr, bool discs)
{
    const float8 zero = 0.0f;
    int kept = 0;
    for (int d = 0; d < *slots; ++d) {
        const float8 rho = vload8(d, dd[3]);
        const float8 key = pn_fiv_key8(vload8(d, dd[4]), vload8(d, dd[5]), vload8(d, dd[6]));
#if PN_FIV_PAIR_BY_ORDER
        const int8 keep = rho >= 0.0f;
#else
        const int8 keep = (rho >= 0.0f) & (key >= thr) & (key > 0.0f);
#endif
        if (!pn_fiv_any8(keep))
            continue;
        const float8 vx = vload8(d, dd[0]), vy = vload8(d, dd[1]), vz = vload8(d, dd[2]);
        const float r = rr[d];
        if (discs) {
            const int8 far = rho > 0.0f;
            vstore8(select(zero, select(q->nx, vx / rho, far), keep), kept, dd[0]);
            vstore8(select(zero, select(q->ny, vy / rho, far), keep), kept, dd[1]);
            vstore8(select(zero, select(q->nz, vz / rho, far), keep), kept, dd[2]);
            vstore8(select(zero, fmin(r / fmax(rho, 1e-30f), 1.0f), keep), kept, dd[3]);
        } else {
            vstore8(select(zero, vx, keep), kept, dd[0]);
            vstore8(select(zero, vy, keep), kept, dd[1]);
            vstore8(select(zero, vz, keep), kept, dd[2]);
            vstore8(select((float8)(-1.0f), rho, keep), kept, dd[3]);
        }
        for (int c = 4; c < 7; ++c)
            vstore8(select(zero, vload8(d, dd[c]), keep), kept, dd[c]);
        rr[kept] = r;
        ++kept;
    }
    *slots = kept;
}

/* The lanes' share of an occluder (taken in `take`) in slot *slots of the
 * disc slots (pn_fiv_drop_slots8 says what they hold). Each lane pairs the
 * `max_overlap` occluders with the largest keys (its largest shadows),
 * whatever the scene's order: top[0 .. max_overlap - 1] holds the lane's
 * largest keys so far, descending (zeros at first), and an occluder is
 * stored only while its key is among them; those pushed out later are
 * dropped before the pairs are formed, or here when the slots are full. An
 * occluder whose irradiance is zero takes no part: it shadows nothing, so
 * nothing of it is counted twice. (PN_FIV_PAIR_BY_ORDER, a build option for
 * measuring: the first `max_overlap` in the scene's order, top[0] counting
 * them, as before.) */
PN_FIV_INLINE void pn_fiv_fill_slot8(const pn_fiv_args *a, const pn_fiv_px8 *q,
                                     float dd[7][PN_FIV_SLOTS * PN_FIV_LANES], float rr[PN_FIV_SLOTS],
                                     float8 top[PN_FIV_MAX_OVERLAP], int *slots, int8 take, float8 vx, float8 vy,
                                     float8 vz, float8 rho, float r, float8 i_r, float8 i_g, float8 i_b)
{
#if PN_FIV_PAIR_BY_ORDER
    int8 fill = take & (top[0] < (float)a->max_overlap);
    top[0] += select((float8)(0.0f), (float8)(1.0f), fill);
#else
    const float8 key = select((float8)(0.0f), pn_fiv_key8(i_r, i_g, i_b), take);
    /* one insertion step of a sorting network per place, no branch: whether
     * a key enters is as likely as not, so a test mispredicts */
    float8 y = key;
    for (int j = 0; j < a->max_overlap; ++j) {
        const float8 t = top[j];
        top[j] = fmax(t, y), y = fmin(t, y);
    }
    const float8 thr = top[a->max_overlap - 1];
    int8 fill = take & (key > 0.0f) & (key >= thr);
#endif
    if (*slots == PN_FIV_SLOTS) { /* rare: the slots are full */
#if !PN_FIV_PAIR_BY_ORDER
        if (pn_fiv_any8(fill))
            pn_fiv_drop_slots8(q, dd, rr, slots, thr, false);
#endif
        if (*slots == PN_FIV_SLOTS) /* only ties of keys can hold this many: the occluder is left out */
            return;
    }
    /* stored in any case, kept (the count moved on) where some lane fills */
    const float8 zero = 0.0f;
    vstore8(select(zero, vx, fill), *slots, dd[0]);
    vstore8(select(zero, vy, fill), *slots, dd[1]);
    vstore8(select(zero, vz, fill), *slots, dd[2]);
    vstore8(select((float8)(-1.0f), rho, fill), *slots, dd[3]);
    vstore8(select(zero, i_r, fill), *slots, dd[4]);
    vstore8(select(zero, i_g, fill), *slots, dd[5]);
    vstore8(select(zero, i_b, fill), *slots, dd[6]);
    rr[*slots] = r;
    *slots += pn_fiv_any8(fill);
}

/* The overlap correction, in lanes (pn_fiv_run8), then the pixels. */
PN_FIV_INLINE void pn_fiv_finish8(const pn_fiv_args *a, const pn_fiv_px8 *q, bool pairs,
                                  float dd[7][PN_FIV_SLOTS * PN_FIV_LANES], float rr[PN_FIV_SLOTS],
                                  const float8 top[PN_FIV_MAX_OVERLAP], int slots)
{
    float8 e_r, e_g, e_b;
    if (a->overlap == PN_OVERLAP_MULTIPLY) {
        e_r = q->base_r * q->vis_r, e_g = q->base_g * q->vis_g, e_b = q->base_b * q->vis_b;
    } else {
        float8 tot_r = q->sum_r, tot_g = q->sum_g, tot_b = q->sum_b;
        if (pairs) {
            /* each lane's largest keys, as unit discs */
            pn_fiv_drop_slots8(q, dd, rr, &slots, top[a->max_overlap - 1], true);
            /* Pairwise: the lens of two unit bounding discs, as a share of their
             * areas, of the two occluders' irradiance is counted once; each
             * lane over its own discs, in the scalar code's order. Per disc d,
             * first the later discs b near it in some lane, listed without a
             * branch (most pairs are apart: no lens, no sqrt or acos spent on
             * them), then the lenses of the listed pairs, in order. */
            for (int d = 0; d < slots; ++d) {
                float8 uax = vload8(d, dd[0]), uay = vload8(d, dd[1]), uaz = vload8(d, dd[2]), ra = vload8(d, dd[3]);
                uchar list[PN_FIV_SLOTS];
                int listed = 0;
                for (int b = d + 1; b < slots; ++b) {
                    float8 rb = vload8(b, dd[3]);
                    float8 ex = uax - vload8(b, dd[0]), ey = uay - vload8(b, dd[1]), ez = uaz - vload8(b, dd[2]);
                    float8 d2 = ex * ex + ey * ey + ez * ez;
                    list[listed] = (uchar)b;
                    listed += pn_fiv_any8(~(d2 >= (ra + rb) * (ra + rb)));
                }
                for (int k = 0; k < listed; ++k) {
                    int b = list[k];
                    float8 rb = vload8(b, dd[3]);
                    float8 ex = uax - vload8(b, dd[0]), ey = uay - vload8(b, dd[1]), ez = uaz - vload8(b, dd[2]);
                    float8 d2 = ex * ex + ey * ey + ez * ez;
                    int8 near = ~(d2 >= (ra + rb) * (ra + rb));
                    float8 lens = pn_fiv_lens8(ra, rb, sqrt(d2));
                    int8 take = near & (lens > 0.0f);
                    float8 share = PN_FIV_LENS_SCALE * lens / (PN_PI * (ra * ra + rb * rb));
                    tot_r = select(tot_r, tot_r - share * (vload8(d, dd[4]) + vload8(b, dd[4])), take);
                    tot_g = select(tot_g, tot_g - share * (vload8(d, dd[5]) + vload8(b, dd[5])), take);
                    tot_b = select(tot_b, tot_b - share * (vload8(d, dd[6]) + vload8(b, dd[6])), take);
                }
            }
            tot_r = clamp(tot_r, q->big_r, q->sum_r), tot_g = clamp(tot_g, q->big_g, q->sum_g);
            tot_b = clamp(tot_b, q->big_b, q->sum_b);
        }
        e_r = q->base_r - tot_r, e_g = q->base_g - tot_g, e_b = q->base_b - tot_b;
    }
    pn_fiv_end8(a, q, e_r, e_g, e_b);
}

/* Whether the disc correction forms pairs (one occluder has none: total =
 * sum, clamped to [largest, sum]). */
PN_FIV_INLINE bool pn_fiv_pairs(const pn_fiv_args *a)
{
    return a->overlap == PN_OVERLAP_DISC && a->occluder_count > 1;
}

/* The 32-occluder words of the tile masks the occluder loop walks (none in
 * the profiling build without the loop). */
PN_FIV_INLINE int pn_fiv_words(const pn_fiv_args *a)
{
#if PN_FIV_PROFILE == 4
    return 0;
#else
    return (a->occluder_count + 31) / 32;
#endif
}

/* Word w of the tile's occluder bits: the mask's, or all occluders unbinned. */
PN_FIV_INLINE uint pn_fiv_word_bits(const pn_fiv_args *a, global const uint *mask, int w)
{
    int left = a->occluder_count - 32 * w;
    return a->binned ? mask[w] : left >= 32 ? 0xFFFFFFFFu : (1u << left) - 1u;
}

/* The occluder loop and the pixels of one group (pn_fiv_begin8 before). */
PN_FIV_INLINE void pn_fiv_run8(const pn_fiv_args *a, pn_fiv_px8 *q)
{
    /* Disc correction: one slot per occluder that some lane stored (in the
     * loop's order), lane l of slot d at [d * 8 + l] (what a slot holds:
     * pn_fiv_drop_slots8); nothing in the lanes that did not take it or hold
     * `max_overlap` larger keys (pn_fiv_fill_slot8). A slot is one
     * occluder in all lanes, so neighbouring pixels' pairs line up: a pair
     * near in one lane is mostly near in the others. A zero disc never adds
     * to a lane's correction (its lens with any disc is 0), so each lane sees
     * its own discs in the scalar order. At most 8 x 32 slots (57 KiB of
     * private memory; a work-item fills only the slots it uses), and per lane
     * its largest keys (1 KiB). */
    float dd[7][PN_FIV_SLOTS * PN_FIV_LANES], rr[PN_FIV_SLOTS];
    float8 top[PN_FIV_MAX_OVERLAP];
    int slots = 0;
    const bool pairs = pn_fiv_pairs(a);
    for (int j = 0; pairs && j < a->max_overlap; ++j)
        top[j] = 0.0f;
    const int words = pn_fiv_words(a);
    global const uint *mask = pn_fiv_tile_mask(a, q, words);
    for (int w = 0; w < words; ++w) {
        /* The occluders of these pixels' tile (all of them unbinned), in order. */
        uint bits = pn_fiv_word_bits(a, mask, w);
        while (bits) {
            int o = 32 * w + (31 - clz(bits & (0u - bits)));
            bits &= bits - 1u;
            global const float4 *occ = a->occluders + PN_FIV_RECORD * o;
            float8 vx, vy, vz, dist_plane, rho;
            int8 take = pn_fiv_take8(q, occ, &vx, &vy, &vz, &dist_plane, &rho);
            if (!any(take))
                continue;
            float fr[9][PN_FIV_LANES];
            float8 fi, fj, fk, falloff;
            take = pn_fiv_index_occ8(a, occ, vx, vy, vz, take, &fi, &fj, &fk, &falloff);
            if (!any(take))
                continue;
            take = pn_fiv_fetch_occ8(a, occ, fi, fj, fk, falloff, take, fr);
            if (!any(take))
                continue;
            const float r = occ[0].w;
            float8 i_r, i_g, i_b;
            pn_fiv_add_occ8(a, q, take, fr, dist_plane, r, &i_r, &i_g, &i_b);
            if (pairs)
                pn_fiv_fill_slot8(a, q, dd, rr, top, &slots, take, vx, vy, vz, rho, r, i_r, i_g, i_b);
        }
    }
    pn_fiv_finish8(a, q, pairs, dd, rr, top, slots);
}

/* pn_fiv_run8 for two groups of one 16x16 tile (the same occluders, in the
 * same order) without the disc correction's pairs: each occluder's tests,
 * then its index math, then its fetch and sums, for both groups side by
 * side, so that their long chains of dependent operations overlap (one
 * group at a time leaves most of the core waiting on them). Per group the
 * operations of pn_fiv_run8, in its order: the same bits. */
PN_FIV_INLINE void pn_fiv_run_pair8(const pn_fiv_args *a, pn_fiv_px8 *p, pn_fiv_px8 *q)
{
    /* the disc slots of each group (pn_fiv_run8) */
    float dd[7][PN_FIV_SLOTS * PN_FIV_LANES], udd[7][PN_FIV_SLOTS * PN_FIV_LANES];
    float rr[PN_FIV_SLOTS], urr[PN_FIV_SLOTS];
    float8 top[PN_FIV_MAX_OVERLAP], utop[PN_FIV_MAX_OVERLAP];
    int slots = 0, uslots = 0;
    const bool pairs = pn_fiv_pairs(a);
    for (int j = 0; pairs && j < a->max_overlap; ++j)
        top[j] = utop[j] = 0.0f;
    const int words = pn_fiv_words(a);
    global const uint *mask = pn_fiv_tile_mask(a, p, words);
    for (int w = 0; w < words; ++w) {
        uint bits = pn_fiv_word_bits(a, mask, w);
        while (bits) {
            int o = 32 * w + (31 - clz(bits & (0u - bits)));
            bits &= bits - 1u;
            global const float4 *occ = a->occluders + PN_FIV_RECORD * o;
            float8 vx, vy, vz, dist_plane, rho, ux, uy, uz, udist_plane, urho;
            int8 take = pn_fiv_take8(p, occ, &vx, &vy, &vz, &dist_plane, &rho);
            int8 utake = pn_fiv_take8(q, occ, &ux, &uy, &uz, &udist_plane, &urho);
            const bool on = any(take), uon = any(utake);
            if (!on && !uon)
                continue;
            float8 fi = 0.0f, fj = 0.0f, fk = 0.0f, falloff = 0.0f, ui = 0.0f, uj = 0.0f, uk = 0.0f, ufalloff = 0.0f;
            if (on)
                take = pn_fiv_index_occ8(a, occ, vx, vy, vz, take, &fi, &fj, &fk, &falloff);
            if (uon)
                utake = pn_fiv_index_occ8(a, occ, ux, uy, uz, utake, &ui, &uj, &uk, &ufalloff);
            const float r = occ[0].w;
            float8 i_r, i_g, i_b;
            if (on && any(take)) {
                float fr[9][PN_FIV_LANES];
                take = pn_fiv_fetch_occ8(a, occ, fi, fj, fk, falloff, take, fr);
                if (any(take)) {
                    pn_fiv_add_occ8(a, p, take, fr, dist_plane, r, &i_r, &i_g, &i_b);
                    if (pairs)
                        pn_fiv_fill_slot8(a, p, dd, rr, top, &slots, take, vx, vy, vz, rho, r, i_r, i_g, i_b);
                }
            }
            if (uon && any(utake)) {
                float fr[9][PN_FIV_LANES];
                utake = pn_fiv_fetch_occ8(a, occ, ui, uj, uk, ufalloff, utake, fr);
                if (any(utake)) {
                    pn_fiv_add_occ8(a, q, utake, fr, udist_plane, r, &i_r, &i_g, &i_b);
                    if (pairs)
                        pn_fiv_fill_slot8(a, q, udd, urr, utop, &uslots, utake, ux, uy, uz, urho, r, i_r, i_g, i_b);
                }
            }
        }
    }
    pn_fiv_finish8(a, p, pairs, dd, rr, top, slots);
    pn_fiv_finish8(a, q, pairs, udd, urr, utop, uslots);
}

#ifndef PN_FIV_PAIR_DISCS
#define PN_FIV_PAIR_DISCS 1
#endif

/* Groups of an all-background work-item whose texel cells are computed
 * before their texels are read (shade_fiv). */
#define PN_FIV_SKY_BATCH 8

/* Whether the groups g0 .. g1 - 1 of the row from index `row0` on are all
 * background (the lanes past the row's end count as background). */
PN_FIV_INLINE bool pn_fiv_all_sky(global const uint *instance_id, int row0, int width, int g0, int g1)
{
    for (int g = g0; g < g1; ++g) {
        const int x0 = PN_FIV_LANES * g;
        if (x0 + PN_FIV_LANES <= width) {
            if (pn_fiv_any8(as_int8(vload8(0, instance_id + row0 + x0) != PN_BACKGROUND)))
                return false;
        } else {
            for (int x = x0; x < width; ++x)
                if (instance_id[row0 + x] != PN_BACKGROUND)
                    return false;
        }
    }
    return true;
}

/* pn_background_cell8 of group g of an all-background row (shade_fiv). */
PN_FIV_INLINE void pn_fiv_sky_cell8(global const float4 *position, int row0, int width, int g, float2 rot,
                                    int latlong_width, int latlong_height, int8 *i00, int8 *i10, int8 *i01,
                                    int8 *i11, float8 *fx, float8 *fy)
{
    const int x0 = PN_FIV_LANES * g;
    const int8 in_row = (int8)(0, 1, 2, 3, 4, 5, 6, 7) < width - x0;
    float8 px, py, pz;
    pn_load_row8(position, row0 + x0, x0 + PN_FIV_LANES <= width, in_row, &px, &py, &pz);
    pn_background_cell8(latlong_width, latlong_height, rot, px, py, pz, in_row, i00, i10, i01, i11, fx, fy);
}

/* One work-item per `row_groups` groups of 8 pixels of a row (above; global
 * size ceil(ceil(width / 8) / row_groups) x height, PN_FIV_ROW_GROUPS in
 * capi/src/methods/fiv.c): neighbouring groups of a flat surface mostly
 * share one normal, whose normalisation and unshadowed irradiance a
 * work-item then computes once (pn_fiv_normal_cache); a work-item of
 * background alone computes its groups' texel cells before their texels;
 * without the disc correction's pairs the two groups of a 16x16 tile go
 * through the occluder loop side by side (pn_fiv_run_pair8). Each group's
 * pixels get the operations of one group alone, so the same bits
 * (docs/performance.md, FIV, "The floor round 2"). */
kernel void shade_fiv(global const float4 *position, global const float4 *normal, global const float4 *albedo,
                      global const uint *instance_id, int count, global const float4 *irradiance, int m,
                      global const float4 *occluders,
                      int occluder_count, global const uchar *fields, float cull_floor, float4 env_x, float4 env_y,
                      float4 env_z,
                      int overlap, int partial, int self_shadow, int trilinear, int width, int binned,
                      global const uint *tile_masks, global float4 *image, int background,
                      global const float *latlong, int latlong_width, int latlong_height, float2 rot,
                      float intensity, int row_groups, int max_overlap)
{
    if (width <= 0 || row_groups <= 0)
        return;
    const int groups = (width + PN_FIV_LANES - 1) / PN_FIV_LANES, per_row = (groups + row_groups - 1) / row_groups;
    const int item = get_global_id(0);
    const int y = item / per_row, g0 = (item - y * per_row) * row_groups;
    if (y >= count / width)
        return;
    const int g1 = min(g0 + row_groups, groups);
#ifndef PN_FIV_NO_SKY_BATCH
    if (background && pn_fiv_all_sky(instance_id, y * width, width, g0, g1)) {
        /* Only env map pixels (the sky above a horizon): the texel offsets
         * and weights of up to PN_FIV_SKY_BATCH groups first
         * (pn_background_cell8), then their texels, so that the groups'
         * chains from the direction through the angles to the texel reads
         * overlap (one group at a time leaves them waiting on each other);
         * the same operations per group as pn_background8, so the same bits. */
        for (int gb = g0; gb < g1; gb += PN_FIV_SKY_BATCH) {
            const int n = min(PN_FIV_SKY_BATCH, g1 - gb);
            int8 c00[PN_FIV_SKY_BATCH], c10[PN_FIV_SKY_BATCH], c01[PN_FIV_SKY_BATCH], c11[PN_FIV_SKY_BATCH];
            float8 cfx[PN_FIV_SKY_BATCH], cfy[PN_FIV_SKY_BATCH];
            for (int b = 0; b < n; ++b)
                pn_fiv_sky_cell8(position, y * width, width, gb + b, rot, latlong_width, latlong_height, &c00[b],
                                 &c10[b], &c01[b], &c11[b], &cfx[b], &cfy[b]);
            for (int b = 0; b < n; ++b) {
                const int x0 = PN_FIV_LANES * (gb + b), row = y * width + x0;
                const bool full = x0 + PN_FIV_LANES <= width;
                const int8 in_row = (int8)(0, 1, 2, 3, 4, 5, 6, 7) < width - x0;
                float8 sky_r, sky_g, sky_b;
                pn_background_texels8(latlong, intensity, in_row, c00[b], c10[b], c01[b], c11[b], cfx[b], cfy[b],
                                      &sky_r, &sky_g, &sky_b);
                pn_store_row8(image, row, full, in_row, sky_r, sky_g, sky_b, (float8)(0.0f));
            }
        }
        return;
    }
#endif
    const pn_fiv_args args = {position, normal, albedo, instance_id, irradiance, occluders, fields, tile_masks, image,
                              latlong, env_x, env_y, env_z, rot, cull_floor, intensity, m, occluder_count, overlap,
                              partial, self_shadow, trilinear, width, binned, background, latlong_width,
                              latlong_height, clamp(max_overlap, 2, PN_FIV_MAX_OVERLAP)};
    const bool pairs = pn_fiv_pairs(&args);
    pn_fiv_normal_cache cache;
    cache.valid = false;
    for (int g = g0; g < g1;) {
        pn_fiv_px8 p, q;
#ifndef PN_FIV_NO_PAIRS
        if ((!pairs || PN_FIV_PAIR_DISCS) && g % 2 == 0 && g + 1 < g1) { /* two groups of one tile side by side */
            const bool on = pn_fiv_begin8(&args, y, PN_FIV_LANES * g, &cache, &p);
            const bool uon = pn_fiv_begin8(&args, y, PN_FIV_LANES * (g + 1), &cache, &q);
            if (on && uon)
                pn_fiv_run_pair8(&args, &p, &q);
            else if (on)
                pn_fiv_run8(&args, &p);
            else if (uon)
                pn_fiv_run8(&args, &q);
            g += 2;
            continue;
        }
#endif
        if (pn_fiv_begin8(&args, y, PN_FIV_LANES * g, &cache, &p))
            pn_fiv_run8(&args, &p);
        ++g;
    }
}
