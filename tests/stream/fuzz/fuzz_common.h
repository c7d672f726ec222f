/* fuzz_common.h - the deterministic frames the fuzz harnesses prime their
 * decoder with and the seed generator encodes (shared so that seeded
 * predicted payloads reference the key the harness holds). */
#ifndef F4D_FUZZ_STREAM_COMMON_H
#define F4D_FUZZ_STREAM_COMMON_H

#include <math.h>

#include "f4d_codec.h"

#define FUZZ_CAP 4096
#define FUZZ_N   64

/* Key k (0 or 1) of a small moving cloud with motion; returns 0 on success. */
static inline int fuzz_frame(int k, struct splat_frame *f)
{
    if (splat_frame_resize(f, FUZZ_N + 8 * (size_t)k, 1, NULL) < 0)
        return -1;
    for (size_t i = 0; i < f->count; i++) {
        float a = 0.37f * (float)i;
        f->pos[3 * i] = cosf(a) + 0.01f * (float)k;
        f->pos[3 * i + 1] = sinf(a);
        f->pos[3 * i + 2] = 0.02f * (float)i;
        for (int c = 0; c < 3; c++) {
            f->scale[3 * i + c] = 0.01f + 0.001f * (float)((i + (size_t)c) % 7);
            f->rgb[3 * i + c] = 0.1f * (float)((i * 3 + (size_t)c) % 10);
            f->motion_fwd[3 * i + c] = c == 0 ? 0.01f : 0.0f;
            f->motion_bwd[3 * i + c] = c == 0 ? -0.01f : 0.0f;
        }
        /* key 1 turns every Gaussian by 0.2 rad more: a common rotation,
         * which version 3 sends as block rotations (seeds with them) */
        f->rot[4 * i] = cosf(a * 0.5f + 0.1f * (float)k);
        f->rot[4 * i + 1] = sinf(a * 0.5f + 0.1f * (float)k);
        f->rot[4 * i + 2] = f->rot[4 * i + 3] = 0.0f;
        f->opacity[i] = 0.5f + 0.4f * sinf(a);
    }
    return 0;
}

#endif
