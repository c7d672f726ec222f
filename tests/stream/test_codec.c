/* test_codec.c - the stream codec: round trips per quality level with error
 * bounds, predicted keys with dropped / new Gaussians, the container (joining
 * mid-stream, a lost packet, corrupted CRC, truncation), refused input, no
 * allocation per frame, SPZ. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <zlib.h>

#include "f4d_test.h"
#include "f4d_codec.h"
#include "scene.h"

/* ---- allocation counter (malloc wrapped at link time) ---- */
void *__real_malloc(size_t n);
void *__real_calloc(size_t a, size_t b);
void *__real_realloc(void *p, size_t n);
static int g_count_allocs;
static long g_allocs;
void *__wrap_malloc(size_t n);
void *__wrap_calloc(size_t a, size_t b);
void *__wrap_realloc(void *p, size_t n);
void *__wrap_malloc(size_t n) { if (g_count_allocs) g_allocs++; return __real_malloc(n); }
void *__wrap_calloc(size_t a, size_t b) { if (g_count_allocs) g_allocs++; return __real_calloc(a, b); }
void *__wrap_realloc(void *p, size_t n) { if (g_count_allocs) g_allocs++; return __real_realloc(p, n); }

static uint32_t codec__test_u32(const uint8_t *p)
{
    return (uint32_t)p[0] | (uint32_t)p[1] << 8 | (uint32_t)p[2] << 16 | (uint32_t)p[3] << 24;
}

#define N_G 4000
#define CAP 8192

static void make_key(scene *s, int k, double dt, struct splat_frame *f)
{
    assert_int_equal(scene_eval(s, k * dt, dt, f, NULL), 0);
}

static scene *walk(void)
{
    scene *s;
    assert_int_equal(scene_new(SCENE_WALK, 3, N_G, &s, NULL), 0);
    return s;
}

/* Every value of b within the level's bounds of a (same Gaussian order).
 * Predicted keys (version 2) may keep a rotation that moves the Gaussian's
 * 2-sigma ellipsoid by no more than the position bound, and motions within
 * two position bounds + half a motion step (see f4d_codec.h). */
static void check_bounds_k(const struct splat_frame *a, const struct splat_frame *b, enum codec_quality q, int pred)
{
    const struct codec_quality_info *qi = codec_quality_get(q);
    assert_int_equal(a->count, b->count);
    float rgb_lo[3] = { 1e9f, 1e9f, 1e9f }, rgb_hi[3] = { -1e9f, -1e9f, -1e9f };
    for (size_t i = 0; i < a->count; i++)
        for (int c = 0; c < 3; c++) {
            rgb_lo[c] = fminf(rgb_lo[c], a->rgb[3 * i + c]);
            rgb_hi[c] = fmaxf(rgb_hi[c], a->rgb[3 * i + c]);
        }
    double ep = 0, el = 0, eo = 0, er = 0, eq = 0, em = 0;
    for (size_t i = 0; i < a->count; i++) {
        for (int c = 0; c < 3; c++) {
            ep = fmax(ep, fabs(a->pos[3 * i + c] - b->pos[3 * i + c]));
            el = fmax(el, fabs(log(fmax(a->scale[3 * i + c], 1e-7)) - log(b->scale[3 * i + c])));
            er = fmax(er, fabs(a->rgb[3 * i + c] - b->rgb[3 * i + c]) /
                              ((rgb_hi[c] - rgb_lo[c]) / ((1 << qi->rgb_bits) - 1)));
            if (a->motion_fwd) {
                em = fmax(em, fabs(a->motion_fwd[3 * i + c] - b->motion_fwd[3 * i + c]));
                em = fmax(em, fabs(a->motion_bwd[3 * i + c] - b->motion_bwd[3 * i + c]));
            }
        }
        eo = fmax(eo, fabs(a->opacity[i] - b->opacity[i]));
        double dot = 0, nn = 0;
        for (int c = 0; c < 4; c++) {
            dot += a->rot[4 * i + c] * b->rot[4 * i + c];
            nn += a->rot[4 * i + c] * a->rot[4 * i + c];
        }
        double e1 = 1.0 - fabs(dot) / sqrt(nn);
        if (pred) {
            const float *sc = a->scale + 3 * i;
            double ext = fmax(sc[0], fmax(sc[1], sc[2])) - fmin(sc[0], fmin(sc[1], sc[2]));
            double ang = 2.0 * acos(fmin(1.0, fabs(dot) / sqrt(nn)));
            if (2.0 * ang * ext <= qi->pos_step_max * 0.5 * 1.02 + 1e-6)
                e1 = 0;
        }
        eq = fmax(eq, e1);
    }
    double rs = 1.41421356 / ((1 << qi->rot_bits) - 1);
    assert_true(ep <= qi->pos_step_max * 0.5 * 1.01 + 2e-6);
    assert_true(el <= qi->log_scale_step * 0.5 + 1e-4);
    assert_true(eo <= 0.5 / ((1 << qi->opacity_bits) - 1) + 1e-6);
    assert_true(er <= 0.5 + 1e-3);
    double mb = qi->motion_step * 0.5 * 1.01 + (pred ? 2.0 * qi->pos_step_max * 0.5 * 1.01 : 0.0);
    assert_true(em <= mb + 2e-6);
    assert_true(eq <= 2.0 * rs * rs + 1e-6); /* 1 - cos(angle) for component error <= step */
}

static void check_bounds(const struct splat_frame *a, const struct splat_frame *b, enum codec_quality q)
{
    check_bounds_k(a, b, q, 0);
}

static void same_frame(const struct splat_frame *a, const struct splat_frame *b)
{
    assert_int_equal(a->count, b->count);
    size_t n = a->count;
    assert_memory_equal(a->pos, b->pos, 3 * n * sizeof(float));
    assert_memory_equal(a->scale, b->scale, 3 * n * sizeof(float));
    assert_memory_equal(a->rot, b->rot, 4 * n * sizeof(float));
    assert_memory_equal(a->opacity, b->opacity, n * sizeof(float));
    assert_memory_equal(a->rgb, b->rgb, 3 * n * sizeof(float));
    assert_int_equal(!!a->motion_fwd, !!b->motion_fwd);
    if (a->motion_fwd) {
        assert_memory_equal(a->motion_fwd, b->motion_fwd, 3 * n * sizeof(float));
        assert_memory_equal(a->motion_bwd, b->motion_bwd, 3 * n * sizeof(float));
    }
}

struct rig {
    codec_enc *e;
    codec_dec *d;
    uint8_t *buf;
    size_t cap;
};

static void rig_open(struct rig *r, enum codec_quality q)
{
    struct f4d_err err = { 0 };
    assert_int_equal(codec_enc_new(CAP, q, &r->e, &err), 0);
    assert_int_equal(codec_dec_new(CAP, &r->d, &err), 0);
    r->cap = codec_packet_bound(CAP);
    r->buf = malloc(r->cap);
    assert_non_null(r->buf);
}

static void rig_close(struct rig *r)
{
    codec_enc_free(r->e);
    codec_dec_free(r->d);
    free(r->buf);
}

/* Encodes, parses and decodes one key; returns the packet size. */
static size_t pass(struct rig *r, const struct splat_frame *f, enum codec_key_mode m, const int32_t *match)
{
    size_t n;
    struct codec_packet p;
    int rc = codec_enc_key(r->e, f, 0, m, match, r->buf, r->cap, &n);
    if (rc)
        fprintf(stderr, "%s\n", codec_enc_error(r->e));
    assert_int_equal(rc, 0);
    assert_int_equal(codec_packet_parse(r->buf, n, &p, NULL), 0);
    rc = codec_dec_packet(r->d, &p);
    if (rc != 1)
        fprintf(stderr, "%s\n", codec_dec_error(r->d));
    assert_int_equal(rc, 1);
    same_frame(codec_enc_recon(r->e), codec_dec_frame(r->d));
    return n;
}

static void test_intra_round_trip_per_level(void **state)
{
    scene *s = walk();
    struct splat_frame f = { 0 };
    make_key(s, 3, 0.1, &f);
    size_t prev = 0;
    static const int by_cost[CODEC_QUALITY_COUNT] = { CODEC_Q_COMPACT, CODEC_Q_LOW, CODEC_Q_MEDIUM, CODEC_Q_HIGH };
    for (int qk = 0; qk < CODEC_QUALITY_COUNT; qk++) {
        int q = by_cost[qk];
        struct rig r;
        rig_open(&r, (enum codec_quality)q);
        size_t n = pass(&r, &f, CODEC_KEY_INTRA, NULL);
        check_bounds(&f, codec_dec_frame(r.d), (enum codec_quality)q);
        assert_true(n > prev); /* higher quality costs more */
        prev = n;
        rig_close(&r);
    }
    splat_frame_free(&f);
    scene_free(s);
}

static void test_predicted_keys(void **state)
{
    scene *s = walk();
    struct splat_frame f = { 0 };
    struct rig r;
    rig_open(&r, CODEC_Q_MEDIUM);
    size_t intra = 0;
    for (int k = 0; k < 4; k++) {
        make_key(s, k, 0.1, &f);
        size_t n = pass(&r, &f, CODEC_KEY_AUTO, NULL);
        const struct codec_enc_stats *st = codec_enc_last(r.e);
        check_bounds_k(&f, codec_dec_frame(r.d), CODEC_Q_MEDIUM, k > 0);
        if (k == 0) {
            intra = n;
            assert_true(st->intra);
        } else {
            assert_false(st->intra);
            assert_true(n < intra);
            assert_true(st->unchanged > 0); /* the floor does not move */
            assert_int_equal(st->unchanged + st->changed, f.count);
        }
    }
    assert_int_equal(codec_dec_stats(r.d)->predicted, 3);
    rig_close(&r);
    splat_frame_free(&f);
    scene_free(s);
}

static void test_predicted_dropped_and_new(void **state)
{
    scene *s = walk();
    struct splat_frame a = { 0 }, b = { 0 }, c = { 0 };
    struct rig r;
    rig_open(&r, CODEC_Q_HIGH);
    make_key(s, 0, 0.1, &a);
    pass(&r, &a, CODEC_KEY_AUTO, NULL);
    make_key(s, 1, 0.1, &b);
    /* c: every 7th Gaussian of b dropped, 100 new ones appended, one moved far */
    size_t n = 0, extra = 100;
    int32_t *match = malloc((b.count + extra) * sizeof *match);
    assert_int_equal(splat_frame_resize(&c, b.count + extra, 1, NULL), 0);
    for (size_t i = 0; i < b.count; i++) {
        if (i % 7 == 3)
            continue;
        memcpy(c.pos + 3 * n, b.pos + 3 * i, 12);
        memcpy(c.scale + 3 * n, b.scale + 3 * i, 12);
        memcpy(c.rot + 4 * n, b.rot + 4 * i, 16);
        memcpy(c.rgb + 3 * n, b.rgb + 3 * i, 12);
        memcpy(c.motion_bwd + 3 * n, b.motion_bwd + 3 * i, 12);
        memcpy(c.motion_fwd + 3 * n, b.motion_fwd + 3 * i, 12);
        c.opacity[n] = b.opacity[i];
        match[n++] = (int32_t)i;
    }
    for (size_t k = 0; k < extra; k++, n++) {
        c.pos[3 * n] = 0.01f * (float)k;
        c.pos[3 * n + 1] = 0.5f;
        c.pos[3 * n + 2] = 1.0f;
        c.scale[3 * n] = c.scale[3 * n + 1] = c.scale[3 * n + 2] = 0.01f;
        c.opacity[n] = 0.5f;
        c.rgb[3 * n] = 1.0f;
        match[n] = -1;
    }
    c.count = n;
    c.pos[0] += 0.3f;
    pass(&r, &c, CODEC_KEY_AUTO, match);
    const struct codec_enc_stats *st = codec_enc_last(r.e);
    assert_int_equal(st->fresh, extra);
    assert_int_equal(st->dropped, (b.count + 3) / 7);
    check_bounds_k(&c, codec_dec_frame(r.d), CODEC_Q_HIGH, 1);
    /* identity correspondence with a shrinking then growing count */
    c.count = n - extra - 50;
    pass(&r, &c, CODEC_KEY_AUTO, NULL);
    check_bounds_k(&c, codec_dec_frame(r.d), CODEC_Q_HIGH, 1);
    c.count = n;
    pass(&r, &c, CODEC_KEY_AUTO, NULL);
    assert_int_equal(codec_enc_last(r.e)->fresh, extra + 50);
    check_bounds_k(&c, codec_dec_frame(r.d), CODEC_Q_HIGH, 1);
    /* a bad match is refused by the encoder */
    size_t len;
    match[0] = (int32_t)c.count + 100000;
    assert_int_equal(codec_enc_key(r.e, &c, 0, CODEC_KEY_AUTO, match, r.buf, r.cap, &len), F4D_EINVAL);
    free(match);
    rig_close(&r);
    splat_frame_free(&a);
    splat_frame_free(&b);
    splat_frame_free(&c);
    scene_free(s);
}

/* A stream: header, I P P I P P, end; packets kept with their offsets. */
struct stream {
    uint8_t *bytes;
    size_t len, off[16], n;
};

static void make_stream(struct stream *st, scene *s)
{
    codec_enc *e;
    assert_int_equal(codec_enc_new(CAP, CODEC_Q_MEDIUM, &e, NULL), 0);
    size_t cap = codec_packet_bound(CAP), l;
    st->bytes = malloc(16 * cap);
    st->len = st->n = 0;
    struct splat_frame f = { 0 };
    assert_int_equal(codec_enc_stream_header(e, 0, st->bytes, cap, &l), 0);
    st->off[st->n++] = 0;
    st->len = l;
    for (int k = 0; k < 6; k++) {
        make_key(s, k, 0.1, &f);
        st->off[st->n++] = st->len;
        assert_int_equal(codec_enc_key(e, &f, (uint64_t)k * 100000, k % 3 == 0 ? CODEC_KEY_INTRA : CODEC_KEY_AUTO,
                                       NULL, st->bytes + st->len, cap, &l), 0);
        st->len += l;
    }
    st->off[st->n++] = st->len;
    assert_int_equal(codec_enc_end(e, 600000, st->bytes + st->len, cap, &l), 0);
    st->len += l;
    st->off[st->n] = st->len;
    splat_frame_free(&f);
    codec_enc_free(e);
}

/* Feeds packets [from, to) except `lose`; returns frames decoded. */
static int feed(codec_dec *d, const struct stream *st, size_t from, size_t to, size_t lose)
{
    int frames = 0;
    for (size_t i = from; i < to; i++) {
        if (i == lose)
            continue;
        struct codec_packet p;
        assert_int_equal(codec_packet_parse(st->bytes + st->off[i], st->off[i + 1] - st->off[i], &p, NULL), 0);
        int rc = codec_dec_packet(d, &p);
        assert_true(rc >= 0);
        frames += rc;
    }
    return frames;
}

static void test_join_mid_stream(void **state)
{
    scene *s = walk();
    struct stream st;
    make_stream(&st, s);
    codec_dec *d;
    assert_int_equal(codec_dec_new(CAP, &d, NULL), 0);
    /* packets: 0 header, 1 I, 2 P, 3 P, 4 I, 5 P, 6 P, 7 end: join at 2 */
    assert_int_equal(feed(d, &st, 2, 8, 99), 3);
    assert_int_equal(codec_dec_stats(d)->skipped, 2);
    assert_int_equal(codec_dec_stats(d)->intra, 1);
    assert_int_equal(codec_dec_time(d), 500000);
    codec_dec_free(d);
    free(st.bytes);
    scene_free(s);
}

static void test_lost_packet(void **state)
{
    scene *s = walk();
    struct stream st;
    make_stream(&st, s);
    codec_dec *d;
    assert_int_equal(codec_dec_new(CAP, &d, NULL), 0);
    assert_int_equal(feed(d, &st, 0, 8, 2), 4); /* lose the first P: the second is skipped */
    const struct codec_dec_stats *ds = codec_dec_stats(d);
    assert_int_equal(ds->lost, 1);
    assert_int_equal(ds->skipped, 1);
    assert_int_equal(ds->intra, 2);
    assert_int_equal(ds->predicted, 2);
    codec_dec_free(d);
    free(st.bytes);
    scene_free(s);
}

static void test_corrupt_and_truncated(void **state)
{
    scene *s = walk();
    struct stream st;
    make_stream(&st, s);
    struct codec_packet p;
    struct f4d_err err = { 0 };
    size_t o = st.off[1], n = st.off[2] - st.off[1];
    /* CRC: one flipped payload bit */
    st.bytes[o + 100] ^= 0x10;
    assert_int_equal(codec_packet_parse(st.bytes + o, n, &p, &err), F4D_ECORRUPT);
    assert_non_null(strstr(err.msg, "CRC"));
    st.bytes[o + 100] ^= 0x10;
    /* truncation: every shorter prefix asks for more */
    assert_int_equal(codec_packet_parse(st.bytes + o, n - 1, &p, NULL), F4D_EEOF);
    assert_int_equal(codec_packet_parse(st.bytes + o, 10, &p, NULL), F4D_EEOF);
    /* resync from inside a packet finds the next one */
    size_t at = 5 + codec_packet_resync(st.bytes + o + 5, st.len - o - 5);
    assert_true(at <= n + 5);
    /* a payload truncated under a valid CRC is refused by the decoder */
    codec_dec *d;
    assert_int_equal(codec_dec_new(CAP, &d, NULL), 0);
    uint8_t *cut = malloc(n);
    size_t cn, plen = n - CODEC_PACKET_HEADER;
    for (size_t keep = 0; keep < plen; keep += plen / 13 + 1) {
        assert_int_equal(codec_packet_write(cut, n, CODEC_PKT_INTRA, 1, 1, 0, st.bytes + o + CODEC_PACKET_HEADER,
                                            keep, &cn, NULL), 0);
        assert_int_equal(codec_packet_parse(cut, cn, &p, NULL), 0);
        assert_true(codec_dec_packet(d, &p) < 0);
        assert_null(codec_dec_frame(d));
    }
    assert_true(codec_dec_stats(d)->refused > 0);
    /* wrong magic / version / type */
    memcpy(cut, st.bytes + o, CODEC_PACKET_HEADER);
    cut[4] = 9;
    assert_int_equal(codec_packet_parse(cut, CODEC_PACKET_HEADER, &p, NULL), F4D_EFORMAT);
    free(cut);
    codec_dec_free(d);
    free(st.bytes);
    scene_free(s);
}

static void test_non_finite_refused(void **state)
{
    scene *s = walk();
    struct splat_frame f = { 0 };
    struct rig r;
    rig_open(&r, CODEC_Q_LOW);
    make_key(s, 0, 0.1, &f);
    size_t n;
    f.pos[3 * 17 + 1] = NAN;
    assert_int_equal(codec_enc_key(r.e, &f, 0, CODEC_KEY_AUTO, NULL, r.buf, r.cap, &n), F4D_EINVAL);
    assert_non_null(strstr(codec_enc_error(r.e), "Gaussian 17"));
    f.pos[3 * 17 + 1] = 0.0f;
    f.motion_fwd[5] = INFINITY;
    assert_int_equal(codec_enc_key(r.e, &f, 0, CODEC_KEY_AUTO, NULL, r.buf, r.cap, &n), F4D_EINVAL);
    f.motion_fwd[5] = 0.0f;
    /* a quantizer made non-finite in the payload is refused by the decoder */
    assert_int_equal(codec_enc_key(r.e, &f, 0, CODEC_KEY_AUTO, NULL, r.buf, r.cap, &n), 0);
    float inf = INFINITY;
    memcpy(r.buf + CODEC_PACKET_HEADER + 20 + 4, &inf, 4);
    size_t m;
    struct codec_packet p;
    assert_int_equal(codec_packet_write(r.buf, r.cap, CODEC_PKT_INTRA, 0, 0, 0, r.buf + CODEC_PACKET_HEADER,
                                        n - CODEC_PACKET_HEADER, &m, NULL), 0);
    assert_int_equal(codec_packet_parse(r.buf, m, &p, NULL), 0);
    assert_int_equal(codec_dec_packet(r.d, &p), F4D_EFORMAT);
    rig_close(&r);
    splat_frame_free(&f);
    scene_free(s);
}

static void test_empty_frames(void **state)
{
    struct rig r;
    rig_open(&r, CODEC_Q_MEDIUM);
    struct splat_frame f = { 0 };
    pass(&r, &f, CODEC_KEY_AUTO, NULL);
    pass(&r, &f, CODEC_KEY_AUTO, NULL);
    assert_int_equal(codec_dec_frame(r.d)->count, 0);
    rig_close(&r);
}

static void test_huge_counts_refused(void **state)
{
    codec_enc *e;
    codec_dec *d;
    assert_int_equal(codec_enc_new(CODEC_CAPACITY_MAX + 1, CODEC_Q_LOW, &e, NULL), F4D_ERANGE);
    assert_int_equal(codec_dec_new(CODEC_CAPACITY_MAX + 1, &d, NULL), F4D_ERANGE);
    struct rig r;
    rig_open(&r, CODEC_Q_LOW);
    struct splat_frame f = { 0 };
    assert_int_equal(splat_frame_resize(&f, CAP + 1, 0, NULL), 0);
    size_t n;
    assert_int_equal(codec_enc_key(r.e, &f, 0, CODEC_KEY_AUTO, NULL, r.buf, r.cap, &n), F4D_ERANGE);
    /* a header claiming 2^32 - 1 Gaussians */
    f.count = 10;
    assert_int_equal(codec_enc_key(r.e, &f, 0, CODEC_KEY_AUTO, NULL, r.buf, r.cap, &n), 0);
    memset(r.buf + CODEC_PACKET_HEADER + 4, 0xff, 4);
    struct codec_packet p;
    assert_int_equal(codec_packet_write(r.buf, r.cap, CODEC_PKT_INTRA, 0, 0, 0, r.buf + CODEC_PACKET_HEADER,
                                        n - CODEC_PACKET_HEADER, &n, NULL), 0);
    assert_int_equal(codec_packet_parse(r.buf, n, &p, NULL), 0);
    assert_int_equal(codec_dec_packet(r.d, &p), F4D_ERANGE);
    /* a packet length over the limit */
    uint8_t h[CODEC_PACKET_HEADER] = { 0x46, 0x34, 0x44, 0x50, 1, 2 };
    h[27] = 0xff;
    assert_int_equal(codec_packet_parse(h, sizeof h, &p, NULL), F4D_EFORMAT);
    rig_close(&r);
    splat_frame_free(&f);
}

static void test_no_allocation_per_frame(void **state)
{
    scene *s = walk();
    struct splat_frame f[4] = { { 0 } };
    for (int k = 0; k < 4; k++)
        make_key(s, k, 0.1, &f[k]);
    struct rig r;
    rig_open(&r, CODEC_Q_MEDIUM);
    g_allocs = 0;
    g_count_allocs = 1;
    for (int k = 0; k < 4; k++)
        pass(&r, &f[k], k == 2 ? CODEC_KEY_INTRA : CODEC_KEY_AUTO, NULL);
    g_count_allocs = 0;
    assert_int_equal(g_allocs, 0);
    rig_close(&r);
    for (int k = 0; k < 4; k++)
        splat_frame_free(&f[k]);
    scene_free(s);
}

/* Decoded g against f within SPZ's quantization steps. */
static void spz_close(const struct splat_frame *f, const struct splat_frame *g)
{
    assert_int_equal(g->count, f->count);
    double ep = 0, el = 0, eo = 0, ec = 0, eq = 0;
    for (size_t i = 0; i < f->count; i++) {
        for (int c = 0; c < 3; c++) {
            ep = fmax(ep, fabs(f->pos[3 * i + c] - g->pos[3 * i + c]));
            double ls = log(f->scale[3 * i + c]);
            if (ls > -10 && ls < 5.9)
                el = fmax(el, fabs(ls - log(g->scale[3 * i + c])));
            double fdc = (f->rgb[3 * i + c] - 0.5) / SPLAT_SH_C0;
            if (fabs(fdc * 0.15 * 255) < 127)
                ec = fmax(ec, fabs(f->rgb[3 * i + c] - g->rgb[3 * i + c]));
        }
        eo = fmax(eo, fabs(f->opacity[i] - g->opacity[i]));
        double dot = 0;
        for (int c = 0; c < 4; c++)
            dot += f->rot[4 * i + c] * g->rot[4 * i + c];
        eq = fmax(eq, 1 - fabs(dot));
    }
    assert_true(ep <= 0.5 / 4096 + 1e-6);
    assert_true(el <= 0.5 / 16 + 1e-4);
    assert_true(eo <= 0.5 / 255 + 1e-6);
    assert_true(ec <= 0.5 / 255 / 0.15 * SPLAT_SH_C0 + 1e-5);
    assert_true(eq < 1e-4);
}

static void test_spz_round_trip(void **state)
{
    (void)state;
    scene *s = walk();
    struct splat_frame f = { 0 }, g = { 0 }, h = { 0 };
    make_key(s, 2, 0.1, &f);
    uint32_t n = (uint32_t)f.count;
    uint8_t *z, *z4;
    size_t zn, z4n;
    /* v3: the header, byte for byte, after gunzip */
    assert_int_equal(codec_spz_encode_version(&f, 3, &z, &zn, NULL), 0);
    uint8_t raw[16];
    z_stream zs;
    memset(&zs, 0, sizeof zs);
    assert_int_equal(inflateInit2(&zs, 15 + 16), Z_OK);
    zs.next_in = z;
    zs.avail_in = (uInt)zn;
    zs.next_out = raw;
    zs.avail_out = sizeof raw;
    inflate(&zs, Z_SYNC_FLUSH);
    inflateEnd(&zs);
    assert_int_equal(zs.total_out, 16);
    const uint8_t want[16] = { 0x4e, 0x47, 0x53, 0x50, 3, 0, 0, 0, (uint8_t)n, (uint8_t)(n >> 8),
                               (uint8_t)(n >> 16), (uint8_t)(n >> 24), 0, 12, 0, 0 };
    assert_memory_equal(raw, want, 16);
    assert_int_equal(z[0], 0x1f);
    assert_int_equal(z[1], 0x8b);
    assert_int_equal(codec_spz_decode(z, zn, &g, NULL), 0);
    spz_close(&f, &g);
    /* v4 (the default): plain header, TOC of 5 streams, each a zstd frame of
     * the v3 array's size; decodes to exactly what v3 decodes to */
    assert_int_equal(codec_spz_encode(&f, &z4, &z4n, NULL), 0);
    const uint8_t want4[20] = { 0x4e, 0x47, 0x53, 0x50, 4, 0, 0, 0, (uint8_t)n, (uint8_t)(n >> 8),
                                (uint8_t)(n >> 16), (uint8_t)(n >> 24), 0, 12, 0, 5, 32, 0, 0, 0 };
    assert_true(z4n > 32 + 5 * 16);
    assert_memory_equal(z4, want4, 20);
    const uint64_t sizes[5] = { 9ull * n, n, 3ull * n, 3ull * n, 4ull * n };
    size_t off = 32 + 5 * 16;
    for (int k = 0; k < 5; k++) {
        uint64_t zc = 0, zu = 0;
        for (int b = 7; b >= 0; b--) {
            zc = zc << 8 | z4[32 + 16 * k + b];
            zu = zu << 8 | z4[32 + 16 * k + 8 + b];
        }
        assert_true(zu == sizes[k]);
        assert_true(z4[off] == 0x28 && z4[off + 1] == 0xb5 && z4[off + 2] == 0x2f && z4[off + 3] == 0xfd);
        off += (size_t)zc;
    }
    assert_int_equal(off, z4n);
    assert_int_equal(codec_spz_decode(z4, z4n, &h, NULL), 0);
    spz_close(&f, &h);
    assert_memory_equal(g.pos, h.pos, 3 * f.count * sizeof(float));
    assert_memory_equal(g.rot, h.rot, 4 * f.count * sizeof(float));
    assert_memory_equal(g.rgb, h.rgb, 3 * f.count * sizeof(float));
    assert_memory_equal(g.opacity, h.opacity, f.count * sizeof(float));
    /* corrupt input: truncated gzip and v4, a v4 header with a bad version,
     * stream count, TOC offset or stream size */
    struct f4d_err err = { 0 };
    assert_true(codec_spz_decode(z, zn / 2, &g, NULL) < 0);
    assert_true(codec_spz_decode(z4, z4n - 1, &g, &err) == F4D_EFORMAT);
    uint8_t *bad = malloc(z4n);
    memcpy(bad, z4, z4n);
    bad[4] = 5;
    assert_int_equal(codec_spz_decode(bad, z4n, &g, &err), F4D_ENOTSUP);
    assert_non_null(strstr(err.msg, "version 5"));
    bad[4] = 4;
    bad[15] = 6;
    assert_int_equal(codec_spz_decode(bad, z4n, &g, &err), F4D_EFORMAT);
    bad[15] = 5;
    bad[16] = 200;
    bad[17] = 200;
    bad[18] = 200;
    assert_int_equal(codec_spz_decode(bad, z4n, &g, &err), F4D_EFORMAT);
    bad[16] = 32;
    bad[17] = bad[18] = 0;
    bad[32 + 8] ^= 1; /* positions' uncompressed size */
    assert_int_equal(codec_spz_decode(bad, z4n, &g, &err), F4D_EFORMAT);
    assert_non_null(strstr(err.msg, "stream 0"));
    free(bad);
    assert_int_equal(codec_spz_encode_version(&f, 2, &z4, &z4n, &err), F4D_ENOTSUP);
    assert_int_equal(codec_spz_read("/nonexistent/x.spz", &g, &err), F4D_EIO);
    assert_non_null(strstr(err.msg, "/nonexistent/x.spz"));
    free(z);
    free(z4);
    splat_frame_free(&f);
    splat_frame_free(&g);
    splat_frame_free(&h);
    scene_free(s);
}

/* Version 2's predictor: with motions over the key interval the fit finds
 * (1, 0) and positions cost next to nothing; with motions over a third of it
 * (a 30 fps take keyed at 10 Hz) it finds the extrapolation (c0 near 6 for
 * a second-order one) and beats the version-1 coefficients' key size. */
static void test_predictor_fit(void **state)
{
    (void)state;
    scene *s = walk();
    struct splat_frame f = { 0 };
    struct rig r;
    rig_open(&r, CODEC_Q_LOW);
    size_t pos_intra = 0, pos_pred = 0;
    for (int k = 0; k < 3; k++) {
        make_key(s, k, 0.1, &f);
        pass(&r, &f, CODEC_KEY_AUTO, NULL);
        const struct codec_enc_stats *st = codec_enc_last(r.e);
        size_t pb = st->bytes_channel[0] + st->bytes_channel[1] + st->bytes_channel[2];
        if (k == 0)
            pos_intra = pb;
        else
            pos_pred = pb;
        check_bounds_k(&f, codec_dec_frame(r.d), CODEC_Q_LOW, k > 0);
    }
    const struct codec_enc_stats *st = codec_enc_last(r.e);
    assert_true(fabsf(st->predictor[0] - 1.0f) < 0.05f && fabsf(st->predictor[1]) < 0.05f);
    assert_true(pos_pred * 20 < pos_intra);
    rig_close(&r);
    /* motion over 1/30 s, keys 0.1 s apart */
    rig_open(&r, CODEC_Q_LOW);
    size_t pos0 = 0;
    for (int k = 0; k < 3; k++) {
        assert_int_equal(scene_eval(s, 0.1 * k, 0.1 / 3, &f, NULL), 0);
        pass(&r, &f, CODEC_KEY_AUTO, NULL);
        check_bounds_k(&f, codec_dec_frame(r.d), CODEC_Q_LOW, 0);
        st = codec_enc_last(r.e);
        if (k == 0)
            pos0 = st->bytes_channel[0] + st->bytes_channel[1] + st->bytes_channel[2];
    }
    st = codec_enc_last(r.e);
    size_t posb = st->bytes_channel[0] + st->bytes_channel[1] + st->bytes_channel[2];
    fprintf(stderr, "1/30 s motions at 10 Hz keys: c0 %.2f c1 %.2f, position bytes %zu (intra %zu)\n",
            (double)st->predictor[0], (double)st->predictor[1], posb, pos0);
    assert_true(st->predictor[0] > 3.0f && st->predictor[0] < 9.0f);
    assert_true(posb * 4 < pos0 * 3); /* c0 = 1 costs about what intra does */
    rig_close(&r);
    splat_frame_free(&f);
    scene_free(s);
}

/* A version-1 packet (no predictor block; the codec version before) still
 * decodes: an intra key rewritten in the version-1 layout gives the same
 * frame, and a static predicted key too. */
static void v1_packet(const uint8_t *pkt, size_t n, uint8_t *out, size_t *out_n)
{
    const size_t H = CODEC_PACKET_HEADER, cut = 28; /* 7 f32 coefficients */
    memcpy(out, pkt, H + 20);
    memcpy(out + H + 20, pkt + H + 20 + cut, n - H - 20 - cut);
    size_t pl = n - H - cut;
    out[4] = 1;
    out[24] = (uint8_t)pl;
    out[25] = (uint8_t)(pl >> 8);
    out[26] = (uint8_t)(pl >> 16);
    out[27] = (uint8_t)(pl >> 24);
    uLong c = crc32(0L, Z_NULL, 0);
    c = crc32(c, out, 28);
    c = crc32(c, out + H, (uInt)pl);
    for (int k = 0; k < 4; k++)
        out[28 + k] = (uint8_t)(c >> (8 * k));
    *out_n = n - cut;
}

static void test_version1_decoded(void **state)
{
    (void)state;
    scene *s = walk();
    struct splat_frame f = { 0 };
    make_key(s, 1, 0.0, &f); /* no motion: a static take */
    struct rig r;
    rig_open(&r, CODEC_Q_MEDIUM);
    assert_int_equal(codec_enc_set_version(r.e, 2), 0); /* the planes version 1 had */
    assert_int_equal(codec_enc_set_version(r.e, 1), F4D_EINVAL);
    codec_dec *d1;
    assert_int_equal(codec_dec_new(CAP, &d1, NULL), 0);
    uint8_t *v1 = malloc(r.cap);
    for (int k = 0; k < 2; k++) {
        size_t n, n1;
        assert_int_equal(codec_enc_key(r.e, &f, 0, CODEC_KEY_AUTO, NULL, r.buf, r.cap, &n), 0);
        assert_int_equal(codec_enc_last(r.e)->intra, k == 0);
        v1_packet(r.buf, n, v1, &n1);
        struct codec_packet p;
        struct f4d_err err = { 0 };
        assert_int_equal(codec_packet_parse(v1, n1, &p, &err), 0);
        assert_int_equal(p.version, 1);
        assert_int_equal(codec_dec_packet(d1, &p), 1);
        same_frame(codec_enc_recon(r.e), codec_dec_frame(d1));
    }
    /* a version beyond this build's is refused with its number */
    r.buf[4] = CODEC_VERSION + 1;
    struct codec_packet p;
    struct f4d_err err = { 0 };
    assert_int_equal(codec_packet_parse(r.buf, 64, &p, &err), F4D_EFORMAT);
    assert_non_null(strstr(err.msg, "version"));
    free(v1);
    codec_dec_free(d1);
    rig_close(&r);
    splat_frame_free(&f);
    scene_free(s);
}

/* An SPZ v3 (gzip) header claiming 60M points in a 100-byte file is refused
 * before the reader allocates for them (fuzz_frame found the 1.5 GB malloc). */
static void test_spz_gzip_claim_refused(void **state)
{
    (void)state;
    uint8_t hdr[16] = { 0x4e, 0x47, 0x53, 0x50, 3, 0, 0, 0 };
    uint32_t n = 60000000u;
    memcpy(hdr + 8, &n, 4);
    hdr[12] = 3; /* shDegree */
    hdr[13] = 12;
    uint8_t gz[256];
    z_stream zs;
    memset(&zs, 0, sizeof zs);
    assert_int_equal(deflateInit2(&zs, 9, Z_DEFLATED, 31, 8, Z_DEFAULT_STRATEGY), Z_OK);
    zs.next_in = hdr;
    zs.avail_in = sizeof hdr;
    zs.next_out = gz;
    zs.avail_out = sizeof gz;
    assert_int_equal(deflate(&zs, Z_FINISH), Z_STREAM_END);
    size_t len = sizeof gz - zs.avail_out;
    deflateEnd(&zs);
    struct splat_frame f = { 0 };
    struct f4d_err err = { 0 };
    g_allocs = 0;
    g_count_allocs = 1;
    assert_int_equal(codec_spz_decode(gz, len, &f, &err), F4D_EFORMAT);
    g_count_allocs = 0;
    assert_int_equal(g_allocs, 0);
    assert_non_null(strstr(err.msg, "cannot hold"));
    splat_frame_free(&f);
}

/* Rewrites a packet's CRC after its bytes were changed on purpose. */
static void recrc(uint8_t *pkt, size_t n)
{
    uLong c = crc32(0L, Z_NULL, 0);
    c = crc32(c, pkt, 28);
    c = crc32(c, pkt + CODEC_PACKET_HEADER, (uInt)(n - CODEC_PACKET_HEADER));
    for (int k = 0; k < 4; k++)
        pkt[28 + k] = (uint8_t)(c >> (8 * k));
}

/* Version 3's coding tools on keyed motion (the walk, motions over the key
 * interval): block motion is sent and used, the decoder reproduces the
 * encoder's reconstruction bit for bit (packed planes and the median
 * transform are lossless), every value stays within the level's bounds,
 * no allocation per key, and the predicted keys cost less than version 2's
 * of the same frames. */
static void test_block_motion(void **state)
{
    (void)state;
    scene *s = walk();
    struct splat_frame f[6] = { { 0 } };
    for (int k = 0; k < 6; k++)
        make_key(s, k, 0.1, &f[k]);
    static const enum codec_quality lv[2] = { CODEC_Q_COMPACT, CODEC_Q_MEDIUM };
    for (int li = 0; li < 2; li++) {
        size_t bytes[2] = { 0, 0 };
        for (int ver = 2; ver <= 3; ver++) {
            struct rig r;
            rig_open(&r, lv[li]);
            assert_int_equal(codec_enc_set_version(r.e, ver), 0);
            g_allocs = 0;
            for (int k = 0; k < 6; k++) {
                g_count_allocs = k > 0;
                size_t n = pass(&r, &f[k], CODEC_KEY_AUTO, NULL);
                g_count_allocs = 0;
                const struct codec_enc_stats *st = codec_enc_last(r.e);
                assert_int_equal(r.buf[4], ver);
                check_bounds_k(&f[k], codec_dec_frame(r.d), lv[li], k > 0);
                if (k == 0)
                    continue;
                bytes[ver - 2] += n;
                uint8_t fl = r.buf[CODEC_PACKET_HEADER + 2];
                if (ver == 3) {
                    /* sent where it pays (the encoder measures): on this
                     * sparse take at the compact level; either way the
                     * flag and the bytes agree */
                    if (lv[li] == CODEC_Q_COMPACT)
                        assert_true(st->bytes_blocks > 0);
                    assert_int_equal(!!(fl & 4), st->bytes_blocks > 0);
                } else {
                    assert_int_equal(st->bytes_blocks, 0);
                    assert_int_equal(fl & ~3, 0);
                }
            }
            assert_int_equal(g_allocs, 0);
            rig_close(&r);
        }
        fprintf(stderr, "%s: predicted keys version 2 %zu bytes, version 3 %zu\n",
                codec_quality_get(lv[li])->name, bytes[0], bytes[1]);
        assert_true(bytes[1] < bytes[0]);
    }
    for (int k = 0; k < 6; k++)
        splat_frame_free(&f[k]);
    scene_free(s);
}

/* g = f in the encoder's stream order (codec_enc_order), as a frame. */
static void in_order(const struct splat_frame *f, const uint32_t *ord, struct splat_frame *g)
{
    assert_int_equal(splat_frame_resize(g, f->count, f->motion_fwd != NULL, NULL), 0);
    for (size_t j = 0; j < f->count; j++) {
        size_t i = ord ? ord[j] : j;
        assert_true(i < f->count);
        memcpy(g->pos + 3 * j, f->pos + 3 * i, 12);
        memcpy(g->scale + 3 * j, f->scale + 3 * i, 12);
        memcpy(g->rot + 4 * j, f->rot + 4 * i, 16);
        memcpy(g->rgb + 3 * j, f->rgb + 3 * i, 12);
        g->opacity[j] = f->opacity[i];
        if (f->motion_fwd) {
            memcpy(g->motion_bwd + 3 * j, f->motion_bwd + 3 * i, 12);
            memcpy(g->motion_fwd + 3 * j, f->motion_fwd + 3 * i, 12);
        }
    }
}

/* Stream order (codec_enc_set_reorder): the intra key in Morton order is
 * smaller than in input order; every key decodes within the level's bounds
 * of the input read through codec_enc_order (a permutation), predicted keys
 * with the identity match, with dropped and new Gaussians through a match
 * in input indices, and a shrinking count; no allocation per key. */
static void test_stream_order(void **state)
{
    (void)state;
    scene *s = walk();
    struct splat_frame f[4] = { { 0 } }, g = { 0 }, c = { 0 };
    for (int k = 0; k < 4; k++)
        make_key(s, k, 0.1, &f[k]);
    struct rig r0, r;
    rig_open(&r0, CODEC_Q_COMPACT);
    size_t plain = pass(&r0, &f[0], CODEC_KEY_AUTO, NULL);
    assert_null(codec_enc_order(r0.e));
    rig_close(&r0);
    rig_open(&r, CODEC_Q_COMPACT);
    assert_int_equal(codec_enc_set_reorder(r.e, 1), 0);
    uint8_t *seen = calloc(CAP, 1);
    for (int k = 0; k < 3; k++) {
        g_allocs = 0;
        g_count_allocs = 1;
        size_t n = pass(&r, &f[k], CODEC_KEY_AUTO, NULL);
        g_count_allocs = 0;
        assert_int_equal(g_allocs, 0);
        const uint32_t *ord = codec_enc_order(r.e);
        assert_non_null(ord);
        memset(seen, 0, CAP);
        for (size_t j = 0; j < f[k].count; j++) {
            assert_true(ord[j] < f[k].count && !seen[ord[j]]);
            seen[ord[j]] = 1;
        }
        in_order(&f[k], ord, &g);
        check_bounds_k(&g, codec_dec_frame(r.d), CODEC_Q_COMPACT, k > 0);
        if (k == 0) {
            fprintf(stderr, "intra key, sparse take: input order %zu bytes, stream order %zu\n", plain, n);
            assert_true(n <= plain); /* the encoder keeps the input order where Morton's is larger */
        } else {
            assert_false(codec_enc_last(r.e)->intra);
            assert_int_equal(codec_enc_last(r.e)->bytes_match, 0); /* the identity, in stream order */
        }
    }
    /* the same key shuffled (a producer whose numbering says nothing of
     * space): Morton order is kept, and smaller */
    {
        uint32_t *perm = malloc(f[0].count * sizeof *perm);
        uint64_t x = 12345;
        for (size_t i = 0; i < f[0].count; i++)
            perm[i] = (uint32_t)i;
        for (size_t i = f[0].count - 1; i > 0; i--) {
            x = x * 6364136223846793005ull + 1442695040888963407ull;
            size_t j = (size_t)(x >> 33) % (i + 1);
            uint32_t t = perm[i];
            perm[i] = perm[j];
            perm[j] = t;
        }
        struct splat_frame sh = { 0 };
        in_order(&f[0], perm, &sh);
        size_t nd[2];
        for (int on = 0; on < 2; on++) {
            rig_open(&r0, CODEC_Q_COMPACT);
            assert_int_equal(codec_enc_set_reorder(r0.e, on), 0);
            nd[on] = pass(&r0, &sh, CODEC_KEY_AUTO, NULL);
            assert_int_equal(!!codec_enc_order(r0.e), on);
            in_order(&sh, codec_enc_order(r0.e), &g);
            check_bounds(&g, codec_dec_frame(r0.d), CODEC_Q_COMPACT);
            rig_close(&r0);
        }
        fprintf(stderr, "intra key, shuffled: input order %zu bytes, stream order %zu\n", nd[0], nd[1]);
        assert_true(nd[1] < nd[0]);
        free(perm);
        splat_frame_free(&sh);
    }
    /* key 3 with every 5th Gaussian dropped, reversed, and 30 new ones */
    size_t n = 0, extra = 30;
    int32_t *match = malloc((f[3].count + extra) * sizeof *match);
    assert_int_equal(splat_frame_resize(&c, f[3].count + extra, 1, NULL), 0);
    for (size_t q = f[3].count; q-- > 0;) {
        if (q % 5 == 1)
            continue;
        memcpy(c.pos + 3 * n, f[3].pos + 3 * q, 12);
        memcpy(c.scale + 3 * n, f[3].scale + 3 * q, 12);
        memcpy(c.rot + 4 * n, f[3].rot + 4 * q, 16);
        memcpy(c.rgb + 3 * n, f[3].rgb + 3 * q, 12);
        memcpy(c.motion_bwd + 3 * n, f[3].motion_bwd + 3 * q, 12);
        memcpy(c.motion_fwd + 3 * n, f[3].motion_fwd + 3 * q, 12);
        c.opacity[n] = f[3].opacity[q];
        match[n++] = (int32_t)q;
    }
    for (size_t k = 0; k < extra; k++, n++) {
        c.pos[3 * n] = 0.02f * (float)k;
        c.pos[3 * n + 1] = 0.4f;
        c.pos[3 * n + 2] = 1.1f;
        c.scale[3 * n] = c.scale[3 * n + 1] = c.scale[3 * n + 2] = 0.01f;
        c.rot[4 * n] = 1.0f;
        c.opacity[n] = 0.5f;
        match[n] = -1;
    }
    c.count = n;
    pass(&r, &c, CODEC_KEY_AUTO, match);
    assert_int_equal(codec_enc_last(r.e)->fresh, extra);
    assert_int_equal(codec_enc_last(r.e)->dropped, (f[3].count + 3) / 5);
    in_order(&c, codec_enc_order(r.e), &g);
    check_bounds_k(&g, codec_dec_frame(r.d), CODEC_Q_COMPACT, 1);
    /* the identity again (input index i continues input index i of c), shrinking */
    c.count = n - extra - 40;
    pass(&r, &c, CODEC_KEY_AUTO, NULL);
    assert_int_equal(codec_enc_last(r.e)->fresh, 0);
    in_order(&c, codec_enc_order(r.e), &g);
    check_bounds_k(&g, codec_dec_frame(r.d), CODEC_Q_COMPACT, 1);
    /* switching it off: the next key is intra, in input order */
    assert_int_equal(codec_enc_set_reorder(r.e, 0), 0);
    pass(&r, &f[0], CODEC_KEY_AUTO, NULL);
    assert_true(codec_enc_last(r.e)->intra);
    assert_null(codec_enc_order(r.e));
    check_bounds(&f[0], codec_dec_frame(r.d), CODEC_Q_COMPACT);
    free(match);
    free(seen);
    rig_close(&r);
    for (int k = 0; k < 4; k++)
        splat_frame_free(&f[k]);
    splat_frame_free(&g);
    splat_frame_free(&c);
    scene_free(s);
}

/* Effort: MAX writes the same choices as DEFAULT (decoded keys bit-identical)
 * at a higher zstd level, so no more bytes; FAST stays within the bounds;
 * out-of-range efforts are refused; no allocation per key at any effort. */
static void test_effort(void **state)
{
    (void)state;
    scene *s = walk();
    struct splat_frame f[4] = { { 0 } };
    for (int k = 0; k < 4; k++)
        make_key(s, k, 0.1, &f[k]);
    static const int eff[3] = { CODEC_EFFORT_DEFAULT, CODEC_EFFORT_MAX, CODEC_EFFORT_FAST };
    struct rig r[3];
    size_t bytes[3] = { 0, 0, 0 };
    for (int x = 0; x < 3; x++) {
        rig_open(&r[x], CODEC_Q_COMPACT);
        assert_int_equal(codec_enc_set_effort(r[x].e, eff[x]), 0);
    }
    assert_int_equal(codec_enc_set_effort(r[0].e, 3), F4D_EINVAL);
    assert_int_equal(codec_enc_set_effort(r[0].e, -1), F4D_EINVAL);
    for (int k = 0; k < 4; k++)
        for (int x = 0; x < 3; x++) {
            g_allocs = 0;
            g_count_allocs = 1;
            bytes[x] += pass(&r[x], &f[k], CODEC_KEY_AUTO, NULL);
            g_count_allocs = 0;
            assert_int_equal(g_allocs, 0);
            check_bounds_k(&f[k], codec_dec_frame(r[x].d), CODEC_Q_COMPACT, k > 0);
            if (x == 1)
                same_frame(codec_dec_frame(r[0].d), codec_dec_frame(r[1].d));
        }
    fprintf(stderr, "4 keys: default %zu bytes, max %zu, fast %zu\n", bytes[0], bytes[1], bytes[2]);
    assert_true(bytes[1] < bytes[0]);
    for (int x = 0; x < 3; x++)
        rig_close(&r[x]);
    for (int k = 0; k < 4; k++)
        splat_frame_free(&f[k]);
    scene_free(s);
}

/* The frame flags of version 3 are refused where they cannot apply: block
 * motion in a version-2 packet, block mf without the block parameters,
 * block motion on an intra key; a payload whose block planes are cut short
 * is refused, and the decoder then waits for the next intra key. */
static void test_block_flags_refused(void **state)
{
    (void)state;
    scene *s = walk();
    struct splat_frame f0 = { 0 }, f1 = { 0 };
    make_key(s, 0, 0.1, &f0);
    make_key(s, 1, 0.1, &f1);
    struct rig r;
    rig_open(&r, CODEC_Q_COMPACT);
    size_t n0, n1;
    uint8_t *k0 = malloc(r.cap), *k1 = malloc(r.cap);
    assert_int_equal(codec_enc_key(r.e, &f0, 0, CODEC_KEY_AUTO, NULL, k0, r.cap, &n0), 0);
    assert_int_equal(codec_enc_key(r.e, &f1, 1, CODEC_KEY_AUTO, NULL, k1, r.cap, &n1), 0);
    const size_t FL = CODEC_PACKET_HEADER + 2;
    assert_true(k1[FL] & 4);
    struct { int version; uint8_t flags; int cut; } bad[4] = {
        { 2, 0, 0 },      /* block motion in a version-2 packet            */
        { 3, 0x08, 0 },   /* block mf without block parameters (bit 2 off) */
        { 3, 0xff, 0 },   /* unknown flag bits                             */
        { 3, 0, 1 },      /* the payload cut inside the block planes        */
    };
    for (int b = 0; b < 4; b++) {
        uint8_t *pk = malloc(n1);
        memcpy(pk, k1, n1);
        size_t n = n1;
        pk[4] = (uint8_t)bad[b].version;
        if (bad[b].flags == 0x08)
            pk[FL] = (uint8_t)((pk[FL] & ~4) | 8);
        else if (bad[b].flags)
            pk[FL] = bad[b].flags;
        if (bad[b].cut) {
            /* header, quantizers, flags plane, then a few block bytes */
            size_t pl = 20 + 28 + 16 * 8 + 5 + codec__test_u32(pk + CODEC_PACKET_HEADER + 20 + 28 + 16 * 8 + 1) + 3;
            n = CODEC_PACKET_HEADER + pl;
            pk[24] = (uint8_t)pl; pk[25] = (uint8_t)(pl >> 8); pk[26] = (uint8_t)(pl >> 16); pk[27] = 0;
        }
        recrc(pk, n);
        struct codec_packet p;
        codec_dec *d;
        assert_int_equal(codec_dec_new(CAP, &d, NULL), 0);
        assert_int_equal(codec_packet_parse(k0, n0, &p, NULL), 0);
        assert_int_equal(codec_dec_packet(d, &p), 1);
        assert_int_equal(codec_packet_parse(pk, n, &p, NULL), 0);
        assert_int_equal(codec_dec_packet(d, &p), F4D_EFORMAT);
        assert_int_equal(codec_dec_stats(d)->refused, 1);
        assert_null(codec_dec_frame(d));
        codec_dec_free(d);
        free(pk);
    }
    /* an intra key claiming block motion */
    uint8_t *pk = malloc(n0);
    memcpy(pk, k0, n0);
    pk[FL] |= 4;
    recrc(pk, n0);
    struct codec_packet p;
    codec_dec *d;
    assert_int_equal(codec_dec_new(CAP, &d, NULL), 0);
    assert_int_equal(codec_packet_parse(pk, n0, &p, NULL), 0);
    assert_int_equal(codec_dec_packet(d, &p), F4D_EFORMAT);
    codec_dec_free(d);
    free(pk);
    free(k0);
    free(k1);
    rig_close(&r);
    splat_frame_free(&f0);
    splat_frame_free(&f1);
    scene_free(s);
}

/* FNV-1a 64 of n bytes, continuing h. */
static uint64_t fnv64(uint64_t h, const void *p, size_t n)
{
    const uint8_t *b = p;
    for (size_t i = 0; i < n; i++) {
        h ^= b[i];
        h *= 1099511628211ull;
    }
    return h;
}

static uint64_t frame_digest(uint64_t h, const struct splat_frame *f)
{
    size_t n = f->count;
    h = fnv64(h, &n, sizeof n);
    h = fnv64(h, f->pos, 3 * n * sizeof(float));
    h = fnv64(h, f->scale, 3 * n * sizeof(float));
    h = fnv64(h, f->rot, 4 * n * sizeof(float));
    h = fnv64(h, f->opacity, n * sizeof(float));
    h = fnv64(h, f->rgb, 3 * n * sizeof(float));
    if (f->motion_fwd) {
        h = fnv64(h, f->motion_fwd, 3 * n * sizeof(float));
        h = fnv64(h, f->motion_bwd, 3 * n * sizeof(float));
    }
    return h;
}

/* c = b with every 5th Gaussian dropped and `extra` new ones appended;
 * match names b's indices. */
static void drop_and_add(const struct splat_frame *b, size_t extra, struct splat_frame *c, int32_t *match)
{
    size_t n = 0;
    assert_int_equal(splat_frame_resize(c, b->count + extra, 1, NULL), 0);
    for (size_t i = 0; i < b->count; i++) {
        if (i % 5 == 2)
            continue;
        memcpy(c->pos + 3 * n, b->pos + 3 * i, 12);
        memcpy(c->scale + 3 * n, b->scale + 3 * i, 12);
        memcpy(c->rot + 4 * n, b->rot + 4 * i, 16);
        memcpy(c->rgb + 3 * n, b->rgb + 3 * i, 12);
        memcpy(c->motion_bwd + 3 * n, b->motion_bwd + 3 * i, 12);
        memcpy(c->motion_fwd + 3 * n, b->motion_fwd + 3 * i, 12);
        c->opacity[n] = b->opacity[i];
        match[n++] = (int32_t)i;
    }
    for (size_t k = 0; k < extra; k++, n++) {
        const float *q = b->pos + 3 * (k * 37 % b->count);
        for (int a = 0; a < 3; a++) {
            c->pos[3 * n + a] = q[a] + 0.003f * (float)(a + 1);
            c->scale[3 * n + a] = 0.004f + 0.001f * (float)a;
            c->rgb[3 * n + a] = 0.25f * (float)(a + 1);
            c->motion_fwd[3 * n + a] = 0.01f;
            c->motion_bwd[3 * n + a] = -0.01f;
        }
        c->rot[4 * n] = 1.0f;
        c->rot[4 * n + 1] = c->rot[4 * n + 2] = c->rot[4 * n + 3] = 0.0f;
        c->opacity[n] = 0.6f;
        match[n] = -1;
    }
    c->count = n;
}

/* Decoded keys are bit-identical to those of the decoder before its tiled
 * rewrite (2026-12-02): digests of the packets (the encoder's output) and
 * of every decoded key of the walk take, version 3 at the compact level
 * (block motion and rotations) and medium, version 2, with dropped and new
 * Gaussians through a match and a shrinking then growing count. pass()
 * also checks each key against the encoder's reconstruction. The golden
 * values were printed by main's decoder (e2f9362) on x86-64 glibc; a
 * change of the scene, the encoder or libm changes the packet digest too:
 * the message prints both. */
static void test_decoded_digest(void **state)
{
    (void)state;
    scene *s = walk();
    struct splat_frame f[6] = { { 0 } }, c = { 0 };
    for (int k = 0; k < 6; k++)
        make_key(s, k, 0.1, &f[k]);
    int32_t *match = malloc((f[0].count + 300) * sizeof *match);
    assert_non_null(match);
    static const struct { enum codec_quality q; int ver; } run[3] = {
        { CODEC_Q_COMPACT, 3 }, { CODEC_Q_MEDIUM, 3 }, { CODEC_Q_MEDIUM, 2 } };
    uint64_t hp = 1469598103934665603ull, hd = hp;
    for (int ri = 0; ri < 3; ri++) {
        struct rig r;
        rig_open(&r, run[ri].q);
        assert_int_equal(codec_enc_set_version(r.e, run[ri].ver), 0);
        for (int k = 0; k < 9; k++) {
            const struct splat_frame *in = &f[k < 6 ? k : 5];
            const int32_t *m = NULL;
            if (k == 4) {
                drop_and_add(&f[3], 300, &c, match);
                in = &c;
                m = match;
            } else if (k == 6) { /* identity, 200 fewer; keys 7 and 8 grow back */
                assert_int_equal(splat_frame_copy(&c, &f[5], NULL), 0);
                c.count -= 200;
                in = &c;
            }
            size_t n = pass(&r, in, CODEC_KEY_AUTO, m);
            hp = fnv64(hp, r.buf, n);
            hd = frame_digest(hd, codec_dec_frame(r.d));
        }
        rig_close(&r);
    }
    fprintf(stderr, "packets %016llx decoded %016llx\n", (unsigned long long)hp, (unsigned long long)hd);
    assert_true(hp == 0x943e7235b1f732baull);
    assert_true(hd == 0xe8fa682a5e6f7447ull);
    free(match);
    splat_frame_free(&c);
    for (int k = 0; k < 6; k++)
        splat_frame_free(&f[k]);
    scene_free(s);
}

int main(int argc, char **argv)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_intra_round_trip_per_level),
        cmocka_unit_test(test_predicted_keys),
        cmocka_unit_test(test_predicted_dropped_and_new),
        cmocka_unit_test(test_join_mid_stream),
        cmocka_unit_test(test_lost_packet),
        cmocka_unit_test(test_corrupt_and_truncated),
        cmocka_unit_test(test_non_finite_refused),
        cmocka_unit_test(test_empty_frames),
        cmocka_unit_test(test_huge_counts_refused),
        cmocka_unit_test(test_no_allocation_per_frame),
        cmocka_unit_test(test_block_motion),
        cmocka_unit_test(test_block_flags_refused),
        cmocka_unit_test(test_stream_order),
        cmocka_unit_test(test_effort),
        cmocka_unit_test(test_spz_gzip_claim_refused),
        cmocka_unit_test(test_spz_round_trip),
        cmocka_unit_test(test_predictor_fit),
        cmocka_unit_test(test_version1_decoded),
        cmocka_unit_test(test_decoded_digest),
    };
    return F4D_TEST_MAIN(argc, argv, "stream", tests, NULL, NULL);
}
