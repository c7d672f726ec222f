/* model_test_util.c - see model_test_util.h. */
#include "model_test_util.h"

#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <cmocka.h>

double mt_max_nan(double m, double v)
{
    return isnan(m) || isnan(v) ? NAN : (v > m ? v : m);
}

double mt_arr_rel(const float *a, const float *b, size_t n)
{
    double md = 0, mr = 0;
    for (size_t i = 0; i < n; i++) {
        md = mt_max_nan(md, fabs((double)a[i] - b[i]));
        mr = mt_max_nan(mr, fabs((double)b[i]));
    }
    if (isinf(mr))
        return NAN;
    return md / (mr > 0 ? mr : 1);
}

float *mt_npy_load(int64_t shape[NPY_MAX_DIMS], int *nd, const char *fmt, ...)
{
    char path[2200];
    struct f4d_err err = {0};
    float *a = NULL;
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(path, sizeof path, fmt, ap);
    va_end(ap);
    if (npy_load_f32(path, &a, shape, nd, &err) < 0)
        fail_msg("%s", err.msg);
    return a;
}

struct mt_ck *mt_ck_add(struct mt_run *r, const char *dir, const char *name, int nchw)
{
    char path[2200];
    struct f4d_err err = {0};
    if (r->n >= MT_MAX_CK) {
        print_error("%s: more than %d checkpoints\n", name, MT_MAX_CK);
        return NULL;
    }
    snprintf(path, sizeof path, "%s/%s.npy", dir, name);
    struct mt_ck *c = &r->ck[r->n];
    memset(c, 0, sizeof *c);
    if (npy_load_f32(path, &c->ref, c->shape, &c->nd, &err) < 0) {
        print_error("%s\n", err.msg);
        return NULL;
    }
    snprintf(c->name, sizeof c->name, "%s", name);
    c->nchw = nchw;
    r->n++;
    return c;
}

struct mt_ck *mt_ck_find(struct mt_run *r, const char *name)
{
    for (int i = 0; i < r->n; i++)
        if (!strcmp(r->ck[i].name, name))
            return &r->ck[i];
    return NULL;
}

void mt_run_free(struct mt_run *r)
{
    for (int i = 0; i < r->n; i++)
        free(r->ck[i].ref);
    r->n = 0;
}

void mt_ck_wrap(struct mt_ck *c, float *ref, size_t n)
{
    memset(c, 0, sizeof *c);
    c->ref = ref;
    c->nd = 1;
    c->shape[0] = (int64_t)n;
}

size_t mt_numel(const struct mt_ck *c, int from)
{
    size_t n = 1;
    for (int i = from; i < c->nd; i++)
        n *= (size_t)c->shape[i];
    return n;
}

void mt_compare(struct mt_ck *c, int frame, const float *data, size_t count)
{
    size_t per = frame < 0 ? mt_numel(c, 0) : mt_numel(c, 1);
    const float *ref = frame < 0 ? c->ref : c->ref + (size_t)frame * per;
    if (count != per) {
        print_error("%s: %zu values, fixture has %zu\n", c->name, count, per);
        c->max_diff = INFINITY;
        return;
    }
    if (c->nchw) { /* ref [ch, h, w] vs data [h, w, ch] */
        size_t ch = (size_t)c->shape[1], hw = per / ch;
        for (size_t i = 0; i < hw; i++)
            for (size_t k = 0; k < ch; k++) {
                double rv = ref[k * hw + i], d = fabs((double)data[i * ch + k] - rv);
                c->max_diff = mt_max_nan(c->max_diff, d);
                c->max_ref = mt_max_nan(c->max_ref, fabs(rv));
            }
    } else {
        for (size_t i = 0; i < count; i++) {
            double rv = ref[i], d = fabs((double)data[i] - rv);
            c->max_diff = mt_max_nan(c->max_diff, d);
            c->max_ref = mt_max_nan(c->max_ref, fabs(rv));
        }
    }
    c->seen = 1;
}

double mt_rel(const struct mt_ck *c)
{
    if (isinf(c->max_ref))
        return NAN;
    return c->max_ref > 0 ? c->max_diff / c->max_ref : c->max_diff;
}

double mt_check(const struct mt_ck *c, const char *tag, double budget, int quiet)
{
    double e = mt_rel(c);
    int bad = !c->seen || !(e <= budget);
    if (bad || !quiet)
        printf("  %s %-22s rel_err %.3e (budget %.1e)%s\n", tag, c->name, e, budget,
               !c->seen ? "  NOT SEEN" : bad ? "  OVER BUDGET" : "");
    assert_true(c->seen);
    assert_true(e <= budget); /* NaN fails */
    return e;
}

void mt_compare_outs(struct mt_run *r, const struct mt_out *outs, size_t n)
{
    for (size_t i = 0; i < n; i++) {
        struct mt_ck *c = mt_ck_find(r, outs[i].name);
        if (!c)
            continue;
        if (!outs[i].p) {
            print_error("%s: output missing\n", outs[i].name);
            c->max_diff = NAN;
            c->seen = 1;
            continue;
        }
        mt_compare(c, -1, outs[i].p, outs[i].count);
    }
}
