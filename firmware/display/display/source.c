/* source.c - packet sources: the interface, a stream file (mmap) and a memory
 * buffer. Both scan bytes the same way: parse at the cursor, and on damage
 * skip to the next magic (codec_packet_resync), counting what was lost. */
#include <errno.h>
#include <fcntl.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#include <sys/stat.h>
#include <unistd.h>

#include "f4d_display.h"

struct display_source {
    struct display_source_ops ops;
    void                     *impl;
};

int display_source_new(const struct display_source_ops *ops, void *impl, display_source **out, struct f4d_err *err)
{
    if (!ops || !ops->next || !out)
        return f4d_fail(err, F4D_EINVAL, "display_source_new: NULL operations");
    display_source *s = calloc(1, sizeof *s);
    if (!s)
        return f4d_fail(err, F4D_ENOMEM, "display_source_new: out of memory");
    s->ops = *ops;
    s->impl = impl;
    *out = s;
    return F4D_OK;
}

int display_source_next(display_source *s, struct codec_packet *p, struct f4d_err *err)
{
    if (!s || !p)
        return f4d_fail(err, F4D_EINVAL, "display_source_next: NULL argument");
    return s->ops.next(s->impl, p, err);
}

void display_source_get_stats(const display_source *s, struct display_source_stats *st)
{
    memset(st, 0, sizeof *st);
    st->latency_ms = -1.0;
    if (s && s->ops.stats)
        s->ops.stats(s->impl, st);
}

void display_source_free(display_source *s)
{
    if (!s)
        return;
    if (s->ops.free)
        s->ops.free(s->impl);
    free(s);
}

/* ---- bytes in memory (a mapped file or a caller's buffer) ---------------------- */

struct bytes_src {
    const uint8_t *buf;
    size_t         len, off;
    void          *map;       /* munmap'd at free when the file was mapped */
    size_t         map_len;
    struct display_source_stats st;
    int            in_damage; /* counts one drop per damaged run of bytes */
};

static int bytes_next(void *impl, struct codec_packet *p, struct f4d_err *err)
{
    struct bytes_src *b = impl;
    while (b->off < b->len) {
        const uint8_t *at = b->buf + b->off;
        size_t left = b->len - b->off;
        struct f4d_err perr;
        int rc = codec_packet_parse(at, left, p, &perr);
        if (rc == 0) {
            b->off += p->size;
            b->st.packets++;
            b->st.bytes += p->size;
            b->in_damage = 0;
            return 1;
        }
        /* damaged, truncated or not a packet start: skip to the next magic */
        if (!b->in_damage)
            b->st.dropped++;
        b->in_damage = 1;
        size_t step = codec_packet_resync(at, left);
        if (step == 0)
            step = 1;
        b->off += step;
        b->st.skipped_bytes += step;
    }
    (void)err;
    return F4D_EEOF;
}

static void bytes_stats(const void *impl, struct display_source_stats *st)
{
    *st = ((const struct bytes_src *)impl)->st;
}

static void bytes_free(void *impl)
{
    struct bytes_src *b = impl;
    if (b->map)
        munmap(b->map, b->map_len);
    free(b);
}

static const struct display_source_ops bytes_ops = { bytes_next, bytes_stats, bytes_free };

static int bytes_open(const uint8_t *buf, size_t len, size_t off, void *map, size_t map_len, display_source **out,
                      struct f4d_err *err)
{
    struct bytes_src *b = calloc(1, sizeof *b);
    if (!b) {
        if (map)
            munmap(map, map_len);
        return f4d_fail(err, F4D_ENOMEM, "display source: out of memory");
    }
    b->buf = buf;
    b->len = len;
    b->off = off;
    b->map = map;
    b->map_len = map_len;
    b->st.latency_ms = -1.0;
    /* a join in the middle starts at the next packet boundary, not counted as damage */
    if (off > 0 && off < len) {
        size_t skip = 0;
        while (b->off + skip < len && codec_packet_parse(buf + b->off + skip, len - b->off - skip,
                                                         &(struct codec_packet){ 0 }, NULL) != 0) {
            size_t step = codec_packet_resync(buf + b->off + skip, len - b->off - skip);
            skip += step ? step : 1;
        }
        b->off += skip;
        b->st.skipped_bytes = skip;
    }
    int rc = display_source_new(&bytes_ops, b, out, err);
    if (rc < 0)
        bytes_free(b);
    return rc;
}

int display_source_memory(const uint8_t *buf, size_t len, display_source **out, struct f4d_err *err)
{
    if (!out || (!buf && len))
        return f4d_fail(err, F4D_EINVAL, "display_source_memory: NULL argument");
    return bytes_open(buf, len, 0, NULL, 0, out, err);
}

int display_source_file(const char *path, size_t offset, display_source **out, struct f4d_err *err)
{
    if (!path || !out)
        return f4d_fail(err, F4D_EINVAL, "display_source_file: NULL argument");
    int fd = open(path, O_RDONLY | O_CLOEXEC);
    if (fd < 0)
        return f4d_fail(err, F4D_EIO, "cannot open '%s': %s", path, strerror(errno));
    struct stat sb;
    if (fstat(fd, &sb) < 0 || !S_ISREG(sb.st_mode)) {
        close(fd);
        return f4d_fail(err, F4D_EIO, "'%s' is not a regular file", path);
    }
    size_t len = (size_t)sb.st_size;
    if (offset > len) {
        close(fd);
        return f4d_fail(err, F4D_EINVAL, "'%s': start offset %zu is past its %zu bytes", path, offset, len);
    }
    void *map = NULL;
    if (len > 0) {
        map = mmap(NULL, len, PROT_READ, MAP_PRIVATE, fd, 0);
        if (map == MAP_FAILED) {
            close(fd);
            return f4d_fail(err, F4D_EIO, "cannot map '%s': %s", path, strerror(errno));
        }
    }
    close(fd);
    return bytes_open(map, len, offset, map, len, out, err);
}
