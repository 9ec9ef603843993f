/* The `reference` method: the brute-force ground truth (docs/reference.md,
 * kernels/reference.cl). The env map's directions on a cube of face_size,
 * with bright texels supersampled, are built at plan time (a read-back of the
 * env map) and kept while the env map and the parameters that shape them
 * stay the same. */
#include "methods/method.h"

#include <stdlib.h>

enum { P_BACKGROUND, P_FACE_SIZE, P_SUN_SUPERSAMPLING, P_SUN_THRESHOLD, P_LIGHT_SAMPLES, P_VISIBILITY, P_RAY_OFFSET };

static const pn_param_desc params[] = {
    PN_PARAM_BACKGROUND,
    {"face_size", PN_PARAM_INT, PN_PARAM_PLAN, 32, 1, 256, "texels",
     "Directions per cube-face side (32: 6144 directions)."},
    {"sun_supersampling", PN_PARAM_INT, PN_PARAM_PLAN, 1, 1, 16, "",
     "Texels brighter than sun_threshold are split into s x s sub-texels."},
    {"sun_threshold", PN_PARAM_FLOAT, PN_PARAM_PLAN, 0.01, 1e-6, 1, "",
     "A texel is bright when its power reaches this share of the brightest texel's."},
    {"light_samples", PN_PARAM_INT, PN_PARAM_FRAME, 16, 1, 64, "", "Stratified samples per light cap side (16: 256 rays)."},
    {"visibility", PN_PARAM_INT, PN_PARAM_FRAME, 1, 0, 1, "", "1: shadow rays, 0: every direction unoccluded."},
    {"ray_offset", PN_PARAM_FLOAT, PN_PARAM_FRAME, 1e-5, 0, 0.1, "",
     "Shadow-ray origin lift, relative to scene size plus distance to the camera."},
};

typedef struct state {
    cl_mem records;          /* direction records built from the env map */
    uint32_t record_count;
    uint64_t env_version;
    double key[3];           /* face size, sun supersampling, sun threshold */
} state;

static void destroy(pn_renderer r)
{
    state *s = r->state;
    pn_mem_release(&s->records);
}

static pn_status plan(pn_renderer r, pn_scene scene)
{
    state *s = r->state;
    pn_envmap env = scene->env;
    const double key[3] = {r->params[P_FACE_SIZE], r->params[P_SUN_SUPERSAMPLING], r->params[P_SUN_THRESHOLD]};
    if (s->records && s->env_version == env->version && s->key[0] == key[0] && s->key[1] == key[1] &&
        s->key[2] == key[2])
        return PN_SUCCESS;
    float *records = NULL;
    size_t count = 0;
    pn_status st = pn_envmap_direction_records(env, (int)key[0], (int)key[1], (float)key[2], &records, &count);
    if (!st) {
        pn_mem_release(&s->records);
        st = pn_alloc(r->obj.ctx, (count ? count : 1) * 32, CL_MEM_READ_ONLY, records, &s->records,
                      "the reference direction records");
    }
    if (!st) {
        s->record_count = (uint32_t)count;
        s->env_version = env->version;
        for (int i = 0; i < 3; ++i)
            s->key[i] = key[i];
    }
    free(records);
    return st;
}

static pn_status execute(pn_renderer r, pn_scene scene, pn_gbuffer gb, pn_image image)
{
    pn_context ctx = r->obj.ctx;
    state *s = r->state;
    cl_kernel k;
    pn_status st;
    if ((st = pn_context_kernel(ctx, "reference", "shade_reference", &k)) ||
        (st = pn_scene_set_kernel_args(scene, k, "shade_reference", 0)))
        return st;
    const cl_int count = (cl_int)(gb->width * gb->height), records = (cl_int)s->record_count;
    const cl_int lights = (cl_int)scene->committed_light_count, side = (cl_int)r->params[P_LIGHT_SAMPLES];
    const cl_float4 camera = pn_scene_camera_position(scene);
    const cl_float offset = (cl_float)r->params[P_RAY_OFFSET], scale = pn_scene_scale(scene);
    const cl_int visibility = (cl_int)r->params[P_VISIBILITY];
    size_t sizes[] = {sizeof(cl_mem), sizeof(cl_mem), sizeof(cl_mem), sizeof(cl_mem), sizeof(cl_mem), sizeof count,
                      sizeof(cl_mem), sizeof records, sizeof(cl_mem), sizeof lights, sizeof side, sizeof camera,
                      sizeof offset, sizeof scale, sizeof visibility, sizeof(cl_mem)};
    const void *vals[] = {&gb->planes[PN_GBUFFER_POSITION], &gb->planes[PN_GBUFFER_NORMAL],
                          &gb->planes[PN_GBUFFER_ALBEDO], &gb->planes[PN_GBUFFER_MATERIAL],
                          &gb->planes[PN_GBUFFER_INSTANCE], &count, &s->records, &records,
                          &scene->light_buffer, &lights, &side, &camera, &offset, &scale, &visibility,
                          &image->buffer};
    /* The six scene arguments come first (pn_scene_set_kernel_args). */
    for (cl_uint i = 0; i < sizeof sizes / sizeof sizes[0]; ++i) {
        cl_int err = clSetKernelArg(k, 6 + i, sizes[i], vals[i]);
        if (err != CL_SUCCESS)
            return pn_fail_cl(ctx, err, "setting shade_reference arguments");
    }
    return pn_enqueue_1d(ctx, k, "shade_reference", (size_t)count, 64);
}

const pn_method_desc pn_method_reference = {
    .name = "reference",
    .summary = "brute-force ground truth: cube-map directions x ray-cast visibility x BRDF, plus spherical lights",
    .stage = "reference",
    .doc_page = "docs/reference.md",
    .params = params,
    .param_count = (int)(sizeof params / sizeof params[0]),
    .inputs = PN_INPUT_ENVMAP | PN_INPUT_GEOMETRY | PN_INPUT_LIGHTS | PN_INPUT_CAMERA,
    .state_size = sizeof(state),
    .destroy = destroy,
    .plan = plan,
    .execute = execute,
};
