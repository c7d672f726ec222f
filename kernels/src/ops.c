/* ops.c - element-wise and row-wise ops: argument checks, dispatch, threading
 * over row or element chunks, and the scalar references (the specification).
 *
 * The references compute in double where it makes the specification exact
 * rather than approximate: LayerNorm statistics, softmax exponentials and
 * sums, GELU and SiLU. The optimized versions are tested against them within
 * the budgets written in tests/kernels/test_ops.c. */
#include <math.h>
#include <stdint.h>
#include <string.h>

#include "../fk_ops.h"
#include "fk_internal.h"
#include "x86/x86.h"
#include "arm/arm.h"

/* ---- scalar references ------------------------------------------------ */

/* x Phi(x) = 0.5 x (1 + erf(x / sqrt 2)), written as 0.5 x erfc(-x / sqrt 2)
 * so the negative tail keeps its relative accuracy (1 + erf cancels). */
float fk_gelu_ref(float x)
{
    if (isinf(x))
        return x > 0 ? x : -0.0f;     /* the limits, not -Inf * 0 */
    return (float)(0.5 * x * erfc(-x * 0.70710678118654752440));
}

float fk_silu_ref(float x)
{
    if (isinf(x))
        return x > 0 ? x : -0.0f;
    return (float)(x / (1.0 + exp(-(double)x)));
}

static float relu_ref(float x)
{
    return x < 0 ? 0.0f : x;          /* NaN and -0 pass through, as maxps(0, x) */
}

static void layernorm_row_ref(const float *x, int n, const float *w, const float *b, float eps,
                              float *y)
{
    double sum = 0;
    for (int j = 0; j < n; j++)
        sum += x[j];
    double mean = sum / n;
    double ss = 0;
    for (int j = 0; j < n; j++)
        ss += (x[j] - mean) * (x[j] - mean);
    double rstd = 1.0 / sqrt(ss / n + eps);
    for (int j = 0; j < n; j++) {
        float v = (float)((x[j] - mean) * rstd);
        if (w)
            v *= w[j];
        if (b)
            v += b[j];
        y[j] = v;
    }
}

static void softmax_row_ref(const float *x, int n, float *y)
{
    float m = -INFINITY;
    for (int j = 0; j < n; j++)
        if (x[j] > m)
            m = x[j];
    double s = 0;
    for (int j = 0; j < n; j++)
        s += exp((double)x[j] - m);
    for (int j = 0; j < n; j++)       /* y may be x: read x[j] before writing y[j] */
        y[j] = (float)(exp((double)x[j] - m) / s);
}

/* ---- argument checks -------------------------------------------------- */

/* [p, p + (rows - 1) * ld + cols) as bytes, for the overlap check. */
static int spans_overlap(const float *a, int lda, const float *b, int ldb, int rows, int cols)
{
    uintptr_t a0 = (uintptr_t)a, b0 = (uintptr_t)b;
    uintptr_t a1 = a0 + ((size_t)(rows - 1) * (size_t)lda + (size_t)cols) * sizeof(float);
    uintptr_t b1 = b0 + ((size_t)(rows - 1) * (size_t)ldb + (size_t)cols) * sizeof(float);
    return a0 < b1 && b0 < a1;
}

/* Shape of a [rows][cols] input with stride ldx and output with ldy: rows >= 0,
 * cols >= 1, strides >= cols, buffers non-NULL when rows > 0, and the output
 * either the input itself (same stride) or disjoint from it. */
static int check_rows(fk_ctx *ctx, const char *func, const void *x, int ldx, const void *y,
                      int ldy, int rows, int cols, const char *xn, const char *yn)
{
    if (rows < 0 || cols < 1)
        return fk__fail(ctx, F4D_EINVAL, func, "bad shape rows=%d cols=%d (need rows >= 0, cols >= 1)",
                        rows, cols);
    if (ldx < cols)
        return fk__fail(ctx, F4D_EINVAL, func, "row stride ld%s=%d < cols=%d", xn, ldx, cols);
    if (ldy < cols)
        return fk__fail(ctx, F4D_EINVAL, func, "row stride ld%s=%d < cols=%d", yn, ldy, cols);
    if (rows == 0)
        return F4D_OK;
    if (!x)
        return fk__fail(ctx, F4D_EINVAL, func, "%s is NULL", xn);
    if (!y)
        return fk__fail(ctx, F4D_EINVAL, func, "%s is NULL", yn);
    if (!(x == y && ldx == ldy) && spans_overlap(x, ldx, y, ldy, rows, cols))
        return fk__fail(ctx, F4D_EINVAL, func,
                        "%s and %s overlap without being the same matrix (in place needs %s == %s "
                        "and ld%s == ld%s)", xn, yn, xn, yn, xn, yn);
    return F4D_OK;
}

static int check_array(fk_ctx *ctx, const char *func, const float *x, size_t n, const float *y)
{
    if (n == 0)
        return F4D_OK;
    if (!x || !y)
        return fk__fail(ctx, F4D_EINVAL, func, "%s is NULL (n=%zu)", x ? "y" : "x", n);
    uintptr_t a = (uintptr_t)x, b = (uintptr_t)y, bytes = n * sizeof(float);
    if (a != b && a < b + bytes && b < a + bytes)
        return fk__fail(ctx, F4D_EINVAL, func, "x and y overlap without being equal");
    return F4D_OK;
}

/* ---- threading -------------------------------------------------------- */

/* Rows per task: about four tasks per thread so the dynamic hand-out evens out. */
static int rows_per_task(const fk_ctx *ctx, int rows)
{
    int tasks = ctx->threads * 4;
    int per = (rows + tasks - 1) / tasks;
    return per > 0 ? per : 1;
}

enum elt_op { ELT_GELU, ELT_SILU, ELT_RELU };

struct elt_job {
    enum elt_op  op;
    int          avx2, neon;
    const float *x;
    float       *y;
    size_t       n, chunk;
};

static void elt_task(void *arg, int task, int thread)
{
    (void)thread;
    const struct elt_job *j = arg;
    size_t i0 = (size_t)task * j->chunk;
    size_t n = j->n - i0 < j->chunk ? j->n - i0 : j->chunk;
    const float *x = j->x + i0;
    float *y = j->y + i0;
    if (j->avx2) {
        switch (j->op) {
        case ELT_GELU: fk__gelu_array_avx2(x, y, n); break;
        case ELT_SILU: fk__silu_array_avx2(x, y, n); break;
        case ELT_RELU: fk__relu_array_avx2(x, y, n); break;
        }
        return;
    }
    if (j->neon) {
        switch (j->op) {
        case ELT_GELU: fk__gelu_array_neon(x, y, n); break;
        case ELT_SILU: fk__silu_array_neon(x, y, n); break;
        case ELT_RELU: fk__relu_array_neon(x, y, n); break;
        }
        return;
    }
    for (size_t i = 0; i < n; i++) {
        switch (j->op) {
        case ELT_GELU: y[i] = fk_gelu_ref(x[i]); break;
        case ELT_SILU: y[i] = fk_silu_ref(x[i]); break;
        case ELT_RELU: y[i] = relu_ref(x[i]); break;
        }
    }
}

/* Scalar operations per element, for the threading threshold. */
static const double elt_cost[] = { 40.0, 25.0, 1.0 };

static int elementwise(fk_ctx *ctx, const char *func, enum elt_op op, const float *x, size_t n,
                       float *y)
{
    FK_CHECK_CTX(ctx);
    int st = check_array(ctx, func, x, n, y);
    if (st != F4D_OK || n == 0)
        return st;
    struct elt_job j = { op, fk__isa_avx2(ctx->isa), fk__isa_neon(ctx->isa), x, y, n, 16384 };
    while ((n + j.chunk - 1) / j.chunk > INT32_MAX)
        j.chunk *= 2;
    fk_parallel_for(ctx, (int)((n + j.chunk - 1) / j.chunk), elt_cost[op] * (double)n, elt_task, &j);
    return F4D_OK;
}

int fk_gelu(fk_ctx *ctx, const float *x, size_t n, float *y)
{
    return elementwise(ctx, __func__, ELT_GELU, x, n, y);
}

int fk_silu(fk_ctx *ctx, const float *x, size_t n, float *y)
{
    return elementwise(ctx, __func__, ELT_SILU, x, n, y);
}

int fk_relu(fk_ctx *ctx, const float *x, size_t n, float *y)
{
    return elementwise(ctx, __func__, ELT_RELU, x, n, y);
}

/* ---- row-wise ops ----------------------------------------------------- */

enum row_op { ROW_LAYERNORM, ROW_SOFTMAX, ROW_RESIDUAL };

/* Rows of x (read) and y (written). For the residual add, x is r, y is the
 * updated matrix and w is gamma. */
struct row_job {
    enum row_op  op;
    int          avx2, neon, per;
    int          rows, cols, ldx, ldy;
    const float *x, *w, *b;
    float       *y;
    float        eps;
};

static void residual_row_ref(float *x, const float *r, const float *gamma, int n)
{
    if (gamma) {
        for (int c = 0; c < n; c++)
            x[c] += gamma[c] * r[c];
    } else {
        for (int c = 0; c < n; c++)
            x[c] += r[c];
    }
}

static void row_task(void *arg, int task, int thread)
{
    (void)thread;
    const struct row_job *j = arg;
    int r0 = task * j->per;
    int nr = j->rows - r0 < j->per ? j->rows - r0 : j->per;
    const float *x = j->x + (size_t)r0 * j->ldx;
    float *y = j->y + (size_t)r0 * j->ldy;
    if (j->avx2) {
        switch (j->op) {
        case ROW_LAYERNORM:
            fk__layernorm_rows_avx2(x, nr, j->cols, j->ldx, j->w, j->b, j->eps, y, j->ldy);
            break;
        case ROW_SOFTMAX:
            fk__softmax_rows_avx2(x, nr, j->cols, j->ldx, y, j->ldy);
            break;
        case ROW_RESIDUAL:
            fk__residual_rows_avx2(y, j->ldy, x, j->ldx, j->w, nr, j->cols);
            break;
        }
        return;
    }
    if (j->neon) {
        switch (j->op) {
        case ROW_LAYERNORM:
            fk__layernorm_rows_neon(x, nr, j->cols, j->ldx, j->w, j->b, j->eps, y, j->ldy);
            break;
        case ROW_SOFTMAX:
            fk__softmax_rows_neon(x, nr, j->cols, j->ldx, y, j->ldy);
            break;
        case ROW_RESIDUAL:
            fk__residual_rows_neon(y, j->ldy, x, j->ldx, j->w, nr, j->cols);
            break;
        }
        return;
    }
    for (int i = 0; i < nr; i++) {
        const float *xi = x + (size_t)i * j->ldx;
        float *yi = y + (size_t)i * j->ldy;
        switch (j->op) {
        case ROW_LAYERNORM: layernorm_row_ref(xi, j->cols, j->w, j->b, j->eps, yi); break;
        case ROW_SOFTMAX:   softmax_row_ref(xi, j->cols, yi); break;
        case ROW_RESIDUAL:  residual_row_ref(yi, xi, j->w, j->cols); break;
        }
    }
}

/* Runs a checked, non-empty job over row chunks; cost is the work per element
 * in scalar operations, for the threading threshold. */
static int run_rows(fk_ctx *ctx, struct row_job *j, double cost)
{
    j->avx2 = fk__isa_avx2(ctx->isa);
    j->neon = fk__isa_neon(ctx->isa);
    j->per = rows_per_task(ctx, j->rows);
    fk_parallel_for(ctx, (j->rows + j->per - 1) / j->per, cost * j->rows * (double)j->cols,
                    row_task, j);
    return F4D_OK;
}

int fk_layernorm(fk_ctx *ctx, const float *x, int rows, int cols, int ldx, const float *w,
                 const float *b, float eps, float *y, int ldy)
{
    FK_CHECK_CTX(ctx);
    int st = check_rows(ctx, __func__, x, ldx, y, ldy, rows, cols, "x", "y");
    if (st != F4D_OK)
        return st;
    if (!(eps >= 0) || isinf(eps))
        return FK_FAIL(ctx, F4D_EINVAL, "eps=%g must be finite and >= 0", (double)eps);
    if (rows == 0)
        return F4D_OK;
    struct row_job j = { .op = ROW_LAYERNORM, .rows = rows, .cols = cols, .ldx = ldx, .ldy = ldy,
                         .x = x, .w = w, .b = b, .y = y, .eps = eps };
    return run_rows(ctx, &j, 12.0);
}

int fk_softmax(fk_ctx *ctx, const float *x, int rows, int cols, int ldx, float *y, int ldy)
{
    FK_CHECK_CTX(ctx);
    int st = check_rows(ctx, __func__, x, ldx, y, ldy, rows, cols, "x", "y");
    if (st != F4D_OK || rows == 0)
        return st;
    struct row_job j = { .op = ROW_SOFTMAX, .rows = rows, .cols = cols, .ldx = ldx, .ldy = ldy,
                         .x = x, .y = y };
    return run_rows(ctx, &j, 30.0);
}

int fk_residual_add(fk_ctx *ctx, float *x, int ldx, const float *r, int ldr, const float *gamma,
                    int rows, int cols)
{
    FK_CHECK_CTX(ctx);
    int st = check_rows(ctx, __func__, r, ldr, x, ldx, rows, cols, "r", "x");
    if (st != F4D_OK || rows == 0)
        return st;
    struct row_job j = { .op = ROW_RESIDUAL, .rows = rows, .cols = cols, .ldx = ldr, .ldy = ldx,
                         .x = r, .w = gamma, .y = x };
    return run_rows(ctx, &j, 2.0);
}
