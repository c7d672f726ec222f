/* test_usb.c: the V4L2 (UVC) backend against a fake /dev/video0 whose ioctls
 * are answered by a umockdev handler in this process (the kernel here has no
 * V4L2). Covers open/QUERYCAP failures, TRY_FMT negotiation, S_FMT/S_PARM,
 * USERPTR streaming (REQBUFS, QBUF, DQBUF, STREAMON/OFF) with sequence
 * numbers and monotonic timestamps, and the host tick trigger that gives free-
 * running UVC frames their trigger sequence. Runs under umockdev-wrapper
 * (LD_PRELOAD); without it the fake-device cases are skipped. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>

#include <errno.h>
#include <linux/videodev2.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <umockdev.h>
#include <unistd.h>

#include "f4d_capture.h"
#include "f4d_test.h"
#include "hal_board.h"
#include "hal_registry.h"
#include "hal_usb.h"

/* ---- the fake UVC camera: 640x480 or 320x240, YUYV only ---- */
struct fake_cam {
    GMutex lock;
    uint32_t width, height;
    bool streaming;
    uint32_t n_req;
    unsigned long userptr[32];
    uint32_t length[32];
    bool queued[32];
    uint32_t next; /* round robin over queued buffers */
    uint32_t sequence;
    uint64_t frame_period_ns, next_frame_ns;
    uint32_t ioctls;
    bool unplugged; /* every ioctl fails ENODEV, as on a node whose device left */
};

static uint64_t mono_ns(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (uint64_t)ts.tv_sec * 1000000000u + (uint64_t)ts.tv_nsec;
}

static void snap(struct v4l2_pix_format *p)
{
    p->pixelformat = V4L2_PIX_FMT_YUYV;
    if (p->width >= 480) {
        p->width = 640;
        p->height = 480;
    } else {
        p->width = 320;
        p->height = 240;
    }
    p->bytesperline = p->width * 2;
    p->sizeimage = p->bytesperline * p->height;
    p->field = V4L2_FIELD_NONE;
}

static gboolean on_ioctl(UMockdevIoctlBase *h, UMockdevIoctlClient *client, gpointer user)
{
    (void)h;
    struct fake_cam *f = user;
    gulong req = umockdev_ioctl_client_get_request(client);
    UMockdevIoctlData *arg = umockdev_ioctl_client_get_arg(client);
    /* the argument is the caller's pointer: resolve the struct it points to
     * (written back to the caller when the ioctl completes) */
    UMockdevIoctlData *data = umockdev_ioctl_data_resolve(arg, 0, _IOC_SIZE(req), NULL);
    if (!data) {
        umockdev_ioctl_client_complete(client, -1, EFAULT);
        return TRUE;
    }
    void *d = data->data;
    long res = 0;
    int err = 0;
    g_mutex_lock(&f->lock);
    f->ioctls++;
    if (f->unplugged)
        req = 0, res = -1, err = ENODEV;
    switch (req) {
    case 0:
        break;
    case VIDIOC_QUERYCAP: {
        struct v4l2_capability *c = d;
        memset(c, 0, sizeof *c);
        snprintf((char *)c->driver, sizeof c->driver, "uvcvideo");
        snprintf((char *)c->card, sizeof c->card, "F4D fake UVC");
        c->capabilities = V4L2_CAP_VIDEO_CAPTURE | V4L2_CAP_STREAMING | V4L2_CAP_DEVICE_CAPS;
        c->device_caps = V4L2_CAP_VIDEO_CAPTURE | V4L2_CAP_STREAMING;
        break;
    }
    case VIDIOC_TRY_FMT:
    case VIDIOC_S_FMT: {
        struct v4l2_format *vf = d;
        snap(&vf->fmt.pix);
        if (req == VIDIOC_S_FMT) {
            f->width = vf->fmt.pix.width;
            f->height = vf->fmt.pix.height;
        }
        break;
    }
    case VIDIOC_S_PARM: {
        struct v4l2_streamparm *sp = d;
        if (sp->parm.capture.timeperframe.denominator)
            f->frame_period_ns = 1000000000ull * sp->parm.capture.timeperframe.numerator /
                                 sp->parm.capture.timeperframe.denominator;
        break;
    }
    case VIDIOC_REQBUFS: {
        struct v4l2_requestbuffers *rb = d;
        if (rb->memory != V4L2_MEMORY_USERPTR) {
            res = -1, err = EINVAL;
            break;
        }
        f->n_req = rb->count > 32 ? 32 : rb->count;
        rb->count = f->n_req;
        memset(f->queued, 0, sizeof f->queued);
        break;
    }
    case VIDIOC_QBUF: {
        struct v4l2_buffer *vb = d;
        if (vb->index >= f->n_req || vb->memory != V4L2_MEMORY_USERPTR ||
            vb->length < f->width * 2 * f->height) {
            res = -1, err = EINVAL;
            break;
        }
        f->userptr[vb->index] = vb->m.userptr;
        f->length[vb->index] = vb->length;
        f->queued[vb->index] = true;
        break;
    }
    case VIDIOC_STREAMON:
        f->streaming = true;
        f->next_frame_ns = mono_ns();
        break;
    case VIDIOC_STREAMOFF:
        f->streaming = false;
        memset(f->queued, 0, sizeof f->queued);
        break;
    case VIDIOC_DQBUF: {
        struct v4l2_buffer *vb = d;
        uint64_t now = mono_ns();
        uint32_t i = 0;
        for (; i < f->n_req && !f->queued[(f->next + i) % f->n_req]; i++) {
        }
        if (!f->streaming || i == f->n_req || now < f->next_frame_ns) {
            res = -1, err = EAGAIN;
            break;
        }
        uint32_t idx = (f->next + i) % f->n_req;
        f->next = idx + 1;
        f->queued[idx] = false;
        /* the "driver" writes the frame into the caller's memory: same process */
        uint8_t *img = (uint8_t *)f->userptr[idx];
        size_t n = (size_t)f->width * 2 * f->height;
        memset(img, (int)(f->sequence & 0xFF), n);
        memset(vb, 0, sizeof *vb);
        vb->type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
        vb->memory = V4L2_MEMORY_USERPTR;
        vb->index = idx;
        vb->m.userptr = f->userptr[idx];
        vb->length = f->length[idx];
        vb->bytesused = (uint32_t)n;
        vb->sequence = f->sequence++;
        vb->flags = V4L2_BUF_FLAG_TIMESTAMP_MONOTONIC | V4L2_BUF_FLAG_DONE;
        /* stamped when the "sensor" captured it (its slot on the frame
         * grid), as a driver does, not when the caller got round to DQBUF:
         * a caller delayed on a loaded machine must not move the frame out
         * of its tick's window */
        uint64_t shot = f->next_frame_ns;
        vb->timestamp.tv_sec = (time_t)(shot / 1000000000u);
        vb->timestamp.tv_usec = (suseconds_t)(shot % 1000000000u / 1000u);
        f->next_frame_ns += f->frame_period_ns ? f->frame_period_ns : 33333333u;
        break;
    }
    default:
        res = -1, err = ENOTTY;
    }
    g_mutex_unlock(&f->lock);
    umockdev_ioctl_client_complete(client, res, err);
    g_object_unref(data);
    return TRUE;
}

struct env {
    UMockdevTestbed *tb;
    UMockdevIoctlBase *handler;
    struct fake_cam fake;
    bool mocked;
    struct fake_cam fake2;          /* the USB camera that is unplugged and replugged */
    UMockdevIoctlBase *handler2;
};

static int setup(void **state)
{
    static struct env e;
    memset(&e, 0, sizeof e);
    *state = &e;
    const char *pre = getenv("LD_PRELOAD");
    e.mocked = pre && strstr(pre, "umockdev");
    if (!e.mocked)
        return 0;
    g_mutex_init(&e.fake.lock);
    e.tb = umockdev_testbed_new();
    GError *err = NULL;
    if (!umockdev_testbed_add_from_string(e.tb,
                                          "P: /devices/virtual/video4linux/video0\n"
                                          "N: video0\n"
                                          "E: DEVNAME=/dev/video0\n"
                                          "E: SUBSYSTEM=video4linux\n"
                                          "A: name=F4D fake UVC\n",
                                          &err)) {
        fprintf(stderr, "umockdev: %s\n", err ? err->message : "?");
        return -1;
    }
    e.handler = umockdev_ioctl_base_new();
    g_signal_connect(e.handler, "handle-ioctl", G_CALLBACK(on_ioctl), &e.fake);
    if (!umockdev_testbed_attach_ioctl(e.tb, "/dev/video0", e.handler, &err)) {
        fprintf(stderr, "umockdev attach: %s\n", err ? err->message : "?");
        return -1;
    }
    return 0;
}

static int teardown(void **state)
{
    struct env *e = *state;
    if (e->handler2)
        g_object_unref(e->handler2);
    if (e->tb) {
        umockdev_testbed_detach_ioctl(e->tb, "/dev/video0", NULL);
        g_object_unref(e->handler);
        g_object_unref(e->tb);
    }
    return 0;
}

static void usb_board(struct hal_board *b, const char *dev)
{
    struct f4d_err err = {0};
    assert_int_equal(hal_board_load(b, F4D_BOARD_DIR "/usb-2cam.json", &err), 0);
    b->n_cams = 1;
    snprintf(b->cams[0].address, sizeof b->cams[0].address, "%s", dev);
}

static void open_failures(void **state)
{
    (void)state;
    struct hal_board b;
    struct hal_rig rig;
    struct f4d_err err = {0};
    usb_board(&b, "/dev/video77");
    assert_int_equal(hal_rig_open(&rig, &b, &err), F4D_ENODEV);
    assert_non_null(strstr(err.msg, "/dev/video77"));
    usb_board(&b, "/dev/null");
    assert_int_equal(hal_rig_open(&rig, &b, &err), F4D_ENODEV);
    assert_non_null(strstr(err.msg, "not a V4L2 device"));
    usb_board(&b, "");
    assert_int_equal(hal_rig_open(&rig, &b, &err), F4D_EINVAL);
    assert_non_null(strstr(err.msg, "no device node"));
}

struct sets {
    uint64_t sets, complete, checked;
};

static int count_set(void *user, const struct hal_set *set)
{
    struct sets *k = user;
    k->sets++;
    k->complete += set->complete;
    const struct hal_buffer *b = set->frames[0];
    if (b) {
        /* the fake writes the low byte of its sequence into every pixel */
        assert_int_equal(b->data[0], (uint8_t)(b->frame_id & 0xFF));
        assert_int_equal(b->data[b->bytes_used - 1], (uint8_t)(b->frame_id & 0xFF));
        assert_int_equal(b->trigger_seq, set->seq);
        assert_int_equal(b->format.pixfmt, HAL_PIXFMT_YUYV);
        k->checked++;
    }
    return 0;
}

static void negotiate_and_stream(void **state)
{
    struct env *e = *state;
    if (!e->mocked)
        f4d_skip("negotiate_and_stream: not run under umockdev-wrapper (LD_PRELOAD has no libumockdev-preload), "
                 "so there is no fake /dev/video0; ctest runs it as umockdev-wrapper test_usb");
    struct hal_board b;
    struct hal_rig rig;
    struct f4d_err err = {0};
    usb_board(&b, "/dev/video0");
    if (hal_rig_open(&rig, &b, &err) < 0)
        fail_msg("%s", err);
    struct hal_camera *cam = &rig.cams[0];
    /* the driver snaps 1000x700 RGB to 640x480 YUYV; a UVC camera runs free */
    struct hal_format f = {HAL_PIXFMT_RGB8, 1000, 700, 0, 30000, HAL_TRIGGER_HARDWARE, 1000, 0};
    assert_int_equal(hal_camera_validate(cam, &f), HAL_FORMAT_ADJUSTED);
    assert_int_equal(f.pixfmt, HAL_PIXFMT_YUYV);
    assert_int_equal(f.width, 640);
    assert_int_equal(f.height, 480);
    assert_int_equal(f.stride, 1280);
    assert_int_equal(f.trigger, HAL_TRIGGER_FREE_RUN);
    assert_int_equal(hal_camera_validate(cam, &f), HAL_FORMAT_VALID);
    assert_int_equal(hal_camera_start(cam), F4D_ESTATE);
    assert_int_equal(hal_camera_configure(cam, &f), F4D_OK);
    assert_int_equal(hal_camera_start(cam), F4D_ESTATE); /* no buffers yet */
    assert_non_null(strstr(hal_camera_last_error(cam), "no buffer"));
    hal_camera_stop(cam);
    hal_rig_close(&rig);

    /* the capture loop over the whole path: tick trigger, USERPTR DQBUF, synchronizer */
    if (hal_rig_open(&rig, &b, &err) < 0)
        fail_msg("%s", err);
    struct f4d_capture_config cfg = {.triggers = 30, .buffers_per_cam = 4};
    struct f4d_capture_stats st;
    struct sets k = {0, 0, 0};
    int rc = f4d_capture_run(&rig, &cfg, count_set, NULL, &k, NULL, &st, &err);
    if (rc < 0)
        fail_msg("capture: %s", err);
    hal_rig_close(&rig);
    printf("[ usb ] %llu ticks, %llu sets, %llu complete, frame ids checked %llu; %u ioctls answered\n",
           (unsigned long long)st.sync.triggers, (unsigned long long)k.sets,
           (unsigned long long)k.complete, (unsigned long long)k.checked, e->fake.ioctls);
    assert_int_equal(st.sync.triggers, 30);
    assert_true(k.complete >= 20);
    assert_true(k.sets <= 30); /* free-running frames outside the ticks belong to no set */
    assert_int_equal(st.dequeue_errors, 0);
}


/* ---- hotplug: a USB camera (sysfs: usb device -> interface -> video4linux
 * node, all in the umockdev testbed) unplugged and replugged mid-stream. The
 * events come from a fake source injected into the session (the libusb
 * monitor itself is tested in test_usb_hotplug.c). ---- */
struct script_src {
    struct hal_usb_event q[8];
    uint32_t head, count;
};

static int script_poll(void *ctx, struct hal_usb_event *out, uint32_t max, uint32_t timeout_us)
{
    (void)timeout_us;
    struct script_src *q = ctx;
    uint32_t n = 0;
    while (n < max && q->head < q->count)
        out[n++] = q->q[q->head++];
    return (int)n;
}
static const struct hal_usb_event_source_ops script_ops = {.poll = script_poll};

static void script_post(struct script_src *q, enum hal_usb_event_kind k, uint8_t devnum)
{
    struct hal_usb_event *e = &q->q[q->count++];
    memset(e, 0, sizeof *e);
    e->kind = k;
    e->dev.vid = 0x046d;
    e->dev.pid = 0x0825;
    e->dev.bus = 1;
    e->dev.devnum = devnum;
    snprintf(e->dev.port_path, sizeof e->dev.port_path, "3");
    if (k == HAL_USB_ARRIVED)
        snprintf(e->dev.serial, sizeof e->dev.serial, "A1");
}

struct usbdev {
    gchar *usb, *intf, *v4l;
    char node[32];
};

/* Plugs 046d:0825 serial A1 into bus 1 port 3 as device `devnum`, with its
 * capture node videoN (and a metadata node video<N+1>, index 1). */
static void plug(struct env *e, struct usbdev *d, const char *devnum, unsigned video)
{
    char name[16], devname[32], meta[16], metadev[32];
    snprintf(name, sizeof name, "video%u", video);
    snprintf(devname, sizeof devname, "/dev/video%u", video);
    snprintf(meta, sizeof meta, "video%u", video + 1);
    snprintf(metadev, sizeof metadev, "/dev/video%u", video + 1);
    d->usb = umockdev_testbed_add_device(e->tb, "usb", "1-3", NULL, "busnum", "1", "devnum", devnum, "devpath", "3",
                                         "idVendor", "046d", "idProduct", "0825", "serial", "A1", NULL, "DEVTYPE",
                                         "usb_device", NULL);
    assert_non_null(d->usb);
    d->intf = umockdev_testbed_add_device(e->tb, "usb", "1-3:1.0", d->usb, "bInterfaceClass", "0e", NULL, "DEVTYPE",
                                          "usb_interface", NULL);
    assert_non_null(d->intf);
    /* the nodes through the record format: N: makes the /dev node, and L: the
     * "device" link to the parent (the USB interface) that the kernel gives every
     * class device (umockdev_testbed_add_device makes neither) */
    for (int k = 1; k >= 0; k--) {
        char rec[512];
        snprintf(rec, sizeof rec,
                 "P: /devices/1-3/1-3:1.0/%s\nN: %s\nL: device=..\nE: DEVNAME=%s\nE: SUBSYSTEM=video4linux\n"
                 "A: index=%d\nA: name=F4D fake UVC (USB)\n",
                 k ? meta : name, k ? meta : name, k ? metadev : devname, k);
        GError *gerr = NULL;
        if (!umockdev_testbed_add_from_string(e->tb, rec, &gerr))
            fail_msg("umockdev: %s", gerr ? gerr->message : "?");
    }
    d->v4l = g_strdup_printf("/sys/devices/1-3/1-3:1.0/%s", name);
    snprintf(d->node, sizeof d->node, "%s", devname);
    GError *err = NULL;
    if (!umockdev_testbed_attach_ioctl(e->tb, d->node, e->handler2, &err))
        fail_msg("umockdev attach %s: %s", d->node, err ? err->message : "?");
    g_mutex_lock(&e->fake2.lock);
    e->fake2.unplugged = false;
    e->fake2.streaming = false;
    e->fake2.n_req = 0;
    e->fake2.sequence = 0; /* a fresh device counts from 0 */
    g_mutex_unlock(&e->fake2.lock);
}

static void unplug(struct env *e, struct usbdev *d)
{
    umockdev_testbed_detach_ioctl(e->tb, d->node, NULL);
    umockdev_testbed_remove_device(e->tb, d->usb); /* the interface and nodes with it */
    /* umockdev 0.17 leaves the children's bus/class links behind: a replug on
     * the same port would collide with them (and it keeps its /dev nodes
     * registered: each plug below uses new node numbers) */
    const char *root = umockdev_testbed_get_root_dir(e->tb);
    static const char *const links[] = {"/sys/bus/usb/devices/1-3", "/sys/bus/usb/devices/1-3:1.0"};
    for (size_t i = 0; i < sizeof links / sizeof links[0]; i++) {
        char *p = g_strconcat(root, links[i], NULL);
        unlink(p);
        g_free(p);
    }
    for (unsigned v = 0; v < 16; v++) { /* dangling class links of the removed nodes */
        char *p = g_strdup_printf("%s/sys/class/video4linux/video%u", root, v);
        char *dev = g_strdup_printf("%s/sys/class/video4linux/video%u/name", root, v);
        if (g_file_test(p, G_FILE_TEST_IS_SYMLINK) && !g_file_test(dev, G_FILE_TEST_EXISTS))
            unlink(p);
        g_free(dev);
        g_free(p);
    }
    g_free(d->usb);
    g_free(d->intf);
    g_free(d->v4l);
    memset(d, 0, sizeof *d);
}

/* Dequeues until a frame; every ABORTED buffer is counted and queued again
 * (as the capture loop does); returns the frame or NULL (rc in *rc). */
static struct hal_buffer *next_frame(struct hal_camera *cam, uint32_t timeout_us, int *rc, uint32_t *aborted)
{
    for (;;) {
        struct hal_buffer *b = NULL;
        *rc = hal_camera_dequeue(cam, &b, timeout_us);
        if (*rc < 0)
            return NULL;
        if (b->status != HAL_FRAME_ABORTED)
            return b;
        (*aborted)++;
        assert_int_equal(hal_camera_enqueue(cam, b), F4D_OK);
    }
}

static void unplug_replug_stream(void **state)
{
    struct env *e = *state;
    if (!e->mocked)
        f4d_skip("unplug_replug_stream: not run under umockdev-wrapper: no fake USB camera");
    g_mutex_init(&e->fake2.lock);
    e->handler2 = umockdev_ioctl_base_new();
    g_signal_connect(e->handler2, "handle-ioctl", G_CALLBACK(on_ioctl), &e->fake2);
    struct usbdev d;
    plug(e, &d, "4", 4);

    /* the board names the USB device, not the node: sysfs maps it to /dev/video4 */
    struct hal_board b;
    struct hal_rig rig;
    struct f4d_err err = {0};
    usb_board(&b, "usb:046d:0825");
    snprintf(b.cams[0].serial, sizeof b.cams[0].serial, "B9");
    assert_int_equal(hal_rig_open(&rig, &b, &err), F4D_ENODEV); /* wrong serial */
    assert_non_null(strstr(err.msg, "046d:0825 serial B9"));
    snprintf(b.cams[0].serial, sizeof b.cams[0].serial, "A1");
    if (hal_rig_open(&rig, &b, &err) < 0)
        fail_msg("%s", err);
    struct script_src q;
    memset(&q, 0, sizeof q);
    struct hal_usb_event_source src = {&script_ops, &q};
    assert_int_equal(hal_usb_session_set_events(hal_rig_session(&rig, "usb"), src), F4D_OK);
    struct hal_camera *cam = &rig.cams[0];
    const struct hal_usb_link *link = hal_usb_camera_link(cam);
    assert_non_null(link);
    assert_int_equal(link->have.devnum, 4);
    assert_string_equal(link->have.serial, "A1");
    assert_string_equal(link->have.port_path, "3");

    struct hal_format f = {HAL_PIXFMT_YUYV, 640, 480, 0, 100000, HAL_TRIGGER_FREE_RUN, 1000, 0};
    hal_camera_validate(cam, &f); /* fills stride and image_bytes */
    assert_int_equal(hal_camera_validate(cam, &f), HAL_FORMAT_VALID);
    assert_int_equal(hal_camera_configure(cam, &f), F4D_OK);
    static uint8_t mem[4][640 * 480 * 2];
    struct hal_buffer bufs[4];
    memset(bufs, 0, sizeof bufs);
    for (int i = 0; i < 4; i++) {
        bufs[i].data = mem[i];
        bufs[i].capacity = sizeof mem[i];
        assert_int_equal(hal_camera_enqueue(cam, &bufs[i]), F4D_OK);
    }
    /* the usb host-tick trigger gives free-running frames their sequence */
    struct hal_pulse_train train = {100000, 1000, 0};
    assert_int_equal(hal_trigger_arm(&rig.trigger, &train), F4D_OK);
    assert_int_equal(hal_camera_start(cam), F4D_OK);
    int rc;
    uint32_t aborted = 0;
    for (int i = 0; i < 3; i++) {
        struct hal_buffer *fr = next_frame(cam, 500000, &rc, &aborted);
        if (!fr)
            fail_msg("frame %d: %d %s", i, rc, hal_camera_last_error(cam));
        assert_int_equal(fr->status, HAL_FRAME_OK);
        assert_int_equal(fr->data[0], (uint8_t)fr->frame_id);
        assert_int_equal(hal_camera_enqueue(cam, fr), F4D_OK);
    }

    /* 1: unplugged, libusb reports it: the 4 queued buffers come back ABORTED, then ENODEV */
    g_mutex_lock(&e->fake2.lock);
    e->fake2.unplugged = true;
    g_mutex_unlock(&e->fake2.lock);
    script_post(&q, HAL_USB_LEFT, 4);
    assert_null(next_frame(cam, 0, &rc, &aborted));
    assert_int_equal(rc, F4D_ENODEV);
    assert_int_equal(aborted, 4);
    assert_non_null(strstr(hal_camera_last_error(cam), "waiting for it to come back"));
    assert_int_equal(link->state, HAL_USB_LINK_WAITING);
    unplug(e, &d);
    assert_null(next_frame(cam, 20000, &rc, &aborted)); /* waits, still gone */
    assert_int_equal(rc, F4D_ENODEV);

    /* replugged: new device number, new node; reopened, format and buffers back */
    plug(e, &d, "5", 6);
    script_post(&q, HAL_USB_ARRIVED, 5);
    struct hal_buffer *fr = next_frame(cam, 500000, &rc, &aborted);
    if (!fr)
        fail_msg("after replug: %d %s", rc, hal_camera_last_error(cam));
    assert_int_equal(fr->status, HAL_FRAME_OK);
    assert_true(fr->flags & HAL_FRAME_FLAG_CLOCK_RESET);
    assert_int_equal(fr->format.width, 640);
    assert_true(fr->frame_id < 3); /* the fresh device counts from 0 again */
    assert_int_equal(fr->data[0], (uint8_t)fr->frame_id);
    assert_int_equal(link->reconnects, 1);
    assert_int_equal(link->have.devnum, 5);
    assert_int_equal(e->fake2.width, 640); /* S_FMT applied again */
    assert_int_equal(hal_camera_enqueue(cam, fr), F4D_OK);
    for (int i = 0; i < 3; i++) {
        fr = next_frame(cam, 500000, &rc, &aborted);
        assert_non_null(fr);
        assert_int_equal(fr->flags, 0);
        assert_int_equal(hal_camera_enqueue(cam, fr), F4D_OK);
    }

    /* 2: the node fails ENODEV before any event: the same path, started by DQBUF */
    aborted = 0;
    g_mutex_lock(&e->fake2.lock);
    e->fake2.unplugged = true;
    g_mutex_unlock(&e->fake2.lock);
    assert_null(next_frame(cam, 0, &rc, &aborted));
    assert_int_equal(rc, F4D_ENODEV);
    assert_int_equal(aborted, 4);
    assert_int_equal(link->losses, 2);
    script_post(&q, HAL_USB_LEFT, 5); /* the late event changes nothing */
    unplug(e, &d);
    plug(e, &d, "6", 8);
    script_post(&q, HAL_USB_ARRIVED, 6);
    fr = next_frame(cam, 500000, &rc, &aborted);
    if (!fr)
        fail_msg("after second replug: %d %s", rc, hal_camera_last_error(cam));
    assert_int_equal(link->reconnects, 2);
    assert_int_equal(link->losses, 2);
    assert_int_equal(hal_camera_enqueue(cam, fr), F4D_OK);
    printf("[ usb ] hotplug: %u reconnects, %u losses, now on %s\n", link->reconnects, link->losses, d.node);
    hal_trigger_disarm(&rig.trigger);
    hal_camera_stop(cam);
    hal_rig_close(&rig);
    unplug(e, &d);
}

int main(int argc, char **argv)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(open_failures),
        cmocka_unit_test(negotiate_and_stream),
        cmocka_unit_test(unplug_replug_stream),
    };
    return F4D_TEST_MAIN(argc, argv, "hal/usb", tests, setup, teardown);
}
