/* arm.h - entry points of the AArch64 NEON kernels (src/arm/), called only
 * when the context runs FK_ISA_NEON. Off AArch64 these are empty stubs and the
 * dispatchers' NEON branches compile away (fk__isa_neon() is 0 there). */
#ifndef FK_ARM_H
#define FK_ARM_H

#include <stddef.h>
#include <stdint.h>

#if defined(__aarch64__)

/* gemm_neon.c: the 6x16 fp32 register tile, c[6][ldc] (+)= a[kc][6] b[kc][16],
 * shared by the GEMM and attention. */
void fk__ukr_f32_6x16_neon(int kc, const float *a, const float *b, float *c, int ldc,
                           int accumulate);

/* ops_neon.c: element-wise and row-wise ops (fk_ops.h). Rows are [rows][ld]. */
void fk__gelu_array_neon     (const float *x, float *y, size_t n);
void fk__silu_array_neon     (const float *x, float *y, size_t n);
void fk__relu_array_neon     (const float *x, float *y, size_t n);
void fk__layernorm_rows_neon (const float *x, int rows, int cols, int ldx, const float *w,
                              const float *b, float eps, float *y, int ldy);
void fk__softmax_rows_neon   (const float *x, int rows, int cols, int ldx, float *y, int ldy);
void fk__residual_rows_neon  (float *x, int ldx, const float *r, int ldr, const float *gamma,
                              int rows, int cols);

/* fp16_neon.c: bulk conversion (fk_fp16.h), bit-exact with the reference. */
void fk__f32_to_f16_neon(const float *src, uint16_t *dst, size_t n);
void fk__f16_to_f32_neon(const uint16_t *src, float *dst, size_t n);

#else
static inline void fk__gelu_array_neon(const float *x, float *y, size_t n) { (void)x; (void)y; (void)n; }
static inline void fk__silu_array_neon(const float *x, float *y, size_t n) { (void)x; (void)y; (void)n; }
static inline void fk__relu_array_neon(const float *x, float *y, size_t n) { (void)x; (void)y; (void)n; }
static inline void fk__layernorm_rows_neon(const float *x, int rows, int cols, int ldx, const float *w,
                                           const float *b, float eps, float *y, int ldy)
{ (void)x; (void)rows; (void)cols; (void)ldx; (void)w; (void)b; (void)eps; (void)y; (void)ldy; }
static inline void fk__softmax_rows_neon(const float *x, int rows, int cols, int ldx, float *y, int ldy)
{ (void)x; (void)rows; (void)cols; (void)ldx; (void)y; (void)ldy; }
static inline void fk__residual_rows_neon(float *x, int ldx, const float *r, int ldr, const float *gamma,
                                          int rows, int cols)
{ (void)x; (void)ldx; (void)r; (void)ldr; (void)gamma; (void)rows; (void)cols; }
static inline void fk__f32_to_f16_neon(const float *src, uint16_t *dst, size_t n) { (void)src; (void)dst; (void)n; }
static inline void fk__f16_to_f32_neon(const uint16_t *src, float *dst, size_t n) { (void)src; (void)dst; (void)n; }
#endif

#endif
