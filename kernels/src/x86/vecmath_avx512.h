/* vecmath_avx512.h - zmm math shared by the AVX-512 attention files
 * (attention_avx512.c, attention_bf16_avx512.c), for files built with
 * AVX-512 F. */
#ifndef FK_VECMATH_AVX512_H
#define FK_VECMATH_AVX512_H

#include <immintrin.h>

/* 2^x for x = s - max <= 0, as the AVX2 piece (same clamp at -127, same
 * degree-6 polynomial on [-0.5, 0.5], exponent add; NaN stays NaN), so
 * both give the same bits. */
static inline __m512 fk__exp2_softmax512(__m512 x)
{
    x = _mm512_max_ps(_mm512_set1_ps(-127.0f), x);
    __m512 n = _mm512_roundscale_ps(x, _MM_FROUND_TO_NEAREST_INT | _MM_FROUND_NO_EXC);
    __m512 f = _mm512_sub_ps(x, n);
    __m512 p = _mm512_set1_ps(1.5403530393e-4f);
    p = _mm512_fmadd_ps(p, f, _mm512_set1_ps(1.3333558146e-3f));
    p = _mm512_fmadd_ps(p, f, _mm512_set1_ps(9.6181291076e-3f));
    p = _mm512_fmadd_ps(p, f, _mm512_set1_ps(5.5504108665e-2f));
    p = _mm512_fmadd_ps(p, f, _mm512_set1_ps(2.4022650696e-1f));
    p = _mm512_fmadd_ps(p, f, _mm512_set1_ps(6.9314718056e-1f));
    p = _mm512_fmadd_ps(p, f, _mm512_set1_ps(1.0f));
    __m512i e = _mm512_slli_epi32(_mm512_add_epi32(_mm512_cvtps_epi32(n), _mm512_set1_epi32(127)), 23);
    return _mm512_mul_ps(p, _mm512_castsi512_ps(e));
}

#endif
