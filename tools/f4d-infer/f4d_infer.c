/* f4d-infer - run the VGGT model on images and write its outputs as .npy.
 *
 *   f4d-infer [--weights W.gguf] (--images A.png B.png ... | --raw-input X.npy)
 *             [--precision f32|f16|int8] [--mode crop|pad] [--size 518]
 *             [--threads N] --out DIR
 *
 * PNG frames (8-bit or 16-bit, grey, RGB or RGBA: RGBA is composited over
 * white as VGGT's loader does) are preprocessed by firmware/preprocess
 * (vggt.md 1a) to --size (518 for VGGT); --raw-input takes f32 [S,3,H,W] in
 * [0,1] as is. DIR receives pose_enc [S,9], extrinsic [S,3,4], intrinsic
 * [S,3,3], depth [S,H,W,1], depth_conf [S,H,W], world_points [S,H,W,3],
 * world_points_conf [S,H,W] (the heads present in the file), and input.npy,
 * the preprocessed model input. Without --weights the shipped model is used
 * (firmware/infer/weights: $F4D_WEIGHTS, the installed copy, the source tree;
 * the int8 file for --precision int8).
 *
 * Forge4D streaming (firmware/gaussians/sequence), one synchronized set per
 * key time t = 0, 1, 2, ...:
 *
 *   f4d-infer --forge4d --weights W.gguf
 *             (--set A0.png B0.png ... [--set A1.png B1.png ...]...
 *              | --raw-input X0.npy [--raw-input X1.npy]...)  [--at T]...
 *             [--precision ...] [--mode ...] [--size ...] [--threads N] --out DIR
 *
 * Each --set lists one image per view (same views and sizes every time); a
 * --raw-input is one set [S,3,H,W] or a whole take [T,S,3,H,W]. DIR/tNNNN/
 * receives key t's metric Gaussians gaussians.ply (INRIA layout, one per input
 * pixel), motion_bwd.npy (M1[t], [S,H,W,3], from t = 1) and motion_fwd.npy
 * (M2[t], from the next key on; both need weights with the motion part),
 * cameras.json (the splat rig: metric world-to-camera and pinhole per view),
 * extrinsic.npy [S,3,4], intrinsic.npy [S,3,3] and gauge.npy [1]. Every --at T
 * (key-time units, 0 <= T <= last key) writes DIR/at_T/gaussians.ply, the
 * Gaussians interpolated at T between the two keys around it (the fusion MLP
 * of the weights, averaging without one, the nearest key without motion).
 */
#include <errno.h>
#include <png.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <time.h>

#include "f4d_sequence.h"
#include "fk_ctx.h"
#include "model.h"
#include "npy.h"
#include "preprocess.h"
#include "weights.h"

static double now(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

static void usage(void)
{
    fprintf(stderr, "usage: f4d-infer [--weights W.gguf] (--images A.png ... | --raw-input X.npy)\n"
                    "                 [--precision f32|f16|int8] [--mode crop|pad] [--size 518]\n"
                    "                 [--threads N] --out DIR\n"
                    "       f4d-infer --forge4d --weights W.gguf (--set A.png ... [--set ...]...\n"
                    "                 | --raw-input X.npy [--raw-input ...]...) [--at T]...\n"
                    "                 [--precision ...] [--mode ...] [--size ...] [--threads N] --out DIR\n");
}

/* Loads a PNG as RGB8 (RGBA composited over white). Caller frees. */
static uint8_t *load_png(const char *path, int *w, int *h)
{
    png_image im;
    memset(&im, 0, sizeof im);
    im.version = PNG_IMAGE_VERSION;
    if (!png_image_begin_read_from_file(&im, path)) {
        fprintf(stderr, "f4d-infer: cannot read PNG '%s': %s\n", path, im.message);
        return NULL;
    }
    im.format = PNG_FORMAT_RGBA;
    size_t n = PNG_IMAGE_SIZE(im);
    uint8_t *rgba = malloc(n), *rgb = malloc((size_t)im.width * im.height * 3);
    if (!rgba || !rgb || !png_image_finish_read(&im, NULL, rgba, 0, NULL)) {
        fprintf(stderr, "f4d-infer: cannot decode PNG '%s': %s\n", path, im.message);
        png_image_free(&im);
        free(rgba);
        free(rgb);
        return NULL;
    }
    for (size_t i = 0; i < (size_t)im.width * im.height; i++) {
        unsigned a = rgba[4 * i + 3];
        for (int c = 0; c < 3; c++)
            rgb[3 * i + c] = (uint8_t)((rgba[4 * i + c] * a + 255u * (255u - a) + 127u) / 255u);
    }
    free(rgba);
    *w = (int)im.width;
    *h = (int)im.height;
    return rgb;
}

static int save(const char *dir, const char *name, const float *data, const int64_t *shape,
                int nd)
{
    char path[4096];
    struct f4d_err err = {0};
    if (!data)
        return 0;
    snprintf(path, sizeof path, "%s/%s.npy", dir, name);
    if (npy_save_f32(path, data, shape, nd, &err) < 0) {
        fprintf(stderr, "f4d-infer: %s\n", err.msg);
        return -1;
    }
    return 0;
}

/* ---- --forge4d: a sequence of sets through firmware/gaussians/sequence ---- */

#define F4D_SEQ_INPUTS_MAX 4096
#define F4D_AT_MAX         64

struct seq_inputs {
    char **sets[F4D_SEQ_INPUTS_MAX]; /* --set: argv pointers, n_set[i] views each */
    int    n_set[F4D_SEQ_INPUTS_MAX];
    int    n_sets;
    const char *raws[F4D_SEQ_INPUTS_MAX];
    int    n_raws;
    double at[F4D_AT_MAX];
    int    n_at;
};

/* One set of PNGs through the preprocessing into input [S,3,target,target]
 * (the planned buffer); the size comes back in *H, *W. */
static int load_set(char **paths, int n, enum prep_mode mode, int target, float *input, int *H, int *W)
{
    struct prep_image ims[MODEL_VIEWS_MAX];
    uint8_t *px[MODEL_VIEWS_MAX] = { 0 };
    size_t sb = 0;
    int ok = 1;
    struct f4d_err err = { 0 };
    for (int i = 0; i < n && ok; i++) {
        int w, h;
        px[i] = load_png(paths[i], &w, &h);
        ok = px[i] != NULL;
        if (ok) {
            ims[i] = (struct prep_image){ px[i], w, h, (size_t)w * 3, PREP_PIXFMT_RGB8 };
            size_t need = prep_scratch_bytes(w, h, target);
            if (!need) {
                fprintf(stderr, "f4d-infer: '%s' (%dx%d) cannot be resized to %d\n", paths[i], w, h, target);
                ok = 0;
            }
            sb = need > sb ? need : sb;
        }
    }
    void *scratch = ok ? malloc(sb) : NULL;
    if (ok && (!scratch || prep_batch(ims, n, mode, target, scratch, sb, input, H, W, &err) < 0)) {
        fprintf(stderr, "f4d-infer: %s\n", scratch ? err.msg : "out of memory");
        ok = 0;
    }
    for (int i = 0; i < n; i++)
        free(px[i]);
    free(scratch);
    return ok ? 0 : -1;
}

static int write_key(const char *outdir, const struct f4d_seq_key *k, int S, int H, int W)
{
    char dir[2048], path[2200];
    struct f4d_err err = { 0 };
    snprintf(dir, sizeof dir, "%s/t%04ld", outdir, k->t);
    if (mkdir(dir, 0777) < 0 && errno != EEXIST) {
        fprintf(stderr, "f4d-infer: cannot create '%s': %s\n", dir, strerror(errno));
        return -1;
    }
    struct splat_frame plain = k->frame; /* the 17 INRIA properties only: motions go to .npy */
    plain.motion_bwd = plain.motion_fwd = NULL;
    snprintf(path, sizeof path, "%s/gaussians.ply", dir);
    if (splat_ply_write(path, &plain, &err) < 0)
        goto fail;
    snprintf(path, sizeof path, "%s/cameras.json", dir);
    if (splat_rig_save(path, &k->rig, &err) < 0)
        goto fail;
    const int64_t sm[4] = { S, H, W, 3 }, s34[3] = { S, 3, 4 }, s33[3] = { S, 3, 3 }, s1[1] = { 1 };
    if (save(dir, "extrinsic", k->extrinsic, s34, 3) < 0 || save(dir, "intrinsic", k->intrinsic, s33, 3) < 0 ||
        save(dir, "gauge", &k->gauge, s1, 1) < 0 || save(dir, "motion_bwd", k->frame.motion_bwd, sm, 4) < 0 ||
        save(dir, "motion_fwd", k->frame.motion_fwd, sm, 4) < 0)
        return -1;
    printf("  t=%ld: %zu Gaussians, gauge %.6g%s%s -> %s\n", k->t, k->frame.count, (double)k->gauge,
           k->frame.motion_bwd ? ", motion_bwd" : "", k->frame.motion_fwd ? ", motion_fwd" : "", dir);
    return 0;
fail:
    fprintf(stderr, "f4d-infer: %s\n", err.msg);
    return -1;
}

static int write_at(const char *outdir, f4d_sequence *sq, double t)
{
    char dir[2048], path[2200];
    struct f4d_err err = { 0 };
    const struct splat_frame *f;
    struct interp_stats st;
    if (f4d_sequence_at(sq, t, &f, &st, &err) < 0) {
        fprintf(stderr, "f4d-infer: --at %g: %s\n", t, err.msg);
        return -1;
    }
    snprintf(dir, sizeof dir, "%s/at_%.3f", outdir, t);
    if (mkdir(dir, 0777) < 0 && errno != EEXIST) {
        fprintf(stderr, "f4d-infer: cannot create '%s': %s\n", dir, strerror(errno));
        return -1;
    }
    snprintf(path, sizeof path, "%s/gaussians.ply", dir);
    if (splat_ply_write(path, f, &err) < 0) {
        fprintf(stderr, "f4d-infer: %s\n", err.msg);
        return -1;
    }
    static const char *mode[] = { "fused", "keep-both", "nearest key" };
    printf("  at %.3f (%s): %zu Gaussians (fused %zu, kept %zu + %zu, dropped %zu) -> %s\n", t,
           mode[f4d_sequence_mode(sq)], f->count, st.fused, st.kept_t, st.kept_tm1, st.dropped_tm1, path);
    return 0;
}

static int run_forge4d(const struct seq_inputs *in, const char *weights, enum fk_wtype wt, enum prep_mode mode,
                       int target, int threads, const char *outdir)
{
    struct f4d_err err = { 0 };
    fk_ctx *ctx = NULL;
    f4d_sequence *sq = NULL;
    float *take = NULL, *input = NULL;
    int rc = 1, S = 0, H = 0, W = 0;
    long T = 0, Tin = 0; /* key times, and those of the 5-D raw input */
    /* The set size, from the first input. */
    if (in->n_sets) {
        S = in->n_set[0];
        T = in->n_sets;
        input = malloc((size_t)S * 3 * target * target * sizeof *input);
        if (!input || load_set(in->sets[0], S, mode, target, input, &H, &W) < 0)
            goto done;
    } else {
        for (int r = 0; r < in->n_raws; r++) {
            int64_t sh[NPY_MAX_DIMS];
            int nd;
            free(take);
            take = NULL;
            if (npy_load_f32(in->raws[r], &take, sh, &nd, &err) < 0) {
                fprintf(stderr, "f4d-infer: %s\n", err.msg);
                goto done;
            }
            int o = nd == 5;
            if ((nd != 4 && nd != 5) || sh[o + 1] != 3 || sh[o] < 1 || sh[o] > MODEL_VIEWS_MAX ||
                (r && (sh[o] != S || sh[o + 2] != H || sh[o + 3] != W))) {
                fprintf(stderr, "f4d-infer: '%s' must be f32 [S,3,H,W] or [T,S,3,H,W] with 1..%d views%s\n",
                        in->raws[r], MODEL_VIEWS_MAX, r ? ", the size of the first input" : "");
                goto done;
            }
            S = (int)sh[o];
            H = (int)sh[o + 2];
            W = (int)sh[o + 3];
            T += o ? (long)sh[0] : 1;
        }
        free(take);
        take = NULL;
    }
    if (in->n_at && T < 2) {
        fprintf(stderr, "f4d-infer: --at needs at least two key times\n");
        goto done;
    }
    for (int i = 0; i < in->n_at; i++)
        if (!(in->at[i] >= 0 && in->at[i] <= (double)(T - 1))) {
            fprintf(stderr, "f4d-infer: --at %g is outside the key times 0..%ld\n", in->at[i], T - 1);
            goto done;
        }
    struct fk_ctx_config cc = { .isa = FK_ISA_AUTO, .threads = threads };
    if (fk_ctx_new(&cc, &ctx) != F4D_OK) {
        fprintf(stderr, "f4d-infer: cannot create the kernel context\n");
        goto done;
    }
    double t0 = now();
    if (f4d_sequence_open(ctx, weights, wt, S, H, W, &sq, &err) < 0) {
        fprintf(stderr, "f4d-infer: %s\n", err.msg);
        goto done;
    }
    printf("f4d-infer --forge4d: %ld key times of %d views %dx%d, open %.2f s; motion %s, fusion %s\n", T, S, W, H,
           now() - t0, f4d_sequence_has_motion(sq) ? "yes" : "no (interpolation: nearest key)",
           f4d_sequence_has_fusion(sq) ? "MLP" : "averaging");
    int raw_i = 0;
    long raw_t = 0;
    double t_eval = 0;
    for (long t = 0; t < T; t++) {
        const float *x;
        if (in->n_sets) {
            int h2, w2;
            if (in->n_set[t] != S) {
                fprintf(stderr, "f4d-infer: --set %ld has %d images, the first has %d\n", t, in->n_set[t], S);
                goto done;
            }
            if (t && (load_set(in->sets[t], S, mode, target, input, &h2, &w2) < 0 || h2 != H || w2 != W)) {
                fprintf(stderr, "f4d-infer: --set %ld does not give %dx%d like the first set\n", t, W, H);
                goto done;
            }
            x = input;
        } else {
            if (!take || raw_t == Tin) { /* next raw file */
                int64_t sh[NPY_MAX_DIMS];
                int nd;
                free(take);
                take = NULL;
                if (npy_load_f32(in->raws[raw_i++], &take, sh, &nd, &err) < 0) {
                    fprintf(stderr, "f4d-infer: %s\n", err.msg);
                    goto done;
                }
                Tin = nd == 5 ? (long)sh[0] : 1;
                raw_t = 0;
            }
            x = take + (size_t)raw_t++ * S * 3 * H * W;
        }
        double te = now();
        if (f4d_sequence_push(sq, x, &err) < 0) {
            fprintf(stderr, "f4d-infer: key %ld: %s\n", t, err.msg);
            goto done;
        }
        t_eval += now() - te;
        struct f4d_seq_key k;
        /* key t-1 is complete now (its forward motion came with key t) */
        if (t && (f4d_sequence_key(sq, 1, &k, &err) < 0 || write_key(outdir, &k, S, H, W) < 0))
            goto done;
        /* T in [t-1, t] once key t is in (a key time between two intervals
         * is written with the earlier one) */
        for (int i = 0; i < in->n_at; i++)
            if (t && in->at[i] >= (double)(t - 1) && in->at[i] <= (double)t &&
                !(in->at[i] == (double)(t - 1) && t > 1) && write_at(outdir, sq, in->at[i]) < 0)
                goto done;
    }
    struct f4d_seq_key k;
    if (f4d_sequence_key(sq, 0, &k, &err) < 0 || write_key(outdir, &k, S, H, W) < 0)
        goto done;
    printf("f4d-infer --forge4d: %.3f s per key time (model + copy + lookup)\n", t_eval / (double)T);
    rc = 0;
done:
    f4d_sequence_close(sq);
    fk_ctx_free(ctx);
    free(take);
    free(input);
    return rc;
}

int main(int argc, char **argv)
{
    const char *weights = NULL, *raw = NULL, *outdir = NULL, *prec = "f32", *mode_s = "crop";
    const char *images[MODEL_VIEWS_MAX];
    int n_img = 0, target = 518, threads = 0, forge4d = 0;
    static struct seq_inputs seq; /* large: off the stack */
    for (int i = 1; i < argc; i++) {
        const char *a = argv[i];
        if (!strcmp(a, "--weights") && i + 1 < argc)
            weights = argv[++i];
        else if (!strcmp(a, "--raw-input") && i + 1 < argc) {
            raw = argv[++i];
            if (seq.n_raws == F4D_SEQ_INPUTS_MAX) {
                fprintf(stderr, "f4d-infer: at most %d --raw-input\n", F4D_SEQ_INPUTS_MAX);
                return 2;
            }
            seq.raws[seq.n_raws++] = raw;
        } else if (!strcmp(a, "--forge4d"))
            forge4d = 1;
        else if (!strcmp(a, "--at") && i + 1 < argc) {
            char *end;
            double t = strtod(argv[++i], &end);
            if (end == argv[i] || *end || seq.n_at == F4D_AT_MAX) {
                fprintf(stderr, "f4d-infer: --at takes a time in key units (at most %d of them), not '%s'\n",
                        F4D_AT_MAX, argv[i]);
                return 2;
            }
            seq.at[seq.n_at++] = t;
        } else if (!strcmp(a, "--set")) {
            if (seq.n_sets == F4D_SEQ_INPUTS_MAX) {
                fprintf(stderr, "f4d-infer: at most %d --set\n", F4D_SEQ_INPUTS_MAX);
                return 2;
            }
            seq.sets[seq.n_sets] = argv + i + 1;
            int n = 0;
            while (i + 1 < argc && argv[i + 1][0] != '-') {
                if (n == MODEL_VIEWS_MAX) {
                    fprintf(stderr, "f4d-infer: at most %d images per --set\n", MODEL_VIEWS_MAX);
                    return 2;
                }
                n++;
                i++;
            }
            if (!n) {
                fprintf(stderr, "f4d-infer: --set needs one image per view\n");
                return 2;
            }
            seq.n_set[seq.n_sets++] = n;
        }
        else if (!strcmp(a, "--out") && i + 1 < argc)
            outdir = argv[++i];
        else if (!strcmp(a, "--precision") && i + 1 < argc)
            prec = argv[++i];
        else if (!strcmp(a, "--mode") && i + 1 < argc)
            mode_s = argv[++i];
        else if (!strcmp(a, "--size") && i + 1 < argc)
            target = atoi(argv[++i]);
        else if (!strcmp(a, "--threads") && i + 1 < argc)
            threads = atoi(argv[++i]);
        else if (!strcmp(a, "--images")) {
            while (i + 1 < argc && argv[i + 1][0] != '-') {
                if (n_img == MODEL_VIEWS_MAX) {
                    fprintf(stderr, "f4d-infer: at most %d images\n", MODEL_VIEWS_MAX);
                    return 2;
                }
                images[n_img++] = argv[++i];
            }
        } else if (!strcmp(a, "-h") || !strcmp(a, "--help")) {
            usage();
            return 0;
        } else {
            fprintf(stderr, "f4d-infer: unknown or incomplete option '%s'\n", a);
            usage();
            return 2;
        }
    }
    if (forge4d ? (!outdir || n_img || (!seq.n_raws && !seq.n_sets) || (seq.n_raws && seq.n_sets))
                : (!outdir || (!raw && !n_img) || (raw && n_img) || seq.n_raws > 1 || seq.n_sets ||
                   seq.n_at)) {
        if (!forge4d && (seq.n_sets || seq.n_at || seq.n_raws > 1))
            fprintf(stderr, "f4d-infer: --set, --at and repeated --raw-input need --forge4d\n");
        usage();
        return 2;
    }
    enum fk_wtype wt;
    if (!strcmp(prec, "f32"))
        wt = FK_W_F32;
    else if (!strcmp(prec, "f16"))
        wt = FK_W_F16;
    else if (!strcmp(prec, "int8"))
        wt = FK_W_Q8;
    else {
        fprintf(stderr, "f4d-infer: --precision must be f32, f16 or int8 (got '%s')\n", prec);
        return 2;
    }
    char wpath[F4D_WEIGHTS_PATH_MAX];
    if (!weights) {
        struct f4d_err werr = { 0 };
        if (f4d_weights_default(wt == FK_W_Q8, wpath, sizeof wpath, &werr) < 0) {
            fprintf(stderr, "f4d-infer: no --weights and %s\n", werr.msg);
            return 1;
        }
        weights = wpath;
    }
    enum prep_mode mode;
    if (!strcmp(mode_s, "crop"))
        mode = PREP_CROP;
    else if (!strcmp(mode_s, "pad"))
        mode = PREP_PAD;
    else {
        fprintf(stderr, "f4d-infer: --mode must be crop or pad (got '%s')\n", mode_s);
        return 2;
    }
    if (target < 14 || target % 14) {
        fprintf(stderr, "f4d-infer: --size %d is not a positive multiple of 14\n", target);
        return 2;
    }
    if (mkdir(outdir, 0777) < 0 && errno != EEXIST) {
        fprintf(stderr, "f4d-infer: cannot create '%s': %s\n", outdir, strerror(errno));
        return 1;
    }
    if (forge4d)
        return run_forge4d(&seq, weights, wt, mode, target, threads, outdir);

    int rc = 1, S = 0, H = 0, W = 0;
    float *input = NULL;
    struct f4d_err err = {0};
    if (raw) {
        int64_t sh[NPY_MAX_DIMS];
        int nd;
        if (npy_load_f32(raw, &input, sh, &nd, &err) < 0) {
            fprintf(stderr, "f4d-infer: %s\n", err.msg);
            return 1;
        }
        if (nd != 4 || sh[1] != 3 || sh[0] < 1 || sh[0] > MODEL_VIEWS_MAX) {
            fprintf(stderr, "f4d-infer: '%s' must be f32 [S,3,H,W] with 1..%d views\n", raw,
                    MODEL_VIEWS_MAX);
            free(input);
            return 1;
        }
        S = (int)sh[0];
        H = (int)sh[2];
        W = (int)sh[3];
    } else {
        struct prep_image ims[MODEL_VIEWS_MAX];
        uint8_t *px[MODEL_VIEWS_MAX] = { 0 };
        size_t sb = 0;
        int ok = 1;
        for (int i = 0; i < n_img && ok; i++) {
            int w, h;
            px[i] = load_png(images[i], &w, &h);
            ok = px[i] != NULL;
            if (ok) {
                ims[i] = (struct prep_image){ px[i], w, h, (size_t)w * 3, PREP_PIXFMT_RGB8 };
                size_t need = prep_scratch_bytes(w, h, target);
                if (!need) {
                    fprintf(stderr, "f4d-infer: '%s' (%dx%d) cannot be resized to %d\n",
                            images[i], w, h, target);
                    ok = 0;
                }
                sb = need > sb ? need : sb;
            }
        }
        void *scratch = ok ? malloc(sb) : NULL;
        input = ok ? malloc((size_t)n_img * 3 * target * target * sizeof *input) : NULL;
        if (ok && (!scratch || !input ||
                   prep_batch(ims, n_img, mode, target, scratch, sb, input, &H, &W, &err) < 0)) {
            fprintf(stderr, "f4d-infer: %s\n", err.msg);
            ok = 0;
        }
        for (int i = 0; i < n_img; i++)
            free(px[i]);
        free(scratch);
        if (!ok) {
            free(input);
            return 1;
        }
        S = n_img;
    }

    fk_ctx *ctx = NULL;
    struct model *m = NULL;
    struct fk_ctx_config cc = { .isa = FK_ISA_AUTO, .threads = threads };
    if (fk_ctx_new(&cc, &ctx) != F4D_OK) {
        fprintf(stderr, "f4d-infer: cannot create the kernel context\n");
        goto done;
    }
    double t0 = now();
    if (model_init(ctx, weights, wt, &m, &err) < 0) {
        fprintf(stderr, "f4d-infer: %s\n", err.msg);
        goto done;
    }
    if (model_prepare(m, S, H, W) < 0) {
        fprintf(stderr, "f4d-infer: %s\n", model_error(m));
        goto done;
    }
    double t1 = now();
    struct model_outputs o;
    if (model_eval(m, input, S, H, W, &o) < 0) {
        fprintf(stderr, "f4d-infer: %s\n", model_error(m));
        goto done;
    }
    double t2 = now();
    printf("f4d-infer: %d views %dx%d, %s weights (%zu bytes packed), arena %zu bytes, "
           "load %.2f s, forward %.3f s\n", S, W, H, prec, model_weight_bytes(m),
           model_arena_bytes(m), t1 - t0, t2 - t1);
    struct model_stage st[16];
    int ns = model_stages(m, st, 16);
    for (int i = 0; i < ns; i++)
        printf("  %-14s %9.3f ms %8.2f GFLOP/s\n", st[i].name, 1e3 * st[i].seconds,
               st[i].seconds > 0 ? st[i].flops / st[i].seconds * 1e-9 : 0.0);
    const int64_t s_in[4] = { S, 3, H, W }, s9[2] = { S, 9 }, s34[3] = { S, 3, 4 },
                  s33[3] = { S, 3, 3 }, sd[4] = { S, H, W, 1 }, sc[3] = { S, H, W },
                  sp[4] = { S, H, W, 3 };
    if (save(outdir, "input", input, s_in, 4) < 0 || save(outdir, "pose_enc", o.pose_enc, s9, 2) < 0 ||
        save(outdir, "extrinsic", o.extrinsic, s34, 3) < 0 ||
        save(outdir, "intrinsic", o.intrinsic, s33, 3) < 0 ||
        save(outdir, "depth", o.depth, sd, 4) < 0 ||
        save(outdir, "depth_conf", o.depth_conf, sc, 3) < 0 ||
        save(outdir, "world_points", o.world_points, sp, 4) < 0 ||
        save(outdir, "world_points_conf", o.world_points_conf, sc, 3) < 0)
        goto done;
    if (!o.pose_enc)
        printf("f4d-infer: no camera head in '%s': pose files not written\n", weights);
    if (!o.depth)
        printf("f4d-infer: no depth head in '%s': depth files not written\n", weights);
    if (!o.world_points)
        printf("f4d-infer: no point head in '%s': point files not written\n", weights);
    rc = 0;
done:
    model_free(m);
    fk_ctx_free(ctx);
    free(input);
    return rc;
}
