/* fk_ctx: ISA selection, the thread pool (every task exactly once, tiny jobs
 * inline), frozen scratch and error reporting. */
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fk_linear.h"
#include "test_util.h"

static void test_isa_selection(void **state)
{
    (void)state;
    fk_ctx *ctx = NULL;
    struct fk_ctx_config cfg = { .isa = FK_ISA_AUTO, .threads = 1 };
    assert_int_equal(fk_ctx_new(&cfg, &ctx), F4D_OK);
    assert_true(fk_isa_supported(fk_ctx_isa(ctx)));
    assert_string_equal(fk_ctx_error(ctx), "");
    fk_ctx_free(ctx);
    cfg.isa = FK_ISA_NEON; /* offered on AArch64, where it is also the automatic choice */
#if defined(__aarch64__)
    assert_true(fk_cpu_features() & FK_CPU_NEON);
    assert_true(fk_isa_supported(FK_ISA_NEON));
    assert_int_equal(fk_ctx_new(&cfg, &ctx), F4D_OK);
    fk_ctx_free(ctx);
    cfg.isa = FK_ISA_AUTO;
    assert_int_equal(fk_ctx_new(&cfg, &ctx), F4D_OK);
    assert_int_equal(fk_ctx_isa(ctx), FK_ISA_NEON);
    fk_ctx_free(ctx);
    printf("aarch64: dot product %s\n", fk_cpu_features() & FK_CPU_ASIMDDP ? "yes (sdot)" : "no (widening int8)");
#else
    assert_false(fk_isa_supported(FK_ISA_NEON));
    assert_int_equal(fk_ctx_new(&cfg, &ctx), F4D_ENOTSUP);
    assert_null(ctx);
#endif
    cfg.isa = (enum fk_isa)99;
    assert_int_equal(fk_ctx_new(&cfg, &ctx), F4D_ENOTSUP);
    cfg = (struct fk_ctx_config){ .isa = FK_ISA_REF, .threads = 1000 };
    assert_int_equal(fk_ctx_new(&cfg, &ctx), F4D_EINVAL);
    assert_int_equal(fk_ctx_new(&cfg, NULL), F4D_EINVAL);
    for (int i = FK_ISA_AUTO; i <= FK_ISA_NEON; i++)
        assert_int_equal(fk_isa_from_name(fk_isa_name((enum fk_isa)i)), i);
    assert_int_equal((int)fk_isa_from_name("sse9"), -1);
    if (fk_cpu_features() & FK_CPU_AVX2)
        assert_true(fk_isa_supported(FK_ISA_AVX2) == ((fk_cpu_features() & (FK_CPU_FMA | FK_CPU_F16C)) ==
                                                     (FK_CPU_FMA | FK_CPU_F16C)));
    /* bf16 attention: only an AVX-512 context on a CPU with AVX512_BF16 */
    if (fk_cpu_features() & FK_CPU_AVX512_BF16)
        assert_true(fk_cpu_features() & FK_CPU_AVX512);
    for (int i = FK_ISA_REF; i <= FK_ISA_AVX512; i++) {
        cfg = (struct fk_ctx_config){ .isa = (enum fk_isa)i, .threads = 1 };
        if (!fk_isa_supported((enum fk_isa)i))
            continue;
        int can = i == FK_ISA_AVX512 && (fk_cpu_features() & FK_CPU_AVX512_BF16) != 0;
        /* AUTO: where vdpbf16ps pays (AMD); ON: wherever it runs; OFF: never */
        static const enum fk_bf16_use uses[] = { FK_BF16_AUTO, FK_BF16_ON, FK_BF16_OFF };
        for (int u = 0; u < 3; u++) {
            cfg.bf16 = uses[u];
            unsetenv("FK_ATTN_BF16");
            assert_int_equal(fk_ctx_new(&cfg, &ctx), F4D_OK);
            int want = uses[u] == FK_BF16_ON ? can
                     : uses[u] == FK_BF16_OFF ? 0 : can && (fk_cpu_features() & FK_CPU_AMD) != 0;
            assert_int_equal(fk_ctx_has_bf16(ctx), want);
            fk_ctx_free(ctx);
            if (uses[u] == FK_BF16_AUTO) { /* the environment decides where the config does not */
                setenv("FK_ATTN_BF16", "1", 1);
                assert_int_equal(fk_ctx_new(&cfg, &ctx), F4D_OK);
                assert_int_equal(fk_ctx_has_bf16(ctx), can);
                fk_ctx_free(ctx);
                setenv("FK_ATTN_BF16", "0", 1);
                assert_int_equal(fk_ctx_new(&cfg, &ctx), F4D_OK);
                assert_int_equal(fk_ctx_has_bf16(ctx), 0);
                fk_ctx_free(ctx);
                unsetenv("FK_ATTN_BF16");
            }
        }
    }
    cfg = (struct fk_ctx_config){ .isa = FK_ISA_REF, .threads = 1, .bf16 = (enum fk_bf16_use)7 };
    assert_int_equal(fk_ctx_new(&cfg, &ctx), F4D_EINVAL);
}

struct count_arg {
    atomic_int *hits;
    atomic_int  max_thread;
};

static void count_task(void *arg, int task, int thread)
{
    struct count_arg *a = arg;
    atomic_fetch_add(&a->hits[task], 1);
    int m = atomic_load(&a->max_thread);
    while (thread > m && !atomic_compare_exchange_weak(&a->max_thread, &m, thread))
        ;
}

static void test_parallel_for(void **state)
{
    (void)state;
    fk_ctx *ctx = test_ctx(FK_ISA_REF, 2);
    enum { N = 1000 };
    atomic_int *hits = xmalloc(sizeof(atomic_int) * N);
    for (int round = 0; round < 50; round++) {
        struct count_arg a = { hits, 0 };
        for (int i = 0; i < N; i++)
            atomic_store(&hits[i], 0);
        fk_parallel_for(ctx, N, 1e9, count_task, &a);
        for (int i = 0; i < N; i++)
            assert_int_equal(atomic_load(&hits[i]), 1);
        assert_true(atomic_load(&a.max_thread) <= 1);
    }
    /* a tiny job never leaves the caller's thread */
    struct count_arg a = { hits, 0 };
    for (int i = 0; i < N; i++)
        atomic_store(&hits[i], 0);
    fk_parallel_for(ctx, N, 10.0, count_task, &a);
    assert_int_equal(atomic_load(&a.max_thread), 0);
    fk_parallel_for(ctx, 0, 1e9, count_task, &a); /* no tasks: nothing runs */
    free(hits);
    fk_ctx_free(ctx);
}

static void test_frozen_scratch(void **state)
{
    (void)state;
    fk_ctx *ctx = test_ctx(FK_ISA_AUTO, 2);
    float w[64 * 64], x[64 * 64], y[64 * 64];
    for (int i = 0; i < 64 * 64; i++)
        w[i] = x[i] = (float)(i % 7) * 0.25f;
    struct fk_linear L;
    assert_int_equal(fk_linear_pack(ctx, &L, FK_W_F32, w, 64, 64, NULL), F4D_OK);
    /* warm up, then freeze: the same call must still work with no allocation */
    assert_int_equal(fk_linear_forward(ctx, &L, x, 64, 64, y, 64, NULL), F4D_OK);
    size_t reserved = fk_ctx_scratch_bytes(ctx);
    assert_true(reserved > 0);
    fk_ctx_freeze(ctx, 1);
    assert_int_equal(fk_linear_forward(ctx, &L, x, 64, 64, y, 64, NULL), F4D_OK);
    assert_int_equal(fk_ctx_scratch_bytes(ctx), reserved);
    /* a bigger job than planned fails cleanly and says why */
    struct fk_linear big;
    float *wb = xmalloc(sizeof(float) * 64 * 4096), *xb = xmalloc(sizeof(float) * 64 * 4096);
    assert_int_equal(fk_linear_pack(ctx, &big, FK_W_F32, wb, 64, 4096, NULL), F4D_OK);
    assert_int_equal(fk_linear_forward(ctx, &big, xb, 64, 4096, y, 64, NULL), F4D_ENOMEM);
    assert_non_null(strstr(fk_ctx_error(ctx), "frozen"));
    fk_ctx_freeze(ctx, 0);
    assert_int_equal(fk_linear_forward(ctx, &big, xb, 64, 4096, y, 64, NULL), F4D_OK);
    fk_linear_free(&big);
    fk_linear_free(&L);
    free(wb);
    free(xb);
    fk_ctx_free(ctx);
}

/* The cache model (fk_gemm_blocks_for) on the caches of the boxes' CPUs. */
static void test_gemm_blocks_model(void **state)
{
    (void)state;
    static const struct {
        struct fk_cache_info c;
        struct fk_gemm_blocks want;
    } cases[] = {
        /* Zen 3: 32K L1d, 512K L2, 32M L3 over 8 cores */
        { { .l1d = 32 << 10, .l2 = 512 << 10, .l3 = 32 << 20, .l3_share = 4 << 20 }, { 256, 252, 2048 } },
        /* Golden Cove P-core: 48K L1d, 1.25M L2, 30M L3 over 12 */
        { { .l1d = 48 << 10, .l2 = 1280 << 10, .l3 = 30 << 20, .l3_share = 2560 << 10 }, { 384, 426, 832 } },
        /* 32K L1d, 2M L2 (Gracemont cluster), L3 unknown */
        { { .l1d = 32 << 10, .l2 = 2 << 20 }, { 256, 1020, 1024 } },
        /* nothing known: 32K / 512K / 2M */
        { { .l1d = 0 }, { 256, 252, 1024 } },
        /* Gracemont (Alder Lake-N): 2M L2 shared by a cluster of 4 cores */
        { { .l1d = 32 << 10, .l2 = 2 << 20, .l2_share = 512 << 10, .l3_share = 1536 << 10 }, { 256, 252, 768 } },
        /* tiny caches clamp */
        { { .l1d = 4 << 10, .l2 = 16 << 10, .l3_share = 64 << 10 }, { 64, 30, 256 } },
    };
    for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++) {
        struct fk_gemm_blocks b = fk_gemm_blocks_for(&cases[i].c);
        if (b.kc != cases[i].want.kc || b.mc != cases[i].want.mc || b.nc != cases[i].want.nc)
            fail_msg("case %zu: blocks %d,%d,%d, want %d,%d,%d", i, b.kc, b.mc, b.nc,
                     cases[i].want.kc, cases[i].want.mc, cases[i].want.nc);
        /* the invariants the model promises */
        assert_true((size_t)b.kc * 16 * 4 <= (cases[i].c.l1d ? cases[i].c.l1d : 32 << 10) / 2 || b.kc == 64);
        assert_int_equal(b.mc % 6, 0);
    }
    assert_int_equal(fk_gemm_blocks_for(NULL).kc, 256);

    /* the config's caches and blocks, and the environment, override */
    fk_ctx *ctx;
    struct fk_ctx_config cfg = { .isa = FK_ISA_REF, .threads = 1,
                                 .caches = { .l1d = 48 << 10, .l2 = 1280 << 10, .l3_share = 2560 << 10 } };
    assert_int_equal(fk_ctx_new(&cfg, &ctx), F4D_OK);
    struct fk_gemm_blocks b = fk_ctx_gemm_blocks(ctx);
    assert_int_equal(b.kc, 384);
    assert_int_equal(b.mc, 426);
    assert_int_equal(fk_ctx_caches(ctx).source, FK_CACHES_GIVEN);
    fk_ctx_free(ctx);
    cfg.blocks = (struct fk_gemm_blocks){ 100, 0, 0 }; /* kc rounded to 8, the rest modelled */
    assert_int_equal(fk_ctx_new(&cfg, &ctx), F4D_OK);
    b = fk_ctx_gemm_blocks(ctx);
    assert_int_equal(b.kc, 104);
    assert_int_equal(b.mc, 426);
    fk_ctx_free(ctx);
    setenv("FK_GEMM_BLOCKS", "64,12,128", 1);
    setenv("FK_CACHES", "32K,512K,4M", 1);
    cfg = (struct fk_ctx_config){ .isa = FK_ISA_REF, .threads = 1, .blocks = { 0, 18, 0 } };
    assert_int_equal(fk_ctx_new(&cfg, &ctx), F4D_OK);
    b = fk_ctx_gemm_blocks(ctx);
    assert_int_equal(b.kc, 64);  /* env */
    assert_int_equal(b.mc, 18);  /* config over env */
    assert_int_equal(b.nc, 128); /* env */
    assert_int_equal(fk_ctx_caches(ctx).l2, 512 << 10);
    fk_ctx_free(ctx);
    unsetenv("FK_GEMM_BLOCKS");
    assert_int_equal(fk_ctx_new(&cfg, &ctx), F4D_OK);
    b = fk_ctx_gemm_blocks(ctx);
    assert_int_equal(b.kc, 256); /* modelled from FK_CACHES = Zen 3 */
    assert_int_equal(b.nc, 2048);
    fk_ctx_free(ctx);
    unsetenv("FK_CACHES");

    /* this CPU: something sane was read or defaulted */
    struct fk_cache_info c = fk_cpu_caches();
    print_message("caches: L1d %zu L2 %zu L3 %zu (share %zu), source %d\n", c.l1d, c.l2, c.l3,
                  c.l3_share, c.source);
    if (c.source != FK_CACHES_DEFAULT)
        assert_true(c.l1d >= 4096 && c.l2 >= c.l1d);
}

/* int8 weight codes: 7 bits where the ISA has no VNNI, unless forced. */
static void test_q8_bits(void **state)
{
    (void)state;
    fk_ctx *ctx;
    struct fk_ctx_config cfg = { .isa = FK_ISA_REF, .threads = 1 };
    assert_int_equal(fk_ctx_new(&cfg, &ctx), F4D_OK);
    assert_int_equal(fk_ctx_q8_bits(ctx), FK_Q8_8BIT);
    fk_ctx_free(ctx);
    if (fk_isa_supported(FK_ISA_AVX2)) {
        cfg.isa = FK_ISA_AVX2;
        assert_int_equal(fk_ctx_new(&cfg, &ctx), F4D_OK);
        assert_int_equal(fk_ctx_q8_bits(ctx), FK_Q8_7BIT);
        assert_string_equal(fk_ctx_q8_path(ctx), "avx2-7bit");
        fk_ctx_free(ctx);
        cfg.q8_bits = FK_Q8_8BIT;
        assert_int_equal(fk_ctx_new(&cfg, &ctx), F4D_OK);
        assert_string_equal(fk_ctx_q8_path(ctx), "avx2-8bit");
        fk_ctx_free(ctx);
    }
    if (fk_isa_supported(FK_ISA_AVX2_VNNI)) {
        cfg = (struct fk_ctx_config){ .isa = FK_ISA_AVX2_VNNI, .threads = 1 };
        assert_int_equal(fk_ctx_new(&cfg, &ctx), F4D_OK);
        assert_string_equal(fk_ctx_q8_path(ctx), "vnni-8bit");
        fk_ctx_free(ctx);
    }
    cfg = (struct fk_ctx_config){ .isa = FK_ISA_REF, .threads = 1, .q8_bits = (enum fk_q8_bits)5 };
    assert_int_equal(fk_ctx_new(&cfg, &ctx), F4D_EINVAL);
}

int main(int argc, char **argv)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_isa_selection),
        cmocka_unit_test(test_parallel_for),
        cmocka_unit_test(test_frozen_scratch),
        cmocka_unit_test(test_gemm_blocks_model),
        cmocka_unit_test(test_q8_bits),
    };
    return KERNEL_TEST_MAIN(argc, argv, "kernels/ctx", tests);
}
