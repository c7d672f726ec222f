/* f4d_codec_tool.c - f4d-codec: encode / decode / info on INRIA PLY, SPZ and
 * our stream files (.f4ds: packets back to back, see f4d_codec.h).
 *
 *   f4d-codec encode IN.ply|IN.spz... -o OUT.f4ds [--quality compact|low|medium|high]
 *                    [--key-rate HZ] [--intra-every N]
 *   f4d-codec encode IN.ply -o OUT.spz        (or IN.spz -o OUT.ply: conversion)
 *   f4d-codec decode IN.f4ds -o OUT.ply|OUT.spz [--frame K]   (K-th key, default 0)
 *   f4d-codec decode IN.f4ds -o 'DIR/key_%04d.ply'            (every key)
 *   f4d-codec info FILE...
 *   --spz-version 3|4: the SPZ version written (default 4, the current one).
 *   --motion-from-keys: motions re-derived over the key interval from the
 *     keys' own positions (takes whose Gaussians keep their index, keyed
 *     below their frame rate: their motions span one frame, not one key).
 *   --stream-order: keys coded in the encoder's order (codec_enc_set_reorder:
 *     an intra key in Morton order where smaller); decoded Gaussians come out
 *     in that order.
 *   --effort fast|default|max: the encoder's search (codec_enc_set_effort).
 * The file kind comes from its first bytes (F4DP, gzip / NGSP, "ply"). */
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "f4d_codec.h"

enum kind { K_NONE, K_PLY, K_SPZ, K_STREAM };

static void usage(FILE *f)
{
    fprintf(f, "usage: f4d-codec encode IN.ply|IN.spz... -o OUT.f4ds|OUT.spz|OUT.ply [--quality compact|low|medium|high]\n"
               "                        [--key-rate HZ] [--intra-every N] [--spz-version 3|4] [--motion-from-keys]\n"
               "                        [--stream-order] [--effort fast|default|max]\n"
               "       f4d-codec decode IN.f4ds|IN.spz|IN.ply -o OUT.ply|OUT.spz|'OUT_%%04d.ply' [--frame K]\n"
               "       f4d-codec info FILE...\n");
}

static int slurp(const char *path, uint8_t **buf, size_t *len)
{
    FILE *f = fopen(path, "rb");
    if (!f) {
        fprintf(stderr, "f4d-codec: cannot open '%s': %s\n", path, strerror(errno));
        return -1;
    }
    size_t cap = 1 << 16, n = 0;
    uint8_t *b = malloc(cap);
    for (;;) {
        if (!b) {
            fclose(f);
            fprintf(stderr, "f4d-codec: '%s': out of memory\n", path);
            return -1;
        }
        n += fread(b + n, 1, cap - n, f);
        if (n < cap)
            break;
        cap *= 2;
        uint8_t *nb = realloc(b, cap);
        if (!nb)
            free(b);
        b = nb;
    }
    int bad = ferror(f);
    fclose(f);
    if (bad) {
        free(b);
        fprintf(stderr, "f4d-codec: read error on '%s'\n", path);
        return -1;
    }
    *buf = b;
    *len = n;
    return 0;
}

static enum kind kind_of_bytes(const uint8_t *b, size_t n)
{
    if (n >= 4 && b[0] == 0x46 && b[1] == 0x34 && b[2] == 0x44 && b[3] == 0x50)
        return K_STREAM;
    if ((n >= 2 && b[0] == 0x1f && b[1] == 0x8b) || (n >= 4 && !memcmp(b, "NGSP", 4)))
        return K_SPZ;
    if (n >= 4 && !memcmp(b, "ply", 3))
        return K_PLY;
    return K_NONE;
}

static enum kind kind_of_name(const char *p)
{
    const char *d = strrchr(p, '.');
    if (!d)
        return K_NONE;
    return !strcmp(d, ".ply") ? K_PLY : !strcmp(d, ".spz") ? K_SPZ : !strcmp(d, ".f4ds") ? K_STREAM : K_NONE;
}

static int read_frame(const char *path, struct splat_frame *f)
{
    uint8_t *b;
    size_t n;
    if (slurp(path, &b, &n) < 0)
        return -1;
    enum kind k = kind_of_bytes(b, n);
    struct f4d_err err = { 0 };
    int rc;
    if (k == K_SPZ)
        rc = codec_spz_decode(b, n, f, &err);
    else if (k == K_PLY)
        rc = splat_ply_read(path, f, &err);
    else
        rc = f4d_fail(&err, F4D_EFORMAT, "not a PLY or SPZ file (first bytes %02x %02x %02x %02x)", n > 0 ? b[0] : 0,
                      n > 1 ? b[1] : 0, n > 2 ? b[2] : 0, n > 3 ? b[3] : 0);
    free(b);
    if (rc < 0)
        fprintf(stderr, "f4d-codec: '%s': %s\n", path, err.msg);
    return rc;
}

/* spz_version: 4 (current) or 3 (gzip). */
static int write_spz(const char *path, const struct splat_frame *f, int spz_version, struct f4d_err *err)
{
    uint8_t *b;
    size_t n;
    int rc = codec_spz_encode_version(f, spz_version, &b, &n, err);
    if (rc < 0)
        return rc;
    FILE *fp = fopen(path, "wb");
    if (!fp) {
        free(b);
        return f4d_fail(err, F4D_EIO, "cannot create: %s", strerror(errno));
    }
    size_t w = fwrite(b, 1, n, fp);
    free(b);
    if (fclose(fp) != 0 || w != n)
        return f4d_fail(err, F4D_EIO, "write failed");
    return F4D_OK;
}

static int write_frame(const char *path, const struct splat_frame *f, int spz_version)
{
    struct f4d_err err = { 0 };
    enum kind k = kind_of_name(path);
    int rc = k == K_SPZ ? write_spz(path, f, spz_version, &err)
           : k == K_PLY ? splat_ply_write(path, f, &err)
                        : f4d_fail(&err, F4D_EINVAL, "output must end in .ply or .spz");
    if (rc < 0)
        fprintf(stderr, "f4d-codec: '%s': %s\n", path, err.msg);
    return rc;
}

/* --motion-from-keys: the take's motions may span a shorter step than the
 * key interval (a 30 fps take keyed every third frame); for Gaussians that
 * keep their index, motion_fwd = next key - this key and motion_bwd =
 * previous key - this key (first / last key: the one side mirrored). *prev
 * (grown here) keeps this key's positions for the next call. */
static int keyed_motion(struct splat_frame *f, const float *prev_pos, const struct splat_frame *next, float **prev,
                        const char *name)
{
    size_t n = f->count;
    if ((next && next->count != n) || (!prev_pos && !next)) {
        fprintf(stderr, "f4d-codec: '%s': --motion-from-keys needs keys of the same Gaussians (%zu, next %zu)\n",
                name, n, next ? next->count : 0);
        return -1;
    }
    struct f4d_err err = { 0 };
    if (!f->motion_fwd && splat_frame_resize(f, n, 1, &err) < 0) {
        fprintf(stderr, "f4d-codec: '%s': %s\n", name, err.msg);
        return -1;
    }
    for (size_t i = 0; i < 3 * n; i++) {
        float fw = next ? next->pos[i] - f->pos[i] : f->pos[i] - prev_pos[i];
        float bw = prev_pos ? prev_pos[i] - f->pos[i] : -fw;
        f->motion_fwd[i] = fw;
        f->motion_bwd[i] = bw;
    }
    float *p = realloc(*prev, (n > 0 ? 3 * n : 1) * sizeof(float));
    if (!p) {
        fprintf(stderr, "f4d-codec: out of memory\n");
        return -1;
    }
    memcpy(p, f->pos, 3 * n * sizeof(float));
    *prev = p;
    return 0;
}

static int do_encode(const char **in, int nin, const char *out, int quality, double rate, int intra_every,
                     int spz_version, int motion_from_keys, int stream_order, int effort)
{
    struct splat_frame nx = { 0 };
    float *prev = NULL;
    enum kind ko = kind_of_name(out);
    struct splat_frame f = { 0 };
    if (ko != K_STREAM) {
        if (nin != 1) {
            fprintf(stderr, "f4d-codec: '%s': a PLY or SPZ output takes one input, %d given\n", out, nin);
            return 1;
        }
        int rc = read_frame(in[0], &f) < 0 || write_frame(out, &f, spz_version) < 0;
        splat_frame_free(&f);
        return rc;
    }
    /* first pass: the largest frame plans the encoder */
    size_t cap = 0;
    for (int i = 0; i < nin; i++) {
        if (read_frame(in[i], &f) < 0) {
            splat_frame_free(&f);
            return 1;
        }
        cap = f.count > cap ? f.count : cap;
    }
    codec_enc *e = NULL;
    struct f4d_err err = { 0 };
    if (codec_enc_new(cap, (enum codec_quality)quality, &e, &err) < 0 ||
        (stream_order && codec_enc_set_reorder(e, 1) < 0) || codec_enc_set_effort(e, effort) < 0) {
        fprintf(stderr, "f4d-codec: %s\n", e ? codec_enc_error(e) : err.msg);
        codec_enc_free(e);
        splat_frame_free(&f);
        return 1;
    }
    size_t pcap = codec_packet_bound(cap), n, total = 0;
    uint8_t *pkt = malloc(pcap);
    FILE *fo = fopen(out, "wb");
    int rc = 0;
    if (!pkt || !fo) {
        fprintf(stderr, "f4d-codec: cannot create '%s': %s\n", out, strerror(errno));
        rc = 1;
        goto done;
    }
    if (codec_enc_stream_header(e, 0, pkt, pcap, &n) < 0 || fwrite(pkt, 1, n, fo) != n)
        goto io;
    total += n;
    for (int i = 0; i < nin; i++) {
        if (!motion_from_keys) {
            if (read_frame(in[i], &f) < 0) {
                rc = 1;
                goto done;
            }
        } else {
            /* f = key i, nx = key i + 1 (read ahead), prev = key i - 1's positions */
            if (i == 0 && read_frame(in[0], &nx) < 0) {
                rc = 1;
                goto done;
            }
            struct splat_frame tmp = f;
            f = nx;
            nx = tmp;
            if (i + 1 < nin && read_frame(in[i + 1], &nx) < 0) {
                rc = 1;
                goto done;
            }
            if (keyed_motion(&f, i > 0 ? prev : NULL, i + 1 < nin ? &nx : NULL, &prev, in[i]) < 0) {
                rc = 1;
                goto done;
            }
        }
        uint64_t t = (uint64_t)((double)i * 1e6 / rate + 0.5);
        /* one frame alone: a still key (Morton-reordered, smaller) */
        enum codec_key_mode m = nin == 1 ? CODEC_KEY_STILL
                                : (intra_every > 0 && i % intra_every == 0) ? CODEC_KEY_INTRA : CODEC_KEY_AUTO;
        if (codec_enc_key(e, &f, t, m, NULL, pkt, pcap, &n) < 0) {
            fprintf(stderr, "f4d-codec: '%s': %s\n", in[i], codec_enc_error(e));
            rc = 1;
            goto done;
        }
        if (fwrite(pkt, 1, n, fo) != n)
            goto io;
        total += n;
        const struct codec_enc_stats *st = codec_enc_last(e);
        printf("%s: %s key, %zu Gaussians, %zu bytes (%.2f B/G; %zu unchanged, %zu new, %zu dropped)\n", in[i],
               st->intra ? "intra" : "predicted", st->count, n, st->count ? (double)n / (double)st->count : 0.0,
               st->unchanged, st->fresh, st->dropped);
        /* where the bytes went: flags / match list, then every channel */
        printf("  bytes: header %zu, flags %zu, match %zu, blocks %zu", st->bytes_header, st->bytes_flags,
               st->bytes_match, st->bytes_blocks);
        for (int c = 0; c < CODEC_CHANNELS; c++)
            if (st->bytes_channel[c])
                printf(", %s %zu", codec_channel_name(c), st->bytes_channel[c]);
        if (!st->intra)
            printf("; predictor %.3g %.3g / %.3g %.3g / %.3g %.3g %.3g", (double)st->predictor[0],
                   (double)st->predictor[1], (double)st->predictor[2], (double)st->predictor[3],
                   (double)st->predictor[4], (double)st->predictor[5], (double)st->predictor[6]);
        printf("\n");
    }
    if (codec_enc_end(e, (uint64_t)((double)nin * 1e6 / rate), pkt, pcap, &n) < 0 || fwrite(pkt, 1, n, fo) != n)
        goto io;
    total += n;
    printf("%s: %d keys, %zu bytes, %s quality\n", out, nin, total + n, codec_quality_get(quality)->name);
    goto done;
io:
    fprintf(stderr, "f4d-codec: write to '%s' failed\n", out);
    rc = 1;
done:
    if (fo && fclose(fo) != 0 && rc == 0) {
        fprintf(stderr, "f4d-codec: write to '%s' failed\n", out);
        rc = 1;
    }
    free(pkt);
    free(prev);
    codec_enc_free(e);
    splat_frame_free(&f);
    splat_frame_free(&nx);
    return rc;
}

/* Expands the one %d / %0Nd of an output pattern. */
static int pattern_name(const char *pat, int k, char *out, size_t n)
{
    const char *p = strchr(pat, '%');
    if (!p)
        return -1;
    const char *q = p + 1;
    int width = 0;
    while (*q >= '0' && *q <= '9' && width < 100)
        width = width * 10 + (*q++ - '0');
    if (*q != 'd' || strchr(q, '%'))
        return -1;
    int w = snprintf(out, n, "%.*s%0*d%s", (int)(p - pat), pat, width, k, q + 1);
    return w < 0 || (size_t)w >= n ? -1 : 0;
}

/* Walks the packets of a stream file: decodes keys (when d) and prints them
 * (when verbose). Returns the number of keys decoded, -1 on error. */
static int walk_stream(const char *path, const uint8_t *b, size_t len, codec_dec *d, int verbose, long want,
                       const char *pattern, int spz_version)
{
    size_t off = 0, bad = 0, keys = 0, gaussians = 0, key_bytes = 0;
    while (off < len) {
        struct codec_packet p;
        struct f4d_err err = { 0 };
        int rc = codec_packet_parse(b + off, len - off, &p, &err);
        if (rc < 0) {
            fprintf(stderr, "f4d-codec: '%s': byte %zu: %s\n", path, off, err.msg);
            if (rc == F4D_EEOF)
                break;
            bad++;
            off += codec_packet_resync(b + off, len - off);
            continue;
        }
        static const char *names[] = { "?", "stream", "intra", "predicted", "end" };
        size_t count = p.payload_len >= 8 && p.type >= CODEC_PKT_INTRA && p.type <= CODEC_PKT_PRED
                           ? (size_t)(p.payload[4] | p.payload[5] << 8 | p.payload[6] << 16 | (size_t)p.payload[7] << 24)
                           : 0;
        if (verbose)
            printf("  seq %6u  %-9s  t %10.3f ms  %9zu bytes%s", p.seq, names[p.type], (double)p.t_us / 1000.0,
                   p.size, count ? "" : "\n");
        if (count && verbose)
            printf("  %8zu Gaussians  %6.2f B/G\n", count, (double)p.size / (double)count);
        if (p.type == CODEC_PKT_INTRA || p.type == CODEC_PKT_PRED) {
            gaussians += count;
            key_bytes += p.size;
        }
        if (d) {
            rc = codec_dec_packet(d, &p);
            if (rc < 0)
                fprintf(stderr, "f4d-codec: '%s': %s\n", path, codec_dec_error(d));
            if (rc == 1) {
                if (pattern) {
                    char name[4096];
                    if (pattern_name(pattern, (int)keys, name, sizeof name) < 0) {
                        fprintf(stderr, "f4d-codec: -o '%s': the pattern takes one %%d or %%0Nd\n", pattern);
                        return -1;
                    }
                    if (write_frame(name, codec_dec_frame(d), spz_version) < 0)
                        return -1;
                } else if ((long)keys == want) {
                    return (int)keys + 1;
                }
                keys++;
            }
        } else if (count) {
            keys++;
        }
        off += p.size;
    }
    if (verbose)
        printf("  %zu keys, %.2f B/G on average, %zu bytes skipped as malformed\n", keys,
               gaussians ? (double)key_bytes / (double)gaussians : 0.0, bad);
    return (int)keys;
}

static int do_decode(const char *in, const char *out, long frame, int spz_version)
{
    uint8_t *b;
    size_t n;
    if (slurp(in, &b, &n) < 0)
        return 1;
    enum kind k = kind_of_bytes(b, n);
    if (k != K_STREAM) {
        free(b);
        return do_encode(&in, 1, out, CODEC_Q_MEDIUM, 10.0, 0, spz_version, 0, 0, CODEC_EFFORT_DEFAULT); /* PLY <-> SPZ */
    }
    codec_dec *d;
    struct f4d_err err = { 0 };
    if (codec_dec_new(CODEC_CAPACITY_MAX, &d, &err) < 0) {
        fprintf(stderr, "f4d-codec: %s\n", err.msg);
        free(b);
        return 1;
    }
    const char *pattern = strchr(out, '%') ? out : NULL;
    int keys = walk_stream(in, b, n, d, 0, frame, pattern, spz_version);
    int rc = 0;
    if (keys < 0) {
        rc = 1;
    } else if (!pattern) {
        if (keys != frame + 1) {
            fprintf(stderr, "f4d-codec: '%s': key %ld not decodable (%d keys decoded)\n", in, frame, keys);
            rc = 1;
        } else {
            rc = write_frame(out, codec_dec_frame(d), spz_version) < 0;
        }
    }
    const struct codec_dec_stats *s = codec_dec_stats(d);
    if (s->lost || s->skipped || s->refused)
        fprintf(stderr, "f4d-codec: '%s': %llu packets lost, %llu keys skipped, %llu refused\n", in,
                (unsigned long long)s->lost, (unsigned long long)s->skipped, (unsigned long long)s->refused);
    codec_dec_free(d);
    free(b);
    return rc;
}

static int do_info(const char *path)
{
    uint8_t *b;
    size_t n;
    if (slurp(path, &b, &n) < 0)
        return 1;
    enum kind k = kind_of_bytes(b, n);
    int rc = 0;
    if (k == K_STREAM) {
        printf("%s: f4d stream, %zu bytes\n", path, n);
        rc = walk_stream(path, b, n, NULL, 1, -1, NULL, 4) < 0;
    } else if (k == K_SPZ || k == K_PLY) {
        struct splat_frame f = { 0 };
        if (read_frame(path, &f) < 0) {
            rc = 1;
        } else {
            float lo[3] = { 0 }, hi[3] = { 0 };
            for (size_t i = 0; i < f.count; i++)
                for (int c = 0; c < 3; c++) {
                    float v = f.pos[3 * i + c];
                    lo[c] = i == 0 || v < lo[c] ? v : lo[c];
                    hi[c] = i == 0 || v > hi[c] ? v : hi[c];
                }
            printf("%s: %s, %zu bytes, %zu Gaussians (%.2f B/G)%s, bounds [%.3f %.3f %.3f] .. [%.3f %.3f %.3f] m\n",
                   path, k != K_SPZ ? "PLY" : b[0] == 0x1f ? "SPZ (v2/v3, gzip)" : "SPZ v4", n, f.count, f.count ? (double)n / (double)f.count : 0.0,
                   f.motion_fwd ? ", with motion" : "", lo[0], lo[1], lo[2], hi[0], hi[1], hi[2]);
        }
        splat_frame_free(&f);
    } else {
        fprintf(stderr, "f4d-codec: '%s': not a PLY, SPZ or f4d stream file\n", path);
        rc = 1;
    }
    free(b);
    return rc;
}

int main(int argc, char **argv)
{
    if (argc < 2 || !strcmp(argv[1], "-h") || !strcmp(argv[1], "--help")) {
        usage(argc < 2 ? stderr : stdout);
        return argc < 2 ? 2 : 0;
    }
    const char *cmd = argv[1], *out = NULL;
    const char **in = calloc((size_t)argc, sizeof *in);
    int nin = 0, quality = CODEC_Q_MEDIUM, intra_every = 0, spz_version = 4, motion_from_keys = 0;
    int stream_order = 0, effort = CODEC_EFFORT_DEFAULT;
    double rate = 10.0;
    long frame = 0;
    for (int i = 2; i < argc; i++) {
        const char *a = argv[i];
        if (!strcmp(a, "--motion-from-keys")) {
            motion_from_keys = 1;
        } else if (!strcmp(a, "--stream-order")) {
            stream_order = 1;
        } else if (a[0] == '-' && a[1]) {
            if (i + 1 >= argc) {
                fprintf(stderr, "f4d-codec: option '%s' needs a value (or is unknown)\n", a);
                return 2;
            }
            const char *v = argv[++i];
            char *end = NULL;
            if (!strcmp(a, "-o")) {
                out = v;
            } else if (!strcmp(a, "--quality")) {
                struct f4d_err err = { 0 };
                if ((quality = codec_quality_from_name(v, &err)) < 0) {
                    fprintf(stderr, "f4d-codec: --quality: %s\n", err.msg);
                    return 2;
                }
            } else if (!strcmp(a, "--effort")) {
                struct f4d_err err = { 0 };
                if ((effort = codec_effort_from_name(v, &err)) < 0) {
                    fprintf(stderr, "f4d-codec: --effort: %s\n", err.msg);
                    return 2;
                }
            } else if (!strcmp(a, "--key-rate")) {
                rate = strtod(v, &end);
                if (*end || !(rate > 0 && rate <= 1000)) {
                    fprintf(stderr, "f4d-codec: --key-rate '%s' must be a rate in Hz (0, 1000]\n", v);
                    return 2;
                }
            } else if (!strcmp(a, "--intra-every")) {
                intra_every = (int)strtol(v, &end, 10);
                if (*end || intra_every < 0) {
                    fprintf(stderr, "f4d-codec: --intra-every '%s' must be a count >= 0\n", v);
                    return 2;
                }
            } else if (!strcmp(a, "--spz-version")) {
                spz_version = (int)strtol(v, &end, 10);
                if (*end || (spz_version != 3 && spz_version != 4)) {
                    fprintf(stderr, "f4d-codec: --spz-version '%s' must be 3 or 4\n", v);
                    return 2;
                }
            } else if (!strcmp(a, "--frame")) {
                frame = strtol(v, &end, 10);
                if (*end || frame < 0) {
                    fprintf(stderr, "f4d-codec: --frame '%s' must be an index >= 0\n", v);
                    return 2;
                }
            } else {
                fprintf(stderr, "f4d-codec: unknown option '%s'\n", a);
                return 2;
            }
        } else {
            in[nin++] = a;
        }
    }
    int rc;
    if (!strcmp(cmd, "info")) {
        if (nin == 0) {
            fprintf(stderr, "f4d-codec: info needs a FILE\n");
            return 2;
        }
        rc = 0;
        for (int i = 0; i < nin; i++)
            rc |= do_info(in[i]);
    } else if (!strcmp(cmd, "encode") || !strcmp(cmd, "decode")) {
        if (nin == 0 || !out) {
            fprintf(stderr, "f4d-codec: %s needs an input and -o OUT\n", cmd);
            return 2;
        }
        if (!strcmp(cmd, "decode") && nin != 1) {
            fprintf(stderr, "f4d-codec: decode takes one input, %d given\n", nin);
            return 2;
        }
        rc = !strcmp(cmd, "encode") ? do_encode(in, nin, out, quality, rate, intra_every, spz_version, motion_from_keys,
                                                stream_order, effort)
                                     : do_decode(in[0], out, frame, spz_version);
    } else {
        fprintf(stderr, "f4d-codec: unknown command '%s'\n", cmd);
        usage(stderr);
        return 2;
    }
    free(in);
    return rc ? 1 : 0;
}
