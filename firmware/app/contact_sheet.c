/* contact_sheet.c: a PNG grid of the views of one set (libpng simplified API). */
#include "contact_sheet.h"

#include <png.h>
#include <stdlib.h>
#include <string.h>

#include "f4d_take.h"

#define GAP 4

static void to_rgb(const struct f4d_take_frame *f, uint8_t *dst, size_t dst_stride)
{
    const struct hal_format *fmt = &f->meta.format;
    for (uint32_t y = 0; y < fmt->height; y++) {
        const uint8_t *s = f->data + (size_t)y * fmt->stride;
        uint8_t *d = dst + (size_t)y * dst_stride;
        bool row_ok = (size_t)(y + 1) * fmt->stride <= f->bytes;
        for (uint32_t x = 0; x < fmt->width; x++) {
            uint8_t r = 0, g = 0, b = 0;
            if (row_ok) {
                switch (fmt->pixfmt) {
                case HAL_PIXFMT_RGB8: r = s[3 * x], g = s[3 * x + 1], b = s[3 * x + 2]; break;
                case HAL_PIXFMT_MONO16: r = g = b = s[2 * x + 1]; break;
                case HAL_PIXFMT_YUYV: r = g = b = s[2 * x]; break;
                default: r = g = b = s[x]; break; /* mono8, raw bayer shown as grey */
                }
            }
            d[3 * x] = r;
            d[3 * x + 1] = g;
            d[3 * x + 2] = b;
        }
    }
}

int f4d_contact_sheet(const char *dir, uint64_t index, const char *png_path, struct f4d_err *err)
{
    struct f4d_take_reader *r;
    int rc = f4d_take_open(&r, dir, err);
    if (rc < 0)
        return rc;
    const struct f4d_take_info *info = f4d_take_get_info(r);
    struct f4d_take_set s;
    uint64_t n = f4d_take_count(r);
    if (index == UINT64_MAX) {
        for (index = 0; index < n; index++)
            if (f4d_take_read(r, index, &s) == F4D_OK && s.complete)
                break;
        if (index == n)
            index = 0;
    }
    if (index >= n) {
        f4d_take_reader_close(r);
        return f4d_fail(err, F4D_EINVAL, "sheet: take %s has %llu sets, no set %llu", dir,
                        (unsigned long long)n, (unsigned long long)index);
    }
    if ((rc = f4d_take_read(r, index, &s)) < 0) {
        f4d_take_reader_close(r);
        return f4d_fail(err, rc, "sheet: set %llu of %s is corrupt", (unsigned long long)index, dir);
    }
    uint32_t cw = 0, ch = 0;
    for (uint32_t c = 0; c < info->n_cams; c++) {
        if (info->formats[c].width > cw)
            cw = info->formats[c].width;
        if (info->formats[c].height > ch)
            ch = info->formats[c].height;
    }
    uint32_t cols = info->n_cams <= 1 ? 1 : info->n_cams <= 4 ? 2 : 4;
    uint32_t rows = (info->n_cams + cols - 1) / cols;
    uint32_t W = cols * cw + (cols + 1) * GAP, H = rows * ch + (rows + 1) * GAP;
    uint8_t *img = malloc((size_t)W * H * 3);
    if (!img) {
        f4d_take_reader_close(r);
        return f4d_fail(err, F4D_ENOMEM, "sheet: out of memory");
    }
    memset(img, 24, (size_t)W * H * 3);
    for (uint32_t c = 0; c < info->n_cams; c++) {
        uint8_t *cell = img + ((size_t)(GAP + (c / cols) * (ch + GAP)) * W + GAP + (c % cols) * (cw + GAP)) * 3;
        if (s.frames[c].present) {
            to_rgb(&s.frames[c], cell, (size_t)W * 3);
        } else {
            for (uint32_t y = 0; y < ch; y++)
                memset(cell + (size_t)y * W * 3, 128, (size_t)cw * 3);
        }
    }
    f4d_take_reader_close(r);
    png_image pi;
    memset(&pi, 0, sizeof pi);
    pi.version = PNG_IMAGE_VERSION;
    pi.width = W;
    pi.height = H;
    pi.format = PNG_FORMAT_RGB;
    int ok = png_image_write_to_file(&pi, png_path, 0, img, (png_int_32)(W * 3), NULL);
    free(img);
    if (!ok)
        return f4d_fail(err, F4D_EIO, "sheet: cannot write %s: %s", png_path, pi.message);
    return F4D_OK;
}
