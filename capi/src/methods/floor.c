/* The `floor` method: reads the G-buffer and writes the image, the
 * memory-bound yardstick every benchmark time is a multiple of
 * (docs/benchmarks.md, kernels/floor.cl). */
#include "methods/method.h"

static pn_status execute(pn_renderer r, pn_scene scene, pn_gbuffer gb, pn_image image)
{
    pn_context ctx = r->obj.ctx;
    cl_kernel k;
    pn_status st = pn_context_kernel(ctx, "floor", "shade_floor", &k);
    if (st)
        return st;
    const cl_int count = (cl_int)(gb->width * gb->height);
    const cl_float4 camera = pn_scene_camera_position(scene);
    size_t sizes[] = {sizeof(cl_mem), sizeof(cl_mem), sizeof(cl_mem), sizeof(cl_mem), sizeof count, sizeof camera,
                      sizeof(cl_mem)};
    const void *vals[] = {&gb->planes[PN_GBUFFER_POSITION], &gb->planes[PN_GBUFFER_NORMAL],
                          &gb->planes[PN_GBUFFER_ALBEDO], &gb->planes[PN_GBUFFER_INSTANCE], &count, &camera,
                          &image->buffer};
    if ((st = pn_set_args(ctx, k, "shade_floor", 7, sizes, vals)))
        return st;
    return pn_enqueue_1d(ctx, k, "shade_floor", (size_t)count, 64);
}

const pn_method_desc pn_method_floor = {
    .name = "floor",
    .summary = "the memory-bound floor: reads the G-buffer, writes the image (a timing yardstick)",
    .stage = "floor",
    .doc_page = "docs/benchmarks.md",
    .inputs = 0,
    .execute = execute,
};
