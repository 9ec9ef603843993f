/* libFuzzer target: the context's configuration string (pn_context_create:
 * key=value pairs, device choice). Input bytes up to the first NUL are the
 * string. A context that comes out is released again. */
#include "fuzz_common.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    FUZZ_BEGIN(data, size);
    char *config = fuzz_string(data, size);
    if (!config)
        return 0;
    unsetenv("PENUMBRA_DEVICE");
    pn_context ctx = NULL;
    pn_status st = pn_context_create(config, &ctx);
    if (st == PN_SUCCESS) {
        FUZZ_CHECK(ctx != NULL);
        FUZZ_CHECK(pn_context_release(ctx) == PN_SUCCESS);
    } else {
        FUZZ_CHECK(ctx == NULL);
        FUZZ_CHECK(st == PN_ERROR_BAD_CONFIG || st == PN_ERROR_NO_DEVICE || st < 0);
        const char *msg = fuzz_error(NULL);
        FUZZ_CHECK(msg[0] != '\0');
    }
    free(config);
    return 0;
}
