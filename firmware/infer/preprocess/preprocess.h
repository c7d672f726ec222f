/* preprocess.h - camera frames to the model's input, as VGGT's demo loader
 * (load_and_preprocess_images, vggt.md 1a) does it.
 *
 * Frames arrive as the HAL delivers them (RGB8, Mono8 or Bayer RG8; the enum
 * values are those of hal_pixfmt). Mono8 is replicated to RGB (PIL convert);
 * Bayer RGGB is demosaiced bilinearly. Then, with target T (518 for VGGT):
 *   crop: width -> T, height -> rint(h * (T / w) / 14) * 14 (half to even, as
 *         Python's round), PIL BICUBIC resize, centre crop of rows to T;
 *   pad:  the longer side -> T, the shorter rounded the same way, resize, then
 *         white (1.0) padding to T x T, top/left = floor(delta / 2).
 * The resize reproduces PIL's 8-bit BICUBIC exactly: antialiased cubic
 * (a = -0.5) coefficients in fixed point (22 fraction bits), horizontal pass
 * first, each pass rounded and clamped to 8 bits. Output is float CHW / 255.
 * Frames of different sizes in one batch are padded with white, centred, to
 * the largest height and width.
 *
 *     size_t need = prep_scratch_bytes(1280, 960, 518);   // at configure time
 *     struct prep_image im = { data, 1280, 960, 1280 * 3, PREP_PIXFMT_RGB8 };
 *     int H, W;
 *     prep_batch(&im, 1, PREP_CROP, 518, scratch, need, out, &H, &W, &err);
 *
 * No allocation: the caller passes scratch of prep_scratch_bytes() for the
 * largest frame and an output of 3 * H * W floats per frame (prep_output_size).
 */
#ifndef F4D_PREPROCESS_H
#define F4D_PREPROCESS_H

#include <stddef.h>
#include <stdint.h>

#include "f4d_status.h"

enum prep_pixfmt {              /* = enum hal_pixfmt values */
    PREP_PIXFMT_MONO8     = 1,
    PREP_PIXFMT_RGB8      = 2,
    PREP_PIXFMT_BAYER_RG8 = 3,
};

enum prep_mode { PREP_CROP = 0, PREP_PAD = 1 };

struct prep_image {
    const uint8_t *data;
    int            width, height;
    size_t         stride;      /* bytes per row */
    int            pixfmt;      /* enum prep_pixfmt */
};

/* Size after resize and crop/pad of one w x h frame; < 0 if the frame or
 * target is unusable (message in err). */
int    prep_output_size  (int w, int h, enum prep_mode mode, int target, int *ow, int *oh);
size_t prep_scratch_bytes(int w, int h, int target);
/* One frame into out [3, oh, ow]. */
int    prep_image        (const struct prep_image *im, enum prep_mode mode, int target,
                          void *scratch, size_t scratch_bytes, float *out, int *ow, int *oh,
                          struct f4d_err *err);
/* n frames into out [n, 3, H, W] (H, W the largest); `out` must hold
 * n * 3 * target * target floats. */
int    prep_batch        (const struct prep_image *ims, int n, enum prep_mode mode, int target,
                          void *scratch, size_t scratch_bytes, float *out, int *H, int *W,
                          struct f4d_err *err);

/* Bilinear demosaic of an RGGB mosaic into RGB8 (exposed for tests). */
void   prep_demosaic_rggb(const uint8_t *src, size_t stride, int w, int h, uint8_t *rgb);

#endif
