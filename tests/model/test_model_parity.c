/* test_model_parity.c - the C model against the PyTorch reference fixtures
 * (tools/reference/make_fixtures.py) at every checkpoint, in f32, f16, int8.
 *
 *   test_model_parity FIXTURE_DIR GGUF_DIR
 *
 * GGUF_DIR holds <config>_<type>.gguf written by f4d-convert (ctest fixtures).
 * Error of a checkpoint = max |c - ref| / max |ref| over the whole tensor. */
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <cmocka.h>

#include "fk_ctx.h"
#include "model.h"
#include "model_test_util.h"
#include "npy.h"

static const char *fixture_dir, *gguf_dir;

/* Budgets per precision (f32 from the issue; f16 / int8 measured on these
 * fixtures with margin: f16 ~1e-3, int8 ~2e-2 at the heads, see the report). */
static const double budget_f32 = 1e-4, budget_f16 = 5e-3, budget_int8 = 8e-2;

static void on_tap(void *user, const char *name, int frame, const float *data, size_t count)
{
    struct mt_run *r = user;
    char nm[64];
    /* camera_iter<i> compares with pose_enc_list[i] */
    if (!strncmp(name, "camera_iter", 11)) {
        for (int i = 0; i < r->n; i++)
            if (!strcmp(r->ck[i].name, "pose_enc_list")) {
                struct mt_ck *c = &r->ck[i];
                int it = atoi(name + 11);
                size_t per = mt_numel(c, 1);
                struct mt_ck tmp = *c;
                tmp.ref = c->ref + (size_t)it * per;
                tmp.nd = c->nd - 1;
                memmove(tmp.shape, c->shape + 1, sizeof(int64_t) * (size_t)tmp.nd);
                tmp.max_diff = c->max_diff;
                tmp.max_ref = c->max_ref;
                mt_compare(&tmp, -1, data, count);
                c->max_diff = tmp.max_diff;
                c->max_ref = tmp.max_ref;
                c->seen = 1;
            }
        return;
    }
    snprintf(nm, sizeof nm, "%s", name);
    struct mt_ck *c = mt_ck_find(r, nm);
    if (c)
        mt_compare(c, frame, data, count);
}

/* Runs one fixture set with one precision; returns the worst relative error. */
static double run_fixture(const char *cfg, int S, const char *type, enum fk_wtype wt,
                          double budget, int prep_S, int prep_H, int prep_W)
{
    char dir[1024], path[2200];
    struct f4d_err err = {0};
    snprintf(dir, sizeof dir, "%s/%s/s%d", fixture_dir, cfg, S);
    snprintf(path, sizeof path, "%s/%s_%s.gguf", gguf_dir, cfg, type);
    fk_ctx *ctx;
    struct fk_ctx_config cc = { .isa = FK_ISA_AUTO, .threads = 2 };
    assert_int_equal(fk_ctx_new(&cc, &ctx), F4D_OK);
    struct model *m = NULL;
    int rc = model_init(ctx, path, wt, &m, &err);
    if (rc < 0)
        print_error("%s\n", err.msg);
    assert_int_equal(rc, 0);
    const struct model_config *mc = model_get_config(m);
    rc = model_prepare(m, prep_S, prep_H, prep_W);
    if (rc < 0)
        print_error("%s\n", model_error(m));
    assert_int_equal(rc, 0);

    static struct mt_run r;
    memset(&r, 0, sizeof r);
    int64_t ish[NPY_MAX_DIMS];
    int ind;
    float *img = mt_npy_load(ish, &ind, "%s/input.npy", dir);
    assert_int_equal(ind, 4);
    assert_int_equal(ish[0], S);
    const int H = (int)ish[2], W = (int)ish[3];
    assert_non_null(mt_ck_add(&r, dir, "patch_embed", 0));
    int seen_layer[MODEL_LAYERS_MAX] = { 0 };
    for (int i = 0; i < 4; i++)
        seen_layer[mc->dpt_layer_idx[i]] = 1;
    seen_layer[mc->depth - 1] = 1;
    for (int l = 0; l < mc->depth; l++)
        if (seen_layer[l]) {
            char nm[32];
            snprintf(nm, sizeof nm, "layer%d", l);
            assert_non_null(mt_ck_add(&r, dir, nm, 0));
        }
    assert_non_null(mt_ck_add(&r, dir, "pose_enc_list", 0));
    static const char *heads[2] = { "depth_head", "point_head" };
    for (int hd = 0; hd < 2; hd++) {
        char nm[64];
        for (int l = 0; l < 4; l++) {
            snprintf(nm, sizeof nm, "%s.level%d", heads[hd], l);
            assert_non_null(mt_ck_add(&r, dir, nm, 1));
        }
        snprintf(nm, sizeof nm, "%s.fused", heads[hd]);
        assert_non_null(mt_ck_add(&r, dir, nm, 1));
    }
    int first_out = r.n;
    static const char *outs[7] = { "pose_enc", "extrinsic", "intrinsic", "depth", "depth_conf",
                                   "world_points", "world_points_conf" };
    for (int i = 0; i < 7; i++)
        assert_non_null(mt_ck_add(&r, dir, outs[i], 0));

    model_set_tap(m, on_tap, &r);
    struct model_outputs out;
    rc = model_eval(m, img, S, H, W, &out);
    if (rc < 0)
        print_error("%s\n", model_error(m));
    assert_int_equal(rc, 0);
    assert_non_null(out.pose_enc);
    assert_non_null(out.depth);
    assert_non_null(out.world_points);
    const float *o[7] = { out.pose_enc, out.extrinsic, out.intrinsic, out.depth, out.depth_conf,
                          out.world_points, out.world_points_conf };
    for (int i = 0; i < 7; i++)
        mt_compare(&r.ck[first_out + i], -1, o[i], mt_numel(&r.ck[first_out + i], 0));

    double worst = 0;
    char tag[48];
    snprintf(tag, sizeof tag, "%-10s %-5s S=%d", cfg, type, S);
    for (int i = 0; i < r.n; i++) {
        worst = mt_max_nan(worst, mt_check(&r.ck[i], tag, budget, 0));
        free(r.ck[i].ref);
    }
    printf("  %-10s %-5s S=%d worst %.3e (budget %.0e), arena %zu bytes\n", cfg, type, S, worst,
           budget, model_arena_bytes(m));
    free(img);
    model_free(m);
    fk_ctx_free(ctx);
    assert_true(worst <= budget);
    return worst;
}

static void test_tiny_f32(void **state)
{
    (void)state;
    for (int S = 1; S <= 4; S++)
        if (S != 2)
            run_fixture("tiny", S, "f32", FK_W_F32, budget_f32, 4, 42, 70);
}

static void test_tiny_conv_f32(void **state)
{
    (void)state;
    run_fixture("tiny_conv", 2, "f32", FK_W_F32, budget_f32, 2, 42, 42);
}

static void test_tiny_f16(void **state)
{
    (void)state;
    run_fixture("tiny", 3, "f16", FK_W_F16, budget_f16, 4, 42, 70);
}

static void test_tiny_int8(void **state)
{
    (void)state;
    run_fixture("tiny", 3, "int8", FK_W_Q8, budget_int8, 4, 42, 70);
}

/* An f32 file packed as int8 at load gives the same budget as an int8 file. */
static void test_tiny_f32_file_as_int8(void **state)
{
    (void)state;
    run_fixture("tiny", 4, "f32", FK_W_Q8, budget_int8, 4, 42, 70);
}

/* The arena planned for a bigger set serves a smaller one; a larger set is
 * refused by name. Prepare reserves the kernel scratch and freezes the
 * context: the first Eval, at the largest planned size, runs frozen. */
static void test_arena_bounds(void **state)
{
    (void)state;
    char path[1024];
    struct f4d_err err = {0};
    snprintf(path, sizeof path, "%s/tiny_f32.gguf", gguf_dir);
    fk_ctx *ctx;
    struct fk_ctx_config cc = { .isa = FK_ISA_AUTO, .threads = 2 };
    assert_int_equal(fk_ctx_new(&cc, &ctx), F4D_OK);
    struct model *m;
    assert_int_equal(model_init(ctx, path, FK_W_F32, &m, &err), 0);
    assert_int_equal(model_prepare(m, 2, 42, 70), 0);
    const struct model_config *c = model_get_config(m);
    assert_int_equal(model_arena_bytes(m), model_plan_bytes(c, MODEL_G_VGGT, 2, 42, 70));
    float *img = calloc((size_t)3 * 3 * 42 * 70, sizeof *img);
    for (size_t i = 0; i < (size_t)3 * 3 * 42 * 70; i++)
        img[i] = (float)(i % 97) / 97.0f;
    struct model_outputs out;
    size_t scratch = fk_ctx_scratch_bytes(ctx);
    assert_true(scratch > 0);
    /* frozen by Prepare: growing the scratch is refused */
    assert_int_equal(fk_ctx_reserve(ctx, 2 * scratch, 0), F4D_ENOMEM);
    fk_ctx_freeze(ctx, 1); /* (also when Prepare forgot to) */
    if (model_eval(m, img, 2, 42, 70, &out) != 0)
        fail_msg("first Eval after Prepare, frozen: %s", model_error(m));
    assert_int_equal(model_eval(m, img, 1, 28, 56, &out), 0);
    assert_int_equal(model_eval(m, img, 1, 42, 14, &out), 0);
    assert_int_equal(model_eval(m, img, 2, 14, 70, &out), 0);
    assert_int_equal(model_eval(m, img, 2, 42, 70, &out), 0);
    assert_int_equal(fk_ctx_scratch_bytes(ctx), scratch);
    assert_int_equal(model_eval(m, img, 3, 42, 70, &out), F4D_EINVAL);
    assert_non_null(strstr(model_error(m), "3 views of 70x42 exceed the 2 views of 70x42"));
    assert_int_equal(model_eval(m, img, 1, 42, 71, &out), F4D_EINVAL);
    assert_non_null(strstr(model_error(m), "multiple of the patch"));
    /* Wider than planned, even when smaller in total: refused (the kernel
     * scratch reserved at Prepare grows with each dimension). */
    assert_int_equal(model_eval(m, img, 1, 28, 84, &out), F4D_EINVAL);
    assert_non_null(strstr(model_error(m), "1 views of 84x28 exceed"));
    assert_int_equal(model_eval(m, img, 1, 42, 126, &out), F4D_EINVAL);
    assert_int_equal(fk_ctx_scratch_bytes(ctx), scratch);
    free(img);
    model_free(m);
    /* model_free thaws the context it froze */
    assert_int_equal(fk_ctx_reserve(ctx, 2 * scratch, 0), F4D_OK);
    fk_ctx_free(ctx);
}

static double npy_rel(const char *a_path, const char *b_path, int64_t *shape, int *nd)
{
    struct f4d_err err = {0};
    float *a, *b;
    int64_t sb[NPY_MAX_DIMS];
    int nb;
    if (npy_load_f32(a_path, &a, shape, nd, &err) < 0) {
        print_error("%s\n", err.msg);
        return INFINITY;
    }
    if (npy_load_f32(b_path, &b, sb, &nb, &err) < 0) {
        print_error("%s\n", err.msg);
        free(a);
        return INFINITY;
    }
    size_t n = 1;
    int same = nb == *nd;
    for (int i = 0; i < *nd; i++) {
        same = same && sb[i] == shape[i];
        n *= (size_t)shape[i];
    }
    double e = same ? mt_arr_rel(a, b, n) : INFINITY;
    free(a);
    free(b);
    return e;
}

/* f4d-infer's files (ctest model/infer_raw, model/infer_png). */
static void test_infer_outputs(void **state)
{
    (void)state;
    static const char *outs[7] = { "pose_enc", "extrinsic", "intrinsic", "depth", "depth_conf",
                                   "world_points", "world_points_conf" };
    char a[2200], b[2200];
    int64_t sh[NPY_MAX_DIMS];
    int nd;
    for (int i = 0; i < 7; i++) {
        snprintf(a, sizeof a, "%s/infer_raw/%s.npy", gguf_dir, outs[i]);
        snprintf(b, sizeof b, "%s/tiny/s3/%s.npy", fixture_dir, outs[i]);
        double e = npy_rel(a, b, sh, &nd);
        printf("  f4d-infer raw %-18s rel_err %.3e\n", outs[i], e);
        assert_true(e <= budget_f32);
    }
    /* PNG -> preprocessing -> input.npy equals PIL's batch; outputs have the shapes */
    snprintf(a, sizeof a, "%s/infer_png/input.npy", gguf_dir);
    snprintf(b, sizeof b, "%s/prep/batch_crop56.npy", fixture_dir);
    assert_true(npy_rel(a, b, sh, &nd) < 1e-6);
    /* f4d-infer's depth against this process's own Eval of PIL's batch (the
     * fixture), same weights and precision: an independent computation of
     * the same numbers, up to threading order */
    struct f4d_err err = {0};
    float *batch, *depth;
    int64_t bsh[NPY_MAX_DIMS];
    int bnd;
    snprintf(b, sizeof b, "%s/prep/batch_crop56.npy", fixture_dir);
    assert_int_equal(npy_load_f32(b, &batch, bsh, &bnd, &err), 0);
    snprintf(a, sizeof a, "%s/infer_png/depth.npy", gguf_dir);
    assert_int_equal(npy_load_f32(a, &depth, sh, &nd, &err), 0);
    assert_int_equal(nd, 4);
    assert_int_equal(sh[0], 2);
    assert_int_equal(sh[1], 56);
    assert_int_equal(sh[2], 56);
    assert_int_equal(sh[3], 1);
    fk_ctx *ctx;
    struct fk_ctx_config cc = { .isa = FK_ISA_AUTO, .threads = 2 };
    assert_int_equal(fk_ctx_new(&cc, &ctx), F4D_OK);
    struct model *m;
    snprintf(b, sizeof b, "%s/tiny_int8.gguf", gguf_dir);
    assert_int_equal(model_init(ctx, b, FK_W_Q8, &m, &err), 0);
    assert_int_equal(model_prepare(m, 2, 56, 56), 0);
    struct model_outputs out;
    assert_int_equal(model_eval(m, batch, 2, 56, 56, &out), 0);
    assert_non_null(out.depth);
    double e = mt_arr_rel(depth, out.depth, (size_t)2 * 56 * 56);
    double dmax = 0;
    for (size_t i = 0; i < (size_t)2 * 56 * 56; i++)
        dmax = mt_max_nan(dmax, fabs((double)out.depth[i]));
    printf("  f4d-infer png depth vs in-process eval rel_err %.3e (max depth %.3g)\n", e, dmax);
    assert_true(dmax > 0);   /* a real depth map, not zeros */
    assert_true(e <= 1e-5);
    model_free(m);
    fk_ctx_free(ctx);
    free(batch);
    free(depth);
}

/* The comparison helpers fail on non-finite output (all NaN, one Inf). */
static void test_compare_fails_on_nan(void **state)
{
    (void)state;
    float ref[16], got[16];
    for (int i = 0; i < 16; i++) {
        ref[i] = 1.0f + (float)i;
        got[i] = NAN;
    }
    assert_false(mt_arr_rel(got, ref, 16) <= 1.0);
    assert_false(mt_arr_rel(ref, got, 16) <= 1.0);
    memcpy(got, ref, sizeof got);
    assert_true(mt_arr_rel(got, ref, 16) == 0.0);
    got[5] = INFINITY;
    assert_false(mt_arr_rel(got, ref, 16) <= 1.0);
    ref[5] = INFINITY;
    assert_false(mt_arr_rel(got, ref, 16) <= 1.0);
    /* the tap comparison: all-NaN data against a finite fixture */
    for (int i = 0; i < 16; i++) {
        ref[i] = 1.0f + (float)i;
        got[i] = NAN;
    }
    struct mt_ck c;
    mt_ck_wrap(&c, ref, 16);
    mt_compare(&c, -1, got, 16);
    assert_false(mt_rel(&c) <= budget_int8);
    got[0] = ref[0];
    mt_ck_wrap(&c, ref, 16);
    memcpy(got, ref, sizeof got);
    mt_compare(&c, -1, got, 16);
    assert_true(mt_rel(&c) == 0.0);
}

int main(int argc, char **argv)
{
    if (argc != 3) {
        fprintf(stderr, "usage: %s FIXTURE_DIR GGUF_DIR\n", argv[0]);
        return 2;
    }
    fixture_dir = argv[1];
    gguf_dir = argv[2];
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_compare_fails_on_nan),
        cmocka_unit_test(test_tiny_f32),
        cmocka_unit_test(test_tiny_conv_f32),
        cmocka_unit_test(test_tiny_f16),
        cmocka_unit_test(test_tiny_int8),
        cmocka_unit_test(test_tiny_f32_file_as_int8),
        cmocka_unit_test(test_arena_bounds),
        cmocka_unit_test(test_infer_outputs),
    };
    return cmocka_run_group_tests_name("/model/parity", tests, NULL, NULL);
}
