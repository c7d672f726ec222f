/* fk_ops.h - row-wise and element-wise operations of the transformer blocks.
 *
 * Matrices are row-major with explicit row strides (in elements). In-place use
 * (y == x, same stride) is allowed everywhere below.
 *
 *     fk_layernorm(ctx, x, n_tok, C, C, ln_w, ln_b, 1e-6f, y, C);
 *     fk_gelu(ctx, h, n_tok * 4 * C, h);
 *     fk_residual_add(ctx, x, C, r, C, gamma, n_tok, C);   // x += gamma (.) r
 *
 * LayerNorm uses the biased variance (PyTorch), computed in two passes from
 * the row mean with the statistics in double, so a constant row gives exactly
 * 0 before the affine part (output = bias) and rows of any finite magnitude
 * (1e-30 ... 3e38) neither overflow nor underflow. GELU is the exact erf form.
 *
 * Shapes: rows == 0 or n == 0 is a no-op; rows < 0, cols < 1, a stride below
 * cols, a NULL buffer, eps < 0 or non-finite, or an output that overlaps the
 * input without being it (same pointer and stride) is F4D_EINVAL with a
 * message naming the argument.
 *
 * Non-finite values: a NaN or Inf in a LayerNorm or softmax row makes that
 * whole row NaN (an all -Inf softmax row too: 0/0); -Inf logits next to
 * finite ones get probability 0. Element-wise functions give NaN for NaN and
 * their limits at +-Inf: gelu and silu (+Inf) = +Inf, (-Inf) = -0, relu(-Inf)
 * = 0; relu passes NaN and -0 through (as maxps(0, x)).
 */
#ifndef FK_OPS_H
#define FK_OPS_H

#include <stddef.h>
#include "fk_ctx.h"

#ifdef __cplusplus
extern "C" {
#endif

/* y = (x - mean) / sqrt(var + eps) * w + b per row; w and b may be NULL
 * (no affine part: 1 and 0). eps > 0 (or 0 with a non-constant row). */
int fk_layernorm    (fk_ctx *ctx, const float *x, int rows, int cols, int ldx,
                     const float *w, const float *b, float eps, float *y, int ldy);

/* Element-wise over n contiguous floats. */
int fk_gelu         (fk_ctx *ctx, const float *x, size_t n, float *y);
int fk_silu         (fk_ctx *ctx, const float *x, size_t n, float *y);
int fk_relu         (fk_ctx *ctx, const float *x, size_t n, float *y);

/* Softmax over each row, in place allowed. */
int fk_softmax      (fk_ctx *ctx, const float *x, int rows, int cols, int ldx,
                     float *y, int ldy);

/* x[i, :] += gamma (.) r[i, :] (gamma NULL means 1): the LayerScale residual. */
int fk_residual_add (fk_ctx *ctx, float *x, int ldx, const float *r, int ldr,
                     const float *gamma, int rows, int cols);

/* Scalar references (the specification) of the element-wise functions. */
float fk_gelu_ref(float x);
float fk_silu_ref(float x);

#ifdef __cplusplus
}
#endif
#endif /* FK_OPS_H */
