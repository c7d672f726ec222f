/* f4d-display - shows a compressed 4D Gaussian stream at its own refresh rate.
 *
 *   f4d-display [--headless] [--window] [--kms [--kms-device DEV]] [--png-dir DIR]
 *               [--rig FILE|--camera-json FILE] [--camera N|NAME] [--size WxH]
 *               [--fps F] [--seconds S] [--frames N] [--renderer auto|cpu|gles]
 *               [--interp fused|both|nearest] [--lookup render|zbuffer] [--offset BYTES] [--no-status]
 *               [--realtime|--no-realtime] [--threads N] [--json FILE]
 *               [--follow [--follow-idle S]] [--live-lag K] [--key-times FILE] [--ready-fd N] INPUT
 *
 * INPUT is a stream file (.f4ds), or srt://HOST:PORT?... / file:PATH through
 * the stream transport (f4d_transport.h: caller or listener, latency,
 * passphrase; the display's source stats then carry SRT's drops and latency).
 * --offset starts reading a plain file at a byte in
 * the middle (a join: the display waits for the next intra key). --follow
 * reads INPUT, a stream file, while it is being written (live: it waits for
 * the file and for more bytes, ends at the stream's end packet or after
 * --follow-idle S, default 30, without new bytes). --live-lag K (default 0
 * with --follow, else off): a live source; every packet there is read at each
 * refresh and the display's clock is kept at most K key intervals behind the
 * newest key, catching up when it falls further behind (0: each key shown as
 * soon as it is decoded and held until the next; 1: the interval before the
 * newest key interpolated, one key interval later; -1: off, the clock runs
 * from the first key, e.g. to play a finished file at its pace). --key-times FILE (the
 * daemon's `forge4d run --key-times`: per key its stream time and trigger on
 * CLOCK_MONOTONIC, written before the key's packet) times each key from its
 * trigger to the end of the first refresh that shows it in full (stream time
 * and newest key both at or past the key's time), p50 / p95 in the summary:
 * both processes read CLOCK_MONOTONIC, one clock on one machine. --ready-fd
 * N: one byte is written to the open descriptor N, which is then closed,
 * once the source is open and the display set up (a starter waits for it:
 * a live display that came up after the stream had ended would show only
 * its last key). Without a
 * camera the first key places an orbit camera. Prints a JSON summary on stdout
 * (and into --json FILE). Exit 0, 1 on error, 2 on bad usage. */
#include <errno.h>
#include <fcntl.h>
#include <math.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#include "f4d_display.h"

static void usage(FILE *f)
{
    fprintf(f, "usage: f4d-display [--headless] [--window] [--kms [--kms-device DEV]] [--png-dir DIR]\n"
               "                   [--rig FILE|--camera-json FILE] [--camera N|NAME] [--size WxH]\n"
               "                   [--fps F] [--seconds S] [--frames N] [--renderer auto|cpu|gles]\n"
               "                   [--interp fused|both|nearest] [--lookup render|zbuffer]\n"
               "                   [--offset BYTES] [--no-status]\n"
               "                   [--realtime|--no-realtime] [--threads N] [--json FILE]\n"
               "                   [--follow [--follow-idle S]] [--live-lag K] [--key-times FILE] [--ready-fd N]\n"
               "                   INPUT\n");
}

static double cpu_ms(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
    return (double)ts.tv_sec * 1e3 + (double)ts.tv_nsec * 1e-6;
}

static uint64_t mono_ns(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (uint64_t)ts.tv_sec * 1000000000u + (uint64_t)ts.tv_nsec;
}

/* ---- --follow: a stream file read while it is written ----
 * Bytes are read into one buffer planned at start (FOLLOW_BUF: any key
 * packet of the shipped model's streams is far smaller); a packet handed out
 * points into it until the next call. Damaged bytes are skipped to the next
 * packet and counted, as the other sources do. */
#define FOLLOW_BUF ((size_t)64 << 20)
#define FOLLOW_READS 64 /* the last key packets' stream times and read times */
struct follow {
    const char *path;
    int fd, ended;
    uint8_t *buf;
    size_t lo, hi;
    double idle_s;
    uint64_t last_ns;
    uint64_t rd_t_us[FOLLOW_READS], rd_ns[FOLLOW_READS], rd_n;
    struct display_source_stats st;
};

/* When the key packet of stream time t_us was read (0: not among the last). */
static uint64_t follow_read_ns(const struct follow *f, uint64_t t_us)
{
    for (uint64_t i = f->rd_n; i > 0 && i + FOLLOW_READS > f->rd_n; i--)
        if (f->rd_t_us[(i - 1) % FOLLOW_READS] == t_us)
            return f->rd_ns[(i - 1) % FOLLOW_READS];
    return 0;
}

static int follow_next(void *impl, struct codec_packet *p, struct f4d_err *err)
{
    struct follow *f = impl;
    if (f->ended)
        return F4D_EEOF;
    uint64_t now = mono_ns();
    if (f->fd < 0 && (f->fd = open(f->path, O_RDONLY)) < 0) {
        if ((double)(now - f->last_ns) * 1e-9 > f->idle_s)
            return f4d_fail(err, F4D_EEOF, "'%s' did not appear in %.0f s", f->path, f->idle_s);
        return 0;
    }
    for (;;) {
        if (f->hi - f->lo >= CODEC_PACKET_HEADER) {
            struct f4d_err e = { 0 };
            int rc = codec_packet_parse(f->buf + f->lo, f->hi - f->lo, p, &e);
            if (rc == 0) {
                f->lo += p->size;
                f->st.packets++;
                f->st.bytes += p->size;
                f->ended = p->type == CODEC_PKT_END;
                if (p->type == CODEC_PKT_INTRA || p->type == CODEC_PKT_PRED) {
                    f->rd_t_us[f->rd_n % FOLLOW_READS] = p->t_us;
                    f->rd_ns[f->rd_n++ % FOLLOW_READS] = mono_ns();
                }
                return 1;
            }
            if (rc != F4D_EEOF) { /* damaged: on to the next packet start */
                size_t skip = codec_packet_resync(f->buf + f->lo, f->hi - f->lo);
                f->lo += skip;
                f->st.dropped++;
                f->st.skipped_bytes += skip;
                continue;
            }
            if (f->hi - f->lo == FOLLOW_BUF)
                return f4d_fail(err, F4D_ERANGE, "'%s': a packet larger than the follow buffer (%zu bytes)",
                                f->path, FOLLOW_BUF);
        }
        if (f->lo > 0) {
            memmove(f->buf, f->buf + f->lo, f->hi - f->lo);
            f->hi -= f->lo;
            f->lo = 0;
        }
        ssize_t n = read(f->fd, f->buf + f->hi, FOLLOW_BUF - f->hi);
        if (n < 0 && errno != EINTR)
            return f4d_fail(err, F4D_EIO, "'%s': %s", f->path, strerror(errno));
        if (n > 0) {
            f->hi += (size_t)n;
            f->last_ns = now;
            continue;
        }
        if ((double)(now - f->last_ns) * 1e-9 > f->idle_s)
            return f4d_fail(err, F4D_EEOF, "'%s': no new bytes for %.0f s", f->path, f->idle_s);
        return 0; /* nothing more yet */
    }
}

static void follow_stats(const void *impl, struct display_source_stats *st)
{
    *st = ((const struct follow *)impl)->st;
}

static void follow_free(void *impl)
{
    struct follow *f = impl;
    if (f->fd >= 0)
        close(f->fd);
    free(f->buf);
    free(f);
}

static int follow_open(const char *path, double idle_s, display_source **out, const struct follow **fw,
                       struct f4d_err *err)
{
    static const struct display_source_ops ops = { follow_next, follow_stats, follow_free };
    struct follow *f = calloc(1, sizeof *f);
    if (!f || !(f->buf = malloc(FOLLOW_BUF))) {
        free(f);
        return f4d_fail(err, F4D_ENOMEM, "--follow: out of memory");
    }
    f->path = path;
    f->fd = -1;
    f->idle_s = idle_s;
    f->last_ns = mono_ns();
    f->st.latency_ms = -1.0;
    int rc = display_source_new(&ops, f, out, err);
    if (rc < 0)
        follow_free(f);
    else
        *fw = f;
    return rc;
}

/* ---- --key-times: trigger -> presentation per key ----
 * Lines "t_us trigger_ns sent_ns ..." are read as they appear (the daemon
 * writes a key's line, once it is encoded, before its packet, so a key on
 * screen has its line on disk); a key waits in `pend` until a refresh shows
 * it in full. With --follow the latency is split: sent -> the packet read
 * here (the sink's write, the file, this reader's polling) -> shown (decode,
 * the display clock reaching the key, draw, present). */
#define KT_PEND 4096
#define KT_SAMPLES 65536
struct keytimes {
    int fd;
    char line[512];
    size_t len;
    uint64_t pend_t[KT_PEND], pend_trig[KT_PEND], pend_sent[KT_PEND];
    size_t head, n;
    float *ms;
    uint64_t timed, overflow;
    const struct follow *fw;       /* read times of the key packets (--follow), or NULL */
    double sum_read, sum_show, sum_total;
    uint64_t parts;                /* keys with all three times */
};

static void kt_read(struct keytimes *k)
{
    char buf[4096];
    ssize_t n;
    while ((n = read(k->fd, buf, sizeof buf)) > 0)
        for (ssize_t i = 0; i < n; i++) {
            if (buf[i] != '\n') {
                if (k->len + 1 < sizeof k->line)
                    k->line[k->len++] = buf[i];
                continue;
            }
            k->line[k->len] = 0;
            k->len = 0;
            unsigned long long t, trig, sent = 0;
            if (sscanf(k->line, "%llu %llu %llu", &t, &trig, &sent) < 2)
                continue;
            if (k->n == KT_PEND) { /* never shown: the oldest gives way */
                k->head = (k->head + 1) % KT_PEND;
                k->n--;
                k->overflow++;
            }
            size_t j = (k->head + k->n++) % KT_PEND;
            k->pend_t[j] = t;
            k->pend_trig[j] = trig;
            k->pend_sent[j] = sent;
        }
}

/* After a presented refresh: keys now shown in full get their latency. */
static void kt_presented(struct keytimes *k, const struct display_stats *st, uint64_t now)
{
    kt_read(k);
    uint64_t shown = st->shown_us < st->key_us ? st->shown_us : st->key_us;
    while (k->n && k->pend_t[k->head] <= shown) {
        uint64_t trig = k->pend_trig[k->head], sent = k->pend_sent[k->head];
        k->ms[k->timed++ % KT_SAMPLES] = now > trig ? (float)((double)(now - trig) * 1e-6) : 0.0f;
        uint64_t rd = k->fw ? follow_read_ns(k->fw, k->pend_t[k->head]) : 0;
        if (rd && sent && trig && sent <= rd && rd <= now && trig <= now) {
            k->sum_read += (double)(rd - sent) * 1e-6;
            k->sum_show += (double)(now - rd) * 1e-6;
            k->sum_total += (double)(now - trig) * 1e-6;
            k->parts++;
        }
        k->head = (k->head + 1) % KT_PEND;
        k->n--;
    }
}

static int cmp_float(const void *a, const void *b)
{
    float x = *(const float *)a, y = *(const float *)b;
    return (x > y) - (x < y);
}

static void kt_percentiles(struct keytimes *k, double *p50, double *p95)
{
    size_t n = k->timed < KT_SAMPLES ? (size_t)k->timed : KT_SAMPLES;
    *p50 = *p95 = NAN;
    if (!n)
        return;
    qsort(k->ms, n, sizeof *k->ms, cmp_float);
    *p50 = k->ms[(size_t)floor(0.50 * (double)(n - 1) + 0.5)];
    *p95 = k->ms[(size_t)floor(0.95 * (double)(n - 1) + 0.5)];
}

static int num(const char *opt, const char *v, double lo, double hi, double *out)
{
    char *end;
    errno = 0;
    double x = strtod(v, &end);
    if (end == v || *end || errno || !(x >= lo && x <= hi)) {
        fprintf(stderr, "f4d-display: %s '%s' must be a number in %g..%g\n", opt, v, lo, hi);
        return -1;
    }
    *out = x;
    return 0;
}

/* Process CPU from the first presented refresh on, per key decoded since. */
struct cpu_mark {
    double ms0;
    uint64_t keys0;
    int taken;
};

static void summary(FILE *f, const struct display_stats *st, const struct display_config *cfg, int W, int H,
                    const struct keytimes *kt, double p50, double p95, const struct cpu_mark *cm)
{
    const struct display_player_stats *p = &st->player;
    double fps = st->seconds > 0 && st->frames > 1 ? (double)(st->frames - 1) / st->seconds : 0.0;
    double fr = st->frames ? (double)st->frames : 1.0, keys = p->keys ? (double)p->keys : 1.0;
    fprintf(f,
            "{\"frames\": %llu, \"frames_drawn\": %llu, \"fps\": %.2f, \"refresh_fps\": %.2f, \"width\": %d, \"height\": %d,\n"
            " \"renderer\": \"%s\", \"gl_renderer\": \"%s\", \"auto_cpu_ms\": %.2f, \"auto_gles_ms\": %.2f,\n"
            " \"keys\": %llu, \"dropped_packets\": %llu, \"lost_packets\": %llu, \"skipped_keys\": %llu,\n"
            " \"refused_packets\": %llu, \"waited_packets\": %llu, \"too_large\": %llu, \"skipped_bytes\": %llu,\n"
            " \"bytes\": %llu, \"bitrate_mbps\": %.3f, \"latency_ms\": %.1f,\n"
            " \"decode_ms_per_key\": %.3f, \"lookup_ms_per_key\": %.3f, \"interp_ms_per_frame\": %.3f,\n"
            " \"render_ms_per_frame\": %.3f, \"present_ms_per_frame\": %.3f, \"raster_ms_per_frame\": %.3f,\n"
            " \"gaussians_per_frame\": %.0f, \"visible_per_frame\": %.0f, \"tile_pairs_per_frame\": %.0f,\n"
            " \"slots_missed\": %llu, \"live_lag_keys\": %.2f, \"clock_raises\": %llu, \"clock_raised_ms\": %.1f,"
            " \"frames_held\": %llu, \"decode_cpu_ms_per_key\": %.3f, \"lookup_cpu_ms_per_key\": %.3f,\n",
            (unsigned long long)st->frames, (unsigned long long)(st->frames - st->redraws_skipped), fps, cfg->fps, W, H, st->renderer == DISPLAY_RENDER_CPU ? "cpu" : "gles",
            st->gl_renderer, st->auto_cpu_ms, st->auto_gles_ms, (unsigned long long)p->keys,
            (unsigned long long)st->source.dropped, (unsigned long long)p->lost, (unsigned long long)p->skipped,
            (unsigned long long)p->refused, (unsigned long long)p->waited, (unsigned long long)p->too_large,
            (unsigned long long)st->source.skipped_bytes, (unsigned long long)st->source.bytes, st->bitrate_mbps,
            st->latency_ms, p->decode_ms / keys, p->lookup_ms / keys, p->interp_ms / fr, st->render_ms / fr,
            st->present_ms / fr, st->raster_ms / fr, (double)st->drawn / fr, (double)st->visible / fr,
            (double)st->pairs / fr, (unsigned long long)st->slots_missed, cfg->live_lag_keys,
            (unsigned long long)p->clock_raises, p->clock_raised_ms, (unsigned long long)p->held,
            p->decode_cpu_ms / keys, p->lookup_cpu_ms / keys);
    if (cm->taken && p->keys > cm->keys0)
        fprintf(f, " \"cpu_ms_per_key\": %.1f,\n", (cpu_ms() - cm->ms0) / (double)(p->keys - cm->keys0));
    if (kt && kt->parts)
        fprintf(f, " \"latency_breakdown_ms\": {\"display_read\": %.1f, \"display_show\": %.1f, \"to_display\": %.1f, "
                   "\"keys\": %llu},\n",
                kt->sum_read / (double)kt->parts, kt->sum_show / (double)kt->parts, kt->sum_total / (double)kt->parts,
                (unsigned long long)kt->parts);
    if (kt && isfinite(p50))
        fprintf(f, " \"keys_timed\": %llu, \"latency_trigger_ms_p50\": %.1f, \"latency_trigger_ms_p95\": %.1f}\n",
                (unsigned long long)kt->timed, p50, p95);
    else
        fprintf(f, " \"keys_timed\": %llu, \"latency_trigger_ms_p50\": null, \"latency_trigger_ms_p95\": null}\n",
                (unsigned long long)(kt ? kt->timed : 0));
}

int main(int argc, char **argv)
{
    struct display_config cfg = display_config_default();
    const char *input = NULL, *rig_path = NULL, *cam_sel = NULL, *json = NULL, *kt_path = NULL;
    int size_given = 0, realtime = -1, threads = 0, follow = 0, ready_fd = -1;
    double seconds = 0, frames = 0, offset = 0, follow_idle = 30, live_lag = NAN;
    for (int i = 1; i < argc; i++) {
        const char *a = argv[i];
        const char *v = i + 1 < argc ? argv[i + 1] : NULL;
        double x;
        if (!strcmp(a, "--headless")) {
            cfg.output = DISPLAY_HEADLESS;
        } else if (!strcmp(a, "--window")) {
            cfg.output = DISPLAY_X11;
        } else if (!strcmp(a, "--kms")) {
            cfg.output = DISPLAY_KMS;
        } else if (!strcmp(a, "--no-status")) {
            cfg.status_line = 0;
        } else if (!strcmp(a, "--realtime")) {
            realtime = 1;
        } else if (!strcmp(a, "--follow")) {
            follow = 1;
        } else if (!strcmp(a, "--no-realtime")) {
            realtime = 0;
        } else if (!strcmp(a, "-h") || !strcmp(a, "--help")) {
            usage(stdout);
            return 0;
        } else if (a[0] == '-' && a[1] == '-') {
            if (!v) {
                fprintf(stderr, "f4d-display: %s needs a value\n", a);
                return 2;
            }
            i++;
            if (!strcmp(a, "--png-dir")) {
                cfg.png_dir = v;
            } else if (!strcmp(a, "--kms-device")) {
                cfg.kms_device = v;
            } else if (!strcmp(a, "--rig") || !strcmp(a, "--camera-json")) {
                rig_path = v;
            } else if (!strcmp(a, "--camera")) {
                cam_sel = v;
            } else if (!strcmp(a, "--json")) {
                json = v;
            } else if (!strcmp(a, "--key-times")) {
                kt_path = v;
            } else if (!strcmp(a, "--live-lag")) {
                if (num(a, v, -1, 1000, &live_lag) < 0)
                    return 2;
            } else if (!strcmp(a, "--follow-idle")) {
                if (num(a, v, 0.1, 1e6, &follow_idle) < 0)
                    return 2;
            } else if (!strcmp(a, "--size")) {
                if (sscanf(v, "%dx%d", &cfg.width, &cfg.height) != 2) {
                    fprintf(stderr, "f4d-display: --size '%s' must be WxH\n", v);
                    return 2;
                }
                size_given = 1;
            } else if (!strcmp(a, "--fps")) {
                if (num(a, v, 1, 1000, &cfg.fps) < 0)
                    return 2;
            } else if (!strcmp(a, "--seconds")) {
                if (num(a, v, 0, 1e6, &seconds) < 0)
                    return 2;
            } else if (!strcmp(a, "--frames")) {
                if (num(a, v, 0, 1e9, &frames) < 0)
                    return 2;
            } else if (!strcmp(a, "--offset")) {
                if (num(a, v, 0, 1e15, &offset) < 0)
                    return 2;
            } else if (!strcmp(a, "--ready-fd")) {
                if (num(a, v, 0, 65535, &x) < 0)
                    return 2;
                ready_fd = (int)x;
                if (x != (double)ready_fd) {
                    fprintf(stderr, "f4d-display: --ready-fd '%s' must be a whole number\n", v);
                    return 2;
                }
                if (fcntl(ready_fd, F_GETFD) < 0) {
                    fprintf(stderr, "f4d-display: --ready-fd %d: not an open descriptor\n", ready_fd);
                    return 2;
                }
            } else if (!strcmp(a, "--threads")) {
                if (num(a, v, 0, 256, &x) < 0)
                    return 2;
                threads = (int)x;
            } else if (!strcmp(a, "--renderer")) {
                if (!strcmp(v, "auto")) cfg.renderer = DISPLAY_RENDER_AUTO;
                else if (!strcmp(v, "cpu")) cfg.renderer = DISPLAY_RENDER_CPU;
                else if (!strcmp(v, "gles")) cfg.renderer = DISPLAY_RENDER_GLES;
                else {
                    fprintf(stderr, "f4d-display: --renderer '%s' must be auto, cpu or gles\n", v);
                    return 2;
                }
            } else if (!strcmp(a, "--interp")) {
                if (!strcmp(v, "fused")) cfg.interp = INTERP_FUSED;
                else if (!strcmp(v, "both")) cfg.interp = INTERP_KEEP_BOTH;
                else if (!strcmp(v, "nearest")) cfg.interp = INTERP_NEAREST;
                else {
                    fprintf(stderr, "f4d-display: --interp '%s' must be fused, both or nearest\n", v);
                    return 2;
                }
            } else if (!strcmp(a, "--lookup")) {
                if (!strcmp(v, "render")) cfg.lookup = INTERP_LOOKUP_RENDER;
                else if (!strcmp(v, "zbuffer")) cfg.lookup = INTERP_LOOKUP_ZBUFFER;
                else {
                    fprintf(stderr, "f4d-display: --lookup '%s' must be render or zbuffer\n", v);
                    return 2;
                }
            } else {
                fprintf(stderr, "f4d-display: unknown option '%s'\n", a);
                usage(stderr);
                return 2;
            }
        } else if (!input) {
            input = a;
        } else {
            fprintf(stderr, "f4d-display: one INPUT only ('%s' and '%s')\n", input, a);
            return 2;
        }
    }
    if (!input) {
        usage(stderr);
        return 2;
    }
    if (cam_sel && !rig_path) {
        fprintf(stderr, "f4d-display: --camera %s needs the rig (--rig FILE): the stream carries no cameras\n",
                cam_sel);
        return 2;
    }
    cfg.realtime = realtime >= 0 ? realtime : cfg.output != DISPLAY_HEADLESS;
    cfg.live_lag_keys = isfinite(live_lag) ? live_lag : follow ? 0.0 : -1.0;
    struct f4d_err err = { 0 };
    struct splat_rig rig;
    struct splat_camera cam;
    if (rig_path) {
        if (splat_rig_load(rig_path, &rig, &err) < 0) {
            fprintf(stderr, "f4d-display: %s\n", err.msg);
            return 1;
        }
        int c = cam_sel ? splat_rig_find(&rig, cam_sel, &err) : 0;
        if (c < 0) {
            fprintf(stderr, "f4d-display: '%s': %s\n", rig_path, err.msg);
            return 1;
        }
        cam = rig.cams[c];
        if (!size_given && cfg.output != DISPLAY_KMS) {
            cfg.width = cam.width;
            cfg.height = cam.height;
        } else if (cfg.width != cam.width || cfg.height != cam.height) {
            /* the same view at the display's size: intrinsics scale with it */
            float sx = (float)cfg.width / (float)cam.width, sy = (float)cfg.height / (float)cam.height;
            cam.fx *= sx; cam.cx *= sx; cam.fy *= sy; cam.cy *= sy;
            cam.width = cfg.width;
            cam.height = cfg.height;
        }
        cfg.camera = &cam;
        int same = 1; /* interp's lookup needs one size for all views */
        for (int i = 1; i < rig.count; i++)
            same &= rig.cams[i].width == rig.cams[0].width && rig.cams[i].height == rig.cams[0].height;
        cfg.lookup_rig = same ? &rig : NULL;
    }
    fk_ctx *ctx;
    struct fk_ctx_config kc = { .isa = FK_ISA_AUTO, .threads = threads };
    if (fk_ctx_new(&kc, &ctx) != F4D_OK) {
        fprintf(stderr, "f4d-display: cannot create the kernel context\n");
        return 1;
    }
    display_source *src = NULL;
    display *d = NULL;
    int rc = 1;
    int net = !strncmp(input, "srt://", 6) || !strncmp(input, "file:", 5);
    if (follow && (net || offset > 0)) {
        fprintf(stderr, "f4d-display: --follow reads a plain stream file from its start, not '%s'%s\n", input,
                offset > 0 ? " at an offset" : "");
        fk_ctx_free(ctx);
        return 2;
    }
    struct keytimes *kt = NULL;
    if (kt_path) {
        kt = calloc(1, sizeof *kt);
        if (!kt || !(kt->ms = malloc(KT_SAMPLES * sizeof *kt->ms)) || (kt->fd = open(kt_path, O_RDONLY)) < 0) {
            fprintf(stderr, "f4d-display: --key-times '%s': %s\n", kt_path, kt ? strerror(errno) : "out of memory");
            if (kt)
                free(kt->ms);
            free(kt);
            fk_ctx_free(ctx);
            return 1;
        }
    }
    if (net && offset > 0) {
        fprintf(stderr, "f4d-display: --offset applies to a plain stream file, not to '%s'\n", input);
        fk_ctx_free(ctx);
        return 2;
    }
    const struct follow *fw = NULL;
#ifdef F4D_DISPLAY_TRANSPORT
    int src_rc = follow ? follow_open(input, follow_idle, &src, &fw, &err)
                 : net  ? display_source_transport(input, 0, &src, &err)
                        : display_source_file(input, (size_t)offset, &src, &err);
#else
    int src_rc = follow ? follow_open(input, follow_idle, &src, &fw, &err)
                 : net  ? f4d_fail(&err, F4D_ENOTSUP, "'%s': built without the stream transport", input)
                        : display_source_file(input, (size_t)offset, &src, &err);
#endif
    if (kt)
        kt->fw = fw;
    if (src_rc < 0 || display_new(ctx, &cfg, &d, &err) < 0) {
        fprintf(stderr, "f4d-display: %s\n", err.msg);
        goto done;
    }
    if (ready_fd >= 0) { /* set up: the starter may begin the stream */
        /* a starter that gave up has closed its end: EPIPE, not a signal */
        void (*old)(int) = signal(SIGPIPE, SIG_IGN);
        ssize_t w;
        while ((w = write(ready_fd, "1", 1)) < 0 && errno == EINTR) {
        }
        signal(SIGPIPE, old);
        if (w < 0)
            fprintf(stderr, "f4d-display: --ready-fd %d: %s (going on)\n", ready_fd, strerror(errno));
        close(ready_fd);
    }
    /* the refresh limit: --frames, or --seconds of stream time at --fps */
    uint64_t limit = frames > 0 ? (uint64_t)frames : seconds > 0 ? (uint64_t)ceil(seconds * cfg.fps) : 0;
    struct cpu_mark cm = { 0 };
    for (;;) {
        const struct display_stats *st = display_get_stats(d);
        if (limit && st->frames >= limit)
            break;
        uint64_t before = st->frames;
        if (before > 0 && !cm.taken) {
            cm = (struct cpu_mark){ cpu_ms(), st->player.keys, 1 };
        }
        int s = display_step(d, src);
        if (s < 0) {
            fprintf(stderr, "f4d-display: '%s': %s\n", input, display_error(d));
            goto done;
        }
        if (s == 0)
            break;
        if (kt && st->frames > before)
            kt_presented(kt, st, mono_ns());
    }
    double p50 = NAN, p95 = NAN;
    if (kt) {
        kt_read(kt);
        kt_percentiles(kt, &p50, &p95);
    }
    const struct display_stats *st = display_get_stats(d);
    int W = 0, H = 0;
    const struct splat_camera *used = display_camera(d);
    if (used) {
        W = used->width;
        H = used->height;
    }
    summary(stdout, st, &cfg, W, H, kt, p50, p95, &cm);
    if (json) {
        FILE *f = fopen(json, "w");
        if (!f) {
            fprintf(stderr, "f4d-display: cannot create '%s': %s\n", json, strerror(errno));
            goto done;
        }
        summary(f, st, &cfg, W, H, kt, p50, p95, &cm);
        fclose(f);
    }
    if (st->frames == 0) {
        fprintf(stderr, "f4d-display: '%s': no key frame could be shown (%llu packets, %llu dropped)\n", input,
                (unsigned long long)st->source.packets, (unsigned long long)st->source.dropped);
        goto done;
    }
    rc = 0;
done:
    display_free(d);
    display_source_free(src);
    fk_ctx_free(ctx);
    if (kt) {
        close(kt->fd);
        free(kt->ms);
        free(kt);
    }
    return rc;
}
