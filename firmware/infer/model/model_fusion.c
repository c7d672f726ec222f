/* model_fusion.c - Forge4D's fusion MLP F_theta (forge4d-arch.md 6):
 *   out = avg(a_t, a_tm1) + fc2(GELU(fc1([a_t, a_tm1, a, D])))
 * with avg the mean of the first 10 attributes and, for the quaternion, the
 * sign-aligned sum normalised (the identity when it vanishes). Attributes in
 * interp's convention (firmware/gaussians/interp/interp.h), pre-activation.
 * Scalar f32 on f32 weights in every precision (30 -> 64 -> 14: 2.8 k MACs a
 * pair), no state: callable from any thread. */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "model_internal.h"

struct model_fusion {
    float w1[MODEL_FUSION_HIDDEN][MODEL_FUSION_IN], b1[MODEL_FUSION_HIDDEN];
    float w2[MODEL_FUSION_ATTRS][MODEL_FUSION_HIDDEN], b2[MODEL_FUSION_ATTRS];
};

int model_fusion_load(struct model *m)
{
    if (!(m->groups & MODEL_G_FUSION))
        return 0;
    const float *w1, *b1, *w2, *b2;
    int rc;
    if ((rc = model_load_f32(m, "fusion.fc1.weight", (size_t)MODEL_FUSION_HIDDEN * MODEL_FUSION_IN, &w1)) < 0 ||
        (rc = model_load_f32(m, "fusion.fc1.bias", MODEL_FUSION_HIDDEN, &b1)) < 0 ||
        (rc = model_load_f32(m, "fusion.fc2.weight", (size_t)MODEL_FUSION_ATTRS * MODEL_FUSION_HIDDEN, &w2)) < 0 ||
        (rc = model_load_f32(m, "fusion.fc2.bias", MODEL_FUSION_ATTRS, &b2)) < 0)
        return rc;
    struct model_fusion *f = malloc(sizeof *f);
    if (!f)
        return model_fail(m, F4D_ENOMEM, "model: out of memory for the fusion MLP");
    memcpy(f->w1, w1, sizeof f->w1);
    memcpy(f->b1, b1, sizeof f->b1);
    memcpy(f->w2, w2, sizeof f->w2);
    memcpy(f->b2, b2, sizeof f->b2);
    m->fusion = f;
    return 0;
}

void model_fusion_free(struct model *m)
{
    free(m->fusion);
    m->fusion = NULL;
}

void *model_fusion(struct model *m) { return m->fusion; }

void model_fusion_fuse(void *fusion, const float a_t[MODEL_FUSION_ATTRS],
                       const float a_tm1[MODEL_FUSION_ATTRS], float a, float D,
                       float out[MODEL_FUSION_ATTRS])
{
    const struct model_fusion *f = fusion;
    float x[MODEL_FUSION_IN], hid[MODEL_FUSION_HIDDEN];
    memcpy(x, a_t, MODEL_FUSION_ATTRS * sizeof(float));
    memcpy(x + MODEL_FUSION_ATTRS, a_tm1, MODEL_FUSION_ATTRS * sizeof(float));
    x[2 * MODEL_FUSION_ATTRS] = a;
    x[2 * MODEL_FUSION_ATTRS + 1] = D;
    for (int j = 0; j < MODEL_FUSION_HIDDEN; j++) {
        float s = f->b1[j];
        for (int k = 0; k < MODEL_FUSION_IN; k++)
            s += f->w1[j][k] * x[k];
        hid[j] = 0.5f * s * (1.0f + erff(s * 0.70710678118654752f)); /* exact GELU */
    }
    for (int c = 0; c < 10; c++)
        out[c] = 0.5f * (a_t[c] + a_tm1[c]);
    float dot = 0.0f, q[4], ss = 0.0f;
    for (int c = 0; c < 4; c++)
        dot += a_t[10 + c] * a_tm1[10 + c];
    const float sg = dot < 0.0f ? -1.0f : 1.0f; /* q and -q are the same rotation */
    for (int c = 0; c < 4; c++) {
        q[c] = a_t[10 + c] + sg * a_tm1[10 + c];
        ss += q[c] * q[c];
    }
    const float n = sqrtf(ss);
    for (int c = 0; c < 4; c++)
        out[10 + c] = n >= MODEL_GAUSS_QUAT_EPS ? q[c] / n : (c == 0 ? 1.0f : 0.0f);
    for (int c = 0; c < MODEL_FUSION_ATTRS; c++) {
        float s = f->b2[c];
        for (int j = 0; j < MODEL_FUSION_HIDDEN; j++)
            s += f->w2[c][j] * hid[j];
        out[c] += s;
    }
}
