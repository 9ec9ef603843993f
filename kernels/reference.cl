/* `reference` method: deterministic brute-force ground truth (docs/reference.md).
 *
 * For each pixel, outgoing radiance towards the camera
 *   L_o = sum_k f(V, w_k) L_k V(p, w_k) max(0, N.w_k) dw_k
 *       + sum_lights sum_s f(V, w_s) L_light V(p, w_s, t_s) max(0, N.w_s) Omega / S
 * over the direction records k built by the host (one per cube texel of the
 * chosen face size with its exact solid angle and area-averaged radiance; bright
 * texels optionally split into sub-texels), and S stratified directions inside
 * each spherical light's cap. V is an any-hit shadow ray against the real
 * triangles. Work-items of a work-group are neighbouring pixels that walk the
 * records in the same order, so their rays are coherent. */
#include "common/brdf.cl"
#include "common/raytrace.cl"
#include "common/sphere_maps.cl"

/* Shadow-ray origin: lifted along the normal by an offset proportional to the
 * scene's size and to the distance from the camera (the G-buffer position's
 * rounding error grows with both); see docs/reference.md. */
inline float3 pn_shadow_origin(float3 p, float3 n, float3 camera, float offset, float scene_scale)
{
    return p + (offset * (scene_scale + fast_length(p - camera))) * n;
}

/* Radiance from one spherical light (centre, radius | radiance), sampled on a
 * side x side stratified grid over the solid angle of its cap. A receiver
 * inside the sphere sees its back faces, which do not emit. */
inline float3 pn_sphere_light(pn_scene_view scene, float4 sphere, float3 radiance, int side, pn_material m, float3 p,
                              float3 o, float3 n, float3 v, int visibility)
{
    float3 w = sphere.xyz - p;
    float dist2 = dot(w, w), r2 = sphere.w * sphere.w;
    if (dist2 <= r2)
        return (float3)(0.0f);
    float dist = sqrt(dist2);
    w /= dist;
    /* 1 - cos(theta_max) without cancellation for small or far lights. */
    float sin2 = r2 / dist2;
    float one_minus_cos = sin2 / (1.0f + sqrt(1.0f - sin2));
    float omega = PN_TWO_PI * one_minus_cos;
    float3 t, b;
    pn_frame(w, &t, &b);
    float3 to_centre = sphere.xyz - o;
    float c2 = dot(to_centre, to_centre);
    float3 sum = (float3)(0.0f);
    for (int j = 0; j < side; ++j) {
        float phi = PN_TWO_PI * ((float)j + 0.5f) / (float)side;
        float sp = sin(phi), cp = cos(phi);
        for (int i = 0; i < side; ++i) {
            float u = one_minus_cos * ((float)i + 0.5f) / (float)side; /* 1 - cos(theta) */
            float st = sqrt(fmax(u * (2.0f - u), 0.0f));
            float3 d = (st * cp) * t + (st * sp) * b + (1.0f - u) * w;
            float nl = dot(n, d);
            if (nl <= 0.0f)
                continue;
            /* Near intersection with the sphere, seen from the shadow-ray origin. */
            float bb = dot(d, to_centre);
            float tmax = bb - sqrt(fmax(r2 - (c2 - bb * bb), 0.0f));
            pn_hit hit;
            if (visibility && tmax > 0.0f && pn_trace(scene, o, d, 0.0f, tmax, &hit, true))
                continue;
            sum += pn_brdf(m, n, v, d) * nl;
        }
    }
    return sum * radiance * (omega / (float)(side * side));
}

kernel void shade_reference(PN_SCENE_ARGS, global const float4 *position, global const float4 *normal,
                            global const float4 *albedo, global const float4 *material,
                            global const uint *instance_id, int count, global const float4 *records,
                            int record_count, global const float4 *lights, int light_count, int light_side,
                            float4 camera, float offset, float scene_scale, int visibility,
                            global float4 *image)
{
    int gid = get_global_id(0);
    if (gid >= count)
        return;
    if (instance_id[gid] == PN_BACKGROUND) { /* black; the renderer draws the env map there (envmap_background) */
        image[gid] = (float4)(0.0f);
        return;
    }
    pn_scene_view scene = pn_make_scene_view(tlas, instances, blas, tris, instance_count);
    float3 p = position[gid].xyz;
    float3 n = normalize(normal[gid].xyz);
    float3 v = normalize(camera.xyz - p);
    pn_material m = pn_material_from_gbuffer(albedo[gid], material[gid]);
    float3 o = pn_shadow_origin(p, n, camera.xyz, offset, scene_scale);
    float3 sum = (float3)(0.0f);
    for (int k = 0; k < record_count; ++k) {
        float4 rec = records[2 * k];
        float nl = dot(n, rec.xyz);
        if (nl <= 0.0f) /* below the horizon: no contribution, no ray */
            continue;
        pn_hit hit;
        if (visibility && pn_trace(scene, o, rec.xyz, 0.0f, INFINITY, &hit, true))
            continue;
        sum += pn_brdf(m, n, v, rec.xyz) * records[2 * k + 1].xyz * (nl * rec.w);
    }
    for (int l = 0; l < light_count; ++l)
        sum += pn_sphere_light(scene, lights[2 * l], lights[2 * l + 1].xyz, light_side, m, p, o, n, v, visibility);
    image[gid] = (float4)(fmax(sum, 0.0f), 1.0f);
}
