/* test_model_masked.c - foreground-only Eval (model_eval_masked) on the tiny
 * VGGT (fixtures/tiny, converted to f32 by the model_gguf ctest fixture).
 *
 *   test_model_masked FIXTURE_DIR GGUF_DIR
 *
 * - an all-ones keep-list gives model_eval's result bit for bit, and so does
 *   a masked first Eval or a masked Eval after a frame-size change (nothing
 *   to reuse: every patch runs);
 * - against the PyTorch reference (make_fixtures.py --masked-only): after a
 *   full Eval of s3/input, a masked Eval of masked_s3/input with view 0
 *   partly kept, view 1 empty (special tokens only) and view 2 all kept:
 *   every aggregator layer the heads read (kept rows computed on the kept
 *   set alone, dropped rows reused) and the heads' outputs;
 * - every view empty: the patch rows are the previous Eval's bit for bit,
 *   the token counts are the special tokens only, the hook sees the packed
 *   stream;
 * - with Forge4D's state / motion blocks (tiny_f4d_seq) the first two steps
 *   run every patch, later ones drop patches (test_stream_masking). */
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

/* f32 against the float64 reference, as test_model_parity holds it. */
static const double budget_f32 = 1e-4;

#define TS 3
#define TH 42
#define TW 70

struct fix {
    fk_ctx       *ctx;
    struct model *m;
    float        *prev, *img;   /* s3/input, masked_s3/input [3,3,42,70] */
    uint8_t       keep[TS * 15];
};

static void fix_open(struct fix *f, int prep_H, int prep_W)
{
    char path[2200];
    struct f4d_err err = {0};
    struct fk_ctx_config cc = { .isa = FK_ISA_AUTO, .threads = 2 };
    assert_int_equal(fk_ctx_new(&cc, &f->ctx), F4D_OK);
    snprintf(path, sizeof path, "%s/tiny_f32.gguf", gguf_dir);
    int rc = model_init(f->ctx, path, FK_W_F32, &f->m, &err);
    if (rc < 0)
        print_error("%s\n", err.msg);
    assert_int_equal(rc, 0);
    rc = model_prepare(f->m, TS, prep_H, prep_W);
    if (rc < 0)
        print_error("%s\n", model_error(f->m));
    assert_int_equal(rc, 0);
    int64_t sh[NPY_MAX_DIMS];
    int nd;
    f->prev = mt_npy_load(sh, &nd, "%s/tiny/s3/input.npy", fixture_dir);
    assert_true(nd == 4 && sh[0] == TS && sh[2] == TH && sh[3] == TW);
    f->img = mt_npy_load(sh, &nd, "%s/tiny/masked_s3/input.npy", fixture_dir);
    assert_true(nd == 4 && sh[0] == TS && sh[2] == TH && sh[3] == TW);
    float *k = mt_npy_load(sh, &nd, "%s/tiny/masked_s3/keep.npy", fixture_dir);
    assert_true(nd == 2 && sh[0] == TS && sh[1] == 15);
    for (int i = 0; i < TS * 15; i++)
        f->keep[i] = k[i] != 0.0f;
    free(k);
}

static void fix_close(struct fix *f)
{
    free(f->prev);
    free(f->img);
    model_free(f->m);
    fk_ctx_free(f->ctx);
}

static void eval_ok(struct model *m, const float *img, int S, int H, int W, const uint8_t *keep,
                    struct model_outputs *out)
{
    int rc = model_eval_masked(m, img, S, H, W, keep, out);
    if (rc < 0)
        print_error("%s\n", model_error(m));
    assert_int_equal(rc, 0);
}

/* Copies of every output and kept layer of the last Eval. */
struct snap {
    float *v[8];
    size_t n[8];
};

static void snap_take(struct snap *s, const struct model *m, const struct model_outputs *o)
{
    const struct model_config *c = model_get_config(m);
    const size_t S = (size_t)o->S, HW = (size_t)o->H * o->W;
    const size_t P1 = 1 + (size_t)c->num_register_tokens +
                      (size_t)(o->H / c->patch_size) * (size_t)(o->W / c->patch_size);
    const float *src[8] = { o->pose_enc, o->depth, o->depth_conf, o->world_points,
                            o->world_points_conf, model_layer(m, c->dpt_layer_idx[0]),
                            model_layer(m, c->dpt_layer_idx[2]), model_layer(m, c->depth - 1) };
    const size_t n[8] = { S * 9, S * HW, S * HW, S * HW * 3, S * HW, S * P1 * 2 * c->embed_dim,
                          S * P1 * 2 * c->embed_dim, S * P1 * 2 * c->embed_dim };
    for (int i = 0; i < 8; i++) {
        assert_non_null(src[i]);
        s->n[i] = n[i];
        s->v[i] = malloc(n[i] * sizeof(float));
        assert_non_null(s->v[i]);
        memcpy(s->v[i], src[i], n[i] * sizeof(float));
    }
}

static void snap_equal(const struct snap *a, const struct snap *b)
{
    for (int i = 0; i < 8; i++) {
        assert_int_equal(a->n[i], b->n[i]);
        assert_memory_equal(a->v[i], b->v[i], a->n[i] * sizeof(float));
    }
}

static void snap_free(struct snap *s)
{
    for (int i = 0; i < 8; i++)
        free(s->v[i]);
}

static void test_all_kept_is_plain(void **state)
{
    (void)state;
    struct fix f;
    fix_open(&f, TH, TW);
    struct model_outputs o;
    struct snap plain, a, first;
    uint8_t ones[TS * 15];
    memset(ones, 1, sizeof ones);

    /* masked first Eval: nothing to reuse, every patch runs */
    eval_ok(f.m, f.img, TS, TH, TW, f.keep, &o);
    assert_int_equal(o.masked, 0);
    assert_int_equal(o.total_tokens, TS * (3 + 15));
    snap_take(&first, f.m, &o);

    eval_ok(f.m, f.prev, TS, TH, TW, NULL, &o);   /* something else in between */
    eval_ok(f.m, f.img, TS, TH, TW, NULL, &o);
    assert_int_equal(o.masked, 0);
    for (int v = 0; v < TS; v++)
        assert_int_equal(o.view_tokens[v], 3 + 15);
    snap_take(&plain, f.m, &o);
    eval_ok(f.m, f.prev, TS, TH, TW, NULL, &o);
    eval_ok(f.m, f.img, TS, TH, TW, ones, &o);
    assert_int_equal(o.masked, 0);
    assert_int_equal(o.total_tokens, TS * (3 + 15));
    snap_take(&a, f.m, &o);
    snap_equal(&plain, &a);
    snap_equal(&plain, &first);
    snap_free(&plain);
    snap_free(&a);
    snap_free(&first);
    fix_close(&f);
}

/* The masked Eval against the reference's foreground-only run. */
static void test_masked_vs_reference(void **state)
{
    (void)state;
    struct fix f;
    fix_open(&f, TH, TW);
    const struct model_config *c = model_get_config(f.m);
    struct model_outputs o;
    eval_ok(f.m, f.prev, TS, TH, TW, NULL, &o);
    eval_ok(f.m, f.img, TS, TH, TW, f.keep, &o);
    assert_int_equal(o.masked, 1);
    const int ns = 1 + c->num_register_tokens;
    int total = 0;
    for (int v = 0; v < TS; v++) {
        int k = 0;
        for (int i = 0; i < 15; i++)
            k += f.keep[v * 15 + i];
        assert_int_equal(o.view_tokens[v], ns + k);
        total += ns + k;
    }
    assert_int_equal(o.view_tokens[1], ns); /* the empty view: specials only */
    assert_int_equal(o.total_tokens, total);

    char dir[1100];
    snprintf(dir, sizeof dir, "%s/tiny/masked_s3", fixture_dir);
    static struct mt_run r;
    memset(&r, 0, sizeof r);
    int seen[MODEL_LAYERS_MAX] = { 0 };
    for (int i = 0; i < 4; i++)
        seen[c->dpt_layer_idx[i]] = 1;
    seen[c->depth - 1] = 1;
    for (int l = 0; l < c->depth; l++)
        if (seen[l]) {
            char nm[32];
            snprintf(nm, sizeof nm, "layer%d", l);
            struct mt_ck *ck = mt_ck_add(&r, dir, nm, 0);
            assert_non_null(ck);
            mt_compare(ck, -1, model_layer(f.m, l), mt_numel(ck, 0));
        }
    static const char *outs[5] = { "pose_enc", "depth", "depth_conf", "world_points",
                                   "world_points_conf" };
    const float *ov[5] = { o.pose_enc, o.depth, o.depth_conf, o.world_points,
                           o.world_points_conf };
    for (int i = 0; i < 5; i++) {
        struct mt_ck *ck = mt_ck_add(&r, dir, outs[i], 0);
        assert_non_null(ck);
        mt_compare(ck, -1, ov[i], mt_numel(ck, 0));
    }
    for (int i = 0; i < r.n; i++)
        mt_check(&r.ck[i], "tiny masked S=3", budget_f32, 0);
    mt_run_free(&r);
    fix_close(&f);
}

struct hook_seen {
    int calls, tokens_arg, rows;
};

static int on_global(void *user, int layer, float *x, int S, int tokens, int C)
{
    (void)layer; (void)x; (void)S; (void)C;
    struct hook_seen *h = user;
    h->calls++;
    h->tokens_arg = tokens;
    return 0;
}

/* Every view empty: only special tokens run; the patch rows of every kept
 * layer are the previous Eval's, bit for bit. */
static void test_all_views_empty(void **state)
{
    (void)state;
    struct fix f;
    fix_open(&f, TH, TW);
    const struct model_config *c = model_get_config(f.m);
    const int ns = 1 + c->num_register_tokens, P1 = ns + 15, D = 2 * c->embed_dim;
    const int L = c->depth - 1;
    struct model_outputs o;
    eval_ok(f.m, f.prev, TS, TH, TW, NULL, &o);
    const size_t nl = (size_t)TS * P1 * D;
    float *before = malloc(nl * sizeof *before);
    assert_non_null(before);
    memcpy(before, model_layer(f.m, L), nl * sizeof *before);

    struct hook_seen hs = { 0, -1, 0 };
    struct model_hooks hk = { .after_global = on_global, .user = &hs };
    model_set_hooks(f.m, &hk);
    uint8_t none[TS * 15] = { 0 };
    eval_ok(f.m, f.img, TS, TH, TW, none, &o);
    assert_int_equal(o.masked, 1);
    assert_int_equal(o.total_tokens, TS * ns);
    assert_int_equal(hs.calls, c->depth);
    assert_int_equal(hs.tokens_arg, 0);
    const int *off;
    const int32_t *row;
    assert_int_equal(model_token_rows(f.m, &off, &row), TS * ns);
    for (int v = 0; v < TS; v++) {
        assert_int_equal(off[v], v * ns);
        for (int t = 0; t < ns; t++)
            assert_int_equal(row[v * ns + t], v * P1 + t);
    }
    const float *after = model_layer(f.m, L);
    int specials_changed = 0;
    for (int v = 0; v < TS; v++) {
        const size_t base = (size_t)v * P1 * D;
        assert_memory_equal(after + base + (size_t)ns * D, before + base + (size_t)ns * D,
                            (size_t)15 * D * sizeof(float));
        specials_changed |= memcmp(after + base, before + base, (size_t)ns * D * sizeof(float)) != 0;
    }
    /* the specials ran on a new input (views 1, 2 also see other views' specials) */
    assert_true(specials_changed);
    for (size_t i = 0; i < (size_t)TS * TH * TW; i++)
        assert_true(isfinite(o.depth[i]));
    model_set_hooks(f.m, NULL);
    free(before);
    fix_close(&f);
}

/* A frame-size change has nothing to reuse: the masked Eval runs every
 * patch (the plain Eval of that size, bit for bit). */
static void test_size_change_runs_all(void **state)
{
    (void)state;
    struct fix f;
    fix_open(&f, TH, TW);
    const int h2 = 28, w2 = 42; /* 2 x 3 patches: the top-left crop */
    float *small = malloc((size_t)TS * 3 * h2 * w2 * sizeof *small);
    assert_non_null(small);
    for (int i = 0; i < TS * 3; i++)
        for (int y = 0; y < h2; y++)
            memcpy(small + ((size_t)i * h2 + y) * w2, f.img + ((size_t)i * TH + y) * TW,
                   (size_t)w2 * sizeof *small);
    uint8_t keep[TS * 6] = { 1, 0, 0, 0, 0, 1 };
    struct model_outputs o;
    struct snap a, b;
    eval_ok(f.m, small, TS, h2, w2, NULL, &o);
    snap_take(&a, f.m, &o);
    eval_ok(f.m, f.prev, TS, TH, TW, NULL, &o);
    eval_ok(f.m, small, TS, h2, w2, keep, &o);
    assert_int_equal(o.masked, 0);
    snap_take(&b, f.m, &o);
    snap_equal(&a, &b);
    /* and the next one of the same size reuses */
    eval_ok(f.m, small, TS, h2, w2, keep, &o);
    assert_int_equal(o.masked, 1);
    assert_int_equal(o.total_tokens, 3 * TS + 2);
    snap_free(&a);
    snap_free(&b);
    free(small);
    fix_close(&f);
}

/* Forge4D state / motion blocks (tiny_f4d_seq: 2 views of 28x42, 2 x 3
 * patches): steps 1 and 2 run every patch whatever the keep-list (no step
 * that ran the motion yet), bit for bit model_eval's; from step 3 on a
 * partial keep-list drops patches (masked, the tokens that ran counted, M1 /
 * M2 exactly 0 at the dropped pixels) and an all-ones keep-list stays
 * model_eval's bit for bit. Parity of masked steps: model/forge4d_seq. */
static void test_stream_masking(void **state)
{
    (void)state;
    char path[2200];
    struct f4d_err err = {0};
    fk_ctx *ctx;
    struct fk_ctx_config cc = { .isa = FK_ISA_AUTO, .threads = 2 };
    struct model *m[3];
    struct model_outputs o[3];
    assert_int_equal(fk_ctx_new(&cc, &ctx), F4D_OK);
    snprintf(path, sizeof path, "%s/tiny_f4d_seq_f32.gguf", gguf_dir);
    enum { S = 2, H = 28, W = 42, P = 6 };
    float *img = malloc((size_t)S * 3 * H * W * sizeof *img);
    assert_non_null(img);
    uint8_t part[S * P] = { 1, 0, 0, 0, 0, 0 }, ones[S * P];
    memset(ones, 1, sizeof ones);
    const uint8_t *keeps[3] = { NULL, part, ones };
    for (int k = 0; k < 3; k++) {
        int rc = model_init(ctx, path, FK_W_F32, &m[k], &err);
        if (rc < 0)
            print_error("%s\n", err.msg);
        assert_int_equal(rc, 0);
        assert_int_equal(model_prepare(m[k], S, H, W), 0);
    }
    const size_t nd = (size_t)S * H * W * sizeof(float);
    for (int t = 0; t < 4; t++) {
        for (size_t i = 0; i < (size_t)S * 3 * H * W; i++)
            img[i] = (float)((i * 7 + (size_t)t * 13) % 97) / 97.0f;
        for (int k = 0; k < 3; k++) {
            int rc = model_eval_masked(m[k], img, S, H, W, keeps[k], &o[k]);
            if (rc < 0)
                print_error("%s\n", model_error(m[k]));
            assert_int_equal(rc, 0);
            assert_int_equal(o[k].step, t + 1);
            assert_int_equal(o[k].has_motion, t > 0);
        }
        assert_int_equal(o[1].masked, t >= 2);
        assert_int_equal(o[1].total_tokens, t >= 2 ? S * 3 + 1 : S * (3 + P));
        assert_int_equal(o[2].masked, 0);
        assert_memory_equal(o[0].depth, o[2].depth, nd);
        if (t > 0) {
            assert_memory_equal(o[0].motion_bwd, o[2].motion_bwd, 3 * nd);
            assert_memory_equal(o[0].motion_fwd_prev, o[2].motion_fwd_prev, 3 * nd);
        }
        if (t < 2) {
            assert_memory_equal(o[0].depth, o[1].depth, nd);
            continue;
        }
        /* kept: view 0's patch (0, 0), pixels y, x < 14; everything else is 0 */
        int nonzero_kept = 0;
        for (int f = 0; f < S; f++)
            for (int y = 0; y < H; y++)
                for (int x = 0; x < W; x++)
                    for (int ch = 0; ch < 3; ch++) {
                        size_t i = (((size_t)f * H + y) * W + x) * 3 + ch;
                        int kept = f == 0 && y < 14 && x < 14;
                        if (!kept) {
                            assert_true(o[1].motion_bwd[i] == 0.0f);
                            assert_true(o[1].motion_fwd_prev[i] == 0.0f);
                        } else {
                            nonzero_kept += o[1].motion_bwd[i] != 0.0f;
                        }
                    }
        assert_true(nonzero_kept > 0);
    }
    for (int k = 0; k < 3; k++)
        model_free(m[k]);
    free(img);
    fk_ctx_free(ctx);
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
        cmocka_unit_test(test_all_kept_is_plain),
        cmocka_unit_test(test_masked_vs_reference),
        cmocka_unit_test(test_all_views_empty),
        cmocka_unit_test(test_size_change_runs_all),
        cmocka_unit_test(test_stream_masking),
    };
    return cmocka_run_group_tests_name("/model/masked", tests, NULL, NULL);
}
