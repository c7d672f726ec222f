/* fuzz_chunks.c - libFuzzer harness for the SRT receiver's chunk reassembler
 * (firmware/stream/transport/reasm.c): the input is a sequence of SRT messages
 * as [u16 little-endian length][bytes]; every completed packet must be a
 * CRC-valid packet inside the planned buffer, and is fed to a decoder. */
#include <stddef.h>
#include <stdint.h>

#include "transport_internal.h"

#define FUZZ_MAX_PACKET 65536

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    static codec_dec *d;
    static struct transport_stats st;
    static struct transport_reasm a;
    if (!d && (codec_dec_new(4096, &d, NULL) < 0 || transport_reasm_init(&a, FUZZ_MAX_PACKET, &st, NULL) < 0))
        return 0;
    transport_reasm_reset(&a);
    for (size_t off = 0; off + 2 <= size;) {
        size_t n = (size_t)data[off] | (size_t)data[off + 1] << 8;
        off += 2;
        if (n > size - off)
            n = size - off;
        struct codec_packet p;
        if (transport_reasm_push(&a, data + off, n, &p) == 0) {
            if (p.size > FUZZ_MAX_PACKET || p.payload != a.buf + CODEC_PACKET_HEADER ||
                codec_packet_parse(a.buf, p.size, &p, NULL) < 0)
                __builtin_trap();
            codec_dec_packet(d, &p);
        }
        off += n;
    }
    transport_reasm_abort(&a);
    return 0;
}
