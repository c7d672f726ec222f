/* hal_gpiod.h: the GPIO trigger through libgpiod (v1 API, Debian 12).
 *
 * Board "trigger": {"backend": "gpiod", "chip": "gpiochip0", "line": 17,
 * "strobe_line": 18, "rate_hz": 30, "pulse_width_us": 1000}.
 *
 * Output: the trigger line is requested as an output (consumer "forge4d") and
 * driven high for pulse_width_us at each pulse of the armed train. Pulses are
 * produced from read_edges, which the capture loop polls every millisecond:
 * no thread, jitter bounded by the polling period plus scheduling (for tighter
 * timing a board wires a hardware PWM or a camera master to the line; the HAL
 * interface is the same).
 *
 * Input: when strobe_line >= 0 it is requested for rising-edge events and the
 * edges returned are the cameras' exposure strobes with kernel timestamps
 * (CLOCK_MONOTONIC for the v1 uAPI on kernels >= 5.7), numbered 1, 2, 3...
 * Without a strobe line the edges are the pulses as sent, timestamped on the
 * host monotonic clock just before the line goes high.
 *
 * Not exercised here: no GPIO chip can exist on this machine (no GPIOLIB in
 * the kernel, no gpio-sim). Tested: the library is linked and every failure
 * path (chip absent, not a GPIO device, bad line, bad rate) returns a clear
 * error naming the chip or line.
 */
#ifndef F4D_HAL_GPIOD_H
#define F4D_HAL_GPIOD_H

#include "hal.h"

extern const struct hal_backend hal_gpiod_backend;

#endif
