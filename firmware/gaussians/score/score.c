/* score.c - a venue take's ground truth and scores against it (f4d_score.h).
 * Moved out of tools/f4d-eval so that forge4d report scores the same way. */
#include <cjson/cJSON.h>
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "f4d_score.h"
#include "fk_resize.h"
#include "npy.h"

struct score_view {
    const struct score_take *t;
    splat_renderer *ren;
    float *out, *ssim;
};

static int load(const char *dir, const char *name, float **a, int64_t *shape, int want_nd, int optional,
                struct f4d_err *err)
{
    char path[1200];
    int nd;
    snprintf(path, sizeof path, "%s/%s.npy", dir, name);
    if (optional && access(path, R_OK) != 0)
        return 1;
    if (npy_load_f32(path, a, shape, &nd, err) < 0)
        return -1;
    if (nd != want_nd)
        return f4d_fail(err, F4D_EFORMAT, "%s: %d dimensions, expected %d", path, nd, want_nd);
    return 0;
}

static int same(const int64_t *s, int nd, const int64_t *want)
{
    for (int i = 0; i < nd; i++)
        if (s[i] != want[i])
            return 0;
    return 1;
}

int score_take_load(const char *dir, struct score_take *t, struct f4d_err *err)
{
    int64_t s[NPY_MAX_DIMS];
    memset(t, 0, sizeof *t);
    if (!dir || !*dir)
        return f4d_fail(err, F4D_EINVAL, "take: no folder given");
    if (strlen(dir) >= sizeof t->dir)
        return f4d_fail(err, F4D_ERANGE, "take: folder name too long");
    snprintf(t->dir, sizeof t->dir, "%s", dir);
    char path[1200];
    snprintf(path, sizeof path, "%s/rgb.npy", dir);
    if (access(path, R_OK) != 0)
        return f4d_fail(err, F4D_ENOENT, "take %s: no rgb.npy (%s): not a venue take (tools/f4d-scene venue)", dir,
                        strerror(errno));
    if (load(dir, "rgb", &t->rgb, s, 5, 0, err) < 0)
        return -1;
    t->T = (int)s[0], t->V = (int)s[1], t->H = (int)s[2], t->W = (int)s[3];
    if (s[4] != 3 || t->T < 1 || t->V < 1 || t->H < 1 || t->W < 1)
        return f4d_fail(err, F4D_EFORMAT, "take %s: rgb.npy is not [T,V,H,W,3]", dir);
    int64_t tv[4] = { t->T, t->V, t->H, t->W }, tv3[5] = { t->T, t->V, t->H, t->W, 3 };
    if (load(dir, "depth", &t->depth, s, 4, 0, err) < 0)
        return -1;
    if (!same(s, 4, tv))
        return f4d_fail(err, F4D_EFORMAT, "take %s: depth.npy is not [T,V,H,W] of rgb.npy", dir);
    if (load(dir, "alpha", &t->alpha, s, 4, 0, err) < 0)
        return -1;
    if (!same(s, 4, tv))
        return f4d_fail(err, F4D_EFORMAT, "take %s: alpha.npy is not [T,V,H,W] of rgb.npy", dir);
    /* a take without held-out cameras (venue --eval 0) has no eval_* files */
    int rc = load(dir, "eval_rgb", &t->ergb, s, 5, 1, err);
    if (rc < 0)
        return -1;
    if (rc == 0) {
        t->E = (int)s[1];
        if (s[0] != t->T || s[2] != t->H || s[3] != t->W || s[4] != 3 || t->E < 1)
            return f4d_fail(err, F4D_EFORMAT, "take %s: eval_rgb and rgb disagree on keys or size", dir);
    }
    if ((rc = load(dir, "motion_bwd", &t->motion_bwd, s, 5, 1, err)) < 0)
        return -1;
    if (rc == 0 && !same(s, 5, tv3))
        return f4d_fail(err, F4D_EFORMAT, "take %s: motion_bwd.npy is not [T,V,H,W,3]", dir);
    if ((rc = load(dir, "motion_fwd", &t->motion_fwd, s, 5, 1, err)) < 0)
        return -1;
    if (rc == 0 && !same(s, 5, tv3))
        return f4d_fail(err, F4D_EFORMAT, "take %s: motion_fwd.npy is not [T,V,H,W,3]", dir);
    if (t->T > 1) {
        int64_t m5[5] = { t->T - 1, t->V + t->E, t->H, t->W, 3 };
        if ((rc = load(dir, "mid_rgb", &t->mid, s, 5, 1, err)) < 0)
            return -1;
        if (rc == 0 && !same(s, 5, m5))
            return f4d_fail(err, F4D_EFORMAT, "take %s: mid_rgb.npy is not [T-1,V+E,H,W,3]", dir);
    }
    int64_t b4[4] = { t->V, t->H, t->W, 3 };
    if ((rc = load(dir, "background_rgb", &t->background, s, 4, 1, err)) < 0)
        return -1;
    if (rc == 0 && !same(s, 4, b4))
        return f4d_fail(err, F4D_EFORMAT, "take %s: background_rgb.npy is not [V,H,W,3]", dir);
    snprintf(path, sizeof path, "%s/rig.json", dir);
    if (splat_rig_load(path, &t->rig, err) < 0)
        return -1;
    snprintf(path, sizeof path, "%s/eval_rig.json", dir);
    if (t->E && splat_rig_load(path, &t->erig, err) < 0)
        return -1;
    if (t->rig.count != t->V || t->erig.count != t->E)
        return f4d_fail(err, F4D_EFORMAT, "take %s: rigs have %d + %d cameras, arrays %d + %d", dir, t->rig.count,
                        t->erig.count, t->V, t->E);
    for (int i = 0; i < t->rig.count + t->erig.count; i++) {
        const struct splat_camera *c = i < t->V ? &t->rig.cams[i] : &t->erig.cams[i - t->V];
        if (c->width != t->W || c->height != t->H)
            return f4d_fail(err, F4D_EFORMAT, "take %s: camera %s is %dx%d, the images %dx%d", dir, c->name,
                            c->width, c->height, t->W, t->H);
    }
    snprintf(path, sizeof path, "%s/take.json", dir);
    FILE *f = fopen(path, "rb");
    if (!f)
        return f4d_fail(err, F4D_EIO, "cannot open %s", path);
    char buf[16384];
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
    cJSON *fps = cJSON_GetObjectItem(j, "fps");
    t->fps = cJSON_IsNumber(fps) && fps->valuedouble > 0 ? (float)fps->valuedouble : 30.0f;
    cJSON_Delete(j);
    return 0;
}

void score_take_free(struct score_take *t)
{
    if (!t)
        return;
    free(t->rgb); free(t->depth); free(t->alpha); free(t->ergb); free(t->mid); free(t->motion_bwd); free(t->motion_fwd);
    free(t->background);
    memset(t, 0, sizeof *t);
}

size_t score_input_scratch_floats(const struct score_take *t)
{
    return 2 * 3 * (size_t)t->H * (size_t)t->W; /* one view HWC, one resized (never larger than the take) */
}

/* One HWC view [H,W,3] into CHW [3,h,w], resized when the size differs. */
static int to_input(fk_ctx *ctx, const struct score_take *t, const float *hwc, int h, int w, float *scratch,
                    float *out, struct f4d_err *err)
{
    const size_t np = (size_t)h * (size_t)w;
    const float *src = hwc;
    if (h != t->H || w != t->W) {
        if (h > t->H || w > t->W || h < 1 || w < 1)
            return f4d_fail(err, F4D_EINVAL, "take %s: input size %dx%d must be within the take's %dx%d", t->dir, w,
                            h, t->W, t->H);
        if (fk_resize_bicubic_aa(ctx, hwc, t->H, t->W, 3, scratch, h, w) != F4D_OK)
            return f4d_fail(err, F4D_EINVAL, "take %s: resize to %dx%d failed: %s", t->dir, w, h, fk_ctx_error(ctx));
        src = scratch;
    }
    for (int c = 0; c < 3; c++)
        for (size_t p = 0; p < np; p++) /* as the take stores it (what f4d-eval and training feed) */
            out[c * np + p] = src[3 * p + c];
    return 0;
}

int score_take_input(fk_ctx *ctx, const struct score_take *t, int k, int h, int w, float *scratch, float *out,
                     struct f4d_err *err)
{
    if (k < 0 || k >= t->T)
        return f4d_fail(err, F4D_EINVAL, "take %s: key %d of %d", t->dir, k, t->T);
    const size_t np = (size_t)t->H * (size_t)t->W;
    for (int v = 0; v < t->V; v++)
        if (to_input(ctx, t, t->rgb + ((size_t)k * t->V + v) * np * 3, h, w, scratch,
                     out + (size_t)v * 3 * (size_t)h * (size_t)w, err) < 0)
            return -1;
    return 0;
}

int score_take_background(fk_ctx *ctx, const struct score_take *t, int h, int w, float *scratch, float *out,
                          struct f4d_err *err)
{
    if (!t->background)
        return f4d_fail(err, F4D_ENOENT, "take %s: no background_rgb.npy", t->dir);
    const size_t np = (size_t)t->H * (size_t)t->W;
    for (int v = 0; v < t->V; v++)
        if (to_input(ctx, t, t->background + (size_t)v * np * 3, h, w, scratch,
                     out + (size_t)v * 3 * (size_t)h * (size_t)w, err) < 0)
            return -1;
    return 0;
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

static void to_view0(const struct score_take *t, const struct splat_camera *src, struct splat_camera *cam)
{
    float inv0[16];
    rigid_inv(t->rig.cams[0].w2c, inv0);
    *cam = *src;
    mul44(src->w2c, inv0, cam->w2c);
}

void score_eval_camera(const struct score_take *t, int e, struct splat_camera *cam)
{
    to_view0(t, &t->erig.cams[e], cam);
}

void score_input_camera(const struct score_take *t, int v, struct splat_camera *cam)
{
    to_view0(t, &t->rig.cams[v], cam);
}

int score_view_new(fk_ctx *ctx, const struct score_take *t, score_view **out, struct f4d_err *err)
{
    *out = NULL;
    score_view *sv = calloc(1, sizeof *sv);
    if (!sv)
        return f4d_fail(err, F4D_ENOMEM, "score: out of memory");
    sv->t = t;
    sv->out = malloc(3 * (size_t)t->H * (size_t)t->W * sizeof(float));
    sv->ssim = malloc(splat_ssim_scratch_floats(t->W, t->H) * sizeof(float));
    if (!sv->out || !sv->ssim) {
        score_view_free(sv);
        return f4d_fail(err, F4D_ENOMEM, "score: out of memory");
    }
    if (splat_renderer_new(ctx, t->W, t->H, &sv->ren, err) < 0) {
        score_view_free(sv);
        return -1;
    }
    *out = sv;
    return 0;
}

void score_view_free(score_view *sv)
{
    if (!sv)
        return;
    splat_renderer_free(sv->ren);
    free(sv->out);
    free(sv->ssim);
    free(sv);
}

int score_render(score_view *sv, const struct splat_camera *cam, const struct splat_frame *f, struct f4d_err *err)
{
    struct splat_render_out ro = { .rgb = sv->out };
    if (splat_render(sv->ren, cam, f, sv->t->sky, &ro) < 0)
        return f4d_fail(err, F4D_EINVAL, "score: %s", splat_renderer_error(sv->ren));
    const size_t n = 3 * (size_t)sv->t->H * (size_t)sv->t->W;
    for (size_t i = 0; i < n; i++)
        sv->out[i] = sv->out[i] < 0 ? 0 : (sv->out[i] > 1 ? 1 : sv->out[i]);
    return 0;
}

const float *score_view_rgb(const score_view *sv)
{
    return sv->out;
}

void score_compare(score_view *sv, const float *gt, double *psnr, double *ssim)
{
    const struct score_take *t = sv->t;
    *psnr = splat_psnr(sv->out, gt, t->W, t->H, 3);
    if (ssim)
        *ssim = splat_ssim(sv->out, gt, t->W, t->H, 3, sv->ssim);
}

/* Mean PSNR / SSIM of f at every evaluation camera against gt + e * image. */
static int score_images(score_view *sv, const struct splat_frame *f, const float *gt, double *psnr, double *ssim,
                        struct f4d_err *err)
{
    const struct score_take *t = sv->t;
    const size_t img = 3 * (size_t)t->H * (size_t)t->W;
    double p = 0, s = 0;
    for (int e = 0; e < t->E; e++) {
        struct splat_camera cam;
        score_eval_camera(t, e, &cam);
        if (score_render(sv, &cam, f, err) < 0)
            return -1;
        double pe, se;
        score_compare(sv, gt + (size_t)e * img, &pe, &se);
        p += pe;
        s += se;
    }
    *psnr = p / t->E;
    *ssim = s / t->E;
    return 0;
}

int score_novel_view(score_view *sv, const struct splat_frame *f, int k, double *psnr, double *ssim,
                     struct f4d_err *err)
{
    const struct score_take *t = sv->t;
    if (!t->E)
        return f4d_fail(err, F4D_ENOENT, "take %s: no held-out cameras (eval_rgb.npy)", t->dir);
    if (k < 0 || k >= t->T)
        return f4d_fail(err, F4D_EINVAL, "take %s: key %d of %d", t->dir, k, t->T);
    return score_images(sv, f, t->ergb + (size_t)k * t->E * 3 * (size_t)t->H * (size_t)t->W, psnr, ssim, err);
}

int score_novel_time(score_view *sv, const struct splat_frame *f, int k, double *psnr, double *ssim,
                     struct f4d_err *err)
{
    const struct score_take *t = sv->t;
    if (!t->mid)
        return f4d_fail(err, F4D_ENOENT, "take %s: no mid_rgb.npy", t->dir);
    if (k < 0 || k >= t->T - 1)
        return f4d_fail(err, F4D_EINVAL, "take %s: mid time %d + 1/2 of %d keys", t->dir, k, t->T);
    const size_t img = 3 * (size_t)t->H * (size_t)t->W;
    return score_images(sv, f, t->mid + ((size_t)k * (t->V + t->E) + t->V) * img, psnr, ssim, err);
}

/* The full-size pixel nearest to the ray of input pixel (x, y) at h x w, and
 * that ray's direction at unit depth in camera v's frame. */
static size_t ray(const struct score_take *t, const struct splat_camera *cv, int x, int y, int h, int w, float *d)
{
    float u = ((float)x + 0.5f) * (float)t->W / (float)w, q = ((float)y + 0.5f) * (float)t->H / (float)h;
    int px = (int)u, py = (int)q;
    px = px >= t->W ? t->W - 1 : px;
    py = py >= t->H ? t->H - 1 : py;
    d[0] = (u - cv->cx) / cv->fx;
    d[1] = (q - cv->cy) / cv->fy;
    d[2] = 1.0f;
    return (size_t)py * t->W + px;
}

int score_points(const struct score_take *t, int k, const float *pos, int h, int w, double *sum, size_t *n,
                 struct f4d_err *err)
{
    if (k < 0 || k >= t->T || h < 1 || w < 1)
        return f4d_fail(err, F4D_EINVAL, "take %s: points of key %d at %dx%d", t->dir, k, w, h);
    const size_t np = (size_t)t->H * t->W, nq = (size_t)h * w;
    double s = 0;
    size_t c = 0;
    float inv0[16];
    rigid_inv(t->rig.cams[0].w2c, inv0);
    for (int v = 0; v < t->V; v++) {
        const struct splat_camera *cv = &t->rig.cams[v];
        float rel[16];
        mul44(cv->w2c, inv0, rel); /* view 0 -> camera v */
        for (int y = 0; y < h; y++)
            for (int x = 0; x < w; x++) {
                float dir[3];
                size_t p = ray(t, cv, x, y, h, w, dir), i = ((size_t)k * t->V + v) * np + p;
                if (t->alpha[i] <= 0.5f)
                    continue;
                float dz = t->depth[i], pc[3] = { dir[0] * dz, dir[1] * dz, dz }, X[3];
                for (int a = 0; a < 3; a++) /* camera v -> view 0: rel^-1 applied to pc */
                    X[a] = rel[a] * (pc[0] - rel[3]) + rel[4 + a] * (pc[1] - rel[7]) + rel[8 + a] * (pc[2] - rel[11]);
                const float *g = pos + 3 * ((size_t)v * nq + (size_t)y * w + x);
                s += sqrt((double)(g[0] - X[0]) * (g[0] - X[0]) + (double)(g[1] - X[1]) * (g[1] - X[1]) +
                          (double)(g[2] - X[2]) * (g[2] - X[2]));
                c++;
            }
    }
    *sum = s;
    *n = c;
    return 0;
}

void score_cameras(const struct score_take *t, const float *ext, double *rot_sum, double *trans_sum)
{
    float inv0[16];
    rigid_inv(t->rig.cams[0].w2c, inv0);
    double re = 0, te = 0;
    for (int v = 0; v < t->V; v++) {
        float rel[16];
        mul44(t->rig.cams[v].w2c, inv0, rel);
        const float *pe = ext + 12 * v;
        double tr = 0, dt = 0;
        for (int a = 0; a < 3; a++) {
            for (int b = 0; b < 3; b++)
                tr += (double)pe[4 * a + b] * rel[4 * a + b];
            dt += ((double)pe[4 * a + 3] - rel[4 * a + 3]) * ((double)pe[4 * a + 3] - rel[4 * a + 3]);
        }
        /* the predicted rotation need not be exactly orthonormal: clamp the cosine */
        double cs = (tr - 1.0) / 2.0;
        cs = cs > 1 ? 1 : (cs < -1 ? -1 : cs);
        re += acos(cs) * 180.0 / 3.14159265358979323846;
        te += sqrt(dt);
    }
    *rot_sum = re;
    *trans_sum = te;
}

int score_motion(const struct score_take *t, int k, const float *motion, int h, int w, double *sum, size_t *n,
                 struct f4d_err *err)
{
    if (!t->motion_bwd)
        return f4d_fail(err, F4D_ENOENT, "take %s: no motion_bwd.npy", t->dir);
    if (k < 1 || k >= t->T || h < 1 || w < 1)
        return f4d_fail(err, F4D_EINVAL, "take %s: motion of key %d at %dx%d", t->dir, k, w, h);
    const size_t np = (size_t)t->H * t->W, nq = (size_t)h * w;
    const float *R = t->rig.cams[0].w2c; /* a displacement turns with view 0's rotation only */
    double s = 0;
    size_t c = 0;
    for (int v = 0; v < t->V; v++)
        for (int y = 0; y < h; y++)
            for (int x = 0; x < w; x++) {
                float dir[3];
                size_t p = ray(t, &t->rig.cams[v], x, y, h, w, dir), i = ((size_t)k * t->V + v) * np + p;
                if (t->alpha[i] <= 0.5f)
                    continue;
                const float *m = t->motion_bwd + 3 * i, *g = motion + 3 * ((size_t)v * nq + (size_t)y * w + x);
                double e2 = 0;
                for (int a = 0; a < 3; a++) {
                    double d = (double)g[a] - (R[4 * a] * m[0] + R[4 * a + 1] * m[1] + R[4 * a + 2] * m[2]);
                    e2 += d * d;
                }
                s += sqrt(e2);
                c++;
            }
    *sum = s;
    *n = c;
    return 0;
}
