/* `isg` method: env lighting as K spherical-Gaussian lobes, occluders as sphere
 * sets, per-pixel diffuse and specular soft shadows by the Integral Spherical
 * Gaussian (Iwasaki et al.; docs/isg.md section 8; float64 twin:
 * tests/isg_shading64.py).
 *
 * For every light lobe G_k and every pixel (p, n):
 *   diffuse  E_k = pn_sg_irradiance(G_k, n) * V(G_k x G_cos)
 *   specular S_k = k_s * pn_sg_irradiance(G_k x G_brdf, n) * V(G_k x G_brdf)
 * or, for a BRDF lobe at least `env_sharpness` sharp, the env cube itself
 * integrated over the BRDF lobe's visible patches, or the prefiltered Gamma_L
 * times their visible share (`specular_mode`; pn_isg_env_specular),
 * where G_cos = G(n, 2.133, 1.170) (the seed's cosine lobe: it only locates
 * the visibility, the unshadowed value is the accurate closed form) and G_brdf
 * is the BRDF lobe as an SG around the mirror direction (pn_brdf_sg, common/sg.cl; the anisotropic
 * lobe is 7 such SGs, each with its own product, pn_brdf_sgs). V(G) is the visible
 * share of the product lobe: its front hemisphere in the ISG frame, cut to a
 * window of +-PN_ISG_WINDOW_SIGMAS / sqrt(lambda) around the axis (all of it
 * for broad lobes), divided into M x M patches; a patch whose centre direction
 * meets a sphere is occluded (once, however many spheres cover it: a bit
 * mask), and
 *   V = 1 - sum over occluded patches of ISG(patch) / ISG(window)
 * with the ISG from the table of common/sg.cl (the seed's eqs. 5-9), separable
 * in the window: 2 (M + 1) table evaluations per lobe, not 4 per patch.
 * Spheres outside the window's cone (axis angle > window + sphere angle) and
 * behind the receiver plane are culled before any patch work.
 *
 * Self-occlusion (the receiver's own instance's spheres; `self_occlusion`):
 *   0  ignored;
 *   1  used, except spheres that contain the receiver point or nearly touch
 *      it (distance < radius * (1 + PN_ISG_SELF_MARGIN)): a receiver on the
 *      surface of its own proxy would otherwise see half its sky cut by the
 *      sphere it sits in (the "dark disc"), and one just outside a sphere
 *      that pokes out of the surface next to it a dark arc (the margin;
 *      docs/isg.md section 9, "The seed's Fig. 12");
 *   2  all used.
 * Under 1, an own sphere that contains or nearly touches the receiver is, with
 * its set's skin s > 0 (`self_push` times the set's (g + 1/2) cells: how far
 * its balls may reach past the surface; 0 for the caller's spheres), tested
 * from the receiver pushed out along its normal, p + s n, instead of skipped:
 * it keeps the shadow it casts past the surface without painting the dark
 * disc (skipped when p + s n is still inside it).
 * A sphere of another instance that contains the receiver (`inside_other`):
 *   0  occludes every patch (the receiver is inside that occluder: V = 0);
 *   1  is skipped;
 *   2  is tested from p + s n with its own set's skin s (skipped when that is
 *      0 or p + s n is still inside it).
 *
 * Spheres: float4 (world centre, world radius) and the owning instance id.
 * Thin shells: triangles (3 float4 world vertices) and their instance ids,
 * marked into the same mask after the spheres (pn_isg_mark_triangle). The
 * LOD cut (`lod`, 0 = off): a tree node subtending under lod patch steps
 * marks with its bounding sphere (pn_isg_node_small). */
#include "common/brdf.cl"
#include "common/sg.cl"
#include "common/sphere_maps.cl"

#define PN_ISG_MAX_GRID 24
/* The shared hemisphere grid (shared_grid; pn_isg_shared_occluded) may be finer: one 32-bit word per row. */
#define PN_ISG_MAX_SHARED 31
#define PN_ISG_LANES 32 /* two float16 */
#define PN_ISG_WINDOW_SIGMAS 3.0f
#define PN_ISG_TOUCH 1e-3f
/* Own spheres within this share of their radius of the receiver are skipped
 * under self_occlusion 1. 0.02 with the inscribed sets of the builder (they
 * poke out of the surface by under 1 % of the object's size; measured on the
 * seed's Fig. 12 bunny and bunny_sunny, docs/isg.md section 9); 0.2 was best
 * for the variational sets, whose spheres poked out by a cell and a half
 * (-DPN_ISG_SELF_MARGIN=0.2f; 1e-3f, = PN_ISG_TOUCH, the rule before that). */
#ifndef PN_ISG_SELF_MARGIN
#define PN_ISG_SELF_MARGIN 0.02f
#endif
/* The seed's cosine lobe (after [WRG*09]). */
#define PN_ISG_COS_SHARPNESS 2.133f
#define PN_ISG_COS_AMPLITUDE 1.170f

/* Half-width of the patch window of a lobe of sharpness lambda. */
inline float pn_isg_window(float lambda)
{
    return fmin(0.5f * PN_PI, PN_ISG_WINDOW_SIGMAS * rsqrt(fmax(lambda, 1e-30f)));
}

/* A lobe's patch grid: its ISG frame, window [lo, lo + grid step]^2 and the
 * sines and cosines of the patch centres' angles (theta and phi alike). */
typedef struct {
    float3 x, y, z;
    float lo, step, cos_lo;
    int grid;
    /* PN_ISG_LANES entries, zero past `grid`: the marking tests 16 rows or columns at once. */
    float sin_c[PN_ISG_LANES], cos_c[PN_ISG_LANES];
} pn_isg_grid;

inline void pn_isg_grid_init(pn_sg g, int grid, pn_isg_grid *pg)
{
    pn_sg_frame(g.axis, &pg->x, &pg->y);
    pg->z = g.axis;
    const float w = pn_isg_window(g.sharpness);
    pg->lo = 0.5f * PN_PI - w;
    pg->step = 2.0f * w / (float)grid;
    pg->cos_lo = cos(pg->lo);
    pg->grid = grid;
    /* Angle addition from the first centre: two sincos per lobe, not 2M. */
    float cs, sn = sincos(pg->lo + 0.5f * pg->step, &cs), cd, sd = sincos(pg->step, &cd);
    for (int i = 0; i < grid; ++i) {
        pg->sin_c[i] = sn, pg->cos_c[i] = cs;
        const float s2 = sn * cd + cs * sd;
        cs = cs * cd - sn * sd, sn = s2;
    }
    for (int i = grid; i < PN_ISG_LANES; ++i)
        pg->sin_c[i] = 0.0f, pg->cos_c[i] = 0.0f;
}

/* The sphere tree (built by the host every frame, capi/src/methods/isg.c
 * sphere_tree; docs/isg.md section 8): the spheres in Morton order, level 1
 * the bounding spheres of 8 consecutive spheres, level l + 1 those of 8
 * consecutive level-l nodes, up to a top level of at most 8 nodes; the levels
 * are stored one after the other in `nodes`. levels = 0: no tree, the flat
 * loop over all spheres (the brute path, kept for the A/B). */
#define PN_ISG_TREE_FANOUT 8
#define PN_ISG_MAX_LEVELS 9

typedef struct {
    int levels;
    int count[PN_ISG_MAX_LEVELS + 1], offset[PN_ISG_MAX_LEVELS + 1];
    /* The LOD cut (`lod`, 0 = off; docs/isg.md section 8): a node wholly in
     * front of the receiver plane whose bounding sphere subtends less than lod
     * patch steps marks with that sphere in place of its spheres. */
    float lod;
    /* Thin shells (docs/isg.md section 8): triangles (3 float4 world-space
     * vertices each) and their instances, marked in every lobe after the
     * spheres, into the same mask. */
    global const float4 *tris;
    global const uint *tri_owners;
    int tri_count;
    /* Self-occlusion (docs/isg.md section 8): each sphere's skin (world
     * units, 0: none; null: all 0) and the inside_other policy. */
    global const float *skins;
    int inside_other;
} pn_isg_tree;

inline void pn_isg_tree_init(int sphere_count, int use_tree, pn_isg_tree *t)
{
    t->levels = 0;
    t->lod = 0.0f;
    t->tris = 0, t->tri_owners = 0, t->tri_count = 0;
    t->skins = 0, t->inside_other = 0;
    t->count[0] = sphere_count, t->offset[0] = 0;
    if (!use_tree || sphere_count <= 0)
        return;
    int n = sphere_count, offset = 0, l = 0;
    do {
        offset += l > 0 ? n : 0; /* past level l's nodes */
        n = (n + PN_ISG_TREE_FANOUT - 1) / PN_ISG_TREE_FANOUT, ++l;
        t->count[l] = n, t->offset[l] = offset;
    } while (n > PN_ISG_TREE_FANOUT && l < PN_ISG_MAX_LEVELS);
    t->levels = l;
}

/* The row (or column) whose centre is nearest the angle t, within one: the walks
 * of pn_isg_mark_sphere_rows start there. */
inline int pn_isg_cell(const pn_isg_grid *pg, float t)
{
    return (int)clamp((t - pg->lo) / pg->step, 0.0f, (float)(pg->grid - 1));
}

/* A patch row's mask with every column marked (grid <= PN_ISG_MAX_GRID < 32). */
inline uint pn_isg_full_row(int grid)
{
    return (1u << grid) - 1u;
}

/* Trailing zeros of f != 0 (ctz is OpenCL 2.0; clz is 1.2). */
inline int pn_isg_ctz(uint f)
{
    return 31 - (int)clz(f & (0u - f));
}

/* Whether every patch of the window is marked: no further sphere can change V. */
inline bool pn_isg_all_marked(const uint *mask, int grid)
{
    uint all = pn_isg_full_row(grid);
    for (int i = 0; i < grid; ++i)
        all &= mask[i];
    return all == pn_isg_full_row(grid);
}

/* Lanes of a 16-wide comparison (-1 where true) as bits base..base + 15. */
inline uint pn_isg_bits16(int16 m, int base)
{
    const uint16 w = as_uint16(m) & (uint16)(1u, 2u, 4u, 8u, 16u, 32u, 64u, 128u, 256u, 512u, 1024u, 2048u, 4096u,
                                             8192u, 16384u, 32768u);
    const uint8 a = w.lo | w.hi;
    const uint4 b = a.lo | a.hi;
    const uint2 c = b.lo | b.hi;
    return (c.x | c.y) << base;
}

/* One sphere's patches: marks in `mask` (one word per patch row, bit j for
 * column j) the patches whose centre direction lies in its cap seen from
 * (p, n). Returns -1 when the receiver is inside it (an occluder), 1 when it
 * marked something new, else 0. skin, inside_other: the sphere's skin and the
 * policy for another instance's sphere holding the receiver (file comment): an
 * own sphere under self_occlusion 1 within the margin, or such a sphere under
 * inside_other 2, is seen from p + skin n instead. No trigonometry: a row can hold marks only
 * where its best direction, at the sphere's phi, is within the cap
 * (sin(theta_i) rho + cos(theta_i) u_y >= cos alpha, with a 1e-6 slack for
 * rounding), and in such a row the patch test is d_ij . u >= cos alpha. Both
 * are evaluated 16 rows or columns at a time (float16: SIMD on a CPU, where the
 * earlier scalar walk from the nearest row and column, found by bisection,
 * was 2-3x slower; it marked the same patches; docs/isg.md section 9). */
inline int pn_isg_mark_sphere_rows(const pn_isg_grid *pg, float cos_cone, float sin_cone, float3 p, float3 n,
                                   float4 sp, bool own, int self_occlusion, float skin, int inside_other,
                                   uint *mask)
{
    const int grid = pg->grid;
    const uint full = pn_isg_full_row(grid);
    float3 v = sp.xyz - p;
    const float r = sp.w;
    float d2 = dot(v, v);
    if (dot(v, n) <= -r) /* wholly behind the receiver plane */
        return 0;
    if (own && self_occlusion == 0)
        return 0;
    const float touch = r * r * (1.0f + PN_ISG_TOUCH) * (1.0f + PN_ISG_TOUCH);
    const bool near_own =
        own && self_occlusion == 1 && d2 <= r * r * (1.0f + PN_ISG_SELF_MARGIN) * (1.0f + PN_ISG_SELF_MARGIN);
    if (!near_own && d2 <= touch && (own || inside_other == 0))
        return -1; /* inside an occluder */
    if (near_own || d2 <= touch) { /* seen from the receiver pushed out by the skin, or skipped */
        if (!(skin > 0.0f) || (!own && inside_other == 1))
            return 0;
        v -= skin * n;
        d2 = dot(v, v);
        if (dot(v, n) <= -r || d2 <= touch)
            return 0;
    }
    const float d = sqrt(d2);
    const float3 u = v / d;
    const float sa = fmin(r / d, 1.0f), ca = sqrt(fmax(1.0f - sa * sa, 0.0f));
    if (cos_cone > -ca && dot(u, pg->z) < cos_cone * ca - sin_cone * sa)
        return 0;
    const float3 ul = (float3)(dot(u, pg->x), dot(u, pg->y), dot(u, pg->z));
    const float rho = sqrt(ul.x * ul.x + ul.z * ul.z);
    const float16 s0 = vload16(0, pg->sin_c), c0 = vload16(0, pg->cos_c);
    uint rows = pn_isg_bits16(s0 * rho + c0 * ul.y >= ca - 1e-6f, 0);
    if (grid > 16)
        rows |= pn_isg_bits16(vload16(1, pg->sin_c) * rho + vload16(1, pg->cos_c) * ul.y >= ca - 1e-6f, 16);
    /* Each column's azimuthal part, shared by the rows. */
    const float16 h0 = c0 * ul.x + s0 * ul.z;
    const float16 h1 = grid > 16 ? vload16(1, pg->cos_c) * ul.x + vload16(1, pg->sin_c) * ul.z : (float16)(0.0f);
    uint marked = 0u;
    for (uint f = rows & full; f != 0u; f &= f - 1u) {
        const int i = pn_isg_ctz(f);
        const uint row = mask[i];
        if (row == full) /* nothing left to mark in this row */
            continue;
        const float si = pg->sin_c[i], ci = pg->cos_c[i];
        uint cols = pn_isg_bits16(si * h0 + ci * ul.y >= ca, 0);
        if (grid > 16)
            cols |= pn_isg_bits16(si * h1 + ci * ul.y >= ca, 16);
        const uint bits = cols & full & ~row;
        mask[i] = row | bits;
        marked |= bits;
    }
    return marked != 0u;
}

#define PN_ISG_SHELL_FLAT 1e-6f
#define PN_ISG_SHELL_OWN_FLAT 1e-3f

/* A triangle's vertices from p (a, b, c), its edge-plane normals (bc, ca, ab)
 * and det = a . (b x c); false when it cannot mark: the receiver's own with
 * self_occlusion 0, wholly behind the receiver's plane, or seen edge-on
 * (|det| within the flatness tolerance of the vertices' distances). */
inline bool pn_isg_triangle_setup(float3 p, float3 n, float3 v0, float3 v1, float3 v2, bool own, int self_occlusion,
                                  float3 *a, float3 *b, float3 *c, float3 *bc, float3 *ca, float3 *ab, float *det)
{
    if (own && self_occlusion == 0)
        return false;
    *a = v0 - p, *b = v1 - p, *c = v2 - p;
    if (dot(*a, n) <= 0.0f && dot(*b, n) <= 0.0f && dot(*c, n) <= 0.0f)
        return false;
    *bc = cross(*b, *c), *ca = cross(*c, *a), *ab = cross(*a, *b);
    *det = dot(*a, *bc);
    const float tol = own && self_occlusion == 1 ? PN_ISG_SHELL_OWN_FLAT : PN_ISG_SHELL_FLAT;
    return fabs(*det) > tol * length(*a) * length(*b) * length(*c);
}

/* The columns of row (si, ci) = (sin, cos of its polar angle) inside the
 * triangle: every edge plane's d . e_k >= 0, with h_k (g_k for columns 16-31)
 * the azimuthal part of d . e_k and ly_k its polar part. */
inline uint pn_isg_triangle_row(float si, float ci, float16 h0, float16 h1, float16 h2, float16 g0, float16 g1,
                                float16 g2, float ly0, float ly1, float ly2, int grid)
{
    uint cols = pn_isg_bits16((si * h0 + ci * ly0 >= 0.0f) & (si * h1 + ci * ly1 >= 0.0f) & (si * h2 + ci * ly2 >= 0.0f), 0);
    if (grid > 16)
        cols |= pn_isg_bits16((si * g0 + ci * ly0 >= 0.0f) & (si * g1 + ci * ly1 >= 0.0f) & (si * g2 + ci * ly2 >= 0.0f), 16);
    return cols;
}

/* Thin shells: a triangle's patches, those whose centre direction d hits it
 * from p (d a positive combination of its vertices seen from p: the three
 * edge planes' normals e_k = +-(b x c, c x a, a x b), signed by the
 * orientation det = a.(b x c), all have d.e_k >= 0). The same 16-wide row
 * and column tests as a sphere's. Skipped: triangles wholly behind the
 * receiver plane, outside the window's cone (by their bounding sphere), and
 * those nearly in the receiver's plane, |det| <= tol |a||b||c| (degenerate
 * triangles, edge-on ones seen from p, the one the receiver lies on): tol is
 * PN_ISG_SHELL_FLAT, or PN_ISG_SHELL_OWN_FLAT for the receiver's own triangles
 * under self_occlusion 1 (its flat neighbourhood on the sheet); own
 * triangles are ignored under self_occlusion 0. Returns 1 when it marked
 * something new, else 0. */
inline int pn_isg_mark_triangle(const pn_isg_grid *pg, float cos_cone, float sin_cone, float3 p, float3 n,
                                float3 v0, float3 v1, float3 v2, bool own, int self_occlusion, uint *mask)
{
    float3 a, b, c, bc, ca, ab;
    float det;
    if (!pn_isg_triangle_setup(p, n, v0, v1, v2, own, self_occlusion, &a, &b, &c, &bc, &ca, &ab, &det))
        return 0;
    /* The cone cull by the triangle's bounding sphere (centroid, farthest vertex,
     * padded by 1e-4), and the rows that can hold its directions: those whose
     * best direction lies in that sphere's cap (the spheres' row test). */
    const float3 m = (a + b + c) * (1.0f / 3.0f);
    const float r = 1.0001f * sqrt(fmax(fmax(dot(a - m, a - m), dot(b - m, b - m)), dot(c - m, c - m)));
    const float d = length(m);
    const int grid = pg->grid;
    const uint full = pn_isg_full_row(grid);
    const float16 s0 = vload16(0, pg->sin_c), c0 = vload16(0, pg->cos_c);
    const float16 s1 = vload16(1, pg->sin_c), c1 = vload16(1, pg->cos_c);
    uint rows = full;
    if (d > r) {
        const float sa = r / d, cs = sqrt(fmax(1.0f - sa * sa, 0.0f));
        if (cos_cone > -cs && dot(m, pg->z) < d * (cos_cone * cs - sin_cone * sa))
            return 0;
        const float3 u = m / d, ul = (float3)(dot(u, pg->x), dot(u, pg->y), dot(u, pg->z));
        const float rho = sqrt(ul.x * ul.x + ul.z * ul.z);
        rows = pn_isg_bits16(s0 * rho + c0 * ul.y >= cs - 1e-6f, 0);
        if (grid > 16)
            rows |= pn_isg_bits16(s1 * rho + c1 * ul.y >= cs - 1e-6f, 16);
    }
    const float sg = det > 0.0f ? 1.0f : -1.0f;
    const float3 e0 = sg * bc, e1 = sg * ca, e2 = sg * ab;
    const float3 l0 = (float3)(dot(e0, pg->x), dot(e0, pg->y), dot(e0, pg->z));
    const float3 l1 = (float3)(dot(e1, pg->x), dot(e1, pg->y), dot(e1, pg->z));
    const float3 l2 = (float3)(dot(e2, pg->x), dot(e2, pg->y), dot(e2, pg->z));
    /* Each column's azimuthal part of d.e_k, shared by the rows. */
    const float16 h0 = c0 * l0.x + s0 * l0.z, h1 = c0 * l1.x + s0 * l1.z, h2 = c0 * l2.x + s0 * l2.z;
    const float16 g0 = c1 * l0.x + s1 * l0.z, g1 = c1 * l1.x + s1 * l1.z, g2 = c1 * l2.x + s1 * l2.z;
    uint marked = 0u;
    for (uint f = rows & full; f != 0u; f &= f - 1u) {
        const int i = pn_isg_ctz(f);
        const uint row = mask[i];
        if (row == full)
            continue;
        const float si = pg->sin_c[i], ci = pg->cos_c[i];
        const uint cols = pn_isg_triangle_row(si, ci, h0, h1, h2, g0, g1, g2, l0.y, l1.y, l2.y, grid);
        const uint bits = cols & full & ~row;
        mask[i] = row | bits;
        marked |= bits;
    }
    return marked != 0u;
}

/* The unmarked patches a triangle inside sphere b may still mark, seen from
 * p, into cand (one word per row, bit j for column j): none when b is wholly
 * behind the receiver plane or outside the window's cone, else those whose
 * centre lies in b's cap (the spheres' row and column tests, with their 1e-6
 * slack: a direction that hits a triangle inside b lies in that cap), or
 * every unmarked patch when the receiver is within b. Returns the rows that
 * hold one (bit i for row i). */
inline uint pn_isg_group_candidates(const pn_isg_grid *pg, float cos_cone, float sin_cone, float3 p, float3 n,
                                    float4 b, const uint *mask, uint *cand)
{
    const float3 v = b.xyz - p;
    const float r = b.w, d2 = dot(v, v);
    if (dot(v, n) <= -r)
        return 0u;
    const int grid = pg->grid;
    const uint full = pn_isg_full_row(grid);
    uint out = 0u;
    if (d2 <= r * r) {
        for (int i = 0; i < grid; ++i) {
            cand[i] = full & ~mask[i];
            out |= cand[i] != 0u ? 1u << i : 0u;
        }
        return out;
    }
    const float d = sqrt(d2), sa = r / d, cs = sqrt(fmax(1.0f - sa * sa, 0.0f));
    if (cos_cone > -cs && dot(v, pg->z) < d * (cos_cone * cs - sin_cone * sa))
        return 0u;
    const float3 u = v / d, ul = (float3)(dot(u, pg->x), dot(u, pg->y), dot(u, pg->z));
    const float rho = sqrt(ul.x * ul.x + ul.z * ul.z);
    const float16 s0 = vload16(0, pg->sin_c), c0 = vload16(0, pg->cos_c);
    uint rows = pn_isg_bits16(s0 * rho + c0 * ul.y >= cs - 1e-6f, 0);
    const float16 h0 = c0 * ul.x + s0 * ul.z;
    float16 h1 = (float16)(0.0f);
    if (grid > 16) {
        const float16 s1 = vload16(1, pg->sin_c), c1 = vload16(1, pg->cos_c);
        rows |= pn_isg_bits16(s1 * rho + c1 * ul.y >= cs - 1e-6f, 16);
        h1 = c1 * ul.x + s1 * ul.z;
    }
    for (uint f = rows & full; f != 0u; f &= f - 1u) {
        const int i = pn_isg_ctz(f);
        const uint row = mask[i];
        if (row == full)
            continue;
        const float si = pg->sin_c[i], ci = pg->cos_c[i];
        uint cols = pn_isg_bits16(si * h0 + ci * ul.y >= cs - 1e-6f, 0);
        if (grid > 16)
            cols |= pn_isg_bits16(si * h1 + ci * ul.y >= cs - 1e-6f, 16);
        cand[i] = cols & full & ~row;
        out |= cand[i] != 0u ? 1u << i : 0u;
    }
    return out;
}

/* pn_isg_mark_triangle on a group's candidate rows (pn_isg_group_candidates):
 * the same skips and edge-plane tests, without the triangle's own cap (the
 * group's is the prefilter); what it marks leaves the candidates, and a row
 * without candidates leaves *rows. Returns 1 when it marked something, else 0. */
inline int pn_isg_mark_triangle_rows(const pn_isg_grid *pg, float3 p, float3 n, float3 v0, float3 v1, float3 v2,
                                     bool own, int self_occlusion, uint *mask, uint *cand, uint *rows)
{
    float3 a, b, c, bc, ca, ab;
    float det;
    if (!pn_isg_triangle_setup(p, n, v0, v1, v2, own, self_occlusion, &a, &b, &c, &bc, &ca, &ab, &det))
        return 0;
    const int grid = pg->grid;
    const uint full = pn_isg_full_row(grid);
    const float sg = det > 0.0f ? 1.0f : -1.0f;
    const float3 e0 = sg * bc, e1 = sg * ca, e2 = sg * ab;
    const float3 l0 = (float3)(dot(e0, pg->x), dot(e0, pg->y), dot(e0, pg->z));
    const float3 l1 = (float3)(dot(e1, pg->x), dot(e1, pg->y), dot(e1, pg->z));
    const float3 l2 = (float3)(dot(e2, pg->x), dot(e2, pg->y), dot(e2, pg->z));
    const float16 s0 = vload16(0, pg->sin_c), c0 = vload16(0, pg->cos_c);
    const float16 h0 = c0 * l0.x + s0 * l0.z, h1 = c0 * l1.x + s0 * l1.z, h2 = c0 * l2.x + s0 * l2.z;
    float16 g0 = (float16)(0.0f), g1 = g0, g2 = g0;
    if (grid > 16) {
        const float16 s1 = vload16(1, pg->sin_c), c1 = vload16(1, pg->cos_c);
        g0 = c1 * l0.x + s1 * l0.z, g1 = c1 * l1.x + s1 * l1.z, g2 = c1 * l2.x + s1 * l2.z;
    }
    uint marked = 0u;
    for (uint f = *rows; f != 0u; f &= f - 1u) {
        const int i = pn_isg_ctz(f);
        const uint row = mask[i];
        const float si = pg->sin_c[i], ci = pg->cos_c[i];
        const uint cols = pn_isg_triangle_row(si, ci, h0, h1, h2, g0, g1, g2, l0.y, l1.y, l2.y, grid);
        const uint bits = cols & full & ~row;
        mask[i] = row | bits;
        marked |= bits;
        cand[i] &= ~bits;
        if (cand[i] == 0u)
            *rows &= ~(1u << i);
    }
    return marked != 0u;
}

/* 0: every triangle tested on its own, groups ignored (the A/B of docs/isg.md section 9, "Thin shells"). */
#ifndef PN_ISG_SHELL_GROUPS
#define PN_ISG_SHELL_GROUPS 1
#endif
#define PN_ISG_SHELL_GROUP 8

/* The thin-shell triangles of `tree` into the mask (after the spheres), in
 * groups of PN_ISG_SHELL_GROUP consecutive triangles: the host
 * (capi/src/methods/isg.c shell_groups) orders them along a Morton curve and
 * writes each group's bounding sphere into the spare w of its first four
 * vertices (centre in the first triangle's, radius in the second's first
 * vertex; radius 0: no bound, the triangles tested on their own). A group
 * finds the unmarked patches its sphere's cap holds
 * (pn_isg_group_candidates): none, it is skipped whole; else its triangles
 * test only the rows holding them, until none is left. The marks are those
 * of testing every triangle (beyond rounding at the caps' 1e-6 slack, as the
 * spheres' and each triangle's own row prefilter). */
inline int pn_isg_mark_triangles(const pn_isg_grid *pg, float cos_cone, float sin_cone, float3 p, float3 n,
                                 uint self_id, int self_occlusion, const pn_isg_tree *tree, uint *mask)
{
    int any = 0;
    const int count = tree->tri_count;
    uint cand[PN_ISG_MAX_SHARED];
    for (int g = 0; g < count; g += PN_ISG_SHELL_GROUP) {
        const int end = min(g + PN_ISG_SHELL_GROUP, count);
        float4 b = (float4)(0.0f);
        if (PN_ISG_SHELL_GROUPS && end - g > 1)
            b = (float4)(tree->tris[3 * g].w, tree->tris[3 * g + 1].w, tree->tris[3 * g + 2].w,
                         tree->tris[3 * g + 3].w);
        if (b.w > 0.0f) {
            uint rows = pn_isg_group_candidates(pg, cos_cone, sin_cone, p, n, b, mask, cand);
            for (int t = g; t < end && rows != 0u; ++t)
                any += pn_isg_mark_triangle_rows(pg, p, n, tree->tris[3 * t].xyz, tree->tris[3 * t + 1].xyz,
                                                 tree->tris[3 * t + 2].xyz, tree->tri_owners[t] == self_id,
                                                 self_occlusion, mask, cand, &rows);
            continue;
        }
        for (int t = g; t < end; ++t) {
            const int m = pn_isg_mark_triangle(pg, cos_cone, sin_cone, p, n, tree->tris[3 * t].xyz,
                                               tree->tris[3 * t + 1].xyz, tree->tris[3 * t + 2].xyz,
                                               tree->tri_owners[t] == self_id, self_occlusion, mask);
            any += m;
            if (m > 0 && pn_isg_all_marked(mask, pg->grid))
                return any;
        }
    }
    return any;
}

/* A tree node (bounding sphere b) that may hold a sphere marking a patch or
 * containing the receiver: not wholly behind the receiver plane, and its cap
 * not outside the window's cone unless the receiver is inside it. The host
 * pads node radii (sphere_tree), so a node is culled only where every sphere
 * in it is culled by pn_isg_mark_sphere_rows's own tests beyond rounding. */
inline bool pn_isg_node_open(float4 b, float3 p, float3 n, float3 z, float cos_cone, float sin_cone)
{
    const float3 v = b.xyz - p;
    const float r = b.w, d2 = dot(v, v);
    if (dot(v, n) <= -r)
        return false;
    /* Open when the receiver is within the self margin: a sphere in it that
     * holds or nearly touches the receiver may be seen from p + skin n. */
    const float rin = r * (1.0f + fmax(PN_ISG_TOUCH, PN_ISG_SELF_MARGIN));
    if (d2 <= rin * rin)
        return true;
    const float d = sqrt(d2), sa = fmin(r / d, 1.0f), ca = sqrt(fmax(1.0f - sa * sa, 0.0f));
    return !(cos_cone > -ca && dot(v, z) < d * (cos_cone * ca - sin_cone * sa));
}

/* The LOD cut's test: node b is wholly in front of the receiver plane and its
 * bounding sphere's angular radius asin(r / d) is below half the cut's angle
 * (r < d sin_lod): then the receiver is outside every sphere in it (none holds
 * or touches it, sin_lod < 1), and the node's cap holds their caps. */
inline bool pn_isg_node_small(float4 b, float3 p, float3 n, float sin_lod)
{
    const float3 v = b.xyz - p;
    return dot(v, n) >= b.w && b.w * b.w < sin_lod * sin_lod * dot(v, v);
}

/* Whether sphere sp makes the receiver "inside an occluder" (pn_isg_mark_sphere_rows's
 * -1): the same tests, none of which depends on the lobe. */
inline bool pn_isg_inside_sphere(float3 p, float3 n, float4 sp, bool own, int self_occlusion, int inside_other)
{
    const float3 v = sp.xyz - p;
    const float r = sp.w;
    if (dot(v, n) <= -r || (own && self_occlusion != 2) || (!own && inside_other != 0))
        return false;
    return dot(v, v) <= r * r * (1.0f + PN_ISG_TOUCH) * (1.0f + PN_ISG_TOUCH);
}

/* Whether the receiver is inside an occluder: a per-pixel fact (every lobe's V
 * is then 0), found once by a walk that opens only the nodes holding p (a node
 * holds its spheres, so it reaches every sphere pn_isg_mark would report). */
inline bool pn_isg_inside(float3 p, float3 n, uint self_id, int self_occlusion, global const float4 *spheres,
                          global const uint *owners, int sphere_count, global const float4 *nodes,
                          const pn_isg_tree *tree)
{
    if (tree->levels == 0) {
        for (int s = 0; s < sphere_count; ++s)
            if (pn_isg_inside_sphere(p, n, spheres[s], owners[s] == self_id, self_occlusion,
                                     tree->inside_other))
                return true;
        return false;
    }
    const int top = tree->levels;
    int l = top, i = 0;
    while (l < top || i < tree->count[top]) {
        const float4 b = nodes[tree->offset[l] + i];
        const float3 v = b.xyz - p;
        const float rin = b.w * (1.0f + PN_ISG_TOUCH);
        if (dot(v, n) > -b.w && dot(v, v) <= rin * rin) {
            if (l > 1) {
                --l, i *= PN_ISG_TREE_FANOUT;
                continue;
            }
            const int s1 = min((i + 1) * PN_ISG_TREE_FANOUT, sphere_count);
            for (int s = i * PN_ISG_TREE_FANOUT; s < s1; ++s)
                if (pn_isg_inside_sphere(p, n, spheres[s], owners[s] == self_id, self_occlusion,
                                     tree->inside_other))
                    return true;
        }
        ++i;
        while (l < top && (i % PN_ISG_TREE_FANOUT == 0 || i >= tree->count[l]))
            i = (i - 1) / PN_ISG_TREE_FANOUT + 1, ++l;
    }
    return false;
}

/* pn_isg_mark_sphere_rows for spheres [s0, s1): -1 when the receiver is inside
 * one, else the number that marked something; stops with *full set once every
 * patch of the window is marked. */
inline int pn_isg_mark_range(const pn_isg_grid *pg, float cos_cone, float sin_cone, float3 p, float3 n, uint self_id,
                             int self_occlusion, global const float4 *spheres, global const uint *owners,
                             const pn_isg_tree *tree, int s0, int s1, uint *mask, bool *full)
{
    int any = 0;
    for (int s = s0; s < s1; ++s) {
        const int m = pn_isg_mark_sphere_rows(pg, cos_cone, sin_cone, p, n, spheres[s], owners[s] == self_id,
                                              self_occlusion, tree->skins ? tree->skins[s] : 0.0f,
                                              tree->inside_other, mask);
        if (m < 0)
            return -1;
        any += m;
        if (m > 0 && pn_isg_all_marked(mask, pg->grid)) {
            *full = true;
            return any;
        }
    }
    return any;
}

/* Marks in `mask` the patches whose centre direction meets a sphere seen from
 * (p, n): every sphere (tree->levels = 0) or those in the tree's nodes that
 * pn_isg_node_open keeps. Returns -1 when the receiver is inside an occluder,
 * else the number of spheres that marked something (0: the lobe is
 * unoccluded). Stops once every patch is marked: the spheres left can only
 * report "inside", which shade_isg has ruled out per pixel (pn_isg_inside),
 * so the image is the same. */
inline int pn_isg_mark_spheres(const pn_isg_grid *pg, float3 p, float3 n, uint self_id, int self_occlusion,
                               global const float4 *spheres, global const uint *owners, int sphere_count,
                               global const float4 *nodes, const pn_isg_tree *tree, uint *mask)
{
    /* The window's cone: its corners lie within w * sqrt(2) of the axis. */
    const float cone = fmin((0.5f * PN_PI - pg->lo) * 1.41421356f, PN_PI), cos_cone = cos(cone), sin_cone = sin(cone);
    for (int i = 0; i < pg->grid; ++i)
        mask[i] = 0u;
    int any = 0;
    if (sphere_count <= 0)
        return 0;
    bool full = false;
    if (tree->levels == 0)
        return pn_isg_mark_range(pg, cos_cone, sin_cone, p, n, self_id, self_occlusion, spheres, owners, tree, 0,
                                 sphere_count, mask, &full);
    /* The LOD cut: nodes subtending less than lod patch steps (half-angle
     * below lod step / 2, capped short of a hemisphere) stand for their
     * spheres. Not with self_occlusion 0, where a node's own spheres would
     * count; 0 when lod is 0 (the exact walk). */
    const float sin_lod =
        tree->lod > 0.0f && self_occlusion != 0 ? sin(fmin(0.5f * tree->lod * pg->step, 1.5f)) : 0.0f;
    const int top = tree->levels;
    int l = top, i = 0;
    while (l < top || i < tree->count[top]) {
        const float4 b = nodes[tree->offset[l] + i];
        if (pn_isg_node_open(b, p, n, pg->z, cos_cone, sin_cone)) {
            if (sin_lod > 0.0f && pn_isg_node_small(b, p, n, sin_lod)) {
                const int m = pn_isg_mark_sphere_rows(pg, cos_cone, sin_cone, p, n, b, false, self_occlusion, 0.0f, 0,
                                                              mask);
                any += m; /* >= 0: the receiver is outside the node */
                if (m > 0 && pn_isg_all_marked(mask, pg->grid))
                    return any;
            } else if (l > 1) {
                --l, i *= PN_ISG_TREE_FANOUT;
                continue;
            } else {
                const int m = pn_isg_mark_range(pg, cos_cone, sin_cone, p, n, self_id, self_occlusion, spheres,
                                                owners, tree, i * PN_ISG_TREE_FANOUT,
                                                min((i + 1) * PN_ISG_TREE_FANOUT, sphere_count), mask, &full);
                if (m < 0)
                    return -1;
                any += m;
                if (full)
                    return any;
            }
        }
        /* The next node: the next sibling, or up while this sibling group is done. */
        ++i;
        while (l < top && (i % PN_ISG_TREE_FANOUT == 0 || i >= tree->count[l]))
            i = (i - 1) / PN_ISG_TREE_FANOUT + 1, ++l;
    }
    return any;
}

/* pn_isg_mark_spheres, then the thin-shell triangles into the same mask (a
 * patch covered by spheres and triangles alike counts once): -1 when the
 * receiver is inside an occluder sphere, else the number of spheres and
 * triangles that marked something. */
inline int pn_isg_mark(const pn_isg_grid *pg, float3 p, float3 n, uint self_id, int self_occlusion,
                       global const float4 *spheres, global const uint *owners, int sphere_count,
                       global const float4 *nodes, const pn_isg_tree *tree, uint *mask)
{
    const int any = pn_isg_mark_spheres(pg, p, n, self_id, self_occlusion, spheres, owners, sphere_count, nodes,
                                        tree, mask);
    if (any < 0 || tree->tri_count <= 0 || (any > 0 && pn_isg_all_marked(mask, pg->grid)))
        return any;
    const float cone = fmin((0.5f * PN_PI - pg->lo) * 1.41421356f, PN_PI), cos_cone = cos(cone), sin_cone = sin(cone);
    return any + pn_isg_mark_triangles(pg, cos_cone, sin_cone, p, n, self_id, self_occlusion, tree, mask);
}

inline bool pn_isg_masked(const uint *mask, int i, int j)
{
    return ((mask[i] >> j) & 1u) != 0u;
}

/* The window lies in the front half (phi <= pi), where the table's ISG is
 * A(theta) B(phi): a patch is (A(t1) - A(t0)) (B(p1) - B(p0)), the four
 * corners of the seed's formula in 2 (M + 1) evaluations. a_edge, b_edge:
 * A and B at the window's patch edges. */
inline void pn_isg_edges(const pn_isg_grid *pg, float lambda, global const float *table, float *a_edge, float *b_edge)
{
    /* pn_isg's marginals with its per-lambda terms hoisted: A = front theta
     * (block 0), B = front phi (block 1) of the table (common/sg.cl). */
    const float u = pn_isg_row(lambda), k = sqrt(0.5f * lambda), inv = 1.0f / erf(k * 0.5f * PN_PI);
    for (int j = 0; j <= pg->grid; ++j) {
        const float e = pg->lo + (float)j * pg->step;
        /* pn_isg_cdf of blocks 0 and 1, sharing the erf warp of the edge (the same angle). */
        const float x = e - 0.5f * PN_PI, rho = pn_isg_front_rho(fabs(x), k, inv);
        a_edge[j] = 0.5f + copysign(pn_isg_lookup(table, 0, u, rho), x);
        b_edge[j] = 0.5f + copysign(pn_isg_lookup(table, 1, u, rho), x);
    }
}

/* The visible share of lobe g (its amplitude unused) seen from p with normal n:
 * 1 - sum over occluded patches of ISG(patch) / ISG(window). */
inline float pn_isg_visibility(pn_sg g, float3 p, float3 n, uint self_id, int self_occlusion,
                               global const float4 *spheres, global const uint *owners, int sphere_count,
                               global const float4 *nodes, const pn_isg_tree *tree, int grid,
                               global const float *table)
{
    pn_isg_grid pg;
    pn_isg_grid_init(g, grid, &pg);
    uint mask[PN_ISG_MAX_GRID];
    const int any = pn_isg_mark(&pg, p, n, self_id, self_occlusion, spheres, owners, sphere_count, nodes, tree, mask);
    if (any <= 0)
        return any < 0 ? 0.0f : 1.0f;
    float a_edge[PN_ISG_MAX_GRID + 1], b_edge[PN_ISG_MAX_GRID + 1];
    pn_isg_edges(&pg, g.sharpness, table, a_edge, b_edge);
    float occluded = 0.0f;
    for (int i = 0; i < grid; ++i) {
        if (mask[i] == 0u)
            continue;
        float row = 0.0f;
        for (int j = 0; j < grid; ++j)
            if (pn_isg_masked(mask, i, j))
                row += b_edge[j + 1] - b_edge[j];
        occluded += (a_edge[i + 1] - a_edge[i]) * row;
    }
    const float total = (a_edge[grid] - a_edge[0]) * (b_edge[grid] - b_edge[0]);
    if (!(total > 0.0f))
        return 1.0f;
    return clamp(1.0f - occluded / total, 0.0f, 1.0f);
}

/* Prefiltered lighting Gamma_L(a, lambda) (the seed's eq. 10; docs/isg.md
 * section 8): the env convolved with a normalised SG,
 *   Gamma_L(a, lambda) = sum_t w_t L_t e^{lambda (a.t - 1)} / sum_t w_t e^{lambda (a.t - 1)}
 * over the source cube's texels t (direction, solid angle w_t), the lobe's
 * tail beyond e^{-PN_ISG_GAMMA_CUT} dropped from both sums (so a constant env
 * gives the constant exactly). Levels lambda_l = lambda_0 2^l, each a
 * vertex-grid cube (pn_cube_grid_lookup: seamless at the cube's edges) built by
 * isg_prefilter from a source halved by isg_cube_halve while its texels stay
 * finer than the lobe (host: capi/src/methods/isg.c build_gamma). Twin:
 * tests/isg_shading64.py prefilter / gamma_lookup. */
#define PN_ISG_GAMMA_CUT 20.0f
/* Above this half-angle of the cut the cube-face window below is not
 * conservative (a face whose axis is 90 degrees or more from a is 35.26
 * degrees or more from it): every texel is visited. */
#define PN_ISG_GAMMA_WINDOWED 0.6f

/* A source of half the face size: each texel the solid-angle-weighted mean of
 * its 2 x 2 children, its solid angle their sum (a cube's power is kept), its
 * direction their power centroid (directions weighted by solid angle x the sum
 * of RGB, + 1e-30 so a black block gets its geometric centre): a sun keeps its
 * direction (a 1e5:1 one-texel sun: 7 % error at lambda = 1 with the plain
 * mean direction, 0.9 % with the centroid; docs/isg.md section 8). */
kernel void isg_cube_halve(global const float4 *cube, global const float4 *dirs, int n, global float4 *cube_out,
                           global float4 *dirs_out)
{
    const int h = n / 2, gid = get_global_id(0);
    if (gid >= 6 * h * h)
        return;
    const int f = gid / (h * h), j = (gid / h) % h, i = gid % h;
    float4 l = (float4)(0.0f);
    float3 d = (float3)(0.0f);
    float w = 0.0f;
    for (int dj = 0; dj < 2; ++dj)
        for (int di = 0; di < 2; ++di) {
            const int t = pn_cube_index(f, 2 * i + di, 2 * j + dj, n);
            const float4 c = cube[t], dw = dirs[t];
            l += dw.w * c;
            d += dw.w * (c.x + c.y + c.z + 1e-30f) * dw.xyz;
            w += dw.w;
        }
    cube_out[gid] = w > 0.0f ? l / w : (float4)(0.0f);
    dirs_out[gid] = (float4)(normalize(d), w);
}

/* One level of Gamma_L: out[offset + vertex] for the 6 n_out^2 vertices of a
 * vertex-grid cube, from the source cube of face n_src. Sharp lobes visit on
 * each face only the texels whose centres can lie within the cut: for t on
 * face g and a projected onto g's plane (gnomonic, a_g = a / (a.e_g)),
 * |t_g - a_g| <= |t_g x a_g| = sin(angle) |t_g| |a_g| <= |t_g| sin(theta_cut) / (a.e_g)
 * with |t_g| <= sqrt 3, so a box of that half-size around a_g (plus a texel:
 * the halved sources' directions are centroids, not centres) holds them all;
 * then again with |t_g| bounded at that box's far corner on the face. */
kernel void isg_prefilter(global const float4 *cube, global const float4 *dirs, int n_src, float lambda, int n_out,
                          int offset, global float4 *out)
{
    const int gid = get_global_id(0);
    if (gid >= 6 * n_out * n_out)
        return;
    const int f = gid / (n_out * n_out), j = (gid / n_out) % n_out, i = gid % n_out;
    const float step = 2.0f / (float)(n_out - 1);
    const float3 a = normalize(pn_cube_to_dir(f, -1.0f + (float)i * step, -1.0f + (float)j * step));
    const float cos_cut = 1.0f - PN_ISG_GAMMA_CUT / lambda, sin_cut = sqrt(fmax(1.0f - cos_cut * cos_cut, 0.0f));
    const bool windowed = cos_cut > cos(PN_ISG_GAMMA_WINDOWED);
    float3 sum = (float3)(0.0f);
    float weight = 0.0f;
    for (int g = 0; g < 6; ++g) {
        int i0 = 0, i1 = n_src - 1, j0 = 0, j1 = n_src - 1;
        if (windowed) {
            const float3 e = pn_cube_to_dir(g, 0.0f, 0.0f);
            const float de = dot(a, e);
            if (de <= 0.0f)
                continue;
            const float ag = dot(a, pn_cube_to_dir(g, 1.0f, 0.0f) - e) / de;
            const float bg = dot(a, pn_cube_to_dir(g, 0.0f, 1.0f) - e) / de;
            /* |t_g| <= sqrt 3 first, then sqrt(1 + a^2 + b^2) at the first box's far corner on the face. */
            const float h0 = fmin(1.73205081f * sin_cut / de, 4.0f);
            const float fa = fmin(fabs(ag) + h0, 1.0f), fb = fmin(fabs(bg) + h0, 1.0f);
            const float h = fmin(sqrt(1.0f + fa * fa + fb * fb) * sin_cut / de, 4.0f), half_n = 0.5f * (float)n_src;
            i0 = max((int)floor((ag - h + 1.0f) * half_n) - 1, 0), i1 = min((int)floor((ag + h + 1.0f) * half_n) + 1, n_src - 1);
            j0 = max((int)floor((bg - h + 1.0f) * half_n) - 1, 0), j1 = min((int)floor((bg + h + 1.0f) * half_n) + 1, n_src - 1);
        }
        for (int tj = j0; tj <= j1; ++tj)
            for (int ti = i0; ti <= i1; ++ti) {
                const int t = pn_cube_index(g, ti, tj, n_src);
                const float4 dw = dirs[t];
                const float c = dot(a, dw.xyz);
                if (c < cos_cut)
                    continue;
                const float w = dw.w * exp(lambda * (c - 1.0f));
                sum += w * cube[t].xyz;
                weight += w;
            }
    }
    out[offset + gid] = (float4)(weight > 0.0f ? sum / weight : (float3)(0.0f), 0.0f);
}

/* Gamma_L(d, lambda): bilinear in direction on the two levels around lambda,
 * linear in log2 lambda between them, clamped to the first and last levels.
 * levels: (offset, face vertices) per level; lambda_l = lambda0 2^l. */
inline float3 pn_isg_gamma(global const float4 *gamma, global const int *levels, int count, float lambda0,
                           float3 d, float lambda)
{
    const float t = clamp(log2(fmax(lambda, 1e-30f) / lambda0), 0.0f, (float)(count - 1));
    const int l0 = min((int)t, max(count - 2, 0)), l1 = min(l0 + 1, count - 1);
    const float3 g0 = pn_cube_grid_lookup(gamma + levels[2 * l0], levels[2 * l0 + 1], d);
    const float3 g1 = pn_cube_grid_lookup(gamma + levels[2 * l1], levels[2 * l1 + 1], d);
    return mix(g0, g1, t - (float)l0);
}

/* Where the specular term of a sharp BRDF lobe finds its light. */
#define PN_ISG_SPECULAR_PATCHES 0     /* the env cube at each visible patch's centre */
#define PN_ISG_SPECULAR_PREFILTERED 1 /* Gamma_L at the lobe's axis, times the visible patches' share */

/* The specular integral of a sharp BRDF lobe b over its visible patches:
 *   patches:      amplitude H(lambda) sum_visible ISG_hat(patch) L(d) max(n.d, 0)
 *   prefiltered:  amplitude H(lambda) Gamma_L(axis, lambda) sum_visible ISG_hat(patch) max(n.d, 0)
 * with d the patch centre, L(d) the env cube there. The first is the seed's
 * Gamma_L by quadrature on the lobe's own patches, occluded patches left out;
 * the second is the seed's eq. 10, Gamma_L times the visibility ratio (the
 * visible over all patches, cosine-weighted, times their unoccluded sum). */
inline float3 pn_isg_env_specular(pn_sg b, float3 p, float3 n, uint self_id, int self_occlusion,
                                  global const float4 *spheres, global const uint *owners, int sphere_count,
                                  global const float4 *nodes, const pn_isg_tree *tree, int grid,
                                  global const float *table, global const float4 *cube, int n_cube, int mode,
                                  global const float4 *gamma, global const int *levels, int level_count,
                                  float lambda0)
{
    pn_isg_grid pg;
    pn_isg_grid_init(b, grid, &pg);
    uint mask[PN_ISG_MAX_GRID];
    if (pn_isg_mark(&pg, p, n, self_id, self_occlusion, spheres, owners, sphere_count, nodes, tree, mask) < 0)
        return (float3)(0.0f);
    float a_edge[PN_ISG_MAX_GRID + 1], b_edge[PN_ISG_MAX_GRID + 1];
    pn_isg_edges(&pg, b.sharpness, table, a_edge, b_edge);
    const bool prefiltered = mode == PN_ISG_SPECULAR_PREFILTERED;
    float3 sum = (float3)(0.0f);
    for (int i = 0; i < grid; ++i) {
        float3 row = (float3)(0.0f);
        for (int j = 0; j < grid; ++j) {
            if (pn_isg_masked(mask, i, j))
                continue;
            const float3 d = pg.sin_c[i] * (pg.cos_c[j] * pg.x + pg.sin_c[j] * pg.z) + pg.cos_c[i] * pg.y;
            const float c = dot(n, d);
            if (c > 0.0f)
                row += (b_edge[j + 1] - b_edge[j]) * c *
                       (prefiltered ? (float3)(1.0f) : pn_cube_texel_lookup(cube, n_cube, d));
        }
        sum += (a_edge[i + 1] - a_edge[i]) * row;
    }
    if (prefiltered)
        sum *= pn_isg_gamma(gamma, levels, level_count, lambda0, b.axis, b.sharpness);
    return b.amplitude * pn_sg_hemisphere_integral(b.sharpness) * sum;
}

/* The shared hemisphere grid (`shared_grid` M_s > 0; docs/isg.md section 9):
 * the diffuse light of every lobe no sharper than `shared_sharpness`, summed
 * into one radiance L_b (the first vertex-grid cube of `lobe_cube`, built by
 * isg_lobe_cubes when the lobes change), is shadowed by one
 * marking per pixel rather than one per lobe: the receiver's hemisphere is the
 * ISG-frame window of the axis n with w = pi/2 (theta, phi in [0, pi], each cut
 * into M_s), its patches marked as a lobe's are (pn_isg_mark: spheres, tree,
 * LOD cut, thin shells, self-occlusion alike), and the occluded irradiance is
 *   O = sum over marked patches of L_b(d_ij) (n . d_ij) Omega_ij
 * with n . d_ij = sin theta_i sin phi_j and the patch's exact solid angle
 * Omega_ij = step (cos theta_i0 - cos theta_i1) = 2 step sin(step / 2) sin theta_i.
 * Returns O (RGB); the caller subtracts it from the same lobes' unshadowed
 * irradiance E_b(n) (their closed forms pn_sg_irradiance summed, read from the
 * second cube of isg_lobe_cubes: one lookup per pixel instead of a closed form
 * per lobe). */
inline float3 pn_isg_shared_occluded(float3 p, float3 n, uint self_id, int self_occlusion,
                                     global const float4 *spheres, global const uint *owners, int sphere_count,
                                     global const float4 *nodes, const pn_isg_tree *tree, int grid,
                                     global const float4 *lobe_cube, int lobe_cube_n)
{
    pn_sg hemi;
    hemi.axis = n;
    hemi.sharpness = 0.0f; /* window pi/2: the whole front hemisphere */
    hemi.amplitude = (float3)(1.0f);
    pn_isg_grid pg;
    pn_isg_grid_init(hemi, grid, &pg);
    uint mask[PN_ISG_MAX_SHARED];
    /* No LOD cut here: its threshold is in patch steps, and this grid's are a broad lobe's (pi / M_s). */
    pn_isg_tree exact = *tree;
    exact.lod = 0.0f;
    if (pn_isg_mark(&pg, p, n, self_id, self_occlusion, spheres, owners, sphere_count, nodes, &exact, mask) <= 0)
        return (float3)(0.0f); /* nothing marked (inside an occluder: ruled out by the caller) */
    float3 occluded = (float3)(0.0f);
    for (int i = 0; i < grid; ++i) {
        uint f = mask[i];
        if (f == 0u)
            continue;
        const float si = pg.sin_c[i], ci = pg.cos_c[i];
        const float3 rx = si * pg.x, ry = ci * pg.y, rz = si * pg.z;
        float3 row = (float3)(0.0f);
        for (; f != 0u; f &= f - 1u) {
            const int j = pn_isg_ctz(f);
            row += pg.sin_c[j] * pn_cube_grid_lookup(lobe_cube, lobe_cube_n, pg.cos_c[j] * rx + ry + pg.sin_c[j] * rz);
        }
        occluded += (si * si) * row;
    }
    return (2.0f * pg.step * sin(0.5f * pg.step)) * occluded;
}

/* The shared hemisphere grid's two vertex-grid cubes (n vertices a side, face f
 * at a_i = -1 + 2 i / (n - 1) as pn_cube_grid_lookup reads them), over the
 * lobes no sharper than `sharpness`: out[0, 6 n^2) their summed radiance
 * L_b(d) = sum amplitude e^{lambda (d.axis - 1)}, out[6 n^2, 12 n^2) their
 * summed unshadowed irradiance E_b(n) = sum pn_sg_irradiance (docs/isg.md
 * section 9). Built by the host (capi/src/methods/isg.c lobe_cubes) when the
 * lobes or the sharpness change. */
kernel void isg_lobe_cubes(global const float4 *lobes, int lobe_count, float sharpness, int n, global float4 *out)
{
    const int gid = get_global_id(0), count = 6 * n * n;
    if (gid >= count)
        return;
    const int f = gid / (n * n), j = (gid / n) % n, i = gid % n;
    const float step = 2.0f / (float)(n - 1);
    const float3 d = normalize(pn_cube_to_dir(f, -1.0f + (float)i * step, -1.0f + (float)j * step));
    float3 l = (float3)(0.0f), e = (float3)(0.0f);
    for (int k = 0; k < lobe_count; ++k) {
        const pn_sg g = pn_sg_load(lobes, k);
        if (!(g.sharpness <= sharpness))
            continue;
        l += g.amplitude * pn_sg_eval(d, g.axis, g.sharpness);
        e += pn_sg_irradiance(g, d);
    }
    out[gid] = (float4)(l, 0.0f);
    out[count + gid] = (float4)(e, 0.0f);
}

kernel void shade_isg(global const float4 *position, global const float4 *normal, global const float4 *albedo,
                      global const float4 *material, global const uint *instance_id, int count,
                      global const float4 *cube, int n_cube, global const float4 *lobes,
                      int lobe_count, global const float4 *spheres, global const uint *owners, int sphere_count,
                      global const float4 *nodes, int use_tree, float lod, global const float4 *triangles,
                      global const uint *triangle_owners, int triangle_count,
                      int grid, int self_occlusion, int specular_shadows, float env_sharpness, float4 camera,
                      global const float *table, int specular_mode, global const float4 *gamma,
                      global const int *gamma_levels, int gamma_count, float gamma_lambda0, int shared_grid,
                      float shared_sharpness, global const float4 *lobe_cube, int lobe_cube_n,
                      global const float4 *irradiance, int irradiance_n, global const float *skins, int inside_other,
                      global float4 *image)
{
    const int gid = get_global_id(0);
    if (gid >= count)
        return;
    const uint id = instance_id[gid];
    if (id == PN_BACKGROUND) { /* drawn by the renderer's background pass */
        image[gid] = (float4)(0.0f);
        return;
    }
    pn_isg_tree tree;
    pn_isg_tree_init(sphere_count, use_tree, &tree);
    tree.lod = tree.levels > 0 ? fmax(lod, 0.0f) : 0.0f;
    tree.tris = triangles, tree.tri_owners = triangle_owners, tree.tri_count = max(triangle_count, 0);
    tree.skins = skins, tree.inside_other = inside_other;
    /* The specular path without shadows sees no occluder. */
    pn_isg_tree spec_tree = tree;
    spec_tree.tri_count = specular_shadows ? tree.tri_count : 0;
    const float3 p = position[gid].xyz;
    const float3 n = normalize(normal[gid].xyz);
    const pn_material m = pn_material_from_gbuffer(albedo[gid], material[gid]);
    pn_sg cosine;
    cosine.axis = n;
    cosine.sharpness = PN_ISG_COS_SHARPNESS;
    cosine.amplitude = (float3)(PN_ISG_COS_AMPLITUDE);
    /* The BRDF as SGs: one, or 7 for the anisotropic lobe (pn_brdf_sgs). */
    pn_sg brdf[PN_BRDF_MAX_SGS];
    int brdf_count = 0;
    brdf[0].sharpness = 0.0f;
    if (m.ks > 0.0f)
        brdf_count = pn_brdf_sgs(m, n, normalize(camera.xyz - p), brdf);
    /* A sharp BRDF lobe integrates the env cube on its own patches; a broad one
     * (whose patches would alias the cube) the SG lobe products, as do the 7. */
    const bool env_specular = brdf_count == 1 && brdf[0].sharpness >= env_sharpness;
    /* Inside an occluder every shadowed lobe's V is 0 (pn_isg_mark would find it per lobe). */
    const bool inside = pn_isg_inside(p, n, id, self_occlusion, spheres, owners, sphere_count, nodes, &tree);
    float3 diffuse = (float3)(0.0f), specular = (float3)(0.0f);
    /* The shared lobes' unshadowed irradiance (shared_light): irradiance_n > 0, the env's own irradiance map
     * minus the closed forms of the lobes with their own windows (subtracted in the loop below), so the K-lobe
     * fit's error leaves the unshadowed term; else the second cube of isg_lobe_cubes (their closed forms). */
    float3 shared = shared_grid <= 0 ? (float3)(0.0f)
                    : irradiance_n > 0 ? pn_cube_grid_lookup(irradiance, irradiance_n, n)
                                       : pn_cube_grid_lookup(lobe_cube + 6 * lobe_cube_n * lobe_cube_n, lobe_cube_n, n);
    if (env_specular && !(inside && specular_shadows))
        specular = pn_isg_env_specular(brdf[0], p, n, id, specular_shadows ? self_occlusion : 0, spheres, owners,
                                       specular_shadows ? sphere_count : 0, nodes, &spec_tree, grid, table, cube,
                                       n_cube,
                                       specular_mode, gamma, gamma_levels, gamma_count, gamma_lambda0);
    for (int k = 0; k < lobe_count; ++k) {
        const pn_sg g = pn_sg_load(lobes, k);
        const bool own_window = shared_grid <= 0 || g.sharpness > shared_sharpness; /* else in `shared` */
        const float3 e = own_window ? pn_sg_irradiance(g, n) : (float3)(0.0f);
        if (shared_grid > 0 && irradiance_n > 0)
            shared -= e;
        if (e.x > 0.0f || e.y > 0.0f || e.z > 0.0f)
            diffuse += e * (inside ? 0.0f
                                   : pn_isg_visibility(pn_sg_product(g, cosine), p, n, id, self_occlusion, spheres,
                                                       owners, sphere_count, nodes, &tree, grid, table));
        for (int j = 0; j < (env_specular ? 0 : brdf_count); ++j) {
            const pn_sg gb = pn_sg_product(g, brdf[j]);
            const float3 s = pn_sg_reflected(g, brdf[j], n);
            if (s.x > 0.0f || s.y > 0.0f || s.z > 0.0f)
                specular += s * (!specular_shadows ? 1.0f
                                 : inside          ? 0.0f
                                                   : pn_isg_visibility(gb, p, n, id, self_occlusion, spheres, owners,
                                                                       sphere_count, nodes, &tree, grid, table));
        }
    }
    if ((shared.x > 0.0f || shared.y > 0.0f || shared.z > 0.0f) && !inside)
        diffuse += fmax(shared - pn_isg_shared_occluded(p, n, id, self_occlusion, spheres, owners, sphere_count, nodes,
                                                        &tree, shared_grid, lobe_cube, lobe_cube_n),
                        0.0f);
    const float3 c = m.albedo * PN_INV_PI * diffuse + m.ks * specular;
    image[gid] = (float4)(fmax(c, 0.0f), 1.0f);
}
