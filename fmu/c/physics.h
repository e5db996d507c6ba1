/* The physics of the FMU behind one small interface: every function calls CasADi-generated
 * code (sm_casadi.c) built from the model's own Functions; nothing here knows FMI.
 * model_data.h (generated at export) gives the sizes, tables and tolerances, and whether the
 * FMU is a continuous model (SM_SAMPLED 0: ODE, equilibrium, Radau IIA steps) or a sampled
 * system (SM_SAMPLED 1: x+ = update(x, u, p) at the sample instants, outputs held). */
#ifndef SM_PHYSICS_H
#define SM_PHYSICS_H

#include "model_data.h"

/* Work memory of the generated functions: one per instance, so instances are independent;
 * the Co-Simulation's relative tolerance (0: the default SM_RTOL of sm_radau.h); and the
 * Co-Simulation integrator's memory (radau.c's, allocated at the first doStep) with the
 * end of the last doStep that succeeded (carried: its time, states, scaled states, inputs,
 * parameters and tolerance), which the next doStep continues when it starts there. */
typedef struct {
    const double* arg[SM_SZ_ARG];
    double* res[SM_SZ_RES];
    long long int iw[SM_SZ_IW + 1];
    double w[SM_SZ_W];
    double rtol;
    double pwm_prev; /* SM_PWM: the duty of the last doStep (the delayed edges' history) */
    int pwm_started; /* SM_PWM: a doStep has run (before it, the duty counts as held) */
    struct SmRadau* radau;
    int carried;
    double end_t, end_rtol, end_x[SM_NX], end_xw[SM_NX], end_u[SM_NU + 1], end_p[SM_NP + 1];
} SmWork;

/* Free the integrator's memory and forget the carried state (reset, free). */
void sm_work_release(SmWork* wk);

/* Each returns 0 on success, nonzero if the generated code failed or a result is not
 * finite; msg (size SM_MSG) then says why. */
#define SM_MSG 512

int sm_derivatives(SmWork* wk, const double* x, const double* u, const double* p, double* xdot);
int sm_outputs(SmWork* wk, const double* x, const double* u, const double* p, double* y);
int sm_directional(SmWork* wk, const double* x, const double* u, const double* p,
                   const double* dx, const double* du, double* dxdot, double* dy);

/* Equilibrium at (u, p): Newton from x (the equilibrium at (u0, p0)), continuing from
 * (u0, p0) to (u, p) in steps that halve on failure; each step's scaled residual must be
 * below SM_EQ_TOL and every bounded output inside its range. x is updated only on
 * success. A sampled system: x = start(u, p), its reset state. */
int sm_equilibrium(SmWork* wk, double* x, const double* u0, const double* p0, const double* u,
                   const double* p, char* msg);

/* The importer's relative tolerance (FMI's setupExperiment / enterInitializationMode):
 * defined = 0 restores the default SM_RTOL; a tolerance outside [SM_RTOL_MIN, SM_RTOL_MAX]
 * is refused. A sampled system's updates are exact: any tolerance is accepted. */
int sm_set_tolerance(SmWork* wk, int defined, double tolerance, char* msg);

/* Advance x from t (time since the start) by h > 0 with u held: the adaptive Radau IIA of
 * radau.c (sm_radau) in the states over sm_radau_scale (their nominal values), rtol from
 * sm_set_tolerance and atol = SM_ATOL_PER_RTOL rtol (in those scaled states), at most
 * SM_RADAU_MAX_STEPS steps; continued from the last doStep (its step size, Jacobian, LU,
 * error history) when that one succeeded and ended at exactly this x, u, p and tolerance
 * (and at t to the rounding of t: nothing was set in between), else restarted at (t, x). A sampled system: x = update(x, u, p) at each
 * sample instant k SM_SAMPLE_PERIOD in [t, t + h) (to SM_SAMPLE_TOL of a period). x is
 * updated only on success; *substeps counts the steps (samples) taken. */
int sm_advance(SmWork* wk, double* x, const double* u, const double* p, double t, double h,
               long* substeps, char* msg);

/* SM_PWM (a PWM valve's duty input SM_PWM_INPUT, dynamics/simulation/pwm.py): sm_advance
 * integrates between the pulse train's edges (period SM_PWM_PERIOD, carrier from the start
 * time, minimum on-time SM_PWM_MIN_ON, delay SM_PWM_DELAY) with the command held in each
 * piece, or (SM_PWM_AVERAGED) with the effective duty as the command. */

/* The sample instants in [t, t + h) a doStep from t (time since the start) runs: a sampled
 * system, at most SM_MAX_SAMPLES per doStep; 0 for a continuous model. */
double sm_samples(double t, double h);

/* "" if every bounded output is inside its range, else a message naming the first one. */
int sm_check_domain(SmWork* wk, const double* x, const double* u, const double* p, char* msg);

#endif
