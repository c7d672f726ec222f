/* f4d-eval - the paper's evaluation table from the C runtime (issue 11) on a
 * venue take (tools/f4d-scene venue, e.g. the test split of tools/train):
 *
 *   f4d-eval --take DIR [--weights W.gguf] [--precision f32|f16|int8|all]
 *            [--keys N] [--threads N] [--json FILE]
 *
 * For every key time of the take the model sees the input views only; its
 * metric Gaussians are rendered (firmware/splat) at the take's evaluation
 * cameras, which it never saw, expressed in view 0's frame (the model's world):
 *   novel_view_psnr / _ssim  against the exact renders (3DGS PSNR / SSIM);
 *   point_dist_m             mean distance of each input pixel's metric
 *                            Gaussian centre to the true surface point of the
 *                            same pixel (no alignment: the gauge's metric scale
 *                            and the cameras both count);
 *   rot_err_deg, trans_err_m predicted metric cameras against the truth;
 *   key_ms                   wall time of one model_eval (all views).
 * Novel time, motion end-point error and TL-STD need the motion blocks and the
 * fusion MLP in the runtime, which it does not have yet: printed as n/a, null
 * in JSON. LPIPS needs network weights this project cannot ship: absent.
 * Without --weights the shipped model is used (firmware/infer/weights). */
#include <cjson/cJSON.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "model.h"
#include "f4d_score.h"
#include "splat.h"
#include "weights.h"

struct row {
    const char *precision;
    double key_ms, psnr, ssim, point_dist, rot_err, trans_err;
};

static double now_ms(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return 1e3 * (double)ts.tv_sec + 1e-6 * (double)ts.tv_nsec;
}

static int eval_precision(const struct score_take *t, const char *weights, enum fk_wtype wt, int keys, int threads,
                          struct row *r, struct f4d_err *err)
{
    fk_ctx *ctx = NULL;
    struct model *m = NULL;
    score_view *sv = NULL;
    int rc = -1;
    const int V = t->V, H = t->H, W = t->W;
    float *img = malloc((size_t)V * 3 * (size_t)H * W * sizeof(float));
    float *scratch = malloc(score_input_scratch_floats(t) * sizeof(float));
    struct fk_ctx_config cc = { .isa = FK_ISA_AUTO, .threads = threads };
    if (!img || !scratch) {
        f4d_fail(err, F4D_ENOMEM, "f4d-eval: out of memory");
        goto done;
    }
    if (fk_ctx_new(&cc, &ctx) != F4D_OK) {
        f4d_fail(err, F4D_ENOMEM, "f4d-eval: cannot create the kernel context");
        goto done;
    }
    if (model_init(ctx, weights, wt, &m, err) < 0)
        goto done;
    if (model_prepare(m, V, H, W) < 0) {
        f4d_fail(err, F4D_EINVAL, "%s", model_error(m));
        goto done;
    }
    if (score_view_new(ctx, t, &sv, err) < 0)
        goto done;
    double ms = 0, psnr = 0, ssim = 0, pd = 0, re = 0, te = 0;
    int n_img = 0, n_cam = 0;
    size_t n_pt = 0;
    if (keys <= 0 || keys > t->T)
        keys = t->T;
    for (int k = 0; k < keys; k++) {
        if (score_take_input(ctx, t, k, H, W, scratch, img, err) < 0)
            goto done;
        struct model_outputs o;
        double t0 = now_ms();
        if (model_eval(m, img, V, H, W, &o) < 0) {
            f4d_fail(err, F4D_EINVAL, "%s", model_error(m));
            goto done;
        }
        ms += now_ms() - t0;
        if (!o.gaussians.count || !o.extrinsic_metric) {
            f4d_fail(err, F4D_ENOTSUP, "f4d-eval: %s has no Gaussian / scale / camera heads", weights);
            goto done;
        }
        const struct model_gaussians *g = &o.gaussians;
        struct splat_frame fr = { .count = g->count, .capacity = g->count, .pos = g->pos, .scale = g->scale,
                                  .rot = g->rot, .opacity = g->opacity, .rgb = g->rgb };
        double p, s, sum, rs, ts;
        size_t n;
        if (score_novel_view(sv, &fr, k, &p, &s, err) < 0 || score_points(t, k, g->pos, H, W, &sum, &n, err) < 0)
            goto done;
        psnr += p * t->E;
        ssim += s * t->E;
        n_img += t->E;
        pd += sum;
        n_pt += n;
        score_cameras(t, o.extrinsic_metric, &rs, &ts);
        re += rs;
        te += ts;
        n_cam += V;
    }
    r->key_ms = ms / keys;
    r->psnr = n_img ? psnr / n_img : NAN;
    r->ssim = n_img ? ssim / n_img : NAN;
    r->point_dist = n_pt ? pd / (double)n_pt : NAN;
    r->rot_err = re / n_cam;
    r->trans_err = te / n_cam;
    rc = 0;
done:
    free(img);
    free(scratch);
    score_view_free(sv);
    model_free(m);
    fk_ctx_free(ctx);
    return rc;
}

static void json_num(FILE *f, const char *k, double v, int last)
{
    if (isfinite(v))
        fprintf(f, "\"%s\": %.6g%s", k, v, last ? "" : ", ");
    else
        fprintf(f, "\"%s\": null%s", k, last ? "" : ", ");
}

int main(int argc, char **argv)
{
    const char *take_dir = NULL, *weights = NULL, *prec = "f32", *json = NULL;
    int keys = 0, threads = 0;
    for (int i = 1; i < argc; i++) {
        const char *a = argv[i];
        if (!strcmp(a, "-h") || !strcmp(a, "--help")) {
            printf("usage: f4d-eval --take DIR [--weights W.gguf] [--precision f32|f16|int8|all] [--keys N]\n"
                   "                [--threads N] [--json FILE]\n");
            return 0;
        }
        if (i + 1 >= argc) {
            fprintf(stderr, "f4d-eval: option '%s' needs a value (or is unknown)\n", a);
            return 2;
        }
        const char *v = argv[++i];
        if (!strcmp(a, "--take")) take_dir = v;
        else if (!strcmp(a, "--weights")) weights = v;
        else if (!strcmp(a, "--precision")) prec = v;
        else if (!strcmp(a, "--json")) json = v;
        else if (!strcmp(a, "--keys")) keys = atoi(v);
        else if (!strcmp(a, "--threads")) threads = atoi(v);
        else {
            fprintf(stderr, "f4d-eval: unknown option '%s'\n", a);
            return 2;
        }
    }
    if (!take_dir) {
        fprintf(stderr, "f4d-eval: --take DIR is required\n");
        return 2;
    }
    static const char *const names[3] = { "f32", "f16", "int8" };
    static const enum fk_wtype types[3] = { FK_W_F32, FK_W_F16, FK_W_Q8 };
    int want[3] = { 0, 0, 0 }, any = 0;
    for (int p = 0; p < 3; p++)
        any |= want[p] = !strcmp(prec, "all") || !strcmp(prec, names[p]);
    if (!any) {
        fprintf(stderr, "f4d-eval: --precision must be f32, f16, int8 or all (got '%s')\n", prec);
        return 2;
    }
    struct f4d_err err = { 0 };
    struct score_take t;
    if (score_take_load(take_dir, &t, &err) < 0) {
        fprintf(stderr, "f4d-eval: %s\n", err.msg);
        score_take_free(&t);
        return 1;
    }
    struct row rows[3];
    int nr = 0;
    for (int p = 0; p < 3; p++) {
        if (!want[p])
            continue;
        char wpath[F4D_WEIGHTS_PATH_MAX];
        const char *w = weights;
        if (!w) {
            if (f4d_weights_default(types[p] == FK_W_Q8, wpath, sizeof wpath, &err) < 0) {
                fprintf(stderr, "f4d-eval: no --weights and %s\n", err.msg);
                score_take_free(&t);
                return 1;
            }
            w = wpath;
        }
        rows[nr].precision = names[p];
        if (eval_precision(&t, w, types[p], keys, threads, &rows[nr], &err) < 0) {
            fprintf(stderr, "f4d-eval: %s: %s\n", names[p], err.msg);
            score_take_free(&t);
            return 1;
        }
        nr++;
    }
    printf("| precision | key ms | novel-view PSNR | novel-view SSIM | novel-time PSNR | novel-time SSIM | "
           "motion EPE (m) | point dist (m) | rot err (deg) | trans err (m) | TL-STD fused | TL-STD unfused |\n");
    printf("|---|---|---|---|---|---|---|---|---|---|---|---|\n");
    for (int i = 0; i < nr; i++)
        printf("| %s | %.1f | %.2f | %.4f | n/a | n/a | n/a | %.4f | %.2f | %.4f | n/a | n/a |\n", rows[i].precision,
               rows[i].key_ms, rows[i].psnr, rows[i].ssim, rows[i].point_dist, rows[i].rot_err, rows[i].trans_err);
    printf("| paper (518^2, H200) | 176.5 | 29.82 | 0.9606 | 29.04 | 0.9566 | 0.00953 | 0.0264 | - | - | 0.5379 | 0.9446 |\n");
    printf("\n%d keys, %d input views, %d evaluation views, %dx%d. n/a: needs the motion blocks / fusion in the "
           "runtime; LPIPS is not computed (no network weights).\n", keys > 0 && keys < t.T ? keys : t.T, t.V, t.E,
           t.W, t.H);
    int rc = 0;
    if (json) {
        FILE *f = fopen(json, "w");
        if (!f) {
            fprintf(stderr, "f4d-eval: cannot create '%s'\n", json);
            rc = 1;
        } else {
            fprintf(f, "{\"rows\": [");
            for (int i = 0; i < nr; i++) {
                fprintf(f, "%s{\"precision\": \"%s\", ", i ? ", " : "", rows[i].precision);
                json_num(f, "key_ms", rows[i].key_ms, 0);
                json_num(f, "novel_view_psnr", rows[i].psnr, 0);
                json_num(f, "novel_view_ssim", rows[i].ssim, 0);
                json_num(f, "novel_time_psnr", NAN, 0);
                json_num(f, "novel_time_ssim", NAN, 0);
                json_num(f, "motion_epe_m", NAN, 0);
                json_num(f, "point_dist_m", rows[i].point_dist, 0);
                json_num(f, "rot_err_deg", rows[i].rot_err, 0);
                json_num(f, "trans_err_m", rows[i].trans_err, 0);
                json_num(f, "tlstd_fused", NAN, 0);
                json_num(f, "tlstd_unfused", NAN, 1);
                fprintf(f, "}");
            }
            fprintf(f, "]}\n");
            if (fclose(f) != 0) {
                fprintf(stderr, "f4d-eval: error writing '%s'\n", json);
                rc = 1;
            }
        }
    }
    score_take_free(&t);
    return rc;
}
