/* Spherical-Gaussian lighting on the host (docs/isg.md): the ISG table the
 * device's pn_isg reads (isg_table.c) and the env map -> SG lobe fit
 * (sg_fit.c). Device side: kernels/common/sg.cl. */
#ifndef PENUMBRA_CORE_SG_H
#define PENUMBRA_CORE_SG_H

#include "core/core.h"

/* Must match kernels/common/sg.cl. */
#define PN_ISG_LAMBDAS 57
#define PN_ISG_RHO 33
#define PN_ISG_PER_DECADE 8
#define PN_ISG_LAMBDA_MIN 1e-3
#define PN_ISG_BACK_MAX 40.0

/* Fills the PN_ISG_TABLE_FLOATS floats of the ISG table (layout in sg.cl) from
 * float64 quadrature of the exact marginals. */
void pn_isg_table_fill(float *out);

/* The context's device copy of the table (built and uploaded once per
 * context, owned by it: do not release). */
pn_status pn_isg_table_buffer(pn_context ctx, cl_mem *out);

/* pn_envmap_fit_sgs after the handle and pointer checks (sg_fit.c). */
pn_status pn_envmap_do_fit_sgs(pn_envmap env, uint32_t count, const pn_sg_fit_options *options, pn_sg_lobe *out,
                               size_t capacity);

#endif
