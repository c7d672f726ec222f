/* attention_plan.h - the ISA-independent driver of the vector attention
 * kernels (x86/attention_avx2.c, arm/attention_neon.c): job setup, padding,
 * head grouping, the RoPE table, the scratch bound, the two parallel phases
 * and the output normalisation live in attention_plan.c (plain C, no ISA
 * flags); each ISA file supplies only its vector pieces through
 * struct fk__attn_isa.
 *
 * Heads are processed in groups sized so that the group's transformed keys,
 * values and queries fit a few MB of shared scratch:
 *   phase 1 (parallel over token chunks): q/k LayerNorm and RoPE, q scaled by
 *     scale * log2(e) (so the softmax uses exp2), keys packed as 16-wide
 *     panels [d][16] (64-wide [d][64] for an ISA's block), values as rows
 *     [nk_pad][d], queries as 6-row panels;
 *   phase 2 (parallel over head x 96-query blocks): for each 64-key block,
 *     S = Q K^T by the GEMM's 6x16 register tile, the running max / sum
 *     update, and O = alpha O + P V by a 6x16 tile, all in L1. Nothing
 *     N_q x N_k is ever stored. Head dims that are not a multiple of 16 run
 *     on tiles padded to the next multiple with zero columns (LayerNorm and
 *     RoPE see the true head dim); above 1024 they use the reference. */
#ifndef FK_ATTENTION_PLAN_H
#define FK_ATTENTION_PLAN_H

#include <math.h>
#include <stdint.h>
#include <string.h>

#include "attention.h"

enum {
    FK_ATTN_MR = 6,  /* query rows per register tile / panel          */
    FK_ATTN_NR = 16, /* keys per packed panel                         */
    FK_ATTN_BK = 64, /* keys per block                                */
    FK_ATTN_QB = 96  /* queries per task: 16 register tiles share each K/V block */
};

/* The fp32 online softmax (AVX2 and AVX-512, the same rule, so the same
 * bits) keeps a row's running max m until a block's max exceeds it by more
 * than this (log2 units): p = 2^(s - m) <= 2^8 then, and the result is the
 * same softmax (m cancels in o / l). Mostly no row's max moves, so the
 * AVX-512 block starts its exponentials without waiting for the block's
 * maxima, and o is rarely rescaled. The int16 and bf16 paths keep m = the
 * running max (their codes are relative to it). */
#define FK_ATTN_SLACK 8.0f

/* Pulls a task's output slice (rows q0 .. q0 + rows - 1, d floats from
 * out + col0, row stride ldo) into the cache for writing, issued while the
 * task's last key block runs: the writes of the normalized rows missed (the
 * rows are ldo apart, a few lines each), and their loop was 44 % of the
 * fp32 attention task's own samples, ~9 % of its block kernel's (Zen 5). */
static inline void fk__attn_prefetch_out(const float *out, int ldo, int q0, int rows, int col0, int d)
{
    for (int r = 0; r < rows; r++) {
        const char *p = (const char *)(out + (size_t)(q0 + r) * (size_t)ldo + (size_t)col0);
        for (size_t b = 0; b < (size_t)d * sizeof(float); b += 64)
            __builtin_prefetch(p + b, 1, 3);
        __builtin_prefetch(p + (size_t)d * sizeof(float) - 1, 1, 3);
    }
}

/* A task's start: its panels' O rows zeroed, m = -inf, l = 0. */
static inline void fk__attn_task_init(float *o, int panels, int dp, float *m, float *l)
{
    memset(o, 0, (size_t)panels * FK_ATTN_MR * (size_t)dp * sizeof *o);
    for (int r = 0; r < panels * FK_ATTN_MR; r++) {
        m[r] = -INFINITY;
        l[r] = 0;
    }
}

/* A task's end: out rows q0 .. q0 + rows - 1 (d floats from col0, stride
 * ldo) = o / l, one rounding per element (o * (1 / l)). */
static inline void fk__attn_task_write(float *out, int ldo, int q0, int rows, int col0, int d,
                                       const float *o, int dp, const float *l)
{
    for (int r = 0; r < rows; r++) {
        float *dst = out + (size_t)(q0 + r) * (size_t)ldo + (size_t)col0;
        const float *orow = o + (size_t)r * (size_t)dp;
        float inv = 1.0f / l[r];
        for (int c = 0; c < d; c++)
            dst[c] = orow[c] * inv;
    }
}

struct fk__rope_table {
    int          on, lo, span, quarter;  /* positions lo .. lo + span - 1 */
    const float *cos, *sin;              /* [span][quarter]               */
};

/* The vector pieces of one ISA. */
struct fk__attn_isa {
    /* LayerNorm over t[d] (d a multiple of 8); NULL w / b mean 1 / 0 */
    void (*head_norm)(float *t, int d, const float *w, const float *b, float eps);
    /* 2D RoPE of t[d] at pos[2] from the table */
    void (*rope_apply)(const struct fk__rope_table *rt, float *t, int d, const int32_t *pos);
    /* the GEMM's 6x16 tile: c[6][16] (ldc) = a[kc][6] panel . b[kc][16] panel */
    void (*ukr_6x16)(int kc, const float *a, const float *b, float *c, int ldc, int accumulate);
    /* online softmax over one 6 x BK block of log2-domain logits, in place:
     * s becomes p = 2^(s - m_new); alpha = 2^(m_old - m_new) (alpha[8]);
     * l = alpha l + sum p */
    void (*softmax_block)(float *s, int valid, float *m, float *l, float *alpha);
    /* o[6][d] = alpha[r] o[r] + p[6][0, kv) . v[0, kv)[d]: kv = the block's
     * keys that exist (a last block's padding keys are skipped; an ISA may
     * round kv up to its step, the padding's p being ~0 and its v rows 0) */
    void (*pv_tile)(int d, int kv, const float *p, const float *v, float *o, const float *alpha);
    /* optional: the whole step for one panel and one key block, in place of
     * ukr_6x16, softmax_block and pv_tile: s[6][BK] (scratch) = the a panel
     * . the key block kp, then packed [d][BK] (not [d][16]), the online
     * softmax (m, l as above), o[6][d] = alpha o + p . v[BK][d]; NULL: the
     * pieces */
    void (*block)(int d, const float *a, const float *kp, const float *v, int valid, float *s,
                  float *o, float *m, float *l);
    /* optional: dst[d] = src[d] through head_norm (when norm) and then
     * rope_apply (when pos), their bits, for d a multiple of 8 and a RoPE
     * table; NULL: a copy and the two pieces */
    void (*prep_row)(const struct fk__rope_table *rt, const float *src, float *dst, int d, int norm,
                     const float *w, const float *b, float eps, const int32_t *pos);
    /* optional: the key panel kp[dp][kw] = the transpose of t[kw][dp]
     * (kw and dp multiples of 8); NULL: a scalar loop */
    void (*key_panel)(const float *t, int dp, int kw, float *kp);
};

#if defined(__x86_64__)
/* The AVX-512 step (x86/attention_avx512.c, called only where the context's
 * ISA is FK_ISA_AVX512): struct fk__attn_isa's block. */
void fk__attn_block_avx512(int d, const float *q, const float *kp, const float *v, int valid,
                           float *s, float *o, float *m, float *l);
#endif

/* bf16 products (x86/attention_bf16_avx512.c), for a desc with bf16 set
 * where ctx->bf16: after phase 1 the group's fp32 packs are rounded once to
 * bf16 pairs (kb, vb), then phase 2 runs S and P V with vdpbf16ps. */
struct fk__attn_bf16_job {
    fk_ctx      *ctx;
    const float *kp, *vp, *qp;         /* the group's fp32 packs (phase 1)  */
    int          kw;                   /* keys per fp32 key panel: NR, or BK for isa->block */
    size_t       head_k, head_v, head_q; /* their floats per head          */
    uint32_t    *kb, *vb;              /* bf16 pair packs of the group      */
    size_t       head_kb;              /* pairs per head in kb and in vb    */
    int          nq, nk, nk_pad, d, dp, h0, hn, q_blocks, ldo;
    float       *out;
};
#if defined(__x86_64__)
/* per-thread scratch and shared bytes per head (kb + vb) of the bf16 path */
void fk__attn_bf16_bytes(int dp, int nk_pad, size_t *local, size_t *per_head);
void fk__attn_bf16_run(const struct fk__attn_bf16_job *j);
#else /* never called: ctx->bf16 is 0 off x86-64 */
static inline void fk__attn_bf16_bytes(int dp, int nk_pad, size_t *local, size_t *per_head)
{
    (void)dp; (void)nk_pad;
    *local = *per_head = 0;
}
static inline void fk__attn_bf16_run(const struct fk__attn_bf16_job *j) { (void)j; }
#endif

#if defined(__x86_64__)
/* The AVX2 softmax's first pass over one 6 x BK block of logits (row
 * stride BK; keys from valid on set to -inf): bmax[r] = the row's max,
 * m_old[r] = m[r], m_new[r] = bmax where bmax > m + slack, else m, each
 * written as 8 floats (lanes 6 and 7 zero)
 * (x86/attention_avx2.c; fp32 passes FK_ATTN_SLACK, the int16 path's
 * softmax 0: m_new = max(bmax, m)). */
void fk__attn_rowmax_avx2(float *s, int valid, const float *m, float slack, float *bmax,
                          float *m_old, float *m_new);
#endif

/* int16 products (x86/attention_i16_avx2.c), for a desc with int16 set
 * where ctx->int16 (and not bf16): after phase 1 the group's fp32 packs are
 * quantized once to int16 pairs with their scales, then phase 2 runs S and
 * P V with vpmaddwd (AVX2-VNNI: VEX vpdpwssd; AVX-512: vpdpwssd in zmm)
 * into exact int32 sums. */
struct fk__attn_i16_job {
    fk_ctx      *ctx;
    const float *kp, *vp, *qp;         /* the group's fp32 packs (phase 1), kw = NR */
    size_t       head_k, head_v, head_q; /* their floats per head          */
    uint32_t    *kq, *vq;              /* int16 pair packs of the group     */
    size_t       head_pairs;           /* pairs per head in kq and in vq    */
    float       *sk, *sv;              /* key scales [nk_pad], value scales [nk_pad/BK][dp] per head */
    int          nq, nk, nk_pad, d, dp, h0, hn, q_blocks, ldo;
    float       *out;
};
#if defined(__x86_64__)
/* The two products of one 6-query panel and BK-key block in zmm with
 * vpdpwssd (x86/attention_i16_avx512.c): the AVX2 tiles' bits. */
void fk__attn_i16_s_block_avx512(int dp, int kv, const uint32_t *q, const uint32_t *kb, const float *sq,
                                 const float *sk, float *s);
void fk__attn_i16_pv_tile_avx512(int dp, int kv, const uint32_t *p, const uint32_t *v, const float *sv,
                                 float *o, const float *alpha, const float *ps);
/* The same two products with AVX-VNNI (x86/attention_i16_vnni.c). */
void fk__attn_i16_s_block_vnni(int dp, int kv, const uint32_t *q, const uint32_t *kb, const float *sq,
                               const float *sk, float *s);
void fk__attn_i16_pv_tile_vnni(int dp, int kv, const uint32_t *p, const uint32_t *v, const float *sv, float *o,
                               const float *alpha, const float *ps);
/* The int16 softmax's codes of one 6 x BK block in zmm: pairs in pb, row
 * sums in tot, NaN rows as the returned bits (x86/attention_i16_avx512.c). */
int fk__attn_i16_codes_avx512(const float *s, const float *bmax, uint32_t *pb, int32_t *tot); /* tot[8] */
/* per-thread scratch of the int16 path (its shared packs and scales are
 * bounded by a fraction of the fp32 packs: attention_plan.c) */
size_t fk__attn_i16_local_bytes(int dp);
void fk__attn_i16_run(const struct fk__attn_i16_job *j);
#else /* never called: ctx->int16 is 0 off x86-64 */
static inline size_t fk__attn_i16_local_bytes(int dp) { (void)dp; return 0; }
static inline void fk__attn_i16_run(const struct fk__attn_i16_job *j) { (void)j; }
#endif

/* fk__attention_avx2 / _neon: validated arguments, the ISA's pieces. */
int fk__attention_plan_run(const struct fk__attn_isa *isa, fk_ctx *ctx,
                           const struct fk_attention_desc *a, const float *q, int ldq, int nq,
                           const float *k, int ldk, const float *v, int ldv, int nk, float *out,
                           int ldo);

#endif
