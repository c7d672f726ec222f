/* preprocess.c - VGGT's loader on camera frames: demosaic / grey -> RGB8, PIL
 * 8-bit BICUBIC resize, crop or pad, float CHW. */
#include "preprocess.h"

#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <string.h>

#define PREC_BITS 22        /* PIL: 32 - 8 - 2 */
#define KSIZE_MAX 512


static int round14(double v)
{
    return (int)nearbyint(v / 14.0) * 14; /* Python round: half to even */
}

/* Resized size before crop/pad, and the final size. */
static int sizes(int w, int h, enum prep_mode mode, int target, int *nw, int *nh, int *ow,
                 int *oh)
{
    if (w < 1 || h < 1 || target < 14 || target > 8192 || w > 65536 || h > 65536)
        return -1;
    if (mode == PREP_PAD && w < h) {
        *nh = target;
        *nw = round14(w * ((double)target / h));
    } else {
        *nw = target;
        *nh = round14(h * ((double)target / w));
    }
    if (*nw < 14 || *nh < 14)
        return -1;
    if (mode == PREP_PAD) {
        *ow = *oh = target;
    } else {
        *ow = *nw;
        *oh = *nh > target ? target : *nh;
    }
    return 0;
}

int prep_output_size(int w, int h, enum prep_mode mode, int target, int *ow, int *oh)
{
    int nw, nh;
    return sizes(w, h, mode, target, &nw, &nh, ow, oh);
}

static int ksize_of(int in, int out)
{
    double scale = (double)in / out, fs = scale < 1.0 ? 1.0 : scale;
    return (int)ceil(2.0 * fs) * 2 + 1;
}

static size_t coeff_bytes(int in, int out)
{
    return ((size_t)2 * out + (size_t)out * ksize_of(in, out)) * sizeof(int32_t);
}

static size_t bytes_for(int w, int h, int nw, int nh)
{
    size_t b = (size_t)w * h * 3 + (size_t)nw * h * 3 + (size_t)nw * nh * 3;
    b += coeff_bytes(w, nw) + coeff_bytes(h, nh) + 64;
    b += (size_t)nw * 3 * sizeof(int32_t) + 64; /* the vertical pass's row of sums */
    return b;
}

size_t prep_scratch_bytes(int w, int h, int target)
{
    size_t best = 0;
    for (int mode = PREP_CROP; mode <= PREP_PAD; mode++) {
        int nw, nh, ow, oh;
        if (sizes(w, h, (enum prep_mode)mode, target, &nw, &nh, &ow, &oh) == 0) {
            size_t b = bytes_for(w, h, nw, nh);
            best = b > best ? b : best;
        }
    }
    return best;
}

static double cubic(double x)
{
    const double a = -0.5;
    x = fabs(x);
    if (x < 1.0)
        return ((a + 2.0) * x - (a + 3.0)) * x * x + 1.0;
    if (x < 2.0)
        return (((x - 5.0) * x + 8.0) * x - 4.0) * a;
    return 0.0;
}

/* PIL precompute_coeffs + normalize_coeffs_8bpc: bounds[2*i] = first input,
 * bounds[2*i+1] = count, k[i*ksize + j] fixed-point weights. */
static void coeffs(int in, int out, int32_t *bounds, int32_t *k)
{
    const double scale = (double)in / out, fs = scale < 1.0 ? 1.0 : scale;
    const double support = 2.0 * fs, ss = 1.0 / fs;
    const int ksize = ksize_of(in, out);
    double w[KSIZE_MAX];
    for (int i = 0; i < out; i++) {
        double center = (i + 0.5) * scale, ww = 0.0;
        int xmin = (int)(center - support + 0.5), xmax = (int)(center + support + 0.5);
        if (xmin < 0)
            xmin = 0;
        if (xmax > in)
            xmax = in;
        xmax -= xmin;
        for (int x = 0; x < xmax; x++) {
            w[x] = cubic((x + xmin - center + 0.5) * ss);
            ww += w[x];
        }
        for (int x = 0; x < ksize; x++) {
            double v = x < xmax && ww != 0.0 ? w[x] / ww : 0.0;
            k[(size_t)i * ksize + x] = (int32_t)(v < 0 ? -0.5 + v * (1 << PREC_BITS)
                                                       : 0.5 + v * (1 << PREC_BITS));
        }
        bounds[2 * i] = xmin;
        bounds[2 * i + 1] = xmax;
    }
}

static uint8_t clip8(int32_t ss)
{
    if (ss < 0)
        return 0;
    ss >>= PREC_BITS;
    return (uint8_t)(ss > 255 ? 255 : ss);
}

void prep_demosaic_rggb(const uint8_t *src, size_t stride, int w, int h, uint8_t *rgb)
{
#define PX(yy, xx) ((int)src[(size_t)(yy) * stride + (size_t)(xx)])
    for (int y = 0; y < h; y++) {
        int yn = y > 0 ? y - 1 : (h > 1 ? 1 : 0), ys = y + 1 < h ? y + 1 : (h > 1 ? h - 2 : 0);
        for (int x = 0; x < w; x++) {
            int xw = x > 0 ? x - 1 : (w > 1 ? 1 : 0), xe = x + 1 < w ? x + 1 : (w > 1 ? w - 2 : 0);
            int cross = (PX(yn, x) + PX(ys, x) + PX(y, xw) + PX(y, xe) + 2) / 4;
            int diag = (PX(yn, xw) + PX(yn, xe) + PX(ys, xw) + PX(ys, xe) + 2) / 4;
            int horiz = (PX(y, xw) + PX(y, xe) + 1) / 2, vert = (PX(yn, x) + PX(ys, x) + 1) / 2;
            int r, g, b, v = PX(y, x);
            if (!(y & 1) && !(x & 1)) {
                r = v; g = cross; b = diag;
            } else if ((y & 1) && (x & 1)) {
                b = v; g = cross; r = diag;
            } else if (!(y & 1)) {
                g = v; r = horiz; b = vert;
            } else {
                g = v; r = vert; b = horiz;
            }
            uint8_t *o = rgb + ((size_t)y * w + x) * 3;
            o[0] = (uint8_t)r;
            o[1] = (uint8_t)g;
            o[2] = (uint8_t)b;
        }
    }
#undef PX
}

/* One frame: resized, cropped/padded, and placed at (top, left) of out
 * [3, OH, OW] (already filled with white by the caller). */
static int place(const struct prep_image *im, enum prep_mode mode, int target, void *scratch,
                 size_t scratch_bytes, float *out, int OH, int OW, int top, int left,
                 struct f4d_err *err)
{
    const int w = im->width, h = im->height;
    int nw, nh, ow, oh;
    if (!im->data || sizes(w, h, mode, target, &nw, &nh, &ow, &oh) < 0)
        return f4d_fail(err, F4D_EINVAL, "preprocess: frame %dx%d cannot be resized to target %d", w, h,
                    target);
    if (im->pixfmt != PREP_PIXFMT_RGB8 && im->pixfmt != PREP_PIXFMT_MONO8 &&
        im->pixfmt != PREP_PIXFMT_BAYER_RG8)
        return f4d_fail(err, F4D_EINVAL, "preprocess: pixel format %d is not RGB8, Mono8 or Bayer RG8",
                    im->pixfmt);
    size_t bpp = im->pixfmt == PREP_PIXFMT_RGB8 ? 3 : 1;
    if (im->stride < (size_t)w * bpp)
        return f4d_fail(err, F4D_EINVAL, "preprocess: stride %zu < %d bytes per row", im->stride,
                    (int)(w * bpp));
    if (ksize_of(w, nw) > KSIZE_MAX || ksize_of(h, nh) > KSIZE_MAX)
        return f4d_fail(err, F4D_EINVAL, "preprocess: %dx%d -> %dx%d shrinks too far", w, h, nw, nh);
    if (bytes_for(w, h, nw, nh) > scratch_bytes)
        return f4d_fail(err, F4D_EINVAL, "preprocess: scratch of %zu bytes < %zu needed for %dx%d",
                    scratch_bytes, bytes_for(w, h, nw, nh), w, h);
    /* scratch: int32 coefficients first (aligned), then the byte images */
    int32_t *hb = scratch, *hk = hb + 2 * nw;
    int32_t *vb = hk + (size_t)nw * ksize_of(w, nw), *vk = vb + 2 * nh;
    int32_t *acc = vk + (size_t)nh * ksize_of(h, nh); /* [nw * 3] */
    uint8_t *rgb = (uint8_t *)(acc + (size_t)nw * 3);
    uint8_t *tmp = rgb + (size_t)w * h * 3, *res = tmp + (size_t)nw * h * 3;

    /* RGB8 frames are read in place (rows of `stride` bytes); the others are
     * converted to packed RGB8 first */
    const uint8_t *src = im->data;
    size_t src_stride = im->stride;
    if (im->pixfmt != PREP_PIXFMT_RGB8) {
        if (im->pixfmt == PREP_PIXFMT_MONO8)
            for (int y = 0; y < h; y++) {
                const uint8_t *row = im->data + (size_t)y * im->stride;
                uint8_t *o = rgb + (size_t)y * w * 3;
                for (int x = 0; x < w; x++)
                    o[3 * x] = o[3 * x + 1] = o[3 * x + 2] = row[x];
            }
        else
            prep_demosaic_rggb(im->data, im->stride, w, h, rgb);
        src = rgb;
        src_stride = (size_t)w * 3;
    }

    /* PIL: horizontal pass first, each pass rounded to 8 bits. The sums are
     * PIL's integer sums (exact in any order), taken three channels at a time
     * horizontally and a whole row at a time vertically. */
    const uint8_t *hsrc = src;
    size_t hstride = src_stride;
    if (nw != w) {
        const int ks = ksize_of(w, nw);
        coeffs(w, nw, hb, hk);
        for (int y = 0; y < h; y++) {
            const uint8_t *row = src + (size_t)y * src_stride;
            uint8_t *o = tmp + (size_t)y * nw * 3;
            for (int x = 0; x < nw; x++) {
                const int32_t *k = hk + (size_t)x * ks;
                const uint8_t *p = row + (size_t)hb[2 * x] * 3;
                int32_t s0 = 1 << (PREC_BITS - 1), s1 = s0, s2 = s0;
                for (int j = 0; j < hb[2 * x + 1]; j++) {
                    s0 += p[3 * j] * k[j];
                    s1 += p[3 * j + 1] * k[j];
                    s2 += p[3 * j + 2] * k[j];
                }
                o[3 * x] = clip8(s0);
                o[3 * x + 1] = clip8(s1);
                o[3 * x + 2] = clip8(s2);
            }
        }
        hsrc = tmp;
        hstride = (size_t)nw * 3;
    }
    const uint8_t *img = hsrc;
    size_t istride = hstride;
    if (nh != h) {
        const int ks = ksize_of(h, nh);
        const size_t n3 = (size_t)nw * 3;
        coeffs(h, nh, vb, vk);
        for (int y = 0; y < nh; y++) {
            const int32_t *k = vk + (size_t)y * ks;
            for (size_t i = 0; i < n3; i++)
                acc[i] = 1 << (PREC_BITS - 1);
            for (int j = 0; j < vb[2 * y + 1]; j++) {
                const uint8_t *row = hsrc + ((size_t)vb[2 * y] + (size_t)j) * hstride;
                const int32_t kj = k[j];
                for (size_t i = 0; i < n3; i++)
                    acc[i] += row[i] * kj;
            }
            uint8_t *o = res + (size_t)y * n3;
            for (size_t i = 0; i < n3; i++)
                o[i] = clip8(acc[i]);
        }
        img = res;
        istride = (size_t)nw * 3;
    }
    /* crop: centre rows; pad: centred with white; then the batch offset. */
    int r0 = 0, rows = nh, pt = 0, pl = 0;
    if (mode == PREP_CROP && nh > target) {
        r0 = (nh - target) / 2;
        rows = target;
    }
    if (mode == PREP_PAD) {
        pt = (target - nh) / 2;
        pl = (target - nw) / 2;
    }
    top += pt;
    left += pl;
    if (top < 0 || left < 0 || top + rows > OH || left + nw > OW)
        return f4d_fail(err, F4D_EINVAL, "preprocess: internal placement error");
    for (int c = 0; c < 3; c++)
        for (int y = 0; y < rows; y++)
            for (int x = 0; x < nw; x++)
                out[((size_t)c * OH + top + y) * OW + left + x] =
                    (float)img[((size_t)r0 + y) * istride + (size_t)x * 3 + c] / 255.0f;
    return 0;
}

static void fill_white(float *out, size_t n)
{
    for (size_t i = 0; i < n; i++)
        out[i] = 1.0f;
}

int prep_image(const struct prep_image *im, enum prep_mode mode, int target, void *scratch,
               size_t scratch_bytes, float *out, int *ow, int *oh, struct f4d_err *err)
{
    if (prep_output_size(im->width, im->height, mode, target, ow, oh) < 0)
        return f4d_fail(err, F4D_EINVAL, "preprocess: frame %dx%d cannot be resized to target %d",
                    im->width, im->height, target);
    fill_white(out, (size_t)3 * *ow * *oh);
    return place(im, mode, target, scratch, scratch_bytes, out, *oh, *ow, 0, 0, err);
}

int prep_batch(const struct prep_image *ims, int n, enum prep_mode mode, int target,
               void *scratch, size_t scratch_bytes, float *out, int *H, int *W, struct f4d_err *err)
{
    int mh = 0, mw = 0;
    if (n < 1)
        return f4d_fail(err, F4D_EINVAL, "preprocess: no frames");
    for (int i = 0; i < n; i++) {
        int ow, oh;
        if (prep_output_size(ims[i].width, ims[i].height, mode, target, &ow, &oh) < 0)
            return f4d_fail(err, F4D_EINVAL, "preprocess: frame %d (%dx%d) cannot be resized to "
                        "target %d", i, ims[i].width, ims[i].height, target);
        mh = oh > mh ? oh : mh;
        mw = ow > mw ? ow : mw;
    }
    for (int i = 0; i < n; i++) {
        int ow, oh;
        prep_output_size(ims[i].width, ims[i].height, mode, target, &ow, &oh);
        float *o = out + (size_t)i * 3 * mh * mw;
        fill_white(o, (size_t)3 * mh * mw);
        if (place(&ims[i], mode, target, scratch, scratch_bytes, o, mh, mw, (mh - oh) / 2,
                  (mw - ow) / 2, err) < 0)
            return -1;
    }
    *H = mh;
    *W = mw;
    return 0;
}
