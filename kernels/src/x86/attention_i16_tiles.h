/* attention_i16_tiles.h - the int16 attention's register tiles, included by
 * attention_i16_avx2.c (I16_DOT: vpmaddwd, then vpaddd) and
 * attention_i16_vnni.c (I16_DOT: AVX-VNNI vpdpwssd), each defining
 * I16_DOT(acc, t, b) (acc += the pair products of t and b, in place) and
 * MR / NR / BK first. The int32 sums are exact either way, the float steps
 * the same: both files give the same bits. */
#ifndef FK_ATTENTION_I16_TILES_H
#define FK_ATTENTION_I16_TILES_H

#include <immintrin.h>
#include <stddef.h>
#include <stdint.h>

/* s[6][16] (row stride BK) = (q pairs [dp/2][6] . key pairs [dp/2][16]) *
 * sq[r] * sk[key]: 12 int32 accumulators, each step one pair of channels. */
static inline __attribute__((always_inline)) void s_tile6(int dp, const uint32_t *q,
                                                          const uint32_t *kb, const float *sq,
                                                          const float *sk, float *s)
{
    __m256i c00 = _mm256_setzero_si256(), c01 = c00, c10 = c00, c11 = c00, c20 = c00, c21 = c00;
    __m256i c30 = c00, c31 = c00, c40 = c00, c41 = c00, c50 = c00, c51 = c00;
    const uint32_t *qr = q;
    for (int i = 0; i < dp / 2; i++, kb += NR, qr += MR) {
        __m256i b0 = _mm256_loadu_si256((const __m256i *)kb);
        __m256i b1 = _mm256_loadu_si256((const __m256i *)(kb + 8));
        __m256i t = _mm256_set1_epi32((int)qr[0]);
        I16_DOT(c00, t, b0); I16_DOT(c01, t, b1);
        t = _mm256_set1_epi32((int)qr[1]);
        I16_DOT(c10, t, b0); I16_DOT(c11, t, b1);
        t = _mm256_set1_epi32((int)qr[2]);
        I16_DOT(c20, t, b0); I16_DOT(c21, t, b1);
        t = _mm256_set1_epi32((int)qr[3]);
        I16_DOT(c30, t, b0); I16_DOT(c31, t, b1);
        t = _mm256_set1_epi32((int)qr[4]);
        I16_DOT(c40, t, b0); I16_DOT(c41, t, b1);
        t = _mm256_set1_epi32((int)qr[5]);
        I16_DOT(c50, t, b0); I16_DOT(c51, t, b1);
    }
    __m256i c[6][2] = { { c00, c01 }, { c10, c11 }, { c20, c21 }, { c30, c31 }, { c40, c41 }, { c50, c51 } };
    __m256 k0 = _mm256_loadu_ps(sk), k1 = _mm256_loadu_ps(sk + 8);
    for (int r = 0; r < 6; r++) {
        __m256 a = _mm256_set1_ps(sq[r]);
        float *sr = s + r * BK;
        _mm256_storeu_ps(sr, _mm256_mul_ps(_mm256_cvtepi32_ps(c[r][0]), _mm256_mul_ps(a, k0)));
        _mm256_storeu_ps(sr + 8, _mm256_mul_ps(_mm256_cvtepi32_ps(c[r][1]), _mm256_mul_ps(a, k1)));
    }
}

/* the 16-key tiles of a block that hold keys: kv of them (a last block's
 * tiles past its keys are skipped; the softmax sets their s to -inf) */
__attribute__((noinline)) static void s_block(int dp, int kv, const uint32_t *q, const uint32_t *kb,
                                              const float *sq, const float *sk, float *s)
{
    for (int p = 0; p * NR < kv; p++)
        s_tile6(dp, q, kb + (size_t)p * (size_t)dp / 2 * NR, sq, sk + p * NR, s + p * NR);
}

/* o[6][dp] columns c0 .. c0 + 15 = alpha[r] o[r] + (p codes . v codes) ps[r] sv,
 * over the block's first kp key pairs (a last block's padding codes are 0:
 * skipping them changes no sum) */
static inline __attribute__((always_inline)) void pv_cols(int dp, int kp, int c0, const uint32_t *p,
                                                           const uint32_t *v, const float *sv,
                                                           float *o, const float *alpha,
                                                           const float *ps)
{
    __m256i c00 = _mm256_setzero_si256(), c01 = c00, c10 = c00, c11 = c00, c20 = c00, c21 = c00;
    __m256i c30 = c00, c31 = c00, c40 = c00, c41 = c00, c50 = c00, c51 = c00;
    const uint32_t *vr = v + c0;
    for (int jp = 0; jp < kp; jp++, vr += dp) {
        __m256i b0 = _mm256_loadu_si256((const __m256i *)vr);
        __m256i b1 = _mm256_loadu_si256((const __m256i *)(vr + 8));
        __m256i t = _mm256_set1_epi32((int)p[0 * (BK / 2) + jp]);
        I16_DOT(c00, t, b0); I16_DOT(c01, t, b1);
        t = _mm256_set1_epi32((int)p[1 * (BK / 2) + jp]);
        I16_DOT(c10, t, b0); I16_DOT(c11, t, b1);
        t = _mm256_set1_epi32((int)p[2 * (BK / 2) + jp]);
        I16_DOT(c20, t, b0); I16_DOT(c21, t, b1);
        t = _mm256_set1_epi32((int)p[3 * (BK / 2) + jp]);
        I16_DOT(c30, t, b0); I16_DOT(c31, t, b1);
        t = _mm256_set1_epi32((int)p[4 * (BK / 2) + jp]);
        I16_DOT(c40, t, b0); I16_DOT(c41, t, b1);
        t = _mm256_set1_epi32((int)p[5 * (BK / 2) + jp]);
        I16_DOT(c50, t, b0); I16_DOT(c51, t, b1);
    }
    __m256i c[6][2] = { { c00, c01 }, { c10, c11 }, { c20, c21 }, { c30, c31 }, { c40, c41 }, { c50, c51 } };
    __m256 s0 = _mm256_loadu_ps(sv + c0), s1 = _mm256_loadu_ps(sv + c0 + 8);
    for (int r = 0; r < MR; r++) {
        __m256 a = _mm256_set1_ps(alpha[r]), f = _mm256_set1_ps(ps[r]);
        float *orow = o + (size_t)r * dp + c0;
        _mm256_storeu_ps(orow, _mm256_fmadd_ps(_mm256_cvtepi32_ps(c[r][0]), _mm256_mul_ps(f, s0),
                                               _mm256_mul_ps(a, _mm256_loadu_ps(orow))));
        _mm256_storeu_ps(orow + 8, _mm256_fmadd_ps(_mm256_cvtepi32_ps(c[r][1]), _mm256_mul_ps(f, s1),
                                                   _mm256_mul_ps(a, _mm256_loadu_ps(orow + 8))));
    }
}

__attribute__((noinline)) static void pv_tile(int dp, int kv, const uint32_t *p, const uint32_t *v,
                                              const float *sv, float *o, const float *alpha,
                                              const float *ps)
{
    int kp = (kv + 1) / 2;
    for (int c0 = 0; c0 < dp; c0 += 16)
        pv_cols(dp, kp, c0, p, v, sv, o, alpha, ps);
}

#endif
