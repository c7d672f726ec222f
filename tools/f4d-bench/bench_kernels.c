/* bench_kernels.c - f4d-bench kernels: speed vs error of the numeric kernels
 * on the real model's shapes (and a tiny model's), beside OpenBLAS sgemm and
 * the machine's measured FMA peak, all in the same run.
 *
 * Errors are relative to the RMS of the fp32 reference output:
 *   f32   ours vs OpenBLAS sgemm (both fp32: summation order only)
 *   f16   fp16 weights vs our fp32 weights, same input
 *   int8  int8 weights + int8 dynamic activations vs our fp32
 *   attention  vs the scalar reference kernel on a sample of query rows.
 *
 * The header names the CPU and its SIMD flags, the caches fk read (and
 * where from), the GEMM blocks chosen from them (FK_GEMM_BLOCKS / FK_CACHES
 * override) and the int8 path. Each row names its path; xf32 is an f16 or
 * int8 GEMM's speed over our f32 GEMM on the same shape in the same run.
 * --isa NAME forces one ISA; --isa all runs f32/f16/int8 on every optimized
 * ISA this CPU has (xf32 always against the same ISA's f32), attention on the
 * best ISA and on AVX2. The variants of a shape and OpenBLAS are timed in
 * turn, rep after rep, and the ratios are medians of those pairs: on a
 * shared machine a slow phase then slows both sides of a pair. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include <cjson/cJSON.h>

#include "bench.h"
#include "fk_attention.h"
#include "fk_linear.h"
#include "peak.h"

#include <unistd.h>

#ifdef F4D_HAVE_OPENBLAS
#include <cblas.h>
void  openblas_set_num_threads(int);
char *openblas_get_corename(void);
#endif

struct opts {
    int         quick;
    int         reps;
    int         threads_max;
    const char *json;
    enum fk_isa isa;
    int         all_isas; /* --isa all: int8 on every optimized ISA too */
    const char *only;   /* "gemm", "attention" or NULL for both */
    int         openblas_native;
    int         cpu_clock; /* --clock cpu: time 1-thread rows on the thread's CPU clock */
    int         shape[3];  /* --shape M,N,K: only this GEMM shape (0: every model shape) */
    int         no_avx512; /* --isa all with the AVX-512 GEMM rows in a second process */
    int         rows_out;  /* --rows-out: also print each row as a "ROW ..." line (that process) */
};

/* Seconds on the clock the rows are timed with. --clock cpu, one thread: the
 * calling thread's CPU time (our 1-thread GEMM and OpenBLAS with one thread
 * both run on it), so time spent descheduled on a shared machine is not
 * counted; otherwise the wall clock. */
static double now_for(const struct opts *o, int threads)
{
    if (o->cpu_clock && threads == 1)
        return bench_thread_cpu_s();
    return bench_now();
}

struct row {
    const char *kernel, *precision;
    int    threads, m, n, k;
    double gflops, openblas_gflops, max_rel_err, mean_rel_err;
    double peer_ratio; /* gemm: ours / OpenBLAS; attention: ours / our f32 GEMM */
    double vs_f32;     /* gemm f16/int8: ours / our f32 GEMM, same shape and run */
    const char *path;  /* the kernel path that ran (ISA, int8 path) */
    enum fk_isa isa;   /* the context's ISA (its FMA peak, its f32 peer)  */
};

/* Attention's peer: our f32 GEMM on the same token count, 1024 -> 1024, same
 * threads, measured in this run (NaN when the GEMM rows were not run). */
static void attention_ratios(struct row *rows, int n)
{
    for (int i = 0; i < n; i++) {
        struct row *r = &rows[i];
        if (strcmp(r->kernel, "attention") != 0)
            continue;
        r->peer_ratio = NAN; /* vs_f32: bench_attention_shape's (bf16 rows) */
        for (int j = 0; j < n; j++)
            if (!strcmp(rows[j].kernel, "gemm") && !strcmp(rows[j].precision, "f32") &&
                rows[j].m == r->m && rows[j].n == 1024 && rows[j].k == 1024 &&
                rows[j].threads == r->threads && rows[j].isa == r->isa)
                r->peer_ratio = r->gflops / rows[j].gflops;
    }
}

static uint64_t rng_state = 88172645463325252ull;
static float frand(void)
{
    rng_state ^= rng_state << 13;
    rng_state ^= rng_state >> 7;
    rng_state ^= rng_state << 17;
    return (float)((rng_state >> 40) * (1.0 / 16777216.0)) * 2.0f - 1.0f;
}

static float *rand_buf(size_t n, float scale)
{
    float *p = malloc(n * sizeof *p);
    if (!p) {
        fprintf(stderr, "f4d-bench: out of memory (%zu floats)\n", n);
        exit(1);
    }
    for (size_t i = 0; i < n; i++)
        p[i] = frand() * scale;
    return p;
}

static void errors_vs(const float *y, const float *ref, size_t n, double *max_rel, double *mean_rel)
{
    double ss = 0, mx = 0, sum = 0;
    for (size_t i = 0; i < n; i++)
        ss += (double)ref[i] * ref[i];
    double rms = sqrt(ss / (double)n) + 1e-30;
    for (size_t i = 0; i < n; i++) {
        double d = fabs((double)y[i] - ref[i]);
        if (d > mx || isnan(d))
            mx = d;
        sum += d;
    }
    *max_rel = mx / rms;
    *mean_rel = sum / (double)n / rms;
}

static fk_ctx *make_ctx(enum fk_isa isa, int threads)
{
    fk_ctx *ctx;
    /* bf16 attention wherever the CPU has it, beside fp32, also where the
     * model's contexts (FK_BF16_AUTO) leave it off */
    struct fk_ctx_config cfg = { .isa = isa, .threads = threads, .bf16 = FK_BF16_ON };
    if (fk_ctx_new(&cfg, &ctx) != F4D_OK) {
        fprintf(stderr, "f4d-bench: cannot create a %s context with %d threads\n",
                fk_isa_name(isa), threads);
        exit(1);
    }
    return ctx;
}

static int cmp_double(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return x < y ? -1 : x > y;
}

/* Before each timed call with threads > 1: 100 us for the idle threads of
 * whichever library ran last to fall asleep (ours spin 4000 pauses, 45 us on
 * the Xeon VM; OpenBLAS 2^OPENBLAS_THREAD_TIMEOUT TSC cycles, set to 2^14
 * below), so that neither is timed beside the other's spinning worker on a
 * 2-core machine, and every timed call pays the same one wake-up. Not
 * longer: a vCPU idle past KVM's halt polling (200 us by default) is
 * descheduled, and the call after a 1 ms settle ran either at its usual time
 * or twice it (226 x 256 <- 64, 2 threads, Xeon VM: 60 or 125 us, both
 * libraries, both weight types), so a row's median of pairs was decided by
 * which side drew the slow wake-up (f16 / f32 0.49-0.60 with best times
 * within 7 %). */
#define SETTLE_NS 100000
static void settle(int threads)
{
    if (threads > 1)
        nanosleep(&(struct timespec){ 0, SETTLE_NS }, NULL);
}

/* Median of num[r] / den[r] over the reps: the ratio of two kernels timed in
 * turn (A B A B ...), so a slow phase of a shared machine hits both sides of
 * a pair instead of one side's best. */
static double paired_ratio(const double *num, const double *den, int reps)
{
    double q[64];
    int n = reps < 64 ? reps : 64;
    for (int r = 0; r < n; r++)
        q[r] = num[r] / den[r];
    qsort(q, (size_t)n, sizeof q[0], cmp_double);
    return n % 2 ? q[n / 2] : 0.5 * (q[n / 2 - 1] + q[n / 2]);
}

static void run_linear(fk_ctx *ctx, const struct fk_linear *L, const float *x, int m, float *y)
{
    if (fk_linear_forward(ctx, L, x, m, L->k, y, L->n, NULL) != F4D_OK) {
        fprintf(stderr, "f4d-bench: %s\n", fk_ctx_error(ctx));
        exit(1);
    }
}

#ifdef F4D_HAVE_OPENBLAS
static void run_openblas(const float *x, const float *w, const float *b, float *y, int m, int n, int k)
{
    for (int i = 0; i < m; i++) /* y = b, then y += x W^T: the same work as ours */
        memcpy(y + (size_t)i * n, b, (size_t)n * sizeof *y);
    cblas_sgemm(CblasRowMajor, CblasNoTrans, CblasTrans, m, n, k, 1.0f, x, k, w, k, 1.0f, y, n);
}
#endif

#define MAX_VAR 12 /* 4 ISAs x f32 / f16 / int8 */

/* One shape: f32, f16 and int8 on each ISA of the run, and OpenBLAS, all
 * packed first and then timed in turn, rep after rep. */
static int bench_gemm_shape(const struct opts *o, int m, int n, int k, struct row *rows, int nrows)
{
    float *x = rand_buf((size_t)m * k, 1.0f), *w = rand_buf((size_t)n * k, 1.0f / sqrtf((float)k));
    float *b = rand_buf((size_t)n, 0.1f);
    float *y32 = malloc((size_t)m * n * sizeof *y32), *y = malloc((size_t)m * n * sizeof *y);
    float *yb = malloc((size_t)m * n * sizeof *yb);
    if (!y32 || !y || !yb) {
        fprintf(stderr, "f4d-bench: out of memory\n");
        exit(1);
    }
    int count = 0, reps_min = o->reps < 63 ? o->reps : 63;
    double flops = 2.0 * m * (double)n * k;
    for (int threads = o->quick ? o->threads_max : 1; threads <= o->threads_max; threads++) {
        fk_ctx *ctxs[4];
        int n_ctx = 0;
        ctxs[n_ctx++] = make_ctx(o->isa, threads);
        if (o->no_avx512 && fk_ctx_isa(ctxs[0]) == FK_ISA_AVX512) { /* timed in the other process */
            fk_ctx_free(ctxs[0]);
            ctxs[0] = make_ctx(FK_ISA_AVX2, threads);
        }
        /* --isa all: every other optimized ISA this CPU has, each with its own paths */
        static const enum fk_isa others[3] = { FK_ISA_AVX2, FK_ISA_AVX2_VNNI, FK_ISA_AVX512 };
        for (int i = 0; o->all_isas && i < 3; i++)
            if (others[i] != fk_ctx_isa(ctxs[0]) && fk_isa_supported(others[i]) &&
                !(o->no_avx512 && others[i] == FK_ISA_AVX512))
                ctxs[n_ctx++] = make_ctx(others[i], threads);
        static const enum fk_wtype types[3] = { FK_W_F32, FK_W_F16, FK_W_Q8 };
        static const char *names[3] = { "f32", "f16", "int8" };
        struct fk_linear L[MAX_VAR];
        double t[MAX_VAR][64], tb[64];
        int nv = 3 * n_ctx;
        /* AVX2-VNNI runs AVX2's f32 and f16 code (only its int8 kernel
         * differs): where AVX2 is in the run too, its f32 / f16 rows are left
         * out and its int8 is paired with AVX2's f32 */
        int skip[MAX_VAR] = { 0 }, ref32[MAX_VAR];
        for (int v = 0; v < nv; v++)
            ref32[v] = v - v % 3;
        for (int c = 0; c < n_ctx; c++)
            if (fk_ctx_isa(ctxs[c]) == FK_ISA_AVX2_VNNI)
                for (int c2 = 0; c2 < n_ctx; c2++)
                    if (fk_ctx_isa(ctxs[c2]) == FK_ISA_AVX2) {
                        skip[3 * c] = skip[3 * c + 1] = 1;
                        ref32[3 * c + 2] = 3 * c2;
                    }
        for (int v = 0; v < nv; v++) {
            fk_ctx *c = ctxs[v / 3];
            if (skip[v])
                continue;
            if (fk_linear_pack(c, &L[v], types[v % 3], w, n, k, b) != F4D_OK) {
                fprintf(stderr, "f4d-bench: %s\n", fk_ctx_error(c));
                exit(1);
            }
        }
        /* one untimed call each (also the outputs the errors come from) */
        double blas_max = NAN, blas_mean = NAN;
        double t_first = bench_now();
        run_linear(ctxs[0], &L[0], x, m, y32);
        t_first = bench_now() - t_first;
#ifdef F4D_HAVE_OPENBLAS
        openblas_set_num_threads(threads);
        run_openblas(x, w, b, yb, m, n, k);
        errors_vs(y32, yb, (size_t)m * n, &blas_max, &blas_mean);
#endif
        double emax[MAX_VAR], emean[MAX_VAR];
        for (int v = 0; v < nv; v++) {
            if (skip[v])
                continue;
            run_linear(ctxs[v / 3], &L[v], x, m, y);
            if (v % 3 == 0) { /* f32 of every ISA: against OpenBLAS, as the first */
                emax[v] = blas_max;
                emean[v] = blas_mean;
            } else {
                errors_vs(y, y32, (size_t)m * n, &emax[v], &emean[v]);
            }
        }
        /* at least --reps pairs, more while a shape's turns stay short (about
         * 1 s in all), at least 5 with 2 threads: a median of 3 pairs swung
         * from 0.38x to 1.3x between runs on the tiny shapes, and this VM's
         * 2 cores slow down together for ~0.3 s at a time (1.75x, every
         * variant: sibling hyperthreads of one host core, it seems), which a
         * median of 3 cannot outvote */
        int reps = (int)(1.0 / ((nv + 1) * (t_first > 1e-6 ? t_first : 1e-6)));
        if (threads > 1 && reps_min < 5)
            reps_min = 5;
        reps = reps < reps_min ? reps_min : reps > 63 ? 63 : reps;
        reps |= 1; /* odd: the median is one pair's ratio */
        for (int r = 0; r < reps; r++) {
            tb[r] = NAN;
#ifdef F4D_HAVE_OPENBLAS
            settle(threads);
            double t0 = now_for(o, threads);
            run_openblas(x, w, b, yb, m, n, k);
            tb[r] = now_for(o, threads) - t0;
#endif
            for (int v = 0; v < nv; v++) {
                if (skip[v])
                    continue;
                settle(threads);
                double t1 = now_for(o, threads);
                run_linear(ctxs[v / 3], &L[v], x, m, y);
                t[v][r] = now_for(o, threads) - t1;
            }
        }
        double best_b = 1e30;
        for (int r = 0; r < reps; r++)
            best_b = tb[r] < best_b ? tb[r] : best_b;
        for (int v = 0; v < nv; v++) {
            if (skip[v])
                continue;
            double best = 1e30;
            for (int r = 0; r < reps; r++)
                best = t[v][r] < best ? t[v][r] : best;
            fk_ctx *c = ctxs[v / 3];
            struct row *rw = &rows[count++];
            if (count > nrows)
                exit(1);
            *rw = (struct row){ "gemm", names[v % 3], threads, m, n, k, flops / best * 1e-9,
                                flops / best_b * 1e-9, emax[v], emean[v],
                                paired_ratio(tb, t[v], reps),
                                v % 3 ? paired_ratio(t[ref32[v]], t[v], reps) : NAN,
                                types[v % 3] == FK_W_Q8 ? fk_ctx_q8_path(c) : fk_isa_name(fk_ctx_isa(c)),
                                fk_ctx_isa(c) };
            fk_linear_free(&L[v]);
        }
        for (int i = 0; i < n_ctx; i++)
            fk_ctx_free(ctxs[i]);
    }
    free(x); free(w); free(b); free(y32); free(y); free(yb);
    return count;
}

/* An attention row's products: fp32, bf16 (desc.bf16) or int16 (desc.int16). */
enum attn_variant { V_F32, V_BF16, V_I16 };

/* The path column of an attention row: the ISA's name for fp32, else the
 * low-precision kernel that ran. */
static const char *attn_path(enum fk_isa isa, enum attn_variant v)
{
    if (v == V_BF16)
        return "avx512-bf16";
    if (v == V_F32)
        return fk_isa_name(isa);
    return isa == FK_ISA_AVX512 ? "avx512-int16" : isa == FK_ISA_AVX2_VNNI ? "vnni-int16" : "avx2-int16";
}

/* One attention call of variant v over the qkv rows into dst: its products
 * set on the desc, int16 on c16 (the context that runs them), the others on
 * ctx; exits on an error. */
static void attention_variant(enum attn_variant v, fk_ctx *ctx, fk_ctx *c16, struct fk_attention_desc *a,
                              const float *qkv, int C, int ntok, float *dst)
{
    a->bf16 = v == V_BF16;
    a->int16 = v == V_I16;
    fk_ctx *cx = v == V_I16 ? c16 : ctx;
    if (fk_attention(cx, a, qkv, 3 * C, ntok, qkv + C, 3 * C, qkv + 2 * C, 3 * C, ntok, dst, C) != F4D_OK) {
        fprintf(stderr, "f4d-bench: %s\n", fk_ctx_error(cx));
        exit(1);
    }
}

/* Attention with the aggregator's settings: qk-norm, 2-D RoPE, 16 heads of 64;
 * f32, and bf16 products (desc.bf16) where the context has AVX512_BF16,
 * int16 products (desc.int16) where it runs them (fk_attention_products). */
static int bench_attention_shape(const struct opts *o, int ntok, int heads, int d, struct row *rows,
                                 int nrows)
{
    int C = heads * d, side = (int)sqrt((double)ntok);
    float *qkv = rand_buf((size_t)ntok * 3 * C, 1.0f), *out = malloc((size_t)ntok * C * sizeof *out);
    float *out16 = malloc((size_t)ntok * C * sizeof *out16);
    float *nw = rand_buf((size_t)d, 0.5f), *nb = rand_buf((size_t)d, 0.1f);
    int32_t *pos = malloc((size_t)ntok * 2 * sizeof *pos);
    if (!out || !out16 || !pos)
        exit(1);
    for (int i = 0; i < d; i++)
        nw[i] += 1.0f;
    for (int t = 0; t < ntok; t++) { /* a per-frame grid repeated, specials at 0 */
        int p = t % (side * side + 5);
        pos[2 * t] = p < 5 ? 0 : (p - 5) / side + 1;
        pos[2 * t + 1] = p < 5 ? 0 : (p - 5) % side + 1;
    }
    struct fk_attention_desc a = { .heads = heads, .head_dim = d, .q_norm_w = nw, .q_norm_b = nb,
                                   .k_norm_w = nw, .k_norm_b = nb, .norm_eps = 1e-5f,
                                   .pos_q = pos, .pos_k = pos, .rope_base = 100.0f };
    /* reference on a sample of query rows */
    int nsample = 48 < ntok ? 48 : ntok;
    float *ref = malloc((size_t)nsample * C * sizeof *ref);
    fk_ctx *rctx = make_ctx(FK_ISA_REF, 1);
    if (!ref || fk_attention(rctx, &a, qkv, 3 * C, nsample, qkv + C, 3 * C, qkv + 2 * C, 3 * C,
                             ntok, ref, C) != F4D_OK) {
        fprintf(stderr, "f4d-bench: reference attention: %s\n", fk_ctx_error(rctx));
        exit(1);
    }
    fk_ctx_free(rctx);
    int count = 0;
    for (int threads = o->quick ? o->threads_max : 1; threads <= o->threads_max; threads++) {
        /* --isa all: also AVX2's and AVX2-VNNI's attention where the first
         * ISA is AVX-512 (their fp32 code is the same; their int16 products
         * are not) */
        fk_ctx *ctxs[3] = { make_ctx(o->isa, threads), NULL, NULL };
        int n_ctx = 1;
        if (o->all_isas && fk_ctx_isa(ctxs[0]) == FK_ISA_AVX512 && fk_isa_supported(FK_ISA_AVX2))
            ctxs[n_ctx++] = make_ctx(FK_ISA_AVX2, threads);
        if (o->all_isas && fk_ctx_isa(ctxs[0]) == FK_ISA_AVX512 && fk_isa_supported(FK_ISA_AVX2_VNNI))
            ctxs[n_ctx++] = make_ctx(FK_ISA_AVX2_VNNI, threads);
        for (int c = 0; c < n_ctx; c++) {
            fk_ctx *ctx = ctxs[c];
            /* f32, bf16 products where the context has AVX512_BF16, int16
             * ones where a context of this ISA without bf16 runs them (AVX2,
             * AVX2-VNNI; AVX-512 with FK_BF16_OFF, Intel's default): in turn
             * rep after rep (xf32 of such a row: the median pair ratio) */
            fk_ctx *x16 = NULL;
            if (fk_ctx_isa(ctx) == FK_ISA_AVX512) {
                struct fk_ctx_config cfg = { .isa = FK_ISA_AVX512, .threads = threads, .bf16 = FK_BF16_OFF };
                if (fk_ctx_new(&cfg, &x16) != F4D_OK)
                    exit(1);
            }
            fk_ctx *c16 = x16 ? x16 : ctx;
            enum attn_variant kind[3];
            int nv = 0, reps = o->reps < 63 ? o->reps : 63;
            kind[nv++] = V_F32;
            if (fk_ctx_has_bf16(ctx))
                kind[nv++] = V_BF16;
            a.bf16 = 0;
            a.int16 = 1;
            if (fk_attention_products(c16, &a) == FK_ATTN_INT16)
                kind[nv++] = V_I16;
            a.int16 = 0;
            double t[3][63];
            for (int r = 0; r < reps; r++)
                for (int vr = 0; vr < nv; vr++) {
                    settle(threads);
                    double t0 = now_for(o, threads);
                    attention_variant(kind[vr], ctx, c16, &a, qkv, C, ntok, vr ? out16 : out);
                    t[vr][r] = now_for(o, threads) - t0;
                }
            if (count + nv > nrows) {
                fprintf(stderr, "f4d-bench: more attention rows than the table holds (%d)\n", nrows);
                exit(1);
            }
            for (int vr = 0; vr < nv; vr++) {
                double best = 1e30;
                for (int r = 0; r < reps; r++)
                    best = t[vr][r] < best ? t[vr][r] : best;
                struct row *r = &rows[count++];
                *r = (struct row){ "attention", kind[vr] == V_F32 ? "f32" : kind[vr] == V_BF16 ? "bf16" : "int16",
                                   threads, ntok, ntok, d,
                                   4.0 * d * (double)ntok * ntok * heads / best * 1e-9, NAN, NAN, NAN, NAN,
                                   vr ? paired_ratio(t[0], t[vr], reps) : NAN,
                                   attn_path(fk_ctx_isa(ctx), kind[vr]),
                                   fk_ctx_isa(ctx) };
                /* out16 holds the last variant's output: each low-precision
                 * one is run once more for its errors */
                if (vr)
                    attention_variant(kind[vr], ctx, c16, &a, qkv, C, ntok, out16);
                errors_vs(vr ? out16 : out, ref, (size_t)nsample * C, &r->max_rel_err, &r->mean_rel_err);
            }
            fk_ctx_free(x16);
            a.bf16 = a.int16 = 0;
            fk_ctx_free(ctx);
        }
    }
    free(qkv); free(out); free(out16); free(nw); free(nb); free(pos); free(ref);
    return count;
}

static cJSON *num_or_null(double v)
{
    return isfinite(v) ? cJSON_CreateNumber(v) : cJSON_CreateNull();
}

/* FMA peak readings, GFLOP/s: ymm and zmm (NAN without AVX-512), all
 * threads and one (best of 3 repeats each). */
struct peaks {
    double y, y1, z, z1;
};

static struct peaks read_peaks(int threads, int zmm)
{
    struct peaks p;
    p.y = bench_fma_peak_gflops(threads, 3);
    p.y1 = bench_fma_peak_gflops(1, 3);
    p.z = zmm ? bench_fma_peak_gflops_isa(threads, 3, FK_ISA_AVX512) : NAN;
    p.z1 = zmm ? bench_fma_peak_gflops_isa(1, 3, FK_ISA_AVX512) : NAN;
    return p;
}

static void print_peaks(const struct peaks *p, int threads, int zmm)
{
    printf("%.1f GFLOP/s (1 thread) %.1f (%d threads) with ymm", p->y1, p->y, threads);
    if (zmm)
        printf("; %.1f / %.1f with zmm (the AVX-512 rows' peak)", p->z1, p->z);
    printf("\n");
}

static int write_json(const char *path, double peak, const struct row *rows, int n, enum fk_isa isa)
{
    cJSON *root = cJSON_CreateObject(), *arr = cJSON_CreateArray();
    cJSON_AddItemToObject(root, "peak_gflops", cJSON_CreateNumber(peak));
    cJSON_AddItemToObject(root, "isa", cJSON_CreateString(fk_isa_name(isa)));
    for (int i = 0; i < n; i++) {
        const struct row *r = &rows[i];
        cJSON *o = cJSON_CreateObject();
        cJSON_AddItemToObject(o, "kernel", cJSON_CreateString(r->kernel));
        cJSON_AddItemToObject(o, "precision", cJSON_CreateString(r->precision));
        cJSON_AddItemToObject(o, "threads", cJSON_CreateNumber(r->threads));
        cJSON_AddItemToObject(o, "m", cJSON_CreateNumber(r->m));
        cJSON_AddItemToObject(o, "n", cJSON_CreateNumber(r->n));
        cJSON_AddItemToObject(o, "k", cJSON_CreateNumber(r->k));
        cJSON_AddItemToObject(o, "gflops", num_or_null(r->gflops));
        cJSON_AddItemToObject(o, "openblas_gflops", num_or_null(r->openblas_gflops));
        cJSON_AddItemToObject(o, "max_rel_err", num_or_null(r->max_rel_err));
        cJSON_AddItemToObject(o, "mean_rel_err", num_or_null(r->mean_rel_err));
        cJSON_AddItemToObject(o, "path", cJSON_CreateString(r->path));
        cJSON_AddItemToObject(o, "isa", cJSON_CreateString(fk_isa_name(r->isa)));
        if (!strcmp(r->kernel, "gemm")) /* median of paired reps: ours vs OpenBLAS */
            cJSON_AddItemToObject(o, "vs_openblas", num_or_null(r->peer_ratio));
        if (strcmp(r->precision, "f32")) /* extra: vs our f32 (GEMM f16/int8, attention bf16) */
            cJSON_AddItemToObject(o, "vs_f32", num_or_null(r->vs_f32));
        if (!strcmp(r->kernel, "attention")) /* extra: the goal is stated against our f32 GEMM */
            cJSON_AddItemToObject(o, "vs_f32_gemm", num_or_null(r->peer_ratio));
        cJSON_AddItemToArray(arr, o);
    }
    cJSON_AddItemToObject(root, "results", arr);
    char *s = cJSON_Print(root);
    FILE *f = fopen(path, "w");
    int ok = f && s && fputs(s, f) >= 0;
    if (f && fclose(f) != 0)
        ok = 0;
    free(s);
    cJSON_Delete(root);
    if (!ok) {
        fprintf(stderr, "f4d-bench: cannot write %s\n", path);
        return 1;
    }
    return 0;
}

/* The CPU's model name and the flags the kernels care about (Linux). */
static void print_cpu(void)
{
    char line[4096], model[256] = "unknown";
    static const char *const want[] = { "avx2", "fma", "f16c", "avx_vnni", "avx512f", "avx512bw",
                                        "avx512vl", "avx512_vnni", "avx512_bf16", "amx_int8", "asimd",
                                        "asimddp", "sve" };
    char have[256] = "";
    FILE *f = fopen("/proc/cpuinfo", "r");
    int got_flags = 0;
    while (f && fgets(line, sizeof line, f)) {
        char *v = strchr(line, ':');
        if (!v)
            continue;
        v += 2;
        if (!strncmp(line, "model name", 10) && !strcmp(model, "unknown")) {
            snprintf(model, sizeof model, "%s", v);
            model[strcspn(model, "\n")] = 0;
        } else if ((!strncmp(line, "flags", 5) || !strncmp(line, "Features", 8)) && !got_flags) {
            got_flags = 1;
            for (size_t i = 0; i < sizeof want / sizeof want[0]; i++) {
                char pat[32];
                size_t len = strlen(want[i]);
                snprintf(pat, sizeof pat, " %s", want[i]);
                for (char *p = strstr(v - 1, pat); p; p = strstr(p + 1, pat))
                    if (p[len + 1] == ' ' || p[len + 1] == '\n') {
                        strncat(have, want[i], sizeof have - strlen(have) - 2);
                        strcat(have, " ");
                        break;
                    }
            }
        }
    }
    if (f)
        fclose(f);
    printf("cpu: %s; flags: %s\n", model, have[0] ? have : "(none of interest)");
}

static int parse(int argc, char **argv, struct opts *o)
{
    *o = (struct opts){ 0, 3, 2, NULL, FK_ISA_AUTO, 0, NULL, 0, 0, { 0, 0, 0 }, 0, 0 };
    for (int i = 1; i < argc; i++) {
        const char *a = argv[i];
        if (!strcmp(a, "--quick")) {
            o->quick = 1;
        } else if (!strcmp(a, "--json") && i + 1 < argc) {
            o->json = argv[++i];
        } else if (!strcmp(a, "--clock") && i + 1 < argc &&
                   (!strcmp(argv[i + 1], "cpu") || !strcmp(argv[i + 1], "wall"))) {
            o->cpu_clock = !strcmp(argv[++i], "cpu");
        } else if (!strcmp(a, "--rows-out")) {
            o->rows_out = 1;
        } else if (!strcmp(a, "--openblas-native")) {
            o->openblas_native = 1;
        } else if (!strcmp(a, "--only") && i + 1 < argc) {
            o->only = argv[++i];
            if (strcmp(o->only, "gemm") && strcmp(o->only, "attention")) {
                fprintf(stderr, "f4d-bench kernels: --only takes gemm or attention, not '%s'\n", o->only);
                return 2;
            }
        } else if (!strcmp(a, "--shape") && i + 1 < argc) {
            if (sscanf(argv[++i], "%d,%d,%d", &o->shape[0], &o->shape[1], &o->shape[2]) != 3 ||
                o->shape[0] < 1 || o->shape[1] < 1 || o->shape[2] < 1) {
                fprintf(stderr, "f4d-bench kernels: --shape takes M,N,K (tokens, outputs, inputs), not '%s'\n", argv[i]);
                return 2;
            }
        } else if (!strcmp(a, "--reps") && i + 1 < argc) {
            o->reps = atoi(argv[++i]);
        } else if (!strcmp(a, "--threads") && i + 1 < argc) {
            o->threads_max = atoi(argv[++i]);
        } else if (!strcmp(a, "--isa") && i + 1 < argc && !strcmp(argv[i + 1], "all")) {
            o->all_isas = 1;
            i++;
        } else if (!strcmp(a, "--isa") && i + 1 < argc) {
            o->isa = fk_isa_from_name(argv[++i]);
            if ((int)o->isa < 0 || !fk_isa_supported(o->isa)) {
                fprintf(stderr, "f4d-bench kernels: ISA '%s' is unknown or not supported here\n", argv[i]);
                return 2;
            }
        } else {
            fprintf(stderr, "usage: f4d-bench kernels [--quick] [--reps N] [--threads N] "
                            "[--isa auto|ref|avx2|avx2-vnni|avx512|all] [--only gemm|attention] [--openblas-native] [--clock wall|cpu] [--shape M,N,K] [--json FILE]\n"
                            "f4d-bench kernels: unexpected argument '%s'\n", a);
            return 2;
        }
    }
    if (o->reps < 1 || o->threads_max < 1 || o->threads_max > 64) {
        fprintf(stderr, "f4d-bench kernels: --reps and --threads must be positive\n");
        return 2;
    }
    return 0;
}

#ifdef F4D_HAVE_OPENBLAS
/* --isa all on an AVX-512 CPU: one process has one OpenBLAS kernel set, so
 * the AVX-512 GEMM rows run in a second process of this program with
 * OPENBLAS_CORETYPE=SkylakeX (`--isa avx512 --only gemm --rows-out`, the same
 * shapes, threads, reps and clock), and its "ROW" lines join the table: every
 * row's xpeer is then against OpenBLAS on the same vectors. path[] keeps the
 * rows' path names. Returns the rows added, or -1 (with a message). */
static int avx512_rows_from_child(const struct opts *o, struct row *rows, int room, char (*path)[32])
{
    char exe[4096], cmd[8192];
    ssize_t len = readlink("/proc/self/exe", exe, sizeof exe - 1);
    if (len <= 0) {
        fprintf(stderr, "f4d-bench kernels: cannot find this program for the AVX-512 rows\n");
        return -1;
    }
    exe[len] = 0;
    char shape[64] = "";
    if (o->shape[0])
        snprintf(shape, sizeof shape, " --shape %d,%d,%d", o->shape[0], o->shape[1], o->shape[2]);
    snprintf(cmd, sizeof cmd,
             "OPENBLAS_CORETYPE=SkylakeX F4D_BENCH_OPENBLAS_SET=1 '%s' kernels --isa avx512 --only gemm "
             "--threads %d --reps %d --clock %s%s%s --rows-out",
             exe, o->threads_max, o->reps, o->cpu_clock ? "cpu" : "wall", o->quick ? " --quick" : "", shape);
    FILE *f = popen(cmd, "r");
    if (!f) {
        fprintf(stderr, "f4d-bench kernels: cannot start the AVX-512 rows' process\n");
        return -1;
    }
    char line[512];
    int n = 0;
    while (fgets(line, sizeof line, f)) {
        struct row r = { "gemm", NULL, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, NULL, FK_ISA_AVX512 };
        char prec[8];
        if (n >= room || sscanf(line, "ROW gemm %7s %31s %d %d %d %d %lf %lf %lf %lf %lf %lf", prec, path[n],
                                &r.threads, &r.m, &r.n, &r.k, &r.gflops, &r.openblas_gflops, &r.peer_ratio,
                                &r.vs_f32, &r.max_rel_err, &r.mean_rel_err) != 12)
            continue;
        r.precision = !strcmp(prec, "f32") ? "f32" : !strcmp(prec, "f16") ? "f16" : "int8";
        r.path = path[n];
        rows[n++] = r;
    }
    int st = pclose(f);
    if (st != 0 || n == 0) {
        fprintf(stderr, "f4d-bench kernels: the AVX-512 rows' process failed (status %d, %d rows)\n", st, n);
        return -1;
    }
    return n;
}
#endif

/* argv is main's argv + 1 (the subcommand first). */
int bench_kernels(int argc, char **argv)
{
    struct opts o;
    int st = parse(argc, argv, &o);
    if (st)
        return st;
#ifdef F4D_HAVE_OPENBLAS
    /* OpenBLAS picks its kernels at load time; unless asked for its native
     * choice, restart once with the kernels of our ISA so that both sides use
     * the same vectors: SkylakeX (AVX-512) when the run's ISA is AVX-512 alone,
     * else Haswell (AVX2; --isa all: its AVX-512 GEMM rows in a SkylakeX child). An
     * OPENBLAS_CORETYPE inherited from the environment is replaced (this
     * machine's shell had Haswell set, which made --isa avx512 and
     * --openblas-native compare with Haswell); F4D_BENCH_OPENBLAS_SET marks
     * the restarted process.
     * Also read at load: how long OpenBLAS's idle workers spin before they
     * sleep, 2^28 TSC cycles by default (0.1 s). On a 2-core machine that
     * spin took a core from whatever ran next: after each OpenBLAS call it
     * slowed our f32 GEMM timed next (2 threads, Zen 5: medians of pairs
     * 0.60-0.92x on shapes where best times gave 1.01-1.06x). 2^14 cycles
     * (6 us at a 2.6 GHz TSC) ends well inside the settle before each timed
     * call; the user's own setting is kept. */
    const char *inherited = getenv("OPENBLAS_CORETYPE");
    int set_timeout = !getenv("OPENBLAS_THREAD_TIMEOUT");
    if (!getenv("F4D_BENCH_OPENBLAS_SET") &&
        ((fk_isa_supported(FK_ISA_AVX2) && (!o.openblas_native || inherited)) || set_timeout)) {
        const char *core = NULL;
        if (!o.openblas_native && fk_isa_supported(FK_ISA_AVX2)) {
            fk_ctx *p0 = make_ctx(o.isa, 1);
            core = fk_ctx_isa(p0) == FK_ISA_AVX512 && !o.all_isas ? "SkylakeX" : "Haswell";
            fk_ctx_free(p0);
        }
        if (inherited && (!core || strcmp(inherited, core)))
            fprintf(stderr, "f4d-bench kernels: OPENBLAS_CORETYPE=%s from the environment replaced by %s\n",
                    inherited, core ? core : "OpenBLAS's own choice");
        if (core)
            setenv("OPENBLAS_CORETYPE", core, 1);
        else if (o.openblas_native)
            unsetenv("OPENBLAS_CORETYPE");
        if (set_timeout)
            setenv("OPENBLAS_THREAD_TIMEOUT", "14", 1);
        setenv("F4D_BENCH_OPENBLAS_SET", "1", 1);
        execv("/proc/self/exe", argv - 1);
        fprintf(stderr, "f4d-bench kernels: cannot restart with OPENBLAS_CORETYPE=%s; "
                        "OpenBLAS keeps its own choice\n", core ? core : "(unset)");
    }
#endif
    fk_ctx *probe = make_ctx(o.isa, 1);
    enum fk_isa isa = fk_ctx_isa(probe);
    struct fk_cache_info ci = fk_ctx_caches(probe);
    struct fk_gemm_blocks bl = fk_ctx_gemm_blocks(probe);
    static const char *const src_names[] = { "defaults", "cpuid", "sysfs", "given (FK_CACHES/config)" };
    print_cpu();
    printf("caches (%s): L1d %zu KiB, L2 %zu KiB (%zu per core), L3 %zu KiB (%zu KiB per core)\n",
           src_names[ci.source & 3], ci.l1d >> 10, ci.l2 >> 10,
           (ci.l2_share ? ci.l2_share : ci.l2) >> 10, ci.l3 >> 10, ci.l3_share >> 10);
    printf("GEMM blocks%s: kc %d, mc %d, nc %d (fp32, a 16-column sliver; AVX-512 pairs of kc / 2; int8 kc x 4); "
           "int8 path %s\n",
           getenv("FK_GEMM_BLOCKS") ? " (FK_GEMM_BLOCKS)" : "", bl.kc, bl.mc, bl.nc, fk_ctx_q8_path(probe));
    fk_ctx_free(probe);

    /* the FMA peak per vector width: ymm for the AVX2 ISAs, zmm for AVX-512 */
    int zmm = isa == FK_ISA_AVX512 || (o.all_isas && fk_isa_supported(FK_ISA_AVX512));
    struct peaks pk0 = read_peaks(o.threads_max, zmm);
    printf("f4d-bench kernels: isa %s, fp32 FMA peak ", fk_isa_name(isa));
    print_peaks(&pk0, o.threads_max, zmm);
    bench_print_int_ceilings(bench_int_ceilings(fk_cpu_features(), 5));
    int gemm = !o.only || !strcmp(o.only, "gemm"), attn = !o.only || !strcmp(o.only, "attention");
#ifdef F4D_HAVE_OPENBLAS
    o.no_avx512 = o.all_isas && !o.openblas_native && gemm && fk_isa_supported(FK_ISA_AVX512) &&
                  getenv("OPENBLAS_CORETYPE") && !strcmp(getenv("OPENBLAS_CORETYPE"), "Haswell");
    printf("peer: OpenBLAS sgemm, %s kernels%s, idle workers spin 2^%s cycles (OPENBLAS_THREAD_TIMEOUT)%s%s\n",
           openblas_get_corename(), getenv("OPENBLAS_CORETYPE") ? " (OPENBLAS_CORETYPE)" : "",
           getenv("OPENBLAS_THREAD_TIMEOUT") ? getenv("OPENBLAS_THREAD_TIMEOUT") : "28",
           o.threads_max > 1 ? "; 100 us settle before each timed multi-thread call" : "",
           o.no_avx512 ? "; the avx512 GEMM rows: SkylakeX kernels, in a second process" : "");
#else
    printf("peer: OpenBLAS not built in (F4D_BENCH_OPENBLAS=OFF)\n");
#endif

    static const int real_nk[][2] = { { 1024, 1024 }, { 3072, 1024 }, { 4096, 1024 }, { 1024, 4096 } };
    static const int tiny_nk[][2] = { { 64, 64 }, { 192, 64 }, { 256, 64 }, { 64, 256 } };
    enum { MAX_ROWS = 512 }; /* --isa all: ~220 GEMM rows, up to 54 attention rows */
    struct row rows[MAX_ROWS];
    int n = 0, failed = 0;
    int tok_real[2] = { 1374, 5496 };
    if (o.shape[0]) /* one GEMM shape, for a focused measurement */
        n += bench_gemm_shape(&o, o.shape[0], o.shape[1], o.shape[2], rows + n, MAX_ROWS - n);
    for (int t = 0; gemm && !o.shape[0] && t < (o.quick ? 1 : 2); t++)
        for (int s = 0; s < 4; s++)
            n += bench_gemm_shape(&o, tok_real[t], real_nk[s][0], real_nk[s][1], rows + n, MAX_ROWS - n);
    for (int s = 0; gemm && !o.shape[0] && s < 4; s++) /* tiny test model: 2 views of 5 + 12x9 patches */
        n += bench_gemm_shape(&o, 226, tiny_nk[s][0], tiny_nk[s][1], rows + n, MAX_ROWS - n);
#ifdef F4D_HAVE_OPENBLAS
    char child_paths[128][32];
    if (o.no_avx512) {
        int c = avx512_rows_from_child(&o, rows + n, MAX_ROWS - n < 128 ? MAX_ROWS - n : 128, child_paths);
        n += c > 0 ? c : 0;
        failed = c < 0;
    }
#endif
    attn = attn && !o.shape[0];
    for (int t = 0; attn && t < (o.quick ? 1 : 2); t++)
        n += bench_attention_shape(&o, tok_real[t], 16, 64, rows + n, MAX_ROWS - n);
    if (attn)
        n += bench_attention_shape(&o, 226, 4, 16, rows + n, MAX_ROWS - n);

    attention_ratios(rows, n);
    /* Read again after the rows, each xpeak against the higher reading: on
     * a shared VM one reading of 3 repeats can catch both threads on one
     * physical core (Zen 5: 2-thread zmm 241-258 against 433-492 in the
     * same hour), which flattered every multi-thread row by 2x. */
    struct peaks pk1 = read_peaks(o.threads_max, zmm);
    printf("FMA peak read again after the rows: ");
    print_peaks(&pk1, o.threads_max, zmm);
    double peak = fmax(pk0.y, pk1.y), peak1 = fmax(pk0.y1, pk1.y1);
    double zpeak = fmax(pk0.z, pk1.z), zpeak1 = fmax(pk0.z1, pk1.z1);
    printf("\n%-9s %-5s %-16s %2s %5s %5s %5s %9s %9s %7s %6s %7s %10s %10s\n", "kernel", "prec", "path",
           "th", "m", "n", "k", "GFLOP/s", "OpenBLAS", "xpeer", "xf32", "xpeak", "max_rel", "mean_rel");
    for (int i = 0; i < n; i++) {
        const struct row *r = &rows[i];
        int z = r->isa == FK_ISA_AVX512;
        double pk = r->threads == 1 ? (z ? zpeak1 : peak1)
                                    : (z ? zpeak : peak) * r->threads / o.threads_max;
        printf("%-9s %-5s %-16s %2d %5d %5d %5d %9.1f %9.1f %7.2f %6.2f %7.2f %10.2e %10.2e\n", r->kernel,
               r->precision, r->path, r->threads, r->m, r->n, r->k, r->gflops, r->openblas_gflops,
               r->peer_ratio, r->vs_f32, r->gflops / pk, r->max_rel_err, r->mean_rel_err);
    }
    for (int i = 0; o.rows_out && i < n; i++) { /* for the process that asked (avx512_rows_from_child) */
        const struct row *r = &rows[i];
        if (!strcmp(r->kernel, "gemm"))
            printf("ROW gemm %s %s %d %d %d %d %.17g %.17g %.17g %.17g %.17g %.17g\n", r->precision, r->path,
                   r->threads, r->m, r->n, r->k, r->gflops, r->openblas_gflops, r->peer_ratio, r->vs_f32,
                   r->max_rel_err, r->mean_rel_err);
    }
    printf("\nerrors are relative to the RMS of the fp32 output: f32 vs OpenBLAS, f16/int8 vs our f32,\n"
           "attention vs the scalar reference on 48 query rows. GFLOP/s: best of %d runs (GEMM: at\n"
           "least, 5 with threads, up to 63 while a shape's reps take under 1 s, odd). GEMM: every\n"
           "variant of a shape (each ISA's f32 / f16 / int8, and OpenBLAS) runs in turn, rep after rep;\n"
           "xpeer = median over reps of OpenBLAS's time / ours in the same rep; xf32 = median of the\n"
           "same ISA's f32 time / this row's (f16, int8). Attention: xpeer = ours / our f32 GEMM (same\n"
           "ISA, tokens, 1024 -> 1024), best of runs; bf16 rows (q.k and p.v in bf16, where the CPU\n"
           "has AVX512_BF16) and int16 rows (in int16, on the AVX2 context) run in turn with f32,\n"
           "xf32 = median of f32 time / theirs. xpeak = ours /\n"
           "the FMA peak for those threads (zmm for avx512 rows, ymm otherwise; the higher of the\n"
           "readings before and after the rows). Clock: %s.\n", o.reps,
           o.cpu_clock ? "the thread's CPU time for 1-thread rows (--clock cpu), wall otherwise" : "wall");
    int jst = o.json ? write_json(o.json, peak, rows, n, isa) : 0;
    return jst ? jst : failed;
}
