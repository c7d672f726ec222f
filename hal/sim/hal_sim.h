/* hal_sim.h: the simulated backend (always built, the default).
 *
 * One simulated world per rig: a trigger generator, N cameras exposed by its
 * pulses, and a clock. Deterministic for `board->sim.seed`. With
 * `sim.realtime = false` the clock is simulated and jumps to the next event,
 * so 10,000 triggers take well under a second.
 *
 * Faults come from `board->sim.faults` and the world counts exactly what it
 * injected (hal_sim_injected), so tests can compare the synchronizer's
 * counters against the truth. Each frame gets at most one of drop, duplicate,
 * late, incomplete. A camera that disconnects loses the frames of every pulse
 * until it reconnects; its first frame after that has HAL_FRAME_FLAG_CLOCK_RESET
 * and a new device clock offset.
 *
 * Every image starts with a 16-byte stamp (magic, camera index, pulse sequence)
 * written by the world, which is the ground truth a test uses to prove that no
 * synchronized set mixes triggers (hal_sim_stamp_read).
 *
 *     struct hal_rig rig;  hal_rig_open(&rig, &board, err, n);
 *     void *world = hal_rig_session(&rig, "sim");
 *     ... capture ...
 *     struct hal_sim_injected inj;  hal_sim_injected_get(world, &inj);
 */
#ifndef F4D_HAL_SIM_H
#define F4D_HAL_SIM_H

#include "hal.h"

/* What the world injected so far (cameras that were started only). */
struct hal_sim_injected {
    uint64_t pulses_scheduled;       /* regular pulses of the armed train */
    uint64_t triggers_missing;       /* regular pulses that never reached the line */
    uint64_t triggers_extra;         /* spurious pulses between regular ones */
    uint64_t edges;                  /* pulses on the line = scheduled - missing + extra */
    uint64_t frames_exposed;         /* camera x edge, disconnected cameras excluded */
    uint64_t frames_dropped;         /* random drops + frames lost while disconnected */
    uint64_t frames_lost_disconnected;
    uint64_t frames_late;
    uint64_t frames_duplicate;
    uint64_t frames_incomplete;
    uint64_t disconnects;
    uint64_t underruns;              /* frames lost because no buffer was queued (not a fault) */
};
int hal_sim_injected_get(const void *world, struct hal_sim_injected *out);

/* Renders camera `cam`'s view at time `t_ns` (rig clock) into `dst`, laid out
 * as `f`. The default draws a procedural pattern (hal_sim_render_pattern);
 * the synthetic 4D scenes plug in here. Returns 0 or <0. */
typedef int (*hal_sim_render_fn)(void *user, uint32_t cam, uint64_t t_ns,
                                 const struct hal_format *f, uint8_t *dst);
void hal_sim_set_renderer(void *world, hal_sim_render_fn fn, void *user);
int hal_sim_render_pattern(void *user, uint32_t cam, uint64_t t_ns,
                           const struct hal_format *f, uint8_t *dst);

/* Fault knobs that board files do not carry (tests): camera `cam`'s start
 * fails with `rc` (<0) from now on, 0 = starts again. F4D_EINVAL if no such camera. */
int hal_sim_fail_start(void *world, uint32_t cam, int rc);
/* Caller buffers camera `cam` holds: queued for a frame, or handed back by
 * stop and not yet dequeued. 0 once the caller took every buffer back. */
uint32_t hal_sim_buffers_held(const void *world, uint32_t cam);

#define HAL_SIM_STAMP_BYTES 16
/* Reads the ground-truth stamp of a sim frame; F4D_EINVAL if absent. */
int hal_sim_stamp_read(const uint8_t *data, size_t n, uint64_t *seq, uint32_t *cam);

extern const struct hal_backend hal_sim_backend;

#endif
