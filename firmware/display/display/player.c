/* player.c - decoder, the last two keys and the interpolation between them. */
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "display_internal.h"

struct key_slot {
    struct splat_frame f;
    struct interp_key  k;
    uint64_t           t_us;
    int                motion;   /* the key carried both motions */
    int                built;    /* k holds f's pixel lookup      */
    int                continuous; /* no loss between the newer key and this one */
};

struct display_player {
    fk_ctx          *ctx;
    struct splat_rig rig;
    int              have_rig;
    enum interp_mode mode;
    enum interp_lookup lookup;      /* how the pixel lookup is made (interp_set_lookup) */
    size_t           cap_cfg, cap;
    codec_dec       *dec;
    interp          *ip;
    /* the older and newer key of the pair, and a third slot for the key
     * after them, decoded ahead (display_player_push_ahead) */
    struct key_slot  slot[3];
    int              nkeys, newest;   /* slot[newest] is the newer key */
    int              older;           /* slot[older] is the older key (nkeys == 2) */
    int              pending;         /* slot[pending] holds the next key, -1 none */
    uint64_t         disc_mark;       /* decoder lost + skipped + refused at the last key */
    struct splat_frame out;
    struct interp_pair pair;          /* partners of the current key pair */
    int              pair_ok;         /* pair holds (slot[older], slot[newest]) */
    int              warm;            /* interp sized for the capacity */
    uint64_t         clock_off_us;    /* display_player_clock's raise so far */
    int              live;            /* display_player_clock was called: hold the newest key */
    struct display_player_stats st;
    struct f4d_err   err;
};

double display__now_ms(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec * 1e3 + (double)ts.tv_nsec * 1e-6;
}

double display__cpu_ms(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
    return (double)ts.tv_sec * 1e3 + (double)ts.tv_nsec * 1e-6;
}

int display_player_new(fk_ctx *ctx, const struct splat_rig *lookup_rig, enum interp_mode mode, size_t capacity,
                       display_player **out, struct f4d_err *err)
{
    if (!ctx || !out)
        return f4d_fail(err, F4D_EINVAL, "display_player_new: NULL argument");
    if (mode != INTERP_FUSED && mode != INTERP_KEEP_BOTH && mode != INTERP_NEAREST)
        return f4d_fail(err, F4D_EINVAL, "display_player_new: unknown interpolation mode %d", (int)mode);
    if (capacity > CODEC_CAPACITY_MAX)
        return f4d_fail(err, F4D_ERANGE, "display_player_new: capacity %zu exceeds %zu Gaussians", capacity,
                        (size_t)CODEC_CAPACITY_MAX);
    display_player *p = calloc(1, sizeof *p);
    if (!p)
        return f4d_fail(err, F4D_ENOMEM, "display_player_new: out of memory");
    p->ctx = ctx;
    p->mode = mode;
    p->cap_cfg = capacity;
    if (lookup_rig) {
        p->rig = *lookup_rig;
        p->have_rig = 1;
        if (mode != INTERP_NEAREST) {
            int rc = interp_new(ctx, lookup_rig, &p->ip, err);
            if (rc < 0) {
                free(p);
                return rc;
            }
        }
    }
    p->pending = -1;
    p->st.interp_mode = (int)mode;
    *out = p;
    return F4D_OK;
}

void display_player_free(display_player *p)
{
    if (!p)
        return;
    codec_dec_free(p->dec);
    interp_free(p->ip);
    for (int i = 0; i < 3; i++) {
        interp_key_free(&p->slot[i].k);
        splat_frame_free(&p->slot[i].f);
    }
    splat_frame_free(&p->out);
    interp_pair_free(&p->pair);
    free(p);
}

int display_player_set_lookup(display_player *p, enum interp_lookup lookup, struct f4d_err *err)
{
    if (!p)
        return f4d_fail(err, F4D_EINVAL, "display_player_set_lookup: NULL player");
    if (lookup != INTERP_LOOKUP_RENDER && lookup != INTERP_LOOKUP_ZBUFFER)
        return f4d_fail(err, F4D_EINVAL, "display_player_set_lookup: unknown lookup %d", (int)lookup);
    if (p->ip) {
        int rc = interp_set_lookup(p->ip, lookup, err);
        if (rc < 0)
            return rc;
    }
    p->lookup = lookup;
    return F4D_OK;
}

const char *display_player_error(const display_player *p) { return p ? p->err.msg : "display_player is NULL"; }
size_t display_player_capacity(const display_player *p) { return p ? p->cap : 0; }
const struct display_player_stats *display_player_get_stats(const display_player *p) { return p ? &p->st : NULL; }

/* Everything the refreshes need, sized once for `cap` Gaussians. */
static int plan(display_player *p, size_t cap)
{
    if (cap == 0)
        cap = 1;
    int rc = codec_dec_new(cap, &p->dec, &p->err);
    if (rc < 0)
        return rc;
    for (int i = 0; i < 3; i++)
        if ((rc = splat_frame_reserve(&p->slot[i].f, cap, 1, &p->err)) < 0)
            return rc;
    /* interp_at's output holds both keys' Gaussians at most */
    if ((rc = splat_frame_reserve(&p->out, 2 * cap, 0, &p->err)) < 0)
        return rc;
    p->cap = cap;
    return F4D_OK;
}

static uint64_t disc_count(const display_player *p)
{
    const struct codec_dec_stats *s = codec_dec_stats(p->dec);
    return s->lost + s->skipped + s->refused;
}

/* The pending key becomes the newer key of the pair (the older one is dropped). */
static void promote(display_player *p)
{
    struct key_slot *ks = &p->slot[p->pending];
    p->older = p->newest;
    p->newest = p->pending;
    p->pending = -1;
    /* across a loss the older key is not this one's neighbour: hold one key */
    p->nkeys = ks->continuous ? 2 : 1;
    p->pair_ok = 0;
}

/* staged: the key the packet completes waits as the pending key. */
static int push(display_player *p, const struct codec_packet *pkt, int staged)
{
    if (!p || !pkt)
        return F4D_EINVAL;
    if (p->pending >= 0) {
        if (staged)
            return f4d_fail(&p->err, F4D_ESTATE, "display_player_push_ahead: a key is pending already");
        promote(p); /* keys stay in stream order */
    }
    if (!p->dec) {
        size_t n = 0;
        int first_key = pkt->type == CODEC_PKT_INTRA;
        if (pkt->type != CODEC_PKT_STREAM && !first_key) {
            p->st.waited++; /* joined mid-stream: wait for a header or an intra key */
            return 0;
        }
        if (codec_packet_gaussians(pkt, &n, &p->err) < 0) {
            p->st.refused++;
            return 0;
        }
        /* joining after the header: the first key's count, with room for growth */
        size_t cap = p->cap_cfg ? p->cap_cfg : first_key ? n + n / 4 : n;
        if (cap > CODEC_CAPACITY_MAX)
            cap = CODEC_CAPACITY_MAX;
        int rc = plan(p, cap);
        if (rc < 0)
            return rc;
    }
    const struct codec_dec_stats *ds = codec_dec_stats(p->dec);
    double t0 = display__now_ms(), c0 = display__cpu_ms();
    int rc = codec_dec_packet(p->dec, pkt);
    p->st.decode_ms += display__now_ms() - t0;
    p->st.decode_cpu_ms += display__cpu_ms() - c0;
    p->st.lost = ds->lost;
    p->st.skipped = ds->skipped;
    if (rc < 0) {
        /* a malformed or oversized payload: counted, the decoder waits for an intra key */
        if (rc == F4D_ERANGE)
            p->st.too_large++;
        p->st.refused = ds->refused;
        p->err = (struct f4d_err){ 0 };
        f4d_fail(&p->err, rc, "%s", codec_dec_error(p->dec));
        return 0;
    }
    p->st.refused = ds->refused;
    if (rc == 0) {
        if (p->st.keys == 0 && pkt->type == CODEC_PKT_PRED)
            p->st.waited++;
        return 0;
    }
    /* a new key: into the slot that holds neither key of the pair */
    const struct splat_frame *f = codec_dec_frame(p->dec);
    int s = 0;
    while (p->nkeys > 0 && (s == p->newest || (p->nkeys == 2 && s == p->older)))
        s++;
    struct key_slot *ks = &p->slot[s];
    if (f->count > p->cap) { /* the decoder refuses these; kept as a guard */
        p->st.too_large++;
        return 0;
    }
    if ((rc = splat_frame_copy(&ks->f, f, &p->err)) < 0)
        return rc;
    ks->motion = f->motion_bwd && f->motion_fwd;
    ks->t_us = codec_dec_time(p->dec);
    ks->built = 0;
    uint64_t mark = disc_count(p);
    ks->continuous = p->nkeys > 0 && mark == p->disc_mark && ks->t_us > p->slot[p->newest].t_us;
    p->disc_mark = mark;
    p->st.keys++;
    p->pending = s;
    if (!staged)
        promote(p);
    else
        p->st.keys_ahead++;
    return 1;
}

int display_player_push(display_player *p, const struct codec_packet *pkt) { return push(p, pkt, 0); }
int display_player_push_ahead(display_player *p, const struct codec_packet *pkt) { return push(p, pkt, 1); }

int display_player_pending(const display_player *p, uint64_t *t_us)
{
    if (!p || p->pending < 0)
        return 0;
    if (t_us)
        *t_us = p->slot[p->pending].t_us;
    return 1;
}

int display_player_advance(display_player *p)
{
    if (!p || p->pending < 0)
        return 0;
    promote(p);
    return 1;
}

int display_player_keys(const display_player *p, uint64_t *t_prev, uint64_t *t_next)
{
    if (!p || p->nkeys == 0)
        return 0;
    if (t_next)
        *t_next = p->slot[p->newest].t_us;
    if (t_prev)
        *t_prev = p->slot[p->nkeys == 2 ? p->older : p->newest].t_us;
    return p->nkeys;
}

static int ensure_built(display_player *p, struct key_slot *ks, enum interp_mode mode)
{
    if (ks->built)
        return F4D_OK;
    if (mode != INTERP_FUSED) { /* only fusion reads the pixel lookup */
        ks->k.f = &ks->f;
        ks->built = 1;
        return F4D_OK;
    }
    double t0 = display__now_ms(), c0 = display__cpu_ms();
    int rc = interp_key_build(p->ip, &ks->f, &ks->k, &p->err);
    p->st.lookup_ms += display__now_ms() - t0;
    p->st.lookup_cpu_ms += display__cpu_ms() - c0;
    if (rc < 0)
        return rc;
    ks->built = 1;
    return F4D_OK;
}

/* Runs the lookup and interp_at once on a frame of `cap` Gaussians (the newest
 * key repeated), so that interp's pixel lists, scratch and renderer reach
 * their largest size now and later keys allocate nothing. */
static int warm_up(display_player *p)
{
    const struct splat_frame *k = &p->slot[p->newest].f;
    if (k->count == 0)
        return F4D_OK;
    struct splat_frame tmp = { 0 };
    int rc = splat_frame_resize(&tmp, p->cap, 1, &p->err);
    for (size_t i = 0; rc == 0 && i < p->cap; i++) {
        size_t j = i % k->count;
        memcpy(tmp.pos + 3 * i, k->pos + 3 * j, 3 * sizeof(float));
        memcpy(tmp.scale + 3 * i, k->scale + 3 * j, 3 * sizeof(float));
        memcpy(tmp.rot + 4 * i, k->rot + 4 * j, 4 * sizeof(float));
        memcpy(tmp.rgb + 3 * i, k->rgb + 3 * j, 3 * sizeof(float));
        tmp.opacity[i] = k->opacity[j];
    }
    for (int i = 0; rc == 0 && i < 3; i++) /* the pair and the key decoded ahead */
        rc = interp_key_build(p->ip, &tmp, &p->slot[i].k, &p->err);
    struct interp_config cfg = interp_config_default();
    if (rc == 0)
        rc = interp_pair_build(p->ip, &p->slot[0].k, &p->slot[1].k, &cfg, &p->pair, &p->err);
    if (rc == 0) /* sizes the per-step buffers too */
        rc = interp_pair_prepare(p->ip, &p->pair, &cfg, &p->out, &p->err);
    splat_frame_free(&tmp);
    p->slot[0].built = p->slot[1].built = p->slot[2].built = 0;
    p->pair_ok = 0;
    return rc;
}

int display_player_prepare(display_player *p, const struct splat_camera *cam)
{
    if (!p)
        return F4D_EINVAL;
    if (p->mode == INTERP_NEAREST || p->warm)
        return F4D_OK;
    if (p->nkeys == 0)
        return f4d_fail(&p->err, F4D_ESTATE, "display_player_prepare: no key decoded yet");
    if (!p->ip) {
        if (!cam)
            return f4d_fail(&p->err, F4D_EINVAL, "display_player_prepare: no lookup rig and no camera");
        /* the model's Gaussians are pixel-aligned at its 518-pixel working size:
         * look them up in the starting view at that size, not the display's */
        struct splat_camera lc = *cam;
        int longest = lc.width > lc.height ? lc.width : lc.height;
        if (longest > DISPLAY_LOOKUP_PX) {
            float s = (float)DISPLAY_LOOKUP_PX / (float)longest;
            lc.width = (int)((float)lc.width * s + 0.5f);
            lc.height = (int)((float)lc.height * s + 0.5f);
            lc.fx *= s; lc.fy *= s; lc.cx *= s; lc.cy *= s;
        }
        p->rig.count = 1;
        p->rig.cams[0] = lc;
        p->have_rig = 1;
        int rc = interp_new(p->ctx, &p->rig, &p->ip, &p->err);
        if (rc < 0)
            return rc;
        if ((rc = interp_set_lookup(p->ip, p->lookup, &p->err)) < 0)
            return rc;
    }
    int rc;
    if (p->mode == INTERP_FUSED) {
        if ((rc = warm_up(p)) < 0)
            return rc;
    }
    p->warm = 1;
    return F4D_OK;
}

int display_player_build_ahead(display_player *p)
{
    if (!p || p->pending < 0 || !p->warm || p->mode != INTERP_FUSED)
        return 0;
    struct key_slot *ks = &p->slot[p->pending];
    if (ks->built || !ks->motion) /* a key without motion is never fused */
        return 0;
    int rc = ensure_built(p, ks, p->mode);
    if (rc < 0)
        return rc;
    p->st.lookups_ahead++;
    return 1;
}

uint64_t display_player_clock(display_player *p, uint64_t t_us, double lag_keys)
{
    if (!p)
        return t_us;
    p->live = 1;
    uint64_t t = t_us + p->clock_off_us;
    if (p->nkeys == 0 || !(lag_keys >= 0.0))
        return t;
    uint64_t tn = p->slot[p->newest].t_us;
    uint64_t span = p->nkeys == 2 ? tn - p->slot[p->older].t_us : 0;
    double lag = lag_keys * (double)span;
    uint64_t floor_t = (double)tn > lag ? tn - (uint64_t)lag : 0;
    if (t < floor_t) { /* behind the newest key by more than the lag: catch up */
        p->clock_off_us += floor_t - t;
        p->st.clock_raises++;
        p->st.clock_raised_ms += (double)(floor_t - t) * 1e-3;
        t = floor_t;
    }
    return t;
}

int display_player_frame(display_player *p, uint64_t t_us, const struct splat_camera *cam,
                         const struct splat_frame **out)
{
    if (!p || !out)
        return F4D_EINVAL;
    if (p->nkeys == 0)
        return f4d_fail(&p->err, F4D_ESTATE, "display_player_frame: no key decoded yet");
    struct key_slot *next = &p->slot[p->newest];
    if (p->nkeys == 1) {
        *out = &next->f;
        p->st.interp_mode = INTERP_NEAREST;
        return F4D_OK;
    }
    if (p->live && t_us >= next->t_us) {
        /* live, the clock at or past the newest key: that key as decoded
         * (held until the next one), no pair to build for times gone by */
        *out = &next->f;
        p->st.held++;
        return F4D_OK;
    }
    struct key_slot *prev = &p->slot[p->older];
    double span = (double)(next->t_us - prev->t_us);
    double a = t_us <= prev->t_us ? 0.0 : t_us >= next->t_us ? 1.0 : (double)(t_us - prev->t_us) / span;
    enum interp_mode mode = p->mode;
    if (!prev->motion || !next->motion)
        mode = INTERP_NEAREST; /* a stream without motion: the nearest key */
    p->st.interp_mode = (int)mode;
    if (mode == INTERP_NEAREST) { /* as interp_at's NEAREST, without its copy */
        *out = a < 0.5 ? &prev->f : &next->f;
        return F4D_OK;
    }
    int rc;
    if ((rc = display_player_prepare(p, cam)) < 0)
        return rc;
    if ((rc = ensure_built(p, prev, mode)) < 0 || (rc = ensure_built(p, next, mode)) < 0)
        return rc;
    struct interp_config cfg = interp_config_default();
    cfg.mode = mode;
    if (mode == INTERP_FUSED && !p->pair_ok) {
        /* once per key pair: the partners, then everything the refreshes do
         * not change (averaging fuses every attribute but the position
         * independently of a), so a refresh only moves positions */
        double t0 = display__now_ms(), c0 = display__cpu_ms();
        rc = interp_pair_build(p->ip, &prev->k, &next->k, &cfg, &p->pair, &p->err);
        if (rc == 0)
            rc = interp_pair_prepare(p->ip, &p->pair, &cfg, &p->out, &p->err);
        p->st.lookup_ms += display__now_ms() - t0;
        p->st.lookup_cpu_ms += display__cpu_ms() - c0;
        if (rc < 0)
            return rc;
        p->pair_ok = 1;
    }
    double t0 = display__now_ms(), c0 = display__cpu_ms();
    rc = mode == INTERP_FUSED ? interp_pair_step(p->ip, &p->pair, (float)a, &p->out, &p->err)
                              : interp_at(p->ip, &prev->k, &next->k, (float)a, &cfg, &p->out, NULL, &p->err);
    p->st.interp_ms += display__now_ms() - t0;
    p->st.interp_cpu_ms += display__cpu_ms() - c0;
    if (rc < 0)
        return rc;
    *out = &p->out;
    return F4D_OK;
}
