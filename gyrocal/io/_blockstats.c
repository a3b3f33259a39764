/* Per-block statistics in one read of each sample (see gyrocal/io/blockstats.py).
 *
 * A block is `size` consecutive values. Sums are taken in double of the values minus the
 * block's first value, so a large offset (400 deg/s) costs no precision in the variance.
 * Outputs are written with a stride so they can fill a column of an (n, 3) array.
 * NaN propagates into a block's moments and is skipped by the finite-only mean, as in the
 * numpy code these functions replace.
 *
 * Loaded with ctypes; the module init exists only so the build is an ordinary extension.
 */
#include <Python.h>
#include <math.h>
#include <stdint.h>

/* Eight independent accumulators per quantity: the compiler can vectorise the lanes
 * without reassociating any single sum, so results do not depend on optimisation flags. */
#define LANES 8
#define MOMENTS(NAME, T)                                                                  \
void NAME(const T *x, int64_t blocks, int64_t size, double *mean, int64_t mean_stride,  \
          float *var, int64_t var_stride)                                                \
{                                                                                        \
    for (int64_t b = 0; b < blocks; b++) {                                               \
        const T *p = x + b * size;                                                       \
        const double x0 = (double)p[0];                                                  \
        double s[LANES] = {0}, q[LANES] = {0};                                           \
        int64_t i = 0;                                                                   \
        for (; i + LANES <= size; i += LANES) {                                          \
            for (int j = 0; j < LANES; j++) {                                            \
                const double d = (double)p[i + j] - x0;                                  \
                s[j] += d; q[j] += d * d;                                                \
            }                                                                            \
        }                                                                                \
        for (int j = 0; i < size; i++, j++) {                                            \
            const double d = (double)p[i] - x0;                                          \
            s[j] += d; q[j] += d * d;                                                    \
        }                                                                                \
        double st = 0, qt = 0;                                                           \
        for (int j = 0; j < LANES; j++) { st += s[j]; qt += q[j]; }                     \
        const double v = (qt - st * st / (double)size) / (double)(size - 1);             \
        mean[b * mean_stride] = x0 + st / (double)size;                                  \
        var[b * var_stride] = (float)(v > 0 ? v : 0);                                    \
    }                                                                                    \
}

#define MEAN(NAME, T)                                                                     \
void NAME(const T *x, int64_t blocks, int64_t size, double *mean, int64_t mean_stride)  \
{                                                                                        \
    for (int64_t b = 0; b < blocks; b++) {                                               \
        const T *p = x + b * size;                                                       \
        double s[LANES] = {0};                                                           \
        int64_t i = 0;                                                                   \
        for (; i + LANES <= size; i += LANES)                                            \
            for (int j = 0; j < LANES; j++) s[j] += (double)p[i + j];                    \
        for (int j = 0; i < size; i++, j++) s[j] += (double)p[i];                        \
        double st = 0;                                                                   \
        for (int j = 0; j < LANES; j++) st += s[j];                                      \
        mean[b * mean_stride] = st / (double)size;                                       \
    }                                                                                    \
}

/* Mean over the finite values only (NaN, +-inf skipped); NaN when a block has none. */
#define FINITE_MEAN(NAME, T)                                                              \
void NAME(const T *x, int64_t blocks, int64_t size, double *mean, int64_t mean_stride)  \
{                                                                                        \
    for (int64_t b = 0; b < blocks; b++) {                                               \
        const T *p = x + b * size;                                                       \
        double s = 0;                                                                    \
        int64_t n = 0;                                                                   \
        for (int64_t i = 0; i < size; i++) {                                             \
            const double a = (double)p[i];                                               \
            if (a - a == 0) { s += a; n++; } /* false for NaN and inf */                 \
        }                                                                                \
        mean[b * mean_stride] = n ? s / (double)n : (double)NAN;                         \
    }                                                                                    \
}

MOMENTS(block_moments_f32, float)
MOMENTS(block_moments_f64, double)
MEAN(block_mean_f32, float)
MEAN(block_mean_f64, double)
FINITE_MEAN(block_finite_mean_f32, float)
FINITE_MEAN(block_finite_mean_f64, double)

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_blockstats",
                                    "Block statistics kernels, loaded with ctypes.", -1, NULL};

PyMODINIT_FUNC PyInit__blockstats(void) { return PyModule_Create(&module); }
