/* hal_libcamera_shim.h: the C API of the C++ shim over libcamera 0.0.3
 * (hal_libcamera_shim.cpp, the only C++ in the tree). Internal to
 * hal/libcamera: hal_libcamera.c implements the HAL camera on top of it.
 *
 * libcamera has no C API and no stable ABI, so the shim keeps everything C++
 * behind opaque handles and plain C types, and returns F4D_* status codes with
 * a message in `err` (the HAL's `struct f4d_err *err` style).
 *
 *     struct f4d_err err = {0};
 *     if (hlc_manager_start(&err) < 0) puts(err.msg);   // refcounted
 *     struct hlc_camera *cam;
 *     if (hlc_camera_acquire("\\_SB_.PCI0...", &cam, &err) < 0) puts(err.msg);
 *     struct hlc_format f = {HLC_FOURCC('Y','U','Y','V'), 640, 480, 0, 0};
 *     hlc_camera_configure(cam, &f, 4, &err);     // allocates 4 FrameBuffers, maps them
 *     hlc_camera_start(cam, &err);
 *     hlc_camera_queue(cam, 0); ...                           // slot = FrameBuffer index
 *     struct hlc_completion done;
 *     hlc_camera_wait(cam, &done, 1000);                      // completed request, oldest first
 *     memcpy(dst, hlc_camera_slot_data(cam, done.slot), done.bytes_used);
 *     hlc_camera_queue(cam, done.slot);
 *     hlc_camera_release(cam);
 *     hlc_manager_stop();
 *
 * Threads: libcamera completes requests on its own thread; the shim moves
 * them into a ring sized at configure (no allocation per frame) guarded by a
 * mutex, and hlc_camera_wait() blocks on a condition variable. Everything else
 * is called from one thread per camera.
 *
 * The CameraManager is a process-wide singleton in libcamera (a second live
 * instance aborts), so hlc_manager_start/stop are reference counted: each
 * backend session takes one reference.
 */
#ifndef F4D_HAL_LIBCAMERA_SHIM_H
#define F4D_HAL_LIBCAMERA_SHIM_H

#include "f4d_status.h"

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

/* DRM fourcc, the pixel format code libcamera uses (formats.h). */
#define HLC_FOURCC(a, b, c, d)                                                                     \
    ((uint32_t)(a) | ((uint32_t)(b) << 8) | ((uint32_t)(c) << 16) | ((uint32_t)(d) << 24))

/* ---- the camera manager (process-wide, reference counted) -------------- */
/* Starts libcamera's CameraManager on the first reference. */
int hlc_manager_start(struct f4d_err *err);
/* Drops one reference; the last one stops the manager. F4D_ESTATE (nothing
 * changes) when not started. */
int hlc_manager_stop(void);
/* References held now (0 = stopped). */
uint32_t hlc_manager_refs(void);
/* Cameras libcamera found, or F4D_ESTATE when the manager is not started. */
int hlc_manager_count(void);
/* Copies the id of camera i into buf; F4D_EINVAL if i is out of range. */
int hlc_manager_camera_id(uint32_t i, char *buf, size_t cap);
/* "none" or a comma-separated list of ids (truncated to cap), for messages. */
void hlc_manager_describe(char *buf, size_t cap);

/* ---- one camera ---------------------------------------------------------- */
struct hlc_camera;

struct hlc_format {
    uint32_t fourcc;       /* DRM fourcc */
    uint32_t width, height;
    uint32_t stride;       /* out: bytes per row of plane 0 */
    uint32_t frame_size;   /* out: bytes of one frame */
};

struct hlc_completion {
    uint32_t slot;         /* FrameBuffer index, as given to hlc_camera_queue */
    int ok;                /* 1: complete; 0: error or cancelled */
    int cancelled;         /* 1: cancelled by stop */
    uint32_t sequence;     /* FrameMetadata::sequence */
    uint64_t sensor_ts_ns; /* controls::SensorTimestamp, else FrameMetadata::timestamp */
    uint32_t bytes_used;   /* plane 0 */
};

/* Acquires the camera with libcamera id `id` (exclusive). F4D_ENODEV with a
 * message naming the id and listing the cameras that exist when none has it;
 * F4D_EBUSY when another process holds it; F4D_ESTATE without a manager. */
int hlc_camera_acquire(const char *id, struct hlc_camera **out, struct f4d_err *err);
/* Stops, frees the buffers and releases the camera. NULL is a no-op. */
void hlc_camera_release(struct hlc_camera *c);
/* Validates f against one video stream: 0 unchanged, 1 adjusted (f now holds
 * what the camera would do), <0 error. */
int hlc_camera_validate(struct hlc_camera *c, struct hlc_format *f, struct f4d_err *err);
/* Configures the stream (f must validate unchanged), allocates `n_buffers`
 * FrameBuffers and maps them; returns how many were allocated (>0) or <0. */
int hlc_camera_configure(struct hlc_camera *c, struct hlc_format *f, uint32_t n_buffers, struct f4d_err *err);
/* Plane-0 memory of slot i (mapped at configure), or NULL. */
const uint8_t *hlc_camera_slot_data(struct hlc_camera *c, uint32_t slot);
int hlc_camera_start(struct hlc_camera *c, struct f4d_err *err);
/* Stops; requests in flight complete as cancelled (wait() hands them back). */
int hlc_camera_stop(struct hlc_camera *c);
/* Queues the request of slot i. */
int hlc_camera_queue(struct hlc_camera *c, uint32_t slot, struct f4d_err *err);
/* Oldest completed request: F4D_OK, F4D_ETIMEDOUT, or F4D_ENODEV once
 * libcamera reported the camera disconnected (and nothing is left). */
int hlc_camera_wait(struct hlc_camera *c, struct hlc_completion *out, uint32_t timeout_us);

#ifdef __cplusplus
}
#endif

#endif /* F4D_HAL_LIBCAMERA_SHIM_H */
