/* Compiles the public header alone as strict C99: it is part of the build, so
 * a header that needs C11 or a C++ compiler fails the build. */
#include "penumbra.h"

int penumbra_header_compiles_as_c99(void);
int penumbra_header_compiles_as_c99(void)
{
    pn_material m = pn_material_default();
    return (int)m.lobe + PN_SUCCESS;
}
