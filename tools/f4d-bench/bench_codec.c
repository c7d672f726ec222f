/* bench_codec.c - f4d-bench codec: rate-distortion of the stream codec.
 *
 * Per synthetic preset (key frames with exact motion from firmware/synth at
 * key rates 5, 10 and 15 Hz over --seconds, one intra key then predicted
 * keys) and quality level: bytes per Gaussian of the intra key, of the
 * predicted keys and of the motion planes in them, the stream's Mbit/s (the
 * display interpolates to 30 fps, so the rate is keys x bytes), render PSNR of
 * the decoded keys against the uncompressed keys at the rig cameras, and at
 * the mid times (both sides moved by half their forward motion), encode and
 * decode ms per key; beside SPZ (our exporter, v4) of the same keys. Mbit/s
 * counts one intra key per run (--seconds of keys); the predicted-only rate
 * is the stream between intra keys.
 * ../shared/data/splats/donut.ply (static, 4 cameras around it) when present:
 * intra per level, a repeated key as a predicted key, the key as a still
 * (Morton-reordered) key ("donut-still"), SPZ.
 * --stream-order / --effort NAME: the encoder's stream order
 * (codec_enc_set_reorder) and effort (codec_enc_set_effort) for every row.
 * --decode-reps R: each row's packets decoded again R times by the same
 * decoder; the row's dec figures are then the best of the R runs' thread
 * CPU ms (intra key; mean predicted key), the decoder alone.
 * PSNR: float renders (not 8-bit), mean over the cameras and keys, 518x518,
 * 100 dB where identical. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#include "bench.h"
#include "f4d_codec.h"
#include "scene.h"

#define W 518
#define H 518
#define NP ((size_t)W * (size_t)H)

struct crow {
    char preset[24];
    size_t gaussians;
    int key_rate, quality, keys;
    double intra_bpg, pred_bpg, motion_bpg, unchanged, mbps, psnr_key, psnr_key_min, psnr_mid;
    double enc_intra_ms, enc_pred_ms, dec_intra_ms, dec_pred_ms;
    double chan_bpg[CODEC_CHANNELS], index_bpg; /* predicted keys, by channel */
    double ichan_bpg[CODEC_CHANNELS];           /* the intra key, by channel */
};
struct srow {
    char preset[24];
    size_t gaussians;
    double bpg, psnr, enc_ms, dec_ms;
};

struct ctx {
    int reorder, effort; /* encoder settings of every row */
    int dec_reps;        /* --decode-reps */
    splat_renderer *r;
    const float *bg;
    float *a, *b;
};

static double psnr_of(struct ctx *c, const struct splat_camera *cam, const struct splat_frame *x,
                      const struct splat_frame *y)
{
    struct splat_render_out oa = { .rgb = c->a }, ob = { .rgb = c->b };
    if (splat_render(c->r, cam, x, c->bg, &oa) < 0 || splat_render(c->r, cam, y, c->bg, &ob) < 0)
        return NAN;
    double p = splat_psnr(c->a, c->b, W, H, 3);
    return isfinite(p) ? (p > 100 ? 100 : p) : 100.0;
}

static double rig_psnr(struct ctx *c, const struct splat_rig *rig, const struct splat_frame *x,
                       const struct splat_frame *y)
{
    double s = 0;
    for (int k = 0; k < rig->count; k++)
        s += psnr_of(c, &rig->cams[k], x, y);
    return s / rig->count;
}

/* dst = src moved by half its forward motion (no motion: a copy). */
static void mid(const struct splat_frame *src, struct splat_frame *dst)
{
    splat_frame_copy(dst, src, NULL);
    if (src->motion_fwd)
        for (size_t i = 0; i < 3 * src->count; i++)
            dst->pos[i] += 0.5f * src->motion_fwd[i];
}

static double thread_ms(void) { return 1e3 * bench_thread_cpu_s(); }

/* The packets pk[0..len) (one key after another) decoded reps times by d:
 * the best run's intra ms and mean predicted ms (thread CPU time). */
static int redecode(codec_dec *d, const uint8_t *pk, size_t len, int reps, double *intra_ms, double *pred_ms)
{
    *intra_ms = *pred_ms = INFINITY;
    for (int r = 0; r < reps; r++) {
        double ti = 0, tp = 0;
        int np = 0;
        for (size_t off = 0; off < len;) {
            struct codec_packet p;
            struct f4d_err err = { 0 };
            if (codec_packet_parse(pk + off, len - off, &p, &err) < 0) {
                fprintf(stderr, "f4d-bench codec: %s\n", err.msg);
                return -1;
            }
            double t0 = thread_ms();
            int rc = codec_dec_packet(d, &p);
            double t1 = thread_ms();
            if (rc != 1) {
                fprintf(stderr, "f4d-bench codec: decode: %s\n", codec_dec_error(d));
                return -1;
            }
            if (p.type == CODEC_PKT_INTRA)
                ti += t1 - t0;
            else {
                tp += t1 - t0;
                np++;
            }
            off += CODEC_PACKET_HEADER + p.payload_len;
        }
        *intra_ms = ti < *intra_ms ? ti : *intra_ms;
        if (np)
            *pred_ms = tp / np < *pred_ms ? tp / np : *pred_ms;
    }
    return 0;
}

/* Encodes + decodes keys[0..nk) at one level; fills the row. */
/* still: keys[0] alone as a CODEC_KEY_STILL key (reordered; no predicted keys). */
static int run_level(struct ctx *c, const struct splat_rig *rig, struct splat_frame *keys, int nk, int q,
                     int do_psnr, int still, struct crow *row)
{
    size_t cap = 0;
    for (int k = 0; k < nk; k++)
        cap = keys[k].count > cap ? keys[k].count : cap;
    codec_enc *e;
    codec_dec *d;
    struct f4d_err err = { 0 };
    if (codec_enc_new(cap, (enum codec_quality)q, &e, &err) < 0 || codec_dec_new(cap, &d, &err) < 0 ||
        codec_enc_set_reorder(e, c->reorder) < 0 || codec_enc_set_effort(e, c->effort) < 0) {
        fprintf(stderr, "f4d-bench codec: %s\n", err.msg[0] ? err.msg : codec_enc_error(e));
        return -1;
    }
    size_t pcap = codec_packet_bound(cap);
    uint8_t *pkt = malloc(pcap);
    struct splat_frame ma = { 0 }, mb = { 0 };
    double pred_bytes = 0, mot_bytes = 0, unch = 0, total = 0, ps = 0, pmin = 1e9, pm = 0;
    double te_p = 0, td_p = 0;
    uint8_t *all = NULL; /* --decode-reps: every packet, for redecode */
    size_t all_len = 0;
    for (int k = 0; k < nk; k++) {
        size_t n;
        double t0 = bench_now();
        if (codec_enc_key(e, &keys[k], (uint64_t)k, still ? CODEC_KEY_STILL : CODEC_KEY_AUTO, NULL, pkt, pcap, &n) <
            0) {
            fprintf(stderr, "f4d-bench codec: %s\n", codec_enc_error(e));
            return -1;
        }
        double t1 = bench_now();
        struct codec_packet p;
        if (codec_packet_parse(pkt, n, &p, &err) < 0 || codec_dec_packet(d, &p) != 1) {
            fprintf(stderr, "f4d-bench codec: decode: %s %s\n", err.msg, codec_dec_error(d));
            return -1;
        }
        double t2 = bench_now();
        if (c->dec_reps > 0) {
            uint8_t *a2 = realloc(all, all_len + n);
            if (!a2) {
                fprintf(stderr, "f4d-bench codec: out of memory\n");
                return -1;
            }
            all = a2;
            memcpy(all + all_len, pkt, n);
            all_len += n;
        }
        const struct codec_enc_stats *st = codec_enc_last(e);
        double g = keys[k].count ? (double)keys[k].count : 1.0;
        total += (double)n;
        mot_bytes += (double)st->bytes_motion / g;
        if (k == 0) {
            row->intra_bpg = (double)n / g;
            row->enc_intra_ms = 1e3 * (t1 - t0);
            row->dec_intra_ms = 1e3 * (t2 - t1);
            for (int ch = 0; ch < CODEC_CHANNELS; ch++)
                row->ichan_bpg[ch] = (double)st->bytes_channel[ch] / g;
        } else {
            pred_bytes += (double)n / g;
            unch += (double)st->unchanged / g;
            for (int ch = 0; ch < CODEC_CHANNELS; ch++)
                row->chan_bpg[ch] += (double)st->bytes_channel[ch] / g;
            row->index_bpg += (double)st->bytes_index / g;
            te_p += 1e3 * (t1 - t0);
            td_p += 1e3 * (t2 - t1);
        }
        if (do_psnr) {
            const struct splat_frame *dec = codec_dec_frame(d);
            double v = rig_psnr(c, rig, &keys[k], dec);
            ps += v;
            pmin = v < pmin ? v : pmin;
            mid(&keys[k], &ma);
            mid(dec, &mb);
            pm += rig_psnr(c, rig, &ma, &mb);
        }
    }
    int np = nk - 1 > 0 ? nk - 1 : 1;
    row->quality = q;
    row->keys = nk;
    row->pred_bpg = nk > 1 ? pred_bytes / np : 0;
    row->motion_bpg = mot_bytes / nk;
    row->unchanged = nk > 1 ? unch / np : 0;
    row->mbps = total / nk * row->key_rate * 8 / 1e6;
    for (int ch = 0; ch < CODEC_CHANNELS; ch++)
        row->chan_bpg[ch] /= np;
    row->index_bpg /= np;
    row->enc_pred_ms = nk > 1 ? te_p / np : 0;
    row->dec_pred_ms = nk > 1 ? td_p / np : 0;
    row->psnr_key = do_psnr ? ps / nk : NAN;
    row->psnr_key_min = do_psnr ? pmin : NAN;
    row->psnr_mid = do_psnr ? pm / nk : NAN;
    if (c->dec_reps > 0) {
        double di, dp;
        if (redecode(d, all, all_len, c->dec_reps, &di, &dp) < 0)
            return -1;
        row->dec_intra_ms = di;
        row->dec_pred_ms = nk > 1 ? dp : 0;
    }
    free(all);
    splat_frame_free(&ma);
    splat_frame_free(&mb);
    free(pkt);
    codec_enc_free(e);
    codec_dec_free(d);
    return 0;
}

static int run_spz(struct ctx *c, const struct splat_rig *rig, const struct splat_frame *f, struct srow *row)
{
    uint8_t *z;
    size_t zn;
    struct f4d_err err = { 0 };
    struct splat_frame g = { 0 };
    double t0 = bench_now();
    if (codec_spz_encode(f, &z, &zn, &err) < 0) {
        fprintf(stderr, "f4d-bench codec: spz: %s\n", err.msg);
        return -1;
    }
    double t1 = bench_now();
    if (codec_spz_decode(z, zn, &g, &err) < 0) {
        fprintf(stderr, "f4d-bench codec: spz: %s\n", err.msg);
        return -1;
    }
    double t2 = bench_now();
    row->gaussians = f->count;
    row->bpg = (double)zn / (double)(f->count ? f->count : 1);
    row->enc_ms = 1e3 * (t1 - t0);
    row->dec_ms = 1e3 * (t2 - t1);
    row->psnr = rig_psnr(c, rig, f, &g);
    free(z);
    splat_frame_free(&g);
    return 0;
}

static void print_row(const struct crow *r)
{
    printf("%-6s %7zu G %2d Hz %-6s  intra %5.2f  pred %5.2f (motion %4.2f, %4.1f%% unchanged) B/G  %7.2f Mbit/s"
           "  PSNR key %6.2f (min %6.2f) mid %6.2f dB  enc %6.1f/%6.1f  dec %5.1f/%5.1f ms\n",
           r->preset, r->gaussians, r->key_rate, codec_quality_get(r->quality)->name, r->intra_bpg, r->pred_bpg,
           r->motion_bpg, 100 * r->unchanged, r->mbps, r->psnr_key, r->psnr_key_min, r->psnr_mid, r->enc_intra_ms,
           r->enc_pred_ms, r->dec_intra_ms, r->dec_pred_ms);
    fflush(stdout);
}

/* Bytes per Gaussian of the intra and the predicted keys by channel (--channels). */
static void print_channels(const struct crow *r)
{
    printf("       intra B/G by channel:");
    for (int ch = 0; ch < CODEC_CHANNELS; ch++)
        if (r->ichan_bpg[ch] >= 0.0005)
            printf("  %s %.3f", codec_channel_name(ch), r->ichan_bpg[ch]);
    printf("\n");
    printf("       predicted B/G by channel: index %.3f", r->index_bpg);
    for (int ch = 0; ch < CODEC_CHANNELS; ch++)
        if (r->chan_bpg[ch] >= 0.0005)
            printf("  %s %.3f", codec_channel_name(ch), r->chan_bpg[ch]);
    printf("\n");
    fflush(stdout);
}

static void print_spz(const struct srow *s)
{
    printf("%-6s %7zu G  SPZ v4 (ours)  %5.2f B/G  PSNR %6.2f dB  enc %6.1f dec %5.1f ms\n", s->preset, s->gaussians,
           s->bpg, s->psnr, s->enc_ms, s->dec_ms);
    fflush(stdout);
}

static void json_num(FILE *fp, const char *k, double v, const char *sep)
{
    if (isfinite(v))
        fprintf(fp, "\"%s\": %.4f%s", k, v, sep);
    else
        fprintf(fp, "\"%s\": null%s", k, sep);
}

int bench_codec(int argc, char **argv)
{
    const char *json = NULL, *donut = "../shared/data/splats/donut.ply";
    int only = -1, only_q = -1, channels = 0, big_all_rates = 0, reorder = 0, effort = CODEC_EFFORT_DEFAULT;
    int dec_reps = 0;
    size_t big = 300000;
    double seconds = 1.0;
    for (int i = 1; i < argc; i++) {
        if (!strcmp(argv[i], "--json") && i + 1 < argc)
            json = argv[++i];
        else if (!strcmp(argv[i], "--preset") && i + 1 < argc) {
            struct f4d_err e;
            if ((only = scene_preset_from_name(argv[++i], &e)) < 0) {
                fprintf(stderr, "f4d-bench codec: %s\n", e.msg);
                return 2;
            }
        } else if (!strcmp(argv[i], "--seconds") && i + 1 < argc)
            seconds = atof(argv[++i]);
        else if (!strcmp(argv[i], "--big") && i + 1 < argc)
            big = (size_t)atol(argv[++i]);
        else if (!strcmp(argv[i], "--donut") && i + 1 < argc)
            donut = argv[++i];
        else if (!strcmp(argv[i], "--quality") && i + 1 < argc) {
            struct f4d_err e;
            if ((only_q = codec_quality_from_name(argv[++i], &e)) < 0) {
                fprintf(stderr, "f4d-bench codec: %s\n", e.msg);
                return 2;
            }
        } else if (!strcmp(argv[i], "--channels"))
            channels = 1;
        else if (!strcmp(argv[i], "--big-all-rates"))
            big_all_rates = 1;
        else if (!strcmp(argv[i], "--stream-order"))
            reorder = 1;
        else if (!strcmp(argv[i], "--decode-reps") && i + 1 < argc)
            dec_reps = atoi(argv[++i]);
        else if (!strcmp(argv[i], "--effort") && i + 1 < argc) {
            struct f4d_err e;
            if ((effort = codec_effort_from_name(argv[++i], &e)) < 0) {
                fprintf(stderr, "f4d-bench codec: %s\n", e.msg);
                return 2;
            }
        }
        else {
            fprintf(stderr, "usage: f4d-bench codec [--preset NAME] [--seconds S] [--big N (0 = skip)] "
                            "[--donut PLY] [--quality NAME] [--channels] [--big-all-rates] [--stream-order] [--effort fast|default|max] [--decode-reps R] [--json FILE]\n");
            return 2;
        }
    }
    if (!(seconds >= 0.2 && seconds <= 10)) {
        fprintf(stderr, "f4d-bench codec: --seconds must be in 0.2..10\n");
        return 2;
    }
    fk_ctx *fk;
    struct fk_ctx_config cfg = { .isa = FK_ISA_AUTO, .threads = 2 };
    struct f4d_err err = { 0 };
    if (fk_ctx_new(&cfg, &fk) != F4D_OK)
        return 1;
    struct ctx c = { .reorder = reorder, .effort = effort, .dec_reps = dec_reps };
    if (splat_renderer_new(fk, W, H, &c.r, &err) < 0) {
        fprintf(stderr, "f4d-bench codec: %s\n", err.msg);
        return 1;
    }
    c.a = malloc(3 * NP * sizeof(float));
    c.b = malloc(3 * NP * sizeof(float));
    struct crow rows[256];
    struct srow srows[32];
    int nr = 0, ns = 0;
    static const int rates[3] = { 5, 10, 15 };
    static const enum scene_preset presets[] = { SCENE_WALK, SCENE_WAVE, SCENE_JUMP, SCENE_FAST };
    /* the default-density presets, every rate; then walk at `big` Gaussians, 10 Hz */
    for (int pass = 0; pass < 2; pass++) {
        for (size_t pi = 0; pi < sizeof presets / sizeof presets[0]; pi++) {
            enum scene_preset p = presets[pi];
            if ((only >= 0 && (int)p != only) || (pass == 1 && (p != SCENE_WALK || big == 0)))
                continue;
            scene *s;
            if (scene_new(p, 1, pass ? big : 0, &s, &err) < 0) {
                fprintf(stderr, "f4d-bench codec: %s\n", err.msg);
                return 1;
            }
            struct splat_rig rig;
            scene_default_rig(s, 4, W, H, &rig);
            c.bg = scene_background();
            for (int ri = 0; ri < 3; ri++) {
                int rate = rates[ri];
                if (pass == 1 && rate != 10 && !big_all_rates)
                    continue;
                int nk = (int)(seconds * rate + 0.5) + 1;
                struct splat_frame *keys = calloc((size_t)nk, sizeof *keys);
                for (int k = 0; k < nk; k++)
                    if (scene_eval(s, (double)k / rate, 1.0 / rate, &keys[k], &err) < 0) {
                        fprintf(stderr, "f4d-bench codec: %s\n", err.msg);
                        return 1;
                    }
                for (int q = 0; q < CODEC_QUALITY_COUNT && nr < 256; q++) {
                    if (only_q >= 0 && q != only_q)
                        continue;
                    struct crow *r = &rows[nr++];
                    memset(r, 0, sizeof *r);
                    snprintf(r->preset, sizeof r->preset, "%s", scene_preset_name(p));
                    r->gaussians = keys[0].count;
                    r->key_rate = rate;
                    if (run_level(&c, &rig, keys, nk, q, rate == 10, 0, r) < 0)
                        return 1;
                    print_row(r);
                    if (channels)
                        print_channels(r);
                }
                if (rate == 10 && ns < 32) {
                    struct srow *sr = &srows[ns++];
                    snprintf(sr->preset, sizeof sr->preset, "%s", scene_preset_name(p));
                    if (run_spz(&c, &rig, &keys[0], sr) < 0)
                        return 1;
                    print_spz(sr);
                }
                for (int k = 0; k < nk; k++)
                    splat_frame_free(&keys[k]);
                free(keys);
            }
            scene_free(s);
        }
    }
    /* donut: static, 4 cameras 0.6 m away around its centre */
    int donut_present = access(donut, R_OK) == 0;
    if (!donut_present) {
        printf("donut: %s is absent, skipped\n", donut);
    } else if (only < 0) {
        struct splat_frame f[2] = { { 0 }, { 0 } };
        if (splat_ply_read(donut, &f[0], &err) < 0 || splat_frame_copy(&f[1], &f[0], &err) < 0) {
            fprintf(stderr, "f4d-bench codec: %s\n", err.msg);
            return 1;
        }
        float ctr[3] = { 0 };
        for (size_t i = 0; i < f[0].count; i++)
            for (int k = 0; k < 3; k++)
                ctr[k] += f[0].pos[3 * i + k] / (float)f[0].count;
        struct splat_rig rig = { .count = 4 };
        for (int k = 0; k < 4; k++) {
            struct splat_camera *cam = &rig.cams[k];
            snprintf(cam->name, sizeof cam->name, "cam%d", k);
            cam->width = W;
            cam->height = H;
            cam->fx = cam->fy = 0.5f * W / tanf(0.5f * 0.8f);
            cam->cx = 0.5f * W;
            cam->cy = 0.5f * H;
            float a = (float)k * 1.5707963f + 0.3f;
            float eye[3] = { ctr[0] + 0.6f * cosf(a), ctr[1] - 0.25f, ctr[2] + 0.6f * sinf(a) };
            float up[3] = { 0, -1, 0 };
            splat_camera_look_at(cam, eye, ctr, up);
        }
        static const float black[3] = { 0, 0, 0 };
        c.bg = black;
        for (int q = 0; q < CODEC_QUALITY_COUNT; q++) {
            if (only_q >= 0 && q != only_q)
                continue;
            struct crow *r = &rows[nr++];
            memset(r, 0, sizeof *r);
            snprintf(r->preset, sizeof r->preset, "donut");
            r->gaussians = f[0].count;
            r->key_rate = 10;
            if (run_level(&c, &rig, f, 2, q, 1, 0, r) < 0)
                return 1;
            print_row(r);
            /* the same key as a still key (Morton-reordered) */
            r = &rows[nr++];
            memset(r, 0, sizeof *r);
            snprintf(r->preset, sizeof r->preset, "donut-still");
            r->gaussians = f[0].count;
            r->key_rate = 10;
            if (run_level(&c, &rig, f, 1, q, 1, 1, r) < 0)
                return 1;
            print_row(r);
        }
        struct srow *sr = &srows[ns++];
        snprintf(sr->preset, sizeof sr->preset, "donut");
        if (run_spz(&c, &rig, &f[0], sr) < 0)
            return 1;
        print_spz(sr);
        splat_frame_free(&f[0]);
        splat_frame_free(&f[1]);
    }
    if (json) {
        FILE *fp = fopen(json, "w");
        if (!fp) {
            fprintf(stderr, "f4d-bench codec: cannot create '%s'\n", json);
            return 1;
        }
        fprintf(fp, "{\"psnr\": \"float renders 518x518, mean over 4 rig cameras and all keys, vs uncompressed\",\n"
                    " \"donut\": \"%s\", \"stream_order\": %s, \"effort\": %d,\n \"codec\": [",
                donut_present ? donut : "absent", reorder ? "true" : "false", effort);
        for (int i = 0; i < nr; i++) {
            const struct crow *r = &rows[i];
            fprintf(fp, "%s\n  {\"preset\": \"%s\", \"gaussians\": %zu, \"key_rate_hz\": %d, \"quality\": \"%s\", "
                        "\"keys\": %d, ", i ? "," : "", r->preset, r->gaussians, r->key_rate,
                    codec_quality_get(r->quality)->name, r->keys);
            json_num(fp, "intra_bytes_per_gaussian", r->intra_bpg, ", ");
            json_num(fp, "pred_bytes_per_gaussian", r->pred_bpg, ", ");
            json_num(fp, "motion_bytes_per_gaussian", r->motion_bpg, ", ");
            json_num(fp, "unchanged_fraction", r->unchanged, ", ");
            json_num(fp, "mbit_per_s_at_30fps_display", r->mbps, ", ");
            json_num(fp, "mbit_per_s_predicted_keys_only", r->pred_bpg * (double)r->gaussians * r->key_rate * 8 / 1e6,
                     ", ");
            /* one intra key every T seconds, the rest predicted at the
             * measured sizes (an extrapolation of this run's keys) */
            static const int periods[4] = { 1, 2, 5, 10 };
            fprintf(fp, "\"mbit_per_s_intra_every_s\": {");
            for (int t = 0; t < 4; t++) {
                double keys_t = (double)r->key_rate * periods[t];
                double bits = (r->intra_bpg + (keys_t - 1) * r->pred_bpg) * (double)r->gaussians * 8;
                fprintf(fp, "%s\"%d\": %.4f", t ? ", " : "", periods[t], bits / periods[t] / 1e6);
            }
            fprintf(fp, "}, \"pred_bytes_per_gaussian_by_channel\": {\"index\": %.4f", r->index_bpg);
            for (int ch = 0; ch < CODEC_CHANNELS; ch++)
                fprintf(fp, ", \"%s\": %.4f", codec_channel_name(ch), r->chan_bpg[ch]);
            fprintf(fp, "}, ");
            json_num(fp, "psnr_key_db", r->psnr_key, ", ");
            json_num(fp, "psnr_key_min_db", r->psnr_key_min, ", ");
            json_num(fp, "psnr_mid_db", r->psnr_mid, ", ");
            json_num(fp, "encode_intra_ms", r->enc_intra_ms, ", ");
            json_num(fp, "encode_pred_ms", r->enc_pred_ms, ", ");
            json_num(fp, "decode_intra_ms", r->dec_intra_ms, ", ");
            json_num(fp, "decode_pred_ms", r->dec_pred_ms, "}");
        }
        fprintf(fp, "\n], \"spz\": [");
        for (int i = 0; i < ns; i++) {
            const struct srow *s = &srows[i];
            fprintf(fp, "%s\n  {\"preset\": \"%s\", \"gaussians\": %zu, \"spz_version\": 4, ", i ? "," : "", s->preset,
                    s->gaussians);
            json_num(fp, "bytes_per_gaussian", s->bpg, ", ");
            json_num(fp, "psnr_db", s->psnr, ", ");
            json_num(fp, "encode_ms", s->enc_ms, ", ");
            json_num(fp, "decode_ms", s->dec_ms, "}");
        }
        fprintf(fp, "\n]}\n");
        fclose(fp);
    }
    free(c.a);
    free(c.b);
    splat_renderer_free(c.r);
    fk_ctx_free(fk);
    return 0;
}
