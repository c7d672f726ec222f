/* fk_conv.h - 2-D convolutions on channels-last (HWC) images.
 *
 * Activations are HWC: element (y, x, c) at [(y * w + x) * c_count + c], one
 * image per call. Weights arrive in PyTorch layout and are packed once, at
 * load, through fk_linear (so f32 / f16 / int8 weights all work):
 *   conv2d            weight [out, in, kh, kw], bias [out] or NULL
 *   conv_transpose2d  weight [in, out, k, k] with stride == k, no padding:
 *                     out[o, s*i+a, s*j+b] = bias[o] + sum_c x[c,i,j] W[c,o,a,b]
 * Output size of conv2d: ho = (h + 2 pad - kh) / stride + 1 (floor), likewise wo.
 * Supported: any kh, kw >= 1, stride >= 1, 0 <= pad < kernel, e.g. 1x1; 3x3
 * pad 1 stride 1 or 2 (37 -> 19); 14x14 stride 14 (the ViT patchify).
 *
 *     struct fk_conv2d c;
 *     fk_conv2d_pack(ctx, &c, FK_W_F32, w, bias, 256, 128, 3, 3, 1, 1);
 *     fk_conv2d_forward(ctx, &c, x, h, w, y, FK_ACT_RELU);
 */
#ifndef FK_CONV_H
#define FK_CONV_H

#include "fk_ctx.h"
#include "fk_linear.h"

#ifdef __cplusplus
extern "C" {
#endif

struct fk_conv2d {
    struct fk_linear lin;       /* [out] x [kh*kw*in], taps ordered (ky, kx, c) */
    int cout, cin, kh, kw, stride, pad;
};

struct fk_conv_transpose2d {
    struct fk_linear lin;       /* [k*k*out] x [in], rows ordered (a, b, o)      */
    int cin, cout, k;
};

int  fk_conv2d_pack   (fk_ctx *ctx, struct fk_conv2d *c, enum fk_wtype as,
                       const float *w, const float *bias,
                       int cout, int cin, int kh, int kw, int stride, int pad);
void fk_conv2d_free   (struct fk_conv2d *c);
void fk_conv2d_out_size(const struct fk_conv2d *c, int h, int w, int *ho, int *wo);
int  fk_conv2d_forward(fk_ctx *ctx, const struct fk_conv2d *c,
                       const float *x, int h, int w, float *y, enum fk_act act);

int  fk_conv_transpose2d_pack   (fk_ctx *ctx, struct fk_conv_transpose2d *c,
                                 enum fk_wtype as, const float *w, const float *bias,
                                 int cin, int cout, int k);
void fk_conv_transpose2d_free   (struct fk_conv_transpose2d *c);
/* Output is (h*k) x (w*k) x cout. */
int  fk_conv_transpose2d_forward(fk_ctx *ctx, const struct fk_conv_transpose2d *c,
                                 const float *x, int h, int w, float *y);

/* Direct-loop references on the unpacked PyTorch weights (the specification). */
int  fk_conv2d_ref(const float *x, int h, int w, int cin, const float *wt,
                   const float *bias, int cout, int kh, int kw, int stride, int pad,
                   float *y);
int  fk_conv_transpose2d_ref(const float *x, int h, int w, int cin, const float *wt,
                             const float *bias, int cout, int k, float *y);

#ifdef __cplusplus
}
#endif
#endif /* FK_CONV_H */
