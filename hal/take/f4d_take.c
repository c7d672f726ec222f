/* f4d_take.c: take writer, reader and verify (format in f4d_take.h). */
#include "f4d_take.h"

#include <errno.h>
#include <fcntl.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <sys/uio.h>
#include <time.h>
#include <unistd.h>
#include <zlib.h>

#define REC_MAGIC 0x52443446u /* "F4DR" little-endian */
#define IDX_MAGIC 0x49443446u /* "F4DI" */
#define REC_VERSION 1u
#define HDR_BYTES 16u
#define SET_META_BYTES 32u
#define FRAME_META_BYTES 72u
#define INFO_CAM_BYTES 56u
#define IDX_ENTRY_BYTES 24u
#define IDX_PENDING 256u

/* ---- little-endian helpers ---- */
static void put32(uint8_t *p, uint32_t v)
{
    for (int i = 0; i < 4; i++)
        p[i] = (uint8_t)(v >> (8 * i));
}
static void put64(uint8_t *p, uint64_t v)
{
    for (int i = 0; i < 8; i++)
        p[i] = (uint8_t)(v >> (8 * i));
}
static uint32_t get32(const uint8_t *p)
{
    return (uint32_t)p[0] | (uint32_t)p[1] << 8 | (uint32_t)p[2] << 16 | (uint32_t)p[3] << 24;
}
static uint64_t get64(const uint8_t *p) { return (uint64_t)get32(p) | (uint64_t)get32(p + 4) << 32; }

static uint32_t crc(uint32_t c, const void *p, size_t n)
{
    const uint8_t *b = p;
    while (n > 0) { /* zlib takes uInt lengths */
        uInt k = n > (1u << 30) ? (1u << 30) : (uInt)n;
        c = (uint32_t)crc32(c, b, k);
        b += k;
        n -= k;
    }
    return c;
}

static uint64_t mono_ns(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (uint64_t)ts.tv_sec * 1000000000u + (uint64_t)ts.tv_nsec;
}

static void make_header(uint8_t *h, uint32_t type, uint32_t len)
{
    put32(h, REC_MAGIC);
    h[4] = (uint8_t)type;
    h[5] = (uint8_t)(type >> 8);
    h[6] = (uint8_t)REC_VERSION;
    h[7] = 0;
    put32(h + 8, len);
    put32(h + 12, crc(0, h, 12));
}

/* Writes every iovec fully (regular files may write short). */
static int write_all(int fd, struct iovec *iov, int n)
{
    while (n > 0) {
        ssize_t w = writev(fd, iov, n);
        if (w < 0) {
            if (errno == EINTR)
                continue;
            return -1;
        }
        while (n > 0 && (size_t)w >= iov->iov_len) {
            w -= (ssize_t)iov->iov_len;
            iov++;
            n--;
        }
        if (n > 0) {
            iov->iov_base = (uint8_t *)iov->iov_base + w;
            iov->iov_len -= (size_t)w;
        }
    }
    return 0;
}

static int path_join(char *out, size_t cap, const char *dir, const char *name)
{
    int n = snprintf(out, cap, "%s/%s", dir, name);
    return n < 0 || (size_t)n >= cap ? -1 : 0;
}

/* mkdir -p: creates the take directory and any missing parents. */
static int mkdir_p(const char *dir)
{
    char p[HAL_PATH_MAX];
    size_t n = strlen(dir);
    if (n == 0 || n >= sizeof p) {
        errno = ENAMETOOLONG;
        return -1;
    }
    memcpy(p, dir, n + 1);
    for (size_t i = 1; i <= n; i++) {
        if (p[i] != '/' && p[i] != 0)
            continue;
        char c = p[i];
        p[i] = 0;
        if (mkdir(p, 0755) < 0 && errno != EEXIST)
            return -1;
        p[i] = c;
    }
    return 0;
}

static void fsync_dir(const char *dir)
{
    int d = open(dir, O_RDONLY | O_DIRECTORY);
    if (d >= 0) {
        fsync(d);
        close(d);
    }
}

/* ======================= writer ======================= */
/* The appender writes records; a syncer thread of the writer's own runs
 * fdatasync, so a slow disk (a second-long fdatasync on a busy machine or an
 * eMMC) delays durability, never an append: the records go on into the page
 * cache meanwhile. `mu` guards the fields the two threads share; the data
 * writes and fdatasync itself run outside it. */
struct f4d_take_writer {
    int fd, idx_fd;
    char dir[HAL_PATH_MAX];
    struct f4d_take_info info;
    uint64_t durability_ns;
    uint64_t offset;          /* bytes in take.f4t (appender only) */
    pthread_t syncer;
    pthread_mutex_t mu;
    pthread_cond_t cv;        /* a set appended, or stop */
    uint64_t sets, durable;   /* written under mu, read atomically by the getters */
    uint64_t unsynced_since;  /* mono time of the oldest set no fdatasync has started on; 0: none */
    uint64_t test_delay_ns;   /* F4D_TAKE_TEST_SYNC_DELAY_MS: a slow disk, for tests */
    long test_fail_after;     /* F4D_TAKE_TEST_SYNC_FAIL_AFTER: this many background syncs
                               * succeed, the next fails with EIO (a dying disk, for tests);
                               * -1: off */
    long syncs;               /* background fdatasyncs done (syncer only) */
    bool stop, failed;
    int sync_errno;           /* the syncer's failure, in sync_op */
    const char *sync_op;
    uint8_t idx_pending[IDX_PENDING * IDX_ENTRY_BYTES];
    uint32_t n_pending;
};

/* Caller holds mu. */
static int flush_index(struct f4d_take_writer *w)
{
    if (!w->n_pending)
        return 0;
    struct iovec iov = {w->idx_pending, (size_t)w->n_pending * IDX_ENTRY_BYTES};
    w->n_pending = 0;
    return write_all(w->idx_fd, &iov, 1);
}

static void ns_timespec(struct timespec *ts, uint64_t ns)
{
    ts->tv_sec = (time_t)(ns / 1000000000u);
    ts->tv_nsec = (long)(ns % 1000000000u);
}

/* Syncs at most durability_ns after the oldest unsynced set was appended. */
static void *syncer_main(void *arg)
{
    struct f4d_take_writer *w = arg;
    pthread_mutex_lock(&w->mu);
    while (!w->stop && !w->failed) {
        if (!w->unsynced_since) {
            pthread_cond_wait(&w->cv, &w->mu);
            continue;
        }
        uint64_t due = w->unsynced_since + w->durability_ns;
        if (mono_ns() < due) {
            struct timespec ts;
            ns_timespec(&ts, due);
            pthread_cond_timedwait(&w->cv, &w->mu, &ts);
            continue;
        }
        uint64_t n = w->sets; /* every record up to n is fully written */
        w->unsynced_since = 0;
        pthread_mutex_unlock(&w->mu);
        if (w->test_delay_ns) {
            struct timespec d;
            ns_timespec(&d, w->test_delay_ns);
            while (nanosleep(&d, &d) < 0 && errno == EINTR) {
            }
        }
        int rc, e;
        if (w->syncs == w->test_fail_after) {
            rc = -1;
            e = EIO;
        } else {
            rc = fdatasync(w->fd);
            e = errno;
        }
        w->syncs++;
        pthread_mutex_lock(&w->mu);
        if (rc < 0) {
            w->failed = true;
            w->sync_errno = e;
            w->sync_op = "fdatasync";
            break;
        }
        __atomic_store_n(&w->durable, n, __ATOMIC_RELEASE);
        if (flush_index(w) < 0) { /* the index is a hint (verify rebuilds it), but a write error is a disk error */
            w->failed = true;
            w->sync_errno = errno;
            w->sync_op = "index write";
        }
    }
    pthread_mutex_unlock(&w->mu);
    return NULL;
}

int f4d_take_create(struct f4d_take_writer **out, const char *dir, const struct f4d_take_info *info,
                    const char *board_json, uint32_t durability_ms, struct f4d_err *err)
{
    *out = NULL;
    if (!info || info->n_cams == 0 || info->n_cams > HAL_RIG_CAMERAS_MAX || durability_ms == 0)
        return f4d_fail(err, F4D_EINVAL, "take %s: bad take info", dir);
    if (mkdir_p(dir) < 0)
        return f4d_fail(err, F4D_EIO, "take %s: cannot create directory: %s", dir, strerror(errno));
    char path[HAL_PATH_MAX + 32];
    if (path_join(path, sizeof path, dir, F4D_TAKE_FILE) < 0 || strlen(dir) >= HAL_PATH_MAX)
        return f4d_fail(err, F4D_EINVAL, "take %s: path too long", dir);
    struct f4d_take_writer *w = calloc(1, sizeof *w);
    if (!w)
        return f4d_fail(err, F4D_ENOMEM, "take %s: out of memory", dir);
    w->idx_fd = -1;
    snprintf(w->dir, sizeof w->dir, "%s", dir);
    w->info = *info;
    w->durability_ns = (uint64_t)durability_ms * 1000000u;
    const char *delay = getenv("F4D_TAKE_TEST_SYNC_DELAY_MS");
    w->test_delay_ns = delay ? (uint64_t)strtoul(delay, NULL, 10) * 1000000u : 0;
    const char *fail_after = getenv("F4D_TAKE_TEST_SYNC_FAIL_AFTER");
    w->test_fail_after = fail_after ? strtol(fail_after, NULL, 10) : -1;
    /* O_EXCL: never append to (or clobber) an existing take */
    w->fd = open(path, O_WRONLY | O_CREAT | O_EXCL | O_APPEND | O_CLOEXEC, 0644);
    if (w->fd < 0) {
        int e = errno;
        free(w);
        return f4d_fail(err, F4D_EIO, "take %s: cannot create %s: %s", dir, F4D_TAKE_FILE,
                        strerror(e));
    }
    path_join(path, sizeof path, dir, F4D_TAKE_INDEX);
    w->idx_fd = open(path, O_WRONLY | O_CREAT | O_TRUNC | O_APPEND | O_CLOEXEC, 0644);
    int rc = F4D_OK;
    if (w->idx_fd < 0) {
        rc = f4d_fail(err, F4D_EIO, "take %s: cannot create index: %s", dir, strerror(errno));
        goto fail;
    }
    uint8_t ih[8];
    put32(ih, IDX_MAGIC);
    put32(ih + 4, 1);
    struct iovec iv = {ih, 8};
    if (write_all(w->idx_fd, &iv, 1) < 0) {
        rc = f4d_fail(err, F4D_EIO, "take %s: index write: %s", dir, strerror(errno));
        goto fail;
    }
    if (board_json) {
        path_join(path, sizeof path, dir, F4D_TAKE_BOARD);
        FILE *f = fopen(path, "w");
        if (!f || fputs(board_json, f) < 0 || fclose(f) != 0) {
            rc = f4d_fail(err, F4D_EIO, "take %s: cannot write board.json", dir);
            goto fail;
        }
    }
    /* info record */
    uint8_t buf[HDR_BYTES + 16 + HAL_RIG_CAMERAS_MAX * INFO_CAM_BYTES + 4];
    uint32_t len = 16 + info->n_cams * INFO_CAM_BYTES;
    uint8_t *p = buf + HDR_BYTES;
    memset(p, 0, len);
    put32(p, info->n_cams);
    put32(p + 4, info->rate_mhz);
    put32(p + 8, durability_ms);
    for (uint32_t i = 0; i < info->n_cams; i++) {
        uint8_t *c = p + 16 + i * INFO_CAM_BYTES;
        const struct hal_format *f = &info->formats[i];
        put32(c, (uint32_t)f->pixfmt);
        put32(c + 4, f->width);
        put32(c + 8, f->height);
        put32(c + 12, f->stride);
        put32(c + 16, f->rate_mhz);
        put32(c + 20, f->exposure_us);
        memcpy(c + 24, info->cam_ids[i], 31);
    }
    make_header(buf, F4D_TAKE_REC_INFO, len);
    put32(p + len, crc(0, p, len));
    struct iovec io = {buf, HDR_BYTES + len + 4};
    if (write_all(w->fd, &io, 1) < 0 || fdatasync(w->fd) < 0) {
        rc = f4d_fail(err, F4D_EIO, "take %s: write: %s", dir, strerror(errno));
        goto fail;
    }
    fsync_dir(dir);
    w->offset = HDR_BYTES + len + 4;
    if (pthread_mutex_init(&w->mu, NULL) != 0) {
        rc = f4d_fail(err, F4D_ENOMEM, "take %s: cannot create a mutex", dir);
        goto fail;
    }
    pthread_condattr_t ca;
    bool cv_ok = pthread_condattr_init(&ca) == 0 && pthread_condattr_setclock(&ca, CLOCK_MONOTONIC) == 0 &&
                 pthread_cond_init(&w->cv, &ca) == 0;
    pthread_condattr_destroy(&ca);
    if (!cv_ok) {
        pthread_mutex_destroy(&w->mu);
        rc = f4d_fail(err, F4D_ENOMEM, "take %s: cannot create a condition variable", dir);
        goto fail;
    }
    int te = pthread_create(&w->syncer, NULL, syncer_main, w);
    if (te != 0) {
        pthread_cond_destroy(&w->cv);
        pthread_mutex_destroy(&w->mu);
        rc = f4d_fail(err, F4D_ENOMEM, "take %s: cannot start the sync thread: %s", dir, strerror(te));
        goto fail;
    }
    *out = w;
    return F4D_OK;
fail:
    if (w->idx_fd >= 0)
        close(w->idx_fd);
    close(w->fd);
    free(w);
    return rc;
}

static bool writer_failed(struct f4d_take_writer *w)
{
    pthread_mutex_lock(&w->mu);
    bool f = w->failed;
    pthread_mutex_unlock(&w->mu);
    return f;
}

static int fail_writer(struct f4d_take_writer *w)
{
    pthread_mutex_lock(&w->mu);
    w->failed = true;
    pthread_cond_signal(&w->cv);
    pthread_mutex_unlock(&w->mu);
    return F4D_EIO;
}

int f4d_take_append(struct f4d_take_writer *w, const struct hal_set *set)
{
    if (writer_failed(w))
        return F4D_EIO;
    uint8_t meta[HDR_BYTES + SET_META_BYTES + HAL_RIG_CAMERAS_MAX * FRAME_META_BYTES];
    uint8_t tail[4];
    struct iovec iov[HAL_RIG_CAMERAS_MAX + 2];
    int niov = 1;
    uint8_t *p = meta + HDR_BYTES;
    uint32_t nf = 0;
    uint64_t len = SET_META_BYTES;
    for (uint32_t c = 0; c < w->info.n_cams; c++) {
        const struct hal_buffer *b = set->frames[c];
        if (!b)
            continue;
        uint8_t *f = p + SET_META_BYTES + nf * FRAME_META_BYTES;
        put32(f, c);
        put32(f + 4, (uint32_t)b->status);
        put32(f + 8, (uint32_t)b->format.pixfmt);
        put32(f + 12, b->format.width);
        put32(f + 16, b->format.height);
        put32(f + 20, b->format.stride);
        put64(f + 24, b->device_ts_ns);
        put64(f + 32, b->host_ts_ns);
        put64(f + 40, b->frame_id);
        put64(f + 48, b->trigger_seq);
        put32(f + 56, (uint32_t)b->bytes_used);
        put32(f + 60, b->flags);
        put64(f + 64, 0);
        iov[niov].iov_base = b->data;
        iov[niov].iov_len = b->bytes_used;
        niov++;
        nf++;
        len += FRAME_META_BYTES + b->bytes_used;
    }
    if (len > F4D_TAKE_RECORD_MAX)
        return F4D_EINVAL;
    /* frame headers sit before all image data: shift them together */
    put64(p, set->seq);
    put64(p + 8, set->trigger_ts_ns);
    put32(p + 16, (set->complete ? 1u : 0u) | (set->has_edge ? 2u : 0u));
    put32(p + 20, set->present_mask);
    put32(p + 24, set->ok_mask);
    put32(p + 28, nf);
    make_header(meta, F4D_TAKE_REC_SET, (uint32_t)len);
    size_t meta_len = HDR_BYTES + SET_META_BYTES + nf * FRAME_META_BYTES;
    uint32_t c = crc(0, p, meta_len - HDR_BYTES);
    for (int i = 1; i < niov; i++)
        c = crc(c, iov[i].iov_base, iov[i].iov_len);
    put32(tail, c);
    iov[0].iov_base = meta;
    iov[0].iov_len = meta_len;
    iov[niov].iov_base = tail;
    iov[niov].iov_len = 4;
    niov++;
    /* One write per part rather than one writev: large records are not
     * written atomically anyway (a power cut tears them), and this way a
     * kill -9 between parts tears them too, so the crash test exercises the
     * same torn-tail repair a power cut needs. */
    for (int i = 0; i < niov; i++)
        if (write_all(w->fd, &iov[i], 1) < 0)
            return fail_writer(w);
    uint8_t e[IDX_ENTRY_BYTES];
    put64(e, set->seq);
    put64(e + 8, w->offset);
    put32(e + 16, (uint32_t)len);
    put32(e + 20, crc(0, e, 20));
    __atomic_store_n(&w->offset, w->offset + HDR_BYTES + len + 4, __ATOMIC_RELAXED);
    pthread_mutex_lock(&w->mu);
    int bad = w->n_pending == IDX_PENDING && flush_index(w) < 0;
    if (!bad) {
        memcpy(w->idx_pending + (size_t)w->n_pending++ * IDX_ENTRY_BYTES, e, sizeof e);
        __atomic_store_n(&w->sets, w->sets + 1, __ATOMIC_RELEASE);
        if (!w->unsynced_since) {
            w->unsynced_since = mono_ns();
            pthread_cond_signal(&w->cv);
        }
    }
    pthread_mutex_unlock(&w->mu);
    return bad ? fail_writer(w) : F4D_OK;
}

uint64_t f4d_take_durable_sets(const struct f4d_take_writer *w) { return __atomic_load_n(&w->durable, __ATOMIC_ACQUIRE); }
uint64_t f4d_take_bytes_written(const struct f4d_take_writer *w) { return __atomic_load_n(&w->offset, __ATOMIC_RELAXED); }
uint64_t f4d_take_sets_written(const struct f4d_take_writer *w) { return __atomic_load_n(&w->sets, __ATOMIC_ACQUIRE); }

int f4d_take_close(struct f4d_take_writer *w, struct f4d_err *err)
{
    pthread_mutex_lock(&w->mu);
    w->stop = true;
    pthread_cond_signal(&w->cv);
    pthread_mutex_unlock(&w->mu);
    pthread_join(w->syncer, NULL); /* an fdatasync in flight finishes first */
    int rc = F4D_OK;
    if (w->sync_errno) {
        rc = f4d_fail(err, F4D_EIO, "take %s: %s: %s", w->dir, w->sync_op, strerror(w->sync_errno));
    } else if (!w->failed) {
        uint8_t buf[HDR_BYTES + 8 + 4];
        put64(buf + HDR_BYTES, w->sets);
        make_header(buf, F4D_TAKE_REC_END, 8);
        put32(buf + HDR_BYTES + 8, crc(0, buf + HDR_BYTES, 8));
        struct iovec io = {buf, sizeof buf};
        if (write_all(w->fd, &io, 1) < 0 || fdatasync(w->fd) < 0 || flush_index(w) < 0 || fsync(w->idx_fd) < 0)
            rc = f4d_fail(err, F4D_EIO, "take %s: closing: %s", w->dir, strerror(errno));
        else
            w->durable = w->sets;
    } else {
        rc = f4d_fail(err, F4D_EIO, "take %s: an earlier write failed", w->dir);
    }
    pthread_cond_destroy(&w->cv);
    pthread_mutex_destroy(&w->mu);
    close(w->idx_fd);
    if (close(w->fd) < 0 && rc == F4D_OK)
        rc = f4d_fail(err, F4D_EIO, "take %s: close: %s", w->dir, strerror(errno));
    free(w);
    return rc;
}

/* ======================= scanning ======================= */
struct rec {
    uint64_t offset;
    uint32_t type, len;
};

struct scanner {
    int fd;
    uint64_t size;
    uint8_t *buf;
    size_t cap;
};

static int read_at(int fd, void *p, size_t n, uint64_t off)
{
    uint8_t *b = p;
    while (n) {
        ssize_t r = pread(fd, b, n, (off_t)off);
        if (r < 0 && errno == EINTR)
            continue;
        if (r <= 0)
            return -1;
        b += r;
        n -= (size_t)r;
        off += (uint64_t)r;
    }
    return 0;
}

static int ensure(struct scanner *s, size_t n)
{
    if (n <= s->cap)
        return 0;
    uint8_t *nb = realloc(s->buf, n);
    if (!nb)
        return -1;
    s->buf = nb;
    s->cap = n;
    return 0;
}

/* Header at off: 1 valid, 0 not a header. */
static int header_at(struct scanner *s, uint64_t off, struct rec *r)
{
    uint8_t h[HDR_BYTES];
    if (off + HDR_BYTES > s->size || read_at(s->fd, h, HDR_BYTES, off) < 0)
        return 0;
    if (get32(h) != REC_MAGIC || get32(h + 12) != crc(0, h, 12))
        return 0;
    r->offset = off;
    r->type = (uint32_t)h[4] | (uint32_t)h[5] << 8;
    r->len = get32(h + 8);
    return r->len <= F4D_TAKE_RECORD_MAX;
}

/* Reads and CRC-checks the payload of r into s->buf: 0 ok, F4D_ECORRUPT, F4D_EEOF (torn). */
static int payload(struct scanner *s, const struct rec *r)
{
    uint64_t end = r->offset + HDR_BYTES + (uint64_t)r->len + 4;
    if (end > s->size)
        return F4D_EEOF;
    if (ensure(s, (size_t)r->len + 4) < 0)
        return F4D_ENOMEM;
    if (read_at(s->fd, s->buf, (size_t)r->len + 4, r->offset + HDR_BYTES) < 0)
        return F4D_EIO;
    return get32(s->buf + r->len) == crc(0, s->buf, r->len) ? F4D_OK : F4D_ECORRUPT;
}

static int parse_info(const uint8_t *p, uint32_t len, struct f4d_take_info *info)
{
    if (len < 16)
        return F4D_ECORRUPT;
    memset(info, 0, sizeof *info);
    info->n_cams = get32(p);
    info->rate_mhz = get32(p + 4);
    info->durability_ms = get32(p + 8);
    if (info->n_cams == 0 || info->n_cams > HAL_RIG_CAMERAS_MAX ||
        len != 16 + info->n_cams * INFO_CAM_BYTES)
        return F4D_ECORRUPT;
    for (uint32_t i = 0; i < info->n_cams; i++) {
        const uint8_t *c = p + 16 + i * INFO_CAM_BYTES;
        struct hal_format *f = &info->formats[i];
        f->pixfmt = (enum hal_pixfmt)get32(c);
        f->width = get32(c + 4);
        f->height = get32(c + 8);
        f->stride = get32(c + 12);
        f->rate_mhz = get32(c + 16);
        f->exposure_us = get32(c + 20);
        f->trigger = HAL_TRIGGER_HARDWARE;
        memcpy(info->cam_ids[i], c + 24, 31);
        info->cam_ids[i][31] = 0;
        if (hal_format_finish(f) < 0)
            return F4D_ECORRUPT;
    }
    return F4D_OK;
}

/* Structure check of a set payload; fills out (data pointers into p). */
static int parse_set(const uint8_t *p, uint32_t len, uint32_t n_cams, struct f4d_take_set *out)
{
    if (len < SET_META_BYTES)
        return F4D_ECORRUPT;
    memset(out, 0, sizeof *out);
    out->seq = get64(p);
    out->trigger_ts_ns = get64(p + 8);
    uint32_t flags = get32(p + 16);
    out->complete = flags & 1u;
    out->has_edge = (flags & 2u) != 0;
    out->present_mask = get32(p + 20);
    out->ok_mask = get32(p + 24);
    uint32_t nf = get32(p + 28);
    if (nf > n_cams || (uint64_t)SET_META_BYTES + (uint64_t)nf * FRAME_META_BYTES > len)
        return F4D_ECORRUPT;
    uint64_t data_off = SET_META_BYTES + (uint64_t)nf * FRAME_META_BYTES;
    uint32_t seen = 0;
    for (uint32_t k = 0; k < nf; k++) {
        const uint8_t *f = p + SET_META_BYTES + k * FRAME_META_BYTES;
        uint32_t cam = get32(f);
        if (cam >= n_cams || (seen & (1u << cam)))
            return F4D_ECORRUPT;
        seen |= 1u << cam;
        struct f4d_take_frame *fr = &out->frames[cam];
        struct hal_buffer *m = &fr->meta;
        m->status = (enum hal_frame_status)get32(f + 4);
        m->format.pixfmt = (enum hal_pixfmt)get32(f + 8);
        m->format.width = get32(f + 12);
        m->format.height = get32(f + 16);
        m->format.stride = get32(f + 20);
        m->device_ts_ns = get64(f + 24);
        m->host_ts_ns = get64(f + 32);
        m->frame_id = get64(f + 40);
        m->trigger_seq = get64(f + 48);
        fr->bytes = get32(f + 56);
        m->flags = get32(f + 60);
        m->camera_index = cam;
        if (m->status > HAL_FRAME_ABORTED || hal_format_finish(&m->format) < 0 ||
            fr->bytes > m->format.image_bytes || data_off + fr->bytes > len)
            return F4D_ECORRUPT;
        m->bytes_used = fr->bytes;
        fr->data = p + data_off;
        fr->present = true;
        data_off += fr->bytes;
    }
    if (data_off != len || seen != out->present_mask || (out->ok_mask & ~seen))
        return F4D_ECORRUPT;
    return F4D_OK;
}

/* Next plausible header at or after `from` (resync after damage); UINT64_MAX if none. */
static uint64_t resync(struct scanner *s, uint64_t from)
{
    uint8_t chunk[65536];
    for (uint64_t off = from; off + HDR_BYTES <= s->size;) {
        size_t n = (size_t)(s->size - off < sizeof chunk ? s->size - off : sizeof chunk);
        if (read_at(s->fd, chunk, n, off) < 0)
            return UINT64_MAX;
        for (size_t i = 0; i + 4 <= n; i++) {
            if (get32(chunk + i) == REC_MAGIC) {
                struct rec r;
                if (header_at(s, off + i, &r))
                    return off + i;
            }
        }
        if (n < 4)
            break;
        off += n - 3;
    }
    return UINT64_MAX;
}

struct scan_result {
    struct f4d_take_info info;
    bool have_info, clean_end;
    uint64_t valid_end;      /* end of the last valid record */
    uint64_t corrupt_total;  /* bad records anywhere (those after valid_end are the torn tail) */
    uint64_t corrupt_before_end;
    struct rec *sets;        /* valid set records, file order */
    uint64_t n_sets, cap_sets;
};

static int scan_all(struct scanner *s, struct scan_result *res)
{
    memset(res, 0, sizeof *res);
    uint64_t off = 0;
    while (off + HDR_BYTES <= s->size) {
        struct rec r;
        if (!header_at(s, off, &r)) {
            uint64_t nx = resync(s, off + 1);
            res->corrupt_total++;
            if (nx == UINT64_MAX)
                break;
            off = nx;
            continue;
        }
        int rc = payload(s, &r);
        if (rc == F4D_EEOF)
            break; /* torn tail */
        if (rc == F4D_ENOMEM || rc == F4D_EIO)
            return rc;
        uint64_t next = off + HDR_BYTES + r.len + 4;
        bool ok = rc == F4D_OK;
        if (ok && r.type == F4D_TAKE_REC_INFO && !res->have_info) {
            ok = parse_info(s->buf, r.len, &res->info) == F4D_OK;
            res->have_info = ok;
        } else if (ok && r.type == F4D_TAKE_REC_SET && res->have_info) {
            struct f4d_take_set tmp;
            ok = parse_set(s->buf, r.len, res->info.n_cams, &tmp) == F4D_OK;
            if (ok) {
                if (res->n_sets == res->cap_sets) {
                    uint64_t nc = res->cap_sets ? res->cap_sets * 2 : 256;
                    struct rec *ns = realloc(res->sets, nc * sizeof *ns);
                    if (!ns)
                        return F4D_ENOMEM;
                    res->sets = ns;
                    res->cap_sets = nc;
                }
                res->sets[res->n_sets++] = r;
            }
        } else if (ok && r.type == F4D_TAKE_REC_END && r.len == 8) {
            res->clean_end = true;
        } else {
            ok = false;
        }
        if (ok) {
            res->valid_end = next;
            res->corrupt_before_end = res->corrupt_total;
        } else {
            res->corrupt_total++;
        }
        off = next;
    }
    return F4D_OK;
}

/* ======================= reader ======================= */
struct f4d_take_reader {
    struct scanner s;
    struct f4d_take_info info;
    struct rec *sets;
    uint64_t n_sets;
};

static int open_take_file(const char *dir, int *fd, uint64_t *size, struct f4d_err *err, int flags)
{
    char path[HAL_PATH_MAX + 32];
    if (path_join(path, sizeof path, dir, F4D_TAKE_FILE) < 0)
        return f4d_fail(err, F4D_EINVAL, "take %s: path too long", dir);
    *fd = open(path, flags | O_CLOEXEC);
    if (*fd < 0)
        return f4d_fail(err, F4D_EIO, "take %s: cannot open %s: %s", dir, F4D_TAKE_FILE,
                        strerror(errno));
    struct stat st;
    if (fstat(*fd, &st) < 0) {
        close(*fd);
        return f4d_fail(err, F4D_EIO, "take %s: stat: %s", dir, strerror(errno));
    }
    *size = (uint64_t)st.st_size;
    return F4D_OK;
}

/* Loads take.idx if every entry is well-formed and inside the file. */
static int load_index(const char *dir, struct f4d_take_reader *r)
{
    char path[HAL_PATH_MAX + 32];
    if (path_join(path, sizeof path, dir, F4D_TAKE_INDEX) < 0)
        return -1;
    int fd = open(path, O_RDONLY | O_CLOEXEC);
    if (fd < 0)
        return -1;
    struct stat st;
    int rc = -1;
    uint8_t *b = NULL;
    if (fstat(fd, &st) < 0 || st.st_size < 8 || (st.st_size - 8) % IDX_ENTRY_BYTES != 0 ||
        (uint64_t)st.st_size > (uint64_t)1 << 32)
        goto out;
    b = malloc((size_t)st.st_size);
    if (!b || read_at(fd, b, (size_t)st.st_size, 0) < 0 || get32(b) != IDX_MAGIC || get32(b + 4) != 1)
        goto out;
    uint64_t n = ((uint64_t)st.st_size - 8) / IDX_ENTRY_BYTES;
    r->sets = calloc(n ? n : 1, sizeof *r->sets);
    if (!r->sets)
        goto out;
    for (uint64_t i = 0; i < n; i++) {
        const uint8_t *e = b + 8 + i * IDX_ENTRY_BYTES;
        struct rec h;
        if (get32(e + 20) != crc(0, e, 20) || !header_at(&r->s, get64(e + 8), &h) ||
            h.type != F4D_TAKE_REC_SET || h.len != get32(e + 16) ||
            h.offset + HDR_BYTES + h.len + 4 > r->s.size) {
            free(r->sets);
            r->sets = NULL;
            goto out;
        }
        r->sets[i] = h;
    }
    r->n_sets = n;
    rc = 0;
out:
    free(b);
    close(fd);
    return rc;
}

int f4d_take_open(struct f4d_take_reader **out, const char *dir, struct f4d_err *err)
{
    *out = NULL;
    struct f4d_take_reader *r = calloc(1, sizeof *r);
    if (!r)
        return f4d_fail(err, F4D_ENOMEM, "take %s: out of memory", dir);
    int rc = open_take_file(dir, &r->s.fd, &r->s.size, err, O_RDONLY);
    if (rc < 0) {
        free(r);
        return rc;
    }
    struct rec h;
    if (header_at(&r->s, 0, &h) && h.type == F4D_TAKE_REC_INFO && payload(&r->s, &h) == F4D_OK &&
        parse_info(r->s.buf, h.len, &r->info) == F4D_OK && load_index(dir, r) == 0) {
        *out = r;
        return F4D_OK;
    }
    struct scan_result res;
    rc = scan_all(&r->s, &res);
    if (rc == F4D_OK && !res.have_info)
        rc = f4d_fail(err, F4D_ECORRUPT, "take %s: no valid take header record", dir);
    else if (rc < 0)
        rc = f4d_fail(err, rc, "take %s: scan failed (%s)", dir, f4d_status_name(rc));
    if (rc < 0) {
        free(res.sets);
        f4d_take_reader_close(r);
        return rc;
    }
    r->info = res.info;
    r->sets = res.sets;
    r->n_sets = res.n_sets;
    *out = r;
    return F4D_OK;
}

const struct f4d_take_info *f4d_take_get_info(const struct f4d_take_reader *r) { return &r->info; }
uint64_t f4d_take_count(const struct f4d_take_reader *r) { return r->n_sets; }

int f4d_take_read(struct f4d_take_reader *r, uint64_t i, struct f4d_take_set *out)
{
    if (i >= r->n_sets)
        return F4D_EINVAL;
    int rc = payload(&r->s, &r->sets[i]);
    if (rc < 0)
        return rc == F4D_EEOF ? F4D_ECORRUPT : rc;
    return parse_set(r->s.buf, r->sets[i].len, r->info.n_cams, out);
}

void f4d_take_reader_close(struct f4d_take_reader *r)
{
    if (!r)
        return;
    close(r->s.fd);
    free(r->s.buf);
    free(r->sets);
    free(r);
}

/* ======================= verify ======================= */
static int write_index(const char *dir, const struct scan_result *res, struct scanner *s)
{
    char path[HAL_PATH_MAX + 32], tmp[HAL_PATH_MAX + 48];
    if (path_join(path, sizeof path, dir, F4D_TAKE_INDEX) < 0 ||
        path_join(tmp, sizeof tmp, dir, F4D_TAKE_INDEX ".tmp") < 0)
        return -1;
    int fd = open(tmp, O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
    if (fd < 0)
        return -1;
    uint8_t h[8];
    put32(h, IDX_MAGIC);
    put32(h + 4, 1);
    struct iovec io = {h, 8};
    int rc = write_all(fd, &io, 1);
    for (uint64_t i = 0; rc == 0 && i < res->n_sets; i++) {
        uint8_t e[IDX_ENTRY_BYTES];
        struct f4d_take_set tmpset;
        /* the set's seq lives in its payload */
        if (payload(s, &res->sets[i]) != F4D_OK ||
            parse_set(s->buf, res->sets[i].len, res->info.n_cams, &tmpset) != F4D_OK) {
            rc = -1;
            break;
        }
        put64(e, tmpset.seq);
        put64(e + 8, res->sets[i].offset);
        put32(e + 16, res->sets[i].len);
        put32(e + 20, crc(0, e, 20));
        struct iovec ie = {e, sizeof e};
        rc = write_all(fd, &ie, 1);
    }
    if (rc == 0)
        rc = fsync(fd);
    close(fd);
    if (rc == 0)
        rc = rename(tmp, path);
    if (rc == 0)
        fsync_dir(dir);
    else
        unlink(tmp);
    return rc;
}

int f4d_take_verify(const char *dir, bool repair, struct f4d_take_report *rep, struct f4d_err *err)
{
    memset(rep, 0, sizeof *rep);
    uint64_t indexed = 0;
    {
        /* how many sets the existing index lists (what a reader saw before repair) */
        struct f4d_take_reader probe = {0};
        if (open_take_file(dir, &probe.s.fd, &probe.s.size, err, O_RDONLY) < 0)
            return f4d_fail(err, F4D_EIO, "take %s: cannot open %s", dir, F4D_TAKE_FILE);
        if (load_index(dir, &probe) == 0)
            indexed = probe.n_sets;
        free(probe.sets);
        close(probe.s.fd);
    }
    struct scanner s = {0};
    int rc = open_take_file(dir, &s.fd, &s.size, err, repair ? O_RDWR : O_RDONLY);
    if (rc < 0)
        return rc;
    struct scan_result res;
    rc = scan_all(&s, &res);
    if (rc < 0) {
        rc = f4d_fail(err, rc, "take %s: scan failed (%s)", dir, f4d_status_name(rc));
        goto out;
    }
    if (!res.have_info) {
        rc = f4d_fail(err, F4D_ECORRUPT, "take %s: no valid take header record", dir);
        goto out;
    }
    rep->sets = res.n_sets;
    rep->corrupt = res.corrupt_before_end;
    rep->clean_end = res.clean_end;
    rep->truncated_bytes = s.size - res.valid_end;
    rep->repaired = res.n_sets > indexed ? res.n_sets - indexed : 0;
    bool index_ok = indexed == res.n_sets && rep->truncated_bytes == 0;
    if (repair) {
        if (rep->truncated_bytes && (ftruncate(s.fd, (off_t)res.valid_end) < 0 || fsync(s.fd) < 0)) {
            rc = f4d_fail(err, F4D_EIO, "take %s: cannot truncate the torn tail: %s", dir,
                          strerror(errno));
            goto out;
        }
        s.size = res.valid_end;
        if (!index_ok) {
            if (write_index(dir, &res, &s) < 0) {
                rc = f4d_fail(err, F4D_EIO, "take %s: cannot rewrite the index", dir);
                goto out;
            }
            rep->index_rebuilt = true;
        }
    }
    rc = F4D_OK;
out:
    free(res.sets);
    free(s.buf);
    close(s.fd);
    return rc;
}
