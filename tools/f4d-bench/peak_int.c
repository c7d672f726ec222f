/* peak_int.c - what the integer and bf16 paths' multiply-add instructions
 * can do on this CPU: multiply-adds per second over fp32 FMA's of the same
 * vector width, one thread, the ceiling of each int8 / int16 / bf16 ratio
 * the benchmarks print. Each loop is 12 independent steps (10 for the
 * 7-bit triple) on fixed registers, written in asm: compiled from
 * intrinsics, GCC 12 spilled the accumulators of the integer loops to the
 * stack (an add from memory per step), which read the int16 pair at 0.99x
 * fp32 where it does 1.5-1.6x. Zen 4, AVX2 code: the 7-bit GEMM's
 * vpmaddubsw + vpmaddwd + vpaddd reach 1.90-2.03x the ymm FMA's
 * multiply-adds and the int16 attention's vpmaddwd + vpaddd 1.50-1.66x, not
 * the 4x and 2x that the lane counts suggest. */
#include <math.h>
#include <stdio.h>

#include "bench.h"
#include "peak.h"

#if defined(__x86_64__)

#define ITERS 8000000L /* 20-40 ms a loop */

/* 12 steps on accumulators 3-14 (ymm or zmm), operands in registers 0 and 1
 * (2: the 7-bit triple's ones), 15 the product */
#define R12(S) S(3) S(4) S(5) S(6) S(7) S(8) S(9) S(10) S(11) S(12) S(13) S(14)
#define R10(S) S(3) S(4) S(5) S(6) S(7) S(8) S(9) S(10) S(11) S(12)
#define LOOP(body)                                                                   \
    "mov %0, %%rcx\n\t"                                                              \
    "1:\n\t" body "dec %%rcx\n\t"                                                    \
    "jnz 1b\n\t"
/* vector registers 0-15 (xmm names cover the ymm and zmm they extend) */
#define VEC_CLOBBERS                                                                 \
    "rcx", "xmm0", "xmm1", "xmm2", "xmm3", "xmm4", "xmm5", "xmm6", "xmm7", "xmm8",   \
        "xmm9", "xmm10", "xmm11", "xmm12", "xmm13", "xmm14", "xmm15", "cc"

#define FMA_Y(i) "vfmadd231ps %%ymm0, %%ymm1, %%ymm" #i "\n\t"
#define S7_Y(i)                                                                      \
    "vpmaddubsw %%ymm1, %%ymm0, %%ymm15\n\t"                                         \
    "vpmaddwd %%ymm2, %%ymm15, %%ymm15\n\t"                                          \
    "vpaddd %%ymm15, %%ymm" #i ", %%ymm" #i "\n\t"
#define I16_Y(i)                                                                     \
    "vpmaddwd %%ymm1, %%ymm0, %%ymm15\n\t"                                           \
    "vpaddd %%ymm15, %%ymm" #i ", %%ymm" #i "\n\t"
#define FMA_Z(i) "vfmadd231ps %%zmm0, %%zmm1, %%zmm" #i "\n\t"
#define VNNI_Z(i) "vpdpbusd %%zmm1, %%zmm0, %%zmm" #i "\n\t"
#define BF16_Z(i) "vdpbf16ps %%zmm1, %%zmm0, %%zmm" #i "\n\t"

/* Zeroed operands: the units' throughput does not depend on the values
 * (no denormals arise from zeros), and nothing overflows. */
#define ZERO_Y "vpxor %%xmm0, %%xmm0, %%xmm0\n\tvpxor %%xmm1, %%xmm1, %%xmm1\n\tvpxor %%xmm2, %%xmm2, %%xmm2\n\t"
#define ZERO_Z "vpxord %%zmm0, %%zmm0, %%zmm0\n\tvpxord %%zmm1, %%zmm1, %%zmm1\n\t"

/* One timed loop: `name`, compiled for `isa` (the assembler takes the
 * instructions either way; the attribute documents what the CPU needs). */
#define RUN_LOOP(name, isa, zero, steps)                                             \
    __attribute__((target(isa))) static double name(void)                            \
    {                                                                                \
        double t = bench_thread_cpu_s();                                             \
        __asm__ volatile(zero LOOP(steps) : : "r"(ITERS) : VEC_CLOBBERS);            \
        return bench_thread_cpu_s() - t;                                             \
    }

RUN_LOOP(run_fma_ymm, "avx2,fma", ZERO_Y, R12(FMA_Y))
RUN_LOOP(run_s7_ymm, "avx2", ZERO_Y, R10(S7_Y))
RUN_LOOP(run_i16_ymm, "avx2", ZERO_Y, R12(I16_Y))
RUN_LOOP(run_fma_zmm, "avx512f", ZERO_Z, R12(FMA_Z))
RUN_LOOP(run_vnni_zmm, "avx512f,avx512vnni", ZERO_Z, R12(VNNI_Z))
RUN_LOOP(run_bf16_zmm, "avx512f,avx512bf16", ZERO_Z, R12(BF16_Z))

static double shorter(double a, double b) { return b < a ? b : a; }

struct int_ceilings bench_int_ceilings(unsigned cpu_features, int repeats)
{
    struct int_ceilings c = { NAN, NAN, NAN, NAN };
    if (!(cpu_features & FK_CPU_AVX2) || !(cpu_features & FK_CPU_FMA))
        return c;
    int zmm = (cpu_features & FK_CPU_AVX512) != 0; /* F + BW + VL + VNNI, zmm state on */
    int bf16 = zmm && (cpu_features & FK_CPU_AVX512_BF16);
    /* every loop once per round, best of the rounds: a slow phase of a
     * shared machine hits the FMA baseline and the paths alike */
    double fy = INFINITY, s7 = INFINITY, i16 = INFINITY, fz = INFINITY, vn = INFINITY, bf = INFINITY;
    for (int r = 0; r < repeats; r++) {
        fy = shorter(fy, run_fma_ymm());
        s7 = shorter(s7, run_s7_ymm());
        i16 = shorter(i16, run_i16_ymm());
        if (zmm) {
            fz = shorter(fz, run_fma_zmm());
            vn = shorter(vn, run_vnni_zmm());
        }
        if (bf16)
            bf = shorter(bf, run_bf16_zmm());
    }
    /* multiply-adds per step: ymm FMA 8, 7-bit 32 (10 steps a loop, the
     * others 12), int16 16; zmm FMA 16, vpdpbusd 64, vdpbf16ps 32 */
    c.s7_avx2 = (32.0 * 10.0 / 12.0 / s7) / (8.0 / fy);
    c.i16_avx2 = (16.0 / i16) / (8.0 / fy);
    if (zmm)
        c.vnni_avx512 = (64.0 / vn) / (16.0 / fz);
    if (bf16)
        c.bf16_avx512 = (32.0 / bf) / (16.0 / fz);
    return c;
}
#else
struct int_ceilings bench_int_ceilings(unsigned cpu_features, int repeats)
{
    (void)cpu_features;
    (void)repeats;
    return (struct int_ceilings){ NAN, NAN, NAN, NAN };
}
#endif

void bench_print_int_ceilings(struct int_ceilings c)
{
    if (isnan(c.s7_avx2))
        return;
    printf("multiply-add ceilings over fp32 FMA (1 thread, same width): 7-bit u8s8 (avx2) %.2fx, "
           "int16 pairs (avx2) %.2fx", c.s7_avx2, c.i16_avx2);
    if (!isnan(c.vnni_avx512))
        printf(", vpdpbusd zmm %.2fx", c.vnni_avx512);
    if (!isnan(c.bf16_avx512))
        printf(", vdpbf16ps zmm %.2fx", c.bf16_avx512);
    printf("\n");
}
