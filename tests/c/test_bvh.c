/* Tests for the host BVH builder (capi/src/bvh.c): structural invariants on
 * awkward inputs, and closest-hit ray queries through the BVH checked against
 * brute force. Last line printed: "N passed, N failed"; exit status nonzero on
 * any failure. */
#include "geometry/bvh.h"

#include <math.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

static int g_passed, g_failed;
static int g_case_errors;

static void fail(const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    fputs("    FAIL: ", stdout);
    vprintf(fmt, ap);
    fputc('\n', stdout);
    va_end(ap);
    g_case_errors++;
}

#define CHECK(cond, ...)              \
    do {                              \
        if (!(cond))                  \
            fail(__VA_ARGS__);        \
    } while (0)

static void case_begin(const char *name)
{
    printf("%s\n", name);
    g_case_errors = 0;
}

static void case_end(void)
{
    if (g_case_errors) {
        g_failed++;
        printf("  -> failed (%d errors)\n", g_case_errors);
    } else {
        g_passed++;
    }
}

static double now_s(void)
{
    struct timespec ts;
    timespec_get(&ts, TIME_UTC);
    return (double)ts.tv_sec + ts.tv_nsec * 1e-9;
}

/* ---- random numbers (splitmix64: reproducible across platforms) ---- */

static uint64_t g_rng = 0x9E3779B97F4A7C15ull;

static uint64_t rng_u64(void)
{
    uint64_t z = (g_rng += 0x9E3779B97F4A7C15ull);
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
    return z ^ (z >> 31);
}

static float rnd(void) /* [0, 1) */
{
    return (float)(rng_u64() >> 40) * (1.0f / 16777216.0f);
}

static float rnd_range(float lo, float hi)
{
    return lo + (hi - lo) * rnd();
}

/* ---- geometry ---- */

typedef struct tri {
    float v[3][3];
} tri;

typedef struct ray {
    float o[3], d[3];
} ray;

static void sub3(float *r, const float *a, const float *b)
{
    for (int i = 0; i < 3; i++)
        r[i] = a[i] - b[i];
}

static void cross3(float *r, const float *a, const float *b)
{
    r[0] = a[1] * b[2] - a[2] * b[1];
    r[1] = a[2] * b[0] - a[0] * b[2];
    r[2] = a[0] * b[1] - a[1] * b[0];
}

static float dot3(const float *a, const float *b)
{
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}

static pn_aabb tri_box(const tri *t)
{
    pn_aabb b;
    for (int a = 0; a < 3; a++) {
        b.lo[a] = fminf(t->v[0][a], fminf(t->v[1][a], t->v[2][a]));
        b.hi[a] = fmaxf(t->v[0][a], fmaxf(t->v[1][a], t->v[2][a]));
    }
    return b;
}

/* Möller–Trumbore; returns the hit distance or INFINITY. Near-degenerate
 * triangles are rejected (relative threshold) so both query paths agree on
 * geometry whose hit point would be numerically meaningless. */
static float tri_hit(const ray *r, const tri *t)
{
    float e1[3], e2[3], p[3], s[3], q[3];
    sub3(e1, t->v[1], t->v[0]);
    sub3(e2, t->v[2], t->v[0]);
    cross3(p, r->d, e2);
    float det = dot3(e1, p);
    float scale = sqrtf(dot3(e1, e1) * dot3(e2, e2));
    if (!(fabsf(det) > 1e-6f * scale))
        return INFINITY;
    float inv = 1.0f / det;
    sub3(s, r->o, t->v[0]);
    float u = dot3(s, p) * inv;
    if (u < 0.0f || u > 1.0f)
        return INFINITY;
    cross3(q, s, e1);
    float v = dot3(r->d, q) * inv;
    if (v < 0.0f || u + v > 1.0f)
        return INFINITY;
    float dist = dot3(e2, q) * inv;
    return dist > 1e-6f ? dist : INFINITY;
}

/* Slab test. The box is padded (relative to the magnitudes involved) so float
 * error in the slab or triangle math cannot cull a triangle that brute force
 * hits; padding only costs visits, it cannot hide a builder bug because exact
 * containment is checked separately. */
static int ray_box(const ray *r, const float *lo, const float *hi, float tmax)
{
    float t0 = 0.0f, t1 = tmax;
    float mag = 1.0f;
    for (int a = 0; a < 3; a++)
        mag = fmaxf(mag, fmaxf(fabsf(r->o[a]), fmaxf(fabsf(lo[a]), fabsf(hi[a]))));
    float pad = 1e-3f * mag;
    for (int a = 0; a < 3; a++) {
        float l = lo[a] - pad, h = hi[a] + pad;
        if (r->d[a] == 0.0f) {
            if (r->o[a] < l || r->o[a] > h)
                return 0;
            continue;
        }
        float inv = 1.0f / r->d[a];
        float ta = (l - r->o[a]) * inv, tb = (h - r->o[a]) * inv;
        if (ta > tb) {
            float tmp = ta;
            ta = tb;
            tb = tmp;
        }
        t0 = ta > t0 ? ta : t0;
        t1 = tb < t1 ? tb : t1;
        if (t0 > t1)
            return 0;
    }
    return 1;
}

static float brute_force(const ray *r, const tri *tris, uint32_t n, uint32_t *prim)
{
    float best = INFINITY;
    *prim = UINT32_MAX;
    for (uint32_t i = 0; i < n; i++) {
        float t = tri_hit(r, &tris[i]);
        if (t < best) {
            best = t;
            *prim = i;
        }
    }
    return best;
}

/* Same scheme as a kernel with a fixed stack: visit one child, push the other.
 * A stack of PN_BVH_MAX_DEPTH entries must never overflow. */
static float bvh_query(const pn_bvh *bvh, const ray *r, const tri *tris, uint32_t *prim, int *overflow)
{
    uint32_t stack[PN_BVH_MAX_DEPTH];
    int sp = 0;
    float best = INFINITY;
    *prim = UINT32_MAX;
    uint32_t ni = 0;
    if (!ray_box(r, bvh->nodes[0].lo, bvh->nodes[0].hi, best))
        return best;
    for (;;) {
        const pn_bvh_node *n = &bvh->nodes[ni];
        if (n->count > 0) {
            for (uint32_t k = n->left_or_first; k < n->left_or_first + n->count; k++) {
                uint32_t p = bvh->order[k];
                float t = tri_hit(r, &tris[p]);
                if (t < best) {
                    best = t;
                    *prim = p;
                }
            }
        } else {
            uint32_t c = n->left_or_first;
            int hl = ray_box(r, bvh->nodes[c].lo, bvh->nodes[c].hi, best);
            int hr = ray_box(r, bvh->nodes[c + 1].lo, bvh->nodes[c + 1].hi, best);
            if (hl && hr) {
                if (sp == PN_BVH_MAX_DEPTH) {
                    *overflow = 1;
                    return best;
                }
                stack[sp++] = c + 1;
                ni = c;
                continue;
            }
            if (hl || hr) {
                ni = hl ? c : c + 1;
                continue;
            }
        }
        if (sp == 0)
            break;
        ni = stack[--sp];
    }
    return best;
}

/* ---- invariants ---- */

static int box_contains(const float *olo, const float *ohi, const float *ilo, const float *ihi)
{
    for (int a = 0; a < 3; a++)
        if (!(olo[a] <= ilo[a] && ihi[a] <= ohi[a]))
            return 0;
    return 1;
}

static void check_invariants(const pn_bvh *bvh, const pn_aabb *boxes, uint32_t n, uint32_t max_leaf)
{
    CHECK(bvh->nodes && bvh->order, "null arrays");
    if (!bvh->nodes || !bvh->order)
        return;
    CHECK(bvh->prim_count == n, "prim_count %u != %u", bvh->prim_count, n);
    CHECK(bvh->node_count >= 1 && bvh->node_count <= 2 * (uint64_t)n - 1, "node_count %u for %u prims",
          bvh->node_count, n);
    CHECK(bvh->depth >= 1 && bvh->depth <= PN_BVH_MAX_DEPTH, "depth %u out of range", bvh->depth);

    uint8_t *seen = calloc(n, 1);
    uint8_t *slot = calloc(n, 1);
    uint8_t *visited = calloc(bvh->node_count, 1);
    uint32_t *stack = malloc(sizeof(uint32_t) * bvh->node_count);
    uint32_t *sdepth = malloc(sizeof(uint32_t) * bvh->node_count);
    if (!seen || !slot || !visited || !stack || !sdepth) {
        fail("test out of memory");
        goto out;
    }

    /* order is a permutation */
    int perm_errors = 0;
    for (uint32_t i = 0; i < n; i++) {
        uint32_t p = bvh->order[i];
        if (p >= n || seen[p]++)
            perm_errors++;
    }
    CHECK(perm_errors == 0, "order is not a permutation (%d bad entries)", perm_errors);

    /* root bounds are exactly the union of all boxes */
    pn_aabb all = boxes[0];
    for (uint32_t i = 1; i < n; i++)
        for (int a = 0; a < 3; a++) {
            all.lo[a] = fminf(all.lo[a], boxes[i].lo[a]);
            all.hi[a] = fmaxf(all.hi[a], boxes[i].hi[a]);
        }
    CHECK(memcmp(all.lo, bvh->nodes[0].lo, sizeof(all.lo)) == 0 &&
              memcmp(all.hi, bvh->nodes[0].hi, sizeof(all.hi)) == 0,
          "root box is not the scene bounds");

    int errors = 0, shown = 0;
#define TREE_ERR(...)                              \
    do {                                           \
        errors++;                                  \
        if (shown++ < 5)                           \
            fail(__VA_ARGS__);                     \
    } while (0)
    uint32_t sp = 0, max_depth = 0;
    stack[sp] = 0;
    sdepth[sp++] = 1;
    visited[0] = 1;
    while (sp > 0) {
        sp--;
        uint32_t ni = stack[sp], d = sdepth[sp];
        const pn_bvh_node *nd = &bvh->nodes[ni];
        if (d > max_depth)
            max_depth = d;
        for (int a = 0; a < 3; a++)
            if (!(nd->lo[a] <= nd->hi[a]))
                TREE_ERR("node %u: inverted box on axis %d", ni, a);
        if (nd->count > 0) {
            if (nd->count > max_leaf)
                TREE_ERR("node %u: leaf of %u > max_leaf %u", ni, nd->count, max_leaf);
            if ((uint64_t)nd->left_or_first + nd->count > n) {
                TREE_ERR("node %u: leaf range %u+%u out of bounds", ni, nd->left_or_first, nd->count);
                continue;
            }
            for (uint32_t k = nd->left_or_first; k < nd->left_or_first + nd->count; k++) {
                if (slot[k]++)
                    TREE_ERR("slot %u covered by more than one leaf", k);
                uint32_t p = bvh->order[k];
                if (p < n && !box_contains(nd->lo, nd->hi, boxes[p].lo, boxes[p].hi))
                    TREE_ERR("node %u: leaf box misses primitive %u", ni, p);
            }
        } else {
            uint32_t c = nd->left_or_first;
            /* children are the adjacent pair c, c+1; never the root */
            if (c == 0 || (uint64_t)c + 1 >= bvh->node_count) {
                TREE_ERR("node %u: children %u,%u out of range", ni, c, c + 1);
                continue;
            }
            for (uint32_t k = c; k <= c + 1; k++) {
                if (visited[k]++) {
                    TREE_ERR("node %u reached twice (shared child or cycle)", k);
                    continue;
                }
                if (!box_contains(nd->lo, nd->hi, bvh->nodes[k].lo, bvh->nodes[k].hi))
                    TREE_ERR("node %u: box does not contain child %u", ni, k);
                stack[sp] = k;
                sdepth[sp++] = d + 1;
            }
        }
    }
#undef TREE_ERR
    uint32_t unreached = 0, uncovered = 0;
    for (uint32_t i = 0; i < bvh->node_count; i++)
        unreached += !visited[i];
    for (uint32_t i = 0; i < n; i++)
        uncovered += !slot[i];
    CHECK(unreached == 0, "%u nodes unreachable from the root", unreached);
    CHECK(uncovered == 0, "%u order slots in no leaf", uncovered);
    CHECK(max_depth == bvh->depth, "reported depth %u, actual %u", bvh->depth, max_depth);
    CHECK(max_depth <= PN_BVH_MAX_DEPTH, "depth %u exceeds PN_BVH_MAX_DEPTH", max_depth);

out:
    free(seen);
    free(slot);
    free(visited);
    free(stack);
    free(sdepth);
}

/* ---- scenes ---- */

static void random_tri(tri *t, float size)
{
    float c[3] = {rnd(), rnd(), rnd()};
    for (int k = 0; k < 3; k++)
        for (int a = 0; a < 3; a++)
            t->v[k][a] = c[a] + rnd_range(-size, size);
}

/* Zero-area: all three vertices equal, or collinear. */
static void degenerate_tri(tri *t, float size)
{
    float c[3] = {rnd(), rnd(), rnd()};
    float d[3] = {rnd_range(-size, size), rnd_range(-size, size), rnd_range(-size, size)};
    int point = rng_u64() & 1;
    for (int k = 0; k < 3; k++)
        for (int a = 0; a < 3; a++)
            t->v[k][a] = point ? c[a] : c[a] + d[a] * (float)k;
}

/* A quarter of the rays go between random points of the scene, half aim at a
 * random point of a random triangle from anywhere around the scene, and a
 * quarter aim at one from close by, so dense clusters get probed too. */
static void make_ray(ray *r, const tri *tris, uint32_t n, const pn_aabb *scene)
{
    const tri *t = &tris[rng_u64() % n];
    const pn_aabb tb = tri_box(t);
    int mode = (int)(rng_u64() % 4);
    float u = rnd(), v = rnd();
    if (u + v > 1.0f) {
        u = 1.0f - u;
        v = 1.0f - v;
    }
    float target[3], local = 0.0f;
    for (int a = 0; a < 3; a++) {
        target[a] = t->v[0][a] + u * (t->v[1][a] - t->v[0][a]) + v * (t->v[2][a] - t->v[0][a]);
        local = fmaxf(local, tb.hi[a] - tb.lo[a]);
    }
    if (!(local > 0.0f))
        local = 1e-3f * (1.0f + fmaxf(fabsf(target[0]), fmaxf(fabsf(target[1]), fabsf(target[2]))));
    float dist = local * rnd_range(0.5f, 4.0f);
    for (int a = 0; a < 3; a++) {
        float ext = scene->hi[a] - scene->lo[a] + 1e-3f;
        if (mode == 3) {
            r->o[a] = target[a] + dist * rnd_range(-1.0f, 1.0f);
        } else {
            r->o[a] = rnd_range(scene->lo[a] - 0.5f * ext, scene->hi[a] + 0.5f * ext);
            if (mode == 0)
                target[a] = rnd_range(scene->lo[a], scene->hi[a]);
        }
    }
    /* Normalize via the largest component: squares of huge scenes overflow. */
    float m = 0.0f;
    for (int a = 0; a < 3; a++) {
        r->d[a] = target[a] - r->o[a];
        m = fmaxf(m, fabsf(r->d[a]));
    }
    if (!(m > 0.0f && m < INFINITY)) {
        r->d[0] = 1.0f;
        r->d[1] = r->d[2] = 0.0f;
        return;
    }
    for (int a = 0; a < 3; a++)
        r->d[a] /= m;
    float inv = 1.0f / sqrtf(dot3(r->d, r->d));
    for (int a = 0; a < 3; a++)
        r->d[a] *= inv;
}

/* Returns the number of rays that hit something. */
static int check_rays(const pn_bvh *bvh, const tri *tris, uint32_t n, int nrays)
{
    const pn_aabb scene = {{bvh->nodes[0].lo[0], bvh->nodes[0].lo[1], bvh->nodes[0].lo[2]},
                           {bvh->nodes[0].hi[0], bvh->nodes[0].hi[1], bvh->nodes[0].hi[2]}};
    int mismatches = 0, hits = 0, overflow = 0;
    for (int i = 0; i < nrays; i++) {
        ray r;
        make_ray(&r, tris, n, &scene);
        uint32_t pb, pq;
        float tb = brute_force(&r, tris, n, &pb);
        float tq = bvh_query(bvh, &r, tris, &pq, &overflow);
        hits += tb < INFINITY;
        /* Distances must match exactly; with coincident triangles the prim may
         * differ, but it must then really be hit at that same distance. */
        int ok = tb == tq || (tb != tb && tq != tq);
        if (ok && pq != pb)
            ok = pq < n && tri_hit(&r, &tris[pq]) == tb;
        if (!ok && mismatches++ < 5)
            fail("ray %d: brute force t=%.9g prim %u, bvh t=%.9g prim %u", i, tb, pb, tq, pq);
    }
    CHECK(mismatches == 0, "%d/%d rays disagree with brute force", mismatches, nrays);
    CHECK(!overflow, "traversal stack of PN_BVH_MAX_DEPTH overflowed");
    printf("  %d rays, %d hits, depth %u, %u nodes\n", nrays, hits, bvh->depth, bvh->node_count);
    return hits;
}

/* ---- the 4- and 8-wide collapses ---- */

/* A wide tree of either width: pn_bvh4_node and pn_bvh8_node are eight
 * arrays of `width` 32-bit words (lo_x, hi_x, lo_y, hi_y, lo_z, hi_z, child,
 * count), read through these helpers. */
typedef struct {
    const unsigned char *nodes;
    uint32_t node_count, depth;
    int width;
} wide_tree;

static wide_tree wide4(const pn_bvh4 *w)
{
    wide_tree t = {(const unsigned char *)w->nodes, w->node_count, w->depth, 4};
    return t;
}

static wide_tree wide8(const pn_bvh8 *w)
{
    wide_tree t = {(const unsigned char *)w->nodes, w->node_count, w->depth, 8};
    return t;
}

static uint32_t node_word(const wide_tree *w, uint32_t ni, int array, int k)
{
    uint32_t v;
    memcpy(&v, w->nodes + 32u * (size_t)w->width * ni + 4u * ((size_t)array * w->width + k), 4);
    return v;
}

static uint32_t slot_child(const wide_tree *w, uint32_t ni, int k) { return node_word(w, ni, 6, k); }
static uint32_t slot_count(const wide_tree *w, uint32_t ni, int k) { return node_word(w, ni, 7, k); }

static void slot_box(const wide_tree *w, uint32_t ni, int k, float *lo, float *hi)
{
    for (int a = 0; a < 3; ++a) {
        uint32_t l = node_word(w, ni, 2 * a, k), h = node_word(w, ni, 2 * a + 1, k);
        memcpy(&lo[a], &l, 4);
        memcpy(&hi[a], &h, 4);
    }
}

/* The kernel's scheme (kernels/common/raytrace.cl): test the child boxes,
 * push every child hit (leaves too), pop; a stack of
 * (width - 1) * PN_BVH_MAX_DEPTH + 1 entries must never overflow. */
static float wide_query(const wide_tree *w, const pn_bvh *bvh, const ray *r, const tri *tris, uint32_t *prim,
                        int *overflow)
{
    enum { STACK_MAX = 7 * PN_BVH_MAX_DEPTH + 1 };
    const int STACK = (w->width - 1) * PN_BVH_MAX_DEPTH + 1;
    uint32_t stack[STACK_MAX], stack_n[STACK_MAX];
    int sp = 0;
    float best = INFINITY;
    *prim = UINT32_MAX;
    uint32_t ni = 0;
    for (;;) {
        for (int k = w->width - 1; k >= 0; --k) {
            float lo[3], hi[3];
            slot_box(w, ni, k, lo, hi);
            if (!(lo[0] <= hi[0])) /* unused slot */
                continue;
            if (!ray_box(r, lo, hi, best))
                continue;
            if (sp == STACK) {
                *overflow = 1;
                return best;
            }
            stack[sp] = slot_child(w, ni, k);
            stack_n[sp++] = slot_count(w, ni, k);
        }
        for (;;) {
            if (sp == 0)
                return best;
            --sp;
            if (stack_n[sp] == 0) {
                ni = stack[sp];
                break;
            }
            for (uint32_t k = stack[sp]; k < stack[sp] + stack_n[sp]; k++) {
                uint32_t p = bvh->order[k];
                float t = tri_hit(r, &tris[p]);
                if (t < best) {
                    best = t;
                    *prim = p;
                }
            }
        }
    }
}

/* The wide tree has exactly the binary tree's leaves (same ranges, same
 * boxes), every interior box bounds its children, unused slots hold the empty
 * box, every node is reached once, and the depth is reported right. */
static void check_wide(const wide_tree *w, const pn_bvh *bvh)
{
    CHECK(w->nodes && w->node_count >= 1 && w->node_count <= bvh->node_count / 2 + 1, "%u wide nodes for %u binary",
          w->node_count, bvh->node_count);
    CHECK(w->depth >= 1 && w->depth <= bvh->depth, "wide depth %u, binary %u", w->depth, bvh->depth);
    if (!w->nodes)
        return;
    uint32_t *stack = malloc(sizeof(uint32_t) * (w->node_count + 1));
    uint32_t *sdepth = malloc(sizeof(uint32_t) * (w->node_count + 1));
    uint8_t *visited = calloc(w->node_count, 1);
    uint8_t *leaf_seen = calloc(bvh->node_count, 1);
    /* first primitive -> binary leaf, to match wide leaves to binary ones */
    uint32_t *leaf_of = malloc(sizeof(uint32_t) * bvh->prim_count);
    if (!stack || !sdepth || !visited || !leaf_seen || !leaf_of) {
        fail("test out of memory");
        goto out;
    }
    for (uint32_t i = 0; i < bvh->prim_count; i++)
        leaf_of[i] = UINT32_MAX;
    for (uint32_t b = 0; b < bvh->node_count; b++)
        if (bvh->nodes[b].count > 0 && bvh->nodes[b].left_or_first < bvh->prim_count)
            leaf_of[bvh->nodes[b].left_or_first] = b;
    int errors = 0;
    uint32_t sp = 0, max_depth = 0;
    stack[sp] = 0;
    sdepth[sp++] = 1;
    visited[0] = 1;
    while (sp > 0 && errors < 5) {
        sp--;
        uint32_t ni = stack[sp], d = sdepth[sp];
        max_depth = d > max_depth ? d : max_depth;
        for (int k = 0; k < w->width; k++) {
            float lo[3], hi[3];
            slot_box(w, ni, k, lo, hi);
            const uint32_t child = slot_child(w, ni, k), count = slot_count(w, ni, k);
            if (lo[0] == INFINITY) {
                int empty = count == 0;
                for (int a = 0; a < 3; a++)
                    empty = empty && lo[a] == INFINITY && hi[a] == -INFINITY;
                if (!empty && errors++ < 5)
                    fail("node %u slot %d: unused slot is not the empty box", ni, k);
                continue;
            }
            if (count > 0) {
                /* find the binary leaf with this range */
                uint32_t b = child < bvh->prim_count ? leaf_of[child] : UINT32_MAX;
                if (b == UINT32_MAX || bvh->nodes[b].count != count || leaf_seen[b]++ ||
                    memcmp(lo, bvh->nodes[b].lo, sizeof lo) || memcmp(hi, bvh->nodes[b].hi, sizeof hi)) {
                    if (errors++ < 5)
                        fail("node %u slot %d: leaf %u+%u is not a binary leaf, or seen twice, or its box differs", ni,
                             k, child, count);
                }
                continue;
            }
            uint32_t c = child;
            if (c == 0 || c >= w->node_count || visited[c]++) {
                if (errors++ < 5)
                    fail("node %u slot %d: child %u out of range or reached twice", ni, k, c);
                continue;
            }
            for (int j = 0; j < w->width; j++) {
                float clo[3], chi[3];
                slot_box(w, c, j, clo, chi);
                if (clo[0] != INFINITY && !box_contains(lo, hi, clo, chi) && errors++ < 5)
                    fail("node %u slot %d: box does not contain child %u's slot %d", ni, k, c, j);
            }
            stack[sp] = c;
            sdepth[sp++] = d + 1;
        }
    }
    uint32_t leaves = 0, unreached = 0, wide_leaves = 0;
    for (uint32_t b = 0; b < bvh->node_count; b++) {
        leaves += bvh->nodes[b].count > 0;
        wide_leaves += leaf_seen[b];
    }
    for (uint32_t i = 0; i < w->node_count; i++)
        unreached += !visited[i];
    CHECK(errors == 0, "%d structural errors", errors);
    CHECK(wide_leaves == leaves, "%u of %u binary leaves in the wide tree", wide_leaves, leaves);
    CHECK(unreached == 0, "%u wide nodes unreachable", unreached);
    CHECK(errors || max_depth == w->depth, "reported wide depth %u, actual %u", w->depth, max_depth);
out:
    free(stack);
    free(sdepth);
    free(visited);
    free(leaf_seen);
    free(leaf_of);
}

/* Collapses bvh, checks the structure and that wide queries give brute
 * force's distances exactly. */
static void check_collapse_width(const pn_bvh *bvh, const tri *tris, uint32_t n, int nrays, int width)
{
    pn_bvh4 w4;
    pn_bvh8 w8;
    int rc = width == 8 ? pn_bvh8_collapse(bvh, &w8) : pn_bvh4_collapse(bvh, &w4);
    CHECK(rc == 0, "%d-wide collapse returned %d", width, rc);
    const wide_tree w = width == 8 ? wide8(&w8) : wide4(&w4);
    if (rc == 0)
        check_wide(&w, bvh);
    if (rc == 0 && g_case_errors == 0 && tris) {
        const pn_aabb scene = {{bvh->nodes[0].lo[0], bvh->nodes[0].lo[1], bvh->nodes[0].lo[2]},
                               {bvh->nodes[0].hi[0], bvh->nodes[0].hi[1], bvh->nodes[0].hi[2]}};
        int mismatches = 0, overflow = 0;
        for (int i = 0; i < nrays; i++) {
            ray r;
            make_ray(&r, tris, n, &scene);
            uint32_t pb, pq;
            float tb = brute_force(&r, tris, n, &pb);
            float tq = wide_query(&w, bvh, &r, tris, &pq, &overflow);
            int ok = tb == tq || (tb != tb && tq != tq);
            if (ok && pq != pb)
                ok = pq < n && tri_hit(&r, &tris[pq]) == tb;
            if (!ok && mismatches++ < 5)
                fail("ray %d: brute force t=%.9g prim %u, %d-wide t=%.9g prim %u", i, tb, pb, width, tq, pq);
        }
        CHECK(mismatches == 0, "%d/%d rays disagree with brute force in the %d-wide tree", mismatches, nrays, width);
        CHECK(!overflow, "%d-wide traversal stack overflowed", width);
        printf("  %d-wide: %u nodes, depth %u\n", width, w.node_count, w.depth);
    }
    if (width == 8) {
        pn_bvh8_free(&w8);
        pn_bvh8_free(&w8); /* safe twice */
    } else {
        pn_bvh4_free(&w4);
        pn_bvh4_free(&w4);
    }
}

static void check_collapse(const pn_bvh *bvh, const tri *tris, uint32_t n, int nrays)
{
    check_collapse_width(bvh, tris, n, nrays, 4);
    check_collapse_width(bvh, tris, n, nrays, 8);
}

/* Builds over tris, checks invariants and ray queries; expect_depth 0 means any. */
static void run_tri_case(const char *name, const tri *tris, uint32_t n, uint32_t max_leaf, int nrays,
                         uint32_t expect_depth)
{
    case_begin(name);
    pn_aabb *boxes = malloc(sizeof(pn_aabb) * n);
    if (!boxes) {
        fail("test out of memory");
        case_end();
        return;
    }
    for (uint32_t i = 0; i < n; i++)
        boxes[i] = tri_box(&tris[i]);
    pn_bvh bvh;
    int rc = pn_bvh_build(boxes, n, max_leaf, &bvh);
    CHECK(rc == 0, "build returned %d", rc);
    if (rc == 0) {
        check_invariants(&bvh, boxes, n, max_leaf);
        CHECK(!expect_depth || bvh.depth == expect_depth, "depth %u, expected %u", bvh.depth, expect_depth);
        /* queries over a malformed tree could read out of bounds */
        if (g_case_errors == 0)
            CHECK(check_rays(&bvh, tris, n, nrays) > 0, "no ray hit anything; the query check is vacuous");
        if (g_case_errors == 0)
            check_collapse(&bvh, tris, n, nrays);
    }
    pn_bvh_free(&bvh);
    free(boxes);
    case_end();
}

static tri *alloc_tris(uint32_t n)
{
    tri *t = malloc(sizeof(tri) * n);
    if (!t) {
        fprintf(stderr, "out of memory\n");
        exit(2);
    }
    return t;
}

static void test_random(uint32_t n, uint32_t max_leaf, int nrays)
{
    char name[96];
    snprintf(name, sizeof(name), "random triangles n=%u max_leaf=%u", n, max_leaf);
    tri *t = alloc_tris(n);
    for (uint32_t i = 0; i < n; i++)
        random_tri(&t[i], 0.02f);
    run_tri_case(name, t, n, max_leaf, nrays, 0);
    free(t);
}

static void test_degenerate_mix(void)
{
    const uint32_t n = 20000;
    tri *t = alloc_tris(n);
    for (uint32_t i = 0; i < n; i++) {
        if (i % 3 == 0)
            random_tri(&t[i], 0.03f);
        else
            degenerate_tri(&t[i], 0.03f);
    }
    run_tri_case("degenerate (zero-area) triangles mixed with normal ones", t, n, 4, 2000, 0);
    free(t);
}

static void test_duplicates_at_point(uint32_t max_leaf)
{
    const uint32_t n = 10000, dup = 8000;
    char name[96];
    snprintf(name, sizeof(name), "8000 triangles collapsed to one point + 2000 normal, max_leaf=%u", max_leaf);
    tri *t = alloc_tris(n);
    for (uint32_t i = 0; i < n; i++) {
        if (i < dup)
            for (int k = 0; k < 3; k++)
                for (int a = 0; a < 3; a++)
                    t[i].v[k][a] = 0.5f;
        else
            random_tri(&t[i], 0.02f);
    }
    /* interleave so duplicates are not one contiguous input run */
    for (uint32_t i = n - 1; i > 0; i--) {
        uint32_t j = (uint32_t)(rng_u64() % (i + 1));
        tri tmp = t[i];
        t[i] = t[j];
        t[j] = tmp;
    }
    run_tri_case(name, t, n, max_leaf, 2000, 0);
    free(t);
}

static void test_identical_triangles(void)
{
    const uint32_t n = 3000;
    tri *t = alloc_tris(n);
    tri one;
    random_tri(&one, 0.2f);
    for (uint32_t i = 0; i < n; i++)
        t[i] = one;
    run_tri_case("3000 identical non-degenerate triangles", t, n, 4, 2000, 0);
    free(t);
}

static void test_flat(void)
{
    const uint32_t n = 20000;
    tri *t = alloc_tris(n);
    for (uint32_t i = 0; i < n; i++) {
        random_tri(&t[i], 0.01f);
        for (int k = 0; k < 3; k++)
            t[i].v[k][2] = 0.25f; /* every box has zero extent in z */
    }
    run_tri_case("flat scene (all triangles in z = 0.25)", t, n, 4, 2000, 0);
    free(t);
}

/* Unit triangles in the planes x = 20^k, identical in y and z. Only the x axis
 * separates centroids, and each plane's centroid lies beyond 16x all the
 * others', so binned SAH can only peel one plane per level: unguarded, the
 * tree would be ~n deep. Once the guard takes over, median splits end every
 * path exactly at PN_BVH_MAX_DEPTH, so depth == PN_BVH_MAX_DEPTH shows the
 * guard engaged (and not merely that the scene was shallow). */
static void test_depth_guard(void)
{
    const uint32_t n = 58; /* 20^-29 .. 20^28 stays inside normal floats */
    tri *t = alloc_tris(n);
    double x = pow(20.0, -29.0);
    for (uint32_t i = 0; i < n; i++, x *= 20.0) {
        static const float yz[3][2] = {{0, 0}, {1, 0}, {0, 1}};
        for (int k = 0; k < 3; k++) {
            t[i].v[k][0] = (float)x;
            t[i].v[k][1] = yz[k][0];
            t[i].v[k][2] = yz[k][1];
        }
    }
    for (uint32_t ml = 1; ml <= 4; ml *= 4) {
        char name[96];
        snprintf(name, sizeof(name), "plane stack forces the depth guard, max_leaf=%u", ml);
        run_tri_case(name, t, n, ml, 2000, PN_BVH_MAX_DEPTH);
    }
    free(t);
}

static void test_tiny(void)
{
    tri t[2];
    random_tri(&t[0], 0.1f);
    random_tri(&t[1], 0.1f);
    run_tri_case("single primitive", t, 1, 4, 2000, 0);
    run_tri_case("two primitives, max_leaf=1", t, 2, 1, 2000, 0);
    run_tri_case("two primitives, max_leaf=4", t, 2, 4, 2000, 0);

    case_begin("single primitive tree shape");
    pn_bvh bvh;
    pn_aabb b = tri_box(&t[0]);
    CHECK(pn_bvh_build(&b, 1, 1, &bvh) == 0, "build failed");
    CHECK(bvh.node_count == 1 && bvh.depth == 1 && bvh.nodes && bvh.nodes[0].count == 1 &&
              bvh.nodes[0].left_or_first == 0 && bvh.order[0] == 0,
          "expected one leaf at the root");
    pn_bvh_free(&bvh);
    case_end();
}

static void test_point_boxes(void)
{
    case_begin("50000 zero-extent boxes, many repeated");
    const uint32_t n = 50000;
    pn_aabb *b = malloc(sizeof(pn_aabb) * n);
    if (!b) {
        fail("test out of memory");
        case_end();
        return;
    }
    for (uint32_t i = 0; i < n; i++) {
        /* only 64 distinct points */
        uint32_t k = (uint32_t)(rng_u64() % 64);
        for (int a = 0; a < 3; a++)
            b[i].lo[a] = b[i].hi[a] = (float)((k >> (2 * a)) & 3);
    }
    for (uint32_t ml = 1; ml <= 8; ml *= 8) {
        pn_bvh bvh;
        int rc = pn_bvh_build(b, n, ml, &bvh);
        CHECK(rc == 0, "build returned %d", rc);
        if (rc == 0)
            check_invariants(&bvh, b, n, ml);
        pn_bvh_free(&bvh);
    }
    free(b);
    case_end();
}

static void test_api_edges(void)
{
    case_begin("count == 0 fails; free of zeroed or freed struct is safe");
    pn_bvh bvh;
    memset(&bvh, 0xAB, sizeof(bvh));
    pn_aabb b = {{0, 0, 0}, {1, 1, 1}};
    CHECK(pn_bvh_build(&b, 0, 4, &bvh) == -1, "count 0 accepted");
    CHECK(bvh.nodes == NULL && bvh.order == NULL, "failed build left non-null arrays");
    pn_bvh_free(&bvh);
    pn_bvh zero;
    memset(&zero, 0, sizeof(zero));
    pn_bvh_free(&zero);
    CHECK(pn_bvh_build(&b, 1, 4, &bvh) == 0, "build failed");
    pn_bvh_free(&bvh);
    pn_bvh_free(&bvh); /* freeing twice is harmless: free zeroes the struct */
    CHECK(bvh.nodes == NULL && bvh.order == NULL && bvh.node_count == 0, "free did not zero the struct");
    pn_bvh4 w;
    memset(&w, 0xAB, sizeof(w));
    CHECK(pn_bvh4_collapse(&bvh, &w) == -1 && w.nodes == NULL, "collapse of an empty tree accepted");
    pn_bvh4_free(&w);
    /* a single leaf: a root with that leaf in slot 0 */
    CHECK(pn_bvh_build(&b, 1, 4, &bvh) == 0 && pn_bvh4_collapse(&bvh, &w) == 0, "build or collapse failed");
    if (w.nodes) {
        CHECK(w.node_count == 1 && w.depth == 1 && w.nodes[0].count[0] == 1, "single leaf: %u nodes, depth %u", w.node_count,
              w.depth);
        const wide_tree t = wide4(&w);
        check_wide(&t, &bvh);
    }
    pn_bvh4_free(&w);
    pn_bvh8 w8;
    memset(&w8, 0xAB, sizeof(w8));
    pn_bvh empty_tree;
    memset(&empty_tree, 0, sizeof(empty_tree));
    CHECK(pn_bvh8_collapse(&empty_tree, &w8) == -1 && w8.nodes == NULL, "8-wide collapse of an empty tree accepted");
    CHECK(pn_bvh8_collapse(&bvh, &w8) == 0, "8-wide collapse failed");
    if (w8.nodes) {
        CHECK(w8.node_count == 1 && w8.depth == 1 && w8.nodes[0].count[0] == 1, "8-wide single leaf: %u nodes, depth %u",
              w8.node_count, w8.depth);
        const wide_tree t = wide8(&w8);
        check_wide(&t, &bvh);
    }
    pn_bvh8_free(&w8);
    pn_bvh_free(&bvh);
    case_end();
}

static void timing_1m(void)
{
    case_begin("timing: 1M random boxes (printed, not asserted)");
    const uint32_t n = 1000000;
    pn_aabb *b = malloc(sizeof(pn_aabb) * n);
    if (!b) {
        fail("test out of memory");
        case_end();
        return;
    }
    for (uint32_t i = 0; i < n; i++)
        for (int a = 0; a < 3; a++) {
            float c = rnd(), e = rnd_range(0.0f, 0.01f);
            b[i].lo[a] = c - e;
            b[i].hi[a] = c + e;
        }
    pn_bvh bvh;
    double t0 = now_s();
    int rc = pn_bvh_build(b, n, 4, &bvh);
    double t1 = now_s();
    CHECK(rc == 0, "build returned %d", rc);
    if (rc == 0) {
        printf("  build: %.3f s, %u nodes, depth %u\n", t1 - t0, bvh.node_count, bvh.depth);
        check_invariants(&bvh, b, n, 4);
    }
    pn_bvh_free(&bvh);

    /* All-identical boxes: the degenerate path must stay O(n log n). */
    for (uint32_t i = 0; i < n; i++)
        b[i] = b[0];
    t0 = now_s();
    rc = pn_bvh_build(b, n, 4, &bvh);
    t1 = now_s();
    CHECK(rc == 0, "build returned %d", rc);
    if (rc == 0) {
        printf("  1M identical boxes: %.3f s, depth %u\n", t1 - t0, bvh.depth);
        check_invariants(&bvh, b, n, 4);
    }
    pn_bvh_free(&bvh);
    free(b);
    case_end();
}

/* `test_bvh --timing` also times a 1M-box build (skipped by ctest: under
 * the sanitizers it takes minutes and asserts nothing). */
int main(int argc, char **argv)
{
    const int timing = argc > 1 && strcmp(argv[1], "--timing") == 0;
    test_api_edges();
    test_tiny();
    test_random(1000, 1, 2000);
    test_random(10000, 4, 2000);
    test_random(timing ? 100000 : 30000, 4, 2000);
    test_random(20000, 16, 2000);
    test_degenerate_mix();
    test_duplicates_at_point(1);
    test_duplicates_at_point(4);
    test_identical_triangles();
    test_flat();
    test_depth_guard();
    test_point_boxes();
    if (timing)
        timing_1m();
    printf("%d passed, %d failed\n", g_passed, g_failed);
    return g_failed != 0;
}
