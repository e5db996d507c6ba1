/* The registries of live instances and saved states, and the saved states themselves
 * (see instance.h). */
#include <float.h>
#include <math.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "instance.h"

/* --- registries: instances and saved states are used only while listed live, so a freed,
 * foreign or bogus handle is refused, never read. No fixed cap: the lists grow. ---------- */
#define SM_FREED_KEPT 64
typedef struct {
    const void* handle;
    SmLogger log;
    SmCallback callback;
    void* log_env;
    char name[64];
} SmFreed; /* a freed handle and, for an instance, the logger to report its misuse to */

typedef struct {
    void** live;
    size_t n, cap;
    SmFreed freed[SM_FREED_KEPT];
    int freed_next;
} SmRegistry;

static SmRegistry instances, states;
static atomic_flag registry_lock = ATOMIC_FLAG_INIT;

static void lock(void) {
    while (atomic_flag_test_and_set(&registry_lock)) {
    }
}
static void unlock(void) { atomic_flag_clear(&registry_lock); }

/* Adds p (0 if out of memory); a freed handle reused by malloc is no longer "freed". */
static int registry_add(SmRegistry* r, void* p) {
    int ok = 1;
    lock();
    if (r->n == r->cap) {
        size_t cap = r->cap ? 2 * r->cap : 16;
        void** grown = realloc(r->live, cap * sizeof *grown);
        if (grown == NULL) {
            ok = 0;
        } else {
            r->live = grown;
            r->cap = cap;
        }
    }
    if (ok) r->live[r->n++] = p;
    for (int i = 0; ok && i < SM_FREED_KEPT; i++) {
        if (r->freed[i].handle == p) r->freed[i].handle = NULL;
    }
    unlock();
    return ok;
}

static int find(const SmRegistry* r, const void* p) {
    for (size_t i = 0; i < r->n; i++) {
        if (r->live[i] == p) return (int)i;
    }
    return -1;
}

/* Removes p, remembering it (and gone's logger, if any) as freed. */
static void registry_remove(SmRegistry* r, const void* p, const SmFreed* gone) {
    lock();
    int i = find(r, p);
    if (i >= 0) r->live[i] = r->live[--r->n];
    SmFreed* f = &r->freed[r->freed_next];
    r->freed_next = (r->freed_next + 1) % SM_FREED_KEPT;
    *f = *gone;
    f->handle = p;
    unlock();
}

/* 1 if p is live; else 0, and *gone is its freed record (handle NULL if never issued). */
static int registry_has(const SmRegistry* r, const void* p, SmFreed* gone) {
    int live = 0;
    SmFreed none = {0};
    *gone = none;
    lock();
    live = p != NULL && find(r, p) >= 0;
    for (int i = 0; i < SM_FREED_KEPT && !live && p != NULL; i++) {
        if (r->freed[i].handle == p) *gone = r->freed[i];
    }
    unlock();
    return live;
}

static void free_states_of(const SmInstance* inst);

int sm_register(SmInstance* inst) { return registry_add(&instances, inst); }

void sm_unregister(SmInstance* inst) {
    SmFreed gone = {inst, inst->log, inst->callback, inst->log_env, ""};
    snprintf(gone.name, sizeof gone.name, "%s", inst->name);
    free_states_of(inst);
    registry_remove(&instances, inst, &gone);
}

SmInstance* sm_lookup(void* handle, const char* function) {
    SmFreed gone;
    if (registry_has(&instances, handle, &gone)) return handle;
    if (gone.handle != NULL && gone.log != NULL && gone.callback != NULL) {
        char msg[SM_MSG];
        snprintf(msg, sizeof msg, "%s: this instance was freed already", function);
        gone.log(gone.callback, gone.log_env, gone.name, SM_ERROR, "logStatusError", msg);
    }
    return NULL;
}

/* --- saved states --------------------------------------------------------------------- */
/* The live state behind handle, or NULL after logging why (NULL, freed, or never issued by
 * this FMU: another FMU's state or a bogus pointer is never read). */
static SmState* live_state(SmInstance* inst, const void* handle, const char* function) {
    SmFreed gone;
    if (registry_has(&states, handle, &gone)) return (SmState*)handle;
    sm_log(inst, SM_ERROR, SM_LOG_ERROR, "%s: %s", function,
           handle == NULL        ? "the FMU state is NULL"
           : gone.handle != NULL ? "this FMU state was freed already"
                                 : "not a state of this FMU");
    return NULL;
}

/* A new registered state made by inst, or NULL (logged). */
static SmState* new_state(SmInstance* inst, const char* function) {
    SmState* s = malloc(sizeof *s);
    if (s != NULL && !registry_add(&states, s)) {
        free(s);
        s = NULL;
    }
    if (s == NULL) sm_log(inst, SM_ERROR, SM_LOG_ERROR, "%s: out of memory", function);
    if (s != NULL) s->maker = inst;
    return s;
}

static void drop_state(SmState* s) {
    SmFreed gone = {0};
    registry_remove(&states, s, &gone);
    free(s);
}

/* Frees the states inst made (fmiFreeInstance frees all memory of the instance). */
static void free_states_of(const SmInstance* inst) {
    for (;;) {
        SmState* mine = NULL;
        lock();
        for (size_t i = 0; i < states.n && mine == NULL; i++) {
            if (((SmState*)states.live[i])->maker == inst) mine = states.live[i];
        }
        unlock();
        if (mine == NULL) return;
        drop_state(mine);
    }
}

/* The state to write into: *handle if live, a new one if *handle is NULL. */
static SmState* target_state(SmInstance* inst, void** handle, const char* function) {
    if (handle == NULL) {
        sm_log(inst, SM_ERROR, SM_LOG_ERROR, "%s: the pointer to the FMU state is NULL",
               function);
        return NULL;
    }
    return *handle == NULL ? new_state(inst, function) : live_state(inst, *handle, function);
}

static const char* kind(int cosim) { return cosim ? "Co-Simulation" : "Model Exchange"; }

/* 1 if a state saved by an instance of type cosim in mode can be set on inst: the same
 * instance type, and a mode that type has (sm_mode_fits); else logs why. */
static int fits(SmInstance* inst, int cosim, int mode, const char* function) {
    if (cosim != inst->cosim) {
        sm_log(inst, SM_ERROR, SM_LOG_ERROR,
               "%s: a state of a %s instance cannot be set on a %s instance", function,
               kind(cosim), kind(inst->cosim));
        return 0;
    }
    if (!sm_mode_fits(inst, mode)) {
        sm_log(inst, SM_ERROR, SM_LOG_ERROR,
               "%s: the state is in event mode, which this Co-Simulation instance does not use",
               function);
        return 0;
    }
    return 1;
}

SmStatus sm_get_state(SmInstance* inst, void** handle, const char* function) {
    SmState* s = target_state(inst, handle, function);
    if (s == NULL) return SM_ERROR;
    s->v = inst->v;
    s->cosim = inst->cosim;
    *handle = s;
    inst->wk.carried = 0; /* the next doStep restarts, as one after setting this state will */
    return SM_OK;
}

SmStatus sm_set_state(SmInstance* inst, const void* handle, const char* function) {
    const SmState* s = live_state(inst, handle, function);
    if (s == NULL || !fits(inst, s->cosim, s->v.mode, function)) return SM_ERROR;
    inst->v = s->v;
    inst->wk.carried = 0; /* restart the integrator: steps repeat those after saving */
    return SM_OK;
}

SmStatus sm_free_state(SmInstance* inst, void** handle, const char* function) {
    if (handle == NULL || *handle == NULL) return SM_OK; /* nothing to free */
    SmState* s = live_state(inst, *handle, function);
    if (s == NULL) return SM_ERROR;
    drop_state(s);
    *handle = NULL;
    return SM_OK;
}

/* Layout: magic, GUID, then the doubles t, t_start, x, u, p and four ints as doubles: the
 * instance type (1: Co-Simulation), the mode and the two flags. */
#define SM_MAGIC "sarcomere-fmu-state-3"
#define SM_N_DOUBLES (2 + SM_NX + SM_NU + SM_NP + 4)
#define SM_BYTES (sizeof SM_MAGIC + sizeof SM_GUID + SM_N_DOUBLES * sizeof(double))

SmStatus sm_serialized_size(SmInstance* inst, const void* handle, size_t* size,
                            const char* function) {
    if (live_state(inst, handle, function) == NULL) return SM_ERROR;
    if (size == NULL) {
        sm_log(inst, SM_ERROR, SM_LOG_ERROR, "%s: size is NULL", function);
        return SM_ERROR;
    }
    *size = SM_BYTES;
    return SM_OK;
}

SmStatus sm_serialize(SmInstance* inst, const void* handle, char* bytes, size_t size,
                      const char* function) {
    double d[SM_N_DOUBLES];
    const SmState* state = live_state(inst, handle, function);
    if (state == NULL) return SM_ERROR;
    if (bytes == NULL || size != SM_BYTES) {
        sm_log(inst, SM_ERROR, SM_LOG_ERROR, "%s: a buffer of %zu bytes is needed", function,
               (size_t)SM_BYTES);
        return SM_ERROR;
    }
    const SmValues* s = &state->v;
    d[0] = s->t;
    d[1] = s->t_start;
    memcpy(d + 2, s->x, sizeof s->x);
    memcpy(d + 2 + SM_NX, s->u, sizeof s->u);
    memcpy(d + 2 + SM_NX + SM_NU, s->p, sizeof s->p);
    d[SM_N_DOUBLES - 4] = state->cosim;
    d[SM_N_DOUBLES - 3] = s->mode;
    d[SM_N_DOUBLES - 2] = s->x_given;
    d[SM_N_DOUBLES - 1] = s->x_solved;
    memcpy(bytes, SM_MAGIC, sizeof SM_MAGIC);
    memcpy(bytes + sizeof SM_MAGIC, SM_GUID, sizeof SM_GUID);
    memcpy(bytes + sizeof SM_MAGIC + sizeof SM_GUID, d, sizeof d);
    return SM_OK;
}

/* 1 if d is one of the modes (a single bit of SM_ANY), checked before any cast to int. */
static int is_mode(double d) {
    for (int mode = 1; mode <= SM_FAILED; mode <<= 1) {
        if (d == (double)mode) return 1;
    }
    return 0;
}

/* Why the doubles d cannot be a state of this FMU, or NULL. Every range is checked on the
 * double itself, before a cast. */
static const char* invalid_values(const double* d) {
    const double t_max = SM_TIME_RESOLUTION / DBL_EPSILON;
    for (int i = 0; i < SM_N_DOUBLES; i++) {
        if (!isfinite(d[i])) return "a value is not finite";
    }
    if (fabs(d[0]) > t_max || fabs(d[1]) > t_max) return "a time outside the FMU's time range";
    if (!is_mode(d[SM_N_DOUBLES - 3])) return "unknown mode";
    for (int k = 4; k > 0; k--) {
        double flag = d[SM_N_DOUBLES - k];
        if (k != 3 && flag != 0.0 && flag != 1.0) return "a flag that is not 0 or 1";
    }
    for (int i = 0; i < SM_NP; i++) {
        double v = d[2 + SM_NX + SM_NU + i];
        if (v < sm_min[SM_VR_P + i] || v > sm_max[SM_VR_P + i]) return "a parameter out of range";
    }
    for (int i = 0; i < SM_NU; i++) {
        double v = d[2 + SM_NX + i];
        if (v < sm_min[SM_VR_U + i] || v > sm_max[SM_VR_U + i]) return "an input out of range";
    }
    return NULL;
}

SmStatus sm_deserialize(SmInstance* inst, const char* bytes, size_t size, void** handle,
                        const char* function) {
    double d[SM_N_DOUBLES];
    const char* why = NULL;
    if (bytes == NULL || size != SM_BYTES) {
        why = "wrong size";
    } else if (memcmp(bytes, SM_MAGIC, sizeof SM_MAGIC) != 0 ||
               memcmp(bytes + sizeof SM_MAGIC, SM_GUID, sizeof SM_GUID) != 0) {
        why = "not a state of this FMU";
    } else {
        memcpy(d, bytes + sizeof SM_MAGIC + sizeof SM_GUID, sizeof d);
        why = invalid_values(d);
    }
    if (why != NULL) {
        sm_log(inst, SM_ERROR, SM_LOG_ERROR, "%s: refused (%s)", function, why);
        return SM_ERROR;
    }
    int cosim = d[SM_N_DOUBLES - 4] != 0.0, mode = (int)d[SM_N_DOUBLES - 3]; /* checked */
    if (!fits(inst, cosim, mode, function)) return SM_ERROR;
    SmState* state = target_state(inst, handle, function);
    if (state == NULL) return SM_ERROR;
    SmValues* s = &state->v;
    s->t = d[0];
    s->t_start = d[1];
    memcpy(s->x, d + 2, sizeof s->x);
    memcpy(s->u, d + 2 + SM_NX, sizeof s->u);
    memcpy(s->p, d + 2 + SM_NX + SM_NU, sizeof s->p);
    s->mode = mode;
    state->cosim = cosim;
    s->x_given = d[SM_N_DOUBLES - 2] != 0.0;
    s->x_solved = d[SM_N_DOUBLES - 1] != 0.0;
    *handle = state;
    return SM_OK;
}
