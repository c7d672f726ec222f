/* fuzz_packets.c - libFuzzer harness: the input is a byte stream as a
 * receiver sees it (a file, or SRT payloads back to back): packets are parsed
 * with resync on anything malformed and fed to one decoder. */
#include <stddef.h>
#include <stdint.h>

#include "fuzz_common.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    static codec_dec *d;
    if (!d && codec_dec_new(FUZZ_CAP, &d, NULL) < 0)
        return 0;
    size_t off = 0;
    while (off < size) {
        struct codec_packet p;
        int rc = codec_packet_parse(data + off, size - off, &p, NULL);
        if (rc == F4D_EEOF)
            break;
        if (rc < 0) {
            off += codec_packet_resync(data + off, size - off);
            continue;
        }
        if (codec_dec_packet(d, &p) == 1) {
            const struct splat_frame *f = codec_dec_frame(d);
            if (!f || f->count > FUZZ_CAP || splat_frame_validate(f, NULL) < 0)
                __builtin_trap();
        }
        off += p.size;
    }
    return 0;
}
