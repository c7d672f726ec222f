/* fk_linear: every optimized ISA against the scalar reference on awkward
 * shapes, the precision budgets of fp16 and int8 weights against fp32, the
 * fused epilogues, exact int8 accumulation, non-finite rows and bad input.
 *
 * Error budgets (per output, relative to S = sum_k |x_k w_k| + |b|, the scale
 * any summation order's rounding error is proportional to):
 *   optimized vs reference, same weights:  f32 / f16  |dy| <= 1e-5 S
 *                                          int8       bit-exact before the activation
 *   f16 weights vs f32 weights:                       |dy| <= 1e-3 S
 *   int8 weights + int8 activations vs f32:           |dy| <= 2e-2 S
 * Activations (GELU, SiLU) add at most 2e-6 relative on top. */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "fk_linear.h"
#include "test_util.h"

struct problem {
    int m, n, k;
    float *x, *w, *b, *gamma, *y0;
    double *scale; /* S per output */
};

static void problem_make(struct problem *p, int m, int n, int k, uint64_t seed)
{
    struct rng r;
    rng_seed(&r, seed);
    p->m = m; p->n = n; p->k = k;
    p->x = xmalloc(sizeof(float) * (size_t)m * (size_t)k);
    p->w = xmalloc(sizeof(float) * (size_t)n * (size_t)k);
    p->b = xmalloc(sizeof(float) * (size_t)n);
    p->gamma = xmalloc(sizeof(float) * (size_t)n);
    p->y0 = xmalloc(sizeof(float) * (size_t)m * (size_t)n);
    p->scale = xmalloc(sizeof(double) * (size_t)m * (size_t)n);
    rng_fill_normal(&r, p->x, (size_t)m * (size_t)k, 1.0f);
    rng_fill_normal(&r, p->w, (size_t)n * (size_t)k, 1.0f / sqrtf((float)k));
    rng_fill_normal(&r, p->b, (size_t)n, 0.1f);
    rng_fill(&r, p->gamma, (size_t)n, 0.01f, 1.0f);
    rng_fill_normal(&r, p->y0, (size_t)m * (size_t)n, 1.0f);
    for (int i = 0; i < m; i++)
        for (int j = 0; j < n; j++) {
            double s = fabs(p->b[j]);
            for (int q = 0; q < k; q++)
                s += fabs((double)p->x[(size_t)i * k + q] * p->w[(size_t)j * k + q]);
            p->scale[(size_t)i * n + j] = s;
        }
}

static void problem_free(struct problem *p)
{
    free(p->x); free(p->w); free(p->b); free(p->gamma); free(p->y0); free(p->scale);
}

/* max over outputs of |a - b| / S; NaN mismatch is infinite */
static double scaled_err(const struct problem *p, const float *a, const float *b)
{
    double worst = 0;
    for (size_t i = 0; i < (size_t)p->m * (size_t)p->n; i++) {
        if (isnan(a[i]) != isnan(b[i]))
            return INFINITY;
        if (isnan(a[i]))
            continue;
        double e = fabs((double)a[i] - b[i]) / (p->scale[i] + 1e-30);
        if (e > worst)
            worst = e;
    }
    return worst;
}

static float *run(fk_ctx *ctx, const struct problem *p, enum fk_wtype t,
                  const struct fk_epilogue *ep)
{
    struct fk_linear L;
    assert_int_equal(fk_linear_pack(ctx, &L, t, p->w, p->n, p->k, p->b), F4D_OK);
    float *y = xmalloc(sizeof(float) * (size_t)p->m * (size_t)p->n);
    memcpy(y, p->y0, sizeof(float) * (size_t)p->m * (size_t)p->n);
    int st = fk_linear_forward(ctx, &L, p->x, p->m, p->k, y, p->n, ep);
    if (st != F4D_OK)
        fail_msg("forward: %s", fk_ctx_error(ctx));
    fk_linear_free(&L);
    return y;
}

static const int shapes[][3] = {
    { 1, 1, 1 }, { 1, 17, 5 }, { 7, 13, 31 }, { 13, 16, 256 }, { 6, 32, 257 },
    { 37, 50, 129 }, { 101, 33, 263 }, { 5, 103, 7 }, { 2, 1031, 3 }, { 150, 48, 64 },
};

static void test_isa_vs_reference(void **state)
{
    (void)state;
    enum fk_isa isas[4];
    int n_isa = test_isas(isas);
    if (n_isa == 0)
        f4d_skip("test_isa_vs_reference: no optimized ISA under test (none on this CPU, or --isa ref)");
    fk_ctx *ref = test_ctx(FK_ISA_REF, 1);
    struct fk_epilogue plain = { FK_ACT_NONE, NULL, 0 };
    for (size_t s = 0; s < sizeof shapes / sizeof shapes[0]; s++) {
        struct problem p;
        problem_make(&p, shapes[s][0], shapes[s][1], shapes[s][2], 100 + s);
        for (int t = FK_W_F32; t <= FK_W_Q8; t++) {
            float *want = run(ref, &p, (enum fk_wtype)t, &plain);
            for (int i = 0; i < n_isa; i++)
                for (int threads = 1; threads <= 2; threads++) {
                    fk_ctx *ctx = test_ctx(isas[i], threads);
                    float *got = run(ctx, &p, (enum fk_wtype)t, &plain);
                    if (t == FK_W_Q8) {
                        if (memcmp(got, want, sizeof(float) * (size_t)p.m * (size_t)p.n) != 0)
                            fail_msg("%s int8 %dx%dx%d not bit-exact (%g)", fk_isa_name(isas[i]),
                                     p.m, p.n, p.k, scaled_err(&p, got, want));
                    } else {
                        double e = scaled_err(&p, got, want);
                        if (e > 1e-5)
                            fail_msg("%s type %d %dx%dx%d threads %d: error %g > 1e-5",
                                     fk_isa_name(isas[i]), t, p.m, p.n, p.k, threads, e);
                    }
                    free(got);
                    fk_ctx_free(ctx);
                }
            free(want);
        }
        problem_free(&p);
    }
    fk_ctx_free(ref);
}

static void test_precision_budgets(void **state)
{
    (void)state;
    fk_ctx *ctx = test_ctx(FK_ISA_AUTO, 2);
    struct fk_epilogue plain = { FK_ACT_NONE, NULL, 0 };
    struct problem p;
    problem_make(&p, 64, 96, 384, 5);
    float *f32 = run(ctx, &p, FK_W_F32, &plain);
    float *f16 = run(ctx, &p, FK_W_F16, &plain);
    float *q8 = run(ctx, &p, FK_W_Q8, &plain);
    double e16 = scaled_err(&p, f16, f32), e8 = scaled_err(&p, q8, f32);
    print_message("f16 vs f32: %.3g S, int8 vs f32: %.3g S\n", e16, e8);
    assert_true(e16 <= 1e-3);
    assert_true(e8 <= 2e-2);
    assert_true(e8 > 0); /* int8 really quantized */
    free(f32); free(f16); free(q8);
    problem_free(&p);
    fk_ctx_free(ctx);
}

static void test_epilogues(void **state)
{
    (void)state;
    enum fk_isa isas[4];
    int n_isa = test_isas(isas);
    if (n_isa == 0)
        f4d_skip("test_epilogues: no optimized ISA under test (none on this CPU, or --isa ref)");
    fk_ctx *ref = test_ctx(FK_ISA_REF, 1);
    struct problem p;
    problem_make(&p, 19, 45, 70, 9);
    const enum fk_act acts[] = { FK_ACT_NONE, FK_ACT_RELU, FK_ACT_GELU, FK_ACT_SILU };
    for (int a = 0; a < 4; a++)
        for (int mode = 0; mode < 3; mode++) {
            struct fk_epilogue ep = { acts[a], mode >= 1 ? p.gamma : NULL, mode == 2 };
            for (int t = FK_W_F32; t <= FK_W_Q8; t++) {
                float *want = run(ref, &p, (enum fk_wtype)t, &ep);
                for (int i = 0; i < n_isa; i++) {
                    fk_ctx *ctx = test_ctx(isas[i], 2);
                    float *got = run(ctx, &p, (enum fk_wtype)t, &ep);
                    /* residual outputs carry y0 (|y0| ~ 1): budget on S + |y0| */
                    double worst = 0;
                    for (int q = 0; q < p.m * p.n; q++) {
                        double s = p.scale[q] + (mode == 2 ? fabs(p.y0[q]) : 0) + 1e-30;
                        double e = fabs((double)got[q] - want[q]) / s;
                        if (e > worst)
                            worst = e;
                    }
                    if (worst > 1e-5)
                        fail_msg("%s act %d mode %d type %d: error %g", fk_isa_name(isas[i]),
                                 a, mode, t, worst);
                    free(got);
                    fk_ctx_free(ctx);
                }
                free(want);
            }
        }
    problem_free(&p);
    fk_ctx_free(ref);
}

/* All codes at +-127 over k = 4096: sums of 66e6 that any int16 intermediate
 * (vpmaddubsw) would saturate; the result must equal the exact integer. */
static void test_int8_exact_accumulation(void **state)
{
    (void)state;
    const int k = 4096, n = 16, m = 6;
    float *x = xmalloc(sizeof(float) * m * k), *w = xmalloc(sizeof(float) * n * k);
    float *y = xmalloc(sizeof(float) * m * n);
    for (int i = 0; i < m * k; i++)
        x[i] = (i % 3 == 0) ? -2.0f : 2.0f;
    for (int j = 0; j < n; j++)
        for (int i = 0; i < k; i++)
            w[j * k + i] = ((i + j) % 2 ? 0.5f : -0.5f) * (i % 3 == 0 ? -1.0f : 1.0f);
    enum fk_isa all[5] = { FK_ISA_REF };
    int n_isa = 1 + test_isas(all + 1);
    for (int a = 0; a < n_isa; a++) {
        fk_ctx *ctx = test_ctx(all[a], 2);
        struct fk_linear L;
        assert_int_equal(fk_linear_pack(ctx, &L, FK_W_Q8, w, n, k, NULL), F4D_OK);
        assert_int_equal(fk_linear_forward(ctx, &L, x, m, k, y, n, NULL), F4D_OK);
        for (int i = 0; i < m; i++)
            for (int j = 0; j < n; j++) {
                int64_t acc = 0;
                for (int q = 0; q < k; q++)
                    acc += (int64_t)(x[i * k + q] > 0 ? 127 : -127) * (w[j * k + q] > 0 ? 127 : -127);
                float want = fmaf((float)acc, (2.0f / 127.0f) * (0.5f / 127.0f), 0.0f);
                if (y[i * n + j] != want)
                    fail_msg("%s: y[%d][%d] = %.9g, exact %.9g", fk_isa_name(all[a]), i, j,
                             y[i * n + j], want);
            }
        fk_linear_free(&L);
        fk_ctx_free(ctx);
    }
    free(x); free(w); free(y);
}

static void test_nonfinite_rows(void **state)
{
    (void)state;
    enum fk_isa all[5] = { FK_ISA_REF };
    int n_isa = 1 + test_isas(all + 1);
    struct problem p;
    problem_make(&p, 9, 20, 40, 3);
    p.x[2 * p.k + 5] = NAN;
    p.x[5 * p.k + 0] = INFINITY;
    p.x[7 * p.k + 39] = -INFINITY;
    for (int a = 0; a < n_isa; a++)
        for (int t = FK_W_F32; t <= FK_W_Q8; t++) {
            fk_ctx *ctx = test_ctx(all[a], 2);
            float *y = run(ctx, &p, (enum fk_wtype)t, NULL);
            for (int i = 0; i < p.m; i++)
                for (int j = 0; j < p.n; j++) {
                    int bad = i == 2 || i == 5 || i == 7;
                    float v = y[i * p.n + j];
                    if (bad && t == FK_W_Q8)
                        assert_true(isnan(v));
                    else if (bad && i == 2)
                        assert_true(isnan(v));
                    else if (!bad && !isfinite(v))
                        fail_msg("%s type %d: finite row %d became %g", fk_isa_name(all[a]), t, i, v);
                }
            free(y);
            fk_ctx_free(ctx);
        }
    problem_free(&p);
}

/* Rows whose largest magnitude is tiny (below FK_Q8_AMAX_MIN, e.g. the
 * subnormal weights the GGUF fuzzer wrote): 127 / amax overflowed to Inf and
 * 0 * Inf gave NaN codes (a float-to-int8 conversion of NaN: undefined). Such
 * a row now quantizes as a zero row, on every ISA. */
static void test_tiny_rows(void **state)
{
    (void)state;
    static const float tiny[6] = { 1e-38f, 0.0f, -3e-38f, 1e-44f, -0.0f, 2.5e-37f };
    int8_t q[6];
    memset(q, 0x55, sizeof q);
    float s = fk_quantize_row_q8(tiny, 6, q);
    if (!(s == 0.0f))
        fail_msg("tiny row: scale %g, expected 0 (a zero row)", (double)s);
    for (int i = 0; i < 6; i++)
        assert_int_equal(q[i], 0);
    /* just above the threshold: still quantized, codes within +-127 */
    const float small[3] = { 2e-30f, -1e-30f, 0.0f };
    s = fk_quantize_row_q8(small, 3, q);
    assert_true(s > 0.0f && isfinite(s));
    assert_int_equal(q[0], 127);
    assert_int_equal(q[2], 0);
    /* every ISA: a tiny weight row and a tiny activation row give the bias */
    enum fk_isa all[5] = { FK_ISA_REF };
    int n_isa = 1 + test_isas(all + 1);
    struct problem p;
    problem_make(&p, 5, 9, 24, 11);
    for (int i = 0; i < p.k; i++) {
        p.w[3 * p.k + i] = tiny[i % 6];   /* weight row 3 */
        p.x[1 * p.k + i] = tiny[(i + 1) % 6]; /* activation row 1 */
    }
    for (int a = 0; a < n_isa; a++) {
        fk_ctx *ctx = test_ctx(all[a], 1);
        float *y = run(ctx, &p, FK_W_Q8, NULL);
        for (int i = 0; i < p.m; i++)
            for (int j = 0; j < p.n; j++) {
                float v = y[i * p.n + j];
                if (!isfinite(v))
                    fail_msg("%s: y[%d][%d] = %g", fk_isa_name(all[a]), i, j, (double)v);
                if ((i == 1 || j == 3) && !(fabsf(v - p.b[j]) <= 1e-6f))
                    fail_msg("%s: y[%d][%d] = %g, expected the bias %g", fk_isa_name(all[a]), i, j,
                             (double)v, (double)p.b[j]);
            }
        free(y);
        fk_ctx_free(ctx);
    }
    problem_free(&p);
}

static void test_bad_input(void **state)
{
    (void)state;
    fk_ctx *ctx = test_ctx(FK_ISA_AUTO, 1);
    float w[12] = { 0 }, x[12] = { 0 }, y[12];
    struct fk_linear L;
    assert_int_equal(fk_linear_pack(ctx, &L, FK_W_F32, w, 0, 3, NULL), F4D_EINVAL);
    assert_non_null(strstr(fk_ctx_error(ctx), "shape"));
    assert_int_equal(fk_linear_pack(ctx, &L, FK_W_F32, w, 3, -1, NULL), F4D_EINVAL);
    assert_int_equal(fk_linear_pack(ctx, &L, (enum fk_wtype)7, w, 3, 4, NULL), F4D_EINVAL);
    assert_int_equal(fk_linear_pack(ctx, &L, FK_W_F32, NULL, 3, 4, NULL), F4D_EINVAL);
    assert_int_equal(fk_linear_pack(ctx, &L, FK_W_Q8, w, 1, 70000, NULL), F4D_ERANGE);
    w[5] = NAN;
    assert_int_equal(fk_linear_pack(ctx, &L, FK_W_Q8, w, 3, 4, NULL), F4D_EINVAL);
    assert_non_null(strstr(fk_ctx_error(ctx), "row 1"));
    int8_t q[4] = { 1, -128, 0, 0 };
    float sc[1] = { 1.0f };
    assert_int_equal(fk_linear_pack_q8(ctx, &L, q, sc, 1, 4, NULL), F4D_EINVAL);
    assert_non_null(strstr(fk_ctx_error(ctx), "-128"));
    w[5] = 0;

    assert_int_equal(fk_linear_pack(ctx, &L, FK_W_F32, w, 3, 4, NULL), F4D_OK);
    assert_int_equal(fk_linear_forward(ctx, &L, x, 2, 3, y, 3, NULL), F4D_EINVAL); /* ldx < k */
    assert_non_null(strstr(fk_ctx_error(ctx), "stride"));
    assert_int_equal(fk_linear_forward(ctx, &L, x, 2, 4, y, 2, NULL), F4D_EINVAL); /* ldy < n */
    assert_int_equal(fk_linear_forward(ctx, &L, x, -1, 4, y, 3, NULL), F4D_EINVAL);
    assert_int_equal(fk_linear_forward(ctx, &L, NULL, 2, 4, y, 3, NULL), F4D_EINVAL);
    assert_int_equal(fk_linear_forward(ctx, &L, x, 0, 4, y, 3, NULL), F4D_OK);     /* empty */
    assert_int_equal(fk_linear_forward(ctx, &L, x, 2, 4, x + 2, 3, NULL), F4D_EINVAL); /* overlap */
    struct fk_epilogue bad = { (enum fk_act)9, NULL, 0 };
    assert_int_equal(fk_linear_forward(ctx, &L, x, 2, 4, y, 3, &bad), F4D_EINVAL);
    assert_int_equal(fk_linear_forward(ctx, NULL, x, 2, 4, y, 3, NULL), F4D_EINVAL);
    if (fk_ctx_isa(ctx) != FK_ISA_REF) { /* weights packed for another layout */
        fk_ctx *ref = test_ctx(FK_ISA_REF, 1);
        assert_int_equal(fk_linear_forward(ref, &L, x, 2, 4, y, 3, NULL), F4D_EINVAL);
        assert_non_null(strstr(fk_ctx_error(ref), "packed"));
        fk_ctx_free(ref);
    }
    fk_linear_free(&L);
    fk_linear_free(&L); /* idempotent */
    fk_ctx_free(ctx);
}

static void test_f16_source_and_q8_import(void **state)
{
    (void)state;
    fk_ctx *ctx = test_ctx(FK_ISA_AUTO, 1);
    struct problem p;
    problem_make(&p, 11, 21, 33, 77);
    fk_f16 *wh = xmalloc(sizeof(fk_f16) * 21 * 33);
    assert_int_equal(fk_f32_to_f16(ctx, p.w, wh, 21 * 33), F4D_OK);
    struct fk_linear a, b;
    float *ya = xmalloc(sizeof(float) * 11 * 21), *yb = xmalloc(sizeof(float) * 11 * 21);
    /* fp16 kept as fp16 equals fp32 weights rounded to fp16 */
    assert_int_equal(fk_linear_pack_f16(ctx, &a, FK_W_F16, wh, 21, 33, p.b), F4D_OK);
    assert_int_equal(fk_linear_pack(ctx, &b, FK_W_F16, p.w, 21, 33, p.b), F4D_OK);
    assert_int_equal(fk_linear_forward(ctx, &a, p.x, 11, 33, ya, 21, NULL), F4D_OK);
    assert_int_equal(fk_linear_forward(ctx, &b, p.x, 11, 33, yb, 21, NULL), F4D_OK);
    assert_memory_equal(ya, yb, sizeof(float) * 11 * 21);
    fk_linear_free(&a); fk_linear_free(&b);
    /* pre-quantized import equals quantize-at-pack */
    int8_t *q = xmalloc(21 * 33);
    float sc[21];
    for (int j = 0; j < 21; j++)
        sc[j] = fk_quantize_row_q8(p.w + j * 33, 33, q + j * 33);
    assert_int_equal(fk_linear_pack_q8(ctx, &a, q, sc, 21, 33, p.b), F4D_OK);
    assert_int_equal(fk_linear_pack(ctx, &b, FK_W_Q8, p.w, 21, 33, p.b), F4D_OK);
    assert_int_equal(fk_linear_forward(ctx, &a, p.x, 11, 33, ya, 21, NULL), F4D_OK);
    assert_int_equal(fk_linear_forward(ctx, &b, p.x, 11, 33, yb, 21, NULL), F4D_OK);
    assert_memory_equal(ya, yb, sizeof(float) * 11 * 21);
    assert_true(a.bytes < (size_t)21 * 33 * 4); /* int8 holds less than fp32 */
    fk_linear_free(&a); fk_linear_free(&b);
    free(q); free(wh); free(ya); free(yb);
    problem_free(&p);
    fk_ctx_free(ctx);
}

int main(int argc, char **argv)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_isa_vs_reference),
        cmocka_unit_test(test_precision_budgets),
        cmocka_unit_test(test_epilogues),
        cmocka_unit_test(test_int8_exact_accumulation),
        cmocka_unit_test(test_nonfinite_rows),
        cmocka_unit_test(test_tiny_rows),
        cmocka_unit_test(test_f16_source_and_q8_import),
        cmocka_unit_test(test_bad_input),
    };
    return KERNEL_TEST_MAIN(argc, argv, "kernels/linear", tests);
}
