/* ops_avx2.c - AVX2/FMA element-wise and row-wise ops of fk_ops.h.
 *
 * LayerNorm keeps its statistics in double, like the reference: the mean of a
 * constant row is then exactly that constant (output == bias), and rows of
 * magnitude 1e30 or 1e-30 neither overflow nor underflow in the variance.
 * The residual add uses a separate multiply and add, so it matches the
 * reference bit for bit. */
#include <immintrin.h>
#include <math.h>

#include "vecmath_avx2.h"
#include "x86.h"

static inline __m256 tail_load(const float *p, __m256i mask)
{
    return _mm256_maskload_ps(p, mask);
}

static inline double hsum_pd(__m256d v)
{
    __m128d s = _mm_add_pd(_mm256_castpd256_pd128(v), _mm256_extractf128_pd(v, 1));
    return _mm_cvtsd_f64(_mm_add_sd(s, _mm_unpackhi_pd(s, s)));
}

#define ELEMENTWISE(name, expr)                                              \
    void name(const float *x, float *y, size_t n)                            \
    {                                                                        \
        size_t i = 0;                                                        \
        for (; i + 8 <= n; i += 8) {                                         \
            __m256 v = _mm256_loadu_ps(x + i);                               \
            _mm256_storeu_ps(y + i, expr);                                   \
        }                                                                    \
        if (i < n) {                                                         \
            __m256i mask = fk__tail_mask_avx2((int)(n - i));                 \
            __m256 v = tail_load(x + i, mask);                               \
            _mm256_maskstore_ps(y + i, mask, expr);                          \
        }                                                                    \
    }

ELEMENTWISE(fk__gelu_array_avx2, fk__gelu_avx2(v))
ELEMENTWISE(fk__silu_array_avx2, fk__silu_avx2(v))
ELEMENTWISE(fk__relu_array_avx2, _mm256_max_ps(_mm256_setzero_ps(), v))   /* NaN passes */

static void layernorm_row(const float *x, int n, const float *w, const float *b, float eps,
                          float *y)
{
    __m256d s0 = _mm256_setzero_pd(), s1 = _mm256_setzero_pd();
    int j = 0;
    for (; j + 8 <= n; j += 8) {
        __m256 v = _mm256_loadu_ps(x + j);
        s0 = _mm256_add_pd(s0, _mm256_cvtps_pd(_mm256_castps256_ps128(v)));
        s1 = _mm256_add_pd(s1, _mm256_cvtps_pd(_mm256_extractf128_ps(v, 1)));
    }
    double sum = hsum_pd(_mm256_add_pd(s0, s1));
    for (int k = j; k < n; k++)
        sum += x[k];
    double mean = sum / n;

    __m256d m = _mm256_set1_pd(mean);
    s0 = _mm256_setzero_pd();
    s1 = _mm256_setzero_pd();
    for (j = 0; j + 8 <= n; j += 8) {
        __m256 v = _mm256_loadu_ps(x + j);
        __m256d d0 = _mm256_sub_pd(_mm256_cvtps_pd(_mm256_castps256_ps128(v)), m);
        __m256d d1 = _mm256_sub_pd(_mm256_cvtps_pd(_mm256_extractf128_ps(v, 1)), m);
        s0 = _mm256_fmadd_pd(d0, d0, s0);
        s1 = _mm256_fmadd_pd(d1, d1, s1);
    }
    double ss = hsum_pd(_mm256_add_pd(s0, s1));
    for (int k = j; k < n; k++)
        ss += (x[k] - mean) * (x[k] - mean);
    double rstd = 1.0 / sqrt(ss / n + eps);

    __m256d r = _mm256_set1_pd(rstd);
    for (j = 0; j + 8 <= n; j += 8) {
        __m256 v = _mm256_loadu_ps(x + j);
        __m256d d0 = _mm256_sub_pd(_mm256_cvtps_pd(_mm256_castps256_ps128(v)), m);
        __m256d d1 = _mm256_sub_pd(_mm256_cvtps_pd(_mm256_extractf128_ps(v, 1)), m);
        __m256 t = _mm256_set_m128(_mm256_cvtpd_ps(_mm256_mul_pd(d1, r)),
                                   _mm256_cvtpd_ps(_mm256_mul_pd(d0, r)));
        if (w)
            t = _mm256_mul_ps(t, _mm256_loadu_ps(w + j));
        if (b)
            t = _mm256_add_ps(t, _mm256_loadu_ps(b + j));
        _mm256_storeu_ps(y + j, t);
    }
    for (; j < n; j++) {
        float v = (float)((x[j] - mean) * rstd);
        if (w)
            v *= w[j];
        if (b)
            v += b[j];
        y[j] = v;
    }
}

void fk__layernorm_rows_avx2(const float *x, int rows, int cols, int ldx, const float *w,
                             const float *b, float eps, float *y, int ldy)
{
    for (int i = 0; i < rows; i++)
        layernorm_row(x + (size_t)i * ldx, cols, w, b, eps, y + (size_t)i * ldy);
}

/* exp(x - max) / sum: max, then the exponentials stored in y with their sum,
 * then one scaling pass. */
static void softmax_row(const float *x, int n, float *y)
{
    const __m256 ninf = _mm256_set1_ps(-INFINITY);
    __m256 vm = ninf;
    int j = 0;
    for (; j + 8 <= n; j += 8)
        vm = _mm256_max_ps(vm, _mm256_loadu_ps(x + j));
    __m256i mask = fk__tail_mask_avx2(n - j);
    if (j < n)
        vm = _mm256_max_ps(vm, _mm256_blendv_ps(ninf, tail_load(x + j, mask),
                                                _mm256_castsi256_ps(mask)));
    __m256 m = _mm256_set1_ps(fk__hmax_avx2(vm));

    __m256 s = _mm256_setzero_ps();
    for (j = 0; j + 8 <= n; j += 8) {
        __m256 e = fk__exp_avx2(_mm256_sub_ps(_mm256_loadu_ps(x + j), m));
        _mm256_storeu_ps(y + j, e);
        s = _mm256_add_ps(s, e);
    }
    if (j < n) {
        __m256 e = fk__exp_avx2(_mm256_sub_ps(tail_load(x + j, mask), m));
        e = _mm256_and_ps(e, _mm256_castsi256_ps(mask));
        _mm256_maskstore_ps(y + j, mask, e);
        s = _mm256_add_ps(s, e);
    }
    __m256 inv = _mm256_set1_ps(1.0f / fk__hsum_avx2(s));

    for (j = 0; j + 8 <= n; j += 8)
        _mm256_storeu_ps(y + j, _mm256_mul_ps(_mm256_loadu_ps(y + j), inv));
    if (j < n)
        _mm256_maskstore_ps(y + j, mask, _mm256_mul_ps(tail_load(y + j, mask), inv));
}

void fk__softmax_rows_avx2(const float *x, int rows, int cols, int ldx, float *y, int ldy)
{
    for (int i = 0; i < rows; i++)
        softmax_row(x + (size_t)i * ldx, cols, y + (size_t)i * ldy);
}

void fk__residual_rows_avx2(float *x, int ldx, const float *r, int ldr, const float *gamma,
                            int rows, int cols)
{
    const __m256 one = _mm256_set1_ps(1.0f);
    for (int i = 0; i < rows; i++) {
        float *xi = x + (size_t)i * ldx;
        const float *ri = r + (size_t)i * ldr;
        int j = 0;
        if (gamma) {
            for (; j + 8 <= cols; j += 8)
                _mm256_storeu_ps(xi + j, _mm256_add_ps(_mm256_loadu_ps(xi + j),
                                                       _mm256_mul_ps(_mm256_loadu_ps(gamma + j),
                                                                     _mm256_loadu_ps(ri + j))));
        } else {
            for (; j + 8 <= cols; j += 8)
                _mm256_storeu_ps(xi + j, _mm256_add_ps(_mm256_loadu_ps(xi + j),
                                                       _mm256_loadu_ps(ri + j)));
        }
        if (j < cols) {
            __m256i mask = fk__tail_mask_avx2(cols - j);
            __m256 g = gamma ? tail_load(gamma + j, mask) : one;
            __m256 v = _mm256_add_ps(tail_load(xi + j, mask), _mm256_mul_ps(g, tail_load(ri + j, mask)));
            _mm256_maskstore_ps(xi + j, mask, v);
        }
    }
}
