/* Contexts: device choice from a config string, borrowed caller objects, and
 * the per-context cache of built programs and kernels. */
#define _XOPEN_SOURCE 700 /* PTHREAD_MUTEX_RECURSIVE */
#include "core/core.h"

#include <ctype.h>
#include <errno.h>
#include <stdint.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static atomic_uint_fast64_t next_serial = 1;

/* ------------------------------------------------------------ config string */

typedef struct device_request {
    char device[64];   /* default | cpu | gpu | accelerator | index */
    char platform[128];
    char build_options[256];
} device_request;

static void copy_value(char *dst, size_t size, const char *src, size_t len)
{
    if (len >= size)
        len = size - 1;
    memcpy(dst, src, len);
    dst[len] = '\0';
}

static pn_status parse_config(const char *config, device_request *req)
{
    memset(req, 0, sizeof *req);
    const char *p = config ? config : "";
    while (*p) {
        while (*p == ' ' || *p == ',')
            ++p;
        if (!*p)
            break;
        const char *end = strchr(p, ',');
        size_t len = end ? (size_t)(end - p) : strlen(p);
        const char *eq = memchr(p, '=', len);
        if (!eq)
            return pn_fail(NULL, PN_ERROR_BAD_CONFIG,
                           "config entry '%.*s' is not key=value (known keys: device, platform, build_options)",
                           (int)len, p);
        size_t klen = (size_t)(eq - p), vlen = len - klen - 1;
        const char *val = eq + 1;
        if (klen == 6 && strncmp(p, "device", 6) == 0)
            copy_value(req->device, sizeof req->device, val, vlen);
        else if (klen == 8 && strncmp(p, "platform", 8) == 0)
            copy_value(req->platform, sizeof req->platform, val, vlen);
        else if (klen == 13 && strncmp(p, "build_options", 13) == 0)
            copy_value(req->build_options, sizeof req->build_options, val, vlen);
        else
            return pn_fail(NULL, PN_ERROR_BAD_CONFIG,
                           "unknown config key '%.*s' (known keys: device, platform, build_options)", (int)klen, p);
        p += len;
    }
    if (!req->device[0]) {
        const char *env = getenv("PENUMBRA_DEVICE");
        if (env && *env)
            copy_value(req->device, sizeof req->device, env, strlen(env));
    }
    if (!req->device[0])
        strcpy(req->device, "default");
    const char *d = req->device;
    bool numeric = true;
    for (const char *c = d; *c; ++c)
        numeric = numeric && isdigit((unsigned char)*c);
    if (!numeric && strcmp(d, "default") && strcmp(d, "cpu") && strcmp(d, "gpu") && strcmp(d, "accelerator"))
        return pn_fail(NULL, PN_ERROR_BAD_CONFIG,
                       "device '%s' is not one of default, cpu, gpu, accelerator or a device index", d);
    return PN_SUCCESS;
}

static bool contains_nocase(const char *hay, const char *needle)
{
    size_t n = strlen(needle);
    for (; *hay; ++hay) {
        size_t i = 0;
        while (i < n && hay[i] && tolower((unsigned char)hay[i]) == tolower((unsigned char)needle[i]))
            ++i;
        if (i == n)
            return true;
    }
    return n == 0;
}

/* Picks a platform and device. "default" prefers a CPU device (reproducible
 * results on PoCL), then any device. */
static pn_status choose_device(const device_request *req, cl_platform_id *platform_out, cl_device_id *device_out)
{
    cl_platform_id platforms[16];
    cl_uint nplat = 0;
    cl_int err = clGetPlatformIDs(16, platforms, &nplat);
    if (err == -1001 /* CL_PLATFORM_NOT_FOUND_KHR */ || nplat == 0)
        return pn_fail(NULL, PN_ERROR_NO_DEVICE,
                       "no OpenCL platform found (install an ICD such as pocl-opencl-icd)");
    if (err != CL_SUCCESS)
        return pn_fail_cl(NULL, err, "listing OpenCL platforms");
    if (nplat > 16)
        nplat = 16;
    bool numeric = isdigit((unsigned char)req->device[0]) != 0;
    cl_device_type want = CL_DEVICE_TYPE_ALL;
    if (!strcmp(req->device, "cpu"))
        want = CL_DEVICE_TYPE_CPU;
    else if (!strcmp(req->device, "gpu"))
        want = CL_DEVICE_TYPE_GPU;
    else if (!strcmp(req->device, "accelerator"))
        want = CL_DEVICE_TYPE_ACCELERATOR;
    const bool prefer_cpu = !strcmp(req->device, "default");
    for (int pass = prefer_cpu ? 0 : 1; pass < 2; ++pass) {
        cl_device_type type = (prefer_cpu && pass == 0) ? CL_DEVICE_TYPE_CPU : want;
        for (cl_uint p = 0; p < nplat; ++p) {
            char name[256] = "";
            clGetPlatformInfo(platforms[p], CL_PLATFORM_NAME, sizeof name, name, NULL);
            if (req->platform[0] && !contains_nocase(name, req->platform))
                continue;
            cl_device_id devices[32];
            cl_uint ndev = 0;
            if (clGetDeviceIDs(platforms[p], type, 32, devices, &ndev) != CL_SUCCESS || ndev == 0)
                continue;
            cl_uint pick = 0;
            if (numeric) {
                pick = (cl_uint)strtoul(req->device, NULL, 10);
                if (pick >= ndev || pick >= 32)
                    return pn_fail(NULL, PN_ERROR_NO_DEVICE, "device index %u is out of range: platform '%s' has %u devices",
                                   pick, name, ndev);
            }
            *platform_out = platforms[p];
            *device_out = devices[pick];
            return PN_SUCCESS;
        }
    }
    return pn_fail(NULL, PN_ERROR_NO_DEVICE, "no OpenCL device matches device=%s%s%s", req->device,
                   req->platform[0] ? " platform=" : "", req->platform);
}

static void destroy_context(pn_object *o);
static const pn_object_type context_type = {PN_MAGIC_CONTEXT, "context", destroy_context, NULL};

pn_status pn_context_new(const char *config, cl_context cl_ctx, cl_command_queue queue, pn_context *out)
{
    device_request req;
    pn_status st = parse_config(config, &req);
    if (st)
        return st;
    /* The kernels walk 8-wide nodes by default (the fastest layout on shadow
     * and primary rays, docs/performance.md); PENUMBRA_BVH_WIDTH=2 or 4
     * selects the binary or 4-wide layout, to time them against it
     * (bench/ray_profile.py). */
    int bvh_width = 8;
    const char *width_env = getenv("PENUMBRA_BVH_WIDTH");
    if (width_env && *width_env) {
        if (strcmp(width_env, "2") && strcmp(width_env, "4") && strcmp(width_env, "8"))
            return pn_fail(NULL, PN_ERROR_BAD_CONFIG, "PENUMBRA_BVH_WIDTH='%s' must be 2, 4 or 8", width_env);
        bvh_width = width_env[0] - '0';
    }
    /* The wide layouts test a leaf's triangles four at a time from
     * structure-of-arrays blocks (scene.c, raytrace.cl: -DPN_TRI_SOA);
     * PENUMBRA_TRI_SOA=0 tests them one by one instead, to time the two. */
    int tri_soa = bvh_width != 2;
    const char *soa_env = getenv("PENUMBRA_TRI_SOA");
    if (soa_env && *soa_env) {
        if (strcmp(soa_env, "0") && strcmp(soa_env, "1"))
            return pn_fail(NULL, PN_ERROR_BAD_CONFIG, "PENUMBRA_TRI_SOA='%s' must be 0 or 1", soa_env);
        tri_soa = soa_env[0] == '1' && bvh_width != 2;
    }
    pn_context ctx = calloc(1, sizeof *ctx);
    if (!ctx)
        return pn_fail(NULL, PN_ERROR_OUT_OF_MEMORY, "out of memory creating a context");
    ctx->obj.magic = PN_MAGIC_CONTEXT;
    ctx->obj.ctx = ctx;
    ctx->obj.type = &context_type;
    ctx->serial = atomic_fetch_add(&next_serial, 1);
    cl_int err;
    if (cl_ctx) {
        /* Borrowed: the caller's objects, retained while we hold them. */
        err = clGetCommandQueueInfo(queue, CL_QUEUE_DEVICE, sizeof ctx->device, &ctx->device, NULL);
        if (err != CL_SUCCESS) {
            free(ctx);
            return pn_fail(NULL, PN_ERROR_INVALID_ARGUMENT, "the command queue is not valid (OpenCL error %d)", err);
        }
        cl_context qctx = NULL;
        clGetCommandQueueInfo(queue, CL_QUEUE_CONTEXT, sizeof qctx, &qctx, NULL);
        if (qctx != cl_ctx) {
            free(ctx);
            return pn_fail(NULL, PN_ERROR_INVALID_ARGUMENT, "the command queue belongs to a different cl_context");
        }
        clRetainContext(cl_ctx);
        clRetainCommandQueue(queue);
        ctx->cl_ctx = cl_ctx;
        ctx->queue = queue;
    } else {
        cl_platform_id platform = NULL;
        st = choose_device(&req, &platform, &ctx->device);
        if (st) {
            free(ctx);
            return st;
        }
        cl_context_properties props[] = {CL_CONTEXT_PLATFORM, (cl_context_properties)platform, 0};
        ctx->cl_ctx = clCreateContext(props, 1, &ctx->device, NULL, NULL, &err);
        if (err != CL_SUCCESS) {
            free(ctx);
            return pn_fail_cl(NULL, err, "creating an OpenCL context");
        }
        ctx->queue = clCreateCommandQueue(ctx->cl_ctx, ctx->device, 0, &err);
        if (err != CL_SUCCESS) {
            clReleaseContext(ctx->cl_ctx);
            free(ctx);
            return pn_fail_cl(NULL, err, "creating an OpenCL command queue");
        }
    }
    const char *extra = getenv("PENUMBRA_CL_BUILD_OPTIONS");
    ctx->bvh_width = bvh_width;
    ctx->tri_soa = tri_soa;
    snprintf(ctx->build_options, sizeof ctx->build_options, "-cl-std=CL1.2 -DPN_BVH_WIDTH=%d%s %s %s", bvh_width,
             tri_soa ? " -DPN_TRI_SOA" : "", req.build_options, extra ? extra : "");
    /* Every call on the context's objects holds its lock; recursive, so that
     * callbacks run under it may call the library again. */
    pthread_mutexattr_t attr;
    pthread_mutexattr_init(&attr);
    pthread_mutexattr_settype(&attr, PTHREAD_MUTEX_RECURSIVE);
    const int lock_err = pthread_mutex_init(&ctx->lock, &attr);
    pthread_mutexattr_destroy(&attr);
    if (lock_err || pn_object_setup(&ctx->obj, ctx, &context_type)) {
        if (!lock_err)
            pthread_mutex_destroy(&ctx->lock);
        clReleaseCommandQueue(ctx->queue);
        clReleaseContext(ctx->cl_ctx);
        free(ctx);
        return lock_err ? pn_fail(NULL, PN_ERROR_OUT_OF_MEMORY, "cannot create the context's mutex") : PN_ERROR_OUT_OF_MEMORY;
    }
    *out = ctx;
    return PN_SUCCESS;
}

static void destroy_context(pn_object *o)
{
    pn_context ctx = (pn_context)o;
    pthread_mutex_destroy(&ctx->lock);
    clFinish(ctx->queue);
    for (int i = 0; i < ctx->kernel_count; ++i)
        clReleaseKernel(ctx->kernels[i].kernel);
    for (int i = 0; i < ctx->program_count; ++i)
        clReleaseProgram(ctx->programs[i].program);
    clReleaseCommandQueue(ctx->queue);
    clReleaseContext(ctx->cl_ctx);
    for (int i = 0; i < ctx->cache_count; ++i)
        ctx->caches[i].free_data(ctx->caches[i].data);
    pn_error_forget(ctx->serial);
}

/* ------------------------------------------------------- program sources */

static const pn_kernel_file *find_file(const char *path, size_t len)
{
    for (size_t i = 0; i < pn_kernel_file_count; ++i)
        if (strlen(pn_kernel_files[i].path) == len && !strncmp(pn_kernel_files[i].path, path, len))
            return &pn_kernel_files[i];
    return NULL;
}

typedef struct text {
    char *data;
    size_t len, cap;
    bool failed;
} text;

static void append(text *t, const char *s, size_t n)
{
    if (t->failed)
        return;
    if (t->len + n + 1 > t->cap) {
        size_t cap = t->cap ? t->cap : 4096;
        while (cap < t->len + n + 1)
            cap *= 2;
        char *d = realloc(t->data, cap);
        if (!d) {
            t->failed = true;
            return;
        }
        t->data = d;
        t->cap = cap;
    }
    memcpy(t->data + t->len, s, n);
    t->len += n;
    t->data[t->len] = '\0';
}

/* Inlines `#include "path"` lines with the embedded files, each file once per
 * program (the files also carry include guards, so the same sources compile
 * unchanged with a real -I path, as the Python tests do). */
static pn_status expand(pn_context ctx, const pn_kernel_file *file, text *out, const pn_kernel_file **seen,
                        size_t *nseen, int depth)
{
    for (size_t i = 0; i < *nseen; ++i)
        if (seen[i] == file)
            return PN_SUCCESS;
    if (depth > 16 || *nseen >= 64)
        return pn_fail(ctx, PN_ERROR_INTERNAL, "kernel includes nest too deeply at %s", file->path);
    seen[(*nseen)++] = file;
    const char *p = file->source;
    while (*p) {
        const char *eol = strchr(p, '\n');
        size_t n = eol ? (size_t)(eol - p + 1) : strlen(p);
        if (!strncmp(p, "#include \"", 10)) {
            const char *name = p + 10;
            const char *close = memchr(name, '"', n - 10);
            const pn_kernel_file *inc = close ? find_file(name, (size_t)(close - name)) : NULL;
            if (!inc)
                return pn_fail(ctx, PN_ERROR_INTERNAL, "kernel file %s includes a file that is not embedded: %.*s",
                               file->path, (int)(n - 1), p);
            pn_status st = expand(ctx, inc, out, seen, nseen, depth + 1);
            if (st)
                return st;
        } else {
            append(out, p, n);
        }
        p += n;
    }
    return PN_SUCCESS;
}

pn_status pn_context_program(pn_context ctx, const char *stage, cl_program *out)
{
    char path[64];
    snprintf(path, sizeof path, "%s.cl", stage);
    /* Cached under the embedded file's path, which outlives the context. */
    for (int i = 0; i < ctx->program_count; ++i)
        if (!strcmp(ctx->programs[i].stage, path)) {
            *out = ctx->programs[i].program;
            return PN_SUCCESS;
        }
    const pn_kernel_file *file = find_file(path, strlen(path));
    if (!file || strchr(stage, '/')) {
        /* Stages are the top-level .cl files of kernels/ (common/ holds includes). */
        char names[512] = "";
        for (size_t i = 0; i < pn_kernel_file_count; ++i) {
            const char *f = pn_kernel_files[i].path;
            size_t used = strlen(names), len = strlen(f);
            if (!strchr(f, '/') && len > 3)
                snprintf(names + used, sizeof names - used, "%s%.*s", used ? ", " : "", (int)(len - 3), f);
        }
        return pn_fail(ctx, PN_ERROR_INVALID_ARGUMENT, "there is no kernel stage '%s' (stages: %s)", stage, names);
    }
    if (ctx->program_count == PN_MAX_PROGRAMS)
        return pn_fail(ctx, PN_ERROR_INTERNAL, "too many kernel stages");
    text src = {0};
    const pn_kernel_file *seen[64];
    size_t nseen = 0;
    pn_status st = expand(ctx, file, &src, seen, &nseen, 0);
    if (!st && src.failed)
        st = pn_fail(ctx, PN_ERROR_OUT_OF_MEMORY, "out of memory assembling kernel stage %s", stage);
    if (st) {
        free(src.data);
        return st;
    }
    cl_int err;
    const char *s = src.data;
    cl_program program = clCreateProgramWithSource(ctx->cl_ctx, 1, &s, &src.len, &err);
    free(src.data);
    if (err != CL_SUCCESS)
        return pn_fail_cl(ctx, err, "creating a program");
    err = clBuildProgram(program, 1, &ctx->device, ctx->build_options, NULL, NULL);
    if (err != CL_SUCCESS) {
        size_t log_size = 0;
        clGetProgramBuildInfo(program, ctx->device, CL_PROGRAM_BUILD_LOG, 0, NULL, &log_size);
        char *log = malloc(log_size + 1);
        if (log) {
            clGetProgramBuildInfo(program, ctx->device, CL_PROGRAM_BUILD_LOG, log_size, log, NULL);
            log[log_size] = '\0';
        }
        st = pn_fail(ctx, PN_ERROR_BUILD_FAILED, "building kernel stage '%s' with options '%s' failed (OpenCL %d):\n%s",
                     stage, ctx->build_options, err, log ? log : "(no log)");
        free(log);
        clReleaseProgram(program);
        return st;
    }
    ctx->programs[ctx->program_count].stage = file->path;
    ctx->programs[ctx->program_count].program = program;
    ctx->program_count++;
    *out = program;
    return PN_SUCCESS;
}

pn_status pn_context_kernel(pn_context ctx, const char *stage, const char *name, cl_kernel *out)
{
    for (int i = 0; i < ctx->kernel_count; ++i)
        if (!strcmp(ctx->kernels[i].name, name)) {
            *out = ctx->kernels[i].kernel;
            return PN_SUCCESS;
        }
    cl_program program;
    pn_status st = pn_context_program(ctx, stage, &program);
    if (st)
        return st;
    if (ctx->kernel_count == PN_MAX_KERNELS)
        return pn_fail(ctx, PN_ERROR_INTERNAL, "too many kernels");
    cl_int err;
    cl_kernel k = clCreateKernel(program, name, &err);
    if (err != CL_SUCCESS)
        return pn_fail(ctx, PN_ERROR_INTERNAL, "kernel '%s' is missing from stage '%s' (OpenCL %d)", name, stage, err);
    /* `name` is a string literal of the caller: it outlives the context. */
    ctx->kernels[ctx->kernel_count].name = name;
    ctx->kernels[ctx->kernel_count].kernel = k;
    ctx->kernel_count++;
    *out = k;
    return PN_SUCCESS;
}

pn_status pn_set_args(pn_context ctx, cl_kernel kernel, const char *name, int count, const size_t *sizes,
                      const void *const *values)
{
    for (int i = 0; i < count; ++i) {
        cl_int err = clSetKernelArg(kernel, (cl_uint)i, sizes[i], values[i]);
        if (err != CL_SUCCESS)
            return pn_fail(ctx, PN_ERROR_INTERNAL, "setting argument %d of kernel %s failed (OpenCL %d)", i, name, err);
    }
    return PN_SUCCESS;
}

pn_status pn_enqueue_1d(pn_context ctx, cl_kernel kernel, const char *name, size_t items, size_t local)
{
    if (items == 0)
        return PN_SUCCESS;
    size_t global = local ? (items + local - 1) / local * local : items;
    cl_int err = clEnqueueNDRangeKernel(ctx->queue, kernel, 1, NULL, &global, local ? &local : NULL, 0, NULL, NULL);
    if (err != CL_SUCCESS) {
        char what[128];
        snprintf(what, sizeof what, "enqueueing kernel %s", name);
        return pn_fail_cl(ctx, err, what);
    }
    return PN_SUCCESS;
}

pn_status pn_alloc(pn_context ctx, size_t bytes, cl_mem_flags flags, const void *host, cl_mem *out, const char *what)
{
    pn_status st = pn_check_bytes(ctx, bytes, what);
    if (st) {
        *out = NULL;
        return st;
    }
    cl_int err;
    if (host && !(flags & CL_MEM_USE_HOST_PTR))
        flags |= CL_MEM_COPY_HOST_PTR;
    *out = clCreateBuffer(ctx->cl_ctx, flags, bytes ? bytes : 16, (void *)host, &err);
    if (err != CL_SUCCESS) {
        *out = NULL;
        return pn_fail(ctx, err == CL_MEM_OBJECT_ALLOCATION_FAILURE || err == CL_OUT_OF_RESOURCES ||
                                    err == CL_OUT_OF_HOST_MEMORY || err == CL_INVALID_BUFFER_SIZE
                                ? PN_ERROR_OUT_OF_MEMORY
                                : err,
                       "allocating %zu bytes on the device for %s failed (OpenCL %d)", bytes, what, err);
    }
    return PN_SUCCESS;
}

void *pn_context_cache(pn_context ctx, const void *key)
{
    for (int i = 0; i < ctx->cache_count; ++i)
        if (ctx->caches[i].key == key)
            return ctx->caches[i].data;
    return NULL;
}

pn_status pn_context_set_cache(pn_context ctx, const void *key, void *data, void (*free_data)(void *data))
{
    if (ctx->cache_count == PN_MAX_CACHES)
        return pn_fail(ctx, PN_ERROR_INTERNAL, "the context's cache table is full (%d entries)", PN_MAX_CACHES);
    pn_cache_entry e = {key, data, free_data};
    ctx->caches[ctx->cache_count++] = e;
    return PN_SUCCESS;
}

typedef struct table_cache {
    cl_mem table;
} table_cache;

static void free_table_cache(void *data)
{
    table_cache *c = data;
    pn_mem_release(&c->table);
    free(c);
}

pn_status pn_context_table(pn_context ctx, const void *key, size_t floats, void (*fill)(float *out),
                           const char *what, cl_mem *out)
{
    table_cache *c = pn_context_cache(ctx, key);
    if (c) {
        *out = c->table;
        return PN_SUCCESS;
    }
    const size_t bytes = floats * sizeof(float);
    float *host = pn_malloc(ctx, bytes, what);
    if (!host)
        return PN_ERROR_OUT_OF_MEMORY;
    fill(host);
    cl_mem buf;
    pn_status st = pn_alloc(ctx, bytes, CL_MEM_READ_ONLY, host, &buf, what);
    free(host);
    if (st)
        return st;
    if (!(c = pn_malloc(ctx, sizeof *c, what))) {
        pn_mem_release(&buf);
        return PN_ERROR_OUT_OF_MEMORY;
    }
    c->table = buf;
    if ((st = pn_context_set_cache(ctx, key, c, free_table_cache))) {
        free_table_cache(c);
        return st;
    }
    *out = buf;
    return PN_SUCCESS;
}

static void CL_CALLBACK free_upload(cl_event event, cl_int status, void *copy)
{
    (void)event;
    (void)status;
    free(copy);
}

pn_status pn_upload_async(pn_context ctx, cl_mem buffer, const void *host, size_t bytes, const char *what)
{
    void *copy = pn_malloc(ctx, bytes, what);
    if (!copy)
        return PN_ERROR_OUT_OF_MEMORY;
    memcpy(copy, host, bytes);
    cl_event done = NULL;
    cl_int err = clEnqueueWriteBuffer(ctx->queue, buffer, CL_FALSE, 0, bytes, copy, 0, NULL, &done);
    if (err == CL_SUCCESS)
        err = clSetEventCallback(done, CL_COMPLETE, free_upload, copy);
    else
        free(copy);
    if (done)
        clReleaseEvent(done);
    /* A callback that could not be set leaks the copy rather than freeing memory still in flight. */
    return err == CL_SUCCESS ? PN_SUCCESS : pn_fail_cl(ctx, err, what);
}

void pn_mem_release(cl_mem *mem)
{
    if (*mem)
        clReleaseMemObject(*mem);
    *mem = NULL;
}

