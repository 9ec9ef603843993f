/* Ray queries against the two-level BVH built by the host (capi/src/bvh.c,
 * capi/src/scene.c).
 *
 * Node: two float4, lo.xyz / hi.xyz bounds; lo.w = left child or first
 * primitive, hi.w = primitive count (0 for an interior node, whose children
 * are adjacent), both stored as uint bits.
 * Triangle: three float4 vertices in BVH leaf order; v0.w = the mesh's own
 * triangle index (uint bits).
 * Instance: PN_INSTANCE_STRIDE float4 (see PN_INST_* below), stored in TLAS
 * leaf order; BLAS node and primitive indices are relative to the instance's
 * mesh offsets.
 * Triangles are tested with the watertight algorithm of Woop, Benthin and
 * Wald (JCGT 2013): a ray through a shared edge or vertex hits one of the
 * triangles, never neither.
 */
#ifndef PN_COMMON_RAYTRACE_CL
#define PN_COMMON_RAYTRACE_CL

#include "common/math.cl"

#define PN_BVH_MAX_DEPTH 48

#define PN_INSTANCE_STRIDE 9
#define PN_INST_WORLD_TO_OBJECT 0 /* 3 rows, xyz | translation */
#define PN_INST_OBJECT_TO_WORLD 3 /* 3 rows */
#define PN_INST_ALBEDO 6          /* rgb, k_s */
#define PN_INST_MATERIAL 7        /* shininess, roughness, lobe, 0 */
#define PN_INST_OFFSETS 8         /* uint bits: blas node offset, triangle offset, flags, instance id */
#define PN_INST_FLAG_NORMALS 1u

typedef struct {
    global const float4 *tlas;      /* TLAS nodes over instances */
    global const float4 *instances; /* instance records in TLAS leaf order */
    global const float4 *blas;      /* all meshes' BVH nodes */
    global const float4 *tris;      /* all meshes' triangles, 3 float4 each */
    uint instance_count;            /* 0: an empty scene, every ray misses */
} pn_scene_view;

typedef struct {
    float t;
    float u, v;     /* barycentric weights of v1 and v2 */
    uint slot;      /* instance record index (TLAS order) */
    uint tri;       /* triangle slot in `tris` (global, leaf order) */
} pn_hit;

/* The six scene arguments every kernel that traces rays takes, in the order
 * pn_scene_set_kernel_args sets them. */
#define PN_SCENE_ARGS                                                                                        \
    global const float4 *tlas, global const float4 *instances, global const float4 *blas,                  \
        global const float4 *tris, global const float4 *normals, uint instance_count

inline pn_scene_view pn_make_scene_view(global const float4 *tlas, global const float4 *instances,
                                         global const float4 *blas, global const float4 *tris, uint instance_count)
{
    pn_scene_view v;
    v.tlas = tlas;
    v.instances = instances;
    v.blas = blas;
    v.tris = tris;
    v.instance_count = instance_count;
    return v;
}

/* camera: origin, forward, right * tan(fov/2), up * tan(fov/2) * height/width. */
inline float3 pn_xform_point(global const float4 *rows, float3 p)
{
    return (float3)(dot(rows[0].xyz, p) + rows[0].w, dot(rows[1].xyz, p) + rows[1].w,
                    dot(rows[2].xyz, p) + rows[2].w);
}

inline float3 pn_xform_vector(global const float4 *rows, float3 v)
{
    return (float3)(dot(rows[0].xyz, v), dot(rows[1].xyz, v), dot(rows[2].xyz, v));
}

/* Transforms a normal by the inverse transpose of object_to_world, i.e. by the
 * transpose of world_to_object. */
inline float3 pn_xform_normal(global const float4 *world_to_object, float3 n)
{
    return world_to_object[0].xyz * n.x + world_to_object[1].xyz * n.y + world_to_object[2].xyz * n.z;
}

/* Entry distance of the ray into the box, or INFINITY when it misses within
 * (tmin, tmax). The far distance is enlarged by 2 ulp-ish so that rounding
 * never culls a box the ray grazes (Ize, "Robust BVH ray traversal"). */
inline float pn_ray_box(float3 org, float3 inv_dir, float tmin, float tmax, float4 lo, float4 hi)
{
    float3 t0 = (lo.xyz - org) * inv_dir;
    float3 t1 = (hi.xyz - org) * inv_dir;
    float3 tn = fmin(t0, t1), tf = fmax(t0, t1);
    /* A zero direction component with the origin in a slab's boundary plane
     * gives 0 * inf = NaN: the ray lies in the closed slab for every t (fmin
     * and fmax would otherwise pair the NaN with the other plane's +-inf and
     * cull the box, losing hits on triangles that lie on the box's face). */
    int3 in_plane = isnan(t0) | isnan(t1);
    tn = select(tn, (float3)(-INFINITY), in_plane);
    tf = select(tf, (float3)(INFINITY), in_plane);
    float enter = fmax(fmax(tn.x, tn.y), fmax(tn.z, tmin));
    float leave = fmin(fmin(tf.x, tf.y), fmin(tf.z, tmax)) * 1.00000024f;
    return enter <= leave ? enter : INFINITY;
}

/* Per-ray constants of the watertight test. */
typedef struct {
    int kx, ky, kz;
    float sx, sy, sz;
} pn_ray_shear;

inline float pn_comp(float3 v, int k)
{
    return k == 0 ? v.x : (k == 1 ? v.y : v.z);
}

inline pn_ray_shear pn_make_shear(float3 dir)
{
    pn_ray_shear s;
    float3 a = fabs(dir);
    s.kz = (a.x >= a.y && a.x >= a.z) ? 0 : (a.y >= a.z ? 1 : 2);
    s.kx = (s.kz + 1) % 3;
    s.ky = (s.kx + 1) % 3;
    float dz = pn_comp(dir, s.kz);
    if (dz < 0.0f) {
        int tmp = s.kx;
        s.kx = s.ky;
        s.ky = tmp;
    }
    s.sx = pn_comp(dir, s.kx) / dz;
    s.sy = pn_comp(dir, s.ky) / dz;
    s.sz = 1.0f / dz;
    return s;
}

/* Watertight ray-triangle test; on a hit in (tmin, tmax) returns true with t
 * and the barycentric weights (u of v1, v of v2). */
inline bool pn_ray_triangle(float3 org, pn_ray_shear s, float tmin, float tmax, float3 v0, float3 v1, float3 v2,
                            float *t_out, float *u_out, float *v_out)
{
    /* No FMA contraction here: a shared edge's function is computed as
     * p.x*q.y - p.y*q.x in one triangle and q.x*p.y - q.y*p.x in the other,
     * exact negatives only when both products are rounded alike. A fused
     * multiply-add (OpenCL C contracts by default) breaks that, and rays
     * through shared edges then miss both triangles. */
#pragma OPENCL FP_CONTRACT OFF
    float3 A = v0 - org, B = v1 - org, C = v2 - org;
    float az = pn_comp(A, s.kz), bz = pn_comp(B, s.kz), cz = pn_comp(C, s.kz);
    float ax = pn_comp(A, s.kx) - s.sx * az, ay = pn_comp(A, s.ky) - s.sy * az;
    float bx = pn_comp(B, s.kx) - s.sx * bz, by = pn_comp(B, s.ky) - s.sy * bz;
    float cx = pn_comp(C, s.kx) - s.sx * cz, cy = pn_comp(C, s.ky) - s.sy * cz;
    float U = cx * by - cy * bx;
    float V = ax * cy - ay * cx;
    float W = bx * ay - by * ax;
    if ((U < 0.0f || V < 0.0f || W < 0.0f) && (U > 0.0f || V > 0.0f || W > 0.0f))
        return false;
    float det = U + V + W;
    if (det == 0.0f)
        return false;
    float T = s.sz * (U * az + V * bz + W * cz);
    float t = T / det;
    if (!(t > tmin && t < tmax))
        return false;
    *t_out = t;
    *u_out = V / det;
    *v_out = W / det;
    return true;
}

/* Traverses one instance's BLAS in object space. any_hit: stop at the first
 * hit. Returns true if hit->t was lowered. */
inline bool pn_trace_blas(pn_scene_view scene, uint slot, float3 org, float3 dir, float tmin, pn_hit *hit,
                          bool any_hit)
{
    global const float4 *inst = scene.instances + slot * PN_INSTANCE_STRIDE;
    uint4 offs = as_uint4(inst[PN_INST_OFFSETS]);
    global const float4 *nodes = scene.blas + 2 * offs.x;
    float3 o = pn_xform_point(inst + PN_INST_WORLD_TO_OBJECT, org);
    float3 d = pn_xform_vector(inst + PN_INST_WORLD_TO_OBJECT, dir);
    float3 inv = 1.0f / d;
    pn_ray_shear shear = pn_make_shear(d);
    bool found = false;
    uint stack[PN_BVH_MAX_DEPTH];
    int sp = 0;
    uint node = 0;
    if (pn_ray_box(o, inv, tmin, hit->t, nodes[0], nodes[1]) == INFINITY)
        return false;
    for (;;) {
        float4 lo = nodes[2 * node], hi = nodes[2 * node + 1];
        uint count = as_uint(hi.w), first = as_uint(lo.w);
        if (count > 0) {
            for (uint k = first; k < first + count; ++k) {
                uint tri = offs.y + k;
                float t, u, v;
                if (pn_ray_triangle(o, shear, tmin, hit->t, scene.tris[3 * tri].xyz, scene.tris[3 * tri + 1].xyz,
                                    scene.tris[3 * tri + 2].xyz, &t, &u, &v)) {
                    hit->t = t;
                    hit->u = u;
                    hit->v = v;
                    hit->slot = slot;
                    hit->tri = tri;
                    found = true;
                    if (any_hit)
                        return true;
                }
            }
        } else {
            uint left = first, right = first + 1;
            float tl = pn_ray_box(o, inv, tmin, hit->t, nodes[2 * left], nodes[2 * left + 1]);
            float tr = pn_ray_box(o, inv, tmin, hit->t, nodes[2 * right], nodes[2 * right + 1]);
            if (tl != INFINITY && tr != INFINITY) {
                /* Visit the nearer child first; the farther waits on the stack. */
                if (tr < tl) {
                    stack[sp++] = left;
                    node = right;
                } else {
                    stack[sp++] = right;
                    node = left;
                }
                continue;
            }
            if (tl != INFINITY) { node = left; continue; }
            if (tr != INFINITY) { node = right; continue; }
        }
        if (sp == 0)
            break;
        node = stack[--sp];
    }
    return found;
}

/* Closest (any_hit = false) or any (any_hit = true) intersection with the
 * scene in (tmin, tmax). hit->t is INFINITY-free only when true is returned. */
inline bool pn_trace(pn_scene_view scene, float3 org, float3 dir, float tmin, float tmax, pn_hit *hit, bool any_hit)
{
    hit->t = tmax;
    hit->slot = PN_BACKGROUND;
    hit->tri = PN_BACKGROUND;
    hit->u = hit->v = 0.0f;
    float3 inv = 1.0f / dir;
    bool found = false;
    uint stack[PN_BVH_MAX_DEPTH];
    int sp = 0;
    uint node = 0;
    global const float4 *nodes = scene.tlas;
    if (scene.instance_count == 0)
        return false;
    if (pn_ray_box(org, inv, tmin, tmax, nodes[0], nodes[1]) == INFINITY)
        return false;
    for (;;) {
        float4 lo = nodes[2 * node], hi = nodes[2 * node + 1];
        uint count = as_uint(hi.w), first = as_uint(lo.w);
        if (count > 0) {
            for (uint k = first; k < first + count; ++k) {
                if (pn_trace_blas(scene, k, org, dir, tmin, hit, any_hit)) {
                    found = true;
                    if (any_hit)
                        return true;
                }
            }
        } else {
            uint left = first, right = first + 1;
            float tl = pn_ray_box(org, inv, tmin, hit->t, nodes[2 * left], nodes[2 * left + 1]);
            float tr = pn_ray_box(org, inv, tmin, hit->t, nodes[2 * right], nodes[2 * right + 1]);
            if (tl != INFINITY && tr != INFINITY) {
                if (tr < tl) {
                    stack[sp++] = left;
                    node = right;
                } else {
                    stack[sp++] = right;
                    node = left;
                }
                continue;
            }
            if (tl != INFINITY) { node = left; continue; }
            if (tr != INFINITY) { node = right; continue; }
        }
        if (sp == 0)
            break;
        node = stack[--sp];
    }
    return found;
}

#endif
