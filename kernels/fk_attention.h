/* fk_attention.h - multi-head attention, tiled with an online softmax.
 *
 * out[i, h*d : (h+1)*d] = sum_j softmax_j(scale * <q'_ih, k'_jh>) v_jh
 * for every head h, where q' and k' are q and k after the optional per-head
 * LayerNorm (over d, weights shared by all heads; vggt.md 4 step 2) and then
 * the optional 2-D RoPE (vggt.md 4a). Queries come from one token set and
 * keys/values from another, so the same call does self-attention (q, k, v
 * strided views of one qkv buffer) and cross-attention (state tokens).
 * No N_q x N_k matrix is ever stored: scratch is O((N_q + N_k) * d) per head.
 *
 * q is [nq, heads*d] with row stride ldq, k and v are [nk, heads*d] with row
 * strides ldk and ldv, out is [nq, heads*d] with row stride ldo (must not
 * overlap the inputs). Channel layout inside a row: head-major, d contiguous.
 *
 *     struct fk_attention_desc a = { .heads = 16, .head_dim = 64,
 *         .q_norm_w = qw, .q_norm_b = qb, .k_norm_w = kw, .k_norm_b = kb,
 *         .norm_eps = 1e-5f, .pos_q = pos, .pos_k = pos, .rope_base = 100.0f };
 *     fk_attention(ctx, &a, qkv, 3*C, n, qkv + C, 3*C, qkv + 2*C, 3*C, n, o, C);
 *
 * Logits are handled in a max-subtracted form, so +-1e4 logits give the exact
 * softmax (one-hot where the gap is large); all-equal rows give the mean of v.
 * NaN or Inf in q, k or v make the affected output rows non-finite.
 */
#ifndef FK_ATTENTION_H
#define FK_ATTENTION_H

#include <stdint.h>
#include "fk_ctx.h"

#ifdef __cplusplus
extern "C" {
#endif

struct fk_attention_desc {
    int            heads;
    int            head_dim;   /* even; multiple of 4 when RoPE is used        */
    float          scale;      /* 0 means 1/sqrt(head_dim)                      */
    /* per-head LayerNorm of q and k before RoPE: all NULL = off. Weights and
     * biases are [head_dim]; a NULL weight/bias inside an enabled norm means
     * 1 / 0. Enabled when q_norm_w or q_norm_b (resp. k_) is non-NULL, or when
     * qk_norm is set. */
    int            qk_norm;
    const float   *q_norm_w, *q_norm_b;
    const float   *k_norm_w, *k_norm_b;
    float          norm_eps;
    /* 2-D RoPE: positions (y, x) per token as int32 pairs; NULL = no RoPE.
     * Both must be given together. */
    const int32_t *pos_q;      /* [nq][2] */
    const int32_t *pos_k;      /* [nk][2] */
    float          rope_base;  /* 100 in VGGT; 0 means 100                       */
    /* Nonzero: the q.k and p.v products in bfloat16 with fp32 accumulation
     * where the context runs them (fk_ctx_has_bf16: AVX512_BF16, and by
     * default only on AMD, where they pay; fp32 elsewhere).
     * LayerNorm, RoPE, the softmax and the row sums stay fp32; q, k, v and
     * the softmax weights p are rounded to bf16 (8-bit significand), and the
     * row sum adds the rounded p that multiply v. Error: see README
     * (kernels, attention). 0 = fp32 throughout. */
    int            bf16;
    /* Nonzero: the q.k and p.v products in int16 with exact int32 sums where
     * the context runs int16 attention (fk_ctx_has_int16; fp32 elsewhere, and
     * bf16 wins where both are set and the context has both). q and k are
     * 12-bit codes (at head dim 64; 11 at 128, 13 at 16) scaled per query /
     * key, v 12-bit per column and 64-key block, p 12-bit (4096 = each
     * block's largest weight) with l summing the codes; LayerNorm, RoPE and
     * the softmax stay fp32. Error: see README (kernels, attention). */
    int            int16;
};

int fk_attention(fk_ctx *ctx, const struct fk_attention_desc *desc,
                 const float *q, int ldq, int nq,
                 const float *k, int ldk,
                 const float *v, int ldv, int nk,
                 float *out, int ldo);

/* The products a call with this desc runs on this context: bf16 where
 * desc.bf16 and fk_ctx_has_bf16; else int16 where desc.int16 and
 * fk_ctx_has_int16 (on AVX-512 from 64-dim heads only: vpdpwssd ran
 * 1.17-1.37x fp32 zmm at 64, 0.76x at 16); else fp32 (also for head dims
 * above 1024, which the reference runs). */
enum fk_attn_products { FK_ATTN_F32 = 0, FK_ATTN_BF16 = 1, FK_ATTN_INT16 = 2 };
enum fk_attn_products fk_attention_products(const fk_ctx *ctx, const struct fk_attention_desc *desc);

/* Apply the 2-D RoPE of vggt.md 4a in place to one head vector t[d]
 * (reference; exposed for tests and for the PyTorch parity tools). */
void fk_rope2d_ref(float *t, int d, int32_t pos_y, int32_t pos_x, float base);

#ifdef __cplusplus
}
#endif
#endif /* FK_ATTENTION_H */
