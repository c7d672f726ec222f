/* model_test_util.h - the checkpoint comparison shared by the model tests
 * (test_model_parity, test_model_masked, test_forge4d, test_forge4d_seq,
 * test_preprocess): fixture arrays loaded from .npy, compared NaN-aware with
 * what the C model produces, and the verdict on each checkpoint.
 *
 * NaN-aware: a NaN or an Inf anywhere (data or fixture) makes the error NaN,
 * so every `e <= budget` check on it fails; fmax() would silently drop it. */
#ifndef MODEL_TEST_UTIL_H
#define MODEL_TEST_UTIL_H

#include <stddef.h>
#include <stdint.h>

#include "npy.h"

/* Running maximum that stays NaN once a NaN is seen. */
double mt_max_nan(double m, double v);

/* max |a - b| / max |b| (or max |a - b| when b is all zero); NaN when either
 * array holds a NaN or an Inf. */
double mt_arr_rel(const float *a, const float *b, size_t n);

/* Loads the float32 array at the printf-style path; fails the test (with the
 * loader's message) when it cannot. */
float *mt_npy_load(int64_t shape[NPY_MAX_DIMS], int *nd, const char *fmt, ...)
    __attribute__((format(printf, 3, 4)));

#define MT_MAX_CK 48

/* One checkpoint: a fixture array and the running error against it. */
struct mt_ck {
    char    name[64];
    float  *ref;           /* fixture array                              */
    int64_t shape[NPY_MAX_DIMS];
    int     nd;
    int     nchw;          /* fixture [S, c, h, w] vs C taps HWC per frame */
    double  max_diff, max_ref;
    int     seen;
};

struct mt_run {
    struct mt_ck ck[MT_MAX_CK];
    int          n;
};

/* Adds checkpoint DIR/NAME.npy to r; NULL (message printed) when it cannot. */
struct mt_ck *mt_ck_add(struct mt_run *r, const char *dir, const char *name, int nchw);
/* The checkpoint of that name, or NULL. */
struct mt_ck *mt_ck_find(struct mt_run *r, const char *name);
/* Frees the fixture arrays. */
void mt_run_free(struct mt_run *r);
/* A one-dimensional checkpoint of n values over `ref` (not owned). */
void mt_ck_wrap(struct mt_ck *c, float *ref, size_t n);

/* Product of the dimensions from `from` on. */
size_t mt_numel(const struct mt_ck *c, int from);

/* Compares `count` values with frame `frame` of the fixture (all of it with
 * frame = -1); a size mismatch makes the error Inf. */
void mt_compare(struct mt_ck *c, int frame, const float *data, size_t count);

/* max |c - ref| / max |ref|; NaN-aware as above. */
double mt_rel(const struct mt_ck *c);

/* The verdict on one checkpoint, the comparison every parity test makes:
 * prints "  TAG NAME rel_err E (budget B)" (with quiet, only when it fails)
 * with "  NOT SEEN" / "  OVER BUDGET" where it does, asserts the checkpoint
 * was compared and its error within budget (NaN fails), returns the error. */
double mt_check(const struct mt_ck *c, const char *tag, double budget, int quiet);

/* One model output to compare with the checkpoint of the same name. */
struct mt_out {
    const char  *name;
    const float *p;
    size_t       count;
};

/* Compares every output with its checkpoint in r (an output r has no
 * checkpoint for is passed over); an output the model did not produce (p
 * NULL) is reported and makes its checkpoint's error NaN. */
void mt_compare_outs(struct mt_run *r, const struct mt_out *outs, size_t n);

#endif
