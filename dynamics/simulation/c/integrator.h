/* What the compiled integrators share (radau.c, rodas.c): the CasADi-generated model
 * calls, their return codes and counters, the sparse LU on the Jacobian's pattern
 * (sparse_lu.h), the error norm and the initial step. Included by each integrator's C
 * file (and copied next to radau.c into an FMU's sources); every function is static (one
 * copy per library, no symbol clash). */
#ifndef SM_INTEGRATOR_H
#define SM_INTEGRATOR_H

#include <math.h>
#include <stdlib.h>

int sm_rhs(const double **arg, double **res, int *iw, double *w, int mem);
int sm_rhs_work(int *sz_arg, int *sz_res, int *sz_iw, int *sz_w);
int sm_jac(const double **arg, double **res, int *iw, double *w, int mem);
int sm_jac_work(int *sz_arg, int *sz_res, int *sz_iw, int *sz_w);

/* Return codes (the Python side turns them into SolverError messages; an integrator's own
 * codes follow SM_RHS). */
enum { SM_OK = 0, SM_MAX_STEPS = 1, SM_STEP_TOO_SMALL = 2, SM_NEWTON = 3, SM_JAC = 4,
       SM_NO_MEMORY = 5, SM_RHS = 6 };

/* Statistics slots (rodas.c fills the first five). */
enum { ST_STEPS, ST_REJECTED, ST_RHS, ST_JAC, ST_LU, ST_NEWTON, ST_NEWTON_FAIL, ST_N };

#include "sparse_lu.h"

/* The work sizes of sm_rhs and sm_jac together (the larger of each). */
static void model_work(int *sz_arg, int *sz_res, int *sz_iw, int *sz_w)
{
    int a2, r2, i2, w2;
    sm_rhs_work(sz_arg, sz_res, sz_iw, sz_w);
    sm_jac_work(&a2, &r2, &i2, &w2);
    *sz_arg = *sz_arg > a2 ? *sz_arg : a2;
    *sz_res = *sz_res > r2 ? *sz_res : r2;
    *sz_iw = *sz_iw > i2 ? *sz_iw : i2;
    *sz_w = *sz_w > w2 ? *sz_w : w2;
}

typedef struct {
    int n;
    const double *w, *p;
    const double **arg;
    double **res;
    int *iw;
    double *cw;
    double *stats;
    Pattern pt;
    double *jnz; /* pt.nnz doubles: the Jacobian's nonzeros */
} Model;

/* f(t, x) into f; nonzero if the call fails or f is not finite. */
static int rhs(Model *m, double t, const double *x, double *f)
{
    m->arg[0] = &t;
    m->arg[1] = x;
    m->arg[2] = m->w;
    m->arg[3] = m->p;
    m->res[0] = f;
    m->stats[ST_RHS] += 1;
    if (sm_rhs(m->arg, m->res, m->iw, m->cw, 0)) return 1;
    for (int i = 0; i < m->n; ++i)
        if (!isfinite(f[i])) return 1;
    return 0;
}

/* The Jacobian's nonzeros at (t, x) into m->jnz; nonzero if the call fails or one is not
 * finite. */
static int jac(Model *m, double t, const double *x)
{
    m->arg[0] = &t;
    m->arg[1] = x;
    m->arg[2] = m->w;
    m->arg[3] = m->p;
    m->res[0] = m->jnz;
    m->stats[ST_JAC] += 1;
    if (sm_jac(m->arg, m->res, m->iw, m->cw, 0)) return 1;
    for (int k = 0; k < m->pt.nnz; ++k)
        if (!isfinite(m->jnz[k])) return 1;
    return 0;
}

/* Root mean square of v / s over b blocks of n entries (s: n entries, for every block). */
static double rms(int b, int n, const double *v, const double *s)
{
    double acc = 0.0;
    for (int k = 0; k < b; ++k, v += n)
        for (int i = 0; i < n; ++i) {
            double r = v[i] / s[i];
            acc += r * r;
        }
    return sqrt(acc / ((double)b * n));
}

/* The initial step (Hairer, Norsett & Wanner I, II.4) for a local error estimate
 * O(h^power) (radau.c: 4, rodas.c: 5), at most span, into *h; f0 = f(t, y); scale, tmp
 * and f1: n doubles of scratch. Nonzero if the right-hand side fails. */
static int initial_step(Model *m, double t, const double *y, const double *f0, double span,
                        double rtol, double atol, int power, double *scale, double *tmp,
                        double *f1, double *h)
{
    int n = m->n;
    for (int i = 0; i < n; ++i) scale[i] = atol + fabs(y[i]) * rtol;
    double d0 = rms(1, n, y, scale), d1 = rms(1, n, f0, scale);
    double h0 = (d0 < 1e-5 || d1 < 1e-5) ? 1e-6 : 0.01 * d0 / d1;
    h0 = fmin(h0, span);
    for (int i = 0; i < n; ++i) tmp[i] = y[i] + h0 * f0[i];
    if (rhs(m, t + h0, tmp, f1)) return 1;
    for (int i = 0; i < n; ++i) tmp[i] = f1[i] - f0[i];
    double d2 = rms(1, n, tmp, scale) / h0;
    double h1 = (d1 <= 1e-15 && d2 <= 1e-15) ? fmax(1e-6, h0 * 1e-3)
                                               : pow(0.01 / fmax(d1, d2), 1.0 / power);
    *h = fmin(100 * h0, h1);
    return 0;
}

#endif
