/* test_gpiod.c: the libgpiod trigger backend's failure paths (no GPIO chip can
 * exist on this machine: see hal.md 2). Each names what is wrong. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>

#include <stdio.h>
#include <string.h>

#include "hal_board.h"
#include "hal_registry.h"

static int open_trigger(const char *chip, int line, int strobe, struct f4d_err *err)
{
    const struct hal_backend *be = hal_backend_find("gpiod");
    assert_non_null(be);
    assert_int_equal(be->api_version, HAL_API_VERSION);
    struct hal_trigger_config cfg = {0};
    snprintf(cfg.backend, sizeof cfg.backend, "gpiod");
    snprintf(cfg.chip, sizeof cfg.chip, "%s", chip);
    cfg.line = line;
    cfg.strobe_line = strobe;
    cfg.rate_mhz = 30000;
    cfg.pulse_width_us = 1000;
    void *session = NULL;
    assert_int_equal(be->session_open(NULL, &session, err), 0);
    struct hal_trigger t;
    int rc = be->trigger_open(session, &cfg, &t, err);
    if (rc == F4D_OK) /* a machine with a real chip: do not drive its lines */
        t.ops.close(t.ctx);
    if (be->session_close)
        be->session_close(session);
    return rc;
}

static void no_chip(void **state)
{
    (void)state;
    struct f4d_err err = {0};
    int rc = open_trigger("gpiochip0", 17, 18, &err);
    if (rc == F4D_OK)
        skip(); /* a GPIO chip exists here after all */
    assert_int_equal(rc, F4D_ENODEV);
    assert_non_null(strstr(err.msg, "gpiochip0"));
    assert_non_null(strstr(err.msg, "No such file"));
    err.msg[0] = 0;
    assert_int_equal(open_trigger("trigger-header", 3, -1, &err), F4D_ENODEV);
    assert_non_null(strstr(err.msg, "trigger-header"));
}

static void not_a_gpio_device(void **state)
{
    (void)state;
    struct f4d_err err = {0};
    int rc = open_trigger("/dev/null", 0, -1, &err);
    assert_true(rc < 0);
    assert_non_null(strstr(err.msg, "/dev/null"));
}

static void bad_config(void **state)
{
    (void)state;
    struct f4d_err err = {0};
    assert_int_equal(open_trigger("", 0, -1, &err), F4D_EINVAL);
    assert_non_null(strstr(err.msg, "trigger.chip"));
    assert_int_equal(open_trigger("gpiochip0", -1, -1, &err), F4D_EINVAL);
    assert_non_null(strstr(err.msg, "line -1"));
}

/* The shipped GigE board opens its GPIO trigger first: the rig fails cleanly,
 * naming the chip, and leaves nothing open. */
static void gige_board_without_gpio(void **state)
{
    (void)state;
    struct hal_board b;
    struct f4d_err err = {0};
    assert_int_equal(hal_board_load(&b, F4D_BOARD_DIR "/gige-4cam.json", &err), 0);
    struct hal_rig rig;
    int rc = hal_rig_open(&rig, &b, &err);
    if (rc == F4D_OK) {
        hal_rig_close(&rig);
        skip();
    }
    assert_true(rc < 0);
    assert_non_null(strstr(err.msg, "gpiochip0"));
    assert_int_equal(rig.n_cams, 0);
    assert_int_equal(rig.n_sessions, 0);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(no_chip),
        cmocka_unit_test(not_a_gpio_device),
        cmocka_unit_test(bad_config),
        cmocka_unit_test(gige_board_without_gpio),
    };
    return cmocka_run_group_tests_name("hal/gpiod", tests, NULL, NULL);
}
