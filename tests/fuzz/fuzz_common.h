/* Shared helpers of the libFuzzer targets (docs/reliability-c.md, "Fuzzing (C)"). */
#ifndef PENUMBRA_FUZZ_COMMON_H
#define PENUMBRA_FUZZ_COMMON_H

#define _GNU_SOURCE /* memfd_create */
#include "penumbra.h"

#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#include <unistd.h>

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);
int LLVMFuzzerInitialize(int *argc, char ***argv);

/* A property every input must keep: abort (libFuzzer saves the input). */
#define FUZZ_CHECK(cond)                                                                                     \
    do {                                                                                                     \
        if (!(cond)) {                                                                                       \
            fprintf(stderr, "%s:%d: property failed: %s\n", __FILE__, __LINE__, #cond);                      \
            abort();                                                                                         \
        }                                                                                                    \
    } while (0)

/* The input as a file: a memfd (no disk) named by /proc/self/fd/N, rewritten
 * for every input. NULL if it cannot be written. */
static inline const char *fuzz_write_input(const uint8_t *data, size_t size)
{
    static int fd = -1;
    static char path[64];
    if (fd < 0) {
        fd = memfd_create("pnfuzz", 0);
        if (fd < 0)
            return NULL;
        snprintf(path, sizeof path, "/proc/self/fd/%d", fd);
    }
    if (ftruncate(fd, 0) != 0 || pwrite(fd, data, size, 0) != (ssize_t)size)
        return NULL;
    return path;
}

/* The input up to its first NUL as a NUL-terminated string (malloc'ed). */
static inline char *fuzz_string(const uint8_t *data, size_t size)
{
    char *s = malloc(size + 1);
    if (!s)
        return NULL;
    memcpy(s, data, size);
    s[size] = '\0';
    return s;
}

static inline const char *fuzz_error(pn_context ctx)
{
    const char *m = NULL;
    pn_get_error(ctx, &m);
    return m ? m : "";
}

#endif
