/* gemm_avx512.c - the GEMM micro-kernels for CPUs with AVX-512 (F, BW, VL,
 * VNNI): two adjacent 16-wide weight panels at once, so the packed layouts of
 * the AVX2 path (A micro-panels [k][6], weight panels [k][16]) serve
 * unchanged and the driver stays the AVX2 one. A 6 x 32 tile is 12 zmm
 * accumulators; each k step loads two zmm of weights and broadcasts six
 * values of A. */
#include <immintrin.h>
#include <string.h>

#include "../fk_internal.h"
#include "../gemm.h"
#include "vecmath_avx2.h"
#include "vecmath_avx512.h"

void fk__gemm_f32_ukr_avx512(int kc, const float *a, const float *b0, const float *b1, float *c,
                             int accumulate)
{
    __m512 c00, c01, c10, c11, c20, c21, c30, c31, c40, c41, c50, c51;
    /* c is [2][6][16]: panel 0's tile, then panel 1's */
    if (accumulate) {
        c00 = _mm512_load_ps(c + 0);  c10 = _mm512_load_ps(c + 16); c20 = _mm512_load_ps(c + 32);
        c30 = _mm512_load_ps(c + 48); c40 = _mm512_load_ps(c + 64); c50 = _mm512_load_ps(c + 80);
        c01 = _mm512_load_ps(c + 96);  c11 = _mm512_load_ps(c + 112); c21 = _mm512_load_ps(c + 128);
        c31 = _mm512_load_ps(c + 144); c41 = _mm512_load_ps(c + 160); c51 = _mm512_load_ps(c + 176);
    } else {
        c00 = c01 = c10 = c11 = c20 = c21 = _mm512_setzero_ps();
        c30 = c31 = c40 = c41 = c50 = c51 = _mm512_setzero_ps();
    }
#pragma GCC unroll 4
    for (int k = 0; k < kc; k++) {
        __m512 w0 = _mm512_load_ps(b0), w1 = _mm512_load_ps(b1), t;
        t = _mm512_set1_ps(a[0]); c00 = _mm512_fmadd_ps(t, w0, c00); c01 = _mm512_fmadd_ps(t, w1, c01);
        t = _mm512_set1_ps(a[1]); c10 = _mm512_fmadd_ps(t, w0, c10); c11 = _mm512_fmadd_ps(t, w1, c11);
        t = _mm512_set1_ps(a[2]); c20 = _mm512_fmadd_ps(t, w0, c20); c21 = _mm512_fmadd_ps(t, w1, c21);
        t = _mm512_set1_ps(a[3]); c30 = _mm512_fmadd_ps(t, w0, c30); c31 = _mm512_fmadd_ps(t, w1, c31);
        t = _mm512_set1_ps(a[4]); c40 = _mm512_fmadd_ps(t, w0, c40); c41 = _mm512_fmadd_ps(t, w1, c41);
        t = _mm512_set1_ps(a[5]); c50 = _mm512_fmadd_ps(t, w0, c50); c51 = _mm512_fmadd_ps(t, w1, c51);
        a += 6;
        b0 += 16;
        b1 += 16;
    }
    _mm512_store_ps(c + 0, c00);   _mm512_store_ps(c + 16, c10);  _mm512_store_ps(c + 32, c20);
    _mm512_store_ps(c + 48, c30);  _mm512_store_ps(c + 64, c40);  _mm512_store_ps(c + 80, c50);
    _mm512_store_ps(c + 96, c01);  _mm512_store_ps(c + 112, c11); _mm512_store_ps(c + 128, c21);
    _mm512_store_ps(c + 144, c31); _mm512_store_ps(c + 160, c41); _mm512_store_ps(c + 176, c51);
}

/* The 6 x 32 tile (or 6 x 16: b1 NULL, six accumulators) with the six rows
 * of A read in place, the tap t's at a[6 t + r] (zeros for padding), cin
 * k-steps per tap: a stride-1 convolution's whole k in one call (ntaps
 * taps), the accumulators in registers from the first tap to the last (a
 * call per tap reloaded and stored the C tile and rebuilt six row pointers
 * for 16 or 32 k-steps: 16- and 32-channel 3x3s at 0.59 / 0.75 of the zmm
 * peak, one thread, Zen 5), or one tap's channel block (ntaps 1, cin = kc,
 * accumulate: add to c), or rows of a plain GEMM read in place. Each element
 * accumulates along k one FMA at a time, as the packed kernel and the AVX2
 * 6x16 one: their bits. c is [2][6][16] (or [6][16]). */
void fk__gemm_f32_ukr_avx512_taps(int ntaps, int cin, const float *const *a, const float *b0,
                                  const float *b1, float *c, int accumulate)
{
    if (!b1) {
        fk__gemm_f32_ukr_avx512_6x16(ntaps, cin, a, 1, b0, c, accumulate);
        return;
    }
    /* named accumulators: arrays of them made GCC zero a stack copy with
     * rep stos on every call */
    __m512 c00, c01, c10, c11, c20, c21, c30, c31, c40, c41, c50, c51, x;
    if (accumulate) {
        c00 = _mm512_load_ps(c + 0);   c10 = _mm512_load_ps(c + 16);  c20 = _mm512_load_ps(c + 32);
        c30 = _mm512_load_ps(c + 48);  c40 = _mm512_load_ps(c + 64);  c50 = _mm512_load_ps(c + 80);
        c01 = _mm512_load_ps(c + 96);  c11 = _mm512_load_ps(c + 112); c21 = _mm512_load_ps(c + 128);
        c31 = _mm512_load_ps(c + 144); c41 = _mm512_load_ps(c + 160); c51 = _mm512_load_ps(c + 176);
    } else {
        c00 = c01 = c10 = c11 = c20 = c21 = _mm512_setzero_ps();
        c30 = c31 = c40 = c41 = c50 = c51 = _mm512_setzero_ps();
    }
    for (int t = 0; t < ntaps; t++, a += FK_GEMM_MR) {
        const float *a0 = a[0], *a1 = a[1], *a2 = a[2], *a3 = a[3], *a4 = a[4], *a5 = a[5];
#pragma GCC unroll 4
        for (int k = 0; k < cin; k++, b0 += 16, b1 += 16) {
            __m512 w0 = _mm512_load_ps(b0), w1 = _mm512_load_ps(b1);
            x = _mm512_set1_ps(a0[k]); c00 = _mm512_fmadd_ps(x, w0, c00); c01 = _mm512_fmadd_ps(x, w1, c01);
            x = _mm512_set1_ps(a1[k]); c10 = _mm512_fmadd_ps(x, w0, c10); c11 = _mm512_fmadd_ps(x, w1, c11);
            x = _mm512_set1_ps(a2[k]); c20 = _mm512_fmadd_ps(x, w0, c20); c21 = _mm512_fmadd_ps(x, w1, c21);
            x = _mm512_set1_ps(a3[k]); c30 = _mm512_fmadd_ps(x, w0, c30); c31 = _mm512_fmadd_ps(x, w1, c31);
            x = _mm512_set1_ps(a4[k]); c40 = _mm512_fmadd_ps(x, w0, c40); c41 = _mm512_fmadd_ps(x, w1, c41);
            x = _mm512_set1_ps(a5[k]); c50 = _mm512_fmadd_ps(x, w0, c50); c51 = _mm512_fmadd_ps(x, w1, c51);
        }
    }
    _mm512_store_ps(c + 0, c00);   _mm512_store_ps(c + 16, c10);  _mm512_store_ps(c + 32, c20);
    _mm512_store_ps(c + 48, c30);  _mm512_store_ps(c + 64, c40);  _mm512_store_ps(c + 80, c50);
    _mm512_store_ps(c + 96, c01);  _mm512_store_ps(c + 112, c11); _mm512_store_ps(c + 128, c21);
    _mm512_store_ps(c + 144, c31); _mm512_store_ps(c + 160, c41); _mm512_store_ps(c + 176, c51);
}

/* One 16-wide panel (the odd one of a chunk, or n <= 16): a 6 x 16 tile in
 * six zmm accumulators, ntaps taps of kc k-steps, row r of tap t at
 * a[6 t + r][k * step] (step 6: a packed micro-panel, 1: rows in place).
 * Six dependent FMA chains fill three quarters of two 4-cycle FMA pipes,
 * against half the zmm rate for the ymm 6x16 tile it replaces (6912 x 16
 * <- 288, the DPT heads' 16-channel 3x3, was 9 % of the tiny forward's
 * samples there); along k one FMA at a time per element, as every other
 * tile: the same bits. c is [6][16]. */
void fk__gemm_f32_ukr_avx512_6x16(int ntaps, int kc, const float *const *a, int step, const float *b,
                                  float *c, int accumulate)
{
    __m512 c0, c1, c2, c3, c4, c5;
    if (accumulate) {
        c0 = _mm512_load_ps(c + 0);  c1 = _mm512_load_ps(c + 16); c2 = _mm512_load_ps(c + 32);
        c3 = _mm512_load_ps(c + 48); c4 = _mm512_load_ps(c + 64); c5 = _mm512_load_ps(c + 80);
    } else {
        c0 = c1 = c2 = c3 = c4 = c5 = _mm512_setzero_ps();
    }
    for (int t = 0; t < ntaps; t++, a += FK_GEMM_MR) {
        const float *a0 = a[0], *a1 = a[1], *a2 = a[2], *a3 = a[3], *a4 = a[4], *a5 = a[5];
#pragma GCC unroll 4
        for (int k = 0; k < kc; k++, b += 16) {
            __m512 w = _mm512_load_ps(b);
            size_t o = (size_t)k * (size_t)step;
            c0 = _mm512_fmadd_ps(_mm512_set1_ps(a0[o]), w, c0);
            c1 = _mm512_fmadd_ps(_mm512_set1_ps(a1[o]), w, c1);
            c2 = _mm512_fmadd_ps(_mm512_set1_ps(a2[o]), w, c2);
            c3 = _mm512_fmadd_ps(_mm512_set1_ps(a3[o]), w, c3);
            c4 = _mm512_fmadd_ps(_mm512_set1_ps(a4[o]), w, c4);
            c5 = _mm512_fmadd_ps(_mm512_set1_ps(a5[o]), w, c5);
        }
    }
    _mm512_store_ps(c + 0, c0);  _mm512_store_ps(c + 16, c1); _mm512_store_ps(c + 32, c2);
    _mm512_store_ps(c + 48, c3); _mm512_store_ps(c + 64, c4); _mm512_store_ps(c + 80, c5);
}

static inline int load_i32(const uint8_t *p)
{
    int v;
    memcpy(&v, p, sizeof v);
    return v;
}

/* u8 activations (code + 128) x s8 weights, four products per int32 lane,
 * no intermediate saturation (vpdpbusd); exact like the AVX-VNNI kernel. */
void fk__gemm_q8_ukr_avx512(int k4, const uint8_t *a, const int8_t *b0, const int8_t *b1,
                            int32_t *c, int accumulate)
{
    __m512i c00, c01, c10, c11, c20, c21, c30, c31, c40, c41, c50, c51;
    if (accumulate) {
#define LD(o) _mm512_load_si512((const void *)(c + (o)))
        c00 = LD(0);  c10 = LD(16);  c20 = LD(32);  c30 = LD(48);  c40 = LD(64);  c50 = LD(80);
        c01 = LD(96); c11 = LD(112); c21 = LD(128); c31 = LD(144); c41 = LD(160); c51 = LD(176);
#undef LD
    } else {
        c00 = c01 = c10 = c11 = c20 = c21 = _mm512_setzero_si512();
        c30 = c31 = c40 = c41 = c50 = c51 = _mm512_setzero_si512();
    }
    for (int k = 0; k < k4; k++) {
        __m512i w0 = _mm512_load_si512((const void *)b0), w1 = _mm512_load_si512((const void *)b1), t;
#define ROW(r, lo, hi)                                  \
    t = _mm512_set1_epi32(load_i32(a + 4 * (r)));       \
    lo = _mm512_dpbusd_epi32(lo, t, w0);                \
    hi = _mm512_dpbusd_epi32(hi, t, w1);
        ROW(0, c00, c01) ROW(1, c10, c11) ROW(2, c20, c21)
        ROW(3, c30, c31) ROW(4, c40, c41) ROW(5, c50, c51)
#undef ROW
        a += 24;
        b0 += 64;
        b1 += 64;
    }
#define ST(o, v) _mm512_store_si512((void *)(c + (o)), v)
    ST(0, c00);  ST(16, c10);  ST(32, c20);  ST(48, c30);  ST(64, c40);  ST(80, c50);
    ST(96, c01); ST(112, c11); ST(128, c21); ST(144, c31); ST(160, c41); ST(176, c51);
#undef ST
}

/* The int8 tile of one panel (as fk__gemm_f32_ukr_avx512_6x16): six zmm
 * accumulators instead of the ymm VNNI tile's twelve half-width ones;
 * exact sums, so the same values. c is [6][16]. */
void fk__gemm_q8_ukr_avx512_6x16(int k4, const uint8_t *a, const int8_t *b, int32_t *c, int accumulate)
{
    __m512i c0, c1, c2, c3, c4, c5;
    if (accumulate) {
#define LD(r) _mm512_load_si512((const void *)(c + 16 * (r)))
        c0 = LD(0); c1 = LD(1); c2 = LD(2); c3 = LD(3); c4 = LD(4); c5 = LD(5);
#undef LD
    } else {
        c0 = c1 = c2 = c3 = c4 = c5 = _mm512_setzero_si512();
    }
    for (int k = 0; k < k4; k++) {
        __m512i w = _mm512_load_si512((const void *)b);
        c0 = _mm512_dpbusd_epi32(c0, _mm512_set1_epi32(load_i32(a + 0)), w);
        c1 = _mm512_dpbusd_epi32(c1, _mm512_set1_epi32(load_i32(a + 4)), w);
        c2 = _mm512_dpbusd_epi32(c2, _mm512_set1_epi32(load_i32(a + 8)), w);
        c3 = _mm512_dpbusd_epi32(c3, _mm512_set1_epi32(load_i32(a + 12)), w);
        c4 = _mm512_dpbusd_epi32(c4, _mm512_set1_epi32(load_i32(a + 16)), w);
        c5 = _mm512_dpbusd_epi32(c5, _mm512_set1_epi32(load_i32(a + 20)), w);
        a += 24;
        b += 64;
    }
#define ST(r, v) _mm512_store_si512((void *)(c + 16 * (r)), v)
    ST(0, c0); ST(1, c1); ST(2, c2); ST(3, c3); ST(4, c4); ST(5, c5);
#undef ST
}

void fk__f16_to_f32_avx512(const uint16_t *h, float *d, int n)
{
    for (int e = 0; e < n; e += 16)
        _mm512_store_ps(d + e, _mm512_cvtph_ps(_mm256_load_si256((const __m256i *)(h + e))));
}

void fk__gemm_prefetchw_rows(const float *y, size_t ldy, int rows, int cols)
{
    for (int r = 0; r < rows; r++) {
        const char *p = (const char *)(y + (size_t)r * ldy);
        for (int b = 0; b < cols * 4; b += 64)
            __builtin_prefetch(p + b, 1, 3); /* prefetchw */
        __builtin_prefetch(p + cols * 4 - 1, 1, 3);
    }
}

/* ------------------------------------------------------------ int8 rows */

/* fk__q8_quantize_rows_avx512: quantize_runs of gemm_avx2.c (itself
 * fk_quantize_row_q8 bit for bit) in zmm with masked tails, no scalar loop,
 * for the rows of a micro-panel together: the DPT heads' thin 3x3
 * convolutions quantize a 9 C row (C = 16-48) per output pixel, short enough
 * that one row at a time waits on its own chain (loads, the max reduction,
 * the division for the scale) before its codes; the rows' chains are
 * independent, so amax of every row comes first, then the scales, then the
 * codes. The reference's poison sum (x * 0: NaN for Inf / NaN) is replaced
 * by an integer max of |x| (for non-negative floats the integer order is the
 * float order, Inf / NaN sort above every finite value), which gives amax
 * and flags the same rows; max does not depend on the order; the codes are
 * vcvtps2dq of x * (127 / amax) under the default rounding (to nearest even,
 * as nearbyintf), |code| <= 127 so the truncating vpmovdb keeps them. */
static inline uint32_t absmax_bits(const struct fk__arun *r, int nr)
{
    __m512i amax = _mm512_setzero_si512();
    const __m512i absmask = _mm512_set1_epi32(0x7fffffff);
    for (int s = 0; s < nr; s++) {
        const float *x = r[s].p;
        int n = r[s].n, i = 0;
        if (!x)
            continue;
        for (; i + 16 <= n; i += 16)
            amax = _mm512_max_epu32(amax, _mm512_and_si512(_mm512_loadu_si512((const void *)(x + i)), absmask));
        if (i < n)
            amax = _mm512_max_epu32(amax, _mm512_and_si512(
                       _mm512_maskz_loadu_epi32((__mmask16)((1u << (n - i)) - 1), x + i), absmask));
    }
    return _mm512_reduce_max_epu32(amax);
}

static inline void zero_bytes(int8_t *q, int n)
{
    int i = 0;
    for (; i + 64 <= n; i += 64)
        _mm512_storeu_si512((void *)(q + i), _mm512_setzero_si512());
    if (i < n)
        _mm512_mask_storeu_epi8(q + i, ((__mmask64)1 << (n - i)) - 1, _mm512_setzero_si512());
}

static inline void codes(const struct fk__arun *r, int nr, __m512 inv, int8_t *q)
{
    for (int s = 0; s < nr; s++) {
        const float *x = r[s].p;
        int n = r[s].n, i = 0;
        if (!x) { /* padding taps */
            zero_bytes(q, n);
            q += n;
            continue;
        }
        for (; i + 16 <= n; i += 16)
            _mm_storeu_si128((__m128i *)(q + i),
                             _mm512_cvtepi32_epi8(_mm512_cvtps_epi32(_mm512_mul_ps(_mm512_loadu_ps(x + i), inv))));
        if (i < n) {
            __mmask16 mk = (__mmask16)((1u << (n - i)) - 1);
            __m512i v = _mm512_cvtps_epi32(_mm512_mul_ps(_mm512_maskz_loadu_ps(mk, x + i), inv));
            _mm_mask_storeu_epi8(q + i, mk, _mm512_cvtepi32_epi8(v));
        }
        q += n;
    }
}

void fk__q8_quantize_rows_avx512(const struct fk__arun *const r[], const int nr[], int rows, int k,
                                 int k_pad, int8_t *q, size_t ldq, float *sa)
{
    uint32_t bits[FK_GEMM_MR];
    float inv[FK_GEMM_MR];
    for (int j = 0; j < rows; j++)
        bits[j] = absmax_bits(r[j], nr[j]);
    for (int j = 0; j < rows; j++)
        sa[j] = fk__q8_row_scale(bits[j], &inv[j]);
    for (int j = 0; j < rows; j++) {
        int8_t *qj = q + (size_t)j * ldq;
        if (inv[j] == 0) {
            zero_bytes(qj, k_pad);
            continue;
        }
        codes(r[j], nr[j], _mm512_set1_ps(inv[j]), qj);
        if (k_pad > k)
            zero_bytes(qj + k, k_pad - k);
    }
}

/* ------------------------------------------------------- int8 epilogue */

static inline __m512 act16(enum fk_act act, __m512 v)
{
    switch (act) {
    case FK_ACT_RELU:
        return _mm512_max_ps(_mm512_setzero_ps(), v); /* NaN stays NaN, as vmaxps ymm */
    case FK_ACT_GELU: return fk__gelu512(v); /* the AVX2 operations: their bits */
    case FK_ACT_SILU: return fk__silu512(v);
    default:          return v;
    }
}

/* The tail of both epilogues: activation, LayerScale, residual, store of
 * row r's 16 columns of one panel (mask k: the columns that exist). */
static inline void finish16(__m512 t, enum fk_act act, const float *gamma, int accumulate, float *d,
                            __mmask16 k)
{
    t = act16(act, t);
    if (gamma)
        t = _mm512_mul_ps(t, _mm512_maskz_loadu_ps(k, gamma));
    if (accumulate)
        t = _mm512_add_ps(_mm512_maskz_loadu_ps(k, d), t);
    _mm512_mask_storeu_ps(d, k, t);
}

/* One panel's 16 columns of row r (mask k: the columns that exist). */
static inline void epi_q8_16(const int32_t *cr, __m512i cs, __m512 s_w, __m512 b, enum fk_act act,
                             const float *gamma, int accumulate, float *d, __mmask16 k)
{
    __m512i a = _mm512_sub_epi32(_mm512_load_si512((const void *)cr), cs);
    finish16(_mm512_fmadd_ps(_mm512_cvtepi32_ps(a), s_w, b), act, gamma, accumulate, d, k);
}

/* A whole 16-32 column tile row per one or two zmm, masked at the edge
 * (the ymm epilogue ran two halves per panel, a call and a masked
 * maskload / maskstore sequence for each short panel). bias, scale and
 * colsum are padded to whole panels at packing. */
void fk__epi_q8_avx512(const int32_t *ci, const float *sa, int nr, int nn, const float *bias,
                       const float *scale, const int32_t *colsum, const struct fk_epilogue *ep,
                       const float *gamma, float *y, size_t ldy)
{
    __mmask16 k0 = nn >= 16 ? (__mmask16)0xffff : (__mmask16)((1u << nn) - 1);
    __mmask16 k1 = nn >= 32 ? (__mmask16)0xffff : nn > 16 ? (__mmask16)((1u << (nn - 16)) - 1) : 0;
    __m512 b0 = _mm512_load_ps(bias), w0 = _mm512_load_ps(scale);
    __m512i cs0 = colsum ? _mm512_load_si512((const void *)colsum) : _mm512_setzero_si512();
    __m512 b1 = b0, w1 = w0;
    __m512i cs1 = cs0;
    if (k1) {
        b1 = _mm512_load_ps(bias + 16);
        w1 = _mm512_load_ps(scale + 16);
        cs1 = colsum ? _mm512_load_si512((const void *)(colsum + 16)) : _mm512_setzero_si512();
    }
    enum fk_act act = ep->act;
    int acc = ep->accumulate;
    for (int r = 0; r < nr; r++) {
        __m512 s_r = _mm512_set1_ps(sa[r]);
        float *d = y + (size_t)r * ldy;
        epi_q8_16(ci + 16 * r, cs0, _mm512_mul_ps(s_r, w0), b0, act, gamma, acc, d, k0);
        if (k1)
            epi_q8_16(ci + 96 + 16 * r, cs1, _mm512_mul_ps(s_r, w1), b1, act, gamma ? gamma + 16 : NULL, acc,
                      d + 16, k1);
    }
}

/* The fp32 epilogue of one 6-row tile of one or two adjacent panels (ci:
 * [np][6][16]) into nn <= 16 np dense columns at y: + bias[n], activation,
 * LayerScale, residual, the AVX2 epilogue's operations per element (its
 * bits), a zmm per panel row (the ymm one ran each row as two halves). */
void fk__epi_f32_avx512(const float *ci, int nr, int nn, const float *bias,
                        const struct fk_epilogue *ep, const float *gamma, float *y, size_t ldy)
{
    __mmask16 k0 = nn >= 16 ? (__mmask16)0xffff : (__mmask16)((1u << nn) - 1);
    __mmask16 k1 = nn >= 32 ? (__mmask16)0xffff : nn > 16 ? (__mmask16)((1u << (nn - 16)) - 1) : 0;
    __m512 b0 = _mm512_load_ps(bias), b1 = k1 ? _mm512_load_ps(bias + 16) : b0;
    enum fk_act act = ep->act;
    int acc = ep->accumulate;
    for (int r = 0; r < nr; r++) {
        float *d = y + (size_t)r * ldy;
        finish16(_mm512_add_ps(_mm512_load_ps(ci + 16 * r), b0), act, gamma, acc, d, k0);
        if (k1)
            finish16(_mm512_add_ps(_mm512_load_ps(ci + 96 + 16 * r), b1), act, gamma ? gamma + 16 : NULL,
                     acc, d + 16, k1);
    }
}
