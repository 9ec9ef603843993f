/* Bake files of occlusion fields (docs/fiv.md, "File format"): a 256-byte
 * little-endian header that describes the grid, the bounding sphere, the
 * precision and the hashes of the mesh and env map it was baked from, then
 * the samples of the spheres baked so far (float32, or float16 scaled by
 * value_scale). Header and samples each carry an FNV-1a checksum. Files are
 * written to a temporary file in the same folder and renamed over the target,
 * so a reader never sees a half-written file and an interrupted bake keeps
 * its last checkpoint. */
#define _POSIX_C_SOURCE 200809L
#include "assets/assets.h"

#include <errno.h>
#include <fcntl.h>
#include <math.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#define HEADER_BYTES 256
#define FORMAT_VERSION 1u
static const unsigned char MAGIC[8] = {'P', 'N', 'F', 'I', 'V', 0, '\r', '\n'};

static void put_u32(unsigned char *p, uint32_t v)
{
    for (int i = 0; i < 4; ++i)
        p[i] = (unsigned char)(v >> (8 * i));
}

static void put_u64(unsigned char *p, uint64_t v)
{
    for (int i = 0; i < 8; ++i)
        p[i] = (unsigned char)(v >> (8 * i));
}

static void put_f32(unsigned char *p, float v)
{
    uint32_t u;
    memcpy(&u, &v, sizeof u);
    put_u32(p, u);
}

static uint32_t get_u32(const unsigned char *p)
{
    uint32_t v = 0;
    for (int i = 0; i < 4; ++i)
        v |= (uint32_t)p[i] << (8 * i);
    return v;
}

static uint64_t get_u64(const unsigned char *p)
{
    uint64_t v = 0;
    for (int i = 0; i < 8; ++i)
        v |= (uint64_t)p[i] << (8 * i);
    return v;
}

static float get_f32(const unsigned char *p)
{
    uint32_t u = get_u32(p);
    float v;
    memcpy(&v, &u, sizeof v);
    return v;
}

/* The stored samples of the spheres done: little-endian float32, or float16 of value / value_scale. */
static unsigned char *encode_samples(pn_fiv f, size_t *bytes)
{
    const size_t n = (size_t)f->radii_done * f->options.theta * f->options.phi * 9u;
    const bool half = f->options.precision == PN_PRECISION_FLOAT16;
    *bytes = n * (half ? 2u : 4u);
    unsigned char *out = malloc(*bytes ? *bytes : 1);
    if (!out)
        return NULL;
    for (size_t i = 0; i < n; ++i) {
        if (half) {
            uint16_t h = pn_half_from_float(f->samples[i] / f->value_scale);
            out[2 * i] = (unsigned char)h;
            out[2 * i + 1] = (unsigned char)(h >> 8);
        } else {
            put_f32(out + 4 * i, f->samples[i]);
        }
    }
    return out;
}

static void encode_header(pn_fiv f, uint64_t payload_checksum, unsigned char *h)
{
    memset(h, 0, HEADER_BYTES);
    memcpy(h, MAGIC, sizeof MAGIC);
    const pn_fiv_options *o = &f->options;
    put_u32(h + 8, FORMAT_VERSION);
    put_u32(h + 12, HEADER_BYTES);
    put_u32(h + 16, o->theta);
    put_u32(h + 20, o->phi);
    put_u32(h + 24, o->radii);
    put_u32(h + 28, f->radii_done);
    put_u32(h + 32, o->precision);
    put_u32(h + 36, o->face_size);
    put_u32(h + 40, o->sun_supersampling);
    put_f32(h + 44, o->sun_threshold);
    put_f32(h + 48, o->inner_radius);
    put_f32(h + 52, o->error_target);
    for (int c = 0; c < 3; ++c)
        put_f32(h + 56 + 4 * c, f->centre[c]);
    put_f32(h + 68, f->radius);
    put_f32(h + 72, f->inner);
    put_f32(h + 76, f->outer);
    put_f32(h + 80, f->value_scale);
    put_f32(h + 84, f->outer_max);
    put_u32(h + 88, f->mesh_vertices);
    put_u32(h + 92, f->mesh_triangles);
    put_u64(h + 96, f->mesh_hash);
    put_u64(h + 104, f->env_hash);
    put_u64(h + 112, f->inside_count);
    put_u64(h + 120, payload_checksum);
    put_u64(h + 128, f->rays);
    uint64_t seconds;
    memcpy(&seconds, &f->bake_seconds, sizeof seconds);
    put_u64(h + 136, seconds);
    put_u64(h + 248, pn_hash_bytes(PN_HASH_SEED, h, 248));
}

/* Creates the temporary file beside `path` (its name written to `tmp`) with
 * mode 0666, so the umask decides the finished file's permissions as for any
 * file a program creates (mkstemp's 0600 would make every bake file private;
 * rename keeps the temporary's mode). Returns the descriptor, or -1 (errno). */
static int create_temp_beside(const char *path, char *tmp, size_t size)
{
    static atomic_uint counter;
    for (int attempt = 0; attempt < 100; ++attempt) {
        snprintf(tmp, size, "%s.tmp-%ld-%u", path, (long)getpid(), atomic_fetch_add(&counter, 1u));
        int fd = open(tmp, O_WRONLY | O_CREAT | O_EXCL | O_CLOEXEC, 0666);
        if (fd >= 0 || errno != EEXIST)
            return fd;
    }
    return -1;
}

pn_status pn_fiv_write_file(pn_fiv f, const char *path)
{
    pn_context ctx = f->obj.ctx;
    const char *problem = pn_fiv_geometry_problem(f);
    if (problem) /* the reader would refuse the file */
        return pn_fail(ctx, PN_ERROR_INVALID_VALUE, "cannot write %s: the occlusion field is not valid: %s", path, problem);
    size_t bytes;
    unsigned char *payload = encode_samples(f, &bytes);
    if (!payload)
        return pn_fail(ctx, PN_ERROR_OUT_OF_MEMORY, "out of memory encoding an occlusion field for %s", path);
    unsigned char header[HEADER_BYTES];
    encode_header(f, pn_hash_bytes(PN_HASH_SEED, payload, bytes), header);
    size_t len = strlen(path);
    const size_t tmp_size = len + 40; /* ".tmp-<pid>-<counter>" */
    char *tmp = malloc(tmp_size);
    pn_status st = PN_SUCCESS;
    if (!tmp) {
        free(payload);
        return pn_fail(ctx, PN_ERROR_OUT_OF_MEMORY, "out of memory writing %s", path);
    }
    int fd = create_temp_beside(path, tmp, tmp_size);
    FILE *file = fd >= 0 ? fdopen(fd, "wb") : NULL;
    if (!file) {
        st = pn_fail(ctx, PN_ERROR_FILE, "cannot create a temporary file beside %s: %s", path, strerror(errno));
        if (fd >= 0) {
            close(fd);
            remove(tmp);
        }
    } else {
        bool ok = fwrite(header, 1, HEADER_BYTES, file) == HEADER_BYTES && fwrite(payload, 1, bytes, file) == bytes &&
                  fflush(file) == 0 && fsync(fileno(file)) == 0;
        int err = errno;
        ok = (fclose(file) == 0) && ok;
        if (ok && rename(tmp, path) != 0) {
            err = errno;
            ok = false;
        }
        if (!ok) {
            remove(tmp);
            st = pn_fail(ctx, PN_ERROR_FILE, "cannot write %s: %s (the previous file, if any, is unchanged)", path,
                         strerror(err));
        }
    }
    free(tmp);
    free(payload);
    return st;
}

/* Reads and checks the header of an open bake file: magic, version,
 * checksum, options and progress (an unfinished bake only with `partial`). */
static pn_status read_header(pn_context ctx, const char *path, FILE *file, bool partial, unsigned char *h,
                             pn_fiv_options *options, uint32_t *spheres_done)
{
    size_t got = fread(h, 1, HEADER_BYTES, file);
    pn_status st = PN_SUCCESS;
    if (got < sizeof MAGIC || memcmp(h, MAGIC, sizeof MAGIC))
        return pn_fail(ctx, PN_ERROR_FILE, "%s is not a penumbra FIV bake file (bad magic)", path);
    if (got < HEADER_BYTES)
        return pn_fail(ctx, PN_ERROR_FILE, "%s is truncated: its header has %zu of %d bytes", path, got, HEADER_BYTES);
    if (get_u32(h + 8) != FORMAT_VERSION)
        return pn_fail(ctx, PN_ERROR_FILE, "%s has FIV format version %u; this library reads version %u", path,
                       get_u32(h + 8), FORMAT_VERSION);
    if (get_u64(h + 248) != pn_hash_bytes(PN_HASH_SEED, h, 248))
        return pn_fail(ctx, PN_ERROR_FILE, "%s is corrupt: its header checksum does not match", path);
    pn_fiv_options o = {get_u32(h + 16), get_u32(h + 20), get_u32(h + 24), get_f32(h + 48), get_f32(h + 52),
                        get_u32(h + 36), get_u32(h + 40), get_f32(h + 44), get_u32(h + 32)};
    if (pn_fiv_check_options(ctx, &o)) {
        const char *why = NULL;
        char detail[256];
        pn_error_take(ctx, &why);
        snprintf(detail, sizeof detail, "%s", why ? why : "invalid options");
        return pn_fail(ctx, PN_ERROR_FILE, "%s is corrupt: its header has %s", path, detail);
    }
    const uint32_t done = get_u32(h + 28);
    if (done > o.radii)
        return pn_fail(ctx, PN_ERROR_FILE, "%s is corrupt: %u of %u spheres done", path, done, o.radii);
    if (done < o.radii && !partial)
        return pn_fail(ctx, PN_ERROR_FILE,
                       "%s is an unfinished bake (%u of %u spheres); run the bake again with the same options to resume",
                       path, done, o.radii);
    /* What the header promises against what the file holds, before anything
     * is allocated for it. */
    const uint64_t per_sphere = (uint64_t)o.theta * o.phi * 9u * (o.precision == PN_PRECISION_FLOAT16 ? 2u : 4u);
    const uint64_t promised = HEADER_BYTES + per_sphere * done;
    struct stat sb;
    if (fstat(fileno(file), &sb) != 0)
        return pn_fail(ctx, PN_ERROR_FILE, "cannot read the size of %s: %s", path, strerror(errno));
    if (!S_ISREG(sb.st_mode))
        return pn_fail(ctx, PN_ERROR_FILE, "%s is not a regular file", path);
    if ((uint64_t)sb.st_size != promised)
        return pn_fail(ctx, PN_ERROR_FILE,
                       "%s %s: its header promises %llu bytes (a %ux%ux%u grid, %u spheres stored) but the file has "
                       "%llu bytes",
                       path, (uint64_t)sb.st_size < promised ? "is truncated" : "is corrupt: it has bytes past its samples",
                       (unsigned long long)promised, o.theta, o.phi, o.radii, done, (unsigned long long)sb.st_size);
    *options = o;
    *spheres_done = done;
    return st;
}

/* The header's description of the field (everything but the samples). */
static pn_status header_fields(pn_context ctx, const char *path, const unsigned char *h, uint32_t done, pn_fiv f)
{
    for (int c = 0; c < 3; ++c)
        f->centre[c] = get_f32(h + 56 + 4 * c);
    f->radius = get_f32(h + 68);
    f->inner = get_f32(h + 72);
    f->outer = get_f32(h + 76);
    f->value_scale = get_f32(h + 80);
    f->outer_max = get_f32(h + 84);
    f->mesh_vertices = get_u32(h + 88);
    f->mesh_triangles = get_u32(h + 92);
    f->mesh_hash = get_u64(h + 96);
    f->env_hash = get_u64(h + 104);
    f->inside_count = get_u64(h + 112);
    f->rays = get_u64(h + 128);
    const uint64_t seconds = get_u64(h + 136);
    memcpy(&f->bake_seconds, &seconds, sizeof seconds);
    f->radii_done = done;
    /* Checked whether or not the checksum matched: a header rewritten with a
     * new checksum is no more plausible for it. */
    const char *problem = pn_fiv_geometry_problem(f);
    if (problem)
        return pn_fail(ctx, PN_ERROR_FILE, "%s is corrupt: its bounding sphere or scales are not valid numbers: %s", path,
                       problem);
    if (!(isfinite(f->bake_seconds) && f->bake_seconds >= 0.0))
        return pn_fail(ctx, PN_ERROR_FILE, "%s is corrupt: its bake time is not a valid number", path);
    return PN_SUCCESS;
}

pn_status pn_fiv_read_file_header(const char *path, pn_fiv_info *info)
{
    FILE *file = fopen(path, "rb");
    if (!file)
        return pn_fail(NULL, PN_ERROR_FILE, "cannot open FIV bake file %s: %s", path, strerror(errno));
    unsigned char h[HEADER_BYTES];
    struct pn_fiv_impl f;
    memset(&f, 0, sizeof f);
    uint32_t done = 0;
    pn_status st = read_header(NULL, path, file, true, h, &f.options, &done);
    fclose(file);
    if (!st)
        st = header_fields(NULL, path, h, done, &f);
    if (!st)
        pn_fiv_fill_info(&f, info);
    return st;
}

pn_status pn_fiv_read_file(pn_context ctx, const char *path, bool partial, pn_fiv *out)
{
    *out = NULL;
    FILE *file = fopen(path, "rb");
    if (!file)
        return pn_fail(ctx, PN_ERROR_FILE, "cannot open FIV bake file %s: %s", path, strerror(errno));
    unsigned char h[HEADER_BYTES];
    pn_fiv_options o;
    uint32_t done = 0;
    pn_status st = read_header(ctx, path, file, partial, h, &o, &done);
    pn_fiv f = NULL;
    unsigned char *payload = NULL;
    const bool half = !st && o.precision == PN_PRECISION_FLOAT16;
    const size_t n = st ? 0 : (size_t)done * o.theta * o.phi * 9u, bytes = n * (half ? 2u : 4u);
    if (!st) { /* the header's numbers, before anything is allocated for them */
        struct pn_fiv_impl probe;
        memset(&probe, 0, sizeof probe);
        st = header_fields(ctx, path, h, done, &probe);
    }
    if (!st && !(st = pn_fiv_new(ctx, &o, &f))) {
        payload = malloc(bytes ? bytes : 1);
        if (!payload)
            st = pn_fail(ctx, PN_ERROR_OUT_OF_MEMORY, "out of memory reading %s", path);
    }
    if (!st) {
        size_t read = fread(payload, 1, bytes, file);
        unsigned char extra;
        if (read != bytes)
            st = pn_fail(ctx, PN_ERROR_FILE, "%s is truncated: %zu of %zu sample bytes", path, read, bytes);
        else if (fread(&extra, 1, 1, file) != 0)
            st = pn_fail(ctx, PN_ERROR_FILE, "%s is corrupt: it has bytes past its samples", path);
        else if (pn_hash_bytes(PN_HASH_SEED, payload, bytes) != get_u64(h + 120))
            st = pn_fail(ctx, PN_ERROR_FILE, "%s is corrupt: its sample checksum does not match", path);
    }
    if (!st)
        st = header_fields(ctx, path, h, done, f);
    for (size_t i = 0; !st && i < n; ++i)
        f->samples[i] = half ? pn_float_from_half((uint16_t)(payload[2 * i] | (payload[2 * i + 1] << 8))) * f->value_scale
                             : get_f32(payload + 4 * i);
    if (!st)
        for (size_t i = n; i < (size_t)pn_fiv_sample_count(&o) * 9u; ++i)
            f->samples[i] = NAN;
    free(payload);
    fclose(file);
    if (st) {
        PN_RELEASE(f);
        return st;
    }
    *out = f;
    return PN_SUCCESS;
}
