/* `floor` method: the memory-bound floor every method is timed against
 * (docs/benchmarks.md). It reads the G-buffer planes a shading method needs
 * (position, normal, albedo, instance) and writes the image, with arithmetic
 * too light to cost anything: no method that reads a G-buffer and writes an
 * image can be faster. The picture (albedo times a head-light term) is only
 * there so the reads cannot be optimised away. */
#include "common/math.cl"

kernel void shade_floor(global const float4 *position, global const float4 *normal, global const float4 *albedo,
                        global const uint *instance_id, int count, float4 camera, global float4 *image)
{
    int gid = get_global_id(0);
    if (gid >= count)
        return;
    float4 p = position[gid];
    if (instance_id[gid] == PN_BACKGROUND) {
        image[gid] = (float4)(0.0f);
        return;
    }
    float3 to_camera = camera.xyz - p.xyz;
    float facing = fabs(dot(normal[gid].xyz, to_camera)) * native_rsqrt(dot(to_camera, to_camera));
    image[gid] = (float4)(albedo[gid].xyz * facing, 1.0f);
}
