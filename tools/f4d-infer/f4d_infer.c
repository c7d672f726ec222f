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
 */
#include <errno.h>
#include <png.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <time.h>

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
                    "                 [--threads N] --out DIR\n");
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

int main(int argc, char **argv)
{
    const char *weights = NULL, *raw = NULL, *outdir = NULL, *prec = "f32", *mode_s = "crop";
    const char *images[MODEL_VIEWS_MAX];
    int n_img = 0, target = 518, threads = 0;
    for (int i = 1; i < argc; i++) {
        const char *a = argv[i];
        if (!strcmp(a, "--weights") && i + 1 < argc)
            weights = argv[++i];
        else if (!strcmp(a, "--raw-input") && i + 1 < argc)
            raw = argv[++i];
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
    if (!outdir || (!raw && !n_img) || (raw && n_img)) {
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
