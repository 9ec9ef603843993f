/* libFuzzer target: pn_fiv_load (header and samples) on a file holding the
 * input, through a context made once (PoCL on the CPU; loading needs no
 * kernel). A loaded field's numbers are read back and must be usable. */
#include "fuzz_common.h"

static pn_context ctx;

int LLVMFuzzerInitialize(int *argc, char ***argv)
{
    (void)argc;
    (void)argv;
    if (pn_context_create(NULL, &ctx) != PN_SUCCESS) {
        fprintf(stderr, "fuzz_fiv_load: no OpenCL context: %s\n", fuzz_error(NULL));
        abort();
    }
    return 0;
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    FUZZ_BEGIN(data, size);
    const char *path = fuzz_write_input(data, size);
    if (!path)
        return 0;
    pn_fiv fiv = NULL;
    pn_status st = pn_fiv_load(ctx, path, &fiv);
    if (st == PN_SUCCESS) {
        pn_fiv_info info;
        FUZZ_CHECK(pn_fiv_get_info(fiv, &info) == PN_SUCCESS);
        FUZZ_CHECK(info.radii_done == info.options.radii);
        FUZZ_CHECK(isfinite(info.radius) && isfinite(info.outer) && isfinite(info.centre[0]));
        const size_t floats = (size_t)info.sample_count * 9u;
        float *samples = malloc(floats * sizeof(float));
        if (samples) {
            FUZZ_CHECK(pn_fiv_read(fiv, samples, floats * sizeof(float)) == PN_SUCCESS);
            free(samples);
        }
        FUZZ_CHECK(pn_fiv_release(fiv) == PN_SUCCESS);
        FUZZ_CHECK(pn_fiv_release(fiv) == PN_ERROR_INVALID_HANDLE);
    } else {
        FUZZ_CHECK(st == PN_ERROR_FILE || st == PN_ERROR_INVALID_SIZE);
        FUZZ_CHECK(fiv == NULL);
    }
    pn_get_error(ctx, NULL);
    pn_get_error(NULL, NULL);
    return 0;
}
