/* peak_fma.c - the machine's fp32 FMA peak, measured: independent FMA chains
 * on every thread, long enough to hide the latency (2 ports x 4 cycles). */
#include <pthread.h>
#include <stdint.h>
#include <unistd.h>

#include "bench.h"
#include "peak.h"

#if defined(__x86_64__)
#include <immintrin.h>

__attribute__((target("avx2,fma")))
static double fma_loop(long iters)
{
    /* distinct starting values, so the compiler cannot merge the chains */
    __m256 a0 = _mm256_set1_ps(1.00f), a1 = _mm256_set1_ps(1.01f), a2 = _mm256_set1_ps(1.02f);
    __m256 a3 = _mm256_set1_ps(1.03f), a4 = _mm256_set1_ps(1.04f), a5 = _mm256_set1_ps(1.05f);
    __m256 a6 = _mm256_set1_ps(1.06f), a7 = _mm256_set1_ps(1.07f), a8 = _mm256_set1_ps(1.08f);
    __m256 a9 = _mm256_set1_ps(1.09f), a10 = _mm256_set1_ps(1.10f), a11 = _mm256_set1_ps(1.11f);
    const __m256 m = _mm256_set1_ps(0.999999f), c = _mm256_set1_ps(1e-7f);
    for (long i = 0; i < iters; i++) {
        a0 = _mm256_fmadd_ps(a0, m, c);   a1 = _mm256_fmadd_ps(a1, m, c);
        a2 = _mm256_fmadd_ps(a2, m, c);   a3 = _mm256_fmadd_ps(a3, m, c);
        a4 = _mm256_fmadd_ps(a4, m, c);   a5 = _mm256_fmadd_ps(a5, m, c);
        a6 = _mm256_fmadd_ps(a6, m, c);   a7 = _mm256_fmadd_ps(a7, m, c);
        a8 = _mm256_fmadd_ps(a8, m, c);   a9 = _mm256_fmadd_ps(a9, m, c);
        a10 = _mm256_fmadd_ps(a10, m, c); a11 = _mm256_fmadd_ps(a11, m, c);
    }
    __m256 s = _mm256_add_ps(_mm256_add_ps(_mm256_add_ps(a0, a1), _mm256_add_ps(a2, a3)),
                             _mm256_add_ps(_mm256_add_ps(a4, a5), _mm256_add_ps(a6, a7)));
    s = _mm256_add_ps(s, _mm256_add_ps(_mm256_add_ps(a8, a9), _mm256_add_ps(a10, a11)));
    float out[8];
    _mm256_storeu_ps(out, s);
    return out[0];
}
#define FLOPS_PER_ITER (12.0 * 8 * 2)

/* The same chains 16 lanes wide: the peak an AVX-512 kernel is held to (a
 * CPU with one 512-bit FMA port gets about the ymm figure, one with two
 * twice it). Called only where the CPU and OS have AVX-512. */
__attribute__((target("avx512f")))
static double fma_loop_zmm(long iters)
{
    __m512 a0 = _mm512_set1_ps(1.00f), a1 = _mm512_set1_ps(1.01f), a2 = _mm512_set1_ps(1.02f);
    __m512 a3 = _mm512_set1_ps(1.03f), a4 = _mm512_set1_ps(1.04f), a5 = _mm512_set1_ps(1.05f);
    __m512 a6 = _mm512_set1_ps(1.06f), a7 = _mm512_set1_ps(1.07f), a8 = _mm512_set1_ps(1.08f);
    __m512 a9 = _mm512_set1_ps(1.09f), a10 = _mm512_set1_ps(1.10f), a11 = _mm512_set1_ps(1.11f);
    const __m512 m = _mm512_set1_ps(0.999999f), c = _mm512_set1_ps(1e-7f);
    for (long i = 0; i < iters; i++) {
        a0 = _mm512_fmadd_ps(a0, m, c);   a1 = _mm512_fmadd_ps(a1, m, c);
        a2 = _mm512_fmadd_ps(a2, m, c);   a3 = _mm512_fmadd_ps(a3, m, c);
        a4 = _mm512_fmadd_ps(a4, m, c);   a5 = _mm512_fmadd_ps(a5, m, c);
        a6 = _mm512_fmadd_ps(a6, m, c);   a7 = _mm512_fmadd_ps(a7, m, c);
        a8 = _mm512_fmadd_ps(a8, m, c);   a9 = _mm512_fmadd_ps(a9, m, c);
        a10 = _mm512_fmadd_ps(a10, m, c); a11 = _mm512_fmadd_ps(a11, m, c);
    }
    __m512 s = _mm512_add_ps(_mm512_add_ps(_mm512_add_ps(a0, a1), _mm512_add_ps(a2, a3)),
                             _mm512_add_ps(_mm512_add_ps(a4, a5), _mm512_add_ps(a6, a7)));
    s = _mm512_add_ps(s, _mm512_add_ps(_mm512_add_ps(a8, a9), _mm512_add_ps(a10, a11)));
    return _mm512_reduce_add_ps(s);
}
#define HAVE_ZMM 1
#else
static double fma_loop(long iters)
{
    float a = 1.0f;
    for (long i = 0; i < iters; i++)
        a = a * 0.999999f + 1e-7f;
    return a;
}
#define FLOPS_PER_ITER 2.0
#endif

struct peak_arg {
    long   iters;
    int    zmm;
    double sink;
    double cpu_s; /* the thread's CPU time for its chains */
};

/* The chains touch no memory, so the compiler may run them before the first
 * clock read (a refactored caller, inlined at -O3, read 0 s: an infinite
 * rate): the empty asm statements pin the loop between the two reads. */
static void *peak_thread(void *v)
{
    struct peak_arg *a = v;
    long iters = a->iters;
    double t0 = bench_thread_cpu_s(), sink;
    __asm__ volatile("" : "+r"(iters) : : "memory");
#ifdef HAVE_ZMM
    if (a->zmm)
        sink = fma_loop_zmm(iters);
    else
#endif
        sink = fma_loop(iters);
    __asm__ volatile("" : "+m"(sink) : : "memory");
    a->sink = sink;
    a->cpu_s = bench_thread_cpu_s() - t0;
    return NULL;
}

double bench_fma_peak_gflops(int threads, int repeats)
{
    return bench_fma_peak_gflops_isa(threads, repeats, FK_ISA_AVX2);
}

/* All threads run their chains at once, each timed on its own CPU clock, and
 * the peak is the sum of their rates. Timed on the wall clock, a 2-thread run
 * whose threads shared one core for a while (another process, a late
 * migration) read as low as the 1-thread rate: 114 of 222 GFLOP/s in 1 run
 * of 4 on Zen 5, best of 3 repeats each. Threads that truly share a core's
 * FMA units (SMT siblings) run concurrently and still read half each. */
double bench_fma_peak_gflops_isa(int threads, int repeats, enum fk_isa isa)
{
#ifdef HAVE_ZMM
    int zmm = isa == FK_ISA_AVX512;
#else
    int zmm = 0;
    (void)isa;
#endif
    double per_iter = FLOPS_PER_ITER * (zmm ? 2 : 1);
    const long iters = 20000000;
    double best = 0;
    if (threads > 64)
        threads = 64;
    for (int r = 0; r < repeats; r++) {
        pthread_t tid[64];
        struct peak_arg args[64];
        for (int t = 0; t < threads; t++)
            args[t] = (struct peak_arg){ .iters = iters, .zmm = zmm };
        int started = 1;
        for (int t = 1; t < threads; t++, started++)
            if (pthread_create(&tid[t], NULL, peak_thread, &args[t]) != 0)
                break;
        peak_thread(&args[0]);
        for (int t = 1; t < started; t++)
            pthread_join(tid[t], NULL);
        double g = 0;
        for (int t = 0; t < started; t++)
            g += per_iter * (double)iters / args[t].cpu_s * 1e-9;
        long cpus = sysconf(_SC_NPROCESSORS_ONLN); /* more threads than CPUs take turns */
        if (cpus > 0 && started > cpus)
            g *= (double)cpus / started;
        if (g > best)
            best = g;
    }
    return best;
}
