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

/* BLAS node layout: 4-wide nodes (the default), or 2 for the binary BVH
 * (PENUMBRA_BVH_WIDTH=2; the host sets the define for the library's builds). */
#ifndef PN_BVH_WIDTH
#define PN_BVH_WIDTH 4
#endif

/* The traversal functions are forced inline: each call site then compiles
 * its own copy with any_hit constant (measured: 1.17x on shadow rays). */
#define PN_TRACE_INLINE inline __attribute__((always_inline))

#define PN_INSTANCE_STRIDE 10
#define PN_INST_WORLD_TO_OBJECT 0 /* 3 rows, xyz | translation */
#define PN_INST_OBJECT_TO_WORLD 3 /* 3 rows */
#define PN_INST_ALBEDO 6          /* rgb, k_s */
#define PN_INST_MATERIAL 7        /* shininess, roughness, lobe, shininess_v */
#define PN_INST_OFFSETS 8         /* uint bits: blas node offset, triangle offset, flags, instance id */
#define PN_INST_TANGENT 9         /* Ashikhmin-Shirley tangent axis in the object's frame, 0 */
#define PN_INST_FLAG_NORMALS 1u
/* world_to_object's linear part is exactly the identity (a translation, or
 * nothing): the object-space direction is the world one, so the walk reuses
 * the world ray's reciprocal direction instead of transforming the direction
 * and dividing again (pn_instance_ray). Builds with -DPN_INSTANCE_GENERAL
 * ignore the flag (tests compare the two). */
#define PN_INST_FLAG_TRANSLATION 2u

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
#ifdef PN_RAY_STATS
    uint nodes, boxes, tests; /* profiling build only: nodes fetched, box and triangle tests of this query */
#endif
} pn_hit;

/* Profiling builds (-DPN_RAY_STATS, see bench/ray_profile.py) count the
 * work of each query; other builds compile these away. */
#ifdef PN_RAY_STATS
#define PN_STAT(hit, field, n) ((hit)->field += (n))
#else
#define PN_STAT(hit, field, n) ((void)0)
#endif

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

/* Loads of node bounds and triangle vertices as three floats. Nodes and
 * triangles keep indices and counts in their w components (uint bits, i.e.
 * denormal floats); loading whole float4 lets those lanes ride along in the
 * vector arithmetic, where every denormal operand costs a microcode assist
 * of about a hundred cycles on x86 CPUs. vload3 leaves that lane 0. */
inline float3 pn_load3(global const float4 *p)
{
    return vload3(0, (global const float *)p);
}

inline uint pn_load_w(global const float4 *p)
{
    return ((global const uint *)p)[3];
}

/* Per-ray constants of the slab test. */
typedef struct {
    float3 org, inv; /* origin, 1 / direction */
    int3 neg;        /* sign bit of inv per axis (-1 set): the near plane is hi there */
} pn_ray_slab;

inline pn_ray_slab pn_make_slab(float3 org, float3 dir)
{
    pn_ray_slab r;
    r.org = org;
    r.inv = 1.0f / dir;
    r.neg = signbit(r.inv);
    return r;
}

/* The ray of the instance at `inst` in object space: its origin and
 * direction and their slab constants. world: the world ray's slab
 * constants, or NULL. For an instance flagged PN_INST_FLAG_TRANSLATION the
 * direction is `dir` itself, so its reciprocal is the world one, and the
 * origin is org + translation: dot((1, 0, 0), org) + t.x in the general
 * transform is org.x + t.x exactly (a product by 1 or 0 is exact and adding
 * zeros does not change a nonzero sum), so answers are bit-identical to the
 * general path (at most the sign of a zero coordinate differs, which no test
 * below can see: zeros compare equal, and a zero times an infinite
 * reciprocal is NaN either way). */
PN_TRACE_INLINE pn_ray_slab pn_instance_ray(global const float4 *inst, uint flags, float3 org, float3 dir,
                                                  const pn_ray_slab *world, float3 *d_out)
{
#ifndef PN_INSTANCE_GENERAL
    if ((flags & PN_INST_FLAG_TRANSLATION) && world) {
        global const float4 *w2o = inst + PN_INST_WORLD_TO_OBJECT;
        pn_ray_slab r = *world;
        r.org = org + (float3)(w2o[0].w, w2o[1].w, w2o[2].w);
        *d_out = dir;
        return r;
    }
#endif
    float3 o = pn_xform_point(inst + PN_INST_WORLD_TO_OBJECT, org);
    float3 d = pn_xform_vector(inst + PN_INST_WORLD_TO_OBJECT, dir);
    *d_out = d;
    return pn_make_slab(o, d);
}

/* Larger (smaller) of acc and t, acc when t is NaN: the compare-and-select
 * form compiles to one max (min) instruction, unlike fmax's NaN handling. */
inline float pn_max_acc(float acc, float t)
{
    return t > acc ? t : acc;
}

inline float pn_min_acc(float acc, float t)
{
    return t < acc ? t : acc;
}

/* Entry distance of the ray into the box, or INFINITY when it misses within
 * (tmin, tmax). The far distance is enlarged by 2 ulp-ish so that rounding
 * never culls a box the ray grazes (Ize, "Robust BVH ray traversal").
 *
 * Each axis contributes its near plane (lo, or hi where the direction is
 * negative, -0 included) to the entry and its far plane to the exit. A zero
 * direction component with the origin in one of the slab's planes gives
 * 0 * inf = NaN for that plane: the ray lies in the closed slab for every t,
 * so the plane must not constrain the interval. The accumulating max/min
 * ignore a NaN term, which is exactly that (a plane that would give NaN as
 * the near plane would give -inf or NaN as the far one and vice versa, so
 * this matches treating the whole axis as unbounded). tmin / tmax seed the
 * accumulators; a NaN bound makes every box miss, as it makes every
 * triangle miss. */
inline float pn_ray_box(const pn_ray_slab *r, float tmin, float tmax, global const float4 *node)
{
    float3 lo = pn_load3(node), hi = pn_load3(node + 1);
    float3 near = select(lo, hi, r->neg), far = select(hi, lo, r->neg);
    float3 tn = (near - r->org) * r->inv;
    float3 tf = (far - r->org) * r->inv;
    float enter = pn_max_acc(pn_max_acc(pn_max_acc(tmin, tn.x), tn.y), tn.z);
    float leave = pn_min_acc(pn_min_acc(pn_min_acc(tmax, tf.x), tf.y), tf.z) * 1.00000024f;
    return enter <= leave ? enter : INFINITY;
}

/* Per-ray constants of the watertight test, with the axes permuted so that
 * z is the dominant direction axis (kz) and x, y the other two in the order
 * that keeps the winding (kx, ky): a point p maps to pn_permute(s, p) =
 * (p[kx], p[ky], p[kz]). */
typedef struct {
    int kz;           /* 0, 1, 2 */
    bool swap;        /* kx and ky exchanged (negative dominant direction) */
    float3 org;       /* permuted origin */
    float sx, sy, sz; /* shear */
} pn_ray_shear;

inline float pn_comp(float3 v, int k)
{
    return k == 0 ? v.x : (k == 1 ? v.y : v.z);
}

inline float3 pn_permute(const pn_ray_shear *s, float3 v)
{
    /* kz = 0: (y, z, x); kz = 1: (z, x, y); kz = 2: (x, y, z) */
    float3 r = s->kz == 0 ? v.yzx : (s->kz == 1 ? v.zxy : v);
    return s->swap ? r.yxz : r;
}

inline pn_ray_shear pn_make_shear(float3 org, float3 dir)
{
    pn_ray_shear s;
    float3 a = fabs(dir);
    s.kz = (a.x >= a.y && a.x >= a.z) ? 0 : (a.y >= a.z ? 1 : 2);
    float dz = pn_comp(dir, s.kz);
    s.swap = dz < 0.0f;
    float3 d = pn_permute(&s, dir);
    s.org = pn_permute(&s, org);
    s.sx = d.x / dz;
    s.sy = d.y / dz;
    s.sz = 1.0f / dz;
    return s;
}

/* Watertight ray-triangle test; on a hit in (tmin, tmax) returns true with t
 * and the barycentric weights (u of v1, v of v2). */
inline bool pn_ray_triangle(const pn_ray_shear *s, float tmin, float tmax, float3 v0, float3 v1, float3 v2,
                            float *t_out, float *u_out, float *v_out)
{
    /* No FMA contraction here: a shared edge's function is computed as
     * p.x*q.y - p.y*q.x in one triangle and q.x*p.y - q.y*p.x in the other,
     * exact negatives only when both products are rounded alike. A fused
     * multiply-add (OpenCL C contracts by default) breaks that, and rays
     * through shared edges then miss both triangles. */
#pragma OPENCL FP_CONTRACT OFF
    /* Permuting before subtracting the (permuted) origin gives the same
     * values as subtracting first: the operations are per component. */
    float3 A = pn_permute(s, v0) - s->org, B = pn_permute(s, v1) - s->org, C = pn_permute(s, v2) - s->org;
    float ax = A.x - s->sx * A.z, ay = A.y - s->sy * A.z;
    float bx = B.x - s->sx * B.z, by = B.y - s->sy * B.z;
    float cx = C.x - s->sx * C.z, cy = C.y - s->sy * C.z;
    float U = cx * by - cy * bx;
    float V = ax * cy - ay * cx;
    float W = bx * ay - by * ax;
    if ((U < 0.0f || V < 0.0f || W < 0.0f) && (U > 0.0f || V > 0.0f || W > 0.0f))
        return false;
    float det = U + V + W;
    if (det == 0.0f)
        return false;
    float T = s->sz * (U * A.z + V * B.z + W * C.z);
    float t = T / det;
    if (!(t > tmin && t < tmax))
        return false;
    *t_out = t;
    *u_out = V / det;
    *v_out = W / det;
    return true;
}

/* Pops the deferred node to visit next into stack index *sp; for closest
 * hits, nodes whose entry distance lies beyond the hit found meanwhile are
 * dropped. False when the stack is empty. */
inline bool pn_pop(const float *stack_t, int *sp, bool any_hit, float t_hit)
{
    while (*sp > 0) {
        --*sp;
        if (any_hit || stack_t[*sp] <= t_hit * 1.00000024f)
            return true;
    }
    return false;
}

/* Traverses one instance's BLAS in object space. any_hit: stop at the first
 * hit. Returns true if hit->t was lowered.
 *
 * Closest hit: children are visited nearer first, the farther one waits on
 * the stack with its entry distance, and a popped node whose entry lies
 * beyond a hit found meanwhile is skipped: the same test its box would fail
 * against the lowered tmax (leave = min(far, tmax) * c passed at push time
 * for the far planes, so only tmax * c can have changed). */
/* A leaf's triangles [first, first + count) of the instance in `slot` (its
 * triangles from tri_base on): the closest hit before hit->t goes into *hit.
 * Returns whether one was found; with any_hit it stops at the first. */
PN_TRACE_INLINE bool pn_leaf_triangles(const pn_ray_shear *shear, float tmin, global const float4 *tris, uint first,
                                       uint count, uint slot, uint tri_base, pn_hit *hit, bool any_hit)
{
    bool found = false;
    PN_STAT(hit, tests, count);
    for (uint k = first; k < first + count; ++k) {
        float t, u, v;
        if (pn_ray_triangle(shear, tmin, hit->t, pn_load3(tris + 3 * k), pn_load3(tris + 3 * k + 1),
                            pn_load3(tris + 3 * k + 2), &t, &u, &v)) {
            hit->t = t;
            hit->u = u;
            hit->v = v;
            hit->slot = slot;
            hit->tri = tri_base + k;
            found = true;
            if (any_hit)
                return true;
        }
    }
    return found;
}

#ifdef PN_TRI_SOA
/* A leaf's triangles four at a time (PN_TRI_SOA, set by the host for the wide
 * layouts unless PENUMBRA_TRI_SOA=0; capi/src/geometry/scene.c
 * writes the block: nine float4 of vertex coordinates, lane k the leaf's
 * k-th triangle, then (first slot, count) as uint bits). Each lane does
 * pn_ray_triangle's operations in its order, without contraction, so t, u
 * and v are bit-identical; of the lanes hit in (tmin, hit->t) the nearest
 * wins and among equal t the lowest lane, as in pn_leaf_triangles' loop
 * (any hit: the lowest lane hit). */
PN_TRACE_INLINE bool pn_leaf_soa(const pn_ray_shear *s, float tmin, global const float4 *block, uint slot,
                                 uint tri_base, pn_hit *hit, bool any_hit)
{
#pragma OPENCL FP_CONTRACT OFF
    uint4 ids = as_uint4(block[9]);
    PN_STAT(hit, tests, ids.y);
    /* pn_permute on the coordinate index: (kx, ky, kz). */
    int kx = s->kz == 0 ? 1 : (s->kz == 1 ? 2 : 0), ky = s->kz == 0 ? 2 : (s->kz == 1 ? 0 : 1);
    int px = s->swap ? ky : kx, py = s->swap ? kx : ky, pz = s->kz;
    float4 Ax = block[px] - s->org.x, Ay = block[py] - s->org.y, Az = block[pz] - s->org.z;
    float4 Bx = block[3 + px] - s->org.x, By = block[3 + py] - s->org.y, Bz = block[3 + pz] - s->org.z;
    float4 Cx = block[6 + px] - s->org.x, Cy = block[6 + py] - s->org.y, Cz = block[6 + pz] - s->org.z;
    float4 ax = Ax - s->sx * Az, ay = Ay - s->sy * Az;
    float4 bx = Bx - s->sx * Bz, by = By - s->sy * Bz;
    float4 cx = Cx - s->sx * Cz, cy = Cy - s->sy * Cz;
    float4 U = cx * by - cy * bx;
    float4 V = ax * cy - ay * cx;
    float4 W = bx * ay - by * ax;
    int4 ok = !((U < 0.0f | V < 0.0f | W < 0.0f) & (U > 0.0f | V > 0.0f | W > 0.0f));
    float4 det = U + V + W;
    float4 T = s->sz * (U * Az + V * Bz + W * Cz);
    float4 t = T / det;
    ok &= (det != 0.0f) & (t > tmin) & (t < hit->t) & ((int4)(0, 1, 2, 3) < (int4)(ids.y));
    if (!any(ok))
        return false;
    if (!any_hit) {
        float4 tc = select((float4)(INFINITY), t, ok);
        float m = fmin(fmin(tc.x, tc.y), fmin(tc.z, tc.w));
        ok &= tc == m;
    }
    uint k = ok.x ? 0 : (ok.y ? 1 : (ok.z ? 2 : 3));
    float dk = det[k];
    hit->t = t[k];
    hit->u = V[k] / dk;
    hit->v = W[k] / dk;
    hit->slot = slot;
    hit->tri = tri_base + ids.x + k;
    return true;
}
#endif

#if PN_BVH_WIDTH == 2
PN_TRACE_INLINE bool pn_trace_blas(pn_scene_view scene, uint slot, float3 org, float3 dir,
                                   const pn_ray_slab *world, float tmin, pn_hit *hit, bool any_hit)
{
    global const float4 *inst = scene.instances + slot * PN_INSTANCE_STRIDE;
    uint4 offs = as_uint4(inst[PN_INST_OFFSETS]);
    global const float4 *nodes = scene.blas + 2 * offs.x;
    global const float4 *tris = scene.tris + 3 * offs.y;
    float3 d;
    pn_ray_slab ray = pn_instance_ray(inst, offs.z, org, dir, world, &d);
    float3 o = ray.org;
    bool found = false;
    uint stack[PN_BVH_MAX_DEPTH];
    float stack_t[PN_BVH_MAX_DEPTH];
    int sp = 0;
    PN_STAT(hit, nodes, 1);
    PN_STAT(hit, boxes, 1);
    if (pn_ray_box(&ray, tmin, hit->t, nodes) == INFINITY)
        return false;
    pn_ray_shear shear = pn_make_shear(o, d);
    uint first = pn_load_w(nodes), count = pn_load_w(nodes + 1);
    for (;;) {
        if (count > 0) {
            if (pn_leaf_triangles(&shear, tmin, tris, first, count, slot, offs.y, hit, any_hit)) {
                found = true;
                if (any_hit)
                    return true;
            }
        } else {
            global const float4 *c = nodes + 2 * first;
            uint lf = pn_load_w(c), lc = pn_load_w(c + 1), rf = pn_load_w(c + 2), rc = pn_load_w(c + 3);
            PN_STAT(hit, nodes, 1);
            PN_STAT(hit, boxes, 2);
            float tl = pn_ray_box(&ray, tmin, hit->t, c);
            float tr = pn_ray_box(&ray, tmin, hit->t, c + 2);
            if (tl != INFINITY && tr != INFINITY) {
                /* Visit the nearer child first; the farther waits on the stack. */
                bool r_first = tr < tl;
                stack[sp] = r_first ? first : first + 1;
                if (!any_hit)
                    stack_t[sp] = r_first ? tl : tr;
                ++sp;
                first = r_first ? rf : lf;
                count = r_first ? rc : lc;
                continue;
            }
            if (tl != INFINITY) { first = lf; count = lc; continue; }
            if (tr != INFINITY) { first = rf; count = rc; continue; }
        }
        if (!pn_pop(stack_t, &sp, any_hit, hit->t))
            return found;
        first = pn_load_w(nodes + 2 * stack[sp]);
        count = pn_load_w(nodes + 2 * stack[sp] + 1);
    }
}

#else /* PN_BVH_WIDTH == 4 or 8 */

/* Larger (smaller) of acc and t per lane, acc where t is NaN: pn_max_acc /
 * pn_min_acc on four lanes. */
inline float4 pn_max_acc4(float4 acc, float4 t)
{
    return select(acc, t, t > acc);
}

inline float4 pn_min_acc4(float4 acc, float4 t)
{
    return select(acc, t, t < acc);
}

/* Entry distances into the four child boxes of a 4-wide node (bvh.h: lo_x,
 * hi_x, lo_y, hi_y, lo_z, hi_z as float4), INFINITY where the ray misses:
 * pn_ray_box lane by lane, the same operations in the same order, so each
 * lane's answer is bit-identical to the binary layout's test of that box.
 * Unused slots hold the empty box (lo = +inf, hi = -inf): for any finite
 * origin every near plane gives +inf and every far plane -inf (a zero
 * direction's inf reciprocal included), so they always miss. */
inline float4 pn_ray_box4(const pn_ray_slab *r, float tmin, float tmax, global const float4 *node)
{
    float4 lx = node[0], hx = node[1], ly = node[2], hy = node[3], lz = node[4], hz = node[5];
    float4 tnx = ((r->neg.x ? hx : lx) - r->org.x) * r->inv.x, tfx = ((r->neg.x ? lx : hx) - r->org.x) * r->inv.x;
    float4 tny = ((r->neg.y ? hy : ly) - r->org.y) * r->inv.y, tfy = ((r->neg.y ? ly : hy) - r->org.y) * r->inv.y;
    float4 tnz = ((r->neg.z ? hz : lz) - r->org.z) * r->inv.z, tfz = ((r->neg.z ? lz : hz) - r->org.z) * r->inv.z;
    float4 enter = pn_max_acc4(pn_max_acc4(pn_max_acc4((float4)(tmin), tnx), tny), tnz);
    float4 leave = pn_min_acc4(pn_min_acc4(pn_min_acc4((float4)(tmax), tfx), tfy), tfz) * 1.00000024f;
    return select((float4)(INFINITY), enter, enter <= leave);
}

/* Orders child (ta, ca, na) before (tb, cb, nb) by entry distance, with
 * selects rather than a branch. */
#define PN_CSWAP(ta, ca, na, tb, cb, nb)                                                                       \
    {                                                                                                        \
        bool sw_ = tb < ta;                                                                                  \
        float t_ = sw_ ? tb : ta; tb = sw_ ? ta : tb; ta = t_;                                               \
        uint c_ = sw_ ? cb : ca; cb = sw_ ? ca : cb; ca = c_;                                                \
        uint n_ = sw_ ? nb : na; nb = sw_ ? na : nb; na = n_;                                                \
    }

/* Defers a child the ray enters (t finite). Written unconditionally and
 * kept only when entered: no branch to mispredict. */
#define PN_PUSH(t, c, n)                                                                                     \
    stack[sp] = (c);                                                                                         \
    stack_n[sp] = (n);                                                                                       \
    stack_t[sp] = (t);                                                                                       \
    sp += (t) != INFINITY;

/* Deferred children: a 4-wide node leaves at most three behind per level
 * (and PN_PUSH writes one past the top). */
#define PN_BVH4_STACK (3 * PN_BVH_MAX_DEPTH + 1)

/* Pushes the children of 4-wide node n whose entry distances te are finite:
 * for closest hits sorted, farthest first, so the nearest is popped next;
 * for any hit in slot order (slot 0 popped next). */
inline void pn_push4(float4 te, global const float4 *n, bool any_hit, uint *stack, uint *stack_n, float *stack_t,
                     int *top)
{
    uint4 child = as_uint4(n[6]), cnt = as_uint4(n[7]);
    float t0 = te.s0, t1 = te.s1, t2 = te.s2, t3 = te.s3;
    uint c0 = child.s0, c1 = child.s1, c2 = child.s2, c3 = child.s3;
    uint n0 = cnt.s0, n1 = cnt.s1, n2 = cnt.s2, n3 = cnt.s3;
    if (!any_hit) {
        /* Sorting network: t0 <= t1 <= t2 <= t3 afterwards, misses (INFINITY) last. */
        PN_CSWAP(t0, c0, n0, t1, c1, n1);
        PN_CSWAP(t2, c2, n2, t3, c3, n3);
        PN_CSWAP(t0, c0, n0, t2, c2, n2);
        PN_CSWAP(t1, c1, n1, t3, c3, n3);
        PN_CSWAP(t1, c1, n1, t2, c2, n2);
    }
    int sp = *top;
    PN_PUSH(t3, c3, n3);
    PN_PUSH(t2, c2, n2);
    PN_PUSH(t1, c1, n1);
    PN_PUSH(t0, c0, n0);
    *top = sp;
}

/* 8-wide nodes (PENUMBRA_BVH_WIDTH=8, bvh.h pn_bvh8_node): the same test on
 * eight lanes (float8: the node's six bound arrays are six float8), so each
 * lane is again bit-identical to the binary test of that box. */
inline float8 pn_max_acc8(float8 acc, float8 t)
{
    return select(acc, t, t > acc);
}

inline float8 pn_min_acc8(float8 acc, float8 t)
{
    return select(acc, t, t < acc);
}

inline float8 pn_ray_box8(const pn_ray_slab *r, float tmin, float tmax, global const float4 *node)
{
    global const float8 *w = (global const float8 *)node;
    float8 lx = w[0], hx = w[1], ly = w[2], hy = w[3], lz = w[4], hz = w[5];
    float8 tnx = ((r->neg.x ? hx : lx) - r->org.x) * r->inv.x, tfx = ((r->neg.x ? lx : hx) - r->org.x) * r->inv.x;
    float8 tny = ((r->neg.y ? hy : ly) - r->org.y) * r->inv.y, tfy = ((r->neg.y ? ly : hy) - r->org.y) * r->inv.y;
    float8 tnz = ((r->neg.z ? hz : lz) - r->org.z) * r->inv.z, tfz = ((r->neg.z ? lz : hz) - r->org.z) * r->inv.z;
    float8 enter = pn_max_acc8(pn_max_acc8(pn_max_acc8((float8)(tmin), tnx), tny), tnz);
    float8 leave = pn_min_acc8(pn_min_acc8(pn_min_acc8((float8)(tmax), tfx), tfy), tfz) * 1.00000024f;
    return select((float8)(INFINITY), enter, enter <= leave);
}

/* pn_push4 for the eight children of an 8-wide node. Closest hits: one or
 * two children entered (most nodes) need no sorting: the farther goes on
 * the stack and the nearer one is handed back (*have, *next_first,
 * *next_count) for the walk to visit next without a store and a load of the
 * stack (measured: primary rays 1.05-1.11x in CPU time; built with
 * -DPN_STACK_NEAREST it is pushed too, as before, for A/B). The walk would
 * pop it next anyway and its entry test against the hit distance, which
 * has not changed since the node test, always passes, so the order of
 * visits and every answer are the same. More than two entered children are
 * sorted with the 19-comparator network for eight and all pushed (handing
 * back their nearest too measured 0.99-1.01x) (measured: the network alone
 * made primary rays 0.68-0.78x the 4-wide walk; the shortcut is
 * 1.27-1.33x faster than it). */
inline void pn_push8(float8 te, global const float4 *node, bool any_hit, uint *stack, uint *stack_n, float *stack_t,
                     int *top, bool *have, uint *next_first, uint *next_count)
{
    *have = false;
    global const float8 *w = (global const float8 *)node;
    uint8 child = as_uint8(w[6]), cnt = as_uint8(w[7]);
    float t0 = te.s0, t1 = te.s1, t2 = te.s2, t3 = te.s3, t4 = te.s4, t5 = te.s5, t6 = te.s6, t7 = te.s7;
    uint c0 = child.s0, c1 = child.s1, c2 = child.s2, c3 = child.s3, c4 = child.s4, c5 = child.s5, c6 = child.s6,
         c7 = child.s7;
    uint n0 = cnt.s0, n1 = cnt.s1, n2 = cnt.s2, n3 = cnt.s3, n4 = cnt.s4, n5 = cnt.s5, n6 = cnt.s6, n7 = cnt.s7;
    if (!any_hit) {
        /* Most nodes are entered through one or two children: those need no
         * sorting network (one compare for two). */
        uint8 bit = as_uint8(te != (float8)(INFINITY)) & (uint8)(1, 2, 4, 8, 16, 32, 64, 128);
        uint4 b4 = bit.lo | bit.hi;
        uint2 b2 = b4.lo | b4.hi;
        uint mask = b2.x | b2.y;
        if (popcount(mask) <= 2) {
            int sp = *top;
            if (mask) {
                uint a = 31 - clz(mask & (0u - mask)), b = 31 - clz(mask);
                float ta = te[a], tb = te[b];
                bool near_a = ta <= tb;
                uint ca = child[a], cb = child[b], na = cnt[a], nb = cnt[b];
                /* Farther one first (b == a pushes the single child twice, the second overwriting the first). */
                stack[sp] = near_a ? cb : ca;
                stack_n[sp] = near_a ? nb : na;
                stack_t[sp] = near_a ? tb : ta;
                sp += a != b;
#ifndef PN_STACK_NEAREST
                /* The nearer one is visited next without the stack. */
                *have = true;
                *next_first = near_a ? ca : cb;
                *next_count = near_a ? na : nb;
#else
                stack[sp] = near_a ? ca : cb;
                stack_n[sp] = near_a ? na : nb;
                stack_t[sp] = near_a ? ta : tb;
                ++sp;
#endif
            }
            *top = sp;
            return;
        }
    }
    if (!any_hit) {
        PN_CSWAP(t0, c0, n0, t2, c2, n2);
        PN_CSWAP(t1, c1, n1, t3, c3, n3);
        PN_CSWAP(t4, c4, n4, t6, c6, n6);
        PN_CSWAP(t5, c5, n5, t7, c7, n7);
        PN_CSWAP(t0, c0, n0, t4, c4, n4);
        PN_CSWAP(t1, c1, n1, t5, c5, n5);
        PN_CSWAP(t2, c2, n2, t6, c6, n6);
        PN_CSWAP(t3, c3, n3, t7, c7, n7);
        PN_CSWAP(t0, c0, n0, t1, c1, n1);
        PN_CSWAP(t2, c2, n2, t3, c3, n3);
        PN_CSWAP(t4, c4, n4, t5, c5, n5);
        PN_CSWAP(t6, c6, n6, t7, c7, n7);
        PN_CSWAP(t2, c2, n2, t4, c4, n4);
        PN_CSWAP(t3, c3, n3, t5, c5, n5);
        PN_CSWAP(t1, c1, n1, t4, c4, n4);
        PN_CSWAP(t3, c3, n3, t6, c6, n6);
        PN_CSWAP(t1, c1, n1, t2, c2, n2);
        PN_CSWAP(t3, c3, n3, t4, c4, n4);
        PN_CSWAP(t5, c5, n5, t6, c6, n6);
    }
    int sp = *top;
    PN_PUSH(t7, c7, n7);
    PN_PUSH(t6, c6, n6);
    PN_PUSH(t5, c5, n5);
    PN_PUSH(t4, c4, n4);
    PN_PUSH(t3, c3, n3);
    PN_PUSH(t2, c2, n2);
    PN_PUSH(t1, c1, n1);
    PN_PUSH(t0, c0, n0);
    *top = sp;
}

/* The walk below serves both wide layouts: node size in float4, stack
 * depth (a node leaves at most width - 1 children behind per level, and
 * PN_PUSH writes one past the top), node test and push. */
#if PN_BVH_WIDTH == 8
#define PN_NODE_F4 16
#define PN_WIDE_STACK (7 * PN_BVH_MAX_DEPTH + 1)
#define PN_WIDE_TEST_PUSH(ray, tmin, tmax, n, any_hit, stack, stack_n, stack_t, sp, have, nf, nc)                      \
    pn_push8(pn_ray_box8(ray, tmin, tmax, n), n, any_hit, stack, stack_n, stack_t, sp, have, nf, nc)
#else
#define PN_NODE_F4 8
#define PN_WIDE_STACK PN_BVH4_STACK
#define PN_WIDE_TEST_PUSH(ray, tmin, tmax, n, any_hit, stack, stack_n, stack_t, sp, have, nf, nc)                      \
    (*(have) = false, pn_push4(pn_ray_box4(ray, tmin, tmax, n), n, any_hit, stack, stack_n, stack_t, sp))
#endif

/* The wide walks' next entry: the child the node test handed back (have:
 * the nearer one, visited without the stack), else the stack's top.
 * Returns false when the stack is empty. */
inline bool pn_next_entry(bool *have, uint next_first, uint next_count, const uint *stack, const uint *stack_n,
                          const float *stack_t, int *sp, bool any_hit, float t_hit, uint *first, uint *count)
{
    if (*have) {
        *have = false;
        *first = next_first;
        *count = next_count;
        return true;
    }
    if (!pn_pop(stack_t, sp, any_hit, t_hit))
        return false;
    *first = stack[*sp];
    *count = stack_n[*sp];
    return true;
}

/* Traverses one instance's 4-wide BLAS in object space (bvh.h, pn_bvh4_node).
 * any_hit: stop at the first hit. Returns true if hit->t was lowered.
 *
 * Each visited node tests its four child boxes at once and pushes the hit
 * children (leaves included) on one stack; for closest hits they go
 * farthest first, so the nearest is popped next, and a popped entry whose
 * entry distance lies beyond a hit found meanwhile is dropped (as in the
 * binary walk: only tmax can have changed since the test). The 8-wide push
 * may hand the nearest child back instead (have): it is visited next, as
 * the pop would have done. */
PN_TRACE_INLINE bool pn_trace_blas(pn_scene_view scene, uint slot, float3 org, float3 dir,
                                   const pn_ray_slab *world, float tmin, pn_hit *hit, bool any_hit)
{
    global const float4 *inst = scene.instances + slot * PN_INSTANCE_STRIDE;
    uint4 offs = as_uint4(inst[PN_INST_OFFSETS]);
    global const float4 *nodes = scene.blas + PN_NODE_F4 * offs.x;
    global const float4 *tris = scene.tris + 3 * offs.y;
#ifdef PN_TRI_SOA
    (void)tris; /* the leaves' blocks follow the nodes */
#endif
    float3 d;
    pn_ray_slab ray = pn_instance_ray(inst, offs.z, org, dir, world, &d);
    float3 o = ray.org;
    pn_ray_shear shear;
    bool sheared = false, found = false;
    uint stack[PN_WIDE_STACK], stack_n[PN_WIDE_STACK];
    float stack_t[PN_WIDE_STACK];
    int sp = 0;
    uint node = 0;
    for (;;) {
        global const float4 *n = nodes + PN_NODE_F4 * node;
        PN_STAT(hit, nodes, 1);
        PN_STAT(hit, boxes, PN_BVH_WIDTH);
        bool have;
        uint next_first, next_count;
        PN_WIDE_TEST_PUSH(&ray, tmin, hit->t, n, any_hit, stack, stack_n, stack_t, &sp, &have, &next_first,
                          &next_count);
        /* Next interior node; leaves on the way are tested here. */
        for (;;) {
            uint first, count;
            if (!pn_next_entry(&have, next_first, next_count, stack, stack_n, stack_t, &sp, any_hit, hit->t, &first,
                               &count))
                return found;
            if (count == 0) {
                node = first;
                break;
            }
            if (!sheared) {
                shear = pn_make_shear(o, d);
                sheared = true;
            }
#ifdef PN_TRI_SOA
            if (pn_leaf_soa(&shear, tmin, nodes + first, slot, offs.y, hit, any_hit)) {
#else
            if (pn_leaf_triangles(&shear, tmin, tris, first, count, slot, offs.y, hit, any_hit)) {
#endif
                found = true;
                if (any_hit)
                    return true;
            }
        }
    }
}
#endif

/* The hit both layouts' walks start from: nothing found before tmax. */
PN_TRACE_INLINE void pn_clear_hit(pn_hit *hit, float tmax)
{
    hit->t = tmax;
    hit->slot = PN_BACKGROUND;
    hit->tri = PN_BACKGROUND;
    hit->u = hit->v = 0.0f;
#ifdef PN_RAY_STATS
    hit->nodes = hit->boxes = hit->tests = 0;
#endif
}

inline bool pn_ray_is_finite(float3 org, float3 dir)
{
    return isfinite(org.x) && isfinite(org.y) && isfinite(org.z) && isfinite(dir.x) && isfinite(dir.y) &&
           isfinite(dir.z);
}

#if PN_BVH_WIDTH == 2
/* Closest (any_hit = false) or any (any_hit = true) intersection with the
 * scene in (tmin, tmax). hit->t is INFINITY-free only when true is returned. */
PN_TRACE_INLINE bool pn_trace(pn_scene_view scene, float3 org, float3 dir, float tmin, float tmax, pn_hit *hit, bool any_hit)
{
    pn_clear_hit(hit, tmax);
    /* A ray made on the device from unchecked data (a caller's G-buffer is
     * only checked by pn_gbuffer_validate) may hold NaN or Inf: the slab
     * tests would then enter empty child slots and overflow the stack. Such
     * a ray misses. */
    if (scene.instance_count == 0 || !pn_ray_is_finite(org, dir))
        return false;
    /* One instance: its BLAS root box test does the TLAS root's job. */
    if (scene.instance_count == 1)
        return pn_trace_blas(scene, 0, org, dir, NULL, tmin, hit, any_hit);
    pn_ray_slab ray = pn_make_slab(org, dir);
    bool found = false;
    uint stack[PN_BVH_MAX_DEPTH];
    float stack_t[PN_BVH_MAX_DEPTH];
    int sp = 0;
    uint node = 0;
    global const float4 *nodes = scene.tlas;
    PN_STAT(hit, nodes, 1);
    PN_STAT(hit, boxes, 1);
    if (pn_ray_box(&ray, tmin, tmax, nodes) == INFINITY)
        return false;
    for (;;) {
        uint first = pn_load_w(nodes + 2 * node), count = pn_load_w(nodes + 2 * node + 1);
        if (count > 0) {
            for (uint k = first; k < first + count; ++k) {
                if (pn_trace_blas(scene, k, org, dir, &ray, tmin, hit, any_hit)) {
                    found = true;
                    if (any_hit)
                        return true;
                }
            }
        } else {
            uint left = first, right = first + 1;
            PN_STAT(hit, nodes, 1);
            PN_STAT(hit, boxes, 2);
            float tl = pn_ray_box(&ray, tmin, hit->t, nodes + 2 * left);
            float tr = pn_ray_box(&ray, tmin, hit->t, nodes + 2 * right);
            if (tl != INFINITY && tr != INFINITY) {
                bool r_first = tr < tl;
                stack[sp] = r_first ? left : right;
                if (!any_hit)
                    stack_t[sp] = r_first ? tl : tr;
                ++sp;
                node = r_first ? right : left;
                continue;
            }
            if (tl != INFINITY) { node = left; continue; }
            if (tr != INFINITY) { node = right; continue; }
        }
        if (!pn_pop(stack_t, &sp, any_hit, hit->t))
            return found;
        node = stack[sp];
    }
}

#else
/* Closest (any_hit = false) or any (any_hit = true) intersection with the
 * scene in (tmin, tmax). hit->t is INFINITY-free only when true is returned.
 * The TLAS is 4-wide like the BLAS (a scene of up to four instances is one
 * node); its leaves hold instance records. */
PN_TRACE_INLINE bool pn_trace(pn_scene_view scene, float3 org, float3 dir, float tmin, float tmax, pn_hit *hit, bool any_hit)
{
    pn_clear_hit(hit, tmax);
    /* A ray made on the device from unchecked data (a caller's G-buffer is
     * only checked by pn_gbuffer_validate) may hold NaN or Inf: the slab
     * tests would then enter empty child slots and overflow the stack. Such
     * a ray misses. */
    if (scene.instance_count == 0 || !pn_ray_is_finite(org, dir))
        return false;
    /* One instance: its BLAS root node does the TLAS root's job. */
    if (scene.instance_count == 1)
        return pn_trace_blas(scene, 0, org, dir, NULL, tmin, hit, any_hit);
    pn_ray_slab ray = pn_make_slab(org, dir);
    bool found = false;
    uint stack[PN_WIDE_STACK], stack_n[PN_WIDE_STACK];
    float stack_t[PN_WIDE_STACK];
    int sp = 0;
    uint node = 0;
    for (;;) {
        global const float4 *n = scene.tlas + PN_NODE_F4 * node;
        PN_STAT(hit, nodes, 1);
        PN_STAT(hit, boxes, PN_BVH_WIDTH);
        bool have;
        uint next_first, next_count;
        PN_WIDE_TEST_PUSH(&ray, tmin, hit->t, n, any_hit, stack, stack_n, stack_t, &sp, &have, &next_first,
                          &next_count);
        for (;;) {
            uint first, count;
            if (!pn_next_entry(&have, next_first, next_count, stack, stack_n, stack_t, &sp, any_hit, hit->t, &first,
                               &count))
                return found;
            if (count == 0) {
                node = first;
                break;
            }
            for (uint k = first; k < first + count; ++k) {
                if (pn_trace_blas(scene, k, org, dir, &ray, tmin, hit, any_hit)) {
                    found = true;
                    if (any_hit)
                        return true;
                }
            }
        }
    }
}
#endif

#endif
