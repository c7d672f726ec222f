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

#include "f4d_capture.h"
#include "f4d_test.h"
#include "hal_board.h"
#include "hal_registry.h"

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
    switch (req) {
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
        vb->timestamp.tv_sec = (time_t)(now / 1000000000u);
        vb->timestamp.tv_usec = (suseconds_t)(now % 1000000000u / 1000u);
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
    if (e->tb) {
        umockdev_testbed_detach_ioctl(e->tb, "/dev/video0", NULL);
        g_object_unref(e->handler);
        g_object_unref(e->tb);
    }
    return 0;
}

static void usb_board(struct hal_board *b, const char *dev)
{
    char err[256];
    assert_int_equal(hal_board_load(b, F4D_BOARD_DIR "/usb-2cam.json", err, sizeof err), 0);
    b->n_cams = 1;
    snprintf(b->cams[0].address, sizeof b->cams[0].address, "%s", dev);
}

static void open_failures(void **state)
{
    (void)state;
    struct hal_board b;
    struct hal_rig rig;
    char err[256];
    usb_board(&b, "/dev/video77");
    assert_int_equal(hal_rig_open(&rig, &b, err, sizeof err), F4D_ENODEV);
    assert_non_null(strstr(err, "/dev/video77"));
    usb_board(&b, "/dev/null");
    assert_int_equal(hal_rig_open(&rig, &b, err, sizeof err), F4D_ENODEV);
    assert_non_null(strstr(err, "not a V4L2 device"));
    usb_board(&b, "");
    assert_int_equal(hal_rig_open(&rig, &b, err, sizeof err), F4D_EINVAL);
    assert_non_null(strstr(err, "no device node"));
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
    char err[256];
    usb_board(&b, "/dev/video0");
    if (hal_rig_open(&rig, &b, err, sizeof err) < 0)
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
    if (hal_rig_open(&rig, &b, err, sizeof err) < 0)
        fail_msg("%s", err);
    struct f4d_capture_config cfg = {.triggers = 30, .buffers_per_cam = 4};
    struct f4d_capture_stats st;
    struct sets k = {0, 0, 0};
    int rc = f4d_capture_run(&rig, &cfg, count_set, NULL, &k, NULL, &st, err, sizeof err);
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

int main(int argc, char **argv)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(open_failures),
        cmocka_unit_test(negotiate_and_stream),
    };
    return F4D_TEST_MAIN(argc, argv, "hal/usb", tests, setup, teardown);
}
