/* hal_usb.h: USB (UVC) cameras through V4L2, in plain C.
 *
 * Why V4L2 and not libcamera: on edge Linux every UVC camera is served by the
 * kernel's uvcvideo driver, which is a V4L2 device; libcamera's UVC pipeline
 * handler is a C++ layer over that same device (Debian 12 ships 0.0.3, with
 * no stable ABI and no C API, so it would need a C++ shim and a C++ runtime in
 * the firmware for no extra capability on UVC). V4L2 also offers USERPTR
 * streaming, which fits the HAL's caller-owned buffer queue exactly: the
 * driver writes into the caller's memory, nothing is copied or allocated per
 * frame. Cameras on a CSI/ISP pipeline would be a separate libcamera backend.
 *
 * UVC cameras have no trigger input, so they run free at the board's rate.
 * The backend's trigger ("usb") is a host timer: it emits ticks at the board's
 * rate on CLOCK_MONOTONIC, and each frame is given the sequence number of the
 * tick nearest to its V4L2 timestamp (monotonic for uvcvideo); the
 * synchronizer's window (set it to about half the period) rejects frames that
 * are too far from any tick. Frames older than the first tick are discarded.
 *
 * Camera address: the device node (/dev/video0). Validate uses VIDIOC_TRY_FMT
 * (the driver's adjustments become HAL_FORMAT_ADJUSTED); configure uses
 * VIDIOC_S_FMT and VIDIOC_S_PARM; streaming uses VIDIOC_REQBUFS(USERPTR),
 * QBUF, DQBUF, STREAMON/OFF.
 *
 * Exercised here (no V4L2 in this kernel): every ioctl path against a fake
 * /dev/video0 answered by a umockdev ioctl handler in tests/hal/test_usb.c,
 * including USERPTR streaming with sequence numbers and timestamps; not
 * exercised: a real uvcvideo device, poll() wake-ups from a real driver.
 */
#ifndef F4D_HAL_USB_H
#define F4D_HAL_USB_H

#include "hal.h"
#include "hal_usb_hotplug.h"

extern const struct hal_backend hal_usb_backend;

/* The session's hotplug event source (tests put a fake one in place of the
 * libusb monitor; session = hal_rig_session(&rig, "usb")). */
int hal_usb_session_set_events(void *session, struct hal_usb_event_source src);
/* Why the session has no libusb monitor ("" when it has one). */
const char *hal_usb_session_hotplug_error(void *session);
/* The reconnect state of a usb camera (reconnect counts), NULL if the camera
 * is not a usb camera or its node has no USB device in sysfs. */
const struct hal_usb_link *hal_usb_camera_link(const struct hal_camera *cam);

#endif
