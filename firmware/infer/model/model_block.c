/* model_block.c - the pre-norm transformer block (vggt.md 4) and the kernel
 * calls with FLOP accounting shared by all stages. */
#include "model_internal.h"

int model_linear(struct model *m, const struct fk_linear *L, const float *x, int rows, int ldx,
                 float *y, int ldy, const struct fk_epilogue *ep)
{
    if (fk_linear_forward(m->ctx, L, x, rows, ldx, y, ldy, ep) != F4D_OK)
        return model_kfail(m, "linear");
    *m->flops += 2.0 * rows * L->n * L->k;
    return 0;
}

int model_conv(struct model *m, const struct fk_conv2d *c, const float *x, int h, int w,
               float *y, enum fk_act act)
{
    int ho, wo;
    if (fk_conv2d_forward(m->ctx, c, x, h, w, y, act) != F4D_OK)
        return model_kfail(m, "conv2d");
    fk_conv2d_out_size(c, h, w, &ho, &wo);
    *m->flops += 2.0 * ho * wo * c->cout * c->cin * c->kh * c->kw;
    return 0;
}

int model_convt(struct model *m, const struct fk_conv_transpose2d *c, const float *x, int h,
                int w, float *y)
{
    if (fk_conv_transpose2d_forward(m->ctx, c, x, h, w, y) != F4D_OK)
        return model_kfail(m, "conv_transpose2d");
    *m->flops += 2.0 * h * w * c->cin * c->cout * c->k * c->k;
    return 0;
}

void model_block_bufs(struct bump *b, int dim, int hidden, int n, struct blk_bufs *bb)
{
    bb->ln = BUMP_F(b, (size_t)n * dim);
    bb->qkv = BUMP_F(b, (size_t)n * 3 * dim);
    bb->o = BUMP_F(b, (size_t)n * dim);
    bb->hid = BUMP_F(b, (size_t)n * hidden);
}

int model_block_forward_seqs(struct model *m, const struct blk *b, float *x, int nseq,
                             const int *off, const int32_t *pos, const struct blk_bufs *bb)
{
    const int C = b->dim, n = off[nseq], d = C / b->heads;
    int rc;
    if (fk_layernorm(m->ctx, x, n, C, C, b->n1w, b->n1b, b->eps, bb->ln, C) != F4D_OK)
        return model_kfail(m, "layernorm");
    if ((rc = model_linear(m, &b->qkv, bb->ln, n, C, bb->qkv, 3 * C, NULL)) < 0)
        return rc;
    struct fk_attention_desc a = {
        .heads = b->heads, .head_dim = d, .qk_norm = b->qk_norm,
        .q_norm_w = b->qnw, .q_norm_b = b->qnb, .k_norm_w = b->knw, .k_norm_b = b->knb,
        .norm_eps = 1e-5f, .rope_base = 100.0f,
        /* int8 weights: attention's products in bf16 where the CPU has
         * AVX512_BF16, in int16 on AVX2 without VNNI (attention was over
         * half the int8 forward's time) */
        .bf16 = m->wtype == FK_W_Q8, .int16 = m->wtype == FK_W_Q8,
    };
    double pairs = 0.0;
    for (int s = 0; s < nseq; s++) {
        const int len = off[s + 1] - off[s];
        const float *q = bb->qkv + (size_t)off[s] * 3 * C;
        a.pos_q = a.pos_k = pos ? pos + 2 * (size_t)off[s] : NULL;
        if (len > 0 && fk_attention(m->ctx, &a, q, 3 * C, len, q + C, 3 * C, q + 2 * C, 3 * C,
                                    len, bb->o + (size_t)off[s] * C, C) != F4D_OK)
            return model_kfail(m, "attention");
        pairs += (double)len * len;
    }
    *m->flops += 4.0 * pairs * C;
    struct fk_epilogue res1 = { .act = FK_ACT_NONE, .gamma = b->g1, .accumulate = 1 };
    if ((rc = model_linear(m, &b->proj, bb->o, n, C, x, C, &res1)) < 0)
        return rc;
    if (fk_layernorm(m->ctx, x, n, C, C, b->n2w, b->n2b, b->eps, bb->ln, C) != F4D_OK)
        return model_kfail(m, "layernorm");
    struct fk_epilogue gelu = { .act = FK_ACT_GELU };
    if ((rc = model_linear(m, &b->fc1, bb->ln, n, C, bb->hid, b->hidden, &gelu)) < 0)
        return rc;
    struct fk_epilogue res2 = { .act = FK_ACT_NONE, .gamma = b->g2, .accumulate = 1 };
    return model_linear(m, &b->fc2, bb->hid, n, b->hidden, x, C, &res2);
}

/* Equal sequences sharing one position table: the DINO and camera-trunk
 * callers (no RoPE). */
int model_block_forward(struct model *m, const struct blk *b, float *x, int nseq, int seqlen,
                        const int32_t *pos, const struct blk_bufs *bb)
{
    int off[MODEL_VIEWS_MAX + 2];
    F4D_ASSERT(nseq >= 1 && nseq <= MODEL_VIEWS_MAX + 1 && (!pos || nseq == 1));
    for (int s = 0; s <= nseq; s++)
        off[s] = s * seqlen;
    return model_block_forward_seqs(m, b, x, nseq, off, pos, bb);
}

int model_load_block(struct model *m, struct blk *b, const char *p, int dim, int heads,
                     int hidden, float eps, int qk_norm)
{
    char n1[MODEL_NAME_MAX + 32], n2[MODEL_NAME_MAX + 32];
    int rc = 0;
    b->dim = dim;
    b->heads = heads;
    b->hidden = hidden;
    b->eps = eps;
    b->qk_norm = qk_norm;
#define VEC(field, suffix, count) \
    snprintf(n1, sizeof n1, "%s." suffix, p); \
    if ((rc = model_load_f32(m, n1, (size_t)(count), &b->field)) < 0) return rc;
    VEC(n1w, "norm1.weight", dim) VEC(n1b, "norm1.bias", dim)
    VEC(n2w, "norm2.weight", dim) VEC(n2b, "norm2.bias", dim)
    VEC(g1, "ls1.gamma", dim) VEC(g2, "ls2.gamma", dim)
    if (qk_norm) {
        VEC(qnw, "attn.q_norm.weight", dim / heads) VEC(qnb, "attn.q_norm.bias", dim / heads)
        VEC(knw, "attn.k_norm.weight", dim / heads) VEC(knb, "attn.k_norm.bias", dim / heads)
    }
#undef VEC
#define LIN(field, name, nout, nin) \
    snprintf(n1, sizeof n1, "%s." name ".weight", p); \
    snprintf(n2, sizeof n2, "%s." name ".bias", p); \
    if ((rc = model_load_linear(m, &b->field, n1, n2, nout, nin)) < 0) return rc;
    LIN(qkv, "attn.qkv", 3 * dim, dim)
    LIN(proj, "attn.proj", dim, dim)
    LIN(fc1, "mlp.fc1", hidden, dim)
    LIN(fc2, "mlp.fc2", dim, hidden)
#undef LIN
    return 0;
}

void model_free_block(struct blk *b)
{
    fk_linear_free(&b->qkv);
    fk_linear_free(&b->proj);
    fk_linear_free(&b->fc1);
    fk_linear_free(&b->fc2);
}
