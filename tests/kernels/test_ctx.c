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
    struct fk_ctx_config cfg = { FK_ISA_AUTO, 1 };
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
    cfg = (struct fk_ctx_config){ FK_ISA_REF, 1000 };
    assert_int_equal(fk_ctx_new(&cfg, &ctx), F4D_EINVAL);
    assert_int_equal(fk_ctx_new(&cfg, NULL), F4D_EINVAL);
    for (int i = FK_ISA_AUTO; i <= FK_ISA_NEON; i++)
        assert_int_equal(fk_isa_from_name(fk_isa_name((enum fk_isa)i)), i);
    assert_int_equal((int)fk_isa_from_name("sse9"), -1);
    if (fk_cpu_features() & FK_CPU_AVX2)
        assert_true(fk_isa_supported(FK_ISA_AVX2) == ((fk_cpu_features() & (FK_CPU_FMA | FK_CPU_F16C)) ==
                                                     (FK_CPU_FMA | FK_CPU_F16C)));
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

int main(int argc, char **argv)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_isa_selection),
        cmocka_unit_test(test_parallel_for),
        cmocka_unit_test(test_frozen_scratch),
    };
    return KERNEL_TEST_MAIN(argc, argv, "kernels/ctx", tests);
}
