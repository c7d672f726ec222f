/* bench_kernels.c - f4d-bench kernels: speed vs error of the numeric kernels on
 * the model's shapes, beside OpenBLAS sgemm and the measured FMA peak. */
#include <stdio.h>
#include <string.h>

#include "bench.h"
#include "peak.h"

int bench_kernels(int argc, char **argv)
{
    (void)argc; (void)argv;
    double p1 = bench_fma_peak_gflops(1, 3), p2 = bench_fma_peak_gflops(2, 3);
    printf("fp32 FMA peak: %.1f GFLOP/s (1 thread), %.1f GFLOP/s (2 threads)\n", p1, p2);
    return 0;
}
