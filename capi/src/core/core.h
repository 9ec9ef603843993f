/* The core layer: object heads and lifetimes, errors, the context (device,
 * programs, kernels, per-context caches), device buffers, env maps, G-buffers
 * and images, and small utilities. It knows no geometry and no technique.
 * Nothing here is exported: capi/src/api.c is the only file with public entry
 * points. Every failure is reported through pn_fail() and never aborts. */
#ifndef PENUMBRA_CORE_H
#define PENUMBRA_CORE_H

#include "penumbra.h"

#include <pthread.h>
#include <stdatomic.h>
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
    PN_MAGIC_SPHERES = 0x504e5350,
    PN_MAGIC_DEAD = 0x44454144,
    PN_MAGIC_ANY = 0 /* pn_call_enter / pn_call_resolve: any kind of object */
};

/* Every reference an object may hold in all (the caller's, other objects',
 * calls in progress); the headroom above it is for the calls' pins. */
#define PN_REFS_MAX (INT32_MAX - (1 << 20))

typedef struct pn_object pn_object;

/* What every object of one kind shares: its tag, its name in messages, how it
 * is destroyed and, for technique assets, where it may be attached. */
typedef struct pn_object_type {
    uint32_t magic;
    const char *name;                 /* "occlusion field" */
    void (*destroy)(pn_object *object); /* frees what the object owns; pn_object_release frees the object */
    /* Assets only (NULL for other kinds): checks that `asset` may attach to
     * instance `instance` of `scene` (PN_WHOLE_SCENE: the scene itself). */
    pn_status (*check_attach)(const pn_object *asset, pn_scene scene, uint32_t instance);
} pn_object_type;

/* Common head of every object: type tag, reference counts, handle, owning
 * context (core/objects.c describes handles and lifetimes). */
struct pn_object {
    uint32_t magic;
    atomic_int refs;     /* every reference: the caller's, other objects', calls' pins */
    atomic_int public_refs; /* the caller's (create, retain, release); the handle is valid while > 0 */
    void *handle;           /* what the caller holds (index and generation of a slot, freed at destruction) */
    pn_context ctx;
    const pn_object_type *type;
};

/* A zeroed object of `size` bytes (head included) of `type`, holding one
 * reference to its context, registered with a handle; NULL (error recorded)
 * when out of memory. */
void *pn_object_new(pn_context ctx, size_t size, const pn_object_type *type, const char *what);
/* Fills the head of an object made without pn_object_new (the context) and registers its handle. */
pn_status pn_object_setup(pn_object *object, pn_context ctx, const pn_object_type *type);
/* The handle the caller holds for an object (what a create function returns). */
void *pn_object_handle(const pn_object *object);
/* A reference held inside the library (a scene's mesh); fails, changing
 * nothing, when the object holds PN_REFS_MAX references. */
pn_status pn_object_retain(pn_object *object);
/* Drops a reference; the last one destroys the object, then releases the
 * context it held (objects keep their context alive). NULL is ignored. */
void pn_object_release(pn_object *object);
/* The caller's references (pn_*_retain / pn_*_release): saturating at
 * PN_REFCOUNT_MAX; the last release makes the handle invalid at once, even
 * while the library still holds the object. Under the context's lock. */
pn_status pn_object_public_retain(pn_object *object);
void pn_object_public_release(pn_object *object);

/* One exported call in progress: the context whose lock it holds. */
typedef struct pn_call {
    pn_context ctx;
} pn_call;
/* Resolves the first handle of a call: *handle (what the caller passed) must
 * be a live object of kind `magic` (PN_MAGIC_ANY: any), else
 * PN_ERROR_NULL_HANDLE (NULL, wrong kind) or PN_ERROR_INVALID_HANDLE (released,
 * or never created), recorded in the global slot with `func` and `arg` named.
 * On success *handle is the object, its context is locked (recursive) and
 * kept alive until pn_call_leave. */
pn_status pn_call_enter(pn_call *call, void **handle, uint32_t magic, const char *kind, const char *func,
                        const char *arg);
/* pn_call_enter for pn_get_error: also accepts a context whose handle the
 * caller released while objects of it still live (its errors stay readable). */
pn_status pn_call_enter_released(pn_call *call, void **handle, uint32_t magic, const char *kind, const char *func,
                                 const char *arg);
/* Resolves another handle of the same call; it must belong to the call's context. */
pn_status pn_call_resolve(pn_call *call, void **handle, uint32_t magic, const char *kind, const char *func,
                          const char *arg);
void pn_call_leave(pn_call *call);
#define PN_RELEASE(handle) pn_object_release((handle) ? &(handle)->obj : NULL)
/* One entry of a parameter table (a method's, or a bake's options): the
 * library's single statement of a parameter's name, type, default, range,
 * unit and meaning, which the public metadata (pn_method_get_param) returns. */
typedef struct pn_param_desc {
    const char *name;
    uint32_t type;            /* pn_param_type */
    uint32_t stage;           /* pn_param_stage */
    double fallback, lo, hi;  /* default and inclusive range */
    const char *unit, *doc;
} pn_param_desc;

/* The index of `name` in a table, or -1. */
int pn_param_find(const pn_param_desc *table, int count, const char *name);
/* Checks `value` against table[i] (finite, in range, whole for ints); the
 * message names `owner` and the parameter. */
pn_status pn_param_check(pn_context ctx, const char *owner, const pn_param_desc *p, double value);

/* A process-wide unique, increasing stamp for commits and attachment changes. */
uint64_t pn_next_version(void);

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
#define PN_MAX_CACHES 8

typedef struct pn_program_entry {
    const char *stage;
    cl_program program;
} pn_program_entry;

typedef struct pn_kernel_entry {
    const char *name;
    cl_kernel kernel;
} pn_kernel_entry;

/* Host data a layer above keeps per context (e.g. a method's float64 tables,
 * shared by every renderer of the context), found by the address of a static
 * key of the owner and freed with the context. */
typedef struct pn_cache_entry {
    const void *key;
    void *data;
    void (*free_data)(void *data);
} pn_cache_entry;

struct pn_context_impl {
    pn_object obj;
    pthread_mutex_t lock; /* recursive: every call on the context's objects holds it (pn_call_enter) */
    uint64_t serial; /* keys the per-thread error slots */
    cl_context cl_ctx;
    cl_command_queue queue;
    cl_device_id device;
    char build_options[512];
    int bvh_width; /* 4, or 2 for the binary BVH layout, 8 for the 8-wide one (PENUMBRA_BVH_WIDTH) */
    int tri_soa;   /* wide layouts: leaf triangles as 4-lane SoA blocks (default; PENUMBRA_TRI_SOA=0 off; -DPN_TRI_SOA) */
    pn_error_callback callback;
    void *callback_user;
    pn_program_entry programs[PN_MAX_PROGRAMS];
    int program_count;
    pn_kernel_entry kernels[PN_MAX_KERNELS];
    int kernel_count;
    pn_cache_entry caches[PN_MAX_CACHES];
    int cache_count;
};

pn_status pn_context_new(const char *config, cl_context cl_ctx, cl_command_queue queue, pn_context *out);
pn_status pn_context_program(pn_context ctx, const char *stage, cl_program *out);
/* The cached kernel `name` of program `stage`. */
pn_status pn_context_kernel(pn_context ctx, const char *stage, const char *name, cl_kernel *out);
/* The context's cache entry of `key` (NULL when there is none). */
void *pn_context_cache(pn_context ctx, const void *key);
/* Stores `data` under `key`; the context frees it with free_data. */
pn_status pn_context_set_cache(pn_context ctx, const void *key, void *data, void (*free_data)(void *data));
/* A read-only table of `floats` floats that `fill` writes on the host, uploaded
 * once per context and cached under `key` (the context owns it). */
pn_status pn_context_table(pn_context ctx, const void *key, size_t floats, void (*fill)(float *out),
                           const char *what, cl_mem *out);
/* Sets kernel arguments from a list of (size, pointer) pairs. */
pn_status pn_set_args(pn_context ctx, cl_kernel kernel, const char *name, int count, const size_t *sizes,
                      const void *const *values);
pn_status pn_enqueue_1d(pn_context ctx, cl_kernel kernel, const char *name, size_t items, size_t local);
/* host: copied into the new buffer (CL_MEM_COPY_HOST_PTR), or used in place
 * when flags hold CL_MEM_USE_HOST_PTR. */
pn_status pn_alloc(pn_context ctx, size_t bytes, cl_mem_flags flags, const void *host, cl_mem *out,
                   const char *what);
/* Enqueues a copy of `bytes` host bytes into `buffer` without waiting: the
 * library keeps its own copy until the transfer is done (execute-time uploads). */
pn_status pn_upload_async(pn_context ctx, cl_mem buffer, const void *host, size_t bytes, const char *what);
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
    /* The last decomposition (core/env_domains.c) and what it was made of. */
    struct pn_env_decomposition *decomposition;
    uint64_t decomposition_hash; /* content_hash it was made from */
    uint32_t decomposition_seed, decomposition_iterations;
    /* The last split decomposition (sharp part + residual; pn_envmap_domains_split) and its key. */
    struct pn_env_decomposition *split;
    uint64_t split_hash;
    uint32_t split_count, split_seed, split_iterations, split_sharp;
    float split_threshold;
};

pn_status pn_envmap_new(pn_context ctx, pn_envmap *out);
pn_status pn_envmap_do_set_latlong(pn_envmap env, const float *rgb, uint32_t width, uint32_t height);
pn_status pn_envmap_param_int(pn_envmap env, const char *name, int32_t *value, bool set);
pn_status pn_envmap_param_float(pn_envmap env, const char *name, float *value, bool set);
pn_status pn_envmap_do_commit(pn_envmap env);
pn_status pn_envmap_do_read(pn_envmap env, pn_envmap_data what, void *host, size_t bytes);
/* Resamples the committed env map onto a cube of face `face` (the commit's
 * area-averaging filter) and reads back 6*face*face float4 radiance and
 * float4 direction + solid angle; either output may be NULL. */
pn_status pn_envmap_sample_cube(pn_envmap env, int face, float *radiance, float *directions);
/* Enqueues the background of an image of `count` pixels: each pixel whose
 * instance is PN_BACKGROUND gets the committed env map's radiance in its view
 * direction (the position plane), bilinear in the lat-long map, alpha 0
 * (kernels/envmap.cl, envmap_background). Other pixels are untouched. */
pn_status pn_envmap_enqueue_background(pn_envmap env, cl_mem position, cl_mem instance, uint32_t count, cl_mem image);
/* (cos, sin) of the env map's rotation about +y, as the background pass and
 * the kernels that draw the background themselves take it. */
cl_float2 pn_envmap_rotation(pn_envmap env);
/* Env directions as records of 2 float4 (direction, solid angle | radiance, 0):
 * cube face f, black texels dropped, texels of power >= threshold x the
 * brightest split into s x s sub-texels. *records is malloc'ed. */
pn_status pn_envmap_direction_records(pn_envmap env, int f, int s, float threshold, float **records, size_t *count);

/* ------------------------------------------------ environment domains */

#define PN_ENV_DOMAINS_MAX 1024
#define PN_ENV_LLOYD_DEFAULT_ITERATIONS 100

/* The decomposition of a committed env map into directional domains
 * (core/env_domains.c, pn_envmap_decompose): `count` domains, and for the
 * sharp-part extraction the domain of every lat-long texel. */
struct pn_env_decomposition {
    uint32_t count;
    pn_env_domain *domains;   /* count */
    int32_t *assignment;      /* width*height, row-major, the domain of each texel */
    uint32_t iterations;      /* Lloyd iterations run */
    bool converged;           /* no texel changed cell at the last iteration */
    uint32_t sharp;           /* pn_envmap_domains_split: the first `sharp` domains are the sharp part (else 0) */
};
typedef struct pn_env_decomposition pn_env_decomposition;

/* The method's plan-time entry point: checks options (as pn_envmap_decompose)
 * and returns the env map's cached decomposition for them, computing it when
 * the env content, N, seed or iteration cap changed. *out stays owned by the
 * env map and valid until its next decomposition with other options or its
 * next commit (copy what you keep). */
pn_status pn_envmap_domains(pn_envmap env, const pn_env_decompose_options *options, const pn_env_decomposition **out);
/* pn_envmap_decompose: the domains copied to `domains` (capacity >= count). */
pn_status pn_envmap_do_decompose(pn_envmap env, const pn_env_decompose_options *options, pn_env_domain *domains,
                                 uint32_t capacity);
/* pn_envmap_extract_sharp (core/env_domains.c). */
#define PN_ENV_SHARP_MAX 64
pn_status pn_envmap_do_extract_sharp(pn_envmap env, const pn_env_sharp_options *options, pn_env_domain *domains,
                                     uint32_t capacity, uint32_t *count, float *residual, size_t residual_floats);
/* The N domains of pn_envmap_domains with the map's sharp part given its
 * own domains (depthmap's `sharp`, docs/depthmap.md): the sharp part of
 * pn_envmap_extract_sharp at `threshold` with at most `sharp_max` domains
 * (the first (*out)->sharp domains: the excess over T, the solid angle of the
 * hot texels), then the residual map decomposed into the other
 * N - (*out)->sharp. sharp_max must be below N; a map without texels above T
 * gives the plain decomposition (sharp 0). Cached per (content, N, seed,
 * max_iterations, sharp_max, threshold) in its own slot; assignment is NULL.
 * *out as pn_envmap_domains'. */
pn_status pn_envmap_domains_split(pn_envmap env, const pn_env_decompose_options *options, uint32_t sharp_max,
                                  float threshold, const pn_env_decomposition **out);
/* Frees the cached decompositions (env map destruction). */
void pn_envmap_forget_domains(pn_envmap env);

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
pn_status pn_gbuffer_transfer(pn_gbuffer gbuffer, pn_gbuffer_plane plane, void *host, size_t bytes, bool write);
pn_status pn_gbuffer_do_validate(pn_gbuffer gbuffer);
pn_status pn_image_new(pn_context ctx, uint32_t width, uint32_t height, cl_mem buffer, pn_image *out);
pn_status pn_image_do_read(pn_image image, float *host, size_t bytes);
/* Fails with PN_ERROR_INVALID_SIZE if `bytes` is smaller than `needed`. */
pn_status pn_check_cl_buffer(pn_context ctx, cl_mem buffer, size_t needed, const char *what);

/* ------------------------------------------------------------------ utils */

/* n-point Gauss–Legendre nodes x and weights w on [-1, 1] (Newton on the recurrence). */
void pn_gauss_legendre(int n, double *x, double *w);

/* The cap on every allocation sized by input: PENUMBRA_MAX_BYTES (bytes, or
 * with a suffix K/M/G/T), default PN_DEFAULT_MAX_BYTES. pn_check_bytes fails
 * with PN_ERROR_INVALID_SIZE naming `what`, the size and the limit when
 * `bytes` exceeds it (SIZE_MAX: a product that overflowed, pn_mul_size), and
 * with PN_ERROR_BAD_CONFIG when the variable is not a byte count. */
#define PN_DEFAULT_MAX_BYTES ((size_t)(SIZE_MAX > 0xFFFFFFFFu ? 8ull << 30 : 0x7FFFFFFFu))
pn_status pn_check_bytes(pn_context ctx, size_t bytes, const char *what);
/* malloc under the cap (an error recorded either way when it fails). */
void *pn_malloc(pn_context ctx, size_t bytes, const char *what);
/* a * b * c without overflow, or SIZE_MAX. */
size_t pn_mul_size(size_t a, size_t b, size_t c);
/* 3x4 row-major affine inverse; false if singular or not finite. */
bool pn_affine_inverse(const float m[12], float inv[12]);
/* s when m is a translation times s * identity (s > 0, 1e-5 relative), else 0. */
float pn_uniform_scale(const float m[12]);
#define PN_HASH_SEED 0xcbf29ce484222325ull
/* FNV-1a 64 of `bytes` bytes, continuing from `hash` (start with PN_HASH_SEED). */
uint64_t pn_hash_bytes(uint64_t hash, const void *data, size_t bytes);

#endif
