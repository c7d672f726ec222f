/* test_sequence.c - the Forge4D streaming API on the tiny fixtures:
 *   - key frames equal the model's own outputs (the fixture's Gaussians and
 *     metric cameras for the fixture input), pixel aligned, valid, one key
 *     time per push, the previous key kept across pushes;
 *   - interpolation: in the mode the weights allow (INTERP_NEAREST without a
 *     motion part), at the keys' times and in between;
 *   - errors: a weight file without the Gaussian head, interpolation before
 *     two keys or outside the last interval, a mode the weights cannot do;
 *   - with the motion part (tiny_f4d_seq, 4 time steps): every key's
 *     Gaussians, M1[t] on key t and M2[t-1] on key t-1 equal the reference
 *     sequence, and frames between keys are fused by the weights' MLP;
 *   - the fusion MLP with fc2 = 0 (weights zeroed in memory) gives exactly
 *     what averaging gives, pair by pair and through interp_at;
 *   - set_fusion switches between the MLP and averaging on the same keys.
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
#include "gguf.h"
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
    if (!f4d_sequence_has_fusion(f->sq)) {
        assert_int_equal(f4d_sequence_set_fusion(f->sq, 1, &err), F4D_EINVAL);
        assert_non_null(strstr(err.msg, "fusion"));
        assert_int_equal(f4d_sequence_set_fusion(f->sq, 0, &err), 0);
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

static float *load_seq(const char *name, size_t want)
{
    char p[1024];
    struct f4d_err err = { 0 };
    float *d = NULL;
    int64_t sh[8];
    int nd;
    snprintf(p, sizeof p, "%s/tiny_f4d_seq/%s.npy", fix_dir, name);
    if (npy_load_f32(p, &d, sh, &nd, &err) < 0)
        fail_msg("%s", err.msg);
    size_t n = 1;
    for (int k = 0; k < nd; k++)
        n *= (size_t)sh[k];
    if (want && n != want)
        fail_msg("%s: %zu values, want %zu", p, n, want);
    return d;
}

/* max |a - b| over the RMS of b: the model's parity measure */
static double err_rms(const float *a, const float *b, size_t n)
{
    double m = 0, ss = 0;
    for (size_t i = 0; i < n; i++) {
        double d = fabs((double)a[i] - b[i]);
        m = d > m ? d : m;
        ss += (double)b[i] * b[i];
    }
    return m / (sqrt(ss / (double)n) + 1e-12);
}

static void motion_parity(void **state)
{
    (void)state;
    char p[1024];
    snprintf(p, sizeof p, "%s/tiny_f4d_seq_f32.gguf", gguf_dir);
    fk_ctx *ctx;
    f4d_sequence *sq;
    struct f4d_err err = { 0 };
    const int S = 2, H = 28, W = 42;
    const size_t n = (size_t)S * H * W;
    assert_int_equal(fk_ctx_new(&(struct fk_ctx_config){ .isa = FK_ISA_AUTO, .threads = 1 }, &ctx), 0);
    if (f4d_sequence_open(ctx, p, FK_W_F32, S, H, W, &sq, &err) < 0)
        fail_msg("open: %s", err.msg);
    assert_true(f4d_sequence_has_motion(sq));
    assert_true(f4d_sequence_has_fusion(sq));
    assert_int_equal(f4d_sequence_mode(sq), INTERP_FUSED);
    double worst = 0;
    for (int t = 0; t < 4; t++) {
        char name[64];
        snprintf(name, sizeof name, "t%d/input", t);
        float *x = load_seq(name, n * 3);
        assert_int_equal(f4d_sequence_push(sq, x, &err), 0);
        free(x);
        struct f4d_seq_key k, kp;
        assert_int_equal(f4d_sequence_key(sq, 0, &k, &err), 0);
        assert_int_equal(k.t, t);
        snprintf(name, sizeof name, "t%d/gaussians_pos", t);
        float *pos = load_seq(name, 3 * n);
        double e = err_rms(k.frame.pos, pos, 3 * n);
        free(pos);
        assert_null(k.frame.motion_fwd); /* comes with the next key */
        if (!t) {
            assert_null(k.frame.motion_bwd);
            printf("t=0: pos %.2e\n", e);
            worst = e > worst ? e : worst;
            continue;
        }
        assert_int_equal(f4d_sequence_key(sq, 1, &kp, &err), 0);
        assert_non_null(k.frame.motion_bwd);
        assert_non_null(kp.frame.motion_fwd);
        snprintf(name, sizeof name, "t%d/motion_bwd", t);
        float *m1 = load_seq(name, 3 * n);
        snprintf(name, sizeof name, "t%d/motion_fwd_prev", t);
        float *m2 = load_seq(name, 3 * n);
        double e1 = err_rms(k.frame.motion_bwd, m1, 3 * n), e2 = err_rms(kp.frame.motion_fwd, m2, 3 * n);
        printf("t=%d: pos %.2e, M1[t] %.2e, M2[t-1] %.2e (max error / RMS)\n", t, e, e1, e2);
        free(m1);
        free(m2);
        worst = e > worst ? e : worst;
        worst = e1 > worst ? e1 : worst;
        worst = e2 > worst ? e2 : worst;
        const struct splat_frame *mid;
        struct interp_stats st;
        assert_int_equal(f4d_sequence_at(sq, t - 0.5, &mid, &st, &err), 0);
        assert_int_equal(splat_frame_validate(mid, &err), 0);
        assert_int_equal(st.fused + st.kept_t, n); /* every Gaussian of t: fused or kept */
        assert_int_equal(st.dropped_tm1 + st.kept_tm1, n);
        assert_int_equal(mid->count, st.fused + st.kept_t + st.kept_tm1);
    }
    assert_true(worst < 1e-4);
    f4d_sequence_close(sq);
    fk_ctx_free(ctx);
}

/* f4d_sequence_set_fusion: 0 gives exactly interp_at with averaging on the
 * same keys, 1 gives the MLP's frame again (bit for bit); where pairs are
 * fused, the fixture's MLP (not averaging) changes the frame. */
static void fusion_switch(void **state)
{
    (void)state;
    char p[1024];
    snprintf(p, sizeof p, "%s/tiny_f4d_seq_f32.gguf", gguf_dir);
    fk_ctx *ctx;
    f4d_sequence *sq;
    struct f4d_err err = { 0 };
    const int S = 2, H = 28, W = 42;
    const size_t n = (size_t)S * H * W;
    assert_int_equal(fk_ctx_new(&(struct fk_ctx_config){ .isa = FK_ISA_AUTO, .threads = 1 }, &ctx), 0);
    if (f4d_sequence_open(ctx, p, FK_W_F32, S, H, W, &sq, &err) < 0)
        fail_msg("open: %s", err.msg);
    const struct splat_frame *mid;
    struct interp_stats st = { 0 }, sa;
    double tm = 0; /* the first mid time with pairs to fuse */
    for (int t = 0; t < 4 && !st.fused; t++) {
        char name[64];
        snprintf(name, sizeof name, "t%d/input", t);
        float *x = load_seq(name, n * 3);
        assert_int_equal(f4d_sequence_push(sq, x, &err), 0);
        free(x);
        tm = t - 0.5;
        if (t)
            assert_int_equal(f4d_sequence_at(sq, tm, &mid, &st, &err), 0);
    }
    /* the random fixture's motions rarely land within tau of a partner: with
     * no pair the MLP and averaging agree trivially, and only the plumbing
     * (same keys, same frame as interp_at) is checked */
    printf("t' = %.1f: %zu pairs fused\n", tm, st.fused);
    size_t cnt = mid->count;
    float *mlp = malloc(3 * cnt * sizeof *mlp);
    memcpy(mlp, mid->pos, 3 * cnt * sizeof *mlp);
    assert_int_equal(f4d_sequence_set_fusion(sq, 0, &err), 0);
    assert_int_equal(f4d_sequence_at(sq, tm, &mid, &sa, &err), 0);
    assert_int_equal(sa.fused, st.fused);
    assert_int_equal(mid->count, cnt);
    /* averaging on the same keys through interp itself */
    struct f4d_seq_key kt, kp;
    assert_int_equal(f4d_sequence_key(sq, 0, &kt, &err), 0);
    assert_int_equal(f4d_sequence_key(sq, 1, &kp, &err), 0);
    interp *ip;
    struct interp_key k0 = { 0 }, k1 = { 0 };
    struct splat_frame avg = { 0 };
    struct interp_config ca = interp_config_default();
    assert_int_equal(interp_new(ctx, &kp.rig, &ip, &err), 0);
    assert_int_equal(interp_key_build_aligned(ip, &kp.frame, &k0, &err), 0);
    assert_int_equal(interp_set_rig(ip, &kt.rig, &err), 0);
    assert_int_equal(interp_key_build_aligned(ip, &kt.frame, &k1, &err), 0);
    assert_int_equal(interp_at(ip, &k0, &k1, (float)(tm - (double)kp.t), &ca, &avg, NULL, &err), 0);
    assert_int_equal(avg.count, cnt);
    assert_memory_equal(avg.pos, mid->pos, 3 * cnt * sizeof(float));
    assert_memory_equal(avg.rgb, mid->rgb, 3 * cnt * sizeof(float));
    if (st.fused)
        assert_true(memcmp(mlp, mid->pos, 3 * cnt * sizeof(float)) != 0); /* the MLP is not averaging */
    assert_int_equal(f4d_sequence_set_fusion(sq, 1, &err), 0);
    assert_int_equal(f4d_sequence_at(sq, tm, &mid, NULL, &err), 0);
    assert_memory_equal(mlp, mid->pos, 3 * cnt * sizeof(float));
    assert_int_equal(f4d_sequence_set_fusion(NULL, 0, &err), F4D_EINVAL);
    free(mlp);
    interp_key_free(&k0);
    interp_key_free(&k1);
    splat_frame_free(&avg);
    interp_free(ip);
    f4d_sequence_close(sq);
    fk_ctx_free(ctx);
}

/* The sequence's batched F_theta (fk GEMMs) against the model's per-pair
 * one and the reference's outputs, on the fixture's 64 fusion pairs. */
static void fusion_batch_parity(void **state)
{
    (void)state;
    char p[1024];
    snprintf(p, sizeof p, "%s/tiny_f4d_seq_f32.gguf", gguf_dir);
    fk_ctx *ctx;
    f4d_sequence *sq;
    struct f4d_err err = { 0 };
    assert_int_equal(fk_ctx_new(&(struct fk_ctx_config){ .isa = FK_ISA_AUTO, .threads = 2 }, &ctx), 0);
    if (f4d_sequence_open(ctx, p, FK_W_F32, 2, 28, 42, &sq, &err) < 0)
        fail_msg("open: %s", err.msg);
    float *in = load_seq("fusion_in", 64 * 30), *ref = load_seq("fusion_out", 64 * 14), out[64 * 14], one[14];
    assert_int_equal(f4d_sequence_fuse_batch(sq, in, 64, out), 0);
    double e_model = 0, e_ref = 0, rms = 0;
    for (int i = 0; i < 64; i++) {
        const float *x = in + 30 * i;
        model_fusion_fuse(model_fusion(f4d_sequence_model(sq)), x, x + 14, x[28], x[29], one);
        for (int c = 0; c < 14; c++) {
            e_model = fmax(e_model, fabs((double)out[14 * i + c] - one[c]));
            e_ref = fmax(e_ref, fabs((double)out[14 * i + c] - ref[14 * i + c]));
            rms += (double)ref[14 * i + c] * ref[14 * i + c];
        }
    }
    rms = sqrt(rms / (64 * 14));
    printf("batched fusion, 64 pairs: max |diff| vs per pair %.2e, vs reference %.2e (RMS %.3g)\n", e_model, e_ref, rms);
    assert_true(e_model <= 1e-5 * rms && e_ref <= 1e-4 * rms);
    assert_int_equal(f4d_sequence_fuse_batch(sq, in, INTERP_FUSE_BATCH + 1, out), F4D_EINVAL);
    free(in);
    free(ref);
    f4d_sequence_close(sq);
    fk_ctx_free(ctx);
}

/* fusion.fc2 = 0: the MLP's output is the mean (q normalised), i.e. averaging. */
static void fusion_fc2_zero_is_average(void **state)
{
    (void)state;
    char p[1024];
    snprintf(p, sizeof p, "%s/tiny_f4d_seq_f32.gguf", gguf_dir);
    FILE *fp = fopen(p, "rb");
    if (!fp)
        fail_msg("%s is absent (model/convert_tiny_f4d_seq_f32 makes it)", p);
    fseek(fp, 0, SEEK_END);
    size_t sz = (size_t)ftell(fp);
    fseek(fp, 0, SEEK_SET);
    void *buf = aligned_alloc(GGUF_MAX_ALIGN, (sz + GGUF_MAX_ALIGN - 1) / GGUF_MAX_ALIGN * GGUF_MAX_ALIGN);
    assert_int_equal(fread(buf, 1, sz, fp), sz);
    fclose(fp);
    gguf_file *gf;
    struct f4d_err err = { 0 };
    /* find fc2 in our copy of the file, zero it there, open the edited bytes */
    size_t off[2], len[2];
    assert_int_equal(gguf_open_memory(buf, sz, &gf, &err), 0);
    for (int k = 0; k < 2; k++) {
        const struct gguf_tensor *t = gguf_find_tensor(gf, k ? "fusion.fc2.bias" : "fusion.fc2.weight");
        assert_non_null(t);
        off[k] = (size_t)((const char *)t->data - (const char *)buf);
        len[k] = t->nbytes;
    }
    gguf_close(gf);
    for (int k = 0; k < 2; k++)
        memset((char *)buf + off[k], 0, len[k]);
    assert_int_equal(gguf_open_memory(buf, sz, &gf, &err), 0);
    fk_ctx *ctx;
    struct model *m;
    assert_int_equal(fk_ctx_new(&(struct fk_ctx_config){ .isa = FK_ISA_AUTO, .threads = 1 }, &ctx), 0);
    if (model_init_gguf(ctx, gf, FK_W_F32, &m, &err) < 0)
        fail_msg("init: %s", err.msg);
    void *fu = model_fusion(m);
    assert_non_null(fu);
    /* pair by pair, on the reference's fusion inputs (nonzero fc1) */
    float *in = load_seq("fusion_in", 0);
    double e = 0;
    for (int i = 0; i < 64; i++) {
        const float *x = in + 30 * i;
        float o1[14], o2[14];
        model_fusion_fuse(fu, x, x + 14, x[28], x[29], o1);
        interp_fuse_average(NULL, x, x + 14, x[28], x[29], o2);
        float n2 = sqrtf(o2[10] * o2[10] + o2[11] * o2[11] + o2[12] * o2[12] + o2[13] * o2[13]);
        for (int c = 10; c < 14; c++) /* averaging leaves q unnormalised (interp normalises after) */
            o2[c] = n2 > 1e-12f ? o2[c] / n2 : (c == 10);
        for (int c = 0; c < 14; c++) {
            double d = fabs((double)o1[c] - o2[c]);
            e = d > e ? d : e;
        }
    }
    free(in);
    printf("fc2 = 0: MLP vs averaging, 64 reference pairs: max |diff| %.2e\n", e);
    assert_true(e < 1e-6);
    /* through the sequence: the fused frame equals the averaged one */
    f4d_sequence *sq;
    const int S = 2, H = 28, W = 42;
    const size_t n = (size_t)S * H * W;
    assert_int_equal(f4d_sequence_open_model(m, S, H, W, &sq, &err), 0);
    assert_true(f4d_sequence_has_fusion(sq));
    for (int t = 0; t < 2; t++) {
        char name[64];
        snprintf(name, sizeof name, "t%d/input", t);
        float *x = load_seq(name, n * 3);
        assert_int_equal(f4d_sequence_push(sq, x, &err), 0);
        free(x);
    }
    struct f4d_seq_key kt, kp;
    assert_int_equal(f4d_sequence_key(sq, 0, &kt, &err), 0);
    assert_int_equal(f4d_sequence_key(sq, 1, &kp, &err), 0);
    const struct splat_frame *mlp;
    struct interp_stats st;
    assert_int_equal(f4d_sequence_at(sq, 0.4, &mlp, &st, &err), 0);
    interp *ip;
    struct interp_key k0 = { 0 }, k1 = { 0 };
    struct splat_frame avg = { 0 }, fus = { 0 };
    assert_int_equal(interp_new(ctx, &kp.rig, &ip, &err), 0);
    assert_int_equal(interp_key_build_aligned(ip, &kp.frame, &k0, &err), 0);
    assert_int_equal(interp_set_rig(ip, &kt.rig, &err), 0);
    assert_int_equal(interp_key_build_aligned(ip, &kt.frame, &k1, &err), 0);
    /* the sequence hands interp the model's MLP: the same frame as interp_at with it */
    struct interp_config cm = interp_config_default(), ca = interp_config_default();
    cm.fuse = model_fusion_fuse;
    cm.fuse_user = fu;
    struct interp_stats sa;
    assert_int_equal(interp_at(ip, &k0, &k1, 0.4f, &cm, &fus, &sa, &err), 0);
    assert_int_equal(fus.count, mlp->count);
    assert_true(max_rel(fus.pos, mlp->pos, 3 * fus.count) < 1e-5); /* batched vs per pair */
    /* The random tiny model's motions match no pixel within 5 cm: with tau
     * raised every Gaussian of t with a partner is fused, by the MLP and by
     * averaging (where the partner pixel exists). */
    cm.tau = ca.tau = 1e9f;
    assert_int_equal(interp_at(ip, &k0, &k1, 0.4f, &cm, &fus, &st, &err), 0);
    assert_int_equal(interp_at(ip, &k0, &k1, 0.4f, &ca, &avg, &sa, &err), 0);
    printf("tau 1e9: fused %zu, kept %zu + %zu of %zu + %zu\n", st.fused, st.kept_t, st.kept_tm1, n, n);
    assert_true(st.fused >= 100); /* 499 here: the others land outside or behind */
    assert_int_equal(sa.fused, st.fused);
    assert_int_equal(avg.count, fus.count);
    double ef = max_rel(fus.pos, avg.pos, 3 * avg.count);
    ef = fmax(ef, max_rel(fus.scale, avg.scale, 3 * avg.count));
    ef = fmax(ef, max_rel(fus.rot, avg.rot, 4 * avg.count));
    ef = fmax(ef, max_rel(fus.opacity, avg.opacity, avg.count));
    ef = fmax(ef, max_rel(fus.rgb, avg.rgb, 3 * avg.count));
    printf("fc2 = 0: fused frame vs averaged frame: max rel %.2e\n", ef);
    assert_true(ef < 1e-5);
    /* the same through interp's batched fusion (what at() runs) */
    struct interp_config cb = cm;
    cb.fuse = NULL;
    cb.fuse_batch = f4d_sequence_fuse_batch;
    cb.fuse_batch_user = sq;
    assert_int_equal(interp_at(ip, &k0, &k1, 0.4f, &cb, &fus, &sa, &err), 0);
    assert_int_equal(sa.fused, st.fused);
    assert_int_equal(fus.count, avg.count);
    ef = max_rel(fus.pos, avg.pos, 3 * avg.count);
    ef = fmax(ef, max_rel(fus.scale, avg.scale, 3 * avg.count));
    ef = fmax(ef, max_rel(fus.rot, avg.rot, 4 * avg.count));
    ef = fmax(ef, max_rel(fus.opacity, avg.opacity, avg.count));
    printf("fc2 = 0, batched: fused frame vs averaged frame: max rel %.2e\n", ef);
    assert_true(ef < 1e-5);
    interp_key_free(&k0);
    interp_key_free(&k1);
    splat_frame_free(&avg);
    splat_frame_free(&fus);
    interp_free(ip);
    f4d_sequence_close(sq);
    model_free(m);
    gguf_close(gf);
    free(buf);
    fk_ctx_free(ctx);
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
        cmocka_unit_test(motion_parity),
        cmocka_unit_test(fusion_fc2_zero_is_average),
        cmocka_unit_test(fusion_batch_parity),
        cmocka_unit_test(fusion_switch),
    };
    return F4D_TEST_MAIN(argc, argv, "sequence", tests, setup, teardown);
}
