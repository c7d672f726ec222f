/* foreground.c - background median / MAD from K learning sets, changed
 * pixels, foreground patches, dilation (foreground.h). */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "foreground.h"

struct fg_model {
    struct fg_config c;
    size_t   n;          /* values per set: views * 3 * H * W */
    int      h, w, P;    /* patch grid */
    int      learned;    /* sets fed so far */
    int      ready;
    uint8_t *samples;    /* [K][n] */
    uint8_t *bg, *thr;   /* [n] median; per-value threshold (8-bit units) */
    uint8_t *pix;        /* [views * H * W] changed pixels of the last mask */
    uint8_t *patch_fg;   /* [views * P] */
    uint8_t *tmp;        /* [views * P] dilation rows */
    int      need;       /* changed pixels that make a patch foreground */
};

static uint8_t to_u8(float v)
{
    /* NaN and out-of-range inputs land on the ends; 0.5 rounds half up */
    if (!(v > 0.0f))
        return 0;
    if (v >= 1.0f)
        return 255;
    return (uint8_t)(v * 255.0f + 0.5f);
}

int fg_new(const struct fg_config *cfg, fg_model **out, struct f4d_err *err)
{
    if (!out)
        return f4d_fail(err, F4D_EINVAL, "foreground: out is NULL");
    *out = NULL;
    if (!cfg)
        return f4d_fail(err, F4D_EINVAL, "foreground: config is NULL");
    struct fg_config c = *cfg;
    if (c.views < 1 || c.views > FG_VIEWS_MAX)
        return f4d_fail(err, F4D_EINVAL, "foreground: %d views (1..%d)", c.views, FG_VIEWS_MAX);
    if (c.patch < 1 || c.patch > 256)
        return f4d_fail(err, F4D_EINVAL, "foreground: patch size %d (1..256)", c.patch);
    if (c.height < c.patch || c.width < c.patch || c.height > FG_SIZE_MAX ||
        c.width > FG_SIZE_MAX || c.height % c.patch || c.width % c.patch)
        return f4d_fail(err, F4D_EINVAL, "foreground: frame %dx%d is not a multiple of the "
                        "patch size %d (or exceeds %d)", c.width, c.height, c.patch, FG_SIZE_MAX);
    if (c.samples < 1 || c.samples > FG_SAMPLES_MAX)
        return f4d_fail(err, F4D_EINVAL, "foreground: %d learning samples (1..%d)", c.samples,
                        FG_SAMPLES_MAX);
    if (!(c.threshold >= 0.0f && c.threshold <= 1.0f))
        return f4d_fail(err, F4D_EINVAL, "foreground: threshold %g (0..1)", (double)c.threshold);
    if (!(c.noise_k >= 0.0f && c.noise_k <= 100.0f))
        return f4d_fail(err, F4D_EINVAL, "foreground: noise_k %g (0..100)", (double)c.noise_k);
    if (!(c.min_fraction >= 0.0f && c.min_fraction <= 1.0f))
        return f4d_fail(err, F4D_EINVAL, "foreground: min_fraction %g (0..1)",
                        (double)c.min_fraction);
    if (c.threshold == 0.0f)
        c.threshold = 0.1f;
    if (c.noise_k == 0.0f)
        c.noise_k = 5.0f;
    if (c.min_fraction == 0.0f)
        c.min_fraction = 0.02f;
    fg_model *g = calloc(1, sizeof *g);
    if (!g)
        return f4d_fail(err, F4D_ENOMEM, "foreground: out of memory");
    g->c = c;
    g->h = c.height / c.patch;
    g->w = c.width / c.patch;
    g->P = g->h * g->w;
    const size_t hw = (size_t)c.height * (size_t)c.width;
    g->n = (size_t)c.views * 3 * hw;
    int need = (int)ceilf(c.min_fraction * (float)(c.patch * c.patch));
    g->need = need < 1 ? 1 : need;
    g->samples = malloc((size_t)c.samples * g->n);
    g->bg = malloc(g->n);
    g->thr = malloc(g->n);
    g->pix = calloc((size_t)c.views * hw, 1);
    g->patch_fg = malloc((size_t)c.views * (size_t)g->P);
    g->tmp = malloc((size_t)c.views * (size_t)g->P);
    if (!g->samples || !g->bg || !g->thr || !g->pix || !g->patch_fg || !g->tmp) {
        const size_t n = g->n;
        fg_free(g);
        return f4d_fail(err, F4D_ENOMEM, "foreground: out of memory for %d samples of %zu bytes",
                        c.samples, n);
    }
    *out = g;
    return 0;
}

void fg_free(fg_model *g)
{
    if (!g)
        return;
    free(g->samples);
    free(g->bg);
    free(g->thr);
    free(g->pix);
    free(g->patch_fg);
    free(g->tmp);
    free(g);
}

int fg_ready(const fg_model *g) { return g->ready; }

void fg_reset(fg_model *g)
{
    g->learned = 0;
    g->ready = 0;
}

const uint8_t *fg_pixels(const fg_model *g) { return g->pix; }
const uint8_t *fg_background(const fg_model *g) { return g->ready ? g->bg : NULL; }

static void sort_u8(uint8_t *v, int n)
{
    for (int i = 1; i < n; i++) {
        uint8_t x = v[i];
        int j = i - 1;
        for (; j >= 0 && v[j] > x; j--)
            v[j + 1] = v[j];
        v[j + 1] = x;
    }
}

/* Median and MAD of every value's K samples -> background and threshold.
 * A MAD of a handful of samples is itself noisy (K = 9 often reads half the
 * true spread), so each pixel's noise is the larger of its own MAD and the
 * median MAD of its view and channel: the sensor's floor. g->thr holds the
 * per-pixel MAD until the pooled one is known. */
static void build(fg_model *g)
{
    const int K = g->c.samples;
    const float floor_thr = g->c.threshold * 255.0f, k = g->c.noise_k * 1.4826f;
    const size_t plane = (size_t)g->c.height * (size_t)g->c.width;
    uint8_t v[FG_SAMPLES_MAX], d[FG_SAMPLES_MAX];
    for (size_t i = 0; i < g->n; i++) {
        for (int s = 0; s < K; s++)
            v[s] = g->samples[(size_t)s * g->n + i];
        sort_u8(v, K);
        const int med = v[K / 2];
        for (int s = 0; s < K; s++)
            d[s] = (uint8_t)abs((int)v[s] - med);
        sort_u8(d, K);
        g->bg[i] = (uint8_t)med;
        g->thr[i] = d[K / 2];
    }
    for (size_t pl = 0; pl < (size_t)g->c.views * 3; pl++) {
        uint8_t *t = g->thr + pl * plane;
        size_t hist[256] = { 0 }, acc = 0;
        int pooled = 0;
        for (size_t i = 0; i < plane; i++)
            hist[t[i]]++;
        while (pooled < 255 && (acc += hist[pooled]) < (plane + 1) / 2)
            pooled++;
        for (size_t i = 0; i < plane; i++) {
            float th = k * (float)(t[i] > pooled ? t[i] : pooled);
            th = th > floor_thr ? th : floor_thr;
            t[i] = (uint8_t)(th >= 255.0f ? 255 : (int)th);
        }
    }
}

int fg_learn(fg_model *g, const float *images, struct f4d_err *err)
{
    if (!g || !images)
        return f4d_fail(err, F4D_EINVAL, "foreground: fg_learn with a NULL %s",
                        g ? "image set" : "model");
    if (g->ready)
        return f4d_fail(err, F4D_EINVAL, "foreground: the background is already learned "
                        "(%d sets); fg_reset to learn again", g->c.samples);
    uint8_t *dst = g->samples + (size_t)g->learned * g->n;
    for (size_t i = 0; i < g->n; i++)
        dst[i] = to_u8(images[i]);
    if (++g->learned < g->c.samples)
        return 0;
    build(g);
    g->ready = 1;
    return 1;
}

/* Square dilation by m patches on each view's h x w grid, separable: a max
 * over rows, then over columns. */
static void dilate(fg_model *g, uint8_t *keep, int m)
{
    const int h = g->h, w = g->w;
    for (int v = 0; v < g->c.views; v++) {
        const uint8_t *src = g->patch_fg + (size_t)v * g->P;
        uint8_t *t = g->tmp + (size_t)v * g->P, *dst = keep + (size_t)v * g->P;
        for (int r = 0; r < h; r++)
            for (int c = 0; c < w; c++) {
                uint8_t a = 0;
                for (int dc = c - m < 0 ? 0 : c - m; dc <= c + m && dc < w && !a; dc++)
                    a = src[r * w + dc];
                t[r * w + c] = a;
            }
        for (int r = 0; r < h; r++)
            for (int c = 0; c < w; c++) {
                uint8_t a = 0;
                for (int dr = r - m < 0 ? 0 : r - m; dr <= r + m && dr < h && !a; dr++)
                    a = t[dr * w + c];
                dst[r * w + c] = a;
            }
    }
}

int fg_mask(fg_model *g, const float *images, int margin, uint8_t *keep, int *kept,
            struct f4d_err *err)
{
    if (!g || !images || !keep)
        return f4d_fail(err, F4D_EINVAL, "foreground: fg_mask with a NULL %s",
                        !g ? "model" : !images ? "image set" : "keep-list");
    if (!g->ready)
        return f4d_fail(err, F4D_EINVAL, "foreground: background not learned yet (%d of %d "
                        "sets)", g->learned, g->c.samples);
    if (margin < 0 || margin > g->h + g->w)
        return f4d_fail(err, F4D_EINVAL, "foreground: margin %d (0..%d patches)", margin,
                        g->h + g->w);
    const int H = g->c.height, W = g->c.width, p = g->c.patch;
    const size_t hw = (size_t)H * (size_t)W;
    for (int v = 0; v < g->c.views; v++) {
        const float *im = images + (size_t)v * 3 * hw;
        const uint8_t *bg = g->bg + (size_t)v * 3 * hw, *thr = g->thr + (size_t)v * 3 * hw;
        uint8_t *pix = g->pix + (size_t)v * hw;
        for (size_t i = 0; i < hw; i++) {
            int ch = 0;
            for (int c = 0; c < 3 && !ch; c++) {
                const size_t j = (size_t)c * hw + i;
                /* NaN counts as changed: a broken pixel is not background */
                float dv = fabsf(im[j] * 255.0f - (float)bg[j]);
                ch = !(dv <= (float)thr[j]);
            }
            pix[i] = (uint8_t)ch;
        }
        uint8_t *pf = g->patch_fg + (size_t)v * g->P;
        for (int r = 0; r < g->h; r++)
            for (int c = 0; c < g->w; c++) {
                int cnt = 0;
                for (int y = r * p; y < (r + 1) * p; y++)
                    for (int x = c * p; x < (c + 1) * p; x++)
                        cnt += pix[(size_t)y * W + x];
                pf[r * g->w + c] = cnt >= g->need;
            }
    }
    dilate(g, keep, margin);
    if (kept)
        for (int v = 0; v < g->c.views; v++) {
            int k = 0;
            for (int i = 0; i < g->P; i++)
                k += keep[(size_t)v * g->P + i];
            kept[v] = k;
        }
    return 0;
}
