/* hal_usb_hotplug.h: USB cameras that leave and come back (hal/usb).
 *
 * Three pieces, so that the logic is testable without libusb:
 *
 * 1. Events and their source. A `struct hal_usb_event` says a USB device
 *    arrived or left, keyed by VID:PID, bus + port path (sysfs "devpath",
 *    e.g. "1.2"), device number and serial. A `struct hal_usb_event_source`
 *    is anything that hands them out: the libusb monitor below, or a fake in
 *    tests.
 *
 * 2. The reconnect logic (hal_usb_reconnect.c, pure: no libusb, no V4L2, no
 *    allocation). One `struct hal_usb_link` per camera:
 *
 *        UP --(device left, or I/O said ENODEV)--> drop(): node closed,
 *            queued buffers handed back ABORTED, dequeue fails F4D_ENODEV
 *        WAITING --(a device matching this camera arrived)--> PENDING
 *        PENDING --(find_node() found its /dev/videoN: uvcvideo binds a moment
 *            after the USB device appears; retried on every pump)--> reopen():
 *            open node, re-apply format, requeue buffers, STREAMON
 *            --> UP, reconnects++ (reopen failure: back to WAITING)
 *
 *    A camera matches by `want` (board: VID:PID, serial, port path; zero or
 *    empty fields match anything): a device with the same VID:PID but another
 *    serial is ignored. Departures match the device the camera is on now
 *    (`have`: bus + device number, as serials cannot be read from a device
 *    that is gone). A `struct hal_usb_hub` (one per backend session) pumps
 *    one event source into every camera's link.
 *
 * 3. The libusb monitor (hal_usb_hotplug.c): libusb_init, a check of
 *    LIBUSB_CAP_HAS_HOTPLUG, libusb_hotplug_register_callback for any
 *    device (arrived + left). No thread of ours: the source's poll() runs
 *    libusb_handle_events_timeout_completed() in the caller's thread (the
 *    camera's dequeue path; libusb's own udev monitor thread only queues
 *    what it sees), the callback copies each event into a fixed
 *    ring (64, no allocation; when full, newer events are counted and
 *    dropped), and the serial of an arrived device is read from sysfs
 *    (/sys/bus/usb/devices/<bus>-<devpath>/serial) after the callback.
 *
 * The sysfs mapping between a V4L2 node and its USB device: /sys/class/
 * video4linux/videoN/device is the USB interface, its parent directory
 * ("device/..") the USB device with busnum, devnum, devpath, idVendor,
 * idProduct and serial; a UVC camera has several nodes (capture and
 * metadata): the one with attribute index 0 is taken.
 */
#ifndef F4D_HAL_USB_HOTPLUG_H
#define F4D_HAL_USB_HOTPLUG_H

#include "hal.h"

/* ---- device identity and events ---------------------------------------- */
struct hal_usb_id {
    uint16_t vid, pid;        /* 0 = any (in a `want`) */
    uint8_t bus, devnum;      /* 0 = unknown / any */
    char port_path[32];       /* sysfs devpath, "1.2"; "" = any */
    char serial[64];          /* "" = any / unknown */
};
/* "046d:0825 serial ABC on 1-1.2 (dev 5)" for messages. */
void hal_usb_id_format(const struct hal_usb_id *id, char *buf, size_t cap);
/* Parses a board address "usb:VVVV:PPPP" or "usb:VVVV:PPPP@BUS-PORTPATH"
 * (hex VID:PID); F4D_EINVAL if it is not one. */
int hal_usb_id_parse(const char *address, struct hal_usb_id *out);
/* Does `dev` satisfy `want`? (every non-zero / non-empty field of want equal) */
bool hal_usb_id_match(const struct hal_usb_id *want, const struct hal_usb_id *dev);

enum hal_usb_event_kind { HAL_USB_ARRIVED = 1, HAL_USB_LEFT = 2 };
struct hal_usb_event {
    enum hal_usb_event_kind kind;
    struct hal_usb_id dev;
};

struct hal_usb_event_source_ops {
    /* Moves up to `max` pending events into `out`, waiting at most
     * `timeout_us` for the first; returns the count (>= 0) or < 0. */
    int (*poll)(void *ctx, struct hal_usb_event *out, uint32_t max, uint32_t timeout_us);
};
struct hal_usb_event_source {
    const struct hal_usb_event_source_ops *ops;
    void *ctx;
};

/* ---- the reconnect logic (pure) ---------------------------------------- */
/* What the logic asks of the camera; every call comes from hub_pump (i.e.
 * from the thread that pumps). */
struct hal_usb_dev_ops {
    /* The V4L2 node of USB device `dev` ("/dev/video3"): F4D_OK, or
     * F4D_ENODEV while it has none (yet). */
    int (*find_node)(void *cam, const struct hal_usb_id *dev, char *node, size_t cap);
    /* Open `node`, re-apply the format, requeue the buffers, restart streaming. */
    int (*reopen)(void *cam, const char *node);
    /* The device is gone: close the node, hand queued buffers back ABORTED. */
    void (*drop)(void *cam);
};

enum hal_usb_link_state {
    HAL_USB_LINK_UP = 0,      /* streaming (or ready to) on `have` */
    HAL_USB_LINK_WAITING = 1, /* device gone, waiting for it to come back */
    HAL_USB_LINK_PENDING = 2, /* it came back; waiting for its V4L2 node */
};
const char *hal_usb_link_state_name(enum hal_usb_link_state s);

struct hal_usb_link {
    struct hal_usb_id want;   /* what this camera is (board) */
    struct hal_usb_id have;   /* the device it is on now / came back as */
    enum hal_usb_link_state state;
    uint32_t reconnects;      /* successful reopens */
    uint32_t losses;          /* times the device was lost */
    uint32_t ignored;         /* arrivals that were not this camera */
    uint32_t reopen_failures;
    int last_rc;              /* last find_node/reopen status */
    const struct hal_usb_dev_ops *ops;
    void *cam;
};
void hal_usb_link_init(struct hal_usb_link *l, const struct hal_usb_id *want, const struct hal_usb_id *have,
                       const struct hal_usb_dev_ops *ops, void *cam);
/* Feeds one event (drop() / find_node() + reopen() as needed). */
void hal_usb_link_feed(struct hal_usb_link *l, const struct hal_usb_event *e);
/* The camera's own I/O said the device is gone (ENODEV) before any event. */
void hal_usb_link_lost(struct hal_usb_link *l);
/* PENDING: tries find_node() + reopen() again. */
void hal_usb_link_retry(struct hal_usb_link *l);

#define HAL_USB_HUB_LINKS 16
struct hal_usb_hub {
    struct hal_usb_event_source src;
    struct hal_usb_link *links[HAL_USB_HUB_LINKS];
    uint32_t n_links;
    uint64_t events;          /* events seen */
};
/* Adds a camera's link; false when full. */
bool hal_usb_hub_add(struct hal_usb_hub *h, struct hal_usb_link *l);
void hal_usb_hub_remove(struct hal_usb_hub *h, struct hal_usb_link *l);
/* Polls the source (waiting up to timeout_us for the first event), feeds
 * every event to every link, then retries PENDING links. Returns the number
 * of events or the source's error. */
int hal_usb_hub_pump(struct hal_usb_hub *h, uint32_t timeout_us);

/* ---- the libusb monitor -------------------------------------------------- */
struct hal_usb_hotplug;
/* libusb_init + hotplug capability check + callback registration.
 * F4D_ENOTSUP when libusb has no hotplug on this platform. */
int hal_usb_hotplug_open(struct hal_usb_hotplug **out, struct f4d_err *err);
void hal_usb_hotplug_close(struct hal_usb_hotplug *h);
/* The monitor as an event source (poll = libusb event handling + the ring). */
struct hal_usb_event_source hal_usb_hotplug_source(struct hal_usb_hotplug *h);
/* Events dropped because the ring was full. */
uint64_t hal_usb_hotplug_dropped(const struct hal_usb_hotplug *h);

/* ---- sysfs ------------------------------------------------------------- */
/* The USB device behind a V4L2 node ("/dev/video0"): F4D_ENODEV when the node
 * has no USB parent in sysfs. */
int hal_usb_sysfs_identify(const char *node, struct hal_usb_id *out);
/* The capture node (index 0) of the USB device matching `want`: F4D_ENODEV
 * when none; the first in videoN order wins. `found` (optional) gets the
 * device's full identity. */
int hal_usb_sysfs_find_node(const struct hal_usb_id *want, char *node, size_t cap, struct hal_usb_id *found);
/* Reads the serial of the device at bus-devpath from sysfs ("" if none). */
void hal_usb_sysfs_serial(uint8_t bus, const char *port_path, char *serial, size_t cap);

#endif /* F4D_HAL_USB_HOTPLUG_H */
