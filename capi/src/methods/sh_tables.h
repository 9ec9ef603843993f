/* Float64 spherical-harmonic tables of the heightfield method (sh_tables.c). */
#ifndef PENUMBRA_SH_TABLES_H
#define PENUMBRA_SH_TABLES_H

#include "core/core.h"

#define PN_SH_MAX_BANDS 6
#define PN_SH_WEDGE_ANGLES 64  /* horizon angles per axis of a wedge table */

void pn_sh_eval64(int nb, double cos_polar, double sin_polar, double phi, double *out);
void pn_sh_clamped_cosine64(int nb, double *a);
/* The context's cached tables, owned by the context. A pointer stays valid
 * until the next pn_sh_cache_begin (call it at the start of each operation
 * that fetches tables; entries used since then are never evicted). */
pn_status pn_sh_cache_begin(pn_context ctx);
pn_status pn_sh_wedge_table(pn_context ctx, int n_phi, int nb, bool light, const float **out);
pn_status pn_sh_triple_product(pn_context ctx, int nb, const double **out);

#endif
