/* ops_neon.c - AArch64 NEON element-wise and row-wise ops of fk_ops.h, the
 * operations of x86/ops_avx2.c four lanes at a time.
 *
 * LayerNorm keeps its statistics in double like the reference (constant rows
 * give exactly the bias; rows of magnitude 1e30 or 1e-30 neither overflow nor
 * underflow); the residual add uses a separate multiply and add, so it matches
 * the reference bit for bit. */
#include <arm_neon.h>
#include <math.h>

#include "arm.h"
#include "vecmath_neon.h"

#define ELEMENTWISE(name, expr)                                              \
    void name(const float *x, float *y, size_t n)                            \
    {                                                                        \
        size_t i = 0;                                                        \
        for (; i + 4 <= n; i += 4) {                                         \
            float32x4_t v = vld1q_f32(x + i);                                \
            vst1q_f32(y + i, expr);                                          \
        }                                                                    \
        if (i < n) {                                                         \
            float t[4] = { 0, 0, 0, 0 };                                     \
            for (size_t k = 0; k < n - i; k++)                               \
                t[k] = x[i + k];                                             \
            float32x4_t v = vld1q_f32(t);                                    \
            vst1q_f32(t, expr);                                              \
            for (size_t k = 0; k < n - i; k++)                               \
                y[i + k] = t[k];                                             \
        }                                                                    \
    }

ELEMENTWISE(fk__gelu_array_neon, fk__gelu_neon(v))
ELEMENTWISE(fk__silu_array_neon, fk__silu_neon(v))
ELEMENTWISE(fk__relu_array_neon, fk__relu_neon(v))   /* NaN and -0 pass */

static void layernorm_row(const float *x, int n, const float *w, const float *b, float eps,
                          float *y)
{
    float64x2_t s0 = vdupq_n_f64(0.0), s1 = s0;
    int j = 0;
    for (; j + 4 <= n; j += 4) {
        float32x4_t v = vld1q_f32(x + j);
        s0 = vaddq_f64(s0, vcvt_f64_f32(vget_low_f32(v)));
        s1 = vaddq_f64(s1, vcvt_high_f64_f32(v));
    }
    double sum = vaddvq_f64(vaddq_f64(s0, s1));
    for (int k = j; k < n; k++)
        sum += x[k];
    double mean = sum / n;

    float64x2_t m = vdupq_n_f64(mean);
    s0 = vdupq_n_f64(0.0);
    s1 = s0;
    for (j = 0; j + 4 <= n; j += 4) {
        float32x4_t v = vld1q_f32(x + j);
        float64x2_t d0 = vsubq_f64(vcvt_f64_f32(vget_low_f32(v)), m);
        float64x2_t d1 = vsubq_f64(vcvt_high_f64_f32(v), m);
        s0 = vfmaq_f64(s0, d0, d0);
        s1 = vfmaq_f64(s1, d1, d1);
    }
    double ss = vaddvq_f64(vaddq_f64(s0, s1));
    for (int k = j; k < n; k++)
        ss += (x[k] - mean) * (x[k] - mean);
    double rstd = 1.0 / sqrt(ss / n + eps);

    float64x2_t r = vdupq_n_f64(rstd);
    for (j = 0; j + 4 <= n; j += 4) {
        float32x4_t v = vld1q_f32(x + j);
        float64x2_t d0 = vsubq_f64(vcvt_f64_f32(vget_low_f32(v)), m);
        float64x2_t d1 = vsubq_f64(vcvt_high_f64_f32(v), m);
        float32x4_t t = vcvt_high_f32_f64(vcvt_f32_f64(vmulq_f64(d0, r)), vmulq_f64(d1, r));
        if (w)
            t = vmulq_f32(t, vld1q_f32(w + j));
        if (b)
            t = vaddq_f32(t, vld1q_f32(b + j));
        vst1q_f32(y + j, t);
    }
    for (; j < n; j++) {
        float v = (float)((x[j] - mean) * rstd);
        if (w)
            v *= w[j];
        if (b)
            v += b[j];
        y[j] = v;
    }
}

void fk__layernorm_rows_neon(const float *x, int rows, int cols, int ldx, const float *w,
                             const float *b, float eps, float *y, int ldy)
{
    for (int i = 0; i < rows; i++)
        layernorm_row(x + (size_t)i * ldx, cols, w, b, eps, y + (size_t)i * ldy);
}

/* exp(x - max) / sum: max, then the exponentials stored in y with their sum,
 * then one scaling pass. */
static void softmax_row(const float *x, int n, float *y)
{
    float32x4_t vm = vdupq_n_f32(-INFINITY);
    int j = 0;
    for (; j + 4 <= n; j += 4)
        vm = vmaxq_f32(vm, vld1q_f32(x + j));
    float mx = vmaxvq_f32(vm);
    for (int k = j; k < n; k++)
        mx = x[k] > mx || isnan(x[k]) ? x[k] : mx;
    float32x4_t m = vdupq_n_f32(mx), s = vdupq_n_f32(0.0f);
    for (j = 0; j + 4 <= n; j += 4) {
        float32x4_t e = fk__exp_neon(vsubq_f32(vld1q_f32(x + j), m));
        vst1q_f32(y + j, e);
        s = vaddq_f32(s, e);
    }
    float sum = vaddvq_f32(s);
    for (int k = j; k < n; k++) {
        float t[4] = { x[k], 0, 0, 0 };
        float e = vgetq_lane_f32(fk__exp_neon(vsubq_f32(vld1q_f32(t), m)), 0);
        y[k] = e;
        sum += e;
    }
    float32x4_t inv = vdupq_n_f32(1.0f / sum);
    for (j = 0; j + 4 <= n; j += 4)
        vst1q_f32(y + j, vmulq_f32(vld1q_f32(y + j), inv));
    for (; j < n; j++)
        y[j] *= vgetq_lane_f32(inv, 0);
}

void fk__softmax_rows_neon(const float *x, int rows, int cols, int ldx, float *y, int ldy)
{
    for (int i = 0; i < rows; i++)
        softmax_row(x + (size_t)i * ldx, cols, y + (size_t)i * ldy);
}

void fk__residual_rows_neon(float *x, int ldx, const float *r, int ldr, const float *gamma,
                            int rows, int cols)
{
    for (int i = 0; i < rows; i++) {
        float *xi = x + (size_t)i * ldx;
        const float *ri = r + (size_t)i * ldr;
        int j = 0;
        if (gamma) {
            for (; j + 4 <= cols; j += 4)
                vst1q_f32(xi + j, vaddq_f32(vld1q_f32(xi + j),
                                            vmulq_f32(vld1q_f32(gamma + j), vld1q_f32(ri + j))));
            for (; j < cols; j++)
                xi[j] += gamma[j] * ri[j];
        } else {
            for (; j + 4 <= cols; j += 4)
                vst1q_f32(xi + j, vaddq_f32(vld1q_f32(xi + j), vld1q_f32(ri + j)));
            for (; j < cols; j++)
                xi[j] += ri[j];
        }
    }
}
