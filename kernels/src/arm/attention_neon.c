/* attention_neon.c - the AArch64 NEON pieces of multi-head attention with
 * an online softmax, the algorithm of x86/attention_avx2.c with four-lane
 * vectors: q/k LayerNorm and RoPE, the online softmax block and the P V
 * tile (S = Q K^T is the GEMM's 6x16 micro-kernel). The driver (head
 * grouping, packing, scratch, the parallel phases) is attention_plan.c. */
#include <arm_neon.h>
#include <float.h>
#include <math.h>
#include <string.h>

#include "../attention_plan.h"
#include "../fk_internal.h"
#include "arm.h"
#include "vecmath_neon.h"

#define MR FK_ATTN_MR
#define BK FK_ATTN_BK

/* ------------------------------------------------------------------- prep */

static void rope_apply(const struct fk__rope_table *rt, float *t, int d, const int32_t *pos)
{
    int m = d / 2, h = m / 2;
    for (int axis = 0; axis < 2; axis++) {
        float *u = t + axis * m;
        int p = pos[axis] - rt->lo;
        const float *c = rt->cos + (size_t)p * (size_t)h, *s = rt->sin + (size_t)p * (size_t)h;
        int kk = 0;
        for (; kk + 4 <= h; kk += 4) {
            float32x4_t a = vld1q_f32(u + kk), b = vld1q_f32(u + kk + h);
            float32x4_t cv = vld1q_f32(c + kk), sv = vld1q_f32(s + kk);
            vst1q_f32(u + kk, vfmsq_f32(vmulq_f32(a, cv), b, sv));
            vst1q_f32(u + kk + h, vfmaq_f32(vmulq_f32(b, cv), a, sv));
        }
        for (; kk < h; kk++) {
            float a = u[kk], b = u[kk + h];
            u[kk] = a * c[kk] - b * s[kk];
            u[kk + h] = b * c[kk] + a * s[kk];
        }
    }
}

/* LayerNorm over d (a multiple of 8) in registers. */
static void head_norm(float *t, int d, const float *w, const float *b, float eps)
{
    float32x4_t s = vdupq_n_f32(0.0f);
    for (int i = 0; i < d; i += 4)
        s = vaddq_f32(s, vld1q_f32(t + i));
    float32x4_t mean = vdupq_n_f32(vaddvq_f32(s) / (float)d), v = vdupq_n_f32(0.0f);
    for (int i = 0; i < d; i += 4) {
        float32x4_t c = vsubq_f32(vld1q_f32(t + i), mean);
        v = vfmaq_f32(v, c, c);
    }
    float32x4_t inv = vdupq_n_f32(1.0f / sqrtf(vaddvq_f32(v) / (float)d + eps));
    for (int i = 0; i < d; i += 4) {
        float32x4_t x = vmulq_f32(vsubq_f32(vld1q_f32(t + i), mean), inv);
        if (w)
            x = vmulq_f32(x, vld1q_f32(w + i));
        if (b)
            x = vaddq_f32(x, vld1q_f32(b + i));
        vst1q_f32(t + i, x);
    }
}

/* -------------------------------------------------------------- the tiles */

/* o[6][d] = alpha[r] o[r] + p[6][0, kv) . v[0, kv)[d], 16 columns at a time
 * (kv rounded up to the 4 keys of a step) */
__attribute__((noinline)) static void pv_tile(int d, int kv, const float *p, const float *v, float *o,
                                              const float *alpha)
{
    kv = (kv + 3) & ~3;
    for (int c0 = 0; c0 < d; c0 += 16) {
        float *oc = o + c0;
        float32x4_t acc[MR][4];
        for (int r = 0; r < MR; r++) {
            float32x4_t a = vdupq_n_f32(alpha[r]);
            for (int q = 0; q < 4; q++)
                acc[r][q] = vmulq_f32(a, vld1q_f32(oc + (size_t)r * (size_t)d + 4 * q));
        }
        const float *vr = v + c0;
        for (int jj = 0; jj < kv; jj += 4) {
            float32x4_t pr[MR];
            for (int r = 0; r < MR; r++)
                pr[r] = vld1q_f32(p + r * BK + jj);
#define STEP(l)                                                               \
            {                                                                 \
                float32x4_t b0 = vld1q_f32(vr), b1 = vld1q_f32(vr + 4);        \
                float32x4_t b2 = vld1q_f32(vr + 8), b3 = vld1q_f32(vr + 12);   \
                for (int r = 0; r < MR; r++) {                                \
                    acc[r][0] = vfmaq_laneq_f32(acc[r][0], b0, pr[r], l);     \
                    acc[r][1] = vfmaq_laneq_f32(acc[r][1], b1, pr[r], l);     \
                    acc[r][2] = vfmaq_laneq_f32(acc[r][2], b2, pr[r], l);     \
                    acc[r][3] = vfmaq_laneq_f32(acc[r][3], b3, pr[r], l);     \
                }                                                             \
                vr += d;                                                      \
            }
            STEP(0) STEP(1) STEP(2) STEP(3)
#undef STEP
        }
        for (int r = 0; r < MR; r++)
            for (int q = 0; q < 4; q++)
                vst1q_f32(oc + (size_t)r * (size_t)d + 4 * q, acc[r][q]);
    }
}

/* 2^x for the softmax, x = s - max <= 0: inputs clamped at -127, the scale a
 * plain exponent add, NaN stays NaN; degree-6 polynomial of 2^f on
 * [-0.5, 0.5], relative error <= 1e-7 above 2^-126 (as the AVX2 version). */
static inline float32x4_t exp2_softmax(float32x4_t x)
{
    x = vmaxq_f32(vdupq_n_f32(-127.0f), x);
    float32x4_t n = vrndnq_f32(x);
    float32x4_t f = vsubq_f32(x, n);
    float32x4_t p = vdupq_n_f32(1.5403530393e-4f);
    p = vfmaq_f32(vdupq_n_f32(1.3333558146e-3f), p, f);
    p = vfmaq_f32(vdupq_n_f32(9.6181291076e-3f), p, f);
    p = vfmaq_f32(vdupq_n_f32(5.5504108665e-2f), p, f);
    p = vfmaq_f32(vdupq_n_f32(2.4022650696e-1f), p, f);
    p = vfmaq_f32(vdupq_n_f32(6.9314718056e-1f), p, f);
    p = vfmaq_f32(vdupq_n_f32(1.0f), p, f);
    int32x4_t e = vshlq_n_s32(vaddq_s32(vcvtnq_s32_f32(n), vdupq_n_s32(127)), 23);
    return vmulq_f32(p, vreinterpretq_f32_s32(e));
}

/* Online softmax over one 6 x BK block of log2-domain logits, in place:
 * s becomes p = 2^(s - m_new); alpha = 2^(m_old - m_new); l = alpha l + sum p. */
__attribute__((noinline)) static void softmax_block(float *s, int valid, float *m, float *l, float *alpha)
{
    float m_new[8] = { 0 }, m_old[8] = { 0 };
    for (int r = 0; r < MR; r++) {
        float *sr = s + r * BK;
        for (int jj = valid; jj < BK; jj++)
            sr[jj] = -INFINITY;
        float32x4_t mx = vld1q_f32(sr);
        for (int jj = 4; jj < BK; jj += 4)
            mx = vmaxq_f32(mx, vld1q_f32(sr + jj));
        float bm = vmaxvq_f32(mx);
        m_old[r] = m[r];
        m_new[r] = bm > m[r] || isnan(bm) ? bm : m[r];
    }
    vst1q_f32(alpha, exp2_softmax(vsubq_f32(vld1q_f32(m_old), vld1q_f32(m_new))));
    vst1q_f32(alpha + 4, exp2_softmax(vsubq_f32(vld1q_f32(m_old + 4), vld1q_f32(m_new + 4))));
    for (int r = 0; r < MR; r++) {
        float *sr = s + r * BK;
        float32x4_t mv = vdupq_n_f32(m_new[r]), sum = vdupq_n_f32(0.0f);
        for (int jj = 0; jj < BK; jj += 4) {
            float32x4_t p = exp2_softmax(vsubq_f32(vld1q_f32(sr + jj), mv));
            vst1q_f32(sr + jj, p);
            sum = vaddq_f32(sum, p);
        }
        l[r] = l[r] * alpha[r] + vaddvq_f32(sum);
        m[r] = m_new[r];
    }
}

static const struct fk__attn_isa attn_neon = {
    head_norm, rope_apply, fk__ukr_f32_6x16_neon, softmax_block, pv_tile, NULL, NULL, NULL,
};

int fk__attention_neon(fk_ctx *ctx, const struct fk_attention_desc *a, const float *q, int ldq,
                       int nq, const float *k, int ldk, const float *v, int ldv, int nk,
                       float *out, int ldo)
{
    return fk__attention_plan_run(&attn_neon, ctx, a, q, ldq, nq, k, ldk, v, ldv, nk, out, ldo);
}
