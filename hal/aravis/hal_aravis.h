/* hal_aravis.h: GigE Vision / USB3 Vision cameras through libaravis 0.8.
 *
 * Cameras are opened by address only (IP for GigE, or a device id), never by
 * discovery: discovery broadcasts on every interface. Per camera the backend
 * sets the region and pixel format, the trigger (TriggerSelector=FrameStart,
 * TriggerMode=On, TriggerSource=Line<trigger_line>, TriggerActivation=
 * RisingEdge through arv_camera_set_trigger), the exposure time, the GVSP
 * packet size and the stream's socket buffer (ARV_GV_STREAM_SOCKET_BUFFER_FIXED),
 * with the standard UDP socket (no packet socket: faster to set up, and it
 * works without CAP_NET_RAW).
 *
 * Buffers: the caller's memory is wrapped once per hal_buffer in an ArvBuffer
 * (arv_buffer_new_full, no copy); the stream fills it in place.
 *
 * Trigger: backend "aravis" is a software trigger: at each pulse of the armed
 * train it sends TriggerSoftware to every Aravis camera of the rig and records
 * the edge on the host monotonic clock. Pulses are sent from read_edges (the
 * capture loop polls it), so no thread is needed; their timing is as good as
 * the polling period. With a GPIO trigger (backend "gpiod") the cameras use
 * their hardware line instead.
 *
 * Streaming (hal_camera_streaming): a free-running or line-triggered camera
 * streams once acquisition start was acknowledged and its stream exists. A
 * software-triggered camera streams once a probe trigger came back as a frame
 * (one probe at a time, resent every 300 ms; an answer to a round with
 * resends is followed by 300 ms of quiet and a fresh single probe, so no
 * probe answer is still on its way). Probe frames are handed straight back to
 * the stream; they also absorb the stream's first, often incomplete, frame.
 * A GigE camera whose control is lost ("control-lost") stops streaming and
 * dequeue reports F4D_ENODEV. The software trigger sends a pulse only to
 * cameras that stream (probing the others instead).
 *
 * Trigger sequence numbers: a triggered camera exposes once per pulse, so the
 * frame counter (GVSP block id, 16-bit with GigE Vision 1.x: unwrapped here)
 * advances with the pulses. With the software trigger the counter is anchored
 * on the first pulse the camera was sent (it streams by then): its first frame
 * arriving after that pulse answers it, earlier frames (probe leftovers) are
 * dropped. With a hardware trigger the first frame is pulse 1. A camera that
 * misses a software trigger is re-anchored once three frames in a row clearly
 * follow other edges than their numbers say (frames renumbered onto a pulse
 * already delivered are dropped). The synchronizer's timestamp window catches
 * frames numbered wrongly meanwhile, so frames of different triggers are
 * never grouped.
 *
 * Timestamps: device_ts = arv_buffer_get_timestamp (device clock; the fake
 * camera uses host real time), host_ts = the arrival time moved onto the host
 * monotonic clock.
 *
 * Tested against the in-process ArvGvFakeCamera over loopback inside a private
 * network namespace (tests/hal/test_contract.c). Not exercised here: real
 * hardware, USB3 Vision, chunk data, packet resend, Line0 hardware trigger
 * (the fake camera does not simulate it).
 */
#ifndef F4D_HAL_ARAVIS_H
#define F4D_HAL_ARAVIS_H

#include "hal.h"

extern const struct hal_backend hal_aravis_backend;

#endif
