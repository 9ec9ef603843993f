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
 * correction, or multiplied visibilities (`overlap`).
 *
 * Screen-space binning (`bin_fiv_tiles`, before `shade_fiv`): per 16x16
 * tile, a bit mask of the occluders whose culling sphere reaches the tile's
 * receivers; the shading loop visits only those, in the same order.
 *
 * PN_FIV_PROFILE (a build option, bench/fiv_profile.py) stops the work early
 * to time the phases apart: 1 = no lookup (a constant field), 2 = the
 * lookup's indices and weights but no sample fetched. 0 (default) = all.
 *
 * Occluder record, 4 float4 (capi/src/fiv.c):
 *   [0] centre xyz (world), bounding radius R (world)
 *   [1] object units per world unit, rho_min, ln(rho_max / rho_min), culling distance (world)
 *   [2] uint bits: byte offset of the samples in `fields`, n_theta, n_phi, n_rho
 *   [3] uint bits: instance id, precision (1 = half); value scale, rho_max
 * `fields`: per field its samples, then (16-byte aligned) its per-direction
 * culling bounds, (n_theta - 1) x n_phi floats per cell and (16-byte
 * aligned) 16 x 32 per direction bin (pn_fiv_lookup). */
#include "common/fiv_grid.cl"
#include "common/sphere_maps.cl"

#ifndef PN_FIV_PROFILE
#define PN_FIV_PROFILE 0
#endif

#define PN_FIV_RECORD 4
#define PN_FIV_TILE 16
#define PN_FIV_MAX_OVERLAP 32

#define PN_OVERLAP_SUM 0
#define PN_OVERLAP_DISC 1
#define PN_OVERLAP_MULTIPLY 2

/* The lookup's helpers are forced inline: PoCL left pn_fiv_lookup and
 * pn_fiv_shell as calls, passing the accumulators through the stack. */
#define PN_FIV_INLINE inline __attribute__((always_inline))

typedef struct {
    float3 x, y, z;
} pn_fiv3;

PN_FIV_INLINE bool pn_fiv_sample(global const uchar *fields, uint offset, int half_precision, int index, pn_fiv3 *s)
{
    /* One 8-wide load and one scalar: X rgb, Y rgb, Z rg | Z b. */
    float8 a;
    float b;
    if (half_precision) {
        global const half *h = (global const half *)(fields + offset) + PN_FIV_FLOATS * index;
        a = vload_half8(0, h);
        b = vload_half(8, h);
    } else {
        global const float *f = (global const float *)(fields + offset) + PN_FIV_FLOATS * index;
        a = vload8(0, f);
        b = f[8];
    }
    s->x = a.s012;
    s->y = a.s345;
    s->z = (float3)(a.s67, b);
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

/* Adds weight w times sample (k, i, j) to acc when the sample is valid. */
PN_FIV_INLINE void pn_fiv_add(global const uchar *fields, uint offset, int hp, int n_theta, int n_phi, int k, int i,
                              int j, float w, pn_fiv3 *acc, float *wsum)
{
    pn_fiv3 s;
    if (w <= 0.0f || !pn_fiv_sample(fields, offset, hp, (k * n_theta + i) * n_phi + j, &s))
        return;
    acc->x += w * s.x;
    acc->y += w * s.y;
    acc->z += w * s.z;
    *wsum += w;
}

/* Bilinear (theta, phi) interpolation on sphere k with total weight wk. */
PN_FIV_INLINE void pn_fiv_shell(global const uchar *fields, uint offset, int hp, int n_theta, int n_phi, int k,
                                float wk, int i0, float ti, int j0, int j1, float tj, pn_fiv3 *acc, float *wsum)
{
    pn_fiv_add(fields, offset, hp, n_theta, n_phi, k, i0, j0, wk * (1.0f - ti) * (1.0f - tj), acc, wsum);
    pn_fiv_add(fields, offset, hp, n_theta, n_phi, k, i0, j1, wk * (1.0f - ti) * tj, acc, wsum);
    pn_fiv_add(fields, offset, hp, n_theta, n_phi, k, i0 + 1, j0, wk * ti * (1.0f - tj), acc, wsum);
    pn_fiv_add(fields, offset, hp, n_theta, n_phi, k, i0 + 1, j1, wk * ti * tj, acc, wsum);
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
    int hp = as_int(occ[3].y);
    float3 v = v_world * inv_scale;
    float rho = length(v);
    if (!isfinite(rho)) /* a NaN/Inf position in an unvalidated G-buffer: no index from it */
        return false;
    /* Beyond the grid: per-direction bounds after the samples (cell_bounds,
     * bin_bounds in capi/src/methods/fiv.c). First the coarse direction bin,
     * before any angle: it bounds every cell the direction can fall in, so
     * it culls only what the cell test below would (rho_max widened by 1e-4
     * so that the cell test, too, sees the pair beyond the grid). */
    size_t samples = (size_t)n_rho * n_theta * n_phi * PN_FIV_FLOATS * (hp ? 2 : 4);
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
    pn_fiv_shell(fields, offset, hp, n_theta, n_phi, k0, 1.0f - tk, i0, ti, j0, j1, tj, &acc, &wsum);
    pn_fiv_shell(fields, offset, hp, n_theta, n_phi, k0 + 1, tk, i0, ti, j0, j1, tj, &acc, &wsum);
    for (int k = k0 + 1; wsum <= 0.0f && k < n_rho; ++k)
        pn_fiv_shell(fields, offset, hp, n_theta, n_phi, k, 1.0f, i0, ti, j0, j1, tj, &acc, &wsum);
    if (wsum <= 0.0f)
        return false;
    float f = occ[3].z * falloff / wsum;
    out->x = acc.x * f;
    out->y = acc.y * f;
    out->z = acc.z * f;
    return true;
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

kernel void shade_fiv(global const float4 *position, global const float4 *normal, global const float4 *albedo,
                      global const uint *instance_id, int count, global const float4 *irradiance, int m,
                      global const float4 *occluders,
                      int occluder_count, global const uchar *fields, float cull_floor, float4 env_x, float4 env_y,
                      float4 env_z,
                      int overlap, int partial, int self_shadow, int trilinear, int width, int binned,
                      global const uint *tile_masks, global float4 *image)
{
    int gid = get_global_id(0);
    if (gid >= count)
        return;
    uint id = instance_id[gid];
    if (id == PN_BACKGROUND) { /* black; the renderer draws the env map there (envmap_background) */
        image[gid] = (float4)(0.0f);
        return;
    }
    float3 p = position[gid].xyz;
    float3 n = normalize(normal[gid].xyz);
    float3 e_tot = pn_cube_grid_lookup(irradiance, m, n);
    float3 e_base = e_tot;
    float3 sum = (float3)(0.0f), largest = (float3)(0.0f), visible = (float3)(1.0f);
    float3 occluded[PN_FIV_MAX_OVERLAP];
    float4 disc[PN_FIV_MAX_OVERLAP]; /* unit-sphere direction, radius */
    int discs = 0;
    /* Self-shadowing: the pixel's own occluder, found by its id among all of
     * them (a tile's mask may leave it out when a G-buffer puts the pixel
     * beyond its culling distance). All unoccluded light is in the positive
     * hemisphere. */
    for (int o = 0; self_shadow && o < occluder_count; ++o) {
        global const float4 *occ = occluders + PN_FIV_RECORD * o;
        pn_fiv3 f;
        if (as_uint(occ[3].x) != id)
            continue;
        if (pn_fiv_lookup(occ, fields, occ[0].xyz - p, trilinear, 0.0f, &f)) {
            /* A sample off the surface also sees unoccluded light behind
             * the receiver plane, which the fullsphere sum subtracts: the
             * estimate errs low, never above the unoccluded irradiance. */
            pn_fiv3 env = {env_x.xyz, env_y.xyz, env_z.xyz};
            e_base = clamp(pn_fiv_dot(n, env) - pn_fiv_dot(n, f), 0.0f, e_tot);
        }
        break; /* one field per instance */
    }
    int words = (occluder_count + 31) / 32;
    global const uint *mask = tile_masks;
    if (binned) { /* one integer division (a slow scalar instruction), none unbinned */
        int y = gid / width, x = gid - y * width;
        int tile = (y / PN_FIV_TILE) * ((width + PN_FIV_TILE - 1) / PN_FIV_TILE) + x / PN_FIV_TILE;
        mask += (size_t)tile * words;
    }
    for (int w = 0; w < words; ++w) {
        /* The occluders of this pixel's tile (all of them unbinned), in order. */
        int left = occluder_count - 32 * w;
        uint bits = binned ? mask[w] : left >= 32 ? 0xFFFFFFFFu : (1u << left) - 1u;
        while (bits) {
            int o = 32 * w + (31 - clz(bits & (0u - bits)));
            bits &= bits - 1u;
            global const float4 *occ = occluders + PN_FIV_RECORD * o;
            float4 sphere = occ[0];
            float3 v = sphere.xyz - p;
            if (as_uint(occ[3].x) == id) /* its own occluder: above */
                continue;
            float r = sphere.w, dist_plane = dot(v, n);
            if (dist_plane <= -r) /* case C: fully behind the receiver plane */
                continue;
            float rho = length(v);
            if (rho > occ[1].w) /* beyond the culling distance */
                continue;
            pn_fiv3 f;
#if PN_FIV_PROFILE == 1
            f.x = f.y = f.z = (float3)(occ[3].z * 1e-3f);
#else
            if (!pn_fiv_lookup(occ, fields, v, trilinear, cull_floor, &f))
                continue;
#endif
            /* An occluder only removes light. */
            float3 i_occ = fmax(pn_fiv_dot(n, f), 0.0f);
            if (partial && dist_plane < r) /* case B: the share above the plane */
                i_occ *= (dist_plane + r) / (2.0f * r);
            sum += i_occ;
            largest = fmax(largest, i_occ);
            if (overlap == PN_OVERLAP_MULTIPLY)
                visible *= clamp(1.0f - i_occ / fmax(e_tot, 1e-30f), 0.0f, 1.0f);
            else if (overlap == PN_OVERLAP_DISC && discs < PN_FIV_MAX_OVERLAP) {
                occluded[discs] = i_occ;
                disc[discs] = (float4)(rho > 0.0f ? v / rho : n, fmin(r / fmax(rho, 1e-30f), 1.0f));
                ++discs;
            }
        }
    }
    float3 e;
    if (overlap == PN_OVERLAP_MULTIPLY) {
        e = e_base * visible;
    } else {
        float3 total = sum;
        if (overlap == PN_OVERLAP_DISC) {
            /* Pairwise: the lens of two unit bounding discs, as a share of their
             * areas, of the two occluders' irradiance is counted once. */
            for (int a = 0; a < discs; ++a)
                for (int b = a + 1; b < discs; ++b) {
                    float ra = disc[a].w, rb = disc[b].w;
                    float3 d = disc[a].xyz - disc[b].xyz;
                    float d2 = dot(d, d);
                    /* Most pairs are apart: no lens, and no sqrt or acos spent on it. */
                    if (d2 >= (ra + rb) * (ra + rb))
                        continue;
                    float lens = pn_lens_area(ra, rb, sqrt(d2));
                    if (lens > 0.0f)
                        total -= lens / (PN_PI * (ra * ra + rb * rb)) * (occluded[a] + occluded[b]);
                }
            total = clamp(total, largest, sum);
        }
        e = e_base - total;
    }
    image[gid] = (float4)(fmax(albedo[gid].xyz * e * PN_INV_PI, 0.0f), 1.0f);
}
