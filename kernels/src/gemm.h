/* gemm.h - the blocked GEMM driver shared by fk_linear and fk_conv.
 *
 * The driver computes y = epilogue(A W^T + b) where the rows of A come from an
 * fk__asrc (a dense matrix, or an im2col view of an HWC image) and the rows of
 * y go to an fk__cdst (a dense matrix, or the scatter of a stride == kernel
 * transposed convolution). Packed layouts for the optimized ISAs:
 *   f32  [n_pad/16][k][16]              panels of 16 output channels
 *   f16  [n_pad/16][k][16] (fp16 bits)  widened per cache block
 *   q8   [n_pad/16][k_pad/4][16][4]     4 consecutive k per 32-bit lane
 * The reference ISA keeps W as given: [n][k]. NEON uses the same packed
 * layouts (sdot multiplies 4 consecutive k of 4 columns per 128-bit lane
 * group, exactly the q8 panel; signed x signed, so no +128 and no colsum). */
#ifndef FK_GEMM_H
#define FK_GEMM_H

#include <math.h>
#include <stdint.h>
#include <string.h>

#include "../fk_linear.h"

#define FK_GEMM_NR 16  /* output channels per packed panel        */
#define FK_GEMM_MR 6   /* rows per register tile                  */
/* Cache blocks (kc, mc, nc) come from the context: fk_gemm_blocks_for(). */
#define FK_Q8_K_MAX 65536

/* Where rows of A come from. */
struct fk__asrc {
    const float *x;    /* dense: x[m * ldx + k]; conv: the HWC image       */
    int          ldx;
    int          conv; /* nonzero: im2col view below                       */
    int          h, w, cin, kh, kw, stride, pad, wo;
};

/* Where rows of y go. */
struct fk__cdst {
    float       *y;    /* dense: y[m * ldy + n]; tconv: the HWC output     */
    int          ldy;
    int          tconv_k; /* nonzero: (m = i*w + j, n = (a*k + b)*cout + o)
                           * goes to y[((k*i + a) * k*w + k*j + b) * cout + o] */
    int          tconv_cout, tconv_w;
};

/* Copies columns [k0, k0 + kn) of row m of A into dst (zero padding outside
 * the image for conv). */
void fk__asrc_row(const struct fk__asrc *a, int m, int k0, int kn, float *dst);

#if defined(__x86_64__)
int  fk__gemm_avx2(fk_ctx *ctx, const struct fk_linear *L, const struct fk__asrc *a,
                   int m, const struct fk__cdst *c, const struct fk_epilogue *ep);
#else /* never called: fk__isa_avx2() is 0 off x86-64 */
static inline int fk__gemm_avx2(fk_ctx *ctx, const struct fk_linear *L, const struct fk__asrc *a,
                                int m, const struct fk__cdst *c, const struct fk_epilogue *ep)
{
    (void)ctx; (void)L; (void)a; (void)m; (void)c; (void)ep;
    return F4D_ENOTSUP;
}
#endif
#if defined(__aarch64__)
int  fk__gemm_neon(fk_ctx *ctx, const struct fk_linear *L, const struct fk__asrc *a,
                   int m, const struct fk__cdst *c, const struct fk_epilogue *ep);
/* int8 micro-kernel with the ARMv8.2 dot product (src/arm/gemm_dot.c, built
 * with +dotprod, called only where HWCAP_ASIMDDP): c[6][16] = sum over k4 of
 * a[k4][6][4] (s8) * b[k4][16][4] (s8). */
void fk__gemm_q8_ukr_sdot(int k4, const int8_t *a, const int8_t *b, int32_t *c);
#else /* never called: fk__isa_neon() is 0 off AArch64 */
static inline int fk__gemm_neon(fk_ctx *ctx, const struct fk_linear *L, const struct fk__asrc *a,
                                int m, const struct fk__cdst *c, const struct fk_epilogue *ep)
{
    (void)ctx; (void)L; (void)a; (void)m; (void)c; (void)ep;
    return F4D_ENOTSUP;
}
#endif
/* Validates the epilogue and the packing ISA, then runs the ISA's driver. */
int  fk__gemm_run (fk_ctx *ctx, const struct fk_linear *L, const struct fk__asrc *a,
                   int m, const struct fk__cdst *c, const struct fk_epilogue *ep);
int  fk__gemm_ref (fk_ctx *ctx, const struct fk_linear *L, const struct fk__asrc *a,
                   int m, const struct fk__cdst *c, const struct fk_epilogue *ep);

/* int8 micro-kernel with AVX-VNNI: c[6][16] (+)= sum over k4 of u8 a * s8 b. */
void fk__gemm_q8_ukr_vnni(int k4, const uint8_t *a, const int8_t *b, int32_t *c, int accumulate);


/* AVX-512 micro-kernels: two adjacent 16-wide panels at once, a 6x32 tile
 * in 12 zmm registers; c is the two 6x16 tiles [2][6][16] (64-byte aligned).
 * fp32: c (+)= a[kc][6] * (b0 | b1)[kc][16]; int8: u8 a x s8 b with vpdpbusd. */
void fk__gemm_f32_ukr_avx512(int kc, const float *a, const float *b0, const float *b1, float *c,
                             int accumulate);
/* fp32, rows of A read in place: ntaps taps of cin k-steps, rows of tap t at
 * a[6 t + r] (a stride-1 convolution's whole k, or ntaps 1 for one k
 * block): c[2][6][16] (+)= the rows * (b0 | b1); b1 NULL: one panel,
 * c[6][16]. */
void fk__gemm_f32_ukr_avx512_taps(int ntaps, int cin, const float *const *a, const float *b0,
                                  const float *b1, float *c, int accumulate);
/* fp32, one panel: c[6][16] (+)= a * b[ntaps kc][16], ntaps taps of kc
 * k-steps, row r of tap t at a[6 t + r][k * step]. */
void fk__gemm_f32_ukr_avx512_6x16(int ntaps, int kc, const float *const *a, int step, const float *b,
                                  float *c, int accumulate);
/* int8, one panel: c[6][16] (+)= u8 a[k4][6][4] * s8 b[k4][16][4]. */
void fk__gemm_q8_ukr_avx512_6x16(int k4, const uint8_t *a, const int8_t *b, int32_t *c, int accumulate);
/* PREFETCHW on `rows` rows of `cols` floats at y (row stride ldy): the
 * AVX-512 driver's output rows, claimed for writing while the last k block
 * of their tile runs. PRFCHW is on every AVX-512 CPU (Intel since Broadwell,
 * AMD since K8 as 3DNowPrefetch), hence in this file's flags. */
void fk__gemm_prefetchw_rows(const float *y, size_t ldy, int rows, int cols);
void fk__gemm_q8_ukr_avx512(int k4, const uint8_t *a, const int8_t *b0, const int8_t *b1,
                            int32_t *c, int accumulate);
/* A run of a row of A: n floats at p, or n zeros (p NULL); a convolution's
 * im2col row is at most a few runs (gemm_avx2.c, row_runs). */
struct fk__arun {
    const float *p;
    int          n;
};
/* An int8 activation row's scale from the bits of its largest |x| (the
 * integer max of |x| as bits: Inf / NaN sort above every finite value), and
 * 127 / amax into *inv (0 when the row's codes are all zero: amax under
 * FK_Q8_AMAX_MIN, scale 0; or Inf / NaN in the row, scale NaN), as
 * fk_quantize_row_q8. Shared by the AVX2 and AVX-512 row quantizers. */
static inline float fk__q8_row_scale(uint32_t absmax_bits, float *inv)
{
    float am;
    memcpy(&am, &absmax_bits, sizeof am);
    if (absmax_bits >= 0x7f800000u || am < FK_Q8_AMAX_MIN) {
        *inv = 0;
        return absmax_bits >= 0x7f800000u ? NAN : 0.0f;
    }
    *inv = 127.0f / am;
    return am / 127.0f;
}
/* AVX-512 int8 quantization of `rows` <= 6 rows of A given as runs (row j:
 * r[j][0 .. nr[j]), k values in all), bit for bit the reference's codes and
 * scales: codes into q + j ldq, [0, k_pad) (zeros past k), scale into sa[j]
 * (0 for an all-zero row, NaN with zero codes when the row holds Inf or NaN). */
void fk__q8_quantize_rows_avx512(const struct fk__arun *const r[], const int nr[], int rows, int k,
                                 int k_pad, int8_t *q, size_t ldq, float *sa);
/* AVX-512 int8 epilogue of one 6-row tile of one or two adjacent panels
 * (ci: [np][6][16] int32) into nn <= 16 np dense columns at y (row stride
 * ldy): (acc - colsum) as fp32 times (sa[r] scale[n]) plus bias[n] (one
 * FMA, as the AVX2 epilogue), activation, LayerScale, residual; the same
 * operations per element as epi_q8, so the same bits. colsum NULL: none. */
void fk__epi_q8_avx512(const int32_t *ci, const float *sa, int nr, int nn, const float *bias,
                       const float *scale, const int32_t *colsum, const struct fk_epilogue *ep,
                       const float *gamma, float *y, size_t ldy);
/* The fp32 epilogue of the same tile shape (ci: [np][6][16] fp32 sums):
 * + bias, activation, LayerScale, residual, as the AVX2 epilogue (same
 * bits); bias padded to whole panels at packing. */
void fk__epi_f32_avx512(const float *ci, int nr, int nn, const float *bias,
                        const struct fk_epilogue *ep, const float *gamma, float *y, size_t ldy);
/* n fp16 weights (a multiple of 16, h 32-byte and d 64-byte aligned) widened
 * to fp32 16 at a time: the AVX-512 driver's per-sliver conversion. */
void fk__f16_to_f32_avx512(const uint16_t *h, float *d, int n);

/* Job planning shared by the ISA drivers (gemm_plan.c, plain C). */
/* The row block for `threads` > 1: mc (a multiple of FK_GEMM_MR) shrunk so
 * that the padded rows make about 4 blocks per thread, but not below min_mc
 * where there are that many rows; then at most the padded rows. */
int  fk__gemm_plan_mc(int threads, int m, int mc, int min_mc);
/* Splits the `panels` 16-wide panels into chunks when the m blocks alone are
 * too few tasks for the threads (about 4 tasks per thread, at least 4 panels
 * per chunk): *n_chunks chunks of *panels_per_chunk panels (the last one may
 * be short). */
void fk__gemm_plan_chunks(int threads, int m_blocks, int panels, int *n_chunks,
                          int *panels_per_chunk);

/* Address of element (m, n) of the destination. */
float *fk__cdst_ptr(const struct fk__cdst *c, int m, int n);
#endif
