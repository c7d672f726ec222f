/* model.h - the inference core: VGGT (vggt.md) on the fk kernels.
 *
 * Three phases, after TFLite Micro:
 *   Init     model_init: opens the GGUF weight file (tools/f4d-convert), reads
 *            every dimension from its forge4d.* metadata, validates each tensor
 *            (name, type, shape) and packs the weights for the kernels in the
 *            requested precision (f32, f16 or int8 per output channel).
 *   Prepare  model_prepare: plans ONE arena for the largest frame set it will
 *            see (views x height x width) and allocates it. model_arena_bytes
 *            reports its size; model_plan_bytes gives it without weights.
 *            It also reserves the kernel scratch every Eval up to that size
 *            needs (a measuring pass, fk_ctx_measure) and FREEZES the context
 *            (fk_ctx_freeze) until model_free: other users of the same fk_ctx
 *            then get F4D_ENOMEM rather than a scratch allocation.
 *   Eval     model_eval: runs the network; it never allocates and never logs.
 *
 *     fk_ctx *ctx;  struct model *m;  struct model_outputs out;  struct f4d_err err = {0};
 *     fk_ctx_new(&(struct fk_ctx_config){ .threads = 0 }, &ctx);
 *     if (model_init(ctx, "vggt.gguf", FK_W_F32, &m, &err) < 0) puts(err);
 *     model_prepare(m, 4, 518, 518);                 // arena for up to 4 views
 *     model_eval(m, images, 4, 392, 518, &out);      // images [S,3,H,W] in [0,1]
 *     ... out.depth[(s * H + y) * W + x] ...
 *     model_free(m);
 *
 * Shape of the model, so that Forge4D's parts plug in without rework:
 *   - per-layer features are addressable: model_layer() returns aggregator
 *     output l (frame || global, [S*P', 2C]) for every layer a head reads,
 *     and a tap callback sees every checkpoint (patch embed, layers, camera
 *     iterations, DPT levels) as it is produced;
 *   - state carried between time steps lives in the arena: Forge4D's state
 *     blocks and motion inputs (forge4d-arch.md 4-5, model_state_reset), and
 *     struct model_hooks gives a callback after each global block with the
 *     token stream for anything else;
 *   - heads are added by registration: struct model_head_ops (init / layers /
 *     plan / eval / free) in a static table of built-in heads (camera, depth,
 *     point) plus model_register_head() for more before model_prepare.
 *
 * Foreground-only evaluation ("compute only where the scene is"):
 *   model_eval_masked takes a per-view patch keep-list (firmware/infer/
 *   foreground builds one from a learned background). Only the kept patches
 *   and every view's camera + register tokens run through the patch embed's
 *   DINO blocks, the frame and global attention and the MLPs; the token
 *   stream is then PACKED, x [n, C] with n = sum of kept tokens (frame f:
 *   its specials, then its kept patches in raster order), so every GEMM and
 *   attention costs what the kept tokens cost. RoPE uses the kept patches'
 *   real (row + 1, col + 1) and the DINO pos-embed their real grid cell, so
 *   a kept token computes exactly what it would in a model that only ever
 *   saw the kept set. A view with no kept patch runs its special tokens only.
 *   Dropped patches are NOT dropped from the output: the kept aggregator
 *   layers (the ones the heads read) stay in the arena between Evals, and a
 *   dropped patch's rows keep the previous Eval's values (the last key's),
 *   so the heads still see a full grid and background depth, points and
 *   Gaussians are recomputed from last-key features, not removed. The
 *   heads themselves run on the full grid. When the kept layers hold no
 *   complete result of the same S x H x W (first Eval, changed frame size,
 *   a failed Eval), or when the file has Forge4D's motion blocks and the
 *   last step did not run them (steps 1 and 2 of a sequence: z(t-1) and the
 *   motion streams are not complete yet), every patch runs (out.masked = 0).
 *   With Forge4D's blocks (forge4d_ref.py, MASKED STEP):
 *     - state block l reads into the kept rows only and writes from the
 *       kept tokens (and every view's specials) only: the state learns
 *       from what ran, not from the reused background rows;
 *     - z_l(t) of a kept row is in_proj_l of its new layer row, of a
 *       dropped row z_l(t-1) (the reused layer row's z). Both motion runs
 *       take queries from the kept rows of this step only (M1: z(t), M2:
 *       z(t-1) at the same rows, the dilation margin covering where the
 *       foreground was at t-1), keys / values from the full grid of the
 *       other time; the motion stream rows of dropped patches are the last
 *       step's, so the motion head runs on the full grid;
 *     - M1[t] and M2[t-1] are exactly 0 at every pixel of a dropped patch:
 *       background is static by the keep-list's definition.
 *   out.view_tokens /
 *   out.total_tokens count the tokens that ran. An all-ones keep-list gives
 *   model_eval's result bit for bit.
 *
 * Errors: functions return 0 or a negative MODEL_E* code, with a message in
 * the caller's buffer (init) or model_error() naming the tensor, key or
 * argument at fault.
 */
#ifndef F4D_MODEL_H
#define F4D_MODEL_H

#include "f4d_status.h"

#include <stddef.h>
#include <stdint.h>

#include "fk_ctx.h"
#include "fk_linear.h"
#include "gguf.h"

#define MODEL_LAYERS_MAX  64   /* aggregator depth limit (bit mask width)   */
#define MODEL_VIEWS_MAX   8
#define MODEL_HEADS_MAX   8
#define MODEL_POSE_DIM    9
#define MODEL_NAME_MAX    96
#define MODEL_DPT_HIDDEN2 32   /* output_conv2.0 width, fixed in VGGT        */
/* Upper bounds of the config (model_config_check): every buffer size derived
 * from them fits size_t products and int element counts of the kernels. */
#define MODEL_IMG_MAX     4096 /* img_size and input height / width          */
#define MODEL_DIM_MAX     8192 /* embed_dim, dpt_features, dpt_out_channels  */

enum model_patch_embed { MODEL_PATCH_DINO = 0, MODEL_PATCH_CONV = 1 };

/* Every dimension of the network. Defaults (model_config_default) are VGGT-1B;
 * the weight file stores each one as a forge4d.<field> key. */
struct model_config {
    int   img_size, patch_size, embed_dim, depth, num_heads;
    float mlp_ratio;
    int   num_register_tokens;
    int   patch_embed;              /* enum model_patch_embed */
    int   dino_depth, dino_num_heads;
    int   camera_trunk_depth, camera_num_heads, camera_iters;
    int   dpt_features, dpt_out_channels[4], dpt_layer_idx[4];
    /* Forge4D's motion path (forge4d-arch.md 5, cut to the paper's 27 % of a
     * key frame; keys forge4d.motion_layers (list), .motion_dpt_features,
     * absent in older files = 0): bit l set = a motion block (and in_proj) at aggregator layer
     * l, 0 = the layers of dpt_layer_idx; must contain dpt_layer_idx (the
     * motion head reads h after those blocks). Full design: all depth bits. */
    uint64_t motion_layers;
    int   motion_dpt_features;      /* the motion head's DPT width; 0 = dpt_features */
};

void model_config_default(struct model_config *c);
/* motion_layers / motion_dpt_features with 0 resolved. */
uint64_t model_motion_mask(const struct model_config *c);
int      model_motion_features(const struct model_config *c);
/* Range and divisibility checks; the message names the field. */
int  model_config_check  (const struct model_config *c, struct f4d_err *err);
int  model_config_read   (gguf_file *f, struct model_config *c, struct f4d_err *err);
int  model_config_write  (const struct model_config *c, gguf_writer *w);
int  model_mlp_hidden    (const struct model_config *c, int dim);  /* int(dim * ratio) */

/* ---- weight schema: the one table of parameter names (vggt.md keys) ------ */

/* Tensor groups; a weight file holds the aggregator and any subset of heads. */
enum model_group {
    MODEL_G_AGGREGATOR = 1u << 0,
    MODEL_G_CAMERA     = 1u << 1,
    MODEL_G_DEPTH      = 1u << 2,
    MODEL_G_POINT      = 1u << 3,
    MODEL_G_GAUSSIAN   = 1u << 4,   /* Forge4D gaussian_head.* (forge4d-arch.md 1) */
    MODEL_G_SCALE      = 1u << 5,   /* Forge4D scale_head.*    (forge4d-arch.md 2) */
    MODEL_G_STATE      = 1u << 6,   /* Forge4D state.*         (forge4d-arch.md 4) */
    MODEL_G_MOTION     = 1u << 7,   /* Forge4D motion.*        (forge4d-arch.md 5) */
    MODEL_G_MOTION_HEAD = 1u << 8,  /* Forge4D motion_head.*   (forge4d-arch.md 5) */
    MODEL_G_FUSION     = 1u << 9,   /* Forge4D fusion.*        (forge4d-arch.md 6) */
};
#define MODEL_G_VGGT    0xfu        /* aggregator + camera, depth, point heads */
#define MODEL_G_FORGE4D 0x3f0u      /* Forge4D's heads and modules */
#define MODEL_G_ALL     0x3ffu

/* Forge4D's stage-2/3 sizes fixed by forge4d-arch.md 4-6 (not in the config). */
#define MODEL_STATE_TOKENS  16  /* N_s state tokens per aggregator layer        */
#define MODEL_MOTION_CH     3   /* motion head output: 3-D motion per pixel     */
#define MODEL_FUSION_ATTRS  14  /* mu 3 | colour 3 | logit(opacity) 1 | log(scale) 3 | q 4 */
#define MODEL_FUSION_IN     30  /* attrs(t) | attrs(t-1) | a | D                */
#define MODEL_FUSION_HIDDEN 64

enum model_tclass {
    MODEL_T_F32    = 0, /* kept f32: norms, biases, LayerScale, tokens, pos-embeds,
                           the patchify conv                                         */
    MODEL_T_QUANT  = 1, /* linear / conv weights: f32, f16 or int8 as converted     */
    MODEL_T_UNUSED = 2, /* known but unused at inference (mask_token): dropped      */
};

struct model_tensor_info {
    char    name[MODEL_NAME_MAX];
    int     n_dims;
    int64_t shape[4];               /* PyTorch order, outermost first         */
    int     tclass;                 /* enum model_tclass                      */
    int     qaxis;                  /* int8 scale axis: the output channel (1
                                       for ConvTranspose [in,out,k,k], else 0) */
    unsigned group;
};

typedef int (*model_tensor_fn)(void *user, const struct model_tensor_info *t);
/* Calls fn for every tensor of the groups, in a fixed order; stops on fn < 0. */
int         model_schema_foreach(const struct model_config *c, unsigned groups,
                                 model_tensor_fn fn, void *user);
/* Bytes of every tensor of the groups at f32 (what Init unpacks at most, per
 * tensor class; int8 scales not counted). The config must pass
 * model_config_check, which keeps every shape and the sum far from overflow. */
uint64_t    model_schema_bytes(const struct model_config *c, unsigned groups);
/* Group of a tensor name by its prefix (0 when none matches). */
unsigned    model_group_of(const char *name);
const char *model_group_prefix(unsigned group);

/* ---- runtime ------------------------------------------------------------ */

/* Forge4D's Gaussian head (forge4d-arch.md 1): 14 raw channels per pixel. */
#define MODEL_GAUSS_CH        14   /* dp 3 | dc 3 | o 1 | s 3 | q 4          */
#define MODEL_GAUSS_OPACITY_BIAS 4.0f
#define MODEL_GAUSS_LOG_MIN  (-8.0f) /* exp clamp of the scale logits        */
#define MODEL_GAUSS_LOG_MAX   4.0f
#define MODEL_GAUSS_QUAT_EPS  1e-12f /* |q| below this: identity rotation    */

/* Pixel-aligned Gaussians, structure of arrays in the layout and units of
 * struct splat_frame (firmware/gaussians/splat/splat.h), which this stage may
 * not include (house.md: infer runs before gaussians): a consumer wraps the
 * arrays into a splat_frame without copying (count = capacity = count, motion
 * arrays NULL). Values are activated: pos / scale in metres after metric
 * recovery (model units without a scale head), scale = std dev per local axis,
 * rot = unit quaternion (w, x, y, z), opacity in [0, 1], rgb linear in [0, 1]. */
struct model_gaussians {
    size_t count;      /* S * H * W; Gaussian (s * H + y) * W + x    */
    float *pos;        /* [3 * count]                                */
    float *scale;      /* [3 * count]                                */
    float *rot;        /* [4 * count]                                */
    float *opacity;    /* [count]                                    */
    float *rgb;        /* [3 * count]                                */
};

struct model;

struct model_outputs {
    int          S, H, W;
    const float *pose_enc;          /* [S, 9]           camera head, else NULL */
    const float *pose_enc_list;     /* [iters, S, 9]                           */
    const float *extrinsic;         /* [S, 3, 4] world-to-camera                */
    const float *intrinsic;         /* [S, 3, 3]                                */
    const float *depth;             /* [S, H, W]        depth head, else NULL  */
    const float *depth_conf;        /* [S, H, W]                               */
    const float *world_points;      /* [S, H, W, 3]     point head, else NULL  */
    const float *world_points_conf; /* [S, H, W]                               */
    /* Forge4D (forge4d-arch.md 1-3), when the weight file has the heads: */
    int          has_gauge;         /* scale head ran: metric outputs            */
    float        gauge;             /* p_gauge_hat (1 without the scale head)    */
    const float *extrinsic_metric;  /* [S, 3, 4] translations / gauge (scale and
                                       camera heads), else NULL                  */
    const float *gaussian_raw;      /* [S, H, W, 14] gaussian head before activation */
    /* Gaussian head output (count 0 without it). The arrays are the model's
     * arena: read-only, valid until the next Eval or model_free; a splat_frame
     * wrapping them must never be passed to splat_frame_reserve / _free. */
    struct model_gaussians gaussians;
    /* Forge4D streaming (forge4d-arch.md 4-5), when the file has them: */
    int          step;              /* Evals since model_state_reset, this one
                                       included (1 on the first time step; 0
                                       without state / motion weights)          */
    int          has_motion;        /* motion ran: a previous step of the same
                                       S x H x W exists (0 on the first step)    */
    const float *motion_bwd;        /* [S, H, W, 3] M1[t]: moves the Gaussians of
                                       this step towards t-1                     */
    const float *motion_fwd_prev;   /* [S, H, W, 3] M2[t-1]: moves the Gaussians
                                       of the PREVIOUS Eval towards this step    */
    /* Both motion maps are pixel-aligned like the Gaussians, in metres (divided
     * by this step's gauge; model units without a scale head), NULL when
     * has_motion is 0; arena memory, valid until the next Eval. */
    /* Tokens the aggregator ran (model_eval_masked): per view its special
     * tokens plus kept patches, and their sum; masked = 1 when patches were
     * dropped and their layer rows reused from the previous Eval. */
    int          masked;
    int          view_tokens[MODEL_VIEWS_MAX];
    int          total_tokens;
};

/* Checkpoint callback. Names and layouts (f = frame, -1 = all frames):
 *   "state<l>"          f=-1 [16, C]          state of layer l after its write (for t+1)
 *   "motion.h<l>"       f=-1 [S, P', C]       motion stream after block l (M1 run), for
 *   "motion.h2_<l>"     f=-1 [S, P', C]       the layers the motion head reads; M2 run
 *   "motion_head.m1"    f [H, W, 3]     M1[t], model units
 *   "motion_head.m2"    f [H, W, 3]     M2[t-1], model units
 *   "gaussian_head.mu"    f [H, W, 3]     Gaussian centres, model units
 *   "gaussian_head.sigma" f [H, W, 3]     Gaussian std devs, model units
 *   "scale_head.gauge"  f=-1 [1]          p_gauge_hat
 *   "patch_embed"       f    [P, C]           patch tokens after the patch embed
 *                                            (masked Eval: kept patches only)
 *   "layer<l>"          f=-1 [S, P', 2C]      aggregator output l (kept layers)
 *   "camera_iter<i>"    f=-1 [S, 9]           activated pose encoding, iteration i
 *   "<head>.level<i>"   f    [h_i, w_i, c_i]  DPT level i after its resize (HWC)
 *   "<head>.fused"      f    [8h, 8w, F]      DPT fusion output (HWC)
 * Called from Eval: it must not keep the pointer. */
typedef void (*model_tap_fn)(void *user, const char *name, int frame,
                             const float *data, size_t count);

/* Extension points between layers (after the built-in state blocks). */
struct model_hooks {
    /* After global block `layer`: x is the token stream [S*P', C] (row
     * f*P' + t), which the hook may update in place; a kept layer's global
     * half is copied after the hook. In a masked Eval that dropped patches
     * the stream is packed ([out.total_tokens, C], model_token_rows) and
     * `tokens` is 0. Return < 0 to abort. */
    int  (*after_global)(void *user, int layer, float *x, int S, int tokens, int C);
    void  *user;
};

/* What a head sees during Eval. */
struct model_run {
    struct model          *m;
    const struct model_config *cfg;
    int                    S, H, W, h, w, P, tokens; /* P patches, P' tokens/frame */
    const float * const   *layers;   /* [depth]; non-NULL for every kept layer */
    const float           *images;   /* the Eval input [S, 3, H, W] in [0, 1] */
    float                 *scratch;  /* the arena's scratch part (phase overlay) */
    size_t                 scratch_bytes;
    struct model_outputs  *out;
};

#define MODEL_HEAD_API_VERSION 1u

/* A head plugged into the model. `init` returns 1 when the weight file holds
 * no tensors under `prefix` (the head is then skipped), 0 when loaded, < 0 on
 * error. `persist` is the head's share of the arena kept across Eval (its
 * outputs), `scratch` what it needs while running; both sized for the largest
 * frame set. */
struct model_head_ops {
    uint32_t    api_version;
    const char *prefix;
    int      (*init)   (struct model *m, void **head);
    uint64_t (*layers) (const void *head);                    /* bit l: reads layer l */
    void     (*plan)   (const void *head, int S, int H, int W,
                        size_t *persist, size_t *scratch);
    int      (*eval)   (void *head, struct model_run *run, float *persist);
    void     (*free)   (void *head);
};

int   model_init        (fk_ctx *ctx, const char *path, enum fk_wtype wtype,
                         struct model **out, struct f4d_err *err);
/* The same Init on a file already open (e.g. gguf_open_memory). The model
 * borrows `gf` (its weights point into the file): gf must stay open until
 * model_free, which does not close it. */
int   model_init_gguf   (fk_ctx *ctx, gguf_file *gf, enum fk_wtype wtype,
                         struct model **out, struct f4d_err *err);
/* Adds a head after the built-in ones; before model_prepare. */
int   model_register_head(struct model *m, const struct model_head_ops *ops);
/* Leaves a loaded head out of Eval (its outputs stay NULL, its arena share and
 * any layer only it read are not planned); before model_prepare. For consumers
 * that never read an output: the streaming path needs no depth map, so it
 * skips "depth_head", a third of a key frame's DPT work. Skipping "motion_head"
 * also leaves out the motion blocks (nothing else reads their streams): no
 * step has motion, and the arena is planned without the motion groups; the
 * other outputs are the same bits. 0 also when the file
 * has no such head; F4D_EINVAL after model_prepare or for a head another one
 * reads (point_head, camera_head under gaussian_head). */
int   model_skip_head   (struct model *m, const char *prefix);
int   model_prepare     (struct model *m, int max_views, int max_h, int max_w);
/* S <= max_views, H <= max_h, W <= max_w of model_prepare, else F4D_EINVAL. */
int   model_eval        (struct model *m, const float *images, int S, int H, int W,
                         struct model_outputs *out);
/* model_eval where only the patches with patch_keep[f * P + r * w + c] != 0
 * (P = h * w patches of view f, row-major; NULL = all) run through the
 * aggregator, with the special tokens of every view. See "Foreground-only
 * evaluation" above for what dropped patches get. */
int   model_eval_masked (struct model *m, const float *images, int S, int H, int W,
                         const uint8_t *patch_keep, struct model_outputs *out);
void  model_free        (struct model *m);

const char                *model_error      (const struct model *m);
const struct model_config *model_get_config (const struct model *m);
fk_ctx                    *model_ctx        (struct model *m);
enum fk_wtype              model_wtype      (const struct model *m);
size_t                     model_arena_bytes(const struct model *m);
size_t                     model_weight_bytes(const struct model *m); /* packed */
/* Aggregator output l of the last Eval, [S*P', 2C], or NULL when not kept
 * (after a masked Eval, dropped patches' rows are the previous Eval's). */
const float               *model_layer      (const struct model *m, int l);
/* The last aggregator run's token stream: returns its row count n; off
 * [S+1] (frame f is rows off[f] .. off[f+1]-1) and row [n] (stream row ->
 * layer row f*P' + t) point into the model, valid until the next Eval. */
int                        model_token_rows (const struct model *m, const int **off,
                                             const int32_t **row);
void  model_set_tap   (struct model *m, model_tap_fn fn, void *user);
void  model_set_hooks (struct model *m, const struct model_hooks *hooks);

/* Arena bytes model_prepare would allocate for this config and frame set
 * with the built-in heads of `groups` (no weights needed). */
size_t model_plan_bytes(const struct model_config *c, unsigned groups, int views, int h, int w);

/* Per-stage time and FLOPs of the last Eval (FLOPs = 2 x MACs of linear,
 * conv and attention matmuls, as vggt.md 8 counts them). */
struct model_stage {
    const char *name;
    double      seconds;
    double      flops;
};
int   model_stages(const struct model *m, struct model_stage *st, int cap);

/* Helpers for heads (and tests): weights of the open file, packed in the
 * model's precision; vectors stay in the mapping. Names are full names. */
gguf_file *model_gguf   (struct model *m);
int   model_load_vec    (struct model *m, const char *name, int n, const float **v);
int   model_load_linear (struct model *m, struct fk_linear *L, const char *wname,
                         const char *bname, int n, int k);

/* ---- Forge4D streaming (forge4d-arch.md 4-6) ------------------------------
 *
 * With state.* weights, every Eval is one time step: state block l runs right
 * after global block l (before any model_hooks callback) and carries its
 * state to the next Eval; with motion.* / motion_head.* weights the model
 * keeps the motion input z_l of each motion layer (motion_layers) of the
 * last Eval and, from the second step on, gives M1[t] and M2[t-1] (struct model_outputs). All of it lives in
 * the arena (planned by model_prepare): memory does not grow with time.
 *
 *     model_state_reset(m);                          // t = 0 (also after prepare)
 *     for (t = 0; ; t++) {
 *         model_eval(m, frames[t], S, H, W, &out);    // out.has_motion from t = 1
 *         ... out.gaussians, out.motion_bwd, out.motion_fwd_prev ...
 *     }
 *
 * A frame set of another S x H x W than the last Eval restarts the motion
 * (has_motion 0) but keeps the state. model_eval_masked is a time step too
 * (what it does with the state and motion: "Foreground-only evaluation"). A failed Eval leaves the state and
 * the motion inputs undefined: call model_state_reset. */

/* Groups present in the weight file (enum model_group bits). */
unsigned model_groups(const struct model *m);
/* Back to t = 0: every layer's state to state.tokens, no previous step. */
void  model_state_reset(struct model *m);

/* The fusion MLP F_theta (forge4d-arch.md 6) of the weight file, or NULL
 * without fusion.* tensors. Read-only after Init: any thread may call
 * model_fusion_fuse on it, and it outlives nothing but the model. */
void *model_fusion(struct model *m);
/* The signature of interp_fuse_fn (firmware/gaussians/interp/interp.h): pass
 * model_fusion_fuse with user = model_fusion(m). Attribute vectors in interp's
 * convention, pre-activation: mu (3), colour (3), logit(opacity) (1),
 * log(scale) (3), quaternion (4). out = mean of both vectors (q: the
 * normalised, sign-aligned sum) + fc2(GELU(fc1([a_t, a_tm1, a, D]))). */
void  model_fusion_fuse(void *fusion, const float a_t[MODEL_FUSION_ATTRS],
                        const float a_tm1[MODEL_FUSION_ATTRS], float a, float D,
                        float out[MODEL_FUSION_ATTRS]);

/* The paper's metric gauge (training target, or a calibrated rig's scale):
 * p = mean over views of |t_true[i]| / |t_pred[i]| (metres over model units),
 * t_* [S, 3], taking only the views where both norms are >= eps (VGGT's view 0
 * sits at the origin; a near-zero prediction gives no ratio). Norms in double.
 * F4D_EINVAL (gauge untouched) when no view qualifies or eps is not > 0. */
int   model_gauge_from_translations(const float *t_true, const float *t_pred, int S,
                                    float eps, float *gauge);

/* vggt.md 5a: pose encoding [9] to extrinsic [3x4] and intrinsic [3x3]. */
void  model_pose_to_extri_intri(const float *enc, int H, int W, float *ext, float *intr);

#endif /* F4D_MODEL_H */
