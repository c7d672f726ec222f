/* test_backend.c: the helpers backends share (hal/core/hal_backend.h): the
 * buffer ring, the camera state rules and their messages, the edge queue. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>

#include <string.h>

#include "hal_backend.h"

static void bufq_is_fifo_and_bounded(void **state)
{
    (void)state;
    static struct hal_bufq q;
    static struct hal_buffer b[HAL_BUFQ_MAX + 1];
    assert_null(hal_bufq_pop(&q));
    /* wrap around the ring a few times */
    for (int round = 0; round < 3; round++) {
        for (int i = 0; i < HAL_BUFQ_MAX; i++)
            assert_true(hal_bufq_push(&q, &b[i]));
        assert_false(hal_bufq_push(&q, &b[HAL_BUFQ_MAX]));
        for (int i = 0; i < HAL_BUFQ_MAX / 2 + round; i++)
            assert_ptr_equal(hal_bufq_pop(&q), &b[i]);
        for (int i = HAL_BUFQ_MAX / 2 + round; i < HAL_BUFQ_MAX; i++)
            assert_ptr_equal(hal_bufq_pop(&q), &b[i]);
        assert_null(hal_bufq_pop(&q));
    }
}

static void cam_state_rules_and_messages(void **state)
{
    (void)state;
    static struct hal_cam_state s;
    static struct hal_bufq q;
    uint8_t px[64];
    struct hal_buffer b = {.data = px, .capacity = sizeof px};
    struct hal_buffer *out = &b;
    hal_cam_name(&s, "test camera %s", "cam0");

    assert_int_equal(hal_cam_fifo_enqueue(&s, &q, &b), F4D_ESTATE);
    assert_string_equal(s.err.msg, "test camera cam0: enqueue before configure");
    assert_int_equal(hal_cam_fifo_start(&s), F4D_ESTATE);
    assert_string_equal(s.err.msg, "test camera cam0: start before configure");
    assert_int_equal(hal_cam_dequeue_begin(&s, &out), F4D_ESTATE);
    assert_null(out);
    assert_string_equal(s.err.msg, "test camera cam0: dequeue while stopped");

    assert_int_equal(hal_cam_check_validated(&s, F4D_EIO), F4D_EIO);
    assert_int_equal(hal_cam_check_validated(&s, HAL_FORMAT_ADJUSTED), F4D_EINVAL);
    assert_string_equal(s.err.msg, "test camera cam0: format does not validate unchanged");
    assert_int_equal(hal_cam_check_validated(&s, HAL_FORMAT_VALID), F4D_OK);

    s.configured = true;
    s.fmt.image_bytes = sizeof px + 1;
    assert_int_equal(hal_cam_fifo_enqueue(&s, &q, &b), F4D_EINVAL);
    assert_string_equal(s.err.msg, "test camera cam0: buffer smaller than the image");
    s.fmt.image_bytes = sizeof px;
    assert_int_equal(hal_cam_fifo_enqueue(&s, &q, &b), F4D_OK);
    assert_int_equal(hal_cam_fifo_start(&s), F4D_OK);
    assert_int_equal(hal_cam_check_configure(&s), F4D_ESTATE);
    assert_string_equal(s.err.msg, "test camera cam0: configure while started");
    assert_int_equal(hal_cam_dequeue_begin(&s, &out), F4D_OK);
    assert_null(out); /* started, nothing aborted: the backend goes on */

    /* stop hands the queued buffer back ABORTED, before the stopped check */
    b.bytes_used = 7;
    hal_cam_fifo_stop(&s, &q);
    assert_false(s.started);
    assert_int_equal(hal_cam_dequeue_begin(&s, &out), F4D_OK);
    assert_ptr_equal(out, &b);
    assert_int_equal(b.status, HAL_FRAME_ABORTED);
    assert_int_equal(b.bytes_used, 0);
    assert_int_equal(hal_cam_dequeue_begin(&s, &out), F4D_ESTATE);

    /* the aborted list never overflows, even if nobody collects it */
    for (int i = 0; i < 3 * HAL_BUFQ_MAX; i++)
        hal_cam_abort(&s, &b);
    assert_int_equal(s.n_aborted, HAL_BUFQ_MAX);

    assert_int_equal(hal_cam_fail(&s, F4D_EIO, "%s: %d", "VIDIOC_X", 5), F4D_EIO);
    assert_string_equal(s.err.msg, "test camera cam0: VIDIOC_X: 5");
}

static void edgeq_drop_newest_or_oldest(void **state)
{
    (void)state;
    static struct hal_edgeq q;
    struct hal_edge out[8];
    q.limit = 4;
    for (uint64_t i = 1; i <= 6; i++) {
        struct hal_edge e = {i, i * 10, 0, true};
        assert_int_equal(hal_edgeq_push(&q, &e), i <= 4);
    }
    assert_int_equal(hal_edgeq_pop(&q, out, 8), 4);
    assert_int_equal(out[0].seq, 1);
    assert_int_equal(out[3].seq, 4); /* 5 and 6 were dropped */

    for (uint64_t i = 1; i <= 6; i++) {
        struct hal_edge e = {i, i * 10, 0, true};
        assert_int_equal(hal_edgeq_push_overwrite(&q, &e), i > 4);
    }
    assert_int_equal(hal_edgeq_pop(&q, out, 2), 2);
    assert_int_equal(out[0].seq, 3); /* 1 and 2 were overwritten */
    assert_int_equal(out[1].seq, 4);
    assert_int_equal(hal_edgeq_pop(&q, out, 8), 2);
    assert_int_equal(out[1].seq, 6);
    assert_int_equal(hal_edgeq_pop(&q, out, 8), 0);
}

static void trigger_claim_once(void **state)
{
    (void)state;
    static const struct hal_trigger_ops ops = {.api_version = HAL_API_VERSION};
    bool taken = false;
    int ctx;
    struct hal_trigger t;
    struct f4d_err err = {0};
    assert_int_equal(hal_trigger_claim(&taken, &t, &ops, &ctx, "x trigger", &err), F4D_OK);
    assert_true(taken);
    assert_ptr_equal(t.ctx, &ctx);
    assert_int_equal(hal_trigger_claim(&taken, &t, &ops, &ctx, "x trigger", &err), F4D_EBUSY);
    assert_string_equal(err.msg, "x trigger already open");
}

static void world_clock_jumps_when_not_realtime(void **state)
{
    (void)state;
    struct hal_world_clock c = {0};
    assert_int_equal(hal_world_clock_read(&c), 0);
    assert_int_equal(hal_world_clock_wait(&c, 5000), 5000);
    assert_int_equal(hal_world_clock_wait(&c, 10), 5000); /* never goes back */
    c.realtime = true;
    c.real_t0 = hal_mono_ns();
    uint64_t t = hal_world_clock_wait(&c, 1000000); /* 1 ms */
    assert_true(t >= 1000000);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(bufq_is_fifo_and_bounded),
        cmocka_unit_test(cam_state_rules_and_messages),
        cmocka_unit_test(edgeq_drop_newest_or_oldest),
        cmocka_unit_test(trigger_claim_once),
        cmocka_unit_test(world_clock_jumps_when_not_realtime),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
