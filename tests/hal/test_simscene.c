/* test_simscene.c: the sim cameras' synthetic-scene renderer (firmware/synth/simscene). */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>

#include <stdlib.h>
#include <string.h>

#include "f4d_simscene.h"

static void renders_the_scene_over_time(void **state)
{
    (void)state;
    struct f4d_simscene *ss;
    struct f4d_err err = {0};
    assert_int_equal(f4d_simscene_new(&ss, "walk", 1, 4, 64, 48, &err), 0);
    struct hal_format f = {HAL_PIXFMT_RGB8, 64, 48, 0, 30000, HAL_TRIGGER_HARDWARE, 1000, 0};
    assert_int_equal(hal_format_finish(&f), 0);
    uint8_t *a = malloc(f.image_bytes), *b = malloc(f.image_bytes), *c = malloc(f.image_bytes);
    assert_int_equal(f4d_simscene_render(ss, 0, 0, &f, a), 0);
    assert_int_equal(f4d_simscene_render(ss, 0, 500000000, &f, b), 0); /* 0.5 s later */
    assert_int_equal(f4d_simscene_render(ss, 2, 500000000, &f, c), 0); /* another view */
    size_t diff_t = 0, diff_v = 0, nonsky = 0;
    for (size_t i = 0; i < f.image_bytes; i++) {
        diff_t += a[i] != b[i];
        diff_v += b[i] != c[i];
        nonsky += a[i] != a[i % 3];
    }
    assert_true(nonsky > f.image_bytes / 20); /* figure and floor drawn */
    assert_true(diff_t > 50);                 /* the figure moved */
    assert_true(diff_v > 50);                 /* views differ */
    /* a size the renderer was not built for is refused (the sim then draws its pattern) */
    struct hal_format g = f;
    g.width = 32;
    g.stride = 0;
    assert_int_equal(hal_format_finish(&g), 0);
    assert_int_equal(f4d_simscene_render(ss, 0, 0, &g, a), F4D_EINVAL);
    assert_int_equal(f4d_simscene_render(ss, 9, 0, &f, a), F4D_EINVAL);
    free(a);
    free(b);
    free(c);
    f4d_simscene_free(ss);
    assert_int_equal(f4d_simscene_new(&ss, "moonwalk", 1, 4, 64, 48, &err), F4D_EINVAL);
    assert_non_null(strstr(err.msg, "moonwalk"));
}

int main(void)
{
    const struct CMUnitTest tests[] = {cmocka_unit_test(renders_the_scene_over_time)};
    return cmocka_run_group_tests_name("firmware/synth/simscene", tests, NULL, NULL);
}
