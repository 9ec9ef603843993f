/* Height fields (docs/heightfield.md): the pn_heightfield asset — heights,
 * placement, albedo map — its triangle mesh (the one the G-buffer ray caster,
 * the reference renderer and the Mitsuba export see), and where it attaches:
 * to the instance of that mesh. The heightfield method's per-frame work is in
 * methods/heightfield.c. */
#include "assets/assets.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

/* ------------------------------------------------------------- the object */

static void destroy_heightfield(pn_object *o)
{
    pn_heightfield hf = (pn_heightfield)o;
    free(hf->heights);
    free(hf->albedo);
}

/* The number of NaN or Inf heights among n, and the index of the first. */
static size_t count_nonfinite(const float *heights, size_t n, size_t *first)
{
    size_t bad = 0;
    *first = 0;
    for (size_t k = 0; k < n; ++k)
        if (!isfinite(heights[k]) && bad++ == 0)
            *first = k;
    return bad;
}

pn_status pn_heightfield_do_set_heights(pn_heightfield hf, const float *heights, uint32_t width, uint32_t depth)
{
    pn_context ctx = hf->obj.ctx;
    if (width < 2 || depth < 2)
        return pn_fail(ctx, PN_ERROR_INVALID_SIZE, "a height field needs at least 2 x 2 heights (got %u x %u)", width,
                       depth);
    if ((uint64_t)width * depth > (uint64_t)INT32_MAX / 4)
        return pn_fail(ctx, PN_ERROR_INVALID_SIZE, "a height field of %u x %u heights is too large (at most 2^29 heights)", width, depth);
    const size_t n = (size_t)width * depth;
    /* heights, and the pyramid and triangle mesh made from them: a few times more */
    pn_status cap = pn_check_bytes(ctx, pn_mul_size(n, sizeof(float), 4), "a height field's heights");
    if (cap)
        return cap;
    size_t first;
    const size_t bad = count_nonfinite(heights, n, &first);
    if (bad)
        return pn_fail(ctx, PN_ERROR_INVALID_ARGUMENT,
                       "height field has %zu non-finite heights (NaN or Inf), the first at row %zu, column %zu", bad,
                       first / width, first % width);
    float *copy = pn_malloc(ctx, n * sizeof(float), "height-field heights");
    if (!copy)
        return PN_ERROR_OUT_OF_MEMORY;
    memcpy(copy, heights, n * sizeof(float));
    if (hf->albedo && (width != hf->width || depth != hf->depth)) {
        free(hf->albedo); /* an albedo map of the old size no longer fits */
        hf->albedo = NULL;
    }
    free(hf->heights);
    hf->heights = copy;
    hf->width = width;
    hf->depth = depth;
    hf->committed = false;
    hf->edit_full = true;
    return PN_SUCCESS;
}

static void box_union(uint32_t *box, uint32_t x0, uint32_t y0, uint32_t x1, uint32_t y1)
{
    if (box[0] > box[2]) {
        box[0] = x0, box[1] = y0, box[2] = x1, box[3] = y1;
        return;
    }
    box[0] = x0 < box[0] ? x0 : box[0];
    box[1] = y0 < box[1] ? y0 : box[1];
    box[2] = x1 > box[2] ? x1 : box[2];
    box[3] = y1 > box[3] ? y1 : box[3];
}

pn_status pn_heightfield_do_set_heights_region(pn_heightfield hf, uint32_t x0, uint32_t y0, uint32_t width,
                                               uint32_t depth, const float *heights)
{
    pn_context ctx = hf->obj.ctx;
    if (!hf->heights)
        return pn_fail(ctx, PN_ERROR_NOT_COMMITTED,
                       "pn_heightfield_set_heights_region: the height field has no heights yet (pn_heightfield_set_heights)");
    if (!width || !depth)
        return pn_fail(ctx, PN_ERROR_INVALID_SIZE, "pn_heightfield_set_heights_region: an empty region (%u x %u heights)",
                       width, depth);
    if (x0 >= hf->width || y0 >= hf->depth || width > hf->width - x0 || depth > hf->depth - y0)
        return pn_fail(ctx, PN_ERROR_INVALID_ARGUMENT,
                       "pn_heightfield_set_heights_region: columns %u..%llu, rows %u..%llu are outside the %u x %u "
                       "height field", x0, (unsigned long long)x0 + width - 1, y0,
                       (unsigned long long)y0 + depth - 1, hf->width, hf->depth);
    const size_t n = (size_t)width * depth;
    size_t first;
    const size_t bad = count_nonfinite(heights, n, &first);
    if (bad)
        return pn_fail(ctx, PN_ERROR_INVALID_ARGUMENT,
                       "height-field region has %zu non-finite heights (NaN or Inf), the first at row %zu, column %zu "
                       "of the field", bad, y0 + first / width, x0 + first % width);
    for (uint32_t j = 0; j < depth; ++j)
        memcpy(hf->heights + (size_t)(y0 + j) * hf->width + x0, heights + (size_t)j * width, width * sizeof(float));
    box_union(hf->edit_box, x0, y0, x0 + width - 1, y0 + depth - 1);
    hf->regional = true;
    hf->committed = false;
    return PN_SUCCESS;
}

bool pn_heightfield_changed_since(pn_heightfield hf, uint64_t from, uint32_t box[4])
{
    if (!hf->committed || !from)
        return false;
    uint32_t u[4] = {1, 1, 0, 0}; /* empty */
    if (from == hf->version) {
        memcpy(box, u, sizeof u);
        return true;
    }
    for (uint32_t k = 0; k < hf->history_count; ++k) {
        const uint32_t *b = hf->history_box[k];
        if (b[0] <= b[2])
            box_union(u, b[0], b[1], b[2], b[3]);
        if (hf->history_from[k] == from) {
            memcpy(box, u, sizeof u);
            return true;
        }
    }
    return false;
}

pn_status pn_heightfield_do_set_placement(pn_heightfield hf, const pn_heightfield_placement *p)
{
    pn_context ctx = hf->obj.ctx;
    for (int i = 0; i < 3; ++i)
        if (!isfinite(p->origin[i]))
            return pn_fail(ctx, PN_ERROR_INVALID_ARGUMENT, "height-field origin[%d] = %g is not finite", i,
                           (double)p->origin[i]);
    for (int i = 0; i < 2; ++i)
        if (!(p->size[i] > 0.0f && isfinite(p->size[i])))
            return pn_fail(ctx, PN_ERROR_INVALID_ARGUMENT, "height-field size[%d] = %g must be finite and > 0", i,
                           (double)p->size[i]);
    if (!isfinite(p->height_scale))
        return pn_fail(ctx, PN_ERROR_INVALID_ARGUMENT, "height-field height_scale = %g is not finite",
                       (double)p->height_scale);
    hf->placement = *p;
    hf->committed = false;
    hf->edit_full = true;
    return PN_SUCCESS;
}

pn_status pn_heightfield_do_set_albedo(pn_heightfield hf, const float *rgb, size_t count)
{
    pn_context ctx = hf->obj.ctx;
    if (!rgb || !count) {
        free(hf->albedo);
        hf->albedo = NULL;
        hf->committed = false;
        hf->edit_full = true;
        return PN_SUCCESS;
    }
    const size_t n = (size_t)hf->width * hf->depth * 3;
    if (!hf->heights)
        return pn_fail(ctx, PN_ERROR_NOT_COMMITTED, "set the heights before the albedo map (it is sized by them)");
    if (count != n)
        return pn_fail(ctx, PN_ERROR_INVALID_SIZE, "albedo map has %zu floats; a %u x %u height field needs %zu (RGB)",
                       count, hf->width, hf->depth, n);
    for (size_t k = 0; k < n; ++k)
        if (!(rgb[k] >= 0.0f && rgb[k] <= 1.0f))
            return pn_fail(ctx, PN_ERROR_INVALID_ARGUMENT,
                           "albedo map value %g at row %zu, column %zu is outside [0, 1]", (double)rgb[k],
                           k / 3 / hf->width, k / 3 % hf->width);
    float *copy = pn_malloc(ctx, n * sizeof(float), "a height-field albedo map");
    if (!copy)
        return PN_ERROR_OUT_OF_MEMORY;
    memcpy(copy, rgb, n * sizeof(float));
    free(hf->albedo);
    hf->albedo = copy;
    hf->committed = false;
    hf->edit_full = true;
    return PN_SUCCESS;
}

pn_status pn_heightfield_do_commit(pn_heightfield hf)
{
    if (!hf->heights)
        return pn_fail(hf->obj.ctx, PN_ERROR_NOT_COMMITTED, "height field has no heights (pn_heightfield_set_heights)");
    hf->hmin = INFINITY;
    hf->hmax = -INFINITY;
    for (size_t k = 0; k < (size_t)hf->width * hf->depth; ++k) {
        hf->hmin = fminf(hf->hmin, hf->heights[k]);
        hf->hmax = fmaxf(hf->hmax, hf->heights[k]);
    }
    /* What changed since the last commit: region edits only (or nothing) are
     * recorded, so that a renderer a few commits behind knows where the
     * heights differ from those it has. */
    const uint64_t old = hf->version;
    if (hf->edit_full || !old) {
        hf->history_count = 0;
    } else {
        const uint32_t n = hf->history_count < PN_HF_HISTORY ? hf->history_count + 1 : PN_HF_HISTORY;
        memmove(hf->history_from + 1, hf->history_from, (n - 1) * sizeof hf->history_from[0]);
        memmove(hf->history_box + 1, hf->history_box, (n - 1) * sizeof hf->history_box[0]);
        hf->history_from[0] = old;
        memcpy(hf->history_box[0], hf->edit_box, sizeof hf->history_box[0]);
        hf->history_count = n;
    }
    hf->edit_full = false;
    hf->edit_box[0] = hf->edit_box[1] = 1; /* empty */
    hf->edit_box[2] = hf->edit_box[3] = 0;
    hf->version = pn_next_version();
    hf->committed = true;
    return PN_SUCCESS;
}

/* World heights H = height_scale h and the grid spacing. */
void pn_heightfield_spacing(pn_heightfield hf, float *sx, float *sz)
{
    *sx = hf->placement.size[0] / (float)(hf->width - 1);
    *sz = hf->placement.size[1] / (float)(hf->depth - 1);
}

pn_status pn_heightfield_do_build_mesh(pn_heightfield hf, pn_mesh *out)
{
    pn_context ctx = hf->obj.ctx;
    pn_mesh mesh = NULL;
    if (!hf->committed)
        return pn_fail(ctx, PN_ERROR_NOT_COMMITTED, "height field changed since its last commit; call pn_heightfield_commit");
    const uint32_t w = hf->width, d = hf->depth;
    const uint64_t tris = 2ull * (w - 1) * (d - 1);
    if (tris > UINT32_MAX / 3)
        return pn_fail(ctx, PN_ERROR_INVALID_SIZE, "a %u x %u height field has too many triangles for a mesh", w, d);
    float sx, sz;
    pn_heightfield_spacing(hf, &sx, &sz);
    const float *o = hf->placement.origin, hs = hf->placement.height_scale;
    float *pos = pn_malloc(ctx, pn_mul_size((size_t)w * d, 3, sizeof(float)), "height-field mesh vertices");
    float *nrm = pn_malloc(ctx, pn_mul_size((size_t)w * d, 3, sizeof(float)), "height-field mesh normals");
    uint32_t *idx = pn_malloc(ctx, pn_mul_size((size_t)tris, 3, sizeof(uint32_t)), "height-field mesh triangles");
    pn_status st = pos && nrm && idx ? pn_mesh_new(ctx, &mesh) : PN_ERROR_OUT_OF_MEMORY;
    for (uint32_t j = 0; !st && j < d; ++j)
        for (uint32_t i = 0; i < w; ++i) {
            const size_t k = (size_t)j * w + i;
            const uint32_t i0 = i ? i - 1 : 0, i1 = i + 1 < w ? i + 1 : i, j0 = j ? j - 1 : 0, j1 = j + 1 < d ? j + 1 : j;
            const float dx = hs * (hf->heights[(size_t)j * w + i1] - hf->heights[(size_t)j * w + i0]) / ((float)(i1 - i0) * sx);
            const float dz = hs * (hf->heights[(size_t)j1 * w + i] - hf->heights[(size_t)j0 * w + i]) / ((float)(j1 - j0) * sz);
            const float len = sqrtf(dx * dx + 1.0f + dz * dz);
            pos[3 * k] = o[0] + (float)i * sx;
            pos[3 * k + 1] = o[1] + hs * hf->heights[k];
            pos[3 * k + 2] = o[2] + (float)j * sz;
            nrm[3 * k] = -dx / len;
            nrm[3 * k + 1] = 1.0f / len;
            nrm[3 * k + 2] = -dz / len;
        }
    size_t t = 0;
    for (uint32_t j = 0; !st && j + 1 < d; ++j)
        for (uint32_t i = 0; i + 1 < w; ++i) {
            /* Counter-clockwise seen from +y: (a, c, b) and (b, c, e). */
            const uint32_t a = j * w + i, b = a + 1, c = a + w, e = c + 1;
            const uint32_t tri[6] = {a, c, b, b, c, e};
            memcpy(idx + t, tri, sizeof tri);
            t += 6;
        }
    if (!st)
        st = pn_mesh_do_set_geometry(mesh, pos, w * d, idx, (uint32_t)tris, nrm);
    if (!st)
        st = pn_mesh_do_commit(mesh);
    free(pos);
    free(nrm);
    free(idx);
    if (st)
        PN_RELEASE(mesh);
    else
        *out = mesh;
    return st;
}

/* A height field attaches to an instance whose mesh has its grid of vertices
 * (normally the mesh of pn_heightfield_build_mesh). */
static pn_status check_attach(const pn_object *asset, pn_scene scene, uint32_t instance)
{
    const pn_heightfield hf = (const pn_heightfield)(uintptr_t)asset;
    pn_context ctx = scene->obj.ctx;
    if (instance == PN_WHOLE_SCENE)
        return pn_fail(ctx, PN_ERROR_INVALID_ARGUMENT,
                       "pn_scene_attach: a height field attaches to the instance of its mesh, not to the whole scene");
    if (!hf->heights)
        return pn_fail(ctx, PN_ERROR_NOT_COMMITTED, "pn_scene_attach: the height field has no heights");
    const pn_mesh mesh = pn_scene_instance(scene, instance)->mesh;
    const uint64_t tris = 2ull * (hf->width - 1) * (hf->depth - 1);
    if ((uint64_t)mesh->vertex_count != (uint64_t)hf->width * hf->depth || mesh->triangle_count != tris)
        return pn_fail(ctx, PN_ERROR_INVALID_ARGUMENT,
                       "pn_scene_attach: instance %u's mesh has %u vertices and %u triangles, not the %u x %u grid of "
                       "the height field (%llu triangles): attach a height field to the instance of its "
                       "pn_heightfield_build_mesh mesh", instance, mesh->vertex_count, mesh->triangle_count,
                       hf->width, hf->depth, (unsigned long long)tris);
    return PN_SUCCESS;
}

static const pn_object_type heightfield_type = {PN_MAGIC_HEIGHTFIELD, "height field", destroy_heightfield,
                                                check_attach};

pn_status pn_heightfield_new(pn_context ctx, pn_heightfield *out)
{
    pn_heightfield hf = pn_object_new(ctx, sizeof *hf, &heightfield_type, "a height field");
    if (!hf)
        return PN_ERROR_OUT_OF_MEMORY;
    hf->placement.height_scale = 1.0f;
    hf->edit_box[0] = hf->edit_box[1] = 1; /* empty */
    *out = hf;
    return PN_SUCCESS;
}
