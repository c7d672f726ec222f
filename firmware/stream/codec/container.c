/* container.c - packets: header, CRC32, parse and resync. */
#include <zlib.h>

#include "codec_internal.h"

uint32_t codec__packet_crc(const uint8_t *hdr, const uint8_t *payload, size_t n)
{
    uLong c = crc32(0L, Z_NULL, 0);
    c = crc32(c, hdr, 28);
    while (n > 0) { /* zlib takes uInt lengths */
        uInt k = n > (1u << 30) ? (1u << 30) : (uInt)n;
        c = crc32(c, payload, k);
        payload += k;
        n -= k;
    }
    return (uint32_t)c;
}

size_t codec_packet_bound(size_t capacity)
{
    /* frame header + quantizers + per plane (tag, length, zstd bound of 4 bytes
     * per Gaussian) for 20 residual + 20 intra + flag + index planes. */
    size_t per = 4 * capacity;
    size_t zb = per + (per >> 8) + 512; /* >= ZSTD_compressBound(per) */
    return CODEC_PACKET_HEADER + 256 + 42 * (5 + zb);
}

int codec_packet_write(uint8_t *out, size_t cap, int type, uint32_t seq, uint32_t ref_seq, uint64_t t_us,
                       const uint8_t *payload, size_t payload_len, size_t *len, struct f4d_err *err)
{
    if (!out || (!payload && payload_len))
        return f4d_fail(err, F4D_EINVAL, "codec_packet_write: NULL buffer");
    if (payload_len > CODEC_PAYLOAD_MAX)
        return f4d_fail(err, F4D_ERANGE, "codec_packet_write: payload of %zu bytes exceeds %u", payload_len,
                        CODEC_PAYLOAD_MAX);
    if (cap < CODEC_PACKET_HEADER + payload_len)
        return f4d_fail(err, F4D_ERANGE, "codec_packet_write: %zu bytes do not hold a packet of %zu", cap,
                        CODEC_PACKET_HEADER + payload_len);
    if (payload && payload != out + CODEC_PACKET_HEADER)
        memmove(out + CODEC_PACKET_HEADER, payload, payload_len);
    codec__put_u32(out, CODEC_PACKET_MAGIC);
    out[4] = CODEC_VERSION;
    out[5] = (uint8_t)type;
    codec__put_u16(out + 6, 0);
    codec__put_u32(out + 8, seq);
    codec__put_u32(out + 12, ref_seq);
    codec__put_u64(out + 16, t_us);
    codec__put_u32(out + 24, (uint32_t)payload_len);
    codec__put_u32(out + 28, codec__packet_crc(out, out + CODEC_PACKET_HEADER, payload_len));
    *len = CODEC_PACKET_HEADER + payload_len;
    return F4D_OK;
}

int codec_packet_parse(const uint8_t *buf, size_t len, struct codec_packet *p, struct f4d_err *err)
{
    if (!buf || !p)
        return f4d_fail(err, F4D_EINVAL, "codec_packet_parse: NULL argument");
    if (len < CODEC_PACKET_HEADER)
        return f4d_fail(err, F4D_EEOF, "packet: %zu bytes, the header needs %d", len, CODEC_PACKET_HEADER);
    if (codec__u32(buf) != CODEC_PACKET_MAGIC)
        return f4d_fail(err, F4D_EFORMAT, "packet: bad magic 0x%08x", codec__u32(buf));
    if (buf[4] < 1 || buf[4] > CODEC_VERSION)
        return f4d_fail(err, F4D_EFORMAT, "packet: version %u, this build reads 1..%d", buf[4], CODEC_VERSION);
    if (buf[5] < CODEC_PKT_STREAM || buf[5] > CODEC_PKT_END)
        return f4d_fail(err, F4D_EFORMAT, "packet: unknown type %u", buf[5]);
    if (codec__u16(buf + 6) != 0)
        return f4d_fail(err, F4D_EFORMAT, "packet: unknown flags 0x%04x", codec__u16(buf + 6));
    uint32_t n = codec__u32(buf + 24);
    if (n > CODEC_PAYLOAD_MAX)
        return f4d_fail(err, F4D_EFORMAT, "packet: payload length %u exceeds %u", n, CODEC_PAYLOAD_MAX);
    if (len - CODEC_PACKET_HEADER < n)
        return f4d_fail(err, F4D_EEOF, "packet: truncated, %zu of %u payload bytes", len - CODEC_PACKET_HEADER, n);
    uint32_t crc = codec__packet_crc(buf, buf + CODEC_PACKET_HEADER, n);
    if (crc != codec__u32(buf + 28))
        return f4d_fail(err, F4D_ECORRUPT, "packet seq %u: CRC 0x%08x, header says 0x%08x", codec__u32(buf + 8),
                        crc, codec__u32(buf + 28));
    p->type = buf[5];
    p->version = buf[4];
    p->seq = codec__u32(buf + 8);
    p->ref_seq = codec__u32(buf + 12);
    p->t_us = codec__u64(buf + 16);
    p->payload = buf + CODEC_PACKET_HEADER;
    p->payload_len = n;
    p->size = CODEC_PACKET_HEADER + (size_t)n;
    return F4D_OK;
}

size_t codec_packet_resync(const uint8_t *buf, size_t len)
{
    for (size_t i = 1; i + 4 <= len; i++)
        if (codec__u32(buf + i) == CODEC_PACKET_MAGIC)
            return i;
    return len;
}
