/* test_util.h - shared helpers of the kernel tests: deterministic random data,
 * contexts for every ISA this CPU runs, and error-budget comparisons. */
#ifndef FK_TEST_UTIL_H
#define FK_TEST_UTIL_H

#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>

#include "fk_ctx.h"
#include "f4d_test.h"

struct rng { uint64_t s; };
static inline void     rng_seed(struct rng *r, uint64_t seed) { r->s = seed * 0x9E3779B97F4A7C15ull + 1; }
uint64_t rng_u64(struct rng *r);
float    rng_uniform(struct rng *r, float lo, float hi);
float    rng_normal(struct rng *r);
void     rng_fill(struct rng *r, float *x, size_t n, float lo, float hi);
void     rng_fill_normal(struct rng *r, float *x, size_t n, float std);

/* Optimized ISAs under test (REF excluded); returns the count. Without
 * --isa: every one this CPU supports. With --isa NAME: that one only (ref: none). */
int      test_isas(enum fk_isa out[4]);

/* main() of a kernel test: --isa NAME (fk_isa_name: ref, avx2, avx2-vnni...)
 * restricts test_isas(); a CPU without that ISA skips the whole run up front
 * (exit 77, saying which ISA is missing). The rest as f4d_test_run. */
int      kernel_test_main(int argc, char **argv, const char *group, const struct CMUnitTest *tests,
                          size_t n);
#define KERNEL_TEST_MAIN(argc, argv, group, tests) \
    kernel_test_main(argc, argv, group, tests, sizeof(tests) / sizeof((tests)[0]))
fk_ctx  *test_ctx(enum fk_isa isa, int threads);   /* asserts success */
/* ... with the int8 weight codes forced (FK_Q8_7BIT / FK_Q8_8BIT) */
fk_ctx  *test_ctx_q8(enum fk_isa isa, int threads, enum fk_q8_bits bits);

/* max |a-b| / (atol + rtol*|b|) over n values: <= 1 means within budget.
 * NaN in exactly one of a, b counts as out of budget. */
double   budget_ratio(const float *a, const float *b, size_t n, double atol, double rtol);
double   max_abs_diff(const float *a, const float *b, size_t n);

void    *xmalloc(size_t bytes);   /* asserts success, zero-filled */

#endif
