/* vecmath_neon.h - AArch64 NEON vector math shared by the element-wise ops,
 * the GEMM epilogues and attention: the operations of x86/vecmath_avx2.h
 * (same polynomials, same range reductions, same special-value handling), four
 * lanes at a time. Header-only, static inline.
 *
 * Accuracy as for the AVX2 versions (see vecmath_avx2.h), held to the same
 * budgets by tests/kernels/test_vecmath.c: exp, exp2 <= 2 ulp; erf absolute
 * 2e-7; erfc and GELU relative 1e-6 (negative tail included); sigmoid and
 * SiLU relative 5e-7; results below FLT_MIN may flush to 0.
 * NaN in gives NaN out: FMIN / FMAX return NaN when either operand is NaN,
 * so every clamp keeps NaN (as the AVX2 code's operand order does). */
#ifndef FK_VECMATH_NEON_H
#define FK_VECMATH_NEON_H

#include <arm_neon.h>

#define FK_NEON_FN static inline

/* p 2^n for integral n, as p * 2^(n/2) * 2^(n - n/2); n < kmin gives 0. */
FK_NEON_FN float32x4_t fk__scale2n_neon(float32x4_t p, float32x4_t n, int kmin)
{
    int32x4_t k = vcvtnq_s32_f32(n);
    int32x4_t k1 = vshrq_n_s32(k, 1);
    int32x4_t k2 = vsubq_s32(k, k1);
    const int32x4_t bias = vdupq_n_s32(127);
    float32x4_t s1 = vreinterpretq_f32_s32(vshlq_n_s32(vaddq_s32(k1, bias), 23));
    float32x4_t s2 = vreinterpretq_f32_s32(vshlq_n_s32(vaddq_s32(k2, bias), 23));
    uint32x4_t low = vcltq_s32(k, vdupq_n_s32(kmin));
    s2 = vreinterpretq_f32_u32(vbicq_u32(vreinterpretq_u32_f32(s2), low));
    return vmulq_f32(vmulq_f32(p, s1), s2);
}

/* e^r for |r| <= ln2/2 (Cephes expf polynomial). */
FK_NEON_FN float32x4_t fk__exp_core_neon(float32x4_t r)
{
    float32x4_t p = vdupq_n_f32(1.9875691500e-4f);
    p = vfmaq_f32(vdupq_n_f32(1.3981999507e-3f), p, r);
    p = vfmaq_f32(vdupq_n_f32(8.3334519073e-3f), p, r);
    p = vfmaq_f32(vdupq_n_f32(4.1665795894e-2f), p, r);
    p = vfmaq_f32(vdupq_n_f32(1.6666665459e-1f), p, r);
    p = vfmaq_f32(vdupq_n_f32(5.0000001201e-1f), p, r);
    p = vfmaq_f32(r, p, vmulq_f32(r, r));
    return vaddq_f32(p, vdupq_n_f32(1.0f));
}

/* e^x = p 2^n with p in [0.7, 1.42]. */
FK_NEON_FN float32x4_t fk__exp_split_neon(float32x4_t x, float32x4_t *n)
{
    x = vminq_f32(vdupq_n_f32(89.0f), vmaxq_f32(vdupq_n_f32(-170.0f), x));
    *n = vrndnq_f32(vmulq_f32(x, vdupq_n_f32(1.44269502e+0f)));
    float32x4_t r = vfmsq_f32(x, *n, vdupq_n_f32(6.93147182e-1f));
    r = vfmsq_f32(r, *n, vdupq_n_f32(-1.90465432e-9f));
    return fk__exp_core_neon(r);
}

FK_NEON_FN float32x4_t fk__exp_neon(float32x4_t x)
{
    float32x4_t n;
    float32x4_t p = fk__exp_split_neon(x, &n);
    return fk__scale2n_neon(p, n, -126);
}

/* 2^x. */
FK_NEON_FN float32x4_t fk__exp2_neon(float32x4_t x)
{
    x = vminq_f32(vdupq_n_f32(129.0f), vmaxq_f32(vdupq_n_f32(-151.0f), x));
    float32x4_t n = vrndnq_f32(x);
    float32x4_t f = vsubq_f32(x, n);                                     /* exact */
    float32x4_t r = vfmaq_f32(vmulq_f32(f, vdupq_n_f32(-1.90465432e-9f)), f, vdupq_n_f32(6.93147182e-1f));
    return fk__scale2n_neon(fk__exp_core_neon(r), n, -126);
}

/* erf(a) / a as a polynomial in a^2, |a| <= 0.5. */
FK_NEON_FN float32x4_t fk__erf_small_neon(float32x4_t a2)
{
    float32x4_t p = vdupq_n_f32(4.719082732e-03f);
    p = vfmaq_f32(vdupq_n_f32(-2.675773203e-02f), p, a2);
    p = vfmaq_f32(vdupq_n_f32(1.128283143e-01f), p, a2);
    p = vfmaq_f32(vdupq_n_f32(-3.761260808e-01f), p, a2);
    return vfmaq_f32(vdupq_n_f32(1.128379107e+00f), p, a2);
}

/* m erfc(a) for a >= 0.5, a^2 = s + t (see fk__erfc_tail_avx2). */
FK_NEON_FN float32x4_t fk__erfc_tail_neon(float32x4_t a, float32x4_t s, float32x4_t t, float32x4_t m)
{
    const float32x4_t two = vdupq_n_f32(2.0f);
    a = vminq_f32(vdupq_n_f32(10.1f), a);
    float32x4_t q = vdivq_f32(vsubq_f32(a, two), vaddq_f32(a, two));
    float32x4_t p = vdupq_n_f32(1.509543217e-04f);
    p = vfmaq_f32(vdupq_n_f32(6.107941590e-05f), p, q);
    p = vfmaq_f32(vdupq_n_f32(-9.750566678e-04f), p, q);
    p = vfmaq_f32(vdupq_n_f32(-8.517430979e-04f), p, q);
    p = vfmaq_f32(vdupq_n_f32(6.996694952e-03f), p, q);
    p = vfmaq_f32(vdupq_n_f32(3.733400023e-03f), p, q);
    p = vfmaq_f32(vdupq_n_f32(-7.897856086e-02f), p, q);
    p = vfmaq_f32(vdupq_n_f32(2.416581810e-01f), p, q);
    p = vfmaq_f32(vdupq_n_f32(-4.271858335e-01f), p, q);
    p = vfmaq_f32(vdupq_n_f32(2.553956807e-01f), p, q);
    float32x4_t n;
    float32x4_t e = fk__exp_split_neon(vnegq_f32(s), &n);
    float32x4_t r = vmulq_f32(m, p);
    r = vfmsq_f32(r, r, t);                       /* exp(-s - t) = exp(-s) (1 - t) */
    return fk__scale2n_neon(vmulq_f32(r, e), n, -126);
}

/* |x| clamped to c (NaN stays NaN), with its square as s + t. */
FK_NEON_FN float32x4_t fk__abs_sq_neon(float32x4_t x, float c, float32x4_t *s, float32x4_t *t)
{
    float32x4_t a = vminq_f32(vdupq_n_f32(c), vabsq_f32(x));
    *s = vmulq_f32(a, a);
    *t = vfmaq_f32(vnegq_f32(*s), a, a);
    return a;
}

FK_NEON_FN float32x4_t fk__erf_neon(float32x4_t x)
{
    float32x4_t s, t;
    float32x4_t a = fk__abs_sq_neon(x, 12.0f, &s, &t);   /* erf(12) == 1 in float */
    float32x4_t small = vmulq_f32(x, fk__erf_small_neon(vmulq_f32(x, x)));
    float32x4_t big = vsubq_f32(vdupq_n_f32(1.0f), fk__erfc_tail_neon(a, s, t, vdupq_n_f32(1.0f)));
    big = vreinterpretq_f32_u32(vorrq_u32(vreinterpretq_u32_f32(big),
                                          vandq_u32(vreinterpretq_u32_f32(x), vdupq_n_u32(0x80000000u))));
    return vbslq_f32(vcltq_f32(a, vdupq_n_f32(0.5f)), small, big);
}

FK_NEON_FN float32x4_t fk__erfc_neon(float32x4_t x)
{
    float32x4_t s, t;
    float32x4_t a = fk__abs_sq_neon(x, 12.0f, &s, &t);
    float32x4_t small = vfmsq_f32(vdupq_n_f32(1.0f), x, fk__erf_small_neon(vmulq_f32(x, x)));
    float32x4_t tail = fk__erfc_tail_neon(a, s, t, vdupq_n_f32(1.0f));
    uint32x4_t neg = vcltq_f32(x, vdupq_n_f32(0.0f));
    tail = vbslq_f32(neg, vsubq_f32(vdupq_n_f32(2.0f), tail), tail);
    return vbslq_f32(vcltq_f32(a, vdupq_n_f32(0.5f)), small, tail);
}

/* Exact-erf GELU, x Phi(x) (see fk__gelu_avx2). */
FK_NEON_FN float32x4_t fk__gelu_neon(float32x4_t x)
{
    const float32x4_t half = vdupq_n_f32(0.5f);
    float32x4_t xc = vminq_f32(vdupq_n_f32(17.0f), vmaxq_f32(vdupq_n_f32(-17.0f), x));
    float32x4_t h = vmulq_f32(xc, xc);
    float32x4_t s = vmulq_f32(h, half);
    float32x4_t t = vmulq_f32(vfmaq_f32(vnegq_f32(h), xc, xc), half);   /* rounding error of xc^2 */
    float32x4_t u = vmulq_f32(xc, vdupq_n_f32(7.071067691e-01f));
    float32x4_t a = vabsq_f32(u);
    float32x4_t hx = vmulq_f32(half, xc);
    uint32x4_t neg = vcltq_f32(x, vdupq_n_f32(0.0f));
    float32x4_t m = vbslq_f32(neg, hx, vdupq_n_f32(-0.5f));
    float32x4_t c = fk__erfc_tail_neon(a, s, t, m);
    float32x4_t big = vbslq_f32(neg, c, vmulq_f32(x, vaddq_f32(vdupq_n_f32(1.0f), c)));
    float32x4_t small = vfmaq_f32(hx, hx, vmulq_f32(u, fk__erf_small_neon(vmulq_f32(u, u))));
    return vbslq_f32(vcltq_f32(a, half), small, big);
}

/* 1 / (1 + e^-x) from e = e^-|x|: 1/(1+e) for x >= 0, e/(1+e) below. */
FK_NEON_FN float32x4_t fk__sigmoid_neon(float32x4_t x)
{
    float32x4_t e = fk__exp_neon(vnegq_f32(vabsq_f32(x)));
    float32x4_t r = vdivq_f32(vdupq_n_f32(1.0f), vaddq_f32(vdupq_n_f32(1.0f), e));
    return vbslq_f32(vcltq_f32(x, vdupq_n_f32(0.0f)), vmulq_f32(e, r), r);
}

/* x sigmoid(x) (see fk__silu_avx2). */
FK_NEON_FN float32x4_t fk__silu_neon(float32x4_t x)
{
    x = vmaxq_f32(vdupq_n_f32(-170.0f), x);
    float32x4_t n;
    float32x4_t p = fk__exp_split_neon(vnegq_f32(vabsq_f32(x)), &n);
    float32x4_t e = fk__scale2n_neon(p, n, -126);
    float32x4_t r = vdivq_f32(vdupq_n_f32(1.0f), vaddq_f32(vdupq_n_f32(1.0f), e));
    uint32x4_t neg = vcltq_f32(x, vdupq_n_f32(0.0f));
    float32x4_t num = vbslq_f32(neg, fk__scale2n_neon(vmulq_f32(x, p), n, -133), x);
    return vmulq_f32(num, r);
}

/* x < 0 ? 0 : x: NaN and -0 pass through (as maxps(0, x) on x86; FMAX
 * would turn -0 into +0). */
FK_NEON_FN float32x4_t fk__relu_neon(float32x4_t x)
{
    return vbslq_f32(vcltq_f32(x, vdupq_n_f32(0.0f)), vdupq_n_f32(0.0f), x);
}

FK_NEON_FN float fk__hsum_neon(float32x4_t v) { return vaddvq_f32(v); }
FK_NEON_FN float fk__hmax_neon(float32x4_t v) { return vmaxvq_f32(v); }

#endif /* FK_VECMATH_NEON_H */
