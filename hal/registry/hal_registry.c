/* hal_registry.c: the one static table of backends, and rig open/close.
 * Only sim is always there; every other backend, replay included, is
 * compiled in when its CMake target exists (HAL_HAS_<NAME>, see
 * CMakeLists.txt; aravis, gpiod and usb only when their library was found). */
#include "hal_registry.h"

#include <stdio.h>
#include <string.h>

extern const struct hal_backend hal_sim_backend;
#if HAL_HAS_REPLAY
extern const struct hal_backend hal_replay_backend;
#endif
#if HAL_HAS_ARAVIS
extern const struct hal_backend hal_aravis_backend;
#endif
#if HAL_HAS_GPIOD
extern const struct hal_backend hal_gpiod_backend;
#endif
#if HAL_HAS_USB
extern const struct hal_backend hal_usb_backend;
#endif
#if HAL_HAS_LIBCAMERA
extern const struct hal_backend hal_libcamera_backend;
#endif

static const struct hal_backend *const backends[] = {
    &hal_sim_backend,
#if HAL_HAS_REPLAY
    &hal_replay_backend,
#endif
#if HAL_HAS_ARAVIS
    &hal_aravis_backend,
#endif
#if HAL_HAS_GPIOD
    &hal_gpiod_backend,
#endif
#if HAL_HAS_USB
    &hal_usb_backend,
#endif
#if HAL_HAS_LIBCAMERA
    &hal_libcamera_backend,
#endif
};

uint32_t hal_backend_count(void) { return (uint32_t)(sizeof backends / sizeof backends[0]); }

const struct hal_backend *hal_backend_at(uint32_t i)
{
    return i < hal_backend_count() ? backends[i] : NULL;
}

const struct hal_backend *hal_backend_find(const char *name)
{
    for (uint32_t i = 0; name && i < hal_backend_count(); i++)
        if (strcmp(backends[i]->name, name) == 0)
            return backends[i];
    return NULL;
}

/* Finds or opens the session of `name` in the rig. */
static int rig_session(struct hal_rig *rig, const char *name, const struct hal_backend **be,
                       void **session, struct f4d_err *err)
{
    for (uint32_t i = 0; i < rig->n_sessions; i++)
        if (strcmp(rig->session_backend[i]->name, name) == 0) {
            *be = rig->session_backend[i];
            *session = rig->session[i];
            return F4D_OK;
        }
    const struct hal_backend *b = hal_backend_find(name);
    if (!b)
        return f4d_fail(err, F4D_ENOTSUP,
                        "backend \"%s\" is not compiled into this build", name);
    if (b->api_version != HAL_API_VERSION)
        return f4d_fail(err, F4D_ENOTSUP, "backend \"%s\" has api_version %u, want %u",
                        name, (unsigned)b->api_version, (unsigned)HAL_API_VERSION);
    if (b->is_available && !b->is_available())
        return f4d_fail(err, F4D_ENODEV, "backend \"%s\" is not available here", name);
    if (rig->n_sessions >= sizeof rig->session / sizeof rig->session[0])
        return f4d_fail(err, F4D_EINVAL, "too many backends in one board");
    void *s = NULL;
    int rc = b->session_open(rig->board, &s, err);
    if (rc < 0)
        return rc;
    rig->session_backend[rig->n_sessions] = b;
    rig->session[rig->n_sessions++] = s;
    *be = b;
    *session = s;
    return F4D_OK;
}

int hal_rig_open(struct hal_rig *rig, const struct hal_board *board, struct f4d_err *err)
{
    memset(rig, 0, sizeof *rig);
    rig->board = board;
    rig->clock = hal_clock_monotonic();
    if (board->n_cams == 0 || board->n_cams > HAL_RIG_CAMERAS_MAX)
        return f4d_fail(err, F4D_EINVAL, "board \"%s\" has %u cameras (want 1..%d)",
                        board->name, (unsigned)board->n_cams, HAL_RIG_CAMERAS_MAX);
    const struct hal_backend *be;
    void *s;
    /* The trigger first: its backend owns the rig clock. */
    int rc = rig_session(rig, board->trigger.backend, &be, &s, err);
    if (rc < 0)
        goto fail;
    if (!be->trigger_open) {
        rc = f4d_fail(err, F4D_ENOTSUP, "backend \"%s\" has no trigger", be->name);
        goto fail;
    }
    if (be->clock_get && (rc = be->clock_get(s, &rig->clock)) < 0)
        goto fail;
    rc = be->trigger_open(s, &board->trigger, &rig->trigger, err);
    if (rc < 0)
        goto fail;
    if (rig->trigger.ops.api_version != HAL_API_VERSION) {
        rc = f4d_fail(err, F4D_ENOTSUP, "trigger ops api_version mismatch");
        goto fail;
    }
    for (uint32_t i = 0; i < board->n_cams; i++) {
        const struct hal_camera_config *cc = &board->cams[i];
        rc = rig_session(rig, cc->backend, &be, &s, err);
        if (rc < 0)
            goto fail;
        if (!be->camera_open) {
            rc = f4d_fail(err, F4D_ENOTSUP, "backend \"%s\" has no cameras", be->name);
            goto fail;
        }
        rc = be->camera_open(s, cc, i, &rig->cams[i], err);
        if (rc < 0)
            goto fail;
        rig->cams[i].index = i;
        rig->n_cams = i + 1;
        if (rig->cams[i].ops.api_version != HAL_API_VERSION) {
            rc = f4d_fail(err, F4D_ENOTSUP, "camera %s: ops api_version mismatch", cc->id);
            goto fail;
        }
    }
    return F4D_OK;
fail:
    hal_rig_close(rig);
    return rc;
}

void hal_rig_close(struct hal_rig *rig)
{
    for (uint32_t i = 0; i < rig->n_cams; i++)
        if (rig->cams[i].ops.close)
            rig->cams[i].ops.close(rig->cams[i].ctx);
    rig->n_cams = 0;
    if (rig->trigger.ops.close)
        rig->trigger.ops.close(rig->trigger.ctx);
    memset(&rig->trigger, 0, sizeof rig->trigger);
    for (uint32_t i = rig->n_sessions; i-- > 0;)
        if (rig->session_backend[i]->session_close)
            rig->session_backend[i]->session_close(rig->session[i]);
    rig->n_sessions = 0;
}

void *hal_rig_session(const struct hal_rig *rig, const char *backend)
{
    for (uint32_t i = 0; i < rig->n_sessions; i++)
        if (strcmp(rig->session_backend[i]->name, backend) == 0)
            return rig->session[i];
    return NULL;
}
