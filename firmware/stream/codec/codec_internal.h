/* codec_internal.h - helpers shared by the codec sources (not installed). */
#ifndef F4D_CODEC_INTERNAL_H
#define F4D_CODEC_INTERNAL_H

#include <stdint.h>
#include <string.h>

#include "f4d_codec.h"

static inline void codec__put_u16(uint8_t *p, uint16_t v) { p[0] = (uint8_t)v; p[1] = (uint8_t)(v >> 8); }
static inline void codec__put_u32(uint8_t *p, uint32_t v)
{
    p[0] = (uint8_t)v; p[1] = (uint8_t)(v >> 8); p[2] = (uint8_t)(v >> 16); p[3] = (uint8_t)(v >> 24);
}
static inline void codec__put_u64(uint8_t *p, uint64_t v)
{
    codec__put_u32(p, (uint32_t)v);
    codec__put_u32(p + 4, (uint32_t)(v >> 32));
}
static inline void codec__put_f32(uint8_t *p, float f)
{
    uint32_t v;
    memcpy(&v, &f, 4);
    codec__put_u32(p, v);
}
static inline uint16_t codec__u16(const uint8_t *p) { return (uint16_t)(p[0] | p[1] << 8); }
static inline uint32_t codec__u32(const uint8_t *p)
{
    return (uint32_t)p[0] | (uint32_t)p[1] << 8 | (uint32_t)p[2] << 16 | (uint32_t)p[3] << 24;
}
static inline uint64_t codec__u64(const uint8_t *p) { return codec__u32(p) | (uint64_t)codec__u32(p + 4) << 32; }
static inline float codec__f32(const uint8_t *p)
{
    uint32_t v = codec__u32(p);
    float f;
    memcpy(&f, &v, 4);
    return f;
}

/* CRC32 (zlib's polynomial) of the packet header bytes 0..27 and the payload. */
uint32_t codec__packet_crc(const uint8_t *hdr, const uint8_t *payload, size_t n);

#endif
