/* f4d_sync.h: the synchronizer. Groups frames from N cameras into multi-view
 * sets by trigger sequence number, checks each frame's device timestamp
 * against its trigger edge within a window, and never puts frames of
 * different triggers in one set.
 *
 *     struct f4d_sync s;
 *     f4d_sync_init(&s, &(struct f4d_sync_config){ .n_cams = 4, .window_us = 2000,
 *                   .max_latency_us = 25000, .policy = HAL_INCOMPLETE_DROP, .pending_max = 8 },
 *                   on_set, on_release, user);
 *     f4d_sync_edge(&s, &edge);            // trigger edges (opens a set)
 *     f4d_sync_frame(&s, buf);             // every dequeued frame, any order
 *     f4d_sync_advance(&s, now_ns);        // closes sets whose latency bound passed
 *     f4d_sync_flush(&s);                  // at the end: closes everything
 *
 * Outcomes (each has a counter):
 *  - a set with an OK frame from every camera is complete -> on_set;
 *  - otherwise, once `max_latency_us` after its trigger (or when more than
 *    `pending_max` sets are open) it is incomplete: passed to on_set marked
 *    (`complete = false`) or dropped, by policy;
 *  - per frame: duplicate (the camera already has a frame in that set), late
 *    (its set was already closed without it; the camera's slot stops counting as
 *    dropped), incomplete (status not OK: it never completes a set),
 *    out_of_window (timestamp disagrees with the trigger edge), stale (older than
 *    the remembered history, so neither duplicate nor late can be told).
 *  - frames_dropped = camera slots still empty when their set closed, minus
 *    those that turned out late.
 *
 * Device clocks: each camera's offset to the trigger clock is learned from its
 * first F4D_SYNC_LEARN_FRAMES frames (the median device-minus-edge time: one
 * stray early or late frame must not bias it), then followed by a slow average
 * that tracks drift; only after learning is the window enforced, so the first
 * frames of a camera are grouped by sequence number alone. A frame flagged
 * HAL_FRAME_FLAG_CLOCK_RESET starts the camera over, and so do
 * F4D_SYNC_RELEARN_MISSES frames in a row outside the window (its first frames
 * were unrepresentative, or its clock jumped; counted in clock_resets: without
 * this, one bad start would reject every later frame). Sets without a trigger
 * edge (no edge input on the board) are opened by their first frame and
 * checked against that frame's mapped time instead.
 *
 * Memory is fixed inside the struct (no allocation); latency is bounded by
 * max_latency_us plus the caller's polling period. Buffers are handed back
 * through on_release as soon as the synchronizer is done with them: after
 * on_set returns for frames of a set, at once for rejected frames.
 */
#ifndef F4D_SYNC_H
#define F4D_SYNC_H

#include "hal.h"

#define F4D_SYNC_CAMS_MAX HAL_RIG_CAMERAS_MAX
#define F4D_SYNC_PENDING_MAX 64
#define F4D_SYNC_HISTORY 256 /* closed sets remembered to tell late from duplicate */
#define F4D_SYNC_LEARN_FRAMES 8 /* frames per camera used to learn its clock offset */
#define F4D_SYNC_RELEARN_MISSES 8 /* out-of-window frames in a row that restart learning */

struct f4d_sync_config {
    uint32_t n_cams;
    uint32_t window_us;
    uint32_t max_latency_us;
    enum hal_incomplete_policy policy;
    uint32_t pending_max;
    uint32_t learn_frames;    /* clock-offset learning per camera, 1..F4D_SYNC_LEARN_FRAMES; 0 = max */
};

struct f4d_sync_counters {
    uint64_t triggers;          /* edges seen */
    uint64_t sets_complete;
    uint64_t sets_incomplete;   /* closed incomplete (passed marked or dropped) */
    uint64_t sets_passed_marked;
    uint64_t sets_dropped;
    uint64_t sets_forced;       /* closed early because pending_max sets were open */
    uint64_t frames_ok;
    uint64_t frames_dropped;
    uint64_t frames_late;
    uint64_t frames_duplicate;
    uint64_t frames_incomplete;
    uint64_t frames_out_of_window;
    uint64_t frames_stale;
    uint64_t clock_resets;
};

typedef void (*f4d_sync_set_fn)(void *user, const struct hal_set *set);
typedef void (*f4d_sync_release_fn)(void *user, struct hal_buffer *buf);

struct f4d_sync_slot {
    struct hal_set set;
    uint64_t deadline_ns;
    uint32_t rejected_mask;   /* cameras whose frame was rejected out of window */
};

struct f4d_sync_cam {
    bool clock_known;
    uint32_t learned;         /* frames seen while learning the offset */
    int64_t learn[F4D_SYNC_LEARN_FRAMES]; /* their device-minus-edge times */
    int64_t offset_ns;        /* device_ts - trigger_ts, learned */
    uint32_t misses;          /* out-of-window frames in a row */
};

struct f4d_sync_hist {
    uint64_t seq;
    uint32_t present_mask;    /* cameras that had a frame when the set closed */
    uint32_t counted_dropped; /* cameras counted in frames_dropped */
};

struct f4d_sync {
    struct f4d_sync_config cfg;
    f4d_sync_set_fn on_set;
    f4d_sync_release_fn on_release;
    void *user;
    struct f4d_sync_slot slots[F4D_SYNC_PENDING_MAX]; /* ring, ordered by seq */
    uint32_t s_head, s_count;
    uint64_t closed_through;  /* every seq <= this is closed */
    struct f4d_sync_hist hist[F4D_SYNC_HISTORY];
    struct f4d_sync_cam cams[F4D_SYNC_CAMS_MAX];
    struct f4d_sync_counters c;
};

/* F4D_EINVAL if the config is out of range (n_cams 1..16, pending 1..64, window > 0). */
int f4d_sync_init(struct f4d_sync *s, const struct f4d_sync_config *cfg, f4d_sync_set_fn on_set,
                  f4d_sync_release_fn on_release, void *user);
void f4d_sync_edge(struct f4d_sync *s, const struct hal_edge *e);
void f4d_sync_frame(struct f4d_sync *s, struct hal_buffer *b);
/* Closes sets (in sequence order) that are complete or past their deadline. */
void f4d_sync_advance(struct f4d_sync *s, uint64_t now_ns);
/* Earliest deadline of an open set, or UINT64_MAX. */
uint64_t f4d_sync_next_deadline(const struct f4d_sync *s);
void f4d_sync_flush(struct f4d_sync *s);
/* Forgets a camera's clock (after the caller saw it disconnect). */
void f4d_sync_camera_reset(struct f4d_sync *s, uint32_t cam);

#endif
