/* test_sequence.c - the Forge4D streaming API on the tiny fixtures:
 *   - key frames equal the model's own outputs (the fixture's Gaussians and
 *     metric cameras for the fixture input), pixel aligned, valid, one key
 *     time per push, the previous key kept across pushes;
 *   - interpolation: in the mode the weights allow (INTERP_NEAREST without a
 *     motion part), at the keys' times and in between;
 *   - errors: a weight file without the Gaussian head, interpolation before
 *     two keys or outside the last interval, a mode the weights cannot do.
 *
 *   test_sequence FIXTURE_DIR GGUF_DIR
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "f4d_sequence.h"
#include "f4d_test.h"
#include "npy.h"

static const char *fix_dir, *gguf_dir;

struct fx {
    fk_ctx       *ctx;
    f4d_sequence *sq;
    float        *input, *pos, *ext;
    int           S, H, W;
};

static float *load(const char *name, int64_t *sh, int *nd)
{
    char p[1024];
    struct f4d_err err = { 0 };
    float *d = NULL;
    snprintf(p, sizeof p, "%s/tiny_f4d/s2/%s.npy", fix_dir, name);
    if (npy_load_f32(p, &d, sh, nd, &err) < 0)
        fail_msg("%s", err.msg);
    return d;
}

static int setup(void **state)
{
    char p[1024];
    snprintf(p, sizeof p, "%s/tiny_f4d_f32.gguf", gguf_dir);
    if (access(p, R_OK) != 0) {
        print_error("%s is absent (model/convert_tiny_f4d_f32 makes it)\n", p);
        return -1;
    }
    struct fx *f = calloc(1, sizeof *f);
    int64_t sh[8];
    int nd;
    f->input = load("input", sh, &nd);
    f->S = (int)sh[0];
    f->H = (int)sh[2];
    f->W = (int)sh[3];
    f->pos = load("gaussians_pos", sh, &nd);
    f->ext = load("extrinsic_metric", sh, &nd);
    struct f4d_err err = { 0 };
    if (fk_ctx_new(&(struct fk_ctx_config){ .isa = FK_ISA_AUTO, .threads = 1 }, &f->ctx) < 0 ||
        f4d_sequence_open(f->ctx, p, FK_W_F32, f->S, f->H, f->W, &f->sq, &err) < 0) {
        print_error("open: %s\n", err.msg);
        return -1;
    }
    *state = f;
    return 0;
}

static int teardown(void **state)
{
    struct fx *f = *state;
    if (!f)
        return 0;
    f4d_sequence_close(f->sq);
    fk_ctx_free(f->ctx);
    free(f->input);
    free(f->pos);
    free(f->ext);
    free(f);
    return 0;
}

static double max_rel(const float *a, const float *b, size_t n)
{
    double m = 0;
    for (size_t i = 0; i < n; i++) {
        double d = fabs((double)a[i] - b[i]) / (fabs((double)b[i]) + 1e-3);
        m = d > m ? d : m;
    }
    return m;
}

/* The fixture input pushed as key 0 gives the fixture's Gaussians; a second
 * (brighter) set is key 1 while key 0 stays intact in the other slot. */
static void keys(void **state)
{
    struct fx *f = *state;
    struct f4d_err err = { 0 };
    const size_t n = (size_t)f->S * f->H * f->W, ni = n * 3;
    assert_int_equal(f4d_sequence_steps(f->sq), 0);
    assert_int_equal(f4d_sequence_push(f->sq, f->input, &err), 0);
    struct f4d_seq_key k0, k1, kp;
    assert_int_equal(f4d_sequence_key(f->sq, 0, &k0, &err), 0);
    assert_int_equal(f4d_sequence_key(f->sq, 1, &kp, &err), F4D_EINVAL); /* one key only */
    assert_int_equal(k0.t, 0);
    assert_int_equal(k0.frame.count, n);
    assert_null(k0.frame.motion_bwd);
    assert_null(k0.frame.motion_fwd);
    assert_int_equal(splat_frame_validate(&k0.frame, &err), 0);
    double e_pos = max_rel(k0.frame.pos, f->pos, 3 * n), e_ext = max_rel(k0.extrinsic, f->ext, 12 * (size_t)f->S);
    printf("key 0 against the fixture: pos %.2e, extrinsic_metric %.2e (max rel)\n", e_pos, e_ext);
    assert_true(e_pos < 1e-4 && e_ext < 1e-4);
    assert_true(k0.has_gauge && k0.gauge > 0);
    assert_int_equal(k0.rig.count, f->S);
    for (int s = 0; s < f->S; s++) {
        assert_int_equal(splat_camera_validate(&k0.rig.cams[s], &err), 0);
        assert_float_equal(k0.rig.cams[s].w2c[3], k0.extrinsic[12 * s + 3], 0);
        assert_float_equal(k0.rig.cams[s].fx, k0.intrinsic[9 * s], 0);
    }
    float *pos0 = malloc(3 * n * sizeof *pos0), *in2 = malloc(ni * sizeof *in2);
    memcpy(pos0, k0.frame.pos, 3 * n * sizeof *pos0);
    for (size_t i = 0; i < ni; i++)
        in2[i] = 0.5f + 0.5f * f->input[i];
    assert_int_equal(f4d_sequence_push(f->sq, in2, &err), 0);
    assert_int_equal(f4d_sequence_steps(f->sq), 2);
    assert_int_equal(f4d_sequence_key(f->sq, 0, &k1, &err), 0);
    assert_int_equal(f4d_sequence_key(f->sq, 1, &kp, &err), 0);
    assert_int_equal(k1.t, 1);
    assert_int_equal(kp.t, 0);
    assert_memory_equal(kp.frame.pos, pos0, 3 * n * sizeof *pos0);
    assert_true(max_rel(k1.frame.pos, pos0, 3 * n) > 1e-3); /* a different set, a different key */
    /* a third push: key 1 becomes the previous key, key 0 is gone */
    assert_int_equal(f4d_sequence_push(f->sq, f->input, &err), 0);
    assert_int_equal(f4d_sequence_key(f->sq, 0, &k1, &err), 0);
    assert_int_equal(f4d_sequence_key(f->sq, 1, &kp, &err), 0);
    assert_int_equal(k1.t, 2);
    assert_int_equal(kp.t, 1);
    free(pos0);
    free(in2);
}

/* Interpolation in the mode the weights allow, at both ends and in between. */
static void interpolate(void **state)
{
    struct fx *f = *state;
    struct f4d_err err = { 0 };
    const struct splat_frame *mid;
    struct f4d_seq_key kt, kp;
    while (f4d_sequence_steps(f->sq) < 2) /* run alone (--case) */
        assert_int_equal(f4d_sequence_push(f->sq, f->input, &err), 0);
    assert_int_equal(f4d_sequence_key(f->sq, 0, &kt, &err), 0);
    assert_int_equal(f4d_sequence_key(f->sq, 1, &kp, &err), 0);
    if (!f4d_sequence_has_motion(f->sq)) {
        assert_int_equal(f4d_sequence_mode(f->sq), INTERP_NEAREST);
        assert_int_equal(f4d_sequence_set_mode(f->sq, INTERP_FUSED, &err), F4D_EINVAL);
        assert_non_null(strstr(err.msg, "motion"));
    }
    double ts[3] = { (double)kp.t, (double)kt.t - 0.5, (double)kt.t };
    for (int i = 0; i < 3; i++) {
        struct interp_stats st;
        assert_int_equal(f4d_sequence_at(f->sq, ts[i], &mid, &st, &err), 0);
        assert_null(mid->motion_bwd);
        assert_int_equal(splat_frame_validate(mid, &err), 0);
        if (f4d_sequence_mode(f->sq) == INTERP_NEAREST) {
            const struct splat_frame *want = ts[i] - kp.t < 0.5 ? &kp.frame : &kt.frame;
            assert_int_equal(mid->count, want->count);
            assert_memory_equal(mid->pos, want->pos, 3 * want->count * sizeof(float));
        } else {
            assert_true(mid->count >= kt.frame.count / 2 && mid->count <= 2 * kt.frame.count);
        }
    }
    assert_int_equal(f4d_sequence_at(f->sq, kt.t + 0.25, &mid, NULL, &err), F4D_EINVAL);
    assert_non_null(strstr(err.msg, "outside"));
    assert_int_equal(f4d_sequence_at(f->sq, kp.t - 0.25, &mid, NULL, &err), F4D_EINVAL);
}

static void errors(void **state)
{
    struct fx *f = *state;
    struct f4d_err err = { 0 };
    char p[1024];
    f4d_sequence *sq = (f4d_sequence *)1;
    snprintf(p, sizeof p, "%s/tiny_f32.gguf", gguf_dir); /* plain VGGT: no Gaussian head */
    assert_int_equal(f4d_sequence_open(f->ctx, p, FK_W_F32, 2, 42, 70, &sq, &err), F4D_EINVAL);
    assert_null(sq);
    assert_non_null(strstr(err.msg, "gaussian_head"));
    snprintf(p, sizeof p, "%s/tiny_f4d_f32.gguf", gguf_dir);
    assert_int_equal(f4d_sequence_open(f->ctx, p, FK_W_F32, 0, 42, 70, &sq, &err), F4D_EINVAL);
    assert_non_null(strstr(err.msg, "views"));
    /* a fresh sequence: no key yet, no interpolation */
    fk_ctx *ctx2;
    assert_int_equal(fk_ctx_new(&(struct fk_ctx_config){ .isa = FK_ISA_AUTO, .threads = 1 }, &ctx2), 0);
    assert_int_equal(f4d_sequence_open(ctx2, p, FK_W_F16, 2, 42, 70, &sq, &err), 0);
    const struct splat_frame *mid;
    struct f4d_seq_key k;
    assert_int_equal(f4d_sequence_key(sq, 0, &k, &err), F4D_EINVAL);
    assert_int_equal(f4d_sequence_at(sq, 0.5, &mid, NULL, &err), F4D_EINVAL);
    assert_non_null(strstr(err.msg, "two keys"));
    assert_int_equal(f4d_sequence_push(sq, NULL, &err), F4D_EINVAL);
    f4d_sequence_close(sq);
    fk_ctx_free(ctx2);
}

int main(int argc, char **argv)
{
    argc = f4d_test_parse(argc, argv);
    if (argc != 3) {
        fprintf(stderr, "usage: test_sequence FIXTURE_DIR GGUF_DIR\n");
        return 2;
    }
    fix_dir = argv[1];
    gguf_dir = argv[2];
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(keys),
        cmocka_unit_test(interpolate),
        cmocka_unit_test(errors),
    };
    return F4D_TEST_MAIN(argc, argv, "sequence", tests, setup, teardown);
}
