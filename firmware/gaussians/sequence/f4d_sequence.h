/* f4d_sequence.h - Forge4D streaming: one synchronized set in per key time,
 * that time's metric Gaussians, cameras, gauge and motions out, and frames at
 * any time between the last two keys. Library f4d_sequence; depends on
 * f4d_model (infer) and f4d_interp / f4d_splat (gaussians).
 *
 *     f4d_sequence *sq;  struct f4d_err err = {0};
 *     if (f4d_sequence_open(ctx, "forge4d.gguf", FK_W_F32, 4, 518, 518, &sq, &err) < 0)
 *         puts(err.msg);
 *     for (;;) {
 *         f4d_sequence_push(sq, images, &err);       // [4,3,518,518] in [0,1]
 *         struct f4d_seq_key k;
 *         f4d_sequence_key(sq, 0, &k);               // key t: k.frame, k.rig, k.gauge
 *         const struct splat_frame *mid;
 *         if (f4d_sequence_steps(sq) >= 2)
 *             f4d_sequence_at(sq, k.t - 0.5, &mid, NULL, &err);   // t' = t - 0.5
 *     }
 *     f4d_sequence_close(sq);
 *
 * Contract:
 *   - Key times are the push indices 0, 1, 2, ... (t in key intervals). Every
 *     push is one set of `views` images [views, 3, H, W] in [0, 1] at the rig
 *     size given at open.
 *   - Key t's Gaussians are pixel aligned (Gaussian (s * H + y) * W + x comes
 *     from view s, pixel (x, y)), metric (metres, forge4d-arch.md 3) when the
 *     weights have a scale head, model units otherwise (gauge 1). They are
 *     copied out of the model's arena into a sequence-owned slot, because the
 *     model overwrites its outputs on the next push while key t-1 must stay.
 *   - Motions (weights with motion.* / motion_head.*): on push t, key t gets
 *     motion_bwd = M1[t] (t -> t-1) and key t-1 gets motion_fwd = M2[t-1]
 *     (t-1 -> t), in metres, per Gaussian. A key's motion pointer is NULL
 *     while that motion does not exist (motion_bwd of key 0, motion_fwd of
 *     the newest key) or the weights have no motion part.
 *   - Interpolation, f4d_sequence_at(t') for t-1 <= t' <= t: interp_at on the
 *     two keys with pixel-aligned lookups (interp_key_build_aligned), with
 *     the weights' fusion MLP (fusion.*) as the fusion function, averaging
 *     (interp_fuse_average, what an untrained MLP computes) when the file has
 *     motion but no fusion part, and INTERP_NEAREST (the nearest key, not
 *     deformed) when it has no motion part at all.
 *   - Memory is flat: the model's arena, two key slots used in turn
 *     (ping-pong), their pixel lookups and the interpolated frame are all
 *     planned and allocated by open; push, key and at never allocate, so
 *     10,000 pushed steps use the bytes of 2 (tests/sequence shows it).
 *   - Pointers returned (frames, cameras) stay valid until the push after
 *     next (keys) or the next at / push (the interpolated frame).
 *
 * Errors: 0 or a negative F4D_E* code with a message in err naming the
 * argument, tensor group or camera at fault.
 */
#ifndef F4D_SEQUENCE_H
#define F4D_SEQUENCE_H

#include "f4d_status.h"

#include "fk_ctx.h"
#include "fk_linear.h"
#include "interp.h"
#include "model.h"
#include "splat.h"

#ifdef __cplusplus
extern "C" {
#endif

typedef struct f4d_sequence f4d_sequence;

/* One key time as the sequence holds it. */
struct f4d_seq_key {
    long               t;          /* key time (push index)                          */
    struct splat_frame frame;      /* view of the slot (never reserve / free it):
                                      count = views * H * W, motion pointers as the
                                      contract says                                  */
    struct splat_rig   rig;        /* metric cameras (world-to-camera, pinhole)      */
    const float       *extrinsic;  /* [views, 3, 4] world-to-camera, metric          */
    const float       *intrinsic;  /* [views, 3, 3]                                  */
    float              gauge;      /* p_gauge_hat (1 without a scale head)           */
    int                has_gauge;
};

/* Opens the weight file with a fresh model in `wtype` precision; the model
 * needs at least a camera head and the Gaussian head (gaussian_head.*). ctx is
 * borrowed and gives the threads. */
int  f4d_sequence_open(fk_ctx *ctx, const char *weights, enum fk_wtype wtype, int views, int height,
                       int width, f4d_sequence **out, struct f4d_err *err);
/* The same on an initialised model that is not prepared yet (borrowed; it
 * must outlive the sequence): the sequence prepares it for (views, height,
 * width) and resets its state. */
int  f4d_sequence_open_model(struct model *m, int views, int height, int width, f4d_sequence **out,
                             struct f4d_err *err);
void f4d_sequence_close(f4d_sequence *sq);

/* Runs the model on the next set: images [views, 3, height, width] in [0, 1].
 * On failure (a model error, cameras that are not valid) the keys held are
 * dropped and the model's state is reset: the next push starts over (its key
 * time still counts on), as the model requires after a failed Eval. */
int  f4d_sequence_push(f4d_sequence *sq, const float *images, struct f4d_err *err);
/* The same with model_eval_masked: only the patches with patch_keep[s * P +
 * r * w + c] != 0 run (P patches per view; NULL = all, exactly push), the
 * others reuse the last key's features (model.h, "Foreground-only
 * evaluation"; firmware/infer/foreground makes the lists). */
int  f4d_sequence_push_masked(f4d_sequence *sq, const float *images, const uint8_t *patch_keep,
                              struct f4d_err *err);
/* Keys held: 0 before the first push, 1 after it, 2 from the second on. */
int  f4d_sequence_steps(const f4d_sequence *sq);
/* which = 0: the newest key t, 1: the key before it (t - 1). */
int  f4d_sequence_key(const f4d_sequence *sq, int which, struct f4d_seq_key *out, struct f4d_err *err);
/* Gaussians at absolute time t' (t - 1 <= t' <= t, t the newest key). *out
 * points at sequence memory (no motion arrays). stats may be NULL. */
int  f4d_sequence_at(f4d_sequence *sq, double t, const struct splat_frame **out, struct interp_stats *stats,
                     struct f4d_err *err);

/* The weights' fusion MLP F_theta as interp's batched fusion (user = the
 * sequence): two GEMMs on the fk kernels per INTERP_FUSE_BATCH pairs instead
 * of model_fusion_fuse's scalar MLP per pair; same result up to float
 * rounding (tests/sequence). at() uses it when the weights have fusion.*. */
int  f4d_sequence_fuse_batch(void *sq, const float *x, int n, float *out);

/* What at() does (chosen at open from the weights; FUSED / KEEP_BOTH need
 * the motion part, F4D_EINVAL otherwise). */
enum interp_mode f4d_sequence_mode(const f4d_sequence *sq);
int  f4d_sequence_set_mode(f4d_sequence *sq, enum interp_mode mode, struct f4d_err *err);
/* learned = 1: matched pairs go through the weights' fusion MLP (the default
 * when the file has fusion.*); 0: plain averaging (interp_fuse_average), the
 * paper's "without fusion" ablation, which f4d-eval scores against it on the
 * same keys. learned = 1 without fusion.* in the weights: F4D_EINVAL. */
int  f4d_sequence_set_fusion(f4d_sequence *sq, int learned, struct f4d_err *err);
int  f4d_sequence_has_motion(const f4d_sequence *sq);
int  f4d_sequence_has_fusion(const f4d_sequence *sq);
/* Bytes planned at open: slots, lookups, the interpolated frame (the model's
 * arena is model_arena_bytes). */
size_t f4d_sequence_bytes(const f4d_sequence *sq);
struct model *f4d_sequence_model(f4d_sequence *sq);

#ifdef __cplusplus
}
#endif
#endif /* F4D_SEQUENCE_H */
