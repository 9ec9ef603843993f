/* Sphere sets (docs/isg.md section 7): the occluder proxies of the isg
 * method. A set is built from a committed mesh or given by the caller
 * (xyz centre, radius, object space), and attaches to instances.
 *
 * Builder: inscribed balls of the solid, chosen to cover it (after the
 * medial-sphere approximations of Stolpner, Kry and Siddiqi 2012 and the
 * one-sided sets of Bradshaw and O'Sullivan 2004; docs/isg.md section 7):
 *   1. the solid as interior voxels (ray parity along x, y and z, majority
 *      vote, so a small hole in an open scan flips one vote, not the cell);
 *   2. every interior cell's distance to the nearest outside cell (exact
 *      Euclidean distance transform), its ball's radius that distance less
 *      half a cell; candidates are the cells whose ball is not inside a
 *      neighbour's (about the medial axis);
 *   3. N balls picked greedily, each covering the most interior cells not
 *      yet covered (lazy evaluation), every radius grown past the surface
 *      by the same amount g (-0.25 to 2 cells), g chosen as the one whose
 *      union has the least outside + missed volume.
 * The union stays within about g cells of the surface (the variational
 * fit this replaced left 15-25 % of the solid's volume outside at every N).
 * The approximation error (outside and missed volume of the union, as shares
 * of the solid's volume) is measured on the same grid and reported.
 * Results are cached per context by (mesh hash, N). */
#include "assets/assets.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#define PN_SPHERES_MAX 65536u
#define CACHE_SLOTS 32

/* ------------------------------------------------------------------ object */

static pn_status check_attach(const pn_object *asset, pn_scene scene, uint32_t instance)
{
    const struct pn_sphere_set_impl *s = (const struct pn_sphere_set_impl *)asset;
    pn_context ctx = scene->obj.ctx;
    if (instance == PN_WHOLE_SCENE)
        return pn_fail(ctx, PN_ERROR_INVALID_ARGUMENT,
                       "pn_scene_attach: a sphere set attaches to an instance, not to the whole scene");
    const pn_mesh mesh = pn_scene_instance(scene, instance)->mesh;
    if (s->mesh_hash && mesh->content_hash != s->mesh_hash)
        return pn_fail(ctx, PN_ERROR_INVALID_ARGUMENT,
                       "pn_scene_attach: the sphere set was built for mesh %016llx but instance %u's mesh is %016llx: "
                       "build a set for that mesh (sets given by the caller attach anywhere)",
                       (unsigned long long)s->mesh_hash, instance, (unsigned long long)mesh->content_hash);
    return PN_SUCCESS;
}

static void destroy_set(pn_object *o)
{
    pn_sphere_set s = (pn_sphere_set)o;
    free(s->spheres), free(s->anchor_ids), free(s->anchor_weights), free(s->rest_spread), free(s->rest_radius);
}

static const pn_object_type sphere_set_type = {PN_MAGIC_SPHERES, "sphere set", destroy_set, check_attach};

static pn_status new_set(pn_context ctx, const float *spheres, uint32_t count, pn_sphere_set *out)
{
    float *copy = pn_malloc(ctx, pn_mul_size(count, 4, sizeof(float)), "a sphere set");
    if (!copy)
        return PN_ERROR_OUT_OF_MEMORY;
    pn_sphere_set s = pn_object_new(ctx, sizeof *s, &sphere_set_type, "a sphere set");
    if (!s) {
        free(copy);
        return PN_ERROR_OUT_OF_MEMORY;
    }
    memcpy(copy, spheres, (size_t)count * 4 * sizeof(float));
    s->spheres = copy;
    s->count = count;
    s->outside_share = s->missed_share = NAN;
    *out = s;
    return PN_SUCCESS;
}

pn_status pn_sphere_set_do_create(pn_context ctx, const float *spheres, uint32_t count, pn_sphere_set *out)
{
    if (count == 0 || count > PN_SPHERES_MAX)
        return pn_fail(ctx, count ? PN_ERROR_INVALID_SIZE : PN_ERROR_EMPTY_INPUT,
                       "pn_sphere_set_create: %u spheres (1 to %u are allowed)", count, PN_SPHERES_MAX);
    uint32_t bad = 0, first = 0;
    for (uint32_t i = 0; i < count; ++i) {
        const float *p = spheres + 4 * i;
        const bool ok = isfinite(p[0]) && isfinite(p[1]) && isfinite(p[2]) && isfinite(p[3]) && p[3] > 0.0f;
        if (!ok && bad++ == 0)
            first = i;
    }
    if (bad) {
        const float *p = spheres + 4 * first;
        return pn_fail(ctx, PN_ERROR_INVALID_VALUE,
                       "pn_sphere_set_create: %u of %u spheres have a non-finite centre or a radius that is not a "
                       "finite positive number; the first is sphere %u (%g, %g, %g, radius %g)",
                       bad, count, first, (double)p[0], (double)p[1], (double)p[2], (double)p[3]);
    }
    return new_set(ctx, spheres, count, out);
}

pn_status pn_sphere_set_do_create_shell(pn_context ctx, pn_sphere_set *out)
{
    const float none[4] = {0.0f, 0.0f, 0.0f, 1.0f}; /* new_set copies one sphere's room; count 0 */
    pn_status st = new_set(ctx, none, 1, out);
    if (!st)
        (*out)->count = 0, (*out)->shell = true;
    return st;
}

void pn_sphere_set_fill_info(pn_sphere_set s, pn_sphere_set_info *info)
{
    memset(info, 0, sizeof *info);
    info->count = s->count;
    info->grid = s->grid;
    info->mesh_hash = s->mesh_hash;
    info->mesh_volume = s->mesh_volume;
    info->outside_share = s->outside_share;
    info->missed_share = s->missed_share;
    info->build_seconds = s->build_seconds;
    info->skin = s->skin;
}

pn_status pn_sphere_set_do_read(pn_sphere_set s, float *host, size_t bytes)
{
    const size_t need = (size_t)s->count * 4 * sizeof(float);
    if (bytes != need)
        return pn_fail(s->obj.ctx, PN_ERROR_INVALID_SIZE, "reading a sphere set of %u spheres needs exactly %zu bytes, "
                       "got %zu", s->count, need, bytes);
    memcpy(host, s->spheres, need);
    return PN_SUCCESS;
}

/* ------------------------------------------------------------ voxelisation */

typedef struct grid {
    int n[3];        /* cells per axis */
    float lo[3], h;  /* corner of cell (0,0,0), cell size */
    uint8_t *inside; /* n0 n1 n2 cells, x fastest */
} grid;

static size_t cell_index(const grid *g, int i, int j, int k)
{
    return ((size_t)k * (size_t)g->n[1] + (size_t)j) * (size_t)g->n[0] + (size_t)i;
}

static int cmp_float(const void *a, const void *b)
{
    const float x = *(const float *)a, y = *(const float *)b;
    return (x > y) - (x < y);
}

/* Adds one vote to every cell whose centre has an odd number of surface
 * crossings before it along axis `a` (rows over the other two axes). */
static pn_status vote_axis(pn_context ctx, const grid *g, pn_mesh mesh, int a, uint8_t *votes)
{
    const int b = (a + 1) % 3, c = (a + 2) % 3, nb = g->n[b], nc = g->n[c];
    const size_t rows = (size_t)nb * (size_t)nc;
    uint32_t *start = calloc(rows + 1, sizeof *start);
    if (!start)
        return pn_fail(ctx, PN_ERROR_OUT_OF_MEMORY, "out of memory voxelising a mesh for a sphere set");
    /* Row centres are shifted by an irrational share of a cell, so a row
     * passing exactly through a mesh edge or vertex is not a practical case. */
    const float shift = 0.5f + 0.0137f * (float)(a + 1);
    float *xs = NULL;
    for (int pass = 0; pass < 2; ++pass) {
        uint32_t *fill = NULL;
        if (pass == 1) {
            for (size_t r = 0; r < rows; ++r)
                start[r + 1] += start[r];
            xs = malloc((size_t)(start[rows] ? start[rows] : 1) * sizeof *xs);
            fill = calloc(rows, sizeof *fill);
            if (!xs || !fill) {
                free(xs);
                free(fill);
                free(start);
                return pn_fail(ctx, PN_ERROR_OUT_OF_MEMORY, "out of memory voxelising a mesh for a sphere set");
            }
        }
        for (uint32_t t = 0; t < mesh->triangle_count; ++t) {
            const uint32_t *idx = mesh->indices + 3 * t;
            const float *v[3] = {mesh->positions + 3 * idx[0], mesh->positions + 3 * idx[1],
                                 mesh->positions + 3 * idx[2]};
            float bmin = INFINITY, bmax = -INFINITY, cmin = INFINITY, cmax = -INFINITY;
            for (int q = 0; q < 3; ++q) {
                bmin = fminf(bmin, v[q][b]), bmax = fmaxf(bmax, v[q][b]);
                cmin = fminf(cmin, v[q][c]), cmax = fmaxf(cmax, v[q][c]);
            }
            const int j0 = (int)ceilf((bmin - g->lo[b]) / g->h - shift), j1 = (int)floorf((bmax - g->lo[b]) / g->h - shift);
            const int k0 = (int)ceilf((cmin - g->lo[c]) / g->h - shift), k1 = (int)floorf((cmax - g->lo[c]) / g->h - shift);
            const double e1b = v[1][b] - v[0][b], e1c = v[1][c] - v[0][c], e2b = v[2][b] - v[0][b],
                         e2c = v[2][c] - v[0][c];
            const double det = e1b * e2c - e1c * e2b;
            if (det == 0.0)
                continue; /* seen edge-on along this axis: no crossing */
            for (int k = k0 > 0 ? k0 : 0; k <= k1 && k < nc; ++k)
                for (int j = j0 > 0 ? j0 : 0; j <= j1 && j < nb; ++j) {
                    const double pb = g->lo[b] + ((double)j + shift) * g->h - v[0][b];
                    const double pc = g->lo[c] + ((double)k + shift) * g->h - v[0][c];
                    const double u = (pb * e2c - pc * e2b) / det, w = (e1b * pc - e1c * pb) / det;
                    if (u < 0.0 || w < 0.0 || u + w > 1.0)
                        continue;
                    const size_t row = (size_t)k * (size_t)nb + (size_t)j;
                    if (pass == 0)
                        start[row + 1]++;
                    else
                        xs[start[row] + fill[row]++] =
                            (float)(v[0][a] + u * (v[1][a] - v[0][a]) + w * (v[2][a] - v[0][a]));
                }
        }
        free(fill);
    }
    for (int k = 0; k < nc; ++k)
        for (int j = 0; j < nb; ++j) {
            const size_t row = (size_t)k * (size_t)nb + (size_t)j;
            float *x = xs + start[row];
            const uint32_t m = start[row + 1] - start[row];
            if (m < 2)
                continue;
            qsort(x, m, sizeof *x, cmp_float);
            uint32_t seen = 0;
            for (int i = 0; i < g->n[a]; ++i) {
                const float centre = g->lo[a] + ((float)i + 0.5f) * g->h;
                while (seen < m && x[seen] < centre)
                    ++seen;
                if (seen & 1u) {
                    int ijk[3];
                    ijk[a] = i, ijk[b] = j, ijk[c] = k;
                    votes[cell_index(g, ijk[0], ijk[1], ijk[2])]++;
                }
            }
        }
    free(xs);
    free(start);
    return PN_SUCCESS;
}

/* The mesh's interior on a grid of `res` cells along its longest side. */
static pn_status voxelise(pn_context ctx, pn_mesh mesh, int res, grid *g)
{
    float ext = 0.0f;
    for (int a = 0; a < 3; ++a)
        ext = fmaxf(ext, mesh->bounds_hi[a] - mesh->bounds_lo[a]);
    g->h = ext / (float)res;
    /* A margin of a quarter of the longest side: a sphere that pokes out of
     * the bounds must still pay for the outside volume it covers. */
    const int pad = 2 + res / 4;
    for (int a = 0; a < 3; ++a) {
        g->n[a] = (int)ceilf((mesh->bounds_hi[a] - mesh->bounds_lo[a]) / g->h) + 2 * pad;
        g->lo[a] = mesh->bounds_lo[a] - (float)pad * g->h;
    }
    const size_t cells = (size_t)g->n[0] * (size_t)g->n[1] * (size_t)g->n[2];
    g->inside = calloc(cells, 1);
    if (!g->inside)
        return pn_fail(ctx, PN_ERROR_OUT_OF_MEMORY, "out of memory voxelising a mesh for a sphere set");
    pn_status st = PN_SUCCESS;
    for (int a = 0; a < 3 && !st; ++a)
        st = vote_axis(ctx, g, mesh, a, g->inside);
    for (size_t i = 0; i < cells; ++i)
        g->inside[i] = g->inside[i] >= 2;
    return st;
}

/* ------------------------------------------------------------- clustering */

static float dist2(const float *p, const float *q)
{
    const float dx = p[0] - q[0], dy = p[1] - q[1], dz = p[2] - q[2];
    return dx * dx + dy * dy + dz * dz;
}

/* One line of the squared Euclidean distance transform (Felzenszwalb and
 * Huttenlocher 2012): d[q] = min_p (q - p)^2 + f[p], the lower envelope of
 * parabolas; v and z are scratch of n and n + 1 entries. */
static void edt_line(const double *f, int n, double *d, int *v, double *z)
{
    int k = 0;
    v[0] = 0, z[0] = -HUGE_VAL, z[1] = HUGE_VAL;
    for (int q = 1; q < n; ++q) {
        double s;
        for (;;) {
            const int p = v[k];
            s = ((f[q] + (double)q * q) - (f[p] + (double)p * p)) / (2.0 * (double)(q - p));
            if (s > z[k])
                break;
            --k; /* z[0] = -inf ends this at k = 0 */
        }
        ++k;
        v[k] = q, z[k] = s, z[k + 1] = HUGE_VAL;
    }
    k = 0;
    for (int q = 0; q < n; ++q) {
        while (z[k + 1] < (double)q)
            ++k;
        d[q] = (double)(q - v[k]) * (double)(q - v[k]) + f[v[k]];
    }
}

/* dist[c]: distance in cells from the centre of interior cell c to the
 * nearest outside cell centre (0 outside). Every grid row ends in outside
 * cells (the padding), so every value is finite. */
static pn_status outside_distance(pn_context ctx, const grid *g, float *dist)
{
    const int nmax = g->n[0] > g->n[1] ? (g->n[0] > g->n[2] ? g->n[0] : g->n[2]) : (g->n[1] > g->n[2] ? g->n[1] : g->n[2]);
    const size_t cells = (size_t)g->n[0] * (size_t)g->n[1] * (size_t)g->n[2];
    double *sq = malloc(cells * sizeof *sq), *f = malloc((size_t)nmax * sizeof *f), *d = malloc((size_t)nmax * sizeof *d);
    double *z = malloc(((size_t)nmax + 1) * sizeof *z);
    int *v = malloc((size_t)nmax * sizeof *v);
    if (!sq || !f || !d || !z || !v) {
        free(sq), free(f), free(d), free(z), free(v);
        return pn_fail(ctx, PN_ERROR_OUT_OF_MEMORY, "out of memory measuring distances for a sphere set");
    }
    for (size_t i = 0; i < cells; ++i)
        sq[i] = g->inside[i] ? 1e12 : 0.0;
    const size_t stride[3] = {1, (size_t)g->n[0], (size_t)g->n[0] * (size_t)g->n[1]};
    for (int a = 0; a < 3; ++a) {
        const int b = (a + 1) % 3, c = (a + 2) % 3;
        for (int k = 0; k < g->n[c]; ++k)
            for (int j = 0; j < g->n[b]; ++j) {
                double *line = sq + (size_t)j * stride[b] + (size_t)k * stride[c];
                for (int i = 0; i < g->n[a]; ++i)
                    f[i] = line[(size_t)i * stride[a]];
                edt_line(f, g->n[a], d, v, z);
                for (int i = 0; i < g->n[a]; ++i)
                    line[(size_t)i * stride[a]] = d[i];
            }
    }
    for (size_t i = 0; i < cells; ++i)
        dist[i] = (float)sqrt(sq[i]);
    free(sq), free(f), free(d), free(z), free(v);
    return PN_SUCCESS;
}

/* ------------------------------------------------- greedy inscribed cover */

typedef struct candidate {
    int c[3];    /* cell */
    float r;     /* inscribed radius, cells (distance to the surface) */
} candidate;

typedef struct heap_item {
    uint32_t gain; /* an upper bound of the interior cells it would newly cover */
    uint32_t id;
} heap_item;

static bool heap_before(heap_item a, heap_item b)
{
    return a.gain != b.gain ? a.gain > b.gain : a.id < b.id;
}

static void heap_push(heap_item *h, size_t *n, heap_item x)
{
    size_t i = (*n)++;
    while (i > 0 && heap_before(x, h[(i - 1) / 2])) {
        h[i] = h[(i - 1) / 2];
        i = (i - 1) / 2;
    }
    h[i] = x;
}

static heap_item heap_pop(heap_item *h, size_t *n)
{
    const heap_item top = h[0], x = h[--*n];
    size_t i = 0;
    for (;;) {
        size_t l = 2 * i + 1, best = i;
        heap_item bx = x;
        if (l < *n && heap_before(h[l], bx))
            best = l, bx = h[l];
        if (l + 1 < *n && heap_before(h[l + 1], bx))
            best = l + 1;
        if (best == i)
            break;
        h[i] = h[best];
        i = best;
    }
    if (*n)
        h[i] = x;
    return top;
}

/* The interior cells not yet covered, as prefix sums along each row of x
 * (n0 + 1 per row): a ball's gain is one difference per row it crosses, so
 * a re-evaluation costs O(r^2) rather than O(r^3) (a round solid's many big
 * near-centre balls are each re-evaluated after the first pick). */
typedef struct cover_state {
    uint8_t *covered;  /* n0 n1 n2 cells */
    uint16_t *prefix;  /* (n0 + 1) n1 n2; a row holds at most 216 * 3 / 2 cells */
} cover_state;

static void row_prefix(const grid *g, const cover_state *cs, int y, int z)
{
    const size_t row = (size_t)z * (size_t)g->n[1] + (size_t)y;
    const size_t c0 = row * (size_t)g->n[0];
    uint16_t *p = cs->prefix + row * (size_t)(g->n[0] + 1);
    uint16_t sum = 0;
    p[0] = 0;
    for (int x = 0; x < g->n[0]; ++x) {
        sum = (uint16_t)(sum + (g->inside[c0 + (size_t)x] && !cs->covered[c0 + (size_t)x]));
        p[x + 1] = sum;
    }
}

/* The half-width in x of the ball's row at (dy, dz): the largest dx <= k with
 * (float)(s + dx^2) <= r2, s = dy^2 + dz^2 (the cells the per-cell test
 * admits, exactly), or -1. */
static int row_half_width(int s, float r2, int k)
{
    int dx = (int)sqrtf(fmaxf(r2 - (float)s, 0.0f));
    if (dx > k)
        dx = k;
    while (dx < k && (float)(s + (dx + 1) * (dx + 1)) <= r2)
        ++dx;
    while (dx >= 0 && (float)(s + dx * dx) > r2)
        --dx;
    return dx;
}

/* Interior cells whose centre lies within `r` cells of cell `c`: counted
 * where not yet covered (mark 0), or marked covered (mark 1). */
static uint32_t ball_cells(const grid *g, cover_state *cs, const int *c, float r, int mark)
{
    const int k = (int)floorf(r);
    const float r2 = r * r;
    uint32_t count = 0;
    for (int dz = -k; dz <= k; ++dz) {
        const int z = c[2] + dz;
        if (z < 0 || z >= g->n[2])
            continue;
        for (int dy = -k; dy <= k; ++dy) {
            const int y = c[1] + dy;
            if (y < 0 || y >= g->n[1])
                continue;
            const int w = row_half_width(dz * dz + dy * dy, r2, k);
            if (w < 0)
                continue;
            const int x0 = c[0] - w < 0 ? 0 : c[0] - w, x1 = c[0] + w >= g->n[0] ? g->n[0] - 1 : c[0] + w;
            if (x0 > x1)
                continue;
            const size_t row = (size_t)z * (size_t)g->n[1] + (size_t)y;
            if (mark) {
                memset(cs->covered + row * (size_t)g->n[0] + (size_t)x0, 1, (size_t)(x1 - x0 + 1));
                row_prefix(g, cs, y, z);
            } else {
                const uint16_t *p = cs->prefix + row * (size_t)(g->n[0] + 1);
                count += (uint32_t)(p[x1 + 1] - p[x0]);
            }
        }
    }
    return count;
}

/* Picks `count` of the candidate balls (radius r + grow cells) greedily, each
 * the one covering most interior cells not yet covered (lazy evaluation: a
 * ball's gain only falls as others are chosen). Writes the chosen ids. */
static void greedy_cover(const grid *g, const candidate *cand, size_t nc, float grow, uint32_t count,
                         cover_state *cs, heap_item *heap, uint32_t *chosen)
{
    const size_t cells = (size_t)g->n[0] * (size_t)g->n[1] * (size_t)g->n[2];
    memset(cs->covered, 0, cells);
    for (int z = 0; z < g->n[2]; ++z)
        for (int y = 0; y < g->n[1]; ++y)
            row_prefix(g, cs, y, z);
    size_t n = 0;
    for (size_t i = 0; i < nc; ++i) {
        const double r = fmax((double)cand[i].r + grow, 0.5) + 0.8660254;
        const double bound = 4.18879020 * r * r * r + 1.0; /* the cells within r + sqrt(3)/2 */
        heap_push(heap, &n, (heap_item){bound > 4e9 ? 4000000000u : (uint32_t)bound, (uint32_t)i});
    }
    uint32_t got = 0;
    while (got < count && n) {
        heap_item top = heap_pop(heap, &n);
        const candidate *c = cand + top.id;
        const float r = fmaxf(c->r + grow, 0.5f);
        top.gain = ball_cells(g, cs, c->c, r, 0);
        if (n == 0 || !heap_before(heap[0], top)) {
            ball_cells(g, cs, c->c, r, 1);
            chosen[got++] = top.id;
        } else {
            heap_push(heap, &n, top);
        }
    }
}

/* Outside and missed shares of the union of `spheres` on the grid. */
static void union_error(const grid *g, const float *spheres, uint32_t count, uint8_t *covered, float *outside,
                        float *missed, size_t *interior)
{
    const size_t cells = (size_t)g->n[0] * (size_t)g->n[1] * (size_t)g->n[2];
    memset(covered, 0, cells);
    for (uint32_t s = 0; s < count; ++s) {
        const float *c = spheres + 4 * s;
        int lo[3], hi[3];
        for (int a = 0; a < 3; ++a) {
            lo[a] = (int)floorf((c[a] - c[3] - g->lo[a]) / g->h);
            hi[a] = (int)ceilf((c[a] + c[3] - g->lo[a]) / g->h);
            lo[a] = lo[a] < 0 ? 0 : lo[a];
            hi[a] = hi[a] >= g->n[a] ? g->n[a] - 1 : hi[a];
        }
        for (int k = lo[2]; k <= hi[2]; ++k)
            for (int j = lo[1]; j <= hi[1]; ++j)
                for (int i = lo[0]; i <= hi[0]; ++i) {
                    const float p[3] = {g->lo[0] + ((float)i + 0.5f) * g->h, g->lo[1] + ((float)j + 0.5f) * g->h,
                                        g->lo[2] + ((float)k + 0.5f) * g->h};
                    if (dist2(p, c) <= c[3] * c[3])
                        covered[cell_index(g, i, j, k)] = 1;
                }
    }
    size_t out = 0, miss = 0, in = 0;
    for (size_t i = 0; i < cells; ++i) {
        in += g->inside[i];
        out += covered[i] && !g->inside[i];
        miss += g->inside[i] && !covered[i];
    }
    *interior = in;
    *outside = (float)((double)out / (double)in);
    *missed = (float)((double)miss / (double)in);
}

/* ------------------------------------------------------------------ cache */

typedef struct cached_set {
    uint64_t mesh_hash, serial;
    uint32_t count, grid;
    float *spheres;
    float mesh_volume, outside_share, missed_share, skin;
    double build_seconds;
} cached_set;

typedef struct set_cache {
    cached_set slot[CACHE_SLOTS];
    uint64_t serial;
} set_cache;

static const char cache_key = 0;

static void free_cache(void *data)
{
    set_cache *c = data;
    for (int i = 0; i < CACHE_SLOTS; ++i)
        free(c->slot[i].spheres);
    free(c);
}

static set_cache *the_cache(pn_context ctx)
{
    set_cache *c = pn_context_cache(ctx, &cache_key);
    if (c)
        return c;
    if (!(c = calloc(1, sizeof *c)))
        return NULL;
    if (pn_context_set_cache(ctx, &cache_key, c, free_cache)) {
        free(c);
        pn_error_clear(ctx); /* a full cache table only costs the caching */
        return NULL;
    }
    return c;
}

static void remember(pn_context ctx, pn_sphere_set s)
{
    set_cache *c = the_cache(ctx);
    if (!c)
        return;
    int victim = 0;
    for (int i = 1; i < CACHE_SLOTS; ++i)
        if (c->slot[i].serial < c->slot[victim].serial)
            victim = i;
    float *copy = malloc((size_t)s->count * 4 * sizeof *copy);
    if (!copy)
        return;
    memcpy(copy, s->spheres, (size_t)s->count * 4 * sizeof *copy);
    cached_set *e = &c->slot[victim];
    free(e->spheres);
    *e = (cached_set){s->mesh_hash, ++c->serial, s->count, s->grid, copy, s->mesh_volume, s->outside_share,
                      s->missed_share, s->skin, s->build_seconds};
}

static bool recall(pn_context ctx, uint64_t mesh_hash, uint32_t count, pn_sphere_set *out, pn_status *st)
{
    set_cache *c = pn_context_cache(ctx, &cache_key);
    for (int i = 0; c && i < CACHE_SLOTS; ++i) {
        cached_set *e = &c->slot[i];
        if (!e->spheres || e->mesh_hash != mesh_hash || e->count != count)
            continue;
        if ((*st = new_set(ctx, e->spheres, count, out)))
            return true;
        pn_sphere_set s = *out;
        s->mesh_hash = mesh_hash, s->grid = e->grid, s->mesh_volume = e->mesh_volume;
        s->outside_share = e->outside_share, s->missed_share = e->missed_share, s->skin = e->skin;
        s->build_seconds = e->build_seconds;
        e->serial = ++c->serial;
        return true;
    }
    return false;
}

/* ------------------------------------------------------------- deformation */

/* Solves the 4 x 4 system m x = b in place (partial pivoting); false when singular. */
static bool solve4(double m[4][4], double b[4])
{
    for (int c = 0; c < 4; ++c) {
        int piv = c;
        for (int r = c + 1; r < 4; ++r)
            if (fabs(m[r][c]) > fabs(m[piv][c]))
                piv = r;
        if (fabs(m[piv][c]) < 1e-12)
            return false;
        for (int k = 0; k < 4; ++k) {
            const double t = m[c][k];
            m[c][k] = m[piv][k], m[piv][k] = t;
        }
        const double tb = b[c];
        b[c] = b[piv], b[piv] = tb;
        for (int r = 0; r < 4; ++r) {
            if (r == c)
                continue;
            const double f = m[r][c] / m[c][c];
            for (int k = c; k < 4; ++k)
                m[r][k] -= f * m[c][k];
            b[r] -= f * b[c];
        }
    }
    for (int c = 0; c < 4; ++c)
        b[c] /= m[c][c];
    return true;
}

/* Anchors of every sphere: its PN_SPHERE_ANCHORS nearest vertices and the
 * least-norm affine weights (sum w = 1, sum w v = centre, exactly); when
 * those vertices are coplanar, inverse-distance weights (the centre then
 * follows approximately). */
static pn_status make_anchors(pn_context ctx, pn_sphere_set s, pn_mesh mesh)
{
    const uint32_t k = PN_SPHERE_ANCHORS, nv = mesh->vertex_count;
    if (nv < k)
        return PN_SUCCESS; /* too few vertices to anchor: the set cannot deform */
    s->anchor_ids = malloc((size_t)s->count * k * sizeof *s->anchor_ids);
    s->anchor_weights = malloc((size_t)s->count * k * sizeof *s->anchor_weights);
    s->rest_spread = malloc((size_t)s->count * sizeof *s->rest_spread);
    s->rest_radius = malloc((size_t)s->count * sizeof *s->rest_radius);
    if (!s->anchor_ids || !s->anchor_weights || !s->rest_spread || !s->rest_radius)
        return pn_fail(ctx, PN_ERROR_OUT_OF_MEMORY, "out of memory anchoring a sphere set");
    for (uint32_t i = 0; i < s->count; ++i) {
        const float *c = s->spheres + 4 * i;
        uint32_t *ids = s->anchor_ids + (size_t)i * k;
        /* The nearest vertex in each octant around the centre, then the
         * nearest others: the k nearest alone can be one planar ring (a
         * centre on the axis of a tube), which no affine weights can follow
         * off that plane. */
        float best[PN_SPHERE_ANCHORS], near_d[PN_SPHERE_ANCHORS], oct_d[8];
        uint32_t near_id[PN_SPHERE_ANCHORS], oct_id[8];
        for (uint32_t j = 0; j < k; ++j)
            near_d[j] = INFINITY, near_id[j] = 0;
        for (int o = 0; o < 8; ++o)
            oct_d[o] = INFINITY, oct_id[o] = 0;
        for (uint32_t v = 0; v < nv; ++v) {
            const float *p = mesh->positions + 3 * v;
            const float d = dist2(p, c);
            const int o = (p[0] > c[0]) | (p[1] > c[1]) << 1 | (p[2] > c[2]) << 2;
            if (d < oct_d[o])
                oct_d[o] = d, oct_id[o] = v;
            if (d >= near_d[k - 1])
                continue;
            uint32_t j = k - 1; /* insertion into the k nearest */
            while (j > 0 && near_d[j - 1] > d) {
                near_d[j] = near_d[j - 1], near_id[j] = near_id[j - 1];
                --j;
            }
            near_d[j] = d, near_id[j] = v;
        }
        uint32_t got = 0;
        for (int o = 0; o < 8 && got < k; ++o)
            if (oct_d[o] < INFINITY)
                best[got] = oct_d[o], ids[got++] = oct_id[o];
        for (uint32_t j = 0; j < k && got < k; ++j) {
            bool taken = false;
            for (uint32_t q = 0; q < got; ++q)
                taken |= ids[q] == near_id[j];
            if (!taken)
                best[got] = near_d[j], ids[got++] = near_id[j];
        }
        /* w = A^T (A A^T)^-1 b with A = [v_j; 1] (4 x k), b = [c; 1]. */
        double a[4][PN_SPHERE_ANCHORS], aat[4][4], b[4] = {c[0], c[1], c[2], 1.0};
        for (uint32_t j = 0; j < k; ++j) {
            const float *v = mesh->positions + 3 * ids[j];
            a[0][j] = v[0] - c[0], a[1][j] = v[1] - c[1], a[2][j] = v[2] - c[2], a[3][j] = 1.0;
        }
        b[0] = b[1] = b[2] = 0.0; /* centred on c: better conditioned */
        for (int r = 0; r < 4; ++r)
            for (int q = 0; q < 4; ++q) {
                aat[r][q] = 0.0;
                for (uint32_t j = 0; j < k; ++j)
                    aat[r][q] += a[r][j] * a[q][j];
            }
        float *w = s->anchor_weights + (size_t)i * k;
        /* Coplanar anchors (a centre on the axis of a ring of vertices, as
         * inscribed spheres often are) make A A^T singular, or nearly so in
         * float, while the centre is still their affine combination: a ridge
         * of 1e-9 of the trace gives the least-norm weights then, and
         * changes well-posed ones by far less than float rounding (the
         * residual is checked). */
        double ridged[4][4], rb[4] = {b[0], b[1], b[2], b[3]};
        const double ridge = 1e-9 * (aat[0][0] + aat[1][1] + aat[2][2] + aat[3][3]);
        for (int r = 0; r < 4; ++r)
            for (int q = 0; q < 4; ++q)
                ridged[r][q] = aat[r][q] + (r == q ? ridge : 0.0);
        bool ok = false;
        if (solve4(ridged, rb)) {
            double res[3] = {0, 0, 0}, sum = 0.0, scale = 0.0;
            for (uint32_t j = 0; j < k; ++j) {
                const double wj = a[0][j] * rb[0] + a[1][j] * rb[1] + a[2][j] * rb[2] + a[3][j] * rb[3];
                sum += wj, scale += sqrt((double)best[j]);
                for (int q = 0; q < 3; ++q)
                    res[q] += wj * a[q][j];
            }
            ok = fabs(sum - 1.0) < 1e-4 && sqrt(res[0] * res[0] + res[1] * res[1] + res[2] * res[2]) < 1e-4 * scale / k;
            memcpy(b, rb, sizeof b);
        }
        if (ok) {
            for (uint32_t j = 0; j < k; ++j)
                w[j] = (float)(a[0][j] * b[0] + a[1][j] * b[1] + a[2][j] * b[2] + a[3][j] * b[3]);
        } else {
            double sum = 0.0;
            for (uint32_t j = 0; j < k; ++j)
                sum += 1.0 / (sqrt((double)best[j]) + 1e-12);
            for (uint32_t j = 0; j < k; ++j)
                w[j] = (float)(1.0 / (sqrt((double)best[j]) + 1e-12) / sum);
        }
        double spread = 0.0;
        for (uint32_t j = 0; j < k; ++j)
            spread += sqrt((double)best[j]);
        s->rest_spread[i] = (float)(spread / k);
        s->rest_radius[i] = c[3];
    }
    s->vertex_count = nv;
    return PN_SUCCESS;
}

pn_status pn_sphere_set_do_deform(pn_sphere_set s, pn_mesh mesh)
{
    pn_context ctx = s->obj.ctx;
    if (s->shell) /* a shell's triangles are its instance's mesh: they follow it already */
        return PN_SUCCESS;
    if (!s->anchor_ids)
        return pn_fail(ctx, PN_ERROR_INVALID_ARGUMENT,
                       "pn_sphere_set_deform: the set was not built from a mesh (or its mesh has fewer than %d "
                       "vertices): it has no vertex anchors to follow",
                       PN_SPHERE_ANCHORS);
    if (!mesh->committed)
        return pn_fail(ctx, PN_ERROR_NOT_COMMITTED, "pn_sphere_set_deform: the mesh is not committed");
    if (mesh->vertex_count != s->vertex_count)
        return pn_fail(ctx, PN_ERROR_INVALID_SIZE,
                       "pn_sphere_set_deform: the mesh has %u vertices but the set was built on %u: a deformed "
                       "mesh keeps its vertices (new positions only)",
                       mesh->vertex_count, s->vertex_count);
    const uint32_t k = PN_SPHERE_ANCHORS;
    for (uint32_t i = 0; i < s->count; ++i) {
        const uint32_t *ids = s->anchor_ids + (size_t)i * k;
        const float *w = s->anchor_weights + (size_t)i * k;
        double c[3] = {0, 0, 0};
        for (uint32_t j = 0; j < k; ++j)
            for (int a = 0; a < 3; ++a)
                c[a] += (double)w[j] * mesh->positions[3 * ids[j] + a];
        float *o = s->spheres + 4 * i;
        o[0] = (float)c[0], o[1] = (float)c[1], o[2] = (float)c[2];
        double spread = 0.0;
        for (uint32_t j = 0; j < k; ++j)
            spread += sqrt(dist2(mesh->positions + 3 * ids[j], o));
        const float scale = s->rest_spread[i] > 0.0f ? (float)(spread / k) / s->rest_spread[i] : 1.0f;
        o[3] = s->rest_radius[i] * scale;
    }
    s->mesh_hash = mesh->content_hash; /* it now describes the deformed mesh */
    return PN_SUCCESS;
}

/* ------------------------------------------------------------------ build */

pn_status pn_sphere_set_do_build(pn_mesh mesh, uint32_t count, pn_sphere_set *out)
{
    pn_context ctx = mesh->obj.ctx;
    if (!mesh->committed)
        return pn_fail(ctx, PN_ERROR_NOT_COMMITTED, "pn_sphere_set_build: the mesh is not committed");
    if (count < 1 || count > 4096)
        return pn_fail(ctx, PN_ERROR_INVALID_ARGUMENT, "pn_sphere_set_build: %u spheres asked for (1 to 4096)", count);
    pn_status st = PN_SUCCESS;
    if (recall(ctx, mesh->content_hash, count, out, &st))
    {
        if (!st && (st = make_anchors(ctx, *out, mesh))) {
            PN_RELEASE(*out);
            *out = NULL;
        }
        return st;
    }
    const clock_t t0 = clock();
    float ext_min = INFINITY;
    for (int a = 0; a < 3; ++a)
        ext_min = fminf(ext_min, mesh->bounds_hi[a] - mesh->bounds_lo[a]);
    if (!(ext_min > 0.0f))
        return pn_fail(ctx, PN_ERROR_EMPTY_INPUT,
                       "pn_sphere_set_build: the mesh is flat (zero extent along an axis) and encloses no volume");
    /* The grid grows until every sphere gets >= 16 interior cells. */
    grid g = {{0, 0, 0}, {0, 0, 0}, 0, NULL};
    size_t np = 0;
    for (int res = 64;; res = res * 3 / 2) {
        free(g.inside);
        if ((st = voxelise(ctx, mesh, res, &g))) {
            free(g.inside);
            return st;
        }
        np = 0;
        const size_t cells = (size_t)g.n[0] * (size_t)g.n[1] * (size_t)g.n[2];
        for (size_t i = 0; i < cells; ++i)
            np += g.inside[i];
        if (np >= 16u * (size_t)count || res >= 216)
            break;
    }
    if (np < count) {
        free(g.inside);
        return pn_fail(ctx, PN_ERROR_EMPTY_INPUT,
                       "pn_sphere_set_build: the mesh encloses %zu interior voxels, fewer than the %u spheres asked "
                       "for: it is open, flat or degenerate (a sphere set needs a solid)",
                       np, count);
    }
    const size_t cells = (size_t)g.n[0] * (size_t)g.n[1] * (size_t)g.n[2];
    float *dist = malloc(cells * sizeof *dist), *spheres = malloc((size_t)count * 4 * sizeof *spheres);
    float *trial = malloc((size_t)count * 4 * sizeof *trial);
    candidate *cand = malloc(np * sizeof *cand);
    heap_item *heap = malloc(np * sizeof *heap);
    uint32_t *chosen = malloc((size_t)count * sizeof *chosen);
    uint8_t *covered = malloc(cells);
    uint16_t *prefix = malloc((size_t)(g.n[0] + 1) * (size_t)g.n[1] * (size_t)g.n[2] * sizeof *prefix);
    cover_state cs = {covered, prefix};
    if (!dist || !spheres || !trial || !cand || !heap || !chosen || !covered || !prefix) {
        st = pn_fail(ctx, PN_ERROR_OUT_OF_MEMORY, "out of memory building a sphere set");
        goto done;
    }
    if ((st = outside_distance(ctx, &g, dist)))
        goto done;
    /* Candidates: the interior cells whose inscribed ball is not inside a
     * neighbour's (about the medial axis); all interior cells when those are
     * fewer than the spheres asked for. */
    size_t nc = 0;
    for (int all = 0; all < 2 && nc < count; ++all) {
        nc = 0;
        for (int k = 1; k < g.n[2] - 1; ++k)
            for (int j = 1; j < g.n[1] - 1; ++j)
                for (int i = 1; i < g.n[0] - 1; ++i) {
                    const size_t ci = cell_index(&g, i, j, k);
                    if (!g.inside[ci])
                        continue;
                    bool dominated = false;
                    for (int o = 0; o < 27 && !all && !dominated; ++o) {
                        const int dx = o % 3 - 1, dy = o / 3 % 3 - 1, dz = o / 9 - 1;
                        if (o == 13)
                            continue;
                        const float len = sqrtf((float)(dx * dx + dy * dy + dz * dz));
                        dominated = dist[cell_index(&g, i + dx, j + dy, k + dz)] - dist[ci] >= len - 1e-4f;
                    }
                    if (!dominated)
                        cand[nc++] = (candidate){{i, j, k}, dist[ci] - 0.5f};
                }
    }
    /* The balls reach past the surface by `grow` cells: chosen per set as
     * the one whose union has the least outside + missed volume. */
    static const float grows[] = {-0.25f, 0.0f, 0.25f, 0.5f, 0.75f, 1.0f, 1.25f, 1.5f, 1.75f, 2.0f};
    float outside = 0.0f, missed = 0.0f, best = INFINITY, skin = 0.0f;
    size_t interior = 0;
    for (size_t t = 0; t < sizeof grows / sizeof grows[0]; ++t) {
        greedy_cover(&g, cand, nc, grows[t], count, &cs, heap, chosen);
        for (uint32_t q = 0; q < count; ++q) {
            const candidate *c = cand + chosen[q];
            for (int a = 0; a < 3; ++a)
                trial[4 * q + a] = g.lo[a] + ((float)c->c[a] + 0.5f) * g.h;
            trial[4 * q + 3] = fmaxf(c->r + grows[t], 0.5f) * g.h;
        }
        float o = 0.0f, m = 0.0f;
        union_error(&g, trial, count, covered, &o, &m, &interior);
        if (o + m < best) {
            best = o + m, outside = o, missed = m, skin = (fmaxf(grows[t], -0.5f) + 0.5f) * g.h;
            memcpy(spheres, trial, (size_t)count * 4 * sizeof *spheres);
        }
    }
    if ((st = new_set(ctx, spheres, count, out)))
        goto done;
    pn_sphere_set s = *out;
    s->mesh_hash = mesh->content_hash;
    s->grid = (uint32_t)(g.n[0] > g.n[1] ? (g.n[0] > g.n[2] ? g.n[0] : g.n[2]) : (g.n[1] > g.n[2] ? g.n[1] : g.n[2]));
    s->mesh_volume = (float)((double)interior * (double)g.h * (double)g.h * (double)g.h);
    s->outside_share = outside;
    s->missed_share = missed;
    s->skin = skin;
    s->build_seconds = (double)(clock() - t0) / CLOCKS_PER_SEC;
    remember(ctx, s);
    if ((st = make_anchors(ctx, s, mesh))) {
        PN_RELEASE(s);
        *out = NULL;
    }
done:
    free(dist), free(spheres), free(trial), free(cand), free(heap), free(chosen), free(covered), free(prefix), free(g.inside);
    return st;
}
