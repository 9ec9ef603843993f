/* Soak of libpenumbra through its public API (penumbra.h): FRAMES frames of
 * a fully dynamic scene in one process, the C twin of tests/soak/soak.py
 * (docs/reliability.md).
 *
 *   test_soak [FRAMES [WIDTH HEIGHT]]      (default 100 frames, 64x48)
 *
 * One context; a height-field terrain and several instances (spheres with a
 * baked occlusion field and a sphere set attached, a rotating box). Every
 * frame: the spheres and the box move and the camera orbits; one transient
 * instance is removed and one added; the terrain gets new heights and a new
 * triangle mesh (its instance swapped); one frame parameter of the method
 * drawn this frame gets a new value inside the range the library declares
 * (pn_method_get_param), and every 10 frames a plan parameter changes; the
 * frame is rendered (G-buffer, execute, read back) by one of unshadowed,
 * floor, heightfield, fiv, depthmap, isg in turn. Every 25 frames a new env
 * map object replaces the old one and a new tiny occlusion field is baked
 * under it; every 100 frames the renderers, every 250 the G-buffer and image
 * are created anew.
 *
 * Before the frames: 20,000 instance additions and removals may not grow the
 * heap (churn_check), and every sky, cheap plan value and integer frame
 * parameter value is rendered once (prime), so first uses (stage builds,
 * cached kernels) are not counted. After the warm-up and at the end the
 * renderers are created anew at their starting values and each method renders
 * once (settle): both measurements see the same state.
 *
 * Checks: every call succeeds and every pixel is finite; the heap in use
 * (ASan's live bytes in sanitizer builds, else glibc's mallinfo2) grows by at
 * most HEAP_BOUND bytes per frame after the warm-up; the cl_context's
 * reference count (held by every cl_mem, program and kernel) is no higher at
 * the end than after the warm-up (no OpenCL objects pile up) and falls back to
 * the soak's own reference once the context is released (none are leaked).
 * Built with the sanitizers (PENUMBRA_SANITIZE), LeakSanitizer checks the
 * host memory at exit (PoCL's own allocations are suppressed by lsan.supp).
 * RSS (/proc/self/statm) is printed, not bounded (ASan's quarantine and
 * shadow memory dominate it; the Python soak bounds RSS). SOAK_HEAP_PROFILE=1
 * prints the live heap by allocation stack at both points (sanitizer builds).
 * Exit status 0 on success. */
#define _POSIX_C_SOURCE 200809L /* nanosleep, sysconf */

#include "penumbra.h"

#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>
#if defined(__GLIBC__) && (__GLIBC__ > 2 || (__GLIBC__ == 2 && __GLIBC_MINOR__ >= 33))
#include <malloc.h>
#define SOAK_MALLINFO2 1
#endif

#define CHECK(ctx, call)                                                                                      \
    do {                                                                                                      \
        pn_status st_ = (call);                                                                               \
        if (st_ != PN_SUCCESS) {                                                                              \
            const char *msg_ = "";                                                                            \
            pn_get_error((ctx), &msg_);                                                                       \
            if (!*msg_)                                                                                       \
                pn_get_error(NULL, &msg_);                                                                    \
            fprintf(stderr, "FAIL: frame %d: %s: %s (%s)\n", g_frame, #call, pn_status_name(st_), msg_);      \
            exit(1);                                                                                          \
        }                                                                                                     \
    } while (0)

static int g_frame = -1;

static const char *const METHODS[] = {"unshadowed", "floor", "heightfield", "fiv", "depthmap", "isg"};
enum { METHOD_COUNT = 6, ENV_EVERY = 25, RENDERER_EVERY = 100, TARGET_EVERY = 250, PLAN_EVERY = 10, GRID = 17 };

/* Plan-time parameters changed now and then, among values cheap at this size. */
typedef struct plan_choice {
    int method;
    const char *name;
    int count;
    double values[3];
} plan_choice;
static const plan_choice PLAN_VALUES[] = {
    {2, "azimuths", 2, {8, 16}},    {2, "level_step", 2, {2, 4}},    {2, "bands", 2, {3, 4}},
    {2, "reconstruction", 2, {0, 1}}, {2, "sun_threshold", 2, {0, 50}}, {4, "directions", 3, {2, 4, 6}},
    {4, "resolution", 2, {16, 32}}, {4, "seed", 2, {1, 2}},          {5, "lobes", 2, {4, 8}},
};
enum { PLAN_CHOICES = sizeof PLAN_VALUES / sizeof PLAN_VALUES[0] };

/* ------------------------------------------------------------ helpers */

static uint64_t g_rng = 0x9E3779B97F4A7C15ull;
static uint32_t rnd(void)
{
    g_rng ^= g_rng << 13;
    g_rng ^= g_rng >> 7;
    g_rng ^= g_rng << 17;
    return (uint32_t)(g_rng >> 32);
}
static double uniform(double lo, double hi) { return lo + (hi - lo) * (rnd() / 4294967296.0); }

static long rss_kib(void)
{
    long pages = 0, resident = 0;
    FILE *f = fopen("/proc/self/statm", "r");
    if (!f)
        return -1;
    if (fscanf(f, "%ld %ld", &pages, &resident) != 2)
        resident = -1;
    fclose(f);
    return resident < 0 ? -1 : resident * (sysconf(_SC_PAGESIZE) / 1024);
}

/* Bytes allocated and not freed: ASan's count in sanitizer builds, else
 * glibc's mallinfo2; -1 where neither is known. */
#if defined(__GNUC__)
extern size_t __sanitizer_get_current_allocated_bytes(void) __attribute__((weak));
#endif
static long long allocated_bytes(void)
{
#if defined(__GNUC__)
    if (__sanitizer_get_current_allocated_bytes)
        return (long long)__sanitizer_get_current_allocated_bytes();
#endif
#ifdef SOAK_MALLINFO2
    const struct mallinfo2 m = mallinfo2();
    return (long long)(m.uordblks + m.hblkhd);
#else
    return -1;
#endif
}


static long heap_kib(void)
{
    const long long b = allocated_bytes();
    return b < 0 ? -1 : (long)(b / 1024);
}

/* Sanitizer builds: live heap by allocation stack (SOAK_HEAP_PROFILE=1 prints
 * it after the warm-up and at the end, to find what grows). */
#if defined(__GNUC__)
extern void __sanitizer_print_memory_profile(size_t top_percent, size_t max_contexts) __attribute__((weak));
#define HEAP_PROFILE()                                                                                        \
    do {                                                                                                      \
        if (getenv("SOAK_HEAP_PROFILE") && __sanitizer_print_memory_profile) {                                \
            fflush(stdout);                                                                                   \
            __sanitizer_print_memory_profile(100, 500);                                                       \
        }                                                                                                     \
    } while (0)
#else
#define HEAP_PROFILE() ((void)0)
#endif

static double now(void)
{
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return (double)t.tv_sec + 1e-9 * (double)t.tv_nsec;
}

static cl_uint refcount_of(cl_context c)
{
    cl_uint n = 0;
    clGetContextInfo(c, CL_CONTEXT_REFERENCE_COUNT, sizeof n, &n, NULL);
    return n;
}

/* PoCL drops the references of finished commands asynchronously, even after
 * clFinish: wait up to 5 s for the count to come down to `target`. */
static cl_uint settled_refcount(cl_context c, cl_uint target)
{
    for (int i = 0; i < 500 && refcount_of(c) > target; ++i) {
        struct timespec ms = {0, 10 * 1000 * 1000};
        nanosleep(&ms, NULL);
    }
    return refcount_of(c);
}

/* The count once it has stopped changing (three equal reads 20 ms apart; 2 s at most). */
static cl_uint stable_refcount(cl_context c)
{
    cl_uint last = refcount_of(c);
    for (int i = 0, same = 0; i < 100 && same < 3; ++i) {
        struct timespec ms = {0, 20 * 1000 * 1000};
        nanosleep(&ms, NULL);
        const cl_uint n = refcount_of(c);
        same = n == last ? same + 1 : 0;
        last = n;
    }
    return last;
}

static void translate(float t[12], float x, float y, float z, float s)
{
    const float m[12] = {s, 0, 0, x, 0, s, 0, y, 0, 0, s, z};
    memcpy(t, m, sizeof m);
}

static void rotate_y(float t[12], float a, float x, float y, float z)
{
    const float c = cosf(a), s = sinf(a);
    const float m[12] = {c, 0, s, x, 0, 1, 0, y, -s, 0, c, z};
    memcpy(t, m, sizeof m);
}

/* A 64x32 lat-long sky (row 0 at +y): a gradient, a dark ground and a sun at azimuth `a`. */
enum { EW = 64, EH = 32 };
static void make_sky(float *rgb, float a)
{
    const float pi = 3.14159265f;
    const float sun[3] = {0.6f * cosf(a), 0.7f, 0.6f * sinf(a)};
    const float n = sqrtf(sun[0] * sun[0] + sun[1] * sun[1] + sun[2] * sun[2]);
    for (int j = 0; j < EH; ++j)
        for (int i = 0; i < EW; ++i) {
            const float theta = pi * (j + 0.5f) / EH, phi = 2 * pi * (i + 0.5f) / EW;
            const float d[3] = {sinf(theta) * sinf(phi), cosf(theta), sinf(theta) * cosf(phi)};
            const float c = (d[0] * sun[0] + d[1] * sun[1] + d[2] * sun[2]) / n;
            float *p = rgb + 3 * (j * EW + i);
            const float sky = d[1] > 0 ? 0.4f + 0.6f * d[1] : 0.1f;
            const float s = c > 0.995f ? 200.0f : 0.0f;
            p[0] = 0.8f * sky + s;
            p[1] = 0.9f * sky + s;
            p[2] = 1.0f * sky + s;
        }
}

/* A UV sphere of radius r: (stacks + 1) x slices vertices, radial normals. */
enum { STACKS = 8, SLICES = 12, SPHERE_V = (STACKS + 1) * SLICES, SPHERE_T = 2 * STACKS * SLICES };
static pn_mesh make_sphere(pn_context ctx, float r)
{
    static float pos[SPHERE_V * 3], nrm[SPHERE_V * 3];
    static uint32_t idx[SPHERE_T * 3];
    int t = 0;
    for (int j = 0; j <= STACKS; ++j)
        for (int i = 0; i < SLICES; ++i) {
            const float th = 3.14159265f * j / STACKS, ph = 6.2831853f * i / SLICES;
            float *n = nrm + 3 * (j * SLICES + i);
            n[0] = sinf(th) * cosf(ph);
            n[1] = cosf(th);
            n[2] = sinf(th) * sinf(ph);
            for (int c = 0; c < 3; ++c)
                pos[3 * (j * SLICES + i) + c] = r * n[c];
        }
    for (int j = 0; j < STACKS; ++j)
        for (int i = 0; i < SLICES; ++i) {
            const uint32_t a = j * SLICES + i, b = j * SLICES + (i + 1) % SLICES, c = a + SLICES, d = b + SLICES;
            const uint32_t tri[6] = {a, b, c, b, d, c}; /* outward (counter-clockwise from outside) */
            memcpy(idx + 3 * t, tri, sizeof tri);
            t += 2;
        }
    pn_mesh mesh;
    CHECK(ctx, pn_mesh_create(ctx, &mesh));
    CHECK(ctx, pn_mesh_set_geometry(mesh, pos, SPHERE_V, idx, SPHERE_T, nrm));
    CHECK(ctx, pn_mesh_commit(mesh));
    return mesh;
}

static pn_mesh make_box(pn_context ctx, float h)
{
    const float p[24] = {-h, -h, -h, h, -h, -h, h, h, -h, -h, h, -h, -h, -h, h, h, -h, h, h, h, h, -h, h, h};
    const uint32_t f[36] = {0, 2, 1, 0, 3, 2, 4, 5, 6, 4, 6, 7, 0, 1, 5, 0, 5, 4,
                            3, 6, 2, 3, 7, 6, 0, 4, 7, 0, 7, 3, 1, 2, 6, 1, 6, 5};
    pn_mesh mesh;
    CHECK(ctx, pn_mesh_create(ctx, &mesh));
    CHECK(ctx, pn_mesh_set_geometry(mesh, p, 8, f, 12, NULL));
    CHECK(ctx, pn_mesh_commit(mesh));
    return mesh;
}

/* ------------------------------------------------------------ the soak */

typedef struct soak {
    pn_context ctx;
    cl_context clc;
    uint32_t w, h;
    float sky[3][EH * EW * 3];
    int sky_index;
    pn_envmap env;
    pn_mesh sphere, box, terrain_mesh;
    pn_fiv_options fiv_options;
    pn_fiv field;
    pn_sphere_set spheres;
    pn_heightfield hf;
    float base[GRID * GRID], heights[GRID * GRID];
    pn_scene scene;
    uint32_t terrain, movers[4], spinner;
    uint32_t transients[2];
    int transient_count;
    int transient_has_field[2];
    pn_renderer renderers[METHOD_COUNT];
    double plan[PLAN_CHOICES]; /* current plan values (NAN: default) */
    pn_gbuffer gbuffer;
    pn_image image;
    float *pixels;
} soak;

static pn_envmap new_env(soak *s)
{
    pn_envmap env;
    CHECK(s->ctx, pn_envmap_create(s->ctx, &env));
    CHECK(s->ctx, pn_envmap_set_latlong(env, s->sky[s->sky_index], EW, EH));
    CHECK(s->ctx, pn_envmap_set_int(env, "face_size", 16));
    CHECK(s->ctx, pn_envmap_commit(env));
    return env;
}

static uint32_t add_sphere(soak *s, const float t[12])
{
    pn_material m = pn_material_default();
    m.albedo[0] = 0.3f, m.albedo[1] = 0.5f, m.albedo[2] = 0.9f;
    uint32_t id;
    CHECK(s->ctx, pn_scene_add_instance(s->scene, s->sphere, t, &m, &id));
    CHECK(s->ctx, pn_scene_attach(s->scene, id, s->field));
    CHECK(s->ctx, pn_scene_attach(s->scene, id, s->spheres));
    return id;
}

static void set_plan(soak *s, int choice, double value)
{
    const plan_choice *c = &PLAN_VALUES[choice];
    pn_renderer r = s->renderers[c->method];
    pn_param_info info;
    int32_t n = 0;
    pn_method_info mi;
    CHECK(NULL, pn_method_get_info(METHODS[c->method], &mi));
    for (uint32_t i = 0; i < mi.param_count; ++i) {
        CHECK(NULL, pn_method_get_param(METHODS[c->method], i, &info));
        if (!strcmp(info.name, c->name))
            n = (int32_t)info.type;
    }
    if (n == PN_PARAM_INT)
        CHECK(s->ctx, pn_renderer_set_int(r, c->name, (int32_t)value));
    else
        CHECK(s->ctx, pn_renderer_set_float(r, c->name, (float)value));
    CHECK(s->ctx, pn_renderer_commit(r));
}

static void new_renderers(soak *s)
{
    static const int32_t start[][3] = {{2, 0, 8}, {4, 5, 4}, {4, 6, 32}, {5, 8, 4}}; /* method, choice, value */
    for (int m = 0; m < METHOD_COUNT; ++m) {
        if (s->renderers[m])
            pn_renderer_release(s->renderers[m]);
        CHECK(s->ctx, pn_renderer_create(s->ctx, METHODS[m], &s->renderers[m]));
        CHECK(s->ctx, pn_renderer_commit(s->renderers[m]));
    }
    for (size_t i = 0; i < sizeof start / sizeof start[0]; ++i)
        if (isnan(s->plan[start[i][1]]))
            s->plan[start[i][1]] = start[i][2];
    for (int c = 0; c < PLAN_CHOICES; ++c)
        if (!isnan(s->plan[c]))
            set_plan(s, c, s->plan[c]);
}

static void new_targets(soak *s)
{
    if (s->gbuffer)
        pn_gbuffer_release(s->gbuffer);
    if (s->image)
        pn_image_release(s->image);
    CHECK(s->ctx, pn_gbuffer_create(s->ctx, s->w, s->h, &s->gbuffer));
    CHECK(s->ctx, pn_image_create(s->ctx, s->w, s->h, &s->image));
}

static void setup(soak *s, uint32_t w, uint32_t h)
{
    memset(s, 0, sizeof *s);
    s->w = w, s->h = h;
    CHECK(NULL, pn_context_create(NULL, &s->ctx));
    CHECK(s->ctx, pn_context_get_cl(s->ctx, &s->clc, NULL, NULL));
    clRetainContext(s->clc); /* ours, to watch its reference count after the context is gone */
    for (int k = 0; k < 3; ++k)
        make_sky(s->sky[k], 2.1f * (float)k);
    s->env = new_env(s);
    s->sphere = make_sphere(s->ctx, 0.3f);
    s->box = make_box(s->ctx, 0.2f);
    s->fiv_options = pn_fiv_options_default();
    s->fiv_options.theta = 5, s->fiv_options.phi = 8, s->fiv_options.radii = 3;
    s->fiv_options.face_size = 4, s->fiv_options.sun_supersampling = 1;
    CHECK(s->ctx, pn_fiv_bake(s->env, s->sphere, &s->fiv_options, NULL, NULL, NULL, &s->field));
    CHECK(s->ctx, pn_sphere_set_build(s->sphere, 8, &s->spheres));

    for (int j = 0; j < GRID; ++j)
        for (int i = 0; i < GRID; ++i)
            s->base[j * GRID + i] = 0.5f + 0.3f * sinf(0.7f * (float)i) * cosf(0.5f * (float)j) +
                                    0.1f * sinf(2.3f * (float)(i + j));
    CHECK(s->ctx, pn_heightfield_create(s->ctx, &s->hf));
    const pn_heightfield_placement place = {{-2.5f, 0.0f, -2.5f}, {5.0f, 5.0f}, 0.3f};
    CHECK(s->ctx, pn_heightfield_set_placement(s->hf, &place));
    CHECK(s->ctx, pn_heightfield_set_heights(s->hf, s->base, GRID, GRID));
    CHECK(s->ctx, pn_heightfield_commit(s->hf));
    CHECK(s->ctx, pn_heightfield_build_mesh(s->hf, &s->terrain_mesh));

    CHECK(s->ctx, pn_scene_create(s->ctx, &s->scene));
    CHECK(s->ctx, pn_scene_set_envmap(s->scene, s->env));
    pn_material ground = pn_material_default();
    CHECK(s->ctx, pn_scene_add_instance(s->scene, s->terrain_mesh, NULL, &ground, &s->terrain));
    CHECK(s->ctx, pn_scene_attach(s->scene, s->terrain, s->hf));
    float t[12];
    for (int k = 0; k < 4; ++k) {
        translate(t, (float)k - 1.5f, 0.6f, 0.0f, 1.0f);
        s->movers[k] = add_sphere(s, t);
    }
    pn_material red = pn_material_default();
    red.albedo[0] = 0.9f, red.albedo[1] = 0.3f, red.albedo[2] = 0.2f;
    rotate_y(t, 0.0f, 0.0f, 0.4f, 1.2f);
    CHECK(s->ctx, pn_scene_add_instance(s->scene, s->box, t, &red, &s->spinner));
    for (int c = 0; c < PLAN_CHOICES; ++c)
        s->plan[c] = NAN;
    new_renderers(s);
    new_targets(s);
    s->pixels = malloc((size_t)w * h * 16);
    if (!s->pixels)
        exit(1);
}

static void change_env(soak *s)
{
    s->sky_index = (s->sky_index + 1) % 3;
    pn_envmap env = new_env(s);
    pn_fiv field;
    CHECK(s->ctx, pn_fiv_bake(env, s->sphere, &s->fiv_options, NULL, NULL, NULL, &field));
    CHECK(s->ctx, pn_scene_set_envmap(s->scene, env));
    for (int k = 0; k < 4; ++k)
        CHECK(s->ctx, pn_scene_attach(s->scene, s->movers[k], field));
    for (int k = 0; k < s->transient_count; ++k)
        if (s->transient_has_field[k])
            CHECK(s->ctx, pn_scene_attach(s->scene, s->transients[k], field));
    pn_envmap_release(s->env);
    pn_fiv_release(s->field);
    s->env = env, s->field = field;
}

static void frame_param(soak *s, int method)
{
    pn_method_info mi;
    pn_param_info frame_params[32];
    uint32_t n = 0;
    CHECK(NULL, pn_method_get_info(METHODS[method], &mi));
    for (uint32_t i = 0; i < mi.param_count && n < 32; ++i) {
        CHECK(NULL, pn_method_get_param(METHODS[method], i, &frame_params[n]));
        if (frame_params[n].stage == PN_PARAM_FRAME)
            ++n;
    }
    if (!n)
        return;
    const pn_param_info *p = &frame_params[rnd() % n];
    double hi = p->max;
    if (!strcmp(p->name, "cap_samples"))
        hi = 32;
    else if (!strcmp(p->name, "patch_grid"))
        hi = 8;
    else if (!strcmp(p->name, "pcf"))
        hi = 2;
    pn_renderer r = s->renderers[method];
    if (p->type == PN_PARAM_INT) {
        const int32_t v = (int32_t)p->min + (int32_t)(rnd() % (uint32_t)(hi - p->min + 1));
        CHECK(s->ctx, pn_renderer_set_int(r, p->name, v));
        int32_t back = 0;
        CHECK(s->ctx, pn_renderer_get_int(r, p->name, &back));
        if (back != v) {
            fprintf(stderr, "FAIL: frame %d: %s %s set to %d reads back %d\n", g_frame, METHODS[method], p->name, v,
                    back);
            exit(1);
        }
    } else {
        double top = p->default_value > 0 ? 2 * p->default_value : 1.0;
        if (top > hi)
            top = hi;
        CHECK(s->ctx, pn_renderer_set_float(r, p->name, (float)uniform(p->min, top > p->min ? top : p->min)));
    }
    CHECK(s->ctx, pn_renderer_commit(r));
}

static void frame(soak *s, int f)
{
    const float t = 0.05f * (float)f;
    float tr[12];
    for (int k = 0; k < 4; ++k) {
        translate(tr, (float)k - 1.5f + 0.3f * sinf(t + (float)k), 0.6f + 0.2f * cosf(1.3f * t + (float)k),
                  0.4f * sinf(0.7f * t + 2.0f * (float)k), 0.8f + 0.2f * sinf(t + (float)k));
        CHECK(s->ctx, pn_scene_set_instance_transform(s->scene, s->movers[k], tr));
    }
    rotate_y(tr, t, 0.5f * cosf(t), 0.4f, 1.2f);
    CHECK(s->ctx, pn_scene_set_instance_transform(s->scene, s->spinner, tr));

    /* One instance out, one in (alternately a sphere with its assets and a box). */
    if (s->transient_count == 2) {
        CHECK(s->ctx, pn_scene_remove_instance(s->scene, s->transients[0]));
        s->transients[0] = s->transients[1];
        s->transient_has_field[0] = s->transient_has_field[1];
        s->transient_count = 1;
    }
    const float x = (float)uniform(-2, 2), z = (float)uniform(-2, 2);
    if (f % 2) {
        translate(tr, x, 0.5f, z, 0.7f);
        s->transients[s->transient_count] = add_sphere(s, tr);
    } else {
        const pn_material m = pn_material_default();
        rotate_y(tr, t, x, 0.4f, z);
        CHECK(s->ctx, pn_scene_add_instance(s->scene, s->box, tr, &m, &s->transients[s->transient_count]));
    }
    s->transient_has_field[s->transient_count++] = f % 2;

    /* New heights; the terrain's triangles follow (a new mesh, the instance swapped). */
    for (int i = 0; i < GRID * GRID; ++i)
        s->heights[i] = s->base[i] * (1.0f + 0.5f * sinf(0.1f * (float)f)) + 0.05f * cosf(0.3f * (float)f);
    CHECK(s->ctx, pn_heightfield_set_heights(s->hf, s->heights, GRID, GRID));
    CHECK(s->ctx, pn_heightfield_commit(s->hf));
    pn_mesh mesh;
    CHECK(s->ctx, pn_heightfield_build_mesh(s->hf, &mesh));
    CHECK(s->ctx, pn_scene_remove_instance(s->scene, s->terrain));
    const pn_material ground = pn_material_default();
    CHECK(s->ctx, pn_scene_add_instance(s->scene, mesh, NULL, &ground, &s->terrain));
    CHECK(s->ctx, pn_scene_attach(s->scene, s->terrain, s->hf));
    pn_mesh_release(s->terrain_mesh);
    s->terrain_mesh = mesh;

    if (f > 0 && f % ENV_EVERY == 0)
        change_env(s);
    if (f > 0 && f % RENDERER_EVERY == 0)
        new_renderers(s);
    if (f > 0 && f % TARGET_EVERY == 0)
        new_targets(s);

    const int method = f % METHOD_COUNT;
    frame_param(s, method);
    if (f % PLAN_EVERY == PLAN_EVERY - 1) {
        static const int planful[3] = {2, 4, 5};
        const int m = planful[(f / PLAN_EVERY) % 3];
        int choices[PLAN_CHOICES], n = 0;
        for (int c = 0; c < PLAN_CHOICES; ++c)
            if (PLAN_VALUES[c].method == m)
                choices[n++] = c;
        const int c = choices[rnd() % (uint32_t)n];
        s->plan[c] = PLAN_VALUES[c].values[rnd() % (uint32_t)PLAN_VALUES[c].count];
        set_plan(s, c, s->plan[c]);
    }

    const float a = 0.02f * (float)f;
    const pn_camera cam = {{5.0f * sinf(a), 3.0f, 5.0f * cosf(a)}, {0, 0.3f, 0}, {0, 1, 0}, 45.0f, s->w, s->h};
    CHECK(s->ctx, pn_scene_set_camera(s->scene, &cam));
    CHECK(s->ctx, pn_scene_commit(s->scene));
    CHECK(s->ctx, pn_scene_render_gbuffer(s->scene, s->gbuffer));
    CHECK(s->ctx, pn_renderer_execute(s->renderers[method], s->scene, s->gbuffer, s->image));
    CHECK(s->ctx, pn_image_read(s->image, s->pixels, (size_t)s->w * s->h * 16));
    for (size_t i = 0; i < (size_t)s->w * s->h * 4; ++i)
        if (!isfinite(s->pixels[i])) {
            fprintf(stderr, "FAIL: frame %d (%s): pixel value %zu is not finite\n", f, METHODS[method], i / 4);
            exit(1);
        }
}

static void render(soak *s, int method)
{
    CHECK(s->ctx, pn_scene_render_gbuffer(s->scene, s->gbuffer));
    CHECK(s->ctx, pn_renderer_execute(s->renderers[method], s->scene, s->gbuffer, s->image));
    CHECK(s->ctx, pn_image_read(s->image, s->pixels, (size_t)s->w * s->h * 16));
}

/* New renderers at the starting parameter values, one render per method: the
 * state measured after the warm-up and at the end (a renderer keeps what it
 * grew for the values it was given, e.g. depthmap's rasteriser tables). */
static void settle(soak *s)
{
    for (int c = 0; c < PLAN_CHOICES; ++c)
        s->plan[c] = NAN;
    new_renderers(s);
    for (int m = 0; m < METHOD_COUNT; ++m)
        render(s, m);
    CHECK(s->ctx, pn_context_finish(s->ctx));
}

/* The height field's SH wedge tables are cached per (azimuths, bands) pair (a
 * bounded cache, capi/src/methods/sh_tables.c): render every pair the frames
 * can reach (the plan values and the default number of bands), so that no
 * table is first computed after the warm-up. */
static void prime_wedge_tables(soak *s)
{
    int az = -1, nb = -1;
    for (int c = 0; c < PLAN_CHOICES; ++c) {
        if (PLAN_VALUES[c].method == 2 && !strcmp(PLAN_VALUES[c].name, "azimuths"))
            az = c;
        if (PLAN_VALUES[c].method == 2 && !strcmp(PLAN_VALUES[c].name, "bands"))
            nb = c;
    }
    pn_method_info mi;
    double default_bands = NAN;
    CHECK(NULL, pn_method_get_info(METHODS[2], &mi));
    for (uint32_t i = 0; i < mi.param_count; ++i) {
        pn_param_info p;
        CHECK(NULL, pn_method_get_param(METHODS[2], i, &p));
        if (!strcmp(p.name, "bands"))
            default_bands = p.default_value;
    }
    if (az < 0 || nb < 0 || isnan(default_bands)) {
        fprintf(stderr, "FAIL: the heightfield plan values or its bands parameter are missing\n");
        exit(1);
    }
    for (int a = 0; a < PLAN_VALUES[az].count; ++a)
        for (int b = 0; b <= PLAN_VALUES[nb].count; ++b) {
            set_plan(s, az, PLAN_VALUES[az].values[a]);
            set_plan(s, nb, b < PLAN_VALUES[nb].count ? PLAN_VALUES[nb].values[b] : default_bands);
            render(s, 2);
        }
}

/* Every sky, every cheap plan value and every integer frame-parameter value
 * (up to its cap) rendered once before the frames: first uses (stage builds,
 * cached kernels) happen here, not after the warm-up. */
static void prime(soak *s)
{
    const pn_camera cam = {{0, 3, 5}, {0, 0.3f, 0}, {0, 1, 0}, 45.0f, s->w, s->h};
    CHECK(s->ctx, pn_scene_set_camera(s->scene, &cam));
    CHECK(s->ctx, pn_scene_commit(s->scene));
    for (int k = 0; k < 3; ++k) {
        change_env(s);
        CHECK(s->ctx, pn_scene_commit(s->scene));
        for (int m = 0; m < METHOD_COUNT; ++m)
            render(s, m);
    }
    for (int c = 0; c < PLAN_CHOICES; ++c)
        for (int v = 0; v < PLAN_VALUES[c].count; ++v) {
            set_plan(s, c, PLAN_VALUES[c].values[v]);
            render(s, PLAN_VALUES[c].method);
        }
    for (int m = 0; m < METHOD_COUNT; ++m) {
        pn_method_info mi;
        CHECK(NULL, pn_method_get_info(METHODS[m], &mi));
        for (uint32_t i = 0; i < mi.param_count; ++i) {
            pn_param_info p;
            CHECK(NULL, pn_method_get_param(METHODS[m], i, &p));
            if (p.stage != PN_PARAM_FRAME || p.type != PN_PARAM_INT)
                continue;
            const double hi = !strcmp(p.name, "cap_samples") ? 32 : !strcmp(p.name, "patch_grid") ? 8
                              : !strcmp(p.name, "pcf") ? 2 : p.max;
            for (int32_t v = (int32_t)p.min; v <= (int32_t)hi; ++v) {
                CHECK(s->ctx, pn_renderer_set_int(s->renderers[m], p.name, v));
                CHECK(s->ctx, pn_renderer_commit(s->renderers[m]));
                render(s, m);
            }
            CHECK(s->ctx, pn_renderer_set_int(s->renderers[m], p.name, (int32_t)p.default_value));
            CHECK(s->ctx, pn_renderer_commit(s->renderers[m]));
        }
    }
    prime_wedge_tables(s);
    settle(s);
}

/* A scene that adds and removes instances forever keeps memory for its live
 * ones only: CHURN additions and removals (two live at a time, committed
 * every 100) may not grow the heap by more than CHURN_SLACK bytes (one slot
 * kept per id ever given out was 136 bytes per addition). Ids keep counting
 * and removed ones stay invalid. Returns 0 on success. */
enum { CHURN = 20000, CHURN_SLACK = 256 * 1024, HEAP_BOUND = 512 /* bytes per frame */ };
static int churn_check(pn_context ctx, pn_mesh mesh)
{
    pn_scene scene;
    CHECK(ctx, pn_scene_create(ctx, &scene));
    float t[12];
    uint32_t live[2];
    translate(t, 0, 0, 0, 1);
    CHECK(ctx, pn_scene_add_instance(scene, mesh, t, NULL, &live[0]));
    CHECK(ctx, pn_scene_add_instance(scene, mesh, t, NULL, &live[1]));
    CHECK(ctx, pn_scene_commit(scene));
    const long long before = allocated_bytes();
    for (int i = 0; i < CHURN; ++i) {
        CHECK(ctx, pn_scene_remove_instance(scene, live[i % 2]));
        translate(t, (float)(i % 7), 0, 0, 1);
        CHECK(ctx, pn_scene_add_instance(scene, mesh, t, NULL, &live[i % 2]));
        if (i % 100 == 99)
            CHECK(ctx, pn_scene_commit(scene));
    }
    const long long after = allocated_bytes();
    int failed = 0;
    if (before >= 0 && after - before > CHURN_SLACK) {
        printf("FAIL: %d instance additions and removals grew the heap by %lld bytes (%.0f per addition)\n", CHURN,
               after - before, (double)(after - before) / CHURN);
        failed = 1;
    }
    if (live[0] != CHURN || live[1] != CHURN + 1) {
        printf("FAIL: the last ids are %u and %u, %u and %u expected\n", live[0], live[1], CHURN, CHURN + 1);
        failed = 1;
    }
    if (pn_scene_set_instance_transform(scene, CHURN / 2, t) != PN_ERROR_OUT_OF_RANGE) {
        printf("FAIL: removed instance %u is still accepted\n", CHURN / 2);
        failed = 1;
    }
    const char *msg;
    pn_get_error(ctx, &msg);
    printf("instance churn: %d additions and removals, heap %+lld bytes%s\n", CHURN, after - before,
           before < 0 ? " (unknown here)" : "");
    pn_scene_release(scene);
    return failed;
}

static void teardown(soak *s)
{
    for (int m = 0; m < METHOD_COUNT; ++m)
        pn_renderer_release(s->renderers[m]);
    pn_image_release(s->image);
    pn_gbuffer_release(s->gbuffer);
    pn_scene_release(s->scene);
    pn_mesh_release(s->terrain_mesh);
    pn_heightfield_release(s->hf);
    pn_sphere_set_release(s->spheres);
    pn_fiv_release(s->field);
    pn_mesh_release(s->box);
    pn_mesh_release(s->sphere);
    pn_envmap_release(s->env);
    pn_context_release(s->ctx);
    free(s->pixels);
}

int main(int argc, char **argv)
{
    const int frames = argc > 1 ? atoi(argv[1]) : 100;
    const uint32_t w = argc > 3 ? (uint32_t)atoi(argv[2]) : 64, h = argc > 3 ? (uint32_t)atoi(argv[3]) : 48;
    if (frames < 20 || !w || !h) {
        fprintf(stderr, "usage: %s [FRAMES >= 20 [WIDTH HEIGHT]]\n", argv[0]);
        return 2;
    }
    /* Warm-up: every stage built, every cheap plan value seen, the allocators filled. */
    const int warmup = frames / 10 < 20 ? 20 : frames / 10 > 500 ? 500 : frames / 10;
    static soak s;
    const double start = now();
    const long rss_start = rss_kib();
    setup(&s, w, h);
    int failed = churn_check(s.ctx, s.box);
    prime(&s);
    long rss_warm = 0, heap_warm = 0;
    cl_uint refs_warm = 0;
    for (g_frame = 0; g_frame < frames; ++g_frame) {
        frame(&s, g_frame);
        if (g_frame + 1 == warmup) {
            settle(&s);
            rss_warm = rss_kib();
            heap_warm = heap_kib();
            HEAP_PROFILE();
            refs_warm = stable_refcount(s.clc);
        }
        if ((g_frame + 1) % (frames >= 5000 ? 1000 : 100) == 0) {
            printf("frame %d: RSS %ld KiB, heap in use %ld KiB, %.0f s\n", g_frame + 1, rss_kib(), heap_kib(),
                   now() - start);
            fflush(stdout);
        }
    }
    settle(&s);
    const cl_uint refs_end = settled_refcount(s.clc, refs_warm);
    const long rss_end = rss_kib(), heap_end = heap_kib();
    HEAP_PROFILE();
    const double seconds = now() - start;
    teardown(&s);
    const cl_uint refs_after = settled_refcount(s.clc, 1);
    clReleaseContext(s.clc);

    printf("%d frames (%d warm-up) at %ux%u in %.1f s; RSS %ld KiB at start, %ld after warm-up, %ld at the end: "
           "%.1f bytes per frame after warm-up; heap in use %ld KiB after warm-up, %ld at the end: %.1f bytes per "
           "frame; cl_context references %u after warm-up, %u at the end, %u after "
           "release (1 expected)\n",
           frames, warmup, w, h, seconds, rss_start, rss_warm, rss_end,
           1024.0 * (double)(rss_end - rss_warm) / (frames - warmup), heap_warm, heap_end,
           1024.0 * (double)(heap_end - heap_warm) / (frames - warmup), refs_warm, refs_end, refs_after);
    /* The heap in use (ASan's live bytes under ASan, else mallinfo2) between
     * the two settled states: flat to the byte under ASan over 630 frames,
     * ~100 bytes per frame over 80 frames without it. */
    const double heap_per_frame = 1024.0 * (double)(heap_end - heap_warm) / (frames - warmup);
    if (heap_warm >= 0 && heap_per_frame > HEAP_BOUND) {
        printf("FAIL: the heap in use grew %.0f bytes per frame after the warm-up (bound %d)\n", heap_per_frame,
               HEAP_BOUND);
        failed = 1;
    }
    if (refs_end > refs_warm) {
        printf("FAIL: the cl_context's reference count grew from %u after warm-up to %u: OpenCL objects pile up\n",
               refs_warm, refs_end);
        failed = 1;
    }
    if (refs_after != 1) {
        printf("FAIL: %u references to the cl_context remain after every penumbra object was released\n",
               refs_after - 1);
        failed = 1;
    }
    printf(failed ? "soak FAILED\n" : "soak passed\n");
    return failed;
}
