/* model_internal.h - shared between the model's files: the model struct, the
 * transformer block, the arena bump allocator and the built-in heads. */
#ifndef F4D_MODEL_INTERNAL_H
#define F4D_MODEL_INTERNAL_H

#include <stdio.h>

#include "fk_attention.h"
#include "fk_conv.h"
#include "fk_linear.h"
#include "fk_ops.h"
#include "fk_resize.h"
#include "model.h"

#define MODEL_ALIGN 64

/* Bump allocator over one region; with base == NULL it only measures, so the
 * same layout code plans (Prepare) and places (Eval). */
struct bump {
    unsigned char *base;
    size_t         off;
};

static inline void *bump_take(struct bump *b, size_t bytes)
{
    void *p = b->base ? (void *)(b->base + b->off) : NULL;
    b->off += (bytes + MODEL_ALIGN - 1) / MODEL_ALIGN * MODEL_ALIGN;
    return p;
}
#define BUMP_F(b, n) ((float *)bump_take((b), (size_t)(n) * sizeof(float)))

/* Pre-norm transformer block (vggt.md 4). */
struct blk {
    int              dim, heads, hidden, qk_norm;
    float            eps;
    const float     *n1w, *n1b, *n2w, *n2b, *g1, *g2;
    const float     *qnw, *qnb, *knw, *knb;
    struct fk_linear qkv, proj, fc1, fc2;
};

struct blk_bufs {
    float *ln, *qkv, *o, *hid;
};

enum model_stage_id {
    ST_PATCH = 0, ST_DINO, ST_FRAME, ST_GLOBAL, ST_STATE, ST_MOTION, ST_HEAD0,
    ST_COUNT = ST_HEAD0 + MODEL_HEADS_MAX,
};

struct model {
    fk_ctx             *ctx;
    gguf_file          *gf;
    int                 owns_gf;           /* model_init opened it: closed by model_free */
    enum fk_wtype       wtype;
    struct model_config cfg;
    struct f4d_err      err;
    size_t              weight_bytes;
    unsigned            groups;            /* groups present in the file */

    /* aggregator */
    struct fk_conv2d    patch;
    const float        *cls, *pos_embed, *dino_reg, *dino_nw, *dino_nb;
    const float        *cam_tok, *reg_tok;
    struct blk         *dino, *frame, *global;
    int                 patch_packed;

    /* heads */
    const struct model_head_ops *head_ops[MODEL_HEADS_MAX];
    void               *head[MODEL_HEADS_MAX];
    int                 n_heads;
    uint64_t            keep;               /* aggregator layers kept */

    /* arena */
    unsigned char      *arena;
    size_t              arena_bytes, persist_bytes, scratch_bytes;
    int                 max_S, max_H, max_W;
    int32_t            *pos;                /* [S*P'][2] per stream row */
    int32_t            *row;                /* [S*P'] stream row -> layer row f*P'+t */
    /* Token stream of the last aggregator run: frame f is rows off[f] ..
     * off[f+1]-1 (specials, then its kept patches in raster order). */
    int                 tok_off[MODEL_VIEWS_MAX + 1], tok_S;
    int                 tok_masked;         /* rows were dropped: layers partly reused */
    const uint8_t      *keep_now;           /* the Eval's keep-list [S*P] when tok_masked */
    /* The kept layers hold a complete result for this frame set (0: none
     * yet, or the last aggregator run failed): a masked Eval may reuse them. */
    int                 layers_valid, layers_S, layers_H, layers_W;
    float              *pe_grid;            /* resized DINO pos-embed [P, C] */
    int                 pe_h, pe_w;         /* size pe_grid holds (0 = none) */
    float              *layers[MODEL_LAYERS_MAX];
    float              *head_persist[MODEL_HEADS_MAX];
    size_t              head_persist_bytes[MODEL_HEADS_MAX];
    float              *scratch;
    int                 froze_ctx;          /* model_prepare froze m->ctx */

    /* Forge4D stages 2-3 (model_stream.c, model_fusion.c); NULL when absent */
    struct model_stream *stream;
    struct model_fusion *fusion;
    int                 measuring;          /* the measuring Eval of model_prepare */

    model_tap_fn        tap;
    void               *tap_user;
    struct model_hooks  hooks;

    double              st_sec[ST_COUNT], st_flops[ST_COUNT];
    double             *flops;              /* stage counter being charged */
};

int  model_fail(struct model *m, int rc, const char *fmt, ...)
#if defined(__GNUC__)
    __attribute__((format(printf, 3, 4)))
#endif
    ;
int  model_kfail(struct model *m, const char *what);  /* kernel error -> message */
double model_now(void);

/* Loading (model.c). */
int  model_load_f32(struct model *m, const char *name, size_t count, const float **v);
int  model_load_conv(struct model *m, struct fk_conv2d *c, const char *prefix, int cout,
                     int cin, int k, int stride, int pad, int bias, enum fk_wtype as);
int  model_load_convt(struct model *m, struct fk_conv_transpose2d *c, const char *prefix,
                      int cin, int cout, int k);
int  model_load_block(struct model *m, struct blk *b, const char *prefix, int dim,
                      int heads, int hidden, float eps, int qk_norm);
void model_free_block(struct blk *b);

/* Kernels with FLOP accounting (model_block.c). */
int  model_linear(struct model *m, const struct fk_linear *L, const float *x, int rows,
                  int ldx, float *y, int ldy, const struct fk_epilogue *ep);
int  model_conv(struct model *m, const struct fk_conv2d *c, const float *x, int h, int w,
                float *y, enum fk_act act);
int  model_convt(struct model *m, const struct fk_conv_transpose2d *c, const float *x,
                 int h, int w, float *y);
void model_block_bufs(struct bump *b, int dim, int hidden, int n, struct blk_bufs *bb);
/* x [off[nseq], dim] in place; sequence s is rows off[s] .. off[s+1]-1 (may
 * be empty) and attends within itself; pos [off[nseq]][2] per row, or NULL
 * (no RoPE). */
int  model_block_forward_seqs(struct model *m, const struct blk *b, float *x, int nseq,
                              const int *off, const int32_t *pos, const struct blk_bufs *bb);
/* nseq equal sequences of seqlen rows; pos [seqlen][2] only when nseq == 1. */
int  model_block_forward(struct model *m, const struct blk *b, float *x, int nseq,
                         int seqlen, const int32_t *pos, const struct blk_bufs *bb);

/* Aggregator (model_aggregator.c). */
int  model_aggregator_load(struct model *m);
void model_aggregator_free(struct model *m);
void model_aggregator_plan(const struct model_config *c, uint64_t keep, int S, int H, int W,
                           size_t *persist, size_t *scratch);
/* keep [S*P] (1 = run the patch) or NULL for all patches; ignored (all
 * patches run) when the kept layers hold no result of this S x H x W. */
int  model_aggregator_eval(struct model *m, const float *images, int S, int H, int W,
                           const uint8_t *keep);

/* Built-in heads. */
extern const struct model_head_ops model_camera_head_ops;
extern const struct model_head_ops model_depth_head_ops;
extern const struct model_head_ops model_point_head_ops;
void model_camera_plan(const struct model_config *c, int S, size_t *persist, size_t *scratch);
void model_dpt_plan(const struct model_config *c, int out_dim, int S, int H, int W,
                    size_t *persist, size_t *scratch);

/* Forge4D heads (model_scale.c, model_gaussian.c), registered after the
 * built-in VGGT heads: the scale head first (the Gaussian head divides by
 * its gauge). */
extern const struct model_head_ops model_scale_head_ops;
extern const struct model_head_ops model_gaussian_head_ops;
void model_scale_plan(const struct model_config *c, int S, size_t *persist, size_t *scratch);
void model_gaussian_plan(const struct model_config *c, int S, int H, int W, size_t *persist,
                         size_t *scratch);

/* Forge4D's state and motion blocks (model_stream.c), run inside the
 * aggregator: _frame after frame block l (keeps its output for the motion
 * input), _global after global block l (state block, then motion block l),
 * both before the model_hooks callback. The arena holds the state, z(t-1)
 * and the kept motion streams (persistent, placed after the aggregator's
 * part) and the streams' scratch (after the aggregator's scratch). */
struct model_stream;
int  model_stream_load   (struct model *m);
void model_stream_free   (struct model *m);
/* The motion head skipped: the motion blocks feed nothing else, so they are
 * neither planned nor run (their weights stay loaded until model_free). */
void model_stream_drop_motion(struct model *m);
/* m->groups less the motion groups once they were dropped: what is planned. */
unsigned model_stream_groups(const struct model *m);
void model_stream_plan   (const struct model_config *c, unsigned groups, int S, int H, int W,
                          size_t *persist, size_t *scratch);
void model_stream_place  (struct model *m, struct bump *b);
void model_stream_scratch(struct model *m, struct bump *b, int S, int H, int W);
void model_stream_begin  (struct model *m, int S, int H, int W);
void model_stream_end    (struct model *m, int S, int H, int W, int ok, struct model_outputs *out);
int  model_stream_frame  (struct model *m, int layer, const float *x, int n);
int  model_stream_global (struct model *m, int layer, float *x, int S, int P1,
                          const struct blk_bufs *bb);
int  model_stream_motion_now(const struct model *m);
/* A masked Eval may drop patches (no motion blocks, or the last step ran the
 * motion: z(t-1) and the kept motion streams are complete); after begin. */
int  model_stream_mask_ok(const struct model *m);
/* Motion stream of run r (0: M1, 1: M2) after block dpt_layer_idx[i], [S*P', C]. */
const float *model_stream_h(const struct model *m, int run, int i);

/* Forge4D's motion head (model_motion.c), registered after the Gaussian head. */
extern const struct model_head_ops model_motion_head_ops;
void model_motion_head_plan(const struct model_config *c, int S, int H, int W, size_t *persist,
                            size_t *scratch);

/* Forge4D's fusion MLP (model_fusion.c). */
struct model_fusion;
int  model_fusion_load(struct model *m);
void model_fusion_free(struct model *m);

/* A DPT head giving its raw output channels (no activation, no confidence):
 * the Gaussian head's trunk. init returns 1 when `prefix` is not in the file.
 * The raw maps [S, H, W, out_dim] sit at the start of the head's persist part,
 * whose size model_dpt_raw_plan gives. */
int      model_dpt_raw_init (struct model *m, void **head, const char *prefix, int out_dim);
/* The same on tokens in_dim wide with its own width `features` (the motion
 * head: C, motion_dpt_features); its plan takes a config with that width. */
int      model_dpt_raw_init_dim(struct model *m, void **head, const char *prefix, int out_dim,
                                int in_dim, int features);
void     model_dpt_raw_plan (const struct model_config *c, int out_dim, int S, int H, int W,
                             size_t *persist, size_t *scratch);
uint64_t model_dpt_head_layers(const void *head);
int      model_dpt_head_eval(void *head, struct model_run *run, float *persist);
void     model_dpt_head_free(void *head);

#endif
