/* image_io.c - PNG through libpng's simplified API, and the NumPy .npy writer. */
#include <errno.h>
#include <png.h>
#include <stdlib.h>
#include <string.h>

#include "splat_internal.h"

static unsigned char quantize(float v)
{
    /* torchvision save_image: mul(255).add(0.5).clamp(0, 255) then truncation */
    float q = v * 255.0f + 0.5f;
    if (!(q > 0.0f))
        return 0; /* also NaN */
    if (q >= 255.0f)
        return 255;
    return (unsigned char)q;
}

int splat_png_write_rgb(const char *path, const float *rgb, int width, int height, struct f4d_err *err)
{
    if (!path || !rgb || width <= 0 || height <= 0)
        return f4d_fail(err, F4D_EINVAL, "png_write: bad arguments (size %dx%d)", width, height);
    size_t n = (size_t)width * (size_t)height * 3;
    unsigned char *buf = malloc(n);
    if (!buf)
        return f4d_fail(err, F4D_ENOMEM, "png_write: out of memory");
    for (size_t i = 0; i < n; i++)
        buf[i] = quantize(rgb[i]);
    png_image img;
    memset(&img, 0, sizeof img);
    img.version = PNG_IMAGE_VERSION;
    img.width = (png_uint_32)width;
    img.height = (png_uint_32)height;
    img.format = PNG_FORMAT_RGB;
    int ok = png_image_write_to_file(&img, path, 0, buf, 0, NULL);
    free(buf);
    if (!ok) {
        int rc = f4d_fail(err, F4D_EIO, "png: cannot write '%s': %s", path, img.message);
        png_image_free(&img);
        return rc;
    }
    return F4D_OK;
}

int splat_png_read_rgb(const char *path, float **rgb, int *width, int *height, struct f4d_err *err)
{
    if (!path || !rgb || !width || !height)
        return f4d_fail(err, F4D_EINVAL, "png_read: NULL argument");
    *rgb = NULL;
    png_image img;
    memset(&img, 0, sizeof img);
    img.version = PNG_IMAGE_VERSION;
    if (!png_image_begin_read_from_file(&img, path))
        return f4d_fail(err, F4D_EIO, "png: cannot read '%s': %s", path, img.message);
    img.format = PNG_FORMAT_RGB;
    size_t n = PNG_IMAGE_SIZE(img);
    unsigned char *buf = malloc(n ? n : 1);
    float *out = malloc((n ? n : 1) * sizeof *out);
    if (!buf || !out) {
        png_image_free(&img);
        free(buf);
        free(out);
        return f4d_fail(err, F4D_ENOMEM, "png: out of memory reading '%s'", path);
    }
    if (!png_image_finish_read(&img, NULL, buf, 0, NULL)) {
        int rc = f4d_fail(err, F4D_EFORMAT, "png: cannot decode '%s': %s", path, img.message);
        free(buf);
        free(out);
        return rc;
    }
    for (size_t i = 0; i < n; i++)
        out[i] = (float)buf[i] / 255.0f;
    free(buf);
    *rgb = out;
    *width = (int)img.width;
    *height = (int)img.height;
    return F4D_OK;
}

int splat_npy_write_f32(const char *path, const float *data, const size_t *shape, int ndim,
                        struct f4d_err *err)
{
    if (!path || !data || !shape || ndim < 1 || ndim > 8)
        return f4d_fail(err, F4D_EINVAL, "npy_write: bad arguments");
    char dims[256];
    size_t o = 0, n = 1;
    for (int k = 0; k < ndim; k++) {
        o += (size_t)snprintf(dims + o, sizeof dims - o, "%zu%s", shape[k],
                              ndim == 1 ? "," : (k + 1 < ndim ? ", " : ""));
        n *= shape[k];
    }
    char header[512];
    int hl = snprintf(header, sizeof header, "{'descr': '<f4', 'fortran_order': False, 'shape': (%s), }", dims);
    /* magic(6) + version(2) + len(2) + header padded with spaces to a multiple of 64, ending in \n */
    int total = 10 + hl + 1;
    int pad = (64 - total % 64) % 64;
    FILE *fp = fopen(path, "wb");
    if (!fp)
        return f4d_fail(err, F4D_EIO, "npy: cannot create '%s': %s", path, strerror(errno));
    unsigned short len = (unsigned short)(hl + pad + 1);
    unsigned char pre[10] = { 0x93, 'N', 'U', 'M', 'P', 'Y', 1, 0, (unsigned char)(len & 255),
                              (unsigned char)(len >> 8) };
    int ok = fwrite(pre, 1, 10, fp) == 10 && fwrite(header, 1, (size_t)hl, fp) == (size_t)hl;
    for (int k = 0; k < pad && ok; k++)
        ok = fputc(' ', fp) != EOF;
    ok = ok && fputc('\n', fp) != EOF;
    ok = ok && fwrite(data, sizeof(float), n, fp) == n; /* little-endian host assumed (x86, ARM) */
    if (fclose(fp) != 0)
        ok = 0;
    if (!ok)
        return f4d_fail(err, F4D_EIO, "npy: error writing '%s'", path);
    return F4D_OK;
}
