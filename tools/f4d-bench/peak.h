/* peak.h - measured machine peaks that benchmarks quote ratios against. */
#ifndef F4D_BENCH_PEAK_H
#define F4D_BENCH_PEAK_H
#include "fk_ctx.h"
/* Best of `repeats` runs of independent fp32 FMA chains (ymm) on `threads`
 * threads: the peak of the AVX2 kernels. */
double bench_fma_peak_gflops(int threads, int repeats);
/* The peak of the vectors `isa`'s GEMM uses: zmm for FK_ISA_AVX512, else as
 * above. */
double bench_fma_peak_gflops_isa(int threads, int repeats, enum fk_isa isa);

/* Ceilings of the integer and bf16 paths on this CPU, one thread (best of
 * `repeats`): multiply-adds per second of each path's instructions over
 * fp32 FMA's of the same vector width (ymm for the AVX2 ones, zmm for the
 * AVX-512 ones); NAN where the CPU lacks the path (fk_cpu_features bits). */
struct int_ceilings {
    double s7_avx2;     /* vpmaddubsw + vpmaddwd + vpaddd: the 7-bit GEMM      */
    double i16_avx2;    /* vpmaddwd + vpaddd: int16 attention on AVX2          */
    double vnni_avx512; /* vpdpbusd zmm: the AVX-512 int8 GEMM                 */
    double bf16_avx512; /* vdpbf16ps zmm: bf16 attention                       */
};
struct int_ceilings bench_int_ceilings(unsigned cpu_features, int repeats);
/* One line on stdout (nothing where the CPU has none of these paths). */
void bench_print_int_ceilings(struct int_ceilings c);
#endif
