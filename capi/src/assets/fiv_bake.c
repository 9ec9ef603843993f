/* The occlusion-field bake (docs/fiv.md): one kernel launch per sphere of
 * the grid (kernels/fiv_bake.cl), traced against a private one-instance
 * scene of the occluder; samples inside the bounding sphere are tested for
 * being inside the geometry by their winding number, evaluated over the
 * mesh's BVH with far nodes as dipoles. The bake checkpoints to
 * its file every few seconds and resumes from it. */
#define _POSIX_C_SOURCE 200809L
#include "assets/assets.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#define CHECKPOINT_SECONDS 2.0

static double now_seconds(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

/* Centre of the bounds and the largest distance from it to a vertex, in double. */
static void bounding_sphere(pn_mesh mesh, float centre[3], float *radius)
{
    double c[3], r2 = 0.0;
    for (int a = 0; a < 3; ++a)
        c[a] = 0.5 * ((double)mesh->bounds_lo[a] + (double)mesh->bounds_hi[a]);
    for (uint32_t v = 0; v < mesh->vertex_count; ++v) {
        double d2 = 0.0;
        for (int a = 0; a < 3; ++a) {
            double d = (double)mesh->positions[3 * (size_t)v + a] - c[a];
            d2 += d * d;
        }
        r2 = d2 > r2 ? d2 : r2;
    }
    for (int a = 0; a < 3; ++a)
        centre[a] = (float)c[a];
    *radius = (float)(sqrt(r2) * (1.0 + 1e-6)); /* rounding never leaves a vertex outside */
}

static bool has_area(pn_mesh mesh)
{
    for (uint32_t t = 0; t < mesh->triangle_count; ++t) {
        const float *p[3];
        for (int k = 0; k < 3; ++k)
            p[k] = mesh->positions + 3 * (size_t)mesh->indices[3 * (size_t)t + k];
        double e1[3], e2[3];
        for (int a = 0; a < 3; ++a) {
            e1[a] = (double)p[1][a] - p[0][a];
            e2[a] = (double)p[2][a] - p[0][a];
        }
        double cx = e1[1] * e2[2] - e1[2] * e2[1], cy = e1[2] * e2[0] - e1[0] * e2[2], cz = e1[0] * e2[1] - e1[1] * e2[0];
        if (cx * cx + cy * cy + cz * cz > 0.0)
            return true;
    }
    return false;
}

/* Per BVH node of the mesh, what the hierarchical winding number reads
 * (kernels/fiv_bake.cl, fiv_inside_sphere), 4 float4:
 *   [0] lo xyz, left_or_first bits   [1] hi xyz, count bits (the node itself)
 *   [2] area-weighted centroid of its triangles, radius of a ball about it
 *       holding them (to the farthest corner of the node's box)
 *   [3] sum of its triangles' area vectors (b - a) x (c - a) / 2, 0
 * Sums in double, children before parents (a child's index is larger). */
static float *winding_nodes(pn_mesh mesh)
{
    const pn_bvh *bvh = &mesh->bvh;
    const uint32_t n = bvh->node_count;
    float *out = calloc((size_t)n, 16 * sizeof(float));
    double *acc = calloc((size_t)n, 7 * sizeof(double)); /* area vector xyz, area, area x centroid xyz */
    if (!out || !acc) {
        free(out);
        free(acc);
        return NULL;
    }
    for (uint32_t k = n; k-- > 0;) {
        const pn_bvh_node *node = &bvh->nodes[k];
        double *a = acc + 7 * (size_t)k;
        if (node->count) {
            for (uint32_t t = node->left_or_first; t < node->left_or_first + node->count; ++t) {
                const float *v = mesh->leaf_tris + 12 * (size_t)t; /* 3 float4 */
                double e1[3], e2[3];
                for (int c = 0; c < 3; ++c) {
                    e1[c] = (double)v[4 + c] - v[c];
                    e2[c] = (double)v[8 + c] - v[c];
                }
                const double av[3] = {0.5 * (e1[1] * e2[2] - e1[2] * e2[1]), 0.5 * (e1[2] * e2[0] - e1[0] * e2[2]),
                                      0.5 * (e1[0] * e2[1] - e1[1] * e2[0])};
                const double area = sqrt(av[0] * av[0] + av[1] * av[1] + av[2] * av[2]);
                for (int c = 0; c < 3; ++c) {
                    a[c] += av[c];
                    a[4 + c] += area * ((double)v[c] + v[4 + c] + v[8 + c]) / 3.0;
                }
                a[3] += area;
            }
        } else {
            for (uint32_t child = node->left_or_first; child < node->left_or_first + 2; ++child)
                for (int c = 0; c < 7; ++c)
                    a[c] += acc[7 * (size_t)child + c];
        }
        float *o = out + 16 * (size_t)k;
        memcpy(o, node, sizeof *node); /* [0], [1]: the node as the ray caster reads it */
        double centre[3], r2 = 0.0;
        for (int c = 0; c < 3; ++c)
            centre[c] = a[3] > 0.0 ? a[4 + c] / a[3] : 0.5 * ((double)node->lo[c] + node->hi[c]);
        for (int corner = 0; corner < 8; ++corner) {
            double d2 = 0.0;
            for (int c = 0; c < 3; ++c) {
                const double d = ((corner >> c) & 1 ? (double)node->hi[c] : (double)node->lo[c]) - centre[c];
                d2 += d * d;
            }
            r2 = d2 > r2 ? d2 : r2;
        }
        for (int c = 0; c < 3; ++c) {
            o[8 + c] = (float)centre[c];
            o[12 + c] = (float)a[c];
        }
        o[11] = (float)(sqrt(r2) * (1.0 + 1e-6));
        o[15] = 0.0f;
    }
    free(acc);
    return out;
}

static bool same_options(const pn_fiv_options *a, const pn_fiv_options *b)
{
    return a->theta == b->theta && a->phi == b->phi && a->radii == b->radii && a->inner_radius == b->inner_radius &&
           a->error_target == b->error_target && a->face_size == b->face_size &&
           a->sun_supersampling == b->sun_supersampling && a->sun_threshold == b->sun_threshold &&
           a->precision == b->precision;
}

/* Takes over an existing bake file at `path` when it is a bake of the same
 * inputs; any other file is an error that leaves it alone. */
static pn_status resume_from(pn_fiv f, const char *path)
{
    pn_context ctx = f->obj.ctx;
    FILE *probe = fopen(path, "rb");
    if (!probe)
        return PN_SUCCESS; /* nothing to resume */
    fclose(probe);
    pn_fiv old;
    pn_status st = pn_fiv_read_file(ctx, path, true, &old);
    if (st)
        return pn_fail(ctx, st, "%s exists and is not a usable FIV bake (%s); it was left untouched: delete it or bake "
                                "to another path", path, pn_status_name_of(st));
    const char *differs = old->mesh_hash != f->mesh_hash ? "another mesh"
                          : old->env_hash != f->env_hash ? "another env map"
                          : !same_options(&old->options, &f->options) ? "other options (grid, radii, directions or precision)"
                                                                      : NULL;
    if (!differs) {
        memcpy(f->samples, old->samples, (size_t)old->radii_done * old->options.theta * old->options.phi * 9u * sizeof(float));
        f->radii_done = old->radii_done;
        f->inside_count = old->inside_count;
        f->outer_max = old->outer_max;
        f->value_scale = old->value_scale;
        f->rays = old->rays;
        f->bake_seconds = old->bake_seconds;
    }
    pn_object_release(&old->obj);
    if (differs)
        return pn_fail(ctx, PN_ERROR_INVALID_ARGUMENT,
                       "%s holds a FIV bake of %s; it was left untouched: delete it or bake to another path", path,
                       differs);
    return PN_SUCCESS;
}

typedef struct {
    cl_kernel bake, inside;
    cl_mem records, out, rays, flags, winding;
    cl_int record_count;
    float *host_out;
    cl_uint *host_rays;
    cl_uchar *host_flags;
} bake_state;

static pn_status bake_sphere(pn_fiv f, pn_scene scene, bake_state *b, uint32_t k)
{
    pn_context ctx = f->obj.ctx;
    const cl_int nt = (cl_int)f->options.theta, np = (cl_int)f->options.phi;
    const size_t per = (size_t)nt * (size_t)np;
    const cl_float rho = pn_fiv_radius(f, k);
    const cl_float4 sphere = {{f->centre[0], f->centre[1], f->centre[2], f->radius}};
    /* Inside flags first (only spheres inside the bounding sphere can have
     * samples inside the geometry), so that the bake skips those samples. */
    const bool test_inside = rho < f->radius;
    pn_status st;
    if (test_inside) {
        size_t sizes[] = {sizeof(cl_mem), sizeof(cl_mem), sizeof sphere, sizeof nt, sizeof np, sizeof rho, sizeof(cl_mem)};
        const void *vals[] = {&b->winding, &scene->tris, &sphere, &nt, &np, &rho, &b->flags};
        if ((st = pn_set_args(ctx, b->inside, "fiv_inside_sphere", 7, sizes, vals)) ||
            (st = pn_enqueue_1d(ctx, b->inside, "fiv_inside_sphere", per, 64)))
            return st;
    } else {
        const cl_uchar zero = 0;
        cl_int err = clEnqueueFillBuffer(ctx->queue, b->flags, &zero, 1, 0, per, 0, NULL, NULL);
        if (err != CL_SUCCESS)
            return pn_fail_cl(ctx, err, "clearing inside flags");
    }
    if ((st = pn_scene_set_kernel_args(scene, b->bake, "fiv_bake_sphere", 0)))
        return st;
    {
        size_t sizes[] = {sizeof(cl_mem), sizeof b->record_count, sizeof sphere, sizeof nt, sizeof np, sizeof rho,
                          sizeof(cl_mem), sizeof(cl_mem), sizeof(cl_mem)};
        const void *vals[] = {&b->records, &b->record_count, &sphere, &nt, &np, &rho, &b->flags, &b->out, &b->rays};
        for (cl_uint i = 0; i < 9; ++i) {
            cl_int err = clSetKernelArg(b->bake, 6 + i, sizes[i], vals[i]);
            if (err != CL_SUCCESS)
                return pn_fail_cl(ctx, err, "setting fiv_bake_sphere arguments");
        }
    }
    if ((st = pn_enqueue_1d(ctx, b->bake, "fiv_bake_sphere", per, 64)))
        return st;
    cl_int err = clEnqueueReadBuffer(ctx->queue, b->out, CL_TRUE, 0, per * 9 * sizeof(float), b->host_out, 0, NULL, NULL);
    if (err == CL_SUCCESS)
        err = clEnqueueReadBuffer(ctx->queue, b->rays, CL_TRUE, 0, per * sizeof(cl_uint), b->host_rays, 0, NULL, NULL);
    if (err == CL_SUCCESS && test_inside)
        err = clEnqueueReadBuffer(ctx->queue, b->flags, CL_TRUE, 0, per, b->host_flags, 0, NULL, NULL);
    if (err != CL_SUCCESS)
        return pn_fail_cl(ctx, err, "reading a baked sphere");
    float *dst = f->samples + (size_t)k * per * 9u;
    const bool half = f->options.precision == PN_PRECISION_FLOAT16;
    for (size_t s = 0; s < per; ++s) {
        const size_t i = s / (size_t)np, j = s % (size_t)np;
        const bool pole = i == 0 || i == (size_t)nt - 1;
        const size_t src = pole ? i * (size_t)np : s; /* a pole's azimuths are one point */
        if (!pole || j == 0)
            f->rays += b->host_rays[s];
        const bool inside = test_inside && b->host_flags[src];
        f->inside_count += inside;
        for (int c = 0; c < 9; ++c) {
            float v = inside ? NAN : b->host_out[9 * src + (size_t)c];
            if (half && !inside) /* keep what the file and the device will hold */
                v = pn_float_from_half(pn_half_from_float(v / f->value_scale)) * f->value_scale;
            dst[9 * s + (size_t)c] = v;
        }
    }
    if (k == f->options.radii - 1) {
        float largest = 0.0f;
        for (size_t s = 0; s < per; ++s)
            for (int c = 0; c < 3; ++c) {
                const float *v = dst + 9 * s;
                float norm = sqrtf(v[c] * v[c] + v[3 + c] * v[3 + c] + v[6 + c] * v[6 + c]);
                if (norm > largest) /* NaN (inside) never compares greater */
                    largest = norm;
            }
        f->outer_max = largest;
    }
    return PN_SUCCESS;
}

pn_status pn_fiv_do_bake(pn_envmap env, pn_mesh mesh, const pn_fiv_options *options, const char *path,
                         pn_progress_callback progress, void *user, pn_fiv *out)
{
    pn_context ctx = env->obj.ctx;
    *out = NULL;
    pn_status st;
    if (mesh->obj.ctx != ctx)
        return pn_fail(ctx, PN_ERROR_INVALID_ARGUMENT, "pn_fiv_bake: the env map and the mesh belong to different contexts");
    if (!env->committed)
        return pn_fail(ctx, PN_ERROR_NOT_COMMITTED, "pn_fiv_bake: the env map changed since its last commit");
    if (!mesh->committed)
        return pn_fail(ctx, PN_ERROR_NOT_COMMITTED, "pn_fiv_bake: the mesh changed since its last commit");
    if ((st = pn_fiv_check_options(ctx, options)))
        return st;
    if (!has_area(mesh))
        return pn_fail(ctx, PN_ERROR_EMPTY_INPUT,
                       "pn_fiv_bake: the occluder mesh has no triangle of nonzero area: it hides nothing");
    const double start = now_seconds();
    pn_fiv f;
    if ((st = pn_fiv_new(ctx, options, &f)))
        return st;
    bounding_sphere(mesh, f->centre, &f->radius);
    f->inner = options->inner_radius * f->radius;
    f->outer = f->radius / sqrtf(options->error_target);
    const char *problem = pn_fiv_geometry_problem(f);
    if (problem) {
        st = pn_fail(ctx, PN_ERROR_INVALID_VALUE,
                     "pn_fiv_bake: the mesh cannot be baked: %s (bounding radius %g, outermost sphere %g; float "
                     "overflow)",
                     problem, (double)f->radius, (double)f->outer);
        pn_object_release(&f->obj);
        return st;
    }
    f->mesh_hash = mesh->content_hash;
    f->env_hash = env->content_hash;
    f->mesh_vertices = mesh->vertex_count;
    f->mesh_triangles = mesh->triangle_count;
    /* A finished bake of the same inputs is loaded before any env work. */
    if (path && (st = resume_from(f, path))) {
        pn_object_release(&f->obj);
        return st;
    }
    const double resumed_seconds = f->bake_seconds; /* of the checkpoint's earlier runs */
    if (f->radii_done == options->radii) {
        *out = f;
        return PN_SUCCESS;
    }
    float *records = NULL;
    size_t record_count = 0;
    st = pn_envmap_direction_records(env, (int)options->face_size, (int)options->sun_supersampling,
                                     options->sun_threshold, &records, &record_count);
    if (!st) {
        /* Half storage scales by the env's total power per channel, a bound
         * on any |FIV| component (the same value a resumed file holds). */
        double power[3] = {0, 0, 0};
        for (size_t r = 0; r < record_count; ++r)
            for (int c = 0; c < 3; ++c)
                power[c] += (double)records[8 * r + 4 + c] * records[8 * r + 3];
        double largest = fmax(power[0], fmax(power[1], power[2]));
        f->value_scale = largest > 0.0 ? (float)largest : 1.0f;
    }
    pn_scene scene = NULL;
    bake_state b = {0};
    const size_t per = (size_t)options->theta * options->phi;
    b.record_count = (cl_int)record_count;
    if (!st && (!(b.host_out = pn_malloc(ctx, per * 9 * sizeof(float), "a baked sphere")) ||
                !(b.host_rays = pn_malloc(ctx, per * sizeof(cl_uint), "ray counts")) ||
                !(b.host_flags = pn_malloc(ctx, per, "inside flags"))))
        st = PN_ERROR_OUT_OF_MEMORY;
    uint32_t id;
    if (!st && !(st = pn_scene_new(ctx, &scene)) && !(st = pn_scene_do_add_instance(scene, mesh, NULL, NULL, &id)))
        st = pn_scene_do_commit(scene);
    if (!st && !(st = pn_context_kernel(ctx, "fiv_bake", "fiv_bake_sphere", &b.bake)) &&
        !(st = pn_context_kernel(ctx, "fiv_bake", "fiv_inside_sphere", &b.inside)) &&
        !(st = pn_alloc(ctx, (record_count ? record_count : 1) * 32, CL_MEM_READ_ONLY, record_count ? records : NULL,
                        &b.records, "FIV bake directions")) &&
        !(st = pn_alloc(ctx, per * 9 * sizeof(float), CL_MEM_WRITE_ONLY, NULL, &b.out, "a baked sphere")) &&
        !(st = pn_alloc(ctx, per * sizeof(cl_uint), CL_MEM_WRITE_ONLY, NULL, &b.rays, "ray counts")) &&
        !(st = pn_alloc(ctx, per, CL_MEM_READ_WRITE, NULL, &b.flags, "inside flags"))) {
        /* The one-mesh scene's triangles are the mesh's, in its BVH's leaf order. */
        float *winding = winding_nodes(mesh);
        st = winding ? pn_alloc(ctx, (size_t)mesh->bvh.node_count * 16 * sizeof(float), CL_MEM_READ_ONLY, winding,
                                &b.winding, "winding-number nodes")
                     : pn_fail(ctx, PN_ERROR_OUT_OF_MEMORY, "out of memory for the winding-number nodes");
        free(winding);
    }
    double last_checkpoint = now_seconds();
    const uint64_t total = pn_fiv_sample_count(options);
    while (!st && f->radii_done < options->radii) {
        if ((st = bake_sphere(f, scene, &b, f->radii_done)))
            break;
        f->radii_done++;
        const bool finished = f->radii_done == options->radii;
        const bool stop = progress && progress(user, (uint64_t)f->radii_done * per, total) != 0;
        f->bake_seconds = resumed_seconds + (now_seconds() - start);
        if (path && (finished || stop || now_seconds() - last_checkpoint >= CHECKPOINT_SECONDS)) {
            if ((st = pn_fiv_write_file(f, path)))
                break;
            last_checkpoint = now_seconds();
        }
        if (stop && !finished)
            st = pn_fail(ctx, PN_ERROR_CANCELLED, "FIV bake stopped after %u of %u spheres%s%s", f->radii_done,
                         options->radii, path ? "; resume it by baking again to " : "", path ? path : "");
    }
    pn_mem_release(&b.records);
    pn_mem_release(&b.out);
    pn_mem_release(&b.rays);
    pn_mem_release(&b.flags);
    pn_mem_release(&b.winding);
    free(b.host_out);
    free(b.host_rays);
    free(b.host_flags);
    free(records);
    PN_RELEASE(scene);
    if (st) {
        pn_object_release(&f->obj);
        return st;
    }
    f->bake_seconds = resumed_seconds + (now_seconds() - start);
    *out = f;
    return PN_SUCCESS;
}
