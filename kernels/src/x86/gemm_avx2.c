/* gemm_avx2.c - blocked GEMM for AVX2/FMA/F16C: the driver shared by
 * fk_linear and fk_conv, the 6x16 fp32 micro-kernel (fp16 weights widened per
 * cache block into it), and two int8 micro-kernels for CPUs without AVX-VNNI:
 * 7-bit weights through vpmaddubsw (u8 x s7 pairs cannot saturate, see
 * ukr_q7_avx2) and the exact 8-bit one (sign-extended int16 pairs through
 * vpmaddwd: no int16 sums, so no saturation, but no faster than fp32).
 *
 * Blocking (BLIS order, blocks from the context's cache model, see
 * fk_gemm_blocks_for): a task owns mc rows of A and a range of 16-wide weight
 * panels, walked nc columns at a time. For each k block of kc it packs the
 * mc x kc block of A (L2) and runs every panel's kc x 16 weight sliver (L1)
 * over all 6-row micro-panels, accumulating in an mc x nc tile of C; after the
 * last k block the epilogue (bias, activation, LayerScale, residual) writes
 * the tile row by row. The order of accumulation along k never depends on the
 * blocks (the tile is stored and reloaded exactly), so every blocking gives
 * bit-identical results. int8 packs A whole (rows are quantized with their
 * full-row scale) and walks it in k blocks of 4 kc. */
#include <immintrin.h>
#include <limits.h>
#include <math.h>
#include <string.h>

#include "../fk_internal.h"
#include "../gemm.h"
#include "vecmath_avx2.h"
#include "x86.h"

#define MR FK_GEMM_MR
#define NR FK_GEMM_NR
#define PG 4 /* fp32 weight panels per output tile */

/* ----------------------------------------------------------- micro-kernels */

/* c[6][ldc] (16 columns) (+)= A[6][ntaps kc] * b[ntaps kc][16]: the fp32
 * register tile of the GEMM, of the convolutions and of attention's Q K^T.
 * Row r of tap t is read at a[6 t + r][k * step]: step 6 walks a packed
 * micro-panel [kc][6], step 1 rows read in place (a stride-1 convolution's
 * six pixels, adjacent in memory, so no im2col gather). Several taps (a
 * convolution's whole k in one call) keep the accumulators in registers
 * across them: a call per tap reloaded the C tile and rebuilt the row
 * pointers for 16 k-steps. Called through the two out-of-line entries
 * below: inlined into a driver, GCC runs out of general registers and
 * spills the A pointers. */
static inline __attribute__((always_inline)) void ukr_f32_body(int ntaps, int kc, const float *const *a,
                                                               int step, const float *b, float *c, int ldc,
                                                               int accumulate)
{
    __m256 c00, c01, c10, c11, c20, c21, c30, c31, c40, c41, c50, c51;
    if (accumulate) {
        c00 = _mm256_load_ps(c + 0 * ldc); c01 = _mm256_load_ps(c + 0 * ldc + 8);
        c10 = _mm256_load_ps(c + 1 * ldc); c11 = _mm256_load_ps(c + 1 * ldc + 8);
        c20 = _mm256_load_ps(c + 2 * ldc); c21 = _mm256_load_ps(c + 2 * ldc + 8);
        c30 = _mm256_load_ps(c + 3 * ldc); c31 = _mm256_load_ps(c + 3 * ldc + 8);
        c40 = _mm256_load_ps(c + 4 * ldc); c41 = _mm256_load_ps(c + 4 * ldc + 8);
        c50 = _mm256_load_ps(c + 5 * ldc); c51 = _mm256_load_ps(c + 5 * ldc + 8);
    } else {
        c00 = c01 = c10 = c11 = c20 = c21 = _mm256_setzero_ps();
        c30 = c31 = c40 = c41 = c50 = c51 = _mm256_setzero_ps();
    }
    for (int tap = 0; tap < ntaps; tap++, a += MR) {
        const float *a0 = a[0], *a1 = a[1], *a2 = a[2], *a3 = a[3], *a4 = a[4], *a5 = a[5];
        /* one offset for the six rows: six pointer adds per k step took
         * integer ports the FMAs share on Intel cores */
        size_t o = 0;
#pragma GCC unroll 4
        for (int k = 0; k < kc; k++, o += (size_t)step) {
            __m256 b0 = _mm256_load_ps(b), b1 = _mm256_load_ps(b + 8), t;
            t = _mm256_broadcast_ss(a0 + o); c00 = _mm256_fmadd_ps(t, b0, c00); c01 = _mm256_fmadd_ps(t, b1, c01);
            t = _mm256_broadcast_ss(a1 + o); c10 = _mm256_fmadd_ps(t, b0, c10); c11 = _mm256_fmadd_ps(t, b1, c11);
            t = _mm256_broadcast_ss(a2 + o); c20 = _mm256_fmadd_ps(t, b0, c20); c21 = _mm256_fmadd_ps(t, b1, c21);
            t = _mm256_broadcast_ss(a3 + o); c30 = _mm256_fmadd_ps(t, b0, c30); c31 = _mm256_fmadd_ps(t, b1, c31);
            t = _mm256_broadcast_ss(a4 + o); c40 = _mm256_fmadd_ps(t, b0, c40); c41 = _mm256_fmadd_ps(t, b1, c41);
            t = _mm256_broadcast_ss(a5 + o); c50 = _mm256_fmadd_ps(t, b0, c50); c51 = _mm256_fmadd_ps(t, b1, c51);
            b += 16;
        }
    }
    _mm256_store_ps(c + 0 * ldc, c00); _mm256_store_ps(c + 0 * ldc + 8, c01);
    _mm256_store_ps(c + 1 * ldc, c10); _mm256_store_ps(c + 1 * ldc + 8, c11);
    _mm256_store_ps(c + 2 * ldc, c20); _mm256_store_ps(c + 2 * ldc + 8, c21);
    _mm256_store_ps(c + 3 * ldc, c30); _mm256_store_ps(c + 3 * ldc + 8, c31);
    _mm256_store_ps(c + 4 * ldc, c40); _mm256_store_ps(c + 4 * ldc + 8, c41);
    _mm256_store_ps(c + 5 * ldc, c50); _mm256_store_ps(c + 5 * ldc + 8, c51);
}

__attribute__((noinline)) static void ukr_f32(int ntaps, int kc, const float *const *a, int step,
                                              const float *b, float *c, int ldc, int accumulate)
{
    ukr_f32_body(ntaps, kc, a, step, b, c, ldc, accumulate);
}

/* The GEMM's common call, a packed micro-panel a[kc][6] into a tile of its
 * own (ldc 16), as an entry of its own: with the rows' offsets and strides
 * constant the call builds no row pointers and saves no registers, which
 * the generic entry and exit did for every 6 x 16 x 256 step (AVX2 f32
 * blocks 1-2.5 % faster, Zen 4, 2 threads). The same operations: the same
 * bits. */
__attribute__((noinline)) static void ukr_f32_packed(int kc, const float *a, const float *b, float *c,
                                                     int accumulate)
{
    const float *rows[MR] = { a, a + 1, a + 2, a + 3, a + 4, a + 5 };
    ukr_f32_body(1, kc, rows, MR, b, c, NR, accumulate);
}

void fk__ukr_f32_6x16(int kc, const float *a, const float *b, float *c, int ldc, int accumulate)
{
    const float *rows[MR] = { a, a + 1, a + 2, a + 3, a + 4, a + 5 };
    ukr_f32(1, kc, rows, MR, b, c, ldc, accumulate);
}

static inline long long load_i64(const int16_t *p)
{
    long long v;
    memcpy(&v, p, sizeof v);
    return v;
}

/* Rows [r0, r0 + R) of c[6][16], columns 8 half .. 8 half + 7: each 32-bit
 * lane holds a pair sum (k01 or k23 of one column), folded with hadd at the
 * end. R <= 4 keeps accumulators, weights and the broadcast in 16 registers
 * (all six rows at once made GCC spill accumulators). */
static inline __attribute__((always_inline)) void
q8_rows(int k4, const int16_t *a, int r0, int R, const int8_t *b, int32_t *c, int half, int accumulate)
{
    __m256i acc[4][2];
    for (int r = 0; r < R; r++)
        acc[r][0] = acc[r][1] = _mm256_setzero_si256();
    const int8_t *bp = b + half * 32;
    const int16_t *ap = a + 4 * r0;
    for (int k = 0; k < k4; k++) {
        /* columns 0-3 and 4-7 of this half, 4 k each, as int16 */
        __m256i b0 = _mm256_cvtepi8_epi16(_mm_load_si128((const __m128i *)bp));
        __m256i b1 = _mm256_cvtepi8_epi16(_mm_load_si128((const __m128i *)(bp + 16)));
        for (int r = 0; r < R; r++) {
            __m256i t = _mm256_set1_epi64x(load_i64(ap + 4 * r));
            acc[r][0] = _mm256_add_epi32(acc[r][0], _mm256_madd_epi16(t, b0));
            acc[r][1] = _mm256_add_epi32(acc[r][1], _mm256_madd_epi16(t, b1));
        }
        ap += 4 * MR;
        bp += 4 * NR;
    }
    /* lanes [c0 c0 c1 c1 | c2 c2 c3 c3] and [c4 c4 c5 c5 | c6 c6 c7 c7] -> c0..c7 */
    for (int r = 0; r < R; r++) {
        __m256i *d = (__m256i *)(c + NR * (r0 + r) + 8 * half);
        __m256i v = _mm256_permute4x64_epi64(_mm256_hadd_epi32(acc[r][0], acc[r][1]), 0xd8);
        _mm256_store_si256(d, accumulate ? _mm256_add_epi32(_mm256_load_si256(d), v) : v);
    }
}

/* c[6][16] = sum over k4 of a[k4][6][4] (int16) * b[k4][16][4] (int8), exact:
 * vpmaddwd sums two int16 products into int32, no int16 intermediate. */
__attribute__((noinline)) static void ukr_q8_avx2(int k4, const int16_t *a, const int8_t *b, int32_t *c,
                                                  int accumulate)
{
    for (int half = 0; half < 2; half++) {
        q8_rows(k4, a, 0, 4, b, c, half, accumulate);
        q8_rows(k4, a, 4, 2, b, c, half, accumulate);
    }
}

static inline int load_u32(const uint8_t *p)
{
    int v;
    memcpy(&v, p, sizeof v);
    return v;
}

/* c[6][16] (+)= sum over k4 of a[k4][6][4] (u8, code + 128) * b[k4][16][4]
 * (7-bit path codes), the same operands as the VNNI kernel, without VNNI.
 *
 * No saturation, by construction: vpmaddubsw multiplies unsigned bytes
 * a in [1, 255] (activation code in [-127, 127] plus 128) by signed bytes w
 * and adds adjacent products (k even, k odd) with signed 16-bit saturation.
 * fk_linear packs this path's weights so that every such pair has
 * |w0| + |w1| <= 128 (7-bit codes, |w| <= 63, are the simplest case; the
 * packer spends the budget per pair, see quantize_row_pairs in linear.c):
 * then |a0 w0 + a1 w1| <= 255 * 128 = 32640 < 32767, so the pair sum is
 * exact. vpmaddwd with ones widens and adds two pair sums into int32
 * (|.| <= 65280), and the int32 accumulation is exact for k <= 65536:
 * |sum| <= 65536 * 255 * 64 < 2^31. (Free 8-bit codes would reach
 * 2 * 255 * 127 = 64770 and saturate.) test_linear's worst cases (all
 * activations 255, pairs summing to 128) check it against exact integers. */
__attribute__((noinline)) static void ukr_q7_avx2(int k4, const uint8_t *a, const int8_t *b, int32_t *c,
                                                  int accumulate);

/* One row of ukr_q7_avx2's k step: t = the row's four activation bytes
 * broadcast; u8 x s7 pairs (vpmaddubsw), widened and summed in pairs with
 * ones (vpmaddwd), added to the row's two accumulators. */
#define Q7_ROW(r, c0, c1)                                                                 \
    do {                                                                                  \
        __m256i t_ = _mm256_set1_epi32(load_u32(a + 4 * (r)));                            \
        __m256i u_ = _mm256_maddubs_epi16(t_, b0);                                        \
        t_ = _mm256_maddubs_epi16(t_, b1);                                                \
        c0 = _mm256_add_epi32(c0, _mm256_madd_epi16(u_, ones));                           \
        c1 = _mm256_add_epi32(c1, _mm256_madd_epi16(t_, ones));                           \
    } while (0)

/* Rows [r0, r0 + 3) of ukr_q7_avx2. Named accumulators (six), weights (two),
 * ones and two temporaries fit the 16 ymm registers; written as an array of
 * accumulators GCC copied each one through a spare register every step and
 * spilled one. */
static inline __attribute__((always_inline)) void
q7_rows3(int k4, const uint8_t *a, int r0, const int8_t *b, int32_t *c, int accumulate)
{
    const __m256i ones = _mm256_set1_epi16(1);
    int32_t *cr = c + NR * r0;
    __m256i c00, c01, c10, c11, c20, c21;
    if (accumulate) {
        c00 = _mm256_load_si256((const __m256i *)(cr + 0));  c01 = _mm256_load_si256((const __m256i *)(cr + 8));
        c10 = _mm256_load_si256((const __m256i *)(cr + 16)); c11 = _mm256_load_si256((const __m256i *)(cr + 24));
        c20 = _mm256_load_si256((const __m256i *)(cr + 32)); c21 = _mm256_load_si256((const __m256i *)(cr + 40));
    } else {
        c00 = c01 = c10 = c11 = c20 = c21 = _mm256_setzero_si256();
    }
    a += 4 * r0;
#pragma GCC unroll 2
    for (int k = 0; k < k4; k++) {
        __m256i b0 = _mm256_load_si256((const __m256i *)b);
        __m256i b1 = _mm256_load_si256((const __m256i *)(b + 32));
        Q7_ROW(0, c00, c01);
        Q7_ROW(1, c10, c11);
        Q7_ROW(2, c20, c21);
        a += 4 * MR;
        b += 4 * NR;
    }
    _mm256_store_si256((__m256i *)(cr + 0), c00);  _mm256_store_si256((__m256i *)(cr + 8), c01);
    _mm256_store_si256((__m256i *)(cr + 16), c10); _mm256_store_si256((__m256i *)(cr + 24), c11);
    _mm256_store_si256((__m256i *)(cr + 32), c20); _mm256_store_si256((__m256i *)(cr + 40), c21);
}
#undef Q7_ROW

__attribute__((noinline)) static void ukr_q7_avx2(int k4, const uint8_t *a, const int8_t *b, int32_t *c,
                                                  int accumulate)
{
    q7_rows3(k4, a, 0, b, c, accumulate);
    q7_rows3(k4, a, 3, b, c, accumulate);
}

/* ----------------------------------------------------------------- packing */

/* Six rows of 8 values (a0..a5) -> 8 columns of 6, each stored as 8 floats
 * at d + 6 j (the last two lanes are overwritten by the next column). */
static inline void transpose_6x8_v(__m256 a0, __m256 a1, __m256 a2, __m256 a3, __m256 a4, __m256 a5,
                                   float *d)
{
    __m256 z = _mm256_setzero_ps();
    __m256 t0 = _mm256_unpacklo_ps(a0, a1), t1 = _mm256_unpackhi_ps(a0, a1);
    __m256 t2 = _mm256_unpacklo_ps(a2, a3), t3 = _mm256_unpackhi_ps(a2, a3);
    __m256 t4 = _mm256_unpacklo_ps(a4, a5), t5 = _mm256_unpackhi_ps(a4, a5);
    __m256 u0 = _mm256_shuffle_ps(t0, t2, 0x44), u1 = _mm256_shuffle_ps(t0, t2, 0xee);
    __m256 u2 = _mm256_shuffle_ps(t1, t3, 0x44), u3 = _mm256_shuffle_ps(t1, t3, 0xee);
    __m256 u4 = _mm256_shuffle_ps(t4, z, 0x44), u5 = _mm256_shuffle_ps(t4, z, 0xee);
    __m256 u6 = _mm256_shuffle_ps(t5, z, 0x44), u7 = _mm256_shuffle_ps(t5, z, 0xee);
    /* column j = rows 0-3 from u*, rows 4-5 from the matching u4..u7 half */
    _mm256_storeu_ps(d + 0 * MR, _mm256_permute2f128_ps(u0, u4, 0x20));
    _mm256_storeu_ps(d + 1 * MR, _mm256_permute2f128_ps(u1, u5, 0x20));
    _mm256_storeu_ps(d + 2 * MR, _mm256_permute2f128_ps(u2, u6, 0x20));
    _mm256_storeu_ps(d + 3 * MR, _mm256_permute2f128_ps(u3, u7, 0x20));
    _mm256_storeu_ps(d + 4 * MR, _mm256_permute2f128_ps(u0, u4, 0x31));
    _mm256_storeu_ps(d + 5 * MR, _mm256_permute2f128_ps(u1, u5, 0x31));
    _mm256_storeu_ps(d + 6 * MR, _mm256_permute2f128_ps(u2, u6, 0x31));
    _mm256_storeu_ps(d + 7 * MR, _mm256_permute2f128_ps(u3, u7, 0x31));
}

/* Six rows of 8 values from r[i] + k0 -> 8 columns of 6 at d + 6 j. */
static inline void transpose_6x8(const float *const r[MR], int k0, float *d)
{
    transpose_6x8_v(_mm256_loadu_ps(r[0] + k0), _mm256_loadu_ps(r[1] + k0), _mm256_loadu_ps(r[2] + k0),
                    _mm256_loadu_ps(r[3] + k0), _mm256_loadu_ps(r[4] + k0), _mm256_loadu_ps(r[5] + k0), d);
}

/* pack_a_f32 for a convolution: each tap's run of channels is transposed
 * straight from the image (or the zero row for padding and rows past the
 * end), six output pixels at a time, without gathering whole im2col rows
 * first (at 8 channels a tap that was a memcpy call per 8 floats). */
static void pack_a_conv_f32(const struct fk__asrc *src, int m0, int rows, int k0, int k, float *ap,
                            const float *zeros)
{
    for (int i = 0; i * MR < rows; i++) {
        int oy[MR], ox[MR];
        for (int rr = 0; rr < MR; rr++) {
            int row = i * MR + rr, m = m0 + row;
            oy[rr] = row < rows ? m / src->wo * src->stride - src->pad : INT_MIN / 2;
            ox[rr] = row < rows ? m % src->wo * src->stride - src->pad : INT_MIN / 2;
        }
        float *d = ap + (size_t)i * (size_t)k * MR;
        for (int kk = 0; kk < k;) {
            int kab = k0 + kk, tap = kab / src->cin, c = kab % src->cin;
            int ky = tap / src->kw, kx = tap % src->kw, run = src->cin - c;
            run = run < k - kk ? run : k - kk;
            const float *r[MR];
            for (int rr = 0; rr < MR; rr++) {
                int iy = oy[rr] + ky, ix = ox[rr] + kx;
                r[rr] = iy < 0 || iy >= src->h || ix < 0 || ix >= src->w
                            ? zeros
                            : src->x + ((size_t)iy * (size_t)src->w + (size_t)ix) * (size_t)src->cin + (size_t)c;
            }
            float *dk = d + (size_t)kk * MR;
            int j = 0;
            for (; j + 8 <= run; j += 8)
                transpose_6x8(r, j, dk + (size_t)j * MR);
            for (; j < run; j++)
                for (int rr = 0; rr < MR; rr++)
                    dk[(size_t)j * MR + (size_t)rr] = r[rr][j];
            kk += run;
        }
    }
}

#define PACK_A_AHEAD 2 /* micro-panels of A prefetched ahead of the pack */

/* Columns [k0, k0 + k) of rows [m0, m0 + rows) of A as micro-panels
 * [i][k][6], zero rows to pad (zeros holds k floats). Writes up to 2 floats
 * past the last panel (the scratch has room). */
static void pack_a_f32(const struct fk__asrc *src, int m0, int rows, int k0, int k, float *ap,
                       const float *zeros)
{
    if (src->conv) {
        pack_a_conv_f32(src, m0, rows, k0, k, ap, zeros);
        return;
    }
    for (int i = 0; i * MR < rows; i++) {
        const float *r[MR];
        for (int rr = 0; rr < MR; rr++) {
            int row = i * MR + rr;
            if (row >= rows) {
                r[rr] = zeros;
            } else {
                r[rr] = src->x + (size_t)(m0 + row) * (size_t)src->ldx + (size_t)k0;
            }
        }
        /* the rows of the micro-panel PACK_A_AHEAD panels on, towards L1:
         * each row's run is a few lines, rows are KBs apart, and the
         * hardware prefetcher does not follow: the pack waited on its loads
         * (f32 GEMM 5496 x 1024 <- 4096, Zen 5, one thread: the driver's
         * share of samples 5.5-5.9 % -> 4.2-4.8 %, 1-6 panels ahead alike) */
        for (int rr = 0; rr < MR; rr++) {
            int row = (i + PACK_A_AHEAD) * MR + rr;
            if (row >= rows)
                break;
            uintptr_t a = (uintptr_t)(src->x + (size_t)(m0 + row) * (size_t)src->ldx + (size_t)k0);
            for (uintptr_t l = a & ~(uintptr_t)63; l < a + (size_t)k * 4; l += 64)
                _mm_prefetch((const char *)l, _MM_HINT_T0);
        }
        float *d = ap + (size_t)i * (size_t)k * MR;
        int kk = 0;
        for (; kk + 8 <= k; kk += 8)
            transpose_6x8(r, kk, d + (size_t)kk * MR);
        for (; kk < k; kk++)
            for (int rr = 0; rr < MR; rr++)
                d[(size_t)kk * MR + (size_t)rr] = r[rr][kk];
    }
}

/* Quantizes one row exactly like fk_quantize_row_q8 (bit for bit; its clamp
 * to +-127 never binds because |x| * 127 / amax <= 127). */
static float quantize_row(const float *x, int k, int8_t *q)
{
    __m256 amax = _mm256_setzero_ps(), poison = _mm256_setzero_ps();
    const __m256 absmask = _mm256_castsi256_ps(_mm256_set1_epi32(0x7fffffff));
    const __m256 zero = _mm256_setzero_ps();
    int i = 0;
    for (; i + 8 <= k; i += 8) {
        __m256 v = _mm256_loadu_ps(x + i);
        poison = _mm256_add_ps(poison, _mm256_mul_ps(v, zero));
        amax = _mm256_max_ps(amax, _mm256_and_ps(v, absmask));
    }
    float am = fk__hmax_avx2(amax);
    float pz = fk__hsum_avx2(poison);
    for (; i < k; i++) {
        pz += x[i] * 0.0f;
        float a = fabsf(x[i]);
        if (a > am)
            am = a;
    }
    if (am < FK_Q8_AMAX_MIN || pz != 0) {
        memset(q, 0, (size_t)k);
        return pz == 0 ? 0.0f : NAN;
    }
    float invs = 127.0f / am;
    __m256 inv = _mm256_set1_ps(invs);
    for (i = 0; i + 8 <= k; i += 8) {
        __m256i v = _mm256_cvtps_epi32(_mm256_mul_ps(_mm256_loadu_ps(x + i), inv));
        __m128i w = _mm_packs_epi32(_mm256_castsi256_si128(v), _mm256_extracti128_si256(v, 1));
        _mm_storel_epi64((__m128i *)(q + i), _mm_packs_epi16(w, w));
    }
    for (; i < k; i++)
        q[i] = (int8_t)(int)nearbyintf(x[i] * invs);
    return am / 127.0f;
}

/* Most runs a convolution row may take: a zero run, the in-image taps of one
 * kernel row (adjacent pixels, so one run in channels-last), a zero run, per
 * kernel row. Larger kernels gather the row with fk__asrc_row. */
#define ARUN_MAX 48

/* Row m of A (of a convolution: output pixel (py, px)) as at most ARUN_MAX
 * runs in k order (k = (ky kw + kx) cin + c); returns their count, or 0 when
 * the row needs more. */
static int row_runs_at(const struct fk__asrc *a, int m, int py, int px, int k, struct fk__arun *r)
{
    if (!a->conv) {
        r[0] = (struct fk__arun){ a->x + (size_t)m * (size_t)a->ldx, k };
        return 1;
    }
    int oy = py * a->stride - a->pad, ox = px * a->stride - a->pad, nr = 0;
    int kx0 = ox < 0 ? -ox : 0, kx1 = a->w - ox < a->kw ? a->w - ox : a->kw; /* in-image taps */
    if (3 * a->kh > ARUN_MAX)
        return 0;
    for (int ky = 0; ky < a->kh; ky++) {
        int iy = oy + ky;
        if (iy < 0 || iy >= a->h || kx1 <= kx0) {
            r[nr++] = (struct fk__arun){ NULL, a->kw * a->cin };
            continue;
        }
        if (kx0 > 0)
            r[nr++] = (struct fk__arun){ NULL, kx0 * a->cin };
        r[nr++] = (struct fk__arun){ a->x + ((size_t)iy * (size_t)a->w + (size_t)(ox + kx0)) * (size_t)a->cin,
                                 (kx1 - kx0) * a->cin };
        if (kx1 < a->kw)
            r[nr++] = (struct fk__arun){ NULL, (a->kw - kx1) * a->cin };
    }
    return nr;
}

/* row_runs for output pixel (py, px) = (m / wo, m % wo) of a convolution,
 * the division done by the caller (quantize_panel walks six pixels). */
static int row_runs(const struct fk__asrc *a, int m, int k, struct fk__arun *r)
{
    return a->conv ? row_runs_at(a, m, m / a->wo, m % a->wo, k, r) : row_runs_at(a, m, 0, 0, k, r);
}

/* |x| of the runs' values as integers, their max: for non-negative floats
 * the integer order is the float order and Inf / NaN sort above every finite
 * value, so this one max gives amax and the reference's poison test (x * 0
 * summed: NaN exactly when some x is Inf or NaN) at once, one reduction
 * instead of two; zero runs add nothing; max does not depend on the order. */
static inline uint32_t runs_absmax_bits(const struct fk__arun *r, int nr)
{
    __m256i amax = _mm256_setzero_si256();
    const __m256i absmask = _mm256_set1_epi32(0x7fffffff);
    uint32_t bits = 0;
    for (int s = 0; s < nr; s++) {
        const float *x = r[s].p;
        int n = r[s].n, i = 0;
        if (!x)
            continue;
        for (; i + 8 <= n; i += 8)
            amax = _mm256_max_epu32(amax, _mm256_and_si256(_mm256_loadu_si256((const __m256i *)(x + i)), absmask));
        for (; i < n; i++) {
            uint32_t b;
            memcpy(&b, x + i, sizeof b);
            b &= 0x7fffffffu;
            bits = b > bits ? b : bits;
        }
    }
    __m128i m4 = _mm_max_epu32(_mm256_castsi256_si128(amax), _mm256_extracti128_si256(amax, 1));
    m4 = _mm_max_epu32(m4, _mm_shuffle_epi32(m4, 0x4e));
    m4 = _mm_max_epu32(m4, _mm_shuffle_epi32(m4, 0xb1));
    uint32_t vb = (uint32_t)_mm_cvtsi128_si32(m4);
    return vb > bits ? vb : bits;
}

/* The runs' codes x * invs into q, rounded to nearest even like quantize_row. */
static inline void runs_codes(const struct fk__arun *r, int nr, float invs, int8_t *q)
{
    __m256 inv = _mm256_set1_ps(invs);
    for (int s = 0; s < nr; s++) {
        const float *x = r[s].p;
        int n = r[s].n, i = 0;
        if (!x) {
            memset(q, 0, (size_t)n);
            q += n;
            continue;
        }
        /* 16 codes per store: the 8-byte stores were the hot spot of the
         * row (a 9 C row per output pixel of a thin 3x3 convolution) */
        for (; i + 16 <= n; i += 16) {
            __m256i v0 = _mm256_cvtps_epi32(_mm256_mul_ps(_mm256_loadu_ps(x + i), inv));
            __m256i v1 = _mm256_cvtps_epi32(_mm256_mul_ps(_mm256_loadu_ps(x + i + 8), inv));
            /* int16 lanes v0[0-3] v1[0-3] | v0[4-7] v1[4-7] -> in order */
            __m256i w = _mm256_permute4x64_epi64(_mm256_packs_epi32(v0, v1), 0xd8);
            _mm_storeu_si128((__m128i *)(q + i),
                             _mm_packs_epi16(_mm256_castsi256_si128(w), _mm256_extracti128_si256(w, 1)));
        }
        for (; i + 8 <= n; i += 8) {
            __m256i v = _mm256_cvtps_epi32(_mm256_mul_ps(_mm256_loadu_ps(x + i), inv));
            __m128i w = _mm_packs_epi32(_mm256_castsi256_si128(v), _mm256_extracti128_si256(v, 1));
            _mm_storel_epi64((__m128i *)(q + i), _mm_packs_epi16(w, w));
        }
        for (; i < n; i++)
            q[i] = (int8_t)(int)nearbyintf(x[i] * invs);
        q += n;
    }
}

/* quantize_row over runs, so the codes and the scale are quantize_row's bit
 * for bit, without copying the row. */
static float quantize_runs(const struct fk__arun *r, int nr, int8_t *q)
{
    int k = 0;
    for (int s = 0; s < nr; s++)
        k += r[s].n;
    float inv, sc = fk__q8_row_scale(runs_absmax_bits(r, nr), &inv);
    if (inv == 0)
        memset(q, 0, (size_t)k);
    else
        runs_codes(r, nr, inv, q);
    return sc;
}

/* Row m's codes into q[k] and its scale: runs straight from A, or the
 * gathered row for kernels with more rows than ARUN_MAX covers. */
static float quantize_a_row(const struct fk__asrc *src, int m, int k, int8_t *q, float *rowbuf)
{
    struct fk__arun r[ARUN_MAX];
    int nr = row_runs(src, m, k, r);
    if (nr == 0) {
        fk__asrc_row(src, m, 0, k, rowbuf);
        return quantize_row(rowbuf, k, q);
    }
    return quantize_runs(r, nr, q);
}

/* The rows of a micro-panel as runs, quantized together into q[6][k_pad]
 * (padding rows as zeros): every row's absmax, then the scales, then the
 * codes. Rows of a thin convolution (a 9 C row per output pixel, C = 16-48)
 * are short enough that one row at a time waited on its own chain (loads,
 * the max reduction, the division); the rows' chains are independent and
 * now overlap. AVX-512: fk__q8_quantize_rows_avx512, the same steps in zmm.
 * Returns 0 when a row needs more runs than ARUN_MAX (the caller then goes
 * row by row). */
static int quantize_panel(const struct fk__asrc *src, int m0, int rows, int k, int k_pad, int8_t *q,
                          float *sa, int wide)
{
    struct fk__arun runs[MR][ARUN_MAX];
    const struct fk__arun *rp[MR];
    int nr[MR];
    /* output pixel of row m0, then stepped: no division per row */
    int py = src->conv ? m0 / src->wo : 0, px = src->conv ? m0 % src->wo : 0;
    for (int rr = 0; rr < MR; rr++) {
        rp[rr] = runs[rr];
        nr[rr] = rr < rows ? row_runs_at(src, m0 + rr, py, px, k, runs[rr]) : 0; /* padding rows: zeros */
        if (rr < rows && nr[rr] == 0)
            return 0;
        if (src->conv && ++px == src->wo) {
            px = 0;
            py++;
        }
    }
    if (wide) {
        fk__q8_quantize_rows_avx512(rp, nr, MR, k, k_pad, q, (size_t)k_pad, sa);
        return 1;
    }
    uint32_t bits[MR];
    float inv[MR];
    for (int rr = 0; rr < MR; rr++)
        bits[rr] = runs_absmax_bits(runs[rr], nr[rr]);
    for (int rr = 0; rr < MR; rr++)
        sa[rr] = fk__q8_row_scale(bits[rr], &inv[rr]);
    for (int rr = 0; rr < MR; rr++) {
        int8_t *qr = q + (size_t)rr * (size_t)k_pad;
        if (inv[rr] == 0) {
            memset(qr, 0, (size_t)k_pad);
            continue;
        }
        runs_codes(runs[rr], nr[rr], inv[rr], qr);
        memset(qr + k, 0, (size_t)(k_pad - k));
    }
    return 1;
}

/* Quantizes rows [m0, m0 + rows) and packs them as micro-panels
 * [i][k4][6][4]: int16 for the AVX2 kernel, uint8 (+128) for VNNI and the
 * 7-bit kernel. u8: the six rows' codes are quantized into q[6][k_pad] and
 * transposed 8 groups of 4 at a time (the 6x8 fp32 transpose moves the
 * 32-bit groups as they are), instead of a scalar store per group; the
 * transpose writes 2 groups past the last one (the scratch has room). */
static void pack_a_q8(const struct fk__asrc *src, int m0, int rows, int k, int k_pad, int vnni,
                      int wide, void *ap, float *sa, float *rowbuf, int8_t *q)
{
    int mp = (rows + MR - 1) / MR, k4n = k_pad / 4;
    size_t panel = (size_t)k_pad * MR;
    if (vnni) {
        const __m256i flip = _mm256_set1_epi8((char)0x80);
        for (int i = 0; i < mp; i++) {
            int left = rows - i * MR;
            int done = quantize_panel(src, m0 + i * MR, left < MR ? left : MR, k, k_pad, q, sa + i * MR, wide);
            for (int rr = 0; !done && rr < MR; rr++) {
                int row = i * MR + rr;
                int8_t *qr = q + (size_t)rr * (size_t)k_pad;
                if (row < rows) {
                    sa[row] = quantize_a_row(src, m0 + row, k, qr, rowbuf);
                    memset(qr + k, 0, (size_t)(k_pad - k));
                } else {
                    sa[row] = 0;
                    memset(qr, 0, (size_t)k_pad);
                }
            }
            float *d = (float *)(void *)((uint8_t *)ap + (size_t)i * panel);
            int g = 0;
            for (; g + 8 <= k4n; g += 8) {
                const int8_t *qg = q + 4 * g;
                const size_t kp = (size_t)k_pad;
#define QROW(rr) _mm256_castsi256_ps(_mm256_xor_si256(_mm256_loadu_si256((const __m256i *)(qg + (rr) * kp)), flip))
                transpose_6x8_v(QROW(0), QROW(1), QROW(2), QROW(3), QROW(4), QROW(5), d + (size_t)g * MR);
#undef QROW
            }
            for (; g < k4n; g++)
                for (int rr = 0; rr < MR; rr++) {
                    uint32_t w;
                    memcpy(&w, q + (size_t)rr * (size_t)k_pad + 4 * g, 4);
                    w ^= 0x80808080u;
                    memcpy(d + (size_t)g * MR + rr, &w, 4);
                }
        }
        return;
    }
    for (int row = 0; row < mp * MR; row++) {
        int i = row / MR, rr = row % MR;
        if (row < rows) {
            sa[row] = quantize_a_row(src, m0 + row, k, q, rowbuf);
        } else {
            sa[row] = 0;
            memset(q, 0, (size_t)k);
        }
        for (int kk = k; kk < k_pad; kk++)
            q[kk] = 0;
        /* 4 consecutive k of this row go to one 64-bit (int16) slot per k4 */
        int16_t *d = (int16_t *)ap + (size_t)i * panel + (size_t)rr * 4;
        int k4 = 0;
        for (; k4 + 1 < k4n; k4 += 2) {
            __m128i v = _mm_cvtepi8_epi16(_mm_loadl_epi64((const __m128i *)(q + 4 * k4)));
            _mm_storel_epi64((__m128i *)(d + (size_t)k4 * MR * 4), v);
            _mm_storeh_pd((double *)(void *)(d + (size_t)(k4 + 1) * MR * 4), _mm_castsi128_pd(v));
        }
        for (; k4 < k4n; k4++)
            for (int e = 0; e < 4; e++)
                d[(size_t)k4 * MR * 4 + (size_t)e] = q[4 * k4 + e];
    }
}

/* ---------------------------------------------------------------- epilogue */

static const int32_t mask_table[32] = {
    -1, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1,
    0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0,
};

static inline __m256 activate(enum fk_act act, __m256 v)
{
    switch (act) {
    case FK_ACT_RELU: return _mm256_max_ps(_mm256_setzero_ps(), v); /* NaN stays NaN */
    case FK_ACT_GELU: return fk__gelu_avx2(v);
    case FK_ACT_SILU: return fk__silu_avx2(v);
    default:          return v;
    }
}

/* An epilogue's fields read once per tile: the intrinsics' stores may alias
 * anything, so fields read through j->ep and j->c were reloaded after every
 * row's store (a third of epi_f32's samples at 226 x 256 <- 64, one thread,
 * Zen 5). c itself is passed on only for the scattered destinations. */
struct row_out {
    enum fk_act              act;
    const float             *gamma;
    int                      accumulate, tconv_k, tconv_cout;
    float                   *y;
    size_t                   ldy;
    const struct fk__cdst   *c;
};

/* Writes t[0..nn) (already biased and activated) to row m, columns n0..,
 * applying LayerScale and the residual accumulation. */
static inline __attribute__((always_inline)) void
store_row(const struct row_out *o, int m, int n0, int nn, __m256 t0, __m256 t1)
{
    int contiguous = !o->tconv_k || (n0 % o->tconv_cout) + nn <= o->tconv_cout;
    if (!contiguous) {
        float t[16];
        _mm256_storeu_ps(t, t0);
        _mm256_storeu_ps(t + 8, t1);
        for (int j = 0; j < nn; j++) {
            float v = o->gamma ? t[j] * o->gamma[n0 + j] : t[j];
            float *d = fk__cdst_ptr(o->c, m, n0 + j);
            *d = o->accumulate ? *d + v : v;
        }
        return;
    }
    /* dense rows inline: the call per row and panel showed in the int8
     * epilogue's profile (thin convolutions, 16-48 columns) */
    float *d = o->tconv_k ? fk__cdst_ptr(o->c, m, n0) : o->y + (size_t)m * o->ldy + (size_t)n0;
    if (nn == 16) {
        if (o->gamma) {
            t0 = _mm256_mul_ps(t0, _mm256_loadu_ps(o->gamma + n0));
            t1 = _mm256_mul_ps(t1, _mm256_loadu_ps(o->gamma + n0 + 8));
        }
        if (o->accumulate) {
            t0 = _mm256_add_ps(_mm256_loadu_ps(d), t0);
            t1 = _mm256_add_ps(_mm256_loadu_ps(d + 8), t1);
        }
        _mm256_storeu_ps(d, t0);
        _mm256_storeu_ps(d + 8, t1);
        return;
    }
    __m256i k0 = _mm256_loadu_si256((const __m256i *)(mask_table + 16 - nn));
    __m256i k1 = _mm256_loadu_si256((const __m256i *)(mask_table + 24 - nn));
    if (o->gamma) {
        t0 = _mm256_mul_ps(t0, _mm256_maskload_ps(o->gamma + n0, k0));
        t1 = _mm256_mul_ps(t1, _mm256_maskload_ps(o->gamma + n0 + 8, k1));
    }
    if (o->accumulate) {
        t0 = _mm256_add_ps(_mm256_maskload_ps(d, k0), t0);
        t1 = _mm256_add_ps(_mm256_maskload_ps(d + 8, k1), t1);
    }
    _mm256_maskstore_ps(d, k0, t0);
    _mm256_maskstore_ps(d + 8, k1, t1);
}

/* ------------------------------------------------------------------ driver */

enum q8_path { Q8_EXACT16, Q8_VNNI, Q8_7BIT };

/* fewest input channels of a stride-1 convolution read in place a tap per
 * call (see fk__gemm_avx2; the all-taps call takes any) */
#define FK_DIRECT_MIN_CIN 16
#define FK_TAPS_MAX 64 /* taps of an all-taps call (tap_rows' offsets) */

struct gemm_job {
    fk_ctx                   *ctx;
    const struct fk_linear   *L;
    const struct fk__asrc    *a;
    const struct fk__cdst    *c;
    const struct fk_epilogue *ep;
    int    m, mc, kc, nc_panels, m_blocks, n_chunks, panels, panels_per_chunk, k_pad, path, direct, inplace;
    int    taps; /* direct convolution: every tap in one call (the taps per call) */
    int    wide; /* AVX-512: two panels per micro-kernel call */
    size_t off_c, off_b, off_tmp, off_q, off_sa, off_zero, off_pix, off_tap;
};

/* The top-left input pixel (oy - pad, ox - pad) of each output row of the
 * task (rows m0 ..), as pix[2 row], pix[2 row + 1]; INT_MIN past the last
 * row. Once per task: per micro-kernel call, the two divisions per row (12
 * a call) were most of the driver's 8 % of the DPT heads' samples. */
static void direct_pix(const struct fk__asrc *a, int m0, int rows, int mp, int *pix)
{
    /* one division, then step along the output rows (a division per pixel
     * showed at 16 channels) */
    int oy = m0 / a->wo, ox = m0 % a->wo;
    for (int row = 0; row < mp * MR; row++) {
        pix[2 * row] = row < rows ? oy - a->pad : INT_MIN;
        pix[2 * row + 1] = row < rows ? ox - a->pad : INT_MIN;
        if (++ox == a->wo) {
            ox = 0;
            oy++;
        }
    }
}

/* The channels of tap (ky, kx) under output pixel p (from direct_pix):
 * zeros for padding and for rows past the end. */
static inline const float *tap_pixel(const struct fk__asrc *a, const int *p, int ky, int kx, const float *zeros)
{
    int iy = p[0] + ky, ix = p[1] + kx;
    if (p[0] == INT_MIN || iy < 0 || iy >= a->h || ix < 0 || ix >= a->w)
        return zeros;
    return a->x + ((size_t)iy * (size_t)a->w + (size_t)ix) * (size_t)a->cin;
}

/* Row pointers of micro-panel i for the k block starting at k0 of a stride-1
 * convolution: output pixel (oy, ox) (from direct_pix), tap (ky, kx),
 * channels from k0 % cin; padding and rows past the end read zeros. */
static void direct_rows(const struct fk__asrc *a, const int *pix, int i, int k0,
                        const float *zeros, const float *ar[MR])
{
    int tap = k0 / a->cin, c0 = k0 % a->cin, ky = tap / a->kw, kx = tap % a->kw;
    for (int r = 0; r < MR; r++) {
        const float *x = tap_pixel(a, pix + 2 * (i * MR + r), ky, kx, zeros);
        ar[r] = x == zeros ? zeros : x + c0;
    }
}

/* Every tap's row pointers for the mp micro-panels, tab[i][t][r] (the
 * taps mode): a pixel whose whole window lies in the image gets its tap
 * offsets added to one base (direct_rows per tap and micro-panel was a
 * quarter of a 16-channel 3x3's time, Zen 5); the others, and rows past
 * the end, by tap_pixel. */
static void tap_rows(const struct fk__asrc *a, const int *pix, int mp, int taps, const float *zeros,
                     const float **tab)
{
    size_t off[FK_TAPS_MAX];
    for (int t = 0; t < taps; t++)
        off[t] = ((size_t)(t / a->kw) * (size_t)a->w + (size_t)(t % a->kw)) * (size_t)a->cin;
    for (int i = 0; i < mp; i++)
        for (int r = 0; r < MR; r++) {
            const int *p = pix + 2 * (i * MR + r);
            const float **d = tab + (size_t)i * (size_t)taps * MR + r;
            if (p[0] != INT_MIN && p[0] >= 0 && p[0] + a->kh <= a->h && p[1] >= 0 && p[1] + a->kw <= a->w) {
                const float *base = a->x + ((size_t)p[0] * (size_t)a->w + (size_t)p[1]) * (size_t)a->cin;
                for (int t = 0; t < taps; t++)
                    d[(size_t)t * MR] = base + off[t];
                continue;
            }
            for (int t = 0; t < taps; t++)
                d[(size_t)t * MR] = tap_pixel(a, p, t / a->kw, t % a->kw, zeros);
        }
}

/* Pulls `lines` cache lines from p towards L1, the share of micro-panel i of mp. */
static inline void prefetch_share(const char *p, size_t lines, int i, int mp)
{
    if (!p)
        return;
    size_t per = (lines + (size_t)mp - 1) / (size_t)mp;
    for (size_t l = (size_t)i * per; l < (size_t)(i + 1) * per && l < lines; l++)
        _mm_prefetch(p + l * 64, _MM_HINT_T0);
}

/* AVX-512: claims the output rows of the tile whose last k block is about
 * to run (rows m.., `pw` panels from jp), so that its epilogue's stores find
 * their lines in L1, owned. Without it the epilogue, mostly those stores
 * (write misses), took 4.2-4.9 % of the f32 GEMM's samples on Zen 5 (1374 x
 * 1024 <- 1024, one thread); with it 2.4 %. */
/* A wide tile's place in a dense destination (the AVX-512 path; not a
 * transposed convolution's scatter): rows from m, `pw` panels from jp. */
struct wide_out {
    int          n0, nn;  /* first column, columns that exist        */
    float       *y;       /* element (m, n0)                         */
    const float *gamma;   /* LayerScale from n0, or NULL             */
};

static inline struct wide_out wide_out(const struct gemm_job *j, int m, int jp, int pw)
{
    struct wide_out w;
    w.n0 = jp * NR;
    w.nn = j->L->n - w.n0 < pw * NR ? j->L->n - w.n0 : pw * NR;
    w.y = j->c->y + (size_t)m * (size_t)j->c->ldy + (size_t)w.n0;
    w.gamma = j->ep->gamma ? j->ep->gamma + w.n0 : NULL;
    return w;
}

static inline void prefetch_out(const struct gemm_job *j, int m, int rows, int jp, int pw)
{
    if (!j->wide || j->c->tconv_k)
        return;
    struct wide_out w = wide_out(j, m, jp, pw);
    fk__gemm_prefetchw_rows(w.y, (size_t)j->c->ldy, rows < MR ? rows : MR, w.nn);
}

/* The C tile is [mp][np][6][16]: micro-tile (i, p) at ((i * np + p) * 6) * 16. */
static inline size_t tile_at(int i, int np, int p) { return ((size_t)i * (size_t)np + (size_t)p) * MR * NR; }

static inline struct row_out row_out_of(const struct gemm_job *j)
{
    const struct fk__cdst *c = j->c;
    return (struct row_out){ j->ep->act, j->ep->gamma, j->ep->accumulate, c->tconv_k, c->tconv_cout,
                             c->y, (size_t)c->ldy, c };
}

/* The epilogue of one finished 6 x 16 fp32 tile (panel jp, rows m .. m +
 * nr - 1), run right after its last k block while the tile is in L1
 * (a pass over the whole mc x nc tile afterwards read it back from L2). */
static void epi_f32(const struct gemm_job *j, const float *ci, int m, int nr, int jp)
{
    const struct fk_linear *L = j->L;
    int n0 = jp * NR, nn = L->n - n0 < NR ? L->n - n0 : NR;
    __m256 b0 = _mm256_load_ps(L->bias + n0), b1 = _mm256_load_ps(L->bias + n0 + 8);
    const struct row_out o = row_out_of(j);
    if (nn == NR && !o.tconv_k && !o.gamma && !o.accumulate && o.act == FK_ACT_NONE) {
        /* the plain case in a loop of its own: store_row's and activate's
         * tests per row were a third of this tile's epilogue at k = 64 */
        float *d = o.y + (size_t)m * o.ldy + (size_t)n0;
        for (int r = 0; r < nr; r++, d += o.ldy) {
            _mm256_storeu_ps(d, _mm256_add_ps(_mm256_load_ps(ci + (size_t)r * NR), b0));
            _mm256_storeu_ps(d + 8, _mm256_add_ps(_mm256_load_ps(ci + (size_t)r * NR + 8), b1));
        }
        return;
    }
    for (int r = 0; r < nr; r++) {
        const float *cr = ci + (size_t)r * NR;
        __m256 t0 = activate(o.act, _mm256_add_ps(_mm256_load_ps(cr), b0));
        __m256 t1 = activate(o.act, _mm256_add_ps(_mm256_load_ps(cr + 8), b1));
        store_row(&o, m + r, n0, nn, t0, t1);
    }
}

/* The int8 epilogue of one finished 6 x 16 int32 tile: take the +128 of the
 * u8 activations back out, scale by row and channel, bias, activation. */
static void epi_q8(const struct gemm_job *j, const int32_t *ci, const float *sa, int m, int nr, int jp,
                   int u8)
{
    const struct fk_linear *L = j->L;
    int n0 = jp * NR, nn = L->n - n0 < NR ? L->n - n0 : NR;
    __m256 b0 = _mm256_load_ps(L->bias + n0), b1 = _mm256_load_ps(L->bias + n0 + 8);
    __m256 w0 = _mm256_load_ps(L->scale + n0), w1 = _mm256_load_ps(L->scale + n0 + 8);
    __m256i cs0 = _mm256_setzero_si256(), cs1 = _mm256_setzero_si256();
    if (u8) {
        cs0 = _mm256_load_si256((const __m256i *)(L->colsum + n0));
        cs1 = _mm256_load_si256((const __m256i *)(L->colsum + n0 + 8));
    }
    const struct row_out o = row_out_of(j);
    for (int r = 0; r < nr; r++) {
        const int32_t *cr = ci + (size_t)r * NR;
        __m256 s_r = _mm256_set1_ps(sa[r]);
        __m256i a0 = _mm256_sub_epi32(_mm256_load_si256((const __m256i *)cr), cs0);
        __m256i a1 = _mm256_sub_epi32(_mm256_load_si256((const __m256i *)(cr + 8)), cs1);
        __m256 t0 = _mm256_fmadd_ps(_mm256_cvtepi32_ps(a0), _mm256_mul_ps(s_r, w0), b0);
        __m256 t1 = _mm256_fmadd_ps(_mm256_cvtepi32_ps(a1), _mm256_mul_ps(s_r, w1), b1);
        store_row(&o, m + r, n0, nn, activate(o.act, t0), activate(o.act, t1));
    }
}

static void task_float(const struct gemm_job *j, int m0, int rows, int jp0, int jp1, char *s)
{
    const struct fk_linear *L = j->L;
    int k = L->k, mp = (rows + MR - 1) / MR, KC = j->kc, f32 = L->type == FK_W_F32;
    float *ap = (float *)s, *ct = (float *)(s + j->off_c), *bconv = (float *)(s + j->off_b);
    const float *zeros = (const float *)(s + j->off_zero);
    const struct fk__asrc *src = j->a;
    int *pix = (int *)(void *)(s + j->off_pix);
    const float **tap = (const float **)(void *)(s + j->off_tap); /* [mp][taps][MR] */
    if (j->direct)
        direct_pix(src, m0, rows, mp, pix);
    if (j->taps)
        tap_rows(src, pix, mp, j->taps, zeros, tap);
    for (int jg = jp0; jg < jp1; jg += j->nc_panels) {
        int jge = jg + j->nc_panels < jp1 ? jg + j->nc_panels : jp1, np = jge - jg;
        for (int k0 = 0, kc; k0 < k; k0 += kc) {
            /* direct convolution: k blocks never straddle two taps */
            kc = j->direct && !j->taps ? src->cin - k0 % src->cin : k - k0;
            kc = kc < KC ? kc : KC;
            if (!j->direct && !j->inplace)
                pack_a_f32(src, m0, rows, k0, kc, ap, zeros);
            /* AVX-512: two panels per step (a 6x32 tile), direct convolutions too
             * (at 6x16 in ymm they ran the DPT heads at half the zmm rate) */
            int step = j->wide ? 2 : 1;
            size_t esz = f32 ? 4 : 2, sliver_lines = (size_t)kc * NR * esz / 64;
            for (int jp = jg; jp < jge; jp += step) {
                int pair = step == 2 && jp + 1 < jge;
                const float *bp, *bp1 = NULL;
                for (int q = 0; q <= pair; q++) {
                    const float *b;
                    if (f32) {
                        b = (const float *)L->data + ((size_t)(jp + q) * (size_t)k + (size_t)k0) * NR;
                    } else {
                        /* fp16: widened once per sliver, used by every micro-panel */
                        const uint16_t *h = (const uint16_t *)L->data + ((size_t)(jp + q) * (size_t)k + (size_t)k0) * NR;
                        float *d = bconv + (size_t)q * (size_t)kc * NR;
                        if (j->wide) /* half the conversion uops, off the FMA ports' time */
                            fk__f16_to_f32_avx512(h, d, kc * NR);
                        else
                            for (int e = 0; e < kc * NR; e += 8)
                                _mm256_store_ps(d + e, _mm256_cvtph_ps(_mm_load_si128((const __m128i *)(h + e))));
                        b = d;
                    }
                    if (q)
                        bp1 = b;
                    else
                        bp = b;
                }
                /* the next sliver(s) (next panels, same k block) towards L1 while
                 * these are in use, a few lines per micro-panel */
                const char *next = NULL, *next1 = NULL;
                int jn = jp + (pair ? 2 : 1);
                if (jn < jge)
                    next = (const char *)L->data + ((size_t)jn * (size_t)k + (size_t)k0) * NR * esz;
                if (pair && jn + 1 < jge)
                    next1 = (const char *)L->data + ((size_t)(jn + 1) * (size_t)k + (size_t)k0) * NR * esz;
                for (int i = 0; i < mp; i++) {
                    prefetch_share(next, sliver_lines, i, mp);
                    prefetch_share(next1, sliver_lines, i, mp);
                    float *ci = ct + tile_at(i, np, jp - jg);
                    if (i + 1 < mp)
                        for (int l = 0; l < MR * NR * 4 * (1 + pair); l += 64)
                            _mm_prefetch((const char *)(ci + MR * NR * np) + l, _MM_HINT_T0);
                    if (k0 + kc >= k)
                        prefetch_out(j, m0 + i * MR, rows - i * MR, jp, 1 + pair);
                    if (j->taps) {
                        const float *const *ti = tap + (size_t)i * (size_t)j->taps * MR;
                        if (j->wide)
                            fk__gemm_f32_ukr_avx512_taps(j->taps, src->cin, ti, bp, pair ? bp1 : NULL, ci, 0);
                        else
                            ukr_f32(j->taps, src->cin, ti, 1, bp, ci, NR, 0);
                    } else if (j->direct || j->inplace) {
                        const float *ar[MR];
                        if (j->direct)
                            direct_rows(src, pix, i, k0, zeros, ar);
                        else
                            for (int r = 0; r < MR; r++)
                                ar[r] = i * MR + r < rows ? src->x + (size_t)(m0 + i * MR + r) * (size_t)src->ldx + (size_t)k0
                                                          : zeros;
                        if (j->wide)
                            fk__gemm_f32_ukr_avx512_taps(1, kc, ar, bp, pair ? bp1 : NULL, ci, k0 > 0);
                        else
                            ukr_f32(1, kc, ar, 1, bp, ci, NR, k0 > 0);
                    } else if (pair) {
                        fk__gemm_f32_ukr_avx512(kc, ap + (size_t)i * (size_t)kc * MR, bp, bp1, ci, k0 > 0);
                    } else if (j->wide) {
                        const float *a0 = ap + (size_t)i * (size_t)kc * MR;
                        const float *ar[MR] = { a0, a0 + 1, a0 + 2, a0 + 3, a0 + 4, a0 + 5 };
                        fk__gemm_f32_ukr_avx512_6x16(1, kc, ar, MR, bp, ci, k0 > 0);
                    } else {
                        ukr_f32_packed(kc, ap + (size_t)i * (size_t)kc * MR, bp, ci, k0 > 0);
                    }
                    if (k0 + kc >= k) { /* last k block: this tile is final */
                        int nr = rows - i * MR < MR ? rows - i * MR : MR;
                        if (j->wide && !j->c->tconv_k) {
                            struct wide_out w = wide_out(j, m0 + i * MR, jp, 1 + pair);
                            fk__epi_f32_avx512(ci, nr, w.nn, L->bias + w.n0, j->ep, w.gamma, w.y,
                                               (size_t)j->c->ldy);
                        } else {
                            epi_f32(j, ci, m0 + i * MR, nr, jp);
                            if (pair)
                                epi_f32(j, ci + MR * NR, m0 + i * MR, nr, jp + 1);
                        }
                    }
                }
            }
        }
    }
}

static void task_q8(const struct gemm_job *j, int m0, int rows, int jp0, int jp1, char *s)
{
    const struct fk_linear *L = j->L;
    int mp = (rows + MR - 1) / MR, k4 = j->k_pad / 4, KC4 = j->kc, u8 = j->path != Q8_EXACT16;
    int32_t *ct = (int32_t *)(s + j->off_c);
    float *sa = (float *)(s + j->off_sa);
    size_t esz = u8 ? 1 : 2, panel_a = (size_t)j->k_pad * MR * esz;
    /* whole rows: each is quantized with its own scale before any k block */
    pack_a_q8(j->a, m0, rows, L->k, j->k_pad, u8, j->wide, s, sa, (float *)(s + j->off_tmp),
              (int8_t *)(s + j->off_q));
    for (int jg = jp0; jg < jp1; jg += j->nc_panels) {
        int jge = jg + j->nc_panels < jp1 ? jg + j->nc_panels : jp1, np = jge - jg;
        for (int q0 = 0, qn; q0 < k4; q0 += qn) {
            qn = k4 - q0 < KC4 ? k4 - q0 : KC4;
            int step = j->wide ? 2 : 1;
            size_t sliver_lines = (size_t)qn * NR * 4 / 64, panel_b = (size_t)k4 * NR * 4;
            for (int jp = jg; jp < jge; jp += step) {
                int pair = step == 2 && jp + 1 < jge;
                const int8_t *bp = (const int8_t *)L->data + ((size_t)jp * (size_t)k4 + (size_t)q0) * NR * 4;
                int jn = jp + (pair ? 2 : 1);
                const char *next = jn < jge ? (const char *)(bp + (size_t)(jn - jp) * panel_b) : NULL;
                const char *next1 = pair && jn + 1 < jge ? (const char *)(bp + (size_t)(jn + 1 - jp) * panel_b) : NULL;
                for (int i = 0; i < mp; i++) {
                    prefetch_share(next, sliver_lines, i, mp);
                    prefetch_share(next1, sliver_lines, i, mp);
                    const char *ai = s + (size_t)i * panel_a + (size_t)q0 * MR * 4 * esz;
                    int32_t *ci = ct + tile_at(i, np, jp - jg);
                    if (q0 + qn >= k4)
                        prefetch_out(j, m0 + i * MR, rows - i * MR, jp, 1 + pair);
                    if (pair) {
                        fk__gemm_q8_ukr_avx512(qn, (const uint8_t *)ai, bp, bp + panel_b, ci, q0 > 0);
                    } else if (j->wide) {
                        fk__gemm_q8_ukr_avx512_6x16(qn, (const uint8_t *)ai, bp, ci, q0 > 0);
                    } else {
                        switch (j->path) {
                        case Q8_VNNI:  fk__gemm_q8_ukr_vnni(qn, (const uint8_t *)ai, bp, ci, q0 > 0); break;
                        case Q8_7BIT:  ukr_q7_avx2(qn, (const uint8_t *)ai, bp, ci, q0 > 0); break;
                        default:       ukr_q8_avx2(qn, (const int16_t *)(const void *)ai, bp, ci, q0 > 0); break;
                        }
                    }
                    if (q0 + qn >= k4) { /* last k block: this tile is final */
                        int nr = rows - i * MR < MR ? rows - i * MR : MR;
                        if (j->wide && !j->c->tconv_k) {
                            struct wide_out w = wide_out(j, m0 + i * MR, jp, 1 + pair);
                            fk__epi_q8_avx512(ci, sa + i * MR, nr, w.nn, L->bias + w.n0, L->scale + w.n0,
                                              u8 ? L->colsum + w.n0 : NULL, j->ep, w.gamma, w.y,
                                              (size_t)j->c->ldy);
                        } else {
                            epi_q8(j, ci, sa + i * MR, m0 + i * MR, nr, jp, u8);
                            if (pair)
                                epi_q8(j, ci + MR * NR, sa + i * MR, m0 + i * MR, nr, jp + 1, u8);
                        }
                    }
                }
            }
        }
    }
}

static void gemm_task(void *arg, int task, int thread)
{
    const struct gemm_job *j = arg;
    /* m blocks inner: tasks running together share one chunk of weights */
    int nb = task / j->m_blocks, mb = task % j->m_blocks;
    int m0 = mb * j->mc, rows = j->m - m0 < j->mc ? j->m - m0 : j->mc;
    int jp0 = nb * j->panels_per_chunk;
    int jp1 = jp0 + j->panels_per_chunk < j->panels ? jp0 + j->panels_per_chunk : j->panels;
    char *s = fk__scratch(j->ctx, thread);
    if (j->L->type == FK_W_Q8)
        task_q8(j, m0, rows, jp0, jp1, s);
    else
        task_float(j, m0, rows, jp0, jp1, s);
}

int fk__gemm_avx2(fk_ctx *ctx, const struct fk_linear *L, const struct fk__asrc *a, int m,
                  const struct fk__cdst *c, const struct fk_epilogue *ep)
{
    struct gemm_job j;
    memset(&j, 0, sizeof j);
    j.ctx = ctx; j.L = L; j.a = a; j.c = c; j.ep = ep; j.m = m; j.n_chunks = 1;
    int k = L->k, q8 = L->type == FK_W_Q8;
    struct fk_gemm_blocks bl = fk_ctx_gemm_blocks(ctx);
    /* 7-bit codes run on any of the three kernels; 8-bit ones never on ukr_q7 */
    j.path = ctx->isa == FK_ISA_AVX2_VNNI || ctx->isa == FK_ISA_AVX512 ? Q8_VNNI
           : L->q8_bits == FK_Q8_7BIT ? Q8_7BIT : Q8_EXACT16;
    j.wide = ctx->isa == FK_ISA_AVX512;
    j.k_pad = q8 ? (int)fk__round_up((size_t)k, 4) : k;
    j.panels = (L->n + NR - 1) / NR;
    /* f32: kc elements of k per block; int8: kc groups of 4 (the same bytes
     * of weights per sliver, a quarter of the A bytes per row of k) */
    j.kc = bl.kc;
    if (j.wide) /* two slivers share the half of L1 that one had */
        j.kc = bl.kc / 2 / 8 * 8 > 8 ? bl.kc / 2 / 8 * 8 : 8;
    j.nc_panels = bl.nc / NR > 0 ? bl.nc / NR : 1;
    /* Stride-1 convolutions (3x3 in the DPT heads) read A in place, every
     * tap in one call (`taps`) where the whole k's weight slivers fit 3/4 of
     * L1 (AVX-512: two slivers; 16 / 32 channels at 3x3; AVX2: one, up to
     * 64): the accumulators stay in registers across the taps. Against the
     * packed im2col path that made 3-12 channels 1.4-2.5x faster (one
     * thread, both ISAs, Zen 5). Larger k reads in place a tap's channels
     * per call where they make a k block worth it: at 8 channels a call per
     * tap spent more on row pointers and C-tile reloads than on FMAs (packed
     * ran 1.6-2x faster), at 16 both ways ran alike. */
    size_t l1 = ctx->caches.l1d ? ctx->caches.l1d : 32 * 1024;
    int kmax = (int)(l1 * 3 / 4 / ((j.wide ? 2 : 1) * NR * sizeof(float))) / 8 * 8;
    int stride1 = !q8 && a->conv && a->stride == 1;
    if (stride1 && k <= kmax && a->kh * a->kw <= FK_TAPS_MAX) {
        j.direct = 1;
        j.taps = a->kh * a->kw;
        j.kc = k;
    } else {
        j.direct = stride1 && a->cin >= FK_DIRECT_MIN_CIN;
    }
    if (j.wide && j.direct && !j.taps && kmax > j.kc) {
        /* AVX-512: a tap's channels in as few equal k blocks as fit two
         * slivers in 3/4 of L1 (the six pixels' runs are the rest): at 256
         * channels one call per tap, not 192 + 64 */
        int parts = (a->cin + kmax - 1) / kmax;
        int kc = (a->cin + parts - 1) / parts;
        kc = (kc + 7) / 8 * 8;
        j.kc = kc < kmax ? kc : kmax;
    }
    /* A read in place, not packed, where the pack would serve at most 4
     * panels (n <= 64): 226 x 64 <- 64 / 256, 1374 x 64 <- 1024, 5496 x 64 <-
     * 1024 and 1374 x 48 <- 4096 ran 3-35 % faster (1 and 2 threads, AVX2 and
     * AVX-512, Zen 5); at 8 panels (226 x 128 <- 128) the zmm path lost 2-6 %,
     * at 16 both were alike. The tiles that read rows in place (the direct
     * convolutions') keep the packed tiles' order of operations: same bits. */
    j.inplace = !q8 && !a->conv && j.panels <= 4;
    int mc = bl.mc / MR * MR;
    if (mc < MR)
        mc = MR;
    /* Scratch is laid out for this mc, which does not depend on m: the need is
     * the same for every row count, so one measured at any size covers all
     * (fk_ctx_measure); mc below never exceeds it (it only shrinks, or becomes
     * 4 * MR). */
    int threads = ctx->threads;
    const int mc_scratch = threads > 1 && mc < 4 * MR ? 4 * MR : mc;
    /* Enough tasks for both threads: shrink mc (not below 4 * MR), then split
     * the panels. */
    mc = fk__gemm_plan_mc(threads, m, mc, 4 * MR);
    /* Near-equal blocks, as many as a multiple of the threads: a short last
     * block leaves a core idle at the end (1374 rows in blocks of 144 lost ~5 %);
     * on one thread it streams every weight from L3 for a few rows (1374 rows
     * as 678 + 678 + 18: AVX-512 f32 0.95-0.99x OpenBLAS, as 3 x 462 1.03-1.11x) */
    {
        int nb = (m + mc - 1) / mc;
        nb = (nb + threads - 1) / threads * threads;
        int even = (int)fk__round_up((size_t)((m + nb - 1) / nb), MR);
        if (even < mc)
            mc = even;
    }
    j.mc = mc;
    j.m_blocks = (m + mc - 1) / mc;
    fk__gemm_plan_chunks(threads, j.m_blocks, j.panels, &j.n_chunks, &j.panels_per_chunk);
    /* AVX-512 runs panels in pairs: an odd chunk leaves one panel to the
     * 6x16 ymm kernel at half the rate (fc1's 256 panels in L2 chunks of 43
     * spent 3.7 % of its time there, one thread, Zen 5) */
    if (j.wide && j.panels_per_chunk % 2 && j.panels_per_chunk < j.panels) {
        j.panels_per_chunk++;
        j.n_chunks = (j.panels + j.panels_per_chunk - 1) / j.panels_per_chunk;
    }
    if (j.wide && j.nc_panels % 2)
        j.nc_panels++;
    /* Scratch is laid out for mc_scratch and for the largest chunk of
     * panels, neither of which depends on m: one need measured at any size
     * covers every size (fk_ctx_measure). The C tile (mc x nc of fp32 /
     * int32) is bounded by half the L3 share (AVX-512; AVX2 fp32 and fp16)
     * or the L2 size (AVX2 int8): the nc of the model then shrinks to even
     * chunks (A is packed once per chunk). */
    size_t mcp = fk__round_up((size_t)mc_scratch, MR);
    size_t l2 = ctx->caches.l2_share ? ctx->caches.l2_share : ctx->caches.l2 ? ctx->caches.l2 : 512 * 1024;
    /* AVX-512's 6x32 calls touch their C tile once per 12 kc / 2 FMAs:
     * from L3 it costs less than packing A again for every L2-sized chunk
     * (one chunk: 5496 x 1024 <- 4096 and 1374 x 1024 <- 4096 1-2.5 %
     * faster, fc1 alike, Zen 5). AVX2's fp32 6x16 calls alike, once per 12
     * kc FMAs: the packs of A, which streams from L3 or memory, were 4-5 %
     * of the GEMM's samples at 32-panel chunks; one chunk ran 0.3-3.8 %
     * faster on every model shape, 1 and 2 threads (Zen 4). int8 packs A
     * once per task whatever the chunks, so its C tile stays in L2. */
    size_t cbound = l2;
    if ((j.wide || !q8) && ctx->caches.l3_share / 2 > l2)
        cbound = ctx->caches.l3_share / 2;
    int cap = (int)(cbound / (mcp * NR * 4));
    cap = cap < 4 ? 4 : j.wide ? cap / 2 * 2 : cap; /* even: whole pairs */
    int np = j.nc_panels < cap ? j.nc_panels : cap; /* bounds the runtime chunk below */
    np = np < j.panels ? np : j.panels;
    if (j.nc_panels > cap) {
        int chunks = (j.panels_per_chunk + cap - 1) / cap;
        j.nc_panels = (j.panels_per_chunk + chunks - 1) / chunks;
        if (j.wide && j.nc_panels % 2) /* still <= cap, which is even */
            j.nc_panels++;
    }

    int kcb = k < j.kc ? k : j.kc; /* fp32 block width */
    size_t a_bytes = q8 ? mcp * (size_t)j.k_pad * (j.path == Q8_EXACT16 ? 2 : 1) + 8 * sizeof(float)
                        : mcp * (size_t)kcb * 4 + 8 * sizeof(float); /* + transpose spill */
    size_t bytes_a = j.direct || j.inplace ? 0 : fk__round_up(a_bytes, FK_ALIGN);
    j.off_c = bytes_a;
    j.off_b = j.off_c + fk__round_up(mcp * (size_t)np * NR * 4, FK_ALIGN);
    j.off_tmp = j.off_b + (q8 || L->type == FK_W_F32 ? 0 : fk__round_up((size_t)kcb * NR * 4 * 2, FK_ALIGN));
    size_t tmp = a->conv && q8 ? (size_t)k * 4 : 0; /* pack_a_q8's im2col row */
    j.off_q = j.off_tmp + fk__round_up(tmp, FK_ALIGN);
    j.off_sa = j.off_q + (q8 ? fk__round_up((size_t)MR * (size_t)j.k_pad, FK_ALIGN) : 0); /* q[6][k_pad] */
    /* a row of zeros stands in for the padding rows of the last micro-panel */
    j.off_zero = j.off_sa + fk__round_up(q8 ? mcp * 4 : 0, FK_ALIGN);
    j.off_pix = j.off_zero + fk__round_up(q8 ? 0 : (size_t)kcb * 4, FK_ALIGN);
    j.off_tap = j.off_pix + fk__round_up(j.direct ? mcp * 2 * sizeof(int) : 0, FK_ALIGN);
    size_t need = j.off_tap + mcp * (size_t)j.taps * sizeof(const float *) + FK_ALIGN;
    int st = fk__scratch_reserve(ctx, need, 0);
    if (st || fk__measuring(ctx))
        return st;
    if (!q8)
        for (int t = 0; t < ctx->threads; t++)
            memset((char *)fk__scratch(ctx, t) + j.off_zero, 0, (size_t)kcb * 4);

    double work = 2.0 * m * (double)L->n * k;
    fk_parallel_for(ctx, j.m_blocks * j.n_chunks, work, gemm_task, &j);
    return F4D_OK;
}
