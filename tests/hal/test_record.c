/* test_record.c: the take format: round trip, CRC catching corruption, torn
 * tails, lost index, a slow disk, and the recorder killed (SIGKILL) at
 * random points. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>

#include <fcntl.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

#include "f4d_capture.h"
#include "f4d_take.h"
#include "hal_board.h"
#include "hal_registry.h"
#include "hal_sim.h"

static char tmp_root[256];

static int setup(void **state)
{
    (void)state;
    snprintf(tmp_root, sizeof tmp_root, "/tmp/f4d_test_record_XXXXXX");
    return mkdtemp(tmp_root) ? 0 : -1;
}

static int teardown(void **state)
{
    (void)state;
    char cmd[300];
    snprintf(cmd, sizeof cmd, "rm -rf '%s'", tmp_root);
    return system(cmd) == 0 ? 0 : -1;
}

static uint64_t now_ns(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (uint64_t)ts.tv_sec * 1000000000u + (uint64_t)ts.tv_nsec;
}

/* ---- a small simulated recording ---- */
struct rec {
    struct f4d_take_writer *w;
    const struct hal_board *board;
    const char *dir;
    uint32_t durability_ms;
    /* crash test: shared with the parent */
    volatile uint64_t *shared; /* [0] appended, [1] durable, [2 + i] append time of set i */
    uint64_t shared_max;
};

static int rec_ready(void *user, const struct f4d_capture_stats *st)
{
    struct rec *r = user;
    struct f4d_take_info info = {0};
    info.n_cams = r->board->n_cams;
    info.rate_mhz = r->board->trigger.rate_mhz;
    for (uint32_t i = 0; i < info.n_cams; i++) {
        info.formats[i] = st->formats[i];
        snprintf(info.cam_ids[i], sizeof info.cam_ids[i], "cam%u", (unsigned)i);
    }
    struct f4d_err err = {0};
    int rc = f4d_take_create(&r->w, r->dir, &info, "{}", r->durability_ms, &err);
    if (rc < 0)
        fprintf(stderr, "%s\n", err.msg);
    return rc;
}

static int rec_set(void *user, const struct hal_set *set)
{
    struct rec *r = user;
    int rc = f4d_take_append(r->w, set);
    if (r->shared) {
        uint64_t n = f4d_take_sets_written(r->w);
        if (n + 2 < r->shared_max)
            r->shared[n + 1] = now_ns();
        r->shared[0] = n;
        r->shared[1] = f4d_take_durable_sets(r->w);
    }
    return rc;
}

static void sim_board(struct hal_board *b, uint32_t w, uint32_t h)
{
    struct f4d_err err = {0};
    assert_int_equal(hal_board_load(b, F4D_BOARD_DIR "/sim-4cam.json", &err), 0);
    b->sim.realtime = false;
    for (uint32_t i = 0; i < b->n_cams; i++) {
        b->cams[i].width = w;
        b->cams[i].height = h;
    }
}

/* A rig of 32 x 32 simulated cameras. */
static void sim_rig(struct hal_board *b, struct hal_rig *rig)
{
    struct f4d_err err = {0};
    sim_board(b, 32, 32);
    assert_int_equal(hal_rig_open(rig, b, &err), 0);
}

static void record(const char *dir, uint64_t triggers)
{
    struct hal_board b;
    struct hal_rig rig;
    struct f4d_err err = {0};
    sim_rig(&b, &rig);
    struct rec r = {NULL, &b, dir, 50, NULL, 0};
    struct f4d_capture_config cfg = {.triggers = triggers, .on_ready = rec_ready};
    struct f4d_capture_stats st;
    assert_int_equal(f4d_capture_run(&rig, &cfg, rec_set, NULL, &r, NULL, &st, &err), 0);
    assert_int_equal(f4d_take_close(r.w, &err), 0);
    hal_rig_close(&rig);
}

static void take_path(char *out, size_t n, const char *dir, const char *file)
{
    snprintf(out, n, "%s/%s", dir, file);
}

static off_t file_size(const char *path)
{
    struct stat st;
    assert_int_equal(stat(path, &st), 0);
    return st.st_size;
}

static void round_trip(void **state)
{
    (void)state;
    char dir[300];
    snprintf(dir, sizeof dir, "%s/rt/parents/made", tmp_root); /* mkdir -p */
    record(dir, 20);
    struct f4d_take_reader *r;
    struct f4d_err err = {0};
    assert_int_equal(f4d_take_open(&r, dir, &err), 0);
    assert_int_equal(f4d_take_count(r), 20);
    assert_int_equal(f4d_take_get_info(r)->n_cams, 4);
    for (uint64_t i = 0; i < 20; i++) {
        struct f4d_take_set s;
        assert_int_equal(f4d_take_read(r, i, &s), 0);
        assert_int_equal(s.seq, i + 1);
        assert_true(s.complete);
        for (uint32_t c = 0; c < 4; c++) {
            uint64_t seq;
            uint32_t cam;
            assert_true(s.frames[c].present);
            assert_int_equal(s.frames[c].bytes, 32 * 32 * 3);
            assert_int_equal(hal_sim_stamp_read(s.frames[c].data, s.frames[c].bytes, &seq, &cam), 0);
            assert_int_equal(seq, s.seq);
            assert_int_equal(cam, c);
        }
    }
    assert_int_equal(f4d_take_read(r, 20, &(struct f4d_take_set){0}), F4D_EINVAL);
    f4d_take_reader_close(r);
    struct f4d_take_report rep;
    assert_int_equal(f4d_take_verify(dir, true, &rep, &err), 0);
    assert_int_equal(rep.sets, 20);
    assert_int_equal(rep.corrupt, 0);
    assert_int_equal(rep.repaired, 0);
    assert_int_equal(rep.truncated_bytes, 0);
    assert_true(rep.clean_end);
    assert_false(rep.index_rebuilt);
    /* an existing take is never overwritten */
    struct f4d_take_writer *w;
    struct f4d_take_info info = {.n_cams = 1};
    assert_int_equal(f4d_take_create(&w, dir, &info, NULL, 10, &err), F4D_EIO);
    assert_non_null(strstr(err.msg, "take.f4t"));
}

static void flip_byte(const char *path, off_t off)
{
    int fd = open(path, O_RDWR);
    assert_true(fd >= 0);
    uint8_t b;
    assert_int_equal(pread(fd, &b, 1, off), 1);
    b ^= 0x5A;
    assert_int_equal(pwrite(fd, &b, 1, off), 1);
    close(fd);
}

static void crc_catches_corruption(void **state)
{
    (void)state;
    char dir[300], path[340];
    snprintf(dir, sizeof dir, "%s/crc", tmp_root);
    record(dir, 10);
    take_path(path, sizeof path, dir, F4D_TAKE_FILE);
    off_t size = file_size(path);
    /* records: info (16 + 16 + 4 x 56 + 4 bytes), 10 sets of equal size, end (28 bytes) */
    const off_t info_bytes = 260;
    off_t set_bytes = (size - 28 - info_bytes) / 10;
    assert_int_equal(info_bytes + 10 * set_bytes + 28, size);
    struct f4d_take_reader *r;
    struct f4d_err err = {0};
    assert_int_equal(f4d_take_open(&r, dir, &err), 0);
    f4d_take_reader_close(r);
    /* corrupt one pixel deep inside set 5 */
    flip_byte(path, info_bytes + 5 * set_bytes + set_bytes / 2);
    assert_int_equal(f4d_take_open(&r, dir, &err), 0);
    int bad = 0;
    for (uint64_t i = 0; i < f4d_take_count(r); i++) {
        struct f4d_take_set s;
        int rc = f4d_take_read(r, i, &s);
        assert_true(rc == F4D_OK || rc == F4D_ECORRUPT);
        bad += rc == F4D_ECORRUPT;
    }
    f4d_take_reader_close(r);
    assert_int_equal(bad, 1);
    struct f4d_take_report rep;
    assert_int_equal(f4d_take_verify(dir, true, &rep, &err), 0);
    assert_int_equal(rep.sets, 9);
    assert_int_equal(rep.corrupt, 1);
    assert_int_equal(rep.truncated_bytes, 0);
    assert_true(rep.clean_end);
    /* a damaged record header: the scan resynchronises on the next record */
    flip_byte(path, info_bytes + 8 * set_bytes + 9); /* set 8's length field */
    assert_int_equal(f4d_take_verify(dir, false, &rep, &err), 0);
    assert_int_equal(rep.sets, 8);
    assert_int_equal(rep.corrupt, 2);
    assert_true(rep.clean_end);
}

static void torn_tail_and_lost_index(void **state)
{
    (void)state;
    char dir[300], path[340], idx[340];
    snprintf(dir, sizeof dir, "%s/torn", tmp_root);
    record(dir, 12);
    take_path(path, sizeof path, dir, F4D_TAKE_FILE);
    take_path(idx, sizeof idx, dir, F4D_TAKE_INDEX);
    off_t size = file_size(path);
    /* cut the end record and half of the last set: what a crash mid-write leaves */
    off_t set_bytes = (size - 28 - 260) / 12;
    assert_int_equal(truncate(path, size - 28 - set_bytes / 2), 0);
    assert_int_equal(unlink(idx), 0);
    struct f4d_take_reader *r;
    struct f4d_err err = {0};
    assert_int_equal(f4d_take_open(&r, dir, &err), 0); /* scans without an index */
    assert_int_equal(f4d_take_count(r), 11);
    f4d_take_reader_close(r);
    struct f4d_take_report rep;
    assert_int_equal(f4d_take_verify(dir, true, &rep, &err), 0);
    assert_int_equal(rep.sets, 11);
    assert_int_equal(rep.repaired, 11);
    assert_true(rep.truncated_bytes > 0);
    assert_false(rep.clean_end);
    assert_true(rep.index_rebuilt);
    /* idempotent: a second verify finds nothing to do */
    assert_int_equal(f4d_take_verify(dir, true, &rep, &err), 0);
    assert_int_equal(rep.sets, 11);
    assert_int_equal(rep.repaired, 0);
    assert_int_equal(rep.truncated_bytes, 0);
    assert_false(rep.index_rebuilt);
    /* garbage is not a take */
    char gdir[300];
    snprintf(gdir, sizeof gdir, "%s/garbage", tmp_root);
    assert_int_equal(mkdir(gdir, 0755), 0);
    take_path(path, sizeof path, gdir, F4D_TAKE_FILE);
    FILE *f = fopen(path, "w");
    fputs("this is not a take", f);
    fclose(f);
    assert_int_equal(f4d_take_verify(gdir, true, &rep, &err), F4D_ECORRUPT);
    assert_non_null(strstr(err.msg, "no valid take header"));
}

/* Appends like rec_set; after the first set it waits past the durability
 * window, so the writer's fdatasync is running while the rest go in. */
struct slow_rec {
    struct rec rec;
    uint64_t t_rest; /* when the sets after the first began */
};

static int slow_set(void *user, const struct hal_set *set)
{
    struct slow_rec *s = user;
    int rc = rec_set(&s->rec, set);
    if (f4d_take_sets_written(s->rec.w) == 1) {
        usleep(100000);
        s->t_rest = now_ns();
    }
    return rc;
}

/* A disk whose fdatasync takes 2 s (the writer's test knob): appends do not
 * wait for it (it runs on the writer's thread), durability lags meanwhile
 * and catches up at close. Had the appender synced inline, its first append
 * after the window would have held it for the whole 2 s. */
static void slow_disk_does_not_block_appends(void **state)
{
    (void)state;
    enum { SETS = 200 };
    const uint64_t delay_ns = 2000000000u;
    char dir[300];
    snprintf(dir, sizeof dir, "%s/slow", tmp_root);
    setenv("F4D_TAKE_TEST_SYNC_DELAY_MS", "2000", 1);
    struct hal_board b;
    struct hal_rig rig;
    struct f4d_err err = {0};
    sim_rig(&b, &rig);
    struct slow_rec r = {{NULL, &b, dir, 20, NULL, 0}, 0};
    struct f4d_capture_config cfg = {.triggers = SETS, .on_ready = rec_ready};
    struct f4d_capture_stats st;
    assert_int_equal(f4d_capture_run(&rig, &cfg, slow_set, NULL, &r, NULL, &st, &err), 0);
    uint64_t took = now_ns() - r.t_rest;
    unsetenv("F4D_TAKE_TEST_SYNC_DELAY_MS");
    uint64_t durable = f4d_take_durable_sets(r.rec.w);
    assert_int_equal(f4d_take_sets_written(r.rec.w), SETS);
    if (took >= delay_ns)
        fail_msg("%d appends took %.2f s: they waited for the 2 s fdatasync", SETS - 1, (double)took / 1e9);
    assert_int_equal(durable, 0); /* the first fdatasync (of set 1) has not returned */
    uint64_t t1 = now_ns();
    assert_int_equal(f4d_take_close(r.rec.w, &err), 0); /* waits for the sync in flight */
    uint64_t closing = now_ns() - t1;
    assert_true(closing > delay_ns / 2); /* the sync began within 0.1 s of the first set */
    hal_rig_close(&rig);
    struct f4d_take_report rep;
    assert_int_equal(f4d_take_verify(dir, false, &rep, &err), 0);
    assert_int_equal(rep.sets, SETS);
    assert_true(rep.clean_end);
    printf("[ slow disk ] %d appends in %.3f s while a 2 s fdatasync ran; close waited %.2f s for it\n", SETS - 1,
           (double)took / 1e9, (double)closing / 1e9);
}

/* Appends with 2 ms between sets (a background sync every ~5 with a 10 ms
 * window) until the writer refuses one. */
struct failing_rec {
    struct rec rec;
    uint64_t appended;       /* accepted appends */
    int refused;             /* the first refusal's status */
    uint64_t durable_before; /* durable sets when it came */
};

static int failing_set(void *user, const struct hal_set *set)
{
    struct failing_rec *f = user;
    usleep(2000);
    int rc = f4d_take_append(f->rec.w, set);
    if (rc < 0) {
        f->refused = rc;
        f->durable_before = f4d_take_durable_sets(f->rec.w);
        return rc;
    }
    f->appended++;
    return 0;
}

/* A disk whose third fdatasync fails (the writer's test knob: a dying eMMC
 * reports EIO on the flush): the syncer marks the writer failed, the next
 * append is refused with F4D_EIO (`forge4d run` then stops the take and
 * streams on), close names the fdatasync error and writes no end record, and
 * every set acknowledged durable before the failure reads back. */
static void failed_fdatasync_stops_the_take(void **state)
{
    (void)state;
    enum { TRIGGERS = 1000 };
    char dir[300];
    snprintf(dir, sizeof dir, "%s/syncfail", tmp_root);
    setenv("F4D_TAKE_TEST_SYNC_FAIL_AFTER", "2", 1);
    struct hal_board b;
    struct hal_rig rig;
    struct f4d_err err = {0};
    sim_rig(&b, &rig);
    struct failing_rec f = {{NULL, &b, dir, 10, NULL, 0}, 0, 0, 0};
    struct f4d_capture_config cfg = {.triggers = TRIGGERS, .on_ready = rec_ready};
    struct f4d_capture_stats st;
    int rc = f4d_capture_run(&rig, &cfg, failing_set, NULL, &f, NULL, &st, &err);
    unsetenv("F4D_TAKE_TEST_SYNC_FAIL_AFTER");
    hal_rig_close(&rig);
    assert_int_equal(rc, F4D_EIO);
    assert_non_null(strstr(err.msg, "set consumer failed"));
    assert_int_equal(f.refused, F4D_EIO);
    assert_true(f.appended < TRIGGERS);
    assert_true(f.durable_before >= 2); /* two syncs went through first */
    assert_true(f.durable_before <= f.appended);
    /* refused from then on */
    struct f4d_err cerr = {0};
    assert_int_equal(f4d_take_close(f.rec.w, &cerr), F4D_EIO);
    assert_non_null(strstr(cerr.msg, "fdatasync: Input/output error"));
    struct f4d_take_report rep;
    assert_int_equal(f4d_take_verify(dir, true, &rep, &err), 0);
    assert_false(rep.clean_end);
    assert_true(rep.sets >= f.durable_before);
    printf("[ failed sync ] %llu sets appended, %llu durable when the third fdatasync failed; %llu read back\n",
           (unsigned long long)f.appended, (unsigned long long)f.durable_before, (unsigned long long)rep.sets);
}

/* The recorder is SIGKILLed at random points; verify must recover every set
 * that was appended longer than the durability window before the kill, and
 * every set the writer had reported durable. */
static void killed_at_random_points(void **state)
{
    (void)state;
    enum { ROUNDS = 24, SHARED = 1 << 16 };
    const uint32_t durability_ms = 20;
    uint64_t rng = 0x1234567;
    uint64_t torn = 0, total_recovered = 0;
    for (int round = 0; round < ROUNDS; round++) {
        char dir[300];
        snprintf(dir, sizeof dir, "%s/crash%02d", tmp_root, round);
        volatile uint64_t *sh = mmap(NULL, SHARED * sizeof(uint64_t), PROT_READ | PROT_WRITE,
                                     MAP_SHARED | MAP_ANONYMOUS, -1, 0);
        assert_true(sh != MAP_FAILED);
        pid_t pid = fork();
        assert_true(pid >= 0);
        if (pid == 0) {
            struct hal_board b;
            sim_board(&b, 128, 128); /* 196 KB per set: kills land inside writes */
            /* simulated clock: the child is always rendering or writing, so kills
             * land inside writes; the writer's durability window is wall time */
            struct hal_rig rig;
            struct f4d_err err = {0};
            if (hal_rig_open(&rig, &b, &err) < 0)
                _exit(2);
            struct rec r = {NULL, &b, dir, durability_ms, sh, SHARED};
            struct f4d_capture_config cfg = {.on_ready = rec_ready};
            struct f4d_capture_stats st;
            f4d_capture_run(&rig, &cfg, rec_set, NULL, &r, NULL, &st, &err);
            _exit(3); /* never reached: runs until killed */
        }
        rng = rng * 6364136223846793005ull + 1442695040888963407ull;
        useconds_t wait_us = 30000 + (useconds_t)((rng >> 33) % 120000);
        usleep(wait_us);
        uint64_t t_kill = now_ns();
        kill(pid, SIGKILL);
        int status;
        waitpid(pid, &status, 0);
        assert_true(WIFSIGNALED(status));
        uint64_t appended = sh[0], durable = sh[1];
        uint64_t old_enough = 0;
        for (uint64_t i = 1; i <= appended && i + 1 < SHARED; i++)
            if (sh[i + 1] + (uint64_t)durability_ms * 1000000u + 50000000u < t_kill)
                old_enough = i;
        struct f4d_take_report rep;
        struct f4d_err err = {0};
        int rc = f4d_take_verify(dir, true, &rep, &err);
        if (rc < 0 && appended == 0) { /* killed before the header was durable */
            munmap((void *)sh, SHARED * sizeof(uint64_t));
            continue;
        }
        if (rc < 0)
            fail_msg("round %d: verify: %s", round, err);
        assert_int_equal(rep.corrupt, 0);
        assert_false(rep.clean_end);
        if (rep.sets < durable || rep.sets < old_enough || rep.sets > appended + 1)
            fail_msg("round %d: recovered %llu sets, appended %llu, durable %llu, older than the "
                     "window %llu",
                     round, (unsigned long long)rep.sets, (unsigned long long)appended,
                     (unsigned long long)durable, (unsigned long long)old_enough);
        torn += rep.truncated_bytes > 0;
        total_recovered += rep.sets;
        /* what verify recovered reads back, in order, with good CRCs */
        struct f4d_take_reader *r;
        assert_int_equal(f4d_take_open(&r, dir, &err), 0);
        assert_int_equal(f4d_take_count(r), rep.sets);
        for (uint64_t i = 0; i < rep.sets; i++) {
            struct f4d_take_set s;
            assert_int_equal(f4d_take_read(r, i, &s), 0);
            assert_int_equal(s.seq, i + 1);
        }
        f4d_take_reader_close(r);
        munmap((void *)sh, SHARED * sizeof(uint64_t));
        char cmd[340];
        snprintf(cmd, sizeof cmd, "rm -rf '%s'", dir);
        assert_int_equal(system(cmd), 0);
    }
    printf("[ crash ] %d kills: %llu sets recovered in total, %llu takes had a torn tail (truncated)\n",
           ROUNDS, (unsigned long long)total_recovered, (unsigned long long)torn);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(round_trip),
        cmocka_unit_test(crc_catches_corruption),
        cmocka_unit_test(torn_tail_and_lost_index),
        cmocka_unit_test(slow_disk_does_not_block_appends),
        cmocka_unit_test(failed_fdatasync_stops_the_take),
        cmocka_unit_test(killed_at_random_points),
    };
    return cmocka_run_group_tests_name("hal/take", tests, setup, teardown);
}
