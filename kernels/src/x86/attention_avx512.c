/* attention_avx512.c - the AVX-512 pieces of attention's inner loop (S = Q K^T
 * over a whole 64-key block, the online softmax, O = alpha O + P V), used by
 * fk__attention_avx2 when the context's ISA is FK_ISA_AVX512; q/k LayerNorm
 * and RoPE (per token, not per pair) stay AVX2. Same packed layouts as the
 * AVX2 pieces: a 6-row query panel [d][6], key panels [d][16] (the four of a
 * block adjacent), values [BK][d]. Every output element is computed with the
 * AVX2 pieces' operations in their order (S and O along k / keys one FMA at a
 * time, the same exp2, the row sums in 8 lanes), so AVX-512 attention gives
 * the AVX2 bits (test_attention checks it): only the width differs. */
#include <immintrin.h>
#include <math.h>

#include "../attention_plan.h"
#include "vecmath_avx2.h"

#define MR FK_ATTN_MR
#define NR FK_ATTN_NR
#define BK FK_ATTN_BK

/* s[6][BK] = q[d][6] . kp (4 panels [d][16]): 24 zmm accumulators, so each k
 * step loads 4 vectors of keys for 24 FMAs (the 6x16 AVX2 tile loads 2 for
 * 12 FMAs of half the width). */
void fk__attn_s_block_avx512(int d, const float *q, const float *kp, float *s)
{
    __m512 c[MR][4];
    for (int r = 0; r < MR; r++)
        for (int p = 0; p < 4; p++)
            c[r][p] = _mm512_setzero_ps();
    const size_t ps = (size_t)d * NR;
    for (int k = 0; k < d; k++) {
        const float *b = kp + (size_t)k * NR;
        __m512 b0 = _mm512_loadu_ps(b), b1 = _mm512_loadu_ps(b + ps);
        __m512 b2 = _mm512_loadu_ps(b + 2 * ps), b3 = _mm512_loadu_ps(b + 3 * ps);
        for (int r = 0; r < MR; r++) {
            __m512 t = _mm512_set1_ps(q[k * MR + r]);
            c[r][0] = _mm512_fmadd_ps(t, b0, c[r][0]);
            c[r][1] = _mm512_fmadd_ps(t, b1, c[r][1]);
            c[r][2] = _mm512_fmadd_ps(t, b2, c[r][2]);
            c[r][3] = _mm512_fmadd_ps(t, b3, c[r][3]);
        }
    }
    for (int r = 0; r < MR; r++)
        for (int p = 0; p < 4; p++)
            _mm512_storeu_ps(s + r * BK + p * NR, c[r][p]);
}

/* 2^x for x = s - max <= 0, as the AVX2 piece (same clamp at -127, same
 * degree-6 polynomial on [-0.5, 0.5], exponent add; NaN stays NaN). */
static inline __m512 exp2_softmax(__m512 x)
{
    x = _mm512_max_ps(_mm512_set1_ps(-127.0f), x);
    __m512 n = _mm512_roundscale_ps(x, _MM_FROUND_TO_NEAREST_INT | _MM_FROUND_NO_EXC);
    __m512 f = _mm512_sub_ps(x, n);
    __m512 p = _mm512_set1_ps(1.5403530393e-4f);
    p = _mm512_fmadd_ps(p, f, _mm512_set1_ps(1.3333558146e-3f));
    p = _mm512_fmadd_ps(p, f, _mm512_set1_ps(9.6181291076e-3f));
    p = _mm512_fmadd_ps(p, f, _mm512_set1_ps(5.5504108665e-2f));
    p = _mm512_fmadd_ps(p, f, _mm512_set1_ps(2.4022650696e-1f));
    p = _mm512_fmadd_ps(p, f, _mm512_set1_ps(6.9314718056e-1f));
    p = _mm512_fmadd_ps(p, f, _mm512_set1_ps(1.0f));
    __m512i e = _mm512_slli_epi32(_mm512_add_epi32(_mm512_cvtps_epi32(n), _mm512_set1_epi32(127)), 23);
    return _mm512_mul_ps(p, _mm512_castsi512_ps(e));
}

/* The online softmax over one 6 x BK block (see struct fk__attn_isa). */
void fk__attn_softmax_block_avx512(float *s, int valid, float *m, float *l, float *alpha)
{
    float m_new[16] __attribute__((aligned(64))) = { 0 }, m_old[16] __attribute__((aligned(64))) = { 0 };
    for (int r = 0; r < MR; r++) {
        float *sr = s + r * BK;
        for (int jj = valid; jj < BK; jj++)
            sr[jj] = -INFINITY;
        __m512 mx = _mm512_max_ps(_mm512_max_ps(_mm512_loadu_ps(sr), _mm512_loadu_ps(sr + 16)),
                                  _mm512_max_ps(_mm512_loadu_ps(sr + 32), _mm512_loadu_ps(sr + 48)));
        float bm = _mm512_reduce_max_ps(mx);
        m_old[r] = m[r];
        m_new[r] = bm > m[r] ? bm : m[r];
    }
    /* the six rescale factors in one vector (lanes 6-15 are 2^0, unused) */
    __m512 al = exp2_softmax(_mm512_sub_ps(_mm512_load_ps(m_old), _mm512_load_ps(m_new)));
    _mm512_mask_storeu_ps(alpha, (__mmask16)0xff, al);
    for (int r = 0; r < MR; r++) {
        float *sr = s + r * BK;
        /* the row sum in 8 lanes, added in the AVX2 piece's order (and
         * reduced by the same hsum), so both give the same bits */
        __m512 mv = _mm512_set1_ps(m_new[r]);
        __m256 sum = _mm256_setzero_ps();
        for (int jj = 0; jj < BK; jj += 16) {
            __m512 p = exp2_softmax(_mm512_sub_ps(_mm512_loadu_ps(sr + jj), mv));
            _mm512_storeu_ps(sr + jj, p);
            sum = _mm256_add_ps(sum, _mm512_castps512_ps256(p));
            sum = _mm256_add_ps(sum, _mm256_castpd_ps(_mm512_extractf64x4_pd(_mm512_castps_pd(p), 1)));
        }
        l[r] = l[r] * alpha[r] + fk__hsum_avx2(sum);
        m[r] = m_new[r];
    }
}

/* o[6][d] = alpha[r] o[r] + p[6][BK] . v[BK][d] (d a multiple of 16): 32
 * columns at a time in 12 zmm accumulators, a 16-column tail in 6. */
void fk__attn_pv_tile_avx512(int d, const float *p, const float *v, float *o, const float *alpha)
{
    int c0 = 0;
    for (; c0 + 32 <= d; c0 += 32) {
        float *oc = o + c0;
        __m512 c[MR][2];
        for (int r = 0; r < MR; r++) {
            __m512 a = _mm512_set1_ps(alpha[r]);
            c[r][0] = _mm512_mul_ps(a, _mm512_loadu_ps(oc + r * d));
            c[r][1] = _mm512_mul_ps(a, _mm512_loadu_ps(oc + r * d + 16));
        }
        const float *vr = v + c0;
        for (int jj = 0; jj < BK; jj++) {
            __m512 b0 = _mm512_loadu_ps(vr), b1 = _mm512_loadu_ps(vr + 16);
            for (int r = 0; r < MR; r++) {
                __m512 t = _mm512_set1_ps(p[r * BK + jj]);
                c[r][0] = _mm512_fmadd_ps(t, b0, c[r][0]);
                c[r][1] = _mm512_fmadd_ps(t, b1, c[r][1]);
            }
            vr += d;
        }
        for (int r = 0; r < MR; r++) {
            _mm512_storeu_ps(oc + r * d, c[r][0]);
            _mm512_storeu_ps(oc + r * d + 16, c[r][1]);
        }
    }
    if (c0 < d) { /* d % 32 == 16 */
        float *oc = o + c0;
        __m512 c[MR];
        for (int r = 0; r < MR; r++)
            c[r] = _mm512_mul_ps(_mm512_set1_ps(alpha[r]), _mm512_loadu_ps(oc + r * d));
        const float *vr = v + c0;
        for (int jj = 0; jj < BK; jj++) {
            __m512 b0 = _mm512_loadu_ps(vr);
            for (int r = 0; r < MR; r++)
                c[r] = _mm512_fmadd_ps(_mm512_set1_ps(p[r * BK + jj]), b0, c[r]);
            vr += d;
        }
        for (int r = 0; r < MR; r++)
            _mm512_storeu_ps(oc + r * d, c[r]);
    }
}
