/* gguf.c - GGUF v3 reader (validating, mmap) and streaming writer. */
#include "gguf.h"

#include <errno.h>
#include <fcntl.h>
#include <inttypes.h>
#include <stdarg.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#include <sys/stat.h>
#include <unistd.h>

struct gguf_kv {
    char    *key;
    uint32_t type;        /* enum gguf_vtype                    */
    uint32_t arr_type;    /* element type when type == ARRAY    */
    uint64_t arr_n;
    const uint8_t *val;   /* raw value bytes in the mapping     */
};

struct gguf_file {
    const uint8_t      *map;       /* the file's bytes: our mapping or the caller's */
    size_t              size;
    int                 mapped;    /* map is ours to munmap (gguf_open)        */
    uint32_t            align;
    size_t              n_kv, n_t;
    struct gguf_kv     *kv;
    struct gguf_tensor *t;
    size_t             *sorted;    /* tensor indices sorted by name */
    struct f4d_err      err;       /* the last getter's failure        */
    char                str[256];  /* gguf_get_str's copy, valid until the next call */
};


size_t gguf_type_size(uint32_t type)
{
    switch (type) {
    case GGUF_T_F32: case GGUF_T_I32: return 4;
    case GGUF_T_F16: case GGUF_T_I16: case GGUF_T_BF16: return 2;
    case GGUF_T_I8: return 1;
    case GGUF_T_I64: case GGUF_T_F64: return 8;
    default: return 0;
    }
}

const char *gguf_type_name(uint32_t type)
{
    switch (type) {
    case GGUF_T_F32: return "F32";
    case GGUF_T_F16: return "F16";
    case GGUF_T_BF16: return "BF16";
    case GGUF_T_I8: return "I8";
    case GGUF_T_I16: return "I16";
    case GGUF_T_I32: return "I32";
    case GGUF_T_I64: return "I64";
    case GGUF_T_F64: return "F64";
    default: return "unknown";
    }
}

static size_t vtype_size(uint32_t t)
{
    switch (t) {
    case GGUF_V_UINT8: case GGUF_V_INT8: case GGUF_V_BOOL: return 1;
    case GGUF_V_UINT16: case GGUF_V_INT16: return 2;
    case GGUF_V_UINT32: case GGUF_V_INT32: case GGUF_V_FLOAT32: return 4;
    case GGUF_V_UINT64: case GGUF_V_INT64: case GGUF_V_FLOAT64: return 8;
    default: return 0;
    }
}

/* ---------------------------------------------------------------- reader */

struct cursor {
    const uint8_t *p;
    size_t         pos, size;
};

static int rd(struct cursor *c, void *dst, size_t n)
{
    if (n > c->size - c->pos)
        return -1;
    memcpy(dst, c->p + c->pos, n);
    c->pos += n;
    return 0;
}

static int skip(struct cursor *c, uint64_t n)
{
    if (n > c->size - c->pos)
        return -1;
    c->pos += (size_t)n;
    return 0;
}

/* Reads a GGUF string into a fresh NUL-terminated copy. */
static int rd_str(struct cursor *c, char **out, const char *what, struct f4d_err *err)
{
    uint64_t len;
    if (rd(c, &len, 8) < 0) {
        return f4d_fail(err, F4D_EFORMAT, "gguf: truncated length of %s at byte %zu", what, c->pos);
    }
    if (len > c->size - c->pos) {
        return f4d_fail(err, F4D_EFORMAT, "gguf: %s length %" PRIu64 " runs past the end of the file", what, len);
    }
    if (len == 0 || len >= GGUF_NAME_MAX) {
        return f4d_fail(err, F4D_EFORMAT, "gguf: %s length %" PRIu64 " out of range 1..%d", what, len,
               GGUF_NAME_MAX - 1);
    }
    char *s = malloc((size_t)len + 1);
    if (!s)
        return F4D_ENOMEM;
    memcpy(s, c->p + c->pos, (size_t)len);
    s[len] = 0;
    c->pos += (size_t)len;
    if (memchr(s, 0, (size_t)len)) {
        f4d_fail(err, F4D_EFORMAT, "gguf: %s contains a NUL byte", what);
        free(s);
        return F4D_EFORMAT;
    }
    *out = s;
    return 0;
}

/* Skips one value of type t, checking its bounds. */
static int skip_value(struct cursor *c, uint32_t t, const char *key, struct f4d_err *err)
{
    if (t == GGUF_V_STRING) {
        uint64_t len;
        if (rd(c, &len, 8) < 0 || skip(c, len) < 0) {
            return f4d_fail(err, F4D_EFORMAT, "gguf: key '%s': string value runs past the end of the file", key);
        }
        return 0;
    }
    size_t sz = vtype_size(t);
    if (!sz) {
        return f4d_fail(err, F4D_EFORMAT, "gguf: key '%s': unknown value type %u", key, t);
    }
    if (skip(c, sz) < 0) {
        return f4d_fail(err, F4D_EFORMAT, "gguf: key '%s': value runs past the end of the file", key);
    }
    return 0;
}

typedef int (*idx_cmp)(size_t a, size_t b, const struct gguf_tensor *t);

static int cmp_names(size_t a, size_t b, const struct gguf_tensor *t)
{
    return strcmp(t[a].name, t[b].name);
}

static int cmp_offsets(size_t a, size_t b, const struct gguf_tensor *t)
{
    return t[a].offset < t[b].offset ? -1 : t[a].offset > t[b].offset;
}

/* qsort has no context argument in C11: sort indices with a small merge sort. */
static void sort_idx(size_t *v, size_t *tmp, size_t n, const struct gguf_tensor *t, idx_cmp cmp)
{
    if (n < 2)
        return;
    size_t h = n / 2;
    sort_idx(v, tmp, h, t, cmp);
    sort_idx(v + h, tmp, n - h, t, cmp);
    size_t i = 0, j = h, k = 0;
    while (i < h && j < n)
        tmp[k++] = cmp(v[j], v[i], t) < 0 ? v[j++] : v[i++];
    while (i < h)
        tmp[k++] = v[i++];
    while (j < n)
        tmp[k++] = v[j++];
    memcpy(v, tmp, n * sizeof *v);
}

static int parse(gguf_file *f, struct f4d_err *err)
{
    struct cursor c = { f->map, 0, f->size };
    uint32_t magic = 0, version = 0;
    uint64_t n_t, n_kv;
    if (rd(&c, &magic, 4) < 0 || magic != GGUF_MAGIC) {
        return f4d_fail(err, F4D_EFORMAT, "gguf: bad magic (not a GGUF file)");
    }
    if (rd(&c, &version, 4) < 0 || version != GGUF_VERSION) {
        return f4d_fail(err, F4D_EFORMAT, "gguf: unsupported version %u (need %u)", version, GGUF_VERSION);
    }
    if (rd(&c, &n_t, 8) < 0 || rd(&c, &n_kv, 8) < 0) {
        return f4d_fail(err, F4D_EFORMAT, "gguf: truncated header");
    }
    /* Each key needs >= 13 bytes and each tensor info >= 29: bound the counts. */
    if (n_kv > f->size / 13 || n_t > f->size / 29) {
        return f4d_fail(err, F4D_EFORMAT, "gguf: %" PRIu64 " keys / %" PRIu64 " tensors cannot fit in %zu bytes",
               n_kv, n_t, f->size);
    }
    f->kv = calloc(n_kv ? n_kv : 1, sizeof *f->kv);
    f->t = calloc(n_t ? n_t : 1, sizeof *f->t);
    f->sorted = calloc(n_t ? n_t : 1, sizeof *f->sorted);
    if (!f->kv || !f->t || !f->sorted)
        return F4D_ENOMEM;
    f->align = GGUF_DEFAULT_ALIGN;
    for (uint64_t i = 0; i < n_kv; i++) {
        struct gguf_kv *kv = &f->kv[i];
        int rc = rd_str(&c, &kv->key, "key name", err);
        if (rc < 0)
            return rc;
        f->n_kv = (size_t)i + 1;
        for (uint64_t j = 0; j < i; j++)
            if (!strcmp(f->kv[j].key, kv->key)) {
                return f4d_fail(err, F4D_EFORMAT, "gguf: duplicate key '%s'", kv->key);
            }
        if (rd(&c, &kv->type, 4) < 0) {
            return f4d_fail(err, F4D_EFORMAT, "gguf: key '%s': truncated type", kv->key);
        }
        if (kv->type == GGUF_V_ARRAY) {
            if (rd(&c, &kv->arr_type, 4) < 0 || rd(&c, &kv->arr_n, 8) < 0) {
                return f4d_fail(err, F4D_EFORMAT, "gguf: key '%s': truncated array header", kv->key);
            }
            if (kv->arr_type == GGUF_V_ARRAY) {
                return f4d_fail(err, F4D_EFORMAT, "gguf: key '%s': nested arrays are not supported", kv->key);
            }
            if (kv->arr_n > c.size - c.pos) {
                return f4d_fail(err, F4D_EFORMAT, "gguf: key '%s': array of %" PRIu64 " runs past the end",
                       kv->key, kv->arr_n);
            }
            kv->val = c.p + c.pos;
            for (uint64_t j = 0; j < kv->arr_n; j++)
                if ((rc = skip_value(&c, kv->arr_type, kv->key, err)) < 0)
                    return rc;
        } else {
            kv->val = c.p + c.pos;
            if ((rc = skip_value(&c, kv->type, kv->key, err)) < 0)
                return rc;
        }
        if (!strcmp(kv->key, "general.alignment")) {
            uint32_t a;
            if (kv->type != GGUF_V_UINT32) {
                return f4d_fail(err, F4D_EFORMAT, "gguf: key 'general.alignment' must be uint32");
            }
            memcpy(&a, kv->val, 4);
            if (a == 0 || (a & (a - 1))) {
                return f4d_fail(err, F4D_EFORMAT, "gguf: key 'general.alignment' = %u is not a power of two", a);
            }
            /* Every tensor is then aligned to its element size (<= 8), and the
             * alignment holds in memory too: mappings start on a page. */
            if (a < GGUF_MIN_ALIGN || a > GGUF_MAX_ALIGN) {
                return f4d_fail(err, F4D_EFORMAT, "gguf: key 'general.alignment' = %u out of %u..%u", a,
                       GGUF_MIN_ALIGN, GGUF_MAX_ALIGN);
            }
            f->align = a;
        }
    }
    for (uint64_t i = 0; i < n_t; i++) {
        struct gguf_tensor *t = &f->t[i];
        char *name = NULL;
        int rc = rd_str(&c, &name, "tensor name", err);
        if (rc < 0)
            return rc;
        t->name = name;
        f->n_t = (size_t)i + 1;
        if (rd(&c, &t->n_dims, 4) < 0) {
            return f4d_fail(err, F4D_EFORMAT, "gguf: tensor '%s': truncated info", name);
        }
        if (t->n_dims < 1 || t->n_dims > GGUF_MAX_DIMS) {
            return f4d_fail(err, F4D_EFORMAT, "gguf: tensor '%s': %u dims (1..%d allowed)", name, t->n_dims,
                   GGUF_MAX_DIMS);
        }
        uint64_t n = 1;
        for (uint32_t d = 0; d < GGUF_MAX_DIMS; d++)
            t->ne[d] = 1;
        for (uint32_t d = 0; d < t->n_dims; d++) {
            if (rd(&c, &t->ne[d], 8) < 0) {
                return f4d_fail(err, F4D_EFORMAT, "gguf: tensor '%s': truncated dims", name);
            }
            if (t->ne[d] == 0 || t->ne[d] > (UINT64_C(1) << 40) / n) {
                return f4d_fail(err, F4D_EFORMAT, "gguf: tensor '%s': dim %u = %" PRIu64 " is zero or too large",
                       name, d, t->ne[d]);
            }
            n *= t->ne[d];
        }
        t->n_elements = n;
        if (rd(&c, &t->type, 4) < 0 || rd(&c, &t->offset, 8) < 0) {
            return f4d_fail(err, F4D_EFORMAT, "gguf: tensor '%s': truncated info", name);
        }
        size_t es = gguf_type_size(t->type);
        if (!es) {
            return f4d_fail(err, F4D_EFORMAT, "gguf: tensor '%s': unsupported type %u", name, t->type);
        }
        t->nbytes = (size_t)(n * es);
        if (t->offset % f->align) {
            return f4d_fail(err, F4D_EFORMAT, "gguf: tensor '%s': offset %" PRIu64 " not aligned to %u", name,
                   t->offset, f->align);
        }
    }
    size_t data_start = (c.pos + f->align - 1) / f->align * f->align;
    if (data_start > f->size) {
        return f4d_fail(err, F4D_EFORMAT, "gguf: data section starts past the end of the file");
    }
    size_t data_size = f->size - data_start;
    for (size_t i = 0; i < f->n_t; i++) {
        struct gguf_tensor *t = &f->t[i];
        if (t->offset > data_size || t->nbytes > data_size - t->offset) {
            return f4d_fail(err, F4D_EFORMAT, "gguf: tensor '%s': bytes [%" PRIu64 ", +%zu) past the data end %zu",
                   t->name, t->offset, t->nbytes, data_size);
        }
        t->data = f->map + data_start + t->offset;
        f->sorted[i] = i;
    }
    size_t *tmp = malloc((f->n_t ? f->n_t : 1) * 2 * sizeof *tmp);
    if (!tmp)
        return F4D_ENOMEM;
    size_t *by_off = tmp + (f->n_t ? f->n_t : 1);
    sort_idx(f->sorted, tmp, f->n_t, f->t, cmp_names);
    for (size_t i = 1; i < f->n_t; i++)
        if (!strcmp(f->t[f->sorted[i]].name, f->t[f->sorted[i - 1]].name)) {
            f4d_fail(err, F4D_EFORMAT, "gguf: duplicate tensor '%s'", f->t[f->sorted[i]].name);
            free(tmp);
            return F4D_EFORMAT;
        }
    /* Overlap check in O(n log n): in offset order, a tensor overlaps an
     * earlier one iff it starts before the furthest end seen so far. */
    for (size_t i = 0; i < f->n_t; i++)
        by_off[i] = i;
    sort_idx(by_off, tmp, f->n_t, f->t, cmp_offsets);
    size_t far = 0; /* index of the tensor reaching furthest so far */
    for (size_t i = 1; i < f->n_t; i++) {
        const struct gguf_tensor *a = &f->t[by_off[far]], *b = &f->t[by_off[i]];
        if (b->offset < a->offset + a->nbytes) {
            f4d_fail(err, F4D_EFORMAT, "gguf: tensors '%s' and '%s' overlap", a->name, b->name);
            free(tmp);
            return F4D_EFORMAT;
        }
        far = i; /* no overlap: b ends after a, since it starts after a's end */
    }
    free(tmp);
    return F4D_OK;
}

/* The checks shared by both entry points; f->map and f->size are set. On
 * failure f is closed. */
static int open_parsed(gguf_file *f, gguf_file **out, const char *what, struct f4d_err *err)
{
    int rc = parse(f, err);
    if (rc == F4D_OK && ((uintptr_t)f->map % f->align)) {
        /* Only a caller's buffer can be misaligned (mappings start on a page). */
        f4d_fail(err, F4D_EINVAL, "gguf: %s: buffer at %p is not aligned to general.alignment %u",
               what, (const void *)f->map, f->align);
        rc = F4D_EINVAL;
    }
    if (rc < 0) {
        if (rc == F4D_ENOMEM)
            f4d_fail(err, F4D_ENOMEM, "gguf: out of memory reading %s", what);
        gguf_close(f);
        return rc;
    }
    *out = f;
    return F4D_OK;
}

int gguf_open(const char *path, gguf_file **out, struct f4d_err *err)
{
    *out = NULL;
    gguf_file *f = calloc(1, sizeof *f);
    if (!f) {
        return f4d_fail(err, F4D_ENOMEM, "gguf: out of memory opening '%s'", path);
    }
    int fd = open(path, O_RDONLY);
    if (fd < 0) {
        f4d_fail(err, F4D_EIO, "gguf: cannot open '%s': %s", path, strerror(errno));
        free(f);
        return F4D_EIO;
    }
    struct stat st;
    if (fstat(fd, &st) < 0 || st.st_size < GGUF_MIN_SIZE) {
        f4d_fail(err, F4D_EFORMAT, "gguf: '%s' is too small to be a GGUF file", path);
        close(fd);
        free(f);
        return F4D_EFORMAT;
    }
    f->size = (size_t)st.st_size;
    void *m = mmap(NULL, f->size, PROT_READ, MAP_PRIVATE, fd, 0);
    close(fd);
    if (m == MAP_FAILED) {
        f4d_fail(err, F4D_EIO, "gguf: cannot mmap '%s': %s", path, strerror(errno));
        free(f);
        return F4D_EIO;
    }
    f->map = m;
    f->mapped = 1;
    char what[300];
    snprintf(what, sizeof what, "'%s'", path);
    return open_parsed(f, out, what, err);
}

int gguf_open_memory(const void *data, size_t size, gguf_file **out, struct f4d_err *err)
{
    *out = NULL;
    if (!data && size) {
        return f4d_fail(err, F4D_EINVAL, "gguf: memory buffer is NULL");
    }
    if (size < GGUF_MIN_SIZE) {
        return f4d_fail(err, F4D_EFORMAT, "gguf: memory buffer of %zu bytes is too small to be a GGUF file",
               size);
    }
    gguf_file *f = calloc(1, sizeof *f);
    if (!f) {
        return f4d_fail(err, F4D_ENOMEM, "gguf: out of memory opening a memory buffer");
    }
    f->map = data;
    f->size = size;
    return open_parsed(f, out, "memory buffer", err);
}

void gguf_close(gguf_file *f)
{
    if (!f)
        return;
    for (size_t i = 0; i < f->n_kv; i++)
        free(f->kv[i].key);
    for (size_t i = 0; i < f->n_t; i++)
        free((char *)f->t[i].name);
    free(f->kv);
    free(f->t);
    free(f->sorted);
    if (f->map && f->mapped)
        munmap((void *)(uintptr_t)f->map, f->size);
    free(f);
}

const char *gguf_error(const gguf_file *f) { return f->err.msg; }
uint32_t gguf_alignment(const gguf_file *f) { return f->align; }
size_t gguf_file_size(const gguf_file *f) { return f->size; }
size_t gguf_key_count(const gguf_file *f) { return f->n_kv; }
const char *gguf_key_name(const gguf_file *f, size_t i) { return i < f->n_kv ? f->kv[i].key : NULL; }
size_t gguf_tensor_count(const gguf_file *f) { return f->n_t; }

const struct gguf_tensor *gguf_tensor_at(const gguf_file *f, size_t i)
{
    return i < f->n_t ? &f->t[i] : NULL;
}

static const struct gguf_kv *find_kv(const gguf_file *f, const char *key)
{
    for (size_t i = 0; i < f->n_kv; i++)
        if (!strcmp(f->kv[i].key, key))
            return &f->kv[i];
    return NULL;
}

int gguf_key_type(const gguf_file *f, const char *key)
{
    const struct gguf_kv *kv = find_kv(f, key);
    return kv ? (int)kv->type : F4D_ENOENT;
}

/* Reads one integer of type t at p into int64, range-checked. */
static int int_at(const uint8_t *p, uint32_t t, int64_t *v)
{
    switch (t) {
    case GGUF_V_UINT8: *v = p[0]; return 0;
    case GGUF_V_INT8: *v = (int8_t)p[0]; return 0;
    case GGUF_V_BOOL: *v = p[0] != 0; return 0;
    case GGUF_V_UINT16: { uint16_t x; memcpy(&x, p, 2); *v = x; return 0; }
    case GGUF_V_INT16: { int16_t x; memcpy(&x, p, 2); *v = x; return 0; }
    case GGUF_V_UINT32: { uint32_t x; memcpy(&x, p, 4); *v = x; return 0; }
    case GGUF_V_INT32: { int32_t x; memcpy(&x, p, 4); *v = x; return 0; }
    case GGUF_V_INT64: { int64_t x; memcpy(&x, p, 8); *v = x; return 0; }
    case GGUF_V_UINT64: {
        uint64_t x;
        memcpy(&x, p, 8);
        if (x > (uint64_t)INT64_MAX)
            return F4D_EFORMAT;
        *v = (int64_t)x;
        return 0;
    }
    default: return F4D_ETYPE;
    }
}

int gguf_get_int(gguf_file *f, const char *key, int64_t *v)
{
    const struct gguf_kv *kv = find_kv(f, key);
    if (!kv) {
        return f4d_fail(&f->err, F4D_ENOENT, "gguf: missing key '%s'", key);
    }
    int rc = int_at(kv->val, kv->type, v);
    if (rc < 0)
        f4d_fail(&f->err, rc, "gguf: key '%s' is not an integer in int64 range (type %u)",
                 key, kv->type);
    return rc;
}

int gguf_get_float(gguf_file *f, const char *key, double *v)
{
    const struct gguf_kv *kv = find_kv(f, key);
    if (!kv) {
        return f4d_fail(&f->err, F4D_ENOENT, "gguf: missing key '%s'", key);
    }
    if (kv->type == GGUF_V_FLOAT32) {
        float x;
        memcpy(&x, kv->val, 4);
        *v = x;
    } else if (kv->type == GGUF_V_FLOAT64) {
        memcpy(v, kv->val, 8);
    } else {
        return f4d_fail(&f->err, F4D_ETYPE, "gguf: key '%s' is not a float (type %u)", key, kv->type);
    }
    return 0;
}

int gguf_get_str(gguf_file *f, const char *key, const char **v)
{
    /* Strings are not NUL-terminated in the file: return them through the key
     * table only when they are short; copy-free access is not needed here. */
    static const char empty[] = "";
    const struct gguf_kv *kv = find_kv(f, key);
    if (!kv) {
        return f4d_fail(&f->err, F4D_ENOENT, "gguf: missing key '%s'", key);
    }
    if (kv->type != GGUF_V_STRING) {
        return f4d_fail(&f->err, F4D_ETYPE, "gguf: key '%s' is not a string (type %u)", key, kv->type);
    }
    uint64_t len;
    memcpy(&len, kv->val, 8);
    if (len >= sizeof f->str) {
        return f4d_fail(&f->err, F4D_EFORMAT, "gguf: key '%s': string too long", key);
    }
    if (len == 0) {
        *v = empty;
        return 0;
    }
    char *s = f->str;
    memcpy(s, kv->val + 8, (size_t)len);
    s[len] = 0;
    if (strlen(s) != len) {
        return f4d_fail(&f->err, F4D_EFORMAT, "gguf: key '%s': string contains NUL", key);
    }
    *v = s;
    return 0;
}

int gguf_get_int_array(gguf_file *f, const char *key, int64_t *v, size_t cap, size_t *n)
{
    const struct gguf_kv *kv = find_kv(f, key);
    if (!kv) {
        return f4d_fail(&f->err, F4D_ENOENT, "gguf: missing key '%s'", key);
    }
    size_t es = vtype_size(kv->arr_type);
    if (kv->type != GGUF_V_ARRAY || kv->arr_type == GGUF_V_FLOAT32 ||
        kv->arr_type == GGUF_V_FLOAT64 || !es) {
        return f4d_fail(&f->err, F4D_ETYPE, "gguf: key '%s' is not an integer array", key);
    }
    if (kv->arr_n > cap) {
        return f4d_fail(&f->err, F4D_EFORMAT, "gguf: key '%s' has %" PRIu64 " entries (at most %zu)",
               key, kv->arr_n, cap);
    }
    for (size_t i = 0; i < kv->arr_n; i++)
        if (int_at(kv->val + i * es, kv->arr_type, &v[i]) < 0) {
            return f4d_fail(&f->err, F4D_EFORMAT, "gguf: key '%s'[%zu] out of range", key, i);
        }
    *n = (size_t)kv->arr_n;
    return 0;
}

const struct gguf_tensor *gguf_find_tensor(const gguf_file *f, const char *name)
{
    size_t lo = 0, hi = f->n_t;
    while (lo < hi) {
        size_t mid = lo + (hi - lo) / 2;
        int c = strcmp(f->t[f->sorted[mid]].name, name);
        if (!c)
            return &f->t[f->sorted[mid]];
        if (c < 0)
            lo = mid + 1;
        else
            hi = mid;
    }
    return NULL;
}

int gguf_expect_tensor(gguf_file *f, const char *name, uint32_t type, int n_dims,
                       const int64_t *shape, const struct gguf_tensor **out)
{
    const struct gguf_tensor *t = gguf_find_tensor(f, name);
    if (!t) {
        return f4d_fail(&f->err, F4D_ENOENT, "gguf: missing tensor '%s'", name);
    }
    if (t->type != type) {
        return f4d_fail(&f->err, F4D_ETYPE, "gguf: tensor '%s' has type %s, expected %s", name,
               gguf_type_name(t->type), gguf_type_name(type));
    }
    int ok = (int)t->n_dims == n_dims;
    for (int d = 0; ok && d < n_dims; d++)
        ok = shape[d] > 0 && t->ne[n_dims - 1 - d] == (uint64_t)shape[d];
    if (!ok) {
        char got[96] = "", want[96] = "";
        for (uint32_t d = 0; d < t->n_dims; d++)
            snprintf(got + strlen(got), sizeof got - strlen(got), "%s%" PRIu64, d ? "," : "",
                     t->ne[t->n_dims - 1 - d]);
        for (int d = 0; d < n_dims; d++)
            snprintf(want + strlen(want), sizeof want - strlen(want), "%s%" PRId64, d ? "," : "",
                     shape[d]);
        return f4d_fail(&f->err, F4D_EFORMAT, "gguf: tensor '%s' has shape [%s], expected [%s]", name,
               got, want);
    }
    *out = t;
    return 0;
}

/* ---------------------------------------------------------------- writer */

struct wbuf {
    uint8_t *p;
    size_t   n, cap;
};

struct gguf_writer {
    struct wbuf kv, ti;       /* serialized metadata and tensor infos */
    uint64_t    n_kv, n_t;
    uint64_t    data_off;     /* next tensor offset                   */
    uint64_t   *sizes;        /* nbytes per tensor, in order          */
    size_t      sizes_cap;
    uint64_t    written_t;    /* tensors written so far               */
    FILE       *fp;
    char       *path, *tmp;
    int         failed;
    struct f4d_err err;
};

static int wput(gguf_writer *w, struct wbuf *b, const void *src, size_t n)
{
    if (b->n + n > b->cap) {
        size_t cap = b->cap ? b->cap : 4096;
        while (cap < b->n + n)
            cap *= 2;
        uint8_t *p = realloc(b->p, cap);
        if (!p) {
            f4d_fail(&w->err, F4D_ENOMEM, "gguf writer: out of memory");
            w->failed = 1;
            return F4D_ENOMEM;
        }
        b->p = p;
        b->cap = cap;
    }
    memcpy(b->p + b->n, src, n);
    b->n += n;
    return 0;
}

static int wstr(gguf_writer *w, struct wbuf *b, const char *s)
{
    uint64_t len = strlen(s);
    if (wput(w, b, &len, 8) < 0)
        return F4D_ENOMEM;
    return wput(w, b, s, (size_t)len);
}

gguf_writer *gguf_writer_new(void)
{
    gguf_writer *w = calloc(1, sizeof *w);
    if (w && gguf_writer_add_int(w, "general.alignment", GGUF_V_UINT32, GGUF_DEFAULT_ALIGN) < 0) {
        gguf_writer_free(w);
        return NULL;
    }
    return w;
}

void gguf_writer_free(gguf_writer *w)
{
    if (!w)
        return;
    if (w->fp) {
        fclose(w->fp);
        remove(w->tmp);
    }
    free(w->kv.p);
    free(w->ti.p);
    free(w->sizes);
    free(w->path);
    free(w->tmp);
    free(w);
}

const char *gguf_writer_error(const gguf_writer *w) { return w->err.msg; }

static int key_ok(gguf_writer *w, const char *key)
{
    if (!key || !*key || strlen(key) >= GGUF_NAME_MAX || w->fp) {
        return f4d_fail(&w->err, F4D_EINVAL, "gguf writer: bad key '%s' or header already written",
               key ? key : "(null)");
    }
    return 0;
}

static int put_int(gguf_writer *w, struct wbuf *b, enum gguf_vtype t, int64_t v)
{
    uint8_t buf[8];
    size_t n = vtype_size(t);
    if (!n || t == GGUF_V_FLOAT32 || t == GGUF_V_FLOAT64 || t == GGUF_V_STRING) {
        return f4d_fail(&w->err, F4D_EINVAL, "gguf writer: type %d is not an integer type", (int)t);
    }
    /* Little-endian truncation to the chosen width (x86/ARM hosts). */
    uint64_t u = (uint64_t)v;
    memcpy(buf, &u, 8);
    return wput(w, b, buf, n);
}

int gguf_writer_add_int(gguf_writer *w, const char *key, enum gguf_vtype t, int64_t v)
{
    uint32_t ty = (uint32_t)t;
    if (key_ok(w, key) < 0 || wstr(w, &w->kv, key) < 0 || wput(w, &w->kv, &ty, 4) < 0 ||
        put_int(w, &w->kv, t, v) < 0)
        return w->failed = 1, F4D_EINVAL;
    w->n_kv++;
    return 0;
}

int gguf_writer_add_f32(gguf_writer *w, const char *key, float v)
{
    uint32_t ty = GGUF_V_FLOAT32;
    if (key_ok(w, key) < 0 || wstr(w, &w->kv, key) < 0 || wput(w, &w->kv, &ty, 4) < 0 ||
        wput(w, &w->kv, &v, 4) < 0)
        return w->failed = 1, F4D_EINVAL;
    w->n_kv++;
    return 0;
}

int gguf_writer_add_str(gguf_writer *w, const char *key, const char *v)
{
    uint32_t ty = GGUF_V_STRING;
    if (key_ok(w, key) < 0 || wstr(w, &w->kv, key) < 0 || wput(w, &w->kv, &ty, 4) < 0 ||
        wstr(w, &w->kv, v) < 0)
        return w->failed = 1, F4D_EINVAL;
    w->n_kv++;
    return 0;
}

int gguf_writer_add_int_array(gguf_writer *w, const char *key, enum gguf_vtype t,
                              const int64_t *v, size_t n)
{
    uint32_t ty = GGUF_V_ARRAY, et = (uint32_t)t;
    uint64_t nn = n;
    if (key_ok(w, key) < 0 || wstr(w, &w->kv, key) < 0 || wput(w, &w->kv, &ty, 4) < 0 ||
        wput(w, &w->kv, &et, 4) < 0 || wput(w, &w->kv, &nn, 8) < 0)
        return w->failed = 1, F4D_EINVAL;
    for (size_t i = 0; i < n; i++)
        if (put_int(w, &w->kv, t, v[i]) < 0)
            return w->failed = 1, F4D_EINVAL;
    w->n_kv++;
    return 0;
}

int gguf_writer_add_tensor(gguf_writer *w, const char *name, uint32_t type, int n_dims,
                           const int64_t *shape)
{
    size_t es = gguf_type_size(type);
    if (key_ok(w, name) < 0 || !es || n_dims < 1 || n_dims > GGUF_MAX_DIMS) {
        w->failed = 1;
        return f4d_fail(&w->err, F4D_EINVAL, "gguf writer: tensor '%s': bad type or dims", name);
    }
    uint64_t n = 1;
    for (int d = 0; d < n_dims; d++) {
        if (shape[d] <= 0) {
            w->failed = 1;
            return f4d_fail(&w->err, F4D_EINVAL, "gguf writer: tensor '%s': dim %d is %" PRId64, name,
                   d, shape[d]);
        }
        n *= (uint64_t)shape[d];
    }
    if (w->n_t == w->sizes_cap) {
        size_t cap = w->sizes_cap ? 2 * w->sizes_cap : 256;
        uint64_t *s = realloc(w->sizes, cap * sizeof *s);
        if (!s)
            return w->failed = 1, F4D_ENOMEM;
        w->sizes = s;
        w->sizes_cap = cap;
    }
    uint32_t nd = (uint32_t)n_dims;
    if (wstr(w, &w->ti, name) < 0 || wput(w, &w->ti, &nd, 4) < 0)
        return w->failed = 1, F4D_ENOMEM;
    for (int d = n_dims - 1; d >= 0; d--) {
        uint64_t ne = (uint64_t)shape[d];
        if (wput(w, &w->ti, &ne, 8) < 0)
            return w->failed = 1, F4D_ENOMEM;
    }
    if (wput(w, &w->ti, &type, 4) < 0 || wput(w, &w->ti, &w->data_off, 8) < 0)
        return w->failed = 1, F4D_ENOMEM;
    w->sizes[w->n_t++] = n * es;
    w->data_off += (n * es + GGUF_DEFAULT_ALIGN - 1) / GGUF_DEFAULT_ALIGN * GGUF_DEFAULT_ALIGN;
    return 0;
}

static int wfile(gguf_writer *w, const void *p, size_t n)
{
    if (n && fwrite(p, 1, n, w->fp) != n) {
        f4d_fail(&w->err, F4D_EIO, "gguf writer: write to '%s' failed: %s", w->tmp,
               strerror(errno));
        w->failed = 1;
        return F4D_EIO;
    }
    return 0;
}

static int wpad(gguf_writer *w)
{
    static const uint8_t zeros[GGUF_DEFAULT_ALIGN];
    long pos = ftell(w->fp);
    if (pos < 0)
        return F4D_EIO;
    size_t pad = (GGUF_DEFAULT_ALIGN - (size_t)pos % GGUF_DEFAULT_ALIGN) % GGUF_DEFAULT_ALIGN;
    return wfile(w, zeros, pad);
}

int gguf_writer_begin(gguf_writer *w, const char *path)
{
    if (w->failed || w->fp)
        return F4D_EINVAL;
    size_t n = strlen(path);
    w->path = malloc(n + 1);
    w->tmp = malloc(n + 5);
    if (!w->path || !w->tmp)
        return F4D_ENOMEM;
    memcpy(w->path, path, n + 1);
    snprintf(w->tmp, n + 5, "%s.tmp", path);
    w->fp = fopen(w->tmp, "wb");
    if (!w->fp) {
        return f4d_fail(&w->err, F4D_EIO, "gguf writer: cannot create '%s': %s", w->tmp,
               strerror(errno));
    }
    uint32_t magic = GGUF_MAGIC, ver = GGUF_VERSION;
    if (wfile(w, &magic, 4) < 0 || wfile(w, &ver, 4) < 0 || wfile(w, &w->n_t, 8) < 0 ||
        wfile(w, &w->n_kv, 8) < 0 || wfile(w, w->kv.p, w->kv.n) < 0 ||
        wfile(w, w->ti.p, w->ti.n) < 0 || wpad(w) < 0)
        return F4D_EIO;
    return 0;
}

int gguf_writer_write(gguf_writer *w, const void *data, size_t nbytes)
{
    if (!w->fp || w->failed || w->written_t >= w->n_t || nbytes != w->sizes[w->written_t]) {
        f4d_fail(&w->err, F4D_EINVAL, "gguf writer: tensor %" PRIu64 " written out of order or "
               "with %zu bytes", w->written_t, nbytes);
        w->failed = 1;
        return F4D_EINVAL;
    }
    w->written_t++;
    if (wfile(w, data, nbytes) < 0 || wpad(w) < 0)
        return F4D_EIO;
    return 0;
}

int gguf_writer_finish(gguf_writer *w)
{
    if (!w->fp || w->failed || w->written_t != w->n_t) {
        return f4d_fail(&w->err, F4D_EINVAL, "gguf writer: %" PRIu64 " of %" PRIu64
               " tensors written", w->written_t, w->n_t);
    }
    int bad = fflush(w->fp) != 0 || fsync(fileno(w->fp)) != 0;
    bad |= fclose(w->fp) != 0;
    w->fp = NULL;
    if (bad || rename(w->tmp, w->path) != 0) {
        f4d_fail(&w->err, F4D_EIO, "gguf writer: cannot finish '%s': %s", w->path,
               strerror(errno));
        remove(w->tmp);
        return F4D_EIO;
    }
    return 0;
}
