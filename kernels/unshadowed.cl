/* `unshadowed` method: diffuse environment lighting without visibility.
 * L_o = albedo / pi * E(n), E from the irradiance cube map (exact integral of
 * the environment, bilinear between its vertex-grid samples). */
#include "common/sphere_maps.cl"

kernel void shade_unshadowed(global const float4 *position, global const float4 *normal,
                             global const float4 *albedo, global const uint *instance_id, int count,
                             global const float4 *irradiance, int m, global const float4 *cube, int n,
                             int show_background, global float4 *image)
{
    int gid = get_global_id(0);
    if (gid >= count)
        return;
    if (instance_id[gid] == PN_BACKGROUND) {
        /* position.xyz holds the view direction of background pixels. */
        float3 env = show_background ? pn_cube_texel_lookup(cube, n, normalize(position[gid].xyz)) : (float3)(0.0f);
        image[gid] = (float4)(env, 0.0f);
        return;
    }
    float3 e = pn_cube_grid_lookup(irradiance, m, normalize(normal[gid].xyz));
    image[gid] = (float4)(fmax(albedo[gid].xyz * e * PN_INV_PI, 0.0f), 1.0f);
}
