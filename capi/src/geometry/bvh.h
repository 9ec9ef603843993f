/* Binned-SAH bounding volume hierarchy, built on the host.
 *
 * One builder serves both levels of the scene: per-mesh BLAS over triangles and
 * the per-frame TLAS over instances. The flattened node layout is what the
 * kernels read (kernels/common/raytrace.cl): two float4 per node.
 */
#ifndef PENUMBRA_BVH_H
#define PENUMBRA_BVH_H

#include <stdint.h>

typedef struct pn_aabb {
    float lo[3];
    float hi[3];
} pn_aabb;

/* 32 bytes = two float4 on the device.
 * count == 0: interior node, children at left_or_first and left_or_first + 1
 *             (siblings are always adjacent).
 * count >  0: leaf holding primitives order[left_or_first .. left_or_first+count).
 * Node 0 is the root. */
typedef struct pn_bvh_node {
    float lo[3];
    uint32_t left_or_first;
    float hi[3];
    uint32_t count;
} pn_bvh_node;

typedef struct pn_bvh {
    pn_bvh_node *nodes;   /* node_count entries, malloc'ed */
    uint32_t node_count;
    uint32_t *order;      /* prim_count entries: leaf slot -> input primitive index */
    uint32_t prim_count;
    uint32_t depth;       /* longest root-to-leaf path, root alone = 1 */
} pn_bvh;

/* Builds over `count` boxes (count >= 1). Boxes may be degenerate (zero extent,
 * e.g. a zero-area triangle); boxes with NaN are not accepted (callers validate).
 * max_leaf_size >= 1. Returns 0 on success, -1 on allocation failure (no leak). */
/* Guarantees depth <= PN_BVH_MAX_DEPTH so the kernels' fixed traversal stack
 * (PN_BVH_MAX_DEPTH entries) cannot overflow, and every leaf holds at most
 * max_leaf_size primitives (near the depth bound, and where centroids
 * coincide, nodes are split at the median instead of by SAH).
 * Also returns -1 for count == 0 or count > 2^31 (node indices are 32-bit).
 * *out is zeroed first, so pn_bvh_free(out) is safe whatever the result. */
#define PN_BVH_MAX_DEPTH 48
int pn_bvh_build(const pn_aabb *boxes, uint32_t count, uint32_t max_leaf_size, pn_bvh *out);

/* Frees and zeroes *bvh; safe on a zeroed or already freed struct. */
void pn_bvh_free(pn_bvh *bvh);

/* 4-wide node, 128 bytes = eight float4 on the device: the boxes of up to
 * four children as structure of arrays (one float4 per bound and axis, so a
 * ray tests the four with vector arithmetic), then per child the node index
 * (interior) or first primitive (leaf), and the primitive count (0 for an
 * interior child). An unused slot has count 0 and the empty box lo = +inf,
 * hi = -inf, which every ray misses. Node 0 is the root; a tree of a single
 * leaf is a root with that leaf in slot 0. */
typedef struct pn_bvh4_node {
    float lo_x[4], hi_x[4], lo_y[4], hi_y[4], lo_z[4], hi_z[4];
    uint32_t child[4];
    uint32_t count[4];
} pn_bvh4_node;

typedef struct pn_bvh4 {
    pn_bvh4_node *nodes; /* node_count entries, malloc'ed */
    uint32_t node_count;
    uint32_t depth;      /* longest root-to-leaf path in 4-wide nodes, <= the binary depth */
} pn_bvh4;

/* Collapses a binary BVH into a 4-wide one with the same leaves and boxes:
 * each 4-wide node takes a binary node's two children and keeps opening the
 * interior child of largest surface area until it has four. Leaves keep
 * their primitive ranges of bvh->order, so per-primitive data in leaf order
 * serves both layouts. Returns 0, or -1 on allocation failure (*out zeroed). */
int pn_bvh4_collapse(const pn_bvh *bvh, pn_bvh4 *out);
void pn_bvh4_free(pn_bvh4 *bvh);

/* 8-wide node, 256 bytes = sixteen float4 (eight float8) on the device: the
 * 4-wide node's layout with eight slots per array, tested with one float8
 * slab test (PENUMBRA_BVH_WIDTH=8). */
typedef struct pn_bvh8_node {
    float lo_x[8], hi_x[8], lo_y[8], hi_y[8], lo_z[8], hi_z[8];
    uint32_t child[8];
    uint32_t count[8];
} pn_bvh8_node;

typedef struct pn_bvh8 {
    pn_bvh8_node *nodes; /* node_count entries, malloc'ed */
    uint32_t node_count;
    uint32_t depth;      /* longest root-to-leaf path in 8-wide nodes, <= the binary depth */
} pn_bvh8;

/* pn_bvh4_collapse with up to eight children per node (the interior child
 * of largest surface area opened until there are eight). */
int pn_bvh8_collapse(const pn_bvh *bvh, pn_bvh8 *out);
void pn_bvh8_free(pn_bvh8 *bvh);

#endif
