/* hal_libcamera.c: the HAL camera over the libcamera shim (see hal_libcamera.h). */
#include "hal_libcamera.h"

#include "hal_backend.h"
#include "hal_libcamera_shim.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define LC_BUFFERS 4 /* FrameBuffers per camera (libcamera's own) */

struct lc_session {
    int unused;
};

struct lc_cam {
    uint32_t index;
    struct hlc_camera *hc;
    struct hal_cam_state st;
    struct hal_bufq q;         /* caller buffers waiting for a frame */
    uint32_t n_slots;          /* libcamera requests, all queued while started */
    uint64_t seq_hi;           /* unwrapping the 32-bit sequence */
    uint32_t last_seq32;
    bool have_seq;
    uint64_t dropped;          /* frames that found no caller buffer */
};

static const struct {
    enum hal_pixfmt hal;
    uint32_t fourcc;
} pixfmts[] = {
    {HAL_PIXFMT_YUYV, HLC_FOURCC('Y', 'U', 'Y', 'V')},
    {HAL_PIXFMT_MONO8, HLC_FOURCC('R', '8', ' ', ' ')},
    {HAL_PIXFMT_MONO16, HLC_FOURCC('R', '1', '6', ' ')},
    {HAL_PIXFMT_RGB8, HLC_FOURCC('B', 'G', '2', '4')}, /* DRM BGR888 = bytes R,G,B */
    {HAL_PIXFMT_BAYER_RG8, HLC_FOURCC('R', 'G', 'G', 'B')},
};

static uint32_t to_fourcc(enum hal_pixfmt f)
{
    for (size_t i = 0; i < sizeof pixfmts / sizeof pixfmts[0]; i++)
        if (pixfmts[i].hal == f)
            return pixfmts[i].fourcc;
    return 0;
}

static enum hal_pixfmt from_fourcc(uint32_t f)
{
    for (size_t i = 0; i < sizeof pixfmts / sizeof pixfmts[0]; i++)
        if (pixfmts[i].fourcc == f)
            return pixfmts[i].hal;
    return HAL_PIXFMT_INVALID;
}

/* ---- camera ---- */
static int cam_validate(void *ctx, struct hal_format *f)
{
    struct lc_cam *c = ctx;
    struct hal_format in = *f;
    uint32_t fourcc = to_fourcc(f->pixfmt);
    if (!fourcc)
        return hal_cam_fail(&c->st, F4D_EINVAL, "unknown pixel format %d", (int)f->pixfmt);
    struct hlc_format hf = {fourcc, f->width, f->height, 0, 0};
    struct f4d_err why = {0};
    int rc = hlc_camera_validate(c->hc, &hf, &why);
    if (rc < 0)
        return hal_cam_fail(&c->st, rc, "%s", why.msg);
    enum hal_pixfmt p = from_fourcc(hf.fourcc);
    if (p == HAL_PIXFMT_INVALID)
        return hal_cam_fail(&c->st, F4D_ENOTSUP, "the camera offers no pixel format this HAL knows");
    f->pixfmt = p;
    f->width = hf.width;
    f->height = hf.height;
    f->stride = hf.stride;
    f->trigger = HAL_TRIGGER_FREE_RUN; /* no trigger control in libcamera 0.0.3 */
    if (hal_format_finish(f) < 0)
        return hal_cam_fail(&c->st, F4D_EINVAL, "libcamera returned an unusable format");
    if (hf.frame_size > f->image_bytes)
        f->image_bytes = hf.frame_size;
    return memcmp(&in, f, sizeof in) == 0 ? HAL_FORMAT_VALID : HAL_FORMAT_ADJUSTED;
}

static int cam_configure(void *ctx, const struct hal_format *f)
{
    struct lc_cam *c = ctx;
    int rc = hal_cam_check_configure(&c->st);
    if (rc < 0)
        return rc;
    struct hal_format v = *f;
    if ((rc = hal_cam_check_validated(&c->st, cam_validate(c, &v))) < 0)
        return rc;
    struct hlc_format hf = {to_fourcc(v.pixfmt), v.width, v.height, 0, 0};
    struct f4d_err why = {0};
    c->st.configured = false;
    rc = hlc_camera_configure(c->hc, &hf, LC_BUFFERS, &why);
    if (rc < 0)
        return hal_cam_fail(&c->st, rc, "%s", why.msg);
    c->n_slots = (uint32_t)rc;
    c->st.fmt = v;
    c->st.configured = true;
    return F4D_OK;
}

static int cam_start(void *ctx)
{
    struct lc_cam *c = ctx;
    int rc = hal_cam_check_start(&c->st);
    if (rc < 0 || c->st.started)
        return rc;
    struct f4d_err why = {0};
    if ((rc = hlc_camera_start(c->hc, &why)) < 0)
        return hal_cam_fail(&c->st, rc, "%s", why.msg);
    for (uint32_t i = 0; i < c->n_slots; i++)
        if ((rc = hlc_camera_queue(c->hc, i, &why)) < 0) {
            hlc_camera_stop(c->hc);
            return hal_cam_fail(&c->st, rc, "%s", why.msg);
        }
    c->have_seq = false;
    c->st.started = true;
    return F4D_OK;
}

static int cam_stop(void *ctx)
{
    struct lc_cam *c = ctx;
    if (c->st.started) {
        hlc_camera_stop(c->hc);
        struct hlc_completion d;
        while (hlc_camera_wait(c->hc, &d, 0) == F4D_OK) {
        } /* the cancelled requests */
    }
    hal_cam_fifo_stop(&c->st, &c->q);
    return F4D_OK;
}

static int cam_enqueue(void *ctx, struct hal_buffer *b)
{
    struct lc_cam *c = ctx;
    return hal_cam_fifo_enqueue(&c->st, &c->q, b);
}

static int cam_dequeue(void *ctx, struct hal_buffer **out, uint32_t timeout_us)
{
    struct lc_cam *c = ctx;
    int rc = hal_cam_dequeue_begin(&c->st, out);
    if (rc < 0 || *out)
        return rc;
    uint64_t deadline = hal_mono_ns() + (uint64_t)timeout_us * 1000u;
    struct f4d_err why = {0};
    for (;;) {
        uint64_t now = hal_mono_ns();
        uint32_t left = now >= deadline ? 0 : (uint32_t)((deadline - now) / 1000u);
        struct hlc_completion d;
        rc = hlc_camera_wait(c->hc, &d, left);
        if (rc == F4D_ETIMEDOUT)
            return rc;
        if (rc == F4D_ENODEV)
            return hal_cam_fail(&c->st, rc, "camera disconnected");
        if (d.cancelled)
            continue;
        struct hal_buffer *b = hal_bufq_pop(&c->q);
        if (b) {
            const uint8_t *src = hlc_camera_slot_data(c->hc, d.slot);
            size_t n = d.bytes_used <= b->capacity ? d.bytes_used : b->capacity;
            if (src && d.ok)
                memcpy(b->data, src, n);
            else
                n = 0;
            if (!c->have_seq) {
                c->have_seq = true;
                c->seq_hi = 0;
            } else if (d.sequence < c->last_seq32) {
                c->seq_hi += 1ull << 32;
            }
            c->last_seq32 = d.sequence;
            b->bytes_used = n;
            b->status = d.ok && n >= c->st.fmt.stride * (size_t)c->st.fmt.height ? HAL_FRAME_OK
                                                                                : HAL_FRAME_MISSING_PACKETS;
            b->flags = 0;
            b->camera_index = c->index;
            b->format = c->st.fmt;
            b->device_ts_ns = d.sensor_ts_ns;
            b->host_ts_ns = hal_mono_ns();
            b->frame_id = c->seq_hi + d.sequence;
            b->trigger_seq = b->frame_id + 1;
            *out = b;
        } else {
            c->dropped++;
        }
        if ((rc = hlc_camera_queue(c->hc, d.slot, &why)) < 0)
            return hal_cam_fail(&c->st, rc, "%s", why.msg);
        if (b)
            return F4D_OK;
    }
}

static void cam_close(void *ctx)
{
    struct lc_cam *c = ctx;
    cam_stop(c);
    hlc_camera_release(c->hc);
    free(c);
}

static const char *cam_last_error(void *ctx) { return ((struct lc_cam *)ctx)->st.err.msg; }

static const struct hal_camera_ops lc_camera_ops = {
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

/* ---- backend ---- */
static int lc_session_open(const struct hal_board *board, void **session, struct f4d_err *err)
{
    (void)board;
    struct lc_session *s = calloc(1, sizeof *s);
    if (!s)
        return f4d_fail(err, F4D_ENOMEM, "libcamera: out of memory");
    int rc = hlc_manager_start(err);
    if (rc < 0) {
        free(s);
        return rc;
    }
    *session = s;
    return F4D_OK;
}

static void lc_session_close(void *s)
{
    hlc_manager_stop();
    free(s);
}

static int lc_camera_open(void *session, const struct hal_camera_config *cfg, uint32_t index,
                          struct hal_camera *out, struct f4d_err *err)
{
    (void)session;
    if (!cfg->address[0])
        return f4d_fail(err, F4D_EINVAL, "libcamera camera %s: no camera id (address)", cfg->id);
    struct hlc_camera *hc = NULL;
    struct f4d_err why = {0};
    int rc = hlc_camera_acquire(cfg->address, &hc, &why);
    if (rc < 0)
        return f4d_fail(err, rc, "libcamera camera %s: %s", cfg->id, why.msg);
    struct lc_cam *c = calloc(1, sizeof *c);
    if (!c) {
        hlc_camera_release(hc);
        return f4d_fail(err, F4D_ENOMEM, "libcamera: out of memory");
    }
    c->index = index;
    c->hc = hc;
    hal_cam_name(&c->st, "libcamera camera %.40s (%.80s)", cfg->id, cfg->address);
    hal_camera_bind(out, &lc_camera_ops, c, index);
    return F4D_OK;
}

const struct hal_backend hal_libcamera_backend = {
    .api_version = HAL_API_VERSION,
    .name = "libcamera",
    .session_open = lc_session_open,
    .session_close = lc_session_close,
    .camera_open = lc_camera_open,
};
