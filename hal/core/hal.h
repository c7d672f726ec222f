/* hal.h: the hardware abstraction layer of Forge4D Edge.
 *
 * Cameras, triggers and clocks are small vtables held by value next to a
 * backend context (`{ops, ctx}`); every ops struct starts with `api_version`,
 * checked when the backend is opened. Backends (sim, replay, aravis, gpiod, usb,
 * libcamera) are listed in one static table (hal_registry.c), selected at
 * compile time.
 *
 * Usage (the normal path goes through a rig, i.e. every device of a board):
 *
 *     struct hal_board board;            // filled by hal_board_load() (hal/board)
 *     struct hal_rig rig;
 *     struct f4d_err err = {0};
 *     if (hal_rig_open(&rig, &board, &err) < 0) { puts(err); ... }
 *     struct hal_format f = { .pixfmt = HAL_PIXFMT_RGB8, .width = 518, .height = 518, ... };
 *     int v = hal_camera_validate(&rig.cams[0], &f);   // HAL_FORMAT_ADJUSTED: f was changed
 *     hal_camera_configure(&rig.cams[0], &f);
 *     hal_camera_enqueue(&rig.cams[0], &buf);           // caller-owned buffers
 *     hal_camera_start(&rig.cams[0]);
 *     hal_trigger_arm(&rig.trigger, &train);
 *     hal_camera_dequeue(&rig.cams[0], &out, 1000);     // status, timestamps, ids
 *     hal_rig_close(&rig);
 *
 * Config/data/ops split: `struct hal_board` (board facts, const once loaded),
 * backend contexts (runtime data, private to each backend), ops (const tables).
 * Errors are negative `HAL_E*` codes; functions that can fail for a reason a
 * human must read also fill an `err` buffer naming what is wrong.
 */
#ifndef F4D_HAL_H
#define F4D_HAL_H

#include "f4d_status.h"

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#define HAL_API_VERSION 1u

/* Status codes: F4D_* from f4d_status.h, shared by the whole tree. */

/* ---- pixel formats (values are stored in take files: never renumber) --- */
enum hal_pixfmt {
    HAL_PIXFMT_INVALID = 0,
    HAL_PIXFMT_MONO8 = 1,
    HAL_PIXFMT_RGB8 = 2,
    HAL_PIXFMT_BAYER_RG8 = 3,
    HAL_PIXFMT_MONO16 = 4,
    HAL_PIXFMT_YUYV = 5,
};
const char *hal_pixfmt_name(enum hal_pixfmt f);           /* "rgb8", "?" if unknown */
enum hal_pixfmt hal_pixfmt_parse(const char *name);        /* INVALID if unknown */
uint32_t hal_pixfmt_bytes_per_pixel(enum hal_pixfmt f);    /* 0 if unknown */

enum hal_trigger_mode {
    HAL_TRIGGER_FREE_RUN = 0, /* camera runs on its own clock */
    HAL_TRIGGER_HARDWARE = 1, /* one exposure per edge on the trigger line */
    HAL_TRIGGER_SOFTWARE = 2, /* one exposure per host command */
};

/* A negotiated stream format. `validate` may change fields to the nearest the
 * device supports and then returns HAL_FORMAT_ADJUSTED; `configure` accepts
 * only a format that validates unchanged. */
struct hal_format {
    enum hal_pixfmt pixfmt;
    uint32_t width, height;
    uint32_t stride;           /* bytes per row; 0 asks for the tight stride */
    uint32_t rate_mhz;         /* frame rate in millihertz (30 Hz = 30000) */
    enum hal_trigger_mode trigger;
    uint32_t exposure_us;
    size_t image_bytes;        /* out: stride * height */
};
enum hal_validate_result { HAL_FORMAT_VALID = 0, HAL_FORMAT_ADJUSTED = 1 };

/* ---- frame buffers: caller-owned, queued to a camera ------------------- */
enum hal_frame_status {
    HAL_FRAME_OK = 0,
    HAL_FRAME_TIMEOUT = 1,
    HAL_FRAME_MISSING_PACKETS = 2, /* incomplete: part of the image never arrived */
    HAL_FRAME_SIZE_MISMATCH = 3,
    HAL_FRAME_ABORTED = 4,         /* returned unfilled by stop/flush */
};
const char *hal_frame_status_name(enum hal_frame_status s);

/* Set on the first frame after the device clock restarted (reconnect), so
 * consumers that track the device clock start over. */
#define HAL_FRAME_FLAG_CLOCK_RESET 0x1u

struct hal_buffer {
    /* owned and set by the caller */
    uint8_t *data;
    size_t capacity;
    void *user;
    /* filled by dequeue */
    size_t bytes_used;
    enum hal_frame_status status;
    uint32_t flags;            /* HAL_FRAME_FLAG_* */
    uint32_t camera_index;     /* position of the camera in its rig */
    uint64_t device_ts_ns;     /* camera clock (offset and drift unknown) */
    uint64_t host_ts_ns;       /* host/rig clock when the frame arrived */
    uint64_t frame_id;         /* camera's own counter, unwrapped */
    uint64_t trigger_seq;      /* sequence number of the trigger edge that exposed it */
    struct hal_format format;  /* format the image was written with */
};

/* ---- clock ------------------------------------------------------------- */
struct hal_clock_ops {
    uint32_t api_version;
    uint64_t (*now_ns)(void *ctx);
    /* Blocks (or, for a simulated clock, jumps) until `t_ns`. */
    void (*sleep_until_ns)(void *ctx, uint64_t t_ns);
    /* optional: earliest time anything is due (simulated clocks), or UINT64_MAX */
    uint64_t (*next_event_ns)(void *ctx);
};
struct hal_clock {
    struct hal_clock_ops ops;
    void *ctx;
};
/* CLOCK_MONOTONIC. */
struct hal_clock hal_clock_monotonic(void);
static inline uint64_t hal_clock_now(const struct hal_clock *c) { return c->ops.now_ns(c->ctx); }
static inline void hal_clock_sleep_until(const struct hal_clock *c, uint64_t t)
{
    c->ops.sleep_until_ns(c->ctx, t);
}
static inline uint64_t hal_clock_next_event(const struct hal_clock *c)
{
    return c->ops.next_event_ns ? c->ops.next_event_ns(c->ctx) : UINT64_MAX;
}

/* ---- camera ------------------------------------------------------------ */
struct hal_camera_ops {
    uint32_t api_version;
    int (*validate)(void *ctx, struct hal_format *fmt);       /* VALID, ADJUSTED or <0 */
    int (*configure)(void *ctx, const struct hal_format *fmt);
    int (*start)(void *ctx);
    int (*stop)(void *ctx);                                   /* queued buffers come back ABORTED */
    int (*enqueue)(void *ctx, struct hal_buffer *buf);
    /* F4D_OK with *out set, F4D_ETIMEDOUT, F4D_ENODEV (disconnected), F4D_EEOF (replay ended). */
    int (*dequeue)(void *ctx, struct hal_buffer **out, uint32_t timeout_us);
    void (*close)(void *ctx);
    const char *(*last_error)(void *ctx);                     /* optional */
    /* optional: true while the device really streams, i.e. a trigger sent now
     * produces a frame: set once the backend knows frames flow (e.g. Aravis:
     * acquisition start acknowledged, stream ready, a probe trigger answered),
     * false before start, after stop and while the device is disconnected.
     * It may do a little work to find out (poll, send a probe) and never
     * blocks. NULL: streaming as soon as start returned. */
    bool (*streaming)(void *ctx);
};
struct hal_camera {
    struct hal_camera_ops ops;
    void *ctx;
    uint32_t index;
};
static inline int hal_camera_validate(struct hal_camera *c, struct hal_format *f) { return c->ops.validate(c->ctx, f); }
static inline int hal_camera_configure(struct hal_camera *c, const struct hal_format *f) { return c->ops.configure(c->ctx, f); }
static inline int hal_camera_start(struct hal_camera *c) { return c->ops.start(c->ctx); }
static inline int hal_camera_stop(struct hal_camera *c) { return c->ops.stop(c->ctx); }
static inline int hal_camera_enqueue(struct hal_camera *c, struct hal_buffer *b) { return c->ops.enqueue(c->ctx, b); }
static inline int hal_camera_dequeue(struct hal_camera *c, struct hal_buffer **b, uint32_t timeout_us)
{
    return c->ops.dequeue(c->ctx, b, timeout_us);
}
/* Ask only after start: with no `streaming` op a started camera streams. */
static inline bool hal_camera_streaming(struct hal_camera *c)
{
    return c->ops.streaming ? c->ops.streaming(c->ctx) : true;
}
static inline const char *hal_camera_last_error(struct hal_camera *c)
{
    return c->ops.last_error ? c->ops.last_error(c->ctx) : "";
}

/* Fills the derived fields of `f` (tight stride if 0, image_bytes); returns
 * F4D_EINVAL if the pixel format is unknown or the sizes overflow. */
int hal_format_finish(struct hal_format *f);

/* ---- trigger ----------------------------------------------------------- */
struct hal_pulse_train {
    uint32_t rate_mhz;     /* pulses per 1000 s */
    uint32_t width_us;
    uint64_t count;        /* pulses to send; 0 = until disarmed */
};
struct hal_edge {
    uint64_t seq;          /* 1, 2, 3... in the order the line saw the pulses */
    uint64_t ts_ns;        /* rig clock */
    uint32_t line;
    bool rising;
};
struct hal_trigger_ops {
    uint32_t api_version;
    int (*arm)(void *ctx, const struct hal_pulse_train *train);
    int (*disarm)(void *ctx);
    /* Copies up to `max` rising edges seen so far; returns the count (>=0) or <0. */
    int (*read_edges)(void *ctx, struct hal_edge *edges, uint32_t max, uint32_t timeout_us);
    void (*close)(void *ctx);
    /* optional: true once a finite train has sent all its pulses */
    bool (*done)(void *ctx);
    const char *(*last_error)(void *ctx); /* optional */
};
struct hal_trigger {
    struct hal_trigger_ops ops;
    void *ctx;
};
static inline int hal_trigger_arm(struct hal_trigger *t, const struct hal_pulse_train *p) { return t->ops.arm(t->ctx, p); }
static inline int hal_trigger_disarm(struct hal_trigger *t) { return t->ops.disarm(t->ctx); }
static inline int hal_trigger_read_edges(struct hal_trigger *t, struct hal_edge *e, uint32_t max, uint32_t timeout_us)
{
    return t->ops.read_edges(t->ctx, e, max, timeout_us);
}
static inline bool hal_trigger_done(struct hal_trigger *t) { return t->ops.done ? t->ops.done(t->ctx) : false; }

/* ---- board description (config: filled by hal/board, then read-only) -- */
#define HAL_RIG_CAMERAS_MAX 16
#define HAL_NAME_MAX 64
#define HAL_PATH_MAX 512

struct hal_intrinsics {
    bool known;
    double fx, fy, cx, cy;
};
struct hal_camera_config {
    char backend[16];             /* "sim", "aravis", "usb", "libcamera", "replay" */
    char id[HAL_NAME_MAX];        /* human name, e.g. "cam0" */
    char serial[HAL_NAME_MAX];
    char address[HAL_PATH_MAX];   /* IP (aravis), /dev/videoN or usb:VID:PID (usb), camera id (libcamera), take dir (replay) */
    uint32_t width, height;
    enum hal_pixfmt pixfmt;
    int32_t trigger_line;         /* camera input line, -1 = none */
    uint32_t exposure_us;
    uint32_t packet_size;         /* GigE: bytes per GVSP packet, 0 = device default */
    uint32_t socket_buffer;       /* GigE: receive buffer bytes, 0 = default */
    struct hal_intrinsics intrinsics;
};
struct hal_trigger_config {
    char backend[16];             /* "sim", "gpiod", "aravis" (software), "replay" */
    char chip[HAL_NAME_MAX];      /* gpiod chip name or path */
    int32_t line;                 /* output line */
    int32_t strobe_line;          /* edge input line (exposure strobe), -1 = none */
    uint32_t rate_mhz;
    uint32_t pulse_width_us;
};
enum hal_incomplete_policy { HAL_INCOMPLETE_DROP = 0, HAL_INCOMPLETE_MARK = 1 };
/* One synchronized multi-view set: what the synchronizer hands downstream and
 * what a take stores. frames[c] is NULL where camera c has no frame. */
struct hal_set {
    uint64_t seq;
    uint64_t trigger_ts_ns;   /* edge time (rig clock), or first frame's mapped time */
    bool has_edge;
    bool complete;
    uint32_t ok_mask;         /* cameras with an OK frame */
    uint32_t present_mask;    /* cameras with any frame (OK or incomplete) */
    struct hal_buffer *frames[HAL_RIG_CAMERAS_MAX];
};
struct hal_sync_config {
    uint32_t window_us;           /* device timestamps must agree to this */
    uint32_t max_latency_us;      /* a set is closed this long after its trigger */
    enum hal_incomplete_policy incomplete;
    uint32_t pending_max;         /* sets open at once (memory bound) */
};
/* Capture queues pending_max + HAL_CAPTURE_SPARE_BUFFERS buffers per camera
 * (firmware/capture/capture/f4d_capture.c), and a camera holds at most
 * HAL_BUFQ_MAX (64, hal_backend.h), the usb backend HAL_USB_BUFFERS_MAX (32
 * V4L2 buffers): the board parser bounds pending_max by both. */
#define HAL_CAPTURE_SPARE_BUFFERS 6u
#define HAL_USB_BUFFERS_MAX       32u /* the usb backend's V4L2 buffer slots */
/* Simulated faults, each a probability per frame (or per pulse). */
struct hal_sim_faults {
    double drop, duplicate, late, incomplete;       /* per camera and pulse, exclusive */
    double trigger_missing, trigger_extra;          /* per pulse */
    double disconnect;                              /* per camera and pulse */
    uint32_t disconnect_ms;                         /* how long a disconnect lasts */
    uint32_t late_ms;                               /* extra delivery delay of a late frame */
    uint32_t jitter_us;                             /* +- device timestamp jitter */
    uint32_t clock_offset_ms;                       /* +- per-camera device clock offset */
    uint32_t clock_drift_ppm;                       /* +- per-camera device clock drift */
};
struct hal_sim_config {
    uint64_t seed;
    bool realtime;                /* false: simulated clock runs as fast as possible */
    char scene[32];               /* "pattern" (procedural) or a renderer name */
    struct hal_sim_faults faults;
};
struct hal_board {
    char name[HAL_NAME_MAX];
    uint32_t n_cams;
    struct hal_camera_config cams[HAL_RIG_CAMERAS_MAX];
    struct hal_trigger_config trigger;
    struct hal_sync_config sync;
    struct hal_sim_config sim;
    char record_dir[HAL_PATH_MAX];
    uint32_t durability_ms;       /* recorder fsync window */
};
/* Defaults for every field (sim backend, 30 Hz, 2 ms window...). */
void hal_board_defaults(struct hal_board *b);

/* ---- backends and the registry ----------------------------------------- */
/* A backend session is shared by all devices of one backend in a rig (the
 * simulated world, the Aravis library, an open take). */
struct hal_backend {
    uint32_t api_version;
    const char *name;
    /* optional: false when the backend is compiled in but cannot run (no library) */
    bool (*is_available)(void);
    int (*session_open)(const struct hal_board *board, void **session, struct f4d_err *err);
    void (*session_close)(void *session);
    /* optional (a backend may offer only cameras or only triggers) */
    int (*camera_open)(void *session, const struct hal_camera_config *cfg, uint32_t index,
                       struct hal_camera *out, struct f4d_err *err);
    int (*trigger_open)(void *session, const struct hal_trigger_config *cfg,
                        struct hal_trigger *out, struct f4d_err *err);
    /* optional: the clock the backend's timestamps live in (simulated worlds) */
    int (*clock_get)(void *session, struct hal_clock *out);
};

/* All devices of a board, (hal_rig_open in hal_registry.h fills it). */
struct hal_rig {
    const struct hal_board *board;
    uint32_t n_cams;
    struct hal_camera cams[HAL_RIG_CAMERAS_MAX];
    struct hal_trigger trigger;
    struct hal_clock clock;           /* the trigger backend's clock, else monotonic */
    uint32_t n_sessions;
    const struct hal_backend *session_backend[4];
    void *session[4];
};


#endif /* F4D_HAL_H */
