/* f4d-eval - the paper's evaluation table from the C runtime (issue 11) on a
 * venue take (tools/f4d-scene venue, e.g. the test split of tools/train):
 *
 *   f4d-eval --take DIR [--weights W.gguf] [--precision f32|f16|int8|all]
 *            [--keys N] [--threads N] [--json FILE]
 *
 * The take's keys 0..T-1 go in order through the streaming runtime
 * (firmware/gaussians/sequence: state tokens carried from key to key, motion
 * and fusion when the weights have them); the model sees the input views
 * only. Everything is scored in view 0's frame (the model's world), the true
 * cameras moved there, with no alignment. Per precision:
 *   key_ms            mean wall time of one f4d_sequence_push (model with
 *                     state and motion, all views; load average printed);
 *   novel_view_psnr / _ssim   renders of each key at the held-out evaluation
 *                     cameras against the take's exact renders (3DGS PSNR /
 *                     SSIM, mean over keys x cameras);
 *   novel_time_psnr / _ssim   renders of f4d_sequence_at(k + 1/2) (the
 *                     weights' fusion MLP; averaging without one) at every
 *                     camera of the take, held-out and input, against the
 *                     take's mid-time renders, mean over mids x cameras;
 *   motion_epe_m      mean |M - R0 m| (metres) of the predicted per-pixel
 *                     motions M1[t] (key t -> t-1) and M2[t-1] (t-1 -> t)
 *                     against the take's exact motion m of the same pixel
 *                     (R0: view 0's true rotation), over foreground pixels:
 *                     valid (alpha > 0.5) and moving (|m| > 1 um; the venue's
 *                     floor and backdrop are static, exactly 0, so these are
 *                     the people). The mean over every valid pixel is printed
 *                     too (JSON "extra");
 *   point_dist_m      mean distance of each valid input pixel's metric
 *                     Gaussian centre to the true surface point of that pixel;
 *   rot_err_deg, trans_err_m  predicted metric cameras against the truth;
 *   tlstd_fused / _unfused    TL-STD (temporal luma standard deviation,
 *                     splat_tlstd: Y = 0.2126 R + 0.7152 G + 0.0722 B in
 *                     [0, 1], per-pixel population std over time, mean over
 *                     pixels; mean over cameras) of the playback key 0, mid
 *                     1/2, key 1, ..., key T-1 rendered at every camera of the
 *                     take; the mids fused by the MLP, or averaged (fusion
 *                     off, the paper's ablation) on the same keys. The truth's
 *                     TL-STD of the same frames is printed beside them.
 * n/a (null in JSON) with the reason printed: novel time, motion and TL-STD
 * when the take has one key or the weights have no motion part; tlstd_fused
 * when they have no fusion MLP; novel view when the take has no held-out
 * cameras (venue --eval 0). LPIPS needs network weights this project
 * cannot ship: absent. Without --weights the shipped model is used
 * (firmware/infer/weights). The take, its cameras in view 0's frame, the
 * renders, PSNR / SSIM, point distance and camera errors come from
 * firmware/gaussians/score (f4d_score.h), which forge4d report scores with
 * too; the foreground motion EPE (both directions) and TL-STD are f4d-eval's. */
#include <cjson/cJSON.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "f4d_score.h"
#include "f4d_sequence.h"
#include "model.h"
#include "splat.h"
#include "weights.h"

/* |m| above this (metres per key interval) marks a moving, foreground pixel */
#define EVAL_MOVING_M 1e-6

struct row {
    const char *precision;
    double key_ms, psnr, ssim, nt_psnr, nt_ssim, epe, point_dist, rot_err, trans_err, tl_fused, tl_unfused;
    double epe_all, epe_zero, nt_psnr_avg, tl_truth, fused_pairs; /* context: "extra" in JSON */
    char   why_view[160], why_time[160], why_epe[160], why_fused[160]; /* reasons for n/a ("" = computed) */
};

static double now_ms(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return 1e3 * (double)ts.tv_sec + 1e-6 * (double)ts.tv_nsec;
}

/* Temporal luma statistics per camera and pixel, one frame at a time: the
 * sums splat_tlstd forms over a stored sequence, without storing it. */
struct tl_acc {
    double *s, *s2;
    size_t  np;
    int     cams, *n;
};

static int tl_new(struct tl_acc *a, int cams, size_t np)
{
    a->cams = cams;
    a->np = np;
    a->s = calloc((size_t)cams * np, sizeof *a->s);
    a->s2 = calloc((size_t)cams * np, sizeof *a->s2);
    a->n = calloc((size_t)cams, sizeof *a->n);
    return a->s && a->s2 && a->n ? 0 : -1;
}

static void tl_free(struct tl_acc *a) { free(a->s); free(a->s2); free(a->n); }

static void tl_add(struct tl_acc *a, int cam, const float *rgb)
{
    double *s = a->s + (size_t)cam * a->np, *s2 = a->s2 + (size_t)cam * a->np;
    for (size_t i = 0; i < a->np; i++) {
        const float *p = rgb + 3 * i;
        double y = 0.2126 * p[0] + 0.7152 * p[1] + 0.0722 * p[2];
        s[i] += y;
        s2[i] += y * y;
    }
    a->n[cam]++;
}

/* splat_tlstd of each camera's sequence, mean over cameras. */
static double tl_value(const struct tl_acc *a)
{
    double acc = 0;
    for (int c = 0; c < a->cams; c++) {
        const double *s = a->s + (size_t)c * a->np, *s2 = a->s2 + (size_t)c * a->np, n = a->n[c];
        if (a->n[c] < 2)
            return NAN;
        double cam = 0;
        for (size_t i = 0; i < a->np; i++) {
            double m = s[i] / n, v = s2[i] / n - m * m;
            cam += v > 0.0 ? sqrt(v) : 0.0;
        }
        acc += cam / (double)a->np;
    }
    return acc / a->cams;
}

/* Sum of |pred - R0 gt| over valid pixels, all and moving (foreground). */
static void epe_add(const float *pred, const float *gt, const float *alpha, const float *R0, size_t n, double *all,
                    size_t *n_all, double *fg, double *fg_zero, size_t *n_fg)
{
    for (size_t i = 0; i < n; i++) {
        if (alpha[i] <= 0.5f)
            continue;
        const float *m = gt + 3 * i, *p = pred + 3 * i;
        double d2 = 0, g2 = 0;
        for (int a = 0; a < 3; a++) {
            double g = (double)R0[4 * a] * m[0] + (double)R0[4 * a + 1] * m[1] + (double)R0[4 * a + 2] * m[2];
            d2 += ((double)p[a] - g) * ((double)p[a] - g);
            g2 += (double)m[a] * m[a];
        }
        *all += sqrt(d2);
        (*n_all)++;
        if (g2 > EVAL_MOVING_M * EVAL_MOVING_M) {
            *fg += sqrt(d2);
            *fg_zero += sqrt(g2); /* what predicting no motion scores */
            (*n_fg)++;
        }
    }
}

static int eval_precision(const struct score_take *t, const char *weights, enum fk_wtype wt, int keys, int threads,
                          struct row *r, struct f4d_err *err)
{
    fk_ctx *ctx = NULL;
    struct model *m = NULL;
    f4d_sequence *sq = NULL;
    score_view *sv = NULL;
    struct tl_acc tl_f = { 0 }, tl_u = { 0 }, tl_g = { 0 };
    int rc = -1;
    const int V = t->V, E = t->E, C = t->V + t->E, H = t->H, W = t->W;
    const size_t np = (size_t)H * W;
    float *img = malloc((size_t)V * 3 * np * sizeof(float));
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
    if (!(model_groups(m) & MODEL_G_SCALE)) {
        f4d_fail(err, F4D_ENOTSUP, "f4d-eval: %s has no scale head (scale_head.*): nothing is metric", weights);
        goto done;
    }
    if (f4d_sequence_open_model(m, V, H, W, &sq, err) < 0)
        goto done;
    if (score_view_new(ctx, t, &sv, err) < 0)
        goto done;
    if (keys <= 0 || keys > t->T)
        keys = t->T;
    /* what this take and these weights allow beyond the per-key columns */
    const int has_motion = f4d_sequence_has_motion(sq), has_fusion = f4d_sequence_has_fusion(sq);
    r->why_view[0] = r->why_time[0] = r->why_epe[0] = r->why_fused[0] = '\0';
    if (!E)
        snprintf(r->why_view, sizeof r->why_view, "the take has no held-out (evaluation) cameras");
    if (keys < 2)
        snprintf(r->why_time, sizeof r->why_time, "%s", t->T < 2 ? "the take has one key (no mid time, no motion)"
                                                                  : "--keys 1 (no mid time, no motion)");
    else if (!t->mid || !t->motion_bwd || !t->motion_fwd)
        snprintf(r->why_time, sizeof r->why_time, "the take has no motion_bwd / motion_fwd / mid_rgb arrays");
    else if (!has_motion)
        snprintf(r->why_time, sizeof r->why_time, "the weights have no motion part (motion.*, motion_head.*)");
    const int timed = r->why_time[0] == '\0';
    if (timed && !has_fusion)
        snprintf(r->why_fused, sizeof r->why_fused, "the weights have no fusion MLP (fusion.*): mids are averaged");
    if (timed && (tl_new(&tl_f, C, np) < 0 || tl_new(&tl_u, C, np) < 0 || tl_new(&tl_g, C, np) < 0)) {
        f4d_fail(err, F4D_ENOMEM, "f4d-eval: out of memory");
        goto done;
    }
    /* the true cameras in view 0's frame (the model's world) */
    struct splat_camera cams[2 * SPLAT_RIG_MAX];
    for (int c = 0; c < C; c++) {
        if (c < V)
            score_input_camera(t, c, &cams[c]);
        else
            score_eval_camera(t, c - V, &cams[c]);
    }
    const float *R0 = t->rig.cams[0].w2c;
    double ms = 0, psnr = 0, ssim = 0, pd = 0, re = 0, te = 0, ntp = 0, nts = 0, ntpa = 0, ea = 0, ef = 0, ez = 0;
    double pairs = 0;
    int n_img = 0, n_cam = 0, n_mid = 0;
    size_t n_pt = 0, n_ea = 0, n_ef = 0;
    for (int k = 0; k < keys; k++) {
        if (score_take_input(ctx, t, k, H, W, scratch, img, err) < 0)
            goto done;
        double t0 = now_ms();
        if (f4d_sequence_push(sq, img, err) < 0)
            goto done;
        ms += now_ms() - t0;
        struct f4d_seq_key key;
        if (f4d_sequence_key(sq, 0, &key, err) < 0)
            goto done;
        if (!key.has_gauge) {
            f4d_fail(err, F4D_ENOTSUP, "f4d-eval: %s gives no metric gauge", weights);
            goto done;
        }
        /* the key at every camera: held-out ones score novel views, and with
         * motion all of them enter the flicker playback (same key both ways) */
        for (int c = timed ? 0 : V; c < C; c++) {
            if (score_render(sv, &cams[c], &key.frame, err) < 0)
                goto done;
            const float *gt = c < V ? t->rgb + ((size_t)k * V + c) * np * 3 : t->ergb + ((size_t)k * E + c - V) * np * 3;
            if (c >= V) {
                double p, s;
                score_compare(sv, gt, &p, &s);
                psnr += p;
                ssim += s;
                n_img++;
            }
            if (timed) {
                tl_add(&tl_f, c, score_view_rgb(sv));
                tl_add(&tl_u, c, score_view_rgb(sv));
                tl_add(&tl_g, c, gt);
            }
        }
        double sum, rs, ts;
        size_t n;
        if (score_points(t, k, key.frame.pos, H, W, &sum, &n, err) < 0)
            goto done;
        pd += sum;
        n_pt += n;
        score_cameras(t, key.extrinsic, &rs, &ts);
        re += rs;
        te += ts;
        n_cam += V;
        if (!timed || k == 0)
            continue;
        /* motion: M1[k] on key k, M2[k-1] on key k-1, against the exact motion */
        struct f4d_seq_key prev;
        if (f4d_sequence_key(sq, 1, &prev, err) < 0)
            goto done;
        if (!key.frame.motion_bwd || !prev.frame.motion_fwd) {
            f4d_fail(err, F4D_EINVAL, "f4d-eval: key %d came without its motion", k);
            goto done;
        }
        epe_add(key.frame.motion_bwd, t->motion_bwd + (size_t)k * V * np * 3, t->alpha + (size_t)k * V * np, R0,
                (size_t)V * np, &ea, &n_ea, &ef, &ez, &n_ef);
        epe_add(prev.frame.motion_fwd, t->motion_fwd + (size_t)(k - 1) * V * np * 3, t->alpha + (size_t)(k - 1) * V * np,
                R0, (size_t)V * np, &ea, &n_ea, &ef, &ez, &n_ef);
        /* mid time k - 1/2: the runtime's interpolation (MLP, or averaging
         * without one), then with fusion off when there is an MLP */
        for (int pass = 0; pass < (has_fusion ? 2 : 1); pass++) {
            const struct splat_frame *mid;
            struct interp_stats st;
            if ((has_fusion && f4d_sequence_set_fusion(sq, pass == 0, err) < 0) ||
                f4d_sequence_at(sq, (double)k - 0.5, &mid, &st, err) < 0)
                goto done;
            if (pass == 0)
                pairs += (double)st.fused;
            for (int c = 0; c < C; c++) {
                if (score_render(sv, &cams[c], mid, err) < 0)
                    goto done;
                const float *gt = t->mid + ((size_t)(k - 1) * C + c) * np * 3;
                double p, s;
                score_compare(sv, gt, &p, pass == 0 ? &s : NULL);
                if (pass == 0) {
                    ntp += p;
                    nts += s;
                    n_mid++;
                    tl_add(&tl_g, c, gt);
                }
                if (pass == 0 && has_fusion)
                    tl_add(&tl_f, c, score_view_rgb(sv));
                else {
                    tl_add(&tl_u, c, score_view_rgb(sv));
                    ntpa += p;
                }
            }
        }
        if (has_fusion && f4d_sequence_set_fusion(sq, 1, err) < 0)
            goto done;
    }
    r->key_ms = ms / keys;
    r->psnr = n_img ? psnr / n_img : NAN;
    r->ssim = n_img ? ssim / n_img : NAN;
    r->point_dist = n_pt ? pd / (double)n_pt : NAN;
    r->rot_err = re / n_cam;
    r->trans_err = te / n_cam;
    r->nt_psnr = n_mid ? ntp / n_mid : NAN;
    r->nt_ssim = n_mid ? nts / n_mid : NAN;
    r->nt_psnr_avg = n_mid ? ntpa / n_mid : NAN;
    r->epe = n_ef ? ef / (double)n_ef : NAN;
    r->epe_all = n_ea ? ea / (double)n_ea : NAN;
    r->epe_zero = n_ef ? ez / (double)n_ef : NAN;
    r->fused_pairs = timed ? pairs / (keys - 1) : NAN;
    if (timed && !n_ef)
        snprintf(r->why_epe, sizeof r->why_epe, "no valid moving (foreground) pixel in the take");
    r->tl_fused = timed && has_fusion ? tl_value(&tl_f) : NAN;
    r->tl_unfused = timed ? tl_value(&tl_u) : NAN;
    r->tl_truth = timed ? tl_value(&tl_g) : NAN;
    rc = 0;
done:
    free(img); free(scratch);
    tl_free(&tl_f); tl_free(&tl_u); tl_free(&tl_g);
    score_view_free(sv);
    f4d_sequence_close(sq);
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

/* A table cell: the value with `digits` decimals, or n/a (its reason is
 * printed below the table). */
static const char *cell(char *buf, size_t n, int digits, double v)
{
    if (!isfinite(v))
        return "n/a";
    snprintf(buf, n, "%.*f", digits, v);
    return buf;
}

/* The 1-minute load average (the machine may be shared), NAN if unknown. */
static double load_average(void)
{
    double l = NAN;
    FILE *f = fopen("/proc/loadavg", "r");
    if (f) {
        if (fscanf(f, "%lf", &l) != 1)
            l = NAN;
        fclose(f);
    }
    return l;
}

/* The reasons for n/a cells, one line each ("" = none). */
static int reasons(const struct row *r, char out[4][256])
{
    int n = 0;
    if (r->why_view[0])
        snprintf(out[n++], 256, "%s: novel view n/a: %s", r->precision, r->why_view);
    if (r->why_time[0])
        snprintf(out[n++], 256, "%s: novel time, motion EPE and TL-STD n/a: %s", r->precision, r->why_time);
    if (r->why_epe[0])
        snprintf(out[n++], 256, "%s: motion EPE n/a: %s", r->precision, r->why_epe);
    if (r->why_fused[0])
        snprintf(out[n++], 256, "%s: TL-STD fused n/a: %s", r->precision, r->why_fused);
    return n;
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
    const double load0 = load_average();
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
        memset(&rows[nr], 0, sizeof rows[nr]);
        rows[nr].precision = names[p];
        if (eval_precision(&t, w, types[p], keys, threads, &rows[nr], &err) < 0) {
            fprintf(stderr, "f4d-eval: %s: %s\n", names[p], err.msg);
            score_take_free(&t);
            return 1;
        }
        nr++;
    }
    const int nkeys = keys > 0 && keys < t.T ? keys : t.T;
    char thr[16] = "all";
    if (threads > 0)
        snprintf(thr, sizeof thr, "%d", threads);
    printf("| precision | key ms | novel-view PSNR | novel-view SSIM | novel-time PSNR | novel-time SSIM | "
           "motion EPE (m) | point dist (m) | rot err (deg) | trans err (m) | TL-STD fused | TL-STD unfused |\n");
    printf("|---|---|---|---|---|---|---|---|---|---|---|---|\n");
    for (int i = 0; i < nr; i++) {
        const struct row *r = &rows[i];
        char b[12][32];
        printf("| %s | %s | %s | %s | %s | %s | %s | %s | %s | %s | %s | %s |\n", r->precision,
               cell(b[0], 32, 1, r->key_ms), cell(b[1], 32, 2, r->psnr), cell(b[2], 32, 4, r->ssim),
               cell(b[3], 32, 2, r->nt_psnr), cell(b[4], 32, 4, r->nt_ssim), cell(b[5], 32, 5, r->epe),
               cell(b[6], 32, 4, r->point_dist), cell(b[7], 32, 2, r->rot_err),
               cell(b[8], 32, 4, r->trans_err), cell(b[9], 32, 4, r->tl_fused),
               cell(b[10], 32, 4, r->tl_unfused));
    }
    printf("| paper (518^2, H200) | 176.5 | 29.82 | 0.9606 | 29.04 | 0.9566 | 0.00953 | 0.0264 | - | - | 0.5379 | 0.9446 |\n");
    printf("\n%d keys, %d input views, %d evaluation views, %dx%d. key ms: mean wall time of one push (model with "
           "state and motion where the weights have them) on %s thread(s), 1-min load average %.2f at start. Motion EPE over valid moving "
           "(foreground) pixels; TL-STD in [0,1] luma over the playback key, mid, key, ... at every camera (the "
           "paper does not state its unit). LPIPS is not computed (no network weights).\n",
           nkeys, t.V, t.E, t.W, t.H, thr, load0);
    for (int i = 0; i < nr; i++) {
        const struct row *r = &rows[i];
        char why[4][256];
        if (isfinite(r->nt_psnr))
            printf("- %s: motion EPE over every valid pixel %.5f m, of zero motion on the foreground %.5f m; "
                   "novel-time PSNR with averaging %.2f dB; %.0f pairs fused per mid; TL-STD of the truth on the "
                   "same frames %.4f\n", r->precision, r->epe_all, r->epe_zero, r->nt_psnr_avg, r->fused_pairs,
                   r->tl_truth);
        for (int k = 0, n = reasons(r, why); k < n; k++)
            printf("- n/a %s\n", why[k]);
    }
    int rc = 0;
    if (json) {
        FILE *f = fopen(json, "w");
        if (!f) {
            fprintf(stderr, "f4d-eval: cannot create '%s'\n", json);
            rc = 1;
        } else {
            fprintf(f, "{\"rows\": [");
            for (int i = 0; i < nr; i++) {
                const struct row *r = &rows[i];
                fprintf(f, "%s{\"precision\": \"%s\", ", i ? ", " : "", r->precision);
                json_num(f, "key_ms", r->key_ms, 0);
                json_num(f, "novel_view_psnr", r->psnr, 0);
                json_num(f, "novel_view_ssim", r->ssim, 0);
                json_num(f, "novel_time_psnr", r->nt_psnr, 0);
                json_num(f, "novel_time_ssim", r->nt_ssim, 0);
                json_num(f, "motion_epe_m", r->epe, 0);
                json_num(f, "point_dist_m", r->point_dist, 0);
                json_num(f, "rot_err_deg", r->rot_err, 0);
                json_num(f, "trans_err_m", r->trans_err, 0);
                json_num(f, "tlstd_fused", r->tl_fused, 0);
                json_num(f, "tlstd_unfused", r->tl_unfused, 1);
                fprintf(f, "}");
            }
            /* context beside the table's columns: n/a reasons, the full-mask
             * EPE, averaging's novel-time PSNR, the truth's flicker, the load */
            fprintf(f, "], \"extra\": [");
            for (int i = 0; i < nr; i++) {
                const struct row *r = &rows[i];
                fprintf(f, "%s{\"precision\": \"%s\", ", i ? ", " : "", r->precision);
                json_num(f, "motion_epe_all_m", r->epe_all, 0);
                json_num(f, "motion_epe_zero_m", r->epe_zero, 0);
                json_num(f, "fused_pairs_per_mid", r->fused_pairs, 0);
                json_num(f, "novel_time_psnr_averaged", r->nt_psnr_avg, 0);
                json_num(f, "tlstd_truth", r->tl_truth, 0);
                fprintf(f, "\"na\": [");
                char why[4][256];
                for (int k = 0, n = reasons(r, why); k < n; k++) {
                    cJSON *s = cJSON_CreateString(why[k]);
                    char *q = s ? cJSON_PrintUnformatted(s) : NULL;
                    fprintf(f, "%s%s", k ? ", " : "", q ? q : "\"?\"");
                    cJSON_free(q);
                    cJSON_Delete(s);
                }
                fprintf(f, "]}");
            }
            fprintf(f, "], \"keys\": %d, \"threads\": %d, ", nkeys, threads);
            json_num(f, "load_average", load0, 1);
            fprintf(f, "}\n");
            if (fclose(f) != 0) {
                fprintf(stderr, "f4d-eval: error writing '%s'\n", json);
                rc = 1;
            }
        }
    }
    score_take_free(&t);
    return rc;
}
