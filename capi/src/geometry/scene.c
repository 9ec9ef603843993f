/* Scenes: instances of meshes with transforms and materials, a camera and an
 * environment. Commit gathers the meshes' BVHs into one device buffer (only
 * when the set of meshes changed) and rebuilds the top-level BVH over the
 * instances (every commit: cheap, so rigid objects can move every frame). */
#include "geometry/geometry.h"

#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#define RECORD_FLOATS (10 * 4)

static const float identity[12] = {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0};

static void destroy_scene(pn_object *o)
{
    pn_scene scene = (pn_scene)o;
    for (uint32_t i = 0; i < scene->instance_count; ++i)
        PN_RELEASE(scene->instances[i].mesh);
    PN_RELEASE(scene->env);
    for (uint32_t i = 0; i < scene->attachment_count; ++i)
        pn_object_release(scene->attachments[i].asset);
    free(scene->attachments);
    free(scene->instances);
    free(scene->mesh_slots);
    pn_mem_release(&scene->blas);
    pn_mem_release(&scene->tris);
    pn_mem_release(&scene->normals);
    pn_mem_release(&scene->tlas);
    pn_mem_release(&scene->records);
    pn_mem_release(&scene->light_buffer);
    free(scene->lights);
}

static const pn_object_type scene_type = {PN_MAGIC_SCENE, "scene", destroy_scene, NULL};

pn_status pn_scene_new(pn_context ctx, pn_scene *out)
{
    pn_scene scene = pn_object_new(ctx, sizeof *scene, &scene_type, "a scene");
    if (!scene)
        return PN_ERROR_OUT_OF_MEMORY;
    scene->attachment_version = pn_next_version(); /* unique among scenes: methods key their plans by it */
    *out = scene;
    return PN_SUCCESS;
}

pn_status pn_scene_do_set_envmap(pn_scene scene, pn_envmap env)
{
    if (env->obj.ctx != scene->obj.ctx)
        return pn_fail(scene->obj.ctx, PN_ERROR_INVALID_ARGUMENT, "the env map belongs to a different context");
    pn_status st = pn_object_retain(&env->obj);
    if (st)
        return st;
    PN_RELEASE(scene->env);
    scene->env = env;
    return PN_SUCCESS;
}

pn_material pn_default_material(void)
{
    pn_material m = {{0.8f, 0.8f, 0.8f}, 0.0f, 100.0f, 0.3f, PN_LOBE_PHONG, 100.0f, {1.0f, 0.0f, 0.0f}};
    return m;
}

pn_status pn_validate_material(pn_context ctx, const pn_material *m)
{
    for (int c = 0; c < 3; ++c)
        if (!(m->albedo[c] >= 0.0f && m->albedo[c] <= 1.0f))
            return pn_fail(ctx, PN_ERROR_INVALID_ARGUMENT, "material albedo[%d] = %g is outside [0, 1]", c,
                           (double)m->albedo[c]);
    if (!(m->specular >= 0.0f && m->specular <= 1.0f))
        return pn_fail(ctx, PN_ERROR_INVALID_ARGUMENT, "material specular = %g is outside [0, 1]", (double)m->specular);
    if (!(m->shininess >= 0.0f && isfinite(m->shininess)))
        return pn_fail(ctx, PN_ERROR_INVALID_ARGUMENT, "material shininess = %g must be finite and >= 0",
                       (double)m->shininess);
    if (!(m->roughness > 0.0f && m->roughness <= 1.0f))
        return pn_fail(ctx, PN_ERROR_INVALID_ARGUMENT, "material roughness = %g is outside (0, 1]", (double)m->roughness);
    if (m->lobe > PN_LOBE_ASHIKHMIN_SHIRLEY)
        return pn_fail(ctx, PN_ERROR_INVALID_ARGUMENT,
                       "material lobe %u is not a pn_lobe (0 Phong, 1 Blinn-Phong, 2 GGX, 3 Ashikhmin-Shirley)", m->lobe);
    if (!(m->shininess_v >= 0.0f && isfinite(m->shininess_v)))
        return pn_fail(ctx, PN_ERROR_INVALID_ARGUMENT, "material shininess_v = %g must be finite and >= 0",
                       (double)m->shininess_v);
    if (m->lobe == PN_LOBE_ASHIKHMIN_SHIRLEY) {
        const float *t = m->tangent;
        const float len2 = t[0] * t[0] + t[1] * t[1] + t[2] * t[2];
        if (!(isfinite(len2) && len2 > 0.0f))
            return pn_fail(ctx, PN_ERROR_INVALID_ARGUMENT,
                           "material tangent = (%g, %g, %g) must be finite and nonzero for the Ashikhmin-Shirley lobe",
                           (double)t[0], (double)t[1], (double)t[2]);
    }
    return PN_SUCCESS;
}

static pn_status set_transform(pn_scene scene, pn_instance *inst, const float *transform)
{
    const float *m = transform ? transform : identity;
    float inv[12];
    if (!pn_affine_inverse(m, inv))
        return pn_fail(scene->obj.ctx, PN_ERROR_INVALID_ARGUMENT, "instance transform is %s",
                       transform && !(isfinite(m[0]) && isfinite(m[1]) && isfinite(m[2]) && isfinite(m[3]) &&
                                      isfinite(m[4]) && isfinite(m[5]) && isfinite(m[6]) && isfinite(m[7]) &&
                                      isfinite(m[8]) && isfinite(m[9]) && isfinite(m[10]) && isfinite(m[11]))
                           ? "not finite"
                           : "singular (not invertible)");
    memcpy(inst->object_to_world, m, sizeof inst->object_to_world);
    memcpy(inst->world_to_object, inv, sizeof inv);
    return PN_SUCCESS;
}

pn_status pn_scene_do_add_instance(pn_scene scene, pn_mesh mesh, const float *transform, const pn_material *material,
                                   uint32_t *id)
{
    pn_context ctx = scene->obj.ctx;
    pn_material mat = material ? *material : pn_default_material();
    pn_status st = pn_validate_material(ctx, &mat);
    if (st)
        return st;
    pn_instance inst = {0};
    if ((st = set_transform(scene, &inst, transform)))
        return st;
    if (scene->next_id == PN_BACKGROUND) /* PN_BACKGROUND marks misses: never an id */
        return pn_fail(ctx, PN_ERROR_OUT_OF_MEMORY, "the scene has given out every instance id (2^32 - 1 additions)");
    if (scene->instance_count == scene->instance_capacity) {
        uint32_t cap = scene->instance_capacity ? 2 * scene->instance_capacity : 8;
        pn_instance *grown = realloc(scene->instances, (size_t)cap * sizeof *grown);
        if (!grown)
            return pn_fail(ctx, PN_ERROR_OUT_OF_MEMORY, "out of memory adding instance %u", scene->instance_count);
        scene->instances = grown;
        scene->instance_capacity = cap;
    }
    if ((st = pn_object_retain(&mesh->obj)))
        return st;
    inst.mesh = mesh;
    inst.material = mat;
    inst.id = scene->next_id++;
    *id = inst.id;
    scene->instances[scene->instance_count++] = inst; /* ids increase: the array stays sorted */
    scene->committed = false;
    return PN_SUCCESS;
}

/* The live instance `id` (binary search: the array holds live instances only,
 * sorted by id, so a scene that adds and removes instances forever keeps
 * memory for the live ones), or NULL. */
static pn_instance *find_instance(pn_scene scene, uint32_t id)
{
    uint32_t lo = 0, hi = scene->instance_count;
    while (lo < hi) {
        const uint32_t mid = lo + (hi - lo) / 2;
        if (scene->instances[mid].id < id)
            lo = mid + 1;
        else
            hi = mid;
    }
    return lo < scene->instance_count && scene->instances[lo].id == id ? &scene->instances[lo] : NULL;
}

static pn_status live_instance(pn_scene scene, uint32_t id, pn_instance **out)
{
    if (!(*out = find_instance(scene, id)))
        return pn_fail(scene->obj.ctx, PN_ERROR_OUT_OF_RANGE, "scene has no instance %u", id);
    return PN_SUCCESS;
}

pn_status pn_scene_do_set_transform(pn_scene scene, uint32_t id, const float *transform)
{
    pn_instance *inst = NULL;
    pn_status st = live_instance(scene, id, &inst);
    if (!st && !(st = set_transform(scene, inst, transform)))
        scene->committed = false;
    return st;
}

pn_status pn_scene_do_set_material(pn_scene scene, uint32_t id, const pn_material *material)
{
    pn_instance *inst = NULL;
    pn_status st = live_instance(scene, id, &inst);
    if (!st && !(st = pn_validate_material(scene->obj.ctx, material))) {
        inst->material = *material;
        scene->committed = false;
    }
    return st;
}

pn_status pn_scene_do_remove(pn_scene scene, uint32_t id)
{
    pn_instance *inst = NULL;
    pn_status st = live_instance(scene, id, &inst);
    if (!st) {
        PN_RELEASE(inst->mesh);
        const size_t at = (size_t)(inst - scene->instances);
        memmove(inst, inst + 1, (scene->instance_count - at - 1) * sizeof *inst);
        scene->instance_count--;
        pn_scene_do_detach(scene, id, NULL);
        scene->committed = false;
    }
    return st;
}

const pn_instance *pn_scene_instance(pn_scene scene, uint32_t id)
{
    return find_instance(scene, id);
}

/* ------------------------------------------------------------ attachments */

pn_status pn_scene_do_attach(pn_scene scene, uint32_t instance, pn_object *asset)
{
    pn_context ctx = scene->obj.ctx;
    if (!asset->type->check_attach)
        return pn_fail(NULL, PN_ERROR_NULL_HANDLE, "pn_scene_attach: a %s is not an asset that attaches to a scene",
                       asset->type->name);
    if (asset->ctx != ctx)
        return pn_fail(ctx, PN_ERROR_INVALID_ARGUMENT, "pn_scene_attach: the %s belongs to another context",
                       asset->type->name);
    if (instance != PN_WHOLE_SCENE && !pn_scene_instance(scene, instance))
        return pn_fail(ctx, PN_ERROR_OUT_OF_RANGE, "pn_scene_attach: the scene has no instance %u", instance);
    pn_status st = asset->type->check_attach(asset, scene, instance);
    if (st)
        return st;
    /* Same kind on the same instance: replaced in place. */
    for (uint32_t i = 0; i < scene->attachment_count; ++i) {
        pn_attachment *a = &scene->attachments[i];
        if (a->instance == instance && a->asset->type == asset->type) {
            if ((st = pn_object_retain(asset)))
                return st;
            pn_object_release(a->asset);
            a->asset = asset;
            scene->attachment_version = pn_next_version();
            scene->committed = false;
            return PN_SUCCESS;
        }
    }
    if (scene->attachment_count == scene->attachment_capacity) {
        const uint32_t cap = scene->attachment_capacity ? 2 * scene->attachment_capacity : 8;
        pn_attachment *grown = realloc(scene->attachments, (size_t)cap * sizeof *grown);
        if (!grown)
            return pn_fail(ctx, PN_ERROR_OUT_OF_MEMORY, "out of memory attaching an asset");
        scene->attachments = grown;
        scene->attachment_capacity = cap;
    }
    /* Kept ordered by instance, so methods meet assets in instance order. */
    uint32_t at = scene->attachment_count;
    while (at > 0 && scene->attachments[at - 1].instance > instance)
        --at;
    if ((st = pn_object_retain(asset)))
        return st;
    memmove(scene->attachments + at + 1, scene->attachments + at,
            (scene->attachment_count - at) * sizeof *scene->attachments);
    scene->attachments[at].instance = instance;
    scene->attachments[at].asset = asset;
    scene->attachment_count++;
    scene->attachment_version = pn_next_version();
    scene->committed = false;
    return PN_SUCCESS;
}

pn_status pn_scene_do_detach(pn_scene scene, uint32_t instance, pn_object *asset)
{
    uint32_t kept = 0;
    for (uint32_t i = 0; i < scene->attachment_count; ++i) {
        pn_attachment a = scene->attachments[i];
        if (a.instance == instance && (!asset || a.asset == asset)) {
            pn_object_release(a.asset);
            scene->attachment_version = pn_next_version();
            scene->committed = false;
        } else {
            scene->attachments[kept++] = a;
        }
    }
    scene->attachment_count = kept;
    return PN_SUCCESS;
}

pn_status pn_scene_do_set_camera(pn_scene scene, const pn_camera *c)
{
    pn_context ctx = scene->obj.ctx;
    for (int i = 0; i < 3; ++i)
        if (!isfinite(c->position[i]) || !isfinite(c->look_at[i]) || !isfinite(c->up[i]))
            return pn_fail(ctx, PN_ERROR_INVALID_ARGUMENT, "camera position, look_at and up must be finite");
    if (!(c->fov_deg > 0.0f && c->fov_deg < 180.0f))
        return pn_fail(ctx, PN_ERROR_INVALID_ARGUMENT, "camera fov_deg = %g is outside (0, 180)", (double)c->fov_deg);
    if (c->width == 0 || c->height == 0 || c->width > 32768 || c->height > 32768)
        return pn_fail(ctx, PN_ERROR_INVALID_SIZE, "camera resolution %ux%u is outside 1..32768", c->width, c->height);
    double f[3], len = 0, cr[3], clen = 0;
    for (int i = 0; i < 3; ++i) {
        f[i] = (double)c->look_at[i] - c->position[i];
        len += f[i] * f[i];
    }
    if (len == 0.0)
        return pn_fail(ctx, PN_ERROR_INVALID_ARGUMENT, "camera look_at equals its position");
    cr[0] = f[1] * c->up[2] - f[2] * c->up[1];
    cr[1] = f[2] * c->up[0] - f[0] * c->up[2];
    cr[2] = f[0] * c->up[1] - f[1] * c->up[0];
    for (int i = 0; i < 3; ++i)
        clen += cr[i] * cr[i];
    double ulen = (double)c->up[0] * c->up[0] + (double)c->up[1] * c->up[1] + (double)c->up[2] * c->up[2];
    if (!(clen > 1e-12 * len * ulen))
        return pn_fail(ctx, PN_ERROR_INVALID_ARGUMENT, "camera up vector is zero or parallel to the view direction");
    scene->camera = *c;
    scene->has_camera = true;
    return PN_SUCCESS;
}

#define PN_MAX_LIGHTS 1024

pn_status pn_scene_do_set_lights(pn_scene scene, const pn_sphere_light *lights, uint32_t count)
{
    pn_context ctx = scene->obj.ctx;
    if (count > PN_MAX_LIGHTS)
        return pn_fail(ctx, PN_ERROR_INVALID_SIZE, "%u spherical lights is more than the %d a scene holds", count,
                       PN_MAX_LIGHTS);
    for (uint32_t i = 0; i < count; ++i) {
        const pn_sphere_light *l = &lights[i];
        bool finite = isfinite(l->radius);
        for (int c = 0; c < 3; ++c)
            finite = finite && isfinite(l->position[c]) && isfinite(l->radiance[c]);
        if (!finite)
            return pn_fail(ctx, PN_ERROR_INVALID_VALUE, "light %u has a NaN or infinite position, radius or radiance", i);
        if (!(l->radius > 0.0f))
            return pn_fail(ctx, PN_ERROR_INVALID_VALUE, "light %u has radius %g; it must be > 0", i, (double)l->radius);
        if (l->radiance[0] < 0.0f || l->radiance[1] < 0.0f || l->radiance[2] < 0.0f)
            return pn_fail(ctx, PN_ERROR_INVALID_VALUE, "light %u has a negative radiance", i);
    }
    pn_sphere_light *copy = NULL;
    if (count) {
        copy = pn_malloc(ctx, pn_mul_size(count, 1, sizeof *copy), "the light list");
        if (!copy)
            return PN_ERROR_OUT_OF_MEMORY;
        memcpy(copy, lights, count * sizeof *copy);
    }
    free(scene->lights);
    scene->lights = copy;
    scene->light_count = count;
    scene->lights_changed = true;
    scene->committed = false;
    return PN_SUCCESS;
}

/* Uploads the lights as 2 float4 each: centre, radius | radiance, 0. */
static pn_status upload_lights(pn_scene scene)
{
    pn_context ctx = scene->obj.ctx;
    const uint32_t n = scene->light_count;
    pn_mem_release(&scene->light_buffer);
    scene->committed_light_count = 0;
    float *data = pn_malloc(ctx, pn_mul_size(n ? n : 1, 8, sizeof(float)), "the light buffer");
    if (!data)
        return PN_ERROR_OUT_OF_MEMORY;
    memset(data, 0, 8 * sizeof(float));
    for (uint32_t i = 0; i < n; ++i) {
        const pn_sphere_light *l = &scene->lights[i];
        float *d = data + 8 * (size_t)i;
        memcpy(d, l->position, 3 * sizeof(float));
        d[3] = l->radius;
        memcpy(d + 4, l->radiance, 3 * sizeof(float));
        d[7] = 0.0f;
    }
    /* A one-light dummy when there are none: OpenCL buffers cannot be empty. */
    pn_status st = pn_alloc(ctx, (size_t)(n ? n : 1) * 8 * sizeof(float), CL_MEM_READ_ONLY,
                            data, &scene->light_buffer, "the light buffer");
    free(data);
    if (!st) {
        scene->committed_light_count = n;
        scene->lights_changed = false;
    }
    return st;
}

float pn_scene_scale(pn_scene scene)
{
    float s = 0.0f;
    for (int i = 0; i < 3; ++i)
        s = fmaxf(s, fmaxf(fabsf(scene->bounds_lo[i]), fabsf(scene->bounds_hi[i])));
    return s;
}

/* ----------------------------------------------------------------- commit */

/* PN_TRI_SOA (ctx->tri_soa): each leaf of a wide BLAS also gets a block of
 * PN_SOA_BLOCK_F4 float4 after the mesh's nodes: its (at most four, the
 * build's leaf size) triangles' nine vertex coordinates as float4 lanes
 * (v0.x, v0.y, v0.z, v1.x, ... v2.z; unused lanes 0) and then (first
 * triangle slot, count, 0, 0) as uint bits. The leaf's child field then
 * holds the block's float4 offset from the mesh's first node
 * (raytrace.cl, pn_leaf_soa). */
#define PN_SOA_BLOCK_F4 10

static uint32_t wide_leaf_count(const void *nodes, uint32_t node_count, int width, size_t node_size)
{
    uint32_t leaves = 0;
    for (uint32_t i = 0; i < node_count; ++i) {
        const uint32_t *cnt = (const uint32_t *)((const char *)nodes + i * node_size) + 7 * width;
        for (int j = 0; j < width; ++j)
            leaves += cnt[j] > 0;
    }
    return leaves;
}

/* Node-sized units the blocks of a mesh with `leaves` leaves take. */
static size_t soa_units(uint32_t leaves, size_t node_size)
{
    return ((size_t)leaves * PN_SOA_BLOCK_F4 * 16 + node_size - 1) / node_size;
}

/* Writes the blocks after the node_count nodes at dst and points the leaves
 * at them; leaf_tris: the mesh's triangles in leaf order (3 float4 each). */
static void write_soa_blocks(char *dst, uint32_t node_count, int width, size_t node_size, const float *leaf_tris)
{
    const uint32_t base = (uint32_t)(node_count * (node_size / 16));
    float *blocks = (float *)(dst + (size_t)node_count * node_size);
    uint32_t leaf = 0;
    for (uint32_t i = 0; i < node_count; ++i) {
        uint32_t *child = (uint32_t *)(dst + i * node_size) + 6 * width, *cnt = child + width;
        for (int j = 0; j < width; ++j) {
            if (!cnt[j])
                continue;
            float *b = blocks + 4 * PN_SOA_BLOCK_F4 * (size_t)leaf;
            memset(b, 0, 4 * PN_SOA_BLOCK_F4 * sizeof(float));
            for (uint32_t lane = 0; lane < cnt[j] && lane < 4; ++lane)
                for (int v = 0; v < 3; ++v)
                    for (int c = 0; c < 3; ++c)
                        b[4 * (3 * v + c) + lane] = leaf_tris[12 * ((size_t)child[j] + lane) + 4 * v + c];
            uint32_t ids[4] = {child[j], cnt[j], 0, 0};
            memcpy(b + 36, ids, sizeof ids);
            child[j] = base + PN_SOA_BLOCK_F4 * leaf++;
        }
    }
}

/* Concatenates the BLAS nodes, triangles and normals of every mesh in use,
 * unless the same meshes at the same versions are already on the device. */
static pn_status gather_meshes(pn_scene scene)
{
    pn_context ctx = scene->obj.ctx;
    uint32_t count = 0;
    pn_mesh_slot *slots = pn_malloc(ctx, pn_mul_size(scene->instance_count ? scene->instance_count : 1, 1, sizeof *slots),
                                    "mesh slots");
    if (!slots)
        return PN_ERROR_OUT_OF_MEMORY;
    size_t nodes = 0, tris = 0;
    bool any_normals = false;
    const int width = ctx->bvh_width;
    const size_t node_size =
        width == 8 ? sizeof(pn_bvh8_node) : width == 4 ? sizeof(pn_bvh4_node) : sizeof(pn_bvh_node);
    for (uint32_t i = 0; i < scene->instance_count; ++i) {
        pn_mesh m = scene->instances[i].mesh;
        if (!m)
            continue;
        if (!m->committed) {
            free(slots);
            return pn_fail(ctx, PN_ERROR_NOT_COMMITTED, "the mesh of instance %u changed since its last commit",
                           scene->instances[i].id);
        }
        uint32_t k = 0;
        while (k < count && slots[k].mesh != m)
            ++k;
        if (k < count)
            continue;
        slots[count].mesh = m;
        slots[count].version = m->version;
        slots[count].node_offset = (uint32_t)nodes;
        slots[count].tri_offset = (uint32_t)tris;
        nodes += width == 8 ? m->wide8.node_count : width == 4 ? m->wide.node_count : m->bvh.node_count;
        if (ctx->tri_soa)
            nodes += soa_units(width == 8 ? wide_leaf_count(m->wide8.nodes, m->wide8.node_count, 8, node_size)
                                          : wide_leaf_count(m->wide.nodes, m->wide.node_count, 4, node_size),
                               node_size);
        tris += m->triangle_count;
        any_normals = any_normals || m->leaf_normals;
        ++count;
    }
    bool same = count == scene->mesh_slot_count && scene->blas;
    for (uint32_t k = 0; same && k < count; ++k)
        same = slots[k].mesh == scene->mesh_slots[k].mesh && slots[k].version == scene->mesh_slots[k].version;
    if (same) {
        free(slots);
        return PN_SUCCESS;
    }
    if (nodes > UINT32_MAX / (node_size / 16) || tris > UINT32_MAX / 3) { /* float4 offsets in the kernels are uint */
        free(slots);
        return pn_fail(ctx, PN_ERROR_INVALID_SIZE, "scene has too many triangles (%zu)", tris);
    }
    float *hnodes = pn_malloc(ctx, pn_mul_size(nodes ? nodes : 1, 1, node_size), "scene BLAS nodes");
    float *htris = pn_malloc(ctx, pn_mul_size(tris ? tris : 1, 12, sizeof(float)), "scene triangles");
    float *hnrm = any_normals ? pn_malloc(ctx, pn_mul_size(tris, 12, sizeof(float)), "scene normals") : NULL;
    pn_status st = PN_SUCCESS;
    if (!hnodes || !htris || (any_normals && !hnrm))
        st = PN_ERROR_OUT_OF_MEMORY;
    for (uint32_t k = 0; !st && k < count; ++k) {
        pn_mesh m = slots[k].mesh;
        const void *src = width == 8 ? (const void *)m->wide8.nodes
                          : width == 4 ? (const void *)m->wide.nodes
                                       : (const void *)m->bvh.nodes;
        const uint32_t nc = width == 8 ? m->wide8.node_count : width == 4 ? m->wide.node_count : m->bvh.node_count;
        memcpy((char *)hnodes + (size_t)slots[k].node_offset * node_size, src, (size_t)nc * node_size);
        if (ctx->tri_soa)
            write_soa_blocks((char *)hnodes + (size_t)slots[k].node_offset * node_size, nc, width, node_size,
                             m->leaf_tris);
        memcpy(htris + 12 * (size_t)slots[k].tri_offset, m->leaf_tris, (size_t)m->triangle_count * 12 * sizeof(float));
        if (hnrm) {
            float *dst = hnrm + 12 * (size_t)slots[k].tri_offset;
            if (m->leaf_normals)
                memcpy(dst, m->leaf_normals, (size_t)m->triangle_count * 12 * sizeof(float));
            else
                memset(dst, 0, (size_t)m->triangle_count * 12 * sizeof(float));
        }
    }
    cl_mem blas = NULL, dtris = NULL, dnrm = NULL;
    if (!st && !(st = pn_alloc(ctx, nodes * node_size, CL_MEM_READ_ONLY, hnodes, &blas, "scene BLAS nodes")) &&
        !(st = pn_alloc(ctx, tris * 12 * sizeof(float), CL_MEM_READ_ONLY, htris, &dtris, "scene triangles")))
        st = pn_alloc(ctx, hnrm ? tris * 12 * sizeof(float) : 16, CL_MEM_READ_ONLY, hnrm, &dnrm, "scene normals");
    free(hnodes);
    free(htris);
    free(hnrm);
    if (st) {
        pn_mem_release(&blas);
        pn_mem_release(&dtris);
        pn_mem_release(&dnrm);
        free(slots);
        return st;
    }
    pn_mem_release(&scene->blas);
    pn_mem_release(&scene->tris);
    pn_mem_release(&scene->normals);
    scene->blas = blas;
    scene->tris = dtris;
    scene->normals = dnrm;
    free(scene->mesh_slots);
    scene->mesh_slots = slots;
    scene->mesh_slot_count = count;
    return PN_SUCCESS;
}

const pn_mesh_slot *pn_scene_mesh_slot(pn_scene scene, pn_mesh mesh)
{
    for (uint32_t k = 0; k < scene->mesh_slot_count; ++k)
        if (scene->mesh_slots[k].mesh == mesh)
            return &scene->mesh_slots[k];
    return NULL;
}

static void world_box(const pn_instance *inst, pn_aabb *box)
{
    const pn_mesh m = inst->mesh;
    const float *x = inst->object_to_world;
    for (int c = 0; c < 3; ++c) {
        box->lo[c] = INFINITY;
        box->hi[c] = -INFINITY;
    }
    for (int corner = 0; corner < 8; ++corner) {
        float p[3] = {corner & 1 ? m->bounds_hi[0] : m->bounds_lo[0], corner & 2 ? m->bounds_hi[1] : m->bounds_lo[1],
                      corner & 4 ? m->bounds_hi[2] : m->bounds_lo[2]};
        for (int r = 0; r < 3; ++r) {
            float w = x[4 * r] * p[0] + x[4 * r + 1] * p[1] + x[4 * r + 2] * p[2] + x[4 * r + 3];
            box->lo[r] = fminf(box->lo[r], w);
            box->hi[r] = fmaxf(box->hi[r], w);
        }
    }
    /* Pad by a few ulps: the box is of float-rounded corners, the kernels transform rays instead. */
    for (int r = 0; r < 3; ++r) {
        float pad = 1e-6f * fmaxf(fabsf(box->lo[r]), fabsf(box->hi[r])) + 1e-30f;
        box->lo[r] -= pad;
        box->hi[r] += pad;
    }
}

static pn_status ensure_buffer(pn_context ctx, cl_mem *buf, size_t *capacity, size_t bytes, const char *what)
{
    if (*buf && *capacity >= bytes)
        return PN_SUCCESS;
    pn_mem_release(buf);
    *capacity = 0;
    pn_status st = pn_alloc(ctx, bytes, CL_MEM_READ_ONLY, NULL, buf, what);
    if (!st)
        *capacity = bytes;
    return st;
}

pn_status pn_scene_do_commit(pn_scene scene)
{
    pn_context ctx = scene->obj.ctx;
    pn_status st = gather_meshes(scene);
    if (st)
        return st;
    uint32_t live = 0;
    for (uint32_t i = 0; i < scene->instance_count; ++i)
        live += scene->instances[i].mesh != NULL;
    pn_aabb *boxes = pn_malloc(ctx, pn_mul_size(live ? live : 1, 1, sizeof *boxes), "instance bounds");
    uint32_t *ids = pn_malloc(ctx, pn_mul_size(live ? live : 1, 1, sizeof *ids), "instance ids");
    float *records = pn_malloc(ctx, pn_mul_size(live ? live : 1, RECORD_FLOATS, sizeof(float)), "instance records");
    pn_bvh tlas = {0};
    if (!boxes || !ids || !records)
        st = PN_ERROR_OUT_OF_MEMORY;
    uint32_t n = 0;
    for (uint32_t i = 0; !st && i < scene->instance_count; ++i)
        if (scene->instances[i].mesh) {
            world_box(&scene->instances[i], &boxes[n]);
            ids[n++] = i;
        }
    for (int c = 0; c < 3; ++c) {
        scene->bounds_lo[c] = n ? INFINITY : 0.0f;
        scene->bounds_hi[c] = n ? -INFINITY : 0.0f;
        for (uint32_t i = 0; !st && i < n; ++i) {
            scene->bounds_lo[c] = fminf(scene->bounds_lo[c], boxes[i].lo[c]);
            scene->bounds_hi[c] = fmaxf(scene->bounds_hi[c], boxes[i].hi[c]);
        }
    }
    pn_bvh4 wide_tlas = {0};
    pn_bvh8 wide8_tlas = {0};
    if (!st && live && pn_bvh_build(boxes, live, 2, &tlas) != 0)
        st = pn_fail(ctx, PN_ERROR_OUT_OF_MEMORY, "out of memory building the instance BVH");
    /* The kernels walk the TLAS in the BLAS' layout. */
    if (!st && live && ctx->bvh_width == 4 && pn_bvh4_collapse(&tlas, &wide_tlas) != 0)
        st = pn_fail(ctx, PN_ERROR_OUT_OF_MEMORY, "out of memory building the instance BVH");
    if (!st && live && ctx->bvh_width == 8 && pn_bvh8_collapse(&tlas, &wide8_tlas) != 0)
        st = pn_fail(ctx, PN_ERROR_OUT_OF_MEMORY, "out of memory building the instance BVH");
    for (uint32_t slot = 0; !st && slot < live; ++slot) {
        const pn_instance *inst = &scene->instances[ids[tlas.order[slot]]];
        const pn_mesh_slot *ms = pn_scene_mesh_slot(scene, inst->mesh);
        float *r = records + (size_t)slot * RECORD_FLOATS;
        memcpy(r, inst->world_to_object, 12 * sizeof(float));
        memcpy(r + 12, inst->object_to_world, 12 * sizeof(float));
        memcpy(r + 24, inst->material.albedo, 3 * sizeof(float));
        r[27] = inst->material.specular;
        r[28] = inst->material.shininess;
        r[29] = inst->material.roughness;
        r[30] = (float)inst->material.lobe;
        r[31] = inst->material.shininess_v;
        /* Flags (kernels/common/raytrace.cl, PN_INST_FLAG_*): 1 vertex normals, 2 a world_to_object whose
         * linear part is exactly the identity (the walk reuses the world ray's direction). */
        const float *w = inst->world_to_object;
        const bool translation = w[0] == 1.0f && w[1] == 0.0f && w[2] == 0.0f && w[4] == 0.0f && w[5] == 1.0f &&
                                 w[6] == 0.0f && w[8] == 0.0f && w[9] == 0.0f && w[10] == 1.0f;
        uint32_t offs[4] = {ms->node_offset, ms->tri_offset,
                            (inst->mesh->leaf_normals ? 1u : 0u) | (translation ? 2u : 0u), inst->id};
        memcpy(r + 32, offs, sizeof offs);
        memcpy(r + 36, inst->material.tangent, 3 * sizeof(float));
        r[39] = 0.0f;
    }
    if (!st) {
        const int width = ctx->bvh_width;
        const void *tlas_nodes = width == 8   ? (const void *)wide8_tlas.nodes
                                 : width == 4 ? (const void *)wide_tlas.nodes
                                              : (const void *)tlas.nodes;
        const size_t node_size =
            width == 8 ? sizeof(pn_bvh8_node) : width == 4 ? sizeof(pn_bvh4_node) : sizeof(pn_bvh_node);
        const uint32_t tlas_count =
            width == 8 ? wide8_tlas.node_count : width == 4 ? wide_tlas.node_count : tlas.node_count;
        size_t tlas_bytes = (live ? (size_t)tlas_count : 1) * node_size;
        size_t rec_bytes = (size_t)(live ? live : 1) * RECORD_FLOATS * sizeof(float);
        if (!(st = ensure_buffer(ctx, &scene->tlas, &scene->tlas_capacity, tlas_bytes, "the instance BVH")) &&
            !(st = ensure_buffer(ctx, &scene->records, &scene->records_capacity, rec_bytes, "instance records"))) {
            cl_int err = CL_SUCCESS;
            if (live) {
                err = clEnqueueWriteBuffer(ctx->queue, scene->tlas, CL_TRUE, 0, tlas_bytes, tlas_nodes, 0, NULL, NULL);
                if (err == CL_SUCCESS)
                    err = clEnqueueWriteBuffer(ctx->queue, scene->records, CL_TRUE, 0, rec_bytes, records, 0, NULL, NULL);
            }
            if (err != CL_SUCCESS)
                st = pn_fail_cl(ctx, err, "uploading the instance BVH");
        }
    }
    pn_bvh_free(&tlas);
    pn_bvh4_free(&wide_tlas);
    pn_bvh8_free(&wide8_tlas);
    free(boxes);
    free(ids);
    free(records);
    /* Commits run every frame for moving objects: lights upload only when they changed. */
    if (!st && (scene->lights_changed || !scene->light_buffer))
        st = upload_lights(scene);
    if (!st) {
        scene->live_instances = live;
        scene->committed = true;
    }
    return st;
}

pn_status pn_scene_ready(pn_scene scene, bool need_env)
{
    pn_context ctx = scene->obj.ctx;
    if (!scene->committed)
        return pn_fail(ctx, PN_ERROR_NOT_COMMITTED, "scene changed since its last commit; call pn_scene_commit");
    for (uint32_t k = 0; k < scene->mesh_slot_count; ++k)
        if (!scene->mesh_slots[k].mesh->committed || scene->mesh_slots[k].version != scene->mesh_slots[k].mesh->version)
            return pn_fail(ctx, PN_ERROR_NOT_COMMITTED, "a mesh of the scene changed since the scene's last commit");
    if (need_env && !scene->env)
        return pn_fail(ctx, PN_ERROR_NOT_COMMITTED, "scene has no env map: call pn_scene_set_envmap");
    if (need_env && !scene->env->committed)
        return pn_fail(ctx, PN_ERROR_NOT_COMMITTED, "the scene's env map changed since its last commit");
    return PN_SUCCESS;
}

pn_status pn_scene_set_kernel_args(pn_scene scene, cl_kernel kernel, const char *name, cl_uint first)
{
    const cl_uint count = scene->live_instances;
    const cl_mem mems[5] = {scene->tlas, scene->records, scene->blas, scene->tris, scene->normals};
    for (cl_uint i = 0; i < 5; ++i) {
        cl_int err = clSetKernelArg(kernel, first + i, sizeof(cl_mem), &mems[i]);
        if (err != CL_SUCCESS)
            return pn_fail_cl(scene->obj.ctx, err, name);
    }
    cl_int err = clSetKernelArg(kernel, first + 5, sizeof count, &count);
    return err == CL_SUCCESS ? PN_SUCCESS : pn_fail_cl(scene->obj.ctx, err, name);
}

/* ---------------------------------------------------------------- queries */

/* Index of the first ray with a non-finite origin or direction or a NaN bound
 * (rays: 8 floats each, bounds at 3 and 7), or count when all are valid. The
 * test works on the bits, branch-free over blocks of rays, so that it
 * vectorises: the check reads every ray of every call. */
static uint32_t first_bad_ray(const float *rays, uint32_t count)
{
    enum { BLOCK = 256 };
    for (uint32_t b = 0; b < count; b += BLOCK) {
        const uint32_t e = count - b < BLOCK ? count : b + BLOCK;
        uint32_t bad = 0;
        for (uint32_t i = b; i < e; ++i)
            for (int c = 0; c < 8; ++c) {
                uint32_t bits;
                memcpy(&bits, rays + 8 * (size_t)i + c, sizeof bits);
                bits &= 0x7fffffffu;
                /* NaN: above the infinity pattern; an infinite origin or direction: equal to it. */
                bad |= (uint32_t)(bits > 0x7f800000u) | (uint32_t)(c != 3 && c != 7 && bits == 0x7f800000u);
            }
        if (bad)
            for (uint32_t i = b; i < e; ++i)
                for (int c = 0; c < 8; ++c)
                    if (isnan(rays[8 * (size_t)i + c]) || (c != 3 && c != 7 && !isfinite(rays[8 * (size_t)i + c])))
                        return i;
    }
    return count;
}

/* Index of the first ray whose origin or direction (3 floats each, separate
 * arrays) is not finite, or count: first_bad_ray's test on these fields. */
static uint32_t first_bad_vec3(const float *origins, const float *directions, uint32_t count)
{
    enum { BLOCK = 256 };
    for (uint32_t b = 0; b < count; b += BLOCK) {
        const uint32_t e = count - b < BLOCK ? count : b + BLOCK;
        uint32_t bad = 0;
        for (size_t i = 3 * (size_t)b; i < 3 * (size_t)e; ++i) {
            uint32_t o, d;
            memcpy(&o, origins + i, sizeof o);
            memcpy(&d, directions + i, sizeof d);
            /* Infinity or NaN: the exponent bits all set. */
            bad |= (uint32_t)((o & 0x7f800000u) == 0x7f800000u) | (uint32_t)((d & 0x7f800000u) == 0x7f800000u);
        }
        if (bad)
            for (uint32_t i = b; i < e; ++i)
                for (int c = 0; c < 3; ++c)
                    if (!isfinite(origins[3 * (size_t)i + c]) || !isfinite(directions[3 * (size_t)i + c]))
                        return i;
    }
    return count;
}

/* A device buffer over `bytes` of caller memory at `host`: the memory itself
 * (CL_MEM_USE_HOST_PTR, no copy; on a CPU device the kernel reads and writes
 * it in place) where `host` has the alignment the kernel's loads need, else
 * a buffer of the library's own (holding a copy of `host` when copy_in).
 * host may be NULL: a buffer of the library's own. *in_place says which. */
static pn_status query_buffer(pn_context ctx, size_t bytes, cl_mem_flags flags, const void *host, size_t align,
                              bool copy_in, cl_mem *out, bool *in_place, const char *what)
{
    *in_place = host && (uintptr_t)host % align == 0;
    if (*in_place)
        return pn_alloc(ctx, bytes, flags | CL_MEM_USE_HOST_PTR, host, out, what);
    return pn_alloc(ctx, bytes, flags, copy_in ? host : NULL, out, what);
}

/* Enqueues the transfer of the results in `mem` to `dst` without waiting:
 * a read, or for a buffer over dst itself a map (which on a CPU device
 * copies nothing; *mapped gets the pointer, to be unmapped once the queue is
 * done). The caller waits for the queue before it uses dst. */
static cl_int enqueue_result(pn_context ctx, cl_mem mem, bool in_place, void *dst, size_t bytes, void **mapped)
{
    *mapped = NULL;
    if (!in_place)
        return clEnqueueReadBuffer(ctx->queue, mem, CL_FALSE, 0, bytes, dst, 0, NULL, NULL);
    cl_int err;
    *mapped = clEnqueueMapBuffer(ctx->queue, mem, CL_FALSE, CL_MAP_READ, 0, bytes, 0, NULL, NULL, &err);
    return err;
}

pn_status pn_scene_do_query(pn_scene scene, const pn_ray_input *in, uint32_t count, float *t, uint32_t *instance,
                            uint32_t *triangle, uint8_t *occluded)
{
    pn_context ctx = scene->obj.ctx;
    pn_status st = pn_scene_ready(scene, false);
    if (st || count == 0)
        return st;
    const bool packed = in->rays != NULL;
    const uint32_t bad = packed ? first_bad_ray(in->rays, count) : first_bad_vec3(in->origins, in->directions, count);
    if (bad < count)
        return pn_fail(ctx, PN_ERROR_INVALID_VALUE, "ray %u has a non-finite origin or direction, or a NaN bound", bad);
    if (!packed && (isnan(in->tmin) || isnan(in->tmax)))
        return pn_fail(ctx, PN_ERROR_INVALID_VALUE, "the rays' tmin or tmax is NaN");
    const bool any = occluded != NULL;
    const char *name = any ? (packed ? "occluded_rays" : "occluded_ray_arrays")
                           : (packed ? "intersect_rays" : "intersect_ray_arrays");
    cl_kernel k;
    if ((st = pn_context_kernel(ctx, "raycast", name, &k)))
        return st;
    /* The rays and the result arrays are used in place where aligned (the
     * packed kernels load rays as float4, the others floats): no per-call
     * copies of them. */
    cl_mem in0 = NULL, in1 = NULL, out[3] = {NULL, NULL, NULL};
    bool in0_place = false, in1_place = false, out_place[3] = {false, false, false};
    const size_t n = count;
    if (packed)
        st = query_buffer(ctx, n * 32, CL_MEM_READ_ONLY, in->rays, 16, true, &in0, &in0_place, "rays");
    else if (!(st = query_buffer(ctx, n * 12, CL_MEM_READ_ONLY, in->origins, 4, true, &in0, &in0_place, "rays")))
        st = query_buffer(ctx, n * 12, CL_MEM_READ_ONLY, in->directions, 4, true, &in1, &in1_place, "rays");
    void *dst[3] = {any ? (void *)occluded : (void *)t, instance, triangle};
    const size_t bytes[3] = {any ? n : n * 4, n * 4, n * 4};
    for (int j = 0; !st && j < (any ? 1 : 3); ++j)
        st = query_buffer(ctx, bytes[j], CL_MEM_WRITE_ONLY, dst[j], any ? 1 : 4, false, &out[j], &out_place[j],
                          "ray results");
    const cl_int cn = (cl_int)count;
    if (!st)
        st = pn_scene_set_kernel_args(scene, k, name, 0);
    if (!st) {
        /* After the six scene arguments: packed: rays, count, outputs;
         * arrays: origins, directions, tmin, tmax, count, outputs. */
        const size_t sizes[] = {sizeof(cl_mem), sizeof(cl_mem), sizeof(float), sizeof(float), sizeof cn,
                                sizeof(cl_mem), sizeof(cl_mem), sizeof(cl_mem)};
        const void *vals[] = {&in0, &in1, &in->tmin, &in->tmax, &cn, &out[0], &out[1], &out[2]};
        cl_uint arg = 6;
        for (int i = 0; !st && i < 8; ++i) {
            if ((packed && i >= 1 && i <= 3) || (any && i >= 6))
                continue;
            cl_int err = clSetKernelArg(k, arg++, sizes[i], vals[i]);
            if (err != CL_SUCCESS)
                st = pn_fail_cl(ctx, err, "setting ray query arguments");
        }
    }
    if (!st)
        st = pn_enqueue_1d(ctx, k, name, n, 64);
    /* The results: every transfer enqueued without waiting, then one wait
     * for the queue (each blocking transfer would be a round trip of its
     * own through the device's scheduler). */
    cl_int err = CL_SUCCESS;
    void *mapped[3] = {NULL, NULL, NULL};
    for (int j = 0; !st && err == CL_SUCCESS && j < (any ? 1 : 3); ++j)
        if (dst[j])
            err = enqueue_result(ctx, out[j], out_place[j], dst[j], bytes[j], &mapped[j]);
    bool moved = false;
    for (int j = 0; j < 3; ++j)
        moved |= mapped[j] && mapped[j] != dst[j];
    if (moved) {
        /* A map that did not return the caller's memory itself: copy once the maps are done. */
        cl_int e = clFinish(ctx->queue);
        err = err == CL_SUCCESS ? e : err;
        for (int j = 0; err == CL_SUCCESS && j < 3; ++j)
            if (mapped[j] && mapped[j] != dst[j])
                memcpy(dst[j], mapped[j], bytes[j]);
    }
    for (int j = 0; j < 3; ++j)
        if (mapped[j]) {
            cl_int e = clEnqueueUnmapMemObject(ctx->queue, out[j], mapped[j], 0, NULL, NULL);
            err = err == CL_SUCCESS ? e : err;
        }
    /* Nothing may still use the caller's memory when the call returns. */
    cl_int e = clFinish(ctx->queue);
    err = err == CL_SUCCESS ? e : err;
    if (!st && err != CL_SUCCESS)
        st = pn_fail_cl(ctx, err, "reading ray query results");
    pn_mem_release(&in0);
    pn_mem_release(&in1);
    for (int j = 0; j < 3; ++j)
        pn_mem_release(&out[j]);
    return st;
}

pn_status pn_scene_do_render_gbuffer(pn_scene scene, pn_gbuffer gb)
{
    pn_context ctx = scene->obj.ctx;
    pn_status st = pn_scene_ready(scene, false);
    if (st)
        return st;
    if (!scene->has_camera)
        return pn_fail(ctx, PN_ERROR_NOT_COMMITTED, "scene has no camera: call pn_scene_set_camera");
    const pn_camera *c = &scene->camera;
    if (gb->width != c->width || gb->height != c->height)
        return pn_fail(ctx, PN_ERROR_INVALID_SIZE, "G-buffer is %ux%u but the camera renders %ux%u", gb->width,
                       gb->height, c->width, c->height);
    double f[3], r[3], u[3];
    for (int i = 0; i < 3; ++i)
        f[i] = (double)c->look_at[i] - c->position[i];
    double fl = sqrt(f[0] * f[0] + f[1] * f[1] + f[2] * f[2]);
    for (int i = 0; i < 3; ++i)
        f[i] /= fl;
    r[0] = f[1] * c->up[2] - f[2] * c->up[1];
    r[1] = f[2] * c->up[0] - f[0] * c->up[2];
    r[2] = f[0] * c->up[1] - f[1] * c->up[0];
    double rl = sqrt(r[0] * r[0] + r[1] * r[1] + r[2] * r[2]);
    for (int i = 0; i < 3; ++i)
        r[i] /= rl;
    u[0] = r[1] * f[2] - r[2] * f[1];
    u[1] = r[2] * f[0] - r[0] * f[2];
    u[2] = r[0] * f[1] - r[1] * f[0];
    const double tx = tan(c->fov_deg * 3.14159265358979323846 / 360.0), ty = tx * c->height / c->width;
    cl_float4 org = {{c->position[0], c->position[1], c->position[2], 0}};
    cl_float4 fwd = {{(float)f[0], (float)f[1], (float)f[2], 0}};
    cl_float4 right = {{(float)(r[0] * tx), (float)(r[1] * tx), (float)(r[2] * tx), 0}};
    cl_float4 up = {{(float)(u[0] * ty), (float)(u[1] * ty), (float)(u[2] * ty), 0}};
    const cl_int w = (cl_int)c->width, h = (cl_int)c->height;
    cl_kernel k;
    if ((st = pn_context_kernel(ctx, "raycast", "gbuffer_primary", &k)) ||
        (st = pn_scene_set_kernel_args(scene, k, "gbuffer_primary", 0)))
        return st;
    size_t sizes[] = {16, 16, 16, 16, sizeof w, sizeof h, sizeof(cl_mem), sizeof(cl_mem), sizeof(cl_mem),
                      sizeof(cl_mem), sizeof(cl_mem)};
    const void *vals[] = {&org, &fwd, &right, &up, &w, &h, &gb->planes[0], &gb->planes[1], &gb->planes[2],
                          &gb->planes[3], &gb->planes[4]};
    for (cl_uint i = 0; i < 11; ++i) {
        cl_int err = clSetKernelArg(k, 6 + i, sizes[i], vals[i]);
        if (err != CL_SUCCESS)
            return pn_fail_cl(ctx, err, "setting G-buffer kernel arguments");
    }
    size_t local[2] = {8, 8};
    size_t global[2] = {(c->width + 7) / 8 * 8, (c->height + 7) / 8 * 8};
    cl_int err = clEnqueueNDRangeKernel(ctx->queue, k, 2, NULL, global, local, 0, NULL, NULL);
    return err == CL_SUCCESS ? PN_SUCCESS : pn_fail_cl(ctx, err, "enqueueing the primary-ray kernel");
}

cl_float4 pn_scene_camera_position(pn_scene scene)
{
    cl_float4 c = {{scene->camera.position[0], scene->camera.position[1], scene->camera.position[2], 0.0f}};
    return c;
}
