/* attention_ref.c - fk_attention: argument checks, the scalar reference
 * (the specification: two-pass softmax in double) and ISA dispatch. */
#include <float.h>
#include <math.h>
#include <string.h>

#include "../fk_attention.h"
#include "attention.h"
#include "fk_internal.h"

void fk_rope2d_ref(float *t, int d, int32_t pos_y, int32_t pos_x, float base)
{
    int m = d / 2, h = m / 2;
    for (int axis = 0; axis < 2; axis++) {
        float *u = t + axis * m;
        float pos = (float)(axis == 0 ? pos_y : pos_x);
        for (int k = 0; k < h; k++) {
            float inv_freq = (float)(1.0 / pow((double)base, (double)(2 * k) / (double)m));
            float theta = pos * inv_freq;
            float c = cosf(theta), s = sinf(theta);
            float a = u[k], b = u[k + h];
            u[k] = a * c - b * s;
            u[k + h] = b * c + a * s;
        }
    }
}

void fk__head_layernorm_ref(float *t, int d, const float *w, const float *b, float eps)
{
    float mean = 0, var = 0;
    for (int i = 0; i < d; i++)
        mean += t[i];
    mean /= (float)d;
    for (int i = 0; i < d; i++)
        var += (t[i] - mean) * (t[i] - mean);
    var /= (float)d;
    float inv = 1.0f / sqrtf(var + eps);
    for (int i = 0; i < d; i++)
        t[i] = (t[i] - mean) * inv * (w ? w[i] : 1.0f) + (b ? b[i] : 0.0f);
}

void fk__attn_prep_ref(const struct fk_attention_desc *a, int which, const float *src,
                       const int32_t *pos, float scale, float *dst)
{
    int d = a->head_dim;
    memcpy(dst, src, (size_t)d * sizeof *dst);
    int norm = a->qk_norm || (which == 0 ? (a->q_norm_w || a->q_norm_b) : (a->k_norm_w || a->k_norm_b));
    if (norm)
        fk__head_layernorm_ref(dst, d, which == 0 ? a->q_norm_w : a->k_norm_w,
                               which == 0 ? a->q_norm_b : a->k_norm_b, a->norm_eps);
    if (pos)
        fk_rope2d_ref(dst, d, pos[0], pos[1], a->rope_base > 0 ? a->rope_base : 100.0f);
    if (scale != 1.0f)
        for (int i = 0; i < d; i++)
            dst[i] *= scale;
}

int fk__attention_ref(fk_ctx *ctx, const struct fk_attention_desc *a, const float *q, int ldq,
                         int nq, const float *k, int ldk, const float *v, int ldv, int nk,
                         float *out, int ldo)
{
    int d = a->head_dim;
    float scale = a->scale > 0 ? a->scale : 1.0f / sqrtf((float)d);
    size_t need = ((size_t)nk * (size_t)d + (size_t)d) * sizeof(float) + (size_t)nk * sizeof(double) +
                  (size_t)d * sizeof(double) + 4 * FK_ALIGN;
    int st = fk__scratch_reserve(ctx, need, 0);
    if (st || fk__measuring(ctx))
        return st;
    char *s = fk__scratch(ctx, 0);
    float *kt = (float *)s;
    float *qt = kt + (size_t)nk * (size_t)d;
    double *p = (double *)fk__round_up((uintptr_t)(qt + d), FK_ALIGN);
    double *acc = p + nk;
    for (int h = 0; h < a->heads; h++) {
        for (int j = 0; j < nk; j++)
            fk__attn_prep_ref(a, 1, k + (size_t)j * (size_t)ldk + (size_t)h * (size_t)d,
                              a->pos_k ? a->pos_k + 2 * j : NULL, 1.0f, kt + (size_t)j * (size_t)d);
        for (int i = 0; i < nq; i++) {
            fk__attn_prep_ref(a, 0, q + (size_t)i * (size_t)ldq + (size_t)h * (size_t)d,
                              a->pos_q ? a->pos_q + 2 * i : NULL, scale, qt);
            double mx = -INFINITY;
            for (int j = 0; j < nk; j++) {
                double s_ij = 0;
                for (int c = 0; c < d; c++)
                    s_ij += (double)qt[c] * kt[(size_t)j * (size_t)d + (size_t)c];
                p[j] = s_ij;
                if (s_ij > mx || isnan(s_ij))
                    mx = s_ij;
            }
            double l = 0;
            for (int j = 0; j < nk; j++) {
                p[j] = exp(p[j] - mx);
                l += p[j];
            }
            for (int c = 0; c < d; c++)
                acc[c] = 0;
            for (int j = 0; j < nk; j++)
                for (int c = 0; c < d; c++)
                    acc[c] += p[j] * v[(size_t)j * (size_t)ldv + (size_t)h * (size_t)d + (size_t)c];
            float *o = out + (size_t)i * (size_t)ldo + (size_t)h * (size_t)d;
            for (int c = 0; c < d; c++)
                o[c] = (float)(acc[c] / l);
        }
    }
    return F4D_OK;
}

static int ranges_overlap(const float *a, int n, int ld, int w, const float *b, int nb, int ldb, int wb)
{
    const char *a0 = (const char *)a, *a1 = (const char *)(a + (size_t)(n - 1) * (size_t)ld + (size_t)w);
    const char *b0 = (const char *)b, *b1 = (const char *)(b + (size_t)(nb - 1) * (size_t)ldb + (size_t)wb);
    return a0 < b1 && b0 < a1;
}

int fk_attention(fk_ctx *ctx, const struct fk_attention_desc *a, const float *q, int ldq, int nq,
                 const float *k, int ldk, const float *v, int ldv, int nk, float *out, int ldo)
{
    FK_CHECK_CTX(ctx);
    if (!a)
        return FK_FAIL(ctx, F4D_EINVAL, "NULL descriptor");
    if (a->heads <= 0 || a->head_dim <= 0 || a->head_dim % 2)
        return FK_FAIL(ctx, F4D_EINVAL, "heads %d x head_dim %d: need heads > 0 and an even head_dim > 0",
                       a->heads, a->head_dim);
    if ((a->pos_q != NULL) != (a->pos_k != NULL))
        return FK_FAIL(ctx, F4D_EINVAL, "RoPE needs both pos_q and pos_k");
    if (a->pos_q && a->head_dim % 4)
        return FK_FAIL(ctx, F4D_EINVAL, "RoPE needs head_dim %% 4 == 0, got %d", a->head_dim);
    if (!(a->scale >= 0) || !isfinite(a->scale))
        return FK_FAIL(ctx, F4D_EINVAL, "scale %g must be finite and >= 0", a->scale);
    int norm = a->qk_norm || a->q_norm_w || a->q_norm_b || a->k_norm_w || a->k_norm_b;
    if (norm && !(a->norm_eps > 0))
        return FK_FAIL(ctx, F4D_EINVAL, "qk-norm needs eps > 0, got %g", a->norm_eps);
    if (nq < 0 || nk < 0)
        return FK_FAIL(ctx, F4D_EINVAL, "negative token count (nq %d, nk %d)", nq, nk);
    if (nq == 0)
        return F4D_OK;
    if (nk == 0)
        return FK_FAIL(ctx, F4D_EINVAL, "%d queries but no keys", nq);
    if (!q || !k || !v || !out)
        return FK_FAIL(ctx, F4D_EINVAL, "NULL %s", !q ? "q" : !k ? "k" : !v ? "v" : "out");
    long width = (long)a->heads * a->head_dim;
    if (width > 1 << 20)
        return FK_FAIL(ctx, F4D_ERANGE, "heads x head_dim = %ld is too wide", width);
    int C = (int)width;
    if (ldq < C || ldk < C || ldv < C || ldo < C)
        return FK_FAIL(ctx, F4D_EINVAL, "row strides (q %d, k %d, v %d, out %d) must be >= heads*head_dim = %d",
                       ldq, ldk, ldv, ldo, C);
    if (ranges_overlap(out, nq, ldo, C, q, nq, ldq, C) || ranges_overlap(out, nq, ldo, C, k, nk, ldk, C) ||
        ranges_overlap(out, nq, ldo, C, v, nk, ldv, C))
        return FK_FAIL(ctx, F4D_EINVAL, "output overlaps q, k or v");
    if (fk__isa_avx2(ctx->isa))
        return fk__attention_avx2(ctx, a, q, ldq, nq, k, ldk, v, ldv, nk, out, ldo);
    if (fk__isa_neon(ctx->isa))
        return fk__attention_neon(ctx, a, q, ldq, nq, k, ldk, v, ldv, nk, out, ldo);
    return fk__attention_ref(ctx, a, q, ldq, nq, k, ldk, v, ldv, nk, out, ldo);
}
