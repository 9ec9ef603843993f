/* Object lifetimes and handles.
 *
 * Every object starts with a pn_object head (tag, reference counts, owning
 * context, type). The caller never sees its address: a handle is an index
 * into a process-wide table of slots plus the slot's generation, so a handle
 * that was released (or never created) is recognised as such and answered
 * with PN_ERROR_INVALID_HANDLE; the library never reads memory through it.
 *
 * Two counts: `public_refs` are the caller's references (create, retain,
 * release); the handle is valid while it is positive (pn_get_error alone
 * still reads a context's errors after that, while the context lives). The
 * slot is freed (its generation advanced) when the object is destroyed. `refs` counts every reference:
 * the caller's, those other objects hold (a scene's meshes, every object's
 * context) and the short pins of calls in progress. The last one destroys the
 * object through its type and then releases the context. Both saturate:
 * a retain at the limit fails and changes nothing.
 *
 * Threads: every call on an object runs under its context's (recursive)
 * mutex (pn_call_enter), so objects of one context are only changed, and
 * released, by one thread at a time. The slot table has its own mutex. */
#include "core/core.h"

#include <limits.h>
#include <pthread.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

/* -------------------------------------------------------------- the table */

typedef struct handle_slot {
    pn_object *object; /* NULL: free */
    uintptr_t generation;
    uint32_t next_free;
} handle_slot;

#define HALF_BITS (sizeof(uintptr_t) * 4u)
#define INDEX_MASK (((uintptr_t)1 << HALF_BITS) - 1u)
#define GEN_MAX INDEX_MASK
#define NO_SLOT UINT32_MAX
/* Slots at most: 2^30, or what the index half of a handle can name. */
#define MAX_SLOTS (INDEX_MASK - 1u < (1u << 30) ? (uint32_t)(INDEX_MASK - 1u) : (1u << 30))

static pthread_mutex_t table_lock = PTHREAD_MUTEX_INITIALIZER;
static handle_slot *table;
static uint32_t table_size, table_capacity, free_head = NO_SLOT;

static void *encode(uint32_t index, uintptr_t generation)
{
    return (void *)((generation << HALF_BITS) | ((uintptr_t)index + 1u));
}

/* Gives `o` a slot and its handle; false when out of memory or out of slots. */
static bool register_object(pn_object *o)
{
    bool ok = true;
    pthread_mutex_lock(&table_lock);
    uint32_t index = free_head;
    if (index != NO_SLOT) {
        free_head = table[index].next_free;
    } else if (table_size == table_capacity && table_capacity >= MAX_SLOTS) {
        ok = false; /* every slot is live or retired */
    } else {
        if (table_size == table_capacity) {
            const uint32_t cap = table_capacity ? 2 * table_capacity : 256;
            handle_slot *grown = realloc(table, (size_t)cap * sizeof *grown);
            if (!grown) {
                pthread_mutex_unlock(&table_lock);
                return false;
            }
            table = grown;
            table_capacity = cap;
        }
        index = table_size++;
        table[index].generation = 0;
    }
    if (ok) {
        table[index].object = o;
        table[index].generation++;
        table[index].next_free = NO_SLOT;
        o->handle = encode(index, table[index].generation);
    }
    pthread_mutex_unlock(&table_lock);
    return ok;
}

static void unregister_object(pn_object *o)
{
    pthread_mutex_lock(&table_lock);
    const uint32_t index = (uint32_t)(((uintptr_t)o->handle & INDEX_MASK) - 1u);
    if (o->handle && index < table_size && table[index].object == o) {
        table[index].object = NULL;
        /* A slot whose generation is used up is retired, so a handle never repeats. */
        if (table[index].generation < GEN_MAX) {
            table[index].next_free = free_head;
            free_head = index;
        }
    }
    o->handle = NULL;
    pthread_mutex_unlock(&table_lock);
}

/* The object of a handle the caller still holds (with `released`: or has
 * released while the object lives), or NULL; call with table_lock held. */
static pn_object *lookup_locked(const void *handle, bool released)
{
    const uintptr_t v = (uintptr_t)handle;
    const uintptr_t index = (v & INDEX_MASK);
    if (index == 0 || index > table_size)
        return NULL;
    const handle_slot *s = &table[index - 1u];
    if (!s->object || s->generation != (v >> HALF_BITS))
        return NULL;
    return released || atomic_load(&s->object->public_refs) > 0 ? s->object : NULL;
}

void *pn_object_handle(const pn_object *o)
{
    return o ? o->handle : NULL;
}

/* ----------------------------------------------------------- reference counts */

static bool add_ref(pn_object *o)
{
    int n = atomic_load(&o->refs);
    do {
        if (n >= PN_REFS_MAX)
            return false;
    } while (!atomic_compare_exchange_weak(&o->refs, &n, n + 1));
    return true;
}

pn_status pn_object_setup(pn_object *o, pn_context ctx, const pn_object_type *type)
{
    o->magic = type->magic;
    atomic_init(&o->refs, 1);
    atomic_init(&o->public_refs, 1);
    o->ctx = ctx;
    o->type = type;
    if (!register_object(o))
        return pn_fail(ctx == (pn_context)o ? NULL : ctx, PN_ERROR_OUT_OF_MEMORY,
                       "out of memory (or out of handles) registering a %s", type->name);
    return PN_SUCCESS;
}

void *pn_object_new(pn_context ctx, size_t size, const pn_object_type *type, const char *what)
{
    pn_object *o = pn_malloc(ctx, size, what);
    if (!o)
        return NULL;
    memset(o, 0, size);
    if (ctx && !add_ref(&ctx->obj)) {
        pn_fail(ctx, PN_ERROR_OUT_OF_RANGE, "the context holds %d references, its limit; release some objects",
                PN_REFS_MAX);
        free(o);
        return NULL;
    }
    if (pn_object_setup(o, ctx, type)) {
        if (ctx)
            pn_object_release(&ctx->obj);
        free(o);
        return NULL;
    }
    return o;
}

pn_status pn_object_retain(pn_object *o)
{
    if (add_ref(o))
        return PN_SUCCESS;
    return pn_fail(o->ctx, PN_ERROR_OUT_OF_RANGE, "a %s holds %d references, its limit", o->type->name, PN_REFS_MAX);
}

static void destroy(pn_object *o)
{
    pn_context owner = o->ctx;
    const bool is_context = o->magic == PN_MAGIC_CONTEXT;
    unregister_object(o); /* from here on its handle is unknown */
    o->type->destroy(o); /* what the object owns */
    o->magic = PN_MAGIC_DEAD;
    free(o);
    if (!is_context && owner)
        pn_object_release(&owner->obj);
}

void pn_object_release(pn_object *o)
{
    if (o && atomic_fetch_sub(&o->refs, 1) == 1)
        destroy(o);
}

pn_status pn_object_public_retain(pn_object *o)
{
    if (atomic_load(&o->public_refs) >= PN_REFCOUNT_MAX)
        return pn_fail(o->ctx, PN_ERROR_OUT_OF_RANGE,
                       "the %s already holds %d references (PN_REFCOUNT_MAX); the retain is refused", o->type->name,
                       PN_REFCOUNT_MAX);
    pn_status st = pn_object_retain(o);
    if (!st)
        atomic_fetch_add(&o->public_refs, 1);
    return st;
}

void pn_object_public_release(pn_object *o)
{
    atomic_fetch_sub(&o->public_refs, 1); /* at 0 the handle is invalid: lookups refuse it */
    pn_object_release(o);
}

/* ------------------------------------------------------------------- calls */

static bool kind_ok(uint32_t have, uint32_t want)
{
    return want == PN_MAGIC_ANY || have == want;
}

static pn_status bad_handle(const void *handle, bool live, const char *type_name, const char *kind, const char *func,
                            const char *arg)
{
    if (!handle)
        return pn_fail(NULL, PN_ERROR_NULL_HANDLE, "%s: the %s handle '%s' is NULL or not a %s", func, kind, arg, kind);
    if (!live)
        return pn_fail(NULL, PN_ERROR_INVALID_HANDLE,
                       "%s: the %s handle '%s' is not a live penumbra object (released already, or never created)",
                       func, kind, arg);
    return pn_fail(NULL, PN_ERROR_NULL_HANDLE, "%s: the %s handle '%s' is NULL or not a %s (it is a %s)", func, kind,
                   arg, kind, type_name);
}

static pn_status enter(pn_call *call, void **handle, uint32_t magic, const char *kind, const char *func,
                       const char *arg, bool released)
{
    /* Under the table's lock: the object is live (its head readable); its
     * context gets a reference (a pin) so neither it nor its lock can go
     * before pn_call_leave. */
    pn_context ctx = NULL;
    const char *type_name = NULL;
    bool right_kind = false;
    pthread_mutex_lock(&table_lock);
    pn_object *o = *handle ? lookup_locked(*handle, released) : NULL;
    if (o) {
        type_name = o->type->name;
        right_kind = kind_ok(o->magic, magic);
        if (right_kind) {
            ctx = o->magic == PN_MAGIC_CONTEXT ? (pn_context)o : o->ctx;
            atomic_fetch_add(&ctx->obj.refs, 1); /* below PN_REFS_MAX + headroom: pins are per thread */
        }
    }
    pthread_mutex_unlock(&table_lock);
    if (!o || !right_kind)
        return bad_handle(*handle, o != NULL, type_name, kind, func, arg);
    pthread_mutex_lock(&ctx->lock);
    /* Released by another thread between the look-up and the lock? (Every
     * release of this context's objects holds the lock, so from here on the
     * object stays.) */
    pthread_mutex_lock(&table_lock);
    const bool live = lookup_locked(*handle, released) == o;
    pthread_mutex_unlock(&table_lock);
    if (!live) {
        pthread_mutex_unlock(&ctx->lock);
        pn_object_release(&ctx->obj);
        return bad_handle(*handle, false, NULL, kind, func, arg);
    }
    call->ctx = ctx;
    *handle = o;
    return PN_SUCCESS;
}

pn_status pn_call_enter(pn_call *call, void **handle, uint32_t magic, const char *kind, const char *func,
                        const char *arg)
{
    return enter(call, handle, magic, kind, func, arg, false);
}

pn_status pn_call_enter_released(pn_call *call, void **handle, uint32_t magic, const char *kind, const char *func,
                                 const char *arg)
{
    return enter(call, handle, magic, kind, func, arg, true);
}

pn_status pn_call_resolve(pn_call *call, void **handle, uint32_t magic, const char *kind, const char *func,
                          const char *arg)
{
    pthread_mutex_lock(&table_lock);
    pn_object *o = *handle ? lookup_locked(*handle, false) : NULL;
    const bool ok = o && kind_ok(o->magic, magic);
    const char *type_name = o ? o->type->name : NULL;
    pn_context owner = ok ? (o->magic == PN_MAGIC_CONTEXT ? (pn_context)o : o->ctx) : NULL;
    pthread_mutex_unlock(&table_lock);
    if (!ok)
        return bad_handle(*handle, o != NULL, type_name, kind, func, arg);
    if (owner != call->ctx)
        return pn_fail(call->ctx, PN_ERROR_INVALID_ARGUMENT, "%s: the %s '%s' belongs to a different context", func,
                       kind, arg);
    *handle = o;
    return PN_SUCCESS;
}

void pn_call_leave(pn_call *call)
{
    if (call->ctx) {
        pn_context ctx = call->ctx;
        call->ctx = NULL;
        pthread_mutex_unlock(&ctx->lock);
        pn_object_release(&ctx->obj); /* may destroy it: its last object went in this call */
    }
}

/* A process-wide counter: a (mesh, version) pair never repeats, even when a
 * released mesh's memory is reused by a new one. */
static atomic_uint_fast64_t versions = 1;

uint64_t pn_next_version(void)
{
    return atomic_fetch_add(&versions, 1);
}

int pn_param_find(const pn_param_desc *table_, int count, const char *name)
{
    for (int i = 0; i < count; ++i)
        if (!strcmp(table_[i].name, name))
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
