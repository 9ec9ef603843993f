/* Host memory under the cap of PENUMBRA_MAX_BYTES (docs/reliability.md,
 * "Limits"): every allocation whose size comes from the caller's input is
 * checked against it before anything is allocated or read. */
#include "core/core.h"

#include <ctype.h>
#include <errno.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

/* PENUMBRA_MAX_BYTES: a byte count, optionally with a binary suffix K, M,
 * G or T ("512M"); 0 when unset. Read at every check (cheap next to what it
 * guards), so a process may change it between calls. */
static pn_status max_bytes(pn_context ctx, size_t *limit)
{
    const char *text = getenv("PENUMBRA_MAX_BYTES");
    *limit = PN_DEFAULT_MAX_BYTES;
    if (!text || !*text)
        return PN_SUCCESS;
    char *end = NULL;
    errno = 0;
    const unsigned long long v = isdigit((unsigned char)text[0]) ? strtoull(text, &end, 10) : 0;
    unsigned shift = 0;
    const char *suffixes = "KMGT";
    const char *at = end && *end ? strchr(suffixes, toupper((unsigned char)*end)) : NULL;
    if (at && *at) {
        shift = 10u * (unsigned)(at - suffixes + 1);
        ++end;
        if (*end == 'i' || *end == 'I')
            ++end;
        if (*end == 'B' || *end == 'b')
            ++end;
    }
    if (!end || *end || errno || v == 0 || v > SIZE_MAX || (shift && v > (SIZE_MAX >> shift)))
        return pn_fail(ctx, PN_ERROR_BAD_CONFIG,
                       "PENUMBRA_MAX_BYTES='%s' is not a positive byte count (e.g. 4294967296 or 4G)", text);
    *limit = (size_t)v << shift;
    return PN_SUCCESS;
}

pn_status pn_check_bytes(pn_context ctx, size_t bytes, const char *what)
{
    size_t limit;
    pn_status st = max_bytes(ctx, &limit);
    if (st)
        return st;
    if (bytes == SIZE_MAX)
        return pn_fail(ctx, PN_ERROR_INVALID_SIZE, "%s: its size in bytes overflows (the limit is %zu bytes, PENUMBRA_MAX_BYTES)",
                       what, limit);
    if (bytes > limit)
        return pn_fail(ctx, PN_ERROR_INVALID_SIZE,
                       "%s needs %zu bytes, more than the limit of %zu bytes (PENUMBRA_MAX_BYTES)", what, bytes, limit);
    return PN_SUCCESS;
}

void *pn_malloc(pn_context ctx, size_t bytes, const char *what)
{
    if (pn_check_bytes(ctx, bytes, what))
        return NULL;
    void *p = malloc(bytes ? bytes : 1);
    if (!p)
        pn_fail(ctx, PN_ERROR_OUT_OF_MEMORY, "out of host memory allocating %zu bytes for %s", bytes, what);
    return p;
}

size_t pn_mul_size(size_t a, size_t b, size_t c)
{
    if (a && b > SIZE_MAX / a)
        return SIZE_MAX;
    size_t ab = a * b;
    if (ab && c > SIZE_MAX / ab)
        return SIZE_MAX;
    return ab * c;
}
