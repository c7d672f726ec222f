/* bench_main.c - f4d-bench entry: dispatches to one benchmark per subcommand. */
#include <stdio.h>
#include <string.h>
#include <time.h>

#include "bench.h"

struct subcommand {
    const char *name;
    int (*run)(int argc, char **argv);
    const char *help;
};

static const struct subcommand table[] = {
    { "kernels", bench_kernels, "GEMM f32/f16/int8 and attention vs OpenBLAS and the FMA peak" },
    { "model",   bench_model,   "VGGT forward per stage (tiny) and full size extrapolated, f32/f16/int8" },
    { "render",  bench_render,  "CPU Gaussian rasterizer vs Mesa llvmpipe (EGL) on 100k/300k/1M Gaussians" },
    { "interp",  bench_interp,  "4D interpolation quality/speed vs nearest key frame, and the scene budget" },
    { "stream",  bench_stream,  "Forge4D playback: interpolation per step (100k/300k Gaussians) vs streaming its bytes at the measured bandwidth" },
    { "pairs",   bench_pairs,   "the display's per-key interpolation work (lookup, partners, prepare) per key, with a digest of the steps" },
    { "hal",     bench_hal,     "synchronizer, sim capture and take writer throughput vs raw write()" },
#ifdef F4D_BENCH_TOKENS
    { "tokens",  bench_tokens,  "foreground-only key frames (walk take): time, tokens and error at 2 mask margins vs all patches" },
#endif
#ifdef F4D_BENCH_CODEC
    { "codec",   bench_codec,   "stream codec rate-distortion (intra/predicted keys, motion, Mbit/s, render PSNR) vs SPZ" },
#endif
#ifdef F4D_BENCH_DISPLAY
    { "display", bench_display, "f4d-display's displayed fps at 100k/300k Gaussians (decode + interp + draw), CPU vs GLES" },
#endif
};

double bench_now(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

double bench_thread_cpu_s(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

static void usage(FILE *f)
{
    fprintf(f, "usage: f4d-bench SUBCOMMAND [options] [--json FILE]\n");
    for (size_t i = 0; i < sizeof table / sizeof table[0]; i++)
        fprintf(f, "  %-10s %s\n", table[i].name, table[i].help);
}

int main(int argc, char **argv)
{
    if (argc < 2 || !strcmp(argv[1], "-h") || !strcmp(argv[1], "--help")) {
        usage(argc < 2 ? stderr : stdout);
        return argc < 2 ? 2 : 0;
    }
    for (size_t i = 0; i < sizeof table / sizeof table[0]; i++)
        if (!strcmp(argv[1], table[i].name))
            return table[i].run(argc - 1, argv + 1);
    fprintf(stderr, "f4d-bench: unknown subcommand '%s'\n", argv[1]);
    usage(stderr);
    return 2;
}
