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

#endif
