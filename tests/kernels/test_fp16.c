/* fp16 <-> fp32: the reference against exact expectations, and every
 * optimized ISA against the reference bit for bit. */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "fk_fp16.h"
#include "test_util.h"

static float bits_f32(uint32_t u) { float f; memcpy(&f, &u, 4); return f; }
static uint32_t f32_bits(float f) { uint32_t u; memcpy(&u, &f, 4); return u; }

static void test_ref_known_values(void **state)
{
    (void)state;
    assert_int_equal(fk_f32_to_f16_ref(1.0f), 0x3c00);
    assert_int_equal(fk_f32_to_f16_ref(-2.0f), 0xc000);
    assert_int_equal(fk_f32_to_f16_ref(65504.0f), 0x7bff);        /* max normal      */
    assert_int_equal(fk_f32_to_f16_ref(65519.99f), 0x7bff);       /* below the tie    */
    assert_int_equal(fk_f32_to_f16_ref(65520.0f), 0x7c00);        /* tie -> even: Inf */
    assert_int_equal(fk_f32_to_f16_ref(1e10f), 0x7c00);           /* beyond range     */
    assert_int_equal(fk_f32_to_f16_ref(-1e10f), 0xfc00);
    assert_int_equal(fk_f32_to_f16_ref(INFINITY), 0x7c00);
    assert_int_equal(fk_f32_to_f16_ref(-0.0f), 0x8000);
    assert_int_equal(fk_f32_to_f16_ref(ldexpf(1, -24)), 0x0001);  /* min subnormal    */
    assert_int_equal(fk_f32_to_f16_ref(ldexpf(1, -25)), 0x0000);  /* tie -> even 0    */
    assert_int_equal(fk_f32_to_f16_ref(ldexpf(1.5f, -25)), 0x0001);
    assert_int_equal(fk_f32_to_f16_ref(ldexpf(3, -25)), 0x0002);  /* 1.5 ulp: tie -> 2 */
    assert_int_equal(fk_f32_to_f16_ref(ldexpf(1, -14)), 0x0400);  /* min normal       */
    assert_int_equal(fk_f32_to_f16_ref(ldexpf(1023, -24)), 0x03ff); /* max subnormal  */
    assert_int_equal(fk_f32_to_f16_ref(ldexpf(2047, -25)), 0x0400); /* rounds up into normal */
    assert_int_equal(fk_f32_to_f16_ref(ldexpf(1, -30)), 0x0000);
    assert_int_equal(fk_f32_to_f16_ref(1.0f + ldexpf(1, -11)), 0x3c00); /* tie -> even */
    assert_int_equal(fk_f32_to_f16_ref(1.0f + ldexpf(3, -11)), 0x3c02); /* tie -> even up */
    uint16_t qn = fk_f32_to_f16_ref(NAN);
    assert_true((qn & 0x7c00) == 0x7c00 && (qn & 0x3ff) != 0);
    /* A signalling NaN whose payload lives only in low bits must stay NaN. */
    uint16_t sn = fk_f32_to_f16_ref(bits_f32(0x7f800001u));
    assert_true((sn & 0x7c00) == 0x7c00 && (sn & 0x3ff) != 0);
}

static void test_ref_f16_to_f32_exhaustive(void **state)
{
    (void)state;
    for (uint32_t h = 0; h < 65536; h++) {
        float f = fk_f16_to_f32_ref((fk_f16)h);
        uint32_t e = (h >> 10) & 31, m = h & 1023;
        double expect;
        if (e == 31) {
            if (m) { assert_true(isnan(f)); continue; }
            expect = INFINITY;
        } else if (e == 0) {
            expect = ldexp((double)m, -24);
        } else {
            expect = ldexp(1.0 + m / 1024.0, (int)e - 15);
        }
        if (h & 0x8000)
            expect = -expect;
        assert_true((double)f == expect);
        assert_true((signbit(f) != 0) == ((h & 0x8000) != 0));
        if (e != 31 || !m) /* round trip of every non-NaN value is exact */
            assert_int_equal(fk_f32_to_f16_ref(f), h);
    }
}

/* f32 -> f16 must round to the nearest representable value: check against a
 * brute-force nearest search over neighbours computed in double. */
static void test_ref_rounding_random(void **state)
{
    (void)state;
    struct rng r;
    rng_seed(&r, 7);
    for (int i = 0; i < 200000; i++) {
        float x = ldexpf(rng_uniform(&r, 1.0f, 2.0f), (int)(rng_u64(&r) % 44) - 28);
        if (rng_u64(&r) & 1)
            x = -x;
        uint16_t h = fk_f32_to_f16_ref(x);
        double v = fk_f16_to_f32_ref(h);
        if (isinf(v)) {
            assert_true(fabs(x) >= 65520.0);
            continue;
        }
        /* neighbours one step up and down in magnitude */
        uint16_t mag = h & 0x7fff;
        double up = mag < 0x7bff ? fk_f16_to_f32_ref((fk_f16)(mag + 1)) : INFINITY;
        double dn = mag > 0 ? fk_f16_to_f32_ref((fk_f16)(mag - 1)) : 0.0;
        double ax = fabs((double)x), av = fabs(v);
        assert_true(fabs(ax - av) <= fabs(ax - up));
        assert_true(fabs(ax - av) <= fabs(ax - dn));
    }
}

static void check_isa_matches_ref(enum fk_isa isa)
{
    fk_ctx *ctx = test_ctx(isa, 1);
    enum { N = 1 << 20 };
    float *src = xmalloc(N * sizeof *src);
    fk_f16 *got = xmalloc(N * sizeof *got);
    struct rng r;
    rng_seed(&r, 11);
    for (size_t i = 0; i < N; i++) /* every kind of bit pattern, NaNs included */
        src[i] = bits_f32((uint32_t)rng_u64(&r));
    src[0] = 65520.0f; src[1] = -65504.0f; src[2] = ldexpf(1, -25); src[3] = INFINITY;
    assert_int_equal(fk_f32_to_f16(ctx, src, got, N), F4D_OK);
    for (size_t i = 0; i < N; i++)
        if (got[i] != fk_f32_to_f16_ref(src[i]))
            fail_msg("%s: f32 0x%08x -> 0x%04x, reference 0x%04x", fk_isa_name(isa),
                     f32_bits(src[i]), got[i], fk_f32_to_f16_ref(src[i]));

    /* every half, at an odd length that exercises the scalar tail */
    fk_f16 *h = xmalloc(65537 * sizeof *h);
    float *f = xmalloc(65537 * sizeof *f);
    for (uint32_t i = 0; i < 65536; i++)
        h[i] = (fk_f16)i;
    assert_int_equal(fk_f16_to_f32(ctx, h, f, 65536), F4D_OK);
    for (uint32_t i = 0; i < 65536; i++) {
        float ref = fk_f16_to_f32_ref((fk_f16)i);
        assert_true(f32_bits(f[i]) == f32_bits(ref) || (isnan(f[i]) && isnan(ref)));
    }
    free(src); free(got); free(h); free(f);
    fk_ctx_free(ctx);
}

static void test_isa_matches_ref(void **state)
{
    (void)state;
    enum fk_isa isas[4];
    int n = test_isas(isas);
    if (n == 0)
        f4d_skip("test_isa_matches_ref: no optimized ISA under test (none on this CPU, or --isa ref)");
    for (int i = 0; i < n; i++)
        check_isa_matches_ref(isas[i]);
}

static void test_bad_arguments(void **state)
{
    (void)state;
    fk_ctx *ctx = test_ctx(FK_ISA_AUTO, 1);
    assert_int_equal(fk_f32_to_f16(ctx, NULL, NULL, 0), F4D_OK);
    assert_int_equal(fk_f32_to_f16(ctx, NULL, NULL, 4), F4D_EINVAL);
    assert_non_null(strstr(fk_ctx_error(ctx), "NULL"));
    assert_int_equal(fk_f16_to_f32(NULL, NULL, NULL, 4), F4D_EINVAL);
    fk_ctx_free(ctx);
}

int main(int argc, char **argv)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_ref_known_values),
        cmocka_unit_test(test_ref_f16_to_f32_exhaustive),
        cmocka_unit_test(test_ref_rounding_random),
        cmocka_unit_test(test_isa_matches_ref),
        cmocka_unit_test(test_bad_arguments),
    };
    return KERNEL_TEST_MAIN(argc, argv, "kernels/fp16", tests);
}
