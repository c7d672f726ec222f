/* x86.h - entry points of the AVX2 / FMA / F16C (and AVX-VNNI) kernels.
 * Each lives in a translation unit compiled with the matching -m flags and is
 * called only after fk_ctx chose that ISA from cpuid. On other architectures
 * these names do not exist; the dispatchers' x86 branches compile away. */
#ifndef FK_X86_H
#define FK_X86_H

#include <stddef.h>
#include <stdint.h>

#if defined(__x86_64__)
#define FK_HAVE_X86 1

void fk__f32_to_f16_avx2(const float *src, uint16_t *dst, size_t n);
void fk__f16_to_f32_avx2(const uint16_t *src, float *dst, size_t n);

/* gemm_avx2.c: the 6x16 fp32 register tile, c[6][ldc] (+)= a[kc][6] b[kc][16],
 * shared by the GEMM and attention (c 32-byte aligned, ldc a multiple of 8). */
void fk__ukr_f32_6x16(int kc, const float *a, const float *b, float *c, int ldc, int accumulate);

/* ops_avx2.c: element-wise and row-wise ops (fk_ops.h). Rows are [rows][ld]. */
void fk__gelu_array_avx2     (const float *x, float *y, size_t n);
void fk__silu_array_avx2     (const float *x, float *y, size_t n);
void fk__relu_array_avx2     (const float *x, float *y, size_t n);
void fk__layernorm_rows_avx2 (const float *x, int rows, int cols, int ldx, const float *w,
                              const float *b, float eps, float *y, int ldy);
void fk__softmax_rows_avx2   (const float *x, int rows, int cols, int ldx, float *y, int ldy);
void fk__residual_rows_avx2  (float *x, int ldx, const float *r, int ldr, const float *gamma,
                              int rows, int cols);

/* resize_avx2.c: one output row of the resamplers (fk_resize.h), vectorized
 * over channels; the index and weight tables come from resize.c. */
void fk__bilinear_row_avx2   (const float *r0, const float *r1, float wy0, float wy1,
                              const int32_t *xi, const float *xw, int wo, int c, float *out);
void fk__aa_hrow_avx2        (const float *in, int c, const int32_t *first, const int32_t *count,
                              const float *wts, int ksize, int wo, float *out);
void fk__aa_vrow_avx2        (const float *in, size_t row_len, int count, const float *wts,
                              float *out);

#else
#define FK_HAVE_X86 0
static inline void fk__f32_to_f16_avx2(const float *s, uint16_t *d, size_t n) { (void)s; (void)d; (void)n; }
static inline void fk__f16_to_f32_avx2(const uint16_t *s, float *d, size_t n) { (void)s; (void)d; (void)n; }
static inline void fk__gelu_array_avx2(const float *x, float *y, size_t n) { (void)x; (void)y; (void)n; }
static inline void fk__silu_array_avx2(const float *x, float *y, size_t n) { (void)x; (void)y; (void)n; }
static inline void fk__relu_array_avx2(const float *x, float *y, size_t n) { (void)x; (void)y; (void)n; }
static inline void fk__layernorm_rows_avx2(const float *x, int rows, int cols, int ldx, const float *w,
                                           const float *b, float eps, float *y, int ldy)
{ (void)x; (void)rows; (void)cols; (void)ldx; (void)w; (void)b; (void)eps; (void)y; (void)ldy; }
static inline void fk__softmax_rows_avx2(const float *x, int rows, int cols, int ldx, float *y, int ldy)
{ (void)x; (void)rows; (void)cols; (void)ldx; (void)y; (void)ldy; }
static inline void fk__residual_rows_avx2(float *x, int ldx, const float *r, int ldr, const float *gamma,
                                          int rows, int cols)
{ (void)x; (void)ldx; (void)r; (void)ldr; (void)gamma; (void)rows; (void)cols; }
static inline void fk__bilinear_row_avx2(const float *r0, const float *r1, float wy0, float wy1,
                                         const int32_t *xi, const float *xw, int wo, int c, float *out)
{ (void)r0; (void)r1; (void)wy0; (void)wy1; (void)xi; (void)xw; (void)wo; (void)c; (void)out; }
static inline void fk__aa_hrow_avx2(const float *in, int c, const int32_t *first, const int32_t *count,
                                    const float *wts, int ksize, int wo, float *out)
{ (void)in; (void)c; (void)first; (void)count; (void)wts; (void)ksize; (void)wo; (void)out; }
static inline void fk__aa_vrow_avx2(const float *in, size_t row_len, int count, const float *wts,
                                    float *out)
{ (void)in; (void)row_len; (void)count; (void)wts; (void)out; }
#endif

#endif
