/* penumbra — environment lighting with soft shadows for dynamic scenes.
 *
 * Public C API. Conventions (docs/api.md has one section per function):
 *  - Every function returns a pn_status; PN_SUCCESS is 0. Negative values in
 *    [-999, -1] are OpenCL error codes passed through unchanged; the library's
 *    own codes start at -1001.
 *  - The message of the last error is kept per context and per thread and read
 *    (and cleared) with pn_get_error(). Errors that cannot be tied to a context
 *    (a NULL handle, a failed context creation) go to the thread's global slot:
 *    pn_get_error(NULL, ...).
 *  - Objects are opaque, reference counted handles: *_create gives a handle
 *    with one reference, *_retain adds one, *_release drops one; the last
 *    release of a context waits for its queued work.
 *  - Configure -> commit -> execute: setters only record; *_commit validates,
 *    uploads and builds; execution only enqueues work. An object changed after
 *    its commit is unusable (PN_ERROR_NOT_COMMITTED) until committed again.
 *  - OpenCL objects handed in by the caller (context, queue, buffers) are
 *    borrowed: retained while penumbra holds them, never copied.
 *  - A context and the objects created on it may be used by one thread at a
 *    time; different contexts are independent.
 */
#ifndef PENUMBRA_H
#define PENUMBRA_H

#include <stddef.h>
#include <stdint.h>

#ifndef CL_TARGET_OPENCL_VERSION
#define CL_TARGET_OPENCL_VERSION 120
#endif
#ifdef __APPLE__
#include <OpenCL/cl.h>
#else
#include <CL/cl.h>
#endif

#ifdef __cplusplus
extern "C" {
#endif

#if defined(_WIN32) && defined(PENUMBRA_BUILDING)
#define PN_API __declspec(dllexport)
#elif defined(__GNUC__)
#define PN_API __attribute__((visibility("default")))
#else
#define PN_API
#endif

#define PN_VERSION_MAJOR 0
#define PN_VERSION_MINOR 1
#define PN_VERSION_PATCH 0

typedef int32_t pn_status;

enum {
    PN_SUCCESS = 0,
    PN_ERROR_NULL_HANDLE = -1001,      /* a handle argument is NULL or not of the expected kind */
    PN_ERROR_INVALID_ARGUMENT = -1002, /* an argument is out of its documented domain */
    PN_ERROR_INVALID_SIZE = -1003,     /* a size or byte count does not match what is required */
    PN_ERROR_INVALID_VALUE = -1004,    /* data holds NaN/Inf or a value out of range (e.g. negative radiance) */
    PN_ERROR_OUT_OF_RANGE = -1005,     /* an index refers past the end of an array */
    PN_ERROR_EMPTY_INPUT = -1006,      /* no vertices, no triangles, zero-sized image */
    PN_ERROR_BAD_CONFIG = -1007,       /* a configuration string or parameter name is not understood */
    PN_ERROR_BUILD_FAILED = -1008,     /* an OpenCL program failed to build; the message has the log */
    PN_ERROR_NOT_COMMITTED = -1009,    /* the object (or one it uses) changed and was not committed */
    PN_ERROR_OUT_OF_MEMORY = -1010,    /* a host allocation failed */
    PN_ERROR_NO_DEVICE = -1011,        /* no OpenCL device matches the request */
    PN_ERROR_UNSUPPORTED = -1012,      /* valid request the chosen method or device cannot do */
    PN_ERROR_CANCELLED = -1013,        /* a progress callback asked to stop (a checkpoint was kept) */
    PN_ERROR_FILE = -1014,             /* a file cannot be read or written, or is corrupt or foreign */
    PN_ERROR_INVALID_HANDLE = -1015,   /* a handle was released already (or never created): see docs/reliability.md */
    PN_ERROR_INTERNAL = -1099
};

/* Marks background pixels in PN_GBUFFER_INSTANCE and misses in pn_scene_intersect. */
#define PN_BACKGROUND 0xFFFFFFFFu

/* Handles (docs/reliability.md). A handle is an opaque value naming a slot
 * of a process-wide table and its generation, never an address: a handle that
 * was released (its last pn_*_release) or never created is answered with
 * PN_ERROR_INVALID_HANDLE, never by reading freed memory. Objects the library
 * holds (a scene's meshes) stay alive after the caller's last release, but the
 * caller's handle is invalid from then on. Each object accepts at most
 * PN_REFCOUNT_MAX references from the caller; a retain beyond it fails with
 * PN_ERROR_OUT_OF_RANGE and changes nothing.
 *
 * Threads: every call is safe from any thread. Calls on the objects of one
 * context are serialised by a mutex of that context (the error callback and
 * progress callbacks run under it and may call back into the library);
 * objects of different contexts run in parallel. */
#define PN_REFCOUNT_MAX 16777215

typedef struct pn_context_impl *pn_context;
typedef struct pn_envmap_impl *pn_envmap;
typedef struct pn_mesh_impl *pn_mesh;
typedef struct pn_scene_impl *pn_scene;
typedef struct pn_gbuffer_impl *pn_gbuffer;
typedef struct pn_image_impl *pn_image;
typedef struct pn_renderer_impl *pn_renderer;
typedef struct pn_fiv_impl *pn_fiv;
typedef struct pn_heightfield_impl *pn_heightfield;
typedef struct pn_sphere_set_impl *pn_sphere_set;

/* ---------------------------------------------------------------- errors */

/* Returns the last error status recorded for `ctx` on the calling thread (or
 * the thread's global slot for ctx == NULL) and clears it. *message (may be
 * NULL) receives a sentence describing it, valid until the next penumbra call
 * on this thread; "" when there is no error. */
PN_API pn_status pn_get_error(pn_context ctx, const char **message);

typedef void (*pn_error_callback)(void *user, pn_status status, const char *message);

/* Calls `callback` (NULL to remove) for every error recorded on `ctx`, on the
 * thread that made the failing call, before that call returns. */
PN_API pn_status pn_context_set_error_callback(pn_context ctx, pn_error_callback callback, void *user);

/* A static, human-readable name for a status code ("PN_ERROR_INVALID_VALUE"). */
PN_API const char *pn_status_name(pn_status status);

/* "0.1.0" */
PN_API const char *pn_version(void);

/* --------------------------------------------------------------- context */

/* Creates a context on a device of its own choosing. `config` (may be NULL) is
 * a comma-separated list of key=value pairs:
 *   device=default|cpu|gpu|accelerator|N   (N: index among the platform's devices)
 *   platform=SUBSTRING                    (case-insensitive match on the platform name)
 *   build_options=...                     (appended to every kernel build; no commas)
 * When config does not name a device, the environment variable PENUMBRA_DEVICE
 * (same values as device=) is used; when neither does, a CPU device is
 * preferred (PoCL on machines without a GPU). PENUMBRA_CL_BUILD_OPTIONS is
 * appended to every build. */
PN_API pn_status pn_context_create(const char *config, pn_context *out);

/* Wraps the caller's context and in-order queue (both retained, not copied). */
PN_API pn_status pn_context_create_from_cl(cl_context cl_ctx, cl_command_queue queue, const char *config,
                                           pn_context *out);
PN_API pn_status pn_context_retain(pn_context ctx);
PN_API pn_status pn_context_release(pn_context ctx);

/* Borrows the context's OpenCL objects (not retained for the caller). */
PN_API pn_status pn_context_get_cl(pn_context ctx, cl_context *cl_ctx, cl_command_queue *queue,
                                   cl_device_id *device);

/* Writes the device name (NUL-terminated, truncated to `size`). */
PN_API pn_status pn_context_get_device_name(pn_context ctx, char *name, size_t size);

/* Waits for all work queued by penumbra on this context. */
PN_API pn_status pn_context_finish(pn_context ctx);

/* Builds (once, then cached in the context) the program of one kernel stage,
 * a top-level file kernels/<stage>.cl: "envmap", "raycast", "fiv_bake" and
 * every method's stage (pn_method_info.stage). Building is otherwise lazy; this lets a
 * caller pay the cost up front. A failed build returns PN_ERROR_BUILD_FAILED
 * with the compiler log in the message. */
PN_API pn_status pn_context_build_program(pn_context ctx, const char *stage);

/* ----------------------------------------------------------- environment */

/* Parameters (pn_envmap_set_int / _float), applied at commit:
 *   "face_size"            int   cube map face size in texels, 1..2048   (default 64)
 *   "irradiance_face_size" int   irradiance map face size, 2..256        (default 32)
 *   "supersampling"        int   sub-samples per cube texel side, 0 = auto (default 0)
 *   "rotation_deg"         float rotation of the map about +y            (default 0)
 *   "intensity"            float radiance scale, >= 0                    (default 1)
 */
PN_API pn_status pn_envmap_create(pn_context ctx, pn_envmap *out);
PN_API pn_status pn_envmap_retain(pn_envmap env);
PN_API pn_status pn_envmap_release(pn_envmap env);

/* Sets the lat-long radiance map: width*height RGB float triples, row 0 at the
 * top (+y). Copied. Refused (PN_ERROR_INVALID_VALUE) when any texel is NaN,
 * infinite or negative; the message counts them and gives the first position. */
PN_API pn_status pn_envmap_set_latlong(pn_envmap env, const float *rgb, uint32_t width, uint32_t height);
PN_API pn_status pn_envmap_set_int(pn_envmap env, const char *name, int32_t value);
PN_API pn_status pn_envmap_set_float(pn_envmap env, const char *name, float value);
PN_API pn_status pn_envmap_get_int(pn_envmap env, const char *name, int32_t *value);
PN_API pn_status pn_envmap_get_float(pn_envmap env, const char *name, float *value);

/* Converts the lat-long map on the device into a cube map (area-correct
 * filtering), its per-texel directions and solid angles, and the irradiance
 * cube map E(n) = sum over texels of L * max(0, n.w) * dw. */
PN_API pn_status pn_envmap_commit(pn_envmap env);

typedef enum pn_envmap_data {
    PN_ENVMAP_CUBE_RADIANCE = 0,  /* 6*F*F float4: RGB radiance, w = 0 */
    PN_ENVMAP_CUBE_DIRECTIONS = 1,/* 6*F*F float4: unit direction of the texel centre, w = solid angle */
    PN_ENVMAP_IRRADIANCE = 2      /* 6*M*M float4: RGB irradiance at the vertex-grid directions, w = 0 */
} pn_envmap_data;

/* Reads committed data to host memory; `bytes` must equal the data's size. */
PN_API pn_status pn_envmap_read(pn_envmap env, pn_envmap_data what, void *host, size_t bytes);

/* 64-bit content hash of the committed lighting: the lat-long texels, rotation,
 * intensity and supersampling (not the cube sizes). Occlusion fields record it. */
PN_API pn_status pn_envmap_get_hash(pn_envmap env, uint64_t *hash);

/* Directional domains of an env map (docs/depthmap.md, "Decomposition"):
 * the sphere split into N cells, each lit as one directional light. */
typedef struct pn_env_domain {
    float direction[3];   /* unit centre direction (world space, the map's rotation applied), towards the light */
    float solid_angle;    /* of the domain's texels, sr */
    float radiance[3];    /* total incoming radiance L~: sum of texel radiance x solid angle (intensity applied) */
    float cap_radius;     /* equivalent cap half-angle r (rad): solid_angle = 2 pi (1 - cos r) */
} pn_env_domain;          /* 32 bytes, also the device layout (two float4) */

typedef struct pn_env_decompose_options {
    uint32_t count;          /* N, 1..1024 */
    uint32_t seed;           /* the draw is deterministic for a given seed (32 bits: the twin's counter is seed * 2^32 + texel) */
    uint32_t max_iterations; /* Lloyd iterations cap (0 = the library's default, 100) */
} pn_env_decompose_options;

/* count 64, seed 1, max_iterations 0. */
PN_API pn_env_decompose_options pn_env_decompose_options_default(void);

/* Splits the committed env map into options->count directional domains
 * (Barsi, Szirmay-Kalos, Szecsi): N distinct lat-long texels drawn with
 * probability proportional to luminance x solid angle (Efraimidis-Spirakis
 * keys from splitmix64 of (seed, texel)), spread by weighted Lloyd relaxation
 * on the sphere (every texel to its nearest centre on the device, centres to
 * their cells' weighted mean direction) until no texel changes cell or
 * max_iterations passes; then per domain its centre, the sum of L x dw of its
 * texels, its solid angle and equivalent cap radius. Every texel (black ones
 * too) is in exactly one domain: the radiances sum to the map's power and the
 * solid angles to 4 pi. Works on the lat-long texels themselves (not the
 * resampled cube), so a one-texel sun keeps its exact power and position.
 * Deterministic for a given seed on a given device; the result is cached per
 * (env content, N, seed, max_iterations) until the next commit.
 * Writes `count` domains to `domains`, in no particular order. Errors:
 * PN_ERROR_NULL_HANDLE (env), PN_ERROR_NOT_COMMITTED (the map changed since
 * its commit), PN_ERROR_INVALID_ARGUMENT (options or domains NULL, count 0 or
 * > 1024, max_iterations > 10000, count larger than the map's non-black
 * texels: the message names both numbers and says when the map is black),
 * PN_ERROR_INVALID_SIZE (capacity < count). */
PN_API pn_status pn_envmap_decompose(pn_envmap env, const pn_env_decompose_options *options, pn_env_domain *domains,
                                     uint32_t capacity);

/* The sharp part of an env map: its concentrated light (a sun, a few lamps)
 * as at most max_count domains, for depth-map shadows, and the rest as a
 * residual lat-long map for a smooth-lighting method (FIV, ISG). */
typedef struct pn_env_sharp_options {
    uint32_t max_count;      /* most sharp domains, 1..64 */
    float threshold;         /* a texel is sharp where its luminance exceeds threshold x the map's mean luminance, > 1 */
    uint32_t seed;           /* of the decomposition of the sharp texels */
    uint32_t max_iterations; /* its Lloyd cap (0 = the default, 100) */
} pn_env_sharp_options;

/* max_count 4, threshold 100, seed 1, max_iterations 0. */
PN_API pn_env_sharp_options pn_env_sharp_options_default(void);

/* Splits the committed map into sharp domains and a residual map with
 * residual + sharp part = the map: every texel whose luminance exceeds
 * T = threshold x the mean luminance (sum over texels of luminance x dw, over
 * 4 pi) keeps luminance T in the residual (its colour unchanged) and gives its
 * excess to the sharp part: the residual has no hole where the sun was, its
 * range is bounded by T, and no light is lost or counted twice. The excess is
 * split into min(max_count, its texel count) domains by the decomposition of
 * pn_envmap_decompose (so a large or bright source may take several); a
 * domain's radiance is its excess L~, its solid angle and cap radius those of
 * its sharp texels (the source's own size). Directions and radiance as in
 * pn_envmap_decompose (world space, intensity applied); `residual` is
 * width*height RGB floats in the input's frame and units (before rotation and
 * intensity), so an env map made of it with the same rotation_deg and
 * intensity lights the rest. A map with no texel above T (overcast, constant,
 * black) gives *count = 0 and residual = the map. Errors:
 * PN_ERROR_NOT_COMMITTED, PN_ERROR_INVALID_ARGUMENT (NULL pointers, max_count
 * outside 1..64, threshold not finite or <= 1, max_iterations > 10000),
 * PN_ERROR_INVALID_SIZE (capacity < max_count, residual_floats not
 * width*height*3). */
PN_API pn_status pn_envmap_extract_sharp(pn_envmap env, const pn_env_sharp_options *options, pn_env_domain *domains,
                                         uint32_t capacity, uint32_t *count, float *residual, size_t residual_floats);
/* ---------------------------------------------------- spherical Gaussians */

/* One spherical-Gaussian (SG) light lobe (docs/isg.md 1). */
typedef struct pn_sg_lobe {
    float axis[3];       /* unit */
    float sharpness;     /* lambda > 0 */
    float amplitude[3];  /* RGB: G(v) = amplitude * exp(lambda (v.axis - 1)) */
    float pad;           /* 0 */
} pn_sg_lobe;            /* 32 bytes, the device layout */

/* Floats in the ISG table (4 blocks of 57 x 33; layout in kernels/common/sg.cl). */
#define PN_ISG_TABLE_FLOATS 7524

/* Fills `out` (`count` must be PN_ISG_TABLE_FLOATS) with the table that the
 * device's pn_isg reads: the normalised Integral Spherical Gaussian's exact
 * marginals by float64 quadrature (docs/isg.md 3). No context needed. */
PN_API pn_status pn_isg_table(float *out, size_t count);

/* Options of the env map -> SG lobe fit (docs/isg.md 5). */
typedef struct pn_sg_fit_options {
    int32_t face_size;     /* cube face the map is resampled to for the fit, 4..256 (default 32) */
    int32_t iterations;    /* least-squares refinement sweeps after the power clustering, 0..100 (default 0) */
    float max_sharpness;   /* cap on lambda; 0 = 4 face_size^2 (no lobe narrower than half a texel) (default 0) */
} pn_sg_fit_options;

#define PN_SG_FIT_MAX_LOBES 128

PN_API pn_sg_fit_options pn_sg_fit_options_default(void);

/* Fits `count` (1..PN_SG_FIT_MAX_LOBES) SG lobes to the committed env map
 * (rotation and intensity applied) by solid-angle-weighted least squares with
 * non-negative RGB amplitudes, and writes them to out[0 .. count) (`capacity`
 * lobes available). Deterministic. A lobe may have zero amplitude (a black
 * map gives only such lobes). `options` may be NULL (the defaults). */
PN_API pn_status pn_envmap_fit_sgs(pn_envmap env, uint32_t count, const pn_sg_fit_options *options, pn_sg_lobe *out,
                                   size_t capacity);

/* ------------------------------------------------------------------ mesh */

PN_API pn_status pn_mesh_create(pn_context ctx, pn_mesh *out);
PN_API pn_status pn_mesh_retain(pn_mesh mesh);
PN_API pn_status pn_mesh_release(pn_mesh mesh);

/* positions: 3 floats per vertex; indices: 3 per triangle; normals: NULL or 3
 * floats per vertex (interpolated as shading normals). Copied and validated:
 * no vertices or triangles (PN_ERROR_EMPTY_INPUT), an index >= vertex_count
 * (PN_ERROR_OUT_OF_RANGE), NaN/Inf coordinates (PN_ERROR_INVALID_VALUE).
 * Degenerate (zero-area) triangles are accepted; rays never hit them. */
PN_API pn_status pn_mesh_set_geometry(pn_mesh mesh, const float *positions, uint32_t vertex_count,
                                      const uint32_t *indices, uint32_t triangle_count, const float *normals);

/* Builds the BVH (binned SAH) on the host; scenes that use the mesh upload it
 * at their next pn_scene_commit (and must be committed again after this). */
PN_API pn_status pn_mesh_commit(pn_mesh mesh);

typedef struct pn_mesh_info {
    uint32_t vertex_count;
    uint32_t triangle_count;
    uint32_t bvh_node_count;
    uint32_t bvh_depth;
    float bounds_lo[3];
    float bounds_hi[3];
    uint32_t has_normals;     /* 1 when the mesh has per-vertex normals */
} pn_mesh_info;

PN_API pn_status pn_mesh_get_info(pn_mesh mesh, pn_mesh_info *info);

/* Copies the mesh's geometry out (the sizes of pn_mesh_get_info): 3 floats per
 * vertex, 3 indices per triangle, and 3 floats per vertex of normals (NULL to
 * skip; PN_ERROR_UNSUPPORTED for a mesh without normals). */
PN_API pn_status pn_mesh_read_geometry(pn_mesh mesh, float *positions, uint32_t *indices, float *normals);

/* The scale s when the 3x4 object-to-world `transform` is a translation times
 * s * identity (s > 0, to 1e-5 relative), else 0: the transforms under which
 * a baked occlusion field stays valid. */
PN_API pn_status pn_transform_uniform_scale(const float transform[12], float *scale);

/* 64-bit content hash of the committed geometry (positions and indices; normals
 * do not change visibility). Occlusion fields record it. */
PN_API pn_status pn_mesh_get_hash(pn_mesh mesh, uint64_t *hash);

/* ----------------------------------------------------------------- scene */

typedef enum pn_lobe {
    PN_LOBE_PHONG = 0,       /* k_s (n+2)/(2pi) cos^n(angle to mirror direction) */
    PN_LOBE_BLINN_PHONG = 1, /* k_s (n+8)/(8pi) cos^n(angle to half vector) */
    PN_LOBE_GGX = 2,         /* k_s * Cook-Torrance with GGX distribution, roughness alpha */
    PN_LOBE_ASHIKHMIN_SHIRLEY = 3 /* k_s * anisotropic Ashikhmin-Shirley, exponents n_u (shininess), n_v, tangent */
} pn_lobe;

typedef struct pn_material {
    float albedo[3];  /* diffuse reflectance, each in [0, 1] */
    float specular;   /* k_s in [0, 1]; 0 = purely diffuse */
    float shininess;  /* Phong / Blinn-Phong exponent, >= 0 */
    float roughness;  /* GGX alpha in (0, 1] */
    uint32_t lobe;    /* pn_lobe */
    float shininess_v; /* Ashikhmin-Shirley n_v (shininess is n_u), >= 0; other lobes ignore it */
    float tangent[3];  /* Ashikhmin-Shirley u axis in the object's frame (transformed with the instance,
                          projected onto each pixel's tangent plane; docs/brdf.md); nonzero for that lobe */
} pn_material;

/* "phong", "blinn_phong", "ggx", "ashikhmin_shirley" for the pn_lobe values, NULL beyond them. */
PN_API const char *pn_lobe_name(uint32_t lobe);

/* albedo 0.8 grey, no specular, shininess 100, roughness 0.3, Phong, shininess_v 100, tangent (1, 0, 0). */
PN_API pn_material pn_material_default(void);

typedef struct pn_camera {
    float position[3];
    float look_at[3];
    float up[3];
    float fov_deg;    /* horizontal field of view, in (0, 180) */
    uint32_t width;   /* pixels, >= 1 */
    uint32_t height;
} pn_camera;

PN_API pn_status pn_scene_create(pn_context ctx, pn_scene *out);
PN_API pn_status pn_scene_retain(pn_scene scene);
PN_API pn_status pn_scene_release(pn_scene scene);

/* The scene's lighting; retained. */
PN_API pn_status pn_scene_set_envmap(pn_scene scene, pn_envmap env);

/* Adds an instance of `mesh` (retained). `transform` is the 3x4 row-major
 * object-to-world matrix (NULL: identity); it must be finite and invertible.
 * `material` NULL means pn_material_default(). *id receives a stable id. */
PN_API pn_status pn_scene_add_instance(pn_scene scene, pn_mesh mesh, const float transform[12],
                                       const pn_material *material, uint32_t *id);
PN_API pn_status pn_scene_set_instance_transform(pn_scene scene, uint32_t id, const float transform[12]);
PN_API pn_status pn_scene_set_instance_material(pn_scene scene, uint32_t id, const pn_material *material);
PN_API pn_status pn_scene_remove_instance(pn_scene scene, uint32_t id);
PN_API pn_status pn_scene_set_camera(pn_scene scene, const pn_camera *camera);

/* A spherical light: a sphere of uniform outgoing radiance (docs/reference.md).
 * Lights illuminate surfaces but are not part of the geometry: they cast no
 * shadow and the camera does not see them. */
typedef struct pn_sphere_light {
    float position[3];
    float radius;      /* > 0 */
    float radiance[3]; /* linear RGB, each >= 0 */
} pn_sphere_light;

/* Replaces the scene's spherical lights (count 0 removes them; lights may be
 * NULL then). Copied; takes effect at the next pn_scene_commit. At most 1024. */
PN_API pn_status pn_scene_set_lights(pn_scene scene, const pn_sphere_light *lights, uint32_t count);

/* Technique assets (pn_fiv, pn_heightfield, ...) attach to instances; the
 * methods that use them find them there (docs/api.md "Attachments"). One
 * generic pair of calls serves every technique:
 *  - pn_scene_attach attaches `asset` (retained) to instance `instance`,
 *    replacing what that instance had of the same kind. An asset that does not
 *    fit its target is PN_ERROR_INVALID_ARGUMENT naming why: an occlusion field
 *    baked for another mesh, a height field on an instance whose mesh does not
 *    have its grid of vertices, PN_WHOLE_SCENE for a kind that attaches to
 *    instances. A handle that is not an asset is PN_ERROR_NULL_HANDLE.
 *  - pn_scene_detach drops the instance's attachment `asset` (NULL: all of the
 *    instance's attachments; detaching what is not attached is a no-op).
 * Removing an instance drops its attachments. Changes take effect at the next
 * pn_scene_commit. */
#define PN_WHOLE_SCENE 0xFFFFFFFFu
PN_API pn_status pn_scene_attach(pn_scene scene, uint32_t instance, void *asset);
PN_API pn_status pn_scene_detach(pn_scene scene, uint32_t instance, void *asset);

/* Uploads per-mesh BVHs when the set of meshes changed and rebuilds the
 * top-level BVH over instances (cheap: done every frame for moving objects). */
PN_API pn_status pn_scene_commit(pn_scene scene);

/* Ray queries against the committed scene, host arrays in and out.
 * rays: 8 floats per ray: origin xyz, tmin, direction xyz (need not be unit), tmax.
 * pn_scene_intersect: closest hit; t (INFINITY on a miss), instance id
 *   (PN_BACKGROUND on a miss) and the mesh's triangle index; any output may be NULL.
 * pn_scene_occluded: 1 if anything is hit in the open interval (tmin, tmax), else 0
 *   (pn_scene_intersect uses the same open interval). */
PN_API pn_status pn_scene_intersect(pn_scene scene, const float *rays, uint32_t count, float *t,
                                    uint32_t *instance, uint32_t *triangle);
PN_API pn_status pn_scene_occluded(pn_scene scene, const float *rays, uint32_t count, uint8_t *occluded);
/* The same queries on rays given as two arrays of 3 floats per ray (origins,
 * directions; read in place where 4-byte aligned, else copied) with one tmin
 * and tmax for all (a NaN bound is an error): no packing into the 8-float
 * layout. Answers are bit-identical to pn_scene_intersect /
 * pn_scene_occluded on the packed rays. */
PN_API pn_status pn_scene_intersect_arrays(pn_scene scene, const float *origins, const float *directions,
                                           uint32_t count, float tmin, float tmax, float *t, uint32_t *instance,
                                           uint32_t *triangle);
PN_API pn_status pn_scene_occluded_arrays(pn_scene scene, const float *origins, const float *directions,
                                          uint32_t count, float tmin, float tmax, uint8_t *occluded);

/* -------------------------------------------------------------- G-buffer */

/* Layout (docs/gbuffer.md), one buffer per plane, width*height elements, pixel
 * (x, y) at index y*width + x, y = 0 the top row:
 *   POSITION  float4  world position xyz, w = distance from the camera.
 *                     Background: xyz = unit view direction, w = +INFINITY.
 *   NORMAL    float4  unit shading normal facing the camera, w = 0
 *   ALBEDO    float4  diffuse albedo rgb, w = specular k_s
 *   MATERIAL  float4  shininess, roughness, lobe (as float), 0; for the Ashikhmin-Shirley lobe
 *                     n_u, n_v, 3, tangent angle (radians from pn_frame's t towards b, docs/brdf.md)
 *   INSTANCE  uint32  instance id, PN_BACKGROUND for background pixels */
typedef enum pn_gbuffer_plane {
    PN_GBUFFER_POSITION = 0,
    PN_GBUFFER_NORMAL = 1,
    PN_GBUFFER_ALBEDO = 2,
    PN_GBUFFER_MATERIAL = 3,
    PN_GBUFFER_INSTANCE = 4
} pn_gbuffer_plane;
#define PN_GBUFFER_PLANE_COUNT 5

/* Element size in bytes of a plane (16 or 4); 0 for an unknown plane. */
PN_API size_t pn_gbuffer_plane_element_size(pn_gbuffer_plane plane);

PN_API pn_status pn_gbuffer_create(pn_context ctx, uint32_t width, uint32_t height, pn_gbuffer *out);

/* Wraps caller-owned buffers (retained; each at least width*height*element
 * bytes, else PN_ERROR_INVALID_SIZE). planes[i] is the buffer of plane i. */
PN_API pn_status pn_gbuffer_create_from_cl(pn_context ctx, uint32_t width, uint32_t height,
                                           const cl_mem planes[PN_GBUFFER_PLANE_COUNT], pn_gbuffer *out);
PN_API pn_status pn_gbuffer_retain(pn_gbuffer gbuffer);
PN_API pn_status pn_gbuffer_release(pn_gbuffer gbuffer);
PN_API pn_status pn_gbuffer_get_size(pn_gbuffer gbuffer, uint32_t *width, uint32_t *height);
PN_API pn_status pn_gbuffer_get_cl(pn_gbuffer gbuffer, pn_gbuffer_plane plane, cl_mem *buffer);

/* Host transfers of one plane (blocking); `bytes` must equal the plane's size. */
PN_API pn_status pn_gbuffer_write(pn_gbuffer gbuffer, pn_gbuffer_plane plane, const void *host, size_t bytes);
PN_API pn_status pn_gbuffer_read(pn_gbuffer gbuffer, pn_gbuffer_plane plane, void *host, size_t bytes);

/* Checks a G-buffer filled by the caller, on the device: a foreground pixel
 * with a non-finite position or normal, or a zero normal, is an error
 * (PN_ERROR_INVALID_VALUE) whose message counts them and gives the first. */
PN_API pn_status pn_gbuffer_validate(pn_gbuffer gbuffer);

/* Casts one primary ray per pixel from the scene's camera (the G-buffer must
 * have the camera's resolution). Enqueued only. */
PN_API pn_status pn_scene_render_gbuffer(pn_scene scene, pn_gbuffer gbuffer);

/* ----------------------------------------------------------------- image */

/* float4 RGBA per pixel (linear radiance; alpha 1 on surfaces, 0 on background). */
PN_API pn_status pn_image_create(pn_context ctx, uint32_t width, uint32_t height, pn_image *out);
PN_API pn_status pn_image_create_from_cl(pn_context ctx, uint32_t width, uint32_t height, cl_mem buffer,
                                         pn_image *out);
PN_API pn_status pn_image_retain(pn_image image);
PN_API pn_status pn_image_release(pn_image image);
PN_API pn_status pn_image_get_cl(pn_image image, cl_mem *buffer);
PN_API pn_status pn_image_read(pn_image image, float *host, size_t bytes);

/* ------------------------------------------------------ occlusion fields */

/* Fullsphere Irradiance Vectors of one occluder mesh under one env map
 * (docs/fiv.md): for sample positions on concentric spheres around the
 * mesh's bounding-sphere centre, the env radiance the mesh hides, as
 * FIV = sum L(w) w dw over the occluded directions w (three RGB vectors). */
typedef enum pn_precision {
    PN_PRECISION_FLOAT32 = 0,
    PN_PRECISION_FLOAT16 = 1  /* half floats, scaled by the env's total power */
} pn_precision;

typedef struct pn_fiv_options {
    uint32_t theta;            /* samples from pole to pole, poles included, 3..1025 (32x17x15: theta 17) */
    uint32_t phi;              /* samples around the axis, periodic, 4..2048 */
    uint32_t radii;            /* concentric spheres, 2..256 */
    float inner_radius;        /* innermost sphere, in bounding radii, (0, 1) (0.2) */
    float error_target;        /* outermost sphere at R / sqrt(error_target), in (0, 0.5] (0.01: 10 R) */
    uint32_t face_size;        /* env directions: a cube of face_size^2 x 6, 1..256 (32) */
    uint32_t sun_supersampling;/* bright texels split into s x s sub-texels, 1..16 (4) */
    float sun_threshold;       /* ... when their power reaches this share of the brightest, (0, 1] (0.1) */
    uint32_t precision;        /* pn_precision (PN_PRECISION_FLOAT16) */
} pn_fiv_options;

PN_API pn_fiv_options pn_fiv_options_default(void);

/* Called after each baked sphere with samples done and total; return nonzero
 * to stop (the bake then fails with PN_ERROR_CANCELLED after its checkpoint). */
typedef int (*pn_progress_callback)(void *user, uint64_t done, uint64_t total);

/* Bakes the occlusion field of `mesh` (committed) under `env` (committed).
 * `checkpoint_path` (may be NULL): the bake file, written atomically after
 * every few spheres; if it already holds a finished bake of the same mesh,
 * env map and options it is loaded instead, an unfinished one is resumed, and
 * a bake of anything else is an error that leaves the file untouched.
 * Degenerate meshes (no triangle of nonzero area) give PN_ERROR_EMPTY_INPUT. */
PN_API pn_status pn_fiv_bake(pn_envmap env, pn_mesh mesh, const pn_fiv_options *options,
                             const char *checkpoint_path, pn_progress_callback progress, void *user, pn_fiv *out);
/* Reads a finished bake file; corrupt, truncated, unfinished or foreign files
 * give PN_ERROR_FILE naming the problem. */
PN_API pn_status pn_fiv_load(pn_context ctx, const char *path, pn_fiv *out);
/* Writes the field atomically (a temporary file renamed over `path`). */
PN_API pn_status pn_fiv_save(pn_fiv fiv, const char *path);
PN_API pn_status pn_fiv_retain(pn_fiv fiv);
PN_API pn_status pn_fiv_release(pn_fiv fiv);

typedef struct pn_fiv_info {
    pn_fiv_options options;
    float centre[3];           /* bounding-sphere centre, object space */
    float radius;              /* bounding radius R */
    float inner, outer;        /* innermost and outermost sphere radii, object units */
    uint64_t mesh_hash, env_hash;
    uint64_t sample_count;     /* theta * phi * radii */
    uint64_t inside_count;     /* samples inside the geometry (winding number), never used */
    uint64_t stored_bytes;     /* the samples as stored (precision) */
    uint64_t rays;             /* rays traced by the bake (recorded in its file; 0 for files older than that) */
    double bake_seconds;       /* wall time of the bake, resumed parts included (recorded likewise) */
    uint32_t radii_done;       /* spheres baked (radii when finished) */
} pn_fiv_info;

PN_API pn_status pn_fiv_get_info(pn_fiv fiv, pn_fiv_info *info);
/* Reads only the header of a bake file, finished or not (radii_done tells),
 * checking its checksum: what `penumbra fiv-info` prints. No context needed;
 * errors go to the global slot. */
PN_API pn_status pn_fiv_read_header(const char *path, pn_fiv_info *info);
/* The samples as float: radii x theta x phi x 9 (X rgb, Y rgb, Z rgb), sample
 * (k, i, j) at ((k * theta + i) * phi + j) * 9; NaN for samples inside. */
PN_API pn_status pn_fiv_read(pn_fiv fiv, float *host, size_t bytes);

/* ---------------------------------------------------------- height fields */

/* A height field (docs/heightfield.md): width x depth heights, row-major,
 * h[j * width + i]; vertex (i, j) is the world point
 * (origin.x + i sx, origin.y + height_scale h, origin.z + j sz) with
 * sx = size[0] / (width - 1), sz = size[1] / (depth - 1). New heights each
 * frame (set_heights + commit) cost one pyramid rebuild; nothing is baked. */
typedef struct pn_heightfield_placement {
    float origin[3];
    float size[2];            /* world extent along x (columns) and z (rows), > 0 */
    float height_scale;       /* world y per height unit */
} pn_heightfield_placement;

PN_API pn_status pn_heightfield_create(pn_context ctx, pn_heightfield *out);
PN_API pn_status pn_heightfield_retain(pn_heightfield hf);
PN_API pn_status pn_heightfield_release(pn_heightfield hf);
/* Copies the heights; width, depth >= 2; NaN/Inf are refused (count and first position). */
PN_API pn_status pn_heightfield_set_heights(pn_heightfield hf, const float *heights, uint32_t width, uint32_t depth);
/* A local edit: replaces the width x depth heights (row-major) of columns
 * x0 .. x0 + width - 1, rows y0 .. y0 + depth - 1 (inside the field; NaN/Inf
 * refused). After the commit, a `heightfield` renderer that rendered the
 * field before updates only what the edited box can change (pyramid levels
 * and horizon lanes), equal bit for bit to a full recompute. */
PN_API pn_status pn_heightfield_set_heights_region(pn_heightfield hf, uint32_t x0, uint32_t y0, uint32_t width,
                                                   uint32_t depth, const float *heights);
/* Default: origin 0, size (width - 1, depth - 1), height_scale 1. */
PN_API pn_status pn_heightfield_set_placement(pn_heightfield hf, const pn_heightfield_placement *placement);
/* Per-vertex RGB albedo in [0, 1] (width * depth * 3 floats), multiplied into
 * the per-vertex outputs; NULL / 0 removes it (white). */
PN_API pn_status pn_heightfield_set_albedo(pn_heightfield hf, const float *rgb, size_t count);
PN_API pn_status pn_heightfield_commit(pn_heightfield hf);
/* A new committed triangle mesh of the committed heights in world space (two
 * triangles per cell, counter-clockwise from above, the method's normals), for
 * the G-buffer ray caster and the reference renderer. */
PN_API pn_status pn_heightfield_build_mesh(pn_heightfield hf, pn_mesh *out);

/* ------------------------------------------------------------ sphere sets */

/* Occluder proxies of the isg method (docs/isg.md section 7): spheres
 * (centre xyz, radius; object space of the instance they attach to).
 * pn_sphere_set_build approximates the solid of a committed mesh by `count`
 * spheres (1..4096): balls inscribed in its voxelised solid, chosen greedily
 * to cover it and grown past its surface by the amount (under two voxels)
 * with the least outside + missed volume; results are cached in the
 * context by (mesh hash, count). A mesh that
 * encloses no volume (flat, open without inside, degenerate) is
 * PN_ERROR_EMPTY_INPUT. A built set attaches to instances of its mesh only.
 * pn_sphere_set_create copies the caller's spheres (4 floats each; a
 * non-finite value or a radius <= 0 is PN_ERROR_INVALID_VALUE naming the
 * first); such a set attaches to any instance. */
PN_API pn_status pn_sphere_set_build(pn_mesh mesh, uint32_t count, pn_sphere_set *out);
PN_API pn_status pn_sphere_set_create(pn_context ctx, const float *spheres, uint32_t count, pn_sphere_set *out);
/* A thin shell (cloth, leaves, open meshes; docs/isg.md section 8): a set of
 * no spheres that, attached to an instance, makes the isg method project
 * that instance's triangles (world space, read from its mesh at every
 * execute, so a deformed mesh needs nothing more) into each lobe's patch
 * grid. At most 4096 triangles per shell instance (more is
 * PN_ERROR_INVALID_SIZE at execute). Attaches to any instance; deform is a
 * no-op. */
PN_API pn_status pn_sphere_set_create_shell(pn_context ctx, pn_sphere_set *out);
PN_API pn_status pn_sphere_set_retain(pn_sphere_set set);
PN_API pn_status pn_sphere_set_release(pn_sphere_set set);

typedef struct pn_sphere_set_info {
    uint32_t count;
    uint32_t grid;             /* voxels along the longest side of the build grid (0: the caller's spheres) */
    uint64_t mesh_hash;        /* 0 for the caller's spheres */
    float mesh_volume;         /* the solid's volume on the build grid, object units^3 */
    float outside_share;       /* volume of the union outside the solid / mesh_volume (NaN: caller's) */
    float missed_share;        /* volume of the solid outside the union / mesh_volume (NaN: caller's) */
    double build_seconds;      /* CPU time of the build (of the first build when cached) */
    float skin;                /* how far the balls may reach past the surface, object units: (g + 1/2) cells
                                * of the build grid, g the growth chosen (docs/isg.md section 7); 0: caller's */
} pn_sphere_set_info;

PN_API pn_status pn_sphere_set_get_info(pn_sphere_set set, pn_sphere_set_info *info);
/* The spheres, count x 4 floats; bytes must be exactly count * 16. */
PN_API pn_status pn_sphere_set_read(pn_sphere_set set, float *spheres, size_t bytes);
/* Deforming objects: moves a built set's spheres with `mesh` (committed,
 * the same vertex count as the mesh it was built on, new positions): each
 * centre is a fixed affine combination of its 8 nearest vertices at build
 * (exact at rest), each radius scales with their mean distance from it. No
 * rebuild; the set then belongs to the mesh's new content hash. A set of the
 * caller's spheres is PN_ERROR_INVALID_ARGUMENT, another vertex count
 * PN_ERROR_INVALID_SIZE. */
PN_API pn_status pn_sphere_set_deform(pn_sphere_set set, pn_mesh mesh);

/* -------------------------------------------------------------- renderer */

/* Shading methods ("unshadowed", "reference", "floor", "fiv", "heightfield",
 * ...) and their parameters are described by the library itself: list them
 * with the calls below (`penumbra methods` prints them; docs/api.md has the
 * same tables, checked against the library by the tests). */
typedef enum pn_param_type {
    PN_PARAM_INT = 0,         /* pn_renderer_set_int (booleans are 0/1 ints) */
    PN_PARAM_FLOAT = 1        /* pn_renderer_set_float (an int value is accepted too) */
} pn_param_type;

typedef enum pn_param_stage {
    PN_PARAM_FRAME = 0,       /* a renderer parameter read at every execute */
    PN_PARAM_PLAN = 1,        /* a renderer parameter whose change re-runs the method's plan (tables, uploads) */
    PN_PARAM_BAKE = 2         /* an option of the method's asset bake (e.g. pn_fiv_options), not of the renderer */
} pn_param_stage;

typedef struct pn_param_info {
    const char *name;
    uint32_t type;            /* pn_param_type */
    uint32_t stage;           /* pn_param_stage */
    double default_value;
    double min, max;          /* inclusive range */
    const char *unit;         /* "" when it has none */
    const char *doc;          /* one sentence */
} pn_param_info;

/* Scene inputs a method reads (pn_method_info.inputs, bits). */
enum {
    PN_INPUT_ENVMAP = 1,      /* the scene's env map */
    PN_INPUT_GEOMETRY = 2,    /* the instances' triangles, ray traced */
    PN_INPUT_LIGHTS = 4,      /* spherical lights */
    PN_INPUT_CAMERA = 8,      /* the camera position (view-dependent BRDFs) */
    PN_INPUT_FIV = 16,        /* occlusion fields attached to instances */
    PN_INPUT_HEIGHTFIELD = 32,/* height fields attached to instances */
    PN_INPUT_SPHERES = 64     /* sphere sets attached to instances */
};

typedef struct pn_method_info {
    const char *name;
    const char *summary;      /* one line */
    const char *stage;        /* its kernel file, kernels/<stage>.cl */
    const char *doc_page;     /* e.g. "docs/fiv.md" */
    uint32_t param_count;
    uint32_t output_count;    /* readable outputs (pn_renderer_read_output) */
    uint32_t inputs;          /* PN_INPUT_* bits */
} pn_method_info;

typedef struct pn_output_info {
    const char *name;
    const char *doc;          /* one sentence: what, per what, its element type */
} pn_output_info;

PN_API uint32_t pn_method_count(void);
/* Name of method i < pn_method_count(), NULL beyond; a static string. */
PN_API const char *pn_method_name(uint32_t index);
/* Metadata of a method, of its parameter `index` and of its output `index`:
 * static strings. An unknown method is PN_ERROR_INVALID_ARGUMENT (listing the
 * methods), an index past the end PN_ERROR_OUT_OF_RANGE; both in the global slot. */
PN_API pn_status pn_method_get_info(const char *method, pn_method_info *info);
PN_API pn_status pn_method_get_param(const char *method, uint32_t index, pn_param_info *info);
PN_API pn_status pn_method_get_output(const char *method, uint32_t index, pn_output_info *info);

/* A renderer of `method`, its parameters at their defaults. Unknown names are
 * PN_ERROR_INVALID_ARGUMENT listing the methods. Setting an unknown parameter
 * is PN_ERROR_BAD_CONFIG (listing the method's), a value outside the range
 * PN_ERROR_INVALID_ARGUMENT, a bake option PN_ERROR_BAD_CONFIG naming where it
 * goes. */
PN_API pn_status pn_renderer_create(pn_context ctx, const char *method, pn_renderer *out);
PN_API pn_status pn_renderer_retain(pn_renderer renderer);
PN_API pn_status pn_renderer_release(pn_renderer renderer);
PN_API pn_status pn_renderer_set_int(pn_renderer renderer, const char *name, int32_t value);
PN_API pn_status pn_renderer_set_float(pn_renderer renderer, const char *name, float value);
PN_API pn_status pn_renderer_get_int(pn_renderer renderer, const char *name, int32_t *value);
PN_API pn_status pn_renderer_get_float(pn_renderer renderer, const char *name, float *value);
PN_API pn_status pn_renderer_commit(pn_renderer renderer);

/* Shades every pixel of `gbuffer` with the scene's lighting into `image`
 * (same size). The scene and its envmap must be committed. The first execute
 * after the renderer's plan-time parameters, the scene's assets or its env map
 * changed runs the method's plan (table builds, uploads, read-backs; it may
 * block); every other execute only enqueues work. */
PN_API pn_status pn_renderer_execute(pn_renderer renderer, pn_scene scene, pn_gbuffer gbuffer, pn_image image);

/* Computes (for the scene as it is now; plans first when needed) and reads
 * one of the method's outputs (pn_method_get_output) into host memory.
 * `instance`: the instance the output is of (e.g. a height field's);
 * `index`: an item within it (e.g. a light), 0 when the output has none.
 * `bytes` must equal the output's size. Blocking. */
PN_API pn_status pn_renderer_read_output(pn_renderer renderer, pn_scene scene, const char *output, uint32_t instance,
                                         uint32_t index, void *host, size_t bytes);

/* The caller's own directional domains for a method that shades with them
 * (depthmap): `count` domains (copied; 1..1024) replace the decomposition of
 * the scene's env map from the next execute on; count 0 returns to the
 * decomposition. The env map still gives the background. Errors:
 * PN_ERROR_UNSUPPORTED (a method without domains), PN_ERROR_INVALID_ARGUMENT
 * (NULL with count > 0, more than 1024, a non-finite or non-unit direction,
 * a non-finite or negative radiance, a cap radius outside [0, pi], a
 * non-finite or negative solid angle: the message names the domain). */
PN_API pn_status pn_renderer_set_env_domains(pn_renderer renderer, const pn_env_domain *domains, uint32_t count);

/* The caller's own depth maps for depthmap (a simulator with its own
 * rasteriser), used instead of drawing them, from the next execute on, until
 * replaced or count 0 (draw again). One map per domain the renderer shades
 * with, in the order of its `domains` output, in the layout of its outputs
 * (docs/depthmap.md "Maps from the caller"): `frames`, count x 16 floats
 * (e1 | u_min, e2 | v_min, d | far, du, dv, depth extent, ignored);
 * `depths`, count x resolution^2 floats, map after map, row-major, the
 * distance far - p.d of the nearest surface at each texel centre, +inf where
 * empty. Copied (blocking upload). `resolution` must equal the renderer's.
 * Errors: PN_ERROR_UNSUPPORTED (another method), PN_ERROR_INVALID_SIZE
 * (resolution other than the renderer's; count above 1024 or, with caller
 * domains set, other than their count; at execute: count other than the
 * domains shaded with, or the resolution changed since),
 * PN_ERROR_INVALID_ARGUMENT (a NULL pointer with count > 0; a frame with a
 * non-finite value, axes not orthonormal to 1e-3 or a non-positive texel size
 * or extent; a depth NaN or negative: the message names map and texel; at
 * execute: a map's d more than 1.4e-3 rad from its domain's direction). */
PN_API pn_status pn_renderer_set_depth_maps(pn_renderer renderer, const float *frames, const float *depths,
                                            uint32_t count, uint32_t resolution);

/* As pn_renderer_set_depth_maps, with a side per map: map m is
 * resolutions[m]^2 floats (1 to 4096 texels a side), the maps packed one
 * after the other in `depths` (any sides: they need not equal the
 * renderer's `resolution`; the bias is in texels of each map). Copied
 * (blocking upload). Errors as pn_renderer_set_depth_maps, and
 * PN_ERROR_INVALID_ARGUMENT for NULL resolutions, PN_ERROR_INVALID_SIZE for a
 * side of 0 or above 4096 or more than 2^28 texels in all. */
PN_API pn_status pn_renderer_set_depth_maps_sized(pn_renderer renderer, const float *frames, const float *depths,
                                                  uint32_t count, const uint32_t *resolutions);

/* Zero copy: the depths are read in place from `depths`, a buffer of the
 * caller's on the renderer's cl_context, laid out as in
 * pn_renderer_set_depth_maps_sized (map after map, resolutions[m]^2 floats
 * each, from offset 0). The buffer is retained until replaced or count 0;
 * every execute reads what it holds then (the caller may redraw it between
 * frames, in order on the context's queue or finished before execute).
 * Its depths are not checked (that would need a blocking read): a NaN reads
 * as shadowed. `frames` are copied and checked as before. Errors as
 * pn_renderer_set_depth_maps_sized, and PN_ERROR_INVALID_ARGUMENT (a NULL or
 * invalid cl_mem, one of another cl_context), PN_ERROR_INVALID_SIZE (a buffer
 * smaller than the sum of resolutions[m]^2 floats). */
PN_API pn_status pn_renderer_set_depth_maps_cl(pn_renderer renderer, const float *frames, cl_mem depths,
                                               uint32_t count, const uint32_t *resolutions);

#ifdef __cplusplus
}
#endif

#endif /* PENUMBRA_H */
