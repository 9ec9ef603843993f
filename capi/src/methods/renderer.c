/* Renderers: a method chosen by name from the table of descriptors, its
 * parameters, and the dispatch of plan, execute and output reads to the
 * method's own file. Nothing here knows a technique. */
#include "methods/method.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static const pn_method_desc *const methods[] = {
    &pn_method_unshadowed, &pn_method_reference, &pn_method_floor, &pn_method_fiv, &pn_method_heightfield,
    &pn_method_depthmap,
    &pn_method_isg,
};
#define METHOD_COUNT (sizeof methods / sizeof methods[0])

uint32_t pn_method_table_size(void)
{
    return (uint32_t)METHOD_COUNT;
}

const pn_method_desc *pn_method_at(uint32_t index)
{
    return index < METHOD_COUNT ? methods[index] : NULL;
}

const pn_method_desc *pn_method_find(const char *name)
{
    char names[256] = "";
    for (size_t i = 0; i < METHOD_COUNT; ++i) {
        if (!strcmp(methods[i]->name, name))
            return methods[i];
        size_t used = strlen(names);
        snprintf(names + used, sizeof names - used, "%s%s", i ? ", " : "", methods[i]->name);
    }
    pn_fail(NULL, PN_ERROR_INVALID_ARGUMENT, "unknown method '%s' (available: %s)", name, names);
    return NULL;
}

static void destroy_renderer(pn_object *o)
{
    pn_renderer r = (pn_renderer)o;
    if (r->method->destroy)
        r->method->destroy(r);
    free(r->state);
}

static const pn_object_type renderer_type = {PN_MAGIC_RENDERER, "renderer", destroy_renderer, NULL};

pn_status pn_renderer_new(pn_context ctx, const char *method, pn_renderer *out)
{
    const pn_method_desc *found = pn_method_find(method);
    if (!found) { /* the message is in the global slot; the caller's context gets it too */
        const char *why = NULL;
        pn_error_take(NULL, &why);
        char msg[512];
        snprintf(msg, sizeof msg, "%s", why ? why : "unknown method");
        return pn_fail(ctx, PN_ERROR_INVALID_ARGUMENT, "%s", msg);
    }
    pn_renderer r = pn_object_new(ctx, sizeof *r, &renderer_type, "a renderer");
    if (!r)
        return PN_ERROR_OUT_OF_MEMORY;
    r->method = found;
    for (int i = 0; i < found->param_count; ++i)
        r->params[i] = found->params[i].fallback;
    pn_status st = PN_SUCCESS;
    if (found->state_size && !(r->state = pn_malloc(ctx, found->state_size, "a renderer's state")))
        st = PN_ERROR_OUT_OF_MEMORY;
    if (r->state)
        memset(r->state, 0, found->state_size);
    if (!st && found->create)
        st = found->create(r);
    if (st) {
        pn_object_release(&r->obj);
        return st;
    }
    *out = r;
    return PN_SUCCESS;
}

/* The parameter's slot, or -1 with an error listing the method's parameters. */
static int find_param(pn_renderer r, const char *name, bool integer)
{
    const pn_method_desc *m = r->method;
    const int slot = pn_param_find(m->params, m->param_count, name);
    if (slot >= 0)
        return slot;
    if (m->bake_params && pn_param_find(m->bake_params, m->bake_param_count, name) >= 0) {
        pn_fail(r->obj.ctx, PN_ERROR_BAD_CONFIG,
                "%s '%s' is a bake option of the method's asset, not a renderer parameter: give it to the bake",
                m->name, name);
        return -1;
    }
    char list[512] = "";
    for (int i = 0; i < m->param_count; ++i) {
        size_t used = strlen(list);
        snprintf(list + used, sizeof list - used, "%s%s", i ? ", " : "", m->params[i].name);
    }
    pn_fail(r->obj.ctx, PN_ERROR_BAD_CONFIG, "method %s has no %s parameter '%s' (parameters: %s)", m->name,
            integer ? "integer" : "float", name, m->param_count ? list : "none");
    return -1;
}

static pn_status set_param(pn_renderer r, int slot, double value)
{
    pn_status st = pn_param_check(r->obj.ctx, r->method->name, &r->method->params[slot], value);
    if (st)
        return st;
    r->params[slot] = value;
    r->committed = false;
    return PN_SUCCESS;
}

pn_status pn_renderer_param_int(pn_renderer r, const char *name, int32_t *value, bool set)
{
    int slot = find_param(r, name, true);
    if (slot < 0)
        return PN_ERROR_BAD_CONFIG;
    if (set) /* an int is accepted for a float parameter */
        return set_param(r, slot, (double)*value);
    if (r->method->params[slot].type != PN_PARAM_INT)
        return pn_fail(r->obj.ctx, PN_ERROR_BAD_CONFIG, "%s %s is a float parameter: use pn_renderer_get_float",
                       r->method->name, name);
    *value = (int32_t)r->params[slot];
    return PN_SUCCESS;
}

pn_status pn_renderer_param_float(pn_renderer r, const char *name, float *value, bool set)
{
    int slot = find_param(r, name, false);
    if (slot < 0)
        return PN_ERROR_BAD_CONFIG;
    if (r->method->params[slot].type == PN_PARAM_INT)
        return pn_fail(r->obj.ctx, PN_ERROR_BAD_CONFIG, "%s %s is an integer parameter: use pn_renderer_%s_int",
                       r->method->name, name, set ? "set" : "get");
    if (set)
        return set_param(r, slot, (double)*value);
    *value = (float)r->params[slot];
    return PN_SUCCESS;
}

pn_status pn_renderer_do_commit(pn_renderer r)
{
    r->committed = true;
    return PN_SUCCESS;
}

/* What every execute and output read checks before the method runs. */
static pn_status ready(pn_renderer r, pn_scene scene)
{
    pn_context ctx = r->obj.ctx;
    if (!r->committed)
        return pn_fail(ctx, PN_ERROR_NOT_COMMITTED, "renderer changed since its last commit; call pn_renderer_commit");
    if (scene->obj.ctx != ctx)
        return pn_fail(ctx, PN_ERROR_INVALID_ARGUMENT, "renderer and scene must share one context");
    pn_status st = pn_scene_ready(scene, true);
    if (st)
        return st;
    if ((r->method->inputs & PN_INPUT_CAMERA) && !scene->has_camera)
        return pn_fail(ctx, PN_ERROR_NOT_COMMITTED, "the %s method needs the scene's camera (the viewer position)",
                       r->method->name);
    return r->method->plan ? r->method->plan(r, scene) : PN_SUCCESS;
}

pn_status pn_renderer_do_execute(pn_renderer r, pn_scene scene, pn_gbuffer gb, pn_image image)
{
    pn_context ctx = r->obj.ctx;
    if (gb->obj.ctx != ctx || image->obj.ctx != ctx)
        return pn_fail(ctx, PN_ERROR_INVALID_ARGUMENT, "renderer, scene, G-buffer and image must share one context");
    if (gb->width != image->width || gb->height != image->height)
        return pn_fail(ctx, PN_ERROR_INVALID_SIZE, "G-buffer is %ux%u but the image is %ux%u", gb->width, gb->height,
                       image->width, image->height);
    pn_status st = ready(r, scene);
    if (!st)
        st = r->method->execute(r, scene, gb, image);
    /* The background is drawn here, once for every method that has the
     * `background` parameter and does not draw it in its own kernel, from the
     * full-resolution env map. */
    const int bg = pn_param_find(r->method->params, r->method->param_count, "background");
    if (!st && bg >= 0 && r->params[bg] != 0.0 && !r->method->draws_background)
        st = pn_envmap_enqueue_background(scene->env, gb->planes[PN_GBUFFER_POSITION],
                                          gb->planes[PN_GBUFFER_INSTANCE], gb->width * gb->height, image->buffer);
    return st;
}

pn_status pn_renderer_do_read_output(pn_renderer r, pn_scene scene, const char *output, uint32_t instance,
                                     uint32_t index, void *host, size_t bytes)
{
    const pn_method_desc *m = r->method;
    int which = -1;
    char list[256] = "";
    for (int i = 0; i < m->output_count; ++i) {
        if (!strcmp(m->outputs[i].name, output))
            which = i;
        size_t used = strlen(list);
        snprintf(list + used, sizeof list - used, "%s%s", i ? ", " : "", m->outputs[i].name);
    }
    if (which < 0)
        return pn_fail(r->obj.ctx, PN_ERROR_INVALID_ARGUMENT, "method %s has no output '%s' (outputs: %s)", m->name,
                       output, m->output_count ? list : "none");
    pn_status st = ready(r, scene);
    return st ? st : m->read_output(r, scene, which, instance, index, host, bytes);
}

pn_status pn_renderer_do_set_env_domains(pn_renderer r, const pn_env_domain *domains, uint32_t count)
{
    if (!r->method->set_domains)
        return pn_fail(r->obj.ctx, PN_ERROR_UNSUPPORTED, "method %s takes no env domains (depthmap does)",
                       r->method->name);
    if (count && !domains)
        return pn_fail(r->obj.ctx, PN_ERROR_INVALID_ARGUMENT, "%u env domains but the pointer is NULL", count);
    return r->method->set_domains(r, domains, count);
}
