/* One FMU instance apart from any FMI version: its mode, values and checks. fmi2.c and
 * fmi3.c translate the standard's calls into these functions; physics.c does the maths. */
#ifndef SM_INSTANCE_H
#define SM_INSTANCE_H

#include <stddef.h>

#include "physics.h"

/* Statuses in the order of fmi2Status and fmi3Status (both number them alike). */
typedef enum { SM_OK = 0, SM_WARNING = 1, SM_DISCARD = 2, SM_ERROR = 3, SM_FATAL = 4 } SmStatus;

/* Modes as bits, so a call names the set of modes it is allowed in. */
enum {
    SM_INSTANTIATED = 1,
    SM_INIT = 2,
    SM_STEP = 4,  /* Co-Simulation: step mode */
    SM_EVENT = 8, /* Model Exchange */
    SM_CONT = 16, /* Model Exchange: continuous-time mode */
    SM_TERMINATED = 32,
    SM_FAILED = 64, /* after an error: only get, reset and free */
    SM_ANY = 127
};

/* Log categories (bits of SmInstance.categories); errors are always logged. */
enum { SM_LOG_ERROR = 1, SM_LOG_WARNING = 2, SM_LOG_SOLVER = 4, SM_LOG_CALLS = 8 };
#define SM_N_CATEGORIES 4
extern const char* const sm_category_names[SM_N_CATEGORIES];

/* The importer's logger, whatever its FMI signature (the FMI layer casts it back), and the
 * FMI layer's adapter that calls it. */
typedef void (*SmCallback)(void);
typedef void (*SmLogger)(SmCallback callback, void* env, const char* instance, SmStatus status,
                         const char* category, const char* message);

/* Everything a saved FMU state holds. */
typedef struct {
    const char* owner; /* the tag of the FMU that made it: a foreign state is refused */
    double t;
    double t_start; /* setupExperiment's start time: sample instants count from it */
    double x[SM_NX];
    double u[SM_NU];
    double p[SM_NP];
    int mode;
    int x_given; /* the importer set the states: no equilibrium at initialisation */
    int x_solved; /* the equilibrium for the current u, p is in x */
} SmValues;

typedef struct {
    char* name;
    int cosim;
    SmLogger log;
    SmCallback callback;
    void* log_env;
    int categories;
    SmValues v;
    long substeps; /* Radau substeps (or samples, a sampled system) of the last doStep */
    SmWork wk;
} SmInstance;

SmInstance* sm_new(const char* name, int cosim, SmLogger log, SmCallback callback, void* log_env,
                   int logging_on);
void sm_free(SmInstance* inst);
/* The instance behind a handle the importer passed, or NULL (then logs, if the handle is one
 * freed before). Every API call starts with it. */
SmInstance* sm_lookup(void* handle, const char* function);

void sm_log(SmInstance* inst, SmStatus status, int category, const char* fmt, ...);
/* 1 if the instance is in one of the modes of mask; else logs an error naming function. */
int sm_allowed(SmInstance* inst, int mask, const char* function);
SmStatus sm_fail(SmInstance* inst, const char* fmt, ...); /* logs, enters SM_FAILED */

SmStatus sm_set_logging(SmInstance* inst, int on, size_t n, const char* const* categories);
void sm_reset(SmInstance* inst);
SmStatus sm_setup(SmInstance* inst, double start_time);
SmStatus sm_enter_init(SmInstance* inst);
SmStatus sm_exit_init(SmInstance* inst, int next_mode);
SmStatus sm_set_reals(SmInstance* inst, const unsigned* vr, size_t n, const double* value);
SmStatus sm_get_reals(SmInstance* inst, const unsigned* vr, size_t n, double* value);
SmStatus sm_do_step(SmInstance* inst, double t, double h);
SmStatus sm_set_time(SmInstance* inst, double t);
SmStatus sm_set_states(SmInstance* inst, const double* x, size_t n);
SmStatus sm_get_states(SmInstance* inst, double* x, size_t n);
SmStatus sm_get_derivatives(SmInstance* inst, double* xdot, size_t n);
SmStatus sm_get_nominals(SmInstance* inst, double* nominal, size_t n);
SmStatus sm_get_directional(SmInstance* inst, const unsigned* unknown, size_t n_unknown,
                        const unsigned* known, size_t n_known, const double* seed,
                        double* sensitivity);

/* Saved states: copies of SmValues; serialised as a checked byte string. */
SmValues* sm_get_state(SmInstance* inst, SmValues* reuse);
SmStatus sm_set_state(SmInstance* inst, const SmValues* state);
size_t sm_serialized_size(void);
SmStatus sm_serialize(SmInstance* inst, const SmValues* state, char* bytes, size_t size);
SmValues* sm_deserialize(SmInstance* inst, const char* bytes, size_t size);

#endif
