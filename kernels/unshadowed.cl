/* `unshadowed` method: diffuse environment lighting without visibility.
 * L_o = albedo / pi * E(n), E from the irradiance cube map (exact integral of
 * the environment, bilinear between its vertex-grid samples). */
#include "common/sphere_maps.cl"

kernel void shade_unshadowed(global const float4 *position, global const float4 *normal,
                             global const float4 *albedo, global const uint *instance_id, int count,
                             global const float4 *irradiance, int m, global float4 *image)
{
    int gid = get_global_id(0);
    if (gid >= count)
        return;
    if (instance_id[gid] == PN_BACKGROUND) { /* black; the renderer draws the env map there (envmap_background) */
        image[gid] = (float4)(0.0f);
        return;
    }
    float3 e = pn_cube_grid_lookup(irradiance, m, normalize(normal[gid].xyz));
    image[gid] = (float4)(fmax(albedo[gid].xyz * e * PN_INV_PI, 0.0f), 1.0f);
}
