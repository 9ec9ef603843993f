/* The boundary: every exported function of libpenumbra is here. Each checks
 * its handles and pointer arguments, then calls the internal function that
 * does the work; every failure comes back as a status with a recorded
 * message, never as a crash. */
#include "internal.h"

#include <stdio.h>
#include <string.h>

/* Every call that takes handles starts with ENTER on its first handle: the
 * handle is looked up in the handle table (a released or unknown one is
 * PN_ERROR_INVALID_HANDLE, never a read of freed memory), replaced by the
 * object, and the object's context is locked until the function returns
 * (the cleanup attribute runs pn_call_leave on every return path). Further
 * handles of the call go through RESOLVE: live, of the right kind, and of the
 * same context. */
static void leave_call(pn_call *call)
{
    pn_call_leave(call);
}

#define ENTER(h, MAGIC, kind)                                                                                \
    pn_call call_ __attribute__((cleanup(leave_call))) = {NULL};                                             \
    do {                                                                                                     \
        void *h_ = (void *)(h);                                                                              \
        pn_status st_ = pn_call_enter(&call_, &h_, (MAGIC), kind, __func__, #h);                             \
        if (st_)                                                                                             \
            return st_;                                                                                      \
        (h) = h_;                                                                                            \
    } while (0)

#define RESOLVE(h, MAGIC, kind)                                                                              \
    do {                                                                                                     \
        void *h_ = (void *)(h);                                                                              \
        pn_status st_ = pn_call_resolve(&call_, &h_, (MAGIC), kind, __func__, #h);                           \
        if (st_)                                                                                             \
            return st_;                                                                                      \
        (h) = h_;                                                                                            \
    } while (0)

#define CHECK_PTR(ctx, p)                                                                                    \
    do {                                                                                                     \
        if (!(p))                                                                                            \
            return pn_fail((ctx), PN_ERROR_INVALID_ARGUMENT, "%s: argument '%s' is NULL", __func__, #p);     \
    } while (0)

#define CHECK_NAME(ctx, name) CHECK_PTR(ctx, name)

/* A created object's handle into *out (what the caller holds). */
#define RETURN_HANDLE(expr, out)                                                                             \
    do {                                                                                                     \
        pn_status st_ = (expr);                                                                              \
        if (!st_ && *(out))                                                                                  \
            *(out) = pn_object_handle(&(*(out))->obj);                                                       \
        return st_;                                                                                          \
    } while (0)

static pn_status retain(pn_object *o)
{
    return pn_object_public_retain(o);
}

/* Drops the caller's reference (the last one invalidates the handle; the
 * object lives on while the library holds it). */
#define RELEASE(h)                                                                                           \
    do {                                                                                                     \
        pn_object_public_release(&(h)->obj);                                                                 \
        return PN_SUCCESS;                                                                                   \
    } while (0)

/* ------------------------------------------------------------------ misc */

pn_status pn_get_error(pn_context ctx, const char **message)
{
    if (!ctx)
        return pn_error_take(NULL, message);
    pn_call call_ __attribute__((cleanup(leave_call))) = {NULL};
    void *h = (void *)ctx;
    pn_status st = pn_call_enter_released(&call_, &h, PN_MAGIC_CONTEXT, "context", "pn_get_error", "ctx");
    if (st) {
        /* Recorded in the global slot too, like every other bad handle. */
        if (message)
            *message = st == PN_ERROR_INVALID_HANDLE ? "pn_get_error: 'ctx' is not a live context (released?)"
                                                     : "pn_get_error: 'ctx' is not a context";
        return st;
    }
    return pn_error_take(h, message);
}

const char *pn_status_name(pn_status status)
{
    return pn_status_name_of(status);
}

const char *pn_version(void)
{
    return "0.1.0";
}

pn_material pn_material_default(void)
{
    return pn_default_material();
}

const char *pn_lobe_name(uint32_t lobe)
{
    static const char *const names[] = {"phong", "blinn_phong", "ggx", "ashikhmin_shirley"};
    return lobe < sizeof names / sizeof names[0] ? names[lobe] : NULL;
}

pn_status pn_transform_uniform_scale(const float transform[12], float *scale)
{
    CHECK_PTR(NULL, transform);
    CHECK_PTR(NULL, scale);
    *scale = pn_uniform_scale(transform);
    return PN_SUCCESS;
}

/* --------------------------------------------------------------- context */

pn_status pn_context_create(const char *config, pn_context *out)
{
    CHECK_PTR(NULL, out);
    *out = NULL;
    RETURN_HANDLE(pn_context_new(config, NULL, NULL, out), out);
}

pn_status pn_context_create_from_cl(cl_context cl_ctx, cl_command_queue queue, const char *config, pn_context *out)
{
    CHECK_PTR(NULL, out);
    *out = NULL;
    CHECK_PTR(NULL, cl_ctx);
    CHECK_PTR(NULL, queue);
    RETURN_HANDLE(pn_context_new(config, cl_ctx, queue, out), out);
}

pn_status pn_context_retain(pn_context ctx)
{
    ENTER(ctx, PN_MAGIC_CONTEXT, "context");
    return retain(&ctx->obj);
}

pn_status pn_context_release(pn_context ctx)
{
    ENTER(ctx, PN_MAGIC_CONTEXT, "context");
    RELEASE(ctx);
}

pn_status pn_context_set_error_callback(pn_context ctx, pn_error_callback callback, void *user)
{
    ENTER(ctx, PN_MAGIC_CONTEXT, "context");
    ctx->callback = callback;
    ctx->callback_user = user;
    return PN_SUCCESS;
}

pn_status pn_context_get_cl(pn_context ctx, cl_context *cl_ctx, cl_command_queue *queue, cl_device_id *device)
{
    ENTER(ctx, PN_MAGIC_CONTEXT, "context");
    if (cl_ctx)
        *cl_ctx = ctx->cl_ctx;
    if (queue)
        *queue = ctx->queue;
    if (device)
        *device = ctx->device;
    return PN_SUCCESS;
}

pn_status pn_context_get_device_name(pn_context ctx, char *name, size_t size)
{
    ENTER(ctx, PN_MAGIC_CONTEXT, "context");
    CHECK_PTR(ctx, name);
    if (size == 0)
        return pn_fail(ctx, PN_ERROR_INVALID_SIZE, "pn_context_get_device_name: size is 0");
    char buf[512] = "";
    cl_int err = clGetDeviceInfo(ctx->device, CL_DEVICE_NAME, sizeof buf, buf, NULL);
    if (err != CL_SUCCESS)
        return pn_fail_cl(ctx, err, "querying the device name");
    snprintf(name, size, "%s", buf);
    return PN_SUCCESS;
}

pn_status pn_context_finish(pn_context ctx)
{
    ENTER(ctx, PN_MAGIC_CONTEXT, "context");
    cl_int err = clFinish(ctx->queue);
    return err == CL_SUCCESS ? PN_SUCCESS : pn_fail_cl(ctx, err, "waiting for queued work");
}

pn_status pn_context_build_program(pn_context ctx, const char *stage)
{
    ENTER(ctx, PN_MAGIC_CONTEXT, "context");
    CHECK_NAME(ctx, stage);
    cl_program program;
    return pn_context_program(ctx, stage, &program);
}

/* ----------------------------------------------------------- environment */

pn_status pn_envmap_create(pn_context ctx, pn_envmap *out)
{
    ENTER(ctx, PN_MAGIC_CONTEXT, "context");
    CHECK_PTR(ctx, out);
    RETURN_HANDLE(pn_envmap_new(ctx, out), out);
}

pn_status pn_envmap_retain(pn_envmap env)
{
    ENTER(env, PN_MAGIC_ENVMAP, "env map");
    return retain(&env->obj);
}

pn_status pn_envmap_release(pn_envmap env)
{
    ENTER(env, PN_MAGIC_ENVMAP, "env map");
    RELEASE(env);
}

pn_status pn_envmap_set_latlong(pn_envmap env, const float *rgb, uint32_t width, uint32_t height)
{
    ENTER(env, PN_MAGIC_ENVMAP, "env map");
    CHECK_PTR(env->obj.ctx, rgb);
    return pn_envmap_do_set_latlong(env, rgb, width, height);
}

pn_status pn_envmap_set_int(pn_envmap env, const char *name, int32_t value)
{
    ENTER(env, PN_MAGIC_ENVMAP, "env map");
    CHECK_NAME(env->obj.ctx, name);
    return pn_envmap_param_int(env, name, &value, true);
}

pn_status pn_envmap_set_float(pn_envmap env, const char *name, float value)
{
    ENTER(env, PN_MAGIC_ENVMAP, "env map");
    CHECK_NAME(env->obj.ctx, name);
    return pn_envmap_param_float(env, name, &value, true);
}

pn_status pn_envmap_get_int(pn_envmap env, const char *name, int32_t *value)
{
    ENTER(env, PN_MAGIC_ENVMAP, "env map");
    CHECK_NAME(env->obj.ctx, name);
    CHECK_PTR(env->obj.ctx, value);
    return pn_envmap_param_int(env, name, value, false);
}

pn_status pn_envmap_get_float(pn_envmap env, const char *name, float *value)
{
    ENTER(env, PN_MAGIC_ENVMAP, "env map");
    CHECK_NAME(env->obj.ctx, name);
    CHECK_PTR(env->obj.ctx, value);
    return pn_envmap_param_float(env, name, value, false);
}

pn_status pn_envmap_commit(pn_envmap env)
{
    ENTER(env, PN_MAGIC_ENVMAP, "env map");
    return pn_envmap_do_commit(env);
}

pn_status pn_envmap_read(pn_envmap env, pn_envmap_data what, void *host, size_t bytes)
{
    ENTER(env, PN_MAGIC_ENVMAP, "env map");
    CHECK_PTR(env->obj.ctx, host);
    return pn_envmap_do_read(env, what, host, bytes);
}

/* ---------------------------------------------------- spherical Gaussians */

pn_status pn_isg_table(float *out, size_t count)
{
    CHECK_PTR(NULL, out);
    if (count != PN_ISG_TABLE_FLOATS)
        return pn_fail(NULL, PN_ERROR_INVALID_SIZE, "pn_isg_table needs exactly %d floats, got %zu", PN_ISG_TABLE_FLOATS,
                       count);
    pn_isg_table_fill(out);
    return PN_SUCCESS;
}

pn_status pn_envmap_fit_sgs(pn_envmap env, uint32_t count, const pn_sg_fit_options *options, pn_sg_lobe *out,
                            size_t capacity)
{
    ENTER(env, PN_MAGIC_ENVMAP, "env map");
    CHECK_PTR(env->obj.ctx, out);
    return pn_envmap_do_fit_sgs(env, count, options, out, capacity);
}

/* ------------------------------------------------------------------ mesh */

pn_status pn_mesh_create(pn_context ctx, pn_mesh *out)
{
    ENTER(ctx, PN_MAGIC_CONTEXT, "context");
    CHECK_PTR(ctx, out);
    RETURN_HANDLE(pn_mesh_new(ctx, out), out);
}

pn_status pn_mesh_retain(pn_mesh mesh)
{
    ENTER(mesh, PN_MAGIC_MESH, "mesh");
    return retain(&mesh->obj);
}

pn_status pn_mesh_release(pn_mesh mesh)
{
    ENTER(mesh, PN_MAGIC_MESH, "mesh");
    RELEASE(mesh);
}

pn_status pn_mesh_set_geometry(pn_mesh mesh, const float *positions, uint32_t vertex_count, const uint32_t *indices,
                               uint32_t triangle_count, const float *normals)
{
    ENTER(mesh, PN_MAGIC_MESH, "mesh");
    if (vertex_count)
        CHECK_PTR(mesh->obj.ctx, positions);
    if (triangle_count)
        CHECK_PTR(mesh->obj.ctx, indices);
    return pn_mesh_do_set_geometry(mesh, positions, vertex_count, indices, triangle_count, normals);
}

pn_status pn_mesh_commit(pn_mesh mesh)
{
    ENTER(mesh, PN_MAGIC_MESH, "mesh");
    return pn_mesh_do_commit(mesh);
}

pn_status pn_mesh_get_hash(pn_mesh mesh, uint64_t *hash)
{
    ENTER(mesh, PN_MAGIC_MESH, "mesh");
    CHECK_PTR(mesh->obj.ctx, hash);
    if (!mesh->committed)
        return pn_fail(mesh->obj.ctx, PN_ERROR_NOT_COMMITTED, "mesh changed since its last commit; call pn_mesh_commit");
    *hash = mesh->content_hash;
    return PN_SUCCESS;
}

pn_status pn_mesh_get_info(pn_mesh mesh, pn_mesh_info *info)
{
    ENTER(mesh, PN_MAGIC_MESH, "mesh");
    CHECK_PTR(mesh->obj.ctx, info);
    if (!mesh->committed)
        return pn_fail(mesh->obj.ctx, PN_ERROR_NOT_COMMITTED, "mesh changed since its last commit; call pn_mesh_commit");
    info->vertex_count = mesh->vertex_count;
    info->triangle_count = mesh->triangle_count;
    info->bvh_node_count = mesh->bvh.node_count;
    info->bvh_depth = mesh->bvh.depth;
    memcpy(info->bounds_lo, mesh->bounds_lo, sizeof info->bounds_lo);
    memcpy(info->bounds_hi, mesh->bounds_hi, sizeof info->bounds_hi);
    info->has_normals = mesh->normals != NULL;
    return PN_SUCCESS;
}

pn_status pn_mesh_read_geometry(pn_mesh mesh, float *positions, uint32_t *indices, float *normals)
{
    ENTER(mesh, PN_MAGIC_MESH, "mesh");
    CHECK_PTR(mesh->obj.ctx, positions);
    CHECK_PTR(mesh->obj.ctx, indices);
    return pn_mesh_do_read_geometry(mesh, positions, indices, normals);
}

/* ----------------------------------------------------------------- scene */

pn_status pn_scene_create(pn_context ctx, pn_scene *out)
{
    ENTER(ctx, PN_MAGIC_CONTEXT, "context");
    CHECK_PTR(ctx, out);
    RETURN_HANDLE(pn_scene_new(ctx, out), out);
}

pn_status pn_scene_retain(pn_scene scene)
{
    ENTER(scene, PN_MAGIC_SCENE, "scene");
    return retain(&scene->obj);
}

pn_status pn_scene_release(pn_scene scene)
{
    ENTER(scene, PN_MAGIC_SCENE, "scene");
    RELEASE(scene);
}

pn_status pn_scene_set_envmap(pn_scene scene, pn_envmap env)
{
    ENTER(scene, PN_MAGIC_SCENE, "scene");
    RESOLVE(env, PN_MAGIC_ENVMAP, "env map");
    return pn_scene_do_set_envmap(scene, env);
}

pn_status pn_scene_add_instance(pn_scene scene, pn_mesh mesh, const float transform[12], const pn_material *material,
                                uint32_t *id)
{
    ENTER(scene, PN_MAGIC_SCENE, "scene");
    RESOLVE(mesh, PN_MAGIC_MESH, "mesh");
    CHECK_PTR(scene->obj.ctx, id);
    if (mesh->obj.ctx != scene->obj.ctx)
        return pn_fail(scene->obj.ctx, PN_ERROR_INVALID_ARGUMENT, "the mesh belongs to a different context");
    return pn_scene_do_add_instance(scene, mesh, transform, material, id);
}

pn_status pn_scene_set_instance_transform(pn_scene scene, uint32_t id, const float transform[12])
{
    ENTER(scene, PN_MAGIC_SCENE, "scene");
    return pn_scene_do_set_transform(scene, id, transform);
}

pn_status pn_scene_set_instance_material(pn_scene scene, uint32_t id, const pn_material *material)
{
    ENTER(scene, PN_MAGIC_SCENE, "scene");
    CHECK_PTR(scene->obj.ctx, material);
    return pn_scene_do_set_material(scene, id, material);
}

pn_status pn_scene_remove_instance(pn_scene scene, uint32_t id)
{
    ENTER(scene, PN_MAGIC_SCENE, "scene");
    return pn_scene_do_remove(scene, id);
}

pn_status pn_scene_set_camera(pn_scene scene, const pn_camera *camera)
{
    ENTER(scene, PN_MAGIC_SCENE, "scene");
    CHECK_PTR(scene->obj.ctx, camera);
    return pn_scene_do_set_camera(scene, camera);
}

pn_status pn_scene_set_lights(pn_scene scene, const pn_sphere_light *lights, uint32_t count)
{
    ENTER(scene, PN_MAGIC_SCENE, "scene");
    if (count)
        CHECK_PTR(scene->obj.ctx, lights);
    return pn_scene_do_set_lights(scene, lights, count);
}

pn_status pn_scene_attach(pn_scene scene, uint32_t instance, void *asset)
{
    ENTER(scene, PN_MAGIC_SCENE, "scene");
    RESOLVE(asset, PN_MAGIC_ANY, "penumbra object");
    return pn_scene_do_attach(scene, instance, (pn_object *)asset);
}

pn_status pn_scene_detach(pn_scene scene, uint32_t instance, void *asset)
{
    ENTER(scene, PN_MAGIC_SCENE, "scene");
    if (asset)
        RESOLVE(asset, PN_MAGIC_ANY, "penumbra object");
    return pn_scene_do_detach(scene, instance, (pn_object *)asset);
}

pn_status pn_scene_commit(pn_scene scene)
{
    ENTER(scene, PN_MAGIC_SCENE, "scene");
    return pn_scene_do_commit(scene);
}

pn_status pn_scene_intersect(pn_scene scene, const float *rays, uint32_t count, float *t, uint32_t *instance,
                             uint32_t *triangle)
{
    ENTER(scene, PN_MAGIC_SCENE, "scene");
    if (count)
        CHECK_PTR(scene->obj.ctx, rays);
    const pn_ray_input in = {rays, NULL, NULL, 0.0f, 0.0f};
    return pn_scene_do_query(scene, &in, count, t, instance, triangle, NULL);
}

pn_status pn_scene_occluded(pn_scene scene, const float *rays, uint32_t count, uint8_t *occluded)
{
    ENTER(scene, PN_MAGIC_SCENE, "scene");
    if (count) {
        CHECK_PTR(scene->obj.ctx, rays);
        CHECK_PTR(scene->obj.ctx, occluded);
    }
    const pn_ray_input in = {rays, NULL, NULL, 0.0f, 0.0f};
    return pn_scene_do_query(scene, &in, count, NULL, NULL, NULL, count ? occluded : NULL);
}

pn_status pn_scene_intersect_arrays(pn_scene scene, const float *origins, const float *directions, uint32_t count,
                                   float tmin, float tmax, float *t, uint32_t *instance, uint32_t *triangle)
{
    ENTER(scene, PN_MAGIC_SCENE, "scene");
    if (count) {
        CHECK_PTR(scene->obj.ctx, origins);
        CHECK_PTR(scene->obj.ctx, directions);
    }
    const pn_ray_input in = {NULL, origins, directions, tmin, tmax};
    return pn_scene_do_query(scene, &in, count, t, instance, triangle, NULL);
}

pn_status pn_scene_occluded_arrays(pn_scene scene, const float *origins, const float *directions, uint32_t count,
                                  float tmin, float tmax, uint8_t *occluded)
{
    ENTER(scene, PN_MAGIC_SCENE, "scene");
    if (count) {
        CHECK_PTR(scene->obj.ctx, origins);
        CHECK_PTR(scene->obj.ctx, directions);
        CHECK_PTR(scene->obj.ctx, occluded);
    }
    const pn_ray_input in = {NULL, origins, directions, tmin, tmax};
    return pn_scene_do_query(scene, &in, count, NULL, NULL, NULL, count ? occluded : NULL);
}

pn_status pn_scene_render_gbuffer(pn_scene scene, pn_gbuffer gbuffer)
{
    ENTER(scene, PN_MAGIC_SCENE, "scene");
    RESOLVE(gbuffer, PN_MAGIC_GBUFFER, "G-buffer");
    if (gbuffer->obj.ctx != scene->obj.ctx)
        return pn_fail(scene->obj.ctx, PN_ERROR_INVALID_ARGUMENT, "the G-buffer belongs to a different context");
    return pn_scene_do_render_gbuffer(scene, gbuffer);
}

/* -------------------------------------------------------------- G-buffer */

pn_status pn_gbuffer_create(pn_context ctx, uint32_t width, uint32_t height, pn_gbuffer *out)
{
    ENTER(ctx, PN_MAGIC_CONTEXT, "context");
    CHECK_PTR(ctx, out);
    RETURN_HANDLE(pn_gbuffer_new(ctx, width, height, NULL, out), out);
}

pn_status pn_gbuffer_create_from_cl(pn_context ctx, uint32_t width, uint32_t height,
                                    const cl_mem planes[PN_GBUFFER_PLANE_COUNT], pn_gbuffer *out)
{
    ENTER(ctx, PN_MAGIC_CONTEXT, "context");
    CHECK_PTR(ctx, planes);
    CHECK_PTR(ctx, out);
    RETURN_HANDLE(pn_gbuffer_new(ctx, width, height, planes, out), out);
}

pn_status pn_gbuffer_retain(pn_gbuffer gbuffer)
{
    ENTER(gbuffer, PN_MAGIC_GBUFFER, "G-buffer");
    return retain(&gbuffer->obj);
}

pn_status pn_gbuffer_release(pn_gbuffer gbuffer)
{
    ENTER(gbuffer, PN_MAGIC_GBUFFER, "G-buffer");
    RELEASE(gbuffer);
}

pn_status pn_gbuffer_get_size(pn_gbuffer gbuffer, uint32_t *width, uint32_t *height)
{
    ENTER(gbuffer, PN_MAGIC_GBUFFER, "G-buffer");
    if (width)
        *width = gbuffer->width;
    if (height)
        *height = gbuffer->height;
    return PN_SUCCESS;
}

static pn_status check_plane(pn_gbuffer gbuffer, pn_gbuffer_plane plane)
{
    if (pn_gbuffer_plane_element_size(plane) == 0)
        return pn_fail(gbuffer->obj.ctx, PN_ERROR_INVALID_ARGUMENT, "G-buffer plane %d does not exist (0..%d)", (int)plane,
                       PN_GBUFFER_PLANE_COUNT - 1);
    return PN_SUCCESS;
}

pn_status pn_gbuffer_get_cl(pn_gbuffer gbuffer, pn_gbuffer_plane plane, cl_mem *buffer)
{
    ENTER(gbuffer, PN_MAGIC_GBUFFER, "G-buffer");
    CHECK_PTR(gbuffer->obj.ctx, buffer);
    pn_status st = check_plane(gbuffer, plane);
    if (!st)
        *buffer = gbuffer->planes[plane];
    return st;
}

pn_status pn_gbuffer_write(pn_gbuffer gbuffer, pn_gbuffer_plane plane, const void *host, size_t bytes)
{
    ENTER(gbuffer, PN_MAGIC_GBUFFER, "G-buffer");
    CHECK_PTR(gbuffer->obj.ctx, host);
    pn_status st = check_plane(gbuffer, plane);
    return st ? st : pn_gbuffer_transfer(gbuffer, plane, (void *)host, bytes, true);
}

pn_status pn_gbuffer_read(pn_gbuffer gbuffer, pn_gbuffer_plane plane, void *host, size_t bytes)
{
    ENTER(gbuffer, PN_MAGIC_GBUFFER, "G-buffer");
    CHECK_PTR(gbuffer->obj.ctx, host);
    pn_status st = check_plane(gbuffer, plane);
    return st ? st : pn_gbuffer_transfer(gbuffer, plane, host, bytes, false);
}

pn_status pn_gbuffer_validate(pn_gbuffer gbuffer)
{
    ENTER(gbuffer, PN_MAGIC_GBUFFER, "G-buffer");
    return pn_gbuffer_do_validate(gbuffer);
}

/* ----------------------------------------------------------------- image */

pn_status pn_image_create(pn_context ctx, uint32_t width, uint32_t height, pn_image *out)
{
    ENTER(ctx, PN_MAGIC_CONTEXT, "context");
    CHECK_PTR(ctx, out);
    RETURN_HANDLE(pn_image_new(ctx, width, height, NULL, out), out);
}

pn_status pn_image_create_from_cl(pn_context ctx, uint32_t width, uint32_t height, cl_mem buffer, pn_image *out)
{
    ENTER(ctx, PN_MAGIC_CONTEXT, "context");
    CHECK_PTR(ctx, buffer);
    CHECK_PTR(ctx, out);
    RETURN_HANDLE(pn_image_new(ctx, width, height, buffer, out), out);
}

pn_status pn_image_retain(pn_image image)
{
    ENTER(image, PN_MAGIC_IMAGE, "image");
    return retain(&image->obj);
}

pn_status pn_image_release(pn_image image)
{
    ENTER(image, PN_MAGIC_IMAGE, "image");
    RELEASE(image);
}

pn_status pn_image_get_cl(pn_image image, cl_mem *buffer)
{
    ENTER(image, PN_MAGIC_IMAGE, "image");
    CHECK_PTR(image->obj.ctx, buffer);
    *buffer = image->buffer;
    return PN_SUCCESS;
}

pn_status pn_image_read(pn_image image, float *host, size_t bytes)
{
    ENTER(image, PN_MAGIC_IMAGE, "image");
    CHECK_PTR(image->obj.ctx, host);
    return pn_image_do_read(image, host, bytes);
}

/* -------------------------------------------------------------- renderer */

uint32_t pn_method_count(void)
{
    return pn_method_table_size();
}

const char *pn_method_name(uint32_t index)
{
    const pn_method_desc *m = pn_method_at(index);
    return m ? m->name : NULL;
}

/* Renderer parameters and bake options together, as the metadata lists them. */
static uint32_t param_total(const pn_method_desc *m)
{
    return (uint32_t)(m->param_count + m->bake_param_count);
}

pn_status pn_method_get_info(const char *method, pn_method_info *info)
{
    CHECK_NAME(NULL, method);
    CHECK_PTR(NULL, info);
    const pn_method_desc *m = pn_method_find(method);
    if (!m)
        return PN_ERROR_INVALID_ARGUMENT;
    info->name = m->name;
    info->summary = m->summary;
    info->stage = m->stage;
    info->doc_page = m->doc_page;
    info->param_count = param_total(m);
    info->output_count = (uint32_t)m->output_count;
    info->inputs = m->inputs;
    return PN_SUCCESS;
}

pn_status pn_method_get_param(const char *method, uint32_t index, pn_param_info *info)
{
    CHECK_NAME(NULL, method);
    CHECK_PTR(NULL, info);
    const pn_method_desc *m = pn_method_find(method);
    if (!m)
        return PN_ERROR_INVALID_ARGUMENT;
    const uint32_t total = param_total(m);
    if (index >= total)
        return pn_fail(NULL, PN_ERROR_OUT_OF_RANGE, "method %s has %u parameters; there is no parameter %u", m->name,
                       total, index);
    /* Renderer parameters first, then the bake's options. */
    const pn_param_desc *p = index < (uint32_t)m->param_count ? &m->params[index]
                                                              : &m->bake_params[index - (uint32_t)m->param_count];
    info->name = p->name;
    info->type = p->type;
    info->stage = p->stage;
    info->default_value = p->fallback;
    info->min = p->lo;
    info->max = p->hi;
    info->unit = p->unit;
    info->doc = p->doc;
    return PN_SUCCESS;
}

pn_status pn_method_get_output(const char *method, uint32_t index, pn_output_info *info)
{
    CHECK_NAME(NULL, method);
    CHECK_PTR(NULL, info);
    const pn_method_desc *m = pn_method_find(method);
    if (!m)
        return PN_ERROR_INVALID_ARGUMENT;
    if (index >= (uint32_t)m->output_count)
        return pn_fail(NULL, PN_ERROR_OUT_OF_RANGE, "method %s has %d outputs; there is no output %u", m->name,
                       m->output_count, index);
    info->name = m->outputs[index].name;
    info->doc = m->outputs[index].doc;
    return PN_SUCCESS;
}

pn_status pn_renderer_create(pn_context ctx, const char *method, pn_renderer *out)
{
    ENTER(ctx, PN_MAGIC_CONTEXT, "context");
    CHECK_NAME(ctx, method);
    CHECK_PTR(ctx, out);
    RETURN_HANDLE(pn_renderer_new(ctx, method, out), out);
}

pn_status pn_renderer_retain(pn_renderer renderer)
{
    ENTER(renderer, PN_MAGIC_RENDERER, "renderer");
    return retain(&renderer->obj);
}

pn_status pn_renderer_release(pn_renderer renderer)
{
    ENTER(renderer, PN_MAGIC_RENDERER, "renderer");
    RELEASE(renderer);
}

pn_status pn_renderer_set_int(pn_renderer renderer, const char *name, int32_t value)
{
    ENTER(renderer, PN_MAGIC_RENDERER, "renderer");
    CHECK_NAME(renderer->obj.ctx, name);
    return pn_renderer_param_int(renderer, name, &value, true);
}

pn_status pn_renderer_set_float(pn_renderer renderer, const char *name, float value)
{
    ENTER(renderer, PN_MAGIC_RENDERER, "renderer");
    CHECK_NAME(renderer->obj.ctx, name);
    return pn_renderer_param_float(renderer, name, &value, true);
}

pn_status pn_renderer_get_int(pn_renderer renderer, const char *name, int32_t *value)
{
    ENTER(renderer, PN_MAGIC_RENDERER, "renderer");
    CHECK_NAME(renderer->obj.ctx, name);
    CHECK_PTR(renderer->obj.ctx, value);
    return pn_renderer_param_int(renderer, name, value, false);
}

pn_status pn_renderer_get_float(pn_renderer renderer, const char *name, float *value)
{
    ENTER(renderer, PN_MAGIC_RENDERER, "renderer");
    CHECK_NAME(renderer->obj.ctx, name);
    CHECK_PTR(renderer->obj.ctx, value);
    return pn_renderer_param_float(renderer, name, value, false);
}

pn_status pn_renderer_commit(pn_renderer renderer)
{
    ENTER(renderer, PN_MAGIC_RENDERER, "renderer");
    return pn_renderer_do_commit(renderer);
}

pn_status pn_renderer_execute(pn_renderer renderer, pn_scene scene, pn_gbuffer gbuffer, pn_image image)
{
    ENTER(renderer, PN_MAGIC_RENDERER, "renderer");
    RESOLVE(scene, PN_MAGIC_SCENE, "scene");
    RESOLVE(gbuffer, PN_MAGIC_GBUFFER, "G-buffer");
    RESOLVE(image, PN_MAGIC_IMAGE, "image");
    return pn_renderer_do_execute(renderer, scene, gbuffer, image);
}

pn_status pn_renderer_read_output(pn_renderer renderer, pn_scene scene, const char *output, uint32_t instance,
                                  uint32_t index, void *host, size_t bytes)
{
    ENTER(renderer, PN_MAGIC_RENDERER, "renderer");
    RESOLVE(scene, PN_MAGIC_SCENE, "scene");
    CHECK_NAME(renderer->obj.ctx, output);
    CHECK_PTR(renderer->obj.ctx, host);
    return pn_renderer_do_read_output(renderer, scene, output, instance, index, host, bytes);
}

pn_status pn_renderer_set_env_domains(pn_renderer renderer, const pn_env_domain *domains, uint32_t count)
{
    ENTER(renderer, PN_MAGIC_RENDERER, "renderer");
    return pn_renderer_do_set_env_domains(renderer, domains, count);
}

pn_status pn_renderer_set_depth_maps(pn_renderer renderer, const float *frames, const float *depths, uint32_t count,
                                     uint32_t resolution)
{
    ENTER(renderer, PN_MAGIC_RENDERER, "renderer");
    return pn_depthmap_set_maps(renderer, frames, depths, count, resolution);
}

pn_status pn_renderer_set_depth_maps_sized(pn_renderer renderer, const float *frames, const float *depths,
                                           uint32_t count, const uint32_t *resolutions)
{
    ENTER(renderer, PN_MAGIC_RENDERER, "renderer");
    return pn_depthmap_set_maps_sized(renderer, frames, depths, count, resolutions);
}

pn_status pn_renderer_set_depth_maps_cl(pn_renderer renderer, const float *frames, cl_mem depths, uint32_t count,
                                        const uint32_t *resolutions)
{
    ENTER(renderer, PN_MAGIC_RENDERER, "renderer");
    return pn_depthmap_set_maps_cl(renderer, frames, depths, count, resolutions);
}

/* ------------------------------------------------------ occlusion fields */

pn_status pn_envmap_get_hash(pn_envmap env, uint64_t *hash)
{
    ENTER(env, PN_MAGIC_ENVMAP, "env map");
    CHECK_PTR(env->obj.ctx, hash);
    if (!env->committed)
        return pn_fail(env->obj.ctx, PN_ERROR_NOT_COMMITTED, "env map changed since its last commit; call pn_envmap_commit");
    *hash = env->content_hash;
    return PN_SUCCESS;
}

pn_env_decompose_options pn_env_decompose_options_default(void)
{
    pn_env_decompose_options o = {64, 1, 0};
    return o;
}

pn_status pn_envmap_decompose(pn_envmap env, const pn_env_decompose_options *options, pn_env_domain *domains,
                              uint32_t capacity)
{
    ENTER(env, PN_MAGIC_ENVMAP, "env map");
    CHECK_PTR(env->obj.ctx, options);
    CHECK_PTR(env->obj.ctx, domains);
    return pn_envmap_do_decompose(env, options, domains, capacity);
}

pn_env_sharp_options pn_env_sharp_options_default(void)
{
    pn_env_sharp_options o = {4, 100.0f, 1, 0};
    return o;
}

pn_status pn_envmap_extract_sharp(pn_envmap env, const pn_env_sharp_options *options, pn_env_domain *domains,
                                  uint32_t capacity, uint32_t *count, float *residual, size_t residual_floats)
{
    ENTER(env, PN_MAGIC_ENVMAP, "env map");
    CHECK_PTR(env->obj.ctx, options);
    CHECK_PTR(env->obj.ctx, domains);
    CHECK_PTR(env->obj.ctx, count);
    CHECK_PTR(env->obj.ctx, residual);
    return pn_envmap_do_extract_sharp(env, options, domains, capacity, count, residual, residual_floats);
}

pn_status pn_fiv_bake(pn_envmap env, pn_mesh mesh, const pn_fiv_options *options, const char *checkpoint_path,
                      pn_progress_callback progress, void *user, pn_fiv *out)
{
    ENTER(env, PN_MAGIC_ENVMAP, "env map");
    RESOLVE(mesh, PN_MAGIC_MESH, "mesh");
    CHECK_PTR(env->obj.ctx, options);
    CHECK_PTR(env->obj.ctx, out);
    *out = NULL;
    RETURN_HANDLE(pn_fiv_do_bake(env, mesh, options, checkpoint_path, progress, user, out), out);
}

pn_status pn_fiv_load(pn_context ctx, const char *path, pn_fiv *out)
{
    ENTER(ctx, PN_MAGIC_CONTEXT, "context");
    CHECK_NAME(ctx, path);
    CHECK_PTR(ctx, out);
    *out = NULL;
    RETURN_HANDLE(pn_fiv_read_file(ctx, path, false, out), out);
}

pn_status pn_fiv_save(pn_fiv fiv, const char *path)
{
    ENTER(fiv, PN_MAGIC_FIV, "occlusion field");
    CHECK_NAME(fiv->obj.ctx, path);
    return pn_fiv_write_file(fiv, path);
}

pn_status pn_fiv_retain(pn_fiv fiv)
{
    ENTER(fiv, PN_MAGIC_FIV, "occlusion field");
    return retain(&fiv->obj);
}

pn_status pn_fiv_release(pn_fiv fiv)
{
    ENTER(fiv, PN_MAGIC_FIV, "occlusion field");
    RELEASE(fiv);
}

pn_status pn_fiv_get_info(pn_fiv fiv, pn_fiv_info *info)
{
    ENTER(fiv, PN_MAGIC_FIV, "occlusion field");
    CHECK_PTR(fiv->obj.ctx, info);
    pn_fiv_fill_info(fiv, info);
    return PN_SUCCESS;
}

pn_status pn_fiv_read_header(const char *path, pn_fiv_info *info)
{
    CHECK_NAME(NULL, path);
    CHECK_PTR(NULL, info);
    return pn_fiv_read_file_header(path, info);
}

pn_fiv_options pn_fiv_options_default(void)
{
    return pn_fiv_default_options();
}

pn_status pn_fiv_read(pn_fiv fiv, float *host, size_t bytes)
{
    ENTER(fiv, PN_MAGIC_FIV, "occlusion field");
    CHECK_PTR(fiv->obj.ctx, host);
    return pn_fiv_do_read(fiv, host, bytes);
}

/* ---------------------------------------------------------- height fields */

pn_status pn_heightfield_create(pn_context ctx, pn_heightfield *out)
{
    ENTER(ctx, PN_MAGIC_CONTEXT, "context");
    CHECK_PTR(ctx, out);
    RETURN_HANDLE(pn_heightfield_new(ctx, out), out);
}

pn_status pn_heightfield_retain(pn_heightfield hf)
{
    ENTER(hf, PN_MAGIC_HEIGHTFIELD, "height field");
    return retain(&hf->obj);
}

pn_status pn_heightfield_release(pn_heightfield hf)
{
    ENTER(hf, PN_MAGIC_HEIGHTFIELD, "height field");
    RELEASE(hf);
}

pn_status pn_heightfield_set_heights(pn_heightfield hf, const float *heights, uint32_t width, uint32_t depth)
{
    ENTER(hf, PN_MAGIC_HEIGHTFIELD, "height field");
    CHECK_PTR(hf->obj.ctx, heights);
    const bool sized = hf->placement.size[0] > 0.0f;
    pn_status st = pn_heightfield_do_set_heights(hf, heights, width, depth);
    if (!st && !sized) { /* default placement: one world unit per grid step */
        hf->placement.size[0] = (float)(width - 1);
        hf->placement.size[1] = (float)(depth - 1);
    }
    return st;
}

pn_status pn_heightfield_set_heights_region(pn_heightfield hf, uint32_t x0, uint32_t y0, uint32_t width,
                                            uint32_t depth, const float *heights)
{
    ENTER(hf, PN_MAGIC_HEIGHTFIELD, "height field");
    CHECK_PTR(hf->obj.ctx, heights);
    return pn_heightfield_do_set_heights_region(hf, x0, y0, width, depth, heights);
}

pn_status pn_heightfield_set_placement(pn_heightfield hf, const pn_heightfield_placement *placement)
{
    ENTER(hf, PN_MAGIC_HEIGHTFIELD, "height field");
    CHECK_PTR(hf->obj.ctx, placement);
    return pn_heightfield_do_set_placement(hf, placement);
}

pn_status pn_heightfield_set_albedo(pn_heightfield hf, const float *rgb, size_t count)
{
    ENTER(hf, PN_MAGIC_HEIGHTFIELD, "height field");
    return pn_heightfield_do_set_albedo(hf, rgb, count);
}

pn_status pn_heightfield_commit(pn_heightfield hf)
{
    ENTER(hf, PN_MAGIC_HEIGHTFIELD, "height field");
    return pn_heightfield_do_commit(hf);
}

pn_status pn_heightfield_build_mesh(pn_heightfield hf, pn_mesh *out)
{
    ENTER(hf, PN_MAGIC_HEIGHTFIELD, "height field");
    CHECK_PTR(hf->obj.ctx, out);
    *out = NULL;
    RETURN_HANDLE(pn_heightfield_do_build_mesh(hf, out), out);
}

/* ------------------------------------------------------------ sphere sets */

pn_status pn_sphere_set_build(pn_mesh mesh, uint32_t count, pn_sphere_set *out)
{
    ENTER(mesh, PN_MAGIC_MESH, "mesh");
    CHECK_PTR(mesh->obj.ctx, out);
    *out = NULL;
    RETURN_HANDLE(pn_sphere_set_do_build(mesh, count, out), out);
}

pn_status pn_sphere_set_create(pn_context ctx, const float *spheres, uint32_t count, pn_sphere_set *out)
{
    ENTER(ctx, PN_MAGIC_CONTEXT, "context");
    CHECK_PTR(ctx, out);
    *out = NULL;
    if (count)
        CHECK_PTR(ctx, spheres);
    RETURN_HANDLE(pn_sphere_set_do_create(ctx, spheres, count, out), out);
}

pn_status pn_sphere_set_create_shell(pn_context ctx, pn_sphere_set *out)
{
    ENTER(ctx, PN_MAGIC_CONTEXT, "context");
    CHECK_PTR(ctx, out);
    *out = NULL;
    RETURN_HANDLE(pn_sphere_set_do_create_shell(ctx, out), out);
}

pn_status pn_sphere_set_retain(pn_sphere_set set)
{
    ENTER(set, PN_MAGIC_SPHERES, "sphere set");
    return retain(&set->obj);
}

pn_status pn_sphere_set_release(pn_sphere_set set)
{
    ENTER(set, PN_MAGIC_SPHERES, "sphere set");
    RELEASE(set);
}

pn_status pn_sphere_set_get_info(pn_sphere_set set, pn_sphere_set_info *info)
{
    ENTER(set, PN_MAGIC_SPHERES, "sphere set");
    CHECK_PTR(set->obj.ctx, info);
    pn_sphere_set_fill_info(set, info);
    return PN_SUCCESS;
}

pn_status pn_sphere_set_read(pn_sphere_set set, float *spheres, size_t bytes)
{
    ENTER(set, PN_MAGIC_SPHERES, "sphere set");
    CHECK_PTR(set->obj.ctx, spheres);
    return pn_sphere_set_do_read(set, spheres, bytes);
}

pn_status pn_sphere_set_deform(pn_sphere_set set, pn_mesh mesh)
{
    ENTER(set, PN_MAGIC_SPHERES, "sphere set");
    RESOLVE(mesh, PN_MAGIC_MESH, "mesh");
    return pn_sphere_set_do_deform(set, mesh);
}
