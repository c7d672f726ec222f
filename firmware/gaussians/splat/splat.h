/* splat.h - metric 3D Gaussian frames, cameras, the CPU rasterizer, PLY / PNG /
 * .npy I/O and image metrics. Library f4d_splat; depends on kernels/ (fk) only,
 * so the simulated HAL and the tools can render without the pipeline.
 *
 *     struct f4d_err err;
 *     struct splat_frame f = {0};
 *     struct splat_rig rig;
 *     if (splat_ply_read("donut.ply", &f, &err) < 0 ||
 *         splat_rig_load("rig.json", &rig, &err) < 0) { puts(err.msg); ... }
 *     splat_renderer *r;
 *     splat_renderer_new(ctx, rig.cams[0].width, rig.cams[0].height, &r, &err);
 *     float *rgb = malloc(3 * W * H * sizeof *rgb);
 *     struct splat_render_out out = { .rgb = rgb };
 *     splat_render(r, &rig.cams[0], &f, NULL, &out);   // bg NULL = black
 *     splat_png_write_rgb("out.png", rgb, W, H, &err);
 *
 * Conventions (all metric, SI units):
 *   - Positions in metres, world frame chosen by the producer (the synthetic
 *     scenes use z up). Motions are displacements in metres over one key
 *     interval: motion_bwd moves a Gaussian of key t to its place at t-1,
 *     motion_fwd to its place at t+1 (Forge4D's M1[t] and M2[t]).
 *   - Values are stored ACTIVATED: scale is the standard deviation per local
 *     axis in metres (PLY stores log), opacity is in [0,1] (PLY stores the
 *     logit), rgb is linear colour, nominally [0,1] (PLY stores the SH degree-0
 *     coefficient, rgb = 0.5 + C0 * f_dc). Rotations are unit quaternions
 *     (w, x, y, z) mapping the local axes to the world.
 *   - Cameras: OpenCV axes (x right, y down, z forward), world_to_camera is a
 *     4x4 row-major matrix [R | t] as in VGGT extrinsics; pinhole fx, fy, cx, cy
 *     in pixels.
 *   - Pixel centres: pixel (i, j) is sampled at image coordinate (i + 0.5,
 *     j + 0.5) where a camera point projects to u = fx x / z + cx (gsplat's
 *     convention). Internally we evaluate pixel i at integer i with the mean at
 *     u - 0.5, which is bit-for-bit the reference rasterizer's ndc2Pix when
 *     cx = W / 2.
 *
 * Errors: functions return 0 (or a count) on success and a negative
 * splat_status on failure, with a message naming the problem in *err when err
 * is not NULL. Nothing here calls exit() or abort().
 */
#ifndef F4D_SPLAT_H
#define F4D_SPLAT_H

#include "f4d_status.h"

#include <stddef.h>
#include <stdint.h>

#include "fk_ctx.h"

#ifdef __cplusplus
extern "C" {
#endif

/* SH degree-0 constant of the reference rasterizer (auxiliary.h SH_C0). */
#define SPLAT_SH_C0 0.28209479177387814f

/* ------------------------------------------------------------------------ */
/* Gaussian frame: structure of arrays, `count` Gaussians, `capacity` slots. */

struct splat_frame {
    size_t count;
    size_t capacity;
    float *pos;        /* [3 * cap] metres, world                           */
    float *scale;      /* [3 * cap] metres, std dev along local x, y, z      */
    float *rot;        /* [4 * cap] unit quaternion w, x, y, z               */
    float *opacity;    /* [cap] in [0, 1]                                    */
    float *rgb;        /* [3 * cap] linear colour, rendered clamped to >= 0  */
    float *motion_bwd; /* [3 * cap] or NULL: metres, key t -> t-1            */
    float *motion_fwd; /* [3 * cap] or NULL: metres, key t -> t+1            */
};

/* Grows the arrays to hold `capacity` Gaussians (count is kept); with_motion
 * also allocates both motion arrays (zero-filled). A zero-initialised struct
 * is a valid empty frame. */
int  splat_frame_reserve(struct splat_frame *f, size_t capacity, int with_motion,
                         struct f4d_err *err);
/* Sets count = n after reserving; new slots are zero with identity rotation. */
int  splat_frame_resize (struct splat_frame *f, size_t n, int with_motion,
                         struct f4d_err *err);
/* Deep copy of src into dst (dst is grown, its motion arrays follow src). */
int  splat_frame_copy   (struct splat_frame *dst, const struct splat_frame *src,
                         struct f4d_err *err);
void splat_frame_free   (struct splat_frame *f);
/* Checks every value is finite, scales >= 0, opacity in [0,1]; names the
 * first offending Gaussian. */
int  splat_frame_validate(const struct splat_frame *f, struct f4d_err *err);

/* ------------------------------------------------------------------------ */
/* Cameras and rigs (JSON: {"cameras": [{"name", "width", "height", "fx",
 * "fy", "cx", "cy", "world_to_camera": [16 numbers or 4 rows of 4]}]}). */

#define SPLAT_RIG_MAX      16
#define SPLAT_NAME_MAX     64

struct splat_camera {
    char  name[SPLAT_NAME_MAX];
    int   width, height;
    float fx, fy, cx, cy;
    float w2c[16];     /* row-major world_to_camera; last row 0 0 0 1 */
};

struct splat_rig {
    int                 count;
    struct splat_camera cams[SPLAT_RIG_MAX];
};

int  splat_rig_load      (const char *path, struct splat_rig *rig, struct f4d_err *err);
int  splat_rig_parse     (const char *json, struct splat_rig *rig, struct f4d_err *err);
int  splat_rig_save      (const char *path, const struct splat_rig *rig, struct f4d_err *err);
/* Index of the camera called `name_or_index`, or parsed as a decimal index. */
int  splat_rig_find      (const struct splat_rig *rig, const char *name_or_index,
                          struct f4d_err *err);
/* Checks sizes > 0, focal > 0, finite values, orthonormal rotation block. */
int  splat_camera_validate(const struct splat_camera *cam, struct f4d_err *err);
/* A camera at `eye` looking at `target` with `up` roughly upward in the image. */
void splat_camera_look_at(struct splat_camera *cam, const float eye[3],
                          const float target[3], const float up[3]);
/* Camera centre in world coordinates. */
void splat_camera_center (const struct splat_camera *cam, float c[3]);
/* World point to camera coordinates. */
void splat_camera_to_cam (const struct splat_camera *cam, const float p[3], float q[3]);
/* Projects one Gaussian as the rasterizer does (EWA, clamped Jacobian) but
 * without the 0.3 px² dilation: mean[2] in image coordinates (u = fx x/z + cx)
 * and cov[3] = (xx, xy, yy) in px². Returns 0 when culled (z <= 0.2 or not
 * finite), 1 otherwise. */
int  splat_camera_project(const struct splat_camera *cam, const float pos[3], const float scale[3],
                          const float rot[4], float mean[2], float cov[3]);

/* ------------------------------------------------------------------------ */
/* Rasterizer: the reference 3DGS forward pass (gaussians.md §1, R):
 * cull z <= 0.2, EWA with the Jacobian clamped to 1.3 tan(fov), +0.3 px²
 * dilation, radius ceil(3 sqrt(lambda_max)), 16x16 tiles with per-tile lists
 * in depth order (ties by index), front-to-back alpha = min(0.99, o exp(power)),
 * skip alpha < 1/255, stop before T < 1e-4. Work runs on the fk pool (all
 * of the context's threads); the image does not depend on the thread count.
 * The fk context's ISA picks the path: FK_ISA_REF is plain scalar C with
 * libm's expf; AVX2 does the same operations 8 at a time (identical culling
 * and tiles) with a vector exp within 2 ulp of expf, so pixels agree to
 * ~1e-6. Tested against a brute-force per-pixel version of R. */

#define SPLAT_TILE         16
#define SPLAT_NEAR         0.2f
#define SPLAT_DILATION     0.3f
#define SPLAT_ALPHA_MAX    0.99f
#define SPLAT_ALPHA_MIN    (1.0f / 255.0f)
#define SPLAT_T_MIN        0.0001f

typedef struct splat_renderer splat_renderer;

struct splat_render_out {
    float *rgb;       /* [H * W * 3] row-major, interleaved; or NULL          */
    float *alpha;     /* [H * W] accumulated opacity 1 - T; or NULL           */
    float *depth;     /* [H * W] expected camera z, sum(z a T) / (1 - T),
                         0 where nothing was drawn; or NULL                   */
    int32_t *top;     /* [H * W] index of the Gaussian with the largest
                         weight a T at the pixel, -1 where none; or NULL      */
    uint8_t *rgba8;   /* [H * W * 4] the rgb image quantised as PNG writing
                         does, floor(clamp(v, 0, 1) * 255 + 0.5), alpha 255:
                         what a display uploads, without a float image; or
                         NULL. Without depth and top the compositing skips
                         their accumulators (the colour is bit-identical).   */
    int rgba8_bottom_up; /* rgba8's rows bottom first (GL's texture order): a
                         display copies it to its framebuffer without a flip */
    /* Called once (on the caller's thread) when preprocessing has read all
     * of the frame and before sorting starts: from then on the caller may
     * refill the frame's arrays, e.g. prepare the next frame on another
     * thread while this one is composited. NULL: no call. */
    void (*frame_read)(void *arg);
    void *frame_read_arg;
    /* Statistics of the last render (written, never read). */
    size_t visible;   /* Gaussians that passed culling                        */
    size_t pairs;     /* Gaussian-tile overlaps                               */
    double ms_stage[4]; /* wall time of preprocess, sort, binning, compositing */
    double cpu_ms_stage[4]; /* the same stages' process CPU time (all threads):
                               what they cost on a machine shared with others */
};

/* A renderer for W x H images. ctx (borrowed, must outlive the renderer)
 * provides the threads. Buffers grow only when a frame exceeds the
 * high-water mark (or splat_renderer_reserve asks for more), so a steady
 * stream of frames allocates nothing. One caller thread at a time per
 * renderer (and per fk context); make one per concurrent camera thread.
 * Measured (f4d-bench render, 2 threads of this 2-core box): 300k Gaussians
 * at 518x518 in 24 ms, 1M in 66 ms. */
int  splat_renderer_new    (fk_ctx *ctx, int width, int height,
                            splat_renderer **out, struct f4d_err *err);
int  splat_renderer_reserve(splat_renderer *r, size_t gaussians, size_t pairs);
void splat_renderer_free   (splat_renderer *r);
const char *splat_renderer_error(const splat_renderer *r);

/* Renders `f` seen by `cam` (whose size must match the renderer). bg is the
 * background colour (3 floats; NULL = black). */
int  splat_render(splat_renderer *r, const struct splat_camera *cam,
                  const struct splat_frame *f, const float bg[3],
                  struct splat_render_out *out);
/* Same geometry, but composites the per-Gaussian 3-vectors `features`
 * ([3 * count], not clamped) into out ([H * W * 3]), normalised by the
 * accumulated alpha: the expected feature of the visible surface (0 where
 * nothing was drawn). Used for per-pixel motion ground truth. */
int  splat_render_features(splat_renderer *r, const struct splat_camera *cam,
                           const struct splat_frame *f, const float *features,
                           float *out);

/* 2D flow of the visible surface of a static camera: each pixel's surface
 * point (its expected depth, pixel centre u = i + 0.5) moved by the pixel's
 * 3D world motion motion3 ([H * W * 3], e.g. from splat_render_features) and
 * projected again; flow ([H * W * 2], pixels) is that point minus the pixel
 * centre. Pixels with depth <= 0 or alpha < 0.5 (background, silhouettes)
 * and points moved behind the camera get 0. */
void splat_flow_from_motion(const struct splat_camera *cam, const float *depth, const float *alpha,
                            const float *motion3, float *flow);

/* ------------------------------------------------------------------------ */
/* Files. */

/* INRIA 3DGS binary little-endian PLY. Read: properties by name (x y z,
 * f_dc_0..2, opacity, scale_0..2, rot_0..3 required; f_rest_* and normals
 * ignored; motion_bwd_0..2 / motion_fwd_0..2 read when present), quaternions
 * normalised (a zero quaternion becomes the identity), activations applied.
 * Write: the 17 standard properties (x y z nx ny nz f_dc_0..2 opacity
 * scale_0..2 rot_0..3 without f_rest; standard viewers read it), plus the
 * motion properties when the frame has motion. */
int  splat_ply_read (const char *path, struct splat_frame *f, struct f4d_err *err);
int  splat_ply_write(const char *path, const struct splat_frame *f, struct f4d_err *err);

/* PNG through libpng. Float images are clamped to [0,1] and quantised as
 * torchvision.save_image does: floor(v * 255 + 0.5). */
int  splat_png_write_rgb(const char *path, const float *rgb, int width, int height,
                         struct f4d_err *err);
/* Reads any PNG as 8-bit RGB into *rgb (malloc'd, [H * W * 3] in [0,1]). */
int  splat_png_read_rgb (const char *path, float **rgb, int *width, int *height,
                         struct f4d_err *err);

/* NumPy .npy (version 1.0, little-endian float32, C order). */
int  splat_npy_write_f32(const char *path, const float *data, const size_t *shape,
                         int ndim, struct f4d_err *err);

/* ------------------------------------------------------------------------ */
/* Metrics, exactly as 3DGS evaluates (gaussians.md §4), on [0,1] images
 * [H * W * C] interleaved. */

/* 20 log10(1 / sqrt(MSE)) over all values; +INFINITY for identical images. */
double splat_psnr(const float *a, const float *b, int width, int height, int channels);
/* Mean SSIM: 11x11 Gaussian window (sigma 1.5), zero padding 5, C1 = 0.01²,
 * C2 = 0.03², per channel, mean over channels and pixels. Needs scratch of
 * splat_ssim_scratch_floats(width, height) floats (or NULL: allocates it);
 * returns NAN on bad arguments or when allocation fails. */
size_t splat_ssim_scratch_floats(int width, int height);
double splat_ssim(const float *a, const float *b, int width, int height, int channels,
                  float *scratch);
/* TL-STD flicker: luma Y = 0.2126 R + 0.7152 G + 0.0722 B of each RGB frame,
 * per-pixel population standard deviation over the n frames, mean over
 * pixels (unit: [0,1] luma). frames[k] is [H * W * 3]. */
double splat_tlstd(const float *const *frames, int n, int width, int height);

#ifdef __cplusplus
}
#endif
#endif /* F4D_SPLAT_H */
