/* model_aggregator.c - patch embed (DINOv2 or conv, vggt.md 2) and the
 * alternating frame / global attention aggregator (vggt.md 3). */
#include <stdlib.h>
#include <string.h>

#include "model_internal.h"

static const float resnet_mean[3] = { 0.485f, 0.456f, 0.406f };
static const float resnet_std[3] = { 0.229f, 0.224f, 0.225f };

int model_aggregator_load(struct model *m)
{
    const struct model_config *c = &m->cfg;
    const int C = c->embed_dim, R = c->num_register_tokens, p = c->patch_size;
    const int hid = model_mlp_hidden(c, C);
    char b[MODEL_NAME_MAX];
    int rc;
    if (c->patch_embed == MODEL_PATCH_DINO) {
        const int g = c->img_size / p;
        if ((rc = model_load_conv(m, &m->patch, "aggregator.patch_embed.patch_embed.proj", C, 3,
                                  p, p, 0, 1, FK_W_F32)) < 0)
            return rc;
        m->patch_packed = 1;
        if ((rc = model_load_f32(m, "aggregator.patch_embed.cls_token", (size_t)C, &m->cls)) < 0 ||
            (rc = model_load_f32(m, "aggregator.patch_embed.pos_embed",
                                 ((size_t)g * (size_t)g + 1) * (size_t)C, &m->pos_embed)) < 0)
            return rc;
        if (R > 0 && (rc = model_load_f32(m, "aggregator.patch_embed.register_tokens",
                                          (size_t)R * C, &m->dino_reg)) < 0)
            return rc;
        if ((rc = model_load_f32(m, "aggregator.patch_embed.norm.weight", (size_t)C, &m->dino_nw)) < 0 ||
            (rc = model_load_f32(m, "aggregator.patch_embed.norm.bias", (size_t)C, &m->dino_nb)) < 0)
            return rc;
        m->dino = calloc((size_t)c->dino_depth, sizeof *m->dino);
        if (!m->dino)
            return model_fail(m, F4D_ENOMEM, "model: out of memory");
        for (int i = 0; i < c->dino_depth; i++) {
            snprintf(b, sizeof b, "aggregator.patch_embed.blocks.%d", i);
            if ((rc = model_load_block(m, &m->dino[i], b, C, c->dino_num_heads, hid, 1e-6f, 0)) < 0)
                return rc;
        }
    } else {
        if ((rc = model_load_conv(m, &m->patch, "aggregator.patch_embed.proj", C, 3, p, p, 0, 1,
                                  FK_W_F32)) < 0)
            return rc;
        m->patch_packed = 1;
    }
    if ((rc = model_load_f32(m, "aggregator.camera_token", (size_t)2 * C, &m->cam_tok)) < 0)
        return rc;
    if (R > 0 && (rc = model_load_f32(m, "aggregator.register_token", (size_t)2 * R * C,
                                      &m->reg_tok)) < 0)
        return rc;
    m->frame = calloc((size_t)c->depth, sizeof *m->frame);
    m->global = calloc((size_t)c->depth, sizeof *m->global);
    if (!m->frame || !m->global)
        return model_fail(m, F4D_ENOMEM, "model: out of memory");
    for (int i = 0; i < c->depth; i++) {
        snprintf(b, sizeof b, "aggregator.frame_blocks.%d", i);
        if ((rc = model_load_block(m, &m->frame[i], b, C, c->num_heads, hid, 1e-5f, 1)) < 0)
            return rc;
        snprintf(b, sizeof b, "aggregator.global_blocks.%d", i);
        if ((rc = model_load_block(m, &m->global[i], b, C, c->num_heads, hid, 1e-5f, 1)) < 0)
            return rc;
    }
    return 0;
}

void model_aggregator_free(struct model *m)
{
    if (m->patch_packed)
        fk_conv2d_free(&m->patch);
    for (int i = 0; m->dino && i < m->cfg.dino_depth; i++)
        model_free_block(&m->dino[i]);
    /* Either array may be NULL when Init ran out of memory allocating it;
     * blocks not loaded yet are zero (calloc), which model_free_block takes. */
    for (int i = 0; m->frame && i < m->cfg.depth; i++)
        model_free_block(&m->frame[i]);
    for (int i = 0; m->global && i < m->cfg.depth; i++)
        model_free_block(&m->global[i]);
    free(m->dino);
    free(m->frame);
    free(m->global);
}

/* Scratch layout of the aggregator phase (shared by plan and eval). */
struct agg_bufs {
    float          *img, *x;
    struct blk_bufs bb;
};

static void agg_layout(struct bump *b, const struct model_config *c, int S, int H, int W,
                       struct agg_bufs *a)
{
    const int p = c->patch_size, P1 = 1 + c->num_register_tokens + (H / p) * (W / p);
    const int n = S * P1, C = c->embed_dim;
    a->img = BUMP_F(b, (size_t)H * W * 3);
    a->x = BUMP_F(b, (size_t)n * C);
    model_block_bufs(b, C, model_mlp_hidden(c, C), n, &a->bb);
}

void model_aggregator_plan(const struct model_config *c, uint64_t keep, int S, int H, int W,
                           size_t *persist, size_t *scratch)
{
    const int p = c->patch_size, P = (H / p) * (W / p), P1 = 1 + c->num_register_tokens + P;
    const size_t n = (size_t)S * P1, C = (size_t)c->embed_dim;
    struct bump b = { NULL, 0 };
    bump_take(&b, n * 2 * sizeof(int32_t));                    /* RoPE positions */
    bump_take(&b, n * sizeof(int32_t));                        /* stream row map */
    if (c->patch_embed == MODEL_PATCH_DINO)
        BUMP_F(&b, (size_t)P * C);                             /* resized pos-embed */
    for (int l = 0; l < c->depth; l++)
        if (keep >> l & 1)
            BUMP_F(&b, n * 2 * C);                             /* kept layer l */
    *persist = b.off;
    struct bump s = { NULL, 0 };
    struct agg_bufs a;
    agg_layout(&s, c, S, H, W, &a);
    *scratch = s.off;
}

static void copy_rows(float *dst, int ldd, const float *src, int lds, int rows, int cols)
{
    for (int r = 0; r < rows; r++)
        memcpy(dst + (size_t)r * ldd, src + (size_t)r * lds, (size_t)cols * sizeof *dst);
}

/* Stream rows into their layer rows (one half of [S*P', 2C]): a straight
 * copy when every token ran, else through the row map; the rows of dropped
 * patches keep what the previous Eval wrote there. */
static void store_layer(const struct model *m, float *dst, const float *x, int n, int C)
{
    if (!m->tok_masked) {
        copy_rows(dst, 2 * C, x, C, n, C);
        return;
    }
    for (int r = 0; r < n; r++)
        memcpy(dst + (size_t)m->row[r] * 2 * C, x + (size_t)r * C, (size_t)C * sizeof *dst);
}

/* The token stream: per frame its specials and kept patches, packed. Fills
 * tok_off, the row map and the RoPE positions (specials (0, 0), patch (r, c)
 * at (r + 1, c + 1): a kept token has its real grid position). */
static int plan_stream(struct model *m, int S, int w, int P, int ns, const uint8_t *keep)
{
    int n = 0;
    m->tok_masked = 0;
    for (int f = 0; f < S; f++) {
        m->tok_off[f] = n;
        for (int t = 0; t < ns + P; t++) {
            if (t >= ns && keep && !keep[(size_t)f * P + (t - ns)]) {
                m->tok_masked = 1;
                continue;
            }
            int32_t *q = m->pos + 2 * (size_t)n;
            q[0] = t < ns ? 0 : (t - ns) / w + 1;
            q[1] = t < ns ? 0 : (t - ns) % w + 1;
            m->row[n++] = f * (ns + P) + t;
        }
    }
    m->tok_off[S] = n;
    m->tok_S = S;
    return n;
}

int model_aggregator_eval(struct model *m, const float *images, int S, int H, int W,
                          const uint8_t *keep)
{
    const struct model_config *c = &m->cfg;
    const int p = c->patch_size, h = H / p, w = W / p, P = h * w;
    const int R = c->num_register_tokens, ns = 1 + R, P1 = ns + P, C = c->embed_dim;
    struct bump sb = { (unsigned char *)m->scratch, 0 };
    struct agg_bufs a;
    agg_layout(&sb, c, S, H, W, &a);
    if (m->stream) /* Forge4D state / motion blocks: their scratch follows */
        model_stream_scratch(m, &sb, S, H, W);
    float *x = a.x;
    int rc;
    double t0 = model_now();
    m->flops = &m->st_flops[ST_PATCH];

    /* Dropped patches reuse their rows of the last complete run of this frame
     * set; without one, every patch runs. The layers are then half-written
     * until the loop ends, so they count as invalid until it does. */
    if (!m->layers_valid || m->layers_S != S || m->layers_H != H || m->layers_W != W)
        keep = NULL;
    /* Forge4D's motion blocks reuse the dropped rows of z(t-1) and of the
     * kept motion streams: only after a step that ran the motion. */
    if (m->stream && !model_stream_mask_ok(m))
        keep = NULL;
    m->layers_valid = 0;
    const int n = plan_stream(m, S, w, P, ns, keep);
    m->keep_now = m->tok_masked ? keep : NULL;
    const int *off = m->tok_off;
    if (c->patch_embed == MODEL_PATCH_DINO && (m->pe_h != h || m->pe_w != w)) {
        const int g = c->img_size / p;
        if (fk_resize_bicubic_aa(m->ctx, m->pos_embed + C, g, g, C, m->pe_grid, h, w) != F4D_OK)
            return model_kfail(m, "pos-embed resize");
        m->pe_h = h;
        m->pe_w = w;
    }
    for (int f = 0; f < S; f++) {
        const float *im = images + (size_t)f * 3 * H * W;
        for (int y = 0; y < H; y++)
            for (int xx = 0; xx < W; xx++)
                for (int ch = 0; ch < 3; ch++)
                    a.img[((size_t)y * W + xx) * 3 + ch] =
                        (im[((size_t)ch * H + y) * W + xx] - resnet_mean[ch]) / resnet_std[ch];
        /* Every patch of frame f at its full-stream place (the patchify is
         * 0.04 % of the model), then the kept rows packed down to off[f]:
         * each row moves to a lower or equal row, frame f+1's place lies
         * above, so forward order never overwrites a row still to move. */
        float *tok = x + (size_t)f * P1 * C;
        if ((rc = model_conv(m, &m->patch, a.img, H, W, tok + (size_t)ns * C, FK_ACT_NONE)) < 0)
            return rc;
        if (c->patch_embed == MODEL_PATCH_DINO) {
            for (int i = 0; i < C; i++)
                tok[i] = m->cls[i] + m->pos_embed[i];
            if (R)
                memcpy(tok + C, m->dino_reg, (size_t)R * C * sizeof *tok);
            if (fk_residual_add(m->ctx, tok + (size_t)ns * C, C, m->pe_grid, C, NULL, P, C) != F4D_OK)
                return model_kfail(m, "pos-embed add");
        }
        if (m->tok_masked)
            for (int r = off[f]; r < off[f + 1]; r++)
                memmove(x + (size_t)r * C, x + (size_t)m->row[r] * C, (size_t)C * sizeof *x);
    }
    double t1 = model_now();
    m->st_sec[ST_PATCH] += t1 - t0;
    if (c->patch_embed == MODEL_PATCH_DINO) {
        m->flops = &m->st_flops[ST_DINO];
        for (int i = 0; i < c->dino_depth; i++)
            if ((rc = model_block_forward_seqs(m, &m->dino[i], x, S, off, NULL, &a.bb)) < 0)
                return rc;
        if (fk_layernorm(m->ctx, x, n, C, C, m->dino_nw, m->dino_nb, 1e-6f, x, C) != F4D_OK)
            return model_kfail(m, "dino norm");
        m->st_sec[ST_DINO] += model_now() - t1;
    }
    for (int f = 0; f < S; f++) {
        float *tok = x + (size_t)off[f] * C;
        if (m->tap)
            m->tap(m->tap_user, "patch_embed", f, tok + (size_t)ns * C,
                   (size_t)(off[f + 1] - off[f] - ns) * C);
        int slot = f == 0 ? 0 : 1;
        memcpy(tok, m->cam_tok + (size_t)slot * C, (size_t)C * sizeof *tok);
        if (R)
            memcpy(tok + C, m->reg_tok + (size_t)slot * R * C, (size_t)R * C * sizeof *tok);
    }

    /* The stream is x [n, C]: n = S*P' when every patch runs, else the packed
     * kept tokens (off[] per frame). Frame attention runs per frame, global
     * attention over all n rows. */
    const int all[2] = { 0, n };
    for (int i = 0; i < c->depth; i++) {
        double ta = model_now();
        m->flops = &m->st_flops[ST_FRAME];
        if ((rc = model_block_forward_seqs(m, &m->frame[i], x, S, off, m->pos, &a.bb)) < 0)
            return rc;
        if (m->layers[i])
            store_layer(m, m->layers[i], x, n, C);
        if (m->stream && (rc = model_stream_frame(m, i, x, n)) < 0)
            return rc;
        double tb = model_now();
        m->st_sec[ST_FRAME] += tb - ta;
        m->flops = &m->st_flops[ST_GLOBAL];
        if ((rc = model_block_forward_seqs(m, &m->global[i], x, 1, all, m->pos, &a.bb)) < 0)
            return rc;
        m->st_sec[ST_GLOBAL] += model_now() - tb;
        if (m->stream && (rc = model_stream_global(m, i, x, S, P1, &a.bb)) < 0)
            return rc;
        if (m->hooks.after_global &&
            (rc = m->hooks.after_global(m->hooks.user, i, x, S, m->tok_masked ? 0 : P1, C)) < 0)
            return model_fail(m, F4D_EINVAL, "model: after_global hook failed at layer %d (%d)",
                              i, rc);
        if (m->layers[i]) {
            store_layer(m, m->layers[i] + C, x, n, C);
            if (m->tap) {
                char nm[32];
                snprintf(nm, sizeof nm, "layer%d", i);
                m->tap(m->tap_user, nm, -1, m->layers[i], (size_t)S * P1 * 2 * C);
            }
        }
    }
    m->layers_valid = 1;
    m->layers_S = S;
    m->layers_H = H;
    m->layers_W = W;
    return 0;
}
