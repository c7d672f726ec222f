/* f4d_transport.h - moves container packets (f4d_codec.h) over SRT or to and
 * from files. Library f4d_transport; depends on firmware/stream/codec (packet
 * parsing and CRC) and libsrt (Debian libsrt-openssl-dev). The codec never
 * depends on it.
 *
 *     struct f4d_err err = {0};
 *     struct transport_opts o = { .max_packet = codec_packet_bound(300000) };
 *     transport_tx *tx;                         // camera side
 *     transport_tx_open("srt://display:7000?latency=200&passphrase=0123456789",
 *                       &o, &tx, &err);
 *     transport_tx_send(tx, pkt, n);            // one container packet
 *     transport_tx_close(tx);                   // drains what SRT still holds
 *
 *     transport_rx *rx;                         // display side
 *     transport_rx_open("srt://:7000?mode=listener&passphrase=0123456789", &o, &rx, &err);
 *     struct codec_packet p;
 *     int rc;
 *     while ((rc = transport_rx_next(rx, 500, &p)) != F4D_EEOF)
 *         if (rc == 0) codec_dec_packet(dec, &p);   // complete, CRC-valid
 *     transport_rx_close(rx);
 *
 * URLs
 *   srt://HOST:PORT?PARAM=VALUE&...   SRT in live mode. Parameters:
 *     mode=caller|listener   default: caller when HOST is given, else listener
 *                            (listener binds HOST, or every address when empty)
 *     latency=MS             TSBPD window, both directions (SRT default 120);
 *                            a lost packet can be retransmitted while its
 *                            delivery time is in the future, later it is dropped
 *     passphrase=TEXT        AES encryption (10..79 characters, %XX escapes);
 *                            both ends must use the same one
 *     pbkeylen=16|24|32      AES key length in bytes (default 16, sender's wins)
 *     timeout=MS             connect timeout, and how long a listening sender
 *                            waits at open for its caller (default 3000)
 *     payload=BYTES          SRT payload per message, 64..1456 (default 1316)
 *     rcvbuf=BYTES           SRT's receive and send buffers (default 32 MiB;
 *                            must hold bitrate x (latency + RTT) plus a key
 *                            frame, or packets are dropped without any loss;
 *                            SRT's own default, ~10 MB, is too small for
 *                            300k-Gaussian keys with a 1 s window)
 *     maxbw=BYTES_PER_S      sender bandwidth cap incl. retransmissions
 *                            (default: SRT's, 1 Gbit/s in live mode)
 *   file:PATH                a stream file (packets back to back): the sender
 *                            writes it, the receiver reads it (paced by the
 *                            packets' timestamps when opts.pace).
 * A bad URL is refused at open naming the part that is wrong.
 *
 * Framing over SRT: one SRT message (live mode: one UDP payload) carries one
 * chunk of one container packet; key frames are larger than a message, so a
 * packet travels as `count` chunks, each with a 16-byte header
 *     u32 magic "F4DC" (0x43443446)  u32 seq (the packet's)  u32 total length
 *     u16 index  u16 count           (all little-endian)
 * followed by bytes [index * stride, +len) of the packet, stride =
 * ceil(total / count), the last chunk shorter. Each packet is followed by a
 * probe, a bare header with total = count = 0 that receivers skip: SRT's
 * live mode notices a loss only from a later sequence number, so a packet's
 * lost last chunk would otherwise wait for the next packet (often longer than
 * the latency window) to be retransmitted; drain sends more while it waits.
 * SRT live mode delivers chunks
 * in order or not at all (too-late drop), so the receiver holds one packet in
 * assembly: a chunk of another seq ends it; if chunks were missing it is
 * dropped and counted (dropped_incomplete). A complete packet is checked by
 * codec_packet_parse (CRC); failures are dropped and counted (dropped_corrupt).
 * Packets of which no chunk arrived show up as a seq gap (missing). The
 * decoder then waits for the next intra key (f4d_codec.h), so a display
 * resynchronises by itself. Nothing is ever handed on half-assembled.
 *
 * Memory: buffers are planned at open from opts.max_packet; sending and
 * receiving packets allocate nothing (libsrt's own buffers are its business).
 * A packet above max_packet is refused (sender: F4D_ERANGE; receiver: dropped
 * and counted as dropped_oversize).
 *
 * Errors: open fails with F4D_ETIMEDOUT when no peer answers within timeout,
 * F4D_EINVAL for a bad URL, F4D_EIO for sockets and files, and a message that
 * says "wrong passphrase" when SRT rejects the handshake for that reason. A
 * closed connection reads as F4D_EEOF; a listening receiver then waits for the
 * next caller on its next call.
 * Threads: one object per thread; objects are independent (libsrt is started
 * and stopped by reference count inside it).
 */
#ifndef F4D_TRANSPORT_H
#define F4D_TRANSPORT_H

#include <stddef.h>
#include <stdint.h>

#include "f4d_codec.h"
#include "f4d_status.h"

#ifdef __cplusplus
extern "C" {
#endif

#define TRANSPORT_CHUNK_HEADER  16
#define TRANSPORT_CHUNK_MAGIC   0x43443446u /* "F4DC" little-endian */
#define TRANSPORT_PAYLOAD_DEF   1316
#define TRANSPORT_PAYLOAD_MAX   1456
#define TRANSPORT_MAX_PACKET_DEF ((size_t)16 << 20)
#define TRANSPORT_RCVBUF_DEF    (32ll << 20)

enum transport_kind { TRANSPORT_SRT = 1, TRANSPORT_FILE = 2 };
enum transport_mode { TRANSPORT_CALLER = 1, TRANSPORT_LISTENER = 2 };

/* A parsed URL (transport_url_parse; the open functions call it). */
struct transport_url {
    int  kind, mode;
    char host[256];          /* empty: any address (listener)          */
    int  port;
    int  latency_ms;         /* -1: SRT's default                      */
    char passphrase[80];     /* empty: no encryption                   */
    int  pbkeylen;           /* 0: SRT's default                       */
    int  timeout_ms;
    int  payload;
    long long rcvbuf;        /* bytes                                  */
    long long maxbw;         /* 0: SRT's default                       */
    char path[4096];         /* file:                                  */
};
int transport_url_parse(const char *url, struct transport_url *u, struct f4d_err *err);

struct transport_opts {
    size_t      max_packet;  /* largest container packet; 0: TRANSPORT_MAX_PACKET_DEF */
    const char *tee_path;    /* also write every packet (sent / received valid) here  */
    int         pace;        /* file: receivers: deliver at the packets' timestamps   */
};

/* Counters since open. Ours first, then SRT's (srt_bstats totals; zero for
 * files). A receiver's packets are the complete, CRC-valid ones it handed on. */
struct transport_stats {
    int      connected;
    uint64_t packets, bytes, chunks;
    uint64_t dropped_incomplete;     /* receiver: packets with chunks missing      */
    uint64_t dropped_corrupt;        /* receiver: complete but CRC / format bad    */
    uint64_t dropped_oversize;       /* receiver: larger than max_packet           */
    uint64_t missing;                /* receiver: seq gaps (no chunk arrived)      */
    uint64_t chunks_bad;             /* receiver: SRT messages that are no chunk   */
    int64_t  srt_sent, srt_recv;     /* data packets (sent incl. retransmissions)  */
    int64_t  srt_lost_snd, srt_lost_rcv; /* losses reported / detected            */
    int64_t  srt_retrans;            /* retransmitted packets (sender side)        */
    int64_t  srt_drop_snd, srt_drop_rcv; /* too late: dropped by TSBPD             */
    int64_t  srt_undecrypt;          /* packets that failed decryption             */
    double   rtt_ms, bandwidth_mbps, send_mbps, recv_mbps;
    int      latency_ms;             /* negotiated TSBPD delay                     */
};

/* ---- sender ---- */
typedef struct transport_tx transport_tx;
int  transport_tx_open (const char *url, const struct transport_opts *o, transport_tx **out, struct f4d_err *err);
/* Sends one container packet (checked with codec_packet_parse first). Blocks
 * while SRT's send buffer is full (at most the URL's timeout). */
int  transport_tx_send (transport_tx *t, const uint8_t *pkt, size_t len);
int  transport_tx_stats(transport_tx *t, struct transport_stats *s);
const char *transport_tx_error(const transport_tx *t);
/* Waits up to timeout_ms until the peer acknowledged everything sent (SRT's
 * live mode drops what is queued at close): 0, or F4D_ETIMEDOUT / F4D_EEOF.
 * Files: flushes. */
int  transport_tx_drain(transport_tx *t, int timeout_ms);
/* Drains (when timeout_ms > 0), waits out the TSBPD window while connected
 * (the receiver hands packets on that long after they arrive), closes. */
void transport_tx_close(transport_tx *t, int timeout_ms);

/* ---- receiver ---- */
typedef struct transport_rx transport_rx;
int  transport_rx_open (const char *url, const struct transport_opts *o, transport_rx **out, struct f4d_err *err);
/* Next complete, CRC-valid packet: 0 (p points into the receiver's buffer,
 * valid until the next call), F4D_ETIMEDOUT (nothing within timeout_ms; < 0
 * waits forever), F4D_EEOF (file end, or the peer closed), < 0 other errors
 * (message: transport_rx_error). */
int  transport_rx_next (transport_rx *r, int timeout_ms, struct codec_packet *p);
int  transport_rx_stats(transport_rx *r, struct transport_stats *s);
const char *transport_rx_error(const transport_rx *r);
void transport_rx_close(transport_rx *r);

/* libsrt's log threshold for the whole process (syslog levels: 2 LOG_CRIT ..
 * 7 LOG_DEBUG; libsrt's default prints warnings). For main to call. */
void transport_srt_log_level(int level);

#ifdef __cplusplus
}
#endif
#endif /* F4D_TRANSPORT_H */
