/* hal_replay.h: plays a recorded take (hal/take) back as cameras and a
 * trigger, so every later stage runs on recordings exactly as on live rigs.
 *
 * Each camera of the board with backend "replay" plays camera `index` of the
 * take in its `address` (the take directory). The trigger (backend "replay")
 * emits the recorded edges. Frames keep their recorded status, device
 * timestamp, frame id and trigger sequence; host timestamps are re-based so
 * the take starts near 0 on the rig clock. With `board->sim.realtime` the
 * take plays at its original timing, otherwise as fast as possible on a
 * simulated clock. When the take is exhausted, the trigger reports done and
 * dequeue returns F4D_EEOF.
 *
 *     struct hal_board b;
 *     hal_replay_board(&b, "takes/t1", false, err, n);   // all cameras of the take
 *     hal_rig_open(&rig, &b, err, n);
 */
#ifndef F4D_HAL_REPLAY_H
#define F4D_HAL_REPLAY_H

#include "hal.h"

/* A board that replays every camera of the take in `dir`. */
int hal_replay_board(struct hal_board *b, const char *dir, bool realtime, struct f4d_err *err);
/* Sets that failed their CRC during playback (skipped). */
uint64_t hal_replay_corrupt_sets(const void *session);

extern const struct hal_backend hal_replay_backend;

#endif
