/* test_interp_hard.c - the hard cases of interpolation (issue 10, item 5), on
 * small pixel-aligned frames (interp_key_build_aligned) seen by one camera at
 * the origin looking down +z, every Gaussian on the plane z = 2 at the centre
 * of its pixel, matched by zero motion unless a case moves it:
 *   - motion carrying a Gaussian behind the camera (camera depth < 0 and
 *     exactly 0): no partner, kept deformed, no NaN anywhere;
 *   - a partner pixel outside the image (right, left, below): no partner;
 *   - a zero quaternion reaching fusion (both of a pair, or one): the fused
 *     Gaussian has a finite unit rotation (the identity, or the other one);
 *   - the aligned lookup and the per-key cameras: wrong counts and rigs are
 *     refused, and a key keeps the cameras it was built with.
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "f4d_test.h"
#include "interp.h"

#define W 8
#define H 6
#define N (W * H)
#define Z 2.0f

struct fx {
    fk_ctx            *ctx;
    interp            *ip;
    struct splat_rig   rig;
    struct splat_frame f0, f1, out;
    struct interp_key  k0, k1;
};

static void camera(struct splat_camera *c, float tx)
{
    memset(c, 0, sizeof *c);
    c->width = W;
    c->height = H;
    c->fx = c->fy = 8.0f;
    c->cx = 0.5f * W;
    c->cy = 0.5f * H;
    for (int k = 0; k < 4; k++)
        c->w2c[5 * k] = 1.0f;
    c->w2c[3] = tx;
}

/* Gaussian y * W + x at the centre of pixel (x, y), depth Z. */
static void plane(struct splat_frame *f)
{
    struct f4d_err err;
    assert_int_equal(splat_frame_resize(f, N, 1, &err), 0);
    for (int y = 0; y < H; y++)
        for (int x = 0; x < W; x++) {
            size_t g = (size_t)y * W + x;
            f->pos[3 * g] = ((float)x + 0.5f - 0.5f * W) * Z / 8.0f;
            f->pos[3 * g + 1] = ((float)y + 0.5f - 0.5f * H) * Z / 8.0f;
            f->pos[3 * g + 2] = Z;
            for (int c = 0; c < 3; c++) {
                f->scale[3 * g + c] = 0.01f;
                f->rgb[3 * g + c] = 0.1f * (float)c + 0.01f * (float)g;
                f->motion_bwd[3 * g + c] = f->motion_fwd[3 * g + c] = 0.0f;
            }
            f->opacity[g] = 0.9f;
            f->rot[4 * g] = 1.0f;
            f->rot[4 * g + 1] = f->rot[4 * g + 2] = f->rot[4 * g + 3] = 0.0f;
        }
}

static int setup(void **state)
{
    struct fx *f = calloc(1, sizeof *f);
    struct f4d_err err = { 0 };
    f->rig.count = 1;
    camera(&f->rig.cams[0], 0.0f);
    if (fk_ctx_new(&(struct fk_ctx_config){ .isa = FK_ISA_AUTO, .threads = 1 }, &f->ctx) < 0 ||
        interp_new(f->ctx, &f->rig, &f->ip, &err) < 0) {
        print_error("setup: %s\n", err.msg);
        return -1;
    }
    *state = f;
    return 0;
}

static int teardown(void **state)
{
    struct fx *f = *state;
    interp_key_free(&f->k0);
    interp_key_free(&f->k1);
    splat_frame_free(&f->f0);
    splat_frame_free(&f->f1);
    splat_frame_free(&f->out);
    interp_free(f->ip);
    fk_ctx_free(f->ctx);
    free(f);
    return 0;
}

/* Both keys on the plane, built; f1's motion_bwd is then edited by the case. */
static void fresh(struct fx *f)
{
    struct f4d_err err = { 0 };
    plane(&f->f0);
    plane(&f->f1);
    assert_int_equal(interp_set_rig(f->ip, &f->rig, &err), 0);
    assert_int_equal(interp_key_build_aligned(f->ip, &f->f0, &f->k0, &err), 0);
    assert_int_equal(interp_key_build_aligned(f->ip, &f->f1, &f->k1, &err), 0);
}

static void all_finite(const struct splat_frame *o)
{
    struct f4d_err err = { 0 };
    if (splat_frame_validate(o, &err) < 0)
        fail_msg("output: %s", err.msg);
}

static void run(struct fx *f, float a, struct interp_stats *st)
{
    struct f4d_err err = { 0 };
    struct interp_config cfg = interp_config_default();
    if (interp_at(f->ip, &f->k0, &f->k1, a, &cfg, &f->out, st, &err) < 0)
        fail_msg("interp_at: %s", err.msg);
    all_finite(&f->out);
}

/* Zero motion everywhere: every Gaussian of t fused with its own pixel. */
static void matched_plane(void **state)
{
    struct fx *f = *state;
    struct interp_stats st;
    fresh(f);
    run(f, 0.5f, &st);
    assert_int_equal(st.fused, N);
    assert_int_equal(st.dropped_tm1, N);
    assert_int_equal(st.kept_t + st.kept_tm1, 0);
    assert_int_equal(f->out.count, N);
}

static void behind_camera(void **state)
{
    struct fx *f = *state;
    struct interp_stats st;
    fresh(f);
    const float a = 0.25f;
    f->f1.motion_bwd[3 * 9 + 2] = -5.0f;  /* to z = -3 */
    f->f1.motion_bwd[3 * 20 + 2] = -Z;    /* to z = 0 exactly: no division by zero */
    f->f1.motion_bwd[3 * 21 + 2] = -1.9f; /* to z = 0.1, inside the near plane */
    run(f, a, &st);
    assert_int_equal(st.kept_t, 3);
    assert_int_equal(st.fused, N - 3);
    /* kept as is, deformed by (1 - a) M1 */
    assert_float_equal(f->out.pos[3 * 9 + 2], Z - (1 - a) * 5.0f, 1e-6);
    assert_float_equal(f->out.pos[3 * 20 + 2], Z - (1 - a) * Z, 1e-6);
    /* the same for key t-1 moved behind by M2 */
    fresh(f);
    f->f0.motion_fwd[3 * 5 + 2] = -4.0f;
    run(f, a, &st);
    assert_int_equal(st.kept_tm1, 1);
    assert_int_equal(st.dropped_tm1, N - 1);
    assert_int_equal(f->out.count, N + 1);
    assert_float_equal(f->out.pos[3 * N + 2], Z - a * 4.0f, 1e-6);
}

static void outside_image(void **state)
{
    struct fx *f = *state;
    struct interp_stats st;
    fresh(f);
    f->f1.motion_bwd[3 * 7] = 2.0f;      /* last column moved right: u >= W */
    f->f1.motion_bwd[3 * 8] = -3.0f;     /* first column moved left: u < 0 */
    f->f1.motion_bwd[3 * 40 + 1] = 1.0f; /* last row moved down: v >= H */
    f->f1.motion_bwd[3 * 41 + 1] = 1e30f; /* far outside: no integer overflow */
    run(f, 0.5f, &st);
    assert_int_equal(st.kept_t, 4);
    assert_int_equal(st.fused, N - 4);
    /* moved exactly to the image border (u = W): still outside */
    fresh(f);
    float u_edge = (float)W;             /* x with fx x / z + cx = W */
    f->f1.motion_bwd[3 * 15] = (u_edge - 0.5f * W) * Z / 8.0f - f->f1.pos[3 * 15];
    run(f, 0.5f, &st);
    assert_int_equal(st.kept_t, 1);
}

struct seen { int calls, zero_t, zero_tm1; };

static void recording_average(void *user, const float at[INTERP_ATTRS], const float am[INTERP_ATTRS], float a,
                              float D, float out[INTERP_ATTRS])
{
    struct seen *s = user;
    s->calls++;
    s->zero_t += at[10] == 0 && at[11] == 0 && at[12] == 0 && at[13] == 0;
    s->zero_tm1 += am[10] == 0 && am[11] == 0 && am[12] == 0 && am[13] == 0;
    interp_fuse_average(NULL, at, am, a, D, out);
}

static void zero_quaternion(void **state)
{
    struct fx *f = *state;
    struct interp_stats st;
    struct f4d_err err = { 0 };
    fresh(f);
    memset(f->f1.rot + 4 * 3, 0, 4 * sizeof(float)); /* both of pair 3 zero */
    memset(f->f0.rot + 4 * 3, 0, 4 * sizeof(float));
    memset(f->f0.rot + 4 * 4, 0, 4 * sizeof(float)); /* one of pair 4 zero */
    const float q[4] = { 0.5f, 0.5f, -0.5f, 0.5f };
    memcpy(f->f1.rot + 4 * 4, q, sizeof q);
    struct seen s = { 0 };
    struct interp_config cfg = interp_config_default();
    cfg.fuse = recording_average;
    cfg.fuse_user = &s;
    assert_int_equal(interp_at(f->ip, &f->k0, &f->k1, 0.5f, &cfg, &f->out, &st, &err), 0);
    all_finite(&f->out);
    assert_int_equal(s.calls, N);
    assert_int_equal(s.zero_t, 1);
    assert_int_equal(s.zero_tm1, 2);
    const float *r3 = f->out.rot + 4 * 3, *r4 = f->out.rot + 4 * 4;
    assert_float_equal(r3[0], 1.0f, 0);
    assert_float_equal(r3[1] * r3[1] + r3[2] * r3[2] + r3[3] * r3[3], 0.0f, 0);
    for (int c = 0; c < 4; c++)
        assert_float_equal(r4[c], q[c], 1e-6);
}

static void aligned_and_rigs(void **state)
{
    struct fx *f = *state;
    struct f4d_err err = { 0 };
    struct splat_frame small = { 0 };
    assert_int_equal(splat_frame_resize(&small, N - 1, 1, &err), 0);
    assert_int_equal(interp_key_build_aligned(f->ip, &small, &f->k0, &err), F4D_EINVAL);
    assert_non_null(strstr(err.msg, "pixel-aligned"));
    splat_frame_free(&small);
    struct splat_rig r2 = f->rig;
    r2.cams[0].width = W + 1;
    assert_int_equal(interp_set_rig(f->ip, &r2, &err), F4D_EINVAL);
    r2 = f->rig;
    r2.count = 2;
    r2.cams[1] = r2.cams[0];
    assert_int_equal(interp_set_rig(f->ip, &r2, &err), F4D_EINVAL);
    /* Key t-1 built with a camera shifted 0.5 m (w2c tx = 0.5) and its
     * Gaussians 0.5 m the other way in the world: each lies 2 columns to the
     * right of key t's Gaussian at the same world point (fx 0.5 / Z = 2 px).
     * Projected with key t-1's own cameras, key t's unmoved Gaussians find
     * exactly those partners (D = 0: fused) except in the last 2 columns,
     * which land outside key t-1's image. With key t's cameras they would
     * find the same pixel, 0.5 m away, and fuse none. */
    fresh(f);
    r2 = f->rig;
    camera(&r2.cams[0], 0.5f);
    for (size_t g = 0; g < N; g++)
        f->f0.pos[3 * g] -= 0.5f;
    assert_int_equal(interp_set_rig(f->ip, &r2, &err), 0);
    assert_int_equal(interp_key_build_aligned(f->ip, &f->f0, &f->k0, &err), 0);
    assert_int_equal(interp_set_rig(f->ip, &f->rig, &err), 0);
    struct interp_stats st;
    run(f, 0.5f, &st);
    assert_int_equal(st.fused, N - 2 * H);
    assert_int_equal(st.kept_t, 2 * H);
}

int main(int argc, char **argv)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(matched_plane),  cmocka_unit_test(behind_camera),
        cmocka_unit_test(outside_image),  cmocka_unit_test(zero_quaternion),
        cmocka_unit_test(aligned_and_rigs),
    };
    return F4D_TEST_MAIN(argc, argv, "interp_hard", tests, setup, teardown);
}
