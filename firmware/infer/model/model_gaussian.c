/* model_gaussian.c - Forge4D's Gaussian head (forge4d-arch.md 1): a DPT head
 * like VGGT's with 14 raw channels per pixel, dp (3) | dc (3) | o (1) | s (3) |
 * q (4), activated into pixel-aligned Gaussians (struct model_gaussians, the
 * layout of the gaussians stage's struct splat_frame) with the
 * point head's X, the camera head's pose and the input colours:
 *
 *   mu    = X + dp                                  (/ gauge: metres)
 *   rgb   = clamp(img + dc, 0, 1)                   (linear colour)
 *   alpha = sigmoid(o + 4)
 *   sigma = exp(clamp(s, -8, 4)) * |z| / |f|        (/ gauge: metres)
 *           z = view depth of X, f = (fx + fy) / 2: one pixel's footprint
 *   q     = normalize((1, 0, 0, 0) + q_raw) (w, x, y, z); identity when
 *           |q| < 1e-12 (q_raw = (-1, 0, 0, 0))
 *
 * The head needs the point and camera heads (refused at Init otherwise) and
 * runs after the scale head, whose gauge it divides by (1 without one). */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "model_internal.h"

struct gauss_head {
    struct model_config cfg;
    void               *dpt;
};

static void gauss_free(void *hp)
{
    struct gauss_head *h = hp;
    if (!h)
        return;
    model_dpt_head_free(h->dpt);
    free(h);
}

static int gauss_init(struct model *m, void **out)
{
    if (!gguf_find_tensor(model_gguf(m), "gaussian_head.norm.weight"))
        return 1;
    if (!gguf_find_tensor(model_gguf(m), "point_head.norm.weight") ||
        !gguf_find_tensor(model_gguf(m), "camera_head.token_norm.weight"))
        return model_fail(m, F4D_EFORMAT, "model: gaussian_head needs point_head and "
                          "camera_head in the same weight file (X and the cameras)");
    struct gauss_head *h = calloc(1, sizeof *h);
    if (!h)
        return model_fail(m, F4D_ENOMEM, "model: out of memory for the gaussian head");
    h->cfg = *model_get_config(m);
    int rc = model_dpt_raw_init(m, &h->dpt, "gaussian_head", MODEL_GAUSS_CH);
    if (rc != 0) {
        free(h);
        return rc < 0 ? rc : model_fail(m, F4D_EFORMAT, "model: gaussian_head incomplete");
    }
    *out = h;
    return 0;
}

static uint64_t gauss_layers(const void *hp)
{
    const struct gauss_head *h = hp;
    return model_dpt_head_layers(h->dpt);
}

/* Persist: the raw DPT maps, then the frame's arrays (SoA, S*H*W each). */
void model_gaussian_plan(const struct model_config *c, int S, int H, int W, size_t *persist,
                         size_t *scratch)
{
    size_t dp;
    model_dpt_raw_plan(c, MODEL_GAUSS_CH, S, H, W, &dp, scratch);
    struct bump pb = { NULL, dp };
    const size_t n = (size_t)S * H * W;
    BUMP_F(&pb, 3 * n);   /* pos     */
    BUMP_F(&pb, 3 * n);   /* scale   */
    BUMP_F(&pb, 4 * n);   /* rot     */
    BUMP_F(&pb, n);       /* opacity */
    BUMP_F(&pb, 3 * n);   /* rgb     */
    *persist = pb.off;
}

static void gauss_plan(const void *hp, int S, int H, int W, size_t *persist, size_t *scratch)
{
    const struct gauss_head *h = hp;
    model_gaussian_plan(&h->cfg, S, H, W, persist, scratch);
}

static inline float clampf(float v, float lo, float hi)
{
    return v < lo ? lo : v > hi ? hi : v;
}

/* normalize((1,0,0,0) + q_raw), identity below MODEL_GAUSS_QUAT_EPS; scaled by
 * the largest component first, so tiny vectors neither underflow nor divide
 * by zero. */
static void quat_activate(const float *qr, float *q)
{
    float v[4] = { 1.0f + qr[0], qr[1], qr[2], qr[3] };
    float mx = 0.0f;
    for (int k = 0; k < 4; k++)
        mx = fabsf(v[k]) > mx ? fabsf(v[k]) : mx;
    if (mx > 0.0f && isfinite(mx)) {
        float ss = 0.0f;
        for (int k = 0; k < 4; k++)
            ss += (v[k] / mx) * (v[k] / mx);
        float n = sqrtf(ss) * mx;
        if (n >= MODEL_GAUSS_QUAT_EPS) {
            for (int k = 0; k < 4; k++)
                q[k] = v[k] / n;
            return;
        }
    }
    q[0] = 1.0f;
    q[1] = q[2] = q[3] = 0.0f;
}

static int gauss_eval(void *hp, struct model_run *run, float *persist)
{
    struct gauss_head *h = hp;
    struct model *m = run->m;
    const struct model_outputs *o = run->out;
    if (!o->world_points || !o->extrinsic || !o->intrinsic || !run->images)
        return model_fail(m, F4D_EINVAL, "model: gaussian_head ran without points, cameras "
                          "or input images");
    int rc = model_dpt_head_eval(h->dpt, run, persist);
    if (rc < 0)
        return rc;
    const int S = run->S, H = run->H, W = run->W;
    const size_t hw = (size_t)H * W, n = (size_t)S * hw;
    size_t dp, dscr;
    model_dpt_raw_plan(&h->cfg, MODEL_GAUSS_CH, S, H, W, &dp, &dscr);
    const float *raw = persist;
    struct bump pb = { (unsigned char *)persist, dp };
    struct model_gaussians *g = &run->out->gaussians;
    memset(g, 0, sizeof *g);
    g->pos = BUMP_F(&pb, 3 * n);
    g->scale = BUMP_F(&pb, 3 * n);
    g->rot = BUMP_F(&pb, 4 * n);
    g->opacity = BUMP_F(&pb, n);
    g->rgb = BUMP_F(&pb, 3 * n);
    const float gauge = o->has_gauge ? o->gauge : 1.0f;
    for (int s = 0; s < S; s++) {
        const float *E = o->extrinsic + (size_t)s * 12, *K = o->intrinsic + (size_t)s * 9;
        const float r0 = E[8], r1 = E[9], r2 = E[10], t2 = E[11];
        const float af = fabsf(0.5f * (K[0] + K[4]));
        const float *img = run->images + (size_t)s * 3 * hw;
        for (size_t i = 0; i < hw; i++) {
            const size_t gi = (size_t)s * hw + i;
            const float *r = raw + gi * MODEL_GAUSS_CH, *X = o->world_points + gi * 3;
            float *mu = g->pos + gi * 3, *sg = g->scale + gi * 3, *c = g->rgb + gi * 3;
            for (int k = 0; k < 3; k++)
                mu[k] = X[k] + r[k];
            for (int k = 0; k < 3; k++)
                c[k] = clampf(img[(size_t)k * hw + i] + r[3 + k], 0.0f, 1.0f);
            g->opacity[gi] = 1.0f / (1.0f + expf(-(r[6] + MODEL_GAUSS_OPACITY_BIAS)));
            const float z = r0 * X[0] + r1 * X[1] + r2 * X[2] + t2;
            const float foot = fabsf(z) / af;
            for (int k = 0; k < 3; k++)
                sg[k] = expf(clampf(r[7 + k], MODEL_GAUSS_LOG_MIN, MODEL_GAUSS_LOG_MAX)) * foot;
            quat_activate(r + 10, g->rot + gi * 4);
        }
        if (m->tap) {
            m->tap(m->tap_user, "gaussian_head.mu", s, g->pos + (size_t)s * hw * 3, hw * 3);
            m->tap(m->tap_user, "gaussian_head.sigma", s, g->scale + (size_t)s * hw * 3, hw * 3);
        }
        if (o->has_gauge) /* metric recovery (forge4d-arch.md 3) */
            for (size_t i = (size_t)s * hw * 3; i < (size_t)(s + 1) * hw * 3; i++) {
                g->pos[i] /= gauge;
                g->scale[i] /= gauge;
            }
    }
    g->count = n;
    run->out->gaussian_raw = raw;
    return 0;
}

const struct model_head_ops model_gaussian_head_ops = {
    .api_version = MODEL_HEAD_API_VERSION,
    .prefix = "gaussian_head",
    .init = gauss_init,
    .layers = gauss_layers,
    .plan = gauss_plan,
    .eval = gauss_eval,
    .free = gauss_free,
};
