/* Hostile input, misuse and faults (issue 17, the C library's half): each
 * case runs in a child process, so a crash (an AddressSanitizer report of a
 * use after free, a segfault) counts as that case's failure and the others
 * still run. Through the public API only.
 *
 *   lifetime_*   stale, double-released and saturated handles
 *   threads_*    8 threads on one context
 *   bake_*       meshes whose bounds overflow float
 *   fiv_header_* bake-file headers that lie (size, NaN centre)
 *   gbuffer_*    G-buffer albedo and material validation
 *   sizes_*      overflowing sizes and the PENUMBRA_MAX_BYTES cap
 *
 * Usage: test_hostile [case-name-substring]. Last line "N passed, M failed". */
#define _POSIX_C_SOURCE 200809L

#include "penumbra.h"

#include <math.h>
#include <pthread.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/wait.h>
#include <unistd.h>

#ifndef PN_REFCOUNT_MAX
#define PN_REFCOUNT_MAX 16777215 /* the documented cap; absent from older headers */
#endif
#define INVALID_HANDLE ((pn_status)-1015) /* PN_ERROR_INVALID_HANDLE */

/* Under AddressSanitizer a huge allocation returns NULL instead of taking
 * the machine's memory: a header that makes the library allocate 9.5 GB shows
 * as PN_ERROR_OUT_OF_MEMORY rather than the refusal the case expects. */
const char *__asan_default_options(void);
const char *__asan_default_options(void)
{
    return "allocator_may_return_null=1:max_allocation_size_mb=2048";
}

static int failures;

static void fail(const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    fputs("  FAIL: ", stdout);
    vprintf(fmt, ap);
    va_end(ap);
    fputc('\n', stdout);
    fflush(stdout);
    ++failures;
}

#define EXPECT(cond, ...)                                                                                    \
    do {                                                                                                     \
        if (!(cond))                                                                                         \
            fail(__VA_ARGS__);                                                                               \
    } while (0)

static const char *last_message(pn_context ctx)
{
    const char *m = NULL;
    pn_get_error(ctx, &m);
    return m ? m : "";
}

/* `st` must be `want` and the slot's message must contain `needle` (NULL: any). */
static void expect_status(const char *what, pn_status st, pn_status want, pn_context slot, const char *needle)
{
    const char *msg = last_message(slot);
    if (st != want)
        fail("%s: status %d (%s), want %d (%s); message: %s", what, (int)st, pn_status_name(st), (int)want,
             pn_status_name(want), msg);
    else if (needle && !strstr(msg, needle))
        fail("%s: message \"%s\" does not name \"%s\"", what, msg, needle);
}

/* ------------------------------------------------------------------ rigs */

static void make_box(float half, float off, float *pos, uint32_t *idx)
{
    for (int i = 0; i < 8; ++i) {
        pos[3 * i + 0] = off + ((i & 1) ? half : -half);
        pos[3 * i + 1] = off + ((i & 2) ? half : -half);
        pos[3 * i + 2] = off + ((i & 4) ? half : -half);
    }
    static const uint32_t tri[36] = {0, 2, 1, 1, 2, 3, 4, 5, 6, 5, 7, 6, 0, 1, 4, 1, 5, 4,
                                     2, 6, 3, 3, 6, 7, 0, 4, 2, 2, 4, 6, 1, 3, 5, 3, 7, 5};
    memcpy(idx, tri, sizeof tri);
}

typedef struct rig {
    pn_context ctx;
    pn_envmap env;
    pn_mesh mesh;
    pn_scene scene;
} rig;

static pn_status mesh_box(pn_context ctx, float half, float off, pn_mesh *out)
{
    float pos[24];
    uint32_t idx[36];
    make_box(half, off, pos, idx);
    pn_status st = pn_mesh_create(ctx, out);
    if (!st)
        st = pn_mesh_set_geometry(*out, pos, 8, idx, 12, NULL);
    if (!st)
        st = pn_mesh_commit(*out);
    return st;
}

static int rig_create(rig *r)
{
    memset(r, 0, sizeof *r);
    float rgb[16 * 8 * 3];
    for (size_t i = 0; i < sizeof rgb / sizeof rgb[0]; ++i)
        rgb[i] = 1.0f;
    pn_camera cam = {{0.0f, 0.0f, 3.0f}, {0.0f, 0.0f, 0.0f}, {0.0f, 1.0f, 0.0f}, 60.0f, 16, 16};
    uint32_t id;
    pn_status st = pn_context_create(NULL, &r->ctx);
    if (!st) st = pn_envmap_create(r->ctx, &r->env);
    if (!st) st = pn_envmap_set_latlong(r->env, rgb, 16, 8);
    if (!st) st = pn_envmap_set_int(r->env, "face_size", 4);
    if (!st) st = pn_envmap_set_int(r->env, "irradiance_face_size", 4);
    if (!st) st = pn_envmap_commit(r->env);
    if (!st) st = mesh_box(r->ctx, 0.5f, 0.0f, &r->mesh);
    if (!st) st = pn_scene_create(r->ctx, &r->scene);
    if (!st) st = pn_scene_set_envmap(r->scene, r->env);
    if (!st) st = pn_scene_add_instance(r->scene, r->mesh, NULL, NULL, &id);
    if (!st) st = pn_scene_set_camera(r->scene, &cam);
    if (!st) st = pn_scene_commit(r->scene);
    if (st)
        fail("building the rig: %s: %s", pn_status_name(st), last_message(r->ctx));
    return st == PN_SUCCESS;
}

static void rig_release(rig *r)
{
    if (r->scene) pn_scene_release(r->scene);
    if (r->mesh) pn_mesh_release(r->mesh);
    if (r->env) pn_envmap_release(r->env);
    if (r->ctx) pn_context_release(r->ctx);
}

/* ------------------------------------------------------- 1. lifetimes */

static void lifetime_double_release(void)
{
    pn_context ctx;
    if (pn_context_create(NULL, &ctx))
        return fail("no context");
    pn_mesh mesh;
    pn_mesh_create(ctx, &mesh);
    expect_status("first release", pn_mesh_release(mesh), PN_SUCCESS, NULL, NULL);
    expect_status("second release of the same mesh", pn_mesh_release(mesh), INVALID_HANDLE, NULL, "pn_mesh_release");
    expect_status("commit after release", pn_mesh_commit(mesh), INVALID_HANDLE, NULL, "mesh");
    pn_scene scene;
    pn_scene_create(ctx, &scene);
    pn_scene_release(scene);
    expect_status("scene commit after release", pn_scene_commit(scene), INVALID_HANDLE, NULL, "scene");
    pn_context_release(ctx);
    expect_status("context use after release", pn_context_finish(ctx), INVALID_HANDLE, NULL, "context");
    expect_status("context double release", pn_context_release(ctx), INVALID_HANDLE, NULL, NULL);
    expect_status("pn_get_error on a released context", pn_get_error(ctx, NULL), INVALID_HANDLE, NULL, NULL);
}

static void lifetime_stale_handle_reused_memory(void)
{
    pn_context ctx;
    if (pn_context_create(NULL, &ctx))
        return fail("no context");
    pn_mesh a, b;
    pn_mesh_create(ctx, &a);
    pn_mesh_release(a);
    pn_mesh_create(ctx, &b); /* typically the same memory as a */
    expect_status("stale handle after a new mesh took its place", pn_mesh_release(a), INVALID_HANDLE, NULL, NULL);
    expect_status("the new mesh is untouched", pn_mesh_release(b), PN_SUCCESS, NULL, NULL);
    pn_context_release(ctx);
    expect_status("a made-up handle", pn_mesh_commit((pn_mesh)(uintptr_t)0x1234567), INVALID_HANDLE, NULL, NULL);
}

static void lifetime_scene_holds_mesh(void)
{
    rig r;
    if (!rig_create(&r))
        return;
    expect_status("release of the caller's mesh", pn_mesh_release(r.mesh), PN_SUCCESS, NULL, NULL);
    expect_status("second release while the scene holds it", pn_mesh_release(r.mesh), INVALID_HANDLE, NULL, NULL);
    r.mesh = NULL;
    float rays[8] = {0, 0, 3, 0, 0, 0, -1, 1e30f};
    float t = 0;
    uint32_t inst = 0, tri = 0;
    expect_status("scene commit with the scene's own reference", pn_scene_commit(r.scene), PN_SUCCESS, r.ctx, NULL);
    expect_status("ray query", pn_scene_intersect(r.scene, rays, 1, &t, &inst, &tri), PN_SUCCESS, r.ctx, NULL);
    EXPECT(fabsf(t - 2.5f) < 1e-3f && inst == 0, "the scene's mesh answers a ray at t = 2.5 (got %g, %u)", (double)t,
           inst);
    /* The context outlives its handle while objects hold it. */
    pn_context ctx = r.ctx;
    expect_status("release of the context handle", pn_context_release(ctx), PN_SUCCESS, NULL, NULL);
    r.ctx = NULL;
    expect_status("scene commit after the context handle is gone", pn_scene_commit(r.scene), PN_SUCCESS, NULL, NULL);
    expect_status("a mesh from a released context handle", pn_mesh_create(ctx, &r.mesh), INVALID_HANDLE, NULL, NULL);
    /* ... but the errors of its live objects stay readable through it. */
    expect_status("an error of the scene after the context handle is gone", pn_scene_remove_instance(r.scene, 999),
                  PN_ERROR_OUT_OF_RANGE, ctx, "999");
    r.mesh = NULL;
    rig_release(&r);
}

static void lifetime_refcount_saturates(void)
{
    pn_context ctx;
    if (pn_context_create(NULL, &ctx))
        return fail("no context");
    pn_mesh mesh;
    pn_mesh_create(ctx, &mesh);
    pn_status st = PN_SUCCESS;
    long n = 1;
    while (n < PN_REFCOUNT_MAX && !(st = pn_mesh_retain(mesh)))
        ++n;
    EXPECT(st == PN_SUCCESS && n == PN_REFCOUNT_MAX, "retains up to the limit: %ld, %s", n, pn_status_name(st));
    expect_status("a retain beyond PN_REFCOUNT_MAX", pn_mesh_retain(mesh), PN_ERROR_OUT_OF_RANGE, ctx, "references");
    for (long i = 1; i < n; ++i)
        if ((st = pn_mesh_release(mesh)))
            break;
    expect_status("releases back down", st, PN_SUCCESS, NULL, NULL);
    expect_status("the object still lives", pn_mesh_commit(mesh), PN_ERROR_NOT_COMMITTED, ctx, NULL);
    expect_status("the last release", pn_mesh_release(mesh), PN_SUCCESS, NULL, NULL);
    expect_status("one more", pn_mesh_release(mesh), INVALID_HANDLE, NULL, NULL);
    pn_context_release(ctx);
}

/* ---------------------------------------------------------- threads */

typedef struct worker {
    rig *r;
    pn_renderer renderer;
    int index, errors;
    char message[512];
} worker;

static void *work(void *arg)
{
    worker *w = arg;
    pn_context ctx = w->r->ctx;
    pn_scene own = NULL; /* changed by this thread only; the rig's scene is shared, read only */
    pn_status st = pn_scene_create(ctx, &own);
    if (!st) st = pn_scene_set_envmap(own, w->r->env);
    for (int it = 0; it < 6 && !st; ++it) {
        pn_gbuffer gb = NULL;
        pn_image img = NULL;
        pn_mesh m = NULL;
        uint32_t id = 0;
        float px[16 * 16 * 4];
        st = pn_gbuffer_create(ctx, 16, 16, &gb);
        if (!st) st = pn_image_create(ctx, 16, 16, &img);
        if (!st) st = pn_scene_render_gbuffer(w->r->scene, gb);
        if (!st) st = pn_renderer_execute(w->renderer, w->r->scene, gb, img);
        if (!st) st = pn_image_read(img, px, sizeof px);
        /* The centre pixel sees the box: lit, finite. */
        if (!st && !(px[(8 * 16 + 8) * 4] > 0.0f && isfinite(px[(8 * 16 + 8) * 4])))
            st = PN_ERROR_INTERNAL;
        if (!st) st = mesh_box(ctx, 0.25f, (float)w->index, &m);
        if (!st) st = pn_scene_add_instance(own, m, NULL, NULL, &id);
        if (!st) st = pn_scene_commit(own);
        if (!st && it % 2) st = pn_scene_remove_instance(own, id);
        if (m) pn_mesh_release(m);
        if (img) pn_image_release(img);
        if (gb) pn_gbuffer_release(gb);
    }
    if (st) {
        w->errors++;
        snprintf(w->message, sizeof w->message, "%s: %s", pn_status_name(st), last_message(ctx));
    }
    if (own) pn_scene_release(own);
    return NULL;
}

static void threads_one_context(void)
{
    rig r;
    if (!rig_create(&r))
        return;
    enum { N = 8 };
    worker w[N];
    pthread_t t[N];
    for (int i = 0; i < N; ++i) {
        memset(&w[i], 0, sizeof w[i]);
        w[i].r = &r;
        w[i].index = i + 2;
        if (i % 2 == 0 || i == 1) { /* some share a renderer, some have their own */
            pn_renderer_create(r.ctx, "unshadowed", &w[i].renderer);
            pn_renderer_commit(w[i].renderer);
        } else {
            w[i].renderer = w[i - 1].renderer;
            pn_renderer_retain(w[i].renderer);
        }
    }
    for (int i = 0; i < N; ++i)
        pthread_create(&t[i], NULL, work, &w[i]);
    for (int i = 0; i < N; ++i)
        pthread_join(t[i], NULL);
    for (int i = 0; i < N; ++i) {
        EXPECT(w[i].errors == 0, "thread %d: %s", i, w[i].message);
        pn_renderer_release(w[i].renderer);
    }
    rig_release(&r);
}

/* A handle released by one thread while others use it: each call either works
 * or answers PN_ERROR_INVALID_HANDLE, never a crash. */
typedef struct racer {
    pn_mesh mesh;
    int bad;
} racer;

static void *race_use(void *arg)
{
    racer *r = arg;
    for (int i = 0; i < 2000; ++i) {
        pn_mesh_info info;
        pn_status st = pn_mesh_get_info(r->mesh, &info);
        if (st != PN_SUCCESS && st != INVALID_HANDLE)
            r->bad++;
    }
    return NULL;
}

static void threads_release_race(void)
{
    pn_context ctx;
    if (pn_context_create(NULL, &ctx))
        return fail("no context");
    for (int round = 0; round < 20; ++round) {
        racer rc = {NULL, 0};
        if (mesh_box(ctx, 0.5f, 0.0f, &rc.mesh))
            return fail("mesh");
        pthread_t t[4];
        for (int i = 0; i < 4; ++i)
            pthread_create(&t[i], NULL, race_use, &rc);
        pn_mesh_release(rc.mesh);
        for (int i = 0; i < 4; ++i)
            pthread_join(t[i], NULL);
        EXPECT(rc.bad == 0, "round %d: %d calls failed otherwise than PN_ERROR_INVALID_HANDLE", round, rc.bad);
    }
    pn_context_release(ctx);
}

/* ------------------------------------------------------------- 2. bake */

static void bake_mesh_bounds_overflow(void)
{
    pn_context ctx;
    if (pn_context_create(NULL, &ctx))
        return fail("no context");
    float pos[24];
    uint32_t idx[36];
    make_box(3e38f, 0.0f, pos, idx); /* each coordinate finite, the extent 6e38 is not */
    pn_mesh mesh;
    pn_mesh_create(ctx, &mesh);
    expect_status("a mesh whose extent overflows float", pn_mesh_set_geometry(mesh, pos, 8, idx, 12, NULL),
                  PN_ERROR_INVALID_VALUE, ctx, "overflow");
    pn_mesh_release(mesh);
    pn_context_release(ctx);
}

/* The smallest bake worth making: 4 x 3 x 2 samples, cube face 2. */
static pn_fiv_options tiny_fiv_options(void)
{
    pn_fiv_options o = pn_fiv_options_default();
    o.theta = 3;
    o.phi = 4;
    o.radii = 2;
    o.face_size = 2;
    o.sun_supersampling = 1;
    return o;
}

/* A file name of its own in /tmp from a mkstemp template (XXXXXX), not yet
 * existing: runs of the suite side by side must not share files. */
static void unique_path(char *path)
{
    int fd = mkstemp(path);
    if (fd >= 0)
        close(fd);
    remove(path);
}

static void bake_outer_sphere_overflow(void)
{
    rig r;
    if (!rig_create(&r))
        return;
    pn_mesh big;
    /* Extent 6e37 (fine), bounding radius 5.2e37, outermost sphere at 10 R: overflows float. */
    pn_status st = mesh_box(r.ctx, 3e37f, 0.0f, &big);
    expect_status("a large but representable mesh", st, PN_SUCCESS, r.ctx, NULL);
    if (st)
        return rig_release(&r);
    pn_fiv_options o = tiny_fiv_options();
    char path[] = "/tmp/pn_hostile_bake_XXXXXX";
    unique_path(path);
    pn_fiv fiv = NULL;
    st = pn_fiv_bake(r.env, big, &o, path, NULL, NULL, &fiv);
    if (st == PN_SUCCESS) {
        /* Whatever the bake accepts, its own loader must accept. */
        pn_fiv back = NULL;
        expect_status("loading the bake's own file", pn_fiv_load(r.ctx, path, &back), PN_SUCCESS, r.ctx, NULL);
        if (back)
            pn_fiv_release(back);
        pn_fiv_release(fiv);
    } else {
        expect_status("the bake refuses an overflowing bounding sphere", st, PN_ERROR_INVALID_VALUE, r.ctx, "overflow");
        EXPECT(access(path, F_OK) != 0, "a refused bake wrote %s", path);
    }
    remove(path);
    pn_mesh_release(big);
    rig_release(&r);
}

/* --------------------------------------------------------- 3. fiv headers */

static uint64_t fnv1a(const unsigned char *p, size_t n)
{
    uint64_t h = 0xcbf29ce484222325ull;
    for (size_t i = 0; i < n; ++i) {
        h ^= p[i];
        h *= 0x100000001b3ull;
    }
    return h;
}

static void put_u32(unsigned char *p, uint32_t v)
{
    for (int i = 0; i < 4; ++i)
        p[i] = (unsigned char)(v >> (8 * i));
}

static void reseal(unsigned char *h)
{
    const uint64_t sum = fnv1a(h, 248);
    for (int i = 0; i < 8; ++i)
        h[248 + i] = (unsigned char)(sum >> (8 * i));
}

/* A small finished bake file at `path`, its header in h[256]. */
static int small_bake(rig *r, const char *path, unsigned char *h)
{
    pn_fiv_options o = tiny_fiv_options();
    pn_fiv fiv;
    pn_status st = pn_fiv_bake(r->env, r->mesh, &o, NULL, NULL, NULL, &fiv);
    if (!st) {
        st = pn_fiv_save(fiv, path);
        pn_fiv_release(fiv);
    }
    FILE *f = st ? NULL : fopen(path, "rb");
    const int ok = f && fread(h, 1, 256, f) == 256;
    if (f)
        fclose(f);
    if (!ok)
        fail("making a small bake file: %s", pn_status_name(st));
    return ok;
}

static void write_file(const char *path, const unsigned char *h, size_t n)
{
    FILE *f = fopen(path, "wb");
    if (f) {
        fwrite(h, 1, n, f);
        fclose(f);
    }
}

static void fiv_header_promises_more_than_the_file(void)
{
    rig r;
    if (!rig_create(&r))
        return;
    char path[] = "/tmp/pn_hostile_header_XXXXXX";
    unique_path(path);
    unsigned char h[256];
    if (small_bake(&r, path, h)) {
        put_u32(h + 16, 1025);
        put_u32(h + 20, 2048);
        put_u32(h + 24, 127);
        put_u32(h + 28, 127);
        reseal(h);
        write_file(path, h, 256); /* the header alone: 256 bytes promising 9.5 GB */
        pn_fiv fiv = NULL;
        expect_status("a 256-byte file promising a 1025x2048x127 grid", pn_fiv_load(r.ctx, path, &fiv), PN_ERROR_FILE,
                      r.ctx, "bytes");
        pn_fiv_info info;
        expect_status("its header alone", pn_fiv_read_header(path, &info), PN_ERROR_FILE, NULL, "bytes");
    }
    remove(path);
    rig_release(&r);
}

static void fiv_header_nan_centre(void)
{
    rig r;
    if (!rig_create(&r))
        return;
    char path[] = "/tmp/pn_hostile_nan_XXXXXX";
    unique_path(path);
    unsigned char h[256];
    if (small_bake(&r, path, h)) {
        FILE *f = fopen(path, "rb");
        unsigned char buf[65536];
        size_t n = f ? fread(buf, 1, sizeof buf, f) : 0;
        if (f)
            fclose(f);
        const float bad[] = {NAN, INFINITY, -INFINITY};
        const int offsets[] = {56, 60, 64, 68, 72, 76};
        for (int k = 0; k < 3; ++k)
            for (int j = 0; j < 6; ++j) {
                memcpy(buf, h, 256);
                uint32_t u;
                memcpy(&u, &bad[k], 4);
                put_u32(buf + offsets[j], u);
                reseal(buf);
                write_file(path, buf, n);
                pn_fiv fiv = NULL;
                char what[128];
                snprintf(what, sizeof what, "header float at %d = %g with its checksum recomputed", offsets[j],
                         (double)bad[k]);
                expect_status(what, pn_fiv_load(r.ctx, path, &fiv), PN_ERROR_FILE, r.ctx, "corrupt");
                if (fiv)
                    pn_fiv_release(fiv);
                pn_fiv_info info;
                expect_status(what, pn_fiv_read_header(path, &info), PN_ERROR_FILE, NULL, "corrupt");
            }
    }
    remove(path);
    rig_release(&r);
}

/* ------------------------------------------------------------- 4. G-buffer */

static void gbuffer_albedo_and_material(void)
{
    pn_context ctx;
    if (pn_context_create(NULL, &ctx))
        return fail("no context");
    enum { W = 4, H = 3, N = W * H };
    pn_gbuffer gb;
    if (pn_gbuffer_create(ctx, W, H, &gb))
        return fail("G-buffer: %s", last_message(ctx));
    float pos[N * 4], nrm[N * 4], alb[N * 4], mat[N * 4];
    uint32_t inst[N];
    for (int i = 0; i < N; ++i) {
        const float p[4] = {0, 0, 0, 1}, n[4] = {0, 0, 1, 0}, a[4] = {0.5f, 0.5f, 0.5f, 0}, m[4] = {10, 0.3f, 0, 0};
        memcpy(pos + 4 * i, p, sizeof p);
        memcpy(nrm + 4 * i, n, sizeof n);
        memcpy(alb + 4 * i, a, sizeof a);
        memcpy(mat + 4 * i, m, sizeof m);
        inst[i] = 0;
    }
    pn_gbuffer_write(gb, PN_GBUFFER_POSITION, pos, sizeof pos);
    pn_gbuffer_write(gb, PN_GBUFFER_NORMAL, nrm, sizeof nrm);
    pn_gbuffer_write(gb, PN_GBUFFER_MATERIAL, mat, sizeof mat);
    pn_gbuffer_write(gb, PN_GBUFFER_INSTANCE, inst, sizeof inst);
    pn_gbuffer_write(gb, PN_GBUFFER_ALBEDO, alb, sizeof alb);
    expect_status("a valid G-buffer", pn_gbuffer_validate(gb), PN_SUCCESS, ctx, NULL);
    const int px = 1 * W + 2; /* (x=2, y=1) */
    struct {
        int plane, component;
        float value;
        const char *names;
    } cases[] = {
        {PN_GBUFFER_ALBEDO, 0, INFINITY, "albedo"},     {PN_GBUFFER_ALBEDO, 1, NAN, "albedo"},
        {PN_GBUFFER_ALBEDO, 2, -0.5f, "albedo"},        {PN_GBUFFER_ALBEDO, 3, 2.0f, "specular"},
        {PN_GBUFFER_MATERIAL, 0, -1.0f, "shininess"},   {PN_GBUFFER_MATERIAL, 0, INFINITY, "shininess"},
        {PN_GBUFFER_MATERIAL, 1, 7.0f, "roughness"},    {PN_GBUFFER_MATERIAL, 2, 9.0f, "lobe"},
        {PN_GBUFFER_MATERIAL, 2, 0.5f, "lobe"},
    };
    for (size_t c = 0; c < sizeof cases / sizeof cases[0]; ++c) {
        float *plane = cases[c].plane == PN_GBUFFER_ALBEDO ? alb : mat;
        const float keep = plane[4 * px + cases[c].component];
        plane[4 * px + cases[c].component] = cases[c].value;
        pn_gbuffer_write(gb, (pn_gbuffer_plane)cases[c].plane, plane, sizeof alb);
        char what[128];
        snprintf(what, sizeof what, "%s = %g at (2, 1)", cases[c].names, (double)cases[c].value);
        pn_status st = pn_gbuffer_validate(gb);
        const char *msg = last_message(ctx);
        EXPECT(st == PN_ERROR_INVALID_VALUE && strstr(msg, cases[c].names) && strstr(msg, "x=2, y=1"),
               "%s: %s, \"%s\"", what, pn_status_name(st), msg);
        plane[4 * px + cases[c].component] = keep;
        pn_gbuffer_write(gb, (pn_gbuffer_plane)cases[c].plane, plane, sizeof alb);
    }
    /* Background pixels are not shaded and not checked. */
    alb[4 * px] = INFINITY;
    inst[px] = PN_BACKGROUND;
    pn_gbuffer_write(gb, PN_GBUFFER_ALBEDO, alb, sizeof alb);
    pn_gbuffer_write(gb, PN_GBUFFER_INSTANCE, inst, sizeof inst);
    expect_status("a background pixel's albedo is not checked", pn_gbuffer_validate(gb), PN_SUCCESS, ctx, NULL);
    pn_gbuffer_release(gb);
    pn_context_release(ctx);
}

/* ---------------------------------------------------------------- 5. sizes */

static void sizes_overflowing_products(void)
{
    pn_context ctx;
    if (pn_context_create(NULL, &ctx))
        return fail("no context");
    float small[12] = {0};
    uint32_t idx[3] = {0, 1, 2};
    pn_envmap env;
    pn_envmap_create(ctx, &env);
    /* 2^31 x 2^31 x 3 floats: the product overflows 64 bits; the library must refuse before reading. */
    expect_status("env map 2^31 x 2^31", pn_envmap_set_latlong(env, small, 1u << 31, 1u << 31), PN_ERROR_INVALID_SIZE,
                  ctx, "too large");
    expect_status("env map 65536 x 32768 (24 GiB)", pn_envmap_set_latlong(env, small, 65536, 32768),
                  PN_ERROR_INVALID_SIZE, ctx, "too large");
    pn_mesh mesh;
    pn_mesh_create(ctx, &mesh);
    expect_status("mesh of 2^32-1 vertices", pn_mesh_set_geometry(mesh, small, UINT32_MAX, idx, 1, NULL),
                  PN_ERROR_INVALID_SIZE, ctx, "PENUMBRA_MAX_BYTES");
    expect_status("mesh of 2^32-1 triangles", pn_mesh_set_geometry(mesh, small, 3, idx, UINT32_MAX, NULL),
                  PN_ERROR_INVALID_SIZE, ctx, "PENUMBRA_MAX_BYTES");
    pn_gbuffer gb = NULL;
    expect_status("G-buffer 65536 x 65536", pn_gbuffer_create(ctx, 65536, 65536, &gb), PN_ERROR_INVALID_SIZE, ctx,
                  "32768");
    expect_status("G-buffer 32768 x 32768 (84 GiB)", pn_gbuffer_create(ctx, 32768, 32768, &gb), PN_ERROR_INVALID_SIZE,
                  ctx, "PENUMBRA_MAX_BYTES");
    pn_image img = NULL;
    expect_status("image 32768 x 32768 (16 GiB)", pn_image_create(ctx, 32768, 32768, &img), PN_ERROR_INVALID_SIZE, ctx,
                  "PENUMBRA_MAX_BYTES");
    pn_heightfield hf;
    pn_heightfield_create(ctx, &hf);
    expect_status("height field 2^20 x 2^20", pn_heightfield_set_heights(hf, small, 1u << 20, 1u << 20),
                  PN_ERROR_INVALID_SIZE, ctx, "too large");

    pn_heightfield_release(hf);
    pn_mesh_release(mesh);
    pn_envmap_release(env);
    pn_context_release(ctx);
}

static void sizes_cap_from_environment(void)
{
    setenv("PENUMBRA_MAX_BYTES", "4096", 1);
    pn_context ctx;
    if (pn_context_create(NULL, &ctx))
        return fail("no context");
    enum { V = 1000 };
    float *pos = calloc(3 * V, sizeof(float));
    uint32_t idx[3] = {0, 1, 2};
    pn_mesh mesh;
    pn_mesh_create(ctx, &mesh);
    expect_status("12 kB of vertices under PENUMBRA_MAX_BYTES=4096", pn_mesh_set_geometry(mesh, pos, V, idx, 1, NULL),
                  PN_ERROR_INVALID_SIZE, ctx, "4096");
    expect_status("a small mesh under it", pn_mesh_set_geometry(mesh, pos, 3, idx, 1, NULL), PN_SUCCESS, ctx, NULL);
    pn_image img = NULL;
    expect_status("a 32x32 image (16 kB) under it", pn_image_create(ctx, 32, 32, &img), PN_ERROR_INVALID_SIZE, ctx,
                  "PENUMBRA_MAX_BYTES");
    pn_heightfield hf;
    pn_heightfield_create(ctx, &hf);
    float *heights = calloc(64 * 64, sizeof(float));
    expect_status("64 x 64 heights under it", pn_heightfield_set_heights(hf, heights, 64, 64), PN_ERROR_INVALID_SIZE,
                  ctx, "PENUMBRA_MAX_BYTES");
    free(heights);
    pn_heightfield_release(hf);
    setenv("PENUMBRA_MAX_BYTES", "1M", 1);
    expect_status("PENUMBRA_MAX_BYTES=1M", pn_mesh_set_geometry(mesh, pos, V, idx, 1, NULL), PN_SUCCESS, ctx, NULL);
    setenv("PENUMBRA_MAX_BYTES", "lots", 1);
    expect_status("a PENUMBRA_MAX_BYTES that is not a number", pn_mesh_set_geometry(mesh, pos, 3, idx, 1, NULL),
                  PN_ERROR_BAD_CONFIG, ctx, "PENUMBRA_MAX_BYTES");
    unsetenv("PENUMBRA_MAX_BYTES");
    free(pos);
    pn_mesh_release(mesh);
    pn_context_release(ctx);
}

/* ----------------------------------------------------------------- main */

typedef struct test_case {
    const char *name;
    void (*run)(void);
} test_case;

static const test_case cases[] = {
    {"lifetime_double_release", lifetime_double_release},
    {"lifetime_stale_handle_reused_memory", lifetime_stale_handle_reused_memory},
    {"lifetime_scene_holds_mesh", lifetime_scene_holds_mesh},
    {"lifetime_refcount_saturates", lifetime_refcount_saturates},
    {"threads_one_context", threads_one_context},
    {"threads_release_race", threads_release_race},
    {"bake_mesh_bounds_overflow", bake_mesh_bounds_overflow},
    {"bake_outer_sphere_overflow", bake_outer_sphere_overflow},
    {"fiv_header_promises_more_than_the_file", fiv_header_promises_more_than_the_file},
    {"fiv_header_nan_centre", fiv_header_nan_centre},
    {"gbuffer_albedo_and_material", gbuffer_albedo_and_material},
    {"sizes_overflowing_products", sizes_overflowing_products},
    {"sizes_cap_from_environment", sizes_cap_from_environment},
};

int main(int argc, char **argv)
{
    setvbuf(stdout, NULL, _IOLBF, 0);
    int passed = 0, failed = 0;
    for (size_t i = 0; i < sizeof cases / sizeof cases[0]; ++i) {
        if (argc > 1 && !strstr(cases[i].name, argv[1]))
            continue;
        printf("%s\n", cases[i].name);
        fflush(stdout);
        pid_t pid = fork();
        if (pid == 0) {
            failures = 0;
            cases[i].run();
            fflush(stdout);
            _exit(failures ? 1 : 0);
        }
        int status = 0;
        waitpid(pid, &status, 0);
        const int ok = WIFEXITED(status) && WEXITSTATUS(status) == 0;
        if (!ok)
            printf("FAIL: %s (%s %d)\n", cases[i].name, WIFSIGNALED(status) ? "signal" : "exit",
                   WIFSIGNALED(status) ? WTERMSIG(status) : WEXITSTATUS(status));
        ok ? ++passed : ++failed;
    }
    printf("%d passed, %d failed\n", passed, failed);
    return failed ? 1 : 0;
}
