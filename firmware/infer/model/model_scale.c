/* model_scale.c - Forge4D's scale head and metric recovery (forge4d-arch.md 2-3).
 *
 *   c = mean over views of F_last[:, 0, :]   (camera tokens, D wide)
 *   p_gauge_hat = exp(fc2(GELU(fc1(LN(c)))))  one scalar per time step
 *
 * Metric recovery of the cameras: extrinsic_metric = [R | T / p_gauge_hat]
 * (rotations and intrinsics unchanged). The Gaussian head (model_gaussian.c)
 * divides positions and scales by the same gauge. */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "model_internal.h"

struct scale_head {
    int              C, D, depth;
    const float     *nw, *nb;
    struct fk_linear fc1, fc2;
    int              packed;   /* linears packed so far (for free) */
};

static void scale_free(void *hp)
{
    struct scale_head *h = hp;
    if (!h)
        return;
    if (h->packed > 0)
        fk_linear_free(&h->fc1);
    if (h->packed > 1)
        fk_linear_free(&h->fc2);
    free(h);
}

static int scale_init(struct model *m, void **out)
{
    if (!gguf_find_tensor(model_gguf(m), "scale_head.norm.weight"))
        return 1;
    const struct model_config *c = model_get_config(m);
    struct scale_head *h = calloc(1, sizeof *h);
    if (!h)
        return model_fail(m, F4D_ENOMEM, "model: out of memory for the scale head");
    h->C = c->embed_dim;
    h->D = 2 * c->embed_dim;
    h->depth = c->depth;
    int rc;
    if ((rc = model_load_vec(m, "scale_head.norm.weight", h->D, &h->nw)) < 0 ||
        (rc = model_load_vec(m, "scale_head.norm.bias", h->D, &h->nb)) < 0 ||
        (rc = model_load_linear(m, &h->fc1, "scale_head.fc1.weight", "scale_head.fc1.bias",
                                h->C, h->D)) < 0)
        goto fail;
    h->packed = 1;
    if ((rc = model_load_linear(m, &h->fc2, "scale_head.fc2.weight", "scale_head.fc2.bias", 1,
                                h->C)) < 0)
        goto fail;
    h->packed = 2;
    *out = h;
    return 0;
fail:
    scale_free(h);
    return rc;
}

static uint64_t scale_layers(const void *hp)
{
    const struct scale_head *h = hp;
    return UINT64_C(1) << (h->depth - 1);
}

struct scale_bufs {
    float *c, *ln, *hid, *x;
};

static void scale_layout(struct bump *b, int C, int D, struct scale_bufs *a)
{
    a->c = BUMP_F(b, D);
    a->ln = BUMP_F(b, D);
    a->hid = BUMP_F(b, C);
    a->x = BUMP_F(b, 1);
}

void model_scale_plan(const struct model_config *c, int S, size_t *persist, size_t *scratch)
{
    struct bump pb = { NULL, 0 }, sb = { NULL, 0 };
    BUMP_F(&pb, 1);                   /* gauge            */
    BUMP_F(&pb, (size_t)S * 12);      /* extrinsic_metric */
    *persist = pb.off;
    struct scale_bufs a;
    scale_layout(&sb, c->embed_dim, 2 * c->embed_dim, &a);
    *scratch = sb.off;
}

static void scale_plan(const void *hp, int S, int H, int W, size_t *persist, size_t *scratch)
{
    const struct scale_head *h = hp;
    (void)H;
    (void)W;
    struct model_config c;
    memset(&c, 0, sizeof c);
    c.embed_dim = h->C;
    model_scale_plan(&c, S, persist, scratch);
}

static int scale_eval(void *hp, struct model_run *run, float *persist)
{
    struct scale_head *h = hp;
    struct model *m = run->m;
    const int S = run->S, D = h->D, P1 = run->tokens;
    struct bump pb = { (unsigned char *)persist, 0 }, sb = { (unsigned char *)run->scratch, 0 };
    float *gauge = BUMP_F(&pb, 1);
    float *ext_m = BUMP_F(&pb, (size_t)S * 12);
    struct scale_bufs a;
    scale_layout(&sb, h->C, D, &a);
    const float *last = run->layers[h->depth - 1];
    /* camera token (index 0) of every view, both halves; mean over views */
    for (int k = 0; k < D; k++)
        a.c[k] = 0.0f;
    for (int s = 0; s < S; s++) {
        const float *t = last + (size_t)s * P1 * D;
        for (int k = 0; k < D; k++)
            a.c[k] += t[k];
    }
    for (int k = 0; k < D; k++)
        a.c[k] /= (float)S;
    if (fk_layernorm(model_ctx(m), a.c, 1, D, D, h->nw, h->nb, 1e-5f, a.ln, D) != F4D_OK)
        return model_kfail(m, "scale head norm");
    struct fk_epilogue gelu = { .act = FK_ACT_GELU };
    int rc;
    if ((rc = model_linear(m, &h->fc1, a.ln, 1, D, a.hid, h->C, &gelu)) < 0 ||
        (rc = model_linear(m, &h->fc2, a.hid, 1, h->C, a.x, 1, NULL)) < 0)
        return rc;
    *gauge = expf(a.x[0]);
    if (m->tap)
        m->tap(m->tap_user, "scale_head.gauge", -1, gauge, 1);
    run->out->has_gauge = 1;
    run->out->gauge = *gauge;
    if (run->out->extrinsic) {
        /* T / g, not T * (1 / g): exact for tiny translations as for large */
        for (int i = 0; i < S * 12; i++)
            ext_m[i] = i % 4 == 3 ? run->out->extrinsic[i] / *gauge : run->out->extrinsic[i];
        run->out->extrinsic_metric = ext_m;
    }
    return 0;
}

int model_gauge_from_translations(const float *t_true, const float *t_pred, int S, float eps,
                                  float *gauge)
{
    if (!t_true || !t_pred || !gauge || S < 1 || !(eps > 0.0f))
        return F4D_EINVAL;
    double sum = 0;
    int n = 0;
    for (int i = 0; i < S; i++) {
        const float *a = t_true + 3 * i, *b = t_pred + 3 * i;
        double na = sqrt((double)a[0] * a[0] + (double)a[1] * a[1] + (double)a[2] * a[2]);
        double nb = sqrt((double)b[0] * b[0] + (double)b[1] * b[1] + (double)b[2] * b[2]);
        if (!(na >= eps) || !(nb >= eps) || !isfinite(na) || !isfinite(nb))
            continue;
        sum += na / nb;
        n++;
    }
    if (n == 0)
        return F4D_EINVAL;
    *gauge = (float)(sum / n);
    return F4D_OK;
}

const struct model_head_ops model_scale_head_ops = {
    .api_version = MODEL_HEAD_API_VERSION,
    .prefix = "scale_head",
    .init = scale_init,
    .layers = scale_layers,
    .plan = scale_plan,
    .eval = scale_eval,
    .free = scale_free,
};
