/* fk_resize.h - image and feature-map resampling on channels-last (HWC) data.
 *
 * Bilinear, separable, PyTorch semantics (F.interpolate, antialias off):
 *   align_corners = 1: src = i * (n_in - 1) / (n_out - 1)   (0 when n_out == 1)
 *   align_corners = 0: src = max((i + 0.5) * n_in / n_out - 0.5, 0)
 *   i0 = floor(src), i1 = min(i0 + 1, n_in - 1), linear blend.
 * Antialiased bicubic (PIL / torch antialias=True, a = -0.5), vggt.md 2:
 *   s = n_in / n_out, support = 2 s (s >= 1) or 2, taps normalised to sum 1,
 *   identity when n_in == n_out. Used for the DINOv2 position-embedding resize
 *   and for image preprocessing. Width pass first, then height (as PIL).
 *
 * Same input and output size is an exact copy for both. Bilinear positions on
 * or past the last pixel use that pixel with weight exactly 1. Every ISA gives
 * the same bits (same tables, same operations). A NaN or Inf input spoils only
 * the outputs whose taps reach it (an Inf may come out as NaN). Errors
 * (F4D_EINVAL): h, w, c, ho or wo < 1, NULL x or y, x and y overlapping,
 * align_corners not 0 or 1; F4D_ENOMEM when the table / intermediate scratch
 * does not fit a frozen context (bicubic: h * wo * c floats when both axes change).
 *
 *     fk_resize_bilinear(ctx, x, 37, 37, 256, y, 148, 148, 1);
 */
#ifndef FK_RESIZE_H
#define FK_RESIZE_H

#include "fk_ctx.h"

#ifdef __cplusplus
extern "C" {
#endif

int fk_resize_bilinear  (fk_ctx *ctx, const float *x, int h, int w, int c,
                         float *y, int ho, int wo, int align_corners);
int fk_resize_bicubic_aa(fk_ctx *ctx, const float *x, int h, int w, int c,
                         float *y, int ho, int wo);

#ifdef __cplusplus
}
#endif
#endif /* FK_RESIZE_H */
