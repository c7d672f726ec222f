/* f4d_score.h - ground truth of a venue take and the scores of predicted metric
 * Gaussians against it. Library f4d_score; depends on firmware/gaussians/splat
 * (renderer, PSNR / SSIM), firmware/infer/npy (the arrays) and the kernels
 * (resize). Used by tools/f4d-eval (the paper's table) and `forge4d report`
 * (the speed-vs-error study), so both score a take the same way.
 *
 * A venue take (tools/f4d-scene venue, tools/train/gen_data.py) is a folder:
 *   rgb [T,V,H,W,3], depth / alpha [T,V,H,W], rig.json (splat rig format),
 *   take.json ("sky", "fps"),
 *   optional: eval_rgb [T,E,H,W,3] with eval_rig.json (held-out cameras; a
 *   take of venue --eval 0 has none: E = 0, and novel views cannot be scored),
 *   motion_bwd / motion_fwd [T,V,H,W,3] (per-pixel 3-D motion to
 *   the key before / after, metres), mid_rgb [T-1,V+E,H,W,3] (renders at the
 *   mid times k + 1/2, input views first), background_rgb [V,H,W,3] (the
 *   venue without people).
 *
 * Frames: the model's world is its first input camera (view 0), metric. Every
 * score moves the ground truth into that frame (no alignment: the gauge's
 * metric scale and the predicted cameras both count).
 *
 *     struct score_take t;  struct f4d_err err = {0};
 *     if (score_take_load("take/", &t, &err) < 0) puts(err.msg);
 *     score_view *sv;  score_view_new(ctx, &t, &sv, &err);
 *     double psnr, ssim;
 *     score_novel_view(sv, &frame, k, &psnr, &ssim, &err);   // eval cameras at key k
 *     score_view_free(sv);  score_take_free(&t);
 *
 * Scores (means; the caller weights them by the counts it is given):
 *   novel view  renders at the held-out evaluation cameras against eval_rgb
 *               (colours clamped to [0, 1], 3DGS PSNR and SSIM);
 *   novel time  the same at the mid time k + 1/2 against mid_rgb;
 *   points      each input pixel's Gaussian centre (pixel aligned, at any
 *               input size h x w) against the true surface point on the same
 *               pixel ray (the true depth at the nearest full-size pixel),
 *               pixels with alpha > 0.5 only;
 *   cameras     rotation angle (degrees) and translation distance (m) of the
 *               predicted metric world-to-camera against the truth;
 *   motion      end-point error (m) of the per-pixel backward motion M1[k]
 *               (key k to k-1) against motion_bwd, alpha > 0.5 pixels.
 * Nothing here allocates after _load / _new.
 *
 * Errors: 0 or a negative F4D_E* code with a message naming the file, array
 * or argument at fault.
 */
#ifndef F4D_SCORE_H
#define F4D_SCORE_H

#include <stddef.h>

#include "f4d_status.h"
#include "fk_ctx.h"
#include "splat.h"

#ifdef __cplusplus
extern "C" {
#endif

struct score_take {
    char   dir[1024];
    int    T, V, E, H, W;
    float  fps;                     /* key rate of the take (take.json "fps", else 30) */
    float *rgb, *depth, *alpha;     /* [T,V,H,W,3], [T,V,H,W], [T,V,H,W]               */
    float *ergb;                    /* [T,E,H,W,3] or NULL (E = 0)                     */
    float *mid;                     /* [T-1,V+E,H,W,3] or NULL                         */
    float *motion_bwd, *motion_fwd; /* [T,V,H,W,3] each, or NULL                       */
    float *background;              /* [V,H,W,3] or NULL                               */
    struct splat_rig rig, erig;     /* input and evaluation cameras (venue world)      */
    float  sky[3];
};

int  score_take_load(const char *dir, struct score_take *t, struct f4d_err *err);
void score_take_free(struct score_take *t);

/* Model input of key k: [V, 3, h, w] (the take's values as stored), resized from H x W with the
 * antialiased bicubic (fk_resize_bicubic_aa) when the size differs. scratch:
 * score_input_scratch_floats(t) floats. */
size_t score_input_scratch_floats(const struct score_take *t);
int  score_take_input(fk_ctx *ctx, const struct score_take *t, int k, int h, int w, float *scratch, float *out,
                      struct f4d_err *err);
/* The background plate as model input [V, 3, h, w] (F4D_ENOENT without one). */
int  score_take_background(fk_ctx *ctx, const struct score_take *t, int h, int w, float *scratch, float *out,
                           struct f4d_err *err);

/* Evaluation camera e (or input camera v) in view 0's frame. */
void score_eval_camera(const struct score_take *t, int e, struct splat_camera *cam);
void score_input_camera(const struct score_take *t, int v, struct splat_camera *cam);

/* Renderer and buffers at the take's size. */
typedef struct score_view score_view;
int  score_view_new(fk_ctx *ctx, const struct score_take *t, score_view **out, struct f4d_err *err);
void score_view_free(score_view *sv);
/* Mean PSNR / SSIM of f over the evaluation cameras at key k (E >= 1). */
int  score_novel_view(score_view *sv, const struct splat_frame *f, int k, double *psnr, double *ssim,
                      struct f4d_err *err);
/* The same at mid time k + 1/2 (0 <= k < T - 1; F4D_ENOENT without mid_rgb). */
int  score_novel_time(score_view *sv, const struct splat_frame *f, int k, double *psnr, double *ssim,
                      struct f4d_err *err);
/* Renders f at camera cam into the view's buffer, colours clamped to [0, 1]
 * (for timing a displayed frame, or scoring it at a camera of the caller's
 * choice with score_compare). */
int  score_render(score_view *sv, const struct splat_camera *cam, const struct splat_frame *f, struct f4d_err *err);
/* The view's buffer: the last render, [H,W,3]. */
const float *score_view_rgb(const score_view *sv);
/* PSNR and SSIM of the last render against gt [H,W,3] (ssim may be NULL: not computed). */
void score_compare(score_view *sv, const float *gt, double *psnr, double *ssim);

/* Sum of point distances (m) and the pixels counted, key k, pos [3 * V*h*w]. */
int  score_points(const struct score_take *t, int k, const float *pos, int h, int w, double *sum, size_t *n,
                  struct f4d_err *err);
/* Sums of rotation errors (deg) and translation errors (m) over the V views,
 * ext [V, 3, 4] metric world-to-camera in view 0's frame. */
void score_cameras(const struct score_take *t, const float *ext, double *rot_sum, double *trans_sum);
/* Sum of motion end-point errors (m) and pixels counted, key k >= 1, motion
 * [3 * V*h*w] (M1[k], view 0's frame); F4D_ENOENT without motion_bwd. */
int  score_motion(const struct score_take *t, int k, const float *motion, int h, int w, double *sum, size_t *n,
                  struct f4d_err *err);

#ifdef __cplusplus
}
#endif
#endif /* F4D_SCORE_H */
