/* gemm_neon.c - blocked GEMM for AArch64 NEON: the driver shared by fk_linear
 * and fk_conv, the 6x16 fp32 micro-kernel (fp16 weights widened per cache
 * block into it; FCVTL is ARMv8.0), and the int8 path: activations quantized
 * per row exactly like fk_quantize_row_q8, then either the sdot micro-kernel
 * (gemm_dot.c, where HWCAP_ASIMDDP) or an exact widening one (smull into
 * int16 products, which cannot overflow for |codes| <= 127, pairwise-added
 * into int32 with sadalp), so int8 is bit-exact with the reference on every
 * AArch64 CPU.
 *
 * Weights are in gemm.h's packed layouts (the same as AVX2's). A task owns mc
 * rows of A, packed for the whole k, and a range of 16-wide weight panels; for
 * each panel it walks k in blocks of kc (the context's cache blocks) over all 6-row micro-panels,
 * then applies the epilogue (bias, activation, LayerScale, residual). */
#include <arm_neon.h>
#include <math.h>
#include <string.h>

#include "../fk_internal.h"
#include "../gemm.h"
#include "arm.h"
#include "vecmath_neon.h"

#define MR FK_GEMM_MR
#define NR FK_GEMM_NR

/* ----------------------------------------------------------- micro-kernels */

void fk__ukr_f32_6x16_neon(int kc, const float *a, const float *b, float *c, int ldc, int accumulate)
{
    float32x4_t c00, c01, c02, c03, c10, c11, c12, c13, c20, c21, c22, c23;
    float32x4_t c30, c31, c32, c33, c40, c41, c42, c43, c50, c51, c52, c53;
#define LOADROW(r)                                                            \
    c##r##0 = vld1q_f32(c + r * ldc);     c##r##1 = vld1q_f32(c + r * ldc + 4); \
    c##r##2 = vld1q_f32(c + r * ldc + 8); c##r##3 = vld1q_f32(c + r * ldc + 12);
    if (accumulate) {
        LOADROW(0) LOADROW(1) LOADROW(2) LOADROW(3) LOADROW(4) LOADROW(5)
    } else {
        c00 = c01 = c02 = c03 = c10 = c11 = c12 = c13 = vdupq_n_f32(0.0f);
        c20 = c21 = c22 = c23 = c30 = c31 = c32 = c33 = c00;
        c40 = c41 = c42 = c43 = c50 = c51 = c52 = c53 = c00;
    }
#undef LOADROW
    for (int k = 0; k < kc; k++) {
        float32x4_t b0 = vld1q_f32(b), b1 = vld1q_f32(b + 4), b2 = vld1q_f32(b + 8), b3 = vld1q_f32(b + 12);
        float32x4_t a03 = vld1q_f32(a);
        float32x2_t a45 = vld1_f32(a + 4);
#define ROWQ(r, l)                                                            \
    c##r##0 = vfmaq_laneq_f32(c##r##0, b0, a03, l); c##r##1 = vfmaq_laneq_f32(c##r##1, b1, a03, l); \
    c##r##2 = vfmaq_laneq_f32(c##r##2, b2, a03, l); c##r##3 = vfmaq_laneq_f32(c##r##3, b3, a03, l);
#define ROWD(r, l)                                                            \
    c##r##0 = vfmaq_lane_f32(c##r##0, b0, a45, l); c##r##1 = vfmaq_lane_f32(c##r##1, b1, a45, l); \
    c##r##2 = vfmaq_lane_f32(c##r##2, b2, a45, l); c##r##3 = vfmaq_lane_f32(c##r##3, b3, a45, l);
        ROWQ(0, 0) ROWQ(1, 1) ROWQ(2, 2) ROWQ(3, 3) ROWD(4, 0) ROWD(5, 1)
#undef ROWQ
#undef ROWD
        a += MR;
        b += NR;
    }
#define STOREROW(r)                                                           \
    vst1q_f32(c + r * ldc, c##r##0);     vst1q_f32(c + r * ldc + 4, c##r##1); \
    vst1q_f32(c + r * ldc + 8, c##r##2); vst1q_f32(c + r * ldc + 12, c##r##3);
    STOREROW(0) STOREROW(1) STOREROW(2) STOREROW(3) STOREROW(4) STOREROW(5)
#undef STOREROW
}

/* c[6][16] = sum over k4 of a[k4][6][4] * b[k4][16][4], exact, for CPUs
 * without the dot product: per row, each 16-byte weight vector (4 columns x
 * 4 k) times the row's 4 codes repeated, as int16 products (|p| <= 127^2),
 * pairwise-accumulated into int32 lanes [col k01, col k23, ...], folded with
 * addp at the end. */
static void ukr_q8_widen(int k4, const int8_t *a, const int8_t *b, int32_t *c)
{
    for (int r = 0; r < MR; r++) {
        int32x4_t acc[8];
        for (int q = 0; q < 8; q++)
            acc[q] = vdupq_n_s32(0);
        const int8_t *ap = a + 4 * r, *bp = b;
        for (int k = 0; k < k4; k++) {
            int32_t w;
            memcpy(&w, ap, sizeof w);
            int8x16_t av = vreinterpretq_s8_s32(vdupq_n_s32(w));
            for (int q = 0; q < 4; q++) {
                int8x16_t bq = vld1q_s8(bp + 16 * q);
                acc[2 * q] = vpadalq_s16(acc[2 * q], vmull_s8(vget_low_s8(bq), vget_low_s8(av)));
                acc[2 * q + 1] = vpadalq_s16(acc[2 * q + 1], vmull_high_s8(bq, av));
            }
            ap += 4 * MR;
            bp += 4 * NR;
        }
        for (int q = 0; q < 4; q++)
            vst1q_s32(c + NR * r + 4 * q, vpaddq_s32(acc[2 * q], acc[2 * q + 1]));
    }
}

/* ----------------------------------------------------------------- packing */

/* Rows [m0, m0 + rows) of A as micro-panels [i][k][6], zero rows to pad. */
static void pack_a_f32(const struct fk__asrc *src, int m0, int rows, int k, float *ap, float *tmp)
{
    int mp = (rows + MR - 1) / MR;
    for (int row = 0; row < mp * MR; row++) {
        float *d = ap + (size_t)(row / MR) * (size_t)k * MR + (size_t)(row % MR);
        if (row >= rows) {
            for (int kk = 0; kk < k; kk++)
                d[(size_t)kk * MR] = 0.0f;
            continue;
        }
        const float *x;
        if (!src->conv) {
            x = src->x + (size_t)(m0 + row) * (size_t)src->ldx;
        } else {
            fk__asrc_row(src, m0 + row, 0, k, tmp);
            x = tmp;
        }
        for (int kk = 0; kk < k; kk++)
            d[(size_t)kk * MR] = x[kk];
    }
}

/* Quantizes one row exactly like fk_quantize_row_q8 (max and the product
 * x * (127 / amax) are exact-the-same operations; FCVTNS rounds half to even
 * like nearbyintf; the clamp to +-127 never binds). */
static float quantize_row(const float *x, int k, int8_t *q)
{
    float32x4_t amax = vdupq_n_f32(0.0f), poison = amax;
    const float32x4_t zero = vdupq_n_f32(0.0f);
    int i = 0;
    for (; i + 4 <= k; i += 4) {
        float32x4_t v = vld1q_f32(x + i);
        poison = vaddq_f32(poison, vmulq_f32(v, zero));
        amax = vmaxq_f32(amax, vabsq_f32(v));
    }
    float am = vmaxvq_f32(amax), pz = vaddvq_f32(poison);
    for (; i < k; i++) {
        pz += x[i] * 0.0f;
        float a = fabsf(x[i]);
        if (a > am)
            am = a;
    }
    if (am == 0 || pz != 0) {
        memset(q, 0, (size_t)k);
        return am == 0 && pz == 0 ? 0.0f : NAN;
    }
    float invs = 127.0f / am;
    float32x4_t inv = vdupq_n_f32(invs);
    for (i = 0; i + 8 <= k; i += 8) {
        int32x4_t v0 = vcvtnq_s32_f32(vmulq_f32(vld1q_f32(x + i), inv));
        int32x4_t v1 = vcvtnq_s32_f32(vmulq_f32(vld1q_f32(x + i + 4), inv));
        vst1_s8(q + i, vqmovn_s16(vcombine_s16(vqmovn_s32(v0), vqmovn_s32(v1))));
    }
    for (; i < k; i++)
        q[i] = (int8_t)(int)nearbyintf(x[i] * invs);
    return am / 127.0f;
}

/* Quantizes rows [m0, m0 + rows) and packs them as micro-panels [i][k4][6][4]. */
static void pack_a_q8(const struct fk__asrc *src, int m0, int rows, int k, int k_pad, int8_t *ap,
                      float *sa, float *rowbuf, int8_t *q)
{
    int mp = (rows + MR - 1) / MR;
    size_t panel = (size_t)k_pad * MR;
    for (int row = 0; row < mp * MR; row++) {
        if (row < rows) {
            const float *x;
            if (!src->conv) {
                x = src->x + (size_t)(m0 + row) * (size_t)src->ldx;
            } else {
                fk__asrc_row(src, m0 + row, 0, k, rowbuf);
                x = rowbuf;
            }
            sa[row] = quantize_row(x, k, q);
        } else {
            sa[row] = 0;
            memset(q, 0, (size_t)k);
        }
        for (int kk = k; kk < k_pad; kk++)
            q[kk] = 0;
        int8_t *d = ap + (size_t)(row / MR) * panel + (size_t)(row % MR) * 4;
        for (int k4 = 0; k4 < k_pad / 4; k4++)
            memcpy(d + (size_t)k4 * MR * 4, q + 4 * k4, 4);
    }
}

/* ---------------------------------------------------------------- epilogue */

static inline float32x4_t activate(enum fk_act act, float32x4_t v)
{
    switch (act) {
    case FK_ACT_RELU: return fk__relu_neon(v);                /* NaN stays NaN */
    case FK_ACT_GELU: return fk__gelu_neon(v);
    case FK_ACT_SILU: return fk__silu_neon(v);
    default:          return v;
    }
}

/* Writes t[0..nn) (biased and activated) to row m, columns n0.., applying
 * LayerScale and the residual accumulation in the reference's order. */
static void store_row(const struct fk__cdst *c, const struct fk_epilogue *ep, int m, int n0, int nn,
                      const float32x4_t t[4])
{
    int contiguous = !c->tconv_k || (n0 % c->tconv_cout) + nn <= c->tconv_cout;
    if (contiguous && nn == NR) {
        float *d = fk__cdst_ptr(c, m, n0);
        for (int q = 0; q < 4; q++) {
            float32x4_t v = t[q];
            if (ep->gamma)
                v = vmulq_f32(v, vld1q_f32(ep->gamma + n0 + 4 * q));
            if (ep->accumulate)
                v = vaddq_f32(vld1q_f32(d + 4 * q), v);
            vst1q_f32(d + 4 * q, v);
        }
        return;
    }
    float tt[NR];
    for (int q = 0; q < 4; q++)
        vst1q_f32(tt + 4 * q, t[q]);
    for (int j = 0; j < nn; j++) {
        float v = ep->gamma ? tt[j] * ep->gamma[n0 + j] : tt[j];
        float *d = fk__cdst_ptr(c, m, n0 + j);
        *d = ep->accumulate ? *d + v : v;
    }
}

/* ------------------------------------------------------------------ driver */

struct gemm_job {
    fk_ctx                   *ctx;
    const struct fk_linear   *L;
    const struct fk__asrc    *a;
    const struct fk__cdst    *c;
    const struct fk_epilogue *ep;
    int    m, mc, kc, n_chunks, panels, panels_per_chunk, k_pad, dot;
    size_t off_c, off_b, off_tmp, off_q, off_sa;
};

static void task_float(const struct gemm_job *j, int m0, int rows, int jp0, int jp1, char *s)
{
    const struct fk_linear *L = j->L;
    int k = L->k, mp = (rows + MR - 1) / MR;
    float *ap = (float *)s, *ct = (float *)(s + j->off_c), *bconv = (float *)(s + j->off_b);
    pack_a_f32(j->a, m0, rows, k, ap, (float *)(s + j->off_tmp));
    for (int jp = jp0; jp < jp1; jp++) {
        for (int k0 = 0; k0 < k; k0 += j->kc) {
            int kc = k - k0 < j->kc ? k - k0 : j->kc;
            const float *bp;
            if (L->type == FK_W_F32) {
                bp = (const float *)L->data + ((size_t)jp * (size_t)k + (size_t)k0) * NR;
            } else {
                const uint16_t *h = (const uint16_t *)L->data + ((size_t)jp * (size_t)k + (size_t)k0) * NR;
                for (int e = 0; e < kc * NR; e += 4)
                    vst1q_f32(bconv + e, vcvt_f32_f16(vreinterpret_f16_u16(vld1_u16(h + e))));
                bp = bconv;
            }
            for (int i = 0; i < mp; i++)
                fk__ukr_f32_6x16_neon(kc, ap + ((size_t)i * (size_t)k + (size_t)k0) * MR, bp,
                                      ct + (size_t)i * MR * NR, NR, k0 > 0);
        }
        int n0 = jp * NR, nn = L->n - n0 < NR ? L->n - n0 : NR;
        for (int r = 0; r < rows; r++) {
            float32x4_t t[4];
            for (int q = 0; q < 4; q++)
                t[q] = activate(j->ep->act, vaddq_f32(vld1q_f32(ct + (size_t)r * NR + 4 * q),
                                                      vld1q_f32(L->bias + n0 + 4 * q)));
            store_row(j->c, j->ep, m0 + r, n0, nn, t);
        }
    }
}

static void task_q8(const struct gemm_job *j, int m0, int rows, int jp0, int jp1, char *s)
{
    const struct fk_linear *L = j->L;
    int mp = (rows + MR - 1) / MR, k4 = j->k_pad / 4;
    int8_t *ap = (int8_t *)s;
    int32_t *ct = (int32_t *)(s + j->off_c);
    float *sa = (float *)(s + j->off_sa);
    pack_a_q8(j->a, m0, rows, L->k, j->k_pad, ap, sa, (float *)(s + j->off_tmp),
              (int8_t *)(s + j->off_q));
    for (int i = 0; i < mp; i++) {
        const int8_t *ai = ap + (size_t)i * (size_t)j->k_pad * MR;
        int r0 = i * MR, nr = rows - r0 < MR ? rows - r0 : MR;
        for (int jp = jp0; jp < jp1; jp++) {
            const int8_t *bp = (const int8_t *)L->data + (size_t)jp * (size_t)j->k_pad * NR;
            if (j->dot)
                fk__gemm_q8_ukr_sdot(k4, ai, bp, ct);
            else
                ukr_q8_widen(k4, ai, bp, ct);
            int n0 = jp * NR, nn = L->n - n0 < NR ? L->n - n0 : NR;
            for (int r = 0; r < nr; r++) {
                float32x4_t sr = vdupq_n_f32(sa[r0 + r]), t[4];
                for (int q = 0; q < 4; q++) {
                    /* fmaf(acc, sa * sw, b), as the reference */
                    float32x4_t acc = vcvtq_f32_s32(vld1q_s32(ct + r * NR + 4 * q));
                    float32x4_t sc = vmulq_f32(sr, vld1q_f32(L->scale + n0 + 4 * q));
                    t[q] = activate(j->ep->act, vfmaq_f32(vld1q_f32(L->bias + n0 + 4 * q), acc, sc));
                }
                store_row(j->c, j->ep, m0 + r0 + r, n0, nn, t);
            }
        }
    }
}

static void gemm_task(void *arg, int task, int thread)
{
    const struct gemm_job *j = arg;
    int mb = task / j->n_chunks, nb = task % j->n_chunks;
    int m0 = mb * j->mc, rows = j->m - m0 < j->mc ? j->m - m0 : j->mc;
    int jp0 = nb * j->panels_per_chunk;
    int jp1 = jp0 + j->panels_per_chunk < j->panels ? jp0 + j->panels_per_chunk : j->panels;
    char *s = fk__scratch(j->ctx, thread);
    if (j->L->type == FK_W_Q8)
        task_q8(j, m0, rows, jp0, jp1, s);
    else
        task_float(j, m0, rows, jp0, jp1, s);
}

int fk__gemm_neon(fk_ctx *ctx, const struct fk_linear *L, const struct fk__asrc *a, int m,
                  const struct fk__cdst *c, const struct fk_epilogue *ep)
{
    struct gemm_job j = { .ctx = ctx, .L = L, .a = a, .c = c, .ep = ep, .m = m, .n_chunks = 1 };
    int k = L->k, q8 = L->type == FK_W_Q8;
    j.dot = q8 && (fk_cpu_features() & FK_CPU_ASIMDDP);
    j.k_pad = q8 ? (int)fk__round_up((size_t)k, 4) : k;
    j.panels = (L->n + NR - 1) / NR;

    /* the packed rows of A stay in L2 (256-512 KB on A76/A78) for the task */
    size_t a_row = q8 ? (size_t)j.k_pad : (size_t)k * 4;
    int mc = (int)((size_t)(192 * 1024) / a_row) / MR * MR;
    if (mc > 144)
        mc = 144;
    if (mc < MR)
        mc = MR;
    /* enough tasks for all threads: shrink mc, then split the panels */
    int threads = ctx->threads;
    mc = fk__gemm_plan_mc(threads, m, mc, MR);
    j.mc = mc;
    int m_blocks = (m + mc - 1) / mc;
    fk__gemm_plan_chunks(threads, m_blocks, j.panels, &j.n_chunks, &j.panels_per_chunk);

    j.kc = fk_ctx_gemm_blocks(ctx).kc;
    if (j.kc < 8)
        j.kc = 8;
    size_t mcp = fk__round_up((size_t)mc, MR);
    j.off_c = fk__round_up(mcp * a_row, FK_ALIGN);
    j.off_b = j.off_c + fk__round_up((q8 ? MR : mcp) * NR * 4, FK_ALIGN);
    j.off_tmp = j.off_b + (L->type == FK_W_F16 ? (size_t)j.kc * NR * 4 : 0);
    j.off_q = j.off_tmp + fk__round_up(a->conv ? (size_t)k * 4 : 0, FK_ALIGN);
    j.off_sa = j.off_q + (q8 ? fk__round_up((size_t)j.k_pad, FK_ALIGN) : 0);
    size_t need = j.off_sa + (q8 ? mcp * 4 : 0) + FK_ALIGN;
    int st = fk__scratch_reserve(ctx, need, 0);
    if (st || fk__measuring(ctx))
        return st;
    double work = 2.0 * m * (double)L->n * k;
    fk_parallel_for(ctx, m_blocks * j.n_chunks, work, gemm_task, &j);
    return F4D_OK;
}
