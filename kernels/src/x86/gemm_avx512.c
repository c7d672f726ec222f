/* gemm_avx512.c - the GEMM micro-kernels for CPUs with AVX-512 (F, BW, VL,
 * VNNI): two adjacent 16-wide weight panels at once, so the packed layouts of
 * the AVX2 path (A micro-panels [k][6], weight panels [k][16]) serve
 * unchanged and the driver stays the AVX2 one. A 6 x 32 tile is 12 zmm
 * accumulators; each k step loads two zmm of weights and broadcasts six
 * values of A. */
#include <immintrin.h>
#include <string.h>

#include "../gemm.h"

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

/* The same 6 x 32 tile with the six rows of A read in place, one float per
 * k step from a[r] (a stride-1 convolution's pixels: the direct path, no
 * packing); each element accumulates along k in the same order as the
 * packed kernel and the AVX2 6x16 one, so the bits are theirs. */
void fk__gemm_f32_ukr_avx512_rows(int kc, const float *const a[6], const float *b0, const float *b1,
                                  float *c, int accumulate)
{
    const float *a0 = a[0], *a1 = a[1], *a2 = a[2], *a3 = a[3], *a4 = a[4], *a5 = a[5];
    __m512 c00, c01, c10, c11, c20, c21, c30, c31, c40, c41, c50, c51;
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
        __m512 w0 = _mm512_load_ps(b0 + 16 * k), w1 = _mm512_load_ps(b1 + 16 * k), t;
        t = _mm512_set1_ps(a0[k]); c00 = _mm512_fmadd_ps(t, w0, c00); c01 = _mm512_fmadd_ps(t, w1, c01);
        t = _mm512_set1_ps(a1[k]); c10 = _mm512_fmadd_ps(t, w0, c10); c11 = _mm512_fmadd_ps(t, w1, c11);
        t = _mm512_set1_ps(a2[k]); c20 = _mm512_fmadd_ps(t, w0, c20); c21 = _mm512_fmadd_ps(t, w1, c21);
        t = _mm512_set1_ps(a3[k]); c30 = _mm512_fmadd_ps(t, w0, c30); c31 = _mm512_fmadd_ps(t, w1, c31);
        t = _mm512_set1_ps(a4[k]); c40 = _mm512_fmadd_ps(t, w0, c40); c41 = _mm512_fmadd_ps(t, w1, c41);
        t = _mm512_set1_ps(a5[k]); c50 = _mm512_fmadd_ps(t, w0, c50); c51 = _mm512_fmadd_ps(t, w1, c51);
    }
    _mm512_store_ps(c + 0, c00);   _mm512_store_ps(c + 16, c10);  _mm512_store_ps(c + 32, c20);
    _mm512_store_ps(c + 48, c30);  _mm512_store_ps(c + 64, c40);  _mm512_store_ps(c + 80, c50);
    _mm512_store_ps(c + 96, c01);  _mm512_store_ps(c + 112, c11); _mm512_store_ps(c + 128, c21);
    _mm512_store_ps(c + 144, c31); _mm512_store_ps(c + 160, c41); _mm512_store_ps(c + 176, c51);
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
