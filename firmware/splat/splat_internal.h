/* splat_internal.h - helpers shared by the splat sources (not installed). */
#ifndef F4D_SPLAT_INTERNAL_H
#define F4D_SPLAT_INTERNAL_H

#include <stdarg.h>
#include <stdio.h>

#include "splat.h"

#if defined(__GNUC__)
__attribute__((format(printf, 3, 4)))
#endif
static inline int splat__fail(struct splat_error *err, int code, const char *fmt, ...)
{
    if (err) {
        va_list ap;
        va_start(ap, fmt);
        vsnprintf(err->msg, sizeof err->msg, fmt, ap);
        va_end(ap);
    }
    return code;
}

/* Rotation matrix (row-major 3x3) of a quaternion (w,x,y,z), normalised here;
 * a zero or non-finite quaternion gives the identity. */
void splat__quat_to_mat(const float q[4], float m[9]);

#endif
