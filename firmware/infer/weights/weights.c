/* weights.c - the default weight file (weights.h): environment, installed copy,
 * source tree, in that order. Paths come from CMake (F4D_WEIGHTS_INSTALL_DIR,
 * F4D_WEIGHTS_SOURCE_DIR). */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "weights.h"

#ifndef F4D_WEIGHTS_INSTALL_DIR
#error "F4D_WEIGHTS_INSTALL_DIR must be defined by the build"
#endif
#ifndef F4D_WEIGHTS_SOURCE_DIR
#error "F4D_WEIGHTS_SOURCE_DIR must be defined by the build"
#endif

static int readable(const char *p) { return access(p, R_OK) == 0; }

static int put(char *path, size_t size, const char *dir, const char *file, struct f4d_err *err)
{
    int n = snprintf(path, size, "%s/%s", dir, file);
    if (n < 0 || (size_t)n >= size)
        return f4d_fail(err, F4D_ERANGE, "weights: path '%s/%s' longer than %zu bytes", dir, file, size - 1);
    return 0;
}

int f4d_weights_default(int int8, char *path, size_t size, struct f4d_err *err)
{
    if (!path || size == 0)
        return f4d_fail(err, F4D_EINVAL, "weights: path buffer is NULL or empty");
    const char *env = getenv("F4D_WEIGHTS");
    if (env && *env) {
        if (!readable(env))
            return f4d_fail(err, F4D_ENOENT, "weights: F4D_WEIGHTS names '%s', which cannot be read", env);
        if (strlen(env) >= size)
            return f4d_fail(err, F4D_ERANGE, "weights: F4D_WEIGHTS is longer than %zu bytes", size - 1);
        memcpy(path, env, strlen(env) + 1);
        return 0;
    }
    static const char *const dirs[2] = { F4D_WEIGHTS_INSTALL_DIR, F4D_WEIGHTS_SOURCE_DIR };
    const char *files[2] = { int8 ? "forge4d_small_int8.gguf" : "forge4d_small.gguf", "forge4d_small.gguf" };
    for (int f = 0; f < (int8 ? 2 : 1); f++)
        for (int d = 0; d < 2; d++) {
            int rc = put(path, size, dirs[d], files[f], err);
            if (rc < 0)
                return rc;
            if (readable(path))
                return 0;
        }
    path[0] = '\0';
    return f4d_fail(err, F4D_ENOENT, "weights: no forge4d_small%s.gguf in %s or %s, and F4D_WEIGHTS is not set",
                    int8 ? "_int8" : "", F4D_WEIGHTS_INSTALL_DIR, F4D_WEIGHTS_SOURCE_DIR);
}
