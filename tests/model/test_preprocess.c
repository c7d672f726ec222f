/* test_preprocess.c - preprocessing against PIL (fixtures/prep, made by
 * tools/reference/make_fixtures.py with VGGT's loader rules on small targets). */
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <cmocka.h>

#include "model_test_util.h"
#include "npy.h"
#include "preprocess.h"

static const char *fixdir;

struct img {
    uint8_t *px;
    int      w, h, c;
};

static struct img load_img(const char *name)
{
    int64_t sh[NPY_MAX_DIMS];
    int nd;
    float *a = mt_npy_load(sh, &nd, "%s/prep/%s.npy", fixdir, name);
    assert_int_equal(nd, 3);
    struct img im = { malloc((size_t)(sh[0] * sh[1] * sh[2])), (int)sh[1], (int)sh[0], (int)sh[2] };
    for (int64_t i = 0; i < sh[0] * sh[1] * sh[2]; i++)
        im.px[i] = (uint8_t)a[i];
    free(a);
    return im;
}

/* Largest |got - ref| in 8-bit steps; NaN when either side has a NaN or an
 * Inf (|Inf - x| = Inf, Inf - Inf = NaN), so `< tol` fails on them. */
static double max_err255(const float *got, const float *ref, size_t n)
{
    double d = 0;
    for (size_t i = 0; i < n; i++)
        d = mt_max_nan(d, fabs((double)got[i] - ref[i]) * 255.0);
    return d;
}

/* max |c - ref| in units of 1/255 */
static double diff255(const char *name, const float *got, int n, int H, int W)
{
    int64_t sh[NPY_MAX_DIMS];
    int nd;
    float *ref = mt_npy_load(sh, &nd, "%s/prep/%s.npy", fixdir, name);
    int64_t want = n > 1 ? sh[0] * sh[1] * sh[2] * sh[3] : sh[0] * sh[1] * sh[2];
    assert_int_equal(sh[nd - 2], H);
    assert_int_equal(sh[nd - 1], W);
    assert_int_equal(want, (int64_t)n * 3 * H * W);
    double d = max_err255(got, ref, (size_t)want);
    free(ref);
    return d;
}

static void check_case(const char *img_name, int mono)
{
    struct img im = load_img(img_name);
    for (int mode = PREP_CROP; mode <= PREP_PAD; mode++)
        for (int target = 28; target <= 56; target += 28) {
            size_t sb = prep_scratch_bytes(im.w, im.h, target);
            void *scratch = malloc(sb);
            float *out = malloc((size_t)3 * target * target * sizeof *out);
            struct prep_image pi = { im.px, im.w, im.h, (size_t)im.w * im.c,
                                     mono ? PREP_PIXFMT_MONO8 : PREP_PIXFMT_RGB8 };
            int ow, oh;
            char name[128];
            struct f4d_err err = {0};
            assert_int_equal(prep_image(&pi, (enum prep_mode)mode, target, scratch, sb, out, &ow,
                                        &oh, &err), 0);
            snprintf(name, sizeof name, "%s_%s%d", img_name, mode ? "pad" : "crop", target);
            double d = diff255(name, out, 1, oh, ow);
            printf("  %-24s %dx%d max diff %.3g / 255\n", name, ow, oh, d);
            /* PIL's exact 8-bit path: identical bytes, so only float rounding remains. */
            assert_true(d < 1e-3);
            free(scratch);
            free(out);
        }
    free(im.px);
}

static void test_rgb_crop_pad(void **s)
{
    (void)s;
    check_case("rgb_40x30", 0);
    check_case("rgb_100x77", 0);
    check_case("rgb_30x50", 0);
}

static void test_mono(void **s)
{
    (void)s;
    check_case("mono_45x33", 1);
}

static void test_batch_pads_to_largest(void **s)
{
    (void)s;
    struct img a = load_img("rgb_40x30"), b = load_img("rgb_30x50");
    struct prep_image ims[2] = {
        { a.px, a.w, a.h, (size_t)a.w * 3, PREP_PIXFMT_RGB8 },
        { b.px, b.w, b.h, (size_t)b.w * 3, PREP_PIXFMT_RGB8 },
    };
    size_t sb = prep_scratch_bytes(40, 30, 56);
    size_t sb2 = prep_scratch_bytes(30, 50, 56);
    sb = sb > sb2 ? sb : sb2;
    void *scratch = malloc(sb);
    float *out = malloc((size_t)2 * 3 * 56 * 56 * sizeof *out);
    int H, W;
    struct f4d_err err = {0};
    assert_int_equal(prep_batch(ims, 2, PREP_CROP, 56, scratch, sb, out, &H, &W, &err), 0);
    assert_int_equal(H, 56);
    assert_int_equal(W, 56);
    assert_true(diff255("batch_crop56", out, 2, H, W) < 1e-3);
    /* too little scratch is refused by name */
    assert_int_equal(prep_batch(ims, 2, PREP_CROP, 56, scratch, 100, out, &H, &W, &err), -1);
    assert_non_null(strstr(err.msg, "scratch"));
    free(scratch);
    free(out);
    free(a.px);
    free(b.px);
}

/* Bayer RGGB: a mosaic of a flat colour demosaics to that colour; a mosaic
 * made from an RGB image keeps every sampled value where it was sampled. */
static void test_bayer(void **s)
{
    (void)s;
    enum { W = 16, H = 12 };
    uint8_t mos[H * W], rgb[H * W * 3];
    for (int y = 0; y < H; y++)
        for (int x = 0; x < W; x++)
            mos[y * W + x] = !(y & 1) && !(x & 1) ? 200 : (y & 1) && (x & 1) ? 30 : 120;
    prep_demosaic_rggb(mos, W, W, H, rgb);
    for (int i = 0; i < W * H; i++) {
        assert_int_equal(rgb[3 * i], 200);
        assert_int_equal(rgb[3 * i + 1], 120);
        assert_int_equal(rgb[3 * i + 2], 30);
    }
    /* through the whole path: equals the RGB8 path of the flat image */
    uint8_t flat[H * W * 3];
    for (int i = 0; i < W * H; i++) {
        flat[3 * i] = 200;
        flat[3 * i + 1] = 120;
        flat[3 * i + 2] = 30;
    }
    struct prep_image bi = { mos, W, H, W, PREP_PIXFMT_BAYER_RG8 };
    struct prep_image ri = { flat, W, H, W * 3, PREP_PIXFMT_RGB8 };
    size_t sb = prep_scratch_bytes(W, H, 28);
    void *scratch = malloc(sb);
    float o1[3 * 28 * 28], o2[3 * 28 * 28];
    int ow, oh;
    struct f4d_err err = {0};
    assert_int_equal(prep_image(&bi, PREP_PAD, 28, scratch, sb, o1, &ow, &oh, &err), 0);
    assert_int_equal(prep_image(&ri, PREP_PAD, 28, scratch, sb, o2, &ow, &oh, &err), 0);
    assert_memory_equal(o1, o2, sizeof o1);
    /* unknown formats are refused */
    struct prep_image bad = { flat, W, H, W * 3, 5 };
    assert_int_equal(prep_image(&bad, PREP_PAD, 28, scratch, sb, o1, &ow, &oh, &err), -1);
    assert_non_null(strstr(err.msg, "pixel format"));
    free(scratch);
}

/* Output sizes follow the loader's rounding (half to even) at 518. */
static void test_sizes_518(void **s)
{
    (void)s;
    int ow, oh;
    assert_int_equal(prep_output_size(640, 480, PREP_CROP, 518, &ow, &oh), 0);
    assert_int_equal(ow, 518);
    assert_int_equal(oh, 392);          /* 4:3 landscape */
    assert_int_equal(prep_output_size(480, 640, PREP_CROP, 518, &ow, &oh), 0);
    assert_int_equal(oh, 518);          /* 690 rows, centre-cropped */
    assert_int_equal(prep_output_size(480, 640, PREP_PAD, 518, &ow, &oh), 0);
    assert_int_equal(ow, 518);
    assert_int_equal(oh, 518);
    /* 518 * 259 / 518 / 14 = 18.5 -> 18 (half to even) -> 252 */
    assert_int_equal(prep_output_size(518, 259, PREP_CROP, 518, &ow, &oh), 0);
    assert_int_equal(oh, 252);
    assert_int_equal(prep_output_size(0, 10, PREP_CROP, 518, &ow, &oh), -1);
}

/* The comparison fails on non-finite output: all NaN, or one Inf. */
static void test_compare_fails_on_nan(void **state)
{
    (void)state;
    float ref[8], got[8];
    for (int i = 0; i < 8; i++) {
        ref[i] = (float)i / 8.0f;
        got[i] = NAN;
    }
    assert_false(max_err255(got, ref, 8) < 0.5);
    memcpy(got, ref, sizeof got);
    assert_true(max_err255(got, ref, 8) == 0.0);
    got[3] = INFINITY;
    assert_false(max_err255(got, ref, 8) < 0.5);
    got[3] = ref[3];
    got[7] = NAN;
    assert_false(max_err255(got, ref, 8) < 0.5);
}

int main(int argc, char **argv)
{
    if (argc != 2) {
        fprintf(stderr, "usage: %s FIXTURE_DIR\n", argv[0]);
        return 2;
    }
    fixdir = argv[1];
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_compare_fails_on_nan),
        cmocka_unit_test(test_rgb_crop_pad),
        cmocka_unit_test(test_mono),
        cmocka_unit_test(test_batch_pads_to_largest),
        cmocka_unit_test(test_bayer),
        cmocka_unit_test(test_sizes_518),
    };
    return cmocka_run_group_tests_name("/model/preprocess", tests, NULL, NULL);
}
