/* gemm_dot.c - the int8 micro-kernel with the ARMv8.2 dot product (sdot),
 * built with -march=armv8.2-a+dotprod and called only where the kernel
 * reports HWCAP_ASIMDDP (Cortex-A76/A78 and later). Signed activations times
 * signed weights, four products summed straight into each int32 lane: exact,
 * no intermediate saturation, and no +128 offset to take back out. */
#include <arm_neon.h>

#include "../gemm.h"

/* c[6][16] = sum over k4 of a[k4][6][4] * b[k4][16][4]: 24 accumulators,
 * the four 16-byte weight vectors and the six rows' codes in two registers
 * (rows 0-3 as lanes of one, rows 4-5 of another). */
void fk__gemm_q8_ukr_sdot(int k4, const int8_t *a, const int8_t *b, int32_t *c)
{
    int32x4_t c00 = vdupq_n_s32(0), c01 = c00, c02 = c00, c03 = c00;
    int32x4_t c10 = c00, c11 = c00, c12 = c00, c13 = c00;
    int32x4_t c20 = c00, c21 = c00, c22 = c00, c23 = c00;
    int32x4_t c30 = c00, c31 = c00, c32 = c00, c33 = c00;
    int32x4_t c40 = c00, c41 = c00, c42 = c00, c43 = c00;
    int32x4_t c50 = c00, c51 = c00, c52 = c00, c53 = c00;
    for (int k = 0; k < k4; k++) {
        int8x16_t b0 = vld1q_s8(b), b1 = vld1q_s8(b + 16), b2 = vld1q_s8(b + 32), b3 = vld1q_s8(b + 48);
        int8x16_t a03 = vld1q_s8(a);
        int8x8_t a45 = vld1_s8(a + 16);
#define ROWQ(r, l)                                                            \
    c##r##0 = vdotq_laneq_s32(c##r##0, b0, a03, l);                           \
    c##r##1 = vdotq_laneq_s32(c##r##1, b1, a03, l);                           \
    c##r##2 = vdotq_laneq_s32(c##r##2, b2, a03, l);                           \
    c##r##3 = vdotq_laneq_s32(c##r##3, b3, a03, l);
#define ROWD(r, l)                                                            \
    c##r##0 = vdotq_lane_s32(c##r##0, b0, a45, l);                            \
    c##r##1 = vdotq_lane_s32(c##r##1, b1, a45, l);                            \
    c##r##2 = vdotq_lane_s32(c##r##2, b2, a45, l);                            \
    c##r##3 = vdotq_lane_s32(c##r##3, b3, a45, l);
        ROWQ(0, 0) ROWQ(1, 1) ROWQ(2, 2) ROWQ(3, 3) ROWD(4, 0) ROWD(5, 1)
#undef ROWQ
#undef ROWD
        a += 24;
        b += 64;
    }
#define STORE(r)                                                              \
    vst1q_s32(c + 16 * r, c##r##0); vst1q_s32(c + 16 * r + 4, c##r##1);        \
    vst1q_s32(c + 16 * r + 8, c##r##2); vst1q_s32(c + 16 * r + 12, c##r##3);
    STORE(0) STORE(1) STORE(2) STORE(3) STORE(4) STORE(5)
#undef STORE
}
