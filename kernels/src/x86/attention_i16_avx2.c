/* attention_i16_avx2.c - attention's two products in int16 with exact int32
 * sums (AVX2 vpmaddwd: two multiply-adds per 32-bit lane), run by
 * attention_plan.c for a desc with int16 set where the context's ISA is
 * FK_ISA_AVX2 (no VNNI, no AVX-512: the 7-bit int8 path, whose attention was
 * fp32 FMAs at the ymm peak's rate while its GEMMs ran at twice it),
 * FK_ISA_AVX2_VNNI (the products by VEX vpdpwssd, attention_i16_vnni.c) or
 * FK_ISA_AVX512 without bf16 attention (the products and the weight codes in
 * zmm, attention_i16_avx512.c); all give the same bits. The
 * plan's phase 1 (LayerNorm, RoPE, q scaled by scale * log2 e, fp32 packs)
 * is reused; this file quantizes the packs once per head group and runs the
 * blocks:
 *   keys    [nk_pad/16][dp/2][16] pairs (k[2i], k[2i+1]) of 16 keys, one
 *           scale per key (its max |k| over the head's channels);
 *   values  [nk_pad/2][dp] pairs (v of keys 2j, 2j+1) per column, one scale
 *           per column and 64-key block;
 *   queries per task [panels][dp/2][6] pairs, one scale per query;
 *   p       [6][BK/2] pairs, after the fp32 softmax: 2^(s - the block row's
 *           max) in [0, 1] times 4096, so each block's largest weight is
 *           4096 and the row's scale 2^(block max - running max) is one
 *           float per row and block (a code relative to the running max
 *           would round a diffuse block's weights to 0-2 codes each).
 * Codes are symmetric, |c| <= 2^b - 1 with b chosen from the head dim so
 * that no int32 sum can overflow: q.k sums dp products of two b-bit codes
 * (dp 2^2b < 2^31: b = 12 at dp 64, 13 at 16, 11 at 128), p.v sums the 64
 * products of one block (64 * 4096 * 4095 < 2^30) before it is converted
 * and scaled into the fp32 output. The softmax (max, exp2, alpha) stays
 * fp32, and the row sum l adds the quantized p that multiply v, so the
 * normalisation matches the weights used. Error: 12-bit codes relative to
 * each row's / column's largest value (README, kernels, attention; the
 * budget in tests/kernels/test_attention.c). NaN in q, k or v gives NaN
 * outputs as the fp32 kernel does (the codes cannot carry it: the scales
 * and l do). */
#include <immintrin.h>
#include <math.h>
#include <string.h>

#include "../attention_plan.h"
#include "../fk_internal.h"
#include "vecmath_avx2.h"

#define MR FK_ATTN_MR
#define NR FK_ATTN_NR
#define BK FK_ATTN_BK
#define QB FK_ATTN_QB
#define PACK_CHUNK 256 /* keys per pack task, a multiple of BK */
#define P_ONE 4096.0f  /* p = 1 as a code                      */
#define V_MAX 4095.0f  /* largest |v| code                     */

/* local scratch: s [MR][BK] f32, p [MR][BK/2] pairs, o [QB][dp] f32,
 * m l [QB] + alpha [8] + ps [8], q pairs [QB/MR][dp/2][MR], q scales [QB],
 * q codes of one panel [dp][MR] */
struct i16_local {
    size_t off_p, off_o, off_ml, off_q, off_sq, off_cb, bytes;
};

static struct i16_local local_layout(int dp)
{
    struct i16_local L;
    L.off_p = fk__round_up((size_t)MR * BK * sizeof(float), FK_ALIGN);
    L.off_o = L.off_p + fk__round_up((size_t)MR * (BK / 2) * sizeof(uint32_t), FK_ALIGN);
    L.off_ml = L.off_o + fk__round_up((size_t)QB * (size_t)dp * sizeof(float), FK_ALIGN);
    L.off_q = L.off_ml + fk__round_up((2 * QB + 16) * sizeof(float), FK_ALIGN);
    L.off_sq = L.off_q + fk__round_up((size_t)QB * (size_t)dp * sizeof(uint16_t), FK_ALIGN);
    L.off_cb = L.off_sq + fk__round_up(QB * sizeof(float), FK_ALIGN);
    L.bytes = L.off_cb + (size_t)MR * (size_t)dp * sizeof(int32_t) + FK_ALIGN;
    return L;
}

size_t fk__attn_i16_local_bytes(int dp) { return local_layout(dp).bytes; }

/* The q / k code bound: dp products of two codes below 2^b each must sum
 * below 2^31 in int32 (and a vpmaddwd pair below 2^31: b <= 15). */
static float qk_max(int dp)
{
    int lg = 0;
    while ((1 << lg) < dp)
        lg++;
    int b = (30 - lg) / 2;
    b = b > 14 ? 14 : b;
    return (float)((1 << b) - 1);
}

/* 8 pairs (lo[i], hi[i]) of int32 codes in 16 bits each, lo in the low half */
static inline __m256i pairs8(__m256i lo, __m256i hi)
{
    return _mm256_or_si256(_mm256_and_si256(lo, _mm256_set1_epi32(0xffff)), _mm256_slli_epi32(hi, 16));
}

/* ------------------------------------------------------------------ packs */

struct i16_head {
    uint32_t *kq, *vq;
    float    *sk, *sv;
};

static struct i16_head head_of(const struct fk__attn_i16_job *j, int hh)
{
    struct i16_head h;
    h.kq = j->kq + (size_t)hh * j->head_pairs;
    h.vq = j->vq + (size_t)hh * j->head_pairs;
    h.sk = j->sk + (size_t)hh * (size_t)j->nk_pad;
    h.sv = j->sv + (size_t)hh * (size_t)(j->nk_pad / BK) * (size_t)j->dp;
    return h;
}

static void pack_task(void *arg, int task, int thread)
{
    const struct fk__attn_i16_job *j = arg;
    int chunks = (j->nk_pad + PACK_CHUNK - 1) / PACK_CHUNK, dp = j->dp;
    int hh = task / chunks, t0 = task % chunks * PACK_CHUNK;
    int t1 = t0 + PACK_CHUNK < j->nk_pad ? t0 + PACK_CHUNK : j->nk_pad;
    const float *kp = j->kp + (size_t)hh * j->head_k, *vp = j->vp + (size_t)hh * j->head_v;
    struct i16_head h = head_of(j, hh);
    const __m256 absmask = _mm256_castsi256_ps(_mm256_set1_epi32(0x7fffffff));
    const __m256 kmax = _mm256_set1_ps(qk_max(dp));
    (void)thread;
    /* keys, 8 at a time from an fp32 panel [dp][16]: each key's max |k|,
     * then codes k * (kmax / max) to [dp/2][16] pairs */
    for (int t = t0; t < t1; t += 8) {
        const float *src = kp + (size_t)(t / NR) * (size_t)dp * NR + (size_t)(t % NR);
        __m256 mx = _mm256_setzero_ps(), nan = _mm256_setzero_ps();
        for (int c = 0; c < dp; c++) {
            __m256 x = _mm256_loadu_ps(src + (size_t)c * NR);
            mx = _mm256_max_ps(mx, _mm256_and_ps(absmask, x));
            nan = _mm256_or_ps(nan, _mm256_cmp_ps(x, x, _CMP_UNORD_Q));
        }
        __m256 nz = _mm256_cmp_ps(mx, _mm256_setzero_ps(), _CMP_GT_OQ);
        __m256 mul = _mm256_and_ps(nz, _mm256_div_ps(kmax, mx));
        __m256 sc = _mm256_and_ps(nz, _mm256_div_ps(mx, kmax));
        _mm256_storeu_ps(h.sk + t, _mm256_blendv_ps(sc, _mm256_set1_ps(NAN), nan));
        uint32_t *dst = h.kq + (size_t)(t / NR) * (size_t)dp / 2 * NR + (size_t)(t % NR);
        for (int i = 0; i < dp / 2; i++) {
            __m256i lo = _mm256_cvtps_epi32(_mm256_mul_ps(mul, _mm256_loadu_ps(src + (size_t)(2 * i) * NR)));
            __m256i hi = _mm256_cvtps_epi32(_mm256_mul_ps(mul, _mm256_loadu_ps(src + (size_t)(2 * i + 1) * NR)));
            _mm256_storeu_si256((__m256i *)(dst + (size_t)i * NR), pairs8(lo, hi));
        }
    }
    /* values per 64-key block: each column's max |v| over the block, then
     * codes of rows t, t+1 as [dp] pairs */
    for (int b0 = t0; b0 < t1; b0 += BK) {
        float *sv = h.sv + (size_t)(b0 / BK) * (size_t)dp;
        for (int c = 0; c < dp; c += 8) {
            __m256 mx = _mm256_setzero_ps(), nan = _mm256_setzero_ps();
            for (int t = b0; t < b0 + BK; t++) {
                __m256 x = _mm256_loadu_ps(vp + (size_t)t * (size_t)dp + c);
                mx = _mm256_max_ps(mx, _mm256_and_ps(absmask, x));
                nan = _mm256_or_ps(nan, _mm256_cmp_ps(x, x, _CMP_UNORD_Q));
            }
            __m256 nz = _mm256_cmp_ps(mx, _mm256_setzero_ps(), _CMP_GT_OQ);
            __m256 mul = _mm256_and_ps(nz, _mm256_div_ps(_mm256_set1_ps(V_MAX), mx));
            /* the output's factor: v = code * max / V_MAX, p = code / P_ONE */
            __m256 sc = _mm256_and_ps(nz, _mm256_div_ps(mx, _mm256_set1_ps(V_MAX * P_ONE)));
            _mm256_storeu_ps(sv + c, _mm256_blendv_ps(sc, _mm256_set1_ps(NAN), nan));
            for (int t = b0; t < b0 + BK; t += 2) {
                const float *r0 = vp + (size_t)t * (size_t)dp + c;
                __m256i lo = _mm256_cvtps_epi32(_mm256_mul_ps(mul, _mm256_loadu_ps(r0)));
                __m256i hi = _mm256_cvtps_epi32(_mm256_mul_ps(mul, _mm256_loadu_ps(r0 + dp)));
                _mm256_storeu_si256((__m256i *)(h.vq + (size_t)t / 2 * (size_t)dp + c), pairs8(lo, hi));
            }
        }
    }
}

/* q panel [dp][6] f32 -> [dp/2][6] pairs (q[2i][r], q[2i+1][r]) and the six
 * rows' scales (a row's max |q| / qmax); codes rounded to nearest by
 * vcvtps2dq in a scratch row of dp * 6 ints (cb). The panel is [dp][6]:
 * element e has row e % 6, so three vectors cover the rows in a pattern that
 * repeats every 24 elements (dp * 6 is a multiple of 96), for the maxima as
 * for the multipliers. (The maxima were a scalar fmaxf per element, a libm
 * call: 13 % of the int16 task's own samples, 7-bit forward, Zen 4.) */
static void pack_q(int dp, const float *q, uint32_t *dst, float *sq, int32_t *cb)
{
    float qmax = qk_max(dp), mul[24] __attribute__((aligned(32))), lane[24] __attribute__((aligned(32)));
    const __m256 absmask = _mm256_castsi256_ps(_mm256_set1_epi32(0x7fffffff));
    __m256 a[3], nan[3];
    for (int i = 0; i < 3; i++)
        a[i] = nan[i] = _mm256_setzero_ps();
    for (int e = 0; e < MR * dp; e += 24)
        for (int i = 0; i < 3; i++) {
            __m256 x = _mm256_loadu_ps(q + e + 8 * i);
            nan[i] = _mm256_or_ps(nan[i], _mm256_cmp_ps(x, x, _CMP_UNORD_Q));
            a[i] = _mm256_max_ps(_mm256_and_ps(absmask, x), a[i]); /* a NaN x keeps a[i] */
        }
    /* bit j / lane j of the 24: row j % 6 */
    unsigned nan_lanes = 0;
    for (int i = 0; i < 3; i++) {
        _mm256_store_ps(lane + 8 * i, a[i]);
        nan_lanes |= (unsigned)_mm256_movemask_ps(nan[i]) << (8 * i);
    }
    for (int r = 0; r < MR; r++) {
        float mx = 0.0f;
        unsigned nan_flag = 0;
        for (int j = r; j < 24; j += 6) {
            mx = lane[j] > mx ? lane[j] : mx;
            nan_flag |= nan_lanes >> j & 1;
        }
        float m = mx > 0.0f && !isinf(mx) ? qmax / mx : 0.0f;
        mul[r] = mul[r + 6] = mul[r + 12] = mul[r + 18] = m;
        sq[r] = nan_flag ? NAN : mx > 0.0f ? mx / qmax : 0.0f;
    }
    const __m256 m0 = _mm256_load_ps(mul), m1 = _mm256_load_ps(mul + 8), m2 = _mm256_load_ps(mul + 16);
    for (int e = 0; e < MR * dp; e += 24) {
        _mm256_storeu_si256((__m256i *)(cb + e), _mm256_cvtps_epi32(_mm256_mul_ps(m0, _mm256_loadu_ps(q + e))));
        _mm256_storeu_si256((__m256i *)(cb + e + 8), _mm256_cvtps_epi32(_mm256_mul_ps(m1, _mm256_loadu_ps(q + e + 8))));
        _mm256_storeu_si256((__m256i *)(cb + e + 16), _mm256_cvtps_epi32(_mm256_mul_ps(m2, _mm256_loadu_ps(q + e + 16))));
    }
    for (int i = 0; i < dp / 2; i++)
        for (int r = 0; r < MR; r++)
            dst[i * MR + r] = ((uint32_t)cb[2 * i * MR + r] & 0xffffu) | (uint32_t)cb[(2 * i + 1) * MR + r] << 16;
}

/* ------------------------------------------------------------------ tiles */

/* acc += m in place. Without VNNI the add after vpmaddwd is a separate
 * instruction, and GCC gave each step's sum a fresh register and copied it
 * back to the accumulator's (six copies a step), or with the arrays of the
 * first version spilled all twelve accumulators: 12 accumulators, 2 key
 * vectors, the broadcast and vpmaddwd's result fill the 16 ymm registers
 * exactly. The asm names the accumulator as the destination. */
#define ACC(acc, m) __asm__("vpaddd %1, %0, %0" : "+x"(acc) : "x"(m))

#define I16_DOT(acc, t, b) ACC(acc, _mm256_madd_epi16(t, b))
#include "attention_i16_tiles.h"

/* The int16 weights of one 6 x BK block: codes round(2^(s - (bmax[r] -
 * 12))) as [6][BK/2] pairs in pb, row r's code sum in tot[r]; returns the
 * rows with a NaN weight as bits (fk__attn_i16_codes_avx512: the same, in
 * zmm). */
static int codes_avx2(const float *s, const float *bmax, uint32_t *pb, int32_t *tot)
{
    __m256i sum[MR];
    int nan_rows = 0;
    for (int r = 0; r < MR; r++) {
        const float *sr = s + r * BK;
        /* 4096 p = 2^(s - (block max - 12)): exact powers of two stay exact;
         * the degree-4 2^x is exact to 0.016 of a code */
        __m256 bv = _mm256_set1_ps(bmax[r] - 12.0f), nan = _mm256_setzero_ps();
        __m256i acc = _mm256_setzero_si256();
        for (int jj = 0; jj < BK; jj += 16) {
            __m256 p0 = fk__exp2_codes_avx2(_mm256_sub_ps(_mm256_loadu_ps(sr + jj), bv));
            __m256 p1 = fk__exp2_codes_avx2(_mm256_sub_ps(_mm256_loadu_ps(sr + jj + 8), bv));
            nan = _mm256_or_ps(nan, _mm256_cmp_ps(p0, p1, _CMP_UNORD_Q));
            __m256i c0 = _mm256_cvtps_epi32(p0);
            __m256i c1 = _mm256_cvtps_epi32(p1);
            acc = _mm256_add_epi32(acc, _mm256_add_epi32(c0, c1));
            /* packs interleaves 128-bit lanes; the permute puts keys back in order */
            __m256i h = _mm256_permute4x64_epi64(_mm256_packs_epi32(c0, c1), _MM_SHUFFLE(3, 1, 2, 0));
            _mm256_storeu_si256((__m256i *)(pb + r * (BK / 2) + jj / 2), h);
        }
        sum[r] = acc;
        nan_rows |= (_mm256_movemask_ps(nan) != 0) << r;
    }
    /* the six rows' code sums at once (a row after row scalar reduction
     * was a dependent chain the core waited on) */
    __m256i h01 = _mm256_hadd_epi32(sum[0], sum[1]), h23 = _mm256_hadd_epi32(sum[2], sum[3]);
    __m256i h45 = _mm256_hadd_epi32(sum[4], sum[5]);
    __m256i q0 = _mm256_hadd_epi32(h01, h23), q1 = _mm256_hadd_epi32(h45, h45);
    _mm_storeu_si128((__m128i *)tot, _mm_add_epi32(_mm256_castsi256_si128(q0), _mm256_extracti128_si256(q0, 1)));
    _mm_storeu_si128((__m128i *)(tot + 4),
                     _mm_add_epi32(_mm256_castsi256_si128(q1), _mm256_extracti128_si256(q1, 1)));
    return nan_rows;
}

/* The online softmax over one 6 x BK block of log2-domain logits: the row
 * maxima by the fp32 AVX2 piece's pass (fk__attn_rowmax_avx2), alpha = 2^(m_old -
 * m_new); then p = 2^(s - block max) to codes round(p 4096) as [6][BK/2]
 * pairs, ps = 2^(block max - m_new) per row (the codes' scale), and
 * l = alpha l + ps (sum of the codes) / 4096: the weights P V uses. A NaN
 * weight (from a NaN logit) makes l NaN, which the codes could not carry. */
static void softmax_block(int wide, float *s, int valid, float *m, float *l, float *alpha, float *ps,
                          uint32_t *pb)
{
    float m_new[8] __attribute__((aligned(32))), m_old[8] __attribute__((aligned(32)));
    float bmax[8] __attribute__((aligned(32)));
    fk__attn_rowmax_avx2(s, valid, m, 0.0f, bmax, m_old, m_new);
    __m256 mn = _mm256_load_ps(m_new);
    __m256 al = fk__exp2_softmax_avx2(_mm256_sub_ps(_mm256_load_ps(m_old), mn));
    __m256 pv = fk__exp2_softmax_avx2(_mm256_sub_ps(_mm256_load_ps(bmax), mn));
    _mm256_store_ps(alpha, al);
    _mm256_store_ps(ps, pv);
    int32_t t[8];
    int nan_rows = wide ? fk__attn_i16_codes_avx512(s, bmax, pb, t) : codes_avx2(s, bmax, pb, t);
    __m256 tot = _mm256_cvtepi32_ps(_mm256_setr_epi32(t[0], t[1], t[2], t[3], t[4], t[5], 0, 0));
    const __m256i rows = _mm256_setr_epi32(-1, -1, -1, -1, -1, -1, 0, 0);
    __m256 lv = _mm256_fmadd_ps(_mm256_maskload_ps(l, rows), al,
                                _mm256_mul_ps(pv, _mm256_mul_ps(tot, _mm256_set1_ps(1.0f / P_ONE))));
    _mm256_maskstore_ps(l, rows, lv);
    _mm256_maskstore_ps(m, rows, mn);
    for (int r = 0; nan_rows && r < MR; r++) /* NaN weights: l NaN, which the codes cannot carry */
        if (nan_rows >> r & 1)
            l[r] = NAN;
}

/* ------------------------------------------------------------------- task */

/* kv: the block's keys (a last block's tiles past them may be skipped) */
typedef void s_block_fn(int dp, int kv, const uint32_t *q, const uint32_t *kb, const float *sq, const float *sk,
                        float *s);
typedef void pv_tile_fn(int dp, int kv, const uint32_t *p, const uint32_t *v, const float *sv, float *o,
                        const float *alpha, const float *ps);

static void attn_task(void *arg, int task, int thread)
{
    const struct fk__attn_i16_job *j = arg;
    int hh = task / j->q_blocks, qb = task % j->q_blocks, d = j->d, dp = j->dp;
    struct i16_head h = head_of(j, hh);
    const float *qp = j->qp + (size_t)hh * j->head_q;
    struct i16_local L = local_layout(dp);
    char *scr = fk__scratch(j->ctx, thread);
    float *s = (float *)scr, *o = (float *)(scr + L.off_o), *ml = (float *)(scr + L.off_ml);
    float *sq = (float *)(scr + L.off_sq);
    int32_t *cb = (int32_t *)(scr + L.off_cb);
    uint32_t *pb = (uint32_t *)(scr + L.off_p), *qq = (uint32_t *)(scr + L.off_q);
    float *mrow = ml, *lrow = ml + QB, *alpha = ml + 2 * QB, *ps = alpha + 8;
    int q0 = qb * QB, rows = j->nq - q0 < QB ? j->nq - q0 : QB;
    int panels = (rows + MR - 1) / MR;
    const size_t qstride = (size_t)dp / 2 * MR;
    /* the products by the context's ISA: vpmaddwd + vpaddd here, VEX
     * vpdpwssd (AVX2-VNNI) or zmm vpdpwssd (AVX-512); the same bits */
    enum fk_isa isa = j->ctx->isa;
    int wide = isa == FK_ISA_AVX512;
    s_block_fn *s_fn = wide ? fk__attn_i16_s_block_avx512 : isa == FK_ISA_AVX2_VNNI ? fk__attn_i16_s_block_vnni : s_block;
    pv_tile_fn *pv_fn = wide ? fk__attn_i16_pv_tile_avx512 : isa == FK_ISA_AVX2_VNNI ? fk__attn_i16_pv_tile_vnni : pv_tile;
    for (int i = 0; i < panels; i++)
        pack_q(dp, qp + (size_t)(q0 / MR + i) * (size_t)dp * MR, qq + (size_t)i * qstride, sq + i * MR, cb);
    fk__attn_task_init(o, panels, dp, mrow, lrow);
    for (int kb = 0; kb < j->nk_pad / BK; kb++) {
        int valid = j->nk - kb * BK < BK ? j->nk - kb * BK : BK;
        if (kb == j->nk_pad / BK - 1)
            fk__attn_prefetch_out(j->out, j->ldo, q0, rows, (j->h0 + hh) * d, d);
        const uint32_t *kbb = h.kq + (size_t)kb * BK * (size_t)dp / 2;
        const uint32_t *vbb = h.vq + (size_t)kb * (BK / 2) * (size_t)dp;
        const float *sk = h.sk + (size_t)kb * BK, *sv = h.sv + (size_t)kb * (size_t)dp;
        for (int i = 0; i < panels; i++) {
            float *oi = o + (size_t)i * MR * (size_t)dp;
            s_fn(dp, valid, qq + (size_t)i * qstride, kbb, sq + i * MR, sk, s);
            softmax_block(wide, s, valid, mrow + i * MR, lrow + i * MR, alpha, ps, pb);
            pv_fn(dp, valid, pb, vbb, sv, oi, alpha, ps);
        }
    }
    fk__attn_task_write(j->out, j->ldo, q0, rows, (j->h0 + hh) * d, d, o, dp, lrow);
}

void fk__attn_i16_run(const struct fk__attn_i16_job *j)
{
    int chunks = (j->nk_pad + PACK_CHUNK - 1) / PACK_CHUNK;
    fk_parallel_for(j->ctx, j->hn * chunks, 6.0 * j->dp * j->hn * (double)j->nk_pad, pack_task, (void *)j);
    fk_parallel_for(j->ctx, j->hn * j->q_blocks, 4.0 * j->d * (double)j->nq * j->nk * j->hn, attn_task,
                    (void *)j);
}
