/* The assets layer: objects a technique attaches to a scene's instances
 * (pn_scene_attach) — occlusion fields (the fiv method's bake) and height
 * fields — with their options, bakes and files. */
#ifndef PENUMBRA_ASSETS_H
#define PENUMBRA_ASSETS_H

#include "geometry/geometry.h"

/* ------------------------------------------------------ occlusion fields */

struct pn_fiv_impl {
    pn_object obj;
    pn_fiv_options options;
    float centre[3], radius;  /* bounding sphere, object space */
    float inner, outer;       /* innermost and outermost sphere radii, object units */
    uint64_t mesh_hash, env_hash;
    uint32_t mesh_vertices, mesh_triangles;
    uint32_t radii_done;      /* spheres baked so far (a bake in progress) */
    float value_scale;        /* half storage holds value / value_scale */
    float outer_max;          /* largest |FIV| of a channel on the outer sphere (culling bound) */
    float *samples;           /* radii x theta x phi x 9 floats, NaN inside; rounded through half if stored so */
    uint64_t inside_count, rays;
    double bake_seconds;      /* the bake's wall time, resumed parts included */
};

/* The bake options as a parameter table (stage PN_PARAM_BAKE), in the order
 * of pn_fiv_options' fields: defaults, ranges and docs of the fiv method's
 * bake parameters. */
#define PN_FIV_BAKE_PARAM_COUNT 9
extern const pn_param_desc pn_fiv_bake_params[PN_FIV_BAKE_PARAM_COUNT];
pn_fiv_options pn_fiv_default_options(void);
pn_status pn_fiv_check_options(pn_context ctx, const pn_fiv_options *options);
/* NULL when the field's geometry and scales are usable numbers (centre
 * finite, 0 < inner < outer, radius and outer finite, the outermost sphere's
 * points representable, value_scale > 0, outer_max >= 0, all finite), else a
 * static phrase naming the first problem. The bake checks it before baking,
 * and the file reader and writer with every header, so the library never
 * writes a file its reader refuses. */
const char *pn_fiv_geometry_problem(const struct pn_fiv_impl *fiv);
pn_status pn_fiv_new(pn_context ctx, const pn_fiv_options *options, pn_fiv *out);
uint64_t pn_fiv_sample_count(const pn_fiv_options *options);
/* Radius of sphere k (geometric from inner to outer). */
float pn_fiv_radius(pn_fiv fiv, uint32_t k);
uint16_t pn_half_from_float(float value);
float pn_float_from_half(uint16_t half);
void pn_fiv_fill_info(pn_fiv fiv, pn_fiv_info *info);
pn_status pn_fiv_do_read(pn_fiv fiv, float *host, size_t bytes);
pn_status pn_fiv_do_bake(pn_envmap env, pn_mesh mesh, const pn_fiv_options *options, const char *path,
                         pn_progress_callback progress, void *user, pn_fiv *out);

/* Bake files (io/fiv_file.c). pn_fiv_read_file loads `path` into a new field;
 * with `partial` an unfinished bake is accepted. pn_fiv_read_file_header
 * fills only the header's fields into a field without samples. */
pn_status pn_fiv_read_file(pn_context ctx, const char *path, bool partial, pn_fiv *out);
pn_status pn_fiv_read_file_header(const char *path, pn_fiv_info *info);
pn_status pn_fiv_write_file(pn_fiv fiv, const char *path);

/* ------------------------------------------------------------ height fields */

#define PN_HF_HISTORY 16

struct pn_heightfield_impl {
    pn_object obj;
    uint32_t width, depth;    /* columns (x), rows (z) */
    float *heights;           /* width * depth, row-major */
    float *albedo;            /* width * depth * 3, or NULL (white) */
    pn_heightfield_placement placement;
    bool committed;
    uint64_t version;         /* a new pn_next_version() at each commit */
    float hmin, hmax;         /* of the heights, at commit */
    /* Local edits (pn_heightfield_set_heights_region), so that a renderer can
     * update only what they change. Boxes are (x0, y0, x1, y1), inclusive;
     * x0 > x1: empty. */
    bool regional;            /* has had region edits: renderers keep what partial updates need */
    bool edit_full;           /* an uncommitted change other than region edits */
    uint32_t edit_box[4];     /* uncommitted region edits */
    /* The last commits that were region edits only, newest first: the heights
     * of commit k's version differ from those of history_from[k] only in
     * history_box[k]. A commit with any other change empties it. */
    uint32_t history_count;
    uint64_t history_from[PN_HF_HISTORY];
    uint32_t history_box[PN_HF_HISTORY][4];
};

pn_status pn_heightfield_new(pn_context ctx, pn_heightfield *out);
pn_status pn_heightfield_do_set_heights(pn_heightfield hf, const float *heights, uint32_t width, uint32_t depth);
pn_status pn_heightfield_do_set_heights_region(pn_heightfield hf, uint32_t x0, uint32_t y0, uint32_t width,
                                               uint32_t depth, const float *heights);
/* Whether the committed heights differ from those of the field's committed
 * version `from` only inside `box` (x0, y0, x1, y1 inclusive; x0 > x1: no
 * change at all); false when that is not known (other changes, or an old
 * version). */
bool pn_heightfield_changed_since(pn_heightfield hf, uint64_t from, uint32_t box[4]);
pn_status pn_heightfield_do_set_placement(pn_heightfield hf, const pn_heightfield_placement *placement);
pn_status pn_heightfield_do_set_albedo(pn_heightfield hf, const float *rgb, size_t count);
pn_status pn_heightfield_do_commit(pn_heightfield hf);
pn_status pn_heightfield_do_build_mesh(pn_heightfield hf, pn_mesh *out);
/* Grid spacing of the committed field along x and z. */
void pn_heightfield_spacing(pn_heightfield hf, float *sx, float *sz);

/* ------------------------------------------------------------ sphere sets */

struct pn_sphere_set_impl {
    pn_object obj;
    float *spheres;           /* count x (centre xyz, radius), object space */
    uint32_t count;
    uint64_t mesh_hash;       /* the mesh it was built for; 0: given by the caller, attaches anywhere */
    uint32_t grid;            /* voxels along the longest side of the build grid (0: caller's) */
    float mesh_volume;        /* of the solid, on the build grid */
    float outside_share, missed_share; /* union outside / solid missed, shares of mesh_volume (NaN: caller's) */
    float skin;               /* (g + 1/2) build cells, object units: how far the balls may reach past the
                               * surface (isg self-occlusion; 0: the caller's spheres) */
    double build_seconds;
    /* A thin shell (pn_sphere_set_create_shell): no spheres; the isg method
     * projects the triangles of the instance it is attached to. */
    bool shell;
    /* Deformation (built sets): each centre is the fixed combination
     * sum w_j v[id_j] of PN_SPHERE_ANCHORS mesh vertices; its radius scales
     * with their mean distance from the centre (rest_spread at build). */
    uint32_t vertex_count;
    uint32_t *anchor_ids;     /* count x PN_SPHERE_ANCHORS, or NULL */
    float *anchor_weights;    /* count x PN_SPHERE_ANCHORS */
    float *rest_spread, *rest_radius; /* count each */
};
#define PN_SPHERE_ANCHORS 8

pn_status pn_sphere_set_do_build(pn_mesh mesh, uint32_t count, pn_sphere_set *out);
pn_status pn_sphere_set_do_create(pn_context ctx, const float *spheres, uint32_t count, pn_sphere_set *out);
pn_status pn_sphere_set_do_create_shell(pn_context ctx, pn_sphere_set *out);
void pn_sphere_set_fill_info(pn_sphere_set set, pn_sphere_set_info *info);
pn_status pn_sphere_set_do_read(pn_sphere_set set, float *host, size_t bytes);
pn_status pn_sphere_set_do_deform(pn_sphere_set set, pn_mesh mesh);

#endif
