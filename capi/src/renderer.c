/* Renderers: a shading method chosen by name, its parameters, and execution
 * on a G-buffer. Each method is one entry of `methods`; later techniques add
 * theirs beside `unshadowed`. */
#include "internal.h"

#include <stdlib.h>
#include <string.h>

struct pn_method {
    const char *name;
    pn_status (*execute)(pn_renderer r, pn_scene scene, pn_gbuffer gb, pn_image image);
};

static pn_status execute_unshadowed(pn_renderer r, pn_scene scene, pn_gbuffer gb, pn_image image)
{
    pn_context ctx = r->obj.ctx;
    pn_envmap env = scene->env;
    cl_kernel k;
    pn_status st = pn_context_kernel(ctx, "unshadowed", "shade_unshadowed", &k);
    if (st)
        return st;
    const cl_int count = (cl_int)(gb->width * gb->height);
    const cl_int m = env->irradiance_face_size, n = env->face_size, bg = r->background;
    size_t sizes[] = {sizeof(cl_mem), sizeof(cl_mem), sizeof(cl_mem), sizeof(cl_mem), sizeof count, sizeof(cl_mem),
                      sizeof m, sizeof(cl_mem), sizeof n, sizeof bg, sizeof(cl_mem)};
    const void *vals[] = {&gb->planes[PN_GBUFFER_POSITION], &gb->planes[PN_GBUFFER_NORMAL],
                          &gb->planes[PN_GBUFFER_ALBEDO], &gb->planes[PN_GBUFFER_INSTANCE], &count, &env->irradiance,
                          &m, &env->cube, &n, &bg, &image->buffer};
    if ((st = pn_set_args(ctx, k, "shade_unshadowed", 11, sizes, vals)))
        return st;
    return pn_enqueue_1d(ctx, k, "shade_unshadowed", (size_t)count, 64);
}

static const pn_method methods[] = {
    {"unshadowed", execute_unshadowed},
};
#define METHOD_COUNT (sizeof methods / sizeof methods[0])

pn_status pn_renderer_new(pn_context ctx, const char *method, pn_renderer *out)
{
    const pn_method *found = NULL;
    for (size_t i = 0; i < METHOD_COUNT; ++i)
        if (!strcmp(methods[i].name, method))
            found = &methods[i];
    if (!found)
        return pn_fail(ctx, PN_ERROR_INVALID_ARGUMENT, "unknown method '%s' (available: unshadowed)", method);
    pn_renderer r = calloc(1, sizeof *r);
    if (!r)
        return pn_fail(ctx, PN_ERROR_OUT_OF_MEMORY, "out of memory creating a renderer");
    r->obj.magic = PN_MAGIC_RENDERER;
    r->obj.refcount = 1;
    r->obj.ctx = ctx;
    r->method = found;
    r->background = 1;
    *out = r;
    return PN_SUCCESS;
}

void pn_renderer_destroy(pn_renderer r)
{
    r->obj.magic = PN_MAGIC_DEAD;
    free(r);
}

pn_status pn_renderer_param_int(pn_renderer r, const char *name, int32_t *value, bool set)
{
    if (strcmp(name, "background"))
        return pn_fail(r->obj.ctx, PN_ERROR_BAD_CONFIG, "method %s has no integer parameter '%s' (background)",
                       r->method->name, name);
    if (!set) {
        *value = r->background;
        return PN_SUCCESS;
    }
    if (*value != 0 && *value != 1)
        return pn_fail(r->obj.ctx, PN_ERROR_INVALID_ARGUMENT, "background = %d must be 0 or 1", *value);
    r->background = *value;
    r->committed = false;
    return PN_SUCCESS;
}

pn_status pn_renderer_param_float(pn_renderer r, const char *name, float *value, bool set)
{
    (void)value;
    (void)set;
    return pn_fail(r->obj.ctx, PN_ERROR_BAD_CONFIG, "method %s has no float parameter '%s'", r->method->name, name);
}

pn_status pn_renderer_do_execute(pn_renderer r, pn_scene scene, pn_gbuffer gb, pn_image image)
{
    pn_context ctx = r->obj.ctx;
    if (!r->committed)
        return pn_fail(ctx, PN_ERROR_NOT_COMMITTED, "renderer changed since its last commit; call pn_renderer_commit");
    if (scene->obj.ctx != ctx || gb->obj.ctx != ctx || image->obj.ctx != ctx)
        return pn_fail(ctx, PN_ERROR_INVALID_ARGUMENT, "renderer, scene, G-buffer and image must share one context");
    if (gb->width != image->width || gb->height != image->height)
        return pn_fail(ctx, PN_ERROR_INVALID_SIZE, "G-buffer is %ux%u but the image is %ux%u", gb->width, gb->height,
                       image->width, image->height);
    pn_status st = pn_scene_ready(scene, true);
    if (st)
        return st;
    return r->method->execute(r, scene, gb, image);
}
