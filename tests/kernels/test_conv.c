/* fk_conv: the GEMM-based convolutions against the direct loops, for every
 * ISA and weight type, on the shapes the model uses (1x1, 3x3 stride 1 and 2,
 * 14x14 patchify, transposed k = 2 and 4) at awkward sizes.
 *
 * Error budget per output, relative to S = sum |x w| + |b|:
 *   f32 weights: 1e-5 S; f16 weights: 1e-3 S; int8 weights and activations:
 *   the rounding bound Q = sum (ex |w| + ew |x| + ex ew) + 1e-5 S, where ex and ew
 *   are half a step of the row's and the channel's int8 grid (amax / 254; the
 *   7-bit weights of CPUs without VNNI: ew = amax / 126). Transposed convs:
 *   2e-2 S for int8, 4e-2 S for 7-bit weights (half the weight resolution). */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "fk_conv.h"
#include "test_util.h"

static const double budget[3] = { 1e-5, 1e-3, 2e-2 };
static const double budget_q7 = 4e-2;

/* S per output of a conv, computed like the reference with |.| */
static void conv_scale(const float *x, int h, int w, int cin, const float *wt, const float *b,
                       int cout, int kh, int kw, int stride, int pad, double *s, double *q,
                       double *q7)
{
    int ho = (h + 2 * pad - kh) / stride + 1, wo = (w + 2 * pad - kw) / stride + 1;
    for (int oy = 0; oy < ho; oy++)
        for (int ox = 0; ox < wo; ox++)
            for (int o = 0; o < cout; o++) {
                double acc = b ? fabs(b[o]) : 0, ex = 0, ew = 0, qb = 0, ew7 = 0, qb7 = 0;
                for (int pass = 0; pass < 2; pass++)
                    for (int i = 0; i < cin; i++)
                        for (int ky = 0; ky < kh; ky++)
                            for (int kx = 0; kx < kw; kx++) {
                                int iy = oy * stride - pad + ky, ix = ox * stride - pad + kx;
                                double wv = fabs(wt[(((size_t)o * cin + i) * kh + ky) * kw + kx]);
                                double xv = iy >= 0 && iy < h && ix >= 0 && ix < w
                                                ? fabs(x[((size_t)iy * w + ix) * cin + i]) : 0;
                                if (pass == 0) {
                                    ex = xv / 254 > ex ? xv / 254 : ex;
                                    ew = wv / 254 > ew ? wv / 254 : ew;
                                    ew7 = wv / 126 > ew7 ? wv / 126 : ew7;
                                } else {
                                    acc += xv * wv;
                                    qb += ex * wv + ew * xv + ex * ew;
                                    qb7 += ex * wv + ew7 * xv + ex * ew7;
                                }
                            }
                s[((size_t)oy * wo + ox) * cout + o] = acc + 1e-30;
                q[((size_t)oy * wo + ox) * cout + o] = qb + 1e-5 * acc + 1e-30;
                q7[((size_t)oy * wo + ox) * cout + o] = qb7 + 1e-5 * acc + 1e-30;
            }
}

static void check_conv(int h, int w, int cin, int cout, int kh, int kw, int stride, int pad, uint64_t seed)
{
    struct rng r;
    rng_seed(&r, seed);
    float *x = xmalloc(sizeof(float) * h * w * cin), *wt = xmalloc(sizeof(float) * cout * cin * kh * kw);
    float *b = xmalloc(sizeof(float) * cout);
    rng_fill_normal(&r, x, (size_t)h * w * cin, 1);
    rng_fill_normal(&r, wt, (size_t)cout * cin * kh * kw, 0.2f);
    rng_fill_normal(&r, b, (size_t)cout, 0.1f);
    int ho = (h + 2 * pad - kh) / stride + 1, wo = (w + 2 * pad - kw) / stride + 1;
    size_t n = (size_t)ho * wo * cout;
    float *want = xmalloc(sizeof(float) * n), *got = xmalloc(sizeof(float) * n);
    double *s = xmalloc(sizeof(double) * n), *q = xmalloc(sizeof(double) * n);
    double *q7 = xmalloc(sizeof(double) * n);
    assert_int_equal(fk_conv2d_ref(x, h, w, cin, wt, b, cout, kh, kw, stride, pad, want), F4D_OK);
    conv_scale(x, h, w, cin, wt, b, cout, kh, kw, stride, pad, s, q, q7);
    enum fk_isa all[5] = { FK_ISA_REF };
    int n_isa = 1 + test_isas(all + 1);
    for (int a = 0; a < n_isa; a++)
        for (int t = FK_W_F32; t <= FK_W_Q8; t++) {
            fk_ctx *ctx = test_ctx(all[a], 2);
            struct fk_conv2d c;
            assert_int_equal(fk_conv2d_pack(ctx, &c, (enum fk_wtype)t, wt, b, cout, cin, kh, kw, stride, pad), F4D_OK);
            int oh, ow;
            fk_conv2d_out_size(&c, h, w, &oh, &ow);
            assert_int_equal(oh, ho);
            assert_int_equal(ow, wo);
            if (fk_conv2d_forward(ctx, &c, x, h, w, got, FK_ACT_NONE) != F4D_OK)
                fail_msg("%s", fk_ctx_error(ctx));
            const double *qb = fk_ctx_q8_bits(ctx) == FK_Q8_7BIT ? q7 : q;
            for (size_t i = 0; i < n; i++)
                if (!(fabs((double)got[i] - want[i]) <= (t == FK_W_Q8 ? qb[i] : budget[t] * s[i])))
                    fail_msg("%s type %d conv %dx%d s%d p%d %dx%dx%d->%d: out %zu = %g, ref %g",
                             fk_isa_name(all[a]), t, kh, kw, stride, pad, h, w, cin, cout, i, got[i], want[i]);
            if (t == FK_W_Q8 && all[a] != FK_ISA_REF) {
                /* int8: bit-exact with the reference of the same weight codes
                 * (the optimized paths quantize im2col rows straight from the
                 * image, the reference from a gathered row) */
                fk_ctx *rc = test_ctx_q8(FK_ISA_REF, 1, fk_ctx_q8_bits(ctx));
                struct fk_conv2d cr;
                float *exact = xmalloc(sizeof(float) * n);
                assert_int_equal(fk_conv2d_pack(rc, &cr, FK_W_Q8, wt, b, cout, cin, kh, kw, stride, pad), F4D_OK);
                assert_int_equal(fk_conv2d_forward(rc, &cr, x, h, w, exact, FK_ACT_NONE), F4D_OK);
                if (memcmp(exact, got, sizeof(float) * n) != 0)
                    fail_msg("%s int8 conv %dx%d s%d p%d %dx%dx%d->%d not bit-exact with the reference",
                             fk_isa_name(all[a]), kh, kw, stride, pad, h, w, cin, cout);
                free(exact);
                fk_conv2d_free(&cr);
                fk_ctx_free(rc);
            }
            /* fused ReLU */
            assert_int_equal(fk_conv2d_forward(ctx, &c, x, h, w, got, FK_ACT_RELU), F4D_OK);
            for (size_t i = 0; i < n; i++)
                assert_true(got[i] >= 0);
            fk_conv2d_free(&c);
            fk_ctx_free(ctx);
        }
    free(x); free(wt); free(b); free(want); free(got); free(s); free(q); free(q7);
}

static void test_conv2d_shapes(void **state)
{
    (void)state;
    check_conv(9, 11, 5, 7, 1, 1, 1, 0, 1);     /* 1x1 projection        */
    check_conv(13, 10, 3, 17, 3, 3, 1, 1, 2);   /* 3x3 pad 1             */
    check_conv(37, 37, 4, 16, 3, 3, 2, 1, 3);   /* 3x3 stride 2: 37 -> 19 */
    check_conv(8, 5, 2, 3, 3, 3, 2, 1, 4);      /* even size, stride 2   */
    check_conv(28, 42, 3, 20, 14, 14, 14, 0, 5);/* ViT patchify          */
    check_conv(1, 1, 1, 1, 1, 1, 1, 0, 6);      /* smallest              */
    check_conv(3, 3, 1, 33, 3, 3, 1, 1, 7);     /* cout not a multiple of 16 */
    check_conv(14, 12, 8, 32, 3, 3, 1, 1, 8);   /* 8 channels, 3x3 (the shipped DPT's full resolution) */
    check_conv(19, 18, 2, 5, 17, 17, 1, 2, 9);  /* 17 kernel rows: int8 gathers the row */
    check_conv(11, 13, 24, 40, 3, 3, 1, 1, 10); /* cin >= 16: f32 / f16 read A in place (direct) */
}

static void check_tconv(int h, int w, int cin, int cout, int k, uint64_t seed)
{
    struct rng r;
    rng_seed(&r, seed);
    float *x = xmalloc(sizeof(float) * h * w * cin), *wt = xmalloc(sizeof(float) * cin * cout * k * k);
    float *b = xmalloc(sizeof(float) * cout);
    rng_fill_normal(&r, x, (size_t)h * w * cin, 1);
    rng_fill_normal(&r, wt, (size_t)cin * cout * k * k, 0.3f);
    rng_fill_normal(&r, b, (size_t)cout, 0.1f);
    size_t n = (size_t)h * k * w * k * cout;
    float *want = xmalloc(sizeof(float) * n), *got = xmalloc(sizeof(float) * n);
    assert_int_equal(fk_conv_transpose2d_ref(x, h, w, cin, wt, b, cout, k, want), F4D_OK);
    enum fk_isa all[5] = { FK_ISA_REF };
    int n_isa = 1 + test_isas(all + 1);
    for (int a = 0; a < n_isa; a++)
        for (int t = FK_W_F32; t <= FK_W_Q8; t++) {
            fk_ctx *ctx = test_ctx(all[a], 2);
            struct fk_conv_transpose2d c;
            assert_int_equal(fk_conv_transpose2d_pack(ctx, &c, (enum fk_wtype)t, wt, b, cin, cout, k), F4D_OK);
            memset(got, 0xff, sizeof(float) * n); /* every output must be written */
            if (fk_conv_transpose2d_forward(ctx, &c, x, h, w, got) != F4D_OK)
                fail_msg("%s", fk_ctx_error(ctx));
            for (int i = 0; i < h; i++)
                for (int j = 0; j < w; j++)
                    for (int aa = 0; aa < k; aa++)
                        for (int bb = 0; bb < k; bb++)
                            for (int o = 0; o < cout; o++) {
                                double s = fabs(b[o]);
                                for (int q = 0; q < cin; q++)
                                    s += fabs((double)x[((size_t)i * w + j) * cin + q] *
                                              wt[(((size_t)q * cout + o) * k + aa) * k + bb]);
                                size_t idx = ((size_t)(k * i + aa) * (w * k) + (size_t)(k * j + bb)) * cout + o;
                                double bt = t == FK_W_Q8 && fk_ctx_q8_bits(ctx) == FK_Q8_7BIT ? budget_q7 : budget[t];
                                if (!(fabs((double)got[idx] - want[idx]) <= bt * s))
                                    fail_msg("%s type %d tconv k%d %dx%dx%d->%d: out %zu = %g, ref %g",
                                             fk_isa_name(all[a]), t, k, h, w, cin, cout, idx, got[idx], want[idx]);
                            }
            fk_conv_transpose2d_free(&c);
            fk_ctx_free(ctx);
        }
    free(x); free(wt); free(b); free(want); free(got);
}

static void test_conv_transpose_shapes(void **state)
{
    (void)state;
    check_tconv(5, 7, 6, 5, 2, 11);    /* cout 5: output columns scatter one by one */
    check_tconv(3, 4, 9, 32, 4, 12);   /* cout 32: contiguous 16-wide stores       */
    check_tconv(2, 3, 16, 24, 4, 13);  /* panels straddle (a, b) groups            */
    check_tconv(1, 1, 1, 1, 2, 14);
}

static void test_bad_input(void **state)
{
    (void)state;
    fk_ctx *ctx = test_ctx(FK_ISA_AUTO, 1);
    float w[64] = { 0 }, x[64] = { 0 }, y[256];
    struct fk_conv2d c;
    struct fk_conv_transpose2d t;
    assert_int_equal(fk_conv2d_pack(ctx, &c, FK_W_F32, w, NULL, 2, 2, 3, 3, 1, 3), F4D_EINVAL);
    assert_non_null(strstr(fk_ctx_error(ctx), "padding"));
    assert_int_equal(fk_conv2d_pack(ctx, &c, FK_W_F32, w, NULL, 0, 2, 3, 3, 1, 1), F4D_EINVAL);
    assert_int_equal(fk_conv2d_pack(ctx, &c, FK_W_F32, w, NULL, 2, 2, 3, 3, 0, 1), F4D_EINVAL);
    assert_int_equal(fk_conv2d_pack(ctx, &c, FK_W_F32, NULL, NULL, 2, 2, 3, 3, 1, 1), F4D_EINVAL);
    assert_int_equal(fk_conv2d_pack(ctx, &c, FK_W_F32, w, NULL, 2, 2, 3, 3, 1, 0), F4D_OK);
    assert_int_equal(fk_conv2d_forward(ctx, &c, x, 2, 2, y, FK_ACT_NONE), F4D_EINVAL); /* 2x2 < 3x3 */
    assert_non_null(strstr(fk_ctx_error(ctx), "smaller"));
    assert_int_equal(fk_conv2d_forward(ctx, &c, x, 0, 5, y, FK_ACT_NONE), F4D_EINVAL);
    assert_int_equal(fk_conv2d_forward(ctx, &c, NULL, 4, 4, y, FK_ACT_NONE), F4D_EINVAL);
    assert_int_equal(fk_conv2d_forward(ctx, &c, x, 4, 4, y, (enum fk_act)12), F4D_EINVAL);
    fk_conv2d_free(&c);
    assert_int_equal(fk_conv2d_forward(ctx, &c, x, 4, 4, y, FK_ACT_NONE), F4D_EINVAL); /* freed */
    assert_int_equal(fk_conv_transpose2d_pack(ctx, &t, FK_W_F32, w, NULL, 2, 2, 0), F4D_EINVAL);
    assert_int_equal(fk_conv_transpose2d_pack(ctx, &t, FK_W_F32, w, NULL, 2, 2, 2), F4D_OK);
    assert_int_equal(fk_conv_transpose2d_forward(ctx, &t, x, -1, 2, y), F4D_EINVAL);
    fk_conv_transpose2d_free(&t);
    assert_int_equal(fk_conv2d_ref(x, 2, 2, 1, w, NULL, 1, 3, 3, 1, 0, y), F4D_EINVAL);
    fk_ctx_free(ctx);
}

int main(int argc, char **argv)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_conv2d_shapes),
        cmocka_unit_test(test_conv_transpose_shapes),
        cmocka_unit_test(test_bad_input),
    };
    return KERNEL_TEST_MAIN(argc, argv, "kernels/conv", tests);
}
