/* run_internal.h: pieces of `forge4d run`, the appliance daemon (run.c wires
 * them): a bounded pointer FIFO, the three replaceable stages (inference,
 * encoder, sink) and the config file. App-internal: only run*.c include it.
 *
 * Why stages behind function tables: the sequence API (key-frame state and
 * motion), the SRT transport and the shipped weights replace one table each
 * without touching the threads, queues and policies in run.c.
 *
 *     struct run_fifo q;  run_fifo_init(&q, 8, &err);      // allocates once
 *     void *old = run_fifo_push_evict(&q, item);           // never blocks
 *     void *it;  while (run_fifo_pop(&q, &it) == 1) ...    // blocks; 0 = closed and empty
 */
#ifndef F4D_RUN_INTERNAL_H
#define F4D_RUN_INTERNAL_H

#include <pthread.h>
#include <signal.h>
#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>
#include <time.h>

#include "f4d_status.h"
#include "hal.h"
#include "interp.h"
#include "splat.h"

/* ---- clocks shared by the daemon's threads ---- */
static inline uint64_t mono_ns(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (uint64_t)ts.tv_sec * 1000000000u + (uint64_t)ts.tv_nsec;
}

/* The calling thread's CPU time (ms): what a stage cost, without the time
 * other jobs held the core. */
static inline double thread_cpu_ms(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
    return (double)ts.tv_sec * 1e3 + (double)ts.tv_nsec * 1e-6;
}

/* ---- the take of a capture run (forge4d record and forge4d run) ----
 * Creates the take in dir for the board's cameras with the formats capture
 * negotiated (st->formats), the board's JSON embedded in it. */
struct hal_board;
struct f4d_capture_stats;
struct f4d_take_writer;
int run_take_create(struct f4d_take_writer **w, const char *dir, const struct hal_board *board,
                    const struct f4d_capture_stats *st, struct f4d_err *err);

/* ---- bounded FIFO of pointers (mutex + condvar; storage allocated once) ---- */
struct run_fifo {
    pthread_mutex_t mu;
    pthread_cond_t cv;
    void **items;
    uint32_t cap, head, n, peak;
    bool closed;
};
int run_fifo_init(struct run_fifo *q, uint32_t cap, struct f4d_err *err);
void run_fifo_destroy(struct run_fifo *q);
/* false when full: the caller applies its own overload policy. */
bool run_fifo_try_push(struct run_fifo *q, void *item);
/* Pushes; when full, first removes the oldest item and returns it (else NULL). */
void *run_fifo_push_evict(struct run_fifo *q, void *item);
/* Oldest item without waiting, or NULL. */
void *run_fifo_try_pop(struct run_fifo *q);
/* Waits for an item: 1 with *item set, 0 once closed and empty. */
int run_fifo_pop(struct run_fifo *q, void **item);
/* Wakes every waiter; later pops drain what is left, then return 0. */
void run_fifo_close(struct run_fifo *q);
uint32_t run_fifo_depth(struct run_fifo *q);

/* ---- one synchronized set, copied out of the capture buffers ---- */
struct run_slot {
    struct hal_set set;                         /* frames[i] -> bufs[i] or NULL */
    struct hal_buffer bufs[HAL_RIG_CAMERAS_MAX];
    int refs;                                   /* holders: recorder, inference (atomic ops) */
    uint64_t arrive_wall_ns;                    /* CLOCK_MONOTONIC at on_set */
    uint64_t delivery_ns;                       /* rig clock: on_set time - trigger time */
};

/* ---- one key frame on its way to the encoder ---- */
struct run_key {
    struct splat_frame f;      /* metric Gaussians after the scene budget (with motion when the weights have it) */
    int32_t *match;            /* [capacity] codec match: index in key match_ref, -1 new (NULL: identity) */
    uint64_t match_ref;        /* seq of the key match refers to (UINT64_MAX: none) */
    uint64_t seq, t_us;        /* trigger sequence and time */
    uint64_t arrive_wall_ns, delivery_ns;
    uint64_t infer_start_ns;   /* CLOCK_MONOTONIC: inference took its set (the caller sets it, as arrive) */
    uint64_t queued_ns;        /* CLOCK_MONOTONIC: the key went into the stream's queue (run.c) */
    double infer_ms;           /* preprocessing + model + budget */
    double prep_ms, model_ms, budget_ms; /* its parts (wall): preprocessing, the sequence push
                                            (model + key build), the budget with the codec match */
    double prep_cpu_ms, budget_cpu_ms;   /* the inference thread's CPU time in those two */
};

/* ---- stage: synchronized set -> metric Gaussians (one key) ----
 * Preprocess + the Forge4D sequence (state between keys, motions M1 / M2,
 * metric cameras) + scene budget (motion carried through it). With motion
 * weights a key leaves one set late (its forward motion needs the next set);
 * with cfg motion_off the motion head is skipped and keys leave at once.
 * key: the caller sets out->arrive_wall_ns / delivery_ns / infer_start_ns for `set` first;
 * returns 1 with a key in *out (all its fields set, possibly an older set's),
 * 0 when none is ready yet, < 0 on error. flush (NULL: nothing held): the key
 * still held at the end, same returns. */
struct run_infer {
    void *self;
    size_t capacity;           /* most Gaussians one key can hold */
    bool motion;               /* keys carry motion arrays */
    double warm_ms;            /* one key's time at start (warm-up eval) */
    int (*key)(void *self, const struct hal_set *set, struct run_key *out, struct f4d_err *err);
    int (*flush)(void *self, struct run_key *out, struct f4d_err *err);
    /* The cameras of the last key put out (model world: its first camera,
     * metric): 1 with *out set, 0 before any key. */
    int (*rig)(void *self, struct splat_rig *out);
    void (*free)(void *self);
};
struct run_infer_config {
    const char *weights;
    int wtype;                 /* enum fk_wtype */
    int threads;               /* fk_ctx threads, 0 = all CPUs */
    uint32_t delay_ms;         /* test knob: added to every key (F4D_RUN_TEST_INFER_DELAY_MS) */
    bool motion_off;           /* skip the motion head: keys without motion, out at once */
    const struct budget_config *budget; /* NULL: budget_config_default() */
};
int run_infer_model_new(struct run_infer *st, const struct run_infer_config *cfg, const struct hal_board *board,
                        struct f4d_err *err);

/* ---- stage: key -> packets ---- */
struct run_encoder {
    void *self;
    size_t packet_cap;         /* bytes of the caller's packet buffer */
    /* pkt_out/len: the packet; intra forces an intra key (joins, recovery) */
    int (*header)(void *self, uint64_t t_us, uint8_t *pkt, size_t *len, struct f4d_err *err);
    int (*key)(void *self, const struct run_key *k, bool intra, uint8_t *pkt, size_t *len, struct f4d_err *err);
    int (*end)(void *self, uint64_t t_us, uint8_t *pkt, size_t *len, struct f4d_err *err);
    void (*free)(void *self);
};
int run_encoder_codec_new(struct run_encoder *st, size_t capacity, const char *quality, const char *effort,
                          struct f4d_err *err);

/* ---- stage: packets -> the stream transport (srt://, file:) ---- */
struct run_sink {
    void *self;
    int (*write)(void *self, const uint8_t *pkt, size_t len, struct f4d_err *err);
    int (*close)(void *self, struct f4d_err *err); /* frees self, also on error */
};
/* "srt://HOST:PORT?..." or "file:PATH" through f4d_transport (a plain path
 * is a file); max_packet: the largest packet that will be written. Other
 * schemes: F4D_ENOTSUP naming them. */
int run_sink_open(struct run_sink *st, const char *url, size_t max_packet, struct f4d_err *err);

/* ---- configuration: command line over the config file over defaults ---- */
struct run_config {
    char board[512], replay[512], weights[512], stream[512], record[512], stats_json[512];
    char rig_json[512];        /* at exit: the last key's metric cameras (splat rig JSON) */
    char key_times[512];       /* one line per streamed key: t_us (stream time), trigger and sent
                                  times on CLOCK_MONOTONIC (ns), seq; written before the key's packet */
    char display[512];         /* f4d-display to attach to a file stream (spawned, live) */
    char display_args[512];    /* extra arguments for it, separated by spaces */
    char display_json[512];    /* its JSON summary (default: the stream file + ".display.json") */
    char precision[16], quality[16];
    char codec_effort[16];     /* the encoder's search: fast (default: a live encoder shares the
                                  cores with inference), default or max (codec_enc_set_effort) */
    double seconds;            /* 0: until SIGINT / SIGTERM */
    double key_hz;             /* most keys a second (0: as many as inference manages): inference
                                  starts a key at most every 1 / key_hz s, leaving the rest of the
                                  CPU to capture, the encoder and a display on the same cores */
    uint32_t keys;             /* stop after this many keys were streamed (0: no limit) */
    int threads;
    uint32_t stall_ms;         /* watchdog: a stage busy this long on one item is reported */
    uint32_t intra_every;      /* keys between forced intra keys */
    bool quiet;
    bool no_lockstep;          /* lockstep = off: a waiting-clock sim rig hands sets over as a real one */
    bool motion_off;           /* motion = off: weights with a motion part run without their motion head;
                                  keys carry no motion and leave as soon as their set ran (on: M1 / M2,
                                  a key one set late) */
};
void run_config_defaults(struct run_config *c);
/* key=value lines, '#' comments; unknown keys and bad values are errors
 * naming the file, line and key. */
int run_config_load(struct run_config *c, const char *path, struct f4d_err *err);
int run_config_set(struct run_config *c, const char *key, const char *value, struct f4d_err *err);

int forge4d_run_main(int argc, char **argv, volatile sig_atomic_t *stop);

#endif
