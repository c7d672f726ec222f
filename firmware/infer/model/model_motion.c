/* model_motion.c - Forge4D's motion head (forge4d-arch.md 5): a DPT head on
 * the C-wide motion streams (model_stream.c) after the blocks of
 * dpt_layer_idx, motion_dpt_features wide, 3 raw channels per pixel. Run twice per step with the same
 * weights: on the M1 streams (queries t, keys t-1) it gives M1[t], on the M2
 * streams M2[t-1]; both divided by this step's gauge (metric recovery,
 * forge4d-arch.md 3). Nothing runs on the first step of a sequence.
 * After a masked aggregator run both maps are exactly 0 at every pixel of a
 * dropped patch: background, static by the keep-list's definition. */
#include <stdlib.h>
#include <string.h>

#include "model_internal.h"

struct motion_head {
    struct model_config cfg;
    void               *dpt;
};

static void mh_free(void *hp)
{
    struct motion_head *h = hp;
    if (!h)
        return;
    model_dpt_head_free(h->dpt);
    free(h);
}

static int mh_init(struct model *m, void **out)
{
    if (!gguf_find_tensor(model_gguf(m), "motion_head.norm.weight"))
        return 1;
    if (!m->stream || !(m->groups & MODEL_G_MOTION))
        return model_fail(m, F4D_EFORMAT, "model: motion_head needs motion.* in the same "
                          "weight file");
    struct motion_head *h = calloc(1, sizeof *h);
    if (!h)
        return model_fail(m, F4D_ENOMEM, "model: out of memory for the motion head");
    h->cfg = *model_get_config(m);
    h->cfg.dpt_features = model_motion_features(&h->cfg); /* its own width (model.h) */
    int rc = model_dpt_raw_init_dim(m, &h->dpt, "motion_head", MODEL_MOTION_CH,
                                    h->cfg.embed_dim, h->cfg.dpt_features);
    if (rc != 0) {
        free(h);
        return rc < 0 ? rc : model_fail(m, F4D_EFORMAT, "model: motion_head incomplete");
    }
    *out = h;
    return 0;
}

/* raw [S, H, W, 3] = 0 at the pixels of patches with keep[f * P + patch] == 0. */
static void zero_dropped(float *raw, const uint8_t *keep, int S, int H, int W, int p)
{
    const int w = W / p, P = (H / p) * w;
    for (int f = 0; f < S; f++)
        for (int y = 0; y < H; y++)
            for (int x = 0; x < W; x++)
                if (!keep[(size_t)f * P + (y / p) * w + x / p])
                    memset(raw + (((size_t)f * H + y) * W + x) * MODEL_MOTION_CH, 0,
                           MODEL_MOTION_CH * sizeof *raw);
}

/* Reads no aggregator layer: its input is the motion stream. */
static uint64_t mh_layers(const void *hp)
{
    (void)hp;
    return 0;
}

/* Persist: per run, the raw DPT maps [S, H, W, 3] (its persist part), then
 * the two metric maps. */
void model_motion_head_plan(const struct model_config *c, int S, int H, int W,
                            size_t *persist, size_t *scratch)
{
    size_t dp;
    struct model_config mc = *c;
    mc.dpt_features = model_motion_features(c);
    model_dpt_raw_plan(&mc, MODEL_MOTION_CH, S, H, W, &dp, scratch);
    struct bump pb = { NULL, 2 * dp };
    BUMP_F(&pb, (size_t)S * H * W * MODEL_MOTION_CH);
    BUMP_F(&pb, (size_t)S * H * W * MODEL_MOTION_CH);
    *persist = pb.off;
}

static void mh_plan(const void *hp, int S, int H, int W, size_t *persist, size_t *scratch)
{
    const struct motion_head *h = hp;
    model_motion_head_plan(&h->cfg, S, H, W, persist, scratch);
}

static int mh_eval(void *hp, struct model_run *run, float *persist)
{
    struct motion_head *h = hp;
    struct model *m = run->m;
    struct model_outputs *o = run->out;
    o->has_motion = 0;
    o->motion_bwd = o->motion_fwd_prev = NULL;
    if (!model_stream_motion_now(m))
        return 0;
    const int S = run->S, H = run->H, W = run->W;
    const size_t hw = (size_t)H * W, cnt = (size_t)S * hw * MODEL_MOTION_CH;
    size_t dp, dscr;
    model_dpt_raw_plan(&h->cfg, MODEL_MOTION_CH, S, H, W, &dp, &dscr);
    struct bump pb = { (unsigned char *)persist, 2 * dp };
    float *metric[2] = { BUMP_F(&pb, cnt), BUMP_F(&pb, cnt) };
    const float gauge = o->has_gauge ? o->gauge : 1.0f;
    for (int r = 0; r < 2; r++) {
        const float *lay[MODEL_LAYERS_MAX] = { 0 };
        for (int i = 0; i < 4; i++)
            lay[h->cfg.dpt_layer_idx[i]] = model_stream_h(m, r, i);
        struct model_run rr = *run;
        rr.layers = lay;
        float *raw = (float *)((unsigned char *)persist + (size_t)r * dp);
        int rc = model_dpt_head_eval(h->dpt, &rr, raw);
        if (rc < 0)
            return rc;
        if (m->keep_now)
            zero_dropped(raw, m->keep_now, S, H, W, h->cfg.patch_size);
        if (m->tap)
            for (int f = 0; f < S; f++)
                m->tap(m->tap_user, r ? "motion_head.m2" : "motion_head.m1", f,
                       raw + (size_t)f * hw * MODEL_MOTION_CH, hw * MODEL_MOTION_CH);
        for (size_t i = 0; i < cnt; i++) /* metric recovery (forge4d-arch.md 3) */
            metric[r][i] = raw[i] / gauge;
    }
    o->motion_bwd = metric[0];
    o->motion_fwd_prev = metric[1];
    o->has_motion = 1;
    return 0;
}

const struct model_head_ops model_motion_head_ops = {
    .api_version = MODEL_HEAD_API_VERSION,
    .prefix = "motion_head",
    .init = mh_init,
    .layers = mh_layers,
    .plan = mh_plan,
    .eval = mh_eval,
    .free = mh_free,
};
