/* bench_tokens.c - f4d-bench tokens: "compute only where the scene is".
 *
 *   f4d-bench tokens [--config mid|tiny|f4d|both|all] [--size HxW] [--reps R]
 *                    [--margins A,B] [--threads N] [--tmp DIR] [--json FILE]
 *
 * The synthetic walk take (firmware/synth/scene, 4 views of the default rig
 * rendered through splat at HxW, default 518x518). The background model
 * (firmware/infer/foreground) learns from 15 sets, every 8th of the first
 * 120 frames (4 s); the key frame is frame 153, the previous key frame 150
 * (10 Hz keys at 30 fps). Per model config, in one run:
 *   all      model_eval of key 153, every patch (the reference);
 *   margin A model_eval_masked of key 153 after a full Eval of key 150 (the
 *   margin B  rows of dropped patches come from there), foreground patches
 *            dilated by A (resp. B) patches.
 * Each: best of R key-frame times, per-stage split (aggregator vs heads),
 * tokens per view and in all, and the error against `all`: depth and world
 * points max |x - x_all| / max |x_all| and mean |x - x_all| / mean |x_all|
 * (depth also on the person's ground-truth pixels and on the rest), and the PSNR of a render of the Gaussian head's output from a novel
 * camera (20 degrees off the first view's axis, looking at the Gaussians'
 * median) against the render of `all`'s. The row "last key" is that PSNR
 * for key 150's Gaussians as they are: what reusing the whole last key
 * would give. Also the mask against the scene's ground-truth person pixels.
 * Configs (random weights, bench_model's generator; VGGT's layout, groups
 * VGGT + Forge4D's Gaussian and scale heads; f4d adds the state / motion
 * blocks and the motion head):
 *   mid   embed 384, 6 heads, depth 8, DINO depth 4, 4 registers, DPT
 *         features 48 (out 48/96/192/384), layers 1/3/5/7: VGGT-1B's shape
 *         scaled down, each DPT head's FLOPs near VGGT-1B's share of the
 *         aggregator's (about 6 % here, 8 % there at 518x518);
 *   tiny  bench_model's tiny config (embed 128, depth 4, DINO 2, features
 *         32): the heads are nearly half its FLOPs, so it shows where
 *         masking the aggregator stops paying.
 *   f4d   mid + Forge4D's state blocks, motion blocks and motion head (groups
 *         MODEL_G_ALL): a time step, not a key alone. Per run and rep the
 *         sequence restarts (model_state_reset) and frames 147 and 150 run
 *         every patch (a masked step needs a last step that ran the motion);
 *         frame 153 is timed: every patch, or masked at margin A / B. The
 *         step's time splits into the key-frame part (everything but the
 *         motion) and the motion part (motion blocks + motion head, M1[153]
 *         and M2[150]); errors against `all` for depth and M1 (motion_bwd;
 *         a masked step's M1 is 0 at dropped patches by definition), on the
 *         person's pixels and on the rest.
 * `both` (the default) runs mid and tiny, `all` mid, tiny and f4d.
 * With random weights the errors say how much dropping the background
 * changes the outputs, not how good a trained model's outputs stay.
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "bench.h"
#include "fk_ctx.h"
#include "foreground.h"
#include "model.h"
#include "scene.h"
#include "splat.h"

#define TV 4            /* views */
#define LEARN_SETS 15
#define LEARN_STEP 8
#define KEY_PREV 150
#define KEY 153
#define NOVEL_SIZE 384  /* novel-view render, square */

struct take {
    scene           *sc;
    splat_renderer  *r;
    struct splat_rig rig;
    struct splat_frame f;
    float           *rgb, *alpha;
    int              H, W;
};

static int take_frame(struct take *t, int k, float *img, uint8_t *gt)
{
    struct f4d_err err = {0};
    const size_t hw = (size_t)t->H * t->W;
    if (scene_eval(t->sc, k / SCENE_FPS, 0.0, &t->f, &err) < 0)
        goto fail;
    for (int v = 0; v < TV; v++) {
        struct splat_render_out o = { .rgb = t->rgb };
        if (splat_render(t->r, &t->rig.cams[v], &t->f, scene_background(), &o) < 0)
            goto fail_r;
        for (size_t i = 0; i < hw; i++)
            for (int c = 0; c < 3; c++) {
                float x = t->rgb[i * 3 + c];
                img[((size_t)v * 3 + c) * hw + i] = x < 0 ? 0 : x > 1 ? 1 : x;
            }
    }
    if (!gt)
        return 0;
    for (size_t i = scene_figure_count(t->sc); i < t->f.count; i++)
        t->f.opacity[i] = 0.0f;
    for (int v = 0; v < TV; v++) {
        struct splat_render_out o = { .alpha = t->alpha };
        if (splat_render(t->r, &t->rig.cams[v], &t->f, NULL, &o) < 0)
            goto fail_r;
        for (size_t i = 0; i < hw; i++)
            gt[(size_t)v * hw + i] = t->alpha[i] > 0.5f;
    }
    return 0;
fail_r:
    fprintf(stderr, "f4d-bench tokens: render: %s\n", splat_renderer_error(t->r));
    return -1;
fail:
    fprintf(stderr, "f4d-bench tokens: scene: %s\n", err.msg);
    return -1;
}

/* What one Eval left: copies of the outputs compared, the Gaussians. */
struct shot {
    double seconds, agg_s, heads_s;
    int    masked, tokens[TV], total;
    float *depth, *points;
    struct splat_frame g;   /* owned copy */
};

static void shot_free(struct shot *s)
{
    free(s->depth);
    free(s->points);
    splat_frame_free(&s->g);
    memset(s, 0, sizeof *s);
}

static void stage_split(const struct model *m, double *agg_s, double *heads_s)
{
    struct model_stage st[16];
    int ns = model_stages(m, st, 16);
    *agg_s = *heads_s = 0;
    for (int i = 0; i < ns; i++) {
        int agg = !strcmp(st[i].name, "patch_embed") || !strcmp(st[i].name, "dino_blocks") ||
                  !strcmp(st[i].name, "frame_blocks") || !strcmp(st[i].name, "global_blocks");
        *(agg ? agg_s : heads_s) += st[i].seconds;
    }
}

static int shot_take(struct shot *s, const struct model_outputs *o)
{
    const size_t n = (size_t)o->S * o->H * o->W;
    s->masked = o->masked;
    s->total = o->total_tokens;
    for (int v = 0; v < TV; v++)
        s->tokens[v] = o->view_tokens[v];
    s->depth = malloc(n * sizeof *s->depth);
    s->points = malloc(3 * n * sizeof *s->points);
    if (!s->depth || !s->points || !o->depth || !o->world_points)
        return -1;
    memcpy(s->depth, o->depth, n * sizeof *s->depth);
    memcpy(s->points, o->world_points, 3 * n * sizeof *s->points);
    if (o->gaussians.count) {
        const struct model_gaussians *q = &o->gaussians;
        struct splat_frame wrap = { .count = q->count, .capacity = q->count, .pos = q->pos,
                                    .scale = q->scale, .rot = q->rot, .opacity = q->opacity,
                                    .rgb = q->rgb };
        struct f4d_err err = {0};
        if (splat_frame_copy(&s->g, &wrap, &err) < 0)
            return -1;
    }
    return 0;
}

/* Runs one Eval `reps` times (the first after `prime`, when given, a full
 * Eval of the previous key); keeps the best time and the first outputs. */
static int run_eval(struct model *m, const float *img, const float *prime, const uint8_t *keep,
                    int H, int W, int reps, struct shot *s)
{
    struct model_outputs o;
    if (prime && model_eval(m, prime, TV, H, W, &o) < 0)
        goto fail;
    s->seconds = INFINITY;
    for (int i = 0; i < reps; i++) {
        double t0 = bench_now();
        if (model_eval_masked(m, img, TV, H, W, keep, &o) < 0)
            goto fail;
        double t = bench_now() - t0;
        if (i == 0 && shot_take(s, &o) < 0) {
            fprintf(stderr, "f4d-bench tokens: out of memory (or a head missing)\n");
            return -1;
        }
        if (t < s->seconds) {
            s->seconds = t;
            stage_split(m, &s->agg_s, &s->heads_s);
        }
    }
    return 0;
fail:
    fprintf(stderr, "f4d-bench tokens: %s\n", model_error(m));
    return -1;
}

static void errs(const float *x, const float *ref, size_t n, double *maxrel, double *meanrel)
{
    double md = 0, mr = 0, sd = 0, sr = 0;
    for (size_t i = 0; i < n; i++) {
        double d = fabs((double)x[i] - ref[i]);
        md = isnan(d) ? INFINITY : fmax(md, d);
        mr = fmax(mr, fabs((double)ref[i]));
        sd += d;
        sr += fabs((double)ref[i]);
    }
    *maxrel = mr > 0 ? md / mr : md;
    *meanrel = sr > 0 ? sd / sr : sd;
}

/* mean |x - ref| / mean |ref| over the pixels where (gt != 0) == sel */
static double region_err(const float *x, const float *ref, const uint8_t *gt, size_t n, int sel)
{
    double sd = 0, sr = 0;
    for (size_t i = 0; i < n; i++)
        if ((gt[i] != 0) == sel) {
            sd += fabs((double)x[i] - ref[i]);
            sr += fabs((double)ref[i]);
        }
    return sr > 0 ? sd / sr : sd;
}

static int cmp_f(const void *a, const void *b)
{
    float x = *(const float *)a, y = *(const float *)b;
    return (x > y) - (x < y);
}

/* A camera 20 degrees around the reference Gaussians' median, at 2.5 x their
 * median distance from it, fx = fy = size. */
static int novel_camera(const struct splat_frame *g, struct splat_camera *cam)
{
    size_t n = g->count, m = 0;
    float *tmp = malloc(n * sizeof *tmp);
    if (!tmp || !n) {
        free(tmp);
        return -1;
    }
    float c[3], rad;
    for (int a = 0; a < 3; a++) {
        m = 0;
        for (size_t i = 0; i < n; i++)
            if (isfinite(g->pos[3 * i + a]))
                tmp[m++] = g->pos[3 * i + a];
        if (!m) {
            free(tmp);
            return -1;
        }
        qsort(tmp, m, sizeof *tmp, cmp_f);
        c[a] = tmp[m / 2];
    }
    m = 0;
    for (size_t i = 0; i < n; i++) {
        float dx = g->pos[3 * i] - c[0], dy = g->pos[3 * i + 1] - c[1], dz = g->pos[3 * i + 2] - c[2];
        float d = sqrtf(dx * dx + dy * dy + dz * dz);
        if (isfinite(d))
            tmp[m++] = d;
    }
    qsort(tmp, m, sizeof *tmp, cmp_f);
    rad = m ? tmp[m / 2] : 1.0f;
    free(tmp);
    if (!(rad > 0))
        rad = 1.0f;
    /* VGGT's world is the first camera's frame (looking down +z, y down) */
    const float ang = 20.0f * 3.14159265f / 180.0f, dist = 2.5f * rad;
    float eye[3] = { c[0] - dist * sinf(ang), c[1], c[2] - dist * cosf(ang) };
    float up[3] = { 0, -1, 0 };
    memset(cam, 0, sizeof *cam);
    snprintf(cam->name, sizeof cam->name, "novel");
    cam->width = cam->height = NOVEL_SIZE;
    cam->fx = cam->fy = (float)NOVEL_SIZE;
    cam->cx = cam->cy = 0.5f * NOVEL_SIZE;
    splat_camera_look_at(cam, eye, c, up);
    return 0;
}

struct cfg_result {
    const char *name;
    struct model_config c;
    int    ok;
    struct shot all, prev, mk[2];
    double psnr[2], psnr_prev;
    /* against `all`: [0], [1] the margins, [2] the last key as it is */
    double d_max[3], d_mean[3], d_person[3], d_rest[3], p_max[3], p_mean[3];
};

static int bench_config(fk_ctx *ctx, const char *path, struct cfg_result *R, const float *img,
                        const float *prime, uint8_t *const keep[2], const uint8_t *gt, int H,
                        int W, int reps)
{
    struct f4d_err err = {0};
    struct model *m = NULL;
    if (bench_write_random_model(path, &R->c, MODEL_G_VGGT | MODEL_G_GAUSSIAN | MODEL_G_SCALE) < 0)
        return -1;
    if (model_init(ctx, path, FK_W_F32, &m, &err) < 0) {
        fprintf(stderr, "f4d-bench tokens: %s\n", err.msg);
        unlink(path);
        return -1;
    }
    int rc = model_prepare(m, TV, H, W);
    if (rc < 0)
        fprintf(stderr, "f4d-bench tokens: %s\n", model_error(m));
    if (rc == 0)
        rc = run_eval(m, img, NULL, NULL, H, W, reps, &R->all);
    if (rc == 0)
        rc = run_eval(m, prime, NULL, NULL, H, W, 1, &R->prev);
    for (int k = 0; rc == 0 && k < 2; k++)
        rc = run_eval(m, img, prime, keep[k], H, W, reps, &R->mk[k]);
    model_free(m);
    unlink(path);
    if (rc < 0)
        return -1;
    const size_t n = (size_t)TV * H * W;
    for (int k = 0; k < 3; k++) {
        const struct shot *s = k < 2 ? &R->mk[k] : &R->prev;
        errs(s->depth, R->all.depth, n, &R->d_max[k], &R->d_mean[k]);
        errs(s->points, R->all.points, 3 * n, &R->p_max[k], &R->p_mean[k]);
        R->d_person[k] = region_err(s->depth, R->all.depth, gt, n, 1);
        R->d_rest[k] = region_err(s->depth, R->all.depth, gt, n, 0);
    }
    /* novel-view render of the Gaussians */
    R->psnr[0] = R->psnr[1] = R->psnr_prev = NAN;
    struct splat_camera cam;
    splat_renderer *r = NULL;
    float *ref = malloc((size_t)NOVEL_SIZE * NOVEL_SIZE * 3 * sizeof *ref);
    float *im = malloc((size_t)NOVEL_SIZE * NOVEL_SIZE * 3 * sizeof *im);
    if (R->all.g.count && ref && im && novel_camera(&R->all.g, &cam) == 0 &&
        splat_renderer_new(ctx, NOVEL_SIZE, NOVEL_SIZE, &r, &err) == 0) {
        struct splat_render_out o = { .rgb = ref };
        if (splat_render(r, &cam, &R->all.g, NULL, &o) == 0) {
            const struct splat_frame *fr[3] = { &R->mk[0].g, &R->mk[1].g, &R->prev.g };
            double *dst[3] = { &R->psnr[0], &R->psnr[1], &R->psnr_prev };
            for (int k = 0; k < 3; k++) {
                struct splat_render_out o2 = { .rgb = im };
                if (splat_render(r, &cam, fr[k], NULL, &o2) == 0)
                    *dst[k] = splat_psnr(im, ref, NOVEL_SIZE, NOVEL_SIZE, 3);
            }
        }
    }
    splat_renderer_free(r);
    free(ref);
    free(im);
    R->ok = 1;
    return 0;
}

/* ---- Forge4D: state + motion, one time step ------------------------------ */

struct f4d_shot {
    double seconds, key_s, motion_s, agg_s;
    int    masked, total;
    float *depth, *m1;
};

struct f4d_result {
    int    ok;
    struct f4d_shot run[3];          /* all, margin A, margin B */
    double d_person[2], d_rest[2], m_person[2], m_rest[2], m_max[2];
};

static void f4d_split(const struct model *m, struct f4d_shot *s)
{
    struct model_stage st[16];
    int ns = model_stages(m, st, 16);
    s->key_s = s->motion_s = s->agg_s = 0;
    for (int i = 0; i < ns; i++) {
        int mot = !strcmp(st[i].name, "motion_blocks") || !strcmp(st[i].name, "motion_head");
        *(mot ? &s->motion_s : &s->key_s) += st[i].seconds;
        if (!strcmp(st[i].name, "patch_embed") || !strcmp(st[i].name, "dino_blocks") ||
            !strcmp(st[i].name, "frame_blocks") || !strcmp(st[i].name, "global_blocks") ||
            !strcmp(st[i].name, "state_blocks") || !strcmp(st[i].name, "motion_blocks"))
            s->agg_s += st[i].seconds;
    }
}

static int bench_f4d(fk_ctx *ctx, const char *path, const struct model_config *c,
                     struct f4d_result *R, const float *const frames[3],
                     uint8_t *const keep[2], const uint8_t *gt, int H, int W, int reps)
{
    struct f4d_err err = {0};
    struct model *m = NULL;
    const size_t n = (size_t)TV * H * W;
    if (bench_write_random_model(path, c, MODEL_G_ALL) < 0)
        return -1;
    int rc = model_init(ctx, path, FK_W_F32, &m, &err);
    if (rc < 0) {
        fprintf(stderr, "f4d-bench tokens: %s\n", err.msg);
        unlink(path);
        return -1;
    }
    if ((rc = model_prepare(m, TV, H, W)) < 0)
        goto fail;
    for (int k = 0; k < 3; k++) {
        struct f4d_shot *s = &R->run[k];
        s->seconds = INFINITY;
        for (int i = 0; i < reps; i++) {
            struct model_outputs o;
            model_state_reset(m);
            if ((rc = model_eval(m, frames[0], TV, H, W, &o)) < 0 ||
                (rc = model_eval(m, frames[1], TV, H, W, &o)) < 0)
                goto fail;
            double t0 = bench_now();
            if ((rc = model_eval_masked(m, frames[2], TV, H, W, k ? keep[k - 1] : NULL, &o)) < 0)
                goto fail;
            double t = bench_now() - t0;
            if (i == 0) {
                s->masked = o.masked;
                s->total = o.total_tokens;
                s->depth = malloc(n * sizeof *s->depth);
                s->m1 = malloc(3 * n * sizeof *s->m1);
                if (!s->depth || !s->m1 || !o.depth || !o.motion_bwd) {
                    fprintf(stderr, "f4d-bench tokens: out of memory (or no motion)\n");
                    rc = -1;
                    goto out;
                }
                memcpy(s->depth, o.depth, n * sizeof *s->depth);
                memcpy(s->m1, o.motion_bwd, 3 * n * sizeof *s->m1);
            }
            if (t < s->seconds) {
                s->seconds = t;
                f4d_split(m, s);
            }
        }
    }
    uint8_t *gt3 = malloc(3 * n);
    if (!gt3) {
        rc = -1;
        goto out;
    }
    for (size_t i = 0; i < 3 * n; i++)
        gt3[i] = gt[i / 3];
    for (int k = 0; k < 2; k++) {
        double dummy;
        R->d_person[k] = region_err(R->run[k + 1].depth, R->run[0].depth, gt, n, 1);
        R->d_rest[k] = region_err(R->run[k + 1].depth, R->run[0].depth, gt, n, 0);
        R->m_person[k] = region_err(R->run[k + 1].m1, R->run[0].m1, gt3, 3 * n, 1);
        R->m_rest[k] = region_err(R->run[k + 1].m1, R->run[0].m1, gt3, 3 * n, 0);
        errs(R->run[k + 1].m1, R->run[0].m1, 3 * n, &R->m_max[k], &dummy);
    }
    free(gt3);
    R->ok = 1;
    goto out;
fail:
    fprintf(stderr, "f4d-bench tokens: %s\n", model_error(m));
out:
    model_free(m);
    unlink(path);
    return rc < 0 ? -1 : 0;
}

static void f4d_free(struct f4d_result *R)
{
    for (int k = 0; k < 3; k++) {
        free(R->run[k].depth);
        free(R->run[k].m1);
    }
    memset(R, 0, sizeof *R);
}

static void config_mid(struct model_config *c)
{
    model_config_default(c);
    c->embed_dim = 384; c->num_heads = 6; c->depth = 8;
    c->num_register_tokens = 4; c->dino_depth = 4; c->dino_num_heads = 6;
    c->camera_trunk_depth = 2; c->camera_num_heads = 6; c->camera_iters = 4;
    c->dpt_features = 48;
    c->dpt_out_channels[0] = 48; c->dpt_out_channels[1] = 96;
    c->dpt_out_channels[2] = 192; c->dpt_out_channels[3] = 384;
    c->dpt_layer_idx[0] = 1; c->dpt_layer_idx[1] = 3;
    c->dpt_layer_idx[2] = 5; c->dpt_layer_idx[3] = 7;
}

int bench_tokens(int argc, char **argv)
{
    const char *json = NULL, *tmpdir = "/tmp", *which = "both";
    int threads = 0, H = 518, W = 518, reps = 3, margin[2] = { 1, 2 };
    for (int i = 1; i < argc; i++) {
        if (!strcmp(argv[i], "--json") && i + 1 < argc)
            json = argv[++i];
        else if (!strcmp(argv[i], "--threads") && i + 1 < argc)
            threads = atoi(argv[++i]);
        else if (!strcmp(argv[i], "--size") && i + 1 < argc &&
                 sscanf(argv[i + 1], "%dx%d", &H, &W) == 2)
            i++;
        else if (!strcmp(argv[i], "--reps") && i + 1 < argc)
            reps = atoi(argv[++i]);
        else if (!strcmp(argv[i], "--margins") && i + 1 < argc &&
                 sscanf(argv[i + 1], "%d,%d", &margin[0], &margin[1]) == 2)
            i++;
        else if (!strcmp(argv[i], "--config") && i + 1 < argc)
            which = argv[++i];
        else if (!strcmp(argv[i], "--tmp") && i + 1 < argc)
            tmpdir = argv[++i];
        else {
            fprintf(stderr, "usage: f4d-bench tokens [--config mid|tiny|f4d|both|all] [--size HxW] "
                            "[--reps R] [--margins A,B] [--threads N] [--tmp DIR] [--json FILE]\n");
            return 2;
        }
    }
    if (H % 14 || W % 14 || H < 14 || W < 14 || H > 2044 || W > 2044 || reps < 1 ||
        margin[0] < 0 || margin[1] < 0 ||
        (strcmp(which, "mid") && strcmp(which, "tiny") && strcmp(which, "both") &&
         strcmp(which, "f4d") && strcmp(which, "all"))) {
        fprintf(stderr, "f4d-bench tokens: bad --size/--reps/--margins/--config\n");
        return 2;
    }
    fk_ctx *ctx;
    struct fk_ctx_config cc = { .threads = threads };
    if (fk_ctx_new(&cc, &ctx) != F4D_OK) {
        fprintf(stderr, "f4d-bench tokens: cannot create the kernel context\n");
        return 1;
    }
    struct f4d_err err = {0};
    struct take t = { .H = H, .W = W };
    const size_t hw = (size_t)H * W, n = (size_t)TV * 3 * hw;
    const int p = 14, P = (H / p) * (W / p);
    float *img = malloc(n * sizeof *img), *prime = malloc(n * sizeof *prime);
    float *prime2 = malloc(n * sizeof *prime2);
    struct f4d_result f4r;
    memset(&f4r, 0, sizeof f4r);
    uint8_t *gt = malloc((size_t)TV * hw), *keep[2] = { malloc((size_t)TV * P), malloc((size_t)TV * P) };
    t.rgb = malloc(hw * 3 * sizeof *t.rgb);
    t.alpha = malloc(hw * sizeof *t.alpha);
    fg_model *g = NULL;
    int rc = 1;
    struct cfg_result res[2];
    memset(res, 0, sizeof res);
    if (!img || !prime || !prime2 || !gt || !keep[0] || !keep[1] || !t.rgb || !t.alpha) {
        fprintf(stderr, "f4d-bench tokens: out of memory\n");
        goto out;
    }
    if (scene_new(SCENE_WALK, 7, 0, &t.sc, &err) < 0 ||
        splat_renderer_new(ctx, W, H, &t.r, &err) < 0) {
        fprintf(stderr, "f4d-bench tokens: %s\n", err.msg);
        goto out;
    }
    scene_default_rig(t.sc, TV, W, H, &t.rig);
    struct fg_config fc = { .views = TV, .height = H, .width = W, .patch = p,
                            .samples = LEARN_SETS };
    if (fg_new(&fc, &g, &err) < 0) {
        fprintf(stderr, "f4d-bench tokens: %s\n", err.msg);
        goto out;
    }
    double t0 = bench_now();
    for (int k = 0; k < LEARN_SETS; k++)
        if (take_frame(&t, k * LEARN_STEP, img, NULL) < 0 || fg_learn(g, img, &err) < 0)
            goto out_err;
    double t_learn = bench_now() - t0;
    if (take_frame(&t, KEY_PREV - 3, prime2, NULL) < 0 ||
        take_frame(&t, KEY_PREV, prime, NULL) < 0 || take_frame(&t, KEY, img, gt) < 0)
        goto out;
    int kept[2][TV];
    double t_mask = INFINITY;
    for (int k = 0; k < 2; k++)
        for (int r = 0; r < 5; r++) {
            double a = bench_now();
            if (fg_mask(g, img, margin[k], keep[k], kept[k], &err) < 0)
                goto out_err;
            t_mask = fmin(t_mask, bench_now() - a);
        }
    /* the mask against the person: pixel IoU (changed pixels), person
     * patches (>= 2 % of the patch) kept at each margin */
    const uint8_t *pix = fg_pixels(g);
    size_t inter = 0, uni = 0;
    for (size_t i = 0; i < (size_t)TV * hw; i++) {
        inter += pix[i] && gt[i];
        uni += pix[i] || gt[i];
    }
    int gt_patches = 0, missed[2] = { 0, 0 };
    for (int v = 0; v < TV; v++)
        for (int pi = 0; pi < P; pi++) {
            int r0 = pi / (W / p) * p, c0 = pi % (W / p) * p, cnt = 0;
            for (int y = r0; y < r0 + p; y++)
                for (int x = c0; x < c0 + p; x++)
                    cnt += gt[(size_t)v * hw + (size_t)y * W + x];
            if (cnt >= 4) {
                gt_patches++;
                for (int k = 0; k < 2; k++)
                    missed[k] += !keep[k][(size_t)v * P + pi];
            }
        }
    printf("tokens: walk take, %d views %dx%d (%d patches each), %d threads (%s); background "
           "from %d sets (every %d frames) in %.2f s; key %d after key %d\n", TV, W, H, P,
           fk_ctx_threads(ctx), fk_isa_name(fk_ctx_isa(ctx)), LEARN_SETS, LEARN_STEP, t_learn,
           KEY, KEY_PREV);
    printf("mask: pixel IoU %.3f against the person (ground truth), %d person patches, missed "
           "at margin %d / %d: %d / %d; keep-list %.2f ms\n", uni ? (double)inter / uni : 0.0,
           gt_patches, margin[0], margin[1], missed[0], missed[1], 1e3 * t_mask);

    char path[1024];
    snprintf(path, sizeof path, "%s/f4d-bench-tokens-%d.gguf", tmpdir, (int)getpid());
    int nres = 0;
    const int run_f4d = !strcmp(which, "f4d") || !strcmp(which, "all");
    if (!strcmp(which, "mid") || !strcmp(which, "both") || !strcmp(which, "all")) {
        res[nres].name = "mid";
        config_mid(&res[nres++].c);
    }
    if (!strcmp(which, "tiny") || !strcmp(which, "both") || !strcmp(which, "all")) {
        res[nres].name = "tiny";
        bench_preset_tiny(&res[nres++].c);
    }
    for (int ri = 0; ri < nres; ri++) {
        struct cfg_result *R = &res[ri];
        if (bench_config(ctx, path, R, img, prime, keep, gt, H, W, reps) < 0)
            goto out;
        printf("\nmodel %s (embed %d, depth %d, DINO %d, DPT features %d; random weights, f32, "
               "+ Gaussian and scale heads), best of %d:\n", R->name, R->c.embed_dim,
               R->c.depth, R->c.dino_depth, R->c.dpt_features, reps);
        printf("  %-9s %8s %7s %8s %8s %-21s %6s %21s %9s %9s %7s\n", "run", "key s",
               "speedup", "aggr s", "heads s", "tokens per view", "total",
               "depth person/rest/all", "depth max", "pts mean", "PSNR");
        for (int k = -1; k < 3; k++) {
            const struct shot *s = k < 0 ? &R->all : k < 2 ? &R->mk[k] : &R->prev;
            char lab[32], tok[64];
            if (k < 0)
                snprintf(lab, sizeof lab, "all");
            else if (k < 2)
                snprintf(lab, sizeof lab, "margin %d", margin[k]);
            else
                snprintf(lab, sizeof lab, "last key");
            snprintf(tok, sizeof tok, "%d %d %d %d", s->tokens[0], s->tokens[1], s->tokens[2],
                     s->tokens[3]);
            if (k < 2)
                printf("  %-9s %8.3f %6.2fx %8.3f %8.3f %-21s %6d", lab, s->seconds,
                       R->all.seconds / s->seconds, s->agg_s, s->heads_s, tok, s->total);
            else
                printf("  %-9s %8s %7s %8s %8s %-21s %6s", lab, "0", "-", "-", "-",
                       "(key 150 as it is)", "-");
            if (k < 0)
                printf(" %21s %9s %9s %7s\n", "-", "-", "-", "-");
            else
                printf("  %.1e/%.1e/%.1e %9.2e %9.2e %7.2f%s\n", R->d_person[k], R->d_rest[k],
                       R->d_mean[k], R->d_max[k], R->p_mean[k],
                       k < 2 ? R->psnr[k] : R->psnr_prev,
                       k < 2 && !s->masked ? " (not masked!)" : "");
        }
    }
    if (run_f4d) {
        struct model_config fcfg;
        config_mid(&fcfg);
        const float *const frames[3] = { prime2, prime, img };
        if (bench_f4d(ctx, path, &fcfg, &f4r, frames, keep, gt, H, W, reps) < 0)
            goto out;
        printf("\nmodel f4d (mid + state blocks, motion blocks, motion head; random weights, "
               "f32): frames %d, %d every patch, step %d timed, best of %d:\n", KEY_PREV - 3,
               KEY_PREV, KEY, reps);
        printf("  %-9s %8s %7s %8s %7s %8s %7s %8s %6s %15s %15s %9s\n", "run", "step s",
               "speedup", "key s", "speedup", "motion s", "speedup", "aggr s", "tokens",
               "depth pers/rest", "M1 pers/rest", "M1 max");
        for (int k = 0; k < 3; k++) {
            const struct f4d_shot *s = &f4r.run[k], *a = &f4r.run[0];
            char lab[32];
            if (k)
                snprintf(lab, sizeof lab, "margin %d", margin[k - 1]);
            else
                snprintf(lab, sizeof lab, "all");
            printf("  %-9s %8.3f %6.2fx %8.3f %6.2fx %8.3f %6.2fx %8.3f %6d", lab, s->seconds,
                   a->seconds / s->seconds, s->key_s, a->key_s / s->key_s, s->motion_s,
                   a->motion_s / s->motion_s, s->agg_s, s->total);
            if (k)
                printf("  %.1e/%.1e %.1e/%.1e %9.2e%s\n", f4r.d_person[k - 1], f4r.d_rest[k - 1],
                       f4r.m_person[k - 1], f4r.m_rest[k - 1], f4r.m_max[k - 1],
                       s->masked ? "" : " (not masked!)");
            else
                printf(" %15s %15s %9s\n", "-", "-", "-");
        }
    }
    if (json) {
        FILE *jf = fopen(json, "w");
        if (!jf) {
            fprintf(stderr, "f4d-bench tokens: cannot create '%s'\n", json);
            goto out;
        }
        fprintf(jf, "{\n  \"views\": %d, \"height\": %d, \"width\": %d, \"patches\": %d, "
                "\"threads\": %d,\n  \"mask\": {\"pixel_iou\": %.4f, \"person_patches\": %d, "
                "\"margins\": [%d, %d], \"missed\": [%d, %d]},\n  \"configs\": [", TV, H, W, P,
                fk_ctx_threads(ctx), uni ? (double)inter / uni : 0.0, gt_patches, margin[0],
                margin[1], missed[0], missed[1]);
        for (int ri = 0; ri < nres; ri++) {
            const struct cfg_result *R = &res[ri];
            fprintf(jf, "%s\n    {\"config\": \"%s\", \"all_s\": %.4f, \"psnr_last_key\": %.3f, "
                    "\"depth_mean_rel_last_key\": %.4e, \"depth_person_rel_last_key\": %.4e, "
                    "\"runs\": [", ri ? "," : "", R->name, R->all.seconds, R->psnr_prev,
                    R->d_mean[2], R->d_person[2]);
            for (int k = 0; k < 2; k++)
                fprintf(jf, "%s{\"margin\": %d, \"seconds\": %.4f, \"speedup\": %.3f, "
                        "\"tokens\": %d, \"tokens_all\": %d, \"depth_max_rel\": %.4e, "
                        "\"depth_mean_rel\": %.4e, \"depth_person_rel\": %.4e, "
                        "\"depth_rest_rel\": %.4e, \"points_max_rel\": %.4e, "
                        "\"points_mean_rel\": %.4e, \"psnr\": %.3f, \"aggregator_s\": %.4f, "
                        "\"heads_s\": %.4f}", k ? ", " : "", margin[k],
                        R->mk[k].seconds, R->all.seconds / R->mk[k].seconds, R->mk[k].total,
                        R->all.total, R->d_max[k], R->d_mean[k], R->d_person[k], R->d_rest[k],
                        R->p_max[k], R->p_mean[k], R->psnr[k], R->mk[k].agg_s, R->mk[k].heads_s);
            fprintf(jf, "]}");
        }
        fprintf(jf, "\n  ]");
        if (f4r.ok) {
            fprintf(jf, ",\n  \"f4d\": [");
            for (int k = 0; k < 3; k++) {
                const struct f4d_shot *s = &f4r.run[k];
                fprintf(jf, "%s{\"margin\": %d, \"step_s\": %.4f, \"key_s\": %.4f, "
                        "\"motion_s\": %.4f, \"aggregator_s\": %.4f, \"tokens\": %d, "
                        "\"masked\": %d", k ? ", " : "", k ? margin[k - 1] : -1, s->seconds,
                        s->key_s, s->motion_s, s->agg_s, s->total, s->masked);
                if (k)
                    fprintf(jf, ", \"depth_person_rel\": %.4e, \"depth_rest_rel\": %.4e, "
                            "\"m1_person_rel\": %.4e, \"m1_rest_rel\": %.4e, "
                            "\"m1_max_rel\": %.4e", f4r.d_person[k - 1], f4r.d_rest[k - 1],
                            f4r.m_person[k - 1], f4r.m_rest[k - 1], f4r.m_max[k - 1]);
                fprintf(jf, "}");
            }
            fprintf(jf, "]");
        }
        fprintf(jf, "\n}\n");
        fclose(jf);
    }
    rc = 0;
    goto out;
out_err:
    fprintf(stderr, "f4d-bench tokens: %s\n", err.msg);
out:
    for (int ri = 0; ri < 2; ri++) {
        shot_free(&res[ri].all);
        shot_free(&res[ri].prev);
        shot_free(&res[ri].mk[0]);
        shot_free(&res[ri].mk[1]);
    }
    fg_free(g);
    splat_frame_free(&t.f);
    splat_renderer_free(t.r);
    scene_free(t.sc);
    free(t.rgb);
    free(t.alpha);
    free(img);
    free(prime);
    free(prime2);
    f4d_free(&f4r);
    free(gt);
    free(keep[0]);
    free(keep[1]);
    fk_ctx_free(ctx);
    return rc;
}
