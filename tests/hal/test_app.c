/* test_app.c: the `forge4d` command end to end: record from the faulty sim
 * board, stats JSON (exact keys, counted == injected), verify --json, the
 * contact sheet, replay, and the error paths. argv[1] is the forge4d binary. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>

#include <cjson/cJSON.h>
#include <fcntl.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/wait.h>
#include <unistd.h>

static const char *forge4d;
static char tmp[256];

/* Runs a shell command; returns the exit status, stdout in out (if given). */
static int run(char *out, size_t cap, const char *fmt, ...)
{
    char cmd[2048];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(cmd, sizeof cmd, fmt, ap);
    va_end(ap);
    FILE *p = popen(cmd, "r");
    assert_non_null(p);
    size_t n = 0;
    char sink[4096];
    char *dst = out ? out : sink;
    size_t dcap = out ? cap : sizeof sink;
    while (n + 1 < dcap) {
        size_t r = fread(dst + n, 1, dcap - 1 - n, p);
        if (r == 0)
            break;
        n += r;
    }
    dst[n] = 0;
    int st = pclose(p);
    return WIFEXITED(st) ? WEXITSTATUS(st) : -1;
}

static cJSON *read_json(const char *path)
{
    FILE *f = fopen(path, "r");
    assert_non_null(f);
    char buf[8192];
    size_t n = fread(buf, 1, sizeof buf - 1, f);
    fclose(f);
    buf[n] = 0;
    cJSON *j = cJSON_Parse(buf);
    assert_non_null(j);
    return j;
}

static double num(const cJSON *o, const char *key)
{
    const cJSON *v = cJSON_GetObjectItemCaseSensitive(o, key);
    if (!cJSON_IsNumber(v))
        fail_msg("stats: \"%s\" missing or not a number", key);
    return v->valuedouble;
}

static void record_verify_sheet_replay(void **state)
{
    (void)state;
    char out[4096];
    int rc = run(NULL, 0,
                 "%s record --board %s/sim-4cam-faulty.json --frames 300 --fast --quiet -o %s/take "
                 "--stats-json %s/stats.json --sheet %s/sheet.png 2>&1",
                 forge4d, F4D_BOARD_DIR, tmp, tmp, tmp);
    assert_int_equal(rc, 0);
    char path[512];
    snprintf(path, sizeof path, "%s/stats.json", tmp);
    cJSON *st = read_json(path);
    /* exactly the keys of the issue, in order */
    static const char *const keys[] = {"triggers", "sets_complete", "sets_incomplete", "frames_dropped",
                                       "frames_late", "frames_duplicate", "frames_incomplete",
                                       "mixed_sets", "injected"};
    int k = 0;
    for (const cJSON *it = st->child; it; it = it->next, k++) {
        assert_true(k < 9);
        assert_string_equal(it->string, keys[k]);
    }
    assert_int_equal(k, 9);
    const cJSON *inj = cJSON_GetObjectItemCaseSensitive(st, "injected");
    assert_true(cJSON_IsObject(inj));
    static const char *const frames[] = {"frames_dropped", "frames_late", "frames_duplicate",
                                         "frames_incomplete"};
    for (int i = 0; i < 4; i++)
        if (num(st, frames[i]) != num(inj, frames[i]))
            fail_msg("%s: counted %g, injected %g", frames[i], num(st, frames[i]), num(inj, frames[i]));
    assert_true(num(st, "frames_dropped") > 0);
    assert_true(num(st, "mixed_sets") == 0);
    double sets = num(st, "sets_complete") + num(st, "sets_incomplete");
    assert_true(sets == num(st, "triggers"));

    /* verify: every set (policy "mark" writes incomplete ones too), clean */
    rc = run(out, sizeof out, "%s verify %s/take --json", forge4d, tmp);
    assert_int_equal(rc, 0);
    cJSON *v = cJSON_Parse(out);
    assert_non_null(v);
    assert_true(num(v, "sets") == sets);
    assert_true(num(v, "corrupt") == 0);
    assert_true(num(v, "repaired") == 0);
    cJSON_Delete(v);

    /* the contact sheet is a PNG */
    snprintf(path, sizeof path, "%s/sheet.png", tmp);
    FILE *f = fopen(path, "rb");
    assert_non_null(f);
    unsigned char sig[8];
    assert_int_equal(fread(sig, 1, 8, f), 8);
    fclose(f);
    assert_memory_equal(sig, "\x89PNG\r\n\x1a\n", 8);

    /* replay: the same sets come back through the synchronizer */
    rc = run(NULL, 0, "%s replay %s/take --fast --stats-json %s/replay.json 2>/dev/null", forge4d, tmp, tmp);
    assert_int_equal(rc, 0);
    snprintf(path, sizeof path, "%s/replay.json", tmp);
    cJSON *rp = read_json(path);
    assert_true(cJSON_IsNull(cJSON_GetObjectItemCaseSensitive(rp, "injected")));
    assert_true(num(rp, "sets_complete") == num(st, "sets_complete"));
    assert_true(num(rp, "mixed_sets") == 0);
    cJSON_Delete(rp);
    cJSON_Delete(st);

    /* a corrupted record: verify says so and exits 3 */
    snprintf(path, sizeof path, "%s/take/take.f4t", tmp);
    int fd = open(path, O_RDWR);
    assert_true(fd >= 0);
    off_t end = lseek(fd, 0, SEEK_END);
    unsigned char b;
    assert_int_equal(pread(fd, &b, 1, end / 2), 1);
    b ^= 0xFF;
    assert_int_equal(pwrite(fd, &b, 1, end / 2), 1);
    close(fd);
    rc = run(out, sizeof out, "%s verify %s/take --json", forge4d, tmp);
    assert_int_equal(rc, 3);
    assert_non_null(strstr(out, "\"corrupt\": 1"));
}

static void errors(void **state)
{
    (void)state;
    char out[4096];
    assert_int_equal(run(out, sizeof out, "%s 2>&1", forge4d), 2);
    assert_non_null(strstr(out, "usage"));
    assert_int_equal(run(out, sizeof out, "%s record --frames 10 -o %s/x 2>&1", forge4d, tmp), 2);
    assert_non_null(strstr(out, "need --board"));
    assert_int_equal(run(out, sizeof out, "%s record --board %s/nope.json --frames 10 -o %s/x 2>&1",
                         forge4d, tmp, tmp),
                     1);
    assert_non_null(strstr(out, "nope.json"));
    assert_int_equal(run(out, sizeof out, "%s record --board %s/sim-4cam.json --frames -3 -o %s/x 2>&1",
                         forge4d, F4D_BOARD_DIR, tmp),
                     2);
    assert_non_null(strstr(out, "--frames"));
    /* an existing take is never overwritten */
    assert_int_equal(run(out, sizeof out,
                         "%s record --board %s/sim-4cam-faulty.json --frames 5 --fast --quiet -o %s/take 2>&1",
                         forge4d, F4D_BOARD_DIR, tmp),
                     1);
    assert_non_null(strstr(out, "take.f4t"));
    assert_int_equal(run(out, sizeof out, "%s verify %s/missing 2>&1", forge4d, tmp), 1);
    assert_non_null(strstr(out, "missing"));
}

static int setup(void **state)
{
    (void)state;
    snprintf(tmp, sizeof tmp, "/tmp/f4d_test_app_XXXXXX");
    return mkdtemp(tmp) ? 0 : -1;
}

static int teardown(void **state)
{
    (void)state;
    char cmd[300];
    snprintf(cmd, sizeof cmd, "rm -rf '%s'", tmp);
    return system(cmd) == 0 ? 0 : -1;
}

int main(int argc, char **argv)
{
    if (argc < 2) {
        fprintf(stderr, "usage: test_app PATH/TO/forge4d\n");
        return 2;
    }
    forge4d = argv[1];
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(record_verify_sheet_replay),
        cmocka_unit_test(errors),
    };
    return cmocka_run_group_tests_name("firmware/app", tests, setup, teardown);
}
