/* foreground.h - which patches of each view hold the scene: a per-pixel
 * background model learned from the first sets of a take, and per-view
 * patch keep-lists for model_eval_masked (model.h, "Foreground-only
 * evaluation"). Library f4d_foreground (depends on nothing but libm).
 *
 * Contract:
 *   - Learning: K sets of model input ([views, 3, H, W] floats in [0, 1],
 *     what model_eval takes) go through fg_learn. The background of each
 *     pixel and channel is the MEDIAN of its K samples (8-bit), its noise the
 *     median absolute deviation (MAD). The median ignores a mover that covers
 *     a pixel in fewer than half of the samples: feed sets spread over the
 *     first seconds of a take (f4d-bench tokens: 15 sets, every 8th of the
 *     first 4 s of the walk take; over the first 2 s the walker, moving
 *     along some views' line of sight, stayed in half the samples of a
 *     tenth of his pixels) or sets of the empty scene.
 *   - A pixel has CHANGED when some channel differs from the background by
 *     more than max(threshold, noise_k * 1.4826 * MAD) (1.4826 MAD = sigma
 *     for Gaussian noise; MAD = the larger of the pixel's own and the median
 *     MAD of its view and channel, since a MAD of K samples is itself noisy). A patch is FOREGROUND when at least min_fraction
 *     of its patch x patch pixels changed (and at least one). The keep-list
 *     is the foreground patches dilated by `margin` patches (a square,
 *     Chebyshev distance), so a limb entering a patch next to the mover
 *     still runs.
 *   - Everything is allocated by fg_new (K x views x 3 x H x W bytes of
 *     samples, the background, thresholds, the changed-pixel map, patch
 *     counts); fg_learn and fg_mask never allocate. The frame size is fixed
 *     at fg_new: another size needs another model (relearned).
 *   - Not done: updating the background after learning (lighting drift, a
 *     moved chair), shadows (the synthetic scenes cast none).
 *
 *     struct fg_config c = { .views = 4, .height = 518, .width = 518,
 *                            .patch = 14, .samples = 15 };
 *     fg_model *g;
 *     fg_new(&c, &g, &err);
 *     for (k = 0; k < 120; k += 8) fg_learn(g, set[k], &err);  // 15 sets
 *     fg_mask(g, images, 2, keep, kept, &err);   // keep [views * P]
 *     model_eval_masked(m, images, 4, 518, 518, keep, &out);
 *
 * Errors: 0 or a negative F4D_E* code with a message in *err naming the bad
 * argument (err may be NULL).
 */
#ifndef F4D_FOREGROUND_H
#define F4D_FOREGROUND_H

#include <stddef.h>
#include <stdint.h>

#include "f4d_status.h"

#define FG_SAMPLES_MAX 31
#define FG_VIEWS_MAX   16
#define FG_SIZE_MAX    8192   /* height, width */

struct fg_config {
    int   views, height, width;  /* model input geometry                     */
    int   patch;                 /* model patch size: divides height, width  */
    int   samples;               /* K sets learned, 1..FG_SAMPLES_MAX         */
    /* 0 picks the default of each: */
    float threshold;             /* min channel difference, [0,1] units: 0.1  */
    float noise_k;               /* x 1.4826 MAD of the samples: 5            */
    float min_fraction;          /* changed pixels for a foreground patch: 0.02 */
};

typedef struct fg_model fg_model;

int  fg_new  (const struct fg_config *c, fg_model **out, struct f4d_err *err);
void fg_free (fg_model *g);
/* One set [views, 3, H, W] into the learning samples. Returns 1 when this
 * was the K-th (the background is built and fg_mask may run), 0 before;
 * F4D_EINVAL once ready (fg_reset starts learning over). */
int  fg_learn(fg_model *g, const float *images, struct f4d_err *err);
int  fg_ready(const fg_model *g);
void fg_reset(fg_model *g);
/* The keep-list of one set: keep [views * P] (P = (H/patch) * (W/patch),
 * row-major per view; 1 = run the patch), margin >= 0 patches of dilation;
 * kept [views] (optional) gets the kept patches per view. F4D_EINVAL before
 * the background is ready. */
int  fg_mask (fg_model *g, const float *images, int margin, uint8_t *keep, int *kept,
              struct f4d_err *err);
/* Changed pixels of the last fg_mask, [views, H, W] (1 = changed), owned by
 * g; and the background, [views, 3, H, W] 8-bit, once ready. */
const uint8_t *fg_pixels   (const fg_model *g);
const uint8_t *fg_background(const fg_model *g);

#endif /* F4D_FOREGROUND_H */
