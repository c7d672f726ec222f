/* gen_chunk_seeds.c - seeds for fuzz_chunks: a small stream (header, intra,
 * predicted, end of tests/stream/fuzz's frames) cut into chunks as the
 * sender does, at payload 1316 and 64, and once with a chunk missing; each
 * as [u16 length][message] records. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "f4d_transport.h"
#include "fuzz_common.h"

static void put16(FILE *f, size_t v) { fputc((int)(v & 255), f); fputc((int)(v >> 8), f); }
static void put32(uint8_t *p, uint32_t v) { for (int i = 0; i < 4; i++) p[i] = (uint8_t)(v >> (8 * i)); }

/* Writes the packets of s[0..len) as chunks of `payload` bytes; skips the
 * chunk numbered `lose` (counting all chunks), -1 for none. */
static int write_seed(const char *dir, const char *name, const uint8_t *s, size_t len, size_t payload, long lose)
{
    char path[1024];
    snprintf(path, sizeof path, "%s/%s", dir, name);
    FILE *f = fopen(path, "wb");
    if (!f)
        return -1;
    long k = 0;
    for (size_t off = 0; off < len;) {
        struct codec_packet p;
        if (codec_packet_parse(s + off, len - off, &p, NULL) < 0)
            return -1;
        size_t data = payload - TRANSPORT_CHUNK_HEADER, count = (p.size + data - 1) / data;
        size_t stride = (p.size + count - 1) / count;
        for (size_t i = 0; i < count; i++, k++) {
            size_t o = i * stride, n = p.size - o < stride ? p.size - o : stride;
            uint8_t h[TRANSPORT_CHUNK_HEADER];
            put32(h, TRANSPORT_CHUNK_MAGIC);
            put32(h + 4, p.seq);
            put32(h + 8, (uint32_t)p.size);
            h[12] = (uint8_t)i, h[13] = (uint8_t)(i >> 8), h[14] = (uint8_t)count, h[15] = (uint8_t)(count >> 8);
            if (k == lose)
                continue;
            put16(f, TRANSPORT_CHUNK_HEADER + n);
            fwrite(h, 1, sizeof h, f);
            fwrite(s + off + o, 1, n, f);
        }
        uint8_t probe[TRANSPORT_CHUNK_HEADER] = { 0 };
        put32(probe, TRANSPORT_CHUNK_MAGIC);
        put32(probe + 4, p.seq);
        put16(f, sizeof probe);
        fwrite(probe, 1, sizeof probe, f);
        off += p.size;
    }
    return fclose(f);
}

int main(int argc, char **argv)
{
    if (argc != 2) {
        fprintf(stderr, "usage: gen_chunk_seeds DIR\n");
        return 2;
    }
    struct splat_frame f0 = { 0 }, f1 = { 0 };
    codec_enc *e;
    if (fuzz_frame(0, &f0) || fuzz_frame(1, &f1) || codec_enc_new(FUZZ_N + 8, CODEC_Q_LOW, &e, NULL) < 0)
        return 1;
    size_t cap = codec_packet_bound(FUZZ_N + 8), len = 0, n;
    uint8_t *s = malloc(4 * cap);
    int rc = codec_enc_stream_header(e, 0, s, cap, &n);
    len += n;
    rc |= codec_enc_key(e, &f0, 0, CODEC_KEY_INTRA, NULL, s + len, cap, &n);
    len += n;
    rc |= codec_enc_key(e, &f1, 100000, CODEC_KEY_AUTO, NULL, s + len, cap, &n);
    len += n;
    rc |= codec_enc_end(e, 200000, s + len, cap, &n);
    len += n;
    if (rc || write_seed(argv[1], "payload1316", s, len, 1316, -1) || write_seed(argv[1], "payload64", s, len, 64, -1) ||
        write_seed(argv[1], "payload64_lost", s, len, 64, 5))
        return 1;
    free(s);
    codec_enc_free(e);
    splat_frame_free(&f0);
    splat_frame_free(&f1);
    return 0;
}
