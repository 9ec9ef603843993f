/* Env map decomposition (core/env_domains.c, docs/depthmap.md): every
 * lat-long texel to its nearest domain centre, the spherical Voronoi by
 * texels that Lloyd's relaxation repeats. */

/* Work-items per group (a power of two: the reduction halves it). */
#define PN_ENV_GROUP 64
/* Most centres (PN_ENV_DOMAINS_MAX in core/core.h). */
#define PN_ENV_MAX_CENTRES 1024
/* Angle added to the culling bound: a float dot product near 1 is off by
 * ~2e-7, which acos turns into up to ~6e-4 rad; a wider margin only keeps
 * more candidates, never loses the nearest one. */
#define PN_ENV_CULL_MARGIN 2e-3f

/* One work-group per tile of texels (tile_w x tile_h of the W-wide map,
 * tiles row-major); cones[t] = (axis, beta) bounds the tile's texel
 * directions: each is within beta of the unit axis. A centre at angle
 * theta_c from the axis is at least theta_c - beta from every texel; the
 * centre nearest the axis (theta*) is at most theta* + beta from every texel;
 * so only centres with theta_c <= theta* + 2 beta can be the nearest of some
 * texel: they are gathered first, then each texel picks among them the
 * largest dot product, ties to the lowest index (tests/depthmap64.py nearest). */
kernel void env_domains_assign(global const float4 *texel_dirs, int width, int height, int tile_w, int tile_h,
                               global const float4 *cones, global const float4 *centres, int count,
                               global int *assignment)
{
    local float best_dot[PN_ENV_GROUP];
    local float4 cand_dir[PN_ENV_MAX_CENTRES];
    local int cand_index[PN_ENV_MAX_CENTRES];
    local int cand_count;
    const int lid = get_local_id(0), tile = get_group_id(0);
    const int tiles_x = (width + tile_w - 1) / tile_w;
    const int x0 = (tile % tiles_x) * tile_w, y0 = (tile / tiles_x) * tile_h;
    const float4 cone = cones[tile];
    const float3 axis = cone.xyz;

    float best = -2.0f;
    for (int k = lid; k < count; k += PN_ENV_GROUP)
        best = fmax(best, dot(axis, centres[k].xyz));
    best_dot[lid] = best;
    if (lid == 0)
        cand_count = 0;
    barrier(CLK_LOCAL_MEM_FENCE);
    for (int step = PN_ENV_GROUP / 2; step > 0; step >>= 1) {
        if (lid < step)
            best_dot[lid] = fmax(best_dot[lid], best_dot[lid + step]);
        barrier(CLK_LOCAL_MEM_FENCE);
    }
    const float limit = acos(clamp(best_dot[0], -1.0f, 1.0f)) + 2.0f * cone.w + PN_ENV_CULL_MARGIN;
    for (int k = lid; k < count; k += PN_ENV_GROUP) {
        float4 c = centres[k];
        if (acos(clamp(dot(axis, c.xyz), -1.0f, 1.0f)) <= limit) {
            int slot = atomic_inc(&cand_count);
            cand_dir[slot] = c;
            cand_index[slot] = k;
        }
    }
    barrier(CLK_LOCAL_MEM_FENCE);

    const int w = min(tile_w, width - x0), h = min(tile_h, height - y0), n = cand_count;
    for (int t = lid; t < w * h; t += PN_ENV_GROUP) {
        const int texel = (y0 + t / w) * width + x0 + t % w;
        const float3 d = texel_dirs[texel].xyz;
        float top = -2.0f;
        int choice = 0x7fffffff;
        for (int q = 0; q < n; ++q) {
            float v = dot(d, cand_dir[q].xyz);
            if (v > top || (v == top && cand_index[q] < choice)) {
                top = v;
                choice = cand_index[q];
            }
        }
        assignment[texel] = choice;
    }
}
