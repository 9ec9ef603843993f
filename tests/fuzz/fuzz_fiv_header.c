/* libFuzzer target: pn_fiv_read_header on a file holding the input (no
 * OpenCL device needed). Every input must give PN_SUCCESS with finite,
 * consistent numbers, or PN_ERROR_FILE; never a crash or a hang. */
#include "fuzz_common.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    FUZZ_BEGIN(data, size);
    const char *path = fuzz_write_input(data, size);
    if (!path)
        return 0;
    pn_fiv_info info;
    memset(&info, 0, sizeof info);
    pn_status st = pn_fiv_read_header(path, &info);
    if (st == PN_SUCCESS) {
        FUZZ_CHECK(info.radii_done <= info.options.radii);
        FUZZ_CHECK(isfinite(info.radius) && info.radius > 0.0f);
        FUZZ_CHECK(isfinite(info.centre[0]) && isfinite(info.centre[1]) && isfinite(info.centre[2]));
        FUZZ_CHECK(isfinite(info.outer) && info.outer > info.inner && info.inner > 0.0f);
        /* The file holds exactly what its header promises. */
        FUZZ_CHECK((uint64_t)size == 256u + info.stored_bytes / info.options.radii * info.radii_done);
    } else {
        FUZZ_CHECK(st == PN_ERROR_FILE);
    }
    pn_get_error(NULL, NULL);
    return 0;
}
