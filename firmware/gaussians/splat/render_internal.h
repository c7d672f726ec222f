/* render_internal.h - what the scalar and the SIMD compositing share. */
#ifndef F4D_SPLAT_RENDER_INTERNAL_H
#define F4D_SPLAT_RENDER_INTERNAL_H

#include <math.h>
#include <stdint.h>

#include "splat.h"

/* One projected Gaussian: one cache line, read once per tile it touches. */
struct projected {
    float   mx, my;       /* mean in pixels, R convention (integer centres) */
    float   A, B, C;      /* conic: inverse of the dilated 2D covariance */
    float   o;            /* opacity */
    float   k2;           /* alpha >= 1/255 needs d' conic d <= k2 */
    float   ey;           /* half height (px) of that ellipse, with margin */
    float   ex;           /* half width (px) of that ellipse, with margin */
    float   z;            /* camera depth */
    float   col[3];       /* colour (or feature) */
    int32_t id;           /* index in the frame */
    int16_t rect[4];      /* tiles x0, y0, x1, y1 (exclusive) */
};
_Static_assert(sizeof(struct projected) == 64, "one projected Gaussian per cache line");

/* Narrows P->rect (the reference's 3-sigma tile rectangle) to the tiles the
 * compositors can touch: both composite a Gaussian only on pixel columns
 * ceil(mx - ex) .. floor(mx + ex) and rows ceil(my - ey) .. floor(my + ey)
 * (where its alpha can reach 1/255), so a tile outside that box adds nothing
 * and is left out of the lists: the same image from fewer Gaussian-tile pairs
 * (a quarter of them in the walk scene at 1280x720). 0: no tile left. */
static inline int splat__narrow_rect(struct projected *P, int tiles_x, int tiles_y)
{
    const float inv = 1.0f / (float)SPLAT_TILE; /* a power of 2: exact */
    float bx0 = floorf(ceilf(P->mx - P->ex) * inv), bx1 = floorf(floorf(P->mx + P->ex) * inv) + 1.0f;
    float by0 = floorf(ceilf(P->my - P->ey) * inv), by1 = floorf(floorf(P->my + P->ey) * inv) + 1.0f;
    const float gx = (float)tiles_x, gy = (float)tiles_y;
    bx0 = bx0 > 0.0f ? (bx0 < gx ? bx0 : gx) : 0.0f;
    bx1 = bx1 > 0.0f ? (bx1 < gx ? bx1 : gx) : 0.0f;
    by0 = by0 > 0.0f ? (by0 < gy ? by0 : gy) : 0.0f;
    by1 = by1 > 0.0f ? (by1 < gy ? by1 : gy) : 0.0f;
    int x0 = (int)bx0, x1 = (int)bx1, y0 = (int)by0, y1 = (int)by1;
    if (x0 > P->rect[0]) P->rect[0] = (int16_t)x0;
    if (y0 > P->rect[1]) P->rect[1] = (int16_t)y0;
    if (x1 < P->rect[2]) P->rect[2] = (int16_t)x1;
    if (y1 < P->rect[3]) P->rect[3] = (int16_t)y1;
    return P->rect[0] < P->rect[2] && P->rect[1] < P->rect[3];
}

/* What preprocessing needs, for any Gaussian. */
struct prep_view {
    const struct splat_frame *f;
    const float              *features;  /* NULL: rgb clamped to >= 0 */
    struct projected         *proj;      /* output, frame order */
    const float              *V;         /* world_to_camera, row-major */
    float fx, fy, cx, cy;
    float lim_x_pos, lim_x_neg, lim_y_pos, lim_y_neg;
    int   tiles_x, tiles_y;
};

/* Preprocesses Gaussians i0 .. i0 + 7 like render.c's scalar prep_one, bit
 * for bit (same operations in the same order, no fused multiply-adds, libm's
 * logf per lane); returns the visibility mask, bit l for Gaussian i0 + l. */
unsigned splat__prep8_avx2(const struct prep_view *pv, size_t i0);

/* What one compositing pass needs, for any tile. */
struct raster_ctx {
    const struct projected *proj;        /* frame order; pairs index it */
    const int32_t          *pairs;
    const uint32_t         *tile_start;
    int                     width, height, tiles_x;
};

struct raster_job {
    struct raster_ctx rc;
    const float    *bg;
    float          *rgb, *alpha, *depth;
    int32_t        *top;
    uint8_t        *rgba8;     /* quantised colour over bg, alpha 255 */
    int             rgba8_up;  /* rgba8 rows bottom first */
    int             normalize; /* features: divide by accumulated alpha */
};

/* Composites one 16x16 tile (index `tile`) of job j. raster_tile_ref is the
 * scalar specification; raster_tile_avx2 evaluates 8 pixels of a row at once
 * with a vector exp accurate to 2 ulp (libm's expf in the scalar path). */
void splat__raster_tile_ref (const struct raster_job *j, int tile);
void splat__tile_write      (const struct raster_job *j, int tile, const float *T, const float *C0,
                             const float *C1, const float *C2, const float *D, const int32_t *top);
void splat__raster_tile_avx2(const struct raster_job *j, int tile);
/* The same on 16 lanes (AVX-512 F/BW/VL), bit-identical to the AVX2 one:
 * narrow boxes take 4 rows of 4 or 2 rows of 8 pixels per step. */
void splat__raster_tile_avx512(const struct raster_job *j, int tile);
/* The same with 4 pixels per step (AArch64 NEON, arm/raster_neon.c). */
void splat__raster_tile_neon(const struct raster_job *j, int tile);

#endif
