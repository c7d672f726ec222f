/* test_capture.c: the capture loop's start and error paths, on the simulated
 * rig (simulated clock, so it runs in milliseconds).
 *
 *  - a camera that fails to start: the capture fails naming it, and no camera
 *    still holds a buffer afterwards (before the fix the cameras after it, never
 *    started, kept buffers whose memory the capture had freed);
 *  - a camera that never streams: the capture fails naming it, without sending
 *    a single pulse, and again no camera holds a buffer;
 *  - hold_while_down: while a camera is disconnected no pulse is sent, so it
 *    loses only the pulse at which it dropped out; without it the train runs on.
 */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>

#include <stdio.h>
#include <string.h>

#include "f4d_capture.h"
#include "hal_board.h"
#include "hal_registry.h"
#include "hal_sim.h"

static void sim_board(struct hal_board *b)
{
    struct f4d_err err = {0};
    assert_int_equal(hal_board_load(b, F4D_BOARD_DIR "/sim-4cam.json", &err), 0);
    b->sim.realtime = false;
    memset(&b->sim.faults, 0, sizeof b->sim.faults);
    for (uint32_t i = 0; i < b->n_cams; i++) {
        b->cams[i].width = 64;
        b->cams[i].height = 48;
    }
}

/* sim_board() opened as a rig; the board outlives the rig (which points at it). */
static void open_sim_rig(struct hal_board *board, struct hal_rig *rig)
{
    struct f4d_err err = {0};
    sim_board(board);
    if (hal_rig_open(rig, board, &err) != 0)
        fail_msg("hal_rig_open: %s", err.msg);
}

static int count_set(void *user, const struct hal_set *set)
{
    (void)set;
    (*(uint64_t *)user)++;
    return 0;
}

static void assert_no_buffer_held(struct hal_rig *rig)
{
    void *world = hal_rig_session(rig, "sim");
    assert_non_null(world);
    for (uint32_t i = 0; i < rig->n_cams; i++) {
        uint32_t held = hal_sim_buffers_held(world, i);
        if (held)
            fail_msg("camera %u still holds %u buffers the capture freed", (unsigned)i, (unsigned)held);
    }
}

static void start_failure_frees_nothing_queued(void **state)
{
    (void)state;
    struct hal_board board;
    struct hal_rig rig;
    open_sim_rig(&board, &rig);
    struct f4d_err err = {0};
    assert_int_equal(hal_sim_fail_start(hal_rig_session(&rig, "sim"), 2, F4D_EIO), F4D_OK);
    uint64_t sets = 0;
    struct f4d_capture_config cfg = {.triggers = 10};
    struct f4d_capture_stats st;
    int rc = f4d_capture_run(&rig, &cfg, count_set, NULL, &sets, NULL, &st, &err);
    printf("[ start failure ] rc %d: %s\n", rc, err.msg);
    assert_int_equal(rc, F4D_EIO);
    assert_non_null(strstr(err.msg, "cam2"));
    assert_int_equal(sets, 0);
    assert_no_buffer_held(&rig);
    /* the cameras are usable again: a second capture, with camera 2 fixed */
    assert_int_equal(hal_sim_fail_start(hal_rig_session(&rig, "sim"), 2, 0), F4D_OK);
    assert_int_equal(f4d_capture_run(&rig, &cfg, count_set, NULL, &sets, NULL, &st, &err), 0);
    assert_int_equal(st.sync.sets_complete, 10);
    assert_no_buffer_held(&rig);
    hal_rig_close(&rig);
}

static bool never_streams(void *ctx)
{
    (void)ctx;
    return false;
}

static void camera_never_streaming_is_named(void **state)
{
    (void)state;
    struct hal_board board;
    struct hal_rig rig;
    open_sim_rig(&board, &rig);
    struct f4d_err err = {0};
    rig.cams[3].ops.streaming = never_streams;
    uint64_t sets = 0;
    struct f4d_capture_config cfg = {.triggers = 10, .ready_timeout_ns = 50000000ull};
    struct f4d_capture_stats st;
    int rc = f4d_capture_run(&rig, &cfg, count_set, NULL, &sets, NULL, &st, &err);
    printf("[ never streaming ] rc %d: %s\n", rc, err.msg);
    assert_int_equal(rc, F4D_ETIMEDOUT);
    assert_non_null(strstr(err.msg, "camera cam3 not streaming"));
    struct hal_sim_injected inj;
    assert_int_equal(hal_sim_injected_get(hal_rig_session(&rig, "sim"), &inj), 0);
    assert_int_equal(inj.pulses_scheduled, 0); /* the trigger was never armed */
    assert_no_buffer_held(&rig);
    hal_rig_close(&rig);
}

static void run_disconnects(bool hold, struct hal_sim_injected *inj, struct f4d_capture_stats *st)
{
    struct hal_board board;
    sim_board(&board);
    board.sim.faults.disconnect = 0.002;
    board.sim.faults.disconnect_ms = 200;
    struct hal_rig rig;
    struct f4d_err err = {0};
    assert_int_equal(hal_rig_open(&rig, &board, &err), 0);
    uint64_t sets = 0;
    struct f4d_capture_config cfg = {.triggers = 3000, .hold_while_down = hold};
    int rc = f4d_capture_run(&rig, &cfg, count_set, NULL, &sets, NULL, st, &err);
    if (rc < 0)
        fail_msg("capture: %s", err);
    assert_int_equal(hal_sim_injected_get(hal_rig_session(&rig, "sim"), inj), 0);
    printf("[ hold %s ] edges %llu, holds %llu, disconnects %llu, frames lost while disconnected %llu, "
           "sets complete %llu incomplete %llu\n",
           hold ? "on " : "off", (unsigned long long)st->sync.triggers, (unsigned long long)st->holds,
           (unsigned long long)inj->disconnects, (unsigned long long)inj->frames_lost_disconnected,
           (unsigned long long)st->sync.sets_complete, (unsigned long long)st->sync.sets_incomplete);
    assert_no_buffer_held(&rig);
    hal_rig_close(&rig);
}

static void hold_while_down(void **state)
{
    (void)state;
    struct hal_sim_injected inj;
    struct f4d_capture_stats st;
    run_disconnects(false, &inj, &st);
    assert_true(inj.disconnects > 0);
    assert_true(inj.frames_lost_disconnected > inj.disconnects); /* pulses went on while down */
    assert_int_equal(st.holds, 0);

    run_disconnects(true, &inj, &st);
    assert_true(inj.disconnects > 0);
    assert_true(st.holds > 0);
    /* each camera lost only the pulse at which it dropped out */
    assert_int_equal(inj.frames_lost_disconnected, inj.disconnects);
    assert_int_equal(st.sync.triggers, 3000); /* every requested pulse was sent */
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(start_failure_frees_nothing_queued),
        cmocka_unit_test(camera_never_streaming_is_named),
        cmocka_unit_test(hold_while_down),
    };
    return cmocka_run_group_tests_name("hal/capture", tests, NULL, NULL);
}
