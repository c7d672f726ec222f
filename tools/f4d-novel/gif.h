/* gif.h: animated GIF writer for f4d-novel (giflib): RGB float frames in,
 * a fixed 6x6x6 colour cube with 4x4 ordered dithering out, looping forever.
 * Tool-internal (tools/f4d-novel); the firmware writes no GIFs.
 *
 *     struct novel_gif *g;
 *     if (novel_gif_open("out.gif", 1036, 518, &g, &err) < 0) puts(err.msg);
 *     novel_gif_frame(g, rgb, 10, &err);       // rgb [H*W*3] in [0,1], 10 cs
 *     novel_gif_close(g, &err);                // frees g, also on error
 */
#ifndef F4D_NOVEL_GIF_H
#define F4D_NOVEL_GIF_H

#include "f4d_status.h"

struct novel_gif;
int novel_gif_open(const char *path, int width, int height, struct novel_gif **out, struct f4d_err *err);
int novel_gif_frame(struct novel_gif *g, const float *rgb, int delay_cs, struct f4d_err *err);
int novel_gif_close(struct novel_gif *g, struct f4d_err *err);

#endif
