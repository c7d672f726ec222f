/* bench_hal.c - f4d-bench hal: capture-path throughput.
 *
 *   f4d-bench hal [--sets N] [--dir DIR] [--size W]
 *
 * 1. synchronizer alone: 4-camera sets per second from hand-fed frames;
 * 2. sim capture (simulated clock, procedural pattern, W x W RGB, 4 views)
 *    through the synchronizer: sets per second;
 * 3. recorder (take format: CRC32 per record, fdatasync every 250 ms) against
 *    its peer measured in the same run: plain write() of the same bytes with the
 *    same fdatasync cadence. Best of 3 runs each. */
#include <fcntl.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "bench.h"
#include "f4d_capture.h"
#include "f4d_take.h"
#include "hal_board.h"
#include "hal_registry.h"

static void null_set(void *u, const struct hal_set *s)
{
    (void)s;
    ++*(uint64_t *)u;
}
static void null_release(void *u, struct hal_buffer *b)
{
    (void)u;
    (void)b;
}

static double bench_sync(uint64_t n)
{
    struct f4d_sync s;
    uint64_t sets = 0;
    struct f4d_sync_config cfg = {4, 2000, 25000, HAL_INCOMPLETE_DROP, 8, 0};
    f4d_sync_init(&s, &cfg, null_set, null_release, &sets);
    struct hal_buffer b[4];
    memset(b, 0, sizeof b);
    double t0 = bench_now();
    for (uint64_t k = 1; k <= n; k++) {
        uint64_t t = k * 33333333u;
        struct hal_edge e = {k, t, 0, true};
        f4d_sync_edge(&s, &e);
        for (uint32_t c = 0; c < 4; c++) {
            b[c].camera_index = c;
            b[c].trigger_seq = k;
            b[c].device_ts_ns = t + 1000u * c + 1000000000u;
            b[c].host_ts_ns = t + 3000000u;
            f4d_sync_frame(&s, &b[c]);
        }
        f4d_sync_advance(&s, t + 3000000u);
    }
    double dt = bench_now() - t0;
    return sets == n ? (double)n / dt : -1.0;
}

struct rec_ctx {
    struct f4d_take_writer *w;
    const struct hal_board *board;
    const char *dir;
    int raw_fd; /* peer: plain write() */
    double last_sync;
    uint64_t bytes;
};

static int on_ready(void *u, const struct f4d_capture_stats *st)
{
    struct rec_ctx *r = u;
    if (!r->dir)
        return 0;
    struct f4d_take_info info = {.n_cams = r->board->n_cams, .rate_mhz = r->board->trigger.rate_mhz};
    for (uint32_t i = 0; i < info.n_cams; i++)
        info.formats[i] = st->formats[i];
    struct f4d_err err = {0};
    return f4d_take_create(&r->w, r->dir, &info, NULL, 250, &err);
}

static int on_set(void *u, const struct hal_set *set)
{
    struct rec_ctx *r = u;
    if (r->w)
        return f4d_take_append(r->w, set);
    if (r->raw_fd >= 0) {
        for (uint32_t c = 0; c < 4; c++) {
            const struct hal_buffer *b = set->frames[c];
            if (b && write(r->raw_fd, b->data, b->bytes_used) != (ssize_t)b->bytes_used)
                return -1;
            if (b)
                r->bytes += b->bytes_used;
        }
        if (bench_now() - r->last_sync >= 0.25) {
            fdatasync(r->raw_fd);
            r->last_sync = bench_now();
        }
    }
    return 0;
}

/* mode 0: capture only; 1: take writer; 2: raw write peer. Returns sets/s. */
static double bench_capture(const struct hal_board *board, uint64_t sets, const char *dir, int mode,
                            double *mb_s)
{
    struct hal_rig rig;
    struct f4d_err err = {0};
    if (hal_rig_open(&rig, board, &err) < 0) {
        fprintf(stderr, "f4d-bench hal: %s\n", err.msg);
        return -1;
    }
    char path[600];
    snprintf(path, sizeof path, "%s/f4d_bench_take", dir);
    char cmd[1400];
    snprintf(cmd, sizeof cmd, "rm -rf '%s' '%s.raw'", path, path);
    if (system(cmd) != 0)
        return -1;
    struct rec_ctx r = {NULL, board, mode == 1 ? path : NULL, -1, bench_now(), 0};
    if (mode == 2) {
        char raw[640];
        snprintf(raw, sizeof raw, "%s.raw", path);
        r.raw_fd = open(raw, O_WRONLY | O_CREAT | O_TRUNC | O_APPEND, 0644);
    }
    struct f4d_capture_config cfg = {.triggers = sets, .on_ready = on_ready};
    struct f4d_capture_stats st;
    double t0 = bench_now();
    int rc = f4d_capture_run(&rig, &cfg, on_set, NULL, &r, NULL, &st, &err);
    uint64_t bytes = r.bytes;
    if (r.w) {
        bytes = f4d_take_bytes_written(r.w);
        f4d_take_close(r.w, &err);
    }
    if (r.raw_fd >= 0) {
        fdatasync(r.raw_fd);
        close(r.raw_fd);
    }
    double dt = bench_now() - t0;
    hal_rig_close(&rig);
    if (system(cmd) != 0 || rc < 0)
        return -1;
    *mb_s = (double)bytes / 1e6 / dt;
    return (double)(st.sync.sets_complete) / dt;
}

int bench_hal(int argc, char **argv)
{
    uint64_t sets = 300;
    const char *dir = "/tmp";
    uint32_t size = 518;
    for (int i = 1; i < argc; i++) {
        if (!strcmp(argv[i], "--sets") && i + 1 < argc)
            sets = strtoull(argv[++i], NULL, 10);
        else if (!strcmp(argv[i], "--dir") && i + 1 < argc)
            dir = argv[++i];
        else if (!strcmp(argv[i], "--size") && i + 1 < argc)
            size = (uint32_t)strtoul(argv[++i], NULL, 10);
        else {
            fprintf(stderr, "usage: f4d-bench hal [--sets N] [--dir DIR] [--size W]\n");
            return 2;
        }
    }
    if (sets == 0 || size < 16) {
        fprintf(stderr, "f4d-bench hal: --sets must be > 0 and --size >= 16\n");
        return 2;
    }
    double best = 0;
    for (int k = 0; k < 3; k++) {
        double v = bench_sync(200000);
        best = v > best ? v : best;
    }
    printf("synchronizer alone      : %10.0f sets/s (4 cameras, hand-fed, best of 3)\n", best);

    struct hal_board b;
    hal_board_defaults(&b);
    b.n_cams = 4;
    b.sim.realtime = false;
    for (uint32_t i = 0; i < 4; i++) {
        b.cams[i].width = size;
        b.cams[i].height = size;
    }
    double cap = 0, rec = 0, raw = 0, rec_mb = 0, raw_mb = 0, mb;
    for (int k = 0; k < 3; k++) {
        double v = bench_capture(&b, sets, dir, 0, &mb);
        cap = v > cap ? v : cap;
        v = bench_capture(&b, sets, dir, 1, &mb);
        if (v > rec)
            rec = v, rec_mb = mb;
        v = bench_capture(&b, sets, dir, 2, &mb);
        if (v > raw)
            raw = v, raw_mb = mb;
    }
    if (cap <= 0 || rec <= 0 || raw <= 0) {
        fprintf(stderr, "f4d-bench hal: a run failed\n");
        return 1;
    }
    printf("sim capture + sync      : %10.1f sets/s (%ux%u RGB x4, pattern, simulated clock)\n", cap,
           (unsigned)size, (unsigned)size);
    printf("  + take writer         : %10.1f sets/s, %7.1f MB/s to %s (CRC32, fdatasync 250 ms)\n", rec,
           rec_mb, dir);
    printf("  + raw write() (peer)  : %10.1f sets/s, %7.1f MB/s (same bytes, same fdatasync cadence)\n", raw,
           raw_mb);
    printf("take writer / raw write : %10.2f (sets/s ratio)\n", rec / raw);
    return 0;
}
