/* fk_ops: the scalar references against exact values, every optimized ISA
 * (1 and 2 threads) against the reference, hard cases and bad arguments.
 *
 * Error budgets of the optimized ISAs against the reference, as
 * |got - ref| <= atol + rtol |ref|:
 *   gelu         rtol 2e-6, atol 1e-37  (vector erfc 1e-6 + reference rounding;
 *                                        atol covers subnormal results)
 *   silu         rtol 1e-6, atol 1e-37
 *   relu         exact
 *   layernorm    rtol 1e-5, atol 1e-6   (statistics in double in both; only
 *                                        the summation order differs)
 *   softmax      rtol 1e-5, atol 1e-37  (float x - max and 2-ulp exp: about
 *                                        |x - max| * 6e-8 relative, float sum)
 *   residual add exact (separate multiply and add, as the reference)
 * Two threads must give the same bits as one: rows and elements never mix. */
#include <float.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fk_ops.h"
#include "test_util.h"

#define SENTINEL 12345.0f

/* Contexts under test: the reference with 2 threads (its threading path) and
 * every optimized ISA with 1 and 2 threads. */
struct cfg { enum fk_isa isa; int threads; };

static int test_cfgs(struct cfg out[10])
{
    enum fk_isa isas[4];
    int n = test_isas(isas), k = 0;
    out[k++] = (struct cfg){ FK_ISA_REF, 2 };
    for (int i = 0; i < n; i++) {
        out[k++] = (struct cfg){ isas[i], 1 };
        out[k++] = (struct cfg){ isas[i], 2 };
    }
    return k;
}

static void check_budget(const char *what, struct cfg c, const float *got, const float *ref,
                         size_t n, double atol, double rtol)
{
    double r = budget_ratio(got, ref, n, atol, rtol);
    if (!(r <= 1.0)) {
        size_t worst = 0;
        double wr = -1;
        for (size_t i = 0; i < n; i++) {
            double ri = budget_ratio(got + i, ref + i, 1, atol, rtol);
            if (!(ri <= wr)) { wr = ri; worst = i; }
        }
        fail_msg("%s [%s, %d threads]: budget ratio %g at %zu: got %.9g ref %.9g", what,
                 fk_isa_name(c.isa), c.threads, r, worst, (double)got[worst], (double)ref[worst]);
    }
}

static void check_same_bits(const char *what, const float *a, const float *b, size_t n)
{
    for (size_t i = 0; i < n; i++)
        if (memcmp(&a[i], &b[i], sizeof(float)) != 0)
            fail_msg("%s: element %zu differs: %.9g vs %.9g", what, i, (double)a[i], (double)b[i]);
}

/* ---- references against exact values ----------------------------------- */

static void test_ref_known_values(void **state)
{
    (void)state;
    assert_true(fabs(fk_gelu_ref(1.0f) - 0.8413447460685429) < 1e-7);
    assert_true(fabs(fk_gelu_ref(-1.0f) + 0.15865525393145707) < 1e-8);
    assert_true(fabs(fk_gelu_ref(-10.0f) / -7.6198530241604696e-23 - 1) < 1e-7);
    assert_true(fk_gelu_ref(0.0f) == 0.0f);
    assert_true(fk_gelu_ref(INFINITY) == INFINITY);
    assert_true(fk_gelu_ref(-INFINITY) == 0.0f && signbit(fk_gelu_ref(-INFINITY)));
    assert_true(isnan(fk_gelu_ref(NAN)));
    assert_true(fk_gelu_ref(1e30f) == 1e30f);
    assert_true(fk_gelu_ref(-1e30f) == 0.0f);

    assert_true(fabs(fk_silu_ref(1.0f) - 0.7310585786300049) < 1e-7);
    assert_true(fabs(fk_silu_ref(-20.0f) / -4.1223072448771163e-08 - 1) < 1e-7);
    float s = fk_silu_ref(-100.0f);
    assert_true(!isnan(s) && s <= 0.0f && s > -1e-40f);
    assert_true(fk_silu_ref(-INFINITY) == 0.0f && signbit(fk_silu_ref(-INFINITY)));
    assert_true(fk_silu_ref(INFINITY) == INFINITY);
    assert_true(isnan(fk_silu_ref(NAN)));
}

/* ---- element-wise ------------------------------------------------------- */

typedef int (*elt_fn)(fk_ctx *, const float *, size_t, float *);

static void fill_elementwise(float *x, size_t n, uint64_t seed)
{
    struct rng r;
    rng_seed(&r, seed);
    for (size_t i = 0; i < n; i++) {
        switch (rng_u64(&r) % 4) {
        case 0:  x[i] = rng_uniform(&r, -20.0f, 20.0f); break;
        case 1:  x[i] = 3.0f * rng_normal(&r); break;
        case 2:  x[i] = rng_uniform(&r, -1.0f, 1.0f) * 1e-3f; break;
        default: x[i] = rng_uniform(&r, -100.0f, 100.0f); break;
        }
    }
}

static void check_elementwise(const char *name, elt_fn fn, double atol, double rtol)
{
    static const size_t sizes[] = { 1, 7, 8, 13, 16, 1031, 100003 };
    struct cfg cfgs[10];
    int nc = test_cfgs(cfgs);
    fk_ctx *ref = test_ctx(FK_ISA_REF, 1);
    for (size_t si = 0; si < sizeof sizes / sizeof sizes[0]; si++) {
        size_t n = sizes[si];
        float *x = xmalloc((n + 1) * sizeof *x), *want = xmalloc(n * sizeof *want);
        float *got = xmalloc((n + 1) * sizeof *got), *one = xmalloc(n * sizeof *one);
        fill_elementwise(x, n, 100 + n);
        assert_int_equal(fn(ref, x, n, want), F4D_OK);
        for (int ci = 0; ci < nc; ci++) {
            fk_ctx *ctx = test_ctx(cfgs[ci].isa, cfgs[ci].threads);
            got[n] = SENTINEL;
            assert_int_equal(fn(ctx, x, n, got), F4D_OK);
            assert_true(got[n] == SENTINEL);          /* nothing written past n */
            check_budget(name, cfgs[ci], got, want, n, atol, rtol);
            if (cfgs[ci].threads == 1 && cfgs[ci].isa != FK_ISA_REF)
                memcpy(one, got, n * sizeof *got);
            else if (cfgs[ci].isa != FK_ISA_REF)
                check_same_bits("2 threads vs 1", got, one, n);
            /* in place */
            memcpy(got, x, n * sizeof *x);
            assert_int_equal(fn(ctx, got, n, got), F4D_OK);
            check_budget(name, cfgs[ci], got, want, n, atol, rtol);
            fk_ctx_free(ctx);
        }
        free(x); free(want); free(got); free(one);
    }
    fk_ctx_free(ref);
}

static void test_gelu_vs_ref(void **state)  { (void)state; check_elementwise("gelu", fk_gelu, 1e-37, 2e-6); }
static void test_silu_vs_ref(void **state)  { (void)state; check_elementwise("silu", fk_silu, 1e-37, 1e-6); }
static void test_relu_vs_ref(void **state)  { (void)state; check_elementwise("relu", fk_relu, 0, 0); }

/* Special values through every ISA: limits at +-Inf, NaN stays in its element,
 * no NaN from exp overflow at large |x|. */
static void test_elementwise_special(void **state)
{
    (void)state;
    const float x[] = { NAN, INFINITY, -INFINITY, -100.0f, 100.0f, -10.0f, 1e30f, -1e30f,
                        -0.0f, 0.0f, FLT_MIN, -FLT_TRUE_MIN, 88.8f, -88.8f, 1.5f, -2.5f, 0.25f };
    enum { N = sizeof x / sizeof x[0] };
    struct cfg cfgs[10];
    int nc = test_cfgs(cfgs);
    cfgs[nc++] = (struct cfg){ FK_ISA_REF, 1 };
    for (int ci = 0; ci < nc; ci++) {
        fk_ctx *ctx = test_ctx(cfgs[ci].isa, cfgs[ci].threads);
        float g[N], s[N], r[N];
        assert_int_equal(fk_gelu(ctx, x, N, g), F4D_OK);
        assert_int_equal(fk_silu(ctx, x, N, s), F4D_OK);
        assert_int_equal(fk_relu(ctx, x, N, r), F4D_OK);
        assert_true(isnan(g[0]) && isnan(s[0]) && isnan(r[0]));
        for (int i = 1; i < N; i++)
            assert_true(!isnan(g[i]) && !isnan(s[i]) && !isnan(r[i]));
        assert_true(g[1] == INFINITY && s[1] == INFINITY && r[1] == INFINITY);
        assert_true(g[2] == 0.0f && s[2] == 0.0f && r[2] == 0.0f);
        assert_true(g[3] == 0.0f && s[3] <= 0.0f && s[3] > -1e-40f);   /* silu(-100) ~ -3.7e-42 */
        assert_true(g[4] == 100.0f && s[4] == 100.0f);
        assert_true(fabs(g[5] / -7.6198530241604696e-23 - 1) < 2e-6); /* gelu(-10) */
        assert_true(g[6] == 1e30f && s[6] == 1e30f && r[6] == 1e30f);
        assert_true(g[7] == 0.0f && s[7] == 0.0f && r[7] == 0.0f);
        assert_true(g[8] == 0.0f && s[8] == 0.0f && r[8] == 0.0f && signbit(r[8]));
        assert_true(r[10] == FLT_MIN && r[11] == 0.0f);
        assert_true(s[12] == 88.8f && g[12] == 88.8f);
        fk_ctx_free(ctx);
    }
}

/* ---- row-wise harness --------------------------------------------------- */

struct row_case { int rows, cols, ldx, ldy, inplace; };

typedef int (*row_op_fn)(fk_ctx *ctx, const float *x, int rows, int cols, int ldx, float *y,
                         int ldy, const void *arg);

/* Runs op on x ([rows][ldx]) with the reference and with every configuration:
 * within budget of the reference, two threads giving the same bits as one,
 * and the padding between output rows untouched. Returns the reference
 * output ([rows][ldy], ldy = ldx in place) for further checks. */
static float *check_rows_vs_ref(const char *name, row_op_fn op, const void *arg,
                                const struct row_case *rc, const float *x, double atol, double rtol)
{
    int ldy = rc->inplace ? rc->ldx : rc->ldy;
    size_t n = (size_t)(rc->rows > 0 ? rc->rows : 1) * ldy;
    float *want = xmalloc(n * sizeof *want), *got = xmalloc(n * sizeof *got);
    float *one = xmalloc(n * sizeof *one);
    struct cfg cfgs[11];
    cfgs[0] = (struct cfg){ FK_ISA_REF, 1 };
    int nc = 1 + test_cfgs(cfgs + 1);
    for (int k = 0; k < nc; k++) {
        fk_ctx *ctx = test_ctx(cfgs[k].isa, cfgs[k].threads);
        float *out = k == 0 ? want : got;
        for (size_t i = 0; i < n; i++)
            out[i] = rc->inplace ? x[i] : SENTINEL;
        assert_int_equal(op(ctx, rc->inplace ? out : x, rc->rows, rc->cols, rc->ldx, out, ldy, arg),
                         F4D_OK);
        fk_ctx_free(ctx);
        if (k == 0) {
            for (int i = 0; i < rc->rows; i++)
                for (int j = rc->cols; j < ldy; j++)
                    assert_true(want[(size_t)i * ldy + j] ==
                                (rc->inplace ? x[(size_t)i * ldy + j] : SENTINEL));
            continue;
        }
        check_budget(name, cfgs[k], got, want, n, atol, rtol);
        if (cfgs[k].threads == 1)
            memcpy(one, got, n * sizeof *got);
        else if (cfgs[k].isa != FK_ISA_REF)
            check_same_bits(name, got, one, n);
    }
    free(got);
    free(one);
    return want;
}

/* ---- layernorm ---------------------------------------------------------- */

struct ln_arg { const float *w, *b; float eps; };

static int layernorm_op(fk_ctx *ctx, const float *x, int rows, int cols, int ldx, float *y,
                        int ldy, const void *arg)
{
    const struct ln_arg *a = arg;
    return fk_layernorm(ctx, x, rows, cols, ldx, a->w, a->b, a->eps, y, ldy);
}

static void test_layernorm_vs_ref(void **state)
{
    (void)state;
    static const struct { struct row_case rc; int affine; float eps; } cases[] = {
        /* affine: 0 none, 1 w and b, 2 w only, 3 b only */
        { { 1, 1, 1, 1, 0 }, 1, 1e-5f },
        { { 1, 7, 7, 7, 0 }, 1, 1e-5f },
        { { 13, 13, 13, 13, 0 }, 0, 1e-6f },
        { { 7, 1031, 1031, 1031, 0 }, 2, 1e-5f },
        { { 5, 64, 80, 72, 0 }, 3, 1e-5f },          /* strides > cols         */
        { { 3, 1024, 1030, 1030, 1 }, 1, 1e-6f },    /* in place, padded rows  */
        { { 2, 9, 9, 9, 1 }, 0, 1e-5f },
        { { 301, 1024, 1024, 1024, 0 }, 1, 1e-6f },  /* big: runs on 2 threads */
        { { 0, 16, 16, 16, 0 }, 1, 1e-5f },          /* no rows: nothing to do */
    };
    for (size_t c = 0; c < sizeof cases / sizeof cases[0]; c++) {
        const struct row_case *rc = &cases[c].rc;
        size_t nx = (size_t)(rc->rows > 0 ? rc->rows : 1) * rc->ldx;
        float *x = xmalloc(nx * sizeof *x), *w = xmalloc(rc->cols * sizeof *w);
        float *b = xmalloc(rc->cols * sizeof *b);
        struct rng r;
        rng_seed(&r, 7 + c);
        for (size_t i = 0; i < nx; i++)
            x[i] = 2.0f * rng_normal(&r) + 0.5f;
        rng_fill_normal(&r, w, rc->cols, 1.0f);
        rng_fill_normal(&r, b, rc->cols, 1.0f);
        int affine = cases[c].affine;
        struct ln_arg arg = { affine == 1 || affine == 2 ? w : NULL,
                              affine == 1 || affine == 3 ? b : NULL, cases[c].eps };
        free(check_rows_vs_ref("layernorm", layernorm_op, &arg, rc, x, 1e-6, 1e-5));
        free(x); free(w); free(b);
    }
}

static void run_layernorm(fk_ctx *ctx, const float *x, int rows, int cols, const float *w,
                          const float *b, float eps, float *y)
{
    assert_int_equal(fk_layernorm(ctx, x, rows, cols, cols, w, b, eps, y, cols), F4D_OK);
}

/* LayerNorm written out in double, no affine part. */
static void direct_layernorm(const float *x, int n, float eps, float *y)
{
    double mean = 0, var = 0;
    for (int j = 0; j < n; j++)
        mean += x[j];
    mean /= n;
    for (int j = 0; j < n; j++)
        var += ((double)x[j] - mean) * ((double)x[j] - mean);
    var /= n;
    for (int j = 0; j < n; j++)
        y[j] = (float)(((double)x[j] - mean) / sqrt(var + eps));
}

static void test_layernorm_hard(void **state)
{
    (void)state;
    enum { C = 1031 };
    struct cfg cfgs[10];
    int nc = test_cfgs(cfgs);
    cfgs[nc++] = (struct cfg){ FK_ISA_REF, 1 };
    float *x = xmalloc(4 * C * sizeof *x), *y = xmalloc(4 * C * sizeof *y);
    float *z = xmalloc(4 * C * sizeof *z), *w = xmalloc(C * sizeof *w), *b = xmalloc(C * sizeof *b);
    struct rng r;
    rng_seed(&r, 3);
    rng_fill_normal(&r, w, C, 1.0f);
    rng_fill_normal(&r, b, C, 1.0f);
    static const float consts[] = { 0.1f, -3.7f, 1e30f, -1e-30f, 0.0f, 3e38f };
    for (int ci = 0; ci < nc; ci++) {
        fk_ctx *ctx = test_ctx(cfgs[ci].isa, cfgs[ci].threads);
        /* constant rows: output is exactly the bias, or exactly 0 without affine */
        for (size_t k = 0; k < sizeof consts / sizeof consts[0]; k++) {
            for (int j = 0; j < C; j++)
                x[j] = consts[k];
            run_layernorm(ctx, x, 1, C, w, b, 1e-5f, y);
            for (int j = 0; j < C; j++)
                assert_true(y[j] == b[j]);
            run_layernorm(ctx, x, 1, C, NULL, NULL, 1e-6f, y);
            for (int j = 0; j < C; j++)
                assert_true(y[j] == 0.0f);
        }

        /* rows scaled far from 1 against the direct formula in double, with
         * eps 0 (scale invariant) and eps 1e-5 (which then dominates) */
        rng_seed(&r, 5);
        rng_fill_normal(&r, z, C, 1.0f);
        static const float scales[] = { 1e30f, 1e-30f, 1e-18f, 1e36f, 0x1p-140f };
        for (size_t k = 0; k < sizeof scales / sizeof scales[0]; k++) {
            for (int j = 0; j < C; j++)
                x[j] = z[j] * scales[k];
            for (int e = 0; e < 2; e++) {
                float eps = e ? 1e-5f : 0.0f;
                direct_layernorm(x, C, eps, z + C);
                run_layernorm(ctx, x, 1, C, NULL, NULL, eps, y);
                double big = 0;
                for (int j = 0; j < C; j++)
                    big = isnan(z[C + j]) || isnan(big) ? NAN : fmax(big, fabs(z[C + j]));
                assert_true(big > 0 && budget_ratio(y, z + C, C, 1e-6 * big, 1e-5) <= 1.0);
            }
        }
        /* values near FLT_MAX of both signs: no overflow in mean or variance */
        for (int j = 0; j < C; j++)
            x[j] = (j & 1) ? 3e38f : -3e38f;
        run_layernorm(ctx, x, 1, C, NULL, NULL, 1e-5f, y);
        for (int j = 0; j < C; j++)
            assert_true(isfinite(y[j]) && fabs(fabs(y[j]) - 1.0) < 1e-3);

        /* NaN / Inf rows: only that row turns non-finite */
        for (int i = 0; i < 4; i++)
            for (int j = 0; j < C; j++)
                x[i * C + j] = z[j] + (float)i;
        x[1 * C + 500] = NAN;
        x[2 * C + 0] = INFINITY;
        run_layernorm(ctx, x, 4, C, w, b, 1e-5f, y);
        for (int j = 0; j < C; j++) {
            assert_true(isfinite(y[j]) && isfinite(y[3 * C + j]));
            assert_true(isnan(y[C + j]) && isnan(y[2 * C + j]));
        }
        fk_ctx_free(ctx);
    }
    free(x); free(y); free(z); free(w); free(b);
}

/* ---- softmax ------------------------------------------------------------ */

static int softmax_op(fk_ctx *ctx, const float *x, int rows, int cols, int ldx, float *y,
                      int ldy, const void *arg)
{
    (void)arg;
    return fk_softmax(ctx, x, rows, cols, ldx, y, ldy);
}

static void test_softmax_vs_ref(void **state)
{
    (void)state;
    static const struct { struct row_case rc; float scale; } cases[] = {
        { { 1, 1, 1, 1, 0 }, 1.0f },
        { { 1, 7, 7, 7, 0 }, 3.0f },
        { { 13, 13, 16, 13, 0 }, 1.0f },
        { { 7, 1031, 1031, 1040, 0 }, 10.0f },
        { { 3, 100, 100, 100, 1 }, 30.0f },
        { { 64, 1374, 1374, 1374, 0 }, 4.0f },   /* an attention row length, 2 threads */
        { { 0, 5, 5, 5, 0 }, 1.0f },
    };
    for (size_t c = 0; c < sizeof cases / sizeof cases[0]; c++) {
        const struct row_case *rc = &cases[c].rc;
        size_t nx = (size_t)(rc->rows > 0 ? rc->rows : 1) * rc->ldx;
        float *x = xmalloc(nx * sizeof *x);
        struct rng r;
        rng_seed(&r, 40 + c);
        rng_fill_normal(&r, x, nx, cases[c].scale);
        float *want = check_rows_vs_ref("softmax", softmax_op, NULL, rc, x, 1e-37, 1e-5);
        int ldy = rc->inplace ? rc->ldx : rc->ldy;
        for (int i = 0; i < rc->rows; i++) {   /* the reference's rows sum to 1 */
            double sum = 0;
            for (int j = 0; j < rc->cols; j++)
                sum += want[(size_t)i * ldy + j];
            assert_true(fabs(sum - 1) < 1e-6);
        }
        free(want);
        free(x);
    }
}

static void test_softmax_hard(void **state)
{
    (void)state;
    enum { C = 13 };
    struct cfg cfgs[10];
    int nc = test_cfgs(cfgs);
    cfgs[nc++] = (struct cfg){ FK_ISA_REF, 1 };
    for (int ci = 0; ci < nc; ci++) {
        fk_ctx *ctx = test_ctx(cfgs[ci].isa, cfgs[ci].threads);
        float x[6][C], y[6][C];
        for (int j = 0; j < C; j++) {
            x[0][j] = (j == 5) ? 1e4f : -1e4f;          /* one-hot, exactly          */
            x[1][j] = (j == 2 || j == 11) ? 1e4f : -1e4f; /* two maxima: exactly 1/2 */
            x[2][j] = 42.0f;                            /* all equal: uniform        */
            x[3][j] = (j == 0) ? 0.0f : -INFINITY;      /* masked: exactly one-hot   */
            x[4][j] = (float)j;
            x[5][j] = (float)-j;
        }
        x[4][7] = NAN;                                  /* NaN: that row only        */
        assert_int_equal(fk_softmax(ctx, &x[0][0], 6, C, C, &y[0][0], C), F4D_OK);
        for (int j = 0; j < C; j++) {
            assert_true(y[0][j] == (j == 5 ? 1.0f : 0.0f));
            assert_true(y[1][j] == (j == 2 || j == 11 ? 0.5f : 0.0f));
            assert_true(y[2][j] == 1.0f / C);
            assert_true(y[3][j] == (j == 0 ? 1.0f : 0.0f));
            assert_true(isnan(y[4][j]));
            assert_true(isfinite(y[5][j]) && y[5][j] > 0);
        }
        /* a single column is always 1; an all -Inf row is NaN (0/0), as +Inf is */
        float one[3] = { -1e30f, -INFINITY, INFINITY }, o[3];
        assert_int_equal(fk_softmax(ctx, one, 3, 1, 1, o, 1), F4D_OK);
        assert_true(o[0] == 1.0f && isnan(o[1]) && isnan(o[2]));
        /* uniform rows of every length up to 40 */
        for (int n = 1; n <= 40; n++) {
            float u[40], v[40];
            for (int j = 0; j < n; j++)
                u[j] = -7.25f;
            assert_int_equal(fk_softmax(ctx, u, 1, n, n, v, n), F4D_OK);
            for (int j = 0; j < n; j++)
                assert_true(v[j] == 1.0f / (float)n);
        }
        fk_ctx_free(ctx);
    }
}

/* ---- residual add ------------------------------------------------------- */

static void test_residual_vs_ref(void **state)
{
    (void)state;
    static const int shapes[][4] = { /* rows, cols, ldx, ldr */
        { 1, 1, 1, 1 }, { 1, 7, 7, 7 }, { 13, 13, 20, 13 }, { 7, 1031, 1031, 1035 },
        { 600, 1024, 1024, 1024 }, { 0, 3, 3, 3 },
    };
    struct cfg cfgs[10];
    int nc = test_cfgs(cfgs);
    for (size_t si = 0; si < sizeof shapes / sizeof shapes[0]; si++) {
        int rows = shapes[si][0], cols = shapes[si][1], ldx = shapes[si][2], ldr = shapes[si][3];
        size_t nx = (size_t)(rows ? rows : 1) * ldx, nr = (size_t)(rows ? rows : 1) * ldr;
        float *x = xmalloc(nx * sizeof *x), *r = xmalloc(nr * sizeof *r);
        float *g = xmalloc(cols * sizeof *g), *want = xmalloc(nx * sizeof *want);
        float *got = xmalloc(nx * sizeof *got);
        struct rng rg;
        rng_seed(&rg, 60 + si);
        rng_fill_normal(&rg, x, nx, 1.0f);
        rng_fill_normal(&rg, r, nr, 1.0f);
        rng_fill(&rg, g, cols, 0.0f, 0.1f);
        for (int gamma = 0; gamma < 2; gamma++) {
            for (int self = 0; self < 2; self++) {  /* self: x += gamma (.) x */
                if (self && ldx != ldr)
                    continue;
                fk_ctx *ref = test_ctx(FK_ISA_REF, 1);
                memcpy(want, x, nx * sizeof *x);
                assert_int_equal(fk_residual_add(ref, want, ldx, self ? want : r, ldr,
                                                 gamma ? g : NULL, rows, cols), F4D_OK);
                fk_ctx_free(ref);
                for (int i = 0; i < rows; i++) /* spot check the definition */
                    assert_true(want[(size_t)i * ldx] ==
                                x[(size_t)i * ldx] + (gamma ? g[0] : 1.0f) *
                                (self ? x[(size_t)i * ldx] : r[(size_t)i * ldr]));
                for (int k = 0; k < nc; k++) {
                    fk_ctx *ctx = test_ctx(cfgs[k].isa, cfgs[k].threads);
                    memcpy(got, x, nx * sizeof *x);
                    assert_int_equal(fk_residual_add(ctx, got, ldx, self ? got : r, ldr,
                                                     gamma ? g : NULL, rows, cols), F4D_OK);
                    check_same_bits("residual add", got, want, nx);
                    fk_ctx_free(ctx);
                }
            }
        }
        free(x); free(r); free(g); free(want); free(got);
    }
}

/* ---- bad arguments ------------------------------------------------------ */

static void expect_einval(fk_ctx *ctx, int st, const char *needle)
{
    assert_int_equal(st, F4D_EINVAL);
    if (!strstr(fk_ctx_error(ctx), needle))
        fail_msg("error \"%s\" does not mention \"%s\"", fk_ctx_error(ctx), needle);
}

static void test_bad_arguments(void **state)
{
    (void)state;
    fk_ctx *ctx = test_ctx(FK_ISA_AUTO, 1);
    float a[64] = { 0 }, b[64] = { 0 };

    assert_int_equal(fk_gelu(NULL, a, 4, b), F4D_EINVAL);
    assert_int_equal(fk_layernorm(NULL, a, 1, 4, 4, NULL, NULL, 1e-5f, b, 4), F4D_EINVAL);
    assert_int_equal(fk_softmax(NULL, a, 1, 4, 4, b, 4), F4D_EINVAL);
    assert_int_equal(fk_residual_add(NULL, a, 4, b, 4, NULL, 1, 4), F4D_EINVAL);

    assert_int_equal(fk_gelu(ctx, NULL, 0, NULL), F4D_OK);      /* empty: nothing to do */
    expect_einval(ctx, fk_gelu(ctx, NULL, 4, b), "x is NULL");
    expect_einval(ctx, fk_silu(ctx, a, 4, NULL), "y is NULL");
    expect_einval(ctx, fk_relu(ctx, a, 8, a + 1), "overlap");

    expect_einval(ctx, fk_layernorm(ctx, a, -1, 4, 4, NULL, NULL, 1e-5f, b, 4), "rows=-1");
    expect_einval(ctx, fk_layernorm(ctx, a, 1, 0, 4, NULL, NULL, 1e-5f, b, 4), "cols=0");
    expect_einval(ctx, fk_layernorm(ctx, a, 2, 8, 7, NULL, NULL, 1e-5f, b, 8), "ldx=7");
    expect_einval(ctx, fk_layernorm(ctx, a, 2, 8, 8, NULL, NULL, 1e-5f, b, 4), "ldy=4");
    expect_einval(ctx, fk_layernorm(ctx, NULL, 2, 8, 8, NULL, NULL, 1e-5f, b, 8), "x is NULL");
    expect_einval(ctx, fk_layernorm(ctx, a, 2, 8, 8, NULL, NULL, 1e-5f, NULL, 8), "y is NULL");
    expect_einval(ctx, fk_layernorm(ctx, a, 2, 8, 8, NULL, NULL, -1.0f, b, 8), "eps");
    expect_einval(ctx, fk_layernorm(ctx, a, 2, 8, 8, NULL, NULL, NAN, b, 8), "eps");
    expect_einval(ctx, fk_layernorm(ctx, a, 2, 8, 8, NULL, NULL, 1e-5f, a, 16), "overlap");
    expect_einval(ctx, fk_layernorm(ctx, a, 2, 8, 8, NULL, NULL, 1e-5f, a + 4, 8), "overlap");
    assert_int_equal(fk_layernorm(ctx, a, 2, 8, 8, NULL, NULL, 1e-5f, a, 8), F4D_OK);  /* in place */
    assert_int_equal(fk_layernorm(ctx, NULL, 0, 8, 8, NULL, NULL, 1e-5f, NULL, 8), F4D_OK);

    expect_einval(ctx, fk_softmax(ctx, a, -3, 4, 4, b, 4), "rows=-3");
    expect_einval(ctx, fk_softmax(ctx, a, 1, 0, 0, b, 0), "cols=0");
    expect_einval(ctx, fk_softmax(ctx, a, 3, 5, 4, b, 5), "ldx=4");
    expect_einval(ctx, fk_softmax(ctx, a, 3, 5, 5, NULL, 5), "y is NULL");

    expect_einval(ctx, fk_residual_add(ctx, a, 4, b, 4, NULL, 1, -2), "cols=-2");
    expect_einval(ctx, fk_residual_add(ctx, a, 3, b, 4, NULL, 2, 4), "ldx=3");
    expect_einval(ctx, fk_residual_add(ctx, a, 4, b, 2, NULL, 2, 4), "ldr=2");
    expect_einval(ctx, fk_residual_add(ctx, NULL, 4, b, 4, NULL, 2, 4), "x is NULL");
    expect_einval(ctx, fk_residual_add(ctx, a, 4, NULL, 4, NULL, 2, 4), "r is NULL");
    expect_einval(ctx, fk_residual_add(ctx, a, 4, a + 2, 4, NULL, 2, 4), "overlap");
    fk_ctx_free(ctx);
}

int main(int argc, char **argv)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_ref_known_values),
        cmocka_unit_test(test_gelu_vs_ref),
        cmocka_unit_test(test_silu_vs_ref),
        cmocka_unit_test(test_relu_vs_ref),
        cmocka_unit_test(test_elementwise_special),
        cmocka_unit_test(test_layernorm_vs_ref),
        cmocka_unit_test(test_layernorm_hard),
        cmocka_unit_test(test_softmax_vs_ref),
        cmocka_unit_test(test_softmax_hard),
        cmocka_unit_test(test_residual_vs_ref),
        cmocka_unit_test(test_bad_arguments),
    };
    return KERNEL_TEST_MAIN(argc, argv, "kernels/ops", tests);
}
