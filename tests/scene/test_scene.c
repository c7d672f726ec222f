/* test_scene.c - synthetic 4D scenes: figure size, exact motion at any real
 * time, every preset finite and moving, the default rig, the hard presets
 * really being hard, determinism, bad input. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>

#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "scene.h"

/* NaN-aware running maximum: once a NaN is seen the result stays NaN, so any
 * bound check on it (x < tol) fails; fmax() would silently drop the NaN. */
static double max_nan(double m, double v)
{
    return isnan(m) || isnan(v) ? NAN : (v > m ? v : m);
}

static scene *make(enum scene_preset p, uint64_t seed)
{
    scene *s = NULL;
    struct f4d_err err;
    if (scene_new(p, seed, 0, &s, &err) < 0)
        fail_msg("%s", err.msg);
    return s;
}

static void test_figure_height_and_counts(void **state)
{
    (void)state;
    for (uint64_t seed = 0; seed < 12; seed++) {
        scene *s = make(SCENE_WAVE, seed);
        assert_true(scene_height(s) >= 1.6f && scene_height(s) <= 1.9f);
        struct splat_frame f = { 0 };
        assert_int_equal(scene_eval(s, 0.0, 0.0, &f, NULL), 0);
        float zmax = 0;
        for (size_t i = 0; i < f.count; i++)
            zmax = (float)max_nan(zmax, f.pos[3 * i + 2]);
        /* the top of the head is the figure's height within a few centimetres */
        assert_true(fabsf(zmax - scene_height(s)) < 0.08f);
        assert_true(f.count > 20000 && f.count < 60000);
        splat_frame_free(&f);
        scene_free(s);
    }
}

static void test_motion_is_exact_at_any_time(void **state)
{
    (void)state;
    const double times[] = { 0.0, 0.5 / SCENE_FPS, 1.37, -0.25, 12.3456 };
    for (int p = 0; p < SCENE_PRESET_COUNT; p++) {
        scene *s = make((enum scene_preset)p, 3);
        struct splat_frame f = { 0 };
        size_t n = scene_count(s);
        float *a = malloc(3 * n * sizeof(float)), *b = malloc(3 * n * sizeof(float));
        for (size_t k = 0; k < sizeof times / sizeof times[0]; k++) {
            double t = times[k], dt = 1.0 / SCENE_FPS;
            assert_int_equal(scene_eval(s, t, dt, &f, NULL), 0);
            struct f4d_err err;
            assert_int_equal(splat_frame_validate(&f, &err), 0);
            scene_positions(s, t - dt, a);
            scene_positions(s, t + dt, b);
            double maxd = 0, moved = 0;
            for (size_t i = 0; i < 3 * n; i++) {
                maxd = max_nan(maxd, fabs((double)f.pos[i] + f.motion_bwd[i] - a[i]));
                maxd = max_nan(maxd, fabs((double)f.pos[i] + f.motion_fwd[i] - b[i]));
                moved = max_nan(moved, fabs((double)f.motion_fwd[i]));
            }
            assert_true(maxd < 1e-5);  /* motion = exact displacement (float rounding only) */
            assert_true(moved > 1e-3); /* every preset moves at every time */
            /* continuity: a tiny time step moves nothing far (the ball included) */
            scene_positions(s, t + 1e-5, a);
            double step = 0;
            for (size_t i = 0; i < 3 * n; i++)
                step = max_nan(step, fabs((double)a[i] - f.pos[i]));
            assert_true(step < 1e-3);
        }
        free(a);
        free(b);
        splat_frame_free(&f);
        scene_free(s);
    }
}

static void test_default_rig(void **state)
{
    (void)state;
    scene *s = make(SCENE_WALK, 1);
    struct splat_rig rig;
    scene_default_rig(s, SCENE_VIEWS_DEFAULT, 518, 518, &rig);
    assert_int_equal(rig.count, 4);
    float c[4][3];
    for (int k = 0; k < 4; k++) {
        struct f4d_err err;
        assert_int_equal(splat_camera_validate(&rig.cams[k], &err), 0);
        assert_int_equal(rig.cams[k].width, 518);
        splat_camera_center(&rig.cams[k], c[k]);
        /* the subject's middle projects near the image centre */
        float mid[3] = { 0, 0, 0.95f * scene_height(s) / 1.78f }, q[3];
        splat_camera_to_cam(&rig.cams[k], mid, q);
        assert_true(q[2] > 2.5f);
        assert_true(fabsf(rig.cams[k].fx * q[0] / q[2]) < 2.0f);
    }
    for (int k = 0; k < 3; k++) {
        float a0 = atan2f(c[k][0], c[k][1]), a1 = atan2f(c[k + 1][0], c[k + 1][1]);
        assert_float_equal(fabsf(a1 - a0) * 180.0f / 3.14159265f, 45.0f, 0.01f);
    }
    scene_free(s);
}

static float min_camera_distance(const scene *s, const struct splat_camera *cam, double t)
{
    struct splat_frame f = { 0 };
    assert_int_equal(scene_eval(s, t, 0.0, &f, NULL), 0);
    float c[3], best = 1e9f;
    splat_camera_center(cam, c);
    for (size_t i = 0; i < f.count; i++) {
        if (f.pos[3 * i + 2] < 0.01f)
            continue; /* floor */
        float d = 0;
        for (int k = 0; k < 3; k++)
            d += (f.pos[3 * i + k] - c[k]) * (f.pos[3 * i + k] - c[k]);
        best = fminf(best, sqrtf(d));
    }
    splat_frame_free(&f);
    return best;
}

static void test_close_preset_has_a_camera_within_half_a_metre(void **state)
{
    (void)state;
    scene *s = make(SCENE_CLOSE, 2);
    struct splat_rig rig;
    scene_default_rig(s, 4, 518, 518, &rig);
    for (double t = 0; t < 4.0; t += 0.5)
        assert_true(min_camera_distance(s, &rig.cams[3], t) < 0.5f);
    assert_true(min_camera_distance(s, &rig.cams[0], 0.0) > 2.0f);
    scene_free(s);
}

/* Is any Gaussian of the ball (the ones far above the body or away from it)
 * inside the image of any camera? */
static int ball_visible(const scene *s, const struct splat_rig *rig, double t, size_t b0, size_t b1)
{
    struct splat_frame f = { 0 };
    assert_int_equal(scene_eval(s, t, 0.0, &f, NULL), 0);
    int vis = 0;
    for (size_t i = b0; i < b1 && !vis; i++)
        for (int c = 0; c < rig->count && !vis; c++) {
            float q[3];
            splat_camera_to_cam(&rig->cams[c], f.pos + 3 * i, q);
            if (q[2] <= 0.2f)
                continue;
            float u = rig->cams[c].fx * q[0] / q[2] + rig->cams[c].cx;
            float v = rig->cams[c].fy * q[1] / q[2] + rig->cams[c].cy;
            vis = u >= 0 && v >= 0 && u < rig->cams[c].width && v < rig->cams[c].height;
        }
    splat_frame_free(&f);
    return vis;
}

static void test_exit_ball_leaves_and_returns(void **state)
{
    (void)state;
    scene *s = make(SCENE_EXIT, 4);
    struct splat_rig rig;
    scene_default_rig(s, 4, 518, 518, &rig);
    size_t n = scene_count(s);
    /* locate the ball: the contiguous run of Gaussians around the highest point at the apex */
    struct splat_frame f = { 0 };
    assert_int_equal(scene_eval(s, 1.0, 0.0, &f, NULL), 0);
    size_t top = 0;
    for (size_t i = 0; i < n; i++)
        if (f.pos[3 * i + 2] > f.pos[3 * top + 2])
            top = i;
    assert_true(f.pos[3 * top + 2] > 4.0f); /* way above every camera's view */
    size_t b0 = top, b1 = top + 1;
    while (b0 > 0 && f.pos[3 * (b0 - 1) + 2] > 3.5f)
        b0--;
    while (b1 < n && f.pos[3 * b1 + 2] > 3.5f)
        b1++;
    assert_true(b1 - b0 > 100);
    assert_true(ball_visible(s, &rig, 0.0, b0, b1));
    assert_false(ball_visible(s, &rig, 1.0, b0, b1));
    assert_true(ball_visible(s, &rig, 2.0, b0, b1));
    splat_frame_free(&f);
    scene_free(s);
}

static double max_step(const scene *s, double t)
{
    struct splat_frame f = { 0 };
    assert_int_equal(scene_eval(s, t, 1.0 / SCENE_FPS, &f, NULL), 0);
    double m = 0;
    for (size_t i = 0; i < f.count; i++) {
        const float *d = f.motion_fwd + 3 * i;
        m = max_nan(m, sqrt((double)d[0] * d[0] + (double)d[1] * d[1] + (double)d[2] * d[2]));
    }
    splat_frame_free(&f);
    return m;
}

static void test_fast_moves_far_per_frame(void **state)
{
    (void)state;
    scene *fast = make(SCENE_FAST, 5), *walk = make(SCENE_WALK, 5);
    double mf = 0, mw = 0;
    for (double t = 0; t < 1.0; t += 0.1) {
        mf = max_nan(mf, max_step(fast, t));
        mw = max_nan(mw, max_step(walk, t));
    }
    assert_true(mf > 0.15);     /* > 15 cm per 1/30 s */
    assert_true(mf > 2.5 * mw);
    assert_true(mw < 0.12);
    scene_free(fast);
    scene_free(walk);
}

static void test_deterministic_by_seed(void **state)
{
    (void)state;
    scene *a = make(SCENE_THROW, 9), *b = make(SCENE_THROW, 9), *c = make(SCENE_THROW, 10);
    struct splat_frame fa = { 0 }, fb = { 0 }, fc = { 0 };
    assert_int_equal(scene_eval(a, 0.7, 0.0, &fa, NULL), 0);
    assert_int_equal(scene_eval(b, 0.7, 0.0, &fb, NULL), 0);
    assert_int_equal(scene_eval(c, 0.7, 0.0, &fc, NULL), 0);
    assert_int_equal(fa.count, fb.count);
    assert_memory_equal(fa.pos, fb.pos, 3 * fa.count * sizeof(float));
    assert_memory_equal(fa.rgb, fb.rgb, 3 * fa.count * sizeof(float));
    assert_true(fa.count != fc.count || memcmp(fa.pos, fc.pos, 3 * fa.count * sizeof(float)) != 0);
    splat_frame_free(&fa); splat_frame_free(&fb); splat_frame_free(&fc);
    scene_free(a); scene_free(b); scene_free(c);
}

static void test_sized_scene(void **state)
{
    (void)state;
    scene *s = NULL;
    assert_int_equal(scene_new(SCENE_WALK, 1, 100000, &s, NULL), 0);
    assert_true(scene_count(s) > 80000 && scene_count(s) < 125000);
    scene_free(s);
}

/* The per-pixel GT (rendered motion, depth, flow) agrees with the motion of
 * the Gaussian that dominates each pixel. */
static void test_pixel_flow_matches_gaussian_motion(void **state)
{
    (void)state;
    const int W = 160, H = 160;
    scene *s = make(SCENE_FAST, 2);
    struct splat_rig rig;
    scene_default_rig(s, 4, W, H, &rig);
    struct splat_frame f = { 0 };
    assert_int_equal(scene_eval(s, 0.4, 1.0 / SCENE_FPS, &f, NULL), 0);
    fk_ctx *ctx;
    struct fk_ctx_config cfg = { .isa = FK_ISA_AUTO, .threads = 2 };
    assert_int_equal(fk_ctx_new(&cfg, &ctx), F4D_OK);
    splat_renderer *r;
    assert_int_equal(splat_renderer_new(ctx, W, H, &r, NULL), 0);
    size_t np = (size_t)W * H;
    float *depth = malloc(np * sizeof(float)), *alpha = malloc(np * sizeof(float));
    float *mf = malloc(3 * np * sizeof(float)), *flow = malloc(2 * np * sizeof(float));
    int32_t *top = malloc(np * sizeof(int32_t));
    const struct splat_camera *cam = &rig.cams[1];
    struct splat_render_out o = { .depth = depth, .alpha = alpha, .top = top };
    assert_int_equal(splat_render(r, cam, &f, NULL, &o), 0);
    assert_int_equal(splat_render_features(r, cam, &f, f.motion_fwd, mf), 0);
    splat_flow_from_motion(cam, depth, alpha, mf, flow);
    size_t checked = 0, close = 0;
    double maxflow = 0;
    for (size_t p = 0; p < np; p++) {
        if (alpha[p] < 0.99f || top[p] < 0 || f.pos[3 * (size_t)top[p] + 2] < 0.05f)
            continue; /* opaque body pixels only */
        const float *x = f.pos + 3 * (size_t)top[p], *m = f.motion_fwd + 3 * (size_t)top[p];
        float a[3], b[3], x2[3] = { x[0] + m[0], x[1] + m[1], x[2] + m[2] };
        splat_camera_to_cam(cam, x, a);
        splat_camera_to_cam(cam, x2, b);
        float gx = cam->fx * (b[0] / b[2] - a[0] / a[2]), gy = cam->fy * (b[1] / b[2] - a[1] / a[2]);
        checked++;
        close += fabsf(gx - flow[2 * p]) < 0.5f && fabsf(gy - flow[2 * p + 1]) < 0.5f;
        maxflow = max_nan(maxflow, fabs(gx) + fabs(gy));
    }
    assert_true(checked > 500);
    assert_true(maxflow > 2.0);               /* `fast` really moves in the image */
    assert_true(close > checked * 9 / 10);    /* edges of limbs may mix two motions */
    free(depth); free(alpha); free(mf); free(flow); free(top);
    splat_renderer_free(r);
    fk_ctx_free(ctx);
    splat_frame_free(&f);
    scene_free(s);
}

static void test_bad_input_rejected(void **state)
{
    (void)state;
    struct f4d_err err;
    assert_int_equal(scene_preset_from_name("dance", &err), -1);
    assert_non_null(strstr(err.msg, "'dance'"));
    assert_non_null(strstr(err.msg, "throw"));
    assert_int_equal(scene_preset_from_name("close", &err), SCENE_CLOSE);
    scene *s = NULL;
    assert_int_equal(scene_new((enum scene_preset)42, 1, 0, &s, &err), F4D_EINVAL);
    assert_non_null(strstr(err.msg, "preset"));
    assert_int_equal(scene_new(SCENE_WALK, 1, 10, &s, &err), F4D_EINVAL);
    assert_non_null(strstr(err.msg, "10 Gaussians"));
    s = make(SCENE_WALK, 1);
    struct splat_frame f = { 0 };
    assert_int_equal(scene_eval(s, NAN, 0.0, &f, &err), F4D_EINVAL);
    assert_int_equal(scene_eval(s, 0.0, -1.0, &f, &err), F4D_EINVAL);
    scene_free(s);
}

/* The running maxima above are NaN-aware: an all-NaN array fails the bound. */
static void test_max_nan_fails_on_nan(void **state)
{
    (void)state;
    double m = 0;
    for (int i = 0; i < 16; i++)
        m = max_nan(m, NAN);
    assert_false(m < 1e-5);
    m = 0;
    m = max_nan(m, 1.0);
    m = max_nan(m, NAN);
    m = max_nan(m, 2.0);
    assert_false(m < 1e9);
    assert_false(m > 0.5);
    assert_true(max_nan(max_nan(0, 3.0), 1.0) == 3.0);
}

/* scene_new_desc: the placement is a rigid motion of the default figure, speed
 * rescales time, girth widens without changing height, no_floor drops only
 * the floor, and bad knobs are refused. */
static void test_scene_desc_knobs(void **state)
{
    (void)state;
    struct f4d_err err;
    scene *a = NULL, *b = NULL, *c = NULL, *g = NULL;
    struct scene_desc da = { .preset = SCENE_WAVE, .seed = 11, .gaussians = 4000, .no_floor = 1 };
    struct scene_desc db = da, dc = da, dg = da;
    db.offset[0] = 0.7f; db.offset[1] = -0.4f; db.yaw = 0.9f;
    dc.speed = 2.0f;
    dg.girth = 1.3f;
    assert_int_equal(scene_new_desc(&da, &a, &err), 0);
    assert_int_equal(scene_new_desc(&db, &b, &err), 0);
    assert_int_equal(scene_new_desc(&dc, &c, &err), 0);
    assert_int_equal(scene_new_desc(&dg, &g, &err), 0);
    scene *fl = NULL;
    assert_int_equal(scene_new(SCENE_WAVE, 11, 4000, &fl, &err), 0);
    assert_true(scene_count(a) < scene_count(fl));
    size_t n = scene_count(a);
    assert_int_equal(scene_count(b), n);
    float *pa = malloc(3 * n * sizeof(float)), *pb = malloc(3 * n * sizeof(float));
    float *pc = malloc(3 * n * sizeof(float)), *pg = malloc(3 * n * sizeof(float));
    assert_non_null(pa); assert_non_null(pb); assert_non_null(pc); assert_non_null(pg);
    double e_place = 0, e_speed = 0, za = -1e9, zg = -1e9, wa = 0, wg = 0;
    scene_positions(a, 0.7, pa);
    scene_positions(b, 0.7, pb);
    float cy = cosf(0.9f), sy = sinf(0.9f);
    for (size_t i = 0; i < n; i++) {
        float x = cy * pa[3 * i] - sy * pa[3 * i + 1] + 0.7f, y = sy * pa[3 * i] + cy * pa[3 * i + 1] - 0.4f;
        e_place = max_nan(e_place, fabs(x - pb[3 * i]) + fabs(y - pb[3 * i + 1]) + fabs(pa[3 * i + 2] - pb[3 * i + 2]));
    }
    scene_positions(a, 1.4, pa);
    scene_positions(c, 0.7, pc);
    for (size_t i = 0; i < 3 * n; i++)
        e_speed = max_nan(e_speed, fabs(pa[i] - pc[i]));
    scene_positions(a, 0.0, pa);
    scene_positions(g, 0.0, pg);
    for (size_t i = 0; i < n; i++) {
        za = fmax(za, pa[3 * i + 2]);
        zg = fmax(zg, pg[3 * i + 2]);
        wa += fabs(pa[3 * i + 1]);
        wg += fabs(pg[3 * i + 1]);
    }
    assert_true(e_place < 1e-5);
    assert_true(e_speed < 1e-6);
    assert_true(fabs(za - zg) < 0.02);   /* same height */
    assert_true(wg > 1.1 * wa);          /* broader: mean front-back depth */
    struct scene_desc bad = da;
    bad.girth = 3.0f;
    scene *x = NULL;
    assert_int_equal(scene_new_desc(&bad, &x, &err), F4D_EINVAL);
    assert_non_null(strstr(err.msg, "girth"));
    bad = da;
    bad.speed = NAN;
    assert_int_equal(scene_new_desc(&bad, &x, &err), F4D_EINVAL);
    assert_null(x);
    free(pa); free(pb); free(pc); free(pg);
    scene_free(a); scene_free(b); scene_free(c); scene_free(g); scene_free(fl);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_max_nan_fails_on_nan),
        cmocka_unit_test(test_figure_height_and_counts),
        cmocka_unit_test(test_motion_is_exact_at_any_time),
        cmocka_unit_test(test_default_rig),
        cmocka_unit_test(test_close_preset_has_a_camera_within_half_a_metre),
        cmocka_unit_test(test_exit_ball_leaves_and_returns),
        cmocka_unit_test(test_fast_moves_far_per_frame),
        cmocka_unit_test(test_deterministic_by_seed),
        cmocka_unit_test(test_sized_scene),
        cmocka_unit_test(test_pixel_flow_matches_gaussian_motion),
        cmocka_unit_test(test_bad_input_rejected),
        cmocka_unit_test(test_scene_desc_knobs),
    };
    return cmocka_run_group_tests_name("scene", tests, NULL, NULL);
}
