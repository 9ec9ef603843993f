/* Everything the boundary (api.c) sees: the four layers, each of which
 * includes only the ones below it:
 *   core/core.h         objects, errors, context, buffers, env maps, utils
 *   core/sg.h           spherical-Gaussian lighting: the ISG table, env map -> SG fit
 *   geometry/geometry.h meshes, BVH, scenes, attachments
 *   assets/assets.h     occlusion fields, height fields, bake files
 *   methods/method.h    method descriptors and the renderer */
#ifndef PENUMBRA_INTERNAL_H
#define PENUMBRA_INTERNAL_H

#include "core/sg.h"
#include "methods/method.h"

#endif
