/* vecmath_avx512.h - zmm math shared by the AVX-512 attention files
 * (attention_avx512.c, attention_bf16_avx512.c) and the AVX-512 GEMM
 * epilogues (gemm_avx512.c). The GELU / SiLU here are vecmath_avx2.h's,
 * operation for operation, 16 lanes wide (blendv -> mask blend, the integer
 * compare -> a mask): the same bits, half the instructions (an f32 GEMM with
 * a GELU epilogue, the MLP's fc1, spent ~7 % of its time in the ymm GELU).
 * Functions carry FK_AVX512_FN (AVX-512 F only: no DQ float logic), so a
 * test built without AVX-512 flags can call them where the CPU has it. */
#ifndef FK_VECMATH_AVX512_H
#define FK_VECMATH_AVX512_H

#include <immintrin.h>

#include "vecmath_avx2.h" /* the coefficients */

#define FK_AVX512_FN __attribute__((target("avx512f,fma"))) static inline

/* fk__exp2_poly_avx2: 2^x for x = s - max <= 0 (same clamp at -127, same
 * polynomial on [-0.5, 0.5], exponent add; NaN stays NaN), so both give the
 * same bits. */
FK_AVX512_FN __m512 fk__exp2_poly512(__m512 x, const float *c, int nc)
{
    x = _mm512_max_ps(_mm512_set1_ps(-127.0f), x);
    __m512 n = _mm512_roundscale_ps(x, _MM_FROUND_TO_NEAREST_INT | _MM_FROUND_NO_EXC);
    __m512 f = _mm512_sub_ps(x, n);
    __m512 p = _mm512_set1_ps(c[0]);
    for (int i = 1; i < nc; i++)
        p = _mm512_fmadd_ps(p, f, _mm512_set1_ps(c[i]));
    __m512i e = _mm512_slli_epi32(_mm512_add_epi32(_mm512_cvtps_epi32(n), _mm512_set1_epi32(127)), 23);
    return _mm512_mul_ps(p, _mm512_castsi512_ps(e));
}

/* the fp32 softmax's 2^x (fk__exp2_softmax_avx2) */
FK_AVX512_FN __m512 fk__exp2_softmax512(__m512 x) { return fk__exp2_poly512(x, fk__exp2_softmax_c, 7); }

/* the int16 softmax's (fk__exp2_codes_avx2) */
FK_AVX512_FN __m512 fk__exp2_codes512(__m512 x) { return fk__exp2_poly512(x, fk__exp2_codes_c, 5); }

/* fk__scale2n_avx2: p 2^n in two normal factors, 0 where n < kmin. */
FK_AVX512_FN __m512 fk__scale2n512(__m512 p, __m512 n, int kmin)
{
    __m512i k = _mm512_cvtps_epi32(n);
    __m512i k1 = _mm512_srai_epi32(k, 1);
    __m512i k2 = _mm512_sub_epi32(k, k1);
    const __m512i bias = _mm512_set1_epi32(127);
    __m512 s1 = _mm512_castsi512_ps(_mm512_slli_epi32(_mm512_add_epi32(k1, bias), 23));
    __m512 s2 = _mm512_castsi512_ps(_mm512_slli_epi32(_mm512_add_epi32(k2, bias), 23));
    __mmask16 low = _mm512_cmpgt_epi32_mask(_mm512_set1_epi32(kmin), k);
    s2 = _mm512_maskz_mov_ps((__mmask16)~low, s2);
    return _mm512_mul_ps(_mm512_mul_ps(p, s1), s2);
}

/* fk__exp_core_avx2: e^r for |r| <= ln2/2. */
FK_AVX512_FN __m512 fk__exp_core512(__m512 r)
{
    __m512 p = _mm512_set1_ps(fk__exp_core_c[0]);
    for (int i = 1; i < 6; i++)
        p = _mm512_fmadd_ps(p, r, _mm512_set1_ps(fk__exp_core_c[i]));
    p = _mm512_fmadd_ps(p, _mm512_mul_ps(r, r), r);
    return _mm512_add_ps(p, _mm512_set1_ps(1.0f));
}

/* fk__exp_split_avx2: e^x = p 2^n. */
FK_AVX512_FN __m512 fk__exp_split512(__m512 x, __m512 *n)
{
    x = _mm512_min_ps(_mm512_set1_ps(89.0f), _mm512_max_ps(_mm512_set1_ps(-170.0f), x));
    *n = _mm512_roundscale_ps(_mm512_mul_ps(x, _mm512_set1_ps(1.44269502e+0f)),
                              _MM_FROUND_TO_NEAREST_INT | _MM_FROUND_NO_EXC);
    __m512 r = _mm512_fnmadd_ps(*n, _mm512_set1_ps(6.93147182e-1f), x);
    r = _mm512_fnmadd_ps(*n, _mm512_set1_ps(-1.90465432e-9f), r);
    return fk__exp_core512(r);
}

/* fk__erf_small_avx2: erf(a) / a in a^2, |a| <= 0.5. */
FK_AVX512_FN __m512 fk__erf_small512(__m512 a2)
{
    __m512 p = _mm512_set1_ps(fk__erf_small_c[0]);
    for (int i = 1; i < 5; i++)
        p = _mm512_fmadd_ps(p, a2, _mm512_set1_ps(fk__erf_small_c[i]));
    return p;
}

/* fk__erfc_tail_avx2: m erfc(a), a >= 0.5, a^2 = s + t. */
FK_AVX512_FN __m512 fk__erfc_tail512(__m512 a, __m512 s, __m512 t, __m512 m)
{
    const __m512 two = _mm512_set1_ps(2.0f);
    a = _mm512_min_ps(_mm512_set1_ps(10.1f), a);
    __m512 q = _mm512_div_ps(_mm512_sub_ps(a, two), _mm512_add_ps(a, two));
    __m512 p = _mm512_set1_ps(fk__erfc_tail_c[0]);
    for (int i = 1; i < 10; i++)
        p = _mm512_fmadd_ps(p, q, _mm512_set1_ps(fk__erfc_tail_c[i]));
    __m512 n;
    __m512 e = fk__exp_split512(_mm512_sub_ps(_mm512_setzero_ps(), s), &n);
    __m512 r = _mm512_mul_ps(m, p);
    r = _mm512_fnmadd_ps(r, t, r);
    return fk__scale2n512(_mm512_mul_ps(r, e), n, -126);
}

/* fk__gelu_avx2: exact-erf GELU. */
FK_AVX512_FN __m512 fk__gelu512(__m512 x)
{
    const __m512 half = _mm512_set1_ps(0.5f);
    __m512 xc = _mm512_min_ps(_mm512_set1_ps(17.0f), _mm512_max_ps(_mm512_set1_ps(-17.0f), x));
    __m512 h = _mm512_mul_ps(xc, xc);
    __m512 s = _mm512_mul_ps(h, half);
    __m512 t = _mm512_mul_ps(_mm512_fmsub_ps(xc, xc, h), half);
    __m512 u = _mm512_mul_ps(xc, _mm512_set1_ps(7.071067691e-01f));
    __m512 a = _mm512_castsi512_ps(_mm512_and_si512(_mm512_castps_si512(u), _mm512_set1_epi32(0x7fffffff)));
    __m512 hx = _mm512_mul_ps(half, xc);
    __mmask16 neg = _mm512_cmp_ps_mask(x, _mm512_setzero_ps(), _CMP_LT_OQ);
    __m512 m = _mm512_mask_blend_ps(neg, _mm512_set1_ps(-0.5f), hx);
    __m512 c = fk__erfc_tail512(a, s, t, m);
    __m512 big = _mm512_mask_blend_ps(neg, _mm512_mul_ps(x, _mm512_add_ps(_mm512_set1_ps(1.0f), c)), c);
    __m512 small = _mm512_fmadd_ps(hx, _mm512_mul_ps(u, fk__erf_small512(_mm512_mul_ps(u, u))), hx);
    return _mm512_mask_blend_ps(_mm512_cmp_ps_mask(a, half, _CMP_LT_OQ), big, small);
}

/* fk__silu_avx2: x sigmoid(x). */
FK_AVX512_FN __m512 fk__silu512(__m512 x)
{
    x = _mm512_max_ps(_mm512_set1_ps(-170.0f), x);
    __m512 n;
    __m512 p = fk__exp_split512(_mm512_castsi512_ps(_mm512_or_si512(_mm512_castps_si512(x), _mm512_set1_epi32((int)0x80000000u))), &n); /* -|x| */
    __m512 e = fk__scale2n512(p, n, -126);
    __m512 r = _mm512_div_ps(_mm512_set1_ps(1.0f), _mm512_add_ps(_mm512_set1_ps(1.0f), e));
    __mmask16 neg = _mm512_cmp_ps_mask(x, _mm512_setzero_ps(), _CMP_LT_OQ);
    __m512 num = _mm512_mask_blend_ps(neg, x, fk__scale2n512(_mm512_mul_ps(x, p), n, -133));
    return _mm512_mul_ps(num, r);
}

#endif
