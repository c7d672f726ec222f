/* hal_replay.c: a take played back as cameras + trigger (see hal_replay.h). */
#include "hal_replay.h"

#include "hal_backend.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "f4d_take.h"

#define RP_EVENTS_MAX 64
#define RP_EDGES_MAX 64 /* full: later edges are not reported */

struct rp_event {
    uint64_t arrival_ns;
    uint64_t set_index;
};

struct rp_world;
struct rp_cam {
    struct rp_world *w;
    uint32_t index;
    struct hal_cam_state st; /* format, configure/start state, aborted buffers, error */
    struct hal_bufq q;       /* caller buffers waiting for a frame */
    struct rp_event ev[RP_EVENTS_MAX];
    uint32_t n_ev;
};

struct rp_world {
    struct f4d_take_reader *take;  /* emission: walks the sets in order */
    struct f4d_take_reader *frames; /* delivery: its last set is reused by every camera */
    uint64_t frames_index;          /* set held by `frames`, UINT64_MAX = none */
    struct f4d_take_set fset;
    char dir[HAL_PATH_MAX];
    bool armed, trig_open;
    struct hal_world_clock clk;
    uint64_t base_ns;
    uint64_t next_set, n_sets;
    uint64_t next_set_ns; /* emission time of next_set */
    uint64_t corrupt;
    struct hal_edgeq edges; /* limit RP_EDGES_MAX */
    struct rp_cam *cams[HAL_RIG_CAMERAS_MAX];
    struct f4d_take_set cur;
    struct f4d_err err;
};

/* Rig time at which a set is "triggered": its edge, else its earliest frame. */
static uint64_t set_time(const struct rp_world *w, const struct f4d_take_set *s)
{
    uint64_t t = UINT64_MAX;
    if (s->has_edge)
        t = s->trigger_ts_ns;
    for (uint32_t c = 0; c < HAL_RIG_CAMERAS_MAX; c++)
        if (s->frames[c].present && s->frames[c].meta.host_ts_ns < t)
            t = s->frames[c].meta.host_ts_ns;
    if (t == UINT64_MAX)
        t = w->base_ns;
    return t < w->base_ns ? 0 : t - w->base_ns;
}

/* Finds the next readable set and its emission time (skipping corrupt ones). */
static void load_next_time(struct rp_world *w)
{
    while (w->next_set < w->n_sets) {
        if (f4d_take_read(w->take, w->next_set, &w->cur) == F4D_OK) {
            uint64_t t = set_time(w, &w->cur);
            w->next_set_ns = t > w->next_set_ns ? t : w->next_set_ns;
            return;
        }
        w->corrupt++;
        w->next_set++;
    }
}

static void cam_push(struct rp_cam *c, uint64_t arrival, uint64_t set_index)
{
    if (c->n_ev == RP_EVENTS_MAX) { /* nobody dequeues: lose the oldest */
        memmove(&c->ev[0], &c->ev[1], (RP_EVENTS_MAX - 1) * sizeof c->ev[0]);
        c->n_ev--;
    }
    uint32_t i = c->n_ev;
    while (i > 0 && c->ev[i - 1].arrival_ns > arrival) {
        c->ev[i] = c->ev[i - 1];
        i--;
    }
    c->ev[i].arrival_ns = arrival;
    c->ev[i].set_index = set_index;
    c->n_ev++;
}

static void world_advance(struct rp_world *w, uint64_t t)
{
    while (w->armed && w->next_set < w->n_sets && w->next_set_ns <= t) {
        /* w->cur holds next_set (read by load_next_time) */
        const struct f4d_take_set *s = &w->cur;
        uint64_t at = w->next_set_ns;
        if (s->has_edge) {
            struct hal_edge e = {s->seq, at, 0, true};
            hal_edgeq_push(&w->edges, &e);
        }
        for (uint32_t c = 0; c < HAL_RIG_CAMERAS_MAX; c++) {
            struct rp_cam *cam = w->cams[c];
            if (!cam || !cam->st.started || !s->frames[c].present)
                continue;
            uint64_t h = s->frames[c].meta.host_ts_ns;
            uint64_t arr = h > w->base_ns ? h - w->base_ns : 0;
            cam_push(cam, arr > at ? arr : at, w->next_set);
        }
        w->next_set++;
        load_next_time(w);
    }
}

static uint64_t world_now(struct rp_world *w)
{
    world_advance(w, hal_world_clock_read(&w->clk));
    return w->clk.now;
}

static void world_sleep_until(struct rp_world *w, uint64_t t)
{
    world_advance(w, hal_world_clock_wait(&w->clk, t));
}

static uint64_t world_next_event(struct rp_world *w)
{
    uint64_t n = UINT64_MAX;
    if (w->armed && w->next_set < w->n_sets)
        n = w->next_set_ns;
    for (uint32_t i = 0; i < HAL_RIG_CAMERAS_MAX; i++)
        if (w->cams[i] && w->cams[i]->n_ev && w->cams[i]->ev[0].arrival_ns < n)
            n = w->cams[i]->ev[0].arrival_ns;
    return n;
}

/* Next time anything can change for camera c (NULL: edges only). */
static uint64_t world_next_for(struct rp_world *w, const struct rp_cam *c)
{
    uint64_t n = UINT64_MAX;
    if (w->armed && w->next_set < w->n_sets)
        n = w->next_set_ns;
    if (c && c->n_ev && c->ev[0].arrival_ns < n)
        n = c->ev[0].arrival_ns;
    return n;
}

static uint64_t clk_now(void *ctx) { return world_now(ctx); }
static void clk_sleep(void *ctx, uint64_t t) { world_sleep_until(ctx, t); }
static uint64_t clk_next(void *ctx)
{
    world_now(ctx);
    return world_next_event(ctx);
}

/* ---- camera ---- */
static int cam_validate(void *ctx, struct hal_format *f)
{
    struct rp_cam *c = ctx;
    const struct hal_format *rec = &f4d_take_get_info(c->w->take)->formats[c->index];
    struct hal_format in = *f;
    /* a recording has exactly one format: everything else is adjusted to it */
    f->pixfmt = rec->pixfmt;
    f->width = rec->width;
    f->height = rec->height;
    f->stride = rec->stride;
    f->image_bytes = rec->image_bytes;
    if (f->rate_mhz == 0)
        f->rate_mhz = rec->rate_mhz;
    f->trigger = HAL_TRIGGER_HARDWARE;
    return memcmp(&in, f, sizeof in) == 0 ? HAL_FORMAT_VALID : HAL_FORMAT_ADJUSTED;
}

static int cam_configure(void *ctx, const struct hal_format *f)
{
    struct rp_cam *c = ctx;
    int rc = hal_cam_check_configure(&c->st);
    if (rc < 0)
        return rc;
    struct hal_format v = *f;
    /* validate never fails here: it only adjusts towards the recording */
    if (cam_validate(c, &v) != HAL_FORMAT_VALID)
        return hal_cam_fail(&c->st, F4D_EINVAL, "format differs from the recording");
    c->st.fmt = v;
    c->st.configured = true;
    return F4D_OK;
}

static int cam_start(void *ctx) { return hal_cam_fifo_start(&((struct rp_cam *)ctx)->st); }
/* A take is "streaming" from start to stop (its end shows as F4D_EEOF). */
static bool cam_streaming(void *ctx) { return ((struct rp_cam *)ctx)->st.streaming; }

static int cam_stop(void *ctx)
{
    struct rp_cam *c = ctx;
    c->n_ev = 0; /* frames in flight are lost */
    hal_cam_fifo_stop(&c->st, &c->q);
    return F4D_OK;
}

static int cam_enqueue(void *ctx, struct hal_buffer *b)
{
    struct rp_cam *c = ctx;
    return hal_cam_fifo_enqueue(&c->st, &c->q, b);
}

static int cam_deliver(struct rp_cam *c, struct hal_buffer **out)
{
    struct rp_world *w = c->w;
    struct rp_event e = c->ev[0];
    memmove(&c->ev[0], &c->ev[1], (c->n_ev - 1) * sizeof c->ev[0]);
    c->n_ev--;
    if (c->q.count == 0)
        return F4D_EBUSY;
    if (w->frames_index != e.set_index) {
        w->frames_index = UINT64_MAX;
        if (f4d_take_read(w->frames, e.set_index, &w->fset) != F4D_OK) {
            w->corrupt++;
            return F4D_ECORRUPT;
        }
        w->frames_index = e.set_index;
    }
    const struct f4d_take_frame *f = &w->fset.frames[c->index];
    struct hal_buffer *b = hal_bufq_pop(&c->q);
    uint8_t *data = b->data;
    size_t cap = b->capacity;
    void *user = b->user;
    *b = f->meta;
    b->data = data;
    b->capacity = cap;
    b->user = user;
    memcpy(b->data, f->data, f->bytes);
    b->bytes_used = f->bytes;
    b->camera_index = c->index;
    b->format = c->st.fmt;
    uint64_t h = f->meta.host_ts_ns;
    b->host_ts_ns = h > w->base_ns ? h - w->base_ns : 0;
    *out = b;
    return F4D_OK;
}

static int cam_dequeue(void *ctx, struct hal_buffer **out, uint32_t timeout_us)
{
    struct rp_cam *c = ctx;
    struct rp_world *w = c->w;
    int rc = hal_cam_dequeue_begin(&c->st, out);
    if (rc < 0 || *out)
        return rc;
    uint64_t now = world_now(w);
    uint64_t deadline = now + (uint64_t)timeout_us * 1000u;
    for (;;) {
        while (c->n_ev && c->ev[0].arrival_ns <= now)
            if (cam_deliver(c, out) == F4D_OK)
                return F4D_OK;
        if (w->next_set >= w->n_sets && c->n_ev == 0)
            return F4D_EEOF;
        if (now >= deadline)
            return F4D_ETIMEDOUT;
        uint64_t next = world_next_for(w, c);
        world_sleep_until(w, next < deadline ? next : deadline);
        now = w->clk.now;
    }
}

static void cam_close(void *ctx)
{
    struct rp_cam *c = ctx;
    c->w->cams[c->index] = NULL;
    free(c);
}

static const char *cam_last_error(void *ctx) { return ((struct rp_cam *)ctx)->st.err.msg; }

static const struct hal_camera_ops rp_camera_ops = {
    .api_version = HAL_API_VERSION,
    .validate = cam_validate,
    .configure = cam_configure,
    .start = cam_start,
    .stop = cam_stop,
    .enqueue = cam_enqueue,
    .dequeue = cam_dequeue,
    .close = cam_close,
    .last_error = cam_last_error,
    .streaming = cam_streaming,
};

/* ---- trigger ---- */
static int trig_arm(void *ctx, const struct hal_pulse_train *p)
{
    (void)p; /* the take decides when pulses come */
    struct rp_world *w = ctx;
    if (w->clk.realtime) /* world time goes on from where it stood */
        w->clk.real_t0 = hal_mono_ns() - w->clk.now;
    w->armed = true;
    world_now(w);
    return F4D_OK;
}
static int trig_disarm(void *ctx)
{
    ((struct rp_world *)ctx)->armed = false;
    return F4D_OK;
}
static int trig_read_edges(void *ctx, struct hal_edge *e, uint32_t max, uint32_t timeout_us)
{
    struct rp_world *w = ctx;
    uint64_t deadline = world_now(w) + (uint64_t)timeout_us * 1000u;
    while (w->edges.count == 0 && w->clk.now < deadline) {
        uint64_t next = world_next_for(w, NULL);
        world_sleep_until(w, next < deadline ? next : deadline);
    }
    return (int)hal_edgeq_pop(&w->edges, e, max);
}
static bool trig_done(void *ctx)
{
    struct rp_world *w = ctx;
    world_now(w);
    return w->next_set >= w->n_sets;
}
static void trig_close(void *ctx) { ((struct rp_world *)ctx)->trig_open = false; }
static const char *trig_last_error(void *ctx) { return ((struct rp_world *)ctx)->err.msg; }

static const struct hal_trigger_ops rp_trigger_ops = {
    .api_version = HAL_API_VERSION,
    .arm = trig_arm,
    .disarm = trig_disarm,
    .read_edges = trig_read_edges,
    .close = trig_close,
    .done = trig_done,
    .last_error = trig_last_error,
};

/* ---- backend ---- */
static int rp_session_open(const struct hal_board *board, void **session, struct f4d_err *err)
{
    const char *dir = NULL;
    for (uint32_t i = 0; i < board->n_cams; i++) {
        if (strcmp(board->cams[i].backend, "replay") != 0)
            continue;
        if (dir && strcmp(dir, board->cams[i].address) != 0)
            return f4d_fail(err, F4D_EINVAL, "replay: all replay cameras must play the same take");
        dir = board->cams[i].address;
    }
    if (!dir || !dir[0])
        return f4d_fail(err, F4D_EINVAL, "replay: no camera names a take directory (address)");
    struct rp_world *w = calloc(1, sizeof *w);
    if (!w)
        return f4d_fail(err, F4D_ENOMEM, "replay: out of memory");
    snprintf(w->dir, sizeof w->dir, "%s", dir);
    int rc = f4d_take_open(&w->take, dir, err);
    if (rc < 0) {
        free(w);
        return rc;
    }
    if ((rc = f4d_take_open(&w->frames, dir, err)) < 0) {
        f4d_take_reader_close(w->take);
        free(w);
        return rc;
    }
    w->frames_index = UINT64_MAX;
    w->edges.limit = RP_EDGES_MAX;
    w->clk.realtime = board->sim.realtime;
    w->clk.real_t0 = hal_mono_ns();
    w->n_sets = f4d_take_count(w->take);
    /* time base: the first readable set starts 1 ms after rig time 0 */
    w->base_ns = 0;
    load_next_time(w);
    if (w->next_set < w->n_sets) {
        uint64_t t0 = set_time(w, &w->cur);
        w->base_ns = t0 > 1000000u ? t0 - 1000000u : 0;
        w->next_set_ns = 0;
        w->next_set_ns = set_time(w, &w->cur);
    }
    *session = w;
    return F4D_OK;
}

static void rp_session_close(void *s)
{
    struct rp_world *w = s;
    f4d_take_reader_close(w->take);
    f4d_take_reader_close(w->frames);
    free(w);
}

static int rp_camera_open(void *session, const struct hal_camera_config *cfg, uint32_t index,
                          struct hal_camera *out, struct f4d_err *err)
{
    struct rp_world *w = session;
    const struct f4d_take_info *info = f4d_take_get_info(w->take);
    if (index >= info->n_cams)
        return f4d_fail(err, F4D_ENODEV, "replay camera %s: take %s has only %u cameras", cfg->id,
                        w->dir, (unsigned)info->n_cams);
    if (w->cams[index])
        return f4d_fail(err, F4D_EBUSY, "replay camera %u already open", (unsigned)index);
    struct rp_cam *c = calloc(1, sizeof *c);
    if (!c)
        return f4d_fail(err, F4D_ENOMEM, "replay: out of memory");
    c->w = w;
    c->index = index;
    hal_cam_name(&c->st, "replay camera %u", (unsigned)index);
    w->cams[index] = c;
    hal_camera_bind(out, &rp_camera_ops, c, index);
    return F4D_OK;
}

static int rp_trigger_open(void *session, const struct hal_trigger_config *cfg,
                           struct hal_trigger *out, struct f4d_err *err)
{
    (void)cfg;
    struct rp_world *w = session;
    return hal_trigger_claim(&w->trig_open, out, &rp_trigger_ops, w, "replay trigger", err);
}

static int rp_clock_get(void *session, struct hal_clock *out)
{
    hal_clock_bind(out, clk_now, clk_sleep, clk_next, session);
    return F4D_OK;
}

const struct hal_backend hal_replay_backend = {
    .api_version = HAL_API_VERSION,
    .name = "replay",
    .session_open = rp_session_open,
    .session_close = rp_session_close,
    .camera_open = rp_camera_open,
    .trigger_open = rp_trigger_open,
    .clock_get = rp_clock_get,
};

uint64_t hal_replay_corrupt_sets(const void *session)
{
    return session ? ((const struct rp_world *)session)->corrupt : 0;
}

int hal_replay_board(struct hal_board *b, const char *dir, bool realtime, struct f4d_err *err)
{
    struct f4d_take_reader *r;
    int rc = f4d_take_open(&r, dir, err);
    if (rc < 0)
        return rc;
    const struct f4d_take_info *info = f4d_take_get_info(r);
    hal_board_defaults(b);
    snprintf(b->name, sizeof b->name, "replay");
    b->n_cams = info->n_cams;
    b->sim.realtime = realtime;
    snprintf(b->trigger.backend, sizeof b->trigger.backend, "replay");
    b->trigger.rate_mhz = info->rate_mhz ? info->rate_mhz : 30000;
    for (uint32_t i = 0; i < info->n_cams; i++) {
        struct hal_camera_config *c = &b->cams[i];
        snprintf(c->backend, sizeof c->backend, "replay");
        snprintf(c->id, sizeof c->id, "%s", info->cam_ids[i][0] ? info->cam_ids[i] : "replay");
        if (strlen(dir) >= sizeof c->address) {
            f4d_take_reader_close(r);
            return f4d_fail(err, F4D_EINVAL, "replay: take path too long");
        }
        snprintf(c->address, sizeof c->address, "%s", dir);
        c->width = info->formats[i].width;
        c->height = info->formats[i].height;
        c->pixfmt = info->formats[i].pixfmt;
        c->exposure_us = info->formats[i].exposure_us;
    }
    f4d_take_reader_close(r);
    return F4D_OK;
}
