/* fuzz_frame.c - libFuzzer harness: the frame decoder and SPZ reader behind a
 * valid packet. Byte 0 selects: 0 an intra payload, 1 a predicted payload
 * against the primed key (fuzz_frame(0)), 2 an SPZ file; the rest is the
 * payload. Every decoded frame must validate (finite, opacity in [0,1]). */
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>

#include "fuzz_common.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

static codec_dec *d;
static uint8_t *key_pkt, *buf;
static size_t key_len, buf_cap;

static int init(void)
{
    codec_enc *e;
    struct splat_frame f = { 0 };
    if (codec_dec_new(FUZZ_CAP, &d, NULL) < 0 || codec_enc_new(FUZZ_N, CODEC_Q_MEDIUM, &e, NULL) < 0 ||
        fuzz_frame(0, &f) < 0)
        return -1;
    size_t cap = codec_packet_bound(FUZZ_N);
    key_pkt = malloc(cap);
    if (!key_pkt || codec_enc_key(e, &f, 0, CODEC_KEY_INTRA, NULL, key_pkt, cap, &key_len) < 0)
        return -1;
    codec_enc_free(e);
    splat_frame_free(&f);
    return 0;
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    if (!d && init() < 0)
        __builtin_trap();
    if (size < 1)
        return 0;
    if (data[0] == 2) {
        struct splat_frame f = { 0 };
        if (codec_spz_decode(data + 1, size - 1, &f, NULL) == 0 && splat_frame_validate(&f, NULL) < 0)
            __builtin_trap();
        splat_frame_free(&f);
        return 0;
    }
    if (buf_cap < size + CODEC_PACKET_HEADER) {
        free(buf);
        buf_cap = size + CODEC_PACKET_HEADER;
        buf = malloc(buf_cap);
    }
    struct codec_packet p;
    if (codec_packet_parse(key_pkt, key_len, &p, NULL) < 0 || codec_dec_packet(d, &p) != 1)
        __builtin_trap();
    size_t n;
    int pred = data[0] & 1;
    if (codec_packet_write(buf, buf_cap, pred ? CODEC_PKT_PRED : CODEC_PKT_INTRA, p.seq + 1, pred ? p.seq : p.seq + 1,
                           1, data + 1, size - 1, &n, NULL) < 0 ||
        codec_packet_parse(buf, n, &p, NULL) < 0)
        __builtin_trap();
    if (codec_dec_packet(d, &p) == 1) {
        const struct splat_frame *f = codec_dec_frame(d);
        if (!f || splat_frame_validate(f, NULL) < 0)
            __builtin_trap();
    }
    return 0;
}
