/* fp16_neon.c - bulk binary16 <-> binary32 conversion with AArch64's FCVT
 * (vcvt_f16_f32 / vcvt_f32_f16), eight values per step: round to nearest
 * even, Inf and subnormals exact, a NaN made quiet with its top payload bits
 * kept (Linux runs with FPCR.DN = 0), bit for bit what fk_f32_to_f16_ref
 * gives (test_fp16 checks it on a million bit patterns and on every half). */
#include <arm_neon.h>

#include "../../fk_fp16.h"
#include "arm.h"

void fk__f32_to_f16_neon(const float *src, fk_f16 *dst, size_t n)
{
    size_t i = 0;
    for (; i + 8 <= n; i += 8) {
        float16x8_t h = vcvt_high_f16_f32(vcvt_f16_f32(vld1q_f32(src + i)), vld1q_f32(src + i + 4));
        vst1q_u16(dst + i, vreinterpretq_u16_f16(h));
    }
    for (; i < n; i++)
        dst[i] = fk_f32_to_f16_ref(src[i]);
}

void fk__f16_to_f32_neon(const fk_f16 *src, float *dst, size_t n)
{
    size_t i = 0;
    for (; i + 8 <= n; i += 8) {
        float16x8_t h = vreinterpretq_f16_u16(vld1q_u16(src + i));
        vst1q_f32(dst + i, vcvt_f32_f16(vget_low_f16(h)));
        vst1q_f32(dst + i + 4, vcvt_high_f32_f16(h));
    }
    for (; i < n; i++)
        dst[i] = fk_f16_to_f32_ref(src[i]);
}
