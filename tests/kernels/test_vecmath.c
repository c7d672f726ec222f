/* The vector math of kernels/src/x86/vecmath_avx2.h (AVX2) and
 * kernels/src/arm/vecmath_neon.h (AArch64 NEON) against double libm over dense
 * sweeps of the float line, and at its special values.
 *
 * Error budgets (the header states the same), for exact results of normal
 * magnitude; below FLT_MIN the functions may flush to 0, so there the
 * absolute error must stay below FLT_MIN:
 *   exp, exp2        2 ulp (ulp of the exact result)
 *   erf              absolute 2e-7
 *   erfc             relative 1e-6 where the exact result is a normal float
 *   gelu             relative 1e-6 where the exact result is a normal float
 *   sigmoid, silu    relative 5e-7 */
#include <float.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "test_util.h"

#if defined(__x86_64__) || defined(__aarch64__)
enum vfn { V_EXP, V_EXP2, V_ERF, V_ERFC, V_GELU, V_SIGMOID, V_SILU };

static const char *const vfn_name[] = { "exp", "exp2", "erf", "erfc", "gelu", "sigmoid", "silu" };
#endif

#if defined(__x86_64__)
#include "../../kernels/src/x86/vecmath_avx2.h"

__attribute__((target("avx2,fma,f16c")))
static __m256 vfn_eval(enum vfn f, __m256 x)
{
    switch (f) {
    case V_EXP:     return fk__exp_avx2(x);
    case V_EXP2:    return fk__exp2_avx2(x);
    case V_ERF:     return fk__erf_avx2(x);
    case V_ERFC:    return fk__erfc_avx2(x);
    case V_GELU:    return fk__gelu_avx2(x);
    case V_SIGMOID: return fk__sigmoid_avx2(x);
    case V_SILU:    return fk__silu_avx2(x);
    }
    return x;
}

/* y[i] = f(x[i]); n is a multiple of 8 or the tail goes through a padded copy. */
__attribute__((target("avx2,fma,f16c")))
static void vfn_apply(enum vfn f, const float *x, float *y, size_t n)
{
    size_t i = 0;
    for (; i + 8 <= n; i += 8)
        _mm256_storeu_ps(y + i, vfn_eval(f, _mm256_loadu_ps(x + i)));
    if (i < n) {
        float bx[8] = { 0 }, by[8];
        memcpy(bx, x + i, (n - i) * sizeof *x);
        _mm256_storeu_ps(by, vfn_eval(f, _mm256_loadu_ps(bx)));
        memcpy(y + i, by, (n - i) * sizeof *y);
    }
}

__attribute__((target("avx2,fma,f16c")))
static void horizontal(const float v[8], float *sum, float *max)
{
    __m256 x = _mm256_loadu_ps(v);
    *sum = fk__hsum_avx2(x);
    *max = fk__hmax_avx2(x);
}

static int have_simd(void)
{
    return fk_isa_supported(FK_ISA_AVX2);
}

#elif defined(__aarch64__)
#include "../../kernels/src/arm/vecmath_neon.h"

static float32x4_t vfn_eval(enum vfn f, float32x4_t x)
{
    switch (f) {
    case V_EXP:     return fk__exp_neon(x);
    case V_EXP2:    return fk__exp2_neon(x);
    case V_ERF:     return fk__erf_neon(x);
    case V_ERFC:    return fk__erfc_neon(x);
    case V_GELU:    return fk__gelu_neon(x);
    case V_SIGMOID: return fk__sigmoid_neon(x);
    case V_SILU:    return fk__silu_neon(x);
    }
    return x;
}

static void vfn_apply(enum vfn f, const float *x, float *y, size_t n)
{
    size_t i = 0;
    for (; i + 4 <= n; i += 4)
        vst1q_f32(y + i, vfn_eval(f, vld1q_f32(x + i)));
    if (i < n) {
        float bx[4] = { 0 }, by[4];
        memcpy(bx, x + i, (n - i) * sizeof *x);
        vst1q_f32(by, vfn_eval(f, vld1q_f32(bx)));
        memcpy(y + i, by, (n - i) * sizeof *y);
    }
}

static void horizontal(const float v[8], float *sum, float *max)
{
    float32x4_t a = vld1q_f32(v), b = vld1q_f32(v + 4);
    *sum = fk__hsum_neon(vaddq_f32(a, b));
    *max = fk__hmax_neon(vmaxq_f32(a, b));
}

static int have_simd(void)
{
    return fk_isa_supported(FK_ISA_NEON);
}
#endif

#if defined(__x86_64__) || defined(__aarch64__)
static float vfn1(enum vfn f, float x)
{
    float y;
    vfn_apply(f, &x, &y, 1);
    return y;
}

static double exact(enum vfn f, double x)
{
    switch (f) {
    case V_EXP:     return exp(x);
    case V_EXP2:    return exp2(x);
    case V_ERF:     return erf(x);
    case V_ERFC:    return erfc(x);
    case V_GELU:    return isinf(x) ? (x > 0 ? x : -0.0) : 0.5 * x * erfc(-x * M_SQRT1_2);
    case V_SIGMOID: return 1.0 / (1.0 + exp(-x));
    case V_SILU:    return isinf(x) ? (x > 0 ? x : -0.0) : x / (1.0 + exp(-x));
    }
    return x;
}

static float bits_f32(uint32_t u) { float f; memcpy(&f, &u, 4); return f; }
static uint32_t f32_bits(float f) { uint32_t u; memcpy(&u, &f, 4); return u; }

/* Error of got against the exact value in units of the float ulp at exact. */
static double ulp_error(float got, double ex)
{
    if (isnan(ex) || isnan(got))
        return isnan(ex) && isnan(got) ? 0 : INFINITY;
    if (fabs(ex) > FLT_MAX) /* exact value beyond range: must round to Inf */
        return isinf(got) && (got > 0) == (ex > 0) ? 0 : INFINITY;
    if (isinf(got))
        return INFINITY;
    int e;
    frexp(ex, &e);
    double ulp = ldexp(1.0, e - 24 < -149 ? -149 : e - 24);
    return fabs((double)got - ex) / ulp;
}

struct sweep {
    double max_ulp, max_abs, max_rel, max_abs_tiny;   /* tiny: exact below FLT_MIN */
    float at_ulp, at_abs, at_rel;
};

/* Under an emulator (cross builds run the tests in qemu-user, ~50x slower on
 * this double-precision libm work) the sweeps take every FK_SWEEP_THIN-th
 * point of the native sweep: still 0.9-2 million points per function. */
#ifndef FK_SWEEP_THIN
#define FK_SWEEP_THIN 1
#endif

/* Every `step`-th float bit pattern in [lo, hi] (both signs handled by the
 * caller through lo < 0), plus the end points. */
static void sweep_run(enum vfn f, float lo, float hi, uint32_t step, struct sweep *s)
{
    step *= FK_SWEEP_THIN;
    enum { CHUNK = 4096 };
    float *x = xmalloc(CHUNK * sizeof *x), *y = xmalloc(CHUNK * sizeof *y);
    memset(s, 0, sizeof *s);
    /* walk magnitudes on each side of zero that falls in [lo, hi] */
    for (int side = 0; side < 2; side++) {
        float a = side ? hi : -lo;          /* largest magnitude on this side */
        if (a < 0)
            continue;
        uint32_t top = f32_bits(a);
        uint32_t u = 0;
        int done = 0;
        while (!done) {
            size_t n = 0;
            while (n < CHUNK && !done) {
                float v = bits_f32(u);
                x[n++] = side ? v : -v;
                if (u == top)
                    done = 1;
                else
                    u = top - u > step ? u + step : top;
            }
            vfn_apply(f, x, y, n);
            for (size_t i = 0; i < n; i++) {
                if (x[i] < lo || x[i] > hi)
                    continue;
                double ex = exact(f, x[i]);
                double ae = fabs((double)y[i] - ex);
                int tiny = fabs(ex) < FLT_MIN;
                double ue = tiny ? 0 : ulp_error(y[i], ex);
                double re = tiny ? 0 : ae / fabs(ex);
                if (tiny && ae > s->max_abs_tiny)
                    s->max_abs_tiny = ae;
                if (isnan(y[i]) != isnan(ex))
                    fail_msg("%s(%a) = %a, exact %a", vfn_name[f], x[i], y[i], ex);
                if (ue > s->max_ulp) { s->max_ulp = ue; s->at_ulp = x[i]; }
                if (ae > s->max_abs) { s->max_abs = ae; s->at_abs = x[i]; }
                if (re > s->max_rel) { s->max_rel = re; s->at_rel = x[i]; }
            }
        }
    }
    free(x);
    free(y);
}

static void test_exp_sweep(void **state)
{
    (void)state;
    if (!have_simd())
        f4d_skip("%s: this CPU has no SIMD vector math (AVX2 + FMA, or NEON)", __func__);
    struct sweep s;
    sweep_run(V_EXP, -110.0f, 90.0f, 509, &s);
    printf("exp:  max %.3f ulp at %a\n", s.max_ulp, s.at_ulp);
    assert_true(s.max_ulp <= 2.0 && s.max_abs_tiny < FLT_MIN);
    sweep_run(V_EXP2, -160.0f, 130.0f, 509, &s);
    printf("exp2: max %.3f ulp at %a\n", s.max_ulp, s.at_ulp);
    assert_true(s.max_ulp <= 2.0 && s.max_abs_tiny < FLT_MIN);
}

static void test_erf_sweep(void **state)
{
    (void)state;
    if (!have_simd())
        f4d_skip("%s: this CPU has no SIMD vector math (AVX2 + FMA, or NEON)", __func__);
    struct sweep s;
    sweep_run(V_ERF, -13.0f, 13.0f, 211, &s);
    printf("erf:  max abs %.3g at %a, max rel %.3g at %a\n", s.max_abs, s.at_abs, s.max_rel,
           s.at_rel);
    assert_true(s.max_abs <= 2e-7);
    sweep_run(V_ERFC, -13.0f, 13.0f, 211, &s);
    printf("erfc: max rel %.3g at %a (normal results), max abs %.3g\n", s.max_rel, s.at_rel,
           s.max_abs);
    assert_true(s.max_rel <= 1e-6 && s.max_abs_tiny < FLT_MIN);
    assert_true(s.max_abs <= 2e-7);
}

static void test_gelu_sweep(void **state)
{
    (void)state;
    if (!have_simd())
        f4d_skip("%s: this CPU has no SIMD vector math (AVX2 + FMA, or NEON)", __func__);
    struct sweep s;
    sweep_run(V_GELU, -30.0f, 30.0f, 211, &s);
    printf("gelu: max rel %.3g at %a (normal results), max abs %.3g at %a\n", s.max_rel,
           s.at_rel, s.max_abs, s.at_abs);
    assert_true(s.max_rel <= 1e-6 && s.max_abs_tiny < FLT_MIN);
}

static void test_sigmoid_silu_sweep(void **state)
{
    (void)state;
    if (!have_simd())
        f4d_skip("%s: this CPU has no SIMD vector math (AVX2 + FMA, or NEON)", __func__);
    struct sweep s;
    sweep_run(V_SIGMOID, -110.0f, 110.0f, 211, &s);
    printf("sigmoid: max rel %.3g at %a, max abs %.3g\n", s.max_rel, s.at_rel, s.max_abs);
    assert_true(s.max_rel <= 5e-7 && s.max_abs_tiny < FLT_MIN);
    assert_true(s.max_abs <= 5e-7);
    sweep_run(V_SILU, -110.0f, 110.0f, 211, &s);
    printf("silu: max rel %.3g at %a, max abs %.3g at %a\n", s.max_rel, s.at_rel, s.max_abs,
           s.at_abs);
    assert_true(s.max_rel <= 5e-7 && s.max_abs_tiny < FLT_MIN);
}

static void test_special_values(void **state)
{
    (void)state;
    if (!have_simd())
        f4d_skip("%s: this CPU has no SIMD vector math (AVX2 + FMA, or NEON)", __func__);
    for (int f = V_EXP; f <= V_SILU; f++) {
        assert_true(isnan(vfn1((enum vfn)f, NAN)));
        assert_true(isnan(vfn1((enum vfn)f, -NAN)));
    }
    assert_true(vfn1(V_EXP, 0.0f) == 1.0f);
    assert_true(vfn1(V_EXP, -0.0f) == 1.0f);
    assert_true(vfn1(V_EXP2, 0.0f) == 1.0f);
    assert_true(vfn1(V_EXP2, 10.0f) == 1024.0f);
    assert_true(vfn1(V_EXP2, -127.0f) == 0.0f);     /* below FLT_MIN: flushed */
    assert_true(vfn1(V_EXP2, -126.0f) == ldexpf(1, -126));
    assert_true(vfn1(V_EXP2, 127.0f) == ldexpf(1, 127));
    assert_true(isinf(vfn1(V_EXP2, 128.0f)));
    assert_true(vfn1(V_EXP2, -151.0f) == 0.0f);
    assert_true(isinf(vfn1(V_EXP, INFINITY)) && vfn1(V_EXP, INFINITY) > 0);
    assert_true(vfn1(V_EXP, -INFINITY) == 0.0f);
    assert_true(isinf(vfn1(V_EXP, 88.73f)));
    assert_true(isfinite(vfn1(V_EXP, 88.72f)));
    assert_true(vfn1(V_EXP, -104.0f) == 0.0f);
    assert_true(vfn1(V_EXP, -1e30f) == 0.0f);
    assert_true(vfn1(V_EXP, -100.0f) == 0.0f);  /* flushed, see fk__scale2n_avx2 */
    assert_true(vfn1(V_EXP, -87.3f) >= FLT_MIN);
    assert_true(vfn1(V_ERF, INFINITY) == 1.0f && vfn1(V_ERF, -INFINITY) == -1.0f);
    assert_true(vfn1(V_ERF, 0.0f) == 0.0f);
    assert_true(vfn1(V_ERFC, INFINITY) == 0.0f && vfn1(V_ERFC, -INFINITY) == 2.0f);

    float g = vfn1(V_GELU, -10.0f);
    assert_true(fabs(g / -7.6198530241604696e-23 - 1) < 1e-6);
    assert_true(vfn1(V_GELU, INFINITY) == INFINITY);
    float gm = vfn1(V_GELU, -INFINITY);
    assert_true(gm == 0.0f && signbit(gm));
    assert_true(vfn1(V_GELU, 1e30f) == 1e30f);
    assert_true(vfn1(V_GELU, 0.0f) == 0.0f);

    float sm = vfn1(V_SILU, -100.0f);
    assert_true(!isnan(sm) && sm <= 0.0f && sm > -1e-40f);
    sm = vfn1(V_SILU, -INFINITY);
    assert_true(sm == 0.0f && signbit(sm));
    assert_true(vfn1(V_SILU, INFINITY) == INFINITY);
    assert_true(vfn1(V_SILU, 1e30f) == 1e30f);
    assert_true(vfn1(V_SIGMOID, INFINITY) == 1.0f);
    assert_true(vfn1(V_SIGMOID, -INFINITY) == 0.0f);
    assert_true(vfn1(V_SIGMOID, 0.0f) == 0.5f);
}

static void test_horizontal(void **state)
{
    (void)state;
    if (!have_simd())
        f4d_skip("%s: this CPU has no SIMD vector math (AVX2 + FMA, or NEON)", __func__);
    float v[8] = { 1, -2, 3.5f, 8, -100, 0.25f, 7, 2 };
    float sum, max;
    horizontal(v, &sum, &max);
    assert_true(sum == -80.25f);
    assert_true(max == 8.0f);
    for (int k = 0; k < 8; k++) { /* the max in every lane */
        float w[8];
        for (int i = 0; i < 8; i++)
            w[i] = -1e30f + (float)i;
        w[k] = 3.0f;
        horizontal(w, &sum, &max);
        assert_true(max == 3.0f);
    }
    float inf[8] = { 1, 2, 3, INFINITY, 5, 6, 7, 8 };
    horizontal(inf, &sum, &max);
    assert_true(max == INFINITY && sum == INFINITY);
}

#if defined(__x86_64__)
#include "../../kernels/src/x86/vecmath_avx512.h"

/* The zmm GELU and SiLU of the AVX-512 GEMM epilogues against the ymm ones,
 * bit for bit (NaN: NaN), 16 floats at a time: every 97th float bit
 * pattern (both signs, subnormals, Inf, NaN) and the specials. */
__attribute__((target("avx2,fma,f16c,avx512f")))
static int zmm_mismatch(const float *x, int silu, float *got, float *want)
{
    __m512 v = _mm512_loadu_ps(x);
    _mm512_storeu_ps(got, silu ? fk__silu512(v) : fk__gelu512(v));
    for (int h = 0; h < 2; h++) {
        __m256 w = _mm256_loadu_ps(x + 8 * h);
        _mm256_storeu_ps(want + 8 * h, silu ? fk__silu_avx2(w) : fk__gelu_avx2(w));
    }
    for (int i = 0; i < 16; i++)
        if (memcmp(&got[i], &want[i], sizeof(float)) != 0 && !(isnan(got[i]) && isnan(want[i])))
            return i + 1;
    return 0;
}

static void test_zmm_same_bits(void **state)
{
    (void)state;
    if (!fk_isa_supported(FK_ISA_AVX512))
        f4d_skip("%s: this CPU has no AVX-512 (the zmm GELU / SiLU are not run)", __func__);
    static const float specials[16] = { 0.0f, -0.0f, INFINITY, -INFINITY, NAN, 1e-45f, -1e-45f, 17.0f,
                                        -17.0f, 0.70710677f, -0.70710677f, 10.1f, -170.0f, -171.0f,
                                        88.7f, -88.7f };
    float x[16], got[16], want[16];
    long checked = 0;
    for (int silu = 0; silu < 2; silu++) {
        int bad = zmm_mismatch(specials, silu, got, want);
        if (bad)
            fail_msg("%s(%g): zmm %a, ymm %a", silu ? "silu" : "gelu", (double)specials[bad - 1],
                     (double)got[bad - 1], (double)want[bad - 1]);
        uint64_t u = 0;
        while (u <= 0xffffffffu) {
            for (int i = 0; i < 16; i++, u += 97) {
                uint32_t b = (uint32_t)u;
                memcpy(&x[i], &b, sizeof b);
            }
            bad = zmm_mismatch(x, silu, got, want);
            if (bad)
                fail_msg("%s(%a): zmm %a, ymm %a", silu ? "silu" : "gelu", (double)x[bad - 1],
                         (double)got[bad - 1], (double)want[bad - 1]);
            checked += 16;
        }
    }
    assert_true(checked > 80000000);
}
#endif

#else /* neither x86-64 nor AArch64: nothing to test */
static void test_no_simd(void **state)
{
    (void)state;
    f4d_skip("the vector math under test is x86-64 AVX2 or AArch64 NEON code: not built for this architecture");
}
#endif

int main(int argc, char **argv)
{
    const struct CMUnitTest tests[] = {
#if defined(__x86_64__) || defined(__aarch64__)
        cmocka_unit_test(test_exp_sweep),
        cmocka_unit_test(test_erf_sweep),
        cmocka_unit_test(test_gelu_sweep),
        cmocka_unit_test(test_sigmoid_silu_sweep),
        cmocka_unit_test(test_special_values),
        cmocka_unit_test(test_horizontal),
#if defined(__x86_64__)
        cmocka_unit_test(test_zmm_same_bits),
#endif
#else
        cmocka_unit_test(test_no_simd),
#endif
    };
    return KERNEL_TEST_MAIN(argc, argv, "kernels/vecmath", tests);
}
