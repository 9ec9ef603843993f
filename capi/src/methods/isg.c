/* The `isg` method (docs/isg.md, kernels/isg.cl): env lighting as K
 * spherical-Gaussian lobes, occluders as the sphere sets attached to
 * instances, diffuse and specular soft shadows by the Integral Spherical
 * Gaussian. Plan: the lobe fit (when the env map or K changed), the
 * prefiltered env Gamma_L (per context and env map, specular_mode 1), the ISG
 * table (once per context). Execute: every attached sphere in world space
 * (from the instances' transforms, so moving objects cost nothing more),
 * uploaded without waiting, and the shading kernel. */
#include "core/sg.h"
#include "methods/method.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

enum {
    P_BACKGROUND,
    P_LOBES,
    P_PATCH_GRID,
    P_SELF_OCCLUSION,
    P_SPECULAR_SHADOWS,
    P_ENV_SHARPNESS,
    P_SPHERE_TREE,
    P_SPECULAR_MODE,
    P_LOD,
    P_SHARED_GRID,
    P_SHARED_SHARPNESS,
    P_SHARED_LIGHT,
    P_SELF_PUSH,
    P_INSIDE_OTHER
};

static const pn_param_desc params[] = {
    PN_PARAM_BACKGROUND,
    {"lobes", PN_PARAM_INT, PN_PARAM_PLAN, 32, 1, 128, "lobes",
     "K: spherical-Gaussian lobes fitted to the env map (plan: refitted when K or the env map changes)."},
    {"patch_grid", PN_PARAM_INT, PN_PARAM_FRAME, 16, 2, 24, "patches per side",
     "M: each lobe's visibility window is cut into M x M ISG patches (16: 256 patches)."},
    {"self_occlusion", PN_PARAM_INT, PN_PARAM_FRAME, 1, 0, 2, "",
     "Own spheres of the receiver's instance: 0 ignored, 1 used except those containing the receiver or "
     "within 0.02 of their radius of it (those are seen from the receiver pushed out by self_push skins, or "
     "skipped), 2 all used."},
    {"specular_shadows", PN_PARAM_INT, PN_PARAM_FRAME, 1, 0, 1, "",
     "1: the specular term is shadowed (patch by patch or by its product lobes' visibility), 0: unshadowed."},
    {"env_sharpness", PN_PARAM_FLOAT, PN_PARAM_FRAME, 10, 0, 1e9, "",
     "BRDF lobes at least this sharp take the specular_mode path (the env on their own visible patches); "
     "broader ones use the SG lobe products."},
    {"sphere_tree", PN_PARAM_INT, PN_PARAM_FRAME, 1, 0, 1, "",
     "1: spheres culled per lobe through a tree of bounding spheres over them (rebuilt every frame in Morton "
     "order), 0: every sphere tested for every lobe (the same image, slower; kept for comparison)."},
    {"specular_mode", PN_PARAM_INT, PN_PARAM_FRAME, 1, 0, 1, "",
     "Light of the sharp BRDF lobes (env_sharpness): 1 the prefiltered env Gamma_L at the lobe's axis times "
     "the visible share of its patches (seed eq. 10; built at plan when the env map changes), 0 the env cube "
     "at each visible patch."},
    {"lod", PN_PARAM_FLOAT, PN_PARAM_FRAME, 0, 0, 16, "patch steps",
     "LOD cut of the sphere tree: a node wholly in front of the receiver whose bounding sphere subtends less "
     "than lod patch steps of a lobe's window occludes with that sphere instead of its spheres (0: off, the "
     "exact walk; needs sphere_tree 1 and self_occlusion 1 or 2; per-lobe windows only, not the shared grid; "
     "docs/isg.md section 8)."},
    {"shared_grid", PN_PARAM_INT, PN_PARAM_FRAME, 16, 0, 31, "patches per side",
     "M_s: the diffuse light of the lobes no sharper than shared_sharpness is shadowed by one marking per "
     "pixel of an M_s x M_s grid over the receiver's hemisphere (their summed radiance read per occluded "
     "patch) instead of one marking per lobe (0: off, every lobe its own window; docs/isg.md section 9)."},
    {"shared_sharpness", PN_PARAM_FLOAT, PN_PARAM_FRAME, 200, 0, 1e9, "",
     "With shared_grid > 0: light lobes at most this sharp go through the shared hemisphere grid, sharper "
     "ones (a sun) keep their own patch window."},
    {"shared_light", PN_PARAM_INT, PN_PARAM_FRAME, 1, 0, 1, "",
     "With shared_grid > 0, the unshadowed irradiance of the shared lobes: 1 the env map's irradiance map minus "
     "the closed forms of the sharper lobes (the K-lobe fit's error leaves it), 0 the shared lobes' closed "
     "forms (docs/isg.md section 9)."},
    {"self_push", PN_PARAM_FLOAT, PN_PARAM_FRAME, 0.5, 0, 8, "skins",
     "With self_occlusion 1, an own sphere that contains or nearly touches the receiver is seen from the "
     "receiver pushed out along its normal by self_push times the set's skin ((g + 1/2) build cells: how far "
     "its balls may reach past the surface) instead of skipped: it keeps the shadow it casts past the surface "
     "without the dark disc (0: skipped; caller's spheres have no skin; docs/isg.md section 8)."},
    {"inside_other", PN_PARAM_INT, PN_PARAM_FRAME, 1, 0, 2, "",
     "A receiver inside another instance's sphere (one poking through the floor under it): 0 that sphere "
     "occludes everything (V = 0), 1 it is skipped, 2 it is seen from the receiver pushed out by self_push "
     "times its set's skin (skipped when that is 0 or still inside it)."},
};

static const pn_param_desc bake_params[] = {
    {"spheres", PN_PARAM_INT, PN_PARAM_BAKE, 64, 1, 4096, "spheres",
     "N: spheres per occluder mesh (pn_sphere_set_build; docs/isg.md section 7)."},
};

typedef struct state {
    cl_mem lobes;             /* K pn_sg_lobe */
    int lobe_count;           /* K that `lobes` holds */
    uint64_t env_version;     /* env map that `lobes` was fitted to */
    float *spheres;           /* host: world centre + radius per sphere */
    uint32_t *owners;         /* host: instance id per sphere */
    float *skins;             /* host: per sphere, self_push x its set's skin in world units */
    float *nodes;             /* host: the sphere tree's bounding spheres, level 1 first */
    uint32_t *scratch;        /* host: Morton keys and order, sorted spheres (sphere_tree) */
    size_t capacity, device_capacity, node_capacity, device_node_capacity;
    cl_mem device_spheres, device_owners, device_nodes, device_skins;
    float *tris;              /* host: thin-shell triangles, 3 world-space float4 vertices each */
    uint32_t *tri_owners;     /* host: instance id per triangle */
    uint32_t *tri_scratch;    /* host: Morton keys and order, sorted triangles and owners (shell_groups) */
    size_t tri_capacity, device_tri_capacity;
    cl_mem device_tris, device_tri_owners;
    cl_mem lobe_cube;         /* the shared lobes' two vertex-grid cubes (isg_lobe_cubes) */
    uint64_t cube_env_version; /* env map, K and sharpness that `lobe_cube` was built for */
    int cube_lobe_count;
    float cube_sharpness;
} state;

static bool is_sphere_set(const pn_attachment *a)
{
    return a->asset->magic == PN_MAGIC_SPHERES;
}

/* The prefiltered Gamma_L (kernels/isg.cl isg_prefilter; docs/isg.md section
 * 8). Levels lambda_l = GAMMA_LAMBDA0 2^l up to the first at least F^2 (F the
 * env cube's face: a lobe half a texel wide, beyond which the cube itself is
 * the limit); level l a vertex-grid cube of clamp(6 sqrt(lambda) + 1, 8, 2F + 1)
 * vertices a side (a third of the lobe's width apart, at most half a texel),
 * built from the env cube halved while its face stays at least 4 sqrt(lambda)
 * (texels under half the lobe's width) and even. Python twin:
 * penumbra.methods.isg.gamma_levels. */
#define GAMMA_LAMBDA0 1.0f
enum { GAMMA_MAX_LEVELS = 32, GAMMA_MAX_MIPS = 12 };

static int gamma_level_count(int face)
{
    int count = 1;
    while (count < GAMMA_MAX_LEVELS && ldexp(GAMMA_LAMBDA0, count - 1) < (double)face * face)
        ++count;
    return count;
}

static int gamma_level_size(int face, double lambda)
{
    const int n = (int)ceil(6.0 * sqrt(lambda)) + 1;
    return n < 8 ? 8 : n > 2 * face + 1 ? 2 * face + 1 : n;
}

/* A built Gamma_L: every level's vertex-grid cube in `gamma`, (offset, size)
 * per level in `levels`; made from the env map of content hash `hash` on a
 * cube of face `face`. */
typedef struct gamma_entry {
    uint64_t hash, used;
    int face, count;
    cl_mem gamma, levels;
} gamma_entry;

/* The Gamma_L tables of a context, shared by its isg renderers: the last
 * GAMMA_CACHED env maps' (a renderer made per frame, as penumbra.render does,
 * or several on one env build it once). */
enum { GAMMA_CACHED = 4 };
typedef struct gamma_cache {
    gamma_entry entry[GAMMA_CACHED];
    uint64_t clock;
} gamma_cache;
static const int gamma_cache_key = 0;

static void free_gamma_cache(void *data)
{
    gamma_cache *c = data;
    for (int i = 0; i < GAMMA_CACHED; ++i) {
        pn_mem_release(&c->entry[i].gamma);
        pn_mem_release(&c->entry[i].levels);
    }
    free(c);
}

static pn_status build_gamma(pn_context ctx, pn_envmap env, gamma_entry *e)
{
    const int face = env->committed_face_size, count = gamma_level_count(face);
    int levels[2 * GAMMA_MAX_LEVELS];
    size_t total = 0;
    for (int l = 0; l < count; ++l) {
        const int n = gamma_level_size(face, ldexp(GAMMA_LAMBDA0, l));
        levels[2 * l] = (int)total, levels[2 * l + 1] = n;
        total += 6 * (size_t)n * (size_t)n;
    }
    cl_kernel halve, prefilter;
    pn_status st;
    if ((st = pn_context_kernel(ctx, "isg", "isg_cube_halve", &halve)) ||
        (st = pn_context_kernel(ctx, "isg", "isg_prefilter", &prefilter)))
        return st;
    pn_mem_release(&e->gamma);
    pn_mem_release(&e->levels);
    e->count = 0;
    if ((st = pn_alloc(ctx, total * 16, CL_MEM_READ_WRITE, NULL, &e->gamma, "the prefiltered env (Gamma_L)")) ||
        (st = pn_alloc(ctx, sizeof levels, CL_MEM_READ_ONLY | CL_MEM_COPY_HOST_PTR, levels, &e->levels,
                       "the prefiltered env's levels")))
        return st;
    /* The halved sources: mip m has face face >> m (the env cube itself at 0). */
    cl_mem cube[GAMMA_MAX_MIPS] = {env->cube}, dirs[GAMMA_MAX_MIPS] = {env->dirs};
    int mips = 1;
    for (; mips < GAMMA_MAX_MIPS && (face >> (mips - 1)) % 2 == 0 && (face >> mips) >= 2; ++mips) {
        const cl_int n = face >> (mips - 1);
        const size_t texels = 6 * (size_t)(n / 2) * (size_t)(n / 2);
        if ((st = pn_alloc(ctx, texels * 16, CL_MEM_READ_WRITE, NULL, &cube[mips], "a halved env cube")) ||
            (st = pn_alloc(ctx, texels * 16, CL_MEM_READ_WRITE, NULL, &dirs[mips], "a halved env cube")))
            break;
        size_t sizes[] = {sizeof(cl_mem), sizeof(cl_mem), sizeof n, sizeof(cl_mem), sizeof(cl_mem)};
        const void *vals[] = {&cube[mips - 1], &dirs[mips - 1], &n, &cube[mips], &dirs[mips]};
        if ((st = pn_set_args(ctx, halve, "isg_cube_halve", 5, sizes, vals)) ||
            (st = pn_enqueue_1d(ctx, halve, "isg_cube_halve", texels, 64)))
            break;
    }
    for (int l = 0; !st && l < count; ++l) {
        const cl_float lambda = (cl_float)ldexp(GAMMA_LAMBDA0, l);
        int m = mips - 1; /* the smallest source whose face is at least 4 sqrt(lambda) */
        while (m > 0 && (double)(face >> m) < 4.0 * sqrt((double)lambda))
            --m;
        const cl_int n_src = face >> m, n_out = levels[2 * l + 1], offset = levels[2 * l];
        size_t sizes[] = {sizeof(cl_mem), sizeof(cl_mem), sizeof n_src, sizeof lambda, sizeof n_out, sizeof offset,
                          sizeof(cl_mem)};
        const void *vals[] = {&cube[m], &dirs[m], &n_src, &lambda, &n_out, &offset, &e->gamma};
        if (!(st = pn_set_args(ctx, prefilter, "isg_prefilter", 7, sizes, vals)))
            st = pn_enqueue_1d(ctx, prefilter, "isg_prefilter", 6 * (size_t)n_out * (size_t)n_out, 64);
    }
    for (int m = 1; m < GAMMA_MAX_MIPS; ++m) { /* released once the queued kernels are done with them */
        pn_mem_release(&cube[m]);
        pn_mem_release(&dirs[m]);
    }
    if (!st)
        e->count = count, e->hash = env->content_hash, e->face = face;
    return st;
}

/* The context's Gamma_L of env (built now when it has none, in place of the
 * least recently used). */
static pn_status gamma_of(pn_context ctx, pn_envmap env, const gamma_entry **out)
{
    gamma_cache *c = pn_context_cache(ctx, &gamma_cache_key);
    pn_status st;
    if (!c) {
        if (!(c = pn_malloc(ctx, sizeof *c, "the prefiltered env cache")))
            return PN_ERROR_OUT_OF_MEMORY;
        memset(c, 0, sizeof *c);
        if ((st = pn_context_set_cache(ctx, &gamma_cache_key, c, free_gamma_cache))) {
            free(c);
            return st;
        }
    }
    gamma_entry *oldest = &c->entry[0];
    for (int i = 0; i < GAMMA_CACHED; ++i) {
        gamma_entry *e = &c->entry[i];
        if (e->count && e->hash == env->content_hash && e->face == env->committed_face_size) {
            e->used = ++c->clock;
            *out = e;
            return PN_SUCCESS;
        }
        if (e->used < oldest->used)
            oldest = e;
    }
    oldest->used = ++c->clock;
    if ((st = build_gamma(ctx, env, oldest)))
        return st;
    *out = oldest;
    return PN_SUCCESS;
}

/* Whether the frame uses Gamma_L: specular_mode 1 and some instance has a
 * specular lobe. A diffuse scene skips the build and its frames get mode 0,
 * whose sharp-lobe path a G-buffer of the scene never enters (k_s = 0) and a
 * G-buffer from elsewhere gets as a valid fallback: the kernel never reads
 * an unbuilt table. */
static bool uses_gamma(pn_renderer r, pn_scene scene)
{
    if (r->params[P_SPECULAR_MODE] != 1)
        return false;
    for (uint32_t i = 0; i < scene->instance_count; ++i)
        if (scene->instances[i].material.specular > 0.0f)
            return true;
    return false;
}

static pn_status plan(pn_renderer r, pn_scene scene)
{
    state *s = r->state;
    pn_context ctx = r->obj.ctx;
    pn_envmap env = scene->env;
    const int k = (int)r->params[P_LOBES];
    pn_status st = PN_SUCCESS;
    const gamma_entry *gamma;
    if (uses_gamma(r, scene) && (st = gamma_of(ctx, env, &gamma)))
        return st;
    if (s->lobes && s->lobe_count == k && s->env_version == env->version)
        return PN_SUCCESS;
    pn_sg_lobe *lobes = pn_malloc(ctx, pn_mul_size((size_t)k, 1, sizeof *lobes), "the env map's SG lobes");
    if (!lobes)
        return PN_ERROR_OUT_OF_MEMORY;
    st = pn_envmap_do_fit_sgs(env, (uint32_t)k, NULL, lobes, (size_t)k);
    if (!st) {
        pn_mem_release(&s->lobes);
        st = pn_alloc(ctx, (size_t)k * sizeof *lobes, CL_MEM_READ_ONLY, lobes, &s->lobes, "the env map's SG lobes");
    }
    free(lobes);
    if (st)
        return st;
    s->lobe_count = k, s->env_version = env->version;
    s->cube_lobe_count = 0; /* the shared lobes' cubes: rebuilt for the new lobes at execute */
    return st;
}

/* The largest column norm of the linear part: a sphere of radius r maps into
 * one of radius r times this (exact for rotations and uniform scales). */
static float radius_scale(const float *m)
{
    float best = 0.0f;
    for (int c = 0; c < 3; ++c)
        best = fmaxf(best, sqrtf(m[c] * m[c] + m[4 + c] * m[4 + c] + m[8 + c] * m[8 + c]));
    return best;
}

/* Every attached sphere in world space, instance order. */
static pn_status gather_spheres(pn_renderer r, pn_scene scene, uint32_t *count_out)
{
    state *s = r->state;
    pn_context ctx = r->obj.ctx;
    size_t total = 0;
    for (uint32_t ai = 0; ai < scene->attachment_count; ++ai)
        if (is_sphere_set(&scene->attachments[ai]))
            total += ((pn_sphere_set)scene->attachments[ai].asset)->count;
    if (total > (1u << 24))
        return pn_fail(ctx, PN_ERROR_INVALID_SIZE, "the scene's sphere sets hold %zu spheres, more than 2^24", total);
    if (total > s->capacity) {
        free(s->spheres), free(s->owners), free(s->skins);
        s->capacity = 0;
        s->spheres = pn_malloc(ctx, pn_mul_size(total, 4, sizeof(float)), "the scene's spheres");
        s->owners = pn_malloc(ctx, pn_mul_size(total, 1, sizeof(uint32_t)), "the scene's sphere owners");
        s->skins = pn_malloc(ctx, pn_mul_size(total, 1, sizeof(float)), "the scene's sphere skins");
        if (!s->spheres || !s->owners || !s->skins)
            return PN_ERROR_OUT_OF_MEMORY;
        s->capacity = total;
    }
    uint32_t n = 0;
    for (uint32_t ai = 0; ai < scene->attachment_count; ++ai) {
        const pn_attachment *a = &scene->attachments[ai];
        if (!is_sphere_set(a))
            continue;
        const pn_sphere_set set = (pn_sphere_set)a->asset;
        const pn_instance *inst = pn_scene_instance(scene, a->instance);
        if (set->mesh_hash && inst->mesh->content_hash != set->mesh_hash)
            return pn_fail(ctx, PN_ERROR_INVALID_ARGUMENT,
                           "instance %u's mesh is now %016llx but its sphere set was built for %016llx: build the "
                           "set again and attach it",
                           a->instance, (unsigned long long)inst->mesh->content_hash,
                           (unsigned long long)set->mesh_hash);
        const float *m = inst->object_to_world, sc = radius_scale(m);
        const float skin = (float)r->params[P_SELF_PUSH] * set->skin * sc;
        for (uint32_t i = 0; i < set->count; ++i, ++n) {
            const float *c = set->spheres + 4 * i;
            float *o = s->spheres + 4 * (size_t)n;
            for (int row = 0; row < 3; ++row)
                o[row] = m[4 * row] * c[0] + m[4 * row + 1] * c[1] + m[4 * row + 2] * c[2] + m[4 * row + 3];
            o[3] = c[3] * sc;
            s->owners[n] = a->instance;
            s->skins[n] = skin;
        }
    }
    *count_out = n;
    return PN_SUCCESS;
}

/* Spreads the low 10 bits of v to every third bit. */
static uint32_t spread3(uint32_t v)
{
    v &= 0x3ffu;
    v = (v | (v << 16)) & 0x030000ffu;
    v = (v | (v << 8)) & 0x0300f00fu;
    v = (v | (v << 4)) & 0x030c30c3u;
    v = (v | (v << 2)) & 0x09249249u;
    return v;
}

/* x's 10-bit cell in [lo, hi] (0 when the extent is empty), its bits spread for a
 * 30-bit Morton key (shifted by 2 - axis). */
static uint32_t morton_axis(float x, float lo, float hi)
{
    const float ext = hi - lo, q = ext > 0.0f ? (x - lo) / ext * 1024.0f : 0.0f;
    return spread3((uint32_t)fminf(fmaxf(q, 0.0f), 1023.0f));
}

/* The n 30-bit Morton keys in key, with their indices in order, sorted by a
 * stable LSD radix sort of three 10-bit passes (key2 and order2 n entries of
 * scratch each); returns the sorted indices (in order or order2). */
static uint32_t *morton_sort(uint32_t n, uint32_t *key, uint32_t *key2, uint32_t *order, uint32_t *order2)
{
    for (int pass = 0; pass < 3; ++pass) {
        uint32_t histogram[1025] = {0};
        const int shift = 10 * pass;
        for (uint32_t i = 0; i < n; ++i)
            ++histogram[((key[i] >> shift) & 1023u) + 1];
        for (int b = 0; b < 1024; ++b)
            histogram[b + 1] += histogram[b];
        for (uint32_t i = 0; i < n; ++i) {
            const uint32_t at = histogram[(key[i] >> shift) & 1023u]++;
            key2[at] = key[i], order2[at] = order[i];
        }
        uint32_t *t = key;
        key = key2, key2 = t, t = order, order = order2, order2 = t;
    }
    return order;
}

/* The groups of the thin shells' triangles (kernels/isg.cl
 * pn_isg_mark_triangles; docs/isg.md section 9, "Thin shells"): the n
 * triangles (and their owners) reordered along a 30-bit Morton curve of their
 * centroids (a stable three-pass radix sort, as sphere_tree's), then for each
 * PN_SHELL_GROUP consecutive ones a bounding sphere of their vertices (the
 * centre of their box; the radius padded by 1e-4 of itself plus 1e-5 of all
 * the triangles' extent, so the kernel skips a group only where each of its
 * triangles would mark nothing beyond rounding), written into the spare w of
 * the group's first four vertices: x, y, z in the first triangle's, the
 * radius in the second's first vertex (a last group of one triangle keeps 0:
 * tested alone). The order of the marking does not change the marks. */
enum { PN_SHELL_GROUP = 8 };

static void shell_groups(state *s, uint32_t n)
{
    if (n == 0)
        return;
    uint32_t *key = s->tri_scratch, *key2 = key + n, *order = key2 + n, *order2 = order + n, *owners = order2 + n;
    float *sorted = (float *)(owners + n);
    float lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
    for (size_t i = 0; i < 12 * (size_t)n; ++i)
        if (i % 4 != 3)
            lo[i % 4] = fminf(lo[i % 4], s->tris[i]), hi[i % 4] = fmaxf(hi[i % 4], s->tris[i]);
    for (uint32_t t = 0; t < n; ++t) {
        uint32_t k = 0;
        for (int a = 0; a < 3; ++a) {
            const float *v = s->tris + 12 * (size_t)t + a;
            k |= morton_axis((v[0] + v[4] + v[8]) * (1.0f / 3.0f), lo[a], hi[a]) << (2 - a);
        }
        key[t] = k, order[t] = t;
    }
    order = morton_sort(n, key, key2, order, order2);
    for (uint32_t i = 0; i < n; ++i) {
        memcpy(sorted + 12 * (size_t)i, s->tris + 12 * (size_t)order[i], 12 * sizeof(float));
        owners[i] = s->tri_owners[order[i]];
    }
    memcpy(s->tris, sorted, (size_t)n * 12 * sizeof(float));
    memcpy(s->tri_owners, owners, (size_t)n * sizeof(uint32_t));
    const float diag = sqrtf((hi[0] - lo[0]) * (hi[0] - lo[0]) + (hi[1] - lo[1]) * (hi[1] - lo[1]) +
                             (hi[2] - lo[2]) * (hi[2] - lo[2]));
    for (uint32_t g = 0; g + 1 < n; g += PN_SHELL_GROUP) {
        const uint32_t end = n - g < PN_SHELL_GROUP ? n : g + PN_SHELL_GROUP;
        double b0[3] = {INFINITY, INFINITY, INFINITY}, b1[3] = {-INFINITY, -INFINITY, -INFINITY}, c[3];
        for (size_t i = 12 * (size_t)g; i < 12 * (size_t)end; ++i)
            if (i % 4 != 3)
                b0[i % 4] = fmin(b0[i % 4], s->tris[i]), b1[i % 4] = fmax(b1[i % 4], s->tris[i]);
        for (int a = 0; a < 3; ++a)
            c[a] = 0.5 * (b0[a] + b1[a]);
        double r = 0.0;
        for (size_t i = 12 * (size_t)g; i < 12 * (size_t)end; i += 4) {
            const double dx = s->tris[i] - c[0], dy = s->tris[i + 1] - c[1], dz = s->tris[i + 2] - c[2];
            r = fmax(r, sqrt(dx * dx + dy * dy + dz * dz));
        }
        float *first = s->tris + 12 * (size_t)g;
        first[3] = (float)c[0], first[7] = (float)c[1], first[11] = (float)c[2];
        first[15] = (float)(r * (1.0 + 1e-4)) + 1e-5f * diag + 1e-30f;
    }
}

/* Thin shells (pn_sphere_set_create_shell; kernels/isg.cl
 * pn_isg_mark_triangle): every triangle of each instance with a shell
 * attached, in world space, the kernel tests all of them per lobe (culled by
 * the receiver plane and the window's cone), hence the bound per instance. */
enum { SHELL_MAX_TRIANGLES = 4096 };

static pn_status gather_triangles(pn_renderer r, pn_scene scene, uint32_t *count_out)
{
    state *s = r->state;
    pn_context ctx = r->obj.ctx;
    size_t total = 0;
    for (uint32_t ai = 0; ai < scene->attachment_count; ++ai) {
        const pn_attachment *a = &scene->attachments[ai];
        if (!is_sphere_set(a) || !((pn_sphere_set)a->asset)->shell)
            continue;
        const pn_mesh mesh = pn_scene_instance(scene, a->instance)->mesh;
        if (mesh->triangle_count > SHELL_MAX_TRIANGLES)
            return pn_fail(ctx, PN_ERROR_INVALID_SIZE,
                           "instance %u is a thin shell of %u triangles, more than the %d the isg method projects "
                           "per shell: simplify its mesh or give it a sphere set",
                           a->instance, mesh->triangle_count, SHELL_MAX_TRIANGLES);
        total += mesh->triangle_count;
    }
    if (total > s->tri_capacity) {
        free(s->tris), free(s->tri_owners), free(s->tri_scratch);
        s->tri_capacity = 0;
        s->tris = pn_malloc(ctx, pn_mul_size(total, 12, sizeof(float)), "the thin shells' triangles");
        s->tri_owners = pn_malloc(ctx, pn_mul_size(total, 1, sizeof(uint32_t)), "the thin shells' owners");
        /* keys and order (twice each, for the radix passes), sorted triangles (12 floats) and owners */
        s->tri_scratch = pn_malloc(ctx, pn_mul_size(total, 17, sizeof(uint32_t)), "the thin shells' scratch");
        if (!s->tris || !s->tri_owners || !s->tri_scratch)
            return PN_ERROR_OUT_OF_MEMORY;
        s->tri_capacity = total;
    }
    uint32_t n = 0;
    for (uint32_t ai = 0; ai < scene->attachment_count; ++ai) {
        const pn_attachment *a = &scene->attachments[ai];
        if (!is_sphere_set(a) || !((pn_sphere_set)a->asset)->shell)
            continue;
        const pn_instance *inst = pn_scene_instance(scene, a->instance);
        const pn_mesh mesh = inst->mesh;
        const float *m = inst->object_to_world;
        for (uint32_t t = 0; t < mesh->triangle_count; ++t, ++n) {
            for (int k = 0; k < 3; ++k) {
                const float *v = mesh->positions + 3 * (size_t)mesh->indices[3 * (size_t)t + k];
                float *o = s->tris + 12 * (size_t)n + 4 * k;
                for (int row = 0; row < 3; ++row)
                    o[row] = m[4 * row] * v[0] + m[4 * row + 1] * v[1] + m[4 * row + 2] * v[2] + m[4 * row + 3];
                o[3] = 0.0f;
            }
            s->tri_owners[n] = a->instance;
        }
    }
    shell_groups(s, n);
    *count_out = n;
    return PN_SUCCESS;
}

enum { TREE_FANOUT = 8 };

/* Nodes of the sphere tree over n > 0 spheres: levels of ceil(previous / 8)
 * up to a top level of at most 8 (kernels/isg.cl pn_isg_tree_init). */
static size_t tree_node_count(size_t n)
{
    size_t total = 0;
    do {
        n = (n + TREE_FANOUT - 1) / TREE_FANOUT;
        total += n;
    } while (n > TREE_FANOUT);
    return total;
}

/* Bounding sphere of `count` spheres (x, y, z, r) at `in` (stride 4): mean
 * centre, padded radius (see sphere_tree). */
static void bound(const float *in, size_t count, float pad, float *out)
{
    double c[3] = {0.0, 0.0, 0.0};
    for (size_t i = 0; i < count; ++i)
        for (int a = 0; a < 3; ++a)
            c[a] += in[4 * i + a];
    for (int a = 0; a < 3; ++a)
        c[a] /= (double)count;
    double r = 0.0;
    for (size_t i = 0; i < count; ++i) {
        const double dx = in[4 * i] - c[0], dy = in[4 * i + 1] - c[1], dz = in[4 * i + 2] - c[2];
        r = fmax(r, sqrt(dx * dx + dy * dy + dz * dz) + in[4 * i + 3]);
    }
    for (int a = 0; a < 3; ++a)
        out[a] = (float)c[a];
    out[3] = (float)(r * (1.0 + 1e-4)) + pad;
}

/* The sphere tree of kernels/isg.cl, O(N) every frame: the spheres (and
 * their owners) reordered along a 30-bit Morton curve of their centres by a
 * three-pass radix sort, then bounding spheres of 8 consecutive spheres
 * (level 1), of 8 consecutive level-1 nodes, ... up to at most 8 nodes. Radii
 * are padded by 1e-4 of themselves plus 1e-5 of the spheres' extent, so the
 * kernel culls a node only where each of its spheres is culled beyond
 * rounding (the image is the flat loop's). Python twin:
 * penumbra.methods.isg.sphere_tree. */
static pn_status sphere_tree(pn_renderer r, uint32_t n, size_t *node_count)
{
    state *s = r->state;
    pn_context ctx = r->obj.ctx;
    *node_count = 0;
    if (n == 0)
        return PN_SUCCESS;
    const size_t nodes = tree_node_count(n);
    if (n > s->node_capacity) { /* the node count grows with n */
        free(s->nodes), free(s->scratch);
        s->node_capacity = 0;
        s->nodes = pn_malloc(ctx, pn_mul_size(nodes, 4, sizeof(float)), "the sphere tree");
        /* keys, order (twice each, for the radix passes), sorted spheres, sorted owners, sorted skins */
        s->scratch = pn_malloc(ctx, pn_mul_size(n, 10, sizeof(uint32_t)), "the sphere tree's scratch");
        if (!s->nodes || !s->scratch)
            return PN_ERROR_OUT_OF_MEMORY;
        s->node_capacity = n;
    }
    uint32_t *key = s->scratch, *key2 = key + n, *order = key2 + n, *order2 = order + n, *owners = order2 + n;
    float *sorted = (float *)(owners + n), *skins = sorted + 4 * (size_t)n;
    float lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY}, rmax = 0.0f;
    for (uint32_t i = 0; i < n; ++i) {
        for (int a = 0; a < 3; ++a)
            lo[a] = fminf(lo[a], s->spheres[4 * i + a]), hi[a] = fmaxf(hi[a], s->spheres[4 * i + a]);
        rmax = fmaxf(rmax, s->spheres[4 * i + 3]);
    }
    for (uint32_t i = 0; i < n; ++i) {
        uint32_t k = 0;
        for (int a = 0; a < 3; ++a) {
            k |= morton_axis(s->spheres[4 * i + a], lo[a], hi[a]) << (2 - a);
        }
        key[i] = k, order[i] = i;
    }
    order = morton_sort(n, key, key2, order, order2);
    for (uint32_t i = 0; i < n; ++i) {
        memcpy(sorted + 4 * (size_t)i, s->spheres + 4 * (size_t)order[i], 4 * sizeof(float));
        owners[i] = s->owners[order[i]];
        skins[i] = s->skins[order[i]];
    }
    memcpy(s->spheres, sorted, (size_t)n * 4 * sizeof(float));
    memcpy(s->owners, owners, (size_t)n * sizeof(uint32_t));
    memcpy(s->skins, skins, (size_t)n * sizeof(float));
    const float diag = sqrtf((hi[0] - lo[0]) * (hi[0] - lo[0]) + (hi[1] - lo[1]) * (hi[1] - lo[1]) +
                             (hi[2] - lo[2]) * (hi[2] - lo[2]));
    const float pad = 1e-5f * (diag + rmax);
    const float *level = s->spheres;
    float *out = s->nodes;
    size_t count = n;
    do {
        const size_t parents = (count + TREE_FANOUT - 1) / TREE_FANOUT;
        for (size_t i = 0; i < parents; ++i) {
            const size_t first = i * TREE_FANOUT, m = count - first < TREE_FANOUT ? count - first : TREE_FANOUT;
            bound(level + 4 * first, m, pad, out + 4 * i);
        }
        level = out, out += 4 * parents, count = parents;
    } while (count > TREE_FANOUT);
    *node_count = nodes;
    return PN_SUCCESS;
}

/* The shared hemisphere grid's two cubes (kernels/isg.cl isg_lobe_cubes: the
 * summed radiance L_b and unshadowed irradiance E_b of the lobes no sharper
 * than `sharpness`), LOBE_CUBE_N vertices a side: at most 0.031 rad between
 * samples, under a third of the width 1/sqrt(lambda) of a lobe of lambda 100.
 * Rebuilt on the device when the lobes or the sharpness change. */
enum { LOBE_CUBE_N = 65 };

static pn_status lobe_cubes(pn_renderer r, float sharpness)
{
    state *s = r->state;
    pn_context ctx = r->obj.ctx;
    if (s->lobe_cube && s->cube_env_version == s->env_version && s->cube_lobe_count == s->lobe_count &&
        s->cube_sharpness == sharpness)
        return PN_SUCCESS;
    const size_t count = 6 * (size_t)LOBE_CUBE_N * LOBE_CUBE_N;
    cl_kernel k;
    pn_status st;
    if (!s->lobe_cube &&
        (st = pn_alloc(ctx, 2 * count * 16, CL_MEM_READ_WRITE, NULL, &s->lobe_cube, "the shared lobes' cubes")))
        return st;
    if ((st = pn_context_kernel(ctx, "isg", "isg_lobe_cubes", &k)))
        return st;
    const cl_int lobes = s->lobe_count, n = LOBE_CUBE_N;
    const cl_float sh = sharpness;
    size_t sizes[] = {sizeof(cl_mem), sizeof lobes, sizeof sh, sizeof n, sizeof(cl_mem)};
    const void *vals[] = {&s->lobes, &lobes, &sh, &n, &s->lobe_cube};
    if ((st = pn_set_args(ctx, k, "isg_lobe_cubes", 5, sizes, vals)) ||
        (st = pn_enqueue_1d(ctx, k, "isg_lobe_cubes", count, 64)))
        return st;
    s->cube_env_version = s->env_version, s->cube_lobe_count = s->lobe_count, s->cube_sharpness = sharpness;
    return PN_SUCCESS;
}

static pn_status execute(pn_renderer r, pn_scene scene, pn_gbuffer gb, pn_image image)
{
    pn_context ctx = r->obj.ctx;
    state *s = r->state;
    pn_envmap env = scene->env;
    cl_kernel k;
    cl_mem table;
    uint32_t sphere_count = 0;
    pn_status st;
    if ((st = pn_context_kernel(ctx, "isg", "shade_isg", &k)) || (st = pn_isg_table_buffer(ctx, &table)) ||
        (st = gather_spheres(r, scene, &sphere_count)))
        return st;
    const cl_int use_tree = (cl_int)r->params[P_SPHERE_TREE];
    const cl_float lod = (cl_float)r->params[P_LOD];
    size_t node_count = 0;
    if (use_tree && (st = sphere_tree(r, sphere_count, &node_count)))
        return st;
    const size_t node_need = node_count ? node_count : 1;
    if (node_need > s->device_node_capacity) {
        pn_mem_release(&s->device_nodes);
        s->device_node_capacity = 0;
        if ((st = pn_alloc(ctx, node_need * 16, CL_MEM_READ_ONLY, NULL, &s->device_nodes, "the sphere tree")))
            return st;
        s->device_node_capacity = node_need;
    }
    if (node_count && (st = pn_upload_async(ctx, s->device_nodes, s->nodes, node_count * 16, "uploading the sphere tree")))
        return st;
    uint32_t tri_count = 0;
    if ((st = gather_triangles(r, scene, &tri_count)))
        return st;
    const size_t tri_need = tri_count ? tri_count : 1;
    if (tri_need > s->device_tri_capacity) {
        pn_mem_release(&s->device_tris);
        pn_mem_release(&s->device_tri_owners);
        s->device_tri_capacity = 0;
        if ((st = pn_alloc(ctx, tri_need * 48, CL_MEM_READ_ONLY, NULL, &s->device_tris,
                           "the thin shells' triangles")) ||
            (st = pn_alloc(ctx, tri_need * 4, CL_MEM_READ_ONLY, NULL, &s->device_tri_owners,
                           "the thin shells' owners")))
            return st;
        s->device_tri_capacity = tri_need;
    }
    if (tri_count &&
        ((st = pn_upload_async(ctx, s->device_tris, s->tris, (size_t)tri_count * 48, "uploading thin shells")) ||
         (st = pn_upload_async(ctx, s->device_tri_owners, s->tri_owners, (size_t)tri_count * 4,
                               "uploading thin shells' owners"))))
        return st;
    const cl_int triangles = (cl_int)tri_count;
    const size_t need = sphere_count ? sphere_count : 1;
    if (need > s->device_capacity) {
        pn_mem_release(&s->device_spheres);
        pn_mem_release(&s->device_owners);
        pn_mem_release(&s->device_skins);
        s->device_capacity = 0;
        if ((st = pn_alloc(ctx, need * 16, CL_MEM_READ_ONLY, NULL, &s->device_spheres, "the scene's spheres")) ||
            (st = pn_alloc(ctx, need * 4, CL_MEM_READ_ONLY, NULL, &s->device_owners, "the scene's sphere owners")) ||
            (st = pn_alloc(ctx, need * 4, CL_MEM_READ_ONLY, NULL, &s->device_skins, "the scene's sphere skins")))
            return st;
        s->device_capacity = need;
    }
    if (sphere_count &&
        ((st = pn_upload_async(ctx, s->device_spheres, s->spheres, (size_t)sphere_count * 16, "uploading spheres")) ||
         (st = pn_upload_async(ctx, s->device_owners, s->owners, (size_t)sphere_count * 4, "uploading sphere owners")) ||
         (st = pn_upload_async(ctx, s->device_skins, s->skins, (size_t)sphere_count * 4, "uploading sphere skins"))))
        return st;
    const cl_int count = (cl_int)(gb->width * gb->height), n = env->face_size;
    const cl_int lobes = s->lobe_count, spheres = (cl_int)sphere_count, grid = (cl_int)r->params[P_PATCH_GRID];
    const cl_int self = (cl_int)r->params[P_SELF_OCCLUSION], spec = (cl_int)r->params[P_SPECULAR_SHADOWS];
    const cl_float env_sharpness = (cl_float)r->params[P_ENV_SHARPNESS];
    const cl_float4 camera = pn_scene_camera_position(scene);
    /* specular_mode 0 never reads Gamma_L: any buffer stands in for it. */
    const cl_int mode = uses_gamma(r, scene) ? 1 : 0;
    const gamma_entry *g = NULL;
    if (mode && (st = gamma_of(ctx, env, &g))) /* built at plan: found */
        return st;
    const cl_int gamma_count = g ? g->count : 1;
    const cl_float lambda0 = GAMMA_LAMBDA0;
    const cl_mem gamma = g ? g->gamma : s->lobes, gamma_levels = g ? g->levels : s->lobes;
    const cl_int shared_grid = (cl_int)r->params[P_SHARED_GRID], cube_n = LOBE_CUBE_N;
    const cl_float shared_sharpness = (cl_float)r->params[P_SHARED_SHARPNESS];
    if (shared_grid > 0 && (st = lobe_cubes(r, shared_sharpness)))
        return st;
    const cl_mem cube_buf = shared_grid > 0 ? s->lobe_cube : s->lobes; /* unread when off */
    const bool env_light = shared_grid > 0 && r->params[P_SHARED_LIGHT] != 0;
    const cl_int irradiance_n = env_light ? env->committed_irradiance_size : 0;
    const cl_mem irradiance = env_light ? env->irradiance : s->lobes; /* unread when 0 */
    const cl_int inside_other = (cl_int)r->params[P_INSIDE_OTHER];
    size_t sizes[] = {sizeof(cl_mem), sizeof(cl_mem), sizeof(cl_mem), sizeof(cl_mem), sizeof(cl_mem), sizeof count,
                      sizeof(cl_mem), sizeof n, sizeof(cl_mem), sizeof lobes, sizeof(cl_mem),
                      sizeof(cl_mem), sizeof spheres, sizeof(cl_mem), sizeof use_tree, sizeof lod, sizeof(cl_mem), sizeof(cl_mem), sizeof triangles, sizeof grid, sizeof self, sizeof spec, sizeof env_sharpness, sizeof camera,
                      sizeof(cl_mem), sizeof mode, sizeof(cl_mem), sizeof(cl_mem), sizeof gamma_count, sizeof lambda0,
                      sizeof shared_grid, sizeof shared_sharpness, sizeof(cl_mem), sizeof cube_n, sizeof(cl_mem),
                      sizeof irradiance_n, sizeof(cl_mem), sizeof inside_other, sizeof(cl_mem)};
    const void *vals[] = {&gb->planes[PN_GBUFFER_POSITION], &gb->planes[PN_GBUFFER_NORMAL],
                          &gb->planes[PN_GBUFFER_ALBEDO], &gb->planes[PN_GBUFFER_MATERIAL],
                          &gb->planes[PN_GBUFFER_INSTANCE], &count, &env->cube, &n, &s->lobes, &lobes,
                          &s->device_spheres, &s->device_owners, &spheres, &s->device_nodes, &use_tree, &lod, &s->device_tris, &s->device_tri_owners,
                          &triangles, &grid, &self,
                          &spec, &env_sharpness, &camera, &table, &mode, &gamma, &gamma_levels, &gamma_count,
                          &lambda0, &shared_grid, &shared_sharpness, &cube_buf, &cube_n, &irradiance, &irradiance_n,
                          &s->device_skins, &inside_other, &image->buffer};
    if ((st = pn_set_args(ctx, k, "shade_isg", 39, sizes, vals)))
        return st;
    return pn_enqueue_1d(ctx, k, "shade_isg", (size_t)count, 64);
}

static void destroy(pn_renderer r)
{
    state *s = r->state;
    pn_mem_release(&s->lobes);
    pn_mem_release(&s->lobe_cube);
    pn_mem_release(&s->device_spheres);
    pn_mem_release(&s->device_owners);
    pn_mem_release(&s->device_skins);
    pn_mem_release(&s->device_nodes);
    pn_mem_release(&s->device_tris);
    pn_mem_release(&s->device_tri_owners);
    free(s->tris);
    free(s->tri_scratch);
    free(s->tri_owners);
    free(s->spheres);
    free(s->owners);
    free(s->skins);
    free(s->nodes);
    free(s->scratch);
}

const pn_method_desc pn_method_isg = {
    .name = "isg",
    .summary = "Integral Spherical Gaussian: env light as SG lobes, occluders as attached sphere sets, per-pixel "
               "diffuse and specular soft shadows",
    .stage = "isg",
    .doc_page = "docs/isg.md",
    .params = params,
    .param_count = (int)(sizeof params / sizeof params[0]),
    .bake_params = bake_params,
    .bake_param_count = (int)(sizeof bake_params / sizeof bake_params[0]),
    .inputs = PN_INPUT_ENVMAP | PN_INPUT_CAMERA | PN_INPUT_SPHERES,
    .state_size = sizeof(state),
    .destroy = destroy,
    .plan = plan,
    .execute = execute,
};
