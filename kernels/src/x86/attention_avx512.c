/* attention_avx512.c - the AVX-512 inner loop of attention: one 6-query panel
 * against one 64-key block (S = Q K^T, the online softmax, O = alpha O + P V)
 * in one call, used by fk__attention_avx2 when the context's ISA is
 * FK_ISA_AVX512; q/k LayerNorm and RoPE (per token, not per pair) stay AVX2.
 * Layouts: a 6-row query panel [d][6] as for AVX2, keys [d][64] per block
 * (the driver packs them so for struct fk__attn_isa's block), values [BK][d].
 *
 * The FMAs of S and P V are the work; everything else per block is
 * overhead paid per 6 x 64 logits, so it is kept short: S is stored once and
 * read back by the softmax, the six row maxima come out of one transposed
 * reduction, a running max moves only when a block's exceeds it by
 * FK_ATTN_SLACK (so the exponentials rarely wait for the reduction), and P
 * is stored in place, for the P V broadcasts. Every output
 * element is computed with the AVX2 pieces' operations in their order (S and
 * O along k / keys one FMA at a time, the same exp2, the row sums in 8 lanes),
 * so AVX-512 attention gives the AVX2 bits (test_attention checks it): the
 * model's fixtures hold for either ISA. */
#include <immintrin.h>
#include <math.h>

#include "../attention_plan.h"
#include "vecmath_avx2.h"
#include "vecmath_avx512.h"

#define MR FK_ATTN_MR
#define NR FK_ATTN_NR
#define BK FK_ATTN_BK

/* The six rows' maxima at once: lane r of the result is max(v[r]) (exact in
 * any order; NaN may be dropped, as by fk__hmax_avx2), lanes 6-15 are
 * unspecified. A tree of 128-bit and in-lane shuffles instead of six serial
 * horizontal reductions. */
static inline __m512 reduce6_max(const __m512 *v)
{
    __m512 a01 = _mm512_max_ps(_mm512_shuffle_f32x4(v[0], v[1], _MM_SHUFFLE(1, 0, 1, 0)),
                               _mm512_shuffle_f32x4(v[0], v[1], _MM_SHUFFLE(3, 2, 3, 2)));
    __m512 a23 = _mm512_max_ps(_mm512_shuffle_f32x4(v[2], v[3], _MM_SHUFFLE(1, 0, 1, 0)),
                               _mm512_shuffle_f32x4(v[2], v[3], _MM_SHUFFLE(3, 2, 3, 2)));
    __m512 a45 = _mm512_max_ps(_mm512_shuffle_f32x4(v[4], v[5], _MM_SHUFFLE(1, 0, 1, 0)),
                               _mm512_shuffle_f32x4(v[4], v[5], _MM_SHUFFLE(3, 2, 3, 2)));
    /* 128-bit chunks: rows 0 1 2 3 and rows 4 5 4 5 */
    __m512 b = _mm512_max_ps(_mm512_shuffle_f32x4(a01, a23, _MM_SHUFFLE(2, 0, 2, 0)),
                             _mm512_shuffle_f32x4(a01, a23, _MM_SHUFFLE(3, 1, 3, 1)));
    __m512 c = _mm512_max_ps(_mm512_shuffle_f32x4(a45, a45, _MM_SHUFFLE(2, 0, 2, 0)),
                             _mm512_shuffle_f32x4(a45, a45, _MM_SHUFFLE(3, 1, 3, 1)));
    /* per chunk: b's row in lanes 0 1, c's in lanes 2 3 */
    __m512 e = _mm512_max_ps(_mm512_shuffle_ps(b, c, _MM_SHUFFLE(1, 0, 1, 0)),
                             _mm512_shuffle_ps(b, c, _MM_SHUFFLE(3, 2, 3, 2)));
    e = _mm512_max_ps(e, _mm512_permute_ps(e, _MM_SHUFFLE(2, 3, 0, 1)));
    return _mm512_permutexvar_ps(_mm512_setr_epi32(0, 4, 8, 12, 2, 6, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0), e);
}

/* o[6][g * 16 ..] (ld d) = alpha o + p[6][0, kv) . v[0, kv)[16 G columns]:
 * 6 G accumulators, each P value broadcast once for the G column vectors. G
 * is a constant where this is inlined, so the arrays live in registers. */
static inline __attribute__((always_inline)) void pv_cols(int G, int d, int kv, const float *p,
                                                          const float *v, float *o,
                                                          const __m512 *al, int rescale)
{
    __m512 c[MR][4];
    for (int r = 0; r < MR; r++)
        for (int g = 0; g < G; g++) {
            c[r][g] = _mm512_loadu_ps(o + r * d + g * 16);
            if (rescale)
                c[r][g] = _mm512_mul_ps(al[r], c[r][g]);
        }
    for (int jj = 0; jj < kv; jj++) {
        __m512 b[4];
        for (int g = 0; g < G; g++)
            b[g] = _mm512_loadu_ps(v + g * 16);
        for (int r = 0; r < MR; r++) {
            __m512 t = _mm512_set1_ps(p[r * BK + jj]);
            for (int g = 0; g < G; g++)
                c[r][g] = _mm512_fmadd_ps(t, b[g], c[r][g]);
        }
        v += d;
    }
    for (int r = 0; r < MR; r++)
        for (int g = 0; g < G; g++)
            _mm512_storeu_ps(o + r * d + g * 16, c[r][g]);
}

/* s[6][BK] = q[d][6] . kp (padding keys -inf): 24 accumulators, each k
 * step loads 4 vectors of keys for 24 FMAs; stored once at the end. Its own
 * phase, so that nothing else competes for the registers (with the softmax
 * in the same scope GCC spilled five of the accumulators inside the loop).
 * G (a constant where inlined): the 16-key groups computed, the rest all
 * padding (-inf), as in a last block with few keys. */
static inline __attribute__((always_inline)) void s_tile(int G, int d, const float *q, const float *kp,
                                                         int valid, int padded, float *s,
                                                         const float *o)
{
    /* groups past G stay 0: the padding mask below stores them as -inf */
    __m512 c[MR][4];
    for (int r = 0; r < MR; r++)
        for (int p = 0; p < 4; p++)
            c[r][p] = _mm512_setzero_ps();
    /* the next panel's q and o follow this one's (the driver's layouts); with
     * the K / V block, the 16 panels' q and o overflow L1: fetch them early */
    const char *qn = (const char *)(q + (size_t)d * MR), *on = (const char *)(o + (size_t)d * MR);
    for (int k = 0; k < d; k++) {
        const float *b = kp + (size_t)k * BK;
        if (k * 64 < MR * d * (int)sizeof(float)) { /* a line per step */
            _mm_prefetch(qn + k * 64, _MM_HINT_T0);
            _mm_prefetch(on + k * 64, _MM_HINT_T0);
        }
        __m512 bv[4];
        for (int p = 0; p < G; p++)
            bv[p] = _mm512_loadu_ps(b + p * NR);
        for (int r = 0; r < MR; r++) {
            __m512 t = _mm512_set1_ps(q[k * MR + r]);
            for (int p = 0; p < G; p++)
                c[r][p] = _mm512_fmadd_ps(t, bv[p], c[r][p]);
        }
    }
#pragma GCC unroll 4
    for (int p = 0; p < 4; p++) {
        __mmask16 pad = 0;
        if (padded) {
            int n = valid - p * NR;
            pad = n <= 0 ? (__mmask16)0xffff : n >= NR ? 0 : (__mmask16)(0xffffu << n);
        }
        for (int r = 0; r < MR; r++)
            _mm512_store_ps(s + r * BK + p * NR, _mm512_mask_mov_ps(c[r][p], pad, _mm512_set1_ps(-INFINITY)));
    }
}

/* One 6-query panel against one BK-key block (struct fk__attn_isa's block):
 * S by s_tile; the six rows' block maxima from one transposed reduction;
 * m_new = the block max where it exceeds m by more than FK_ATTN_SLACK, else
 * m (fk__attn_rowmax_avx2's rule); p = 2^(s - m_new) into s, alpha =
 * 2^(m - m_new), l = alpha l + row sum of p; then o = alpha o + p . v, 64
 * columns (24 accumulators) at a time. Mostly no row's max moves: the
 * exponentials then start from m without waiting for the reduction (the
 * branch is predicted) and o is not rescaled. */
static inline __attribute__((always_inline)) void block(int d, const float *q, const float *kp,
                                                        const float *v, int valid, float *s,
                                                        float *o, float *m, float *l, int padded)
{
    if (!padded)
        s_tile(4, d, q, kp, valid, 0, s, o);
    else /* a last block: the key groups it has */
        switch ((valid + NR - 1) / NR) {
        case 1: s_tile(1, d, q, kp, valid, 1, s, o); break;
        case 2: s_tile(2, d, q, kp, valid, 1, s, o); break;
        case 3: s_tile(3, d, q, kp, valid, 1, s, o); break;
        default: s_tile(4, d, q, kp, valid, 1, s, o); break;
        }
    __m512 red[MR];
    for (int r = 0; r < MR; r++) {
        const float *sr = s + r * BK;
        red[r] = _mm512_max_ps(_mm512_max_ps(_mm512_load_ps(sr), _mm512_load_ps(sr + NR)),
                               _mm512_max_ps(_mm512_load_ps(sr + 2 * NR), _mm512_load_ps(sr + 3 * NR)));
    }
    const __mmask16 rows = (__mmask16)((1u << MR) - 1);
    __m512 m_old = _mm512_maskz_loadu_ps(rows, m), bm = reduce6_max(red), m_new, al_v;
    __mmask16 grow = _mm512_mask_cmp_ps_mask(rows, bm, _mm512_add_ps(m_old, _mm512_set1_ps(FK_ATTN_SLACK)),
                                             _CMP_GT_OQ);
    int rescale = grow != 0;
    if (__builtin_expect(!rescale, 1)) {
        m_new = m_old;
        al_v = _mm512_set1_ps(1.0f); /* 2^0, as the AVX2 piece computes it */
    } else {
        m_new = _mm512_mask_mov_ps(m_old, grow, bm);
        al_v = fk__exp2_softmax512(_mm512_sub_ps(m_old, m_new));
        _mm512_mask_storeu_ps(m, rows, m_new);
    }
    __m256 sum[MR];
#pragma GCC unroll 6
    for (int r = 0; r < MR; r++) {
        __m512 mv = _mm512_permutexvar_ps(_mm512_set1_epi32(r), m_new);
        float *sr = s + r * BK;
        /* the row sum in 8 lanes, added in the AVX2 piece's order */
        sum[r] = _mm256_setzero_ps();
        for (int p = 0; p < 4; p++) {
            __m512 e = fk__exp2_softmax512(_mm512_sub_ps(_mm512_load_ps(sr + p * NR), mv));
            _mm512_store_ps(sr + p * NR, e);
            sum[r] = _mm256_add_ps(sum[r], _mm512_castps512_ps256(e));
            sum[r] = _mm256_add_ps(sum[r], _mm256_castpd_ps(_mm512_extractf64x4_pd(_mm512_castps_pd(e), 1)));
        }
    }
    /* l = l alpha + the row sums for the six rows at once, as the AVX2
     * piece: the same hsum, a multiply then an add (not six dependent
     * scalar chains) */
    const __m256i six = _mm256_setr_epi32(-1, -1, -1, -1, -1, -1, 0, 0);
    __m256 lv = _mm256_add_ps(_mm256_mul_ps(_mm256_maskload_ps(l, six), _mm512_castps512_ps256(al_v)),
                              fk__hsum6_avx2(sum));
    _mm256_maskstore_ps(l, six, lv);
    __m512 al[MR];
    for (int r = 0; r < MR; r++)
        al[r] = _mm512_permutexvar_ps(_mm512_set1_epi32(r), al_v);
    /* P V over the keys that exist (the AVX2 pieces' order) */
    int c0 = 0, kv = padded ? valid : BK;
    for (; c0 + 64 <= d; c0 += 64)
        pv_cols(4, d, kv, s, v + c0, o + c0, al, rescale);
    if (d - c0 >= 32) {
        pv_cols(2, d, kv, s, v + c0, o + c0, al, rescale);
        c0 += 32;
    }
    if (c0 < d)
        pv_cols(1, d, kv, s, v + c0, o + c0, al, rescale);
}

/* Two copies: only the last key block has padding keys, and without the
 * padding code the S accumulators stay in registers. */
void fk__attn_block_avx512(int d, const float *q, const float *kp, const float *v, int valid,
                           float *s, float *o, float *m, float *l)
{
    if (valid < BK)
        block(d, q, kp, v, valid, s, o, m, l, 1);
    else
        block(d, q, kp, v, valid, s, o, m, l, 0);
}
