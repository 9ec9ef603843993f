/* libFuzzer target: every entry point that looks up a name given as a
 * string (method names, renderer and env-map parameters, method metadata)
 * and the PENUMBRA_MAX_BYTES variable's parser. Input: a 4-byte selector and
 * value, then the string (up to the first NUL). One context, made once. */
#include "fuzz_common.h"

static pn_context ctx;
static pn_envmap env;
static pn_mesh mesh;

int LLVMFuzzerInitialize(int *argc, char ***argv)
{
    (void)argc;
    (void)argv;
    if (pn_context_create(NULL, &ctx) != PN_SUCCESS || pn_envmap_create(ctx, &env) != PN_SUCCESS ||
        pn_mesh_create(ctx, &mesh) != PN_SUCCESS) {
        fprintf(stderr, "fuzz_params: no OpenCL context: %s\n", fuzz_error(NULL));
        abort();
    }
    return 0;
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    FUZZ_BEGIN(data, size);
    if (size < 5)
        return 0;
    uint32_t bits;
    memcpy(&bits, data + 1, sizeof bits);
    float fvalue;
    memcpy(&fvalue, &bits, sizeof fvalue);
    const int32_t ivalue = (int32_t)bits;
    char *name = fuzz_string(data + 5, size - 5);
    if (!name)
        return 0;
    switch (data[0] % 6) {
    case 0: { /* a method by name, and its parameters by name */
        pn_method_info info;
        if (pn_method_get_info(name, &info) == PN_SUCCESS) {
            pn_param_info p;
            FUZZ_CHECK(pn_method_get_param(name, bits % (info.param_count + 2), &p) == PN_SUCCESS ||
                       bits % (info.param_count + 2) >= info.param_count);
        }
        pn_renderer r = NULL;
        if (pn_renderer_create(ctx, name, &r) == PN_SUCCESS)
            FUZZ_CHECK(pn_renderer_release(r) == PN_SUCCESS);
        break;
    }
    case 1:
    case 2: { /* a renderer parameter by name, int or float */
        pn_renderer r = NULL;
        const uint32_t count = pn_method_count();
        const char *method = pn_method_name(bits % (count ? count : 1));
        if (method && pn_renderer_create(ctx, method, &r) == PN_SUCCESS) {
            pn_status st = data[0] % 6 == 1 ? pn_renderer_set_int(r, name, ivalue) : pn_renderer_set_float(r, name, fvalue);
            if (st == PN_SUCCESS) { /* a parameter that was set reads back as its own type (an int may set a float) */
                float fback = 0.0f;
                int32_t iback = 0;
                FUZZ_CHECK(pn_renderer_get_int(r, name, &iback) == PN_SUCCESS ||
                           pn_renderer_get_float(r, name, &fback) == PN_SUCCESS);
            }
            pn_renderer_release(r);
        }
        break;
    }
    case 3: /* an env-map parameter by name */
        pn_envmap_set_int(env, name, ivalue);
        pn_envmap_set_float(env, name, fvalue);
        break;
    case 4: { /* PENUMBRA_MAX_BYTES: a byte count with an optional suffix */
        setenv("PENUMBRA_MAX_BYTES", name, 1);
        const float pos[9] = {0, 0, 0, 1, 0, 0, 0, 1, 0};
        const uint32_t idx[3] = {0, 1, 2};
        pn_status st = pn_mesh_set_geometry(mesh, pos, 3, idx, 1, NULL);
        FUZZ_CHECK(st == PN_SUCCESS || st == PN_ERROR_BAD_CONFIG || st == PN_ERROR_INVALID_SIZE);
        unsetenv("PENUMBRA_MAX_BYTES");
        break;
    }
    default: /* an output by name, and the other name look-ups */
        pn_method_get_output(name, bits % 4, &(pn_output_info){0});
        pn_status_name((pn_status)ivalue);
        pn_lobe_name(bits);
        break;
    }
    pn_get_error(ctx, NULL);
    pn_get_error(NULL, NULL);
    free(name);
    return 0;
}
