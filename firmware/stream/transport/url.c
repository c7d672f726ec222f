/* url.c - srt:// and file: URLs (see f4d_transport.h). */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "f4d_transport.h"

static int hexval(char c)
{
    return c >= '0' && c <= '9' ? c - '0' : c >= 'a' && c <= 'f' ? c - 'a' + 10 : c >= 'A' && c <= 'F' ? c - 'A' + 10 : -1;
}

/* Percent-decodes src[0..n) into out (NUL-terminated); -1 on a bad escape or
 * when it does not fit. */
static int unescape(const char *src, size_t n, char *out, size_t cap)
{
    size_t k = 0;
    for (size_t i = 0; i < n; i++) {
        char c = src[i];
        if (c == '%') {
            int a = i + 2 < n ? hexval(src[i + 1]) : -1, b = i + 2 < n ? hexval(src[i + 2]) : -1;
            if (a < 0 || b < 0 || a * 16 + b == 0)
                return -1;
            c = (char)(a * 16 + b);
            i += 2;
        }
        if (k + 1 >= cap)
            return -1;
        out[k++] = c;
    }
    out[k] = 0;
    return 0;
}

/* A decimal integer in [lo, hi] from s[0..n). */
static int number(const char *s, size_t n, long long lo, long long hi, long long *v)
{
    char tmp[32];
    if (n == 0 || n >= sizeof tmp)
        return -1;
    memcpy(tmp, s, n);
    tmp[n] = 0;
    char *end;
    long long x = strtoll(tmp, &end, 10);
    if (*end || x < lo || x > hi)
        return -1;
    *v = x;
    return 0;
}

static int param(struct transport_url *u, const char *url, const char *k, size_t kn, const char *v, size_t vn,
                 struct f4d_err *err)
{
    long long x;
#define KEY(s) (kn == sizeof(s) - 1 && !memcmp(k, s, kn))
    if (KEY("mode")) {
        if (vn == 6 && !memcmp(v, "caller", 6))
            u->mode = TRANSPORT_CALLER;
        else if (vn == 8 && !memcmp(v, "listener", 8))
            u->mode = TRANSPORT_LISTENER;
        else
            return f4d_fail(err, F4D_EINVAL, "'%s': mode '%.*s' is neither caller nor listener", url, (int)vn, v);
    } else if (KEY("latency")) {
        if (number(v, vn, 0, 60000, &x) < 0)
            return f4d_fail(err, F4D_EINVAL, "'%s': latency '%.*s' must be milliseconds in [0, 60000]", url, (int)vn, v);
        u->latency_ms = (int)x;
    } else if (KEY("passphrase")) {
        if (unescape(v, vn, u->passphrase, sizeof u->passphrase) < 0)
            return f4d_fail(err, F4D_EINVAL, "'%s': passphrase has a bad %%XX escape or exceeds 79 characters", url);
        size_t n = strlen(u->passphrase);
        if (n < 10 || n > 79)
            return f4d_fail(err, F4D_EINVAL, "'%s': passphrase of %zu characters, SRT takes 10 to 79", url, n);
    } else if (KEY("pbkeylen")) {
        if (number(v, vn, 16, 32, &x) < 0 || (x != 16 && x != 24 && x != 32))
            return f4d_fail(err, F4D_EINVAL, "'%s': pbkeylen '%.*s' must be 16, 24 or 32", url, (int)vn, v);
        u->pbkeylen = (int)x;
    } else if (KEY("timeout")) {
        if (number(v, vn, 1, 3600000, &x) < 0)
            return f4d_fail(err, F4D_EINVAL, "'%s': timeout '%.*s' must be milliseconds in [1, 3600000]", url, (int)vn, v);
        u->timeout_ms = (int)x;
    } else if (KEY("payload")) {
        if (number(v, vn, 64, TRANSPORT_PAYLOAD_MAX, &x) < 0)
            return f4d_fail(err, F4D_EINVAL, "'%s': payload '%.*s' must be bytes in [64, %d]", url, (int)vn, v,
                            TRANSPORT_PAYLOAD_MAX);
        u->payload = (int)x;
    } else if (KEY("rcvbuf")) {
        if (number(v, vn, 1 << 20, 1 << 30, &x) < 0)
            return f4d_fail(err, F4D_EINVAL, "'%s': rcvbuf '%.*s' must be bytes in [1 MiB, 1 GiB]", url, (int)vn, v);
        u->rcvbuf = x;
    } else if (KEY("maxbw")) {
        if (number(v, vn, 1, (long long)1 << 40, &x) < 0)
            return f4d_fail(err, F4D_EINVAL, "'%s': maxbw '%.*s' must be bytes per second > 0", url, (int)vn, v);
        u->maxbw = x;
    } else {
        return f4d_fail(err, F4D_EINVAL, "'%s': unknown parameter '%.*s' (mode, latency, passphrase, pbkeylen, "
                        "timeout, payload, rcvbuf, maxbw)", url, (int)kn, k);
    }
#undef KEY
    return F4D_OK;
}

int transport_url_parse(const char *url, struct transport_url *u, struct f4d_err *err)
{
    if (!url || !u)
        return f4d_fail(err, F4D_EINVAL, "transport_url_parse: NULL argument");
    memset(u, 0, sizeof *u);
    u->latency_ms = -1;
    u->timeout_ms = 3000;
    u->payload = TRANSPORT_PAYLOAD_DEF;
    u->rcvbuf = TRANSPORT_RCVBUF_DEF;
    if (!strncmp(url, "file:", 5)) {
        const char *p = url + 5;
        if (!strncmp(p, "//", 2))
            p += 2;
        if (!*p)
            return f4d_fail(err, F4D_EINVAL, "'%s': file: URL without a path", url);
        if (strlen(p) >= sizeof u->path)
            return f4d_fail(err, F4D_EINVAL, "'%s': path too long", url);
        u->kind = TRANSPORT_FILE;
        strcpy(u->path, p);
        return F4D_OK;
    }
    if (strncmp(url, "srt://", 6))
        return f4d_fail(err, F4D_EINVAL, "'%s': unknown scheme (srt://HOST:PORT?... or file:PATH)", url);
    u->kind = TRANSPORT_SRT;
    const char *h = url + 6, *q = strchr(h, '?');
    const char *end = q ? q : h + strlen(h);
    if (end > h && end[-1] == '/')
        end--; /* srt://host:port/?... */
    const char *hend, *colon;
    if (*h == '[') { /* [v6]:port */
        hend = memchr(h, ']', (size_t)(end - h));
        if (!hend || hend[1] != ':')
            return f4d_fail(err, F4D_EINVAL, "'%s': an IPv6 host is written [ADDR]:PORT", url);
        colon = hend + 1;
        h++;
    } else {
        colon = NULL;
        for (const char *c = h; c < end; c++)
            if (*c == ':')
                colon = c;
        if (!colon)
            return f4d_fail(err, F4D_EINVAL, "'%s': no port (srt://HOST:PORT, or srt://:PORT to listen)", url);
        hend = colon;
    }
    if ((size_t)(hend - h) >= sizeof u->host)
        return f4d_fail(err, F4D_EINVAL, "'%s': host name too long", url);
    memcpy(u->host, h, (size_t)(hend - h));
    u->host[hend - h] = 0;
    long long port;
    if (number(colon + 1, (size_t)(end - colon - 1), 1, 65535, &port) < 0)
        return f4d_fail(err, F4D_EINVAL, "'%s': port '%.*s' is not a number in [1, 65535]", url,
                        (int)(end - colon - 1), colon + 1);
    u->port = (int)port;
    u->mode = u->host[0] ? TRANSPORT_CALLER : TRANSPORT_LISTENER;
    for (const char *p = q ? q + 1 : NULL; p && *p;) {
        const char *amp = strchr(p, '&'), *e = amp ? amp : p + strlen(p);
        const char *eq = memchr(p, '=', (size_t)(e - p));
        if (!eq)
            return f4d_fail(err, F4D_EINVAL, "'%s': parameter '%.*s' has no =VALUE", url, (int)(e - p), p);
        int rc = param(u, url, p, (size_t)(eq - p), eq + 1, (size_t)(e - eq - 1), err);
        if (rc < 0)
            return rc;
        p = amp ? amp + 1 : NULL;
    }
    if (u->mode == TRANSPORT_CALLER && !u->host[0])
        return f4d_fail(err, F4D_EINVAL, "'%s': a caller needs a HOST to call", url);
    return F4D_OK;
}
