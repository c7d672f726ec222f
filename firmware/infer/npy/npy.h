/* npy.h - NumPy .npy files of float32 (format 1.0), read and written.
 *
 *     int64_t shape[NPY_MAX_DIMS]; int nd; float *a; struct f4d_err err = {0};
 *     if (npy_load_f32("x.npy", &a, shape, &nd, &err) < 0) puts(err);
 *     npy_save_f32("y.npy", a, shape, nd, &err);
 *     free(a);
 *
 * Only little-endian float32 ('<f4'), C order, is read: anything else fails
 * with a message naming the file and what is wrong. Saving writes to
 * "<path>.tmp" and renames, so a failed save never leaves a half file.
 */
#ifndef F4D_NPY_H
#define F4D_NPY_H

#include <stddef.h>
#include <stdint.h>

#include "f4d_status.h"

#define NPY_MAX_DIMS 8

/* Loads into a malloc'ed array (caller frees). */
int npy_load_f32(const char *path, float **data, int64_t *shape, int *ndim,
                 struct f4d_err *err);
int npy_save_f32(const char *path, const float *data, const int64_t *shape, int ndim,
                 struct f4d_err *err);

#endif
