/* Object lifetimes: every handle starts with a pn_object head (tag,
 * reference count, owning context, type). Creation retains the context,
 * the last release destroys the object through its type and then releases
 * the context, so no layer needs the exported *_release functions. */
#include "core/core.h"

#include <stdatomic.h>
#include <stdlib.h>
#include <string.h>

void *pn_object_new(pn_context ctx, size_t size, const pn_object_type *type, const char *what)
{
    pn_object *o = pn_malloc(ctx, size, what);
    if (!o)
        return NULL;
    memset(o, 0, size);
    o->magic = type->magic;
    o->refcount = 1;
    o->ctx = ctx;
    o->type = type;
    if (ctx)
        ctx->obj.refcount++;
    return o;
}

void pn_object_retain(pn_object *o)
{
    o->refcount++;
}

void pn_object_release(pn_object *o)
{
    if (!o || --o->refcount > 0)
        return;
    pn_context owner = o->ctx;
    const bool is_context = o->magic == PN_MAGIC_CONTEXT;
    o->type->destroy(o); /* sets the tag to PN_MAGIC_DEAD and frees */
    if (!is_context && owner)
        pn_object_release(&owner->obj);
}

/* A process-wide counter: a (mesh, version) pair never repeats, even when a
 * released mesh's memory is reused by a new one. */
static atomic_uint_fast64_t versions = 1;

uint64_t pn_next_version(void)
{
    return atomic_fetch_add(&versions, 1);
}

int pn_param_find(const pn_param_desc *table, int count, const char *name)
{
    for (int i = 0; i < count; ++i)
        if (!strcmp(table[i].name, name))
            return i;
    return -1;
}

pn_status pn_param_check(pn_context ctx, const char *owner, const pn_param_desc *p, double value)
{
    if (!(value >= p->lo && value <= p->hi)) /* NaN fails too */
        return pn_fail(ctx, PN_ERROR_INVALID_ARGUMENT, "%s %s = %g is outside [%g, %g]", owner, p->name, value, p->lo,
                       p->hi);
    if (p->type == PN_PARAM_INT && value != (double)(long long)value)
        return pn_fail(ctx, PN_ERROR_INVALID_ARGUMENT, "%s %s = %g must be an integer", owner, p->name, value);
    return PN_SUCCESS;
}
