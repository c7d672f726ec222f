/* sequence.c - Forge4D streaming on the model and the interpolator: two key
 * slots used in turn, everything allocated at open. */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "f4d_sequence.h"

struct slot {
    long               t;
    struct splat_frame f;       /* capacity n, with both motion arrays        */
    struct interp_key  key;     /* pixel-aligned lookup, planned at open      */
    struct splat_rig   rig;
    float              ext[MODEL_VIEWS_MAX * 12], intr[MODEL_VIEWS_MAX * 9];
    float              gauge;
    int                has_gauge, has_bwd, has_fwd;
};

struct f4d_sequence {
    struct model      *m;
    int                own_model;
    fk_ctx            *ctx;
    int                S, H, W;
    size_t             n;       /* Gaussians per key: S * H * W */
    struct slot        slot[2];
    int                cur;     /* slot of the newest key */
    int                steps;   /* keys held, 0..2 */
    long               next_t;
    interp            *ip;
    struct splat_frame out;     /* interpolated frame, capacity 2n */
    struct splat_frame outv;    /* what at() hands out: out without motion */
    struct interp_config icfg;
    int                has_motion, has_fusion;
    size_t             bytes;
    /* F_theta batched: fc1 / fc2 packed f32 from the model's fusion.* tensors,
     * run as GEMMs on INTERP_FUSE_BATCH pairs at a time */
    struct fk_linear   fc1, fc2;
    float             *hid;     /* [INTERP_FUSE_BATCH, MODEL_FUSION_HIDDEN] */
};

int f4d_sequence_fuse_batch(void *user, const float *x, int n, float *out)
{
    f4d_sequence *sq = user;
    const struct fk_epilogue gelu = { .act = FK_ACT_GELU };
    if (!sq || !sq->hid || n < 0 || n > INTERP_FUSE_BATCH)
        return F4D_EINVAL;
    int rc = fk_linear_forward(sq->ctx, &sq->fc1, x, n, INTERP_FUSE_IN, sq->hid, MODEL_FUSION_HIDDEN, &gelu);
    if (rc == F4D_OK)
        rc = fk_linear_forward(sq->ctx, &sq->fc2, sq->hid, n, MODEL_FUSION_HIDDEN, out, INTERP_ATTRS, NULL);
    if (rc != F4D_OK)
        return rc;
    /* + the mean of both attribute vectors, the quaternion as the normalised
     * sign-aligned sum: model_fusion_fuse's base, row by row */
    for (int i = 0; i < n; i++) {
        const float *at = x + (size_t)i * INTERP_FUSE_IN, *am = at + INTERP_ATTRS;
        float *o = out + (size_t)i * INTERP_ATTRS, dot = 0.0f, q[4], ss = 0.0f;
        for (int c = 0; c < 10; c++)
            o[c] += 0.5f * (at[c] + am[c]);
        for (int c = 0; c < 4; c++)
            dot += at[10 + c] * am[10 + c];
        const float sg = dot < 0.0f ? -1.0f : 1.0f;
        for (int c = 0; c < 4; c++) {
            q[c] = at[10 + c] + sg * am[10 + c];
            ss += q[c] * q[c];
        }
        const float nq = sqrtf(ss);
        for (int c = 0; c < 4; c++)
            o[10 + c] += nq >= MODEL_GAUSS_QUAT_EPS ? q[c] / nq : (c == 0 ? 1.0f : 0.0f);
    }
    return F4D_OK;
}

/* Packs F_theta for the batched path and reserves its kernel scratch: the
 * model froze the context at prepare, so the GEMMs are measured once here
 * (fk_ctx_measure) and the context frozen again. */
static int plan_fusion(f4d_sequence *sq, struct f4d_err *err)
{
    const float *w1, *b1, *w2, *b2;
    struct model *m = sq->m;
    if (model_load_vec(m, "fusion.fc1.weight", MODEL_FUSION_HIDDEN * MODEL_FUSION_IN, &w1) < 0 ||
        model_load_vec(m, "fusion.fc1.bias", MODEL_FUSION_HIDDEN, &b1) < 0 ||
        model_load_vec(m, "fusion.fc2.weight", MODEL_FUSION_ATTRS * MODEL_FUSION_HIDDEN, &w2) < 0 ||
        model_load_vec(m, "fusion.fc2.bias", MODEL_FUSION_ATTRS, &b2) < 0)
        return f4d_fail(err, F4D_EFORMAT, "sequence: %s", model_error(m));
    sq->hid = malloc((size_t)INTERP_FUSE_BATCH * MODEL_FUSION_HIDDEN * sizeof *sq->hid);
    if (!sq->hid)
        return f4d_fail(err, F4D_ENOMEM, "sequence: out of memory for the fusion MLP");
    if (fk_linear_pack(sq->ctx, &sq->fc1, FK_W_F32, w1, MODEL_FUSION_HIDDEN, MODEL_FUSION_IN, b1) != F4D_OK ||
        fk_linear_pack(sq->ctx, &sq->fc2, FK_W_F32, w2, MODEL_FUSION_ATTRS, MODEL_FUSION_HIDDEN, b2) != F4D_OK)
        return f4d_fail(err, F4D_ENOMEM, "sequence: cannot pack the fusion MLP");
    float *x = calloc((size_t)INTERP_FUSE_BATCH * (INTERP_FUSE_IN + INTERP_ATTRS), sizeof *x);
    if (!x)
        return f4d_fail(err, F4D_ENOMEM, "sequence: out of memory for the fusion MLP");
    fk_ctx_freeze(sq->ctx, 0);
    fk_ctx_measure(sq->ctx, 1);
    int rc = f4d_sequence_fuse_batch(sq, x, INTERP_FUSE_BATCH, x + (size_t)INTERP_FUSE_BATCH * INTERP_FUSE_IN);
    fk_ctx_measure(sq->ctx, 0);
    fk_ctx_freeze(sq->ctx, 1);
    /* one real run: touches hid and the scratch now rather than at the first
     * interpolation (resident memory is then flat from the first step) */
    if (rc == F4D_OK)
        rc = f4d_sequence_fuse_batch(sq, x, INTERP_FUSE_BATCH, x + (size_t)INTERP_FUSE_BATCH * INTERP_FUSE_IN);
    free(x);
    if (rc < 0)
        return f4d_fail(err, rc, "sequence: cannot plan the fusion MLP's scratch");
    return F4D_OK;
}

/* A pinhole placeholder until the first push brings the model's cameras. */
static void placeholder_rig(struct splat_rig *rig, int S, int H, int W)
{
    memset(rig, 0, sizeof *rig);
    rig->count = S;
    for (int s = 0; s < S; s++) {
        struct splat_camera *c = &rig->cams[s];
        c->width = W;
        c->height = H;
        c->fx = c->fy = (float)(W > H ? W : H);
        c->cx = 0.5f * (float)W;
        c->cy = 0.5f * (float)H;
        for (int k = 0; k < 4; k++)
            c->w2c[5 * k] = 1.0f;
    }
}

/* extrinsic [S,3,4] world-to-camera and intrinsic [S,3,3] -> splat cameras. */
static void rig_from(struct splat_rig *rig, const float *ext, const float *intr, int S, int H, int W)
{
    memset(rig, 0, sizeof *rig);
    rig->count = S;
    for (int s = 0; s < S; s++) {
        struct splat_camera *c = &rig->cams[s];
        const float *E = ext + 12 * s, *K = intr + 9 * s;
        c->width = W;
        c->height = H;
        c->fx = K[0];
        c->fy = K[4];
        c->cx = K[2];
        c->cy = K[5];
        for (int k = 0; k < 12; k++)
            c->w2c[k] = E[k];
        c->w2c[15] = 1.0f;
        c->name[0] = (char)('0' + s % 10);
    }
}

static int open_common(struct model *m, int own, int S, int H, int W, f4d_sequence **out, struct f4d_err *err)
{
    *out = NULL;
    if (S < 1 || S > MODEL_VIEWS_MAX || S > SPLAT_RIG_MAX)
        return f4d_fail(err, F4D_EINVAL, "sequence: %d views, the rig takes 1..%d", S, MODEL_VIEWS_MAX);
    if (H < 1 || W < 1 || H > MODEL_IMG_MAX || W > MODEL_IMG_MAX)
        return f4d_fail(err, F4D_EINVAL, "sequence: image size %dx%d is outside 1..%d", W, H, MODEL_IMG_MAX);
    if (!(model_groups(m) & MODEL_G_GAUSSIAN))
        return f4d_fail(err, F4D_EINVAL, "sequence: the weight file has no Gaussian head (gaussian_head.*)");
    if (!(model_groups(m) & MODEL_G_CAMERA))
        return f4d_fail(err, F4D_EINVAL, "sequence: the weight file has no camera head (camera_head.*)");
    f4d_sequence *sq = calloc(1, sizeof *sq);
    if (!sq)
        return f4d_fail(err, F4D_ENOMEM, "sequence: out of memory");
    sq->m = m;
    sq->own_model = own;
    sq->ctx = model_ctx(m);
    sq->S = S;
    sq->H = H;
    sq->W = W;
    sq->n = (size_t)S * (size_t)H * (size_t)W;
    const unsigned motion = MODEL_G_MOTION | MODEL_G_MOTION_HEAD;
    sq->has_motion = (model_groups(m) & motion) == motion;
    sq->has_fusion = sq->has_motion && model_fusion(m) != NULL;
    sq->icfg = interp_config_default();
    sq->icfg.mode = sq->has_motion ? INTERP_FUSED : INTERP_NEAREST;
    if (sq->has_fusion) { /* the learned F_theta in place of averaging */
        sq->icfg.fuse = model_fusion_fuse;
        sq->icfg.fuse_user = model_fusion(m);
    }
    int rc = model_prepare(m, S, H, W);
    if (rc < 0) {
        f4d_fail(err, rc, "sequence: %s", model_error(m));
        goto fail;
    }
    model_state_reset(m); /* t = 0 */
    if (sq->has_fusion) {
        if ((rc = plan_fusion(sq, err)) < 0)
            goto fail;
        sq->icfg.fuse_batch = f4d_sequence_fuse_batch;
        sq->icfg.fuse_batch_user = sq;
    }
    struct splat_rig rig;
    placeholder_rig(&rig, S, H, W);
    if ((rc = interp_new(sq->ctx, &rig, &sq->ip, err)) < 0)
        goto fail;
    /* Plan: both slots at full size with motion, their lookups built once at
     * that size, the interpolated frame at both keys' size (with motion so
     * that INTERP_NEAREST's copy never grows it). */
    for (int i = 0; i < 2; i++) {
        struct slot *sl = &sq->slot[i];
        if ((rc = splat_frame_resize(&sl->f, sq->n, 1, err)) < 0 ||
            (rc = interp_key_build_aligned(sq->ip, &sl->f, &sl->key, err)) < 0)
            goto fail;
    }
    if ((rc = splat_frame_reserve(&sq->out, 2 * sq->n, 1, err)) < 0)
        goto fail;
    size_t frame_bytes = sq->n * 19 * sizeof(float); /* pos 3 scale 3 rot 4 opacity 1 rgb 3 motion 3+3 */
    size_t key_bytes = sq->slot[0].key.cap_cells * 4 + sq->slot[0].key.cap_items * 4 + sq->slot[0].key.cap_origin * 4;
    sq->bytes = sizeof *sq + 2 * (frame_bytes + key_bytes) + 2 * frame_bytes + sq->fc1.bytes + sq->fc2.bytes +
                (sq->hid ? (size_t)INTERP_FUSE_BATCH * MODEL_FUSION_HIDDEN * sizeof(float) : 0);
    *out = sq;
    return F4D_OK;
fail:
    sq->own_model = 0; /* the caller's model (or open's, freed there) */
    f4d_sequence_close(sq);
    return rc;
}

int f4d_sequence_open_model(struct model *m, int views, int height, int width, f4d_sequence **out,
                            struct f4d_err *err)
{
    if (!out)
        return f4d_fail(err, F4D_EINVAL, "sequence: out is NULL");
    *out = NULL;
    if (!m)
        return f4d_fail(err, F4D_EINVAL, "sequence: model is NULL");
    return open_common(m, 0, views, height, width, out, err);
}

int f4d_sequence_open(fk_ctx *ctx, const char *weights, enum fk_wtype wtype, int views, int height, int width,
                      f4d_sequence **out, struct f4d_err *err)
{
    if (!out)
        return f4d_fail(err, F4D_EINVAL, "sequence: out is NULL");
    *out = NULL;
    if (!ctx || !weights)
        return f4d_fail(err, F4D_EINVAL, "sequence: NULL context or weight path");
    struct model *m = NULL;
    int rc = model_init(ctx, weights, wtype, &m, err);
    if (rc < 0)
        return rc;
    /* keys need Gaussians, cameras, gauge and motion, never the depth map */
    if ((rc = model_skip_head(m, "depth_head")) < 0) {
        f4d_fail(err, rc, "sequence: %s", model_error(m));
        model_free(m);
        return rc;
    }
    if ((rc = open_common(m, 1, views, height, width, out, err)) < 0) {
        model_free(m);
        return rc;
    }
    return F4D_OK;
}

void f4d_sequence_close(f4d_sequence *sq)
{
    if (!sq)
        return;
    for (int i = 0; i < 2; i++) {
        interp_key_free(&sq->slot[i].key);
        splat_frame_free(&sq->slot[i].f);
    }
    splat_frame_free(&sq->out);
    interp_free(sq->ip);
    fk_linear_free(&sq->fc1);
    fk_linear_free(&sq->fc2);
    free(sq->hid);
    if (sq->own_model)
        model_free(sq->m);
    free(sq);
}

int f4d_sequence_push(f4d_sequence *sq, const float *images, struct f4d_err *err)
{
    return f4d_sequence_push_masked(sq, images, NULL, err);
}

int f4d_sequence_push_masked(f4d_sequence *sq, const float *images, const uint8_t *patch_keep, struct f4d_err *err)
{
    if (!sq || !images)
        return f4d_fail(err, F4D_EINVAL, "sequence_push: NULL argument");
    struct model_outputs o;
    int rc = model_eval_masked(sq->m, images, sq->S, sq->H, sq->W, patch_keep, &o);
    if (rc < 0) {
        /* the model's state is undefined now: start over at the next push
         * (its key time goes on counting) */
        f4d_fail(err, rc, "sequence_push: %s (the sequence restarts)", model_error(sq->m));
        model_state_reset(sq->m);
        sq->steps = 0;
        return rc;
    }
    const struct model_gaussians *g = &o.gaussians;
    if (g->count != sq->n || !o.extrinsic || !o.intrinsic) { /* cannot happen after open's checks */
        model_state_reset(sq->m);
        sq->steps = 0;
        return f4d_fail(err, F4D_EINVAL, "sequence_push: the model gave %zu Gaussians (want %zu) and %s cameras",
                        g->count, sq->n, o.extrinsic ? "its" : "no");
    }
    const float *ext = o.extrinsic_metric ? o.extrinsic_metric : o.extrinsic;
    struct slot *nw = &sq->slot[sq->steps ? 1 - sq->cur : sq->cur];
    struct splat_rig rig;
    rig_from(&rig, ext, o.intrinsic, sq->S, sq->H, sq->W);
    /* Cameras first: a bad one leaves both keys untouched. The model has
     * moved on to this step, though: restart as after a failed Eval. */
    if ((rc = interp_set_rig(sq->ip, &rig, err)) < 0) {
        model_state_reset(sq->m);
        sq->steps = 0;
        return rc;
    }
    const size_t n = sq->n;
    struct splat_frame *f = &nw->f;
    memcpy(f->pos, g->pos, 3 * n * sizeof(float));
    memcpy(f->scale, g->scale, 3 * n * sizeof(float));
    memcpy(f->rot, g->rot, 4 * n * sizeof(float));
    memcpy(f->opacity, g->opacity, n * sizeof(float));
    memcpy(f->rgb, g->rgb, 3 * n * sizeof(float));
    f->count = n;
    nw->has_bwd = nw->has_fwd = 0;
    nw->rig = rig;
    memcpy(nw->ext, ext, (size_t)sq->S * 12 * sizeof(float));
    memcpy(nw->intr, o.intrinsic, (size_t)sq->S * 9 * sizeof(float));
    nw->gauge = o.gauge;
    nw->has_gauge = o.has_gauge;
    nw->t = sq->next_t++;
    if (sq->has_motion && o.has_motion && o.motion_bwd && o.motion_fwd_prev && sq->steps) {
        /* M1[t] for the new key, M2[t-1] for the key before it */
        struct slot *pv = &sq->slot[sq->cur];
        memcpy(f->motion_bwd, o.motion_bwd, 3 * n * sizeof(float));
        memcpy(pv->f.motion_fwd, o.motion_fwd_prev, 3 * n * sizeof(float));
        nw->has_bwd = pv->has_fwd = 1;
    }
    if ((rc = interp_key_build_aligned(sq->ip, f, &nw->key, err)) < 0)
        return rc;
    if (sq->steps)
        sq->cur = 1 - sq->cur;
    if (sq->steps < 2)
        sq->steps++;
    return F4D_OK;
}

int f4d_sequence_steps(const f4d_sequence *sq) { return sq ? sq->steps : 0; }

int f4d_sequence_key(const f4d_sequence *sq, int which, struct f4d_seq_key *out, struct f4d_err *err)
{
    if (!sq || !out)
        return f4d_fail(err, F4D_EINVAL, "sequence_key: NULL argument");
    if (which < 0 || which > 1 || which >= sq->steps)
        return f4d_fail(err, F4D_EINVAL, "sequence_key: key %d of %d held", which, sq->steps);
    const struct slot *sl = &sq->slot[which ? 1 - sq->cur : sq->cur];
    out->t = sl->t;
    out->frame = sl->f;
    if (!sl->has_bwd)
        out->frame.motion_bwd = NULL;
    if (!sl->has_fwd)
        out->frame.motion_fwd = NULL;
    out->rig = sl->rig;
    out->extrinsic = sl->ext;
    out->intrinsic = sl->intr;
    out->gauge = sl->gauge;
    out->has_gauge = sl->has_gauge;
    return F4D_OK;
}

int f4d_sequence_at(f4d_sequence *sq, double t, const struct splat_frame **out, struct interp_stats *stats,
                    struct f4d_err *err)
{
    if (!sq || !out)
        return f4d_fail(err, F4D_EINVAL, "sequence_at: NULL argument");
    if (sq->steps < 2)
        return f4d_fail(err, F4D_EINVAL, "sequence_at: needs two keys, %d pushed", sq->steps);
    const struct slot *next = &sq->slot[sq->cur], *prev = &sq->slot[1 - sq->cur];
    double a = t - (double)prev->t;
    if (!(a >= 0.0 && a <= 1.0))
        return f4d_fail(err, F4D_EINVAL, "sequence_at: t' = %g is outside the last keys [%ld, %ld]", t, prev->t,
                        next->t);
    struct interp_config cfg = sq->icfg;
    if (cfg.mode != INTERP_NEAREST && !(prev->has_fwd && next->has_bwd))
        cfg.mode = INTERP_NEAREST; /* a pair without motion (after a restart) */
    int rc = interp_at(sq->ip, &prev->key, &next->key, (float)a, &cfg, &sq->out, stats, err);
    if (rc < 0)
        return rc;
    sq->outv = sq->out;
    sq->outv.motion_bwd = sq->outv.motion_fwd = NULL;
    *out = &sq->outv;
    return F4D_OK;
}

enum interp_mode f4d_sequence_mode(const f4d_sequence *sq) { return sq->icfg.mode; }

int f4d_sequence_set_mode(f4d_sequence *sq, enum interp_mode mode, struct f4d_err *err)
{
    if (!sq)
        return f4d_fail(err, F4D_EINVAL, "sequence_set_mode: NULL sequence");
    if (mode != INTERP_NEAREST && mode != INTERP_FUSED && mode != INTERP_KEEP_BOTH)
        return f4d_fail(err, F4D_EINVAL, "sequence_set_mode: unknown mode %d", (int)mode);
    if (mode != INTERP_NEAREST && !sq->has_motion)
        return f4d_fail(err, F4D_EINVAL, "sequence_set_mode: the weights have no motion part (motion.*, "
                                         "motion_head.*): only INTERP_NEAREST");
    sq->icfg.mode = mode;
    return F4D_OK;
}

int f4d_sequence_set_fusion(f4d_sequence *sq, int learned, struct f4d_err *err)
{
    if (!sq)
        return f4d_fail(err, F4D_EINVAL, "sequence_set_fusion: NULL sequence");
    if (learned && !sq->has_fusion)
        return f4d_fail(err, F4D_EINVAL, "sequence_set_fusion: the weights have no fusion MLP (fusion.*)");
    if (learned) {
        sq->icfg.fuse = model_fusion_fuse;
        sq->icfg.fuse_user = model_fusion(sq->m);
        sq->icfg.fuse_batch = f4d_sequence_fuse_batch;
        sq->icfg.fuse_batch_user = sq;
    } else {
        sq->icfg.fuse = interp_fuse_average;
        sq->icfg.fuse_user = NULL;
        sq->icfg.fuse_batch = NULL;
        sq->icfg.fuse_batch_user = NULL;
    }
    return F4D_OK;
}

int    f4d_sequence_has_motion(const f4d_sequence *sq) { return sq->has_motion; }
int    f4d_sequence_has_fusion(const f4d_sequence *sq) { return sq->has_fusion; }
size_t f4d_sequence_bytes(const f4d_sequence *sq) { return sq->bytes; }
struct model *f4d_sequence_model(f4d_sequence *sq) { return sq->m; }
