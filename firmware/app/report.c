/* report.c: `forge4d report`, the speed-vs-error study of the appliance's path
 * on venue takes with exact ground truth (report_internal.h has the command).
 *
 * Per take and per model configuration (precision, input size, token budget,
 * motion on / off as the daemon's --motion) the take's keys go through the Forge4D sequence (state and motion when the
 * weights have them; foreground-only keys through model_eval_masked with a
 * firmware/infer/foreground keep-list). Every finished key (with both motions)
 * is kept; then per Gaussian budget (the daemon's scene budget, interp.h) and
 * codec level the keys run the rest of the path as the daemon and the display
 * do: budget -> encoder (matches through the pixel origin, as run_stages.c)
 * -> packet -> the display's player (decode, interpolation) -> render.
 * Scores (f4d_score.h): novel-view PSNR / SSIM of what the display shows at
 * each key time at the held-out cameras, novel-time PSNR at the mid times,
 * metric point distance and camera errors of the model's keys, motion EPE
 * when the weights have motion. Speed: key ms = model + budget + encode per
 * key (the key path), displayed-frame ms = interpolation + one render.
 * Speeds are compared only as ratios inside one run (the machine is shared).
 *
 * What "time per key" is (--clock): `cpu` (the default) is the CPU time of
 * the calling thread over the key path with ONE kernel thread: the work a key
 * costs, which other jobs on a shared machine change little (they take turns
 * on the core, they do not add to our clock). It needs --threads 1: the
 * kernel pool's workers and its caller spin up to SPIN_ROUNDS pauses
 * (kernels/src/pool.c) before sleeping, and process CPU time counts that
 * spin, so with 2 threads it measures waiting as work. `wall` is the
 * monotonic time, for a quiet machine (any --threads). Both are always
 * measured and printed; the clock picks the one the front and goal use.
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <errno.h>
#include <time.h>
#include <unistd.h>

#include <cjson/cJSON.h>

#include "f4d_codec.h"
#include "f4d_display.h"
#include "f4d_score.h"
#include "f4d_sequence.h"
#include "fk_ctx.h"
#include "foreground.h"
#include "interp.h"
#include "model.h"
#include "report_internal.h"
#include "weights.h"

#define NPREC 3
#define NSCALE 5
#define NTOK 2
#define NMOT 2
#define NBUD 3
#define NCOD 4
#define TAKES_MAX 16
#define FG_MARGIN 1

static const char *const prec_name[NPREC] = {"f32", "f16", "int8"};
static const enum fk_wtype prec_type[NPREC] = {FK_W_F32, FK_W_F16, FK_W_Q8};
/* input side over the take's: 112 -> 112, 98, 84, 70, 56 for the shipped model
 * (whole 14-pixel patches: 8x8, 7x7, 6x6, 5x5, 4x4 per view) */
static const double scale_val[NSCALE] = {1.0, 0.875, 0.75, 0.625, 0.5};
static const char *const scale_name[NSCALE] = {"1", "7/8", "3/4", "5/8", "1/2"};
static const char *const tok_name[NTOK] = {"all", "fg"};
/* motion: the daemon's --motion on|off (off: the motion head and blocks skipped,
 * keys without motion, the display shows the nearest key) */
static const char *const mot_name[NMOT] = {"on", "off"};
static const char *const bud_name[NBUD] = {"none", "default", "coarse"};
static const char *const cod_name[NCOD] = {"compact", "low", "medium", "high"};

/* What the grid runs: a subset of every axis (--quick: the reduced one). */
struct grid {
    bool prec[NPREC], scale[NSCALE], tok[NTOK], mot[NMOT], bud[NBUD], cod[NCOD];
};

/* Sums over every take of one grid point. */
struct acc {
    double model_ms, model_cpu_ms, model_pcpu_ms, budget_ms, budget_cpu_ms, enc_ms, enc_cpu_ms, dec_ms; size_t keys;
    double disp_ms, lookup_ms; size_t frames;
    double bytes, gauss;
    double nv_psnr, nv_ssim; size_t nv_n;
    double nt_psnr, nt_ssim; size_t nt_n;
    double pt; size_t pt_n;
    double rot, trans; size_t cams;
    double mot; size_t mot_n;
    double tok_ran, tok_all;
    double bits_s; /* bits x take fps, for the mean rate */
    int h, w;
};

struct point {
    int p, s, t, m, b, c;
    double key_ms, key_wall_ms, key_cpu_ms, model_ms, model_cpu_ms, model_pcpu_ms, budget_ms, budget_cpu_ms, enc_ms,
        enc_cpu_ms, dec_ms, disp_ms, lookup_ms, key_hz, gauss, bytes, mbps;
    double nv_psnr, nv_ssim, nt_psnr, nt_ssim, pt, rot, trans, mot, tok_frac, speedup, dpsnr;
    int h, w;
    bool front;
};

/* The keys of one model configuration on one take, finished (both motions). */
struct keyrun {
    int T, S, h, w;
    size_t n;
    struct splat_frame *keys;   /* [T] */
    struct splat_rig *rigs;     /* [T] metric cameras, model world */
    bool motion;
};

static double clock_ms(clockid_t id)
{
    struct timespec ts;
    clock_gettime(id, &ts);
    return 1e3 * (double)ts.tv_sec + 1e-6 * (double)ts.tv_nsec;
}

static double now_ms(void) { return clock_ms(CLOCK_MONOTONIC); }

/* CPU time of the calling thread. With --threads 1 the key path runs on it
 * alone (the model's context then has no pool), so this is the key's work,
 * without another job's share and without any pool spin. */
static double cpu_ms(void) { return clock_ms(CLOCK_THREAD_CPUTIME_ID); }

/* CPU time of the whole process, every kernel thread: with --threads > 1 it
 * includes the pool's spin-waits (kernels/src/pool.c), so it is printed for
 * reference and never used for a speed ratio then. */
static double proc_cpu_ms(void) { return clock_ms(CLOCK_PROCESS_CPUTIME_ID); }

static void model_run_free(struct keyrun *r)
{
    if (r->keys)
        for (int k = 0; k < r->T; k++)
            splat_frame_free(&r->keys[k]);
    free(r->keys);
    free(r->rigs);
    memset(r, 0, sizeof *r);
}

/* A key with both motion arrays when the weights have motion (zero where the
 * sequence has none yet: key 0's backward, the last key's forward motion), as
 * the daemon's budget hands them to the encoder. */
static int copy_key(struct splat_frame *d, const struct splat_frame *s, bool motion, struct f4d_err *err)
{
    const size_t n = s->count;
    if (splat_frame_resize(d, n, motion, err) < 0)
        return -1;
    memcpy(d->pos, s->pos, 3 * n * sizeof(float));
    memcpy(d->scale, s->scale, 3 * n * sizeof(float));
    memcpy(d->rot, s->rot, 4 * n * sizeof(float));
    memcpy(d->opacity, s->opacity, n * sizeof(float));
    memcpy(d->rgb, s->rgb, 3 * n * sizeof(float));
    if (motion) {
        if (s->motion_bwd)
            memcpy(d->motion_bwd, s->motion_bwd, 3 * n * sizeof(float));
        else
            memset(d->motion_bwd, 0, 3 * n * sizeof(float));
        if (s->motion_fwd)
            memcpy(d->motion_fwd, s->motion_fwd, 3 * n * sizeof(float));
        else
            memset(d->motion_fwd, 0, 3 * n * sizeof(float));
    }
    return 0;
}

static int weights_for(const char *given, int p, char *buf, size_t cap, const char **out, struct f4d_err *err)
{
    if (given) {
        *out = given;
        return 0;
    }
    if (f4d_weights_default(prec_type[p] == FK_W_Q8, buf, cap, err) < 0)
        return -1;
    *out = buf;
    return 0;
}

static void input_size(const struct score_take *t, int s, int patch, int *h, int *w)
{
    *h = (int)(t->H * scale_val[s] / patch) * patch;
    *w = (int)(t->W * scale_val[s] / patch) * patch;
}

/* One take through the sequence at (precision p, size h x w, token budget tok):
 * the finished keys into r, the model's scores and times into a, and per key
 * into kt[3 k ..] (wall, thread CPU, process CPU ms) when kt is not NULL. */
static int run_model(const struct score_take *t, int keys, const char *weights, enum fk_wtype wt, int h, int w,
                     int tok, bool motion_off, int threads, fk_ctx *sctx, struct keyrun *r, struct acc *a, double *kt,
                     struct f4d_err *err)
{
    fk_ctx *ctx = NULL;
    struct model *m = NULL;
    f4d_sequence *sq = NULL;
    fg_model *fg = NULL;
    int rc = -1;
    const int S = t->V;
    const size_t n = (size_t)S * h * w;
    float *in = malloc((size_t)S * 3 * h * w * sizeof(float));
    float *scr = malloc(score_input_scratch_floats(t) * sizeof(float));
    uint8_t *keep = NULL;
    memset(r, 0, sizeof *r);
    r->T = keys, r->S = S, r->h = h, r->w = w, r->n = n;
    r->keys = calloc((size_t)keys, sizeof *r->keys);
    r->rigs = calloc((size_t)keys, sizeof *r->rigs);
    if (!in || !scr || !r->keys || !r->rigs) {
        f4d_fail(err, F4D_ENOMEM, "report: out of memory");
        goto done;
    }
    /* the model freezes its context: its own, as the daemon's inference stage */
    if (fk_ctx_new(&(struct fk_ctx_config){.isa = FK_ISA_AUTO, .threads = threads}, &ctx) != F4D_OK) {
        f4d_fail(err, F4D_ENOMEM, "report: cannot create the kernel context");
        goto done;
    }
    if (model_init(ctx, weights, wt, &m, err) < 0)
        goto done;
    /* motion off as the daemon's: nothing reads the motion head's maps (the
     * model then leaves out the motion blocks too) */
    if (motion_off && model_skip_head(m, "motion_head") < 0) {
        f4d_fail(err, F4D_EINVAL, "report: %s", model_error(m));
        goto done;
    }
    const int patch = model_get_config(m)->patch_size;
    if (h % patch || w % patch || h < patch || w < patch) {
        f4d_fail(err, F4D_EINVAL, "report: input %dx%d is not a multiple of the patch size %d", w, h, patch);
        goto done;
    }
    if (f4d_sequence_open_model(m, S, h, w, &sq, err) < 0)
        goto done;
    r->motion = f4d_sequence_has_motion(sq) != 0 && !motion_off;
    const int P = (h / patch) * (w / patch);
    if (tok == 1) { /* foreground: the background plate, else the take's own keys (median) */
        int K = t->background ? 1 : (t->T < FG_SAMPLES_MAX ? t->T : FG_SAMPLES_MAX);
        struct fg_config fc = {.views = S, .height = h, .width = w, .patch = patch, .samples = K};
        keep = malloc((size_t)S * P);
        if (!keep) {
            f4d_fail(err, F4D_ENOMEM, "report: out of memory");
            goto done;
        }
        if (fg_new(&fc, &fg, err) < 0)
            goto done;
        for (int k = 0; k < K; k++) {
            if ((t->background ? score_take_background(sctx, t, h, w, scr, in, err)
                               : score_take_input(sctx, t, k, h, w, scr, in, err)) < 0)
                goto done;
            if (fg_learn(fg, in, err) < 0)
                goto done;
        }
    }
    /* warm-up (caches, arena) on the first key, then back to t = 0 */
    if (score_take_input(sctx, t, 0, h, w, scr, in, err) < 0)
        goto done;
    struct model_outputs o;
    if (model_eval(m, in, S, h, w, &o) < 0) {
        f4d_fail(err, F4D_EINVAL, "report: %s", model_error(m));
        goto done;
    }
    model_state_reset(m);
    for (int k = 0; k < keys; k++) {
        if (score_take_input(sctx, t, k, h, w, scr, in, err) < 0)
            goto done;
        const uint8_t *kp = NULL;
        int kept[MODEL_VIEWS_MAX] = {0};
        /* the keep-list is part of a foreground key's model step: timed with it */
        double t0 = now_ms(), c0 = cpu_ms(), p0 = proc_cpu_ms();
        if (fg && k > 0) { /* the first key of a take runs every patch (nothing to reuse yet) */
            if (fg_mask(fg, in, FG_MARGIN, keep, kept, err) < 0)
                goto done;
            kp = keep;
        }
        if (f4d_sequence_push_masked(sq, in, kp, err) < 0)
            goto done;
        double dw = now_ms() - t0, dc = cpu_ms() - c0, dp = proc_cpu_ms() - p0;
        a->model_ms += dw;
        a->model_cpu_ms += dc;
        a->model_pcpu_ms += dp;
        if (kt)
            kt[3 * k] = dw, kt[3 * k + 1] = dc, kt[3 * k + 2] = dp;
        int ran = 0, all = 0;
        (void)kept;
        /* tokens that ran: the model counts them (per view: specials + kept patches) */
        {
            const int *off;
            const int32_t *row;
            ran = model_token_rows(m, &off, &row);
            all = S * (P + 1 + model_get_config(m)->num_register_tokens);
        }
        a->tok_ran += ran;
        a->tok_all += all;
        struct f4d_seq_key sk;
        if (f4d_sequence_key(sq, 0, &sk, err) < 0)
            goto done;
        /* the model's own scores on the key as it comes out */
        double sum, rs, ts;
        size_t cnt;
        if (score_points(t, k, sk.frame.pos, h, w, &sum, &cnt, err) < 0)
            goto done;
        a->pt += sum;
        a->pt_n += cnt;
        score_cameras(t, sk.extrinsic, &rs, &ts);
        a->rot += rs;
        a->trans += ts;
        a->cams += (size_t)S;
        if (r->motion && sk.frame.motion_bwd && t->motion_bwd) {
            if (score_motion(t, k, sk.frame.motion_bwd, h, w, &sum, &cnt, err) < 0)
                goto done;
            a->mot += sum;
            a->mot_n += cnt;
        }
        if (copy_key(&r->keys[k], &sk.frame, r->motion, err) < 0)
            goto done;
        r->rigs[k] = sk.rig;
        if (k > 0 && r->motion) { /* key k-1 now has its forward motion M2[k-1] */
            struct f4d_seq_key pk;
            if (f4d_sequence_key(sq, 1, &pk, err) < 0 || copy_key(&r->keys[k - 1], &pk.frame, true, err) < 0)
                goto done;
        }
    }
    a->keys += (size_t)keys;
    rc = 0;
done:
    if (rc < 0 && m && !err->msg[0])
        f4d_fail(err, F4D_EINVAL, "report: %s", model_error(m));
    fg_free(fg);
    free(keep);
    free(in);
    free(scr);
    f4d_sequence_close(sq);
    model_free(m);
    fk_ctx_free(ctx);
    return rc;
}

static struct budget_config budget_level(int b)
{
    struct budget_config c = budget_config_default();
    if (b == 2) { /* coarse: 4x the merge cell, twice the footprint, more opacity pruned */
        c.voxel *= 4.0f;
        c.min_footprint *= 2.0f;
        c.min_opacity = 0.05f;
    }
    return c;
}

/* An encoder as the daemon makes it: at level q and the daemon's effort
 * (run_config_defaults: fast). *e is set even on failure (the caller frees). */
static int report_encoder_new(size_t n, enum codec_quality q, codec_enc **e, struct f4d_err *err)
{
    if (codec_enc_new(n, q, e, err) < 0)
        return -1;
    if (codec_enc_set_effort(*e, CODEC_EFFORT_FAST) < 0)
        return f4d_fail(err, F4D_EINVAL, "report: encoder: %s", codec_enc_error(*e));
    return 0;
}

static enum codec_quality codec_level(int c)
{
    return c == 0 ? CODEC_Q_COMPACT : c == 1 ? CODEC_Q_LOW : c == 2 ? CODEC_Q_MEDIUM : CODEC_Q_HIGH;
}

/* The keys of r through budget level b and codec level c into the display's
 * player; scores and times into a. The budget and the encoder first run the
 * keys `passes` more times, each with a fresh encoder (the same packets), and
 * each key keeps its fastest budget and encode times, as the model's. */
static int run_stream(const struct score_take *t, const struct keyrun *r, int b, int c, int passes, fk_ctx *ctx,
                      score_view *sv, struct acc *a, struct f4d_err *err)
{
    int rc = -1;
    codec_enc *enc = NULL, *te = NULL;
    double *kb = malloc(4 * (size_t)r->T * sizeof *kb); /* per key: budget wall, CPU; encode wall, CPU */
    display_player *pl = NULL;
    struct splat_frame pf = {0};
    const size_t n = r->n;
    size_t wsb = budget_scratch_bytes(n);
    void *ws = malloc(wsb);
    uint32_t *origin = malloc(n * sizeof *origin);
    int32_t *pix[2] = {malloc(n * sizeof(int32_t)), malloc(n * sizeof(int32_t))}, *match = malloc(n * sizeof(int32_t));
    size_t cap = codec_packet_bound(n);
    uint8_t *pkt = malloc(cap);
    if (!ws || !origin || !pix[0] || !pix[1] || !match || !pkt || !kb) {
        f4d_fail(err, F4D_ENOMEM, "report: out of memory");
        goto done;
    }
    for (int i = 0; i < 4 * r->T; i++)
        kb[i] = INFINITY;
    if (splat_frame_reserve(&pf, n, 1, err) < 0 || report_encoder_new(n, codec_level(c), &enc, err) < 0)
        goto done;
    /* lookups in the model's cameras, as f4d-display with the daemon's --rig-json */
    if (display_player_new(ctx, &r->rigs[0], r->motion ? INTERP_FUSED : INTERP_NEAREST, n, &pl, err) < 0)
        goto done;
    size_t len;
    struct codec_packet cp;
    if (codec_enc_stream_header(enc, 0, pkt, cap, &len) < 0 || codec_packet_parse(pkt, len, &cp, err) < 0 ||
        display_player_push(pl, &cp) < 0) {
        f4d_fail(err, F4D_EINVAL, "report: stream header: %s", codec_enc_error(enc));
        goto done;
    }
    struct budget_config bc = budget_level(b);
    const double key_us = 1e6 / t->fps;
    struct splat_camera cam0;
    score_eval_camera(t, 0, &cam0);
    for (int pass = 0; pass <= passes; pass++) {
        const bool timing = pass < passes; /* a timing pass: budget + encoder only */
        codec_enc *ce = enc;
        if (timing) {
            codec_enc_free(te);
            te = NULL;
            if (report_encoder_new(n, codec_level(c), &te, err) < 0)
                goto done;
            if (codec_enc_stream_header(te, 0, pkt, cap, &len) < 0) {
                f4d_fail(err, F4D_EINVAL, "report: stream header: %s", codec_enc_error(te));
                goto done;
            }
            ce = te;
        }
        int cur = 0;
        for (int k = 0; k < r->T; k++) {
            const struct splat_frame *kf = &r->keys[k];
            const int32_t *mt = NULL;
            double t0 = now_ms(), c0 = cpu_ms();
            if (b > 0) { /* the daemon's scene budget; matches through the pixel origin (run_stages.c) */
                if (budget_prune_origin_ws(kf, &r->rigs[k], &bc, ws, wsb, &pf, origin, NULL, err) < 0)
                    goto done;
                int32_t *prev = pix[cur], *next = pix[1 - cur];
                for (size_t i = 0; i < n; i++)
                    next[i] = -1;
                for (size_t j = 0; j < pf.count; j++) {
                    next[origin[j]] = (int32_t)j;
                    match[j] = k > 0 ? prev[origin[j]] : -1;
                }
                cur = 1 - cur;
                kf = &pf;
                mt = k > 0 ? match : NULL;
            }
            double t1 = now_ms(), c1 = cpu_ms();
            uint64_t tus = (uint64_t)(k * key_us + 0.5);
            int e = codec_enc_key(ce, kf, tus, k == 0 ? CODEC_KEY_INTRA : CODEC_KEY_AUTO, mt, pkt, cap, &len);
            double t2 = now_ms(), c2 = cpu_ms();
            if (e < 0) {
                f4d_fail(err, e, "report: encoder: %s", codec_enc_error(ce));
                goto done;
            }
            double *kk = &kb[4 * k];
            kk[0] = fmin(kk[0], t1 - t0);
            kk[1] = fmin(kk[1], c1 - c0);
            kk[2] = fmin(kk[2], t2 - t1);
            kk[3] = fmin(kk[3], c2 - c1);
            if (timing)
                continue;
            a->bytes += (double)len;
            a->bits_s += 8.0 * (double)len * t->fps;
            a->gauss += (double)kf->count;
            if (codec_packet_parse(pkt, len, &cp, err) < 0)
                goto done;
            double d0 = display_player_get_stats(pl)->decode_ms;
            if ((e = display_player_push(pl, &cp)) != 1) {
                f4d_fail(err, F4D_EINVAL, "report: the player did not decode key %d: %s", k,
                         e < 0 ? display_player_error(pl) : "skipped");
                goto done;
            }
            a->dec_ms += display_player_get_stats(pl)->decode_ms - d0;
            const struct splat_frame *df;
            double p, s;
            if (k > 0) { /* a displayed frame between the keys: interpolation + one render */
                uint64_t mid = (uint64_t)((k - 0.5) * key_us + 0.5), q1 = (uint64_t)((k - 0.75) * key_us + 0.5);
                /* the first frame of a key pair also finds the pair's partners (the
                 * lookups, once per key): timed apart from the per-frame cost */
                double l0 = now_ms();
                if (display_player_frame(pl, q1, &cam0, &df) < 0) {
                    f4d_fail(err, F4D_EINVAL, "report: display: %s", display_player_error(pl));
                    goto done;
                }
                a->lookup_ms += now_ms() - l0;
                double f0 = now_ms();
                if (display_player_frame(pl, mid, &cam0, &df) < 0) {
                    f4d_fail(err, F4D_EINVAL, "report: display: %s", display_player_error(pl));
                    goto done;
                }
                if (score_render(sv, &cam0, df, err) < 0)
                    goto done;
                a->disp_ms += now_ms() - f0;
                a->frames++;
                if (t->mid) {
                    if (score_novel_time(sv, df, k - 1, &p, &s, err) < 0)
                        goto done;
                    a->nt_psnr += p * t->E;
                    a->nt_ssim += s * t->E;
                    a->nt_n += (size_t)t->E;
                }
            }
            if (display_player_frame(pl, tus, &cam0, &df) < 0) {
                f4d_fail(err, F4D_EINVAL, "report: display: %s", display_player_error(pl));
                goto done;
            }
            if (score_novel_view(sv, df, k, &p, &s, err) < 0)
                goto done;
            a->nv_psnr += p * t->E;
            a->nv_ssim += s * t->E;
            a->nv_n += (size_t)t->E;
        }
    }
    for (int k = 0; k < r->T; k++) {
        a->budget_ms += kb[4 * k];
        a->budget_cpu_ms += kb[4 * k + 1];
        a->enc_ms += kb[4 * k + 2];
        a->enc_cpu_ms += kb[4 * k + 3];
    }
    rc = 0;
done:
    display_player_free(pl);
    codec_enc_free(enc);
    codec_enc_free(te);
    free(kb);
    splat_frame_free(&pf);
    free(ws);
    free(origin);
    free(pix[0]);
    free(pix[1]);
    free(match);
    free(pkt);
    return rc;
}

static double ratio(double s, size_t n) { return n ? s / (double)n : NAN; }

static void cpu_model(char *buf, size_t cap)
{
    snprintf(buf, cap, "unknown CPU");
    FILE *f = fopen("/proc/cpuinfo", "r");
    if (!f)
        return;
    char line[512];
    while (fgets(line, sizeof line, f)) {
        if (!strncmp(line, "model name", 10)) {
            char *c = strchr(line, ':');
            if (c) {
                c++;
                while (*c == ' ' || *c == '\t')
                    c++;
                c[strcspn(c, "\n")] = '\0';
                snprintf(buf, cap, "%s", c);
            }
            break;
        }
    }
    fclose(f);
}

/* Non-dominated in (key_hz up, nv_psnr up); points without a PSNR are never on it. */
static void pareto(struct point *pt, int n)
{
    for (int i = 0; i < n; i++) {
        pt[i].front = isfinite(pt[i].nv_psnr) && isfinite(pt[i].key_hz);
        for (int j = 0; j < n && pt[i].front; j++) {
            if (j == i || !isfinite(pt[j].nv_psnr))
                continue;
            if (pt[j].key_hz >= pt[i].key_hz && pt[j].nv_psnr >= pt[i].nv_psnr &&
                (pt[j].key_hz > pt[i].key_hz || pt[j].nv_psnr > pt[i].nv_psnr))
                pt[i].front = false;
        }
    }
}

static cJSON *num(double v) { return isfinite(v) ? cJSON_CreateNumber(v) : cJSON_CreateNull(); }

static void label(const struct point *p, char *buf, size_t cap)
{
    snprintf(buf, cap, "%s %dx%d %s motion:%s budget:%s codec:%s", prec_name[p->p], p->w, p->h, tok_name[p->t],
             mot_name[p->m], bud_name[p->b], cod_name[p->c]);
}

static int usage(void)
{
    fprintf(stderr, "usage: forge4d report [--quick] -o DIR --take TAKE [--take TAKE ...] [--weights W]\n"
                    "                      [--clock cpu|wall] [--threads N] [--keys N] [--reps N]\n"
                    "                      [--precision L] [--size L] [--tokens L] [--motion L] [--budget L] [--codec L]\n"
                    "  TAKE: a venue take with ground truth (tools/f4d-scene venue --seed S -o TAKE, or the\n"
                    "        test split of tools/train/gen_data.py); --quick: a reduced grid on the first\n"
                    "        3 keys (CI)\n"
                    "  --clock cpu (default): time per key = the key path's thread CPU time, --threads 1;\n"
                    "        wall: monotonic time (a quiet machine; any --threads)\n"
                    "  L: comma-separated values of one axis of the grid (default: every value):\n"
                    "        precision f32,f16,int8  size 1,7/8,3/4,5/8,1/2 (of the take's side)\n"
                    "        tokens all,fg  motion on,off  budget none,default,coarse  codec compact,low,medium,high\n");
    return 2;
}

/* "a,b" into sel over names (every entry false first); -1 naming the bad value. */
static int parse_axis(const char *opt, const char *v, const char *const *names, int n, bool *sel)
{
    for (int i = 0; i < n; i++)
        sel[i] = false;
    for (const char *p = v; *p;) {
        size_t len = strcspn(p, ",");
        int hit = -1;
        for (int i = 0; i < n; i++)
            if (strlen(names[i]) == len && !strncmp(p, names[i], len))
                hit = i;
        if (hit < 0) {
            fprintf(stderr, "forge4d report: %s: unknown value \"%.*s\" (one of", opt, (int)len, p);
            for (int i = 0; i < n; i++)
                fprintf(stderr, "%s %s", i ? "," : "", names[i]);
            fprintf(stderr, ")\n");
            return -1;
        }
        sel[hit] = true;
        p += len;
        if (*p == ',')
            p++;
    }
    return 0;
}

static int mkdir_p(const char *dir, struct f4d_err *err)
{
    char tmp[1024];
    if (snprintf(tmp, sizeof tmp, "%s", dir) >= (int)sizeof tmp)
        return f4d_fail(err, F4D_ERANGE, "report: output folder name too long");
    for (char *p = tmp + 1; *p; p++)
        if (*p == '/') {
            *p = '\0';
            if (mkdir(tmp, 0777) != 0 && errno != EEXIST)
                return f4d_fail(err, F4D_EIO, "report: cannot create %s: %s", tmp, strerror(errno));
            *p = '/';
        }
    if (mkdir(tmp, 0777) != 0 && errno != EEXIST)
        return f4d_fail(err, F4D_EIO, "report: cannot create %s: %s", tmp, strerror(errno));
    return 0;
}

static int write_outputs(const char *dir, struct point *pt, int np, int base, const struct score_take *takes,
                         int nt, const char *weights, bool motion, bool quick, bool wall, int threads, int keys,
                         int reps, struct f4d_err *err);

int forge4d_report_main(int argc, char **argv, volatile sig_atomic_t *stop)
{
    const char *out = NULL, *weights = NULL, *take_dirs[TAKES_MAX];
    int ntakes = 0, threads = -1, keys = 0, reps = 0;
    bool quick = false, wall = false, picked[6] = {false};
    struct grid pick;
    memset(&pick, 0, sizeof pick);
    for (int i = 0; i < argc; i++) {
        const char *a = argv[i], *v = i + 1 < argc ? argv[i + 1] : NULL;
        if (!strcmp(a, "--quick")) quick = true;
        else if (!strcmp(a, "--clock") && v && (!strcmp(v, "cpu") || !strcmp(v, "wall"))) wall = !strcmp(v, "wall"), i++;
        else if (!strcmp(a, "--precision") && v) {
            if (parse_axis(a, v, prec_name, NPREC, pick.prec) < 0) return 2;
            picked[0] = true, i++;
        } else if (!strcmp(a, "--size") && v) {
            if (parse_axis(a, v, scale_name, NSCALE, pick.scale) < 0) return 2;
            picked[1] = true, i++;
        } else if (!strcmp(a, "--tokens") && v) {
            if (parse_axis(a, v, tok_name, NTOK, pick.tok) < 0) return 2;
            picked[2] = true, i++;
        } else if (!strcmp(a, "--motion") && v) {
            if (parse_axis(a, v, mot_name, NMOT, pick.mot) < 0) return 2;
            picked[5] = true, i++;
        } else if (!strcmp(a, "--budget") && v) {
            if (parse_axis(a, v, bud_name, NBUD, pick.bud) < 0) return 2;
            picked[3] = true, i++;
        } else if (!strcmp(a, "--codec") && v) {
            if (parse_axis(a, v, cod_name, NCOD, pick.cod) < 0) return 2;
            picked[4] = true, i++;
        }
        else if (!strcmp(a, "-h") || !strcmp(a, "--help")) return usage(), 0;
        else if (!strcmp(a, "-o") && v) out = v, i++;
        else if (!strcmp(a, "--weights") && v) weights = v, i++;
        else if (!strcmp(a, "--take") && v) {
            if (ntakes == TAKES_MAX) {
                fprintf(stderr, "forge4d report: at most %d takes\n", TAKES_MAX);
                return 2;
            }
            take_dirs[ntakes++] = v, i++;
        } else if ((!strcmp(a, "--threads") || !strcmp(a, "--keys") || !strcmp(a, "--reps")) && v) {
            char *end;
            long x = strtol(v, &end, 10);
            if (*end || x < 0 || x > 1024 || end == v) {
                fprintf(stderr, "forge4d report: %s wants a number >= 0, got \"%s\"\n", a, v);
                return 2;
            }
            *(!strcmp(a, "--threads") ? &threads : !strcmp(a, "--keys") ? &keys : &reps) = (int)x;
            i++;
        } else {
            fprintf(stderr, "forge4d report: unknown or incomplete option \"%s\"\n", a);
            return usage();
        }
    }
    if (!out) {
        fprintf(stderr, "forge4d report: -o DIR is required (where report.md, report.json and the plots go)\n");
        return usage();
    }
    if (!ntakes) {
        fprintf(stderr, "forge4d report: no take given: pass --take DIR, a venue take with ground truth "
                        "(tools/f4d-scene venue --seed 300000 -o DIR, or a test take of tools/train/gen_data.py)\n");
        return 2;
    }
    if (threads < 0)
        threads = wall ? 0 : 1;
    if (!wall && threads != 1) {
        fprintf(stderr, "forge4d report: --clock cpu times the key path on one thread: use --threads 1, or "
                        "--clock wall for %d threads (the kernel pool spins while it waits, and CPU time would "
                        "count the spin)\n", threads);
        return 2;
    }
    if (quick && !keys)
        keys = 3;
    if (!reps) /* the timing passes cost model steps only: cheap beside the stream and the scores */
        reps = quick ? 1 : 5;
    /* the budget and the encoder run once per stream setting: min(reps, 3) passes */
    const int sreps = reps < 3 ? reps : 3;
    struct grid g;
    memset(&g, 0, sizeof g);
    for (int i = 0; i < NPREC; i++) g.prec[i] = picked[0] ? pick.prec[i] : !quick || i != 1;
    for (int i = 0; i < NSCALE; i++) g.scale[i] = picked[1] ? pick.scale[i] : !quick || i == 0 || i == NSCALE - 1;
    for (int i = 0; i < NTOK; i++) g.tok[i] = picked[2] ? pick.tok[i] : true;
    for (int i = 0; i < NMOT; i++) g.mot[i] = picked[5] ? pick.mot[i] : true;
    for (int i = 0; i < NBUD; i++) g.bud[i] = picked[3] ? pick.bud[i] : !quick || i != 0;
    for (int i = 0; i < NCOD; i++) g.cod[i] = picked[4] ? pick.cod[i] : !quick || i == 0 || i == 2;
    /* every ratio is against the baseline: it must be in the grid */
    if (!g.prec[0] || !g.scale[0] || !g.tok[0] || !g.mot[0] || !g.bud[1] || !g.cod[2]) {
        fprintf(stderr, "forge4d report: the grid must hold the baseline (precision f32, size 1, tokens all, "
                        "motion on, budget default, codec medium): every speed and PSNR is a ratio or difference to it\n");
        return 2;
    }
    struct f4d_err err = {0};
    struct score_take *takes = calloc((size_t)ntakes, sizeof *takes);
    const int NP = NPREC * NSCALE * NTOK * NMOT * NBUD * NCOD;
    struct acc *acc = calloc((size_t)NP, sizeof *acc);
    struct point *pt = calloc((size_t)NP, sizeof *pt);
    fk_ctx *sctx = NULL;
    /* [take][precision][size][tokens][motion][key][wall, cpu, process cpu]: each key's fastest model step of the passes */
    double *best = NULL, *kt = NULL;
    int kmax = 0;
    int status = 1, np = 0, base = -1;
    bool motion = false;
    if (!takes || !acc || !pt) {
        fprintf(stderr, "forge4d report: out of memory\n");
        goto done;
    }
    for (int i = 0; i < ntakes; i++)
        if (score_take_load(take_dirs[i], &takes[i], &err) < 0 ||
            (!takes[i].E && f4d_fail(&err, F4D_EFORMAT, "take %s: no held-out cameras (eval_rgb.npy; venue --eval 0): "
                                     "the report scores novel views", take_dirs[i]) < 0)) {
            fprintf(stderr, "forge4d report: %s\n", err.msg);
            goto done;
        }
    if (mkdir_p(out, &err) < 0) {
        fprintf(stderr, "forge4d report: %s\n", err.msg);
        goto done;
    }
    if (fk_ctx_new(&(struct fk_ctx_config){.isa = FK_ISA_AUTO, .threads = threads}, &sctx) != F4D_OK) {
        fprintf(stderr, "forge4d report: cannot create the kernel context\n");
        goto done;
    }
    const int patch = 14; /* checked against the weights by run_model */
    double t_start = now_ms();
    /* Speed is best of reps: reps - 1 timing passes over every take and model
     * configuration first (the keys are dropped), then the scored pass; each
     * key keeps its fastest pass (spread over time on a shared machine: a
     * slow phase then costs one key of one pass, not the whole pass). The work
     * of a key is the same in every pass (same inputs, same keep-lists). */
    for (int ti = 0; ti < ntakes; ti++) {
        int K = keys && keys < takes[ti].T ? keys : takes[ti].T;
        kmax = K > kmax ? K : kmax;
    }
    const size_t nbest = 3 * (size_t)ntakes * NPREC * NSCALE * NTOK * NMOT * (size_t)kmax;
    best = malloc(nbest * sizeof *best);
    kt = malloc(3 * (size_t)kmax * sizeof *kt);
    if (!best || !kt) {
        fprintf(stderr, "forge4d report: out of memory\n");
        goto done;
    }
    for (size_t i = 0; i < nbest; i++)
        best[i] = INFINITY;
#define BEST(ti, p, s, tk, mo) \
    (&best[3 * (size_t)kmax * (((((ti) * NPREC + (p)) * NSCALE + (s)) * NTOK + (tk)) * NMOT + (mo))])
    for (int rep = 0; rep + 1 < reps; rep++)
        for (int ti = 0; ti < ntakes; ti++)
            for (int p = 0; p < NPREC; p++) for (int s = 0; s < NSCALE; s++) for (int tk = 0; tk < NTOK; tk++)
            for (int mo = 0; mo < NMOT; mo++) {
                if (!g.prec[p] || !g.scale[s] || !g.tok[tk] || !g.mot[mo])
                    continue;
                const struct score_take *t = &takes[ti];
                int K = keys && keys < t->T ? keys : t->T, h, w;
                input_size(t, s, patch, &h, &w);
                char wbuf[F4D_WEIGHTS_PATH_MAX];
                const char *wp;
                struct acc am = {0};
                struct keyrun r = {0};
                if (*stop || weights_for(weights, p, wbuf, sizeof wbuf, &wp, &err) < 0 ||
                    run_model(t, K, wp, prec_type[p], h, w, tk, mo == 1, threads, sctx, &r, &am, kt, &err) < 0) {
                    fprintf(stderr, "forge4d report: take %s, %s %dx%d %s motion %s: %s\n", t->dir, prec_name[p], w,
                            h, tok_name[tk], mot_name[mo], *stop ? "interrupted" : err.msg);
                    model_run_free(&r);
                    goto done;
                }
                model_run_free(&r);
                double *b = BEST(ti, p, s, tk, mo);
                for (int i = 0; i < 3 * K; i++)
                    b[i] = fmin(b[i], kt[i]);
                fprintf(stderr, "[report] timing pass %d/%d, take %d/%d: %s %dx%d %s motion %s: model %.1f ms/key "
                        "wall, %.1f ms CPU\n", rep + 1, reps - 1, ti + 1, ntakes, prec_name[p], w, h, tok_name[tk],
                        mot_name[mo], am.model_ms / K, am.model_cpu_ms / K);
            }
    for (int ti = 0; ti < ntakes; ti++) {
        const struct score_take *t = &takes[ti];
        int K = keys && keys < t->T ? keys : t->T;
        score_view *sv = NULL;
        if (score_view_new(sctx, t, &sv, &err) < 0) {
            fprintf(stderr, "forge4d report: %s\n", err.msg);
            goto done;
        }
        for (int p = 0; p < NPREC; p++) for (int s = 0; s < NSCALE; s++) for (int tk = 0; tk < NTOK; tk++)
        for (int mo = 0; mo < NMOT; mo++) {
            if (!g.prec[p] || !g.scale[s] || !g.tok[tk] || !g.mot[mo])
                continue;
            if (*stop) {
                fprintf(stderr, "forge4d report: interrupted\n");
                score_view_free(sv);
                goto done;
            }
            int h, w;
            input_size(t, s, patch, &h, &w);
            char wbuf[F4D_WEIGHTS_PATH_MAX];
            const char *wp;
            if (weights_for(weights, p, wbuf, sizeof wbuf, &wp, &err) < 0) {
                fprintf(stderr, "forge4d report: no --weights and %s\n", err.msg);
                score_view_free(sv);
                goto done;
            }
            struct acc am = {0};
            struct keyrun r = {0};
            double m0 = now_ms();
            int rc = run_model(t, K, wp, prec_type[p], h, w, tk, mo == 1, threads, sctx, &r, &am, kt, &err);
            if (rc < 0) {
                fprintf(stderr, "forge4d report: take %s, %s %dx%d %s motion %s: %s\n", t->dir, prec_name[p], w, h,
                        tok_name[tk], mot_name[mo], err.msg);
                model_run_free(&r);
                score_view_free(sv);
                goto done;
            }
            motion |= r.motion;
            const double *bt = BEST(ti, p, s, tk, mo);
            am.model_ms = am.model_cpu_ms = am.model_pcpu_ms = 0;
            for (int k = 0; k < K; k++) {
                am.model_ms += fmin(kt[3 * k], bt[3 * k]);
                am.model_cpu_ms += fmin(kt[3 * k + 1], bt[3 * k + 1]);
                am.model_pcpu_ms += fmin(kt[3 * k + 2], bt[3 * k + 2]);
            }
            fprintf(stderr, "[report] take %d/%d %s: %s %dx%d %s motion %s: model %.1f ms/key wall, %.1f ms CPU "
                    "(best of %d), %.1f s\n", ti + 1, ntakes, t->dir, prec_name[p], w, h, tok_name[tk], mot_name[mo],
                    am.model_ms / K, am.model_cpu_ms / K, reps, (now_ms() - m0) * 1e-3);
            for (int b = 0; b < NBUD; b++) for (int c = 0; c < NCOD; c++) {
                if (!g.bud[b] || !g.cod[c])
                    continue;
                int idx = ((((p * NSCALE + s) * NTOK + tk) * NMOT + mo) * NBUD + b) * NCOD + c;
                struct acc *a = &acc[idx];
                /* the model's share is the same for every stream setting */
                a->model_ms += am.model_ms; a->model_cpu_ms += am.model_cpu_ms; a->keys += am.keys;
                a->model_pcpu_ms += am.model_pcpu_ms;
                a->pt += am.pt; a->pt_n += am.pt_n;
                a->rot += am.rot; a->trans += am.trans; a->cams += am.cams;
                a->mot += am.mot; a->mot_n += am.mot_n;
                a->tok_ran += am.tok_ran; a->tok_all += am.tok_all;
                a->h = h; a->w = w;
                if (run_stream(t, &r, b, c, sreps - 1, sctx, sv, a, &err) < 0) {
                    fprintf(stderr, "forge4d report: take %s, %s %dx%d %s motion %s budget %s codec %s: %s\n",
                            t->dir, prec_name[p], w, h, tok_name[tk], mot_name[mo], bud_name[b], cod_name[c], err.msg);
                    model_run_free(&r);
                    score_view_free(sv);
                    goto done;
                }
            }
            model_run_free(&r);
        }
        score_view_free(sv);
    }
    /* grid points, the baseline (f32, full size, all patches, the daemon's budget and codec level) */
    for (int p = 0; p < NPREC; p++) for (int s = 0; s < NSCALE; s++) for (int tk = 0; tk < NTOK; tk++)
    for (int mo = 0; mo < NMOT; mo++) for (int b = 0; b < NBUD; b++) for (int c = 0; c < NCOD; c++) {
        int idx = ((((p * NSCALE + s) * NTOK + tk) * NMOT + mo) * NBUD + b) * NCOD + c;
        const struct acc *a = &acc[idx];
        if (!a->keys)
            continue;
        struct point *q = &pt[np];
        q->p = p, q->s = s, q->t = tk, q->m = mo, q->b = b, q->c = c, q->h = a->h, q->w = a->w;
        q->model_ms = a->model_ms / a->keys;
        q->model_cpu_ms = a->model_cpu_ms / a->keys;
        q->model_pcpu_ms = a->model_pcpu_ms / a->keys;
        q->budget_ms = a->budget_ms / a->keys;
        q->budget_cpu_ms = a->budget_cpu_ms / a->keys;
        q->enc_ms = a->enc_ms / a->keys;
        q->enc_cpu_ms = a->enc_cpu_ms / a->keys;
        q->dec_ms = a->dec_ms / a->keys;
        q->key_wall_ms = q->model_ms + q->budget_ms + q->enc_ms;
        q->key_cpu_ms = q->model_cpu_ms + q->budget_cpu_ms + q->enc_cpu_ms;
        q->key_ms = wall ? q->key_wall_ms : q->key_cpu_ms;
        q->key_hz = 1e3 / q->key_ms;
        q->disp_ms = ratio(a->disp_ms, a->frames);
        q->lookup_ms = ratio(a->lookup_ms, a->frames);
        q->gauss = a->gauss / a->keys;
        q->bytes = a->bytes / a->keys;
        q->mbps = a->bits_s / a->keys * 1e-6;
        q->nv_psnr = ratio(a->nv_psnr, a->nv_n);
        q->nv_ssim = ratio(a->nv_ssim, a->nv_n);
        q->nt_psnr = ratio(a->nt_psnr, a->nt_n);
        q->nt_ssim = ratio(a->nt_ssim, a->nt_n);
        q->pt = ratio(a->pt, a->pt_n);
        q->rot = ratio(a->rot, a->cams);
        q->trans = ratio(a->trans, a->cams);
        q->mot = ratio(a->mot, a->mot_n);
        q->tok_frac = a->tok_all > 0 ? a->tok_ran / a->tok_all : NAN;
        if (p == 0 && s == 0 && tk == 0 && mo == 0 && b == 1 && c == 2)
            base = np;
        np++;
    }
    if (base < 0) {
        fprintf(stderr, "forge4d report: the grid has no baseline point\n");
        goto done;
    }
    for (int i = 0; i < np; i++) {
        pt[i].speedup = pt[base].key_ms / pt[i].key_ms;
        pt[i].dpsnr = pt[i].nv_psnr - pt[base].nv_psnr;
    }
    pareto(pt, np);
    fprintf(stderr, "[report] %d points in %.1f s\n", np, (now_ms() - t_start) * 1e-3);
    if (write_outputs(out, pt, np, base, takes, ntakes, weights ? weights : "(shipped)", motion, quick, wall,
                      threads, keys, reps, &err) < 0) {
        fprintf(stderr, "forge4d report: %s\n", err.msg);
        goto done;
    }
    fprintf(stderr, "[report] -> %s/report.md, report.json, pareto.png, bitrate.png, display.png\n", out);
    status = 0;
#undef BEST
done:
    if (takes)
        for (int i = 0; i < ntakes; i++)
            score_take_free(&takes[i]);
    free(takes);
    free(acc);
    free(pt);
    free(best);
    free(kt);
    fk_ctx_free(sctx);
    report_plot_done();
    return status;
}

/* ---- outputs ---- */

/* v with dec decimals (sign: always signed) and a suffix, n/a when not finite. */
static void md_num(FILE *f, double v, int dec, bool sign, const char *suffix)
{
    if (isfinite(v))
        fprintf(f, sign ? "%+.*f%s" : "%.*f%s", dec, v, suffix);
    else
        fprintf(f, "n/a");
}

static int write_plots(const char *dir, const struct point *pt, int np, int base, bool wall, struct f4d_err *err)
{
    double *x = malloc((size_t)np * sizeof *x), *y = malloc((size_t)np * sizeof *y);
    int *ser = malloc((size_t)np * sizeof *ser);
    bool *hol = malloc((size_t)np * sizeof *hol), *fr = malloc((size_t)np * sizeof *fr), *none = calloc((size_t)np, 1);
    int rc = -1;
    char path[1200];
    if (!x || !y || !ser || !hol || !fr || !none) {
        f4d_fail(err, F4D_ENOMEM, "report: out of memory");
        goto done;
    }
    for (int i = 0; i < np; i++) {
        x[i] = pt[i].key_hz;
        y[i] = pt[i].nv_psnr;
        ser[i] = pt[i].p;
        hol[i] = pt[i].t == 1;
        fr[i] = pt[i].front;
    }
    snprintf(path, sizeof path, "%s/pareto.png", dir);
    struct report_plot p = {.path = path, .title = "Speed vs novel-view PSNR (line: Pareto front)",
                            .xlabel = wall ? "key frames per second, wall (model + budget + encode)"
                                           : "key frames per CPU second, one thread (model + budget + encode)",
                            .ylabel = "novel-view PSNR (dB)", .n = np, .x = x, .y = y, .series = ser, .hollow = hol,
                            .front = fr, .log_x = true, .n_series = NPREC, .hollow_name = "foreground tokens",
                            .solid_name = "all patches", .mark = base, .mark_label = "f32 all patches"};
    for (int i = 0; i < NPREC; i++)
        p.series_name[i] = prec_name[i];
    if (report_plot_write(&p, err) < 0)
        goto done;
    for (int i = 0; i < np; i++) {
        x[i] = pt[i].mbps;
        ser[i] = pt[i].c;
        hol[i] = pt[i].b == 0;
    }
    snprintf(path, sizeof path, "%s/bitrate.png", dir);
    struct report_plot q = {.path = path, .title = "Bitrate vs novel-view PSNR (at the take's key rate)",
                            .xlabel = "Mbit/s", .ylabel = "novel-view PSNR (dB)", .n = np, .x = x, .y = y,
                            .series = ser, .hollow = hol, .front = none, .log_x = true, .n_series = NCOD,
                            .hollow_name = "no budget", .solid_name = "budget on", .mark = base,
                            .mark_label = "baseline"};
    for (int i = 0; i < NCOD; i++)
        q.series_name[i] = cod_name[i];
    if (report_plot_write(&q, err) < 0)
        goto done;
    for (int i = 0; i < np; i++) {
        x[i] = pt[i].disp_ms;
        y[i] = pt[i].nt_psnr;
        ser[i] = pt[i].b;
        hol[i] = pt[i].t == 1;
    }
    snprintf(path, sizeof path, "%s/display.png", dir);
    struct report_plot d = {.path = path, .title = "Displayed frame: time vs novel-time PSNR (mid times)",
                            .xlabel = "ms per displayed frame (interpolation + render)",
                            .ylabel = "novel-time PSNR (dB)", .n = np, .x = x, .y = y, .series = ser, .hollow = hol,
                            .front = none, .log_x = false, .n_series = NBUD, .hollow_name = "foreground tokens",
                            .solid_name = "all patches", .mark = base, .mark_label = "baseline"};
    for (int i = 0; i < NBUD; i++)
        d.series_name[i] = bud_name[i];
    if (report_plot_write(&d, err) < 0)
        goto done;
    rc = 0;
done:
    free(x); free(y); free(ser); free(hol); free(fr); free(none);
    return rc;
}

static int write_outputs(const char *dir, struct point *pt, int np, int base, const struct score_take *takes,
                         int nt, const char *weights, bool motion, bool quick, bool wall, int threads, int keys,
                         int reps, struct f4d_err *err)
{
    char cpu[256], path[1200], lb[256];
    cpu_model(cpu, sizeof cpu);
    long ncpu = sysconf(_SC_NPROCESSORS_ONLN);
    /* the goal: a front point >= 3x faster than the baseline within 1 dB of its PSNR */
    int goal = -1, near = -1;
    for (int i = 0; i < np; i++) {
        if (!pt[i].front)
            continue;
        if (pt[i].dpsnr >= -1.0 && (near < 0 || pt[i].speedup > pt[near].speedup))
            near = i;
        if (pt[i].speedup >= 3.0 && pt[i].dpsnr >= -1.0 && (goal < 0 || pt[i].speedup > pt[goal].speedup))
            goal = i;
    }
    /* motion off trades the mid times (nearest key) for speed: the fastest
     * point within 1 dB that keeps the motion is named beside it */
    int near_on = -1;
    for (int i = 0; i < np; i++)
        if (pt[i].m == 0 && pt[i].dpsnr >= -1.0 && (near_on < 0 || pt[i].speedup > pt[near_on].speedup))
            near_on = i;
    /* report.json */
    cJSON *root = cJSON_CreateObject();
    if (!root)
        return f4d_fail(err, F4D_ENOMEM, "report: out of memory");
    cJSON_AddStringToObject(root, "cpu", cpu);
    cJSON_AddNumberToObject(root, "cpus_online", (double)ncpu);
    cJSON_AddNumberToObject(root, "threads", threads);
    cJSON_AddStringToObject(root, "clock", wall ? "wall" : "cpu");
    double la[3] = {NAN, NAN, NAN};
    FILE *lf = fopen("/proc/loadavg", "r");
    if (lf) { /* the load the run ended under: how far the wall figures were disturbed */
        if (fscanf(lf, "%lf %lf %lf", &la[0], &la[1], &la[2]) != 3)
            la[0] = la[1] = la[2] = NAN;
        fclose(lf);
    }
    cJSON_AddItemToObject(root, "loadavg_1min_at_end", num(la[0]));
    cJSON_AddNumberToObject(root, "reps", reps);
    cJSON_AddBoolToObject(root, "quick", quick);
    cJSON_AddStringToObject(root, "weights", weights);
    cJSON_AddBoolToObject(root, "motion", motion);
    cJSON_AddStringToObject(root, "speed_axis", "key_hz");
    cJSON_AddStringToObject(root, "quality_axis", "novel_view_psnr");
    cJSON *jt = cJSON_AddArrayToObject(root, "takes");
    for (int i = 0; i < nt; i++) {
        cJSON *o = cJSON_CreateObject();
        cJSON_AddStringToObject(o, "dir", takes[i].dir);
        cJSON_AddNumberToObject(o, "keys", keys && keys < takes[i].T ? keys : takes[i].T);
        cJSON_AddNumberToObject(o, "views", takes[i].V);
        cJSON_AddNumberToObject(o, "eval_views", takes[i].E);
        cJSON_AddNumberToObject(o, "width", takes[i].W);
        cJSON_AddNumberToObject(o, "height", takes[i].H);
        cJSON_AddNumberToObject(o, "fps", takes[i].fps);
        cJSON_AddBoolToObject(o, "background_plate", takes[i].background != NULL);
        cJSON_AddItemToArray(jt, o);
    }
    cJSON_AddNumberToObject(root, "baseline", base);
    cJSON *jp = cJSON_AddArrayToObject(root, "points"), *jf = cJSON_AddArrayToObject(root, "front");
    for (int i = 0; i < np; i++) {
        const struct point *q = &pt[i];
        cJSON *o = cJSON_CreateObject();
        cJSON_AddNumberToObject(o, "index", i);
        cJSON_AddStringToObject(o, "precision", prec_name[q->p]);
        cJSON_AddNumberToObject(o, "input_w", q->w);
        cJSON_AddNumberToObject(o, "input_h", q->h);
        cJSON_AddStringToObject(o, "tokens", tok_name[q->t]);
        cJSON_AddStringToObject(o, "motion", mot_name[q->m]);
        cJSON_AddStringToObject(o, "budget", bud_name[q->b]);
        cJSON_AddStringToObject(o, "codec", cod_name[q->c]);
        cJSON_AddItemToObject(o, "key_ms", num(q->key_ms));
        cJSON_AddItemToObject(o, "key_hz", num(q->key_hz));
        cJSON_AddItemToObject(o, "key_wall_ms", num(q->key_wall_ms));
        cJSON_AddItemToObject(o, "key_cpu_ms", num(q->key_cpu_ms));
        cJSON_AddItemToObject(o, "model_ms", num(q->model_ms));
        cJSON_AddItemToObject(o, "model_cpu_ms", num(q->model_cpu_ms));
        cJSON_AddItemToObject(o, "model_process_cpu_ms", num(q->model_pcpu_ms));
        cJSON_AddItemToObject(o, "budget_ms", num(q->budget_ms));
        cJSON_AddItemToObject(o, "budget_cpu_ms", num(q->budget_cpu_ms));
        cJSON_AddItemToObject(o, "encode_ms", num(q->enc_ms));
        cJSON_AddItemToObject(o, "encode_cpu_ms", num(q->enc_cpu_ms));
        cJSON_AddItemToObject(o, "decode_ms", num(q->dec_ms));
        cJSON_AddItemToObject(o, "display_frame_ms", num(q->disp_ms));
        cJSON_AddItemToObject(o, "display_pair_ms", num(q->lookup_ms));
        cJSON_AddItemToObject(o, "tokens_ran_fraction", num(q->tok_frac));
        cJSON_AddItemToObject(o, "gaussians_per_key", num(q->gauss));
        cJSON_AddItemToObject(o, "bytes_per_key", num(q->bytes));
        cJSON_AddItemToObject(o, "mbps_at_take_rate", num(q->mbps));
        cJSON_AddItemToObject(o, "novel_view_psnr", num(q->nv_psnr));
        cJSON_AddItemToObject(o, "novel_view_ssim", num(q->nv_ssim));
        cJSON_AddItemToObject(o, "novel_time_psnr", num(q->nt_psnr));
        cJSON_AddItemToObject(o, "novel_time_ssim", num(q->nt_ssim));
        cJSON_AddItemToObject(o, "point_dist_m", num(q->pt));
        cJSON_AddItemToObject(o, "rot_err_deg", num(q->rot));
        cJSON_AddItemToObject(o, "trans_err_m", num(q->trans));
        cJSON_AddItemToObject(o, "motion_epe_m", num(q->mot));
        cJSON_AddItemToObject(o, "speedup_vs_baseline", num(q->speedup));
        cJSON_AddItemToObject(o, "wall_speedup_vs_baseline", num(pt[base].key_wall_ms / q->key_wall_ms));
        cJSON_AddItemToObject(o, "cpu_speedup_vs_baseline", num(pt[base].key_cpu_ms / q->key_cpu_ms));
        cJSON_AddItemToObject(o, "dpsnr_vs_baseline_db", num(q->dpsnr));
        cJSON_AddBoolToObject(o, "on_front", q->front);
        cJSON_AddItemToArray(jp, o);
        if (q->front)
            cJSON_AddItemToArray(jf, cJSON_CreateNumber(i));
    }
    cJSON *jg = cJSON_AddObjectToObject(root, "goal");
    cJSON_AddStringToObject(jg, "text", "a Pareto point >= 3x faster than f32 all patches within 1 dB of its "
                                        "novel-view PSNR");
    cJSON_AddBoolToObject(jg, "met", goal >= 0);
    int gi = goal >= 0 ? goal : near;
    cJSON_AddItemToObject(jg, "point", gi >= 0 ? cJSON_CreateNumber(gi) : cJSON_CreateNull());
    cJSON_AddItemToObject(jg, "speedup", num(gi >= 0 ? pt[gi].speedup : NAN));
    cJSON_AddItemToObject(jg, "dpsnr_db", num(gi >= 0 ? pt[gi].dpsnr : NAN));
    cJSON_AddStringToObject(jg, "clock", wall ? "wall" : "cpu");
    /* the same point by both clocks (the key path: model + budget + encode) */
    cJSON_AddItemToObject(jg, "cpu_speedup", num(gi >= 0 ? pt[base].key_cpu_ms / pt[gi].key_cpu_ms : NAN));
    cJSON_AddItemToObject(jg, "wall_speedup", num(gi >= 0 ? pt[base].key_wall_ms / pt[gi].key_wall_ms : NAN));
    cJSON_AddItemToObject(jg, "dnt_psnr_db", num(gi >= 0 ? pt[gi].nt_psnr - pt[base].nt_psnr : NAN));
    cJSON_AddItemToObject(jg, "motion_on_point", near_on >= 0 ? cJSON_CreateNumber(near_on) : cJSON_CreateNull());
    cJSON_AddItemToObject(jg, "motion_on_speedup", num(near_on >= 0 ? pt[near_on].speedup : NAN));
    char *js = cJSON_Print(root);
    cJSON_Delete(root);
    if (!js)
        return f4d_fail(err, F4D_ENOMEM, "report: out of memory");
    snprintf(path, sizeof path, "%s/report.json", dir);
    FILE *f = fopen(path, "w");
    int bad = !f || fprintf(f, "%s\n", js) < 0;
    free(js);
    if (f && fclose(f) != 0)
        bad = 1;
    if (bad)
        return f4d_fail(err, F4D_EIO, "report: cannot write %s", path);

    /* report.md */
    snprintf(path, sizeof path, "%s/report.md", dir);
    f = fopen(path, "w");
    if (!f)
        return f4d_fail(err, F4D_EIO, "report: cannot create %s", path);
    fprintf(f, "# Forge4D speed vs error%s\n\n", quick ? " (quick grid)" : "");
    fprintf(f, "Machine: %s, %ld CPUs online, %d kernel threads (%s), load average %.2f at the end. Speeds are "
               "ratios inside this run (the machine may be shared); absolute times are loose.\n\n",
            cpu, ncpu, threads, threads ? "--threads" : "0 = all", la[0]);
    fprintf(f, "Weights: %s (%s). Takes:", weights, motion ? "with motion: Forge4D interpolation between keys"
                                                             : "no motion part: the display shows the nearest key");
    for (int i = 0; i < nt; i++)
        fprintf(f, "%s `%s` (%d keys, %d views, %d held-out, %dx%d%s)", i ? "," : "", takes[i].dir,
                keys && keys < takes[i].T ? keys : takes[i].T, takes[i].V, takes[i].E, takes[i].W, takes[i].H,
                takes[i].background ? ", background plate" : "");
    fprintf(f, ".\n\n");
    fprintf(f, "Time per key frame (the speed axis, clock `%s`) = model (sequence step incl. state / motion) + scene "
               "budget + encoder, per key, the model's share best of %d passes. %s "
               "Key CPU ms: the calling thread's CPU time (with --threads 1 the whole key path runs on it: its "
               "work, whatever else the machine runs); key wall ms: monotonic time (includes waiting for a shared "
               "core); both speedups are printed. Model process CPU ms: every thread (with more than one it counts "
               "the kernel pool's spin-waits). Display ms = the display's interpolation at a mid time + one render (CPU); pair ms = its lookups "
               "for a new key pair (once per key, in the first frame after it). PSNR: novel view = "
               "what the display shows at each key time, rendered at the held-out cameras; novel time = the "
               "same at the mid times. Point distance, camera and motion errors are the model's keys before the "
               "budget. Tokens `fg`: foreground patches (firmware/infer/foreground, margin %d; the first key "
               "runs all) learned from %s. Motion `off`: the daemon's --motion off (the model's motion head and motion "
               "blocks skipped; keys without motion, the display shows the nearest key: see novel time). Budget: `none` off, `default` the daemon's (budget_config_default), "
               "`coarse` 4x merge cell, 2x footprint, opacity 0.05. Bitrate at the take's key rate.\n\n",
            wall ? "wall" : "cpu", reps,
            wall ? "Wall time: trustworthy on an idle machine only."
                 : "CPU time of one kernel thread: what a key costs, robust to other jobs on the machine.",
            FG_MARGIN, takes[0].background ? "the background plate" : "the take's own keys (median; no empty plate)");
    if (goal >= 0) {
        label(&pt[goal], lb, sizeof lb);
        fprintf(f, "**Goal met**: front point %d (%s) is %.2fx faster (%s time per key) than f32 all patches "
                   "(point %d) at %+.2f dB novel-view PSNR (key CPU time %.2fx, wall %.2fx).\n\n", goal, lb,
                pt[goal].speedup, wall ? "wall" : "CPU", base, pt[goal].dpsnr,
                pt[base].key_cpu_ms / pt[goal].key_cpu_ms, pt[base].key_wall_ms / pt[goal].key_wall_ms);
    } else {
        fprintf(f, "**Goal not met**: no front point is >= 3x faster than f32 all patches (point %d) within 1 dB.",
                base);
        if (near >= 0) {
            label(&pt[near], lb, sizeof lb);
            fprintf(f, " Fastest front point within 1 dB: %d (%s), %.2fx (%s) at %+.2f dB (key CPU time %.2fx, "
                       "wall %.2fx).", near, lb, pt[near].speedup, wall ? "wall" : "CPU", pt[near].dpsnr,
                    pt[base].key_cpu_ms / pt[near].key_cpu_ms, pt[base].key_wall_ms / pt[near].key_wall_ms);
        }
        fprintf(f, "\n\n");
    }
    if (gi >= 0 && isfinite(pt[gi].nt_psnr) && isfinite(pt[base].nt_psnr))
        fprintf(f, "That point's novel-time PSNR: %+.2f dB against the baseline's.", pt[gi].nt_psnr - pt[base].nt_psnr);
    if (gi >= 0 && pt[gi].m != 0 && near_on >= 0) {
        label(&pt[near_on], lb, sizeof lb);
        fprintf(f, " With motion on, the fastest point within 1 dB: %d (%s), %.2fx at %+.2f dB.", near_on, lb,
                pt[near_on].speedup, pt[near_on].dpsnr);
    }
    fprintf(f, "\n\n");
    fprintf(f, "Pareto front (key frames/s up, novel-view PSNR up): ");
    int first = 1;
    for (int i = 0; i < np; i++)
        if (pt[i].front) {
            fprintf(f, "%s%d", first ? "" : ", ", i);
            first = 0;
        }
    fprintf(f, " (marked * below).\n\n");
    fprintf(f, "| # | precision | input | tokens | motion | budget | codec | key ms (%s) | speedup | key CPU ms | key wall ms | "
               "wall speedup | model process CPU ms | display ms | pair ms | tokens ran | "
               "Gaussians/key | kB/key | Mbit/s | NV PSNR | dPSNR | NV SSIM | NT PSNR | point dist (m) | "
               "rot (deg) | trans (m) | motion EPE (m) | front |\n", wall ? "wall" : "CPU");
    fprintf(f, "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"
               "---|\n");
    for (int i = 0; i < np; i++) {
        const struct point *q = &pt[i];
        fprintf(f, "| %d%s | %s | %dx%d | %s | %s | %s | %s | ", i, i == base ? " (base)" : "", prec_name[q->p], q->w,
                q->h, tok_name[q->t], mot_name[q->m], bud_name[q->b], cod_name[q->c]);
        md_num(f, q->key_ms, 1, false, ""); fputs(" | ", f);
        md_num(f, q->speedup, 2, false, "x"); fputs(" | ", f);
        md_num(f, q->key_cpu_ms, 1, false, ""); fputs(" | ", f);
        md_num(f, q->key_wall_ms, 1, false, ""); fputs(" | ", f);
        md_num(f, pt[base].key_wall_ms / q->key_wall_ms, 2, false, "x"); fputs(" | ", f);
        md_num(f, q->model_pcpu_ms, 1, false, ""); fputs(" | ", f);
        md_num(f, q->disp_ms, 2, false, ""); fputs(" | ", f);
        md_num(f, q->lookup_ms, 2, false, ""); fputs(" | ", f);
        md_num(f, 100.0 * q->tok_frac, 0, false, " %"); fputs(" | ", f);
        md_num(f, q->gauss, 0, false, ""); fputs(" | ", f);
        md_num(f, q->bytes / 1e3, 1, false, ""); fputs(" | ", f);
        md_num(f, q->mbps, 2, false, ""); fputs(" | ", f);
        md_num(f, q->nv_psnr, 2, false, ""); fputs(" | ", f);
        md_num(f, q->dpsnr, 2, true, ""); fputs(" | ", f);
        md_num(f, q->nv_ssim, 4, false, ""); fputs(" | ", f);
        md_num(f, q->nt_psnr, 2, false, ""); fputs(" | ", f);
        md_num(f, q->pt, 4, false, ""); fputs(" | ", f);
        md_num(f, q->rot, 2, false, ""); fputs(" | ", f);
        md_num(f, q->trans, 4, false, ""); fputs(" | ", f);
        md_num(f, q->mot, 4, false, ""); fputs(" | ", f);
        fprintf(f, "%s |\n", q->front ? "*" : "");
    }
    fprintf(f, "\nPlots: `pareto.png` (speed vs novel-view PSNR, colour = precision, open = foreground tokens), "
               "`bitrate.png` (colour = codec level, open = no budget), `display.png` (displayed-frame time vs "
               "novel-time PSNR, colour = budget). JSON with every figure: `report.json`.\n");
    if (fclose(f) != 0)
        return f4d_fail(err, F4D_EIO, "report: cannot write %s", path);
    return write_plots(dir, pt, np, base, wall, err);
}
