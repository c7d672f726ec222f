/* attention_avx2.c - the AVX2/FMA pieces of multi-head attention with an
 * online softmax: q/k LayerNorm and RoPE, the online softmax block and the
 * P V tile (S = Q K^T is the GEMM's 6x16 micro-kernel). The driver (head
 * grouping, packing, scratch, the parallel phases) is attention_plan.c. */
#include <float.h>
#include <immintrin.h>
#include <math.h>
#include <string.h>

#include "../attention_plan.h"
#include "../fk_internal.h"
#include "vecmath_avx2.h"
#include "x86.h"

#define MR FK_ATTN_MR
#define BK FK_ATTN_BK

/* ------------------------------------------------------------------- prep */

static inline __attribute__((always_inline)) void rope_apply_in(const struct fk__rope_table *rt, float *t, int d, const int32_t *pos)
{
    int m = d / 2, h = m / 2;
    for (int axis = 0; axis < 2; axis++) {
        float *u = t + axis * m;
        int p = pos[axis] - rt->lo;
        const float *c = rt->cos + (size_t)p * (size_t)h, *s = rt->sin + (size_t)p * (size_t)h;
        int kk = 0;
        for (; kk + 8 <= h; kk += 8) {
            __m256 a = _mm256_loadu_ps(u + kk), b = _mm256_loadu_ps(u + kk + h);
            __m256 cv = _mm256_loadu_ps(c + kk), sv = _mm256_loadu_ps(s + kk);
            _mm256_storeu_ps(u + kk, _mm256_fmsub_ps(a, cv, _mm256_mul_ps(b, sv)));
            _mm256_storeu_ps(u + kk + h, _mm256_fmadd_ps(b, cv, _mm256_mul_ps(a, sv)));
        }
        for (; kk < h; kk++) {
            float a = u[kk], b = u[kk + h];
            u[kk] = a * c[kk] - b * s[kk];
            u[kk + h] = b * c[kk] + a * s[kk];
        }
    }
}

static void rope_apply(const struct fk__rope_table *rt, float *t, int d, const int32_t *pos)
{
    rope_apply_in(rt, t, d, pos);
}

/* LayerNorm over d (a multiple of 8) in registers, from src to dst (which
 * may be src). */
static inline __attribute__((always_inline)) void head_norm_to(const float *src, float *dst, int d,
                                                               const float *w, const float *b, float eps)
{
    __m256 s = _mm256_setzero_ps();
    for (int i = 0; i < d; i += 8)
        s = _mm256_add_ps(s, _mm256_loadu_ps(src + i));
    __m256 mean = _mm256_set1_ps(fk__hsum_avx2(s) / (float)d), v = _mm256_setzero_ps();
    for (int i = 0; i < d; i += 8) {
        __m256 c = _mm256_sub_ps(_mm256_loadu_ps(src + i), mean);
        v = _mm256_fmadd_ps(c, c, v);
    }
    __m256 inv = _mm256_set1_ps(1.0f / sqrtf(fk__hsum_avx2(v) / (float)d + eps));
    for (int i = 0; i < d; i += 8) {
        __m256 x = _mm256_mul_ps(_mm256_sub_ps(_mm256_loadu_ps(src + i), mean), inv);
        if (w)
            x = _mm256_mul_ps(x, _mm256_loadu_ps(w + i));
        if (b)
            x = _mm256_add_ps(x, _mm256_loadu_ps(b + i));
        _mm256_storeu_ps(dst + i, x);
    }
}

static void head_norm(float *t, int d, const float *w, const float *b, float eps)
{
    head_norm_to(t, t, d, w, b, eps);
}

/* struct fk__attn_isa's prep_row: head_norm and rope_apply's operations in
 * their order (the same bits), read from the qkv row, with no copy and no
 * calls between (the copy and the two calls per token and head were a
 * quarter of phase 1's samples, 1374 tokens, Zen 5). */
static void prep_row(const struct fk__rope_table *rt, const float *src, float *dst, int d, int norm,
                     const float *w, const float *b, float eps, const int32_t *pos)
{
    if (norm)
        head_norm_to(src, dst, d, w, b, eps);
    else
        for (int i = 0; i < d; i += 8)
            _mm256_storeu_ps(dst + i, _mm256_loadu_ps(src + i));
    if (pos)
        rope_apply_in(rt, dst, d, pos);
}

/* struct fk__attn_isa's key_panel: kp[dp][kw] = t[kw][dp] transposed by
 * 8 x 8 blocks in registers (the scalar loop was a third of phase 1's own
 * samples, 1374 tokens, Zen 5). */
static void key_panel(const float *t, int dp, int kw, float *kp)
{
    for (int t0 = 0; t0 < kw; t0 += 8)
        for (int c0 = 0; c0 < dp; c0 += 8) {
            __m256 r[8], u[8], v[8];
            for (int i = 0; i < 8; i++)
                r[i] = _mm256_loadu_ps(t + (size_t)(t0 + i) * (size_t)dp + c0);
            for (int i = 0; i < 8; i += 2) {
                u[i] = _mm256_unpacklo_ps(r[i], r[i + 1]);
                u[i + 1] = _mm256_unpackhi_ps(r[i], r[i + 1]);
            }
            for (int i = 0; i < 8; i += 4) {
                v[i] = _mm256_shuffle_ps(u[i], u[i + 2], _MM_SHUFFLE(1, 0, 1, 0));
                v[i + 1] = _mm256_shuffle_ps(u[i], u[i + 2], _MM_SHUFFLE(3, 2, 3, 2));
                v[i + 2] = _mm256_shuffle_ps(u[i + 1], u[i + 3], _MM_SHUFFLE(1, 0, 1, 0));
                v[i + 3] = _mm256_shuffle_ps(u[i + 1], u[i + 3], _MM_SHUFFLE(3, 2, 3, 2));
            }
            /* v[0..3]: columns c0 .. c0 + 3 of rows t0 .. t0 + 3 (low) and + 4 .. 7
             * of the same rows (high); v[4..7] the same for rows t0 + 4 .. t0 + 7 */
            for (int i = 0; i < 4; i++) {
                _mm256_storeu_ps(kp + (size_t)(c0 + i) * kw + t0, _mm256_permute2f128_ps(v[i], v[i + 4], 0x20));
                _mm256_storeu_ps(kp + (size_t)(c0 + i + 4) * kw + t0, _mm256_permute2f128_ps(v[i], v[i + 4], 0x31));
            }
        }
}

/* -------------------------------------------------------------- the tiles */

/* The tile stays out of line: inlined into the task loop GCC spills. */

/* o[6][d] = alpha[r] o[r] + p[6][0, kv) . v[0, kv)[d] */
__attribute__((noinline)) static void pv_tile(int d, int kv, const float *p, const float *v, float *o,
                                              const float *alpha)
{
    for (int c0 = 0; c0 < d; c0 += 16) {
        float *oc = o + c0;
        __m256 a, c00, c01, c10, c11, c20, c21, c30, c31, c40, c41, c50, c51;
        a = _mm256_set1_ps(alpha[0]); c00 = _mm256_mul_ps(a, _mm256_load_ps(oc + 0 * d)); c01 = _mm256_mul_ps(a, _mm256_load_ps(oc + 0 * d + 8));
        a = _mm256_set1_ps(alpha[1]); c10 = _mm256_mul_ps(a, _mm256_load_ps(oc + 1 * d)); c11 = _mm256_mul_ps(a, _mm256_load_ps(oc + 1 * d + 8));
        a = _mm256_set1_ps(alpha[2]); c20 = _mm256_mul_ps(a, _mm256_load_ps(oc + 2 * d)); c21 = _mm256_mul_ps(a, _mm256_load_ps(oc + 2 * d + 8));
        a = _mm256_set1_ps(alpha[3]); c30 = _mm256_mul_ps(a, _mm256_load_ps(oc + 3 * d)); c31 = _mm256_mul_ps(a, _mm256_load_ps(oc + 3 * d + 8));
        a = _mm256_set1_ps(alpha[4]); c40 = _mm256_mul_ps(a, _mm256_load_ps(oc + 4 * d)); c41 = _mm256_mul_ps(a, _mm256_load_ps(oc + 4 * d + 8));
        a = _mm256_set1_ps(alpha[5]); c50 = _mm256_mul_ps(a, _mm256_load_ps(oc + 5 * d)); c51 = _mm256_mul_ps(a, _mm256_load_ps(oc + 5 * d + 8));
        const float *vr = v + c0;
        for (int jj = 0; jj < kv; jj++) {
            __m256 b0 = _mm256_load_ps(vr), b1 = _mm256_load_ps(vr + 8), t;
            t = _mm256_broadcast_ss(p + 0 * BK + jj); c00 = _mm256_fmadd_ps(t, b0, c00); c01 = _mm256_fmadd_ps(t, b1, c01);
            t = _mm256_broadcast_ss(p + 1 * BK + jj); c10 = _mm256_fmadd_ps(t, b0, c10); c11 = _mm256_fmadd_ps(t, b1, c11);
            t = _mm256_broadcast_ss(p + 2 * BK + jj); c20 = _mm256_fmadd_ps(t, b0, c20); c21 = _mm256_fmadd_ps(t, b1, c21);
            t = _mm256_broadcast_ss(p + 3 * BK + jj); c30 = _mm256_fmadd_ps(t, b0, c30); c31 = _mm256_fmadd_ps(t, b1, c31);
            t = _mm256_broadcast_ss(p + 4 * BK + jj); c40 = _mm256_fmadd_ps(t, b0, c40); c41 = _mm256_fmadd_ps(t, b1, c41);
            t = _mm256_broadcast_ss(p + 5 * BK + jj); c50 = _mm256_fmadd_ps(t, b0, c50); c51 = _mm256_fmadd_ps(t, b1, c51);
            vr += d;
        }
        _mm256_store_ps(oc + 0 * d, c00); _mm256_store_ps(oc + 0 * d + 8, c01);
        _mm256_store_ps(oc + 1 * d, c10); _mm256_store_ps(oc + 1 * d + 8, c11);
        _mm256_store_ps(oc + 2 * d, c20); _mm256_store_ps(oc + 2 * d + 8, c21);
        _mm256_store_ps(oc + 3 * d, c30); _mm256_store_ps(oc + 3 * d + 8, c31);
        _mm256_store_ps(oc + 4 * d, c40); _mm256_store_ps(oc + 4 * d + 8, c41);
        _mm256_store_ps(oc + 5 * d, c50); _mm256_store_ps(oc + 5 * d + 8, c51);
    }
}

/* The first pass of the online softmax, the six rows at once in registers
 * (lanes 0-5; lanes 6 and 7 of m_old and m_new are 0): bmax = the rows'
 * block maxima, m_old = m, m_new = bmax where bmax > m + slack, else m (NaN:
 * no move). Six serial reductions and scalar updates were a dependent chain
 * (1.4 % of the 7-bit forward's samples, Zen 5). */
static inline __attribute__((always_inline)) void rowmax6(float *s, int valid, const float *m, float slack,
                                                          __m256 *bmax, __m256 *m_old, __m256 *m_new)
{
    __m256 red[MR];
    for (int r = 0; r < MR; r++) {
        float *sr = s + r * BK;
        for (int jj = valid; jj < BK; jj++)
            sr[jj] = -INFINITY;
        __m256 mx = _mm256_loadu_ps(sr);
        for (int jj = 8; jj < BK; jj += 8)
            mx = _mm256_max_ps(mx, _mm256_loadu_ps(sr + jj));
        red[r] = mx;
    }
    const __m256i six = _mm256_setr_epi32(-1, -1, -1, -1, -1, -1, 0, 0);
    __m256 bm = fk__hmax6_avx2(red), mo = _mm256_maskload_ps(m, six);
    __m256 grow = _mm256_and_ps(_mm256_castsi256_ps(six),
                                _mm256_cmp_ps(bm, _mm256_add_ps(mo, _mm256_set1_ps(slack)), _CMP_GT_OQ));
    *bmax = bm;
    *m_old = mo;
    *m_new = _mm256_blendv_ps(mo, bm, grow);
}

/* Whole 8-lane stores, lanes 6 and 7 zero: masked stores do not forward to
 * the caller's loads that follow. */
void fk__attn_rowmax_avx2(float *s, int valid, const float *m, float slack, float *bmax,
                          float *m_old, float *m_new)
{
    const __m256i six = _mm256_setr_epi32(-1, -1, -1, -1, -1, -1, 0, 0);
    __m256 bm, mo, mn;
    rowmax6(s, valid, m, slack, &bm, &mo, &mn);
    _mm256_storeu_ps(bmax, _mm256_and_ps(bm, _mm256_castsi256_ps(six)));
    _mm256_storeu_ps(m_old, mo);
    _mm256_storeu_ps(m_new, mn);
}

/* Online softmax over one 6 x BK block of log2-domain logits, in place:
 * m_new by rowmax6 with FK_ATTN_SLACK; s becomes p = 2^(s - m_new); alpha =
 * 2^(m_old - m_new); l = alpha l + sum p. The maxima stay in registers: read
 * back through memory after masked stores (which do not forward to loads)
 * they cost 3-7 % of this function (Zen 4, in L1). */
__attribute__((noinline)) static void softmax_block(float *s, int valid, float *m, float *l, float *alpha)
{
    __m256 bm, mo, mn;
    rowmax6(s, valid, m, FK_ATTN_SLACK, &bm, &mo, &mn);
    (void)bm;
    /* all six rescale factors in one vector */
    __m256 al = fk__exp2_softmax_avx2(_mm256_sub_ps(mo, mn));
    _mm256_store_ps(alpha, al);
    __m256 sum[MR];
    for (int r = 0; r < MR; r++) {
        float *sr = s + r * BK;
        __m256 mv = _mm256_permutevar8x32_ps(mn, _mm256_set1_epi32(r));
        sum[r] = _mm256_setzero_ps();
        for (int jj = 0; jj < BK; jj += 8) {
            __m256 p = fk__exp2_softmax_avx2(_mm256_sub_ps(_mm256_load_ps(sr + jj), mv));
            _mm256_store_ps(sr + jj, p);
            sum[r] = _mm256_add_ps(sum[r], p);
        }
    }
    /* l = l alpha + sum p, the six rows at once (a multiply, then an add) */
    const __m256i six = _mm256_setr_epi32(-1, -1, -1, -1, -1, -1, 0, 0);
    _mm256_maskstore_ps(l, six, _mm256_add_ps(_mm256_mul_ps(_mm256_maskload_ps(l, six), al), fk__hsum6_avx2(sum)));
    _mm256_maskstore_ps(m, six, mn);
}

static const struct fk__attn_isa attn_avx2 = {
    head_norm, rope_apply, fk__ukr_f32_6x16, softmax_block, pv_tile, NULL, prep_row, key_panel,
};

/* AVX-512: the per-pair work in zmm, one call per panel and key block
 * (attention_avx512.c), the per-token prep as above. */
static const struct fk__attn_isa attn_avx512 = {
    head_norm, rope_apply, fk__ukr_f32_6x16, softmax_block, pv_tile, fk__attn_block_avx512, prep_row,
    key_panel,
};

int fk__attention_avx2(fk_ctx *ctx, const struct fk_attention_desc *a, const float *q, int ldq,
                       int nq, const float *k, int ldk, const float *v, int ldv, int nk,
                       float *out, int ldo)
{
    const struct fk__attn_isa *isa = ctx->isa == FK_ISA_AVX512 ? &attn_avx512 : &attn_avx2;
    return fk__attention_plan_run(isa, ctx, a, q, ldq, nq, k, ldk, v, ldv, nk, out, ldo);
}
