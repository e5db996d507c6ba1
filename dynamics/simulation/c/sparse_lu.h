/* The sparse LU of the integrators' iteration matrices (real and complex), over the
 * Jacobian's compressed-column pattern and the fill-in: a header of static functions,
 * included by integrator.h (and copied next to radau.c into an FMU's sources). */
#ifndef SM_SPARSE_LU_H
#define SM_SPARSE_LU_H

#include <complex.h>
#include <math.h>
#include <stdlib.h>

const int *sm_jac_sparsity_out(int i);

/* The Jacobian's compressed-column pattern (built in own, to be freed, if sm_jac is dense). */
typedef struct {
    int nnz;
    const int *colind, *row;
    int *own;
} Pattern;

/* The pattern of sm_jac's output; pt.nnz < 0 if out of memory. */
static Pattern jac_pattern(int n)
{
    const int *sp = sm_jac_sparsity_out(0);
    Pattern pt = {0, sp + 2, sp + 3 + n, NULL};
    if (sp[2] != 1) { /* compressed columns: colind[0] = 0 */
        pt.nnz = pt.colind[n];
        return pt;
    }
    pt.own = malloc(sizeof(int) * ((size_t)n * n + n + 1)); /* dense: [nrow, ncol, 1] */
    if (!pt.own) {
        pt.nnz = -1;
        return pt;
    }
    int *colind = pt.own, *row = colind + n + 1;
    for (int c = 0; c <= n; ++c) colind[c] = c * n;
    for (size_t k = 0; k < (size_t)n * n; ++k) row[k] = (int)(k % n);
    pt.colind = colind;
    pt.row = row;
    pt.nnz = n * n;
    return pt;
}

/* The factors of P A = L U, rows kept in place (P implicit): step k pivots on row
 * prow[k]; the multipliers of column k sit in (original) rows li[lp[k]..lp[k+1]), row k of
 * U (the pivot row's part right of column k) in columns ui[up[k]..up[k+1]).
 * The working matrix's possibly nonzero positions (the Jacobian's pattern, the diagonal
 * and the fill-in of every factorisation so far) are listed by rows (row i's columns
 * rcol[i*n .. i*n + rlen[i])) and by columns (column j's rows ccol[j*n .. j*n + clen[j])),
 * each position once (listed[i + j*n] marks it): the pivot search, the updates and the
 * next fill's clearing visit only those, so an LU costs O(n) plus its arithmetic on the
 * nonzeros and their fill-in, not O(n^2). */
typedef struct {
    int *prow, *lp, *li, *up, *ui, *rlen, *rcol, *clen, *ccol, *done;
    unsigned char *listed;
} Factor;

/* Carve a Factor for size n out of mem (SM_FACTOR_INTS(n) ints) and bytes (n*n, zero);
 * returns the rest of mem. Then factor_list_pattern; the working matrix must start zero. */
static int *factor_init(Factor *f, int n, int *mem, unsigned char *bytes)
{
    size_t nn = (size_t)n * n;
    f->prow = mem;
    f->lp = f->prow + n;
    f->up = f->lp + n + 1;
    f->li = f->up + n + 1;
    f->ui = f->li + nn;
    f->rcol = f->ui + nn;
    f->ccol = f->rcol + nn;
    f->rlen = f->ccol + nn;
    f->clen = f->rlen + n;
    f->done = f->clen + n;
    f->listed = bytes;
    for (int i = 0; i < n; ++i) f->rlen[i] = f->clen[i] = 0;
    return f->done + n;
}

/* Ints a Factor takes from mem. */
#define SM_FACTOR_INTS(n) (4 * (size_t)(n) * (n) + 6 * (size_t)(n) + 2)

/* Doubles (or complex numbers) an LU of size n works in: SM_LU_SIZE(n). */
#define SM_LU_SIZE(n) (3 * (size_t)(n) * (n) + 2 * (size_t)(n))

/* List position (i, j) of a Factor as nonzero (once). */
static inline void list_nonzero(Factor *f, int n, int i, int j)
{
    size_t ij = i + (size_t)j * n;
    if (f->listed[ij]) return;
    f->listed[ij] = 1;
    f->rcol[(size_t)i * n + f->rlen[i]++] = j;
    f->ccol[(size_t)j * n + f->clen[j]++] = i;
}

/* List the positions of diag I - J (J in pattern pt): once, after factor_init. */
static void factor_list_pattern(Factor *f, int n, const Pattern *pt)
{
    for (int i = 0; i < n; ++i) list_nonzero(f, n, i, i);
    for (int c = 0; c < n; ++c)
        for (int k = pt->colind[c]; k < pt->colind[c + 1]; ++k) list_nonzero(f, n, pt->row[k], c);
}

/* a = diag I - J (J: the nonzeros jnz in pattern pt), after zeroing every listed position
 * (the lists keep the fill-in of earlier factorisations: they only grow). */
#define SM_FILL(NAME, T)                                                               \
    static void NAME(int n, T *a, const Factor *f, const Pattern *pt, const double *jnz, \
                     T diag)                                                           \
    {                                                                                  \
        for (int i = 0; i < n; ++i) {                                                  \
            const int *c = f->rcol + (size_t)i * n;                                    \
            for (int r = 0; r < f->rlen[i]; ++r) a[i + (size_t)c[r] * n] = 0.0;        \
            a[i + (size_t)i * n] = diag;                                               \
        }                                                                              \
        for (int c = 0; c < n; ++c)                                                    \
            for (int k = pt->colind[c]; k < pt->colind[c + 1]; ++k)                    \
                a[pt->row[k] + (size_t)c * n] -= jnz[k];                               \
    }

/* LU with partial pivoting of the column-major n x n matrix a (the first n*n of
 * SM_LU_SIZE(n) entries, filled by SM_FILL; overwritten), rows in place. The factors are
 * packed for the solves as they are found: the multipliers of column k (rows in the
 * Factor, values at a + n*n), row k of U (columns in the Factor, values at a + 2 n*n) and
 * the inverse pivots (a + 3 n*n). */
#define SM_LU(NAME, T, ABS)                                                           \
    static int NAME(int n, T *a, Factor *f)                                           \
    {                                                                                 \
        T *lv = a + (size_t)n * n, *uv = lv + (size_t)n * n, *dv = uv + (size_t)n * n; \
        int nl = 0, nu = 0;                                                           \
        for (int i = 0; i < n; ++i) f->done[i] = 0;                                   \
        for (int k = 0; k < n; ++k) {                                                 \
            const T *ak = a + (size_t)k * n;                                          \
            const int *rows = f->ccol + (size_t)k * n;                                \
            int q = -1;                                                               \
            double big = 0.0;                                                         \
            for (int r = 0; r < f->clen[k]; ++r)                                      \
                if (!f->done[rows[r]] && ABS(ak[rows[r]]) > big)                      \
                    big = ABS(ak[rows[r]]), q = rows[r];                              \
            if (q < 0) return 1;                                                      \
            f->prow[k] = q;                                                           \
            f->done[q] = 1;                                                           \
            T inv = dv[k] = 1.0 / ak[q];                                              \
            int l0 = f->lp[k] = nl;                                                   \
            for (int r = 0; r < f->clen[k]; ++r) {                                    \
                int i = rows[r];                                                      \
                if (!f->done[i] && ak[i] != 0.0) lv[nl] = ak[i] * inv, f->li[nl++] = i; \
            }                                                                         \
            f->up[k] = nu;                                                            \
            const int *cols = f->rcol + (size_t)q * n;                                \
            for (int r = 0; r < f->rlen[q]; ++r) {                                    \
                int j = cols[r];                                                      \
                T aqj = a[q + (size_t)j * n], *aj = a + (size_t)j * n;                \
                if (j <= k || aqj == 0.0) continue;                                   \
                uv[nu] = aqj, f->ui[nu++] = j;                                        \
                for (int t = l0; t < nl; ++t) {                                       \
                    list_nonzero(f, n, f->li[t], j);                                  \
                    aj[f->li[t]] -= lv[t] * aqj;                                      \
                }                                                                     \
            }                                                                         \
        }                                                                             \
        f->lp[n] = nl;                                                                \
        f->up[n] = nu;                                                                \
        return 0;                                                                     \
    }

/* Solve A x = b with the factors of SM_LU (x into b): forward through the pivot rows
 * (each final when its step comes), then U by rows. */
#define SM_SOLVE(NAME, T)                                                             \
    static void NAME(int n, T *a, const Factor *f, T *b)                              \
    {                                                                                 \
        T *lv = a + (size_t)n * n, *uv = lv + (size_t)n * n, *dv = uv + (size_t)n * n; \
        T *z = dv + n;                                                                \
        for (int k = 0; k < n; ++k) {                                                 \
            T bk = z[k] = b[f->prow[k]];                                              \
            for (int r = f->lp[k]; r < f->lp[k + 1]; ++r) b[f->li[r]] -= lv[r] * bk;  \
        }                                                                             \
        for (int k = n - 1; k >= 0; --k) {                                            \
            T bk = z[k];                                                              \
            for (int r = f->up[k]; r < f->up[k + 1]; ++r) bk -= uv[r] * b[f->ui[r]];  \
            b[k] = bk * dv[k];                                                        \
        }                                                                             \
    }

/* |re| + |im|: the pivot size of LAPACK's complex LU, without a square root */
static inline double abs1(double complex z) { return fabs(creal(z)) + fabs(cimag(z)); }

SM_FILL(fill_real, double)
SM_FILL(fill_complex, double complex)
SM_LU(lu_real, double, fabs)
SM_LU(lu_complex, double complex, abs1)
SM_SOLVE(solve_real, double)
SM_SOLVE(solve_complex, double complex)

#endif
