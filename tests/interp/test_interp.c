/* test_interp.c - 4D interpolation and the scene budget: fusion arithmetic,
 * exact constant-velocity motion, dual consistency on a hand-made pair, GT
 * interpolation beating the nearest key frame on every preset, budget
 * pruning, bad input. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "interp.h"
#include "scene.h"

static fk_ctx *make_ctx(void)
{
    fk_ctx *ctx = NULL;
    struct fk_ctx_config cfg = { .isa = FK_ISA_AUTO, .threads = 2 };
    assert_int_equal(fk_ctx_new(&cfg, &ctx), F4D_OK);
    return ctx;
}

static void test_fuse_average(void **state)
{
    (void)state;
    float a[INTERP_ATTRS] = { 1, 2, 3, 0.2f, 0.4f, 0.6f, 1.0f, -3, -4, -5, 1, 0, 0, 0 };
    float b[INTERP_ATTRS] = { 3, 2, 1, 0.4f, 0.4f, 0.2f, 3.0f, -5, -4, -3, -1, 0, 0, 0 }; /* -q: same rotation */
    float o[INTERP_ATTRS];
    interp_fuse_average(NULL, a, b, 0.5f, 0.01f, o);
    for (int c = 0; c < 10; c++)
        assert_float_equal(o[c], 0.5f * (a[c] + b[c]), 1e-6);
    /* sign-aligned sum: 2 * identity, not zero */
    assert_float_equal(o[10], 2.0f, 1e-6);
    assert_float_equal(o[11] + o[12] + o[13], 0.0f, 1e-6);
}

/* A small rig of 2 cameras 64x64 looking at the origin from +y. */
static void small_rig(struct splat_rig *rig)
{
    memset(rig, 0, sizeof *rig);
    rig->count = 2;
    for (int k = 0; k < 2; k++) {
        struct splat_camera *c = &rig->cams[k];
        snprintf(c->name, sizeof c->name, "c%d", k);
        c->width = c->height = 64;
        c->fx = c->fy = 64;
        c->cx = c->cy = 32;
        float eye[3] = { k ? 0.5f : -0.5f, 3, 0 }, at[3] = { 0, 0, 0 }, up[3] = { 0, 0, 1 };
        splat_camera_look_at(c, eye, at, up);
    }
}

/* Two well-separated opaque Gaussians moving 4 cm per key; a third one in key
 * t only (appears): it has no partner and must be kept. */
static void test_dual_consistency_pairs(void **state)
{
    (void)state;
    fk_ctx *ctx = make_ctx();
    struct splat_rig rig;
    small_rig(&rig);
    interp *ip;
    struct f4d_err err;
    assert_int_equal(interp_new(ctx, &rig, &ip, &err), 0);
    struct splat_frame f0 = { 0 }, f1 = { 0 }, out = { 0 };
    assert_int_equal(splat_frame_resize(&f0, 2, 1, NULL), 0);
    assert_int_equal(splat_frame_resize(&f1, 3, 1, NULL), 0);
    const float x0[2][3] = { { -0.4f, 0, 0 }, { 0.4f, 0, 0.2f } }, d[3] = { 0.04f, 0, 0 };
    for (int i = 0; i < 3; i++) {
        struct splat_frame *fs[2] = { &f0, &f1 };
        for (int s = 0; s < 2; s++) {
            struct splat_frame *f = fs[s];
            if ((size_t)i >= f->count)
                continue;
            for (int c = 0; c < 3; c++) {
                f->pos[3 * i + c] = (i < 2 ? x0[i][c] : (c == 2 ? -0.3f : 0.0f)) + (float)s * d[c];
                f->scale[3 * i + c] = 0.05f;
                f->rgb[3 * i + c] = 0.5f;
                f->motion_fwd[3 * i + c] = d[c];
                f->motion_bwd[3 * i + c] = -d[c];
            }
            f->opacity[i] = 0.9f;
        }
    }
    struct interp_key k0 = { 0 }, k1 = { 0 };
    assert_int_equal(interp_key_build(ip, &f0, &k0, &err), 0);
    assert_int_equal(interp_key_build(ip, &f1, &k1, &err), 0);
    for (int i = 0; i < 3; i++)
        assert_true(k1.origin[i] >= 0);
    struct interp_config cfg = interp_config_default();
    struct interp_stats st;
    assert_int_equal(interp_at(ip, &k0, &k1, 0.25f, &cfg, &out, &st, &err), 0);
    /* the two moving ones are fused pairs (t-1 copies dropped), the new one kept */
    assert_int_equal(st.fused, 2);
    assert_int_equal(st.dropped_tm1, 2);
    assert_int_equal(st.kept_t, 1);
    assert_int_equal(out.count, 3);
    assert_float_equal(out.pos[0], -0.4f + 0.25f * 0.04f, 1e-6);
    assert_float_equal(out.pos[3], 0.4f + 0.25f * 0.04f, 1e-6);
    assert_float_equal(out.opacity[0], 0.9f, 1e-5);
    assert_float_equal(out.scale[0], 0.05f, 1e-6);
    /* keep-both doubles, nearest copies */
    cfg.mode = INTERP_KEEP_BOTH;
    assert_int_equal(interp_at(ip, &k0, &k1, 0.25f, &cfg, &out, &st, &err), 0);
    assert_int_equal(out.count, 5);
    cfg.mode = INTERP_NEAREST;
    assert_int_equal(interp_at(ip, &k0, &k1, 0.75f, &cfg, &out, &st, &err), 0);
    assert_int_equal(out.count, 3);
    /* tau 0: nothing is consistent enough, everything kept */
    cfg = interp_config_default();
    cfg.tau = 0.0f;
    f0.pos[0] += 0.001f;
    f0.pos[3] += 0.001f;
    /* the lookup holds the positions it was built with: rebuild after moving */
    assert_int_equal(interp_key_build(ip, &f0, &k0, &err), 0);
    assert_int_equal(interp_at(ip, &k0, &k1, 0.5f, &cfg, &out, &st, &err), 0);
    assert_int_equal(st.fused, 0);
    assert_int_equal(out.count, 5);
    /* bad input */
    assert_int_equal(interp_at(ip, &k0, &k1, 1.5f, &cfg, &out, &st, &err), F4D_EINVAL);
    assert_non_null(strstr(err.msg, "[0, 1]"));
    free(f1.motion_bwd);
    f1.motion_bwd = NULL;
    assert_int_equal(interp_at(ip, &k0, &k1, 0.5f, &cfg, &out, &st, &err), F4D_EINVAL);
    assert_non_null(strstr(err.msg, "backward motion"));
    interp_key_free(&k0);
    interp_key_free(&k1);
    splat_frame_free(&f0);
    splat_frame_free(&f1);
    splat_frame_free(&out);
    interp_free(ip);
    fk_ctx_free(ctx);
}

static double mean_psnr(splat_renderer *r, const struct splat_rig *rig, const struct splat_frame *a,
                        const struct splat_frame *b, float *ia, float *ib)
{
    double s = 0;
    for (int c = 0; c < rig->count; c++) {
        struct splat_render_out oa = { .rgb = ia }, ob = { .rgb = ib };
        assert_int_equal(splat_render(r, &rig->cams[c], a, scene_background(), &oa), 0);
        assert_int_equal(splat_render(r, &rig->cams[c], b, scene_background(), &ob), 0);
        s += splat_psnr(ia, ib, rig->cams[c].width, rig->cams[c].height, 3);
    }
    return s / rig->count;
}

/* Interpolation with the exact GT motion against the nearest key frame, at the
 * mid time of two keys, for every preset, on small images. */
static void test_gt_interpolation_beats_nearest_on_every_preset(void **state)
{
    (void)state;
    fk_ctx *ctx = make_ctx();
    const int W = 128, H = 128;
    float *ia = malloc(3 * W * H * sizeof(float)), *ib = malloc(3 * W * H * sizeof(float));
    splat_renderer *r;
    assert_int_equal(splat_renderer_new(ctx, W, H, &r, NULL), 0);
    const double dt = 1.0 / SCENE_FPS;
    for (int p = 0; p < SCENE_PRESET_COUNT; p++) {
        scene *s;
        assert_int_equal(scene_new((enum scene_preset)p, 11, 0, &s, NULL), 0);
        struct splat_rig rig;
        scene_default_rig(s, 4, W, H, &rig);
        interp *ip;
        struct f4d_err err;
        assert_int_equal(interp_new(ctx, &rig, &ip, &err), 0);
        struct splat_frame f0 = { 0 }, f1 = { 0 }, gt = { 0 }, out = { 0 };
        struct interp_key k0 = { 0 }, k1 = { 0 };
        /* three phases per preset (exit: while the ball is low, just thrown) */
        const double phases[3] = { 0.3, 0.7, 1.1 }, base = p == SCENE_EXIT ? 2.0 : 0.0;
        double fused = 0, nearest = 0;
        for (int q = 0; q < 3; q++) {
            const double t1 = base + phases[q];
            assert_int_equal(scene_eval(s, t1 - dt, dt, &f0, NULL), 0);
            assert_int_equal(scene_eval(s, t1, dt, &f1, NULL), 0);
            assert_int_equal(scene_eval(s, t1 - 0.5 * dt, 0.0, &gt, NULL), 0);
            assert_int_equal(interp_key_build(ip, &f0, &k0, &err), 0);
            assert_int_equal(interp_key_build(ip, &f1, &k1, &err), 0);
            struct interp_config cfg = interp_config_default();
            assert_int_equal(interp_at(ip, &k0, &k1, 0.5f, &cfg, &out, NULL, &err), 0);
            fused += mean_psnr(r, &rig, &gt, &out, ia, ib) / 3;
            cfg.mode = INTERP_NEAREST;
            assert_int_equal(interp_at(ip, &k0, &k1, 0.5f, &cfg, &out, NULL, &err), 0);
            nearest += mean_psnr(r, &rig, &gt, &out, ia, ib) / 3;
        }
        print_message("%-6s mid-time PSNR with GT motion %.2f dB, nearest key frame %.2f dB\n",
                      scene_preset_name((enum scene_preset)p), fused, nearest);
        assert_true(fused > nearest + 0.5);
        interp_key_free(&k0);
        interp_key_free(&k1);
        splat_frame_free(&f0); splat_frame_free(&f1); splat_frame_free(&gt); splat_frame_free(&out);
        interp_free(ip);
        scene_free(s);
    }
    splat_renderer_free(r);
    free(ia);
    free(ib);
    fk_ctx_free(ctx);
}

static int batch_average(void *user, const float *x, int n, float *out)
{
    for (int i = 0; i < n; i++) {
        const float *r = x + (size_t)i * INTERP_FUSE_IN;
        interp_fuse_average(user, r, r + INTERP_ATTRS, r[2 * INTERP_ATTRS], r[2 * INTERP_ATTRS + 1],
                            out + (size_t)i * INTERP_ATTRS);
    }
    return 0;
}

/* interp_pair_step (positions pos0 + a dpos, the rest prepared once) gives
 * interp_pair_at's frame: every attribute but the position bit for bit, the
 * position within 2e-6 (1 + |pos|) (the affine sum is associated
 * differently); 1 and 2 threads write the same bytes. 40k Gaussians so that
 * the step is large enough for fk_parallel_for to split it. */
static void test_step_matches_pair_at(void **state)
{
    (void)state;
    struct f4d_err err;
    fk_ctx *c1, *c2;
    struct fk_ctx_config kc1 = { .isa = FK_ISA_AUTO, .threads = 1 }, kc2 = { .isa = FK_ISA_AUTO, .threads = 2 };
    assert_int_equal(fk_ctx_new(&kc1, &c1), 0);
    assert_int_equal(fk_ctx_new(&kc2, &c2), 0);
    scene *s;
    assert_int_equal(scene_new(SCENE_WALK, 5, 40000, &s, &err), 0);
    struct splat_rig rig;
    scene_default_rig(s, 2, 128, 128, &rig);
    struct splat_frame f0 = { 0 }, f1 = { 0 }, a = { 0 }, b = { 0 }, c = { 0 };
    assert_int_equal(scene_eval(s, 0.3, 0.1, &f0, &err), 0);
    assert_int_equal(scene_eval(s, 0.4, 0.1, &f1, &err), 0);
    interp *ip1, *ip2;
    assert_int_equal(interp_new(c1, &rig, &ip1, &err), 0);
    assert_int_equal(interp_new(c2, &rig, &ip2, &err), 0);
    struct interp_key k0 = { 0 }, k1 = { 0 };
    assert_int_equal(interp_key_build(ip1, &f0, &k0, &err), 0);
    assert_int_equal(interp_key_build(ip1, &f1, &k1, &err), 0);
    struct interp_config cfg = interp_config_default();
    struct interp_pair pr = { 0 };
    assert_int_equal(interp_pair_build(ip1, &k0, &k1, &cfg, &pr, &err), 0);
    assert_int_equal(interp_pair_prepare(ip1, &pr, &cfg, &b, &err), 0);
    assert_int_equal(interp_pair_prepare(ip2, &pr, &cfg, &c, &err), 0);
    assert_true(3 * b.count * 2 > 200000); /* above FK_PARALLEL_MIN_WORK: 2 threads do split it */
    const float as[5] = { 0.0f, 0.25f, 0.5f, 0.8f, 1.0f };
    for (int i = 0; i < 5; i++) {
        struct interp_stats sa;
        assert_int_equal(interp_pair_at(ip1, &pr, as[i], &cfg, &a, &sa, &err), 0);
        assert_true(sa.fused > 0 && sa.kept_t + sa.kept_tm1 > 0);
        assert_int_equal(interp_pair_step(ip1, &pr, as[i], &b, &err), 0);
        assert_int_equal(interp_pair_step(ip2, &pr, as[i], &c, &err), 0);
        assert_int_equal(a.count, b.count);
        assert_memory_equal(a.scale, b.scale, 3 * a.count * sizeof(float));
        assert_memory_equal(a.rot, b.rot, 4 * a.count * sizeof(float));
        assert_memory_equal(a.rgb, b.rgb, 3 * a.count * sizeof(float));
        assert_memory_equal(a.opacity, b.opacity, a.count * sizeof(float));
        for (size_t k = 0; k < 3 * a.count; k++) {
            double want = a.pos[k], got = b.pos[k];
            if (fabs(got - want) > 2e-6 * (1.0 + fabs(want)))
                fail_msg("a %.2f: pos[%zu] = %.9g, interp_pair_at %.9g", (double)as[i], k, got, want);
        }
        assert_memory_equal(b.pos, c.pos, 3 * b.count * sizeof(float));
    }
    /* refused: a learned fusion, a out of range, a frame it did not prepare */
    cfg.fuse_batch = batch_average;
    assert_int_equal(interp_pair_prepare(ip1, &pr, &cfg, &b, &err), F4D_EINVAL);
    assert_non_null(strstr(err.msg, "averaging"));
    assert_int_equal(interp_pair_step(ip1, &pr, 1.5f, &b, &err), F4D_EINVAL);
    b.count--;
    assert_int_equal(interp_pair_step(ip1, &pr, 0.5f, &b, &err), F4D_EINVAL);
    interp_pair_free(&pr);
    interp_key_free(&k0);
    interp_key_free(&k1);
    interp_free(ip1);
    interp_free(ip2);
    splat_frame_free(&f0);
    splat_frame_free(&f1);
    splat_frame_free(&a);
    splat_frame_free(&b);
    splat_frame_free(&c);
    scene_free(s);
    fk_ctx_free(c1);
    fk_ctx_free(c2);
}

/* Two empty keys (a budget that pruned everything): prepared and stepped like
 * any pair, zero Gaussians out, no error (the display met this in a report run). */
static void test_step_empty_pair(void **state)
{
    (void)state;
    struct f4d_err err;
    fk_ctx *c;
    struct fk_ctx_config kc = { .isa = FK_ISA_AUTO, .threads = 1 };
    assert_int_equal(fk_ctx_new(&kc, &c), 0);
    scene *s;
    assert_int_equal(scene_new(SCENE_WALK, 5, 1000, &s, &err), 0);
    struct splat_rig rig;
    scene_default_rig(s, 2, 32, 32, &rig);
    struct splat_frame f0 = { 0 }, f1 = { 0 }, out = { 0 };
    assert_int_equal(splat_frame_resize(&f0, 0, 1, &err), 0);
    assert_int_equal(splat_frame_resize(&f1, 0, 1, &err), 0);
    interp *ip;
    assert_int_equal(interp_new(c, &rig, &ip, &err), 0);
    struct interp_key k0 = { 0 }, k1 = { 0 };
    assert_int_equal(interp_key_build(ip, &f0, &k0, &err), 0);
    assert_int_equal(interp_key_build(ip, &f1, &k1, &err), 0);
    struct interp_config cfg = interp_config_default();
    struct interp_pair pr = { 0 };
    assert_int_equal(interp_pair_build(ip, &k0, &k1, &cfg, &pr, &err), 0);
    assert_int_equal(interp_pair_prepare(ip, &pr, &cfg, &out, &err), 0);
    assert_int_equal(interp_pair_step(ip, &pr, 0.5f, &out, &err), 0);
    assert_int_equal(out.count, 0);
    interp_pair_free(&pr);
    interp_key_free(&k0);
    interp_key_free(&k1);
    interp_free(ip);
    splat_frame_free(&f0);
    splat_frame_free(&f1);
    splat_frame_free(&out);
    scene_free(s);
    fk_ctx_free(c);
}

/* interp_pair_at (partners found once per key pair) gives interp_at's frame
 * bit for bit at every a, on a real scene with fused, kept and dropped ones. */
static void test_pair_matches_interp_at(void **state)
{
    (void)state;
    struct f4d_err err;
    fk_ctx *ctx;
    struct fk_ctx_config kc = { .isa = FK_ISA_AUTO, .threads = 2 };
    assert_int_equal(fk_ctx_new(&kc, &ctx), 0);
    scene *s;
    assert_int_equal(scene_new(SCENE_WALK, 5, 6000, &s, &err), 0);
    struct splat_rig rig;
    scene_default_rig(s, 2, 128, 128, &rig);
    struct splat_frame f0 = { 0 }, f1 = { 0 }, a = { 0 }, b = { 0 };
    assert_int_equal(scene_eval(s, 0.3, 0.1, &f0, &err), 0);
    assert_int_equal(scene_eval(s, 0.4, 0.1, &f1, &err), 0);
    interp *ip;
    assert_int_equal(interp_new(ctx, &rig, &ip, &err), 0);
    struct interp_key k0 = { 0 }, k1 = { 0 };
    assert_int_equal(interp_key_build(ip, &f0, &k0, &err), 0);
    assert_int_equal(interp_key_build(ip, &f1, &k1, &err), 0);
    struct interp_config cfg = interp_config_default();
    struct interp_pair pr = { 0 };
    assert_int_equal(interp_pair_build(ip, &k0, &k1, &cfg, &pr, &err), 0);
    const float as[4] = { 0.0f, 0.3f, 0.75f, 1.0f };
    for (int i = 0; i < 4; i++) {
        struct interp_stats sa, sb;
        assert_int_equal(interp_at(ip, &k0, &k1, as[i], &cfg, &a, &sa, &err), 0);
        assert_int_equal(interp_pair_at(ip, &pr, as[i], &cfg, &b, &sb, &err), 0);
        assert_true(sa.fused > 0 && sa.kept_t + sa.kept_tm1 > 0);
        assert_memory_equal(&sa, &sb, sizeof sa);
        assert_int_equal(a.count, b.count);
        assert_memory_equal(a.pos, b.pos, 3 * a.count * sizeof(float));
        assert_memory_equal(a.scale, b.scale, 3 * a.count * sizeof(float));
        assert_memory_equal(a.rot, b.rot, 4 * a.count * sizeof(float));
        assert_memory_equal(a.rgb, b.rgb, 3 * a.count * sizeof(float));
        assert_memory_equal(a.opacity, b.opacity, a.count * sizeof(float));
    }
    /* the batched fusion hook (rows averaged here) takes the same path */
    cfg.fuse_batch = batch_average;
    for (int i = 0; i < 4; i++) {
        assert_int_equal(interp_at(ip, &k0, &k1, as[i], &cfg, &a, NULL, &err), 0);
        assert_int_equal(interp_pair_at(ip, &pr, as[i], &cfg, &b, NULL, &err), 0);
        assert_int_equal(a.count, b.count);
        assert_memory_equal(a.pos, b.pos, 3 * a.count * sizeof(float));
        assert_memory_equal(a.rot, b.rot, 4 * a.count * sizeof(float));
        assert_memory_equal(a.opacity, b.opacity, a.count * sizeof(float));
    }
    cfg.fuse_batch = NULL;
    cfg.tau = 0.01f; /* built with another tau: refused */
    assert_int_equal(interp_pair_at(ip, &pr, 0.5f, &cfg, &b, NULL, &err), F4D_EINVAL);
    assert_non_null(strstr(err.msg, "tau"));
    interp_pair_free(&pr);
    interp_key_free(&k0);
    interp_key_free(&k1);
    interp_free(ip);
    splat_frame_free(&f0);
    splat_frame_free(&f1);
    splat_frame_free(&a);
    splat_frame_free(&b);
    scene_free(s);
    fk_ctx_free(ctx);
}

/* interp's pixel_of, operation for operation: the pixel a point lands on. */
static long ref_pixel(const struct splat_camera *cam, const float p[3])
{
    const float *m = cam->w2c;
    float q[3];
    for (int r = 0; r < 3; r++)
        q[r] = m[4 * r] * p[0] + m[4 * r + 1] * p[1] + m[4 * r + 2] * p[2] + m[4 * r + 3];
    if (!(q[2] > SPLAT_NEAR))
        return -1;
    float iz = 1.0f / q[2];
    float u = cam->fx * q[0] * iz + cam->cx, v = cam->fy * q[1] * iz + cam->cy;
    if (!(u >= 0.0f && v >= 0.0f && u < (float)cam->width && v < (float)cam->height))
        return -1;
    return (long)v * cam->width + (long)u;
}

/* The partner rule by brute force over the key's pixel list: the nearest
 * entry, the lowest index on a tie, within tau. */
static int32_t ref_partner(const struct interp_key *self, const struct interp_key *other, const float *motion,
                           size_t g, float tau, int W, int H, float *D)
{
    int32_t o = self->origin[g];
    if (o < 0)
        return -1;
    const size_t np = (size_t)W * (size_t)H;
    int v = (int)((size_t)o / np);
    const float *mu = self->f->pos + 3 * g;
    float X[3] = { mu[0] + motion[3 * g], mu[1] + motion[3 * g + 1], mu[2] + motion[3 * g + 2] };
    long p = ref_pixel(&other->rig.cams[v], X);
    if (p < 0)
        return -1;
    const int32_t *start = other->cell_start + (size_t)v * (np + 1), *items = other->cell_items + (size_t)v * other->f->count;
    int32_t best = -1;
    float bd = INFINITY;
    for (int32_t k = start[p]; k < start[p + 1]; k++) {
        const float *m = other->f->pos + 3 * (size_t)items[k];
        float dx = X[0] - m[0], dy = X[1] - m[1], dz = X[2] - m[2], d2 = dx * dx + dy * dy + dz * dz;
        if (d2 < bd || (d2 == bd && items[k] < best)) {
            bd = d2;
            best = items[k];
        }
    }
    if (best < 0 || sqrtf(bd) > tau)
        return -1;
    *D = sqrtf(bd);
    return best;
}

/* The partner search walks pixel lists sorted along the view axis and stops
 * at a bound: it must find exactly what a full scan of the list finds, ties
 * (duplicated Gaussians) going to the lowest index, in a dense cloud with
 * tens of entries per pixel, for a small and a large tau. */
static void partner_search_is_exhaustive(enum interp_lookup lookup)
{
    fk_ctx *ctx = make_ctx();
    struct splat_rig rig;
    small_rig(&rig);
    interp *ip;
    struct f4d_err err;
    assert_int_equal(interp_new(ctx, &rig, &ip, &err), 0);
    assert_int_equal(interp_set_lookup(ip, lookup, &err), 0);
    const size_t n = 4000;
    struct splat_frame f0 = { 0 }, f1 = { 0 };
    assert_int_equal(splat_frame_resize(&f0, n, 1, NULL), 0);
    assert_int_equal(splat_frame_resize(&f1, n, 1, NULL), 0);
    uint32_t seed = 12345u;
    for (size_t i = 0; i < n; i++) {
        float m[3];
        for (int c = 0; c < 3; c++) {
            seed = seed * 1664525u + 1013904223u;
            float r = (float)(seed >> 8) / 16777216.0f - 0.5f;
            seed = seed * 1664525u + 1013904223u;
            m[c] = 0.04f * ((float)(seed >> 8) / 16777216.0f - 0.5f);
            f0.pos[3 * i + c] = i % 5 == 4 ? f0.pos[3 * (i - 1) + c] : 0.3f * r; /* every 5th a duplicate */
            f0.scale[3 * i + c] = f1.scale[3 * i + c] = 0.01f;
            f0.rgb[3 * i + c] = f1.rgb[3 * i + c] = 0.5f;
        }
        for (int c = 0; c < 3; c++) {
            f1.pos[3 * i + c] = i % 5 == 4 ? f1.pos[3 * (i - 1) + c] : f0.pos[3 * i + c] + m[c];
            f0.motion_fwd[3 * i + c] = m[c];
            /* a third come back elsewhere: partners far away or none */
            f1.motion_bwd[3 * i + c] = i % 3 ? -m[c] : 2.0f * m[c];
        }
        f0.opacity[i] = f1.opacity[i] = 0.5f;
    }
    struct interp_key k0 = { 0 }, k1 = { 0 };
    assert_int_equal(interp_key_build(ip, &f0, &k0, &err), 0);
    assert_int_equal(interp_key_build(ip, &f1, &k1, &err), 0);
    size_t longest = 0;
    for (size_t p = 0; p < 64 * 64; p++) {
        size_t L = (size_t)(k0.cell_start[p + 1] - k0.cell_start[p]);
        longest = L > longest ? L : longest;
    }
    assert_true(longest >= 20); /* the lists are long enough for the bound to matter */
    const float taus[2] = { 0.05f, 1.0f };
    for (int ti = 0; ti < 2; ti++) {
        struct interp_config cfg = interp_config_default();
        cfg.tau = taus[ti];
        struct interp_pair pr = { 0 };
        assert_int_equal(interp_pair_build(ip, &k0, &k1, &cfg, &pr, &err), 0);
        size_t matched = 0, ties = 0;
        for (size_t g = 0; g < n; g++) {
            float D = -1.0f;
            int32_t h = ref_partner(&k1, &k0, f1.motion_bwd, g, cfg.tau, 64, 64, &D);
            assert_int_equal(pr.partner_t[g], h);
            if (h >= 0) {
                assert_true(pr.dist_t[g] == D);
                matched++;
                ties += h % 5 == 3; /* its duplicate h + 1 is as near: the lower index wins */
            }
        }
        for (size_t g = 0; g < n; g++) {
            float D;
            assert_int_equal(pr.partner_tm1[g], ref_partner(&k0, &k1, f0.motion_fwd, g, cfg.tau, 64, 64, &D));
        }
        assert_true(matched > n / 4);
        assert_true(ties > 0);
        interp_pair_free(&pr);
    }
    interp_key_free(&k0);
    interp_key_free(&k1);
    splat_frame_free(&f0);
    splat_frame_free(&f1);
    interp_free(ip);
    fk_ctx_free(ctx);
}

static void test_partner_search_is_exhaustive(void **state)
{
    (void)state;
    partner_search_is_exhaustive(INTERP_LOOKUP_RENDER);
    partner_search_is_exhaustive(INTERP_LOOKUP_ZBUFFER);
}

/* The z-buffer lookup on the hand-made pair: the same matches as the
 * render's (two fused, the new one kept), and an unknown lookup refused. */
static void test_zbuffer_lookup(void **state)
{
    (void)state;
    fk_ctx *ctx = make_ctx();
    struct splat_rig rig;
    small_rig(&rig);
    interp *ip;
    struct f4d_err err;
    assert_int_equal(interp_new(ctx, &rig, &ip, &err), 0);
    assert_int_equal(interp_set_lookup(ip, (enum interp_lookup)7, &err), F4D_EINVAL);
    assert_non_null(strstr(err.msg, "unknown lookup"));
    assert_int_equal(interp_set_lookup(ip, INTERP_LOOKUP_ZBUFFER, &err), 0);
    struct splat_frame f0 = { 0 }, f1 = { 0 }, out = { 0 };
    assert_int_equal(splat_frame_resize(&f0, 3, 1, NULL), 0);
    assert_int_equal(splat_frame_resize(&f1, 3, 1, NULL), 0);
    /* 0 and 1 move 4 cm; 2 sits 0.5 m behind 0, large and opaque in front of
     * it is 0, a few pixels off its centre: hidden behind its core in both
     * cameras, so it has no origin */
    const float x[3][3] = { { -0.4f, 0, 0 }, { 0.4f, 0, 0.2f }, { -0.25f, -0.5f, 0 } };
    for (int i = 0; i < 3; i++)
        for (int s = 0; s < 2; s++) {
            struct splat_frame *f = s ? &f1 : &f0;
            for (int c = 0; c < 3; c++) {
                f->pos[3 * i + c] = x[i][c] + (c == 0 && i < 2 ? 0.04f * (float)s : 0.0f);
                f->scale[3 * i + c] = i == 0 ? 0.3f : 0.05f;
                f->rgb[3 * i + c] = 0.5f;
                f->motion_fwd[3 * i + c] = c == 0 && i < 2 ? 0.04f : 0.0f;
                f->motion_bwd[3 * i + c] = c == 0 && i < 2 ? -0.04f : 0.0f;
            }
            f->opacity[i] = 0.95f;
        }
    struct interp_key k0 = { 0 }, k1 = { 0 };
    assert_int_equal(interp_key_build(ip, &f0, &k0, &err), 0);
    assert_int_equal(interp_key_build(ip, &f1, &k1, &err), 0);
    assert_true(k1.origin[0] >= 0 && k1.origin[1] >= 0);
    assert_int_equal(k1.origin[2], -1); /* behind 0's core */
    struct interp_config cfg = interp_config_default();
    struct interp_stats st;
    assert_int_equal(interp_at(ip, &k0, &k1, 0.5f, &cfg, &out, &st, &err), 0);
    assert_int_equal(st.fused, 2);
    assert_int_equal(st.no_origin_t, 1);
    assert_int_equal(st.kept_t, 1);
    interp_key_free(&k0);
    interp_key_free(&k1);
    splat_frame_free(&f0);
    splat_frame_free(&f1);
    splat_frame_free(&out);
    interp_free(ip);
    fk_ctx_free(ctx);
}

static void test_budget(void **state)
{
    (void)state;
    struct splat_rig rig;
    small_rig(&rig);
    struct splat_frame f = { 0 }, out = { 0 };
    assert_int_equal(splat_frame_resize(&f, 5, 0, NULL), 0);
    for (int i = 0; i < 5; i++) {
        for (int c = 0; c < 3; c++) {
            f.pos[3 * i + c] = 0.0f;
            f.scale[3 * i + c] = 0.05f;
            f.rgb[3 * i + c] = 0.2f * (float)i;
        }
        f.opacity[i] = 0.8f;
    }
    f.opacity[1] = 0.01f;                              /* too transparent */
    f.scale[6] = f.scale[7] = f.scale[8] = 1e-4f;      /* 2: a fraction of a pixel everywhere */
    f.pos[9] = 0.001f;                                 /* 3: duplicate of 0 (same voxel) */
    f.pos[12] = 0.5f;                                  /* 4: its own voxel */
    f.opacity[3] = 0.4f;
    struct budget_config cfg = budget_config_default();
    struct budget_stats st;
    struct f4d_err err;
    assert_int_equal(budget_prune(&f, &rig, &cfg, &out, &st, &err), 0);
    assert_int_equal(st.total, 5);
    assert_int_equal(st.pruned_opacity, 1);
    assert_int_equal(st.subpixel, 1);  /* merged into a pixel-sized cell with its neighbours */
    assert_int_equal(st.pruned_outside, 0);
    /* 0 and 3 share a 4 mm voxel; 2 sits alone in its pixel-sized cell; 4 alone */
    assert_int_equal(st.merged, 1);
    assert_int_equal(st.kept, 3);
    assert_int_equal(out.count, 3);
    size_t m0 = out.count;
    for (size_t i = 0; i < out.count; i++)
        if (out.scale[3 * i] > 0.01f && out.pos[3 * i] < 0.25f)
            m0 = i;
    assert_true(m0 < out.count);
    /* merged: opacity-weighted colour, largest opacity, covariance moment-matched */
    assert_float_equal(out.rgb[3 * m0], (0.8f * 0.0f + 0.4f * 0.6f) / 1.2f, 1e-4);
    assert_float_equal(out.opacity[m0], 0.8f, 0);
    assert_float_equal(out.scale[3 * m0 + 1], 0.05f, 1e-4); /* spread only along x */
    /* a Gaussian outside every view is pruned */
    f.pos[12] = 100.0f;
    assert_int_equal(budget_prune(&f, &rig, &cfg, &out, &st, &err), 0);
    assert_int_equal(st.pruned_outside, 1);
    assert_int_equal(budget_prune(&f, &rig, &cfg, &f, &st, &err), F4D_EINVAL);
    cfg.voxel = -1.0f;
    assert_int_equal(budget_prune(&f, &rig, &cfg, &out, &st, &err), F4D_EINVAL);
    assert_non_null(strstr(err.msg, ">= 0"));
    splat_frame_free(&f);
    splat_frame_free(&out);
}

/* budget_prune_ws (caller scratch, radix-sorted cells) gives exactly what
 * budget_prune gives, on a dense cloud where many Gaussians share cells;
 * too little scratch is refused, naming the need. */
static void test_budget_ws(void **state)
{
    (void)state;
    struct splat_rig rig;
    small_rig(&rig);
    const size_t n = 4000;
    struct splat_frame f = { 0 }, a = { 0 }, b = { 0 };
    assert_int_equal(splat_frame_resize(&f, n, 0, NULL), 0);
    uint32_t r = 12345;
    for (size_t i = 0; i < n; i++) {
        for (int c = 0; c < 3; c++) {
            r = r * 1664525u + 1013904223u;
            f.pos[3 * i + c] = 0.1f * ((float)(r >> 8) / 16777216.0f - 0.5f);
            f.scale[3 * i + c] = 0.002f;
            f.rgb[3 * i + c] = (float)((r >> 4) & 255) / 255.0f;
        }
        f.opacity[i] = 0.05f + 0.9f * (float)(i % 7) / 6.0f;
    }
    struct budget_config cfg = budget_config_default();
    struct budget_stats sa, sb;
    struct f4d_err err;
    assert_int_equal(budget_prune(&f, &rig, &cfg, &a, &sa, &err), 0);
    size_t bytes = budget_scratch_bytes(n);
    void *scratch = malloc(bytes);
    assert_non_null(scratch);
    assert_int_equal(splat_frame_reserve(&b, n, 0, NULL), 0);
    assert_int_equal(budget_prune_ws(&f, &rig, &cfg, scratch, bytes, &b, &sb, &err), 0);
    assert_true(sa.merged > 100); /* the cloud is dense: cells are shared */
    assert_int_equal(sa.kept, sb.kept);
    assert_int_equal(sa.merged, sb.merged);
    assert_int_equal(a.count, b.count);
    assert_memory_equal(a.pos, b.pos, 3 * a.count * sizeof(float));
    assert_memory_equal(a.scale, b.scale, 3 * a.count * sizeof(float));
    assert_memory_equal(a.rot, b.rot, 4 * a.count * sizeof(float));
    assert_memory_equal(a.opacity, b.opacity, a.count * sizeof(float));
    assert_memory_equal(a.rgb, b.rgb, 3 * a.count * sizeof(float));
    assert_int_equal(budget_prune_ws(&f, &rig, &cfg, scratch, bytes - 1, &b, &sb, &err), F4D_EINVAL);
    assert_non_null(strstr(err.msg, "scratch"));
    free(scratch);
    splat_frame_free(&f);
    splat_frame_free(&a);
    splat_frame_free(&b);
}

/* Motion survives the budget: a kept Gaussian keeps its motion, a merged one
 * gets its members' opacity-weighted mean motion, a motion array the input
 * lacks is zero, origin names each output's most opaque member, and output
 * motion is freed when the next input has none. */
static void test_budget_motion(void **state)
{
    (void)state;
    struct splat_rig rig;
    small_rig(&rig);
    struct splat_frame f = { 0 }, out = { 0 };
    assert_int_equal(splat_frame_resize(&f, 3, 1, NULL), 0);
    for (int i = 0; i < 3; i++) {
        for (int c = 0; c < 3; c++) {
            f.pos[3 * i + c] = 0.0f;
            f.scale[3 * i + c] = 0.05f;
            f.motion_fwd[3 * i + c] = 0.01f * (float)(i + 1) * (float)(c + 1);
            f.motion_bwd[3 * i + c] = -0.02f * (float)(i + 1);
        }
    }
    f.opacity[0] = 0.3f;
    f.opacity[1] = 0.9f;  /* 0 and 1 share a voxel: merged, 1 the most opaque */
    f.pos[1] = 0.001f;
    f.opacity[2] = 0.5f;  /* 2 alone */
    f.pos[6] = 0.5f;
    struct budget_config cfg = budget_config_default();
    struct budget_stats st;
    struct f4d_err err;
    uint32_t origin[3] = { 99, 99, 99 };
    void *scratch = malloc(budget_scratch_bytes(3));
    assert_non_null(scratch);
    assert_int_equal(budget_prune_origin_ws(&f, &rig, &cfg, scratch, budget_scratch_bytes(3), &out, origin, &st,
                                            &err), 0);
    assert_int_equal(out.count, 2);
    assert_non_null(out.motion_fwd);
    assert_non_null(out.motion_bwd);
    size_t m = out.pos[0] < 0.25f ? 0 : 1, k = 1 - m;
    assert_int_equal(origin[m], 1);
    assert_int_equal(origin[k], 2);
    double w0 = 0.3 + 1e-6, w1 = 0.9 + 1e-6;
    for (int c = 0; c < 3; c++) {
        assert_float_equal(out.motion_fwd[3 * m + c], (w0 * 0.01 * (c + 1) + w1 * 0.02 * (c + 1)) / (w0 + w1), 1e-6);
        assert_float_equal(out.motion_bwd[3 * m + c], (w0 * -0.02 + w1 * -0.04) / (w0 + w1), 1e-6);
        assert_float_equal(out.motion_fwd[3 * k + c], 0.03f * (float)(c + 1), 0);
        assert_float_equal(out.motion_bwd[3 * k + c], -0.06f, 0);
    }
    /* only motion_fwd in (key 0 has no backward motion): bwd comes out zero */
    float *bwd = f.motion_bwd;
    f.motion_bwd = NULL;
    assert_int_equal(budget_prune(&f, &rig, &cfg, &out, &st, &err), 0);
    assert_non_null(out.motion_bwd);
    assert_float_equal(out.motion_bwd[3 * k], 0.0f, 0);
    assert_float_equal(out.motion_fwd[3 * k + 2], 0.09f, 1e-7);
    /* no motion in: none out */
    float *fwd = f.motion_fwd;
    f.motion_fwd = NULL;
    assert_int_equal(budget_prune(&f, &rig, &cfg, &out, &st, &err), 0);
    assert_null(out.motion_fwd);
    assert_null(out.motion_bwd);
    f.motion_bwd = bwd;
    f.motion_fwd = fwd;
    free(scratch);
    splat_frame_free(&f);
    splat_frame_free(&out);
}

/* ---- the merged Gaussian's shape (budget_prune's moment matching) -------- */

struct gauss {
    float pos[3], scale[3], rot[4], opacity;
};

static void quat_to_mat(const float q[4], double R[9])
{
    double n = sqrt((double)q[0] * q[0] + (double)q[1] * q[1] + (double)q[2] * q[2] + (double)q[3] * q[3]);
    double w = q[0] / n, x = q[1] / n, y = q[2] / n, z = q[3] / n;
    R[0] = 1 - 2 * (y * y + z * z); R[1] = 2 * (x * y - w * z);     R[2] = 2 * (x * z + w * y);
    R[3] = 2 * (x * y + w * z);     R[4] = 1 - 2 * (x * x + z * z); R[5] = 2 * (y * z - w * x);
    R[6] = 2 * (x * z - w * y);     R[7] = 2 * (y * z + w * x);     R[8] = 1 - 2 * (x * x + y * y);
}

/* Sigma = R diag(s^2) R^T, row-major. */
static void covariance(const float q[4], const float s[3], double C[9])
{
    double R[9];
    quat_to_mat(q, R);
    for (int r = 0; r < 3; r++)
        for (int c = 0; c < 3; c++) {
            double acc = 0;
            for (int m = 0; m < 3; m++)
                acc += R[3 * r + m] * (double)s[m] * s[m] * R[3 * c + m];
            C[3 * r + c] = acc;
        }
}

/* The unit quaternion of `deg` degrees about axis (ax, ay, az). */
static void axis_angle(float q[4], double deg, double ax, double ay, double az)
{
    double n = sqrt(ax * ax + ay * ay + az * az), h = 0.5 * deg * M_PI / 180.0;
    q[0] = (float)cos(h);
    q[1] = (float)(sin(h) * ax / n);
    q[2] = (float)(sin(h) * ay / n);
    q[3] = (float)(sin(h) * az / n);
}

/* Runs budget_prune on two Gaussians that share one (1 m) cell and returns
 * the single merged Gaussian. */
static void merge_two(const struct gauss *a, const struct gauss *b, struct gauss *m)
{
    struct splat_rig rig;
    small_rig(&rig);
    struct splat_frame f = { 0 }, out = { 0 };
    assert_int_equal(splat_frame_resize(&f, 2, 0, NULL), 0);
    const struct gauss *g[2] = { a, b };
    for (int i = 0; i < 2; i++) {
        memcpy(f.pos + 3 * i, g[i]->pos, sizeof g[i]->pos);
        memcpy(f.scale + 3 * i, g[i]->scale, sizeof g[i]->scale);
        memcpy(f.rot + 4 * i, g[i]->rot, sizeof g[i]->rot);
        f.opacity[i] = g[i]->opacity;
        f.rgb[3 * i] = f.rgb[3 * i + 1] = f.rgb[3 * i + 2] = 0.5f;
    }
    struct budget_config cfg = budget_config_default();
    cfg.voxel = 1.0f;
    struct budget_stats st;
    struct f4d_err err = { 0 };
    if (budget_prune(&f, &rig, &cfg, &out, &st, &err) < 0)
        fail_msg("budget_prune: %s", err.msg);
    assert_int_equal(st.merged, 1);
    assert_int_equal(out.count, 1);
    memcpy(m->pos, out.pos, sizeof m->pos);
    memcpy(m->scale, out.scale, sizeof m->scale);
    memcpy(m->rot, out.rot, sizeof m->rot);
    m->opacity = out.opacity[0];
    splat_frame_free(&f);
    splat_frame_free(&out);
}

/* NaN-aware: |got - want| <= rel * scale for every entry (a NaN fails). */
static void expect_cov(const double got[9], const double want[9], double rel, const char *what)
{
    double mag = 0;
    for (int i = 0; i < 9; i++)
        mag = fmax(mag, fabs(want[i]));
    for (int i = 0; i < 9; i++)
        if (!(fabs(got[i] - want[i]) <= rel * mag))
            fail_msg("%s: covariance[%d][%d] = %.9g, expected %.9g (tolerance %.3g)", what,
                     i / 3, i % 3, got[i], want[i], rel * mag);
}

static void expect_unit_quat(const float q[4], const char *what)
{
    double n = sqrt((double)q[0] * q[0] + (double)q[1] * q[1] + (double)q[2] * q[2] + (double)q[3] * q[3]);
    if (!(fabs(n - 1.0) <= 1e-6))
        fail_msg("%s: quaternion (%g, %g, %g, %g) has norm %.9g", what, (double)q[0], (double)q[1],
                 (double)q[2], (double)q[3], n);
}

/* |<q1, q2>| = 1: the same rotation (q and -q are one rotation). */
static void expect_same_rotation(const float q1[4], const float q2[4], const char *what)
{
    double d = fabs((double)q1[0] * q2[0] + (double)q1[1] * q2[1] + (double)q1[2] * q2[2] + (double)q1[3] * q2[3]);
    if (!(fabs(d - 1.0) <= 1e-6))
        fail_msg("%s: rotation (%g, %g, %g, %g), expected +-(%g, %g, %g, %g)", what, (double)q1[0],
                 (double)q1[1], (double)q1[2], (double)q1[3], (double)q2[0], (double)q2[1], (double)q2[2],
                 (double)q2[3]);
}

/* Two identical Gaussians: the merge is the Gaussian itself, rotation (up to
 * the quaternion's sign) and scales included. */
static void test_merge_identical_keeps_shape(void **state)
{
    (void)state;
    struct gauss g = { { 0.2f, 0.3f, 0.4f }, { 0.02f, 0.05f, 0.09f }, { 0 }, 0.7f }, m;
    axis_angle(g.rot, 35.0, 1, 2, 3);
    merge_two(&g, &g, &m);
    double want[9], got[9];
    covariance(g.rot, g.scale, want);
    covariance(m.rot, m.scale, got);
    expect_cov(got, want, 1e-5, "identical pair");
    expect_unit_quat(m.rot, "identical pair");
    for (int c = 0; c < 3; c++) {
        if (!(fabs(m.pos[c] - g.pos[c]) <= 1e-6))
            fail_msg("identical pair: mean[%d] = %g, expected %g", c, (double)m.pos[c], (double)g.pos[c]);
        if (!(fabs(m.scale[c] - g.scale[c]) <= 1e-5 * g.scale[c]))
            fail_msg("identical pair: scale[%d] = %.9g, expected %.9g", c, (double)m.scale[c],
                     (double)g.scale[c]);
    }
    expect_same_rotation(m.rot, g.rot, "identical pair");
    assert_true(m.opacity == g.opacity);
}

/* Axis-aligned members with different scales and offset means: the merged
 * covariance is the weighted mean of diag(s_i^2) plus the weighted spread of
 * the means, w1 w2 / W^2 d d^T (weights: opacity + 1e-6, as budget_prune). */
static void test_merge_offset_pair_covariance(void **state)
{
    (void)state;
    struct gauss a = { { 0.10f, 0.20f, 0.30f }, { 0.02f, 0.03f, 0.04f }, { 1, 0, 0, 0 }, 0.8f };
    struct gauss b = { { 0.16f, 0.17f, 0.32f }, { 0.05f, 0.01f, 0.02f }, { 1, 0, 0, 0 }, 0.4f };
    struct gauss m;
    merge_two(&a, &b, &m);
    double w1 = (double)a.opacity + 1e-6, w2 = (double)b.opacity + 1e-6, W = w1 + w2;
    double want[9], got[9], d[3];
    for (int c = 0; c < 3; c++)
        d[c] = (double)b.pos[c] - a.pos[c];
    for (int r = 0; r < 3; r++)
        for (int c = 0; c < 3; c++)
            want[3 * r + c] = (r == c ? (w1 * a.scale[r] * a.scale[r] + w2 * b.scale[r] * b.scale[r]) / W : 0) +
                              w1 * w2 / (W * W) * d[r] * d[c];
    covariance(m.rot, m.scale, got);
    expect_cov(got, want, 1e-5, "offset pair");
    expect_unit_quat(m.rot, "offset pair");
    for (int c = 0; c < 3; c++) {
        double mu = (w1 * a.pos[c] + w2 * b.pos[c]) / W;
        if (!(fabs(m.pos[c] - mu) <= 1e-6))
            fail_msg("offset pair: mean[%d] = %.9g, expected %.9g", c, (double)m.pos[c], mu);
    }
    assert_true(m.opacity == a.opacity);
    /* the spread is off-axis: the merged frame is not the members' (identity) */
    if (!(fabs(fabs((double)m.rot[0]) - 1.0) > 1e-3))
        fail_msg("offset pair: merged rotation is the identity, the spread along d is lost");
}

/* Rotated members (same rotation, different scales, offset along their own
 * long axis): the merged long axis is the rotated one, not a world axis. */
static void test_merge_rotated_pair(void **state)
{
    (void)state;
    struct gauss a = { { 0.3f, 0.3f, 0.3f }, { 0.08f, 0.02f, 0.03f }, { 0 }, 0.6f }, b, m;
    axis_angle(a.rot, 50.0, 0.2, -0.4, 1.0);
    b = a;
    b.scale[0] = 0.06f; b.scale[1] = 0.025f; b.scale[2] = 0.02f;
    double R[9];
    quat_to_mat(a.rot, R);
    for (int c = 0; c < 3; c++)
        b.pos[c] = a.pos[c] + 0.05f * (float)R[3 * c]; /* along the members' local x */
    merge_two(&a, &b, &m);
    double C1[9], C2[9], want[9], got[9], d[3];
    covariance(a.rot, a.scale, C1);
    covariance(b.rot, b.scale, C2);
    double w1 = (double)a.opacity + 1e-6, w2 = (double)b.opacity + 1e-6, W = w1 + w2;
    for (int c = 0; c < 3; c++)
        d[c] = (double)b.pos[c] - a.pos[c];
    for (int i = 0; i < 9; i++)
        want[i] = (w1 * C1[i] + w2 * C2[i]) / W + w1 * w2 / (W * W) * d[i / 3] * d[i % 3];
    covariance(m.rot, m.scale, got);
    expect_cov(got, want, 1e-5, "rotated pair");
    expect_unit_quat(m.rot, "rotated pair");
    /* the merged axis of the largest scale is the members' local x */
    int k = 0;
    for (int c = 1; c < 3; c++)
        if (m.scale[c] > m.scale[k])
            k = c;
    double Rm[9];
    quat_to_mat(m.rot, Rm);
    double dot = fabs(Rm[k] * R[0] + Rm[3 + k] * R[3] + Rm[6 + k] * R[6]);
    if (!(dot >= 1.0 - 1e-5))
        fail_msg("rotated pair: merged long axis . members' x = %.9g (expected 1)", dot);
    if (!(fabs(fabs((double)m.rot[0]) - 1.0) > 1e-2))
        fail_msg("rotated pair: merged rotation is the identity");
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_fuse_average),
        cmocka_unit_test(test_dual_consistency_pairs),
        cmocka_unit_test(test_gt_interpolation_beats_nearest_on_every_preset),
        cmocka_unit_test(test_pair_matches_interp_at),
        cmocka_unit_test(test_step_matches_pair_at),
        cmocka_unit_test(test_step_empty_pair),
        cmocka_unit_test(test_partner_search_is_exhaustive),
        cmocka_unit_test(test_zbuffer_lookup),
        cmocka_unit_test(test_budget),
        cmocka_unit_test(test_budget_ws),
        cmocka_unit_test(test_budget_motion),
        cmocka_unit_test(test_merge_identical_keeps_shape),
        cmocka_unit_test(test_merge_offset_pair_covariance),
        cmocka_unit_test(test_merge_rotated_pair),
    };
    return cmocka_run_group_tests_name("interp", tests, NULL, NULL);
}
