/* The `depthmap` method (docs/depthmap.md, kernels/depthmap.cl): depth-map
 * environment sampling. The env map is split into N directional domains
 * (pn_envmap_domains, or the caller's through pn_renderer_set_env_domains);
 * every frame each domain gets an orthographic depth map fitted to the scene
 * along its direction, and the pixels are shaded with the domains' radiance
 * times their depth-map visibility.
 * Plan: the domains uploaded (when the env map, N, seed or the caller's
 * domains change) and the map buffers sized. Execute: the map frames from
 * the instances' boxes (host, uploaded without waiting), the maps (clear and
 * rasterise, or ray cast) and the shading kernel, all enqueued. */
#include "methods/depthmap_table.h"
#include "methods/method.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#define DM_FRAME_FLOATS 16 /* kernels/depthmap.cl DM_FRAME float4 */
#define DM_MAX_TEXELS (1u << 28) /* maps x res^2 (1 GiB of depths) */
#define DM_LARGE_CAPACITY (1u << 20) /* (map, triangle) entries of the rasteriser's large-triangle list */
#define DM_LARGE_GROUPS 256          /* work-groups of depthmap_raster_large */
#define SKIP_POWER_DEFAULT 0.01      /* skip_power's default (docs/depthmap.md, measured) */
#define TABLE_MIN_EXPONENT_DEFAULT 32 /* below it the cap quadrature is closer (docs/depthmap.md, measured) */
#define STRONG_RESOLUTION_DEFAULT 256 /* strong domains' map side (0: none; docs/depthmap.md, measured) */
#define STRONG_SHARE_DEFAULT 0.2      /* a domain with this share of the power is strong (the sun; docs/depthmap.md) */
#define STRONG_RATIO_DEFAULT 4.0      /* or with this many times the mean domain power (any N; docs/depthmap.md, measured) */
#define DM_MAX_SIDE 4096              /* largest map side, the renderer's or the caller's */
#define GRADE_DEFAULT 0.5             /* map side exponent of the power over the mean (docs/depthmap.md, measured) */
#define STRONG_CLUSTER_DEFAULT 32.0   /* radiance per sr over the average that joins a cluster (docs/depthmap.md) */
#define SHARP_DEFAULT 1               /* sharp domains of the env map's concentrated light (docs/depthmap.md) */
#define SOFT_SHADOWS_DEFAULT 1        /* the sharp domains filtered by their cap (docs/depthmap.md, measured) */
#define SHARP_THRESHOLD_DEFAULT 100.0 /* a texel is sharp above this many times the mean luminance */
#define DM_CLUSTER_REACH 1.5          /* neighbours: centres within this many times the sum of their cap radii */

enum { P_BACKGROUND, P_DIRECTIONS, P_SEED, P_RESOLUTION, P_MAP_RENDERER, P_BIAS, P_SLOPE_BIAS, P_PCF, P_SPECULAR,
       P_CAP_SAMPLES, P_VISIBILITY, P_REUSE_MAPS, P_SKIP_POWER, P_HALF_MAPS, P_FIT,
       P_TABLE_MIN_EXPONENT, P_STRONG_RESOLUTION, P_STRONG_SHARE,
       P_STRONG_RATIO, P_GRADE, P_STRONG_CLUSTER, P_SHARP, P_SHARP_THRESHOLD, P_LOBE_TABLES, P_SOFT_SHADOWS,
       P_RECEIVER_PLANE, P_LOBE_CENTROID };

static const pn_param_desc params[] = {
    PN_PARAM_BACKGROUND,
    {"directions", PN_PARAM_INT, PN_PARAM_PLAN, 64, 1, PN_ENV_DOMAINS_MAX, "domains",
     "N, the env map's directional domains, one depth map each (ignored when the caller gives its domains)."},
    {"seed", PN_PARAM_INT, PN_PARAM_PLAN, 1, 0, 4294967295.0, "", "Seed of the decomposition's initial draw."},
    {"resolution", PN_PARAM_INT, PN_PARAM_PLAN, 128, 8, 4096, "texels",
     "Depth-map side (maps are square; 128 with fit 1 is below 256 with fit 0 in error, docs/depthmap.md)."},
    {"map_renderer", PN_PARAM_INT, PN_PARAM_FRAME, 1, 0, 1, "",
     "How the maps are drawn: 0 compute rasteriser (atomic-min depth), 1 BVH ray caster (as fast or faster on "
     "CPUs, docs/depthmap.md)."},
    {"bias", PN_PARAM_FLOAT, PN_PARAM_FRAME, 1.0, 0, 64, "texels",
     "Constant depth bias, in texels of the map."},
    {"slope_bias", PN_PARAM_FLOAT, PN_PARAM_FRAME, 1.0, 0, 64, "texels",
     "Depth bias per unit tan(angle to the normal), times sqrt(2) pcf + 1, in texels (tan capped at 32)."},
    {"pcf", PN_PARAM_INT, PN_PARAM_FRAME, 0, 0, 4, "texels",
     "Percentage-closer filter radius: (2 pcf + 1)^2 depth comparisons per lookup."},
    {"specular", PN_PARAM_INT, PN_PARAM_FRAME, 3, 0, 3, "",
     "Lobe over a domain: 0 point sample at its centre, 1 the seed's average-reflectivity blend (Phong; others "
     "point), 2 cap quadrature (every lobe), 3 the table of exact cap averages (every lobe; docs/depthmap.md)."},
    {"cap_samples", PN_PARAM_INT, PN_PARAM_FRAME, 16, 1, 256, "",
     "Points of the cap quadrature (specular 2; with 3, for lobes broader than the table's)."},
    {"visibility", PN_PARAM_INT, PN_PARAM_FRAME, 1, 0, 1, "", "1: depth-map shadows, 0: every domain unoccluded."},
    {"reuse_maps", PN_PARAM_INT, PN_PARAM_FRAME, 0, 0, 1, "",
     "1: keep the maps of the previous frame (nothing moved); the first frame draws them anyway."},
    {"skip_power", PN_PARAM_FLOAT, PN_PARAM_FRAME, SKIP_POWER_DEFAULT, 0, 1, "of the power",
     "The weakest domains whose powers add up to at most this share of the total get no depth map and are lit "
     "unshadowed (docs/depthmap.md)."},
    {"half_maps", PN_PARAM_INT, PN_PARAM_FRAME, 0, 0, 1, "",
     "1: the shading looks up 16-bit copies of the maps (depth quantised to extent / 65534, the seed's storage); 0: "
     "32-bit floats."},
    {"fit", PN_PARAM_INT, PN_PARAM_FRAME, 1, 0, 1, "",
     "What a map's footprint covers: 0 every instance's box, 1 only where a shadow can fall (every non-flat "
     "instance, and a flat one where something lies behind it; docs/depthmap.md)."},
    {"table_min_exponent", PN_PARAM_FLOAT, PN_PARAM_FRAME, TABLE_MIN_EXPONENT_DEFAULT, 1, 1e6, "",
     "specular 3: lobes of this equivalent Phong exponent and sharper use the table, broader ones the cap "
     "quadrature (docs/depthmap.md, measured)."},
    {"strong_resolution", PN_PARAM_INT, PN_PARAM_PLAN, STRONG_RESOLUTION_DEFAULT, 0, DM_MAX_SIDE, "texels",
     "Map side of the strong domains (strong_share or strong_ratio) when above resolution, all maps packed in one "
     "atlas; 0: every map resolution (docs/depthmap.md, measured)."},
    {"strong_share", PN_PARAM_FLOAT, PN_PARAM_PLAN, STRONG_SHARE_DEFAULT, 0, 1, "of the power",
     "A domain whose power (luminance of its radiance) is at least this share of the total gets strong_resolution "
     "(when that is set)."},
    {"strong_ratio", PN_PARAM_FLOAT, PN_PARAM_PLAN, STRONG_RATIO_DEFAULT, 0, 1e6, "x the mean",
     "So does a domain whose power is at least this many times the mean domain power (total / N: holds at any N, "
     "where the sun splits across domains); 0: strong_share alone (docs/depthmap.md, measured)."},
    {"grade", PN_PARAM_FLOAT, PN_PARAM_PLAN, GRADE_DEFAULT, 0, 4, "",
     "Map side of a domain that is not strong: resolution x (its power over the mean domain power)^grade, rounded "
     "to a multiple of 8, from 8 up to max(resolution, strong_resolution); 0: every such map resolution "
     "(docs/depthmap.md, measured)."},
    {"strong_cluster", PN_PARAM_FLOAT, PN_PARAM_PLAN, STRONG_CLUSTER_DEFAULT, 0, 1e9, "x the average radiance/sr",
     "Domains at least this many times as bright per solid angle as the environment's average that neighbour each "
     "other form a cluster; a cluster whose summed power is strong (strong_share or strong_ratio) makes all its "
     "domains strong (a sun split across domains); 0: off (docs/depthmap.md, measured)."},
    {"sharp", PN_PARAM_INT, PN_PARAM_PLAN, SHARP_DEFAULT, 0, PN_ENV_SHARP_MAX, "domains",
     "At most this many of the N domains (and fewer than N) hold the env map's sharp part alone (its texels above "
     "sharp_threshold x the mean luminance, their excess, at the light's own size; pn_envmap_extract_sharp), the "
     "residual map the rest; they are strong; 0: one decomposition of the whole map (docs/depthmap.md, measured)."},
    {"sharp_threshold", PN_PARAM_FLOAT, PN_PARAM_PLAN, SHARP_THRESHOLD_DEFAULT, 1, 1e9, "x the mean luminance",
     "A texel belongs to the sharp part (sharp > 0) where its luminance exceeds this many times the map's mean; "
     "above 1."},
    {"lobe_tables", PN_PARAM_INT, PN_PARAM_FRAME, 2, 0, 2, "",
     "specular 3: Blinn-Phong and GGX by their own tables (built once per context, seconds of CPU): 2 when an "
     "instance of the scene has such a lobe with k_s > 0, 1 always (a caller's G-buffer with lobes the scene lacks), "
     "0 never (the cap quadrature)."},
    {"soft_shadows", PN_PARAM_INT, PN_PARAM_FRAME, SOFT_SHADOWS_DEFAULT, 0, 2, "",
     "Penumbrae of the domains' caps (percentage-closer soft shadows: blocker search, then a disc filter of radius "
     "(receiver - blocker depth) x tan(cap radius), up to 8 texels; pcf ignored there): 0 none, 1 the sharp "
     "domains, 2 every domain (docs/depthmap.md, measured)."},
    {"receiver_plane", PN_PARAM_INT, PN_PARAM_FRAME, 1, 0, 1, "",
     "Hard lookups: 1 compares each tap with the receiver's depth along its tangent plane at the tap's texel "
     "centre (receiver-plane depth bias, the constant bias on top, slope_bias unused), 0 the slope-scaled bias of "
     "the farthest tap (docs/depthmap.md)."},
    {"lobe_centroid", PN_PARAM_INT, PN_PARAM_FRAME, 0, 0, 1, "",
     "Blinn-Phong and GGX tables: 0 the lobe's cosine (and G1, V.H) at the cap's point of least lobe distance; 1 "
     "at four points about the lobe-weighted centroid the tables also hold: 2-4x less error at 60-85 degree views "
     "for about 1.5x the specular shading, not the default since the rendered error barely moved (docs/depthmap.md)."},
};

_Static_assert(sizeof params / sizeof params[0] <= PN_MAX_METHOD_PARAMS,
               "depthmap has more parameters than a renderer holds (PN_MAX_METHOD_PARAMS)");

enum { OUT_DOMAINS, OUT_FRAMES, OUT_DEPTH, OUT_RESOLUTIONS };

static const pn_output_desc outputs[] = {
    {"domains",
     "N pn_env_domain (8 floats each): the domains shaded with (with sharp, the env map's sharp part first)."},
    {"map_frames", "16 floats per domain: e1 | u_min, e2 | v_min, d | far, du, dv, depth extent, has a map (1) or "
                   "is lit unshadowed (0, skip_power) (kernels/depthmap.cl)."},
    {"depth_map", "side^2 floats of domain `index` (its side: map_resolutions), row-major: depth from the light side "
                  "of its box, +inf empty (all +inf for a domain without a map)."},
    {"map_resolutions",
     "N floats: each domain's map side in texels (resolution graded by grade, strong_resolution or the caller's)."},
};

typedef struct state {
    pn_env_domain *domains;        /* the domains shaded with (host copy) */
    uint32_t domain_count;
    pn_env_domain *caller;         /* the caller's domains, or NULL */
    uint32_t caller_count;
    uint64_t caller_version;       /* a new version at each set */
    uint64_t key_env, key_caller;  /* what `domains` was built from */
    uint32_t key_n, key_seed;
    uint32_t key_sharp;            /* the sharp domains asked for (0: none) */
    double key_threshold;
    uint32_t sharp_count;          /* the first sharp_count domains are the env map's sharp part */
    cl_mem device_domains;
    cl_mem frames, depth;          /* map frames (4 float4 each), the renderer's depths (uint, an atlas) */
    uint32_t map_count;            /* what `frames` is sized for */
    size_t depth_texels;           /* what `depth` holds */
    /* The atlas of the maps shaded with (the caller's or the renderer's):
     * per domain the first texel and the side. */
    uint32_t *host_atlas, atlas_count;
    size_t atlas_texels;
    cl_mem atlas;
    uint32_t *host_list_start;     /* drawn + 1: first texel of each drawn map in a dispatch over them */
    uint32_t list_start_count;
    cl_mem list_start;
    float *host_frames;
    cl_mem ranges, starts, objects; /* rasteriser instance tables */
    cl_mem large, large_count;      /* its list of large triangles and their count */
    size_t table_capacity;          /* instances the tables hold */
    uint32_t *host_ranges, *host_starts;
    float *host_objects;
    bool maps_drawn;               /* the maps hold a frame (reuse_maps) */
    /* skip_power: which domains get a map */
    unsigned char *shadowed;       /* per domain: 1 has a map, 0 lit unshadowed */
    uint32_t *host_list;           /* the domains with a map, in domain order */
    uint32_t drawn;                /* their count */
    cl_mem list;                   /* host_list on the device */
    double key_skip;               /* skip_power the list was made for */
    bool skip_valid;               /* false when the domains changed */
    /* The caller's maps (pn_renderer_set_depth_maps*), or none (supplied_count 0). */
    cl_mem supplied_depth;         /* sum of supplied_res[m]^2 floats: ours (uploaded) or the caller's (retained) */
    bool supplied_borrowed;        /* supplied_depth is the caller's buffer */
    float *supplied_frames;        /* supplied_count x DM_FRAME_FLOATS */
    uint32_t *supplied_res;        /* per map its side */
    uint32_t supplied_count;
    uint32_t supplied_uniform;     /* pn_renderer_set_depth_maps: the renderer's resolution then (checked at execute) */
    size_t supplied_bytes;         /* size of supplied_depth when ours */
    /* half_maps: 16-bit copies of the maps for the lookups */
    cl_mem depth16;                /* atlas_texels ushort, or NULL */
    size_t depth16_texels;
    bool packed;                   /* depth16 holds the current maps */
} state;

/* --------------------------------------------------------------- domains */

static pn_status check_domains(pn_context ctx, const pn_env_domain *d, uint32_t count)
{
    if (count > PN_ENV_DOMAINS_MAX)
        return pn_fail(ctx, PN_ERROR_INVALID_ARGUMENT, "%u env domains: at most %u", count, PN_ENV_DOMAINS_MAX);
    for (uint32_t i = 0; i < count; ++i) {
        const float *dir = d[i].direction, *l = d[i].radiance;
        for (int c = 0; c < 3; ++c)
            if (!isfinite(dir[c]) || !isfinite(l[c]))
                return pn_fail(ctx, PN_ERROR_INVALID_ARGUMENT, "env domain %u has a non-finite %s (component %d)", i,
                               isfinite(dir[c]) ? "radiance" : "direction", c);
        const double len = sqrt((double)dir[0] * dir[0] + (double)dir[1] * dir[1] + (double)dir[2] * dir[2]);
        if (fabs(len - 1.0) > 1e-3)
            return pn_fail(ctx, PN_ERROR_INVALID_ARGUMENT, "env domain %u's direction has length %g: it must be unit",
                           i, len);
        if (l[0] < 0.0f || l[1] < 0.0f || l[2] < 0.0f)
            return pn_fail(ctx, PN_ERROR_INVALID_ARGUMENT, "env domain %u has a negative radiance (%g, %g, %g)", i,
                           (double)l[0], (double)l[1], (double)l[2]);
        if (!(d[i].cap_radius >= 0.0f && d[i].cap_radius <= 3.14159266f) || !(d[i].solid_angle >= 0.0f) ||
            !isfinite(d[i].solid_angle))
            return pn_fail(ctx, PN_ERROR_INVALID_ARGUMENT,
                           "env domain %u has cap radius %g and solid angle %g: the radius must be in [0, pi] rad and "
                           "the solid angle finite and >= 0",
                           i, (double)d[i].cap_radius, (double)d[i].solid_angle);
    }
    return PN_SUCCESS;
}

static pn_status set_domains(pn_renderer r, const pn_env_domain *domains, uint32_t count)
{
    state *s = r->state;
    pn_context ctx = r->obj.ctx;
    pn_status st = check_domains(ctx, domains, count);
    if (st)
        return st;
    pn_env_domain *copy = NULL;
    if (count && !(copy = pn_malloc(ctx, pn_mul_size(count, 1, sizeof *copy), "the caller's env domains")))
        return PN_ERROR_OUT_OF_MEMORY;
    if (count)
        memcpy(copy, domains, count * sizeof *copy);
    free(s->caller);
    s->caller = copy;
    s->caller_count = count;
    s->caller_version = pn_next_version();
    return PN_SUCCESS;
}

/* ---------------------------------------------------------- caller's maps */

static pn_status check_frame(pn_context ctx, const float *f, uint32_t m)
{
    for (int k = 0; k < DM_FRAME_FLOATS - 1; ++k)
        if (!isfinite(f[k]))
            return pn_fail(ctx, PN_ERROR_INVALID_ARGUMENT, "depth map %u's frame has a non-finite value at float %d",
                           m, k);
    const float *axis[3] = {f, f + 4, f + 8};
    static const char *const names[3] = {"e1", "e2", "d"};
    for (int a = 0; a < 3; ++a)
        for (int b = a; b < 3; ++b) {
            const double dot = (double)axis[a][0] * axis[b][0] + (double)axis[a][1] * axis[b][1] +
                               (double)axis[a][2] * axis[b][2];
            if (fabs(dot - (a == b ? 1.0 : 0.0)) > 1e-3)
                return pn_fail(ctx, PN_ERROR_INVALID_ARGUMENT,
                               "depth map %u's frame is not orthonormal: %s.%s = %g (e1, e2, d must be unit and "
                               "orthogonal)",
                               m, names[a], names[b], dot);
        }
    if (!(f[12] > 0.0f && f[13] > 0.0f && f[14] > 0.0f))
        return pn_fail(ctx, PN_ERROR_INVALID_ARGUMENT,
                       "depth map %u's frame has texel sizes %g x %g and depth extent %g: all must be > 0", m,
                       (double)f[12], (double)f[13], (double)f[14]);
    return PN_SUCCESS;
}

static void clear_supplied(state *s)
{
    pn_mem_release(&s->supplied_depth); /* ours, or our retain of the caller's */
    free(s->supplied_frames);
    free(s->supplied_res);
    s->supplied_frames = NULL;
    s->supplied_res = NULL;
    s->supplied_count = s->supplied_uniform = 0;
    s->supplied_bytes = 0;
    s->supplied_borrowed = false;
    s->maps_drawn = false;
}

/* The caller's maps: `frames` (host) and the depths either on the host
 * (`depths`, uploaded) or in the caller's `buffer` (retained, read in place),
 * map m of side resolutions[m], packed map after map. `uniform`: the old
 * single-resolution call's side (checked against the renderer's). */
static pn_status supply_maps(pn_renderer r, const float *frames, const float *depths, cl_mem buffer, uint32_t count,
                             const uint32_t *resolutions, uint32_t uniform)
{
    pn_context ctx = r->obj.ctx;
    if (r->method != &pn_method_depthmap)
        return pn_fail(ctx, PN_ERROR_UNSUPPORTED, "method %s takes no depth maps (depthmap does)", r->method->name);
    state *s = r->state;
    if (!count) {
        clear_supplied(s);
        return PN_SUCCESS;
    }
    if (!frames || (!depths && !buffer) || (!uniform && !resolutions))
        return pn_fail(ctx, PN_ERROR_INVALID_ARGUMENT, "%u depth maps but the %s pointer is NULL", count,
                       !frames ? "frames" : (!depths && !buffer) ? "depths" : "resolutions");
    if (count > PN_ENV_DOMAINS_MAX)
        return pn_fail(ctx, PN_ERROR_INVALID_SIZE, "%u depth maps: at most %u (one per domain)", count,
                       PN_ENV_DOMAINS_MAX);
    if (uniform && uniform != (uint32_t)r->params[P_RESOLUTION])
        return pn_fail(ctx, PN_ERROR_INVALID_SIZE,
                       "depth maps of %u x %u texels but the renderer's resolution is %u: set resolution first",
                       uniform, uniform, (uint32_t)r->params[P_RESOLUTION]);
    if (s->caller_count && count != s->caller_count)
        return pn_fail(ctx, PN_ERROR_INVALID_SIZE,
                       "%u depth maps but the renderer shades with %u domains (one map each)", count, s->caller_count);
    size_t texels = 0;
    for (uint32_t m = 0; m < count; ++m) {
        const uint32_t side = uniform ? uniform : resolutions[m];
        if (side < 1 || side > DM_MAX_SIDE)
            return pn_fail(ctx, PN_ERROR_INVALID_SIZE, "depth map %u is %u x %u texels: the side must be 1 to %u", m,
                           side, side, DM_MAX_SIDE);
        texels += (size_t)side * side;
    }
    if (texels > DM_MAX_TEXELS)
        return pn_fail(ctx, PN_ERROR_INVALID_SIZE, "%u depth maps of %zu texels in all: more than %u texels", count,
                       texels, DM_MAX_TEXELS);
    pn_status st;
    for (uint32_t m = 0; m < count; ++m)
        if ((st = check_frame(ctx, frames + (size_t)m * DM_FRAME_FLOATS, m)))
            return st;
    const size_t bytes = texels * sizeof(float);
    if (depths) {
        size_t k = 0;
        for (uint32_t m = 0; m < count; ++m) {
            const uint32_t side = uniform ? uniform : resolutions[m];
            for (size_t t = 0; t < (size_t)side * side; ++t, ++k)
                if (!(depths[k] >= 0.0f)) /* NaN, negative, -inf; +inf is an empty texel */
                    return pn_fail(ctx, PN_ERROR_INVALID_ARGUMENT,
                                   "depth map %u has %g at texel (%zu, %zu): depths must be >= 0 (+inf: empty)", m,
                                   (double)depths[k], t % side, t / side);
        }
    } else if ((st = pn_check_cl_buffer(ctx, buffer, bytes, "the caller's depth-map buffer"))) {
        return st;
    }
    float *copy = pn_malloc(ctx, pn_mul_size(count, DM_FRAME_FLOATS, sizeof(float)), "the caller's map frames");
    uint32_t *sides = pn_malloc(ctx, pn_mul_size(count, 1, sizeof(uint32_t)), "the caller's map sides");
    if (!copy || !sides) {
        free(copy);
        free(sides);
        return PN_ERROR_OUT_OF_MEMORY;
    }
    memcpy(copy, frames, (size_t)count * DM_FRAME_FLOATS * sizeof(float));
    for (uint32_t m = 0; m < count; ++m)
        sides[m] = uniform ? uniform : resolutions[m];
    if (buffer) { /* zero copy: the caller's buffer, read by every execute */
        cl_int err = clRetainMemObject(buffer);
        if (err != CL_SUCCESS) {
            free(copy);
            free(sides);
            return pn_fail_cl(ctx, err, "retaining the caller's depth-map buffer");
        }
        clear_supplied(s);
        s->supplied_depth = buffer;
        s->supplied_borrowed = true;
    } else {
        if (s->supplied_borrowed || s->supplied_bytes != bytes) {
            pn_mem_release(&s->supplied_depth);
            s->supplied_borrowed = false;
            s->supplied_bytes = 0;
            if ((st = pn_alloc(ctx, bytes, CL_MEM_READ_ONLY, NULL, &s->supplied_depth, "the caller's depth maps"))) {
                free(copy);
                free(sides);
                return st;
            }
            s->supplied_bytes = bytes;
        }
        cl_int err = clEnqueueWriteBuffer(ctx->queue, s->supplied_depth, CL_TRUE, 0, bytes, depths, 0, NULL, NULL);
        if (err != CL_SUCCESS) {
            free(copy);
            free(sides);
            return pn_fail_cl(ctx, err, "uploading the caller's depth maps");
        }
    }
    s->maps_drawn = false;
    free(s->supplied_frames);
    free(s->supplied_res);
    s->supplied_frames = copy;
    s->supplied_res = sides;
    s->supplied_count = count;
    s->supplied_uniform = uniform;
    return PN_SUCCESS;
}

pn_status pn_depthmap_set_maps(pn_renderer r, const float *frames, const float *depths, uint32_t count,
                               uint32_t resolution)
{
    if (count && !resolution)
        return pn_fail(r->obj.ctx, PN_ERROR_INVALID_SIZE, "depth maps of 0 x 0 texels");
    return supply_maps(r, frames, depths, NULL, count, NULL, count ? resolution : 0);
}

pn_status pn_depthmap_set_maps_sized(pn_renderer r, const float *frames, const float *depths, uint32_t count,
                                     const uint32_t *resolutions)
{
    return supply_maps(r, frames, depths, NULL, count, resolutions, 0);
}

pn_status pn_depthmap_set_maps_cl(pn_renderer r, const float *frames, cl_mem depths, uint32_t count,
                                  const uint32_t *resolutions)
{
    if (count && !depths)
        return pn_fail(r->obj.ctx, PN_ERROR_INVALID_ARGUMENT, "%u depth maps but the depth buffer is NULL", count);
    return supply_maps(r, frames, NULL, depths, count, resolutions, 0);
}

/* The caller's maps against the domains and resolution of this frame. */
static pn_status check_supplied(pn_renderer r)
{
    state *s = r->state;
    pn_context ctx = r->obj.ctx;
    if (!s->supplied_count)
        return PN_SUCCESS;
    if (s->supplied_count != s->domain_count)
        return pn_fail(ctx, PN_ERROR_INVALID_SIZE,
                       "%u depth maps were supplied but the renderer shades with %u domains (one map each)",
                       s->supplied_count, s->domain_count);
    if (s->supplied_uniform && s->supplied_uniform != (uint32_t)r->params[P_RESOLUTION])
        return pn_fail(ctx, PN_ERROR_INVALID_SIZE,
                       "the supplied depth maps are %u x %u texels but the renderer's resolution is now %u",
                       s->supplied_uniform, s->supplied_uniform, (uint32_t)r->params[P_RESOLUTION]);
    for (uint32_t m = 0; m < s->domain_count; ++m) {
        const float *d = s->supplied_frames + (size_t)m * DM_FRAME_FLOATS + 8, *c = s->domains[m].direction;
        const double dot = (double)d[0] * c[0] + (double)d[1] * c[1] + (double)d[2] * c[2];
        if (dot < 1.0 - 1e-6) /* 1.4e-3 rad */
            return pn_fail(ctx, PN_ERROR_INVALID_ARGUMENT,
                           "supplied depth map %u looks along (%g, %g, %g) but domain %u's direction is (%g, %g, %g)",
                           m, (double)d[0], (double)d[1], (double)d[2], m, (double)c[0], (double)c[1], (double)c[2]);
    }
    return PN_SUCCESS;
}

/* The domains to shade with: the caller's, or the env map's decomposition. */
static pn_status plan_domains(pn_renderer r, pn_scene scene)
{
    state *s = r->state;
    pn_context ctx = r->obj.ctx;
    const uint32_t n = (uint32_t)r->params[P_DIRECTIONS], seed = (uint32_t)r->params[P_SEED];
    /* sharp: at most N - 1 of the N (N = 1 keeps the whole sphere). */
    const uint32_t want = (uint32_t)r->params[P_SHARP], sharp = want < n ? want : n - 1;
    const double threshold = r->params[P_SHARP_THRESHOLD];
    const bool caller = s->caller_count > 0;
    if (s->device_domains && (caller ? s->key_caller == s->caller_version
                                     : (!s->key_caller && s->key_env == scene->env->version && s->key_n == n &&
                                        s->key_seed == seed && s->key_sharp == sharp &&
                                        (!sharp || s->key_threshold == threshold))))
        return PN_SUCCESS;
    const pn_env_domain *src = s->caller;
    uint32_t count = s->caller_count, sharp_count = 0;
    if (!caller) {
        pn_env_decompose_options o = {n, seed, 0};
        const pn_env_decomposition *dec = NULL;
        pn_status st = sharp ? pn_envmap_domains_split(scene->env, &o, sharp, (float)threshold, &dec)
                             : pn_envmap_domains(scene->env, &o, &dec);
        if (st)
            return st;
        src = dec->domains;
        count = dec->count;
        sharp_count = dec->sharp;
    }
    pn_env_domain *copy = pn_malloc(ctx, pn_mul_size(count ? count : 1, 1, sizeof *copy), "the env domains");
    if (!copy)
        return PN_ERROR_OUT_OF_MEMORY;
    memcpy(copy, src, count * sizeof *copy);
    pn_mem_release(&s->device_domains);
    pn_status st = pn_alloc(ctx, (count ? count : 1) * sizeof *copy, CL_MEM_READ_ONLY, copy, &s->device_domains,
                            "the env domains");
    if (st) {
        free(copy);
        return st;
    }
    free(s->domains);
    s->domains = copy;
    s->domain_count = count;
    s->sharp_count = sharp_count;
    s->key_caller = caller ? s->caller_version : 0;
    s->key_env = scene->env->version;
    s->key_n = n;
    s->key_seed = seed;
    s->key_sharp = sharp;
    s->key_threshold = threshold;
    s->maps_drawn = false;
    s->skip_valid = false;
    return PN_SUCCESS;
}

/* skip_power: the domains sorted by power (luminance of L~, ties by index);
 * the weakest whose powers add up to at most skip_power x the total get no
 * map (black domains always: they add nothing). The rest, in domain order,
 * is the list of maps to draw. */
typedef struct ranked {
    double power;
    uint32_t index;
} ranked;

static double domain_power(const pn_env_domain *d)
{
    return 0.2126 * d->radiance[0] + 0.7152 * d->radiance[1] + 0.0722 * d->radiance[2];
}

static int by_power(const void *a, const void *b)
{
    const ranked *x = a, *y = b;
    return x->power < y->power ? -1 : x->power > y->power ? 1 : (x->index > y->index) - (x->index < y->index);
}

static pn_status plan_skip(pn_renderer r)
{
    state *s = r->state;
    pn_context ctx = r->obj.ctx;
    const double fraction = r->params[P_SKIP_POWER];
    if (s->skip_valid && s->key_skip == fraction)
        return PN_SUCCESS;
    const uint32_t n = s->domain_count, cap = n ? n : 1;
    unsigned char *shadowed = pn_malloc(ctx, cap, "the shadowed domains");
    uint32_t *list = pn_malloc(ctx, pn_mul_size(cap, 1, sizeof *list), "the list of depth maps");
    ranked *order = pn_malloc(ctx, pn_mul_size(cap, 1, sizeof *order), "the domains by power");
    if (!shadowed || !list || !order) {
        free(shadowed);
        free(list);
        free(order);
        return PN_ERROR_OUT_OF_MEMORY;
    }
    double total = 0.0;
    for (uint32_t i = 0; i < n; ++i) {
        order[i].power = domain_power(s->domains + i);
        order[i].index = i;
        shadowed[i] = 1;
        total += order[i].power;
    }
    qsort(order, n, sizeof *order, by_power);
    double sum = 0.0;
    for (uint32_t k = 0; k < n; ++k) {
        if (fraction < 1.0 && sum + order[k].power > fraction * total)
            break;
        sum += order[k].power;
        shadowed[order[k].index] = 0;
    }
    free(order);
    uint32_t m = 0;
    for (uint32_t i = 0; i < n; ++i)
        if (shadowed[i])
            list[m++] = i;
    pn_status st = PN_SUCCESS;
    pn_mem_release(&s->list);
    if ((st = pn_alloc(ctx, (size_t)cap * sizeof *list, CL_MEM_READ_ONLY, list, &s->list, "the list of depth maps"))) {
        free(shadowed);
        free(list);
        return st;
    }
    free(s->shadowed);
    free(s->host_list);
    s->shadowed = shadowed;
    s->host_list = list;
    s->drawn = m;
    s->key_skip = fraction;
    s->skip_valid = true;
    s->maps_drawn = false;
    return PN_SUCCESS;
}

/* strong_cluster: the domains at least `cut` times the average radiance per
 * solid angle (sum of powers over sum of solid angles; a domain of no solid
 * angle with power counts as concentrated) are joined with their
 * neighbours among them (centres within DM_CLUSTER_REACH x (r_i + r_j)) by
 * union-find; every member of a cluster whose summed power reaches
 * `threshold` is marked strong in `strong`. */
static uint32_t find_root(uint32_t *parent, uint32_t i)
{
    while (parent[i] != i) {
        parent[i] = parent[parent[i]];
        i = parent[i];
    }
    return i;
}

static pn_status mark_clusters(pn_context ctx, const pn_env_domain *d, uint32_t n, const double *power, double total,
                               double threshold, double cut, unsigned char *strong)
{
    double omega = 0.0;
    for (uint32_t i = 0; i < n; ++i)
        omega += d[i].solid_angle > 0.0f ? d[i].solid_angle : 0.0;
    if (!(cut > 0.0) || !(total > 0.0) || !(omega > 0.0))
        return PN_SUCCESS;
    const double average = total / omega;
    uint32_t *member = pn_malloc(ctx, pn_mul_size(n, 2, sizeof *member), "the clusters of bright domains");
    double *sum = pn_malloc(ctx, pn_mul_size(n, 1, sizeof *sum), "the clusters' powers");
    if (!member || !sum) {
        free(member);
        free(sum);
        return PN_ERROR_OUT_OF_MEMORY;
    }
    uint32_t *parent = member + n, count = 0;
    for (uint32_t i = 0; i < n; ++i)
        if (power[i] > 0.0 && (d[i].solid_angle <= 0.0f || power[i] / d[i].solid_angle >= cut * average))
            member[count++] = i;
    for (uint32_t a = 0; a < count; ++a)
        parent[a] = a;
    for (uint32_t a = 0; a < count; ++a) {
        const pn_env_domain *x = d + member[a];
        for (uint32_t b = a + 1; b < count; ++b) {
            const pn_env_domain *y = d + member[b];
            double c = (double)x->direction[0] * y->direction[0] + (double)x->direction[1] * y->direction[1] +
                       (double)x->direction[2] * y->direction[2];
            c = c > 1.0 ? 1.0 : c < -1.0 ? -1.0 : c;
            if (acos(c) <= DM_CLUSTER_REACH * ((double)x->cap_radius + y->cap_radius)) {
                const uint32_t ra = find_root(parent, a), rb = find_root(parent, b);
                if (ra != rb)
                    parent[ra > rb ? ra : rb] = ra < rb ? ra : rb;
            }
        }
    }
    for (uint32_t a = 0; a < count; ++a)
        sum[a] = 0.0;
    for (uint32_t a = 0; a < count; ++a)
        sum[find_root(parent, a)] += power[member[a]];
    for (uint32_t a = 0; a < count; ++a)
        if (sum[find_root(parent, a)] >= threshold)
            strong[member[a]] = 1;
    free(member);
    free(sum);
    return PN_SUCCESS;
}

/* grade: a domain that is not strong gets resolution x (P_i / mean)^grade
 * texels a side, rounded to the nearest multiple of 8, within [8, cap]. */
static uint32_t graded_side(uint32_t base, uint32_t cap, double grade, double power, double mean)
{
    if (!(grade > 0.0) || !(mean > 0.0))
        return base;
    if (!(power > 0.0)) /* black (or a caller's negative luminance): the smallest map */
        return 8u < cap ? 8u : cap;
    const double want = base * pow(power / mean, grade);
    if (!(want < cap)) /* also +inf */
        return cap;
    uint32_t side = 8u * (uint32_t)floor(want / 8.0 + 0.5);
    return side < 8u ? 8u : side > cap ? cap : side;
}

/* The atlas of the maps shaded with: the caller's sides, or per domain
 * strong_resolution for a domain holding strong_share of the power or
 * strong_ratio times the mean domain power (or in a cluster that does,
 * strong_cluster), the others `resolution` graded by their power (grade); then the first texel of each drawn map in a dispatch over them.
 * Uploaded when changed. */
static pn_status plan_atlas(pn_renderer r)
{
    state *s = r->state;
    pn_context ctx = r->obj.ctx;
    const uint32_t n = s->domain_count, maps = n ? n : 1;
    uint32_t *atlas = pn_malloc(ctx, pn_mul_size(maps, 2, sizeof(uint32_t)), "the depth-map atlas");
    uint32_t *starts = pn_malloc(ctx, pn_mul_size(s->drawn + 1, 1, sizeof(uint32_t)), "the depth-map starts");
    if (!atlas || !starts) {
        free(atlas);
        free(starts);
        return PN_ERROR_OUT_OF_MEMORY;
    }
    const uint32_t base = (uint32_t)r->params[P_RESOLUTION], strong = (uint32_t)r->params[P_STRONG_RESOLUTION];
    const double share = r->params[P_STRONG_SHARE], ratio = r->params[P_STRONG_RATIO];
    if (strong && strong < 8) {
        free(atlas);
        free(starts);
        return pn_fail(ctx, PN_ERROR_INVALID_ARGUMENT, "strong_resolution %u: 0 (off) or 8 to %u texels", strong,
                       DM_MAX_SIDE);
    }
    double *power = pn_malloc(ctx, pn_mul_size(maps, 1, sizeof *power), "the domains' powers");
    unsigned char *is_strong = pn_malloc(ctx, maps, "the strong domains");
    if (!power || !is_strong) {
        free(atlas);
        free(starts);
        free(power);
        free(is_strong);
        return PN_ERROR_OUT_OF_MEMORY;
    }
    double total_power = 0.0;
    for (uint32_t m = 0; m < n; ++m)
        total_power += power[m] = domain_power(s->domains + m);
    /* A domain is strong at share * total or ratio * mean, whichever is lower
     * (ratio 0: the share alone). The share alone misses the sun at large N,
     * where it splits across several domains none of which reaches it. */
    double threshold = share * total_power;
    if (ratio > 0.0 && n && ratio * total_power / n < threshold)
        threshold = ratio * total_power / n;
    for (uint32_t m = 0; m < maps; ++m) /* the sharp part's domains are strong whatever their power */
        is_strong[m] =
            m < n && total_power > 0.0 && (power[m] >= threshold || (m < s->sharp_count && power[m] > 0.0));
    pn_status st = PN_SUCCESS;
    if (strong > base && !s->supplied_count &&
        (st = mark_clusters(ctx, s->domains, n, power, total_power, threshold, r->params[P_STRONG_CLUSTER],
                            is_strong))) {
        free(atlas);
        free(starts);
        free(power);
        free(is_strong);
        return st;
    }
    const uint32_t cap = strong > base ? strong : base;
    const double mean = n ? total_power / n : 0.0;
    size_t texels = 0;
    for (uint32_t m = 0; m < maps; ++m) {
        uint32_t side = base;
        if (s->supplied_count)
            side = s->supplied_res[m]; /* check_supplied: one per domain */
        else if (strong > base && is_strong[m])
            side = strong; /* never smaller than the others */
        else if (m < n)
            side = graded_side(base, cap, r->params[P_GRADE], power[m], mean);
        atlas[2 * m] = (uint32_t)texels;
        atlas[2 * m + 1] = side;
        texels += (size_t)side * side;
        if (texels > DM_MAX_TEXELS) {
            free(atlas);
            free(starts);
            free(power);
            free(is_strong);
            return pn_fail(ctx, PN_ERROR_INVALID_ARGUMENT,
                           "%u depth maps of %u x %u texels (strong: %u x %u) are more than %u texels: lower directions "
                           "or resolution",
                           maps, base, base, strong, strong, DM_MAX_TEXELS);
        }
    }
    free(power);
    free(is_strong);
    size_t drawn_texels = 0;
    for (uint32_t k = 0; k < s->drawn; ++k) {
        starts[k] = (uint32_t)drawn_texels;
        const size_t side = atlas[2 * s->host_list[k] + 1];
        drawn_texels += side * side;
    }
    starts[s->drawn] = (uint32_t)drawn_texels;
    if (s->atlas && s->atlas_count == maps && !memcmp(s->host_atlas, atlas, (size_t)maps * 2 * sizeof *atlas)) {
        free(atlas);
    } else {
        pn_mem_release(&s->atlas);
        free(s->host_atlas);
        s->host_atlas = NULL;
        s->atlas_count = 0;
        if ((st = pn_alloc(ctx, (size_t)maps * 2 * sizeof *atlas, CL_MEM_READ_ONLY, atlas, &s->atlas,
                           "the depth-map atlas"))) {
            free(atlas);
            free(starts);
            return st;
        }
        s->host_atlas = atlas;
        s->atlas_count = maps;
        s->atlas_texels = texels;
        s->maps_drawn = false;
        s->packed = false;
    }
    if (s->list_start && s->list_start_count == s->drawn + 1 &&
        !memcmp(s->host_list_start, starts, (size_t)(s->drawn + 1) * sizeof *starts)) {
        free(starts);
        return PN_SUCCESS;
    }
    pn_mem_release(&s->list_start);
    free(s->host_list_start);
    s->host_list_start = NULL;
    s->list_start_count = 0;
    if ((st = pn_alloc(ctx, (size_t)(s->drawn + 1) * sizeof *starts, CL_MEM_READ_ONLY, starts, &s->list_start,
                       "the depth-map starts"))) {
        free(starts);
        return st;
    }
    s->host_list_start = starts;
    s->list_start_count = s->drawn + 1;
    s->packed = false;
    return PN_SUCCESS;
}

static pn_status plan(pn_renderer r, pn_scene scene)
{
    state *s = r->state;
    pn_context ctx = r->obj.ctx;
    pn_status st = plan_domains(r, scene);
    if (st || (st = plan_skip(r)) || (st = check_supplied(r)) || (st = plan_atlas(r)))
        return st;
    const uint32_t maps = s->domain_count ? s->domain_count : 1;
    const size_t texels = s->atlas_texels;
    if (!s->large &&
        ((st = pn_alloc(ctx, (size_t)DM_LARGE_CAPACITY * 8, CL_MEM_READ_WRITE, NULL, &s->large,
                        "the rasteriser's large triangles")) ||
         (st = pn_alloc(ctx, 4, CL_MEM_READ_WRITE, NULL, &s->large_count, "the rasteriser's count"))))
        return st;
    if (!s->frames || s->map_count != maps) {
        float *host = pn_malloc(ctx, pn_mul_size(maps, DM_FRAME_FLOATS, sizeof(float)), "the depth-map frames");
        if (!host)
            return PN_ERROR_OUT_OF_MEMORY;
        pn_mem_release(&s->frames);
        free(s->host_frames);
        s->host_frames = host;
        s->map_count = 0;
        s->maps_drawn = false;
        if ((st = pn_alloc(ctx, (size_t)maps * DM_FRAME_FLOATS * sizeof(float), CL_MEM_READ_ONLY, NULL, &s->frames,
                           "the depth-map frames")))
            return st;
        s->map_count = maps;
    }
    /* The renderer's own maps (none needed while the caller's are used). */
    if (!s->supplied_count && (!s->depth || s->depth_texels != texels)) {
        pn_mem_release(&s->depth);
        s->depth_texels = 0;
        s->maps_drawn = false;
        if ((st = pn_alloc(ctx, texels * sizeof(uint32_t), CL_MEM_READ_WRITE, NULL, &s->depth, "the depth maps")))
            return st;
        s->depth_texels = texels;
    }
    if ((int)r->params[P_HALF_MAPS] && (!s->depth16 || s->depth16_texels != texels)) {
        pn_mem_release(&s->depth16);
        s->depth16_texels = 0;
        s->packed = false;
        if ((st = pn_alloc(ctx, texels * sizeof(uint16_t), CL_MEM_READ_WRITE, NULL, &s->depth16,
                           "the 16-bit depth maps")))
            return st;
        s->depth16_texels = texels;
    }
    return PN_SUCCESS;
}

/* ------------------------------------------------------------ map frames */

/* An orthonormal frame (e1, e2) completing d (Duff et al. 2017, as pn_frame). */
static void complete_frame(const double d[3], double e1[3], double e2[3])
{
    const double sg = d[2] >= 0.0 ? 1.0 : -1.0, a = -1.0 / (sg + d[2]), b = d[0] * d[1] * a;
    e1[0] = 1.0 + sg * d[0] * d[0] * a;
    e1[1] = sg * b;
    e1[2] = -sg * d[0];
    e2[0] = b;
    e2[1] = sg + d[1] * d[1] * a;
    e2[2] = -d[1];
}

/* Range of p.a over instance `inst`'s world-transformed object box: the box's
 * centre and half extents in object space against a pulled back into it. */
static void project_box(const pn_instance *inst, const double a[3], double *lo, double *hi)
{
    const float *x = inst->object_to_world;
    double centre = 0.0, radius = 0.0;
    for (int c = 0; c < 3; ++c) {
        const double back = x[c] * a[0] + x[4 + c] * a[1] + x[8 + c] * a[2]; /* (M^T a)_c */
        const double mid = 0.5 * ((double)inst->mesh->bounds_lo[c] + inst->mesh->bounds_hi[c]);
        const double half = 0.5 * ((double)inst->mesh->bounds_hi[c] - inst->mesh->bounds_lo[c]);
        centre += back * mid;
        radius += fabs(back) * half;
    }
    centre += x[3] * a[0] + x[7] * a[1] + x[11] * a[2];
    *lo = fmin(*lo, centre - radius);
    *hi = fmax(*hi, centre + radius);
}

/* The 8 world corners of an instance's object box (corner k: bit c set =
 * the high side on object axis c). */
static void box_corners(const pn_instance *inst, double out[8][3])
{
    const float *x = inst->object_to_world;
    for (int k = 0; k < 8; ++k) {
        double o[3];
        for (int c = 0; c < 3; ++c)
            o[c] = (k >> c) & 1 ? inst->mesh->bounds_hi[c] : inst->mesh->bounds_lo[c];
        for (int r = 0; r < 3; ++r)
            out[k][r] = x[4 * r] * o[0] + x[4 * r + 1] * o[1] + x[4 * r + 2] * o[2] + x[4 * r + 3];
    }
}

static double dot3(const double a[3], const double b[3]) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }

/* A flat instance (a plane, a quad: its object box has no thickness on one
 * axis): its world normal n (unit) and plane offset n.p; false otherwise. */
static bool flat_plane(const pn_instance *inst, const double corners[8][3], double n[3], double *offset)
{
    double size = 0.0;
    int thin = -1;
    for (int c = 0; c < 3; ++c)
        size = fmax(size, (double)inst->mesh->bounds_hi[c] - inst->mesh->bounds_lo[c]);
    for (int c = 0; c < 3; ++c)
        if ((double)inst->mesh->bounds_hi[c] - inst->mesh->bounds_lo[c] <= 1e-6 * size)
            thin = c;
    if (thin < 0 || !(size > 0.0))
        return false;
    const int a = (thin + 1) % 3, b = (thin + 2) % 3; /* the box's edges along its two other axes */
    double ea[3], eb[3];
    for (int r = 0; r < 3; ++r) {
        ea[r] = corners[1 << a][r] - corners[0][r];
        eb[r] = corners[1 << b][r] - corners[0][r];
    }
    n[0] = ea[1] * eb[2] - ea[2] * eb[1];
    n[1] = ea[2] * eb[0] - ea[0] * eb[2];
    n[2] = ea[0] * eb[1] - ea[1] * eb[0];
    const double len = sqrt(dot3(n, n));
    if (!(len > 0.0))
        return false;
    for (int r = 0; r < 3; ++r)
        n[r] /= len;
    *offset = dot3(n, corners[0]);
    return true;
}

/* Range of p.e1 and p.e2 over the part of a box (its corners) where
 * p.h <= c: the extremes of a linear function over a convex polytope lie at
 * its vertices, which are the corners inside the halfspace and the crossings
 * of the box's 12 edges with its plane. Widens lo/hi; false when empty. */
static bool clipped_range(const double corners[8][3], const double h[3], double c, const double *axes[2], double lo[2],
                          double hi[2])
{
    bool any = false;
    double side[8];
    for (int k = 0; k < 8; ++k)
        side[k] = dot3(corners[k], h) - c;
    for (int k = 0; k < 8; ++k) {
        double pts[4][3];
        int count = 0;
        if (side[k] <= 0.0) {
            memcpy(pts[count++], corners[k], sizeof pts[0]);
        }
        for (int b = 0; b < 3; ++b) { /* edge k -> k | bit, once each */
            const int j = k | (1 << b);
            if (j == k || (side[k] <= 0.0) == (side[j] <= 0.0))
                continue;
            const double t = side[k] / (side[k] - side[j]);
            for (int r = 0; r < 3; ++r)
                pts[count][r] = corners[k][r] + t * (corners[j][r] - corners[k][r]);
            ++count;
        }
        for (int q = 0; q < count; ++q) {
            any = true;
            for (int a = 0; a < 2; ++a) {
                const double v = dot3(pts[q], axes[a]);
                lo[a] = fmin(lo[a], v);
                hi[a] = fmax(hi[a], v);
            }
        }
    }
    return any;
}

/* fit 1: the part of the map where a shadow can fall, as a (u, v) range.
 * A non-flat instance can shadow itself: its whole box. A flat one shadows
 * only what lies behind it as seen from the light: the other instances'
 * boxes clipped to the far side of its plane (by more than tol: what rests
 * on a floor is not under it), intersected with its own projection. Outside
 * the range nothing stands between a scene point and the light, which is
 * how the lookup treats it. False when no shadow can fall. */
static bool shadow_footprint(pn_scene scene, const double d[3], const double *axes[2], double tol, double lo[2],
                             double hi[2])
{
    bool any = false;
    lo[0] = lo[1] = INFINITY;
    hi[0] = hi[1] = -INFINITY;
    for (uint32_t i = 0; i < scene->instance_count; ++i) {
        const pn_instance *c = &scene->instances[i];
        if (!c->mesh->triangle_count)
            continue;
        double cc[8][3], n[3], offset;
        box_corners(c, cc);
        if (!flat_plane(c, cc, n, &offset)) {
            for (int a = 0; a < 2; ++a)
                project_box(c, axes[a], &lo[a], &hi[a]);
            any = true;
            continue;
        }
        const double nd = dot3(n, d);
        if (fabs(nd) < 1e-9)
            continue; /* seen edge-on: it covers no area of the map */
        const double sg = nd > 0.0 ? 1.0 : -1.0; /* n towards the light */
        const double h[3] = {sg * n[0], sg * n[1], sg * n[2]};
        double own_lo[2] = {INFINITY, INFINITY}, own_hi[2] = {-INFINITY, -INFINITY};
        for (int a = 0; a < 2; ++a)
            project_box(c, axes[a], &own_lo[a], &own_hi[a]);
        for (uint32_t j = 0; j < scene->instance_count; ++j) {
            const pn_instance *r = &scene->instances[j];
            if (j == i || !r->mesh->triangle_count)
                continue;
            double rc[8][3], rlo[2] = {INFINITY, INFINITY}, rhi[2] = {-INFINITY, -INFINITY};
            box_corners(r, rc);
            if (!clipped_range(rc, h, sg * offset - tol, axes, rlo, rhi))
                continue;
            const double ilo[2] = {fmax(rlo[0], own_lo[0]), fmax(rlo[1], own_lo[1])};
            const double ihi[2] = {fmin(rhi[0], own_hi[0]), fmin(rhi[1], own_hi[1])};
            if (ilo[0] > ihi[0] || ilo[1] > ihi[1])
                continue;
            for (int a = 0; a < 2; ++a) {
                lo[a] = fmin(lo[a], ilo[a]);
                hi[a] = fmax(hi[a], ihi[a]);
            }
            any = true;
        }
    }
    return any;
}

/* Each map's frame: along e1 and e2 the tight range of every live
 * instance's transformed box (fit 0) or of where a shadow can fall (fit 1:
 * shadow_footprint; the whole scene when nothing can be shadowed), along d
 * always the whole scene; padded by half a texel so that texel centres
 * cover the range's edges; returns false for a scene without instances (no
 * maps). */
static bool fit_frames(state *s, pn_scene scene, int fit)
{
    bool any = false;
    for (uint32_t m = 0; m < s->domain_count; ++m) {
        const uint32_t res = s->host_atlas[2 * m + 1];
        const float *df = s->domains[m].direction;
        double d[3] = {df[0], df[1], df[2]}, e1[3], e2[3];
        const double len = sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
        for (int c = 0; c < 3; ++c)
            d[c] /= len;
        complete_frame(d, e1, e2);
        double lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
        const double *axes[3] = {e1, e2, d};
        for (uint32_t i = 0; i < scene->instance_count; ++i) {
            const pn_instance *inst = &scene->instances[i]; /* the live instances */
            if (!inst->mesh->triangle_count)
                continue;
            any = true;
            for (int k = 0; k < 3; ++k)
                project_box(inst, axes[k], &lo[k], &hi[k]);
        }
        if (!any)
            return false;
        /* A flat or tiny scene still gets texels of positive size. */
        double scale = 0.0;
        for (int k = 0; k < 3; ++k)
            scale = fmax(scale, fmax(fabs(lo[k]), fabs(hi[k])));
        const double floor_size = 1e-6 * fmax(scale, 1e-30);
        double flo[2], fhi[2];
        if (fit == 1 && shadow_footprint(scene, d, axes, floor_size, flo, fhi))
            for (int k = 0; k < 2; ++k) {
                lo[k] = flo[k];
                hi[k] = fhi[k];
            }
        /* res texels of size du span the range plus one texel: the outermost
         * texel centres lie on the range's outline. */
        const double du = fmax(hi[0] - lo[0], floor_size) / (res - 1), dv = fmax(hi[1] - lo[1], floor_size) / (res - 1);
        const double u0 = 0.5 * (lo[0] + hi[0]) - 0.5 * du * res, v0 = 0.5 * (lo[1] + hi[1]) - 0.5 * dv * res;
        const double extent = fmax(hi[2] - lo[2], floor_size);
        float *f = s->host_frames + (size_t)m * DM_FRAME_FLOATS;
        const double vals[DM_FRAME_FLOATS] = {e1[0], e1[1], e1[2], u0, e2[0], e2[1], e2[2], v0,
                                              d[0],  d[1],  d[2],  hi[2], du, dv, extent, s->shadowed[m]};
        for (int k = 0; k < DM_FRAME_FLOATS; ++k)
            f[k] = (float)vals[k];
    }
    return any;
}

/* --------------------------------------------------------------- execute */

/* The rasteriser's per-instance tables: triangle range, prefix start and
 * object-to-world rows of every live instance with triangles. */
static pn_status raster_tables(pn_renderer r, pn_scene scene, uint32_t *instances, uint32_t *triangles)
{
    state *s = r->state;
    pn_context ctx = r->obj.ctx;
    const size_t need = scene->instance_count ? scene->instance_count : 1;
    pn_status st;
    if (need > s->table_capacity) {
        free(s->host_ranges);
        free(s->host_starts);
        free(s->host_objects);
        pn_mem_release(&s->ranges);
        pn_mem_release(&s->starts);
        pn_mem_release(&s->objects);
        s->table_capacity = 0;
        s->host_ranges = pn_malloc(ctx, pn_mul_size(need, 2, sizeof(uint32_t)), "the rasteriser's ranges");
        s->host_starts = pn_malloc(ctx, pn_mul_size(need, 1, sizeof(uint32_t)), "the rasteriser's starts");
        s->host_objects = pn_malloc(ctx, pn_mul_size(need, 12, sizeof(float)), "the rasteriser's transforms");
        if (!s->host_ranges || !s->host_starts || !s->host_objects)
            return PN_ERROR_OUT_OF_MEMORY;
        if ((st = pn_alloc(ctx, need * 8, CL_MEM_READ_ONLY, NULL, &s->ranges, "the rasteriser's ranges")) ||
            (st = pn_alloc(ctx, need * 4, CL_MEM_READ_ONLY, NULL, &s->starts, "the rasteriser's starts")) ||
            (st = pn_alloc(ctx, need * 48, CL_MEM_READ_ONLY, NULL, &s->objects, "the rasteriser's transforms")))
            return st;
        s->table_capacity = need;
    }
    uint32_t n = 0;
    uint64_t total = 0;
    for (uint32_t i = 0; i < scene->instance_count; ++i) {
        const pn_instance *inst = &scene->instances[i]; /* the live instances */
        if (!inst->mesh->triangle_count)
            continue;
        const pn_mesh_slot *slot = pn_scene_mesh_slot(scene, inst->mesh);
        if (!slot)
            return pn_fail(ctx, PN_ERROR_INTERNAL, "instance %u's mesh is not in the committed scene", inst->id);
        s->host_ranges[2 * n] = slot->tri_offset;
        s->host_ranges[2 * n + 1] = inst->mesh->triangle_count;
        s->host_starts[n] = (uint32_t)total;
        memcpy(s->host_objects + 12 * (size_t)n, inst->object_to_world, 12 * sizeof(float));
        total += inst->mesh->triangle_count;
        ++n;
    }
    if (total * s->domain_count > INT32_MAX)
        return pn_fail(ctx, PN_ERROR_INVALID_SIZE,
                       "%llu triangles x %u maps is more work-items than the rasteriser indexes (2^31): use "
                       "map_renderer 1 (ray caster) or fewer directions",
                       (unsigned long long)total, s->domain_count);
    if (n && ((st = pn_upload_async(ctx, s->ranges, s->host_ranges, (size_t)n * 8, "uploading raster ranges")) ||
              (st = pn_upload_async(ctx, s->starts, s->host_starts, (size_t)n * 4, "uploading raster starts")) ||
              (st = pn_upload_async(ctx, s->objects, s->host_objects, (size_t)n * 48, "uploading raster transforms"))))
        return st;
    *instances = n;
    *triangles = (uint32_t)total;
    return PN_SUCCESS;
}

static pn_status draw_maps(pn_renderer r, pn_scene scene)
{
    state *s = r->state;
    pn_context ctx = r->obj.ctx;
    /* `maps`: the maps drawn (the list), `texels`: every domain's, cleared */
    const cl_int maps = (cl_int)s->drawn;
    const size_t texels = s->atlas_texels;
    cl_kernel k;
    pn_status st;
    if ((int)r->params[P_MAP_RENDERER] == 1) {
        if ((st = pn_context_kernel(ctx, "depthmap", "depthmap_raycast", &k)) ||
            (st = pn_scene_set_kernel_args(scene, k, "depthmap_raycast", 0)))
            return st;
        const size_t sizes[] = {sizeof(cl_mem), sizeof maps, sizeof(cl_mem), sizeof(cl_mem), sizeof(cl_mem),
                                sizeof(cl_mem)};
        const void *vals[] = {&s->frames, &maps, &s->atlas, &s->depth, &s->list, &s->list_start};
        for (cl_uint i = 0; i < 6; ++i) {
            cl_int err = clSetKernelArg(k, 6 + i, sizes[i], vals[i]);
            if (err != CL_SUCCESS)
                return pn_fail_cl(ctx, err, "setting depthmap_raycast arguments");
        }
        return pn_enqueue_1d(ctx, k, "depthmap_raycast", s->host_list_start[s->drawn], 64);
    }
    uint32_t instances = 0, triangles = 0;
    if ((st = raster_tables(r, scene, &instances, &triangles)))
        return st;
    const cl_int count = (cl_int)texels;
    if ((st = pn_context_kernel(ctx, "depthmap", "depthmap_clear", &k)))
        return st;
    {
        const size_t sizes[] = {sizeof(cl_mem), sizeof count, sizeof(cl_mem)};
        const void *vals[] = {&s->depth, &count, &s->large_count};
        if ((st = pn_set_args(ctx, k, "depthmap_clear", 3, sizes, vals)) ||
            (st = pn_enqueue_1d(ctx, k, "depthmap_clear", texels, 64)))
            return st;
    }
    if (!triangles)
        return PN_SUCCESS;
    if ((st = pn_context_kernel(ctx, "depthmap", "depthmap_raster", &k)))
        return st;
    const cl_int inst = (cl_int)instances, tri_total = (cl_int)triangles, capacity = (cl_int)DM_LARGE_CAPACITY;
    const size_t sizes[] = {sizeof(cl_mem), sizeof(cl_mem), sizeof(cl_mem), sizeof(cl_mem), sizeof inst,
                            sizeof tri_total, sizeof(cl_mem), sizeof maps, sizeof(cl_mem), sizeof(cl_mem),
                            sizeof(cl_mem), sizeof(cl_mem), sizeof capacity, sizeof(cl_mem)};
    const void *vals[] = {&scene->tris, &s->ranges, &s->starts, &s->objects, &inst, &tri_total, &s->frames,
                          &maps, &s->atlas, &s->depth, &s->large_count, &s->large, &capacity, &s->list};
    if ((st = pn_set_args(ctx, k, "depthmap_raster", 14, sizes, vals)) ||
        (st = pn_enqueue_1d(ctx, k, "depthmap_raster", (size_t)triangles * (size_t)maps, 64)) ||
        (st = pn_context_kernel(ctx, "depthmap", "depthmap_raster_large", &k)))
        return st;
    const size_t lsizes[] = {sizeof(cl_mem), sizeof(cl_mem), sizeof(cl_mem), sizeof(cl_mem), sizeof inst,
                             sizeof(cl_mem), sizeof(cl_mem), sizeof(cl_mem), sizeof(cl_mem), sizeof(cl_mem),
                             sizeof capacity};
    const void *lvals[] = {&scene->tris, &s->ranges, &s->starts, &s->objects, &inst, &s->frames,
                           &s->atlas, &s->depth, &s->large_count, &s->large, &capacity};
    if ((st = pn_set_args(ctx, k, "depthmap_raster_large", 11, lsizes, lvals)))
        return st;
    return pn_enqueue_1d(ctx, k, "depthmap_raster_large", (size_t)DM_LARGE_GROUPS * 64, 64);
}

/* Frames and maps of the scene as it is (enqueued); *use_maps false when
 * no map is needed (visibility off, no geometry). */
static pn_status prepare_maps(pn_renderer r, pn_scene scene, bool *use_maps)
{
    state *s = r->state;
    *use_maps = false;
    if (!(int)r->params[P_VISIBILITY] || !s->domain_count)
        return PN_SUCCESS;
    if ((int)r->params[P_REUSE_MAPS] && s->maps_drawn) {
        *use_maps = s->drawn > 0;
        return PN_SUCCESS;
    }
    if (s->supplied_count) { /* the caller's maps: their frames, the renderer's flags */
        for (uint32_t m = 0; m < s->domain_count; ++m) {
            float *f = s->host_frames + (size_t)m * DM_FRAME_FLOATS;
            memcpy(f, s->supplied_frames + (size_t)m * DM_FRAME_FLOATS, (DM_FRAME_FLOATS - 1) * sizeof(float));
            f[DM_FRAME_FLOATS - 1] = s->shadowed[m];
        }
        pn_status st = pn_upload_async(r->obj.ctx, s->frames, s->host_frames,
                                       (size_t)s->domain_count * DM_FRAME_FLOATS * sizeof(float),
                                       "uploading the caller's map frames");
        s->maps_drawn = !st;
        s->packed = false;
        *use_maps = !st && s->drawn;
        return st;
    }
    if (!fit_frames(s, scene, (int)r->params[P_FIT])) {
        s->maps_drawn = false;
        return PN_SUCCESS; /* no triangles: nothing casts a shadow */
    }
    pn_status st = pn_upload_async(r->obj.ctx, s->frames, s->host_frames,
                                   (size_t)s->domain_count * DM_FRAME_FLOATS * sizeof(float), "uploading map frames");
    if (!st && s->drawn)
        st = draw_maps(r, scene);
    s->maps_drawn = !st;
    s->packed = false;
    *use_maps = !st && s->drawn;
    return st;
}

/* The lobe families the scene's instances use with k_s > 0 (PN_DM_LOBE_BLINN_PHONG_BIT,
   PN_DM_LOBE_GGX_BIT): only those tables are built at lobe_tables 2 (about a second of CPU each per
   context); pixels of a family not built (a caller's G-buffer) take the cap quadrature. */
static int scene_table_lobes(pn_scene scene)
{
    int mask = 0;
    for (uint32_t i = 0; i < scene->instance_count; ++i) {
        const pn_material *m = &scene->instances[i].material;
        if (m->specular > 0.0f && m->lobe == PN_LOBE_BLINN_PHONG)
            mask |= PN_DM_LOBE_BLINN_PHONG_BIT;
        if (m->specular > 0.0f && m->lobe == PN_LOBE_GGX)
            mask |= PN_DM_LOBE_GGX_BIT;
    }
    return mask;
}

static pn_status execute(pn_renderer r, pn_scene scene, pn_gbuffer gb, pn_image image)
{
    pn_context ctx = r->obj.ctx;
    state *s = r->state;
    bool maps = false;
    pn_status st = prepare_maps(r, scene, &maps);
    cl_kernel k;
    const cl_int half = maps && (int)r->params[P_HALF_MAPS] && s->depth16;
    if (!st && half && !s->packed) { /* the 16-bit copies of the maps just drawn or supplied */
        const cl_int drawn = (cl_int)s->drawn;
        const size_t psizes[] = {sizeof(cl_mem), sizeof(cl_mem), sizeof(cl_mem), sizeof drawn, sizeof(cl_mem),
                                 sizeof(cl_mem), sizeof(cl_mem)};
        const void *pvals[] = {s->supplied_count ? &s->supplied_depth : &s->depth, &s->frames, &s->list, &drawn,
                               &s->atlas, &s->list_start, &s->depth16};
        if (!(st = pn_context_kernel(ctx, "depthmap", "depthmap_pack16", &k)) &&
            !(st = pn_set_args(ctx, k, "depthmap_pack16", 7, psizes, pvals)) &&
            !(st = pn_enqueue_1d(ctx, k, "depthmap_pack16", s->host_list_start[s->drawn], 64)))
            s->packed = true;
    }
    cl_mem table = NULL; /* the kernel reads it only with specular 3; any buffer stands in otherwise */
    const int lobe_mode = (int)r->params[P_LOBE_TABLES];
    const cl_int table_lobes = lobe_mode == 1 ? PN_DM_LOBE_BLINN_PHONG_BIT | PN_DM_LOBE_GGX_BIT
                               : lobe_mode == 2 ? scene_table_lobes(scene)
                                                : 0;
    if (!st && (int)r->params[P_SPECULAR] == 3)
        st = pn_depthmap_cap_table(ctx, table_lobes, &table);
    /* the kernel's lobe_tables: the families built, and bit 2 the four-point rule */
    const cl_int lobe_tables = table_lobes | ((int)r->params[P_LOBE_CENTROID] ? 4 : 0);
    if (st || (st = pn_context_kernel(ctx, "depthmap", "shade_depthmap", &k)))
        return st;
    if (!table)
        table = s->device_domains;
    const cl_int count = (cl_int)(gb->width * gb->height), domains = (cl_int)s->domain_count;
    const cl_int use_maps = maps ? 1 : 0, pcf = (cl_int)r->params[P_PCF];
    cl_mem *depth = s->supplied_count ? &s->supplied_depth : &s->depth;
    const cl_float bias = (cl_float)r->params[P_BIAS], slope = (cl_float)r->params[P_SLOPE_BIAS];
    const cl_int specular = (cl_int)r->params[P_SPECULAR], samples = (cl_int)r->params[P_CAP_SAMPLES];
    const cl_float table_min = (cl_float)r->params[P_TABLE_MIN_EXPONENT];
    const int soft_mode = (int)r->params[P_SOFT_SHADOWS];
    const cl_int plane = (cl_int)r->params[P_RECEIVER_PLANE];
    const cl_int soft_count = soft_mode == 2 ? (cl_int)s->domain_count : soft_mode == 1 ? (cl_int)s->sharp_count : 0;
    const cl_float4 camera = pn_scene_camera_position(scene);
    const size_t sizes[] = {sizeof(cl_mem), sizeof(cl_mem), sizeof(cl_mem), sizeof(cl_mem), sizeof(cl_mem),
                            sizeof count, sizeof camera, sizeof(cl_mem), sizeof domains, sizeof(cl_mem),
                            sizeof(cl_mem), sizeof(cl_mem), sizeof use_maps, sizeof bias, sizeof slope, sizeof pcf,
                            sizeof specular, sizeof samples, sizeof(cl_mem), sizeof(cl_mem), sizeof half,
                            sizeof(cl_mem), sizeof table_min, sizeof lobe_tables, sizeof soft_count, sizeof plane};
    const void *vals[] = {&gb->planes[PN_GBUFFER_POSITION], &gb->planes[PN_GBUFFER_NORMAL],
                          &gb->planes[PN_GBUFFER_ALBEDO], &gb->planes[PN_GBUFFER_MATERIAL],
                          &gb->planes[PN_GBUFFER_INSTANCE], &count, &camera, &s->device_domains, &domains,
                          &s->frames, depth, &s->atlas, &use_maps, &bias, &slope, &pcf, &specular, &samples,
                          &image->buffer, half ? &s->depth16 : depth, &half, &table, &table_min, &lobe_tables, &soft_count, &plane};
    if ((st = pn_set_args(ctx, k, "shade_depthmap", 26, sizes, vals)))
        return st;
    return pn_enqueue_1d(ctx, k, "shade_depthmap", (size_t)count, 64);
}

static pn_status read_output(pn_renderer r, pn_scene scene, int what, uint32_t instance, uint32_t index, void *host,
                             size_t bytes)
{
    (void)instance;
    state *s = r->state;
    pn_context ctx = r->obj.ctx;
    size_t need = 0;
    if (what == OUT_DEPTH && index >= s->domain_count)
        return pn_fail(ctx, PN_ERROR_INVALID_ARGUMENT, "depth map %u: the method has %u domains", index,
                       s->domain_count);
    const size_t side = what == OUT_DEPTH ? s->host_atlas[2 * index + 1] : 0;
    if (what == OUT_DOMAINS)
        need = (size_t)s->domain_count * sizeof(pn_env_domain);
    else if (what == OUT_FRAMES)
        need = (size_t)s->domain_count * DM_FRAME_FLOATS * sizeof(float);
    else if (what == OUT_RESOLUTIONS)
        need = (size_t)s->domain_count * sizeof(float);
    else
        need = side * side * sizeof(float);
    if (bytes != need)
        return pn_fail(ctx, PN_ERROR_INVALID_SIZE, "depthmap output %s needs %zu bytes, the buffer has %zu",
                       outputs[what].name, need, bytes);
    if (what == OUT_DOMAINS) {
        memcpy(host, s->domains, need);
        return PN_SUCCESS;
    }
    if (what == OUT_RESOLUTIONS) {
        float *out = host;
        for (uint32_t m = 0; m < s->domain_count; ++m)
            out[m] = (float)s->host_atlas[2 * m + 1];
        return PN_SUCCESS;
    }
    if (what == OUT_DEPTH && !s->shadowed[index]) { /* lit unshadowed (skip_power): an empty map */
        float *out = host;
        for (size_t k = 0; k < side * side; ++k)
            out[k] = INFINITY;
        return PN_SUCCESS;
    }
    /* Frames and maps of the scene as it is now, drawn even with visibility 0. */
    const double visibility = r->params[P_VISIBILITY], reuse = r->params[P_REUSE_MAPS];
    r->params[P_VISIBILITY] = 1;
    r->params[P_REUSE_MAPS] = 0;
    bool maps = false;
    pn_status st = prepare_maps(r, scene, &maps);
    r->params[P_VISIBILITY] = visibility;
    r->params[P_REUSE_MAPS] = reuse;
    if (st)
        return st;
    if (!maps && !(s->supplied_count || (what == OUT_FRAMES && s->maps_drawn)))
        return pn_fail(ctx, PN_ERROR_INVALID_ARGUMENT, "the scene has no triangles: there are no depth maps");
    cl_int err = what == OUT_FRAMES
                     ? clEnqueueReadBuffer(ctx->queue, s->frames, CL_TRUE, 0, need, host, 0, NULL, NULL)
                     : clEnqueueReadBuffer(ctx->queue, s->supplied_count ? s->supplied_depth : s->depth, CL_TRUE,
                                           (size_t)s->host_atlas[2 * index] * sizeof(float), need, host, 0, NULL,
                                           NULL);
    return err == CL_SUCCESS ? PN_SUCCESS : pn_fail_cl(ctx, err, "reading a depthmap output");
}

static void destroy(pn_renderer r)
{
    state *s = r->state;
    pn_mem_release(&s->device_domains);
    pn_mem_release(&s->frames);
    pn_mem_release(&s->depth);
    pn_mem_release(&s->ranges);
    pn_mem_release(&s->starts);
    pn_mem_release(&s->objects);
    pn_mem_release(&s->large);
    pn_mem_release(&s->large_count);
    pn_mem_release(&s->list);
    pn_mem_release(&s->supplied_depth);
    pn_mem_release(&s->depth16);
    pn_mem_release(&s->atlas);
    pn_mem_release(&s->list_start);
    free(s->host_atlas);
    free(s->host_list_start);
    free(s->supplied_res);
    free(s->shadowed);
    free(s->host_list);
    free(s->supplied_frames);
    free(s->domains);
    free(s->caller);
    free(s->host_frames);
    free(s->host_ranges);
    free(s->host_starts);
    free(s->host_objects);
}

const pn_method_desc pn_method_depthmap = {
    .name = "depthmap",
    .summary = "depth-map environment sampling: N directional domains of the env map, one depth map each per frame, "
               "diffuse and specular from the domains' radiance",
    .stage = "depthmap",
    .doc_page = "docs/depthmap.md",
    .params = params,
    .param_count = (int)(sizeof params / sizeof params[0]),
    .outputs = outputs,
    .output_count = (int)(sizeof outputs / sizeof outputs[0]),
    .inputs = PN_INPUT_ENVMAP | PN_INPUT_GEOMETRY | PN_INPUT_CAMERA,
    .state_size = sizeof(state),
    .destroy = destroy,
    .plan = plan,
    .execute = execute,
    .read_output = read_output,
    .set_domains = set_domains,
};
