/* test_board.c: board description files and the parser's error messages. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "hal_board.h"

static void shipped_boards_load(void **state)
{
    (void)state;
    const char *names[] = {"sim-4cam", "sim-4cam-faulty", "gige-4cam", "usb-2cam"};
    for (int i = 0; i < 4; i++) {
        char path[512];
        struct f4d_err err = {0};
        struct hal_board b;
        snprintf(path, sizeof path, "%s/%s.json", F4D_BOARD_DIR, names[i]);
        int rc = hal_board_load(&b, path, &err);
        if (rc < 0)
            fail_msg("%s: %s", path, err);
        assert_string_equal(b.name, names[i]);
    }
    struct hal_board b;
    struct f4d_err err = {0};
    assert_int_equal(hal_board_load(&b, F4D_BOARD_DIR "/sim-4cam.json", &err), 0);
    assert_int_equal(b.n_cams, 4);
    assert_int_equal(b.cams[3].width, 518);
    assert_int_equal(b.cams[3].height, 518);
    assert_int_equal(b.trigger.rate_mhz, 30000);
    assert_string_equal(b.cams[0].backend, "sim");
    assert_true(b.cams[0].intrinsics.known);
    assert_int_equal(hal_board_load(&b, F4D_BOARD_DIR "/sim-4cam-faulty.json", &err), 0);
    assert_true(b.sim.faults.drop > 0 && b.sim.faults.duplicate > 0 && b.sim.faults.late > 0 &&
                b.sim.faults.incomplete > 0 && b.sim.faults.trigger_missing > 0 &&
                b.sim.faults.trigger_extra > 0 && b.sim.faults.disconnect > 0 &&
                b.sim.faults.jitter_us > 0 && b.sim.faults.clock_offset_ms > 0 &&
                b.sim.faults.clock_drift_ppm > 0);
    assert_int_equal(hal_board_load(&b, F4D_BOARD_DIR "/gige-4cam.json", &err), 0);
    assert_string_equal(b.cams[2].backend, "aravis");
    assert_string_equal(b.trigger.backend, "gpiod");
    assert_int_equal(b.cams[0].packet_size, 8192);
}

static void round_trip(void **state)
{
    (void)state;
    struct hal_board a, b;
    struct f4d_err err = {0};
    assert_int_equal(hal_board_load(&a, F4D_BOARD_DIR "/sim-4cam-faulty.json", &err), 0);
    char *js = hal_board_to_json(&a);
    assert_non_null(js);
    int rc = hal_board_parse(&b, js, strlen(js), &err);
    if (rc < 0)
        fail_msg("%s", err);
    free(js);
    assert_memory_equal(&a.cams[0], &b.cams[0], sizeof a.cams[0]);
    assert_memory_equal(&a.sim.faults, &b.sim.faults, sizeof a.sim.faults);
    assert_int_equal(a.trigger.rate_mhz, b.trigger.rate_mhz);
    assert_int_equal(a.sync.incomplete, b.sync.incomplete);
}

/* Each bad input is rejected with a message that names the offending key. */
static void errors_name_the_key(void **state)
{
    (void)state;
    static const struct {
        const char *json, *want;
    } cases[] = {
        {"{", "not valid JSON"},
        {"[]", "(root)"},
        {"{\"name\":\"x\"}", "cameras: missing"},
        {"{\"cameras\":[]}", "cameras: must hold 1..16"},
        {"{\"cameras\":[{\"widht\":10}]}", "cameras[0].widht: unknown key"},
        {"{\"cameras\":[{\"width\":\"518\"}]}", "cameras[0].width: must be a number"},
        {"{\"cameras\":[{\"width\":5}]}", "cameras[0].width: must be 16..65535, got 5"},
        {"{\"cameras\":[{\"width\":100.5}]}", "cameras[0].width: must be an integer"},
        {"{\"cameras\":[{\"pixel_format\":\"rgb9\"}]}", "cameras[0].pixel_format: unknown"},
        {"{\"cameras\":[{\"backend\":\"firewire\"}]}", "cameras[0].backend: unknown backend"},
        {"{\"cameras\":[{\"id\":\"a\"},{\"id\":\"a\"}]}", "cameras[1]: duplicate camera id"},
        {"{\"cameras\":[{\"intrinsics\":{\"fx\":1}}]}", "cameras[0].intrinsics.fy: missing"},
        {"{\"cameras\":[{}],\"trigger\":{\"rate_hz\":0}}", "trigger.rate_hz: must be"},
        {"{\"cameras\":[{}],\"trigger\":{\"rate_hz\":1000,\"pulse_width_us\":2000}}",
         "trigger.pulse_width_us: must be shorter"},
        {"{\"cameras\":[{}],\"sync\":{\"incomplete\":\"keep\"}}", "sync.incomplete: must be"},
        {"{\"cameras\":[{}],\"sim\":{\"faults\":{\"drop\":0.6,\"late\":0.6}}}", "sim.faults.drop"},
        {"{\"cameras\":[{}],\"sim\":{\"faults\":{\"drop\":2}}}", "sim.faults.drop: must be 0..1"},
        {"{\"cameras\":[{}],\"sim\":{\"realtime\":1}}", "sim.realtime: must be true or false"},
        {"{\"cameras\":[{}],\"sync\":[]}", "sync: must be an object"},
        /* capture queues pending_max + 6 buffers per camera: a sim / aravis /
         * replay camera holds 64, a usb camera 32 */
        {"{\"cameras\":[{}],\"sync\":{\"pending_max\":59}}",
         "sync.pending_max: must be at most 58 for camera"},
        {"{\"cameras\":[{}],\"sync\":{\"pending_max\":64}}", "(sim backend: 64 buffers"},
        {"{\"cameras\":[{},{\"id\":\"u\",\"backend\":\"usb\"}],\"sync\":{\"pending_max\":27}}",
         "sync.pending_max: must be at most 26 for camera \"u\" (usb backend: 32 buffers"},
    };
    for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++) {
        struct hal_board b;
        struct f4d_err err = {0};
        int rc = hal_board_parse(&b, cases[i].json, strlen(cases[i].json), &err);
        if (rc != F4D_EINVAL || !strstr(err.msg, cases[i].want))
            fail_msg("case %zu (%s): rc %d, message \"%s\", want \"%s\"", i, cases[i].json, rc, err,
                     cases[i].want);
    }
    struct hal_board b;
    struct f4d_err err = {0};
    assert_int_equal(hal_board_load(&b, "/nonexistent/board.json", &err), F4D_EIO);
    assert_non_null(strstr(err.msg, "/nonexistent/board.json"));
}

/* The largest pending_max capture can enqueue is accepted, per backend. */
static void pending_max_bound_accepted(void **state)
{
    (void)state;
    static const char *const ok[] = {
        "{\"cameras\":[{}],\"sync\":{\"pending_max\":58}}",
        "{\"cameras\":[{\"backend\":\"usb\"}],\"sync\":{\"pending_max\":26}}",
    };
    static const uint32_t want[] = { 58, 26 };
    for (size_t i = 0; i < 2; i++) {
        struct hal_board b;
        struct f4d_err err = {0};
        int rc = hal_board_parse(&b, ok[i], strlen(ok[i]), &err);
        if (rc != F4D_OK)
            fail_msg("%s: %s", ok[i], err);
        assert_int_equal(b.sync.pending_max, want[i]);
    }
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(pending_max_bound_accepted),
        cmocka_unit_test(shipped_boards_load),
        cmocka_unit_test(round_trip),
        cmocka_unit_test(errors_name_the_key),
    };
    return cmocka_run_group_tests_name("hal/board", tests, NULL, NULL);
}
