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
    int event_mode; /* FMI 3.0 Co-Simulation: the importer uses event mode (eventModeUsed) */
    SmLogger log;
    SmCallback callback;
    void* log_env;
    int categories;
    SmValues v;
    int stop_defined; /* the set-up gave a stop time: no doStep goes past t_stop */
    double t_stop;
    long substeps; /* Radau substeps (or samples, a sampled system) of the last doStep */
    SmWork wk;
} SmInstance;

/* A saved state: a copy of the values and the instance that made it (freed with it). Its
 * handle is used only while the registry of saved states lists it: a freed, foreign or
 * bogus pointer is refused without being read. */
typedef struct {
    SmValues v;
    int cosim; /* made by a Co-Simulation instance: set only on one */
    const SmInstance* maker;
} SmState;

/* Time range of the FMU [s]: beyond it doubles no longer resolve SM_TIME_RESOLUTION, and
 * a doStep whose end lies beyond it is refused (SM_TIME_RESOLUTION / DBL_EPSILON, 4.5e6 s,
 * 52 days). */
#define SM_TIME_RESOLUTION 1e-9

SmInstance* sm_new(const char* name, int cosim, SmLogger log, SmCallback callback, void* log_env,
                   int logging_on);
void sm_free(SmInstance* inst);
/* registry.c: lists a new instance (0 if out of memory); removes one, freeing its states. */
int sm_register(SmInstance* inst);
void sm_unregister(SmInstance* inst);
/* The instance behind a handle the importer passed, or NULL (then logs, if the handle is one
 * freed before). Every API call starts with it. */
SmInstance* sm_lookup(void* handle, const char* function);

void sm_log(SmInstance* inst, SmStatus status, int category, const char* fmt, ...);
/* 1 if the instance is in one of the modes of mask; else logs an error naming function. */
int sm_allowed(SmInstance* inst, int mask, const char* function);
SmStatus sm_fail(SmInstance* inst, const char* fmt, ...); /* logs, enters SM_FAILED */
/* 1 if an instance of inst's type has mode: step mode is Co-Simulation's, continuous-time
 * mode Model Exchange's, event mode Model Exchange's or an FMI 3.0 Co-Simulation's that
 * uses it (event_mode). */
int sm_mode_fits(const SmInstance* inst, int mode);

SmStatus sm_set_logging(SmInstance* inst, int on, size_t n, const char* const* categories);
void sm_reset(SmInstance* inst);
/* Start time, and the stop time if stop_defined: finite, stop >= start. */
SmStatus sm_setup(SmInstance* inst, double start_time, int stop_defined, double stop_time);
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

/* Saved states, by the importer's handles (void*: checked against the registry before any
 * use); serialised as a checked byte string. `*handle` NULL asks for a new state, else it
 * must be a live one, which is overwritten. */
SmStatus sm_get_state(SmInstance* inst, void** handle, const char* function);
SmStatus sm_set_state(SmInstance* inst, const void* handle, const char* function);
SmStatus sm_free_state(SmInstance* inst, void** handle, const char* function);
SmStatus sm_serialized_size(SmInstance* inst, const void* handle, size_t* size,
                            const char* function);
SmStatus sm_serialize(SmInstance* inst, const void* handle, char* bytes, size_t size,
                      const char* function);
SmStatus sm_deserialize(SmInstance* inst, const char* bytes, size_t size, void** handle,
                        const char* function);

#endif
