/* f4d-scene - writes a synthetic 4D scene with exact ground truth:
 *   f4d-scene --preset NAME --frames N [--views V] [--size WxH] [--seed S] -o DIR
 *             [--gaussians N] [--threads N]
 *   f4d-scene venue --seed S -o DIR ...   randomised training takes (venue.c)
 * Layout of DIR:
 *   scene.json                      preset, seed, frames, fps, Gaussians, height
 *   rig.json                        the cameras (splat rig format)
 *   tKKKK/gaussians.ply             GT Gaussians at t = K / 30 s, with motion
 *   tKKKK/motion_bwd.npy, motion_fwd.npy        [N, 3] per-Gaussian 3D motion (m)
 *   tKKKK/CAM.png                   render over the sky colour
 *   tKKKK/CAM_depth.npy             [H, W] expected z-depth (m, 0 = nothing)
 *   tKKKK/CAM_flow.npy              [H, W, 2] 2D flow to step K+1 (px)
 *   tKKKK/CAM_motion_bwd.npy, CAM_motion_fwd.npy  [H, W, 3] per-pixel 3D motion */
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

#include "scene.h"
#include "venue.h"

static void usage(FILE *f)
{
    fprintf(f, "usage: f4d-scene --preset NAME --frames N [--views V] [--size WxH] [--seed S] -o DIR\n"
               "                 [--gaussians N] [--threads N]\n"
               "  presets: walk jump wave throw fast cross exit close; V in 1..8 (default 4);\n"
               "  size default 518x518; N frames at 30 fps starting at t = 0.\n"
               "       f4d-scene venue --seed S -o DIR [--frames T] [--size WxH] [--eval E] [--views V]\n"
               "                 [--person-gaussians N] [--ply]: a randomised training take (tools/train)\n");
}

static int parse_long(const char *opt, const char *v, long lo, long hi, long *out)
{
    char *end;
    errno = 0;
    long x = strtol(v, &end, 10);
    if (end == v || *end || errno || x < lo || x > hi) {
        fprintf(stderr, "f4d-scene: %s '%s' must be an integer in %ld..%ld\n", opt, v, lo, hi);
        return -1;
    }
    *out = x;
    return 0;
}

static int mkdir_p(const char *p)
{
    if (mkdir(p, 0777) == 0 || errno == EEXIST)
        return 0;
    fprintf(stderr, "f4d-scene: cannot create directory '%s': %s\n", p, strerror(errno));
    return -1;
}

int main(int argc, char **argv)
{
    if (argc > 1 && !strcmp(argv[1], "venue"))
        return venue_main(argc - 1, argv + 1);
    const char *preset_name = NULL, *outdir = NULL;
    long frames = -1, views = SCENE_VIEWS_DEFAULT, W = 518, H = 518, seed = 1, gaussians = 0, threads = 0;
    for (int i = 1; i < argc; i++) {
        const char *a = argv[i];
        if (!strcmp(a, "-h") || !strcmp(a, "--help")) {
            usage(stdout);
            return 0;
        }
        if (i + 1 >= argc) {
            fprintf(stderr, "f4d-scene: option '%s' needs a value (or is unknown)\n", a);
            return 2;
        }
        const char *v = argv[++i];
        int bad = 0;
        if (!strcmp(a, "--preset")) preset_name = v;
        else if (!strcmp(a, "-o")) outdir = v;
        else if (!strcmp(a, "--frames")) bad = parse_long(a, v, 1, 100000, &frames);
        else if (!strcmp(a, "--views")) bad = parse_long(a, v, 1, 8, &views);
        else if (!strcmp(a, "--seed")) bad = parse_long(a, v, 0, 2147483647L, &seed);
        else if (!strcmp(a, "--gaussians")) bad = parse_long(a, v, 1000, 20000000, &gaussians);
        else if (!strcmp(a, "--threads")) bad = parse_long(a, v, 1, 256, &threads);
        else if (!strcmp(a, "--size")) {
            char *x = strchr(v, 'x');
            char wbuf[32];
            if (!x || (size_t)(x - v) >= sizeof wbuf) {
                fprintf(stderr, "f4d-scene: --size '%s' must be WxH, e.g. 518x518\n", v);
                return 2;
            }
            memcpy(wbuf, v, (size_t)(x - v));
            wbuf[x - v] = '\0';
            bad = parse_long("--size width", wbuf, 16, 8192, &W) || parse_long("--size height", x + 1, 16, 8192, &H);
        } else {
            fprintf(stderr, "f4d-scene: unknown option '%s'\n", a);
            usage(stderr);
            return 2;
        }
        if (bad)
            return 2;
    }
    if (!preset_name || frames < 0 || !outdir) {
        fprintf(stderr, "f4d-scene: --preset, --frames and -o are required\n");
        usage(stderr);
        return 2;
    }
    struct f4d_err err = {0};
    int preset = scene_preset_from_name(preset_name, &err);
    if (preset < 0) {
        fprintf(stderr, "f4d-scene: %s\n", err.msg);
        return 2;
    }
    if (mkdir_p(outdir) < 0)
        return 1;

    int rc = 1;
    scene *sc = NULL;
    fk_ctx *ctx = NULL;
    splat_renderer *r = NULL;
    struct splat_frame f = { 0 };
    size_t np = (size_t)W * (size_t)H;
    float *rgb = malloc(3 * np * sizeof(float)), *depth = malloc(np * sizeof(float)),
          *mb = malloc(3 * np * sizeof(float)), *mf = malloc(3 * np * sizeof(float)),
          *flow = malloc(2 * np * sizeof(float)), *alpha = malloc(np * sizeof(float));
    char path[4096];
    if (!rgb || !depth || !mb || !mf || !flow || !alpha) {
        fprintf(stderr, "f4d-scene: out of memory\n");
        goto done;
    }
    if (scene_new((enum scene_preset)preset, (uint64_t)seed, (size_t)gaussians, &sc, &err) < 0) {
        fprintf(stderr, "f4d-scene: %s\n", err.msg);
        goto done;
    }
    struct splat_rig rig;
    scene_default_rig(sc, (int)views, (int)W, (int)H, &rig);
    struct fk_ctx_config cfg = { .isa = FK_ISA_AUTO, .threads = (int)threads };
    if (fk_ctx_new(&cfg, &ctx) != F4D_OK || splat_renderer_new(ctx, (int)W, (int)H, &r, &err) < 0) {
        fprintf(stderr, "f4d-scene: cannot create the renderer: %s\n", err.msg);
        goto done;
    }
    snprintf(path, sizeof path, "%s/rig.json", outdir);
    if (splat_rig_save(path, &rig, &err) < 0) {
        fprintf(stderr, "f4d-scene: %s\n", err.msg);
        goto done;
    }
    snprintf(path, sizeof path, "%s/scene.json", outdir);
    FILE *fp = fopen(path, "w");
    if (!fp) {
        fprintf(stderr, "f4d-scene: cannot create '%s': %s\n", path, strerror(errno));
        goto done;
    }
    fprintf(fp, "{\"preset\": \"%s\", \"seed\": %ld, \"frames\": %ld, \"fps\": %g, \"gaussians\": %zu, "
                "\"height_m\": %.4f, \"views\": %ld, \"width\": %ld, \"height\": %ld}\n",
            preset_name, seed, frames, SCENE_FPS, scene_count(sc), (double)scene_height(sc), views, W, H);
    if (fclose(fp) != 0) {
        fprintf(stderr, "f4d-scene: error writing '%s'\n", path);
        goto done;
    }
    const double dt = 1.0 / SCENE_FPS;
    for (long k = 0; k < frames; k++) {
        double t = (double)k * dt;
        char dir[3072];
        snprintf(dir, sizeof dir, "%s/t%04ld", outdir, k);
        if (mkdir_p(dir) < 0)
            goto done;
        if (scene_eval(sc, t, dt, &f, &err) < 0) {
            fprintf(stderr, "f4d-scene: %s\n", err.msg);
            goto done;
        }
        size_t gshape[2] = { f.count, 3 };
        snprintf(path, sizeof path, "%s/gaussians.ply", dir);
        int bad = splat_ply_write(path, &f, &err) < 0;
        snprintf(path, sizeof path, "%s/motion_bwd.npy", dir);
        bad = bad || splat_npy_write_f32(path, f.motion_bwd, gshape, 2, &err) < 0;
        snprintf(path, sizeof path, "%s/motion_fwd.npy", dir);
        bad = bad || splat_npy_write_f32(path, f.motion_fwd, gshape, 2, &err) < 0;
        if (bad) {
            fprintf(stderr, "f4d-scene: %s\n", err.msg);
            goto done;
        }
        for (int c = 0; c < rig.count; c++) {
            const struct splat_camera *cam = &rig.cams[c];
            struct splat_render_out o = { .rgb = rgb, .depth = depth, .alpha = alpha };
            if (splat_render(r, cam, &f, scene_background(), &o) < 0 ||
                splat_render_features(r, cam, &f, f.motion_bwd, mb) < 0 ||
                splat_render_features(r, cam, &f, f.motion_fwd, mf) < 0) {
                fprintf(stderr, "f4d-scene: %s\n", splat_renderer_error(r));
                goto done;
            }
            /* flow: each pixel's surface point moved by its forward motion */
            splat_flow_from_motion(cam, depth, alpha, mf, flow);
            size_t s2[2] = { (size_t)H, (size_t)W }, s3[3] = { (size_t)H, (size_t)W, 3 },
                   sf[3] = { (size_t)H, (size_t)W, 2 };
            snprintf(path, sizeof path, "%s/%s.png", dir, cam->name);
            bad = splat_png_write_rgb(path, rgb, (int)W, (int)H, &err) < 0;
            snprintf(path, sizeof path, "%s/%s_depth.npy", dir, cam->name);
            bad = bad || splat_npy_write_f32(path, depth, s2, 2, &err) < 0;
            snprintf(path, sizeof path, "%s/%s_flow.npy", dir, cam->name);
            bad = bad || splat_npy_write_f32(path, flow, sf, 3, &err) < 0;
            snprintf(path, sizeof path, "%s/%s_motion_bwd.npy", dir, cam->name);
            bad = bad || splat_npy_write_f32(path, mb, s3, 3, &err) < 0;
            snprintf(path, sizeof path, "%s/%s_motion_fwd.npy", dir, cam->name);
            bad = bad || splat_npy_write_f32(path, mf, s3, 3, &err) < 0;
            if (bad) {
                fprintf(stderr, "f4d-scene: %s\n", err.msg);
                goto done;
            }
        }
    }
    printf("wrote %ld steps of '%s' (%zu Gaussians, figure %.2f m, %d views %ldx%ld) to %s\n", frames,
           preset_name, scene_count(sc), (double)scene_height(sc), rig.count, W, H, outdir);
    rc = 0;
done:
    free(rgb); free(depth); free(mb); free(mf); free(flow); free(alpha);
    splat_frame_free(&f);
    splat_renderer_free(r);
    fk_ctx_free(ctx);
    scene_free(sc);
    return rc;
}
