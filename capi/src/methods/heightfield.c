/* The `heightfield` method (docs/heightfield.md, kernels/heightfield.cl):
 * environment and spherical-light lighting with soft self-shadows on the
 * height fields attached to instances; other pixels get `unshadowed`.
 * Plan: SH tables (float64, cached per context), the env map's SH product
 * and sun texels (a read-back), each field's pyramid when its heights
 * change. Execute: the per-vertex passes and the G-buffer shading, enqueued.
 * Outputs: per-vertex radiance, horizons, SH visibility and normals. */
#include "methods/method.h"
#include "methods/sh_tables.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#define PI 3.14159265358979323846
#define HF_MAX_LEVELS 128   /* kernels/heightfield.cl */
#define MAX_FIELDS 16
#define MAX_SUN 256          /* sun texels lit as directional lights */
#define SUN_FLOATS 12        /* per sun texel: 3 float4 (kernels/heightfield.cl, hf_sun) */
#define SUN_TRAILER 20       /* then 5 float4 for all of them */
#define KEEP_MAX_BYTES ((size_t)512 << 20) /* partial_update: the most kept state per field */

enum { P_BACKGROUND, P_LEVEL_STEP, P_LEVEL_OFFSET, P_AZIMUTHS, P_BANDS, P_EXACT_HORIZON, P_LIGHT_THRESHOLD,
       P_EXACT_UNOCCLUDED, P_SUN_THRESHOLD, P_LIGHT_VISIBILITY, P_RECONSTRUCTION, P_PARTIAL_UPDATE };

static const pn_param_desc params[] = {
    PN_PARAM_BACKGROUND,
    {"level_step", PN_PARAM_INT, PN_PARAM_PLAN, 4, 1, 8, "levels per octave", "Pyramid levels per octave."},
    {"level_offset", PN_PARAM_FLOAT, PN_PARAM_FRAME, 4, 0, 8, "octaves",
     "Pyramid level read, in octaves finer than the sample spacing."},
    {"azimuths", PN_PARAM_INT, PN_PARAM_PLAN, 32, 4, 256, "directions", "Horizon directions per vertex."},
    {"bands", PN_PARAM_INT, PN_PARAM_PLAN, 6, 3, 6, "", "Spherical-harmonic bands."},
    {"exact_horizon", PN_PARAM_INT, PN_PARAM_FRAME, 0, 0, 1, "",
     "1: horizons by marching the full-resolution field (for measuring)."},
    {"light_threshold", PN_PARAM_FLOAT, PN_PARAM_FRAME, 1e-4, 0, 1, "",
     "Skip a light where radiance x solid angle is below this share of the env's reference irradiance."},
    {"exact_unoccluded", PN_PARAM_INT, PN_PARAM_FRAME, 1, 0, 1, "",
     "1: the unoccluded part from the exact upper-hemisphere irradiance, SH only for what the terrain blocks; 0: "
     "the seed's all-SH product."},
    {"sun_threshold", PN_PARAM_FLOAT, PN_PARAM_PLAN, 50, 0, 1e9, "x mean radiance",
     "Env texels brighter than this are lit as directional lights with a horizon test; 0: none."},
    {"light_visibility", PN_PARAM_INT, PN_PARAM_FRAME, 1, 0, 1, "",
     "Spherical lights: 1 horizon test x exact cap irradiance, 0 the seed's SH wedges."},
    {"reconstruction", PN_PARAM_INT, PN_PARAM_PLAN, 0, 0, 1, "",
     "Pyramid levels: 0 the seed's approximating B-spline, 1 interpolating."},
    {"partial_update", PN_PARAM_INT, PN_PARAM_PLAN, 1, 0, 1, "",
     "1: for fields that have had local edits (pn_heightfield_set_heights_region), keep the env horizons and "
     "search checkpoints (azimuths x (1 + (levels - 1) / level_step) floats per vertex, where that is at most "
     "512 MiB per field) so that the next edit recomputes only what it can change; 0: every frame recomputes all."},
};

enum { OUT_ENV, OUT_LIGHT, OUT_TOTAL, OUT_ENV_HORIZONS, OUT_LIGHT_HORIZONS, OUT_ENV_VISIBILITY, OUT_LIGHT_VISIBILITY,
       OUT_NORMALS, OUT_ENV_SEARCHED };

static const pn_output_desc outputs[] = {
    {"env", "float4 per vertex: outgoing radiance from the environment (rgb, 1)."},
    {"light", "float4 per vertex: outgoing radiance from light `index` (rgb, 1)."},
    {"total", "float4 per vertex: environment plus every light (rgb, 1)."},
    {"env_horizons", "azimuths floats per vertex: horizon elevations in radians."},
    {"light_horizons", "azimuths floats per vertex: horizon elevations toward light `index`, in radians."},
    {"env_visibility", "bands^2 floats per vertex: SH visibility."},
    {"light_visibility", "bands^2 floats per vertex: SH visibility for light `index`."},
    {"normals", "float4 per vertex: the method's world normal."},
    {"env_searched", "azimuths floats per vertex: 1 where the last env pass searched the horizon again, 0 where it "
                     "kept it (partial_update = 1: after a local edit only what can read a changed height is "
                     "searched; a vertex with every azimuth kept keeps its radiance unless its normal changed)."},
};

/* The method's settings, from the renderer's parameters. */
typedef struct pn_hf_settings {
    int level_step, azimuths, bands, exact, exact_unoccluded, light_visibility, reconstruction, partial_update;
    float level_offset, light_threshold, sun_threshold;
} pn_hf_settings;

/* Per attached field: the pyramid and per-vertex outputs. */
typedef struct pn_hf_state {
    uint64_t version;         /* field version the pyramid holds (0: none) */
    int level_step, reconstruction;
    cl_int4 grid;             /* W, D, levels, level offset in samples */
    cl_float8 geom;           /* x0, y0, z0, sx, sz, level step, s0, 0 */
    size_t pyramid_floats;
    bool has_albedo;
    uint32_t light_capacity;
    cl_mem pyr, levels, normals, albedo, out_env, out_lights, out_total;
    /* Partial updates (partial_update = 1): the field the pyramid was built
     * from, the env horizons of the last env pass and what that pass was
     * for, and per level the box of values changed since (HF_MAX_LEVELS + 1:
     * the normals' box last). */
    pn_heightfield owner;
    cl_mem horizons, changed, checkpoints;
    size_t checkpoint_floats;
    cl_int last_update;       /* the last env pass's mode (hf_env); `changed` holds its boxes */
    size_t horizon_floats;
    bool pass_valid;
    pn_hf_settings pass_settings;
    uint64_t pass_env;
    cl_int4 pending[HF_MAX_LEVELS + 1];
    cl_int4 levels_host[HF_MAX_LEVELS]; /* what `levels` holds */
} pn_hf_state;

typedef struct pn_hf_cache {
    pn_heightfield hfs[MAX_FIELDS];  /* the attached fields (held by the scene) and their instances */
    uint32_t hf_instances[MAX_FIELDS];
    uint32_t hf_count;
    pn_hf_state fields[MAX_FIELDS];
    int tables_nphi, tables_nb;
    cl_mem env_table, light_table;
    int gamma_nb, gamma_count;
    cl_mem gamma_index, gamma_value;
    uint64_t m_env_version;
    int m_nb, m_nphi;
    float m_sun;              /* sun_threshold the env data was split with */
    cl_mem sun;               /* MAX_SUN at most: 3 float4 per sun texel */
    int sun_count;
    cl_mem m;                 /* 3 x nc x nc */
    float u[3 * PN_SH_MAX_BANDS * PN_SH_MAX_BANDS]; /* Hᵀ M per channel (exact_unoccluded) */
    cl_mem u_buf;
    cl_mem up_irradiance;     /* irradiance map of the env's upper half */
    int up_size;
    float env_ref;            /* π x the env's mean radiance */
    uint32_t lights_culled;   /* light passes skipped in the last frame */
    /* What the per-vertex outputs were last computed for: reads of the same
     * state reuse them (pn_renderer_execute always recomputes: a frame). */
    bool outputs_valid;
    pn_hf_settings outputs_settings;
    uint64_t outputs_env, outputs_fields[MAX_FIELDS];
    pn_sphere_light *outputs_lights;
    uint32_t outputs_light_count, outputs_field_count;
} pn_hf_cache;

/* ------------------------------------------------------------- renderer */

static void destroy(pn_renderer r)
{
    pn_hf_cache *c = r->state;
    for (int i = 0; i < MAX_FIELDS; ++i) {
        pn_hf_state *s = &c->fields[i];
        cl_mem *mems[] = {&s->pyr, &s->levels, &s->normals, &s->albedo, &s->out_env, &s->out_lights, &s->out_total,
                          &s->horizons, &s->changed, &s->checkpoints};
        for (size_t k = 0; k < sizeof mems / sizeof mems[0]; ++k)
            pn_mem_release(mems[k]);
    }
    pn_mem_release(&c->env_table);
    pn_mem_release(&c->light_table);
    pn_mem_release(&c->gamma_index);
    pn_mem_release(&c->gamma_value);
    pn_mem_release(&c->m);
    pn_mem_release(&c->up_irradiance);
    pn_mem_release(&c->u_buf);
    pn_mem_release(&c->sun);
    free(c->outputs_lights);
}

/* SH vectors on the device: nc coefficients padded with zeros to whole
 * chunks of 16 floats (the kernels' float16 chunks), so every chunk load is
 * one aligned vload16 of a whole 64-byte line. */
static int sh_stride(int nc)
{
    return 16 * ((nc + 15) / 16);
}

/* `rows` vectors of nc floats at src, uploaded padded to sh_stride(nc). */
static pn_status alloc_padded(pn_context ctx, const float *src, size_t rows, int nc, cl_mem *out, const char *what)
{
    const int ns = sh_stride(nc);
    float *p = calloc(rows * (size_t)ns, sizeof(float));
    if (!p)
        return pn_fail(ctx, PN_ERROR_OUT_OF_MEMORY, "out of memory for a padded SH table");
    for (size_t r = 0; r < rows; ++r)
        memcpy(p + r * ns, src + r * nc, (size_t)nc * sizeof(float));
    pn_status st = pn_alloc(ctx, rows * (size_t)ns * sizeof(float), CL_MEM_READ_ONLY, p, out, what);
    free(p);
    return st;
}

/* Wedge tables for (n_phi, bands) and the triple product for `bands`. */
static pn_status prepare_tables(pn_context ctx, pn_hf_cache *c, int n_phi, int nb)
{
    pn_status st = PN_SUCCESS;
    const int nc = nb * nb;
    if (c->tables_nphi != n_phi || c->tables_nb != nb) {
        const float *env = NULL, *light = NULL;
        const size_t rows = (size_t)PN_SH_WEDGE_ANGLES * PN_SH_WEDGE_ANGLES;
        pn_mem_release(&c->env_table);
        pn_mem_release(&c->light_table);
        c->tables_nphi = 0;
        if (!(st = pn_sh_wedge_table(ctx, n_phi, nb, false, &env)) &&
            !(st = pn_sh_wedge_table(ctx, n_phi, nb, true, &light)) &&
            !(st = alloc_padded(ctx, env, rows, nc, &c->env_table, "the environment wedge table")) &&
            !(st = alloc_padded(ctx, light, rows, nc, &c->light_table, "the light wedge table"))) {
            c->tables_nphi = n_phi;
            c->tables_nb = nb;
        }
        if (st)
            return st;
    }
    if (c->gamma_nb != nb) {
        pn_mem_release(&c->gamma_index);
        pn_mem_release(&c->gamma_value);
        c->gamma_nb = 0;
        c->m_env_version = UINT64_MAX;
        const double *gamma;
        if ((st = pn_sh_triple_product(ctx, nb, &gamma)))
            return st;
        size_t count = 0;
        for (size_t q = 0; q < (size_t)nc * nc * nc; ++q)
            count += gamma[q] != 0.0;
        cl_int *index = malloc(count * 4 * sizeof(cl_int));
        float *value = malloc(count * sizeof(float));
        if (!index || !value) {
            free(index);
            free(value);
            return pn_fail(ctx, PN_ERROR_OUT_OF_MEMORY, "out of memory for the sparse SH triple product");
        }
        size_t g = 0;
        for (int i = 0; i < nc; ++i)
            for (int j = 0; j < nc; ++j)
                for (int k = 0; k < nc; ++k) {
                    const double v = gamma[((size_t)i * nc + j) * nc + k];
                    if (v != 0.0) {
                        cl_int e[4] = {i, j, k, 0};
                        memcpy(index + 4 * g, e, sizeof e);
                        value[g++] = (float)v;
                    }
                }
        if (!(st = pn_alloc(ctx, count * 4 * sizeof(cl_int), CL_MEM_READ_ONLY, index, &c->gamma_index,
                            "the SH triple-product indices")) &&
            !(st = pn_alloc(ctx, count * sizeof(float), CL_MEM_READ_ONLY, value, &c->gamma_value,
                            "the SH triple-product values"))) {
            c->gamma_count = (int)count;
            c->gamma_nb = nb;
        }
        free(index);
        free(value);
    }
    return st;
}

static int by_power_desc(const void *a, const void *b)
{
    const float pa = ((const float *)a)[7], pb = ((const float *)b)[7];
    return pa < pb ? 1 : pa > pb ? -1 : 0;
}

/* Texels brighter than sun_threshold x the env's mean radiance (the sun) are
 * taken out of the env's texels (rad is changed: they become black there) and
 * kept as directional lights, at most MAX_SUN of the most powerful:
 * records (direction, angular radius | radiance x solid angle, power |
 * azimuth in the SH frame, elevation), the angles once here instead of per
 * vertex, then 5 float4 for all of them (hf_sun): their bounds (least and
 * greatest azimuth, least elevation - r and greatest elevation + r), their
 * mean direction with the largest distance of a texel's direction from it,
 * and the 3 x 3 sum of radiance x direction (per channel a row). Their
 * visibility is then a test against the horizon instead of a low-order SH
 * product, which smears a sun over the whole sky. */
static pn_status split_sun(pn_context ctx, pn_hf_cache *c, float *rad, const float *dirs, size_t texels,
                           float sun_threshold)
{
    double power = 0.0, omega = 0.0;
    for (size_t t = 0; t < texels; ++t) {
        power += (rad[4 * t] + rad[4 * t + 1] + rad[4 * t + 2]) / 3.0 * dirs[4 * t + 3];
        omega += dirs[4 * t + 3];
    }
    const double mean = power / omega;
    size_t count = 0;
    float *found = NULL;
    for (int pass = 0; pass < 2; ++pass) {
        size_t k = 0;
        for (size_t t = 0; t < texels; ++t) {
            const float *r = rad + 4 * t, *d = dirs + 4 * t;
            const double lum = (r[0] + r[1] + r[2]) / 3.0;
            if (!(sun_threshold > 0.0f && mean > 0.0 && lum >= sun_threshold * mean))
                continue;
            if (pass == 1) {
                float *o = found + SUN_FLOATS * k;
                o[0] = d[0], o[1] = d[1], o[2] = d[2], o[3] = sqrtf(d[3] / (float)PI); /* disc of that solid angle */
                o[4] = r[0] * d[3], o[5] = r[1] * d[3], o[6] = r[2] * d[3], o[7] = (float)(lum * d[3]);
                /* SH frame: azimuth of (x, -z) in [0, 2π); elevation asin(y). */
                double az = atan2(-(double)d[2], (double)d[0]);
                az = az < 0.0 ? az + 2.0 * PI : az;
                o[8] = (float)az, o[9] = (float)asin(fmax(-1.0, fmin(1.0, (double)d[1]))), o[10] = o[11] = 0.0f;
            }
            ++k;
        }
        if (pass == 0 && !(count = k))
            break;
        if (pass == 0 && !(found = pn_malloc(ctx, count * SUN_FLOATS * sizeof(float), "the env's sun texels")))
            return PN_ERROR_OUT_OF_MEMORY;
    }
    c->sun_count = 0;
    if (!count) {
        free(found);
        return PN_SUCCESS;
    }
    qsort(found, count, SUN_FLOATS * sizeof(float), by_power_desc);
    if (count > MAX_SUN)
        count = MAX_SUN;
    /* Black where the kept ones were (matched by direction). */
    for (size_t t = 0; t < texels; ++t)
        for (size_t k = 0; k < count; ++k)
            if (found[SUN_FLOATS * k] == dirs[4 * t] && found[SUN_FLOATS * k + 1] == dirs[4 * t + 1] &&
                found[SUN_FLOATS * k + 2] == dirs[4 * t + 2])
                rad[4 * t] = rad[4 * t + 1] = rad[4 * t + 2] = 0.0f;
    /* The bounds after the records, in the kernel's float arithmetic (r as max(r, 1e-6)). */
    float *all = realloc(found, (count * SUN_FLOATS + SUN_TRAILER) * sizeof(float));
    if (!all) {
        free(found);
        return pn_fail(ctx, PN_ERROR_OUT_OF_MEMORY, "out of memory for the env's sun texels");
    }
    found = all;
    float *box = found + count * SUN_FLOATS;
    box[0] = box[2] = INFINITY;
    box[1] = box[3] = -INFINITY;
    for (size_t k = 0; k < count; ++k) {
        const float *o = found + SUN_FLOATS * k, r = fmaxf(o[3], 1e-6f);
        box[0] = fminf(box[0], o[8]);
        box[1] = fmaxf(box[1], o[8]);
        box[2] = fminf(box[2], o[9] - r);
        box[3] = fmaxf(box[3], o[9] + r);
    }
    /* Where every texel is wholly above its horizon and in front of the normal n, their light is
     * Σ L_i Ω_i (n · s_i) = S n: n · s_i >= n · s_c - |s_i - s_c| > 0 when n · s_c exceeds the spread. */
    double sc[3] = {0.0, 0.0, 0.0}, sm[9] = {0.0};
    for (size_t k = 0; k < count; ++k) {
        const float *o = found + SUN_FLOATS * k;
        for (int a = 0; a < 3; ++a) {
            sc[a] += o[a];
            for (int ch = 0; ch < 3; ++ch)
                sm[3 * ch + a] += (double)o[4 + ch] * o[a];
        }
    }
    const double len = sqrt(sc[0] * sc[0] + sc[1] * sc[1] + sc[2] * sc[2]);
    double spread = 0.0;
    for (size_t k = 0; k < count; ++k) {
        const float *o = found + SUN_FLOATS * k;
        double d2 = 0.0;
        for (int a = 0; a < 3; ++a)
            d2 += (o[a] - sc[a] / len) * (o[a] - sc[a] / len);
        spread = fmax(spread, sqrt(d2));
    }
    for (int a = 0; a < 3; ++a)
        box[4 + a] = (float)(sc[a] / len);
    box[7] = (float)(spread + 1e-4); /* room for the rounding of n · s in float */
    for (int ch = 0; ch < 3; ++ch) {
        for (int a = 0; a < 3; ++a)
            box[8 + 4 * ch + a] = (float)sm[3 * ch + a];
        box[8 + 4 * ch + 3] = 0.0f;
    }
    pn_mem_release(&c->sun);
    pn_status st = pn_alloc(ctx, (count * SUN_FLOATS + SUN_TRAILER) * sizeof(float), CL_MEM_READ_ONLY, found, &c->sun,
                            "the env's sun texels");
    if (!st)
        c->sun_count = (int)count;
    free(found);
    return st;
}

/* The env map in SH (float64 over its cube texels with exact solid angles)
 * folded into M_jk = Σ_i L_i Γ_ijk per channel; the exact irradiance of the
 * env's upper half (an irradiance map of the cube with the texels below the
 * horizontal plane black) and u = Hᵀ M, H = the upper hemisphere as the
 * summed wedges at horizon 0, which the `exact_unoccluded` split subtracts;
 * and the reference irradiance (π × mean radiance) that scales the light
 * threshold. */
static pn_status prepare_env(pn_context ctx, pn_hf_cache *c, pn_envmap env, int nb, int n_phi, float sun_threshold)
{
    if (c->m_env_version == env->version && c->m_nb == nb && c->m_nphi == n_phi && c->m_sun == sun_threshold)
        return PN_SUCCESS;
    const int f = env->committed_face_size, nc = nb * nb, mi = env->committed_irradiance_size;
    const size_t texels = 6u * (size_t)f * f;
    float *rad = malloc(texels * 4 * sizeof(float)), *dirs = malloc(texels * 4 * sizeof(float));
    float *m = malloc((size_t)3 * nc * nc * sizeof(float));
    const float *table = NULL;
    const double *gamma = NULL;
    cl_mem cube = NULL, cube_dirs = NULL;
    pn_status st = rad && dirs && m ? PN_SUCCESS : pn_fail(ctx, PN_ERROR_OUT_OF_MEMORY, "out of memory for the env's SH");
    if (!st)
        st = pn_envmap_sample_cube(env, f, rad, dirs);
    if (!st)
        st = pn_sh_wedge_table(ctx, n_phi, nb, false, &table);
    if (!st)
        st = pn_sh_triple_product(ctx, nb, &gamma);
    if (!st)
        st = split_sun(ctx, c, rad, dirs, texels, sun_threshold);
    if (!st) {
        double l[PN_SH_MAX_BANDS * PN_SH_MAX_BANDS][3] = {{0}}, y[PN_SH_MAX_BANDS * PN_SH_MAX_BANDS], power = 0.0;
        double h[PN_SH_MAX_BANDS * PN_SH_MAX_BANDS] = {0};
        for (size_t t = 0; t < texels; ++t) {
            const float *d = dirs + 4 * t, *r = rad + 4 * t;
            /* SH frame: (x, -z, y) of the world direction. */
            const double x = d[0], yy = -(double)d[2], z = d[1];
            pn_sh_eval64(nb, z, sqrt(fmax(0.0, 1.0 - z * z)), atan2(yy, x), y);
            for (int q = 0; q < nc; ++q)
                for (int ch = 0; ch < 3; ++ch)
                    l[q][ch] += (double)r[ch] * d[3] * y[q];
            power += (r[0] + r[1] + r[2]) / 3.0 * d[3];
        }
        /* H: table(0, 0) turned to every azimuth and summed (as the kernel sums V). */
        for (int k = 0; k < n_phi; ++k) {
            const double a = 2.0 * PI * k / n_phi;
            for (int lb = 0; lb < nb; ++lb) {
                h[lb * lb + lb] += table[lb * lb + lb];
                for (int mm = 1; mm <= lb; ++mm) {
                    const double p = table[lb * lb + lb + mm], q = table[lb * lb + lb - mm];
                    h[lb * lb + lb + mm] += p * cos(mm * a) - q * sin(mm * a);
                    h[lb * lb + lb - mm] += p * sin(mm * a) + q * cos(mm * a);
                }
            }
        }
        for (int ch = 0; ch < 3; ++ch)
            for (int k = 0; k < nc; ++k) {
                double uk = 0.0;
                for (int j = 0; j < nc; ++j) {
                    double s = 0.0;
                    for (int i = 0; i < nc; ++i)
                        s += l[i][ch] * gamma[((size_t)i * nc + j) * nc + k];
                    m[((size_t)ch * nc + k) * nc + j] = (float)s; /* stored by columns: hf_env_vertex sums C_k M_·k */
                    uk += h[j] * s;
                }
                c->u[ch * PN_SH_MAX_BANDS * PN_SH_MAX_BANDS + k] = (float)uk;
            }
        c->env_ref = (float)(power / 4.0);
        pn_mem_release(&c->m);
        pn_mem_release(&c->u_buf);
        if (!(st = alloc_padded(ctx, m, (size_t)3 * nc, nc, &c->m, "the env's SH product matrices")))
            st = pn_alloc(ctx, sizeof c->u, CL_MEM_READ_ONLY, c->u, &c->u_buf, "the upper hemisphere's SH product");
    }
    /* The upper half's irradiance map, by the env map's own irradiance kernel. */
    for (size_t t = 0; !st && t < texels; ++t)
        if (dirs[4 * t + 1] <= 0.0f)
            rad[4 * t] = rad[4 * t + 1] = rad[4 * t + 2] = 0.0f;
    cl_kernel k;
    if (!st && !(st = pn_alloc(ctx, texels * 16, CL_MEM_READ_ONLY, rad, &cube, "the env's upper half")) &&
        !(st = pn_alloc(ctx, texels * 16, CL_MEM_READ_ONLY, dirs, &cube_dirs, "the env's directions")) &&
        !(st = pn_context_kernel(ctx, "envmap", "envmap_irradiance", &k))) {
        pn_mem_release(&c->up_irradiance);
        const cl_int ct = (cl_int)texels, cm = mi;
        size_t sizes[] = {sizeof(cl_mem), sizeof(cl_mem), sizeof ct, sizeof cm, sizeof(cl_mem)};
        const void *vals[] = {&cube, &cube_dirs, &ct, &cm, &c->up_irradiance};
        if (!(st = pn_alloc(ctx, 6u * (size_t)mi * mi * 16, CL_MEM_READ_WRITE, NULL, &c->up_irradiance,
                            "the upper-half irradiance map")) &&
            !(st = pn_set_args(ctx, k, "envmap_irradiance", 5, sizes, vals)) &&
            !(st = pn_enqueue_1d(ctx, k, "envmap_irradiance", 6u * (size_t)mi * mi, 64))) {
            c->up_size = mi;
            c->m_env_version = env->version;
            c->m_nb = nb;
            c->m_nphi = n_phi;
            c->m_sun = sun_threshold;
        }
    }
    if (cube || cube_dirs)
        clFinish(ctx->queue); /* the kernel reads them before they go */
    pn_mem_release(&cube);
    pn_mem_release(&cube_dirs);
    free(rad);
    free(dirs);
    free(m);
    return st;
}

static int level_count(int ls, uint32_t w, uint32_t d)
{
    const uint32_t res = w > d ? w : d;
    return (int)ceil(ls * log2((double)res) - 1e-9) + 1;
}

/* Per level the box (a0, b0, a1, b1), inclusive, of the values that a change
 * of the base heights inside `box` can reach: level k's value a averages the
 * values q of level k - 1 with |u_q - u_a| < ru (the tent's radius, level k's
 * spacing), i.e. a in (lo hu / ru - 1, hi hu / ru + 1) along each axis (0.01
 * of slack for the float weights at the support's edge); where the cell
 * counts are equal the axis is not filtered. Empty boxes have a0 > a1. */
static void changed_levels(const cl_int4 *levels, int n, uint32_t w, uint32_t d, const uint32_t box[4], cl_int4 *out)
{
    out[0].s[0] = (cl_int)box[0], out[0].s[1] = (cl_int)box[1], out[0].s[2] = (cl_int)box[2],
    out[0].s[3] = (cl_int)box[3];
    for (int k = 1; k < n; ++k) {
        cl_int4 b = out[k - 1];
        if (b.s[0] <= b.s[2])
            for (int axis = 0; axis < 2; ++axis) {
                const int np = levels[k - 1].s[1 + axis], nn = levels[k].s[1 + axis];
                if (np == nn)
                    continue;
                const double span = axis ? (double)d - 1.0 : (double)w - 1.0, hu = span / np, ru = span / nn;
                const double lo = ceil(b.s[axis] * hu / ru - 1.0 - 1e-2);
                const double hi = floor(b.s[2 + axis] * hu / ru + 1.0 + 1e-2);
                b.s[axis] = (cl_int)(lo < 0.0 ? 0.0 : lo);
                b.s[2 + axis] = (cl_int)(hi > nn ? nn : hi);
            }
        out[k] = b;
    }
}

static void box_union4(cl_int4 *a, cl_int4 b)
{
    if (b.s[0] > b.s[2])
        return;
    if (a->s[0] > a->s[2]) {
        *a = b;
        return;
    }
    for (int q = 0; q < 2; ++q) {
        a->s[q] = b.s[q] < a->s[q] ? b.s[q] : a->s[q];
        a->s[2 + q] = b.s[2 + q] > a->s[2 + q] ? b.s[2 + q] : a->s[2 + q];
    }
}

static void clear_pending(pn_hf_state *s)
{
    const cl_int4 none = {{1, 1, 0, 0}};
    for (int k = 0; k <= HF_MAX_LEVELS; ++k)
        s->pending[k] = none;
}

/* Runs hf_decimate on box `r` (a0, b0, a1, b1) of level q. */
static pn_status decimate(pn_context ctx, cl_kernel k, pn_hf_state *s, const cl_int4 *levels, int q, cl_int4 r,
                          cl_float wm1, cl_float dm1)
{
    if (r.s[0] > r.s[2] || r.s[1] > r.s[3])
        return PN_SUCCESS;
    const cl_int4 rect = {{r.s[0], r.s[1], r.s[2] - r.s[0] + 1, r.s[3] - r.s[1] + 1}};
    size_t sizes[] = {sizeof(cl_mem), sizeof(cl_int4), sizeof(cl_int4), sizeof wm1, sizeof dm1, sizeof rect};
    const void *vals[] = {&s->pyr, &levels[q - 1], &levels[q], &wm1, &dm1, &rect};
    pn_status st = pn_set_args(ctx, k, "hf_decimate", 6, sizes, vals);
    return st ? st : pn_enqueue_1d(ctx, k, "hf_decimate", (size_t)rect.s[2] * (size_t)rect.s[3], 64);
}

static pn_status run_normals(pn_context ctx, pn_hf_state *s, size_t base)
{
    cl_kernel k;
    pn_status st = pn_context_kernel(ctx, "heightfield", "hf_normals", &k);
    if (st)
        return st;
    size_t sizes[] = {sizeof(cl_mem), sizeof s->grid, sizeof s->geom, sizeof(cl_mem)};
    const void *vals[] = {&s->pyr, &s->grid, &s->geom, &s->normals};
    if (!(st = pn_set_args(ctx, k, "hf_normals", 4, sizes, vals)))
        st = pn_enqueue_1d(ctx, k, "hf_normals", base, 64);
    return st;
}

/* A local edit (pn_heightfield_set_heights_region) since the pyramid's
 * version: the box's world heights uploaded, only the values of each level
 * that the box can change decimated again (the same arithmetic as a full
 * build, so the same floats), the normals, and the changed boxes added to
 * the pending ones of the next env pass. */
static pn_status update_field(pn_context ctx, pn_hf_state *s, pn_heightfield hf, const uint32_t box[4])
{
    const uint32_t w = hf->width, d = hf->depth;
    const int n = s->grid.s[2];
    const size_t base = (size_t)w * d;
    pn_status st = PN_SUCCESS;
    if (box[0] <= box[2]) {
        const cl_int4 *levels = s->levels_host;
        cl_int4 *boxes = malloc((size_t)n * sizeof *boxes);
        const size_t bw = box[2] - box[0] + 1, bh = box[3] - box[1] + 1;
        float *rect = malloc(bw * bh * sizeof(float));
        if (!boxes || !rect)
            st = pn_fail(ctx, PN_ERROR_OUT_OF_MEMORY, "out of memory for a height-field update");
        cl_int err = CL_SUCCESS;
        for (size_t j = 0; !st && err == CL_SUCCESS && j < bh; ++j)
            for (size_t i = 0; i < bw; ++i)
                rect[j * bw + i] = hf->placement.height_scale * hf->heights[(box[1] + j) * w + box[0] + i];
        /* the world heights, and level 0 (the same values after them) */
        for (int copy = 0; !st && err == CL_SUCCESS && copy < 2; ++copy) {
            const size_t origin[3] = {(copy * base + box[0]) * sizeof(float), box[1], 0}, host[3] = {0, 0, 0};
            const size_t region[3] = {bw * sizeof(float), bh, 1};
            err = clEnqueueWriteBufferRect(ctx->queue, s->pyr, CL_TRUE, origin, host, region, w * sizeof(float), 0,
                                           bw * sizeof(float), 0, rect, 0, NULL, NULL);
        }
        if (!st && err != CL_SUCCESS)
            st = pn_fail_cl(ctx, err, "uploading a height-field region");
        cl_kernel k;
        if (!st)
            changed_levels(levels, n, w, d, box, boxes);
        if (!st)
            st = pn_context_kernel(ctx, "heightfield", "hf_decimate", &k);
        const cl_float wm1 = (cl_float)(w - 1), dm1 = (cl_float)(d - 1);
        for (int q = 1; !st && q < n; ++q)
            st = decimate(ctx, k, s, levels, q, boxes[q], wm1, dm1);
        if (!st)
            st = run_normals(ctx, s, base);
        for (int q = 0; !st && q < n; ++q)
            box_union4(&s->pending[q], boxes[q]);
        if (!st) { /* normals: central differences reach one vertex further */
            const cl_int4 nb = {{(cl_int)box[0] - 1, (cl_int)box[1] - 1, (cl_int)box[2] + 1, (cl_int)box[3] + 1}};
            box_union4(&s->pending[n], nb);
        }
        free(boxes);
        free(rect);
    }
    if (!st)
        s->version = hf->version;
    else
        s->version = 0, s->pass_valid = false; /* rebuilt in full next time */
    return st;
}

/* Pyramid (level 0 = world heights, then tent decimation on the device),
 * normals and albedo of field i, rebuilt when the field or ls changes. */
static pn_status prepare_field(pn_context ctx, pn_hf_state *s, pn_heightfield hf, const pn_hf_settings *set)
{
    if (!hf->committed)
        return pn_fail(ctx, PN_ERROR_NOT_COMMITTED, "height field changed since its last commit; call pn_heightfield_commit");
    const uint32_t w = hf->width, d = hf->depth;
    const int n = level_count(set->level_step, w, d);
    if (n > HF_MAX_LEVELS)
        return pn_fail(ctx, PN_ERROR_INVALID_ARGUMENT,
                       "heightfield: level_step %d on a %u x %u field needs %d pyramid levels (at most %d)",
                       set->level_step, w, d, n, HF_MAX_LEVELS);
    float sx, sz;
    pn_heightfield_spacing(hf, &sx, &sz);
    const float *o = hf->placement.origin;
    /* geom.s7: the largest |H| (world heights), a bound on every level's values for the searches' early exits
     * (levels are weighted means of the heights); the interpolating reconstruction's control points overshoot
     * the heights, so there it is infinite (no exit on a bound). */
    const float amax = set->reconstruction ? INFINITY
                                           : fmaxf(fabsf(hf->placement.height_scale * hf->hmin),
                                                   fabsf(hf->placement.height_scale * hf->hmax));
    const float geom[8] = {o[0], o[1], o[2], sx, sz, (float)set->level_step, sx < sz ? sx : sz, amax};
    memcpy(s->geom.s, geom, sizeof geom);
    s->grid.s[0] = (cl_int)w;
    s->grid.s[1] = (cl_int)d;
    s->grid.s[2] = n;
    s->grid.s[3] = (cl_int)lround(set->level_step * set->level_offset);
    if (s->version == hf->version && s->level_step == set->level_step && s->reconstruction == set->reconstruction)
        return PN_SUCCESS;
    /* A local edit since: only what it changes. The interpolating
     * reconstruction solves along whole rows and columns of every level (any
     * edit changes them all): rebuilt in full. */
    uint32_t box[4];
    if (set->partial_update && !set->reconstruction && s->owner == hf && s->version &&
        s->level_step == set->level_step && s->reconstruction == 0 && s->has_albedo == (hf->albedo != NULL) &&
        pn_heightfield_changed_since(hf, s->version, box))
        return update_field(ctx, s, hf, box);
    cl_int4 *levels = malloc((size_t)n * sizeof *levels);
    if (!levels)
        return pn_fail(ctx, PN_ERROR_OUT_OF_MEMORY, "out of memory for the pyramid levels");
    /* pyr: the world heights (vertex gid at gid), then the levels' B-spline control points. */
    const size_t base = (size_t)w * d;
    size_t total = base;
    for (int k = 0; k < n; ++k) {
        const double f = pow(2.0, (double)k / set->level_step); /* exact at multiples of ls */
        const long ck = k ? lround((w - 1) / f) : (long)(w - 1), ek = k ? lround((d - 1) / f) : (long)(d - 1);
        levels[k].s[0] = (cl_int)total;
        levels[k].s[1] = (cl_int)(ck < 1 ? 1 : ck);
        levels[k].s[2] = (cl_int)(ek < 1 ? 1 : ek);
        levels[k].s[3] = 0;
        total += (size_t)(levels[k].s[1] + 1) * (levels[k].s[2] + 1);
    }
    s->pyramid_floats = total;
    memcpy(s->levels_host, levels, (size_t)n * sizeof *levels);
    float *heights = malloc(base * sizeof(float));
    pn_status st = heights ? PN_SUCCESS : pn_fail(ctx, PN_ERROR_OUT_OF_MEMORY, "out of memory for the world heights");
    for (size_t k = 0; !st && k < base; ++k)
        heights[k] = hf->placement.height_scale * hf->heights[k];
    s->version = 0;
    s->pass_valid = false;
    s->owner = hf;
    clear_pending(s);
    if (!st) {
        cl_mem *mems[] = {&s->pyr, &s->levels, &s->normals, &s->albedo, &s->out_env, &s->out_total, &s->horizons,
                          &s->checkpoints};
        for (size_t k = 0; k < sizeof mems / sizeof mems[0]; ++k)
            pn_mem_release(mems[k]);
    }
    if (!st && !(st = pn_alloc(ctx, total * sizeof(float), CL_MEM_READ_WRITE, NULL, &s->pyr, "the height pyramid")) &&
        !(st = pn_alloc(ctx, (size_t)n * sizeof *levels, CL_MEM_READ_ONLY, levels, &s->levels, "the pyramid levels")) &&
        !(st = pn_alloc(ctx, base * 16, CL_MEM_READ_WRITE, NULL, &s->normals, "height-field normals")) &&
        !(st = pn_alloc(ctx, base * 16, CL_MEM_READ_WRITE, NULL, &s->out_env, "height-field env radiance")) &&
        !(st = pn_alloc(ctx, base * 16, CL_MEM_READ_WRITE, NULL, &s->out_total, "height-field total radiance")) &&
        !(st = pn_alloc(ctx, hf->albedo ? base * 3 * sizeof(float) : 16, CL_MEM_READ_ONLY, hf->albedo, &s->albedo,
                        "a height-field albedo map"))) {
        cl_int err = clEnqueueWriteBuffer(ctx->queue, s->pyr, CL_TRUE, 0, base * sizeof(float), heights, 0, NULL, NULL);
        if (err == CL_SUCCESS) /* level 0 starts as the heights themselves */
            err = clEnqueueWriteBuffer(ctx->queue, s->pyr, CL_TRUE, base * sizeof(float), base * sizeof(float), heights,
                                       0, NULL, NULL);
        if (err != CL_SUCCESS)
            st = pn_fail_cl(ctx, err, "uploading the height field");
    }
    free(heights);
    cl_kernel k;
    const cl_float wm1 = (cl_float)(w - 1), dm1 = (cl_float)(d - 1);
    if (!st)
        st = pn_context_kernel(ctx, "heightfield", "hf_decimate", &k);
    for (int q = 1; !st && q < n; ++q) {
        const cl_int4 whole = {{0, 0, levels[q].s[1], levels[q].s[2]}};
        st = decimate(ctx, k, s, levels, q, whole, wm1, dm1);
    }
    /* Interpolating reconstruction: every level's values become the control
     * points whose B-spline passes through them (rows, then columns). */
    if (!st && set->reconstruction)
        st = pn_context_kernel(ctx, "heightfield", "hf_prefilter", &k);
    for (int q = 0; !st && set->reconstruction && q < n; ++q)
        for (cl_int rows = 1; !st && rows >= 0; --rows) {
            size_t sizes[] = {sizeof(cl_mem), sizeof(cl_int4), sizeof rows};
            const void *vals[] = {&s->pyr, &levels[q], &rows};
            const size_t lines = (size_t)(rows ? levels[q].s[2] : levels[q].s[1]) + 1;
            if (!(st = pn_set_args(ctx, k, "hf_prefilter", 3, sizes, vals)))
                st = pn_enqueue_1d(ctx, k, "hf_prefilter", lines, 16);
        }
    free(levels);
    if (!st)
        st = run_normals(ctx, s, base);
    if (!st) {
        s->version = hf->version;
        s->level_step = set->level_step;
        s->reconstruction = set->reconstruction;
        s->has_albedo = hf->albedo != NULL;
        s->light_capacity = 0;
        pn_mem_release(&s->out_lights);
    }
    return st;
}

static pn_hf_settings hf_settings(pn_renderer r)
{
    pn_hf_settings s = {(int)r->params[P_LEVEL_STEP], (int)r->params[P_AZIMUTHS], (int)r->params[P_BANDS],
                        (int)r->params[P_EXACT_HORIZON], (int)r->params[P_EXACT_UNOCCLUDED],
                        (int)r->params[P_LIGHT_VISIBILITY], (int)r->params[P_RECONSTRUCTION],
                        (int)r->params[P_PARTIAL_UPDATE], (float)r->params[P_LEVEL_OFFSET], (float)r->params[P_LIGHT_THRESHOLD],
                        (float)r->params[P_SUN_THRESHOLD]};
    return s;
}

/* The fields attached to the scene's instances, in instance order. */
static pn_status collect_fields(pn_context ctx, pn_hf_cache *c, pn_scene scene)
{
    c->hf_count = 0;
    for (uint32_t i = 0; i < scene->attachment_count; ++i) {
        const pn_attachment *a = &scene->attachments[i];
        if (a->asset->magic != PN_MAGIC_HEIGHTFIELD)
            continue;
        if (c->hf_count == MAX_FIELDS)
            return pn_fail(ctx, PN_ERROR_UNSUPPORTED, "heightfield: more than %d height fields are attached",
                           MAX_FIELDS);
        c->hfs[c->hf_count] = (pn_heightfield)a->asset;
        c->hf_instances[c->hf_count++] = a->instance;
    }
    if (!c->hf_count)
        return pn_fail(ctx, PN_ERROR_NOT_COMMITTED,
                       "heightfield: no height field is attached to the scene (pn_scene_attach)");
    return PN_SUCCESS;
}

/* Everything the passes and probes read, for every attached field: the
 * method's plan. */
static pn_status plan(pn_renderer r, pn_scene scene)
{
    pn_context ctx = r->obj.ctx;
    pn_hf_cache *c = r->state;
    const pn_hf_settings settings = hf_settings(r), *set = &settings;
    pn_status st;
    if ((st = collect_fields(ctx, c, scene)) || (st = pn_sh_cache_begin(ctx)))
        return st;
    if ((st = prepare_tables(ctx, c, set->azimuths, set->bands)) || (st = prepare_env(ctx, c, scene->env, set->bands, set->azimuths, set->sun_threshold)))
        return st;
    for (uint32_t i = 0; i < c->hf_count; ++i)
        if ((st = prepare_field(ctx, &c->fields[i], c->hfs[i], set)))
            return st;
    return PN_SUCCESS;
}

static void cosine_zh(int nb, cl_float8 *out)
{
    double a[PN_SH_MAX_BANDS];
    pn_sh_clamped_cosine64(nb, a);
    /* odd l >= 3: 0 (the quadrature leaves ~1e-17), so that hf_env_vertex skips those bands of C */
    for (int l = 0; l < 8; ++l)
        out->s[l] = l < nb && (l < 3 || l % 2 == 0) ? (float)a[l] : 0.0f;
}

/* Nearest distance from the light's centre to the field's bounding box. */
static float light_distance(pn_heightfield hf, const pn_sphere_light *l)
{
    const float *o = hf->placement.origin, hs = hf->placement.height_scale;
    const float lo = fminf(hs * hf->hmin, hs * hf->hmax), hi = fmaxf(hs * hf->hmin, hs * hf->hmax);
    const float bmin[3] = {o[0], o[1] + lo, o[2]}, bmax[3] = {o[0] + hf->placement.size[0], o[1] + hi,
                                                               o[2] + hf->placement.size[1]};
    float d2 = 0.0f;
    for (int a = 0; a < 3; ++a) {
        const float e = fmaxf(fmaxf(bmin[a] - l->position[a], l->position[a] - bmax[a]), 0.0f);
        d2 += e * e;
    }
    return sqrtf(d2);
}

/* Whether the per-vertex outputs already hold this scene state. */
static bool outputs_current(const pn_hf_cache *c, pn_scene scene, const pn_hf_settings *set)
{
    if (!c->outputs_valid || memcmp(&c->outputs_settings, set, sizeof *set) ||
        c->outputs_env != scene->env->version || c->outputs_field_count != c->hf_count ||
        c->outputs_light_count != scene->light_count ||
        (scene->light_count &&
         memcmp(c->outputs_lights, scene->lights, scene->light_count * sizeof *scene->lights)))
        return false;
    for (uint32_t f = 0; f < c->hf_count; ++f)
        if (c->outputs_fields[f] != c->hfs[f]->version)
            return false;
    return true;
}

static void remember_outputs(pn_context ctx, pn_hf_cache *c, pn_scene scene, const pn_hf_settings *set)
{
    c->outputs_valid = false;
    free(c->outputs_lights);
    c->outputs_lights = NULL;
    const size_t bytes = scene->light_count * sizeof *scene->lights;
    if (bytes && !(c->outputs_lights = pn_malloc(ctx, bytes, "the lights of the last height-field passes")))
        return; /* not remembered: the next read recomputes */
    if (bytes)
        memcpy(c->outputs_lights, scene->lights, bytes);
    c->outputs_settings = *set;
    c->outputs_env = scene->env->version;
    c->outputs_field_count = c->hf_count;
    c->outputs_light_count = scene->light_count;
    for (uint32_t f = 0; f < c->hf_count; ++f)
        c->outputs_fields[f] = c->hfs[f]->version;
    c->outputs_valid = true;
}

/* Checkpoints of the pyramid search kept per vertex and azimuth (hf_env):
 * before samples ls, 2 ls, ... < levels. */
static int checkpoint_count(const pn_hf_state *s)
{
    const int n = s->grid.s[2], ls = (int)s->geom.s[5];
    return (n - 1) / ls > 0 ? (n - 1) / ls : 1;
}

/* Bytes kept for partial updates: horizons and checkpoints. */
static size_t keep_bytes(const pn_hf_state *s, const pn_hf_settings *set, size_t base)
{
    return pn_mul_size(pn_mul_size(base, (size_t)set->azimuths, sizeof(float)),
                       set->exact ? 1u : 1u + (size_t)checkpoint_count(s), 1);
}

/* A kept device array of `want` floats: reallocated (and the kept pass
 * invalidated) when its size changes. */
static pn_status keep_floats(pn_context ctx, pn_hf_state *s, cl_mem *mem, size_t *have, size_t want,
                             const char *what)
{
    if (*mem && *have == want)
        return PN_SUCCESS;
    pn_mem_release(mem);
    s->pass_valid = false;
    pn_status st = pn_alloc(ctx, pn_mul_size(want, sizeof(float), 1), CL_MEM_READ_WRITE, NULL, mem, what);
    if (!st)
        *have = want;
    return st;
}

/* The env pass's update mode (hf_env) for field state s: the horizon store
 * allocated, and with a partial update (2) the pending changed boxes
 * uploaded. */
static pn_status prepare_update(pn_context ctx, pn_hf_state *s, pn_scene scene, const pn_hf_settings *set,
                                size_t base, cl_int *update)
{
    pn_status st;
    const size_t floats = pn_mul_size(base, (size_t)set->azimuths, 1);
    if ((st = keep_floats(ctx, s, &s->horizons, &s->horizon_floats, floats, "the kept height-field horizons")))
        return st;
    /* the pyramid search's running maximum every ls samples (exact mode: none) */
    const size_t cps = set->exact ? 1 : pn_mul_size(floats, (size_t)checkpoint_count(s), 1);
    if ((st = keep_floats(ctx, s, &s->checkpoints, &s->checkpoint_floats, cps,
                          "the kept height-field search checkpoints")))
        return st;
    if (!s->changed && (st = pn_alloc(ctx, sizeof s->pending, CL_MEM_READ_ONLY, NULL, &s->changed,
                                      "the changed pyramid boxes")))
        return st;
    *update = 1;
    if (!s->pass_valid || memcmp(&s->pass_settings, set, sizeof *set) || s->pass_env != scene->env->version)
        return PN_SUCCESS;
    /* A new buffer made from the boxes (execute only enqueues: no blocking
     * write; the old one lives on until the kernels that read it are done). */
    pn_mem_release(&s->changed);
    if ((st = pn_alloc(ctx, sizeof s->pending, CL_MEM_READ_ONLY, s->pending, &s->changed, "the changed pyramid boxes")))
        return st;
    *update = 2;
    return PN_SUCCESS;
}

static pn_status run_passes(pn_context ctx, pn_hf_cache *c, pn_scene scene, const pn_hf_settings *set)
{
    pn_status st;
    cl_kernel kenv, klight;
    if ((st = pn_context_kernel(ctx, "heightfield", "hf_env", &kenv)) ||
        (st = pn_context_kernel(ctx, "heightfield", "hf_light", &klight)))
        return st;
    c->outputs_valid = false;
    cl_float8 czh;
    cosine_zh(set->bands, &czh);
    const cl_int n_phi = set->azimuths, nb = set->bands, exact = set->exact;
    const uint32_t lights = scene->light_count;
    c->lights_culled = 0;
    for (uint32_t f = 0; f < c->hf_count; ++f) {
        pn_hf_state *s = &c->fields[f];
        pn_heightfield hf = c->hfs[f];
        const size_t base = (size_t)hf->width * hf->depth;
        const cl_int has_albedo = s->has_albedo, split = set->exact_unoccluded, up_size = c->up_size;
        const cl_int suns = c->sun_count;
        cl_mem sun = c->sun ? c->sun : c->u_buf; /* any valid buffer when there is no sun */
        /* Partial updates: update 1 keeps the horizons; 2 (the last env
         * pass was for the same settings and env, its horizons kept) redoes
         * only what the pending changed boxes reach. */
        cl_int update = 0;
        /* Kept only for fields that have had local edits: the others' frames cost as before. */
        if (set->partial_update && hf->regional && keep_bytes(s, set, base) <= KEEP_MAX_BYTES &&
            (st = prepare_update(ctx, s, scene, set, base, &update)))
            return st;
        s->pass_valid = false;
        cl_mem changed = s->changed ? s->changed : s->levels, horizons = s->horizons ? s->horizons : s->out_env;
        cl_mem checkpoints = s->checkpoints ? s->checkpoints : s->out_env;
        const cl_int ncp = checkpoint_count(s);
        size_t sizes[] = {sizeof(cl_mem), sizeof(cl_mem), sizeof s->grid, sizeof s->geom, sizeof(cl_mem),
                          sizeof(cl_mem), sizeof has_albedo, sizeof n_phi, sizeof nb, sizeof exact, sizeof(cl_mem),
                          sizeof(cl_mem), sizeof czh, sizeof split, sizeof(cl_mem), sizeof up_size, sizeof(cl_mem),
                          sizeof(cl_mem), sizeof suns, sizeof(cl_mem), sizeof(cl_mem), sizeof update, sizeof(cl_mem),
                          sizeof(cl_mem), sizeof(cl_mem), sizeof ncp};
        const void *vals[] = {&s->pyr, &s->levels, &s->grid, &s->geom, &s->normals, &s->albedo, &has_albedo, &n_phi,
                              &nb, &exact, &c->env_table, &c->m, &czh, &split, &c->up_irradiance, &up_size, &c->u_buf,
                              &sun, &suns, &s->out_env, &s->out_total, &update, &changed, &horizons, &checkpoints,
                              &ncp};
        s->last_update = 0;
        if ((st = pn_set_args(ctx, kenv, "hf_env", 26, sizes, vals)) ||
            (st = pn_enqueue_1d(ctx, kenv, "hf_env", base, 64)))
            return st;
        s->last_update = update;
        if (update) {
            s->pass_valid = true;
            s->pass_settings = *set;
            s->pass_env = scene->env->version;
            clear_pending(s);
        }
        if (s->light_capacity < lights) {
            pn_mem_release(&s->out_lights);
            s->light_capacity = 0;
            if ((st = pn_alloc(ctx, pn_mul_size(base, lights, 16), CL_MEM_READ_WRITE, NULL, &s->out_lights,
                               "height-field light radiance")))
                return st;
            s->light_capacity = lights;
        }
        const float threshold = set->light_threshold * c->env_ref;
        for (uint32_t li = 0; li < lights; ++li) {
            const pn_sphere_light *l = &scene->lights[li];
            const float le = fmaxf(fmaxf(l->radiance[0], l->radiance[1]), l->radiance[2]);
            const float dist = light_distance(hf, l);
            float cap = 2.0f; /* 1 - cos of the largest half-angle the light subtends over the field */
            if (dist > l->radius) {
                const float q = l->radius * l->radius / (dist * dist);
                cap = q / (1.0f + sqrtf(1.0f - q));
            }
            const cl_int out_offset = (cl_int)(li * base);
            if (le <= 0.0f || le * 2.0f * (float)PI * cap < threshold) {
                /* Negligible everywhere on this field: no pass. */
                const cl_float4 zero = {{0.0f, 0.0f, 0.0f, 0.0f}};
                cl_int err = clEnqueueFillBuffer(ctx->queue, s->out_lights, &zero, sizeof zero, li * base * 16,
                                                 base * 16, 0, NULL, NULL);
                if (err != CL_SUCCESS)
                    return pn_fail_cl(ctx, err, "clearing a culled light's output");
                c->lights_culled++;
                continue;
            }
            const cl_float4 light = {{l->position[0], l->position[1], l->position[2], l->radius}};
            const cl_float4 radiance = {{l->radiance[0], l->radiance[1], l->radiance[2], 0.0f}};
            const cl_int gamma_count = c->gamma_count, mode = set->light_visibility;
            size_t lsizes[] = {sizeof(cl_mem), sizeof(cl_mem), sizeof s->grid, sizeof s->geom, sizeof(cl_mem),
                               sizeof(cl_mem), sizeof has_albedo, sizeof n_phi, sizeof nb, sizeof exact,
                               sizeof(cl_mem), sizeof(cl_mem), sizeof(cl_mem), sizeof gamma_count, sizeof czh,
                               sizeof light, sizeof radiance, sizeof threshold, sizeof mode, sizeof out_offset,
                               sizeof(cl_mem), sizeof(cl_mem)};
            const void *lvals[] = {&s->pyr, &s->levels, &s->grid, &s->geom, &s->normals, &s->albedo, &has_albedo,
                                   &n_phi, &nb, &exact, &c->light_table, &c->gamma_index, &c->gamma_value,
                                   &gamma_count, &czh, &light, &radiance, &threshold, &mode, &out_offset,
                                   &s->out_lights, &s->out_total};
            if ((st = pn_set_args(ctx, klight, "hf_light", 22, lsizes, lvals)) ||
                (st = pn_enqueue_1d(ctx, klight, "hf_light", base, 64)))
                return st;
        }
    }
    return PN_SUCCESS;
}

/* Pixels that are not on a height field (and the background) get `unshadowed`. */
static pn_status execute(pn_renderer r, pn_scene scene, pn_gbuffer gb, pn_image image)
{
    pn_context ctx = r->obj.ctx;
    pn_hf_cache *c = r->state;
    const pn_hf_settings settings = hf_settings(r), *set = &settings;
    pn_status st;
    cl_kernel k;
    if ((st = pn_unshadowed_enqueue(r, scene, gb, image, (int)r->params[P_BACKGROUND])) ||
        (st = run_passes(ctx, c, scene, set)) ||
        (st = pn_context_kernel(ctx, "heightfield", "hf_shade", &k)))
        return st;
    remember_outputs(ctx, c, scene, set);
    const cl_int count = (cl_int)(gb->width * gb->height);
    for (uint32_t f = 0; f < c->hf_count; ++f) {
        pn_hf_state *s = &c->fields[f];
        const cl_uint instance = c->hf_instances[f];
        size_t sizes[] = {sizeof(cl_mem), sizeof(cl_mem), sizeof(cl_mem), sizeof count, sizeof instance,
                          sizeof s->grid, sizeof s->geom, sizeof(cl_mem), sizeof(cl_mem)};
        const void *vals[] = {&gb->planes[PN_GBUFFER_POSITION], &gb->planes[PN_GBUFFER_ALBEDO],
                              &gb->planes[PN_GBUFFER_INSTANCE], &count, &instance, &s->grid, &s->geom,
                              &s->out_total, &image->buffer};
        if ((st = pn_set_args(ctx, k, "hf_shade", 9, sizes, vals)) ||
            (st = pn_enqueue_1d(ctx, k, "hf_shade", (size_t)count, 64)))
            return st;
    }
    return PN_SUCCESS;
}

static pn_status read_output(pn_renderer r, pn_scene scene, int what, uint32_t instance, uint32_t light, void *host,
                             size_t bytes)
{
    pn_context ctx = r->obj.ctx;
    pn_hf_cache *c = r->state;
    const pn_hf_settings settings = hf_settings(r), *set = &settings;
    pn_status st;
    uint32_t field = 0;
    while (field < c->hf_count && c->hf_instances[field] != instance)
        ++field;
    if (field == c->hf_count)
        return pn_fail(ctx, PN_ERROR_INVALID_ARGUMENT, "instance %u has no height field attached (%u fields attached)",
                       instance, c->hf_count);
    const bool needs_light = what == OUT_LIGHT || what == OUT_LIGHT_HORIZONS || what == OUT_LIGHT_VISIBILITY;
    if (needs_light && light >= scene->light_count)
        return pn_fail(ctx, PN_ERROR_INVALID_ARGUMENT, "light %u: the scene has %u lights", light, scene->light_count);
    pn_hf_state *s = &c->fields[field];
    pn_heightfield hf = c->hfs[field];
    const size_t base = (size_t)hf->width * hf->depth;
    size_t per = 0;
    switch (what) {
    case OUT_ENV:
    case OUT_LIGHT:
    case OUT_TOTAL:
    case OUT_NORMALS:
        per = 4;
        break;
    case OUT_ENV_HORIZONS:
    case OUT_LIGHT_HORIZONS:
        per = (size_t)set->azimuths;
        break;
    case OUT_ENV_VISIBILITY:
    case OUT_LIGHT_VISIBILITY:
        per = (size_t)set->bands * set->bands;
        break;
    case OUT_ENV_SEARCHED:
        per = (size_t)set->azimuths;
        break;
    default:
        return pn_fail(ctx, PN_ERROR_INTERNAL, "unknown height-field output %d", what);
    }
    const size_t need = pn_mul_size(base, per, sizeof(float));
    if (bytes != need)
        return pn_fail(ctx, PN_ERROR_INVALID_SIZE, "height-field output %s needs %zu bytes, the buffer has %zu",
                       outputs[what].name, need, bytes);
    cl_mem src = NULL, temp = NULL;
    size_t offset = 0;
    if (what == OUT_ENV || what == OUT_LIGHT || what == OUT_TOTAL) {
        if (!outputs_current(c, scene, set)) {
            if ((st = run_passes(ctx, c, scene, set)))
                return st;
            remember_outputs(ctx, c, scene, set);
        }
        src = what == OUT_ENV ? s->out_env : what == OUT_TOTAL ? s->out_total : s->out_lights;
        offset = what == OUT_LIGHT ? light * base * 16 : 0;
    } else if (what == OUT_NORMALS) {
        src = s->normals;
    } else if (what == OUT_ENV_SEARCHED) {
        if (!set->partial_update)
            return pn_fail(ctx, PN_ERROR_INVALID_ARGUMENT, "height-field output env_searched needs partial_update = 1");
        if (!outputs_current(c, scene, set)) {
            if ((st = run_passes(ctx, c, scene, set)))
                return st;
            remember_outputs(ctx, c, scene, set);
        }
        cl_kernel k;
        const cl_int n_phi = set->azimuths, exact = set->exact, update = s->last_update;
        if ((st = pn_context_kernel(ctx, "heightfield", "hf_searched", &k)) ||
            (st = pn_alloc(ctx, need, CL_MEM_READ_WRITE, NULL, &temp, "a height-field probe")))
            return st;
        size_t sizes[] = {sizeof(cl_mem), sizeof s->grid, sizeof s->geom, sizeof n_phi, sizeof exact, sizeof update,
                          sizeof(cl_mem), sizeof(cl_mem)};
        cl_mem changed = s->changed ? s->changed : s->levels; /* none kept: update 0, every lane */
        const void *vals[] = {&s->levels, &s->grid, &s->geom, &n_phi, &exact, &update, &changed, &temp};
        if ((st = pn_set_args(ctx, k, "hf_searched", 8, sizes, vals)) ||
            (st = pn_enqueue_1d(ctx, k, "hf_searched", base, 64))) {
            pn_mem_release(&temp);
            return st;
        }
        src = temp;
    } else {
        cl_kernel k;
        const bool env = what == OUT_ENV_HORIZONS || what == OUT_ENV_VISIBILITY;
        const cl_int n_phi = set->azimuths, nb = set->bands, exact = set->exact;
        const cl_int mode = what == OUT_ENV_HORIZONS || what == OUT_LIGHT_HORIZONS ? 0 : 1;
        cl_float4 lv = {{0.0f, 0.0f, 0.0f, -1.0f}};
        if (!env) {
            const pn_sphere_light *l = &scene->lights[light];
            cl_float4 t = {{l->position[0], l->position[1], l->position[2], l->radius}};
            lv = t;
        }
        if ((st = pn_context_kernel(ctx, "heightfield", "hf_probe", &k)) ||
            (st = pn_alloc(ctx, need, CL_MEM_READ_WRITE, NULL, &temp, "a height-field probe")))
            return st;
        size_t sizes[] = {sizeof(cl_mem), sizeof(cl_mem), sizeof s->grid, sizeof s->geom, sizeof n_phi, sizeof nb,
                          sizeof exact, sizeof(cl_mem), sizeof lv, sizeof mode, sizeof(cl_mem)};
        const void *vals[] = {&s->pyr, &s->levels, &s->grid, &s->geom, &n_phi, &nb, &exact,
                              env ? &c->env_table : &c->light_table, &lv, &mode, &temp};
        if ((st = pn_set_args(ctx, k, "hf_probe", 11, sizes, vals)) ||
            (st = pn_enqueue_1d(ctx, k, "hf_probe", base, 64))) {
            pn_mem_release(&temp);
            return st;
        }
        src = temp;
    }
    cl_int err = clEnqueueReadBuffer(ctx->queue, src, CL_TRUE, offset, need, host, 0, NULL, NULL);
    pn_mem_release(&temp);
    if (err != CL_SUCCESS)
        return pn_fail_cl(ctx, err, "reading a height-field output");
    return PN_SUCCESS;
}

static pn_status create(pn_renderer r)
{
    pn_hf_cache *c = r->state;
    c->m_env_version = UINT64_MAX;
    return PN_SUCCESS;
}

const pn_method_desc pn_method_heightfield = {
    .name = "heightfield",
    .summary = "environment and spherical-light lighting with soft self-shadows on the attached height fields; "
               "other pixels get unshadowed",
    .stage = "heightfield",
    .doc_page = "docs/heightfield.md",
    .params = params,
    .param_count = (int)(sizeof params / sizeof params[0]),
    .outputs = outputs,
    .output_count = (int)(sizeof outputs / sizeof outputs[0]),
    .inputs = PN_INPUT_ENVMAP | PN_INPUT_LIGHTS | PN_INPUT_HEIGHTFIELD,
    .state_size = sizeof(pn_hf_cache),
    .create = create,
    .destroy = destroy,
    .plan = plan,
    .execute = execute,
    .read_output = read_output,
};
