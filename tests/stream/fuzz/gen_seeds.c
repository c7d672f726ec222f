/* gen_seeds.c - writes the fuzz seed corpora: OUT/packets/ (small streams:
 * header, intra, predicted with block motion, end, per level; one written
 * as version 2, one in stream order at the fast effort) and OUT/frame/ (selector byte + payload:
 * intra, predicted against fuzz_frame(0), SPZ). */
#include <stdio.h>
#include <stdlib.h>

#include "fuzz_common.h"

static int put(const char *dir, const char *name, uint8_t sel, int with_sel, const uint8_t *b, size_t n)
{
    char path[1024];
    snprintf(path, sizeof path, "%s/%s", dir, name);
    FILE *f = fopen(path, "wb");
    if (!f)
        return -1;
    if (with_sel)
        fputc(sel, f);
    fwrite(b, 1, n, f);
    return fclose(f);
}

int main(int argc, char **argv)
{
    if (argc != 3) {
        fprintf(stderr, "usage: gen_seeds PACKETS_DIR FRAME_DIR\n");
        return 2;
    }
    struct splat_frame f0 = { 0 }, f1 = { 0 };
    if (fuzz_frame(0, &f0) || fuzz_frame(1, &f1))
        return 1;
    /* every level at the current version, compact written as version 2, and
     * compact in stream order at the fast effort (intra in Morton order,
     * forced block motion) */
    for (int q = 0; q <= CODEC_QUALITY_COUNT + 1; q++) {
        codec_enc *e;
        int v2 = q == CODEC_QUALITY_COUNT, so = q == CODEC_QUALITY_COUNT + 1;
        if (codec_enc_new(FUZZ_N + 8, v2 || so ? CODEC_Q_COMPACT : (enum codec_quality)q, &e, NULL) < 0 ||
            (v2 && codec_enc_set_version(e, 2) < 0) ||
            (so && (codec_enc_set_reorder(e, 1) < 0 || codec_enc_set_effort(e, CODEC_EFFORT_FAST) < 0)))
            return 1;
        size_t cap = codec_packet_bound(FUZZ_N + 8), len = 0, n;
        uint8_t *s = malloc(4 * cap);
        int rc = codec_enc_stream_header(e, 0, s, cap, &n);
        len += n;
        size_t k0 = len;
        rc |= codec_enc_key(e, &f0, 0, CODEC_KEY_INTRA, NULL, s + len, cap, &n);
        size_t k0n = n;
        len += n;
        size_t k1 = len;
        rc |= codec_enc_key(e, &f1, 100000, CODEC_KEY_AUTO, NULL, s + len, cap, &n);
        size_t k1n = n;
        len += n;
        rc |= codec_enc_end(e, 200000, s + len, cap, &n);
        len += n;
        if (rc)
            return 1;
        char name[64];
        snprintf(name, sizeof name, v2 ? "stream_v2" : so ? "stream_order" : "stream_q%d", q);
        if (!v2 && (s[k1 + CODEC_PACKET_HEADER + 2] & 4) == 0) {
            fprintf(stderr, "gen_seeds: level %d: the predicted key sends no block motion to seed\n", q);
            return 1;
        }
        if (put(argv[1], name, 0, 0, s, len))
            return 1;
        if (q == CODEC_Q_MEDIUM) { /* the harness's primed key is medium */
            if (put(argv[2], "intra", 0, 1, s + k0 + CODEC_PACKET_HEADER, k0n - CODEC_PACKET_HEADER) ||
                put(argv[2], "pred", 1, 1, s + k1 + CODEC_PACKET_HEADER, k1n - CODEC_PACKET_HEADER))
                return 1;
        }
        free(s);
        codec_enc_free(e);
    }
    uint8_t *z;
    size_t zn;
    if (codec_spz_encode(&f0, &z, &zn, NULL) || put(argv[2], "spz", 2, 1, z, zn))
        return 1;
    free(z);
    if (codec_spz_encode_version(&f0, 3, &z, &zn, NULL) || put(argv[2], "spz3", 2, 1, z, zn))
        return 1;
    free(z);
    splat_frame_free(&f0);
    splat_frame_free(&f1);
    return 0;
}
