/* test_splat.c - the splat core: rasterizer against analytic cases, each
 * threshold at its boundary, a brute-force per-pixel reference, hard cases,
 * the colour-only rgba8 output against the float image on every ISA,
 * PLY / rig / PNG / .npy I/O, metrics, and the real donut.ply when present. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "f4d_test.h"
#include "splat.h"

/* NaN-aware running maximum: once a NaN is seen the result stays NaN, so any
 * bound check on it (x < tol) fails; fmax() would silently drop the NaN. */
static double max_nan(double m, double v)
{
    return isnan(m) || isnan(v) ? NAN : (v > m ? v : m);
}

#ifndef SHARED_DIR
#define SHARED_DIR "../shared"
#endif

static uint64_t rng_state = 88172645463325252ull;
static float rnd(float lo, float hi)
{
    rng_state ^= rng_state << 13;
    rng_state ^= rng_state >> 7;
    rng_state ^= rng_state << 17;
    return lo + (hi - lo) * (float)((rng_state >> 11) * (1.0 / 9007199254740992.0));
}

static fk_ctx *make_ctx(int threads)
{
    fk_ctx *ctx = NULL;
    struct fk_ctx_config cfg = { .isa = FK_ISA_AUTO, .threads = threads };
    assert_int_equal(fk_ctx_new(&cfg, &ctx), F4D_OK);
    return ctx;
}

/* W x H camera at the origin looking down +z; cx = W/2 + 0.5 puts the centre
 * of pixel (W/2, H/2) exactly on the optical axis. */
static struct splat_camera axis_camera(int W, int H, float f)
{
    struct splat_camera c;
    memset(&c, 0, sizeof c);
    snprintf(c.name, sizeof c.name, "axis");
    c.width = W; c.height = H;
    c.fx = c.fy = f;
    c.cx = 0.5f * (float)W + 0.5f;
    c.cy = 0.5f * (float)H + 0.5f;
    c.w2c[0] = c.w2c[5] = c.w2c[10] = c.w2c[15] = 1.0f;
    return c;
}

static void set_gaussian(struct splat_frame *f, size_t i, float x, float y, float z, float s, float o,
                         float r, float g, float b)
{
    f->pos[3 * i] = x; f->pos[3 * i + 1] = y; f->pos[3 * i + 2] = z;
    f->scale[3 * i] = f->scale[3 * i + 1] = f->scale[3 * i + 2] = s;
    f->rot[4 * i] = 1; f->rot[4 * i + 1] = f->rot[4 * i + 2] = f->rot[4 * i + 3] = 0;
    f->opacity[i] = o;
    f->rgb[3 * i] = r; f->rgb[3 * i + 1] = g; f->rgb[3 * i + 2] = b;
}

struct img { float *rgb, *alpha, *depth; int32_t *top; int W, H; size_t visible, pairs; };

static struct img render(fk_ctx *ctx, const struct splat_camera *cam, const struct splat_frame *f,
                         const float *bg)
{
    struct img m = { .W = cam->width, .H = cam->height };
    size_t np = (size_t)m.W * (size_t)m.H;
    m.rgb = malloc(3 * np * sizeof(float));
    m.alpha = malloc(np * sizeof(float));
    m.depth = malloc(np * sizeof(float));
    m.top = malloc(np * sizeof(int32_t));
    assert_non_null(m.rgb);
    splat_renderer *r;
    struct f4d_err err;
    assert_int_equal(splat_renderer_new(ctx, m.W, m.H, &r, &err), 0);
    struct splat_render_out o = { .rgb = m.rgb, .alpha = m.alpha, .depth = m.depth, .top = m.top };
    int rc = splat_render(r, cam, f, bg, &o);
    if (rc < 0)
        fail_msg("render: %s", splat_renderer_error(r));
    m.visible = o.visible;
    m.pairs = o.pairs;
    splat_renderer_free(r);
    return m;
}

static void img_free(struct img *m)
{
    free(m->rgb); free(m->alpha); free(m->depth); free(m->top);
}

static const float *px(const struct img *m, int x, int y) { return m->rgb + 3 * ((size_t)y * m->W + x); }

/* ---- analytic cases ------------------------------------------------------- */

static void test_single_isotropic_peak_and_falloff(void **state)
{
    (void)state;
    fk_ctx *ctx = make_ctx(2);
    struct splat_camera cam = axis_camera(64, 64, 100.0f);
    struct splat_frame f = { 0 };
    assert_int_equal(splat_frame_resize(&f, 1, 0, NULL), 0);
    const float z = 2.0f, s = 0.04f, o = 0.8f;
    set_gaussian(&f, 0, 0, 0, z, s, o, 1.0f, 0.5f, 0.25f);
    struct img m = render(ctx, &cam, &f, NULL);
    /* peak: alpha = o exactly at the centre pixel */
    assert_float_equal(px(&m, 32, 32)[0], o * 1.0f, 1e-6);
    assert_float_equal(px(&m, 32, 32)[1], o * 0.5f, 1e-6);
    assert_float_equal(m.alpha[32 * 64 + 32], o, 1e-6);
    assert_float_equal(m.depth[32 * 64 + 32], z, 1e-5);
    assert_int_equal(m.top[32 * 64 + 32], 0);
    /* falloff: sigma_px^2 = (f s / z)^2 + 0.3, alpha(r) = o exp(-r^2 / (2 sigma^2)) */
    double sig2 = (100.0 * s / z) * (100.0 * s / z) + 0.3;
    for (int d = 1; d <= 8; d++) {
        double expect = o * exp(-0.5 * d * d / sig2);
        if (expect < 1.0 / 255)
            expect = 0.0;
        assert_float_equal(px(&m, 32 + d, 32)[0], expect, 2e-6);
        assert_float_equal(px(&m, 32, 32 - d)[0], expect, 2e-6);
    }
    /* 1/e^2 of the peak at 2 sigma along the diagonal too */
    assert_float_equal(px(&m, 35, 36)[0], o * exp(-0.5 * 25 / sig2), 2e-6);
    img_free(&m);
    splat_frame_free(&f);
    fk_ctx_free(ctx);
}

static void test_two_overlapping_order_and_transmittance(void **state)
{
    (void)state;
    fk_ctx *ctx = make_ctx(2);
    struct splat_camera cam = axis_camera(32, 32, 50.0f);
    struct splat_frame f = { 0 };
    assert_int_equal(splat_frame_resize(&f, 2, 0, NULL), 0);
    /* the far green one comes first in memory: order must follow depth */
    set_gaussian(&f, 0, 0, 0, 3.0f, 0.05f, 0.5f, 0, 1, 0);
    set_gaussian(&f, 1, 0, 0, 2.0f, 0.05f, 0.6f, 1, 0, 0);
    const float bg[3] = { 0, 0, 1 };
    struct img m = render(ctx, &cam, &f, bg);
    const float *c = px(&m, 16, 16);
    assert_float_equal(c[0], 0.6f, 1e-6);               /* red, T = 1    */
    assert_float_equal(c[1], 0.5f * 0.4f, 1e-6);        /* green, T = 0.4 */
    assert_float_equal(c[2], 0.4f * 0.5f, 1e-6);        /* background, T = 0.2 */
    assert_float_equal(m.alpha[16 * 32 + 16], 0.8f, 1e-6);
    assert_float_equal(m.depth[16 * 32 + 16], (2.0f * 0.6f + 3.0f * 0.2f) / 0.8f, 1e-5);
    assert_int_equal(m.top[16 * 32 + 16], 1);
    img_free(&m);
    splat_frame_free(&f);
    fk_ctx_free(ctx);
}

static float centre_red(fk_ctx *ctx, const struct splat_frame *f)
{
    struct splat_camera cam = axis_camera(32, 32, 50.0f);
    struct img m = render(ctx, &cam, f, NULL);
    float v = px(&m, 16, 16)[0];
    img_free(&m);
    return v;
}

static void test_alpha_clamp_099(void **state)
{
    (void)state;
    fk_ctx *ctx = make_ctx(1);
    struct splat_frame f = { 0 };
    assert_int_equal(splat_frame_resize(&f, 1, 0, NULL), 0);
    set_gaussian(&f, 0, 0, 0, 2.0f, 0.05f, 1.0f, 1, 0, 0);
    assert_float_equal(centre_red(ctx, &f), 0.99f, 1e-7);
    f.opacity[0] = 0.9899f; /* just below the clamp: passes through */
    assert_float_equal(centre_red(ctx, &f), 0.9899f, 1e-7);
    f.opacity[0] = 0.9901f; /* just above: clamped */
    assert_float_equal(centre_red(ctx, &f), 0.99f, 1e-7);
    splat_frame_free(&f);
    fk_ctx_free(ctx);
}

static void test_alpha_skip_1_over_255(void **state)
{
    (void)state;
    fk_ctx *ctx = make_ctx(1);
    struct splat_frame f = { 0 };
    assert_int_equal(splat_frame_resize(&f, 1, 0, NULL), 0);
    const float th = 1.0f / 255.0f;
    set_gaussian(&f, 0, 0, 0, 2.0f, 0.05f, th, 1, 0, 0);
    assert_float_equal(centre_red(ctx, &f), th, 1e-9);   /* alpha == 1/255 is kept */
    f.opacity[0] = nextafterf(th, 0.0f);                 /* one ulp below: skipped */
    assert_true(centre_red(ctx, &f) == 0.0f);
    f.opacity[0] = th * 1.01f;
    assert_float_equal(centre_red(ctx, &f), th * 1.01f, 1e-9);
    splat_frame_free(&f);
    fk_ctx_free(ctx);
}

/* Front to back: alpha 0.5, then 0.99 (T = 0.005), then a3, then a blue one.
 * T would drop to 0.005 (1 - a3): below 1e-4 the pixel stops, a3 and the blue
 * one are not added. */
static void test_transmittance_stop_1e4(void **state)
{
    (void)state;
    fk_ctx *ctx = make_ctx(1);
    struct splat_camera cam = axis_camera(32, 32, 50.0f);
    struct splat_frame f = { 0 };
    assert_int_equal(splat_frame_resize(&f, 4, 0, NULL), 0);
    const float a3s[2] = { 0.979f, 0.981f }; /* T after: 1.05e-4 (kept), 0.95e-4 (stop) */
    for (int c = 0; c < 2; c++) {
        float a3 = a3s[c];
        set_gaussian(&f, 0, 0, 0, 2.0f, 0.05f, 0.5f, 0.1f, 0, 0);
        set_gaussian(&f, 1, 0, 0, 2.1f, 0.05f, 0.99f, 0.2f, 0, 0);
        set_gaussian(&f, 2, 0, 0, 2.2f, 0.05f, a3, 0, 1, 0);
        set_gaussian(&f, 3, 0, 0, 2.3f, 0.05f, 0.9f, 0, 0, 1);
        struct img m = render(ctx, &cam, &f, NULL);
        const float *p = px(&m, 16, 16);
        float T = 1.0f, r = 0, g = 0, b = 0;
        r += 0.1f * 0.5f * T; T = T * (1.0f - 0.5f);
        r += 0.2f * 0.99f * T; T = T * (1.0f - 0.99f);
        float t3 = T * (1.0f - a3);
        if (c == 0) {
            assert_true(t3 >= 1e-4f);
            g += 1.0f * a3 * T; T = t3;
            float t4 = T * (1.0f - 0.9f);
            assert_true(t4 < 1e-4f);
        } else {
            assert_true(t3 < 1e-4f);
        }
        assert_float_equal(p[0], r, 1e-7);
        assert_float_equal(p[1], g, 1e-7);
        assert_true(p[2] == b); /* the blue one is never added */
        assert_float_equal(m.alpha[16 * 32 + 16], 1.0f - T, 1e-7);
        img_free(&m);
    }
    splat_frame_free(&f);
    fk_ctx_free(ctx);
}

static void test_near_plane_cull_02(void **state)
{
    (void)state;
    fk_ctx *ctx = make_ctx(1);
    struct splat_frame f = { 0 };
    assert_int_equal(splat_frame_resize(&f, 1, 0, NULL), 0);
    set_gaussian(&f, 0, 0, 0, SPLAT_NEAR, 0.001f, 0.7f, 1, 0, 0);
    assert_true(centre_red(ctx, &f) == 0.0f);             /* z == 0.2: culled */
    f.pos[2] = nextafterf(SPLAT_NEAR, 1.0f);
    assert_float_equal(centre_red(ctx, &f), 0.7f, 1e-6); /* just beyond: drawn */
    f.pos[2] = -1.0f;
    assert_true(centre_red(ctx, &f) == 0.0f);             /* behind: culled */
    splat_frame_free(&f);
    fk_ctx_free(ctx);
}

/* ---- brute-force reference -------------------------------------------------
 * R's algorithm written the slow way: per pixel, all Gaussians whose tile
 * rectangle covers the pixel's tile, in depth order (ties by index), with no
 * pixel-box shortcut. */
struct ref_g { float mx, my, A, B, C, o, z, col[3]; int x0, y0, x1, y1, idx; };

static int cmp_ref(const void *a, const void *b)
{
    const struct ref_g *p = a, *q = b;
    if (p->z != q->z)
        return p->z < q->z ? -1 : 1;
    return p->idx - q->idx;
}

static void reference_render(const struct splat_camera *cam, const struct splat_frame *f, float *out)
{
    int W = cam->width, H = cam->height, gx = (W + 15) / 16, gy = (H + 15) / 16;
    struct ref_g *g = calloc(f->count, sizeof *g);
    size_t n = 0;
    for (size_t i = 0; i < f->count; i++) {
        float t[3];
        splat_camera_to_cam(cam, f->pos + 3 * i, t);
        if (t[2] <= 0.2f)
            continue;
        double q[4] = { f->rot[4 * i], f->rot[4 * i + 1], f->rot[4 * i + 2], f->rot[4 * i + 3] };
        double qn = sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
        double w = q[0] / qn, x = q[1] / qn, y = q[2] / qn, z = q[3] / qn;
        double R[3][3] = { { 1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y) },
                           { 2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x) },
                           { 2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y) } };
        double S[3][3] = { { 0 } };
        for (int a = 0; a < 3; a++)
            for (int b = 0; b < 3; b++)
                for (int k = 0; k < 3; k++)
                    S[a][b] += R[a][k] * f->scale[3 * i + k] * f->scale[3 * i + k] * R[b][k];
        double tanx = 0.5 * W / cam->fx, tany = 0.5 * H / cam->fy;
        double limx = 1.3 * tanx, limy = 1.3 * tany; /* cx = W/2 cameras only */
        double txc = fmin(limx, fmax(-limx, t[0] / t[2])) * t[2];
        double tyc = fmin(limy, fmax(-limy, t[1] / t[2])) * t[2];
        double J[2][3] = { { cam->fx / t[2], 0, -cam->fx * txc / (t[2] * t[2]) },
                           { 0, cam->fy / t[2], -cam->fy * tyc / (t[2] * t[2]) } };
        double T[2][3] = { { 0 } };
        for (int a = 0; a < 2; a++)
            for (int b = 0; b < 3; b++)
                for (int k = 0; k < 3; k++)
                    T[a][b] += J[a][k] * cam->w2c[4 * k + b];
        double cv[2][2] = { { 0 } };
        for (int a = 0; a < 2; a++)
            for (int b = 0; b < 2; b++)
                for (int k = 0; k < 3; k++)
                    for (int l = 0; l < 3; l++)
                        cv[a][b] += T[a][k] * S[k][l] * T[b][l];
        double A = cv[0][0] + 0.3, B = cv[0][1], C = cv[1][1] + 0.3, det = A * C - B * B;
        double mid = 0.5 * (A + C), l1 = mid + sqrt(fmax(0.1, mid * mid - det));
        double rad = ceil(3 * sqrt(l1));
        double mx = ((2 * cam->fx / W * t[0] / t[2] + 1) * W - 1) * 0.5;
        double my = ((2 * cam->fy / H * t[1] / t[2] + 1) * H - 1) * 0.5;
        struct ref_g *r = &g[n];
        r->x0 = (int)fmin(gx, fmax(0, (mx - rad) / 16));
        r->y0 = (int)fmin(gy, fmax(0, (my - rad) / 16));
        r->x1 = (int)fmin(gx, fmax(0, (mx + rad + 15) / 16));
        r->y1 = (int)fmin(gy, fmax(0, (my + rad + 15) / 16));
        if ((r->x1 - r->x0) * (r->y1 - r->y0) == 0)
            continue;
        r->mx = (float)mx; r->my = (float)my;
        r->A = (float)(C / det); r->B = (float)(-B / det); r->C = (float)(A / det);
        r->o = f->opacity[i]; r->z = t[2]; r->idx = (int)i;
        for (int k = 0; k < 3; k++)
            r->col[k] = fmaxf(0.0f, f->rgb[3 * i + k]);
        n++;
    }
    qsort(g, n, sizeof *g, cmp_ref);
    for (int yy = 0; yy < H; yy++)
        for (int xx = 0; xx < W; xx++) {
            int tx = xx / 16, ty = yy / 16;
            float T = 1, C[3] = { 0, 0, 0 };
            for (size_t k = 0; k < n; k++) {
                const struct ref_g *r = &g[k];
                if (tx < r->x0 || tx >= r->x1 || ty < r->y0 || ty >= r->y1)
                    continue;
                float dx = r->mx - (float)xx, dy = r->my - (float)yy;
                float power = -0.5f * (r->A * dx * dx + r->C * dy * dy) - r->B * dx * dy;
                if (power > 0.0f)
                    continue;
                float alpha = fminf(0.99f, r->o * expf(power));
                if (alpha < 1.0f / 255.0f)
                    continue;
                float tt = T * (1 - alpha);
                if (tt < 0.0001f)
                    break;
                for (int c = 0; c < 3; c++)
                    C[c] += r->col[c] * alpha * T;
                T = tt;
            }
            for (int c = 0; c < 3; c++)
                out[3 * ((size_t)yy * W + xx) + c] = C[c];
        }
    free(g);
}

static void random_frame(struct splat_frame *f, size_t n, float zlo, float zhi, float spread)
{
    assert_int_equal(splat_frame_resize(f, n, 0, NULL), 0);
    for (size_t i = 0; i < n; i++) {
        f->pos[3 * i] = rnd(-spread, spread);
        f->pos[3 * i + 1] = rnd(-spread, spread);
        f->pos[3 * i + 2] = rnd(zlo, zhi);
        for (int k = 0; k < 3; k++) {
            f->scale[3 * i + k] = rnd(0.002f, 0.08f);
            f->rgb[3 * i + k] = rnd(-0.1f, 1.1f);
        }
        for (int k = 0; k < 4; k++)
            f->rot[4 * i + k] = rnd(-1, 1);
        f->opacity[i] = rnd(0.0f, 1.0f);
    }
}

static void test_matches_bruteforce_reference(void **state)
{
    (void)state;
    fk_ctx *ctx = make_ctx(2);
    struct splat_camera cam = axis_camera(80, 72, 70.0f);
    cam.cx = 40.0f; cam.cy = 36.0f; /* cx = W/2: R's convention exactly */
    struct splat_frame f = { 0 };
    random_frame(&f, 600, 0.1f, 4.0f, 1.2f);
    struct img m = render(ctx, &cam, &f, NULL);
    float *ref = malloc(3 * 80 * 72 * sizeof(float));
    reference_render(&cam, &f, ref);
    double maxd = 0;
    for (size_t i = 0; i < 3 * 80 * 72; i++)
        maxd = max_nan(maxd, fabs((double)ref[i] - m.rgb[i]));
    assert_true(maxd < 2e-4); /* float vs double set-up only; the per-pixel logic is R's */
    free(ref);
    img_free(&m);
    splat_frame_free(&f);
    fk_ctx_free(ctx);
}

static void test_threads_give_identical_images(void **state)
{
    (void)state;
    fk_ctx *c1 = make_ctx(1), *c2 = make_ctx(2);
    struct splat_camera cam = axis_camera(96, 64, 60.0f);
    struct splat_frame f = { 0 };
    random_frame(&f, 5000, 0.5f, 5.0f, 2.0f);
    struct img a = render(c1, &cam, &f, NULL), b = render(c2, &cam, &f, NULL);
    assert_memory_equal(a.rgb, b.rgb, 3 * 96 * 64 * sizeof(float));
    assert_memory_equal(a.depth, b.depth, 96 * 64 * sizeof(float));
    img_free(&a);
    img_free(&b);
    splat_frame_free(&f);
    fk_ctx_free(c1);
    fk_ctx_free(c2);
}

/* The SIMD compositing (AVX2 or NEON, when this CPU has it) against the
 * scalar reference. */
static void test_simd_matches_scalar(void **state)
{
    (void)state;
    enum fk_isa isa = fk_isa_supported(FK_ISA_AVX2) ? FK_ISA_AVX2
                    : fk_isa_supported(FK_ISA_NEON) ? FK_ISA_NEON : FK_ISA_REF;
    if (isa == FK_ISA_REF)
        f4d_skip("test_simd_matches_scalar: this CPU has neither AVX2 + FMA + F16C nor NEON (the SIMD compositor's ISAs)");
    fk_ctx *ref = NULL, *simd = NULL;
    struct fk_ctx_config c1 = { .isa = FK_ISA_REF, .threads = 2 }, c2 = { .isa = isa, .threads = 2 };
    assert_int_equal(fk_ctx_new(&c1, &ref), F4D_OK);
    assert_int_equal(fk_ctx_new(&c2, &simd), F4D_OK);
    struct splat_camera cam = axis_camera(100, 60, 60.0f);
    struct splat_frame f = { 0 };
    random_frame(&f, 4003, 0.1f, 5.0f, 2.0f); /* 4003: a tail beyond the 8-wide blocks */
    /* hard cases inside the SIMD blocks: on the near plane, zero quaternion,
     * zero and huge scales, NaN opacity, transparent */
    f.pos[3 * 8 + 2] = SPLAT_NEAR;
    memset(f.rot + 4 * 9, 0, 4 * sizeof(float));
    f.scale[3 * 10] = f.scale[3 * 10 + 1] = f.scale[3 * 10 + 2] = 0.0f;
    f.scale[3 * 11] = 1e30f;
    f.opacity[12] = NAN;
    f.opacity[13] = 1.0f / 255.0f;
    f.opacity[14] = nextafterf(1.0f / 255.0f, 0.0f);
    struct img a = render(ref, &cam, &f, NULL), b = render(simd, &cam, &f, NULL);
    /* preprocessing is the same computation: same culling, same tile rectangles */
    assert_int_equal(a.visible, b.visible);
    assert_int_equal(a.pairs, b.pairs);
    double maxd = 0;
    for (size_t i = 0; i < 3 * 100 * 60; i++)
        if (isfinite(a.rgb[i]) || isfinite(b.rgb[i]))
            maxd = max_nan(maxd, fabs((double)a.rgb[i] - b.rgb[i]));
    assert_true(maxd < 1e-4); /* exp within 2 ulp; a T-threshold flip could differ more, none here */
    size_t same_top = 0;
    for (size_t i = 0; i < 100 * 60; i++)
        same_top += a.top[i] == b.top[i];
    assert_true(same_top > 100 * 60 * 99 / 100);
    img_free(&a);
    img_free(&b);
    splat_frame_free(&f);
    fk_ctx_free(ref);
    fk_ctx_free(simd);
}

/* The 16-lane compositor against the 8-lane one: the same operations per
 * pixel, so every output is identical bit for bit (colour, alpha, depth, top;
 * depth alone; rgba8 alone, both row orders), on partial tiles and on boxes
 * narrow (4 rows of 4 lanes, 2 of 8) and wide (a row of 16). */
static void test_avx512_matches_avx2(void **state)
{
    (void)state;
    if (!fk_isa_supported(FK_ISA_AVX512) || !fk_isa_supported(FK_ISA_AVX2))
        f4d_skip("test_avx512_matches_avx2: this CPU lacks AVX-512 F/BW/VL/VNNI (the 16-lane compositor's ISA)");
    fk_ctx *c2 = NULL, *c5 = NULL;
    struct fk_ctx_config k2 = { .isa = FK_ISA_AVX2, .threads = 2 }, k5 = { .isa = FK_ISA_AVX512, .threads = 2 };
    assert_int_equal(fk_ctx_new(&k2, &c2), F4D_OK);
    assert_int_equal(fk_ctx_new(&k5, &c5), F4D_OK);
    const int sizes[3][2] = { { 100, 60 }, { 203, 117 }, { 64, 64 } };
    const float focal[3] = { 60.0f, 220.0f, 700.0f };
    const float bg[3] = { 0.1f, 0.5f, 1.0f };
    struct splat_frame f = { 0 };
    random_frame(&f, 4003, 0.1f, 5.0f, 2.0f);
    for (int k = 0; k < 3; k++) {
        const int W = sizes[k][0], H = sizes[k][1];
        const size_t np = (size_t)W * (size_t)H;
        struct splat_camera cam = axis_camera(W, H, focal[k]);
        struct img a = render(c2, &cam, &f, bg), b = render(c5, &cam, &f, bg);
        assert_memory_equal(a.rgb, b.rgb, 3 * np * sizeof(float));
        assert_memory_equal(a.alpha, b.alpha, np * sizeof(float));
        assert_memory_equal(a.depth, b.depth, np * sizeof(float));
        assert_memory_equal(a.top, b.top, np * sizeof(int32_t));
        splat_renderer *r2, *r5;
        assert_int_equal(splat_renderer_new(c2, W, H, &r2, NULL), 0);
        assert_int_equal(splat_renderer_new(c5, W, H, &r5, NULL), 0);
        float *d2 = malloc(np * sizeof(float)), *d5 = malloc(np * sizeof(float));
        uint8_t *q2 = malloc(4 * np), *q5 = malloc(4 * np);
        assert_true(d2 && d5 && q2 && q5);
        struct splat_render_out o2 = { .depth = d2 }, o5 = { .depth = d5 };
        assert_int_equal(splat_render(r2, &cam, &f, bg, &o2), 0);
        assert_int_equal(splat_render(r5, &cam, &f, bg, &o5), 0);
        assert_memory_equal(d2, d5, np * sizeof(float));
        assert_memory_equal(d2, a.depth, np * sizeof(float));
        for (int up = 0; up < 2; up++) {
            struct splat_render_out p2 = { .rgba8 = q2, .rgba8_bottom_up = up }, p5 = { .rgba8 = q5, .rgba8_bottom_up = up };
            assert_int_equal(splat_render(r2, &cam, &f, bg, &p2), 0);
            assert_int_equal(splat_render(r5, &cam, &f, bg, &p5), 0);
            assert_memory_equal(q2, q5, 4 * np);
        }
        free(d2); free(d5); free(q2); free(q5);
        splat_renderer_free(r2);
        splat_renderer_free(r5);
        img_free(&a);
        img_free(&b);
    }
    splat_frame_free(&f);
    fk_ctx_free(c2);
    fk_ctx_free(c5);
}

/* rgba8 alone (a display's request: no depth, no top, so the compositor
 * skips their accumulators) is the full render's rgb quantised as PNG
 * writing does, byte for byte, on the scalar path and on the SIMD ones;
 * rgba8_bottom_up gives the same rows in GL's order. */
static void test_rgba8_matches_rgb(void **state)
{
    (void)state;
    enum fk_isa isas[3] = { FK_ISA_REF, fk_isa_supported(FK_ISA_AVX2) ? FK_ISA_AVX2
                                        : fk_isa_supported(FK_ISA_NEON) ? FK_ISA_NEON : FK_ISA_REF,
                            fk_isa_supported(FK_ISA_AVX512) ? FK_ISA_AVX512 : FK_ISA_REF };
    struct splat_camera cam = axis_camera(100, 60, 60.0f);
    struct splat_frame f = { 0 };
    random_frame(&f, 4003, 0.1f, 5.0f, 2.0f);
    const float bg[3] = { 0.1f, 0.5f, 1.0f };
    uint8_t *q = malloc(4 * 100 * 60);
    assert_non_null(q);
    for (int k = 0; k < 3; k++) {
        fk_ctx *ctx = NULL;
        struct fk_ctx_config c = { .isa = isas[k], .threads = 2 };
        assert_int_equal(fk_ctx_new(&c, &ctx), F4D_OK);
        struct img a = render(ctx, &cam, &f, bg);
        splat_renderer *r;
        assert_int_equal(splat_renderer_new(ctx, 100, 60, &r, NULL), 0);
        memset(q, 7, 4 * 100 * 60);
        struct splat_render_out o = { .rgba8 = q };
        assert_int_equal(splat_render(r, &cam, &f, bg, &o), 0);
        size_t lit = 0;
        for (size_t i = 0; i < 100 * 60; i++) {
            for (int ch = 0; ch < 3; ch++) {
                float v = a.rgb[3 * i + (size_t)ch];
                v = v > 0.0f ? v : 0.0f;
                v = v < 1.0f ? v : 1.0f;
                assert_int_equal(q[4 * i + (size_t)ch], (uint8_t)floorf(v * 255.0f + 0.5f));
            }
            assert_int_equal(q[4 * i + 3], 255);
            lit += a.alpha[i] > 0.5f;
        }
        assert_true(lit > 100 * 60 / 10); /* the frame covers part of the view */
        /* bottom row first: the same rows in the opposite order */
        uint8_t *u = malloc(4 * 100 * 60);
        assert_non_null(u);
        memset(u, 7, 4 * 100 * 60);
        struct splat_render_out ou = { .rgba8 = u, .rgba8_bottom_up = 1 };
        assert_int_equal(splat_render(r, &cam, &f, bg, &ou), 0);
        for (int y = 0; y < 60; y++)
            assert_memory_equal(u + 4 * 100 * (size_t)y, q + 4 * 100 * (size_t)(59 - y), 4 * 100);
        free(u);
        splat_renderer_free(r);
        img_free(&a);
        fk_ctx_free(ctx);
    }
    free(q);
    splat_frame_free(&f);
}

/* Flow of a fronto-parallel surface moving sideways: fx * dx / z everywhere
 * it is seen, 0 elsewhere. */
static void test_flow_from_motion(void **state)
{
    (void)state;
    struct splat_camera cam = axis_camera(8, 6, 50.0f);
    cam.w2c[3] = 0.2f; /* camera translated: flow must not depend on it */
    float depth[48], alpha[48], motion[144], flow[96];
    for (int i = 0; i < 48; i++) {
        depth[i] = 2.0f;
        alpha[i] = i == 5 ? 0.2f : 1.0f;
        motion[3 * i] = 0.04f;
        motion[3 * i + 1] = -0.02f;
        motion[3 * i + 2] = 0.0f;
    }
    depth[7] = 0.0f;
    splat_flow_from_motion(&cam, depth, alpha, motion, flow);
    for (int i = 0; i < 48; i++) {
        float ex = (i == 5 || i == 7) ? 0.0f : 50.0f * 0.04f / 2.0f;
        float ey = (i == 5 || i == 7) ? 0.0f : -50.0f * 0.02f / 2.0f;
        assert_float_equal(flow[2 * i], ex, 1e-4);
        assert_float_equal(flow[2 * i + 1], ey, 1e-4);
    }
}

/* ---- hard cases ------------------------------------------------------------- */

static void test_hard_cases_stay_finite(void **state)
{
    (void)state;
    fk_ctx *ctx = make_ctx(2);
    struct splat_camera cam = axis_camera(64, 48, 40.0f);
    struct splat_frame f = { 0 };
    assert_int_equal(splat_frame_resize(&f, 9, 0, NULL), 0);
    set_gaussian(&f, 0, 0.1f, 0, 0.2f, 0.05f, 0.9f, 1, 0, 0);     /* on the near plane */
    set_gaussian(&f, 1, 0, 0.1f, -0.5f, 0.05f, 0.9f, 1, 0, 0);    /* behind */
    set_gaussian(&f, 2, 0.2f, 0, 2.0f, 0.05f, 0.9f, 0, 1, 0);
    f.rot[8] = f.rot[9] = f.rot[10] = f.rot[11] = 0.0f;         /* zero quaternion */
    set_gaussian(&f, 3, -0.2f, 0, 2.0f, 0.0f, 0.9f, 0, 0, 1);     /* zero scale */
    set_gaussian(&f, 4, 0, 0.3f, 3.0f, 1e30f, 0.9f, 1, 1, 0);     /* huge scale */
    set_gaussian(&f, 5, 0, 0, 0.0f, 3.0f, 0.5f, 0, 1, 1);         /* camera inside */
    set_gaussian(&f, 6, 0, 0, 0.5f, 5.0f, 0.5f, 1, 0, 1);         /* camera inside, centre ahead */
    set_gaussian(&f, 7, 50.0f, 0, 0.25f, 0.01f, 0.9f, 1, 1, 1);   /* grazing: far off-axis */
    set_gaussian(&f, 8, 0, 0, 1e20f, 1e19f, 0.9f, 1, 1, 1);       /* very far */
    struct img m = render(ctx, &cam, &f, NULL);
    for (size_t i = 0; i < 3 * 64 * 48; i++)
        assert_true(isfinite(m.rgb[i]));
    for (size_t i = 0; i < 64 * 48; i++)
        assert_true(isfinite(m.depth[i]) && isfinite(m.alpha[i]) && m.alpha[i] >= 0 && m.alpha[i] <= 1);
    /* the zero-quaternion and zero-scale Gaussians still draw a dilated dot */
    assert_true(m.alpha[24 * 64 + 32 + 8] > 0.1f || m.alpha[25 * 64 + 32 + 8] > 0.1f);
    img_free(&m);
    splat_frame_free(&f);
    fk_ctx_free(ctx);
}

static void test_bad_render_input_rejected(void **state)
{
    (void)state;
    fk_ctx *ctx = make_ctx(1);
    splat_renderer *r;
    struct f4d_err err;
    assert_int_equal(splat_renderer_new(ctx, 0, 10, &r, &err), F4D_EINVAL);
    assert_non_null(strstr(err.msg, "0x10"));
    assert_int_equal(splat_renderer_new(ctx, 32, 32, &r, &err), 0);
    struct splat_camera cam = axis_camera(64, 32, 40.0f);
    struct splat_frame f = { 0 };
    float rgb[3 * 32 * 32];
    struct splat_render_out o = { .rgb = rgb };
    assert_int_equal(splat_render(r, &cam, &f, NULL, &o), F4D_EINVAL);
    assert_non_null(strstr(splat_renderer_error(r), "64x32"));
    splat_renderer_free(r);
    /* validation names the offending Gaussian */
    assert_int_equal(splat_frame_resize(&f, 3, 0, NULL), 0);
    set_gaussian(&f, 2, 0, 0, 1, 0.1f, 1.5f, 1, 1, 1);
    assert_int_equal(splat_frame_validate(&f, &err), F4D_EINVAL);
    assert_non_null(strstr(err.msg, "Gaussian 2"));
    splat_frame_free(&f);
    fk_ctx_free(ctx);
}

/* ---- files ----------------------------------------------------------------- */

static char tmpdir[256];

static void tmp_path(char *out, size_t n, const char *name)
{
    snprintf(out, n, "%s/%s", tmpdir, name);
}

static void test_ply_round_trip(void **state)
{
    (void)state;
    struct splat_frame f = { 0 }, g = { 0 };
    random_frame(&f, 257, 0.5f, 3.0f, 1.0f);
    assert_int_equal(splat_frame_reserve(&f, f.count, 1, NULL), 0);
    for (size_t i = 0; i < f.count; i++) {
        float *q = f.rot + 4 * i, n = sqrtf(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
        for (int k = 0; k < 4; k++)
            q[k] /= n;
        for (int k = 0; k < 3; k++) {
            f.motion_bwd[3 * i + k] = rnd(-0.1f, 0.1f);
            f.motion_fwd[3 * i + k] = rnd(-0.1f, 0.1f);
        }
    }
    f.opacity[0] = 0.0f;  /* logit clamps keep these finite */
    f.opacity[1] = 1.0f;
    char p[300];
    tmp_path(p, sizeof p, "rt.ply");
    struct f4d_err err;
    assert_int_equal(splat_ply_write(p, &f, &err), 0);
    assert_int_equal(splat_ply_read(p, &g, &err), 0);
    assert_int_equal(g.count, f.count);
    assert_non_null(g.motion_bwd);
    for (size_t i = 0; i < f.count; i++) {
        for (int k = 0; k < 3; k++) {
            assert_true(g.pos[3 * i + k] == f.pos[3 * i + k]);
            assert_float_equal(g.scale[3 * i + k], f.scale[3 * i + k], 1e-6 * f.scale[3 * i + k] + 1e-9);
            assert_float_equal(g.rgb[3 * i + k], f.rgb[3 * i + k], 1e-6);
            assert_true(g.motion_bwd[3 * i + k] == f.motion_bwd[3 * i + k]);
            assert_true(g.motion_fwd[3 * i + k] == f.motion_fwd[3 * i + k]);
        }
        for (int k = 0; k < 4; k++)
            assert_float_equal(g.rot[4 * i + k], f.rot[4 * i + k], 1e-6);
        assert_float_equal(g.opacity[i], f.opacity[i], 1e-6);
    }
    splat_frame_free(&f);
    splat_frame_free(&g);
}

/* A foreign INRIA file: properties in another order, f_rest and normals,
 * unnormalised and zero quaternions, an extra element after the vertices. */
static void test_ply_inria_by_name(void **state)
{
    (void)state;
    char p[300];
    tmp_path(p, sizeof p, "inria.ply");
    FILE *fp = fopen(p, "wb");
    assert_non_null(fp);
    const char *names[] = { "rot_0", "rot_1", "rot_2", "rot_3", "x", "y", "z", "nx", "ny", "nz", "f_dc_0",
                            "f_dc_1", "f_dc_2", "f_rest_0", "f_rest_1", "opacity", "scale_0", "scale_1", "scale_2" };
    fprintf(fp, "ply\nformat binary_little_endian 1.0\ncomment test\nelement vertex 2\n");
    for (int k = 0; k < 19; k++)
        fprintf(fp, "property float %s\n", names[k]);
    fprintf(fp, "element face 0\nproperty list uchar int vertex_indices\nend_header\n");
    float v[2][19] = { { 0, 0, 2, 0, 1, 2, 3, 0, 0, 0, 1, 0, -1, 9, 9, 0, -2, -3, -4 },
                       { 0, 0, 0, 0, 4, 5, 6, 0, 0, 0, 0, 0, 0, 9, 9, 2, 0, 0, 0 } };
    fwrite(v, sizeof v, 1, fp);
    fclose(fp);
    struct splat_frame f = { 0 };
    struct f4d_err err;
    assert_int_equal(splat_ply_read(p, &f, &err), 0);
    assert_int_equal(f.count, 2);
    assert_null(f.motion_bwd);
    assert_float_equal(f.pos[0], 1, 0); assert_float_equal(f.pos[2], 3, 0);
    assert_float_equal(f.rot[0], 0, 1e-7); assert_float_equal(f.rot[2], 1, 1e-7); /* (0,0,2,0) normalised */
    assert_float_equal(f.rot[4], 1, 0);                                           /* zero -> identity */
    assert_float_equal(f.rgb[0], 0.5f + SPLAT_SH_C0, 1e-6);
    assert_float_equal(f.rgb[2], 0.5f - SPLAT_SH_C0, 1e-6);
    assert_float_equal(f.opacity[0], 0.5f, 1e-7);
    assert_float_equal(f.scale[1], expf(-3), 1e-7);
    splat_frame_free(&f);
}

static void write_text(const char *p, const char *s)
{
    FILE *fp = fopen(p, "wb");
    assert_non_null(fp);
    fputs(s, fp);
    fclose(fp);
}

static void test_ply_bad_input_rejected(void **state)
{
    (void)state;
    char p[300];
    tmp_path(p, sizeof p, "bad.ply");
    struct splat_frame f = { 0 };
    struct f4d_err err;
    assert_int_equal(splat_ply_read("/nonexistent/x.ply", &f, &err), F4D_EIO);
    assert_non_null(strstr(err.msg, "cannot open"));
    write_text(p, "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nend_header\n1\n");
    assert_int_equal(splat_ply_read(p, &f, &err), F4D_EFORMAT);
    assert_non_null(strstr(err.msg, "ascii"));
    write_text(p, "ply\nformat binary_little_endian 1.0\nelement vertex 1\nproperty float x\nend_header\n");
    assert_int_equal(splat_ply_read(p, &f, &err), F4D_EFORMAT);
    assert_non_null(strstr(err.msg, "'y' is missing"));
    write_text(p, "not a ply\n");
    assert_int_equal(splat_ply_read(p, &f, &err), F4D_EFORMAT);
    /* truncated data */
    struct splat_frame g = { 0 };
    random_frame(&g, 10, 1, 2, 1);
    assert_int_equal(splat_ply_write(p, &g, &err), 0);
    struct stat st;
    assert_int_equal(stat(p, &st), 0);
    assert_int_equal(truncate(p, st.st_size - 100), 0);
    assert_int_equal(splat_ply_read(p, &f, &err), F4D_EFORMAT);
    assert_non_null(strstr(err.msg, "truncated"));
    splat_frame_free(&g);
    splat_frame_free(&f);
}

static void test_rig_json(void **state)
{
    (void)state;
    struct splat_rig rig, back;
    struct f4d_err err;
    const char *good = "{\"cameras\": [{\"name\": \"left\", \"width\": 64, \"height\": 48, \"fx\": 50, \"fy\": 51,"
                       " \"cx\": 32, \"cy\": 24, \"world_to_camera\": [[1,0,0,0.5],[0,1,0,0],[0,0,1,2],[0,0,0,1]]},"
                       " {\"name\": \"right\", \"width\": 64, \"height\": 48, \"fx\": 50, \"fy\": 50, \"cx\": 32,"
                       " \"cy\": 24, \"world_to_camera\": [0,0,1,0, 0,1,0,0, -1,0,0,3, 0,0,0,1]}]}";
    assert_int_equal(splat_rig_parse(good, &rig, &err), 0);
    assert_int_equal(rig.count, 2);
    assert_string_equal(rig.cams[1].name, "right");
    assert_float_equal(rig.cams[0].w2c[3], 0.5f, 0);
    assert_float_equal(rig.cams[0].fy, 51.0f, 0);
    assert_int_equal(splat_rig_find(&rig, "right", &err), 1);
    assert_int_equal(splat_rig_find(&rig, "0", &err), 0);
    assert_true(splat_rig_find(&rig, "7", &err) < 0);
    assert_non_null(strstr(err.msg, "out of range"));
    assert_true(splat_rig_find(&rig, "middle", &err) < 0);
    assert_non_null(strstr(err.msg, "middle"));
    float c[3];
    splat_camera_center(&rig.cams[1], c);
    assert_float_equal(c[0], 3.0f, 1e-6);
    char p[300];
    tmp_path(p, sizeof p, "rig.json");
    assert_int_equal(splat_rig_save(p, &rig, &err), 0);
    assert_int_equal(splat_rig_load(p, &back, &err), 0);
    assert_memory_equal(&back.cams[0], &rig.cams[0], sizeof rig.cams[0]);
    assert_memory_equal(&back.cams[1], &rig.cams[1], sizeof rig.cams[1]);

    assert_int_equal(splat_rig_parse("{\"cameras\": [", &rig, &err), F4D_EFORMAT);
    assert_non_null(strstr(err.msg, "invalid JSON"));
    assert_int_equal(splat_rig_parse("{\"cams\": []}", &rig, &err), F4D_EFORMAT);
    assert_non_null(strstr(err.msg, "cameras"));
    assert_int_equal(splat_rig_parse("{\"cameras\": [{\"width\": 4, \"height\": 4, \"fx\": 1, \"fy\": 1, \"cx\": 2,"
                                     " \"world_to_camera\": [1,0,0,0,0,1,0,0,0,0,1,0,0,0,0,1]}]}", &rig, &err),
                     F4D_EFORMAT);
    assert_non_null(strstr(err.msg, "cy"));
    assert_int_equal(splat_rig_parse("{\"cameras\": [{\"width\": 4, \"height\": 4, \"fx\": 1, \"fy\": 1, \"cx\": 2,"
                                     " \"cy\": 2, \"world_to_camera\": [2,0,0,0,0,1,0,0,0,0,1,0,0,0,0,1]}]}", &rig, &err),
                     F4D_EFORMAT);
    assert_non_null(strstr(err.msg, "orthonormal"));
    assert_int_equal(splat_rig_parse("{\"cameras\": [{\"width\": 4, \"height\": 4, \"fx\": 1, \"fy\": 1, \"cx\": 2,"
                                     " \"cy\": 2, \"world_to_camera\": [1,0,0]}]}", &rig, &err), F4D_EFORMAT);
    assert_non_null(strstr(err.msg, "16"));
    assert_int_equal(splat_rig_load("/nonexistent.json", &rig, &err), F4D_EIO);
}

static void test_png_and_npy(void **state)
{
    (void)state;
    char p[300];
    tmp_path(p, sizeof p, "t.png");
    float img[3 * 5 * 4];
    for (int i = 0; i < 60; i++)
        img[i] = (float)i / 59.0f * 1.2f - 0.1f;
    struct f4d_err err;
    assert_int_equal(splat_png_write_rgb(p, img, 5, 4, &err), 0);
    float *back;
    int w, h;
    assert_int_equal(splat_png_read_rgb(p, &back, &w, &h, &err), 0);
    assert_int_equal(w, 5);
    assert_int_equal(h, 4);
    for (int i = 0; i < 60; i++) {
        float v = fminf(1.0f, fmaxf(0.0f, img[i]));
        assert_float_equal(back[i], floorf(v * 255.0f + 0.5f) / 255.0f, 1e-7);
    }
    free(back);
    assert_int_equal(splat_png_read_rgb("/nonexistent.png", &back, &w, &h, &err), F4D_EIO);
    tmp_path(p, sizeof p, "t.npy");
    size_t shape[3] = { 4, 5, 3 };
    assert_int_equal(splat_npy_write_f32(p, img, shape, 3, &err), 0);
    FILE *fp = fopen(p, "rb");
    unsigned char hdr[256];
    size_t got = fread(hdr, 1, sizeof hdr, fp);
    fclose(fp);
    assert_true(got == sizeof hdr);
    struct stat st;
    assert_int_equal(stat(p, &st), 0);
    assert_int_equal(st.st_size, 128 + 240);
    assert_memory_equal(hdr, "\x93NUMPY\x01\x00", 8);
    assert_int_equal(hdr[8] + 256 * hdr[9] + 10, 128);
    assert_non_null(strstr((const char *)hdr + 10, "'shape': (4, 5, 3)"));
    assert_int_equal(hdr[127], '\n');
}

/* ---- metrics --------------------------------------------------------------- */

static void test_metrics(void **state)
{
    (void)state;
    enum { W = 23, H = 17 };
    float a[W * H * 3], b[W * H * 3];
    for (int i = 0; i < W * H * 3; i++) {
        a[i] = rnd(0.2f, 0.8f);
        b[i] = a[i] + 0.1f;
    }
    assert_float_equal(splat_psnr(a, b, W, H, 3), 20.0, 1e-4);
    assert_true(isinf(splat_psnr(a, a, W, H, 3)));
    assert_float_equal(splat_ssim(a, a, W, H, 3, NULL), 1.0, 1e-6);
    /* brute-force 2-D conv with zero padding, as 3DGS's F.conv2d(padding=5) */
    for (int i = 0; i < W * H * 3; i++)
        b[i] = fminf(1.0f, fmaxf(0.0f, a[i] + rnd(-0.2f, 0.2f)));
    double g[11], gs = 0;
    for (int x = 0; x < 11; x++)
        gs += g[x] = exp(-(x - 5.0) * (x - 5.0) / 4.5);
    double total = 0;
    for (int c = 0; c < 3; c++)
        for (int y = 0; y < H; y++)
            for (int x = 0; x < W; x++) {
                double m1 = 0, m2 = 0, s11 = 0, s22 = 0, s12 = 0;
                for (int v = -5; v <= 5; v++)
                    for (int u = -5; u <= 5; u++) {
                        int xx = x + u, yy = y + v;
                        if (xx < 0 || yy < 0 || xx >= W || yy >= H)
                            continue;
                        double w = g[u + 5] * g[v + 5] / (gs * gs), p = a[3 * (yy * W + xx) + c],
                               q = b[3 * (yy * W + xx) + c];
                        m1 += w * p; m2 += w * q; s11 += w * p * p; s22 += w * q * q; s12 += w * p * q;
                    }
                double C1 = 1e-4, C2 = 9e-4;
                total += ((2 * m1 * m2 + C1) * (2 * (s12 - m1 * m2) + C2)) /
                         ((m1 * m1 + m2 * m2 + C1) * (s11 - m1 * m1 + s22 - m2 * m2 + C2));
            }
    assert_float_equal(splat_ssim(a, b, W, H, 3, NULL), total / (W * H * 3), 2e-5);
    /* TL-STD: grey frames alternating 0 and 1 -> luma std 0.5 everywhere */
    static float f0[W * H * 3], f1[W * H * 3];
    for (int i = 0; i < W * H * 3; i++) {
        f0[i] = 0.0f;
        f1[i] = 1.0f;
    }
    const float *seq[4] = { f0, f1, f0, f1 };
    assert_float_equal(splat_tlstd(seq, 4, W, H), 0.5, 1e-6);
    const float *still[3] = { a, a, a };
    assert_float_equal(splat_tlstd(still, 3, W, H), 0.0, 1e-6);
}

/* ---- real data -------------------------------------------------------------- */

static void test_donut_renders(void **state)
{
    (void)state;
    const char *path = SHARED_DIR "/data/splats/donut.ply";
    if (access(path, R_OK) != 0)
        f4d_skip("test_donut_renders: %s is absent (../shared beside the repository holds the data)", path);
    struct splat_frame f = { 0 };
    struct f4d_err err;
    if (splat_ply_read(path, &f, &err) < 0)
        fail_msg("%s", err.msg);
    assert_int_equal(f.count, 45624);
    assert_int_equal(splat_frame_validate(&f, &err), 0);
    struct splat_camera cam;
    memset(&cam, 0, sizeof cam);
    cam.width = 128; cam.height = 128; cam.fx = cam.fy = 150; cam.cx = cam.cy = 64;
    const float eye[3] = { 0, -0.35f, 0.3f }, at[3] = { 0, 0, 0.03f }, up[3] = { 0, 0, 1 };
    splat_camera_look_at(&cam, eye, at, up);
    assert_int_equal(splat_camera_validate(&cam, &err), 0);
    fk_ctx *ctx = make_ctx(2);
    const float white[3] = { 1, 1, 1 };
    struct img m = render(ctx, &cam, &f, white);
    size_t covered = 0;
    double pink = 0;
    for (int i = 0; i < 128 * 128; i++) {
        assert_true(isfinite(m.rgb[3 * i]) && isfinite(m.depth[i]));
        if (m.alpha[i] > 0.9f) {
            covered++;
            assert_true(m.depth[i] > 0.3f && m.depth[i] < 0.6f);
            pink += m.rgb[3 * i] - m.rgb[3 * i + 1];
        }
    }
    /* the donut fills a good part of the view; icing and dough are warm (red > green) */
    assert_true(covered > 128 * 128 / 8 && covered < 128 * 128 * 3 / 4);
    assert_true(pink / (double)covered > 0.02);
    img_free(&m);
    fk_ctx_free(ctx);
    splat_frame_free(&f);
}

static int setup(void **state)
{
    (void)state;
    return f4d_test_mkdtemp(tmpdir, sizeof tmpdir, "test_splat");
}

static int teardown(void **state)
{
    (void)state;
    return f4d_test_rmtree(tmpdir);
}

int main(int argc, char **argv)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_single_isotropic_peak_and_falloff),
        cmocka_unit_test(test_two_overlapping_order_and_transmittance),
        cmocka_unit_test(test_alpha_clamp_099),
        cmocka_unit_test(test_alpha_skip_1_over_255),
        cmocka_unit_test(test_transmittance_stop_1e4),
        cmocka_unit_test(test_near_plane_cull_02),
        cmocka_unit_test(test_matches_bruteforce_reference),
        cmocka_unit_test(test_threads_give_identical_images),
        cmocka_unit_test(test_simd_matches_scalar),
        cmocka_unit_test(test_avx512_matches_avx2),
        cmocka_unit_test(test_flow_from_motion),
        cmocka_unit_test(test_hard_cases_stay_finite),
        cmocka_unit_test(test_bad_render_input_rejected),
        cmocka_unit_test(test_ply_round_trip),
        cmocka_unit_test(test_ply_inria_by_name),
        cmocka_unit_test(test_ply_bad_input_rejected),
        cmocka_unit_test(test_rig_json),
        cmocka_unit_test(test_png_and_npy),
        cmocka_unit_test(test_metrics),
        cmocka_unit_test(test_rgba8_matches_rgb),
        cmocka_unit_test(test_donut_renders),
    };
    return F4D_TEST_MAIN(argc, argv, "splat", tests, setup, teardown);
}
