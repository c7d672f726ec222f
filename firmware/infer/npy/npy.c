/* npy.c - float32 .npy reader and writer (format versions 1 and 2 read, 1 written). */
#include "npy.h"

#include <errno.h>
#include <inttypes.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>


/* Parses "(a, b, c)" or "()" after "'shape':" in the header dict. */
static int parse_shape(const char *h, int64_t *shape, int *ndim)
{
    const char *p = strstr(h, "'shape'");
    if (!p || !(p = strchr(p, '(')))
        return -1;
    p++;
    int n = 0;
    for (;;) {
        while (*p == ' ' || *p == ',')
            p++;
        if (*p == ')')
            break;
        if (n == NPY_MAX_DIMS || *p < '0' || *p > '9')
            return -1;
        char *end;
        errno = 0;
        long long v = strtoll(p, &end, 10);
        if (errno || end == p || v < 0)
            return -1;
        shape[n++] = v;
        p = end;
    }
    *ndim = n;
    return 0;
}

int npy_load_f32(const char *path, float **data, int64_t *shape, int *ndim,
                 struct f4d_err *err)
{
    *data = NULL;
    FILE *f = fopen(path, "rb");
    if (!f)
        return f4d_fail(err, F4D_EIO, "npy: cannot open '%s': %s", path, strerror(errno));
    unsigned char pre[12];
    char *hdr = NULL;
    int rc = -1;
    if (fread(pre, 1, 10, f) != 10 || memcmp(pre, "\x93NUMPY", 6)) {
        f4d_fail(err, F4D_EFORMAT, "npy: '%s' is not a .npy file", path);
        goto out;
    }
    uint32_t hlen;
    if (pre[6] == 1) {
        hlen = (uint32_t)pre[8] | (uint32_t)pre[9] << 8;
    } else if (pre[6] == 2 || pre[6] == 3) {
        if (fread(pre + 10, 1, 2, f) != 2)
            goto trunc;
        hlen = (uint32_t)pre[8] | (uint32_t)pre[9] << 8 | (uint32_t)pre[10] << 16 |
               (uint32_t)pre[11] << 24;
        if (hlen > (1u << 20)) {
            f4d_fail(err, F4D_EFORMAT, "npy: '%s': header of %u bytes", path, hlen);
            goto out;
        }
    } else {
        f4d_fail(err, F4D_EFORMAT, "npy: '%s': unsupported version %u", path, pre[6]);
        goto out;
    }
    hdr = malloc(hlen + 1);
    if (!hdr || fread(hdr, 1, hlen, f) != hlen)
        goto trunc;
    hdr[hlen] = 0;
    if (!strstr(hdr, "'descr': '<f4'")) {
        f4d_fail(err, F4D_EFORMAT, "npy: '%s': dtype is not little-endian float32", path);
        goto out;
    }
    if (!strstr(hdr, "'fortran_order': False")) {
        f4d_fail(err, F4D_EFORMAT, "npy: '%s': Fortran order is not supported", path);
        goto out;
    }
    if (parse_shape(hdr, shape, ndim) < 0) {
        f4d_fail(err, F4D_EFORMAT, "npy: '%s': bad shape in header", path);
        goto out;
    }
    size_t n = 1;
    for (int i = 0; i < *ndim; i++) {
        if (shape[i] && (uint64_t)shape[i] > (SIZE_MAX / 4) / (n ? n : 1)) {
            f4d_fail(err, F4D_EFORMAT, "npy: '%s': shape too large", path);
            goto out;
        }
        n *= (size_t)shape[i];
    }
    *data = malloc(n ? n * 4 : 4);
    if (!*data) {
        f4d_fail(err, F4D_EFORMAT, "npy: '%s': out of memory", path);
        goto out;
    }
    if (fread(*data, 4, n, f) != n) {
        free(*data);
        *data = NULL;
        goto trunc;
    }
    rc = 0;
    goto out;
trunc:
    f4d_fail(err, F4D_EFORMAT, "npy: '%s' is truncated", path);
out:
    free(hdr);
    fclose(f);
    return rc;
}

int npy_save_f32(const char *path, const float *data, const int64_t *shape, int ndim,
                 struct f4d_err *err)
{
    if (ndim < 0 || ndim > NPY_MAX_DIMS)
        return f4d_fail(err, F4D_EFORMAT, "npy: '%s': %d dims", path, ndim);
    char dict[256];
    int k = snprintf(dict, sizeof dict, "{'descr': '<f4', 'fortran_order': False, 'shape': (");
    size_t n = 1;
    for (int i = 0; i < ndim; i++) {
        k += snprintf(dict + k, sizeof dict - (size_t)k, "%" PRId64 "%s", shape[i],
                      ndim == 1 ? "," : (i + 1 < ndim ? ", " : ""));
        n *= (size_t)shape[i];
    }
    k += snprintf(dict + k, sizeof dict - (size_t)k, "), }");
    /* Pad with spaces and a newline so that the data starts on 64 bytes. */
    size_t total = 10 + (size_t)k + 1;
    size_t pad = (64 - total % 64) % 64;
    size_t hlen = (size_t)k + pad + 1;
    char tmp[4096];
    snprintf(tmp, sizeof tmp, "%s.tmp", path);
    FILE *f = fopen(tmp, "wb");
    if (!f)
        return f4d_fail(err, F4D_EIO, "npy: cannot create '%s': %s", tmp, strerror(errno));
    unsigned char pre[10] = { 0x93, 'N', 'U', 'M', 'P', 'Y', 1, 0,
                              (unsigned char)(hlen & 0xff), (unsigned char)(hlen >> 8) };
    int ok = fwrite(pre, 1, 10, f) == 10 && fwrite(dict, 1, (size_t)k, f) == (size_t)k;
    for (size_t i = 0; ok && i < pad; i++)
        ok = fputc(' ', f) != EOF;
    ok = ok && fputc('\n', f) != EOF && (n == 0 || fwrite(data, 4, n, f) == n);
    ok = (fclose(f) == 0) && ok;
    if (!ok || rename(tmp, path) != 0) {
        remove(tmp);
        return f4d_fail(err, F4D_EFORMAT, "npy: cannot write '%s': %s", path, strerror(errno));
    }
    return 0;
}
