/* fk_fp16.h - IEEE 754 binary16 <-> binary32 conversion.
 *
 * fp16 is a storage type (fk_f16, the raw bits); arithmetic is always fp32.
 * f32 -> f16 rounds to nearest, ties to even; values beyond the fp16 range
 * (|x| >= 65520) become +-Inf; results below the normal range become
 * subnormals (correctly rounded) or signed zero; NaN stays NaN (quiet, sign and
 * the top payload bits kept). f16 -> f32 is exact.
 *
 *     fk_f16 h = fk_f32_to_f16_ref(1.0f);            // 0x3c00
 *     fk_f32_to_f16(ctx, src, dst, n);                 // bulk, F16C where present
 */
#ifndef FK_FP16_H
#define FK_FP16_H

#include <stddef.h>
#include <stdint.h>
#include "fk_ctx.h"

#ifdef __cplusplus
extern "C" {
#endif

typedef uint16_t fk_f16;

/* Portable scalar references (the specification). */
fk_f16 fk_f32_to_f16_ref(float x);
float  fk_f16_to_f32_ref(fk_f16 h);

/* Bulk conversion with the context's ISA. n may be 0; pointers may then be NULL. */
int    fk_f32_to_f16(fk_ctx *ctx, const float *src, fk_f16 *dst, size_t n);
int    fk_f16_to_f32(fk_ctx *ctx, const fk_f16 *src, float *dst, size_t n);

#ifdef __cplusplus
}
#endif
#endif /* FK_FP16_H */
