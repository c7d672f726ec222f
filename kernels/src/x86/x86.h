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

#else
#define FK_HAVE_X86 0
static inline void fk__f32_to_f16_avx2(const float *s, uint16_t *d, size_t n) { (void)s; (void)d; (void)n; }
static inline void fk__f16_to_f32_avx2(const uint16_t *s, float *d, size_t n) { (void)s; (void)d; (void)n; }
#endif

#endif
