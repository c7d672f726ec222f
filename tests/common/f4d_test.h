/* f4d_test.h: the shared main of the cmocka test binaries, so that ctest sees
 * a skip as a skip.
 *
 *   test_x [--case GLOB]... [--not GLOB]... [--list] [test's own arguments]
 *
 * --case keeps only the cases whose name matches one of the GLOBs (fnmatch),
 * --not drops the matching ones; a selection that keeps nothing is an error
 * (exit 2), so a misspelt case name in CMake cannot make an empty, passing
 * test. Exit status: 0 all selected cases passed, 1 a case failed, 77 none
 * failed but at least one was skipped (ctest: SKIP_RETURN_CODE 77, which
 * f4d_add_test sets).
 *
 * A case skips through f4d_skip("why, naming what is missing"), never bare
 * skip(): the reason is printed on stderr ("[  SKIP    ] case: why") and
 * counted. Usage:
 *
 *   static void needs_data(void **state) {
 *       if (access(path, R_OK) != 0)
 *           f4d_skip("%s is absent", path);
 *       ...
 *   }
 *   int main(int argc, char **argv) {
 *       const struct CMUnitTest tests[] = { cmocka_unit_test(needs_data) };
 *       return F4D_TEST_MAIN(argc, argv, "group", tests, NULL, NULL);
 *   }
 */
#ifndef F4D_TEST_H
#define F4D_TEST_H

#include <setjmp.h>
#include <stdarg.h>
#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>

#define F4D_TEST_SKIPPED 77

/* Prints why and counts the skip (use f4d_skip, which then leaves the case). */
void f4d_test_note_skip(const char *fmt, ...) __attribute__((format(printf, 1, 2)));
#define f4d_skip(...)                      \
    do {                                   \
        f4d_test_note_skip(__VA_ARGS__);   \
        skip();                            \
    } while (0)

/* Removes the --case/--not/--list options from argv (so the test can read its
 * own arguments afterwards, argv[1]...) and records the selection; returns the
 * new argc, or -1 on a bad option (message printed). Called by f4d_test_run
 * when the test did not call it first. */
int f4d_test_parse(int argc, char **argv);
/* True when the case `name` is selected (for work only some cases need, e.g.
 * a network namespace made in main before any thread exists). */
bool f4d_test_selected(const char *name);
int f4d_test_run(int argc, char **argv, const char *group, const struct CMUnitTest *tests, size_t n,
                 CMFixtureFunction setup, CMFixtureFunction teardown);
#define F4D_TEST_MAIN(argc, argv, group, tests, setup, teardown) \
    f4d_test_run(argc, argv, group, tests, sizeof(tests) / sizeof((tests)[0]), setup, teardown)

/* A path of a fresh directory for the test's files (mkdtemp under $TMPDIR or
 * /tmp, tag in the name), and its recursive removal. Return 0 / -1. */
int f4d_test_mkdtemp(char *out, size_t n, const char *tag);
int f4d_test_rmtree(const char *dir);

/* Loopback UDP ports for tests that ctest runs side by side (-j): each test
 * owns a range [first, first + count) of its own below the kernel's ephemeral
 * ports (32768 and up, where SRT callers bind), disjoint from every other
 * test's (tests/common/f4d_ports.sh lists them). Returns a base b such that
 * b .. b + n - 1 are all free on 127.0.0.1 now (probed by binding), starting
 * the search at an offset from the pid so that two runs of one test start
 * apart; -1 when the whole range is taken. */
int f4d_test_udp_ports(int first, int count, int n);
/* Waits until something listens on UDP `port` (/proc/net/udp and udp6): true
 * once it does; false when `pid` (if > 0) exited first or after `seconds`. An
 * event to wait on instead of a sleep before calling a listener that another
 * process opens. */
bool f4d_test_wait_udp(int port, int pid, int seconds);

#endif
