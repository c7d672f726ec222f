/* weights.h - where the firmware finds its model by default: the small Forge4D
 * trained on synthetic venues (tools/train) and shipped in this folder as
 * forge4d_small.gguf (f32) and forge4d_small_int8.gguf, installed with the
 * programs under <datadir>/forge4d/.
 *
 * Search order: $F4D_WEIGHTS (when set, it must name a readable file), then
 * the installed copy (CMake's install prefix), then this source folder (a
 * build that was never installed). The int8 precision picks the int8 file
 * where one exists beside the f32 one.
 *
 *     char path[F4D_WEIGHTS_PATH_MAX];
 *     struct f4d_err err = {0};
 *     if (f4d_weights_default(0, path, sizeof path, &err) < 0) puts(err.msg);
 *     else model_init(ctx, path, FK_W_F32, &m, &err);
 *
 * Errors: F4D_ENOENT naming every place looked at, F4D_ERANGE when the path
 * does not fit, F4D_EINVAL for a NULL buffer. */
#ifndef F4D_WEIGHTS_H
#define F4D_WEIGHTS_H

#include <stddef.h>

#include "f4d_status.h"

#ifdef __cplusplus
extern "C" {
#endif

#define F4D_WEIGHTS_PATH_MAX 4096

/* int8 != 0 asks for the int8 file first (falls back to f32). */
int f4d_weights_default(int int8, char *path, size_t size, struct f4d_err *err);

#ifdef __cplusplus
}
#endif
#endif /* F4D_WEIGHTS_H */
