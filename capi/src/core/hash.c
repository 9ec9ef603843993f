/* 64-bit FNV-1a: content hashes of meshes and env maps (which occlusion
 * fields record) and checksums of bake files. Not cryptographic: it detects
 * corruption and mismatched inputs, not tampering. */
#include "core/core.h"

#define FNV_PRIME 0x100000001b3ull

uint64_t pn_hash_bytes(uint64_t hash, const void *data, size_t bytes)
{
    const unsigned char *p = data;
    for (size_t i = 0; i < bytes; ++i) {
        hash ^= p[i];
        hash *= FNV_PRIME;
    }
    return hash;
}
