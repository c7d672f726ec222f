/* bench_pairs.c - f4d-bench pairs: the display's per-key interpolation work
 * (interp_key_build's pixel lookup, interp_pair_build's partner search,
 * interp_pair_prepare) per key, and a digest of every interp_pair_step
 * output so that two builds can be compared bit for bit.
 *
 * Streams (keys at 10 Hz with their exact motion over one key interval):
 *   - walk N: the synthetic walk figure resampled to N Gaussians (--gaussians,
 *     100k and 300k by default), as f4d-bench display streams it (not coded);
 *   - model: pixel-aligned keys as the model gives them (--model-px s: 4 views
 *     of s x s pixels, 112 by default: ~50k Gaussians, background included),
 *     each pixel's Gaussian at the walk scene's rendered depth with the
 *     rendered motion, isotropic and about one model pixel wide, so that at
 *     the display's 518-px lookup they overlap in layers.
 * The lookup view is the display's: cam1 of the scene's default rig at
 * 1280x720, scaled to 518 px on its longest side. Keys are handled as the
 * display's player does (two slots, each key built once, a pair built and
 * prepared per new key, then stepped at a = 1/3 and 2/3). Per key: process
 * CPU ms (all threads) and wall ms of each stage, best of --reps over the
 * keys after the first two. digest: FNV-1a over each step's output frame
 * (count and every attribute's bytes) and the pair counts. */
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#include "bench.h"
#include "interp.h"
#include "scene.h"

#define LOOKUP_PX 518

static double cpu_ms(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
    return (double)ts.tv_sec * 1e3 + 1e-6 * (double)ts.tv_nsec;
}

static uint64_t fnv(uint64_t h, const void *p, size_t n)
{
    const unsigned char *b = p;
    for (size_t i = 0; i < n; i++) {
        h ^= b[i];
        h *= 1099511628211ull;
    }
    return h;
}

static uint64_t frame_digest(uint64_t h, const struct splat_frame *f)
{
    h = fnv(h, &f->count, sizeof f->count);
    h = fnv(h, f->pos, 3 * f->count * sizeof(float));
    h = fnv(h, f->scale, 3 * f->count * sizeof(float));
    h = fnv(h, f->rot, 4 * f->count * sizeof(float));
    h = fnv(h, f->rgb, 3 * f->count * sizeof(float));
    return fnv(h, f->opacity, f->count * sizeof(float));
}

/* Pixel-aligned keys from the walk scene's render: view v's pixel (x, y) is
 * Gaussian (v * s + y) * s + x, at the rendered depth along the pixel's ray
 * (or on a backdrop 6 m away), moving with the rendered motion. */
static int model_key(fk_ctx *ctx, const scene *sc, const struct splat_rig *rig, double t, struct splat_frame *out,
                     struct splat_frame *tmp)
{
    struct f4d_err err;
    const int V = rig->count, W = rig->cams[0].width, H = rig->cams[0].height;
    const size_t np = (size_t)W * (size_t)H;
    if (scene_eval(sc, t, 0.1, tmp, &err) < 0 || splat_frame_resize(out, (size_t)V * np, 1, &err) < 0) {
        fprintf(stderr, "f4d-bench pairs: %s\n", err.msg);
        return -1;
    }
    splat_renderer *r;
    if (splat_renderer_new(ctx, W, H, &r, &err) < 0) {
        fprintf(stderr, "f4d-bench pairs: %s\n", err.msg);
        return -1;
    }
    float *rgb = malloc(np * 3 * sizeof *rgb), *alpha = malloc(np * sizeof *alpha),
          *depth = malloc(np * sizeof *depth), *mb = malloc(np * 3 * sizeof *mb), *mf = malloc(np * 3 * sizeof *mf);
    int rc = rgb && alpha && depth && mb && mf ? 0 : -1;
    for (int v = 0; v < V && rc == 0; v++) {
        const struct splat_camera *cam = &rig->cams[v];
        struct splat_render_out o = { .rgb = rgb, .alpha = alpha, .depth = depth };
        if (splat_render(r, cam, tmp, scene_background(), &o) < 0 ||
            splat_render_features(r, cam, tmp, tmp->motion_bwd, mb) < 0 ||
            splat_render_features(r, cam, tmp, tmp->motion_fwd, mf) < 0) {
            rc = -1;
            break;
        }
        const float *m = cam->w2c; /* rows: R | t; the camera centre is -R' t */
        for (int y = 0; y < H; y++)
            for (int x = 0; x < W; x++) {
                size_t p = (size_t)y * W + x, g = (size_t)v * np + p;
                int fg = alpha[p] > 0.5f && depth[p] > 0.0f;
                float z = fg ? depth[p] : 6.0f;
                float q[3] = { ((float)x + 0.5f - cam->cx) / cam->fx * z, ((float)y + 0.5f - cam->cy) / cam->fy * z, z };
                for (int c = 0; c < 3; c++) { /* world = R' (q - t) */
                    float w = 0.0f;
                    for (int k = 0; k < 3; k++)
                        w += m[4 * k + c] * (q[k] - m[4 * k + 3]);
                    out->pos[3 * g + c] = w;
                    out->scale[3 * g + c] = 0.5f * z / cam->fx;
                    out->rgb[3 * g + c] = rgb[3 * p + c];
                    out->motion_bwd[3 * g + c] = fg ? mb[3 * p + c] : 0.0f;
                    out->motion_fwd[3 * g + c] = fg ? mf[3 * p + c] : 0.0f;
                }
                out->rot[4 * g] = 1.0f;
                out->rot[4 * g + 1] = out->rot[4 * g + 2] = out->rot[4 * g + 3] = 0.0f;
                out->opacity[g] = 0.9f;
            }
    }
    free(rgb);
    free(alpha);
    free(depth);
    free(mb);
    free(mf);
    splat_renderer_free(r);
    return rc;
}

struct stage { double key_cpu, pair_cpu, prep_cpu, key_ms, pair_ms, prep_ms, step_cpu; };

/* One pass over the keys as the player handles them; per-key sums from key 2. */
/* Mid-time pictures: each step's output rendered by the display's camera,
 * kept (cmp 0) or compared with those kept (cmp 1: PSNR per picture). */
struct pics {
    const struct splat_camera *cam;
    splat_renderer            *r;
    float                    **img; /* [2 * (keys - 1)] */
    int                        cmp;
    double                     psnr_min, psnr_sum;
    int                        count;
};

static int run_pass(fk_ctx *ctx, const struct splat_rig *lrig, struct splat_frame *keys, int nk, struct stage *s,
                    uint64_t *digest, struct interp_stats *last, int lookup, struct pics *pics)
{
    struct f4d_err err;
    interp *ip;
    if (interp_new(ctx, lrig, &ip, &err) < 0 || interp_set_lookup(ip, (enum interp_lookup)lookup, &err) < 0) {
        fprintf(stderr, "f4d-bench pairs: %s\n", err.msg);
        return -1;
    }
    struct interp_key k[2] = { { 0 } };
    struct interp_pair pr = { 0 };
    struct splat_frame out = { 0 };
    struct interp_config cfg = interp_config_default();
    memset(s, 0, sizeof *s);
    uint64_t h = 1469598103934665603ull;
    int rc = interp_key_build(ip, &keys[0], &k[0], &err);
    for (int i = 1; i < nk && rc == 0; i++) {
        struct interp_key *prev = &k[(i - 1) & 1], *next = &k[i & 1];
        double t0 = bench_now(), q0 = cpu_ms();
        rc = interp_key_build(ip, &keys[i], next, &err);
        double t1 = bench_now(), q1 = cpu_ms();
        if (rc == 0)
            rc = interp_pair_build(ip, prev, next, &cfg, &pr, &err);
        double t2 = bench_now(), q2 = cpu_ms();
        if (rc == 0)
            rc = interp_pair_prepare(ip, &pr, &cfg, &out, &err);
        double t3 = bench_now(), q3 = cpu_ms();
        for (int st = 1; st <= 2 && rc == 0; st++) {
            rc = interp_pair_step(ip, &pr, (float)st / 3.0f, &out, &err);
            h = frame_digest(h, &out);
            if (pics && rc == 0) {
                const int W = pics->cam->width, H = pics->cam->height;
                float **slot = &pics->img[2 * (i - 1) + st - 1], *img = pics->cmp ? malloc((size_t)W * H * 3 * sizeof *img) : NULL;
                if (!pics->cmp)
                    img = *slot = malloc((size_t)W * H * 3 * sizeof *img);
                struct splat_render_out o = { .rgb = img };
                if (!img || splat_render(pics->r, pics->cam, &out, NULL, &o) < 0) {
                    free(img);
                    rc = -1;
                    break;
                }
                if (pics->cmp) {
                    double q = splat_psnr(img, *slot, W, H, 3);
                    pics->psnr_min = pics->count == 0 || q < pics->psnr_min ? q : pics->psnr_min;
                    pics->psnr_sum += q;
                    pics->count++;
                    free(img);
                }
            }
        }
        double q4 = cpu_ms();
        if (rc == 0) {
            h = fnv(h, &pr.st, sizeof pr.st);
            *last = pr.st;
        }
        if (i >= 2) {
            s->key_cpu += q1 - q0;
            s->pair_cpu += q2 - q1;
            s->prep_cpu += q3 - q2;
            s->step_cpu += q4 - q3;
            s->key_ms += 1e3 * (t1 - t0);
            s->pair_ms += 1e3 * (t2 - t1);
            s->prep_ms += 1e3 * (t3 - t2);
        }
    }
    if (rc < 0)
        fprintf(stderr, "f4d-bench pairs: %s\n", err.msg);
    *digest = h;
    splat_frame_free(&out);
    interp_pair_free(&pr);
    interp_key_free(&k[0]);
    interp_key_free(&k[1]);
    interp_free(ip);
    return rc;
}

int bench_pairs(int argc, char **argv)
{
    size_t ns[8];
    int nn = 0, nk = 8, reps = 3, threads = 0, model = 1, model_px = 112, lookup = INTERP_LOOKUP_RENDER, psnr = 0;
    const char *json = NULL;
    for (int i = 1; i < argc; i++) {
        if (!strcmp(argv[i], "--gaussians") && i + 1 < argc && nn < 8)
            ns[nn++] = (size_t)strtoul(argv[++i], NULL, 10);
        else if (!strcmp(argv[i], "--keys") && i + 1 < argc)
            nk = atoi(argv[++i]);
        else if (!strcmp(argv[i], "--reps") && i + 1 < argc)
            reps = atoi(argv[++i]);
        else if (!strcmp(argv[i], "--threads") && i + 1 < argc)
            threads = atoi(argv[++i]);
        else if (!strcmp(argv[i], "--model-px") && i + 1 < argc)
            model_px = atoi(argv[++i]);
        else if (!strcmp(argv[i], "--no-model"))
            model = 0;
        else if (!strcmp(argv[i], "--lookup") && i + 1 < argc && !strcmp(argv[i + 1], "render"))
            lookup = INTERP_LOOKUP_RENDER, i++;
        else if (!strcmp(argv[i], "--lookup") && i + 1 < argc && !strcmp(argv[i + 1], "zbuffer"))
            lookup = INTERP_LOOKUP_ZBUFFER, i++;
        else if (!strcmp(argv[i], "--psnr"))
            psnr = 1;
        else if (!strcmp(argv[i], "--json") && i + 1 < argc)
            json = argv[++i];
        else {
            fprintf(stderr, "usage: f4d-bench pairs [--gaussians N]... [--no-model] [--model-px S] [--keys K] "
                            "[--reps R] [--threads T] [--lookup render|zbuffer] [--psnr] [--json FILE]\n"
                            "  --psnr: also the mid-time pictures (cam1 at 1280x720) of --lookup against render's\n");
            return 2;
        }
    }
    if (nn == 0) {
        ns[nn++] = 100000;
        ns[nn++] = 300000;
    }
    if (nk < 4 || reps < 1 || model_px < 8) {
        fprintf(stderr, "f4d-bench pairs: --keys >= 4, --reps >= 1, --model-px >= 8\n");
        return 2;
    }
    fk_ctx *ctx;
    if (fk_ctx_new(&(struct fk_ctx_config){ .isa = FK_ISA_AUTO, .threads = threads }, &ctx) != F4D_OK) {
        fprintf(stderr, "f4d-bench pairs: no fk context\n");
        return 1;
    }
    FILE *jf = json ? fopen(json, "w") : NULL;
    if (jf)
        fprintf(jf, "[\n");
    printf("f4d-bench pairs: per key (from key 2 of %d), best of %d; lookup view 518 px (%s), %d threads\n", nk, reps,
           lookup == INTERP_LOOKUP_ZBUFFER ? "zbuffer" : "render", fk_ctx_threads(ctx));
    int rc = 0;
    for (int row = 0; row < nn + model && rc == 0; row++) {
        int is_model = row == nn;
        scene *sc;
        struct f4d_err err;
        if (scene_new(SCENE_WALK, 1, is_model ? 0 : ns[row], &sc, &err) < 0) {
            fprintf(stderr, "f4d-bench pairs: %s\n", err.msg);
            rc = 1;
            break;
        }
        struct splat_rig rig, lrig = { .count = 1 };
        scene_default_rig(sc, 4, 1280, 720, &rig);
        struct splat_camera lc = rig.cams[1];
        float sc518 = (float)LOOKUP_PX / 1280.0f; /* as the display's player scales its view */
        lc.width = (int)((float)lc.width * sc518 + 0.5f);
        lc.height = (int)((float)lc.height * sc518 + 0.5f);
        lc.fx *= sc518; lc.fy *= sc518; lc.cx *= sc518; lc.cy *= sc518;
        lrig.cams[0] = lc;
        struct splat_frame *keys = calloc((size_t)nk, sizeof *keys), tmp = { 0 };
        struct splat_rig mrig;
        scene_default_rig(sc, 4, model_px, model_px, &mrig);
        for (int i = 0; i < nk && rc == 0; i++) {
            double t = 0.3 + 0.1 * i;
            if (is_model)
                rc = model_key(ctx, sc, &mrig, t, &keys[i], &tmp) < 0;
            else if (scene_eval(sc, t, 0.1, &keys[i], &err) < 0) {
                fprintf(stderr, "f4d-bench pairs: %s\n", err.msg);
                rc = 1;
            }
        }
        struct stage best = { 1e30, 1e30, 1e30, 1e30, 1e30, 1e30, 1e30 };
        double best_cpu = 1e30, best_ms = 1e30;
        uint64_t dig = 0;
        struct interp_stats st = { 0 };
        for (int r = 0; r < reps && rc == 0; r++) {
            struct stage s;
            uint64_t d;
            if (run_pass(ctx, &lrig, keys, nk, &s, &d, &st, lookup, NULL) < 0) {
                rc = 1;
                break;
            }
            if (r > 0 && d != dig)
                printf("  WARNING: digest differs between passes (%016llx vs %016llx)\n", (unsigned long long)d,
                       (unsigned long long)dig);
            dig = d;
            double c = s.key_cpu + s.pair_cpu + s.prep_cpu, w = s.key_ms + s.pair_ms + s.prep_ms;
            if (c < best_cpu) {
                best_cpu = c;
                best = s;
            }
            best_ms = w < best_ms ? w : best_ms;
        }
        if (rc == 0 && psnr) { /* the pictures of render's lookup, then of this one's */
            struct pics pc = { .cam = &rig.cams[1], .img = calloc(2 * (size_t)nk, sizeof(float *)) };
            struct stage s2;
            uint64_t d2;
            struct interp_stats st2;
            if (!pc.img || splat_renderer_new(ctx, rig.cams[1].width, rig.cams[1].height, &pc.r, &err) < 0 ||
                run_pass(ctx, &lrig, keys, nk, &s2, &d2, &st2, INTERP_LOOKUP_RENDER, &pc) < 0 ||
                (pc.cmp = 1, run_pass(ctx, &lrig, keys, nk, &s2, &d2, &st2, lookup, &pc) < 0))
                rc = 1;
            else
                printf("  %-6s %7zu Gaussians: mid-time pictures (a = 1/3, 2/3, %d), %s lookup vs render: PSNR min %.2f "
                       "mean %.2f dB\n",
                       is_model ? "model" : "walk", keys[0].count, pc.count,
                       lookup == INTERP_LOOKUP_ZBUFFER ? "zbuffer" : "render", pc.psnr_min,
                       pc.count ? pc.psnr_sum / pc.count : 0.0);
            for (int i = 0; pc.img && i < 2 * nk; i++)
                free(pc.img[i]);
            free(pc.img);
            splat_renderer_free(pc.r);
        }
        if (rc == 0) {
            const double per = 1.0 / (double)(nk - 2);
            printf("  %-6s %7zu Gaussians: lookup+partners %.1f ms CPU per key (lookup %.1f, partners %.1f, "
                   "prepare %.1f), wall %.1f ms; steps %.2f ms CPU per key; fused %zu kept %zu+%zu; "
                   "digest %016llx\n",
                   is_model ? "model" : "walk", keys[0].count, best_cpu * per, best.key_cpu * per,
                   best.pair_cpu * per, best.prep_cpu * per, best_ms * per, best.step_cpu * per, st.fused, st.kept_t,
                   st.kept_tm1, (unsigned long long)dig);
            if (jf)
                fprintf(jf,
                        "%s  {\"stream\": \"%s\", \"gaussians\": %zu, \"cpu_ms_per_key\": %.3f, \"lookup_cpu_ms\": "
                        "%.3f, \"partners_cpu_ms\": %.3f, \"prepare_cpu_ms\": %.3f, \"wall_ms_per_key\": %.3f, "
                        "\"digest\": \"%016llx\"}",
                        row ? ",\n" : "", is_model ? "model" : "walk", keys[0].count, best_cpu * per,
                        best.key_cpu * per, best.pair_cpu * per, best.prep_cpu * per, best_ms * per,
                        (unsigned long long)dig);
        }
        for (int i = 0; i < nk; i++)
            splat_frame_free(&keys[i]);
        free(keys);
        splat_frame_free(&tmp);
        scene_free(sc);
    }
    if (jf) {
        fprintf(jf, "\n]\n");
        fclose(jf);
    }
    fk_ctx_free(ctx);
    return rc;
}
