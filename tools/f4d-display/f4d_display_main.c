/* f4d-display - shows a compressed 4D Gaussian stream at its own refresh rate.
 *
 *   f4d-display [--headless] [--window] [--kms [--kms-device DEV]] [--png-dir DIR]
 *               [--rig FILE|--camera-json FILE] [--camera N|NAME] [--size WxH]
 *               [--fps F] [--seconds S] [--frames N] [--renderer auto|cpu|gles]
 *               [--interp fused|both|nearest] [--offset BYTES] [--no-status]
 *               [--realtime|--no-realtime] [--threads N] [--json FILE] INPUT
 *
 * INPUT is a stream file (.f4ds), or srt://HOST:PORT?... / file:PATH through
 * the stream transport (f4d_transport.h: caller or listener, latency,
 * passphrase; the display's source stats then carry SRT's drops and latency).
 * --offset starts reading a plain file at a byte in
 * the middle (a join: the display waits for the next intra key). Without a
 * camera the first key places an orbit camera. Prints a JSON summary on stdout
 * (and into --json FILE). Exit 0, 1 on error, 2 on bad usage. */
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "f4d_display.h"

static void usage(FILE *f)
{
    fprintf(f, "usage: f4d-display [--headless] [--window] [--kms [--kms-device DEV]] [--png-dir DIR]\n"
               "                   [--rig FILE|--camera-json FILE] [--camera N|NAME] [--size WxH]\n"
               "                   [--fps F] [--seconds S] [--frames N] [--renderer auto|cpu|gles]\n"
               "                   [--interp fused|both|nearest] [--offset BYTES] [--no-status]\n"
               "                   [--realtime|--no-realtime] [--threads N] [--json FILE] INPUT\n");
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

static void summary(FILE *f, const struct display_stats *st, const struct display_config *cfg, int W, int H)
{
    const struct display_player_stats *p = &st->player;
    double fps = st->seconds > 0 && st->frames > 1 ? (double)(st->frames - 1) / st->seconds : 0.0;
    double fr = st->frames ? (double)st->frames : 1.0, keys = p->keys ? (double)p->keys : 1.0;
    fprintf(f,
            "{\"frames\": %llu, \"fps\": %.2f, \"refresh_fps\": %.2f, \"width\": %d, \"height\": %d,\n"
            " \"renderer\": \"%s\", \"gl_renderer\": \"%s\", \"auto_cpu_ms\": %.2f, \"auto_gles_ms\": %.2f,\n"
            " \"keys\": %llu, \"dropped_packets\": %llu, \"lost_packets\": %llu, \"skipped_keys\": %llu,\n"
            " \"refused_packets\": %llu, \"waited_packets\": %llu, \"too_large\": %llu, \"skipped_bytes\": %llu,\n"
            " \"bytes\": %llu, \"bitrate_mbps\": %.3f, \"latency_ms\": %.1f,\n"
            " \"decode_ms_per_key\": %.3f, \"lookup_ms_per_key\": %.3f, \"interp_ms_per_frame\": %.3f,\n"
            " \"render_ms_per_frame\": %.3f, \"present_ms_per_frame\": %.3f}\n",
            (unsigned long long)st->frames, fps, cfg->fps, W, H, st->renderer == DISPLAY_RENDER_CPU ? "cpu" : "gles",
            st->gl_renderer, st->auto_cpu_ms, st->auto_gles_ms, (unsigned long long)p->keys,
            (unsigned long long)st->source.dropped, (unsigned long long)p->lost, (unsigned long long)p->skipped,
            (unsigned long long)p->refused, (unsigned long long)p->waited, (unsigned long long)p->too_large,
            (unsigned long long)st->source.skipped_bytes, (unsigned long long)st->source.bytes, st->bitrate_mbps,
            st->latency_ms, p->decode_ms / keys, p->lookup_ms / keys, p->interp_ms / fr, st->render_ms / fr,
            st->present_ms / fr);
}

int main(int argc, char **argv)
{
    struct display_config cfg = display_config_default();
    const char *input = NULL, *rig_path = NULL, *cam_sel = NULL, *json = NULL;
    int size_given = 0, realtime = -1, threads = 0;
    double seconds = 0, frames = 0, offset = 0;
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
    if (net && offset > 0) {
        fprintf(stderr, "f4d-display: --offset applies to a plain stream file, not to '%s'\n", input);
        fk_ctx_free(ctx);
        return 2;
    }
#ifdef F4D_DISPLAY_TRANSPORT
    int src_rc = net ? display_source_transport(input, 0, &src, &err)
                     : display_source_file(input, (size_t)offset, &src, &err);
#else
    int src_rc = net ? f4d_fail(&err, F4D_ENOTSUP, "'%s': built without the stream transport", input)
                     : display_source_file(input, (size_t)offset, &src, &err);
#endif
    if (src_rc < 0 || display_new(ctx, &cfg, &d, &err) < 0) {
        fprintf(stderr, "f4d-display: %s\n", err.msg);
        goto done;
    }
    /* the refresh limit: --frames, or --seconds of stream time at --fps */
    uint64_t limit = frames > 0 ? (uint64_t)frames : seconds > 0 ? (uint64_t)ceil(seconds * cfg.fps) : 0;
    for (;;) {
        const struct display_stats *st = display_get_stats(d);
        if (limit && st->frames >= limit)
            break;
        int s = display_step(d, src);
        if (s < 0) {
            fprintf(stderr, "f4d-display: '%s': %s\n", input, display_error(d));
            goto done;
        }
        if (s == 0)
            break;
    }
    const struct display_stats *st = display_get_stats(d);
    int W = 0, H = 0;
    const struct splat_camera *used = display_camera(d);
    if (used) {
        W = used->width;
        H = used->height;
    }
    summary(stdout, st, &cfg, W, H);
    if (json) {
        FILE *f = fopen(json, "w");
        if (!f) {
            fprintf(stderr, "f4d-display: cannot create '%s': %s\n", json, strerror(errno));
            goto done;
        }
        summary(f, st, &cfg, W, H);
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
    return rc;
}
