/* display_internal.h - what the display's sources share (not installed):
 * the clock, the bitmap font and the EGL/GLES presenter. */
#ifndef F4D_DISPLAY_INTERNAL_H
#define F4D_DISPLAY_INTERNAL_H

#include <stdint.h>

#include "f4d_display.h"

#define DISPLAY_GLYPH_ADVANCE 6 /* 5 columns + 1 of spacing */
#define DISPLAY_LOOKUP_PX     518 /* longest side of the default lookup view */

double display__now_ms(void);
/* Process CPU time (every thread), ms. */
double display__cpu_ms(void);

/* 7 rows of 5 bits of character c (bit 4 = leftmost column). */
const unsigned char *display__glyph(char c);
/* Draws s into an RGBA8 image (w x h, top row first) at (x0, y0), each font
 * pixel a scale x scale block of colour. */
void display__text(uint8_t *rgba, int w, int h, int x0, int y0, int scale, const char *s, const uint8_t colour[4]);

/* ---- the presenter (gl.c): EGL output + GLES drawing ---------------------------- */
typedef struct display_gl display_gl;

struct display_input {         /* what the window reported since the last poll */
    int   quit, reset;
    float move[3];             /* right, up, forward steps (key presses)         */
    float turn[2];             /* yaw, pitch in radians                          */
};

int  display__gl_open(enum display_output out, int width, int height, const char *kms_device, display_gl **g,
                      struct f4d_err *err);
void display__gl_close(display_gl *g);
void display__gl_size(const display_gl *g, int *width, int *height);
const char *display__gl_renderer(const display_gl *g);
/* Instance buffers for up to n Gaussians (allocates: call at planning time). */
int  display__gl_plan(display_gl *g, size_t n, struct f4d_err *err);
/* GLES splats of f seen by cam into the scene target (back to front). */
int  display__gl_draw_splats(display_gl *g, const struct splat_camera *cam, const struct splat_frame *f,
                             const float bg[3], struct f4d_err *err);
/* RGBA8 image (bottom row first, GL's order; width x height of the output) as the scene
 * (RGBA: the layout the driver keeps, so the upload is a copy). */
int  display__gl_upload(display_gl *g, const uint8_t *rgba, struct f4d_err *err);
/* Draws the scene (from the last draw_splats or upload) and the overlay
 * (RGBA8, width x overlay_h, premultiplied, top row first; NULL = none) into
 * the output's framebuffer. */
int  display__gl_compose(display_gl *g, int from_upload, const uint8_t *overlay, int overlay_h, struct f4d_err *err);
/* The output framebuffer as RGB8 top row first (rgba: scratch of 4 W H). */
int  display__gl_read(display_gl *g, uint8_t *rgb, uint8_t *rgba, struct f4d_err *err);
/* Waits for the GL work of the frame (timing). */
void display__gl_finish(display_gl *g);
/* Swap (window), page flip (KMS) or nothing (headless). */
int  display__gl_present(display_gl *g, struct f4d_err *err);
/* Window events since the last call (no-op for other outputs). */
void display__gl_poll(display_gl *g, struct display_input *in);

#endif /* F4D_DISPLAY_INTERNAL_H */
