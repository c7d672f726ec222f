/* fk_resize: bilinear (align_corners true and false) and the antialiased
 * bicubic of vggt.md 2 against direct formulas in double, hand-computed
 * weights, identity and edge cases, and bad arguments.
 *
 * Error budgets:
 *   reference vs direct double formula   |err| <= 1e-6 + 1e-6 |y| (N(0,1) data;
 *                                         float weights and float accumulation)
 *   optimized ISAs vs reference          exact (same operations, same order)
 *   extracted bicubic weights vs hand    1e-7 (the float weights themselves)
 * Two threads must give the same bits as one. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fk_resize.h"
#include "test_util.h"

struct cfg { enum fk_isa isa; int threads; };

static int test_cfgs(struct cfg out[10])
{
    enum fk_isa isas[4];
    int n = test_isas(isas), k = 0;
    out[k++] = (struct cfg){ FK_ISA_REF, 1 };
    out[k++] = (struct cfg){ FK_ISA_REF, 2 };
    for (int i = 0; i < n; i++) {
        out[k++] = (struct cfg){ isas[i], 1 };
        out[k++] = (struct cfg){ isas[i], 2 };
    }
    return k;
}

/* ---- direct formulas in double ------------------------------------------ */

static void bilinear_src(int n_in, int n_out, int align, int i, int *i0, int *i1, double *l)
{
    double src = align ? (n_out > 1 ? (double)i * (n_in - 1) / (n_out - 1) : 0.0)
                       : fmax((i + 0.5) * n_in / n_out - 0.5, 0.0);
    *i0 = (int)floor(src);
    if (*i0 > n_in - 1)
        *i0 = n_in - 1;
    *i1 = *i0 + 1 < n_in ? *i0 + 1 : n_in - 1;
    *l = src - *i0;
}

static void direct_bilinear(const float *x, int h, int w, int c, float *y, int ho, int wo, int align)
{
    for (int i = 0; i < ho; i++) {
        int y0, y1;
        double ly;
        bilinear_src(h, ho, align, i, &y0, &y1, &ly);
        for (int j = 0; j < wo; j++) {
            int x0, x1;
            double lx;
            bilinear_src(w, wo, align, j, &x0, &x1, &lx);
            for (int k = 0; k < c; k++) {
                double a = x[((size_t)y0 * w + x0) * c + k], b = x[((size_t)y0 * w + x1) * c + k];
                double d = x[((size_t)y1 * w + x0) * c + k], e = x[((size_t)y1 * w + x1) * c + k];
                y[((size_t)i * wo + j) * c + k] =
                    (float)((1 - ly) * ((1 - lx) * a + lx * b) + ly * ((1 - lx) * d + lx * e));
            }
        }
    }
}

static double cubic(double t)
{
    const double a = -0.5;
    t = fabs(t);
    if (t < 1)
        return ((a + 2) * t - (a + 3)) * t * t + 1;
    if (t < 2)
        return a * (t * t * t - 5 * t * t + 8 * t - 4);
    return 0;
}

/* The n_out x n_in weight matrix of vggt.md 2, written out again. */
static double *aa_matrix(int n_in, int n_out)
{
    double *m = xmalloc((size_t)n_in * n_out * sizeof *m);
    double s = (double)n_in / n_out;
    double support = s >= 1 ? 2 * s : 2, inv = s >= 1 ? 1 / s : 1;
    for (int i = 0; i < n_out; i++) {
        double center = s * (i + 0.5), total = 0;
        int lo = (int)floor(center - support + 0.5), hi = (int)floor(center + support + 0.5);
        lo = lo < 0 ? 0 : lo;
        hi = hi > n_in ? n_in : hi;
        for (int j = lo; j < hi; j++)
            total += m[(size_t)i * n_in + j] = cubic((j - center + 0.5) * inv);
        for (int j = lo; j < hi; j++)
            m[(size_t)i * n_in + j] /= total;
    }
    return m;
}

static void direct_bicubic_aa(const float *x, int h, int w, int c, float *y, int ho, int wo)
{
    double *mh = aa_matrix(h, ho), *mw = aa_matrix(w, wo);
    for (int i = 0; i < ho; i++)
        for (int j = 0; j < wo; j++)
            for (int k = 0; k < c; k++) {
                double acc = 0;
                for (int a = 0; a < h; a++)
                    for (int b = 0; b < w; b++)
                        acc += mh[(size_t)i * h + a] * mw[(size_t)j * w + b] *
                               x[((size_t)a * w + b) * c + k];
                y[((size_t)i * wo + j) * c + k] = (float)acc;
            }
    free(mh);
    free(mw);
}

/* ---- harness ------------------------------------------------------------ */

typedef int (*resize_fn)(fk_ctx *, const float *, int, int, int, float *, int, int, int);

static int bicubic_as_fn(fk_ctx *ctx, const float *x, int h, int w, int c, float *y, int ho,
                         int wo, int unused)
{
    (void)unused;
    return fk_resize_bicubic_aa(ctx, x, h, w, c, y, ho, wo);
}

/* Runs every configuration: the reference within budget of `direct`, every
 * other configuration bit-identical to the reference. */
static void check_resize(const char *name, resize_fn fn, int align, int h, int w, int c, int ho,
                         int wo, const float *direct, const float *x)
{
    size_t ny = (size_t)ho * wo * c;
    float *ref = xmalloc((ny + 1) * sizeof *ref), *got = xmalloc((ny + 1) * sizeof *got);
    struct cfg cfgs[10];
    int nc = test_cfgs(cfgs);
    for (int k = 0; k < nc; k++) {
        fk_ctx *ctx = test_ctx(cfgs[k].isa, cfgs[k].threads);
        float *out = k == 0 ? ref : got;
        out[ny] = 12345.0f;
        assert_int_equal(fn(ctx, x, h, w, c, out, ho, wo, align), F4D_OK);
        assert_true(out[ny] == 12345.0f);
        if (k == 0) {
            double r = budget_ratio(ref, direct, ny, 1e-6, 1e-6);
            if (!(r <= 1.0))
                fail_msg("%s %dx%dx%d -> %dx%d align=%d: reference vs direct formula ratio %g", name,
                         h, w, c, ho, wo, align, r);
        } else if (memcmp(ref, got, ny * sizeof *got) != 0) {
            fail_msg("%s %dx%dx%d -> %dx%d align=%d: %s with %d threads differs from the reference",
                     name, h, w, c, ho, wo, align, fk_isa_name(cfgs[k].isa), cfgs[k].threads);
        }
        fk_ctx_free(ctx);
    }
    free(ref);
    free(got);
}

static float *random_image(int h, int w, int c, uint64_t seed)
{
    size_t n = (size_t)h * w * c;
    float *x = xmalloc(n * sizeof *x);
    struct rng r;
    rng_seed(&r, seed);
    rng_fill_normal(&r, x, n, 1.0f);
    return x;
}

static const int shapes[][5] = { /* h, w, c, ho, wo */
    { 1, 1, 1, 3, 3 },    { 5, 7, 3, 11, 4 },    { 4, 6, 13, 1, 1 },   { 7, 13, 9, 29, 5 },
    { 37, 37, 8, 74, 74 }, { 19, 19, 33, 37, 37 }, { 3, 2, 256, 8, 5 }, { 37, 37, 1, 28, 37 },
    { 6, 6, 17, 6, 6 },   { 2, 9, 40, 7, 9 },
};

static void test_bilinear_vs_direct(void **state)
{
    (void)state;
    for (size_t s = 0; s < sizeof shapes / sizeof shapes[0]; s++) {
        int h = shapes[s][0], w = shapes[s][1], c = shapes[s][2], ho = shapes[s][3], wo = shapes[s][4];
        float *x = random_image(h, w, c, 10 + s);
        float *d = xmalloc((size_t)ho * wo * c * sizeof *d);
        for (int align = 0; align < 2; align++) {
            direct_bilinear(x, h, w, c, d, ho, wo, align);
            check_resize("bilinear", fk_resize_bilinear, align, h, w, c, ho, wo, d, x);
        }
        free(x);
        free(d);
    }
}

static void test_bicubic_aa_vs_direct(void **state)
{
    (void)state;
    for (size_t s = 0; s < sizeof shapes / sizeof shapes[0]; s++) {
        int h = shapes[s][0], w = shapes[s][1], c = shapes[s][2], ho = shapes[s][3], wo = shapes[s][4];
        float *x = random_image(h, w, c, 30 + s);
        float *d = xmalloc((size_t)ho * wo * c * sizeof *d);
        direct_bicubic_aa(x, h, w, c, d, ho, wo);
        check_resize("bicubic_aa", bicubic_as_fn, 0, h, w, c, ho, wo, d, x);
        free(x);
        free(d);
    }
    /* the position-embedding case of a 518 x 392 input: 37 x 37 x 64 -> 28 x 37,
     * and a downscale on both axes (image preprocessing) */
    static const int big[][5] = { { 37, 37, 64, 28, 37 }, { 50, 61, 3, 20, 23 } };
    for (size_t s = 0; s < 2; s++) {
        int h = big[s][0], w = big[s][1], c = big[s][2], ho = big[s][3], wo = big[s][4];
        float *x = random_image(h, w, c, 77 + s);
        float *d = xmalloc((size_t)ho * wo * c * sizeof *d);
        direct_bicubic_aa(x, h, w, c, d, ho, wo);
        check_resize("bicubic_aa", bicubic_as_fn, 0, h, w, c, ho, wo, d, x);
        free(x);
        free(d);
    }
}

/* Weight matrix of one axis as the kernel applies it: resize n_in one-hot
 * channels along w (axis 0) or h (axis 1). */
static float *extract_weights(fk_ctx *ctx, int n_in, int n_out, int axis)
{
    float *x = xmalloc((size_t)n_in * n_in * sizeof *x);
    float *y = xmalloc((size_t)n_out * n_in * sizeof *y);
    for (int j = 0; j < n_in; j++)
        x[(size_t)j * n_in + j] = 1.0f;   /* pixel j, channel j */
    if (axis == 0)
        assert_int_equal(fk_resize_bicubic_aa(ctx, x, 1, n_in, n_in, y, 1, n_out), F4D_OK);
    else
        assert_int_equal(fk_resize_bicubic_aa(ctx, x, n_in, 1, n_in, y, n_out, 1), F4D_OK);
    free(x);
    return y;   /* y[i * n_in + j] = weight of input j in output i */
}

static void test_bicubic_aa_weights(void **state)
{
    (void)state;
    /* 5 -> 7, output 0: center 5/14, taps t = 1/7 and 8/7:
     * k(1/7) = 327/343, k(8/7) = -18/343, normalised 327/309 and -18/309. */
    static const struct { int n_in, n_out, i, first, n; double w[8]; } hand[] = {
        { 5, 7, 0, 0, 2, { 327.0 / 309, -18.0 / 309 } },
        { 5, 7, 3, 2, 1, { 1.0 } },     /* center 2.5: pixel 2 exactly */
        { 37, 28, 0, 0, 3, { 0.760957175, 0.296139042, -0.057096216 } },
        { 37, 28, 13, 15, 5, { -0.015337203, -0.004961571, 0.649366187, 0.424444744, -0.053512157 } },
        { 37, 20, 0, 0, 5, { 0.512643416, 0.464796212, 0.065705507, -0.041913945, -0.001231189 } },
        { 37, 20, 10, 16, 7, { -0.027496991, -0.010063088, 0.303347908, 0.537123233, 0.242769755,
                               -0.025302448, -0.020378369 } },
    };
    static const int pairs[][2] = { { 37, 28 }, { 5, 7 }, { 37, 20 }, { 37, 45 }, { 37, 50 },
                                    { 28, 28 }, { 1, 4 }, { 100, 3 } };
    struct cfg cfgs[10];
    int nc = test_cfgs(cfgs);
    for (int k = 0; k < nc; k++) {
        fk_ctx *ctx = test_ctx(cfgs[k].isa, cfgs[k].threads);
        for (size_t p = 0; p < sizeof pairs / sizeof pairs[0]; p++) {
            int n_in = pairs[p][0], n_out = pairs[p][1];
            double *m = aa_matrix(n_in, n_out);
            for (int axis = 0; axis < 2; axis++) {
                float *wk = extract_weights(ctx, n_in, n_out, axis);
                for (int i = 0; i < n_out; i++) {
                    double sum = 0;
                    for (int j = 0; j < n_in; j++) {
                        double e = m[(size_t)i * n_in + j], g = wk[(size_t)i * n_in + j];
                        if (fabs(g - e) > 1e-7)
                            fail_msg("%d -> %d axis %d: w[%d][%d] = %.9f, expected %.9f", n_in,
                                     n_out, axis, i, j, g, e);
                        sum += g;
                    }
                    assert_true(fabs(sum - 1) < 1e-6);   /* normalised to sum 1 */
                }
                for (size_t t = 0; t < sizeof hand / sizeof hand[0]; t++) {
                    if (hand[t].n_in != n_in || hand[t].n_out != n_out)
                        continue;
                    for (int j = 0; j < n_in; j++) {
                        int o = j - hand[t].first;
                        double e = (o >= 0 && o < hand[t].n) ? hand[t].w[o] : 0.0;
                        assert_true(fabs(wk[(size_t)hand[t].i * n_in + j] - e) < 2e-7);
                    }
                }
                free(wk);
            }
            free(m);
        }
        fk_ctx_free(ctx);
    }
}

static void test_identity_and_constants(void **state)
{
    (void)state;
    struct cfg cfgs[10];
    int nc = test_cfgs(cfgs);
    enum { H = 9, W = 11, C = 13 };
    float *x = random_image(H, W, C, 5);
    float *y = xmalloc((size_t)8 * H * W * C * sizeof *y);
    x[(4 * W + 5) * C + 3] = NAN;           /* stays in its own pixel under identity */
    x[(1 * W + 2) * C + 0] = INFINITY;
    for (int k = 0; k < nc; k++) {
        fk_ctx *ctx = test_ctx(cfgs[k].isa, cfgs[k].threads);
        for (int align = 0; align < 2; align++) {
            assert_int_equal(fk_resize_bilinear(ctx, x, H, W, C, y, H, W, align), F4D_OK);
            assert_true(budget_ratio(y, x, (size_t)H * W * C, 0, 0) == 0);
        }
        assert_int_equal(fk_resize_bicubic_aa(ctx, x, H, W, C, y, H, W), F4D_OK);
        assert_true(budget_ratio(y, x, (size_t)H * W * C, 0, 0) == 0);
        /* one identity axis: the other axis only, no mixing along the first */
        assert_int_equal(fk_resize_bicubic_aa(ctx, x, H, W, C, y, 2 * H, W), F4D_OK);
        for (int i = 0; i < 2 * H; i++)
            for (int j = 0; j < W; j++)
                for (int ch = 0; ch < C; ch++)
                    if (!((j == 5 && ch == 3) || (j == 2 && ch == 0)))
                        assert_true(isfinite(y[((size_t)i * W + j) * C + ch]));

        /* constant images stay constant; a 1 x 1 image fills the output */
        float cst[4 * 5 * 3], one[3] = { 2.5f, -1.0f, 7.0f };
        for (int i = 0; i < 4 * 5 * 3; i++)
            cst[i] = one[i % 3];
        for (int align = 0; align < 2; align++) {
            assert_int_equal(fk_resize_bilinear(ctx, cst, 4, 5, 3, y, 13, 2, align), F4D_OK);
            for (int i = 0; i < 13 * 2 * 3; i++)
                assert_true(fabsf(y[i] - one[i % 3]) <= 1e-6f * fabsf(one[i % 3]));
            assert_int_equal(fk_resize_bilinear(ctx, one, 1, 1, 3, y, 4, 6, align), F4D_OK);
            for (int i = 0; i < 4 * 6 * 3; i++)
                assert_true(y[i] == one[i % 3]);
        }
        assert_int_equal(fk_resize_bicubic_aa(ctx, cst, 4, 5, 3, y, 13, 2), F4D_OK);
        for (int i = 0; i < 13 * 2 * 3; i++)
            assert_true(fabsf(y[i] - one[i % 3]) <= 1e-6f * fabsf(one[i % 3]));
        assert_int_equal(fk_resize_bicubic_aa(ctx, one, 1, 1, 3, y, 4, 6), F4D_OK);
        for (int i = 0; i < 4 * 6 * 3; i++)
            assert_true(fabsf(y[i] - one[i % 3]) <= 1e-6f * fabsf(one[i % 3]));

        /* align_corners = 1 hits the corners exactly */
        assert_int_equal(fk_resize_bilinear(ctx, x, H, W, C, y, 3 * H - 1, 2 * W + 3, 1), F4D_OK);
        for (int ch = 0; ch < C; ch++) {
            size_t wo = 2 * W + 3, last = (size_t)(3 * H - 2) * wo;
            assert_true(y[ch] == x[ch]);
            assert_true(y[(wo - 1) * C + ch] == x[(W - 1) * C + ch]);
            assert_true(y[last * C + ch] == x[(size_t)(H - 1) * W * C + ch]);
        }
        fk_ctx_free(ctx);
    }
    free(x);
    free(y);
}

/* A NaN pixel spoils only the outputs whose taps reach it. */
static void test_nan_stays_local(void **state)
{
    (void)state;
    enum { H = 20, W = 20, C = 9 };
    float *x = random_image(H, W, C, 9);
    float *y = xmalloc((size_t)40 * 40 * C * sizeof *y);
    x[(10 * W + 10) * C + 4] = NAN;
    struct cfg cfgs[10];
    int nc = test_cfgs(cfgs);
    for (int k = 0; k < nc; k++) {
        fk_ctx *ctx = test_ctx(cfgs[k].isa, cfgs[k].threads);
        for (int f = 0; f < 3; f++) {
            int st = f < 2 ? fk_resize_bilinear(ctx, x, H, W, C, y, 40, 40, f)
                           : fk_resize_bicubic_aa(ctx, x, H, W, C, y, 40, 40);
            assert_int_equal(st, F4D_OK);
            int nan_count = 0;
            for (int i = 0; i < 40; i++)
                for (int j = 0; j < 40; j++)
                    for (int ch = 0; ch < C; ch++) {
                        float v = y[((size_t)i * 40 + j) * C + ch];
                        if (isnan(v)) {
                            nan_count++;
                            assert_int_equal(ch, 4);
                            assert_true(abs(i - 20) <= 5 && abs(j - 20) <= 5);
                        }
                    }
            assert_true(nan_count > 0);
        }
        fk_ctx_free(ctx);
    }
    free(x);
    free(y);
}

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
    assert_int_equal(fk_resize_bilinear(NULL, a, 2, 2, 1, b, 2, 2, 0), F4D_EINVAL);
    assert_int_equal(fk_resize_bicubic_aa(NULL, a, 2, 2, 1, b, 2, 2), F4D_EINVAL);
    expect_einval(ctx, fk_resize_bilinear(ctx, NULL, 2, 2, 1, b, 2, 2, 0), "x is NULL");
    expect_einval(ctx, fk_resize_bilinear(ctx, a, 2, 2, 1, NULL, 2, 2, 1), "y is NULL");
    expect_einval(ctx, fk_resize_bilinear(ctx, a, 0, 2, 1, b, 2, 2, 0), "h=0");
    expect_einval(ctx, fk_resize_bilinear(ctx, a, 2, -1, 1, b, 2, 2, 0), "w=-1");
    expect_einval(ctx, fk_resize_bilinear(ctx, a, 2, 2, 0, b, 2, 2, 0), "c=0");
    expect_einval(ctx, fk_resize_bilinear(ctx, a, 2, 2, 1, b, 0, 2, 0), "ho=0");
    expect_einval(ctx, fk_resize_bilinear(ctx, a, 2, 2, 1, b, 2, -5, 0), "wo=-5");
    expect_einval(ctx, fk_resize_bilinear(ctx, a, 2, 2, 1, b, 2, 2, 2), "align_corners=2");
    expect_einval(ctx, fk_resize_bilinear(ctx, a, 2, 2, 1, a + 2, 2, 2, 0), "overlap");
    expect_einval(ctx, fk_resize_bicubic_aa(ctx, NULL, 2, 2, 1, b, 2, 2), "x is NULL");
    expect_einval(ctx, fk_resize_bicubic_aa(ctx, a, 2, 2, 1, NULL, 3, 3), "y is NULL");
    expect_einval(ctx, fk_resize_bicubic_aa(ctx, a, 2, 0, 1, b, 2, 2), "w=0");
    expect_einval(ctx, fk_resize_bicubic_aa(ctx, a, 2, 2, 1, b, 2, 0), "wo=0");
    expect_einval(ctx, fk_resize_bicubic_aa(ctx, a, 4, 4, 1, a, 2, 2), "overlap");
    /* a frozen context without scratch reports F4D_ENOMEM instead of allocating */
    fk_ctx *frozen = test_ctx(FK_ISA_AUTO, 1);
    fk_ctx_freeze(frozen, 1);
    assert_int_equal(fk_resize_bicubic_aa(frozen, a, 4, 4, 2, b, 3, 3), F4D_ENOMEM);
    fk_ctx_freeze(frozen, 0);
    assert_int_equal(fk_resize_bicubic_aa(frozen, a, 4, 4, 2, b, 3, 3), F4D_OK);
    fk_ctx_freeze(frozen, 1);
    assert_int_equal(fk_resize_bicubic_aa(frozen, a, 4, 4, 2, b, 3, 3), F4D_OK);
    fk_ctx_free(frozen);
    fk_ctx_free(ctx);
}

int main(int argc, char **argv)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_bilinear_vs_direct),
        cmocka_unit_test(test_bicubic_aa_vs_direct),
        cmocka_unit_test(test_bicubic_aa_weights),
        cmocka_unit_test(test_identity_and_constants),
        cmocka_unit_test(test_nan_stays_local),
        cmocka_unit_test(test_bad_arguments),
    };
    return KERNEL_TEST_MAIN(argc, argv, "kernels/resize", tests);
}
