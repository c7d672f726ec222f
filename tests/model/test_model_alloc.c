/* test_model_alloc.c - the model's memory behaviour, through a malloc seam:
 * this binary links with -Wl,--wrap for malloc, calloc, realloc,
 * posix_memalign and aligned_alloc, so every allocation of the statically
 * linked model, GGUF reader and kernels goes through the counters below.
 *
 *   - out of memory at every distinct allocation site of Init and Prepare:
 *     each one fails cleanly with F4D_ENOMEM and a message (no crash, no
 *     leak: ASan). A site is the call stack of the allocation (backtrace);
 *     the sweep fails the first and the last allocation of each site (the
 *     partly and the fully built states before it), skipping sites an
 *     earlier model of the sweep already failed: a file's repeated blocks
 *     and the backbone the stream model shares with the plain ones cost one
 *     Init each, not one per allocation;
 *   - Eval never allocates once Prepare has run (any ISA, any planned size).
 *
 *   test_model_alloc GGUF_DIR
 */
#include <execinfo.h>
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <cmocka.h>

#include "fk_ctx.h"
#include "model.h"

void *__real_malloc(size_t n);
void *__real_calloc(size_t k, size_t n);
int   __real_posix_memalign(void **p, size_t a, size_t n);
void *__real_aligned_alloc(size_t a, size_t n);
void *__wrap_malloc(size_t n);
void *__wrap_calloc(size_t k, size_t n);
void *__wrap_realloc(void *p, size_t n);
int   __wrap_posix_memalign(void **p, size_t a, size_t n);
void *__wrap_aligned_alloc(size_t a, size_t n);

static long n_allocs;     /* allocations since the last reset          */
static long fail_at = -1; /* index of the allocation to fail (-1: none) */
static int  injected;     /* the armed failure happened                */
/* Recording pass: the call-stack hash of each allocation, by index. */
static int       recording, in_backtrace;
static int       test_frames;  /* frames of init_prepare's callers: not hashed */
static uint64_t *site_of;
static long      site_cap;

void *__real_realloc(void *p, size_t n);

static void record_site(long i)
{
    if (!recording || in_backtrace)
        return;
    in_backtrace = 1;
    void *fr[128];
    const int n = backtrace(fr, 128);
    uint64_t h = UINT64_C(1469598103934665603); /* FNV-1a over the return addresses */
    for (int j = 0; j < n - test_frames; j++)
        h = (h ^ (uint64_t)(uintptr_t)fr[j]) * UINT64_C(1099511628211);
    if (i >= site_cap) {
        long cap = site_cap ? 2 * site_cap : 4096;
        while (cap <= i)
            cap *= 2;
        uint64_t *p = __real_realloc(site_of, (size_t)cap * sizeof *p);
        if (!p)
            abort();
        site_of = p;
        site_cap = cap;
    }
    site_of[i] = h;
    in_backtrace = 0;
}

/* 1 when this allocation is the one to fail. */
static int fail_now(void)
{
    if (in_backtrace) /* backtrace's own (first-call) allocations: not the model's */
        return 0;
    long i = n_allocs++;
    record_site(i);
    if (i == fail_at) {
        injected = 1;
        return 1;
    }
    return 0;
}

void *__wrap_malloc(size_t n) { return fail_now() ? NULL : __real_malloc(n); }
void *__wrap_calloc(size_t k, size_t n) { return fail_now() ? NULL : __real_calloc(k, n); }
void *__wrap_realloc(void *p, size_t n) { return fail_now() ? NULL : __real_realloc(p, n); }
void *__wrap_aligned_alloc(size_t a, size_t n)
{
    return fail_now() ? NULL : __real_aligned_alloc(a, n);
}
int __wrap_posix_memalign(void **p, size_t a, size_t n)
{
    return fail_now() ? 12 /* ENOMEM */ : __real_posix_memalign(p, a, n);
}

static const char *gguf_dir;

/* Init + Prepare on a fresh context (so every run allocates the same
 * sequence: a context keeps the scratch an earlier Prepare reserved) with
 * allocation `k` failing; returns the status. After a failure the context
 * must be left unfrozen and usable. */
static int init_prepare(enum fk_isa isa, const char *path, enum fk_wtype wt, long k,
                        struct f4d_err *err)
{
    fk_ctx *ctx;
    struct fk_ctx_config cc = { .isa = isa, .threads = 1 };
    assert_int_equal(fk_ctx_new(&cc, &ctx), F4D_OK);
    if (recording) { /* a site is the stack below this function */
        void *fr[128];
        in_backtrace = 1;
        test_frames = backtrace(fr, 128) - 1;
        in_backtrace = 0;
    }
    struct model *m = NULL;
    n_allocs = 0;
    injected = 0;
    fail_at = k;
    err->msg[0] = 0;
    int rc = model_init(ctx, path, wt, &m, err);
    if (rc == 0) {
        assert_non_null(m);
        rc = model_prepare(m, 2, 42, 70);
        if (rc < 0)
            f4d_fail(err, rc, "%s", model_error(m));
    } else {
        assert_null(m);
    }
    fail_at = -1;
    model_free(m);
    if (rc < 0)
        assert_int_equal(fk_ctx_reserve(ctx, 64, 64), F4D_OK);
    fk_ctx_free(ctx);
    return rc;
}

/* Sites failed by an earlier sweep of this run (the plain models' backbone). */
static uint64_t covered[8192];
static long     n_covered;

static int is_covered(uint64_t h)
{
    for (long i = 0; i < n_covered; i++)
        if (covered[i] == h)
            return 1;
    return 0;
}

static void oom_sweep(const char *file, enum fk_wtype wt, enum fk_isa isa)
{
    char path[1024];
    struct f4d_err err = {0};
    snprintf(path, sizeof path, "%s/%s", gguf_dir, file);
    const clock_t c0 = clock();
    /* a clean run records the site of every allocation */
    recording = 1;
    int rc = init_prepare(isa, path, wt, -1, &err);
    recording = 0;
    if (rc != 0)
        print_error("%s without a failure: rc %d '%s'\n", file, rc, err.msg);
    assert_int_equal(rc, 0);
    const long total = n_allocs;
    assert_true(total > 50);
    long n_sites = 0, n_failed = 0;
    const long covered0 = n_covered;
    for (long k = 0; k < total; k++) {
        const uint64_t h = site_of[k];
        long first = -1, last = -1;
        for (long j = 0; j < total; j++)
            if (site_of[j] == h) {
                if (first < 0)
                    first = j;
                last = j;
            }
        if (first != k)
            continue; /* handled at its first allocation */
        n_sites++;
        if (is_covered(h))
            continue;
        assert_true(n_covered < (long)(sizeof covered / sizeof covered[0]));
        covered[n_covered++] = h;
        for (int e = 0; e < 2; e++) {
            const long at = e ? last : first;
            if (e && last == first)
                break;
            rc = init_prepare(isa, path, wt, at, &err);
            assert_true(injected);
            if (rc != F4D_ENOMEM || !err.msg[0])
                print_error("%s, allocation %ld failing: rc %d '%s'\n", file, at, rc, err.msg);
            assert_int_equal(rc, F4D_ENOMEM);
            assert_true(err.msg[0] != 0);
            n_failed++;
        }
    }
    printf("  %s (%s): %ld allocations at %ld sites, %ld new: out of memory at %ld of them "
           "(first and last of each new site) fails cleanly (%.1f s CPU)\n", file,
           fk_isa_name(isa), total, n_sites, n_covered - covered0, n_failed,
           (double)(clock() - c0) / CLOCKS_PER_SEC);
}

static void test_init_prepare_oom(void **state)
{
    (void)state;
    oom_sweep("tiny_f32.gguf", FK_W_F32, FK_ISA_AUTO);
    oom_sweep("tiny_int8.gguf", FK_W_Q8, FK_ISA_AUTO);
    oom_sweep("tiny_conv_f16.gguf", FK_W_F16, FK_ISA_REF);
    /* Forge4D's state / motion blocks, motion head and fusion MLP too */
    oom_sweep("tiny_f4d_seq_f32.gguf", FK_W_F32, FK_ISA_AUTO);
}

/* Forge4D streaming: memory is flat over time. 200 time steps of the tiny
 * stream model (state blocks, motion, fusion) make no allocation, the arena
 * keeps its size, and the carried state stays finite. Every odd step is a
 * masked one (model_eval_masked, keep-lists varying, every 5th with an
 * empty view), which drops patches once a step ran the motion. */
static void test_stream_flat_memory(void **state)
{
    (void)state;
    enum { S = 2, H = 28, W = 42, STEPS = 200 };
    char path[1024];
    struct f4d_err err = {0};
    snprintf(path, sizeof path, "%s/tiny_f4d_seq_f32.gguf", gguf_dir);
    fk_ctx *ctx;
    struct fk_ctx_config cc = { .isa = FK_ISA_AUTO, .threads = 2 };
    assert_int_equal(fk_ctx_new(&cc, &ctx), F4D_OK);
    struct model *m;
    assert_int_equal(model_init(ctx, path, FK_W_F32, &m, &err), 0);
    assert_int_equal(model_prepare(m, S, H, W), 0);
    const size_t arena = model_arena_bytes(m), n_img = (size_t)S * 3 * H * W;
    float *img = calloc(n_img, sizeof *img);
    assert_non_null(img);
    void *fu = model_fusion(m);
    assert_non_null(fu);
    float at[MODEL_FUSION_ATTRS] = { 0.1f, 0.2f, 0.3f, 0.5f, 0.5f, 0.5f, 2.0f, -4.0f, -4.0f,
                                     -4.0f, 1.0f, 0.0f, 0.0f, 0.0f };
    float fo[MODEL_FUSION_ATTRS];
    struct model_outputs out;
    n_allocs = 0;
    const clock_t c0 = clock();
    for (int t = 0; t < STEPS; t++) {
        for (size_t j = 0; j < n_img; j++) /* a pattern drifting with t */
            img[j] = (float)((j * 7 + (size_t)t * 13) % 251) / 251.0f;
        if (t == STEPS / 2)
            model_state_reset(m);
        uint8_t keep[S * 6];
        for (int j = 0; j < S * 6; j++)
            keep[j] = (t % 5 == 0 && j < 6) ? 0 : (j + t) % 3 == 0;
        assert_int_equal(model_eval_masked(m, img, S, H, W, t % 2 ? keep : NULL, &out), 0);
        assert_int_equal(out.has_motion, t != 0 && t != STEPS / 2);
        assert_int_equal(out.masked, t % 2 && t > 2 && t != STEPS / 2 + 1);
        model_fusion_fuse(fu, at, at, 0.5f, 0.01f, fo);
        assert_int_equal(model_arena_bytes(m), arena);
    }
    if (n_allocs)
        print_error("%d stream steps made %ld allocations\n", STEPS, n_allocs);
    assert_int_equal(n_allocs, 0);
    assert_int_equal(out.step, STEPS / 2);
    for (size_t i = 0; i < (size_t)3 * S * H * W; i++)
        assert_true(isfinite(out.gaussians.pos[i]) && isfinite(out.motion_bwd[i]) &&
                    isfinite(out.motion_fwd_prev[i]));
    printf("  %d stream steps: arena %zu bytes throughout, no allocation (%.1f s CPU)\n", STEPS,
           arena, (double)(clock() - c0) / CLOCKS_PER_SEC);
    free(img);
    model_free(m);
    fk_ctx_free(ctx);
}

/* After Prepare, no Eval up to the planned size allocates: not the first one
 * (kernel scratch reserved by Prepare), not on the scalar ISA (whose GEMM
 * used to malloc a row per call). */
static void test_eval_never_allocates(void **state)
{
    (void)state;
    static const enum fk_isa isas[2] = { FK_ISA_AUTO, FK_ISA_REF };
    static const char *files[2] = { "tiny_f32.gguf", "tiny_int8.gguf" };
    static const enum fk_wtype wts[2] = { FK_W_F32, FK_W_Q8 };
    char path[1024];
    struct f4d_err err = {0};
    for (int i = 0; i < 2; i++)
        for (int f = 0; f < 2; f++) {
            fk_ctx *ctx;
            struct fk_ctx_config cc = { .isa = isas[i], .threads = 2 };
            assert_int_equal(fk_ctx_new(&cc, &ctx), F4D_OK);
            snprintf(path, sizeof path, "%s/%s", gguf_dir, files[f]);
            struct model *m;
            assert_int_equal(model_init(ctx, path, wts[f], &m, &err), 0);
            assert_int_equal(model_prepare(m, 2, 42, 70), 0);
            float *img = calloc((size_t)2 * 3 * 42 * 70, sizeof *img);
            assert_non_null(img);
            for (size_t j = 0; j < (size_t)2 * 3 * 42 * 70; j++)
                img[j] = (float)(j % 251) / 251.0f;
            struct model_outputs out;
            n_allocs = 0;
            assert_int_equal(model_eval(m, img, 2, 42, 70, &out), 0);
            assert_int_equal(model_eval(m, img, 1, 28, 56, &out), 0);
            assert_int_equal(model_eval(m, img, 2, 14, 70, &out), 0);
            assert_int_equal(model_eval(m, img, 2, 42, 70, &out), 0);
            /* foreground-only Evals: a partial and an empty keep-list */
            uint8_t keep[2 * 15] = { 1, 0, 1, 1, 0, 0, 0, 1 };
            assert_int_equal(model_eval_masked(m, img, 2, 42, 70, keep, &out), 0);
            assert_int_equal(out.masked, 1);
            memset(keep, 0, sizeof keep);
            assert_int_equal(model_eval_masked(m, img, 2, 42, 70, keep, &out), 0);
            if (n_allocs)
                print_error("%s on %s: Eval made %ld allocations\n", files[f],
                            fk_isa_name(isas[i]), n_allocs);
            assert_int_equal(n_allocs, 0);
            free(img);
            model_free(m);
            fk_ctx_free(ctx);
        }
}

int main(int argc, char **argv)
{
    if (argc != 2) {
        fprintf(stderr, "usage: %s GGUF_DIR\n", argv[0]);
        return 2;
    }
    gguf_dir = argv[1];
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_init_prepare_oom),
        cmocka_unit_test(test_eval_never_allocates),
        cmocka_unit_test(test_stream_flat_memory),
    };
    return cmocka_run_group_tests_name("/model/alloc", tests, NULL, NULL);
}
