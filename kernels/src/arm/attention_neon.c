/* attention_neon.c - multi-head attention with an online softmax (AArch64
 * NEON): the algorithm of x86/attention_avx2.c with four-lane vectors.
 *
 * Heads are processed in groups sized so that the group's transformed keys,
 * values and queries fit a few MB of shared scratch:
 *   phase 1 (parallel over token chunks): q/k LayerNorm and RoPE, q scaled by
 *     scale * log2(e) (so the softmax uses exp2), keys packed as 16-wide
 *     panels [d][16], values as rows [nk_pad][d], queries as 6-row panels;
 *   phase 2 (parallel over head x 96-query blocks): for each 64-key block,
 *     S = Q K^T by the GEMM's 6x16 register tile, the running max / sum
 *     update, and O = alpha O + P V by a 6x16 tile. Nothing N_q x N_k is ever
 *     stored. Head dims that are not a multiple of 16 use the reference. */
#include <arm_neon.h>
#include <float.h>
#include <math.h>
#include <string.h>

#include "../attention.h"
#include "../fk_internal.h"
#include "arm.h"
#include "vecmath_neon.h"

#define MR 6
#define NR 16
#define BK 64                  /* keys per block                    */
#define QB 96                  /* queries per task                  */
#define GROUP_BYTES (8u << 20) /* shared scratch per head group      */
#define LOG2E 1.4426950408889634f

struct rope_table {
    int          on, lo, span, quarter;  /* positions lo .. lo + span - 1 */
    const float *cos, *sin;              /* [span][quarter]               */
};

struct attn_job {
    fk_ctx                         *ctx;
    const struct fk_attention_desc *a;
    const float *q, *k, *v;
    int    ldq, ldk, ldv, nq, nk, ldo, d, nk_pad, nq_pad;
    int    h0, hn;                       /* heads of this group           */
    float  qscale;
    float *out;
    float *kp, *vp, *qp;                 /* group scratch, per head blocks */
    size_t head_k, head_v, head_q;       /* floats per head                */
    struct rope_table rope;
    int    chunk, k_chunks, q_chunks, q_blocks;
    size_t off_o, off_ml;
};

/* ------------------------------------------------------------------- prep */

static void rope_apply(const struct rope_table *rt, float *t, int d, const int32_t *pos)
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

/* LayerNorm over d (a multiple of 16) in registers. */
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

static void prep_vec(const struct attn_job *j, int which, const float *src, const int32_t *pos,
                     float *dst)
{
    const struct fk_attention_desc *a = j->a;
    int d = j->d;
    memcpy(dst, src, (size_t)d * sizeof *dst);
    const float *w = which == 0 ? a->q_norm_w : a->k_norm_w;
    const float *b = which == 0 ? a->q_norm_b : a->k_norm_b;
    if (a->qk_norm || w || b)
        head_norm(dst, d, w, b, a->norm_eps);
    if (pos) {
        if (j->rope.on)
            rope_apply(&j->rope, dst, d, pos);
        else
            fk_rope2d_ref(dst, d, pos[0], pos[1], a->rope_base > 0 ? a->rope_base : 100.0f);
    }
}

static void prep_task(void *arg, int task, int thread)
{
    const struct attn_job *j = arg;
    int d = j->d;
    float buf[1024] __attribute__((aligned(32)));
    (void)thread;
    if (task < j->k_chunks) { /* keys and values */
        int t0 = task * j->chunk, t1 = t0 + j->chunk < j->nk_pad ? t0 + j->chunk : j->nk_pad;
        for (int h = j->h0; h < j->h0 + j->hn; h++) {
            float *kp = j->kp + (size_t)(h - j->h0) * j->head_k;
            float *vp = j->vp + (size_t)(h - j->h0) * j->head_v;
            for (int t = t0; t < t1; t++) {
                float *kd = kp + (size_t)(t / NR) * (size_t)d * NR + (size_t)(t % NR);
                if (t < j->nk) {
                    prep_vec(j, 1, j->k + (size_t)t * (size_t)j->ldk + (size_t)h * (size_t)d,
                             j->a->pos_k ? j->a->pos_k + 2 * t : NULL, buf);
                    for (int c = 0; c < d; c++)
                        kd[(size_t)c * NR] = buf[c];
                    memcpy(vp + (size_t)t * (size_t)d, j->v + (size_t)t * (size_t)j->ldv + (size_t)h * (size_t)d,
                           (size_t)d * sizeof(float));
                } else {
                    for (int c = 0; c < d; c++)
                        kd[(size_t)c * NR] = 0;
                    memset(vp + (size_t)t * (size_t)d, 0, (size_t)d * sizeof(float));
                }
            }
        }
        return;
    }
    task -= j->k_chunks; /* queries */
    int t0 = task * j->chunk, t1 = t0 + j->chunk < j->nq_pad ? t0 + j->chunk : j->nq_pad;
    for (int h = j->h0; h < j->h0 + j->hn; h++) {
        float *qp = j->qp + (size_t)(h - j->h0) * j->head_q;
        for (int t = t0; t < t1; t++) {
            float *qd = qp + (size_t)(t / MR) * (size_t)d * MR + (size_t)(t % MR);
            if (t < j->nq) {
                prep_vec(j, 0, j->q + (size_t)t * (size_t)j->ldq + (size_t)h * (size_t)d,
                         j->a->pos_q ? j->a->pos_q + 2 * t : NULL, buf);
                for (int c = 0; c < d; c++)
                    qd[(size_t)c * MR] = buf[c] * j->qscale;
            } else {
                for (int c = 0; c < d; c++)
                    qd[(size_t)c * MR] = 0;
            }
        }
    }
}

/* -------------------------------------------------------------- the tiles */

/* o[6][d] = alpha[r] o[r] + p[6][BK] . v[BK][d], 16 columns at a time */
__attribute__((noinline)) static void pv_tile(int d, const float *p, const float *v, float *o, const float *alpha)
{
    for (int c0 = 0; c0 < d; c0 += 16) {
        float *oc = o + c0;
        float32x4_t acc[MR][4];
        for (int r = 0; r < MR; r++) {
            float32x4_t a = vdupq_n_f32(alpha[r]);
            for (int q = 0; q < 4; q++)
                acc[r][q] = vmulq_f32(a, vld1q_f32(oc + (size_t)r * (size_t)d + 4 * q));
        }
        const float *vr = v + c0;
        for (int jj = 0; jj < BK; jj += 4) {
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

static void attn_task(void *arg, int task, int thread)
{
    const struct attn_job *j = arg;
    int hh = task / j->q_blocks, qb = task % j->q_blocks, d = j->d;
    int h = j->h0 + hh;
    const float *kp = j->kp + (size_t)hh * j->head_k, *vp = j->vp + (size_t)hh * j->head_v;
    const float *qp = j->qp + (size_t)hh * j->head_q;
    char *scr = fk__scratch(j->ctx, thread);
    float *s = (float *)scr;                  /* [6][BK]    */
    float *o = (float *)(scr + j->off_o);     /* [QB][d]    */
    float *ml = (float *)(scr + j->off_ml);   /* m[QB] l[QB] alpha[8] */
    float *mrow = ml, *lrow = ml + QB, *alpha = ml + 2 * QB;
    int q0 = qb * QB, rows = j->nq - q0 < QB ? j->nq - q0 : QB;
    int panels = (rows + MR - 1) / MR;
    memset(o, 0, (size_t)panels * MR * (size_t)d * sizeof *o);
    for (int r = 0; r < panels * MR; r++) {
        mrow[r] = -INFINITY;
        lrow[r] = 0;
    }
    for (int kb = 0; kb < j->nk_pad / BK; kb++) {
        int valid = j->nk - kb * BK < BK ? j->nk - kb * BK : BK;
        for (int i = 0; i < panels; i++) {
            const float *qi = qp + (size_t)(q0 / MR + i) * (size_t)d * MR;
            for (int p = 0; p < BK / NR; p++)
                fk__ukr_f32_6x16_neon(d, qi, kp + (size_t)(kb * (BK / NR) + p) * (size_t)d * NR,
                                      s + p * NR, BK, 0);
            softmax_block(s, valid, mrow + i * MR, lrow + i * MR, alpha);
            pv_tile(d, s, vp + (size_t)kb * BK * (size_t)d, o + (size_t)i * MR * (size_t)d, alpha);
        }
    }
    for (int r = 0; r < rows; r++) {
        float *dst = j->out + (size_t)(q0 + r) * (size_t)j->ldo + (size_t)h * (size_t)d;
        float32x4_t inv = vdupq_n_f32(1.0f / lrow[r]);
        for (int c = 0; c < d; c += 4)
            vst1q_f32(dst + c, vmulq_f32(vld1q_f32(o + (size_t)r * (size_t)d + c), inv));
    }
}

/* ------------------------------------------------------------------ driver */

/* RoPE cos/sin per distinct position value (VGGT's grid has a few dozen),
 * so no token pays for sinf/cosf; NULL table = positions too spread out. */
static long rope_span(const struct attn_job *j, int *lo_out)
{
    const struct fk_attention_desc *a = j->a;
    int lo = a->pos_q[0], hi = lo;
    for (int t = 0; t < 2 * j->nq; t++) {
        lo = a->pos_q[t] < lo ? a->pos_q[t] : lo;
        hi = a->pos_q[t] > hi ? a->pos_q[t] : hi;
    }
    for (int t = 0; t < 2 * j->nk; t++) {
        lo = a->pos_k[t] < lo ? a->pos_k[t] : lo;
        hi = a->pos_k[t] > hi ? a->pos_k[t] : hi;
    }
    *lo_out = lo;
    return (long)hi - lo + 1;
}

static void build_rope(struct attn_job *j, int lo, int span, float *t)
{
    const struct fk_attention_desc *a = j->a;
    int quarter = j->d / 4, m = j->d / 2;
    float base = a->rope_base > 0 ? a->rope_base : 100.0f;
    float *sn = t + (size_t)span * (size_t)quarter;
    for (int p = 0; p < span; p++)
        for (int k = 0; k < quarter; k++) {
            float inv_freq = (float)(1.0 / pow((double)base, (double)(2 * k) / (double)m));
            float theta = (float)(lo + p) * inv_freq;
            t[(size_t)p * (size_t)quarter + (size_t)k] = cosf(theta);
            sn[(size_t)p * (size_t)quarter + (size_t)k] = sinf(theta);
        }
    j->rope = (struct rope_table){ 1, lo, span, quarter, t, sn };
}

int fk__attention_neon(fk_ctx *ctx, const struct fk_attention_desc *a, const float *q, int ldq,
                       int nq, const float *k, int ldk, const float *v, int ldv, int nk,
                       float *out, int ldo)
{
    int d = a->head_dim;
    if (d % 16 != 0 || d > 1024)
        return fk__attention_ref(ctx, a, q, ldq, nq, k, ldk, v, ldv, nk, out, ldo);
    struct attn_job j = { 0 };
    j.ctx = ctx; j.a = a; j.q = q; j.k = k; j.v = v;
    j.ldq = ldq; j.ldk = ldk; j.ldv = ldv; j.ldo = ldo; j.nq = nq; j.nk = nk; j.d = d; j.out = out;
    j.nk_pad = (int)fk__round_up((size_t)nk, BK);
    j.nq_pad = (int)fk__round_up((size_t)nq, MR);
    j.qscale = (a->scale > 0 ? a->scale : 1.0f / sqrtf((float)d)) * LOG2E;
    j.head_k = (size_t)j.nk_pad * (size_t)d;
    j.head_v = (size_t)j.nk_pad * (size_t)d;
    j.head_q = (size_t)j.nq_pad * (size_t)d;
    size_t per_head = (j.head_k + j.head_v + j.head_q) * sizeof(float);
    int group = (int)(GROUP_BYTES / per_head);
    if (group < 1)
        group = 1;
    if (group > a->heads)
        group = a->heads;

    int lo = 0;
    long span = a->pos_q ? rope_span(&j, &lo) : 0;
    if (span > 65536)
        span = 0; /* per-token sinf/cosf instead of a table */
    size_t table = fk__round_up((size_t)span * (size_t)(d / 4) * 2 * sizeof(float), FK_ALIGN);
    j.off_o = fk__round_up((size_t)MR * BK * sizeof(float), FK_ALIGN);
    j.off_ml = j.off_o + fk__round_up((size_t)QB * (size_t)d * sizeof(float), FK_ALIGN);
    size_t local = j.off_ml + (2 * QB + 8) * sizeof(float) + FK_ALIGN;
    /* A bound that grows monotonically with nq / nk (as on AVX2): a smaller
     * problem may fit more heads per group, so per_head * group measured at
     * the largest size (fk_ctx_measure) would not cover it. */
    size_t grp_bytes = per_head > GROUP_BYTES ? per_head : GROUP_BYTES;
    if (grp_bytes > per_head * (size_t)a->heads)
        grp_bytes = per_head * (size_t)a->heads;
    int st = fk__scratch_reserve(ctx, local, table + grp_bytes + 3 * FK_ALIGN);
    if (st || fk__measuring(ctx))
        return st;
    char *sh = fk__scratch_shared(ctx);
    if (span > 0)
        build_rope(&j, lo, (int)span, (float *)sh);
    sh += table;
    j.chunk = 128;
    j.k_chunks = j.nk_pad / j.chunk + (j.nk_pad % j.chunk != 0);
    j.q_chunks = j.nq_pad / j.chunk + (j.nq_pad % j.chunk != 0);
    j.q_blocks = (nq + QB - 1) / QB;
    double att_work = 4.0 * d * (double)nq * nk;
    for (int h0 = 0; h0 < a->heads; h0 += group) {
        j.h0 = h0;
        j.hn = a->heads - h0 < group ? a->heads - h0 : group;
        j.kp = (float *)sh;
        j.vp = (float *)fk__round_up((uintptr_t)(j.kp + j.head_k * (size_t)j.hn), FK_ALIGN);
        j.qp = (float *)fk__round_up((uintptr_t)(j.vp + j.head_v * (size_t)j.hn), FK_ALIGN);
        fk_parallel_for(ctx, j.k_chunks + j.q_chunks, 20.0 * d * j.hn * (double)(nq + nk), prep_task, &j);
        fk_parallel_for(ctx, j.hn * j.q_blocks, att_work * j.hn, attn_task, &j);
    }
    return F4D_OK;
}
