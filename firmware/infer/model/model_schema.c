/* model_schema.c - every parameter name and shape of VGGT (vggt.md 2-6) and of
 * Forge4D's modules (forge4d-arch.md 1-7), from the config. The converter checks a checkpoint against it and the loader reads
 * the weight file through it, so there is one table of names. */
#include <stdarg.h>
#include <stdio.h>
#include <string.h>

#include "model.h"

struct emit {
    model_tensor_fn fn;
    void           *user;
    unsigned        group;
    int             rc;
};

static void put(struct emit *e, int tclass, int qaxis, int nd, const int64_t *shape,
                const char *fmt, ...)
{
    if (e->rc < 0)
        return;
    struct model_tensor_info t;
    memset(&t, 0, sizeof t);
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(t.name, sizeof t.name, fmt, ap);
    va_end(ap);
    t.n_dims = nd;
    for (int i = 0; i < nd; i++)
        t.shape[i] = shape[i];
    t.tclass = tclass;
    t.qaxis = qaxis;
    t.group = e->group;
    e->rc = e->fn(e->user, &t);
}

#define S1(a) (const int64_t[]){ (a) }
#define S2(a, b) (const int64_t[]){ (a), (b) }
#define S3(a, b, c) (const int64_t[]){ (a), (b), (c) }
#define S4(a, b, c, d) (const int64_t[]){ (a), (b), (c), (d) }

static void linear(struct emit *e, const char *p, int out, int in)
{
    put(e, MODEL_T_QUANT, 0, 2, S2(out, in), "%s.weight", p);
    put(e, MODEL_T_F32, 0, 1, S1(out), "%s.bias", p);
}

static void norm(struct emit *e, const char *p, int n)
{
    put(e, MODEL_T_F32, 0, 1, S1(n), "%s.weight", p);
    put(e, MODEL_T_F32, 0, 1, S1(n), "%s.bias", p);
}

static void conv(struct emit *e, const char *p, int out, int in, int k, int bias)
{
    put(e, MODEL_T_QUANT, 0, 4, S4(out, in, k, k), "%s.weight", p);
    if (bias)
        put(e, MODEL_T_F32, 0, 1, S1(out), "%s.bias", p);
}

static void block(struct emit *e, const char *p, int dim, int heads, int hidden, int qk_norm)
{
    char b[MODEL_NAME_MAX];
    snprintf(b, sizeof b, "%s.norm1", p);      norm(e, b, dim);
    snprintf(b, sizeof b, "%s.attn.qkv", p);   linear(e, b, 3 * dim, dim);
    if (qk_norm) {
        snprintf(b, sizeof b, "%s.attn.q_norm", p); norm(e, b, dim / heads);
        snprintf(b, sizeof b, "%s.attn.k_norm", p); norm(e, b, dim / heads);
    }
    snprintf(b, sizeof b, "%s.attn.proj", p);  linear(e, b, dim, dim);
    put(e, MODEL_T_F32, 0, 1, S1(dim), "%s.ls1.gamma", p);
    snprintf(b, sizeof b, "%s.norm2", p);      norm(e, b, dim);
    snprintf(b, sizeof b, "%s.mlp.fc1", p);    linear(e, b, hidden, dim);
    snprintf(b, sizeof b, "%s.mlp.fc2", p);    linear(e, b, dim, hidden);
    put(e, MODEL_T_F32, 0, 1, S1(dim), "%s.ls2.gamma", p);
}

/* A DPT head on tokens `D` wide (2C for the VGGT heads, C for the motion head). */
/* "<p>.<sub>" into buf (names are far shorter than MODEL_NAME_MAX; a longer
 * one is cut and then fails every lookup). */
static const char *sub(char *buf, const char *p, const char *suffix)
{
    if (snprintf(buf, MODEL_NAME_MAX, "%s.%s", p, suffix) >= MODEL_NAME_MAX)
        buf[MODEL_NAME_MAX - 1] = 0;
    return buf;
}

/* Cross-attention of forge4d-arch.md 4-5: q (C -> C), kv (C -> 2C: k then v), proj. */
static void xattn(struct emit *e, const char *p, int dim)
{
    char b[MODEL_NAME_MAX];
    linear(e, sub(b, p, "q"), dim, dim);
    linear(e, sub(b, p, "kv"), 2 * dim, dim);
    linear(e, sub(b, p, "proj"), dim, dim);
}

/* The MLP of a Forge4D block and the LayerScale after it. */
static void mlp_ls(struct emit *e, const char *p, int dim, int hidden, const char *ls)
{
    char b[MODEL_NAME_MAX];
    linear(e, sub(b, p, "mlp.fc1"), hidden, dim);
    linear(e, sub(b, p, "mlp.fc2"), dim, hidden);
    put(e, MODEL_T_F32, 0, 1, S1(dim), "%s.%s.gamma", p, ls);
}

static void dpt(struct emit *e, const char *h, const struct model_config *c, int out_dim, int D)
{
    char b[MODEL_NAME_MAX];
    const int *oc = c->dpt_out_channels, F = c->dpt_features;
    snprintf(b, sizeof b, "%s.norm", h); norm(e, b, D);
    for (int i = 0; i < 4; i++) {
        snprintf(b, sizeof b, "%s.projects.%d", h, i);
        conv(e, b, oc[i], D, 1, 1);
    }
    put(e, MODEL_T_QUANT, 1, 4, S4(oc[0], oc[0], 4, 4), "%s.resize_layers.0.weight", h);
    put(e, MODEL_T_F32, 0, 1, S1(oc[0]), "%s.resize_layers.0.bias", h);
    put(e, MODEL_T_QUANT, 1, 4, S4(oc[1], oc[1], 2, 2), "%s.resize_layers.1.weight", h);
    put(e, MODEL_T_F32, 0, 1, S1(oc[1]), "%s.resize_layers.1.bias", h);
    snprintf(b, sizeof b, "%s.resize_layers.3", h); conv(e, b, oc[3], oc[3], 3, 1);
    for (int i = 0; i < 4; i++) {
        snprintf(b, sizeof b, "%s.scratch.layer%d_rn", h, i + 1);
        conv(e, b, F, oc[i], 3, 0);
    }
    for (int r = 1; r <= 4; r++)
        for (int u = (r == 4 ? 2 : 1); u <= 2; u++)
            for (int k = 1; k <= 2; k++) {
                snprintf(b, sizeof b, "%s.scratch.refinenet%d.resConfUnit%d.conv%d", h, r, u, k);
                conv(e, b, F, F, 3, 1);
            }
    for (int r = 1; r <= 4; r++) {
        snprintf(b, sizeof b, "%s.scratch.refinenet%d.out_conv", h, r);
        conv(e, b, F, F, 1, 1);
    }
    snprintf(b, sizeof b, "%s.scratch.output_conv1", h);   conv(e, b, F / 2, F, 3, 1);
    snprintf(b, sizeof b, "%s.scratch.output_conv2.0", h); conv(e, b, MODEL_DPT_HIDDEN2, F / 2, 3, 1);
    snprintf(b, sizeof b, "%s.scratch.output_conv2.2", h); conv(e, b, out_dim, MODEL_DPT_HIDDEN2, 1, 1);
}

int model_schema_foreach(const struct model_config *c, unsigned groups, model_tensor_fn fn,
                         void *user)
{
    struct emit e = { fn, user, 0, 0 };
    char b[MODEL_NAME_MAX];
    const int C = c->embed_dim, D = 2 * C, R = c->num_register_tokens, p = c->patch_size;
    const int hid = model_mlp_hidden(c, C);
    if (groups & MODEL_G_AGGREGATOR) {
        e.group = MODEL_G_AGGREGATOR;
        if (c->patch_embed == MODEL_PATCH_DINO) {
            const int g = c->img_size / p;
            /* The patchify conv stays f32: it sees raw pixels (6.6 GFLOP only). */
            put(&e, MODEL_T_F32, 0, 4, S4(C, 3, p, p), "aggregator.patch_embed.patch_embed.proj.weight");
            put(&e, MODEL_T_F32, 0, 1, S1(C), "aggregator.patch_embed.patch_embed.proj.bias");
            put(&e, MODEL_T_F32, 0, 3, S3(1, 1, C), "aggregator.patch_embed.cls_token");
            put(&e, MODEL_T_F32, 0, 3, S3(1, (int64_t)g * g + 1, C), "aggregator.patch_embed.pos_embed");
            if (R > 0)
                put(&e, MODEL_T_F32, 0, 3, S3(1, R, C), "aggregator.patch_embed.register_tokens");
            put(&e, MODEL_T_UNUSED, 0, 2, S2(1, C), "aggregator.patch_embed.mask_token");
            for (int i = 0; i < c->dino_depth; i++) {
                snprintf(b, sizeof b, "aggregator.patch_embed.blocks.%d", i);
                block(&e, b, C, c->dino_num_heads, hid, 0);
            }
            norm(&e, "aggregator.patch_embed.norm", C);
        } else {
            put(&e, MODEL_T_F32, 0, 4, S4(C, 3, p, p), "aggregator.patch_embed.proj.weight");
            put(&e, MODEL_T_F32, 0, 1, S1(C), "aggregator.patch_embed.proj.bias");
        }
        put(&e, MODEL_T_F32, 0, 4, S4(1, 2, 1, C), "aggregator.camera_token");
        if (R > 0)
            put(&e, MODEL_T_F32, 0, 4, S4(1, 2, R, C), "aggregator.register_token");
        for (int i = 0; i < c->depth; i++) {
            snprintf(b, sizeof b, "aggregator.frame_blocks.%d", i);
            block(&e, b, C, c->num_heads, hid, 1);
        }
        for (int i = 0; i < c->depth; i++) {
            snprintf(b, sizeof b, "aggregator.global_blocks.%d", i);
            block(&e, b, C, c->num_heads, hid, 1);
        }
    }
    if (groups & MODEL_G_CAMERA) {
        e.group = MODEL_G_CAMERA;
        norm(&e, "camera_head.token_norm", D);
        norm(&e, "camera_head.trunk_norm", D);
        put(&e, MODEL_T_F32, 0, 3, S3(1, 1, MODEL_POSE_DIM), "camera_head.empty_pose_tokens");
        linear(&e, "camera_head.embed_pose", D, MODEL_POSE_DIM);
        linear(&e, "camera_head.poseLN_modulation.1", 3 * D, D);
        for (int i = 0; i < c->camera_trunk_depth; i++) {
            snprintf(b, sizeof b, "camera_head.trunk.%d", i);
            block(&e, b, D, c->camera_num_heads, model_mlp_hidden(c, D), 0);
        }
        linear(&e, "camera_head.pose_branch.fc1", D / 2, D);
        linear(&e, "camera_head.pose_branch.fc2", MODEL_POSE_DIM, D / 2);
    }
    if (groups & MODEL_G_DEPTH) {
        e.group = MODEL_G_DEPTH;
        dpt(&e, "depth_head", c, 2, D);
    }
    if (groups & MODEL_G_POINT) {
        e.group = MODEL_G_POINT;
        dpt(&e, "point_head", c, 4, D);
    }
    /* Forge4D (forge4d-arch.md 1-2) */
    if (groups & MODEL_G_GAUSSIAN) {
        e.group = MODEL_G_GAUSSIAN;
        dpt(&e, "gaussian_head", c, MODEL_GAUSS_CH, D);
    }
    if (groups & MODEL_G_SCALE) {
        e.group = MODEL_G_SCALE;
        norm(&e, "scale_head.norm", D);
        linear(&e, "scale_head.fc1", C, D);
        linear(&e, "scale_head.fc2", 1, C);
    }
    /* Forge4D stages 2-3 (forge4d-arch.md 4-6; sub-names in forge4d_ref.py) */
    if (groups & MODEL_G_STATE) {
        e.group = MODEL_G_STATE;
        put(&e, MODEL_T_F32, 0, 2, S2(MODEL_STATE_TOKENS, C), "state.tokens");
        for (int i = 0; i < c->depth; i++) {
            char q[MODEL_NAME_MAX];
            snprintf(b, sizeof b, "state.blocks.%d", i);
            norm(&e, sub(q, b, "norm_x"), C);
            norm(&e, sub(q, b, "norm_s"), C);
            xattn(&e, sub(q, b, "attn_r"), C);
            put(&e, MODEL_T_F32, 0, 1, S1(C), "%s.ls_r.gamma", b);
            norm(&e, sub(q, b, "norm_s2"), C);
            norm(&e, sub(q, b, "norm_x2"), C);
            xattn(&e, sub(q, b, "attn_w"), C);
            put(&e, MODEL_T_F32, 0, 1, S1(C), "%s.ls_w.gamma", b);
            norm(&e, sub(q, b, "norm_m"), C);
            mlp_ls(&e, b, C, hid, "ls_m");
        }
    }
    if (groups & MODEL_G_MOTION) {
        e.group = MODEL_G_MOTION;
        /* only at the layers of motion_layers (model.h); names keep the layer index */
        const uint64_t mm = model_motion_mask(c);
        for (int i = 0; i < c->depth; i++) {
            if (!((mm >> i) & 1))
                continue;
            snprintf(b, sizeof b, "motion.in_proj.%d", i);
            linear(&e, b, C, D);
        }
        for (int i = 0; i < c->depth; i++) {
            char q[MODEL_NAME_MAX];
            if (!((mm >> i) & 1))
                continue;
            snprintf(b, sizeof b, "motion.blocks.%d", i);
            norm(&e, sub(q, b, "norm1"), C);
            norm(&e, sub(q, b, "norm_kv"), C);
            xattn(&e, sub(q, b, "attn"), C);
            put(&e, MODEL_T_F32, 0, 1, S1(C), "%s.ls1.gamma", b);
            norm(&e, sub(q, b, "norm2"), C);
            mlp_ls(&e, b, C, hid, "ls2");
        }
    }
    if (groups & MODEL_G_MOTION_HEAD) {
        e.group = MODEL_G_MOTION_HEAD;
        struct model_config mc = *c; /* its own DPT width */
        mc.dpt_features = model_motion_features(c);
        dpt(&e, "motion_head", &mc, MODEL_MOTION_CH, C);
    }
    if (groups & MODEL_G_FUSION) {
        /* Kept f32 in every precision: 2.8 k MACs per fused pair, scalar code. */
        e.group = MODEL_G_FUSION;
        put(&e, MODEL_T_F32, 0, 2, S2(MODEL_FUSION_HIDDEN, MODEL_FUSION_IN), "fusion.fc1.weight");
        put(&e, MODEL_T_F32, 0, 1, S1(MODEL_FUSION_HIDDEN), "fusion.fc1.bias");
        put(&e, MODEL_T_F32, 0, 2, S2(MODEL_FUSION_ATTRS, MODEL_FUSION_HIDDEN), "fusion.fc2.weight");
        put(&e, MODEL_T_F32, 0, 1, S1(MODEL_FUSION_ATTRS), "fusion.fc2.bias");
    }
    return e.rc;
}

static const struct { unsigned g; const char *prefix; } groups_tab[] = {
    { MODEL_G_AGGREGATOR, "aggregator." }, { MODEL_G_CAMERA, "camera_head." },
    { MODEL_G_DEPTH, "depth_head." },      { MODEL_G_POINT, "point_head." },
    { MODEL_G_GAUSSIAN, "gaussian_head." }, { MODEL_G_SCALE, "scale_head." },
    { MODEL_G_STATE, "state." },           { MODEL_G_MOTION, "motion." },
    { MODEL_G_MOTION_HEAD, "motion_head." }, { MODEL_G_FUSION, "fusion." },
};

unsigned model_group_of(const char *name)
{
    for (size_t i = 0; i < sizeof groups_tab / sizeof groups_tab[0]; i++)
        if (!strncmp(name, groups_tab[i].prefix, strlen(groups_tab[i].prefix)))
            return groups_tab[i].g;
    return 0;
}

const char *model_group_prefix(unsigned group)
{
    for (size_t i = 0; i < sizeof groups_tab / sizeof groups_tab[0]; i++)
        if (groups_tab[i].g == group)
            return groups_tab[i].prefix;
    return "";
}

static int add_bytes(void *user, const struct model_tensor_info *t)
{
    uint64_t *sum = user, n = 1;
    if (t->tclass == MODEL_T_UNUSED)
        return 0;
    for (int d = 0; d < t->n_dims; d++)
        n *= (uint64_t)t->shape[d];
    *sum += n * sizeof(float);
    return 0;
}

uint64_t model_schema_bytes(const struct model_config *c, unsigned groups)
{
    uint64_t sum = 0;
    model_schema_foreach(c, groups, add_bytes, &sum);
    return sum;
}
