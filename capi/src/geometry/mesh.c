/* Meshes: validated copies of the caller's triangles and, at commit, the
 * binned-SAH BVH with the triangles laid out in leaf order for the kernels. */
#include "geometry/geometry.h"

#include <float.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static void free_geometry(pn_mesh mesh)
{
    free(mesh->positions);
    free(mesh->normals);
    free(mesh->indices);
    free(mesh->leaf_tris);
    free(mesh->leaf_normals);
    pn_bvh_free(&mesh->bvh);
    pn_bvh4_free(&mesh->wide);
    pn_bvh8_free(&mesh->wide8);
    mesh->positions = mesh->normals = mesh->leaf_tris = mesh->leaf_normals = NULL;
    mesh->indices = NULL;
}

static void destroy_mesh(pn_object *o)
{
    pn_mesh mesh = (pn_mesh)o;
    free_geometry(mesh);
}

static const pn_object_type mesh_type = {PN_MAGIC_MESH, "mesh", destroy_mesh, NULL};

pn_status pn_mesh_new(pn_context ctx, pn_mesh *out)
{
    pn_mesh mesh = pn_object_new(ctx, sizeof *mesh, &mesh_type, "a mesh");
    if (!mesh)
        return PN_ERROR_OUT_OF_MEMORY;
    *out = mesh;
    return PN_SUCCESS;
}

pn_status pn_mesh_do_read_geometry(pn_mesh mesh, float *positions, uint32_t *indices, float *normals)
{
    if (!mesh->committed)
        return pn_fail(mesh->obj.ctx, PN_ERROR_NOT_COMMITTED, "mesh changed since its last commit; call pn_mesh_commit");
    if (normals && !mesh->normals)
        return pn_fail(mesh->obj.ctx, PN_ERROR_UNSUPPORTED, "the mesh has no normals to read (pass normals = NULL)");
    memcpy(positions, mesh->positions, (size_t)mesh->vertex_count * 3 * sizeof(float));
    memcpy(indices, mesh->indices, (size_t)mesh->triangle_count * 3 * sizeof(uint32_t));
    if (normals)
        memcpy(normals, mesh->normals, (size_t)mesh->vertex_count * 3 * sizeof(float));
    return PN_SUCCESS;
}

pn_status pn_mesh_do_set_geometry(pn_mesh mesh, const float *positions, uint32_t vertex_count,
                                  const uint32_t *indices, uint32_t triangle_count, const float *normals)
{
    pn_context ctx = mesh->obj.ctx;
    if (vertex_count == 0 || triangle_count == 0)
        return pn_fail(ctx, PN_ERROR_EMPTY_INPUT, "mesh has %u vertices and %u triangles; it needs at least one of each",
                       vertex_count, triangle_count);
    /* Sizes first: nothing is read from the caller's arrays before they are known to fit the cap. */
    char what[96];
    snprintf(what, sizeof what, "a mesh of %u vertices", vertex_count);
    pn_status st = pn_check_bytes(ctx, pn_mul_size(vertex_count, normals ? 6 : 3, sizeof(float)), what);
    if (!st) {
        snprintf(what, sizeof what, "a mesh of %u triangles", triangle_count);
        /* indices, and at commit the leaf-ordered triangles (3 float4) and BVH */
        st = pn_check_bytes(ctx, pn_mul_size(triangle_count, 3 * sizeof(uint32_t) + 3 * 16 + 64, 1), what);
    }
    if (st)
        return st;
    for (uint32_t v = 0; v < vertex_count; ++v)
        for (int c = 0; c < 3; ++c)
            if (!isfinite(positions[3 * (size_t)v + c]))
                return pn_fail(ctx, PN_ERROR_INVALID_VALUE, "mesh vertex %u has a non-finite coordinate (%g)", v,
                               (double)positions[3 * (size_t)v + c]);
    /* Finite coordinates can still span more than a float holds: the bounds'
     * extent, the bounding sphere and every distance computed from them would
     * be Inf (a bake of it would write a file its reader refuses). */
    double lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
    for (uint32_t v = 0; v < vertex_count; ++v)
        for (int c = 0; c < 3; ++c) {
            const double x = positions[3 * (size_t)v + c];
            lo[c] = x < lo[c] ? x : lo[c];
            hi[c] = x > hi[c] ? x : hi[c];
        }
    double diagonal2 = 0.0;
    for (int c = 0; c < 3; ++c)
        diagonal2 += (hi[c] - lo[c]) * (hi[c] - lo[c]);
    if (sqrt(diagonal2) > (double)FLT_MAX)
        return pn_fail(ctx, PN_ERROR_INVALID_VALUE,
                       "mesh bounds [%g, %g] x [%g, %g] x [%g, %g]: their extent (diagonal %g) overflows float; scale "
                       "the mesh down",
                       lo[0], hi[0], lo[1], hi[1], lo[2], hi[2], sqrt(diagonal2));
    if (normals)
        for (uint32_t v = 0; v < vertex_count; ++v)
            for (int c = 0; c < 3; ++c)
                if (!isfinite(normals[3 * (size_t)v + c]))
                    return pn_fail(ctx, PN_ERROR_INVALID_VALUE, "mesh normal %u has a non-finite component (%g)", v,
                                   (double)normals[3 * (size_t)v + c]);
    for (uint32_t t = 0; t < triangle_count; ++t)
        for (int c = 0; c < 3; ++c)
            if (indices[3 * (size_t)t + c] >= vertex_count)
                return pn_fail(ctx, PN_ERROR_OUT_OF_RANGE, "mesh triangle %u refers to vertex %u but the mesh has %u vertices",
                               t, indices[3 * (size_t)t + c], vertex_count);
    size_t vbytes = pn_mul_size(vertex_count, 3, sizeof(float));
    size_t ibytes = pn_mul_size(triangle_count, 3, sizeof(uint32_t));
    float *p = pn_malloc(ctx, vbytes, "mesh vertices");
    float *n = normals ? pn_malloc(ctx, vbytes, "mesh normals") : NULL;
    uint32_t *idx = pn_malloc(ctx, ibytes, "mesh indices");
    if (!p || !idx || (normals && !n)) {
        free(p);
        free(n);
        free(idx);
        return PN_ERROR_OUT_OF_MEMORY;
    }
    memcpy(p, positions, vbytes);
    if (n)
        memcpy(n, normals, vbytes);
    memcpy(idx, indices, ibytes);
    free_geometry(mesh);
    mesh->positions = p;
    mesh->normals = n;
    mesh->indices = idx;
    mesh->vertex_count = vertex_count;
    mesh->triangle_count = triangle_count;
    mesh->committed = false;
    return PN_SUCCESS;
}

/* True when the triangle has zero area: its edge vectors' cross product is 0
 * in double (exact for collinear float inputs: equal products round alike). */
static bool zero_area(const float *a, const float *b, const float *c)
{
    const double e1[3] = {(double)b[0] - a[0], (double)b[1] - a[1], (double)b[2] - a[2]};
    const double e2[3] = {(double)c[0] - a[0], (double)c[1] - a[1], (double)c[2] - a[2]};
    return e1[1] * e2[2] == e1[2] * e2[1] && e1[2] * e2[0] == e1[0] * e2[2] && e1[0] * e2[1] == e1[1] * e2[0];
}

pn_status pn_mesh_do_commit(pn_mesh mesh)
{
    pn_context ctx = mesh->obj.ctx;
    if (!mesh->positions)
        return pn_fail(ctx, PN_ERROR_NOT_COMMITTED, "mesh has no geometry: call pn_mesh_set_geometry before committing");
    const uint32_t nt = mesh->triangle_count;
    pn_aabb *boxes = pn_malloc(ctx, pn_mul_size(nt, 1, sizeof *boxes), "triangle bounds");
    float *tris = pn_malloc(ctx, pn_mul_size(nt, 12, sizeof(float)), "leaf-ordered triangles");
    float *nrms = mesh->normals ? pn_malloc(ctx, pn_mul_size(nt, 12, sizeof(float)), "leaf-ordered normals") : NULL;
    if (!boxes || !tris || (mesh->normals && !nrms)) {
        free(boxes);
        free(tris);
        free(nrms);
        return PN_ERROR_OUT_OF_MEMORY;
    }
    for (int c = 0; c < 3; ++c) {
        mesh->bounds_lo[c] = INFINITY;
        mesh->bounds_hi[c] = -INFINITY;
    }
    for (uint32_t t = 0; t < nt; ++t) {
        for (int c = 0; c < 3; ++c) {
            boxes[t].lo[c] = INFINITY;
            boxes[t].hi[c] = -INFINITY;
        }
        for (int k = 0; k < 3; ++k) {
            const float *v = mesh->positions + 3 * (size_t)mesh->indices[3 * (size_t)t + k];
            for (int c = 0; c < 3; ++c) {
                boxes[t].lo[c] = fminf(boxes[t].lo[c], v[c]);
                boxes[t].hi[c] = fmaxf(boxes[t].hi[c], v[c]);
            }
        }
        for (int c = 0; c < 3; ++c) {
            mesh->bounds_lo[c] = fminf(mesh->bounds_lo[c], boxes[t].lo[c]);
            mesh->bounds_hi[c] = fmaxf(mesh->bounds_hi[c], boxes[t].hi[c]);
        }
    }
    pn_bvh bvh = {0};
    if (pn_bvh_build(boxes, nt, 4, &bvh) != 0) {
        free(boxes);
        free(tris);
        free(nrms);
        return pn_fail(ctx, PN_ERROR_OUT_OF_MEMORY, "out of memory building the BVH of a %u-triangle mesh", nt);
    }
    free(boxes);
    /* The kernels walk the context's wide form (8-wide by default, 4-wide
     * under PENUMBRA_BVH_WIDTH=4); the binary one stays for host users
     * (fiv_bake's winding tree) and the binary layout (PENUMBRA_BVH_WIDTH=2). */
    pn_bvh4 wide = {0};
    pn_bvh8 wide8 = {0};
    if ((ctx->bvh_width == 4 && pn_bvh4_collapse(&bvh, &wide) != 0) ||
        (ctx->bvh_width == 8 && pn_bvh8_collapse(&bvh, &wide8) != 0)) {
        pn_bvh4_free(&wide);
        pn_bvh_free(&bvh);
        free(tris);
        free(nrms);
        return pn_fail(ctx, PN_ERROR_OUT_OF_MEMORY, "out of memory building the BVH of a %u-triangle mesh", nt);
    }
    for (uint32_t slot = 0; slot < nt; ++slot) {
        const uint32_t t = bvh.order[slot];
        const uint32_t *idx = mesh->indices + 3 * (size_t)t;
        /* A zero-area triangle is stored as three copies of its first vertex:
         * the kernel's edge functions are then exactly 0 and it is never hit.
         * (Kept as stored, the ray-relative rounding of collinear vertices can
         * give three tiny edge functions of one sign and a spurious hit.) */
        const bool degenerate = zero_area(mesh->positions + 3 * (size_t)idx[0], mesh->positions + 3 * (size_t)idx[1],
                                          mesh->positions + 3 * (size_t)idx[2]);
        for (int k = 0; k < 3; ++k) {
            const uint32_t v = mesh->indices[3 * (size_t)t + k];
            float *dst = tris + 12 * (size_t)slot + 4 * k;
            memcpy(dst, mesh->positions + 3 * (size_t)idx[degenerate ? 0 : k], 3 * sizeof(float));
            /* v0.w carries the mesh's own triangle index (as uint bits). */
            uint32_t bits = k == 0 ? t : 0;
            memcpy(dst + 3, &bits, sizeof bits);
            if (nrms) {
                float *nd = nrms + 12 * (size_t)slot + 4 * k;
                memcpy(nd, mesh->normals + 3 * (size_t)v, 3 * sizeof(float));
                nd[3] = 0.0f;
            }
        }
    }
    pn_bvh_free(&mesh->bvh);
    pn_bvh4_free(&mesh->wide);
    pn_bvh8_free(&mesh->wide8);
    free(mesh->leaf_tris);
    free(mesh->leaf_normals);
    mesh->bvh = bvh;
    mesh->wide = wide;
    mesh->wide8 = wide8;
    mesh->leaf_tris = tris;
    mesh->leaf_normals = nrms;
    mesh->content_hash = pn_hash_bytes(pn_hash_bytes(PN_HASH_SEED, mesh->positions, 12u * (size_t)mesh->vertex_count),
                                       mesh->indices, 12u * (size_t)mesh->triangle_count);
    mesh->committed = true;
    mesh->version = pn_next_version();
    return PN_SUCCESS;
}
