/* test_transport.c - firmware/stream/transport over loopback: URLs, a
 * passphrase-protected stream whose decoded keys equal the file's, wrong and
 * missing passphrases, an unreachable peer, file: URLs with a corrupt packet,
 * 5 % loss with a large latency window (SRT's ARQ recovers everything), and a
 * link outage longer than the window (the receiver drops what it cannot
 * complete, the decoder resynchronises at the next intra key). No allocation
 * per packet in our code (malloc wrapped at link time). */
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>
#include <zlib.h>

#include "f4d_test.h"
#include "f4d_codec.h"
#include "f4d_transport.h"
#include "loss_proxy.h"
#include "scene.h"

/* ---- allocation counter (malloc wrapped at link time) ---- */
void *__real_malloc(size_t n);
void *__real_calloc(size_t a, size_t b);
void *__real_realloc(void *p, size_t n);
/* per thread: the sender thread's open must not count as the receiver's */
static _Thread_local int g_count_allocs;
static _Thread_local long g_allocs;
void *__wrap_malloc(size_t n);
void *__wrap_calloc(size_t a, size_t b);
void *__wrap_realloc(void *p, size_t n);
void *__wrap_malloc(size_t n) { if (g_count_allocs) g_allocs++; return __real_malloc(n); }
void *__wrap_calloc(size_t a, size_t b) { if (g_count_allocs) g_allocs++; return __real_calloc(a, b); }
void *__wrap_realloc(void *p, size_t n) { if (g_count_allocs) g_allocs++; return __real_realloc(p, n); }

#define N_G   3000
#define CAP   4096
#define KEYS  40
#define KEY_US 50000 /* 20 Hz keys: the paced stream lasts 2 s */
#define PASS  "forge4d-test-passphrase"

/* The stream under test: header, KEYS keys (intra every 10), end; and the
 * CRC of every decoded key (by packet seq) from a straight decode. */
struct stream {
    uint8_t *bytes;
    size_t   len, off[KEYS + 3], n, max_packet;
    uint32_t key_crc[KEYS + 3];
    int      is_key[KEYS + 3];
};

static uint32_t frame_crc(const struct splat_frame *f)
{
    uLong c = crc32(0L, Z_NULL, 0);
    c = crc32(c, (const Bytef *)&f->count, sizeof f->count);
    c = crc32(c, (const Bytef *)f->pos, (uInt)(3 * f->count * sizeof(float)));
    c = crc32(c, (const Bytef *)f->scale, (uInt)(3 * f->count * sizeof(float)));
    c = crc32(c, (const Bytef *)f->rot, (uInt)(4 * f->count * sizeof(float)));
    c = crc32(c, (const Bytef *)f->opacity, (uInt)(f->count * sizeof(float)));
    c = crc32(c, (const Bytef *)f->rgb, (uInt)(3 * f->count * sizeof(float)));
    if (f->motion_fwd)
        c = crc32(c, (const Bytef *)f->motion_fwd, (uInt)(3 * f->count * sizeof(float)));
    return (uint32_t)c;
}

static struct stream *g_stream; /* built once (test fixture), read-only after */

static int make_stream(void **state)
{
    (void)state;
    struct stream *st = calloc(1, sizeof *st);
    scene *s;
    codec_enc *e;
    codec_dec *d;
    if (!st || scene_new(SCENE_WALK, 3, N_G, &s, NULL) < 0 || codec_enc_new(CAP, CODEC_Q_MEDIUM, &e, NULL) < 0 ||
        codec_dec_new(CAP, &d, NULL) < 0)
        return -1;
    size_t cap = codec_packet_bound(CAP), l;
    st->bytes = malloc((KEYS + 2) * cap / 4);
    struct splat_frame f = { 0 };
    codec_enc_stream_header(e, 0, st->bytes, cap, &l);
    st->off[st->n++] = 0;
    st->len = l;
    for (int k = 0; k < KEYS; k++) {
        if (scene_eval(s, k * 0.05, 0.05, &f, NULL) < 0)
            return -1;
        st->off[st->n++] = st->len;
        if (codec_enc_key(e, &f, (uint64_t)k * KEY_US, k % 10 == 0 ? CODEC_KEY_INTRA : CODEC_KEY_AUTO, NULL,
                          st->bytes + st->len, cap, &l) < 0)
            return -1;
        st->len += l;
    }
    st->off[st->n++] = st->len;
    codec_enc_end(e, (uint64_t)KEYS * KEY_US, st->bytes + st->len, cap, &l);
    st->len += l;
    st->off[st->n] = st->len;
    for (size_t i = 0; i < st->n; i++) {
        struct codec_packet p;
        size_t sz = st->off[i + 1] - st->off[i];
        st->max_packet = sz > st->max_packet ? sz : st->max_packet;
        if (codec_packet_parse(st->bytes + st->off[i], sz, &p, NULL) < 0 || p.seq != i)
            return -1;
        if (codec_dec_packet(d, &p) == 1) {
            st->is_key[i] = 1;
            st->key_crc[i] = frame_crc(codec_dec_frame(d));
        }
    }
    splat_frame_free(&f);
    codec_enc_free(e);
    codec_dec_free(d);
    scene_free(s);
    g_stream = st;
    return 0;
}

static int free_stream(void **state)
{
    (void)state;
    if (g_stream)
        free(g_stream->bytes);
    free(g_stream);
    return 0;
}

/* Ports: 8 free ones from this test's own range (20000..23999, see
 * tests/common/f4d_ports.sh), so that no test ctest runs beside it and no
 * second run of it takes the same ones. */
static int port(int k)
{
    static int base;
    if (!base)
        base = f4d_test_udp_ports(20000, 4000, 8);
    assert_true(base > 0);
    return base + k;
}

/* A receiver's wait for the next packet: a hang bound, not a speed limit
 * (a loaded machine may stall a paced stream for seconds). */
#define RX_IDLE_MS 30000

/* ---- sender thread ---- */
struct sender {
    char url[256];
    int  pace;
    int  rc, open_rc;
    long allocs;
    char msg[F4D_ERR_MAX];
    struct transport_stats st;
};

static void sleep_until(const struct timespec *t0, uint64_t us)
{
    struct timespec t = *t0;
    t.tv_sec += (time_t)(us / 1000000);
    t.tv_nsec += (long)(us % 1000000) * 1000;
    if (t.tv_nsec >= 1000000000) {
        t.tv_sec++;
        t.tv_nsec -= 1000000000;
    }
    clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &t, NULL);
}

static void *send_thread(void *arg)
{
    struct sender *s = arg;
    const struct stream *st = g_stream;
    struct f4d_err err = { 0 };
    struct transport_opts o = { .max_packet = st->max_packet };
    transport_tx *tx;
    s->open_rc = s->rc = transport_tx_open(s->url, &o, &tx, &err);
    if (s->rc < 0) {
        snprintf(s->msg, sizeof s->msg, "%s", err.msg);
        return NULL;
    }
    struct timespec t0;
    clock_gettime(CLOCK_MONOTONIC, &t0);
    g_count_allocs = 1;
    for (size_t i = 0; i < st->n && s->rc == 0; i++) {
        struct codec_packet p;
        codec_packet_parse(st->bytes + st->off[i], st->off[i + 1] - st->off[i], &p, NULL);
        if (s->pace)
            sleep_until(&t0, p.t_us);
        long before = g_allocs;
        s->rc = transport_tx_send(tx, st->bytes + st->off[i], p.size);
        s->allocs += g_allocs - before;
    }
    g_count_allocs = 0;
    if (s->rc < 0)
        snprintf(s->msg, sizeof s->msg, "%s", transport_tx_error(tx));
    else if ((s->rc = transport_tx_drain(tx, 20000)) < 0)
        snprintf(s->msg, sizeof s->msg, "%s", transport_tx_error(tx));
    transport_tx_stats(tx, &s->st);
    transport_tx_close(tx, 0);
    return NULL;
}

/* ---- receiver loop: decodes, checks every key against the straight decode ---- */
struct received {
    int      keys, mismatched, packets, last_key_seq, ended;
    long     allocs;
    struct codec_dec_stats dec;
    struct transport_stats st;
};

static void receive_all(transport_rx *rx, struct received *r)
{
    codec_dec *d;
    assert_int_equal(codec_dec_new(CAP, &d, NULL), 0);
    memset(r, 0, sizeof *r);
    r->last_key_seq = -1;
    for (;;) {
        struct codec_packet p;
        g_count_allocs = 1;
        long before = g_allocs;
        int rc = transport_rx_next(rx, RX_IDLE_MS, &p);
        int got = rc == 0 ? codec_dec_packet(d, &p) : 0;
        r->allocs += g_allocs - before;
        g_count_allocs = 0;
        if (rc < 0) {
            fprintf(stderr, "receiver: %s\n", transport_rx_error(rx));
            break;
        }
        r->packets++;
        if (got == 1) {
            r->keys++;
            r->last_key_seq = (int)p.seq;
            if (p.seq >= g_stream->n || !g_stream->is_key[p.seq] ||
                frame_crc(codec_dec_frame(d)) != g_stream->key_crc[p.seq])
                r->mismatched++;
        }
        if (p.type == CODEC_PKT_END) {
            r->ended = 1;
            break;
        }
    }
    r->dec = *codec_dec_stats(d);
    transport_rx_stats(rx, &r->st);
    codec_dec_free(d);
}

static void test_url(void **state)
{
    (void)state;
    struct transport_url u;
    struct f4d_err err = { 0 };
    assert_int_equal(transport_url_parse("srt://127.0.0.1:9000?latency=250&passphrase=abc%20defghij&pbkeylen=32", &u,
                                         &err), 0);
    assert_int_equal(u.kind, TRANSPORT_SRT);
    assert_int_equal(u.mode, TRANSPORT_CALLER);
    assert_int_equal(u.port, 9000);
    assert_int_equal(u.latency_ms, 250);
    assert_string_equal(u.passphrase, "abc defghij");
    assert_int_equal(u.pbkeylen, 32);
    assert_int_equal(transport_url_parse("srt://:9000", &u, &err), 0);
    assert_int_equal(u.mode, TRANSPORT_LISTENER);
    assert_int_equal(transport_url_parse("srt://[::1]:9000?mode=caller&timeout=50&payload=1456&maxbw=1000000", &u,
                                         &err), 0);
    assert_string_equal(u.host, "::1");
    assert_int_equal(u.payload, 1456);
    assert_int_equal(u.rcvbuf, TRANSPORT_RCVBUF_DEF);
    assert_int_equal(transport_url_parse("srt://h:1?rcvbuf=8388608", &u, &err), 0);
    assert_int_equal(u.rcvbuf, 8388608);
    assert_int_equal(transport_url_parse("file:/tmp/x.f4ds", &u, &err), 0);
    assert_string_equal(u.path, "/tmp/x.f4ds");
    static const struct { const char *url, *says; } bad[] = {
        { "udp://1.2.3.4:5", "unknown scheme" },
        { "srt://host", "no port" },
        { "srt://host:0", "port '0'" },
        { "srt://host:99999", "port '99999'" },
        { "srt://:9000?mode=caller", "needs a HOST" },
        { "srt://h:9000?mode=rendezvous", "mode 'rendezvous'" },
        { "srt://h:9000?latency=-5", "latency '-5'" },
        { "srt://h:9000?passphrase=short", "10 to 79" },
        { "srt://h:9000?passphrase=abcdefghij%zz", "escape" },
        { "srt://h:9000?pbkeylen=20", "pbkeylen '20'" },
        { "srt://h:9000?payload=2000", "payload '2000'" },
        { "srt://h:9000?rcvbuf=1000", "rcvbuf '1000'" },
        { "srt://h:9000?colour=red", "unknown parameter 'colour'" },
        { "srt://h:9000?latency", "no =VALUE" },
        { "file:", "without a path" },
    };
    for (size_t i = 0; i < sizeof bad / sizeof bad[0]; i++) {
        err.msg[0] = 0;
        assert_int_equal(transport_url_parse(bad[i].url, &u, &err), F4D_EINVAL);
        if (!strstr(err.msg, bad[i].says)) {
            fprintf(stderr, "'%s': message '%s' lacks '%s'\n", bad[i].url, err.msg, bad[i].says);
            fail();
        }
    }
}

static void run_pair(const char *rx_url, const char *tx_url, int pace, const char *tee, struct received *r,
                     struct sender *s)
{
    struct f4d_err err = { 0 };
    struct transport_opts o = { .max_packet = g_stream->max_packet, .tee_path = tee };
    transport_rx *rx;
    assert_int_equal(transport_rx_open(rx_url, &o, &rx, &err), 0);
    memset(s, 0, sizeof *s);
    snprintf(s->url, sizeof s->url, "%s", tx_url);
    s->pace = pace;
    pthread_t th;
    assert_int_equal(pthread_create(&th, NULL, send_thread, s), 0);
    receive_all(rx, r);
    pthread_join(th, NULL);
    transport_rx_close(rx);
    if (s->rc < 0)
        fprintf(stderr, "sender: %s\n", s->msg);
}

static void test_loopback_passphrase(void **state)
{
    (void)state;
    char dir[256], tee[300], rx_url[128], tx_url[128];
    assert_int_equal(f4d_test_mkdtemp(dir, sizeof dir, "transport"), 0);
    snprintf(tee, sizeof tee, "%s/tee.f4ds", dir);
    snprintf(rx_url, sizeof rx_url, "srt://127.0.0.1:%d?mode=listener&passphrase=" PASS "&pbkeylen=32", port(0));
    snprintf(tx_url, sizeof tx_url, "srt://127.0.0.1:%d?passphrase=" PASS "&latency=200", port(0));
    struct received r;
    struct sender s;
    run_pair(rx_url, tx_url, 0, tee, &r, &s);
    assert_int_equal(s.rc, 0);
    assert_true(r.ended);
    assert_int_equal(r.packets, (int)g_stream->n);
    assert_int_equal(r.keys, KEYS);
    assert_int_equal(r.mismatched, 0);
    assert_int_equal(r.st.dropped_incomplete + r.st.dropped_corrupt + r.st.missing + r.st.chunks_bad, 0);
    assert_int_equal(r.st.bytes, g_stream->len);
    assert_true(r.st.srt_recv >= (int64_t)r.st.chunks);
    assert_int_equal(r.st.srt_undecrypt, 0);
    assert_true(r.st.latency_ms >= 200); /* the larger of the two ends wins */
    assert_int_equal(s.st.packets, g_stream->n);
    /* one packet can exceed the 1316-byte SRT payload: it went as chunks */
    assert_true(s.st.chunks > s.st.packets);
    /* no allocation in our code per packet, on either side */
    assert_int_equal(s.allocs, 0);
    assert_int_equal(r.allocs, 0);
    /* the tee holds exactly the stream */
    FILE *f = fopen(tee, "rb");
    assert_non_null(f);
    uint8_t *b = malloc(g_stream->len + 1);
    size_t n = fread(b, 1, g_stream->len + 1, f);
    fclose(f);
    assert_int_equal(n, g_stream->len);
    assert_memory_equal(b, g_stream->bytes, n);
    free(b);
    f4d_test_rmtree(dir);
}

static void test_wrong_passphrase(void **state)
{
    (void)state;
    char rx_url[128], tx_url[128];
    struct f4d_err err = { 0 };
    struct transport_opts o = { 0 };
    transport_rx *rx;
    snprintf(rx_url, sizeof rx_url, "srt://127.0.0.1:%d?mode=listener&passphrase=" PASS, port(1));
    assert_int_equal(transport_rx_open(rx_url, &o, &rx, &err), 0);
    transport_tx *tx = NULL;
    snprintf(tx_url, sizeof tx_url, "srt://127.0.0.1:%d?passphrase=not-the-passphrase", port(1));
    int rc = transport_tx_open(tx_url, &o, &tx, &err);
    assert_int_equal(rc, F4D_EINVAL);
    assert_null(tx);
    assert_non_null(strstr(err.msg, "wrong passphrase"));
    snprintf(tx_url, sizeof tx_url, "srt://127.0.0.1:%d", port(1));
    rc = transport_tx_open(tx_url, &o, &tx, &err);
    assert_int_equal(rc, F4D_EINVAL);
    assert_non_null(strstr(err.msg, "passphrase"));
    /* the listener saw no connection: it times out cleanly */
    struct codec_packet p;
    assert_int_equal(transport_rx_next(rx, 100, &p), F4D_ETIMEDOUT);
    struct transport_stats st;
    assert_int_equal(transport_rx_stats(rx, &st), 0);
    assert_int_equal(st.packets, 0);
    assert_int_equal(st.connected, 0);
    transport_rx_close(rx);
}

static void test_unreachable(void **state)
{
    (void)state;
    char url[128];
    struct f4d_err err = { 0 };
    transport_tx *tx = NULL;
    snprintf(url, sizeof url, "srt://127.0.0.1:%d?timeout=300", port(2));
    struct timespec a, b;
    clock_gettime(CLOCK_MONOTONIC, &a);
    assert_int_equal(transport_tx_open(url, NULL, &tx, &err), F4D_ETIMEDOUT);
    clock_gettime(CLOCK_MONOTONIC, &b);
    assert_non_null(strstr(err.msg, "no SRT peer answered within 300 ms"));
    assert_true(b.tv_sec - a.tv_sec < 5); /* bounded by the timeout, not SRT's default */
    /* a listening sender that nobody calls */
    snprintf(url, sizeof url, "srt://127.0.0.1:%d?mode=listener&timeout=200", port(2));
    assert_int_equal(transport_tx_open(url, NULL, &tx, &err), F4D_ETIMEDOUT);
    assert_non_null(strstr(err.msg, "no caller connected within 200 ms"));
    transport_rx *rx = NULL;
    assert_int_equal(transport_rx_open("file:/nonexistent/dir/x.f4ds", NULL, &rx, &err), F4D_EIO);
    assert_non_null(strstr(err.msg, "/nonexistent/dir/x.f4ds"));
}

static void test_file_urls(void **state)
{
    (void)state;
    char dir[256], path[300], url[320];
    assert_int_equal(f4d_test_mkdtemp(dir, sizeof dir, "transport"), 0);
    snprintf(path, sizeof path, "%s/s.f4ds", dir);
    snprintf(url, sizeof url, "file:%s", path);
    struct f4d_err err = { 0 };
    struct transport_opts o = { .max_packet = g_stream->max_packet };
    transport_tx *tx;
    assert_int_equal(transport_tx_open(url, &o, &tx, &err), 0);
    for (size_t i = 0; i < g_stream->n; i++)
        assert_int_equal(transport_tx_send(tx, g_stream->bytes + g_stream->off[i], g_stream->off[i + 1] - g_stream->off[i]), 0);
    /* a packet that is not one is refused, naming the problem */
    uint8_t junk[64] = { 1, 2, 3 };
    assert_int_equal(transport_tx_send(tx, junk, sizeof junk), F4D_EFORMAT);
    assert_non_null(strstr(transport_tx_error(tx), "magic"));
    transport_tx_close(tx, 1000);
    /* flip one payload byte of key 3: that packet is dropped, the rest read */
    FILE *f = fopen(path, "r+b");
    assert_non_null(f);
    fseek(f, (long)g_stream->off[4] + CODEC_PACKET_HEADER + 10, SEEK_SET);
    int c = fgetc(f);
    fseek(f, (long)g_stream->off[4] + CODEC_PACKET_HEADER + 10, SEEK_SET);
    fputc(c ^ 0x40, f);
    fclose(f);
    transport_rx *rx;
    assert_int_equal(transport_rx_open(url, &o, &rx, &err), 0);
    struct received r;
    receive_all(rx, &r);
    transport_rx_close(rx);
    assert_true(r.ended);
    assert_int_equal(r.packets, (int)g_stream->n - 1);
    assert_int_equal(r.st.dropped_corrupt, 1);
    assert_int_equal(r.mismatched, 0);
    /* key 3 lost: the predicted keys after it wait for the intra at key 10 */
    assert_int_equal(r.keys, KEYS - 7);
    assert_int_equal(r.dec.lost, 1);
    assert_int_equal(r.last_key_seq, KEYS);
    f4d_test_rmtree(dir);
}

static double mono_ms(void)
{
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return (double)t.tv_sec * 1e3 + (double)t.tv_nsec * 1e-6;
}

/* file: with pace: packets come at their timestamps, a short wait times out */
static void test_file_pace(void **state)
{
    (void)state;
    char dir[256], path[300], url[320];
    assert_int_equal(f4d_test_mkdtemp(dir, sizeof dir, "transport"), 0);
    snprintf(path, sizeof path, "%s/s.f4ds", dir);
    snprintf(url, sizeof url, "file:%s", path);
    FILE *f = fopen(path, "wb");
    assert_non_null(f);
    assert_int_equal(fwrite(g_stream->bytes, 1, g_stream->off[4], f), g_stream->off[4]); /* header, keys 0..2 */
    fclose(f);
    struct transport_opts o = { .max_packet = g_stream->max_packet, .pace = 1 };
    /* Key 1 is due 50 ms after the header: a 10 ms wait before then times out.
     * A run descheduled for 40 ms between two calls (a loaded machine) finds
     * it due within the wait and gets it, on time; it reads the file again:
     * the timeout has to be seen in one of 20 runs, and no run may get a
     * packet early. */
    bool timed_out = false;
    for (int run = 0; run < 20 && !timed_out; run++) {
        transport_rx *rx;
        assert_int_equal(transport_rx_open(url, &o, &rx, NULL), 0);
        struct codec_packet p;
        double t0 = mono_ms();
        assert_int_equal(transport_rx_next(rx, 0, &p), 0); /* header, t = 0 */
        assert_int_equal(transport_rx_next(rx, 0, &p), 0); /* key 0, t = 0 */
        int rc = transport_rx_next(rx, 10, &p);
        if (rc == F4D_ETIMEDOUT) {
            timed_out = true;
            assert_int_equal(transport_rx_next(rx, 500, &p), 0);
        } else {
            assert_int_equal(rc, 0);
        }
        assert_int_equal(p.seq, 2);
        assert_true(mono_ms() - t0 >= 45);
        assert_int_equal(transport_rx_next(rx, 500, &p), 0);
        assert_int_equal(p.seq, 3);
        assert_true(mono_ms() - t0 >= 95);
        assert_int_equal(transport_rx_next(rx, 500, &p), F4D_EEOF);
        transport_rx_close(rx);
    }
    assert_true(timed_out);
    f4d_test_rmtree(dir);
}

/* The roles reversed (a listening sender, a calling receiver: a display that
 * dials the camera), AES-192 and 1456-byte payloads; then a listening
 * receiver serves a second sender after the first one closed. */
static void test_roles_and_reconnect(void **state)
{
    (void)state;
    struct sender s;
    memset(&s, 0, sizeof s);
    snprintf(s.url, sizeof s.url, "srt://127.0.0.1:%d?mode=listener&timeout=30000&pbkeylen=24&payload=1456"
             "&passphrase=" PASS, port(7));
    pthread_t th;
    assert_int_equal(pthread_create(&th, NULL, send_thread, &s), 0);
    assert_true(f4d_test_wait_udp(port(7), 0, 60)); /* the sender listens */
    char url[200];
    snprintf(url, sizeof url, "srt://127.0.0.1:%d?timeout=30000&passphrase=" PASS, port(7));
    struct transport_opts o = { .max_packet = g_stream->max_packet };
    transport_rx *rx;
    struct f4d_err err = { 0 };
    assert_int_equal(transport_rx_open(url, &o, &rx, &err), 0);
    struct received r;
    receive_all(rx, &r);
    pthread_join(th, NULL);
    assert_int_equal(s.rc, 0);
    assert_int_equal(r.keys, KEYS);
    assert_int_equal(r.mismatched, 0);
    uint64_t chunks = 0; /* 1456-byte messages: 1440 bytes of packet each */
    for (size_t i = 0; i < g_stream->n; i++)
        chunks += (g_stream->off[i + 1] - g_stream->off[i] + 1439) / 1440;
    assert_int_equal(r.st.chunks, chunks);
    transport_rx_close(rx);

    /* a listening receiver: sender 1 goes away, sender 2 is served */
    snprintf(url, sizeof url, "srt://127.0.0.1:%d?mode=listener&passphrase=" PASS, port(7));
    assert_int_equal(transport_rx_open(url, &o, &rx, &err), 0);
    for (int k = 0; k < 2; k++) {
        memset(&s, 0, sizeof s);
        snprintf(s.url, sizeof s.url, "srt://127.0.0.1:%d?passphrase=" PASS, port(7));
        assert_int_equal(pthread_create(&th, NULL, send_thread, &s), 0);
        receive_all(rx, &r);
        pthread_join(th, NULL);
        assert_int_equal(s.rc, 0);
        assert_true(r.ended);
        assert_int_equal(r.keys, KEYS);
        assert_int_equal(r.mismatched, 0);
        /* the sender closes after its drain: the receiver sees the end */
        struct codec_packet p;
        int rc;
        do
            rc = transport_rx_next(rx, 3000, &p);
        while (rc == 0);
        assert_int_equal(rc, F4D_EEOF);
        assert_non_null(strstr(transport_rx_error(rx), "closed"));
    }
    transport_rx_close(rx);
}

/* A caller -> proxy -> listener run with the proxy in a thread. */
struct proxy_run {
    struct loss_proxy_cfg cfg;
    int fd;
    atomic_int stop;
    struct loss_proxy_stats st;
};

static void *proxy_thread(void *arg)
{
    struct proxy_run *p = arg;
    loss_proxy_run(&p->cfg, p->fd, &p->stop, &p->st);
    return NULL;
}

static void run_lossy(int k, double loss, int latency, int blackout_at, int blackout_ms, struct received *r,
                      struct sender *s, struct proxy_run *pr)
{
    memset(pr, 0, sizeof *pr);
    pr->cfg = (struct loss_proxy_cfg){ port(k + 1), port(k), loss, 12345, blackout_at, blackout_ms };
    assert_int_equal(loss_proxy_bind(&pr->cfg, &pr->fd), 0);
    pthread_t th;
    assert_int_equal(pthread_create(&th, NULL, proxy_thread, pr), 0);
    char rx_url[160], tx_url[160];
    snprintf(rx_url, sizeof rx_url, "srt://127.0.0.1:%d?mode=listener&latency=%d&passphrase=" PASS, port(k), latency);
    snprintf(tx_url, sizeof tx_url, "srt://127.0.0.1:%d?latency=%d&passphrase=" PASS, port(k + 1), latency);
    run_pair(rx_url, tx_url, 1, NULL, r, s);
    atomic_store(&pr->stop, 1);
    pthread_join(th, NULL);
    fprintf(stderr,
            "loss %.0f%% latency %d ms: proxy dropped %llu/%llu datagrams; srt retrans %lld, rcv loss %lld, rcv drop "
            "%lld; transport: %llu packets, %llu incomplete, %llu missing; decoder: %d keys, %llu lost, %llu skipped\n",
            loss * 100, latency, (unsigned long long)(pr->st.dropped_fwd + pr->st.dropped_back),
            (unsigned long long)(pr->st.fwd + pr->st.back + pr->st.dropped_fwd + pr->st.dropped_back),
            (long long)s->st.srt_retrans, (long long)r->st.srt_lost_rcv, (long long)r->st.srt_drop_rcv,
            (unsigned long long)r->st.packets, (unsigned long long)r->st.dropped_incomplete,
            (unsigned long long)r->st.missing, r->keys, (unsigned long long)r->dec.lost,
            (unsigned long long)r->dec.skipped);
}

static void test_loss_recovered(void **state)
{
    (void)state;
    struct received r;
    struct sender s;
    struct proxy_run pr;
    run_lossy(3, 0.05, 1000, -1, 0, &r, &s, &pr);
    assert_int_equal(s.rc, 0);
    assert_true(pr.st.dropped_fwd > 0 && pr.st.dropped_back > 0);
    assert_true(s.st.srt_retrans > 0);
    assert_true(r.st.srt_lost_rcv > 0);
    /* a window much larger than the RTT: ARQ repairs every loss */
    assert_true(r.ended);
    assert_int_equal(r.packets, (int)g_stream->n);
    assert_int_equal(r.keys, KEYS);
    assert_int_equal(r.mismatched, 0);
    assert_int_equal(r.st.dropped_incomplete + r.st.missing + r.st.dropped_corrupt, 0);
}

static void test_outage_resync(void **state)
{
    (void)state;
    struct received r;
    struct sender s;
    struct proxy_run pr;
    /* keys at 20 Hz, intra every 10 (0.5 s). Packets a receiver misses are
     * retransmitted, late or not, until the sender gives them up: SRT's sender
     * drops what waited more than max(latency, 1 s) + 20 ms. So a 1.3 s
     * outage from 0.6 s loses the keys sent in its first ~0.3 s (~12..17); the
     * intra key 20 resynchronises the decoder. */
    run_lossy(5, 0.0, 80, 600, 1300, &r, &s, &pr);
    assert_true(pr.st.dropped_fwd > 0);
    assert_true(r.st.srt_drop_rcv > 0 || r.st.missing > 0);
    assert_true(r.st.dropped_incomplete + r.st.missing > 0);
    assert_true(r.dec.lost + r.dec.skipped > 0);
    assert_true(r.keys < KEYS);
    assert_true(r.keys >= 20); /* keys 0..11 before the outage, 20..39 after */
    assert_int_equal(r.mismatched, 0);
    /* resynchronised: the last key arrived and decoded */
    assert_int_equal(r.last_key_seq, KEYS);
    assert_int_equal(r.st.dropped_corrupt, 0); /* incomplete packets never reach the CRC */
}

int main(int argc, char **argv)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_url),
        cmocka_unit_test(test_loopback_passphrase),
        cmocka_unit_test(test_wrong_passphrase),
        cmocka_unit_test(test_unreachable),
        cmocka_unit_test(test_file_urls),
        cmocka_unit_test(test_file_pace),
        cmocka_unit_test(test_roles_and_reconnect),
        cmocka_unit_test(test_loss_recovered),
        cmocka_unit_test(test_outage_resync),
    };
    transport_srt_log_level(2); /* the rejections below are expected */
    return F4D_TEST_MAIN(argc, argv, "transport", tests, make_stream, free_stream);
}
