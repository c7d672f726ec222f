/* f4d_status.h: the one status space of the whole tree, the one way a message
 * reaches the caller, and checks of internal invariants.
 *
 * Status: every function that can fail returns an int, 0 (F4D_OK) or a
 * negative F4D_E* code; the same name and number mean the same thing in every
 * module (kernels, hal, firmware, tools). Values are stored in logs and test
 * expectations: never renumbered.
 *
 * Message: a failing call writes one line naming what is wrong (the argument,
 * file, tensor or camera) into a `struct f4d_err` that the caller owns, with
 * f4d_fail(). Functions that have no object yet (open, load, parse, create)
 * take `struct f4d_err *err` as their last argument (NULL = no message); long-
 * lived objects whose methods fail later (fk_ctx, gguf_file, model, renderer,
 * camera) own a struct f4d_err and hand it out through `<object>_error()`.
 *
 *     struct f4d_err err = {0};
 *     if (hal_board_load(&b, path, &err) < 0)
 *         fprintf(stderr, "%s (%s)\n", err.msg, f4d_status_name(err.code));
 *
 * Invariants: F4D_ASSERT(cond) is for what no input can cause (a bug); it calls
 * the abort hook (default: print file:line and the expression, then abort()).
 * Everything input can cause returns a status instead.
 */
#ifndef F4D_STATUS_H
#define F4D_STATUS_H

#include <stdarg.h>
#include <stddef.h>

#ifdef __cplusplus
extern "C" {
#endif

enum f4d_status {
    F4D_OK        =   0,
    F4D_EINVAL    =  -1, /* bad argument, shape or configuration value            */
    F4D_ENOMEM    =  -2, /* allocation failed, or scratch needed after a freeze   */
    F4D_EIO       =  -3, /* open/read/write/mmap/device I/O failed                */
    F4D_ETIMEDOUT =  -4, /* nothing arrived within the timeout                    */
    F4D_ENODEV    =  -5, /* device absent or disconnected                         */
    F4D_ENOTSUP   =  -6, /* valid request this build, backend or ISA does not do  */
    F4D_EBUSY     =  -7, /* resource in use / no buffer queued                    */
    F4D_ESTATE    =  -8, /* call not allowed in the current state                 */
    F4D_EEOF      =  -9, /* no more data (end of a take)                          */
    F4D_ECORRUPT  = -10, /* data failed a CRC check                               */
    F4D_EFORMAT   = -11, /* file or stream malformed, inconsistent or unsupported */
    F4D_ENOENT    = -12, /* named key, tensor or file absent                      */
    F4D_ETYPE     = -13, /* present, but with another type                        */
    F4D_ERANGE    = -14, /* a size or value would overflow its range              */
};

/* "F4D_EINVAL" for -1, ...; "F4D_EUNKNOWN" for values outside the enum. */
const char *f4d_status_name(int rc);

#define F4D_ERR_MAX 256
struct f4d_err {
    int code;                /* the status of the failure, F4D_OK if none */
    char msg[F4D_ERR_MAX];   /* one line, no trailing newline */
};

/* Records code and message in *err (if err is non-NULL) and returns code:
 *     return f4d_fail(err, F4D_EINVAL, "board: camera %u: width 0", i); */
int f4d_fail(struct f4d_err *err, int code, const char *fmt, ...)
#if defined(__GNUC__)
    __attribute__((format(printf, 3, 4)))
#endif
    ;
/* f4d_fail with a va_list, for modules' own printf-style fail helpers. */
int f4d_vfail(struct f4d_err *err, int code, const char *fmt, va_list ap);
/* Prefixes an existing message: "<prefix>: <old message>" (keeps the code). */
void f4d_err_prefix(struct f4d_err *err, const char *fmt, ...)
#if defined(__GNUC__)
    __attribute__((format(printf, 2, 3)))
#endif
    ;

/* ---- invariants ---- */
typedef void (*f4d_abort_hook)(const char *file, int line, const char *expr);
/* Replaces the hook F4D_ASSERT calls (NULL restores the default). Set once
 * from main (e.g. to close a take before aborting); the hook must not return. */
void f4d_set_abort_hook(f4d_abort_hook hook);
void f4d_assert_failed(const char *file, int line, const char *expr)
#if defined(__GNUC__)
    __attribute__((noreturn))
#endif
    ;
#define F4D_ASSERT(cond) ((cond) ? (void)0 : f4d_assert_failed(__FILE__, __LINE__, #cond))

#ifdef __cplusplus
}
#endif

#endif /* F4D_STATUS_H */
