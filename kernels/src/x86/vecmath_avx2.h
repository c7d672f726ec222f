/* vecmath_avx2.h - AVX2/FMA vector math shared by the element-wise ops, the
 * GEMM epilogues and attention. Header-only, static inline; every function
 * carries FK_AVX2_FN, so it also inlines into a function of a translation
 * unit built without -mavx2 that has the same target attribute (the tests).
 *
 * Accuracy against the exact value (measured in tests/kernels/test_vecmath.c
 * by dense sweeps against double libm), for results of normal magnitude:
 *   fk__exp_avx2, fk__exp2_avx2  <= 2 ulp (measured 1.0); +Inf above 88.72 / 128
 *   fk__erf_avx2                 absolute error <= 2e-7
 *   fk__erfc_avx2                relative error <= 1e-6
 *   fk__gelu_avx2                x Phi(x), exact-erf GELU: relative error
 *                                <= 1e-6, negative tail included
 *                                (gelu(-10) = -7.62e-23)
 *   fk__sigmoid_avx2             relative error <= 5e-7
 *   fk__silu_avx2                relative error <= 5e-7
 * Results below FLT_MIN (2^-126) come out as 0, or as a subnormal in a narrow
 * window just below FLT_MIN: see fk__scale2n_avx2 for why.
 * Special values: NaN in gives NaN out everywhere. exp(+Inf) = +Inf,
 * exp(-Inf) = 0, erf(+-Inf) = +-1, gelu and silu return their limits at
 * +-Inf (+Inf and -0), sigmoid(+-Inf) = 1 and 0.
 *
 * NaN and clamping: _mm256_min_ps / _mm256_max_ps return their SECOND operand
 * when either is NaN, so every clamp below puts the value second.
 *
 * fk__hmax_avx2 may drop NaN lanes: use it where a NaN shows up later anyway,
 * as in softmax, where exp(NaN - max) is NaN. */
#ifndef FK_VECMATH_AVX2_H
#define FK_VECMATH_AVX2_H

#include <immintrin.h>

#define FK_AVX2_FN __attribute__((target("avx2,fma,f16c"))) static inline

/* p 2^n for integral n in [-252, 254], as p * 2^(n/2) * 2^(n - n/2) so both
 * factors are normal: results overflow to Inf, and where n < kmin the result
 * is 0. Producing a subnormal costs a microcode assist of ~100 cycles per
 * instruction on x86 (and softmax / attention feed these functions logits far
 * below the row max all the time), so callers pick kmin such that everything
 * flushed is below FLT_MIN anyway: kmin = -126 with p in [0.7, 1.42] flushes
 * only results < 2^-126 and leaves subnormal results only for n = -126. */
FK_AVX2_FN __m256 fk__scale2n_avx2(__m256 p, __m256 n, int kmin)
{
    __m256i k = _mm256_cvtps_epi32(n);
    __m256i k1 = _mm256_srai_epi32(k, 1);
    __m256i k2 = _mm256_sub_epi32(k, k1);
    const __m256i bias = _mm256_set1_epi32(127);
    __m256 s1 = _mm256_castsi256_ps(_mm256_slli_epi32(_mm256_add_epi32(k1, bias), 23));
    __m256 s2 = _mm256_castsi256_ps(_mm256_slli_epi32(_mm256_add_epi32(k2, bias), 23));
    __m256i low = _mm256_cmpgt_epi32(_mm256_set1_epi32(kmin), k);
    s2 = _mm256_andnot_ps(_mm256_castsi256_ps(low), s2);
    return _mm256_mul_ps(_mm256_mul_ps(p, s1), s2);
}

/* The polynomials' coefficients, highest degree first, shared with the zmm
 * copies in vecmath_avx512.h (which must give these functions' bits). */
static const float fk__exp2_softmax_c[7] = { 1.5403530393e-4f, 1.3333558146e-3f, 9.6181291076e-3f,
                                             5.5504108665e-2f, 2.4022650696e-1f, 6.9314718056e-1f,
                                             1.0f };
static const float fk__exp_core_c[6] = { 1.9875691500e-4f, 1.3981999507e-3f, 8.3334519073e-3f,
                                         4.1665795894e-2f, 1.6666665459e-1f, 5.0000001201e-1f };
static const float fk__erf_small_c[5] = { 4.719082732e-03f, -2.675773203e-02f, 1.128283143e-01f,
                                          -3.761260808e-01f, 1.128379107e+00f };
static const float fk__erfc_tail_c[10] = { 1.509543217e-04f, 6.107941590e-05f, -9.750566678e-04f,
                                           -8.517430979e-04f, 6.996694952e-03f, 3.733400023e-03f,
                                           -7.897856086e-02f, 2.416581810e-01f, -4.271858335e-01f,
                                           2.553956807e-01f };

/* e^r for |r| <= ln2/2 (Cephes expf minimax polynomial, ~1 ulp). */
FK_AVX2_FN __m256 fk__exp_core_avx2(__m256 r)
{
    __m256 p = _mm256_set1_ps(fk__exp_core_c[0]);
    for (int i = 1; i < 6; i++)
        p = _mm256_fmadd_ps(p, r, _mm256_set1_ps(fk__exp_core_c[i]));
    p = _mm256_fmadd_ps(p, _mm256_mul_ps(r, r), r);
    return _mm256_add_ps(p, _mm256_set1_ps(1.0f));   /* exp(0) == 1 exactly */
}

/* e^x = p * 2^n with p in [0.7, 1.42]: callers that multiply the result by
 * something scale p first, so a result near the subnormal range is rounded
 * once, at the end (see fk__erfc_tail_avx2 and fk__silu_avx2). */
FK_AVX2_FN __m256 fk__exp_split_avx2(__m256 x, __m256 *n)
{
    /* e^89 overflows and even 1e38 e^-170 is below 2^-150: clamping there
     * keeps n inside fk__scale2n_avx2's range and changes no result, also
     * not of a product m p 2^n with |m| < 1e38. */
    x = _mm256_min_ps(_mm256_set1_ps(89.0f), _mm256_max_ps(_mm256_set1_ps(-170.0f), x));
    *n = _mm256_round_ps(_mm256_mul_ps(x, _mm256_set1_ps(1.44269502e+0f)),
                         _MM_FROUND_TO_NEAREST_INT | _MM_FROUND_NO_EXC);
    __m256 r = _mm256_fnmadd_ps(*n, _mm256_set1_ps(6.93147182e-1f), x);   /* ln2 hi */
    r = _mm256_fnmadd_ps(*n, _mm256_set1_ps(-1.90465432e-9f), r);         /* ln2 lo */
    return fk__exp_core_avx2(r);
}

/* Natural exponential. */
FK_AVX2_FN __m256 fk__exp_avx2(__m256 x)
{
    __m256 n;
    __m256 p = fk__exp_split_avx2(x, &n);
    return fk__scale2n_avx2(p, n, -126);
}

/* 2^x. */
FK_AVX2_FN __m256 fk__exp2_avx2(__m256 x)
{
    x = _mm256_min_ps(_mm256_set1_ps(129.0f), _mm256_max_ps(_mm256_set1_ps(-151.0f), x));
    __m256 n = _mm256_round_ps(x, _MM_FROUND_TO_NEAREST_INT | _MM_FROUND_NO_EXC);
    __m256 f = _mm256_sub_ps(x, n);                                      /* exact */
    __m256 r = _mm256_fmadd_ps(f, _mm256_set1_ps(6.93147182e-1f),
                               _mm256_mul_ps(f, _mm256_set1_ps(-1.90465432e-9f)));
    return fk__scale2n_avx2(fk__exp_core_avx2(r), n, -126);
}

/* erf(a) / a as a polynomial in a^2, for |a| <= 0.5 (relative error 1.4e-9). */
FK_AVX2_FN __m256 fk__erf_small_avx2(__m256 a2)
{
    __m256 p = _mm256_set1_ps(fk__erf_small_c[0]);
    for (int i = 1; i < 5; i++)
        p = _mm256_fmadd_ps(p, a2, _mm256_set1_ps(fk__erf_small_c[i]));
    return p;
}

/* m erfc(a) for a >= 0.5 with relative accuracy, given a^2 = s + t as an
 * unevaluated sum (s rounded, t its rounding error: without t, exp(-a^2)
 * would lose a^2 * 2^-24 relative, 3e-6 at a = 7). The factor m goes in
 * before the final scaling by 2^n, so a product near FLT_MIN is rounded once.
 * erfc(a) = exp(-a^2) R(a), R(a) = exp(a^2) erfc(a) a polynomial in
 * q = (a - 2) / (a + 2) fitted on a in [0.5, 10.1] (relative error 6e-9).
 * Beyond a = 10.1, exp(-s) is 0 and so is the result. */
FK_AVX2_FN __m256 fk__erfc_tail_avx2(__m256 a, __m256 s, __m256 t, __m256 m)
{
    const __m256 two = _mm256_set1_ps(2.0f);
    a = _mm256_min_ps(_mm256_set1_ps(10.1f), a);
    __m256 q = _mm256_div_ps(_mm256_sub_ps(a, two), _mm256_add_ps(a, two));
    __m256 p = _mm256_set1_ps(fk__erfc_tail_c[0]);
    for (int i = 1; i < 10; i++)
        p = _mm256_fmadd_ps(p, q, _mm256_set1_ps(fk__erfc_tail_c[i]));
    __m256 n;
    __m256 e = fk__exp_split_avx2(_mm256_sub_ps(_mm256_setzero_ps(), s), &n);
    __m256 r = _mm256_mul_ps(m, p);
    r = _mm256_fnmadd_ps(r, t, r);             /* exp(-s - t) = exp(-s) (1 - t) */
    return fk__scale2n_avx2(_mm256_mul_ps(r, e), n, -126);
}

FK_AVX2_FN __m256 fk__abs_avx2(__m256 x)
{
    return _mm256_andnot_ps(_mm256_set1_ps(-0.0f), x);
}

/* |x| clamped to c (NaN stays NaN), with its square as s + t. */
FK_AVX2_FN __m256 fk__abs_sq_avx2(__m256 x, float c, __m256 *s, __m256 *t)
{
    __m256 a = _mm256_min_ps(_mm256_set1_ps(c), fk__abs_avx2(x));
    *s = _mm256_mul_ps(a, a);
    *t = _mm256_fmsub_ps(a, a, *s);
    return a;
}

FK_AVX2_FN __m256 fk__erf_avx2(__m256 x)
{
    __m256 s, t;
    __m256 a = fk__abs_sq_avx2(x, 12.0f, &s, &t);   /* erf(12) == 1 in float */
    __m256 small = _mm256_mul_ps(x, fk__erf_small_avx2(_mm256_mul_ps(x, x)));
    __m256 big = _mm256_sub_ps(_mm256_set1_ps(1.0f), fk__erfc_tail_avx2(a, s, t, _mm256_set1_ps(1.0f)));
    big = _mm256_or_ps(big, _mm256_and_ps(x, _mm256_set1_ps(-0.0f)));   /* sign of x */
    return _mm256_blendv_ps(big, small, _mm256_cmp_ps(a, _mm256_set1_ps(0.5f), _CMP_LT_OQ));
}

FK_AVX2_FN __m256 fk__erfc_avx2(__m256 x)
{
    __m256 s, t;
    __m256 a = fk__abs_sq_avx2(x, 12.0f, &s, &t);
    __m256 small = _mm256_fnmadd_ps(x, fk__erf_small_avx2(_mm256_mul_ps(x, x)),
                                    _mm256_set1_ps(1.0f));
    __m256 tail = fk__erfc_tail_avx2(a, s, t, _mm256_set1_ps(1.0f));
    __m256 neg = _mm256_cmp_ps(x, _mm256_setzero_ps(), _CMP_LT_OQ);
    tail = _mm256_blendv_ps(tail, _mm256_sub_ps(_mm256_set1_ps(2.0f), tail), neg);
    return _mm256_blendv_ps(tail, small, _mm256_cmp_ps(a, _mm256_set1_ps(0.5f), _CMP_LT_OQ));
}

/* Exact-erf GELU, x Phi(x) = 0.5 x (1 + erf(x / sqrt 2)) = 0.5 x erfc(-x / sqrt 2).
 * For |x| >= 0.5 sqrt 2 it goes through erfc(|x| / sqrt 2), with x^2 / 2 taken
 * from x directly (not from the rounded x / sqrt 2), so the negative tail keeps
 * its relative accuracy. */
FK_AVX2_FN __m256 fk__gelu_avx2(__m256 x)
{
    const __m256 half = _mm256_set1_ps(0.5f);
    /* gelu(-17) and 1 - gelu(17)/17 vanish in float: the clamp changes
     * nothing but keeps Inf out of x^2 (Inf - Inf) */
    __m256 xc = _mm256_min_ps(_mm256_set1_ps(17.0f), _mm256_max_ps(_mm256_set1_ps(-17.0f), x));
    __m256 h = _mm256_mul_ps(xc, xc);
    __m256 s = _mm256_mul_ps(h, half);
    __m256 t = _mm256_mul_ps(_mm256_fmsub_ps(xc, xc, h), half);
    __m256 u = _mm256_mul_ps(xc, _mm256_set1_ps(7.071067691e-01f));
    __m256 a = fk__abs_avx2(u);
    __m256 hx = _mm256_mul_ps(half, xc);
    __m256 neg = _mm256_cmp_ps(x, _mm256_setzero_ps(), _CMP_LT_OQ);
    /* x < 0: 0.5 x erfc(|x| / sqrt 2) directly; x >= 0: x (1 - 0.5 erfc) */
    __m256 m = _mm256_blendv_ps(_mm256_set1_ps(-0.5f), hx, neg);
    __m256 c = fk__erfc_tail_avx2(a, s, t, m);
    __m256 big = _mm256_blendv_ps(_mm256_mul_ps(x, _mm256_add_ps(_mm256_set1_ps(1.0f), c)), c, neg);
    __m256 small = _mm256_fmadd_ps(hx, _mm256_mul_ps(u, fk__erf_small_avx2(_mm256_mul_ps(u, u))), hx);
    return _mm256_blendv_ps(big, small, _mm256_cmp_ps(a, half, _CMP_LT_OQ));
}

/* 1 / (1 + e^-x) from e = e^-|x| in (0, 1]: 1/(1+e) for x >= 0, e/(1+e) below,
 * so both tails keep their relative accuracy. */
FK_AVX2_FN __m256 fk__sigmoid_avx2(__m256 x)
{
    __m256 e = fk__exp_avx2(_mm256_or_ps(x, _mm256_set1_ps(-0.0f)));   /* -|x| */
    __m256 r = _mm256_div_ps(_mm256_set1_ps(1.0f), _mm256_add_ps(_mm256_set1_ps(1.0f), e));
    __m256 neg = _mm256_cmp_ps(x, _mm256_setzero_ps(), _CMP_LT_OQ);
    return _mm256_blendv_ps(r, _mm256_mul_ps(e, r), neg);
}

/* x sigmoid(x): x / (1 + e) for x >= 0 and x e / (1 + e) below, with x e
 * scaled by 2^n in one step (|x| p <= 241 < 2^8, hence kmin = -133: what is
 * flushed is below FLT_MIN, what is kept is rounded once). x is clamped below
 * at -170 first, where the result is -0 anyway, so silu(-Inf) is -0, not
 * -Inf * 0. */
FK_AVX2_FN __m256 fk__silu_avx2(__m256 x)
{
    x = _mm256_max_ps(_mm256_set1_ps(-170.0f), x);
    __m256 n;
    __m256 p = fk__exp_split_avx2(_mm256_or_ps(x, _mm256_set1_ps(-0.0f)), &n);
    __m256 e = fk__scale2n_avx2(p, n, -126);
    __m256 r = _mm256_div_ps(_mm256_set1_ps(1.0f), _mm256_add_ps(_mm256_set1_ps(1.0f), e));
    __m256 neg = _mm256_cmp_ps(x, _mm256_setzero_ps(), _CMP_LT_OQ);
    __m256 num = _mm256_blendv_ps(x, fk__scale2n_avx2(_mm256_mul_ps(x, p), n, -133), neg);
    return _mm256_mul_ps(num, r);
}

/* 2^x for the softmax, where x = s - max <= 0: results below 2^-126 only
 * need to be tiny, not exact (they are added to a sum >= 1), so inputs are
 * clamped at -127 and the scale is a plain exponent add. NaN stays NaN.
 * p(f) ~ 2^f on [-0.5, 0.5]: the n coefficients c, highest degree first. */
FK_AVX2_FN __m256 fk__exp2_poly_avx2(__m256 x, const float *c, int n)
{
    x = _mm256_max_ps(_mm256_set1_ps(-127.0f), x);
    __m256 k = _mm256_round_ps(x, _MM_FROUND_TO_NEAREST_INT | _MM_FROUND_NO_EXC);
    __m256 f = _mm256_sub_ps(x, k); /* [-0.5, 0.5] */
    __m256 p = _mm256_set1_ps(c[0]);
    for (int i = 1; i < n; i++)
        p = _mm256_fmadd_ps(p, f, _mm256_set1_ps(c[i]));
    __m256i e = _mm256_slli_epi32(_mm256_add_epi32(_mm256_cvtps_epi32(k), _mm256_set1_epi32(127)), 23);
    return _mm256_mul_ps(p, _mm256_castsi256_ps(e));
}

/* The fp32 softmax's: degree-6 Taylor polynomial (fk__exp2_softmax_c),
 * relative error <= 1e-7 above 2^-126. */
FK_AVX2_FN __m256 fk__exp2_softmax_avx2(__m256 x)
{
    return fk__exp2_poly_avx2(x, fk__exp2_softmax_c, 7);
}

/* The int16 softmax's weights, which are rounded to 12-bit codes (p 4096
 * <= 4096): a degree-4 polynomial whose constant term is 1 (powers of two
 * stay exact), relative error <= 3.7e-6, under 0.016 of a code; two fewer
 * FMAs per vector. Coefficients: a Remez fit of 2^f on [-0.5, 0.5]
 * (relative error). */
static const float fk__exp2_codes_c[5] = { 9.7829122096e-03f, 5.5976882577e-02f, 2.4020710588e-01f,
                                           6.9311362505e-01f, 1.0f };
FK_AVX2_FN __m256 fk__exp2_codes_avx2(__m256 x)
{
    return fk__exp2_poly_avx2(x, fk__exp2_codes_c, 5);
}

/* The six rows' maxima at once: lane r of the result is max(v[r]) for r <
 * 6 (exact in any order; NaN may be dropped, as by fk__hmax_avx2), lanes 6
 * and 7 unspecified. A transposed tree instead of six serial reductions. */
FK_AVX2_FN __m256 fk__hmax6_avx2(const __m256 *v)
{
    /* per 128-bit half: rows 2k, 2k+1 interleaved */
    __m256 a01 = _mm256_max_ps(_mm256_unpacklo_ps(v[0], v[1]), _mm256_unpackhi_ps(v[0], v[1]));
    __m256 a23 = _mm256_max_ps(_mm256_unpacklo_ps(v[2], v[3]), _mm256_unpackhi_ps(v[2], v[3]));
    __m256 a45 = _mm256_max_ps(_mm256_unpacklo_ps(v[4], v[5]), _mm256_unpackhi_ps(v[4], v[5]));
    /* per half: rows 0 1 2 3, and rows 4 5 4 5 */
    __m256 b = _mm256_max_ps(_mm256_shuffle_ps(a01, a23, _MM_SHUFFLE(1, 0, 1, 0)),
                             _mm256_shuffle_ps(a01, a23, _MM_SHUFFLE(3, 2, 3, 2)));
    __m256 c = _mm256_max_ps(_mm256_shuffle_ps(a45, a45, _MM_SHUFFLE(1, 0, 1, 0)),
                             _mm256_shuffle_ps(a45, a45, _MM_SHUFFLE(3, 2, 3, 2)));
    return _mm256_max_ps(_mm256_permute2f128_ps(b, c, 0x20), _mm256_permute2f128_ps(b, c, 0x31));
}

FK_AVX2_FN float fk__hsum_avx2(__m256 v)
{
    __m128 s = _mm_add_ps(_mm256_castps256_ps128(v), _mm256_extractf128_ps(v, 1));
    s = _mm_add_ps(s, _mm_movehl_ps(s, s));
    s = _mm_add_ss(s, _mm_movehdup_ps(s));
    return _mm_cvtss_f32(s);
}

/* fk__hsum_avx2 of six vectors at once: lane r of the result is the sum of
 * s[r] added as fk__hsum_avx2 adds it (the halves, then lanes 0+2 and 1+3,
 * then those two), so the same bits; lanes 6 and 7 unspecified. */
FK_AVX2_FN __m256 fk__hsum6_avx2(const __m256 *s)
{
    __m128 x[3];
    for (int k = 0; k < 3; k++) {
        __m256 a = s[2 * k], b = s[2 * k + 1];
        __m256 t = _mm256_add_ps(_mm256_permute2f128_ps(a, b, 0x20), _mm256_permute2f128_ps(a, b, 0x31));
        t = _mm256_add_ps(t, _mm256_permute_ps(t, _MM_SHUFFLE(3, 2, 3, 2)));
        t = _mm256_add_ps(t, _mm256_movehdup_ps(t)); /* s[2k] in lane 0, s[2k+1] in lane 4 */
        x[k] = _mm_unpacklo_ps(_mm256_castps256_ps128(t), _mm256_extractf128_ps(t, 1));
    }
    return _mm256_set_m128(x[2], _mm_movelh_ps(x[0], x[1]));
}

FK_AVX2_FN float fk__hmax_avx2(__m256 v)
{
    __m128 m = _mm_max_ps(_mm256_castps256_ps128(v), _mm256_extractf128_ps(v, 1));
    m = _mm_max_ps(m, _mm_movehl_ps(m, m));
    m = _mm_max_ss(m, _mm_movehdup_ps(m));
    return _mm_cvtss_f32(m);
}

/* Lane mask of the first n lanes (0 <= n <= 8), for _mm256_maskload_ps /
 * _mm256_maskstore_ps of the tail of a row. */
FK_AVX2_FN __m256i fk__tail_mask_avx2(int n)
{
    const __m256i idx = _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7);
    return _mm256_cmpgt_epi32(_mm256_set1_epi32(n), idx);
}

#endif /* FK_VECMATH_AVX2_H */
