/* test_foreground.c - the background model and keep-lists (foreground.h).
 *
 * - walk take (firmware/synth/scene, 4 views of 224x224 rendered through
 *   splat): learned from 15 sets (every 8th of the first 120 frames), the
 *   changed pixels at later frames against the scene's ground-truth person
 *   pixels (the figure's Gaussians alone, alpha > 0.5): IoU; the keep-list
 *   at margin 1 holds every patch the person covers and leaves the static
 *   floor and sky mostly out;
 * - sensor-like noise in the learning sets: the MAD threshold keeps a new
 *   noisy frame of the empty scene out of the mask;
 * - dilation on a hand-made change (margin 0, 1, 2, clipped at the corner),
 *   an unchanged set (empty keep-lists), and the argument errors. */
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <cmocka.h>

#include "fk_ctx.h"
#include "foreground.h"
#include "scene.h"
#include "splat.h"

#define V  4
#define HH 224
#define WW 224
#define PS 14
#define GH (HH / PS)
#define GW (WW / PS)
#define NP (GH * GW)

struct take {
    fk_ctx         *ctx;
    scene          *sc;
    splat_renderer *r;
    struct splat_rig rig;
    struct splat_frame f;
    float          *rgb, *alpha;
};

static void take_open(struct take *t)
{
    struct f4d_err err = {0};
    struct fk_ctx_config cc = { .isa = FK_ISA_AUTO, .threads = 2 };
    memset(t, 0, sizeof *t);
    assert_int_equal(fk_ctx_new(&cc, &t->ctx), F4D_OK);
    assert_int_equal(scene_new(SCENE_WALK, 7, 0, &t->sc, &err), 0);
    scene_default_rig(t->sc, V, WW, HH, &t->rig);
    assert_int_equal(splat_renderer_new(t->ctx, WW, HH, &t->r, &err), 0);
    t->rgb = malloc((size_t)HH * WW * 3 * sizeof *t->rgb);
    t->alpha = malloc((size_t)HH * WW * sizeof *t->alpha);
    assert_true(t->rgb && t->alpha);
}

static void take_close(struct take *t)
{
    splat_frame_free(&t->f);
    splat_renderer_free(t->r);
    scene_free(t->sc);
    free(t->rgb);
    free(t->alpha);
    fk_ctx_free(t->ctx);
}

/* Frame k as model input [V, 3, H, W]; with gt, the person's pixels [V, H, W]. */
static void take_frame(struct take *t, int k, float *img, uint8_t *gt)
{
    struct f4d_err err = {0};
    assert_int_equal(scene_eval(t->sc, k / SCENE_FPS, 0.0, &t->f, &err), 0);
    const size_t hw = (size_t)HH * WW;
    for (int v = 0; v < V; v++) {
        struct splat_render_out o = { .rgb = t->rgb };
        assert_int_equal(splat_render(t->r, &t->rig.cams[v], &t->f, scene_background(), &o), 0);
        for (size_t i = 0; i < hw; i++)
            for (int c = 0; c < 3; c++) {
                float x = t->rgb[i * 3 + c];
                img[((size_t)v * 3 + c) * hw + i] = x < 0 ? 0 : x > 1 ? 1 : x;
            }
    }
    if (!gt)
        return;
    const size_t nfig = scene_figure_count(t->sc);
    assert_true(nfig > 0 && nfig < t->f.count);
    for (size_t i = nfig; i < t->f.count; i++)
        t->f.opacity[i] = 0.0f;
    for (int v = 0; v < V; v++) {
        struct splat_render_out o = { .alpha = t->alpha };
        assert_int_equal(splat_render(t->r, &t->rig.cams[v], &t->f, NULL, &o), 0);
        for (size_t i = 0; i < hw; i++)
            gt[(size_t)v * hw + i] = t->alpha[i] > 0.5f;
    }
}

static void test_walk_take(void **state)
{
    (void)state;
    struct take t;
    take_open(&t);
    struct f4d_err err = {0};
    const size_t n = (size_t)V * 3 * HH * WW, hw = (size_t)HH * WW;
    float *img = malloc(n * sizeof *img);
    uint8_t *gt = malloc((size_t)V * hw);
    assert_true(img && gt);
    fg_model *g;
    struct fg_config c = { .views = V, .height = HH, .width = WW, .patch = PS, .samples = 15 };
    assert_int_equal(fg_new(&c, &g, &err), 0);
    for (int k = 0; k < 120; k += 8) {
        take_frame(&t, k, img, NULL);
        assert_int_equal(fg_learn(g, img, &err), k == 112 ? 1 : 0);
    }
    assert_true(fg_ready(g));
    static const int frames[3] = { 63, 130, 170 };
    for (int fi = 0; fi < 3; fi++) {
        take_frame(&t, frames[fi], img, gt);
        uint8_t keep0[V * NP], keep1[V * NP];
        int kept0[V], kept1[V];
        assert_int_equal(fg_mask(g, img, 0, keep0, kept0, &err), 0);
        const uint8_t *pix = fg_pixels(g);
        size_t inter = 0, uni = 0, gt_n = 0, fg_n = 0;
        for (size_t i = 0; i < (size_t)V * hw; i++) {
            inter += pix[i] && gt[i];
            uni += pix[i] || gt[i];
            gt_n += gt[i];
            fg_n += pix[i];
        }
        double iou = (double)inter / (double)uni;
        assert_int_equal(fg_mask(g, img, 1, keep1, kept1, &err), 0);
        /* patches holding at least 2 % of person pixels (the keep rule's own
         * fraction): every one is kept at margin 1 */
        int gt_patches = 0, missed = 0, total1 = 0, total0 = 0;
        for (int v = 0; v < V; v++) {
            total1 += kept1[v];
            total0 += kept0[v];
            for (int r = 0; r < GH; r++)
                for (int cc = 0; cc < GW; cc++) {
                    int cnt = 0;
                    for (int y = r * PS; y < (r + 1) * PS; y++)
                        for (int x = cc * PS; x < (cc + 1) * PS; x++)
                            cnt += gt[(size_t)v * hw + (size_t)y * WW + x];
                    if (cnt >= 4) {
                        gt_patches++;
                        missed += !keep1[v * NP + r * GW + cc];
                    }
                }
        }
        printf("  walk frame %d: pixel IoU %.3f (precision %.3f, recall %.3f; %zu person "
               "pixels), person patches %d, kept margin 0 / 1: %d / %d of %d, missed at "
               "margin 1: %d\n", frames[fi], iou, (double)inter / (double)fg_n,
               (double)inter / (double)gt_n, gt_n, gt_patches, total0, total1, V * NP, missed);
        assert_true(gt_n > 1000);
        assert_true(iou >= 0.9);
        assert_int_equal(missed, 0);
        assert_true(total0 >= gt_patches * 8 / 10);
        assert_true(total1 <= V * NP * 40 / 100);  /* the floor stays out */
    }
    fg_free(g);
    free(img);
    free(gt);
    take_close(&t);
}

static double noise(uint64_t *s)
{
    double u[2];
    for (int i = 0; i < 2; i++) {
        *s ^= *s >> 12;
        *s ^= *s << 25;
        *s ^= *s >> 27;
        u[i] = ((*s * UINT64_C(2685821657736338717)) >> 11) * (1.0 / 9007199254740992.0);
    }
    return sqrt(-2.0 * log(u[0] + 1e-300)) * cos(6.283185307179586 * u[1]);
}

/* Flat grey scene: K noisy sets, then a new noisy set (nothing changed) and
 * one with a bright square. */
static void test_noise_and_dilation(void **state)
{
    (void)state;
    struct f4d_err err = {0};
    enum { S = 2, H = 56, W = 70, h = 4, w = 5, P = h * w };
    const size_t hw = (size_t)H * W, n = (size_t)S * 3 * hw;
    float *img = malloc(n * sizeof *img);
    assert_non_null(img);
    uint64_t rs = 99;
    fg_model *g;
    struct fg_config c = { .views = S, .height = H, .width = W, .patch = 14, .samples = 15,
                           .threshold = 0.02f };
    assert_int_equal(fg_new(&c, &g, &err), 0);
    uint8_t keep[S * P];
    int kept[S];
    assert_int_equal(fg_mask(g, img, 0, keep, kept, &err), F4D_EINVAL);
    assert_non_null(strstr(err.msg, "not learned"));
    for (int k = 0; k < 15; k++) {
        for (size_t i = 0; i < n; i++)
            img[i] = (float)(0.5 + 0.03 * noise(&rs));
        assert_true(fg_learn(g, img, &err) >= 0);
    }
    assert_int_equal(fg_learn(g, img, &err), F4D_EINVAL);
    assert_non_null(strstr(err.msg, "already learned"));
    for (size_t i = 0; i < n; i++)
        img[i] = (float)(0.5 + 0.03 * noise(&rs));
    assert_int_equal(fg_mask(g, img, 2, keep, kept, &err), 0);
    assert_int_equal(kept[0] + kept[1], 0);
    size_t changed = 0;
    for (size_t i = 0; i < (size_t)S * hw; i++)
        changed += fg_pixels(g)[i];
    assert_true(changed < (size_t)S * hw / 1000);
    /* without the MAD term (noise_k tiny) the same noise shows up */
    fg_model *g2;
    struct fg_config c2 = c;
    c2.noise_k = 0.01f;
    assert_int_equal(fg_new(&c2, &g2, &err), 0);
    for (int k = 0; k < 15; k++) {
        for (size_t i = 0; i < n; i++)
            img[i] = (float)(0.5 + 0.03 * noise(&rs));
        assert_true(fg_learn(g2, img, &err) >= 0);
    }
    assert_int_equal(fg_mask(g2, img, 0, keep, kept, &err), 0);
    assert_true(kept[0] + kept[1] > 0);
    fg_free(g2);

    /* a bright 5x5 square inside patch (1, 2) of view 1 */
    for (size_t i = 0; i < n; i++)
        img[i] = 0.5f;
    for (int y = 16; y < 21; y++)
        for (int x = 30; x < 35; x++)
            img[((size_t)1 * 3 + 0) * hw + (size_t)y * W + x] = 1.0f;
    assert_int_equal(fg_mask(g, img, 0, keep, kept, &err), 0);
    assert_int_equal(kept[0], 0);
    assert_int_equal(kept[1], 1);
    assert_int_equal(keep[P + 1 * w + 2], 1);
    assert_int_equal(fg_mask(g, img, 1, keep, kept, &err), 0);
    assert_int_equal(kept[1], 9);
    for (int r = 0; r < h; r++)
        for (int cc = 0; cc < w; cc++)
            assert_int_equal(keep[P + r * w + cc], r <= 2 && cc >= 1 && cc <= 3);
    assert_int_equal(fg_mask(g, img, 2, keep, kept, &err), 0);
    assert_int_equal(kept[1], 4 * 5);   /* rows 0..3 (clipped), columns 0..4 */
    /* a corner patch, margin 1: clipped to 2 x 2 */
    for (size_t i = 0; i < n; i++)
        img[i] = 0.5f;
    for (int y = 0; y < 3; y++)
        for (int x = 0; x < 3; x++)
            img[(size_t)y * W + x] = 0.0f;
    assert_int_equal(fg_mask(g, img, 1, keep, kept, &err), 0);
    assert_int_equal(kept[0], 4);
    assert_int_equal(kept[1], 0);
    assert_true(keep[0] && keep[1] && keep[w] && keep[w + 1]);
    /* NaN pixels are not background */
    for (int y = 5; y < 7; y++)
        for (int x = 60; x < 62; x++)
            img[(size_t)2 * hw + (size_t)y * W + x] = NAN;
    assert_int_equal(fg_mask(g, img, 0, keep, kept, &err), 0);
    assert_int_equal(kept[0], 2);
    assert_int_equal(fg_mask(g, img, -1, keep, kept, &err), F4D_EINVAL);
    assert_non_null(strstr(err.msg, "margin"));
    fg_free(g);
    free(img);
}

static void test_config_errors(void **state)
{
    (void)state;
    struct f4d_err err = {0};
    fg_model *g = (fg_model *)&err;
    struct fg_config ok = { .views = 2, .height = 28, .width = 42, .patch = 14, .samples = 5 };
    struct { struct fg_config c; const char *msg; } bad[] = {
        { ok, "views" }, { ok, "multiple" }, { ok, "multiple" }, { ok, "samples" },
        { ok, "threshold" }, { ok, "min_fraction" }, { ok, "patch size" },
    };
    bad[0].c.views = 0;
    bad[1].c.width = 40;
    bad[2].c.height = 0;
    bad[3].c.samples = FG_SAMPLES_MAX + 1;
    bad[4].c.threshold = -0.5f;
    bad[5].c.min_fraction = NAN;
    bad[6].c.patch = 0;
    for (size_t i = 0; i < sizeof bad / sizeof bad[0]; i++) {
        memset(&err, 0, sizeof err);
        assert_int_equal(fg_new(&bad[i].c, &g, &err), F4D_EINVAL);
        assert_null(g);
        if (!strstr(err.msg, bad[i].msg))
            print_error("case %zu: '%s' lacks '%s'\n", i, err.msg, bad[i].msg);
        assert_non_null(strstr(err.msg, bad[i].msg));
    }
    assert_int_equal(fg_new(&ok, &g, &err), 0);
    assert_int_equal(fg_learn(g, NULL, &err), F4D_EINVAL);
    assert_null(fg_background(g));
    uint8_t keep[2 * 6];
    float img[2 * 3 * 28 * 42] = { 0 };
    assert_int_equal(fg_mask(g, img, 0, NULL, NULL, &err), F4D_EINVAL);
    assert_non_null(strstr(err.msg, "keep-list"));
    for (int k = 0; k < 5; k++)
        assert_int_equal(fg_learn(g, img, &err), k == 4);
    assert_non_null(fg_background(g));
    assert_int_equal(fg_mask(g, img, 0, keep, NULL, &err), 0);
    for (int i = 0; i < 12; i++)
        assert_int_equal(keep[i], 0);
    fg_reset(g);
    assert_false(fg_ready(g));
    assert_int_equal(fg_mask(g, img, 0, keep, NULL, &err), F4D_EINVAL);
    fg_free(g);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_config_errors),
        cmocka_unit_test(test_noise_and_dilation),
        cmocka_unit_test(test_walk_take),
    };
    return cmocka_run_group_tests_name("/model/foreground", tests, NULL, NULL);
}
