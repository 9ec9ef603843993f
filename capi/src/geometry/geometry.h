/* The geometry layer: meshes (validation, BVH), scenes (instances, camera,
 * lights, the two-level BVH, ray queries, the G-buffer) and the generic
 * attachment of technique assets to instances. It knows no technique: an
 * asset is any object whose type has check_attach. */
#ifndef PENUMBRA_GEOMETRY_H
#define PENUMBRA_GEOMETRY_H

#include "core/core.h"
#include "geometry/bvh.h"

/* ------------------------------------------------------------------- mesh */

struct pn_mesh_impl {
    pn_object obj;
    float *positions;        /* 3 per vertex */
    float *normals;          /* 3 per vertex or NULL */
    uint32_t *indices;       /* 3 per triangle */
    uint32_t vertex_count, triangle_count;
    bool committed;
    uint64_t version;        /* a new pn_next_version() at each commit */
    uint64_t content_hash;   /* of positions and indices (commit) */
    pn_bvh bvh;
    pn_bvh4 wide;            /* bvh collapsed to 4-wide nodes, for contexts with PENUMBRA_BVH_WIDTH=4 only */
    pn_bvh8 wide8;           /* 8-wide nodes: what the kernels walk by default */
    float bounds_lo[3], bounds_hi[3];
    /* Triangles in BVH leaf order, gathered by every scene that uses the mesh. */
    float *leaf_tris;        /* 12 floats per triangle (3 float4) */
    float *leaf_normals;     /* 12 floats per triangle, or NULL */
};

pn_status pn_mesh_new(pn_context ctx, pn_mesh *out);
pn_status pn_mesh_do_set_geometry(pn_mesh mesh, const float *positions, uint32_t vertex_count,
                                  const uint32_t *indices, uint32_t triangle_count, const float *normals);
pn_status pn_mesh_do_commit(pn_mesh mesh);
pn_status pn_mesh_do_read_geometry(pn_mesh mesh, float *positions, uint32_t *indices, float *normals);

/* ------------------------------------------------------------------ scene */

typedef struct pn_instance {
    pn_mesh mesh;
    uint32_t id;             /* as returned by pn_scene_add_instance (never reused) */
    float object_to_world[12];
    float world_to_object[12];
    pn_material material;
} pn_instance;

typedef struct pn_mesh_slot {
    pn_mesh mesh;
    uint64_t version;
    uint32_t node_offset, tri_offset;
} pn_mesh_slot;

/* One asset attached to one instance (or PN_WHOLE_SCENE). */
typedef struct pn_attachment {
    uint32_t instance;
    pn_object *asset;        /* retained */
} pn_attachment;

struct pn_scene_impl {
    pn_object obj;
    pn_envmap env;
    pn_instance *instances;  /* the live instances only, in increasing id order */
    uint32_t instance_count, instance_capacity;
    uint32_t next_id;        /* ids are 0, 1, 2, ... in order of addition */
    pn_camera camera;
    bool has_camera;
    bool committed;
    /* Device data built at commit. */
    pn_mesh_slot *mesh_slots;
    uint32_t mesh_slot_count;
    cl_mem blas, tris, normals;   /* concatenated per-mesh data, rebuilt when meshes change */
    cl_mem tlas, records;         /* rebuilt at every commit */
    size_t tlas_capacity, records_capacity;
    uint32_t live_instances;
    float bounds_lo[3], bounds_hi[3]; /* world bounds of the live instances at commit */
    pn_sphere_light *lights;          /* set by pn_scene_set_lights, uploaded at commit */
    uint32_t light_count, committed_light_count;
    bool lights_changed;              /* set_lights since the last upload */
    cl_mem light_buffer;              /* 2 float4 per light: centre, radius | radiance, 0 */
    pn_attachment *attachments;       /* ordered by instance, then by attach order */
    uint32_t attachment_count, attachment_capacity;
    uint64_t attachment_version;      /* a new pn_next_version() at each change of the list */
};

pn_status pn_scene_new(pn_context ctx, pn_scene *out);
pn_status pn_scene_do_set_envmap(pn_scene scene, pn_envmap env);
pn_status pn_scene_do_add_instance(pn_scene scene, pn_mesh mesh, const float *transform,
                                   const pn_material *material, uint32_t *id);
pn_status pn_scene_do_set_transform(pn_scene scene, uint32_t id, const float *transform);
pn_status pn_scene_do_set_material(pn_scene scene, uint32_t id, const pn_material *material);
pn_status pn_scene_do_remove(pn_scene scene, uint32_t id);
pn_status pn_scene_do_set_camera(pn_scene scene, const pn_camera *camera);
pn_status pn_scene_do_set_lights(pn_scene scene, const pn_sphere_light *lights, uint32_t count);
pn_status pn_scene_do_attach(pn_scene scene, uint32_t instance, pn_object *asset);
pn_status pn_scene_do_detach(pn_scene scene, uint32_t instance, pn_object *asset);
/* The live instance `id`, or NULL (with no error recorded). */
const pn_instance *pn_scene_instance(pn_scene scene, uint32_t id);
/* The committed scene's slot of `mesh` (its node and triangle offsets), or NULL. */
const pn_mesh_slot *pn_scene_mesh_slot(pn_scene scene, pn_mesh mesh);
/* The camera position as a kernel argument (w = 0). */
cl_float4 pn_scene_camera_position(pn_scene scene);
/* Largest absolute coordinate of the committed scene's bounds (0 when empty). */
float pn_scene_scale(pn_scene scene);
pn_status pn_scene_do_commit(pn_scene scene);
/* Checks the scene and everything it uses is committed. */
pn_status pn_scene_ready(pn_scene scene, bool need_env);
/* Sets the six scene arguments (tlas ... instance count) starting at `first`. */
pn_status pn_scene_set_kernel_args(pn_scene scene, cl_kernel kernel, const char *name, cl_uint first);
/* The rays of a query: packed (8 floats per ray) when `rays` is set, else
 * origins and directions (3 floats per ray) with one tmin and tmax. */
typedef struct pn_ray_input {
    const float *rays;
    const float *origins, *directions;
    float tmin, tmax;
} pn_ray_input;
pn_status pn_scene_do_query(pn_scene scene, const pn_ray_input *in, uint32_t count, float *t, uint32_t *instance,
                            uint32_t *triangle, uint8_t *occluded);
pn_status pn_scene_do_render_gbuffer(pn_scene scene, pn_gbuffer gbuffer);
pn_material pn_default_material(void);
pn_status pn_validate_material(pn_context ctx, const pn_material *m);

#endif
