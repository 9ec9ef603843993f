/* Everything the boundary (api.c) sees: the four layers, each of which
 * includes only the ones below it:
 *   core/core.h         objects, errors, context, buffers, env maps, utils
 *   geometry/geometry.h meshes, BVH, scenes, attachments
 *   assets/assets.h     occlusion fields, height fields, bake files
 *   methods/method.h    method descriptors and the renderer */
#ifndef PENUMBRA_INTERNAL_H
#define PENUMBRA_INTERNAL_H

#include "methods/method.h"

#endif
