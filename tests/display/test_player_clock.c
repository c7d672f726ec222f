/* test_player_clock.c - the display player's live policy (no GL needed):
 *   catch_up      display_player_clock raises a clock that trails the newest
 *                 key by more than the lag to the newest key less the lag,
 *                 keeps the raise (never goes back) and counts it;
 *   lag_one       with a lag of one key interval a clock inside the last
 *                 interval is left alone and the frame there interpolates
 *                 (the pair's lookup runs);
 *   hold_newest   live, a frame at or past the newest key is that key as
 *                 decoded, with no lookup; without the live clock the same
 *                 time still goes through the interpolation;
 *   no_keys       before any key the clock is returned as given. */
#include <stdlib.h>
#include <string.h>

#include "f4d_display.h"
#include "f4d_test.h"
#include "scene.h"

#define W 96
#define H 72
#define KEY_HZ 10
#define NK 3

struct stream {
    uint8_t *buf;
    size_t off[NK + 2], len, count;
    int npk;
    struct splat_rig rig;
    struct splat_frame key[NK]; /* the keys as decoded by a second decoder */
};

/* NK keys of the walk figure with exact motion at 10 Hz (0, 100, 200 ms). */
static void make_stream(struct stream *s)
{
    memset(s, 0, sizeof *s);
    scene *sc;
    struct f4d_err err;
    assert_int_equal(scene_new(SCENE_WALK, 5, 4000, &sc, &err), 0);
    scene_default_rig(sc, 2, W, H, &s->rig);
    struct splat_frame f = {0};
    assert_int_equal(scene_eval(sc, 0.2, 1.0 / KEY_HZ, &f, &err), 0);
    s->count = f.count;
    codec_enc *e;
    assert_int_equal(codec_enc_new(f.count, CODEC_Q_MEDIUM, &e, &err), 0);
    size_t cap = codec_packet_bound(f.count) * (NK + 2), n;
    s->buf = malloc(cap);
    assert_non_null(s->buf);
    assert_int_equal(codec_enc_stream_header(e, 0, s->buf, cap, &n), 0);
    s->off[s->npk++] = 0;
    s->len = n;
    for (int k = 0; k < NK; k++) {
        assert_int_equal(scene_eval(sc, 0.2 + (double)k / KEY_HZ, 1.0 / KEY_HZ, &f, &err), 0);
        uint64_t t = (uint64_t)k * 1000000u / KEY_HZ;
        enum codec_key_mode m = k == 0 ? CODEC_KEY_INTRA : CODEC_KEY_AUTO;
        assert_int_equal(codec_enc_key(e, &f, t, m, NULL, s->buf + s->len, cap - s->len, &n), 0);
        s->off[s->npk++] = s->len;
        s->len += n;
    }
    codec_enc_free(e);
    splat_frame_free(&f);
    scene_free(sc);
    /* the reference: every key through a decoder of its own */
    codec_dec *d;
    assert_int_equal(codec_dec_new(s->count, &d, &err), 0);
    for (int i = 0, k = 0; i < s->npk; i++) {
        struct codec_packet p;
        size_t end = i + 1 < s->npk ? s->off[i + 1] : s->len;
        assert_int_equal(codec_packet_parse(s->buf + s->off[i], end - s->off[i], &p, &err), 0);
        int rc = codec_dec_packet(d, &p);
        assert_true(rc >= 0);
        if (rc == 1)
            assert_int_equal(splat_frame_copy(&s->key[k++], codec_dec_frame(d), &err), 0);
    }
    codec_dec_free(d);
}

static void free_stream(struct stream *s)
{
    for (int k = 0; k < NK; k++)
        splat_frame_free(&s->key[k]);
    free(s->buf);
}

/* Packets 0 .. upto (the header is packet 0, key k is packet k + 1). */
static void push_upto(display_player *p, const struct stream *s, int upto)
{
    struct f4d_err err;
    for (int i = 0; i <= upto; i++) {
        struct codec_packet pk;
        size_t end = i + 1 < s->npk ? s->off[i + 1] : s->len;
        assert_int_equal(codec_packet_parse(s->buf + s->off[i], end - s->off[i], &pk, &err), 0);
        assert_true(display_player_push(p, &pk) >= 0);
    }
}

static int same_frame(const struct splat_frame *a, const struct splat_frame *b)
{
    return a->count == b->count && !memcmp(a->pos, b->pos, 3 * a->count * sizeof(float)) &&
           !memcmp(a->rgb, b->rgb, 3 * a->count * sizeof(float)) &&
           !memcmp(a->opacity, b->opacity, a->count * sizeof(float));
}

struct fx {
    fk_ctx *ctx;
    struct stream s;
};

static int setup(void **state)
{
    struct fx *x = calloc(1, sizeof *x);
    struct fk_ctx_config kc = {.isa = FK_ISA_AUTO, .threads = 1};
    if (!x || fk_ctx_new(&kc, &x->ctx) != F4D_OK)
        return -1;
    make_stream(&x->s);
    *state = x;
    return 0;
}

static int teardown(void **state)
{
    struct fx *x = *state;
    free_stream(&x->s);
    fk_ctx_free(x->ctx);
    free(x);
    return 0;
}

static void no_keys(void **state)
{
    struct fx *x = *state;
    display_player *p;
    struct f4d_err err;
    assert_int_equal(display_player_new(x->ctx, &x->s.rig, INTERP_FUSED, 0, &p, &err), 0);
    assert_true(display_player_clock(p, 12345, 0.0) == 12345);
    assert_true(display_player_get_stats(p)->clock_raises == 0);
    display_player_free(p);
}

static void catch_up(void **state)
{
    struct fx *x = *state;
    display_player *p;
    struct f4d_err err;
    assert_int_equal(display_player_new(x->ctx, &x->s.rig, INTERP_FUSED, 0, &p, &err), 0);
    push_upto(p, &x->s, 2); /* keys at 0 and 100 ms */
    /* the display's own clock at 0: 100 ms behind the newest key */
    assert_true(display_player_clock(p, 0, 0.0) == 100000);
    const struct display_player_stats *st = display_player_get_stats(p);
    assert_true(st->clock_raises == 1);
    assert_true(st->clock_raised_ms > 99.9 && st->clock_raised_ms < 100.1);
    /* the raise is kept: 10 ms later on the own clock is 110 ms, no new raise */
    assert_true(display_player_clock(p, 10000, 0.0) == 110000);
    assert_true(st->clock_raises == 1);
    /* key 2 (200 ms) arrives: caught up again, never back */
    push_upto(p, &x->s, 3);
    uint64_t t = display_player_clock(p, 20000, 0.0);
    assert_true(t == 200000);
    assert_true(st->clock_raises == 2);
    assert_true(display_player_clock(p, 30000, 0.0) == 210000);
    display_player_free(p);
}

static void lag_one(void **state)
{
    struct fx *x = *state;
    display_player *p;
    struct f4d_err err;
    assert_int_equal(display_player_new(x->ctx, &x->s.rig, INTERP_FUSED, 0, &p, &err), 0);
    push_upto(p, &x->s, 2);
    /* one key interval behind the newest is allowed: 0 stays 0 */
    assert_true(display_player_clock(p, 0, 1.0) == 0);
    assert_true(display_player_clock(p, 50000, 1.0) == 50000);
    assert_true(display_player_get_stats(p)->clock_raises == 0);
    /* inside the interval: interpolated (the pair's lookup ran), not a key */
    const struct splat_frame *f;
    assert_int_equal(display_player_frame(p, 50000, NULL, &f), 0);
    assert_true(display_player_get_stats(p)->lookup_ms > 0);
    assert_false(same_frame(f, &x->s.key[0]));
    assert_false(same_frame(f, &x->s.key[1]));
    /* half a key interval lag, behind by one: raised to 50 ms */
    push_upto(p, &x->s, 0); /* nothing new: the header again is ignored */
    assert_true(display_player_clock(p, 0, 0.5) == 50000);
    display_player_free(p);
}

static void hold_newest(void **state)
{
    struct fx *x = *state;
    struct f4d_err err;
    for (int live = 0; live <= 1; live++) {
        display_player *p;
        assert_int_equal(display_player_new(x->ctx, &x->s.rig, INTERP_FUSED, 0, &p, &err), 0);
        push_upto(p, &x->s, 2);
        uint64_t t = live ? display_player_clock(p, 0, 0.0) : 100000;
        assert_true(t == 100000);
        const struct splat_frame *f;
        assert_int_equal(display_player_frame(p, t, NULL, &f), 0);
        const struct display_player_stats *st = display_player_get_stats(p);
        if (live) { /* the newest key exactly as decoded, no lookup */
            assert_true(same_frame(f, &x->s.key[1]));
            assert_true(st->held == 1);
            assert_true(st->lookup_ms == 0);
            /* past it too (the next key late): still held */
            assert_int_equal(display_player_frame(p, display_player_clock(p, 40000, 0.0), NULL, &f), 0);
            assert_true(same_frame(f, &x->s.key[1]));
            assert_true(st->held == 2);
        } else { /* not live: a = 1 of the fused pair, which is not key 1 as decoded */
            assert_true(st->held == 0);
            assert_true(st->lookup_ms > 0);
            assert_false(same_frame(f, &x->s.key[1]));
        }
        display_player_free(p);
    }
}

int main(int argc, char **argv)
{
    argc = f4d_test_parse(argc, argv);
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(no_keys),
        cmocka_unit_test(catch_up),
        cmocka_unit_test(lag_one),
        cmocka_unit_test(hold_newest),
    };
    return F4D_TEST_MAIN(argc, argv, "display/player_clock", tests, setup, teardown);
}
