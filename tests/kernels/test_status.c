/* test_status.c: the one status space (f4d_status.h): names, numbers that
 * never change, struct f4d_err through f4d_fail / f4d_err_prefix, and the
 * abort hook of F4D_ASSERT (run in a child process: it must not return). */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>

#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/wait.h>
#include <unistd.h>

#include "f4d_status.h"

static void test_numbers_and_names(void **state)
{
    (void)state;
    /* stored in logs and test expectations: never renumbered */
    static const struct { int code; const char *name; } table[] = {
        {F4D_OK, "F4D_OK"},           {F4D_EINVAL, "F4D_EINVAL"},   {F4D_ENOMEM, "F4D_ENOMEM"},
        {F4D_EIO, "F4D_EIO"},         {F4D_ETIMEDOUT, "F4D_ETIMEDOUT"},
        {F4D_ENODEV, "F4D_ENODEV"},   {F4D_ENOTSUP, "F4D_ENOTSUP"}, {F4D_EBUSY, "F4D_EBUSY"},
        {F4D_ESTATE, "F4D_ESTATE"},   {F4D_EEOF, "F4D_EEOF"},       {F4D_ECORRUPT, "F4D_ECORRUPT"},
        {F4D_EFORMAT, "F4D_EFORMAT"}, {F4D_ENOENT, "F4D_ENOENT"},   {F4D_ETYPE, "F4D_ETYPE"},
        {F4D_ERANGE, "F4D_ERANGE"},
    };
    for (int i = 0; i < (int)(sizeof table / sizeof table[0]); i++) {
        assert_int_equal(table[i].code, -i);
        assert_string_equal(f4d_status_name(table[i].code), table[i].name);
    }
    assert_string_equal(f4d_status_name(1), "F4D_EUNKNOWN");
    assert_string_equal(f4d_status_name(-15), "F4D_EUNKNOWN");
    assert_string_equal(f4d_status_name(-100000), "F4D_EUNKNOWN");
}

static void test_fail_and_prefix(void **state)
{
    (void)state;
    struct f4d_err e = {0};
    assert_int_equal(f4d_fail(&e, F4D_EFORMAT, "tensor '%s': %d dims", "blk.0.w", 5), F4D_EFORMAT);
    assert_int_equal(e.code, F4D_EFORMAT);
    assert_string_equal(e.msg, "tensor 'blk.0.w': 5 dims");
    f4d_err_prefix(&e, "model %s", "tiny");
    assert_string_equal(e.msg, "model tiny: tensor 'blk.0.w': 5 dims");
    assert_int_equal(e.code, F4D_EFORMAT);
    /* NULL err: the code still comes back */
    assert_int_equal(f4d_fail(NULL, F4D_EIO, "x"), F4D_EIO);
    f4d_err_prefix(NULL, "y");
    /* a message longer than the buffer is cut, never overrun */
    char big[600];
    memset(big, 'a', sizeof big - 1);
    big[sizeof big - 1] = '\0';
    f4d_fail(&e, F4D_EINVAL, "%s", big);
    assert_int_equal(strlen(e.msg), F4D_ERR_MAX - 1);
    f4d_err_prefix(&e, "%s", big);
    assert_true(strlen(e.msg) < F4D_ERR_MAX);
}

static void hook_exit(const char *file, int line, const char *expr)
{
    /* the hook sees where and what, and may end the process its own way */
    fprintf(stderr, "hook: %s:%d %s\n", strrchr(file, '/') ? strrchr(file, '/') + 1 : file, line, expr);
    _exit(strcmp(expr, "1 + 1 == 3") == 0 ? 42 : 43);
}

static int child_status(void (*body)(void))
{
    fflush(NULL);
    pid_t pid = fork();
    assert_true(pid >= 0);
    if (pid == 0) {
        body();
        _exit(0); /* reached only if the assertion returned */
    }
    int st = 0;
    assert_int_equal(waitpid(pid, &st, 0), pid);
    return st;
}

static void body_hooked(void)
{
    f4d_set_abort_hook(hook_exit);
    F4D_ASSERT(2 + 2 == 4); /* holds: nothing happens */
    F4D_ASSERT(1 + 1 == 3);
}

static void body_default(void)
{
    f4d_set_abort_hook(NULL);
    F4D_ASSERT(sizeof(int) == 1);
}

static void test_assert_hook(void **state)
{
    (void)state;
    int st = child_status(body_hooked);
    assert_true(WIFEXITED(st));
    assert_int_equal(WEXITSTATUS(st), 42);
    st = child_status(body_default);
    assert_true(WIFSIGNALED(st));
    assert_int_equal(WTERMSIG(st), SIGABRT);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_numbers_and_names),
        cmocka_unit_test(test_fail_and_prefix),
        cmocka_unit_test(test_assert_hook),
    };
    return cmocka_run_group_tests_name("f4d_status", tests, NULL, NULL);
}
