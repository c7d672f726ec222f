/* f4d_stream_tool.c - f4d-stream: a stream file (.f4ds, see f4d_codec.h) over
 * SRT in real time, and back into a file (f4d_transport.h has the URLs).
 *
 *   f4d-stream send IN.f4ds URL [--speed X] [--tee FILE] [--status-ms MS] [--quiet]
 *       paces packets by their timestamps (--speed 1: real time, 2: twice as
 *       fast, 0: as fast as SRT takes them); drains SRT before it exits
 *   f4d-stream recv URL -o OUT.f4ds [--decode] [--timeout MS] [--capacity N]
 *                   [--max-packet BYTES] [--status-ms MS] [--quiet]
 *   --srt-log LEVEL: libsrt's log threshold (syslog 2..7, default 3: errors)
 *       writes every complete, CRC-valid packet to OUT; --decode also runs the
 *       codec's decoder (keys decoded, skipped until the next intra, lost);
 *       ends at the end-of-stream packet, when the peer closes, or when no
 *       packet came for --timeout ms (default 10000)
 * Live status on stderr (every --status-ms, default 1000; rate, SRT losses,
 * retransmissions, drops, RTT), a one-line JSON summary on stdout at the end.
 * Exit status 0 on success; 1 when nothing was sent / received or on an error. */
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "f4d_codec.h"
#include "f4d_transport.h"

static void usage(FILE *f)
{
    fprintf(f, "usage: f4d-stream send IN.f4ds URL [--speed X] [--tee FILE] [--status-ms MS] [--quiet]\n"
               "       f4d-stream recv URL -o OUT.f4ds [--decode] [--timeout MS] [--capacity N]\n"
               "                       [--max-packet BYTES] [--status-ms MS] [--quiet]\n"
               "       (both: --srt-log 2..7, libsrt's log level; default 3, errors)\n"
               "URL: srt://HOST:PORT?mode=caller|listener&latency=MS&passphrase=TEXT&pbkeylen=16|24|32\n"
               "     &timeout=MS&payload=BYTES&maxbw=BYTES_PER_S, or file:PATH\n");
}

static double now_s(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + (double)ts.tv_nsec * 1e-9;
}

static void sleep_s(double s)
{
    if (s <= 0)
        return;
    struct timespec ts = { (time_t)s, (long)((s - (double)(time_t)s) * 1e9) };
    while (nanosleep(&ts, &ts) != 0 && errno == EINTR) {
    }
}

static int slurp(const char *path, uint8_t **buf, size_t *len)
{
    FILE *f = fopen(path, "rb");
    if (!f) {
        fprintf(stderr, "f4d-stream: cannot open '%s': %s\n", path, strerror(errno));
        return -1;
    }
    int rc = -1;
    if (fseeko(f, 0, SEEK_END) == 0) {
        off_t n = ftello(f);
        rewind(f);
        *buf = n > 0 ? malloc((size_t)n) : NULL;
        if (*buf && fread(*buf, 1, (size_t)n, f) == (size_t)n) {
            *len = (size_t)n;
            rc = 0;
        } else {
            free(*buf);
        }
    }
    if (rc < 0)
        fprintf(stderr, "f4d-stream: cannot read '%s' (empty or unreadable)\n", path);
    fclose(f);
    return rc;
}

static void print_srt(FILE *f, const struct transport_stats *s)
{
    fprintf(f,
            "\"srt\":{\"sent\":%lld,\"recv\":%lld,\"lost_snd\":%lld,\"lost_rcv\":%lld,\"retrans\":%lld,"
            "\"drop_snd\":%lld,\"drop_rcv\":%lld,\"undecrypt\":%lld,\"rtt_ms\":%.3f,\"bandwidth_mbps\":%.1f,"
            "\"latency_ms\":%d}",
            (long long)s->srt_sent, (long long)s->srt_recv, (long long)s->srt_lost_snd, (long long)s->srt_lost_rcv,
            (long long)s->srt_retrans, (long long)s->srt_drop_snd, (long long)s->srt_drop_rcv,
            (long long)s->srt_undecrypt, s->rtt_ms, s->bandwidth_mbps, s->latency_ms);
}

/* One live status line: rate over the last period, and SRT's counters. */
struct status {
    double   t0, last;
    uint64_t last_bytes;
};

static void status_line(const char *what, struct status *st, const struct transport_stats *s, double now)
{
    double dt = now - st->last;
    double mbps = dt > 0 ? (double)(s->bytes - st->last_bytes) * 8e-6 / dt : 0;
    fprintf(stderr,
            "%s %7.1f s  %6llu packets  %8.2f Mbit/s  srt: sent %lld recv %lld lost %lld/%lld retrans %lld "
            "drop %lld/%lld rtt %.2f ms",
            what, now - st->t0, (unsigned long long)s->packets, mbps, (long long)s->srt_sent, (long long)s->srt_recv,
            (long long)s->srt_lost_snd, (long long)s->srt_lost_rcv, (long long)s->srt_retrans,
            (long long)s->srt_drop_snd, (long long)s->srt_drop_rcv, s->rtt_ms);
    if (s->dropped_incomplete || s->dropped_corrupt || s->missing)
        fprintf(stderr, "  dropped %llu incomplete %llu corrupt, %llu missing",
                (unsigned long long)s->dropped_incomplete, (unsigned long long)s->dropped_corrupt,
                (unsigned long long)s->missing);
    fputc('\n', stderr);
    st->last = now;
    st->last_bytes = s->bytes;
}

static int do_send(const char *in, const char *url, double speed, const char *tee, int status_ms, int quiet)
{
    uint8_t *b;
    size_t len;
    if (slurp(in, &b, &len) < 0)
        return 1;
    /* the largest packet plans the sender */
    size_t maxp = 0, npk = 0;
    for (size_t off = 0; off < len;) {
        struct codec_packet p;
        struct f4d_err err = { 0 };
        if (codec_packet_parse(b + off, len - off, &p, &err) < 0) {
            fprintf(stderr, "f4d-stream: '%s': byte %zu: %s\n", in, off, err.msg);
            free(b);
            return 1;
        }
        maxp = p.size > maxp ? p.size : maxp;
        npk++;
        off += p.size;
    }
    struct f4d_err err = { 0 };
    struct transport_opts o = { .max_packet = maxp, .tee_path = tee };
    transport_tx *tx;
    if (transport_tx_open(url, &o, &tx, &err) < 0) {
        fprintf(stderr, "f4d-stream: %s\n", err.msg);
        free(b);
        return 1;
    }
    struct transport_stats s = { 0 };
    struct status st = { now_s(), now_s(), 0 };
    double next_status = st.t0 + status_ms * 1e-3;
    uint64_t t_first = 0;
    int rc = 0;
    for (size_t off = 0, k = 0; off < len; k++) {
        struct codec_packet p;
        codec_packet_parse(b + off, len - off, &p, &err);
        if (k == 0)
            t_first = p.t_us;
        if (speed > 0)
            sleep_s(st.t0 + (double)(p.t_us - t_first) * 1e-6 / speed - now_s());
        if (transport_tx_send(tx, b + off, p.size) < 0) {
            fprintf(stderr, "f4d-stream: packet %zu: %s\n", k, transport_tx_error(tx));
            rc = 1;
            break;
        }
        off += p.size;
        double t = now_s();
        if (!quiet && t >= next_status) {
            transport_tx_stats(tx, &s);
            status_line("send", &st, &s, t);
            next_status = t + status_ms * 1e-3;
        }
    }
    if (rc == 0 && transport_tx_drain(tx, 10000) < 0) {
        fprintf(stderr, "f4d-stream: %s\n", transport_tx_error(tx));
        rc = 1;
    }
    double t_sent = now_s() - st.t0; /* until the peer acknowledged the last byte */
    transport_tx_stats(tx, &s); /* before close: SRT's counters go with the socket */
    transport_tx_close(tx, 0);
    printf("{\"command\":\"send\",\"file\":\"%s\",\"packets\":%llu,\"of\":%zu,\"bytes\":%llu,\"chunks\":%llu,"
           "\"seconds\":%.3f,\"mbps\":%.3f,",
           in, (unsigned long long)s.packets, npk, (unsigned long long)s.bytes, (unsigned long long)s.chunks, t_sent,
           t_sent > 0 ? (double)s.bytes * 8e-6 / t_sent : 0.0);
    print_srt(stdout, &s);
    printf(",\"ok\":%s}\n", rc == 0 ? "true" : "false");
    free(b);
    return rc;
}

static int do_recv(const char *url, const char *out, int decode, int timeout_ms, size_t capacity, size_t max_packet,
                   int status_ms, int quiet)
{
    struct f4d_err err = { 0 };
    codec_dec *dec = NULL;
    if (decode && codec_dec_new(capacity, &dec, &err) < 0) {
        fprintf(stderr, "f4d-stream: %s\n", err.msg);
        return 1;
    }
    struct transport_opts o = { .max_packet = max_packet, .tee_path = out };
    transport_rx *rx;
    if (transport_rx_open(url, &o, &rx, &err) < 0) {
        fprintf(stderr, "f4d-stream: %s\n", err.msg);
        codec_dec_free(dec);
        return 1;
    }
    struct transport_stats s = { 0 };
    struct status st = { now_s(), now_s(), 0 };
    double next_status = st.t0 + status_ms * 1e-3, t_first = 0, t_last = 0;
    const char *ended = "timeout";
    uint64_t keys = 0;
    int rc = 0;
    for (;;) {
        struct codec_packet p;
        int r = transport_rx_next(rx, quiet ? timeout_ms : (timeout_ms < status_ms ? timeout_ms : status_ms), &p);
        double t = now_s();
        if (r == 0) {
            if (t_first == 0)
                t_first = t;
            t_last = t;
            if (dec && codec_dec_packet(dec, &p) == 1)
                keys++;
            if (p.type == CODEC_PKT_END) {
                ended = "end";
                break;
            }
        } else if (r == F4D_ETIMEDOUT) {
            double since = t - (t_last > 0 ? t_last : st.t0);
            if (since * 1000 >= timeout_ms)
                break;
        } else if (r == F4D_EEOF) {
            ended = "closed";
            break;
        } else {
            fprintf(stderr, "f4d-stream: %s\n", transport_rx_error(rx));
            ended = "error";
            rc = 1;
            break;
        }
        if (!quiet && t >= next_status) {
            transport_rx_stats(rx, &s);
            status_line("recv", &st, &s, t);
            next_status = t + status_ms * 1e-3;
        }
    }
    transport_rx_stats(rx, &s);
    transport_rx_close(rx);
    double span = t_last - t_first;
    printf("{\"command\":\"recv\",\"file\":\"%s\",\"ended\":\"%s\",\"packets\":%llu,\"bytes\":%llu,\"chunks\":%llu,"
           "\"seconds\":%.3f,\"mbps\":%.3f,\"dropped_incomplete\":%llu,\"dropped_corrupt\":%llu,"
           "\"dropped_oversize\":%llu,\"missing\":%llu,\"chunks_bad\":%llu,",
           out, ended, (unsigned long long)s.packets, (unsigned long long)s.bytes, (unsigned long long)s.chunks, span,
           span > 0 ? (double)s.bytes * 8e-6 / span : 0.0, (unsigned long long)s.dropped_incomplete,
           (unsigned long long)s.dropped_corrupt, (unsigned long long)s.dropped_oversize,
           (unsigned long long)s.missing, (unsigned long long)s.chunks_bad);
    if (dec) {
        const struct codec_dec_stats *ds = codec_dec_stats(dec);
        printf("\"decoded\":{\"keys\":%llu,\"intra\":%llu,\"predicted\":%llu,\"lost\":%llu,\"skipped\":%llu,"
               "\"refused\":%llu},",
               (unsigned long long)keys, (unsigned long long)ds->intra, (unsigned long long)ds->predicted,
               (unsigned long long)ds->lost, (unsigned long long)ds->skipped, (unsigned long long)ds->refused);
    }
    print_srt(stdout, &s);
    printf("}\n");
    codec_dec_free(dec);
    if (s.packets == 0) {
        fprintf(stderr, "f4d-stream: nothing received from '%s'\n", url);
        rc = 1;
    }
    return rc;
}

static int int_arg(const char *opt, const char *v, long lo, long hi, long *out)
{
    char *end;
    long x = strtol(v, &end, 10);
    if (*end || x < lo || x > hi) {
        fprintf(stderr, "f4d-stream: %s '%s' must be an integer in [%ld, %ld]\n", opt, v, lo, hi);
        return -1;
    }
    *out = x;
    return 0;
}

int main(int argc, char **argv)
{
    if (argc < 2 || !strcmp(argv[1], "-h") || !strcmp(argv[1], "--help")) {
        usage(argc < 2 ? stderr : stdout);
        return argc < 2 ? 2 : 0;
    }
    const char *cmd = argv[1], *out = NULL, *tee = NULL, *pos[2] = { NULL, NULL };
    int npos = 0, decode = 0, quiet = 0, srt_log = 3; /* errors only */
    long status_ms = 1000, timeout_ms = 10000, capacity = 1 << 20, max_packet = (long)TRANSPORT_MAX_PACKET_DEF;
    double speed = 1.0;
    for (int i = 2; i < argc; i++) {
        const char *a = argv[i];
        if (!strcmp(a, "--decode")) {
            decode = 1;
        } else if (!strcmp(a, "--quiet")) {
            quiet = 1;
        } else if (!strcmp(a, "--srt-log")) {
            if (i + 1 >= argc) {
                fprintf(stderr, "f4d-stream: --srt-log needs a level (2 critical .. 7 debug)\n");
                return 2;
            }
            long lv;
            if (int_arg(a, argv[++i], 2, 7, &lv) < 0)
                return 2;
            srt_log = (int)lv;
        } else if (a[0] == '-' && a[1]) {
            if (i + 1 >= argc) {
                fprintf(stderr, "f4d-stream: option '%s' needs a value (or is unknown)\n", a);
                return 2;
            }
            const char *v = argv[++i];
            int bad = 0;
            if (!strcmp(a, "-o")) {
                out = v;
            } else if (!strcmp(a, "--tee")) {
                tee = v;
            } else if (!strcmp(a, "--speed")) {
                char *end;
                speed = strtod(v, &end);
                if (*end || !(speed >= 0 && speed <= 1000)) {
                    fprintf(stderr, "f4d-stream: --speed '%s' must be in [0, 1000] (0: unpaced)\n", v);
                    return 2;
                }
            } else if (!strcmp(a, "--status-ms")) {
                bad = int_arg(a, v, 10, 3600000, &status_ms);
            } else if (!strcmp(a, "--timeout")) {
                bad = int_arg(a, v, 1, 86400000, &timeout_ms);
            } else if (!strcmp(a, "--capacity")) {
                bad = int_arg(a, v, 1, (long)CODEC_CAPACITY_MAX, &capacity);
            } else if (!strcmp(a, "--max-packet")) {
                bad = int_arg(a, v, CODEC_PACKET_HEADER, 1L << 31, &max_packet);
            } else {
                fprintf(stderr, "f4d-stream: unknown option '%s'\n", a);
                return 2;
            }
            if (bad)
                return 2;
        } else if (npos < 2) {
            pos[npos++] = a;
        } else {
            fprintf(stderr, "f4d-stream: unexpected argument '%s'\n", a);
            return 2;
        }
    }
    transport_srt_log_level(srt_log);
    if (!strcmp(cmd, "send")) {
        if (npos != 2) {
            fprintf(stderr, "f4d-stream: send needs IN.f4ds and a URL\n");
            return 2;
        }
        return do_send(pos[0], pos[1], speed, tee, (int)status_ms, quiet) ? 1 : 0;
    }
    if (!strcmp(cmd, "recv")) {
        if (npos != 1 || !out) {
            fprintf(stderr, "f4d-stream: recv needs a URL and -o OUT.f4ds\n");
            return 2;
        }
        return do_recv(pos[0], out, decode, (int)timeout_ms, (size_t)capacity, (size_t)max_packet, (int)status_ms,
                       quiet)
                   ? 1
                   : 0;
    }
    fprintf(stderr, "f4d-stream: unknown command '%s'\n", cmd);
    usage(stderr);
    return 2;
}
