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

/* AuthenticAMD or HygonGenuine (leaf 0's vendor string in b, d, c) */
static int vendor_amd(void)
{
    unsigned a, b, c, d;
    if (!__get_cpuid(0, &a, &b, &c, &d))
        return 0;
    return (b == 0x68747541u && d == 0x69746e65u && c == 0x444d4163u) ||
           (b == 0x6f677948u && d == 0x6e65476eu && c == 0x656e6975u);
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
        /* F (b16), BW (b30), VL (b31), VNNI (c11); opmask and ZMM state saved */
        if (((b >> 16) & 1) && ((b >> 30) & 1) && ((b >> 31) & 1) && ((c >> 11) & 1) &&
            (xgetbv0() & 0xe6) == 0xe6)
            f |= FK_CPU_AVX512;
        __cpuid_count(7, 1, a, b, c, d);
        if ((a >> 4) & 1) f |= FK_CPU_AVX_VNNI;
        if (((a >> 5) & 1) && (f & FK_CPU_AVX512)) f |= FK_CPU_AVX512_BF16;
    }
    if (vendor_amd()) f |= FK_CPU_AMD;
    return f;
}
#endif

/* ------------------------------------------------------------ caches */

#if defined(__x86_64__) || defined(__i386__)
/* Deterministic cache parameters: leaf 4 (Intel) and 0x8000001D (AMD, with
 * topology extensions) share one layout. Sharing counts logical CPUs; the L3
 * share per core is l3 * (CPUs sharing L2) / (CPUs sharing L3). */
static int caches_cpuid(struct fk_cache_info *ci)
{
    unsigned a, b, c, d, leaf = 0;
    if (!__get_cpuid(0, &a, &b, &c, &d))
        return 0;
    unsigned max_std = a;
    int amd = vendor_amd();
    if (amd) {
        unsigned max_ext = __get_cpuid_max(0x80000000u, NULL);
        if (max_ext >= 0x8000001Du && __get_cpuid(0x80000001u, &a, &b, &c, &d) && ((c >> 22) & 1))
            leaf = 0x8000001Du;
    } else if (max_std >= 4) {
        leaf = 4;
    }
    if (!leaf)
        return 0;
    unsigned share1 = 1, share2 = 1, share3 = 1;
    for (unsigned i = 0; i < 16; i++) {
        __cpuid_count(leaf, i, a, b, c, d);
        unsigned type = a & 31, level = (a >> 5) & 7;
        if (type == 0)
            break;
        if (type != 1 && type != 3) /* data or unified */
            continue;
        size_t ways = (b >> 22) + 1, parts = ((b >> 12) & 0x3ff) + 1, line = (b & 0xfff) + 1;
        size_t size = ways * parts * line * ((size_t)c + 1);
        unsigned sharing = ((a >> 14) & 0xfff) + 1;
        if (level == 1) {
            ci->l1d = size;
            ci->l1d_ways = (int)ways;
            share1 = sharing;
        } else if (level == 2) {
            ci->l2 = size;
            ci->l2_ways = (int)ways;
            share2 = sharing;
        } else if (level == 3) {
            ci->l3 = size;
            share3 = sharing;
        }
    }
    /* L1 is per core: CPUs sharing L2 over CPUs sharing L1 = cores on the L2 */
    if (ci->l2 && share2 > share1)
        ci->l2_share = ci->l2 / share2 * share1;
    if (ci->l3)
        ci->l3_share = share3 > share2 ? ci->l3 / share3 * share2 : ci->l3;
    return ci->l1d != 0 && ci->l2 != 0;
}
#endif

/* Parses "48K", "2M", "1.25M", "512" (bytes); 0 when unreadable. */
static size_t parse_size(const char *s, const char **end)
{
    char *e;
    double v = strtod(s, &e);
    if (e == s || v < 0)
        return 0;
    if (*e == 'K' || *e == 'k') { v *= 1024; e++; }
    else if (*e == 'M' || *e == 'm') { v *= 1024 * 1024; e++; }
    else if (*e == 'G' || *e == 'g') { v *= 1024.0 * 1024 * 1024; e++; }
    if (end)
        *end = e;
    return (size_t)v;
}

static int read_line(const char *path, char *buf, size_t n)
{
    FILE *f = fopen(path, "r");
    if (!f)
        return 0;
    int ok = fgets(buf, (int)n, f) != NULL;
    fclose(f);
    if (ok)
        buf[strcspn(buf, "\n")] = 0;
    return ok;
}

/* CPUs named by a list like "0-3,8,10-11". */
static int count_cpus(const char *s)
{
    int n = 0;
    while (*s) {
        char *e;
        long a = strtol(s, &e, 10), b = a;
        if (e == s)
            break;
        if (*e == '-')
            b = strtol(e + 1, &e, 10);
        n += (int)(b - a + 1);
        s = *e == ',' ? e + 1 : e;
    }
    return n > 0 ? n : 1;
}

static int caches_sysfs(struct fk_cache_info *ci)
{
    int share1 = 1, share2 = 1, share3 = 1;
    for (int i = 0; i < 8; i++) {
        char path[96], buf[256];
        snprintf(path, sizeof path, "/sys/devices/system/cpu/cpu0/cache/index%d/level", i);
        if (!read_line(path, buf, sizeof buf))
            break;
        int level = atoi(buf);
        snprintf(path, sizeof path, "/sys/devices/system/cpu/cpu0/cache/index%d/type", i);
        if (!read_line(path, buf, sizeof buf) || strcmp(buf, "Instruction") == 0)
            continue;
        snprintf(path, sizeof path, "/sys/devices/system/cpu/cpu0/cache/index%d/size", i);
        if (!read_line(path, buf, sizeof buf))
            continue;
        size_t size = parse_size(buf, NULL);
        snprintf(path, sizeof path, "/sys/devices/system/cpu/cpu0/cache/index%d/ways_of_associativity", i);
        int ways = read_line(path, buf, sizeof buf) ? atoi(buf) : 0;
        snprintf(path, sizeof path, "/sys/devices/system/cpu/cpu0/cache/index%d/shared_cpu_list", i);
        int sharing = read_line(path, buf, sizeof buf) ? count_cpus(buf) : 1;
        if (level == 1) {
            ci->l1d = size;
            ci->l1d_ways = ways;
            share1 = sharing;
        } else if (level == 2) {
            ci->l2 = size;
            ci->l2_ways = ways;
            share2 = sharing;
        } else if (level == 3) {
            ci->l3 = size;
            share3 = sharing;
        }
    }
    if (ci->l2 && share2 > share1)
        ci->l2_share = ci->l2 / (size_t)share2 * (size_t)share1;
    if (ci->l3)
        ci->l3_share = share3 > share2 ? ci->l3 / (size_t)share3 * (size_t)share2 : ci->l3;
    return ci->l1d != 0 && ci->l2 != 0;
}

struct fk_cache_info fk_cpu_caches(void)
{
    struct fk_cache_info ci;
#if defined(__x86_64__) || defined(__i386__)
    memset(&ci, 0, sizeof ci);
    if (caches_cpuid(&ci)) {
        ci.source = FK_CACHES_CPUID;
        return ci;
    }
#endif
    memset(&ci, 0, sizeof ci);
    if (caches_sysfs(&ci)) {
        ci.source = FK_CACHES_SYSFS;
        return ci;
    }
    memset(&ci, 0, sizeof ci);
    ci.source = FK_CACHES_DEFAULT;
    return ci;
}

static int clampi(long v, int lo, int hi) { return v < lo ? lo : v > hi ? hi : (int)v; }

struct fk_gemm_blocks fk_gemm_blocks_for(const struct fk_cache_info *c)
{
    size_t l1 = c && c->l1d ? c->l1d : 32 * 1024;
    size_t l2 = c && c->l2_share ? c->l2_share : c && c->l2 ? c->l2 : 512 * 1024;
    size_t l3 = c && c->l3_share ? c->l3_share : 2 * 1024 * 1024;
    struct fk_gemm_blocks b;
    /* the kc x 16 fp32 weight sliver in half of L1 */
    b.kc = clampi((long)(l1 / 2 / (16 * 4)) / 16 * 16, 64, 1024);
    /* the packed mc x kc block of A in half of L2 */
    b.mc = clampi((long)(l2 / 2 / ((size_t)b.kc * 4)) / 6 * 6, 6, 1020);
    /* a kc x nc block of weights in half of the L3 share */
    b.nc = clampi((long)(l3 / 2 / ((size_t)b.kc * 4)) / 64 * 64, 256, 4096);
    return b;
}

/* Overrides: nonzero fields of `over` win; the rest keep `b`. Values are
 * rounded to what the kernels need (kc a multiple of 8, mc of 6, nc of 16). */
static struct fk_gemm_blocks blocks_override(struct fk_gemm_blocks b, struct fk_gemm_blocks over)
{
    if (over.kc > 0)
        b.kc = clampi((over.kc + 7) / 8 * 8, 8, 1 << 16);
    if (over.mc > 0)
        b.mc = clampi((over.mc + 5) / 6 * 6, 6, 1 << 16);
    if (over.nc > 0)
        b.nc = clampi((over.nc + 15) / 16 * 16, 16, 1 << 20);
    return b;
}

static struct fk_gemm_blocks blocks_env(void)
{
    struct fk_gemm_blocks b = { 0, 0, 0 };
    const char *s = getenv("FK_GEMM_BLOCKS");
    if (s)
        sscanf(s, "%d,%d,%d", &b.kc, &b.mc, &b.nc);
    return b;
}

static struct fk_cache_info caches_env(void)
{
    struct fk_cache_info c;
    memset(&c, 0, sizeof c);
    const char *s = getenv("FK_CACHES"), *e;
    if (!s)
        return c;
    size_t v[3] = { 0, 0, 0 };
    for (int i = 0; i < 3 && *s; i++) {
        v[i] = parse_size(s, &e);
        s = *e == ',' ? e + 1 : e;
        if (*e != ',')
            break;
    }
    c.l1d = v[0];
    c.l2 = v[1];
    c.l3 = c.l3_share = v[2];
    c.source = FK_CACHES_GIVEN;
    return c;
}

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
    case FK_ISA_AVX512:    return (f & (avx2 | FK_CPU_AVX512)) == (avx2 | FK_CPU_AVX512);
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

/* ggml-style score: the best ISA this CPU can run. AVX-512 first: its GEMM
 * measured 1.5-2.1x OpenBLAS's AVX2 sgemm (f32) and 5-6.5x our f32 (int8) on
 * the model's shapes; the other kernels run their AVX2 code under it. */
static enum fk_isa best_isa(void)
{
    static const enum fk_isa order[] = { FK_ISA_AVX512, FK_ISA_AVX2_VNNI, FK_ISA_AVX2, FK_ISA_NEON };
    for (size_t i = 0; i < sizeof order / sizeof order[0]; i++)
        if (fk_isa_supported(order[i]))
            return order[i];
    return FK_ISA_REF;
}

static const char *const isa_names[] = { "auto", "ref", "avx2", "avx2-vnni", "neon", "avx512" };

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
    va_start(ap, fmt);
    f4d_vfail(&ctx->err, status, fmt, ap);
    va_end(ap);
    f4d_err_prefix(&ctx->err, "%s", func);
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
    /* touched now, at reserve time: not page-faulted in by the first frame
     * (2 % of the first full-size forward's samples on Zen 5) */
    memset(p, 0, fk__round_up(bytes, FK_ALIGN));
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
    struct fk_ctx_config def = { .isa = FK_ISA_AUTO, .threads = 0 };
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
    /* int8 weight codes: the config's, else FK_Q8_BITS (ignored when not 7
     * or 8), else 7 where the ISA has no VNNI: u8 x s8 products then only fit
     * vpmaddubsw's int16 pairs with the 7-bit path's codes, and the exact
     * 8-bit vpmaddwd path is no faster than fp32 */
    if (cfg->q8_bits != FK_Q8_AUTO && cfg->q8_bits != FK_Q8_7BIT && cfg->q8_bits != FK_Q8_8BIT)
        return F4D_EINVAL;
    const char *qenv = getenv("FK_Q8_BITS");
    int qbits = cfg->q8_bits != FK_Q8_AUTO ? (int)cfg->q8_bits : qenv ? atoi(qenv) : 0;
    if (qbits != FK_Q8_7BIT && qbits != FK_Q8_8BIT)
        qbits = isa == FK_ISA_AVX2 ? FK_Q8_7BIT : FK_Q8_8BIT;

    /* bf16 attention: the config's choice, else FK_ATTN_BF16 (0 or 1),
     * else on AMD's CPUs only (fk_bf16_use) */
    if (cfg->bf16 != FK_BF16_AUTO && cfg->bf16 != FK_BF16_ON && cfg->bf16 != FK_BF16_OFF)
        return F4D_EINVAL;
    const char *benv = getenv("FK_ATTN_BF16");
    int bf16_use = cfg->bf16 == FK_BF16_ON                               ? 1
                 : cfg->bf16 == FK_BF16_OFF                              ? 0
                 : benv && (!strcmp(benv, "0") || !strcmp(benv, "1")) ? benv[0] == '1'
                                                                         : (fk_cpu_features() & FK_CPU_AMD) != 0;

    fk_ctx *ctx = calloc(1, sizeof *ctx);
    if (!ctx)
        return F4D_ENOMEM;
    ctx->isa = isa;
    ctx->threads = threads;
    /* caches: the config's, else FK_CACHES, else this CPU's */
    struct fk_cache_info given = cfg->caches, env = caches_env();
    if (given.l1d && given.l2) {
        ctx->caches = given;
        ctx->caches.source = FK_CACHES_GIVEN;
    } else if (env.l1d && env.l2) {
        ctx->caches = env;
    } else {
        ctx->caches = fk_cpu_caches();
    }
    ctx->blocks = blocks_override(blocks_override(fk_gemm_blocks_for(&ctx->caches), blocks_env()),
                                  cfg->blocks);
    ctx->q8_bits = qbits;
    ctx->bf16 = isa == FK_ISA_AVX512 && (fk_cpu_features() & FK_CPU_AVX512_BF16) && bf16_use;
    /* int16 attention where int8's GEMMs outrun fp32 FMAs and no bf16 does
     * better: AVX2 without VNNI (vpmaddwd), AVX2-VNNI (VEX vpdpwssd),
     * AVX-512 without bf16 (vpdpwssd in zmm) */
    ctx->int16 = isa == FK_ISA_AVX2 || isa == FK_ISA_AVX2_VNNI || (isa == FK_ISA_AVX512 && !ctx->bf16);
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
struct fk_cache_info fk_ctx_caches(const fk_ctx *ctx) { return ctx->caches; }
struct fk_gemm_blocks fk_ctx_gemm_blocks(const fk_ctx *ctx) { return ctx->blocks; }
enum fk_q8_bits fk_ctx_q8_bits(const fk_ctx *ctx) { return (enum fk_q8_bits)ctx->q8_bits; }
int fk_ctx_has_bf16(const fk_ctx *ctx) { return ctx->bf16; }
int fk_ctx_has_int16(const fk_ctx *ctx) { return ctx->int16; }

const char *fk_ctx_q8_path(const fk_ctx *ctx)
{
    int b7 = ctx->q8_bits == FK_Q8_7BIT;
    switch (ctx->isa) {
    case FK_ISA_AVX2_VNNI: return b7 ? "vnni-7bit" : "vnni-8bit";
    case FK_ISA_AVX512:    return b7 ? "avx512-vnni-7bit" : "avx512-vnni-8bit";
    case FK_ISA_AVX2:      return b7 ? "avx2-7bit" : "avx2-8bit";
    default:               return b7 ? "ref-7bit" : "ref-8bit";
    }
}

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
