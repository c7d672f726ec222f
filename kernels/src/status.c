/* status.c: status names, struct f4d_err and the abort hook (f4d_status.h). */
#include "f4d_status.h"

#include <stdarg.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

const char *f4d_status_name(int rc)
{
    static const char *const names[] = {
        "F4D_OK",      "F4D_EINVAL", "F4D_ENOMEM",  "F4D_EIO",      "F4D_ETIMEDOUT",
        "F4D_ENODEV",  "F4D_ENOTSUP", "F4D_EBUSY",  "F4D_ESTATE",   "F4D_EEOF",
        "F4D_ECORRUPT", "F4D_EFORMAT", "F4D_ENOENT", "F4D_ETYPE",   "F4D_ERANGE",
    };
    if (rc > 0 || rc < -(int)(sizeof names / sizeof names[0] - 1))
        return "F4D_EUNKNOWN";
    return names[-rc];
}

int f4d_vfail(struct f4d_err *err, int code, const char *fmt, va_list ap)
{
    if (err) {
        vsnprintf(err->msg, sizeof err->msg, fmt, ap);
        err->code = code;
    }
    return code;
}

int f4d_fail(struct f4d_err *err, int code, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    f4d_vfail(err, code, fmt, ap);
    va_end(ap);
    return code;
}

void f4d_err_prefix(struct f4d_err *err, const char *fmt, ...)
{
    if (!err)
        return;
    char prefix[F4D_ERR_MAX], old[F4D_ERR_MAX];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(prefix, sizeof prefix, fmt, ap);
    va_end(ap);
    memcpy(old, err->msg, sizeof old);
    old[sizeof old - 1] = '\0';
    /* Both parts fit in msg only together with a cut: copy by hand. */
    size_t np = strnlen(prefix, sizeof err->msg - 3);
    memcpy(err->msg, prefix, np);
    memcpy(err->msg + np, ": ", 2);
    size_t room = sizeof err->msg - np - 3;
    size_t no = strnlen(old, room);
    memcpy(err->msg + np + 2, old, no);
    err->msg[np + 2 + no] = '\0';
}

/* The one process-wide setting of the tree: written by main, read on a bug. */
static _Atomic(f4d_abort_hook) abort_hook;

void f4d_set_abort_hook(f4d_abort_hook hook) { atomic_store(&abort_hook, hook); }

void f4d_assert_failed(const char *file, int line, const char *expr)
{
    f4d_abort_hook h = atomic_load(&abort_hook);
    if (h)
        h(file, line, expr);
    fprintf(stderr, "%s:%d: internal invariant failed: %s\n", file, line, expr);
    fflush(stderr);
    abort();
}
