/* `unshadowed` method: diffuse environment lighting without visibility.
 * L_o = albedo / pi * E(n), E from the irradiance cube map (exact integral of
 * the environment, bilinear between its vertex-grid samples). */
#include "common/sphere_maps.cl"

/* One work-item per 8 consecutive pixels (global size ceil(count / 8)): the
 * irradiance of the 8 normals in lanes (pn_cube_grid_lookup8: one lookup
 * for one normal, else the face branches as selects, each lane doing
 * pn_cube_grid_lookup's operations in the same order, the 4 samples read
 * once for lanes in one cell), then per pixel the output. */
#define PN_UNSHADOWED_LANES 8
kernel void shade_unshadowed(global const float4 *position, global const float4 *normal,
                             global const float4 *albedo, global const uint *instance_id, int count,
                             global const float4 *irradiance, int m, global float4 *image)
{
    int base = get_global_id(0) * PN_UNSHADOWED_LANES;
    if (base >= count)
        return;
    /* Each lane's normal goes into the lane vectors as elements, unrolled
     * (kept in registers: a lane array written one lane at a time and read
     * back as a vector stalls the load on the 8 stores). */
    int8 live8;
    float8 nx, ny, nz;
#define PN_UNSHADOWED_LANE(l)                                                                      \
    {                                                                                              \
        int gid = base + l;                                                                        \
        uint id = gid < count ? instance_id[gid] : PN_BACKGROUND;                                  \
        float3 n = (float3)(0.0f, 1.0f, 0.0f);                                                     \
        if (id != PN_BACKGROUND)                                                                   \
            n = normalize(normal[gid].xyz);                                                        \
        else if (gid < count) /* black; the renderer draws the env map there (envmap_background) */ \
            image[gid] = (float4)(0.0f);                                                           \
        live8.s##l = id != PN_BACKGROUND;                                                          \
        nx.s##l = n.x, ny.s##l = n.y, nz.s##l = n.z;                                               \
    }
    PN_UNSHADOWED_LANE(0) PN_UNSHADOWED_LANE(1) PN_UNSHADOWED_LANE(2) PN_UNSHADOWED_LANE(3)
    PN_UNSHADOWED_LANE(4) PN_UNSHADOWED_LANE(5) PN_UNSHADOWED_LANE(6) PN_UNSHADOWED_LANE(7)
#undef PN_UNSHADOWED_LANE
    if (!any(live8 != 0))
        return;
    /* 8 neighbouring pixels of a flat surface share one normal: one lookup
     * (pn_cube_grid_lookup8; the same bits either way) */
    const bool one_normal = all((nx == nx.s0) & (ny == ny.s0) & (nz == nz.s0));
    float8 er, eg, eb;
    pn_cube_grid_lookup8(irradiance, m, nx, ny, nz, live8 != 0, one_normal, &er, &eg, &eb);
    int live[PN_UNSHADOWED_LANES];
    float e[3][PN_UNSHADOWED_LANES];
    vstore8(live8, 0, live);
    vstore8(er, 0, e[0]), vstore8(eg, 0, e[1]), vstore8(eb, 0, e[2]);
    for (int l = 0; l < PN_UNSHADOWED_LANES; ++l) {
        if (!live[l])
            continue;
        int gid = base + l;
        image[gid] = (float4)(fmax(albedo[gid].xyz * (float3)(e[0][l], e[1][l], e[2][l]) * PN_INV_PI, 0.0f), 1.0f);
    }
}
