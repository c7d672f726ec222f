/* f4d-novel: a stream seen from a camera the rig does not have, beside the
 * synthetic scene's ground truth of the same view and time.
 *
 *   f4d-novel STREAM.f4ds -o DIR [--rig PRED.json] [--scene walk] [--seed 1] [--views 4] [--size 518]
 *
 * Decodes every key of the stream (firmware/stream/codec), renders it from
 * the novel camera (the front camera of the scene's 5-view rig, between the
 * 4-view rig's cam1 and cam2) and renders the scene's exact Gaussians at the
 * key's trigger time from the same camera; writes DIR/novel.gif (left: the
 * stream, right: ground truth, looping at the keys' own pace), DIR/novel.png
 * (the last pair) and DIR/novel.json (per key time and PSNR, their mean).
 *
 * Frames: the novel camera is carried into the reconstruction's world
 * through camera 0: with --rig (the model's cameras, `forge4d run
 * --rig-json`), w2c = [Ra Rb | Ra tb + s ta] where [Ra|ta] = w2c_novel *
 * inverse(w2c_rig_cam0) (ground truth), [Rb|tb] the model's camera 0 and s
 * the model's camera baselines over the rig's (its scale error); a uniformly
 * scaled camera frame renders the same image. Without --rig the model's
 * camera 0 is taken as its world origin (the VGGT convention) at scale 1.
 * With untrained weights the left side shows what they make of the scene.
 */
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

#include "f4d_codec.h"
#include "fk_ctx.h"
#include "gif.h"
#include "scene.h"
#include "splat.h"

static int usage(void)
{
    fprintf(stderr, "usage: f4d-novel STREAM.f4ds -o DIR [--rig PRED.json] [--scene walk] [--seed 1] [--views 4] "
                    "[--size 518]\n");
    return 2;
}

/* 4x4 rigid inverse of a row-major world-to-camera matrix. */
static void rigid_inverse(const float m[16], float inv[16])
{
    memset(inv, 0, 16 * sizeof *inv);
    for (int r = 0; r < 3; r++)
        for (int c = 0; c < 3; c++)
            inv[4 * r + c] = m[4 * c + r];
    for (int r = 0; r < 3; r++)
        inv[4 * r + 3] = -(inv[4 * r] * m[3] + inv[4 * r + 1] * m[7] + inv[4 * r + 2] * m[11]);
    inv[15] = 1.0f;
}

static void mat4_mul(const float a[16], const float b[16], float out[16])
{
    for (int r = 0; r < 4; r++)
        for (int c = 0; c < 4; c++) {
            float s = 0;
            for (int k = 0; k < 4; k++)
                s += a[4 * r + k] * b[4 * k + c];
            out[4 * r + c] = s;
        }
}

static int read_all(const char *path, uint8_t **buf, size_t *len, struct f4d_err *err)
{
    FILE *f = fopen(path, "rb");
    if (!f)
        return f4d_fail(err, F4D_EIO, "%s: %s", path, strerror(errno));
    size_t cap = 1 << 20, n = 0;
    uint8_t *b = malloc(cap);
    for (;;) {
        if (!b) {
            fclose(f);
            return f4d_fail(err, F4D_ENOMEM, "%s: out of memory", path);
        }
        n += fread(b + n, 1, cap - n, f);
        if (n < cap)
            break;
        uint8_t *nb = realloc(b, cap *= 2);
        if (!nb)
            free(b);
        b = nb;
    }
    int bad = ferror(f);
    fclose(f);
    if (bad) {
        free(b);
        return f4d_fail(err, F4D_EIO, "%s: read error", path);
    }
    *buf = b;
    *len = n;
    return 0;
}

int main(int argc, char **argv)
{
    const char *in = NULL, *dir = NULL, *preset = "walk", *pred_path = NULL;
    unsigned long long seed = 1;
    int views = 4, size = 518;
    for (int i = 1; i < argc; i++) {
        const char *a = argv[i];
        if (!strcmp(a, "-o") && i + 1 < argc)
            dir = argv[++i];
        else if (!strcmp(a, "--rig") && i + 1 < argc)
            pred_path = argv[++i];
        else if (!strcmp(a, "--scene") && i + 1 < argc)
            preset = argv[++i];
        else if (!strcmp(a, "--seed") && i + 1 < argc)
            seed = strtoull(argv[++i], NULL, 10);
        else if (!strcmp(a, "--views") && i + 1 < argc)
            views = atoi(argv[++i]);
        else if (!strcmp(a, "--size") && i + 1 < argc)
            size = atoi(argv[++i]);
        else if (a[0] != '-' && !in)
            in = a;
        else
            return usage();
    }
    if (!in || !dir)
        return usage();
    if (views < 1 || views > 7 || size < 16 || size > 4096) {
        fprintf(stderr, "f4d-novel: --views 1..7 and --size 16..4096\n");
        return 2;
    }
    struct f4d_err err = {0};
    int status = 1;
    uint8_t *buf = NULL;
    size_t len = 0;
    scene *sc = NULL;
    fk_ctx *ctx = NULL;
    splat_renderer *rd = NULL;
    codec_dec *dec = NULL;
    struct novel_gif *gif = NULL;
    float *left = NULL, *right = NULL, *pair = NULL;
    struct splat_frame gt = {0};
    FILE *js = NULL;
    char path[1024];
    int p = scene_preset_from_name(preset, &err);
    if (p < 0 || scene_new((enum scene_preset)p, seed, 0, &sc, &err) < 0 || read_all(in, &buf, &len, &err) < 0)
        goto out;
    if (mkdir(dir, 0755) < 0 && errno != EEXIST) {
        f4d_fail(&err, F4D_EIO, "%s: %s", dir, strerror(errno));
        goto out;
    }
    /* the rig the board films with and the view it lacks */
    struct splat_rig rig, wide;
    scene_default_rig(sc, views, size, size, &rig);
    scene_default_rig(sc, views + 1, size, size, &wide);
    struct splat_camera novel = wide.cams[views / 2], novel_rec = novel;
    snprintf(novel.name, sizeof novel.name, "novel");
    float inv0[16], A[16];
    rigid_inverse(rig.cams[0].w2c, inv0);
    mat4_mul(novel.w2c, inv0, A);
    memcpy(novel_rec.w2c, A, sizeof A);
    double scale = 1.0;
    if (pred_path) {
        struct splat_rig pred;
        if (splat_rig_load(pred_path, &pred, &err) < 0)
            goto out;
        if (pred.count != rig.count) {
            f4d_fail(&err, F4D_EINVAL, "%s: %d cameras, the rig has %d", pred_path, pred.count, rig.count);
            goto out;
        }
        double bm = 0, bg = 0; /* baselines to camera 0: the model's scale over the truth's */
        float c0m[3], c0g[3];
        splat_camera_center(&pred.cams[0], c0m);
        splat_camera_center(&rig.cams[0], c0g);
        for (int i = 1; i < rig.count; i++) {
            float cm[3], cg[3];
            splat_camera_center(&pred.cams[i], cm);
            splat_camera_center(&rig.cams[i], cg);
            bm += sqrt(pow(cm[0] - c0m[0], 2) + pow(cm[1] - c0m[1], 2) + pow(cm[2] - c0m[2], 2));
            bg += sqrt(pow(cg[0] - c0g[0], 2) + pow(cg[1] - c0g[1], 2) + pow(cg[2] - c0g[2], 2));
        }
        scale = bg > 0 && bm > 0 ? bm / bg : 1.0;
        const float *B = pred.cams[0].w2c;
        for (int r = 0; r < 3; r++) {
            for (int c = 0; c < 3; c++)
                novel_rec.w2c[4 * r + c] = A[4 * r] * B[c] + A[4 * r + 1] * B[4 + c] + A[4 * r + 2] * B[8 + c];
            novel_rec.w2c[4 * r + 3] = A[4 * r] * B[3] + A[4 * r + 1] * B[7] + A[4 * r + 2] * B[11] +
                                       (float)scale * A[4 * r + 3];
        }
        fprintf(stderr, "[f4d-novel] model cameras from %s: scale %.3f of the rig's\n", pred_path, scale);
    }
    size_t px = (size_t)size * size * 3;
    left = malloc(px * sizeof *left);
    right = malloc(px * sizeof *right);
    pair = malloc(2 * px * sizeof *pair);
    if (!left || !right || !pair) {
        f4d_fail(&err, F4D_ENOMEM, "out of memory");
        goto out;
    }
    if (fk_ctx_new(&(struct fk_ctx_config){.isa = FK_ISA_AUTO}, &ctx) != F4D_OK) {
        f4d_fail(&err, F4D_ENOMEM, "cannot create the kernel context");
        goto out;
    }
    if (splat_renderer_new(ctx, size, size, &rd, &err) < 0 || codec_dec_new(CODEC_CAPACITY_MAX, &dec, &err) < 0)
        goto out;
    snprintf(path, sizeof path, "%s/novel.gif", dir);
    if (novel_gif_open(path, 2 * size, size, &gif, &err) < 0)
        goto out;
    snprintf(path, sizeof path, "%s/novel.json", dir);
    if (!(js = fopen(path, "w"))) {
        f4d_fail(&err, F4D_EIO, "%s: %s", path, strerror(errno));
        goto out;
    }
    fprintf(js, "{\"stream\": \"%s\", \"scene\": \"%s\", \"seed\": %llu, \"camera\": \"front of the %d-view rig "
            "(not in the %d-view rig)\", \"model_cameras\": %s, \"model_scale\": %.4f, \"keys\": [", in, preset, seed,
            views + 1, views, pred_path ? "true" : "false", scale);
    size_t off = 0, keys = 0;
    double psnr_sum = 0, last_t = -1;
    int pending = 0; /* frames rendered but not yet written: their delay is the next key's gap */
    while (off < len) {
        struct codec_packet pk;
        int rc = codec_packet_parse(buf + off, len - off, &pk, &err);
        if (rc == F4D_EEOF)
            break;
        if (rc < 0) { /* a damaged stretch: find the next packet */
            off += codec_packet_resync(buf + off, len - off);
            continue;
        }
        off += pk.size;
        if ((rc = codec_dec_packet(dec, &pk)) < 0 || rc == 0)
            continue;
        const struct splat_frame *f = codec_dec_frame(dec);
        double t = (double)codec_dec_time(dec) * 1e-6;
        if (pending) {
            int cs = (int)lround((t - last_t) * 100.0);
            if (novel_gif_frame(gif, pair, cs, &err) < 0)
                goto out;
        }
        struct splat_render_out o = {.rgb = left};
        if (splat_render(rd, &novel_rec, f, scene_background(), &o) < 0 || (o.rgb = right, 0) ||
            scene_eval(sc, t, 0.0, &gt, &err) < 0 || splat_render(rd, &novel, &gt, scene_background(), &o) < 0) {
            if (!err.msg[0])
                f4d_fail(&err, F4D_EIO, "render: %s", splat_renderer_error(rd));
            goto out;
        }
        double psnr = splat_psnr(left, right, size, size, 3);
        for (int y = 0; y < size; y++) {
            memcpy(pair + (size_t)y * 2 * size * 3, left + (size_t)y * size * 3, (size_t)size * 3 * sizeof *pair);
            memcpy(pair + ((size_t)y * 2 + 1) * size * 3, right + (size_t)y * size * 3,
                   (size_t)size * 3 * sizeof *pair);
        }
        fprintf(js, "%s{\"t_s\": %.6f, \"gaussians\": %zu, \"psnr_db\": %.3f}", keys ? ", " : "", t, f->count,
                isfinite(psnr) ? psnr : 99.0);
        psnr_sum += isfinite(psnr) ? psnr : 99.0;
        keys++;
        pending = 1;
        last_t = t;
        fprintf(stderr, "\r[f4d-novel] key %zu at %.3f s: %zu Gaussians, %.2f dB", keys, t, f->count, psnr);
    }
    if (!keys) {
        f4d_fail(&err, F4D_EFORMAT, "%s: no key frame decodes", in);
        goto out;
    }
    if (novel_gif_frame(gif, pair, 10, &err) < 0)
        goto out;
    snprintf(path, sizeof path, "%s/novel.png", dir);
    if (splat_png_write_rgb(path, pair, 2 * size, size, &err) < 0)
        goto out;
    fprintf(js, "], \"key_frames\": %zu, \"psnr_db_mean\": %.3f}\n", keys, psnr_sum / (double)keys);
    fprintf(stderr, "\n[f4d-novel] %zu keys, novel-view PSNR %.2f dB on average: %s/novel.gif\n", keys,
            psnr_sum / (double)keys, dir);
    status = 0;
out:
    if (status)
        fprintf(stderr, "\nf4d-novel: %s\n", err.msg);
    if (js && fclose(js) != 0 && !status) {
        fprintf(stderr, "f4d-novel: novel.json: write failed\n");
        status = 1;
    }
    if (gif && novel_gif_close(gif, &err) < 0 && !status) {
        fprintf(stderr, "f4d-novel: %s\n", err.msg);
        status = 1;
    }
    splat_frame_free(&gt);
    codec_dec_free(dec);
    splat_renderer_free(rd);
    fk_ctx_free(ctx);
    scene_free(sc);
    free(buf);
    free(left);
    free(right);
    free(pair);
    return status;
}
