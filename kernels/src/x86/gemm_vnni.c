/* gemm_vnni.c - the int8 micro-kernel for CPUs with AVX-VNNI (VEX vpdpbusd):
 * unsigned activations (code + 128) times signed weights, four products
 * summed straight into each int32 lane with no intermediate saturation. The
 * +128 is taken back out with the per-channel sums stored at packing. */
#include <immintrin.h>
#include <string.h>

#include "../gemm.h"

static inline int load_i32(const uint8_t *p)
{
    int v;
    memcpy(&v, p, sizeof v);
    return v;
}

void fk__gemm_q8_ukr_vnni(int k4, const uint8_t *a, const int8_t *b, int32_t *c, int accumulate)
{
    __m256i c00 = _mm256_setzero_si256(), c01 = c00, c10 = c00, c11 = c00, c20 = c00, c21 = c00;
    __m256i c30 = c00, c31 = c00, c40 = c00, c41 = c00, c50 = c00, c51 = c00;
    if (accumulate) {
#define LD(i) _mm256_load_si256((const __m256i *)(c + 8 * (i)))
        c00 = LD(0); c01 = LD(1); c10 = LD(2); c11 = LD(3); c20 = LD(4); c21 = LD(5);
        c30 = LD(6); c31 = LD(7); c40 = LD(8); c41 = LD(9); c50 = LD(10); c51 = LD(11);
#undef LD
    }
    for (int k = 0; k < k4; k++) {
        __m256i b0 = _mm256_load_si256((const __m256i *)b);
        __m256i b1 = _mm256_load_si256((const __m256i *)(b + 32));
        __m256i t;
#define ROW(r, lo, hi)                                                        \
    t = _mm256_set1_epi32(load_i32(a + 4 * (r)));                             \
    lo = _mm256_dpbusd_avx_epi32(lo, t, b0);                                  \
    hi = _mm256_dpbusd_avx_epi32(hi, t, b1);
        ROW(0, c00, c01) ROW(1, c10, c11) ROW(2, c20, c21)
        ROW(3, c30, c31) ROW(4, c40, c41) ROW(5, c50, c51)
#undef ROW
        a += 24;
        b += 64;
    }
    _mm256_store_si256((__m256i *)(c + 0), c00);  _mm256_store_si256((__m256i *)(c + 8), c01);
    _mm256_store_si256((__m256i *)(c + 16), c10); _mm256_store_si256((__m256i *)(c + 24), c11);
    _mm256_store_si256((__m256i *)(c + 32), c20); _mm256_store_si256((__m256i *)(c + 40), c21);
    _mm256_store_si256((__m256i *)(c + 48), c30); _mm256_store_si256((__m256i *)(c + 56), c31);
    _mm256_store_si256((__m256i *)(c + 64), c40); _mm256_store_si256((__m256i *)(c + 72), c41);
    _mm256_store_si256((__m256i *)(c + 80), c50); _mm256_store_si256((__m256i *)(c + 88), c51);
}
