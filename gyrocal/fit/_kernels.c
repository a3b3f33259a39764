/* The fit's kernels (see gyrocal/fit/kernels.py): the overlapping Allan variance's sums of
 * the noise model, and the Cholesky factor of the wander-aware fit's covariance.
 *
 * Loaded with ctypes; the module init exists only so the build is an ordinary extension.
 */
#include <Python.h>
#include <math.h>
#include <stdint.h>

/* Eight independent accumulators per sum: the compiler can vectorise the lanes without
 * reassociating any single sum, so results do not depend on optimisation flags. */
#define LANES 8

/* Overlapping Allan variance sums (gyrocal/fit/noise.py): for each averaging factor m[j],
 * out[j] = sum over i < N - 2m of (theta[i+2m] - 2 theta[i+m] + theta[i])^2, in one read of
 * theta per factor instead of numpy's four passes with temporaries. */
void second_diff_sumsq(const double *theta, int64_t n, const int64_t *m, int64_t k, double *out)
{
    for (int64_t j = 0; j < k; j++) {
        const int64_t step = m[j], count = n - 2 * step;
        double acc[LANES] = {0};
        int64_t i = 0;
        for (; i + LANES <= count; i += LANES) {
            for (int l = 0; l < LANES; l++) {
                const double d = theta[i + l + 2 * step] - 2.0 * theta[i + l + step] + theta[i + l];
                acc[l] += d * d;
            }
        }
        for (int l = 0; i < count; i++, l++) {
            const double d = theta[i + 2 * step] - 2.0 * theta[i + step] + theta[i];
            acc[l] += d * d;
        }
        double total = 0;
        for (int l = 0; l < LANES; l++) total += acc[l];
        out[j] = count > 0 ? total : 0.0;
    }
}

/* Cholesky factor of a diagonal plus a semiseparable matrix, and its inverse applied to
 * columns (gyrocal/fit/kernels.py: semiseparable_cholesky): celerite's recursion
 * (Foreman-Mackey et al. 2017), O(n J^2) and O(n J p), with decays of at most 1.
 *
 * With u = U[n] * s and v = V[m] * s (the generators at the column scales s), for m < n:
 * C[n][m] = sum_k u_k v_k P_k(m, n), P_k(m, n) = alpha[n][k] beta[n-1][k] alpha[n-1][k]
 * ... beta[m+1][k] alpha[m+1][k]; C[n][n] = diag[n]. C = L diag(D) L^T with L unit lower
 * triangular, L[n][m] = sum_k u_k W[m][k] P_k(m, n). S (J x J) is work space.
 * Returns 0, or 1 + the row whose pivot is not positive (C is not positive definite to
 * rounding). */
int64_t semisep_factor(int64_t n, int64_t J, const double *restrict diag,
                       const double *restrict U, const double *restrict V,
                       const double *restrict s, const double *restrict alpha,
                       const double *restrict beta, double *restrict W, double *restrict D,
                       double *restrict work)
{
    /* work: S (J x J), then the decays g and h of the previous row and this row's u */
    double *restrict S = work, *restrict g = work + J * J, *restrict h = g + J, *restrict u = h + J;
    for (int64_t k = 0; k < J * J; k++) S[k] = 0.0;
    for (int64_t i = 0; i < n; i++) {
        const double *restrict a = alpha + i * J;
        double *restrict w = W + i * J;
        const double dp = i > 0 ? D[i - 1] : 0.0;
        for (int64_t k = 0; k < J; k++) {
            g[k] = i > 0 ? a[k] * beta[(i - 1) * J + k] : 0.0;
            h[k] = i > 0 ? a[k] * W[(i - 1) * J + k] : 0.0;
            u[k] = U[i * J + k] * s[k];
        }
        double quad = 0.0;
        for (int64_t k = 0; k < J; k++) {
            double *restrict row = S + k * J;
            const double gk = g[k], hk = dp * h[k];
            double t = 0.0;
            for (int64_t l = 0; l < J; l++) {
                row[l] = gk * g[l] * row[l] + hk * h[l];
                t += row[l] * u[l];
            }
            w[k] = t;                   /* (S u)_k, until the pivot is known */
            quad += u[k] * t;
        }
        const double d = diag[i] - quad;
        if (!(d > 0.0)) return i + 1;
        D[i] = d;
        const double *restrict v = V + i * J, *restrict b = beta + i * J;
        for (int64_t k = 0; k < J; k++) w[k] = (v[k] * s[k] - b[k] * w[k]) / d;
    }
    return 0;
}

/* Z = diag(D)^(-1/2) L^(-1) Y for the factor above; Y and Z are (n, p), row-major.
 * work: f (J x p), then the previous row's z (p). */
void semisep_solve(int64_t n, int64_t J, int64_t p, const double *restrict U,
                   const double *restrict s, const double *restrict W,
                   const double *restrict D, const double *restrict alpha,
                   const double *restrict beta, const double *restrict Y, double *restrict Z,
                   double *restrict work)
{
    double *restrict f = work, *restrict z = work + J * p;
    for (int64_t k = 0; k < J * p + p; k++) work[k] = 0.0;
    for (int64_t i = 0; i < n; i++) {
        const double *restrict a = alpha + i * J, *restrict y = Y + i * p;
        double *restrict out = Z + i * p;
        for (int64_t c = 0; c < p; c++) out[c] = y[c];
        for (int64_t k = 0; k < J; k++) {
            const double gk = i > 0 ? a[k] * beta[(i - 1) * J + k] : 0.0;
            const double hk = i > 0 ? a[k] * W[(i - 1) * J + k] : 0.0;
            const double uk = U[i * J + k] * s[k];
            double *restrict row = f + k * p;
            for (int64_t c = 0; c < p; c++) {
                row[c] = gk * row[c] + hk * z[c];
                out[c] -= uk * row[c];
            }
        }
        const double root = sqrt(D[i]);
        for (int64_t c = 0; c < p; c++) {
            z[c] = out[c];
            out[c] /= root;
        }
    }
}

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_kernels",
                                    "The fit's kernels, loaded with ctypes.", -1, NULL};

PyMODINIT_FUNC PyInit__kernels(void) { return PyModule_Create(&module); }
