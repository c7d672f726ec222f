/* hal_registry.h: the one static table of backends compiled into this build,
 * and the rig: every camera and the trigger of a board, opened through it.
 *
 *     struct hal_rig rig; struct f4d_err err = {0};
 *     if (hal_rig_open(&rig, &board, &err) < 0) puts(err);
 *     ... hal_camera_start(&rig.cams[0]) ...
 *     hal_rig_close(&rig);
 *
 * This is the only target that links the backends: hal/core (interfaces) and
 * every backend sit below it, and code that opens a board links hal_registry.
 */
#ifndef F4D_HAL_REGISTRY_H
#define F4D_HAL_REGISTRY_H

#include "hal.h"

/* The static registry: NULL if `name` is not compiled in. */
const struct hal_backend *hal_backend_find(const char *name);
/* Number of compiled-in backends, and the i-th one (for listing/tests). */
uint32_t hal_backend_count(void);
const struct hal_backend *hal_backend_at(uint32_t i);

/* Opens every camera and the trigger of `board` through the registry. */
int hal_rig_open(struct hal_rig *rig, const struct hal_board *board, struct f4d_err *err);
void hal_rig_close(struct hal_rig *rig);
/* The session of the named backend inside an open rig, or NULL. */
void *hal_rig_session(const struct hal_rig *rig, const char *backend);

#endif /* F4D_HAL_REGISTRY_H */
