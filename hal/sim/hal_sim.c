/* hal_sim.c: the simulated world (trigger generator, cameras, clock). */
#include "hal_sim.h"

#include "hal_backend.h"

#include <stdlib.h>
#include <string.h>

#define SIM_EVENTS_MAX 64  /* frames in flight per camera */
#define SIM_TRANSFER_NS 1500000u
#define SIM_DUP_DELAY_NS 1000000u
#define SIM_DEVICE_EPOCH_NS 1000000000000ull /* device clocks started 1000 s before the rig */

enum sim_kind { SIM_EV_NORMAL, SIM_EV_DUPLICATE, SIM_EV_LATE, SIM_EV_INCOMPLETE };

struct sim_event {
    uint64_t arrival_ns;
    uint64_t pulse_ns;
    uint64_t seq;
    uint64_t device_ts_ns;
    uint64_t frame_id;
    uint32_t clock_epoch; /* which device clock stamped it (bumped by reconnects) */
    uint8_t kind;
};

struct sim_world;

struct sim_cam {
    struct sim_world *w;
    uint32_t index;
    const struct hal_camera_config *cfg;
    struct hal_cam_state st; /* format, configure/start state, aborted buffers, error */
    struct hal_bufq q;       /* caller buffers waiting for a frame */
    struct sim_event ev[SIM_EVENTS_MAX];
    uint32_t n_ev;
    int64_t offset_ns;
    double drift;
    uint64_t frame_id;
    uint64_t disconnected_until;
    uint32_t clock_epoch, delivered_epoch;
    int start_fail;          /* hal_sim_fail_start: start returns this (<0), 0 = none */
};

struct sim_world {
    const struct hal_board *board;
    struct hal_sim_config cfg;
    uint64_t rng;
    struct hal_world_clock clk;
    /* trigger */
    bool trig_open, armed;
    uint64_t period_ns, width_ns;
    uint64_t next_pulse_ns, scheduled_limit;
    uint64_t extra_at; /* 0 = none pending */
    uint64_t seq;
    struct hal_edgeq edges; /* full: the oldest is lost (edges_overrun) */
    uint64_t edges_overrun;
    struct sim_cam *cams[HAL_RIG_CAMERAS_MAX];
    uint32_t n_cams;
    struct hal_sim_injected inj;
    hal_sim_render_fn render;
    void *render_user;
    struct f4d_err err;
};

/* ---- deterministic random numbers (splitmix64) ---- */
static uint64_t rng_next(uint64_t *s)
{
    uint64_t z = (*s += 0x9E3779B97F4A7C15ull);
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
    return z ^ (z >> 31);
}
static double rng_unit(uint64_t *s) { return (double)(rng_next(s) >> 11) * (1.0 / 9007199254740992.0); }
/* uniform in [-a, a] */
static double rng_sym(uint64_t *s, double a) { return (2.0 * rng_unit(s) - 1.0) * a; }

static void cam_new_clock(struct sim_cam *c)
{
    const struct hal_sim_faults *f = &c->w->cfg.faults;
    c->offset_ns = (int64_t)rng_sym(&c->w->rng, (double)f->clock_offset_ms * 1e6);
    c->drift = rng_sym(&c->w->rng, (double)f->clock_drift_ppm * 1e-6);
}

/* Inserts keeping events sorted by arrival (stable for equal times). */
static void cam_push_event(struct sim_cam *c, const struct sim_event *e)
{
    if (c->n_ev == SIM_EVENTS_MAX) { /* nobody is dequeuing: the oldest is lost */
        memmove(&c->ev[0], &c->ev[1], (SIM_EVENTS_MAX - 1) * sizeof c->ev[0]);
        c->n_ev--;
        c->w->inj.underruns++;
    }
    uint32_t i = c->n_ev;
    while (i > 0 && c->ev[i - 1].arrival_ns > e->arrival_ns) {
        c->ev[i] = c->ev[i - 1];
        i--;
    }
    c->ev[i] = *e;
    c->n_ev++;
}

static void world_emit_pulse(struct sim_world *w, uint64_t t)
{
    const struct hal_sim_faults *f = &w->cfg.faults;
    uint64_t seq = ++w->seq;
    w->inj.edges++;
    struct hal_edge e = {seq, t, w->board->trigger.line >= 0 ? (uint32_t)w->board->trigger.line : 0, true};
    if (hal_edgeq_push_overwrite(&w->edges, &e))
        w->edges_overrun++;

    for (uint32_t i = 0; i < w->n_cams; i++) {
        struct sim_cam *c = w->cams[i];
        if (!c || !c->st.started)
            continue;
        if (t < c->disconnected_until) {
            w->inj.frames_lost_disconnected++;
            w->inj.frames_dropped++;
            continue;
        }
        if (f->disconnect > 0 && rng_unit(&w->rng) < f->disconnect) {
            c->disconnected_until = t + (uint64_t)f->disconnect_ms * 1000000u;
            c->clock_epoch++;
            cam_new_clock(c);
            w->inj.disconnects++;
            w->inj.frames_lost_disconnected++;
            w->inj.frames_dropped++;
            continue;
        }
        w->inj.frames_exposed++;
        struct sim_event ev = {0};
        ev.pulse_ns = t;
        ev.seq = seq;
        ev.frame_id = ++c->frame_id;
        double dev = (double)SIM_DEVICE_EPOCH_NS + (double)t * (1.0 + c->drift) +
                     (double)c->offset_ns + rng_sym(&w->rng, (double)f->jitter_us * 1000.0);
        ev.device_ts_ns = (uint64_t)(dev > 0 ? dev : 0);
        ev.clock_epoch = c->clock_epoch;
        ev.arrival_ns = t + (uint64_t)c->st.fmt.exposure_us * 1000u + SIM_TRANSFER_NS +
                        (uint64_t)(rng_unit(&w->rng) * SIM_TRANSFER_NS);
        double u = rng_unit(&w->rng);
        double p = f->drop;
        if (u < p) {
            w->inj.frames_dropped++;
            continue;
        }
        if (u < (p += f->duplicate)) {
            cam_push_event(c, &ev);
            ev.kind = SIM_EV_DUPLICATE;
            ev.arrival_ns += SIM_DUP_DELAY_NS;
            w->inj.frames_duplicate++;
        } else if (u < (p += f->late)) {
            ev.kind = SIM_EV_LATE;
            ev.arrival_ns += (uint64_t)f->late_ms * 1000000u;
            w->inj.frames_late++;
        } else if (u < (p += f->incomplete)) {
            ev.kind = SIM_EV_INCOMPLETE;
            w->inj.frames_incomplete++;
        }
        cam_push_event(c, &ev);
    }
}

/* Runs the trigger generator up to time t. */
static void world_advance(struct sim_world *w, uint64_t t)
{
    const struct hal_sim_faults *f = &w->cfg.faults;
    for (;;) {
        bool regular = w->armed && w->next_pulse_ns <= t &&
                       (w->scheduled_limit == 0 || w->inj.pulses_scheduled < w->scheduled_limit);
        bool extra = w->extra_at && w->extra_at <= t;
        if (!regular && !extra)
            break;
        if (extra && (!regular || w->extra_at < w->next_pulse_ns)) {
            uint64_t at = w->extra_at;
            w->extra_at = 0;
            w->inj.triggers_extra++;
            world_emit_pulse(w, at);
            continue;
        }
        uint64_t at = w->next_pulse_ns;
        w->next_pulse_ns += w->period_ns;
        w->inj.pulses_scheduled++;
        if (f->trigger_missing > 0 && rng_unit(&w->rng) < f->trigger_missing)
            w->inj.triggers_missing++;
        else
            world_emit_pulse(w, at);
        if (f->trigger_extra > 0 && rng_unit(&w->rng) < f->trigger_extra)
            w->extra_at = at + w->period_ns / 2;
    }
}

static uint64_t world_now(struct sim_world *w)
{
    world_advance(w, hal_world_clock_read(&w->clk));
    return w->clk.now;
}

static void world_sleep_until(struct sim_world *w, uint64_t t)
{
    world_advance(w, hal_world_clock_wait(&w->clk, t));
}

static uint64_t world_next_event(struct sim_world *w)
{
    uint64_t n = UINT64_MAX;
    if (w->armed && (w->scheduled_limit == 0 || w->inj.pulses_scheduled < w->scheduled_limit))
        n = w->next_pulse_ns;
    if (w->extra_at && w->extra_at < n)
        n = w->extra_at;
    for (uint32_t i = 0; i < w->n_cams; i++) {
        struct sim_cam *c = w->cams[i];
        if (c && c->n_ev && c->ev[0].arrival_ns < n)
            n = c->ev[0].arrival_ns;
        if (c && c->disconnected_until > w->clk.now && c->disconnected_until < n)
            n = c->disconnected_until;
    }
    return n;
}

/* Next time anything can change for camera c (c = NULL: the trigger line only).
 * Other cameras' ready frames do not count: waiting on them would not advance. */
static uint64_t world_next_for(struct sim_world *w, const struct sim_cam *c)
{
    uint64_t n = UINT64_MAX;
    if (w->armed && (w->scheduled_limit == 0 || w->inj.pulses_scheduled < w->scheduled_limit))
        n = w->next_pulse_ns;
    if (w->extra_at && w->extra_at < n)
        n = w->extra_at;
    if (c && c->n_ev && c->ev[0].arrival_ns < n)
        n = c->ev[0].arrival_ns;
    if (c && c->disconnected_until > w->clk.now && c->disconnected_until < n)
        n = c->disconnected_until;
    return n;
}

/* ---- clock ops ---- */
static uint64_t clk_now(void *ctx) { return world_now(ctx); }
static void clk_sleep(void *ctx, uint64_t t) { world_sleep_until(ctx, t); }
static uint64_t clk_next(void *ctx)
{
    struct sim_world *w = ctx;
    world_now(w);
    return world_next_event(w);
}

/* ---- camera ops ---- */
static int cam_validate(void *ctx, struct hal_format *f)
{
    struct sim_cam *c = ctx;
    struct hal_format in = *f;
    if (f->pixfmt != HAL_PIXFMT_MONO8 && f->pixfmt != HAL_PIXFMT_RGB8)
        f->pixfmt = c->cfg->pixfmt == HAL_PIXFMT_MONO8 ? HAL_PIXFMT_MONO8 : HAL_PIXFMT_RGB8;
    if (f->width < 16)
        f->width = 16;
    if (f->width > 4096)
        f->width = 4096;
    if (f->height < 16)
        f->height = 16;
    if (f->height > 4096)
        f->height = 4096;
    f->width &= ~1u;
    f->height &= ~1u;
    if (f->rate_mhz < 1000)
        f->rate_mhz = 1000;
    if (f->rate_mhz > 1000000)
        f->rate_mhz = 1000000;
    f->trigger = HAL_TRIGGER_HARDWARE;
    if (f->exposure_us > 1000000000u / (f->rate_mhz / 1000u) / 1000u / 2u)
        f->exposure_us = 1000000000u / (f->rate_mhz / 1000u) / 1000u / 2u;
    uint32_t tight = f->width * hal_pixfmt_bytes_per_pixel(f->pixfmt);
    if (f->stride < tight)
        f->stride = tight;
    if (hal_format_finish(f) < 0)
        return hal_cam_fail(&c->st, F4D_EINVAL, "format cannot be represented");
    return memcmp(&in, f, sizeof in) == 0 ? HAL_FORMAT_VALID : HAL_FORMAT_ADJUSTED;
}

static int cam_configure(void *ctx, const struct hal_format *f)
{
    struct sim_cam *c = ctx;
    int rc = hal_cam_check_configure(&c->st);
    if (rc < 0)
        return rc;
    struct hal_format v = *f;
    if ((rc = hal_cam_check_validated(&c->st, cam_validate(c, &v))) < 0)
        return rc;
    c->st.fmt = v;
    c->st.configured = true;
    return F4D_OK;
}

static int cam_start(void *ctx)
{
    struct sim_cam *c = ctx;
    if (c->start_fail < 0)
        return hal_cam_fail(&c->st, c->start_fail, "start failed (injected)");
    return hal_cam_fifo_start(&c->st);
}

/* Streams once started, except while disconnected. */
static bool cam_streaming(void *ctx)
{
    struct sim_cam *c = ctx;
    return c->st.streaming && world_now(c->w) >= c->disconnected_until;
}

static int cam_stop(void *ctx)
{
    struct sim_cam *c = ctx;
    c->n_ev = 0; /* frames in flight are lost */
    hal_cam_fifo_stop(&c->st, &c->q);
    return F4D_OK;
}

static int cam_enqueue(void *ctx, struct hal_buffer *b)
{
    struct sim_cam *c = ctx;
    return hal_cam_fifo_enqueue(&c->st, &c->q, b);
}

static void stamp_write(uint8_t *d, size_t n, uint64_t seq, uint32_t cam)
{
    if (n < HAL_SIM_STAMP_BYTES)
        return;
    memcpy(d, "F4S1", 4);
    for (int i = 0; i < 4; i++)
        d[4 + i] = (uint8_t)(cam >> (8 * i));
    for (int i = 0; i < 8; i++)
        d[8 + i] = (uint8_t)(seq >> (8 * i));
}

int hal_sim_stamp_read(const uint8_t *d, size_t n, uint64_t *seq, uint32_t *cam)
{
    if (!d || n < HAL_SIM_STAMP_BYTES || memcmp(d, "F4S1", 4) != 0)
        return F4D_EINVAL;
    uint32_t c = 0;
    uint64_t s = 0;
    for (int i = 0; i < 4; i++)
        c |= (uint32_t)d[4 + i] << (8 * i);
    for (int i = 0; i < 8; i++)
        s |= (uint64_t)d[8 + i] << (8 * i);
    *cam = c;
    *seq = s;
    return F4D_OK;
}

static int cam_deliver(struct sim_cam *c, struct hal_buffer **out)
{
    struct sim_world *w = c->w;
    struct sim_event e = c->ev[0];
    memmove(&c->ev[0], &c->ev[1], (c->n_ev - 1) * sizeof c->ev[0]);
    c->n_ev--;
    struct hal_buffer *b = hal_bufq_pop(&c->q);
    if (!b) {
        w->inj.underruns++;
        return F4D_EBUSY;
    }
    b->format = c->st.fmt;
    int rc = w->render(w->render_user, c->index, e.pulse_ns, &c->st.fmt, b->data);
    if (rc < 0)
        hal_sim_render_pattern(NULL, c->index, e.pulse_ns, &c->st.fmt, b->data);
    stamp_write(b->data, c->st.fmt.image_bytes, e.seq, c->index);
    b->bytes_used = c->st.fmt.image_bytes;
    b->status = HAL_FRAME_OK;
    if (e.kind == SIM_EV_INCOMPLETE) {
        /* the last quarter of the packets never arrived */
        size_t keep = c->st.fmt.image_bytes - c->st.fmt.image_bytes / 4;
        memset(b->data + keep, 0, c->st.fmt.image_bytes - keep);
        b->bytes_used = keep;
        b->status = HAL_FRAME_MISSING_PACKETS;
    }
    /* a frame from another clock epoch than the last one delivered */
    b->flags = e.clock_epoch != c->delivered_epoch ? HAL_FRAME_FLAG_CLOCK_RESET : 0;
    if (e.clock_epoch > c->delivered_epoch)
        c->delivered_epoch = e.clock_epoch;
    b->camera_index = c->index;
    b->device_ts_ns = e.device_ts_ns;
    b->host_ts_ns = e.arrival_ns;
    b->frame_id = e.frame_id;
    b->trigger_seq = e.seq;
    *out = b;
    return F4D_OK;
}

static int cam_dequeue(void *ctx, struct hal_buffer **out, uint32_t timeout_us)
{
    struct sim_cam *c = ctx;
    struct sim_world *w = c->w;
    int rc = hal_cam_dequeue_begin(&c->st, out);
    if (rc < 0 || *out)
        return rc;
    uint64_t now = world_now(w);
    uint64_t deadline = now + (uint64_t)timeout_us * 1000u;
    for (;;) {
        while (c->n_ev && c->ev[0].arrival_ns <= now) {
            if (cam_deliver(c, out) == F4D_OK)
                return F4D_OK;
        }
        if (now < c->disconnected_until)
            return hal_cam_fail(&c->st, F4D_ENODEV, "disconnected");
        if (now >= deadline)
            return F4D_ETIMEDOUT;
        uint64_t next = world_next_for(w, c);
        world_sleep_until(w, next < deadline ? next : deadline);
        now = w->clk.now;
    }
}

static void cam_close(void *ctx)
{
    struct sim_cam *c = ctx;
    c->w->cams[c->index] = NULL;
    free(c);
}

static const char *cam_last_error(void *ctx) { return ((struct sim_cam *)ctx)->st.err.msg; }

static const struct hal_camera_ops sim_camera_ops = {
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

int hal_sim_fail_start(void *world, uint32_t cam, int rc)
{
    struct sim_world *w = world;
    if (!w || cam >= HAL_RIG_CAMERAS_MAX || !w->cams[cam] || rc > 0)
        return F4D_EINVAL;
    w->cams[cam]->start_fail = rc;
    return F4D_OK;
}

uint32_t hal_sim_buffers_held(const void *world, uint32_t cam)
{
    const struct sim_world *w = world;
    if (!w || cam >= HAL_RIG_CAMERAS_MAX || !w->cams[cam])
        return 0;
    return w->cams[cam]->q.count + w->cams[cam]->st.n_aborted;
}

/* ---- trigger ops ---- */
static int trig_arm(void *ctx, const struct hal_pulse_train *p)
{
    struct sim_world *w = ctx;
    if (p->rate_mhz == 0 || p->rate_mhz > 10000000u)
        return f4d_fail(&w->err, F4D_EINVAL, "sim trigger: rate %u mHz out of range",
                        (unsigned)p->rate_mhz);
    world_now(w);
    w->period_ns = 1000000000000ull / p->rate_mhz;
    w->width_ns = (uint64_t)p->width_us * 1000u;
    if (w->width_ns >= w->period_ns)
        return f4d_fail(&w->err, F4D_EINVAL, "sim trigger: pulse width %u us >= period",
                        (unsigned)p->width_us);
    w->next_pulse_ns = w->clk.now + w->period_ns;
    w->scheduled_limit = w->inj.pulses_scheduled + p->count;
    if (p->count == 0)
        w->scheduled_limit = 0;
    w->armed = true;
    return F4D_OK;
}

static int trig_disarm(void *ctx)
{
    struct sim_world *w = ctx;
    world_now(w);
    w->armed = false;
    w->extra_at = 0;
    return F4D_OK;
}

static int trig_read_edges(void *ctx, struct hal_edge *e, uint32_t max, uint32_t timeout_us)
{
    struct sim_world *w = ctx;
    uint64_t deadline = world_now(w) + (uint64_t)timeout_us * 1000u;
    while (w->edges.count == 0 && w->clk.now < deadline) {
        uint64_t next = world_next_for(w, NULL);
        world_sleep_until(w, next < deadline ? next : deadline);
    }
    return (int)hal_edgeq_pop(&w->edges, e, max);
}

static bool trig_done(void *ctx)
{
    struct sim_world *w = ctx;
    world_now(w);
    return w->scheduled_limit != 0 && w->inj.pulses_scheduled >= w->scheduled_limit && !w->extra_at;
}

static void trig_close(void *ctx)
{
    struct sim_world *w = ctx;
    w->armed = false;
    w->trig_open = false;
}

static const char *trig_last_error(void *ctx) { return ((struct sim_world *)ctx)->err.msg; }

static const struct hal_trigger_ops sim_trigger_ops = {
    .api_version = HAL_API_VERSION,
    .arm = trig_arm,
    .disarm = trig_disarm,
    .read_edges = trig_read_edges,
    .close = trig_close,
    .done = trig_done,
    .last_error = trig_last_error,
};

/* ---- backend ---- */
static int sim_session_open(const struct hal_board *board, void **session, struct f4d_err *err)
{
    const struct hal_sim_faults *f = &board->sim.faults;
    double sum = f->drop + f->duplicate + f->late + f->incomplete;
    if (f->drop < 0 || f->duplicate < 0 || f->late < 0 || f->incomplete < 0 || sum > 1.0 ||
        f->trigger_missing < 0 || f->trigger_missing > 1 || f->trigger_extra < 0 ||
        f->trigger_extra > 1 || f->disconnect < 0 || f->disconnect > 1)
        return f4d_fail(err, F4D_EINVAL,
                        "sim faults: probabilities must be in [0,1] and drop+duplicate+late+incomplete <= 1 (got %.3f)",
                        sum);
    struct sim_world *w = calloc(1, sizeof *w);
    if (!w)
        return f4d_fail(err, F4D_ENOMEM, "sim: out of memory");
    w->board = board;
    w->cfg = board->sim;
    w->rng = board->sim.seed ^ 0x5EEDF4D0ull;
    w->clk.realtime = board->sim.realtime;
    w->clk.real_t0 = hal_mono_ns();
    w->render = hal_sim_render_pattern;
    *session = w;
    return F4D_OK;
}

static void sim_session_close(void *s) { free(s); }

static int sim_camera_open(void *session, const struct hal_camera_config *cfg, uint32_t index,
                           struct hal_camera *out, struct f4d_err *err)
{
    struct sim_world *w = session;
    if (index >= HAL_RIG_CAMERAS_MAX || w->cams[index])
        return f4d_fail(err, F4D_EBUSY, "sim camera %s: index %u already open", cfg->id, (unsigned)index);
    struct sim_cam *c = calloc(1, sizeof *c);
    if (!c)
        return f4d_fail(err, F4D_ENOMEM, "sim camera %s: out of memory", cfg->id);
    c->w = w;
    c->index = index;
    c->cfg = cfg;
    hal_cam_name(&c->st, "sim camera %s", cfg->id);
    cam_new_clock(c);
    /* the board's format is the starting point of negotiation */
    c->st.fmt.pixfmt = cfg->pixfmt;
    c->st.fmt.width = cfg->width;
    c->st.fmt.height = cfg->height;
    c->st.fmt.rate_mhz = w->board->trigger.rate_mhz;
    c->st.fmt.exposure_us = cfg->exposure_us;
    c->st.fmt.trigger = HAL_TRIGGER_HARDWARE;
    w->cams[index] = c;
    if (index + 1 > w->n_cams)
        w->n_cams = index + 1;
    hal_camera_bind(out, &sim_camera_ops, c, index);
    return F4D_OK;
}

static int sim_trigger_open(void *session, const struct hal_trigger_config *cfg,
                            struct hal_trigger *out, struct f4d_err *err)
{
    (void)cfg;
    struct sim_world *w = session;
    return hal_trigger_claim(&w->trig_open, out, &sim_trigger_ops, w, "sim trigger", err);
}

static int sim_clock_get(void *session, struct hal_clock *out)
{
    hal_clock_bind(out, clk_now, clk_sleep, clk_next, session);
    return F4D_OK;
}

const struct hal_backend hal_sim_backend = {
    .api_version = HAL_API_VERSION,
    .name = "sim",
    .session_open = sim_session_open,
    .session_close = sim_session_close,
    .camera_open = sim_camera_open,
    .trigger_open = sim_trigger_open,
    .clock_get = sim_clock_get,
};

int hal_sim_injected_get(const void *world, struct hal_sim_injected *out)
{
    if (!world)
        return F4D_EINVAL;
    *out = ((const struct sim_world *)world)->inj;
    return F4D_OK;
}

void hal_sim_set_renderer(void *world, hal_sim_render_fn fn, void *user)
{
    struct sim_world *w = world;
    w->render = fn ? fn : hal_sim_render_pattern;
    w->render_user = fn ? user : NULL;
}
