/* reasm.c - chunks -> container packets (see f4d_transport.h). SRT's live
 * mode delivers messages in order or drops them, so one packet is assembled
 * at a time; every field of a chunk header is checked against the others and
 * against the buffer before a byte is copied. */
#include <stdlib.h>
#include <string.h>

#include "transport_internal.h"

static uint32_t get_u16(const uint8_t *p) { return (uint32_t)p[0] | (uint32_t)p[1] << 8; }
static uint32_t get_u32(const uint8_t *p) { return get_u16(p) | get_u16(p + 2) << 16; }

int transport_reasm_init(struct transport_reasm *a, size_t max_packet, struct transport_stats *st, struct f4d_err *err)
{
    memset(a, 0, sizeof *a);
    a->max_packet = max_packet < CODEC_PACKET_HEADER ? CODEC_PACKET_HEADER : max_packet;
    /* chunks carry at least 64 - 16 bytes (the smallest payload): the most a
     * packet can need */
    a->have_cap = a->max_packet / 48 + 2;
    a->buf = malloc(a->max_packet);
    a->have = calloc((a->have_cap + 7) / 8, 1);
    a->st = st;
    if (!a->buf || !a->have) {
        transport_reasm_free(a);
        return f4d_fail(err, F4D_ENOMEM, "transport: %zu bytes for the receive buffer", a->max_packet);
    }
    return F4D_OK;
}

void transport_reasm_free(struct transport_reasm *a)
{
    free(a->buf);
    free(a->have);
    a->buf = a->have = NULL;
}

void transport_reasm_reset(struct transport_reasm *a)
{
    a->active = 0;
    a->expect_valid = 0;
}

void transport_reasm_abort(struct transport_reasm *a)
{
    if (a->active)
        a->st->dropped_incomplete++;
    a->active = 0;
}

int transport_reasm_check(struct transport_reasm *a, size_t len, struct codec_packet *p)
{
    if (codec_packet_parse(a->buf, len, p, NULL) < 0 || p->size != len) {
        a->st->dropped_corrupt++;
        return 1;
    }
    a->st->packets++;
    a->st->bytes += len;
    return 0;
}

int transport_reasm_push(struct transport_reasm *a, const uint8_t *m, size_t n, struct codec_packet *p)
{
    struct transport_stats *st = a->st;
    if (n < TRANSPORT_CHUNK_HEADER || get_u32(m) != TRANSPORT_CHUNK_MAGIC) {
        st->chunks_bad++;
        return 1;
    }
    uint32_t seq = get_u32(m + 4), total = get_u32(m + 8), index = get_u16(m + 12), count = get_u16(m + 14);
    if (total == 0 && count == 0 && index == 0 && n == TRANSPORT_CHUNK_HEADER)
        return 1; /* a tail probe */
    if (total < CODEC_PACKET_HEADER || count == 0 || index >= count || count > total) {
        st->chunks_bad++;
        return 1;
    }
    uint32_t stride = (uint32_t)(((uint64_t)total + count - 1) / count);
    uint64_t off = (uint64_t)index * stride;
    uint64_t len = off < total ? (total - off < stride ? total - off : stride) : 0;
    if (off >= total || n - TRANSPORT_CHUNK_HEADER != len) {
        st->chunks_bad++;
        return 1;
    }
    st->chunks++;
    if (a->active && seq != a->seq)
        transport_reasm_abort(a);
    if (!a->active) {
        if (a->expect_valid) {
            int32_t gap = (int32_t)(seq - a->expect);
            if (gap > 0 && gap < (1 << 20))
                st->missing += (uint64_t)gap;
            else if (gap < 0 && gap > -4)
                return 1; /* a chunk of a packet already handed on or dropped */
        }
        a->expect_valid = 1;
        a->expect = seq + 1;
        if (total > a->max_packet || count > a->have_cap) {
            st->dropped_oversize++; /* its later chunks fall in the branch above */
            return 1;
        }
        a->active = 1;
        a->seq = seq;
        a->total = total;
        a->count = count;
        a->got = 0;
        memset(a->have, 0, (count + 7) / 8);
    } else if (total != a->total || count != a->count) {
        st->chunks_bad++;
        return 1;
    }
    if (a->have[index >> 3] & (1u << (index & 7)))
        return 1; /* duplicate */
    a->have[index >> 3] |= (uint8_t)(1u << (index & 7));
    memcpy(a->buf + off, m + TRANSPORT_CHUNK_HEADER, (size_t)len);
    if (++a->got < a->count)
        return 1;
    a->active = 0;
    return transport_reasm_check(a, a->total, p);
}
