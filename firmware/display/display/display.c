/* display.c - the refresh loop: pump packets, interpolate, draw with the CPU
 * rasterizer or GLES, overlay the status line, read back, present. Unpaced
 * with the CPU rasterizer, the next refresh's pump and interpolation run on
 * the ahead thread once the rasterizer has read this refresh's frame. */
#include <errno.h>
#include <math.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <time.h>

#include "display_internal.h"

#define STATUS_SCALE 2
#define STATUS_H     (7 * STATUS_SCALE + 6)

/* The next refresh's packets and frame, prepared on the ahead thread while
 * this refresh is sorted, composited and presented (CPU renderer, unpaced):
 * the decode and the per-key lookup and partners, serial or parallel only in
 * part, then fill the time the drawing leaves a core idle. The request is
 * what the serial refresh would do next; the result is taken by that refresh. */
struct ahead {
    /* request */
    display_source     *src;
    uint64_t            t_us, refresh;   /* the refresh it prepares, its stream time */
    struct splat_camera cam;
    int                 drawn_keys;      /* what this refresh draws (the redraw test) */
    uint64_t            drawn_tp, drawn_tn, drawn_t;
    /* result */
    int                 valid, rc;
    const struct splat_frame *f;         /* NULL: not interpolated (a redraw or the end) */
    struct f4d_err      err;
};

struct display {
    struct display_config cfg;
    fk_ctx           *ctx;
    display_gl       *gl;
    display_player   *player;
    splat_renderer   *cpu;
    int               W, H;
    int               planned;          /* buffers sized from the first key */
    enum display_renderer renderer;
    struct splat_camera cam, cam0;
    int               have_cam;
    float             eye[3], yaw, pitch; /* free camera (window) */
    uint64_t          t0_us;            /* stream time of refresh 0 */
    uint64_t          refresh;          /* refreshes since the first key */
    double            next_ms;          /* realtime pacing deadline */
    double            wall0_ms;         /* realtime: wall clock of refresh 0 */
    double            fps_avg, last_ms;
    int               eof;
    float            *rgbf;             /* [H W 3] CPU render / PNG staging */
    uint8_t          *rgb8, *rgba, *overlay;
    int               have_readback;
    char             *png_path;
    size_t            png_path_cap;
    struct display_stats st;
    struct f4d_err    err;
    /* the last picture drawn (CPU path): its key pair, stream time, camera */
    int               drawn_valid, drawn_keys;
    uint64_t          drawn_tp, drawn_tn, drawn_t;
    struct splat_camera drawn_cam;
    /* the ahead thread (player on its own fk context: one caller per context) */
    fk_ctx           *pctx;
    pthread_t         ahead_tid;
    pthread_mutex_t   ahead_mu;
    pthread_cond_t    ahead_cv;
    int               ahead_sync;       /* mutex and condition made */
    int               ahead_ok;         /* the thread runs */
    int               ahead_req, ahead_busy, ahead_quit, ahead_launched;
    struct ahead      ahead;
};

static int pump(display *d, display_source *src, uint64_t until, int want_first, struct f4d_err *err);
static int read_ahead(display *d, display_source *src, uint64_t tn_before, struct f4d_err *err);

/* The ahead thread's work: what display_step does from the pump to the
 * interpolation for refresh a->refresh (unpaced: its time is known now),
 * then a part of the next key's work. */
static void ahead_frame(display *d, struct ahead *a)
{
    if ((a->rc = pump(d, a->src, a->t_us, 0, &a->err)) < 0)
        return;
    uint64_t tp = 0, tn = 0;
    int keys = display_player_keys(d->player, &tp, &tn);
    /* the refresh that would end the stream or present the last picture
     * again interpolates nothing (display_step tests both again) */
    if (keys == 0 || (d->eof && (double)a->t_us > (double)tn + 0.5e6 / d->cfg.fps))
        return;
    if (keys == a->drawn_keys && tp == a->drawn_tp && tn == a->drawn_tn && a->t_us >= tn && a->drawn_t >= tn)
        return;
    if ((a->rc = display_player_frame(d->player, a->t_us, &a->cam, &a->f)) < 0)
        f4d_fail(&a->err, a->rc, "%s", display_player_error(d->player));
}

static void ahead_run(display *d, struct ahead *a)
{
    a->f = NULL;
    a->err = (struct f4d_err){ 0 };
    uint64_t tp = 0, tn = 0;
    display_player_keys(d->player, &tp, &tn);
    ahead_frame(d, a);
    if (a->rc >= 0)
        a->rc = read_ahead(d, a->src, tn, &a->err);
}

static void *ahead_main(void *arg)
{
    display *d = arg;
    pthread_mutex_lock(&d->ahead_mu);
    for (;;) {
        while (!d->ahead_req && !d->ahead_quit)
            pthread_cond_wait(&d->ahead_cv, &d->ahead_mu);
        if (d->ahead_quit)
            break;
        d->ahead_req = 0;
        d->ahead_busy = 1;
        pthread_mutex_unlock(&d->ahead_mu);
        ahead_run(d, &d->ahead);
        pthread_mutex_lock(&d->ahead_mu);
        d->ahead.valid = 1;
        d->ahead_busy = 0;
        pthread_cond_broadcast(&d->ahead_cv);
    }
    pthread_mutex_unlock(&d->ahead_mu);
    return NULL;
}

/* splat_render's frame_read: the frame is read, the player may refill it. */
static void ahead_launch(void *arg)
{
    display *d = arg;
    pthread_mutex_lock(&d->ahead_mu);
    d->ahead.valid = 0;
    d->ahead_req = 1;
    d->ahead_launched = 1;
    pthread_cond_broadcast(&d->ahead_cv);
    pthread_mutex_unlock(&d->ahead_mu);
}

/* Waits for the ahead thread: display_step never returns with it running
 * (the caller may free the source between refreshes). */
static void ahead_join(display *d)
{
    if (!d->ahead_launched)
        return;
    pthread_mutex_lock(&d->ahead_mu);
    while (d->ahead_req || d->ahead_busy)
        pthread_cond_wait(&d->ahead_cv, &d->ahead_mu);
    pthread_mutex_unlock(&d->ahead_mu);
    d->ahead_launched = 0;
}

struct display_config display_config_default(void)
{
    struct display_config c = { 0 };
    c.output = DISPLAY_HEADLESS;
    c.renderer = DISPLAY_RENDER_AUTO;
    c.width = 960;
    c.height = 540;
    c.fps = 30.0;
    c.status_line = 1;
    c.interp = INTERP_FUSED;
    c.lookup = INTERP_LOOKUP_ZBUFFER; /* README: Display, the cost and the pictures of each */
    c.kms_device = "/dev/dri/card0";
    c.live_lag_keys = -1.0;
    return c;
}

const char *display_error(const display *d) { return d ? d->err.msg : "display is NULL"; }
const struct display_stats *display_get_stats(const display *d) { return d ? &d->st : NULL; }
const struct splat_camera *display_camera(const display *d) { return d && d->have_cam ? &d->cam : NULL; }

const uint8_t *display_read_back(display *d, int *width, int *height)
{
    if (!d || !d->have_readback)
        return NULL;
    *width = d->W;
    *height = d->H;
    return d->rgb8;
}

int display_new(fk_ctx *ctx, const struct display_config *cfg, display **out, struct f4d_err *err)
{
    if (!ctx || !cfg || !out)
        return f4d_fail(err, F4D_EINVAL, "display_new: NULL argument");
    if (!(cfg->fps > 0.0 && cfg->fps <= 1000.0))
        return f4d_fail(err, F4D_EINVAL, "display_new: fps %g is not in (0, 1000]", cfg->fps);
    if (cfg->output != DISPLAY_KMS && (cfg->width < 16 || cfg->height < 16 || cfg->width > 8192 || cfg->height > 8192))
        return f4d_fail(err, F4D_EINVAL, "display_new: size %dx%d is not in 16..8192", cfg->width, cfg->height);
    if (cfg->renderer < DISPLAY_RENDER_AUTO || cfg->renderer > DISPLAY_RENDER_GLES)
        return f4d_fail(err, F4D_EINVAL, "display_new: unknown renderer %d", (int)cfg->renderer);
    if (cfg->camera) {
        int rc = splat_camera_validate(cfg->camera, err);
        if (rc < 0)
            return rc;
    }
    display *d = calloc(1, sizeof *d);
    if (!d)
        return f4d_fail(err, F4D_ENOMEM, "display_new: out of memory");
    d->cfg = *cfg;
    d->ctx = ctx;
    int rc = display__gl_open(cfg->output, cfg->width, cfg->height, cfg->kms_device, &d->gl, err);
    if (rc < 0)
        goto fail;
    display__gl_size(d->gl, &d->W, &d->H); /* KMS: the mode's size */

    snprintf(d->st.gl_renderer, sizeof d->st.gl_renderer, "%s", display__gl_renderer(d->gl));
    /* the player's own threads (as many as ctx's): its per-key work runs on
     * the ahead thread beside the rasterizer's jobs on ctx */
    struct fk_ctx_config pc = { .isa = fk_ctx_isa(ctx), .threads = fk_ctx_threads(ctx) };
    if (fk_ctx_new(&pc, &d->pctx) != F4D_OK) {
        rc = f4d_fail(err, F4D_ENOMEM, "display_new: cannot make the player's thread context");
        goto fail;
    }
    if (pthread_mutex_init(&d->ahead_mu, NULL) == 0) {
        if (pthread_cond_init(&d->ahead_cv, NULL) == 0)
            d->ahead_sync = 1;
        else
            pthread_mutex_destroy(&d->ahead_mu);
    }
    /* without the thread every refresh runs serially, as with cfg.serial; a
     * context of one thread asked for one core: no ahead thread either */
    d->ahead_ok = d->ahead_sync && !cfg->serial && fk_ctx_threads(ctx) > 1 &&
                  pthread_create(&d->ahead_tid, NULL, ahead_main, d) == 0;
    if ((rc = display_player_new(d->pctx, cfg->lookup_rig, cfg->interp, cfg->capacity, &d->player, err)) < 0 ||
        (rc = display_player_set_lookup(d->player, cfg->lookup, err)) < 0 ||
        (rc = splat_renderer_new(ctx, d->W, d->H, &d->cpu, err)) < 0)
        goto fail;
    size_t px = (size_t)d->W * (size_t)d->H;
    d->rgbf = malloc(3 * px * sizeof *d->rgbf);
    d->rgb8 = malloc(3 * px);
    d->rgba = malloc(4 * px);
    d->overlay = malloc(4 * (size_t)d->W * STATUS_H);
    if (cfg->png_dir) {
        d->png_path_cap = strlen(cfg->png_dir) + 32;
        d->png_path = malloc(d->png_path_cap);
        if (d->png_path && mkdir(cfg->png_dir, 0777) < 0 && errno != EEXIST) {
            rc = f4d_fail(err, F4D_EIO, "display: cannot create '%s': %s", cfg->png_dir, strerror(errno));
            goto fail;
        }
    }
    if (!d->rgbf || !d->rgb8 || !d->rgba || !d->overlay || (cfg->png_dir && !d->png_path)) {
        rc = f4d_fail(err, F4D_ENOMEM, "display_new: out of memory for %dx%d", d->W, d->H);
        goto fail;
    }
    if (cfg->camera) {
        /* the same view at the output's size (KMS: the mode's): intrinsics scale */
        d->cam = *cfg->camera;
        float sx = (float)d->W / (float)d->cam.width, sy = (float)d->H / (float)d->cam.height;
        d->cam.fx *= sx; d->cam.cx *= sx; d->cam.fy *= sy; d->cam.cy *= sy;
        d->cam.width = d->W;
        d->cam.height = d->H;
        d->have_cam = 1;
    }
    d->renderer = cfg->renderer;
    d->st.renderer = cfg->renderer;
    *out = d;
    return F4D_OK;
fail:
    display_free(d);
    return rc;
}

void display_free(display *d)
{
    if (!d)
        return;
    if (d->ahead_ok) {
        pthread_mutex_lock(&d->ahead_mu);
        d->ahead_quit = 1;
        pthread_cond_broadcast(&d->ahead_cv);
        pthread_mutex_unlock(&d->ahead_mu);
        pthread_join(d->ahead_tid, NULL);
    }
    if (d->ahead_sync) {
        pthread_cond_destroy(&d->ahead_cv);
        pthread_mutex_destroy(&d->ahead_mu);
    }
    splat_renderer_free(d->cpu);
    display_player_free(d->player);
    fk_ctx_free(d->pctx);
    display__gl_close(d->gl);
    free(d->rgbf);
    free(d->rgb8);
    free(d->rgba);
    free(d->overlay);
    free(d->png_path);
    free(d);
}

/* ---- camera ----------------------------------------------------------------------------- */

static void camera_from_pose(display *d)
{
    float f[3] = { cosf(d->pitch) * cosf(d->yaw), cosf(d->pitch) * sinf(d->yaw), sinf(d->pitch) };
    float target[3] = { d->eye[0] + f[0], d->eye[1] + f[1], d->eye[2] + f[2] };
    const float up[3] = { 0.0f, 0.0f, 1.0f };
    splat_camera_look_at(&d->cam, d->eye, target, up);
}

/* The pose (eye, yaw, pitch) of a camera, for the free camera to start from. */
static void pose_from_camera(display *d)
{
    splat_camera_center(&d->cam, d->eye);
    const float *z = d->cam.w2c + 8; /* third row: the viewing direction in world */
    d->pitch = asinf(fmaxf(-1.0f, fminf(1.0f, z[2])));
    d->yaw = atan2f(z[1], z[0]);
}

/* Orbit camera from the first key: 60° horizontal field of view, the bounds'
 * centre in the middle, seen from -y, slightly above (world z up). */
static void orbit_camera(display *d, const struct splat_frame *f)
{
    float lo[3] = { INFINITY, INFINITY, INFINITY }, hi[3] = { -INFINITY, -INFINITY, -INFINITY };
    for (size_t i = 0; i < f->count; i++)
        for (int c = 0; c < 3; c++) {
            lo[c] = fminf(lo[c], f->pos[3 * i + c]);
            hi[c] = fmaxf(hi[c], f->pos[3 * i + c]);
        }
    float ctr[3] = { 0, 0, 0 }, r = 1.0f;
    if (f->count) {
        float dx = hi[0] - lo[0], dy = hi[1] - lo[1], dz = hi[2] - lo[2];
        r = fmaxf(0.1f, 0.5f * sqrtf(dx * dx + dy * dy + dz * dz));
        for (int c = 0; c < 3; c++)
            ctr[c] = 0.5f * (lo[c] + hi[c]);
    }
    struct splat_camera *cam = &d->cam;
    memset(cam, 0, sizeof *cam);
    snprintf(cam->name, sizeof cam->name, "orbit");
    cam->width = d->W;
    cam->height = d->H;
    cam->fx = cam->fy = 0.5f * (float)d->W / tanf(0.5f * 60.0f * 3.14159265f / 180.0f);
    cam->cx = 0.5f * (float)d->W;
    cam->cy = 0.5f * (float)d->H;
    float vtan = 0.5f * (float)d->H / cam->fy, dist = 1.1f * r / vtan + r;
    float dir[3] = { 0.0f, -0.97f, 0.243f };
    float eye[3] = { ctr[0] + dist * dir[0], ctr[1] + dist * dir[1], ctr[2] + dist * dir[2] };
    const float up[3] = { 0.0f, 0.0f, 1.0f };
    splat_camera_look_at(cam, eye, ctr, up);
    d->have_cam = 1;
}

static void apply_input(display *d, const struct display_input *in)
{
    if (in->reset) {
        d->cam = d->cam0;
        pose_from_camera(d);
        return;
    }
    if (!in->move[0] && !in->move[1] && !in->move[2] && !in->turn[0] && !in->turn[1])
        return;
    d->yaw += in->turn[0];
    d->pitch = fmaxf(-1.5f, fminf(1.5f, d->pitch + in->turn[1]));
    const float *R = d->cam.w2c; /* rows: right, down, forward */
    for (int c = 0; c < 3; c++)
        d->eye[c] += in->move[0] * R[c] - in->move[1] * R[4 + c] + in->move[2] * R[8 + c];
    camera_from_pose(d);
}

/* ---- renderers ---------------------------------------------------------------------------- */

static int draw_cpu(display *d, const struct splat_frame *f, int ahead)
{
    /* the renderer writes the 8-bit image the texture takes, quantised as
     * splat_png_write_rgb does: no float image, no second pass over it;
     * ahead: once it has read f, the next refresh is prepared beside it */
    struct splat_render_out ro = { .rgba8 = d->rgba, .rgba8_bottom_up = 1,
                                   .frame_read = ahead ? ahead_launch : NULL, .frame_read_arg = d };
    double t0 = display__now_ms();
    const size_t count = f->count; /* f may hold the next frame once read */
    if (splat_render(d->cpu, &d->cam, f, d->cfg.bg, &ro) < 0)
        return f4d_fail(&d->err, F4D_EINVAL, "%s", splat_renderer_error(d->cpu));
    d->st.raster_ms += display__now_ms() - t0;
    d->st.drawn += count;
    d->st.visible += ro.visible;
    d->st.pairs += ro.pairs;
    for (int k = 0; k < 4; k++)
        d->st.raster_cpu_ms[k] += ro.cpu_ms_stage[k];
    double c0 = display__cpu_ms();
    int rc = display__gl_upload(d->gl, d->rgba, &d->err);
    d->st.upload_cpu_ms += display__cpu_ms() - c0;
    return rc;
}

static int draw(display *d, enum display_renderer r, const struct splat_frame *f, int ahead)
{
    if (r == DISPLAY_RENDER_CPU)
        return draw_cpu(d, f, ahead);
    return display__gl_draw_splats(d->gl, &d->cam, f, d->cfg.bg, &d->err);
}

/* AUTO: both renderers on the first frame, best of two after a warm-up each. */
static int choose_renderer(display *d, const struct splat_frame *f)
{
    double best[3] = { 0, 1e30, 1e30 };
    for (int r = DISPLAY_RENDER_CPU; r <= DISPLAY_RENDER_GLES; r++)
        for (int k = 0; k < 3; k++) {
            double t0 = display__now_ms();
            int rc = draw(d, (enum display_renderer)r, f, 0);
            if (rc < 0)
                return rc;
            display__gl_finish(d->gl);
            double dt = display__now_ms() - t0;
            if (k > 0 && dt < best[r])
                best[r] = dt;
        }
    d->st.raster_ms = d->st.upload_cpu_ms = 0.0;
    memset(d->st.raster_cpu_ms, 0, sizeof d->st.raster_cpu_ms);
    d->st.auto_cpu_ms = best[DISPLAY_RENDER_CPU];
    d->st.auto_gles_ms = best[DISPLAY_RENDER_GLES];
    d->renderer = best[DISPLAY_RENDER_CPU] <= best[DISPLAY_RENDER_GLES] ? DISPLAY_RENDER_CPU : DISPLAY_RENDER_GLES;
    return F4D_OK;
}

/* Everything sized once, from the player's capacity (the stream's plan). */
static int plan(display *d, const struct splat_frame *first)
{
    size_t cap = display_player_capacity(d->player);
    int rc = display__gl_plan(d->gl, 2 * cap, &d->err);
    if (rc < 0)
        return rc;
    /* interpolated frames hold up to both keys; tile pairs: a generous start */
    splat_renderer_reserve(d->cpu, 2 * cap, 8 * cap);
    if (!d->have_cam)
        orbit_camera(d, first);
    d->cam0 = d->cam;
    pose_from_camera(d);
    if ((rc = display_player_prepare(d->player, &d->cam)) < 0)
        return f4d_fail(&d->err, rc, "%s", display_player_error(d->player));
    d->planned = 1;
    return F4D_OK;
}

/* ---- status line ----------------------------------------------------------------------------- */

static void draw_status(display *d)
{
    memset(d->overlay, 0, 4 * (size_t)d->W * STATUS_H);
    for (size_t i = 0; i < (size_t)d->W * STATUS_H; i++) { /* a dark, half transparent bar */
        uint8_t *p = d->overlay + 4 * i;
        p[3] = 160;
    }
    const struct display_stats *st = &d->st;
    const struct display_player_stats *ps = &st->player;
    char line[160];
    snprintf(line, sizeof line, "%.1f FPS  %.2f MBIT/S  LAT %.0f MS  KEYS %llu  LOST %llu  SKIP %llu  DROP %llu  %s",
             d->fps_avg, st->bitrate_mbps, st->latency_ms, (unsigned long long)ps->keys,
             (unsigned long long)ps->lost, (unsigned long long)(ps->skipped + ps->refused),
             (unsigned long long)st->source.dropped, d->renderer == DISPLAY_RENDER_CPU ? "CPU" : "GLES");
    const uint8_t white[4] = { 255, 255, 255, 255 };
    display__text(d->overlay, d->W, STATUS_H, 4, 3, STATUS_SCALE, line, white);
}

/* ---- the refresh --------------------------------------------------------------------------- */

/* Pulls packets until a key at or after `until` is held (or the source has
 * nothing now). want_first: stop at the first key. */
static int pump(display *d, display_source *src, uint64_t until, int want_first, struct f4d_err *err)
{
    for (;;) {
        uint64_t tp, tn;
        int keys = display_player_keys(d->player, &tp, &tn);
        if (keys > 0 && (want_first || tn >= until))
            return F4D_OK;
        if (display_player_advance(d->player))
            continue; /* the key read ahead */
        if (d->eof)
            return F4D_OK;
        struct codec_packet p;
        int rc = display_source_next(src, &p, err);
        if (rc == F4D_EEOF) {
            d->eof = 1;
            return F4D_OK;
        }
        if (rc < 0)
            return rc;
        if (rc == 0)
            return F4D_OK; /* live source, nothing yet */
        rc = display_player_push(d->player, &p);
        if (rc < 0)
            return f4d_fail(err, rc, "%s", display_player_error(d->player));
    }
}

/* A stream that is not live is read one key ahead of the pair it shows, and
 * each refresh that took no new key (that one builds the new pair's partners)
 * does one part of that key's work: its decode, then, a refresh later, its
 * pixel lookup; with 3 refreshes a key the parts land on 3 refreshes instead
 * of one. tn_before: the newer key's time before this refresh's pump. */
static int read_ahead(display *d, display_source *src, uint64_t tn_before, struct f4d_err *err)
{
    uint64_t tp, tn;
    if (d->cfg.live_lag_keys >= 0.0 || display_player_keys(d->player, &tp, &tn) == 0 || tn != tn_before)
        return F4D_OK;
    if (display_player_pending(d->player, NULL)) {
        int rc = display_player_build_ahead(d->player);
        return rc < 0 ? f4d_fail(err, rc, "%s", display_player_error(d->player)) : F4D_OK;
    }
    while (!d->eof) {
        struct codec_packet p;
        int rc = display_source_next(src, &p, err);
        if (rc == F4D_EEOF) {
            d->eof = 1;
            break;
        }
        if (rc <= 0)
            return rc; /* an error, or a growing source with nothing yet */
        if ((rc = display_player_push_ahead(d->player, &p)) < 0)
            return f4d_fail(err, rc, "%s", display_player_error(d->player));
        if (rc == 1)
            break;
    }
    return F4D_OK;
}

/* Refresh slots every 1 / fps on absolute deadlines (clock_nanosleep on
 * CLOCK_MONOTONIC, TIMER_ABSTIME: no drift from the time spent computing the
 * wait). A refresh that starts a whole period or more after its slot began
 * has missed it: it takes the current slot and the missed ones are counted
 * (slots_missed), never made up by presenting refreshes back to back. */
static void pace(display *d)
{
    if (!d->cfg.realtime)
        return;
    double now = display__now_ms(), period = 1e3 / d->cfg.fps;
    if (d->next_ms == 0.0)
        d->next_ms = now; /* the first refresh */
    else if (now - d->next_ms >= period) {
        double missed = floor((now - d->next_ms) / period);
        if (d->st.frames > 0)
            d->st.slots_missed += (uint64_t)missed;
        d->next_ms += missed * period;
    }
    if (d->next_ms > now) {
        double at = d->next_ms;
        struct timespec ts = { (time_t)(at / 1e3), (long)(fmod(at, 1e3) * 1e6) };
        while (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &ts, NULL) == EINTR) {
        }
    }
    d->next_ms += period;
}

static int step(display *d, display_source *src)
{
    struct display_input in;
    display__gl_poll(d->gl, &in);
    if (in.quit)
        return 0;
    int rc, paced = 0;
    if (!d->planned) {
        pace(d); /* a paced display waiting for its first key does not spin */
        paced = 1;
        if ((rc = pump(d, src, 0, 1, &d->err)) < 0)
            return rc;
        uint64_t tp, tn;
        if (display_player_keys(d->player, &tp, &tn) == 0) {
            display_source_get_stats(src, &d->st.source);
            d->st.player = *display_player_get_stats(d->player);
            return d->eof ? 0 : 1; /* still waiting for an intra key */
        }
        d->t0_us = tn;
        const struct splat_frame *first;
        if ((rc = display_player_frame(d->player, tn, NULL, &first)) < 0)
            return f4d_fail(&d->err, rc, "%s", display_player_error(d->player));
        if ((rc = plan(d, first)) < 0)
            return rc;
        if (d->renderer == DISPLAY_RENDER_AUTO && (rc = choose_renderer(d, first)) < 0)
            return rc;
        d->st.renderer = d->renderer;
    }
    apply_input(d, &in);
    if (!paced)
        pace(d);
    uint64_t tp_before = 0, tn_before = 0;
    display_player_keys(d->player, &tp_before, &tn_before);
    double t_start = display__now_ms();
    /* stream time: paced, the wall clock since the first refresh (a slow
     * refresh skips ahead, as a live display must); unpaced, refresh k shows
     * k / fps (every refresh, as fast as the machine goes) */
    if (d->cfg.realtime && d->refresh == 0)
        d->wall0_ms = t_start;
    double k = d->cfg.realtime ? (t_start - d->wall0_ms) * 1e-3 * d->cfg.fps : (double)d->refresh;
    uint64_t t_us = d->t0_us + (uint64_t)(k * 1e6 / d->cfg.fps + 0.5), t_own = t_us;
    /* live: every packet there is now is read (the newest key first), and the
     * clock is kept near the newest key (the player's policy); its times are
     * not known ahead, so it is never prepared on the ahead thread */
    int live = d->cfg.live_lag_keys >= 0.0;
    const struct splat_frame *f = NULL;
    if (live) {
        d->ahead.valid = 0;
        t_us = display_player_clock(d->player, t_own, d->cfg.live_lag_keys);
        if ((rc = pump(d, src, UINT64_MAX, 0, &d->err)) < 0)
            return rc;
        t_us = display_player_clock(d->player, t_own, d->cfg.live_lag_keys);
    } else if (d->ahead.valid && d->ahead.refresh == d->refresh && d->ahead.t_us == t_us && d->ahead.src == src &&
               !memcmp(&d->ahead.cam, &d->cam, sizeof d->cam)) {
        /* prepared during the last refresh (the same request: unpaced times
         * are known ahead) */
        d->ahead.valid = 0;
        if (d->ahead.rc < 0) {
            d->err = d->ahead.err;
            return d->ahead.rc;
        }
        f = d->ahead.f;
        /* a growing source may have more by now: pull as the serial refresh
         * would (nothing to do when the key is held); a new key makes the
         * prepared frame stale */
        uint64_t tp0 = 0, tn0 = 0, tp1 = 0, tn1 = 0;
        int k0 = display_player_keys(d->player, &tp0, &tn0);
        if ((rc = pump(d, src, t_us, 0, &d->err)) < 0)
            return rc;
        int k1 = display_player_keys(d->player, &tp1, &tn1);
        if (k1 != k0 || tp1 != tp0 || tn1 != tn0)
            f = NULL;
    } else {
        d->ahead.valid = 0;
        if ((rc = pump(d, src, t_us, 0, &d->err)) < 0)
            return rc;
    }
    uint64_t tp, tn;
    display_player_keys(d->player, &tp, &tn);
    display_source_get_stats(src, &d->st.source);
    d->st.player = *display_player_get_stats(d->player);
    /* the stream ended and its last key was shown (half a refresh of slack:
     * key times and refresh times are both rounded to microseconds); a paced
     * display whose clock ran past a live stream may get the last key with
     * the end packet: it presents that key once before it stops */
    uint64_t shown = d->st.shown_us < d->st.key_us ? d->st.shown_us : d->st.key_us;
    if (d->eof && d->refresh > 0 && (double)t_us > (double)tn + 0.5e6 / d->cfg.fps &&
        (!d->cfg.realtime || shown >= tn))
        return 0;
    /* A refresh past the newest key of the same pair, from the same camera,
     * shows what was drawn last (interp clamps a to 1): the CPU path's
     * texture still holds it, so only the compose and present run (a live
     * stream behind the display's clock, a stalled sender). */
    int keys = display_player_keys(d->player, &tp, &tn);
    int same = d->renderer == DISPLAY_RENDER_CPU && d->drawn_valid && keys == d->drawn_keys && tp == d->drawn_tp &&
               tn == d->drawn_tn && t_us >= tn && d->drawn_t >= tn && !memcmp(&d->cam, &d->drawn_cam, sizeof d->cam);
    double t_draw = display__now_ms();
    /* the next refresh prepared beside this one's drawing: CPU renderer, unpaced */
    int ahead = d->ahead_ok && d->renderer == DISPLAY_RENDER_CPU && !d->cfg.realtime && !live;
    if (same) {
        d->st.redraws_skipped++;
        d->st.player = *display_player_get_stats(d->player);
    } else {
        if (!f && (rc = display_player_frame(d->player, t_us, &d->cam, &f)) < 0)
            return f4d_fail(&d->err, rc, "%s", display_player_error(d->player));
        d->st.player = *display_player_get_stats(d->player); /* interp time of this frame */
        d->drawn_valid = 1;
        d->drawn_keys = keys;
        d->drawn_tp = tp;
        d->drawn_tn = tn;
        d->drawn_t = t_us;
        d->drawn_cam = d->cam;
    }
    if (ahead) {
        struct ahead *a = &d->ahead;
        a->src = src;
        a->refresh = d->refresh + 1;
        a->t_us = d->t0_us + (uint64_t)((double)a->refresh * 1e6 / d->cfg.fps + 0.5);
        a->cam = d->cam;
        a->drawn_keys = d->drawn_valid ? d->drawn_keys : -1;
        a->drawn_tp = d->drawn_tp;
        a->drawn_tn = d->drawn_tn;
        a->drawn_t = d->drawn_t;
    }
    if (same) {
        if (ahead) /* nothing reads the player's frame this refresh */
            ahead_launch(d);
    } else {
        t_draw = display__now_ms();
        if ((rc = draw(d, d->renderer, f, ahead)) < 0)
            return rc;
    }
    double span_s = (double)(tn - d->t0_us) * 1e-6;
    d->st.bitrate_mbps = span_s > 0 ? (double)d->st.source.bytes * 8e-6 / span_s : 0.0;
    d->st.shown_us = t_us;
    d->st.key_us = tn;
    d->st.latency_ms = (tn > t_us ? (double)(tn - t_us) * 1e-3 : 0.0) +
                       (d->st.source.latency_ms > 0 ? d->st.source.latency_ms : 0.0);
    double c_present = display__cpu_ms();
    if (d->cfg.status_line)
        draw_status(d);
    if ((rc = display__gl_compose(d->gl, d->renderer == DISPLAY_RENDER_CPU, d->cfg.status_line ? d->overlay : NULL,
                                  STATUS_H, &d->err)) < 0)
        return rc;
    double t_present = display__now_ms();
    if (d->cfg.png_dir || d->cfg.read_back) {
        if ((rc = display__gl_read(d->gl, d->rgb8, d->rgba, &d->err)) < 0)
            return rc;
        d->have_readback = 1;
    }
    if (d->cfg.png_dir) {
        size_t n = 3 * (size_t)d->W * (size_t)d->H;
        for (size_t i = 0; i < n; i++)
            d->rgbf[i] = (float)d->rgb8[i] / 255.0f;
        snprintf(d->png_path, d->png_path_cap, "%s/frame_%06llu.png", d->cfg.png_dir,
                 (unsigned long long)d->st.frames);
        if ((rc = splat_png_write_rgb(d->png_path, d->rgbf, d->W, d->H, &d->err)) < 0)
            return rc;
    }
    if ((rc = display__gl_present(d->gl, &d->err)) < 0)
        return rc;
    display__gl_finish(d->gl);
    double t_end = display__now_ms();
    d->st.render_ms += t_present - t_draw;
    d->st.present_ms += t_end - t_present;
    d->st.present_cpu_ms += display__cpu_ms() - c_present;
    if (d->st.frames > 0) {
        d->st.seconds += (t_end - d->last_ms) * 1e-3;
        double inst = 1e3 / fmax(1e-3, t_end - d->last_ms);
        d->fps_avg = d->fps_avg > 0 ? 0.9 * d->fps_avg + 0.1 * inst : inst;
    }
    d->last_ms = t_end;
    d->st.frames++;
    d->refresh++;
    /* serial: the next key's part after the present (a paced display's slack) */
    if (!ahead && (rc = read_ahead(d, src, tn_before, &d->err)) < 0)
        return rc;
    return 1;
}

int display_step(display *d, display_source *src)
{
    if (!d || !src)
        return F4D_EINVAL;
    int rc = step(d, src);
    ahead_join(d);
    return rc;
}
