/* The `reference` method: the brute-force ground truth (docs/reference.md,
 * kernels/reference.cl). The env map's directions on a cube of face_size,
 * with bright texels supersampled, are built at plan time (a read-back of the
 * env map) and kept while the env map and the parameters that shape them
 * stay the same. face_size and sun_supersampling 0 (the defaults) are chosen
 * from the env map at plan time (pick_directions). */
#include "methods/method.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

enum { P_BACKGROUND, P_FACE_SIZE, P_SUN_SUPERSAMPLING, P_SUN_THRESHOLD, P_LIGHT_SAMPLES, P_VISIBILITY, P_RAY_OFFSET };

static const pn_param_desc params[] = {
    PN_PARAM_BACKGROUND,
    {"face_size", PN_PARAM_INT, PN_PARAM_PLAN, 0, 0, 256, "texels",
     "Directions per cube-face side (32: 6144 directions); 0: chosen from the env map (32 or 64)."},
    {"sun_supersampling", PN_PARAM_INT, PN_PARAM_PLAN, 0, 0, 16, "",
     "Texels brighter than sun_threshold are split into s x s sub-texels; 0: chosen from the env map (1 or 4)."},
    {"sun_threshold", PN_PARAM_FLOAT, PN_PARAM_PLAN, 0.01, 1e-6, 1, "",
     "A texel is bright when its power reaches this share of the brightest texel's."},
    {"light_samples", PN_PARAM_INT, PN_PARAM_FRAME, 16, 1, 64, "", "Stratified samples per light cap side (16: 256 rays)."},
    {"visibility", PN_PARAM_INT, PN_PARAM_FRAME, 1, 0, 1, "", "1: shadow rays, 0: every direction unoccluded."},
    {"ray_offset", PN_PARAM_FLOAT, PN_PARAM_FRAME, 1e-5, 0, 0.1, "",
     "Shadow-ray origin lift, relative to scene size plus distance to the camera."},
};

static const pn_output_desc outputs[] = {
    {"directions", "3 floats: the face size and sun supersampling in use (the picks when 0) and the direction count."},
};

typedef struct state {
    cl_mem records;          /* direction records built from the env map */
    uint32_t record_count;
    uint64_t env_version;
    double key[3];           /* face size, sun supersampling, sun threshold (as set; 0 = auto) */
    int face, sun;           /* what the records were built with */
} state;

/* The automatic direction grid (docs/reference.md, "Choosing the directions";
 * measured against converged Mitsuba on every map of ../shared/data by
 * bench/reference_auto.py). On the cube of face 32, the env map is
 * concentrated when its brightest texel carries at least 100 times the mean
 * texel power (at least 1.6 % of the total on 1/6144 of the sphere: a sun, a
 * lamp, a softbox): then the shadow edges of that light need the finer face
 * 64, and its bright texels (power >= sun_threshold of the brightest) are
 * split 4 x 4 when they are few (at most 5 % of the texels at face 64, so the
 * direction count grows by at most 75 %). A broad sky or an interior without
 * dominant lights keeps face 32, unsplit. */
#define AUTO_CONCENTRATION 100.0
#define AUTO_BRIGHT_SHARE 0.05
static pn_status pick_directions(pn_envmap env, int set_face, int set_sun, float threshold, int *face, int *sun)
{
    *face = set_face;
    *sun = set_sun;
    if (set_face && set_sun)
        return PN_SUCCESS;
    pn_context ctx = env->obj.ctx;
    float *rad = pn_malloc(ctx, 6u * 64 * 64 * 16, "the env cube for the reference's picks");
    float *dirs = pn_malloc(ctx, 6u * 64 * 64 * 16, "the cube directions for the reference's picks");
    pn_status st = rad && dirs ? pn_envmap_sample_cube(env, 32, rad, dirs) : PN_ERROR_OUT_OF_MEMORY;
    double total = 0.0, brightest = 0.0;
    for (size_t k = 0; !st && k < 6u * 32 * 32; ++k) {
        const float *l = rad + 4 * k;
        const double p = (0.2126 * l[0] + 0.7152 * l[1] + 0.0722 * l[2]) * dirs[4 * k + 3];
        total += p;
        brightest = fmax(brightest, p);
    }
    const bool concentrated = !st && total > 0.0 && brightest >= AUTO_CONCENTRATION * total / (6.0 * 32 * 32);
    if (!set_face)
        *face = concentrated ? 64 : 32;
    size_t bright = 0, texels = 6u * (size_t)*face * *face;
    if (!st && !set_sun && concentrated) {
        st = pn_envmap_sample_cube(env, 64, rad, dirs); /* the bright count at face 64 */
        double max64 = 0.0;
        for (size_t k = 0; !st && k < 6u * 64 * 64; ++k) {
            const float *l = rad + 4 * k;
            max64 = fmax(max64, (0.2126 * l[0] + 0.7152 * l[1] + 0.0722 * l[2]) * dirs[4 * k + 3]);
        }
        for (size_t k = 0; !st && k < 6u * 64 * 64; ++k) {
            const float *l = rad + 4 * k;
            bright += (0.2126 * l[0] + 0.7152 * l[1] + 0.0722 * l[2]) * dirs[4 * k + 3] >= threshold * max64;
        }
        texels = 6u * 64 * 64;
    }
    if (!set_sun)
        *sun = concentrated && (double)bright <= AUTO_BRIGHT_SHARE * (double)texels ? 4 : 1;
    if (*face * *sun > 2048) /* a large set face with the automatic supersampling */
        *sun = 2048 / *face;
    free(rad);
    free(dirs);
    return st;
}

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
    int face = 0, sun = 0;
    pn_status st = pick_directions(env, (int)key[0], (int)key[1], (float)key[2], &face, &sun);
    if (!st)
        st = pn_envmap_direction_records(env, face, sun, (float)key[2], &records, &count);
    if (!st) {
        pn_mem_release(&s->records);
        st = pn_alloc(r->obj.ctx, (count ? count : 1) * 32, CL_MEM_READ_ONLY, records, &s->records,
                      "the reference direction records");
    }
    if (!st) {
        s->record_count = (uint32_t)count;
        s->env_version = env->version;
        s->face = face;
        s->sun = sun;
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

static pn_status read_output(pn_renderer r, pn_scene scene, int output, uint32_t instance, uint32_t index,
                             void *host, size_t bytes)
{
    (void)scene, (void)output, (void)instance, (void)index; /* one output, for the whole scene */
    const state *s = r->state;
    if (bytes != 3 * sizeof(float))
        return pn_fail(r->obj.ctx, PN_ERROR_INVALID_SIZE, "reference output 'directions' is 3 floats (12 bytes), got %zu",
                       bytes);
    const float v[3] = {(float)s->face, (float)s->sun, (float)s->record_count};
    memcpy(host, v, sizeof v);
    return PN_SUCCESS;
}

const pn_method_desc pn_method_reference = {
    .name = "reference",
    .summary = "brute-force ground truth: cube-map directions x ray-cast visibility x BRDF, plus spherical lights",
    .stage = "reference",
    .doc_page = "docs/reference.md",
    .params = params,
    .param_count = (int)(sizeof params / sizeof params[0]),
    .outputs = outputs,
    .output_count = (int)(sizeof outputs / sizeof outputs[0]),
    .inputs = PN_INPUT_ENVMAP | PN_INPUT_GEOMETRY | PN_INPUT_LIGHTS | PN_INPUT_CAMERA,
    .state_size = sizeof(state),
    .destroy = destroy,
    .plan = plan,
    .execute = execute,
    .read_output = read_output,
};
