/* render_scene: a standalone consumer of libpenumbra.
 *
 *   render_scene ENV.hdr|ENV.exr OUT.pfm [WIDTH HEIGHT [METHOD]]
 *
 * Reads a lat-long environment map from a Radiance .hdr file (through
 * stb_image, Debian's libstb-dev: `pkg-config stb`) or, when OpenEXR's
 * development files were found at configure time (`pkg-config OpenEXR`,
 * Debian's libopenexr-dev), from an OpenEXR file through its C API
 * (OpenEXRCore), builds a small scene in
 * C (a unit box standing on a ground quad), renders it with the "unshadowed"
 * method (or METHOD; the library's method metadata says what the method
 * reads: for one that reads occlusion fields, such as "fiv", the box's field
 * is baked on a small 16x9x8 grid and attached to the box, so it casts soft
 * shadows) and writes the RGB result as a PFM file (float32, exact; written
 * to a temporary file beside OUT.pfm, then renamed over it).
 *
 * .hdr: stb_image decodes RGBE (flat or run-length encoded scanlines, the
 * "-Y H +X W" orientation every Radiance map uses) to linear floats, top row
 * first, as penumbra takes them. It does not apply the header's EXPOSURE or
 * COLORCORR (penumbra.imageio.read_envmap divides them out).
 * PFM output: a text header "PF\n<width> <height>\n-1.0\n" followed by
 * little-endian 32-bit floats with the rows stored bottom-to-top, so rows
 * are flipped on the way out. */
#define _POSIX_C_SOURCE 200809L

#include <penumbra.h>
#include <stb_image.h>
#ifdef RENDER_SCENE_OPENEXR
#include <openexr.h>
#endif

#include <errno.h>
#include <fcntl.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

/* ------------------------------------------------------------ env map in */

#ifdef RENDER_SCENE_OPENEXR
/* Returns width*height RGB triples of a scanline OpenEXR file's R, G and B
 * channels (half, float or uint, converted to float by OpenEXRCore), top row
 * first (free with free()), or NULL with a message on stderr. */
static float *read_exr(const char *path, uint32_t *width, uint32_t *height)
{
    exr_context_t exr = NULL;
    exr_context_initializer_t init = EXR_DEFAULT_CONTEXT_INITIALIZER;
    exr_decode_pipeline_t decoder = EXR_DECODE_PIPELINE_INITIALIZER;
    int decoder_ready = 0;
    float *rgb = NULL;
    const char *problem = NULL;
    exr_result_t rv = exr_start_read(&exr, path, &init);
    exr_storage_t storage;
    exr_attr_box2i_t dw;
    const exr_attr_chlist_t *channels = NULL;
    int32_t lines_per_chunk = 0;
    if (rv != EXR_ERR_SUCCESS)
        goto fail;
    if ((rv = exr_get_storage(exr, 0, &storage)) || (rv = exr_get_data_window(exr, 0, &dw)) ||
        (rv = exr_get_channels(exr, 0, &channels)) || (rv = exr_get_scanlines_per_chunk(exr, 0, &lines_per_chunk)))
        goto fail;
    if (storage != EXR_STORAGE_SCANLINE) {
        problem = "only scanline images are read (this one is tiled or deep)";
        goto fail;
    }
    const int64_t w = (int64_t)dw.max.x - dw.min.x + 1, h = (int64_t)dw.max.y - dw.min.y + 1;
    if (w < 1 || h < 1 || w > 65536 || h > 65536) {
        problem = "its data window is empty or larger than 65536 pixels on a side";
        goto fail;
    }
    int found = 0;
    for (int32_t c = 0; c < channels->num_channels; ++c) {
        const exr_attr_chlist_entry_t *e = &channels->entries[c];
        if (e->name.length == 1 && e->name.str[0] && strchr("RGB", e->name.str[0])) {
            if (e->x_sampling != 1 || e->y_sampling != 1) {
                problem = "its R, G or B channel is subsampled";
                goto fail;
            }
            found |= 1 << (strchr("RGB", e->name.str[0]) - "RGB");
        }
    }
    if (found != 7) {
        problem = "it has no R, G and B channels";
        goto fail;
    }
    rgb = calloc((size_t)w * (size_t)h * 3, sizeof *rgb);
    if (!rgb) {
        problem = "out of memory";
        goto fail;
    }
    for (int64_t y = dw.min.y; y <= dw.max.y; y += lines_per_chunk) {
        exr_chunk_info_t chunk;
        if ((rv = exr_read_scanline_chunk_info(exr, 0, (int)y, &chunk)))
            goto fail;
        rv = decoder_ready ? exr_decoding_update(exr, 0, &chunk, &decoder)
                           : exr_decoding_initialize(exr, 0, &chunk, &decoder);
        if (rv)
            goto fail;
        decoder_ready = 1;
        for (int16_t c = 0; c < decoder.channel_count; ++c) {
            exr_coding_channel_info_t *ch = &decoder.channels[c];
            const char *name = ch->channel_name;
            const char *slot = name && name[0] && !name[1] ? strchr("RGB", name[0]) : NULL;
            if (!slot) {
                ch->decode_to_ptr = NULL; /* other channels (A, Z, ...) are skipped */
                continue;
            }
            const size_t row = (size_t)(chunk.start_y - dw.min.y);
            ch->decode_to_ptr = (uint8_t *)(rgb + row * (size_t)w * 3 + (size_t)(slot - "RGB"));
            ch->user_pixel_stride = 3 * (int32_t)sizeof(float);
            ch->user_line_stride = (int32_t)(w * 3 * (int64_t)sizeof(float));
            ch->user_bytes_per_element = sizeof(float);
            ch->user_data_type = EXR_PIXEL_FLOAT;
        }
        if ((rv = exr_decoding_choose_default_routines(exr, 0, &decoder)) || (rv = exr_decoding_run(exr, 0, &decoder)))
            goto fail;
    }
    if (decoder_ready)
        exr_decoding_destroy(exr, &decoder);
    exr_finish(&exr);
    *width = (uint32_t)w;
    *height = (uint32_t)h;
    return rgb;
fail:
    fprintf(stderr, "render_scene: cannot read %s: %s\n", path,
            problem ? problem : exr_get_default_error_message(rv));
    if (decoder_ready)
        exr_decoding_destroy(exr, &decoder);
    if (exr)
        exr_finish(&exr);
    free(rgb);
    return NULL;
}
#endif

/* Returns width*height RGB triples, top row first (free with free()), or
 * NULL with a message on stderr. Radiance .hdr files through stb_image, and
 * OpenEXR files when the example was built with OpenEXR (RENDER_SCENE_OPENEXR,
 * found by pkg-config). Other image files are refused: stb_image would also
 * decode an 8-bit PNG or JPEG, but guessing its radiance (an inverse gamma of
 * 2.2, up to 1) would light the scene with made-up values. */
static float *read_envmap(const char *path, uint32_t *width, uint32_t *height)
{
    FILE *f = fopen(path, "rb");
    if (!f) {
        fprintf(stderr, "render_scene: cannot open %s: %s\n", path, strerror(errno));
        return NULL;
    }
    unsigned char magic[4] = {0};
    const size_t got = fread(magic, 1, 4, f);
    rewind(f);
    const int hdr = stbi_is_hdr_from_file(f);
    fclose(f);
    const int exr = got == 4 && magic[0] == 0x76 && magic[1] == 0x2f && magic[2] == 0x31 && magic[3] == 0x01;
    if (exr) {
#ifdef RENDER_SCENE_OPENEXR
        return read_exr(path, width, height);
#else
        fprintf(stderr, "render_scene: %s is an OpenEXR file, and this build has no OpenEXR (install OpenEXR's "
                "development files, e.g. Debian's libopenexr-dev, and configure again)\n", path);
        return NULL;
#endif
    }
    if (!hdr) {
        fprintf(stderr, "render_scene: %s is not a Radiance .hdr file (no \"#?RADIANCE\" or \"#?RGBE\" header)"
#ifdef RENDER_SCENE_OPENEXR
                " nor an OpenEXR file"
#endif
                "\n", path);
        return NULL;
    }
    int w = 0, h = 0, channels = 0;
    float *stb = stbi_loadf(path, &w, &h, &channels, 3);
    if (!stb) {
        fprintf(stderr, "render_scene: cannot read %s: %s\n", path, stbi_failure_reason());
        return NULL;
    }
    /* A copy in memory of our own, so every reader's result is freed with free(). */
    float *rgb = malloc((size_t)w * (size_t)h * 3 * sizeof *rgb);
    if (rgb)
        memcpy(rgb, stb, (size_t)w * (size_t)h * 3 * sizeof *rgb);
    else
        fprintf(stderr, "render_scene: out of memory reading %s\n", path);
    stbi_image_free(stb);
    *width = (uint32_t)w;
    *height = (uint32_t)h;
    return rgb;
}

/* --------------------------------------------------------------- image out */

static int host_is_little_endian(void)
{
    const uint16_t one = 1;
    unsigned char first;
    memcpy(&first, &one, 1);
    return first == 1;
}

static void swap_floats(float *v, size_t n)
{
    for (size_t i = 0; i < n; ++i) {
        unsigned char b[4], t;
        memcpy(b, &v[i], 4);
        t = b[0], b[0] = b[3], b[3] = t;
        t = b[1], b[1] = b[2], b[2] = t;
        memcpy(&v[i], b, 4);
    }
}

/* Writes RGBA pixels (top row first) as an RGB PFM, atomically: a temporary
 * file in the same directory, flushed to disk, then renamed over `path`. */
static int write_pfm(const char *path, const float *rgba, uint32_t width, uint32_t height)
{
    size_t len = strlen(path) + 64;
    char *tmp = malloc(len);
    float *row = malloc((size_t)width * 3 * sizeof *row);
    FILE *f = NULL;
    int ok = 0;
    if (!tmp || !row) {
        fprintf(stderr, "render_scene: out of memory writing %s\n", path);
        goto done;
    }
    snprintf(tmp, len, "%s.%ld.tmp", path, (long)getpid());
    int fd = open(tmp, O_WRONLY | O_CREAT | O_EXCL, 0666);
    if (fd < 0 || !(f = fdopen(fd, "wb"))) {
        fprintf(stderr, "render_scene: cannot create %s: %s\n", tmp, strerror(errno));
        if (fd >= 0) {
            close(fd);
            unlink(tmp);
        }
        goto done;
    }
    int good = fprintf(f, "PF\n%u %u\n-1.0\n", width, height) > 0;
    const int swap = !host_is_little_endian();
    for (uint32_t y = height; good && y-- > 0;) { /* bottom row first */
        const float *src = rgba + (size_t)y * width * 4;
        for (uint32_t x = 0; x < width; ++x)
            for (uint32_t c = 0; c < 3; ++c)
                row[3 * x + c] = src[4 * x + c];
        if (swap)
            swap_floats(row, (size_t)width * 3);
        good = fwrite(row, sizeof *row, (size_t)width * 3, f) == (size_t)width * 3;
    }
    good = good && fflush(f) == 0 && fsync(fileno(f)) == 0;
    good = fclose(f) == 0 && good;
    if (!good || rename(tmp, path) != 0) {
        fprintf(stderr, "render_scene: cannot write %s: %s\n", path, strerror(errno));
        unlink(tmp);
        goto done;
    }
    ok = 1;
done:
    free(tmp);
    free(row);
    return ok;
}

/* ---------------------------------------------------------------- scene */

/* Unit box centred at (0, 0.5, 0): 8 corners, 12 triangles wound counter-clockwise seen from outside. */
static const float box_positions[8 * 3] = {
    -0.5f, 0.0f, -0.5f, /* 0 */
    0.5f,  0.0f, -0.5f, /* 1 */
    0.5f,  1.0f, -0.5f, /* 2 */
    -0.5f, 1.0f, -0.5f, /* 3 */
    -0.5f, 0.0f, 0.5f,  /* 4 */
    0.5f,  0.0f, 0.5f,  /* 5 */
    0.5f,  1.0f, 0.5f,  /* 6 */
    -0.5f, 1.0f, 0.5f,  /* 7 */
};
static const uint32_t box_indices[12 * 3] = {
    0, 3, 2, 0, 2, 1, /* -z */
    4, 5, 6, 4, 6, 7, /* +z */
    0, 4, 7, 0, 7, 3, /* -x */
    1, 2, 6, 1, 6, 5, /* +x */
    0, 1, 5, 0, 5, 4, /* -y */
    3, 7, 6, 3, 6, 2, /* +y */
};

/* Ground quad y = 0 over [-3, 3] x [-3, 3], facing +y. */
static const float ground_positions[4 * 3] = {
    -3.0f, 0.0f, -3.0f, 3.0f, 0.0f, -3.0f, 3.0f, 0.0f, 3.0f, -3.0f, 0.0f, 3.0f,
};
static const uint32_t ground_indices[2 * 3] = {0, 3, 2, 0, 2, 1};

/* ----------------------------------------------------------------- main */

static pn_context g_ctx; /* for error messages: NULL until created */

/* On failure prints the call, the status and penumbra's message. */
static int check(pn_status status, const char *what)
{
    if (status == PN_SUCCESS)
        return 1;
    const char *msg = NULL;
    pn_status recorded = g_ctx ? pn_get_error(g_ctx, &msg) : PN_SUCCESS;
    if (recorded == PN_SUCCESS) /* NULL handles and context creation report in the global slot */
        pn_get_error(NULL, &msg);
    fprintf(stderr, "render_scene: %s failed: %s: %s\n", what, pn_status_name(status), msg && *msg ? msg : "(no message)");
    return 0;
}

static int parse_size(const char *s, uint32_t *out)
{
    char *end;
    unsigned long v = strtoul(s, &end, 10);
    if (*s == '\0' || *end != '\0' || v == 0 || v > 32768)
        return 0;
    *out = (uint32_t)v;
    return 1;
}

int main(int argc, char **argv)
{
    uint32_t width = 160, height = 120;
    const char *method = argc == 6 ? argv[5] : "unshadowed";
    if (argc != 3 && argc != 5 && argc != 6) {
        fprintf(stderr, "usage: %s ENV.hdr|ENV.exr OUT.pfm [WIDTH HEIGHT [METHOD]]\n", argv[0]);
        return 2;
    }
    if (argc >= 5 && (!parse_size(argv[3], &width) || !parse_size(argv[4], &height))) {
        fprintf(stderr, "render_scene: WIDTH and HEIGHT must be integers in 1..32768\n");
        return 2;
    }
    uint32_t env_w = 0, env_h = 0;
    float *env_rgb = read_envmap(argv[1], &env_w, &env_h);
    if (!env_rgb)
        return 1;

    pn_envmap env = NULL;
    pn_mesh box = NULL, ground = NULL;
    pn_scene scene = NULL;
    pn_gbuffer gbuffer = NULL;
    pn_image image = NULL;
    pn_renderer renderer = NULL;
    pn_fiv box_field = NULL;
    float *pixels = NULL;
    int ok = 0;

    pn_material box_material = pn_material_default();
    box_material.albedo[0] = 0.7f;
    box_material.albedo[1] = 0.5f;
    box_material.albedo[2] = 0.3f;
    pn_material ground_material = pn_material_default();
    ground_material.albedo[0] = ground_material.albedo[1] = ground_material.albedo[2] = 0.8f;
    const pn_camera camera = {{2.5f, 2.0f, 3.5f}, {0.0f, 0.4f, 0.0f}, {0.0f, 1.0f, 0.0f}, 45.0f, width, height};
    uint32_t box_id, ground_id;

    if (!check(pn_context_create(NULL, &g_ctx), "pn_context_create") ||
        !check(pn_envmap_create(g_ctx, &env), "pn_envmap_create") ||
        !check(pn_envmap_set_latlong(env, env_rgb, env_w, env_h), "pn_envmap_set_latlong") ||
        !check(pn_envmap_commit(env), "pn_envmap_commit") ||
        !check(pn_mesh_create(g_ctx, &box), "pn_mesh_create (box)") ||
        !check(pn_mesh_set_geometry(box, box_positions, 8, box_indices, 12, NULL), "pn_mesh_set_geometry (box)") ||
        !check(pn_mesh_commit(box), "pn_mesh_commit (box)") ||
        !check(pn_mesh_create(g_ctx, &ground), "pn_mesh_create (ground)") ||
        !check(pn_mesh_set_geometry(ground, ground_positions, 4, ground_indices, 2, NULL),
               "pn_mesh_set_geometry (ground)") ||
        !check(pn_mesh_commit(ground), "pn_mesh_commit (ground)") ||
        !check(pn_scene_create(g_ctx, &scene), "pn_scene_create") ||
        !check(pn_scene_set_envmap(scene, env), "pn_scene_set_envmap") ||
        !check(pn_scene_add_instance(scene, box, NULL, &box_material, &box_id), "pn_scene_add_instance (box)") ||
        !check(pn_scene_add_instance(scene, ground, NULL, &ground_material, &ground_id),
               "pn_scene_add_instance (ground)") ||
        !check(pn_scene_set_camera(scene, &camera), "pn_scene_set_camera") ||
        !check(pn_scene_commit(scene), "pn_scene_commit"))
        goto cleanup;
    pn_method_info info;
    if (!check(pn_method_get_info(method, &info), "pn_method_get_info"))
        goto cleanup;
    if (info.inputs & PN_INPUT_HEIGHTFIELD) {
        fprintf(stderr, "render_scene: method %s shades height fields; this scene has none\n", method);
        goto cleanup;
    }
    if (info.inputs & PN_INPUT_FIV) {
        /* The box's occlusion field under this env map, attached to the box's
         * instance: it then occludes (and shadows itself). */
        pn_fiv_options options = pn_fiv_options_default();
        options.theta = 9;
        options.phi = 16;
        options.radii = 8;
        options.face_size = 16;
        if (!check(pn_fiv_bake(env, box, &options, NULL, NULL, NULL, &box_field), "pn_fiv_bake") ||
            !check(pn_scene_attach(scene, box_id, box_field), "pn_scene_attach") ||
            !check(pn_scene_commit(scene), "pn_scene_commit"))
            goto cleanup;
    }
    if (!check(pn_gbuffer_create(g_ctx, width, height, &gbuffer), "pn_gbuffer_create") ||
        !check(pn_image_create(g_ctx, width, height, &image), "pn_image_create") ||
        !check(pn_renderer_create(g_ctx, method, &renderer), "pn_renderer_create") ||
        !check(pn_renderer_commit(renderer), "pn_renderer_commit") ||
        !check(pn_scene_render_gbuffer(scene, gbuffer), "pn_scene_render_gbuffer") ||
        !check(pn_renderer_execute(renderer, scene, gbuffer, image), "pn_renderer_execute"))
        goto cleanup;

    const size_t bytes = (size_t)width * height * 4 * sizeof(float);
    pixels = malloc(bytes);
    if (!pixels) {
        fprintf(stderr, "render_scene: out of memory for a %ux%u image\n", width, height);
        goto cleanup;
    }
    if (!check(pn_image_read(image, pixels, bytes), "pn_image_read"))
        goto cleanup;
    ok = write_pfm(argv[2], pixels, width, height);

cleanup:
    /* Release what exists, checking each call. */
    if (renderer && !check(pn_renderer_release(renderer), "pn_renderer_release")) ok = 0;
    if (image && !check(pn_image_release(image), "pn_image_release")) ok = 0;
    if (gbuffer && !check(pn_gbuffer_release(gbuffer), "pn_gbuffer_release")) ok = 0;
    if (scene && !check(pn_scene_release(scene), "pn_scene_release")) ok = 0;
    if (box_field && !check(pn_fiv_release(box_field), "pn_fiv_release")) ok = 0;
    if (ground && !check(pn_mesh_release(ground), "pn_mesh_release (ground)")) ok = 0;
    if (box && !check(pn_mesh_release(box), "pn_mesh_release (box)")) ok = 0;
    if (env && !check(pn_envmap_release(env), "pn_envmap_release")) ok = 0;
    if (g_ctx) {
        pn_context ctx = g_ctx;
        g_ctx = NULL;
        if (!check(pn_context_release(ctx), "pn_context_release"))
            ok = 0;
    }
    free(pixels);
    free(env_rgb);
    if (ok)
        printf("wrote %s (%ux%u)\n", argv[2], width, height);
    return ok ? 0 : 1;
}
