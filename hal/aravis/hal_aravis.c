/* hal_aravis.c: Aravis cameras and the software trigger (see hal_aravis.h). */
#include "hal_aravis.h"

#include "hal_backend.h"

#include <arv.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#define AV_BUFFERS_MAX 64
#define AV_CAMS_MAX HAL_RIG_CAMERAS_MAX
#define AV_EDGE_LOG 64
/* Software trigger: a started camera streams once a probe trigger comes back
 * as a frame. One probe at a time; unanswered after AV_PROBE_RETRY_NS it is
 * sent again, and an answer to a round with resends (it may be an early one,
 * with a later answer still to come) is followed by AV_PROBE_QUIET_NS of
 * silence and a fresh single probe. */
#define AV_PROBE_RETRY_NS 300000000ull
#define AV_PROBE_QUIET_NS 300000000ull

struct av_session;

enum av_slot_state { AV_IDLE, AV_PENDING, AV_IN_STREAM };
struct av_slot {
    struct hal_buffer *hb;
    ArvBuffer *ab; /* our own reference; the stream holds another while queued */
    enum av_slot_state state;
};

struct av_cam {
    struct av_session *s;
    uint32_t index;
    const struct hal_camera_config *cfg;
    ArvCamera *cam;
    ArvStream *stream;
    bool gige;
    struct hal_cam_state st; /* format, configure/start state, aborted buffers, error */
    /* each caller buffer is wrapped once in an ArvBuffer and found again by
     * it, so buffers live in a slot table here, not in a struct hal_bufq */
    struct av_slot slots[AV_BUFFERS_MAX];
    uint32_t n_slots;
    /* streaming (st.streaming): software-trigger probe, lost control */
    uint64_t probe_ns;        /* probe in flight since (host monotonic), 0 = none */
    bool probe_resent;        /* this round sent more than one probe */
    uint64_t quiet_until;     /* no new probe before this */
    uint32_t probes;          /* probes sent since start */
    gint control_lost;        /* set by the heartbeat thread ("control-lost") */
    /* frame counter unwrapping and trigger anchoring */
    bool have_first;
    uint64_t last_raw, unwrapped, seq_base;
    bool want_anchor;         /* the next pulse sent to it is its first: anchor on it */
    uint64_t anchor_seq, anchor_ts; /* that pulse (0 = not sent yet) */
    int64_t slip_delta;       /* software trigger: disagreement seen between counter and edges */
    uint32_t slip_count;
    uint64_t reanchors;
    uint64_t last_seq_out;    /* sequence numbers handed out only grow */
};

struct av_session {
    const struct hal_board *board;
    struct av_cam *cams[AV_CAMS_MAX];
    bool software_trigger;
    /* software trigger */
    bool trig_open, armed;
    uint64_t period_ns, next_pulse_ns, sent, limit, seq;
    struct hal_edgeq edges; /* full: later edges are not reported */
    struct hal_edge log[AV_EDGE_LOG]; /* recent edges, for anchoring first frames */
    uint32_t log_n;
    struct f4d_err err;
};

static uint64_t realtime_ns(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_REALTIME, &ts);
    return (uint64_t)ts.tv_sec * 1000000000u + (uint64_t)ts.tv_nsec;
}

/* hal_cam_fail with the library's reason, if any; frees e. */
static int cam_fail(struct av_cam *c, int rc, const char *what, GError *e)
{
    hal_cam_fail(&c->st, rc, "%.60s%s%.100s", what, e ? ": " : "", e ? e->message : "");
    if (e)
        g_error_free(e);
    return rc;
}

static const struct {
    enum hal_pixfmt hal;
    ArvPixelFormat arv;
} pixfmts[] = {
    {HAL_PIXFMT_MONO8, ARV_PIXEL_FORMAT_MONO_8},
    {HAL_PIXFMT_RGB8, ARV_PIXEL_FORMAT_RGB_8_PACKED},
    {HAL_PIXFMT_BAYER_RG8, ARV_PIXEL_FORMAT_BAYER_RG_8},
    {HAL_PIXFMT_MONO16, ARV_PIXEL_FORMAT_MONO_16},
    {HAL_PIXFMT_YUYV, ARV_PIXEL_FORMAT_YUV_422_YUYV_PACKED},
};

static ArvPixelFormat to_arv(enum hal_pixfmt f)
{
    for (size_t i = 0; i < sizeof pixfmts / sizeof pixfmts[0]; i++)
        if (pixfmts[i].hal == f)
            return pixfmts[i].arv;
    return 0;
}

static uint32_t clamp_step(uint32_t v, gint lo, gint hi, gint inc)
{
    if (inc < 1)
        inc = 1;
    if ((gint)v < lo)
        v = (uint32_t)lo;
    if ((gint)v > hi)
        v = (uint32_t)hi;
    return v - (v - (uint32_t)lo) % (uint32_t)inc;
}

/* ---- camera ---- */
static int cam_validate(void *ctx, struct hal_format *f)
{
    struct av_cam *c = ctx;
    struct hal_format in = *f;
    GError *e = NULL;
    gint wmin, wmax, hmin, hmax;
    arv_camera_get_width_bounds(c->cam, &wmin, &wmax, &e);
    if (!e)
        arv_camera_get_height_bounds(c->cam, &hmin, &hmax, &e);
    if (e)
        return cam_fail(c, F4D_EIO, "reading the image size bounds", e);
    gint winc = arv_camera_get_width_increment(c->cam, NULL);
    gint hinc = arv_camera_get_height_increment(c->cam, NULL);
    f->width = clamp_step(f->width, wmin, wmax, winc);
    f->height = clamp_step(f->height, hmin, hmax, hinc);
    /* pixel format: the wish if the camera has it, else the first one we know */
    guint n = 0;
    gint64 *avail = arv_camera_dup_available_pixel_formats(c->cam, &n, &e);
    if (e)
        return cam_fail(c, F4D_EIO, "reading the pixel formats", e);
    bool have = false;
    enum hal_pixfmt first = HAL_PIXFMT_INVALID;
    for (guint i = 0; i < n; i++) {
        for (size_t k = 0; k < sizeof pixfmts / sizeof pixfmts[0]; k++) {
            if ((ArvPixelFormat)avail[i] != pixfmts[k].arv)
                continue;
            if (first == HAL_PIXFMT_INVALID)
                first = pixfmts[k].hal;
            have |= pixfmts[k].hal == f->pixfmt;
        }
    }
    g_free(avail);
    if (!have) {
        if (first == HAL_PIXFMT_INVALID)
            return cam_fail(c, F4D_ENOTSUP, "no supported pixel format", NULL);
        f->pixfmt = first;
    }
    double rmin = 0, rmax = 0;
    arv_camera_get_frame_rate_bounds(c->cam, &rmin, &rmax, &e);
    if (e) {
        g_error_free(e); /* some cameras have no frame rate control: keep the wish */
        e = NULL;
    } else if (f->rate_mhz) {
        double hz = f->rate_mhz / 1000.0;
        if (hz < rmin)
            f->rate_mhz = (uint32_t)(rmin * 1000.0 + 0.5);
        if (hz > rmax)
            f->rate_mhz = (uint32_t)(rmax * 1000.0);
    }
    if (arv_camera_is_exposure_time_available(c->cam, NULL)) {
        double emin = 0, emax = 0;
        arv_camera_get_exposure_time_bounds(c->cam, &emin, &emax, &e);
        if (e) {
            g_error_free(e);
            e = NULL;
        } else {
            if (f->exposure_us < emin)
                f->exposure_us = (uint32_t)(emin + 0.999);
            if (f->exposure_us > emax)
                f->exposure_us = (uint32_t)emax;
        }
    }
    /* the rig's trigger decides: a software trigger drives the cameras by command */
    if (f->trigger == HAL_TRIGGER_HARDWARE && c->s->software_trigger)
        f->trigger = HAL_TRIGGER_SOFTWARE;
    if (f->trigger == HAL_TRIGGER_HARDWARE && c->cfg->trigger_line < 0)
        f->trigger = HAL_TRIGGER_FREE_RUN;
    f->stride = f->width * hal_pixfmt_bytes_per_pixel(f->pixfmt);
    if (hal_format_finish(f) < 0)
        return cam_fail(c, F4D_EINVAL, "format cannot be represented", NULL);
    return memcmp(&in, f, sizeof in) == 0 ? HAL_FORMAT_VALID : HAL_FORMAT_ADJUSTED;
}

static int cam_configure(void *ctx, const struct hal_format *f)
{
    struct av_cam *c = ctx;
    int rc = hal_cam_check_configure(&c->st);
    if (rc < 0)
        return rc;
    struct hal_format v = *f;
    if ((rc = hal_cam_check_validated(&c->st, cam_validate(c, &v))) < 0)
        return rc;
    GError *e = NULL;
    arv_camera_set_region(c->cam, 0, 0, (gint)f->width, (gint)f->height, &e);
    if (e)
        return cam_fail(c, F4D_EIO, "setting the region", e);
    arv_camera_set_pixel_format(c->cam, to_arv(f->pixfmt), &e);
    if (e)
        return cam_fail(c, F4D_EIO, "setting the pixel format", e);
    if (f->trigger == HAL_TRIGGER_SOFTWARE) {
        arv_camera_set_trigger(c->cam, "Software", &e);
    } else if (f->trigger == HAL_TRIGGER_HARDWARE) {
        char line[16];
        snprintf(line, sizeof line, "Line%d", (int)c->cfg->trigger_line);
        arv_camera_set_trigger(c->cam, line, &e);
    } else {
        arv_camera_clear_triggers(c->cam, &e);
        if (!e && f->rate_mhz)
            arv_camera_set_frame_rate(c->cam, f->rate_mhz / 1000.0, &e);
    }
    if (e)
        return cam_fail(c, F4D_EIO, "setting the trigger", e);
    if (arv_camera_is_exposure_time_available(c->cam, NULL)) {
        arv_camera_set_exposure_time(c->cam, (double)f->exposure_us, &e);
        if (e)
            return cam_fail(c, F4D_EIO, "setting the exposure time", e);
    }
    if (c->gige && c->cfg->packet_size) {
        arv_camera_gv_set_packet_size(c->cam, (gint)c->cfg->packet_size, &e);
        if (e)
            return cam_fail(c, F4D_EIO, "setting the packet size", e);
    }
    c->st.fmt = v;
    c->st.configured = true;
    return F4D_OK;
}

static int push_slot(struct av_cam *c, struct av_slot *sl)
{
    g_object_ref(sl->ab); /* the stream's reference */
    arv_stream_push_buffer(c->stream, sl->ab);
    sl->state = AV_IN_STREAM;
    return F4D_OK;
}

static int cam_start(void *ctx)
{
    struct av_cam *c = ctx;
    int rc = hal_cam_check_start(&c->st);
    if (rc < 0)
        return rc;
    if (c->st.started)
        return F4D_OK;
    GError *e = NULL;
    c->stream = arv_camera_create_stream(c->cam, NULL, NULL, &e);
    if (e || !c->stream)
        return cam_fail(c, F4D_EIO, "creating the stream", e);
    if (c->gige && ARV_IS_GV_STREAM(c->stream) && c->cfg->socket_buffer)
        g_object_set(c->stream, "socket-buffer", ARV_GV_STREAM_SOCKET_BUFFER_FIXED,
                     "socket-buffer-size", (gint)c->cfg->socket_buffer, NULL);
    for (uint32_t i = 0; i < c->n_slots; i++)
        if (c->slots[i].state == AV_PENDING)
            push_slot(c, &c->slots[i]);
    c->have_first = false;
    c->want_anchor = false;
    c->anchor_seq = c->anchor_ts = 0;
    c->last_seq_out = 0;
    c->slip_count = 0;
    c->probe_ns = c->quiet_until = 0;
    c->probe_resent = false;
    c->probes = 0;
    arv_camera_start_acquisition(c->cam, &e);
    if (e) {
        g_clear_object(&c->stream);
        for (uint32_t i = 0; i < c->n_slots; i++)
            if (c->slots[i].state == AV_IN_STREAM)
                c->slots[i].state = AV_PENDING;
        return cam_fail(c, F4D_EIO, "starting the acquisition", e);
    }
    c->st.started = true;
    /* acquisition start is acknowledged and the stream receives: a free-running
     * or line-triggered camera streams now; a software-triggered one once a
     * probe trigger came back (probe_poll) */
    c->st.streaming = c->st.fmt.trigger != HAL_TRIGGER_SOFTWARE;
    return F4D_OK;
}

static void send_probe(struct av_cam *c, uint64_t now)
{
    GError *e = NULL;
    arv_camera_software_trigger(c->cam, &e);
    if (e)
        cam_fail(c, F4D_EIO, "probe trigger", e);
    c->probe_resent = c->probe_ns != 0;
    c->probe_ns = now;
    c->probes++;
}

/* Software trigger, started, not streaming yet: collects answers to probe
 * triggers (frames handed straight back to the stream) and sends the next
 * probe when due. Never blocks. */
static void probe_poll(struct av_cam *c)
{
    if (!c->st.started || c->st.streaming || g_atomic_int_get(&c->control_lost))
        return;
    uint64_t now = hal_mono_ns();
    ArvBuffer *ab;
    while ((ab = arv_stream_try_pop_buffer(c->stream)) != NULL) {
        arv_stream_push_buffer(c->stream, ab); /* ownership goes back with it */
        if (c->probe_ns && !c->probe_resent) {
            /* the one probe of this round came back: the camera answers
             * triggers, and nothing else is outstanding */
            c->st.streaming = true;
            c->want_anchor = true;
            c->probe_ns = 0;
            return;
        }
        c->probe_ns = 0; /* a stray or an ambiguous answer: quiet, then a fresh round */
        c->quiet_until = now + AV_PROBE_QUIET_NS;
    }
    if (c->probe_ns == 0 ? now >= c->quiet_until : now - c->probe_ns >= AV_PROBE_RETRY_NS)
        send_probe(c, now);
    if (c->probes && c->probe_ns)
        hal_cam_fail(&c->st, F4D_ETIMEDOUT, "%u probe trigger%s unanswered (not streaming yet)",
                     (unsigned)c->probes, c->probes > 1 ? "s" : "");
}

static bool cam_streaming(void *ctx)
{
    struct av_cam *c = ctx;
    if (g_atomic_int_get(&c->control_lost)) {
        if (c->st.streaming)
            hal_cam_fail(&c->st, F4D_ENODEV, "control lost");
        c->st.streaming = false;
    }
    probe_poll(c);
    return c->st.streaming;
}

static int cam_stop(void *ctx)
{
    struct av_cam *c = ctx;
    if (c->st.started) {
        GError *e = NULL;
        arv_camera_stop_acquisition(c->cam, &e);
        if (e)
            g_error_free(e); /* the camera may be gone: still release everything */
        g_clear_object(&c->stream); /* drops the stream's references */
        c->st.started = false;
    }
    c->st.streaming = false;
    for (uint32_t i = 0; i < c->n_slots; i++) {
        struct av_slot *sl = &c->slots[i];
        if (sl->state != AV_IDLE)
            hal_cam_abort(&c->st, sl->hb);
        /* forget the wrapper too: the caller may free or reuse the memory
         * once it has its buffers back, and a new hal_buffer at the same
         * address must not find an ArvBuffer around the old data */
        g_clear_object(&sl->ab);
        sl->hb = NULL;
        sl->state = AV_IDLE;
    }
    c->n_slots = 0;
    return F4D_OK;
}

static int cam_enqueue(void *ctx, struct hal_buffer *b)
{
    struct av_cam *c = ctx;
    int rc = hal_cam_check_enqueue(&c->st, b);
    if (rc < 0)
        return rc;
    struct av_slot *sl = NULL;
    for (uint32_t i = 0; i < c->n_slots && !sl; i++)
        if (c->slots[i].hb == b)
            sl = &c->slots[i];
    if (sl && sl->state != AV_IDLE)
        return cam_fail(c, F4D_EBUSY, "buffer is already queued", NULL);
    if (!sl) {
        if (c->n_slots == AV_BUFFERS_MAX)
            return cam_fail(c, F4D_EBUSY, "too many distinct buffers", NULL);
        sl = &c->slots[c->n_slots++];
        sl->hb = b;
        sl->ab = arv_buffer_new_full(b->capacity, b->data, b, NULL);
    }
    if (c->st.started)
        return push_slot(c, sl);
    sl->state = AV_PENDING;
    return F4D_OK;
}

static enum hal_frame_status map_status(ArvBufferStatus s)
{
    switch (s) {
    case ARV_BUFFER_STATUS_SUCCESS: return HAL_FRAME_OK;
    case ARV_BUFFER_STATUS_TIMEOUT: return HAL_FRAME_TIMEOUT;
    case ARV_BUFFER_STATUS_SIZE_MISMATCH: return HAL_FRAME_SIZE_MISMATCH;
    case ARV_BUFFER_STATUS_ABORTED: return HAL_FRAME_ABORTED;
    default: return HAL_FRAME_MISSING_PACKETS;
    }
}

/* GigE Vision 1.x block ids are 16-bit and skip 0. */
static uint64_t unwrap(struct av_cam *c, uint64_t raw)
{
    if (!c->have_first) {
        c->last_raw = raw;
        c->unwrapped = raw;
        return raw;
    }
    uint64_t d;
    if (c->gige && raw <= 0xFFFF && c->last_raw <= 0xFFFF)
        d = raw >= c->last_raw ? raw - c->last_raw : raw + 0xFFFF - c->last_raw;
    else
        d = raw - c->last_raw;
    c->last_raw = raw;
    c->unwrapped += d;
    return c->unwrapped;
}

/* The latest software edge sent at or before t (seq 0 if none). */
static void clear_edge(const struct av_session *s, uint64_t t, uint64_t *seq, uint64_t *ts)
{
    *seq = 0;
    *ts = 0;
    for (uint32_t i = 0; i < s->log_n && i < AV_EDGE_LOG; i++)
        if (s->log[i].ts_ns <= t && s->log[i].seq > *seq) {
            *seq = s->log[i].seq;
            *ts = s->log[i].ts_ns;
        }
}

/* Time of edge `seq` in the software-trigger log, or 0 if it fell out. */
static uint64_t edge_time(const struct av_session *s, uint64_t seq)
{
    for (uint32_t i = 0; i < s->log_n && i < AV_EDGE_LOG; i++)
        if (s->log[i].seq == seq)
            return s->log[i].ts_ns;
    return 0;
}

/* A camera that misses a trigger (busy, or the command merged with the next)
 * does not advance its counter, so every later frame would be numbered one
 * pulse early. With a software trigger the edges are known: when three
 * frames in a row arrive clearly after a different edge than their number
 * says (and clearly not after their own), the numbering moves to follow the
 * edges. Until then the synchronizer's window rejects them: never mixed. */
static void reanchor(struct av_cam *c, struct hal_buffer *b)
{
    const struct av_session *s = c->s;
    if (!s->software_trigger || !s->log_n || !s->period_ns)
        return;
    uint64_t best = 0, best_ts = 0;
    clear_edge(s, b->host_ts_ns, &best, &best_ts);
    uint64_t own = edge_time(s, b->trigger_seq);
    bool own_ok = own && b->host_ts_ns >= own && b->host_ts_ns - own < s->period_ns;
    bool best_clear = best && b->host_ts_ns - best_ts < s->period_ns / 2;
    if (own_ok || !best_clear || best == b->trigger_seq) {
        c->slip_count = 0;
        return;
    }
    int64_t delta = (int64_t)(best - b->trigger_seq);
    if (delta != c->slip_delta) {
        c->slip_delta = delta;
        c->slip_count = 0;
    }
    if (++c->slip_count >= 3) {
        c->seq_base += (uint64_t)delta;
        b->trigger_seq = best;
        c->slip_count = 0;
        c->reanchors++;
    }
}

static int cam_dequeue(void *ctx, struct hal_buffer **out, uint32_t timeout_us)
{
    struct av_cam *c = ctx;
    int rc = hal_cam_dequeue_begin(&c->st, out);
    if (rc < 0 || *out)
        return rc;
    if (g_atomic_int_get(&c->control_lost)) {
        c->st.streaming = false;
        return hal_cam_fail(&c->st, F4D_ENODEV, "control lost");
    }
    if (!c->st.streaming) {
        /* frames before the probe was answered belong to no pulse */
        probe_poll(c);
        if (!c->st.streaming && timeout_us) {
            hal_sleep_until_mono_ns(hal_mono_ns() + (timeout_us < 2000 ? timeout_us : 2000) * 1000ull);
            probe_poll(c);
        }
        if (!c->st.streaming)
            return F4D_ETIMEDOUT;
    }
    ArvBuffer *ab = timeout_us ? arv_stream_timeout_pop_buffer(c->stream, timeout_us)
                               : arv_stream_try_pop_buffer(c->stream);
    if (!ab)
        return F4D_ETIMEDOUT;
    struct hal_buffer *b = (struct hal_buffer *)arv_buffer_get_user_data(ab);
    struct av_slot *sl = NULL;
    for (uint32_t i = 0; i < c->n_slots && !sl; i++)
        if (c->slots[i].ab == ab)
            sl = &c->slots[i];
    g_object_unref(ab); /* the stream's reference */
    if (!sl || !b)
        return cam_fail(c, F4D_EIO, "stream returned a foreign buffer", NULL);
    sl->state = AV_IDLE;
    uint64_t mono = hal_mono_ns(), real = realtime_ns();
    uint64_t sys = arv_buffer_get_system_timestamp(ab);
    b->status = map_status(arv_buffer_get_status(ab));
    size_t size = 0;
    if (b->status == HAL_FRAME_OK)
        arv_buffer_get_image_data(ab, &size);
    else
        arv_buffer_get_data(ab, &size);
    b->bytes_used = size <= b->capacity ? size : b->capacity;
    if (b->status == HAL_FRAME_OK && b->bytes_used < c->st.fmt.image_bytes)
        b->status = HAL_FRAME_SIZE_MISMATCH;
    b->flags = 0;
    b->camera_index = c->index;
    b->format = c->st.fmt;
    b->device_ts_ns = arv_buffer_get_timestamp(ab);
    b->host_ts_ns = sys && sys <= real && real - sys < mono ? mono - (real - sys) : mono;
    if (!c->have_first && c->s->software_trigger) {
        /* The camera streamed (its probe came back) before it got any pulse,
         * and pulses go only to streaming cameras: its first frame that
         * arrives after the first pulse it was sent answers that pulse.
         * Anything earlier is left over from probing and belongs to no set. */
        if (!c->anchor_seq || b->host_ts_ns < c->anchor_ts) {
            push_slot(c, sl);
            return F4D_ETIMEDOUT;
        }
        uint64_t fid = unwrap(c, arv_buffer_get_frame_id(ab));
        c->have_first = true;
        c->seq_base = c->anchor_seq - fid;
    }
    uint64_t fid = unwrap(c, arv_buffer_get_frame_id(ab));
    if (!c->have_first) { /* hardware trigger: the counter starts at pulse 1 */
        c->have_first = true;
        c->seq_base = 1 - fid;
    }
    b->frame_id = fid;
    b->trigger_seq = fid + c->seq_base;
    reanchor(c, b);
    if (b->trigger_seq <= c->last_seq_out) { /* renumbered onto a pulse already delivered: drop */
        push_slot(c, sl);
        return F4D_ETIMEDOUT;
    }
    c->last_seq_out = b->trigger_seq;
    *out = b;
    return F4D_OK;
}

static void cam_close(void *ctx)
{
    struct av_cam *c = ctx;
    cam_stop(c);
    if (c->gige)
        g_signal_handlers_disconnect_by_data(arv_camera_get_device(c->cam), c);
    g_clear_object(&c->cam);
    c->s->cams[c->index] = NULL;
    free(c);
}

static const char *cam_last_error(void *ctx) { return ((struct av_cam *)ctx)->st.err.msg; }

static const struct hal_camera_ops av_camera_ops = {
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

/* ---- software trigger ---- */
static void fire_due(struct av_session *s, uint64_t now)
{
    while (s->armed && now >= s->next_pulse_ns && (s->limit == 0 || s->sent < s->limit)) {
        /* a pulse goes only to cameras that stream: one that is not (yet)
         * would lose it, or answer it late with a frame numbered wrongly */
        for (uint32_t i = 0; i < AV_CAMS_MAX; i++) {
            struct av_cam *c = s->cams[i];
            if (!c || !c->st.started)
                continue;
            if (!cam_streaming(c))
                continue;
            GError *e = NULL;
            arv_camera_software_trigger(c->cam, &e);
            if (e) {
                f4d_fail(&s->err, F4D_EIO, "camera %.40s: TriggerSoftware: %.160s", c->cfg->id, e->message);
                g_error_free(e);
            }
            if (c->want_anchor) {
                c->want_anchor = false;
                c->anchor_seq = s->seq + 1;
                c->anchor_ts = now;
            }
        }
        struct hal_edge ed = {++s->seq, now, 0, true};
        s->sent++;
        /* late polls fire once, not in a burst: the next pulse keeps the grid */
        while (s->next_pulse_ns <= now)
            s->next_pulse_ns += s->period_ns;
        hal_edgeq_push(&s->edges, &ed);
        s->log[s->log_n++ % AV_EDGE_LOG] = ed;
    }
}

static int trig_arm(void *ctx, const struct hal_pulse_train *p)
{
    struct av_session *s = ctx;
    if (p->rate_mhz == 0 || p->rate_mhz > 1000000u)
        return f4d_fail(&s->err, F4D_EINVAL, "aravis trigger: rate %u mHz out of range",
                        (unsigned)p->rate_mhz);
    s->period_ns = 1000000000000ull / p->rate_mhz;
    s->next_pulse_ns = hal_mono_ns() + s->period_ns;
    s->limit = p->count ? s->sent + p->count : 0;
    s->armed = true;
    return F4D_OK;
}

static int trig_disarm(void *ctx)
{
    ((struct av_session *)ctx)->armed = false;
    return F4D_OK;
}

static int trig_read_edges(void *ctx, struct hal_edge *e, uint32_t max, uint32_t timeout_us)
{
    struct av_session *s = ctx;
    uint64_t now = hal_mono_ns();
    uint64_t deadline = now + (uint64_t)timeout_us * 1000u;
    fire_due(s, now);
    while (s->edges.count == 0 && now < deadline && s->armed) {
        hal_sleep_until_mono_ns(s->next_pulse_ns < deadline ? s->next_pulse_ns : deadline);
        now = hal_mono_ns();
        fire_due(s, now);
    }
    return (int)hal_edgeq_pop(&s->edges, e, max);
}

static bool trig_done(void *ctx)
{
    struct av_session *s = ctx;
    return s->limit != 0 && s->sent >= s->limit;
}

static void trig_close(void *ctx)
{
    struct av_session *s = ctx;
    s->armed = false;
    s->trig_open = false;
}

static const char *trig_last_error(void *ctx) { return ((struct av_session *)ctx)->err.msg; }

static const struct hal_trigger_ops av_trigger_ops = {
    .api_version = HAL_API_VERSION,
    .arm = trig_arm,
    .disarm = trig_disarm,
    .read_edges = trig_read_edges,
    .close = trig_close,
    .done = trig_done,
    .last_error = trig_last_error,
};

/* ---- backend ---- */
static int av_session_open(const struct hal_board *board, void **session, struct f4d_err *err)
{
    struct av_session *s = calloc(1, sizeof *s);
    if (!s)
        return f4d_fail(err, F4D_ENOMEM, "aravis: out of memory");
    s->board = board;
    s->software_trigger = strcmp(board->trigger.backend, "aravis") == 0;
    *session = s;
    return F4D_OK;
}

static void av_session_close(void *session) { free(session); }

/* Emitted by the heartbeat thread when the device stops answering. */
static void on_control_lost(ArvGvDevice *dev, gpointer user)
{
    (void)dev;
    g_atomic_int_set(&((struct av_cam *)user)->control_lost, 1);
}

static int av_camera_open(void *session, const struct hal_camera_config *cfg, uint32_t index,
                          struct hal_camera *out, struct f4d_err *err)
{
    struct av_session *s = session;
    if (!cfg->address[0])
        return f4d_fail(err, F4D_EINVAL,
                        "aravis camera %s: no address (an IP or device id); discovery is never used",
                        cfg->id);
    if (index >= AV_CAMS_MAX || s->cams[index])
        return f4d_fail(err, F4D_EBUSY, "aravis camera %s: index in use", cfg->id);
    GError *e = NULL;
    ArvCamera *cam = arv_camera_new(cfg->address, &e);
    if (!cam) {
        int rc = f4d_fail(err, F4D_ENODEV, "aravis camera %s: cannot open %s: %s", cfg->id,
                          cfg->address, e ? e->message : "unknown error");
        if (e)
            g_error_free(e);
        return rc;
    }
    struct av_cam *c = calloc(1, sizeof *c);
    if (!c) {
        g_object_unref(cam);
        return f4d_fail(err, F4D_ENOMEM, "aravis: out of memory");
    }
    c->s = s;
    c->index = index;
    c->cfg = cfg;
    c->cam = cam;
    hal_cam_name(&c->st, "aravis camera %.40s (%.40s)", cfg->id, cfg->address);
    c->gige = arv_camera_is_gv_device(cam);
    if (c->gige) {
        arv_camera_gv_set_stream_options(cam, ARV_GV_STREAM_OPTION_PACKET_SOCKET_DISABLED);
        g_signal_connect(arv_camera_get_device(cam), "control-lost", G_CALLBACK(on_control_lost), c);
    }
    s->cams[index] = c;
    hal_camera_bind(out, &av_camera_ops, c, index);
    return F4D_OK;
}

static int av_trigger_open(void *session, const struct hal_trigger_config *cfg,
                           struct hal_trigger *out, struct f4d_err *err)
{
    (void)cfg;
    struct av_session *s = session;
    return hal_trigger_claim(&s->trig_open, out, &av_trigger_ops, s, "aravis trigger", err);
}

const struct hal_backend hal_aravis_backend = {
    .api_version = HAL_API_VERSION,
    .name = "aravis",
    .session_open = av_session_open,
    .session_close = av_session_close,
    .camera_open = av_camera_open,
    .trigger_open = av_trigger_open,
};
