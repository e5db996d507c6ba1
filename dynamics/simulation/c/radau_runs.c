/* The simulator's run in one call: several pieces of a simulation, each integrated by
 * radau.c from a fresh start (as one call per piece would), with the states written at
 * every output time and checked there: finite, and every bounded signal inside its
 * [low, high] (the physical domain), evaluated by the CasADi-generated
 *   sm_dom(t, x, w, p) -> the bounded signals (the model's order, inputs from the law)
 * compiled into the same library. Compiled into the simulator's libraries only (an FMU
 * checks its domain after each doStep, physics.c). */
#include <math.h>
#include <stdlib.h>

typedef struct SmRadau SmRadau;
int sm_radau(SmRadau *r, const double *w, const double *p, double t0, double *x, int nout,
             const double *tout, double *xout, const double *cst, const double *opt,
             long max_steps, int max_newton, double *stats, double *t_fail, int resume);
int sm_dom(const double **arg, double **res, int *iw, double *w, int mem);
int sm_dom_work(int *sz_arg, int *sz_res, int *sz_iw, int *sz_w);

/* Return codes beyond radau.c's (1-6). */
enum { RUN_NONFINITE = 7, RUN_DOMAIN = 8, RUN_NO_MEMORY = 5 };

/* Integrate the pieces k = 0 .. npiece - 1: piece k runs from the end of piece k - 1 (t0,
 * x for the first) through tout[ends[k - 1] .. ends[k]) (ends[-1] = 0) with the law's
 * argument W[k * nw ...], writing the states into xout (one row of n per time).
 *   x      in: the start; out: the state at the end of the last piece that passed
 *   nb, low, high, y   the bounded signals' count, ranges and room for their values
 *   info   out on failure: [0] the piece, [1] the row (the output time), [2] the signal
 *          (RUN_DOMAIN), [3] its value
 * Returns 0, radau.c's code of a failing piece (t_fail from it), RUN_NONFINITE (a state
 * not finite at row info[1]) or RUN_DOMAIN. */
int sm_radau_runs(SmRadau *r, int n, int npiece, const int *ends, int nw, const double *W,
                  const double *p, double t0, double *x, const double *tout, double *xout,
                  const double *cst, const double *opt, long max_steps, int max_newton,
                  double *stats, double *t_fail, int nb, const double *low,
                  const double *high, double *y, double *info)
{
    int sz_arg, sz_res, sz_iw, sz_w;
    sm_dom_work(&sz_arg, &sz_res, &sz_iw, &sz_w);
    const double **arg = malloc(sizeof(double *) * (sz_arg + 4));
    double **res = malloc(sizeof(double *) * (sz_res + 1));
    int *iw = malloc(sizeof(int) * (sz_iw + 1));
    double *dw = malloc(sizeof(double) * (sz_w + 1));
    int code = 0;
    if (!arg || !res || !iw || !dw) {
        code = RUN_NO_MEMORY;
        goto out;
    }
    for (int k = 0, row = 0; k < npiece; row = ends[k++]) {
        double t_start = k ? tout[row - 1] : t0;
        const double *w = W + (size_t)k * nw;
        double *xk = xout + (size_t)row * n;
        info[0] = k;
        code = sm_radau(r, w, p, t_start, x, ends[k] - row, tout + row, xk, cst, opt,
                        max_steps, max_newton, stats, t_fail, 0);
        if (code) goto out;
        for (int i = row; i < ends[k]; ++i)
            for (int j = 0; j < n; ++j)
                if (!isfinite(xout[(size_t)i * n + j])) {
                    info[1] = i;
                    code = RUN_NONFINITE;
                    goto out;
                }
        for (int i = row; i < ends[k]; ++i) {
            arg[0] = tout + i, arg[1] = xout + (size_t)i * n, arg[2] = w, arg[3] = p;
            res[0] = y;
            int failed = sm_dom(arg, res, iw, dw, 0);
            for (int j = 0; j < nb; ++j)
                if (failed || !(y[j] >= low[j] && y[j] <= high[j])) {
                    info[1] = i, info[2] = j, info[3] = failed ? NAN : y[j];
                    code = RUN_DOMAIN;
                    goto out;
                }
        }
    }
out:
    free(arg), free(res), free(iw), free(dw);
    return code;
}
