/* hal_libcamera.h: CSI (and UVC) cameras through libcamera 0.0.3.
 *
 * Backend name "libcamera"; a board camera's `address` is the libcamera
 * camera id (what `cam -l` prints, e.g. "/base/soc/i2c0mux/i2c@1/imx219@10"
 * for a CSI sensor, "\_SB_.PCI0.XHC_.RHUB.HS01-1:1.0-046d:0825" for UVC).
 * Cameras only: no trigger (libcamera 0.0.3 has no trigger control), the
 * sensors run free; pair the board with the "usb" host-tick trigger or a
 * hardware line that the sensor's own driver wires up.
 *
 * libcamera is C++ only, so the backend is a C file over a small extern "C"
 * shim (hal_libcamera_shim.h/.cpp, the only C++ in the tree). The session
 * holds one reference on libcamera's process-wide CameraManager.
 *
 * Buffers: libcamera 0.0.3 cannot import caller memory (only dmabufs), so the
 * shim allocates FrameBuffers (FrameBufferAllocator) at configure, maps them
 * once, and each completed request is copied into the caller's oldest queued
 * hal_buffer (one memcpy per frame, no allocation); a frame that finds no
 * queued caller buffer is dropped and its request goes straight back.
 *
 * Format: our enum hal_pixfmt maps onto DRM fourccs: mono8 = R8, mono16 =
 * R16, rgb8 = BGR888 (bytes R,G,B in memory), bayer_rg8 = SRGGB8, yuyv =
 * YUYV; validate = CameraConfiguration::validate (Adjusted -> ADJUSTED).
 * Frames: device_ts = controls::SensorTimestamp (FrameMetadata::timestamp
 * when absent), frame_id = unwrapped FrameMetadata::sequence, trigger_seq =
 * frame_id + 1 (free run), host_ts = CLOCK_MONOTONIC at dequeue.
 *
 * Overlap with hal/usb: libcamera's UVC pipeline handler drives the same
 * uvcvideo V4L2 node as hal/usb, so a UVC camera can be opened either way.
 * The USB rig boards use hal/usb (V4L2 USERPTR: zero copy, testable here with
 * umockdev, and the node libusb hotplug reopens); this backend is for CSI
 * sensors, which need libcamera's pipeline handlers and ISP.
 *
 * Exercised here: the real shim's CameraManager start/stop (0 cameras on
 * this machine), refcounted double start/stop and restart, camera lookup
 * failures through the registry (tests/hal/test_libcamera.c); the C camera
 * ops (format mapping, state rules, caller-buffer FIFO and copy, sequence
 * unwrap, stop -> ABORTED, disconnect -> F4D_ENODEV) over a fake shim
 * (tests/hal/test_libcamera_ops.c). Not exercised: the shim's camera half
 * (configure, FrameBufferAllocator, mmap, requests, SensorTimestamp) against
 * a real camera: there is none here, and libcamera 0.0.3 has no virtual
 * pipeline handler (vimc needs a kernel driver).
 */
#ifndef F4D_HAL_LIBCAMERA_H
#define F4D_HAL_LIBCAMERA_H

#include "hal.h"

extern const struct hal_backend hal_libcamera_backend;

#endif
