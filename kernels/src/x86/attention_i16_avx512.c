/* attention_i16_avx512.c - the int16 attention's two integer products in
 * zmm with AVX512_VNNI vpdpwssd (two multiply-adds per 32-bit lane, the sum
 * added in the same instruction), for attention_i16_avx2.c's tasks on an
 * AVX-512 context without bf16 attention (Intel's AVX-512 CPUs, where
 * vdpbf16ps runs at the FMA rate). The packs, the softmax and the codes are
 * the AVX2 file's; the int32 sums are exact either way, and the conversions
 * and scalings below are the AVX2 tiles' operations in their order, lane for
 * lane: the same bits as AVX2 (tested). Layouts as there: key pairs
 * [dp/2][16] per 16 keys (one zmm per pair of channels), q pairs [dp/2][6],
 * p pairs [6][BK/2], value pairs [BK/2][dp]. */
#include <immintrin.h>

#include "../attention_plan.h"
#include "../fk_internal.h"
#include "vecmath_avx512.h"

#define MR FK_ATTN_MR
#define NR FK_ATTN_NR
#define BK FK_ATTN_BK

_Static_assert(BK == 4 * NR, "s_block_avx512 takes a block as four 16-key groups");

/* acc += pairs t . b in place. With the intrinsic GCC 12 gave every step's
 * sum a fresh register, copied it back and stored it to the stack (24
 * accumulators): the asm names the accumulator as the destination. */
#define DP(acc, t, b) __asm__("vpdpwssd %2, %1, %0" : "+v"(acc) : "v"(t), "v"(b))

/* Six rows by four 16-lane groups of int32 sums, in 24 named registers (an
 * array of them GCC 12 kept on the stack). */
#define DECL24(c)                                                                             \
    __m512i c##00 = _mm512_setzero_si512(), c##01 = c##00, c##02 = c##00, c##03 = c##00;   \
    __m512i c##10 = c##00, c##11 = c##00, c##12 = c##00, c##13 = c##00;                     \
    __m512i c##20 = c##00, c##21 = c##00, c##22 = c##00, c##23 = c##00;                     \
    __m512i c##30 = c##00, c##31 = c##00, c##32 = c##00, c##33 = c##00;                     \
    __m512i c##40 = c##00, c##41 = c##00, c##42 = c##00, c##43 = c##00;                     \
    __m512i c##50 = c##00, c##51 = c##00, c##52 = c##00, c##53 = c##00
/* row r's four groups += the broadcast pair x times b0 .. b3 */
#define ROW4(c, r, x)                                                                         \
    do {                                                                                      \
        __m512i t_ = _mm512_set1_epi32((int)(x));                                             \
        DP(c##r##0, t_, b0); DP(c##r##1, t_, b1); DP(c##r##2, t_, b2); DP(c##r##3, t_, b3);   \
    } while (0)
#define GATHER24(c, arr)                                                                      \
    __m512i arr[MR][4] = { { c##00, c##01, c##02, c##03 }, { c##10, c##11, c##12, c##13 },    \
                           { c##20, c##21, c##22, c##23 }, { c##30, c##31, c##32, c##33 },    \
                           { c##40, c##41, c##42, c##43 }, { c##50, c##51, c##52, c##53 } }

/* s[6][BK] = (q pairs [dp/2][6] . the block's key pairs) * sq[r] * sk[key]:
 * 24 int32 accumulators, the four groups' key pairs loaded once per step
 * (all four in a last block too: kv unused). */
void fk__attn_i16_s_block_avx512(int dp, int kv, const uint32_t *q, const uint32_t *kb, const float *sq,
                                 const float *sk, float *s)
{
    (void)kv;
    DECL24(c);
    const size_t gs = (size_t)dp / 2 * NR; /* pairs per 16-key group */
    for (int i = 0; i < dp / 2; i++, kb += NR, q += MR) {
        __m512i b0 = _mm512_loadu_si512(kb), b1 = _mm512_loadu_si512(kb + gs);
        __m512i b2 = _mm512_loadu_si512(kb + 2 * gs), b3 = _mm512_loadu_si512(kb + 3 * gs);
        ROW4(c, 0, q[0]); ROW4(c, 1, q[1]); ROW4(c, 2, q[2]);
        ROW4(c, 3, q[3]); ROW4(c, 4, q[4]); ROW4(c, 5, q[5]);
    }
    GATHER24(c, acc);
    for (int g = 0; g < 4; g++) {
        __m512 k = _mm512_loadu_ps(sk + g * NR);
        for (int r = 0; r < MR; r++) {
            __m512 a = _mm512_set1_ps(sq[r]);
            _mm512_storeu_ps(s + r * BK + g * NR, _mm512_mul_ps(_mm512_cvtepi32_ps(acc[r][g]), _mm512_mul_ps(a, k)));
        }
    }
}

/* o[r][c0 + 16 g ..] = alpha[r] o + (p codes . v codes) ps[r] sv, for the
 * n groups of sums in acc */
static inline __attribute__((always_inline)) void pv_out(int dp, int c0, int n, __m512i acc[MR][4],
                                                          const float *sv, float *o, const float *alpha,
                                                          const float *ps)
{
    for (int g = 0; g < n; g++) {
        __m512 s0 = _mm512_loadu_ps(sv + c0 + 16 * g);
        for (int r = 0; r < MR; r++) {
            __m512 a = _mm512_set1_ps(alpha[r]), f = _mm512_set1_ps(ps[r]);
            float *orow = o + (size_t)r * (size_t)dp + c0 + 16 * g;
            _mm512_storeu_ps(orow, _mm512_fmadd_ps(_mm512_cvtepi32_ps(acc[r][g]), _mm512_mul_ps(f, s0),
                                                   _mm512_mul_ps(a, _mm512_loadu_ps(orow))));
        }
    }
}

void fk__attn_i16_pv_tile_avx512(int dp, int kv, const uint32_t *p, const uint32_t *v, const float *sv,
                                 float *o, const float *alpha, const float *ps)
{
    const int P = BK / 2;       /* a row's p pairs */
    const int kp = (kv + 1) / 2; /* those with keys: a last block's padding codes are 0 */
    int c0 = 0;
    for (; c0 + 64 <= dp; c0 += 64) { /* the models' head dims: 64 columns in 24 accumulators */
        DECL24(c);
        const uint32_t *vr = v + c0;
        for (int jp = 0; jp < kp; jp++, vr += dp) {
            __m512i b0 = _mm512_loadu_si512(vr), b1 = _mm512_loadu_si512(vr + 16);
            __m512i b2 = _mm512_loadu_si512(vr + 32), b3 = _mm512_loadu_si512(vr + 48);
            ROW4(c, 0, p[jp]); ROW4(c, 1, p[P + jp]); ROW4(c, 2, p[2 * P + jp]);
            ROW4(c, 3, p[3 * P + jp]); ROW4(c, 4, p[4 * P + jp]); ROW4(c, 5, p[5 * P + jp]);
        }
        GATHER24(c, acc);
        pv_out(dp, c0, 4, acc, sv, o, alpha, ps);
    }
    for (; c0 < dp; c0 += 16) { /* 16 columns at a time */
        __m512i c0r = _mm512_setzero_si512(), c1r = c0r, c2r = c0r, c3r = c0r, c4r = c0r, c5r = c0r;
        const uint32_t *vr = v + c0;
        for (int jp = 0; jp < kp; jp++, vr += dp) {
            __m512i b = _mm512_loadu_si512(vr);
            DP(c0r, _mm512_set1_epi32((int)p[jp]), b);
            DP(c1r, _mm512_set1_epi32((int)p[P + jp]), b);
            DP(c2r, _mm512_set1_epi32((int)p[2 * P + jp]), b);
            DP(c3r, _mm512_set1_epi32((int)p[3 * P + jp]), b);
            DP(c4r, _mm512_set1_epi32((int)p[4 * P + jp]), b);
            DP(c5r, _mm512_set1_epi32((int)p[5 * P + jp]), b);
        }
        __m512i z = _mm512_setzero_si512();
        __m512i acc[MR][4] = { { c0r, z, z, z }, { c1r, z, z, z }, { c2r, z, z, z },
                               { c3r, z, z, z }, { c4r, z, z, z }, { c5r, z, z, z } };
        pv_out(dp, c0, 1, acc, sv, o, alpha, ps);
    }
}

/* The int16 softmax's weights of one 6 x BK block (softmax_block in
 * attention_i16_avx2.c, 16 lanes at a time): codes round(2^(s - (bmax[r] -
 * 12))) as [6][BK/2] pairs in pb, each row's code sum in tot[r] (exact);
 * returns the rows with a NaN weight as bits. The AVX2 loop's operations
 * per element, and signed saturation to int16 as its packs: the same codes. */
int fk__attn_i16_codes_avx512(const float *s, const float *bmax, uint32_t *pb, int32_t *tot)
{
    int nan_rows = 0;
    for (int r = 0; r < MR; r++) {
        const float *sr = s + r * BK;
        __m512 bv = _mm512_set1_ps(bmax[r] - 12.0f);
        __m512i acc = _mm512_setzero_si512();
        __mmask16 nan = 0;
        for (int jj = 0; jj < BK; jj += 16) {
            __m512 p = fk__exp2_codes512(_mm512_sub_ps(_mm512_loadu_ps(sr + jj), bv));
            nan |= _mm512_cmp_ps_mask(p, p, _CMP_UNORD_Q);
            __m512i c = _mm512_cvtps_epi32(p);
            acc = _mm512_add_epi32(acc, c);
            _mm256_storeu_si256((__m256i *)(pb + r * (BK / 2) + jj / 2), _mm512_cvtsepi32_epi16(c));
        }
        tot[r] = _mm512_reduce_add_epi32(acc);
        nan_rows |= (nan != 0) << r;
    }
    return nan_rows;
}
