/* bench_model.c - f4d-bench model: the VGGT forward, per stage, per precision.
 *
 *   f4d-bench model [--json FILE] [--threads N] [--views S] [--size HxW]
 *                   [--reps R] [--skip-full] [--stream-only | --skip-stream] [--tmp DIR]
 *                   [--isa NAME|all] [--clock wall|cpu] [--precision f32|f16|int8]
 *
 * --clock cpu (with --threads 1): every Eval's time and stage times are scaled
 * by its thread CPU time over its wall time, and the FMA peak is timed on the
 * thread's CPU clock too: the figures a shared, loaded machine can still give.
 *
 * tiny: a small random-weight config (embed 128, depth 4) end to end, best of
 *       R runs: ms and GFLOP/s per stage.
 * full: the VGGT-1B dimensions on random weights, built with ONE DINO block,
 *       ONE frame and ONE global block and ONE DPT head, run on S views of
 *       HxW (default 4 x 518x518), R runs, each stage's best of them
 *       (stages only, 1-2 s each: a shared machine's slow spells hit
 *       some runs of a stage and not others); the full forward is extrapolated as
 *       patch + 24 (dino + frame + global) + 2 DPT heads + camera head, the
 *       camera head (6.9 GFLOP, 0.04 %) counted at the measured frame-block
 *       rate. Per precision (f32, f16, int8 weights in every linear and
 *       convolution layer but the patchify), the error against the f32 run of
 *       the same weights: max |x - x_f32| / max |x_f32| over the aggregator
 *       output and the depth map. Also the arena of the full 4 x 518^2 plan.
 *       int8 names the kernel path that ran (vnni-8bit, avx2-7bit, ...)
 *       and its attention (bf16 products where AVX512_BF16, else f32);
 *       --isa forces one ISA, --isa all runs f16 on the best ISA and f32
 *       and int8 on every ISA this CPU has, side by side; each int8 speed is
 *       over its own ISA's f32, each forward's GFLOP/s over the FMA peak of
 *       its vector width (zmm for AVX-512, ymm else): the best of the readings
 *       taken before and after every run of that width in the process;
 *       --precision f32|f16|int8 runs f32 and that one only.
 * Forge4D streaming (forge4d-arch.md 4-5): the tiny model carries state,
 *       motion and fusion too and is timed on a motion step (the second and
 *       later Evals); full: VGGT-1B dims with one state block, one motion
 *       block and the motion head (f32), best of R motion steps. The
 *       motion-step / key-frame ratio (paper: 47.77 / 176.50 ms = 27 %):
 *       motion = in_proj + both motion runs of every motion layer + both
 *       motion head runs; key frame = everything else of the Eval (full:
 *       extrapolated to 24 layers and the depth, point and Gaussian DPT
 *       heads). Full: the default motion config (model_config_default: the
 *       4 DPT layers, motion_dpt_features) and, from the same run, the head
 *       at the other widths (dpt_features, 64) and every layer with a motion
 *       block (forge4d-arch.md 5 as written). --stream-only skips the
 *       per-precision VGGT rows.
 * JSON: {"tiny": [{"stage","ms","gflops"}], "full": [{"precision","seconds",
 *        "max_rel_err", ...}], "stream": {...}, ...}.
 *
 *   f4d-bench model --weights W.gguf [--views S] [--size HxW] [--reps R]
 *                   [--skip-head PREFIX] [--precision f32|f16|int8]
 *
 * times a given weight file (the shipped model: its own img_size unless
 * --size) per stage at f32, f16 and int8, best of R steps (with motion
 * weights, motion steps), and exits; --skip-head depth_head times what the
 * streaming path (forge4d run, f4d_sequence_open) runs.
 *
 *   f4d-bench model --write-random OUT.gguf [--preset tiny|mid|full1]
 *
 * writes a random-weight model with every head (Forge4D's Gaussian and scale
 * heads included) and exits: for timing `forge4d run` and the like without
 * trained weights. tiny: the config above (img 126); mid: embed 384, depth 8,
 * 6 heads, 4 DINO blocks, img 224 (about ViT-S width); full1: the full rows'
 * model (VGGT-1B dims, one block of each kind, the depth head), e.g. for
 * `--weights F --skip-head depth_head --precision f32` under a profiler.
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#include "bench.h"
#include "fk_ctx.h"
#include "gguf.h"
#include "model.h"
#include "peak.h"

struct rng {
    uint64_t s;
};

/* the products of int8 weights' attention on this context (model_block.c
 * sets desc.bf16 and desc.int16 for int8 weights) */
static const char *attn_kind(const fk_ctx *ctx)
{
    return fk_ctx_has_bf16(ctx) ? "bf16" : fk_ctx_has_int16(ctx) ? "int16" : "f32";
}

static double rnd_normal(struct rng *r)
{
    /* xorshift64* -> two uniforms -> Box-Muller */
    double u[2];
    for (int i = 0; i < 2; i++) {
        r->s ^= r->s >> 12;
        r->s ^= r->s << 25;
        r->s ^= r->s >> 27;
        u[i] = ((r->s * UINT64_C(2685821657736338717)) >> 11) * (1.0 / 9007199254740992.0);
    }
    return sqrt(-2.0 * log(u[0] + 1e-300)) * cos(6.283185307179586 * u[1]);
}

struct gen {
    gguf_writer *w;
    struct rng   rng;
    int          pass;
    float       *buf;
    size_t       cap;
};

/* Random weights with activations in a realistic range: LayerScale 0.1,
 * Linear/conv N(0, 1/fan_in), norms near 1, small biases. */
static int gen_tensor(void *user, const struct model_tensor_info *t)
{
    struct gen *g = user;
    if (t->tclass == MODEL_T_UNUSED)
        return 0;
    if (g->pass == 0)
        return gguf_writer_add_tensor(g->w, t->name, GGUF_T_F32, t->n_dims, t->shape);
    size_t n = 1;
    for (int i = 0; i < t->n_dims; i++)
        n *= (size_t)t->shape[i];
    if (n > g->cap) {
        free(g->buf);
        g->buf = malloc(n * sizeof *g->buf);
        g->cap = g->buf ? n : 0;
        if (!g->buf)
            return -1;
    }
    const char *nm = t->name;
    size_t len = strlen(nm);
    int is_gamma = len > 6 && !strcmp(nm + len - 6, ".gamma");
    int is_bias = len > 5 && !strcmp(nm + len - 5, ".bias");
    int is_norm = strstr(nm, "norm") && len > 7 && !strcmp(nm + len - 7, ".weight");
    double fan_in = (double)n / (double)t->shape[t->qaxis];
    for (size_t i = 0; i < n; i++) {
        double v;
        if (is_gamma)
            v = 0.1;
        else if (is_bias)
            v = 0.02 * rnd_normal(&g->rng);
        else if (is_norm)
            v = 1.0 + 0.05 * rnd_normal(&g->rng);
        else if (t->tclass == MODEL_T_QUANT || strstr(nm, "proj.weight"))
            v = rnd_normal(&g->rng) / sqrt(fan_in);
        else
            v = 0.5 * rnd_normal(&g->rng);
        g->buf[i] = (float)v;
    }
    return gguf_writer_write(g->w, g->buf, n * sizeof *g->buf);
}

int bench_write_random_model(const char *path, const struct model_config *c, unsigned groups)
{
    struct gen g = { gguf_writer_new(), { UINT64_C(0x9e3779b97f4a7c15) }, 0, NULL, 0 };
    int rc = -1;
    if (!g.w || model_config_write(c, g.w) < 0 ||
        gguf_writer_add_str(g.w, "forge4d.file_type", "f32") < 0)
        goto out;
    if (model_schema_foreach(c, groups, gen_tensor, &g) < 0 || gguf_writer_begin(g.w, path) < 0)
        goto out;
    g.pass = 1;
    if (model_schema_foreach(c, groups, gen_tensor, &g) < 0 || gguf_writer_finish(g.w) < 0)
        goto out;
    rc = 0;
out:
    if (rc < 0)
        fprintf(stderr, "f4d-bench model: cannot write '%s': %s\n", path,
                g.w ? gguf_writer_error(g.w) : "out of memory");
    gguf_writer_free(g.w);
    free(g.buf);
    return rc;
}

void bench_preset_tiny(struct model_config *c)
{
    model_config_default(c);
    c->img_size = 126; c->embed_dim = 128; c->depth = 4; c->num_heads = 4;
    c->num_register_tokens = 4; c->dino_depth = 2; c->dino_num_heads = 4;
    c->camera_trunk_depth = 1; c->camera_num_heads = 4; c->camera_iters = 4;
    c->dpt_features = 32;
    c->dpt_out_channels[0] = 32; c->dpt_out_channels[1] = 64;
    c->dpt_out_channels[2] = 128; c->dpt_out_channels[3] = 128;
    c->dpt_layer_idx[0] = 0; c->dpt_layer_idx[1] = 1;
    c->dpt_layer_idx[2] = 2; c->dpt_layer_idx[3] = 3;
}

/* The full rows' model: VGGT-1B dimensions with one DINO, one frame and one
 * global block, the DPT head reading layer 0, one motion layer; written
 * with the aggregator and the depth head (PRESET_FULL1_GROUPS). */
#define PRESET_FULL1_GROUPS (MODEL_G_AGGREGATOR | MODEL_G_DEPTH)
static void preset_full1(struct model_config *c)
{
    model_config_default(c);
    c->depth = 1;
    c->dino_depth = 1;
    for (int i = 0; i < 4; i++)
        c->dpt_layer_idx[i] = 0;
    c->motion_layers = 1;
}

static void preset_mid(struct model_config *c)
{
    model_config_default(c);
    c->img_size = 224; c->embed_dim = 384; c->depth = 8; c->num_heads = 6;
    c->num_register_tokens = 4; c->dino_depth = 4; c->dino_num_heads = 6;
    c->camera_trunk_depth = 2; c->camera_num_heads = 6; c->camera_iters = 4;
    c->dpt_features = 64;
    c->dpt_out_channels[0] = 48; c->dpt_out_channels[1] = 96;
    c->dpt_out_channels[2] = 192; c->dpt_out_channels[3] = 384;
    c->dpt_layer_idx[0] = 1; c->dpt_layer_idx[1] = 3;
    c->dpt_layer_idx[2] = 5; c->dpt_layer_idx[3] = 7;
}

static int write_preset(const char *path, const char *preset)
{
    struct model_config c;
    if (!strcmp(preset, "tiny"))
        bench_preset_tiny(&c);
    else if (!strcmp(preset, "mid"))
        preset_mid(&c);
    else if (!strcmp(preset, "full1")) /* for profiling one stage */
        preset_full1(&c);
    else {
        fprintf(stderr, "f4d-bench model: --preset must be tiny, mid or full1 (got '%s')\n", preset);
        return 2;
    }
    unsigned groups = strcmp(preset, "full1") ? MODEL_G_ALL : PRESET_FULL1_GROUPS;
    struct f4d_err err = {0};
    if (model_config_check(&c, &err) < 0) {
        fprintf(stderr, "f4d-bench model: preset %s: %s\n", preset, err.msg);
        return 1;
    }
    if (bench_write_random_model(path, &c, groups) < 0)
        return 1;
    printf("f4d-bench model: random %s model (embed %d, depth %d, img %d, %s) -> %s\n", preset,
           c.embed_dim, c.depth, c.img_size, groups == MODEL_G_ALL ? "every head" : "depth head", path);
    return 0;
}

static void random_images(float *img, size_t n, uint64_t seed)
{
    struct rng r = { seed };
    for (size_t i = 0; i < n; i++)
        img[i] = (float)(0.5 + 0.25 * rnd_normal(&r));
}

struct result {
    struct model_stage st[16];
    int    n_st;
    struct model_stage st_best[16]; /* each stage's least time over the runs */
    double total;
    double cpu;             /* least process CPU time of one run (all threads, spinning included) */
    float *layer, *depth;   /* copies for the error columns */
    size_t n_layer, n_depth;
    size_t arena, weights;
};

/* CPU seconds of this process: under load from other jobs (this 2-core box
 * often runs at load 8-10) wall times vary 3x between runs, CPU time much less */
static double cpu_now(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

/* Loads `path` as `wt`, prepares, runs `reps` times; keeps the best run
 * (st) and each stage's best (st_best). --clock cpu with one thread: each
 * Eval's stage times (wall clock, measured inside the model) are scaled by
 * the Eval's thread CPU time over its wall time, so time spent descheduled
 * on a shared machine is taken out (assumed spread evenly over the
 * stages). skip_head: a head left out (model_skip_head, as the streaming
 * path does), or NULL. */
static int run_model(fk_ctx *ctx, const char *path, enum fk_wtype wt, int S, int H, int W,
                     int reps, int layer, int cpu_clock, const char *skip_head, struct result *r)
{
    struct f4d_err err = {0};
    struct model *m;
    memset(r, 0, sizeof *r);
    if (model_init(ctx, path, wt, &m, &err) < 0) {
        fprintf(stderr, "f4d-bench model: %s\n", err.msg);
        return -1;
    }
    float *img = malloc((size_t)S * 3 * H * W * sizeof *img);
    int rc = img ? 0 : -1;
    if (rc == 0 && skip_head)
        rc = model_skip_head(m, skip_head);
    if (rc == 0)
        rc = model_prepare(m, S, H, W);
    if (rc < 0) {
        fprintf(stderr, "f4d-bench model: %s\n", img ? model_error(m) : "out of memory");
        free(img);
        model_free(m);
        return -1;
    }
    random_images(img, (size_t)S * 3 * H * W, 42);
    r->total = r->cpu = INFINITY;
    /* with motion weights the first step has no motion: time the later ones */
    const int warm = (model_groups(m) & MODEL_G_MOTION) ? 1 : 0;
    for (int i = 0; i < reps + warm; i++) {
        struct model_outputs o;
        double t0 = bench_now(), c0 = bench_thread_cpu_s(), p0 = cpu_now();
        if (model_eval(m, img, S, H, W, &o) < 0) {
            fprintf(stderr, "f4d-bench model: %s\n", model_error(m));
            rc = -1;
            break;
        }
        double t = bench_now() - t0, scale = 1.0, tc = cpu_now() - p0;
        if (cpu_clock && fk_ctx_threads(ctx) == 1 && t > 0) {
            scale = (bench_thread_cpu_s() - c0) / t;
            t *= scale;
        }
        if (i >= warm && tc < r->cpu)
            r->cpu = tc;
        if (i >= warm && !o.has_motion && warm) {
            fprintf(stderr, "f4d-bench model: step %d has no motion\n", i + 1);
            rc = -1;
            break;
        }
        if (i >= warm) {
            struct model_stage st[16];
            int n = model_stages(m, st, 16);
            for (int q = 0; q < n; q++) {
                st[q].seconds *= scale;
                if (i == warm || st[q].seconds < r->st_best[q].seconds)
                    r->st_best[q] = st[q];
            }
            if (t < r->total) {
                r->total = t;
                r->n_st = n;
                memcpy(r->st, st, sizeof st);
            }
        }
        if (i == 0) {
            const struct model_config *c = model_get_config(m);
            const int p = c->patch_size;
            r->n_layer = (size_t)S * (1 + c->num_register_tokens + (H / p) * (W / p)) * 2 * c->embed_dim;
            r->n_depth = o.depth ? (size_t)S * H * W : 0;
            r->layer = malloc(r->n_layer * sizeof(float));
            r->depth = malloc((r->n_depth ? r->n_depth : 1) * sizeof(float));
            if (r->layer && model_layer(m, layer))
                memcpy(r->layer, model_layer(m, layer), r->n_layer * sizeof(float));
            if (r->depth && o.depth)
                memcpy(r->depth, o.depth, r->n_depth * sizeof(float));
        }
    }
    r->arena = model_arena_bytes(m);
    r->weights = model_weight_bytes(m);
    free(img);
    model_free(m);
    return rc;
}

static double rel_err(const float *x, const float *ref, size_t n)
{
    double md = 0, mr = 0;
    for (size_t i = 0; i < n; i++) {
        double d = fabs((double)x[i] - ref[i]);
        md = isnan(d) ? INFINITY : fmax(md, d);
        mr = fmax(mr, fabs((double)ref[i]));
    }
    return mr > 0 ? md / mr : md;
}

static double stage_sec(const struct result *r, const char *name, double *flops)
{
    for (int i = 0; i < r->n_st; i++)
        if (!strcmp(r->st[i].name, name)) {
            if (flops)
                *flops = r->st[i].flops;
            return r->st[i].seconds;
        }
    if (flops)
        *flops = 0;
    return 0;
}

/* --weights: one file, per stage and precision. */
static int bench_weights(fk_ctx *ctx, const char *path, int S, int H, int W, int reps, const char *skip,
                         const char *only)
{
    if (H == 0) { /* the file's own input size */
        struct f4d_err err = {0};
        struct model *m;
        if (model_init(ctx, path, FK_W_F32, &m, &err) < 0) {
            fprintf(stderr, "f4d-bench model: %s\n", err.msg);
            return 1;
        }
        H = W = model_get_config(m)->img_size;
        model_free(m);
    }
    static const enum fk_wtype wt[3] = { FK_W_F32, FK_W_F16, FK_W_Q8 };
    static const char *const wn[3] = { "f32", "f16", "int8" };
    for (int p = 0; p < 3; p++) {
        struct result r;
        if (only && strcmp(only, wn[p]))
            continue;
        if (run_model(ctx, path, wt[p], S, H, W, reps, 0, 0, skip, &r) < 0)
            return 1;
        printf("model %s%s%s: %d views %dx%d, %s, isa %s, %d threads, best of %d: %.2f ms wall, %.2f ms CPU, "
               "arena %zu bytes\n", path, skip ? " without " : "", skip ? skip : "", S, W, H, wn[p],
               fk_isa_name(fk_ctx_isa(ctx)), fk_ctx_threads(ctx), reps, 1e3 * r.total, 1e3 * r.cpu, r.arena);
        for (int i = 0; i < r.n_st; i++)
            printf("  %-14s %9.3f ms %8.2f GFLOP/s\n", r.st[i].name, 1e3 * r.st[i].seconds,
                   r.st[i].seconds > 0 ? 1e-9 * r.st[i].flops / r.st[i].seconds : 0.0);
        free(r.layer);
        free(r.depth);
    }
    return 0;
}

int bench_model(int argc, char **argv)
{
    const char *json = NULL, *tmpdir = "/tmp", *write_path = NULL, *preset = "tiny", *weights = NULL;
    const char *skip_head = NULL, *only_prec = NULL;
    int threads = 0, S = 4, H = 518, W = 518, reps = 3, skip_full = 0, all_isas = 0, sized = 0;
    int stream_only = 0, skip_stream = 0, cpu_clock = 0;
    enum fk_isa isa = FK_ISA_AUTO;
    for (int i = 1; i < argc; i++) {
        if (!strcmp(argv[i], "--json") && i + 1 < argc)
            json = argv[++i];
        else if (!strcmp(argv[i], "--threads") && i + 1 < argc)
            threads = atoi(argv[++i]);
        else if (!strcmp(argv[i], "--views") && i + 1 < argc)
            S = atoi(argv[++i]);
        else if (!strcmp(argv[i], "--size") && i + 1 < argc && sscanf(argv[i + 1], "%dx%d", &H, &W) == 2)
            i++, sized = 1;
        else if (!strcmp(argv[i], "--weights") && i + 1 < argc)
            weights = argv[++i];
        else if (!strcmp(argv[i], "--skip-head") && i + 1 < argc)
            skip_head = argv[++i];
        else if (!strcmp(argv[i], "--precision") && i + 1 < argc &&
                 (!strcmp(argv[i + 1], "f32") || !strcmp(argv[i + 1], "f16") || !strcmp(argv[i + 1], "int8")))
            only_prec = argv[++i];
        else if (!strcmp(argv[i], "--reps") && i + 1 < argc)
            reps = atoi(argv[++i]);
        else if (!strcmp(argv[i], "--write-random") && i + 1 < argc)
            write_path = argv[++i];
        else if (!strcmp(argv[i], "--preset") && i + 1 < argc)
            preset = argv[++i];
        else if (!strcmp(argv[i], "--skip-full"))
            skip_full = 1;
        else if (!strcmp(argv[i], "--stream-only"))
            stream_only = 1;
        else if (!strcmp(argv[i], "--skip-stream"))
            skip_stream = 1;
        else if (!strcmp(argv[i], "--clock") && i + 1 < argc &&
                 (!strcmp(argv[i + 1], "cpu") || !strcmp(argv[i + 1], "wall")))
            cpu_clock = !strcmp(argv[++i], "cpu");
        else if (!strcmp(argv[i], "--tmp") && i + 1 < argc)
            tmpdir = argv[++i];
        else if (!strcmp(argv[i], "--isa") && i + 1 < argc) {
            i++;
            if (!strcmp(argv[i], "all")) {
                all_isas = 1;
            } else {
                isa = fk_isa_from_name(argv[i]);
                if ((int)isa < 0 || !fk_isa_supported(isa)) {
                    fprintf(stderr, "f4d-bench model: ISA '%s' is unknown or not supported here\n", argv[i]);
                    return 2;
                }
            }
        } else {
            fprintf(stderr, "usage: f4d-bench model [--json FILE] [--threads N] [--views S] "
                            "[--size HxW] [--reps R] [--skip-full] [--stream-only | --skip-stream] [--clock wall|cpu] [--tmp DIR] "
                            "[--isa auto|ref|avx2|avx2-vnni|avx512|all] [--precision f32|f16|int8]\n"
                            "       f4d-bench model --weights W.gguf [--views S] [--size HxW] [--reps R] "
                            "[--threads N] [--isa NAME] [--skip-head PREFIX] [--precision f32|f16|int8]\n"
                            "       f4d-bench model --write-random OUT.gguf [--preset tiny|mid|full1]\n");
            return 2;
        }
    }
    if (write_path)
        return write_preset(write_path, preset);
    if (S < 1 || S > MODEL_VIEWS_MAX || H % 14 || W % 14 || H < 14 || W < 14 || reps < 1) {
        fprintf(stderr, "f4d-bench model: bad --views/--size/--reps\n");
        return 2;
    }
    fk_ctx *ctx, *xctx[3] = { NULL, NULL, NULL };
    struct fk_ctx_config cc = { .isa = isa, .threads = threads };
    if (fk_ctx_new(&cc, &ctx) != F4D_OK) {
        fprintf(stderr, "f4d-bench model: cannot create the kernel context\n");
        return 1;
    }
    /* --isa all: int8 again on every other optimized ISA of this CPU */
    int n_x = 0;
    static const enum fk_isa others[3] = { FK_ISA_AVX2, FK_ISA_AVX2_VNNI, FK_ISA_AVX512 };
    for (int i = 0; all_isas && i < 3; i++)
        if (others[i] != fk_ctx_isa(ctx) && fk_isa_supported(others[i])) {
            struct fk_ctx_config xc = { .isa = others[i], .threads = threads };
            if (fk_ctx_new(&xc, &xctx[n_x]) == F4D_OK)
                n_x++;
        }
    if (weights) {
        int wrc = bench_weights(ctx, weights, S, sized ? H : 0, sized ? W : 0, reps, skip_head, only_prec);
        for (int i = 0; i < n_x; i++)
            fk_ctx_free(xctx[i]);
        fk_ctx_free(ctx);
        return wrc;
    }
    /* int8 models run attention's products in bf16 where the context has
     * AVX512_BF16, in int16 on the AVX2 context (model_block.c), fp32
     * elsewhere */
    printf("model: isa %s, int8 path %s, int8 attention %s", fk_isa_name(fk_ctx_isa(ctx)),
           fk_ctx_q8_path(ctx), attn_kind(ctx));
    for (int i = 0; i < n_x; i++)
        printf(", also int8 on %s (%s, attention %s)", fk_isa_name(fk_ctx_isa(xctx[i])),
               fk_ctx_q8_path(xctx[i]), attn_kind(xctx[i]));
    printf("\n");
    /* what those paths' instructions can reach here: the int8 forward's
     * ratio to the FMA peak is bounded by them */
    bench_print_int_ceilings(bench_int_ceilings(fk_cpu_features(), 5));
    int nthr = fk_ctx_threads(ctx);
    double peak = bench_fma_peak_gflops(nthr, 3);
    char path[1024];
    snprintf(path, sizeof path, "%s/f4d-bench-model-%d.gguf", tmpdir, (int)getpid());
    FILE *jf = NULL;
    int rc = 1;

    /* ---- tiny: end to end, per stage ---- */
    struct model_config tiny;
    bench_preset_tiny(&tiny);
    /* the motion head as wide as the DPT heads: at 16 wide it measured no
     * faster here (its 8-channel convolutions ran at 4.9 GFLOP/s) */
    tiny.motion_dpt_features = tiny.dpt_features;
    const int tS = 4, tH = 126, tW = 168;
    struct result tr;
    if (bench_write_random_model(path, &tiny, MODEL_G_ALL) < 0 ||
        run_model(ctx, path, FK_W_F32, tS, tH, tW, 5 * reps, tiny.depth - 1, cpu_clock, NULL, &tr) < 0)
        goto done;
    remove(path);
    printf("model tiny (embed %d, depth %d, dino %d; %d views %dx%d), f32, %d threads, "
           "FMA peak %.1f GFLOP/s, best of %d: %.2f ms, arena %zu bytes\n", tiny.embed_dim,
           tiny.depth, tiny.dino_depth, tS, tW, tH, nthr, peak, 5 * reps, 1e3 * tr.total, tr.arena);
    for (int i = 0; i < tr.n_st; i++)
        printf("  %-14s %9.3f ms %8.2f GFLOP/s\n", tr.st[i].name, 1e3 * tr.st[i].seconds,
               tr.st[i].seconds > 0 ? 1e-9 * tr.st[i].flops / tr.st[i].seconds : 0.0);
    double tsum = 0;
    for (int i = 0; i < tr.n_st; i++)
        tsum += tr.st[i].seconds;
    const double t_mot = stage_sec(&tr, "motion_blocks", NULL) + stage_sec(&tr, "motion_head", NULL);
    const double tiny_ratio = t_mot / (tsum - t_mot);
    printf("model tiny stream: state blocks %.3f ms, motion blocks %.3f ms, motion head %.3f ms; "
           "motion step / key frame %.1f %% (goal <= 27 %%)\n",
           1e3 * stage_sec(&tr, "state_blocks", NULL), 1e3 * stage_sec(&tr, "motion_blocks", NULL),
           1e3 * stage_sec(&tr, "motion_head", NULL), 100.0 * tiny_ratio);

    if (json) {
        jf = fopen(json, "w");
        if (!jf) {
            fprintf(stderr, "f4d-bench model: cannot write '%s'\n", json);
            goto done;
        }
        fprintf(jf, "{\n  \"threads\": %d,\n  \"fma_peak_gflops\": %.1f,\n", nthr, peak);
        fprintf(jf, "  \"tiny_config\": {\"embed_dim\": %d, \"depth\": %d, \"dino_depth\": %d, "
                "\"views\": %d, \"height\": %d, \"width\": %d, \"total_ms\": %.3f},\n",
                tiny.embed_dim, tiny.depth, tiny.dino_depth, tS, tH, tW, 1e3 * tr.total);
        fprintf(jf, "  \"tiny\": [");
        for (int i = 0; i < tr.n_st; i++)
            fprintf(jf, "%s\n    {\"stage\": \"%s\", \"ms\": %.4f, \"gflops\": %.3f}", i ? "," : "",
                    tr.st[i].name, 1e3 * tr.st[i].seconds,
                    tr.st[i].seconds > 0 ? 1e-9 * tr.st[i].flops / tr.st[i].seconds : 0.0);
        fprintf(jf, "\n  ],\n  \"tiny_motion_over_keyframe\": %.4f", tiny_ratio);
    }
    free(tr.layer);
    free(tr.depth);

    /* ---- full-size plan (no weights needed) ---- */
    struct model_config full;
    model_config_default(&full);
    size_t plan = model_plan_bytes(&full, MODEL_G_VGGT, 4, 518, 518);
    printf("full VGGT-1B plan, 4 views 518x518, camera+depth+point heads: arena %zu bytes "
           "(%.2f GiB)\n", plan, plan / 1073741824.0);
    size_t plan_f4d = model_plan_bytes(&full, MODEL_G_ALL, 4, 518, 518);
    int n_ml = 0;
    for (int l = 0; l < full.depth; l++)
        n_ml += (int)((model_motion_mask(&full) >> l) & 1);
    printf("full Forge4D plan, 4 views 518x518, every head, state and motion (z(t-1) of %d "
           "motion layers kept): arena %zu bytes (%.2f GiB)\n", n_ml, plan_f4d,
           plan_f4d / 1073741824.0);
    if (jf)
        fprintf(jf, ",\n  \"full_plan_arena_bytes_4x518x518\": %zu,\n"
                "  \"full_forge4d_plan_arena_bytes_4x518x518\": %zu", plan, plan_f4d);

    if (!skip_full) {
        /* ---- full dims, one block of each kind, one DPT head ---- */
        struct model_config one;
        preset_full1(&one);
        if (stream_only)
            goto stream;
        if (bench_write_random_model(path, &one, PRESET_FULL1_GROUPS) < 0)
            goto done;
        /* the best ISA: f32, f16, int8; --isa all: f32 and int8 on every other
         * ISA too, so each int8 path is compared with its own ISA's f32 and
         * each forward with the FMA peak of its vector width */
        enum fk_wtype wts[9];
        fk_ctx *rctx[9];
        int nrun = 0;
        /* --precision f16 / int8: that one beside f32 (the reference of the
         * errors and speed-ups, always run); f32: f32 alone */
        const int want_f16 = !only_prec || !strcmp(only_prec, "f16");
        const int want_q8 = !only_prec || !strcmp(only_prec, "int8");
        for (int c = 0; c <= n_x; c++) {
            fk_ctx *cx = c ? xctx[c - 1] : ctx;
            wts[nrun] = FK_W_F32; rctx[nrun++] = cx;
            if (!c && want_f16) {
                wts[nrun] = FK_W_F16; rctx[nrun++] = cx;
            }
            if (want_q8) {
                wts[nrun] = FK_W_Q8; rctx[nrun++] = cx;
            }
        }
        char wn[9][48];
        for (int p = 0; p < nrun; p++) {
            if (wts[p] == FK_W_Q8)
                snprintf(wn[p], sizeof wn[p], "int8 %s attention %s", fk_ctx_q8_path(rctx[p]),
                         attn_kind(rctx[p]));
            else
                snprintf(wn[p], sizeof wn[p], "%s %s", wts[p] == FK_W_F32 ? "f32" : "f16",
                         fk_isa_name(fk_ctx_isa(rctx[p])));
        }
        struct result fr[9];
        int ok = 1;
        double peak_run[9];
        for (int p = 0; p < nrun && ok; p++) {
            /* the machine may be shared: the peak of this run's vector width
             * (zmm for AVX-512, else ymm) is measured before and after each
             * run; each forward is then held to the best of every reading of
             * its width in this process (below) */
            peak_run[p] = bench_fma_peak_gflops_isa(nthr, 3, fk_ctx_isa(rctx[p]));
            ok = run_model(rctx[p], path, wts[p], S, H, W, reps, 0, cpu_clock, NULL, &fr[p]) == 0;
            peak_run[p] = fmax(peak_run[p], bench_fma_peak_gflops_isa(nthr, 3, fk_ctx_isa(rctx[p])));
            if (ok) {
                /* each stage's best of the runs: the forward is extrapolated
                 * stage by stage, and one run of a stage on a shared machine
                 * swung 0.72-0.83x of the peak (AVX-512 f32, Zen 5) */
                memcpy(fr[p].st, fr[p].st_best, sizeof fr[p].st);
                printf("full dims, one block each, %d views %dx%d, %s weights (%zu bytes "
                       "packed, arena %zu bytes), best of %d per stage:\n", S, W, H, wn[p],
                       fr[p].weights, fr[p].arena, reps);
                for (int i = 0; i < fr[p].n_st; i++)
                    printf("  %-14s %9.3f s %8.2f GFLOP/s\n", fr[p].st[i].name, fr[p].st[i].seconds,
                           fr[p].st[i].seconds > 0 ? 1e-9 * fr[p].st[i].flops / fr[p].st[i].seconds : 0.0);
            }
        }
        remove(path);
        if (!ok)
            goto done;
        /* a reading taken in a slow spell (396 against 447-473 GFLOP/s zmm,
         * Zen 5) flattered the forward beside it: the best of the width's
         * readings is the peak */
        for (int p = 0; p < nrun; p++)
            for (int q = 0; q < nrun; q++)
                if ((fk_ctx_isa(rctx[q]) == FK_ISA_AVX512) == (fk_ctx_isa(rctx[p]) == FK_ISA_AVX512))
                    peak_run[p] = fmax(peak_run[p], peak_run[q]);
        if (jf)
            fprintf(jf, ",\n  \"full\": [");
        for (int p = 0; p < nrun; p++) {
            double fpatch, fdino, fframe, fglobal, fdpt;
            double tpatch = stage_sec(&fr[p], "patch_embed", &fpatch);
            double tdino = stage_sec(&fr[p], "dino_blocks", &fdino);
            double tframe = stage_sec(&fr[p], "frame_blocks", &fframe);
            double tglobal = stage_sec(&fr[p], "global_blocks", &fglobal);
            double tdpt = stage_sec(&fr[p], "depth_head", &fdpt);
            const double cam_flops = 6.9e9 * S / 4.0;
            double tcam = fframe > 0 ? cam_flops / (fframe / tframe) : 0;
            double total = tpatch + 24 * (tdino + tframe + tglobal) + 2 * tdpt + tcam;
            double flops = fpatch + 24 * (fdino + fframe + fglobal) + 2 * fdpt + cam_flops;
            double el = p ? rel_err(fr[p].layer, fr[0].layer, fr[0].n_layer) : 0;
            double ed = p ? rel_err(fr[p].depth, fr[0].depth, fr[0].n_depth) : 0;
            double e = fmax(el, ed);
            /* the ratio to f32 on the same ISA in the same run: the comparison
             * that survives a shared machine */
            int p32 = 0;
            for (int q = 0; q < nrun; q++)
                if (wts[q] == FK_W_F32 && rctx[q] == rctx[p])
                    p32 = q;
            double f32_total = stage_sec(&fr[p32], "patch_embed", NULL) +
                               24 * (stage_sec(&fr[p32], "dino_blocks", NULL) + stage_sec(&fr[p32], "frame_blocks", NULL) +
                                     stage_sec(&fr[p32], "global_blocks", NULL)) +
                               2 * stage_sec(&fr[p32], "depth_head", NULL);
            double mine = total - tcam;
            int zmm = fk_ctx_isa(rctx[p]) == FK_ISA_AVX512;
            printf("full forward %s (extrapolated): %.1f s, %.0f GFLOP, %.1f GFLOP/s "
                   "= %.2fx the %s FMA peak %.1f (best reading of this run) (goal f32 >= 0.87x, int8 >= 1.4x), "
                   "%.2fx %s speed; error vs f32: layer %.3e, depth %.3e\n", wn[p], total, 1e-9 * flops,
                   1e-9 * flops / total, 1e-9 * flops / total / peak_run[p], zmm ? "zmm" : "ymm",
                   peak_run[p], f32_total / mine, wn[p32], el, ed);
            if (jf)
                fprintf(jf, "%s\n    {\"precision\": \"%s\", \"seconds\": %.2f, \"max_rel_err\": %.3e, "
                        "\"layer_rel_err\": %.3e, \"depth_rel_err\": %.3e, \"gflop\": %.1f, "
                        "\"dino_block_s\": %.4f, \"frame_block_s\": %.4f, \"global_block_s\": %.4f, "
                        "\"dpt_head_s\": %.4f, \"patch_embed_s\": %.4f, \"camera_head_s_est\": %.4f, "
                        "\"weights_bytes_one_block_each\": %zu, \"fma_peak_gflops_beside\": %.1f, "
                        "\"isa\": \"%s\", \"speed_vs_f32\": %.3f, \"of_fma_peak\": %.3f}",
                        p ? "," : "", wn[p], total, e, el, ed, 1e-9 * flops, tdino, tframe,
                        tglobal, tdpt, tpatch, tcam, fr[p].weights, peak_run[p],
                        fk_isa_name(fk_ctx_isa(rctx[p])), f32_total / mine,
                        1e-9 * flops / total / peak_run[p]);
        }
        if (jf)
            fprintf(jf, "\n  ],\n  \"full_views\": %d, \"full_height\": %d, \"full_width\": %d", S, H, W);
        for (int p = 0; p < nrun; p++) {
            free(fr[p].layer);
            free(fr[p].depth);
        }
        if (skip_stream) /* the VGGT rows alone (the forward's fraction of peak) */
            goto end_full;
        /* ---- Forge4D stream at full dims: one state block, one motion block,
         * the motion head; f32, best of reps motion steps. Then the head alone
         * at the other widths (same file but the head, no depth head). ---- */
stream:;
        int nmot = 0, nmot_all = full.depth;
        for (int l = 0; l < full.depth; l++)
            nmot += (int)((model_motion_mask(&full) >> l) & 1);
        const int widths[3] = { model_motion_features(&full), full.dpt_features, 64 };
        double tmh_w[3] = { 0, 0, 0 }, fmh_w[3] = { 0, 0, 0 };
        struct result sr;
        int sok = 1;
        for (int k = 0; k < 3 && sok; k++) {
            if (k && (widths[k] == widths[0] || (k == 2 && widths[2] == widths[1])))
                continue;
            struct model_config sc = one;
            sc.motion_dpt_features = widths[k];
            unsigned g = MODEL_G_AGGREGATOR | MODEL_G_STATE | MODEL_G_MOTION | MODEL_G_MOTION_HEAD;
            struct result wr;
            if (bench_write_random_model(path, &sc, g | (k ? 0u : MODEL_G_DEPTH)) < 0)
                goto done;
            sok = run_model(ctx, path, FK_W_F32, S, H, W, k ? 1 : reps, 0, cpu_clock, NULL, k ? &wr : &sr) == 0;
            remove(path);
            if (!sok)
                goto done;
            struct result *r = k ? &wr : &sr;
            tmh_w[k] = stage_sec(r, "motion_head", &fmh_w[k]);
            if (k) {
                free(wr.layer);
                free(wr.depth);
            }
        }
        printf("full dims stream step, one block each, %d views %dx%d, f32, best of %d (arena "
               "%zu bytes):\n", S, W, H, reps, sr.arena);
        for (int i = 0; i < sr.n_st; i++)
            printf("  %-14s %9.3f s %8.2f GFLOP/s\n", sr.st[i].name, sr.st[i].seconds,
                   sr.st[i].seconds > 0 ? 1e-9 * sr.st[i].flops / sr.st[i].seconds : 0.0);
        double fstate, fmot, fframe, fdino, fglob, fpatch, fdpt;
        const double ts = stage_sec(&sr, "state_blocks", &fstate);
        const double tm = stage_sec(&sr, "motion_blocks", &fmot);
        const double tdpt = stage_sec(&sr, "depth_head", &fdpt);
        const double tframe = stage_sec(&sr, "frame_blocks", &fframe);
        const double tdino = stage_sec(&sr, "dino_blocks", &fdino);
        const double tglob = stage_sec(&sr, "global_blocks", &fglob);
        const double tpatch = stage_sec(&sr, "patch_embed", &fpatch);
        const double cam_fl = 6.9e9 * S / 4.0;
        const double tcam = fframe > 0 ? cam_fl / (fframe / tframe) : 0;
        /* key frame: 24 layers with their state blocks, depth + point + Gaussian heads */
        const int L = full.depth;
        const double key = tpatch + L * (tdino + tframe + tglob + ts) + 3 * tdpt + tcam;
        const double fkey = fpatch + L * (fdino + fframe + fglob + fstate) + 3 * fdpt + cam_fl;
        printf("full stream (extrapolated to %d layers): state block %.3f s (%.0f GFLOP), motion "
               "block (in_proj + 2 runs) %.3f s (%.0f GFLOP); key frame %.1f s (%.0f GFLOP)\n",
               L, ts, 1e-9 * fstate, tm, 1e-9 * fmot, key, 1e-9 * fkey);
        if (jf)
            fprintf(jf, ",\n  \"stream\": {\"state_block_s\": %.4f, \"motion_block_s\": %.4f, "
                    "\"keyframe_s_est\": %.3f, \"keyframe_gflop\": %.1f, \"motion_layers\": %d, "
                    "\"arena_bytes_one_block_each\": %zu, \"rows\": [", ts, tm, key, 1e-9 * fkey,
                    nmot, sr.arena);
        int nrow = 0;
        for (int k = 0; k < 3; k++)
            for (int all = 0; all < 2; all++) {
                if (!tmh_w[k] || (all && k != 1))
                    continue;
                const int nl = all ? nmot_all : nmot;
                const double mot = nl * tm + tmh_w[k], fm = nl * fmot + fmh_w[k];
                printf("  motion blocks at %2d layers, motion head %3d wide (2 runs) %.3f s "
                       "(%.0f GFLOP): motion step %.1f s, %.1f %% of a key frame (%.1f %% by "
                       "FLOPs)%s\n", nl, widths[k], tmh_w[k], 1e-9 * fmh_w[k], mot, 100.0 * mot / key,
                       100.0 * fm / fkey, k == 0 && !all ? "  <- default (goal <= 27 %)" :
                       all ? "  (forge4d-arch.md 5 as written)" : "");
                if (jf)
                    fprintf(jf, "%s\n    {\"motion_layers\": %d, \"motion_dpt_features\": %d, "
                            "\"motion_head_s\": %.4f, \"motion_step_s_est\": %.3f, "
                            "\"motion_over_keyframe\": %.4f, \"motion_over_keyframe_flops\": %.4f, "
                            "\"default\": %s}", nrow++ ? "," : "", nl, widths[k], tmh_w[k], mot,
                            mot / key, fm / fkey, k == 0 && !all ? "true" : "false");
            }
        if (jf)
            fprintf(jf, "\n  ]}");
        free(sr.layer);
        free(sr.depth);
    }
end_full:
    if (jf)
        fprintf(jf, "\n}\n");
    rc = 0;
done:
    if (jf && fclose(jf) != 0)
        rc = 1;
    remove(path);
    fk_ctx_free(ctx);
    for (int i = 0; i < n_x; i++)
        fk_ctx_free(xctx[i]);
    return rc;
}
