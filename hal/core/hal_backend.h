/* hal_backend.h: helpers for backend implementers (hal/sim, hal/replay,
 * hal/aravis, hal/usb, hal/gpiod). Internal: users of the HAL include only
 * hal.h; this header is for code that implements hal_camera_ops or
 * hal_trigger_ops, so that every backend keeps the caller-owned buffer ring,
 * the camera state rules, the edge queue and the error buffer the same way.
 *
 * Every piece is a plain struct embedded by value in a backend's context
 * (zero-initialised by calloc is a valid empty state) plus small functions;
 * none of them allocates, so they are safe in the per-frame path.
 */
#ifndef F4D_HAL_BACKEND_H
#define F4D_HAL_BACKEND_H

#include "hal.h"

/* ---- time -------------------------------------------------------------- */
/* CLOCK_MONOTONIC in ns. */
uint64_t hal_mono_ns(void);
/* Sleeps until CLOCK_MONOTONIC reaches t_ns (retries when a signal interrupts). */
void hal_sleep_until_mono_ns(uint64_t t_ns);

/* ---- handing out devices (camera_open, trigger_open, clock_get) ------- */
/* Fills a camera handle with the backend's ops and context. */
void hal_camera_bind(struct hal_camera *out, const struct hal_camera_ops *ops, void *ctx, uint32_t index);
/* A session's one trigger: F4D_EBUSY ("<who> already open" in err) when
 * *taken, else marks it taken and fills `out`. */
int hal_trigger_claim(bool *taken, struct hal_trigger *out, const struct hal_trigger_ops *ops, void *ctx,
                      const char *who, struct f4d_err *err);
/* A clock whose time lives in `ctx` (a simulated or replayed world). */
void hal_clock_bind(struct hal_clock *out, uint64_t (*now_ns)(void *), void (*sleep_until_ns)(void *, uint64_t),
                    uint64_t (*next_event_ns)(void *), void *ctx);

/* ---- the time of a simulated or replayed world ------------------------- */
/* Realtime: CLOCK_MONOTONIC since real_t0. Otherwise a counter that jumps to
 * whatever is waited for, so the world runs as fast as the host can. */
struct hal_world_clock {
    bool realtime;
    uint64_t real_t0;         /* realtime: CLOCK_MONOTONIC at world time 0 */
    uint64_t now;             /* world time (ns) as last read */
};
/* Reads the clock into c->now and returns it. */
uint64_t hal_world_clock_read(struct hal_world_clock *c);
/* Waits until world time t (realtime), or jumps there; then reads the clock. */
uint64_t hal_world_clock_wait(struct hal_world_clock *c, uint64_t t);

/* ---- caller-owned buffers --------------------------------------------- */
#define HAL_BUFQ_MAX 64 /* most buffers one camera holds at once */

/* FIFO of queued caller buffers (the order frames will fill them). */
struct hal_bufq {
    struct hal_buffer *ring[HAL_BUFQ_MAX];
    uint32_t head, count;
};
/* false (and nothing queued) when the ring is full. */
bool hal_bufq_push(struct hal_bufq *q, struct hal_buffer *b);
/* The oldest queued buffer, or NULL when empty. */
struct hal_buffer *hal_bufq_pop(struct hal_bufq *q);

/* State every camera shares: the configured format, the configure/start
 * rules, the buffers handed back unfilled by stop, and the last error. */
struct hal_cam_state {
    struct hal_format fmt;    /* valid once configured */
    bool configured, started;
    /* what hal_camera_ops.streaming reports: set when the device really
     * delivers (FIFO cameras: at start), cleared by stop and while the
     * device is gone */
    bool streaming;
    struct hal_buffer *aborted[HAL_BUFQ_MAX]; /* returned by dequeue before any frame */
    uint32_t n_aborted;
    char name[160];           /* prefix of every message, e.g. "sim camera cam0" */
    struct f4d_err err;       /* last_error(): "<name>: <what>" */
};

/* Sets the message prefix (printf), once when the camera is opened. */
void hal_cam_name(struct hal_cam_state *s, const char *fmt, ...)
#if defined(__GNUC__)
    __attribute__((format(printf, 2, 3)))
#endif
    ;
/* Records "<name>: <fmt...>" as the last error and returns rc:
 * `return hal_cam_fail(&c->st, F4D_EIO, "VIDIOC_S_FMT")`. */
int hal_cam_fail(struct hal_cam_state *s, int rc, const char *fmt, ...)
#if defined(__GNUC__)
    __attribute__((format(printf, 3, 4)))
#endif
    ;

/* The state rules of hal_camera_ops: F4D_OK, or a negative code with the
 * reason recorded by hal_cam_fail. */
int hal_cam_check_configure(struct hal_cam_state *s);                 /* not started */
int hal_cam_check_start(struct hal_cam_state *s);                     /* configured */
/* Configured, and `b` can hold a whole image. */
int hal_cam_check_enqueue(struct hal_cam_state *s, const struct hal_buffer *b);
/* `rc` is what validate returned for the format given to configure: only an
 * unchanged (VALID) format may be configured. */
int hal_cam_check_validated(struct hal_cam_state *s, int rc);
/* Start of every dequeue: sets *out to NULL, hands back an aborted buffer
 * first (F4D_OK with *out set), else F4D_OK with *out NULL when started, or
 * F4D_ESTATE when stopped. Use: `if (rc < 0 || *out) return rc;`. */
int hal_cam_dequeue_begin(struct hal_cam_state *s, struct hal_buffer **out);

/* Marks `b` ABORTED (no bytes) and keeps it for dequeue. */
void hal_cam_abort(struct hal_cam_state *s, struct hal_buffer *b);

/* Cameras whose buffers simply wait in a struct hal_bufq (sim, replay): */
/* start = check and mark started (and streaming) */
int hal_cam_fifo_start(struct hal_cam_state *s);
/* stop = mark stopped (not streaming) and abort every queued buffer */
void hal_cam_fifo_stop(struct hal_cam_state *s, struct hal_bufq *q);
/* enqueue = check and append, F4D_EBUSY when the ring is full */
int hal_cam_fifo_enqueue(struct hal_cam_state *s, struct hal_bufq *q, struct hal_buffer *b);

/* ---- trigger edges not yet read by the host ---------------------------- */
#define HAL_EDGEQ_MAX 256

struct hal_edgeq {
    struct hal_edge ring[HAL_EDGEQ_MAX];
    uint32_t head, count;
    uint32_t limit;           /* capacity; 0 = HAL_EDGEQ_MAX */
};
/* Appends e; false (e dropped) when the queue is full. */
bool hal_edgeq_push(struct hal_edgeq *q, const struct hal_edge *e);
/* Appends e, dropping the oldest edge when full; true if one was dropped. */
bool hal_edgeq_push_overwrite(struct hal_edgeq *q, const struct hal_edge *e);
/* Moves up to max edges, oldest first, into out; returns how many. */
uint32_t hal_edgeq_pop(struct hal_edgeq *q, struct hal_edge *out, uint32_t max);

#endif /* F4D_HAL_BACKEND_H */
