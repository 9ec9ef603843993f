/* G-buffers and images: per-pixel device buffers, owned or borrowed from the
 * caller (docs/gbuffer.md gives the layout). */
#include "core/core.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>

size_t pn_gbuffer_plane_element_size(pn_gbuffer_plane plane)
{
    switch (plane) {
    case PN_GBUFFER_POSITION:
    case PN_GBUFFER_NORMAL:
    case PN_GBUFFER_ALBEDO:
    case PN_GBUFFER_MATERIAL: return 16;
    case PN_GBUFFER_INSTANCE: return 4;
    default: return 0;
    }
}

static const char *plane_names[PN_GBUFFER_PLANE_COUNT] = {"position", "normal", "albedo", "material", "instance"};

pn_status pn_check_cl_buffer(pn_context ctx, cl_mem buffer, size_t needed, const char *what)
{
    size_t size = 0;
    cl_int err = clGetMemObjectInfo(buffer, CL_MEM_SIZE, sizeof size, &size, NULL);
    if (err != CL_SUCCESS)
        return pn_fail(ctx, PN_ERROR_INVALID_ARGUMENT, "%s is not a valid cl_mem (OpenCL %d)", what, err);
    cl_context owner = NULL;
    clGetMemObjectInfo(buffer, CL_MEM_CONTEXT, sizeof owner, &owner, NULL);
    if (owner != ctx->cl_ctx)
        return pn_fail(ctx, PN_ERROR_INVALID_ARGUMENT, "%s belongs to a different cl_context", what);
    if (size < needed)
        return pn_fail(ctx, PN_ERROR_INVALID_SIZE, "%s holds %zu bytes but %zu are needed", what, size, needed);
    return PN_SUCCESS;
}

static pn_status check_size(pn_context ctx, uint32_t width, uint32_t height, const char *what)
{
    if (width == 0 || height == 0)
        return pn_fail(ctx, PN_ERROR_EMPTY_INPUT, "%s size %ux%u is empty", what, width, height);
    if (width > 32768 || height > 32768)
        return pn_fail(ctx, PN_ERROR_INVALID_SIZE, "%s size %ux%u exceeds 32768", what, width, height);
    return PN_SUCCESS;
}

static void destroy_gbuffer(pn_object *o);
static const pn_object_type gbuffer_type = {PN_MAGIC_GBUFFER, "G-buffer", destroy_gbuffer, NULL};

pn_status pn_gbuffer_new(pn_context ctx, uint32_t width, uint32_t height, const cl_mem *planes, pn_gbuffer *out)
{
    pn_status st = check_size(ctx, width, height, "G-buffer");
    if (st)
        return st;
    const size_t pixels = (size_t)width * height;
    if (!planes && (st = pn_check_bytes(ctx, pn_mul_size(pixels, 4 * 16 + 4, 1), "a G-buffer")))
        return st;
    for (int p = 0; planes && p < PN_GBUFFER_PLANE_COUNT; ++p) {
        char what[64];
        snprintf(what, sizeof what, "G-buffer plane %d (%s)", p, plane_names[p]);
        if (!planes[p])
            return pn_fail(ctx, PN_ERROR_NULL_HANDLE, "%s is NULL", what);
        if ((st = pn_check_cl_buffer(ctx, planes[p], pixels * pn_gbuffer_plane_element_size((pn_gbuffer_plane)p), what)))
            return st;
    }
    pn_gbuffer gb = pn_object_new(ctx, sizeof *gb, &gbuffer_type, "a G-buffer");
    if (!gb)
        return PN_ERROR_OUT_OF_MEMORY;
    gb->width = width;
    gb->height = height;
    for (int p = 0; p < PN_GBUFFER_PLANE_COUNT; ++p) {
        if (planes) {
            clRetainMemObject(planes[p]);
            gb->planes[p] = planes[p];
        } else if ((st = pn_alloc(ctx, pixels * pn_gbuffer_plane_element_size((pn_gbuffer_plane)p), CL_MEM_READ_WRITE, NULL,
                                  &gb->planes[p], plane_names[p]))) {
            pn_object_release(&gb->obj);
            return st;
        }
    }
    *out = gb;
    return PN_SUCCESS;
}

static void destroy_gbuffer(pn_object *o)
{
    pn_gbuffer gb = (pn_gbuffer)o;
    for (int p = 0; p < PN_GBUFFER_PLANE_COUNT; ++p)
        pn_mem_release(&gb->planes[p]);
}

pn_status pn_gbuffer_transfer(pn_gbuffer gb, pn_gbuffer_plane plane, void *host, size_t bytes, bool write)
{
    pn_context ctx = gb->obj.ctx;
    const size_t need = (size_t)gb->width * gb->height * pn_gbuffer_plane_element_size(plane);
    if (bytes != need)
        return pn_fail(ctx, PN_ERROR_INVALID_SIZE, "G-buffer plane %s of %ux%u pixels needs exactly %zu bytes, got %zu",
                       plane_names[plane], gb->width, gb->height, need, bytes);
    cl_int err = write ? clEnqueueWriteBuffer(ctx->queue, gb->planes[plane], CL_TRUE, 0, need, host, 0, NULL, NULL)
                       : clEnqueueReadBuffer(ctx->queue, gb->planes[plane], CL_TRUE, 0, need, host, 0, NULL, NULL);
    return err == CL_SUCCESS ? PN_SUCCESS : pn_fail_cl(ctx, err, write ? "writing a G-buffer plane" : "reading a G-buffer plane");
}

/* The first field of a pixel's albedo (rgb, k_s) or material (shininess,
 * roughness or n_v, lobe, tangent angle) that the validation kernel's rules refuse. */
static const char *bad_field(int plane, const float v[4], char *buf, size_t size)
{
    if (plane == 1) {
        static const char *const names[3] = {"albedo.r", "albedo.g", "albedo.b"};
        for (int c = 0; c < 3; ++c)
            if (!(v[c] >= 0.0f && isfinite(v[c]))) {
                snprintf(buf, size, "%s = %g (must be finite and >= 0)", names[c], (double)v[c]);
                return buf;
            }
        snprintf(buf, size, "specular k_s (albedo.w) = %g (must be in [0, 1])", (double)v[3]);
        return buf;
    }
    const bool aniso = v[2] == 3.0f;
    if (!(v[0] >= 0.0f && isfinite(v[0])))
        snprintf(buf, size, "shininess (material.x) = %g (must be finite and >= 0)", (double)v[0]);
    else if (aniso && !(v[1] >= 0.0f && isfinite(v[1])))
        snprintf(buf, size, "shininess n_v (material.y, Ashikhmin-Shirley) = %g (must be finite and >= 0)", (double)v[1]);
    else if (!aniso && !(v[1] >= 0.0f && v[1] <= 1.0f))
        snprintf(buf, size, "roughness (material.y) = %g (must be in [0, 1])", (double)v[1]);
    else if (aniso)
        snprintf(buf, size, "tangent angle (material.w, Ashikhmin-Shirley) = %g (must be finite)", (double)v[3]);
    else
        snprintf(buf, size, "lobe (material.z) = %g (must be 0, 1, 2 or 3)", (double)v[2]);
    return buf;
}

pn_status pn_gbuffer_do_validate(pn_gbuffer gb)
{
    pn_context ctx = gb->obj.ctx;
    cl_kernel k;
    pn_status st = pn_context_kernel(ctx, "raycast", "gbuffer_validate", &k);
    if (st)
        return st;
    cl_int zero[3] = {0, 0, 0};
    cl_mem counters;
    if ((st = pn_alloc(ctx, sizeof zero, CL_MEM_READ_WRITE, zero, &counters, "G-buffer validation")))
        return st;
    cl_mem first = NULL;
    cl_int init_first[3] = {0x7fffffff, 0x7fffffff, 0x7fffffff};
    st = pn_alloc(ctx, sizeof init_first, CL_MEM_READ_WRITE, init_first, &first, "G-buffer validation");
    const cl_int count = (cl_int)(gb->width * gb->height);
    if (!st) {
        size_t sizes[] = {sizeof(cl_mem), sizeof(cl_mem), sizeof(cl_mem), sizeof(cl_mem),
                          sizeof(cl_mem), sizeof count,   sizeof(cl_mem), sizeof(cl_mem)};
        const void *vals[] = {&gb->planes[PN_GBUFFER_POSITION], &gb->planes[PN_GBUFFER_NORMAL],
                              &gb->planes[PN_GBUFFER_ALBEDO],   &gb->planes[PN_GBUFFER_MATERIAL],
                              &gb->planes[PN_GBUFFER_INSTANCE], &count,
                              &counters,                        &first};
        st = pn_set_args(ctx, k, "gbuffer_validate", 8, sizes, vals);
    }
    if (!st)
        st = pn_enqueue_1d(ctx, k, "gbuffer_validate", (size_t)count, 64);
    cl_int bad[3] = {0, 0, 0}, first_bad[3] = {0, 0, 0};
    if (!st) {
        cl_int err = clEnqueueReadBuffer(ctx->queue, counters, CL_TRUE, 0, sizeof bad, bad, 0, NULL, NULL);
        if (err == CL_SUCCESS)
            err = clEnqueueReadBuffer(ctx->queue, first, CL_TRUE, 0, sizeof first_bad, first_bad, 0, NULL, NULL);
        if (err != CL_SUCCESS)
            st = pn_fail_cl(ctx, err, "reading G-buffer validation results");
    }
    pn_mem_release(&counters);
    pn_mem_release(&first);
    if (!st && bad[0] > 0)
        return pn_fail(ctx, PN_ERROR_INVALID_VALUE,
                       "G-buffer has %d foreground pixels with a non-finite position or normal or a zero normal, first "
                       "at (x=%u, y=%u)",
                       bad[0], (unsigned)first_bad[0] % gb->width, (unsigned)first_bad[0] / gb->width);
    for (int c = 1; !st && c < 3; ++c) {
        if (bad[c] <= 0)
            continue;
        const pn_gbuffer_plane plane = c == 1 ? PN_GBUFFER_ALBEDO : PN_GBUFFER_MATERIAL;
        float v[4] = {0, 0, 0, 0};
        cl_int err = clEnqueueReadBuffer(ctx->queue, gb->planes[plane], CL_TRUE, (size_t)first_bad[c] * sizeof v,
                                         sizeof v, v, 0, NULL, NULL);
        if (err != CL_SUCCESS)
            return pn_fail_cl(ctx, err, "reading a G-buffer pixel that failed validation");
        char field[128];
        return pn_fail(ctx, PN_ERROR_INVALID_VALUE,
                       "G-buffer %s plane has %d foreground pixels out of range, first at (x=%u, y=%u): %s",
                       plane_names[plane], bad[c], (unsigned)first_bad[c] % gb->width,
                       (unsigned)first_bad[c] / gb->width, bad_field(c, v, field, sizeof field));
    }
    return st;
}

static void destroy_image(pn_object *o);
static const pn_object_type image_type = {PN_MAGIC_IMAGE, "image", destroy_image, NULL};

pn_status pn_image_new(pn_context ctx, uint32_t width, uint32_t height, cl_mem buffer, pn_image *out)
{
    pn_status st = check_size(ctx, width, height, "image");
    if (st)
        return st;
    const size_t bytes = (size_t)width * height * 16;
    if (buffer && (st = pn_check_cl_buffer(ctx, buffer, bytes, "image buffer")))
        return st;
    if (!buffer && (st = pn_check_bytes(ctx, bytes, "an image")))
        return st;
    pn_image img = pn_object_new(ctx, sizeof *img, &image_type, "an image");
    if (!img)
        return PN_ERROR_OUT_OF_MEMORY;
    img->width = width;
    img->height = height;
    if (buffer) {
        clRetainMemObject(buffer);
        img->buffer = buffer;
    } else if ((st = pn_alloc(ctx, bytes, CL_MEM_READ_WRITE, NULL, &img->buffer, "an image"))) {
        pn_object_release(&img->obj);
        return st;
    }
    *out = img;
    return PN_SUCCESS;
}

static void destroy_image(pn_object *o)
{
    pn_image img = (pn_image)o;
    pn_mem_release(&img->buffer);
}

pn_status pn_image_do_read(pn_image img, float *host, size_t bytes)
{
    pn_context ctx = img->obj.ctx;
    const size_t need = (size_t)img->width * img->height * 16;
    if (bytes != need)
        return pn_fail(ctx, PN_ERROR_INVALID_SIZE, "image of %ux%u pixels needs exactly %zu bytes, got %zu", img->width,
                       img->height, need, bytes);
    cl_int err = clEnqueueReadBuffer(ctx->queue, img->buffer, CL_TRUE, 0, need, host, 0, NULL, NULL);
    return err == CL_SUCCESS ? PN_SUCCESS : pn_fail_cl(ctx, err, "reading an image");
}
