/* f4d_sync.c: multi-view set assembly (see f4d_sync.h for the contract). */
#include "f4d_sync.h"

#include <string.h>

static uint32_t all_mask(const struct f4d_sync *s)
{
    return s->cfg.n_cams >= 32 ? 0xFFFFFFFFu : (1u << s->cfg.n_cams) - 1u;
}

/* Median of n <= F4D_SYNC_LEARN_FRAMES values (lower middle for even n). */
static int64_t median(const int64_t *v, uint32_t n)
{
    int64_t t[F4D_SYNC_LEARN_FRAMES];
    memcpy(t, v, n * sizeof *t);
    for (uint32_t i = 1; i < n; i++)
        for (uint32_t j = i; j > 0 && t[j - 1] > t[j]; j--) {
            int64_t x = t[j];
            t[j] = t[j - 1];
            t[j - 1] = x;
        }
    return t[(n - 1) / 2];
}

static uint32_t popcount32(uint32_t v)
{
    uint32_t n = 0;
    for (; v; v &= v - 1)
        n++;
    return n;
}

int f4d_sync_init(struct f4d_sync *s, const struct f4d_sync_config *cfg, f4d_sync_set_fn on_set,
                  f4d_sync_release_fn on_release, void *user)
{
    if (!cfg || cfg->n_cams < 1 || cfg->n_cams > F4D_SYNC_CAMS_MAX || cfg->pending_max < 1 ||
        cfg->pending_max > F4D_SYNC_PENDING_MAX || cfg->window_us == 0 || cfg->max_latency_us == 0 ||
        !on_set || !on_release)
        return F4D_EINVAL;
    memset(s, 0, sizeof *s);
    s->cfg = *cfg;
    if (s->cfg.learn_frames == 0 || s->cfg.learn_frames > F4D_SYNC_LEARN_FRAMES)
        s->cfg.learn_frames = F4D_SYNC_LEARN_FRAMES;
    s->on_set = on_set;
    s->on_release = on_release;
    s->user = user;
    return F4D_OK;
}

static struct f4d_sync_slot *slot_at(struct f4d_sync *s, uint32_t i)
{
    F4D_ASSERT(i < s->s_count || i == s->s_count); /* the open slots, or the next one */
    return &s->slots[(s->s_head + i) % F4D_SYNC_PENDING_MAX];
}

static void close_oldest(struct f4d_sync *s)
{
    F4D_ASSERT(s->s_count > 0);
    struct f4d_sync_slot *sl = slot_at(s, 0);
    struct hal_set *set = &sl->set;
    const uint32_t all = all_mask(s);
    set->complete = set->ok_mask == all;
    uint32_t missing = all & ~set->present_mask & ~sl->rejected_mask;
    s->c.frames_dropped += popcount32(missing);
    struct f4d_sync_hist *h = &s->hist[set->seq % F4D_SYNC_HISTORY];
    h->seq = set->seq;
    h->present_mask = set->present_mask | sl->rejected_mask;
    h->counted_dropped = missing;
    if (set->complete) {
        s->c.sets_complete++;
        s->on_set(s->user, set);
    } else {
        s->c.sets_incomplete++;
        if (s->cfg.policy == HAL_INCOMPLETE_MARK) {
            s->c.sets_passed_marked++;
            s->on_set(s->user, set);
        } else {
            s->c.sets_dropped++;
        }
    }
    for (uint32_t i = 0; i < s->cfg.n_cams; i++)
        if (set->frames[i])
            s->on_release(s->user, set->frames[i]);
    if (set->seq > s->closed_through)
        s->closed_through = set->seq;
    s->s_head = (s->s_head + 1) % F4D_SYNC_PENDING_MAX;
    s->s_count--;
}

/* The open slot for seq, created (in seq order) if absent; NULL if seq is
 * already closed (possibly by making room). */
static struct f4d_sync_slot *slot_get(struct f4d_sync *s, uint64_t seq, uint64_t deadline_ns)
{
    uint32_t i = 0;
    for (; i < s->s_count; i++) {
        struct f4d_sync_slot *sl = slot_at(s, i);
        if (sl->set.seq == seq)
            return sl;
        if (sl->set.seq > seq)
            break;
    }
    if (s->s_count == s->cfg.pending_max) {
        s->c.sets_forced++;
        close_oldest(s);
        if (seq <= s->closed_through)
            return NULL;
        i = i ? i - 1 : 0;
    }
    /* shift slots [i, count) up by one */
    for (uint32_t j = s->s_count; j > i; j--)
        *slot_at(s, j) = *slot_at(s, j - 1);
    s->s_count++;
    struct f4d_sync_slot *sl = slot_at(s, i);
    memset(sl, 0, sizeof *sl);
    sl->set.seq = seq;
    sl->deadline_ns = deadline_ns;
    return sl;
}

void f4d_sync_edge(struct f4d_sync *s, const struct hal_edge *e)
{
    s->c.triggers++;
    if (e->seq <= s->closed_through)
        return;
    struct f4d_sync_slot *sl = slot_get(s, e->seq, e->ts_ns + s->cfg.max_latency_us * 1000ull);
    if (!sl)
        return;
    sl->set.has_edge = true;
    sl->set.trigger_ts_ns = e->ts_ns;
    sl->deadline_ns = e->ts_ns + s->cfg.max_latency_us * 1000ull;
}

void f4d_sync_frame(struct f4d_sync *s, struct hal_buffer *b)
{
    const uint32_t cam = b->camera_index;
    if (cam >= s->cfg.n_cams) {
        s->c.frames_stale++;
        s->on_release(s->user, b);
        return;
    }
    const uint32_t bit = 1u << cam;
    struct f4d_sync_cam *ck = &s->cams[cam];
    if (b->flags & HAL_FRAME_FLAG_CLOCK_RESET) {
        ck->clock_known = false;
        s->c.clock_resets++;
    }
    struct f4d_sync_slot *sl = NULL;
    if (b->trigger_seq > s->closed_through)
        sl = slot_get(s, b->trigger_seq, b->host_ts_ns + s->cfg.max_latency_us * 1000ull);
    if (!sl) { /* its set is closed already */
        struct f4d_sync_hist *h = &s->hist[b->trigger_seq % F4D_SYNC_HISTORY];
        if (h->seq != b->trigger_seq) {
            s->c.frames_stale++;
        } else if (h->present_mask & bit) {
            s->c.frames_duplicate++;
        } else {
            s->c.frames_late++;
            h->present_mask |= bit;
            if (h->counted_dropped & bit) {
                h->counted_dropped &= ~bit;
                s->c.frames_dropped--;
            }
        }
        s->on_release(s->user, b);
        return;
    }
    struct hal_set *set = &sl->set;
    if ((set->present_mask | sl->rejected_mask) & bit) {
        s->c.frames_duplicate++;
        s->on_release(s->user, b);
        return;
    }
    /* Map the device clock onto the trigger clock and check the window. */
    const int64_t window = (int64_t)s->cfg.window_us * 1000;
    if (set->has_edge) {
        int64_t off = (int64_t)(b->device_ts_ns - set->trigger_ts_ns);
        if (!ck->clock_known || ck->learned < s->cfg.learn_frames) {
            if (!ck->clock_known)
                ck->learned = 0;
            ck->clock_known = true;
            ck->learn[ck->learned++] = off;
            ck->offset_ns = median(ck->learn, ck->learned);
        } else {
            int64_t r = off - ck->offset_ns;
            if (r > window || r < -window) {
                s->c.frames_out_of_window++;
                sl->rejected_mask |= bit;
                if (++ck->misses >= F4D_SYNC_RELEARN_MISSES) {
                    ck->clock_known = false;
                    ck->misses = 0;
                    s->c.clock_resets++;
                }
                s->on_release(s->user, b);
                return;
            }
            ck->misses = 0;
            ck->offset_ns += r / 8; /* follows drift, smooths jitter */
        }
    } else if (ck->clock_known) {
        /* no edge: compare with the mapped time of the set's first frame */
        uint64_t mapped = b->device_ts_ns - (uint64_t)ck->offset_ns;
        if (set->present_mask == 0) {
            set->trigger_ts_ns = mapped;
        } else {
            int64_t r = (int64_t)(mapped - set->trigger_ts_ns);
            if (r > window || r < -window) {
                s->c.frames_out_of_window++;
                sl->rejected_mask |= bit;
                s->on_release(s->user, b);
                return;
            }
        }
    }
    set->present_mask |= bit;
    set->frames[cam] = b;
    if (b->status == HAL_FRAME_OK) {
        set->ok_mask |= bit;
        s->c.frames_ok++;
    } else {
        s->c.frames_incomplete++;
    }
}

void f4d_sync_advance(struct f4d_sync *s, uint64_t now_ns)
{
    const uint32_t all = all_mask(s);
    while (s->s_count) {
        struct f4d_sync_slot *sl = slot_at(s, 0);
        if (sl->set.ok_mask != all && sl->deadline_ns > now_ns)
            break;
        close_oldest(s);
    }
}

uint64_t f4d_sync_next_deadline(const struct f4d_sync *s)
{
    uint64_t d = UINT64_MAX;
    for (uint32_t i = 0; i < s->s_count; i++) {
        const struct f4d_sync_slot *sl = &s->slots[(s->s_head + i) % F4D_SYNC_PENDING_MAX];
        if (sl->deadline_ns < d)
            d = sl->deadline_ns;
    }
    return d;
}

void f4d_sync_flush(struct f4d_sync *s)
{
    while (s->s_count)
        close_oldest(s);
}

void f4d_sync_camera_reset(struct f4d_sync *s, uint32_t cam)
{
    if (cam < F4D_SYNC_CAMS_MAX)
        s->cams[cam].clock_known = false;
}
