/* `heightfield` method: environment and spherical-light lighting with soft
 * self-shadows on dynamic height fields (Snyder and Nowrouzezahrai's pyramid
 * horizon search and SH visibility wedges; local lights after the seed's
 * chapter 4.3). Every formula is specified in docs/heightfield.md.
 *
 * Per frame: hf_decimate builds the pyramid level by level (tent filter),
 * hf_normals the vertex normals; hf_env and hf_light compute per-vertex
 * outgoing radiance (horizons -> SH visibility -> SH product with the
 * clamped cosine -> dot with the lighting); hf_shade maps G-buffer pixels on
 * the height field to those per-vertex results.
 *
 * Per-field constants: grid = (W, D, levels, level offset in samples),
 * geom = (x0, y0, z0, sx, sz, level step, s0, max |H|). Pyramid levels are
 * concatenated in `pyr`; level k is levels[k] = (offset, cells x, cells z, 0),
 * level 0 being the world heights H (height_scale x input). */
#include "common/sh.cl"
#include "common/sphere_maps.cl"

#define HF_MAX_LEVELS 128
#define HF_MAX_AZIMUTHS 256
#define HF_TABLE 64
/* Early exits of the pyramid searches (env: hf_search_done; lights:
 * hf_horizon_pyramid_v), tested after every sample m with
 * (m & HF_EXIT_EVERY) == 0. */
#ifndef HF_EARLY_EXIT /* a build option only to measure without them (0) */
#define HF_EARLY_EXIT 1
#endif
#ifndef HF_EXIT_EVERY
#define HF_EXIT_EVERY 3
#endif
#ifndef HF_LIGHT_ROWS /* a build option only to measure the per-vertex light search (0) */
#define HF_LIGHT_ROWS 1
#endif
/* Profiling stubs (build options only to measure a part's share; 0 = stubbed). */
#ifndef HF_PROF_SHADE
#define HF_PROF_SHADE 1
#endif
#ifndef HF_PROF_VIS
#define HF_PROF_VIS 1
#endif
#ifndef HF_PROF_PRODUCT
#define HF_PROF_PRODUCT 1
#endif
#ifndef HF_PROF_SUN
#define HF_PROF_SUN 1
#endif
/* The row sampler's clamped taps (hf_level_sample_row2): every lane's taps
 * at one border column, and taps clamped at one border only, without the
 * column-by-column path (the same floats; build options 0 only to measure
 * and test against it). */
#ifndef HF_OUTSIDE_FAST
#define HF_OUTSIDE_FAST 1
#endif
#ifndef HF_STRADDLE_FAST
#define HF_STRADDLE_FAST 1
#endif
#ifndef HF_BORDER_TEST /* build options only to test that the tests catch a wrong border path: 1 reads */
#define HF_BORDER_TEST 0 /* the outside column one value in, 2 lets a spread of 16 columns take the window */
#endif
#ifndef HF_VIS_PREP /* a build option only to measure the per-wedge scalar index work (0) */
#define HF_VIS_PREP 1
#endif
#ifndef HF_EXIT_BOUND /* added to max |H|: a build option only to test that a wrong bound is caught */
#define HF_EXIT_BOUND 0.0f
#endif

/* Uniform cubic B-spline weights at t in [0, 1), times 6. */
inline float4 hf_bspline6(float t)
{
    const float t2 = t * t, t3 = t2 * t, s = 1.0f - t;
    return (float4)(s * s * s, 3.0f * t3 - 6.0f * t2 + 4.0f, -3.0f * t3 + 3.0f * t2 + 3.0f * t + 1.0f, t3);
}

/* Uniform cubic B-spline weights at t in [0, 1). */
inline float4 hf_bspline(float t)
{
    return hf_bspline6(t) / 6.0f;
}

/* H_k - ref at base coordinates (u, v): the B-spline of level k's values,
 * indices clamped (the terrain continues beyond its border at the border's
 * height). Taking `ref` (the receiver's height) off every value keeps
 * differences exact: a flat field gives exactly 0, at any altitude. */
inline float hf_level_sample(global const float *pyr, int4 lev, float u, float v, float inv_wm1, float inv_dm1,
                             float ref)
{
    const float a = u * (float)lev.y * inv_wm1, b = v * (float)lev.z * inv_dm1;
    const float fa = floor(a), fb = floor(b);
    const float4 wa = hf_bspline(a - fa), wb = hf_bspline(b - fb);
    const int ia = (int)fa - 1, ib = (int)fb - 1, row = lev.y + 1;
    const int a0 = clamp(ia, 0, lev.y), a1 = clamp(ia + 1, 0, lev.y), a2 = clamp(ia + 2, 0, lev.y),
              a3 = clamp(ia + 3, 0, lev.y);
    global const float *base = pyr + lev.x;
    float4 rows;
    global const float *r = base + clamp(ib, 0, lev.z) * row;
    rows.x = wa.x * (r[a0] - ref) + wa.y * (r[a1] - ref) + wa.z * (r[a2] - ref) + wa.w * (r[a3] - ref);
    r = base + clamp(ib + 1, 0, lev.z) * row;
    rows.y = wa.x * (r[a0] - ref) + wa.y * (r[a1] - ref) + wa.z * (r[a2] - ref) + wa.w * (r[a3] - ref);
    r = base + clamp(ib + 2, 0, lev.z) * row;
    rows.z = wa.x * (r[a0] - ref) + wa.y * (r[a1] - ref) + wa.z * (r[a2] - ref) + wa.w * (r[a3] - ref);
    r = base + clamp(ib + 3, 0, lev.z) * row;
    rows.w = wa.x * (r[a0] - ref) + wa.y * (r[a1] - ref) + wa.z * (r[a2] - ref) + wa.w * (r[a3] - ref);
    return dot(wb, rows);
}

kernel void hf_decimate(global float *pyr, int4 src, int4 dst, float wm1, float dm1, int4 rect)
{
    /* rect: the values (a, b) = (rect.x, rect.y) + (0 .. rect.z - 1, 0 .. rect.w - 1) of the level
     * (the whole level, or the box a local edit can change: the same arithmetic either way). */
    const int gid = get_global_id(0), row = dst.y + 1;
    if (gid >= rect.z * rect.w)
        return;
    const int a = rect.x + gid % rect.z, b = rect.y + gid / rect.z;
    /* Distances in base units; the tent's radius is the destination spacing. */
    const float ru = wm1 / (float)dst.y, rv = dm1 / (float)dst.z, hu = wm1 / (float)src.y, hv = dm1 / (float)src.z;
    const float u = (float)a * ru, v = (float)b * rv;
    const int a0 = max((int)floor((u - ru) / hu), 0), a1 = min((int)ceil((u + ru) / hu), src.y);
    const int b0 = max((int)floor((v - rv) / hv), 0), b1 = min((int)ceil((v + rv) / hv), src.z);
    /* Averaged relative to one source value, so a constant field stays exactly constant. */
    const float anchor = pyr[src.x + clamp((int)round(v / hv), 0, src.z) * (src.y + 1) + clamp((int)round(u / hu), 0, src.y)];
    float sum = 0.0f, wsum = 0.0f;
    for (int qb = b0; qb <= b1; ++qb) {
        const float wv = fmax(1.0f - fabs((float)qb * hv - v) / rv, 0.0f);
        if (wv <= 0.0f)
            continue;
        for (int qa = a0; qa <= a1; ++qa) {
            const float w = wv * fmax(1.0f - fabs((float)qa * hu - u) / ru, 0.0f);
            sum += w * (pyr[src.x + qb * (src.y + 1) + qa] - anchor);
            wsum += w;
        }
    }
    pyr[dst.x + b * row + a] = anchor + sum / wsum;
}

/* Interpolating reconstruction: solves, along one row (rows = 1) or column
 * of a level, the tridiagonal system B c = h of the clamped cubic B-spline at
 * its knots ((5, 1) / 6 at the ends, (1, 4, 1) / 6 inside) by the Thomas
 * algorithm, in place, relative to the line's first value (a constant line
 * stays exactly constant). The forward sweep's ratios depend only on the
 * position and reach 2 - sqrt(3) to float precision after 16 steps. */
#define HF_THOMAS 16
kernel void hf_prefilter(global float *pyr, int4 lev, int rows)
{
    const int line = get_global_id(0), n = rows ? lev.y + 1 : lev.z + 1;
    if (line >= (rows ? lev.z + 1 : lev.y + 1) || n < 2)
        return;
    const int stride = rows ? 1 : lev.y + 1;
    global float *x = pyr + lev.x + (rows ? line * (lev.y + 1) : line);
    const float anchor = x[0], sixth = 1.0f / 6.0f;
    float cp[HF_THOMAS];
    float c_prev = 0.0f, d_prev = 0.0f;
    for (int i = 0; i < n; ++i) {
        const float b = (i == 0 || i == n - 1) ? 5.0f * sixth : 4.0f * sixth;
        const float denom = b - sixth * c_prev;
        const float c = sixth / denom;
        const float dv = (x[i * stride] - anchor - sixth * d_prev) / denom;
        x[i * stride] = dv;
        if (i < HF_THOMAS)
            cp[i] = c;
        c_prev = c;
        d_prev = dv;
    }
    const float c_limit = 2.0f - sqrt(3.0f);
    float next = x[(n - 1) * stride];
    x[(n - 1) * stride] = next + anchor;
    for (int i = n - 2; i >= 0; --i) {
        const float v = x[i * stride] - (i < HF_THOMAS ? cp[i] : c_limit) * next;
        x[i * stride] = v + anchor;
        next = v;
    }
}

/* Central differences of H (one-sided on the border): n = normalize(-dH/dx, 1, -dH/dz). */
kernel void hf_normals(global const float *pyr, int4 grid, float8 geom, global float4 *normals)
{
    const int gid = get_global_id(0), w = grid.x, d = grid.y;
    if (gid >= w * d)
        return;
    const int i = gid % w, j = gid / w;
    const int i0 = max(i - 1, 0), i1 = min(i + 1, w - 1), j0 = max(j - 1, 0), j1 = min(j + 1, d - 1);
    const float dx = (pyr[j * w + i1] - pyr[j * w + i0]) / ((float)(i1 - i0) * geom.s3);
    const float dz = (pyr[j1 * w + i] - pyr[j0 * w + i]) / ((float)(j1 - j0) * geom.s4);
    normals[gid] = (float4)(normalize((float3)(-dx, 1.0f, -dz)), 0.0f);
}

/* The pyramid horizon search (docs/heightfield.md): samples at d_m = s0 sr^m
 * (only d_m < limit), level m - offset, B-spline maximum over knots and
 * midpoints with repeated ends; -pi/2 without samples. HF_LANES azimuths at
 * once, one per vector lane: the sample loop is uniform over azimuths (same
 * m, d and level), so the B-spline weights, atan and the window run as
 * vector arithmetic and only the 16 taps per sample are per-lane loads.
 * PoCL does not vectorise a work-item's own loops, so the lanes are written
 * out here: 5x less time per sample than one azimuth at a time. */
#ifndef HF_LANES
#define HF_LANES 8
#endif
#if HF_LANES == 16
typedef float16 hf_vf;
typedef int16 hf_vi;
#define hf_convert_vi convert_int16
#define HF_CONVERT_F convert_float16
#define hf_vload vload16
#define hf_vstore vstore16
#define HF_GATHER(p, i) ((hf_vf)(p[i.s0], p[i.s1], p[i.s2], p[i.s3], p[i.s4], p[i.s5], p[i.s6], p[i.s7], \
                                  p[i.s8], p[i.s9], p[i.sa], p[i.sb], p[i.sc], p[i.sd], p[i.se], p[i.sf]))
#define HF_LANE_IDS ((hf_vi)(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15))
#else
typedef float8 hf_vf;
typedef int8 hf_vi;
#define hf_convert_vi convert_int8
#define HF_CONVERT_F convert_float8
#define hf_vload vload8
#define hf_vstore vstore8
#define HF_GATHER(p, i) HF_GATHER8(p, i)
#define HF_LANE_IDS ((hf_vi)(0, 1, 2, 3, 4, 5, 6, 7))
#endif
#define HF_GATHER8(p, i) ((float8)(p[i.s0], p[i.s1], p[i.s2], p[i.s3], p[i.s4], p[i.s5], p[i.s6], p[i.s7]))

/* pn_atan (common/math.cl), lane by lane. */
#define HF_DEFINE_ATAN(name, T)                                                                                 \
    inline T name(T x)                                                                                          \
    {                                                                                                           \
        const T a = fabs(x), t = select(a, 1.0f / a, a > 1.0f), t2 = t * t;                                     \
        T p;                                                                                                    \
        PN_ATAN_POLY(p, t2);                                                                                    \
        const T r = t * p;                                                                                      \
        return copysign(select(r, M_PI_2_F - r, a > 1.0f), x);                                                  \
    }
HF_DEFINE_ATAN(hf_atan_v, hf_vf)

/* hf_level_sample for HF_LANES points (same formula, lane by lane). */
inline hf_vf hf_level_sample_v(global const float *pyr, int4 lev, hf_vf u, hf_vf v, float inv_wm1, float inv_dm1,
                               float ref)
{
    const hf_vf a = u * (float)lev.y * inv_wm1, b = v * (float)lev.z * inv_dm1;
    const hf_vf fa = floor(a), fb = floor(b), ta = a - fa, tb = b - fb;
    const hf_vf sa = 1.0f - ta, sb = 1.0f - tb, ta2 = ta * ta, tb2 = tb * tb, ta3 = ta2 * ta, tb3 = tb2 * tb;
    const hf_vf wa0 = sa * sa * sa / 6.0f, wa1 = (3.0f * ta3 - 6.0f * ta2 + 4.0f) / 6.0f,
                wa2 = (-3.0f * ta3 + 3.0f * ta2 + 3.0f * ta + 1.0f) / 6.0f, wa3 = ta3 / 6.0f;
    const hf_vf wb0 = sb * sb * sb / 6.0f, wb1 = (3.0f * tb3 - 6.0f * tb2 + 4.0f) / 6.0f,
                wb2 = (-3.0f * tb3 + 3.0f * tb2 + 3.0f * tb + 1.0f) / 6.0f, wb3 = tb3 / 6.0f;
    const hf_vi ia = hf_convert_vi(fa) - 1, ib = hf_convert_vi(fb) - 1, row = lev.y + 1;
    const hf_vi a0 = clamp(ia, 0, lev.y), a1 = clamp(ia + 1, 0, lev.y), a2 = clamp(ia + 2, 0, lev.y),
                a3 = clamp(ia + 3, 0, lev.y);
    global const float *base = pyr + lev.x;
    const hf_vi r0 = clamp(ib, 0, lev.z) * row, r1 = clamp(ib + 1, 0, lev.z) * row,
                r2 = clamp(ib + 2, 0, lev.z) * row, r3 = clamp(ib + 3, 0, lev.z) * row;
    hf_vi i0, i1, i2, i3;
    hf_vf rows0, rows1, rows2, rows3;
#define HF_ROW_AT(rr) (i0 = rr + a0, i1 = rr + a1, i2 = rr + a2, i3 = rr + a3,                          \
                       wa0 * (HF_GATHER(base, i0) - ref) + wa1 * (HF_GATHER(base, i1) - ref) +         \
                       wa2 * (HF_GATHER(base, i2) - ref) + wa3 * (HF_GATHER(base, i3) - ref))
    rows0 = HF_ROW_AT(r0);
    rows1 = HF_ROW_AT(r1);
    rows2 = HF_ROW_AT(r2);
    rows3 = HF_ROW_AT(r3);
#undef HF_ROW_AT
    return wb0 * rows0 + wb1 * rows1 + wb2 * rows2 + wb3 * rows3;
}

/* Elevations along HF_LANES directions (cu, cv) in base units per world
 * unit; `hp` holds H_k - H_0 at the receiver. A window of four elevations
 * slides along the samples: with w0..w3 = ω_{m-2}..ω_{m+1}, the knot at m-1
 * and the midpoint between m-2 and m-1 are complete. Ends repeat
 * (ω_{-1} = ω_0, ω_count = ω_{count-1}). */
/* The sliding window over elevations: one new elevation w3, and the end. */
#define HF_WINDOW_STEP(w0, w1, w2, w3, best, count)                                                             \
    {                                                                                                           \
        if (count == 0)                                                                                         \
            w0 = w1 = w2 = w3;                                                                                  \
        else {                                                                                                  \
            best = fmax(best, (w1 + 4.0f * w2 + w3) / 6.0f);                                                    \
            if (count >= 2)                                                                                     \
                best = fmax(best, (w0 + 23.0f * w1 + 23.0f * w2 + w3) / 48.0f);                                 \
        }                                                                                                       \
        w0 = w1;                                                                                                \
        w1 = w2;                                                                                                \
        w2 = w3;                                                                                                \
        ++count;                                                                                                \
    }
#define HF_WINDOW_END(w0, w1, w2, best, count)                                                                  \
    {                                                                                                           \
        if (count == 0)                                                                                         \
            return -M_PI_2_F;                                                                                   \
        best = fmax(best, (w1 + 5.0f * w2) / 6.0f);                                                             \
        if (count >= 2)                                                                                         \
            best = fmax(best, (w0 + 23.0f * w1 + 24.0f * w2) / 48.0f);                                          \
        return best;                                                                                            \
    }

/* The same maximum with the divisions by 6 and 48 taken once at the end:
 * x -> x / 6 (correctly rounded) is monotone, so the largest quotient is the
 * quotient of the largest numerator, the same float. `knot` and `mid` are
 * the running maxima of the numerators. */
#define HF_WINDOW_STEP_N(w0, w1, w2, w3, knot, mid, count)                                                      \
    {                                                                                                           \
        if (count == 0)                                                                                         \
            w0 = w1 = w2 = w3;                                                                                  \
        else {                                                                                                  \
            knot = fmax(knot, w1 + 4.0f * w2 + w3);                                                             \
            if (count >= 2)                                                                                     \
                mid = fmax(mid, w0 + 23.0f * w1 + 23.0f * w2 + w3);                                             \
        }                                                                                                       \
        w0 = w1;                                                                                                \
        w1 = w2;                                                                                                \
        w2 = w3;                                                                                                \
        ++count;                                                                                                \
    }
#define HF_WINDOW_MAX(best, knot, mid) fmax(best, fmax(knot / 6.0f, mid / 48.0f))
#define HF_WINDOW_END_N(w0, w1, w2, best, knot, mid, count)                                                     \
    {                                                                                                           \
        if (count == 0)                                                                                         \
            return -M_PI_2_F;                                                                                   \
        knot = fmax(knot, w1 + 5.0f * w2);                                                                      \
        if (count >= 2)                                                                                         \
            mid = fmax(mid, w0 + 23.0f * w1 + 24.0f * w2);                                                      \
        return HF_WINDOW_MAX(best, knot, mid);                                                                  \
    }

/* With ur (lights, hf_light_horizon): the search may stop once every lane's
 * horizon is known to be at least `hidden` (the running maximum is there,
 * and the result only grows) or at most `clear` (the maximum and every
 * later candidate, all combinations of the window's elevations and later
 * ones, bounded by ur[m + 1] from sample m + 1 on, lie below it): it then
 * returns the running maximum, on the same side. */
inline hf_vf hf_horizon_pyramid_v(global const float *pyr, global const int4 *levels, int4 grid, float8 geom,
                                  const float *hp, float ref, float u0, float v0, hf_vf cu, hf_vf cv, float limit,
                                  float inv_wm1, float inv_dm1, const float *ur, float hidden, float clear)
{
    hf_vf w0 = 0.0f, w1 = 0.0f, w2 = 0.0f, best = -M_PI_2_F;
    int count = 0;
    const float sr = exp2(1.0f / geom.s5);
    float d = geom.s6;
    for (int m = 0; m < grid.z; ++m, d *= sr) {
        if (!(d < limit))
            break;
        const int k = clamp(m - grid.w, 0, grid.z - 1);
        const hf_vf h = hf_level_sample_v(pyr, levels[k], u0 + d * cu, v0 + d * cv, inv_wm1, inv_dm1, ref);
        const hf_vf w3 = hf_atan_v((h - hp[k]) / d);
        HF_WINDOW_STEP(w0, w1, w2, w3, best, count)
#if HF_EARLY_EXIT
        if (ur && m >= 3 && (m & HF_EXIT_EVERY) == 0 &&
            all((best >= hidden) | ((best <= clear) & (fmax(fmax(w0, w1), fmax(w2, ur[m + 1])) <= clear))))
            return best;
#endif
    }
    HF_WINDOW_END(w0, w1, w2, best, count)
}

/* Row groups: the environment's search also runs HF_ROW = 16 consecutive
 * vertices of a row at once, one per lane of a float16, one azimuth at a
 * time. Their samples then share d, the level and v, and their u differ by
 * at most one base cell per lane, so the 4 x 4 taps of all lanes lie on the
 * same 4 rows, within 19 values of each (15 cells of spread plus 3 taps):
 * the rows are combined over a window first (4 vector FMAs, weights in v
 * shared), then each lane takes its 4 columns from the combined row
 * (hf_level_sample_row). The same B-spline as hf_level_sample (rows first,
 * columns second; `ref` is the group's first vertex, so a flat field still
 * gives exactly 0), but times 36: the weights' two divisions by 6 are folded
 * into the one reciprocal per sample that divides by d (no vector division
 * but the atan's). Per sample the scalar work (d, level, row pointers,
 * weights in v, branches) is shared by 16 vertices (8 before: 1.6-1.8x
 * less time for the search, docs/performance.md). */
#define HF_ROW 16
typedef float16 hf_rf;
typedef int16 hf_ri;
#define hf_convert_rf convert_float16
#define hf_vstore_r vstore16
#define hf_vload_r vload16
#define HF_ROW_IDS ((hf_ri)(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15))
#define HF_RLAST(x) ((x).sf)
#define HF_RGATHER(p, i) ((float16)(p[i.s0], p[i.s1], p[i.s2], p[i.s3], p[i.s4], p[i.s5], p[i.s6], p[i.s7], \
                                    p[i.s8], p[i.s9], p[i.sa], p[i.sb], p[i.sc], p[i.sd], p[i.se], p[i.sf]))
HF_DEFINE_ATAN(hf_atan_r, hf_rf)
#define HF_INLINE inline __attribute__((always_inline))
/* Lane l's 4 columns w[s_l .. s_l + 3] of a window w of 20 values (l, lh),
 * s_l in [0, S], S <= 15: a select tree on the bits of s over broadcasts
 * of the window's values, as deep as S needs (the coarse levels: S <= 1,
 * one stage) -- no private memory, no per-lane loads. */
HF_INLINE void hf_pick_columns(float16 l, float4 lh, int16 s, int S, float16 *c0, float16 *c1, float16 *c2,
                               float16 *c3)
{
    const int16 m0 = (s & 1) != 0, m1 = (s & 2) != 0, m2 = (s & 4) != 0, m3 = (s & 8) != 0;
    if (S <= 0) {
        *c0 = l.s0;
        *c1 = l.s1;
        *c2 = l.s2;
        *c3 = l.s3;
    } else if (S <= 1) {
        const float16 p0 = l.s0, p1 = l.s1, p2 = l.s2, p3 = l.s3, p4 = l.s4;
        *c0 = select(p0, p1, m0);
        *c1 = select(p1, p2, m0);
        *c2 = select(p2, p3, m0);
        *c3 = select(p3, p4, m0);
    } else if (S <= 3) {
        const float16 p0 = l.s0, p1 = l.s1, p2 = l.s2, p3 = l.s3, p4 = l.s4, p5 = l.s5, p6 = l.s6;
        const float16 e0 = select(p0, p1, m0), e1 = select(p1, p2, m0), e2 = select(p2, p3, m0),
                      e3 = select(p3, p4, m0), e4 = select(p4, p5, m0), e5 = select(p5, p6, m0);
        *c0 = select(e0, e2, m1);
        *c1 = select(e1, e3, m1);
        *c2 = select(e2, e4, m1);
        *c3 = select(e3, e5, m1);
    } else if (S <= 7) {
        const float16 p0 = l.s0, p1 = l.s1, p2 = l.s2, p3 = l.s3, p4 = l.s4, p5 = l.s5, p6 = l.s6, p7 = l.s7,
                      p8 = l.s8, p9 = l.s9, p10 = l.sa;
        const float16 e0 = select(p0, p1, m0), e1 = select(p1, p2, m0), e2 = select(p2, p3, m0),
                      e3 = select(p3, p4, m0), e4 = select(p4, p5, m0), e5 = select(p5, p6, m0),
                      e6 = select(p6, p7, m0), e7 = select(p7, p8, m0), e8 = select(p8, p9, m0),
                      e9 = select(p9, p10, m0);
        const float16 f0 = select(e0, e2, m1), f1 = select(e1, e3, m1), f2 = select(e2, e4, m1),
                      f3 = select(e3, e5, m1), f4 = select(e4, e6, m1), f5 = select(e5, e7, m1),
                      f6 = select(e6, e8, m1), f7 = select(e7, e9, m1);
        *c0 = select(f0, f4, m2);
        *c1 = select(f1, f5, m2);
        *c2 = select(f2, f6, m2);
        *c3 = select(f3, f7, m2);
    } else {
        const float16 p0 = l.s0, p1 = l.s1, p2 = l.s2, p3 = l.s3, p4 = l.s4, p5 = l.s5, p6 = l.s6, p7 = l.s7,
                      p8 = l.s8, p9 = l.s9, p10 = l.sa, p11 = l.sb, p12 = l.sc, p13 = l.sd, p14 = l.se, p15 = l.sf,
                      p16 = lh.x, p17 = lh.y, p18 = lh.z;
        const float16 e0 = select(p0, p1, m0), e1 = select(p1, p2, m0), e2 = select(p2, p3, m0),
                      e3 = select(p3, p4, m0), e4 = select(p4, p5, m0), e5 = select(p5, p6, m0),
                      e6 = select(p6, p7, m0), e7 = select(p7, p8, m0), e8 = select(p8, p9, m0),
                      e9 = select(p9, p10, m0), e10 = select(p10, p11, m0), e11 = select(p11, p12, m0),
                      e12 = select(p12, p13, m0), e13 = select(p13, p14, m0), e14 = select(p14, p15, m0),
                      e15 = select(p15, p16, m0), e16 = select(p16, p17, m0), e17 = select(p17, p18, m0);
        const float16 f0 = select(e0, e2, m1), f1 = select(e1, e3, m1), f2 = select(e2, e4, m1),
                      f3 = select(e3, e5, m1), f4 = select(e4, e6, m1), f5 = select(e5, e7, m1),
                      f6 = select(e6, e8, m1), f7 = select(e7, e9, m1), f8 = select(e8, e10, m1),
                      f9 = select(e9, e11, m1), f10 = select(e10, e12, m1), f11 = select(e11, e13, m1),
                      f12 = select(e12, e14, m1), f13 = select(e13, e15, m1), f14 = select(e14, e16, m1),
                      f15 = select(e15, e17, m1);
        const float16 g0 = select(f0, f4, m2), g1 = select(f1, f5, m2), g2 = select(f2, f6, m2),
                      g3 = select(f3, f7, m2), g4 = select(f4, f8, m2), g5 = select(f5, f9, m2),
                      g6 = select(f6, f10, m2), g7 = select(f7, f11, m2), g8 = select(f8, f12, m2),
                      g9 = select(f9, f13, m2), g10 = select(f10, f14, m2), g11 = select(f11, f15, m2);
        *c0 = select(g0, g8, m3);
        *c1 = select(g1, g9, m3);
        *c2 = select(g2, g10, m3);
        *c3 = select(g3, g11, m3);
    }
}

/* 16 lanes: their taps lie within 19 values of each of the 4 rows (15
 * cells of spread plus 3 taps). On base-wide levels away from the border
 * the rows are combined over 20 values (a float16 and a float4 per row) and
 * the lanes' columns are constant swizzles. Elsewhere, with no tap clamped,
 * the rows are combined over the narrowest window of 8, 16 or 20 values
 * that holds every lane's taps (moved left at the level's right end) and
 * the columns picked by hf_pick_columns; where a tap is clamped (the
 * border, samples outside the field) the lanes' columns are combined one by
 * one and picked from private memory.
 *
 * Two rows at once (vA, vB: a row group's two rows, or the same row twice
 * for a field's last odd row): everything that depends on u -- the column
 * weights, the lanes' column offsets and the select masks, the window and
 * the path taken -- is computed once for both; only the weights in v, the
 * row pointers and the row combination are per row. Each row's result is
 * the same float as hf_level_sample_row's for that row alone (the same
 * expressions). */
#define HF_COMBINE16(r0, r1, r2, r3, wb, ref, off)                                                              \
    (wb.x * (vload16(0, r0 + (off)) - ref) + wb.y * (vload16(0, r1 + (off)) - ref) +                            \
     wb.z * (vload16(0, r2 + (off)) - ref) + wb.w * (vload16(0, r3 + (off)) - ref))
#define HF_COMBINE8(r0, r1, r2, r3, wb, ref, off)                                                               \
    (wb.x * (vload8(0, r0 + (off)) - ref) + wb.y * (vload8(0, r1 + (off)) - ref) +                              \
     wb.z * (vload8(0, r2 + (off)) - ref) + wb.w * (vload8(0, r3 + (off)) - ref))
#define HF_COMBINE4(r0, r1, r2, r3, wb, ref, off)                                                               \
    (wb.x * (vload4(0, r0 + (off)) - ref) + wb.y * (vload4(0, r1 + (off)) - ref) +                              \
     wb.z * (vload4(0, r2 + (off)) - ref) + wb.w * (vload4(0, r3 + (off)) - ref))

/* Base-wide levels: lanes one column apart, sharing the weights wa. */
HF_INLINE float16 hf_columns_shift(float16 l, float4 lh, float4 wa)
{
    const float16 l1 = (float16)(l.s1234, l.s5678, l.s9abc, l.sdef, lh.x),
                  l2 = (float16)(l.s2345, l.s6789, l.sabcd, l.sef, lh.xy),
                  l3 = (float16)(l.s3456, l.s789a, l.sbcde, l.sf, lh.xyz);
    return wa.x * l + wa.y * l1 + wa.z * l2 + wa.w * l3;
}

/* Clamped taps: the lanes' columns p_lo .. p_hi (clamped) of one row combined one by one (at most 19). */
HF_INLINE float16 hf_columns_clamped(global const float *r0, global const float *r1, global const float *r2,
                                     global const float *r3, float4 wb, float ref, int p_lo, int p_hi, int16 o0,
                                     int16 o1, int16 o2, int16 o3, float16 wa0, float16 wa1, float16 wa2,
                                     float16 wa3)
{
    float line[20];
    for (int p = p_lo; p <= p_hi; ++p)
        line[p - p_lo] = wb.x * (r0[p] - ref) + wb.y * (r1[p] - ref) + wb.z * (r2[p] - ref) + wb.w * (r3[p] - ref);
    return wa0 * HF_RGATHER(line, o0) + wa1 * HF_RGATHER(line, o1) + wa2 * HF_RGATHER(line, o2) +
           wa3 * HF_RGATHER(line, o3);
}

/* A window of 20 values (l, lh) shifted by a uniform amount, n in [0, 31]:
 * right (toward higher indices) with l.s0 repeated in front, or left with
 * lh.w repeated behind; one constant swizzle per set bit of n. */
HF_INLINE void hf_window_shift_right(float16 *l, float4 *lh, int n)
{
    const float f = (*l).s0;
    const float2 f2 = f;
    const float4 f4 = f;
    if (n & 1) {
        *lh = (float4)((*l).sf, (*lh).xyz);
        *l = (float16)(f, (*l).s0123, (*l).s4567, (*l).s89ab, (*l).scde);
    }
    if (n & 2) {
        *lh = (float4)((*l).sef, (*lh).xy);
        *l = (float16)(f2, (*l).s0123, (*l).s4567, (*l).s89ab, (*l).scd);
    }
    if (n & 4) {
        *lh = (*l).scdef;
        *l = (float16)(f4, (*l).s0123, (*l).s4567, (*l).s89ab);
    }
    if (n & 8) {
        *lh = (*l).s89ab;
        *l = (float16)(f4, f4, (*l).s0123, (*l).s4567);
    }
    if (n & 16) {
        *lh = (*l).s0123;
        *l = (float16)(f4, f4, f4, f4);
    }
}

HF_INLINE void hf_window_shift_left(float16 *l, float4 *lh, int n)
{
    const float g = (*lh).w;
    const float2 g2 = g;
    const float4 g4 = g;
    if (n & 1) {
        *l = (float16)((*l).s1234, (*l).s5678, (*l).s9abc, (*l).sdef, (*lh).x);
        *lh = (float4)((*lh).yzw, g);
    }
    if (n & 2) {
        *l = (float16)((*l).s2345, (*l).s6789, (*l).sabcd, (*l).sef, (*lh).xy);
        *lh = (float4)((*lh).zw, g2);
    }
    if (n & 4) {
        *l = (float16)((*l).s4567, (*l).s89ab, (*l).scdef, *lh);
        *lh = g4;
    }
    if (n & 8) {
        *l = (float16)((*l).s89ab, (*l).scdef, *lh, g4);
        *lh = g4;
    }
    if (n & 16) {
        *l = (float16)(*lh, g4, g4, g4);
        *lh = g4;
    }
}

HF_INLINE void hf_level_sample_row2(global const float *pyr, int4 lev, int wm1, float16 u, float vA, float vB,
                                    float inv_wm1, float inv_dm1, float refA, float refB, float16 *hA, float16 *hB)
{
    const bool whole = lev.y == wm1;
    const float a_first = u.s0 * (float)lev.y * inv_wm1, fa_first = floor(a_first);
    const float bA = vA * (float)lev.z * inv_dm1, fbA = floor(bA), bB = vB * (float)lev.z * inv_dm1, fbB = floor(bB);
    const float4 wbA = hf_bspline6(bA - fbA), wbB = hf_bspline6(bB - fbB);
    const int ibA = (int)fbA - 1, ibB = (int)fbB - 1, row = lev.y + 1, c0 = (int)fa_first - 1; /* lane 0's first column */
    global const float *base = pyr + lev.x;
    global const float *a0 = base + clamp(ibA, 0, lev.z) * row, *a1 = base + clamp(ibA + 1, 0, lev.z) * row,
                       *a2 = base + clamp(ibA + 2, 0, lev.z) * row, *a3 = base + clamp(ibA + 3, 0, lev.z) * row;
    global const float *b0 = base + clamp(ibB, 0, lev.z) * row, *b1 = base + clamp(ibB + 1, 0, lev.z) * row,
                       *b2 = base + clamp(ibB + 2, 0, lev.z) * row, *b3 = base + clamp(ibB + 3, 0, lev.z) * row;
    if (whole && c0 >= 0 && c0 + 19 <= lev.y) {
        /* values c0 .. c0 + 18 (and c0 + 19, not used); lanes one column
         * apart (lanes past the row's end are not stored) */
        const float4 wa = hf_bspline6(a_first - fa_first);
        *hA = hf_columns_shift(HF_COMBINE16(a0, a1, a2, a3, wbA, refA, c0), HF_COMBINE4(a0, a1, a2, a3, wbA, refA, c0 + 16),
                               wa);
        *hB = hf_columns_shift(HF_COMBINE16(b0, b1, b2, b3, wbB, refB, c0), HF_COMBINE4(b0, b1, b2, b3, wbB, refB, c0 + 16),
                               wa);
        return;
    }
    const float16 a = u * (float)lev.y * inv_wm1, fa = floor(a), ta = a - fa, sa = 1.0f - ta, ta2 = ta * ta,
                  ta3 = ta2 * ta;
    const int16 ia = convert_int16(fa) - 1;
    const float16 wa0 = sa * sa * sa, wa1 = 3.0f * ta3 - 6.0f * ta2 + 4.0f,
                  wa2 = -3.0f * ta3 + 3.0f * ta2 + 3.0f * ta + 1.0f, wa3 = ta3;
    /* u, so ia, grows with the lane: lane 0 and lane 15 bound the taps */
    const int lo = ia.s0, hi = ia.sf + 3;
    if (lo >= 0 && hi <= lev.y) {
        int cs = -1;
        float16 lA, lB;
        float4 lhA = 0.0f, lhB = 0.0f;
        if (lev.y >= 7 && hi - min(lo, lev.y - 7) <= 7) {
            cs = min(lo, lev.y - 7);
            const float8 l8A = HF_COMBINE8(a0, a1, a2, a3, wbA, refA, cs),
                         l8B = HF_COMBINE8(b0, b1, b2, b3, wbB, refB, cs);
            lA = (float16)(l8A, l8A.s7777, l8A.s7777); /* past the window: never picked */
            lB = (float16)(l8B, l8B.s7777, l8B.s7777);
        } else if (lev.y >= 15 && hi - min(lo, lev.y - 15) <= 15) {
            cs = min(lo, lev.y - 15);
            lA = HF_COMBINE16(a0, a1, a2, a3, wbA, refA, cs);
            lB = HF_COMBINE16(b0, b1, b2, b3, wbB, refB, cs);
        } else if (lev.y >= 19 && hi - min(lo, lev.y - 19) <= 18) {
            cs = min(lo, lev.y - 19);
            lA = HF_COMBINE16(a0, a1, a2, a3, wbA, refA, cs);
            lB = HF_COMBINE16(b0, b1, b2, b3, wbB, refB, cs);
            lhA = HF_COMBINE4(a0, a1, a2, a3, wbA, refA, cs + 16);
            lhB = HF_COMBINE4(b0, b1, b2, b3, wbB, refB, cs + 16);
        }
        if (cs >= 0) {
            float16 c0, c1, c2, c3;
            hf_pick_columns(lA, lhA, ia - cs, hi - 3 - cs, &c0, &c1, &c2, &c3);
            *hA = wa0 * c0 + wa1 * c1 + wa2 * c2 + wa3 * c3;
            hf_pick_columns(lB, lhB, ia - cs, hi - 3 - cs, &c0, &c1, &c2, &c3);
            *hB = wa0 * c0 + wa1 * c1 + wa2 * c2 + wa3 * c3;
            return;
        }
    }
#if HF_OUTSIDE_FAST
    if (lo >= lev.y || hi <= 0) {
        /* every lane's taps clamped to one border column p: the values the
         * column-by-column path gathers are all that column's combination */
        const int p = lo >= lev.y ? lev.y - (HF_BORDER_TEST == 1) : (HF_BORDER_TEST == 1);
        const float16 xA = wbA.x * (a0[p] - refA) + wbA.y * (a1[p] - refA) + wbA.z * (a2[p] - refA) +
                           wbA.w * (a3[p] - refA),
                      xB = wbB.x * (b0[p] - refB) + wbB.y * (b1[p] - refB) + wbB.z * (b2[p] - refB) +
                           wbB.w * (b3[p] - refB);
        *hA = wa0 * xA + wa1 * xA + wa2 * xA + wa3 * xA;
        *hB = wa0 * xB + wa1 * xB + wa2 * xB + wa3 * xB;
        return;
    }
#endif
#if HF_STRADDLE_FAST
    if (lev.y >= 19 && hi - lo <= 18 + (HF_BORDER_TEST == 2) && (lo >= 0 || hi <= lev.y)) {
        /* taps clamped at one border only: the window w[c] = (the combined
         * row at column clamp(lo + c, 0, C)), c = 0 .. 19, is the 20 values
         * at that border shifted by a uniform amount with the border value
         * repeated; lane l's taps are then w[s_l .. s_l + 3], s_l = ia_l - lo
         * in [0, 15], picked as on the unclamped path. The same values as
         * the column-by-column path gathers, so the same floats. (Lane 0
         * rounding down and lane 15 not can make the spread 16 columns:
         * those keep the column-by-column path.) */
        const int cs = lo < 0 ? 0 : lev.y - 19;
        float16 lA = HF_COMBINE16(a0, a1, a2, a3, wbA, refA, cs), lB = HF_COMBINE16(b0, b1, b2, b3, wbB, refB, cs);
        float4 lhA = HF_COMBINE4(a0, a1, a2, a3, wbA, refA, cs + 16),
               lhB = HF_COMBINE4(b0, b1, b2, b3, wbB, refB, cs + 16);
        if (lo < 0) {
            hf_window_shift_right(&lA, &lhA, -lo);
            hf_window_shift_right(&lB, &lhB, -lo);
        } else {
            hf_window_shift_left(&lA, &lhA, lo - cs);
            hf_window_shift_left(&lB, &lhB, lo - cs);
        }
        float16 c0, c1, c2, c3;
        hf_pick_columns(lA, lhA, ia - lo, hi - 3 - lo, &c0, &c1, &c2, &c3);
        *hA = wa0 * c0 + wa1 * c1 + wa2 * c2 + wa3 * c3;
        hf_pick_columns(lB, lhB, ia - lo, hi - 3 - lo, &c0, &c1, &c2, &c3);
        *hB = wa0 * c0 + wa1 * c1 + wa2 * c2 + wa3 * c3;
        return;
    }
#endif
    const int p_lo = clamp(lo, 0, lev.y), p_hi = clamp(hi, 0, lev.y);
    const int16 o0 = clamp(ia, 0, lev.y) - p_lo, o1 = clamp(ia + 1, 0, lev.y) - p_lo,
                o2 = clamp(ia + 2, 0, lev.y) - p_lo, o3 = clamp(ia + 3, 0, lev.y) - p_lo;
    *hA = hf_columns_clamped(a0, a1, a2, a3, wbA, refA, p_lo, p_hi, o0, o1, o2, o3, wa0, wa1, wa2, wa3);
    *hB = hf_columns_clamped(b0, b1, b2, b3, wbB, refB, p_lo, p_hi, o0, o1, o2, o3, wa0, wa1, wa2, wa3);
}

/* One row (the receivers' own levels). */
HF_INLINE float16 hf_level_sample_row(global const float *pyr, int4 lev, int wm1, float16 u, float v, float inv_wm1,
                                      float inv_dm1, float ref)
{
    float16 h, unused;
    hf_level_sample_row2(pyr, lev, wm1, u, v, v, inv_wm1, inv_dm1, ref, ref, &h, &unused);
    return h;
}

#define HF_WINDOW_FINISH_N(w0, w1, w2, best, knot, mid, count, out)                                             \
    {                                                                                                           \
        if (count == 0)                                                                                         \
            out = -M_PI_2_F;                                                                                    \
        else {                                                                                                  \
            knot = fmax(knot, w1 + 5.0f * w2);                                                                  \
            if (count >= 2)                                                                                     \
                mid = fmax(mid, w0 + 23.0f * w1 + 24.0f * w2);                                                 \
            out = HF_WINDOW_MAX(best, knot, mid);                                                               \
        }                                                                                                       \
    }

/* Whether no later spline candidate can change max(result, 0) when every
 * elevation they combine is at most b: b <= 0 (their numerators are sums of
 * non-positive terms), or b below the running maximum of the knots (6 b) or
 * the midpoints (48 b), with room for the numerators' float rounding. */
HF_INLINE hf_ri hf_search_done(hf_rf b, hf_rf knot, hf_rf mid)
{
    return (b <= 0.0f) | (6.00006f * b + 1e-5f < knot) | (48.0005f * b + 1e-4f < mid);
}

/* hf_horizon_pyramid_v for a row group's two rows along one direction (cu,
 * cv); hpA, hpB hold H_k - ref at each lane's vertex. The environment's
 * search: no limit. With start > 0 (partial updates) the search resumes at
 * sample start (a checkpoint, >= 3) from the kept maxima best0A, best0B,
 * the window refilled from the three samples before it (which read nothing
 * changed: the same floats); with ncp > 0 the running maximum before sample
 * c ls (c = 1 .. ncp, ls the level step) is kept in cp[cpi + c - 1] of each
 * of the `lanes` first lanes of each of the `rows` rows. The same
 * arithmetic either way, so the same result. */
HF_INLINE void hf_horizon_pyramid_row2(global const float *pyr, global const int4 *levels, int4 grid, float8 geom,
                                       const hf_rf *hpA, const hf_rf *hpB, float refA, float refB, hf_rf u0, float vA,
                                       float vB, float cu, float cv, float inv_wm1, float inv_dm1, int start,
                                       hf_rf best0A, hf_rf best0B, global float *cp, hf_ri cpiA, hf_ri cpiB,
                                       int lanes, int rows, int ncp, const hf_rf *urA, const hf_rf *urB,
                                       hf_rf *outA, hf_rf *outB)
{
    hf_rf wA0 = 0.0f, wA1 = 0.0f, wA2 = 0.0f, bestA = start ? best0A : -M_PI_2_F, knotA = -INFINITY,
          midA = -INFINITY;
    hf_rf wB0 = 0.0f, wB1 = 0.0f, wB2 = 0.0f, bestB = start ? best0B : -M_PI_2_F, knotB = -INFINITY,
          midB = -INFINITY;
    int countA = start, countB = start;
    const int ls = (int)geom.s5, m0 = start ? start - 3 : 0;
    const float sr = exp2(1.0f / geom.s5);
    float d = geom.s6;
    for (int m = 0; m < m0; ++m)
        d *= sr;
    for (int m = m0; m < grid.z; ++m, d *= sr) {
        if (ncp && m > start && m % ls == 0 && m / ls <= ncp) {
            float b[HF_ROW];
            int idx[HF_ROW];
            hf_vstore_r(HF_WINDOW_MAX(bestA, knotA, midA), 0, b);
            hf_vstore_r(cpiA, 0, idx);
            for (int l = 0; l < lanes; ++l)
                cp[(size_t)idx[l] + m / ls - 1] = b[l];
            if (rows > 1) {
                hf_vstore_r(HF_WINDOW_MAX(bestB, knotB, midB), 0, b);
                hf_vstore_r(cpiB, 0, idx);
                for (int l = 0; l < lanes; ++l)
                    cp[(size_t)idx[l] + m / ls - 1] = b[l];
            }
        }
        const int k = clamp(m - grid.w, 0, grid.z - 1);
        hf_rf hA, hB;
        hf_level_sample_row2(pyr, levels[k], grid.x - 1, u0 + d * cu, vA + d * cv, vB + d * cv, inv_wm1, inv_dm1,
                             refA, refB, &hA, &hB);
        const float rd = 1.0f / (36.0f * d);
        const hf_rf w3A = hf_atan_r((hA - hpA[k]) * rd), w3B = hf_atan_r((hB - hpB[k]) * rd);
        if (m < start) {
            wA0 = wA1;
            wA1 = wA2;
            wA2 = w3A;
            wB0 = wB1;
            wB1 = wB2;
            wB2 = w3B;
            continue;
        }
        HF_WINDOW_STEP_N(wA0, wA1, wA2, w3A, knotA, midA, countA)
        HF_WINDOW_STEP_N(wB0, wB1, wB2, w3B, knotB, midB, countB)
#if HF_EARLY_EXIT
        /* Early exit (urA, urB: bounds on every elevation from sample m + 1
         * on): every later candidate combines the window's three elevations
         * and later ones, so none can change the clamped result once all
         * lanes' bounds lie below their maxima (or at or below 0). */
        if (urA && m >= 3 && (m & HF_EXIT_EVERY) == 0 &&
            all(hf_search_done(fmax(fmax(wA0, wA1), fmax(wA2, urA[m + 1])), knotA, midA) &
                hf_search_done(fmax(fmax(wB0, wB1), fmax(wB2, urB[m + 1])), knotB, midB))) {
            break;
        }
#endif
    }
    HF_WINDOW_FINISH_N(wA0, wA1, wA2, bestA, knotA, midA, countA, *outA)
    HF_WINDOW_FINISH_N(wB0, wB1, wB2, bestB, knotB, midB, countB, *outB)
#ifdef HF_COUNT_SAMPLES /* a build option only to measure the early exits: the samples taken, not the horizon */
    *outA = *outB = (float)countA;
#endif
}

/* Partial updates (docs/heightfield.md, "Dynamic terrain"): changed[k] is
 * the box (a0, b0, a1, b1), inclusive, of level k's values that a local edit
 * changed (a0 > a1: none), changed[levels] the vertices whose normals did.
 * A search reads only B-spline taps, so a lane whose taps all miss the boxes
 * gives the same floats as before. Whether the taps of level coordinates
 * [lo, hi] along one axis (indices floor - 1 .. floor + 2, clamped to the
 * level's n + 1 values) meet [c0, c1]: the coordinates are taken
 * HF_TAP_SLACK wider, for the rounding of another evaluation order. */
#ifndef HF_TAP_SLACK /* a build option only to test that the tests catch a narrower mask */
#define HF_TAP_SLACK 0.01f
#endif
inline bool hf_taps_meet(float lo, float hi, int n, int c0, int c1)
{
    const int t0 = clamp((int)floor(lo - HF_TAP_SLACK) - 1, 0, n), t1 = clamp((int)floor(hi + HF_TAP_SLACK) + 2, 0, n);
    return t0 <= c1 && t1 >= c0;
}

/* The first sample of a row group's search along (cu, cv) (lanes' u in
 * [ulo, uhi], rows [vlo, vhi]) that reads a changed value, grid.z if none:
 * one box test per sample. receiver: the first sample whose level's H_k at
 * the receivers changed (d = 0, one test per level). */
inline int hf_row_first_changed(global const int4 *levels, global const int4 *changed, int4 grid, float8 geom,
                                float ulo, float uhi, float vlo, float vhi, float cu, float cv, float inv_wm1,
                                float inv_dm1, int receiver)
{
    const float sr = exp2(1.0f / geom.s5);
    float d = receiver ? 0.0f : geom.s6;
    const int count = receiver ? max(grid.z - grid.w, 1) : grid.z;
    for (int m = 0; m < count; ++m, d *= sr) {
        const int k = receiver ? m : clamp(m - grid.w, 0, grid.z - 1);
        const int4 c = changed[k];
        if (c.x > c.z)
            continue;
        const int4 lev = levels[k];
        const float sa = (float)lev.y * inv_wm1, sb = (float)lev.z * inv_dm1;
        const float a0 = (ulo + d * cu) * sa, a1 = (uhi + d * cu) * sa, b0 = (vlo + d * cv) * sb,
                    b1 = (vhi + d * cv) * sb;
        if (hf_taps_meet(fmin(a0, a1), fmax(a0, a1), lev.y, c.x, c.z) &&
            hf_taps_meet(fmin(b0, b1), fmax(b0, b1), lev.z, c.y, c.w))
            return receiver ? (k ? k + grid.w : 0) : m; /* level k's first sample */
    }
    return grid.z;
}

/* A row group: HF_ROW consecutive vertices of each of two consecutive rows
 * (the field's last row alone when D is odd), led by the work-item of its
 * first vertex. */
#define HF_GROUP_ROWS 2
#ifndef HF_ROW_FEW /* a row's last vertices, if at most this many, are searched one by one */
#define HF_ROW_FEW 4
#endif
inline bool hf_row_leader(int gid, int4 grid, int exact)
{
    return exact || ((gid % grid.x) % HF_ROW == 0 && (gid / grid.x) % HF_GROUP_ROWS == 0);
}

/* Environment horizons (clamped at 0) of the row group starting at vertex
 * gid: om[(r * HF_ROW + lane) * n_phi + k] for row r (0, 1) and the lanes
 * inside the row (lanes past its end repeat its last vertex and are not
 * stored). update 0: all searched; 1: all searched, kept in `horizons`
 * (n_phi per vertex) with their checkpoints (`cp`, ncp per vertex and
 * azimuth); 2: only the azimuths whose search reads a changed value
 * (`changed`, tested for both rows) are searched again, from the last
 * checkpoint before the first such sample, the others read from
 * `horizons`. Returns how many were searched; *moved gets bit
 * r * HF_ROW + l set where row r's lane l's horizons differ (bit for bit)
 * from the kept ones (update 2) or every lane's (otherwise). */
inline void hf_vertex_horizons(global const float *pyr, global const int4 *levels, int4 grid, float8 geom,
                               int gid, int n_phi, int exact, float limit, int env, float *om);
inline int hf_row_env_horizons(global const float *pyr, global const int4 *levels, int4 grid, float8 geom, int gid,
                               int n_phi, int update, global const int4 *changed, global float *horizons,
                               global float *cp, int ncp, float *om, uint *moved)
{
    const float inv_wm1 = 1.0f / (float)(grid.x - 1), inv_dm1 = 1.0f / (float)(grid.y - 1);
    const int i0 = gid % grid.x, lanes = min(HF_ROW, grid.x - i0), ls = (int)geom.s5;
    const int rows = min(HF_GROUP_ROWS, grid.y - gid / grid.x), gidB = gid + (rows - 1) * grid.x;
    if (lanes <= HF_ROW_FEW) {
        /* A row's last few vertices (one at W = 257): each by the per-vertex
         * search (azimuths in the lanes), every azimuth in every mode (no
         * checkpoints), instead of a group whose other lanes are wasted. */
        *moved = update == 2 ? 0u : 0xffffffffu;
        for (int r = 0; r < rows; ++r)
            for (int l = 0; l < lanes; ++l) {
                const int g = gid + r * grid.x + l, q = r * HF_ROW + l;
                hf_vertex_horizons(pyr, levels, grid, geom, g, n_phi, 0, INFINITY, 1, om + q * n_phi);
                for (int k = 0; update && k < n_phi; ++k) {
                    global float *kept = horizons + (size_t)g * n_phi + k;
                    if (as_uint(*kept) != as_uint(om[q * n_phi + k]))
                        *moved |= 1u << q;
                    *kept = om[q * n_phi + k];
                }
            }
        return n_phi;
    }
    const hf_rf u0 = hf_convert_rf(min(i0 + HF_ROW_IDS, grid.x - 1));
    const float vA = (float)(gid / grid.x), vB = vA + (float)(rows - 1), refA = pyr[gid], refB = pyr[gidB];
    const int first_receiver =
        update != 2 ? 0
                    : hf_row_first_changed(levels, changed, grid, geom, u0.s0, HF_RLAST(u0), vA, vB, 0.0f, 0.0f,
                                           inv_wm1, inv_dm1, 1);
    hf_rf hpA[HF_MAX_LEVELS], hpB[HF_MAX_LEVELS];
    const int top = max(grid.z - 1 - grid.w, 0);
    for (int k = 0; k <= top; ++k)
        hf_level_sample_row2(pyr, levels[k], grid.x - 1, u0, vA, vB, inv_wm1, inv_dm1, refA, refB, hpA + k, hpB + k);
    /* Full searches (update 0): bounds for the early exit, the same for every
     * azimuth. No value of any level exceeds max |H| (geom.s7: the levels
     * are weighted means of the heights), so a sample's 36 (H_L - ref) is
     * at most hi (plus room for the float rounding of its 16 taps and of
     * hp) and its elevation at most atan((hi - hp[k]) / (36 d)); ur[m] is
     * the largest of these over samples m .. n - 1 (ur[n] = -inf). */
    hf_rf urA[HF_MAX_LEVELS + 1], urB[HF_MAX_LEVELS + 1];
    if (!update) {
        const float amax = geom.s7 + HF_EXIT_BOUND;
        const float hiA = 36.0f * (amax - refA) + 4e-4f * (amax + fabs(refA)),
                    hiB = 36.0f * (amax - refB) + 4e-4f * (amax + fabs(refB)), sr = exp2(1.0f / geom.s5);
        float d = geom.s6;
        for (int m = 0; m < grid.z; ++m, d *= sr) {
            const int k = clamp(m - grid.w, 0, grid.z - 1);
            const float rd = 1.0f / (36.0f * d);
            urA[m] = hf_atan_r((hiA - hpA[k]) * rd);
            urB[m] = hf_atan_r((hiB - hpB[k]) * rd);
        }
        urA[grid.z] = urB[grid.z] = -INFINITY;
        for (int m = grid.z - 1; m >= 0; --m) {
            urA[m] = fmax(urA[m], urA[m + 1]);
            urB[m] = fmax(urB[m], urB[m + 1]);
        }
    }
    const float dphi = 2.0f * M_PI_F / (float)n_phi;
    const hf_ri laneA = gid + min(HF_ROW_IDS, lanes - 1), laneB = laneA + (gidB - gid);
    int searched = 0;
    *moved = update == 2 ? 0u : 0xffffffffu;
    for (int k = 0; k < n_phi; ++k) {
        float s, c;
        s = sincos(dphi * (float)k, &c);
        float hA[HF_ROW], hB[HF_ROW];
        hf_rf oA, oB;
        if (!update) {
            hf_horizon_pyramid_row2(pyr, levels, grid, geom, hpA, hpB, refA, refB, u0, vA, vB, c / geom.s3,
                                    -s / geom.s4, inv_wm1, inv_dm1, 0, 0.0f, 0.0f, 0, 0, 0, 0, 0, 0, urA, urB, &oA,
                                    &oB);
            hf_vstore_r(fmax(oA, 0.0f), 0, hA);
            hf_vstore_r(fmax(oB, 0.0f), 0, hB);
            for (int l = 0; l < lanes; ++l) {
                om[l * n_phi + k] = hA[l];
                om[(HF_ROW + l) * n_phi + k] = hB[l];
            }
            ++searched;
            continue;
        }
        const int first = update != 2 ? 0
                                      : min(first_receiver,
                                            hf_row_first_changed(levels, changed, grid, geom, u0.s0, HF_RLAST(u0), vA,
                                                                 vB, c / geom.s3, -s / geom.s4, inv_wm1, inv_dm1, 0));
        if (first >= grid.z) {
            for (int r = 0; r < rows; ++r)
                for (int l = 0; l < lanes; ++l)
                    om[(r * HF_ROW + l) * n_phi + k] = horizons[(size_t)(gid + r * grid.x + l) * n_phi + k];
            continue;
        }
        ++searched;
        const hf_ri cpiA = (laneA * n_phi + k) * ncp, cpiB = (laneB * n_phi + k) * ncp;
        /* resume at the last checkpoint at or before the first changed sample */
        const int ck = min(first / ls, ncp), start = ck * ls >= 3 ? ck * ls : 0;
        hf_rf best0A = 0.0f, best0B = 0.0f;
        if (start) {
            int idx[HF_ROW];
            float b0[HF_ROW];
            hf_vstore_r(cpiA, 0, idx);
            for (int l = 0; l < HF_ROW; ++l)
                b0[l] = cp[idx[l] + ck - 1];
            best0A = hf_vload_r(0, b0);
            hf_vstore_r(cpiB, 0, idx);
            for (int l = 0; l < HF_ROW; ++l)
                b0[l] = cp[idx[l] + ck - 1];
            best0B = hf_vload_r(0, b0);
        }
        hf_horizon_pyramid_row2(pyr, levels, grid, geom, hpA, hpB, refA, refB, u0, vA, vB, c / geom.s3, -s / geom.s4,
                                inv_wm1, inv_dm1, start, best0A, best0B, cp, cpiA, cpiB, lanes, rows, ncp, 0, 0, &oA,
                                &oB);
        hf_vstore_r(fmax(oA, 0.0f), 0, hA);
        hf_vstore_r(fmax(oB, 0.0f), 0, hB);
        for (int r = 0; r < rows; ++r)
            for (int l = 0; l < lanes; ++l) {
                const float h = r ? hB[l] : hA[l];
                global float *kept = horizons + (size_t)(gid + r * grid.x + l) * n_phi + k;
                if (as_uint(*kept) != as_uint(h))
                    *moved |= 1u << (r * HF_ROW + l);
                om[(r * HF_ROW + l) * n_phi + k] = h;
                *kept = h;
            }
    }
    return searched;
}

/* The exact-horizon mode: the base field (bilinear) marched in steps of s0 / 2
 * up to the border (and below `limit`). */
inline float hf_horizon_exact(global const float *pyr, int4 grid, float8 geom, float h0, float u0, float v0,
                              float cu, float cv, float limit)
{
    const int w = grid.x;
    const float step = 0.5f * geom.s6, umax = (float)(grid.x - 1), vmax = (float)(grid.y - 1);
    float best = -M_PI_2_F;
    for (int s = 1;; ++s) {
        const float t = step * (float)s, u = u0 + t * cu, v = v0 + t * cv;
        /* A step landing on the border (up to float rounding) still counts. */
        if (!(t < limit) || u < -1e-4f || v < -1e-4f || u > umax + 1e-4f || v > vmax + 1e-4f)
            break;
        const float uc = clamp(u, 0.0f, umax), vc = clamp(v, 0.0f, vmax);
        const int iu = min((int)uc, grid.x - 2), iv = min((int)vc, grid.y - 2);
        const float fu = uc - (float)iu, fv = vc - (float)iv;
        const float h = mix(mix(pyr[iv * w + iu], pyr[iv * w + iu + 1], fu),
                            mix(pyr[(iv + 1) * w + iu], pyr[(iv + 1) * w + iu + 1], fu), fv);
        best = fmax(best, pn_atan((h - h0) / t));
    }
    return best;
}

/* H_k - H_0 at the receiver for every level a sample can use. */
inline void hf_receiver_levels(global const float *pyr, global const int4 *levels, int4 grid, int gid, float *hp)
{
    const float inv_wm1 = 1.0f / (float)(grid.x - 1), inv_dm1 = 1.0f / (float)(grid.y - 1);
    const float u0 = (float)(gid % grid.x), v0 = (float)(gid / grid.x);
    const int top = max(grid.z - 1 - grid.w, 0);
    for (int k = 0; k <= top; ++k)
        hp[k] = hf_level_sample(pyr, levels[k], u0, v0, inv_wm1, inv_dm1, pyr[gid]);
}

/* The exact horizon of vertex gid at azimuth phi (SH frame: world direction
 * (cos, 0, -sin)). */
inline float hf_horizon_exact_at(global const float *pyr, int4 grid, float8 geom, int gid, float phi, float limit)
{
    const float u0 = (float)(gid % grid.x), v0 = (float)(gid / grid.x);
    float s, c;
    s = sincos(phi, &c);
    return hf_horizon_exact(pyr, grid, geom, pyr[gid], u0, v0, c / geom.s3, -s / geom.s4, limit);
}

/* Share of a disc of angular radius r, centred at elevation e, above a
 * horizon at elevation h (the area above a chord). */
inline float hf_disc_above(float e, float h, float r)
{
    const float x = clamp((e - h) / fmax(r, 1e-6f), -1.0f, 1.0f);
    /* wholly below or above the horizon: the formula's own 0 and 1 (exactly), without the asin */
    if (x <= -1.0f)
        return 0.0f;
    if (x >= 1.0f)
        return 1.0f;
    return clamp(0.5f + (x * sqrt(1.0f - x * x) + asin(x)) * M_1_PI_F, 0.0f, 1.0f);
}

/* Horizon angles of vertex gid for every azimuth (environment: clamped at 0;
 * light: only what lies nearer than `limit`). */
inline void hf_vertex_horizons(global const float *pyr, global const int4 *levels, int4 grid, float8 geom,
                               int gid, int n_phi, int exact, float limit, int env, float *om)
{
    float hp[HF_MAX_LEVELS];
    if (!exact)
        hf_receiver_levels(pyr, levels, grid, gid, hp);
    const float dphi = 2.0f * M_PI_F / (float)n_phi;
    if (!exact) {
        /* HF_LANES azimuths per vector (the last lanes past n_phi repeat
         * the last azimuth and are not stored). */
        const float inv_wm1 = 1.0f / (float)(grid.x - 1), inv_dm1 = 1.0f / (float)(grid.y - 1);
        const float u0 = (float)(gid % grid.x), v0 = (float)(gid / grid.x);
        for (int k0 = 0; k0 < n_phi; k0 += HF_LANES) {
            const hf_vi kk = min(k0 + HF_LANE_IDS, n_phi - 1);
            hf_vf c;
            const hf_vf sn = sincos(dphi * HF_CONVERT_F(kk), &c);
            hf_vf h = hf_horizon_pyramid_v(pyr, levels, grid, geom, hp, pyr[gid], u0, v0, c / geom.s3, -sn / geom.s4,
                                           limit, inv_wm1, inv_dm1, 0, 0.0f, 0.0f);
            if (env)
                h = fmax(h, 0.0f);
            if (k0 + HF_LANES <= n_phi)
                hf_vstore(h, 0, om + k0);
            else {
                float tmp[HF_LANES];
                hf_vstore(h, 0, tmp);
                for (int q = 0; k0 + q < n_phi; ++q)
                    om[k0 + q] = tmp[q];
            }
        }
        return;
    }
    for (int k = 0; k < n_phi; ++k) {
        const float h = hf_horizon_exact_at(pyr, grid, geom, gid, dphi * (float)k, limit);
        om[k] = env ? fmax(h, 0.0f) : h;
    }
}

/* Whether the exact march from (u0, v0) along (cu, cv) can read a changed
 * height: a bilinear read at u touches columns floor(u) and floor(u) + 1,
 * so the segment from the vertex onwards is tested against the changed
 * box grown by one cell (and HF_TAP_SLACK), slab by slab. */
inline bool hf_ray_meets(float u0, float v0, float cu, float cv, int4 c)
{
    if (c.x > c.z)
        return false;
    const float lo[2] = {(float)c.x - 1.0f - HF_TAP_SLACK, (float)c.y - 1.0f - HF_TAP_SLACK};
    const float hi[2] = {(float)c.z + 1.0f + HF_TAP_SLACK, (float)c.w + 1.0f + HF_TAP_SLACK};
    const float p[2] = {u0, v0}, dir[2] = {cu, cv};
    float t0 = 0.0f, t1 = INFINITY;
    for (int a = 0; a < 2; ++a) {
        if (fabs(dir[a]) < 1e-20f) {
            if (p[a] < lo[a] || p[a] > hi[a])
                return false;
            continue;
        }
        const float ta = (lo[a] - p[a]) / dir[a], tb = (hi[a] - p[a]) / dir[a];
        t0 = fmax(t0, fmin(ta, tb));
        t1 = fmin(t1, fmax(ta, tb));
    }
    return t0 <= t1;
}

/* The exact mode's environment horizons of vertex gid with the update
 * modes of hf_row_env_horizons; returns how many were marched. */
inline int hf_vertex_env_horizons(global const float *pyr, global const int4 *levels, int4 grid, float8 geom,
                                   int gid, int n_phi, int update, global const int4 *changed,
                                   global float *horizons, float *om, uint *moved)
{
    *moved = update != 2;
    if (update != 2) {
        hf_vertex_horizons(pyr, levels, grid, geom, gid, n_phi, 1, INFINITY, 1, om);
        for (int k = 0; update && k < n_phi; ++k)
            horizons[(size_t)gid * n_phi + k] = om[k];
        return n_phi;
    }
    const float u0 = (float)(gid % grid.x), v0 = (float)(gid / grid.x), dphi = 2.0f * M_PI_F / (float)n_phi;
    const int4 c = changed[0];
    /* the receiver's own height: every azimuth */
    const bool all = c.x <= c.z && u0 >= (float)c.x && u0 <= (float)c.z && v0 >= (float)c.y && v0 <= (float)c.w;
    int searched = 0;
    for (int k = 0; k < n_phi; ++k) {
        float s, cs;
        s = sincos(dphi * (float)k, &cs);
        if (!all && !hf_ray_meets(u0, v0, cs / geom.s3, -s / geom.s4, c)) {
            om[k] = horizons[(size_t)gid * n_phi + k];
            continue;
        }
        ++searched;
        const float h = hf_horizon_exact_at(pyr, grid, geom, gid, dphi * (float)k, INFINITY);
        om[k] = fmax(h, 0.0f);
        if (as_uint(horizons[(size_t)gid * n_phi + k]) != as_uint(om[k]))
            *moved = 1u;
        horizons[(size_t)gid * n_phi + k] = om[k];
    }
    return searched;
}

/* SH vectors in float16 chunks (coefficient q = 16 chunk + lane; 6 bands:
 * 36 coefficients in 3 chunks, the last lanes zero). PoCL runs a work-item's
 * loops as scalar code, so the coefficient loops of the visibility and the
 * product are written out as chunk arithmetic. */
#define HF_SH_CHUNKS ((PN_SH_MAX_COEFFS + 15) / 16)

/* Chunk `chunk` of the nc floats at p (lanes past nc are 0, nothing past nc is read). */
inline float16 hf_sh_chunk(global const float *p, int nc, int chunk)
{
    const int rest = nc - 16 * chunk;
    if (rest >= 16)
        return vload16(chunk, p);
    float16 x = 0.0f;
    if (rest == 4) {
        x.s0123 = vload4(0, p + 16 * chunk);
        return x;
    }
    float t[16];
    for (int i = 0; i < 16; ++i)
        t[i] = i < rest ? p[16 * chunk + i] : 0.0f;
    return vload16(0, t);
}

inline float hf_hsum16(float16 x)
{
    const float8 y = x.lo + x.hi;
    const float4 z = y.lo + y.hi;
    return (z.x + z.y) + (z.z + z.w);
}

/* Per chunk lane: |m| of the coefficient (7 = a zero lane past 6 bands) and sign(m). */
#define HF_ABS_M0 ((uint16)(0, 1, 0, 1, 2, 1, 0, 1, 2, 3, 2, 1, 0, 1, 2, 3))
#define HF_ABS_M1 ((uint16)(4, 3, 2, 1, 0, 1, 2, 3, 4, 5, 4, 3, 2, 1, 0, 1))
#define HF_ABS_M2 ((uint16)(2, 3, 4, 5, 7, 7, 7, 7, 7, 7, 7, 7, 7, 7, 7, 7))
#define HF_SIGN_M0 ((float16)(0, -1, 0, 1, -1, -1, 0, 1, 1, -1, -1, -1, 0, 1, 1, 1))
#define HF_SIGN_M1 ((float16)(-1, -1, -1, -1, 0, 1, 1, 1, 1, -1, -1, -1, -1, -1, 0, 1))
#define HF_SIGN_M2 ((float16)(1, 1, 1, 1, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0))

/* V = sum over azimuths of the wedge table, bilinear at (ω_k, ω_k+1), turned
 * to φ_k. The turn about z (pn_sh_zrotate) maps c to cos(mφ) c + S ∘ swap(c),
 * swap exchanging (l, m) and (l, -m); since swap is fixed and linear, the sum
 * over wedges is A + swap(B) with A = Σ cos(mφ_k) c_k and
 * B = Σ sign(m) sin(|m| φ_k) c_k, both plain lane-wise chunk arithmetic. */
inline void hf_visibility(const float *om, int n_phi, global const float *table, int nb, float lo, float *v)
{
    const int nc = nb * nb, nch = (nc + 15) / 16, ns = 16 * nch;
    const float scale = (float)(HF_TABLE - 1) / (0.5f * M_PI_F - lo), dphi = 2.0f * M_PI_F / (float)n_phi;
    /* cos mφ_k and sign(m) sin |m|φ_k per chunk lane, turned from wedge to
     * wedge by the fixed step δ = dphi (a rotation of each lane's pair:
     * cos, sin of |m|δ from one sincos and the recurrence over m that
     * pn_sh_zrotate uses), instead of a sincos, the recurrence over m and
     * the lane shuffles per wedge. φ_0 = 0: cos 1, sin 0. */
    float sn, cs;
    sn = sincos(dphi, &cs);
    float cm[8] = {1.0f, cs, 0.0f, 0.0f, 0.0f, 0.0f, 0.0f, 0.0f}, sm[8] = {0.0f, sn, 0.0f, 0.0f, 0.0f, 0.0f, 0.0f, 0.0f};
    for (int m = 2; m < PN_SH_MAX_BANDS; ++m) {
        cm[m] = cm[m - 1] * cs - sm[m - 1] * sn;
        sm[m] = sm[m - 1] * cs + cm[m - 1] * sn;
    }
    const float8 c8 = vload8(0, cm), s8 = vload8(0, sm);
    const float16 dc0 = shuffle(c8, HF_ABS_M0), dc1 = shuffle(c8, HF_ABS_M1), dc2 = shuffle(c8, HF_ABS_M2);
    const float16 ds0 = shuffle(s8, HF_ABS_M0) * HF_SIGN_M0, ds1 = shuffle(s8, HF_ABS_M1) * HF_SIGN_M1,
                  ds2 = shuffle(s8, HF_ABS_M2) * HF_SIGN_M2;
    /* lanes past 6 bands (|m| 7) stay 0 */
    float16 rc0 = select((float16)(1.0f), (float16)(0.0f), HF_ABS_M0 == 7u),
            rc1 = select((float16)(1.0f), (float16)(0.0f), HF_ABS_M1 == 7u),
            rc2 = select((float16)(1.0f), (float16)(0.0f), HF_ABS_M2 == 7u);
    float16 rs0 = 0.0f, rs1 = 0.0f, rs2 = 0.0f;
    float16 a0 = 0.0f, a1 = 0.0f, a2 = 0.0f, b0 = 0.0f, b1 = 0.0f, b2 = 0.0f;
#if HF_VIS_PREP
    /* Each wedge's table cell and bilinear weights, 16 wedges at a time in
     * the lanes (the same float operations as the scalar form below, lane
     * by lane), kept in private arrays for the chunk loop. */
    int toff[HF_MAX_AZIMUTHS];
    float tw00[HF_MAX_AZIMUTHS], tw01[HF_MAX_AZIMUTHS], tw10[HF_MAX_AZIMUTHS], tw11[HF_MAX_AZIMUTHS];
    int k0 = 0;
    for (; k0 + 16 <= n_phi; k0 += 16) {
        const float16 oa = vload16(0, om + k0);
        float16 ob;
        if (k0 + 16 < n_phi)
            ob = vload16(0, om + k0 + 1);
        else
            ob = shuffle2(oa, (float16)(om[0]), (uint16)(1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15, 16));
        const float16 fa = clamp((oa - lo) * scale, 0.0f, (float)(HF_TABLE - 1));
        const float16 fb = clamp((ob - lo) * scale, 0.0f, (float)(HF_TABLE - 1));
        const int16 ia = min(convert_int16(fa), HF_TABLE - 2), ib = min(convert_int16(fb), HF_TABLE - 2);
        const float16 ta = fa - convert_float16(ia), tb = fb - convert_float16(ib);
        const float16 w11 = ta * tb, w10 = ta - w11, w01 = tb - w11, w00 = 1.0f - ta - w01;
        vstore16((ia * HF_TABLE + ib) * ns, 0, toff + k0);
        vstore16(w00, 0, tw00 + k0);
        vstore16(w01, 0, tw01 + k0);
        vstore16(w10, 0, tw10 + k0);
        vstore16(w11, 0, tw11 + k0);
    }
    for (int k = k0; k < n_phi; ++k) {
        const float fa = clamp((om[k] - lo) * scale, 0.0f, (float)(HF_TABLE - 1));
        const float fb = clamp((om[k + 1 < n_phi ? k + 1 : 0] - lo) * scale, 0.0f, (float)(HF_TABLE - 1));
        const int ia = min((int)fa, HF_TABLE - 2), ib = min((int)fb, HF_TABLE - 2);
        const float ta = fa - (float)ia, tb = fb - (float)ib;
        const float w11 = ta * tb, w01 = tb - w11;
        toff[k] = (ia * HF_TABLE + ib) * ns;
        tw00[k] = 1.0f - ta - w01;
        tw01[k] = w01;
        tw10[k] = ta - w11;
        tw11[k] = w11;
    }
#endif
    for (int k = 0; k < n_phi; ++k) {
#if HF_VIS_PREP
        global const float *t00 = table + toff[k], *t01 = t00 + ns;
        global const float *t10 = t00 + HF_TABLE * ns, *t11 = t10 + ns;
        const float w00 = tw00[k], w01 = tw01[k], w10 = tw10[k], w11 = tw11[k];
#else
        const float fa = clamp((om[k] - lo) * scale, 0.0f, (float)(HF_TABLE - 1));
        const float fb = clamp((om[k + 1 < n_phi ? k + 1 : 0] - lo) * scale, 0.0f, (float)(HF_TABLE - 1));
        const int ia = min((int)fa, HF_TABLE - 2), ib = min((int)fb, HF_TABLE - 2);
        const float ta = fa - (float)ia, tb = fb - (float)ib;
        global const float *t00 = table + (ia * HF_TABLE + ib) * ns, *t01 = t00 + ns;
        global const float *t10 = t00 + HF_TABLE * ns, *t11 = t10 + ns;
        /* the bilinear weights (four FMAs per chunk instead of three mixes) */
        const float w11 = ta * tb, w10 = ta - w11, w01 = tb - w11, w00 = 1.0f - ta - w01;
#endif
        /* (c, s) -> (c cos|m|δ - s sign sin|m|δ, s cos|m|δ + c sign sin|m|δ); sign² = 1 where sin|m|δ != 0 */
#define HF_WEDGE_CHUNK(q, a, b, rc, rs, dc, ds)                                                                 \
    {                                                                                                           \
        const float16 x = w00 * vload16(q, t00) + w01 * vload16(q, t01) + w10 * vload16(q, t10) +               \
                          w11 * vload16(q, t11);                                                                \
        a += rc * x;                                                                                            \
        b += rs * x;                                                                                            \
        const float16 rn = rc * dc - rs * ds;                                                                   \
        rs = rs * dc + rc * ds;                                                                                 \
        rc = rn;                                                                                                \
    }
        HF_WEDGE_CHUNK(0, a0, b0, rc0, rs0, dc0, ds0)
        if (nch > 1)
            HF_WEDGE_CHUNK(1, a1, b1, rc1, rs1, dc1, ds1)
        if (nch > 2)
            HF_WEDGE_CHUNK(2, a2, b2, rc2, rs2, dc2, ds2)
#undef HF_WEDGE_CHUNK
    }
    float a[16 * HF_SH_CHUNKS], b[16 * HF_SH_CHUNKS];
    vstore16(a0, 0, a);
    vstore16(a1, 1, a);
    vstore16(a2, 2, a);
    vstore16(b0, 0, b);
    vstore16(b1, 1, b);
    vstore16(b2, 2, b);
    for (int l = 0; l < nb; ++l)
        for (int m = -l; m <= l; ++m)
            v[l * l + l + m] = a[l * l + l + m] + b[l * l + l - m];
}

/* Clamped cosine about the world normal n, in SH: C_lm = A_l y_lm(n). */
inline void hf_cosine(float3 n, int nb, float8 cosine_zh, float *cvec)
{
    const float a[8] = {cosine_zh.s0, cosine_zh.s1, cosine_zh.s2, cosine_zh.s3,
                        cosine_zh.s4, cosine_zh.s5, cosine_zh.s6, cosine_zh.s7};
    pn_sh_eval((float3)(n.x, -n.z, n.y), nb, cvec);
    for (int l = 0; l < nb; ++l)
        for (int q = l * l; q < (l + 1) * (l + 1); ++q)
            cvec[q] *= a[l];
}

inline float3 hf_albedo(global const float *albedo, int has_albedo, int gid)
{
    return has_albedo ? vload3(gid, albedo) : (float3)(1.0f);
}

/* The sun texels as directional lights: each is visible by the fraction of
 * its disc (angular radius r) above the horizon at its azimuth, times N·s.
 * The horizon there is the Catmull-Rom cubic through the four nearest
 * azimuths (hf_horizon_cubic; the wedges take it linear, but a sun's shadow
 * edge is sharp: the cubic places it closer to the reference on every
 * terrain measured, docs/heightfield.md, "Sun texels"). Records of
 * three float4: (direction, r), (radiance x solid angle, power), (azimuth in
 * [0, 2π) in the SH frame, elevation, 0, 0) -- the angles do not depend on
 * the vertex, so the host computes them once. After the records 5 float4
 * for all of them: their bounds (least azimuth, greatest azimuth, least
 * elevation - r, greatest elevation + r; r taken as in x below), their mean
 * direction s_c and the largest |s_i - s_c| (plus room for rounding), and
 * S = Σ_i L_i Ω_i s_iᵀ (a row per channel). The cubic of four horizons
 * lies within their range widened by 1/8 of it on either side (its two
 * outer weights sum to -t (1 - t) / 2 >= -1/8). Where that bound over the
 * azimuths the texels read is all above the greatest elevation (every
 * disc wholly below its horizon) the texels give nothing; where it is all
 * below the least (every disc wholly above: vis = 1), with HF_SUN_MARGIN to
 * spare for the rounding of the interpolation, the texels need no horizon,
 * and if moreover n · s_c exceeds the spread (every n · s_i > 0) their sum
 * is S n (three dots instead of a loop over the texels; the same sum up to
 * float rounding). */
#ifndef HF_SUN_MARGIN /* a build option only to measure without the shortcuts (1e30f) */
#define HF_SUN_MARGIN 1e-4f
#endif
#ifndef HF_SUN_LINEAR /* a build option only to measure against the linear interpolation (1) */
#define HF_SUN_LINEAR 0
#endif
/* The Catmull-Rom cubic through om[k - 1 .. k + 2] (wrapping) at k + t. */
inline float hf_horizon_cubic(const float *om, int n_phi, int k, float t)
{
    const float p0 = om[k > 0 ? k - 1 : n_phi - 1], p1 = om[k], p2 = om[k + 1 < n_phi ? k + 1 : 0],
                p3 = om[k + 2 < n_phi ? k + 2 : k + 2 - n_phi];
    if (HF_SUN_LINEAR)
        return mix(p1, p2, t);
    return p1 + 0.5f * t * (p2 - p0 + t * (2.0f * p0 - 5.0f * p1 + 4.0f * p2 - p3 + t * (3.0f * (p1 - p2) + p3 - p0)));
}

inline float3 hf_sun(const float *om, int n_phi, float3 n, global const float4 *sun, int suns)
{
    float3 e = (float3)(0.0f);
    if (suns <= 0)
        return e;
    const float scale = (float)n_phi / (2.0f * M_PI_F);
    const float4 box = sun[3 * suns];
    /* texel i reads om[k_i - 1 .. k_i + 2] (wrapping), k_i = min((int)(azimuth_i scale), n_phi - 1) */
    const int klo = min((int)(box.x * scale), n_phi - 1) - 1, khi = min((int)(box.y * scale), n_phi - 1) + 2;
    float hmin = INFINITY, hmax = -INFINITY;
    for (int k = klo; k <= khi; ++k) {
        const float h = om[k < 0 ? k + n_phi : k < n_phi ? k : k - n_phi];
        hmin = fmin(hmin, h);
        hmax = fmax(hmax, h);
    }
    const float overshoot = 0.125f * (hmax - hmin);
    if (hmin - overshoot >= box.w + HF_SUN_MARGIN)
        return e;
    if (hmax + overshoot <= box.z - HF_SUN_MARGIN) {
        const float4 sc = sun[3 * suns + 1];
        if (dot(n, sc.xyz) > sc.w)
            return (float3)(dot(n, sun[3 * suns + 2].xyz), dot(n, sun[3 * suns + 3].xyz), dot(n, sun[3 * suns + 4].xyz));
        for (int i = 0; i < suns; ++i) {
            const float c = dot(n, sun[3 * i].xyz);
            if (c > 0.0f)
                e += sun[3 * i + 1].xyz * c;
        }
        return e;
    }
    for (int i = 0; i < suns; ++i) {
        const float4 d = sun[3 * i];
        const float c = dot(n, d.xyz);
        if (c <= 0.0f)
            continue;
        const float2 g = sun[3 * i + 2].xy;
        const float a = g.x * scale;
        const int k = min((int)a, n_phi - 1);
        const float horizon = hf_horizon_cubic(om, n_phi, k, a - (float)k);
        /* Fully below or fully above the horizon: no chord to integrate. */
        const float x = (g.y - horizon) / fmax(d.w, 1e-6f);
        if (x <= -1.0f)
            continue;
        const float vis = x >= 1.0f ? 1.0f : hf_disc_above(g.y, horizon, d.w);
        e += sun[3 * i + 1].xyz * (c * vis);
    }
    return e;
}

/* Environment pass: E = V^T M C per channel (M_jk = Σ_i L_i Γ_ijk). With
 * `split`, the SH estimate of the unoccluded upper hemisphere (u·C, u = Hᵀ M)
 * is replaced by the exact irradiance of the env's upper half, so SH carries
 * only what the terrain blocks: E = E_up(n) - (H - V)^T M C. Clamped at 0;
 * writes albedo / π E and starts the total with it. */
inline void hf_env_vertex(int gid, const float *om, global const float4 *normals, global const float *albedo,
                          int has_albedo, int n_phi, int nb, global const float *table, global const float *m,
                          float8 cosine_zh, int split, global const float4 *up_irradiance, int up_size,
                          global const float *u, global const float4 *sun, int suns, global float4 *out_env,
                          global float4 *out_total)
{
    const int nc = nb * nb;
    /* zero-padded to whole chunks */
    float v[16 * HF_SH_CHUNKS], cvec[16 * HF_SH_CHUNKS];
#if HF_PROF_VIS
    hf_visibility(om, n_phi, table, nb, 0.0f, v);
#else
    for (int q = 0; q < nc; ++q)
        v[q] = om[q % n_phi];
#endif
    const float3 n = normals[gid].xyz;
    hf_cosine(n, nb, cosine_zh, cvec);
    for (int q = nc; q < 16 * HF_SH_CHUNKS; ++q)
        v[q] = cvec[q] = 0.0f;
    const float3 up = split ? pn_cube_grid_lookup(up_irradiance, up_size, n) : (float3)(0.0f);
    const float upv[3] = {up.x, up.y, up.z};
    float e[3];
    /* V^T M C per channel as chunks: acc = Σ_k C_k M_·k (M stored by
     * columns, each padded to whole chunks), then acc · V. The clamped
     * cosine is 0 on the odd bands from l = 3 on (cosine_zh), so half of the
     * 36 columns are skipped. The three channels run in one pass over the
     * columns (each C_k broadcast once; the same sums in the same order). */
    const int nch = (nc + 15) / 16, ms = nc * 16 * nch;
    const float16 c0 = vload16(0, cvec), c1 = vload16(1, cvec), c2 = vload16(2, cvec);
    const float16 v0 = vload16(0, v), v1 = vload16(1, v), v2 = vload16(2, v);
    const float zh[8] = {cosine_zh.s0, cosine_zh.s1, cosine_zh.s2, cosine_zh.s3,
                         cosine_zh.s4, cosine_zh.s5, cosine_zh.s6, cosine_zh.s7};
    float16 r0 = 0.0f, r1 = 0.0f, r2 = 0.0f, g0 = 0.0f, g1 = 0.0f, g2 = 0.0f, b0 = 0.0f, b1 = 0.0f, b2 = 0.0f;
#if HF_PROF_PRODUCT
    for (int l = 0; l < nb; ++l) {
        if (zh[l] == 0.0f)
            continue;
        for (int k = l * l; k < (l + 1) * (l + 1); ++k) {
            global const float *col = m + k * 16 * nch;
            const float ck = cvec[k];
            r0 += ck * vload16(0, col);
            g0 += ck * vload16(0, col + ms);
            b0 += ck * vload16(0, col + 2 * ms);
            if (nch > 1) {
                r1 += ck * vload16(1, col);
                g1 += ck * vload16(1, col + ms);
                b1 += ck * vload16(1, col + 2 * ms);
            }
            if (nch > 2) {
                r2 += ck * vload16(2, col);
                g2 += ck * vload16(2, col + ms);
                b2 += ck * vload16(2, col + 2 * ms);
            }
        }
    }
#endif
    const float sums[3] = {hf_hsum16(r0 * v0 + r1 * v1 + r2 * v2), hf_hsum16(g0 * v0 + g1 * v1 + g2 * v2),
                           hf_hsum16(b0 * v0 + b1 * v1 + b2 * v2)};
    for (int ch = 0; ch < 3; ++ch) {
#if !HF_PROF_PRODUCT
        e[ch] = v[ch] + cvec[ch];
        continue;
#endif
        float sum = sums[ch];
        if (split) {
            global const float *uch = u + ch * PN_SH_MAX_COEFFS;
            float16 ud = hf_sh_chunk(uch, nc, 0) * c0;
            if (nch > 1)
                ud += hf_sh_chunk(uch, nc, 1) * c1;
            if (nch > 2)
                ud += hf_sh_chunk(uch, nc, 2) * c2;
            const float uc = hf_hsum16(ud);
            /* Terrain only takes light away: SH ringing of the blocked part
             * must not lift E above the unoccluded upper-hemisphere irradiance. */
            sum = fmin(sum + upv[ch] - uc, upv[ch]);
        }
        e[ch] = fmax(sum, 0.0f);
    }
#if HF_PROF_SUN
    const float3 direct = hf_sun(om, n_phi, n, sun, suns);
#else
    const float3 direct = (float3)(0.0f);
#endif
    e[0] += direct.x;
    e[1] += direct.y;
    e[2] += direct.z;
    const float4 out = (float4)(hf_albedo(albedo, has_albedo, gid) * (float3)(e[0], e[1], e[2]) * M_1_PI_F, 1.0f);
    out_env[gid] = out;
    out_total[gid] = out;
}

kernel void hf_env(global const float *pyr, global const int4 *levels, int4 grid, float8 geom,
                   global const float4 *normals, global const float *albedo, int has_albedo, int n_phi, int nb,
                   int exact, global const float *table, global const float *m, float8 cosine_zh, int split,
                   global const float4 *up_irradiance, int up_size, global const float *u,
                   global const float4 *sun, int suns, global float4 *out_env, global float4 *out_total,
                   int update, global const int4 *changed, global float *horizons, global float *cp, int ncp)
{
    /* update (hf_row_env_horizons): 0 every vertex; 1 every vertex, horizons
     * kept; 2 a partial update: only what reads a changed value is searched
     * again, and only vertices whose horizons came out different (bit for
     * bit) or whose normal changed are shaded again; the others keep out_env
     * (and restart the total from it).
     * hf_searched tells which azimuths a partial update searched. */
    const int gid = get_global_id(0);
    if (gid >= grid.x * grid.y || !hf_row_leader(gid, grid, exact))
        return;
    float om[HF_GROUP_ROWS * HF_ROW * HF_MAX_AZIMUTHS];
    int lanes = 1, rows = 1;
    uint moved;
    if (exact)
        hf_vertex_env_horizons(pyr, levels, grid, geom, gid, n_phi, update, changed, horizons, om, &moved);
    else {
        hf_row_env_horizons(pyr, levels, grid, geom, gid, n_phi, update, changed, horizons, cp, ncp, om, &moved);
        lanes = min(HF_ROW, grid.x - gid % grid.x);
        rows = min(HF_GROUP_ROWS, grid.y - gid / grid.x);
    }
    const int4 nbox = update == 2 ? changed[grid.z] : (int4)(1, 1, 0, 0);
    for (int r = 0; r < rows; ++r)
        for (int l = 0; l < lanes; ++l) {
            const int i = gid % grid.x + l, j = gid / grid.x + r, g = gid + r * grid.x + l, q = r * HF_ROW + l;
            /* the same horizons (bit for bit) and normal: the same radiance */
            if (update == 2 && !(moved >> q & 1u) && !(i >= nbox.x && i <= nbox.z && j >= nbox.y && j <= nbox.w)) {
                out_total[g] = out_env[g];
                continue;
            }
#if !HF_PROF_SHADE
            out_env[g] = out_total[g] = (float4)(om[q * n_phi]);
            continue;
#endif
            hf_env_vertex(g, om + q * n_phi, normals, albedo, has_albedo, n_phi, nb, table, m, cosine_zh, split,
                          up_irradiance, up_size, u, sun, suns, out_env, out_total);
        }
}

/* Cap of light (centre c, radius r) seen from p: s = 1 - cos α (2 inside the light). */
inline float hf_cap(float3 rel, float r)
{
    const float d2 = dot(rel, rel);
    if (d2 <= r * r)
        return 2.0f;
    const float q = r * r / d2;
    return q / (1.0f + sqrt(1.0f - q));
}

/* Irradiance from a spherical light of unit radiance with angular radius
 * asin(sqrt(sin2)) at angle acos(c) from the normal, clipped by the tangent
 * plane (the closed form of Lagarde and de Rousiers, "Moving Frostbite to
 * PBR", 2014, for a sphere or disc light). */
inline float hf_sphere_irradiance(float c, float sin2)
{
    if (c * c > sin2)
        return c > 0.0f ? M_PI_F * sin2 * c : 0.0f;
    const float sn = sqrt(fmax(1.0f - c * c, 0.0f)), x = sqrt(fmax(1.0f / sin2 - 1.0f, 0.0f));
    const float y = clamp(-x * c / fmax(sn, 1e-7f), -1.0f, 1.0f), sy = sn * sqrt(1.0f - y * y);
    return fmax((c * acos(y) - x * sy) * sin2 + atan2(sy, x), 0.0f);
}

/* `light_visibility = 1`: the light's exact clipped irradiance times the
 * share of its disc above the horizon, the horizon taken (only nearer than
 * the light) at three azimuths across the disc. Visibility as a direct
 * horizon test needs no SH of a small cap, which 4 bands smear widely. */
inline float hf_light_horizon(global const float *pyr, global const int4 *levels, int4 grid, float8 geom, int gid,
                              int exact, float3 rel, float r, float3 n)
{
    const float d2 = dot(rel, rel), dist = sqrt(d2);
    if (d2 <= r * r)
        return 0.0f; /* inside the light: its surface emits outwards only (as the reference's) */
    const float sin2 = r * r / d2, alpha = asin(sqrt(sin2)), c = dot(n, rel) / dist;
    const float irr = hf_sphere_irradiance(c, sin2);
    if (irr <= 0.0f)
        return 0.0f;
    const float limit = sqrt(rel.x * rel.x + rel.z * rel.z);
    if (!(limit > 0.0f))
        return irr; /* straight above: no terrain between */
    float hp[HF_MAX_LEVELS];
    if (!exact)
        hf_receiver_levels(pyr, levels, grid, gid, hp);
    const float elev = asin(clamp(rel.y / dist, -1.0f, 1.0f)), phi = atan2(-rel.z, rel.x);
    /* The disc's azimuthal half-width, seen from p. */
    const float spread = fmin(alpha / fmax(cos(elev), 1e-3f), M_PI_F);
    float vis = 0.0f;
    if (exact) {
        for (int q = -1; q <= 1; ++q) {
            const float h = hf_horizon_exact_at(pyr, grid, geom, gid, phi + 0.5f * spread * (float)q, limit);
            vis += hf_disc_above(elev, h, alpha);
        }
    } else {
        /* The three azimuths in the lanes of one vector search (lanes past
         * the third repeat it). */
        const float inv_wm1 = 1.0f / (float)(grid.x - 1), inv_dm1 = 1.0f / (float)(grid.y - 1);
        const hf_vf q = HF_CONVERT_F(min(HF_LANE_IDS, 2) - 1);
        hf_vf c;
        const hf_vf sn = sincos(phi + 0.5f * spread * q, &c);
        /* Early exit: a horizon at or above elev + alpha hides the disc, one at
         * or below elev - alpha clears it (hf_disc_above gives exactly 0 or
         * 1 either way; margins for the float rounding of x). ur: bounds on
         * the elevations from sample m on, as in hf_row_env_horizons. */
        float ur[HF_MAX_LEVELS + 1];
        const float ref = pyr[gid], amax = geom.s7 + HF_EXIT_BOUND, sr = exp2(1.0f / geom.s5);
        const float hi = amax - ref + 1e-5f * (amax + fabs(ref));
        float d = geom.s6;
        int count = 0;
        for (int m = 0; m < grid.z && d < limit; ++m, d *= sr, ++count)
            ur[m] = pn_atan((hi - hp[clamp(m - grid.w, 0, grid.z - 1)]) / d) + 1e-6f;
        ur[count] = -INFINITY;
        for (int m = count - 1; m >= 0; --m)
            ur[m] = fmax(ur[m], ur[m + 1]);
        const float margin = 1.001f * fmax(alpha, 1e-6f) + 1e-5f;
        float h[HF_LANES];
        hf_vstore(hf_horizon_pyramid_v(pyr, levels, grid, geom, hp, ref, (float)(gid % grid.x), (float)(gid / grid.x),
                                       c / geom.s3, -sn / geom.s4, limit, inv_wm1, inv_dm1, ur, elev + margin,
                                       elev - margin),
                  0, h);
        for (int l = 0; l < 3; ++l)
            vis += hf_disc_above(elev, h[l], alpha);
    }
    return irr * vis / 3.0f;
}

/* Lights in row groups (light_visibility = 1, pyramid mode): the 16
 * vertices of a row group run in the lanes of a float16, one of the three
 * azimuths across each vertex's disc at a time, instead of one vertex's
 * three azimuths in a float8 (5 lanes wasted) per vertex. Each lane has its
 * own direction and limit, so the taps are per-lane loads as in
 * hf_level_sample_v (weights times 6 per axis here); the receivers' levels
 * come from the row sampler, relative to the group's first vertex. */
HF_INLINE hf_rf hf_level_sample_g(global const float *pyr, int4 lev, hf_rf u, hf_rf v, float inv_wm1, float inv_dm1,
                                  float ref)
{
    const hf_rf a = u * (float)lev.y * inv_wm1, b = v * (float)lev.z * inv_dm1;
    const hf_rf fa = floor(a), fb = floor(b), ta = a - fa, tb = b - fb;
    const hf_rf sa = 1.0f - ta, sb = 1.0f - tb, ta2 = ta * ta, tb2 = tb * tb, ta3 = ta2 * ta, tb3 = tb2 * tb;
    const hf_rf wa0 = sa * sa * sa, wa1 = 3.0f * ta3 - 6.0f * ta2 + 4.0f, wa2 = -3.0f * ta3 + 3.0f * ta2 + 3.0f * ta + 1.0f,
                wa3 = ta3;
    const hf_rf wb0 = sb * sb * sb, wb1 = 3.0f * tb3 - 6.0f * tb2 + 4.0f, wb2 = -3.0f * tb3 + 3.0f * tb2 + 3.0f * tb + 1.0f,
                wb3 = tb3;
    const hf_ri ia = convert_int16(fa) - 1, ib = convert_int16(fb) - 1, row = lev.y + 1;
    const hf_ri a0 = clamp(ia, 0, lev.y), a1 = clamp(ia + 1, 0, lev.y), a2 = clamp(ia + 2, 0, lev.y),
                a3 = clamp(ia + 3, 0, lev.y);
    global const float *base = pyr + lev.x;
    hf_ri i0, i1, i2, i3;
#define HF_ROW_AT_G(rr) (i0 = rr + a0, i1 = rr + a1, i2 = rr + a2, i3 = rr + a3,                        \
                         wa0 * (HF_RGATHER(base, i0) - ref) + wa1 * (HF_RGATHER(base, i1) - ref) +     \
                         wa2 * (HF_RGATHER(base, i2) - ref) + wa3 * (HF_RGATHER(base, i3) - ref))
    const hf_rf rows0 = HF_ROW_AT_G(clamp(ib, 0, lev.z) * row), rows1 = HF_ROW_AT_G(clamp(ib + 1, 0, lev.z) * row),
                rows2 = HF_ROW_AT_G(clamp(ib + 2, 0, lev.z) * row), rows3 = HF_ROW_AT_G(clamp(ib + 3, 0, lev.z) * row);
#undef HF_ROW_AT_G
    return wb0 * rows0 + wb1 * rows1 + wb2 * rows2 + wb3 * rows3;
}

/* The search of hf_horizon_pyramid_v with a direction (cu, cv), a limit and
 * exit levels per lane (the window per lane: a lane stops taking samples at
 * its limit); hp holds 36 (H_k - ref) per lane. Early exit as there, once
 * every lane is finished, hidden or clear. */
HF_INLINE hf_rf hf_horizon_pyramid_lanes(global const float *pyr, global const int4 *levels, int4 grid, float8 geom,
                                         const hf_rf *hp, float ref, hf_rf u0, float v0, hf_rf cu, hf_rf cv,
                                         hf_rf limit, float inv_wm1, float inv_dm1, const hf_rf *ur, hf_rf hidden,
                                         hf_rf clear)
{
    hf_rf w0 = 0.0f, w1 = 0.0f, w2 = 0.0f, best = -M_PI_2_F;
    hf_ri count = 0;
    const float8 l8 = fmax(limit.lo, limit.hi);
    const float4 l4 = fmax(l8.lo, l8.hi);
    const float dmax = fmax(fmax(l4.x, l4.y), fmax(l4.z, l4.w)), sr = exp2(1.0f / geom.s5);
    float d = geom.s6;
    for (int m = 0; m < grid.z && d < dmax; ++m, d *= sr) {
        const int k = clamp(m - grid.w, 0, grid.z - 1);
        const hf_rf h = hf_level_sample_g(pyr, levels[k], u0 + d * cu, v0 + d * cv, inv_wm1, inv_dm1, ref);
        const hf_rf w3 = hf_atan_r((h - hp[k]) * (1.0f / (36.0f * d)));
        const hf_ri act = (hf_rf)(d) < limit, first = act & (count == 0);
        w0 = select(w0, w3, first);
        w1 = select(w1, w3, first);
        w2 = select(w2, w3, first);
        best = select(best, fmax(best, (w1 + 4.0f * w2 + w3) / 6.0f), act & (count >= 1));
        best = select(best, fmax(best, (w0 + 23.0f * w1 + 23.0f * w2 + w3) / 48.0f), act & (count >= 2));
        w0 = select(w0, w1, act);
        w1 = select(w1, w2, act);
        w2 = select(w2, w3, act);
        count -= act; /* act is -1 where true */
#if HF_EARLY_EXIT
        if (m >= 3 && (m & HF_EXIT_EVERY) == 0 &&
            all(!act | (best >= hidden) | ((best <= clear) & (fmax(fmax(w0, w1), fmax(w2, ur[m + 1])) <= clear))))
            break;
#endif
    }
    best = select(best, fmax(best, (w1 + 5.0f * w2) / 6.0f), count >= 1);
    best = select(best, fmax(best, (w0 + 23.0f * w1 + 24.0f * w2) / 48.0f), count >= 2);
    return select(best, (hf_rf)(-M_PI_2_F), count == 0);
}

#ifndef HF_LIGHT_SETUP_LANES /* a build option only to measure the lane-by-lane setup (0) */
#define HF_LIGHT_SETUP_LANES 1
#endif
/* dot() of 3-vectors in the lanes, as the builtin rounds it (no contraction into FMAs). */
HF_INLINE hf_rf hf_dot3_r(hf_rf ax, hf_rf ay, hf_rf az, hf_rf bx, hf_rf by, hf_rf bz)
{
#pragma OPENCL FP_CONTRACT OFF
    return ax * bx + ay * by + az * bz;
}

HF_INLINE int hf_any_r(hf_ri m)
{
    return any(m);
}

/* hf_sphere_irradiance in the lanes (the partial branch only where a lane needs it). */
HF_INLINE hf_rf hf_sphere_irradiance_r(hf_rf c, hf_rf sin2)
{
    const hf_ri whole = c * c > sin2;
    hf_rf e = select((hf_rf)(0.0f), M_PI_F * sin2 * c, c > 0.0f);
    if (!all(whole)) {
        const hf_rf sn = sqrt(fmax(1.0f - c * c, 0.0f)), x = sqrt(fmax(1.0f / sin2 - 1.0f, 0.0f));
        const hf_rf y = clamp(-x * c / fmax(sn, 1e-7f), -1.0f, 1.0f), sy = sn * sqrt(1.0f - y * y);
        e = select(fmax((c * acos(y) - x * sy) * sin2 + atan2(sy, x), 0.0f), e, whole);
    }
    return e;
}

/* hf_light (light_visibility = 1, pyramid) for the row group of 16
 * vertices starting at gid (fewer at the row's end). */
inline void hf_light_row(global const float *pyr, global const int4 *levels, int4 grid, float8 geom,
                         global const float4 *normals, global const float *albedo, int has_albedo, float4 light,
                         float4 radiance, float threshold, int out_offset, global float4 *out_light,
                         global float4 *out_total, int gid)
{
    const int i0 = gid % grid.x, j = gid / grid.x, lanes = min(HF_ROW, grid.x - i0);
    const float le = fmax(fmax(radiance.x, radiance.y), radiance.z), r = light.w;
    float e[HF_ROW], irr[HF_ROW], elev[HF_ROW], alpha[HF_ROW], phi[HF_ROW], spread[HF_ROW], lim[HF_ROW];
    bool any = false;
#if HF_LIGHT_SETUP_LANES
    /* The per-vertex setup below (the cap, the clipped irradiance, the
     * disc's elevation, azimuth and spread) for the 16 lanes at once, lanes
     * that the scalar form skips (continue) masked to the same zeros. */
    {
        float hv[HF_ROW], nxv[HF_ROW], nyv[HF_ROW], nzv[HF_ROW];
        for (int l = 0; l < HF_ROW; ++l) {
            const int g = gid + min(l, lanes - 1);
            const float4 nn = normals[g];
            hv[l] = pyr[g];
            nxv[l] = nn.x;
            nyv[l] = nn.y;
            nzv[l] = nn.z;
        }
        const hf_rf rx = light.x - (geom.s0 + hf_convert_rf(i0 + HF_ROW_IDS) * geom.s3),
                    ry = light.y - (geom.s1 + hf_vload_r(0, hv));
        const float rz = light.z - (geom.s2 + (float)j * geom.s4);
        const hf_rf nx = hf_vload_r(0, nxv), ny = hf_vload_r(0, nyv), nz = hf_vload_r(0, nzv);
        const hf_rf d2 = hf_dot3_r(rx, ry, rz, rx, ry, rz), dist = sqrt(d2), nr = hf_dot3_r(nx, ny, nz, rx, ry, rz);
        const hf_ri inside = d2 <= r * r;
        const hf_rf qc = r * r / d2;
        const hf_rf s = select(qc / (1.0f + sqrt(1.0f - qc)), (hf_rf)(2.0f), inside);
        const hf_rf sin_alpha = sqrt(fmax(0.0f, s * (2.0f - s)));
        const hf_rf cos_n = select((hf_rf)(1.0f), nr / dist, dist > 0.0f);
        hf_ri ok = (HF_ROW_IDS < lanes) & !(s >= 2.0f) & !(cos_n <= -sin_alpha) & (le * 2.0f * M_PI_F * s >= threshold) &
                   !inside;
        const hf_rf sin2 = qc, a = asin(sqrt(sin2)), c = nr / dist;
        const hf_rf ir = hf_sphere_irradiance_r(c, sin2);
        ok &= ir > 0.0f;
        const hf_rf limit = sqrt(rx * rx + rz * rz);
        const hf_ri srch = ok & (limit > 0.0f);
        const hf_rf el = asin(clamp(ry / dist, -1.0f, 1.0f));
        hf_vstore_r(select((hf_rf)(0.0f), ir, ok & !srch), 0, e);
        hf_vstore_r(select((hf_rf)(0.0f), ir, srch), 0, irr);
        hf_vstore_r(select((hf_rf)(0.0f), a, srch), 0, alpha);
        hf_vstore_r(select((hf_rf)(0.0f), el, srch), 0, elev);
        hf_vstore_r(select((hf_rf)(0.0f), atan2(-rz, rx), srch), 0, phi);
        hf_vstore_r(select((hf_rf)(0.0f), fmin(a / fmax(cos(el), 1e-3f), M_PI_F), srch), 0, spread);
        hf_vstore_r(select((hf_rf)(0.0f), limit, srch), 0, lim);
        any = hf_any_r(srch);
    }
#else
    for (int l = 0; l < HF_ROW; ++l) {
        e[l] = irr[l] = elev[l] = alpha[l] = phi[l] = spread[l] = lim[l] = 0.0f;
        if (l >= lanes)
            continue;
        const int g = gid + l;
        const float3 p = (float3)(geom.s0 + (float)(i0 + l) * geom.s3, geom.s1 + pyr[g], geom.s2 + (float)j * geom.s4);
        const float3 rel = light.xyz - p, n = normals[g].xyz;
        const float s = hf_cap(rel, r), dist = length(rel);
        const float sin_alpha = sqrt(fmax(0.0f, s * (2.0f - s)));
        const float cos_n = dist > 0.0f ? dot(n, rel) / dist : 1.0f;
        /* as hf_light and hf_light_horizon */
        if (s >= 2.0f || cos_n <= -sin_alpha || !(le * 2.0f * M_PI_F * s >= threshold))
            continue;
        const float d2 = dot(rel, rel), dd = sqrt(d2);
        if (d2 <= r * r)
            continue;
        const float sin2 = r * r / d2, a = asin(sqrt(sin2)), c = dot(n, rel) / dd;
        const float ir = hf_sphere_irradiance(c, sin2);
        if (ir <= 0.0f)
            continue;
        const float limit = sqrt(rel.x * rel.x + rel.z * rel.z);
        if (!(limit > 0.0f)) {
            e[l] = ir;
            continue;
        }
        irr[l] = ir;
        alpha[l] = a;
        elev[l] = asin(clamp(rel.y / dd, -1.0f, 1.0f));
        phi[l] = atan2(-rel.z, rel.x);
        spread[l] = fmin(a / fmax(cos(elev[l]), 1e-3f), M_PI_F);
        lim[l] = limit;
        any = true;
    }
#endif
    if (any) {
        const float inv_wm1 = 1.0f / (float)(grid.x - 1), inv_dm1 = 1.0f / (float)(grid.y - 1), v0 = (float)j;
        const float ref = pyr[gid];
        const hf_rf u0 = hf_convert_rf(min(i0 + HF_ROW_IDS, grid.x - 1));
        hf_rf hp[HF_MAX_LEVELS], ur[HF_MAX_LEVELS + 1];
        const int top = max(grid.z - 1 - grid.w, 0);
        for (int k = 0; k <= top; ++k)
            hp[k] = hf_level_sample_row(pyr, levels[k], grid.x - 1, u0, v0, inv_wm1, inv_dm1, ref);
        /* bounds for the early exit, as in hf_row_env_horizons */
        const float amax = geom.s7 + HF_EXIT_BOUND, hi = 36.0f * (amax - ref) + 4e-4f * (amax + fabs(ref));
        const float sr = exp2(1.0f / geom.s5);
        float d = geom.s6;
        for (int m = 0; m < grid.z; ++m, d *= sr)
            ur[m] = hf_atan_r((hi - hp[clamp(m - grid.w, 0, grid.z - 1)]) * (1.0f / (36.0f * d))) + 1e-6f;
        ur[grid.z] = -INFINITY;
        for (int m = grid.z - 1; m >= 0; --m)
            ur[m] = fmax(ur[m], ur[m + 1]);
        const hf_rf el = hf_vload_r(0, elev), al = hf_vload_r(0, alpha), ph = hf_vload_r(0, phi),
                    sp = hf_vload_r(0, spread), limit = hf_vload_r(0, lim);
        const hf_rf margin = 1.001f * fmax(al, 1e-6f) + 1e-5f;
        float vis[HF_ROW];
        for (int l = 0; l < HF_ROW; ++l)
            vis[l] = 0.0f;
        for (int q = -1; q <= 1; ++q) {
            hf_rf c;
            const hf_rf sn = sincos(ph + 0.5f * sp * (float)q, &c);
            float h[HF_ROW];
            hf_vstore_r(hf_horizon_pyramid_lanes(pyr, levels, grid, geom, hp, ref, u0, v0, c / geom.s3, -sn / geom.s4,
                                                 limit, inv_wm1, inv_dm1, ur, el + margin, el - margin),
                        0, h);
            for (int l = 0; l < lanes; ++l)
                if (lim[l] > 0.0f)
                    vis[l] += hf_disc_above(elev[l], h[l], alpha[l]);
        }
        for (int l = 0; l < lanes; ++l)
            if (lim[l] > 0.0f)
                e[l] = irr[l] * vis[l] / 3.0f;
    }
    for (int l = 0; l < lanes; ++l) {
        const int g = gid + l;
        const float4 out = (float4)(hf_albedo(albedo, has_albedo, g) * radiance.xyz * e[l] * M_1_PI_F, 1.0f);
        out_light[out_offset + g] = out;
        out_total[g] += (float4)(out.xyz, 0.0f);
    }
}

/* One spherical light: E = Le Σ_i z_l(i) y_i(ĉ - p) T_i, T_i = Σ Γ_ijk V_j C_k
 * (sparse Γ), clamped at 0. Vertices where the light cannot matter (its cap
 * entirely below the tangent plane, or Le Ω below `threshold`) get 0
 * without a horizon search. Adds albedo / π E to the total. */
kernel void hf_light(global const float *pyr, global const int4 *levels, int4 grid, float8 geom,
                     global const float4 *normals, global const float *albedo, int has_albedo, int n_phi, int nb,
                     int exact, global const float *table, global const int4 *gamma_index,
                     global const float *gamma_value, int gamma_count, float8 cosine_zh, float4 light,
                     float4 radiance, float threshold, int mode, int out_offset, global float4 *out_light,
                     global float4 *out_total)
{
    const int gid = get_global_id(0);
    if (gid >= grid.x * grid.y)
        return;
#if HF_LIGHT_ROWS
    if (mode == 1 && !exact) {
        if (gid % grid.x % HF_ROW == 0)
            hf_light_row(pyr, levels, grid, geom, normals, albedo, has_albedo, light, radiance, threshold, out_offset,
                         out_light, out_total, gid);
        return;
    }
#endif
    const int nc = nb * nb;
    const int i = gid % grid.x, j = gid / grid.x;
    const float3 p = (float3)(geom.s0 + (float)i * geom.s3, geom.s1 + pyr[gid], geom.s2 + (float)j * geom.s4);
    const float3 rel = light.xyz - p, n = normals[gid].xyz;
    const float s = hf_cap(rel, light.w), dist = length(rel);
    const float le = fmax(fmax(radiance.x, radiance.y), radiance.z);
    const float sin_alpha = sqrt(fmax(0.0f, s * (2.0f - s)));
    const float cos_n = dist > 0.0f ? dot(n, rel) / dist : 1.0f;
    /* Cap below the tangent plane, or p inside the light (whose surface
     * emits outwards only, as in the reference): nothing. */
    const bool below = s >= 2.0f || cos_n <= -sin_alpha; /* cos(π/2 + α) = -sin α */
    float e = 0.0f;
    if (!below && le * 2.0f * M_PI_F * s >= threshold && mode == 1) {
        e = hf_light_horizon(pyr, levels, grid, geom, gid, exact, rel, light.w, n);
    } else if (!below && le * 2.0f * M_PI_F * s >= threshold) {
        float om[HF_MAX_AZIMUTHS], v[PN_SH_MAX_COEFFS], cvec[PN_SH_MAX_COEFFS], t[PN_SH_MAX_COEFFS];
        float y[PN_SH_MAX_COEFFS], z[PN_SH_MAX_BANDS];
        const float limit = sqrt(rel.x * rel.x + rel.z * rel.z);
        hf_vertex_horizons(pyr, levels, grid, geom, gid, n_phi, exact, limit, 0, om);
        hf_visibility(om, n_phi, table, nb, -M_PI_2_F, v);
        hf_cosine(n, nb, cosine_zh, cvec);
        for (int q = 0; q < nc; ++q)
            t[q] = 0.0f;
        for (int g = 0; g < gamma_count; ++g) {
            const int4 ijk = gamma_index[g];
            t[ijk.x] += gamma_value[g] * v[ijk.y] * cvec[ijk.z];
        }
        const float3 dir = dist > 0.0f ? rel / dist : (float3)(0.0f, 1.0f, 0.0f);
        pn_sh_eval((float3)(dir.x, -dir.z, dir.y), nb, y);
        pn_sh_cap(s, nb, z);
        for (int l = 0; l < nb; ++l)
            for (int q = l * l; q < (l + 1) * (l + 1); ++q)
                e += z[l] * y[q] * t[q];
        e = fmax(e, 0.0f);
    }
    const float4 out = (float4)(hf_albedo(albedo, has_albedo, gid) * radiance.xyz * e * M_1_PI_F, 1.0f);
    out_light[out_offset + gid] = out;
    out_total[gid] += (float4)(out.xyz, 0.0f);
}

/* What the tests and the error-splitting experiments read: horizons
 * (n_phi per vertex) or SH visibility (nb*nb per vertex), for the
 * environment (light.w < 0) or for one light. */
kernel void hf_probe(global const float *pyr, global const int4 *levels, int4 grid, float8 geom, int n_phi,
                     int nb, int exact, global const float *table, float4 light, int what, global float *out)
{
    const int gid = get_global_id(0);
    const bool env = light.w < 0.0f;
    /* The environment's pyramid search runs in row groups (as in hf_env). */
    if (gid >= grid.x * grid.y || (env && !hf_row_leader(gid, grid, exact)))
        return;
    float limit = INFINITY;
    if (!env) {
        const int i = gid % grid.x, j = gid / grid.x;
        const float3 p = (float3)(geom.s0 + (float)i * geom.s3, geom.s1 + pyr[gid], geom.s2 + (float)j * geom.s4);
        const float3 rel = light.xyz - p;
        limit = sqrt(rel.x * rel.x + rel.z * rel.z);
    }
    float om[HF_GROUP_ROWS * HF_ROW * HF_MAX_AZIMUTHS];
    int lanes = 1, rows = 1;
    if (env && !exact) {
        uint moved;
        hf_row_env_horizons(pyr, levels, grid, geom, gid, n_phi, 0, 0, 0, 0, 0, om, &moved);
        lanes = min(HF_ROW, grid.x - gid % grid.x);
        rows = min(HF_GROUP_ROWS, grid.y - gid / grid.x);
    } else
        hf_vertex_horizons(pyr, levels, grid, geom, gid, n_phi, exact, limit, env, om);
    for (int q = 0; q < rows * HF_ROW; ++q) {
        const int l = q % HF_ROW;
        if (l >= lanes)
            continue;
        const float *o = om + q * n_phi;
        const size_t g = (size_t)gid + (q / HF_ROW) * grid.x + l;
        if (what == 0) {
            for (int k = 0; k < n_phi; ++k)
                out[g * n_phi + k] = o[k];
            continue;
        }
        float v[PN_SH_MAX_COEFFS];
        hf_visibility(o, n_phi, table, nb, env ? 0.0f : -M_PI_2_F, v);
        for (int q = 0; q < nb * nb; ++q)
            out[g * nb * nb + q] = v[q];
    }
}

/* Which lanes the last env pass searched again (1) or kept (0), n_phi per
 * vertex, from the boxes and mode it ran with: the same tests as
 * hf_row_env_horizons and hf_vertex_env_horizons (for the tests and the
 * benchmark of partial updates). */
kernel void hf_searched(global const int4 *levels, int4 grid, float8 geom, int n_phi, int exact, int update,
                        global const int4 *changed, global float *out)
{
    const int gid = get_global_id(0);
    if (gid >= grid.x * grid.y || !hf_row_leader(gid, grid, exact))
        return;
    const float inv_wm1 = 1.0f / (float)(grid.x - 1), inv_dm1 = 1.0f / (float)(grid.y - 1);
    const float dphi = 2.0f * M_PI_F / (float)n_phi, v0 = (float)(gid / grid.x);
    const int i0 = gid % grid.x, lanes = exact ? 1 : min(HF_ROW, grid.x - i0),
              rows = exact ? 1 : min(HF_GROUP_ROWS, grid.y - gid / grid.x);
    const float v1 = v0 + (float)(rows - 1);
    const hf_rf u0 = hf_convert_rf(min(i0 + HF_ROW_IDS, grid.x - 1));
    const int4 c = changed[0];
    bool all = update != 2 || (!exact && lanes <= HF_ROW_FEW);
    if (!all && exact)
        all = c.x <= c.z && u0.s0 >= (float)c.x && u0.s0 <= (float)c.z && v0 >= (float)c.y && v0 <= (float)c.w;
    else if (!all)
        all = hf_row_first_changed(levels, changed, grid, geom, u0.s0, HF_RLAST(u0), v0, v1, 0.0f, 0.0f, inv_wm1,
                                   inv_dm1, 1) < grid.z;
    for (int k = 0; k < n_phi; ++k) {
        float s, cs;
        s = sincos(dphi * (float)k, &cs);
        const bool hit = all || (exact ? hf_ray_meets(u0.s0, v0, cs / geom.s3, -s / geom.s4, c)
                                       : hf_row_first_changed(levels, changed, grid, geom, u0.s0, HF_RLAST(u0), v0,
                                                              v1, cs / geom.s3, -s / geom.s4, inv_wm1, inv_dm1, 0) <
                                             grid.z);
        for (int r = 0; r < rows; ++r)
            for (int l = 0; l < lanes; ++l)
                out[(size_t)(gid + r * grid.x + l) * n_phi + k] = hit ? 1.0f : 0.0f;
    }
}

/* G-buffer pixels on the height field's instance: the per-vertex outgoing
 * radiance (total), bilinear at the pixel's (x, z), times the pixel's albedo. */
kernel void hf_shade(global const float4 *position, global const float4 *albedo, global const uint *instance_id,
                     int count, uint instance, int4 grid, float8 geom, global const float4 *total,
                     global float4 *image)
{
    const int gid = get_global_id(0);
    if (gid >= count || instance_id[gid] != instance)
        return;
    const float3 p = position[gid].xyz;
    const float u = clamp((p.x - geom.s0) / geom.s3, 0.0f, (float)(grid.x - 1));
    const float v = clamp((p.z - geom.s2) / geom.s4, 0.0f, (float)(grid.y - 1));
    const int iu = min((int)u, grid.x - 2), iv = min((int)v, grid.y - 2), w = grid.x;
    const float fu = u - (float)iu, fv = v - (float)iv;
    const float3 l = mix(mix(total[iv * w + iu].xyz, total[iv * w + iu + 1].xyz, fu),
                         mix(total[(iv + 1) * w + iu].xyz, total[(iv + 1) * w + iu + 1].xyz, fu), fv);
    image[gid] = (float4)(fmax(albedo[gid].xyz * l, 0.0f), 1.0f);
}
