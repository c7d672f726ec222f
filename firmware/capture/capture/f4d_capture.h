/* f4d_capture.h: runs a rig. Negotiates each camera's format (validate ->
 * adjusted -> configure), queues caller-owned buffers (allocated once, before
 * the first frame), starts every camera, waits until every camera streams,
 * arms the trigger, and feeds trigger edges and frames to the synchronizer
 * until the requested pulses were sent and every frame in flight came home;
 * each closed set goes to `on_set`.
 *
 * Trigger policy (no pulse for a camera that cannot answer it):
 *  - Start: the trigger is armed only once hal_camera_streaming() is true for
 *    EVERY camera (polled every 2 ms, real time). A camera still not streaming
 *    after `ready_timeout_ns` fails the capture with F4D_ETIMEDOUT and an error
 *    naming it ("camera cam2 not streaming 5000 ms after start: ..."); no
 *    pulse was sent. So pulse 1 reaches every camera: a camera that started
 *    late cannot lose the first pulses or merge them into one frame.
 *  - A camera down while running (disconnected; streaming() false): with
 *    `hold_while_down` the train is disarmed at once (stats.holds counts it)
 *    and re-armed for the pulses still owed (requested minus edges seen) when
 *    every camera streams again; no set is opened meanwhile. Without it
 *    (default: the other views keep recording) the train runs on and the down
 *    camera's slots stay empty (sets incomplete, by the board's policy); a
 *    backend that sends pulses per camera (aravis software trigger) sends none
 *    to a camera that is not streaming, and a hardware line pulses anyway.
 *    Holding relies on the backend's `streaming` op: a backend without it
 *    (usb) is never seen down.
 *  - Frames are numbered by the backends; a reconnected camera restarts its
 *    clock (HAL_FRAME_FLAG_CLOCK_RESET) and the synchronizer relearns it.
 *
 * Buffers: every negotiated camera is stopped at the end (also on an error
 * path, started or not) and the buffers stop hands back are dequeued before
 * their memory is freed; memory a camera still holds is never freed.
 *
 *     struct f4d_capture_config cfg = { .triggers = 300 };
 *     struct f4d_capture_stats st;
 *     int rc = f4d_capture_run(&rig, &cfg, on_set, on_progress, user, &stop_flag, &st, err, n);
 *
 * The loop never allocates. With a simulated clock (hal_clock_next_event) it
 * jumps from event to event, so simulated takes run faster than real time.
 */
#ifndef F4D_CAPTURE_H
#define F4D_CAPTURE_H

#include <signal.h>

#include "f4d_sync.h"
#include "hal.h"

struct f4d_capture_stats;
struct f4d_capture_config {
    uint64_t triggers;        /* pulses to send; 0 = until duration_ns or *stop */
    uint64_t duration_ns;     /* 0 = no time limit */
    uint32_t buffers_per_cam; /* 0 = pending_max + 6 */
    uint32_t poll_us;         /* real clocks: polling period (0 = 1000) */
    uint64_t drain_ns;        /* real clocks: wait after the last edge (0 = latency + 100 ms) */
    uint64_t progress_ns;     /* rig-clock period of on_progress (0 = 1 s) */
    /* optional: called once formats are negotiated, before the trigger is armed
     * (st->formats is filled); <0 aborts the capture */
    int (*on_ready)(void *user, const struct f4d_capture_stats *st);
    uint64_t ready_timeout_ns; /* real time for every camera to stream (0 = 5 s) */
    bool hold_while_down;     /* disarm while a camera is down, re-arm when all stream */
};

struct f4d_capture_stats {
    struct f4d_sync_counters sync;
    uint64_t disconnects;       /* times a camera reported F4D_ENODEV after delivering */
    uint64_t dequeue_errors;    /* other dequeue failures */
    uint64_t frames_in;         /* frames dequeued */
    uint64_t bytes_in;          /* image bytes dequeued */
    uint64_t t_start_ns, t_end_ns; /* rig clock */
    uint64_t ready_wait_ns;     /* real time from start until every camera streamed */
    uint64_t holds;             /* times the trigger was held for a down camera */
    struct hal_format formats[HAL_RIG_CAMERAS_MAX]; /* negotiated */
};

/* Returns <0 to stop the capture (e.g. the disk failed). */
typedef int (*f4d_capture_set_fn)(void *user, const struct hal_set *set);
typedef void (*f4d_capture_progress_fn)(void *user, const struct f4d_capture_stats *st,
                                        uint64_t now_ns);

int f4d_capture_run(struct hal_rig *rig, const struct f4d_capture_config *cfg,
                    f4d_capture_set_fn on_set, f4d_capture_progress_fn on_progress, void *user,
                    volatile sig_atomic_t *stop, struct f4d_capture_stats *out, struct f4d_err *err);

#endif
