/* transport.c - container packets over SRT (chunked, reassembled) and files.
 * See f4d_transport.h for the framing and the guarantees. */
#include <errno.h>
#include <netdb.h>
#include <netinet/in.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <time.h>

#include <srt.h>

#include "transport_internal.h"

#define RX_MSG_MAX 1500 /* > any SRT live payload */

static void put_u16(uint8_t *p, uint32_t v) { p[0] = (uint8_t)v; p[1] = (uint8_t)(v >> 8); }
static void put_u32(uint8_t *p, uint32_t v) { put_u16(p, v); put_u16(p + 2, v >> 16); }
static uint32_t get_u16(const uint8_t *p) { return (uint32_t)p[0] | (uint32_t)p[1] << 8; }
static uint32_t get_u32(const uint8_t *p) { return get_u16(p) | get_u16(p + 2) << 16; }

static int64_t now_ms(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (int64_t)ts.tv_sec * 1000 + ts.tv_nsec / 1000000;
}

static int64_t now_us(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (int64_t)ts.tv_sec * 1000000 + ts.tv_nsec / 1000;
}

static void sleep_us(int64_t us)
{
    if (us <= 0)
        return;
    struct timespec ts = { (time_t)(us / 1000000), (long)(us % 1000000) * 1000 };
    while (nanosleep(&ts, &ts) != 0 && errno == EINTR) {
    }
}

/* ---- SRT plumbing shared by both ends ---- */

struct link {
    struct transport_url u;
    int      started;          /* srt_startup called */
    SRTSOCKET lsn, sock;       /* listener (listener mode), data socket */
    int      eid;
    struct transport_stats srt; /* SRT's counters at the last successful read */
};

static void link_init(struct link *l)
{
    l->started = 0;
    l->lsn = l->sock = SRT_INVALID_SOCK;
    l->eid = -1;
}

static void link_close(struct link *l)
{
    if (l->eid >= 0)
        srt_epoll_release(l->eid);
    if (l->sock != SRT_INVALID_SOCK)
        srt_close(l->sock);
    if (l->lsn != SRT_INVALID_SOCK)
        srt_close(l->lsn);
    if (l->started)
        srt_cleanup();
    link_init(l);
}

static const char *srt_why(void) { return srt_getlasterror_str(); }

static int set_flag(SRTSOCKET s, SRT_SOCKOPT o, const void *v, int n, const char *name, struct f4d_err *err)
{
    if (srt_setsockflag(s, o, v, n) == SRT_ERROR)
        return f4d_fail(err, F4D_EINVAL, "SRT option %s: %s", name, srt_why());
    return F4D_OK;
}

/* Options every socket gets before connect / listen (accepted sockets inherit
 * the listener's). */
static int configure(SRTSOCKET s, const struct transport_url *u, struct f4d_err *err)
{
    int live = SRTT_LIVE, rc;
    if ((rc = set_flag(s, SRTO_TRANSTYPE, &live, sizeof live, "transtype", err)) < 0)
        return rc;
    if (u->latency_ms >= 0 && (rc = set_flag(s, SRTO_LATENCY, &u->latency_ms, sizeof(int), "latency", err)) < 0)
        return rc;
    if ((rc = set_flag(s, SRTO_PAYLOADSIZE, &u->payload, sizeof(int), "payload", err)) < 0)
        return rc;
    if ((rc = set_flag(s, SRTO_CONNTIMEO, &u->timeout_ms, sizeof(int), "timeout", err)) < 0)
        return rc;
    if ((rc = set_flag(s, SRTO_SNDTIMEO, &u->timeout_ms, sizeof(int), "timeout", err)) < 0)
        return rc;
    /* buffers: SRT's default receive buffer (8192 packets, ~10 MB) holds 0.7 s
     * of a 300k-Gaussian stream at 110 Mbit/s; a latency window longer than
     * what the buffer holds overflows it (drops even without loss). The
     * flight window (FC, packets) must cover the buffer. */
    int fc = (int)(u->rcvbuf / 1316) + 256, sbuf = (int)u->rcvbuf;
    if ((rc = set_flag(s, SRTO_FC, &fc, sizeof fc, "flow control window", err)) < 0 ||
        (rc = set_flag(s, SRTO_RCVBUF, &sbuf, sizeof sbuf, "rcvbuf", err)) < 0 ||
        (rc = set_flag(s, SRTO_SNDBUF, &sbuf, sizeof sbuf, "sndbuf", err)) < 0)
        return rc;
    int ubuf = sbuf < (8 << 20) ? sbuf : (8 << 20); /* the kernel caps it at net.core.rmem_max */
    if ((rc = set_flag(s, SRTO_UDP_RCVBUF, &ubuf, sizeof ubuf, "udp rcvbuf", err)) < 0 ||
        (rc = set_flag(s, SRTO_UDP_SNDBUF, &ubuf, sizeof ubuf, "udp sndbuf", err)) < 0)
        return rc;
    if (u->maxbw > 0) {
        int64_t bw = u->maxbw;
        if ((rc = set_flag(s, SRTO_MAXBW, &bw, sizeof bw, "maxbw", err)) < 0)
            return rc;
    }
    if (u->passphrase[0]) {
        if ((rc = set_flag(s, SRTO_PASSPHRASE, u->passphrase, (int)strlen(u->passphrase), "passphrase", err)) < 0)
            return rc;
        if (u->pbkeylen && (rc = set_flag(s, SRTO_PBKEYLEN, &u->pbkeylen, sizeof(int), "pbkeylen", err)) < 0)
            return rc;
    }
    return F4D_OK;
}

static int resolve(const struct transport_url *u, int passive, struct sockaddr_storage *ss, int *len,
                   struct f4d_err *err)
{
    struct addrinfo hints = { 0 }, *ai = NULL;
    hints.ai_family = u->host[0] ? AF_UNSPEC : AF_INET;
    hints.ai_socktype = SOCK_DGRAM;
    hints.ai_flags = passive ? AI_PASSIVE : 0;
    char port[16];
    snprintf(port, sizeof port, "%d", u->port);
    int g = getaddrinfo(u->host[0] ? u->host : NULL, port, &hints, &ai);
    if (g != 0 || !ai)
        return f4d_fail(err, F4D_EINVAL, "cannot resolve host '%s': %s", u->host, gai_strerror(g));
    memcpy(ss, ai->ai_addr, ai->ai_addrlen);
    *len = (int)ai->ai_addrlen;
    freeaddrinfo(ai);
    return F4D_OK;
}

/* Why SRT refused a connection, in words a user can act on. */
static int connect_fail(const struct transport_url *u, SRTSOCKET s, int srt_errno, struct f4d_err *err)
{
    const char *who = u->host[0] ? u->host : "*";
    if (srt_errno == SRT_ENOSERVER)
        return f4d_fail(err, F4D_ETIMEDOUT, "srt://%s:%d: no SRT peer answered within %d ms (is a listener running?)",
                        who, u->port, u->timeout_ms);
    if (srt_errno == SRT_ECONNREJ) {
        int why = srt_getrejectreason(s);
        if (why == SRT_REJ_BADSECRET)
            return f4d_fail(err, F4D_EINVAL, "srt://%s:%d: connection rejected: wrong passphrase", who, u->port);
        if (why == SRT_REJ_UNSECURE)
            return f4d_fail(err, F4D_EINVAL,
                            "srt://%s:%d: connection rejected: one side has a passphrase, the other has none", who,
                            u->port);
        if (why == SRT_REJ_TIMEOUT)
            return f4d_fail(err, F4D_ETIMEDOUT, "srt://%s:%d: no SRT peer answered within %d ms", who, u->port,
                            u->timeout_ms);
        return f4d_fail(err, F4D_EIO, "srt://%s:%d: connection rejected: %s", who, u->port, srt_rejectreason_str(why));
    }
    return f4d_fail(err, F4D_EIO, "srt://%s:%d: connect: %s", who, u->port, srt_why());
}

static int make_nonblocking_rx(SRTSOCKET s)
{
    int no = 0;
    return srt_setsockflag(s, SRTO_RCVSYN, &no, sizeof no);
}

/* Opens the link: caller connects (blocking up to the timeout), listener
 * binds and listens. */
static int link_open(struct link *l, struct f4d_err *err)
{
    const struct transport_url *u = &l->u;
    if (srt_startup() < 0)
        return f4d_fail(err, F4D_EIO, "srt_startup: %s", srt_why());
    l->started = 1;
    l->eid = srt_epoll_create();
    if (l->eid < 0)
        return f4d_fail(err, F4D_EIO, "srt_epoll_create: %s", srt_why());
    struct sockaddr_storage ss;
    int alen = 0, rc;
    if ((rc = resolve(u, u->mode == TRANSPORT_LISTENER, &ss, &alen, err)) < 0)
        return rc;
    SRTSOCKET s = srt_create_socket();
    if (s == SRT_INVALID_SOCK)
        return f4d_fail(err, F4D_EIO, "srt_create_socket: %s", srt_why());
    if ((rc = configure(s, u, err)) < 0) {
        srt_close(s);
        return rc;
    }
    if (u->mode == TRANSPORT_CALLER) {
        if (srt_connect(s, (struct sockaddr *)&ss, alen) == SRT_ERROR) {
            int e = srt_getlasterror(NULL);
            rc = connect_fail(u, s, e, err);
            srt_close(s);
            return rc;
        }
        l->sock = s;
        return F4D_OK;
    }
    if (srt_bind(s, (struct sockaddr *)&ss, alen) == SRT_ERROR) {
        rc = f4d_fail(err, F4D_EIO, "srt://%s:%d: bind: %s", u->host, u->port, srt_why());
        srt_close(s);
        return rc;
    }
    if (srt_listen(s, 4) == SRT_ERROR || make_nonblocking_rx(s) == SRT_ERROR) {
        rc = f4d_fail(err, F4D_EIO, "srt://%s:%d: listen: %s", u->host, u->port, srt_why());
        srt_close(s);
        return rc;
    }
    l->lsn = s;
    int ev = SRT_EPOLL_IN | SRT_EPOLL_ERR;
    if (srt_epoll_add_usock(l->eid, s, &ev) == SRT_ERROR)
        return f4d_fail(err, F4D_EIO, "srt_epoll_add_usock: %s", srt_why());
    return F4D_OK;
}

/* Waits on the epoll set; 1 ready, 0 timed out, < 0 error. */
static int link_wait(struct link *l, int64_t timeout_ms, struct f4d_err *err)
{
    SRT_EPOLL_EVENT ev[2];
    int n = srt_epoll_uwait(l->eid, ev, 2, timeout_ms < 0 ? -1 : timeout_ms);
    if (n > 0)
        return 1;
    if (n == 0 || srt_getlasterror(NULL) == SRT_ETIMEOUT)
        return 0;
    return f4d_fail(err, F4D_EIO, "srt_epoll_uwait: %s", srt_why());
}

/* Listener: accepts one caller within timeout_ms. 1 accepted, 0 timed out.
 * Waits before accepting: srt_accept on an empty queue logs an error. */
static int link_accept(struct link *l, int64_t timeout_ms, struct f4d_err *err)
{
    int64_t deadline = timeout_ms < 0 ? -1 : now_ms() + timeout_ms;
    for (;;) {
        int64_t left = deadline < 0 ? -1 : deadline - now_ms();
        if (deadline >= 0 && left < 0)
            left = 0;
        int w = link_wait(l, left, err);
        if (w <= 0)
            return w;
        struct sockaddr_storage ss;
        int alen = sizeof ss;
        SRTSOCKET s = srt_accept(l->lsn, (struct sockaddr *)&ss, &alen);
        if (s != SRT_INVALID_SOCK) {
            int ev = SRT_EPOLL_IN | SRT_EPOLL_ERR;
            srt_epoll_remove_usock(l->eid, l->lsn);
            if (make_nonblocking_rx(s) == SRT_ERROR || srt_epoll_add_usock(l->eid, s, &ev) == SRT_ERROR) {
                srt_close(s);
                return f4d_fail(err, F4D_EIO, "srt: accepted socket: %s", srt_why());
            }
            l->sock = s;
            return 1;
        }
        if (srt_getlasterror(NULL) != SRT_EASYNCRCV)
            return f4d_fail(err, F4D_EIO, "srt://%s:%d: accept: %s", l->u.host, l->u.port, srt_why());
        if (deadline >= 0 && left == 0)
            return 0;
    }
}

static void link_stats(struct link *l, struct transport_stats *s);

/* The data socket went away: a listener goes back to waiting for callers. */
static void link_lost(struct link *l)
{
    struct transport_stats keep;
    link_stats(l, &keep);
    if (l->sock != SRT_INVALID_SOCK) {
        srt_epoll_remove_usock(l->eid, l->sock);
        srt_close(l->sock);
        l->sock = SRT_INVALID_SOCK;
    }
    if (l->lsn != SRT_INVALID_SOCK) {
        int ev = SRT_EPOLL_IN | SRT_EPOLL_ERR;
        srt_epoll_add_usock(l->eid, l->lsn, &ev);
    }
}

/* SRT's counters into s; the last good reading once the socket is gone. */
static void link_stats(struct link *l, struct transport_stats *s)
{
    SRT_TRACEBSTATS b;
    struct transport_stats *c = &l->srt;
    if (l->sock != SRT_INVALID_SOCK && srt_bstats(l->sock, &b, 0) != SRT_ERROR) {
        c->connected = srt_getsockstate(l->sock) == SRTS_CONNECTED;
        c->srt_sent = b.pktSentTotal;
        c->srt_recv = b.pktRecvTotal;
        c->srt_lost_snd = b.pktSndLossTotal;
        c->srt_lost_rcv = b.pktRcvLossTotal;
        c->srt_retrans = b.pktRetransTotal;
        c->srt_drop_snd = b.pktSndDropTotal;
        c->srt_drop_rcv = b.pktRcvDropTotal;
        c->srt_undecrypt = b.pktRcvUndecryptTotal;
        c->rtt_ms = b.msRTT;
        c->bandwidth_mbps = b.mbpsBandwidth;
        c->send_mbps = b.mbpsSendRate;
        c->recv_mbps = b.mbpsRecvRate;
        c->latency_ms = b.msRcvTsbPdDelay > b.msSndTsbPdDelay ? b.msRcvTsbPdDelay : b.msSndTsbPdDelay;
    } else {
        c->connected = 0;
    }
    if (l->u.kind != TRANSPORT_SRT)
        return;
    s->connected = c->connected;
    s->srt_sent = c->srt_sent;
    s->srt_recv = c->srt_recv;
    s->srt_lost_snd = c->srt_lost_snd;
    s->srt_lost_rcv = c->srt_lost_rcv;
    s->srt_retrans = c->srt_retrans;
    s->srt_drop_snd = c->srt_drop_snd;
    s->srt_drop_rcv = c->srt_drop_rcv;
    s->srt_undecrypt = c->srt_undecrypt;
    s->rtt_ms = c->rtt_ms;
    s->bandwidth_mbps = c->bandwidth_mbps;
    s->send_mbps = c->send_mbps;
    s->recv_mbps = c->recv_mbps;
    s->latency_ms = c->latency_ms;
}

static int open_tee(const char *path, FILE **out, struct f4d_err *err)
{
    *out = NULL;
    if (!path)
        return F4D_OK;
    *out = fopen(path, "wb");
    if (!*out)
        return f4d_fail(err, F4D_EIO, "cannot create '%s': %s", path, strerror(errno));
    return F4D_OK;
}

static size_t max_packet_of(const struct transport_opts *o)
{
    size_t m = o && o->max_packet ? o->max_packet : TRANSPORT_MAX_PACKET_DEF;
    return m < CODEC_PACKET_HEADER ? CODEC_PACKET_HEADER : m;
}

/* ---- sender ---- */

struct transport_tx {
    struct link link;
    size_t   max_packet;
    FILE    *file, *tee;
    uint8_t  chunk[TRANSPORT_PAYLOAD_MAX];
    uint32_t last_seq;
    struct transport_stats st;
    struct f4d_err err;
};

int transport_tx_open(const char *url, const struct transport_opts *o, transport_tx **out, struct f4d_err *err)
{
    if (!out)
        return f4d_fail(err, F4D_EINVAL, "transport_tx_open: NULL out");
    *out = NULL;
    transport_tx *t = calloc(1, sizeof *t);
    if (!t)
        return f4d_fail(err, F4D_ENOMEM, "transport_tx_open: out of memory");
    link_init(&t->link);
    t->max_packet = max_packet_of(o);
    int rc = transport_url_parse(url, &t->link.u, err);
    if (rc == 0)
        rc = open_tee(o ? o->tee_path : NULL, &t->tee, err);
    if (rc == 0 && t->link.u.kind == TRANSPORT_FILE) {
        t->file = fopen(t->link.u.path, "wb");
        if (!t->file)
            rc = f4d_fail(err, F4D_EIO, "cannot create '%s': %s", t->link.u.path, strerror(errno));
    } else if (rc == 0) {
        rc = link_open(&t->link, err);
        if (rc == 0 && t->link.u.mode == TRANSPORT_LISTENER) {
            rc = link_accept(&t->link, t->link.u.timeout_ms, err);
            if (rc == 0)
                rc = f4d_fail(err, F4D_ETIMEDOUT, "srt://%s:%d: no caller connected within %d ms", t->link.u.host,
                              t->link.u.port, t->link.u.timeout_ms);
            else if (rc == 1)
                rc = F4D_OK;
        }
        if (rc == 0) {
            int yes = 1; /* sending blocks (up to SNDTIMEO) when the buffer is full */
            if (srt_setsockflag(t->link.sock, SRTO_SNDSYN, &yes, sizeof yes) == SRT_ERROR)
                rc = f4d_fail(err, F4D_EIO, "SRT option sndsyn: %s", srt_why());
        }
    }
    if (rc < 0) {
        transport_tx_close(t, 0);
        return rc;
    }
    *out = t;
    return F4D_OK;
}

const char *transport_tx_error(const transport_tx *t) { return t ? t->err.msg : "NULL sender"; }

static int write_all(FILE *f, const uint8_t *b, size_t n, const char *what, struct f4d_err *err)
{
    if (fwrite(b, 1, n, f) != n)
        return f4d_fail(err, F4D_EIO, "write to %s failed: %s", what, strerror(errno));
    return F4D_OK;
}

/* One SRT message; 0 or a failure (which ends the link on connection loss). */
static int tx_msg(transport_tx *t, size_t n, uint32_t seq)
{
    if (srt_sendmsg2(t->link.sock, (const char *)t->chunk, (int)n, NULL) != SRT_ERROR)
        return F4D_OK;
    int e = srt_getlasterror(NULL);
    if (e == SRT_EASYNCSND)
        return f4d_fail(&t->err, F4D_ETIMEDOUT, "srt: send buffer still full after %d ms", t->link.u.timeout_ms);
    int rc = f4d_fail(&t->err, e == SRT_ECONNLOST || e == SRT_ENOCONN ? F4D_EEOF : F4D_EIO,
                      "srt: send of packet seq %u: %s", seq, srt_why());
    link_lost(&t->link);
    return rc;
}

/* The tail probe: SRT's live mode learns of a loss only from a later
 * sequence number, so without it a packet's lost last chunk would wait for the
 * next packet (often longer than the latency window) to be noticed. */
static int tx_probe(transport_tx *t, uint32_t seq)
{
    memset(t->chunk, 0, TRANSPORT_CHUNK_HEADER);
    put_u32(t->chunk, TRANSPORT_CHUNK_MAGIC);
    put_u32(t->chunk + 4, seq);
    return tx_msg(t, TRANSPORT_CHUNK_HEADER, seq);
}

int transport_tx_send(transport_tx *t, const uint8_t *pkt, size_t len)
{
    if (!t)
        return F4D_EINVAL;
    struct codec_packet p;
    int rc = codec_packet_parse(pkt, len, &p, &t->err);
    if (rc < 0) {
        f4d_err_prefix(&t->err, "transport_tx_send");
        return rc;
    }
    if (p.size != len)
        return f4d_fail(&t->err, F4D_EINVAL, "transport_tx_send: %zu bytes hold a packet of %zu plus more", len,
                        p.size);
    if (len > t->max_packet)
        return f4d_fail(&t->err, F4D_ERANGE, "transport_tx_send: packet seq %u of %zu bytes exceeds max_packet %zu",
                        p.seq, len, t->max_packet);
    if (t->tee && (rc = write_all(t->tee, pkt, len, "the tee file", &t->err)) < 0)
        return rc;
    if (t->file) {
        if ((rc = write_all(t->file, pkt, len, t->link.u.path, &t->err)) < 0)
            return rc;
        t->st.packets++;
        t->st.bytes += len;
        return F4D_OK;
    }
    if (t->link.sock == SRT_INVALID_SOCK)
        return f4d_fail(&t->err, F4D_EEOF, "transport_tx_send: the connection is closed");
    size_t data = (size_t)t->link.u.payload - TRANSPORT_CHUNK_HEADER;
    size_t count = (len + data - 1) / data;
    if (count > 0xffff)
        return f4d_fail(&t->err, F4D_ERANGE, "transport_tx_send: packet of %zu bytes needs %zu chunks (max 65535)", len,
                        count);
    size_t stride = (len + count - 1) / count;
    for (size_t i = 0; i < count; i++) {
        size_t off = i * stride, n = len - off < stride ? len - off : stride;
        put_u32(t->chunk, TRANSPORT_CHUNK_MAGIC);
        put_u32(t->chunk + 4, p.seq);
        put_u32(t->chunk + 8, (uint32_t)len);
        put_u16(t->chunk + 12, (uint32_t)i);
        put_u16(t->chunk + 14, (uint32_t)count);
        memcpy(t->chunk + TRANSPORT_CHUNK_HEADER, pkt + off, n);
        if ((rc = tx_msg(t, TRANSPORT_CHUNK_HEADER + n, p.seq)) < 0)
            return rc;
        t->st.chunks++;
    }
    if ((rc = tx_probe(t, p.seq)) < 0)
        return rc;
    t->last_seq = p.seq;
    t->st.packets++;
    t->st.bytes += len;
    struct transport_stats keep; /* SRT's counters vanish with a broken socket */
    link_stats(&t->link, &keep);
    return F4D_OK;
}

int transport_tx_stats(transport_tx *t, struct transport_stats *s)
{
    if (!t || !s)
        return F4D_EINVAL;
    *s = t->st;
    s->connected = t->file != NULL;
    link_stats(&t->link, s);
    return F4D_OK;
}

int transport_tx_drain(transport_tx *t, int timeout_ms)
{
    if (!t)
        return F4D_EINVAL;
    if (t->file)
        return fflush(t->file) == 0 ? F4D_OK : f4d_fail(&t->err, F4D_EIO, "'%s': %s", t->link.u.path, strerror(errno));
    if (t->link.sock == SRT_INVALID_SOCK)
        return f4d_fail(&t->err, F4D_EEOF, "transport_tx_drain: the connection is closed");
    /* live mode does not linger: wait for the peer's ACKs */
    int64_t deadline = now_ms() + timeout_ms, probe = now_ms();
    size_t blocks = 0, bytes = 0;
    while (srt_getsockstate(t->link.sock) == SRTS_CONNECTED && srt_getsndbuffer(t->link.sock, &blocks, &bytes) >= 0 &&
           blocks > 0) {
        int64_t now = now_ms();
        if (now >= deadline)
            return f4d_fail(&t->err, F4D_ETIMEDOUT, "srt: %zu messages still unacknowledged after %d ms", blocks,
                            timeout_ms);
        if (now - probe >= 20) { /* the probes lost too: more until SRT sees the gap */
            int rc = tx_probe(t, t->last_seq);
            if (rc < 0)
                return rc;
            probe = now;
        }
        sleep_us(2000);
    }
    if (blocks > 0)
        return f4d_fail(&t->err, F4D_EEOF, "srt: the connection closed with %zu messages unacknowledged", blocks);
    return F4D_OK;
}

void transport_tx_close(transport_tx *t, int timeout_ms)
{
    if (!t)
        return;
    if (timeout_ms > 0 && (t->file || t->link.sock != SRT_INVALID_SOCK))
        transport_tx_drain(t, timeout_ms);
    if (t->link.sock != SRT_INVALID_SOCK && srt_getsockstate(t->link.sock) == SRTS_CONNECTED) {
        /* the receiver hands packets on a TSBPD window after they arrived:
         * closing earlier would lose the last ones */
        struct transport_stats s = { 0 };
        link_stats(&t->link, &s);
        sleep_us(1000 * (s.latency_ms + 2 * (int64_t)s.rtt_ms + 20));
    }
    link_close(&t->link);
    if (t->file)
        fclose(t->file);
    if (t->tee)
        fclose(t->tee);
    free(t);
}

void transport_srt_log_level(int level)
{
    srt_setloglevel(level);
}

/* ---- receiver ---- */

struct transport_rx {
    struct link link;
    struct transport_reasm a;  /* buffers planned at open */
    FILE    *file, *tee;
    int      pace;
    /* file pacing */
    int      pending;          /* pend was read and waits for its time      */
    struct codec_packet pend;
    int      t0_valid;
    uint64_t t0_pkt;
    int64_t  t0_wall;
    uint8_t  msg[RX_MSG_MAX];
    struct transport_stats st;
    struct f4d_err err;
};

int transport_rx_open(const char *url, const struct transport_opts *o, transport_rx **out, struct f4d_err *err)
{
    if (!out)
        return f4d_fail(err, F4D_EINVAL, "transport_rx_open: NULL out");
    *out = NULL;
    transport_rx *r = calloc(1, sizeof *r);
    if (!r)
        return f4d_fail(err, F4D_ENOMEM, "transport_rx_open: out of memory");
    link_init(&r->link);
    r->pace = o ? o->pace : 0;
    int rc = transport_reasm_init(&r->a, max_packet_of(o), &r->st, err);
    if (rc == 0)
        rc = transport_url_parse(url, &r->link.u, err);
    if (rc == 0)
        rc = open_tee(o ? o->tee_path : NULL, &r->tee, err);
    if (rc == 0 && r->link.u.kind == TRANSPORT_FILE) {
        r->file = fopen(r->link.u.path, "rb");
        if (!r->file)
            rc = f4d_fail(err, F4D_EIO, "cannot open '%s': %s", r->link.u.path, strerror(errno));
    } else if (rc == 0) {
        rc = link_open(&r->link, err);
        int ev = SRT_EPOLL_IN | SRT_EPOLL_ERR;
        if (rc == 0 && r->link.sock != SRT_INVALID_SOCK &&
            (make_nonblocking_rx(r->link.sock) == SRT_ERROR ||
             srt_epoll_add_usock(r->link.eid, r->link.sock, &ev) == SRT_ERROR))
            rc = f4d_fail(err, F4D_EIO, "srt: %s", srt_why());
    }
    if (rc < 0) {
        transport_rx_close(r);
        return rc;
    }
    *out = r;
    return F4D_OK;
}

const char *transport_rx_error(const transport_rx *r) { return r ? r->err.msg : "NULL receiver"; }

/* Archives a packet handed on and refreshes SRT's counters (they vanish
 * with a broken socket). */
static int handed_on(transport_rx *r, const struct codec_packet *p)
{
    int rc;
    if (r->tee && (rc = write_all(r->tee, r->a.buf, p->size, "the tee file", &r->err)) < 0)
        return rc;
    struct transport_stats keep;
    link_stats(&r->link, &keep);
    return F4D_OK;
}

static int rx_srt(transport_rx *r, int timeout_ms, struct codec_packet *p)
{
    struct link *l = &r->link;
    int64_t deadline = timeout_ms < 0 ? -1 : now_ms() + timeout_ms;
    for (;;) {
        int64_t left = deadline < 0 ? -1 : deadline - now_ms();
        if (deadline >= 0 && left < 0)
            left = 0;
        if (l->sock == SRT_INVALID_SOCK) {
            if (l->lsn == SRT_INVALID_SOCK)
                return f4d_fail(&r->err, F4D_EEOF, "srt://%s:%d: the connection is closed", l->u.host, l->u.port);
            int a = link_accept(l, left, &r->err);
            if (a < 0)
                return a;
            if (a == 0)
                return f4d_fail(&r->err, F4D_ETIMEDOUT, "srt://%s:%d: no caller within %d ms", l->u.host,
                                l->u.port, timeout_ms);
            transport_reasm_reset(&r->a);
            continue;
        }
        SRT_MSGCTRL mc = srt_msgctrl_default;
        int n = srt_recvmsg2(l->sock, (char *)r->msg, (int)sizeof r->msg, &mc);
        if (n == 0)
            continue;
        if (n > 0) {
            if (transport_reasm_push(&r->a, r->msg, (size_t)n, p) == 0)
                return handed_on(r, p);
            continue;
        }
        int e = srt_getlasterror(NULL);
        if (n == SRT_ERROR && e == SRT_EASYNCRCV && srt_getsockstate(l->sock) == SRTS_CONNECTED) {
            if (deadline >= 0 && left == 0)
                return f4d_fail(&r->err, F4D_ETIMEDOUT, "srt: no packet within %d ms", timeout_ms);
            int w = link_wait(l, left, &r->err);
            if (w < 0)
                return w;
            continue;
        }
        transport_reasm_abort(&r->a);
        link_lost(l);
        return f4d_fail(&r->err, F4D_EEOF, "srt://%s:%d: the peer closed the connection", l->u.host, l->u.port);
    }
}

/* Reads exactly n bytes: 0, or F4D_EEOF when the file ends first. */
static int read_exact(FILE *f, uint8_t *b, size_t n)
{
    return fread(b, 1, n, f) == n ? 0 : F4D_EEOF;
}

static int rx_file(transport_rx *r, int timeout_ms, struct codec_packet *p)
{
    const char *path = r->link.u.path;
    while (!r->pending) {
        uint8_t *buf = r->a.buf;
        if (read_exact(r->file, buf, CODEC_PACKET_HEADER) < 0)
            return f4d_fail(&r->err, F4D_EEOF, "'%s': end of file", path);
        if (get_u32(buf) != CODEC_PACKET_MAGIC) {
            /* resync: slide byte by byte to the next magic (corrupt files only) */
            r->st.dropped_corrupt++;
            do {
                memmove(buf, buf + 1, CODEC_PACKET_HEADER - 1);
                if (read_exact(r->file, buf + CODEC_PACKET_HEADER - 1, 1) < 0)
                    return f4d_fail(&r->err, F4D_EEOF, "'%s': end of file", path);
            } while (get_u32(buf) != CODEC_PACKET_MAGIC);
        }
        uint64_t n = get_u32(buf + 24);
        if (CODEC_PACKET_HEADER + n > r->a.max_packet) {
            r->st.dropped_oversize++;
            if (fseeko(r->file, (off_t)n, SEEK_CUR) != 0)
                return f4d_fail(&r->err, F4D_EEOF, "'%s': end of file", path);
            continue;
        }
        if (read_exact(r->file, buf + CODEC_PACKET_HEADER, (size_t)n) < 0) {
            r->st.dropped_incomplete++;
            return f4d_fail(&r->err, F4D_EEOF, "'%s': ends inside a packet", path);
        }
        if (transport_reasm_check(&r->a, CODEC_PACKET_HEADER + (size_t)n, &r->pend) == 0) {
            int rc = handed_on(r, &r->pend);
            if (rc < 0)
                return rc;
            r->pending = 1;
        }
    }
    if (r->pace) {
        int64_t t = now_us();
        if (!r->t0_valid) {
            r->t0_valid = 1;
            r->t0_pkt = r->pend.t_us;
            r->t0_wall = t;
        }
        int64_t due = r->t0_wall + (int64_t)(r->pend.t_us - r->t0_pkt);
        if (due > t) {
            if (timeout_ms >= 0 && due - t > (int64_t)timeout_ms * 1000) {
                sleep_us((int64_t)timeout_ms * 1000);
                return f4d_fail(&r->err, F4D_ETIMEDOUT, "'%s': next packet due in %lld ms", path,
                                (long long)((due - now_us()) / 1000));
            }
            sleep_us(due - t);
        }
    }
    r->pending = 0;
    *p = r->pend;
    return F4D_OK;
}

int transport_rx_next(transport_rx *r, int timeout_ms, struct codec_packet *p)
{
    if (!r || !p)
        return F4D_EINVAL;
    return r->file ? rx_file(r, timeout_ms, p) : rx_srt(r, timeout_ms, p);
}

int transport_rx_stats(transport_rx *r, struct transport_stats *s)
{
    if (!r || !s)
        return F4D_EINVAL;
    *s = r->st;
    s->connected = r->file != NULL;
    link_stats(&r->link, s);
    return F4D_OK;
}

void transport_rx_close(transport_rx *r)
{
    if (!r)
        return;
    link_close(&r->link);
    if (r->file)
        fclose(r->file);
    if (r->tee)
        fclose(r->tee);
    transport_reasm_free(&r->a);
    free(r);
}
