/* Adaptive Rodas5P: an 8-stage Rosenbrock method of order 5 with an embedded order-4
 * solution, both stiffly accurate, L-stable, for x' = f(t, x).
 *
 * The method of G. Steinebach, "Construction of Rosenbrock-Wanner method Rodas5P and
 * numerical benchmarks within the Julia Differential Equations package", BIT Numer.
 * Math. 63, 27 (2023): Rodas5 (Di Marzo 1993) re-derived so that it also keeps its order
 * on the Prothero-Robinson problem x' = lambda (x - g(t)) + g'(t) (a stiff state that
 * follows a moving input: the ramp scene's regulator) and with a dense output of order 4
 * that stays accurate in stiff components. The coefficients are the paper's in the
 * transformed form of Hairer & Wanner (Solving ODEs II, section IV.7, eq. 7.25) as
 * OrdinaryDiffEq.jl tabulates them (Rodas5PTableau), typed in here; code was read, not
 * copied. With u_i = h sum_j gamma_ij k_j:
 *   (1/(h gamma) I - J) u_i = f(t + c_i h, x + sum_j a_ij u_j) + sum_j (c_ij / h) u_j
 *                             + h d_i df/dt,                     i = 1..8,
 * J = df/dx at (t, x), once per step (the method's order needs the exact Jacobian).
 * Stages 7 and 8 are evaluated at the previous stage's argument plus its u (a_7j =
 * a_6j, a_76 = 1; a_8j = a_7j, a_87 = 1): stage 8's argument is the embedded solution
 * and x_new = that + u_8, so u_8 itself is the error estimate (order 4 against 5).
 * df/dt, when f depends on t (an input signal), is a forward difference (backward at
 * the segment's end), as Hairer's rodas.f does. The step size follows rodas.f's
 * controller with the exponent of this pair: h_new = h / fac, fac = err^(1/5) / 0.9
 * within [1/6, 5], and after the first accepted step Gustafsson's predictor (the larger
 * reduction of the two). Outputs between steps: the dense output
 *   x(t + s h) = (1 - s) x + s (x_new + (1 - s) (q1 + s (q2 + s q3))),
 *   q_m = sum_j h_mj u_j (j = 1..8).
 * f and J are the CasADi-generated sm_rhs / sm_jac that radau.c integrates (same
 * sources, same sparse LU: integrator.h with sparse_lu.h); one real LU of size n per
 * attempted step.
 */
#include <float.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "integrator.h"

enum { SM_SINGULAR = 7 }; /* rodas.c's code beyond integrator.h's */

/* Rodas5P (Steinebach 2023; the transformed coefficients of OrdinaryDiffEq.jl). */
#define STAGES 8
static const double GAMMA = 0.21193756319429014;
static const double C[STAGES] = {0.0, 0.6358126895828704, 0.4095798393397535,
                                 0.9769306725060716, 0.4288403609558664, 1.0, 1.0, 1.0};
static const double D[STAGES] = {0.21193756319429014, -0.42387512638858027,
                                 -0.3384627126235924, 1.8046452872882734,
                                 2.325825639765069, 0.0, 0.0, 0.0};
#define A6 -7.502846399306121, 2.561846144803919, -11.627539656261098, \
           -0.18268767659942256, 0.030198172008377946
static const double A[STAGES][STAGES - 1] = {  /* a_ij, j < i */
    {0},
    {3.0},
    {2.849394379747939, 0.45842242204463923},
    {-6.954028509809101, 2.489845061869568, -10.358996098473584},
    {2.8029986275628964, 0.5072464736228206, -0.3988312541770524, -0.04721187230404641},
    {A6},
    {A6, 1.0},
    {A6, 1.0, 1.0},
};
static const double CC[STAGES][STAGES - 1] = {  /* c_ij, j < i */
    {0},
    {-14.155112264123755},
    {-17.97296035885952, -2.859693295451294},
    {147.12150275711716, -1.41221402718213, 71.68940251302358},
    {165.43517024871676, -0.4592823456491126, 42.90938336958603, -5.961986721573306},
    {24.854864614690072, -3.0009227002832186, 47.4931110020768, 5.5814197821558125,
     -0.6610691825249471},
    {30.91273214028599, -3.1208243349937974, 77.79954646070892, 34.28646028294783,
     -19.097331116725623, -28.087943162872662},
    {37.80277123390563, -3.2571969029072276, 112.26918849496327, 66.9347231244047,
     -40.06618937091002, -54.66780262877968, -9.48861652309627},
};
#define DENSE 3
static const double H[DENSE][STAGES] = {  /* dense output */
    {25.948786856663858, -2.5579724845846235, 10.433815404888879, -2.3679251022685204,
     0.524948541321073, 1.1241088310450404, 0.4272876194431874, -0.17202221070155493},
    {-9.91568850695171, -0.9689944594115154, 3.0438037242978453, -24.495224566215796,
     20.176138334709044, 15.98066361424651, -6.789040303419874, -6.710236069923372},
    {11.419903575922262, 2.8879645146136994, 72.92137995996029, 80.12511834622643,
     -52.072871366152654, -59.78993625266729, -0.15582684282751913, 4.883087185713722},
};
#define SAFE 0.9
#define FAC_MIN 0.2  /* h_new / h >= 0.2 ... */
#define FAC_MAX 6.0  /* ... <= 6 (rodas.f: FAC1 = 5, FAC2 = 1/6 on h / h_new) */
#define MAX_FAILS 10 /* consecutive failed attempts (singular matrix, non-finite stage) */

/* One attempted step of size h from (t, y) with f0 = f(t, y), J (m->jnz) and ft = df/dt
 * (or NULL): the stages into U (STAGES n), the new state into ynew; *en the error norm.
 * Returns 0, SM_SINGULAR, or SM_RHS (a stage's f not finite). */
static int attempt(Model *m, Factor *fr, double *LU, double t, double h, const double *y,
                   const double *f0, const double *ft, double rtol, double atol, double *U,
                   double *ynew, double *tmp, double *en)
{
    int n = m->n;
    fill_real(n, LU, fr, &m->pt, m->jnz, 1.0 / (h * GAMMA));
    m->stats[ST_LU] += 1;
    if (lu_real(n, LU, fr)) return SM_SINGULAR;
    for (int i = 0; i < STAGES; ++i) {
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
    /* ynew holds the last stage's argument, the embedded solution; add its u */
    const double *ul = U + (STAGES - 1) * (size_t)n;
    for (int j = 0; j < n; ++j) {
        ynew[j] += ul[j];
        double big = fabs(y[j]) > fabs(ynew[j]) ? fabs(y[j]) : fabs(ynew[j]);
        tmp[j] = atol + big * rtol;
    }
    *en = rms(1, n, ul, tmp);
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

    int sz_arg, sz_res, sz_iw, sz_w;
    model_work(&sz_arg, &sz_res, &sz_iw, &sz_w);

    size_t nn = (size_t)n * n;
    Pattern pt = jac_pattern(n);
    size_t nd = SM_LU_SIZE(n) + (6 + DENSE + STAGES) * (size_t)n + (size_t)sz_w;
    double *dbl = malloc(sizeof(double) * (nd + (size_t)(pt.nnz > 0 ? pt.nnz : 0) + 1));
    int *ints = malloc(sizeof(int) * (SM_FACTOR_INTS(n) + (size_t)sz_iw + 1));
    unsigned char *bytes = calloc(nn + 1, 1);
    const double **arg = malloc(sizeof(double *) * (sz_arg + 1));
    double **res = malloc(sizeof(double *) * (sz_res + 1));
    if (!dbl || !ints || !bytes || !arg || !res || pt.nnz < 0) {
        free(dbl), free(ints), free(bytes), free(arg), free(res), free(pt.own);
        return SM_NO_MEMORY;
    }
    double *LU = dbl, *y = LU + SM_LU_SIZE(n), *f0 = y + n, *ft = f0 + n, *ynew = ft + n;
    double *tmp = ynew + n, *scr = tmp + n, *Q = scr + n, *U = Q + DENSE * (size_t)n;
    double *jnz = U + STAGES * (size_t)n, *cw = jnz + (pt.nnz > 0 ? pt.nnz : 0);
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
    if (!(h > 0) && initial_step(&m, t, y, f0, t_end - t, rtol, atol, 5, tmp, scr, ynew, &h)) {
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
        double fac = fmin(1 / FAC_MIN, fmax(1 / FAC_MAX, pow(en, 0.2) / SAFE));
        if (en > 1) {
            h /= fac;
            rejected = 1;
            stats[ST_REJECTED] += 1;
            continue;
        }
        if (h_acc > 0) {  /* Gustafsson's predictor */
            double gus = h_acc / h * pow(en * en / err_acc, 0.2) / SAFE;
            fac = fmax(fac, fmin(1 / FAC_MIN, fmax(1 / FAC_MAX, gus)));
        }
        h_acc = h;
        err_acc = fmax(1e-2, en);

        /* accepted: outputs in (t, t + h] from the dense output */
        double t_new = (h == t_end - t) ? t_end : t + h;
        if (k_out < nout && tout[k_out] < t_new)
            for (int r = 0; r < DENSE; ++r)
                for (int j = 0; j < n; ++j) {
                    double q = 0;
                    for (int k = 0; k < STAGES; ++k) q += H[r][k] * U[(size_t)k * n + j];
                    Q[(size_t)r * n + j] = q;
                }
        for (; k_out < nout && tout[k_out] <= t_new; ++k_out) {
            double *xo = xout + (size_t)k_out * n;
            if (tout[k_out] == t_new) {
                memcpy(xo, ynew, sizeof(double) * n);
                continue;
            }
            double s = (tout[k_out] - t) / h, s1 = 1 - s;
            for (int j = 0; j < n; ++j)
                xo[j] = s1 * y[j]
                      + s * (ynew[j] + s1 * (Q[j] + s * (Q[n + j] + s * Q[2 * n + j])));
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
