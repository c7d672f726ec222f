/* test_sequence_mem.c - the sequence's memory is flat: after open and two
 * pushes, every further push and interpolation allocates nothing, so N pushed
 * steps hold the bytes of 2. malloc, calloc, realloc, posix_memalign and
 * aligned_alloc are wrapped at link time (-Wl,--wrap, as test_model_alloc
 * does): every allocation of the statically linked sequence, model,
 * interpolator and kernels is counted with its size. The resident set
 * (/proc/self/statm) is compared as well. The weights are tiny_f4d_seq (state
 * blocks, motion, fusion MLP): every step runs the whole streaming path.
 *
 *   test_sequence_mem GGUF_DIR STEPS
 *
 * ctest runs 10,000 steps in the normal build and fewer under ASan (the
 * count is in the test's name).
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "f4d_sequence.h"
#include "f4d_test.h"

void *__real_malloc(size_t n);
void *__real_calloc(size_t k, size_t n);
void *__real_realloc(void *p, size_t n);
int   __real_posix_memalign(void **p, size_t a, size_t n);
void *__real_aligned_alloc(size_t a, size_t n);
void *__wrap_malloc(size_t n);
void *__wrap_calloc(size_t k, size_t n);
void *__wrap_realloc(void *p, size_t n);
int   __wrap_posix_memalign(void **p, size_t a, size_t n);
void *__wrap_aligned_alloc(size_t a, size_t n);

static long   n_allocs;
static size_t n_bytes;

void *__wrap_malloc(size_t n) { n_allocs++; n_bytes += n; return __real_malloc(n); }
void *__wrap_calloc(size_t k, size_t n) { n_allocs++; n_bytes += k * n; return __real_calloc(k, n); }
void *__wrap_realloc(void *p, size_t n) { n_allocs++; n_bytes += n; return __real_realloc(p, n); }
void *__wrap_aligned_alloc(size_t a, size_t n) { n_allocs++; n_bytes += n; return __real_aligned_alloc(a, n); }
int __wrap_posix_memalign(void **p, size_t a, size_t n) { n_allocs++; n_bytes += n; return __real_posix_memalign(p, a, n); }

static const char *gguf_dir;
static long        steps;

static long rss_kib(void)
{
    long pages = 0, res = 0;
    FILE *f = fopen("/proc/self/statm", "r");
    if (!f)
        return -1;
    if (fscanf(f, "%ld %ld", &pages, &res) != 2)
        res = -1;
    fclose(f);
    return res < 0 ? -1 : res * (sysconf(_SC_PAGESIZE) / 1024);
}

static void flat(void **state)
{
    (void)state;
    char p[1024];
    /* the whole streaming path: state blocks, motion, fusion MLP in interp */
    snprintf(p, sizeof p, "%s/tiny_f4d_seq_f32.gguf", gguf_dir);
    if (access(p, R_OK) != 0)
        fail_msg("%s is absent (model/convert_tiny_f4d_seq_f32 makes it)", p);
    const int S = 2, H = 14, W = 28; /* small: 10,000 steps in ~30 s of CPU */
    const size_t ni = (size_t)S * 3 * H * W;
    float *img[2] = { malloc(ni * sizeof(float)), malloc(ni * sizeof(float)) };
    unsigned seed = 1;
    for (int k = 0; k < 2; k++)
        for (size_t i = 0; i < ni; i++) {
            seed = seed * 1103515245u + 12345u;
            img[k][i] = (float)((seed >> 8) & 0xffff) / 65535.0f;
        }
    fk_ctx *ctx;
    f4d_sequence *sq;
    struct f4d_err err = { 0 };
    assert_int_equal(fk_ctx_new(&(struct fk_ctx_config){ .isa = FK_ISA_AUTO, .threads = 1 }, &ctx), 0);
    long a_open = n_allocs;
    size_t b_open = n_bytes;
    if (f4d_sequence_open(ctx, p, FK_W_F32, S, H, W, &sq, &err) < 0)
        fail_msg("open: %s", err.msg);
    assert_true(f4d_sequence_has_motion(sq) && f4d_sequence_has_fusion(sq));
    long a0 = n_allocs;
    size_t b0 = n_bytes;
    const struct splat_frame *mid;
    /* the batched fusion MLP on a full batch, at step 1 and then every 100
     * steps (the random tiny weights match few pairs within tau, so at()
     * alone rarely reaches it); its buffers are the test's, touched here */
    static float fx[INTERP_FUSE_BATCH * INTERP_FUSE_IN], fo[INTERP_FUSE_BATCH * INTERP_ATTRS];
    for (size_t i = 0; i < sizeof fx / sizeof fx[0]; i++)
        fx[i] = (float)(i % 7) * 0.1f;
    memset(fo, 0, sizeof fo);
    /* steps 0 and 1: the first interval, interpolated at its middle */
    for (long t = 0; t < 2; t++)
        assert_int_equal(f4d_sequence_push(sq, img[t & 1], &err), 0);
    assert_int_equal(f4d_sequence_at(sq, 0.5, &mid, NULL, &err), 0);
    assert_int_equal(f4d_sequence_fuse_batch(sq, fx, INTERP_FUSE_BATCH, fo), 0);
    long a2 = n_allocs, rss2 = rss_kib();
    size_t b2 = n_bytes;
    for (long t = 2; t < steps; t++) {
        if (f4d_sequence_push(sq, img[t & 1], &err) < 0 || f4d_sequence_at(sq, (double)t - 0.5, &mid, NULL, &err) < 0)
            fail_msg("step %ld: %s", t, err.msg);
        if (t % 100 == 2)
            assert_int_equal(f4d_sequence_fuse_batch(sq, fx, INTERP_FUSE_BATCH, fo), 0);
    }
    long an = n_allocs, rssn = rss_kib();
    size_t bn = n_bytes;
    struct f4d_seq_key k;
    assert_int_equal(f4d_sequence_key(sq, 0, &k, &err), 0);
    assert_int_equal(k.t, steps - 1);
    assert_non_null(k.frame.motion_bwd); /* motion ran on the last step too */
    assert_int_equal(splat_frame_validate(&k.frame, &err), 0);
    printf("open: %ld allocations, %zu bytes (model arena %zu, sequence %zu)\n", a0 - a_open, b0 - b_open,
           model_arena_bytes(f4d_sequence_model(sq)), f4d_sequence_bytes(sq));
    printf("after 2 steps: %ld allocations, %zu bytes since open; rss %ld KiB\n", a2 - a0, b2 - b0, rss2);
    printf("after %ld steps: %ld allocations, %zu bytes since step 2; rss %ld KiB (%+ld)\n", steps, an - a2,
           bn - b2, rssn, rssn - rss2);
    assert_int_equal(a2 - a0, 0);  /* even the first pushes run on what open planned */
    assert_int_equal(an - a2, 0);
    assert_int_equal(bn - b2, 0);
    /* KiB: nothing grows; the resident set moves by a few pages (stacks,
     * libc) from run to run, +-128 KiB measured here */
    assert_true(rssn - rss2 <= 256);
    f4d_sequence_close(sq);
    fk_ctx_free(ctx);
    free(img[0]);
    free(img[1]);
}

int main(int argc, char **argv)
{
    argc = f4d_test_parse(argc, argv);
    if (argc != 3 || (steps = atol(argv[2])) < 3) {
        fprintf(stderr, "usage: test_sequence_mem GGUF_DIR STEPS (>= 3)\n");
        return 2;
    }
    gguf_dir = argv[1];
    const struct CMUnitTest tests[] = { cmocka_unit_test(flat) };
    return F4D_TEST_MAIN(argc, argv, "sequence_mem", tests, NULL, NULL);
}
