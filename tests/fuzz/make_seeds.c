/* Writes the seed corpora of the fuzz targets into <dir>/<target>/ (the
 * committed ones in tests/fuzz/corpus were made by it): small bake files made
 * by the library itself (finished and a checkpoint, float16 and float32),
 * configuration strings and parameter names. Usage: fuzz_make_seeds DIR. */
#define _POSIX_C_SOURCE 200809L
#include "penumbra.h"

#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

static void put(const char *dir, const char *target, const char *name, const void *data, size_t size)
{
    char path[1024];
    snprintf(path, sizeof path, "%s/%s", dir, target);
    mkdir(path, 0777);
    snprintf(path, sizeof path, "%s/%s/%s", dir, target, name);
    FILE *f = fopen(path, "wb");
    if (!f || fwrite(data, 1, size, f) != size) {
        fprintf(stderr, "cannot write %s\n", path);
        exit(1);
    }
    fclose(f);
}

static int copy_file(const char *dir, const char *target, const char *name, const char *from)
{
    FILE *f = fopen(from, "rb");
    if (!f)
        return 0;
    static unsigned char buf[1 << 16];
    size_t n = fread(buf, 1, sizeof buf, f);
    fclose(f);
    put(dir, target, name, buf, n);
    return 1;
}

static int progress_stop(void *user, uint64_t done, uint64_t total)
{
    (void)user;
    return done < total; /* stop after the first sphere: a checkpoint */
}

int main(int argc, char **argv)
{
    if (argc != 2) {
        fprintf(stderr, "usage: %s DIR\n", argv[0]);
        return 2;
    }
    const char *dir = argv[1];
    mkdir(dir, 0777);
    pn_context ctx;
    pn_envmap env;
    pn_mesh mesh;
    float rgb[8 * 4 * 3];
    for (size_t i = 0; i < sizeof rgb / sizeof rgb[0]; ++i)
        rgb[i] = (float)(i % 7) * 0.25f;
    const float pos[] = {-1, -1, -1, 1, -1, -1, -1, 1, -1, 1, 1, -1, -1, -1, 1, 1, -1, 1, -1, 1, 1, 1, 1, 1};
    const uint32_t idx[] = {0, 2, 1, 1, 2, 3, 4, 5, 6, 5, 7, 6, 0, 1, 4, 1, 5, 4,
                            2, 6, 3, 3, 6, 7, 0, 4, 2, 2, 4, 6, 1, 3, 5, 3, 7, 5};
    if (pn_context_create(NULL, &ctx) || pn_envmap_create(ctx, &env) || pn_envmap_set_latlong(env, rgb, 8, 4) ||
        pn_envmap_set_int(env, "face_size", 2) || pn_envmap_set_int(env, "irradiance_face_size", 2) ||
        pn_envmap_commit(env) || pn_mesh_create(ctx, &mesh) || pn_mesh_set_geometry(mesh, pos, 8, idx, 12, NULL) ||
        pn_mesh_commit(mesh)) {
        const char *m = NULL;
        pn_get_error(ctx, &m);
        fprintf(stderr, "setting up: %s\n", m ? m : "");
        return 1;
    }
    const char *tmp = "/tmp/pn_fuzz_seed.pnfiv";
    for (int precision = 0; precision < 2; ++precision) {
        pn_fiv_options o = pn_fiv_options_default();
        o.theta = 3;
        o.phi = 4;
        o.radii = 2;
        o.face_size = 2;
        o.sun_supersampling = 1;
        o.precision = precision ? PN_PRECISION_FLOAT32 : PN_PRECISION_FLOAT16;
        pn_fiv fiv;
        remove(tmp);
        if (pn_fiv_bake(env, mesh, &o, NULL, NULL, NULL, &fiv) || pn_fiv_save(fiv, tmp))
            return 1;
        pn_fiv_release(fiv);
        const char *name = precision ? "finished_f32.pnfiv" : "finished_f16.pnfiv";
        copy_file(dir, "fuzz_fiv_header", name, tmp);
        copy_file(dir, "fuzz_fiv_load", name, tmp);
        /* A checkpoint: one sphere of two, then cancelled. */
        o.radii = 3;
        remove(tmp);
        fiv = NULL;
        pn_fiv_bake(env, mesh, &o, tmp, progress_stop, NULL, &fiv);
        if (fiv)
            pn_fiv_release(fiv);
        name = precision ? "checkpoint_f32.pnfiv" : "checkpoint_f16.pnfiv";
        copy_file(dir, "fuzz_fiv_header", name, tmp);
        copy_file(dir, "fuzz_fiv_load", name, tmp);
    }
    remove(tmp);
    static const char *const configs[] = {"", "device=cpu", "device=default,platform=portable",
                                          "device=0,build_options=-cl-fast-relaxed-math", "device=gpu", "platform=x"};
    for (size_t i = 0; i < sizeof configs / sizeof configs[0]; ++i) {
        char name[32];
        snprintf(name, sizeof name, "config_%zu", i);
        put(dir, "fuzz_config", name, configs[i], strlen(configs[i]));
    }
    /* fuzz_params: selector byte, 4 value bytes, then the name. */
    static const struct { unsigned char selector; float value; const char *name; } params[] = {
        {0, 0.0f, "unshadowed"}, {0, 3.0f, "fiv"},           {1, 1.0f, "background"}, {2, 0.5f, "exposure"},
        {3, 16.0f, "face_size"}, {3, 90.0f, "rotation_deg"}, {4, 0.0f, "4G"},        {4, 0.0f, "12345"},
        {5, 1.0f, "heightfield"},
    };
    for (size_t i = 0; i < sizeof params / sizeof params[0]; ++i) {
        unsigned char buf[64];
        buf[0] = params[i].selector;
        memcpy(buf + 1, &params[i].value, 4);
        const size_t n = strlen(params[i].name);
        memcpy(buf + 5, params[i].name, n);
        char name[32];
        snprintf(name, sizeof name, "param_%zu", i);
        put(dir, "fuzz_params", name, buf, 5 + n);
    }
    pn_mesh_release(mesh);
    pn_envmap_release(env);
    pn_context_release(ctx);
    return 0;
}
