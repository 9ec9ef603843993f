/* Binned-SAH BVH builder (see bvh.h).
 *
 * Top-down, iterative, depth-first. Each node's primitives are binned by
 * centroid into SAH_BINS bins per axis over the node's centroid bounds; the
 * cheapest bin boundary over the three axes wins. Children are allocated as a
 * pair so siblings are adjacent; the left child is built next and the right
 * one waits on a stack, whose size is bounded by the depth limit.
 *
 * Depth bound: a median split halves a node, so a node of n primitives needs
 * levels_needed(n) more levels to reach leaves of at most max_leaf_size. SAH
 * is used only while one more level still leaves that much room below; past
 * that point nodes are median-split, which keeps every leaf within both
 * PN_BVH_MAX_DEPTH and max_leaf_size (n < 2^32 needs at most 32 levels).
 */
#include "geometry/bvh.h"

#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

/* SAH cost model: splitting costs SAH_C_TRAV + SAH_C_ISECT * (A_l*N_l + A_r*N_r) / A,
 * a leaf costs SAH_C_ISECT * N. Equal weights: on the device one node visit
 * (a 32-byte load plus slab test) costs about as much as one triangle or
 * instance test. */
#define SAH_C_TRAV  1.0
#define SAH_C_ISECT 1.0
#define SAH_BINS    16 /* per axis; nodes of fewer primitives use fewer (>= 4) */

typedef struct bin {
    pn_aabb box;
    uint32_t count;
} bin;

typedef struct task {
    uint32_t node, first, count, depth;
    pn_aabb box;   /* bounds of the primitives' boxes */
    pn_aabb cbox;  /* bounds of the primitives' centroids */
} task;

/* Working copy of the input in leaf-slot order, so every pass over a node's
 * range reads memory sequentially instead of chasing order[] into boxes[]. */
typedef struct prim {
    pn_aabb box;
    uint32_t id;
} prim;

typedef struct builder {
    prim *prims;
    pn_bvh_node *nodes;
    uint32_t node_count;
    uint32_t max_leaf;
} builder;

static void aabb_empty(pn_aabb *b)
{
    for (int a = 0; a < 3; a++) {
        b->lo[a] = INFINITY;
        b->hi[a] = -INFINITY;
    }
}

/* Plain compares rather than fminf/fmaxf: inputs are NaN-free and these
 * compile to single min/max instructions in the hot loops. */
static inline void aabb_grow(pn_aabb *b, const pn_aabb *o)
{
    for (int a = 0; a < 3; a++) {
        b->lo[a] = o->lo[a] < b->lo[a] ? o->lo[a] : b->lo[a];
        b->hi[a] = o->hi[a] > b->hi[a] ? o->hi[a] : b->hi[a];
    }
}

static inline void aabb_grow_pt(pn_aabb *b, const float *p)
{
    for (int a = 0; a < 3; a++) {
        b->lo[a] = p[a] < b->lo[a] ? p[a] : b->lo[a];
        b->hi[a] = p[a] > b->hi[a] ? p[a] : b->hi[a];
    }
}

/* Halves first: lo + hi may overflow. Every use goes through this one
 * expression, so binning and partitioning see bit-identical centroids. */
static inline float centroid(const prim *p, int a)
{
    return 0.5f * p->box.lo[a] + 0.5f * p->box.hi[a];
}

static inline void grow_centroid(pn_aabb *b, const prim *p)
{
    float c[3] = {centroid(p, 0), centroid(p, 1), centroid(p, 2)};
    aabb_grow_pt(b, c);
}

/* Half the surface area; double so huge (finite) boxes do not overflow. */
static double half_area(const pn_aabb *b)
{
    double dx = (double)b->hi[0] - b->lo[0];
    double dy = (double)b->hi[1] - b->lo[1];
    double dz = (double)b->hi[2] - b->lo[2];
    return dx * dy + dy * dz + dz * dx;
}

/* Smallest k with 2^k >= ceil(count / max_leaf): levels a median split needs. */
static uint32_t levels_needed(uint32_t count, uint32_t max_leaf)
{
    uint64_t leaves = ((uint64_t)count + max_leaf - 1) / max_leaf;
    uint32_t k = 0;
    while (((uint64_t)1 << k) < leaves)
        k++;
    return k;
}

/* Maps a centroid to one of nb bins. NaN or out-of-range values land in a
 * valid bin instead of reaching an undefined float-to-int conversion.
 * Binning and partitioning both call this, so they always agree. */
static inline uint32_t bin_of(float c, float cmin, float scale, int nb)
{
    float t = (c - cmin) * scale;
    if (!(t > 0.0f))
        return 0;
    return t < (float)nb ? (uint32_t)t : (uint32_t)nb - 1;
}

static void child_pair(builder *b, const task *t, uint32_t left_count, task *l, task *r)
{
    l->node = b->node_count;
    r->node = b->node_count + 1;
    b->node_count += 2;
    l->depth = r->depth = t->depth + 1;
    l->first = t->first;
    l->count = left_count;
    r->first = t->first + left_count;
    r->count = t->count - left_count;
}

static void range_bounds(const builder *b, uint32_t first, uint32_t count, pn_aabb *box, pn_aabb *cbox)
{
    aabb_empty(box);
    aabb_empty(cbox);
    for (uint32_t i = first; i < first + count; i++) {
        aabb_grow(box, &b->prims[i].box);
        grow_centroid(cbox, &b->prims[i]);
    }
}

/* Reorders p[lo..hi] (inclusive) so p[k] holds the k-th smallest centroid
 * along `axis`, smaller-or-equal ones before it (Hoare selection). Equal keys
 * stop both scans, so many duplicates still split evenly. */
static void select_nth(prim *p, int axis, int64_t lo, int64_t hi, int64_t k)
{
    while (lo < hi) {
        float x = centroid(&p[lo], axis);
        float y = centroid(&p[lo + (hi - lo) / 2], axis);
        float z = centroid(&p[hi], axis);
        /* median of three, against already sorted or reversed input */
        float pivot = x < y ? (y < z ? y : (x < z ? z : x)) : (x < z ? x : (y < z ? z : y));
        int64_t i = lo, j = hi;
        while (i <= j) {
            while (centroid(&p[i], axis) < pivot)
                i++;
            while (centroid(&p[j], axis) > pivot)
                j--;
            if (i <= j) {
                prim tmp = p[i];
                p[i++] = p[j];
                p[j--] = tmp;
            }
        }
        if (k <= j)
            hi = j;
        else if (k >= i)
            lo = i;
        else
            return;
    }
}

/* Halves the node: object median along the widest centroid axis, or plain
 * index middle when all centroids coincide (nothing to sort by). */
static void median_split(builder *b, const task *t, task *l, task *r)
{
    int axis = -1;
    float widest = 0.0f;
    for (int a = 0; a < 3; a++) {
        float ext = t->cbox.hi[a] - t->cbox.lo[a];
        if (ext > widest) {
            widest = ext;
            axis = a;
        }
    }
    uint32_t half = t->count / 2;
    if (axis >= 0)
        select_nth(b->prims, axis, t->first, (int64_t)t->first + t->count - 1,
                   (int64_t)t->first + half);
    child_pair(b, t, half, l, r);
    range_bounds(b, l->first, l->count, &l->box, &l->cbox);
    range_bounds(b, r->first, r->count, &r->box, &r->cbox);
}

/* Returns 1 and fills l/r when SAH found a split worth taking (or one is
 * required because count > max_leaf), 0 when a leaf is cheaper, -1 when no
 * bin boundary separates the primitives. */
static int sah_split(builder *b, const task *t, task *l, task *r)
{
    bin bins[3][SAH_BINS];
    /* Small nodes would leave most bins empty; fewer bins cut the per-node
     * setup and sweep cost, which dominates near the leaves. */
    const int nb = t->count < SAH_BINS ? (t->count < 4 ? 4 : (int)t->count) : SAH_BINS;
    float scale[3];
    int any_axis = 0;
    for (int a = 0; a < 3; a++) {
        float ext = t->cbox.hi[a] - t->cbox.lo[a];
        float s = ext > 0.0f ? (float)nb / ext : 0.0f;
        /* a tiny extent can overflow the scale; an infinite one zeroes it */
        scale[a] = (s > 0.0f && s < INFINITY) ? s : 0.0f;
        any_axis |= scale[a] > 0.0f;
        for (int k = 0; k < nb; k++) {
            aabb_empty(&bins[a][k].box);
            bins[a][k].count = 0;
        }
    }
    if (!any_axis)
        return -1;

    const uint32_t end = t->first + t->count;
    for (uint32_t i = t->first; i < end; i++) {
        const prim *p = &b->prims[i];
        for (int a = 0; a < 3; a++) {
            if (scale[a] == 0.0f)
                continue;
            bin *bn = &bins[a][bin_of(centroid(p, a), t->cbox.lo[a], scale[a], nb)];
            aabb_grow(&bn->box, &p->box);
            bn->count++;
        }
    }

    double best = INFINITY;
    int best_axis = -1;
    uint32_t best_bin = 0;
    for (int a = 0; a < 3; a++) {
        if (scale[a] == 0.0f)
            continue;
        double right_area[SAH_BINS];
        uint32_t right_count[SAH_BINS];
        pn_aabb acc;
        uint32_t n = 0;
        aabb_empty(&acc);
        /* Only boundaries right after a non-empty bin are distinct candidates;
         * skipping the rest saves most of the area work in small nodes. */
        for (int k = nb - 1; k > 0; k--) {
            aabb_grow(&acc, &bins[a][k].box);
            n += bins[a][k].count;
            right_count[k] = n;
            right_area[k] = n && bins[a][k - 1].count ? half_area(&acc) : 0.0;
        }
        aabb_empty(&acc);
        n = 0;
        for (int k = 0; k < nb - 1; k++) {
            if (bins[a][k].count == 0)
                continue;
            aabb_grow(&acc, &bins[a][k].box);
            n += bins[a][k].count;
            if (right_count[k + 1] == 0)
                break;
            double cost = half_area(&acc) * n + right_area[k + 1] * right_count[k + 1];
            if (cost < best) {
                best = cost;
                best_axis = a;
                best_bin = (uint32_t)k;
            }
        }
    }
    if (best_axis < 0)
        return -1;

    double area = half_area(&t->box);
    double split_cost = SAH_C_TRAV * area + SAH_C_ISECT * best;
    double leaf_cost = SAH_C_ISECT * t->count * area;
    if (t->count <= b->max_leaf && !(split_cost < leaf_cost))
        return 0;

    /* Partition in place, collecting both children's bounds on the way. */
    pn_aabb lbox, lcbox, rbox, rcbox;
    aabb_empty(&lbox);
    aabb_empty(&lcbox);
    aabb_empty(&rbox);
    aabb_empty(&rcbox);
    const int a = best_axis;
    const float cmin = t->cbox.lo[a], s = scale[a];
    uint32_t i = t->first, j = end;
    while (i < j) {
        prim p = b->prims[i];
        if (bin_of(centroid(&p, a), cmin, s, nb) <= best_bin) {
            aabb_grow(&lbox, &p.box);
            grow_centroid(&lcbox, &p);
            i++;
        } else {
            aabb_grow(&rbox, &p.box);
            grow_centroid(&rcbox, &p);
            b->prims[i] = b->prims[--j];
            b->prims[j] = p;
        }
    }
    uint32_t left_count = i - t->first;
    if (left_count == 0 || left_count == t->count)
        return -1; /* unreachable with consistent binning; never emit an empty child */
    child_pair(b, t, left_count, l, r);
    l->box = lbox;
    l->cbox = lcbox;
    r->box = rbox;
    r->cbox = rcbox;
    return 1;
}

/* Returns 1 with l/r filled when the node is split, 0 when it becomes a leaf. */
static int split_node(builder *b, const task *t, task *l, task *r)
{
    if (t->count <= 1)
        return 0;
    int sah_room = t->depth + 1 + levels_needed(t->count, b->max_leaf) <= PN_BVH_MAX_DEPTH;
    if (sah_room) {
        int res = sah_split(b, t, l, r);
        if (res >= 0)
            return res;
    }
    /* SAH found nothing to separate, or the depth budget is tight. */
    if (t->count <= b->max_leaf)
        return 0;
    median_split(b, t, l, r);
    return 1;
}

int pn_bvh_build(const pn_aabb *boxes, uint32_t count, uint32_t max_leaf_size, pn_bvh *out)
{
    memset(out, 0, sizeof(*out));
    /* Node indices are uint32_t and a tree with count leaves has 2*count-1 nodes. */
    if (count == 0 || count > UINT32_MAX / 2 + 1)
        return -1;
    size_t max_nodes = 2 * (size_t)count - 1;
    /* The node array is the largest allocation; if it fits size_t so do the others. */
    if (max_nodes > SIZE_MAX / sizeof(pn_bvh_node))
        return -1;

    builder b;
    b.max_leaf = max_leaf_size ? max_leaf_size : 1;
    b.node_count = 1;
    b.nodes = malloc(max_nodes * sizeof(pn_bvh_node));
    b.prims = malloc((size_t)count * sizeof(prim));
    uint32_t *order = malloc((size_t)count * sizeof(uint32_t));
    if (!b.nodes || !b.prims || !order) {
        free(b.nodes);
        free(b.prims);
        free(order);
        return -1;
    }

    task cur;
    cur.node = 0;
    cur.first = 0;
    cur.count = count;
    cur.depth = 1;
    aabb_empty(&cur.box);
    aabb_empty(&cur.cbox);
    for (uint32_t i = 0; i < count; i++) {
        b.prims[i].box = boxes[i];
        b.prims[i].id = i;
        aabb_grow(&cur.box, &boxes[i]);
        grow_centroid(&cur.cbox, &b.prims[i]);
    }

    /* Pending right siblings, one per ancestor of the current node at most. */
    task stack[PN_BVH_MAX_DEPTH];
    int sp = 0;
    uint32_t depth = 0;
    for (;;) {
        pn_bvh_node *n = &b.nodes[cur.node];
        memcpy(n->lo, cur.box.lo, sizeof(n->lo));
        memcpy(n->hi, cur.box.hi, sizeof(n->hi));
        if (cur.depth > depth)
            depth = cur.depth;
        task l, r;
        if (split_node(&b, &cur, &l, &r)) {
            n->left_or_first = l.node;
            n->count = 0;
            stack[sp++] = r;
            cur = l;
            continue;
        }
        n->left_or_first = cur.first;
        n->count = cur.count;
        if (sp == 0)
            break;
        cur = stack[--sp];
    }
    for (uint32_t i = 0; i < count; i++)
        order[i] = b.prims[i].id;
    free(b.prims);

    /* Give back the unused tail; keeping the larger block is fine if that fails. */
    pn_bvh_node *shrunk = realloc(b.nodes, (size_t)b.node_count * sizeof(pn_bvh_node));
    out->nodes = shrunk ? shrunk : b.nodes;
    out->node_count = b.node_count;
    out->order = order;
    out->prim_count = count;
    out->depth = depth;
    return 0;
}

void pn_bvh_free(pn_bvh *bvh)
{
    if (!bvh)
        return;
    free(bvh->nodes);
    free(bvh->order);
    memset(bvh, 0, sizeof(*bvh));
}

/* ---------------------------------------------------------- 4-wide collapse */

static double node_half_area(const pn_bvh_node *n)
{
    pn_aabb b;
    memcpy(b.lo, n->lo, sizeof b.lo);
    memcpy(b.hi, n->hi, sizeof b.hi);
    return half_area(&b);
}

/* Fills slot k of w from binary node n (interior: child = the 4-wide index to come). */
/* Wide nodes of W children (pn_bvh4_node, pn_bvh8_node) share one layout:
 * eight arrays of W 32-bit words (lo_x, hi_x, lo_y, hi_y, lo_z, hi_z, child,
 * count). The collapse writes them through these offsets. */
static void set_word(unsigned char *node, int width, int array, int k, const void *value)
{
    memcpy(node + 4 * ((size_t)array * width + k), value, 4);
}

static void set_slot(unsigned char *node, int width, int k, const pn_bvh_node *n, uint32_t child, uint32_t count)
{
    for (int a = 0; a < 3; ++a) {
        set_word(node, width, 2 * a, k, &n->lo[a]);
        set_word(node, width, 2 * a + 1, k, &n->hi[a]);
    }
    set_word(node, width, 6, k, &child);
    set_word(node, width, 7, k, &count);
}

static void clear_node(unsigned char *node, int width)
{
    const float lo = INFINITY, hi = -INFINITY;
    const uint32_t zero = 0;
    for (int k = 0; k < width; ++k) {
        for (int a = 0; a < 3; ++a) {
            set_word(node, width, 2 * a, k, &lo);
            set_word(node, width, 2 * a + 1, k, &hi);
        }
        set_word(node, width, 6, k, &zero);
        set_word(node, width, 7, k, &zero);
    }
}

/* The collapse of pn_bvh4_collapse for `width` (4 or 8) children per node;
 * *nodes_out gets node_count nodes of 32 * width bytes. */
static int collapse_wide(const pn_bvh *bvh, int width, void **nodes_out, uint32_t *count_out, uint32_t *depth_out)
{
    *nodes_out = NULL;
    *count_out = *depth_out = 0;
    if (!bvh || !bvh->nodes || bvh->node_count == 0)
        return -1;
    const size_t node_bytes = 32u * (size_t)width;
    /* Every wide node expands its own binary interior node (or is a
     * single-leaf root), so there are at most max(1, (node_count - 1) / 2);
     * each level of wide nodes is at least one binary level deeper, so the
     * depth stays within the binary one. */
    const uint32_t cap = bvh->node_count / 2 + 1;
    unsigned char *nodes = malloc((size_t)cap * node_bytes);
    /* Work list: binary node to expand into the wide node of the same position, and its depth. */
    uint32_t *todo = malloc((size_t)cap * 2 * sizeof(uint32_t));
    if (!nodes || !todo) {
        free(nodes);
        free(todo);
        return -1;
    }
    uint32_t count = 1, depth = 1;
    todo[0] = 0;
    todo[1] = 1;
    for (uint32_t w = 0; w < count; ++w) {
        const pn_bvh_node *src = &bvh->nodes[todo[2 * w]];
        const uint32_t wdepth = todo[2 * w + 1];
        uint32_t kids[8];
        int n = 0;
        if (src->count > 0) {
            kids[n++] = todo[2 * w]; /* the root is a leaf */
        } else {
            kids[n++] = src->left_or_first;
            kids[n++] = src->left_or_first + 1;
            while (n < width) {
                int best = -1;
                double best_area = -1.0;
                for (int k = 0; k < n; ++k) {
                    const pn_bvh_node *c = &bvh->nodes[kids[k]];
                    double a = node_half_area(c);
                    if (c->count == 0 && a > best_area) {
                        best_area = a;
                        best = k;
                    }
                }
                if (best < 0)
                    break;
                const uint32_t l = bvh->nodes[kids[best]].left_or_first;
                kids[best] = l; /* keep the pair adjacent: left in place, right at the end */
                kids[n++] = l + 1;
            }
        }
        unsigned char *dst = nodes + (size_t)w * node_bytes;
        clear_node(dst, width);
        for (int k = 0; k < n; ++k) {
            const pn_bvh_node *c = &bvh->nodes[kids[k]];
            if (c->count > 0) {
                set_slot(dst, width, k, c, c->left_or_first, c->count);
                continue;
            }
            if (count >= cap) { /* cannot happen by the bound above; never write past the array */
                free(nodes);
                free(todo);
                return -1;
            }
            set_slot(dst, width, k, c, count, 0);
            todo[2 * count] = kids[k];
            todo[2 * count + 1] = wdepth + 1;
            ++count;
        }
        if (wdepth > depth)
            depth = wdepth;
    }
    free(todo);
    unsigned char *shrunk = realloc(nodes, (size_t)count * node_bytes);
    *nodes_out = shrunk ? shrunk : nodes;
    *count_out = count;
    *depth_out = depth;
    return 0;
}

int pn_bvh4_collapse(const pn_bvh *bvh, pn_bvh4 *out)
{
    memset(out, 0, sizeof(*out));
    void *nodes;
    if (collapse_wide(bvh, 4, &nodes, &out->node_count, &out->depth) != 0)
        return -1;
    out->nodes = nodes;
    return 0;
}

int pn_bvh8_collapse(const pn_bvh *bvh, pn_bvh8 *out)
{
    memset(out, 0, sizeof(*out));
    void *nodes;
    if (collapse_wide(bvh, 8, &nodes, &out->node_count, &out->depth) != 0)
        return -1;
    out->nodes = nodes;
    return 0;
}

void pn_bvh8_free(pn_bvh8 *bvh)
{
    if (!bvh)
        return;
    free(bvh->nodes);
    memset(bvh, 0, sizeof(*bvh));
}

void pn_bvh4_free(pn_bvh4 *bvh)
{
    if (!bvh)
        return;
    free(bvh->nodes);
    memset(bvh, 0, sizeof(*bvh));
}
