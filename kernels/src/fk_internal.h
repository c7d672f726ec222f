/* fk_internal.h - what the kernel modules share behind the public headers:
 * the context layout, error reporting, scratch access and ISA entry points. */
#ifndef FK_INTERNAL_H
#define FK_INTERNAL_H

#include <stddef.h>
#include <stdint.h>
#include "../fk_ctx.h"

#define FK_ERR_LEN 256
#define FK_ALIGN 64

struct fk_pool;

struct fk_arena {
    void  *ptr;
    size_t bytes;
};

struct fk_ctx {
    enum fk_isa      isa;
    int              threads;
    int              q8_bits;    /* 7 or 8: int8 weight codes packed       */
    int              bf16;       /* bf16 attention: AVX-512 ISA, AVX512_BF16, fk_bf16_use */
    int              int16;      /* int16 attention: AVX2 / AVX2-VNNI ISA, or AVX-512 without bf16 */
    struct fk_cache_info  caches;
    struct fk_gemm_blocks blocks; /* resolved: model, then overrides       */
    int              frozen;
    int              measuring;  /* fk_ctx_measure: reserve, then skip  */
    struct fk_pool  *pool;       /* NULL when threads == 1           */
    struct fk_arena *local;      /* [threads] per-thread scratch      */
    struct fk_arena  shared;
    struct f4d_err   err;        /* last failure: code + "func: what" */
};

/* Records "func: message" as the context's error and returns status. */
int   fk__fail(fk_ctx *ctx, int status, const char *func, const char *fmt, ...)
      __attribute__((format(printf, 4, 5)));
#define FK_FAIL(ctx, st, ...) fk__fail((ctx), (st), __func__, __VA_ARGS__)

/* Scratch, reserved on the caller's thread before a parallel loop:
 * fk__scratch_reserve makes every per-thread arena at least `per_thread`
 * bytes and the shared one at least `shared` bytes (F4D_ENOMEM with a message
 * when frozen or out of memory). Inside tasks, fk__scratch(ctx, thread) and
 * fk__scratch_shared(ctx) return the 64-byte aligned arenas. */
int   fk__scratch_reserve(fk_ctx *ctx, size_t per_thread, size_t shared);
/* True while the context measures (fk_ctx_measure): a kernel returns F4D_OK
 * right after its fk__scratch_reserve, without computing. */
static inline int fk__measuring(const fk_ctx *ctx) { return ctx->measuring; }
static inline void *fk__scratch(fk_ctx *ctx, int thread) { return ctx->local[thread].ptr; }
static inline void *fk__scratch_shared(fk_ctx *ctx) { return ctx->shared.ptr; }

/* 64-byte aligned allocation for packed weights (free with free()). */
void *fk__alloc(size_t bytes);

static inline size_t fk__round_up(size_t x, size_t a) { return (x + a - 1) / a * a; }

/* Nonzero when the context runs the AVX2 kernels (AVX2, AVX2_VNNI and AVX512
 * share layouts and code; only the GEMM micro-kernels differ). Always 0 off x86-64,
 * where every front end runs its reference. */
static inline int fk__isa_avx2(enum fk_isa isa)
{
#if defined(__x86_64__)
    return isa == FK_ISA_AVX2 || isa == FK_ISA_AVX2_VNNI || isa == FK_ISA_AVX512;
#else
    (void)isa;
    return 0;
#endif
}

/* Nonzero when the context runs the AArch64 NEON kernels. Always 0 off
 * AArch64. */
static inline int fk__isa_neon(enum fk_isa isa)
{
#if defined(__aarch64__)
    return isa == FK_ISA_NEON;
#else
    (void)isa;
    return 0;
#endif
}

/* Nonzero when weights are stored in the packed panel layouts of gemm.h
 * (the AVX2 and the NEON kernels share them; the reference keeps [n][k]). */
static inline int fk__isa_packed(enum fk_isa isa)
{
    return fk__isa_avx2(isa) || fk__isa_neon(isa);
}

/* Checks shared by the front ends. */
#define FK_CHECK_CTX(ctx) do { if (!(ctx)) return F4D_EINVAL; } while (0)

#endif /* FK_INTERNAL_H */
