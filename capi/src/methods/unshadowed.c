/* The `unshadowed` method: albedo / pi x E(n) from the env map's irradiance
 * map, no visibility (kernels/unshadowed.cl). Also the base of heightfield. */
#include "methods/method.h"

static const pn_param_desc params[] = {
    PN_PARAM_BACKGROUND,
};

pn_status pn_unshadowed_enqueue(pn_renderer r, pn_scene scene, pn_gbuffer gb, pn_image image, int background)
{
    pn_context ctx = r->obj.ctx;
    pn_envmap env = scene->env;
    cl_kernel k;
    pn_status st = pn_context_kernel(ctx, "unshadowed", "shade_unshadowed", &k);
    if (st)
        return st;
    const cl_int count = (cl_int)(gb->width * gb->height);
    const cl_int m = env->irradiance_face_size;
    /* The kernel draws the background itself for a method that says so
     * (draws_background: unshadowed); for the others (heightfield, whose
     * base this is) the renderer's pass draws it after their last kernel. */
    const cl_int draw = background && r->method->draws_background;
    const cl_int lat_w = (cl_int)env->width, lat_h = (cl_int)env->height;
    const cl_float2 rot = pn_envmap_rotation(env);
    size_t sizes[] = {sizeof(cl_mem), sizeof(cl_mem), sizeof(cl_mem), sizeof(cl_mem), sizeof count, sizeof(cl_mem),
                      sizeof m, sizeof(cl_mem), sizeof draw, sizeof(cl_mem), sizeof lat_w, sizeof lat_h, sizeof rot,
                      sizeof env->intensity};
    const void *vals[] = {&gb->planes[PN_GBUFFER_POSITION], &gb->planes[PN_GBUFFER_NORMAL],
                          &gb->planes[PN_GBUFFER_ALBEDO], &gb->planes[PN_GBUFFER_INSTANCE], &count, &env->irradiance,
                          &m, &image->buffer, &draw, &env->latlong, &lat_w, &lat_h, &rot, &env->intensity};
    if ((st = pn_set_args(ctx, k, "shade_unshadowed", 14, sizes, vals)))
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
    .draws_background = true,
    .execute = execute,
};
