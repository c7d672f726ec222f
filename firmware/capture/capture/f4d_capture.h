/* f4d_capture.h: runs a rig. Negotiates each camera's format (validate ->
 * adjusted -> configure), queues caller-owned buffers (allocated once, before
 * the first frame), arms the trigger, and feeds trigger edges and frames to the
 * synchronizer until the requested pulses were sent and every frame in flight
 * came home; each closed set goes to `on_set`.
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
};

struct f4d_capture_stats {
    struct f4d_sync_counters sync;
    uint64_t disconnects;       /* times a camera reported F4D_ENODEV after delivering */
    uint64_t dequeue_errors;    /* other dequeue failures */
    uint64_t frames_in;         /* frames dequeued */
    uint64_t bytes_in;          /* image bytes dequeued */
    uint64_t t_start_ns, t_end_ns; /* rig clock */
    struct hal_format formats[HAL_RIG_CAMERAS_MAX]; /* negotiated */
};

/* Returns <0 to stop the capture (e.g. the disk failed). */
typedef int (*f4d_capture_set_fn)(void *user, const struct hal_set *set);
typedef void (*f4d_capture_progress_fn)(void *user, const struct f4d_capture_stats *st,
                                        uint64_t now_ns);

int f4d_capture_run(struct hal_rig *rig, const struct f4d_capture_config *cfg,
                    f4d_capture_set_fn on_set, f4d_capture_progress_fn on_progress, void *user,
                    volatile sig_atomic_t *stop, struct f4d_capture_stats *out, char *err,
                    size_t errlen);

#endif
