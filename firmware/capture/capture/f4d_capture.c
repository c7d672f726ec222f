/* f4d_capture.c: the capture loop (see f4d_capture.h). */
#include "f4d_capture.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

struct run {
    struct hal_rig *rig;
    struct f4d_sync sync;
    f4d_capture_set_fn on_set;
    void *user;
    int set_rc;
    uint32_t requeue_errors;
    /* buffers each camera holds (queued, or handed back by stop and not yet
     * dequeued): its arena may be freed only at 0 */
    uint32_t owned[HAL_RIG_CAMERAS_MAX];
};

static int enqueue(struct run *r, uint32_t cam, struct hal_buffer *b)
{
    int rc = hal_camera_enqueue(&r->rig->cams[cam], b);
    if (rc == F4D_OK)
        r->owned[cam]++;
    return rc;
}

static int dequeue(struct run *r, uint32_t cam, struct hal_buffer **b)
{
    int rc = hal_camera_dequeue(&r->rig->cams[cam], b, 0);
    if (rc == F4D_OK && r->owned[cam])
        r->owned[cam]--;
    return rc;
}

static void on_release(void *user, struct hal_buffer *b)
{
    struct run *r = user;
    if (enqueue(r, b->camera_index, b) < 0)
        r->requeue_errors++;
}

/* Waits (real time, polling) until every camera streams. */
static int wait_streaming(struct hal_rig *rig, uint64_t timeout_ns, uint64_t *waited_ns, struct f4d_err *err)
{
    struct hal_clock mono = hal_clock_monotonic();
    const uint64_t t0 = hal_clock_now(&mono);
    for (;;) {
        uint32_t waiting = 0, first = 0;
        for (uint32_t i = 0; i < rig->n_cams; i++) {
            if (!hal_camera_streaming(&rig->cams[i]) && waiting++ == 0)
                first = i;
        }
        uint64_t now = hal_clock_now(&mono);
        *waited_ns = now - t0;
        if (waiting == 0)
            return F4D_OK;
        if (now - t0 >= timeout_ns) {
            char names[160] = "";
            size_t n = 0;
            for (uint32_t i = 0; i < rig->n_cams && n < sizeof names; i++) {
                if (hal_camera_streaming(&rig->cams[i]))
                    continue;
                int w = snprintf(names + n, sizeof names - n, "%s%s", n ? ", " : "", rig->board->cams[i].id);
                n = w < 0 ? sizeof names : n + (size_t)w;
            }
            const char *why = hal_camera_last_error(&rig->cams[first]);
            return f4d_fail(err, F4D_ETIMEDOUT,
                            "camera%s %s not streaming %llu ms after start: trigger not armed%s%s",
                            waiting > 1 ? "s" : "", names, (unsigned long long)(timeout_ns / 1000000u),
                            why[0] ? "; " : "", why);
        }
        hal_clock_sleep_until(&mono, now + 2000000u);
    }
}

static void on_sync_set(void *user, const struct hal_set *set)
{
    struct run *r = user;
    if (r->set_rc >= 0) {
        int rc = r->on_set(r->user, set);
        if (rc < 0)
            r->set_rc = rc;
    }
}

int f4d_capture_run(struct hal_rig *rig, const struct f4d_capture_config *cfg,
                    f4d_capture_set_fn on_set, f4d_capture_progress_fn on_progress, void *user,
                    volatile sig_atomic_t *stop, struct f4d_capture_stats *out, struct f4d_err *err)
{
    const struct hal_board *board = rig->board;
    memset(out, 0, sizeof *out);
    struct run *r = calloc(1, sizeof *r);
    if (!r)
        return f4d_fail(err, F4D_ENOMEM, "capture: out of memory");
    r->rig = rig;
    r->on_set = on_set;
    r->user = user;
    struct f4d_sync_config sc = {rig->n_cams, board->sync.window_us, board->sync.max_latency_us,
                                 board->sync.incomplete, board->sync.pending_max, 0};
    int rc = f4d_sync_init(&r->sync, &sc, on_sync_set, on_release, r);
    if (rc < 0) {
        free(r);
        return f4d_fail(err, rc, "capture: bad sync settings in board \"%s\"", board->name);
    }
    const uint32_t nbuf = cfg->buffers_per_cam ? cfg->buffers_per_cam : board->sync.pending_max + HAL_CAPTURE_SPARE_BUFFERS;
    struct hal_buffer *bufs = calloc((size_t)nbuf * rig->n_cams, sizeof *bufs);
    uint8_t *arena[HAL_RIG_CAMERAS_MAX] = {0};
    uint32_t configured = 0; /* cameras [0, configured) were negotiated (and may hold buffers) */
    if (!bufs) {
        rc = f4d_fail(err, F4D_ENOMEM, "capture: out of memory");
        goto out;
    }
    /* Negotiate: the board's wish, adjusted once by the device, then fixed. */
    for (uint32_t i = 0; i < rig->n_cams; i++) {
        const struct hal_camera_config *cc = &board->cams[i];
        struct hal_format f = {cc->pixfmt, cc->width, cc->height, 0, board->trigger.rate_mhz,
                               HAL_TRIGGER_HARDWARE, cc->exposure_us, 0};
        struct hal_camera *cam = &rig->cams[i];
        rc = hal_camera_validate(cam, &f);
        if (rc == HAL_FORMAT_ADJUSTED)
            rc = hal_camera_validate(cam, &f);
        if (rc != HAL_FORMAT_VALID) {
            rc = f4d_fail(err, rc < 0 ? rc : F4D_EINVAL,
                          "camera %s: no usable format (%s)", cc->id, hal_camera_last_error(cam));
            goto out;
        }
        if ((rc = hal_camera_configure(cam, &f)) < 0) {
            rc = f4d_fail(err, rc, "camera %s: configure: %s", cc->id,
                          hal_camera_last_error(cam));
            goto out;
        }
        configured = i + 1;
        out->formats[i] = f;
        arena[i] = malloc((size_t)nbuf * f.image_bytes);
        if (!arena[i]) {
            rc = f4d_fail(err, F4D_ENOMEM, "camera %s: cannot allocate %u buffers of %zu bytes",
                          cc->id, (unsigned)nbuf, f.image_bytes);
            goto out;
        }
        for (uint32_t k = 0; k < nbuf; k++) {
            struct hal_buffer *b = &bufs[(size_t)i * nbuf + k];
            b->data = arena[i] + (size_t)k * f.image_bytes;
            b->capacity = f.image_bytes;
            b->camera_index = i;
            if ((rc = enqueue(r, i, b)) < 0) {
                rc = f4d_fail(err, rc, "camera %s: enqueue: %s", cc->id,
                              hal_camera_last_error(cam));
                goto out;
            }
        }
    }
    for (uint32_t i = 0; i < rig->n_cams; i++) {
        if ((rc = hal_camera_start(&rig->cams[i])) < 0) {
            rc = f4d_fail(err, rc, "camera %s: start: %s", board->cams[i].id,
                          hal_camera_last_error(&rig->cams[i]));
            goto out;
        }
    }
    if (cfg->on_ready && (rc = cfg->on_ready(user, out)) < 0) {
        rc = f4d_fail(err, rc, "capture: the set consumer could not start");
        goto out;
    }
    /* the first pulse goes out only when every camera can answer it */
    rc = wait_streaming(rig, cfg->ready_timeout_ns ? cfg->ready_timeout_ns : 5000000000ull,
                        &out->ready_wait_ns, err);
    if (rc < 0)
        goto out;
    struct hal_pulse_train train = {board->trigger.rate_mhz, board->trigger.pulse_width_us,
                                     cfg->triggers};
    if ((rc = hal_trigger_arm(&rig->trigger, &train)) < 0) {
        rc = f4d_fail(err, rc, "trigger: arm failed (%s)",
                      rig->trigger.ops.last_error ? rig->trigger.ops.last_error(rig->trigger.ctx) : "");
        goto out;
    }

    const struct hal_clock *clk = &rig->clock;
    const bool simulated = clk->ops.next_event_ns != NULL;
    const uint64_t poll_ns = (uint64_t)(cfg->poll_us ? cfg->poll_us : 1000) * 1000u;
    const uint64_t drain_ns = cfg->drain_ns ? cfg->drain_ns : board->sync.max_latency_us * 1000ull + 100000000ull;
    const uint64_t progress_ns = cfg->progress_ns ? cfg->progress_ns : 1000000000ull;
    const uint64_t t0 = hal_clock_now(clk);
    uint64_t next_progress = t0 + progress_ns;
    uint64_t last_edge = t0;
    bool armed = true, held = false, cam_gone[HAL_RIG_CAMERAS_MAX] = {false};
    out->t_start_ns = t0;
    rc = F4D_OK;
    for (;;) {
        uint64_t now = hal_clock_now(clk);
        struct hal_edge edges[32];
        int ne;
        while ((ne = hal_trigger_read_edges(&rig->trigger, edges, 32, 0)) > 0) {
            for (int k = 0; k < ne; k++) {
                f4d_sync_edge(&r->sync, &edges[k]);
                last_edge = now;
            }
        }
        for (uint32_t i = 0; i < rig->n_cams; i++) {
            for (uint32_t guard = 0; guard < nbuf * 4; guard++) {
                struct hal_buffer *b = NULL;
                int d = dequeue(r, i, &b);
                if (d == F4D_OK && b->status == HAL_FRAME_ABORTED) {
                    /* handed back unfilled (a camera lost and reopened): not a
                     * frame, so it goes straight back to the camera */
                    if (enqueue(r, i, b) < 0)
                        r->requeue_errors++;
                    continue;
                }
                if (d == F4D_OK) {
                    cam_gone[i] = false;
                    out->frames_in++;
                    out->bytes_in += b->bytes_used;
                    b->camera_index = i;
                    f4d_sync_frame(&r->sync, b);
                    continue;
                }
                if (d == F4D_ENODEV) {
                    if (!cam_gone[i]) {
                        cam_gone[i] = true;
                        out->disconnects++;
                        f4d_sync_camera_reset(&r->sync, i);
                    }
                } else if (d != F4D_ETIMEDOUT && d != F4D_EEOF) {
                    out->dequeue_errors++;
                }
                break;
            }
        }
        f4d_sync_advance(&r->sync, now);
        if (r->set_rc < 0) {
            rc = f4d_fail(err, r->set_rc, "capture stopped: the set consumer failed");
            break;
        }
        if (on_progress && now >= next_progress) {
            out->sync = r->sync.c;
            out->t_end_ns = now;
            on_progress(user, out, now);
            next_progress = now + progress_ns;
        }
        bool want_stop = (stop && *stop) || (cfg->duration_ns && now - t0 >= cfg->duration_ns);
        if (armed && want_stop) {
            hal_trigger_disarm(&rig->trigger);
            armed = false;
            last_edge = now;
        }
        if (held && want_stop) {
            held = false;
            last_edge = now;
        }
        if (cfg->hold_while_down && (armed || held)) {
            /* hold the train while a camera is down, re-arm it for the pulses
             * still owed once every camera streams again */
            bool all = true;
            for (uint32_t i = 0; i < rig->n_cams && all; i++)
                all = hal_camera_streaming(&rig->cams[i]);
            if (armed && !all) {
                hal_trigger_disarm(&rig->trigger);
                armed = false;
                held = true;
                out->holds++;
            } else if (held && all) {
                held = false;
                uint64_t seen = r->sync.c.triggers;
                if (!cfg->triggers || seen < cfg->triggers) {
                    train.count = cfg->triggers ? cfg->triggers - seen : 0;
                    if ((rc = hal_trigger_arm(&rig->trigger, &train)) < 0) {
                        rc = f4d_fail(err, rc, "trigger: re-arm after a hold failed (%s)",
                                      rig->trigger.ops.last_error ? rig->trigger.ops.last_error(rig->trigger.ctx)
                                                                  : "");
                        break;
                    }
                    armed = true;
                }
                last_edge = now;
            }
        }
        if (armed && hal_trigger_done(&rig->trigger))
            armed = false;
        if (!armed && !held) {
            /* drained when nothing more is due (simulated) or after the drain window */
            if (simulated ? hal_clock_next_event(clk) == UINT64_MAX : now - last_edge >= drain_ns)
                break;
        }
        uint64_t wake = simulated ? hal_clock_next_event(clk) : now + poll_ns;
        uint64_t dl = f4d_sync_next_deadline(&r->sync);
        if (dl < wake)
            wake = dl;
        if (!simulated && wake > now + poll_ns)
            wake = now + poll_ns;
        if (wake == UINT64_MAX)
            wake = now + poll_ns;
        if (wake > now)
            hal_clock_sleep_until(clk, wake);
    }
    f4d_sync_flush(&r->sync);
    if (armed)
        hal_trigger_disarm(&rig->trigger);
    out->sync = r->sync.c;
    out->t_end_ns = hal_clock_now(clk);
    if (rc >= 0 && r->set_rc < 0)
        rc = f4d_fail(err, r->set_rc, "capture stopped: the set consumer failed");
    if (rc >= 0 && r->requeue_errors)
        rc = f4d_fail(err, F4D_EIO, "capture: %u buffers could not be queued again",
                      (unsigned)r->requeue_errors);
out:;
    /* Every negotiated camera is stopped, started or not (a camera that never
     * started, or failed to, still holds the buffers queued to it), and the
     * buffers stop hands back are collected before their memory is freed. A
     * camera that keeps any (a backend bug) keeps its memory too: leaked, never
     * freed under it. */
    bool kept = false;
    for (uint32_t i = 0; i < configured; i++) {
        hal_camera_stop(&rig->cams[i]);
        struct hal_buffer *b;
        for (uint32_t k = 0; k < nbuf * 2 && r->owned[i] && dequeue(r, i, &b) == F4D_OK; k++) {
        }
        if (r->owned[i]) {
            kept = true;
            if (rc >= 0)
                rc = f4d_fail(err, F4D_ESTATE, "camera %s: still holds %u buffers after stop (%s)",
                              board->cams[i].id, (unsigned)r->owned[i], hal_camera_last_error(&rig->cams[i]));
            continue;
        }
        free(arena[i]);
    }
    if (!kept)
        free(bufs);
    free(r);
    return rc;
}
