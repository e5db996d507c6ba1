/* One FMU instance: modes, argument checks, values and logging (see instance.h). */
#include "instance.h"

#include <float.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

const char* const sm_category_names[SM_N_CATEGORIES] = {"logStatusError", "logStatusWarning",
                                                        "logSolver", "logCalls"};


/* --- logging -------------------------------------------------------------------------- */
static void vlog(SmInstance* inst, SmStatus status, int category, const char* fmt, va_list ap) {
    if (inst->log == NULL || inst->callback == NULL || !(category == SM_LOG_ERROR || (inst->categories & category))) return;
    char msg[SM_MSG];
    vsnprintf(msg, sizeof msg, fmt, ap);
    int index = 0; /* the first known category of the bits given; errors if none */
    while (index < SM_N_CATEGORIES && !(category & (1 << index))) index++;
    if (index == SM_N_CATEGORIES) index = 0;
    inst->log(inst->callback, inst->log_env, inst->name, status, sm_category_names[index], msg);
}

void sm_log(SmInstance* inst, SmStatus status, int category, const char* fmt, ...) {
    va_list ap;
    va_start(ap, fmt);
    vlog(inst, status, category, fmt, ap);
    va_end(ap);
}

SmStatus sm_fail(SmInstance* inst, const char* fmt, ...) {
    va_list ap;
    va_start(ap, fmt);
    vlog(inst, SM_ERROR, SM_LOG_ERROR, fmt, ap);
    va_end(ap);
    inst->v.mode = SM_FAILED;
    return SM_ERROR;
}

static const char* mode_name(int mode) {
    switch (mode) {
        case SM_INSTANTIATED: return "instantiated";
        case SM_INIT: return "initialization mode";
        case SM_STEP: return "step mode";
        case SM_EVENT: return "event mode";
        case SM_CONT: return "continuous-time mode";
        case SM_TERMINATED: return "terminated";
        default: return "error state (after an error: only get, reset and free)";
    }
}

int sm_mode_fits(const SmInstance* inst, int mode) {
    if (mode == SM_STEP) return inst->cosim;
    if (mode == SM_CONT) return !inst->cosim;
    if (mode == SM_EVENT) return !inst->cosim || inst->event_mode;
    return 1;
}

int sm_allowed(SmInstance* inst, int mask, const char* function) {
    if (inst->v.mode & mask) {
        sm_log(inst, SM_OK, SM_LOG_CALLS, "%s", function);
        return 1;
    }
    sm_log(inst, SM_ERROR, SM_LOG_ERROR, "%s is not allowed in %s", function,
           mode_name(inst->v.mode));
    return 0;
}

SmStatus sm_set_logging(SmInstance* inst, int on, size_t n, const char* const* categories) {
    int bits = 0;
    if (n > 0 && categories == NULL) {
        sm_log(inst, SM_ERROR, SM_LOG_ERROR, "setDebugLogging: categories is NULL");
        return SM_ERROR;
    }
    for (size_t i = 0; i < n; i++) {
        int found = 0;
        for (int k = 0; k < SM_N_CATEGORIES && categories[i] != NULL; k++) {
            if (strcmp(categories[i], sm_category_names[k]) == 0) {
                bits |= 1 << k;
                found = 1;
            }
        }
        if (!found) {
            sm_log(inst, SM_ERROR, SM_LOG_ERROR,
                   "setDebugLogging: unknown log category '%s' (logStatusError, "
                   "logStatusWarning, logSolver, logCalls)",
                   categories[i] ? categories[i] : "(null)");
            return SM_ERROR;
        }
    }
    if (n == 0) bits = (1 << SM_N_CATEGORIES) - 1;
    inst->categories = on ? (inst->categories | bits) : (inst->categories & ~bits);
    return SM_OK;
}

/* --- life cycle ----------------------------------------------------------------------- */
void sm_reset(SmInstance* inst) {
    sm_work_release(&inst->wk);
    inst->v.t = 0.0;
    inst->v.t_start = 0.0;
    memcpy(inst->v.x, sm_x_start, sizeof inst->v.x);
    memcpy(inst->v.u, sm_u_start, sizeof inst->v.u);
    memcpy(inst->v.p, sm_p_start, sizeof inst->v.p);
    inst->v.mode = SM_INSTANTIATED;
    inst->v.x_given = 0;
    inst->v.x_solved = 1; /* the start values are the equilibrium at the start point */
    inst->stop_defined = 0;
    inst->t_stop = 0.0;
    inst->substeps = 0;
}

SmInstance* sm_new(const char* name, int cosim, SmLogger log, SmCallback callback, void* log_env,
                   int logging_on) {
    if (!cosim && SM_SAMPLED) { /* no continuous-time form: Model Exchange is refused */
        char msg[SM_MSG];
        snprintf(msg, sizeof msg,
                 "instantiate: '%s' is a sampled system (period %g s): Co-Simulation only, no "
                 "Model Exchange",
                 SM_MODEL_NAME, SM_SAMPLE_PERIOD);
        if (log != NULL && callback != NULL) {
            log(callback, log_env, name, SM_ERROR, "logStatusError", msg);
        }
        return NULL;
    }
    SmInstance* inst = calloc(1, sizeof *inst);
    if (inst == NULL) return NULL;
    inst->name = malloc(strlen(name) + 1);
    if (inst->name == NULL) {
        free(inst);
        return NULL;
    }
    strcpy(inst->name, name);
    inst->cosim = cosim;
    inst->log = log;
    inst->callback = callback;
    inst->log_env = log_env;
    inst->categories = logging_on ? SM_LOG_WARNING : 0;
    sm_reset(inst);
    if (!sm_register(inst)) {
        sm_log(inst, SM_ERROR, SM_LOG_ERROR, "instantiate: out of memory");
        free(inst->name);
        free(inst);
        return NULL;
    }
    return inst;
}

void sm_free(SmInstance* inst) {
    sm_unregister(inst);
    sm_work_release(&inst->wk);
    free(inst->name);
    free(inst);
}

SmStatus sm_setup(SmInstance* inst, double start_time, int stop_defined, double stop_time) {
    const double t_max = SM_TIME_RESOLUTION / DBL_EPSILON;
    if (!isfinite(start_time) || fabs(start_time) > t_max) {
        sm_log(inst, SM_ERROR, SM_LOG_ERROR,
               "setup: start time %g s is outside the FMU's time range [-%g, %g] s", start_time,
               t_max, t_max);
        return SM_ERROR;
    }
    if (stop_defined && (!isfinite(stop_time) || stop_time < start_time)) {
        sm_log(inst, SM_ERROR, SM_LOG_ERROR,
               "setup: stop time %g s is not a finite time >= the start time %g s", stop_time,
               start_time);
        return SM_ERROR;
    }
    inst->v.t = start_time;
    inst->v.t_start = start_time;
    inst->stop_defined = stop_defined != 0;
    inst->t_stop = stop_defined ? stop_time : 0.0;
    return SM_OK;
}

SmStatus sm_enter_init(SmInstance* inst) {
    inst->v.mode = SM_INIT;
    return SM_OK;
}

/* The equilibrium for the current inputs and parameters, unless the importer set the
 * states or it is solved already. */
static SmStatus settle(SmInstance* inst) {
    char msg[SM_MSG] = "";
    if (inst->v.x_given || inst->v.x_solved) return SM_OK;
    double x[SM_NX];
    memcpy(x, sm_x_start, sizeof x);
    if (sm_equilibrium(&inst->wk, x, sm_u_start, sm_p_start, inst->v.u, inst->v.p, msg)) {
        return sm_fail(inst, "initialisation: %s", msg);
    }
    memcpy(inst->v.x, x, sizeof x);
    inst->v.x_solved = 1;
    sm_log(inst, SM_OK, SM_LOG_SOLVER, "initialisation: equilibrium solved");
    return SM_OK;
}

SmStatus sm_exit_init(SmInstance* inst, int next_mode) {
    char msg[SM_MSG] = "";
    if (settle(inst) != SM_OK) return SM_ERROR;
    if (sm_check_domain(&inst->wk, inst->v.x, inst->v.u, inst->v.p, msg)) {
        return sm_fail(inst, "initialisation: %s", msg);
    }
    inst->v.mode = next_mode;
    return SM_OK;
}

/* --- values --------------------------------------------------------------------------- */
static int check_vrs(SmInstance* inst, const unsigned* vr, size_t n, const void* values,
                     const char* function) {
    if (n > 0 && (vr == NULL || values == NULL)) {
        sm_log(inst, SM_ERROR, SM_LOG_ERROR, "%s: a NULL array with %zu values", function, n);
        return 0;
    }
    for (size_t i = 0; i < n; i++) {
        if (vr[i] > SM_NVARS || (vr[i] == SM_VR_TIME && !SM_HAS_TIME_VR)) {
            sm_log(inst, SM_ERROR, SM_LOG_ERROR,
                   "%s: unknown value reference %u (this FMU has Float64/Real variables %d to %d)",
                   function, vr[i], SM_HAS_TIME_VR ? SM_VR_TIME : SM_VR_X, SM_NVARS);
            return 0;
        }
    }
    return 1;
}

SmStatus sm_set_reals(SmInstance* inst, const unsigned* vr, size_t n, const double* value) {
    const int before_run = SM_INSTANTIATED | SM_INIT;
    if (!sm_allowed(inst, SM_ANY & ~(SM_TERMINATED | SM_FAILED), "set real") ||
        !check_vrs(inst, vr, n, value, "set real")) {
        return SM_ERROR;
    }
    for (size_t i = 0; i < n; i++) { /* check all first: a refused call changes nothing */
        unsigned r = vr[i];
        const char* name = sm_names[r];
        int is_x = r >= SM_VR_X && r < SM_VR_DER, is_u = r >= SM_VR_U && r < SM_VR_Y;
        int is_p = r >= SM_VR_P;
        if (r == SM_VR_TIME) {
            sm_log(inst, SM_ERROR, SM_LOG_ERROR, "set real: time is the independent variable");
            return SM_ERROR;
        }
        if (!(is_x || is_u || is_p)) {
            sm_log(inst, SM_ERROR, SM_LOG_ERROR, "set real: %s is %s and cannot be set", name,
                   r < SM_VR_U ? "a state derivative" : "an output");
            return SM_ERROR;
        }
        /* Model Exchange: setting a state by value reference is setting the continuous
         * states (importers such as CasADi's do so) */
        if (is_x && !(inst->v.mode & (before_run | SM_EVENT | SM_CONT))) {
            sm_log(inst, SM_ERROR, SM_LOG_ERROR,
                   "set real: %s is a state; it can be set only before the end of "
                   "initialisation (Co-Simulation)",
                   name);
            return SM_ERROR;
        }
        if (is_p && !(inst->v.mode & before_run) &&
            !(sm_tunable[r - SM_VR_P] && (inst->v.mode & (SM_STEP | SM_EVENT)))) {
            sm_log(inst, SM_ERROR, SM_LOG_ERROR, "set real: %s is %s", name,
                   sm_tunable[r - SM_VR_P]
                       ? "a tunable parameter; after initialisation it can be set in step mode "
                         "(Co-Simulation) or event mode (Model Exchange)"
                       : "a fixed parameter; it can be set only before the end of "
                         "initialisation");
            return SM_ERROR;
        }
        if (!isfinite(value[i]) || value[i] < sm_min[r] || value[i] > sm_max[r]) {
            sm_log(inst, SM_ERROR, SM_LOG_ERROR, "set real: %s = %.17g is outside [%.17g, %.17g]",
                   name, value[i], sm_min[r], sm_max[r]);
            return SM_ERROR;
        }
    }
    for (size_t i = 0; i < n; i++) {
        unsigned r = vr[i]; /* a state, an input or a parameter: checked above */
        if (r < SM_VR_DER) {
            inst->v.x[r - SM_VR_X] = value[i];
            inst->v.x_given |= (inst->v.mode & before_run) != 0;
        } else if (r < SM_VR_Y) {
            if (inst->v.u[r - SM_VR_U] != value[i]) inst->v.x_solved = 0;
            inst->v.u[r - SM_VR_U] = value[i];
        } else {
            if (inst->v.p[r - SM_VR_P] != value[i]) inst->v.x_solved = 0;
            inst->v.p[r - SM_VR_P] = value[i];
        }
    }
    return SM_OK;
}

SmStatus sm_get_reals(SmInstance* inst, const unsigned* vr, size_t n, double* value) {
    double xdot[SM_NX], y[SM_NY];
    int have_xdot = 0, have_y = 0;
    if (!sm_allowed(inst, SM_ANY & ~SM_INSTANTIATED, "get real") ||
        !check_vrs(inst, vr, n, value, "get real")) {
        return SM_ERROR;
    }
    if (inst->v.mode == SM_INIT && settle(inst) != SM_OK) return SM_ERROR;
    for (size_t i = 0; i < n; i++) {
        unsigned r = vr[i];
        if (r == SM_VR_TIME) {
            value[i] = inst->v.t;
        } else if (r < SM_VR_DER) {
            value[i] = inst->v.x[r - SM_VR_X];
        } else if (r < SM_VR_U) {
            if (!have_xdot && sm_derivatives(&inst->wk, inst->v.x, inst->v.u, inst->v.p, xdot)) {
                return sm_fail(inst, "get real: the state derivatives are not finite");
            }
            have_xdot = 1;
            value[i] = xdot[r - SM_VR_DER];
        } else if (r < SM_VR_Y) {
            value[i] = inst->v.u[r - SM_VR_U];
        } else if (r < SM_VR_P) {
            if (!have_y && sm_outputs(&inst->wk, inst->v.x, inst->v.u, inst->v.p, y)) {
                return sm_fail(inst, "get real: the outputs are not finite");
            }
            have_y = 1;
            value[i] = y[r - SM_VR_Y];
        } else {
            value[i] = inst->v.p[r - SM_VR_P];
        }
    }
    return SM_OK;
}

/* --- Co-Simulation -------------------------------------------------------------------- */
/* Refuses a step that cannot be taken: not a finite h > 0, a t + h that does not advance
 * time or leaves the FMU's time range, one past the stop time given at set-up, or (a
 * sampled system) one holding more than SM_MAX_SAMPLES sample instants. */
static int check_step(SmInstance* inst, double t, double h) {
    const double t_max = SM_TIME_RESOLUTION / DBL_EPSILON;
    const char* why = NULL;
    if (!isfinite(h) || !(h > 0.0)) {
        why = "is not a finite number > 0";
    } else if (t + h == t) {
        why = "does not advance the time (below its resolution at t)";
    } else if (fabs(t + h) > t_max) {
        sm_log(inst, SM_ERROR, SM_LOG_ERROR,
               "doStep: step size %g s ends at t = %g s, outside the FMU's time range [-%g, %g] "
               "s (where doubles resolve %g s)",
               h, t + h, t_max, t_max, SM_TIME_RESOLUTION);
        return 0;
    } else if (inst->stop_defined && t + h > inst->t_stop + 1e-9 * (1.0 + fabs(inst->t_stop))) {
        sm_log(inst, SM_ERROR, SM_LOG_ERROR,
               "doStep: step size %g s ends at t = %.9g s, past the stop time %.9g s given at "
               "set-up",
               h, t + h, inst->t_stop);
        return 0;
    } else if (sm_samples(t - inst->v.t_start, h) > SM_MAX_SAMPLES) {
        sm_log(inst, SM_ERROR, SM_LOG_ERROR,
               "doStep: step size %g s holds %.0f sample instants (period %g s), more than %d "
               "in one doStep (all would see the same held inputs): take shorter doSteps",
               h, sm_samples(t - inst->v.t_start, h), SM_SAMPLE_PERIOD, SM_MAX_SAMPLES);
        return 0;
    }
    if (why != NULL) {
        sm_log(inst, SM_ERROR, SM_LOG_ERROR, "doStep: step size %g %s", h, why);
        return 0;
    }
    return 1;
}

SmStatus sm_do_step(SmInstance* inst, double t, double h) {
    char msg[SM_MSG] = "";
    double x[SM_NX];
    if (!sm_allowed(inst, SM_STEP, "doStep")) return SM_ERROR;
    if (!isfinite(t) || fabs(t - inst->v.t) > 1e-9 * (1.0 + fabs(t))) {
        sm_log(inst, SM_ERROR, SM_LOG_ERROR,
               "doStep: communication point %.17g is not the FMU's time %.17g", t, inst->v.t);
        return SM_ERROR;
    }
    if (!check_step(inst, t, h)) return SM_ERROR;
    memcpy(x, inst->v.x, sizeof x);
    if (sm_advance(&inst->wk, x, inst->v.u, inst->v.p, t - inst->v.t_start, h, &inst->substeps,
                   msg)) {
        return sm_fail(inst, "doStep from t = %.9g s: %s", t, msg);
    }
    if (sm_check_domain(&inst->wk, x, inst->v.u, inst->v.p, msg)) {
        return sm_fail(inst, "doStep to t = %.9g s: %s", t + h, msg);
    }
    memcpy(inst->v.x, x, sizeof x);
    inst->v.t = t + h;
    sm_log(inst, SM_OK, SM_LOG_SOLVER, "doStep to t = %.9g s: %ld %s", inst->v.t, inst->substeps,
           SM_ADVANCE_UNIT);
    return SM_OK;
}

/* --- Model Exchange ------------------------------------------------------------------- */
SmStatus sm_set_time(SmInstance* inst, double t) {
    if (!sm_allowed(inst, SM_EVENT | SM_CONT, "setTime")) return SM_ERROR;
    if (!isfinite(t)) {
        sm_log(inst, SM_ERROR, SM_LOG_ERROR, "setTime: %g is not finite", t);
        return SM_ERROR;
    }
    inst->v.t = t;
    return SM_OK;
}

static int check_n(SmInstance* inst, size_t n, const void* array, const char* function) {
    if (array == NULL || n != SM_NX) {
        sm_log(inst, SM_ERROR, SM_LOG_ERROR, "%s: expected an array of %d states, got %zu%s",
               function, SM_NX, n, array == NULL ? " (NULL)" : "");
        return 0;
    }
    return 1;
}

SmStatus sm_set_states(SmInstance* inst, const double* x, size_t n) {
    if (!sm_allowed(inst, SM_EVENT | SM_CONT, "setContinuousStates") ||
        !check_n(inst, n, x, "setContinuousStates")) {
        return SM_ERROR;
    }
    for (size_t i = 0; i < n; i++) {
        if (!isfinite(x[i])) {
            sm_log(inst, SM_ERROR, SM_LOG_ERROR, "setContinuousStates: %s = %g is not finite",
                   sm_names[SM_VR_X + i], x[i]);
            return SM_ERROR;
        }
    }
    memcpy(inst->v.x, x, sizeof inst->v.x);
    return SM_OK;
}

SmStatus sm_get_states(SmInstance* inst, double* x, size_t n) {
    if (!sm_allowed(inst, SM_ANY & ~SM_INSTANTIATED, "getContinuousStates") ||
        !check_n(inst, n, x, "getContinuousStates")) {
        return SM_ERROR;
    }
    if (inst->v.mode == SM_INIT && settle(inst) != SM_OK) return SM_ERROR;
    memcpy(x, inst->v.x, sizeof inst->v.x);
    return SM_OK;
}

SmStatus sm_get_derivatives(SmInstance* inst, double* xdot, size_t n) {
    if (!sm_allowed(inst, SM_ANY & ~SM_INSTANTIATED, "getDerivatives") ||
        !check_n(inst, n, xdot, "getDerivatives")) {
        return SM_ERROR;
    }
    if (inst->v.mode == SM_INIT && settle(inst) != SM_OK) return SM_ERROR;
    if (sm_derivatives(&inst->wk, inst->v.x, inst->v.u, inst->v.p, xdot)) {
        sm_log(inst, SM_ERROR, SM_LOG_ERROR, "getDerivatives: not finite at t = %g", inst->v.t);
        return SM_ERROR;
    }
    return SM_OK;
}

SmStatus sm_get_nominals(SmInstance* inst, double* nominal, size_t n) {
    if (!check_n(inst, n, nominal, "getNominalsOfContinuousStates")) return SM_ERROR;
    memcpy(nominal, sm_x_nominal, sizeof sm_x_nominal);
    return SM_OK;
}

SmStatus sm_get_directional(SmInstance* inst, const unsigned* unknown, size_t n_unknown,
                        const unsigned* known, size_t n_known, const double* seed,
                        double* sensitivity) {
    const char* f = "getDirectionalDerivative";
    double dx[SM_NX] = {0}, du[SM_NU] = {0}, dxdot[SM_NX], dy[SM_NY];
    if (!sm_allowed(inst, SM_ANY & ~(SM_INSTANTIATED | SM_FAILED), f) ||
        !check_vrs(inst, known, n_known, seed, f) ||
        !check_vrs(inst, unknown, n_unknown, sensitivity, f)) {
        return SM_ERROR;
    }
    if (SM_SAMPLED) {
        sm_log(inst, SM_ERROR, SM_LOG_ERROR, "%s: a sampled system has no derivatives", f);
        return SM_ERROR;
    }
    for (size_t i = 0; i < n_known; i++) {
        unsigned r = known[i];
        if (r >= SM_VR_X && r < SM_VR_DER) {
            dx[r - SM_VR_X] += seed[i];
        } else if (r >= SM_VR_U && r < SM_VR_Y) {
            du[r - SM_VR_U] += seed[i];
        } else {
            sm_log(inst, SM_ERROR, SM_LOG_ERROR, "%s: known %s is not a state or an input", f,
                   sm_names[r]);
            return SM_ERROR;
        }
        if (!isfinite(seed[i])) {
            sm_log(inst, SM_ERROR, SM_LOG_ERROR, "%s: seed of %s is not finite", f, sm_names[r]);
            return SM_ERROR;
        }
    }
    for (size_t i = 0; i < n_unknown; i++) {
        unsigned r = unknown[i];
        if (!((r >= SM_VR_DER && r < SM_VR_U) || (r >= SM_VR_Y && r < SM_VR_P))) {
            sm_log(inst, SM_ERROR, SM_LOG_ERROR,
                   "%s: unknown %s is not a state derivative or an output", f, sm_names[r]);
            return SM_ERROR;
        }
    }
    if (inst->v.mode == SM_INIT && settle(inst) != SM_OK) return SM_ERROR;
    if (sm_directional(&inst->wk, inst->v.x, inst->v.u, inst->v.p, dx, du,
                       dxdot, dy)) {
        sm_log(inst, SM_ERROR, SM_LOG_ERROR, "%s: not finite", f);
        return SM_ERROR;
    }
    for (size_t i = 0; i < n_unknown; i++) {
        unsigned r = unknown[i];
        sensitivity[i] = r < SM_VR_U ? dxdot[r - SM_VR_DER] : dy[r - SM_VR_Y];
    }
    return SM_OK;
}
