/* hal_backend.c: the helpers every backend shares (see hal_backend.h). */
#include "hal_backend.h"

#include <stdarg.h>
#include <stdio.h>
#include <time.h>

uint64_t hal_mono_ns(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (uint64_t)ts.tv_sec * 1000000000u + (uint64_t)ts.tv_nsec;
}

void hal_sleep_until_mono_ns(uint64_t t_ns)
{
    struct timespec ts = {(time_t)(t_ns / 1000000000u), (long)(t_ns % 1000000000u)};
    while (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &ts, NULL) != 0) {
    }
}

uint64_t hal_world_clock_read(struct hal_world_clock *c)
{
    if (c->realtime)
        c->now = hal_mono_ns() - c->real_t0;
    return c->now;
}

uint64_t hal_world_clock_wait(struct hal_world_clock *c, uint64_t t)
{
    if (c->realtime)
        hal_sleep_until_mono_ns(c->real_t0 + t);
    else if (t > c->now)
        c->now = t;
    return hal_world_clock_read(c);
}

/* ---- devices ---- */
void hal_camera_bind(struct hal_camera *out, const struct hal_camera_ops *ops, void *ctx, uint32_t index)
{
    out->ops = *ops;
    out->ctx = ctx;
    out->index = index;
}

int hal_trigger_claim(bool *taken, struct hal_trigger *out, const struct hal_trigger_ops *ops, void *ctx,
                      const char *who, struct f4d_err *err)
{
    if (*taken)
        return f4d_fail(err, F4D_EBUSY, "%s already open", who);
    *taken = true;
    out->ops = *ops;
    out->ctx = ctx;
    return F4D_OK;
}

void hal_clock_bind(struct hal_clock *out, uint64_t (*now_ns)(void *), void (*sleep_until_ns)(void *, uint64_t),
                    uint64_t (*next_event_ns)(void *), void *ctx)
{
    out->ops.api_version = HAL_API_VERSION;
    out->ops.now_ns = now_ns;
    out->ops.sleep_until_ns = sleep_until_ns;
    out->ops.next_event_ns = next_event_ns;
    out->ctx = ctx;
}

/* ---- buffers ---- */
bool hal_bufq_push(struct hal_bufq *q, struct hal_buffer *b)
{
    if (q->count == HAL_BUFQ_MAX)
        return false;
    q->ring[(q->head + q->count++) % HAL_BUFQ_MAX] = b;
    return true;
}

struct hal_buffer *hal_bufq_pop(struct hal_bufq *q)
{
    F4D_ASSERT(q->count <= HAL_BUFQ_MAX && q->head < HAL_BUFQ_MAX);
    if (q->count == 0)
        return NULL;
    struct hal_buffer *b = q->ring[q->head];
    q->head = (q->head + 1) % HAL_BUFQ_MAX;
    q->count--;
    return b;
}

void hal_cam_name(struct hal_cam_state *s, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(s->name, sizeof s->name, fmt, ap);
    va_end(ap);
}

int hal_cam_fail(struct hal_cam_state *s, int rc, const char *fmt, ...)
{
    /* name is shorter than err, so the prefix always fits */
    va_list ap;
    va_start(ap, fmt);
    f4d_vfail(&s->err, rc, fmt, ap);
    va_end(ap);
    f4d_err_prefix(&s->err, "%s", s->name);
    return rc;
}

int hal_cam_check_configure(struct hal_cam_state *s)
{
    return s->started ? hal_cam_fail(s, F4D_ESTATE, "configure while started") : F4D_OK;
}

int hal_cam_check_start(struct hal_cam_state *s)
{
    return s->configured ? F4D_OK : hal_cam_fail(s, F4D_ESTATE, "start before configure");
}

int hal_cam_check_enqueue(struct hal_cam_state *s, const struct hal_buffer *b)
{
    if (!s->configured)
        return hal_cam_fail(s, F4D_ESTATE, "enqueue before configure");
    if (!b || !b->data || b->capacity < s->fmt.image_bytes)
        return hal_cam_fail(s, F4D_EINVAL, "buffer smaller than the image");
    return F4D_OK;
}

int hal_cam_check_validated(struct hal_cam_state *s, int rc)
{
    if (rc < 0)
        return rc; /* validate recorded why */
    if (rc != HAL_FORMAT_VALID)
        return hal_cam_fail(s, F4D_EINVAL, "format does not validate unchanged");
    return F4D_OK;
}

int hal_cam_dequeue_begin(struct hal_cam_state *s, struct hal_buffer **out)
{
    *out = NULL;
    if (s->n_aborted) {
        *out = s->aborted[--s->n_aborted];
        return F4D_OK;
    }
    return s->started ? F4D_OK : hal_cam_fail(s, F4D_ESTATE, "dequeue while stopped");
}

void hal_cam_abort(struct hal_cam_state *s, struct hal_buffer *b)
{
    b->status = HAL_FRAME_ABORTED;
    b->bytes_used = 0;
    /* a camera holds at most HAL_BUFQ_MAX buffers, so this only fills up when
     * the caller stops again without collecting the aborted ones */
    if (s->n_aborted < HAL_BUFQ_MAX)
        s->aborted[s->n_aborted++] = b;
}

int hal_cam_fifo_start(struct hal_cam_state *s)
{
    int rc = hal_cam_check_start(s);
    if (rc == F4D_OK)
        s->started = s->streaming = true;
    return rc;
}

void hal_cam_fifo_stop(struct hal_cam_state *s, struct hal_bufq *q)
{
    s->started = s->streaming = false;
    struct hal_buffer *b;
    while ((b = hal_bufq_pop(q)) != NULL)
        hal_cam_abort(s, b);
}

int hal_cam_fifo_enqueue(struct hal_cam_state *s, struct hal_bufq *q, struct hal_buffer *b)
{
    int rc = hal_cam_check_enqueue(s, b);
    if (rc < 0)
        return rc;
    if (!hal_bufq_push(q, b))
        return hal_cam_fail(s, F4D_EBUSY, "buffer queue full");
    return F4D_OK;
}

/* ---- edges ---- */
static uint32_t edgeq_cap(const struct hal_edgeq *q)
{
    return q->limit && q->limit < HAL_EDGEQ_MAX ? q->limit : HAL_EDGEQ_MAX;
}

bool hal_edgeq_push(struct hal_edgeq *q, const struct hal_edge *e)
{
    if (q->count >= edgeq_cap(q))
        return false;
    q->ring[(q->head + q->count++) % HAL_EDGEQ_MAX] = *e;
    return true;
}

bool hal_edgeq_push_overwrite(struct hal_edgeq *q, const struct hal_edge *e)
{
    bool dropped = false;
    if (q->count >= edgeq_cap(q)) {
        q->head = (q->head + 1) % HAL_EDGEQ_MAX;
        q->count--;
        dropped = true;
    }
    q->ring[(q->head + q->count++) % HAL_EDGEQ_MAX] = *e;
    return dropped;
}

uint32_t hal_edgeq_pop(struct hal_edgeq *q, struct hal_edge *out, uint32_t max)
{
    F4D_ASSERT(q->count <= HAL_EDGEQ_MAX && q->head < HAL_EDGEQ_MAX);
    uint32_t n = 0;
    while (n < max && q->count) {
        out[n++] = q->ring[q->head];
        q->head = (q->head + 1) % HAL_EDGEQ_MAX;
        q->count--;
    }
    return n;
}
