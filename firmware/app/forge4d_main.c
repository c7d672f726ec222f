/* forge4d_main.c: the `forge4d` appliance command.
 *
 *   forge4d record --board FILE (--frames N | --seconds S) -o DIR
 *                  [--stats-json FILE] [--sheet PNG] [--fast] [--quiet]
 *   forge4d verify DIR [--json] [--no-repair]
 *   forge4d sheet DIR -o PNG [--set N]
 *   forge4d replay DIR [--fast] [--stats-json FILE]
 *   forge4d run [--board FILE | --replay TAKE] [--weights W] [--stream URL] ...
 *   forge4d report [--quick] -o DIR --take TAKE [--take TAKE ...] [--weights W]
 *
 * record: opens the board's rig, captures N trigger pulses (or S seconds),
 * writes every synchronized set to the take DIR as it arrives, prints a live
 * progress line (rate, drops, disk throughput) and, at the end, the stats
 * JSON. verify: checks every record's CRC, truncates a torn tail and rebuilds
 * the index after a crash. sheet: PNG contact sheet of one set. replay: runs a
 * take back through the synchronizer and prints the same stats. run: the
 * appliance daemon, capture to stream (run.c). report: the speed-vs-error
 * study on venue takes with ground truth (report.c).
 */
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#include <cjson/cJSON.h>

#include "contact_sheet.h"
#include "f4d_capture.h"
#include "f4d_simscene.h"
#include "f4d_take.h"
#include "hal_board.h"
#include "hal_registry.h"
#include "hal_replay.h"
#include "hal_sim.h"
#include "report_internal.h"
#include "run_internal.h"

/* SIGINT/SIGTERM: 1, finish the take and the stream cleanly; 2, a second
 * request (also one after --seconds or --keys ended the run): stop waiting
 * for a display that has not ended */
static volatile sig_atomic_t g_stop;

static void on_signal(int sig)
{
    (void)sig;
    g_stop = g_stop ? 2 : 1;
}

static int usage(void)
{
    fprintf(stderr,
            "usage:\n"
            "  forge4d record --board FILE (--frames N | --seconds S) -o DIR\n"
            "                 [--stats-json FILE] [--sheet PNG] [--fast] [--quiet]\n"
            "  forge4d verify DIR [--json] [--no-repair]\n"
            "  forge4d sheet DIR -o PNG [--set N]\n"
            "  forge4d replay DIR [--fast] [--stats-json FILE]\n"
            "  forge4d run [--board FILE | --replay TAKE] [--weights W] [--stream file:PATH]\n"
            "              [--record DIR] [--seconds S] [--stats-json FILE] [--precision P] (run --help)\n"
            "  forge4d report [--quick] -o DIR --take TAKE [--take TAKE ...] [--weights W] [--threads N]\n"
            "                 [--keys N]\n");
    return 2;
}

struct rec_ctx {
    const struct hal_board *board;
    const char *dir;
    struct f4d_take_writer *w;
    bool sim, quiet, tty;
    uint64_t mixed_sets;
    uint64_t wall_t0;
    struct f4d_err err;
};

static uint64_t wall_ns(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (uint64_t)ts.tv_sec * 1000000000u + (uint64_t)ts.tv_nsec;
}

static int rec_ready(void *user, const struct f4d_capture_stats *st)
{
    struct rec_ctx *c = user;
    if (!c->dir)
        return 0;
    return run_take_create(&c->w, c->dir, c->board, st, &c->err);
}

int run_take_create(struct f4d_take_writer **w, const char *dir, const struct hal_board *board,
                    const struct f4d_capture_stats *st, struct f4d_err *err)
{
    struct f4d_take_info info = {0};
    info.n_cams = board->n_cams;
    info.rate_mhz = board->trigger.rate_mhz;
    info.durability_ms = board->durability_ms;
    for (uint32_t i = 0; i < info.n_cams; i++) {
        info.formats[i] = st->formats[i];
        snprintf(info.cam_ids[i], sizeof info.cam_ids[i], "%.31s", board->cams[i].id);
    }
    char *js = hal_board_to_json(board);
    if (!js)
        return f4d_fail(err, F4D_ENOMEM, "take %s: cannot describe the board as JSON", dir);
    int rc = f4d_take_create(w, dir, &info, js, board->durability_ms, err);
    free(js);
    return rc;
}

/* A set is mixed if any frame carries another trigger than the set, or (sim)
 * its ground-truth stamp names another pulse or camera. */
static bool set_is_mixed(const struct rec_ctx *c, const struct hal_set *set)
{
    for (uint32_t i = 0; i < c->board->n_cams; i++) {
        const struct hal_buffer *b = set->frames[i];
        if (!b)
            continue;
        if (b->trigger_seq != set->seq)
            return true;
        uint64_t seq;
        uint32_t cam;
        if (c->sim && hal_sim_stamp_read(b->data, b->bytes_used, &seq, &cam) == F4D_OK &&
            (seq != set->seq || cam != i))
            return true;
    }
    return false;
}

static int rec_set(void *user, const struct hal_set *set)
{
    struct rec_ctx *c = user;
    c->mixed_sets += set_is_mixed(c, set);
    if (!c->w)
        return 0;
    int rc = f4d_take_append(c->w, set);
    if (rc < 0)
        f4d_fail(&c->err, rc, "take %s: write failed (disk full?)", c->dir);
    return rc;
}

static void rec_progress(void *user, const struct f4d_capture_stats *st, uint64_t now)
{
    struct rec_ctx *c = user;
    if (c->quiet)
        return;
    double t = (double)(now - st->t_start_ns) * 1e-9;
    double wall = (double)(wall_ns() - c->wall_t0) * 1e-9;
    uint64_t sets = st->sync.sets_complete + st->sync.sets_incomplete;
    double mb = c->w ? (double)f4d_take_bytes_written(c->w) / 1e6 : 0.0;
    fprintf(stderr,
            "%s[forge4d] %6.1f s  sets %llu (%.1f/s)  incomplete %llu  dropped %llu late %llu "
            "dup %llu  disk %.1f MB (%.1f MB/s)  durable %llu%s",
            c->tty ? "\r" : "", t, (unsigned long long)sets, t > 0 ? (double)sets / t : 0.0,
            (unsigned long long)st->sync.sets_incomplete, (unsigned long long)st->sync.frames_dropped,
            (unsigned long long)st->sync.frames_late, (unsigned long long)st->sync.frames_duplicate, mb,
            wall > 0 ? mb / wall : 0.0,
            (unsigned long long)(c->w ? f4d_take_durable_sets(c->w) : 0), c->tty ? "  " : "\n");
}

static int write_stats(const char *path, const struct f4d_capture_stats *st, uint64_t mixed,
                       const struct hal_sim_injected *inj)
{
    cJSON *o = cJSON_CreateObject();
    if (!o)
        return -1;
    cJSON_AddNumberToObject(o, "triggers", (double)st->sync.triggers);
    cJSON_AddNumberToObject(o, "sets_complete", (double)st->sync.sets_complete);
    cJSON_AddNumberToObject(o, "sets_incomplete", (double)st->sync.sets_incomplete);
    cJSON_AddNumberToObject(o, "frames_dropped", (double)st->sync.frames_dropped);
    cJSON_AddNumberToObject(o, "frames_late", (double)st->sync.frames_late);
    cJSON_AddNumberToObject(o, "frames_duplicate", (double)st->sync.frames_duplicate);
    cJSON_AddNumberToObject(o, "frames_incomplete", (double)st->sync.frames_incomplete);
    cJSON_AddNumberToObject(o, "mixed_sets", (double)mixed);
    if (inj) {
        cJSON *i = cJSON_AddObjectToObject(o, "injected");
        cJSON_AddNumberToObject(i, "frames_dropped", (double)inj->frames_dropped);
        cJSON_AddNumberToObject(i, "frames_late", (double)inj->frames_late);
        cJSON_AddNumberToObject(i, "frames_duplicate", (double)inj->frames_duplicate);
        cJSON_AddNumberToObject(i, "frames_incomplete", (double)inj->frames_incomplete);
    } else {
        cJSON_AddNullToObject(o, "injected");
    }
    char *s = cJSON_Print(o);
    cJSON_Delete(o);
    if (!s)
        return -1;
    FILE *f = strcmp(path, "-") == 0 ? stdout : fopen(path, "w");
    int rc = (!f || fprintf(f, "%s\n", s) < 0) ? -1 : 0;
    if (f && f != stdout && fclose(f) != 0)
        rc = -1;
    free(s);
    return rc;
}

/* Shared by record and replay: capture from `board` into `dir` (NULL = no take). */
static int run_capture(const struct hal_board *board, const char *dir, uint64_t frames, double seconds,
                       const char *stats_path, bool quiet)
{
    struct f4d_err err = {0};
    struct hal_rig rig;
    if (hal_rig_open(&rig, board, &err) < 0) {
        fprintf(stderr, "forge4d: %s\n", err.msg);
        return 1;
    }
    struct rec_ctx c = {board, dir, NULL, false, quiet, isatty(2) != 0, 0, wall_ns(), {0}};
    void *world = hal_rig_session(&rig, "sim");
    c.sim = world != NULL;
    struct f4d_simscene *scene = NULL;
    if (world && strcmp(board->sim.scene, "pattern") != 0) {
        /* the synthetic 4D scene at each trigger time, through the scene's rig */
        if (f4d_simscene_new(&scene, board->sim.scene, board->sim.seed, board->n_cams, board->cams[0].width,
                             board->cams[0].height, &err) < 0) {
            fprintf(stderr, "forge4d: %s\n", err.msg);
            hal_rig_close(&rig);
            return 1;
        }
        hal_sim_set_renderer(world, f4d_simscene_render, scene);
    }
    struct f4d_capture_config cfg = {0};
    cfg.triggers = frames;
    cfg.duration_ns = (uint64_t)(seconds * 1e9);
    cfg.on_ready = rec_ready;
    struct f4d_capture_stats st;
    int rc = f4d_capture_run(&rig, &cfg, rec_set, rec_progress, &c, &g_stop, &st, &err);
    if (!quiet && c.tty)
        fputc('\n', stderr);
    int status = 0;
    if (rc < 0) {
        fprintf(stderr, "forge4d: %s%s%s\n", err.msg, c.err.msg[0] ? ": " : "", c.err.msg);
        status = 1;
    }
    if (c.w && f4d_take_close(c.w, &err) < 0) {
        fprintf(stderr, "forge4d: %s\n", err.msg);
        status = 1;
    }
    struct hal_sim_injected inj;
    bool have_inj = world && hal_sim_injected_get(world, &inj) == F4D_OK;
    if (rc >= 0 && !quiet) {
        double t = (double)(st.t_end_ns - st.t_start_ns) * 1e-9;
        uint64_t sets = st.sync.sets_complete + st.sync.sets_incomplete;
        fprintf(stderr, "[forge4d] done: %llu triggers, %llu sets (%llu complete) in %.2f s rig time, "
                        "%.2f s wall%s%s\n",
                (unsigned long long)st.sync.triggers, (unsigned long long)sets,
                (unsigned long long)st.sync.sets_complete, t, (double)(wall_ns() - c.wall_t0) * 1e-9,
                dir ? " -> " : "", dir ? dir : "");
    }
    if (stats_path && write_stats(stats_path, &st, c.mixed_sets, have_inj ? &inj : NULL) < 0) {
        fprintf(stderr, "forge4d: cannot write %s\n", stats_path);
        status = 1;
    }
    hal_rig_close(&rig);
    f4d_simscene_free(scene);
    return status;
}

static int cmd_record(int argc, char **argv)
{
    const char *board_path = NULL, *out = NULL, *stats = NULL, *sheet = NULL;
    uint64_t frames = 0;
    double seconds = 0;
    bool fast = false, quiet = false;
    for (int i = 0; i < argc; i++) {
        const char *a = argv[i];
        const char *v = i + 1 < argc ? argv[i + 1] : NULL;
        if (!strcmp(a, "--board") && v) board_path = v, i++;
        else if (!strcmp(a, "-o") && v) out = v, i++;
        else if (!strcmp(a, "--stats-json") && v) stats = v, i++;
        else if (!strcmp(a, "--sheet") && v) sheet = v, i++;
        else if (!strcmp(a, "--frames") && v) {
            char *end;
            frames = strtoull(v, &end, 10);
            if (*end || frames == 0 || v[0] < '0' || v[0] > '9') {
                fprintf(stderr, "forge4d record: --frames wants a positive integer, got \"%s\"\n", v);
                return 2;
            }
            i++;
        } else if (!strcmp(a, "--seconds") && v) {
            char *end;
            seconds = strtod(v, &end);
            if (*end || !(seconds > 0) || seconds > 1e6) {
                fprintf(stderr, "forge4d record: --seconds wants a positive number, got \"%s\"\n", v);
                return 2;
            }
            i++;
        } else if (!strcmp(a, "--fast")) fast = true;
        else if (!strcmp(a, "--quiet")) quiet = true;
        else {
            fprintf(stderr, "forge4d record: unknown or incomplete option \"%s\"\n", a);
            return usage();
        }
    }
    if (!board_path || !out || (frames == 0) == (seconds == 0)) {
        fprintf(stderr, "forge4d record: need --board, -o and exactly one of --frames/--seconds\n");
        return usage();
    }
    struct hal_board board;
    struct f4d_err err = {0};
    if (hal_board_load(&board, board_path, &err) < 0) {
        fprintf(stderr, "forge4d: %s\n", err.msg);
        return 1;
    }
    if (fast)
        board.sim.realtime = false;
    int rc = run_capture(&board, out, frames, seconds, stats, quiet);
    if (rc == 0 && sheet) {
        if (f4d_contact_sheet(out, UINT64_MAX, sheet, &err) < 0) {
            fprintf(stderr, "forge4d: %s\n", err.msg);
            return 1;
        }
        if (!quiet)
            fprintf(stderr, "[forge4d] contact sheet -> %s\n", sheet);
    }
    return rc;
}

static int cmd_verify(int argc, char **argv)
{
    const char *dir = NULL;
    bool json = false, repair = true;
    for (int i = 0; i < argc; i++) {
        if (!strcmp(argv[i], "--json")) json = true;
        else if (!strcmp(argv[i], "--no-repair")) repair = false;
        else if (!dir && argv[i][0] != '-') dir = argv[i];
        else return usage();
    }
    if (!dir)
        return usage();
    struct f4d_take_report rep;
    struct f4d_err err = {0};
    if (f4d_take_verify(dir, repair, &rep, &err) < 0) {
        fprintf(stderr, "forge4d: %s\n", err.msg);
        return 1;
    }
    if (json) {
        printf("{\"sets\": %llu, \"corrupt\": %llu, \"repaired\": %llu, \"truncated_bytes\": %llu, "
               "\"clean_end\": %s}\n",
               (unsigned long long)rep.sets, (unsigned long long)rep.corrupt,
               (unsigned long long)rep.repaired, (unsigned long long)rep.truncated_bytes,
               rep.clean_end ? "true" : "false");
    } else {
        printf("%s: %llu sets, %llu corrupt records, %llu sets recovered into the index, %llu torn "
               "bytes %s, %s\n",
               dir, (unsigned long long)rep.sets, (unsigned long long)rep.corrupt,
               (unsigned long long)rep.repaired, (unsigned long long)rep.truncated_bytes,
               repair ? "truncated" : "found", rep.clean_end ? "closed cleanly" : "not closed (crash?)");
    }
    return rep.corrupt ? 3 : 0;
}

static int cmd_sheet(int argc, char **argv)
{
    const char *dir = NULL, *out = NULL;
    uint64_t set = UINT64_MAX;
    for (int i = 0; i < argc; i++) {
        if (!strcmp(argv[i], "-o") && i + 1 < argc) out = argv[++i];
        else if (!strcmp(argv[i], "--set") && i + 1 < argc) set = strtoull(argv[++i], NULL, 10);
        else if (!dir && argv[i][0] != '-') dir = argv[i];
        else return usage();
    }
    if (!dir || !out)
        return usage();
    struct f4d_err err = {0};
    if (f4d_contact_sheet(dir, set, out, &err) < 0) {
        fprintf(stderr, "forge4d: %s\n", err.msg);
        return 1;
    }
    return 0;
}

static int cmd_replay(int argc, char **argv)
{
    const char *dir = NULL, *stats = NULL;
    bool fast = false;
    for (int i = 0; i < argc; i++) {
        if (!strcmp(argv[i], "--fast")) fast = true;
        else if (!strcmp(argv[i], "--stats-json") && i + 1 < argc) stats = argv[++i];
        else if (!dir && argv[i][0] != '-') dir = argv[i];
        else return usage();
    }
    if (!dir)
        return usage();
    struct hal_board board;
    struct f4d_err err = {0};
    if (hal_replay_board(&board, dir, !fast, &err) < 0) {
        fprintf(stderr, "forge4d: %s\n", err.msg);
        return 1;
    }
    return run_capture(&board, NULL, 0, 0, stats, false);
}

/* A broken internal invariant is a bug: say so plainly, and point at verify,
 * which recovers every set the take writer had appended before the abort. */
static void on_invariant(const char *file, int line, const char *expr)
{
    fprintf(stderr, "forge4d: internal error at %s:%d (%s); please report it. "
                    "A take being recorded is recoverable with `forge4d verify DIR`.\n",
            file, line, expr);
    fflush(stderr);
    abort();
}

int main(int argc, char **argv)
{
    f4d_set_abort_hook(on_invariant);
    if (argc < 2)
        return usage();
    struct sigaction sa;
    memset(&sa, 0, sizeof sa);
    sa.sa_handler = on_signal;
    sigaction(SIGINT, &sa, NULL);
    sigaction(SIGTERM, &sa, NULL);
    if (!strcmp(argv[1], "record"))
        return cmd_record(argc - 2, argv + 2);
    if (!strcmp(argv[1], "verify"))
        return cmd_verify(argc - 2, argv + 2);
    if (!strcmp(argv[1], "sheet"))
        return cmd_sheet(argc - 2, argv + 2);
    if (!strcmp(argv[1], "replay"))
        return cmd_replay(argc - 2, argv + 2);
    if (!strcmp(argv[1], "run"))
        return forge4d_run_main(argc - 2, argv + 2, &g_stop);
    if (!strcmp(argv[1], "report")) {
#ifdef F4D_RUN_HAVE_REPORT
        return forge4d_report_main(argc - 2, argv + 2, &g_stop);
#else
        fprintf(stderr, "forge4d report: not built here: it needs the display's player (F4D_WITH_DISPLAY) "
                        "and the scorer (firmware/gaussians/score)\n");
        return 2;
#endif
    }
    return usage();
}
