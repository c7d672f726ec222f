/* hal_usb.c: UVC cameras over V4L2 with USERPTR streaming, and the host tick
 * trigger (see hal_usb.h). */
#include "hal_usb.h"

#include "hal_backend.h"
#include "hal_usb_hotplug.h"

#include <errno.h>
#include <fcntl.h>
#include <linux/videodev2.h>
#include <poll.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/ioctl.h>
#include <unistd.h>

#define USB_BUFFERS_MAX HAL_USB_BUFFERS_MAX /* the board parser bounds pending_max by it */

struct usb_session;

struct usb_cam {
    struct usb_session *s;
    uint32_t index;
    const struct hal_camera_config *cfg;
    int fd;
    struct hal_cam_state st; /* format, configure/start state, aborted buffers, error */
    /* V4L2 fixes the buffer set at start and re-queues by index, so the
     * caller's buffers live in a slot table here, not in a struct hal_bufq */
    struct hal_buffer *slots[USB_BUFFERS_MAX]; /* V4L2 index -> caller buffer */
    bool queued[USB_BUFFERS_MAX];
    uint32_t n_slots;
    uint64_t seq_hi, last_seq32; /* unwrapping the 32-bit V4L2 sequence */
    bool have_seq;
    /* hotplug: the USB device behind the node, and the reconnect state */
    bool hotplug;                /* the node has a USB parent in sysfs */
    bool gone;                   /* the device left: fd closed, waiting for it */
    bool clock_reset;            /* flag the first frame after a reopen */
    char node[HAL_PATH_MAX];     /* the node in use now */
    struct hal_usb_link link;
};

struct usb_session {
    const struct hal_board *board;
    bool trig_open, armed;
    uint64_t period_ns, first_tick_ns, next_tick_ns, sent, limit, seq;
    struct hal_edgeq edges; /* full: later ticks are not reported */
    struct hal_usb_hotplug *hp; /* libusb monitor, NULL when unavailable */
    struct hal_usb_hub hub;     /* pumps hp (or a test's source) into the cameras */
    struct f4d_err hp_err;       /* why there is no monitor */
};

static int xioctl(int fd, unsigned long req, void *arg)
{
    int r;
    do
        r = ioctl(fd, req, arg);
    while (r < 0 && errno == EINTR);
    return r;
}

/* hal_cam_fail with the reason errno gives, if any. */
static int cam_fail(struct usb_cam *c, int rc, const char *what)
{
    int e = errno;
    return hal_cam_fail(&c->st, rc, "%.80s%s%.60s", what, e ? ": " : "", e ? strerror(e) : "");
}

static const struct {
    enum hal_pixfmt hal;
    uint32_t fourcc;
} pixfmts[] = {
    {HAL_PIXFMT_YUYV, V4L2_PIX_FMT_YUYV},    {HAL_PIXFMT_MONO8, V4L2_PIX_FMT_GREY},
    {HAL_PIXFMT_RGB8, V4L2_PIX_FMT_RGB24},   {HAL_PIXFMT_MONO16, V4L2_PIX_FMT_Y16},
    {HAL_PIXFMT_BAYER_RG8, V4L2_PIX_FMT_SRGGB8},
};

static uint32_t to_fourcc(enum hal_pixfmt f)
{
    for (size_t i = 0; i < sizeof pixfmts / sizeof pixfmts[0]; i++)
        if (pixfmts[i].hal == f)
            return pixfmts[i].fourcc;
    return V4L2_PIX_FMT_YUYV;
}

static enum hal_pixfmt from_fourcc(uint32_t f)
{
    for (size_t i = 0; i < sizeof pixfmts / sizeof pixfmts[0]; i++)
        if (pixfmts[i].fourcc == f)
            return pixfmts[i].hal;
    return HAL_PIXFMT_INVALID;
}

/* The V4L2 request for f (TRY_FMT and S_FMT ask the same). */
static struct v4l2_format capture_format(const struct hal_format *f)
{
    struct v4l2_format vf;
    memset(&vf, 0, sizeof vf);
    vf.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
    vf.fmt.pix.width = f->width;
    vf.fmt.pix.height = f->height;
    vf.fmt.pix.pixelformat = to_fourcc(f->pixfmt);
    vf.fmt.pix.field = V4L2_FIELD_NONE;
    return vf;
}

/* ---- hotplug: the reconnect logic's view of a camera ---- */
static int stream_on(struct usb_cam *c);

static void dev_drop(void *cam)
{
    struct usb_cam *c = cam;
    if (c->fd >= 0)
        close(c->fd); /* the driver's buffers die with the device */
    c->fd = -1;
    c->gone = true;
    for (uint32_t i = 0; i < c->n_slots; i++) {
        if (c->queued[i])
            hal_cam_abort(&c->st, c->slots[i]);
        c->queued[i] = false;
    }
    char id[160];
    hal_usb_id_format(&c->link.have, id, sizeof id);
    errno = 0;
    hal_cam_fail(&c->st, F4D_ENODEV, "device %s left (waiting for it to come back)", id);
}

static int dev_find_node(void *cam, const struct hal_usb_id *dev, char *node, size_t cap)
{
    (void)cam;
    return hal_usb_sysfs_find_node(dev, node, cap, NULL);
}

static int dev_reopen(void *cam, const char *node)
{
    struct usb_cam *c = cam;
    errno = 0;
    int fd = open(node, O_RDWR | O_NONBLOCK | O_CLOEXEC);
    if (fd < 0)
        return cam_fail(c, F4D_ENODEV, "reopen");
    c->fd = fd;
    snprintf(c->node, sizeof c->node, "%s", node);
    int rc = F4D_OK;
    if (c->st.configured) {
        struct v4l2_format vf = capture_format(&c->st.fmt);
        if (xioctl(fd, VIDIOC_S_FMT, &vf) < 0 || vf.fmt.pix.width != c->st.fmt.width ||
            vf.fmt.pix.height != c->st.fmt.height || from_fourcc(vf.fmt.pix.pixelformat) != c->st.fmt.pixfmt)
            rc = cam_fail(c, F4D_EIO, "reopen: VIDIOC_S_FMT (format not taken again)");
        if (rc == F4D_OK && c->st.fmt.rate_mhz) {
            struct v4l2_streamparm sp;
            memset(&sp, 0, sizeof sp);
            sp.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
            sp.parm.capture.timeperframe.numerator = 1000;
            sp.parm.capture.timeperframe.denominator = c->st.fmt.rate_mhz;
            xioctl(fd, VIDIOC_S_PARM, &sp); /* best effort, as at configure */
        }
    }
    if (rc == F4D_OK && c->st.started && c->n_slots)
        rc = stream_on(c);
    if (rc < 0) {
        close(fd);
        c->fd = -1;
        return rc; /* queued[] still marks our buffers: QBUF on the next try */
    }
    c->gone = false;
    c->clock_reset = true;
    return F4D_OK;
}

static const struct hal_usb_dev_ops usb_dev_ops = {
    .find_node = dev_find_node,
    .reopen = dev_reopen,
    .drop = dev_drop,
};

/* Pumps hotplug events; while the device is gone, hands back its aborted
 * buffers, then waits for it until `deadline`. Returns 1 when the device is
 * there (go on with DQBUF), else what dequeue returns. */
static int wait_device(struct usb_cam *c, uint64_t deadline, struct hal_buffer **out)
{
    hal_usb_hub_pump(&c->s->hub, 0);
    for (;;) {
        if (c->st.n_aborted)
            return hal_cam_dequeue_begin(&c->st, out);
        if (!c->gone)
            return 1;
        if (!c->s->hub.src.ops) /* no hotplug events: nothing will bring it back */
            return hal_cam_fail(&c->st, F4D_ENODEV, "device gone (no hotplug: %.100s)", c->s->hp_err.msg);
        uint64_t now = hal_mono_ns();
        if (now >= deadline)
            return hal_cam_fail(&c->st, F4D_ENODEV, "device gone (waiting for it to come back)");
        uint64_t left_us = (deadline - now) / 1000u;
        hal_usb_hub_pump(&c->s->hub, left_us > 100000u ? 100000u : (uint32_t)left_us);
    }
}

/* ---- camera ---- */
static int cam_validate(void *ctx, struct hal_format *f)
{
    struct usb_cam *c = ctx;
    struct hal_format in = *f;
    struct v4l2_format vf = capture_format(f);
    errno = 0;
    if (xioctl(c->fd, VIDIOC_TRY_FMT, &vf) < 0)
        return cam_fail(c, F4D_EIO, "VIDIOC_TRY_FMT");
    enum hal_pixfmt p = from_fourcc(vf.fmt.pix.pixelformat);
    errno = 0;
    if (p == HAL_PIXFMT_INVALID)
        return cam_fail(c, F4D_ENOTSUP, "the driver offers no pixel format this HAL knows");
    f->pixfmt = p;
    f->width = vf.fmt.pix.width;
    f->height = vf.fmt.pix.height;
    f->stride = vf.fmt.pix.bytesperline;
    f->trigger = HAL_TRIGGER_FREE_RUN; /* UVC has no trigger input */
    if (hal_format_finish(f) < 0)
        return cam_fail(c, F4D_EINVAL, "the driver returned an unusable format");
    if (vf.fmt.pix.sizeimage > f->image_bytes)
        f->image_bytes = vf.fmt.pix.sizeimage;
    return memcmp(&in, f, sizeof in) == 0 ? HAL_FORMAT_VALID : HAL_FORMAT_ADJUSTED;
}

static int cam_configure(void *ctx, const struct hal_format *f)
{
    struct usb_cam *c = ctx;
    errno = 0;
    int rc = hal_cam_check_configure(&c->st);
    if (rc < 0)
        return rc;
    struct hal_format v = *f;
    if ((rc = hal_cam_check_validated(&c->st, cam_validate(c, &v))) < 0)
        return rc;
    struct v4l2_format vf = capture_format(f);
    if (xioctl(c->fd, VIDIOC_S_FMT, &vf) < 0)
        return cam_fail(c, F4D_EIO, "VIDIOC_S_FMT");
    if (f->rate_mhz) {
        struct v4l2_streamparm sp;
        memset(&sp, 0, sizeof sp);
        sp.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
        sp.parm.capture.timeperframe.numerator = 1000;
        sp.parm.capture.timeperframe.denominator = f->rate_mhz;
        if (xioctl(c->fd, VIDIOC_S_PARM, &sp) < 0 && errno != ENOTTY && errno != EINVAL)
            return cam_fail(c, F4D_EIO, "VIDIOC_S_PARM (frame interval)");
    }
    c->st.fmt = v;
    c->st.configured = true;
    return F4D_OK;
}

static int qbuf(struct usb_cam *c, uint32_t i)
{
    struct v4l2_buffer vb;
    memset(&vb, 0, sizeof vb);
    vb.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
    vb.memory = V4L2_MEMORY_USERPTR;
    vb.index = i;
    vb.m.userptr = (unsigned long)c->slots[i]->data;
    vb.length = (uint32_t)c->slots[i]->capacity;
    errno = 0;
    if (xioctl(c->fd, VIDIOC_QBUF, &vb) < 0)
        return cam_fail(c, F4D_EIO, "VIDIOC_QBUF");
    c->queued[i] = true;
    return F4D_OK;
}

/* REQBUFS for every slot, QBUF the queued ones, STREAMON (start and reopen). */
static int stream_on(struct usb_cam *c)
{
    int rc;
    struct v4l2_requestbuffers rb;
    memset(&rb, 0, sizeof rb);
    rb.count = c->n_slots;
    rb.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
    rb.memory = V4L2_MEMORY_USERPTR;
    if (xioctl(c->fd, VIDIOC_REQBUFS, &rb) < 0)
        return cam_fail(c, F4D_ENOTSUP, "VIDIOC_REQBUFS (USERPTR streaming)");
    if (rb.count < c->n_slots) {
        errno = 0;
        return cam_fail(c, F4D_ENOMEM, "the driver accepted fewer buffers than queued");
    }
    for (uint32_t i = 0; i < c->n_slots; i++) {
        if (!c->queued[i])
            continue;
        rc = qbuf(c, i);
        if (rc < 0)
            return rc;
    }
    int type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
    if (xioctl(c->fd, VIDIOC_STREAMON, &type) < 0)
        return cam_fail(c, F4D_EIO, "VIDIOC_STREAMON");
    c->have_seq = false;
    return F4D_OK;
}

static int cam_start(void *ctx)
{
    struct usb_cam *c = ctx;
    errno = 0;
    int rc = hal_cam_check_start(&c->st);
    if (rc < 0)
        return rc;
    if (c->st.started)
        return F4D_OK;
    if (c->n_slots == 0)
        return cam_fail(c, F4D_ESTATE, "start with no buffer queued");
    if (c->gone)
        return hal_cam_fail(&c->st, F4D_ENODEV, "device gone (waiting for it to come back)");
    if ((rc = stream_on(c)) < 0)
        return rc;
    c->st.started = true;
    return F4D_OK;
}

static int cam_stop(void *ctx)
{
    struct usb_cam *c = ctx;
    if (c->st.started && !c->gone) {
        int type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
        xioctl(c->fd, VIDIOC_STREAMOFF, &type); /* also dequeues everything in the driver */
        struct v4l2_requestbuffers rb;
        memset(&rb, 0, sizeof rb);
        rb.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
        rb.memory = V4L2_MEMORY_USERPTR;
        xioctl(c->fd, VIDIOC_REQBUFS, &rb);
    }
    c->st.started = false;
    /* only buffers the camera holds: those the caller holds stay the caller's */
    for (uint32_t i = 0; i < c->n_slots; i++) {
        if (c->queued[i])
            hal_cam_abort(&c->st, c->slots[i]);
        c->queued[i] = false;
    }
    c->n_slots = 0; /* the next start requests buffers again */
    return F4D_OK;
}

static int cam_enqueue(void *ctx, struct hal_buffer *b)
{
    struct usb_cam *c = ctx;
    errno = 0;
    int rc = hal_cam_check_enqueue(&c->st, b);
    if (rc < 0)
        return rc;
    for (uint32_t i = 0; i < c->n_slots; i++) {
        if (c->slots[i] != b)
            continue;
        if (c->queued[i])
            return cam_fail(c, F4D_EBUSY, "buffer is already queued");
        /* device gone: kept queued, QBUF again when it comes back */
        return c->st.started && !c->gone ? qbuf(c, i) : (c->queued[i] = true, F4D_OK);
    }
    if (c->st.started)
        return cam_fail(c, F4D_ESTATE, "a new buffer while streaming (V4L2 fixes the set at start)");
    if (c->n_slots == USB_BUFFERS_MAX)
        return cam_fail(c, F4D_EBUSY, "too many buffers");
    c->slots[c->n_slots] = b;
    c->queued[c->n_slots++] = true;
    return F4D_OK;
}

/* Sequence of the host tick nearest to t, 0 if before the first tick. */
static uint64_t tick_seq(const struct usb_session *s, uint64_t t)
{
    if (!s->first_tick_ns || !s->period_ns || t + s->period_ns / 2 < s->first_tick_ns)
        return 0;
    return (t + s->period_ns / 2 - s->first_tick_ns) / s->period_ns + 1;
}

static int cam_dequeue(void *ctx, struct hal_buffer **out, uint32_t timeout_us)
{
    struct usb_cam *c = ctx;
    errno = 0;
    int rc = hal_cam_dequeue_begin(&c->st, out);
    if (rc < 0 || *out)
        return rc;
    uint64_t deadline = hal_mono_ns() + (uint64_t)timeout_us * 1000u;
    if (c->hotplug && (rc = wait_device(c, deadline, out)) != 1)
        return rc;
    for (;;) {
        struct v4l2_buffer vb;
        memset(&vb, 0, sizeof vb);
        vb.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
        vb.memory = V4L2_MEMORY_USERPTR;
        if (xioctl(c->fd, VIDIOC_DQBUF, &vb) == 0) {
            if (vb.index >= c->n_slots)
                return cam_fail(c, F4D_EIO, "VIDIOC_DQBUF returned an unknown index");
            struct hal_buffer *b = c->slots[vb.index];
            c->queued[vb.index] = false;
            uint64_t ts = (uint64_t)vb.timestamp.tv_sec * 1000000000u + (uint64_t)vb.timestamp.tv_usec * 1000u;
            bool mono = (vb.flags & V4L2_BUF_FLAG_TIMESTAMP_MASK) == V4L2_BUF_FLAG_TIMESTAMP_MONOTONIC;
            uint64_t seq = tick_seq(c->s, mono ? ts : hal_mono_ns());
            const struct usb_session *s = c->s;
            if (seq == 0 || (s->limit && seq > s->limit) || (!s->armed && seq > s->sent)) {
                /* before the first tick or after the last: belongs to no trigger */
                rc = qbuf(c, vb.index);
                if (rc < 0)
                    return rc;
                continue;
            }
            if (!c->have_seq) {
                c->have_seq = true;
                c->seq_hi = 0;
            } else if (vb.sequence < c->last_seq32) {
                c->seq_hi += 1ull << 32;
            }
            c->last_seq32 = vb.sequence;
            b->status = (vb.flags & V4L2_BUF_FLAG_ERROR) ? HAL_FRAME_MISSING_PACKETS : HAL_FRAME_OK;
            b->bytes_used = vb.bytesused <= b->capacity ? vb.bytesused : b->capacity;
            if (b->status == HAL_FRAME_OK && b->bytes_used < c->st.fmt.stride * (size_t)c->st.fmt.height)
                b->status = HAL_FRAME_MISSING_PACKETS;
            b->flags = c->clock_reset ? HAL_FRAME_FLAG_CLOCK_RESET : 0;
            c->clock_reset = false;
            b->camera_index = c->index;
            b->format = c->st.fmt;
            b->device_ts_ns = ts;
            b->host_ts_ns = mono ? ts : hal_mono_ns();
            b->frame_id = c->seq_hi + vb.sequence;
            b->trigger_seq = seq;
            *out = b;
            return F4D_OK;
        }
        if (errno == ENODEV && c->hotplug) {
            /* unplugged: the buffers come back ABORTED, then F4D_ENODEV until it is back */
            hal_usb_link_lost(&c->link);
            if ((rc = wait_device(c, deadline, out)) != 1)
                return rc;
            continue;
        }
        if (errno != EAGAIN)
            return cam_fail(c, errno == ENODEV ? F4D_ENODEV : F4D_EIO, "VIDIOC_DQBUF");
        uint64_t now = hal_mono_ns();
        if (now >= deadline)
            return F4D_ETIMEDOUT;
        struct pollfd p = {c->fd, POLLIN, 0};
        int ms = (int)((deadline - now + 999999u) / 1000000u);
        if (poll(&p, 1, ms) < 0 && errno != EINTR)
            return cam_fail(c, F4D_EIO, "poll");
        errno = 0;
    }
}

static void cam_close(void *ctx)
{
    struct usb_cam *c = ctx;
    cam_stop(c);
    if (c->hotplug)
        hal_usb_hub_remove(&c->s->hub, &c->link);
    if (c->fd >= 0)
        close(c->fd);
    free(c);
}

static const char *cam_last_error(void *ctx) { return ((struct usb_cam *)ctx)->st.err.msg; }

static const struct hal_camera_ops usb_camera_ops = {
    .api_version = HAL_API_VERSION,
    .validate = cam_validate,
    .configure = cam_configure,
    .start = cam_start,
    .stop = cam_stop,
    .enqueue = cam_enqueue,
    .dequeue = cam_dequeue,
    .close = cam_close,
    .last_error = cam_last_error,
};

/* ---- host tick trigger ---- */
static void fire_due(struct usb_session *s, uint64_t now)
{
    while (s->armed && now >= s->next_tick_ns && (s->limit == 0 || s->sent < s->limit)) {
        struct hal_edge e = {tick_seq(s, s->next_tick_ns), s->next_tick_ns, 0, true};
        hal_edgeq_push(&s->edges, &e);
        s->sent++;
        s->next_tick_ns += s->period_ns;
    }
}

static int trig_arm(void *ctx, const struct hal_pulse_train *p)
{
    struct usb_session *s = ctx;
    if (p->rate_mhz == 0 || p->rate_mhz > 1000000u)
        return F4D_EINVAL;
    s->period_ns = 1000000000000ull / p->rate_mhz;
    s->first_tick_ns = s->next_tick_ns = hal_mono_ns() + s->period_ns;
    s->sent = 0;
    s->limit = p->count;
    s->armed = true;
    return F4D_OK;
}

static int trig_disarm(void *ctx)
{
    ((struct usb_session *)ctx)->armed = false;
    return F4D_OK;
}

static int trig_read_edges(void *ctx, struct hal_edge *e, uint32_t max, uint32_t timeout_us)
{
    struct usb_session *s = ctx;
    uint64_t now = hal_mono_ns(), deadline = now + (uint64_t)timeout_us * 1000u;
    fire_due(s, now);
    while (s->edges.count == 0 && s->armed && now < deadline) {
        hal_sleep_until_mono_ns(s->next_tick_ns < deadline ? s->next_tick_ns : deadline);
        now = hal_mono_ns();
        fire_due(s, now);
    }
    return (int)hal_edgeq_pop(&s->edges, e, max);
}

static bool trig_done(void *ctx)
{
    struct usb_session *s = ctx;
    return s->limit != 0 && s->sent >= s->limit;
}

static void trig_close(void *ctx) { ((struct usb_session *)ctx)->trig_open = false; }

static const struct hal_trigger_ops usb_trigger_ops = {
    .api_version = HAL_API_VERSION,
    .arm = trig_arm,
    .disarm = trig_disarm,
    .read_edges = trig_read_edges,
    .close = trig_close,
    .done = trig_done,
};

/* ---- backend ---- */
static int usb_session_open(const struct hal_board *board, void **session, struct f4d_err *err)
{
    struct usb_session *s = calloc(1, sizeof *s);
    if (!s)
        return f4d_fail(err, F4D_ENOMEM, "usb: out of memory");
    s->board = board;
    /* hotplug is best effort: without it a camera that leaves stays gone */
    if (hal_usb_hotplug_open(&s->hp, &s->hp_err) == F4D_OK)
        s->hub.src = hal_usb_hotplug_source(s->hp);
    *session = s;
    return F4D_OK;
}

static void usb_session_close(void *session)
{
    struct usb_session *s = session;
    hal_usb_hotplug_close(s->hp);
    free(s);
}

int hal_usb_session_set_events(void *session, struct hal_usb_event_source src)
{
    struct usb_session *s = session;
    if (!s)
        return F4D_EINVAL;
    s->hub.src = src;
    return F4D_OK;
}

const char *hal_usb_session_hotplug_error(void *session)
{
    struct usb_session *s = session;
    return s && !s->hp ? s->hp_err.msg : "";
}

const struct hal_usb_link *hal_usb_camera_link(const struct hal_camera *cam)
{
    if (cam->ops.dequeue != cam_dequeue)
        return NULL;
    const struct usb_cam *c = cam->ctx;
    return c->hotplug ? &c->link : NULL;
}

static int usb_camera_open(void *session, const struct hal_camera_config *cfg, uint32_t index,
                           struct hal_camera *out, struct f4d_err *err)
{
    if (!cfg->address[0])
        return f4d_fail(err, F4D_EINVAL, "usb camera %s: no device node (address)", cfg->id);
    /* the address is a node (/dev/video0) or a USB device (usb:VID:PID[@BUS-PORTS] + serial) */
    struct usb_session *s = session;
    struct hal_usb_id want, have;
    char node[HAL_PATH_MAX];
    bool by_id = strncmp(cfg->address, "usb:", 4) == 0;
    if (by_id) {
        if (hal_usb_id_parse(cfg->address, &want) < 0)
            return f4d_fail(err, F4D_EINVAL, "usb camera %s: address \"%s\" is not usb:VVVV:PPPP[@BUS-PORTS]",
                            cfg->id, cfg->address);
        snprintf(want.serial, sizeof want.serial, "%s", cfg->serial);
        if (hal_usb_sysfs_find_node(&want, node, sizeof node, &have) < 0) {
            char id[160];
            hal_usb_id_format(&want, id, sizeof id);
            return f4d_fail(err, F4D_ENODEV, "usb camera %s: no V4L2 node for USB device %s", cfg->id, id);
        }
    } else {
        snprintf(node, sizeof node, "%s", cfg->address);
    }
    int fd = open(node, O_RDWR | O_NONBLOCK | O_CLOEXEC);
    if (fd < 0)
        return f4d_fail(err, errno == ENOENT ? F4D_ENODEV : F4D_EIO, "usb camera %s: cannot open %s: %s",
                        cfg->id, node, strerror(errno));
    struct v4l2_capability cap;
    memset(&cap, 0, sizeof cap);
    if (xioctl(fd, VIDIOC_QUERYCAP, &cap) < 0) {
        int e = errno;
        close(fd);
        return f4d_fail(err, F4D_ENODEV, "usb camera %s: %s is not a V4L2 device (VIDIOC_QUERYCAP: %s)",
                        cfg->id, cfg->address, strerror(e));
    }
    uint32_t caps = (cap.capabilities & V4L2_CAP_DEVICE_CAPS) ? cap.device_caps : cap.capabilities;
    if (!(caps & V4L2_CAP_VIDEO_CAPTURE) || !(caps & V4L2_CAP_STREAMING)) {
        close(fd);
        return f4d_fail(err, F4D_ENOTSUP, "usb camera %s: %s (%.32s) cannot stream video capture",
                        cfg->id, cfg->address, (const char *)cap.card);
    }
    struct usb_cam *c = calloc(1, sizeof *c);
    if (!c) {
        close(fd);
        return f4d_fail(err, F4D_ENOMEM, "usb: out of memory");
    }
    c->s = session;
    c->index = index;
    c->cfg = cfg;
    c->fd = fd;
    snprintf(c->node, sizeof c->node, "%s", node);
    /* hotplug needs to know which USB device this is: sysfs, when the node has a USB parent */
    if (by_id || hal_usb_sysfs_identify(node, &have) == F4D_OK) {
        if (!by_id) { /* this very device: by serial, else by the port it sits on */
            memset(&want, 0, sizeof want);
            want.vid = have.vid;
            want.pid = have.pid;
            snprintf(want.serial, sizeof want.serial, "%s", cfg->serial[0] ? cfg->serial : have.serial);
            if (!want.serial[0]) {
                want.bus = have.bus;
                snprintf(want.port_path, sizeof want.port_path, "%s", have.port_path);
            }
        }
        hal_usb_link_init(&c->link, &want, &have, &usb_dev_ops, c);
        c->hotplug = hal_usb_hub_add(&s->hub, &c->link);
    }
    hal_cam_name(&c->st, "usb camera %.40s (%.80s)", cfg->id, cfg->address);
    hal_camera_bind(out, &usb_camera_ops, c, index);
    return F4D_OK;
}

static int usb_trigger_open(void *session, const struct hal_trigger_config *cfg,
                            struct hal_trigger *out, struct f4d_err *err)
{
    (void)cfg;
    struct usb_session *s = session;
    return hal_trigger_claim(&s->trig_open, out, &usb_trigger_ops, s, "usb tick trigger", err);
}

const struct hal_backend hal_usb_backend = {
    .api_version = HAL_API_VERSION,
    .name = "usb",
    .session_open = usb_session_open,
    .session_close = usb_session_close,
    .camera_open = usb_camera_open,
    .trigger_open = usb_trigger_open,
};
