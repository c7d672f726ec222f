/* test_libcamera.c: the libcamera backend as far as this machine allows.
 * libcamera 0.0.3 starts here with 0 cameras (no CSI sensor, no V4L2 in the
 * kernel, no virtual pipeline handler in 0.0.3), so this covers the shim's
 * CameraManager lifetime (refcounted start/stop, restart), the camera list,
 * and the failure paths of opening a board camera through the registry; the
 * streaming path needs a real camera and is not exercised. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>

#include <stdio.h>
#include <string.h>

#include "hal_board.h"
#include "hal_libcamera_shim.h"
#include "hal_registry.h"

static void manager_lifetime(void **state)
{
    (void)state;
    struct f4d_err err = {0};
    assert_int_equal(hlc_manager_refs(), 0);
    /* nothing to stop, nothing to list before start */
    assert_int_equal(hlc_manager_stop(), F4D_ESTATE);
    assert_int_equal(hlc_manager_count(), F4D_ESTATE);
    struct hlc_camera *cam = (struct hlc_camera *)&err; /* must be reset to NULL */
    assert_int_equal(hlc_camera_acquire("x", &cam, &err), F4D_ESTATE);
    assert_null(cam);
    assert_non_null(strstr(err.msg, "not started"));

    if (hlc_manager_start(&err) < 0)
        fail_msg("%s", err);
    assert_int_equal(hlc_manager_refs(), 1);
    assert_int_equal(hlc_manager_count(), 0); /* no camera on this machine */
    char id[64];
    assert_int_equal(hlc_manager_camera_id(0, id, sizeof id), F4D_EINVAL);
    char list[128];
    hlc_manager_describe(list, sizeof list);
    assert_string_equal(list, "no cameras");

    /* a second start (another rig) shares the one CameraManager */
    assert_int_equal(hlc_manager_start(&err), F4D_OK);
    assert_int_equal(hlc_manager_refs(), 2);
    assert_int_equal(hlc_manager_stop(), F4D_OK);
    assert_int_equal(hlc_manager_count(), 0); /* still running */
    assert_int_equal(hlc_manager_stop(), F4D_OK);
    assert_int_equal(hlc_manager_refs(), 0);
    assert_int_equal(hlc_manager_stop(), F4D_ESTATE);
    assert_int_equal(hlc_manager_count(), F4D_ESTATE);

    /* and it can be started again after a full stop */
    if (hlc_manager_start(&err) < 0)
        fail_msg("restart: %s", err);
    assert_int_equal(hlc_manager_count(), 0);
    assert_int_equal(hlc_camera_acquire("/base/soc/i2c0mux/i2c@1/imx219@10", &cam, &err),
                     F4D_ENODEV);
    assert_null(cam);
    assert_int_equal(hlc_manager_stop(), F4D_OK);
}

/* A board with one libcamera camera and the usb host-tick trigger. */
static void libcamera_board(struct hal_board *b, const char *id)
{
    struct f4d_err err = {0};
    assert_int_equal(hal_board_load(b, F4D_BOARD_DIR "/usb-2cam.json", &err), 0);
    b->n_cams = 1;
    snprintf(b->cams[0].backend, sizeof b->cams[0].backend, "libcamera");
    snprintf(b->cams[0].address, sizeof b->cams[0].address, "%s", id);
}

static void registry_and_board(void **state)
{
    (void)state;
    const struct hal_backend *be = hal_backend_find("libcamera");
    assert_non_null(be);
    assert_non_null(be->camera_open);
    assert_null(be->trigger_open); /* cameras only */

    /* the board parser accepts "libcamera" as a camera backend, not as a trigger */
    struct f4d_err err = {0};
    struct hal_board b;
    const char *json = "{\"name\":\"csi\",\"cameras\":[{\"id\":\"cam0\",\"backend\":\"libcamera\","
                       "\"address\":\"/base/soc/i2c0mux/i2c@1/imx219@10\",\"width\":640,\"height\":480}],"
                       "\"trigger\":{\"backend\":\"usb\",\"rate_hz\":30}}";
    if (hal_board_parse(&b, json, strlen(json), &err) < 0)
        fail_msg("%s", err);
    assert_string_equal(b.cams[0].backend, "libcamera");
    assert_string_equal(b.cams[0].address, "/base/soc/i2c0mux/i2c@1/imx219@10");
    const char *bad = "{\"name\":\"csi\",\"cameras\":[{\"id\":\"cam0\",\"backend\":\"sim\"}],"
                      "\"trigger\":{\"backend\":\"libcamera\"}}";
    assert_int_equal(hal_board_parse(&b, bad, strlen(bad), &err), F4D_EINVAL);
    assert_non_null(strstr(err.msg, "unknown backend \"libcamera\""));
}

static void open_missing_camera(void **state)
{
    (void)state;
    struct hal_board b;
    struct hal_rig rig;
    struct f4d_err err = {0};
    libcamera_board(&b, "/base/soc/i2c0mux/i2c@1/imx219@10");
    assert_int_equal(hal_rig_open(&rig, &b, &err), F4D_ENODEV);
    printf("[ libcamera ] %s\n", err.msg);
    /* names the board camera, the id asked for, and what does exist */
    assert_non_null(strstr(err.msg, "cam0"));
    assert_non_null(strstr(err.msg, "\"/base/soc/i2c0mux/i2c@1/imx219@10\""));
    assert_non_null(strstr(err.msg, "no cameras"));
    /* the failed rig released its reference on the manager */
    assert_int_equal(hlc_manager_refs(), 0);

    libcamera_board(&b, "");
    assert_int_equal(hal_rig_open(&rig, &b, &err), F4D_EINVAL);
    assert_non_null(strstr(err.msg, "no camera id"));
    assert_int_equal(hlc_manager_refs(), 0);

    /* twice in a row: the manager is stopped and started again each time */
    libcamera_board(&b, "nope");
    assert_int_equal(hal_rig_open(&rig, &b, &err), F4D_ENODEV);
    assert_non_null(strstr(err.msg, "\"nope\""));
    assert_int_equal(hlc_manager_refs(), 0);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(manager_lifetime),
        cmocka_unit_test(registry_and_board),
        cmocka_unit_test(open_missing_camera),
    };
    return cmocka_run_group_tests_name("hal/libcamera", tests, NULL, NULL);
}
