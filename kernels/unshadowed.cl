/* `unshadowed` method: diffuse environment lighting without visibility.
 * L_o = albedo / pi * E(n), E from the irradiance cube map (exact integral of
 * the environment, bilinear between its vertex-grid samples). */
#include "common/sphere_maps.cl"

/* One work-item per 8 consecutive pixels (global size ceil(count / 8)): the
 * cube grid's face and cell of the 8 normals in float8 lanes
 * (pn_cube_grid_cell8, the face branches as selects, each lane doing
 * pn_cube_grid_lookup's operations in the same order), then per pixel its
 * 4 samples, and the output in lanes; the background drawn here when
 * `background` is set (the unshadowed method; heightfield, which builds on
 * this kernel, leaves it to the renderer's pass). */
#define PN_UNSHADOWED_LANES 8
kernel void shade_unshadowed(global const float4 *position, global const float4 *normal,
                             global const float4 *albedo, global const uint *instance_id, int count,
                             global const float4 *irradiance, int m, global float4 *image, int background,
                             global const float *latlong, int latlong_width, int latlong_height, float2 rot,
                             float intensity)
{
    const int base = get_global_id(0) * PN_UNSHADOWED_LANES;
    if (base >= count)
        return;
    /* The planes in lanes by 8-wide loads and shuffles, the lanes past the
     * end one by one (pn_load_row8); each lane's values go into the lane
     * vectors as elements or by shuffles, never through a lane array read
     * back as a vector (that stalls the load on the scalar stores). With
     * `background` the background pixels get the env map here
     * (pn_background8, the background pass's operations: the same bits). */
    const bool full = base + PN_UNSHADOWED_LANES <= count;
    const int8 in_row = (int8)(0, 1, 2, 3, 4, 5, 6, 7) < count - base;
    uint8 id8;
    if (full) {
        id8 = vload8(0, instance_id + base);
    } else {
#define PN_UNSHADOWED_ID_LANE(l) id8.s##l = base + l < count ? instance_id[base + l] : PN_BACKGROUND;
        PN_UNSHADOWED_ID_LANE(0) PN_UNSHADOWED_ID_LANE(1) PN_UNSHADOWED_ID_LANE(2) PN_UNSHADOWED_ID_LANE(3)
        PN_UNSHADOWED_ID_LANE(4) PN_UNSHADOWED_ID_LANE(5) PN_UNSHADOWED_ID_LANE(6) PN_UNSHADOWED_ID_LANE(7)
#undef PN_UNSHADOWED_ID_LANE
    }
    const int8 live8 = id8 != PN_BACKGROUND, sky = ~live8 & in_row;
    float8 sky_r = 0.0f, sky_g = 0.0f, sky_b = 0.0f;
    if (background && any(sky)) {
        float8 px, py, pz;
        pn_load_row8(position, base, full, in_row, &px, &py, &pz);
        pn_background8(latlong, latlong_width, latlong_height, rot, intensity, px, py, pz, sky, &sky_r, &sky_g,
                       &sky_b);
    }
    if (!any(live8)) {
        pn_store_row8(image, base, full, in_row, sky_r, sky_g, sky_b, (float8)(0.0f));
        return;
    }
    float8 nx, ny, nz;
    pn_load_row8(normal, base, full, in_row, &nx, &ny, &nz);
    nx = select((float8)(0.0f), nx, live8), ny = select((float8)(1.0f), ny, live8);
    nz = select((float8)(0.0f), nz, live8);
    pn_normalize8(&nx, &ny, &nz);
    int live[PN_UNSHADOWED_LANES];
    vstore8(live8, 0, live);
    int face[PN_UNSHADOWED_LANES], cx[PN_UNSHADOWED_LANES], cy[PN_UNSHADOWED_LANES];
    float fx[PN_UNSHADOWED_LANES], fy[PN_UNSHADOWED_LANES];
    pn_cube_grid_cell8(m, nx, ny, nz, face, cx, cy, fx, fy);
    float8 e_r = 0.0f, e_g = 0.0f, e_b = 0.0f;
#define PN_UNSHADOWED_LANE(l)                                                                 \
    if (live[l]) {                                                                            \
        float3 e = pn_cube_grid_fetch(irradiance, m, face[l], cx[l], cy[l], fx[l], fy[l]);    \
        e_r.s##l = e.x, e_g.s##l = e.y, e_b.s##l = e.z;                                       \
    }
    PN_UNSHADOWED_LANE(0) PN_UNSHADOWED_LANE(1) PN_UNSHADOWED_LANE(2) PN_UNSHADOWED_LANE(3)
    PN_UNSHADOWED_LANE(4) PN_UNSHADOWED_LANE(5) PN_UNSHADOWED_LANE(6) PN_UNSHADOWED_LANE(7)
#undef PN_UNSHADOWED_LANE
    float8 ar, ag, ab;
    pn_load_row8(albedo, base, full, in_row, &ar, &ag, &ab);
    /* fmax(albedo.xyz * e * PN_INV_PI, 0) per lane, as one pixel's */
    float8 out_r = select(sky_r, fmax(ar * e_r * PN_INV_PI, 0.0f), live8);
    float8 out_g = select(sky_g, fmax(ag * e_g * PN_INV_PI, 0.0f), live8);
    float8 out_b = select(sky_b, fmax(ab * e_b * PN_INV_PI, 0.0f), live8);
    pn_store_row8(image, base, full, in_row, out_r, out_g, out_b, select((float8)(0.0f), (float8)(1.0f), live8));
}
