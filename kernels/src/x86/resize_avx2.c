/* resize_avx2.c - one output row of the resamplers, vectorized over channels
 * (HWC: the c values of a pixel are contiguous). Every value is computed with
 * the same multiplies and adds in the same order as the references in
 * resize.c, so the results are identical; channels past the last multiple of
 * 8 go through the same scalar expression. */
#include <immintrin.h>

#include "x86.h"

void fk__bilinear_row_avx2(const float *r0, const float *r1, float wy0, float wy1,
                           const int32_t *xi, const float *xw, int wo, int c, float *out)
{
    const __m256 vy0 = _mm256_set1_ps(wy0), vy1 = _mm256_set1_ps(wy1);
    for (int j = 0; j < wo; j++) {
        const float *a = r0 + (size_t)xi[2 * j] * c, *b = r0 + (size_t)xi[2 * j + 1] * c;
        const float *d = r1 + (size_t)xi[2 * j] * c, *e = r1 + (size_t)xi[2 * j + 1] * c;
        float w0 = xw[2 * j], w1 = xw[2 * j + 1];
        const __m256 v0 = _mm256_set1_ps(w0), v1 = _mm256_set1_ps(w1);
        float *o = out + (size_t)j * c;
        int k = 0;
        for (; k + 8 <= c; k += 8) {
            __m256 top = _mm256_add_ps(_mm256_mul_ps(v0, _mm256_loadu_ps(a + k)),
                                       _mm256_mul_ps(v1, _mm256_loadu_ps(b + k)));
            __m256 bot = _mm256_add_ps(_mm256_mul_ps(v0, _mm256_loadu_ps(d + k)),
                                       _mm256_mul_ps(v1, _mm256_loadu_ps(e + k)));
            _mm256_storeu_ps(o + k, _mm256_add_ps(_mm256_mul_ps(vy0, top), _mm256_mul_ps(vy1, bot)));
        }
        for (; k < c; k++)
            o[k] = wy0 * (w0 * a[k] + w1 * b[k]) + wy1 * (w0 * d[k] + w1 * e[k]);
    }
}

/* out[e] = sum_t w[t] * in[t * stride + e] for e in [0, n), accumulated in t
 * order from 0.0f. */
static void weighted_sum(const float *in, size_t stride, int count, const float *w, float *out,
                         size_t n)
{
    size_t e = 0;
    for (; e + 32 <= n; e += 32) {
        __m256 a0 = _mm256_setzero_ps(), a1 = a0, a2 = a0, a3 = a0;
        for (int t = 0; t < count; t++) {
            const float *p = in + (size_t)t * stride + e;
            __m256 wt = _mm256_set1_ps(w[t]);
            a0 = _mm256_add_ps(a0, _mm256_mul_ps(wt, _mm256_loadu_ps(p)));
            a1 = _mm256_add_ps(a1, _mm256_mul_ps(wt, _mm256_loadu_ps(p + 8)));
            a2 = _mm256_add_ps(a2, _mm256_mul_ps(wt, _mm256_loadu_ps(p + 16)));
            a3 = _mm256_add_ps(a3, _mm256_mul_ps(wt, _mm256_loadu_ps(p + 24)));
        }
        _mm256_storeu_ps(out + e, a0);
        _mm256_storeu_ps(out + e + 8, a1);
        _mm256_storeu_ps(out + e + 16, a2);
        _mm256_storeu_ps(out + e + 24, a3);
    }
    for (; e + 8 <= n; e += 8) {
        __m256 a0 = _mm256_setzero_ps();
        for (int t = 0; t < count; t++)
            a0 = _mm256_add_ps(a0, _mm256_mul_ps(_mm256_set1_ps(w[t]),
                                                 _mm256_loadu_ps(in + (size_t)t * stride + e)));
        _mm256_storeu_ps(out + e, a0);
    }
    for (; e < n; e++) {
        float acc = 0.0f;
        for (int t = 0; t < count; t++)
            acc += w[t] * in[(size_t)t * stride + e];
        out[e] = acc;
    }
}

void fk__aa_hrow_avx2(const float *in, int c, const int32_t *first, const int32_t *count,
                      const float *wts, int ksize, int wo, float *out)
{
    for (int i = 0; i < wo; i++)
        weighted_sum(in + (size_t)first[i] * c, (size_t)c, count[i], wts + (size_t)i * ksize,
                     out + (size_t)i * c, (size_t)c);
}

void fk__aa_vrow_avx2(const float *in, size_t row_len, int count, const float *wts, float *out)
{
    weighted_sum(in, row_len, count, wts, out, row_len);
}
