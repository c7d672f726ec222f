/* splat_internal.h - helpers shared by the splat sources (not installed). */
#ifndef F4D_SPLAT_INTERNAL_H
#define F4D_SPLAT_INTERNAL_H

#include <math.h>
#include <stdarg.h>
#include <stdio.h>

#include "splat.h"


/* Rotation matrix (row-major 3x3) of a quaternion (w,x,y,z), normalised here;
 * a zero or non-finite quaternion gives the identity. Inline: the
 * rasterizer's preprocessing calls it per Gaussian. */
static inline void splat__quat_to_mat(const float q[4], float m[9])
{
    float w = q[0], x = q[1], y = q[2], z = q[3];
    float n2 = w * w + x * x + y * y + z * z;
    if (!(n2 > 1e-30f) || !isfinite(n2)) {
        w = 1.0f;
        x = y = z = 0.0f;
    } else {
        float inv = 1.0f / sqrtf(n2);
        w *= inv; x *= inv; y *= inv; z *= inv;
    }
    m[0] = 1.f - 2.f * (y * y + z * z); m[1] = 2.f * (x * y - w * z);       m[2] = 2.f * (x * z + w * y);
    m[3] = 2.f * (x * y + w * z);       m[4] = 1.f - 2.f * (x * x + z * z); m[5] = 2.f * (y * z - w * x);
    m[6] = 2.f * (x * z - w * y);       m[7] = 2.f * (y * z + w * x);       m[8] = 1.f - 2.f * (x * x + y * y);
}

#endif
