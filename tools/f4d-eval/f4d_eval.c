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
#include "npy.h"
#include "splat.h"
#include "weights.h"

struct take {
    int    T, V, E, H, W;
    float *rgb, *depth, *alpha, *ergb;
    struct splat_rig rig, erig;
    float  sky[3];
};

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

static int load(const char *dir, const char *name, float **a, int64_t *shape, int want_nd, struct f4d_err *err)
{
    char path[4096];
    int nd;
    snprintf(path, sizeof path, "%s/%s.npy", dir, name);
    if (npy_load_f32(path, a, shape, &nd, err) < 0)
        return -1;
    if (nd != want_nd)
        return f4d_fail(err, F4D_EFORMAT, "%s: %d dimensions, expected %d", path, nd, want_nd);
    return 0;
}

static int take_load(const char *dir, struct take *t, struct f4d_err *err)
{
    int64_t s[NPY_MAX_DIMS], s2[NPY_MAX_DIMS];
    memset(t, 0, sizeof *t);
    if (load(dir, "rgb", &t->rgb, s, 5, err) < 0)
        return -1;
    t->T = (int)s[0], t->V = (int)s[1], t->H = (int)s[2], t->W = (int)s[3];
    if (load(dir, "depth", &t->depth, s2, 4, err) < 0 || load(dir, "alpha", &t->alpha, s2, 4, err) < 0 ||
        load(dir, "eval_rgb", &t->ergb, s2, 5, err) < 0)
        return -1;
    t->E = (int)s2[1];
    if (s2[0] != t->T || s2[2] != t->H || s2[3] != t->W || s[4] != 3)
        return f4d_fail(err, F4D_EFORMAT, "take %s: eval_rgb and rgb disagree on keys or size", dir);
    char path[4096];
    snprintf(path, sizeof path, "%s/rig.json", dir);
    if (splat_rig_load(path, &t->rig, err) < 0)
        return -1;
    snprintf(path, sizeof path, "%s/eval_rig.json", dir);
    if (splat_rig_load(path, &t->erig, err) < 0)
        return -1;
    if (t->rig.count != t->V || t->erig.count != t->E)
        return f4d_fail(err, F4D_EFORMAT, "take %s: rigs have %d + %d cameras, arrays %d + %d", dir, t->rig.count,
                        t->erig.count, t->V, t->E);
    snprintf(path, sizeof path, "%s/take.json", dir);
    FILE *f = fopen(path, "rb");
    if (!f)
        return f4d_fail(err, F4D_EIO, "cannot open %s", path);
    char buf[8192];
    size_t n = fread(buf, 1, sizeof buf - 1, f);
    fclose(f);
    buf[n] = '\0';
    cJSON *j = cJSON_Parse(buf);
    cJSON *sky = j ? cJSON_GetObjectItem(j, "sky") : NULL;
    if (!cJSON_IsArray(sky) || cJSON_GetArraySize(sky) != 3) {
        cJSON_Delete(j);
        return f4d_fail(err, F4D_EFORMAT, "%s: no \"sky\": [r, g, b]", path);
    }
    for (int k = 0; k < 3; k++)
        t->sky[k] = (float)cJSON_GetArrayItem(sky, k)->valuedouble;
    cJSON_Delete(j);
    return 0;
}

static void take_free(struct take *t)
{
    free(t->rgb); free(t->depth); free(t->alpha); free(t->ergb);
}

/* c = a * b for 4x4 row-major. */
static void mul44(const float *a, const float *b, float *c)
{
    for (int i = 0; i < 4; i++)
        for (int j = 0; j < 4; j++) {
            double s = 0;
            for (int k = 0; k < 4; k++)
                s += (double)a[4 * i + k] * b[4 * k + j];
            c[4 * i + j] = (float)s;
        }
}

/* Inverse of a rigid [R | t] (row-major 4x4). */
static void rigid_inv(const float *m, float *o)
{
    memset(o, 0, 16 * sizeof *o);
    for (int i = 0; i < 3; i++) {
        for (int j = 0; j < 3; j++)
            o[4 * i + j] = m[4 * j + i];
        o[4 * i + 3] = -(m[i] * m[3] + m[4 + i] * m[7] + m[8 + i] * m[11]);
    }
    o[15] = 1.0f;
}

static int eval_precision(const struct take *t, const char *weights, enum fk_wtype wt, int keys, int threads,
                          struct row *r, struct f4d_err *err)
{
    fk_ctx *ctx = NULL;
    struct model *m = NULL;
    splat_renderer *ren = NULL;
    int rc = -1;
    const int V = t->V, H = t->H, W = t->W;
    const size_t np = (size_t)H * W;
    float *img = malloc((size_t)V * 3 * np * sizeof(float)), *out = malloc(3 * np * sizeof(float));
    float *ssim_scratch = malloc(splat_ssim_scratch_floats(W, H) * sizeof(float));
    struct fk_ctx_config cc = { .isa = FK_ISA_AUTO, .threads = threads };
    if (!img || !out || !ssim_scratch) {
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
    if (splat_renderer_new(ctx, W, H, &ren, err) < 0)
        goto done;
    float inv0[16];
    rigid_inv(t->rig.cams[0].w2c, inv0);
    double ms = 0, psnr = 0, ssim = 0, pd = 0, re = 0, te = 0;
    int n_img = 0, n_cam = 0;
    size_t n_pt = 0;
    if (keys <= 0 || keys > t->T)
        keys = t->T;
    for (int k = 0; k < keys; k++) {
        for (int v = 0; v < V; v++)
            for (int c = 0; c < 3; c++)
                for (size_t p = 0; p < np; p++)
                    img[((size_t)v * 3 + c) * np + p] = t->rgb[(((size_t)k * V + v) * np + p) * 3 + c];
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
        for (int e = 0; e < t->E; e++) {
            struct splat_camera cam = t->erig.cams[e];
            mul44(t->erig.cams[e].w2c, inv0, cam.w2c); /* into view 0's frame */
            struct splat_render_out ro = { .rgb = out };
            if (splat_render(ren, &cam, &fr, t->sky, &ro) < 0) {
                f4d_fail(err, F4D_EINVAL, "%s", splat_renderer_error(ren));
                goto done;
            }
            for (size_t i = 0; i < 3 * np; i++)
                out[i] = out[i] < 0 ? 0 : (out[i] > 1 ? 1 : out[i]);
            const float *gt = t->ergb + ((size_t)k * t->E + e) * np * 3;
            psnr += splat_psnr(out, gt, W, H, 3);
            ssim += splat_ssim(out, gt, W, H, 3, ssim_scratch);
            n_img++;
        }
        for (int v = 0; v < V; v++) {
            const struct splat_camera *cv = &t->rig.cams[v];
            float rel[16];
            mul44(cv->w2c, inv0, rel);
            for (size_t p = 0; p < np; p++) {
                size_t i = ((size_t)k * V + v) * np + p;
                if (t->alpha[i] <= 0.5f)
                    continue;
                float d = t->depth[i], u = (float)(p % W) + 0.5f, w = (float)(p / W) + 0.5f;
                float pc[3] = { (u - cv->cx) / cv->fx * d, (w - cv->cy) / cv->fy * d, d }, x[3];
                for (int a = 0; a < 3; a++) /* camera v -> view 0: rel^-1 applied to pc */
                    x[a] = rel[a] * (pc[0] - rel[3]) + rel[4 + a] * (pc[1] - rel[7]) + rel[8 + a] * (pc[2] - rel[11]);
                const float *q = g->pos + 3 * ((size_t)v * np + p);
                pd += sqrt((double)(q[0] - x[0]) * (q[0] - x[0]) + (double)(q[1] - x[1]) * (q[1] - x[1]) +
                           (double)(q[2] - x[2]) * (q[2] - x[2]));
                n_pt++;
            }
            const float *pe = o.extrinsic_metric + 12 * v;
            double tr = 0, dt = 0;
            for (int a = 0; a < 3; a++) {
                for (int b = 0; b < 3; b++)
                    tr += (double)pe[4 * a + b] * rel[4 * a + b];
                dt += ((double)pe[4 * a + 3] - rel[4 * a + 3]) * ((double)pe[4 * a + 3] - rel[4 * a + 3]);
            }
            /* pe's rotation need not be exactly orthonormal: clamp the cosine */
            double cs = (tr - 1.0) / 2.0;
            cs = cs > 1 ? 1 : (cs < -1 ? -1 : cs);
            re += acos(cs) * 180.0 / 3.14159265358979323846;
            te += sqrt(dt);
            n_cam++;
        }
    }
    r->key_ms = ms / keys;
    r->psnr = n_img ? psnr / n_img : NAN;
    r->ssim = n_img ? ssim / n_img : NAN;
    r->point_dist = n_pt ? pd / (double)n_pt : NAN;
    r->rot_err = re / n_cam;
    r->trans_err = te / n_cam;
    rc = 0;
done:
    free(img); free(out); free(ssim_scratch);
    splat_renderer_free(ren);
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
    struct take t;
    if (take_load(take_dir, &t, &err) < 0) {
        fprintf(stderr, "f4d-eval: %s\n", err.msg);
        take_free(&t);
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
                take_free(&t);
                return 1;
            }
            w = wpath;
        }
        rows[nr].precision = names[p];
        if (eval_precision(&t, w, types[p], keys, threads, &rows[nr], &err) < 0) {
            fprintf(stderr, "f4d-eval: %s: %s\n", names[p], err.msg);
            take_free(&t);
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
    take_free(&t);
    return rc;
}
