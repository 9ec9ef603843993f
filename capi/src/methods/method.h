/* The methods layer: one descriptor per shading technique (its own file in
 * methods/), and the renderer that dispatches over them (methods/renderer.c).
 * A descriptor says everything the library knows about a method: name,
 * summary, parameter tables, the scene inputs it reads, its outputs, and the
 * functions of its life cycle:
 *   create/destroy  the method's own state (r->state, state_size bytes, zeroed)
 *   plan            runs before every execute and output read; it does the
 *                   work that may block (table builds, read-backs, uploads)
 *                   only when its inputs changed since the last plan, and
 *                   returns at once otherwise
 *   execute         enqueues the frame's kernels and nothing that waits
 *   read_output     computes and reads one output (blocking) */
#ifndef PENUMBRA_METHOD_H
#define PENUMBRA_METHOD_H

#include "assets/assets.h"

#define PN_MAX_METHOD_PARAMS 32

/* The parameter every env-lit method has, first in its table (slot 0). */
#define PN_PARAM_BACKGROUND                                                                                   \
    { "background", PN_PARAM_INT, PN_PARAM_FRAME, 1, 0, 1, "", "1: background pixels show the environment, 0: black." }

typedef struct pn_output_desc {
    const char *name, *doc;
} pn_output_desc;

typedef struct pn_method_desc {
    const char *name;
    const char *summary;
    const char *stage;            /* kernels/<stage>.cl */
    const char *doc_page;
    const pn_param_desc *params;  /* renderer parameters (frame and plan stages) */
    int param_count;
    const pn_param_desc *bake_params; /* options of the method's asset bake (stage bake), or NULL */
    int bake_param_count;
    const pn_output_desc *outputs;
    int output_count;
    uint32_t inputs;              /* PN_INPUT_* */
    /* true: execute draws the background itself (the `background` parameter)
     * in its own kernel; the renderer then runs no background pass after it. */
    bool draws_background;
    size_t state_size;
    pn_status (*create)(pn_renderer r);
    void (*destroy)(pn_renderer r);
    pn_status (*plan)(pn_renderer r, pn_scene scene);
    pn_status (*execute)(pn_renderer r, pn_scene scene, pn_gbuffer gb, pn_image image);
    pn_status (*read_output)(pn_renderer r, pn_scene scene, int output, uint32_t instance, uint32_t index,
                             void *host, size_t bytes);
    /* The caller's env domains (pn_renderer_set_env_domains), or NULL when the method takes none. */
    pn_status (*set_domains)(pn_renderer r, const pn_env_domain *domains, uint32_t count);
} pn_method_desc;

struct pn_renderer_impl {
    pn_object obj;
    const pn_method_desc *method;
    double params[PN_MAX_METHOD_PARAMS]; /* by the method's parameter table; ints stored exactly */
    bool committed;
    void *state;                         /* the method's own, state_size bytes */
};

/* The descriptors, one per method file. */
extern const pn_method_desc pn_method_unshadowed, pn_method_reference, pn_method_floor, pn_method_fiv,
    pn_method_heightfield, pn_method_depthmap, pn_method_isg;

/* The descriptor named `name`, or NULL with an error listing the methods. */
const pn_method_desc *pn_method_find(const char *name);
const pn_method_desc *pn_method_at(uint32_t index);
uint32_t pn_method_table_size(void);

/* Renderer dispatch (methods/renderer.c). */
pn_status pn_renderer_new(pn_context ctx, const char *method, pn_renderer *out);
pn_status pn_renderer_param_int(pn_renderer r, const char *name, int32_t *value, bool set);
pn_status pn_renderer_param_float(pn_renderer r, const char *name, float *value, bool set);
pn_status pn_renderer_do_commit(pn_renderer r);
pn_status pn_renderer_do_execute(pn_renderer r, pn_scene scene, pn_gbuffer gbuffer, pn_image image);
pn_status pn_renderer_do_set_env_domains(pn_renderer r, const pn_env_domain *domains, uint32_t count);
/* pn_renderer_set_depth_maps (methods/depthmap.c). */
pn_status pn_depthmap_set_maps(pn_renderer r, const float *frames, const float *depths, uint32_t count,
                               uint32_t resolution);
pn_status pn_depthmap_set_maps_sized(pn_renderer r, const float *frames, const float *depths, uint32_t count,
                                     const uint32_t *resolutions);
pn_status pn_depthmap_set_maps_cl(pn_renderer r, const float *frames, cl_mem depths, uint32_t count,
                                  const uint32_t *resolutions);
pn_status pn_renderer_do_read_output(pn_renderer r, pn_scene scene, const char *output, uint32_t instance,
                                     uint32_t index, void *host, size_t bytes);

/* Shared by method files. */
/* The unshadowed shading of every pixel (also the base of heightfield). */
pn_status pn_unshadowed_enqueue(pn_renderer r, pn_scene scene, pn_gbuffer gb, pn_image image, int background);

#endif
