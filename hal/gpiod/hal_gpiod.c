/* hal_gpiod.c: GPIO trigger output and strobe input (see hal_gpiod.h). */
#include "hal_gpiod.h"

#include "hal_backend.h"

#include <errno.h>
#include <gpiod.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#define GP_CONSUMER "forge4d"

struct gp_trigger {
    struct gpiod_chip *chip;
    struct gpiod_line *out, *strobe;
    uint32_t out_line;
    bool armed;
    uint64_t period_ns, width_ns, next_pulse_ns, sent, limit, seq;
    struct hal_edgeq edges; /* full: the oldest is lost */
    struct f4d_err err;
};

static void push_edge(struct gp_trigger *g, uint64_t ts)
{
    struct hal_edge e = {++g->seq, ts, g->out_line, true};
    hal_edgeq_push_overwrite(&g->edges, &e); /* nobody reads: the oldest is lost */
}

static int fire_due(struct gp_trigger *g)
{
    uint64_t now = hal_mono_ns();
    while (g->armed && now >= g->next_pulse_ns && (g->limit == 0 || g->sent < g->limit)) {
        uint64_t t = hal_mono_ns();
        if (gpiod_line_set_value(g->out, 1) < 0)
            return f4d_fail(&g->err, F4D_EIO, "gpiod: line %u: set high: %s", (unsigned)g->out_line,
                            strerror(errno));
        hal_sleep_until_mono_ns(t + g->width_ns);
        if (gpiod_line_set_value(g->out, 0) < 0)
            return f4d_fail(&g->err, F4D_EIO, "gpiod: line %u: set low: %s", (unsigned)g->out_line,
                            strerror(errno));
        g->sent++;
        if (!g->strobe)
            push_edge(g, t);
        while (g->next_pulse_ns <= now)
            g->next_pulse_ns += g->period_ns;
        now = hal_mono_ns();
    }
    return F4D_OK;
}

static int read_strobes(struct gp_trigger *g, uint64_t timeout_ns)
{
    struct timespec to = {(time_t)(timeout_ns / 1000000000u), (long)(timeout_ns % 1000000000u)};
    int rc = gpiod_line_event_wait(g->strobe, &to);
    while (rc > 0) {
        struct gpiod_line_event ev;
        if (gpiod_line_event_read(g->strobe, &ev) < 0)
            return f4d_fail(&g->err, F4D_EIO, "gpiod: strobe line: read: %s", strerror(errno));
        if (ev.event_type == GPIOD_LINE_EVENT_RISING_EDGE)
            push_edge(g, (uint64_t)ev.ts.tv_sec * 1000000000u + (uint64_t)ev.ts.tv_nsec);
        struct timespec zero = {0, 0};
        rc = gpiod_line_event_wait(g->strobe, &zero);
    }
    if (rc < 0)
        return f4d_fail(&g->err, F4D_EIO, "gpiod: strobe line: wait: %s", strerror(errno));
    return F4D_OK;
}

static int trig_arm(void *ctx, const struct hal_pulse_train *p)
{
    struct gp_trigger *g = ctx;
    if (p->rate_mhz == 0 || p->rate_mhz > 10000000u)
        return f4d_fail(&g->err, F4D_EINVAL, "gpiod: rate %u mHz out of range", (unsigned)p->rate_mhz);
    g->period_ns = 1000000000000ull / p->rate_mhz;
    g->width_ns = (uint64_t)p->width_us * 1000u;
    if (g->width_ns == 0 || g->width_ns >= g->period_ns)
        return f4d_fail(&g->err, F4D_EINVAL, "gpiod: pulse width %u us must be > 0 and < the period",
                        (unsigned)p->width_us);
    g->next_pulse_ns = hal_mono_ns() + g->period_ns;
    g->limit = p->count ? g->sent + p->count : 0;
    g->armed = true;
    return F4D_OK;
}

static int trig_disarm(void *ctx)
{
    struct gp_trigger *g = ctx;
    g->armed = false;
    return gpiod_line_set_value(g->out, 0) < 0 ? F4D_EIO : F4D_OK;
}

static int trig_read_edges(void *ctx, struct hal_edge *e, uint32_t max, uint32_t timeout_us)
{
    struct gp_trigger *g = ctx;
    uint64_t deadline = hal_mono_ns() + (uint64_t)timeout_us * 1000u;
    for (;;) {
        int rc = fire_due(g);
        if (rc == F4D_OK && g->strobe)
            rc = read_strobes(g, 0);
        if (rc < 0)
            return rc;
        uint64_t now = hal_mono_ns();
        if (g->edges.count || now >= deadline)
            break;
        uint64_t t = g->armed && g->next_pulse_ns < deadline ? g->next_pulse_ns : deadline;
        if (g->strobe) {
            if ((rc = read_strobes(g, t - now)) < 0)
                return rc;
        } else {
            hal_sleep_until_mono_ns(t);
        }
    }
    return (int)hal_edgeq_pop(&g->edges, e, max);
}

static bool trig_done(void *ctx)
{
    struct gp_trigger *g = ctx;
    return g->limit != 0 && g->sent >= g->limit;
}

static void trig_close(void *ctx)
{
    struct gp_trigger *g = ctx;
    if (g->out)
        gpiod_line_release(g->out);
    if (g->strobe)
        gpiod_line_release(g->strobe);
    if (g->chip)
        gpiod_chip_close(g->chip);
    free(g);
}

static const char *trig_last_error(void *ctx) { return ((struct gp_trigger *)ctx)->err.msg; }

static const struct hal_trigger_ops gp_trigger_ops = {
    .api_version = HAL_API_VERSION,
    .arm = trig_arm,
    .disarm = trig_disarm,
    .read_edges = trig_read_edges,
    .close = trig_close,
    .done = trig_done,
    .last_error = trig_last_error,
};

static int gp_session_open(const struct hal_board *board, void **session, struct f4d_err *err)
{
    (void)board;
    (void)err;
    *session = NULL; /* nothing shared: each trigger owns its chip */
    return F4D_OK;
}

static int gp_trigger_open(void *session, const struct hal_trigger_config *cfg,
                           struct hal_trigger *out, struct f4d_err *err)
{
    (void)session;
    if (!cfg->chip[0])
        return f4d_fail(err, F4D_EINVAL, "gpiod: the board names no GPIO chip (trigger.chip)");
    if (cfg->line < 0)
        return f4d_fail(err, F4D_EINVAL, "gpiod: chip %s: trigger line %d is invalid", cfg->chip,
                        (int)cfg->line);
    struct gp_trigger *g = calloc(1, sizeof *g);
    if (!g)
        return f4d_fail(err, F4D_ENOMEM, "gpiod: out of memory");
    g->out_line = (uint32_t)cfg->line;
    errno = 0;
    g->chip = gpiod_chip_open_lookup(cfg->chip);
    int rc;
    if (!g->chip) {
        int e = errno;
        rc = f4d_fail(err, e == ENOENT ? F4D_ENODEV : F4D_EIO, "gpiod: cannot open GPIO chip \"%s\": %s",
                      cfg->chip, strerror(e ? e : ENODEV));
        goto fail;
    }
    g->out = gpiod_chip_get_line(g->chip, (unsigned)cfg->line);
    if (!g->out || gpiod_line_request_output(g->out, GP_CONSUMER, 0) < 0) {
        int e = errno;
        g->out = NULL;
        rc = f4d_fail(err, F4D_EIO, "gpiod: chip %s: cannot drive line %d: %s", cfg->chip,
                      (int)cfg->line, strerror(e));
        goto fail;
    }
    if (cfg->strobe_line >= 0) {
        g->strobe = gpiod_chip_get_line(g->chip, (unsigned)cfg->strobe_line);
        if (!g->strobe || gpiod_line_request_rising_edge_events(g->strobe, GP_CONSUMER) < 0) {
            int e = errno;
            g->strobe = NULL;
            rc = f4d_fail(err, F4D_EIO, "gpiod: chip %s: cannot watch strobe line %d: %s", cfg->chip,
                          (int)cfg->strobe_line, strerror(e));
            goto fail;
        }
    }
    out->ops = gp_trigger_ops;
    out->ctx = g;
    return F4D_OK;
fail:
    trig_close(g);
    return rc;
}

const struct hal_backend hal_gpiod_backend = {
    .api_version = HAL_API_VERSION,
    .name = "gpiod",
    .session_open = gp_session_open,
    .trigger_open = gp_trigger_open,
};
