/* test_usb_hotplug.c: USB camera reconnects (hal/usb/hal_usb_hotplug.h).
 *
 * (i) The pure reconnect logic against a FAKE event source and a fake camera
 *     (no libusb, no V4L2): unplug mid-stream, replug, frames resume,
 *     reconnects counted; unrelated devices, and a device with the same
 *     VID:PID but another serial, ignored; a node that appears late.
 * (ii) The real libusb monitor: libusb_init + LIBUSB_CAP_HAS_HOTPLUG +
 *     libusb_hotplug_register_callback, and, under umockdev-wrapper, whether
 *     a device added / removed in the umockdev testbed at runtime reaches the
 *     callback (see the comment in that test for what umockdev 0.17 does).
 */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>

#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <umockdev.h>

#include "hal_usb_hotplug.h"

/* ---- a fake event source: a script of events, handed out in order ---- */
struct fake_src {
    struct hal_usb_event q[32];
    uint32_t head, count;
    uint32_t polls;
};

static int fake_poll(void *ctx, struct hal_usb_event *out, uint32_t max, uint32_t timeout_us)
{
    (void)timeout_us; /* deterministic: never waits */
    struct fake_src *f = ctx;
    f->polls++;
    uint32_t n = 0;
    while (n < max && f->head < f->count)
        out[n++] = f->q[f->head++];
    return (int)n;
}
static const struct hal_usb_event_source_ops fake_src_ops = {.poll = fake_poll};

static void post(struct fake_src *f, enum hal_usb_event_kind k, uint16_t vid, uint16_t pid, uint8_t bus,
                 uint8_t devnum, const char *port, const char *serial)
{
    assert_true(f->count < 32);
    struct hal_usb_event *e = &f->q[f->count++];
    memset(e, 0, sizeof *e);
    e->kind = k;
    e->dev.vid = vid;
    e->dev.pid = pid;
    e->dev.bus = bus;
    e->dev.devnum = devnum;
    snprintf(e->dev.port_path, sizeof e->dev.port_path, "%s", port);
    snprintf(e->dev.serial, sizeof e->dev.serial, "%s", serial);
}

/* ---- a fake camera: streams while it has a node ---- */
struct fake_cam {
    bool open, streaming;
    uint32_t frames, drops, reopens, finds;
    uint32_t aborted;          /* buffers handed back ABORTED */
    uint32_t queued;           /* buffers the camera holds */
    bool node_ready;           /* the V4L2 node exists (uvcvideo bound) */
    uint8_t node_devnum;       /* the device whose node exists */
    char node[64];
};

static int fc_find(void *cam, const struct hal_usb_id *dev, char *node, size_t cap)
{
    struct fake_cam *c = cam;
    c->finds++;
    if (!c->node_ready || dev->devnum != c->node_devnum)
        return F4D_ENODEV;
    snprintf(node, cap, "/dev/video%u", (unsigned)dev->devnum);
    return F4D_OK;
}

static int fc_reopen(void *cam, const char *node)
{
    struct fake_cam *c = cam;
    c->reopens++;
    snprintf(c->node, sizeof c->node, "%s", node);
    c->open = c->streaming = true;
    c->queued = 4; /* the aborted buffers came back from the caller and are queued again */
    return F4D_OK;
}

static void fc_drop(void *cam)
{
    struct fake_cam *c = cam;
    c->drops++;
    c->open = c->streaming = false;
    c->aborted += c->queued;
    c->queued = 0;
}
static const struct hal_usb_dev_ops fc_ops = {fc_find, fc_reopen, fc_drop};

/* One capture-loop step: F4D_OK (a frame) or F4D_ENODEV, as a camera's
 * dequeue would answer after pumping the hub. */
static int step(struct hal_usb_hub *hub, struct hal_usb_link *l, struct fake_cam *c)
{
    assert_true(hal_usb_hub_pump(hub, 0) >= 0);
    if (l->state != HAL_USB_LINK_UP || !c->streaming)
        return F4D_ENODEV;
    c->frames++;
    return F4D_OK;
}

static void setup_cam(struct hal_usb_hub *hub, struct fake_src *src, struct hal_usb_link *l, struct fake_cam *c,
                      const char *want_serial)
{
    memset(hub, 0, sizeof *hub);
    memset(src, 0, sizeof *src);
    memset(c, 0, sizeof *c);
    hub->src.ops = &fake_src_ops;
    hub->src.ctx = src;
    /* the board names 046d:0825 with a serial; it is on bus 1 port 1.2, device 5 */
    struct hal_usb_id want = {0x046d, 0x0825, 0, 0, "", ""};
    snprintf(want.serial, sizeof want.serial, "%s", want_serial);
    struct hal_usb_id have = {0x046d, 0x0825, 1, 5, "1.2", ""};
    snprintf(have.serial, sizeof have.serial, "%s", want_serial);
    hal_usb_link_init(l, &want, &have, &fc_ops, c);
    assert_true(hal_usb_hub_add(hub, l));
    c->open = c->streaming = true;
    c->queued = 4;
}

static void unplug_replug(void **state)
{
    (void)state;
    struct hal_usb_hub hub;
    struct fake_src src;
    struct hal_usb_link l;
    struct fake_cam c;
    setup_cam(&hub, &src, &l, &c, "A1");
    for (int i = 0; i < 10; i++)
        assert_int_equal(step(&hub, &l, &c), F4D_OK);

    /* an unrelated device comes and goes: nothing happens */
    post(&src, HAL_USB_ARRIVED, 0x1209, 0x0001, 1, 6, "1.3", "");
    post(&src, HAL_USB_LEFT, 0x1209, 0x0001, 1, 6, "1.3", "");
    assert_int_equal(step(&hub, &l, &c), F4D_OK);
    assert_int_equal(l.state, HAL_USB_LINK_UP);
    assert_int_equal(c.drops, 0);

    /* unplugged mid-stream: the buffers come back ABORTED, frames fail ENODEV */
    post(&src, HAL_USB_LEFT, 0x046d, 0x0825, 1, 5, "1.2", "");
    assert_int_equal(step(&hub, &l, &c), F4D_ENODEV);
    assert_int_equal(l.state, HAL_USB_LINK_WAITING);
    assert_int_equal(c.drops, 1);
    assert_int_equal(c.aborted, 4);
    assert_int_equal(l.losses, 1);
    for (int i = 0; i < 5; i++)
        assert_int_equal(step(&hub, &l, &c), F4D_ENODEV);

    /* the same VID:PID with another serial (a second camera of the same model): ignored */
    post(&src, HAL_USB_ARRIVED, 0x046d, 0x0825, 1, 7, "1.2", "B2");
    c.node_ready = true;
    c.node_devnum = 7;
    assert_int_equal(step(&hub, &l, &c), F4D_ENODEV);
    assert_int_equal(l.state, HAL_USB_LINK_WAITING);
    assert_int_equal(c.reopens, 0);
    assert_int_equal(l.ignored, 2); /* the unrelated arrival and this one */

    /* ours comes back on another port with a new device number: reopened */
    post(&src, HAL_USB_ARRIVED, 0x046d, 0x0825, 2, 9, "4", "A1");
    c.node_devnum = 9;
    assert_int_equal(step(&hub, &l, &c), F4D_OK);
    assert_int_equal(l.state, HAL_USB_LINK_UP);
    assert_int_equal(l.reconnects, 1);
    assert_int_equal(c.reopens, 1);
    assert_string_equal(c.node, "/dev/video9");
    assert_int_equal(l.have.devnum, 9);
    for (int i = 0; i < 10; i++)
        assert_int_equal(step(&hub, &l, &c), F4D_OK);
    assert_int_equal(c.frames, 22); /* 11 before, 1 + 10 after the replug */

    /* the other camera (B2) leaving is not ours; ours leaving again is */
    post(&src, HAL_USB_LEFT, 0x046d, 0x0825, 1, 7, "1.2", "");
    assert_int_equal(step(&hub, &l, &c), F4D_OK);
    post(&src, HAL_USB_LEFT, 0x046d, 0x0825, 2, 9, "4", "");
    assert_int_equal(step(&hub, &l, &c), F4D_ENODEV);
    assert_int_equal(l.losses, 2);
    post(&src, HAL_USB_ARRIVED, 0x046d, 0x0825, 2, 10, "4", "A1");
    c.node_devnum = 10;
    assert_int_equal(step(&hub, &l, &c), F4D_OK);
    assert_int_equal(l.reconnects, 2);
    char id[160];
    hal_usb_id_format(&l.have, id, sizeof id);
    assert_string_equal(id, "046d:0825 serial A1 on 2-4 (dev 10)");
}

static void late_node_and_io_loss(void **state)
{
    (void)state;
    struct hal_usb_hub hub;
    struct fake_src src;
    struct hal_usb_link l;
    struct fake_cam c;
    setup_cam(&hub, &src, &l, &c, "");
    /* no serial: the board's want is VID:PID only here, so match by that */
    assert_int_equal(step(&hub, &l, &c), F4D_OK);

    /* the V4L2 node says ENODEV before libusb reports the departure */
    hal_usb_link_lost(&l);
    assert_int_equal(c.drops, 1);
    hal_usb_link_lost(&l); /* twice: once */
    assert_int_equal(c.drops, 1);
    post(&src, HAL_USB_LEFT, 0x046d, 0x0825, 1, 5, "1.2", ""); /* the late event changes nothing */
    assert_int_equal(step(&hub, &l, &c), F4D_ENODEV);
    assert_int_equal(c.drops, 1);
    assert_int_equal(l.losses, 1);

    /* back, but uvcvideo has not made the node yet: pending, retried each pump */
    post(&src, HAL_USB_ARRIVED, 0x046d, 0x0825, 1, 6, "1.2", "");
    assert_int_equal(step(&hub, &l, &c), F4D_ENODEV);
    assert_int_equal(l.state, HAL_USB_LINK_PENDING);
    assert_int_equal(step(&hub, &l, &c), F4D_ENODEV);
    uint32_t finds = c.finds;
    assert_true(finds >= 2);
    c.node_ready = true;
    c.node_devnum = 6;
    assert_int_equal(step(&hub, &l, &c), F4D_OK);
    assert_int_equal(l.reconnects, 1);

    /* hub bookkeeping */
    hal_usb_hub_remove(&hub, &l);
    assert_int_equal(hub.n_links, 0);
    assert_int_equal(hal_usb_link_state_name(HAL_USB_LINK_PENDING)[0], 'p');
}

static void ids(void **state)
{
    (void)state;
    struct hal_usb_id id;
    assert_int_equal(hal_usb_id_parse("usb:046d:0825", &id), F4D_OK);
    assert_int_equal(id.vid, 0x046d);
    assert_int_equal(id.pid, 0x0825);
    assert_int_equal(id.bus, 0);
    assert_int_equal(hal_usb_id_parse("usb:046D:0825@3-1.4.2", &id), F4D_OK);
    assert_int_equal(id.bus, 3);
    assert_string_equal(id.port_path, "1.4.2");
    assert_int_equal(hal_usb_id_parse("/dev/video0", &id), F4D_EINVAL);
    assert_int_equal(hal_usb_id_parse("usb:046d", &id), F4D_EINVAL);
    assert_int_equal(hal_usb_id_parse("usb:046d:08z5", &id), F4D_EINVAL);
    assert_int_equal(hal_usb_id_parse("usb:12345:0001", &id), F4D_EINVAL);
    assert_int_equal(hal_usb_id_parse("usb:046d:0825@3", &id), F4D_EINVAL);
    assert_int_equal(hal_usb_id_parse("usb:046d:0825@3-x", &id), F4D_EINVAL);
    struct hal_usb_id want = {0x046d, 0, 0, 0, "", "S"};
    struct hal_usb_id dev = {0x046d, 0x0825, 1, 2, "1", "S"};
    assert_true(hal_usb_id_match(&want, &dev));
    dev.serial[0] = 0;
    assert_false(hal_usb_id_match(&want, &dev));
}

/* ---- (ii) the real libusb monitor ---- */
static bool under_umockdev(void)
{
    const char *pre = getenv("LD_PRELOAD");
    return pre && strstr(pre, "umockdev");
}

static void libusb_monitor(void **state)
{
    (void)state;
    struct f4d_err err = {0};
    struct hal_usb_hotplug *h = NULL;
    int rc = hal_usb_hotplug_open(&h, &err);
    printf("[ hotplug ] libusb monitor: %s%s\n", rc == F4D_OK ? "registered" : "failed: ", err.msg);
    assert_int_equal(rc, F4D_OK); /* libusb_init + LIBUSB_CAP_HAS_HOTPLUG + register */
    struct hal_usb_event_source src = hal_usb_hotplug_source(h);
    struct hal_usb_event ev[8];
    assert_int_equal(src.ops->poll(src.ctx, ev, 8, 1000), 0); /* nothing happened */
    hal_usb_hotplug_close(h);

    if (!under_umockdev()) {
        printf("[ hotplug ] not under umockdev-wrapper: runtime add/remove not tried\n");
        return;
    }
    /* Runtime add/remove in the umockdev testbed: libusb (Debian builds it with
     * libudev) learns about devices from a udev monitor, and umockdev's
     * preload delivers the testbed's emulated uevents (umockdev_testbed_uevent)
     * to udev monitors of this process. */
    UMockdevTestbed *tb = umockdev_testbed_new();
    rc = hal_usb_hotplug_open(&h, &err);
    assert_int_equal(rc, F4D_OK);
    src = hal_usb_hotplug_source(h);
    /* device + configuration + interface descriptors, as the kernel's sysfs "descriptors" */
    GError *gerr = NULL;
    gboolean added = umockdev_testbed_add_from_string(
        tb,
        "P: /devices/pci0000:00/0000:00:14.0/usb1/1-2\n"
        "N: bus/usb/001/009\n"
        "E: SUBSYSTEM=usb\nE: DEVTYPE=usb_device\nE: BUSNUM=001\nE: DEVNUM=009\n"
        "E: DEVNAME=/dev/bus/usb/001/009\nE: PRODUCT=1209/1/100\n"
        "A: busnum=1\nA: devnum=9\nA: devpath=2\nA: idVendor=1209\nA: idProduct=0001\nA: serial=F4DHOT\n"
        "H: descriptors=12010002000000400912010000010000000109021200010100803209040000000000ff0000\n",
        &gerr);
    if (!added)
        fail_msg("umockdev: %s", gerr ? gerr->message : "?");
    const gchar *sys = "/sys/devices/pci0000:00/0000:00:14.0/usb1/1-2";
    umockdev_testbed_uevent(tb, sys, "add");
    int got_add = 0, got_left = 0;
    struct hal_usb_event last;
    memset(&last, 0, sizeof last);
    for (int i = 0; i < 20 && !got_add; i++) {
        int n = src.ops->poll(src.ctx, ev, 8, 50000);
        for (int k = 0; k < n; k++) {
            got_add += ev[k].kind == HAL_USB_ARRIVED;
            last = ev[k];
        }
    }
    umockdev_testbed_uevent(tb, sys, "remove");
    umockdev_testbed_remove_device(tb, sys);
    for (int i = 0; i < 20 && got_add && !got_left; i++) {
        int n = src.ops->poll(src.ctx, ev, 8, 50000);
        for (int k = 0; k < n; k++)
            got_left += ev[k].kind == HAL_USB_LEFT;
    }
    printf("[ hotplug ] umockdev runtime add -> %d arrival(s)%s%04x:%04x bus %u dev %u port %s serial \"%s\"; "
           "remove -> %d departure(s)\n",
           got_add, got_add ? ": " : " (", last.dev.vid, last.dev.pid, (unsigned)last.dev.bus,
           (unsigned)last.dev.devnum, last.dev.port_path, last.dev.serial, got_left);
    /* umockdev 0.17.16 + libusb 1.0.26: the emulated uevents reach libusb's
     * hotplug thread, so the callback fires for both */
    assert_int_equal(got_add, 1);
    assert_int_equal(last.dev.vid, 0x1209);
    assert_int_equal(last.dev.pid, 0x0001);
    assert_int_equal(last.dev.bus, 1);
    assert_int_equal(last.dev.devnum, 9);
    assert_string_equal(last.dev.port_path, "2");
    assert_string_equal(last.dev.serial, "F4DHOT"); /* read from sysfs after the callback */
    assert_int_equal(got_left, 1);
    hal_usb_hotplug_close(h);
    g_object_unref(tb);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(ids),
        cmocka_unit_test(unplug_replug),
        cmocka_unit_test(late_node_and_io_loss),
        cmocka_unit_test(libusb_monitor),
    };
    return cmocka_run_group_tests_name("hal/usb_hotplug", tests, NULL, NULL);
}
