/* f4d-render - renders a Gaussian PLY from one camera of a rig file:
 *   f4d-render --ply F --rig R --camera NAME|INDEX -o OUT.png
 *              [--background r,g,b] [--depth OUT.npy] [--rgb-npy OUT.npy] [--threads N] */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "splat.h"

static void usage(FILE *f)
{
    fprintf(f, "usage: f4d-render --ply F --rig R --camera NAME|INDEX -o OUT.png\n"
               "                  [--background r,g,b] [--depth OUT.npy] [--rgb-npy OUT.npy] [--threads N]\n"
               "  Renders the 3D Gaussians of F (INRIA PLY, metres) seen by one camera of the\n"
               "  rig R (JSON). --background takes three numbers in [0,1] (default 0,0,0);\n"
               "  --depth writes the expected depth (metres, float32 HxW, 0 = empty);\n"
               "  --rgb-npy the unquantised colour (float32 HxWx3, for exact comparisons).\n");
}

static int parse_bg(const char *s, float bg[3])
{
    char *end;
    for (int k = 0; k < 3; k++) {
        bg[k] = strtof(s, &end);
        if (end == s || !(bg[k] >= 0.0f && bg[k] <= 1.0f))
            return -1;
        s = end;
        if (k < 2) {
            if (*s != ',')
                return -1;
            s++;
        }
    }
    return *s ? -1 : 0;
}

int main(int argc, char **argv)
{
    const char *ply = NULL, *rigp = NULL, *camname = NULL, *out = NULL, *depthp = NULL, *rgbp = NULL;
    float bg[3] = { 0, 0, 0 };
    int threads = 0;
    for (int i = 1; i < argc; i++) {
        const char *a = argv[i];
        if (!strcmp(a, "-h") || !strcmp(a, "--help")) {
            usage(stdout);
            return 0;
        }
        if (i + 1 >= argc) {
            fprintf(stderr, "f4d-render: option '%s' needs a value (or is unknown)\n", a);
            usage(stderr);
            return 2;
        }
        const char *v = argv[++i];
        if (!strcmp(a, "--ply")) ply = v;
        else if (!strcmp(a, "--rig")) rigp = v;
        else if (!strcmp(a, "--camera")) camname = v;
        else if (!strcmp(a, "-o")) out = v;
        else if (!strcmp(a, "--depth")) depthp = v;
        else if (!strcmp(a, "--rgb-npy")) rgbp = v;
        else if (!strcmp(a, "--threads")) {
            char *end;
            long t = strtol(v, &end, 10);
            if (*end || t < 1 || t > 256) {
                fprintf(stderr, "f4d-render: --threads '%s' must be an integer in 1..256\n", v);
                return 2;
            }
            threads = (int)t;
        } else if (!strcmp(a, "--background")) {
            if (parse_bg(v, bg) < 0) {
                fprintf(stderr, "f4d-render: --background '%s' must be r,g,b with each in [0,1]\n", v);
                return 2;
            }
        } else {
            fprintf(stderr, "f4d-render: unknown option '%s'\n", a);
            usage(stderr);
            return 2;
        }
    }
    if (!ply || !rigp || !camname || !out) {
        fprintf(stderr, "f4d-render: --ply, --rig, --camera and -o are required\n");
        usage(stderr);
        return 2;
    }
    struct f4d_err err = {0};
    struct splat_frame f = { 0 };
    struct splat_rig rig;
    int rc = 1;
    fk_ctx *ctx = NULL;
    splat_renderer *r = NULL;
    float *rgb = NULL, *depth = NULL;
    if (splat_rig_load(rigp, &rig, &err) < 0 || splat_ply_read(ply, &f, &err) < 0 ||
        splat_frame_validate(&f, &err) < 0) {
        fprintf(stderr, "f4d-render: %s\n", err.msg);
        goto done;
    }
    int ci = splat_rig_find(&rig, camname, &err);
    if (ci < 0) {
        fprintf(stderr, "f4d-render: %s\n", err.msg);
        goto done;
    }
    const struct splat_camera *cam = &rig.cams[ci];
    struct fk_ctx_config cfg = { .isa = FK_ISA_AUTO, .threads = threads };
    if (fk_ctx_new(&cfg, &ctx) != F4D_OK) {
        fprintf(stderr, "f4d-render: cannot create the kernel context\n");
        goto done;
    }
    if (splat_renderer_new(ctx, cam->width, cam->height, &r, &err) < 0) {
        fprintf(stderr, "f4d-render: %s\n", err.msg);
        goto done;
    }
    size_t np = (size_t)cam->width * (size_t)cam->height;
    rgb = malloc(3 * np * sizeof *rgb);
    depth = depthp ? malloc(np * sizeof *depth) : NULL;
    if (!rgb || (depthp && !depth)) {
        fprintf(stderr, "f4d-render: out of memory\n");
        goto done;
    }
    struct splat_render_out o = { .rgb = rgb, .depth = depth };
    if (splat_render(r, cam, &f, bg, &o) < 0) {
        fprintf(stderr, "f4d-render: %s\n", splat_renderer_error(r));
        goto done;
    }
    size_t shape[2] = { (size_t)cam->height, (size_t)cam->width },
           shape3[3] = { (size_t)cam->height, (size_t)cam->width, 3 };
    if (splat_png_write_rgb(out, rgb, cam->width, cam->height, &err) < 0 ||
        (rgbp && splat_npy_write_f32(rgbp, rgb, shape3, 3, &err) < 0) ||
        (depthp && splat_npy_write_f32(depthp, depth, shape, 2, &err) < 0)) {
        fprintf(stderr, "f4d-render: %s\n", err.msg);
        goto done;
    }
    printf("rendered %zu Gaussians (%zu visible) from camera '%s' (%dx%d) to %s\n", f.count, o.visible,
           cam->name, cam->width, cam->height, out);
    rc = 0;
done:
    free(rgb);
    free(depth);
    splat_renderer_free(r);
    fk_ctx_free(ctx);
    splat_frame_free(&f);
    return rc;
}
