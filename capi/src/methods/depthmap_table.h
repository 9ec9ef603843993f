/* The depthmap method's table of exact cap averages (depthmap_table.c);
 * the sizes and constants are repeated in kernels/depthmap.cl (DM_TABLE_*). */
#ifndef PENUMBRA_DEPTHMAP_TABLE_H
#define PENUMBRA_DEPTHMAP_TABLE_H

#include "core/core.h"

#define PN_DM_TABLE_R 48           /* cap radius axis */
#define PN_DM_TABLE_D 64           /* centre-to-axis angle axis (signed distance from the cap's edge) */
#define PN_DM_TABLE_N 32           /* lobe exponent axis, log-spaced */
#define PN_DM_TABLE_N_MAX 1e6      /* the largest exponent tabulated (the smallest is 1) */
#define PN_DM_TABLE_SPREAD 4.0     /* lobe widths of the edge's half of the psi axis */
#define PN_DM_TABLE_FLOATS (PN_DM_TABLE_R * PN_DM_TABLE_D * PN_DM_TABLE_N)

/* Fills PN_DM_TABLE_FLOATS floats, [n][psi][r] (float64 quadrature). */
void pn_depthmap_cap_table_fill(float *out);
/* The context's device copy, built at the first call and owned by the context. */
pn_status pn_depthmap_cap_table(pn_context ctx, cl_mem *out);

#endif
