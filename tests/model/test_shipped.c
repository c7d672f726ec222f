/* test_shipped.c - the model shipped in firmware/infer/weights (trained by
 * tools/train on synthetic venues) is found by default, loads in f32 and int8,
 * and on a synthetic frame set (3 views of a scene from firmware/synth/scene)
 * gives finite outputs: cameras, depth, points, Gaussians valid for the splat
 * library, a positive gauge; and its metric output is on a metric scale (the
 * cameras stand 3 m from the figure: metric depth of the figure within a
 * factor two of the truth), which random weights do not give. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>

#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "model.h"
#include "scene.h"
#include "splat.h"
#include "weights.h"

#define V 3
#define SZ 112

static float *synthetic_views(float *truth_depth)
{
    struct f4d_err err = {0};
    scene *s = NULL;
    if (scene_new(SCENE_WAVE, 5, 20000, &s, &err) < 0)
        fail_msg("%s", err.msg);
    struct splat_rig rig;
    scene_default_rig(s, V, SZ, SZ, &rig);
    struct splat_frame f = {0};
    assert_int_equal(scene_eval(s, 0.4, 0.0, &f, &err), 0);
    fk_ctx *ctx;
    struct fk_ctx_config cc = { .isa = FK_ISA_AUTO, .threads = 1 };
    assert_int_equal(fk_ctx_new(&cc, &ctx), F4D_OK);
    splat_renderer *r;
    assert_int_equal(splat_renderer_new(ctx, SZ, SZ, &r, &err), 0);
    float *hwc = malloc(3 * SZ * SZ * sizeof(float)), *img = malloc((size_t)V * 3 * SZ * SZ * sizeof(float));
    assert_non_null(hwc);
    assert_non_null(img);
    for (int v = 0; v < V; v++) {
        struct splat_render_out o = { .rgb = hwc, .depth = truth_depth + (size_t)v * SZ * SZ };
        assert_int_equal(splat_render(r, &rig.cams[v], &f, scene_background(), &o), 0);
        for (int c = 0; c < 3; c++)
            for (int p = 0; p < SZ * SZ; p++) {
                float x = hwc[3 * p + c];
                img[((size_t)v * 3 + c) * SZ * SZ + p] = x < 0 ? 0 : (x > 1 ? 1 : x);
            }
    }
    free(hwc);
    splat_renderer_free(r);
    fk_ctx_free(ctx);
    splat_frame_free(&f);
    scene_free(s);
    return img;
}

static void run(int int8)
{
    char path[F4D_WEIGHTS_PATH_MAX];
    struct f4d_err err = {0};
    if (f4d_weights_default(int8, path, sizeof path, &err) < 0)
        fail_msg("%s", err.msg);
    float *truth = malloc((size_t)V * SZ * SZ * sizeof(float));
    assert_non_null(truth);
    float *img = synthetic_views(truth);
    fk_ctx *ctx;
    struct fk_ctx_config cc = { .isa = FK_ISA_AUTO, .threads = 2 };
    assert_int_equal(fk_ctx_new(&cc, &ctx), F4D_OK);
    struct model *m = NULL;
    if (model_init(ctx, path, int8 ? FK_W_Q8 : FK_W_F32, &m, &err) < 0)
        fail_msg("%s: %s", path, err.msg);
    if (model_prepare(m, V, SZ, SZ) < 0)
        fail_msg("%s", model_error(m));
    struct model_outputs o;
    if (model_eval(m, img, V, SZ, SZ, &o) < 0)
        fail_msg("%s", model_error(m));
    assert_non_null(o.depth);
    assert_non_null(o.world_points);
    assert_non_null(o.extrinsic_metric);
    assert_true(o.has_gauge);
    assert_true(isfinite(o.gauge) && o.gauge > 0.0f);
    const size_t np = (size_t)V * SZ * SZ;
    for (size_t i = 0; i < np; i++) {
        assert_true(isfinite(o.depth[i]) && isfinite(o.depth_conf[i]));
        for (int k = 0; k < 3; k++)
            assert_true(isfinite(o.world_points[3 * i + k]));
    }
    for (int i = 0; i < V * 12; i++)
        assert_true(isfinite(o.extrinsic_metric[i]) && isfinite(o.intrinsic[i % 9 + 9 * (i / 12)]));
    const struct model_gaussians *g = &o.gaussians;
    assert_int_equal(g->count, np);
    const struct splat_frame fr = { .count = g->count, .capacity = g->count, .pos = g->pos, .scale = g->scale,
                                    .rot = g->rot, .opacity = g->opacity, .rgb = g->rgb };
    if (splat_frame_validate(&fr, &err) < 0)
        fail_msg("%s", err.msg);
    /* metric scale: model depth / gauge against the rendered truth on the figure and floor */
    double ratio = 0;
    size_t n = 0;
    for (size_t i = 0; i < np; i++)
        if (truth[i] > 0.5f) {
            ratio += log((double)o.depth[i] / o.gauge / truth[i]);
            n++;
        }
    assert_true(n > np / 4);
    ratio = exp(ratio / (double)n);
    print_message("shipped %s (%s): gauge %.4f, metric depth / truth (geometric mean) %.3f\n",
                  int8 ? "int8" : "f32", path, (double)o.gauge, ratio);
    assert_true(ratio > 0.5 && ratio < 2.0);
    model_free(m);
    fk_ctx_free(ctx);
    free(img);
    free(truth);
}

static void test_f32(void **state) { (void)state; run(0); }
static void test_int8(void **state) { (void)state; run(1); }

static void test_env_override(void **state)
{
    (void)state;
    char path[F4D_WEIGHTS_PATH_MAX];
    struct f4d_err err = {0};
    setenv("F4D_WEIGHTS", "/nonexistent/forge4d.gguf", 1);
    assert_int_equal(f4d_weights_default(0, path, sizeof path, &err), F4D_ENOENT);
    assert_non_null(strstr(err.msg, "/nonexistent/forge4d.gguf"));
    unsetenv("F4D_WEIGHTS");
    assert_int_equal(f4d_weights_default(0, path, 4, &err), F4D_ERANGE);
}

int main(void)
{
    unsetenv("F4D_WEIGHTS");
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_env_override),
        cmocka_unit_test(test_f32),
        cmocka_unit_test(test_int8),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
