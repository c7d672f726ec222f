/* linear.c - fk_linear: weight packing, the scalar reference GEMM and the
 * front end that validates arguments and dispatches on the context's ISA. */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "../fk_linear.h"
#include "../fk_ops.h"
#include "fk_internal.h"
#include "gemm.h"

/* Symmetric quantization of a row to codes in [-qmax, qmax]. */
static float quantize_row_qmax(const float *w, int k, int8_t *q, int qmax)
{
    float amax = 0, poison = 0;
    if (k <= 0)
        return 0;
    for (int i = 0; i < k; i++) {
        poison += w[i] * 0.0f; /* NaN as soon as one value is Inf or NaN */
        float a = fabsf(w[i]);
        if (a > amax)
            amax = a;
    }
    if (amax < FK_Q8_AMAX_MIN || poison != 0) {
        memset(q, 0, (size_t)k);
        return poison == 0 ? 0.0f : NAN;
    }
    float fq = (float)qmax, inv = fq / amax;
    for (int i = 0; i < k; i++) {
        float r = nearbyintf(w[i] * inv);
        q[i] = (int8_t)(r > fq ? fq : r < -fq ? -fq : r);
    }
    return amax / fq;
}

float fk_quantize_row_q8(const float *w, int k, int8_t *q)
{
    return quantize_row_qmax(w, k, q, 127);
}

/* Largest |q[2i]| + |q[2i+1]| of a row of codes (k odd: the last one alone). */
static int pair_max(const int8_t *q, int k)
{
    int pm = 0;
    for (int i = 0; i < k; i += 2) {
        int s = abs(q[i]) + (i + 1 < k ? abs(q[i + 1]) : 0);
        pm = s > pm ? s : pm;
    }
    return pm;
}

/* Codes for the 7-bit path (CPUs without VNNI): the int16 pair budget of
 * vpmaddubsw, spent per pair. With u8 activations up to 255, a pair sum
 * a0 q0 + a1 q1 stays exact while |q0| + |q1| <= 128 (255 * 128 = 32640 <=
 * 32767), the bound two 7-bit codes (|q| <= 63) meet with room. The scale
 * puts the row's largest pair |w0| + |w1| at 127: rounding adds at most 1/2
 * to each code, so every pair of codes sums to <= 128, and single codes stay
 * in [-127, 127]; a row's weights are resolved between 1x and 2x the 8-bit
 * step (7-bit codes would be 2x everywhere). Pairs are (k even, k odd), as
 * the packed [k4][16][4] layout hands them to vpmaddubsw. */
static float quantize_row_pairs(const float *w, int k, int8_t *q)
{
    float pmax = 0, poison = 0;
    if (k <= 0)
        return 0;
    for (int i = 0; i < k; i += 2) {
        float a = fabsf(w[i]), b = i + 1 < k ? fabsf(w[i + 1]) : 0.0f;
        poison += w[i] * 0.0f + (i + 1 < k ? w[i + 1] * 0.0f : 0.0f);
        pmax = a + b > pmax ? a + b : pmax;
    }
    if (pmax == 0 || poison != 0) {
        memset(q, 0, (size_t)k);
        return pmax == 0 && poison == 0 ? 0.0f : NAN;
    }
    float inv = 127.0f / pmax;
    for (int i = 0; i < k; i++) {
        float r = nearbyintf(w[i] * inv);
        q[i] = (int8_t)(r > 127 ? 127 : r < -127 ? -127 : r);
    }
    return pmax / 127.0f;
}

/* ---------------------------------------------------------------- packing */

static int pack_alloc(fk_ctx *ctx, struct fk_linear *L, enum fk_wtype as, int n, int k,
                      const float *bias)
{
    memset(L, 0, sizeof *L);
    if (n <= 0 || k <= 0)
        return FK_FAIL(ctx, F4D_EINVAL, "weight shape [%d, %d] must be positive", n, k);
    if (as != FK_W_F32 && as != FK_W_F16 && as != FK_W_Q8)
        return FK_FAIL(ctx, F4D_EINVAL, "unknown weight type %d", (int)as);
    if (as == FK_W_Q8 && k > FK_Q8_K_MAX)
        return FK_FAIL(ctx, F4D_ERANGE, "int8 rows of %d exceed %d: the int32 sum could overflow",
                       k, FK_Q8_K_MAX);
    L->type = as;
    L->isa = ctx->isa;
    L->q8_bits = as == FK_W_Q8 ? ctx->q8_bits : 0;
    L->n = n;
    L->k = k;
    int simd = fk__isa_packed(ctx->isa);
    size_t n_pad = simd ? fk__round_up((size_t)n, FK_GEMM_NR) : (size_t)n;
    size_t k_pad = simd && as == FK_W_Q8 ? fk__round_up((size_t)k, 4) : (size_t)k;
    size_t esize = as == FK_W_F32 ? 4 : as == FK_W_F16 ? 2 : 1;
    if (n_pad * k_pad > SIZE_MAX / 8)
        return FK_FAIL(ctx, F4D_ERANGE, "weight shape [%d, %d] is too large", n, k);
    size_t wbytes = n_pad * k_pad * esize;
    L->data = fk__alloc(wbytes);
    L->bias = fk__alloc(n_pad * sizeof(float));
    L->bytes = fk__round_up(wbytes, FK_ALIGN) + fk__round_up(n_pad * 4, FK_ALIGN);
    if (as == FK_W_Q8) {
        L->scale = fk__alloc(n_pad * sizeof(float));
        L->colsum = fk__alloc(n_pad * sizeof(int32_t));
        L->bytes += 2 * fk__round_up(n_pad * 4, FK_ALIGN);
        if (L->scale)
            memset(L->scale, 0, n_pad * sizeof(float));
        if (L->colsum)
            memset(L->colsum, 0, n_pad * sizeof(int32_t));
    }
    if (!L->data || !L->bias || (as == FK_W_Q8 && (!L->scale || !L->colsum))) {
        fk_linear_free(L);
        return FK_FAIL(ctx, F4D_ENOMEM, "cannot allocate %zu bytes of weights", wbytes);
    }
    memset(L->data, 0, wbytes);
    memset(L->bias, 0, n_pad * sizeof(float));
    if (bias)
        memcpy(L->bias, bias, (size_t)n * sizeof(float));
    return F4D_OK;
}

/* Index of element (row j, column i) of W in the packed layout. */
static size_t packed_index(const struct fk_linear *L, int j, int i)
{
    if (!fk__isa_packed(L->isa))
        return (size_t)j * (size_t)L->k + (size_t)i;
    size_t panel = (size_t)(j / FK_GEMM_NR), col = (size_t)(j % FK_GEMM_NR);
    if (L->type == FK_W_Q8) {
        size_t k_pad = fk__round_up((size_t)L->k, 4);
        return panel * k_pad * FK_GEMM_NR + (size_t)(i / 4) * FK_GEMM_NR * 4 + col * 4 +
               (size_t)(i % 4);
    }
    return panel * (size_t)L->k * FK_GEMM_NR + (size_t)i * FK_GEMM_NR + col;
}

static void finish_q8(struct fk_linear *L, int j, const int8_t *q, float scale)
{
    int8_t *d = L->data;
    int32_t sum = 0;
    for (int i = 0; i < L->k; i++) {
        d[packed_index(L, j, i)] = q[i];
        sum += q[i];
    }
    L->scale[j] = scale;
    L->colsum[j] = 128 * sum; /* the +128 offset of VNNI's unsigned operand */
}

static int pack_rows(fk_ctx *ctx, struct fk_linear *L, const float *wf, const fk_f16 *wh)
{
    int8_t *q = NULL;
    float *row = NULL;
    if (L->type == FK_W_Q8 || wh) {
        q = malloc((size_t)L->k);
        row = malloc((size_t)L->k * sizeof *row);
        if (!q || !row) {
            free(q);
            free(row);
            fk_linear_free(L);
            return FK_FAIL(ctx, F4D_ENOMEM, "cannot allocate a %d-wide row", L->k);
        }
    }
    for (int j = 0; j < L->n; j++) {
        const float *src = wf ? wf + (size_t)j * (size_t)L->k : NULL;
        if (wh) {
            for (int i = 0; i < L->k; i++)
                row[i] = fk_f16_to_f32_ref(wh[(size_t)j * (size_t)L->k + (size_t)i]);
            src = row;
        }
        switch (L->type) {
        case FK_W_F32:
            for (int i = 0; i < L->k; i++)
                ((float *)L->data)[packed_index(L, j, i)] = src[i];
            break;
        case FK_W_F16:
            for (int i = 0; i < L->k; i++)
                ((fk_f16 *)L->data)[packed_index(L, j, i)] =
                    wh ? wh[(size_t)j * (size_t)L->k + (size_t)i] : fk_f32_to_f16_ref(src[i]);
            break;
        case FK_W_Q8: {
            float s = L->q8_bits == FK_Q8_7BIT ? quantize_row_pairs(src, L->k, q)
                                                : fk_quantize_row_q8(src, L->k, q);
            if (isnan(s)) {
                free(q);
                free(row);
                fk_linear_free(L);
                return FK_FAIL(ctx, F4D_EINVAL, "weight row %d holds Inf or NaN", j);
            }
            finish_q8(L, j, q, s);
            break;
        }
        }
    }
    free(q);
    free(row);
    return F4D_OK;
}

int fk_linear_pack(fk_ctx *ctx, struct fk_linear *L, enum fk_wtype as, const float *w, int n,
                   int k, const float *bias)
{
    FK_CHECK_CTX(ctx);
    if (!L || !w)
        return FK_FAIL(ctx, F4D_EINVAL, "NULL %s", !L ? "layer" : "weights");
    int st = pack_alloc(ctx, L, as, n, k, bias);
    return st ? st : pack_rows(ctx, L, w, NULL);
}

int fk_linear_pack_f16(fk_ctx *ctx, struct fk_linear *L, enum fk_wtype as, const fk_f16 *w,
                       int n, int k, const float *bias)
{
    FK_CHECK_CTX(ctx);
    if (!L || !w)
        return FK_FAIL(ctx, F4D_EINVAL, "NULL %s", !L ? "layer" : "weights");
    int st = pack_alloc(ctx, L, as, n, k, bias);
    return st ? st : pack_rows(ctx, L, NULL, w);
}

int fk_linear_pack_q8(fk_ctx *ctx, struct fk_linear *L, const int8_t *q, const float *scale,
                      int n, int k, const float *bias)
{
    FK_CHECK_CTX(ctx);
    if (!L || !q || !scale)
        return FK_FAIL(ctx, F4D_EINVAL, "NULL %s", !L ? "layer" : !q ? "weights" : "scales");
    int st = pack_alloc(ctx, L, FK_W_Q8, n, k, bias);
    if (st)
        return st;
    for (int j = 0; j < n; j++) {
        const int8_t *r = q + (size_t)j * (size_t)k;
        if (!isfinite(scale[j]) || scale[j] < 0) {
            fk_linear_free(L);
            return FK_FAIL(ctx, F4D_EINVAL, "scale of output channel %d is %g", j, scale[j]);
        }
        for (int i = 0; i < k; i++)
            if (r[i] == -128) {
                fk_linear_free(L);
                return FK_FAIL(ctx, F4D_EINVAL,
                               "weight [%d, %d] is -128: symmetric int8 uses [-127, 127]", j, i);
            }
        int pm = L->q8_bits == FK_Q8_7BIT ? pair_max(r, k) : 0;
        if (pm > 128) {
            /* the file stays 8-bit; rows whose pairs overrun the 7-bit path's
             * budget are requantized: q' = round(q * 127 / pm), pairs <= 128 */
            int8_t *q7 = malloc((size_t)k);
            if (!q7) {
                fk_linear_free(L);
                return FK_FAIL(ctx, F4D_ENOMEM, "cannot allocate a %d-wide row", k);
            }
            for (int i = 0; i < k; i++)
                q7[i] = (int8_t)nearbyintf((float)r[i] * 127.0f / (float)pm);
            finish_q8(L, j, q7, scale[j] * ((float)pm / 127.0f));
            free(q7);
        } else {
            finish_q8(L, j, r, scale[j]);
        }
    }
    return F4D_OK;
}

void fk_linear_free(struct fk_linear *L)
{
    if (!L)
        return;
    free(L->data);
    free(L->bias);
    free(L->scale);
    free(L->colsum);
    memset(L, 0, sizeof *L);
}

/* -------------------------------------------------------------- reference */

void fk__asrc_row(const struct fk__asrc *a, int m, int k0, int kn, float *dst)
{
    if (!a->conv) {
        memcpy(dst, a->x + (size_t)m * (size_t)a->ldx + (size_t)k0, (size_t)kn * sizeof *dst);
        return;
    }
    int oy = m / a->wo, ox = m % a->wo;
    int k = k0, end = k0 + kn;
    while (k < end) {
        int tap = k / a->cin, c = k % a->cin;
        int ky = tap / a->kw, kx = tap % a->kw;
        int iy = oy * a->stride - a->pad + ky, ix = ox * a->stride - a->pad + kx;
        int run = a->cin - c;
        if (run > end - k)
            run = end - k;
        if (iy < 0 || iy >= a->h || ix < 0 || ix >= a->w)
            memset(dst, 0, (size_t)run * sizeof *dst);
        else
            memcpy(dst, a->x + ((size_t)iy * (size_t)a->w + (size_t)ix) * (size_t)a->cin + (size_t)c,
                   (size_t)run * sizeof *dst);
        dst += run;
        k += run;
    }
}

static float act_ref(enum fk_act act, float v)
{
    switch (act) {
    case FK_ACT_RELU: return v > 0 ? v : (v == v ? 0.0f : v);
    case FK_ACT_GELU: return fk_gelu_ref(v);
    case FK_ACT_SILU: return fk_silu_ref(v);
    default:          return v;
    }
}

float *fk__cdst_ptr(const struct fk__cdst *c, int m, int n)
{
    if (!c->tconv_k)
        return c->y + (size_t)m * (size_t)c->ldy + (size_t)n;
    int k = c->tconv_k, i = m / c->tconv_w, j = m % c->tconv_w;
    int g = n / c->tconv_cout, o = n % c->tconv_cout, a = g / k, b = g % k;
    size_t row = (size_t)(k * i + a) * (size_t)(k * c->tconv_w) + (size_t)(k * j + b);
    return c->y + row * (size_t)c->tconv_cout + (size_t)o;
}

int fk__gemm_ref(fk_ctx *ctx, const struct fk_linear *L, const struct fk__asrc *a, int m,
                 const struct fk__cdst *c, const struct fk_epilogue *ep)
{
    int n = L->n, k = L->k;
    /* one row of A (and its int8 copy) in the caller's scratch: no malloc per call */
    size_t row_bytes = fk__round_up((size_t)k * sizeof(float), FK_ALIGN);
    int st = fk__scratch_reserve(ctx, row_bytes + (size_t)k, 0);
    if (st != F4D_OK || fk__measuring(ctx))
        return st;
    float *row = fk__scratch(ctx, 0);
    int8_t *qa = (int8_t *)((char *)row + row_bytes);
    for (int r = 0; r < m; r++) {
        fk__asrc_row(a, r, 0, k, row);
        float sa = L->type == FK_W_Q8 ? fk_quantize_row_q8(row, k, qa) : 0;
        for (int j = 0; j < n; j++) {
            float v;
            if (L->type == FK_W_Q8) {
                const int8_t *w = (const int8_t *)L->data + (size_t)j * (size_t)k;
                int32_t acc = 0;
                for (int i = 0; i < k; i++)
                    acc += (int32_t)qa[i] * (int32_t)w[i];
                v = fmaf((float)acc, sa * L->scale[j], L->bias[j]);
            } else {
                float acc = 0;
                for (int i = 0; i < k; i++) {
                    float w = L->type == FK_W_F32
                                  ? ((const float *)L->data)[(size_t)j * (size_t)k + (size_t)i]
                                  : fk_f16_to_f32_ref(((const fk_f16 *)L->data)[(size_t)j * (size_t)k + (size_t)i]);
                    acc += row[i] * w;
                }
                v = acc + L->bias[j];
            }
            v = act_ref(ep->act, v);
            if (ep->gamma)
                v *= ep->gamma[j];
            float *d = fk__cdst_ptr(c, r, j);
            *d = ep->accumulate ? *d + v : v;
        }
    }
    return F4D_OK;
}

/* -------------------------------------------------------------- front end */

int fk__gemm_run(fk_ctx *ctx, const struct fk_linear *L, const struct fk__asrc *a, int m,
                 const struct fk__cdst *c, const struct fk_epilogue *ep)
{
    static const struct fk_epilogue none = { FK_ACT_NONE, NULL, 0 };
    if (!ep)
        ep = &none;
    if ((unsigned)ep->act > FK_ACT_SILU)
        return FK_FAIL(ctx, F4D_EINVAL, "unknown activation %d", (int)ep->act);
    if (L->isa != ctx->isa && (fk__isa_avx2(L->isa) != fk__isa_avx2(ctx->isa) ||
                               fk__isa_neon(L->isa) != fk__isa_neon(ctx->isa)))
        return FK_FAIL(ctx, F4D_EINVAL, "weights were packed for %s, context runs %s",
                       fk_isa_name(L->isa), fk_isa_name(ctx->isa));
    if (m == 0)
        return F4D_OK;
    if (fk__isa_avx2(ctx->isa))
        return fk__gemm_avx2(ctx, L, a, m, c, ep);
    if (fk__isa_neon(ctx->isa))
        return fk__gemm_neon(ctx, L, a, m, c, ep);
    return fk__gemm_ref(ctx, L, a, m, c, ep);
}

int fk_linear_forward(fk_ctx *ctx, const struct fk_linear *L, const float *x, int m, int ldx,
                      float *y, int ldy, const struct fk_epilogue *ep)
{
    FK_CHECK_CTX(ctx);
    if (!L || !L->data)
        return FK_FAIL(ctx, F4D_EINVAL, "layer is NULL or not packed");
    if (m < 0)
        return FK_FAIL(ctx, F4D_EINVAL, "negative row count %d", m);
    if (m > 0 && (!x || !y))
        return FK_FAIL(ctx, F4D_EINVAL, "NULL %s", !x ? "input" : "output");
    if (ldx < L->k)
        return FK_FAIL(ctx, F4D_EINVAL, "input row stride %d is less than k = %d", ldx, L->k);
    if (ldy < L->n)
        return FK_FAIL(ctx, F4D_EINVAL, "output row stride %d is less than n = %d", ldy, L->n);
    if (m > 0) {
        const char *xb = (const char *)x, *xe = (const char *)(x + (size_t)(m - 1) * (size_t)ldx + (size_t)L->k);
        const char *yb = (const char *)y, *ye = (const char *)(y + (size_t)(m - 1) * (size_t)ldy + (size_t)L->n);
        if (xb < ye && yb < xe)
            return FK_FAIL(ctx, F4D_EINVAL, "input and output overlap");
    }
    struct fk__asrc a = { .x = x, .ldx = ldx };
    struct fk__cdst c = { .y = y, .ldy = ldy };
    return fk__gemm_run(ctx, L, &a, m, &c, ep);
}
