/* spz.c - Niantic SPZ export/import: v4 (the current version: 32-byte plain
 * header, a TOC and one zstd stream per attribute) and v3 (16-byte header and
 * the same arrays, gzipped) written; v2, v3 and v4 read. Written from the
 * format description in ../shared/docs/gaussians.md §3.1 (facts checked
 * against public SPZ v4 readers: streams positions, alphas, colours, scales,
 * rotations[, SH], zero-size streams omitted). */
#include <zlib.h>
#include <zstd.h>

#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>

#include "codec_internal.h"

#define SPZ_MAGIC   0x5053474eu
#define SPZ_HDR     16
#define SPZ4_HDR    32
#define SPZ4_ZLEVEL 12
#define SPZ_FB      12
#define SPZ_MAX_PTS ((size_t)1 << 26)

static int sh_coeffs(int degree) { return degree == 0 ? 0 : degree == 1 ? 3 : degree == 2 ? 8 : 15; }

static uint8_t u8r(float v)
{
    float r = roundf(v);
    return r <= 0.0f ? 0 : r >= 255.0f ? 255 : (uint8_t)r;
}

/* v4: header, TOC of (compressed, uncompressed) u64 pairs, the five
 * attribute arrays of the v3 layout each as its own zstd frame. */
static int spz4_pack(const uint8_t *arrays, size_t n, uint8_t **out, size_t *len, struct f4d_err *err)
{
    const size_t sz[5] = { 9 * n, n, 3 * n, 3 * n, 4 * n };
    size_t cap = SPZ4_HDR + 5 * 16;
    for (int k = 0; k < 5; k++)
        cap += ZSTD_compressBound(sz[k]);
    uint8_t *o = malloc(cap);
    if (!o)
        return f4d_fail(err, F4D_ENOMEM, "spz: out of memory for %zu Gaussians", n);
    memset(o, 0, SPZ4_HDR);
    codec__put_u32(o, SPZ_MAGIC);
    codec__put_u32(o + 4, 4);
    codec__put_u32(o + 8, (uint32_t)n);
    o[12] = 0;      /* SH degree */
    o[13] = SPZ_FB; /* fractional bits */
    o[14] = 0;      /* flags: not antialiased, no extensions */
    int ns = 0;
    for (int k = 0; k < 5; k++)
        ns += sz[k] > 0;
    o[15] = (uint8_t)ns;
    codec__put_u32(o + 16, SPZ4_HDR); /* TOC right after the header */
    size_t off = SPZ4_HDR + 16 * (size_t)ns, src = 0, t = SPZ4_HDR;
    for (int k = 0; k < 5; k++) {
        if (!sz[k])
            continue;
        size_t z = ZSTD_compress(o + off, cap - off, arrays + src, sz[k], SPZ4_ZLEVEL);
        if (ZSTD_isError(z)) {
            free(o);
            return f4d_fail(err, F4D_EIO, "spz: zstd: %s", ZSTD_getErrorName(z));
        }
        codec__put_u64(o + t, z);
        codec__put_u64(o + t + 8, sz[k]);
        t += 16;
        off += z;
        src += sz[k];
    }
    *out = o;
    *len = off;
    return F4D_OK;
}

int codec_spz_encode(const struct splat_frame *f, uint8_t **out, size_t *len, struct f4d_err *err)
{
    return codec_spz_encode_version(f, 4, out, len, err);
}

int codec_spz_encode_version(const struct splat_frame *f, int version, uint8_t **out, size_t *len,
                             struct f4d_err *err)
{
    if (!f || !out || !len)
        return f4d_fail(err, F4D_EINVAL, "spz: NULL argument");
    if (version != 3 && version != 4)
        return f4d_fail(err, F4D_ENOTSUP, "spz: writing version %d; versions 3 and 4 are written", version);
    int rc = splat_frame_validate(f, err);
    if (rc < 0)
        return rc;
    size_t n = f->count;
    if (n > SPZ_MAX_PTS || n > UINT32_MAX)
        return f4d_fail(err, F4D_ERANGE, "spz: %zu Gaussians exceed %zu", n, SPZ_MAX_PTS);
    size_t raw_n = SPZ_HDR + n * 20;
    uint8_t *raw = malloc(raw_n);
    if (!raw)
        return f4d_fail(err, F4D_ENOMEM, "spz: out of memory for %zu Gaussians", n);
    codec__put_u32(raw, SPZ_MAGIC);
    codec__put_u32(raw + 4, 3);
    codec__put_u32(raw + 8, (uint32_t)n);
    raw[12] = 0;      /* SH degree */
    raw[13] = SPZ_FB; /* fractional bits */
    raw[14] = 0;      /* flags */
    raw[15] = 0;
    uint8_t *pp = raw + SPZ_HDR, *pa = pp + 9 * n, *pc = pa + n, *ps = pc + 3 * n, *pr = ps + 3 * n;
    const float sgn[3] = { 1.0f, -1.0f, -1.0f }; /* RDF -> RUB */
    for (size_t i = 0; i < n; i++) {
        for (int c = 0; c < 3; c++) {
            double v = (double)f->pos[3 * i + c] * sgn[c] * (1 << SPZ_FB);
            if (!(fabs(v) < 8388607.0)) {
                free(raw);
                return f4d_fail(err, F4D_ERANGE, "spz: Gaussian %zu: position %g m outside +-2048 m", i,
                                (double)f->pos[3 * i + c]);
            }
            int32_t q = (int32_t)lrint(v);
            pp[9 * i + 3 * c] = (uint8_t)q;
            pp[9 * i + 3 * c + 1] = (uint8_t)(q >> 8);
            pp[9 * i + 3 * c + 2] = (uint8_t)(q >> 16);
            float fdc = (f->rgb[3 * i + c] - 0.5f) / SPLAT_SH_C0;
            pc[3 * i + c] = u8r(fdc * (0.15f * 255.0f) + 127.5f);
            float s = f->scale[3 * i + c];
            float ls = logf(s > 1e-30f ? s : 1e-30f);
            ps[3 * i + c] = u8r((ls + 10.0f) * 16.0f);
        }
        pa[i] = u8r(f->opacity[i] * 255.0f);
        /* SPZ order x y z w, axes flipped: (w, x, -y, -z) */
        const float *r = f->rot + 4 * i;
        float q[4] = { r[1], -r[2], -r[3], r[0] }, nn = 0;
        for (int c = 0; c < 4; c++)
            nn += q[c] * q[c];
        if (!(nn > 1e-30f)) {
            q[0] = q[1] = q[2] = 0.0f;
            q[3] = 1.0f;
            nn = 1.0f;
        }
        nn = 1.0f / sqrtf(nn);
        int big = 0;
        for (int c = 0; c < 4; c++) {
            q[c] *= nn;
            if (fabsf(q[c]) > fabsf(q[big]))
                big = c;
        }
        if (q[big] < 0)
            for (int c = 0; c < 4; c++)
                q[c] = -q[c];
        uint32_t comp = (uint32_t)big;
        for (int c = 0; c < 4; c++) {
            if (c == big)
                continue;
            uint32_t mag = (uint32_t)lrintf(511.0f * fabsf(q[c]) / 0.70710678f);
            mag = mag > 511 ? 511 : mag;
            comp = comp << 10 | (uint32_t)(q[c] < 0) << 9 | mag;
        }
        codec__put_u32(pr + 4 * i, comp);
    }
    if (version == 4) {
        rc = spz4_pack(raw + SPZ_HDR, n, out, len, err);
        free(raw);
        return rc;
    }
    /* v3: gzip */
    z_stream zs;
    memset(&zs, 0, sizeof zs);
    if (deflateInit2(&zs, 9, Z_DEFLATED, 15 + 16, 9, Z_DEFAULT_STRATEGY) != Z_OK) {
        free(raw);
        return f4d_fail(err, F4D_ENOMEM, "spz: deflateInit2 failed");
    }
    size_t cap = deflateBound(&zs, (uLong)raw_n) + 64;
    uint8_t *z = malloc(cap);
    if (!z) {
        deflateEnd(&zs);
        free(raw);
        return f4d_fail(err, F4D_ENOMEM, "spz: out of memory");
    }
    zs.next_in = raw;
    zs.avail_in = (uInt)raw_n;
    zs.next_out = z;
    zs.avail_out = (uInt)cap;
    int zr = deflate(&zs, Z_FINISH);
    size_t zn = zs.total_out;
    deflateEnd(&zs);
    free(raw);
    if (zr != Z_STREAM_END) {
        free(z);
        return f4d_fail(err, F4D_EIO, "spz: deflate failed (%d)", zr);
    }
    *out = z;
    *len = zn;
    return F4D_OK;
}

/* Inflates up to `cap` bytes of a gzip stream; *got is what came out, *more
 * says the stream had further bytes. */
static int gunzip(const uint8_t *in, size_t n, uint8_t *out, size_t cap, size_t *got, int *more,
                  struct f4d_err *err)
{
    z_stream zs;
    memset(&zs, 0, sizeof zs);
    if (inflateInit2(&zs, 15 + 16) != Z_OK)
        return f4d_fail(err, F4D_ENOMEM, "spz: inflateInit2 failed");
    if (n > UINT32_MAX)
        n = UINT32_MAX;
    zs.next_in = (Bytef *)(uintptr_t)in;
    zs.avail_in = (uInt)n;
    zs.next_out = out;
    zs.avail_out = (uInt)cap;
    int r = inflate(&zs, Z_FINISH);
    *got = zs.total_out;
    *more = 0;
    if (r == Z_BUF_ERROR && zs.avail_out == 0) {
        uint8_t b;
        zs.next_out = &b;
        zs.avail_out = 1;
        r = inflate(&zs, Z_FINISH);
        *more = zs.avail_out == 0;
    }
    inflateEnd(&zs);
    if (r != Z_STREAM_END && r != Z_BUF_ERROR && !(*more))
        return f4d_fail(err, F4D_EFORMAT, "spz: gzip data is corrupt (%d)", r);
    return F4D_OK;
}

/* The arrays of the v2/v3 layout (v4 streams concatenated) into f. */
static int spz_unpack(const uint8_t *arrays, size_t n, uint32_t ver, int fb, struct splat_frame *f,
                      struct f4d_err *err)
{
    int rc = splat_frame_resize(f, n, 0, err);
    if (rc < 0)
        return rc;
    const uint8_t *pp = arrays, *pa = pp + 9 * n, *pc = pa + n, *ps = pc + 3 * n, *pr = ps + 3 * n;
    const float sgn[3] = { 1.0f, -1.0f, -1.0f };
    float inv = 1.0f / (float)(1 << fb);
    for (size_t i = 0; i < n; i++) {
        for (int c = 0; c < 3; c++) {
            const uint8_t *b = pp + 9 * i + 3 * c;
            int32_t q = (int32_t)((uint32_t)b[0] | (uint32_t)b[1] << 8 | (uint32_t)b[2] << 16);
            if (q & 0x800000)
                q -= 0x1000000;
            f->pos[3 * i + c] = (float)q * inv * sgn[c];
            float fdc = ((float)pc[3 * i + c] / 255.0f - 0.5f) / 0.15f;
            f->rgb[3 * i + c] = 0.5f + SPLAT_SH_C0 * fdc;
            f->scale[3 * i + c] = expf((float)ps[3 * i + c] / 16.0f - 10.0f);
        }
        f->opacity[i] = (float)pa[i] / 255.0f;
        float q[4]; /* x y z w (RUB) */
        if (ver >= 3) {
            uint32_t comp = codec__u32(pr + 4 * i);
            int big = (int)(comp >> 30);
            float ss = 0;
            for (int c = 3; c >= 0; c--) {
                if (c == big)
                    continue;
                float m = (float)(comp & 511) / 511.0f * 0.70710678f;
                q[c] = (comp >> 9 & 1) ? -m : m;
                ss += m * m;
                comp >>= 10;
            }
            q[big] = sqrtf(ss < 1.0f ? 1.0f - ss : 0.0f);
        } else {
            float ss = 0;
            for (int c = 0; c < 3; c++) {
                q[c] = (float)pr[3 * i + c] / 127.5f - 1.0f;
                ss += q[c] * q[c];
            }
            q[3] = sqrtf(ss < 1.0f ? 1.0f - ss : 0.0f);
        }
        float nn = q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3];
        nn = nn > 1e-30f ? 1.0f / sqrtf(nn) : 0.0f;
        float *r = f->rot + 4 * i;
        if (nn == 0.0f) {
            r[0] = 1.0f;
            r[1] = r[2] = r[3] = 0.0f;
        } else {
            r[0] = q[3] * nn;
            r[1] = q[0] * nn;
            r[2] = -q[1] * nn;
            r[3] = -q[2] * nn;
        }
    }
    return F4D_OK;
}

/* v4: 32-byte header, optional extension records up to tocByteOffset, TOC,
 * streams back to back. Every size is checked against the file and against
 * what numPoints and shDegree imply before anything is decompressed. */
static int spz4_decode(const uint8_t *buf, size_t len, struct splat_frame *f, struct f4d_err *err)
{
    if (len < SPZ4_HDR)
        return f4d_fail(err, F4D_EFORMAT, "spz: %zu bytes, the v4 header needs %d", len, SPZ4_HDR);
    uint32_t ver = codec__u32(buf + 4);
    if (ver != 4)
        return f4d_fail(err, F4D_ENOTSUP, "spz: uncompressed header with version %u; only version 4 has one "
                        "(versions 2 and 3 are gzipped)", ver);
    size_t n = codec__u32(buf + 8);
    int shd = buf[12], fb = buf[13], ns = buf[15];
    size_t toc = codec__u32(buf + 16);
    if (n > SPZ_MAX_PTS)
        return f4d_fail(err, F4D_ERANGE, "spz: numPoints %zu exceeds %zu", n, SPZ_MAX_PTS);
    if (shd > 3)
        return f4d_fail(err, F4D_EFORMAT, "spz: shDegree %d (0..3)", shd);
    if (fb > 23)
        return f4d_fail(err, F4D_EFORMAT, "spz: fractionalBits %d (0..23)", fb);
    const size_t want[6] = { 9 * n, n, 3 * n, 3 * n, 4 * n, 3 * (size_t)sh_coeffs(shd) * n };
    int expect = 0;
    for (int k = 0; k < 6; k++)
        expect += want[k] > 0;
    if (ns != expect)
        return f4d_fail(err, F4D_EFORMAT, "spz: %d streams, %zu points at SH degree %d need %d", ns, n, shd, expect);
    if (toc < SPZ4_HDR || toc > len || (len - toc) / 16 < (size_t)ns)
        return f4d_fail(err, F4D_EFORMAT, "spz: TOC at byte %zu (%d entries) outside the %zu-byte file", toc, ns, len);
    /* the whole TOC first: sizes as implied, streams inside the file, so a
     * short file claiming many points is refused before any allocation */
    size_t total = 0, end = toc + 16 * (size_t)ns;
    for (int k = 0, s = 0; k < 6; k++) {
        total += want[k];
        if (!want[k])
            continue;
        uint64_t zc = codec__u64(buf + toc + 16 * (size_t)s), zu = codec__u64(buf + toc + 16 * (size_t)s + 8);
        s++;
        if (zu != want[k] || zc > len - end)
            return f4d_fail(err, F4D_EFORMAT, "spz: stream %d: %llu bytes (%llu compressed at byte %zu), expected "
                            "%zu in a %zu-byte file", k, (unsigned long long)zu, (unsigned long long)zc, end,
                            want[k], len);
        end += (size_t)zc;
    }
    uint8_t *raw = malloc(total ? total : 1);
    if (!raw)
        return f4d_fail(err, F4D_ENOMEM, "spz: out of memory for %zu points", n);
    size_t off = toc + 16 * (size_t)ns, dst = 0;
    for (int k = 0, s = 0; k < 6; k++) {
        if (!want[k])
            continue;
        uint64_t zc = codec__u64(buf + toc + 16 * (size_t)s), zu = codec__u64(buf + toc + 16 * (size_t)s + 8);
        s++;
        if (zu != want[k] || zc > len - off) {
            free(raw);
            return f4d_fail(err, F4D_EFORMAT, "spz: stream %d: %llu bytes (%llu compressed at byte %zu), expected "
                            "%zu in a %zu-byte file", k, (unsigned long long)zu, (unsigned long long)zc, off,
                            want[k], len);
        }
        size_t got = ZSTD_decompress(raw + dst, want[k], buf + off, (size_t)zc);
        if (ZSTD_isError(got) || got != want[k]) {
            free(raw);
            return f4d_fail(err, F4D_EFORMAT, "spz: stream %d: zstd gave %s, %zu bytes expected", k,
                            ZSTD_isError(got) ? ZSTD_getErrorName(got) : "a different size", want[k]);
        }
        off += (size_t)zc;
        dst += want[k];
    }
    int rc = spz_unpack(raw, n, 4, fb, f, err);
    free(raw);
    return rc;
}

int codec_spz_decode(const uint8_t *buf, size_t len, struct splat_frame *f, struct f4d_err *err)
{
    if (!buf || !f)
        return f4d_fail(err, F4D_EINVAL, "spz: NULL argument");
    if (len >= 4 && codec__u32(buf) == SPZ_MAGIC)
        return spz4_decode(buf, len, f, err);
    if (len < 18 || buf[0] != 0x1f || buf[1] != 0x8b)
        return f4d_fail(err, F4D_EFORMAT, "spz: not gzip data (no 1f 8b at the start)");
    uint8_t h[SPZ_HDR];
    size_t got;
    int more, rc;
    if ((rc = gunzip(buf, len, h, sizeof h, &got, &more, err)) < 0)
        return rc;
    if (got < SPZ_HDR)
        return f4d_fail(err, F4D_EFORMAT, "spz: %zu bytes after gunzip, the header needs %d", got, SPZ_HDR);
    if (codec__u32(h) != SPZ_MAGIC)
        return f4d_fail(err, F4D_EFORMAT, "spz: magic 0x%08x, expected 0x%08x (NGSP)", codec__u32(h), SPZ_MAGIC);
    uint32_t ver = codec__u32(h + 4);
    if (ver < 2 || ver > 3)
        return f4d_fail(err, F4D_ENOTSUP, "spz: version %u, this reader takes 2 and 3", ver);
    size_t n = codec__u32(h + 8);
    int shd = h[12], fb = h[13];
    if (n > SPZ_MAX_PTS)
        return f4d_fail(err, F4D_ERANGE, "spz: numPoints %zu exceeds %zu", n, SPZ_MAX_PTS);
    if (shd > 3)
        return f4d_fail(err, F4D_EFORMAT, "spz: shDegree %d (0..3)", shd);
    if (fb > 23)
        return f4d_fail(err, F4D_EFORMAT, "spz: fractionalBits %d (0..23)", fb);
    size_t rb = ver >= 3 ? 4 : 3, per = 9 + 1 + 3 + 3 + rb + 3 * (size_t)sh_coeffs(shd);
    size_t total = SPZ_HDR + n * per;
    /* deflate expands at most 1032:1: a header claiming more than the
     * file can inflate to is refused before the allocation */
    if (total / 1032 > len)
        return f4d_fail(err, F4D_EFORMAT, "spz: %zu points need %zu bytes, %zu gzip bytes cannot hold them", n,
                        total, len);
    uint8_t *raw = malloc(total ? total : 1);
    if (!raw)
        return f4d_fail(err, F4D_ENOMEM, "spz: out of memory for %zu points", n);
    if ((rc = gunzip(buf, len, raw, total, &got, &more, err)) < 0) {
        free(raw);
        return rc;
    }
    if (got != total || more) {
        free(raw);
        return f4d_fail(err, F4D_EFORMAT, "spz: %zu points need %zu bytes, the data has %s%zu", n, total,
                        more ? "more than " : "", got);
    }
    rc = spz_unpack(raw + SPZ_HDR, n, ver, fb, f, err);
    free(raw);
    return rc;
}

int codec_spz_write(const char *path, const struct splat_frame *f, struct f4d_err *err)
{
    uint8_t *b;
    size_t n;
    int rc = codec_spz_encode(f, &b, &n, err);
    if (rc < 0)
        return rc;
    FILE *fp = fopen(path, "wb");
    if (!fp) {
        free(b);
        return f4d_fail(err, F4D_EIO, "spz: cannot create '%s': %s", path, strerror(errno));
    }
    size_t w = fwrite(b, 1, n, fp);
    free(b);
    if (fclose(fp) != 0 || w != n)
        return f4d_fail(err, F4D_EIO, "spz: write to '%s' failed", path);
    return F4D_OK;
}

int codec_spz_read(const char *path, struct splat_frame *f, struct f4d_err *err)
{
    FILE *fp = fopen(path, "rb");
    if (!fp)
        return f4d_fail(err, F4D_EIO, "spz: cannot open '%s': %s", path, strerror(errno));
    fseek(fp, 0, SEEK_END);
    long sz = ftell(fp);
    fseek(fp, 0, SEEK_SET);
    if (sz < 0 || (unsigned long)sz > (1ul << 31)) {
        fclose(fp);
        return f4d_fail(err, F4D_EFORMAT, "spz: '%s': size %ld not readable", path, sz);
    }
    uint8_t *b = malloc((size_t)sz + 1);
    if (!b) {
        fclose(fp);
        return f4d_fail(err, F4D_ENOMEM, "spz: '%s': out of memory", path);
    }
    size_t got = fread(b, 1, (size_t)sz, fp);
    fclose(fp);
    int rc = got == (size_t)sz ? codec_spz_decode(b, got, f, err)
                               : f4d_fail(err, F4D_EIO, "spz: short read of '%s'", path);
    free(b);
    if (rc < 0 && err && err->msg[0] && strncmp(err->msg, "spz: cannot", 11))
        f4d_err_prefix(err, "%s", path);
    return rc;
}
