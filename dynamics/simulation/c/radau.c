/* Adaptive 3-stage Radau IIA (order 5, stiffly accurate, L-stable) for x' = f(t, x).
 *
 * The algorithm of Hairer & Wanner, Solving ODEs II, section IV.8 (RADAU5), written
 * anew for sarcomere:
 *   - the collocation system is solved by a simplified Newton iteration in the
 *     variables W = T^-1 Z, where T^-1 A^-1 T is one real eigenvalue and one complex
 *     pair: one real and one complex LU of size n per Jacobian or step-size change;
 *   - the Jacobian is reused across steps while the Newton iteration converges fast;
 *   - the error is the embedded estimate (the extra real solve), refined by one more
 *     right-hand side after a first or rejected step;
 *   - the step size is predicted by Gustafsson's controller;
 *   - outputs come from the collocation polynomial of each accepted step.
 * f and its Jacobian are CasADi-generated functions (casadi_int = int) compiled into the
 * same library:
 *   sm_rhs(t, x, w, p) -> f      sm_jac(t, x, w, p) -> the nonzeros of df/dx
 * in the compressed-column pattern of sm_jac_sparsity_out(0) (CasADi's compressed form:
 * [nrow, ncol, colind[ncol + 1], row[nnz]], or [nrow, ncol, 1] if dense); they are
 * scattered into the iteration matrices, whose LU visits only the nonzeros and their
 * fill-in (SM_LU).
 * The method constants (T, T^-1, eigenvalues, nodes, error weights, dense-output matrix)
 * are computed by the Python side and passed in.
 */
#include <complex.h>
#include <float.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "integrator.h"

/* RADAU5's reuse of the Jacobian and of the LU pair (Hairer & Wanner II, IV.8: THET,
 * QUOT1, QUOT2): after an accepted step the Jacobian is re-evaluated only if the Newton
 * contraction rate exceeded SM_THET, and the step size is kept (and with it the LU pair)
 * while the controller's new/old ratio is below SM_QUOT2 (and the Jacobian kept). Here the
 * LU pair costs about two thirds of the integrator's instructions at n = 3 (18 states),
 * as for RADAU5's "large systems" (THET 0.01-0.1, QUOT2 2): SM_THET 0.01 with SM_QUOT2 2
 * halves the LU pairs of the work-precision scenes and takes 10-22 % less C time at error
 * 1e-6 than 0.001 and 1.2 (BENCHMARKS.md, section 1). A step the controller would shrink
 * keeps its size too (scipy's rule; the error test still rejects a step that fails). */
#define SM_THET 1e-2
#define SM_QUOT2 2.0

/* The method constants, in the order radau.py packs them. */
typedef struct {
    double T[9], TI[9];  /* row-major */
    double mu_r, mu_cr, mu_ci;  /* eigenvalues of A^-1: real, complex (mu_cr + i mu_ci) */
    double c[3];  /* nodes */
    double e[3];  /* error weights on Z / h */
    double P[9];  /* dense output: Q_k = sum_i Z_i P[i][k], x(t0 + s h) = x0 + sum_k Q_k s^(k+1) */
} Tableau;

/* An integrator's memory for one system size: the work arrays (allocated once) and the
 * state of the integration that a call leaves behind, which the next call continues when
 * asked to (sm_radau's resume): the point (t, y) with f0 = f(t, y), the Jacobian (and
 * whether it was evaluated at the current point), the LU pair and the step size it was
 * made for, the predicted step size, Gustafsson's error history, the Newton convergence
 * factor and the last step's collocation polynomial (the next Newton start). */
struct SmRadau {
    int n;
    Pattern pt;
    Factor fr, fc;
    Model m;
    double *dbl;
    double complex *cplx;
    int *ints;
    unsigned char *bytes;
    double *LUr, *y, *f0, *ynew, *scale, *tmp, *err, *Z, *W, *dW, *F, *Q, *Qold, *rr, *ypoly;
    double complex *LUc, *rc;
    /* the carried state */
    int valid, current_jac, lu_ok, have_poly;
    double t, h, h_lu, t_poly, h_poly, h_old, err_old, faccon;
};
typedef struct SmRadau SmRadau;

void sm_radau_free(SmRadau *r)
{
    if (!r) return;
    free(r->dbl), free(r->cplx), free(r->ints), free(r->bytes), free(r->m.arg), free(r->m.res);
    free(r->pt.own);
    free(r);
}

/* A new integrator memory for n states, or NULL if out of memory. */
SmRadau *sm_radau_new(int n)
{
    SmRadau *r = calloc(1, sizeof *r);
    if (!r) return NULL;
    int sz_arg, sz_res, sz_iw, sz_w;
    model_work(&sz_arg, &sz_res, &sz_iw, &sz_w);
    size_t nn = (size_t)n * n;
    r->n = n;
    r->pt = jac_pattern(n);
    int nnz = r->pt.nnz > 0 ? r->pt.nnz : 0;
    r->dbl = malloc(sizeof(double) * (SM_LU_SIZE(n) + 28 * (size_t)n + (size_t)sz_w + nnz + 1));
    r->cplx = malloc(sizeof(double complex) * (SM_LU_SIZE(n) + n));
    r->ints = malloc(sizeof(int) * (2 * SM_FACTOR_INTS(n) + (size_t)sz_iw + 1));
    r->bytes = calloc(2 * nn + 1, 1);
    r->m.arg = malloc(sizeof(double *) * (sz_arg + 1));
    r->m.res = malloc(sizeof(double *) * (sz_res + 1));
    if (!r->dbl || !r->cplx || !r->ints || !r->bytes || !r->m.arg || !r->m.res || r->pt.nnz < 0) {
        sm_radau_free(r);
        return NULL;
    }
    r->LUr = r->dbl, r->y = r->LUr + SM_LU_SIZE(n);
    r->f0 = r->y + n, r->ynew = r->f0 + n, r->scale = r->ynew + n, r->tmp = r->scale + n;
    r->err = r->tmp + n, r->Z = r->err + n, r->W = r->Z + 3 * n, r->dW = r->W + 3 * n;
    r->F = r->dW + 3 * n, r->Q = r->F + 3 * n, r->Qold = r->Q + 3 * n, r->rr = r->Qold + 3 * n;
    r->ypoly = r->rr + n;
    r->m.jnz = r->ypoly + n;
    r->m.cw = r->m.jnz + nnz;
    r->LUc = r->cplx, r->rc = r->LUc + SM_LU_SIZE(n);
    r->m.iw = factor_init(&r->fc, n, factor_init(&r->fr, n, r->ints, r->bytes), r->bytes + nn);
    r->m.n = n;
    r->m.pt = r->pt;
    return r;
}

/* Integrate x' = f(t, x; w, p) from t0 to tout[nout - 1], writing x at every tout[k]
 * (increasing, > t0) into xout[k * n ...].
 *   r          the memory (sm_radau_new(n))
 *   x          in: state at t0; out: state at the last accepted time
 *   cst        the Tableau (36 doubles)
 *   opt        rtol, atol, first step (0: automatic), max step
 *   max_steps  accepted-step limit of this call; max_newton: Newton iterations per attempt
 *   stats      ST_N counters, added to
 *   t_fail     time reached when a failure is returned
 *   resume     nonzero: continue the integration the last call of r ended (its step size,
 *              Jacobian, LU, error history, Newton start), if that call succeeded and
 *              ended at x exactly and at t0 to the rounding of t; the caller vouches that
 *              w, p, cst and opt are those of that call. Otherwise (or 0) a fresh start.
 * Returns one of the SM_ codes. */
int sm_radau(SmRadau *r, const double *w, const double *p, double t0, double *x, int nout,
             const double *tout, double *xout, const double *cst, const double *opt,
             long max_steps, int max_newton, double *stats, double *t_fail, int resume)
{
    const int n = r->n;
    Tableau tb;
    memcpy(&tb, cst, sizeof tb);
    const double rtol = opt[0], atol = opt[1], hmax = opt[3];
    const double t_end = tout[nout - 1];
    /* Newton stopping tolerance, in the error norm of (rtol, atol): RADAU5's
     * max(10 eps / r, min(0.03, sqrt(r))) taken at its transformed tolerance
     * r = 0.1 rtol^(2/3) (with atol scaled alike) and carried back to (rtol, atol) by
     * the factor r / rtol: about 0.03 for every rtol <= 1e-3. Taken at rtol itself
     * (sqrt(1e-10) = 1e-5) it asks the velocity increments for 1e-18 m/s at
     * atol = 1e-13, below the roundoff floor of the stage equations (about 1e-16 m/s at
     * h = 1 ms): the iteration stalls and every step size fails. */
    const double rtol_t = 0.1 * pow(rtol, 2.0 / 3.0);
    const double newton_tol = fmax(10 * DBL_EPSILON / rtol,
                                   fmin(0.03, sqrt(rtol_t)) * rtol_t / rtol);
    const double mu_c_re = tb.mu_cr, mu_c_im = tb.mu_ci;
    Model *m = &r->m;
    m->w = w, m->p = p, m->stats = stats;
    const Pattern *pt = &r->pt;
    Factor *fr = &r->fr, *fc = &r->fc;
    double *LUr = r->LUr, *y = r->y, *f0 = r->f0, *ynew = r->ynew, *scale = r->scale;
    double *tmp = r->tmp, *err = r->err, *Z = r->Z, *W = r->W, *dW = r->dW, *F = r->F;
    double *Q = r->Q, *Qold = r->Qold, *rr = r->rr, *ypoly = r->ypoly, *jnz = m->jnz;
    double complex *LUc = r->LUc, *rc = r->rc;

    int code = SM_OK, k_out = 0;
    double t = t0;
    *t_fail = t0;
    int first = 1, rejected = 0, fails = 0;
    if (resume && r->valid && fabs(r->t - t0) <= 4 * DBL_EPSILON * fabs(t0)
        && !memcmp(y, x, sizeof(double) * n)) {
        first = 0;
    } else {
        /* the LU's lists as new: the fill-in and its order (the sums of the solves) of a
         * fresh start never depend on what the memory integrated before */
        size_t nn = (size_t)n * n;
        memset(r->bytes, 0, 2 * nn);
        factor_init(&r->fc, n, factor_init(&r->fr, n, r->ints, r->bytes), r->bytes + nn);
        factor_list_pattern(fr, n, pt);
        factor_list_pattern(fc, n, pt);
        memset(LUr, 0, sizeof(double) * nn); /* unlisted positions stay zero (SM_FILL) */
        memset(LUc, 0, sizeof(double complex) * nn);
        memcpy(y, x, sizeof(double) * n);
        r->valid = 0;
        r->lu_ok = r->have_poly = 0;
        r->h_old = r->err_old = -1;
        r->faccon = 1.0;
        if (rhs(m, t, y, f0)) { code = SM_RHS; goto done; }
        if (jac(m, t, y)) { code = SM_JAC; goto done; }
        r->current_jac = 1;
        /* the initial step for the error estimate, O(h^4) */
        r->h = opt[2];
        if (!(r->h > 0)
            && initial_step(m, t, y, f0, t_end - t, rtol, atol, 4, scale, tmp, err, &r->h)) {
            code = SM_RHS;
            goto done;
        }
    }
    r->valid = 0;

    int current_jac = r->current_jac, lu_ok = r->lu_ok, have_poly = r->have_poly;
    double faccon = r->faccon, h = r->h, h_lu = r->h_lu, t_poly = r->t_poly;
    double h_poly = r->h_poly, h_old = r->h_old, err_old = r->err_old;
    long steps = 0;
    while (t < t_end) {
        if (steps >= max_steps) {
            code = SM_MAX_STEPS;
            break;
        }
        double hmin = 10 * DBL_EPSILON * fmax(fabs(t), fabs(t_end - t0));
        h = fmin(h, hmax);
        if (h < hmin) { code = SM_STEP_TOO_SMALL; break; }
        if (t + 1.0001 * h >= t_end) h = t_end - t;  /* land on the end, no sliver step */
        /* the LU pair is kept for a step size that differs from its own only by the
         * rounding of t (a landing step t_end - t of a resumed integration) */
        if (!lu_ok || fabs(h - h_lu) > 4 * DBL_EPSILON * fmax(fabs(t), fabs(t_end))) {
            fill_real(n, LUr, fr, pt, jnz, tb.mu_r / h);
            fill_complex(n, LUc, fc, pt, jnz, (mu_c_re + I * mu_c_im) / h);
            stats[ST_LU] += 1;
            if (lu_real(n, LUr, fr) || lu_complex(n, LUc, fc)) {
                h *= 0.5;  /* singular iteration matrix: try a smaller step */
                lu_ok = 0;
                continue;
            }
            lu_ok = 1;
            h_lu = h;
        }

        /* start from the previous step's collocation polynomial, or from zero */
        for (int i = 0; i < 3; ++i) {
            double *zi = Z + i * n;
            if (!have_poly) {
                memset(zi, 0, sizeof(double) * n);
                continue;
            }
            double s = (t + tb.c[i] * h - t_poly) / h_poly, s2 = s * s, s3 = s2 * s;
            for (int j = 0; j < n; ++j)
                zi[j] = ypoly[j] + Qold[j] * s + Qold[n + j] * s2 + Qold[2 * n + j] * s3 - y[j];
        }
        for (int i = 0; i < 3; ++i)
            for (int j = 0; j < n; ++j)
                W[i * n + j] = tb.TI[3 * i] * Z[j] + tb.TI[3 * i + 1] * Z[n + j]
                             + tb.TI[3 * i + 2] * Z[2 * n + j];
        for (int i = 0; i < n; ++i) scale[i] = atol + fabs(y[i]) * rtol;

        /* simplified Newton iteration on the transformed collocation system; the
         * convergence test faccon * |dW| <= tol carries faccon over from the last step */
        int converged = 0, iters = 0;
        double theta = 0, thq_old = 0, norm_old = 0;
        for (int k = 0; k < max_newton; ++k) {
            int bad = 0;
            for (int i = 0; i < 3 && !bad; ++i) {
                for (int j = 0; j < n; ++j) tmp[j] = y[j] + Z[i * n + j];
                bad = rhs(m, t + tb.c[i] * h, tmp, F + i * n);
            }
            iters = k + 1;
            if (bad) break;
            for (int j = 0; j < n; ++j) {
                double g0 = tb.TI[0] * F[j] + tb.TI[1] * F[n + j] + tb.TI[2] * F[2 * n + j];
                double g1 = tb.TI[3] * F[j] + tb.TI[4] * F[n + j] + tb.TI[5] * F[2 * n + j];
                double g2 = tb.TI[6] * F[j] + tb.TI[7] * F[n + j] + tb.TI[8] * F[2 * n + j];
                double w1 = W[n + j], w2 = W[2 * n + j];
                rr[j] = g0 - tb.mu_r / h * W[j];
                /* g - mu_c / h * (w1 + i w2) */
                rc[j] = (g1 - (mu_c_re * w1 - mu_c_im * w2) / h)
                      + I * (g2 - (mu_c_re * w2 + mu_c_im * w1) / h);
            }
            solve_real(n, LUr, fr, rr);
            solve_complex(n, LUc, fc, rc);
            for (int j = 0; j < n; ++j) {
                dW[j] = rr[j];
                dW[n + j] = creal(rc[j]);
                dW[2 * n + j] = cimag(rc[j]);
            }
            double nrm = rms(3, n, dW, scale);
            if (k > 0) {  /* contraction rate: geometric mean of the last two ratios */
                double thq = nrm / norm_old;
                theta = k == 1 ? thq : sqrt(thq * thq_old);
                thq_old = thq;
                if (theta >= 0.99) break;
                faccon = theta / (1 - theta);
                double left = faccon * nrm;  /* the error left after the remaining iterations */
                for (int q = k + 2; q < max_newton; ++q) left *= theta;
                if (left >= newton_tol) break;
            }
            norm_old = fmax(nrm, DBL_EPSILON);
            for (int i = 0; i < 3 * n; ++i) W[i] += dW[i];
            for (int i = 0; i < 3; ++i)
                for (int j = 0; j < n; ++j)
                    Z[i * n + j] = tb.T[3 * i] * W[j] + tb.T[3 * i + 1] * W[n + j]
                                 + tb.T[3 * i + 2] * W[2 * n + j];
            if (faccon * nrm <= newton_tol) {
                converged = 1;
                break;
            }
        }
        stats[ST_NEWTON] += iters;
        if (!converged) {
            stats[ST_NEWTON_FAIL] += 1;
            if (!current_jac) {  /* first a fresh Jacobian at the same step size */
                if (jac(m, t, y)) { code = SM_JAC; break; }
                current_jac = 1;
                lu_ok = 0;
                continue;
            }
            if (++fails > 10) { code = SM_NEWTON; break; }
            h *= 0.5;
            rejected = 1;
            continue;
        }

        /* embedded error estimate */
        for (int j = 0; j < n; ++j) {
            ynew[j] = y[j] + Z[2 * n + j];
            double big = fabs(y[j]) > fabs(ynew[j]) ? fabs(y[j]) : fabs(ynew[j]);
            scale[j] = atol + big * rtol;
            tmp[j] = (tb.e[0] * Z[j] + tb.e[1] * Z[n + j] + tb.e[2] * Z[2 * n + j]) / h;
            err[j] = f0[j] + tmp[j];
        }
        solve_real(n, LUr, fr, err);
        double en = rms(1, n, err, scale);
        if (en >= 1 && (first || rejected)) {
            for (int j = 0; j < n; ++j) rr[j] = y[j] + err[j];
            if (rhs(m, t, rr, err)) { en = 2.0; }
            else {
                for (int j = 0; j < n; ++j) err[j] += tmp[j];
                solve_real(n, LUr, fr, err);
                en = rms(1, n, err, scale);
            }
        }
        en = fmax(en, 1e-10);
        double safety = 0.9 * (2 * max_newton + 1) / (2 * max_newton + iters);
        double root4 = sqrt(sqrt(en));  /* en^(1/4): the error estimate is O(h^4) */
        double mult = (h_old > 0 && err_old > 0) ? h / h_old * sqrt(sqrt(err_old)) / root4 : 1.0;
        double factor = fmin(1.0, mult) / root4;  /* Gustafsson's predictor */
        if (en > 1) {
            h *= fmax(0.2, safety * factor);
            rejected = 1;
            stats[ST_REJECTED] += 1;
            continue;
        }

        /* accepted: outputs from the collocation polynomial through (t, t + h] */
        double t_new = (h == t_end - t) ? t_end : t + h;
        for (int k = 0; k < 3; ++k)
            for (int j = 0; j < n; ++j)
                Q[k * n + j] = Z[j] * tb.P[k] + Z[n + j] * tb.P[3 + k] + Z[2 * n + j] * tb.P[6 + k];
        for (; k_out < nout && tout[k_out] <= t_new; ++k_out) {
            double *xo = xout + (size_t)k_out * n;
            if (tout[k_out] == t_new) {
                memcpy(xo, ynew, sizeof(double) * n);
                continue;
            }
            double s = (tout[k_out] - t) / h, sk = s;
            memcpy(xo, y, sizeof(double) * n);
            for (int k = 0; k < 3; ++k, sk *= s)
                for (int j = 0; j < n; ++j) xo[j] += Q[k * n + j] * sk;
        }
        memcpy(Qold, Q, sizeof(double) * 3 * n);
        memcpy(ypoly, y, sizeof(double) * n);
        t_poly = t;
        h_poly = h;
        have_poly = 1;
        stats[ST_STEPS] += 1;
        ++steps;

        int refresh_jac = theta > SM_THET;
        factor = fmin(10.0, safety * factor);
        if (rejected) factor = fmin(factor, 1.0);
        if (!refresh_jac && factor < SM_QUOT2) factor = 1.0;
        t = t_new;
        memcpy(y, ynew, sizeof(double) * n);
        *t_fail = t;
        if (rhs(m, t, y, f0)) { code = SM_RHS; break; }
        if (refresh_jac) {
            if (jac(m, t, y)) { code = SM_JAC; break; }
            lu_ok = 0;
        }
        current_jac = refresh_jac;
        h_old = h;
        err_old = en;
        h *= factor;
        first = rejected = fails = 0;
        faccon = pow(fmax(faccon, DBL_EPSILON), 0.8);
    }
    if (code == SM_OK) {  /* what a resumed call continues */
        r->valid = 1;
        r->t = t;
        r->current_jac = current_jac, r->lu_ok = lu_ok, r->have_poly = have_poly;
        r->faccon = faccon, r->h = h, r->h_lu = h_lu, r->t_poly = t_poly;
        r->h_poly = h_poly, r->h_old = h_old, r->err_old = err_old;
    }
done:
    memcpy(x, y, sizeof(double) * n);
    if (code != SM_OK) *t_fail = t;
    return code;
}
