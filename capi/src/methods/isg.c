/* The `isg` method (docs/isg.md, kernels/isg.cl): env lighting as K
 * spherical-Gaussian lobes, occluders as the sphere sets attached to
 * instances, diffuse and specular soft shadows by the Integral Spherical
 * Gaussian. Plan: the lobe fit (when the env map or K changed), the ISG
 * table (once per context). Execute: every attached sphere in world space
 * (from the instances' transforms, so moving objects cost nothing more),
 * uploaded without waiting, and the shading kernel. */
#include "core/sg.h"
#include "methods/method.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

enum { P_BACKGROUND, P_LOBES, P_PATCH_GRID, P_SELF_OCCLUSION, P_SPECULAR_SHADOWS, P_ENV_SHARPNESS };

static const pn_param_desc params[] = {
    PN_PARAM_BACKGROUND,
    {"lobes", PN_PARAM_INT, PN_PARAM_PLAN, 32, 1, 128, "lobes",
     "K: spherical-Gaussian lobes fitted to the env map (plan: refitted when K or the env map changes)."},
    {"patch_grid", PN_PARAM_INT, PN_PARAM_FRAME, 16, 2, 24, "patches per side",
     "M: each lobe's visibility window is cut into M x M ISG patches (16: 256 patches)."},
    {"self_occlusion", PN_PARAM_INT, PN_PARAM_FRAME, 1, 0, 2, "",
     "Own spheres of the receiver's instance: 0 ignored, 1 used except those containing or touching the "
     "receiver, 2 all used."},
    {"specular_shadows", PN_PARAM_INT, PN_PARAM_FRAME, 1, 0, 1, "",
     "1: the specular term is shadowed (patch by patch or by its product lobes' visibility), 0: unshadowed."},
    {"env_sharpness", PN_PARAM_FLOAT, PN_PARAM_FRAME, 100, 0, 1e9, "",
     "BRDF lobes at least this sharp integrate the env cube on their own visible patches; broader ones use "
     "the SG lobe products."},
};

static const pn_param_desc bake_params[] = {
    {"spheres", PN_PARAM_INT, PN_PARAM_BAKE, 64, 1, 4096, "spheres",
     "N: spheres per occluder mesh (pn_sphere_set_build; docs/isg.md section 7)."},
};

typedef struct state {
    cl_mem lobes;             /* K pn_sg_lobe */
    int lobe_count;           /* K that `lobes` holds */
    uint64_t env_version;     /* env map that `lobes` was fitted to */
    float *spheres;           /* host: world centre + radius per sphere */
    uint32_t *owners;         /* host: instance id per sphere */
    size_t capacity, device_capacity;
    cl_mem device_spheres, device_owners;
} state;

static bool is_sphere_set(const pn_attachment *a)
{
    return a->asset->magic == PN_MAGIC_SPHERES;
}

static pn_status plan(pn_renderer r, pn_scene scene)
{
    state *s = r->state;
    pn_context ctx = r->obj.ctx;
    pn_envmap env = scene->env;
    const int k = (int)r->params[P_LOBES];
    if (s->lobes && s->lobe_count == k && s->env_version == env->version)
        return PN_SUCCESS;
    pn_sg_lobe *lobes = pn_malloc(ctx, pn_mul_size((size_t)k, 1, sizeof *lobes), "the env map's SG lobes");
    if (!lobes)
        return PN_ERROR_OUT_OF_MEMORY;
    pn_status st = pn_envmap_do_fit_sgs(env, (uint32_t)k, NULL, lobes, (size_t)k);
    if (!st) {
        pn_mem_release(&s->lobes);
        st = pn_alloc(ctx, (size_t)k * sizeof *lobes, CL_MEM_READ_ONLY, lobes, &s->lobes, "the env map's SG lobes");
    }
    free(lobes);
    if (!st)
        s->lobe_count = k, s->env_version = env->version;
    return st;
}

/* The largest column norm of the linear part: a sphere of radius r maps into
 * one of radius r times this (exact for rotations and uniform scales). */
static float radius_scale(const float *m)
{
    float best = 0.0f;
    for (int c = 0; c < 3; ++c)
        best = fmaxf(best, sqrtf(m[c] * m[c] + m[4 + c] * m[4 + c] + m[8 + c] * m[8 + c]));
    return best;
}

/* Every attached sphere in world space, instance order. */
static pn_status gather_spheres(pn_renderer r, pn_scene scene, uint32_t *count_out)
{
    state *s = r->state;
    pn_context ctx = r->obj.ctx;
    size_t total = 0;
    for (uint32_t ai = 0; ai < scene->attachment_count; ++ai)
        if (is_sphere_set(&scene->attachments[ai]))
            total += ((pn_sphere_set)scene->attachments[ai].asset)->count;
    if (total > (1u << 24))
        return pn_fail(ctx, PN_ERROR_INVALID_SIZE, "the scene's sphere sets hold %zu spheres, more than 2^24", total);
    if (total > s->capacity) {
        free(s->spheres), free(s->owners);
        s->capacity = 0;
        s->spheres = pn_malloc(ctx, pn_mul_size(total, 4, sizeof(float)), "the scene's spheres");
        s->owners = pn_malloc(ctx, pn_mul_size(total, 1, sizeof(uint32_t)), "the scene's sphere owners");
        if (!s->spheres || !s->owners)
            return PN_ERROR_OUT_OF_MEMORY;
        s->capacity = total;
    }
    uint32_t n = 0;
    for (uint32_t ai = 0; ai < scene->attachment_count; ++ai) {
        const pn_attachment *a = &scene->attachments[ai];
        if (!is_sphere_set(a))
            continue;
        const pn_sphere_set set = (pn_sphere_set)a->asset;
        const pn_instance *inst = pn_scene_instance(scene, a->instance);
        if (set->mesh_hash && inst->mesh->content_hash != set->mesh_hash)
            return pn_fail(ctx, PN_ERROR_INVALID_ARGUMENT,
                           "instance %u's mesh is now %016llx but its sphere set was built for %016llx: build the "
                           "set again and attach it",
                           a->instance, (unsigned long long)inst->mesh->content_hash,
                           (unsigned long long)set->mesh_hash);
        const float *m = inst->object_to_world, sc = radius_scale(m);
        for (uint32_t i = 0; i < set->count; ++i, ++n) {
            const float *c = set->spheres + 4 * i;
            float *o = s->spheres + 4 * (size_t)n;
            for (int row = 0; row < 3; ++row)
                o[row] = m[4 * row] * c[0] + m[4 * row + 1] * c[1] + m[4 * row + 2] * c[2] + m[4 * row + 3];
            o[3] = c[3] * sc;
            s->owners[n] = a->instance;
        }
    }
    *count_out = n;
    return PN_SUCCESS;
}

static pn_status execute(pn_renderer r, pn_scene scene, pn_gbuffer gb, pn_image image)
{
    pn_context ctx = r->obj.ctx;
    state *s = r->state;
    pn_envmap env = scene->env;
    cl_kernel k;
    cl_mem table;
    uint32_t sphere_count = 0;
    pn_status st;
    if ((st = pn_context_kernel(ctx, "isg", "shade_isg", &k)) || (st = pn_isg_table_buffer(ctx, &table)) ||
        (st = gather_spheres(r, scene, &sphere_count)))
        return st;
    const size_t need = sphere_count ? sphere_count : 1;
    if (need > s->device_capacity) {
        pn_mem_release(&s->device_spheres);
        pn_mem_release(&s->device_owners);
        s->device_capacity = 0;
        if ((st = pn_alloc(ctx, need * 16, CL_MEM_READ_ONLY, NULL, &s->device_spheres, "the scene's spheres")) ||
            (st = pn_alloc(ctx, need * 4, CL_MEM_READ_ONLY, NULL, &s->device_owners, "the scene's sphere owners")))
            return st;
        s->device_capacity = need;
    }
    if (sphere_count &&
        ((st = pn_upload_async(ctx, s->device_spheres, s->spheres, (size_t)sphere_count * 16, "uploading spheres")) ||
         (st = pn_upload_async(ctx, s->device_owners, s->owners, (size_t)sphere_count * 4, "uploading sphere owners"))))
        return st;
    const cl_int count = (cl_int)(gb->width * gb->height), n = env->face_size;
    const cl_int lobes = s->lobe_count, spheres = (cl_int)sphere_count, grid = (cl_int)r->params[P_PATCH_GRID];
    const cl_int self = (cl_int)r->params[P_SELF_OCCLUSION], spec = (cl_int)r->params[P_SPECULAR_SHADOWS];
    const cl_float env_sharpness = (cl_float)r->params[P_ENV_SHARPNESS];
    const cl_float4 camera = pn_scene_camera_position(scene);
    size_t sizes[] = {sizeof(cl_mem), sizeof(cl_mem), sizeof(cl_mem), sizeof(cl_mem), sizeof(cl_mem), sizeof count,
                      sizeof(cl_mem), sizeof n, sizeof(cl_mem), sizeof lobes, sizeof(cl_mem),
                      sizeof(cl_mem), sizeof spheres, sizeof grid, sizeof self, sizeof spec, sizeof env_sharpness, sizeof camera,
                      sizeof(cl_mem), sizeof(cl_mem)};
    const void *vals[] = {&gb->planes[PN_GBUFFER_POSITION], &gb->planes[PN_GBUFFER_NORMAL],
                          &gb->planes[PN_GBUFFER_ALBEDO], &gb->planes[PN_GBUFFER_MATERIAL],
                          &gb->planes[PN_GBUFFER_INSTANCE], &count, &env->cube, &n, &s->lobes, &lobes,
                          &s->device_spheres, &s->device_owners, &spheres, &grid, &self, &spec, &env_sharpness, &camera, &table,
                          &image->buffer};
    if ((st = pn_set_args(ctx, k, "shade_isg", 20, sizes, vals)))
        return st;
    return pn_enqueue_1d(ctx, k, "shade_isg", (size_t)count, 64);
}

static void destroy(pn_renderer r)
{
    state *s = r->state;
    pn_mem_release(&s->lobes);
    pn_mem_release(&s->device_spheres);
    pn_mem_release(&s->device_owners);
    free(s->spheres);
    free(s->owners);
}

const pn_method_desc pn_method_isg = {
    .name = "isg",
    .summary = "Integral Spherical Gaussian: env light as SG lobes, occluders as attached sphere sets, per-pixel "
               "diffuse and specular soft shadows",
    .stage = "isg",
    .doc_page = "docs/isg.md",
    .params = params,
    .param_count = (int)(sizeof params / sizeof params[0]),
    .bake_params = bake_params,
    .bake_param_count = (int)(sizeof bake_params / sizeof bake_params[0]),
    .inputs = PN_INPUT_ENVMAP | PN_INPUT_CAMERA | PN_INPUT_SPHERES,
    .state_size = sizeof(state),
    .destroy = destroy,
    .plan = plan,
    .execute = execute,
};
