#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "test_util.h"

uint64_t rng_u64(struct rng *r)
{
    uint64_t x = r->s;
    x ^= x >> 12;
    x ^= x << 25;
    x ^= x >> 27;
    r->s = x;
    return x * 0x2545F4914F6CDD1Dull;
}

float rng_uniform(struct rng *r, float lo, float hi)
{
    double u = (double)(rng_u64(r) >> 11) * (1.0 / 9007199254740992.0);
    return (float)(lo + (hi - lo) * u);
}

float rng_normal(struct rng *r)
{
    double u1 = ((double)(rng_u64(r) >> 11) + 1.0) * (1.0 / 9007199254740993.0);
    double u2 = (double)(rng_u64(r) >> 11) * (1.0 / 9007199254740992.0);
    return (float)(sqrt(-2.0 * log(u1)) * cos(6.283185307179586 * u2));
}

void rng_fill(struct rng *r, float *x, size_t n, float lo, float hi)
{
    for (size_t i = 0; i < n; i++)
        x[i] = rng_uniform(r, lo, hi);
}

void rng_fill_normal(struct rng *r, float *x, size_t n, float std)
{
    for (size_t i = 0; i < n; i++)
        x[i] = std * rng_normal(r);
}

static int only_isa = -1; /* --isa: the one ISA under test, -1 = all */

int test_isas(enum fk_isa out[4])
{
    static const enum fk_isa all[] = { FK_ISA_AVX2, FK_ISA_AVX2_VNNI, FK_ISA_NEON, FK_ISA_AVX512 };
    if (only_isa >= 0) {
        if (only_isa == FK_ISA_REF)
            return 0;
        out[0] = (enum fk_isa)only_isa;
        return 1;
    }
    int n = 0;
    for (size_t i = 0; i < sizeof all / sizeof all[0]; i++)
        if (fk_isa_supported(all[i]))
            out[n++] = all[i];
    return n;
}

fk_ctx *test_ctx(enum fk_isa isa, int threads)
{
    fk_ctx *ctx = NULL;
    /* bf16 attention wherever the CPU has it: the tests hold every path */
    struct fk_ctx_config cfg = { .isa = isa, .threads = threads, .bf16 = FK_BF16_ON };
    assert_int_equal(fk_ctx_new(&cfg, &ctx), F4D_OK);
    return ctx;
}

fk_ctx *test_ctx_q8(enum fk_isa isa, int threads, enum fk_q8_bits bits)
{
    fk_ctx *ctx = NULL;
    struct fk_ctx_config cfg = { .isa = isa, .threads = threads, .q8_bits = bits };
    assert_int_equal(fk_ctx_new(&cfg, &ctx), F4D_OK);
    return ctx;
}

double budget_ratio(const float *a, const float *b, size_t n, double atol, double rtol)
{
    double worst = 0;
    for (size_t i = 0; i < n; i++) {
        int na = isnan(a[i]), nb = isnan(b[i]);
        if (na || nb) {
            if (na != nb)
                return INFINITY;
            continue;
        }
        if (isinf(a[i]) || isinf(b[i])) {
            if (a[i] != b[i])
                return INFINITY;
            continue;
        }
        double r = fabs((double)a[i] - b[i]) / (atol + rtol * fabs((double)b[i]));
        if (r > worst)
            worst = r;
    }
    return worst;
}

double max_abs_diff(const float *a, const float *b, size_t n)
{
    double m = 0;
    for (size_t i = 0; i < n; i++) {
        double d = fabs((double)a[i] - b[i]);
        if (d > m || isnan(d))
            m = d;
    }
    return m;
}

void *xmalloc(size_t bytes)
{
    void *p = calloc(1, bytes ? bytes : 1);
    assert_non_null(p);
    return p;
}

int kernel_test_main(int argc, char **argv, const char *group, const struct CMUnitTest *tests, size_t n)
{
    int out = 1;
    for (int i = 1; i < argc; i++) {
        if (strcmp(argv[i], "--isa") != 0) {
            argv[out++] = argv[i];
            continue;
        }
        if (i + 1 >= argc) {
            fprintf(stderr, "%s: --isa needs a name (ref, avx2, avx2-vnni, neon)\n", argv[0]);
            return 2;
        }
        const char *name = argv[++i];
        int isa = (int)fk_isa_from_name(name);
        if (isa <= FK_ISA_AUTO) {
            fprintf(stderr, "%s: --isa '%s' is not an ISA fk knows\n", argv[0], name);
            return 2;
        }
        if (isa != FK_ISA_REF && !fk_isa_supported((enum fk_isa)isa)) {
            fprintf(stderr, "[  SKIP    ] %s --isa %s: this CPU does not support %s (cpuid), nothing of %s "
                    "can run on it\n", group, name, name, group);
            return F4D_TEST_SKIPPED;
        }
        only_isa = isa;
    }
    argv[out] = NULL;
    return f4d_test_run(out, argv, group, tests, n, NULL, NULL);
}
