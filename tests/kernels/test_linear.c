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
 *   7-bit path weights (no VNNI) + int8 act.:         |dy| <= 3e-2 S
 *     (pairs |q0| + |q1| <= 128: each weight's step is 1x to 2x the 8-bit one)
 *   different cache blocks (kc, mc, nc), any type:    bit-identical
 *   AVX-512 vs AVX2, f32 / f16 weights, epilogues:    bit-identical
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
    struct fk_epilogue plain = { FK_ACT_NONE, NULL, 0 };
    for (size_t s = 0; s < sizeof shapes / sizeof shapes[0]; s++) {
        struct problem p;
        problem_make(&p, shapes[s][0], shapes[s][1], shapes[s][2], 100 + s);
        /* int8 twice: 8-bit and 7-bit weight codes, each path against the
         * reference packing the same codes */
        for (int v = 0; v < 4; v++) {
            int t = v < FK_W_Q8 ? v : FK_W_Q8, bits = v == 3 ? 7 : 8;
            fk_ctx *ref = test_ctx_q8(FK_ISA_REF, 1, (enum fk_q8_bits)bits);
            float *want = run(ref, &p, (enum fk_wtype)t, &plain);
            fk_ctx_free(ref);
            for (int i = 0; i < n_isa; i++)
                for (int threads = 1; threads <= 2; threads++) {
                    fk_ctx *ctx = test_ctx_q8(isas[i], threads, (enum fk_q8_bits)bits);
                    float *got = run(ctx, &p, (enum fk_wtype)t, &plain);
                    if (t == FK_W_Q8) {
                        if (memcmp(got, want, sizeof(float) * (size_t)p.m * (size_t)p.n) != 0)
                            fail_msg("%s int8 (%s) %dx%dx%d not bit-exact (%g)", fk_isa_name(isas[i]),
                                     fk_ctx_q8_path(ctx), p.m, p.n, p.k, scaled_err(&p, got, want));
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
    fk_ctx *c8 = test_ctx_q8(FK_ISA_AUTO, 2, FK_Q8_8BIT), *c7 = test_ctx_q8(FK_ISA_AUTO, 2, FK_Q8_7BIT);
    float *q8 = run(c8, &p, FK_W_Q8, &plain), *q7 = run(c7, &p, FK_W_Q8, &plain);
    double e16 = scaled_err(&p, f16, f32), e8 = scaled_err(&p, q8, f32), e7 = scaled_err(&p, q7, f32);
    print_message("f16 vs f32: %.3g S, int8 vs f32: %.3g S (%s), 7-bit weights vs f32: %.3g S (%s)\n",
                  e16, e8, fk_ctx_q8_path(c8), e7, fk_ctx_q8_path(c7));
    assert_true(e16 <= 1e-3);
    assert_true(e8 <= 2e-2);
    assert_true(e7 <= 3e-2);
    assert_true(e8 > 0); /* int8 really quantized */
    assert_true(e7 > e8); /* and 7 bits really coarser */
    free(f32); free(f16); free(q8); free(q7);
    problem_free(&p);
    fk_ctx_free(ctx); fk_ctx_free(c8); fk_ctx_free(c7);
}

static void test_epilogues(void **state)
{
    (void)state;
    enum fk_isa isas[4];
    int n_isa = test_isas(isas);
    if (n_isa == 0)
        f4d_skip("test_epilogues: no optimized ISA under test (none on this CPU, or --isa ref)");
    /* AVX2 (which any AVX-512 CPU runs) is the AVX-512 rows' bit reference */
    int has_avx2 = fk_isa_supported(FK_ISA_AVX2), has_avx512 = 0;
    for (int i = 0; i < n_isa; i++)
        has_avx512 |= isas[i] == FK_ISA_AVX512;
    fk_ctx *refs[2] = { test_ctx_q8(FK_ISA_REF, 1, FK_Q8_8BIT), test_ctx_q8(FK_ISA_REF, 1, FK_Q8_7BIT) };
    /* n = 45: an AVX-512 pair of panels and a lone 13-column one; n = 57: two
     * pairs, the second with 25 columns */
    const int widths[] = { 45, 57 };
    const enum fk_act acts[] = { FK_ACT_NONE, FK_ACT_RELU, FK_ACT_GELU, FK_ACT_SILU };
    for (int wi = 0; wi < 2; wi++) {
        struct problem p;
        problem_make(&p, 19, widths[wi], 70, 9);
        for (int a = 0; a < 4; a++)
            for (int mode = 0; mode < 3; mode++) {
                struct fk_epilogue ep = { acts[a], mode >= 1 ? p.gamma : NULL, mode == 2 };
                for (int t = FK_W_F32; t <= FK_W_Q8; t++) {
                    /* AVX-512 float GEMMs accumulate each element in the AVX2
                     * order and finish it with the same operations: same bits */
                    float *avx2 = NULL;
                    if (has_avx2 && has_avx512 && t != FK_W_Q8) {
                        fk_ctx *c2 = test_ctx(FK_ISA_AVX2, 2);
                        avx2 = run(c2, &p, (enum fk_wtype)t, &ep);
                        fk_ctx_free(c2);
                    }
                    for (int i = 0; i < n_isa; i++) {
                        fk_ctx *ctx = test_ctx(isas[i], 2);
                        float *want = run(refs[fk_ctx_q8_bits(ctx) == FK_Q8_7BIT], &p, (enum fk_wtype)t, &ep);
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
                            fail_msg("%s n %d act %d mode %d type %d: error %g", fk_isa_name(isas[i]),
                                     p.n, a, mode, t, worst);
                        if (avx2 && isas[i] == FK_ISA_AVX512 &&
                            memcmp(got, avx2, sizeof(float) * (size_t)p.m * (size_t)p.n) != 0)
                            fail_msg("avx512 n %d act %d mode %d type %d: not AVX2's bits", p.n, a, mode, t);
                        free(got);
                        free(want);
                        fk_ctx_free(ctx);
                    }
                    free(avx2);
                }
            }
        problem_free(&p);
    }
    fk_ctx_free(refs[0]);
    fk_ctx_free(refs[1]);
}

/* All codes at +-127 over k = 4096 (8-bit weight codes on every ISA): sums of
 * 66e6 that any int16 intermediate of 8-bit x 8-bit pairs (vpmaddubsw) would
 * saturate; the result must equal the exact integer. */
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
        fk_ctx *ctx = test_ctx_q8(all[a], 2, FK_Q8_8BIT);
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

/* The 7-bit path's worst cases, exact against int64 sums over k = 4096 and
 * in several k blocks: every activation at code 127 (255 as the unsigned
 * operand of vpmaddubsw; row 6 at -127, i.e. 1), weights whose (even, odd)
 * pairs sum to the budget |q0| + |q1| = 128, so each int16 pair sum reaches
 * +-255 * 128 = +-32640. From fp32 (+-0.5 everywhere: codes +-64) and from an
 * int8 file holding pairs (127, 1), (64, 64), (-1, -127) kept as they are.
 * Any saturation would show. */
static void test_q7_worst_case(void **state)
{
    (void)state;
    const int k = 4096, n = 16, m = 7;
    float *x = xmalloc(sizeof(float) * m * k), *w = xmalloc(sizeof(float) * n * k);
    float *y = xmalloc(sizeof(float) * m * n), sc[16];
    int8_t *qf = xmalloc((size_t)n * k);
    for (int i = 0; i < m * k; i++)
        x[i] = i / k == 6 ? -2.0f : 2.0f;
    for (int j = 0; j < n; j++) {
        sc[j] = 0.25f;
        for (int i = 0; i < k; i++) {
            /* all +, all -, pairs alternating sign, then mixed runs */
            int neg = j == 0 ? 0 : j == 1 ? 1 : j < 8 ? (i / 2 + j) % 2 : (i / (2 * j)) % 2;
            w[j * k + i] = neg ? -0.5f : 0.5f;
            int big = (i / 2 + j) % 3, v = big == 0 ? (i % 2 ? 1 : 127) : big == 1 ? 64 : (i % 2 ? 127 : 1);
            qf[j * k + i] = (int8_t)(neg ? -v : v);
        }
    }
    enum fk_isa all[5] = { FK_ISA_REF };
    int n_isa = 1 + test_isas(all + 1);
    static const struct fk_gemm_blocks blocks[] = { { 0, 0, 0 }, { 64, 6, 16 } };
    for (int a = 0; a < n_isa; a++)
        for (int bl = 0; bl < 2; bl++)
            for (int src = 0; src < 2; src++) {
                fk_ctx *ctx = NULL;
                struct fk_ctx_config cfg = { .isa = all[a], .threads = 2, .q8_bits = FK_Q8_7BIT,
                                             .blocks = blocks[bl] };
                assert_int_equal(fk_ctx_new(&cfg, &ctx), F4D_OK);
                struct fk_linear L;
                if (src == 0)
                    assert_int_equal(fk_linear_pack(ctx, &L, FK_W_Q8, w, n, k, NULL), F4D_OK);
                else
                    assert_int_equal(fk_linear_pack_q8(ctx, &L, qf, sc, n, k, NULL), F4D_OK);
                assert_int_equal(L.q8_bits, 7);
                assert_int_equal(fk_linear_forward(ctx, &L, x, m, k, y, n, NULL), F4D_OK);
                for (int i = 0; i < m; i++)
                    for (int j = 0; j < n; j++) {
                        int64_t acc = 0;
                        for (int q = 0; q < k; q++) {
                            int wq = src == 0 ? (w[j * k + q] > 0 ? 64 : -64) : qf[j * k + q];
                            acc += (int64_t)(x[i * k + q] > 0 ? 127 : -127) * wq;
                        }
                        float sw = src == 0 ? 1.0f / 127.0f : 0.25f;
                        float want = fmaf((float)acc, (2.0f / 127.0f) * sw, 0.0f);
                        if (y[i * n + j] != want)
                            fail_msg("%s (%s, %s): y[%d][%d] = %.9g, exact %.9g", fk_isa_name(all[a]),
                                     fk_ctx_q8_path(ctx), src ? "int8 file" : "fp32", i, j,
                                     y[i * n + j], want);
                    }
                fk_linear_free(&L);
                fk_ctx_free(ctx);
            }
    free(x); free(w); free(y); free(qf);
}

/* The cache blocks change where partial sums are stored, never the order of
 * accumulation: every blocking gives bit-identical results, for every weight
 * type, including blocks far from the model's (kc 8, mc 6, nc 16). */
static void test_blockings_identical(void **state)
{
    (void)state;
    enum fk_isa isas[4];
    int n_isa = test_isas(isas);
    if (n_isa == 0)
        f4d_skip("test_blockings_identical: no optimized ISA under test (none on this CPU, or --isa ref)");
    static const struct fk_gemm_blocks blocks[] = {
        { 8, 6, 16 }, { 64, 12, 32 }, { 128, 30, 256 }, { 256, 252, 1024 }, { 384, 426, 2048 },
        { 1024, 1020, 4096 },
    };
    static const int dims[][3] = { { 97, 70, 1000 }, { 13, 33, 263 }, { 250, 128, 520 } };
    struct fk_epilogue ep = { FK_ACT_GELU, NULL, 0 };
    for (size_t d = 0; d < sizeof dims / sizeof dims[0]; d++) {
        struct problem p;
        problem_make(&p, dims[d][0], dims[d][1], dims[d][2], 31 + d);
        for (int i = 0; i < n_isa; i++)
            for (int t = FK_W_F32; t <= FK_W_Q8 + 1; t++) {
                enum fk_wtype wt = t > FK_W_Q8 ? FK_W_Q8 : (enum fk_wtype)t;
                enum fk_q8_bits bits = t > FK_W_Q8 ? FK_Q8_7BIT : FK_Q8_8BIT;
                float *first = NULL;
                for (size_t b = 0; b < sizeof blocks / sizeof blocks[0]; b++)
                    for (int threads = 1; threads <= 2; threads++) {
                        fk_ctx *ctx = NULL;
                        struct fk_ctx_config cfg = { .isa = isas[i], .threads = threads,
                                                     .blocks = blocks[b], .q8_bits = bits };
                        assert_int_equal(fk_ctx_new(&cfg, &ctx), F4D_OK);
                        struct fk_gemm_blocks got = fk_ctx_gemm_blocks(ctx);
                        assert_int_equal(got.kc, blocks[b].kc);
                        assert_int_equal(got.mc, blocks[b].mc);
                        assert_int_equal(got.nc, blocks[b].nc);
                        float *y = run(ctx, &p, wt, &ep);
                        if (!first)
                            first = y;
                        else if (memcmp(first, y, sizeof(float) * (size_t)p.m * (size_t)p.n) != 0)
                            fail_msg("%s type %d (%d-bit) %dx%dx%d: blocks %d,%d,%d threads %d differ (%g)",
                                     fk_isa_name(isas[i]), (int)wt, (int)bits, p.m, p.n, p.k,
                                     blocks[b].kc, blocks[b].mc, blocks[b].nc, threads,
                                     scaled_err(&p, y, first));
                        if (y != first)
                            free(y);
                        fk_ctx_free(ctx);
                    }
                free(first);
            }
        problem_free(&p);
    }
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
    fk_ctx *ctx = test_ctx_q8(FK_ISA_AUTO, 1, FK_Q8_8BIT);
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
    /* an 8-bit file under 7-bit codes: requantized at packing, the same on
     * every ISA as on the reference, and within the 7-bit budget */
    fk_ctx *r7 = test_ctx_q8(FK_ISA_REF, 1, FK_Q8_7BIT), *c7 = test_ctx_q8(FK_ISA_AUTO, 1, FK_Q8_7BIT);
    assert_int_equal(fk_linear_pack_q8(r7, &a, q, sc, 21, 33, p.b), F4D_OK);
    assert_int_equal(fk_linear_pack_q8(c7, &b, q, sc, 21, 33, p.b), F4D_OK);
    assert_int_equal(a.q8_bits, 7);
    assert_int_equal(fk_linear_forward(r7, &a, p.x, 11, 33, ya, 21, NULL), F4D_OK);
    assert_int_equal(fk_linear_forward(c7, &b, p.x, 11, 33, yb, 21, NULL), F4D_OK);
    assert_memory_equal(ya, yb, sizeof(float) * 11 * 21);
    float *yf = run(ctx, &p, FK_W_F32, NULL);
    assert_true(scaled_err(&p, ya, yf) <= 3e-2);
    free(yf);
    fk_linear_free(&a); fk_linear_free(&b);
    fk_ctx_free(r7); fk_ctx_free(c7);
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
        cmocka_unit_test(test_q7_worst_case),
        cmocka_unit_test(test_blockings_identical),
        cmocka_unit_test(test_nonfinite_rows),
        cmocka_unit_test(test_tiny_rows),
        cmocka_unit_test(test_f16_source_and_q8_import),
        cmocka_unit_test(test_bad_input),
    };
    return KERNEL_TEST_MAIN(argc, argv, "kernels/linear", tests);
}
