/* attention_bf16_avx512.c - attention's two products in bfloat16 (AVX512_BF16
 * vdpbf16ps: two multiply-adds per 32-bit lane, fp32 accumulation), run by
 * attention_plan.c for a desc with bf16 set where fk_ctx_has_bf16 (see
 * attention_plan.h). The plan's phase 1 (LayerNorm, RoPE, q scaled by
 * scale * log2 e, fp32 packs) is reused; this file rounds the packs to bf16
 * pairs once per head group and runs the blocks:
 *   keys   [nk_pad/16][dp/2][16] pairs (k[2i], k[2i+1]) of 16 keys: a zmm;
 *   values [nk_pad/2][dp] pairs (v of keys 2j, 2j+1) per column;
 *   queries per task [panels][dp/2][6] pairs, broadcast one per row;
 *   p     [6][SB/2] pairs of adjacent keys, rounded after the fp32 softmax.
 * S = Q K^T is dp/2 steps of 24 vdpbf16ps per 64 keys, O = alpha O + P V is
 * a step of 6 x dp/16 per key pair: half the instructions of the fp32 tiles.
 * The online softmax (max, exp2, alpha) is the fp32 one, run on SB = 256
 * keys (four of the plan's 64-key blocks) at a time, which quarters its
 * per-key work (row maxima and sums, rescaling O); the row sum l adds the
 * bf16-rounded p that multiply v, so the normalisation matches the weights
 * used. */
#include <immintrin.h>
#include <math.h>
#include <string.h>

#include "../attention_plan.h"
#include "../fk_internal.h"
#include "vecmath_avx512.h"

#define MR FK_ATTN_MR
#define NR FK_ATTN_NR
#define BK FK_ATTN_BK
#define SB (4 * BK) /* keys per softmax block */
#define QB FK_ATTN_QB
#define PACK_CHUNK 256 /* keys per pack task */

/* local scratch: s [MR][SB] f32, p [MR][SB/2] pairs, o [QB][dp] f32,
 * m l [QB] + alpha [16], q pairs [QB/MR][dp/2][MR] */
struct bf16_local {
    size_t off_p, off_o, off_ml, off_q, bytes;
};

static struct bf16_local local_layout(int dp)
{
    struct bf16_local L;
    L.off_p = fk__round_up((size_t)MR * SB * sizeof(float), FK_ALIGN);
    L.off_o = L.off_p + fk__round_up((size_t)MR * (SB / 2) * sizeof(uint32_t), FK_ALIGN);
    L.off_ml = L.off_o + fk__round_up((size_t)QB * (size_t)dp * sizeof(float), FK_ALIGN);
    L.off_q = L.off_ml + fk__round_up((2 * QB + 16) * sizeof(float), FK_ALIGN);
    L.bytes = L.off_q + (size_t)QB * (size_t)dp * sizeof(uint16_t) + FK_ALIGN;
    return L;
}

void fk__attn_bf16_bytes(int dp, int nk_pad, size_t *local, size_t *per_head)
{
    *local = local_layout(dp).bytes;
    *per_head = 2 * fk__round_up((size_t)nk_pad * (size_t)dp * sizeof(uint16_t), FK_ALIGN);
}

/* 16 pairs (lo[i], hi[i]) rounded to nearest even, lo in the low half. */
static inline __m512i pairs16(const float *lo, const float *hi)
{
    __m512i a = _mm512_cvtepu16_epi32((__m256i)_mm512_cvtneps_pbh(_mm512_loadu_ps(lo)));
    __m512i b = _mm512_cvtepu16_epi32((__m256i)_mm512_cvtneps_pbh(_mm512_loadu_ps(hi)));
    return _mm512_or_si512(a, _mm512_slli_epi32(b, 16));
}

/* ------------------------------------------------------------------ packs */

static void pack_task(void *arg, int task, int thread)
{
    const struct fk__attn_bf16_job *j = arg;
    int chunks = (j->nk_pad + PACK_CHUNK - 1) / PACK_CHUNK, dp = j->dp;
    int hh = task / chunks, t0 = task % chunks * PACK_CHUNK;
    int t1 = t0 + PACK_CHUNK < j->nk_pad ? t0 + PACK_CHUNK : j->nk_pad;
    const float *kp = j->kp + (size_t)hh * j->head_k, *vp = j->vp + (size_t)hh * j->head_v;
    uint32_t *kb = j->kb + (size_t)hh * j->head_kb, *vb = j->vb + (size_t)hh * j->head_kb;
    (void)thread;
    for (int t = t0; t < t1; t += NR) { /* 16 keys of an fp32 panel [dp][kw] -> [dp/2][16] pairs */
        size_t kw = (size_t)j->kw;
        const float *src = kp + (size_t)t / kw * (size_t)dp * kw + (size_t)t % kw;
        uint32_t *dst = kb + (size_t)t * (size_t)dp / 2;
        for (int i = 0; i < dp / 2; i++)
            _mm512_storeu_si512(dst + (size_t)i * NR, pairs16(src + (size_t)(2 * i) * kw, src + (size_t)(2 * i + 1) * kw));
    }
    for (int t = t0; t < t1; t += 2) { /* rows t, t+1 [dp] -> [dp] pairs */
        const float *r0 = vp + (size_t)t * (size_t)dp, *r1 = r0 + dp;
        uint32_t *dst = vb + (size_t)t / 2 * (size_t)dp;
        for (int c = 0; c < dp; c += 16)
            _mm512_storeu_si512(dst + c, pairs16(r0 + c, r1 + c));
    }
}

/* q panel [dp][6] f32 -> [dp/2][6] pairs (q[2i][r], q[2i+1][r]) */
static void pack_q(int dp, const float *q, uint32_t *dst)
{
    uint16_t h[6 * 1024] __attribute__((aligned(64)));
    for (int c = 0; c < MR * dp; c += 16)
        _mm256_store_si256((__m256i *)(h + c), (__m256i)_mm512_cvtneps_pbh(_mm512_loadu_ps(q + c)));
    for (int i = 0; i < dp / 2; i++)
        for (int r = 0; r < MR; r++)
            dst[i * MR + r] = (uint32_t)h[2 * i * MR + r] | (uint32_t)h[(2 * i + 1) * MR + r] << 16;
}

/* ------------------------------------------------------------------ tiles */

/* s[6][64] (row stride SB) = q pairs [dp/2][6] . the 4 key panels [dp/2][16] at kb */
__attribute__((noinline)) static void s_block(int dp, const uint32_t *q, const uint32_t *kb, float *s)
{
    __m512 c[MR][4];
    for (int r = 0; r < MR; r++)
        for (int p = 0; p < 4; p++)
            c[r][p] = _mm512_setzero_ps();
    const size_t ps = (size_t)dp / 2 * NR;
    int i = 0;
    do { /* dp >= 16: no empty path, so GCC keeps c in registers */
        const uint32_t *b = kb + (size_t)i * NR;
        __m512bh b0 = (__m512bh)_mm512_loadu_si512(b), b1 = (__m512bh)_mm512_loadu_si512(b + ps);
        __m512bh b2 = (__m512bh)_mm512_loadu_si512(b + 2 * ps), b3 = (__m512bh)_mm512_loadu_si512(b + 3 * ps);
        for (int r = 0; r < MR; r++) {
            __m512bh t = (__m512bh)_mm512_set1_epi32((int)q[i * MR + r]);
            c[r][0] = _mm512_dpbf16_ps(c[r][0], t, b0);
            c[r][1] = _mm512_dpbf16_ps(c[r][1], t, b1);
            c[r][2] = _mm512_dpbf16_ps(c[r][2], t, b2);
            c[r][3] = _mm512_dpbf16_ps(c[r][3], t, b3);
        }
    } while (++i < dp / 2);
    for (int r = 0; r < MR; r++)
        for (int p = 0; p < 4; p++)
            _mm512_storeu_ps(s + r * SB + p * NR, c[r][p]);
}

/* 2^x for the weights p, which are rounded to bf16 (2^-9 relative) right
 * after: a degree-3 polynomial on [-0.5, 0.5] (relative error 7.5e-5, a
 * 26th of that rounding; 2^0 still rounds to 1 exactly) and vscalefps.
 * The clamp at -127 keeps -inf (masked keys) finite: 2^-127 is a denormal,
 * which the bf16 conversion flushes to 0. NaN stays NaN. */
static inline __m512 exp2_p(__m512 x)
{
    x = _mm512_max_ps(_mm512_set1_ps(-127.0f), x);
    __m512 n = _mm512_roundscale_ps(x, _MM_FROUND_TO_NEAREST_INT | _MM_FROUND_NO_EXC);
    __m512 f = _mm512_sub_ps(x, n);
    __m512 p = _mm512_set1_ps(5.5171493256e-2f);
    p = _mm512_fmadd_ps(p, f, _mm512_set1_ps(2.4261110869e-1f));
    p = _mm512_fmadd_ps(p, f, _mm512_set1_ps(6.9326101791e-1f));
    p = _mm512_fmadd_ps(p, f, _mm512_set1_ps(9.9992807520e-1f));
    return _mm512_scalef_ps(p, n);
}

/* The online softmax over one 6 x nk block (nk a multiple of 64 up to SB, row stride SB),
 * as fk__attn_softmax_block_avx512; p rounded to bf16 pairs into
 * pb[6][SB/2]; l adds the rounded p (by vdpbf16ps with ones: the same
 * products, denormals flushed alike). */
static void softmax_block(float *s, int nk, int valid, float *m, float *l, float *alpha, uint32_t *pb)
{
    float m_new[16] __attribute__((aligned(64))) = { 0 }, m_old[16] __attribute__((aligned(64))) = { 0 };
    for (int r = 0; r < MR; r++) {
        float *sr = s + r * SB;
        for (int jj = valid; jj < nk; jj++)
            sr[jj] = -INFINITY;
        __m512 mx = _mm512_max_ps(_mm512_max_ps(_mm512_loadu_ps(sr), _mm512_loadu_ps(sr + 16)),
                                  _mm512_max_ps(_mm512_loadu_ps(sr + 32), _mm512_loadu_ps(sr + 48)));
        for (int jj = 64; jj < nk; jj += 64)
            mx = _mm512_max_ps(mx, _mm512_max_ps(_mm512_max_ps(_mm512_loadu_ps(sr + jj), _mm512_loadu_ps(sr + jj + 16)),
                                                 _mm512_max_ps(_mm512_loadu_ps(sr + jj + 32), _mm512_loadu_ps(sr + jj + 48))));
        float bm = _mm512_reduce_max_ps(mx);
        m_old[r] = m[r];
        m_new[r] = bm > m[r] ? bm : m[r];
    }
    __m512 al = fk__exp2_softmax512(_mm512_sub_ps(_mm512_load_ps(m_old), _mm512_load_ps(m_new)));
    _mm512_mask_storeu_ps(alpha, (__mmask16)0xff, al);
    const __m512bh ones = (__m512bh)_mm512_set1_epi32(0x3f803f80); /* bf16 1.0 pairs */
    for (int r = 0; r < MR; r++) {
        const float *sr = s + r * SB;
        __m512 mv = _mm512_set1_ps(m_new[r]), sum = _mm512_setzero_ps();
        for (int jj = 0; jj < nk; jj += 32) {
            __m512 p0 = exp2_p(_mm512_sub_ps(_mm512_loadu_ps(sr + jj), mv));
            __m512 p1 = exp2_p(_mm512_sub_ps(_mm512_loadu_ps(sr + jj + 16), mv));
            __m512bh h = _mm512_cvtne2ps_pbh(p1, p0); /* pairs (p[2w], p[2w+1]) */
            _mm512_storeu_si512(pb + r * (SB / 2) + jj / 2, (__m512i)h);
            sum = _mm512_dpbf16_ps(sum, h, ones);
        }
        l[r] = l[r] * alpha[r] + _mm512_reduce_add_ps(sum);
        m[r] = m_new[r];
    }
}

/* o[6][dp] columns c0 .. c0 + 16 NC: alpha[r] o[r] + p pairs . v pairs */
static inline __attribute__((always_inline)) void pv_cols(int dp, int np, int c0, const uint32_t *p,
                                                           const uint32_t *v, float *o,
                                                           const float *alpha, const int NC)
{
    __m512 c[MR][4];
    for (int r = 0; r < MR; r++) {
        __m512 a = _mm512_set1_ps(alpha[r]);
        for (int x = 0; x < NC; x++)
            c[r][x] = _mm512_mul_ps(a, _mm512_loadu_ps(o + (size_t)r * dp + c0 + 16 * x));
    }
    const uint32_t *vr = v + c0;
    for (int jp = 0; jp < np; jp++) {
        __m512bh b[4];
        for (int x = 0; x < NC; x++)
            b[x] = (__m512bh)_mm512_loadu_si512(vr + 16 * x);
        for (int r = 0; r < MR; r++) {
            __m512bh t = (__m512bh)_mm512_set1_epi32((int)p[r * (SB / 2) + jp]);
            for (int x = 0; x < NC; x++)
                c[r][x] = _mm512_dpbf16_ps(c[r][x], t, b[x]);
        }
        vr += dp;
    }
    for (int r = 0; r < MR; r++)
        for (int x = 0; x < NC; x++)
            _mm512_storeu_ps(o + (size_t)r * dp + c0 + 16 * x, c[r][x]);
}

/* o[6][dp] = alpha[r] o[r] + p[6][np] . v[np][dp] (np key pairs, p row
 * stride SB/2): 64 columns (24 zmm) at a time, then the 16-48 column tail */
__attribute__((noinline)) static void pv_tile(int dp, int np, const uint32_t *p, const uint32_t *v,
                                              float *o, const float *alpha)
{
    int c0 = 0;
    for (; c0 + 64 <= dp; c0 += 64)
        pv_cols(dp, np, c0, p, v, o, alpha, 4);
    switch ((dp - c0) / 16) {
    case 3: pv_cols(dp, np, c0, p, v, o, alpha, 3); break;
    case 2: pv_cols(dp, np, c0, p, v, o, alpha, 2); break;
    case 1: pv_cols(dp, np, c0, p, v, o, alpha, 1); break;
    default: break;
    }
}

/* ------------------------------------------------------------------- task */

static void attn_task(void *arg, int task, int thread)
{
    const struct fk__attn_bf16_job *j = arg;
    int hh = task / j->q_blocks, qb = task % j->q_blocks, d = j->d, dp = j->dp;
    const uint32_t *kb = j->kb + (size_t)hh * j->head_kb, *vb = j->vb + (size_t)hh * j->head_kb;
    const float *qp = j->qp + (size_t)hh * j->head_q;
    struct bf16_local L = local_layout(dp);
    char *scr = fk__scratch(j->ctx, thread);
    float *s = (float *)scr, *o = (float *)(scr + L.off_o), *ml = (float *)(scr + L.off_ml);
    uint32_t *pb = (uint32_t *)(scr + L.off_p), *qb2 = (uint32_t *)(scr + L.off_q);
    float *mrow = ml, *lrow = ml + QB, *alpha = ml + 2 * QB;
    int q0 = qb * QB, rows = j->nq - q0 < QB ? j->nq - q0 : QB;
    int panels = (rows + MR - 1) / MR;
    const size_t qstride = (size_t)dp / 2 * MR;
    for (int i = 0; i < panels; i++)
        pack_q(dp, qp + (size_t)(q0 / MR + i) * (size_t)dp * MR, qb2 + (size_t)i * qstride);
    fk__attn_task_init(o, panels, dp, mrow, lrow);
    for (int k0 = 0; k0 < j->nk_pad; k0 += SB) { /* nk_pad is a multiple of BK */
        int nk = j->nk_pad - k0 < SB ? j->nk_pad - k0 : SB;
        int valid = j->nk - k0 < nk ? j->nk - k0 : nk;
        if (k0 + SB >= j->nk_pad)
            fk__attn_prefetch_out(j->out, j->ldo, q0, rows, (j->h0 + hh) * d, d);
        const uint32_t *kbb = kb + (size_t)k0 * (size_t)dp / 2;
        const uint32_t *vbb = vb + (size_t)k0 / 2 * (size_t)dp;
        for (int i = 0; i < panels; i++) {
            const uint32_t *qi = qb2 + (size_t)i * qstride;
            /* a last block: S only for the key blocks it has (the softmax
             * sets the rest to -inf), P V up to its last key pair (the
             * padding's p are 0 in bf16 and its v rows 0) */
            for (int kk = 0; kk < valid; kk += BK)
                s_block(dp, qi, kbb + (size_t)kk * (size_t)dp / 2, s + kk);
            softmax_block(s, nk, valid, mrow + i * MR, lrow + i * MR, alpha, pb);
            pv_tile(dp, (valid + 1) / 2, pb, vbb, o + (size_t)i * MR * (size_t)dp, alpha);
        }
    }
    fk__attn_task_write(j->out, j->ldo, q0, rows, (j->h0 + hh) * d, d, o, dp, lrow);
}

void fk__attn_bf16_run(const struct fk__attn_bf16_job *j)
{
    int chunks = (j->nk_pad + PACK_CHUNK - 1) / PACK_CHUNK;
    fk_parallel_for(j->ctx, j->hn * chunks, 4.0 * j->dp * j->hn * (double)j->nk_pad, pack_task, (void *)j);
    fk_parallel_for(j->ctx, j->hn * j->q_blocks, 4.0 * j->d * (double)j->nq * j->nk * j->hn, attn_task,
                    (void *)j);
}
