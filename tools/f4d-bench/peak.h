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
#endif
