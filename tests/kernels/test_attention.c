/* fk_attention: the optimized kernels against the scalar reference
 * (self- and cross-attention, qk-norm, RoPE, awkward token counts), the
 * online softmax on hard logits, non-finite inputs and bad arguments.
 *
 * Error budget: |out - ref| <= 2e-5 (atol) + 2e-5 |ref| per element. The
 * reference accumulates in double; the budget covers fp32 dot products of
 * length head_dim and the fp32 running sums over up to a few thousand keys. */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "fk_attention.h"
#include "test_util.h"
#include "../../kernels/src/attention.h" /* fk__attn_prep_ref: q', k' for the bf16 budget */

struct attn_case {
    int heads, d, nq, nk, rope, norm, cross;
};

static void make_pos(int32_t *pos, int n, int side)
{
    for (int t = 0; t < n; t++) {
        int p = t % (side * side + 5);
        pos[2 * t] = p < 5 ? 0 : (p - 5) / side + 1;
        pos[2 * t + 1] = p < 5 ? 0 : (p - 5) % side + 1;
    }
}

/* The inputs of one case: q, k, v as strided views of one qkv buffer (or
 * k, v of a separate kv buffer for cross-attention), random normals of std
 * logit_scale, per-head LayerNorm weights and RoPE positions when asked. */
struct attn_inputs {
    float  *qkv, *kv, *nw, *nb;
    int32_t *pq, *pk;
    struct fk_attention_desc a;
    const float *q, *k, *v;
    int     C, ld, ldk, nkv;
};

static void make_inputs(const struct attn_case *c, uint64_t seed, float logit_scale, int pos_side,
                        int swap_k_norm, struct attn_inputs *in)
{
    struct rng r;
    rng_seed(&r, seed);
    int C = c->heads * c->d, ld = 3 * C + 5; /* strided views of a qkv buffer */
    int nkv = c->cross ? c->nk : c->nq, nmax = c->nq > nkv ? c->nq : nkv;
    float *qkv = xmalloc(sizeof(float) * (size_t)nmax * ld);
    rng_fill_normal(&r, qkv, (size_t)nmax * ld, logit_scale);
    float *kv = c->cross ? xmalloc(sizeof(float) * (size_t)nkv * 2 * C) : NULL;
    if (kv)
        rng_fill_normal(&r, kv, (size_t)nkv * 2 * C, logit_scale);
    float *nw = xmalloc(sizeof(float) * c->d), *nb = xmalloc(sizeof(float) * c->d);
    for (int i = 0; i < c->d; i++) {
        nw[i] = 1.0f + 0.3f * rng_normal(&r);
        nb[i] = 0.1f * rng_normal(&r);
    }
    int32_t *pq = xmalloc(sizeof(int32_t) * 2 * c->nq), *pk = xmalloc(sizeof(int32_t) * 2 * nkv);
    make_pos(pq, c->nq, pos_side);
    make_pos(pk, nkv, pos_side);
    struct fk_attention_desc a = { .heads = c->heads, .head_dim = c->d };
    if (c->norm) {
        a.q_norm_w = nw; a.q_norm_b = nb; a.norm_eps = 1e-5f;
        a.k_norm_w = swap_k_norm ? nb : nw; a.k_norm_b = swap_k_norm ? nw : nb;
    }
    if (c->rope) {
        a.pos_q = pq; a.pos_k = pk; a.rope_base = 100.0f;
    }
    *in = (struct attn_inputs){ qkv, kv, nw, nb, pq, pk, a, qkv, kv ? kv : qkv + C,
                                kv ? kv + C : qkv + 2 * C, C, ld, kv ? 2 * C : ld, nkv };
}

static void free_inputs(struct attn_inputs *in)
{
    free(in->qkv); free(in->kv); free(in->nw); free(in->nb); free(in->pq); free(in->pk);
}

static void run_case(const struct attn_case *c, uint64_t seed, float logit_scale)
{
    struct attn_inputs in;
    make_inputs(c, seed, logit_scale, 7, 1, &in);
    struct fk_attention_desc a = in.a;
    const float *q = in.q, *k = in.k, *v = in.v;
    int C = in.C, ld = in.ld, ldk = in.ldk, nkv = in.nkv;
    float *want = xmalloc(sizeof(float) * (size_t)c->nq * C), *got = xmalloc(sizeof(float) * (size_t)c->nq * C);
    fk_ctx *ref = test_ctx(FK_ISA_REF, 1);
    assert_int_equal(fk_attention(ref, &a, q, ld, c->nq, k, ldk, v, ldk, nkv, want, C), F4D_OK);
    fk_ctx_free(ref);
    enum fk_isa isas[4];
    int n_isa = test_isas(isas);
    float *one = xmalloc(sizeof(float) * (size_t)c->nq * C); /* threads 1's output */
    for (int i = 0; i < n_isa; i++)
        for (int threads = 1; threads <= 2; threads++) {
            fk_ctx *ctx = test_ctx(isas[i], threads);
            memset(got, 0xff, sizeof(float) * (size_t)c->nq * C);
            int st = fk_attention(ctx, &a, q, ld, c->nq, k, ldk, v, ldk, nkv, got, C);
            if (st != F4D_OK)
                fail_msg("%s", fk_ctx_error(ctx));
            double e = budget_ratio(got, want, (size_t)c->nq * C, 2e-5, 2e-5);
            if (e > 1.0)
                fail_msg("%s threads %d heads %d d %d nq %d nk %d rope %d norm %d: error %.3g of budget",
                         fk_isa_name(isas[i]), threads, c->heads, c->d, c->nq, nkv, c->rope, c->norm, e);
            /* the same bits for any thread count */
            if (threads == 1)
                memcpy(one, got, sizeof(float) * (size_t)c->nq * C);
            else if (memcmp(one, got, sizeof(float) * (size_t)c->nq * C) != 0)
                fail_msg("%s heads %d d %d nq %d nk %d: 2 threads differ from 1", fk_isa_name(isas[i]),
                         c->heads, c->d, c->nq, nkv);
            if (isas[i] == FK_ISA_AVX512) { /* the zmm block keeps the AVX2 pieces' bits */
                fk_ctx *x2 = test_ctx(FK_ISA_AVX2, threads);
                float *alt = xmalloc(sizeof(float) * (size_t)c->nq * C);
                assert_int_equal(fk_attention(x2, &a, q, ld, c->nq, k, ldk, v, ldk, nkv, alt, C), F4D_OK);
                for (size_t e2 = 0; e2 < (size_t)c->nq * C; e2++)
                    if (memcmp(&alt[e2], &got[e2], sizeof(float)) != 0)
                        fail_msg("avx512 vs avx2, heads %d d %d nq %d nk %d: element %zu %.9g vs %.9g",
                                 c->heads, c->d, c->nq, nkv, e2, got[e2], alt[e2]);
                free(alt);
                fk_ctx_free(x2);
            }
            fk_ctx_free(ctx);
        }
    free(one);
    free_inputs(&in);
    free(want); free(got);
}

static void test_vs_reference(void **state)
{
    (void)state;
    static const struct attn_case cases[] = {
        { 1, 16, 1, 1, 0, 0, 0 },   { 2, 16, 7, 7, 1, 1, 0 },    { 4, 16, 59, 59, 1, 1, 0 },
        { 3, 64, 131, 131, 1, 1, 0 }, { 2, 64, 200, 200, 0, 0, 0 }, { 2, 32, 16, 301, 0, 0, 1 },
        { 2, 64, 301, 16, 0, 1, 1 }, { 1, 128, 13, 5, 0, 0, 1 },  { 2, 8, 9, 11, 1, 1, 0 },
        { 1, 12, 5, 70, 1, 0, 1 },  { 2, 64, 65, 65, 1, 1, 0 },
        /* d = 48, 80: AVX-512's P V tile runs 32 columns, then a 16-column tail */
        { 2, 48, 70, 70, 1, 1, 0 }, { 1, 80, 29, 130, 0, 1, 0 },
        /* off the 16-wide tiles: the shipped model's 24 (4 views of 8x8 patches + 5 specials), 40 */
        { 4, 24, 276, 276, 1, 1, 0 }, { 2, 40, 37, 130, 0, 1, 1 }, { 3, 24, 69, 69, 1, 0, 0 },
    };
    for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++)
        run_case(&cases[i], 40 + i, 1.0f);
}

/* Logits of +-1e4: q and k scaled up so that q.k/sqrt(d) reaches ~1e4. */
static void test_huge_logits(void **state)
{
    (void)state;
    static const struct attn_case c = { 2, 16, 23, 23, 0, 0, 0 };
    run_case(&c, 7, 50.0f);
}

/* Exact expectations: one dominant key gives its value; equal logits give the mean. */
static void test_onehot_and_uniform(void **state)
{
    (void)state;
    enum fk_isa all[5] = { FK_ISA_REF };
    int n_isa = 1 + test_isas(all + 1);
    const int d = 16, nk = 37, nq = 3;
    float *q = xmalloc(sizeof(float) * nq * d), *k = xmalloc(sizeof(float) * nk * d);
    float *v = xmalloc(sizeof(float) * nk * d), *o = xmalloc(sizeof(float) * nq * d);
    for (int j = 0; j < nk; j++)
        for (int c = 0; c < d; c++)
            v[j * d + c] = (float)(j * 3 + c);
    /* query 0: key 20 has logit +1e4, the rest 0 or -1e4 */
    for (int c = 0; c < d; c++)
        q[c] = c == 0 ? 4e4f : 0;
    for (int j = 0; j < nk; j++)
        for (int c = 0; c < d; c++)
            k[j * d + c] = c == 0 ? (j == 20 ? 1.0f : (j % 2 ? -1.0f : 0.0f)) : 0.0f;
    /* queries 1, 2: all logits equal (zero query; then a huge but equal one) */
    for (int c = 0; c < d; c++) {
        q[d + c] = 0;
        q[2 * d + c] = c == 1 ? 1e4f : 0;
    }
    /* bf16 too: v (integers < 256), the one-hot and the equal p are exact;
     * int16: so are the q, k and p codes, v is within half a 12-bit code of
     * its column's largest |v| (126) */
    for (int a = 0; a < 3 * n_isa; a++) {
        fk_ctx *ctx = test_ctx(all[a / 3], 2);
        struct fk_attention_desc desc = { .heads = 1, .head_dim = d, .bf16 = a % 3 == 1, .int16 = a % 3 == 2 };
        double tol = fk_attention_products(ctx, &desc) == FK_ATTN_INT16 ? 126.0 / 8190 : 0;
        assert_int_equal(fk_attention(ctx, &desc, q, d, nq, k, d, v, d, nk, o, d), F4D_OK);
        for (int c = 0; c < d; c++) {
            assert_float_equal(o[c], v[20 * d + c], 1e-4 + tol);
            float mean = (float)((nk - 1) * 3) / 2.0f + (float)c;
            assert_float_equal(o[d + c], mean, 1e-3 + tol);
            assert_float_equal(o[2 * d + c], mean, 1e-3 + tol);
            assert_true(isfinite(o[c]) && isfinite(o[2 * d + c]));
        }
        fk_ctx_free(ctx);
    }
    free(q); free(k); free(v); free(o);
}

/* Logits that rise from key block to key block by 0.5 to 40 (log2 units)
 * per 64 keys, one rate per query: the fp32 running max stays while a
 * block's max is within FK_ATTN_SLACK (8) of it (p then reaches 2^8) and
 * moves past that, both in one run; against the reference, and AVX-512
 * giving the AVX2 bits. A rule that never moved the max would overflow p. */
static void test_rising_logits(void **state)
{
    (void)state;
    enum fk_isa isas[4];
    int n_isa = test_isas(isas);
    const int d = 16, nk = 300, nq = 10;
    static const float rate[5] = { 0.5f, 3.0f, 7.5f, 9.0f, 40.0f }; /* log2 units per block */
    struct rng r;
    rng_seed(&r, 11);
    float *q = xmalloc(sizeof(float) * nq * d), *k = xmalloc(sizeof(float) * nk * d);
    float *v = xmalloc(sizeof(float) * nk * d), *want = xmalloc(sizeof(float) * nq * d);
    float *got = xmalloc(sizeof(float) * nq * d), *alt = xmalloc(sizeof(float) * nq * d);
    rng_fill_normal(&r, q, (size_t)nq * d, 0.05f);
    rng_fill_normal(&r, k, (size_t)nk * d, 0.05f);
    rng_fill_normal(&r, v, (size_t)nk * d, 1.0f);
    /* logit of key j = q0 k0 / sqrt(d) (natural units) + small noise; k0 =
     * j / 64 rises by 1 per block; rows 5-9 run the keys backwards (the
     * first block holds the max) */
    for (int j = 0; j < nk; j++)
        k[j * d] = (float)j / 64.0f;
    for (int i = 0; i < nq; i++)
        q[i * d] = (i < 5 ? 1.0f : -1.0f) * rate[i % 5] * 4.0f / 1.44269504f;
    struct fk_attention_desc desc = { .heads = 1, .head_dim = d };
    fk_ctx *ref = test_ctx(FK_ISA_REF, 1);
    assert_int_equal(fk_attention(ref, &desc, q, d, nq, k, d, v, d, nk, want, d), F4D_OK);
    fk_ctx_free(ref);
    for (int i = 0; i < n_isa; i++) {
        fk_ctx *ctx = test_ctx(isas[i], 2);
        assert_int_equal(fk_attention(ctx, &desc, q, d, nq, k, d, v, d, nk, got, d), F4D_OK);
        double e = budget_ratio(got, want, (size_t)nq * d, 2e-5, 2e-5);
        if (e > 1.0)
            fail_msg("%s: error %.3g of budget", fk_isa_name(isas[i]), e);
        if (isas[i] == FK_ISA_AVX512) {
            fk_ctx *x2 = test_ctx(FK_ISA_AVX2, 2);
            assert_int_equal(fk_attention(x2, &desc, q, d, nq, k, d, v, d, nk, alt, d), F4D_OK);
            if (memcmp(alt, got, sizeof(float) * (size_t)nq * d) != 0)
                fail_msg("avx512 and avx2 differ on rising logits");
            fk_ctx_free(x2);
        }
        fk_ctx_free(ctx);
    }
    free(q); free(k); free(v); free(want); free(got); free(alt);
}

static void test_nonfinite(void **state)
{
    (void)state;
    enum fk_isa all[5] = { FK_ISA_REF };
    int n_isa = 1 + test_isas(all + 1);
    const int d = 16, n = 20, heads = 2, C = heads * d;
    struct rng r;
    rng_seed(&r, 5);
    float *q = xmalloc(sizeof(float) * n * C), *k = xmalloc(sizeof(float) * n * C);
    float *v = xmalloc(sizeof(float) * n * C), *o = xmalloc(sizeof(float) * n * C);
    rng_fill_normal(&r, q, (size_t)n * C, 1);
    rng_fill_normal(&r, k, (size_t)n * C, 1);
    rng_fill_normal(&r, v, (size_t)n * C, 1);
    q[3 * C + 2] = NAN;             /* query 3, head 0 */
    q[7 * C + d + 1] = INFINITY;    /* query 7, head 1 */
    /* fp32, bf16 (NaN and Inf survive rounding), int16 (the scales and l carry them) */
    for (int a = 0; a < 3 * n_isa; a++) {
        fk_ctx *ctx = test_ctx(all[a / 3], 1);
        struct fk_attention_desc desc = { .heads = heads, .head_dim = d, .bf16 = a % 3 == 1, .int16 = a % 3 == 2 };
        assert_int_equal(fk_attention(ctx, &desc, q, C, n, k, C, v, C, n, o, C), F4D_OK);
        for (int i = 0; i < n; i++)
            for (int h = 0; h < heads; h++) {
                int bad = (i == 3 && h == 0) || (i == 7 && h == 1);
                for (int c = 0; c < d; c++) {
                    float x = o[i * C + h * d + c];
                    if (bad && i == 3)
                        assert_true(isnan(x));
                    else if (!bad && !isfinite(x))
                        fail_msg("%s mode %d: finite query %d head %d became %g", fk_isa_name(all[a / 3]), a % 3, i, h, x);
                }
            }
        /* a NaN value row poisons every query that attends to it */
        v[5 * C + 3] = NAN;
        assert_int_equal(fk_attention(ctx, &desc, q, C, n, k, C, v, C, n, o, C), F4D_OK);
        for (int i = 0; i < n; i++)
            assert_true(isnan(o[i * C + 3]));
        v[5 * C + 3] = 0;
        fk_ctx_free(ctx);
    }
    free(q); free(k); free(v); free(o);
}

static void test_bad_arguments(void **state)
{
    (void)state;
    fk_ctx *ctx = test_ctx(FK_ISA_AUTO, 1);
    float x[64] = { 0 }, o[64];
    int32_t pos[8] = { 0 };
    struct fk_attention_desc a = { .heads = 2, .head_dim = 8 };
    assert_int_equal(fk_attention(ctx, NULL, x, 16, 2, x, 16, x, 16, 2, o, 16), F4D_EINVAL);
    assert_int_equal(fk_attention(ctx, &a, x, 16, 2, x, 16, x, 16, 2, o, 15), F4D_EINVAL);
    assert_non_null(strstr(fk_ctx_error(ctx), "stride"));
    assert_int_equal(fk_attention(ctx, &a, x, 16, 2, x, 16, x, 16, 0, o, 16), F4D_EINVAL);
    assert_non_null(strstr(fk_ctx_error(ctx), "no keys"));
    assert_int_equal(fk_attention(ctx, &a, x, 16, 0, x, 16, x, 16, 0, o, 16), F4D_OK);
    assert_int_equal(fk_attention(ctx, &a, x, 16, -1, x, 16, x, 16, 2, o, 16), F4D_EINVAL);
    assert_int_equal(fk_attention(ctx, &a, NULL, 16, 2, x, 16, x, 16, 2, o, 16), F4D_EINVAL);
    assert_int_equal(fk_attention(ctx, &a, x, 16, 2, x, 16, x, 16, 2, x + 4, 16), F4D_EINVAL);
    assert_non_null(strstr(fk_ctx_error(ctx), "overlap"));
    struct fk_attention_desc odd = { .heads = 1, .head_dim = 7 };
    assert_int_equal(fk_attention(ctx, &odd, x, 16, 2, x, 16, x, 16, 2, o, 16), F4D_EINVAL);
    struct fk_attention_desc half_rope = { .heads = 2, .head_dim = 8, .pos_q = pos };
    assert_int_equal(fk_attention(ctx, &half_rope, x, 16, 2, x, 16, x, 16, 2, o, 16), F4D_EINVAL);
    struct fk_attention_desc rope6 = { .heads = 1, .head_dim = 6, .pos_q = pos, .pos_k = pos };
    assert_int_equal(fk_attention(ctx, &rope6, x, 16, 2, x, 16, x, 16, 2, o, 16), F4D_EINVAL);
    struct fk_attention_desc noeps = { .heads = 2, .head_dim = 8, .qk_norm = 1 };
    assert_int_equal(fk_attention(ctx, &noeps, x, 16, 2, x, 16, x, 16, 2, o, 16), F4D_EINVAL);
    assert_non_null(strstr(fk_ctx_error(ctx), "eps"));
    struct fk_attention_desc badscale = { .heads = 2, .head_dim = 8, .scale = NAN };
    assert_int_equal(fk_attention(ctx, &badscale, x, 16, 2, x, 16, x, 16, 2, o, 16), F4D_EINVAL);
    fk_ctx_free(ctx);
}

/* RoPE reference: the (0,0) position is the identity; rotations preserve
 * each pair's norm; y rotates the first half and x the second. */
static void test_rope_reference(void **state)
{
    (void)state;
    float t[16], u[16];
    for (int i = 0; i < 16; i++)
        t[i] = u[i] = (float)(i + 1);
    fk_rope2d_ref(u, 16, 0, 0, 100.0f);
    assert_memory_equal(t, u, sizeof t);
    fk_rope2d_ref(u, 16, 3, 0, 100.0f);
    for (int i = 8; i < 16; i++)
        assert_true(u[i] == t[i]); /* x = 0 leaves the second half */
    for (int kk = 0; kk < 4; kk++) {
        float n0 = t[kk] * t[kk] + t[kk + 4] * t[kk + 4], n1 = u[kk] * u[kk] + u[kk + 4] * u[kk + 4];
        assert_float_equal(n0, n1, 1e-4 * n0);
    }
    /* k = 0 frequency is 1: angle = position */
    assert_float_equal(u[0], t[0] * cosf(3.0f) - t[4] * sinf(3.0f), 1e-5);
}

/* ---- bf16 products (desc.bf16) ----
 *
 * Where the context has AVX512_BF16 the q.k and p.v products take bf16
 * inputs (8-bit significands: each rounding is within 2^-9 relative) with
 * fp32 sums. The error budget follows from those roundings:
 *   - v rounded: at most 2^-9 |v| per term, so 2^-9 max|v| on the output;
 *   - p rounded (and l summed from the rounded p): the weights move by at
 *     most 2^-8 relative, so 2^-8 max|v| on the output;
 *   - q and k rounded: each logit moves by up to 2^-8 sum_i |q_i k_i| scale
 *     (log2 e in the exp2 domain), which moves the weights by a factor
 *     within 2^(+-2 delta), so about 1.4 delta max|v| for delta <= 0.1.
 * The worst-case budget is |out - ref| <= (2^-7 + 2 delta_max) max|v| per
 * element, with delta_max the largest logit bound over the head's rows
 * (computed below from q and k as the kernel sees them: after LayerNorm and
 * RoPE). It is loose (measured 0-5 % of it), so a statistical one holds the
 * kernel too: the roundings are independent, each within 2^-9 relative, so
 * the RMS error stays a few 2^-9 of the output's RMS: within 2^-7 for unit
 * logits (measured 1.4e-3 to 4.5e-3), 2^-6 for std-3 logits (7.9e-3); a 1 %
 * drift of the rescaling per 256-key block fails it (1.0e-2 to 3.2e-2).
 * Contexts without AVX512_BF16 (and every other ISA, and the reference)
 * ignore the field: the same bits as bf16 = 0. */
struct bf16_err {
    double ratio, max_abs, bound;
};

/* Head h's n vectors of x (row stride ld) as the kernel sees them (q/k
 * LayerNorm, RoPE), into out[n][d]: prepared once, not once per pair. */
static void prep_head(const struct fk_attention_desc *a, int which, const float *x, int ld, int n,
                      int h, float *out)
{
    int d = a->head_dim;
    const int32_t *pos = which == 0 ? a->pos_q : a->pos_k;
    for (int i = 0; i < n; i++)
        fk__attn_prep_ref(a, which, x + (size_t)i * ld + h * d, pos ? pos + 2 * i : NULL, 1.0f,
                          out + (size_t)i * d);
}

/* max over rows and heads of 2^-8 scale log2(e) sum_i |q'_i k'_i| for the
 * worst key, with q', k' as the kernel sees them */
static double logit_bound(const struct fk_attention_desc *a, const float *q, int ldq, int nq,
                          const float *k, int ldk, int nk)
{
    int d = a->head_dim;
    float *qs = xmalloc(sizeof(float) * (size_t)nq * d), *ks = xmalloc(sizeof(float) * (size_t)nk * d);
    double worst = 0, scale = a->scale > 0 ? a->scale : 1.0 / sqrt((double)d);
    for (int h = 0; h < a->heads; h++) {
        prep_head(a, 0, q, ldq, nq, h, qs);
        prep_head(a, 1, k, ldk, nk, h, ks);
        for (int i = 0; i < nq; i++)
            for (int jj = 0; jj < nk; jj++) {
                double s = 0;
                for (int c = 0; c < d; c++)
                    s += fabs((double)qs[(size_t)i * d + c] * ks[(size_t)jj * d + c]);
                worst = s > worst ? s : worst;
            }
    }
    free(qs); free(ks);
    return worst * scale * 1.4426950408889634 / 256.0;
}

/* ---- int16 products (desc.int16) ----
 *
 * Where the context runs int16 attention (AVX2 without VNNI) q, k, v and p
 * are integer codes with exact int32 sums. The worst-case budget follows
 * from the codes, as bf16's from its roundings:
 *   - v: 12-bit codes of each column and 64-key block, within half a code
 *     (2^-13 of the column's max |v|): 2^-12 max|v| on the output;
 *   - p: codes round(4096 p / block max), l summing the codes: each block's
 *     64 weights move by at most 32 codes against its >= 4096, so the
 *     weights move by at most 2^-7 of their sum: 2^-6 max|v|;
 *   - q, k: b-bit codes per query / key (qmax = 2^b - 1, b = 12 at d 64),
 *     within half a code of the row's max |x|: a logit moves by at most
 *     delta = scale log2(e) (Mq sum|k| + Mk sum|q|) / (2 qmax) + d Mq Mk /
 *     (4 qmax^2), the weights by a factor within 2^(+-2 delta): 2 delta
 *     max|v| (delta <= 0.1), with the max over the head's rows and keys.
 * Statistically the codes' errors are independent and far below bf16's
 * 2^-9 relative (measured in test_int16), so the same RMS budgets hold. */
static double qk_code_max(int d)
{
    int dp = (d + 15) / 16 * 16, lg = 0;
    while ((1 << lg) < dp)
        lg++;
    int b = (30 - lg) / 2;
    return (double)((1 << (b > 14 ? 14 : b)) - 1);
}

/* max |x_c| and sum |x_c| of x[d] */
static void abs_max_sum(const float *x, int d, double *mx, double *sum)
{
    *mx = *sum = 0;
    for (int c = 0; c < d; c++) {
        *mx = fmax(*mx, fabs((double)x[c]));
        *sum += fabs((double)x[c]);
    }
}

static double logit_bound_i16(const struct fk_attention_desc *a, const float *q, int ldq, int nq,
                              const float *k, int ldk, int nk)
{
    int d = a->head_dim;
    float *qs = xmalloc(sizeof(float) * (size_t)nq * d), *ks = xmalloc(sizeof(float) * (size_t)nk * d);
    double *mk = xmalloc(sizeof(double) * (size_t)nk), *sk = xmalloc(sizeof(double) * (size_t)nk);
    double worst = 0, scale = a->scale > 0 ? a->scale : 1.0 / sqrt((double)d), qmax = qk_code_max(d);
    for (int h = 0; h < a->heads; h++) {
        prep_head(a, 0, q, ldq, nq, h, qs);
        prep_head(a, 1, k, ldk, nk, h, ks);
        for (int jj = 0; jj < nk; jj++)
            abs_max_sum(ks + (size_t)jj * d, d, &mk[jj], &sk[jj]);
        for (int i = 0; i < nq; i++) {
            double mq, sq;
            abs_max_sum(qs + (size_t)i * d, d, &mq, &sq);
            for (int jj = 0; jj < nk; jj++) {
                double e = (mq * sk[jj] + mk[jj] * sq) / (2 * qmax) + d * mq * mk[jj] / (4 * qmax * qmax);
                worst = e > worst ? e : worst;
            }
        }
    }
    free(qs); free(ks); free(mk); free(sk);
    return worst * scale * 1.4426950408889634;
}

enum lowp { LOWP_BF16, LOWP_INT16 };

/* One case with desc.bf16 or desc.int16 = 1 on every ISA under test: within
 * the budget where the context runs that mode, the fp32 bits elsewhere.
 * Returns how many contexts ran it. */
static int run_lowp_case(enum lowp mode, const struct attn_case *c, uint64_t seed, float logit_scale,
                         double rms_budget)
{
    const char *name = mode == LOWP_BF16 ? "bf16" : "int16";
    struct attn_inputs in;
    make_inputs(c, seed, logit_scale, 37, 0, &in);
    struct fk_attention_desc a = in.a;
    const float *q = in.q, *k = in.k, *v = in.v;
    int C = in.C, ld = in.ld, ldk = in.ldk, nkv = in.nkv;
    size_t n_out = (size_t)c->nq * C;
    float *want = xmalloc(sizeof(float) * n_out), *f32 = xmalloc(sizeof(float) * n_out);
    float *got = xmalloc(sizeof(float) * n_out), *one = xmalloc(sizeof(float) * n_out);
    fk_ctx *ref = test_ctx(FK_ISA_REF, 1);
    assert_int_equal(fk_attention(ref, &a, q, ld, c->nq, k, ldk, v, ldk, nkv, want, C), F4D_OK);
    fk_ctx_free(ref);
    double vmax = 0;
    for (int t = 0; t < nkv; t++)
        for (int e = 0; e < C; e++)
            vmax = fmax(vmax, fabs((double)v[(size_t)t * ldk + e]));
    double delta = mode == LOWP_BF16 ? logit_bound(&a, q, ld, c->nq, k, ldk, nkv)
                                     : logit_bound_i16(&a, q, ld, c->nq, k, ldk, nkv);
    double bound = (mode == LOWP_BF16 ? 1.0 / 128 : 1.0 / 64 + 1.0 / 4096) * vmax + 2 * delta * vmax;
    enum fk_isa all[5] = { FK_ISA_REF };
    int n_isa = 1 + test_isas(all + 1), ran = 0;
    for (int i = 0; i < n_isa; i++)
        for (int threads = 1; threads <= 2; threads++) {
            fk_ctx *ctx = test_ctx(all[i], threads);
            a.bf16 = a.int16 = 0;
            assert_int_equal(fk_attention(ctx, &a, q, ld, c->nq, k, ldk, v, ldk, nkv, f32, C), F4D_OK);
            a.bf16 = mode == LOWP_BF16;
            a.int16 = mode == LOWP_INT16;
            memset(got, 0xff, sizeof(float) * n_out);
            if (fk_attention(ctx, &a, q, ld, c->nq, k, ldk, v, ldk, nkv, got, C) != F4D_OK)
                fail_msg("%s", fk_ctx_error(ctx));
            if (fk_attention_products(ctx, &a) != (mode == LOWP_BF16 ? FK_ATTN_BF16 : FK_ATTN_INT16)) {
                assert_memory_equal(got, f32, sizeof(float) * n_out);
            } else {
                double e = max_abs_diff(got, want, n_out), e32 = max_abs_diff(f32, want, n_out);
                double se = 0, so = 0;
                for (size_t x = 0; x < n_out; x++) {
                    se += ((double)got[x] - want[x]) * ((double)got[x] - want[x]);
                    so += (double)want[x] * want[x];
                }
                double rms = sqrt(se / so);
                if (rms_budget > 0 && !(rms <= rms_budget))
                    fail_msg("%s threads %d heads %d d %d nq %d nk %d: RMS error %.3g of the output's > %.3g",
                             name, threads, c->heads, c->d, c->nq, nkv, rms, rms_budget);
                if (!(e <= bound))
                    fail_msg("%s threads %d heads %d d %d nq %d nk %d scale %g: max |err| %.3g > "
                             "budget %.3g (max|v| %.3g, logit bound %.3g)",
                             name, threads, c->heads, c->d, c->nq, nkv, logit_scale, e, bound, vmax, delta);
                if (threads == 1) {
                    print_message("%s heads %d d %d nq %d nk %d scale %g: max |err| %.3g (fp32 %.3g), "
                                  "budget %.3g = %.2f of it; RMS err / RMS(out) %.3g\n", name, c->heads, c->d,
                                  c->nq, nkv, logit_scale, e, e32, bound, e / bound, rms);
                    memcpy(one, got, sizeof(float) * n_out);
                } else if (memcmp(one, got, sizeof(float) * n_out) != 0) {
                    fail_msg("%s heads %d d %d nq %d nk %d: 2 threads differ from 1", name, c->heads, c->d,
                             c->nq, nkv);
                }
                ran++;
            }
            fk_ctx_free(ctx);
        }
    /* AVX-512 without bf16 attention (Intel's default) runs int16's products
     * in zmm with vpdpwssd, AVX2-VNNI in ymm with VEX vpdpwssd: AVX2's bits
     * exactly, 1 and 2 threads */
    for (int i = 0; mode == LOWP_INT16 && i < n_isa; i++) {
        if (all[i] != FK_ISA_AVX512 && all[i] != FK_ISA_AVX2_VNNI)
            continue;
        for (int threads = 1; threads <= 2; threads++) {
            fk_ctx *z = NULL, *x2 = test_ctx(FK_ISA_AVX2, threads);
            struct fk_ctx_config cfg = { .isa = all[i], .threads = threads, .bf16 = FK_BF16_OFF };
            assert_int_equal(fk_ctx_new(&cfg, &z), F4D_OK);
            assert_true(fk_ctx_has_int16(z) && !fk_ctx_has_bf16(z));
            a.bf16 = 0;
            a.int16 = 1;
            /* AVX-512 from 64-dim heads (fk_attention_products); fp32 below */
            assert_int_equal(fk_attention_products(z, &a),
                             a.head_dim > 48 || all[i] != FK_ISA_AVX512 ? FK_ATTN_INT16 : FK_ATTN_F32);
            if (fk_attention_products(z, &a) != FK_ATTN_INT16) {
                fk_ctx_free(z);
                fk_ctx_free(x2);
                continue;
            }
            memset(got, 0xff, sizeof(float) * n_out);
            memset(one, 0, sizeof(float) * n_out);
            assert_int_equal(fk_attention(z, &a, q, ld, c->nq, k, ldk, v, ldk, nkv, got, C), F4D_OK);
            assert_int_equal(fk_attention(x2, &a, q, ld, c->nq, k, ldk, v, ldk, nkv, one, C), F4D_OK);
            if (memcmp(got, one, sizeof(float) * n_out) != 0)
                fail_msg("int16 %s (vpdpwssd) threads %d heads %d d %d nq %d nk %d: not AVX2's bits",
                         fk_isa_name(all[i]), threads, c->heads, c->d, c->nq, nkv);
            ran++;
            fk_ctx_free(z);
            fk_ctx_free(x2);
        }
    }
    free_inputs(&in);
    free(want); free(f32); free(got); free(one);
    return ran;
}

/* The low-precision cases, on every ISA under test: the model's shapes and
 * padded ones at unit logits (RMS budget rms_unit), raw std-3 logits
 * (rms_big) and +-1e4 logits (one-hot rows: the max bound only). Returns
 * how many contexts ran the mode. */
static int run_lowp_suite(enum lowp mode, double rms_unit, double rms_big)
{
    static const struct attn_case cases[] = {
        { 2, 64, 131, 131, 1, 1, 0 }, { 4, 24, 276, 276, 1, 1, 0 }, { 2, 48, 70, 70, 1, 1, 0 },
        { 1, 80, 29, 130, 0, 1, 0 }, { 2, 32, 16, 301, 0, 0, 1 },  { 1, 16, 1, 1, 0, 0, 0 },
        { 2, 40, 37, 130, 0, 1, 1 },
        /* long rows: one global block's 5496 keys */
        { 1, 64, 13, 5496, 1, 1, 1 },
    };
    int ran = 0;
    for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++)
        ran += run_lowp_case(mode, &cases[i], 70 + i, 1.0f, rms_unit);
    static const struct attn_case big = { 2, 64, 50, 300, 0, 0, 1 };
    ran += run_lowp_case(mode, &big, 9, 3.0f, rms_big);
    static const struct attn_case huge = { 2, 16, 23, 23, 0, 0, 0 };
    ran += run_lowp_case(mode, &huge, 7, 50.0f, 0);
    return ran;
}

static int isa_under_test(enum fk_isa isa)
{
    enum fk_isa isas[4];
    int n_isa = test_isas(isas), found = 0;
    for (int i = 0; i < n_isa; i++)
        found |= isas[i] == isa;
    return found;
}

static void test_bf16(void **state)
{
    (void)state;
    int ran = run_lowp_suite(LOWP_BF16, 1.0 / 128, 1.0 / 64);
    /* the AVX-512 run is where bf16 runs: without AVX512_BF16 it checked
     * only the fp32 fallback, so it says so; other ISAs never run bf16 */
    if (isa_under_test(FK_ISA_AVX512) && !ran)
        f4d_skip("the CPU has AVX-512 but no AVX512_BF16: only bf16 = 1 giving the fp32 bits was checked");
}

/* RMS budgets a quarter of bf16's: measured 4.6e-4 to 6.2e-4 of the
 * output's RMS for unit logits, 8.8e-4 for std-3 logits (bf16: 1.4e-3 to
 * 7.9e-3). int16 runs on the AVX2 context (every x86-64 CPU here has it);
 * the other ISAs' runs check that int16 = 1 gives their fp32 bits, which
 * is all there is to check on them. */
static void test_int16(void **state)
{
    (void)state;
    int ran = run_lowp_suite(LOWP_INT16, 1.0 / 512, 1.0 / 256);
    if (isa_under_test(FK_ISA_AVX2) && !ran)
        fail_msg("the AVX2 context ran no int16 case");
}

int main(int argc, char **argv)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_vs_reference),
        cmocka_unit_test(test_huge_logits),
        cmocka_unit_test(test_onehot_and_uniform),
        cmocka_unit_test(test_rising_logits),
        cmocka_unit_test(test_nonfinite),
        cmocka_unit_test(test_rope_reference),
        cmocka_unit_test(test_bad_arguments),
        cmocka_unit_test(test_bf16),
        cmocka_unit_test(test_int16),
    };
    return KERNEL_TEST_MAIN(argc, argv, "kernels/attention", tests);
}
