/* resize.c - bilinear and antialiased bicubic resampling of HWC images:
 * argument checks, the index / weight tables (shared by every ISA, so the
 * ISAs differ only in how they run the same multiply-adds), threading over
 * output rows, and the scalar references.
 *
 * Each output value is computed in the same order by the reference and the
 * AVX2 code (separate multiplies and adds, no FMA), so they agree bit for bit. */
#include <math.h>
#include <stdint.h>
#include <string.h>

#include "../fk_resize.h"
#include "fk_internal.h"
#include "x86/x86.h"

static int check_resize(fk_ctx *ctx, const char *func, const float *x, int h, int w, int c,
                        const float *y, int ho, int wo)
{
    if (h < 1 || w < 1 || c < 1)
        return fk__fail(ctx, F4D_EINVAL, func, "bad input shape h=%d w=%d c=%d (need >= 1)", h, w, c);
    if (ho < 1 || wo < 1)
        return fk__fail(ctx, F4D_EINVAL, func, "bad output size ho=%d wo=%d (need >= 1)", ho, wo);
    if (!x)
        return fk__fail(ctx, F4D_EINVAL, func, "x is NULL");
    if (!y)
        return fk__fail(ctx, F4D_EINVAL, func, "y is NULL");
    uintptr_t a0 = (uintptr_t)x, b0 = (uintptr_t)y;
    uintptr_t a1 = a0 + (size_t)h * w * c * sizeof(float);
    uintptr_t b1 = b0 + (size_t)ho * wo * c * sizeof(float);
    if (a0 < b1 && b0 < a1)
        return fk__fail(ctx, F4D_EINVAL, func, "x and y overlap (resizing cannot run in place)");
    return F4D_OK;
}

/* ---- bilinear ---------------------------------------------------------- */

/* Per output index: the two source indices and their weights (fk_resize.h).
 * An exact hit (align_corners end points, integer positions) and positions
 * past the last pixel point both taps at one pixel with weights 1 and 0, so
 * they reproduce it exactly and never read a neighbour. */
static void bilinear_axis(int n_in, int n_out, int align_corners, int32_t *idx, float *wt)
{
    for (int i = 0; i < n_out; i++) {
        double src;
        if (align_corners)
            src = n_out > 1 ? (double)i * (n_in - 1) / (n_out - 1) : 0.0;
        else
            src = fmax(((double)i + 0.5) * n_in / n_out - 0.5, 0.0);
        int i0 = (int)src, i1 = i0 + 1;
        float l1 = (float)(src - i0);
        if (i0 >= n_in - 1) {  /* past the last pixel: that pixel, weight exactly 1 */
            i0 = i1 = n_in - 1;
            l1 = 0.0f;
        } else if (l1 == 0.0f) {
            i1 = i0;
        }
        idx[2 * i] = i0;
        idx[2 * i + 1] = i1;
        wt[2 * i] = 1.0f - l1;
        wt[2 * i + 1] = l1;
    }
}

static void bilinear_row_ref(const float *r0, const float *r1, float wy0, float wy1,
                             const int32_t *xi, const float *xw, int wo, int c, float *out)
{
    for (int j = 0; j < wo; j++) {
        const float *a = r0 + (size_t)xi[2 * j] * c, *b = r0 + (size_t)xi[2 * j + 1] * c;
        const float *d = r1 + (size_t)xi[2 * j] * c, *e = r1 + (size_t)xi[2 * j + 1] * c;
        float w0 = xw[2 * j], w1 = xw[2 * j + 1];
        for (int k = 0; k < c; k++)
            out[(size_t)j * c + k] = wy0 * (w0 * a[k] + w1 * b[k]) + wy1 * (w0 * d[k] + w1 * e[k]);
    }
}

struct bilinear_job {
    int            avx2, per, ho, w, c, wo;
    const float   *x;
    float         *y;
    const int32_t *yi, *xi;
    const float   *yw, *xw;
};

static void bilinear_task(void *arg, int task, int thread)
{
    (void)thread;
    const struct bilinear_job *j = arg;
    int i1 = (task + 1) * j->per < j->ho ? (task + 1) * j->per : j->ho;
    size_t row = (size_t)j->w * j->c;
    for (int i = task * j->per; i < i1; i++) {
        const float *r0 = j->x + (size_t)j->yi[2 * i] * row, *r1 = j->x + (size_t)j->yi[2 * i + 1] * row;
        float *out = j->y + (size_t)i * j->wo * j->c;
        if (j->avx2)
            fk__bilinear_row_avx2(r0, r1, j->yw[2 * i], j->yw[2 * i + 1], j->xi, j->xw, j->wo, j->c, out);
        else
            bilinear_row_ref(r0, r1, j->yw[2 * i], j->yw[2 * i + 1], j->xi, j->xw, j->wo, j->c, out);
    }
}

/* Output rows per task: about four tasks per thread. */
static int rows_per_task(const fk_ctx *ctx, int rows)
{
    int tasks = ctx->threads * 4;
    int per = (rows + tasks - 1) / tasks;
    return per > 0 ? per : 1;
}

int fk_resize_bilinear(fk_ctx *ctx, const float *x, int h, int w, int c, float *y, int ho, int wo,
                       int align_corners)
{
    FK_CHECK_CTX(ctx);
    int st = check_resize(ctx, __func__, x, h, w, c, y, ho, wo);
    if (st != F4D_OK)
        return st;
    if (align_corners != 0 && align_corners != 1)
        return FK_FAIL(ctx, F4D_EINVAL, "align_corners=%d (need 0 or 1)", align_corners);
    if (ho == h && wo == w) { /* identity either way: a copy, so Inf stays Inf */
        memcpy(y, x, (size_t)h * w * c * sizeof *x);
        return F4D_OK;
    }
    size_t tab = fk__round_up(2 * ((size_t)ho + wo) * sizeof(int32_t), FK_ALIGN);
    st = fk__scratch_reserve(ctx, 0, 2 * tab);
    if (st != F4D_OK || fk__measuring(ctx))
        return st;
    char *s = fk__scratch_shared(ctx);
    int32_t *yi = (int32_t *)s, *xi = yi + 2 * (size_t)ho;
    float *yw = (float *)(s + tab), *xw = yw + 2 * (size_t)ho;
    bilinear_axis(h, ho, align_corners, yi, yw);
    bilinear_axis(w, wo, align_corners, xi, xw);
    struct bilinear_job j = { fk__isa_avx2(ctx->isa), rows_per_task(ctx, ho), ho, w, c, wo, x, y,
                              yi, xi, yw, xw };
    fk_parallel_for(ctx, (ho + j.per - 1) / j.per, 8.0 * ho * (double)wo * c, bilinear_task, &j);
    return F4D_OK;
}

/* ---- antialiased bicubic (PIL / torch antialias=True, a = -0.5) -------- */

static double cubic_a05(double t)
{
    const double a = -0.5;
    t = fabs(t);
    if (t < 1.0)
        return ((a + 2.0) * t - (a + 3.0)) * t * t + 1.0;
    if (t < 2.0)
        return a * (((t - 5.0) * t + 8.0) * t - 4.0);
    return 0.0;
}

/* Taps per output index for n_in -> n_out: at most ceil(support) * 2 + 1. */
static int aa_ksize(int n_in, int n_out)
{
    double scale = (double)n_in / n_out;
    double support = scale >= 1.0 ? 2.0 * scale : 2.0;
    return (int)ceil(support) * 2 + 1;
}

/* vggt.md 2: center = s (i + 0.5), window [floor(center - support + 0.5),
 * floor(center + support + 0.5)) clipped to the input, weights
 * k((j - center + 0.5) inv) normalised to sum 1 (in double, stored as float).
 * Taps whose weight is exactly 0 at either end of the window are dropped. */
static void aa_axis(int n_in, int n_out, int ksize, int32_t *first, int32_t *count, float *wt)
{
    double scale = (double)n_in / n_out;
    double support = scale >= 1.0 ? 2.0 * scale : 2.0;
    double inv = scale >= 1.0 ? 1.0 / scale : 1.0;
    for (int i = 0; i < n_out; i++) {
        double center = scale * (i + 0.5);
        int lo = (int)floor(center - support + 0.5), hi = (int)floor(center + support + 0.5);
        if (lo < 0)
            lo = 0;
        if (hi > n_in)
            hi = n_in;
        double total = 0;
        for (int t = lo; t < hi; t++)
            total += cubic_a05((t - center + 0.5) * inv);
        if (total == 0.0)
            total = 1.0;
        while (lo < hi && cubic_a05((lo - center + 0.5) * inv) == 0.0)
            lo++;
        while (hi > lo && cubic_a05((hi - 1 - center + 0.5) * inv) == 0.0)
            hi--;
        first[i] = lo;
        count[i] = hi - lo;
        float *wi = wt + (size_t)i * ksize;
        for (int t = 0; t < ksize; t++)
            wi[t] = t < hi - lo ? (float)(cubic_a05((lo + t - center + 0.5) * inv) / total) : 0.0f;
    }
}

static void aa_hrow_ref(const float *in, int c, const int32_t *first, const int32_t *count,
                        const float *wts, int ksize, int wo, float *out)
{
    for (int i = 0; i < wo; i++) {
        const float *src = in + (size_t)first[i] * c, *wi = wts + (size_t)i * ksize;
        for (int ch = 0; ch < c; ch++) {
            float acc = 0.0f;
            for (int t = 0; t < count[i]; t++)
                acc += wi[t] * src[(size_t)t * c + ch];
            out[(size_t)i * c + ch] = acc;
        }
    }
}

static void aa_vrow_ref(const float *in, size_t row_len, int count, const float *wts, float *out)
{
    for (size_t e = 0; e < row_len; e++) {
        float acc = 0.0f;
        for (int t = 0; t < count; t++)
            acc += wts[t] * in[(size_t)t * row_len + e];
        out[e] = acc;
    }
}

struct aa_job {
    int            avx2, per, rows, c, ksize, n_out;
    size_t         in_row, out_row;   /* floats per row of input and output */
    const float   *in;
    float         *out;
    const int32_t *first, *count;
    const float   *wt;
};

/* Horizontal pass: input row r -> output row r, along w. */
static void aa_htask(void *arg, int task, int thread)
{
    (void)thread;
    const struct aa_job *j = arg;
    int r1 = (task + 1) * j->per < j->rows ? (task + 1) * j->per : j->rows;
    for (int r = task * j->per; r < r1; r++) {
        const float *in = j->in + (size_t)r * j->in_row;
        float *out = j->out + (size_t)r * j->out_row;
        if (j->avx2)
            fk__aa_hrow_avx2(in, j->c, j->first, j->count, j->wt, j->ksize, j->n_out, out);
        else
            aa_hrow_ref(in, j->c, j->first, j->count, j->wt, j->ksize, j->n_out, out);
    }
}

/* Vertical pass: output row i from input rows first[i] .. + count[i]. */
static void aa_vtask(void *arg, int task, int thread)
{
    (void)thread;
    const struct aa_job *j = arg;
    int i1 = (task + 1) * j->per < j->rows ? (task + 1) * j->per : j->rows;
    for (int i = task * j->per; i < i1; i++) {
        const float *in = j->in + (size_t)j->first[i] * j->in_row;
        const float *wi = j->wt + (size_t)i * j->ksize;
        float *out = j->out + (size_t)i * j->out_row;
        if (j->avx2)
            fk__aa_vrow_avx2(in, j->in_row, j->count[i], wi, out);
        else
            aa_vrow_ref(in, j->in_row, j->count[i], wi, out);
    }
}

int fk_resize_bicubic_aa(fk_ctx *ctx, const float *x, int h, int w, int c, float *y, int ho,
                         int wo)
{
    FK_CHECK_CTX(ctx);
    int st = check_resize(ctx, __func__, x, h, w, c, y, ho, wo);
    if (st != F4D_OK)
        return st;
    if (ho == h && wo == w) { /* identity on both axes */
        memcpy(y, x, (size_t)h * w * c * sizeof *x);
        return F4D_OK;
    }
    int do_h = wo != w, do_v = ho != h;
    int kw = aa_ksize(w, wo), kh = aa_ksize(h, ho);
    size_t tab_w = do_h ? fk__round_up((size_t)wo * (2 * sizeof(int32_t) + kw * sizeof(float)), FK_ALIGN) : 0;
    size_t tab_h = do_v ? fk__round_up((size_t)ho * (2 * sizeof(int32_t) + kh * sizeof(float)), FK_ALIGN) : 0;
    size_t tmp = do_h && do_v ? (size_t)h * wo * c * sizeof(float) : 0;
    st = fk__scratch_reserve(ctx, 0, tab_w + tab_h + tmp);
    if (st != F4D_OK || fk__measuring(ctx))
        return st;
    char *s = fk__scratch_shared(ctx);
    int avx2 = fk__isa_avx2(ctx->isa);

    const float *mid = x;                 /* [h][wo][c] after the horizontal pass */
    if (do_h) {
        int32_t *first = (int32_t *)s, *count = first + wo;
        float *wt = (float *)(count + wo);
        aa_axis(w, wo, kw, first, count, wt);
        float *out = do_v ? (float *)(s + tab_w + tab_h) : y;
        struct aa_job j = { avx2, rows_per_task(ctx, h), h, c, kw, wo, (size_t)w * c,
                            (size_t)wo * c, x, out, first, count, wt };
        fk_parallel_for(ctx, (h + j.per - 1) / j.per, 2.0 * h * (double)wo * c * kw, aa_htask, &j);
        mid = out;
    }
    if (do_v) {
        int32_t *first = (int32_t *)(s + tab_w), *count = first + ho;
        float *wt = (float *)(count + ho);
        aa_axis(h, ho, kh, first, count, wt);
        struct aa_job j = { avx2, rows_per_task(ctx, ho), ho, c, kh, ho, (size_t)wo * c,
                            (size_t)wo * c, mid, y, first, count, wt };
        fk_parallel_for(ctx, (ho + j.per - 1) / j.per, 2.0 * ho * (double)wo * c * kh, aa_vtask, &j);
    }
    return F4D_OK;
}
