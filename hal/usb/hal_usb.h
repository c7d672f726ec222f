/* hal_usb.h: USB (UVC) cameras through V4L2, in plain C.
 *
 * Why V4L2 and not libcamera for UVC: on edge Linux every UVC camera is
 * served by the kernel's uvcvideo driver, which is a V4L2 device; libcamera's
 * UVC pipeline handler is a C++ layer over that same device. V4L2 offers
 * USERPTR streaming, which fits the HAL's caller-owned buffer queue exactly
 * (the driver writes into the caller's memory, nothing is copied or
 * allocated per frame; libcamera 0.0.3 can only fill its own dmabufs, so
 * hal/libcamera copies once per frame), it is the path umockdev can exercise
 * here, and it is the node that the libusb hotplug logic reopens. Cameras on
 * a CSI/ISP pipeline use hal/libcamera (backend "libcamera"), which can also
 * open a UVC camera by its libcamera id: the overlap is deliberate and the
 * USB boards use this backend.
 *
 * UVC cameras have no trigger input, so they run free at the board's rate.
 * The backend's trigger ("usb") is a host timer: it emits ticks at the board's
 * rate on CLOCK_MONOTONIC, and each frame is given the sequence number of the
 * tick nearest to its V4L2 timestamp (monotonic for uvcvideo); the
 * synchronizer's window (set it to about half the period) rejects frames that
 * are too far from any tick. Frames older than the first tick are discarded.
 *
 * Camera address: the device node (/dev/video0), or the USB device,
 * "usb:VVVV:PPPP" or "usb:VVVV:PPPP@BUS-PORTS" plus the board's "serial",
 * mapped to its capture node through sysfs (hal_usb_hotplug.h). Validate uses
 * VIDIOC_TRY_FMT (the driver's adjustments become HAL_FORMAT_ADJUSTED);
 * configure uses VIDIOC_S_FMT and VIDIOC_S_PARM; streaming uses
 * VIDIOC_REQBUFS(USERPTR), QBUF, DQBUF, STREAMON/OFF.
 *
 * Hotplug (hal_usb_hotplug.h): a camera whose node has a USB parent in
 * sysfs joins the session's hub. When its device leaves (libusb hotplug
 * event, or DQBUF failing ENODEV first) the node is closed, the buffers it
 * held come back from dequeue ABORTED, and dequeue then fails F4D_ENODEV
 * (waiting up to its timeout for the device). When a device matching the
 * camera arrives (VID:PID + serial, or the same port when it has no serial;
 * same VID:PID with another serial is not it), its new node is found in
 * sysfs, opened, the format set again, the caller's queued buffers queued
 * and streaming restarted; the first frame carries HAL_FRAME_FLAG_CLOCK_RESET.
 * The capture loop needs no restart. Events are pumped from dequeue (libusb's
 * own udev monitor thread collects them; the callbacks and the reopen run in
 * the caller's thread); without libusb hotplug (libusb_init fails, no
 * capability) a camera that leaves stays gone (hal_usb_session_hotplug_error).
 *
 * Exercised here (no V4L2 in this kernel): every ioctl path against a fake
 * /dev/video0 answered by a umockdev ioctl handler in tests/hal/test_usb.c,
 * including USERPTR streaming with sequence numbers and timestamps, and an
 * unplug/replug mid-stream of a fake USB camera whose sysfs tree (usb device,
 * interface, capture + metadata nodes) lives in the umockdev testbed, with
 * the events scripted; tests/hal/test_usb_hotplug.c runs the reconnect logic
 * against a fake event source and the real libusb monitor, whose callback
 * fires for a device added to / removed from the umockdev testbed at run
 * time. Not exercised: a real uvcvideo device, poll() wake-ups from a real
 * driver, real udev timing between the USB device and its V4L2 node.
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
