/* test_libcamera_ops.c: the C half of the libcamera backend
 * (hal/libcamera/hal_libcamera.c) over a FAKE shim: this file implements the
 * extern "C" API of hal_libcamera_shim.h with one fake camera, so the camera
 * ops (format mapping, state rules, the caller-buffer FIFO, copying, frame
 * metadata, stop, disconnect) run here although libcamera finds no camera on
 * this machine. No C++ and no libcamera: builds with F4D_WITH_LIBCAMERA=OFF
 * too. The real shim is covered by test_libcamera.c. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>

#include <stdio.h>
#include <string.h>

#include "hal_libcamera.h"
#include "hal_libcamera_shim.h"

/* ---- the fake shim: one camera "fake0", 640x480 or 320x240, YUYV/R8/BG24 ---- */
#define FK_SLOTS 4
static struct {
    uint32_t refs;
    bool acquired, configured, started, disconnected;
    uint32_t fourcc, width, height, stride;
    uint32_t last_asked_fourcc;
    uint8_t mem[FK_SLOTS][640 * 480 * 3];
    bool queued[FK_SLOTS];
    struct hlc_completion ring[FK_SLOTS];
    uint32_t head, count;
    uint32_t sequence;
    uint32_t queues;
} fk;

int hlc_manager_start(struct f4d_err *err)
{
    (void)err;
    fk.refs++;
    return F4D_OK;
}
int hlc_manager_stop(void)
{
    if (!fk.refs)
        return F4D_ESTATE;
    fk.refs--;
    return F4D_OK;
}
uint32_t hlc_manager_refs(void) { return fk.refs; }
int hlc_manager_count(void) { return fk.refs ? 1 : F4D_ESTATE; }
int hlc_manager_camera_id(uint32_t i, char *buf, size_t cap)
{
    if (i)
        return F4D_EINVAL;
    snprintf(buf, cap, "fake0");
    return F4D_OK;
}
void hlc_manager_describe(char *buf, size_t cap) { snprintf(buf, cap, "cameras: \"fake0\""); }

struct hlc_camera {
    int unused;
};
static struct hlc_camera the_cam;

int hlc_camera_acquire(const char *id, struct hlc_camera **out, struct f4d_err *err)
{
    *out = NULL;
    if (strcmp(id, "fake0") != 0) {
        return f4d_fail(err, F4D_ENODEV, "libcamera: no camera with id \"%s\" (libcamera sees cameras: \"fake0\")", id);
    }
    if (fk.acquired) {
        return f4d_fail(err, F4D_EBUSY, "busy");
    }
    fk.acquired = true;
    *out = &the_cam;
    return F4D_OK;
}
void hlc_camera_release(struct hlc_camera *c)
{
    (void)c;
    hlc_camera_stop(c);
    fk.acquired = fk.configured = false;
}
static uint32_t bpp(uint32_t fourcc) { return fourcc == HLC_FOURCC('B', 'G', '2', '4') ? 3 : fourcc == HLC_FOURCC('R', '8', ' ', ' ') ? 1 : 2; }
int hlc_camera_validate(struct hlc_camera *c, struct hlc_format *f, struct f4d_err *err)
{
    (void)c, (void)err;
    struct hlc_format in = *f;
    fk.last_asked_fourcc = f->fourcc;
    if (f->fourcc != HLC_FOURCC('Y', 'U', 'Y', 'V') && f->fourcc != HLC_FOURCC('R', '8', ' ', ' ') &&
        f->fourcc != HLC_FOURCC('B', 'G', '2', '4'))
        f->fourcc = HLC_FOURCC('Y', 'U', 'Y', 'V');
    if (f->width >= 480)
        f->width = 640, f->height = 480;
    else
        f->width = 320, f->height = 240;
    f->stride = f->width * bpp(f->fourcc);
    f->frame_size = f->stride * f->height;
    return in.fourcc == f->fourcc && in.width == f->width && in.height == f->height ? 0 : 1;
}
int hlc_camera_configure(struct hlc_camera *c, struct hlc_format *f, uint32_t n, struct f4d_err *err)
{
    if (fk.started)
        return F4D_ESTATE;
    if (hlc_camera_validate(c, f, err) != 0)
        return F4D_EINVAL;
    fk.fourcc = f->fourcc, fk.width = f->width, fk.height = f->height, fk.stride = f->stride;
    fk.configured = true;
    return (int)(n < FK_SLOTS ? n : FK_SLOTS);
}
const uint8_t *hlc_camera_slot_data(struct hlc_camera *c, uint32_t slot)
{
    (void)c;
    return slot < FK_SLOTS ? fk.mem[slot] : NULL;
}
int hlc_camera_start(struct hlc_camera *c, struct f4d_err *err)
{
    (void)c, (void)err;
    if (!fk.configured)
        return F4D_ESTATE;
    fk.started = true;
    return F4D_OK;
}
static void complete(uint32_t slot, bool cancelled)
{
    struct hlc_completion *d = &fk.ring[(fk.head + fk.count++) % FK_SLOTS];
    memset(d, 0, sizeof *d);
    d->slot = slot;
    d->cancelled = cancelled;
    d->ok = !cancelled;
    if (!cancelled) {
        d->sequence = fk.sequence++;
        d->sensor_ts_ns = 1000000000ull + (uint64_t)d->sequence * 33333333u;
        d->bytes_used = fk.stride * fk.height;
        memset(fk.mem[slot], (int)(d->sequence & 0xFF), d->bytes_used);
    }
    fk.queued[slot] = false;
}
int hlc_camera_stop(struct hlc_camera *c)
{
    (void)c;
    if (!fk.started)
        return F4D_OK;
    for (uint32_t i = 0; i < FK_SLOTS; i++)
        if (fk.queued[i])
            complete(i, true);
    fk.started = false;
    return F4D_OK;
}
int hlc_camera_queue(struct hlc_camera *c, uint32_t slot, struct f4d_err *err)
{
    (void)c, (void)err;
    if (!fk.started || slot >= FK_SLOTS || fk.queued[slot])
        return F4D_EINVAL;
    fk.queued[slot] = true;
    fk.queues++;
    return F4D_OK;
}
int hlc_camera_wait(struct hlc_camera *c, struct hlc_completion *out, uint32_t timeout_us)
{
    (void)c, (void)timeout_us;
    if (fk.count) {
        *out = fk.ring[fk.head];
        fk.head = (fk.head + 1) % FK_SLOTS;
        fk.count--;
        return F4D_OK;
    }
    return fk.disconnected ? F4D_ENODEV : F4D_ETIMEDOUT;
}
/* the "sensor": completes the oldest queued request */
static void sensor_frame(void)
{
    for (uint32_t i = 0; i < FK_SLOTS; i++)
        if (fk.queued[i]) {
            complete(i, false);
            return;
        }
    fail_msg("no request queued");
}

/* ---- the tests ---- */
static void open_cam(struct hal_camera *cam, void **session)
{
    struct f4d_err err = {0};
    struct hal_camera_config cc;
    memset(&cc, 0, sizeof cc);
    snprintf(cc.id, sizeof cc.id, "cam0");
    snprintf(cc.address, sizeof cc.address, "fake0");
    assert_int_equal(hal_libcamera_backend.session_open(NULL, session, &err), F4D_OK);
    if (hal_libcamera_backend.camera_open(*session, &cc, 2, cam, &err) < 0)
        fail_msg("%s", err);
}

static void state_rules_and_frames(void **state)
{
    (void)state;
    memset(&fk, 0, sizeof fk);
    void *session;
    struct hal_camera cam;
    open_cam(&cam, &session);
    assert_int_equal(fk.refs, 1);

    static uint8_t mem[4][640 * 480 * 3];
    struct hal_buffer bufs[4];
    memset(bufs, 0, sizeof bufs);
    for (int i = 0; i < 4; i++)
        bufs[i].data = mem[i], bufs[i].capacity = sizeof mem[i];
    struct hal_buffer *out;
    assert_int_equal(hal_camera_start(&cam), F4D_ESTATE);
    assert_non_null(strstr(hal_camera_last_error(&cam), "start before configure"));
    assert_int_equal(hal_camera_enqueue(&cam, &bufs[0]), F4D_ESTATE);
    assert_int_equal(hal_camera_dequeue(&cam, &out, 0), F4D_ESTATE);

    /* rgb8 is asked as DRM BGR888 (bytes R,G,B); sizes snap */
    struct hal_format f = {HAL_PIXFMT_RGB8, 1000, 700, 0, 30000, HAL_TRIGGER_HARDWARE, 1000, 0};
    assert_int_equal(hal_camera_validate(&cam, &f), HAL_FORMAT_ADJUSTED);
    assert_int_equal(fk.last_asked_fourcc, HLC_FOURCC('B', 'G', '2', '4'));
    assert_int_equal(f.pixfmt, HAL_PIXFMT_RGB8);
    assert_int_equal(f.width, 640);
    assert_int_equal(f.stride, 1920);
    assert_int_equal(f.trigger, HAL_TRIGGER_FREE_RUN);
    assert_int_equal(f.image_bytes, 1920 * 480);
    struct hal_format bad = f;
    bad.width = 1000;
    assert_int_equal(hal_camera_configure(&cam, &bad), F4D_EINVAL);
    assert_int_equal(hal_camera_validate(&cam, &f), HAL_FORMAT_VALID);
    assert_int_equal(hal_camera_configure(&cam, &f), F4D_OK);
    struct hal_format mono16 = f;
    mono16.pixfmt = HAL_PIXFMT_MONO16; /* R16: the fake camera offers YUYV instead */
    assert_int_equal(hal_camera_validate(&cam, &mono16), HAL_FORMAT_ADJUSTED);
    assert_int_equal(mono16.pixfmt, HAL_PIXFMT_YUYV);

    struct hal_buffer small = {mem[0], 100, NULL, 0, 0, 0, 0, 0, 0, 0, 0, {0}};
    assert_int_equal(hal_camera_enqueue(&cam, &small), F4D_EINVAL);
    for (int i = 0; i < 3; i++)
        assert_int_equal(hal_camera_enqueue(&cam, &bufs[i]), F4D_OK);
    assert_int_equal(hal_camera_start(&cam), F4D_OK);
    assert_int_equal(hal_camera_start(&cam), F4D_OK); /* twice: nothing more */
    assert_int_equal(fk.queues, 4);                   /* every libcamera request queued once */
    assert_int_equal(hal_camera_configure(&cam, &f), F4D_ESTATE);
    assert_int_equal(hal_camera_dequeue(&cam, &out, 0), F4D_ETIMEDOUT);

    /* frames are copied into the caller's buffers in the order queued */
    for (uint32_t k = 0; k < 2; k++) {
        sensor_frame();
        assert_int_equal(hal_camera_dequeue(&cam, &out, 1000), F4D_OK);
        assert_ptr_equal(out, &bufs[k]);
        assert_int_equal(out->status, HAL_FRAME_OK);
        assert_int_equal(out->frame_id, k);
        assert_int_equal(out->trigger_seq, k + 1);
        assert_int_equal(out->camera_index, 2);
        assert_int_equal(out->device_ts_ns, 1000000000ull + k * 33333333u);
        assert_int_equal(out->bytes_used, 1920 * 480);
        assert_int_equal(out->data[0], k);
        assert_int_equal(out->data[out->bytes_used - 1], k);
        assert_int_equal(out->format.pixfmt, HAL_PIXFMT_RGB8);
    }
    assert_int_equal(fk.queues, 6); /* their requests went straight back */

    /* 1 caller buffer left: a frame with none to fill is dropped, not an error */
    sensor_frame();
    assert_int_equal(hal_camera_dequeue(&cam, &out, 0), F4D_OK);
    assert_ptr_equal(out, &bufs[2]);
    sensor_frame();
    assert_int_equal(hal_camera_dequeue(&cam, &out, 0), F4D_ETIMEDOUT);

    /* the 32-bit sequence is unwrapped */
    assert_int_equal(hal_camera_enqueue(&cam, &bufs[0]), F4D_OK);
    assert_int_equal(hal_camera_enqueue(&cam, &bufs[1]), F4D_OK);
    fk.sequence = 0xFFFFFFFFu;
    sensor_frame();
    sensor_frame();
    assert_int_equal(hal_camera_dequeue(&cam, &out, 0), F4D_OK);
    assert_int_equal(out->frame_id, 0xFFFFFFFFull);
    assert_int_equal(hal_camera_dequeue(&cam, &out, 0), F4D_OK);
    assert_int_equal(out->frame_id, 0x100000000ull);

    /* stop: the caller's queued buffers come back ABORTED, the requests cancelled */
    assert_int_equal(hal_camera_enqueue(&cam, &bufs[3]), F4D_OK);
    assert_int_equal(hal_camera_stop(&cam), F4D_OK);
    assert_int_equal(hal_camera_stop(&cam), F4D_OK); /* twice */
    assert_int_equal(hal_camera_dequeue(&cam, &out, 0), F4D_OK);
    assert_ptr_equal(out, &bufs[3]);
    assert_int_equal(out->status, HAL_FRAME_ABORTED);
    assert_int_equal(hal_camera_dequeue(&cam, &out, 0), F4D_ESTATE);
    assert_int_equal(fk.count, 0); /* the cancelled completions were drained */

    /* again, then the camera disconnects */
    assert_int_equal(hal_camera_enqueue(&cam, &bufs[0]), F4D_OK);
    assert_int_equal(hal_camera_start(&cam), F4D_OK);
    fk.disconnected = true;
    assert_int_equal(hal_camera_dequeue(&cam, &out, 0), F4D_ENODEV);
    assert_non_null(strstr(hal_camera_last_error(&cam), "cam0"));
    assert_non_null(strstr(hal_camera_last_error(&cam), "disconnected"));
    cam.ops.close(cam.ctx);
    assert_false(fk.acquired);
    hal_libcamera_backend.session_close(session);
    assert_int_equal(fk.refs, 0);
}

static void open_failures(void **state)
{
    (void)state;
    memset(&fk, 0, sizeof fk);
    void *session;
    struct f4d_err err = {0};
    assert_int_equal(hal_libcamera_backend.session_open(NULL, &session, &err), F4D_OK);
    struct hal_camera_config cc;
    memset(&cc, 0, sizeof cc);
    snprintf(cc.id, sizeof cc.id, "cam1");
    snprintf(cc.address, sizeof cc.address, "imx477");
    struct hal_camera cam;
    assert_int_equal(hal_libcamera_backend.camera_open(session, &cc, 0, &cam, &err), F4D_ENODEV);
    assert_non_null(strstr(err.msg, "cam1"));
    assert_non_null(strstr(err.msg, "\"imx477\""));
    assert_non_null(strstr(err.msg, "\"fake0\"")); /* what does exist */
    snprintf(cc.address, sizeof cc.address, "fake0");
    assert_int_equal(hal_libcamera_backend.camera_open(session, &cc, 0, &cam, &err), F4D_OK);
    struct hal_camera cam2;
    assert_int_equal(hal_libcamera_backend.camera_open(session, &cc, 1, &cam2, &err), F4D_EBUSY);
    cam.ops.close(cam.ctx);
    hal_libcamera_backend.session_close(session);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(state_rules_and_frames),
        cmocka_unit_test(open_failures),
    };
    return cmocka_run_group_tests_name("hal/libcamera_ops", tests, NULL, NULL);
}
