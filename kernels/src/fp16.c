/* fp16.c - binary16 conversion: scalar reference and ISA dispatch. */
#include <string.h>

#include "../fk_fp16.h"
#include "fk_internal.h"
#include "arm/arm.h"
#include "x86/x86.h"

fk_f16 fk_f32_to_f16_ref(float x)
{
    uint32_t u;
    memcpy(&u, &x, sizeof u);
    uint32_t sign = (u >> 16) & 0x8000u;
    uint32_t exp = (u >> 23) & 0xffu;
    uint32_t mant = u & 0x7fffffu;

    if (exp == 0xff) /* Inf, or NaN made quiet with its top payload bits kept */
        return (fk_f16)(mant ? (sign | 0x7e00u | (mant >> 13)) : (sign | 0x7c00u));

    int32_t e = (int32_t)exp - 127 + 15;
    if (e >= 31)
        return (fk_f16)(sign | 0x7c00u);
    if (e <= 0) {
        if (e < -10) /* below half the smallest subnormal: rounds to zero */
            return (fk_f16)sign;
        mant |= 0x800000u;
        uint32_t shift = (uint32_t)(14 - e);
        uint32_t half = mant >> shift;
        uint32_t rem = mant & ((1u << shift) - 1);
        uint32_t halfway = 1u << (shift - 1);
        if (rem > halfway || (rem == halfway && (half & 1u)))
            half++; /* may carry into the smallest normal: still correct */
        return (fk_f16)(sign | half);
    }
    uint32_t half = ((uint32_t)e << 10) | (mant >> 13);
    uint32_t rem = mant & 0x1fffu;
    if (rem > 0x1000u || (rem == 0x1000u && (half & 1u)))
        half++; /* a carry out of 0x7bff gives Inf, as it should */
    return (fk_f16)(sign | half);
}

float fk_f16_to_f32_ref(fk_f16 h)
{
    uint32_t sign = ((uint32_t)h & 0x8000u) << 16;
    uint32_t exp = ((uint32_t)h >> 10) & 0x1fu;
    uint32_t mant = (uint32_t)h & 0x3ffu;
    uint32_t u;
    if (exp == 0) {
        if (mant == 0) {
            u = sign;
        } else { /* subnormal: normalise */
            uint32_t e = 0;
            while (!(mant & 0x400u)) {
                mant <<= 1;
                e++;
            }
            mant &= 0x3ffu;
            u = sign | ((113u - e) << 23) | (mant << 13);
        }
    } else if (exp == 31) {
        u = sign | 0x7f800000u | (mant << 13);
    } else {
        u = sign | ((exp + 112u) << 23) | (mant << 13);
    }
    float f;
    memcpy(&f, &u, sizeof f);
    return f;
}

/* Argument checks shared by both directions: 1 when there is work to do. */
static int bulk_args(fk_ctx *ctx, const void *src, void *dst, size_t n, int *st)
{
    *st = F4D_OK;
    if (!ctx)
        *st = F4D_EINVAL;
    else if (n > 0 && (!src || !dst))
        *st = FK_FAIL(ctx, F4D_EINVAL, "NULL buffer for %zu values", n);
    return *st == F4D_OK && n > 0;
}

int fk_f32_to_f16(fk_ctx *ctx, const float *src, fk_f16 *dst, size_t n)
{
    int st;
    if (!bulk_args(ctx, src, dst, n, &st))
        return st;
    if (fk__isa_avx2(ctx->isa))
        fk__f32_to_f16_avx2(src, dst, n);
    else if (fk__isa_neon(ctx->isa))
        fk__f32_to_f16_neon(src, dst, n);
    else
        for (size_t i = 0; i < n; i++)
            dst[i] = fk_f32_to_f16_ref(src[i]);
    return F4D_OK;
}

int fk_f16_to_f32(fk_ctx *ctx, const fk_f16 *src, float *dst, size_t n)
{
    int st;
    if (!bulk_args(ctx, src, dst, n, &st))
        return st;
    if (fk__isa_avx2(ctx->isa))
        fk__f16_to_f32_avx2(src, dst, n);
    else if (fk__isa_neon(ctx->isa))
        fk__f16_to_f32_neon(src, dst, n);
    else
        for (size_t i = 0; i < n; i++)
            dst[i] = fk_f16_to_f32_ref(src[i]);
    return F4D_OK;
}
