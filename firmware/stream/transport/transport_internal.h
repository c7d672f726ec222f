/* transport_internal.h - the chunk reassembler of the SRT receiver, apart from
 * libsrt so that the libFuzzer harness (tests/stream/transport/fuzz_chunks.c) can drive it
 * with arbitrary messages. See f4d_transport.h for the chunk format. */
#ifndef F4D_TRANSPORT_INTERNAL_H
#define F4D_TRANSPORT_INTERNAL_H

#include <stddef.h>
#include <stdint.h>

#include "f4d_transport.h"

struct transport_reasm {
    size_t   max_packet, have_cap; /* bytes; chunks (bits of have)          */
    uint8_t *buf, *have;           /* the packet in assembly; chunk bitmap   */
    int      active, expect_valid;
    uint32_t seq, total, count, got, expect;
    struct transport_stats *st;    /* counters: chunks, chunks_bad, dropped_*, missing, packets, bytes */
};

/* Allocates the buffers for packets up to max_packet (>= the packet header). */
int  transport_reasm_init (struct transport_reasm *a, size_t max_packet, struct transport_stats *st,
                           struct f4d_err *err);
void transport_reasm_free (struct transport_reasm *a);
/* A new peer: forget the packet in assembly (not counted) and the seq. */
void transport_reasm_reset(struct transport_reasm *a);
/* The peer went away: a packet in assembly counts as dropped_incomplete. */
void transport_reasm_abort(struct transport_reasm *a);
/* One SRT message: 0 when it completed a CRC-valid packet (p points into
 * a->buf until the next push), 1 when consumed (counted if dropped). */
int  transport_reasm_push (struct transport_reasm *a, const uint8_t *m, size_t n, struct codec_packet *p);
/* Checks the len bytes in a->buf as one packet: 0 valid (counted as a packet),
 * 1 dropped (counted as dropped_corrupt). */
int  transport_reasm_check(struct transport_reasm *a, size_t len, struct codec_packet *p);

#endif /* F4D_TRANSPORT_INTERNAL_H */
