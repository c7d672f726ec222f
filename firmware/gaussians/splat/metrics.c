/* metrics.c - PSNR, SSIM and TL-STD exactly as gaussians.md §4 pins them. */
#include <math.h>
#include <stdlib.h>

#include "splat_internal.h"

double splat_psnr(const float *a, const float *b, int width, int height, int channels)
{
    if (!a || !b || width <= 0 || height <= 0 || channels <= 0)
        return NAN;
    size_t n = (size_t)width * (size_t)height * (size_t)channels;
    double se = 0.0;
    for (size_t i = 0; i < n; i++) {
        double d = (double)a[i] - (double)b[i];
        se += d * d;
    }
    double mse = se / (double)n;
    if (mse == 0.0)
        return INFINITY;
    return 20.0 * log10(1.0 / sqrt(mse));
}

size_t splat_ssim_scratch_floats(int width, int height)
{
    return 7 * (size_t)width * (size_t)height;
}

/* 11-tap Gaussian, sigma 1.5, normalised to sum 1 (3DGS create_window). */
static void ssim_window(float g[11])
{
    double w[11], s = 0.0;
    for (int x = 0; x < 11; x++) {
        w[x] = exp(-(double)((x - 5) * (x - 5)) / (2.0 * 1.5 * 1.5));
        s += w[x];
    }
    for (int x = 0; x < 11; x++)
        g[x] = (float)(w[x] / s);
}

/* Separable 11x11 filter with zero padding 5: equal to conv2d(g gᵀ, padding=5). */
static void filter(const float *in, float *tmp, float *out, int W, int H, const float g[11])
{
    for (int y = 0; y < H; y++)
        for (int x = 0; x < W; x++) {
            float s = 0.0f;
            for (int k = -5; k <= 5; k++) {
                int xx = x + k;
                if (xx >= 0 && xx < W)
                    s += g[k + 5] * in[(size_t)y * W + xx];
            }
            tmp[(size_t)y * W + x] = s;
        }
    for (int y = 0; y < H; y++)
        for (int x = 0; x < W; x++) {
            float s = 0.0f;
            for (int k = -5; k <= 5; k++) {
                int yy = y + k;
                if (yy >= 0 && yy < H)
                    s += g[k + 5] * tmp[(size_t)yy * W + x];
            }
            out[(size_t)y * W + x] = s;
        }
}

double splat_ssim(const float *a, const float *b, int W, int H, int channels, float *scratch)
{
    if (!a || !b || W <= 0 || H <= 0 || channels <= 0)
        return NAN;
    size_t np = (size_t)W * (size_t)H;
    float *own = NULL;
    if (!scratch) {
        own = malloc(splat_ssim_scratch_floats(W, H) * sizeof(float));
        if (!own)
            return NAN;
        scratch = own;
    }
    float *x = scratch, *tmp = x + np, *mu1 = tmp + np, *mu2 = mu1 + np, *s11 = mu2 + np, *s22 = s11 + np,
          *s12 = s22 + np;
    float g[11];
    ssim_window(g);
    const float C1 = 0.01f * 0.01f, C2 = 0.03f * 0.03f;
    double total = 0.0;
    for (int c = 0; c < channels; c++) {
        for (size_t i = 0; i < np; i++)
            x[i] = a[i * channels + c];
        filter(x, tmp, mu1, W, H, g);
        for (size_t i = 0; i < np; i++)
            x[i] = a[i * channels + c] * a[i * channels + c];
        filter(x, tmp, s11, W, H, g);
        for (size_t i = 0; i < np; i++)
            x[i] = b[i * channels + c];
        filter(x, tmp, mu2, W, H, g);
        for (size_t i = 0; i < np; i++)
            x[i] = b[i * channels + c] * b[i * channels + c];
        filter(x, tmp, s22, W, H, g);
        for (size_t i = 0; i < np; i++)
            x[i] = a[i * channels + c] * b[i * channels + c];
        filter(x, tmp, s12, W, H, g);
        for (size_t i = 0; i < np; i++) {
            float m1 = mu1[i], m2 = mu2[i];
            float v1 = s11[i] - m1 * m1, v2 = s22[i] - m2 * m2, v12 = s12[i] - m1 * m2;
            float num = (2.0f * m1 * m2 + C1) * (2.0f * v12 + C2);
            float den = (m1 * m1 + m2 * m2 + C1) * (v1 + v2 + C2);
            total += (double)(num / den);
        }
    }
    free(own);
    return total / ((double)np * (double)channels);
}

double splat_tlstd(const float *const *frames, int n, int W, int H)
{
    if (!frames || n < 1 || W <= 0 || H <= 0)
        return NAN;
    size_t np = (size_t)W * (size_t)H;
    double acc = 0.0;
    for (size_t i = 0; i < np; i++) {
        double s = 0.0, s2 = 0.0;
        for (int t = 0; t < n; t++) {
            const float *p = frames[t] + 3 * i;
            double y = 0.2126 * p[0] + 0.7152 * p[1] + 0.0722 * p[2];
            s += y;
            s2 += y * y;
        }
        double m = s / n, v = s2 / n - m * m;
        acc += v > 0.0 ? sqrt(v) : 0.0;
    }
    return acc / (double)np;
}
