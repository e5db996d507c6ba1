/* The physics interface (physics.h) on top of the CasADi-generated functions. Numerics
 * only: the continuation of the equilibrium and the adaptive Radau IIA of a doStep
 * (radau.c), or the sample instants of a sampled system. */
#include "physics.h"

#include <float.h>
#include <math.h>
#include <stdio.h>
#include <string.h>

#include "sm_casadi.h"
#if SM_SHARED_MEMORY
#include <stdatomic.h>
#endif
#if !SM_SAMPLED
#include "sm_radau.h"
#endif

typedef int (*SmFunction)(const casadi_real** arg, casadi_real** res, casadi_int* iw,
                          casadi_real* w, int mem);

static int all_finite(const double* v, int n) {
    for (int i = 0; i < n; i++) {
        if (!isfinite(v[i])) return 0;
    }
    return 1;
}

static int call(SmWork* wk, SmFunction f, int n_arg, const double** arg, int n_res, double** res) {
    for (int i = 0; i < n_arg; i++) wk->arg[i] = arg[i];
    for (int i = 0; i < n_res; i++) wk->res[i] = res[i];
    return f(wk->arg, wk->res, wk->iw, wk->w, 0);
}

int sm_outputs(SmWork* wk, const double* x, const double* u, const double* p, double* y) {
    const double* arg[] = {x, u, p};
    double* res[] = {y};
    return call(wk, sm_out, 3, arg, 1, res) || !all_finite(y, SM_NY);
}

int sm_check_domain(SmWork* wk, const double* x, const double* u, const double* p, char* msg) {
    double y[SM_NY];
    if (sm_outputs(wk, x, u, p, y)) {
        snprintf(msg, SM_MSG, "the outputs are not finite");
        return 1;
    }
    for (int i = 0; i < SM_NY; i++) {
        int vr = SM_VR_Y + i;
        if (y[i] < sm_min[vr] || y[i] > sm_max[vr]) {
            snprintf(msg, SM_MSG, "%s = %.6g is outside its physical domain [%.6g, %.6g]",
                     sm_names[vr], y[i], sm_min[vr], sm_max[vr]);
            return 1;
        }
    }
    for (int i = 0; i < SM_NX; i++) {
        if (x[i] < sm_min[SM_VR_X + i] || x[i] > sm_max[SM_VR_X + i]) {
            snprintf(msg, SM_MSG, "%s = %.6g is outside its physical domain [%.6g, %.6g]",
                     sm_names[SM_VR_X + i], x[i], sm_min[SM_VR_X + i], sm_max[SM_VR_X + i]);
            return 1;
        }
    }
    return 0;
}

#if SM_SAMPLED
/* --- a sampled system: no continuous-time form (instantiation refuses Model Exchange) --- */
int sm_derivatives(SmWork* wk, const double* x, const double* u, const double* p, double* xdot) {
    (void)wk, (void)x, (void)u, (void)p, (void)xdot;
    return 1;
}

int sm_directional(SmWork* wk, const double* x, const double* u, const double* p,
                   const double* dx, const double* du, double* dxdot, double* dy) {
    (void)wk, (void)x, (void)u, (void)p, (void)dx, (void)du, (void)dxdot, (void)dy;
    return 1;
}

int sm_equilibrium(SmWork* wk, double* x, const double* u0, const double* p0, const double* u,
                   const double* p, char* msg) {
    double xs[SM_NX];
    const double* arg[] = {u, p};
    double* res[] = {xs};
    (void)u0, (void)p0;
    if (call(wk, sm_start, 2, arg, 1, res) || !all_finite(xs, SM_NX)) {
        snprintf(msg, SM_MSG, "the start state is not finite");
        return 1;
    }
    memcpy(x, xs, sizeof xs);
    return 0;
}

int sm_set_tolerance(SmWork* wk, int defined, double tolerance, char* msg) {
    (void)wk, (void)defined, (void)tolerance, (void)msg;
    return 0;
}

void sm_work_release(SmWork* wk) { (void)wk; }

/* The sample instants k T in [t, t + h): k from ceil(t / T) to ceil((t + h) / T) - 1. */
static double first_sample(double t) { return ceil(t / SM_SAMPLE_PERIOD - SM_SAMPLE_TOL); }

double sm_samples(double t, double h) {
    return ceil((t + h) / SM_SAMPLE_PERIOD - SM_SAMPLE_TOL) - first_sample(t);
}

#if SM_SHARED_MEMORY
/* The generated law keeps a solver's memory in static slots, one per loaded binary
 * (CasADi's code generation): one update at a time in the process, so instances stepped in
 * parallel threads wait for each other instead of failing. */
static atomic_flag law_lock = ATOMIC_FLAG_INIT;
#endif

static int update(SmWork* wk, const double* x, const double* u, const double* p, double* xn) {
    const double* arg[] = {x, u, p};
    double* res[] = {xn};
#if SM_SHARED_MEMORY
    while (atomic_flag_test_and_set(&law_lock)) {
    }
#endif
    int failed = call(wk, sm_update, 3, arg, 1, res);
#if SM_SHARED_MEMORY
    atomic_flag_clear(&law_lock);
#endif
    return failed;
}

int sm_advance(SmWork* wk, double* x, const double* u, const double* p, double t, double h,
               long* substeps, char* msg) {
    double xw[SM_NX], xn[SM_NX];
    double first = first_sample(t), end = first + sm_samples(t, h);
    memcpy(xw, x, sizeof xw);
    *substeps = 0;
    for (double k = first; k < end; k += 1.0) {
        if (update(wk, xw, u, p, xn)) {
            snprintf(msg, SM_MSG,
                     "the law's generated code failed at the sample t = %.9g s (a solver inside "
                     "it returned an error)",
                     k * SM_SAMPLE_PERIOD);
            return 1;
        }
        if (!all_finite(xn, SM_NX)) {
            snprintf(msg, SM_MSG, "the update at the sample t = %.9g s is not finite",
                     k * SM_SAMPLE_PERIOD);
            return 1;
        }
        memcpy(xw, xn, sizeof xw);
        (*substeps)++;
    }
    memcpy(x, xw, sizeof xw);
    return 0;
}
#else
/* --- a continuous model: ODE, equilibrium, Radau IIA ---------------------------------- */
int sm_derivatives(SmWork* wk, const double* x, const double* u, const double* p, double* xdot) {
    const double* arg[] = {x, u, p};
    double* res[] = {xdot};
    return call(wk, sm_ode, 3, arg, 1, res) || !all_finite(xdot, SM_NX);
}

int sm_directional(SmWork* wk, const double* x, const double* u, const double* p,
                   const double* dx, const double* du, double* dxdot, double* dy) {
    const double* arg[] = {x, u, p, dx, du};
    double* res[] = {dxdot, dy};
    return call(wk, sm_fwd, 5, arg, 2, res) || !all_finite(dxdot, SM_NX) ||
           !all_finite(dy, SM_NY);
}

/* One Newton solve of the equilibrium at (u, p) from x; 0 and x updated on success. */
static int newton(SmWork* wk, double* x, const double* u, const double* p, double* residual,
                  char* msg) {
    double xn[SM_NX];
    const double* arg[] = {x, u, p};
    double* res[] = {xn, residual};
    if (call(wk, sm_eq, 3, arg, 2, res) || !all_finite(xn, SM_NX) || !(*residual < SM_EQ_TOL)) {
        return 1;
    }
    if (sm_check_domain(wk, xn, u, p, msg)) return 1;
    memcpy(x, xn, sizeof xn);
    return 0;
}

int sm_equilibrium(SmWork* wk, double* x, const double* u0, const double* p0, const double* u,
                   const double* p, char* msg) {
    double xw[SM_NX], uc[SM_NU], pc[SM_NP], residual = NAN;
    double frac = 0.0, step = 1.0;
    char why[SM_MSG] = "";
    memcpy(xw, x, sizeof xw);
    while (frac < 1.0) {
        double next = frac + step < 1.0 ? frac + step : 1.0;
        for (int i = 0; i < SM_NU; i++) uc[i] = u0[i] + next * (u[i] - u0[i]);
        for (int i = 0; i < SM_NP; i++) pc[i] = p0[i] + next * (p[i] - p0[i]);
        why[0] = '\0';
        if (newton(wk, xw, uc, pc, &residual, why)) {
            step /= 2;
            if (step < SM_EQ_MIN_FRACTION) {
                snprintf(msg, SM_MSG,
                         "equilibrium not found: scaled residual %.3g after %d Newton iterations "
                         "(tolerance %.3g)%s%s; the continuation from the exported operating "
                         "point reached %.3g %% of the way to the inputs and parameters set",
                         residual, SM_EQ_ITERATIONS, SM_EQ_TOL, why[0] ? "; " : "", why,
                         100 * frac);
                return 1;
            }
            continue;
        }
        frac = next;
        step = 2 * step < 1.0 ? 2 * step : 1.0;
    }
    memcpy(x, xw, sizeof xw);
    return 0;
}

int sm_set_tolerance(SmWork* wk, int defined, double tolerance, char* msg) {
    if (!defined) {
        wk->rtol = 0.0;
        return 0;
    }
    if (!(tolerance >= SM_RTOL_MIN && tolerance <= SM_RTOL_MAX)) {
        snprintf(msg, SM_MSG,
                 "tolerance %g is outside the relative tolerances of the Co-Simulation's "
                 "Radau IIA [%g, %g]",
                 tolerance, SM_RTOL_MIN, SM_RTOL_MAX);
        return 1;
    }
    wk->rtol = tolerance;
    return 0;
}

static const char* radau_cause(int code) {
    switch (code) {
        case 1: return "too many steps (SM_RADAU_MAX_STEPS in one doStep)";
        case 2: return "the step size became too small";
        case 3: return "the Newton iteration failed to converge repeatedly (11 step halvings)";
        case 4: return "the Jacobian is not finite";
        case 5: return "out of memory";
        case 6: return "the right-hand side is not finite";
        default: return "unknown failure";
    }
}

double sm_samples(double t, double h) {
    (void)t, (void)h;
    return 0.0;
}

#if SM_PWM
/* The PWM (physics.h; dynamics/simulation/pwm.py): the effective duty, the command at t
 * (the duty d from the carrier time t_switch on, prev before it) and the next edge. */
static double pwm_duty(double d) {
    double brief = SM_PWM_MIN_ON * (1.0 - 1e-9) / SM_PWM_PERIOD;
    return d < brief ? 0.0 : (1.0 - d < brief ? 1.0 : d);
}

static double pwm_command(double t, double d, double prev, double t_switch) {
    double s = t - SM_PWM_DELAY, T = SM_PWM_PERIOD;
    double duty = pwm_duty(s >= t_switch ? d : prev);
    return s - T * floor(s / T) < duty * T ? 1.0 : 0.0;
}

/* The first edge after t by more than rounding (so that every piece advances). */
static double pwm_next_edge(double t, double d, double prev, double t_switch) {
    double s = t - SM_PWM_DELAY, T = SM_PWM_PERIOD, next = INFINITY;
    double after = t + 1e-12 * (1.0 + fabs(t)), k = floor(s / T);
    for (int j = 0; j < 3; j++) {
        double start = (k + j) * T;
        double edges[4] = {start, start + pwm_duty(prev) * T, start + pwm_duty(d) * T,
                           j ? INFINITY : t_switch};
        for (int i = 0; i < 4; i++) {
            double e = edges[i] + SM_PWM_DELAY;
            if (e > after && e < next) next = e;
        }
    }
    return next;
}
#endif


void sm_work_release(SmWork* wk) {
    sm_radau_free(wk->radau);
    wk->radau = NULL;
    wk->carried = 0;
}

int sm_advance(SmWork* wk, double* x, const double* u, const double* p, double t, double h,
               long* substeps, char* msg) {
    double rtol = wk->rtol > 0.0 ? wk->rtol : SM_RTOL;
    /* atol in the scaled states (times each state's scale); first step automatic */
    double opt[4] = {rtol, fmax(SM_ATOL_PER_RTOL * rtol, SM_ATOL_MIN), 0.0, INFINITY};
    double stats[SM_RADAU_STATS] = {0.0};
    double xw[SM_NX], xf[SM_NX], t_end = t + h, t_fail = t;
    int code = 0;
    *substeps = 0;
    if (!(h > 0.0)) return 0;
    if (wk->radau == NULL && (wk->radau = sm_radau_new(SM_NX)) == NULL) {
        snprintf(msg, SM_MSG, "the Radau IIA integrator: out of memory");
        return 1;
    }
#if SM_PWM
    int resume = 0; /* every switching edge restarts the integrator */
#else
    /* nothing set since the last doStep: continue its integration (radau.c checks t) */
    int resume = wk->carried && wk->end_rtol == rtol && !memcmp(x, wk->end_x, sizeof xw) &&
                 !memcmp(u, wk->end_u, sizeof(double) * SM_NU) &&
                 !memcmp(p, wk->end_p, sizeof(double) * SM_NP);
#endif
    if (resume) {
        memcpy(xw, wk->end_xw, sizeof xw);
    } else {
        for (int i = 0; i < SM_NX; i++) xw[i] = x[i] / sm_radau_scale[i]; /* what sm_rhs takes */
    }
    wk->carried = 0;
#if SM_PWM
    double ua[SM_NU], d = u[SM_PWM_INPUT];
    double prev = wk->pwm_started ? wk->pwm_prev : d;
    memcpy(ua, u, sizeof ua);
    ua[SM_PWM_INPUT] = pwm_duty(d);
    /* the pieces between edges, each with its command held (averaged: one piece) */
    for (double a = t; a < t_end && !code;) {
        double b = SM_PWM_AVERAGED ? t_end : fmin(pwm_next_edge(a, d, prev, t), t_end);
        if (!SM_PWM_AVERAGED) ua[SM_PWM_INPUT] = pwm_command(0.5 * (a + b), d, prev, t);
        if (b - a > 1e-13 * (1.0 + fabs(b))) { /* shorter: an edge twice, to rounding */
            double b_out = b;
            code = sm_radau(wk->radau, ua, p, a, xw, 1, &b_out, xf, sm_radau_tableau, opt,
                            SM_RADAU_MAX_STEPS, SM_RADAU_MAX_NEWTON, stats, &t_fail, 0);
            *substeps = (long)stats[0]; /* radau.c adds to its counters */
            memcpy(xw, xf, sizeof xw);
        }
        a = b;
    }
    if (!code) wk->pwm_prev = d, wk->pwm_started = 1;
#else
    code = sm_radau(wk->radau, u, p, t, xw, 1, &t_end, xf, sm_radau_tableau, opt,
                    SM_RADAU_MAX_STEPS, SM_RADAU_MAX_NEWTON, stats, &t_fail, resume);
    *substeps = (long)stats[0];
#endif
    if (code) {
        /* radau.c's smallest step: 10 machine epsilons of the larger of |t| and h */
        char why[SM_MSG / 2] = "";
        if (code == 2 && h >= fabs(t_fail)) {
            snprintf(why, sizeof why,
                     " (below %.3g s, 10 machine epsilons of this doStep's length %g s: it is "
                     "the step's end that limits; take shorter doSteps)",
                     10 * DBL_EPSILON * h, h);
        } else if (code == 2) {
            snprintf(why, sizeof why, " (below %.3g s, 10 machine epsilons of t)",
                     10 * DBL_EPSILON * fabs(t_fail));
        }
        snprintf(msg, SM_MSG,
                 "the Radau IIA integrator (rtol %.3g, atol %.3g x nominal) stopped at %.9g s "
                 "into the step after %ld steps: %s%s",
                 opt[0], opt[1], t_fail - t, *substeps, radau_cause(code), why);
        return 1;
    }
    if (!all_finite(xf, SM_NX)) {
        snprintf(msg, SM_MSG, "the Radau IIA integrator returned a state that is not finite");
        return 1;
    }
    for (int i = 0; i < SM_NX; i++) x[i] = xf[i] * sm_radau_scale[i];
    wk->carried = 1;
    wk->end_t = t_end;
    wk->end_rtol = rtol;
    memcpy(wk->end_x, x, sizeof xw);
    memcpy(wk->end_xw, xf, sizeof xw);
    memcpy(wk->end_u, u, sizeof(double) * SM_NU);
    memcpy(wk->end_p, p, sizeof(double) * SM_NP);
    return 0;
}
#endif
