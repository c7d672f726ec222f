/* model_dpt.c - the DPT depth and point heads (vggt.md 6), one frame at a time
 * on channels-last maps. */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "model_internal.h"

enum dpt_act { DPT_EXP = 0, DPT_INV_LOG = 1, DPT_RAW = 2 };

struct rcu {
    struct fk_conv2d conv1, conv2;
};

struct dpt_head {
    struct model_config cfg;
    const char         *prefix;
    int                 out_dim, act, n_packed, in_dim;  /* in_dim: 2C, C for motion */
    const float        *norm_w, *norm_b;
    struct fk_conv2d    proj[4], rs3, rn[4], out_conv[4], oc1, oc2a, oc2b;
    struct fk_conv_transpose2d rs0, rs1;
    struct rcu          rcu1[4], rcu2[4];   /* rcu1[3] unused: refinenet4 has none */
    /* packed-conv list for freeing */
    struct fk_conv2d   *convs[40];
    int                 n_convs, rs_packed;
};

static void dpt_free(void *hp)
{
    struct dpt_head *h = hp;
    if (!h)
        return;
    for (int i = 0; i < h->n_convs; i++)
        fk_conv2d_free(h->convs[i]);
    if (h->rs_packed > 0)
        fk_conv_transpose2d_free(&h->rs0);
    if (h->rs_packed > 1)
        fk_conv_transpose2d_free(&h->rs1);
    free(h);
}

static int conv(struct model *m, struct dpt_head *h, struct fk_conv2d *c, const char *name,
                int cout, int cin, int k, int stride, int bias)
{
    char p[2 * MODEL_NAME_MAX];
    snprintf(p, sizeof p, "%s.%s", h->prefix, name);
    int rc = model_load_conv(m, c, p, cout, cin, k, stride, k / 2, bias, model_wtype(m));
    if (rc == 0)
        h->convs[h->n_convs++] = c;
    return rc;
}

static int dpt_init_common(struct model *m, void **out, const char *prefix, int out_dim, int act,
                           int in_dim, int features)
{
    char nm[MODEL_NAME_MAX];
    snprintf(nm, sizeof nm, "%s.norm.weight", prefix);
    if (!gguf_find_tensor(model_gguf(m), nm))
        return 1;
    struct dpt_head *h = calloc(1, sizeof *h);
    if (!h)
        return F4D_ENOMEM;
    h->cfg = *model_get_config(m);
    h->cfg.dpt_features = features;
    const struct model_config *c = &h->cfg;
    h->prefix = prefix;
    h->out_dim = out_dim;
    h->act = act;
    h->in_dim = in_dim;
    const int D = in_dim, F = c->dpt_features;
    const int *oc = c->dpt_out_channels;
    int rc;
    char b[MODEL_NAME_MAX];
    snprintf(nm, sizeof nm, "%s.norm.weight", prefix);
    if ((rc = model_load_vec(m, nm, D, &h->norm_w)) < 0)
        goto fail;
    snprintf(nm, sizeof nm, "%s.norm.bias", prefix);
    if ((rc = model_load_vec(m, nm, D, &h->norm_b)) < 0)
        goto fail;
    for (int i = 0; i < 4; i++) {
        snprintf(b, sizeof b, "projects.%d", i);
        if ((rc = conv(m, h, &h->proj[i], b, oc[i], D, 1, 1, 1)) < 0)
            goto fail;
    }
    snprintf(nm, sizeof nm, "%s.resize_layers.0", prefix);
    if ((rc = model_load_convt(m, &h->rs0, nm, oc[0], oc[0], 4)) < 0)
        goto fail;
    h->rs_packed = 1;
    snprintf(nm, sizeof nm, "%s.resize_layers.1", prefix);
    if ((rc = model_load_convt(m, &h->rs1, nm, oc[1], oc[1], 2)) < 0)
        goto fail;
    h->rs_packed = 2;
    if ((rc = conv(m, h, &h->rs3, "resize_layers.3", oc[3], oc[3], 3, 2, 1)) < 0)
        goto fail;
    for (int i = 0; i < 4; i++) {
        snprintf(b, sizeof b, "scratch.layer%d_rn", i + 1);
        if ((rc = conv(m, h, &h->rn[i], b, F, oc[i], 3, 1, 0)) < 0)
            goto fail;
    }
    for (int r = 0; r < 4; r++) {
        for (int u = (r == 3 ? 2 : 1); u <= 2; u++) {
            struct rcu *ru = u == 1 ? &h->rcu1[r] : &h->rcu2[r];
            snprintf(b, sizeof b, "scratch.refinenet%d.resConfUnit%d.conv1", r + 1, u);
            if ((rc = conv(m, h, &ru->conv1, b, F, F, 3, 1, 1)) < 0)
                goto fail;
            snprintf(b, sizeof b, "scratch.refinenet%d.resConfUnit%d.conv2", r + 1, u);
            if ((rc = conv(m, h, &ru->conv2, b, F, F, 3, 1, 1)) < 0)
                goto fail;
        }
        snprintf(b, sizeof b, "scratch.refinenet%d.out_conv", r + 1);
        if ((rc = conv(m, h, &h->out_conv[r], b, F, F, 1, 1, 1)) < 0)
            goto fail;
    }
    if ((rc = conv(m, h, &h->oc1, "scratch.output_conv1", F / 2, F, 3, 1, 1)) < 0 ||
        (rc = conv(m, h, &h->oc2a, "scratch.output_conv2.0", MODEL_DPT_HIDDEN2, F / 2, 3, 1, 1)) < 0 ||
        (rc = conv(m, h, &h->oc2b, "scratch.output_conv2.2", out_dim, MODEL_DPT_HIDDEN2, 1, 1, 1)) < 0)
        goto fail;
    *out = h;
    return 0;
fail:
    dpt_free(h);
    return rc;
}

static int depth_init(struct model *m, void **out)
{
    return dpt_init_common(m, out, "depth_head", 2, DPT_EXP, 2 * model_get_config(m)->embed_dim,
                           model_get_config(m)->dpt_features);
}

static int point_init(struct model *m, void **out)
{
    return dpt_init_common(m, out, "point_head", 4, DPT_INV_LOG, 2 * model_get_config(m)->embed_dim,
                           model_get_config(m)->dpt_features);
}

static uint64_t dpt_layers(const void *hp)
{
    const struct dpt_head *h = hp;
    uint64_t mask = 0;
    for (int i = 0; i < 4; i++)
        mask |= UINT64_C(1) << h->cfg.dpt_layer_idx[i];
    return mask;
}

/* Level sizes (vggt.md 6 step 1): 4h x 4w, 2h x 2w, h x w, ceil(h/2) x ceil(w/2). */
static void level_size(int l, int h, int w, int *lh, int *lw)
{
    static const int mul[3] = { 4, 2, 1 };
    if (l < 3) {
        *lh = h * mul[l];
        *lw = w * mul[l];
    } else {
        *lh = (h + 1) / 2;
        *lw = (w + 1) / 2;
    }
}

struct dpt_bufs {
    float *tok, *proj, *lvl, *rn[4], *tm, *y, *up, *o, *big1, *big2, *logit, *pe;
};

static void dpt_layout(struct bump *b, const struct model_config *c, int out_dim, int H, int W,
                       struct dpt_bufs *a)
{
    const int p = c->patch_size, h = H / p, w = W / p, P = h * w, D = 2 * c->embed_dim;
    const int F = c->dpt_features, *oc = c->dpt_out_channels;
    size_t lvl = 0, maxc = (size_t)F / 2;
    int lh, lw;
    for (int l = 0; l < 4; l++) {
        level_size(l, h, w, &lh, &lw);
        lvl = lvl > (size_t)lh * lw * oc[l] ? lvl : (size_t)lh * lw * oc[l];
        maxc = maxc > (size_t)oc[l] ? maxc : (size_t)oc[l];
    }
    int oc_max = oc[0];
    for (int l = 1; l < 4; l++)
        oc_max = oc_max > oc[l] ? oc_max : oc[l];
    a->tok = BUMP_F(b, (size_t)P * D);
    a->proj = BUMP_F(b, (size_t)P * oc_max);
    a->lvl = BUMP_F(b, lvl);
    for (int l = 0; l < 4; l++) {
        level_size(l, h, w, &lh, &lw);
        a->rn[l] = BUMP_F(b, (size_t)lh * lw * F);
    }
    const size_t s0 = (size_t)16 * P * F, s8 = (size_t)64 * P * F;
    a->tm = BUMP_F(b, s0);
    a->y = BUMP_F(b, s0);
    a->up = BUMP_F(b, s8);
    a->o = BUMP_F(b, s8);
    a->big1 = BUMP_F(b, (size_t)H * W * (F / 2));
    a->big2 = BUMP_F(b, (size_t)H * W * MODEL_DPT_HIDDEN2);
    a->logit = BUMP_F(b, (size_t)H * W * out_dim);
    a->pe = BUMP_F(b, (size_t)(H + W) * maxc);
}

void model_dpt_plan(const struct model_config *c, int out_dim, int S, int H, int W,
                    size_t *persist, size_t *scratch)
{
    struct bump pb = { NULL, 0 }, sb = { NULL, 0 };
    BUMP_F(&pb, (size_t)S * H * W * (out_dim - 1));
    BUMP_F(&pb, (size_t)S * H * W);
    *persist = pb.off;
    struct dpt_bufs a;
    dpt_layout(&sb, c, out_dim, H, W, &a);
    *scratch = sb.off;
}

static void dpt_plan(const void *hp, int S, int H, int W, size_t *persist, size_t *scratch)
{
    const struct dpt_head *h = hp;
    model_dpt_plan(&h->cfg, h->out_dim, S, H, W, persist, scratch);
}

/* x[nh, nw, cx] += 0.1 * PE(cx, nh, nw) for an input image of W x H (vggt.md 6):
 * channels [sin(u w_k), cos(u w_k), sin(v w_k), cos(v w_k)], w_k = 100^(-k/K).
 * The tables (nw + nh rows of cx/2) are computed in double, then rounded. */
struct uv_job {
    float       *x;
    const float *tu, *tv;
    int          nh, nw, cx, K, rows_per_task;
};

/* Rows [task * rows_per_task, ..) of the image: px += 0.1 pu, 0.1 pv. */
static void uv_task(void *arg, int task, int thread)
{
    const struct uv_job *j = arg;
    const int K = j->K, i1 = (task + 1) * j->rows_per_task < j->nh ? (task + 1) * j->rows_per_task : j->nh;
    (void)thread;
    for (int i = task * j->rows_per_task; i < i1; i++)
        for (int jj = 0; jj < j->nw; jj++) {
            float *px = j->x + ((size_t)i * j->nw + jj) * j->cx;
            const float *pu = j->tu + (size_t)jj * 2 * K, *pv = j->tv + (size_t)i * 2 * K;
            for (int k = 0; k < 2 * K; k++)
                px[k] += 0.1f * pu[k];
            for (int k = 0; k < 2 * K; k++)
                px[2 * K + k] += 0.1f * pv[k];
        }
}

static void add_uv_pe(fk_ctx *ctx, float *x, int nh, int nw, int cx, int H, int W, float *tab)
{
    const int K = cx / 4;
    const double a = (double)W / H, sx = a / sqrt(a * a + 1), sy = 1 / sqrt(a * a + 1);
    float *tu = tab, *tv = tab + (size_t)nw * 2 * K;
    for (int k = 0; k < K; k++) { /* channel outer: w_k once, not per pixel */
        const double w = 1.0 / pow(100.0, (double)k / K);
        for (int j = 0; j < nw; j++) {
            double lo = -sx * (nw - 1) / nw, u = nw > 1 ? lo + (-2 * lo) * j / (nw - 1) : lo;
            tu[(size_t)j * 2 * K + k] = (float)sin(u * w);
            tu[(size_t)j * 2 * K + K + k] = (float)cos(u * w);
        }
        for (int i = 0; i < nh; i++) {
            double lo = -sy * (nh - 1) / nh, v = nh > 1 ? lo + (-2 * lo) * i / (nh - 1) : lo;
            tv[(size_t)i * 2 * K + k] = (float)sin(v * w);
            tv[(size_t)i * 2 * K + K + k] = (float)cos(v * w);
        }
    }
    /* the adds on every core: on one, the full-resolution map (518 x 518 x
     * 128) kept the other core idle for ~2.5 % of the DPT head (Zen 5) */
    struct uv_job jb = { x, tu, tv, nh, nw, cx, K, 8 };
    fk_parallel_for(ctx, (nh + jb.rows_per_task - 1) / jb.rows_per_task, (double)nh * nw * cx, uv_task, &jb);
}

/* RCU (vggt.md 6): x <- relu(x) in place, y = relu(x) + conv2(relu(conv1(relu(x)))). */
static int rcu(struct model *m, const struct rcu *r, float *x, int nh, int nw, int F, float *tm,
               float *y)
{
    int rc;
    fk_ctx *ctx = model_ctx(m);
    if (fk_relu(ctx, x, (size_t)nh * nw * F, x) != F4D_OK)
        return model_kfail(m, "relu");
    if ((rc = model_conv(m, &r->conv1, x, nh, nw, tm, FK_ACT_RELU)) < 0 ||
        (rc = model_conv(m, &r->conv2, tm, nh, nw, y, FK_ACT_NONE)) < 0)
        return rc;
    if (fk_residual_add(ctx, y, F, x, F, NULL, nh * nw, F) != F4D_OK)
        return model_kfail(m, "rcu residual");
    return 0;
}

static int dpt_frame(struct model *m, struct dpt_head *h, const struct model_run *run, int f,
                     const struct dpt_bufs *a, float *val, float *conf)
{
    const struct model_config *c = &h->cfg;
    fk_ctx *ctx = model_ctx(m);
    const int H = run->H, W = run->W, hh = run->h, ww = run->w, P = run->P, P1 = run->tokens;
    const int D = h->in_dim, F = c->dpt_features, ns = 1 + c->num_register_tokens;
    int lh[4], lw[4], rc;
    char nm[MODEL_NAME_MAX];
    for (int l = 0; l < 4; l++) {
        const float *lay = run->layers[c->dpt_layer_idx[l]] + ((size_t)f * P1 + ns) * D;
        const int ocl = c->dpt_out_channels[l];
        if (fk_layernorm(ctx, lay, P, D, D, h->norm_w, h->norm_b, 1e-5f, a->tok, D) != F4D_OK)
            return model_kfail(m, "dpt norm");
        if ((rc = model_conv(m, &h->proj[l], a->tok, hh, ww, a->proj, FK_ACT_NONE)) < 0)
            return rc;
        add_uv_pe(ctx, a->proj, hh, ww, ocl, H, W, a->pe);
        level_size(l, hh, ww, &lh[l], &lw[l]);
        const float *lv = a->lvl;
        if (l == 0)
            rc = model_convt(m, &h->rs0, a->proj, hh, ww, a->lvl);
        else if (l == 1)
            rc = model_convt(m, &h->rs1, a->proj, hh, ww, a->lvl);
        else if (l == 3)
            rc = model_conv(m, &h->rs3, a->proj, hh, ww, a->lvl, FK_ACT_NONE);
        else
            lv = a->proj;
        if (rc < 0)
            return rc;
        if (m->tap) {
            snprintf(nm, sizeof nm, "%s.level%d", h->prefix, l);
            m->tap(m->tap_user, nm, f, lv, (size_t)lh[l] * lw[l] * ocl);
        }
        if ((rc = model_conv(m, &h->rn[l], lv, lh[l], lw[l], a->rn[l], FK_ACT_NONE)) < 0)
            return rc;
    }
    /* Fusion: refinenet4 .. refinenet1; `cur` is the running map at level l. */
    float *cur = a->rn[3];
    for (int l = 3; l >= 0; l--) {
        if (l < 3) {
            if ((rc = rcu(m, &h->rcu1[l], a->rn[l], lh[l], lw[l], F, a->tm, a->y)) < 0)
                return rc;
            if (fk_residual_add(ctx, cur, F, a->y, F, NULL, lh[l] * lw[l], F) != F4D_OK)
                return model_kfail(m, "fusion add");
        }
        if ((rc = rcu(m, &h->rcu2[l], cur, lh[l], lw[l], F, a->tm, a->y)) < 0)
            return rc;
        int th = l > 0 ? lh[l - 1] : 2 * lh[0], tw = l > 0 ? lw[l - 1] : 2 * lw[0];
        if (fk_resize_bilinear(ctx, a->y, lh[l], lw[l], F, a->up, th, tw, 1) != F4D_OK)
            return model_kfail(m, "fusion upsample");
        if ((rc = model_conv(m, &h->out_conv[l], a->up, th, tw, a->o, FK_ACT_NONE)) < 0)
            return rc;
        cur = a->o;
    }
    const int fh = 2 * lh[0], fw = 2 * lw[0];
    if (m->tap) {
        snprintf(nm, sizeof nm, "%s.fused", h->prefix);
        m->tap(m->tap_user, nm, f, a->o, (size_t)fh * fw * F);
    }
    if ((rc = model_conv(m, &h->oc1, a->o, fh, fw, a->up, FK_ACT_NONE)) < 0)
        return rc;
    if (fk_resize_bilinear(ctx, a->up, fh, fw, F / 2, a->big1, H, W, 1) != F4D_OK)
        return model_kfail(m, "dpt output upsample");
    add_uv_pe(ctx, a->big1, H, W, F / 2, H, W, a->pe);
    if ((rc = model_conv(m, &h->oc2a, a->big1, H, W, a->big2, FK_ACT_RELU)) < 0 ||
        (rc = model_conv(m, &h->oc2b, a->big2, H, W, a->logit, FK_ACT_NONE)) < 0)
        return rc;
    const int od = h->out_dim, vd = od - 1;
    if (h->act == DPT_RAW) {
        memcpy(val, a->logit, (size_t)H * W * od * sizeof(float));
        return 0;
    }
    for (size_t i = 0; i < (size_t)H * W; i++) {
        const float *lg = a->logit + i * od;
        for (int k = 0; k < vd; k++) {
            float v = lg[k];
            val[i * vd + k] = h->act == DPT_EXP ? expf(v)
                                                : (v < 0 ? -expm1f(-v) : expm1f(v));
        }
        conf[i] = 1.0f + expf(lg[vd]);
    }
    return 0;
}

static int dpt_eval(void *hp, struct model_run *run, float *persist)
{
    struct dpt_head *h = hp;
    const int S = run->S, H = run->H, W = run->W, vd = h->out_dim - 1;
    struct bump pb = { (unsigned char *)persist, 0 }, sb = { (unsigned char *)run->scratch, 0 };
    struct dpt_bufs a;
    dpt_layout(&sb, &h->cfg, h->out_dim, H, W, &a);
    if (h->act == DPT_RAW) { /* [S, H, W, out_dim], no confidence */
        float *raw = BUMP_F(&pb, (size_t)S * H * W * h->out_dim);
        for (int f = 0; f < S; f++) {
            int rc = dpt_frame(run->m, h, run, f, &a, raw + (size_t)f * H * W * h->out_dim, NULL);
            if (rc < 0)
                return rc;
        }
        return 0;
    }
    float *val = BUMP_F(&pb, (size_t)S * H * W * vd);
    float *conf = BUMP_F(&pb, (size_t)S * H * W);
    for (int f = 0; f < S; f++) {
        int rc = dpt_frame(run->m, h, run, f, &a, val + (size_t)f * H * W * vd,
                           conf + (size_t)f * H * W);
        if (rc < 0)
            return rc;
    }
    if (h->act == DPT_EXP) {
        run->out->depth = val;
        run->out->depth_conf = conf;
    } else {
        run->out->world_points = val;
        run->out->world_points_conf = conf;
    }
    return 0;
}

const struct model_head_ops model_depth_head_ops = {
    .api_version = MODEL_HEAD_API_VERSION, .prefix = "depth_head", .init = depth_init,
    .layers = dpt_layers, .plan = dpt_plan, .eval = dpt_eval, .free = dpt_free,
};

const struct model_head_ops model_point_head_ops = {
    .api_version = MODEL_HEAD_API_VERSION, .prefix = "point_head", .init = point_init,
    .layers = dpt_layers, .plan = dpt_plan, .eval = dpt_eval, .free = dpt_free,
};

/* ---- the raw DPT trunk of Forge4D's Gaussian head ------------------------ */

int model_dpt_raw_init(struct model *m, void **head, const char *prefix, int out_dim)
{
    return dpt_init_common(m, head, prefix, out_dim, DPT_RAW, 2 * model_get_config(m)->embed_dim,
                           model_get_config(m)->dpt_features);
}

int model_dpt_raw_init_dim(struct model *m, void **head, const char *prefix, int out_dim,
                           int in_dim, int features)
{
    return dpt_init_common(m, head, prefix, out_dim, DPT_RAW, in_dim, features);
}

void model_dpt_raw_plan(const struct model_config *c, int out_dim, int S, int H, int W,
                        size_t *persist, size_t *scratch)
{
    struct bump pb = { NULL, 0 }, sb = { NULL, 0 };
    BUMP_F(&pb, (size_t)S * H * W * out_dim);
    *persist = pb.off;
    struct dpt_bufs a;
    dpt_layout(&sb, c, out_dim, H, W, &a);
    *scratch = sb.off;
}

uint64_t model_dpt_head_layers(const void *head) { return dpt_layers(head); }
int model_dpt_head_eval(void *head, struct model_run *run, float *persist)
{
    return dpt_eval(head, run, persist);
}
void model_dpt_head_free(void *head) { dpt_free(head); }
