/* Shared helpers of the libFuzzer targets (docs/reliability.md, "Fuzzing (C)"). */
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

/* The input being run (FUZZ_BEGIN), saved by a failed FUZZ_CHECK itself:
 * with an OpenCL context in the process, SIGABRT no longer reaches
 * libFuzzer's handler (the OpenCL runtime's signal set-up), so libFuzzer
 * would not write the crash file. */
static const uint8_t *fuzz_data;
static size_t fuzz_size;
#define FUZZ_BEGIN(data, size) (fuzz_data = (data), fuzz_size = (size))

/* Writes the current input to $FUZZ_ARTIFACT_PREFIX (default "./crash-")
 * followed by "property-<pid>", and names it. */
static inline void fuzz_save_input(void)
{
    const char *prefix = getenv("FUZZ_ARTIFACT_PREFIX");
    char path[1024];
    snprintf(path, sizeof path, "%sproperty-%ld", prefix ? prefix : "./crash-", (long)getpid());
    FILE *f = fopen(path, "wb");
    if (f) {
        if (fuzz_size)
            fwrite(fuzz_data, 1, fuzz_size, f);
        fclose(f);
        fprintf(stderr, "input written to %s\n", path);
    }
}

/* A property every input must keep: the input is saved, then abort. */
#define FUZZ_CHECK(cond)                                                                                     \
    do {                                                                                                     \
        if (!(cond)) {                                                                                       \
            fprintf(stderr, "%s:%d: property failed: %s\n", __FILE__, __LINE__, #cond);                      \
            fuzz_save_input();                                                                               \
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
