/* fk_linear.h - dense layers: y = x W^T + b (PyTorch Linear layout).
 *
 * x is [m, k] row-major (row stride ldx), W is [n, k] (out, in), y is [m, n]
 * (row stride ldy). Weights are packed once, at load, into the layout of the
 * context's ISA; activations stay f32. Weight precisions:
 *   FK_W_F32  fp32.
 *   FK_W_F16  fp16 storage (half the memory), converted to fp32 per cache block.
 *   FK_W_Q8   int8, symmetric, one fp32 scale per output channel
 *             (W ~= scale[n] * q[n][k], q in [-127, 127]). Each row of x is
 *             quantized on the fly to int8 with its own scale (max|x|/127,
 *             round half to even), products are accumulated exactly in int32
 *             (no int16 intermediate, so no saturation), and
 *             y = acc * (sx * sw[n]) + b[n]. The optimized paths are bit-exact
 *             with the reference before the activation. k <= 65536 keeps the
 *             int32 sum exact; longer rows are F4D_ERANGE.
 *             On CPUs without VNNI (FK_Q8_7BIT, see fk_ctx_config.q8_bits)
 *             the weight codes keep vpmaddubsw's int16 pair sums exact:
 *             |q[n][2i]| + |q[n][2i+1]| <= 128 (what two 7-bit codes give;
 *             the scale is the row's largest |w0| + |w1| over 127). From
 *             int8 files, rows whose pairs exceed 128 are requantized
 *             (q' = round(q * 127 / max pair)). The reference run with the
 *             same q8_bits packs the same codes and is bit-exact with it.
 * Non-finite values in a row of x make that output row non-finite (all
 * precisions), never a crash.
 *
 *     struct fk_linear fc1;
 *     fk_linear_pack(ctx, &fc1, FK_W_Q8, w, n, k, bias);       // at load
 *     struct fk_epilogue ep = { .act = FK_ACT_GELU };
 *     fk_linear_forward(ctx, &fc1, x, m, k, h, n, &ep);        // per frame
 *     fk_linear_free(&fc1);
 */
#ifndef FK_LINEAR_H
#define FK_LINEAR_H

#include <stddef.h>
#include <stdint.h>
#include "fk_ctx.h"
#include "fk_fp16.h"

#ifdef __cplusplus
extern "C" {
#endif

/* Weight storage types. Values are stored in files and never renumbered. */
enum fk_wtype {
    FK_W_F32 = 0,
    FK_W_F16 = 1,
    FK_W_Q8  = 2,
};

enum fk_act {
    FK_ACT_NONE = 0,
    FK_ACT_RELU = 1,
    FK_ACT_GELU = 2, /* exact: 0.5 x (1 + erf(x / sqrt 2)) */
    FK_ACT_SILU = 3,
};

/* What happens to t = act(x W^T + b) on its way into y:
 *   y = (accumulate ? y : 0) + (gamma ? gamma (.) t : t)
 * accumulate + gamma is a residual add with LayerScale, fused. */
struct fk_epilogue {
    enum fk_act  act;
    const float *gamma;      /* [n] or NULL                      */
    int          accumulate; /* add into y instead of overwriting */
};

/* Packed weights. Owned; release with fk_linear_free. Fields are read-only
 * for callers (the layout behind `data` belongs to the ISA that packed it). */
struct fk_linear {
    enum fk_wtype type;
    enum fk_isa   isa;       /* the ISA whose layout `data` is in  */
    int           n, k;      /* out and in features                */
    void         *data;      /* packed weights                     */
    float        *scale;     /* FK_W_Q8: per output channel        */
    int32_t      *colsum;    /* FK_W_Q8, VNNI: sum_k q[n][k] * 128 */
    float        *bias;      /* [n], zeros when none was given     */
    size_t        bytes;     /* memory held by this layer          */
    int           q8_bits;   /* FK_W_Q8: 8, or 7 (codes in [-63, 63]) */
};

/* Pack from fp32 weights into `as` (quantizing for FK_W_Q8, rounding for
 * FK_W_F16). bias may be NULL. */
int    fk_linear_pack    (fk_ctx *ctx, struct fk_linear *L, enum fk_wtype as,
                          const float *w, int n, int k, const float *bias);
/* Pack from fp16 weights kept as fp16 (FK_W_F16) or widened (FK_W_F32). */
int    fk_linear_pack_f16(fk_ctx *ctx, struct fk_linear *L, enum fk_wtype as,
                          const fk_f16 *w, int n, int k, const float *bias);
/* Pack already quantized int8 weights with their per-channel scales. */
int    fk_linear_pack_q8 (fk_ctx *ctx, struct fk_linear *L, const int8_t *q,
                          const float *scale, int n, int k, const float *bias);
void   fk_linear_free    (struct fk_linear *L);

/* Quantize one fp32 row the way fk_linear_pack does for weights and the
 * forward pass does for activations (reference): returns the scale amax/127,
 * 0 for a zero row, NaN (codes all 0) when the row holds Inf or NaN. A row
 * with amax below FK_Q8_AMAX_MIN counts as zero: 127 / amax would overflow
 * to Inf (and w * Inf to NaN codes) for amax < 127 / FLT_MAX ~ 3.7e-37. */
#define FK_Q8_AMAX_MIN 1e-30f
float  fk_quantize_row_q8(const float *w, int k, int8_t *q);

/* y = epilogue(x W^T + b). m == 0 is a no-op. ld* are in elements and must be
 * >= k (ldx) and >= n (ldy). x and y must not overlap. */
int    fk_linear_forward (fk_ctx *ctx, const struct fk_linear *L,
                          const float *x, int m, int ldx,
                          float *y, int ldy, const struct fk_epilogue *ep);

#ifdef __cplusplus
}
#endif
#endif /* FK_LINEAR_H */
