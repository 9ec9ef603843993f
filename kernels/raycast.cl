/* Ray casting stage: primary rays into the G-buffer, batched ray queries,
 * and validation of caller-supplied G-buffers (docs/gbuffer.md). */
#include "common/raytrace.cl"
#include "common/brdf.cl"

/* A record's material as the G-buffer stores it: (n, alpha, lobe, 0), or for
 * the Ashikhmin-Shirley lobe (n_u, n_v, 3, tangent angle) with the object's
 * tangent axis carried to world space by the instance (a tangent vector: the
 * linear part, not the normal matrix) and measured in the tangent plane of
 * the stored normal (pn_tangent_angle, docs/brdf.md). */
inline float4 pn_gbuffer_material(float4 rec, global const float4 *o2w, float3 axis, float3 n)
{
    if ((int)rec.z != PN_LOBE_ASHIKHMIN_SHIRLEY)
        return (float4)(rec.xyz, 0.0f);
    return (float4)(rec.x, rec.w, rec.z, pn_tangent_angle(n, pn_xform_vector(o2w, axis)));
}

kernel void gbuffer_primary(PN_SCENE_ARGS, float4 cam_origin, float4 cam_forward, float4 cam_right, float4 cam_up,
                            int width, int height, global float4 *position, global float4 *normal,
                            global float4 *albedo, global float4 *material, global uint *instance_id)
{
    int x = get_global_id(0), y = get_global_id(1);
    if (x >= width || y >= height)
        return;
    int idx = y * width + x;
    float sx = 2.0f * ((float)x + 0.5f) / (float)width - 1.0f;
    float sy = 1.0f - 2.0f * ((float)y + 0.5f) / (float)height;
    float3 dir = normalize(cam_forward.xyz + sx * cam_right.xyz + sy * cam_up.xyz);
    float3 org = cam_origin.xyz;
    pn_scene_view scene = pn_make_scene_view(tlas, instances, blas, tris, instance_count);
    pn_hit hit;
    if (!pn_trace(scene, org, dir, 0.0f, INFINITY, &hit, false)) {
        position[idx] = (float4)(dir, INFINITY);
        normal[idx] = (float4)(0.0f);
        albedo[idx] = (float4)(0.0f);
        material[idx] = (float4)(0.0f);
        instance_id[idx] = PN_BACKGROUND;
        return;
    }
    global const float4 *inst = instances + hit.slot * PN_INSTANCE_STRIDE;
    global const float4 *w2o = inst + PN_INST_WORLD_TO_OBJECT;
    uint4 offs = as_uint4(inst[PN_INST_OFFSETS]);
    float3 v0 = tris[3 * hit.tri].xyz, v1 = tris[3 * hit.tri + 1].xyz, v2 = tris[3 * hit.tri + 2].xyz;
    float3 ng = normalize(pn_xform_normal(w2o, cross(v1 - v0, v2 - v0)));
    float3 ns = ng;
    if (offs.z & PN_INST_FLAG_NORMALS) {
        float w0 = 1.0f - hit.u - hit.v;
        float3 n = w0 * normals[3 * hit.tri].xyz + hit.u * normals[3 * hit.tri + 1].xyz +
                   hit.v * normals[3 * hit.tri + 2].xyz;
        n = pn_xform_normal(w2o, n);
        float len = length(n);
        /* A zero or flipped interpolated normal (bad vertex normals) falls back to the geometric one. */
        if (len > 0.0f && dot(n, ng) > 0.0f)
            ns = n / len;
    }
    /* Two-sided surfaces: both normals face the camera. */
    if (dot(ng, dir) > 0.0f) {
        ng = -ng;
        ns = -ns;
    }
    /* Near the silhouette of a coarse smooth mesh the interpolated normal can
     * still face away from the camera; the G-buffer promises normals facing
     * it, so such pixels fall back to the geometric normal too. */
    if (dot(ns, dir) > 0.0f)
        ns = ng;
    position[idx] = (float4)(org + hit.t * dir, hit.t);
    normal[idx] = (float4)(ns, 0.0f);
    albedo[idx] = inst[PN_INST_ALBEDO];
    material[idx] = pn_gbuffer_material(inst[PN_INST_MATERIAL], inst + PN_INST_OBJECT_TO_WORLD,
                                        inst[PN_INST_TANGENT].xyz, ns);
    instance_id[idx] = offs.w;
}

/* A closest-hit query's answer for ray gid: t, the instance's id and the
 * triangle's id, or (INFINITY, background, background) on a miss. In a
 * profiling build (PN_RAY_STATS; =2 profiles any-hit queries) the three
 * outputs carry the walk's node, box and triangle counts instead. */
#ifdef PN_RAY_STATS
#define PN_QUERY_ANY_HIT (PN_RAY_STATS == 2)
#else
#define PN_QUERY_ANY_HIT false
#endif
inline void pn_store_closest(bool found, const pn_hit *hit, global const float4 *instances,
                             global const float4 *tris, int gid, global float *t_out, global uint *instance_out,
                             global uint *triangle_out)
{
#ifdef PN_RAY_STATS
    (void)found;
    t_out[gid] = (float)hit->nodes; /* hit or miss */
    instance_out[gid] = hit->boxes;
    triangle_out[gid] = hit->tests;
#else
    if (found) {
        t_out[gid] = hit->t;
        instance_out[gid] = as_uint4(instances[hit->slot * PN_INSTANCE_STRIDE + PN_INST_OFFSETS]).w;
        triangle_out[gid] = as_uint(tris[3 * hit->tri].w);
    } else {
        t_out[gid] = INFINITY;
        instance_out[gid] = PN_BACKGROUND;
        triangle_out[gid] = PN_BACKGROUND;
    }
#endif
}

/* rays: two float4 per ray (origin, tmin), (direction, tmax). */
kernel void intersect_rays(PN_SCENE_ARGS, global const float4 *rays, int count, global float *t_out,
                           global uint *instance_out, global uint *triangle_out)
{
    int gid = get_global_id(0);
    if (gid >= count)
        return;
    float4 o = rays[2 * gid], d = rays[2 * gid + 1];
    pn_scene_view scene = pn_make_scene_view(tlas, instances, blas, tris, instance_count);
    pn_hit hit;
    bool found = pn_trace(scene, o.xyz, d.xyz, o.w, d.w, &hit, PN_QUERY_ANY_HIT);
    pn_store_closest(found, &hit, instances, tris, gid, t_out, instance_out, triangle_out);
}

kernel void occluded_rays(PN_SCENE_ARGS, global const float4 *rays, int count, global uchar *occluded)
{
    int gid = get_global_id(0);
    if (gid >= count)
        return;
    float4 o = rays[2 * gid], d = rays[2 * gid + 1];
    pn_scene_view scene = pn_make_scene_view(tlas, instances, blas, tris, instance_count);
    pn_hit hit;
    occluded[gid] = pn_trace(scene, o.xyz, d.xyz, o.w, d.w, &hit, true) ? 1 : 0;
}

/* intersect_rays and occluded_rays on rays given as origin and direction
 * arrays (3 floats per ray) with one tmin and tmax: the same trace, so the
 * same answers, without the host packing rays into two float4. */
kernel void intersect_ray_arrays(PN_SCENE_ARGS, global const float *origins, global const float *directions,
                                 float tmin, float tmax, int count, global float *t_out, global uint *instance_out,
                                 global uint *triangle_out)
{
    int gid = get_global_id(0);
    if (gid >= count)
        return;
    float3 o = vload3(gid, origins), d = vload3(gid, directions);
    pn_scene_view scene = pn_make_scene_view(tlas, instances, blas, tris, instance_count);
    pn_hit hit;
    bool found = pn_trace(scene, o, d, tmin, tmax, &hit, PN_QUERY_ANY_HIT);
    pn_store_closest(found, &hit, instances, tris, gid, t_out, instance_out, triangle_out);
}

kernel void occluded_ray_arrays(PN_SCENE_ARGS, global const float *origins, global const float *directions,
                                float tmin, float tmax, int count, global uchar *occluded)
{
    int gid = get_global_id(0);
    if (gid >= count)
        return;
    float3 o = vload3(gid, origins), d = vload3(gid, directions);
    pn_scene_view scene = pn_make_scene_view(tlas, instances, blas, tris, instance_count);
    pn_hit hit;
    occluded[gid] = pn_trace(scene, o, d, tmin, tmax, &hit, true) ? 1 : 0;
}

/* Checks every foreground pixel of a G-buffer in three classes: [0] a
 * position or normal that is not finite, or a zero normal; [1] an albedo that
 * is NaN, Inf or negative, or k_s outside [0, 1]; [2] a material whose
 * shininess is not finite and >= 0, roughness not in [0, 1], or lobe not one
 * of 0, 1, 2, 3 (for 3, Ashikhmin-Shirley: n_v in y finite and >= 0 instead
 * of the roughness, and a finite tangent angle in w). bad_count[c] counts the pixels of class c, first_bad[c] gets
 * the smallest such pixel index (the host names the field from it). */
kernel void gbuffer_validate(global const float4 *position, global const float4 *normal,
                             global const float4 *albedo, global const float4 *material,
                             global const uint *instance_id, int count, volatile global int *bad_count,
                             volatile global int *first_bad)
{
    int gid = get_global_id(0);
    if (gid >= count || instance_id[gid] == PN_BACKGROUND)
        return;
    float4 p = position[gid], n = normal[gid], a = albedo[gid], m = material[gid];
    bool finite = isfinite(p.x) && isfinite(p.y) && isfinite(p.z) && isfinite(n.x) && isfinite(n.y) &&
                  isfinite(n.z);
    if (!finite || dot(n.xyz, n.xyz) == 0.0f) {
        atomic_inc(&bad_count[0]);
        atomic_min(&first_bad[0], gid);
    }
    /* Written so that NaN fails every test. */
    bool albedo_ok = a.x >= 0.0f && a.y >= 0.0f && a.z >= 0.0f && isfinite(a.x) && isfinite(a.y) && isfinite(a.z) &&
                     a.w >= 0.0f && a.w <= 1.0f;
    if (!albedo_ok) {
        atomic_inc(&bad_count[1]);
        atomic_min(&first_bad[1], gid);
    }
    bool aniso = m.z == 3.0f;
    bool material_ok = m.x >= 0.0f && isfinite(m.x) && m.y >= 0.0f &&
                       (aniso ? isfinite(m.y) && isfinite(m.w) : m.y <= 1.0f && (m.z == 0.0f || m.z == 1.0f || m.z == 2.0f));
    if (!material_ok) {
        atomic_inc(&bad_count[2]);
        atomic_min(&first_bad[2], gid);
    }
}
