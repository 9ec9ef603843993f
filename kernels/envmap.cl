/* Environment map stage: lat-long -> cube map, cube texel directions and
 * solid angles, and the irradiance cube map (docs/conventions.md). */
#include "common/sphere_maps.cl"

/* Radiance of lat-long texel containing direction d (box filter: the texel's
 * constant value over its footprint). */
inline float3 latlong_fetch(global const float *latlong, int width, int height, float3 d)
{
    float2 uv = pn_dir_to_latlong(d);
    int x = min((int)(uv.x * (float)width), width - 1);
    int y = min((int)(uv.y * (float)height), height - 1);
    global const float *p = latlong + 3 * (y * width + x);
    return (float3)(p[0], p[1], p[2]);
}

/* One work-item per cube texel (global size 6*n*n). The texel's radiance is
 * the solid-angle-weighted mean of the lat-long map over its footprint,
 * estimated on an s x s grid of sub-texels each weighted by its exact solid
 * angle (Gauss-Legendre for small sub-texels): it converges to the area
 * average as s grows; with the automatic s a sun keeps its power to ~1 %.
 * rot = (cos, sin) of the map's rotation about +y; the world direction d sees
 * the map at R_y(-angle) d. */
kernel void envmap_latlong_to_cube(global const float *latlong, int width, int height, int n, int s, float2 rot,
                                   float intensity, global float4 *cube)
{
    int gid = get_global_id(0);
    if (gid >= 6 * n * n)
        return;
    int face = gid / (n * n), j = (gid / n) % n, i = gid % n;
    float step = 2.0f / (float)n, sub = step / (float)s;
    float a0 = -1.0f + step * (float)i, b0 = -1.0f + step * (float)j;
    float3 sum = (float3)(0.0f);
    float weight = 0.0f;
    for (int sj = 0; sj < s; ++sj) {
        for (int si = 0; si < s; ++si) {
            float a = a0 + sub * (float)si, b = b0 + sub * (float)sj;
            float w = pn_cube_solid_angle(a, b, a + sub, b + sub);
            float3 d = normalize(pn_cube_to_dir(face, a + 0.5f * sub, b + 0.5f * sub));
            sum += w * latlong_fetch(latlong, width, height, pn_rotate_y(d, rot.x, -rot.y));
            weight += w;
        }
    }
    cube[gid] = (float4)(intensity * sum / weight, 0.0f);
}

/* The background of a rendered image: every background pixel (position.xyz
 * holds its view direction) gets the env map's radiance in that direction,
 * looked up bilinearly in the full-resolution lat-long map (not the cube,
 * whose face size is chosen for lighting and would show as blocks), with the
 * map's rotation and intensity, alpha 0. Other pixels are left alone. Run by
 * the renderer after every method that has the `background` parameter and
 * does not draw it in its own kernel (fiv does: pn_background8).
 * One work-item per 8 consecutive pixels (global size ceil(count / 8)): each
 * lane's direction normalised as one pixel's was, then its rotation and the
 * lookup's angles and indices in float8 lanes, one pixel per lane
 * (pn_latlong_bilinear8; the same bits as the scalar pass); a work-item with
 * no background pixel stops after reading the 8 ids. */
#define PN_BACKGROUND_LANES 8
kernel void envmap_background(global const float4 *position, global const uint *instance_id, int count,
                              global const float *latlong, int width, int height, float2 rot, float intensity,
                              global float4 *image)
{
    int base = get_global_id(0) * PN_BACKGROUND_LANES;
    if (base >= count)
        return;
    /* Each lane's direction goes into the lane vectors as elements, unrolled
     * (kept in registers: a lane array written one lane at a time and read
     * back as a vector stalls the load on the 8 stores). */
    int8 live8;
    float8 px, py, pz;
#define PN_BACKGROUND_LANE(l)                                                               \
    {                                                                                       \
        int gid = base + l;                                                                 \
        int bg = gid < count && instance_id[gid] == PN_BACKGROUND;                          \
        float3 p = bg ? normalize(position[gid].xyz) : (float3)(0.0f, 1.0f, 0.0f);          \
        live8.s##l = bg;                                                                    \
        px.s##l = p.x, py.s##l = p.y, pz.s##l = p.z;                                        \
    }
    PN_BACKGROUND_LANE(0) PN_BACKGROUND_LANE(1) PN_BACKGROUND_LANE(2) PN_BACKGROUND_LANE(3)
    PN_BACKGROUND_LANE(4) PN_BACKGROUND_LANE(5) PN_BACKGROUND_LANE(6) PN_BACKGROUND_LANE(7)
#undef PN_BACKGROUND_LANE
    if (!any(live8 != 0))
        return;
    int live[PN_BACKGROUND_LANES];
    vstore8(live8, 0, live);
    /* pn_rotate_y(d, rot.x, -rot.y) */
    float8 dx = rot.x * px + -rot.y * pz, dz = rot.y * px + rot.x * pz;
    float rgb[3 * PN_BACKGROUND_LANES];
    pn_latlong_bilinear8(latlong, width, height, dx, py, dz, live, rgb);
    for (int l = 0; l < PN_BACKGROUND_LANES; ++l)
        if (live[l])
            image[base + l] = (float4)(intensity * vload3(l, rgb), 0.0f);
}

/* Unit direction of each cube texel centre, w = its exact solid angle. */
kernel void envmap_cube_directions(int n, global float4 *dirs)
{
    int gid = get_global_id(0);
    if (gid >= 6 * n * n)
        return;
    int face = gid / (n * n), j = (gid / n) % n, i = gid % n;
    float step = 2.0f / (float)n;
    float a0 = -1.0f + step * (float)i, b0 = -1.0f + step * (float)j;
    float3 d = normalize(pn_cube_to_dir(face, a0 + 0.5f * step, b0 + 0.5f * step));
    dirs[gid] = (float4)(d, pn_cube_solid_angle(a0, b0, a0 + step, b0 + step));
}

/* Irradiance E(n) = sum_k L_k max(0, n . w_k) dw_k over every cube texel k:
 * the exact integral of the discretised environment. One work-item per
 * vertex-grid sample (global size 6*m*m, see pn_cube_grid_lookup). The
 * environment is streamed through local memory in tiles. */
#define PN_IRRADIANCE_TILE 256
kernel void envmap_irradiance(global const float4 *cube, global const float4 *dirs, int texels, int m,
                              global float4 *irradiance)
{
    local float4 tile_l[PN_IRRADIANCE_TILE];
    local float4 tile_d[PN_IRRADIANCE_TILE];
    int gid = get_global_id(0), lid = get_local_id(0), lsize = get_local_size(0);
    bool active = gid < 6 * m * m;
    float3 nrm = (float3)(0.0f, 1.0f, 0.0f);
    if (active) {
        int face = gid / (m * m), j = (gid / m) % m, i = gid % m;
        float a = -1.0f + 2.0f * (float)i / (float)(m - 1), b = -1.0f + 2.0f * (float)j / (float)(m - 1);
        nrm = normalize(pn_cube_to_dir(face, a, b));
    }
    float3 sum = (float3)(0.0f);
    for (int base = 0; base < texels; base += PN_IRRADIANCE_TILE) {
        for (int k = lid; k < PN_IRRADIANCE_TILE; k += lsize) {
            int src = base + k;
            tile_l[k] = src < texels ? cube[src] : (float4)(0.0f);
            tile_d[k] = src < texels ? dirs[src] : (float4)(0.0f);
        }
        barrier(CLK_LOCAL_MEM_FENCE);
        for (int k = 0; k < PN_IRRADIANCE_TILE; ++k) {
            float c = dot(nrm, tile_d[k].xyz);
            if (c > 0.0f)
                sum += tile_l[k].xyz * (c * tile_d[k].w);
        }
        barrier(CLK_LOCAL_MEM_FENCE);
    }
    if (active)
        irradiance[gid] = (float4)(sum, 0.0f);
}
