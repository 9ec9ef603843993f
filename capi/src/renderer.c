/* Renderers: a shading method chosen by name, its parameters, and execution
 * on a G-buffer. Each method is one entry of `methods` (name, kernel stage,
 * parameter table, execute function); the C API, the Python package and the
 * CLI all list methods from this table. */
#include "internal.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

typedef struct {
    const char *name;
    bool integer;
    float fallback, lo, hi; /* default and inclusive range */
} pn_param;

struct pn_method {
    const char *name;
    const char *stage; /* kernels/<stage>.cl */
    pn_status (*execute)(pn_renderer r, pn_scene scene, pn_gbuffer gb, pn_image image);
    const pn_param *params;
    int param_count;
};

/* Parameter slots, in the order of each method's table. */
enum { P_BACKGROUND = 0 };
enum { P_FACE_SIZE = 1, P_SUN_SUPERSAMPLING, P_SUN_THRESHOLD, P_LIGHT_SAMPLES, P_VISIBILITY, P_RAY_OFFSET };
enum { P_OVERLAP = 1, P_PARTIAL, P_SELF_SHADOW, P_TRILINEAR, P_CULL_THRESHOLD };
enum { P_LEVEL_STEP = 1, P_LEVEL_OFFSET, P_AZIMUTHS, P_BANDS, P_EXACT_HORIZON, P_LIGHT_THRESHOLD, P_EXACT_UNOCCLUDED,
       P_HF_SUN_THRESHOLD, P_LIGHT_VISIBILITY, P_RECONSTRUCTION };

static const pn_param unshadowed_params[] = {
    {"background", true, 1, 0, 1},
};

static const pn_param reference_params[] = {
    {"background", true, 1, 0, 1},
    {"face_size", true, 32, 1, 256},
    {"sun_supersampling", true, 1, 1, 16},
    {"sun_threshold", false, 0.01f, 1e-6f, 1},
    {"light_samples", true, 16, 1, 64},
    {"visibility", true, 1, 0, 1},
    {"ray_offset", false, 1e-5f, 0, 0.1f},
};

static const pn_param fiv_params[] = {
    {"background", true, 1, 0, 1},
    {"overlap", true, 1, 0, 2},          /* 0 sum, 1 unit-bounding-disc correction, 2 multiplied visibility */
    {"partial", true, 0, 0, 1},          /* case B scaled by (d + R) / 2R (the paper's; off: see docs/fiv.md) */
    {"self_shadow", true, 1, 0, 1},
    {"trilinear", true, 1, 0, 1},        /* 0: nearest sample */
    {"cull_threshold", false, 1e-3f, 0, 1},
};

static const pn_param heightfield_params[] = {
    {"background", true, 1, 0, 1},
    {"level_step", true, 4, 1, 8},
    {"level_offset", false, 4, 0, 8},
    {"azimuths", true, 32, 4, 256},
    {"bands", true, 4, 3, 6},
    {"exact_horizon", true, 0, 0, 1},
    {"light_threshold", false, 1e-4f, 0, 1},
    {"exact_unoccluded", true, 1, 0, 1},  /* 0: the seed's all-SH environment product */
    {"sun_threshold", false, 50, 0, 1e9f}, /* x mean radiance: directional sun texels; 0: none */
    {"light_visibility", true, 1, 0, 1},   /* 0: the seed's SH wedges, 1: horizon test + exact cap */
    {"reconstruction", true, 0, 0, 1},     /* 0: the seed's approximating B-spline, 1: interpolating */
};

static cl_float4 camera_position(pn_scene scene)
{
    cl_float4 c = {{scene->camera.position[0], scene->camera.position[1], scene->camera.position[2], 0.0f}};
    return c;
}

static pn_status execute_unshadowed(pn_renderer r, pn_scene scene, pn_gbuffer gb, pn_image image)
{
    pn_context ctx = r->obj.ctx;
    pn_envmap env = scene->env;
    cl_kernel k;
    pn_status st = pn_context_kernel(ctx, "unshadowed", "shade_unshadowed", &k);
    if (st)
        return st;
    const cl_int count = (cl_int)(gb->width * gb->height);
    const cl_int m = env->irradiance_face_size, n = env->face_size, bg = (cl_int)r->params[P_BACKGROUND];
    size_t sizes[] = {sizeof(cl_mem), sizeof(cl_mem), sizeof(cl_mem), sizeof(cl_mem), sizeof count, sizeof(cl_mem),
                      sizeof m, sizeof(cl_mem), sizeof n, sizeof bg, sizeof(cl_mem)};
    const void *vals[] = {&gb->planes[PN_GBUFFER_POSITION], &gb->planes[PN_GBUFFER_NORMAL],
                          &gb->planes[PN_GBUFFER_ALBEDO], &gb->planes[PN_GBUFFER_INSTANCE], &count, &env->irradiance,
                          &m, &env->cube, &n, &bg, &image->buffer};
    if ((st = pn_set_args(ctx, k, "shade_unshadowed", 11, sizes, vals)))
        return st;
    return pn_enqueue_1d(ctx, k, "shade_unshadowed", (size_t)count, 64);
}

static pn_status execute_floor(pn_renderer r, pn_scene scene, pn_gbuffer gb, pn_image image)
{
    pn_context ctx = r->obj.ctx;
    cl_kernel k;
    pn_status st = pn_context_kernel(ctx, "floor", "shade_floor", &k);
    if (st)
        return st;
    const cl_int count = (cl_int)(gb->width * gb->height);
    const cl_float4 camera = camera_position(scene);
    size_t sizes[] = {sizeof(cl_mem), sizeof(cl_mem), sizeof(cl_mem), sizeof(cl_mem), sizeof count, sizeof camera,
                      sizeof(cl_mem)};
    const void *vals[] = {&gb->planes[PN_GBUFFER_POSITION], &gb->planes[PN_GBUFFER_NORMAL],
                          &gb->planes[PN_GBUFFER_ALBEDO], &gb->planes[PN_GBUFFER_INSTANCE], &count, &camera,
                          &image->buffer};
    if ((st = pn_set_args(ctx, k, "shade_floor", 7, sizes, vals)))
        return st;
    return pn_enqueue_1d(ctx, k, "shade_floor", (size_t)count, 64);
}

/* The `reference` direction records (pn_envmap_direction_records), rebuilt
 * only when the env map or the parameters that shape them change. */
static pn_status build_direction_records(pn_renderer r, pn_envmap env)
{
    pn_context ctx = r->obj.ctx;
    const int f = (int)r->params[P_FACE_SIZE], s = (int)r->params[P_SUN_SUPERSAMPLING];
    const float threshold = r->params[P_SUN_THRESHOLD];
    if (r->dir_records && r->dir_env_version == env->version && r->dir_key[0] == (float)f &&
        r->dir_key[1] == (float)s && r->dir_key[2] == threshold)
        return PN_SUCCESS;
    float *records = NULL;
    size_t count = 0;
    pn_status st = pn_envmap_direction_records(env, f, s, threshold, &records, &count);
    if (!st) {
        pn_mem_release(&r->dir_records);
        st = pn_alloc(ctx, (count ? count : 1) * 32, CL_MEM_READ_ONLY, records, &r->dir_records,
                      "the reference direction records");
    }
    if (!st) {
        r->dir_record_count = (uint32_t)count;
        r->dir_env_version = env->version;
        r->dir_key[0] = (float)f;
        r->dir_key[1] = (float)s;
        r->dir_key[2] = threshold;
    }
    free(records);
    return st;
}

static pn_status execute_reference(pn_renderer r, pn_scene scene, pn_gbuffer gb, pn_image image)
{
    pn_context ctx = r->obj.ctx;
    pn_envmap env = scene->env;
    cl_kernel k;
    pn_status st;
    if (!scene->has_camera)
        return pn_fail(ctx, PN_ERROR_NOT_COMMITTED,
                       "the reference method needs the scene's camera (the viewer position for the BRDF)");
    if ((st = pn_context_kernel(ctx, "reference", "shade_reference", &k)) ||
        (st = build_direction_records(r, env)) ||
        (st = pn_scene_set_kernel_args(scene, k, "shade_reference", 0)))
        return st;
    const cl_int count = (cl_int)(gb->width * gb->height), records = (cl_int)r->dir_record_count;
    const cl_int lights = (cl_int)scene->committed_light_count, side = (cl_int)r->params[P_LIGHT_SAMPLES];
    const cl_float4 camera = camera_position(scene);
    const cl_float offset = r->params[P_RAY_OFFSET], scale = pn_scene_scale(scene);
    const cl_int visibility = (cl_int)r->params[P_VISIBILITY], n = env->face_size;
    const cl_int bg = (cl_int)r->params[P_BACKGROUND];
    size_t sizes[] = {sizeof(cl_mem), sizeof(cl_mem), sizeof(cl_mem), sizeof(cl_mem), sizeof(cl_mem), sizeof count,
                      sizeof(cl_mem), sizeof records, sizeof(cl_mem), sizeof lights, sizeof side, sizeof camera,
                      sizeof offset, sizeof scale, sizeof visibility, sizeof(cl_mem), sizeof n, sizeof bg,
                      sizeof(cl_mem)};
    const void *vals[] = {&gb->planes[PN_GBUFFER_POSITION], &gb->planes[PN_GBUFFER_NORMAL],
                          &gb->planes[PN_GBUFFER_ALBEDO], &gb->planes[PN_GBUFFER_MATERIAL],
                          &gb->planes[PN_GBUFFER_INSTANCE], &count, &r->dir_records, &records,
                          &scene->light_buffer, &lights, &side, &camera, &offset, &scale, &visibility, &env->cube, &n,
                          &bg, &image->buffer};
    /* The six scene arguments come first (pn_scene_set_kernel_args). */
    for (cl_uint i = 0; i < sizeof sizes / sizeof sizes[0]; ++i) {
        cl_int err = clSetKernelArg(k, 6 + i, sizes[i], vals[i]);
        if (err != CL_SUCCESS)
            return pn_fail_cl(ctx, err, "setting shade_reference arguments");
    }
    return pn_enqueue_1d(ctx, k, "shade_reference", (size_t)count, 64);
}

static pn_status execute_fiv(pn_renderer r, pn_scene scene, pn_gbuffer gb, pn_image image)
{
    pn_context ctx = r->obj.ctx;
    pn_envmap env = scene->env;
    cl_kernel k;
    pn_fiv_frame frame;
    pn_status st;
    if ((st = pn_context_kernel(ctx, "fiv", "shade_fiv", &k)) ||
        (st = pn_fiv_prepare(&r->fiv, scene, r->params[P_CULL_THRESHOLD], &frame)))
        return st;
    const cl_int count = (cl_int)(gb->width * gb->height), m = env->irradiance_face_size, n = env->face_size;
    const cl_int bg = (cl_int)r->params[P_BACKGROUND], occluders = (cl_int)frame.occluder_count;
    const cl_int overlap = (cl_int)r->params[P_OVERLAP], partial = (cl_int)r->params[P_PARTIAL];
    const cl_int self_shadow = (cl_int)r->params[P_SELF_SHADOW], trilinear = (cl_int)r->params[P_TRILINEAR];
    cl_float4 env_fiv[3];
    for (int a = 0; a < 3; ++a)
        for (int c = 0; c < 4; ++c)
            env_fiv[a].s[c] = c < 3 ? r->fiv.env_fiv[3 * a + c] : 0.0f;
    size_t sizes[] = {sizeof(cl_mem), sizeof(cl_mem), sizeof(cl_mem), sizeof(cl_mem), sizeof count, sizeof(cl_mem),
                      sizeof m, sizeof(cl_mem), sizeof n, sizeof bg, sizeof(cl_mem), sizeof occluders, sizeof(cl_mem),
                      sizeof env_fiv[0], sizeof env_fiv[1], sizeof env_fiv[2], sizeof overlap, sizeof partial,
                      sizeof self_shadow, sizeof trilinear, sizeof(cl_mem)};
    const void *vals[] = {&gb->planes[PN_GBUFFER_POSITION], &gb->planes[PN_GBUFFER_NORMAL],
                          &gb->planes[PN_GBUFFER_ALBEDO], &gb->planes[PN_GBUFFER_INSTANCE], &count, &env->irradiance,
                          &m, &env->cube, &n, &bg, &frame.occluders, &occluders, &frame.fields, &env_fiv[0],
                          &env_fiv[1], &env_fiv[2], &overlap, &partial, &self_shadow, &trilinear, &image->buffer};
    if ((st = pn_set_args(ctx, k, "shade_fiv", 21, sizes, vals)))
        return st;
    return pn_enqueue_1d(ctx, k, "shade_fiv", (size_t)count, 64);
}

static pn_hf_settings hf_settings(pn_renderer r)
{
    pn_hf_settings s = {(int)r->params[P_LEVEL_STEP], (int)r->params[P_AZIMUTHS], (int)r->params[P_BANDS],
                        (int)r->params[P_EXACT_HORIZON], (int)r->params[P_EXACT_UNOCCLUDED],
                        (int)r->params[P_LIGHT_VISIBILITY], (int)r->params[P_RECONSTRUCTION],
                        r->params[P_LEVEL_OFFSET], r->params[P_LIGHT_THRESHOLD], r->params[P_HF_SUN_THRESHOLD]};
    return s;
}

/* Pixels that are not on a height field (and the background) get `unshadowed`. */
static pn_status execute_heightfield(pn_renderer r, pn_scene scene, pn_gbuffer gb, pn_image image)
{
    const pn_hf_settings set = hf_settings(r);
    pn_status st = execute_unshadowed(r, scene, gb, image);
    return st ? st : pn_hf_execute(&r->hf, scene, &set, gb, image);
}

pn_status pn_renderer_do_read_heightfield(pn_renderer r, pn_scene scene, uint32_t field, pn_heightfield_output what,
                                          uint32_t light, float *host, size_t bytes)
{
    pn_context ctx = r->obj.ctx;
    if (r->method->execute != execute_heightfield)
        return pn_fail(ctx, PN_ERROR_INVALID_ARGUMENT, "pn_renderer_read_heightfield needs a heightfield renderer (this is %s)",
                       r->method->name);
    if (!r->committed)
        return pn_fail(ctx, PN_ERROR_NOT_COMMITTED, "renderer changed since its last commit; call pn_renderer_commit");
    if (scene->obj.ctx != ctx)
        return pn_fail(ctx, PN_ERROR_INVALID_ARGUMENT, "renderer and scene must share one context");
    pn_status st = pn_scene_ready(scene, true);
    if (st)
        return st;
    const pn_hf_settings set = hf_settings(r);
    return pn_hf_read(&r->hf, scene, &set, field, what, light, host, bytes);
}

#define PARAMS(table) table, (int)(sizeof table / sizeof table[0])
static const pn_method methods[] = {
    {"unshadowed", "unshadowed", execute_unshadowed, PARAMS(unshadowed_params)},
    {"reference", "reference", execute_reference, PARAMS(reference_params)},
    {"floor", "floor", execute_floor, NULL, 0},
    {"fiv", "fiv", execute_fiv, PARAMS(fiv_params)},
    {"heightfield", "heightfield", execute_heightfield, PARAMS(heightfield_params)},
};
#define METHOD_COUNT (sizeof methods / sizeof methods[0])

uint32_t pn_renderer_method_count(void)
{
    return (uint32_t)METHOD_COUNT;
}

const char *pn_renderer_method_name(uint32_t index)
{
    return index < METHOD_COUNT ? methods[index].name : NULL;
}

pn_status pn_renderer_new(pn_context ctx, const char *method, pn_renderer *out)
{
    const pn_method *found = NULL;
    char names[256] = "";
    for (size_t i = 0; i < METHOD_COUNT; ++i) {
        if (!strcmp(methods[i].name, method))
            found = &methods[i];
        size_t used = strlen(names);
        snprintf(names + used, sizeof names - used, "%s%s", i ? ", " : "", methods[i].name);
    }
    if (!found)
        return pn_fail(ctx, PN_ERROR_INVALID_ARGUMENT, "unknown method '%s' (available: %s)", method, names);
    pn_renderer r = calloc(1, sizeof *r);
    if (!r)
        return pn_fail(ctx, PN_ERROR_OUT_OF_MEMORY, "out of memory creating a renderer");
    r->obj.magic = PN_MAGIC_RENDERER;
    r->obj.refcount = 1;
    r->obj.ctx = ctx;
    r->method = found;
    r->fiv.env_version = UINT64_MAX;
    r->hf.m_env_version = UINT64_MAX;
    for (int i = 0; i < found->param_count; ++i)
        r->params[i] = found->params[i].fallback;
    *out = r;
    return PN_SUCCESS;
}

void pn_renderer_destroy(pn_renderer r)
{
    pn_mem_release(&r->dir_records);
    pn_fiv_cache_release(&r->fiv);
    pn_hf_cache_release(&r->hf);
    r->obj.magic = PN_MAGIC_DEAD;
    free(r);
}

/* The parameter's slot, or -1 with an error listing the method's parameters. */
static int find_param(pn_renderer r, const char *name, bool integer)
{
    const pn_method *m = r->method;
    char list[256] = "";
    for (int i = 0; i < m->param_count; ++i) {
        if (!strcmp(m->params[i].name, name))
            return i;
        size_t used = strlen(list);
        snprintf(list + used, sizeof list - used, "%s%s", i ? ", " : "", m->params[i].name);
    }
    pn_fail(r->obj.ctx, PN_ERROR_BAD_CONFIG, "method %s has no %s parameter '%s' (parameters: %s)", m->name,
            integer ? "integer" : "float", name, m->param_count ? list : "none");
    return -1;
}

static pn_status set_param(pn_renderer r, int slot, double value)
{
    const pn_param *p = &r->method->params[slot];
    if (!isfinite(value) || value < p->lo || value > p->hi)
        return pn_fail(r->obj.ctx, PN_ERROR_INVALID_ARGUMENT, "%s %s = %g is outside [%g, %g]", r->method->name,
                       p->name, value, (double)p->lo, (double)p->hi);
    if (p->integer && value != floor(value))
        return pn_fail(r->obj.ctx, PN_ERROR_INVALID_ARGUMENT, "%s %s = %g must be an integer", r->method->name,
                       p->name, value);
    r->params[slot] = (float)value;
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
    if (!r->method->params[slot].integer)
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
    if (r->method->params[slot].integer)
        return pn_fail(r->obj.ctx, PN_ERROR_BAD_CONFIG, "%s %s is an integer parameter: use pn_renderer_%s_int",
                       r->method->name, name, set ? "set" : "get");
    if (set)
        return set_param(r, slot, (double)*value);
    *value = r->params[slot];
    return PN_SUCCESS;
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
