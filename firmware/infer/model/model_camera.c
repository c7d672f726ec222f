/* model_camera.c - the camera head (vggt.md 5) and pose decoding (5a). */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "model_internal.h"

struct camera_head {
    struct model_config cfg;
    int              D, trunk_depth, iters;
    const float     *tn_w, *tn_b, *kn_w, *kn_b, *empty;
    struct fk_linear embed, mod, fc1, fc2;
    struct blk      *trunk;
};

static void camera_free(void *hp)
{
    struct camera_head *h = hp;
    if (!h)
        return;
    fk_linear_free(&h->embed);
    fk_linear_free(&h->mod);
    fk_linear_free(&h->fc1);
    fk_linear_free(&h->fc2);
    for (int i = 0; h->trunk && i < h->trunk_depth; i++)
        model_free_block(&h->trunk[i]);
    free(h->trunk);
    free(h);
}

static int camera_init(struct model *m, void **out)
{
    const struct model_config *c = model_get_config(m);
    if (!gguf_find_tensor(model_gguf(m), "camera_head.token_norm.weight"))
        return 1;
    struct camera_head *h = calloc(1, sizeof *h);
    if (!h)
        return F4D_ENOMEM;
    const int D = 2 * c->embed_dim;
    h->cfg = *c;
    h->D = D;
    h->trunk_depth = c->camera_trunk_depth;
    h->iters = c->camera_iters;
    int rc;
    if ((rc = model_load_vec(m, "camera_head.token_norm.weight", D, &h->tn_w)) < 0 ||
        (rc = model_load_vec(m, "camera_head.token_norm.bias", D, &h->tn_b)) < 0 ||
        (rc = model_load_vec(m, "camera_head.trunk_norm.weight", D, &h->kn_w)) < 0 ||
        (rc = model_load_vec(m, "camera_head.trunk_norm.bias", D, &h->kn_b)) < 0 ||
        (rc = model_load_f32(m, "camera_head.empty_pose_tokens", MODEL_POSE_DIM, &h->empty)) < 0 ||
        (rc = model_load_linear(m, &h->embed, "camera_head.embed_pose.weight",
                                "camera_head.embed_pose.bias", D, MODEL_POSE_DIM)) < 0 ||
        (rc = model_load_linear(m, &h->mod, "camera_head.poseLN_modulation.1.weight",
                                "camera_head.poseLN_modulation.1.bias", 3 * D, D)) < 0 ||
        (rc = model_load_linear(m, &h->fc1, "camera_head.pose_branch.fc1.weight",
                                "camera_head.pose_branch.fc1.bias", D / 2, D)) < 0 ||
        (rc = model_load_linear(m, &h->fc2, "camera_head.pose_branch.fc2.weight",
                                "camera_head.pose_branch.fc2.bias", MODEL_POSE_DIM, D / 2)) < 0)
        goto fail;
    h->trunk = calloc((size_t)h->trunk_depth, sizeof *h->trunk);
    if (!h->trunk) {
        rc = F4D_ENOMEM;
        goto fail;
    }
    for (int i = 0; i < h->trunk_depth; i++) {
        char b[MODEL_NAME_MAX];
        snprintf(b, sizeof b, "camera_head.trunk.%d", i);
        if ((rc = model_load_block(m, &h->trunk[i], b, D, c->camera_num_heads,
                                   model_mlp_hidden(c, D), 1e-5f, 0)) < 0)
            goto fail;
    }
    *out = h;
    return 0;
fail:
    camera_free(h);
    return rc;
}

static uint64_t camera_layers(const void *hp)
{
    const struct camera_head *h = hp;
    return UINT64_C(1) << (h->cfg.depth - 1);  /* the camera token of the last layer */
}

struct cam_bufs {
    float          *t, *tn, *x, *e, *mod, *ln, *h1, *pred, *delta;
    struct blk_bufs bb;
};

static void cam_layout(struct bump *b, const struct model_config *c, int S, struct cam_bufs *a)
{
    const int D = 2 * c->embed_dim;
    a->t = BUMP_F(b, (size_t)S * D);
    a->tn = BUMP_F(b, (size_t)S * D);
    a->x = BUMP_F(b, (size_t)S * D);
    a->e = BUMP_F(b, (size_t)S * D);
    a->mod = BUMP_F(b, (size_t)S * 3 * D);
    a->ln = BUMP_F(b, (size_t)S * D);
    a->h1 = BUMP_F(b, (size_t)S * D / 2);
    a->pred = BUMP_F(b, (size_t)S * MODEL_POSE_DIM);
    a->delta = BUMP_F(b, (size_t)S * MODEL_POSE_DIM);
    model_block_bufs(b, D, model_mlp_hidden(c, D), S, &a->bb);
}

void model_camera_plan(const struct model_config *c, int S, size_t *persist, size_t *scratch)
{
    struct bump p = { NULL, 0 }, s = { NULL, 0 };
    BUMP_F(&p, (size_t)c->camera_iters * S * MODEL_POSE_DIM);
    BUMP_F(&p, (size_t)S * 12);
    BUMP_F(&p, (size_t)S * 9);
    *persist = p.off;
    struct cam_bufs a;
    cam_layout(&s, c, S, &a);
    *scratch = s.off;
}

static void camera_plan(const void *hp, int S, int H, int W, size_t *persist, size_t *scratch)
{
    const struct camera_head *h = hp;
    (void)H;
    (void)W;
    model_camera_plan(&h->cfg, S, persist, scratch);
}

void model_pose_to_extri_intri(const float *enc, int H, int W, float *ext, float *intr)
{
    const double x = enc[3], y = enc[4], z = enc[5], w = enc[6];
    const double s = 2.0 / (x * x + y * y + z * z + w * w);
    const double R[9] = {
        1 - s * (y * y + z * z), s * (x * y - z * w), s * (x * z + y * w),
        s * (x * y + z * w), 1 - s * (x * x + z * z), s * (y * z - x * w),
        s * (x * z - y * w), s * (y * z + x * w), 1 - s * (x * x + y * y),
    };
    for (int r = 0; r < 3; r++) {
        for (int k = 0; k < 3; k++)
            ext[r * 4 + k] = (float)R[r * 3 + k];
        ext[r * 4 + 3] = enc[r];
    }
    memset(intr, 0, 9 * sizeof *intr);
    intr[0] = (float)((W / 2.0) / tan(enc[8] / 2.0));
    intr[4] = (float)((H / 2.0) / tan(enc[7] / 2.0));
    intr[2] = (float)(W / 2.0);
    intr[5] = (float)(H / 2.0);
    intr[8] = 1.0f;
}

static int camera_eval(void *hp, struct model_run *run, float *persist)
{
    struct camera_head *h = hp;
    struct model *m = run->m;
    fk_ctx *ctx = model_ctx(m);
    const int S = run->S, D = h->D, P1 = run->tokens;
    struct bump sb = { (unsigned char *)run->scratch, 0 };
    struct cam_bufs a;
    cam_layout(&sb, &h->cfg, S, &a);
    struct bump pb = { (unsigned char *)persist, 0 };
    float *list = BUMP_F(&pb, (size_t)h->iters * S * MODEL_POSE_DIM);
    float *ext = BUMP_F(&pb, (size_t)S * 12);
    float *intr = BUMP_F(&pb, (size_t)S * 9);
    const float *last = run->layers[run->cfg->depth - 1];
    int rc;
    /* Camera token (index 0) of every frame, both halves. */
    if (fk_layernorm(ctx, last, S, D, P1 * D, h->tn_w, h->tn_b, 1e-5f, a.t, D) != F4D_OK ||
        fk_layernorm(ctx, a.t, S, D, D, NULL, NULL, 1e-6f, a.tn, D) != F4D_OK)
        return model_kfail(m, "camera token norm");
    for (int it = 0; it < h->iters; it++) {
        if (it == 0) {
            for (int s = 0; s < S; s++)
                memcpy(a.delta + s * MODEL_POSE_DIM, h->empty, MODEL_POSE_DIM * sizeof(float));
            rc = model_linear(m, &h->embed, a.delta, S, MODEL_POSE_DIM, a.e, D, NULL);
        } else {
            rc = model_linear(m, &h->embed, a.pred, S, MODEL_POSE_DIM, a.e, D, NULL);
        }
        if (rc < 0)
            return rc;
        if (fk_silu(ctx, a.e, (size_t)S * D, a.e) != F4D_OK)
            return model_kfail(m, "silu");
        if ((rc = model_linear(m, &h->mod, a.e, S, D, a.mod, 3 * D, NULL)) < 0)
            return rc;
        for (int s = 0; s < S; s++) {
            const float *shift = a.mod + (size_t)s * 3 * D, *scale = shift + D, *gate = shift + 2 * D;
            const float *tn = a.tn + (size_t)s * D, *t = a.t + (size_t)s * D;
            float *x = a.x + (size_t)s * D;
            for (int i = 0; i < D; i++)
                x[i] = gate[i] * (tn[i] * (1.0f + scale[i]) + shift[i]) + t[i];
        }
        for (int b = 0; b < h->trunk_depth; b++)
            if ((rc = model_block_forward(m, &h->trunk[b], a.x, 1, S, NULL, &a.bb)) < 0)
                return rc;
        if (fk_layernorm(ctx, a.x, S, D, D, h->kn_w, h->kn_b, 1e-5f, a.ln, D) != F4D_OK)
            return model_kfail(m, "trunk norm");
        struct fk_epilogue gelu = { .act = FK_ACT_GELU };
        if ((rc = model_linear(m, &h->fc1, a.ln, S, D, a.h1, D / 2, &gelu)) < 0)
            return rc;
        if ((rc = model_linear(m, &h->fc2, a.h1, S, D / 2, a.delta, MODEL_POSE_DIM, NULL)) < 0)
            return rc;
        float *o = list + (size_t)it * S * MODEL_POSE_DIM;
        for (int i = 0; i < S * MODEL_POSE_DIM; i++) {
            a.pred[i] = it == 0 ? a.delta[i] : a.pred[i] + a.delta[i];
            o[i] = (i % MODEL_POSE_DIM >= 7 && a.pred[i] < 0.0f) ? 0.0f : a.pred[i];
        }
        if (m->tap) {
            char nm[32];
            snprintf(nm, sizeof nm, "camera_iter%d", it);
            m->tap(m->tap_user, nm, -1, o, (size_t)S * MODEL_POSE_DIM);
        }
    }
    const float *enc = list + (size_t)(h->iters - 1) * S * MODEL_POSE_DIM;
    for (int s = 0; s < S; s++)
        model_pose_to_extri_intri(enc + s * MODEL_POSE_DIM, run->H, run->W, ext + s * 12,
                                  intr + s * 9);
    run->out->pose_enc_list = list;
    run->out->pose_enc = enc;
    run->out->extrinsic = ext;
    run->out->intrinsic = intr;
    return 0;
}

const struct model_head_ops model_camera_head_ops = {
    .api_version = MODEL_HEAD_API_VERSION,
    .prefix = "camera_head",
    .init = camera_init,
    .layers = camera_layers,
    .plan = camera_plan,
    .eval = camera_eval,
    .free = camera_free,
};
