/* run.c: `forge4d run`, the appliance daemon.
 *
 *   forge4d run [--board FILE | --replay TAKE] [--weights W] [--stream URL] [--record DIR]
 *               [--seconds S] [--keys N] [--stats-json FILE] [--precision f32|f16|int8]
 *               [--quality low|medium|high] [--codec-effort fast|default|max]
 *               [--threads N] [--stall-ms MS]
 *               [--config FILE | --no-config] [--quiet] [--lockstep auto|off]
 *               [--motion on|off] [--key-hz HZ]
 *
 * Threads and the queues between them (each queue's overload policy beside it):
 *
 *   capture (main thread: rig -> synchronizer -> on_set copies the set into a
 *   |        preallocated slot; it never waits on anything downstream)
 *   |-- rec_q (FIFO, at most rec_cap slots, about 2 s of sets): recorder thread
 *   |     appends every set to the take. Never drops while it keeps up; when
 *   |     the disk falls behind by a whole queue, the set is left out of the
 *   |     take and counted (record_overflow) rather than stalling capture.
 *   |-- infer_box (mailbox of ONE complete set): inference thread. A newer set
 *   |     replaces an unread one: inference skips to the newest complete set
 *   |     and counts each skipped set (sets_skipped_by_inference).
 *   |     Lockstep (a sim rig whose clock waits for its renderer; lockstep =
 *   |     off disables it): capture waits until inference is idle and the
 *   |     stream thread took the last key (key_q empty) before it hands a
 *   |     set over, so the sim renders only the sets inference takes;
 *   |     its clock stands still meanwhile, so no frame is late or lost.
 *   inference (preprocess -> model with the Gaussian head, metric -> scene
 *   |          budget) -> one of 3 key buffers
 *   |-- key_q (FIFO of 3 keys): stream thread. When all key buffers are taken,
 *   |     inference takes back the oldest queued key (counted, keys_dropped):
 *   |     the encoder predicts from its own reconstruction, so a missing key
 *   |     costs bits, never a broken stream.
 *   stream (encoder -> sink: srt://HOST:PORT?... or file:PATH through the
 *          transport; SRT's send blocking only holds this thread); a forced intra key
 *          every intra_every keys lets a receiver join.
 *   status (once a second: the status line on stderr, the stall watchdog,
 *           cameras without frames, --seconds)
 *
 * Stop (SIGINT / SIGTERM, --seconds, --keys, the end of a replayed take): capture
 * stops, the key being inferred finishes and is streamed, the set waiting in
 * the mailbox is dropped (counted), the recorder writes what it holds and
 * closes the take, the stream gets its end packet and is closed. Exit 0.
 * With --display the run then waits for the display to end at the end
 * packet (at most 120 s); a second stop request ends that wait: the display
 * gets SIGTERM, SIGKILL 3 s later, and the run exits 1 naming it.
 *
 * Memory: slots, keys, packet buffer, model arena, budget scratch and latency
 * samples are allocated before the trigger is armed; the per-set path does
 * not allocate.
 *
 * Latency: trigger time to the key's packet handed to the sink, i.e. (rig
 * clock at on_set - trigger time) + wall time from on_set to the sink; with
 * a display attached (--display: f4d-display spawned on the stream file,
 * following it), trigger time to the display presenting the key, from the
 * key-times file (key_time_line) and the display's clock, both
 * CLOCK_MONOTONIC. With no display attached the displayed figures are null.
 *
 * Test knob: F4D_RUN_TEST_INFER_DELAY_MS=N adds N ms to every key (a slow
 * inference stage, for the load test).
 */
#include <errno.h>
#include <fcntl.h>
#include <stdarg.h>
#include <math.h>
#include <poll.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <signal.h>
#include <spawn.h>
#include <stdint.h>
#include <sys/syscall.h>
#include <sys/prctl.h>
#include <sys/resource.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

#include <cjson/cJSON.h>

#include "f4d_capture.h"
#include "f4d_simscene.h"
#include "f4d_take.h"
#include "fk_linear.h"
#include "hal_board.h"
#include "hal_registry.h"
#include "hal_replay.h"
#include "hal_sim.h"
#include "run_internal.h"

#ifndef F4D_RUN_CONFIG_DEFAULT
#define F4D_RUN_CONFIG_DEFAULT "/etc/forge4d/forge4d.conf"
#endif
#ifndef F4D_RUN_BOARD_DEFAULT
#define F4D_RUN_BOARD_DEFAULT "/usr/share/forge4d/board/sim-4cam.json"
#endif

#define RUN_KEYS 3
/* Inference (its thread and the kernel pool's) runs this much nicer than
 * capture, recorder, stream and an attached display: on a 2-core box the
 * model would otherwise starve the capture thread (frames arrive late) and
 * the display (refresh slots missed while a key is decoded: main.sh at 6
 * keys/s, 29.3-29.7 -> 30.0 fps presented). Not on a simulated rig whose
 * clock waits for its renderer ("realtime": false) run without lockstep: the
 * CPU rasterizer that stands in for the cameras (about 120 ms of CPU per
 * 4 x 518^2 set, 3.7 cores at 30 Hz) would take nearly all of both cores from
 * the stages being demonstrated; in lockstep it renders only while inference
 * is idle. */
#define RUN_INFER_NICE 5
#define RUN_LAT_MAX (1u << 16) /* latency samples kept (the last ones) */
/* A streamed key's trigger-to-sink latency, part by part (they add up to it):
 * rig time from the trigger to on_set; on_set to inference taking the set
 * (mailbox, a free key buffer); inference (preprocess, model, budget, and with
 * motion weights the wait for the next set); the stream queue; the encoder;
 * the sink's write (file: flushed). */
/* CPU by stage, from the threads' names (prctl PR_SET_NAME; a thread
 * inherits its creator's, so a stage's kernel pool counts with it): capture
 * is the main thread with the simulated cameras' render pool (the process's
 * own name), inference its thread and the model's pool, stream the encoder
 * and sink, record the take writer, other the status thread. */
#define RUN_CPU_PARTS 5
static const char *const cpu_part_names[RUN_CPU_PARTS] = {"capture", "inference", "stream", "record", "other"};
static const char *const cpu_thread_names[RUN_CPU_PARTS] = {NULL, "f4d-infer", "f4d-stream", "f4d-record", NULL};

static void name_thread(const char *name) { (void)prctl(PR_SET_NAME, name, 0, 0, 0); }

/* One record of getdents64 (the kernel's linux_dirent64). */
struct task_dirent {
    uint64_t       ino;
    int64_t        off;
    unsigned short reclen;
    unsigned char  type;
    char           name[];
};

/* CPU seconds of this process's live threads by stage (a thread that has
 * exited is not listed: called while the stages run). The task directory is
 * read with getdents64 into a stack buffer, not opendir, which allocates: the
 * status thread calls this once the first key is out, which a short run may
 * end before, and an allocation there made the allocation count of a 3-key
 * run differ from a 9-key run's (app/run_alloc). */
static void cpu_by_stage(double out[RUN_CPU_PARTS])
{
    for (int i = 0; i < RUN_CPU_PARTS; i++)
        out[i] = 0.0;
    int dfd = open("/proc/self/task", O_RDONLY | O_DIRECTORY | O_CLOEXEC);
    if (dfd < 0)
        return;
    double tick = (double)sysconf(_SC_CLK_TCK);
    _Alignas(8) char dbuf[4096];
    long got;
    while ((got = syscall(SYS_getdents64, dfd, dbuf, sizeof dbuf)) > 0) {
        for (long at = 0; at < got;) {
            const struct task_dirent *e = (const struct task_dirent *)(dbuf + at);
            at += e->reclen;
            if (e->name[0] == '.')
                continue;
            char path[64], buf[1024];
            snprintf(path, sizeof path, "/proc/self/task/%.20s/stat", e->name);
            int fd = open(path, O_RDONLY);
            if (fd < 0)
                continue;
            ssize_t n = read(fd, buf, sizeof buf - 1);
            close(fd);
            if (n <= 0)
                continue;
            buf[n] = 0;
            char *lp = strchr(buf, '('), *rp = strrchr(buf, ')');
            if (!lp || !rp || rp < lp)
                continue;
            *rp = 0;
            const char *comm = lp + 1;
            unsigned long long ut = 0, st = 0;
            /* after the name: state (field 3) ... utime (14), stime (15) */
            if (sscanf(rp + 2, "%*c %*d %*d %*d %*d %*d %*u %*u %*u %*u %*u %llu %llu", &ut, &st) != 2)
                continue;
            int part = 0; /* the main thread's name (capture) unless named */
            if (!strcmp(comm, "f4d-status"))
                part = RUN_CPU_PARTS - 1;
            for (int i = 1; i < RUN_CPU_PARTS; i++)
                if (cpu_thread_names[i] && !strcmp(comm, cpu_thread_names[i]))
                    part = i;
            out[part] += (double)(ut + st) / tick;
        }
    }
    close(dfd);
}

#define RUN_LAT_PARTS 6
static const char *const lat_part_names[RUN_LAT_PARTS] = {
    "delivery", "infer_wait", "inference", "key_queue_wait", "encode", "sink_write"};

typedef _Atomic uint64_t counter;

/* A stage is busy from taking an item until it is done with it; the watchdog
 * reports one busy longer than its limit (and again when it recovers). */
struct stage_hb {
    const char *name;
    _Atomic uint64_t busy_since; /* 0 = waiting */
    int reported;                /* status thread only */
};

struct run {
    const struct run_config *cfg;
    const struct hal_board *board;
    struct hal_rig *rig;
    volatile sig_atomic_t *stop;
    bool tty;
    /* sets */
    struct run_slot *slots;
    uint8_t *slot_mem;
    uint32_t n_slots, rec_cap;
    struct run_fifo free_slots, rec_q, infer_box;
    uint32_t all_mask;
    /* keys */
    struct run_key kbuf[RUN_KEYS];
    struct run_fifo free_keys, key_q;
    /* stages */
    bool have_infer, have_sink;
    struct run_infer infer;
    struct run_encoder enc;
    struct run_sink sink;
    uint8_t *pkt;
    struct f4d_take_writer *take;
    const char *take_dir;
    struct f4d_err take_err;
    /* counters */
    counter sets_captured, sets_complete, sets_skipped, sets_no_slot, rec_written, rec_overflow, keys,
        keys_dropped, infer_errors, stream_errors, stream_bytes, key_us_last;
    counter rec_durable; /* the take's fdatasynced sets, as the recorder last saw them */
    counter rec_stop_captured; /* sets_captured when the take stopped on a disk error */
    _Atomic int rec_failed;
    _Atomic uint64_t cam_seen[HAL_RIG_CAMERAS_MAX];
    int cam_reported[HAL_RIG_CAMERAS_MAX];
    float *lat_ms;
    counter lat_n;
    /* per-stage wall time of the keys streamed (stream thread only), for the
     * stats: preprocessing, model, budget, encoder */
    double stage_ms[4];
    double stage_cpu_ms[3]; /* thread CPU time: preprocessing, budget, encoder */
    /* where a key's latency to the sink went (stream thread only; sums of ms
     * over the keys streamed), RUN_LAT_PARTS parts in lat_part_names order */
    double lat_part_ms[RUN_LAT_PARTS];
    /* CPU seconds of the threads by stage (cpu_by_stage) when the first key
     * had been streamed and when capture ended, and the keys streamed then */
    double cpu_first[RUN_CPU_PARTS], cpu_last[RUN_CPU_PARTS];
    uint64_t cpu_first_keys, cpu_last_keys;
    _Atomic int cpu_first_taken;
    /* capture statistics, copied by the progress callback */
    pthread_mutex_t st_mu;
    struct f4d_capture_stats cap_st;
    struct stage_hb hb_capture, hb_record, hb_infer, hb_stream;
    /* key times for a display (--key-times): line-buffered into kt_buf,
     * allocated before the first key, so a key's line costs no allocation */
    FILE *kt;
    char *kt_buf;
    /* the attached display (--display), its JSON summary */
    pid_t display_pid;
    char kt_path[1024], display_json[1024];
    _Atomic int done, capturing;
    /* lockstep (a simulated rig whose clock waits for its renderer): capture
     * hands inference a set only once it is idle, so the sim renders the
     * sets inference consumes and no frame waits in the mailbox */
    bool lockstep;
    _Atomic int infer_idle;
    pthread_mutex_t idle_mu;
    pthread_cond_t idle_cv;
    uint64_t t0, t_end;
    double rss_start, rss_end;
    bool rss_warm;
};

/* Resident set in MB from /proc/self/statm (no stdio: no allocation). */
static double rss_mb(void)
{
    int fd = open("/proc/self/statm", O_RDONLY);
    if (fd < 0)
        return NAN;
    char b[128];
    ssize_t n = read(fd, b, sizeof b - 1);
    close(fd);
    if (n <= 0)
        return NAN;
    b[n] = 0;
    unsigned long long size, res;
    if (sscanf(b, "%llu %llu", &size, &res) != 2)
        return NAN;
    return (double)res * (double)sysconf(_SC_PAGESIZE) / 1e6;
}

static void hb_busy(struct stage_hb *h) { atomic_store(&h->busy_since, mono_ns()); }
static void hb_idle(struct stage_hb *h) { atomic_store(&h->busy_since, 0); }

static void say(struct run *r, const char *fmt, ...) __attribute__((format(printf, 2, 3)));
static void say(struct run *r, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    char line[512];
    vsnprintf(line, sizeof line, fmt, ap);
    va_end(ap);
    /* on a terminal the status line is redrawn in place: start a fresh line */
    fprintf(stderr, "%s[forge4d run] %s\n", r->tty ? "\r\033[K" : "", line);
}

static void slot_release(struct run *r, struct run_slot *s)
{
    if (__atomic_sub_fetch(&s->refs, 1, __ATOMIC_ACQ_REL) == 0)
        run_fifo_try_push(&r->free_slots, s); /* never full: it holds every slot */
}

/* ---- capture thread (callbacks of f4d_capture_run) ---- */

static int on_ready(void *user, const struct f4d_capture_stats *st)
{
    struct run *r = user;
    struct f4d_err err = {0};
    size_t per_set = 0, bytes[HAL_RIG_CAMERAS_MAX];
    for (uint32_t i = 0; i < r->board->n_cams; i++) {
        const struct hal_format *f = &st->formats[i];
        bytes[i] = f->image_bytes ? f->image_bytes : (size_t)f->height * f->stride;
        per_set += bytes[i];
    }
    r->slot_mem = malloc(per_set * r->n_slots);
    if (!r->slot_mem) {
        say(r, "cannot allocate %u set slots of %zu bytes", r->n_slots, per_set);
        return F4D_ENOMEM;
    }
    uint8_t *p = r->slot_mem;
    for (uint32_t s = 0; s < r->n_slots; s++)
        for (uint32_t i = 0; i < r->board->n_cams; i++) {
            r->slots[s].bufs[i].data = p;
            r->slots[s].bufs[i].capacity = bytes[i];
            memset(p, 0, bytes[i]); /* touch now: RSS is flat from the first set */
            p += bytes[i];
        }
    if (!r->take_dir)
        return 0;
    int rc = run_take_create(&r->take, r->take_dir, r->board, st, &err);
    if (rc < 0)
        say(r, "%s", err.msg);
    return rc;
}

static void slot_fill(struct run *r, struct run_slot *s, const struct hal_set *set, uint64_t now_wall)
{
    s->set = *set;
    for (uint32_t i = 0; i < r->board->n_cams; i++) {
        const struct hal_buffer *b = set->frames[i];
        if (!b) {
            s->set.frames[i] = NULL;
            continue;
        }
        struct hal_buffer *d = &s->bufs[i];
        uint8_t *data = d->data;
        size_t cap = d->capacity;
        *d = *b;
        d->data = data;
        d->capacity = cap;
        d->bytes_used = b->bytes_used < cap ? b->bytes_used : cap;
        memcpy(data, b->data, d->bytes_used);
        s->set.frames[i] = d;
    }
    uint64_t rig_now = hal_clock_now(&r->rig->clock);
    s->delivery_ns = rig_now > set->trigger_ts_ns ? rig_now - set->trigger_ts_ns : 0;
    s->arrive_wall_ns = now_wall;
}

static int on_set(void *user, const struct hal_set *set)
{
    struct run *r = user;
    uint64_t now = mono_ns();
    atomic_store(&r->hb_capture.busy_since, now); /* capture: time of the last set */
    atomic_fetch_add(&r->sets_captured, 1);
    for (uint32_t i = 0; i < r->board->n_cams; i++)
        if (set->present_mask & (1u << i))
            atomic_store(&r->cam_seen[i], now);
    bool complete = set->complete && (set->ok_mask & r->all_mask) == r->all_mask;
    atomic_fetch_add(&r->sets_complete, complete);
    bool want_rec = r->take != NULL, want_inf = r->have_infer && complete;
    if (!want_rec && !want_inf)
        return 0;
    struct run_slot *s = run_fifo_try_pop(&r->free_slots);
    if (!s) { /* every slot held downstream: the set is lost to both */
        atomic_fetch_add(&r->sets_no_slot, 1);
        atomic_fetch_add(&r->rec_overflow, want_rec);
        atomic_fetch_add(&r->sets_skipped, want_inf);
        return 0;
    }
    if (want_inf && r->lockstep) {
        /* the world's clock stands still meanwhile (it waits for us), so the
         * set ages nothing in rig time: its trigger maps to wall time at the
         * handover below, delivery_ns (rig time since the trigger) before it */
        pthread_mutex_lock(&r->idle_mu);
        /* ... and once the stream thread took the last key: a key waiting
         * behind the encoder would only age there (latency), as the
         * throughput is the encoder's either way */
        while ((!atomic_load(&r->infer_idle) || run_fifo_depth(&r->key_q) > 0) && !*r->stop) {
            struct timespec ts;
            clock_gettime(CLOCK_REALTIME, &ts);
            ts.tv_nsec += 50000000;
            if (ts.tv_nsec >= 1000000000) {
                ts.tv_sec++;
                ts.tv_nsec -= 1000000000;
            }
            pthread_cond_timedwait(&r->idle_cv, &r->idle_mu, &ts);
            atomic_store(&r->hb_capture.busy_since, mono_ns()); /* waiting by design, not stalled */
        }
        atomic_store(&r->infer_idle, 0);
        pthread_mutex_unlock(&r->idle_mu);
        now = mono_ns();
    }
    slot_fill(r, s, set, now);
    bool rec = want_rec && run_fifo_depth(&r->rec_q) < r->rec_cap; /* only this thread pushes */
    if (want_rec && !rec)
        atomic_fetch_add(&r->rec_overflow, 1);
    s->refs = (int)rec + (int)want_inf;
    if (s->refs == 0) {
        run_fifo_try_push(&r->free_slots, s);
        return 0;
    }
    if (rec)
        run_fifo_try_push(&r->rec_q, s);
    if (want_inf) {
        struct run_slot *old = run_fifo_push_evict(&r->infer_box, s);
        if (old) {
            atomic_fetch_add(&r->sets_skipped, 1);
            slot_release(r, old);
        }
    }
    return 0;
}

static void on_progress(void *user, const struct f4d_capture_stats *st, uint64_t now)
{
    (void)now;
    struct run *r = user;
    pthread_mutex_lock(&r->st_mu);
    r->cap_st = *st;
    pthread_mutex_unlock(&r->st_mu);
}

/* ---- recorder thread ---- */
static void *record_main(void *arg)
{
    struct run *r = arg;
    name_thread("f4d-record");
    void *it;
    while (run_fifo_pop(&r->rec_q, &it) == 1) {
        struct run_slot *s = it;
        hb_busy(&r->hb_record);
        if (!atomic_load(&r->rec_failed)) {
            int rc = f4d_take_append(r->take, &s->set);
            if (rc < 0) { /* the take stops here; streaming goes on */
                atomic_store(&r->rec_stop_captured, atomic_load(&r->sets_captured));
                atomic_store(&r->rec_failed, 1);
                say(r, "take %s: a write or flush failed (%s: disk full or failing?): recording stopped, the stream goes on",
                    r->take_dir, f4d_status_name(rc));
            } else {
                atomic_fetch_add(&r->rec_written, 1);
                atomic_store(&r->rec_durable, f4d_take_durable_sets(r->take));
            }
        }
        slot_release(r, s);
        hb_idle(&r->hb_record);
    }
    return NULL;
}

/* ---- inference thread ---- */

/* Lowers the calling thread's priority (Linux: PRIO_PROCESS with 0 is the
 * calling thread; threads it creates inherit the value). Raising nice needs
 * no privilege; failure only leaves the priority as it was. */
static void nicer(int by)
{
    if (by <= 0)
        return;
    errno = 0;
    int cur = getpriority(PRIO_PROCESS, 0);
    if (errno == 0)
        (void)setpriority(PRIO_PROCESS, 0, cur + by);
}

/* A rig of simulated cameras whose clock waits for its renderer. */
static bool waiting_sim(const struct hal_board *b)
{
    if (b->sim.realtime || b->n_cams == 0)
        return false;
    for (uint32_t i = 0; i < b->n_cams; i++)
        if (strcmp(b->cams[i].backend, "sim") != 0)
            return false;
    return true;
}

/* RUN_INFER_NICE, or 0 on a waiting-clock sim rig without lockstep (its
 * renderer would take the cores from inference); in lockstep the renderer
 * runs only while inference is idle, so inference yields to the display and
 * the encoder there as on a real rig. */
static int infer_nice_for(const struct hal_board *b, bool lockstep)
{
    return waiting_sim(b) && !lockstep ? 0 : RUN_INFER_NICE;
}

/* Builds the inference stage on its own thread at the lowered priority, so
 * the kernel pool's threads (created with the context) inherit it. */
struct infer_setup {
    struct run_infer *st;
    const struct run_infer_config *cfg;
    const struct hal_board *board;
    bool lockstep;
    struct f4d_err *err;
    int rc;
};

static void *infer_setup_main(void *arg)
{
    struct infer_setup *s = arg;
    name_thread("f4d-infer"); /* the model's kernel pool inherits it */
    nicer(infer_nice_for(s->board, s->lockstep));
    s->rc = run_infer_model_new(s->st, s->cfg, s->board, s->err);
    return NULL;
}

static int infer_new_nicer(struct run_infer *st, const struct run_infer_config *cfg, const struct hal_board *board,
                           bool lockstep, struct f4d_err *err)
{
    struct infer_setup s = {st, cfg, board, lockstep, err, 0};
    pthread_t th;
    if (pthread_create(&th, NULL, infer_setup_main, &s) != 0)
        return run_infer_model_new(st, cfg, board, err);
    pthread_join(th, NULL);
    return s.rc;
}
static struct run_key *key_buffer(struct run *r)
{
    for (;;) {
        struct run_key *k = run_fifo_try_pop(&r->free_keys);
        if (k)
            return k;
        if ((k = run_fifo_try_pop(&r->key_q))) { /* stream behind: drop its oldest key */
            atomic_fetch_add(&r->keys_dropped, 1);
            return k;
        }
        /* the stream thread holds the last one for a moment */
        nanosleep(&(struct timespec){0, 1000000}, NULL);
    }
}

/* Lockstep: inference is ready for the next set. */
static void infer_ready(struct run *r)
{
    if (!r->lockstep)
        return;
    pthread_mutex_lock(&r->idle_mu);
    atomic_store(&r->infer_idle, 1);
    pthread_cond_signal(&r->idle_cv);
    pthread_mutex_unlock(&r->idle_mu);
}

/* Lockstep: wakes capture to check its condition again (the stream thread
 * took a key). */
static void infer_ready_signal(struct run *r)
{
    if (!r->lockstep)
        return;
    pthread_mutex_lock(&r->idle_mu);
    pthread_cond_signal(&r->idle_cv);
    pthread_mutex_unlock(&r->idle_mu);
}

/* key_hz: waits until `start` + 1 / key_hz before inference takes the next
 * set. In lockstep this runs before capture is told inference is idle, so the
 * next set is handed over (and its trigger mapped) only then: no set waits in
 * the mailbox for the pace; on a real rig the newest set is taken after it. */
static void key_pace(struct run *r, uint64_t start)
{
    if (!(r->cfg->key_hz > 0))
        return;
    uint64_t at = start + (uint64_t)(1e9 / r->cfg->key_hz), now;
    /* in steps of at most 50 ms: a stop is not kept waiting for a slow pace */
    while (!*r->stop && (now = mono_ns()) < at) {
        uint64_t until = at - now > 50000000u ? now + 50000000u : at;
        struct timespec ts = {(time_t)(until / 1000000000u), (long)(until % 1000000000u)};
        clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &ts, NULL);
    }
}

static void *infer_main(void *arg)
{
    struct run *r = arg;
    name_thread("f4d-infer");
    nicer(infer_nice_for(r->board, r->lockstep));
    void *it;
    while (run_fifo_pop(&r->infer_box, &it) == 1) {
        struct run_slot *s = it;
        struct run_key *k = key_buffer(r);
        struct f4d_err err = {0};
        hb_busy(&r->hb_infer);
        k->arrive_wall_ns = s->arrive_wall_ns;
        k->delivery_ns = s->delivery_ns;
        k->infer_start_ns = mono_ns();
        uint64_t start = k->infer_start_ns;
        int rc = r->infer.key(r->infer.self, &s->set, k, &err);
        uint64_t seq = s->set.seq;
        slot_release(r, s); /* capture may reuse it from here */
        hb_idle(&r->hb_infer);
        if (rc < 0) {
            uint64_t n = atomic_fetch_add(&r->infer_errors, 1);
            if (n < 3 || n % 100 == 0)
                say(r, "key from set %llu failed (%llu so far): %s", (unsigned long long)seq,
                    (unsigned long long)n + 1, err.msg);
            run_fifo_try_push(&r->free_keys, k);
            key_pace(r, start);
            infer_ready(r);
            continue;
        }
        if (rc == 0) { /* the stage holds this set's key until the next set (its forward motion) */
            run_fifo_try_push(&r->free_keys, k);
            key_pace(r, start);
            infer_ready(r);
            continue;
        }
        atomic_store(&r->key_us_last, (uint64_t)(k->infer_ms * 1000.0));
        k->queued_ns = mono_ns();
        run_fifo_try_push(&r->key_q, k); /* RUN_KEYS buffers, RUN_KEYS places: always fits */
        key_pace(r, start);
        infer_ready(r);
    }
    if (r->infer.flush) { /* the key the stage still holds (no forward motion) */
        struct run_key *k = key_buffer(r);
        struct f4d_err err = {0};
        int rc = r->infer.flush(r->infer.self, k, &err);
        if (rc < 0)
            say(r, "last key failed: %s", err.msg);
        k->queued_ns = mono_ns();
        run_fifo_try_push(rc == 1 ? &r->key_q : &r->free_keys, k);
    }
    run_fifo_close(&r->key_q);
    return NULL;
}

/* ---- stream thread ---- */
static int stream_out(struct run *r, const uint8_t *pkt, size_t len)
{
    atomic_fetch_add(&r->stream_bytes, len);
    if (!r->have_sink)
        return 0;
    struct f4d_err err = {0};
    int rc = r->sink.write(r->sink.self, pkt, len, &err);
    if (rc < 0) {
        uint64_t n = atomic_fetch_add(&r->stream_errors, 1);
        if (n < 3 || n % 100 == 0)
            say(r, "%s", err.msg);
    }
    return rc;
}

/* The key's line for a display measuring capture-to-display latency: the
 * trigger on CLOCK_MONOTONIC is on_set's monotonic time less the rig clock's
 * time from trigger to on_set. Exact when the rig clock is CLOCK_MONOTONIC
 * (a hardware trigger's edge times) or runs at its rate (the realtime sim);
 * on a simulated clock that waits for its renderer it places the trigger
 * that many rig nanoseconds before the set arrived, i.e. as if the cameras
 * had delivered on their modelled delays (the renderer's time excluded).
 * Written before the packet, so a reader that has the packet has the line. */
static void key_time_line(struct run *r, const struct run_key *k)
{
    if (!r->kt)
        return;
    uint64_t trig = k->arrive_wall_ns > k->delivery_ns ? k->arrive_wall_ns - k->delivery_ns : 0;
    if (fprintf(r->kt, "%llu %llu %llu %llu\n", (unsigned long long)k->t_us, (unsigned long long)trig,
                (unsigned long long)mono_ns(), (unsigned long long)k->seq) < 0 || fflush(r->kt) != 0) {
        say(r, "key times %s: write failed (%s): no more key times", r->kt_path, strerror(errno));
        fclose(r->kt);
        r->kt = NULL;
    }
}

static void *stream_main(void *arg)
{
    struct run *r = arg;
    name_thread("f4d-stream");
    struct f4d_err err = {0};
    size_t len = r->enc.packet_cap;
    if (r->enc.header(r->enc.self, 0, r->pkt, &len, &err) < 0)
        say(r, "%s", err.msg);
    else
        stream_out(r, r->pkt, len);
    uint64_t n = 0, t_last = 0;
    bool resync = false;
    void *it;
    while (run_fifo_pop(&r->key_q, &it) == 1) {
        struct run_key *k = it;
        infer_ready_signal(r); /* lockstep: the key queue is empty again */
        if (r->cfg->keys && atomic_load(&r->keys) >= r->cfg->keys) {
            /* --keys reached: keys still queued behind it are not streamed */
            run_fifo_try_push(&r->free_keys, k);
            continue;
        }
        hb_busy(&r->hb_stream);
        bool intra = resync || n % r->cfg->intra_every == 0;
        len = r->enc.packet_cap;
        uint64_t e0 = mono_ns();
        double ec0 = thread_cpu_ms();
        int rc = r->enc.key(r->enc.self, k, intra, r->pkt, &len, &err);
        double enc_cpu = thread_cpu_ms() - ec0;
        uint64_t e1 = mono_ns();
        if (rc < 0) {
            uint64_t e = atomic_fetch_add(&r->stream_errors, 1);
            if (e < 3 || e % 100 == 0)
                say(r, "%s", err.msg);
        } else if (key_time_line(r, k), stream_out(r, r->pkt, len) < 0) {
            resync = true; /* a receiver lost a packet: rejoin on an intra key */
        } else {
            resync = false;
            n++;
            t_last = k->t_us;
            uint64_t now = mono_ns();
            r->stage_ms[0] += k->prep_ms;
            r->stage_ms[1] += k->model_ms;
            r->stage_ms[2] += k->budget_ms;
            r->stage_ms[3] += (double)(now - e0) * 1e-6;
            r->stage_cpu_ms[0] += k->prep_cpu_ms;
            r->stage_cpu_ms[1] += k->budget_cpu_ms;
            r->stage_cpu_ms[2] += enc_cpu;
            double ms = (double)(k->delivery_ns + (now - k->arrive_wall_ns)) * 1e-6;
            const uint64_t at[RUN_LAT_PARTS + 1] = {k->arrive_wall_ns, k->infer_start_ns, k->queued_ns, e0, e1, now};
            r->lat_part_ms[0] += (double)k->delivery_ns * 1e-6;
            for (int j = 0; j + 1 < RUN_LAT_PARTS; j++)
                r->lat_part_ms[j + 1] += at[j + 1] > at[j] ? (double)(at[j + 1] - at[j]) * 1e-6 : 0.0;
            uint64_t i = atomic_fetch_add(&r->lat_n, 1);
            r->lat_ms[i % RUN_LAT_MAX] = (float)ms;
            if (atomic_fetch_add(&r->keys, 1) + 1 == r->cfg->keys && !*r->stop)
                *r->stop = 1; /* --keys: enough streamed (a 2, a second request, stays) */
        }
        run_fifo_try_push(&r->free_keys, k);
        hb_idle(&r->hb_stream);
    }
    len = r->enc.packet_cap;
    if (r->enc.end(r->enc.self, t_last, r->pkt, &len, &err) < 0)
        say(r, "%s", err.msg);
    else
        stream_out(r, r->pkt, len);
    return NULL;
}

/* ---- status thread: status line, watchdog, --seconds ---- */
static void watch(struct run *r, struct stage_hb *h, uint64_t now, uint64_t limit_ns, const char *what)
{
    uint64_t since = atomic_load(&h->busy_since);
    bool stalled = since && now > since && now - since > limit_ns;
    if (stalled && !h->reported)
        say(r, "stall: %s %s for %.1f s (watchdog limit %.1f s); the other stages keep running", h->name, what,
            (double)(now - since) * 1e-9, (double)limit_ns * 1e-9);
    else if (!stalled && h->reported)
        say(r, "%s running again", h->name);
    h->reported = stalled;
}

static void status_tick(struct run *r, uint64_t now, uint64_t *prev_sets, uint64_t *prev_keys,
                        uint64_t *prev_bytes, uint64_t *prev_t)
{
    double dt = (double)(now - *prev_t) * 1e-9;
    uint64_t sets = atomic_load(&r->sets_captured), keys = atomic_load(&r->keys),
             bytes = atomic_load(&r->stream_bytes);
    pthread_mutex_lock(&r->st_mu);
    struct f4d_sync_counters sc = r->cap_st.sync;
    pthread_mutex_unlock(&r->st_mu);
    uint64_t limit = (uint64_t)r->cfg->stall_ms * 1000000u;
    /* a key that normally takes seconds is not a stall */
    uint64_t infer_limit = limit > (uint64_t)(4e6 * r->infer.warm_ms) ? limit : (uint64_t)(4e6 * r->infer.warm_ms);
    watch(r, &r->hb_capture, now, limit, "delivered no set");
    watch(r, &r->hb_record, now, limit, "busy writing one set");
    watch(r, &r->hb_infer, now, infer_limit, "busy on one key");
    watch(r, &r->hb_stream, now, limit, "busy sending one key");
    if (sets > 0)
        for (uint32_t i = 0; i < r->board->n_cams; i++) {
            uint64_t seen = atomic_load(&r->cam_seen[i]);
            bool down = now - seen > 1000000000u && atomic_load(&r->hb_capture.busy_since) > seen;
            if (down && !r->cam_reported[i])
                say(r, "camera %s: no frames for %.1f s (failed or disconnected); the other views go on",
                    r->board->cams[i].id, (double)(now - seen) * 1e-9);
            else if (!down && r->cam_reported[i])
                say(r, "camera %s delivers again", r->board->cams[i].id);
            r->cam_reported[i] = down;
        }
    if (!r->cfg->quiet) {
        double t = (double)(now - r->t0) * 1e-9;
        fprintf(stderr,
                "%s[forge4d run] %6.1f s  sets %llu (%.1f/s)  queues rec %u/%u (%llu unsynced) infer %u/1 key %u/%d  "
                "drops: frames %llu incomplete %llu skipped %llu rec %llu keys %llu  key %.0f ms (%.1f Hz)  "
                "%.2f Mbit/s  rss %.0f MB%s",
                r->tty ? "\r\033[K" : "", t, (unsigned long long)sets,
                dt > 0 ? (double)(sets - *prev_sets) / dt : 0.0, run_fifo_depth(&r->rec_q), r->rec_cap,
                (unsigned long long)(atomic_load(&r->rec_written) - atomic_load(&r->rec_durable)),
                run_fifo_depth(&r->infer_box), run_fifo_depth(&r->key_q), RUN_KEYS,
                (unsigned long long)sc.frames_dropped, (unsigned long long)sc.sets_incomplete,
                (unsigned long long)atomic_load(&r->sets_skipped), (unsigned long long)atomic_load(&r->rec_overflow),
                (unsigned long long)atomic_load(&r->keys_dropped), (double)atomic_load(&r->key_us_last) * 1e-3,
                dt > 0 ? (double)(keys - *prev_keys) / dt : 0.0,
                dt > 0 ? (double)(bytes - *prev_bytes) * 8e-6 / dt : 0.0, rss_mb(), r->tty ? "" : "\n");
    }
    *prev_sets = sets, *prev_keys = keys, *prev_bytes = bytes, *prev_t = now;
}

static void *status_main(void *arg)
{
    struct run *r = arg;
    name_thread("f4d-status");
    uint64_t prev_sets = 0, prev_keys = 0, prev_bytes = 0, prev_t = r->t0, next = r->t0 + 1000000000u;
    while (!atomic_load(&r->done)) {
        nanosleep(&(struct timespec){0, 50000000}, NULL);
        uint64_t now = mono_ns();
        if (r->cfg->seconds > 0 && now - r->t0 >= (uint64_t)(r->cfg->seconds * 1e9) && !*r->stop)
            *r->stop = 1;
        if (now >= next) {
            status_tick(r, now, &prev_sets, &prev_keys, &prev_bytes, &prev_t);
            next += 1000000000u;
        }
        /* RSS every 50 ms (a read of /proc, no allocation). The end: the last
         * sample taken before the stop was asked for, while capture still ran
         * (it frees its buffers on its way out: a 10-minute run's end sample,
         * taken between the stop and capture's return, read 134 MB of a flat
         * 168). The start: once every buffer was touched: the capture
         * buffers (pending_max + spares per camera, first written as they
         * cycle), the slots, and arena, codec and sink by the first key; a
         * run too short for that keeps its first sample after the first key. */
        uint64_t kn = atomic_load(&r->keys);
        if (kn > 0 && !atomic_load(&r->cpu_first_taken) && atomic_load(&r->capturing)) {
            r->cpu_first_keys = kn;
            cpu_by_stage(r->cpu_first);
            atomic_store(&r->cpu_first_taken, 1);
        }
        double rss = rss_mb();
        if (atomic_load(&r->capturing) && (!*r->stop || isnan(r->rss_end)))
            r->rss_end = rss;
        bool warm = atomic_load(&r->sets_captured) >= r->board->sync.pending_max + HAL_CAPTURE_SPARE_BUFFERS &&
                    (!r->have_infer || atomic_load(&r->keys) > 0);
        if (!r->rss_warm && (warm || isnan(r->rss_start)) &&
            (atomic_load(&r->keys) > 0 || (!r->have_infer && atomic_load(&r->sets_captured) > 0))) {
            r->rss_start = rss;
            r->rss_warm = warm;
        }
    }
    if (!r->cfg->quiet && r->tty)
        fputc('\n', stderr);
    return NULL;
}

/* ---- stats ---- */
static int cmp_float(const void *a, const void *b)
{
    float x = *(const float *)a, y = *(const float *)b;
    return (x > y) - (x < y);
}

/* The attached display's figures from its JSON summary (NAN when absent);
 * part: its latency_breakdown_ms, the mean ms from the key-times line
 * (written once the key is encoded) to the display reading the packet, from
 * there to the end of the refresh that shows it, and trigger to display. */
#define DISPLAY_LAT_PARTS 3
static const char *const display_part_names[DISPLAY_LAT_PARTS] = {"display_read", "display_show", "to_display"};
struct display_figures {
    double fps, p50, p95, presented;
    double part[DISPLAY_LAT_PARTS];
    double cpu_per_key;        /* its process CPU ms a key after the first */
};

static double json_num(const cJSON *o, const char *name)
{
    const cJSON *v = cJSON_GetObjectItemCaseSensitive(o, name);
    return cJSON_IsNumber(v) ? v->valuedouble : NAN;
}

static void display_figures_read(const char *path, struct display_figures *d)
{
    d->fps = d->p50 = d->p95 = d->presented = d->cpu_per_key = NAN;
    for (int i = 0; i < DISPLAY_LAT_PARTS; i++)
        d->part[i] = NAN;
    FILE *f = path[0] ? fopen(path, "rb") : NULL;
    if (!f)
        return;
    char buf[8192];
    size_t n = fread(buf, 1, sizeof buf - 1, f);
    fclose(f);
    buf[n] = 0;
    cJSON *o = cJSON_Parse(buf);
    if (!o)
        return;
    d->fps = json_num(o, "fps");
    d->p50 = json_num(o, "latency_trigger_ms_p50");
    d->p95 = json_num(o, "latency_trigger_ms_p95");
    d->presented = json_num(o, "keys_timed");
    d->cpu_per_key = json_num(o, "cpu_ms_per_key");
    const cJSON *lb = cJSON_GetObjectItemCaseSensitive(o, "latency_breakdown_ms");
    for (int i = 0; lb && i < DISPLAY_LAT_PARTS; i++)
        d->part[i] = json_num(lb, display_part_names[i]);
    cJSON_Delete(o);
}

static int write_stats(struct run *r, const char *path, const struct display_figures *disp, double *p50,
                       double *p95)
{
    double wall = (double)(r->t_end - r->t0) * 1e-9;
    uint64_t keys = atomic_load(&r->keys), nl = atomic_load(&r->lat_n);
    size_t n = nl < RUN_LAT_MAX ? (size_t)nl : RUN_LAT_MAX;
    *p50 = *p95 = NAN;
    if (n) {
        qsort(r->lat_ms, n, sizeof *r->lat_ms, cmp_float);
        *p50 = r->lat_ms[(size_t)floor(0.50 * (double)(n - 1) + 0.5)];
        *p95 = r->lat_ms[(size_t)floor(0.95 * (double)(n - 1) + 0.5)];
    }
    if (!path)
        return 0;
    cJSON *o = cJSON_CreateObject();
    if (!o)
        return -1;
    cJSON_AddNumberToObject(o, "sets_captured", (double)atomic_load(&r->sets_captured));
    cJSON_AddNumberToObject(o, "sets_skipped_by_inference", (double)atomic_load(&r->sets_skipped));
    cJSON_AddNumberToObject(o, "key_frames", (double)keys);
    cJSON_AddNumberToObject(o, "key_hz", wall > 0 ? (double)keys / wall : 0.0);
#define NUM_OR_NULL(name, v) ((isfinite(v)) ? (void)cJSON_AddNumberToObject(o, name, v) : (void)cJSON_AddNullToObject(o, name))
    /* with a display attached, latency runs from the trigger to the display
     * presenting the key; without, to the key's packet handed to the sink */
    bool shown = disp && isfinite(disp->p50);
    NUM_OR_NULL("displayed_fps", disp ? disp->fps : NAN);
    NUM_OR_NULL("latency_ms_p50", shown ? disp->p50 : *p50);
    NUM_OR_NULL("latency_ms_p95", shown ? disp->p95 : *p95);
    cJSON_AddNumberToObject(o, "bitrate_mbps", wall > 0 ? (double)atomic_load(&r->stream_bytes) * 8e-6 / wall : 0.0);
    NUM_OR_NULL("rss_mb_start", r->rss_start);
    NUM_OR_NULL("rss_mb_end", r->rss_end);
    /* where a key's time goes (mean wall ms of the keys streamed; the model
     * part includes the sequence's key build; the encoder's, the sink write) */
    cJSON *sm = keys ? cJSON_AddObjectToObject(o, "key_stage_ms") : NULL;
    static const char *const stage_names[4] = { "preprocess", "model", "budget", "encode" };
    for (int i = 0; sm && i < 4; i++)
        cJSON_AddNumberToObject(sm, stage_names[i], r->stage_ms[i] / (double)keys);
    /* the same on the stage thread's CPU clock (not the model: its kernel
     * pool's threads run beside other work); what a loaded box cannot blur */
    cJSON *sc = keys ? cJSON_AddObjectToObject(o, "key_stage_cpu_ms") : NULL;
    static const char *const cpu_names[3] = { "preprocess", "budget", "encode" };
    for (int i = 0; sc && i < 3; i++)
        cJSON_AddNumberToObject(sc, cpu_names[i], r->stage_cpu_ms[i] / (double)keys);
    /* the mean trigger-to-sink latency part by part (they add up to its mean);
     * with a display, its parts after the sink (the display's own JSON) */
    cJSON *lb = keys ? cJSON_AddObjectToObject(o, "latency_breakdown_ms") : NULL;
    double lsum = 0;
    for (int i = 0; lb && i < RUN_LAT_PARTS; i++) {
        cJSON_AddNumberToObject(lb, lat_part_names[i], r->lat_part_ms[i] / (double)keys);
        lsum += r->lat_part_ms[i] / (double)keys;
    }
    if (lb) {
        cJSON_AddNumberToObject(lb, "to_sink", lsum);
        if (disp)
            for (int i = 0; i < DISPLAY_LAT_PARTS; i++)
                if (isfinite(disp->part[i]))
                    cJSON_AddNumberToObject(lb, display_part_names[i], disp->part[i]);
    }
    /* CPU ms a key by stage between the first key and the end of capture
     * (start-up excluded; null when no key followed the first before capture
     * ended), and the attached display's (its JSON) */
    uint64_t dk = atomic_load(&r->cpu_first_taken) && r->cpu_last_keys > r->cpu_first_keys
                      ? r->cpu_last_keys - r->cpu_first_keys : 0;
    cJSON *cp = keys ? cJSON_AddObjectToObject(o, "cpu_ms_per_key") : NULL;
    double csum = 0;
    for (int i = 0; cp && i < RUN_CPU_PARTS; i++) {
        double v = dk ? (r->cpu_last[i] - r->cpu_first[i]) * 1e3 / (double)dk : NAN;
        csum += v;
        if (isfinite(v))
            cJSON_AddNumberToObject(cp, cpu_part_names[i], v);
        else
            cJSON_AddNullToObject(cp, cpu_part_names[i]);
    }
    if (cp) {
        double dc = disp ? disp->cpu_per_key : NAN;
        const char *const names[3] = {"daemon", "display", "total"};
        const double vals[3] = {csum, dc, csum + dc};
        for (int i = 0; i < 3; i++) {
            if (isfinite(vals[i]))
                cJSON_AddNumberToObject(cp, names[i], vals[i]);
            else
                cJSON_AddNullToObject(cp, names[i]);
        }
        cJSON_AddNumberToObject(cp, "keys", (double)dk);
    }
    /* which latency the fields give, and the sink's in any case */
    cJSON_AddStringToObject(o, "latency_to", shown ? "display" : "sink");
    NUM_OR_NULL("latency_sink_ms_p50", *p50);
    NUM_OR_NULL("latency_sink_ms_p95", *p95);
    if (disp)
        NUM_OR_NULL("keys_displayed", disp->presented);
    /* the take (with --record): how much of the capture it holds, and where
     * a disk error stopped it while capture and the stream went on */
    cJSON *tk = r->take_dir ? cJSON_AddObjectToObject(o, "record") : NULL;
    if (tk) {
        bool failed = atomic_load(&r->rec_failed);
        cJSON_AddNumberToObject(tk, "sets_written", (double)atomic_load(&r->rec_written));
        cJSON_AddNumberToObject(tk, "sets_left_out", (double)atomic_load(&r->rec_overflow));
        cJSON_AddBoolToObject(tk, "stopped_by_disk_error", failed);
        if (failed)
            cJSON_AddNumberToObject(tk, "sets_captured_at_stop", (double)atomic_load(&r->rec_stop_captured));
        else
            cJSON_AddNullToObject(tk, "sets_captured_at_stop");
    }
#undef NUM_OR_NULL
    /* the text in one buffer of its final size class: cJSON_Print grows its
     * buffer as the text grows, so the allocation count followed the
     * numbers' digits (tests/app case alloc compares two runs' counts and
     * failed 1 time in ~20 on a loaded machine: 1136 vs 1150 bytes) */
    char *s = cJSON_PrintBuffered(o, 16384, 1);
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

/* ---- the attached display (--display) ---- */

/* The stream's file path ("file:PATH" or a plain path), or NULL for srt://. */
static const char *stream_file(const char *url)
{
    if (!strncmp(url, "file:", 5))
        return url + 5;
    return strstr(url, "://") ? NULL : url;
}

/* Spawns the display on the stream file being written, headless and paced,
 * timing each key against the key-times file, and waits until it is set up
 * (its --ready-fd byte), at most limit_s: a live display that came up after
 * a short stream had ended showed only its last key (a cold start of its
 * libraries took about a second on a loaded 2-core machine). Its stdout (the
 * summary, also in its --json) is discarded. A display that exits or does
 * not answer in time is reported at the end by display_wait. */
static int display_spawn(struct run *r, const char *stream_path, double limit_s, struct f4d_err *err)
{
    char extra[sizeof r->cfg->display_args];
    snprintf(extra, sizeof extra, "%s", r->cfg->display_args);
    int ready[2];
    if (pipe(ready) < 0)
        return f4d_fail(err, F4D_EIO, "display: pipe: %s", strerror(errno));
    /* neither end leaks into other children (the descriptor the display
     * gets is its own dup2 copy) */
    fcntl(ready[0], F_SETFD, FD_CLOEXEC);
    fcntl(ready[1], F_SETFD, FD_CLOEXEC);
    /* the child's copy on a fixed descriptor (dup2 clears close-on-exec
     * there; the same number would keep it) */
    int child_fd = ready[1] == 3 ? 4 : 3;
    char fd_arg[16];
    snprintf(fd_arg, sizeof fd_arg, "%d", child_fd);
    char *argv[48];
    int n = 0;
    argv[n++] = (char *)r->cfg->display;
    argv[n++] = "--headless";
    argv[n++] = "--no-status";
    argv[n++] = "--realtime";
    argv[n++] = "--follow";
    argv[n++] = "--key-times";
    argv[n++] = r->kt_path;
    argv[n++] = "--json";
    argv[n++] = r->display_json;
    argv[n++] = "--ready-fd";
    argv[n++] = fd_arg;
    const int fixed = n, most = 46; /* the stream path and NULL follow */
    char *save = NULL;
    for (char *t = strtok_r(extra, " \t", &save); t; t = strtok_r(NULL, " \t", &save)) {
        if (n >= most) {
            close(ready[0]);
            close(ready[1]);
            return f4d_fail(err, F4D_EINVAL, "display_args: more than %d arguments", most - fixed);
        }
        argv[n++] = t;
    }
    argv[n++] = (char *)stream_path;
    argv[n] = NULL;
    posix_spawn_file_actions_t fa;
    posix_spawn_file_actions_init(&fa);
    posix_spawn_file_actions_addopen(&fa, 1, "/dev/null", O_WRONLY, 0);
    posix_spawn_file_actions_adddup2(&fa, ready[1], child_fd);
    extern char **environ;
    int rc = posix_spawn(&r->display_pid, r->cfg->display, &fa, NULL, argv, environ);
    posix_spawn_file_actions_destroy(&fa);
    close(ready[1]);
    if (rc != 0) {
        close(ready[0]);
        r->display_pid = 0;
        return f4d_fail(err, F4D_EIO, "display %s: cannot start: %s", r->cfg->display, strerror(rc));
    }
    /* a byte: set up; end of file: it exited (or closed the descriptor)
     * before that; neither in limit_s: go on without it. In steps of at
     * most 50 ms: a stop is not kept waiting. */
    struct pollfd pf = { .fd = ready[0], .events = POLLIN };
    uint64_t t0 = mono_ns();
    while (!*r->stop) {
        double left_ms = limit_s * 1e3 - (double)(mono_ns() - t0) * 1e-6;
        if (left_ms <= 0) { /* a warning, shown under --quiet too */
            fprintf(stderr, "forge4d run: display %s: not set up after %.0f s; starting without it\n",
                    r->cfg->display, limit_s);
            break;
        }
        int pr = poll(&pf, 1, left_ms < 50 ? (int)ceil(left_ms) : 50);
        if (pr > 0) {
            char b;
            while (read(ready[0], &b, 1) < 0 && errno == EINTR) {
            }
            break;
        }
        if (pr < 0 && errno != EINTR)
            break; /* cannot wait: go on, as after the limit */
    }
    close(ready[0]);
    return 0;
}

/* Ends a display that did not end by itself: SIGTERM, then SIGKILL after
 * 3 s (a hung one may ignore SIGTERM). */
static void display_end(pid_t pid)
{
    kill(pid, SIGTERM);
    uint64_t t0 = mono_ns();
    while (waitpid(pid, NULL, WNOHANG) == 0) {
        if (mono_ns() - t0 > 3000000000u) {
            kill(pid, SIGKILL);
            waitpid(pid, NULL, 0);
            return;
        }
        nanosleep(&(struct timespec){0, 20000000}, NULL);
    }
}

/* Waits for the display to exit (it does at the end packet), at most
 * limit_s, or until a second stop request (*stop 2: a signal after the run
 * was already stopping): a hung display must not hold a stopping appliance.
 * Returns its exit status, DISPLAY_TIMEOUT or DISPLAY_STOPPED (ended here). */
enum { DISPLAY_TIMEOUT = -1, DISPLAY_STOPPED = -2 };
static int display_wait(struct run *r, double limit_s)
{
    if (r->display_pid <= 0)
        return DISPLAY_TIMEOUT;
    int st = 0;
    uint64_t t0 = mono_ns();
    bool told = false;
    pid_t got;
    while ((got = waitpid(r->display_pid, &st, WNOHANG)) == 0 && *r->stop < 2) {
        double waited = (double)(mono_ns() - t0) * 1e-9;
        if (waited >= limit_s)
            break;
        if (waited >= 2.0 && !told && !r->cfg->quiet) {
            fprintf(stderr, "[forge4d run] waiting for the display to end (at most %.0f s; a second stop "
                            "request ends it now)\n", limit_s);
            told = true;
        }
        nanosleep(&(struct timespec){0, 20000000}, NULL);
    }
    if (got == 0) {
        display_end(r->display_pid);
        r->display_pid = 0;
        return *r->stop >= 2 ? DISPLAY_STOPPED : DISPLAY_TIMEOUT;
    }
    r->display_pid = 0;
    return got > 0 && WIFEXITED(st) ? WEXITSTATUS(st) : DISPLAY_TIMEOUT;
}

/* ---- the command ---- */
static int usage(void)
{
    fprintf(stderr, "usage: forge4d run [--board FILE | --replay TAKE] [--weights W] [--stream file:PATH]\n"
                    "                   [--record DIR] [--seconds S] [--keys N] [--stats-json FILE] [--rig-json FILE]\n"
                    "                   [--precision f32|f16|int8] [--quality low|medium|high]\n"
                    "                   [--codec-effort fast|default|max] [--threads N]\n"
                    "                   [--stall-ms MS] [--config FILE | --no-config] [--quiet]\n"
                    "                   [--lockstep auto|off] [--motion on|off] [--key-hz HZ]\n"
                    "                   [--key-times FILE] [--display F4D_DISPLAY [--display-args ARGS]\n"
                    "                    [--display-json FILE]]\n"
                    "  settings absent from the command line come from the config file (default "
                    F4D_RUN_CONFIG_DEFAULT ", key = value; the same names without --, '-' as '_')\n");
    return 2;
}

static int parse_args(struct run_config *c, int argc, char **argv, bool apply, const char **config, bool *no_config)
{
    for (int i = 0; i < argc; i++) {
        const char *a = argv[i], *v = i + 1 < argc ? argv[i + 1] : NULL;
        if (!strcmp(a, "--quiet")) {
            c->quiet = true;
            continue;
        }
        if (!strcmp(a, "--no-config")) {
            *no_config = true;
            continue;
        }
        if (strncmp(a, "--", 2) || !v) {
            fprintf(stderr, "forge4d run: unknown or incomplete option \"%s\"\n", a);
            return usage();
        }
        i++;
        if (!strcmp(a, "--config")) {
            *config = v;
            continue;
        }
        char key[32];
        snprintf(key, sizeof key, "%s", a + 2);
        for (char *p = key; *p; p++)
            *p = *p == '-' ? '_' : *p;
        struct f4d_err err = {0};
        struct run_config probe = *c;
        if (run_config_set(apply ? c : &probe, key, v, &err) < 0) {
            fprintf(stderr, "forge4d run: --%s\n", err.msg);
            return 2;
        }
    }
    return 0;
}

static int run_threads(struct run *r, struct f4d_capture_stats *st, struct f4d_err *err)
{
    pthread_t th_rec, th_inf, th_str, th_stat;
    bool rec = r->take_dir != NULL;
    sigset_t block, old;
    sigemptyset(&block);
    sigaddset(&block, SIGINT);
    sigaddset(&block, SIGTERM);
    pthread_sigmask(SIG_BLOCK, &block, &old); /* signals go to the capture thread */
    r->t0 = mono_ns();
    atomic_store(&r->capturing, 1);
    bool ok_stat = pthread_create(&th_stat, NULL, status_main, r) == 0;
    bool ok_rec = rec && pthread_create(&th_rec, NULL, record_main, r) == 0;
    bool ok_inf = r->have_infer && pthread_create(&th_inf, NULL, infer_main, r) == 0;
    bool ok_str = ok_inf && pthread_create(&th_str, NULL, stream_main, r) == 0;
    pthread_sigmask(SIG_SETMASK, &old, NULL);

    int rc;
    struct f4d_capture_config cfg = {0};
    cfg.on_ready = on_ready;
    if (!ok_stat || ok_rec != rec || ok_inf != r->have_infer || ok_str != ok_inf) {
        rc = f4d_fail(err, F4D_ENOMEM, "cannot start the stage threads");
        if (ok_inf && !ok_str)
            run_fifo_close(&r->key_q); /* nothing will drain it */
    } else {
        rc = f4d_capture_run(r->rig, &cfg, on_set, on_progress, r, r->stop, st, err);
        on_progress(r, st, 0);
    }
    atomic_store(&r->capturing, 0);
    r->cpu_last_keys = atomic_load(&r->keys);
    cpu_by_stage(r->cpu_last); /* every stage thread still runs */

    /* stop: the set waiting for inference is dropped, the key in flight finishes */
    struct run_slot *s = run_fifo_try_pop(&r->infer_box);
    if (s) {
        atomic_fetch_add(&r->sets_skipped, 1);
        slot_release(r, s);
    }
    run_fifo_close(&r->infer_box);
    run_fifo_close(&r->rec_q);
    if (ok_inf)
        pthread_join(th_inf, NULL); /* closes key_q */
    if (ok_str)
        pthread_join(th_str, NULL);
    if (ok_rec)
        pthread_join(th_rec, NULL);
    r->t_end = mono_ns();
    atomic_store(&r->done, 1);
    if (ok_stat)
        pthread_join(th_stat, NULL);
    return rc;
}

int forge4d_run_main(int argc, char **argv, volatile sig_atomic_t *stop)
{
    struct run_config cfg;
    run_config_defaults(&cfg);
    const char *config = NULL;
    bool no_config = false;
    int rc = parse_args(&cfg, argc, argv, false, &config, &no_config); /* validate; find --config */
    if (rc)
        return rc;
    struct f4d_err err = {0};
    if (config || (!no_config && access(F4D_RUN_CONFIG_DEFAULT, F_OK) == 0)) {
        if (run_config_load(&cfg, config ? config : F4D_RUN_CONFIG_DEFAULT, &err) < 0) {
            fprintf(stderr, "forge4d run: %s\n", err.msg);
            return 1;
        }
    }
    if ((rc = parse_args(&cfg, argc, argv, true, &config, &no_config)))
        return rc;
    if (cfg.stream[0] && !cfg.weights[0]) {
        fprintf(stderr, "forge4d run: --stream needs --weights (a stream carries the model's Gaussians)\n");
        return 2;
    }
    if (cfg.display[0] && !(cfg.stream[0] && stream_file(cfg.stream))) {
        fprintf(stderr, "forge4d run: --display follows a stream file (--stream file:PATH); for srt:// run "
                "f4d-display as the receiver\n");
        return 2;
    }

    struct hal_board board;
    if (cfg.replay[0])
        rc = hal_replay_board(&board, cfg.replay, true, &err);
    else
        rc = hal_board_load(&board, cfg.board[0] ? cfg.board : F4D_RUN_BOARD_DEFAULT, &err);
    if (rc < 0) {
        fprintf(stderr, "forge4d run: %s\n", err.msg);
        return 1;
    }

    struct run *r = calloc(1, sizeof *r);
    if (!r) {
        fprintf(stderr, "forge4d run: out of memory\n");
        return 1;
    }
    r->cfg = &cfg;
    r->board = &board;
    r->stop = stop;
    r->tty = isatty(2) != 0;
    /* record = .../take-%Y%m%dT%H%M%SZ: one take per start (a restarted
     * service must not meet its last take) */
    char take_dir[sizeof cfg.record + 64];
    if (strchr(cfg.record, '%')) {
        time_t now = time(NULL);
        struct tm tm;
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wformat-nonliteral" /* the pattern is the user's, by design */
        size_t n = gmtime_r(&now, &tm) ? strftime(take_dir, sizeof take_dir, cfg.record, &tm) : 0;
#pragma GCC diagnostic pop
        if (n == 0) {
            fprintf(stderr, "forge4d run: record = %s: bad time pattern\n", cfg.record);
            free(r);
            return 2;
        }
    } else {
        snprintf(take_dir, sizeof take_dir, "%s", cfg.record);
    }
    r->take_dir = take_dir[0] ? take_dir : NULL;
    r->rss_start = r->rss_end = NAN;
    r->hb_capture.name = "capture";
    r->hb_record.name = "recorder";
    r->hb_infer.name = "inference";
    r->hb_stream.name = "stream";
    r->all_mask = board.n_cams >= 32 ? 0xffffffffu : (1u << board.n_cams) - 1;
    pthread_mutex_init(&r->st_mu, NULL);
    pthread_mutex_init(&r->idle_mu, NULL);
    pthread_cond_init(&r->idle_cv, NULL);
    atomic_store(&r->infer_idle, 1);
    int status = 1;
    struct hal_rig rig;
    bool rig_open = false;
    struct f4d_simscene *scene = NULL;

    if (cfg.weights[0]) {
        const char *env = getenv("F4D_RUN_TEST_INFER_DELAY_MS");
        struct run_infer_config ic = {.weights = cfg.weights, .wtype = FK_W_F32, .threads = cfg.threads,
                                      .delay_ms = env ? (uint32_t)strtoul(env, NULL, 10) : 0};
        ic.motion_off = cfg.motion_off;
        ic.wtype = !strcmp(cfg.precision, "f16") ? FK_W_F16 : !strcmp(cfg.precision, "int8") ? FK_W_Q8 : FK_W_F32;
        r->lockstep = waiting_sim(&board) && !cfg.no_lockstep;
        if (infer_new_nicer(&r->infer, &ic, &board, r->lockstep, &err) < 0 ||
            run_encoder_codec_new(&r->enc, r->infer.capacity, cfg.quality, cfg.codec_effort, &err) < 0)
            goto out;
        r->have_infer = true;
        if (cfg.stream[0]) {
            if (run_sink_open(&r->sink, cfg.stream, r->enc.packet_cap, &err) < 0)
                goto out;
            r->have_sink = true;
        }
        /* key times for a display: --key-times, or beside the stream file
         * when a display is attached */
        const char *sf = cfg.stream[0] ? stream_file(cfg.stream) : NULL;
        if (cfg.key_times[0] || cfg.display[0]) {
            const char *base = cfg.key_times[0] ? cfg.key_times : sf, *ext = cfg.key_times[0] ? "" : ".keys";
            if (strlen(base) + strlen(ext) >= sizeof r->kt_path) {
                f4d_fail(&err, F4D_EINVAL, "key times path too long");
                goto out;
            }
            memcpy(r->kt_path, base, strlen(base));
            memcpy(r->kt_path + strlen(base), ext, strlen(ext) + 1);
        }
        if (r->kt_path[0]) {
            r->kt_buf = malloc(4096);
            if (!r->kt_buf || !(r->kt = fopen(r->kt_path, "w"))) {
                f4d_fail(&err, F4D_EIO, "key times %s: %s", r->kt_path, r->kt_buf ? strerror(errno) : "out of memory");
                goto out;
            }
            setvbuf(r->kt, r->kt_buf, _IOFBF, 4096);
        }
        if (cfg.display[0]) {
            const char *base = cfg.display_json[0] ? cfg.display_json : sf,
                       *ext = cfg.display_json[0] ? "" : ".display.json";
            if (strlen(base) + strlen(ext) >= sizeof r->display_json) {
                f4d_fail(&err, F4D_EINVAL, "display JSON path too long");
                goto out;
            }
            memcpy(r->display_json, base, strlen(base));
            memcpy(r->display_json + strlen(base), ext, strlen(ext) + 1);
            remove(r->display_json); /* a summary left from an earlier run must not be read as this one's */
            if (display_spawn(r, sf, 60.0, &err) < 0)
                goto out;
        }
        r->pkt = malloc(r->enc.packet_cap);
        r->lat_ms = calloc(RUN_LAT_MAX, sizeof *r->lat_ms);
        if (!r->pkt || !r->lat_ms) {
            f4d_fail(&err, F4D_ENOMEM, "out of memory");
            goto out;
        }
        for (int i = 0; i < RUN_KEYS; i++) {
            if (splat_frame_reserve(&r->kbuf[i].f, r->infer.capacity, r->infer.motion, &err) < 0)
                goto out;
            if (!(r->kbuf[i].match = malloc(r->infer.capacity * sizeof *r->kbuf[i].match))) {
                f4d_fail(&err, F4D_ENOMEM, "out of memory");
                goto out;
            }
        }
        if (!cfg.quiet)
            fprintf(stderr, "[forge4d run] %s (%s): %zu Gaussians per key before the budget, one key %.0f ms at start; "
                    "%s\n", cfg.weights, cfg.precision, r->infer.capacity, r->infer.warm_ms,
                    r->infer.motion ? "motion M1/M2 encoded with the keys (a key leaves one set late)"
                    : cfg.motion_off ? "motion off (the motion head skipped: keys without motion, out at once)"
                                     : "no motion in the weights (keys without motion)");
    } else if (!cfg.quiet) {
        fprintf(stderr, "[forge4d run] no weights: capture%s only, no inference or stream\n",
                r->take_dir ? " and recording" : "");
    }
    /* about two seconds of sets for the recorder (its fdatasync runs on
     * the take's own thread; this covers writes the kernel throttles when
     * the disk falls behind the page cache), three for inference */
    uint32_t rate2 = 2 * ((board.trigger.rate_mhz + 999) / 1000);
    r->rec_cap = r->take_dir ? (rate2 < 8 ? 8 : rate2 > 64 ? 64 : rate2) : 0;
    r->n_slots = r->rec_cap + 3;
    r->slots = calloc(r->n_slots, sizeof *r->slots);
    if (!r->slots || run_fifo_init(&r->free_slots, r->n_slots, &err) < 0 ||
        run_fifo_init(&r->rec_q, r->rec_cap ? r->rec_cap : 1, &err) < 0 ||
        run_fifo_init(&r->infer_box, 1, &err) < 0 || run_fifo_init(&r->free_keys, RUN_KEYS, &err) < 0 ||
        run_fifo_init(&r->key_q, RUN_KEYS, &err) < 0) {
        f4d_fail(&err, F4D_ENOMEM, "out of memory");
        goto out;
    }
    for (uint32_t i = 0; i < r->n_slots; i++)
        run_fifo_try_push(&r->free_slots, &r->slots[i]);
    for (int i = 0; i < RUN_KEYS; i++)
        run_fifo_try_push(&r->free_keys, &r->kbuf[i]);

    if (hal_rig_open(&rig, &board, &err) < 0)
        goto out;
    rig_open = true;
    r->rig = &rig;
    void *world = hal_rig_session(&rig, "sim");
    if (world && strcmp(board.sim.scene, "pattern") != 0) {
        if (f4d_simscene_new(&scene, board.sim.scene, board.sim.seed, board.n_cams, board.cams[0].width,
                             board.cams[0].height, &err) < 0)
            goto out;
        hal_sim_set_renderer(world, f4d_simscene_render, scene);
    }

    struct f4d_capture_stats st;
    memset(&st, 0, sizeof st);
    rc = run_threads(r, &st, &err);
    status = 0;
    if (rc < 0) {
        fprintf(stderr, "forge4d run: capture: %s\n", err.msg);
        status = 1;
    }
    if (r->take) {
        struct f4d_err e = {0};
        if (f4d_take_close(r->take, &e) < 0) {
            fprintf(stderr, "forge4d run: %s\n", e.msg);
            status = 1;
        }
        r->take = NULL;
    }
    if (r->have_sink) {
        struct f4d_err e = {0};
        r->have_sink = false;
        if (r->sink.close(r->sink.self, &e) < 0) {
            fprintf(stderr, "forge4d run: %s\n", e.msg);
            status = 1;
        }
    }
    if (cfg.rig_json[0] && r->have_infer && r->infer.rig) {
        struct splat_rig kr;
        struct f4d_err e = {0};
        if (r->infer.rig(r->infer.self, &kr) == 1 && splat_rig_save(cfg.rig_json, &kr, &e) < 0) {
            fprintf(stderr, "forge4d run: %s\n", e.msg);
            status = 1;
        }
    }
    if (r->kt) {
        fclose(r->kt);
        r->kt = NULL;
    }
    /* the display exits once it has shown the end packet the sink just wrote */
    struct display_figures disp;
    bool have_disp = r->display_pid > 0;
    if (have_disp) {
        int drc = display_wait(r, 120.0);
        if (drc != 0) {
            fprintf(stderr, "forge4d run: display %s %s\n", cfg.display,
                    drc == DISPLAY_STOPPED   ? "had not ended at a second stop request: stopped"
                    : drc == DISPLAY_TIMEOUT ? "did not finish in 120 s: stopped"
                                             : "failed (see above)");
            status = 1;
        }
        display_figures_read(r->display_json, &disp);
    }
    double p50, p95;
    if (write_stats(r, cfg.stats_json[0] ? cfg.stats_json : NULL, have_disp ? &disp : NULL, &p50, &p95) < 0) {
        fprintf(stderr, "forge4d run: cannot write %s\n", cfg.stats_json);
        status = 1;
    }
    double wall = (double)(r->t_end - r->t0) * 1e-9;
    fprintf(stderr,
            "[forge4d run] done in %.1f s: %llu sets (%llu complete), frames dropped %llu late %llu duplicate %llu, "
            "sets incomplete %llu, skipped by inference %llu, lost for want of a slot %llu; take %llu sets "
            "(%llu left out%s); %llu keys (%.2f Hz, %llu dropped, %llu failed), latency p50 %.0f ms p95 %.0f ms, "
            "%.2f Mbit/s, %llu stream errors; rss %.0f -> %.0f MB\n",
            wall, (unsigned long long)atomic_load(&r->sets_captured), (unsigned long long)atomic_load(&r->sets_complete),
            (unsigned long long)st.sync.frames_dropped, (unsigned long long)st.sync.frames_late,
            (unsigned long long)st.sync.frames_duplicate, (unsigned long long)st.sync.sets_incomplete,
            (unsigned long long)atomic_load(&r->sets_skipped), (unsigned long long)atomic_load(&r->sets_no_slot),
            (unsigned long long)atomic_load(&r->rec_written), (unsigned long long)atomic_load(&r->rec_overflow),
            atomic_load(&r->rec_failed) ? ", then stopped by a disk error" : "",
            (unsigned long long)atomic_load(&r->keys), wall > 0 ? (double)atomic_load(&r->keys) / wall : 0.0,
            (unsigned long long)atomic_load(&r->keys_dropped), (unsigned long long)atomic_load(&r->infer_errors), p50,
            p95, wall > 0 ? (double)atomic_load(&r->stream_bytes) * 8e-6 / wall : 0.0,
            (unsigned long long)atomic_load(&r->stream_errors), r->rss_start, r->rss_end);
    if (have_disp)
        fprintf(stderr, "[forge4d run] display: %.1f fps, capture to display latency p50 %.0f ms p95 %.0f ms "
                "(%.0f keys timed)\n", disp.fps, disp.p50, disp.p95, disp.presented);
    goto cleanup;
out:
    fprintf(stderr, "forge4d run: %s\n", err.msg[0] ? err.msg : "setup failed");
cleanup:
    if (r->display_pid > 0) { /* setup failed after the display started */
        kill(r->display_pid, SIGTERM);
        waitpid(r->display_pid, NULL, 0);
    }
    if (r->kt)
        fclose(r->kt);
    free(r->kt_buf);
    if (r->take) {
        struct f4d_err e = {0};
        f4d_take_close(r->take, &e);
    }
    if (r->have_sink) {
        struct f4d_err e = {0};
        r->sink.close(r->sink.self, &e);
    }
    if (rig_open)
        hal_rig_close(&rig);
    f4d_simscene_free(scene);
    if (r->infer.free)
        r->infer.free(r->infer.self);
    if (r->enc.free)
        r->enc.free(r->enc.self);
    for (int i = 0; i < RUN_KEYS; i++) {
        splat_frame_free(&r->kbuf[i].f);
        free(r->kbuf[i].match);
    }
    run_fifo_destroy(&r->free_slots);
    run_fifo_destroy(&r->rec_q);
    run_fifo_destroy(&r->infer_box);
    run_fifo_destroy(&r->free_keys);
    run_fifo_destroy(&r->key_q);
    pthread_mutex_destroy(&r->st_mu);
    pthread_mutex_destroy(&r->idle_mu);
    pthread_cond_destroy(&r->idle_cv);
    free(r->slots);
    free(r->slot_mem);
    free(r->pkt);
    free(r->lat_ms);
    free(r);
    return status;
}
