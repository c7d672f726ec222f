/* hal_usb_hotplug.c: the libusb hotplug monitor and the sysfs mapping
 * between V4L2 nodes and USB devices (see hal_usb_hotplug.h). */
#include "hal_usb_hotplug.h"

#include "hal_backend.h"

#include <dirent.h>
#include <libusb.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/time.h>

/* ---- sysfs ---- */
/* Reads one line of a sysfs attribute into buf (trailing newline removed). */
static bool read_attr(const char *path, char *buf, size_t cap)
{
    FILE *f = fopen(path, "re");
    if (!f)
        return false;
    bool ok = fgets(buf, (int)cap, f) != NULL;
    fclose(f);
    if (!ok)
        return false;
    buf[strcspn(buf, "\n")] = 0;
    return true;
}

static bool read_num(const char *path, int base, unsigned long *out)
{
    char b[32];
    if (!read_attr(path, b, sizeof b) || !b[0])
        return false;
    char *end = NULL;
    *out = strtoul(b, &end, base);
    return end != b;
}

/* The identity of the USB device directory `dir` (has idVendor etc.). */
static int identify_usb_dir(const char *dir, struct hal_usb_id *out)
{
    char p[512];
    unsigned long vid, pid, bus, dev;
    memset(out, 0, sizeof *out);
    snprintf(p, sizeof p, "%s/idVendor", dir);
    if (!read_num(p, 16, &vid))
        return F4D_ENODEV;
    snprintf(p, sizeof p, "%s/idProduct", dir);
    if (!read_num(p, 16, &pid))
        return F4D_ENODEV;
    snprintf(p, sizeof p, "%s/busnum", dir);
    if (!read_num(p, 10, &bus))
        bus = 0;
    snprintf(p, sizeof p, "%s/devnum", dir);
    if (!read_num(p, 10, &dev))
        dev = 0;
    out->vid = (uint16_t)vid;
    out->pid = (uint16_t)pid;
    out->bus = (uint8_t)bus;
    out->devnum = (uint8_t)dev;
    snprintf(p, sizeof p, "%s/devpath", dir);
    if (!read_attr(p, out->port_path, sizeof out->port_path))
        out->port_path[0] = 0;
    snprintf(p, sizeof p, "%s/serial", dir);
    if (!read_attr(p, out->serial, sizeof out->serial))
        out->serial[0] = 0;
    return F4D_OK;
}

static int identify_v4l(const char *name, struct hal_usb_id *out)
{
    char dir[256];
    /* device = the USB interface; its parent directory is the USB device */
    snprintf(dir, sizeof dir, "/sys/class/video4linux/%.64s/device/..", name);
    return identify_usb_dir(dir, out);
}

int hal_usb_sysfs_identify(const char *node, struct hal_usb_id *out)
{
    const char *name = strrchr(node, '/');
    name = name ? name + 1 : node;
    if (strncmp(name, "video", 5) != 0)
        return F4D_ENODEV;
    return identify_v4l(name, out);
}

int hal_usb_sysfs_find_node(const struct hal_usb_id *want, char *node, size_t cap, struct hal_usb_id *found)
{
    DIR *d = opendir("/sys/class/video4linux");
    if (!d)
        return F4D_ENODEV;
    long best = -1;
    struct hal_usb_id best_id;
    memset(&best_id, 0, sizeof best_id);
    struct dirent *e;
    while ((e = readdir(d)) != NULL) {
        if (strncmp(e->d_name, "video", 5) != 0)
            continue;
        char *end = NULL;
        long n = strtol(e->d_name + 5, &end, 10);
        if (end == e->d_name + 5 || *end)
            continue;
        struct hal_usb_id id;
        if (identify_v4l(e->d_name, &id) < 0 || !hal_usb_id_match(want, &id))
            continue;
        char p[256];
        unsigned long index = 0;
        snprintf(p, sizeof p, "/sys/class/video4linux/%.64s/index", e->d_name);
        if (read_num(p, 10, &index) && index != 0)
            continue; /* metadata node of the same camera */
        if (best < 0 || n < best) {
            best = n;
            best_id = id;
        }
    }
    closedir(d);
    if (best < 0)
        return F4D_ENODEV;
    snprintf(node, cap, "/dev/video%ld", best);
    if (found)
        *found = best_id;
    return F4D_OK;
}

void hal_usb_sysfs_serial(uint8_t bus, const char *port_path, char *serial, size_t cap)
{
    char p[128];
    snprintf(p, sizeof p, "/sys/bus/usb/devices/%u-%.31s/serial", (unsigned)bus, port_path);
    if (!read_attr(p, serial, cap))
        serial[0] = 0;
}

/* ---- libusb monitor ---- */
#define HOTPLUG_RING 64

struct hal_usb_hotplug {
    libusb_context *ctx;
    libusb_hotplug_callback_handle cb;
    struct hal_usb_event ring[HOTPLUG_RING];
    uint32_t head, count;
    uint64_t dropped;
};

static int LIBUSB_CALL on_hotplug(libusb_context *ctx, libusb_device *dev, libusb_hotplug_event event,
                                  void *user)
{
    (void)ctx;
    struct hal_usb_hotplug *h = user;
    if (h->count == HOTPLUG_RING) {
        h->dropped++;
        return 0;
    }
    struct hal_usb_event *e = &h->ring[(h->head + h->count++) % HOTPLUG_RING];
    memset(e, 0, sizeof *e);
    e->kind = event == LIBUSB_HOTPLUG_EVENT_DEVICE_ARRIVED ? HAL_USB_ARRIVED : HAL_USB_LEFT;
    struct libusb_device_descriptor dd;
    if (libusb_get_device_descriptor(dev, &dd) == 0) { /* cached: works after departure too */
        e->dev.vid = dd.idVendor;
        e->dev.pid = dd.idProduct;
    }
    e->dev.bus = libusb_get_bus_number(dev);
    e->dev.devnum = libusb_get_device_address(dev);
    uint8_t ports[8];
    int n = libusb_get_port_numbers(dev, ports, sizeof ports);
    size_t used = 0;
    for (int i = 0; i < n && used < sizeof e->dev.port_path; i++)
        used += (size_t)snprintf(e->dev.port_path + used, sizeof e->dev.port_path - used, "%s%u", i ? "." : "",
                                 (unsigned)ports[i]);
    return 0; /* stay registered */
}

static int hotplug_poll(void *ctx, struct hal_usb_event *out, uint32_t max, uint32_t timeout_us)
{
    struct hal_usb_hotplug *h = ctx;
    struct timeval tv = {(time_t)(timeout_us / 1000000u), (suseconds_t)(timeout_us % 1000000u)};
    if (h->count == 0) {
        int r = libusb_handle_events_timeout_completed(h->ctx, &tv, NULL);
        if (r < 0 && r != LIBUSB_ERROR_INTERRUPTED && r != LIBUSB_ERROR_TIMEOUT)
            return F4D_EIO;
    } else {
        struct timeval zero = {0, 0};
        libusb_handle_events_timeout_completed(h->ctx, &zero, NULL);
    }
    uint32_t n = 0;
    while (n < max && h->count) {
        out[n] = h->ring[h->head];
        h->head = (h->head + 1) % HOTPLUG_RING;
        h->count--;
        /* outside the callback: read what libusb cannot give without opening the device */
        if (out[n].kind == HAL_USB_ARRIVED && out[n].dev.port_path[0])
            hal_usb_sysfs_serial(out[n].dev.bus, out[n].dev.port_path, out[n].dev.serial,
                                 sizeof out[n].dev.serial);
        n++;
    }
    return (int)n;
}

static const struct hal_usb_event_source_ops hotplug_source_ops = {.poll = hotplug_poll};

int hal_usb_hotplug_open(struct hal_usb_hotplug **out, struct f4d_err *err)
{
    *out = NULL;
    struct hal_usb_hotplug *h = calloc(1, sizeof *h);
    if (!h)
        return f4d_fail(err, F4D_ENOMEM, "usb hotplug: out of memory");
    int r = libusb_init(&h->ctx);
    if (r < 0) {
        free(h);
        return f4d_fail(err, F4D_EIO, "usb hotplug: libusb_init: %s", libusb_strerror(r));
    }
    if (!libusb_has_capability(LIBUSB_CAP_HAS_HOTPLUG)) {
        libusb_exit(h->ctx);
        free(h);
        return f4d_fail(err, F4D_ENOTSUP, "usb hotplug: libusb has no hotplug support here");
    }
    /* no ENUMERATE flag: devices present now are the ones the cameras opened */
    r = libusb_hotplug_register_callback(h->ctx,
                                         LIBUSB_HOTPLUG_EVENT_DEVICE_ARRIVED | LIBUSB_HOTPLUG_EVENT_DEVICE_LEFT,
                                         0, LIBUSB_HOTPLUG_MATCH_ANY, LIBUSB_HOTPLUG_MATCH_ANY,
                                         LIBUSB_HOTPLUG_MATCH_ANY, on_hotplug, h, &h->cb);
    if (r != LIBUSB_SUCCESS) {
        libusb_exit(h->ctx);
        free(h);
        return f4d_fail(err, F4D_EIO, "usb hotplug: libusb_hotplug_register_callback: %s",
                        libusb_strerror(r));
    }
    *out = h;
    return F4D_OK;
}

void hal_usb_hotplug_close(struct hal_usb_hotplug *h)
{
    if (!h)
        return;
    libusb_hotplug_deregister_callback(h->ctx, h->cb);
    libusb_exit(h->ctx);
    free(h);
}

struct hal_usb_event_source hal_usb_hotplug_source(struct hal_usb_hotplug *h)
{
    struct hal_usb_event_source s = {&hotplug_source_ops, h};
    return s;
}

uint64_t hal_usb_hotplug_dropped(const struct hal_usb_hotplug *h) { return h->dropped; }
