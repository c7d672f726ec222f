/* model_config.c - the network's dimensions: VGGT-1B defaults, checks, GGUF keys. */
#include <stdarg.h>
#include <stdio.h>
#include <string.h>

#include "model.h"


void model_config_default(struct model_config *c)
{
    static const struct model_config vggt_1b = {
        .img_size = 518, .patch_size = 14, .embed_dim = 1024, .depth = 24, .num_heads = 16,
        .mlp_ratio = 4.0f, .num_register_tokens = 4, .patch_embed = MODEL_PATCH_DINO,
        .dino_depth = 24, .dino_num_heads = 16, .camera_trunk_depth = 4,
        .camera_num_heads = 16, .camera_iters = 4, .dpt_features = 256,
        .dpt_out_channels = { 256, 512, 1024, 1024 }, .dpt_layer_idx = { 4, 11, 17, 23 },
        /* motion blocks at the 4 DPT layers, a 128-wide motion head: a motion
         * step at ~15 % of a key frame (README), the paper's 27 % or less */
        .motion_layers = 0, .motion_dpt_features = 128,
    };
    *c = vggt_1b;
}

uint64_t model_motion_mask(const struct model_config *c)
{
    if (c->motion_layers)
        return c->motion_layers;
    uint64_t m = 0;
    for (int i = 0; i < 4; i++)
        if (c->dpt_layer_idx[i] >= 0 && c->dpt_layer_idx[i] < MODEL_LAYERS_MAX)
            m |= UINT64_C(1) << c->dpt_layer_idx[i];
    return m;
}

int model_motion_features(const struct model_config *c)
{
    return c->motion_dpt_features ? c->motion_dpt_features : c->dpt_features;
}

int model_mlp_hidden(const struct model_config *c, int dim)
{
    return (int)((double)dim * (double)c->mlp_ratio); /* Python int(dim * ratio) */
}

int model_config_check(const struct model_config *c, struct f4d_err *err)
{
    if (c->patch_size < 1 || c->patch_size > 64)
        return f4d_fail(err, F4D_EFORMAT, "config: patch_size %d out of 1..64", c->patch_size);
    /* img_size sizes the DINO pos-embed table, 1 + (img_size / patch_size)^2
     * rows: bounded like the input frames (model_prepare takes <= 4096). */
    if (c->img_size < c->patch_size || c->img_size > MODEL_IMG_MAX)
        return f4d_fail(err, F4D_EFORMAT, "config: img_size %d out of patch_size %d..%d", c->img_size,
                    c->patch_size, MODEL_IMG_MAX);
    if (c->img_size % c->patch_size)
        return f4d_fail(err, F4D_EFORMAT, "config: img_size %d is not a multiple of patch_size %d",
                    c->img_size, c->patch_size);
    if (c->embed_dim < 4 || c->embed_dim > MODEL_DIM_MAX)
        return f4d_fail(err, F4D_EFORMAT, "config: embed_dim %d out of 4..%d", c->embed_dim, MODEL_DIM_MAX);
    if (c->depth < 1 || c->depth > MODEL_LAYERS_MAX)
        return f4d_fail(err, F4D_EFORMAT, "config: depth %d out of 1..%d", c->depth, MODEL_LAYERS_MAX);
    if (c->num_heads < 1 || c->num_heads > c->embed_dim || c->embed_dim % c->num_heads || (c->embed_dim / c->num_heads) % 4)
        return f4d_fail(err, F4D_EFORMAT, "config: num_heads %d must divide embed_dim %d into head dims "
                    "that are multiples of 4 (RoPE)", c->num_heads, c->embed_dim);
    if (!(c->mlp_ratio > 0.0f) || c->mlp_ratio > 16.0f || model_mlp_hidden(c, c->embed_dim) < 1)
        return f4d_fail(err, F4D_EFORMAT, "config: mlp_ratio %g out of (0, 16]", (double)c->mlp_ratio);
    if (c->num_register_tokens < 0 || c->num_register_tokens > 64)
        return f4d_fail(err, F4D_EFORMAT, "config: num_register_tokens %d out of 0..64",
                    c->num_register_tokens);
    if (c->patch_embed != MODEL_PATCH_DINO && c->patch_embed != MODEL_PATCH_CONV)
        return f4d_fail(err, F4D_EFORMAT, "config: patch_embed %d is neither dino nor conv", c->patch_embed);
    if (c->patch_embed == MODEL_PATCH_DINO) {
        if (c->dino_depth < 1 || c->dino_depth > MODEL_LAYERS_MAX)
            return f4d_fail(err, F4D_EFORMAT, "config: dino_depth %d out of 1..%d", c->dino_depth,
                        MODEL_LAYERS_MAX);
        if (c->dino_num_heads < 1 || c->dino_num_heads > c->embed_dim ||
            c->embed_dim % c->dino_num_heads ||
            (c->embed_dim / c->dino_num_heads) % 2)
            return f4d_fail(err, F4D_EFORMAT, "config: dino_num_heads %d does not divide embed_dim %d",
                        c->dino_num_heads, c->embed_dim);
    }
    int d2 = 2 * c->embed_dim;
    if (c->camera_trunk_depth < 1 || c->camera_trunk_depth > MODEL_LAYERS_MAX)
        return f4d_fail(err, F4D_EFORMAT, "config: camera_trunk_depth %d out of 1..%d",
                    c->camera_trunk_depth, MODEL_LAYERS_MAX);
    if (c->camera_num_heads < 1 || c->camera_num_heads > d2 || d2 % c->camera_num_heads || (d2 / c->camera_num_heads) % 2)
        return f4d_fail(err, F4D_EFORMAT, "config: camera_num_heads %d does not divide 2*embed_dim %d",
                    c->camera_num_heads, d2);
    if (c->camera_iters < 1 || c->camera_iters > 16)
        return f4d_fail(err, F4D_EFORMAT, "config: camera_iters %d out of 1..16", c->camera_iters);
    if (c->dpt_features < 8 || c->dpt_features > MODEL_DIM_MAX || c->dpt_features % 8)
        return f4d_fail(err, F4D_EFORMAT, "config: dpt_features %d must be a multiple of 8 in 8..%d",
                    c->dpt_features, MODEL_DIM_MAX);
    for (int i = 0; i < 4; i++) {
        if (c->dpt_out_channels[i] < 4 || c->dpt_out_channels[i] > MODEL_DIM_MAX ||
            c->dpt_out_channels[i] % 4)
            return f4d_fail(err, F4D_EFORMAT, "config: dpt_out_channels[%d] = %d must be a multiple of 4 "
                        "in 4..%d", i, c->dpt_out_channels[i], MODEL_DIM_MAX);
        if (c->dpt_layer_idx[i] < 0 || c->dpt_layer_idx[i] >= c->depth)
            return f4d_fail(err, F4D_EFORMAT, "config: dpt_layer_idx[%d] = %d out of 0..%d", i,
                        c->dpt_layer_idx[i], c->depth - 1);
    }
    const int mf = model_motion_features(c);
    if (mf < 8 || mf > MODEL_DIM_MAX || mf % 8)
        return f4d_fail(err, F4D_EFORMAT, "config: motion_dpt_features %d must be a multiple of 8 "
                        "in 8..%d", mf, MODEL_DIM_MAX);
    const uint64_t mm = model_motion_mask(c);
    if (c->depth < MODEL_LAYERS_MAX && (mm >> c->depth))
        return f4d_fail(err, F4D_EFORMAT, "config: motion_layers names a layer beyond depth %d",
                        c->depth);
    for (int i = 0; i < 4; i++)
        if (!((mm >> c->dpt_layer_idx[i]) & 1))
            return f4d_fail(err, F4D_EFORMAT, "config: motion_layers lacks dpt_layer_idx[%d] = %d "
                            "(the motion head reads the stream after it)", i, c->dpt_layer_idx[i]);
    return F4D_OK;
}

/* The forge4d.* integer keys, in one table shared by reader and writer. */
#define INT_KEYS(X) \
    X(img_size) X(patch_size) X(embed_dim) X(depth) X(num_heads) X(num_register_tokens) \
    X(dino_depth) X(dino_num_heads) X(camera_trunk_depth) X(camera_num_heads) \
    X(camera_iters) X(dpt_features)

int model_config_read(gguf_file *f, struct model_config *c, struct f4d_err *err)
{
    int64_t v;
    double d;
    const char *s;
    memset(c, 0, sizeof *c);
    if (gguf_get_str(f, "general.architecture", &s) < 0 || strcmp(s, "forge4d"))
        return f4d_fail(err, F4D_EFORMAT, "config: key 'general.architecture' must be \"forge4d\"");
#define READ_INT(k) \
    if (gguf_get_int(f, "forge4d." #k, &v) < 0) return f4d_fail(err, F4D_EFORMAT, "%s", gguf_error(f)); \
    if (v < 0 || v > 1000000) return f4d_fail(err, F4D_EFORMAT, "config: key 'forge4d." #k "' = %lld out of range", (long long)v); \
    c->k = (int)v;
    INT_KEYS(READ_INT)
#undef READ_INT
    if (gguf_get_float(f, "forge4d.mlp_ratio", &d) < 0)
        return f4d_fail(err, F4D_EFORMAT, "%s", gguf_error(f));
    c->mlp_ratio = (float)d;
    if (gguf_get_str(f, "forge4d.patch_embed", &s) < 0)
        return f4d_fail(err, F4D_EFORMAT, "%s", gguf_error(f));
    if (!strcmp(s, "dino"))
        c->patch_embed = MODEL_PATCH_DINO;
    else if (!strcmp(s, "conv"))
        c->patch_embed = MODEL_PATCH_CONV;
    else
        return f4d_fail(err, F4D_EFORMAT, "config: key 'forge4d.patch_embed' = \"%s\" (dino or conv)", s);
    int64_t a[8];
    size_t na;
    static const char *arr_keys[2] = { "forge4d.dpt_out_channels", "forge4d.dpt_layer_idx" };
    for (int k = 0; k < 2; k++) {
        if (gguf_get_int_array(f, arr_keys[k], a, 8, &na) < 0)
            return f4d_fail(err, F4D_EFORMAT, "%s", gguf_error(f));
        if (na != 4)
            return f4d_fail(err, F4D_EFORMAT, "config: key '%s' has %zu entries, expected 4", arr_keys[k], na);
        for (int i = 0; i < 4; i++) {
            if (a[i] < 0 || a[i] > 100000)
                return f4d_fail(err, F4D_EFORMAT, "config: key '%s'[%d] out of range", arr_keys[k], i);
            (k ? c->dpt_layer_idx : c->dpt_out_channels)[i] = (int)a[i];
        }
    }
    /* Forge4D's motion keys are optional (files from before them): absent,
     * the fields stay 0, i.e. blocks at the DPT layers, head at dpt_features. */
    if (gguf_key_type(f, "forge4d.motion_layers") >= 0) {
        int64_t ml[MODEL_LAYERS_MAX];
        size_t nm;
        if (gguf_get_int_array(f, "forge4d.motion_layers", ml, MODEL_LAYERS_MAX, &nm) < 0)
            return f4d_fail(err, F4D_EFORMAT, "%s", gguf_error(f));
        if (nm == 0)
            return f4d_fail(err, F4D_EFORMAT, "config: key 'forge4d.motion_layers' is empty");
        for (size_t i = 0; i < nm; i++) {
            if (ml[i] < 0 || ml[i] >= MODEL_LAYERS_MAX)
                return f4d_fail(err, F4D_EFORMAT, "config: key 'forge4d.motion_layers'[%zu] = %lld "
                                "out of 0..%d", i, (long long)ml[i], MODEL_LAYERS_MAX - 1);
            c->motion_layers |= UINT64_C(1) << ml[i];
        }
    }
    if (gguf_key_type(f, "forge4d.motion_dpt_features") >= 0) {
        if (gguf_get_int(f, "forge4d.motion_dpt_features", &v) < 0)
            return f4d_fail(err, F4D_EFORMAT, "%s", gguf_error(f));
        if (v < 1 || v > 1000000)
            return f4d_fail(err, F4D_EFORMAT, "config: key 'forge4d.motion_dpt_features' = %lld "
                            "out of range", (long long)v);
        c->motion_dpt_features = (int)v;
    }
    return model_config_check(c, err);
}

int model_config_write(const struct model_config *c, gguf_writer *w)
{
    int rc = 0;
    rc |= gguf_writer_add_str(w, "general.architecture", "forge4d");
    rc |= gguf_writer_add_str(w, "general.name", "VGGT");
#define WRITE_INT(k) rc |= gguf_writer_add_int(w, "forge4d." #k, GGUF_V_UINT32, c->k);
    INT_KEYS(WRITE_INT)
#undef WRITE_INT
    rc |= gguf_writer_add_f32(w, "forge4d.mlp_ratio", c->mlp_ratio);
    rc |= gguf_writer_add_str(w, "forge4d.patch_embed",
                              c->patch_embed == MODEL_PATCH_CONV ? "conv" : "dino");
    int64_t oc[4], li[4];
    for (int i = 0; i < 4; i++) {
        oc[i] = c->dpt_out_channels[i];
        li[i] = c->dpt_layer_idx[i];
    }
    rc |= gguf_writer_add_int_array(w, "forge4d.dpt_out_channels", GGUF_V_UINT32, oc, 4);
    rc |= gguf_writer_add_int_array(w, "forge4d.dpt_layer_idx", GGUF_V_UINT32, li, 4);
    /* the motion keys resolved, so a reader needs no default */
    int64_t ml[MODEL_LAYERS_MAX];
    size_t nm = 0;
    const uint64_t mm = model_motion_mask(c);
    for (int l = 0; l < MODEL_LAYERS_MAX; l++)
        if ((mm >> l) & 1)
            ml[nm++] = l;
    rc |= gguf_writer_add_int_array(w, "forge4d.motion_layers", GGUF_V_UINT32, ml, nm);
    rc |= gguf_writer_add_int(w, "forge4d.motion_dpt_features", GGUF_V_UINT32,
                              model_motion_features(c));
    /* Derived dimensions, for readers of the file (not read back). */
    rc |= gguf_writer_add_int(w, "forge4d.head_dim", GGUF_V_UINT32, c->embed_dim / c->num_heads);
    rc |= gguf_writer_add_int(w, "forge4d.mlp_hidden", GGUF_V_UINT32,
                              model_mlp_hidden(c, c->embed_dim));
    rc |= gguf_writer_add_int(w, "forge4d.patch_start_idx", GGUF_V_UINT32,
                              1 + c->num_register_tokens);
    return rc ? F4D_EINVAL : F4D_OK;
}
