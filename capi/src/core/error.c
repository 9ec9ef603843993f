/* Per-context, per-thread last error (STYLE.md: the first thing a caller
 * reads after a failed call). Slots are thread-local and keyed by the
 * context's serial number, so a context never sees another thread's error
 * and a new context at a recycled address never inherits an old message. */
#include "core/core.h"

#include <stdarg.h>
#include <stdio.h>
#include <string.h>

#define PN_ERROR_SLOTS 64 /* contexts per thread with a pending error; older ones are recycled */
#define PN_MESSAGE_SIZE 2048

typedef struct error_slot {
    uint64_t serial; /* 0: the global slot (no context) */
    pn_status status;
    char message[PN_MESSAGE_SIZE];
    bool used;
} error_slot;

static _Thread_local error_slot slots[PN_ERROR_SLOTS];
static _Thread_local unsigned next_victim;
/* Returned by pn_get_error; lives until the next call on this thread. */
static _Thread_local char returned[PN_MESSAGE_SIZE];

static error_slot *find_slot(uint64_t serial, bool create)
{
    for (int i = 0; i < PN_ERROR_SLOTS; ++i)
        if (slots[i].used && slots[i].serial == serial)
            return &slots[i];
    if (!create)
        return NULL;
    for (int i = 0; i < PN_ERROR_SLOTS; ++i)
        if (!slots[i].used) {
            slots[i].used = true;
            slots[i].serial = serial;
            return &slots[i];
        }
    /* More live contexts with errors than slots on this thread: reuse one. */
    error_slot *s = &slots[next_victim++ % PN_ERROR_SLOTS];
    s->serial = serial;
    return s;
}

static uint64_t serial_of(pn_context ctx)
{
    return ctx ? ctx->serial : 0;
}

pn_status pn_fail(pn_context ctx, pn_status status, const char *fmt, ...)
{
    error_slot *s = find_slot(serial_of(ctx), true);
    s->status = status;
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(s->message, sizeof s->message, fmt, ap);
    va_end(ap);
    if (ctx && ctx->callback)
        ctx->callback(ctx->callback_user, status, s->message);
    return status;
}

pn_status pn_fail_cl(pn_context ctx, cl_int err, const char *what)
{
    return pn_fail(ctx, err, "OpenCL error %d while %s", (int)err, what);
}

void pn_error_clear(pn_context ctx)
{
    error_slot *s = find_slot(serial_of(ctx), false);
    if (s) {
        s->status = PN_SUCCESS;
        s->message[0] = '\0';
    }
}

void pn_error_forget(uint64_t context_serial)
{
    error_slot *s = find_slot(context_serial, false);
    if (s)
        memset(s, 0, sizeof *s);
}

pn_status pn_error_take(pn_context ctx, const char **message)
{
    error_slot *s = find_slot(serial_of(ctx), false);
    pn_status status = PN_SUCCESS;
    returned[0] = '\0';
    if (s) {
        status = s->status;
        memcpy(returned, s->message, sizeof returned);
        s->status = PN_SUCCESS;
        s->message[0] = '\0';
    }
    if (message)
        *message = returned;
    return status;
}

const char *pn_status_name_of(pn_status status)
{
    switch (status) {
    case PN_SUCCESS: return "PN_SUCCESS";
    case PN_ERROR_NULL_HANDLE: return "PN_ERROR_NULL_HANDLE";
    case PN_ERROR_INVALID_ARGUMENT: return "PN_ERROR_INVALID_ARGUMENT";
    case PN_ERROR_INVALID_SIZE: return "PN_ERROR_INVALID_SIZE";
    case PN_ERROR_INVALID_VALUE: return "PN_ERROR_INVALID_VALUE";
    case PN_ERROR_OUT_OF_RANGE: return "PN_ERROR_OUT_OF_RANGE";
    case PN_ERROR_EMPTY_INPUT: return "PN_ERROR_EMPTY_INPUT";
    case PN_ERROR_BAD_CONFIG: return "PN_ERROR_BAD_CONFIG";
    case PN_ERROR_BUILD_FAILED: return "PN_ERROR_BUILD_FAILED";
    case PN_ERROR_NOT_COMMITTED: return "PN_ERROR_NOT_COMMITTED";
    case PN_ERROR_OUT_OF_MEMORY: return "PN_ERROR_OUT_OF_MEMORY";
    case PN_ERROR_NO_DEVICE: return "PN_ERROR_NO_DEVICE";
    case PN_ERROR_UNSUPPORTED: return "PN_ERROR_UNSUPPORTED";
    case PN_ERROR_CANCELLED: return "PN_ERROR_CANCELLED";
    case PN_ERROR_FILE: return "PN_ERROR_FILE";
    case PN_ERROR_INVALID_HANDLE: return "PN_ERROR_INVALID_HANDLE";
    case PN_ERROR_INTERNAL: return "PN_ERROR_INTERNAL";
    default: return status < 0 && status > -1000 ? "OpenCL error" : "unknown status";
    }
}
