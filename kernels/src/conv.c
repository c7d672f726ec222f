/* conv.c - fk_conv: 2-D convolutions as GEMMs over packed weights.
 * conv2d reads its input through an im2col view (no im2col buffer: the GEMM
 * packer gathers each row), transposed conv with stride == kernel is one GEMM
 * whose output rows scatter to k x k output pixels. The direct loops below
 * are the specification the tests hold them to. */
#include <stdlib.h>
#include <string.h>

#include "../fk_conv.h"
#include "fk_internal.h"
#include "gemm.h"

int fk_conv2d_pack(fk_ctx *ctx, struct fk_conv2d *c, enum fk_wtype as, const float *w,
                   const float *bias, int cout, int cin, int kh, int kw, int stride, int pad)
{
    FK_CHECK_CTX(ctx);
    if (!c || !w)
        return FK_FAIL(ctx, F4D_EINVAL, "NULL %s", !c ? "conv" : "weights");
    memset(c, 0, sizeof *c);
    if (cout <= 0 || cin <= 0 || kh <= 0 || kw <= 0 || stride <= 0)
        return FK_FAIL(ctx, F4D_EINVAL, "conv shape out %d in %d kernel %dx%d stride %d must be positive",
                       cout, cin, kh, kw, stride);
    if (pad < 0 || pad >= kh || pad >= kw)
        return FK_FAIL(ctx, F4D_EINVAL, "padding %d must be in [0, kernel %dx%d)", pad, kh, kw);
    long taps = (long)kh * kw * cin;
    if (taps > 1 << 26)
        return FK_FAIL(ctx, F4D_ERANGE, "kernel %dx%dx%d is too large", kh, kw, cin);
    int k = (int)taps;
    float *wr = malloc((size_t)cout * (size_t)k * sizeof *wr);
    if (!wr)
        return FK_FAIL(ctx, F4D_ENOMEM, "cannot allocate %zu bytes", (size_t)cout * (size_t)k * 4);
    /* [out][in][ky][kx] -> [out][ky][kx][in]: the order of an HWC gather */
    for (int o = 0; o < cout; o++)
        for (int i = 0; i < cin; i++)
            for (int y = 0; y < kh; y++)
                for (int x = 0; x < kw; x++)
                    wr[(size_t)o * k + ((size_t)y * kw + x) * cin + i] =
                        w[(((size_t)o * cin + i) * kh + y) * kw + x];
    int st = fk_linear_pack(ctx, &c->lin, as, wr, cout, k, bias);
    free(wr);
    if (st)
        return st;
    c->cout = cout; c->cin = cin; c->kh = kh; c->kw = kw; c->stride = stride; c->pad = pad;
    return F4D_OK;
}

void fk_conv2d_free(struct fk_conv2d *c)
{
    if (c) {
        fk_linear_free(&c->lin);
        memset(c, 0, sizeof *c);
    }
}

void fk_conv2d_out_size(const struct fk_conv2d *c, int h, int w, int *ho, int *wo)
{
    *ho = h + 2 * c->pad < c->kh ? 0 : (h + 2 * c->pad - c->kh) / c->stride + 1;
    *wo = w + 2 * c->pad < c->kw ? 0 : (w + 2 * c->pad - c->kw) / c->stride + 1;
}

int fk_conv2d_forward(fk_ctx *ctx, const struct fk_conv2d *c, const float *x, int h, int w,
                      float *y, enum fk_act act)
{
    FK_CHECK_CTX(ctx);
    if (!c || !c->lin.data)
        return FK_FAIL(ctx, F4D_EINVAL, "conv is NULL or not packed");
    if (h <= 0 || w <= 0)
        return FK_FAIL(ctx, F4D_EINVAL, "image %dx%d must not be empty", h, w);
    if (!x || !y)
        return FK_FAIL(ctx, F4D_EINVAL, "NULL %s", !x ? "input" : "output");
    int ho, wo;
    fk_conv2d_out_size(c, h, w, &ho, &wo);
    if (ho <= 0 || wo <= 0)
        return FK_FAIL(ctx, F4D_EINVAL, "image %dx%d is smaller than the %dx%d kernel", h, w, c->kh, c->kw);
    if ((long)ho * wo > 1 << 28)
        return FK_FAIL(ctx, F4D_ERANGE, "output %dx%d is too large", ho, wo);
    struct fk__asrc a = { .x = x, .ldx = c->cin, .conv = 1, .h = h, .w = w, .cin = c->cin,
                          .kh = c->kh, .kw = c->kw, .stride = c->stride, .pad = c->pad, .wo = wo };
    if (c->kh == 1 && c->kw == 1 && c->stride == 1 && c->pad == 0)
        a.conv = 0; /* 1x1: the image already is the GEMM's A */
    struct fk__cdst d = { .y = y, .ldy = c->cout };
    struct fk_epilogue ep = { act, NULL, 0 };
    return fk__gemm_run(ctx, &c->lin, &a, ho * wo, &d, &ep);
}

int fk_conv_transpose2d_pack(fk_ctx *ctx, struct fk_conv_transpose2d *c, enum fk_wtype as,
                             const float *w, const float *bias, int cin, int cout, int k)
{
    FK_CHECK_CTX(ctx);
    if (!c || !w)
        return FK_FAIL(ctx, F4D_EINVAL, "NULL %s", !c ? "conv" : "weights");
    memset(c, 0, sizeof *c);
    if (cin <= 0 || cout <= 0 || k <= 0 || k > 64)
        return FK_FAIL(ctx, F4D_EINVAL, "transposed conv in %d out %d kernel %d: need positive sizes, kernel <= 64",
                       cin, cout, k);
    size_t n = (size_t)k * (size_t)k * (size_t)cout;
    if (n > (size_t)1 << 26)
        return FK_FAIL(ctx, F4D_ERANGE, "transposed conv output width %zu is too large", n);
    float *wr = malloc(n * (size_t)cin * sizeof *wr), *br = malloc(n * sizeof *br);
    if (!wr || !br) {
        free(wr);
        free(br);
        return FK_FAIL(ctx, F4D_ENOMEM, "cannot allocate %zu bytes", n * (size_t)cin * 4);
    }
    /* [in][out][a][b] -> rows (a, b, o), columns c */
    for (int i = 0; i < cin; i++)
        for (int o = 0; o < cout; o++)
            for (int a = 0; a < k; a++)
                for (int b = 0; b < k; b++)
                    wr[(((size_t)a * k + b) * cout + o) * cin + i] = w[(((size_t)i * cout + o) * k + a) * k + b];
    for (size_t r = 0; r < n; r++)
        br[r] = bias ? bias[r % (size_t)cout] : 0.0f;
    int st = fk_linear_pack(ctx, &c->lin, as, wr, (int)n, cin, br);
    free(wr);
    free(br);
    if (st)
        return st;
    c->cin = cin; c->cout = cout; c->k = k;
    return F4D_OK;
}

void fk_conv_transpose2d_free(struct fk_conv_transpose2d *c)
{
    if (c) {
        fk_linear_free(&c->lin);
        memset(c, 0, sizeof *c);
    }
}

int fk_conv_transpose2d_forward(fk_ctx *ctx, const struct fk_conv_transpose2d *c, const float *x,
                                int h, int w, float *y)
{
    FK_CHECK_CTX(ctx);
    if (!c || !c->lin.data)
        return FK_FAIL(ctx, F4D_EINVAL, "transposed conv is NULL or not packed");
    if (h <= 0 || w <= 0)
        return FK_FAIL(ctx, F4D_EINVAL, "image %dx%d must not be empty", h, w);
    if (!x || !y)
        return FK_FAIL(ctx, F4D_EINVAL, "NULL %s", !x ? "input" : "output");
    if ((long)h * w > 1 << 26)
        return FK_FAIL(ctx, F4D_ERANGE, "image %dx%d is too large", h, w);
    struct fk__asrc a = { .x = x, .ldx = c->cin };
    struct fk__cdst d = { .y = y, .tconv_k = c->k, .tconv_cout = c->cout, .tconv_w = w };
    return fk__gemm_run(ctx, &c->lin, &a, h * w, &d, NULL);
}

/* ------------------------------------------------------------- references */

int fk_conv2d_ref(const float *x, int h, int w, int cin, const float *wt, const float *bias,
                  int cout, int kh, int kw, int stride, int pad, float *y)
{
    if (!x || !wt || !y || h <= 0 || w <= 0 || cin <= 0 || cout <= 0 || kh <= 0 || kw <= 0 ||
        stride <= 0 || pad < 0)
        return F4D_EINVAL;
    int ho = (h + 2 * pad - kh) / stride + 1, wo = (w + 2 * pad - kw) / stride + 1;
    if (h + 2 * pad < kh || w + 2 * pad < kw)
        return F4D_EINVAL;
    for (int oy = 0; oy < ho; oy++)
        for (int ox = 0; ox < wo; ox++)
            for (int o = 0; o < cout; o++) {
                float acc = bias ? bias[o] : 0.0f;
                for (int i = 0; i < cin; i++)
                    for (int ky = 0; ky < kh; ky++)
                        for (int kx = 0; kx < kw; kx++) {
                            int iy = oy * stride - pad + ky, ix = ox * stride - pad + kx;
                            if (iy < 0 || iy >= h || ix < 0 || ix >= w)
                                continue;
                            acc += x[((size_t)iy * w + ix) * cin + i] *
                                   wt[(((size_t)o * cin + i) * kh + ky) * kw + kx];
                        }
                y[((size_t)oy * wo + ox) * cout + o] = acc;
            }
    return F4D_OK;
}

int fk_conv_transpose2d_ref(const float *x, int h, int w, int cin, const float *wt,
                            const float *bias, int cout, int k, float *y)
{
    if (!x || !wt || !y || h <= 0 || w <= 0 || cin <= 0 || cout <= 0 || k <= 0)
        return F4D_EINVAL;
    int wo = w * k;
    for (int i = 0; i < h; i++)
        for (int j = 0; j < w; j++)
            for (int a = 0; a < k; a++)
                for (int b = 0; b < k; b++)
                    for (int o = 0; o < cout; o++) {
                        float acc = bias ? bias[o] : 0.0f;
                        for (int c = 0; c < cin; c++)
                            acc += x[((size_t)i * w + j) * cin + c] * wt[(((size_t)c * cout + o) * k + a) * k + b];
                        y[((size_t)(k * i + a) * wo + (size_t)(k * j + b)) * cout + o] = acc;
                    }
    return F4D_OK;
}
