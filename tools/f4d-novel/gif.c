/* gif.c: see gif.h. */
#include "gif.h"

#include <gif_lib.h>
#include <stdbool.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

struct novel_gif {
    GifFileType *f;
    int w, h;
    GifByteType *row;
    char path[512];
};

static int gif_fail(struct novel_gif *g, struct f4d_err *err, const char *what, int code)
{
    return f4d_fail(err, F4D_EIO, "gif %s: %s: %s", g ? g->path : "?", what, GifErrorString(code));
}

int novel_gif_open(const char *path, int width, int height, struct novel_gif **out, struct f4d_err *err)
{
    *out = NULL;
    if (!path || width <= 0 || height <= 0 || width > 65535 || height > 65535)
        return f4d_fail(err, F4D_EINVAL, "gif: bad size %dx%d (1..65535) or no path", width, height);
    struct novel_gif *g = calloc(1, sizeof *g);
    if (!g || !(g->row = malloc((size_t)width))) {
        free(g);
        return f4d_fail(err, F4D_ENOMEM, "gif: out of memory");
    }
    snprintf(g->path, sizeof g->path, "%s", path);
    g->w = width;
    g->h = height;
    int code = 0;
    if (!(g->f = EGifOpenFileName(path, false, &code))) {
        int rc = gif_fail(g, err, "open", code);
        free(g->row);
        free(g);
        return rc;
    }
    EGifSetGifVersion(g->f, true); /* GIF89a: delays and the loop extension */
    ColorMapObject *cm = GifMakeMapObject(256, NULL);
    if (!cm) {
        EGifCloseFile(g->f, &code);
        free(g->row);
        free(g);
        return f4d_fail(err, F4D_ENOMEM, "gif: out of memory");
    }
    for (int i = 0; i < 256; i++) { /* 0..215: the cube; the rest grey */
        GifColorType *c = &cm->Colors[i];
        if (i < 216) {
            c->Red = (GifByteType)(51 * (i / 36));
            c->Green = (GifByteType)(51 * (i / 6 % 6));
            c->Blue = (GifByteType)(51 * (i % 6));
        } else {
            c->Red = c->Green = c->Blue = (GifByteType)((i - 216) * 255 / 39);
        }
    }
    int rc = EGifPutScreenDesc(g->f, width, height, 8, 0, cm);
    GifFreeMapObject(cm);
    static const GifByteType loop[3] = {1, 0, 0}; /* NETSCAPE2.0: loop forever */
    if (rc != GIF_OK || EGifPutExtensionLeader(g->f, APPLICATION_EXT_FUNC_CODE) != GIF_OK ||
        EGifPutExtensionBlock(g->f, 11, "NETSCAPE2.0") != GIF_OK || EGifPutExtensionBlock(g->f, 3, loop) != GIF_OK ||
        EGifPutExtensionTrailer(g->f) != GIF_OK) {
        rc = gif_fail(g, err, "header", g->f->Error);
        EGifCloseFile(g->f, &code);
        free(g->row);
        free(g);
        return rc;
    }
    *out = g;
    return 0;
}

int novel_gif_frame(struct novel_gif *g, const float *rgb, int delay_cs, struct f4d_err *err)
{
    if (!g || !rgb)
        return f4d_fail(err, F4D_EINVAL, "gif: NULL frame");
    delay_cs = delay_cs < 2 ? 2 : delay_cs > 65535 ? 65535 : delay_cs; /* viewers treat < 2 cs as 10 */
    GifByteType gce[4] = {0, (GifByteType)(delay_cs & 0xff), (GifByteType)(delay_cs >> 8), 0};
    if (EGifPutExtension(g->f, GRAPHICS_EXT_FUNC_CODE, 4, gce) != GIF_OK ||
        EGifPutImageDesc(g->f, 0, 0, g->w, g->h, false, NULL) != GIF_OK)
        return gif_fail(g, err, "frame", g->f->Error);
    /* 4x4 Bayer thresholds: the cube's 51-level steps dither instead of banding */
    static const int bayer[16] = {0, 8, 2, 10, 12, 4, 14, 6, 3, 11, 1, 9, 15, 7, 13, 5};
    for (int y = 0; y < g->h; y++) {
        for (int x = 0; x < g->w; x++) {
            float d = ((float)bayer[(y & 3) * 4 + (x & 3)] + 0.5f) / 16.0f;
            int q[3];
            for (int c = 0; c < 3; c++) {
                float v = rgb[((size_t)y * g->w + x) * 3 + c];
                v = v < 0 ? 0 : v > 1 ? 1 : v;
                int l = (int)(v * 5.0f + d);
                q[c] = l > 5 ? 5 : l;
            }
            g->row[x] = (GifByteType)(36 * q[0] + 6 * q[1] + q[2]);
        }
        if (EGifPutLine(g->f, g->row, g->w) != GIF_OK)
            return gif_fail(g, err, "pixels", g->f->Error);
    }
    return 0;
}

int novel_gif_close(struct novel_gif *g, struct f4d_err *err)
{
    if (!g)
        return 0;
    int code = 0, rc = 0;
    if (EGifCloseFile(g->f, &code) != GIF_OK)
        rc = gif_fail(g, err, "close", code);
    free(g->row);
    free(g);
    return rc;
}
