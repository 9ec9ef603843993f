/* The `unshadowed` method: albedo / pi x E(n) from the env map's irradiance
 * map, no visibility (kernels/unshadowed.cl). Also the base of heightfield. */
#include "methods/method.h"

static const pn_param_desc params[] = {
    PN_PARAM_BACKGROUND,
};

pn_status pn_unshadowed_enqueue(pn_renderer r, pn_scene scene, pn_gbuffer gb, pn_image image, int background)
{
    (void)background; /* the renderer draws the background after execute (methods/renderer.c) */
    pn_context ctx = r->obj.ctx;
    pn_envmap env = scene->env;
    cl_kernel k;
    pn_status st = pn_context_kernel(ctx, "unshadowed", "shade_unshadowed", &k);
    if (st)
        return st;
    const cl_int count = (cl_int)(gb->width * gb->height);
    const cl_int m = env->irradiance_face_size;
    size_t sizes[] = {sizeof(cl_mem), sizeof(cl_mem), sizeof(cl_mem), sizeof(cl_mem), sizeof count, sizeof(cl_mem),
                      sizeof m, sizeof(cl_mem)};
    const void *vals[] = {&gb->planes[PN_GBUFFER_POSITION], &gb->planes[PN_GBUFFER_NORMAL],
                          &gb->planes[PN_GBUFFER_ALBEDO], &gb->planes[PN_GBUFFER_INSTANCE], &count, &env->irradiance,
                          &m, &image->buffer};
    if ((st = pn_set_args(ctx, k, "shade_unshadowed", 8, sizes, vals)))
        return st;
    /* 8 consecutive pixels per work-item (vector lanes, kernels/unshadowed.cl). */
    return pn_enqueue_1d(ctx, k, "shade_unshadowed", ((size_t)count + 7) / 8, 16);
}

static pn_status execute(pn_renderer r, pn_scene scene, pn_gbuffer gb, pn_image image)
{
    return pn_unshadowed_enqueue(r, scene, gb, image, (int)r->params[0]);
}

const pn_method_desc pn_method_unshadowed = {
    .name = "unshadowed",
    .summary = "diffuse env lighting without visibility, from the irradiance map",
    .stage = "unshadowed",
    .doc_page = "docs/api.md",
    .params = params,
    .param_count = 1,
    .inputs = PN_INPUT_ENVMAP,
    .execute = execute,
};
