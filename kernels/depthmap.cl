/* `depthmap` method: depth-map environment sampling (docs/depthmap.md; seed:
 * Barsi, Szirmay-Kalos, Szecsi). The env map is N directional domains (centre
 * d_i, total radiance L~_i, cap radius r_i); each has one orthographic depth
 * map along d_i, rendered every frame, and a pixel's outgoing radiance is
 *   L_o = sum_i v_i L~_i (rho/pi max(0, n.d_i) + k_s a_i)
 * with v_i the depth-map visibility and a_i the lobe's average over the
 * domain (a point sample, the seed's Phong blend, a cap quadrature or the
 * table of exact cap averages).
 * float64 twin: tests/depthmap64.py (shade, rasterise).
 *
 * A map's frame is DM_FRAME float4 (host: methods/depthmap.c, fit_frames):
 *   [0] e1.xyz, u_min     [1] e2.xyz, v_min     [2] d.xyz, far = max p.d
 *   [3] du, dv, depth extent, has a map (1; 0: lit unshadowed, skip_power)
 * texel coordinates of a point p: ((p.e1 - u_min) / du, (p.e2 - v_min) / dv),
 * its depth z = far - p.d (distance from the light side of the fitted box).
 * Depths are float bits of z >= 0 in uint (their order is the float order,
 * so atomic_min works); an empty texel holds +inf.
 * The maps are packed in one atlas buffer: map m has atlas[m] = (offset of
 * its first texel, its side res_m); texel (i, j) is at offset + j res_m + i.
 * Maps may differ in size (the strong domains' larger maps). */
#include "common/brdf.cl"
#include "common/raytrace.cl"
#include "common/sphere_maps.cl"

#define DM_FRAME 4
#define DM_EMPTY 0x7F800000u /* +inf */
#define DM_MAX_SLOPE 32.0f   /* tan(theta) cap of the slope-scaled bias (88.2 degrees) */
#define DM_LOBE_CULL 1e-3f   /* a cap whose nearest point sees below this share of the lobe's peak is skipped */

#define DM_SPECULAR_POINT 0
#define DM_SPECULAR_SEED 1
#define DM_SPECULAR_CAP 2
#define DM_SPECULAR_TABLE 3

/* The table of exact cap averages (capi/src/methods/depthmap_table.[ch], PN_DM_TABLE_*). */
#define DM_TABLE_R 48
#define DM_TABLE_D 64
#define DM_TABLE_N 32
#define DM_TABLE_N_MAX 1e6f
#define DM_TABLE_SPREAD 4.0f
#define DM_TABLE_PHONG_FLOATS (DM_TABLE_R * DM_TABLE_D * DM_TABLE_N)
/* Blinn-Phong's and GGX's tables after Phong's (PN_DM_LOBE_*): [family][c][phi_s][delta][rho] */
#define DM_LOBE_R 32
#define DM_LOBE_D 40
#define DM_LOBE_P 8
#define DM_LOBE_C 10
#define DM_LOBE_RHO_MAX 4096.0f
#define DM_LOBE_RHO_0 0.25f
#define DM_LOBE_DELTA_MAX 32.0f
#define DM_LOBE_C_MIN 0.01f
#define DM_LOBE_NEWTON 4 /* steps to the disk's point of least u */
#define DM_LOBE_CULL_U_BLINN 3.717f /* exp(-u^2 / 2) = DM_LOBE_CULL */
#define DM_LOBE_CULL_U_GGX 5.535f   /* (1 + u^2)^-2 = DM_LOBE_CULL */
#define DM_LOBE_J_MAX 4.0f /* the largest V.H / c taken (dm_lobe_average) */
#define DM_LOBE_TILT_MAX 0.35f /* the largest tilt of H from N (rad) at which dm_lobe_average evaluates K */
#define DM_LOBE_V 5 /* per entry: log G, the lobe-weighted centroid's x and y / c, the spreads of x and y / c */
#define DM_LOBE_FAMILY (DM_LOBE_V * DM_LOBE_R * DM_LOBE_D * DM_LOBE_P * DM_LOBE_C)

/* Clears every map to empty and the rasteriser's list of large triangles. */
kernel void depthmap_clear(global uint *depth, int count, global uint *large_count)
{
    int gid = get_global_id(0);
    if (gid < count)
        depth[gid] = DM_EMPTY;
    if (gid == 0)
        *large_count = 0u;
}

/* The slot of work-item gid in a dispatch over the texels of the maps drawn:
 * list_start[s] is the first texel of slot s (exclusive prefix sum of the
 * drawn maps' res^2, map_count + 1 entries); false past the last. */
inline bool dm_slot(global const uint *list_start, int map_count, int gid, int *slot)
{
    if (gid >= (int)list_start[map_count])
        return false;
    int lo = 0, hi = map_count - 1;
    while (lo < hi) {
        int mid = (lo + hi + 1) / 2;
        if ((int)list_start[mid] <= gid)
            lo = mid;
        else
            hi = mid - 1;
    }
    *slot = lo;
    return true;
}

/* Ray-cast maps: one closest-hit ray per texel centre, from just outside the
 * fitted box towards -d. One work-item per texel of every map drawn: `list`
 * holds the map_count domains that have a map (skip_power). */
kernel void depthmap_raycast(PN_SCENE_ARGS, global const float4 *frames, int map_count, global const uint2 *atlas,
                             global uint *depth, global const uint *list, global const uint *list_start)
{
    int gid = get_global_id(0);
    int slot = 0;
    if (!dm_slot(list_start, map_count, gid, &slot))
        return;
    int m = (int)list[slot], k = gid - (int)list_start[slot];
    int res = (int)atlas[m].y;
    int j = k / res, i = k - j * res;
    global const float4 *f = frames + DM_FRAME * m;
    float3 e1 = f[0].xyz, e2 = f[1].xyz, d = f[2].xyz;
    float extent = f[3].z, margin = 1e-3f * extent + 1e-6f;
    float u = f[0].w + ((float)i + 0.5f) * f[3].x, v = f[1].w + ((float)j + 0.5f) * f[3].y;
    float3 org = u * e1 + v * e2 + (f[2].w + margin) * d;
    pn_scene_view scene = pn_make_scene_view(tlas, instances, blas, tris, instance_count);
    pn_hit hit;
    uint z = DM_EMPTY;
    if (pn_trace(scene, org, -d, 0.0f, extent + 2.0f * margin, &hit, false))
        z = as_uint(fmax(hit.t - margin, 0.0f));
    depth[atlas[m].x + k] = z;
}

/* half_maps: the 16-bit copy of every map drawn, depth quantised to
 * q = rint(z / extent * DM_Q_MAX) (clamped to DM_Q_MAX), DM_Q_EMPTY where empty. */
#define DM_Q_MAX 65534.0f
#define DM_Q_EMPTY 65535
kernel void depthmap_pack16(global const uint *depth, global const float4 *frames, global const uint *list,
                            int map_count, global const uint2 *atlas, global const uint *list_start,
                            global ushort *out)
{
    int gid = get_global_id(0);
    int slot = 0;
    if (!dm_slot(list_start, map_count, gid, &slot))
        return;
    size_t at = (size_t)atlas[list[slot]].x + (size_t)(gid - (int)list_start[slot]);
    float z = as_float(depth[at]);
    float extent = frames[DM_FRAME * list[slot] + 3].z;
    out[at] = isinf(z) ? (ushort)DM_Q_EMPTY : (ushort)fmin(rint(z / extent * DM_Q_MAX), DM_Q_MAX);
}

/* Rasterised maps. A triangle's three vertices in map m: texel coordinates
 * q and depths z; false when it is degenerate in this projection. */
typedef struct {
    float2 q[3];
    float z[3];
    float inv_area;
    int i0, i1, j0, j1; /* texel bounding box, clipped to the map */
} dm_projected;

inline bool dm_project(global const float4 *tris, global const uint2 *ranges, global const uint *starts,
                       global const float4 *objects, int instance_total, int g, global const float4 *f, int res,
                       dm_projected *t)
{
    /* The instance holding triangle g: the last start <= g. */
    int lo = 0, hi = instance_total - 1;
    while (lo < hi) {
        int mid = (lo + hi + 1) / 2;
        if ((int)starts[mid] <= g)
            lo = mid;
        else
            hi = mid - 1;
    }
    uint k = ranges[lo].x + (uint)(g - (int)starts[lo]);
    global const float4 *rows = objects + 3 * lo;
    float3 e1 = f[0].xyz, e2 = f[1].xyz, d = f[2].xyz;
    float inv_du = 1.0f / f[3].x, inv_dv = 1.0f / f[3].y;
    for (int c = 0; c < 3; ++c) {
        float3 p = pn_xform_point(rows, pn_load3(tris + 3 * k + c));
        t->q[c] = (float2)((dot(p, e1) - f[0].w) * inv_du, (dot(p, e2) - f[1].w) * inv_dv);
        t->z[c] = f[2].w - dot(p, d);
    }
    float area = (t->q[1].x - t->q[0].x) * (t->q[2].y - t->q[0].y) - (t->q[2].x - t->q[0].x) * (t->q[1].y - t->q[0].y);
    if (!(fabs(area) > 0.0f))
        return false; /* zero-area (or NaN) in this projection: covers no texel centre */
    t->inv_area = 1.0f / area;
    t->i0 = max((int)floor(fmin(t->q[0].x, fmin(t->q[1].x, t->q[2].x)) - 0.5f), 0);
    t->i1 = min((int)ceil(fmax(t->q[0].x, fmax(t->q[1].x, t->q[2].x)) - 0.5f), res - 1);
    t->j0 = max((int)floor(fmin(t->q[0].y, fmin(t->q[1].y, t->q[2].y)) - 0.5f), 0);
    t->j1 = min((int)ceil(fmax(t->q[0].y, fmax(t->q[1].y, t->q[2].y)) - 0.5f), res - 1);
    return t->i0 <= t->i1 && t->j0 <= t->j1;
}

/* Texel (i, j) takes the triangle's depth at its centre when covered. */
inline void dm_texel(const dm_projected *t, int i, int j, int res, volatile global uint *map)
{
    float x = (float)i + 0.5f, y = (float)j + 0.5f;
    /* Barycentric weights of the texel centre; inside when all >= 0. */
    float w1 = ((x - t->q[0].x) * (t->q[2].y - t->q[0].y) - (t->q[2].x - t->q[0].x) * (y - t->q[0].y)) * t->inv_area;
    float w2 = ((t->q[1].x - t->q[0].x) * (y - t->q[0].y) - (x - t->q[0].x) * (t->q[1].y - t->q[0].y)) * t->inv_area;
    float w0 = 1.0f - w1 - w2;
    if (w0 < 0.0f || w1 < 0.0f || w2 < 0.0f)
        return;
    float zz = fmax(w0 * t->z[0] + w1 * t->z[1] + w2 * t->z[2], 0.0f);
    atomic_min(map + j * res + i, as_uint(zz));
}

/* One work-item per (triangle, map drawn: `list` holds the map_count domains
 * that have one). `ranges`: per instance the first
 * triangle in `tris` and the count; `objects`: per instance its
 * object-to-world rows (3 float4); `starts`: the exclusive prefix sum of the
 * counts. A triangle covering more than DM_LARGE texels of bounding box goes
 * to the `large` list (map, triangle) for depthmap_raster_large, where a
 * whole work-group shares it; when the list is full it is drawn here. */
#define DM_LARGE 256
kernel void depthmap_raster(global const float4 *tris, global const uint2 *ranges, global const uint *starts,
                            global const float4 *objects, int instance_total, int triangle_total,
                            global const float4 *frames, int map_count, global const uint2 *atlas,
                            volatile global uint *depth, volatile global uint *large_count, global uint2 *large,
                            int large_capacity, global const uint *list)
{
    int gid = get_global_id(0);
    if (gid >= triangle_total * map_count)
        return;
    int slot = gid / triangle_total, g = gid - slot * triangle_total;
    int m = (int)list[slot], res = (int)atlas[m].y;
    dm_projected t;
    if (!dm_project(tris, ranges, starts, objects, instance_total, g, frames + DM_FRAME * m, res, &t))
        return;
    if ((t.i1 - t.i0 + 1) * (t.j1 - t.j0 + 1) > DM_LARGE) {
        uint slot = atomic_inc(large_count);
        if (slot < (uint)large_capacity) {
            large[slot] = (uint2)((uint)m, (uint)g);
            return;
        }
    }
    volatile global uint *map = depth + atlas[m].x;
    for (int j = t.j0; j <= t.j1; ++j)
        for (int i = t.i0; i <= t.i1; ++i)
            dm_texel(&t, i, j, res, map);
}

/* The large triangles: work-groups take list entries in turn, and the
 * work-items of a group split the entry's bounding box, so every lane of a
 * group does the same amount of work. */
kernel void depthmap_raster_large(global const float4 *tris, global const uint2 *ranges, global const uint *starts,
                                  global const float4 *objects, int instance_total, global const float4 *frames,
                                  global const uint2 *atlas, volatile global uint *depth, global const uint *large_count,
                                  global const uint2 *large, int large_capacity)
{
    uint count = min(*large_count, (uint)large_capacity);
    int lid = get_local_id(0), lsize = get_local_size(0);
    for (uint e = get_group_id(0); e < count; e += get_num_groups(0)) {
        uint2 entry = large[e];
        int res = (int)atlas[entry.x].y;
        dm_projected t;
        if (!dm_project(tris, ranges, starts, objects, instance_total, (int)entry.y, frames + DM_FRAME * entry.x,
                        res, &t))
            continue;
        volatile global uint *map = depth + atlas[entry.x].x;
        int w = t.i1 - t.i0 + 1, texels = w * (t.j1 - t.j0 + 1);
        for (int k = lid; k < texels; k += lsize)
            dm_texel(&t, t.i0 + k % w, t.j0 + k / w, res, map);
    }
}

/* Visibility of p along map m's direction: the share of the (2 pcf + 1)^2
 * texels around p's texel whose stored depth is not in front of p by more
 * than the bias. Outside the footprint nothing of the scene lies between p
 * and the light: visible. */
inline float dm_visibility(global const float4 *f, global const uint *map, global const ushort *map16, int res,
                           float3 p, float bias, int pcf, float2 grad)
{
    float quantum = f[3].z / DM_Q_MAX; /* 16-bit maps: depth of one step */
    float tu = (dot(p, f[0].xyz) - f[0].w) / f[3].x, tv = (dot(p, f[1].xyz) - f[1].w) / f[3].y;
    float z0 = f[2].w - dot(p, f[2].xyz) - bias;
    if (!(tu >= 0.0f && tv >= 0.0f && tu < (float)res && tv < (float)res))
        return 1.0f;
    int ci = (int)tu, cj = (int)tv;
    int lit = 0, taps = 0;
    /* receiver_plane: the receiver's depth at each tap's texel centre along
     * its tangent plane (grad: depth per texel along u and v; 0 otherwise) */
    float gu = grad.x, gv = grad.y;
    for (int dj = -pcf; dj <= pcf; ++dj) {
        int j = cj + dj;
        for (int di = -pcf; di <= pcf; ++di) {
            int i = ci + di;
            float z = z0 + gu * ((float)i + 0.5f - tu) + gv * ((float)j + 0.5f - tv);
            ++taps;
            if (i < 0 || j < 0 || i >= res || j >= res)
                ++lit;
            else if (map16) {
                ushort q = map16[j * res + i];
                if (q == DM_Q_EMPTY || z <= (float)q * quantum)
                    ++lit;
            } else if (z <= as_float(map[j * res + i]))
                ++lit;
        }
    }
    return (float)lit / (float)taps;
}

/* soft_shadows (docs/depthmap.md, "Penumbrae from the cap: soft_shadows"):
 * a percentage-closer soft shadow of the domain's cap. The blocker search
 * averages the depths in front of p over the disc a blocker can hide part
 * of the cap from (radius z tan r: a blocker at depth 0), then the cap seen
 * from p through the blockers' plane is a disc of radius (z - z_blocker)
 * tan r, and v is the share of taps in that disc that are lit. Both discs
 * are clamped to DM_SOFT_MAX texels and sampled on a grid of (2K + 1)^2
 * points (K = ceil(radius) up to DM_SOFT_STEPS), nearest texel each. */
#define DM_SOFT_MAX 8.0f
#define DM_SOFT_STEPS 3

/* The stored depth of texel (i, j), +inf when empty or off the map. */
inline float dm_depth(global const uint *map, global const ushort *map16, float quantum, int res, int i, int j)
{
    if (i < 0 || j < 0 || i >= res || j >= res)
        return INFINITY;
    if (map16) {
        ushort q = map16[j * res + i];
        return q == DM_Q_EMPTY ? INFINITY : (float)q * quantum;
    }
    return as_float(map[j * res + i]);
}

inline float dm_soft_visibility(global const float4 *f, global const uint *map, global const ushort *map16, int res,
                                float3 p, float bias_constant, float bias_slope, float tan_theta, float tan_r)
{
    float quantum = f[3].z / DM_Q_MAX;
    float texel = fmax(f[3].x, f[3].y);
    float tu = (dot(p, f[0].xyz) - f[0].w) / f[3].x, tv = (dot(p, f[1].xyz) - f[1].w) / f[3].y;
    float z0 = f[2].w - dot(p, f[2].xyz);
    /* blocker search, with the bias of a one-texel lookup */
    float zs = z0 - texel * (bias_constant + bias_slope * tan_theta);
    float ws = fmin(fmax(z0, 0.0f) * tan_r / texel, DM_SOFT_MAX);
    /* a penumbra reaches ws beyond the footprint (fit covers the hard shadows), no further */
    float edge = ws + 1.0f;
    if (!(tu >= -edge && tv >= -edge && tu < (float)res + edge && tv < (float)res + edge))
        return 1.0f;
    int ks = clamp((int)ceil(ws), 1, DM_SOFT_STEPS);
    float hs = ws / (float)ks, blockers = 0.0f, depth_sum = 0.0f;
    for (int dj = -ks; dj <= ks; ++dj)
        for (int di = -ks; di <= ks; ++di) {
            if (di * di + dj * dj > ks * ks)
                continue;
            float d = dm_depth(map, map16, quantum, res, (int)floor(tu + (float)di * hs),
                               (int)floor(tv + (float)dj * hs));
            if (d < zs) {
                blockers += 1.0f;
                depth_sum += d;
            }
        }
    if (blockers == 0.0f)
        return 1.0f;
    /* the cap through the blockers' plane: its radius in texels */
    float w = fmin(fmax(zs - depth_sum / blockers, 0.0f) * tan_r / texel, DM_SOFT_MAX);
    float z = z0 - texel * (bias_constant + bias_slope * (w + 1.0f) * tan_theta);
    int k = clamp((int)ceil(w), 1, DM_SOFT_STEPS);
    float h = w / (float)k;
    int lit = 0, taps = 0;
    for (int dj = -k; dj <= k; ++dj)
        for (int di = -k; di <= k; ++di) {
            if (di * di + dj * dj > k * k)
                continue;
            ++taps;
            if (z <= dm_depth(map, map16, quantum, res, (int)floor(tu + (float)di * h), (int)floor(tv + (float)dj * h)))
                ++lit;
        }
    return (float)lit / (float)taps;
}

/* The seed's average of cos^n psi over a cap of radius r whose centre is
 * psi_c from R (docs/depthmap.md): inside the cap the exact value at
 * psi_c = 0 blended toward the point sample, beyond it the point sample. */
inline float dm_seed_blend(float cos_psi_c, float cos_r, float n)
{
    float point = pn_pow0(cos_psi_c, n);
    if (cos_psi_c <= cos_r)
        return point;
    float one_minus_cos_r = 1.0f - cos_r;
    float a0 = (1.0f - pn_pow0(cos_r, n + 1.0f)) / ((n + 1.0f) * one_minus_cos_r);
    return a0 * (cos_psi_c - cos_r) / one_minus_cos_r + point * (1.0f - cos_psi_c) / one_minus_cos_r;
}

/* Average of f_lobe(l) max(0, n.l) over the cap of radius r around d by
 * `samples` equal-area points (rings of equal solid angle, golden-angle
 * azimuths); the same points as depthmap64.cap_points. */
inline float dm_cap_lobe(pn_material m, float3 n, float3 v, float3 d, float one_minus_cos_r, int samples)
{
    float3 t, b;
    pn_frame(d, &t, &b);
    float sum = 0.0f;
    for (int k = 0; k < samples; ++k) {
        float u = one_minus_cos_r * ((float)k + 0.5f) / (float)samples; /* 1 - cos(beta) */
        float sb = sqrt(fmax(u * (2.0f - u), 0.0f));
        float a = 2.39996322972865332f * (float)k;
        float3 l = (sb * cos(a)) * t + (sb * sin(a)) * b + (1.0f - u) * d;
        float nl = dot(n, l);
        if (nl > 0.0f)
            sum += pn_brdf_lobe(m, n, v, l, nl) * nl;
    }
    return sum / (float)samples;
}

/* The lobe times the cosine at l (0 below the horizon or where the lobe is not positive). */
inline float dm_lobe_cosine(pn_material m, float3 n, float3 v, float3 l)
{
    float nl = dot(n, l);
    if (!(nl > 0.0f))
        return 0.0f;
    float f = pn_brdf_lobe(m, n, v, l, nl) * nl;
    return f > 0.0f ? f : 0.0f;
}

inline float dm_edge_t(float delta) { return delta / (fabs(delta) + DM_TABLE_SPREAD); }

/* H(r, psi_c, n): the exact average of max(0, cos psi)^n (psi from the
 * lobe's axis R) over a cap of radius r whose centre is psi_c from R, over
 * its value at the cap's point nearest R; trilinear in the table's grid
 * (depthmap_table.c: x from r / sigma, y from the signed distance to the
 * cap's edge in lobe widths sigma = 1 / sqrt(n + 1), z = log n). */
inline float dm_cap_ratio(global const float *table, float r, float psi_c, float n)
{
    float sigma = rsqrt(n + 1.0f);
    float t0 = dm_edge_t(-r / sigma), t1 = dm_edge_t(M_PI_2_F / sigma);
    float x = clamp(log1p(r / sigma) / log1p(M_PI_F / sigma), 0.0f, 1.0f) * (float)(DM_TABLE_R - 1);
    float y = clamp((dm_edge_t((psi_c - r) / sigma) - t0) / (t1 - t0), 0.0f, 1.0f) * (float)(DM_TABLE_D - 1);
    float z = clamp(log(n) / log(DM_TABLE_N_MAX), 0.0f, 1.0f) * (float)(DM_TABLE_N - 1);
    int i = min((int)x, DM_TABLE_R - 2), j = min((int)y, DM_TABLE_D - 2), k = min((int)z, DM_TABLE_N - 2);
    float ax = x - (float)i, ay = y - (float)j, az = z - (float)k;
    float w = 0.0f;
    for (int dk = 0; dk < 2; ++dk)
        for (int dj = 0; dj < 2; ++dj) {
            global const float *row = table + ((k + dk) * DM_TABLE_D + j + dj) * DM_TABLE_R + i;
            w += (dk ? az : 1.0f - az) * (dj ? ay : 1.0f - ay) * mix(row[0], row[1], ax);
        }
    float s = sin(0.5f * r);
    return w / (1.0f + (n + 1.0f) * 2.0f * s * s); /* the table stores H (1 + (n + 1)(1 - cos r)) */
}

/* The direction at the tangent offset (px, py) (radians, along ex and ey) from R, by the exponential map. */
inline float3 dm_tangent_point(float3 refl, float3 ex, float3 ey, float px, float py)
{
    float3 t = px * ex + py * ey;
    float tl = length(t);
    return tl > 0.0f ? cos(tl) * refl + sin(tl) * (t / tl) : refl;
}

/* log of the lobe profile at u^2: Blinn-Phong -u^2 / 2, GGX -2 log(1 + u^2) */
inline float dm_lobe_log(int family, float u2) { return family == 0 ? -0.5f * u2 : -2.0f * log1p(u2); }

/* Blinn-Phong (family 0, s = 2 / sqrt(n)) and GGX (family 1, s = 2 alpha):
 * the lobe times the cosine averaged over the cap (d, r), per unit k_s. About R
 * the lobe depends on u = |(x, y / c)| / s, (x, y) the tangent offset from R in
 * and across the plane of N and R, c = N.V (depthmap_table.c); in units of s
 * the cap is a disk of radius rho = r / s. The table gives, quadrilinearly, G
 * (the profile Lambda's disk average over its value at the disk's point of
 * least u, u*), the lobe-weighted centroid of the disk in the round metric
 * (x, y / c) and the spreads of x and y / c; the rest of the integrand, K
 * (below), is averaged by four points at the centroid +- the spreads:
 *   a = G Lambda(u*) pi r^2 / (2 pi (1 - cos r)) mean K. */
inline float dm_lobe_average(global const float *table, pn_material m, float3 n, float3 v, float3 refl, float3 d,
                             float psi_c, float r, int centroid)
{
    int family = m.lobe == PN_LOBE_BLINN_PHONG ? 0 : 1;
    float s = family == 0 ? 2.0f * rsqrt(m.shininess) : 2.0f * m.roughness;
    float c = clamp(dot(n, v), DM_LOBE_C_MIN, 1.0f);
    float3 ex = (float3)(1.0f, 0.0f, 0.0f), ey = cross(n, refl);
    float bx = 1.0f, by = 0.0f; /* d's tangent components at R along x and y */
    float ly = length(ey);
    if (ly > 1e-6f) {
        ey /= ly;
        ex = cross(ey, refl);
        bx = dot(d, ex);
        by = dot(d, ey);
    } else { /* N along R (c = 1, a round lobe): any tangent frame */
        pn_frame(refl, &ex, &ey);
        bx = dot(d, ex);
        by = dot(d, ey);
    }
    float bl = hypot(bx, by);
    float ax = bl > 0.0f ? fabs(bx) / bl : 1.0f, ay = bl > 0.0f ? fabs(by) / bl : 0.0f;
    /* u is at least the plain distance in units of s: a cap whose nearest point is DM_LOBE_CULL_U lobe widths
     * from R sees below DM_LOBE_CULL of the lobe's peak (the quadrature's dm_lobe_reaches), and is skipped */
    if (psi_c - r > (family == 0 ? DM_LOBE_CULL_U_BLINN : DM_LOBE_CULL_U_GGX) * s)
        return 0.0f;
    float gamma = hypot(ax, ay / c);
    float gd = psi_c - r;
    float rho = r / s, delta_u = gd / s * gamma, phi_s = atan2(ay, c * ax);
    /* u*: on the disk's edge where x^2 + (y / c)^2 is least (safeguarded Newton on the edge's angle tau);
     * 0 when R is inside */
    float log_ref = 0.0f, f_near = 0.0f;
    float3 l_near = refl;
    if (gd > 0.0f) {
        float x0 = psi_c / s * ax, y0 = psi_c / s * ay, ic2 = 1.0f / (c * c);
        float lo = M_PI_F, hi = 1.5f * M_PI_F, tau = atan2(-y0, -x0) + 2.0f * M_PI_F, ct, st;
        for (int it = 0; it < DM_LOBE_NEWTON; ++it) {
            st = sincos(tau, &ct);
            float px = x0 + rho * ct, py = y0 + rho * st;
            float fp = -px * st + py * ct * ic2; /* d/dtau of (px^2 + py^2 / c^2) / (2 rho) */
            float fpp = rho * st * st - px * ct + (rho * ct * ct - py * st) * ic2;
            if (fp > 0.0f)
                hi = tau;
            else
                lo = tau;
            float next = tau - fp / fpp;
            tau = fpp > 0.0f && next >= lo && next <= hi ? next : 0.5f * (lo + hi);
        }
        st = sincos(tau, &ct);
        float px = x0 + rho * ct, py = y0 + rho * st;
        log_ref = dm_lobe_log(family, px * px + py * py * ic2);
        l_near = dm_tangent_point(refl, ex, ey, copysign(px * s, bx), copysign(py * s, by));
    }
    if (!centroid) { /* lobe_centroid 0: the rest of the integrand at u*'s direction alone */
        f_near = dm_lobe_cosine(m, n, v, l_near);
        if (!(f_near > 0.0f))
            return 0.0f;
    }
    float t0 = dm_edge_t(-rho * gamma), t1 = dm_edge_t(DM_LOBE_DELTA_MAX);
    float x = clamp(log1p(rho / DM_LOBE_RHO_0) / log1p(DM_LOBE_RHO_MAX / DM_LOBE_RHO_0), 0.0f, 1.0f) * (float)(DM_LOBE_R - 1);
    float y = clamp((dm_edge_t(delta_u) - t0) / (t1 - t0), 0.0f, 1.0f) * (float)(DM_LOBE_D - 1);
    float p = clamp(phi_s * M_2_PI_F, 0.0f, 1.0f) * (float)(DM_LOBE_P - 1);
    float q = clamp(log(c) / log(DM_LOBE_C_MIN), 0.0f, 1.0f) * (float)(DM_LOBE_C - 1);
    int i = min((int)x, DM_LOBE_R - 2), j = min((int)y, DM_LOBE_D - 2), k = min((int)p, DM_LOBE_P - 2),
        w = min((int)q, DM_LOBE_C - 2);
    float ai = x - (float)i, aj = y - (float)j, ak = p - (float)k, aw = q - (float)w;
    global const float *base = table + family * DM_LOBE_FAMILY;
    float4 g = (float4)(0.0f); /* log G, the centroid's x and y / c, x's spread, in units of s */
    float gsy = 0.0f;          /* the spread of y / c */
    for (int dw = 0; dw < 2; ++dw)
        for (int dk = 0; dk < 2; ++dk)
            for (int dj = 0; dj < 2; ++dj) {
                global const float *row =
                    base + DM_LOBE_V * ((((w + dw) * DM_LOBE_P + k + dk) * DM_LOBE_D + j + dj) * DM_LOBE_R + i);
                float wt = (dw ? aw : 1.0f - aw) * (dk ? ak : 1.0f - ak) * (dj ? aj : 1.0f - aj);
                g += wt * mix(vload4(0, row), vload4(0, row + DM_LOBE_V), ai);
                gsy += wt * mix(row[4], row[DM_LOBE_V + 4], ai);
            }
    float h = 0.5f * r, sh = sin(h);
    float area = sh > 0.0f ? (h * h) / (sh * sh) : 1.0f; /* the disk's area pi r^2 over the cap's */
    if (!centroid)
        return f_near * exp(fmin(g.x, 0.0f)) * area;
    /* The rest of the integrand, K = f_lobe(L) (n.L) min(V.H / c, J_MAX) / Lambda(|P|), by the half vector H:
     * a point P of the model's round plane is H turned from N by s |P| / 2 (x in the plane of incidence,
     * along hx, y across it, along ey), L = 2 (V.H) H - V, and V.H / c the Jacobian of L over the model's.
     * K is nearly quadratic in P (the cosine n.L and V.H are each linear in x; G1), so its lobe-weighted
     * mean is that of the four points (centroid +- spreads): exact for K quadratic in x and y. */
    float3 hx = cross(ey, n);
    float mx = bx < 0.0f ? -g.y : g.y, my = by < 0.0f ? -fabs(g.z) : fabs(g.z), sx = fmax(g.w, 0.0f);
    /* The horizon n.L = 0 cuts x at about x_h = c / (s sin theta_v) (n.L ~ c - s sin theta_v x): the points
     * are taken in x's part below x_h, as a normal distribution of x (mean mx, spread sx) truncated there,
     * weighted by its mass p. */
    float sin_v = sqrt(fmax(1.0f - c * c, 0.0f)), p_mass = 1.0f;
    if (sx > 0.0f && sin_v > 0.0f) {
        float z = (c / (s * sin_v) - mx) / sx;
        if (z < 6.0f) {
            if (z < -9.0f)
                return 0.0f;
            p_mass = 0.5f * erfc(-z * M_SQRT1_2_F);
            float lam = 0.3989422804f * exp(-0.5f * z * z) / p_mass; /* phi(z) / Phi(z) */
            mx -= sx * lam;
            sx *= sqrt(fmax(1.0f - z * lam - lam * lam, 0.0f));
        }
    }
    float sy = fmax(gsy, 0.0f), kk = 0.0f;
    for (int corner = 0; corner < 4; ++corner) {
        float qx = mx + ((corner & 1) ? sx : -sx), qy = my + ((corner & 2) ? sy : -sy), ql = hypot(qx, qy);
        if (0.5f * s * ql > DM_LOBE_TILT_MAX) { /* beyond the model's small angles (GGX's far tail): pulled in */
            float pull = DM_LOBE_TILT_MAX / (0.5f * s * ql);
            qx *= pull;
            qy *= pull;
            ql *= pull;
        }
        float th = 0.5f * s * ql;
        float3 hv = ql > 0.0f ? cos(th) * n + sin(th) * ((qx / ql) * hx + (qy / ql) * ey) : n;
        float vh = dot(v, hv);
        if (!(vh > 0.0f))
            continue;
        float3 l = 2.0f * vh * hv - v;
        float f = dm_lobe_cosine(m, n, v, l);
        if (f > 0.0f)
            kk += f * fmin(vh / c, DM_LOBE_J_MAX) * exp(fmin(log_ref - dm_lobe_log(family, ql * ql), 80.0f));
    }
    kk *= 0.25f * p_mass; /* the four points' mean, times the mass above the horizon */
    if (!(kk > 0.0f))
        return 0.0f;
    return kk * exp(fmin(g.x, 0.0f)) * area;
}

/* The lobe times the cosine averaged over the cap (d, r) by the tables:
 * Phong's cap average over its value at the cap's point l nearest R (R
 * itself when inside) times the true lobe and cosine at l (exact but for the
 * cosine, taken at l); Blinn-Phong and GGX by their own tables with the view
 * (dm_lobe_average). n_eq (Phong: n; Blinn-Phong: n / 4, the half angle; GGX:
 * 1 / (2 alpha^2), the Gaussian of the same integral) decides against min_n
 * whether the table is used. Returns -1 for the anisotropic lobe and when
 * n_eq is below min_n (at least 1, the Phong table's range): the caller uses the quadrature. */
inline float dm_table_lobe(global const float *table, pn_material m, float3 n, float3 v, float3 refl, float3 d,
                           float r, float min_n, int lobe_tables)
{
    /* The anisotropic lobe has no equivalent exponent: the quadrature samples it;
       so do Blinn-Phong and GGX when their tables were not built (lobe_tables: bit 0 Blinn-Phong's, bit 1 GGX's;
       bit 2 the four-point rule of lobe_centroid 1). */
    if (m.lobe == PN_LOBE_ASHIKHMIN_SHIRLEY ||
        (m.lobe != PN_LOBE_PHONG && !(lobe_tables & (m.lobe == PN_LOBE_BLINN_PHONG ? 1 : 2))))
        return -1.0f;
    float n_eq = m.lobe == PN_LOBE_PHONG         ? m.shininess
                 : m.lobe == PN_LOBE_BLINN_PHONG ? 0.25f * m.shininess
                                                 : 0.5f / (m.roughness * m.roughness);
    if (!(n_eq >= fmax(min_n, 1.0f)))
        return -1.0f;
    float c = dot(refl, d);
    float3 side = refl - c * d;
    float sl = length(side);
    float psi_c = atan2(sl, c); /* accurate near 0, unlike acos */
    if (m.lobe != PN_LOBE_PHONG) /* Blinn-Phong and GGX: their own tables, with the view */
        return dm_lobe_average(table + DM_TABLE_PHONG_FLOATS, m, n, v, refl, d, psi_c, r, lobe_tables & 4);
    float3 l = refl;
    if (psi_c > r)
        l = cos(r) * d + sin(r) * (side / sl); /* psi_c > r >= 0: sl > 0 */
    float f = dm_lobe_cosine(m, n, v, l);
    if (!(f > 0.0f))
        return 0.0f;
    return f * dm_cap_ratio(table, r, psi_c, n_eq);
}

/* Whether any of the lobe can reach the cap: the lobe at the cap's point
 * nearest to the reflection direction R against its value at R. */
inline bool dm_lobe_reaches(pn_material m, float3 n, float3 v, float3 refl, float3 d, float cos_r)
{
    /* The anisotropic lobe does not fall off with the distance to R alike in
     * every direction: the nearest point bounds nothing, sample. */
    if (m.lobe == PN_LOBE_ASHIKHMIN_SHIRLEY)
        return true;
    float c = dot(refl, d);
    if (c >= cos_r)
        return true; /* R inside the cap */
    /* Rotate d towards R by the cap radius. */
    float3 side = refl - c * d;
    float sl = length(side);
    if (!(sl > 0.0f))
        return true;
    float sin_r = sqrt(fmax(1.0f - cos_r * cos_r, 0.0f));
    float3 near = cos_r * d + sin_r * (side / sl);
    float nl = dot(n, near), nr = dot(n, refl);
    if (!(nr > 0.0f))
        return true; /* R under the horizon: no cheap bound, sample */
    if (!(nl > 0.0f))
        return false;
    return pn_brdf_lobe(m, n, v, near, nl) * nl >= DM_LOBE_CULL * pn_brdf_lobe(m, n, v, refl, nr) * nr;
}

/* One work-item per pixel. `domains`: 2 float4 each (pn_env_domain: direction,
 * solid angle | radiance, cap radius); `frames`, `depth`, `atlas`: the maps (none when
 * use_maps is 0: every domain visible). bias: in texels, constant and slope
 * terms; specular: DM_SPECULAR_*; the first soft_count domains are looked up
 * by dm_soft_visibility (soft_shadows), the others by dm_visibility (pcf). */
kernel void shade_depthmap(global const float4 *position, global const float4 *normal, global const float4 *albedo,
                           global const float4 *material, global const uint *instance_id, int count, float4 camera,
                           global const float4 *domains, int domain_count, global const float4 *frames,
                           global const uint *depth, global const uint2 *atlas, int use_maps, float bias_constant, float bias_slope,
                           int pcf, int specular, int cap_samples, global float4 *image,
                           global const ushort *depth16, int half_maps, global const float *cap_table,
                           float table_min_n, int lobe_tables, int soft_count, int receiver_plane)
{
    int gid = get_global_id(0);
    if (gid >= count)
        return;
    if (instance_id[gid] == PN_BACKGROUND) { /* drawn by the renderer's background pass */
        image[gid] = (float4)(0.0f);
        return;
    }
    float3 p = position[gid].xyz;
    float3 n = normalize(normal[gid].xyz);
    float3 v = normalize(camera.xyz - p);
    pn_material m = pn_material_from_gbuffer(albedo[gid], material[gid]);
    float3 refl = 2.0f * dot(n, v) * n - v;
    bool spec = m.ks > 0.0f;
    float3 sum = (float3)(0.0f);
    for (int i = 0; i < domain_count; ++i) {
        float4 dir = domains[2 * i], rad = domains[2 * i + 1];
        float3 d = dir.xyz;
        float c = dot(n, d);
        if (c <= 0.0f)
            continue; /* the centre below the horizon: the seed's rule, no lookup */
        float vis = 1.0f;
        global const float4 *f = frames + DM_FRAME * i;
        if (use_maps && f[3].w != 0.0f) { /* a domain without a map (skip_power) is lit unshadowed */
            float tan_theta = fmin(sqrt(fmax(1.0f - c * c, 0.0f)) / c, DM_MAX_SLOPE);
            float texel = fmax(f[3].x, f[3].y);
            /* a diagonal PCF tap is up to sqrt(2) pcf + 0.71 texels from p: the slope term covers it, or
             * (receiver_plane) the receiver's tangent plane gives each tap's own depth, and the constant
             * term alone covers rounding and the surface's curvature within a texel */
            float2 grad = (float2)(0.0f);
            float bias;
            if (receiver_plane) {
                float cd = fmax(c, 1.0f / DM_MAX_SLOPE); /* |grad| = tan(theta), capped like the bias */
                grad = (float2)(dot(n, f[0].xyz) * f[3].x, dot(n, f[1].xyz) * f[3].y) / cd;
                bias = texel * bias_constant;
            } else {
                bias = texel * (bias_constant + bias_slope * (M_SQRT2_F * (float)pcf + 1.0f) * tan_theta);
            }
            uint2 where = atlas[i]; /* the map's first texel and side */
            global const ushort *map16 = half_maps ? depth16 + where.x : (global const ushort *)0;
            if (i < soft_count) /* soft_shadows: the cap's penumbra */
                vis = dm_soft_visibility(f, depth + where.x, map16, (int)where.y, p, bias_constant, bias_slope,
                                         tan_theta, tan(fmin(rad.w, 1.5f)));
            else
                vis = dm_visibility(f, depth + where.x, map16, (int)where.y, p, bias, pcf, grad);
            if (vis == 0.0f)
                continue;
        }
        float a = 0.0f; /* the lobe's average times the cosine, per unit k_s */
        if (spec) {
            a = specular == DM_SPECULAR_TABLE ? dm_table_lobe(cap_table, m, n, v, refl, d, rad.w, table_min_n, lobe_tables)
                                                : -1.0f;
            if (a >= 0.0f) {
                /* the table's value */
            } else if (specular >= DM_SPECULAR_CAP) { /* the quadrature, and the table's broad lobes */
                float cos_r = cos(rad.w);
                a = 0.0f;
                if (dm_lobe_reaches(m, n, v, refl, d, cos_r))
                    a = dm_cap_lobe(m, n, v, d, 1.0f - cos_r, cap_samples);
            } else if (specular == DM_SPECULAR_SEED && m.lobe == PN_LOBE_PHONG) {
                a = (m.shininess + 2.0f) * PN_INV_TWO_PI * dm_seed_blend(dot(refl, d), cos(rad.w), m.shininess) * c;
            } else {
                a = pn_brdf_lobe(m, n, v, d, c) * c;
            }
        }
        sum += vis * rad.xyz * (m.albedo * (PN_INV_PI * c) + m.ks * a);
    }
    image[gid] = (float4)(fmax(sum, 0.0f), 1.0f);
}
