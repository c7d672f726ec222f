/* ctx.c - the kernel context: ISA selection, scratch arenas, error messages. */
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "fk_internal.h"
#include "pool.h"

#if defined(__aarch64__)
#include <sys/auxv.h>
#ifndef HWCAP_ASIMD
#define HWCAP_ASIMD (1 << 1)
#endif
#ifndef HWCAP_ASIMDDP
#define HWCAP_ASIMDDP (1 << 20)
#endif
#endif

#if defined(__x86_64__) || defined(__i386__)
#include <cpuid.h>

static unsigned long long xgetbv0(void)
{
    unsigned int lo, hi;
    __asm__ volatile("xgetbv" : "=a"(lo), "=d"(hi) : "c"(0));
    return ((unsigned long long)hi << 32) | lo;
}

static unsigned detect_x86(void)
{
    unsigned a, b, c, d, f = 0;
    if (!__get_cpuid(1, &a, &b, &c, &d))
        return 0;
    int osxsave = (c >> 27) & 1, avx = (c >> 28) & 1;
    int fma = (c >> 12) & 1, f16c = (c >> 29) & 1;
    /* The OS must save the YMM state, or AVX instructions fault. */
    if (!osxsave || !avx || (xgetbv0() & 6) != 6)
        return 0;
    if (fma)  f |= FK_CPU_FMA;
    if (f16c) f |= FK_CPU_F16C;
    if (__get_cpuid_max(0, NULL) >= 7) {
        __cpuid_count(7, 0, a, b, c, d);
        if ((b >> 5) & 1) f |= FK_CPU_AVX2;
        __cpuid_count(7, 1, a, b, c, d);
        if ((a >> 4) & 1) f |= FK_CPU_AVX_VNNI;
    }
    return f;
}
#endif

unsigned fk_cpu_features(void)
{
#if defined(__x86_64__) || defined(__i386__)
    return detect_x86();
#elif defined(__aarch64__)
    /* AdvSIMD is architectural on AArch64 Linux; the dot product is optional */
    unsigned long hw = getauxval(AT_HWCAP);
    unsigned f = FK_CPU_NEON;
    if (hw & HWCAP_ASIMDDP)
        f |= FK_CPU_ASIMDDP;
    return f;
#else
    return 0;
#endif
}

int fk_isa_supported(enum fk_isa isa)
{
    unsigned f = fk_cpu_features();
    unsigned avx2 = FK_CPU_AVX2 | FK_CPU_FMA | FK_CPU_F16C;
    switch (isa) {
    case FK_ISA_REF:       return 1;
    case FK_ISA_AVX2:      return (f & avx2) == avx2;
    case FK_ISA_AVX2_VNNI: return (f & (avx2 | FK_CPU_AVX_VNNI)) == (avx2 | FK_CPU_AVX_VNNI);
    /* NEON kernels exist for AArch64 only (the int8 GEMM picks sdot or its
     * widening fallback from FK_CPU_ASIMDDP per call) */
    case FK_ISA_NEON:
#if defined(__aarch64__)
        return (f & FK_CPU_NEON) != 0;
#else
        return 0;
#endif
    default:               return 0;
    }
}

/* ggml-style score: the best ISA this CPU can run. */
static enum fk_isa best_isa(void)
{
    static const enum fk_isa order[] = { FK_ISA_AVX2_VNNI, FK_ISA_AVX2, FK_ISA_NEON };
    for (size_t i = 0; i < sizeof order / sizeof order[0]; i++)
        if (fk_isa_supported(order[i]))
            return order[i];
    return FK_ISA_REF;
}

static const char *const isa_names[] = { "auto", "ref", "avx2", "avx2-vnni", "neon" };

const char *fk_isa_name(enum fk_isa isa)
{
    if ((unsigned)isa < sizeof isa_names / sizeof isa_names[0])
        return isa_names[isa];
    return "unknown";
}

enum fk_isa fk_isa_from_name(const char *name)
{
    for (size_t i = 0; name && i < sizeof isa_names / sizeof isa_names[0]; i++)
        if (strcmp(name, isa_names[i]) == 0)
            return (enum fk_isa)i;
    return (enum fk_isa)-1;
}

int fk__fail(fk_ctx *ctx, int status, const char *func, const char *fmt, ...)
{
    if (!ctx)
        return status;
    va_list ap;
    int n = snprintf(ctx->err.msg, sizeof ctx->err.msg, "%s: ", func);
    if (n < 0 || (size_t)n >= sizeof ctx->err.msg)
        n = 0;
    va_start(ap, fmt);
    vsnprintf(ctx->err.msg + n, sizeof ctx->err.msg - (size_t)n, fmt, ap);
    va_end(ap);
    ctx->err.code = status;
    return status;
}

void *fk__alloc(size_t bytes)
{
    void *p = NULL;
    if (posix_memalign(&p, FK_ALIGN, fk__round_up(bytes ? bytes : 1, FK_ALIGN)) != 0)
        return NULL;
    return p;
}

static int arena_grow(fk_ctx *ctx, struct fk_arena *a, size_t bytes)
{
    if (a->bytes >= bytes)
        return F4D_OK;
    if (ctx->frozen)
        return fk__fail(ctx, F4D_ENOMEM, "fk_scratch",
                        "context is frozen and %zu scratch bytes are needed (%zu reserved)",
                        bytes, a->bytes);
    void *p = fk__alloc(bytes);
    if (!p)
        return fk__fail(ctx, F4D_ENOMEM, "fk_scratch", "cannot allocate %zu bytes", bytes);
    free(a->ptr);
    a->ptr = p;
    a->bytes = fk__round_up(bytes, FK_ALIGN);
    return F4D_OK;
}

int fk__scratch_reserve(fk_ctx *ctx, size_t per_thread, size_t shared)
{
    for (int t = 0; t < ctx->threads; t++) {
        int st = arena_grow(ctx, &ctx->local[t], per_thread);
        if (st != F4D_OK)
            return st;
    }
    return arena_grow(ctx, &ctx->shared, shared);
}

int fk_ctx_reserve(fk_ctx *ctx, size_t per_thread, size_t shared)
{
    FK_CHECK_CTX(ctx);
    return fk__scratch_reserve(ctx, per_thread, shared);
}

void fk_ctx_freeze(fk_ctx *ctx, int frozen)
{
    if (ctx)
        ctx->frozen = frozen != 0;
}

void fk_ctx_measure(fk_ctx *ctx, int on)
{
    if (ctx)
        ctx->measuring = on != 0;
}

size_t fk_ctx_scratch_bytes(const fk_ctx *ctx)
{
    size_t s = ctx->shared.bytes;
    for (int t = 0; t < ctx->threads; t++)
        s += ctx->local[t].bytes;
    return s;
}

int fk_ctx_new(const struct fk_ctx_config *cfg, fk_ctx **out)
{
    if (!out)
        return F4D_EINVAL;
    *out = NULL;
    struct fk_ctx_config def = { FK_ISA_AUTO, 0 };
    if (!cfg)
        cfg = &def;
    enum fk_isa isa = cfg->isa == FK_ISA_AUTO ? best_isa() : cfg->isa;
    if (!fk_isa_supported(isa))
        return F4D_ENOTSUP;
    int threads = cfg->threads;
    if (threads <= 0) {
        long n = sysconf(_SC_NPROCESSORS_ONLN);
        threads = n > 0 ? (int)n : 1;
    }
    if (threads > 256)
        return F4D_EINVAL;

    fk_ctx *ctx = calloc(1, sizeof *ctx);
    if (!ctx)
        return F4D_ENOMEM;
    ctx->isa = isa;
    ctx->threads = threads;
    ctx->local = calloc((size_t)threads, sizeof *ctx->local);
    if (!ctx->local) {
        free(ctx);
        return F4D_ENOMEM;
    }
    if (threads > 1) {
        ctx->pool = fk__pool_new(threads);
        if (!ctx->pool) {
            fk_ctx_free(ctx);
            return F4D_ENOMEM;
        }
    }
    *out = ctx;
    return F4D_OK;
}

void fk_ctx_free(fk_ctx *ctx)
{
    if (!ctx)
        return;
    fk__pool_free(ctx->pool);
    for (int t = 0; t < ctx->threads; t++)
        free(ctx->local[t].ptr);
    free(ctx->local);
    free(ctx->shared.ptr);
    free(ctx);
}

enum fk_isa fk_ctx_isa(const fk_ctx *ctx) { return ctx->isa; }
int fk_ctx_threads(const fk_ctx *ctx) { return ctx->threads; }
const char *fk_ctx_error(const fk_ctx *ctx) { return ctx ? ctx->err.msg : "no context"; }

int fk_ctx_status(const fk_ctx *ctx) { return ctx ? ctx->err.code : F4D_EINVAL; }

void fk_parallel_for(fk_ctx *ctx, int n_tasks, double work, fk_task_fn fn, void *arg)
{
    if (n_tasks <= 0)
        return;
    if (!ctx->pool || n_tasks == 1 || work < FK_PARALLEL_MIN_WORK) {
        for (int t = 0; t < n_tasks; t++)
            fn(arg, t, 0);
        return;
    }
    fk__pool_run(ctx->pool, n_tasks, fn, arg);
}
