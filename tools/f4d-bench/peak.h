/* peak.h - measured machine peaks that benchmarks quote ratios against. */
#ifndef F4D_BENCH_PEAK_H
#define F4D_BENCH_PEAK_H
/* Best of `repeats` runs of independent FMA chains on `threads` threads. */
double bench_fma_peak_gflops(int threads, int repeats);
#endif
