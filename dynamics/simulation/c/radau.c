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

/* |re| + |im|: the pivot size of LAPACK's complex LU, without a square root */
static inline double abs1(double complex z) { return fabs(creal(z)) + fabs(cimag(z)); }

SM_FILL(fill_real, double)
SM_FILL(fill_complex, double complex)
SM_LU(lu_real, double, fabs)
SM_LU(lu_complex, double complex, abs1)
SM_SOLVE(solve_real, double)
SM_SOLVE(solve_complex, double complex)

/* The method constants, in the order radau.py packs them. */
typedef struct {
    double T[9], TI[9];  /* row-major */
    double mu_r, mu_cr, mu_ci;  /* eigenvalues of A^-1: real, complex (mu_cr + i mu_ci) */
    double c[3];  /* nodes */
    double e[3];  /* error weights on Z / h */
    double P[9];  /* dense output: Q_k = sum_i Z_i P[i][k], x(t0 + s h) = x0 + sum_k Q_k s^(k+1) */
} Tableau;

/* Integrate x' = f(t, x; w, p) from t0 to tout[nout - 1], writing x at every tout[k]
 * (increasing, > t0) into xout[k * n ...].
 *   x          in: state at t0; out: state at the last accepted time
 *   cst        the Tableau (36 doubles)
 *   opt        rtol, atol, first step (0: automatic), max step
 *   max_steps  accepted-step limit of this call; max_newton: Newton iterations per attempt
 *   stats      ST_N counters, added to
 *   t_fail     time reached when a failure is returned
 * Returns one of the SM_ codes. */
int sm_radau(int n, const double *w, const double *p, double t0, double *x, int nout,
             const double *tout, double *xout, const double *cst, const double *opt,
             long max_steps, int max_newton, double *stats, double *t_fail)
{
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

    int sz_arg, sz_res, sz_iw, sz_w, a2, r2, i2, w2;
    sm_rhs_work(&sz_arg, &sz_res, &sz_iw, &sz_w);
    sm_jac_work(&a2, &r2, &i2, &w2);
    sz_arg = sz_arg > a2 ? sz_arg : a2;
    sz_res = sz_res > r2 ? sz_res : r2;
    sz_iw = sz_iw > i2 ? sz_iw : i2;
    sz_w = sz_w > w2 ? sz_w : w2;

    size_t nn = (size_t)n * n;
    Pattern pt = jac_pattern(n);
    double *dbl = malloc(sizeof(double) * (SM_LU_SIZE(n) + 28 * (size_t)n + (size_t)sz_w
                                           + (size_t)(pt.nnz > 0 ? pt.nnz : 0) + 1));
    double complex *cplx = malloc(sizeof(double complex) * (SM_LU_SIZE(n) + n));
    int *ints = malloc(sizeof(int) * (2 * SM_FACTOR_INTS(n) + (size_t)sz_iw + 1));
    unsigned char *bytes = calloc(2 * nn + 1, 1);
    const double **arg = malloc(sizeof(double *) * (sz_arg + 1));
    double **res = malloc(sizeof(double *) * (sz_res + 1));
    if (!dbl || !cplx || !ints || !bytes || !arg || !res || pt.nnz < 0) {
        free(dbl), free(cplx), free(ints), free(bytes), free(arg), free(res), free(pt.own);
        return SM_NO_MEMORY;
    }
    double *LUr = dbl, *y = LUr + SM_LU_SIZE(n);
    double *f0 = y + n, *ynew = f0 + n, *scale = ynew + n, *tmp = scale + n, *err = tmp + n;
    double *Z = err + n, *W = Z + 3 * n, *dW = W + 3 * n, *F = dW + 3 * n, *Q = F + 3 * n;
    double *Qold = Q + 3 * n, *rr = Qold + 3 * n, *ypoly = rr + n, *jnz = ypoly + n;
    double *cw = jnz + pt.nnz;
    double complex *LUc = cplx, *rc = LUc + SM_LU_SIZE(n);
    Factor fr, fc;
    int *iw = factor_init(&fc, n, factor_init(&fr, n, ints, bytes), bytes + nn);
    factor_list_pattern(&fr, n, &pt);
    factor_list_pattern(&fc, n, &pt);
    memset(LUr, 0, sizeof(double) * nn); /* unlisted positions stay zero (SM_FILL) */
    memset(LUc, 0, sizeof(double complex) * nn);
    Model m = {n, w, p, arg, res, iw, cw, stats, pt, jnz};

    int code = SM_OK, k_out = 0;
    double t = t0;
    memcpy(y, x, sizeof(double) * n);
    *t_fail = t0;

    if (rhs(&m, t, y, f0)) { code = SM_RHS; goto done; }
    if (jac(&m, t, y)) { code = SM_JAC; goto done; }
    int current_jac = 1;

    double h = opt[2];
    if (!(h > 0) && initial_step(&m, t, y, f0, t_end - t, rtol, atol, 4, scale, tmp, err, &h)) {
        code = SM_RHS;
        goto done;
    }

    int lu_ok = 0, have_poly = 0, first = 1, rejected = 0, fails = 0;
    double faccon = 1.0;
    long steps = 0;
    double h_lu = 0, t_poly = 0, h_poly = 0, h_old = -1, err_old = -1;
    while (t < t_end) {
        if (steps >= max_steps) {
            code = SM_MAX_STEPS;
            break;
        }
        double hmin = 10 * DBL_EPSILON * fmax(fabs(t), fabs(t_end - t0));
        h = fmin(h, hmax);
        if (h < hmin) { code = SM_STEP_TOO_SMALL; break; }
        if (t + 1.0001 * h >= t_end) h = t_end - t;  /* land on the end, no sliver step */
        if (!lu_ok || h != h_lu) {
            fill_real(n, LUr, &fr, &pt, jnz, tb.mu_r / h);
            fill_complex(n, LUc, &fc, &pt, jnz, (mu_c_re + I * mu_c_im) / h);
            stats[ST_LU] += 1;
            if (lu_real(n, LUr, &fr) || lu_complex(n, LUc, &fc)) {
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
                bad = rhs(&m, t + tb.c[i] * h, tmp, F + i * n);
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
            solve_real(n, LUr, &fr, rr);
            solve_complex(n, LUc, &fc, rc);
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
                for (int r = k + 2; r < max_newton; ++r) left *= theta;
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
                if (jac(&m, t, y)) { code = SM_JAC; break; }
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
        solve_real(n, LUr, &fr, err);
        double en = rms(1, n, err, scale);
        if (en >= 1 && (first || rejected)) {
            for (int j = 0; j < n; ++j) rr[j] = y[j] + err[j];
            if (rhs(&m, t, rr, err)) { en = 2.0; }
            else {
                for (int j = 0; j < n; ++j) err[j] += tmp[j];
                solve_real(n, LUr, &fr, err);
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

        int refresh_jac = theta > 1e-3;
        factor = fmin(10.0, safety * factor);
        if (rejected) factor = fmin(factor, 1.0);
        if (!refresh_jac && factor < 1.2) factor = 1.0;
        t = t_new;
        memcpy(y, ynew, sizeof(double) * n);
        *t_fail = t;
        if (rhs(&m, t, y, f0)) { code = SM_RHS; break; }
        if (refresh_jac) {
            if (jac(&m, t, y)) { code = SM_JAC; break; }
            lu_ok = 0;
        }
        current_jac = refresh_jac;
        h_old = h;
        err_old = en;
        h *= factor;
        first = rejected = fails = 0;
        faccon = pow(fmax(faccon, DBL_EPSILON), 0.8);
    }
done:
    memcpy(x, y, sizeof(double) * n);
    if (code != SM_OK) *t_fail = t;
    free(dbl), free(cplx), free(ints), free(bytes), free(arg), free(res), free(pt.own);
    return code;
}
