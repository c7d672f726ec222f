/* fk_ctx.h - the kernel context: ISA choice, thread pool, scratch, errors.
 *
 * Every kernel in kernels/ takes an fk_ctx. The context owns
 *   - the instruction set chosen once at creation (scored from cpuid / the
 *     AArch64 hwcaps, or forced),
 *   - a small pthread pool (the caller's thread is worker 0),
 *   - per-thread and shared scratch arenas, reserved up front and optionally
 *     frozen so that the per-frame path provably never allocates,
 *   - the message of the last error.
 *
 *     fk_ctx *ctx;
 *     struct fk_ctx_config cfg = { .isa = FK_ISA_AUTO, .threads = 2 };
 *     if (fk_ctx_new(&cfg, &ctx) != F4D_OK) ...;
 *     if (fk_layernorm(ctx, x, rows, cols, cols, w, b, 1e-5f, y, cols) != F4D_OK)
 *         fprintf(stderr, "%s\n", fk_ctx_error(ctx));
 *     fk_ctx_free(ctx);
 *
 * A context is used by one caller thread at a time; make one per pipeline stage
 * that runs concurrently. Kernels never call exit() or abort() on bad input:
 * they return a negative fk_status and leave a message naming what is wrong.
 *
 * Non-finite inputs (NaN, +-Inf) propagate: a kernel never crashes on them and
 * the affected outputs become non-finite; finite rows stay unaffected.
 */
#ifndef FK_CTX_H
#define FK_CTX_H

#include <stddef.h>
#include <stdint.h>

#include "f4d_status.h"

#ifdef __cplusplus
extern "C" {
#endif

/* Instruction sets. Values are stored in files and never renumbered. */
enum fk_isa {
    FK_ISA_AUTO      = 0, /* best available on this CPU                         */
    FK_ISA_REF       = 1, /* portable scalar C: the specification               */
    FK_ISA_AVX2      = 2, /* x86-64 AVX2 + FMA + F16C                           */
    FK_ISA_AVX2_VNNI = 3, /* AVX2 plus AVX-VNNI (VEX vpdpbusd) for int8 GEMM     */
    FK_ISA_NEON      = 4, /* AArch64 NEON (int8 GEMM with sdot where HWCAP_ASIMDDP) */
    FK_ISA_AVX512    = 5, /* AVX2_VNNI's set plus AVX-512 F/BW/VL/VNNI: 6x32 zmm
                           * GEMM tiles (same packed layouts); the other
                           * kernels run their AVX2 code under it            */
};

/* CPU feature bits reported by fk_cpu_features(). */
enum {
    FK_CPU_AVX2     = 1u << 0,
    FK_CPU_FMA      = 1u << 1,
    FK_CPU_F16C     = 1u << 2,
    FK_CPU_AVX_VNNI = 1u << 3,
    FK_CPU_NEON     = 1u << 4,
    FK_CPU_ASIMDDP  = 1u << 5, /* AArch64 dot product (sdot/udot), ARMv8.2+ */
    FK_CPU_AVX512   = 1u << 6, /* F + BW + VL + VNNI, ZMM state enabled by the OS */
    FK_CPU_AVX512_BF16 = 1u << 7, /* AVX512_BF16 (vdpbf16ps) beside FK_CPU_AVX512 */
    FK_CPU_AMD      = 1u << 8, /* vendor AuthenticAMD / HygonGenuine: not an ISA,
                                * it picks where bf16 attention pays (fk_bf16_use) */
};

/* Data caches as read at context creation (cpuid leaf 4 on Intel, 0x8000001D
 * on AMD, sysfs as the fallback; 0 = unknown). l2_share and l3_share are the
 * bytes per core (the cache divided among the cores that share it: an
 * Alder Lake-N cluster shares 2 MiB of L2 between 4 cores); 0 = not shared. */
struct fk_cache_info {
    size_t l1d, l2, l3, l3_share, l2_share;
    int    l1d_ways, l2_ways;
    int    source;           /* FK_CACHES_* below                            */
};
enum { FK_CACHES_DEFAULT = 0, FK_CACHES_CPUID = 1, FK_CACHES_SYSFS = 2, FK_CACHES_GIVEN = 3 };

/* Cache blocks of the GEMM (fp32 elements; int8 uses 4 kc): kc rows of k per
 * weight panel slice (kept in L1), mc rows of A per packed block (kept in
 * L2), nc output columns per chunk of weights (kept in the L3 share). 0 in a
 * field of an override means "from the cache model". */
struct fk_gemm_blocks {
    int kc, mc, nc;
};

/* int8 weight codes on the optimized x86 path (FK_W_Q8). */
enum fk_q8_bits {
    FK_Q8_AUTO = 0, /* 8 where the CPU has VNNI dot products, else 7            */
    FK_Q8_8BIT = 8, /* [-127, 127]: VNNI vpdpbusd, or exact vpmaddwd pairs      */
    FK_Q8_7BIT = 7, /* the int16 pair budget of 7-bit codes: |q[2i]| + |q[2i+1]|
                     * <= 128 (so u8 x s8 vpmaddubsw pairs cannot saturate),
                     * spent per pair; requantized at packing              */
};

/* Whether a desc's bf16 attention (desc.bf16, set by the model for int8
 * weights) runs in bf16 on an AVX-512 context of a CPU with AVX512_BF16.
 * AUTO: on AMD's CPUs (bf16 attention 1.3-1.5x fp32 on Zen 5, 1.7-1.9x
 * on Zen 4, whose zmm vdpbf16ps retires once a cycle: twice the zmm FMAs'
 * multiply-adds); not on Intel's
 * (the Xeon VM retired a zmm vdpbf16ps every other cycle, half the FMAs'
 * multiply-adds: bf16 attention 0.63-0.71x fp32 there). ON: wherever the
 * CPU has it (tests, benches); OFF: never. */
enum fk_bf16_use { FK_BF16_AUTO = 0, FK_BF16_ON = 1, FK_BF16_OFF = 2 };

struct fk_ctx_config {
    enum fk_isa isa;     /* FK_ISA_AUTO picks the best the CPU supports          */
    int         threads; /* 0 = all online CPUs; 1 = no pool threads at all      */
    /* Experiments; zero = automatic. The environment variables
     * FK_GEMM_BLOCKS="kc,mc,nc", FK_CACHES="l1d,l2,l3share" (bytes, K/M
     * suffixes) and FK_Q8_BITS=7|8 apply where these are zero. */
    struct fk_gemm_blocks blocks;  /* override of the cache model's blocks  */
    struct fk_cache_info  caches;  /* l1d/l2 nonzero: model these caches     */
    enum fk_q8_bits       q8_bits; /* int8 weight codes                      */
    enum fk_bf16_use      bf16;    /* bf16 attention (FK_ATTN_BF16=0|1 where AUTO) */
};

typedef struct fk_ctx fk_ctx;

/* Creates a context. An explicitly requested ISA the CPU lacks is F4D_ENOTSUP. */
int          fk_ctx_new      (const struct fk_ctx_config *cfg, fk_ctx **out);
void         fk_ctx_free     (fk_ctx *ctx);
enum fk_isa  fk_ctx_isa      (const fk_ctx *ctx);
int          fk_ctx_threads  (const fk_ctx *ctx);
const char * fk_ctx_error    (const fk_ctx *ctx);   /* "" when no error yet     */
int          fk_ctx_status   (const fk_ctx *ctx);   /* code of that error, 0 if none */
struct fk_cache_info  fk_ctx_caches     (const fk_ctx *ctx);
struct fk_gemm_blocks fk_ctx_gemm_blocks(const fk_ctx *ctx);
enum fk_q8_bits       fk_ctx_q8_bits    (const fk_ctx *ctx); /* 7 or 8 (never AUTO) */
/* Name of the int8 GEMM path the context runs: "ref", "vnni-8bit",
 * "avx2-7bit", "avx2-8bit". */
const char * fk_ctx_q8_path  (const fk_ctx *ctx);
/* Nonzero where a desc's bf16 attention runs in bf16: the context's ISA is
 * FK_ISA_AVX512, the CPU has AVX512_BF16 and the config's bf16 (AUTO: an
 * AMD CPU) lets it. */
int          fk_ctx_has_bf16 (const fk_ctx *ctx);
/* Nonzero where a desc's int16 attention runs in int16: the context's ISA
 * is FK_ISA_AVX2 (AVX2 without VNNI or AVX-512, where int8 weights take the
 * 7-bit path and fp32 attention would hold the forward to the FMA rate),
 * FK_ISA_AVX2_VNNI (VEX vpdpwssd), or FK_ISA_AVX512 without bf16 attention
 * (vpdpwssd in zmm; from 64-dim heads, see fk_attention_products). */
int          fk_ctx_has_int16(const fk_ctx *ctx);

/* The cache model (pure; unknown sizes take 32K / 512K / 2M defaults), with
 * MR = 6 rows by NR = 16 columns per register tile of fp32:
 *   kc: the kc x NR weight sliver takes half of L1 (it is reused across all
 *       micro-panels of A; the other half holds the streaming MR x kc A
 *       slivers and the C tile), a multiple of 16 in [64, 1024];
 *   mc: the packed mc x kc block of A takes half of the core's L2 (l2_share
 *       where set, else l2), a multiple of MR in [MR, 1020];
 *   nc: a kc x nc block of weights takes half of the L3 share, a multiple
 *       of 64 in [256, 4096]. */
struct fk_gemm_blocks fk_gemm_blocks_for(const struct fk_cache_info *caches);
/* Reads this CPU's caches (what fk_ctx_new does). */
struct fk_cache_info  fk_cpu_caches(void);

/* Scratch. Kernels grow the arenas on demand until the context is frozen;
 * after fk_ctx_freeze a kernel that needs more scratch fails with F4D_ENOMEM.
 * fk_ctx_reserve grows every per-thread arena to at least `per_thread` bytes
 * and the shared arena to at least `shared` bytes. */
int          fk_ctx_reserve  (fk_ctx *ctx, size_t per_thread, size_t shared);
void         fk_ctx_freeze   (fk_ctx *ctx, int frozen);
size_t       fk_ctx_scratch_bytes(const fk_ctx *ctx); /* total reserved now  */
/* Measuring: while on, every kernel that uses scratch reserves what the call
 * needs (growing the arenas, as unfrozen) and returns F4D_OK WITHOUT computing:
 * its outputs are left as they were. Kernels without scratch run normally.
 * A caller runs its per-frame path once at the largest planned sizes with
 * measuring on, then turns it off and freezes (model_prepare does). Scratch
 * needs grow monotonically with the problem sizes, so smaller calls fit. */
void         fk_ctx_measure  (fk_ctx *ctx, int on);

unsigned     fk_cpu_features (void);
int          fk_isa_supported(enum fk_isa isa);
const char * fk_isa_name     (enum fk_isa isa);
enum fk_isa  fk_isa_from_name(const char *name);     /* -1 cast when unknown */

/* Parallel loop: fn(arg, task, thread) for task in [0, n_tasks), tasks handed
 * out dynamically; returns when all are done. `thread` is in [0, threads) and
 * indexes per-thread scratch. With n_tasks <= 1, or when `work` (an estimate of
 * the whole job in scalar operations) is below FK_PARALLEL_MIN_WORK, it runs
 * inline on the caller: a barrier per tiny op costs a scheduler tick here. */
#define FK_PARALLEL_MIN_WORK 200000.0
typedef void (*fk_task_fn)(void *arg, int task, int thread);
void         fk_parallel_for (fk_ctx *ctx, int n_tasks, double work, fk_task_fn fn, void *arg);

#ifdef __cplusplus
}
#endif
#endif /* FK_CTX_H */
