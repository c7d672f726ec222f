/* frame.c - the Gaussian frame: allocation, copy and validation. */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "splat_internal.h"

static int grow(float **p, size_t old_n, size_t n)
{
    float *q = realloc(*p, n * sizeof *q);
    if (!q)
        return -1;
    memset(q + old_n, 0, (n - old_n) * sizeof *q);
    *p = q;
    return 0;
}

int splat_frame_reserve(struct splat_frame *f, size_t capacity, int with_motion,
                        struct f4d_err *err)
{
    if (!f)
        return f4d_fail(err, F4D_EINVAL, "splat_frame_reserve: frame is NULL");
    if (capacity > SIZE_MAX / (4 * sizeof(float)))
        return f4d_fail(err, F4D_EINVAL, "splat_frame_reserve: %zu Gaussians is too many", capacity);
    size_t old = f->capacity;
    if (capacity > old) {
        if (grow(&f->pos, 3 * old, 3 * capacity) || grow(&f->scale, 3 * old, 3 * capacity) ||
            grow(&f->rot, 4 * old, 4 * capacity) || grow(&f->opacity, old, capacity) ||
            grow(&f->rgb, 3 * old, 3 * capacity) ||
            (f->motion_bwd && grow(&f->motion_bwd, 3 * old, 3 * capacity)) ||
            (f->motion_fwd && grow(&f->motion_fwd, 3 * old, 3 * capacity)))
            return f4d_fail(err, F4D_ENOMEM, "splat_frame_reserve: out of memory for %zu Gaussians", capacity);
        for (size_t i = old; i < capacity; i++)
            f->rot[4 * i] = 1.0f;
        f->capacity = capacity;
    }
    if (with_motion) {
        if (!f->motion_bwd && !(f->motion_bwd = calloc(3 * f->capacity + 1, sizeof(float))))
            return f4d_fail(err, F4D_ENOMEM, "splat_frame_reserve: out of memory for motion");
        if (!f->motion_fwd && !(f->motion_fwd = calloc(3 * f->capacity + 1, sizeof(float))))
            return f4d_fail(err, F4D_ENOMEM, "splat_frame_reserve: out of memory for motion");
    }
    return F4D_OK;
}

int splat_frame_resize(struct splat_frame *f, size_t n, int with_motion, struct f4d_err *err)
{
    int rc = splat_frame_reserve(f, n, with_motion, err);
    if (rc < 0)
        return rc;
    f->count = n;
    return F4D_OK;
}

int splat_frame_copy(struct splat_frame *dst, const struct splat_frame *src, struct f4d_err *err)
{
    if (!dst || !src)
        return f4d_fail(err, F4D_EINVAL, "splat_frame_copy: NULL frame");
    int motion = src->motion_bwd && src->motion_fwd;
    int rc = splat_frame_resize(dst, src->count, motion, err);
    if (rc < 0)
        return rc;
    size_t n = src->count;
    memcpy(dst->pos, src->pos, 3 * n * sizeof(float));
    memcpy(dst->scale, src->scale, 3 * n * sizeof(float));
    memcpy(dst->rot, src->rot, 4 * n * sizeof(float));
    memcpy(dst->opacity, src->opacity, n * sizeof(float));
    memcpy(dst->rgb, src->rgb, 3 * n * sizeof(float));
    if (motion) {
        memcpy(dst->motion_bwd, src->motion_bwd, 3 * n * sizeof(float));
        memcpy(dst->motion_fwd, src->motion_fwd, 3 * n * sizeof(float));
    }
    return F4D_OK;
}

void splat_frame_free(struct splat_frame *f)
{
    if (!f)
        return;
    free(f->pos);
    free(f->scale);
    free(f->rot);
    free(f->opacity);
    free(f->rgb);
    free(f->motion_bwd);
    free(f->motion_fwd);
    memset(f, 0, sizeof *f);
}

static int all_finite(const float *v, int n)
{
    for (int k = 0; k < n; k++)
        if (!isfinite(v[k]))
            return 0;
    return 1;
}

int splat_frame_validate(const struct splat_frame *f, struct f4d_err *err)
{
    if (!f)
        return f4d_fail(err, F4D_EINVAL, "frame is NULL");
    if (f->count > f->capacity)
        return f4d_fail(err, F4D_EINVAL, "frame count %zu exceeds capacity %zu", f->count, f->capacity);
    for (size_t i = 0; i < f->count; i++) {
        if (!all_finite(f->pos + 3 * i, 3))
            return f4d_fail(err, F4D_EINVAL, "Gaussian %zu: position is not finite", i);
        if (!all_finite(f->scale + 3 * i, 3) || f->scale[3 * i] < 0 || f->scale[3 * i + 1] < 0 ||
            f->scale[3 * i + 2] < 0)
            return f4d_fail(err, F4D_EINVAL, "Gaussian %zu: scale must be finite and >= 0", i);
        if (!all_finite(f->rot + 4 * i, 4))
            return f4d_fail(err, F4D_EINVAL, "Gaussian %zu: rotation is not finite", i);
        if (!(f->opacity[i] >= 0.0f && f->opacity[i] <= 1.0f))
            return f4d_fail(err, F4D_EINVAL, "Gaussian %zu: opacity %g is outside [0,1]", i, (double)f->opacity[i]);
        if (!all_finite(f->rgb + 3 * i, 3))
            return f4d_fail(err, F4D_EINVAL, "Gaussian %zu: colour is not finite", i);
        if (f->motion_bwd && !all_finite(f->motion_bwd + 3 * i, 3))
            return f4d_fail(err, F4D_EINVAL, "Gaussian %zu: backward motion is not finite", i);
        if (f->motion_fwd && !all_finite(f->motion_fwd + 3 * i, 3))
            return f4d_fail(err, F4D_EINVAL, "Gaussian %zu: forward motion is not finite", i);
    }
    return F4D_OK;
}
