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
#define PN_DM_TABLE_PHONG_FLOATS (PN_DM_TABLE_R * PN_DM_TABLE_D * PN_DM_TABLE_N)

/* Blinn-Phong's and GGX's tables (two families, each [c][phi_s][delta][rho]), after Phong's. */
#define PN_DM_LOBE_R 32              /* disk radius rho = r / s, log1p(rho / RHO_0)-spaced */
#define PN_DM_LOBE_D 40              /* signed lobe-metric distance of R from the disk's edge */
#define PN_DM_LOBE_P 8               /* the offset's angle phi_s in the stretched plane, [0, pi / 2] */
#define PN_DM_LOBE_C 10              /* c = N.V, log-spaced in [C_MIN, 1] */
#define PN_DM_LOBE_RHO_MAX 4096.0    /* the largest rho tabulated */
#define PN_DM_LOBE_RHO_0 0.25        /* rho's axis is log-spaced above this, linear below */
#define PN_DM_LOBE_DELTA_MAX 32.0    /* the largest delta_u tabulated */
#define PN_DM_LOBE_C_MIN 0.01        /* the smallest N.V tabulated (89.4 degrees) */
#define PN_DM_LOBE_V 5 /* per entry: log G, the lobe-weighted centroid (x, y / c) and the spreads of x and y / c */
#define PN_DM_LOBE_FAMILY (PN_DM_LOBE_V * PN_DM_LOBE_R * PN_DM_LOBE_D * PN_DM_LOBE_P * PN_DM_LOBE_C)
#define PN_DM_TABLE_FLOATS (PN_DM_TABLE_PHONG_FLOATS + 2 * PN_DM_LOBE_FAMILY)

/* Fills PN_DM_TABLE_FLOATS floats: Phong's [n][psi][r], then the two lobe families (float64 quadrature). */
void pn_depthmap_cap_table_fill(float *out);
/* The lobe families alone (2 PN_DM_LOBE_FAMILY floats of log G). */
void pn_depthmap_lobe_table_fill(float *out);
#define PN_DM_LOBE_BLINN_PHONG_BIT 1 /* family 0 */
#define PN_DM_LOBE_GGX_BIT 2         /* family 1 */
/* The context's device copy, built at the first call and owned by the context: Phong's table alone
   (lobes 0), or PN_DM_TABLE_FLOATS with the Blinn-Phong and GGX families after it, only those of the
   mask `lobes` filled (the others zero; the kernel does not read them). One cache entry per mask. */
pn_status pn_depthmap_cap_table(pn_context ctx, int lobes, cl_mem *out);
/* One family (0 Blinn-Phong, 1 GGX): PN_DM_LOBE_FAMILY floats. */
void pn_depthmap_lobe_family_fill(int family, float *out);

#endif
