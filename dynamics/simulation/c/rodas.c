/* Adaptive Rodas4: a 6-stage Rosenbrock method of order 4 with an embedded order-3
 * solution, both stiffly accurate, L-stable, for x' = f(t, x).
 *
 * The method RODAS of Hairer & Wanner, Solving ODEs II (2nd ed. 1996), section VI.4,
 * with the coefficients of their code rodas.f (subroutine ROCOE, METH = 1: "RODAS4"),
 * written anew for sarcomere. In the variables of their
 * implementation (u_i = h sum_j gamma_ij k_j):
 *   (1/(h gamma) I - J) u_i = f(t + c_i h, x + sum_j a_ij u_j) + sum_j (c_ij / h) u_j
 *                             + h d_i df/dt,                     i = 1..6,
 * J = df/dx at (t, x), once per step (the method's order needs the exact Jacobian);
 * stage 6 is evaluated at x + sum_j a_6j u_j, which is the embedded solution, and
 * x_new = that + u_6, so u_6 itself is the error estimate (order 3 against order 4).
 * df/dt, when f depends on t (an input signal), is a forward difference (backward at
 * the segment's end), as rodas.f does. The step size follows rodas.f's controller:
 * h_new = h / fac, fac = err^(1/4) / 0.9 within [1/6, 5], and after the first accepted
 * step Gustafsson's predictor (the larger reduction of the two). Outputs between steps: the dense output of rodas.f (order 3),
 *   x(t + s h) = (1 - s) x + s (x_new + (1 - s) (q1 + s q2)),
 *   q1 = sum_j d2j u_j, q2 = sum_j d3j u_j (j = 1..5).
 * f and J are the CasADi-generated sm_rhs / sm_jac that radau.c integrates (same
 * sources, same sparse LU: integrator.h); one real LU of size n per attempted step.
 * Code from elsewhere was read, not copied; the coefficients were typed from rodas.f.
 */
#include <float.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "integrator.h"

SM_FILL(fill_real, double)
SM_LU(lu_real, double, fabs)
SM_SOLVE(solve_real, double)

/* RODAS4 (Hairer & Wanner, rodas.f, ROCOE METH = 1). */
static const double GAMMA = 0.25;
static const double C[6] = {0.0, 0.386, 0.21, 0.63, 1.0, 1.0};  /* stage times */
static const double D[6] = {0.25, -0.1043, 0.1035, -0.3620000000000023e-01, 0.0, 0.0};
static const double A[6][5] = {  /* a_ij, j < i; a_6j = a_5j, a_65 = 1 */
    {0},
    {0.1544000000000000e+01},
    {0.9466785280815826e+00, 0.2557011698983284e+00},
    {0.3314825187068521e+01, 0.2896124015972201e+01, 0.9986419139977817e+00},
    {0.1221224509226641e+01, 0.6019134481288629e+01, 0.1253708332932087e+02,
     -0.6878860361058950e+00},
    {0.1221224509226641e+01, 0.6019134481288629e+01, 0.1253708332932087e+02,
     -0.6878860361058950e+00, 1.0},
};
static const double CC[6][5] = {  /* c_ij, j < i */
    {0},
    {-0.5668800000000000e+01},
    {-0.2430093356833875e+01, -0.2063599157091915e+00},
    {-0.1073529058151375e+00, -0.9594562251023355e+01, -0.2047028614809616e+02},
    {0.7496443313967647e+01, -0.1024680431464352e+02, -0.3399990352819905e+02,
     0.1170890893206160e+02},
    {0.8083246795921522e+01, -0.7981132988064893e+01, -0.3152159432874371e+02,
     0.1631930543123136e+02, -0.6058818238834054e+01},
};
static const double DD[2][5] = {  /* dense output */
    {0.1012623508344586e+02, -0.7487995877610167e+01, -0.3480091861555747e+02,
     -0.7992771707568823e+01, 0.1025137723295662e+01},
    {-0.6762803392801253e+00, 0.6087714651680015e+01, 0.1643084320892478e+02,
     0.2476722511418386e+02, -0.6594389125716872e+01},
};
#define SAFE 0.9
#define FAC_MIN 0.2  /* h_new / h >= 0.2 ... */
#define FAC_MAX 6.0  /* ... <= 6 (rodas.f: FAC1 = 5, FAC2 = 1/6 on h / h_new) */
#define MAX_FAILS 10 /* consecutive failed attempts (singular matrix, non-finite stage) */

/* One attempted step of size h from (t, y) with f0 = f(t, y), J (m->jnz) and ft = df/dt
 * (or NULL): the stages into U (6 n), the new state into ynew; *en the error norm.
 * Returns 0, SM_SINGULAR, or SM_RHS (a stage's f not finite). */
static int attempt(Model *m, Factor *fr, double *LU, double t, double h, const double *y,
                   const double *f0, const double *ft, double rtol, double atol, double *U,
                   double *ynew, double *tmp, double *en)
{
    int n = m->n;
    fill_real(n, LU, fr, &m->pt, m->jnz, 1.0 / (h * GAMMA));
    m->stats[ST_LU] += 1;
    if (lu_real(n, LU, fr)) return SM_SINGULAR;
    for (int i = 0; i < 6; ++i) {
        double *ui = U + (size_t)i * n;
        if (i == 0) {
            memcpy(ui, f0, sizeof(double) * n);
        } else {
            for (int j = 0; j < n; ++j) {
                double s = y[j];
                for (int k = 0; k < i; ++k) s += A[i][k] * U[(size_t)k * n + j];
                ynew[j] = s;
            }
            if (rhs(m, t + C[i] * h, ynew, ui)) return SM_RHS;
            for (int j = 0; j < n; ++j) {
                double s = 0.0;
                for (int k = 0; k < i; ++k) s += CC[i][k] * U[(size_t)k * n + j];
                ui[j] += s / h;
            }
        }
        if (ft && D[i] != 0.0)
            for (int j = 0; j < n; ++j) ui[j] += h * D[i] * ft[j];
        solve_real(n, LU, fr, ui);
    }
    /* ynew holds stage 6's argument, the embedded solution; add u6 */
    const double *u6 = U + 5 * (size_t)n;
    for (int j = 0; j < n; ++j) {
        ynew[j] += u6[j];
        double big = fabs(y[j]) > fabs(ynew[j]) ? fabs(y[j]) : fabs(ynew[j]);
        tmp[j] = atol + big * rtol;
    }
    *en = rms(1, n, u6, tmp);
    return isfinite(*en) ? 0 : SM_RHS;
}

/* df/dt at (t, y) by a difference over delta = sqrt(eps max(1e-5, |t|)) (rodas.f),
 * forward unless t + delta passes t_end (the input law is clamped there), into ft. */
static int time_derivative(Model *m, double t, double t_end, const double *y,
                           const double *f0, double *ft)
{
    double delta = sqrt(DBL_EPSILON * fmax(1e-5, fabs(t)));
    if (t + delta > t_end) delta = -delta;
    if (rhs(m, t + delta, y, ft)) return 1;
    for (int j = 0; j < m->n; ++j) ft[j] = (ft[j] - f0[j]) / delta;
    return 0;
}

/* Integrate x' = f(t, x; w, p) from t0 to tout[nout - 1], writing x at every tout[k]
 * (increasing, > t0) into xout[k * n ...].
 *   x           in: state at t0; out: state at the last accepted time
 *   opt         rtol, atol, first step (0: automatic), max step
 *   max_steps   accepted-step limit of this call
 *   autonomous  nonzero if f does not depend on t (no df/dt)
 *   stats       ST_N counters, added to (steps, rejected, rhs, jac, lu)
 *   t_fail      time reached when a failure is returned
 * Returns one of the SM_ codes. */
int sm_rodas(int n, const double *w, const double *p, double t0, double *x, int nout,
             const double *tout, double *xout, const double *opt, long max_steps,
             int autonomous, double *stats, double *t_fail)
{
    const double rtol = opt[0], atol = opt[1], hmax = opt[3];
    const double t_end = tout[nout - 1];

    int sz_arg, sz_res, sz_iw, sz_w, a2, r2, i2, w2;
    sm_rhs_work(&sz_arg, &sz_res, &sz_iw, &sz_w);
    sm_jac_work(&a2, &r2, &i2, &w2);
    sz_arg = sz_arg > a2 ? sz_arg : a2;
    sz_res = sz_res > r2 ? sz_res : r2;
    sz_iw = sz_iw > i2 ? sz_iw : i2;
    sz_w = sz_w > w2 ? sz_w : w2;

    size_t nn = (size_t)n * n;
    Pattern pt = jac_pattern(n);
    double *dbl = malloc(sizeof(double) * (SM_LU_SIZE(n) + 16 * (size_t)n + (size_t)sz_w
                                           + (size_t)(pt.nnz > 0 ? pt.nnz : 0) + 1));
    int *ints = malloc(sizeof(int) * (SM_FACTOR_INTS(n) + (size_t)sz_iw + 1));
    unsigned char *bytes = calloc(nn + 1, 1);
    const double **arg = malloc(sizeof(double *) * (sz_arg + 1));
    double **res = malloc(sizeof(double *) * (sz_res + 1));
    if (!dbl || !ints || !bytes || !arg || !res || pt.nnz < 0) {
        free(dbl), free(ints), free(bytes), free(arg), free(res), free(pt.own);
        return SM_NO_MEMORY;
    }
    double *LU = dbl, *y = LU + SM_LU_SIZE(n), *f0 = y + n, *ft = f0 + n, *ynew = ft + n;
    double *tmp = ynew + n, *scr = tmp + n, *q1 = scr + n, *q2 = q1 + n, *U = q2 + n;
    double *jnz = U + 6 * (size_t)n, *cw = jnz + (pt.nnz > 0 ? pt.nnz : 0);
    Factor fr;
    int *iw = factor_init(&fr, n, ints, bytes);
    factor_list_pattern(&fr, n, &pt);
    memset(LU, 0, sizeof(double) * nn); /* unlisted positions stay zero (SM_FILL) */
    Model m = {n, w, p, arg, res, iw, cw, stats, pt, jnz};

    int code = SM_OK, k_out = 0;
    double t = t0;
    memcpy(y, x, sizeof(double) * n);
    *t_fail = t0;
    if (rhs(&m, t, y, f0)) { code = SM_RHS; goto done; }
    double h = opt[2];
    if (!(h > 0) && initial_step(&m, t, y, f0, t_end - t, rtol, atol, tmp, scr, ynew, &h)) {
        code = SM_RHS;
        goto done;
    }

    int rejected = 0, fails = 0, fresh = 0;  /* fresh: J (and df/dt) are at (t, y) */
    long steps = 0;
    double h_acc = 0, err_acc = 1e-2;
    while (t < t_end) {
        if (steps >= max_steps) { code = SM_MAX_STEPS; break; }
        double hmin = 10 * DBL_EPSILON * fmax(fabs(t), fabs(t_end - t0));
        h = fmin(h, hmax);
        if (h < hmin) { code = SM_STEP_TOO_SMALL; break; }
        if (t + 1.0001 * h >= t_end) h = t_end - t;  /* land on the end, no sliver step */
        if (!fresh) {
            if (jac(&m, t, y)) { code = SM_JAC; break; }
            if (!autonomous && time_derivative(&m, t, t_end, y, f0, ft)) {
                code = SM_RHS;
                break;
            }
            fresh = 1;
        }
        double en = 0;
        int why = attempt(&m, &fr, LU, t, h, y, f0, autonomous ? NULL : ft, rtol, atol, U,
                          ynew, tmp, &en);
        if (why) {  /* singular matrix or a non-finite stage: a smaller step */
            if (++fails > MAX_FAILS) { code = why; break; }
            h *= 0.5;
            rejected = 1;
            stats[ST_REJECTED] += 1;
            continue;
        }
        en = fmax(en, 1e-10);
        double fac = fmin(1 / FAC_MIN, fmax(1 / FAC_MAX, pow(en, 0.25) / SAFE));
        if (en > 1) {
            h /= fac;
            rejected = 1;
            stats[ST_REJECTED] += 1;
            continue;
        }
        if (h_acc > 0) {  /* Gustafsson's predictor */
            double gus = h_acc / h * pow(en * en / err_acc, 0.25) / SAFE;
            fac = fmax(fac, fmin(1 / FAC_MIN, fmax(1 / FAC_MAX, gus)));
        }
        h_acc = h;
        err_acc = fmax(1e-2, en);

        /* accepted: outputs in (t, t + h] from the dense output */
        double t_new = (h == t_end - t) ? t_end : t + h;
        if (k_out < nout && tout[k_out] < t_new)
            for (int j = 0; j < n; ++j) {
                double a = 0, b = 0;
                for (int k = 0; k < 5; ++k) {
                    a += DD[0][k] * U[(size_t)k * n + j];
                    b += DD[1][k] * U[(size_t)k * n + j];
                }
                q1[j] = a, q2[j] = b;
            }
        for (; k_out < nout && tout[k_out] <= t_new; ++k_out) {
            double *xo = xout + (size_t)k_out * n;
            if (tout[k_out] == t_new) {
                memcpy(xo, ynew, sizeof(double) * n);
                continue;
            }
            double s = (tout[k_out] - t) / h, s1 = 1 - s;
            for (int j = 0; j < n; ++j)
                xo[j] = s1 * y[j] + s * (ynew[j] + s1 * (q1[j] + s * q2[j]));
        }
        stats[ST_STEPS] += 1;
        ++steps;
        t = t_new;
        memcpy(y, ynew, sizeof(double) * n);
        *t_fail = t;
        fresh = 0;
        if (t < t_end && rhs(&m, t, y, f0)) { code = SM_RHS; break; }
        double h_new = h / fac;
        if (rejected) h_new = fmin(h_new, h);
        h = h_new;
        rejected = fails = 0;
    }
done:
    memcpy(x, y, sizeof(double) * n);
    if (code != SM_OK) *t_fail = t;
    free(dbl), free(ints), free(bytes), free(arg), free(res), free(pt.own);
    return code;
}
