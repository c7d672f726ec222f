/* test_display.c - f4d_display headless on Mesa (llvmpipe here):
 *   cpu_matches_splat   every refresh of the CPU path (keys and interpolated
 *                       times) is byte for byte firmware/splat's render of the
 *                       same Gaussians, quantised as PNG does;
 *   gles_matches_splat  the GLES path against the same renders: PSNR printed,
 *                       held to a floor (measured here 57.5 dB; floor 45);
 *   auto_picks          AUTO measures both renderers and keeps the faster;
 *   join_mid_stream     a file source started inside a predicted key waits for
 *                       the next intra key, then shows the rest;
 *   damaged_packet      a corrupt packet is dropped, the keys after it until
 *                       the next intra are skipped, the display goes on;
 *   status_line         the status line draws text over the picture;
 *   no_alloc_per_frame  after the first refresh nothing here allocates
 *                       (malloc wrapped at link time; Mesa's own are not seen);
 *   bad_input           refused configurations name what is wrong.
 * A case skips (77) only when no surfaceless EGL display can be opened. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "f4d_display.h"
#include "f4d_test.h"
#include "scene.h"

/* ---- allocation counter (the binary links with --wrap=malloc,calloc,realloc) ---- */
void *__real_malloc(size_t n);
void *__real_calloc(size_t n, size_t m);
void *__real_realloc(void *p, size_t n);
static long allocs;
void *__wrap_malloc(size_t n);
void *__wrap_calloc(size_t n, size_t m);
void *__wrap_realloc(void *p, size_t n);
void *__wrap_malloc(size_t n) { allocs++; return __real_malloc(n); }
void *__wrap_calloc(size_t n, size_t m) { allocs++; return __real_calloc(n, m); }
void *__wrap_realloc(void *p, size_t n) { allocs++; return __real_realloc(p, n); }

#define W 192
#define H 144
#define FPS 30.0
#define KEY_HZ 10

struct stream {
    uint8_t *buf;
    size_t   len;
    size_t   off[32];  /* packet offsets */
    int      types[32];
    uint64_t t[32];
    int      npk;
    struct splat_rig rig;
};

/* nk keys of the walk figure at 10 Hz with exact motion, intra every `intra`. */
static void make_stream(struct stream *s, int nk, int intra)
{
    memset(s, 0, sizeof *s);
    scene *sc;
    struct f4d_err err;
    assert_int_equal(scene_new(SCENE_WALK, 3, 12000, &sc, &err), 0);
    scene_default_rig(sc, 2, W, H, &s->rig);
    struct splat_frame f = { 0 };
    assert_int_equal(scene_eval(sc, 0.2, 1.0 / KEY_HZ, &f, &err), 0);
    codec_enc *e;
    assert_int_equal(codec_enc_new(f.count, CODEC_Q_MEDIUM, &e, &err), 0);
    size_t pcap = codec_packet_bound(f.count), cap = pcap * (size_t)(nk + 2), n;
    s->buf = malloc(cap);
    assert_non_null(s->buf);
    assert_int_equal(codec_enc_stream_header(e, 0, s->buf, cap, &n), 0);
    s->off[s->npk] = 0;
    s->types[s->npk++] = CODEC_PKT_STREAM;
    s->len = n;
    for (int k = 0; k < nk; k++) {
        assert_int_equal(scene_eval(sc, 0.2 + (double)k / KEY_HZ, 1.0 / KEY_HZ, &f, &err), 0);
        enum codec_key_mode m = k % intra == 0 ? CODEC_KEY_INTRA : CODEC_KEY_AUTO;
        uint64_t t = (uint64_t)k * 1000000u / KEY_HZ;
        assert_int_equal(codec_enc_key(e, &f, t, m, NULL, s->buf + s->len, cap - s->len, &n), 0);
        s->off[s->npk] = s->len;
        s->t[s->npk] = t;
        s->types[s->npk++] = m == CODEC_KEY_INTRA ? CODEC_PKT_INTRA : CODEC_PKT_PRED;
        s->len += n;
    }
    assert_int_equal(codec_enc_end(e, (uint64_t)nk * 1000000u / KEY_HZ, s->buf + s->len, cap - s->len, &n), 0);
    s->off[s->npk] = s->len;
    s->types[s->npk++] = CODEC_PKT_END;
    s->len += n;
    codec_enc_free(e);
    splat_frame_free(&f);
    scene_free(sc);
}

static struct display_config headless(const struct stream *s, enum display_renderer r)
{
    struct display_config c = display_config_default();
    c.output = DISPLAY_HEADLESS;
    c.renderer = r;
    c.width = W;
    c.height = H;
    c.fps = FPS;
    c.status_line = 0;
    c.read_back = 1;
    c.camera = &s->rig.cams[0];
    c.lookup_rig = &s->rig;
    return c;
}

static fk_ctx *ctx_new(void)
{
    fk_ctx *ctx;
    struct fk_ctx_config kc = { .isa = FK_ISA_AUTO, .threads = 2 };
    assert_int_equal(fk_ctx_new(&kc, &ctx), 0);
    return ctx;
}

/* display_new, or a skip when this machine has no surfaceless EGL at all. */
static display *open_or_skip(fk_ctx *ctx, const struct display_config *c)
{
    display *d = NULL;
    struct f4d_err err = { 0 };
    int rc = display_new(ctx, c, &d, &err);
    if (rc == F4D_ENODEV || rc == F4D_ENOTSUP) {
        fk_ctx_free(ctx);
        f4d_skip("no surfaceless EGL display (Mesa's libegl-mesa0 / libgl1-mesa-dri): %s", err.msg);
    }
    if (rc < 0)
        fail_msg("display_new: %s", err.msg);
    return d;
}

/* The reference: a player fed the same packets as the display's pump, the
 * frame at refresh k's time, rendered by firmware/splat and quantised. */
struct ref {
    display_player *p;
    display_source *src;
    splat_renderer *r;
    float          *rgb;
    uint8_t        *rgb8;
    uint64_t        t0;
    int             eof;
};

static void ref_open(struct ref *R, fk_ctx *ctx, const struct stream *s)
{
    struct f4d_err err;
    assert_int_equal(display_player_new(ctx, &s->rig, INTERP_FUSED, 0, &R->p, &err), 0);
    /* the display's lookup; the player pushes every packet as it comes (no read-ahead) */
    assert_int_equal(display_player_set_lookup(R->p, display_config_default().lookup, &err), 0);
    assert_int_equal(display_source_memory(s->buf, s->len, &R->src, &err), 0);
    assert_int_equal(splat_renderer_new(ctx, W, H, &R->r, &err), 0);
    R->rgb = malloc(3 * W * H * sizeof(float));
    R->rgb8 = malloc(3 * W * H);
    R->eof = 0;
}

static void ref_close(struct ref *R)
{
    display_player_free(R->p);
    display_source_free(R->src);
    splat_renderer_free(R->r);
    free(R->rgb);
    free(R->rgb8);
}

/* Pulls until a key at or after t (the display's rule), renders refresh k. */
static void ref_frame(struct ref *R, const struct splat_camera *cam, int k)
{
    uint64_t tp, tn;
    if (k == 0) {
        while (display_player_keys(R->p, &tp, &tn) == 0) {
            struct codec_packet pk;
            assert_int_equal(display_source_next(R->src, &pk, NULL), 1);
            assert_true(display_player_push(R->p, &pk) >= 0);
        }
        R->t0 = tn;
    }
    uint64_t t = R->t0 + (uint64_t)((double)k * 1e6 / FPS + 0.5);
    while (!R->eof && (display_player_keys(R->p, &tp, &tn) == 0 || tn < t)) {
        struct codec_packet pk;
        int rc = display_source_next(R->src, &pk, NULL);
        if (rc == F4D_EEOF) {
            R->eof = 1;
            break;
        }
        assert_int_equal(rc, 1);
        assert_true(display_player_push(R->p, &pk) >= 0);
    }
    const struct splat_frame *f;
    assert_int_equal(display_player_frame(R->p, t, cam, &f), 0);
    struct splat_render_out o = { .rgb = R->rgb };
    assert_int_equal(splat_render(R->r, cam, f, NULL, &o), 0);
    for (size_t i = 0; i < 3 * W * H; i++) {
        float v = R->rgb[i];
        v = v < 0.0f ? 0.0f : (v > 1.0f ? 1.0f : v);
        R->rgb8[i] = (uint8_t)floorf(v * 255.0f + 0.5f);
    }
}

static double psnr8(const uint8_t *a, const uint8_t *b, size_t n)
{
    double se = 0;
    for (size_t i = 0; i < n; i++) {
        double d = ((double)a[i] - (double)b[i]) / 255.0;
        se += d * d;
    }
    return se == 0 ? INFINITY : 10.0 * log10((double)n / se);
}

/* Runs `frames` refreshes of renderer r against the reference; returns the
 * lowest PSNR (dB) and checks every refresh drew something. */
static double compare_run(enum display_renderer r, int frames)
{
    struct stream s;
    make_stream(&s, 4, 100);
    fk_ctx *ctx = ctx_new();
    struct display_config c = headless(&s, r);
    display *d = open_or_skip(ctx, &c);
    struct f4d_err err;
    display_source *src;
    assert_int_equal(display_source_memory(s.buf, s.len, &src, &err), 0);
    struct ref R;
    ref_open(&R, ctx, &s);
    double worst = INFINITY;
    for (int k = 0; k < frames; k++) {
        assert_int_equal(display_step(d, src), 1);
        int w, h;
        const uint8_t *img = display_read_back(d, &w, &h);
        assert_non_null(img);
        assert_int_equal(w, W);
        assert_int_equal(h, H);
        ref_frame(&R, &s.rig.cams[0], k);
        size_t lit = 0;
        for (size_t i = 0; i < 3 * W * H; i++)
            lit += R.rgb8[i] > 0;
        assert_true(lit > 3 * W * H / 50); /* the figure is in view */
        double p = psnr8(img, R.rgb8, 3 * W * H);
        printf("  %s refresh %d (t = %.3f s): PSNR %.2f dB against firmware/splat\n",
               r == DISPLAY_RENDER_CPU ? "cpu " : "gles", k, (double)k / FPS, p);
        worst = fmin(worst, p);
    }
    assert_int_equal((int)display_get_stats(d)->renderer, (int)r);
    assert_true(display_get_stats(d)->player.keys >= 2);
    ref_close(&R);
    display_source_free(src);
    display_free(d);
    fk_ctx_free(ctx);
    free(s.buf);
    return worst;
}

static void cpu_matches_splat(void **state)
{
    (void)state;
    /* 7 refreshes at 30 fps over 10 Hz keys: key times and a = 1/3, 2/3 between */
    double p = compare_run(DISPLAY_RENDER_CPU, 7);
    assert_true(isinf(p));
}

#define GLES_PSNR_FLOOR 45.0
static void gles_matches_splat(void **state)
{
    (void)state;
    double p = compare_run(DISPLAY_RENDER_GLES, 4);
    printf("  gles worst PSNR %.2f dB (floor %.1f)\n", p, GLES_PSNR_FLOOR);
    assert_true(p >= GLES_PSNR_FLOOR);
}

static void auto_picks(void **state)
{
    (void)state;
    struct stream s;
    make_stream(&s, 2, 100);
    fk_ctx *ctx = ctx_new();
    struct display_config c = headless(&s, DISPLAY_RENDER_AUTO);
    display *d = open_or_skip(ctx, &c);
    display_source *src;
    assert_int_equal(display_source_memory(s.buf, s.len, &src, NULL), 0);
    assert_int_equal(display_step(d, src), 1);
    const struct display_stats *st = display_get_stats(d);
    printf("  AUTO on '%s': cpu %.2f ms, gles %.2f ms -> %s\n", st->gl_renderer, st->auto_cpu_ms, st->auto_gles_ms,
           st->renderer == DISPLAY_RENDER_CPU ? "cpu" : "gles");
    assert_true(st->auto_cpu_ms > 0 && st->auto_gles_ms > 0);
    assert_int_equal((int)st->renderer,
                     st->auto_cpu_ms <= st->auto_gles_ms ? DISPLAY_RENDER_CPU : DISPLAY_RENDER_GLES);
    display_source_free(src);
    display_free(d);
    fk_ctx_free(ctx);
    free(s.buf);
}

static void run_to_end(display *d, display_source *src, int max)
{
    int rc, n = 0;
    while ((rc = display_step(d, src)) == 1 && n++ < max) {
    }
    assert_true(rc == 0);
}

static void join_mid_stream(void **state)
{
    (void)state;
    struct stream s;
    make_stream(&s, 10, 4); /* intra keys 0, 4, 8 = packets 1, 5, 9 */
    assert_int_equal(s.types[5], CODEC_PKT_INTRA);
    assert_int_equal(s.types[3], CODEC_PKT_PRED);
    char path[] = "/tmp/f4d_display_join_XXXXXX";
    int fd = mkstemp(path);
    assert_true(fd >= 0);
    assert_int_equal(write(fd, s.buf, s.len), (ssize_t)s.len);
    close(fd);
    fk_ctx *ctx = ctx_new();
    struct display_config c = headless(&s, DISPLAY_RENDER_CPU);
    display *d = open_or_skip(ctx, &c);
    display_source *src;
    struct f4d_err err;
    /* 7 bytes into the predicted key 2 (packet 3): inside a packet */
    assert_int_equal(display_source_file(path, s.off[3] + 7, &src, &err), 0);
    int waits = 0;
    while (display_get_stats(d)->frames == 0) {
        assert_int_equal(display_step(d, src), 1);
        waits++;
        assert_true(waits < 100);
    }
    const struct display_stats *st = display_get_stats(d);
    assert_int_equal(st->player.keys, 1);            /* the intra key 4 */
    assert_int_equal(st->player.waited, 1);          /* predicted key 3 before it */
    assert_int_equal(st->source.skipped_bytes, s.off[4] - s.off[3] - 7);
    assert_int_equal(st->source.dropped, 0);         /* a join is not damage */
    run_to_end(d, src, 1000);
    st = display_get_stats(d);
    /* keys 4..9 at 10 Hz shown at 30 fps: 0.5 s of stream, 16 refreshes */
    printf("  joined at byte %zu: %llu packets waited, %llu keys, %llu frames\n", s.off[3] + 7,
           (unsigned long long)st->player.waited, (unsigned long long)st->player.keys,
           (unsigned long long)st->frames);
    assert_int_equal(st->player.keys, 6);
    assert_int_equal(st->frames, 16);
    display_source_free(src);
    display_free(d);
    fk_ctx_free(ctx);
    unlink(path);
    free(s.buf);
}

static void damaged_packet(void **state)
{
    (void)state;
    struct stream s;
    make_stream(&s, 10, 4);
    s.buf[s.off[2] + CODEC_PACKET_HEADER + 40] ^= 0x5a; /* predicted key 1: CRC fails */
    fk_ctx *ctx = ctx_new();
    struct display_config c = headless(&s, DISPLAY_RENDER_CPU);
    display *d = open_or_skip(ctx, &c);
    display_source *src;
    assert_int_equal(display_source_memory(s.buf, s.len, &src, NULL), 0);
    run_to_end(d, src, 1000);
    const struct display_stats *st = display_get_stats(d);
    printf("  damaged key 1: %llu dropped, %llu lost, %llu skipped, %llu keys, %llu frames\n",
           (unsigned long long)st->source.dropped, (unsigned long long)st->player.lost,
           (unsigned long long)st->player.skipped, (unsigned long long)st->player.keys,
           (unsigned long long)st->frames);
    assert_int_equal(st->source.dropped, 1);
    assert_int_equal(st->player.lost, 1);
    assert_int_equal(st->player.skipped, 2); /* keys 2 and 3 have no reference */
    assert_int_equal(st->player.keys, 7);    /* 0, then 4..9 */
    assert_int_equal(st->frames, 28);        /* 0.9 s of stream at 30 fps, + 1 */
    display_source_free(src);
    display_free(d);
    fk_ctx_free(ctx);
    free(s.buf);
}

static void status_line(void **state)
{
    (void)state;
    struct stream s;
    make_stream(&s, 2, 100);
    fk_ctx *ctx = ctx_new();
    struct display_config c = headless(&s, DISPLAY_RENDER_CPU);
    c.status_line = 1;
    display *d = open_or_skip(ctx, &c);
    display_source *src;
    assert_int_equal(display_source_memory(s.buf, s.len, &src, NULL), 0);
    assert_int_equal(display_step(d, src), 1);
    int w, h;
    const uint8_t *img = display_read_back(d, &w, &h);
    size_t white = 0, below = 0;
    for (int y = 0; y < 20; y++) /* the bar: 7 x 2 px glyphs from row 3 */
        for (int x = 0; x < w; x++)
            white += img[3 * ((size_t)y * w + x)] == 255 && img[3 * ((size_t)y * w + x) + 1] == 255;
    for (int y = 20; y < h; y++)
        for (int x = 0; x < w; x++)
            below += img[3 * ((size_t)y * w + x)] == 255 && img[3 * ((size_t)y * w + x) + 1] == 255 &&
                     img[3 * ((size_t)y * w + x) + 2] == 255;
    printf("  status line: %zu white pixels in the bar\n", white);
    assert_true(white > 200);
    (void)below;
    display_source_free(src);
    display_free(d);
    fk_ctx_free(ctx);
    free(s.buf);
}

static void no_alloc_per_frame(void **state)
{
    (void)state;
    for (int r = DISPLAY_RENDER_CPU; r <= DISPLAY_RENDER_GLES; r++) {
        struct stream s;
        make_stream(&s, 6, 3); /* intra and predicted keys, decoded inside the refreshes */
        fk_ctx *ctx = ctx_new();
        struct display_config c = headless(&s, (enum display_renderer)r);
        c.read_back = 0;
        c.status_line = 1;
        display *d = open_or_skip(ctx, &c);
        display_source *src;
        assert_int_equal(display_source_memory(s.buf, s.len, &src, NULL), 0);
        assert_int_equal(display_step(d, src), 1); /* the first key sizes everything */
        long before = allocs;
        int n = 0, rc;
        while ((rc = display_step(d, src)) == 1)
            n++;
        assert_int_equal(rc, 0);
        printf("  %s: %d refreshes, %llu keys, %ld allocations after the first\n", r == DISPLAY_RENDER_CPU ? "cpu" : "gles",
               n, (unsigned long long)display_get_stats(d)->player.keys, allocs - before);
        assert_true(n >= 10);
        assert_int_equal(allocs - before, 0);
        display_source_free(src);
        display_free(d);
        fk_ctx_free(ctx);
        free(s.buf);
    }
}

/* Runs two displays with configurations c[0] and c[1] over the same stream
 * in step (both must end alike); returns the refreshes and the lowest PSNR
 * between their pictures (INFINITY: every refresh byte for byte equal). */
static int run_two(const struct stream *s, struct display_config c[2], double *worst,
                   struct display_stats st[2])
{
    fk_ctx *ctx = ctx_new();
    display *d[2];
    display_source *src[2];
    for (int m = 0; m < 2; m++) {
        d[m] = open_or_skip(ctx, &c[m]);
        assert_int_equal(display_source_memory(s->buf, s->len, &src[m], NULL), 0);
    }
    int n = 0, rc[2];
    *worst = INFINITY;
    do {
        for (int m = 0; m < 2; m++)
            rc[m] = display_step(d[m], src[m]);
        assert_int_equal(rc[0], rc[1]);
        if (rc[0] == 1) {
            int w[2], h[2];
            const uint8_t *a = display_read_back(d[0], &w[0], &h[0]), *b = display_read_back(d[1], &w[1], &h[1]);
            assert_non_null(a);
            assert_non_null(b);
            double p = psnr8(a, b, 3 * (size_t)W * H);
            *worst = p < *worst ? p : *worst;
            n++;
        }
    } while (rc[0] == 1);
    assert_int_equal(rc[0], 0);
    for (int m = 0; m < 2; m++) {
        st[m] = *display_get_stats(d[m]);
        display_source_free(src[m]);
        display_free(d[m]);
    }
    fk_ctx_free(ctx);
    return n;
}

/* The ahead thread (the next refresh pulled, decoded and interpolated while
 * this one is drawn, then a part of the key read ahead) changes nothing:
 * every refresh's picture, the end of the stream and the counters are the
 * serial display's. */
static void ahead_matches_serial(void **state)
{
    (void)state;
    struct stream s;
    make_stream(&s, 6, 3);
    struct display_config c[2];
    for (int m = 0; m < 2; m++) {
        c[m] = headless(&s, DISPLAY_RENDER_CPU);
        c[m].serial = m; /* no status line: its fps differs between runs */
    }
    double worst;
    struct display_stats st[2];
    int n = run_two(&s, c, &worst, st);
    const struct display_stats *x = &st[0], *y = &st[1];
    printf("  %d refreshes identical, %llu keys (%llu / %llu decoded ahead, %llu / %llu lookups built ahead), "
           "%llu redraws skipped\n",
           n, (unsigned long long)x->player.keys, (unsigned long long)x->player.keys_ahead,
           (unsigned long long)y->player.keys_ahead, (unsigned long long)x->player.lookups_ahead,
           (unsigned long long)y->player.lookups_ahead, (unsigned long long)x->redraws_skipped);
    assert_true(n >= 10);
    assert_true(isinf(worst)); /* every refresh byte for byte */
    assert_int_equal(x->frames, y->frames);
    assert_int_equal(x->player.keys, y->player.keys);
    assert_true(x->player.keys >= 5);
    assert_int_equal(x->redraws_skipped, y->redraws_skipped);
    assert_int_equal(x->drawn, y->drawn);
    assert_int_equal(x->pairs, y->pairs);
    /* both read ahead: every key after the first two pairs' is decoded and
     * looked up a refresh or two before the refresh that shows it */
    for (int m = 0; m < 2; m++) {
        assert_true(st[m].player.keys_ahead + 2 >= st[m].player.keys);
        assert_true(st[m].player.lookups_ahead + 3 >= st[m].player.keys);
    }
    free(s.buf);
}

/* The z-buffer lookup (cfg.lookup) changes only which Gaussians fuse between
 * keys: the pictures stay close to the render lookup's (and differ: the
 * setting reaches the player). */
static void zbuffer_lookup_close(void **state)
{
    (void)state;
    struct stream s;
    make_stream(&s, 6, 3);
    struct display_config c[2];
    for (int m = 0; m < 2; m++) {
        c[m] = headless(&s, DISPLAY_RENDER_CPU);
        c[m].lookup = m ? INTERP_LOOKUP_ZBUFFER : INTERP_LOOKUP_RENDER;
    }
    double worst;
    struct display_stats st[2];
    int n = run_two(&s, c, &worst, st);
    printf("  %d refreshes, worst PSNR z-buffer vs render lookup %.1f dB\n", n, worst);
    assert_true(n >= 10);
    assert_true(worst >= 40.0);
    assert_false(isinf(worst));
    free(s.buf);
}

static void bad_input(void **state)
{
    (void)state;
    fk_ctx *ctx = ctx_new();
    struct display_config c = display_config_default();
    struct f4d_err err = { 0 };
    display *d = NULL;
    c.fps = 0;
    assert_int_equal(display_new(ctx, &c, &d, &err), F4D_EINVAL);
    assert_non_null(strstr(err.msg, "fps"));
    c = display_config_default();
    c.width = 4;
    assert_int_equal(display_new(ctx, &c, &d, &err), F4D_EINVAL);
    assert_non_null(strstr(err.msg, "size"));
    display_source *src = NULL;
    assert_int_equal(display_source_file("/nonexistent/x.f4ds", 0, &src, &err), F4D_EIO);
    assert_non_null(strstr(err.msg, "/nonexistent/x.f4ds"));
    display_player *p = NULL;
    assert_int_equal(display_player_new(ctx, NULL, (enum interp_mode)7, 0, &p, &err), F4D_EINVAL);
    assert_non_null(strstr(err.msg, "mode"));
    assert_int_equal(display_player_new(ctx, NULL, INTERP_FUSED, 0, &p, &err), 0);
    assert_int_equal(display_player_set_lookup(p, (enum interp_lookup)9, &err), F4D_EINVAL);
    assert_non_null(strstr(err.msg, "lookup"));
    display_player_free(p);
    fk_ctx_free(ctx);
}

int main(int argc, char **argv)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(cpu_matches_splat),  cmocka_unit_test(gles_matches_splat), cmocka_unit_test(auto_picks),
        cmocka_unit_test(join_mid_stream),    cmocka_unit_test(damaged_packet),     cmocka_unit_test(status_line),
        cmocka_unit_test(no_alloc_per_frame), cmocka_unit_test(ahead_matches_serial), cmocka_unit_test(zbuffer_lookup_close),
        cmocka_unit_test(bad_input),
    };
    return F4D_TEST_MAIN(argc, argv, "display", tests, NULL, NULL);
}
