/* Internal declarations shared by libpenumbra's sources. Nothing here is
 * exported: capi/src/api.c is the only file with public entry points; it
 * checks handles and arguments and calls the functions declared below, which
 * report every failure through pn_fail() and never abort. */
#ifndef PENUMBRA_INTERNAL_H
#define PENUMBRA_INTERNAL_H

#include "penumbra.h"
#include "bvh.h"

#include <stdbool.h>

/* ---------------------------------------------------------------- objects */

enum {
    PN_MAGIC_CONTEXT = 0x504e4358,  /* "PNCX" */
    PN_MAGIC_ENVMAP = 0x504e454e,
    PN_MAGIC_MESH = 0x504e4d45,
    PN_MAGIC_SCENE = 0x504e5343,
    PN_MAGIC_GBUFFER = 0x504e4742,
    PN_MAGIC_IMAGE = 0x504e494d,
    PN_MAGIC_RENDERER = 0x504e5245,
    PN_MAGIC_FIV = 0x504e4656,
    PN_MAGIC_HEIGHTFIELD = 0x504e4846,
    PN_MAGIC_DEAD = 0x44454144
};

/* Common head of every handle: type tag, reference count, owning context. */
typedef struct pn_object {
    uint32_t magic;
    int32_t refcount;
    pn_context ctx;
} pn_object;

/* ----------------------------------------------------------------- errors */

/* Records an error for ctx (NULL: the thread's global slot), calls the
 * context's callback and returns `status`, so callers can `return pn_fail(...)`. */
pn_status pn_fail(pn_context ctx, pn_status status, const char *fmt, ...)
#if defined(__GNUC__)
    __attribute__((format(printf, 3, 4)))
#endif
    ;

/* Turns an OpenCL error into a recorded one naming what was being done. */
pn_status pn_fail_cl(pn_context ctx, cl_int err, const char *what);

/* Forgets the calling thread's error slot of a context being destroyed. */
void pn_error_forget(uint64_t context_serial);

/* Clears the slot before a call so pn_get_error reports this call's error only. */
void pn_error_clear(pn_context ctx);
/* Reads and clears the slot (pn_get_error). */
pn_status pn_error_take(pn_context ctx, const char **message);
const char *pn_status_name_of(pn_status status);

/* ---------------------------------------------------------------- context */

#define PN_MAX_PROGRAMS 16
#define PN_MAX_KERNELS 48

typedef struct pn_program_entry {
    const char *stage;
    cl_program program;
} pn_program_entry;

typedef struct pn_kernel_entry {
    const char *name;
    cl_kernel kernel;
} pn_kernel_entry;

/* Host SH tables of the heightfield method (sh_tables.c), kept per context:
 * computed once in float64, shared by every renderer of the context. */
#define PN_SH_CACHE 16
typedef struct pn_sh_cache_entry {
    int n_phi, bands, kind;   /* kind: 0 env wedges, 1 light wedges, 2 triple product (n_phi 0) */
    void *data;               /* float table or double tensor */
    uint64_t stamp;           /* operation that last used it: never evicted during that operation */
} pn_sh_cache_entry;

struct pn_context_impl {
    pn_object obj;
    uint64_t serial; /* keys the per-thread error slots */
    cl_context cl_ctx;
    cl_command_queue queue;
    cl_device_id device;
    char build_options[512];
    pn_error_callback callback;
    void *callback_user;
    pn_program_entry programs[PN_MAX_PROGRAMS];
    int program_count;
    pn_kernel_entry kernels[PN_MAX_KERNELS];
    int kernel_count;
    pn_sh_cache_entry sh_cache[PN_SH_CACHE];
    int sh_cache_next;        /* round-robin slot to reuse when full */
    uint64_t sh_operation;    /* pn_sh_cache_begin count */
};

pn_status pn_context_new(const char *config, cl_context cl_ctx, cl_command_queue queue, pn_context *out);
void pn_context_destroy(pn_context ctx);
pn_status pn_context_program(pn_context ctx, const char *stage, cl_program *out);
/* The cached kernel `name` of program `stage`. */
pn_status pn_context_kernel(pn_context ctx, const char *stage, const char *name, cl_kernel *out);
/* Sets kernel arguments from a list of (size, pointer) pairs. */
pn_status pn_set_args(pn_context ctx, cl_kernel kernel, const char *name, int count, const size_t *sizes,
                      const void *const *values);
pn_status pn_enqueue_1d(pn_context ctx, cl_kernel kernel, const char *name, size_t items, size_t local);
pn_status pn_alloc(pn_context ctx, size_t bytes, cl_mem_flags flags, const void *host, cl_mem *out,
                   const char *what);
void pn_mem_release(cl_mem *mem);

/* Embedded kernel sources (generated from kernels/ by CMake). */
typedef struct pn_kernel_file {
    const char *path; /* relative to kernels/, e.g. "common/math.cl" */
    const char *source;
} pn_kernel_file;
extern const pn_kernel_file pn_kernel_files[];
extern const size_t pn_kernel_file_count;

/* ------------------------------------------------------------ environment */

struct pn_envmap_impl {
    pn_object obj;
    cl_mem latlong;          /* width*height*3 floats */
    uint32_t width, height;
    int32_t face_size, irradiance_face_size, supersampling;
    float rotation_deg, intensity;
    bool committed;
    uint64_t version;        /* a new pn_next_version() at each commit */
    uint64_t data_hash;      /* of the lat-long texels (set_latlong) */
    uint64_t content_hash;   /* data_hash + rotation, intensity, supersampling (commit) */
    int32_t committed_face_size, committed_irradiance_size;
    cl_mem cube;             /* 6*F*F float4 radiance */
    cl_mem dirs;             /* 6*F*F float4 direction + solid angle */
    cl_mem irradiance;       /* 6*M*M float4 */
};

void pn_envmap_destroy(pn_envmap env);
pn_status pn_envmap_do_set_latlong(pn_envmap env, const float *rgb, uint32_t width, uint32_t height);
pn_status pn_envmap_param_int(pn_envmap env, const char *name, int32_t *value, bool set);
pn_status pn_envmap_param_float(pn_envmap env, const char *name, float *value, bool set);
pn_status pn_envmap_do_commit(pn_envmap env);
pn_status pn_envmap_do_read(pn_envmap env, pn_envmap_data what, void *host, size_t bytes);
/* Resamples the committed env map onto a cube of face `face` (the commit's
 * area-averaging filter) and reads back 6*face*face float4 radiance and
 * float4 direction + solid angle; either output may be NULL. */
pn_status pn_envmap_sample_cube(pn_envmap env, int face, float *radiance, float *directions);
/* Env directions as records of 2 float4 (direction, solid angle | radiance, 0):
 * cube face f, black texels dropped, texels of power >= threshold x the
 * brightest split into s x s sub-texels. *records is malloc'ed. */
pn_status pn_envmap_direction_records(pn_envmap env, int f, int s, float threshold, float **records, size_t *count);

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
    float bounds_lo[3], bounds_hi[3];
    /* Triangles in BVH leaf order, gathered by every scene that uses the mesh. */
    float *leaf_tris;        /* 12 floats per triangle (3 float4) */
    float *leaf_normals;     /* 12 floats per triangle, or NULL */
};

void pn_mesh_destroy(pn_mesh mesh);
pn_status pn_mesh_do_set_geometry(pn_mesh mesh, const float *positions, uint32_t vertex_count,
                                  const uint32_t *indices, uint32_t triangle_count, const float *normals);
pn_status pn_mesh_do_commit(pn_mesh mesh);
/* A process-wide unique version stamp for a mesh or env map commit. */
uint64_t pn_next_version(void);

/* ------------------------------------------------------------------ scene */

typedef struct pn_instance {
    pn_mesh mesh;            /* NULL: removed slot */
    float object_to_world[12];
    float world_to_object[12];
    pn_material material;
} pn_instance;

typedef struct pn_mesh_slot {
    pn_mesh mesh;
    uint64_t version;
    uint32_t node_offset, tri_offset;
} pn_mesh_slot;

struct pn_scene_impl {
    pn_object obj;
    pn_envmap env;
    pn_instance *instances;
    uint32_t instance_count, instance_capacity;
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
    pn_fiv *fivs;                     /* occlusion fields (retained), one per mesh */
    uint32_t fiv_count;
    uint64_t fiv_version;             /* a new pn_next_version() at each pn_scene_set_fivs */
    pn_heightfield *hfs;              /* height fields (retained) and the instance each one is */
    uint32_t *hf_instances;
    uint32_t hf_count;
};

void pn_scene_destroy(pn_scene scene);
pn_status pn_scene_do_add_instance(pn_scene scene, pn_mesh mesh, const float *transform,
                                   const pn_material *material, uint32_t *id);
pn_status pn_scene_do_set_transform(pn_scene scene, uint32_t id, const float *transform);
pn_status pn_scene_do_set_material(pn_scene scene, uint32_t id, const pn_material *material);
pn_status pn_scene_do_remove(pn_scene scene, uint32_t id);
pn_status pn_scene_do_set_camera(pn_scene scene, const pn_camera *camera);
pn_status pn_scene_do_set_lights(pn_scene scene, const pn_sphere_light *lights, uint32_t count);
/* Largest absolute coordinate of the committed scene's bounds (0 when empty). */
float pn_scene_scale(pn_scene scene);
pn_status pn_scene_do_commit(pn_scene scene);
/* Checks the scene and everything it uses is committed. */
pn_status pn_scene_ready(pn_scene scene, bool need_env);
/* Sets the six scene arguments (tlas ... instance count) starting at `first`. */
pn_status pn_scene_set_kernel_args(pn_scene scene, cl_kernel kernel, const char *name, cl_uint first);
pn_status pn_scene_do_query(pn_scene scene, const float *rays, uint32_t count, float *t, uint32_t *instance,
                            uint32_t *triangle, uint8_t *occluded);
pn_status pn_scene_do_render_gbuffer(pn_scene scene, pn_gbuffer gbuffer);
pn_status pn_validate_material(pn_context ctx, const pn_material *m);

/* ------------------------------------------------------- G-buffer, image */

struct pn_gbuffer_impl {
    pn_object obj;
    uint32_t width, height;
    cl_mem planes[PN_GBUFFER_PLANE_COUNT];
};

struct pn_image_impl {
    pn_object obj;
    uint32_t width, height;
    cl_mem buffer;
};

pn_status pn_gbuffer_new(pn_context ctx, uint32_t width, uint32_t height, const cl_mem *planes, pn_gbuffer *out);
void pn_gbuffer_destroy(pn_gbuffer gbuffer);
pn_status pn_gbuffer_transfer(pn_gbuffer gbuffer, pn_gbuffer_plane plane, void *host, size_t bytes, bool write);
pn_status pn_gbuffer_do_validate(pn_gbuffer gbuffer);
pn_status pn_image_new(pn_context ctx, uint32_t width, uint32_t height, cl_mem buffer, pn_image *out);
void pn_image_destroy(pn_image image);
pn_status pn_image_do_read(pn_image image, float *host, size_t bytes);
/* Fails with PN_ERROR_INVALID_SIZE if `bytes` is smaller than `needed`. */
pn_status pn_check_cl_buffer(pn_context ctx, cl_mem buffer, size_t needed, const char *what);

/* ------------------------------------------------------ occlusion fields */

struct pn_fiv_impl {
    pn_object obj;
    pn_fiv_options options;
    float centre[3], radius;  /* bounding sphere, object space */
    float inner, outer;       /* innermost and outermost sphere radii, object units */
    uint64_t mesh_hash, env_hash;
    uint32_t mesh_vertices, mesh_triangles;
    uint32_t radii_done;      /* spheres baked so far (a bake in progress) */
    float value_scale;        /* half storage holds value / value_scale */
    float outer_max;          /* largest |FIV| of a channel on the outer sphere (culling bound) */
    float *samples;           /* radii x theta x phi x 9 floats, NaN inside; rounded through half if stored so */
    uint64_t inside_count, rays;
    double bake_seconds;
};

pn_status pn_fiv_check_options(pn_context ctx, const pn_fiv_options *options);
pn_status pn_fiv_new(pn_context ctx, const pn_fiv_options *options, pn_fiv *out);
void pn_fiv_destroy(pn_fiv fiv);
uint64_t pn_fiv_sample_count(const pn_fiv_options *options);
/* Radius of sphere k (geometric from inner to outer). */
float pn_fiv_radius(pn_fiv fiv, uint32_t k);
uint16_t pn_half_from_float(float value);
float pn_float_from_half(uint16_t half);
pn_status pn_fiv_do_get_info(pn_fiv fiv, pn_fiv_info *info);
pn_status pn_fiv_do_read(pn_fiv fiv, float *host, size_t bytes);
pn_status pn_fiv_do_bake(pn_envmap env, pn_mesh mesh, const pn_fiv_options *options, const char *path,
                         pn_progress_callback progress, void *user, pn_fiv *out);
/* Bake files (fiv_file.c). pn_fiv_read_file loads `path` into a new field;
 * with `partial` an unfinished bake is accepted. */
pn_status pn_fiv_read_file(pn_context ctx, const char *path, bool partial, pn_fiv *out);
pn_status pn_fiv_write_file(pn_fiv fiv, const char *path);
pn_status pn_scene_do_set_fivs(pn_scene scene, const pn_fiv *fields, uint32_t count);
void pn_scene_release_fivs(pn_scene scene);

/* What a `fiv` renderer keeps between frames. */
typedef struct pn_fiv_cache {
    cl_mem data;              /* the scene's fields concatenated as stored */
    uint32_t *offsets;        /* byte offset of each field in `data` */
    uint64_t list_version;    /* scene->fiv_version that `data` holds */
    uint64_t env_version;     /* env map that env_fiv / env_ref describe */
    float env_fiv[9];         /* FIV(Env): X rgb, Y rgb, Z rgb */
    float env_ref;            /* reference irradiance for culling */
    float *records;           /* host occluder records, 16 floats each */
    size_t records_capacity, device_capacity;
    cl_mem device_records;
} pn_fiv_cache;

typedef struct pn_fiv_frame {
    cl_mem occluders, fields;
    uint32_t occluder_count;
} pn_fiv_frame;

/* Checks the fields match the scene's env map and every occluder instance
 * only translates and scales uniformly, uploads what changed, and returns
 * this frame's occluder records. */
pn_status pn_fiv_prepare(pn_fiv_cache *cache, pn_scene scene, float cull_threshold, pn_fiv_frame *frame);
void pn_fiv_cache_release(pn_fiv_cache *cache);

/* ------------------------------------------------------------ height fields */

#define PN_SH_MAX_BANDS 6
#define PN_SH_WEDGE_ANGLES 64  /* horizon angles per axis of a wedge table */
#define PN_HF_MAX_FIELDS 16
#define PN_HF_MAX_SUN 256   /* sun texels lit as directional lights */

struct pn_heightfield_impl {
    pn_object obj;
    uint32_t width, depth;    /* columns (x), rows (z) */
    float *heights;           /* width * depth, row-major */
    float *albedo;            /* width * depth * 3, or NULL (white) */
    pn_heightfield_placement placement;
    bool committed;
    uint64_t version;         /* a new pn_next_version() at each commit */
    float hmin, hmax;         /* of the heights, at commit */
};

void pn_heightfield_destroy(pn_heightfield hf);
pn_status pn_heightfield_do_set_heights(pn_heightfield hf, const float *heights, uint32_t width, uint32_t depth);
pn_status pn_heightfield_do_set_placement(pn_heightfield hf, const pn_heightfield_placement *placement);
pn_status pn_heightfield_do_set_albedo(pn_heightfield hf, const float *rgb, size_t count);
pn_status pn_heightfield_do_commit(pn_heightfield hf);
pn_status pn_heightfield_do_build_mesh(pn_heightfield hf, pn_mesh mesh);
pn_status pn_scene_do_set_heightfields(pn_scene scene, const pn_heightfield *fields, const uint32_t *instances,
                                       uint32_t count);
void pn_scene_release_heightfields(pn_scene scene);

/* Float64 SH tables (sh_tables.c). */
void pn_sh_eval64(int nb, double cos_polar, double sin_polar, double phi, double *out);
void pn_sh_clamped_cosine64(int nb, double *a);
/* The context's cached tables, owned by the context. A pointer stays valid
 * until the next pn_sh_cache_begin (call it at the start of each operation
 * that fetches tables; entries used since then are never evicted). */
void pn_sh_cache_begin(pn_context ctx);
pn_status pn_sh_wedge_table(pn_context ctx, int n_phi, int nb, bool light, const float **out);
pn_status pn_sh_triple_product(pn_context ctx, int nb, const double **out);
void pn_sh_cache_release(pn_context ctx);

/* The `heightfield` method's parameters. */
typedef struct pn_hf_settings {
    int level_step, azimuths, bands, exact, exact_unoccluded, light_visibility, reconstruction;
    float level_offset, light_threshold, sun_threshold;
} pn_hf_settings;

/* Per bound field: the pyramid and per-vertex outputs. */
typedef struct pn_hf_state {
    uint64_t version;         /* field version the pyramid holds (0: none) */
    int level_step, reconstruction;
    cl_int4 grid;             /* W, D, levels, level offset in samples */
    cl_float8 geom;           /* x0, y0, z0, sx, sz, level step, s0, 0 */
    size_t pyramid_floats;
    bool has_albedo;
    uint32_t light_capacity;
    cl_mem pyr, levels, normals, albedo, out_env, out_lights, out_total;
} pn_hf_state;

typedef struct pn_hf_cache {
    pn_hf_state fields[PN_HF_MAX_FIELDS];
    int tables_nphi, tables_nb;
    cl_mem env_table, light_table;
    int gamma_nb, gamma_count;
    cl_mem gamma_index, gamma_value;
    uint64_t m_env_version;
    int m_nb, m_nphi;
    float m_sun;              /* sun_threshold the env data was split with */
    cl_mem sun;               /* PN_HF_MAX_SUN at most: 2 float4 per sun texel */
    int sun_count;
    cl_mem m;                 /* 3 x nc x nc */
    float u[3 * PN_SH_MAX_BANDS * PN_SH_MAX_BANDS]; /* Hᵀ M per channel (exact_unoccluded) */
    cl_mem u_buf;
    cl_mem up_irradiance;     /* irradiance map of the env's upper half */
    int up_size;
    float env_ref;            /* π x the env's mean radiance */
    uint32_t lights_culled;   /* light passes skipped in the last frame */
    /* What the per-vertex outputs were last computed for: reads of the same
     * state reuse them (pn_renderer_execute always recomputes: a frame). */
    bool outputs_valid;
    pn_hf_settings outputs_settings;
    uint64_t outputs_env, outputs_fields[PN_HF_MAX_FIELDS];
    pn_sphere_light *outputs_lights;
    uint32_t outputs_light_count, outputs_field_count;
} pn_hf_cache;

pn_status pn_hf_execute(pn_hf_cache *c, pn_scene scene, const pn_hf_settings *set, pn_gbuffer gb, pn_image image);
pn_status pn_hf_read(pn_hf_cache *c, pn_scene scene, const pn_hf_settings *set, uint32_t field,
                     pn_heightfield_output what, uint32_t light, float *host, size_t bytes);
void pn_hf_cache_release(pn_hf_cache *c);

/* --------------------------------------------------------------- renderer */

typedef struct pn_method pn_method;

#define PN_MAX_METHOD_PARAMS 12

struct pn_renderer_impl {
    pn_object obj;
    const pn_method *method;
    float params[PN_MAX_METHOD_PARAMS]; /* by the method's parameter table; ints stored exactly */
    bool committed;
    /* `reference`: direction records built from the env map, reused while
     * the env map and the parameters that shape them stay the same. */
    cl_mem dir_records;
    uint32_t dir_record_count;
    uint64_t dir_env_version;
    float dir_key[3];                   /* face size, sun supersampling, sun threshold */
    pn_fiv_cache fiv;                   /* `fiv`: fields, FIV(Env), occluder records */
    pn_hf_cache hf;                     /* `heightfield`: tables, pyramids, per-vertex outputs */
};

uint32_t pn_renderer_method_count(void);
const char *pn_renderer_method_name(uint32_t index);
pn_status pn_renderer_new(pn_context ctx, const char *method, pn_renderer *out);
void pn_renderer_destroy(pn_renderer renderer);
pn_status pn_renderer_param_int(pn_renderer r, const char *name, int32_t *value, bool set);
pn_status pn_renderer_param_float(pn_renderer r, const char *name, float *value, bool set);
pn_status pn_renderer_do_execute(pn_renderer r, pn_scene scene, pn_gbuffer gbuffer, pn_image image);
pn_status pn_renderer_do_read_heightfield(pn_renderer r, pn_scene scene, uint32_t field, pn_heightfield_output what,
                                          uint32_t light, float *host, size_t bytes);

/* ------------------------------------------------------------------ utils */

void *pn_malloc(pn_context ctx, size_t bytes, const char *what);
/* a * b * c without overflow, or SIZE_MAX. */
size_t pn_mul_size(size_t a, size_t b, size_t c);
/* 3x4 row-major affine inverse; false if singular or not finite. */
bool pn_affine_inverse(const float m[12], float inv[12]);
#define PN_HASH_SEED 0xcbf29ce484222325ull
/* FNV-1a 64 of `bytes` bytes, continuing from `hash` (start with PN_HASH_SEED). */
uint64_t pn_hash_bytes(uint64_t hash, const void *data, size_t bytes);

#endif
