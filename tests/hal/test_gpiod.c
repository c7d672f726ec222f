/* test_gpiod.c: the libgpiod trigger backend's failure paths (no GPIO chip can
 * exist on this machine: see hal.md 2). Each names what is wrong. The cases that
 * need the machine to have no chip (no_chip, gige_board_without_gpio) and the
 * one that needs a real chip (real_chip_pulses) skip, saying why, where the
 * machine is the other way: ctest registers them apart, labelled
 * machine-dependent. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>

#include <glob.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "hal_board.h"
#include "hal_registry.h"

#include "f4d_test.h"

/* The first /dev/gpiochip* of this machine, or "" */
static void first_chip(char *out, size_t n)
{
    glob_t g;
    out[0] = 0;
    if (glob("/dev/gpiochip*", 0, NULL, &g) == 0 && g.gl_pathc > 0)
        snprintf(out, n, "%s", g.gl_pathv[0]);
    globfree(&g);
}

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
        f4d_skip("no_chip: gpiochip0 exists and opened on this machine: the no-chip path cannot be exercised");
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
        f4d_skip("gige_board_without_gpio: gige-4cam.json's GPIO trigger and cameras opened on this machine");
    }
    assert_true(rc < 0);
    assert_non_null(strstr(err.msg, "gpiochip0"));
    assert_int_equal(rig.n_cams, 0);
    assert_int_equal(rig.n_sessions, 0);
}

/* A real chip: only where one exists AND the person running the test names a
 * line that is free to be driven (a pulse train on a line wired to something
 * else could do harm), F4D_TEST_GPIO_CHIP=gpiochip0 F4D_TEST_GPIO_LINE=17.
 * Without a strobe line the backend reports each pulse it sent as an edge. */
static void real_chip_pulses(void **state)
{
    (void)state;
    char chip[256];
    first_chip(chip, sizeof chip);
    const char *want = getenv("F4D_TEST_GPIO_CHIP"), *line = getenv("F4D_TEST_GPIO_LINE");
    if (!chip[0] && !(want && *want))
        f4d_skip("real_chip_pulses: no GPIO chip on this machine (no /dev/gpiochip*: a kernel without "
                 "CONFIG_GPIOLIB, see ../shared/docs/hal.md section 2)");
    if (!want || !*want || !line || !*line)
        f4d_skip("real_chip_pulses: %s exists; set F4D_TEST_GPIO_CHIP and F4D_TEST_GPIO_LINE to a line "
                 "that is free to be driven to run this case", chip);
    const struct hal_backend *be = hal_backend_find("gpiod");
    assert_non_null(be);
    struct hal_trigger_config cfg = {0};
    snprintf(cfg.backend, sizeof cfg.backend, "gpiod");
    snprintf(cfg.chip, sizeof cfg.chip, "%s", want);
    cfg.line = atoi(line);
    cfg.strobe_line = -1;
    cfg.rate_mhz = 100000; /* 100 Hz */
    cfg.pulse_width_us = 1000;
    void *session = NULL;
    struct f4d_err err = {0};
    assert_int_equal(be->session_open(NULL, &session, &err), 0);
    struct hal_trigger t;
    if (be->trigger_open(session, &cfg, &t, &err) != F4D_OK)
        fail_msg("%s", err);
    struct hal_pulse_train train = {cfg.rate_mhz, cfg.pulse_width_us, 3};
    assert_int_equal(hal_trigger_arm(&t, &train), F4D_OK);
    struct hal_edge e[8];
    uint32_t got = 0;
    for (int tries = 0; tries < 100 && got < 3; tries++) {
        int n = hal_trigger_read_edges(&t, e + got, 8 - got, 20000);
        assert_true(n >= 0);
        got += (uint32_t)n;
    }
    assert_int_equal(got, 3);
    for (uint32_t i = 0; i < got; i++) {
        assert_int_equal(e[i].seq, i + 1);
        assert_int_equal(e[i].line, (uint32_t)cfg.line);
        if (i > 0)
            assert_true(e[i].ts_ns > e[i - 1].ts_ns);
    }
    hal_trigger_disarm(&t);
    t.ops.close(t.ctx);
    if (be->session_close)
        be->session_close(session);
}

int main(int argc, char **argv)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(no_chip),
        cmocka_unit_test(not_a_gpio_device),
        cmocka_unit_test(bad_config),
        cmocka_unit_test(gige_board_without_gpio),
        cmocka_unit_test(real_chip_pulses),
    };
    return F4D_TEST_MAIN(argc, argv, "hal/gpiod", tests, NULL, NULL);
}
