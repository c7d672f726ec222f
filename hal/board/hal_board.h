/* hal_board.h: reads a board description file (JSON, parsed with cJSON) into
 * `struct hal_board` (hal.h). Read once at start; the result is plain data.
 *
 *     struct hal_board b;
 *     struct f4d_err err = {0};
 *     if (hal_board_load(&b, "board/sim-4cam.json", &err) < 0)
 *         fprintf(stderr, "%s\n", err);   // e.g. "cameras[2].width: must be 16..65535, got 0"
 *
 * Format (every key optional except "cameras"; unknown keys are errors, so a
 * typo never silently becomes a default):
 *
 *     { "name": "sim-4cam",
 *       "cameras": [ { "id": "cam0", "backend": "sim", "serial": "", "address": "",
 *                      "width": 518, "height": 518, "pixel_format": "rgb8",
 *                      "trigger_line": 0, "exposure_us": 2000,
 *                      "packet_size": 8192, "socket_buffer": 4000000,
 *                      "intrinsics": { "fx": 400, "fy": 400, "cx": 259, "cy": 259 } } ],
 *       "trigger": { "backend": "sim"|"gpiod"|"aravis"|"usb"|"replay", "chip": "gpiochip0", "line": 17, "strobe_line": -1,
 *                    "rate_hz": 30, "pulse_width_us": 1000 },
 *       "sync": { "window_us": 2000, "max_latency_ms": 25, "incomplete": "drop"|"mark",
 *                 "pending_max": 8 },
 *       "recording": { "directory": "takes", "durability_ms": 250 },
 *       "sim": { "seed": 1, "realtime": true, "scene": "pattern",
 *                "faults": { "drop": 0.01, "duplicate": 0.01, "late": 0.01, "incomplete": 0.01,
 *                            "trigger_missing": 0.005, "trigger_extra": 0.005,
 *                            "disconnect": 0.0005, "disconnect_ms": 200, "late_ms": 80,
 *                            "jitter_us": 100, "clock_offset_ms": 5000, "clock_drift_ppm": 100 } } }
 */
#ifndef F4D_HAL_BOARD_H
#define F4D_HAL_BOARD_H

#include "hal.h"

/* Parses `len` bytes of JSON. On error returns <0 and names the key in err. */
int hal_board_parse(struct hal_board *b, const char *json, size_t len, struct f4d_err *err);
/* Reads and parses a file (at most 1 MiB). */
int hal_board_load(struct hal_board *b, const char *path, struct f4d_err *err);
/* Writes the board as JSON (the format above) into a malloc'd string; NULL on OOM. */
char *hal_board_to_json(const struct hal_board *b);

#endif
