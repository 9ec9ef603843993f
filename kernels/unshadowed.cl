/* `unshadowed` method: diffuse environment lighting without visibility.
 * L_o = albedo / pi * E(n), E from the irradiance cube map (exact integral of
 * the environment, bilinear between its vertex-grid samples). */
#include "common/sphere_maps.cl"

/* One work-item per 8 consecutive pixels (global size ceil(count / 8)): the
 * cube grid's face and cell of the 8 normals in float8 lanes
 * (pn_cube_grid_cell8, the face branches as selects, each lane doing
 * pn_cube_grid_lookup's operations in the same order), then per pixel its
 * 4 samples and the output. */
#define PN_UNSHADOWED_LANES 8
kernel void shade_unshadowed(global const float4 *position, global const float4 *normal,
                             global const float4 *albedo, global const uint *instance_id, int count,
                             global const float4 *irradiance, int m, global float4 *image)
{
    int base = get_global_id(0) * PN_UNSHADOWED_LANES;
    if (base >= count)
        return;
    int live[PN_UNSHADOWED_LANES], any_live = 0;
    float lx[PN_UNSHADOWED_LANES], ly[PN_UNSHADOWED_LANES], lz[PN_UNSHADOWED_LANES];
    for (int l = 0; l < PN_UNSHADOWED_LANES; ++l) {
        int gid = base + l;
        uint id = gid < count ? instance_id[gid] : PN_BACKGROUND;
        float3 n = (float3)(0.0f, 1.0f, 0.0f);
        if (id != PN_BACKGROUND)
            n = normalize(normal[gid].xyz);
        else if (gid < count) /* black; the renderer draws the env map there (envmap_background) */
            image[gid] = (float4)(0.0f);
        live[l] = id != PN_BACKGROUND;
        any_live |= live[l];
        lx[l] = n.x, ly[l] = n.y, lz[l] = n.z;
    }
    if (!any_live)
        return;
    int face[PN_UNSHADOWED_LANES], cx[PN_UNSHADOWED_LANES], cy[PN_UNSHADOWED_LANES];
    float fx[PN_UNSHADOWED_LANES], fy[PN_UNSHADOWED_LANES];
    pn_cube_grid_cell8(m, vload8(0, lx), vload8(0, ly), vload8(0, lz), face, cx, cy, fx, fy);
    for (int l = 0; l < PN_UNSHADOWED_LANES; ++l) {
        if (!live[l])
            continue;
        int gid = base + l;
        float3 e = pn_cube_grid_fetch(irradiance, m, face[l], cx[l], cy[l], fx[l], fy[l]);
        image[gid] = (float4)(fmax(albedo[gid].xyz * e * PN_INV_PI, 0.0f), 1.0f);
    }
}
