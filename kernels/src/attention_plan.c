/* attention_plan.c - the ISA-independent driver of the vector attention
 * kernels (see attention_plan.h): plain C without ISA flags; the vector work
 * goes through struct fk__attn_isa. */
#include <math.h>
#include <string.h>

#include "attention_plan.h"
#include "fk_internal.h"

#define MR FK_ATTN_MR
#define NR FK_ATTN_NR
#define BK FK_ATTN_BK
#define QB FK_ATTN_QB
#define GROUP_BYTES (8u << 20) /* shared scratch per head group      */
#define LOG2E 1.4426950408889634f

_Static_assert(QB >= BK, "phase 1's token block lives in phase 2's O rows");

struct attn_job {
    const struct fk__attn_isa      *isa;
    fk_ctx                         *ctx;
    const struct fk_attention_desc *a;
    const float *q, *k, *v;
    int    ldq, ldk, ldv, nq, nk, ldo, d, nk_pad, nq_pad;
    int    dp;                           /* d rounded up to 16: the tiles' width, zero-padded */
    int    kw;                           /* keys per packed key panel: BK with isa->block, else NR */
    int    h0, hn;                       /* heads of this group           */
    float  qscale;
    float *out;
    float *kp, *vp, *qp;                 /* group scratch, per head blocks */
    size_t head_k, head_v, head_q;       /* floats per head                */
    struct fk__rope_table rope;
    int    chunk, k_chunks, q_chunks, q_blocks;
    size_t off_o, off_ml;
};

/* ------------------------------------------------------------------- prep */

/* Phase 1 fills one packed panel at a time, per head: its tokens' vectors
 * (LayerNorm, RoPE) into a contiguous block tmp[tokens][dp] of the thread's
 * scratch, then the panel from it row by row. A panel holds a token's d
 * values kw (or MR) floats apart; stored there straight, each value touched
 * a line of its own across all the group's panels, and those scattered
 * stores were half of phase 1, which was 13 % of 1374-token attention (2
 * threads, Zen 5). */
#define PREP_AHEAD 8

/* Head h's slice of token t of src (ld floats a row), fetched ahead: rows
 * are a whole qkv row apart, too far for the hardware prefetchers. Inlined:
 * GCC finds an out-of-line copy free of side effects and drops its calls. */
static inline __attribute__((always_inline)) void prefetch_head(const struct attn_job *j, const float *src,
                                                                int ld, int t, int h)
{
    const char *p = (const char *)(src + (size_t)t * (size_t)ld + (size_t)h * (size_t)j->d);
    for (size_t b = 0; b < (size_t)j->d * sizeof(float); b += 64)
        __builtin_prefetch(p + b);
}

static void prep_vec(const struct attn_job *j, int which, const float *src, const int32_t *pos,
                     float *dst)
{
    const struct fk_attention_desc *a = j->a;
    int d = j->d;
    const float *w = which == 0 ? a->q_norm_w : a->k_norm_w;
    const float *b = which == 0 ? a->q_norm_b : a->k_norm_b;
    const int norm = a->qk_norm || w || b;
    if (j->isa->prep_row && d % 8 == 0 && (!pos || j->rope.on)) {
        j->isa->prep_row(&j->rope, src, dst, d, norm, w, b, a->norm_eps, pos);
    } else {
        memcpy(dst, src, (size_t)d * sizeof *dst);
        if (norm) {
            if (d % 8 == 0)
                j->isa->head_norm(dst, d, w, b, a->norm_eps);
            else
                fk__head_layernorm_ref(dst, d, w, b, a->norm_eps);
        }
        if (pos) {
            if (j->rope.on)
                j->isa->rope_apply(&j->rope, dst, d, pos);
            else
                fk_rope2d_ref(dst, d, pos[0], pos[1], a->rope_base > 0 ? a->rope_base : 100.0f);
        }
    }
    if (j->dp > d) /* padding columns: zeros */
        memset(dst + d, 0, (size_t)(j->dp - d) * sizeof *dst);
}

/* Tokens of a panel of `width` from b0 that exist (n of them in all). */
static inline int panel_tokens(int n, int b0, int width)
{
    return n - b0 >= width ? width : n - b0 > 0 ? n - b0 : 0;
}

/* Keys b0 .. b0 + kw - 1 of every head of the group: a key panel [dp][kw]
 * and kw value rows [dp] per head (tokens from nk on: zeros). The slices
 * are read head by head, each fetched PREP_AHEAD slices ahead in that order. */
static void prep_keys(const struct attn_job *j, int b0, float *tmp)
{
    const int d = j->d, dp = j->dp, kw = j->kw;
    const int real = panel_tokens(j->nk, b0, kw);
    const int32_t *pos = j->a->pos_k;
    for (int h = j->h0; h < j->h0 + j->hn; h++) {
        float *kpan = j->kp + (size_t)(h - j->h0) * j->head_k + (size_t)(b0 / kw) * (size_t)dp * kw;
        float *vd = j->vp + (size_t)(h - j->h0) * j->head_v + (size_t)b0 * (size_t)dp;
        for (int t = 0; t < real; t++, vd += dp) {
            int s = (h - j->h0) * real + t + PREP_AHEAD; /* the slice that far ahead */
            if (s < j->hn * real) {
                prefetch_head(j, j->k, j->ldk, b0 + s % real, j->h0 + s / real);
                prefetch_head(j, j->v, j->ldv, b0 + s % real, j->h0 + s / real);
            }
            prep_vec(j, 1, j->k + (size_t)(b0 + t) * (size_t)j->ldk + (size_t)h * (size_t)d,
                     pos ? pos + 2 * (size_t)(b0 + t) : NULL, tmp + (size_t)t * (size_t)dp);
            memcpy(vd, j->v + (size_t)(b0 + t) * (size_t)j->ldv + (size_t)h * (size_t)d, (size_t)d * sizeof *vd);
            memset(vd + d, 0, (size_t)(dp - d) * sizeof *vd);
        }
        memset(tmp + (size_t)real * (size_t)dp, 0, (size_t)(kw - real) * (size_t)dp * sizeof *tmp);
        memset(vd, 0, (size_t)(kw - real) * (size_t)dp * sizeof *vd);
        if (j->isa->key_panel)
            j->isa->key_panel(tmp, dp, kw, kpan);
        else
            for (int c = 0; c < dp; c++)
                for (int t = 0; t < kw; t++)
                    kpan[(size_t)c * kw + t] = tmp[(size_t)t * (size_t)dp + c];
    }
}

/* Queries b0 .. b0 + MR - 1: a query panel [dp][MR] per head, scaled by
 * qscale (tokens from nq on: zeros). */
static void prep_queries(const struct attn_job *j, int b0, float *tmp)
{
    const int dp = j->dp;
    const int real = panel_tokens(j->nq, b0, MR);
    const int32_t *pos = j->a->pos_q;
    for (int h = j->h0; h < j->h0 + j->hn; h++) {
        float *qpan = j->qp + (size_t)(h - j->h0) * j->head_q + (size_t)(b0 / MR) * (size_t)dp * MR;
        for (int t = 0; t < real; t++) {
            if (h == j->h0 && b0 + MR + t < j->nq) /* the next panel's rows, every head of the group */
                for (int c = 0; c < j->hn * j->d; c += 16)
                    __builtin_prefetch(j->q + (size_t)(b0 + MR + t) * (size_t)j->ldq + (size_t)j->h0 * (size_t)j->d + c);
            prep_vec(j, 0, j->q + (size_t)(b0 + t) * (size_t)j->ldq + (size_t)h * (size_t)j->d,
                     pos ? pos + 2 * (size_t)(b0 + t) : NULL, tmp + (size_t)t * (size_t)dp);
        }
        for (int c = 0; c < dp; c++)
            for (int t = 0; t < MR; t++)
                qpan[(size_t)c * MR + t] = t < real ? tmp[(size_t)t * (size_t)dp + c] * j->qscale : 0.0f;
    }
}

/* Tasks 0 .. k_chunks - 1: chunk keys each; then chunk / MR * MR queries each. */
static void prep_task(void *arg, int task, int thread)
{
    const struct attn_job *j = arg;
    /* [max(kw, MR)][dp]: phase 2's scratch, unused yet, which holds the
     * task's QB rows of O, and QB >= BK >= kw */
    float *tmp = fk__scratch(j->ctx, thread);
    if (task < j->k_chunks) {
        int t0 = task * j->chunk, t1 = t0 + j->chunk < j->nk_pad ? t0 + j->chunk : j->nk_pad;
        for (int b0 = t0; b0 < t1; b0 += j->kw)
            prep_keys(j, b0, tmp);
        return;
    }
    int qc = j->chunk / MR * MR;
    int t0 = (task - j->k_chunks) * qc, t1 = t0 + qc < j->nq_pad ? t0 + qc : j->nq_pad;
    for (int b0 = t0; b0 < t1; b0 += MR)
        prep_queries(j, b0, tmp);
}

/* ------------------------------------------------------------- attention */

static void attn_task(void *arg, int task, int thread)
{
    const struct attn_job *j = arg;
    const struct fk__attn_isa *isa = j->isa;
    int hh = task / j->q_blocks, qb = task % j->q_blocks, d = j->d, dp = j->dp;
    int h = j->h0 + hh;
    const float *kp = j->kp + (size_t)hh * j->head_k, *vp = j->vp + (size_t)hh * j->head_v;
    const float *qp = j->qp + (size_t)hh * j->head_q;
    char *scr = fk__scratch(j->ctx, thread);
    float *s = (float *)scr;                  /* [6][BK]    */
    float *o = (float *)(scr + j->off_o);     /* [QB][dp]   */
    float *ml = (float *)(scr + j->off_ml);   /* m[QB] l[QB] alpha[8] */
    float *mrow = ml, *lrow = ml + QB, *alpha = ml + 2 * QB;
    int q0 = qb * QB, rows = j->nq - q0 < QB ? j->nq - q0 : QB;
    int panels = (rows + MR - 1) / MR;
    fk__attn_task_init(o, panels, dp, mrow, lrow);
    for (int kb = 0; kb < j->nk_pad / BK; kb++) {
        int valid = j->nk - kb * BK < BK ? j->nk - kb * BK : BK;
        if (kb == j->nk_pad / BK - 1)
            fk__attn_prefetch_out(j->out, j->ldo, q0, rows, h * d, d);
        for (int i = 0; i < panels; i++) {
            const float *qi = qp + (size_t)(q0 / MR + i) * (size_t)dp * MR;
            const float *kb_p = kp + (size_t)kb * (BK / NR) * (size_t)dp * NR;
            if (isa->block) {
                isa->block(dp, qi, kb_p, vp + (size_t)kb * BK * (size_t)dp, valid, s,
                           o + (size_t)i * MR * (size_t)dp, mrow + i * MR, lrow + i * MR);
                continue;
            }
            /* a last block's key tiles past its keys are skipped (the
             * softmax sets their s to -inf), and its P V stops at them */
            for (int p = 0; p * NR < valid; p++)
                isa->ukr_6x16(dp, qi, kb_p + (size_t)p * (size_t)dp * NR, s + p * NR, BK, 0);
            isa->softmax_block(s, valid, mrow + i * MR, lrow + i * MR, alpha);
            isa->pv_tile(dp, valid, s, vp + (size_t)kb * BK * (size_t)dp, o + (size_t)i * MR * (size_t)dp,
                         alpha);
        }
    }
    fk__attn_task_write(j->out, j->ldo, q0, rows, h * d, d, o, dp, lrow);
}

/* ------------------------------------------------------------------ driver */

/* RoPE cos/sin per distinct position value (VGGT's grid has a few dozen),
 * so no token pays for sinf/cosf; NULL table = positions too spread out. */
static long rope_span(const struct attn_job *j, int *lo_out)
{
    const struct fk_attention_desc *a = j->a;
    int lo = a->pos_q[0], hi = lo;
    for (int t = 0; t < 2 * j->nq; t++) {
        lo = a->pos_q[t] < lo ? a->pos_q[t] : lo;
        hi = a->pos_q[t] > hi ? a->pos_q[t] : hi;
    }
    for (int t = 0; t < 2 * j->nk; t++) {
        lo = a->pos_k[t] < lo ? a->pos_k[t] : lo;
        hi = a->pos_k[t] > hi ? a->pos_k[t] : hi;
    }
    *lo_out = lo;
    return (long)hi - lo + 1;
}

static void build_rope(struct attn_job *j, int lo, int span, float *t)
{
    const struct fk_attention_desc *a = j->a;
    int quarter = j->d / 4, m = j->d / 2;
    float base = a->rope_base > 0 ? a->rope_base : 100.0f;
    float *sn = t + (size_t)span * (size_t)quarter;
    float inv_freq[256]; /* head_dim <= 1024 here (larger ones run the reference) */
    for (int k = 0; k < quarter; k++)
        inv_freq[k] = (float)(1.0 / pow((double)base, (double)(2 * k) / (double)m));
    for (int p = 0; p < span; p++)
        for (int k = 0; k < quarter; k++) {
            float theta = (float)(lo + p) * inv_freq[k];
            t[(size_t)p * (size_t)quarter + (size_t)k] = cosf(theta);
            sn[(size_t)p * (size_t)quarter + (size_t)k] = sinf(theta);
        }
    j->rope = (struct fk__rope_table){ 1, lo, span, quarter, t, sn };
}

enum fk_attn_products fk_attention_products(const fk_ctx *ctx, const struct fk_attention_desc *a)
{
    if (!ctx || !a || a->head_dim > 1024) /* the reference runs those */
        return FK_ATTN_F32;
    if (a->bf16 && ctx->bf16)
        return FK_ATTN_BF16;
    /* AVX-512 (vpdpwssd) from 64-dim heads: 1.17-1.37x fp32 zmm at 64, 0.76x
     * at 16 (the softmax's AVX2 code outweighs the cheaper products there) */
    int dp = (int)fk__round_up((size_t)(a->head_dim > 0 ? a->head_dim : 0), 16);
    if (a->int16 && ctx->int16 && (ctx->isa != FK_ISA_AVX512 || dp >= 64))
        return FK_ATTN_INT16;
    return FK_ATTN_F32;
}

int fk__attention_plan_run(const struct fk__attn_isa *isa, fk_ctx *ctx,
                           const struct fk_attention_desc *a, const float *q, int ldq, int nq,
                           const float *k, int ldk, const float *v, int ldv, int nk, float *out,
                           int ldo)
{
    int d = a->head_dim;
    if (d > 1024)
        return fk__attention_ref(ctx, a, q, ldq, nq, k, ldk, v, ldv, nk, out, ldo);
    struct attn_job j = { 0 };
    j.isa = isa;
    j.ctx = ctx; j.a = a; j.q = q; j.k = k; j.v = v;
    j.ldq = ldq; j.ldk = ldk; j.ldv = ldv; j.ldo = ldo; j.nq = nq; j.nk = nk; j.d = d; j.out = out;
    /* Head dims off the 16-wide tiles (the shipped model's 24) run on tiles
     * padded with zero columns: they add nothing to q.k or to P V. */
    j.dp = (int)fk__round_up((size_t)d, 16);
    /* bf16 / int16 products where the desc asks and the context runs them */
    enum fk_attn_products prod = fk_attention_products(ctx, a);
    int bf16 = prod == FK_ATTN_BF16, i16 = prod == FK_ATTN_INT16;
    /* see attention_plan.h; the int16 packs read 16-key panels on every ISA */
    j.kw = isa->block && !i16 ? BK : NR;
    j.nk_pad = (int)fk__round_up((size_t)nk, BK);
    j.nq_pad = (int)fk__round_up((size_t)nq, MR);
    j.qscale = (a->scale > 0 ? a->scale : 1.0f / sqrtf((float)d)) * LOG2E;
    j.head_k = (size_t)j.nk_pad * (size_t)j.dp;
    j.head_v = (size_t)j.nk_pad * (size_t)j.dp;
    j.head_q = (size_t)j.nq_pad * (size_t)j.dp;
    size_t per_head = (j.head_k + j.head_v + j.head_q) * sizeof(float);
    int group = (int)(GROUP_BYTES / per_head);
    if (group < 1)
        group = 1;
    if (group > a->heads)
        group = a->heads;

    int lo = 0;
    long span = a->pos_q ? rope_span(&j, &lo) : 0;
    if (span > 65536)
        span = 0; /* per-token sinf/cosf instead of a table */
    size_t table = fk__round_up((size_t)span * (size_t)(d / 4) * 2 * sizeof(float), FK_ALIGN);
    j.off_o = fk__round_up((size_t)MR * BK * sizeof(float), FK_ALIGN);
    j.off_ml = j.off_o + fk__round_up((size_t)QB * (size_t)j.dp * sizeof(float), FK_ALIGN);
    size_t local = j.off_ml + (2 * QB + 8) * sizeof(float) + FK_ALIGN;
    /* Reserve a bound that grows monotonically with nq / nk, not per_head * group
     * itself: a smaller problem may fit more heads per group and need more (4 views
     * of 518x518 take one head of 4.2 MB, 3 views two heads of 3.2 MB), so scratch
     * measured at the largest size (fk_ctx_measure) would not cover it.
     * per_head * group is at most heads * per_head, and at most
     * max(per_head, GROUP_BYTES). */
    size_t grp_bytes = per_head > GROUP_BYTES ? per_head : GROUP_BYTES;
    if (grp_bytes > per_head * (size_t)a->heads)
        grp_bytes = per_head * (size_t)a->heads;
    /* bf16 products: the bf16 packs take at most half of the fp32 ones */
    size_t bf_local = 0, bf_head = 0;
    if (bf16) {
        fk__attn_bf16_bytes(j.dp, j.nk_pad, &bf_local, &bf_head);
        local = local > bf_local ? local : bf_local;
        grp_bytes += grp_bytes / 2 + 2 * FK_ALIGN;
    }
    /* int16 products: packs as bf16's plus their scales, which take at
     * most (1 + dp / 64) / (2 dp) <= 1/25 of the fp32 packs (dp >= 16) */
    if (i16) {
        size_t i16_local = fk__attn_i16_local_bytes(j.dp);
        local = local > i16_local ? local : i16_local;
        grp_bytes += grp_bytes / 2 + grp_bytes / 16 + 6 * FK_ALIGN;
    }
    int st = fk__scratch_reserve(ctx, local, table + grp_bytes + 3 * FK_ALIGN);
    if (st || fk__measuring(ctx))
        return st;
    char *sh = fk__scratch_shared(ctx);
    if (span > 0)
        build_rope(&j, lo, (int)span, (float *)sh);
    sh += table;
    j.chunk = 128;
    j.k_chunks = j.nk_pad / j.chunk + (j.nk_pad % j.chunk != 0);
    j.q_chunks = (j.nq_pad + j.chunk / MR * MR - 1) / (j.chunk / MR * MR);
    j.q_blocks = (nq + QB - 1) / QB;
    double att_work = 4.0 * d * (double)nq * nk;
    for (int h0 = 0; h0 < a->heads; h0 += group) {
        j.h0 = h0;
        j.hn = a->heads - h0 < group ? a->heads - h0 : group;
        j.kp = (float *)sh;
        j.vp = (float *)fk__round_up((uintptr_t)(j.kp + j.head_k * (size_t)j.hn), FK_ALIGN);
        j.qp = (float *)fk__round_up((uintptr_t)(j.vp + j.head_v * (size_t)j.hn), FK_ALIGN);
        fk_parallel_for(ctx, j.k_chunks + j.q_chunks, 20.0 * d * j.hn * (double)(nq + nk), prep_task, &j);
        if (bf16) {
            uint32_t *kb = (uint32_t *)fk__round_up((uintptr_t)(j.qp + j.head_q * (size_t)j.hn), FK_ALIGN);
            struct fk__attn_bf16_job b = {
                ctx, j.kp, j.vp, j.qp, j.kw, j.head_k, j.head_v, j.head_q,
                kb, kb + bf_head / 8 * (size_t)j.hn, bf_head / 8,
                nq, nk, j.nk_pad, d, j.dp, h0, j.hn, j.q_blocks, ldo, out,
            };
            fk__attn_bf16_run(&b);
            continue;
        }
        if (i16) {
            size_t pairs = (size_t)j.nk_pad * (size_t)j.dp / 2;
            uint32_t *kq = (uint32_t *)fk__round_up((uintptr_t)(j.qp + j.head_q * (size_t)j.hn), FK_ALIGN);
            uint32_t *vq = (uint32_t *)fk__round_up((uintptr_t)(kq + pairs * (size_t)j.hn), FK_ALIGN);
            float *sk = (float *)fk__round_up((uintptr_t)(vq + pairs * (size_t)j.hn), FK_ALIGN);
            float *sv = (float *)fk__round_up((uintptr_t)(sk + (size_t)j.nk_pad * (size_t)j.hn), FK_ALIGN);
            struct fk__attn_i16_job b = {
                ctx, j.kp, j.vp, j.qp, j.head_k, j.head_v, j.head_q, kq, vq, pairs, sk, sv,
                nq, nk, j.nk_pad, d, j.dp, h0, j.hn, j.q_blocks, ldo, out,
            };
            fk__attn_i16_run(&b);
            continue;
        }
        fk_parallel_for(ctx, j.hn * j.q_blocks, att_work * j.hn, attn_task, &j);
    }
    return F4D_OK;
}
