/* attention.h - pieces of fk_attention shared by the reference and the ISA
 * versions. */
#ifndef FK_ATTENTION_INTERNAL_H
#define FK_ATTENTION_INTERNAL_H

#include "../fk_attention.h"

/* LayerNorm of one head vector (biased variance; NULL w / b mean 1 / 0). */
void fk__head_layernorm_ref(float *t, int d, const float *w, const float *b, float eps);
/* One head vector of q (which = 0) or k (which = 1) after the optional
 * qk-norm and RoPE, times scale, into dst[d]. */
void fk__attn_prep_ref(const struct fk_attention_desc *a, int which, const float *src,
                       const int32_t *pos, float scale, float *dst);

/* The scalar reference on validated arguments. */
int  fk__attention_ref (fk_ctx *ctx, const struct fk_attention_desc *a, const float *q, int ldq,
                        int nq, const float *k, int ldk, const float *v, int ldv, int nk,
                        float *out, int ldo);
#if defined(__x86_64__)
int  fk__attention_avx2(fk_ctx *ctx, const struct fk_attention_desc *a, const float *q, int ldq,
                        int nq, const float *k, int ldk, const float *v, int ldv, int nk,
                        float *out, int ldo);
#else /* never called: fk__isa_avx2() is 0 off x86-64 */
static inline int fk__attention_avx2(fk_ctx *ctx, const struct fk_attention_desc *a, const float *q,
                                     int ldq, int nq, const float *k, int ldk, const float *v,
                                     int ldv, int nk, float *out, int ldo)
{
    (void)ctx; (void)a; (void)q; (void)ldq; (void)nq; (void)k; (void)ldk; (void)v; (void)ldv;
    (void)nk; (void)out; (void)ldo;
    return F4D_ENOTSUP;
}
#endif
#if defined(__aarch64__)
int  fk__attention_neon(fk_ctx *ctx, const struct fk_attention_desc *a, const float *q, int ldq,
                        int nq, const float *k, int ldk, const float *v, int ldv, int nk,
                        float *out, int ldo);
#else /* never called: fk__isa_neon() is 0 off AArch64 */
static inline int fk__attention_neon(fk_ctx *ctx, const struct fk_attention_desc *a, const float *q,
                                     int ldq, int nq, const float *k, int ldk, const float *v,
                                     int ldv, int nk, float *out, int ldo)
{
    (void)ctx; (void)a; (void)q; (void)ldq; (void)nq; (void)k; (void)ldk; (void)v; (void)ldv;
    (void)nk; (void)out; (void)ldo;
    return F4D_ENOTSUP;
}
#endif

#endif
