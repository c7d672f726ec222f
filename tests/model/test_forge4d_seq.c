/* test_forge4d_seq.c - Forge4D's state blocks, motion blocks, motion head and
 * fusion MLP (forge4d-arch.md 4-6) against the PyTorch reference over a
 * sequence of time steps (tools/reference/forge4d_ref.py via make_fixtures.py,
 * fixtures/tiny_f4d_seq/: 4 steps of 2 views at 28x42, every LayerScale and
 * zero-initialised last layer nonzero so that nothing is the identity).
 *
 *   test_forge4d_seq FIXTURE_DIR GGUF_DIR
 *
 * GGUF_DIR holds tiny_f4d_seq_<type>.gguf, tiny_f4d_f32.gguf and tiny_f32.gguf
 * (f4d-convert, ctest fixtures). Error of a checkpoint = max |c - ref| /
 * max |ref| over the whole tensor, NaN-aware (model_test_util.h). Per step:
 * the kept aggregator layers (state blocks included), every layer's state,
 * gauge, metric Gaussian positions and scales, and from the second step on
 * the motion streams at the DPT layers of both runs, M1[t] / M2[t-1] in model
 * units (taps) and metric (outputs). Drift: the worst error of the last step
 * stays within twice that of the second step (the first with motion) plus a
 * small floor, so errors do not compound through the carried state.
 * Hard cases, a test each: zero-motion weights give exactly 0, the first step
 * (and a changed frame size) has no motion, model_state_reset reproduces the
 * first step bit for bit, checkpoints without the stage-2/3 parts run as
 * before (VGGT, stage 1). */
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <cmocka.h>

#include "fk_ctx.h"
#include "gguf.h"
#include "interp.h"
#include "model.h"
#include "model_test_util.h"
#include "npy.h"

static const char *fixture_dir, *gguf_dir;

enum { SEQ_T = 4, SEQ_S = 2, SEQ_H = 28, SEQ_W = 42, N_PAIRS = 64 };

/* f32 from the issue. f16 / int8 measured on this fixture (worst over the
 * steps, printed per step) and set with margin (f16 worst 1.2e-3, int8
 * 5.0e-2 outside the scales; scales 6.2e-3 and 8.1e-2). The Gaussian scales carry
 * the point head's error through the view depth z = R X + T, where terms
 * cancel (as in test_forge4d.c): they get their own budget. The drift floor
 * is an absolute term for steps whose error is already tiny. */
static const double budget_f32 = 1e-4, budget_f16 = 5e-3, budget_int8 = 8e-2,
                    drift_floor = 1e-6;
static const double budget_f16_scale = 1.5e-2, budget_int8_scale = 1.5e-1;

static double ck_budget(const char *name, double base)
{
    if (!strcmp(name, "gaussians_scale"))
        return base == budget_f16 ? budget_f16_scale : base == budget_int8 ? budget_int8_scale : base;
    return base;
}

static fk_ctx *new_ctx(void)
{
    fk_ctx *ctx;
    struct fk_ctx_config cc = { .isa = FK_ISA_AUTO, .threads = 2 };
    assert_int_equal(fk_ctx_new(&cc, &ctx), F4D_OK);
    return ctx;
}

static float *load_input_in(const char *sub, int t)
{
    int64_t sh[NPY_MAX_DIMS];
    int nd;
    float *img = mt_npy_load(sh, &nd, "%s/tiny_f4d_seq/%st%d/input.npy", fixture_dir, sub, t);
    assert_int_equal(nd, 4);
    assert_int_equal(sh[0], SEQ_S);
    assert_int_equal(sh[2], SEQ_H);
    assert_int_equal(sh[3], SEQ_W);
    return img;
}

static float *load_input(int t)
{
    return load_input_in("", t);
}

static struct model *open_model(fk_ctx *ctx, const char *file, enum fk_wtype wt)
{
    char path[1200];
    struct f4d_err err = {0};
    struct model *m = NULL;
    snprintf(path, sizeof path, "%s/%s", gguf_dir, file);
    if (model_init(ctx, path, wt, &m, &err) < 0)
        fail_msg("%s: %s", path, err.msg);
    if (model_prepare(m, SEQ_S, SEQ_H, SEQ_W) < 0)
        fail_msg("%s", model_error(m));
    return m;
}

static void on_tap(void *user, const char *name, int frame, const float *data, size_t count)
{
    struct mt_ck *c = mt_ck_find(user, name);
    if (c)
        mt_compare(c, frame, data, count);
}

static void compare_outputs(struct mt_run *r, const struct model_outputs *o)
{
    const size_t n = (size_t)o->S * o->H * o->W;
    const struct mt_out outs[] = {
        { "gauge", &o->gauge, 1 },
        { "gaussians_pos", o->gaussians.pos, 3 * n },
        { "gaussians_scale", o->gaussians.scale, 3 * n },
        { "motion_bwd", o->motion_bwd, 3 * n },
        { "motion_fwd_prev", o->motion_fwd_prev, 3 * n },
    };
    mt_compare_outs(r, outs, sizeof outs / sizeof outs[0]);
}

/* The checkpoints of step t (in tiny_f4d_seq/<sub>t<t>); motion from step 1. */
static void add_step_in(struct mt_run *r, const struct model_config *c, const char *sub, int t)
{
    char dir[1200], nm[64];
    snprintf(dir, sizeof dir, "%s/tiny_f4d_seq/%st%d", fixture_dir, sub, t);
    uint64_t kept = UINT64_C(1) << (c->depth - 1);
    for (int i = 0; i < 4; i++)
        kept |= UINT64_C(1) << c->dpt_layer_idx[i];
    for (int l = 0; l < c->depth; l++) {
        snprintf(nm, sizeof nm, "state%d", l);
        assert_non_null(mt_ck_add(r, dir, nm, 0));
        if (kept >> l & 1) {
            snprintf(nm, sizeof nm, "layer%d", l);
            assert_non_null(mt_ck_add(r, dir, nm, 0));
        }
    }
    static const char *plain[] = { "gauge", "gaussians_pos", "gaussians_scale" };
    for (size_t i = 0; i < sizeof plain / sizeof plain[0]; i++)
        assert_non_null(mt_ck_add(r, dir, plain[i], 0));
    if (t == 0)
        return;
    for (int run = 0; run < 2; run++)
        for (int i = 0; i < 4; i++) {
            snprintf(nm, sizeof nm, "motion.m%dh%d", run + 1, c->dpt_layer_idx[i]);
            if (!mt_ck_find(r, nm))
                assert_non_null(mt_ck_add(r, dir, nm, 0));
        }
    static const char *motion[] = { "motion_head.m1", "motion_head.m2", "motion_bwd",
                                    "motion_fwd_prev" };
    for (size_t i = 0; i < sizeof motion / sizeof motion[0]; i++)
        assert_non_null(mt_ck_add(r, dir, motion[i], 0));
}

static void add_step(struct mt_run *r, const struct model_config *c, int t)
{
    add_step_in(r, c, "", t);
}

/* Prints and asserts every checkpoint of a step; returns the worst. */
static double report(struct mt_run *r, const char *tag, int t, double budget)
{
    double worst = 0, worst_sc = 0;
    const char *wn = "-";
    char tt[48];
    snprintf(tt, sizeof tt, "%-12s t%d", tag, t);
    for (int i = 0; i < r->n; i++) {
        struct mt_ck *c = &r->ck[i];
        double e = mt_check(c, tt, ck_budget(c->name, budget), 1);
        if (!strcmp(c->name, "gaussians_scale")) {
            worst_sc = mt_max_nan(worst_sc, e);
            continue;
        }
        if (!(e <= worst))
            wn = c->name;
        worst = mt_max_nan(worst, e);
    }
    printf("  %-12s t%d: %2d checkpoints, worst rel_err %.3e (%s; budget %.1e), "
           "gaussians_scale %.3e (budget %.1e)\n", tag, t, r->n, worst, wn, budget, worst_sc,
           ck_budget("gaussians_scale", budget));
    return mt_max_nan(worst, worst_sc);
}

/* ---- parity over the sequence ------------------------------------------ */

static void run_sequence(const char *type, enum fk_wtype wt, double budget)
{
    char file[64], tag[32];
    snprintf(file, sizeof file, "tiny_f4d_seq_%s.gguf", type);
    snprintf(tag, sizeof tag, "seq %s", type);
    fk_ctx *ctx = new_ctx();
    struct model *m = open_model(ctx, file, wt);
    const struct model_config *c = model_get_config(m);
    assert_int_equal(model_groups(m), MODEL_G_ALL);
    /* one arena, as planned from the groups without weights */
    assert_int_equal(model_arena_bytes(m),
                     model_plan_bytes(c, MODEL_G_ALL, SEQ_S, SEQ_H, SEQ_W));
    double worst[SEQ_T];
    static struct mt_run r;
    for (int t = 0; t < SEQ_T; t++) {
        memset(&r, 0, sizeof r);
        add_step(&r, c, t);
        model_set_tap(m, on_tap, &r);
        float *img = load_input(t);
        struct model_outputs out;
        if (model_eval(m, img, SEQ_S, SEQ_H, SEQ_W, &out) < 0)
            fail_msg("t%d: %s", t, model_error(m));
        assert_int_equal(out.step, t + 1);
        assert_int_equal(out.has_motion, t > 0);
        assert_true(out.has_gauge);
        compare_outputs(&r, &out);
        worst[t] = report(&r, tag, t, budget);
        mt_run_free(&r);
        free(img);
    }
    printf("  %-12s drift: worst t3 %.3e <= 2 x t1 %.3e + %.0e\n", tag, worst[3], worst[1],
           drift_floor);
    assert_true(worst[3] <= 2.0 * worst[1] + drift_floor);
    model_free(m);
    fk_ctx_free(ctx);
}

static void test_seq_f32(void **state)
{
    (void)state;
    run_sequence("f32", FK_W_F32, budget_f32);
}

static void test_seq_f16(void **state)
{
    (void)state;
    run_sequence("f16", FK_W_F16, budget_f16);
}

static void test_seq_int8(void **state)
{
    (void)state;
    run_sequence("int8", FK_W_Q8, budget_int8);
}

/* ---- masked steps (model_eval_masked with state and motion blocks) ------ */

/* fixtures/tiny_f4d_seq/masked: 5 steps with a keep-list each (Forge4D.step_masked
 * of forge4d_ref.py): steps 0 and 1 run every patch (no step that ran the motion
 * yet), then a partial + an empty view, an empty + a partial view, two partial
 * views. Every checkpoint of every step: the kept layers (reused rows included),
 * the state written from the kept tokens, the full-grid motion streams (dropped
 * rows the last step's), M1 / M2 with the dropped patches' pixels at 0. */
enum { MASK_T = 5, MASK_P = 6 };

static void run_masked_sequence(const char *type, enum fk_wtype wt, double budget)
{
    char file[64], tag[32];
    snprintf(file, sizeof file, "tiny_f4d_seq_%s.gguf", type);
    snprintf(tag, sizeof tag, "masked %s", type);
    fk_ctx *ctx = new_ctx();
    struct model *m = open_model(ctx, file, wt);
    const struct model_config *c = model_get_config(m);
    static struct mt_run r;
    for (int t = 0; t < MASK_T; t++) {
        memset(&r, 0, sizeof r);
        add_step_in(&r, c, "masked/", t);
        model_set_tap(m, on_tap, &r);
        float *img = load_input_in("masked/", t);
        int64_t sh[NPY_MAX_DIMS];
        int nd;
        float *kf = mt_npy_load(sh, &nd, "%s/tiny_f4d_seq/masked/t%d/keep.npy", fixture_dir, t);
        assert_int_equal(nd, 2);
        assert_int_equal(sh[0], SEQ_S);
        assert_int_equal(sh[1], MASK_P);
        uint8_t keep[SEQ_S * MASK_P];
        int kept = 0;
        for (int i = 0; i < SEQ_S * MASK_P; i++)
            kept += keep[i] = kf[i] != 0.0f;
        struct model_outputs out;
        if (model_eval_masked(m, img, SEQ_S, SEQ_H, SEQ_W, keep, &out) < 0)
            fail_msg("t%d: %s", t, model_error(m));
        assert_int_equal(out.step, t + 1);
        assert_int_equal(out.has_motion, t > 0);
        assert_int_equal(out.masked, t >= 2);
        assert_int_equal(out.total_tokens, t >= 2 ? SEQ_S * 3 + kept : SEQ_S * (3 + MASK_P));
        compare_outputs(&r, &out);
        report(&r, tag, t, budget);
        mt_run_free(&r);
        free(kf);
        free(img);
    }
    model_free(m);
    fk_ctx_free(ctx);
}

static void test_masked_f32(void **state)
{
    (void)state;
    run_masked_sequence("f32", FK_W_F32, budget_f32);
}

static void test_masked_f16(void **state)
{
    (void)state;
    run_masked_sequence("f16", FK_W_F16, budget_f16);
}

/* ---- fusion MLP ---------------------------------------------------------- */

static void test_fusion(void **state)
{
    (void)state;
    int64_t sh[NPY_MAX_DIMS];
    int nd;
    float *in = mt_npy_load(sh, &nd, "%s/tiny_f4d_seq/fusion_in.npy", fixture_dir);
    assert_int_equal(sh[0], N_PAIRS);
    assert_int_equal(sh[1], MODEL_FUSION_IN);
    float *ref = mt_npy_load(sh, &nd, "%s/tiny_f4d_seq/fusion_out.npy", fixture_dir);
    assert_int_equal(sh[1], MODEL_FUSION_ATTRS);
    static const char *types[] = { "f32", "int8" };
    static const enum fk_wtype wts[] = { FK_W_F32, FK_W_Q8 };
    float got[2][N_PAIRS * MODEL_FUSION_ATTRS];
    for (int k = 0; k < 2; k++) {
        char file[64];
        snprintf(file, sizeof file, "tiny_f4d_seq_%s.gguf", types[k]);
        fk_ctx *ctx = new_ctx();
        struct model *m = open_model(ctx, file, wts[k]);
        void *fu = model_fusion(m);
        assert_non_null(fu);
        for (int i = 0; i < N_PAIRS; i++) {
            const float *x = in + (size_t)i * MODEL_FUSION_IN;
            model_fusion_fuse(fu, x, x + MODEL_FUSION_ATTRS, x[28], x[29],
                              got[k] + (size_t)i * MODEL_FUSION_ATTRS);
        }
        model_free(m);
        fk_ctx_free(ctx);
    }
    double e = mt_arr_rel(got[0], ref, (size_t)N_PAIRS * MODEL_FUSION_ATTRS);
    printf("  fusion: %d pairs, rel_err %.3e (budget %.1e)\n", N_PAIRS, e, budget_f32);
    assert_true(e <= budget_f32);
    /* fusion weights stay f32 in every precision: the same bits */
    assert_memory_equal(got[0], got[1], sizeof got[0]);
    free(in);
    free(ref);
}

/* ---- hard cases ---------------------------------------------------------- */

struct mem_gguf {
    unsigned char *buf;
    size_t         size;
};

static void mem_load(struct mem_gguf *mg, const char *file)
{
    char path[1200];
    snprintf(path, sizeof path, "%s/%s", gguf_dir, file);
    FILE *f = fopen(path, "rb");
    assert_non_null(f);
    fseek(f, 0, SEEK_END);
    long sz = ftell(f);
    fseek(f, 0, SEEK_SET);
    assert_true(sz > 0);
    mg->size = (size_t)sz;
    mg->buf = aligned_alloc(GGUF_MAX_ALIGN, (mg->size + GGUF_MAX_ALIGN - 1) / GGUF_MAX_ALIGN *
                                                GGUF_MAX_ALIGN);
    assert_non_null(mg->buf);
    assert_int_equal(fread(mg->buf, 1, mg->size, f), mg->size);
    fclose(f);
}

static float *mem_tensor(struct mem_gguf *mg, const char *name, size_t *count)
{
    gguf_file *gf;
    struct f4d_err err = {0};
    if (gguf_open_memory(mg->buf, mg->size, &gf, &err) < 0)
        fail_msg("%s", err.msg);
    const struct gguf_tensor *t = gguf_find_tensor(gf, name);
    assert_non_null(t);
    assert_int_equal(t->type, GGUF_T_F32);
    float *p = (float *)(mg->buf + ((const unsigned char *)t->data - mg->buf));
    *count = (size_t)t->n_elements;
    gguf_close(gf);
    return p;
}

/* The motion head's last conv zeroed (its untrained state): every motion
 * vector of both maps is exactly 0, in model units and metric, while the
 * motion blocks themselves run on nonzero weights. */
static void test_zero_motion(void **state)
{
    (void)state;
    struct mem_gguf mg;
    mem_load(&mg, "tiny_f4d_seq_f32.gguf");
    size_t nw, nb;
    float *w = mem_tensor(&mg, "motion_head.scratch.output_conv2.2.weight", &nw);
    float *b = mem_tensor(&mg, "motion_head.scratch.output_conv2.2.bias", &nb);
    memset(w, 0, nw * sizeof *w);
    memset(b, 0, nb * sizeof *b);
    gguf_file *gf;
    struct f4d_err err = {0};
    if (gguf_open_memory(mg.buf, mg.size, &gf, &err) < 0)
        fail_msg("%s", err.msg);
    fk_ctx *ctx = new_ctx();
    struct model *m;
    if (model_init_gguf(ctx, gf, FK_W_F32, &m, &err) < 0)
        fail_msg("%s", err.msg);
    assert_int_equal(model_prepare(m, SEQ_S, SEQ_H, SEQ_W), 0);
    struct model_outputs out;
    for (int t = 0; t < 3; t++) {
        float *img = load_input(t);
        assert_int_equal(model_eval(m, img, SEQ_S, SEQ_H, SEQ_W, &out), 0);
        free(img);
        assert_int_equal(out.has_motion, t > 0);
        if (t == 0)
            continue;
        const size_t n = (size_t)3 * SEQ_S * SEQ_H * SEQ_W;
        for (size_t i = 0; i < n; i++) {
            assert_true(out.motion_bwd[i] == 0.0f && !signbit(out.motion_bwd[i]));
            assert_true(out.motion_fwd_prev[i] == 0.0f && !signbit(out.motion_fwd_prev[i]));
        }
    }
    model_free(m);
    gguf_close(gf);
    fk_ctx_free(ctx);
    free(mg.buf);
}

/* No motion on the first step, nor after a change of frame size (the kept
 * inputs belong to another frame set); the state carries on. */
static void test_first_step_no_motion(void **state)
{
    (void)state;
    fk_ctx *ctx = new_ctx();
    struct model *m = open_model(ctx, "tiny_f4d_seq_f32.gguf", FK_W_F32);
    struct model_outputs out;
    float *img0 = load_input(0), *img1 = load_input(1);
    assert_int_equal(model_eval(m, img0, SEQ_S, SEQ_H, SEQ_W, &out), 0);
    assert_int_equal(out.step, 1);
    assert_int_equal(out.has_motion, 0);
    assert_null(out.motion_bwd);
    assert_null(out.motion_fwd_prev);
    assert_non_null(out.gaussians.pos);
    assert_int_equal(model_eval(m, img1, SEQ_S, SEQ_H, SEQ_W, &out), 0);
    assert_int_equal(out.has_motion, 1);
    assert_non_null(out.motion_bwd);
    /* one view: another frame set, so no motion on this step ... */
    assert_int_equal(model_eval(m, img1, 1, SEQ_H, SEQ_W, &out), 0);
    assert_int_equal(out.step, 3);
    assert_int_equal(out.has_motion, 0);
    assert_null(out.motion_bwd);
    /* ... and motion again on the next one of the same size */
    assert_int_equal(model_eval(m, img0, 1, SEQ_H, SEQ_W, &out), 0);
    assert_int_equal(out.has_motion, 1);
    /* per-stage time: the new stages are reported by name */
    struct model_stage st[32];
    int ns = model_stages(m, st, 32), found = 0;
    for (int i = 0; i < ns; i++)
        if (!strcmp(st[i].name, "state_blocks") || !strcmp(st[i].name, "motion_blocks") ||
            !strcmp(st[i].name, "motion_head")) {
            assert_true(st[i].seconds > 0 && st[i].flops > 0);
            found++;
        }
    assert_int_equal(found, 3);
    free(img0);
    free(img1);
    model_free(m);
    fk_ctx_free(ctx);
}

/* model_state_reset: the first step again, bit for bit (state, layers,
 * Gaussians), and no motion. */
static void test_reset_reproduces_first_step(void **state)
{
    (void)state;
    fk_ctx *ctx = new_ctx();
    struct model *m = open_model(ctx, "tiny_f4d_seq_f32.gguf", FK_W_F32);
    const size_t n = (size_t)SEQ_S * SEQ_H * SEQ_W;
    struct model_outputs out;
    float *img[3] = { load_input(0), load_input(1), load_input(2) };
    float *pos0 = malloc(3 * n * sizeof *pos0), *lay0 = NULL;
    assert_non_null(pos0);
    const int last = model_get_config(m)->depth - 1;
    size_t lay_n = 0;
    for (int run = 0; run < 2; run++) {
        if (run)
            model_state_reset(m);
        assert_int_equal(model_eval(m, img[0], SEQ_S, SEQ_H, SEQ_W, &out), 0);
        assert_int_equal(out.step, 1);
        assert_int_equal(out.has_motion, 0);
        const float *lay = model_layer(m, last);
        assert_non_null(lay);
        if (!run) {
            int p = model_get_config(m)->patch_size;
            lay_n = (size_t)SEQ_S * (1 + model_get_config(m)->num_register_tokens +
                                     (SEQ_H / p) * (SEQ_W / p)) * 2 * model_get_config(m)->embed_dim;
            lay0 = malloc(lay_n * sizeof *lay0);
            assert_non_null(lay0);
            memcpy(lay0, lay, lay_n * sizeof *lay0);
            memcpy(pos0, out.gaussians.pos, 3 * n * sizeof *pos0);
            /* two more steps move the state and the motion inputs on */
            assert_int_equal(model_eval(m, img[1], SEQ_S, SEQ_H, SEQ_W, &out), 0);
            assert_int_equal(model_eval(m, img[2], SEQ_S, SEQ_H, SEQ_W, &out), 0);
            assert_true(memcmp(model_layer(m, last), lay0, lay_n * sizeof *lay0) != 0);
        } else {
            assert_memory_equal(lay, lay0, lay_n * sizeof *lay0);
            assert_memory_equal(out.gaussians.pos, pos0, 3 * n * sizeof *pos0);
        }
    }
    /* and the step after the reset has motion again */
    assert_int_equal(model_eval(m, img[1], SEQ_S, SEQ_H, SEQ_W, &out), 0);
    assert_int_equal(out.has_motion, 1);
    for (int i = 0; i < 3; i++)
        free(img[i]);
    free(pos0);
    free(lay0);
    model_free(m);
    fk_ctx_free(ctx);
}

/* Skipping the motion head (the daemon's --motion off) also leaves out the
 * motion blocks: nothing else reads their streams. The arena is the plan
 * without the motion groups, no step has motion or runs motion blocks, and
 * every step's Gaussians, gauge and cameras equal the full model's bit for
 * bit (the motion stream never feeds back into the aggregator). */
static void test_skip_motion_head(void **state)
{
    (void)state;
    char path[1200];
    struct f4d_err err = {0};
    snprintf(path, sizeof path, "%s/tiny_f4d_seq_f32.gguf", gguf_dir);
    fk_ctx *ctx = new_ctx(), *ctx2 = new_ctx();
    struct model *full = open_model(ctx, "tiny_f4d_seq_f32.gguf", FK_W_F32), *m = NULL;
    if (model_init(ctx2, path, FK_W_F32, &m, &err) < 0)
        fail_msg("%s: %s", path, err.msg);
    assert_int_equal(model_skip_head(m, "motion_head"), 0);
    assert_int_equal(model_prepare(m, SEQ_S, SEQ_H, SEQ_W), 0);
    assert_int_equal(model_groups(m), MODEL_G_ALL); /* the file's groups */
    const unsigned run = MODEL_G_ALL & ~(MODEL_G_MOTION | MODEL_G_MOTION_HEAD);
    assert_int_equal(model_arena_bytes(m), model_plan_bytes(model_get_config(m), run, SEQ_S, SEQ_H, SEQ_W));
    assert_true(model_arena_bytes(m) < model_arena_bytes(full));
    const size_t n = (size_t)SEQ_S * SEQ_H * SEQ_W;
    struct model_outputs a, b;
    for (int t = 0; t < 3; t++) {
        float *img = load_input(t);
        assert_int_equal(model_eval(full, img, SEQ_S, SEQ_H, SEQ_W, &a), 0);
        assert_int_equal(model_eval(m, img, SEQ_S, SEQ_H, SEQ_W, &b), 0);
        free(img);
        assert_int_equal(a.has_motion, t > 0);
        assert_int_equal(b.has_motion, 0);
        assert_null(b.motion_bwd);
        assert_null(b.motion_fwd_prev);
        assert_true(a.gauge == b.gauge);
        assert_memory_equal(a.gaussians.pos, b.gaussians.pos, 3 * n * sizeof(float));
        assert_memory_equal(a.gaussians.scale, b.gaussians.scale, 3 * n * sizeof(float));
        assert_memory_equal(a.gaussians.rot, b.gaussians.rot, 4 * n * sizeof(float));
        assert_memory_equal(a.extrinsic_metric, b.extrinsic_metric, (size_t)SEQ_S * 12 * sizeof(float));
        struct model_stage st[32];
        int ns = model_stages(m, st, 32);
        for (int i = 0; i < ns; i++) {
            assert_string_not_equal(st[i].name, "motion_blocks");
            assert_string_not_equal(st[i].name, "motion_head");
        }
    }
    model_free(m);
    model_free(full);
    fk_ctx_free(ctx2);
    fk_ctx_free(ctx);
}

/* Checkpoints without the stage-2/3 parts: plain VGGT and the stage-1 model
 * run as before, nothing carried between Evals (the same input twice gives
 * the same bits), no motion, no fusion. */
static void test_without_stream_parts(void **state)
{
    (void)state;
    static const char *files[] = { "tiny_f32.gguf", "tiny_f4d_f32.gguf" };
    for (int k = 0; k < 2; k++) {
        fk_ctx *ctx = new_ctx();
        struct model *m = open_model(ctx, files[k], FK_W_F32);
        const unsigned want = k ? (MODEL_G_VGGT | MODEL_G_GAUSSIAN | MODEL_G_SCALE) : MODEL_G_VGGT;
        assert_int_equal(model_groups(m), want);
        assert_int_equal(model_arena_bytes(m),
                         model_plan_bytes(model_get_config(m), want, SEQ_S, SEQ_H, SEQ_W));
        assert_null(model_fusion(m));
        float *img = load_input(0);
        const size_t n = (size_t)SEQ_S * SEQ_H * SEQ_W * 3;
        float *wp = malloc(n * sizeof *wp);
        assert_non_null(wp);
        struct model_outputs out;
        for (int t = 0; t < 3; t++) {
            if (t == 2)
                model_state_reset(m); /* a no-op without state */
            assert_int_equal(model_eval(m, img, SEQ_S, SEQ_H, SEQ_W, &out), 0);
            assert_int_equal(out.has_motion, 0);
            assert_int_equal(out.step, 0);
            assert_null(out.motion_bwd);
            assert_null(out.motion_fwd_prev);
            assert_non_null(out.world_points);
            if (t == 0)
                memcpy(wp, out.world_points, n * sizeof *wp);
            else
                assert_memory_equal(out.world_points, wp, n * sizeof *wp);
        }
        struct model_stage st[32];
        int ns = model_stages(m, st, 32);
        for (int i = 0; i < ns; i++) {
            assert_string_not_equal(st[i].name, "state_blocks");
            assert_string_not_equal(st[i].name, "motion_blocks");
        }
        free(wp);
        free(img);
        model_free(m);
        fk_ctx_free(ctx);
    }
}

/* The fusion MLP plugs into interp as its fuse function (the same type), and
 * with fc2 zeroed (untrained) it is interp_fuse_average: the first 10
 * attributes bit for bit, the quaternion up to interp's normalisation. */
static void test_zero_fusion_is_interp_average(void **state)
{
    (void)state;
    const interp_fuse_fn fn = model_fusion_fuse; /* the signatures match */
    struct mem_gguf mg;
    mem_load(&mg, "tiny_f4d_seq_f32.gguf");
    size_t nw, nb;
    float *w = mem_tensor(&mg, "fusion.fc2.weight", &nw);
    float *b = mem_tensor(&mg, "fusion.fc2.bias", &nb);
    memset(w, 0, nw * sizeof *w);
    memset(b, 0, nb * sizeof *b);
    gguf_file *gf;
    struct f4d_err err = {0};
    if (gguf_open_memory(mg.buf, mg.size, &gf, &err) < 0)
        fail_msg("%s", err.msg);
    fk_ctx *ctx = new_ctx();
    struct model *m;
    if (model_init_gguf(ctx, gf, FK_W_F32, &m, &err) < 0)
        fail_msg("%s", err.msg);
    int64_t sh[NPY_MAX_DIMS];
    int nd;
    float *in = mt_npy_load(sh, &nd, "%s/tiny_f4d_seq/fusion_in.npy", fixture_dir);
    for (int i = 0; i < N_PAIRS; i++) {
        const float *x = in + (size_t)i * MODEL_FUSION_IN;
        float got[INTERP_ATTRS], avg[INTERP_ATTRS];
        fn(model_fusion(m), x, x + INTERP_ATTRS, x[28], x[29], got);
        interp_fuse_average(NULL, x, x + INTERP_ATTRS, x[28], x[29], avg);
        assert_memory_equal(got, avg, 10 * sizeof(float));
        double n = 0;
        for (int c = 10; c < 14; c++)
            n += (double)avg[c] * avg[c];
        n = sqrt(n);
        for (int c = 10; c < 14; c++)
            assert_true(fabs(got[c] - avg[c] / n) < 1e-6);
    }
    free(in);
    model_free(m);
    gguf_close(gf);
    fk_ctx_free(ctx);
    free(mg.buf);
}

/* The f32 stream file without the tensors whose names start with `drop`
 * (NULL: none), with the config `cfg` (NULL: the file's), written under
 * GGUF_DIR as `out`. */
static void write_variant(const char *drop, const struct model_config *cfg, const char *out)
{
    char src[1200], dst[1200];
    struct f4d_err err = {0};
    snprintf(src, sizeof src, "%s/tiny_f4d_seq_f32.gguf", gguf_dir);
    snprintf(dst, sizeof dst, "%s/%s", gguf_dir, out);
    gguf_file *gf;
    if (gguf_open(src, &gf, &err) < 0)
        fail_msg("%s", err.msg);
    struct model_config c;
    assert_int_equal(model_config_read(gf, &c, &err), 0);
    gguf_writer *w = gguf_writer_new();
    assert_non_null(w);
    assert_int_equal(model_config_write(cfg ? cfg : &c, w), 0);
    assert_int_equal(gguf_writer_add_str(w, "forge4d.file_type", "f32"), 0);
    const size_t nd = drop ? strlen(drop) : 0;
    for (int pass = 0; pass < 2; pass++) {
        for (size_t i = 0; i < gguf_tensor_count(gf); i++) {
            const struct gguf_tensor *t = gguf_tensor_at(gf, i);
            if (drop && !strncmp(t->name, drop, nd))
                continue;
            if (pass) {
                assert_int_equal(gguf_writer_write(w, t->data, t->nbytes), 0);
                continue;
            }
            int64_t shape[GGUF_MAX_DIMS];
            for (uint32_t d = 0; d < t->n_dims; d++)
                shape[d] = (int64_t)t->ne[t->n_dims - 1 - d];
            assert_int_equal(gguf_writer_add_tensor(w, t->name, t->type, (int)t->n_dims, shape), 0);
        }
        if (!pass && gguf_writer_begin(w, dst) < 0)
            fail_msg("%s", gguf_writer_error(w));
    }
    if (gguf_writer_finish(w) < 0)
        fail_msg("%s", gguf_writer_error(w));
    gguf_writer_free(w);
    gguf_close(gf);
}

/* Motion blocks without the motion head (or the head without the blocks)
 * are refused at Init, naming what is missing; state alone runs: the state
 * carries (a second Eval of the same input differs), never any motion. */
static void test_partial_stream_files(void **state)
{
    (void)state;
    static const struct { const char *drop, *file, *msg; } bad[] = {
        { "motion_head.", "seq_no_motion_head.gguf", "motion_head" },
        { "motion.", "seq_no_motion.gguf", "motion" },
    };
    fk_ctx *ctx = new_ctx();
    for (int i = 0; i < 2; i++) {
        char path[1200];
        struct f4d_err err = {0};
        struct model *m = NULL;
        write_variant(bad[i].drop, NULL, bad[i].file);
        snprintf(path, sizeof path, "%s/%s", gguf_dir, bad[i].file);
        assert_int_equal(model_init(ctx, path, FK_W_F32, &m, &err), F4D_EFORMAT);
        assert_null(m);
        printf("  without %s*: '%s'\n", bad[i].drop, err.msg);
        assert_non_null(strstr(err.msg, bad[i].msg));
    }
    fk_ctx_free(ctx);
    /* state only: drop motion.*, then motion_head.* from that copy */
    write_variant("motion", NULL, "seq_state_fusion.gguf");
    ctx = new_ctx();
    struct model *m = open_model(ctx, "seq_state_fusion.gguf", FK_W_F32);
    assert_int_equal(model_groups(m), MODEL_G_ALL & ~(MODEL_G_MOTION | MODEL_G_MOTION_HEAD));
    float *img = load_input(0);
    const size_t n = (size_t)SEQ_S * SEQ_H * SEQ_W * 3;
    float *p0 = malloc(n * sizeof *p0);
    assert_non_null(p0);
    struct model_outputs out;
    for (int t = 0; t < 2; t++) {
        assert_int_equal(model_eval(m, img, SEQ_S, SEQ_H, SEQ_W, &out), 0);
        assert_int_equal(out.step, t + 1);
        assert_int_equal(out.has_motion, 0);
        assert_null(out.motion_bwd);
        if (!t)
            memcpy(p0, out.gaussians.pos, n * sizeof *p0);
    }
    assert_true(memcmp(p0, out.gaussians.pos, n * sizeof *p0) != 0);
    free(p0);
    free(img);
    model_free(m);
    fk_ctx_free(ctx);
}

static int count_tensor(void *user, const struct model_tensor_info *t)
{
    (void)t;
    ++*(size_t *)user;
    return 0;
}

/* The motion path's cost keys (model.h motion_layers, motion_dpt_features):
 * f4d-convert writes the fixture's ([1, 2, 3, 4], 8); a file whose blocks do
 * not match its motion_layers, a set without a DPT layer, and a motion head
 * of another width are refused by name; the full design (every layer) stays
 * expressible and costs 6x the default's motion blocks at VGGT-1B size. */
static void test_motion_layer_config(void **state)
{
    (void)state;
    char src[1200];
    struct f4d_err err = {0};
    snprintf(src, sizeof src, "%s/tiny_f4d_seq_f32.gguf", gguf_dir);
    gguf_file *gf;
    if (gguf_open(src, &gf, &err) < 0)
        fail_msg("%s", err.msg);
    struct model_config c;
    assert_int_equal(model_config_read(gf, &c, &err), 0);
    gguf_close(gf);
    assert_true(c.motion_layers == 0x1E);
    assert_int_equal(c.motion_dpt_features, 8);
    assert_int_equal(model_motion_features(&c), 8);
    struct model_config v[3] = { c, c, c };
    v[0].motion_layers = 0x1A;          /* no block 2, but the file has one */
    v[1].motion_layers = 0x1F;          /* block 0 too, the file has none */
    v[2].motion_dpt_features = 16;      /* the head is 8 wide */
    static const char *msg[3] = { "motion.in_proj.2", "motion.in_proj.0", "motion_head" };
    fk_ctx *ctx = new_ctx();
    for (int i = 0; i < 3; i++) {
        char file[64], path[1200];
        snprintf(file, sizeof file, "seq_motion_cfg%d.gguf", i);
        write_variant(NULL, &v[i], file);
        snprintf(path, sizeof path, "%s/%s", gguf_dir, file);
        struct model *m = NULL;
        err.msg[0] = 0;
        assert_int_equal(model_init(ctx, path, FK_W_F32, &m, &err), F4D_EFORMAT);
        assert_null(m);
        printf("  motion config %d: '%s'\n", i, err.msg);
        assert_non_null(strstr(err.msg, msg[i]));
    }
    fk_ctx_free(ctx);
    struct model_config bad = c;
    bad.motion_layers = 0x16;           /* lacks dpt_layer_idx 3 */
    assert_int_equal(model_config_check(&bad, &err), F4D_EFORMAT);
    assert_non_null(strstr(err.msg, "dpt_layer_idx[1] = 3"));
    bad.motion_layers = 0x3E;           /* layer 5 of a depth-5 model */
    assert_int_equal(model_config_check(&bad, &err), F4D_EFORMAT);
    assert_non_null(strstr(err.msg, "beyond depth"));
    /* VGGT-1B: the default (4 DPT layers) and the full design (24 layers) */
    struct model_config full;
    model_config_default(&full);
    assert_int_equal(model_config_check(&full, &err), 0);
    assert_true(model_motion_mask(&full) == ((UINT64_C(1) << 4) | (UINT64_C(1) << 11) |
                                             (UINT64_C(1) << 17) | (UINT64_C(1) << 23)));
    size_t n_def = 0, n_all = 0;
    assert_int_equal(model_schema_foreach(&full, MODEL_G_MOTION, count_tensor, &n_def), 0);
    struct model_config all = full;
    all.motion_layers = (UINT64_C(1) << 24) - 1;
    all.motion_dpt_features = 256;
    assert_int_equal(model_config_check(&all, &err), 0);
    assert_int_equal(model_schema_foreach(&all, MODEL_G_MOTION, count_tensor, &n_all), 0);
    assert_int_equal(n_all, 6 * n_def);
    assert_true(model_schema_bytes(&all, MODEL_G_MOTION_HEAD) >
                model_schema_bytes(&full, MODEL_G_MOTION_HEAD));
    assert_true(model_plan_bytes(&all, MODEL_G_ALL, 4, 518, 518) >
                model_plan_bytes(&full, MODEL_G_ALL, 4, 518, 518));
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
        cmocka_unit_test(test_seq_f32),
        cmocka_unit_test(test_seq_f16),
        cmocka_unit_test(test_seq_int8),
        cmocka_unit_test(test_masked_f32),
        cmocka_unit_test(test_masked_f16),
        cmocka_unit_test(test_fusion),
        cmocka_unit_test(test_zero_fusion_is_interp_average),
        cmocka_unit_test(test_zero_motion),
        cmocka_unit_test(test_first_step_no_motion),
        cmocka_unit_test(test_reset_reproduces_first_step),
        cmocka_unit_test(test_without_stream_parts),
        cmocka_unit_test(test_skip_motion_head),
        cmocka_unit_test(test_partial_stream_files),
        cmocka_unit_test(test_motion_layer_config),
    };
    return cmocka_run_group_tests_name("/model/forge4d_seq", tests, NULL, NULL);
}
