/* venue.c - `f4d-scene venue`: one training take of a randomised venue with
 * exact ground truth, for tools/train (issue 11). Everything follows from the
 * seed: 1-3 people (preset, height, girth, clothing colours, place, heading,
 * speed), a textured floor and backdrop, the exposure, and a rig of 2-6 input
 * cameras (radius, height, look-at jitter, focal length) plus held-out
 * evaluation cameras between them.
 *
 *   f4d-scene venue --seed S -o DIR [--frames T] [--size WxH] [--eval E]
 *                   [--person-gaussians N] [--views V] [--ply] [--threads N]
 *
 * DIR gets float32 .npy arrays (T key times k / 30 s after a seeded start,
 * V input views, E evaluation views):
 *   rgb [T,V,H,W,3]  depth, alpha [T,V,H,W]  motion_bwd, motion_fwd [T,V,H,W,3]
 *   (per-pixel 3D motion of the visible surface to the key before / after, m)
 *   eval_rgb [T,E,H,W,3]  eval_depth, eval_alpha [T,E,H,W]
 *   mid_rgb [T-1,V+E,H,W,3]  (renders at the mid times k + 1/2, inputs first)
 *   rig.json, eval_rig.json (splat rig format), take.json (what was drawn),
 *   and with --ply gaussians_t0.ply (the Gaussians of the first key); with
 *   --background background_rgb [V,H,W,3]: the empty venue (no people) from
 *   the input views, the plate a foreground model learns (forge4d report). */
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

#include "scene.h"
#include "venue.h"

#define PI_D 3.14159265358979323846
#define VENUE_PEOPLE_MAX 3

struct rng { uint64_t s; };

static double rnd(struct rng *r)
{
    r->s ^= r->s << 13;
    r->s ^= r->s >> 7;
    r->s ^= r->s << 17;
    return (double)(r->s >> 11) * (1.0 / 9007199254740992.0);
}
static double uni(struct rng *r, double lo, double hi) { return lo + (hi - lo) * rnd(r); }

struct person { int preset; uint64_t seed; float x, y, yaw, speed, girth; };

struct venue {
    int    people;
    struct person p[VENUE_PEOPLE_MAX];
    float  checker, floor_a[3], floor_b[3], wall_r, wall_a[3], wall_b[3], stripe;
    float  exposure, sky[3], t0;
};

static const int venue_presets[] = { SCENE_WALK, SCENE_JUMP, SCENE_WAVE, SCENE_THROW, SCENE_FAST, SCENE_CROSS };

static void draw_venue(struct rng *r, struct venue *v)
{
    memset(v, 0, sizeof *v);
    v->people = 1 + (int)(rnd(r) * 3.0);
    for (int i = 0; i < v->people; i++) {
        struct person *p = &v->p[i];
        p->preset = venue_presets[(int)(rnd(r) * 6.0) % 6];
        p->seed = (uint64_t)(rnd(r) * 2147483647.0);
        p->yaw = (float)uni(r, -PI_D, PI_D);
        p->speed = (float)uni(r, 0.6, 1.5);
        p->girth = (float)uni(r, 0.85, 1.25);
        for (int guard = 0; guard < 100; guard++) { /* keep people about 0.8 m apart */
            double rad = i ? uni(r, 0.5, 1.3) : uni(r, 0.0, 0.3), a = uni(r, -PI_D, PI_D);
            p->x = (float)(rad * sin(a));
            p->y = (float)(rad * cos(a) * 0.7);
            int ok = 1;
            for (int j = 0; j < i; j++)
                ok &= hypotf(p->x - v->p[j].x, p->y - v->p[j].y) > 0.8f;
            if (ok)
                break;
        }
    }
    v->checker = (float)uni(r, 0.2, 0.6);
    float base = (float)uni(r, 0.3, 0.6), tint[3] = { (float)uni(r, 0.85, 1.1), (float)uni(r, 0.85, 1.05),
                                                      (float)uni(r, 0.7, 1.0) };
    float contrast = (float)uni(r, 0.05, 0.25);
    for (int k = 0; k < 3; k++) {
        v->floor_a[k] = base * tint[k];
        v->floor_b[k] = (base + contrast) * tint[k];
    }
    v->wall_r = (float)uni(r, 3.2, 4.2);
    for (int k = 0; k < 3; k++) {
        v->wall_a[k] = (float)uni(r, 0.2, 0.8);
        v->wall_b[k] = (float)uni(r, 0.2, 0.8);
    }
    v->stripe = (float)uni(r, 0.15, 0.5);
    v->exposure = (float)uni(r, 0.75, 1.25);
    v->sky[0] = (float)uni(r, 0.45, 0.7);
    v->sky[1] = (float)uni(r, 0.55, 0.75);
    v->sky[2] = (float)uni(r, 0.65, 0.9);
    v->t0 = (float)uni(r, 0.0, 3.0);
}

/* Appends one flat Gaussian (normal n, tangent size st, normal size sn). */
static void put(struct splat_frame *f, size_t i, const float p[3], const float n[3], float st, float sn,
                const float rgb[3])
{
    memcpy(f->pos + 3 * i, p, 3 * sizeof(float));
    float *q = f->rot + 4 * i; /* shortest arc from +z to n */
    if (n[2] < -0.9999f) {
        q[0] = 0; q[1] = 1; q[2] = 0; q[3] = 0;
    } else {
        float w = 1.0f + n[2], x = -n[1], y = n[0];
        float len = sqrtf(w * w + x * x + y * y);
        q[0] = w / len; q[1] = x / len; q[2] = y / len; q[3] = 0.0f;
    }
    f->scale[3 * i] = st;
    f->scale[3 * i + 1] = st;
    f->scale[3 * i + 2] = sn;
    memcpy(f->rgb + 3 * i, rgb, 3 * sizeof(float));
    f->opacity[i] = 0.98f;
}

/* The static venue: a checkered floor (6 x 6 m) and a striped cylindrical
 * backdrop behind the people (the cameras stand on the +y side). */
static int build_static(const struct venue *v, struct splat_frame *f, struct f4d_err *err)
{
    const float sp = 0.07f, half = 3.0f;
    const int nf = (int)(2.0f * half / sp);
    const float wh = 3.0f, arc = 2.0f * 1.9f; /* backdrop height (m), angle span (rad) */
    const int nwa = (int)(arc * v->wall_r / sp), nwh = (int)(wh / sp);
    size_t n = (size_t)nf * (size_t)nf + (size_t)nwa * (size_t)nwh;
    int rc = splat_frame_resize(f, n, 1, err);
    if (rc < 0)
        return rc;
    size_t i = 0;
    for (int a = 0; a < nf; a++)
        for (int b = 0; b < nf; b++) {
            float p[3] = { -half + ((float)a + 0.5f) * sp, -half + ((float)b + 0.5f) * sp, 0.0f };
            float nn[3] = { 0, 0, 1 }, c[3];
            int ci = (int)floorf(p[0] / v->checker + 100.0f), cj = (int)floorf(p[1] / v->checker + 100.0f);
            memcpy(c, ((ci + cj) & 1) ? v->floor_a : v->floor_b, sizeof c);
            put(f, i++, p, nn, 0.6f * sp, 0.05f * sp, c);
        }
    for (int a = 0; a < nwa; a++)
        for (int b = 0; b < nwh; b++) {
            float th = (float)(-0.5 * arc + ((double)a + 0.5) * arc / nwa); /* around -y */
            float p[3] = { v->wall_r * sinf(th), -v->wall_r * cosf(th), ((float)b + 0.5f) * sp };
            float nn[3] = { -sinf(th), cosf(th), 0.0f }, c[3];
            int si = (int)floorf(th * v->wall_r / v->stripe + 1000.0f), sj = (int)floorf(p[2] / 0.5f);
            int pick = (si + (sj & (si & 1))) & 1; /* stripes, broken into blocks every other */
            float shade = 1.0f - 0.15f * (float)(sj & 1);
            for (int k = 0; k < 3; k++)
                c[k] = (pick ? v->wall_a[k] : v->wall_b[k]) * shade;
            put(f, i++, p, nn, 0.6f * sp, 0.05f * sp, c);
        }
    f->count = i;
    return 0;
}

/* Input cameras on an arc facing the people, evaluation cameras between two
 * neighbouring inputs (novel views inside the rig's span, as the paper tests). */
static void draw_rig(struct rng *r, int views, int evals, int W, int H, struct splat_rig *in,
                     struct splat_rig *ev)
{
    memset(in, 0, sizeof *in);
    memset(ev, 0, sizeof *ev);
    double spacing = uni(r, 30.0, 55.0) * PI_D / 180.0, centre = uni(r, -0.35, 0.35);
    double fov = uni(r, 45.0, 65.0) * PI_D / 180.0;
    const float up[3] = { 0, 0, 1 };
    double angles[8];
    for (int k = 0; k < views; k++)
        angles[k] = centre + spacing * ((double)k - 0.5 * (views - 1));
    for (int k = 0; k < views + evals; k++) {
        int is_eval = k >= views;
        struct splat_camera *c = is_eval ? &ev->cams[k - views] : &in->cams[k];
        double a;
        if (is_eval) {
            int j = (int)(rnd(r) * (views - 1));
            a = 0.5 * (angles[j] + angles[j + 1]) + uni(r, -0.15, 0.15) * spacing;
        } else {
            a = angles[k];
        }
        double rad = uni(r, 2.3, 3.5), h = uni(r, 0.9, 1.9), f = 0.5 * H / tan(0.5 * fov * uni(r, 0.93, 1.07));
        snprintf(c->name, sizeof c->name, "%s%d", is_eval ? "eval" : "cam", is_eval ? k - views : k);
        c->width = W;
        c->height = H;
        c->fx = c->fy = (float)f;
        c->cx = 0.5f * (float)W;
        c->cy = 0.5f * (float)H;
        float eye[3] = { (float)(rad * sin(a)), (float)(rad * cos(a)), (float)h };
        float at[3] = { (float)uni(r, -0.15, 0.15), (float)uni(r, -0.15, 0.15), (float)uni(r, 0.75, 1.05) };
        splat_camera_look_at(c, eye, at, up);
    }
    in->count = views;
    ev->count = evals;
}

/* The venue's Gaussians at time t with motion over dt: static part, then people. */
static int venue_frame(scene *const *ppl, int np, const struct splat_frame *st, float exposure, double t,
                       double dt, struct splat_frame *tmp, struct splat_frame *out, struct f4d_err *err)
{
    size_t n = st->count;
    for (int i = 0; i < np; i++)
        n += scene_count(ppl[i]);
    int rc = splat_frame_resize(out, n, 1, err);
    if (rc < 0)
        return rc;
    size_t o = 0;
    memcpy(out->pos, st->pos, 3 * st->count * sizeof(float));
    memcpy(out->scale, st->scale, 3 * st->count * sizeof(float));
    memcpy(out->rot, st->rot, 4 * st->count * sizeof(float));
    memcpy(out->rgb, st->rgb, 3 * st->count * sizeof(float));
    memcpy(out->opacity, st->opacity, st->count * sizeof(float));
    memset(out->motion_bwd, 0, 3 * st->count * sizeof(float));
    memset(out->motion_fwd, 0, 3 * st->count * sizeof(float));
    o = st->count;
    for (int i = 0; i < np; i++) {
        if ((rc = scene_eval(ppl[i], t, dt, tmp, err)) < 0)
            return rc;
        size_t m = tmp->count;
        memcpy(out->pos + 3 * o, tmp->pos, 3 * m * sizeof(float));
        memcpy(out->scale + 3 * o, tmp->scale, 3 * m * sizeof(float));
        memcpy(out->rot + 4 * o, tmp->rot, 4 * m * sizeof(float));
        memcpy(out->rgb + 3 * o, tmp->rgb, 3 * m * sizeof(float));
        memcpy(out->opacity + o, tmp->opacity, m * sizeof(float));
        memcpy(out->motion_bwd + 3 * o, tmp->motion_bwd, 3 * m * sizeof(float));
        memcpy(out->motion_fwd + 3 * o, tmp->motion_fwd, 3 * m * sizeof(float));
        o += m;
    }
    for (size_t i = 0; i < 3 * n; i++) /* exposure: the camera sees brighter or darker colours */
        out->rgb[i] *= exposure;
    return 0;
}

static int parse_long(const char *opt, const char *v, long lo, long hi, long *out)
{
    char *end;
    errno = 0;
    long x = strtol(v, &end, 10);
    if (end == v || *end || errno || x < lo || x > hi) {
        fprintf(stderr, "f4d-scene venue: %s '%s' must be an integer in %ld..%ld\n", opt, v, lo, hi);
        return -1;
    }
    *out = x;
    return 0;
}

static int write_npy(const char *dir, const char *name, const float *d, const size_t *shape, int nd,
                     struct f4d_err *err)
{
    char path[4096];
    snprintf(path, sizeof path, "%s/%s.npy", dir, name);
    return splat_npy_write_f32(path, d, shape, nd, err);
}

int venue_main(int argc, char **argv)
{
    const char *outdir = NULL;
    long seed = -1, frames = 3, W = 112, H = 112, evals = 2, pg = 5000, views = 0, threads = 1;
    int want_ply = 0, want_bg = 0;
    for (int i = 1; i < argc; i++) {
        const char *a = argv[i];
        if (!strcmp(a, "--ply")) {
            want_ply = 1;
            continue;
        }
        if (!strcmp(a, "--background")) {
            want_bg = 1;
            continue;
        }
        if (i + 1 >= argc) {
            fprintf(stderr, "f4d-scene venue: option '%s' needs a value (or is unknown)\n", a);
            return 2;
        }
        const char *v = argv[++i];
        int bad = 0;
        if (!strcmp(a, "-o")) outdir = v;
        else if (!strcmp(a, "--seed")) bad = parse_long(a, v, 0, 2147483647L, &seed);
        else if (!strcmp(a, "--frames")) bad = parse_long(a, v, 1, 64, &frames);
        else if (!strcmp(a, "--eval")) bad = parse_long(a, v, 0, 8, &evals);
        else if (!strcmp(a, "--views")) bad = parse_long(a, v, 2, 6, &views);
        else if (!strcmp(a, "--person-gaussians")) bad = parse_long(a, v, 1000, 200000, &pg);
        else if (!strcmp(a, "--threads")) bad = parse_long(a, v, 1, 256, &threads);
        else if (!strcmp(a, "--size")) {
            char *x = strchr(v, 'x');
            char wbuf[32];
            if (!x || (size_t)(x - v) >= sizeof wbuf) {
                fprintf(stderr, "f4d-scene venue: --size '%s' must be WxH, e.g. 112x112\n", v);
                return 2;
            }
            memcpy(wbuf, v, (size_t)(x - v));
            wbuf[x - v] = '\0';
            bad = parse_long("--size width", wbuf, 16, 4096, &W) || parse_long("--size height", x + 1, 16, 4096, &H);
        } else {
            fprintf(stderr, "f4d-scene venue: unknown option '%s'\n", a);
            return 2;
        }
        if (bad)
            return 2;
    }
    if (seed < 0 || !outdir) {
        fprintf(stderr, "usage: f4d-scene venue --seed S -o DIR [--frames T] [--size WxH] [--eval E]\n"
                        "                       [--views V] [--person-gaussians N] [--ply] [--background]\n"
                        "                       [--threads N]\n");
        return 2;
    }
    if (mkdir(outdir, 0777) != 0 && errno != EEXIST) {
        fprintf(stderr, "f4d-scene venue: cannot create '%s': %s\n", outdir, strerror(errno));
        return 1;
    }
    struct rng r = { (uint64_t)seed * 0xD1B54A32D192ED03ull + 0x9E3779B97F4A7C15ull };
    for (int k = 0; k < 4; k++)
        rnd(&r);
    struct venue v;
    draw_venue(&r, &v);
    int V = views ? (int)views : 2 + (int)(rnd(&r) * 5.0); /* 2..6 */
    if (V > 6)
        V = 6;
    struct splat_rig rig, erig;
    draw_rig(&r, V, (int)evals, (int)W, (int)H, &rig, &erig);
    int E = erig.count, T = (int)frames;

    int rc = 1;
    struct f4d_err err = { 0 };
    scene *ppl[VENUE_PEOPLE_MAX] = { 0 };
    struct splat_frame st = { 0 }, tmp = { 0 }, fr = { 0 };
    fk_ctx *ctx = NULL;
    splat_renderer *ren = NULL;
    size_t np = (size_t)W * (size_t)H, nimg = (size_t)T * (size_t)(V + E) + (size_t)(T - 1) * (size_t)(V + E);
    float *rgb = malloc(3 * np * nimg * sizeof(float)), *dep = malloc(np * nimg * sizeof(float)),
          *alp = malloc(np * nimg * sizeof(float)), *mb = malloc(3 * np * (size_t)(T * V) * sizeof(float)),
          *mf = malloc(3 * np * (size_t)(T * V) * sizeof(float));
    if (!rgb || !dep || !alp || !mb || !mf) {
        fprintf(stderr, "f4d-scene venue: out of memory\n");
        goto done;
    }
    for (int i = 0; i < v.people; i++) {
        struct scene_desc d = { .preset = (enum scene_preset)v.p[i].preset, .seed = v.p[i].seed,
                                .gaussians = (size_t)pg, .no_floor = 1, .offset = { v.p[i].x, v.p[i].y },
                                .yaw = v.p[i].yaw, .speed = v.p[i].speed, .girth = v.p[i].girth };
        if (scene_new_desc(&d, &ppl[i], &err) < 0) {
            fprintf(stderr, "f4d-scene venue: %s\n", err.msg);
            goto done;
        }
    }
    if (build_static(&v, &st, &err) < 0) {
        fprintf(stderr, "f4d-scene venue: %s\n", err.msg);
        goto done;
    }
    struct fk_ctx_config cfg = { .isa = FK_ISA_AUTO, .threads = (int)threads };
    if (fk_ctx_new(&cfg, &ctx) != F4D_OK || splat_renderer_new(ctx, (int)W, (int)H, &ren, &err) < 0) {
        fprintf(stderr, "f4d-scene venue: cannot create the renderer: %s\n", err.msg);
        goto done;
    }
    float sky[3];
    for (int k = 0; k < 3; k++)
        sky[k] = fminf(1.0f, v.sky[k] * v.exposure);
    const double dt = 1.0 / SCENE_FPS;
    /* image slots: key k, view c (inputs then evals) at k*(V+E)+c; mid m at T*(V+E) + m*(V+E) + c */
    for (int k = 0; k < 2 * T - 1; k++) {
        int mid = k >= T, key = mid ? k - T : k;
        double t = v.t0 + ((double)key + (mid ? 0.5 : 0.0)) * dt;
        if (venue_frame(ppl, v.people, &st, v.exposure, t, dt, &tmp, &fr, &err) < 0) {
            fprintf(stderr, "f4d-scene venue: %s\n", err.msg);
            goto done;
        }
        if (k == 0 && want_ply) {
            char path[4096];
            snprintf(path, sizeof path, "%s/gaussians_t0.ply", outdir);
            if (splat_ply_write(path, &fr, &err) < 0) {
                fprintf(stderr, "f4d-scene venue: %s\n", err.msg);
                goto done;
            }
        }
        for (int c = 0; c < V + E; c++) {
            const struct splat_camera *cam = c < V ? &rig.cams[c] : &erig.cams[c - V];
            size_t slot = (size_t)k * (size_t)(V + E) + (size_t)c;
            struct splat_render_out o = { .rgb = rgb + 3 * np * slot, .depth = dep + np * slot,
                                          .alpha = alp + np * slot };
            if (splat_render(ren, cam, &fr, sky, &o) < 0) {
                fprintf(stderr, "f4d-scene venue: %s\n", splat_renderer_error(ren));
                goto done;
            }
            if (!mid && c < V) {
                size_t ms = (size_t)key * (size_t)V + (size_t)c;
                if (splat_render_features(ren, cam, &fr, fr.motion_bwd, mb + 3 * np * ms) < 0 ||
                    splat_render_features(ren, cam, &fr, fr.motion_fwd, mf + 3 * np * ms) < 0) {
                    fprintf(stderr, "f4d-scene venue: %s\n", splat_renderer_error(ren));
                    goto done;
                }
            }
        }
    }
    /* regroup [k][V+E] into inputs / evals: copy the eval slots out */
    {
        size_t sz = 3 * np;
        float *ergb = malloc(sz * (size_t)(T * (E ? E : 1)) * sizeof(float));
        float *edep = malloc(np * (size_t)(T * (E ? E : 1)) * sizeof(float));
        float *ealp = malloc(np * (size_t)(T * (E ? E : 1)) * sizeof(float));
        float *irgb = malloc(sz * (size_t)(T * V) * sizeof(float));
        float *idep = malloc(np * (size_t)(T * V) * sizeof(float));
        float *ialp = malloc(np * (size_t)(T * V) * sizeof(float));
        int bad = !ergb || !edep || !ealp || !irgb || !idep || !ialp;
        if (!bad) {
            for (int k = 0; k < T; k++)
                for (int c = 0; c < V + E; c++) {
                    size_t s = (size_t)k * (size_t)(V + E) + (size_t)c;
                    size_t d = c < V ? (size_t)k * (size_t)V + (size_t)c : (size_t)k * (size_t)E + (size_t)(c - V);
                    memcpy((c < V ? irgb : ergb) + sz * d, rgb + sz * s, sz * sizeof(float));
                    memcpy((c < V ? idep : edep) + np * d, dep + np * s, np * sizeof(float));
                    memcpy((c < V ? ialp : ealp) + np * d, alp + np * s, np * sizeof(float));
                }
            size_t s5[5] = { (size_t)T, (size_t)V, (size_t)H, (size_t)W, 3 }, s4[4] = { (size_t)T, (size_t)V, (size_t)H, (size_t)W };
            size_t e5[5] = { (size_t)T, (size_t)E, (size_t)H, (size_t)W, 3 }, e4[4] = { (size_t)T, (size_t)E, (size_t)H, (size_t)W };
            size_t m5[5] = { (size_t)(T - 1), (size_t)(V + E), (size_t)H, (size_t)W, 3 };
            bad = write_npy(outdir, "rgb", irgb, s5, 5, &err) < 0 || write_npy(outdir, "depth", idep, s4, 4, &err) < 0 ||
                  write_npy(outdir, "alpha", ialp, s4, 4, &err) < 0 ||
                  write_npy(outdir, "motion_bwd", mb, s5, 5, &err) < 0 ||
                  write_npy(outdir, "motion_fwd", mf, s5, 5, &err) < 0 ||
                  (E && (write_npy(outdir, "eval_rgb", ergb, e5, 5, &err) < 0 ||
                         write_npy(outdir, "eval_depth", edep, e4, 4, &err) < 0 ||
                         write_npy(outdir, "eval_alpha", ealp, e4, 4, &err) < 0)) ||
                  (T > 1 && write_npy(outdir, "mid_rgb", rgb + sz * (size_t)T * (size_t)(V + E), m5, 5, &err) < 0);
            if (bad)
                fprintf(stderr, "f4d-scene venue: %s\n", err.msg);
        } else {
            fprintf(stderr, "f4d-scene venue: out of memory\n");
        }
        free(ergb); free(edep); free(ealp); free(irgb); free(idep); free(ialp);
        if (bad)
            goto done;
    }
    size_t drawn = fr.count; /* take.json's count, before the background frame reuses fr */
    if (want_bg) { /* the static venue alone, same exposure and sky: key 0's slots are free now */
        if (venue_frame(ppl, 0, &st, v.exposure, v.t0, dt, &tmp, &fr, &err) < 0) {
            fprintf(stderr, "f4d-scene venue: %s\n", err.msg);
            goto done;
        }
        for (int c = 0; c < V; c++) {
            struct splat_render_out o = { .rgb = rgb + 3 * np * (size_t)c };
            if (splat_render(ren, &rig.cams[c], &fr, sky, &o) < 0) {
                fprintf(stderr, "f4d-scene venue: %s\n", splat_renderer_error(ren));
                goto done;
            }
        }
        size_t b4[4] = { (size_t)V, (size_t)H, (size_t)W, 3 };
        if (write_npy(outdir, "background_rgb", rgb, b4, 4, &err) < 0) {
            fprintf(stderr, "f4d-scene venue: %s\n", err.msg);
            goto done;
        }
    }
    char path[4096];
    snprintf(path, sizeof path, "%s/rig.json", outdir);
    if (splat_rig_save(path, &rig, &err) < 0) {
        fprintf(stderr, "f4d-scene venue: %s\n", err.msg);
        goto done;
    }
    if (E) {
        snprintf(path, sizeof path, "%s/eval_rig.json", outdir);
        if (splat_rig_save(path, &erig, &err) < 0) {
            fprintf(stderr, "f4d-scene venue: %s\n", err.msg);
            goto done;
        }
    }
    snprintf(path, sizeof path, "%s/take.json", outdir);
    FILE *fp = fopen(path, "w");
    if (!fp) {
        fprintf(stderr, "f4d-scene venue: cannot create '%s': %s\n", path, strerror(errno));
        goto done;
    }
    fprintf(fp, "{\"seed\": %ld, \"frames\": %d, \"fps\": %g, \"t0\": %.6f, \"views\": %d, \"eval_views\": %d, "
                "\"width\": %ld, \"height\": %ld, \"exposure\": %.4f, \"sky\": [%.4f, %.4f, %.4f], "
                "\"gaussians\": %zu, \"people\": [",
            seed, T, SCENE_FPS, (double)v.t0, V, E, W, H, (double)v.exposure, (double)sky[0], (double)sky[1],
            (double)sky[2], drawn);
    for (int i = 0; i < v.people; i++)
        fprintf(fp, "%s{\"preset\": \"%s\", \"seed\": %llu, \"x\": %.4f, \"y\": %.4f, \"yaw\": %.4f, "
                    "\"speed\": %.4f, \"girth\": %.4f, \"height_m\": %.4f}",
                i ? ", " : "", scene_preset_name((enum scene_preset)v.p[i].preset),
                (unsigned long long)v.p[i].seed, (double)v.p[i].x, (double)v.p[i].y, (double)v.p[i].yaw,
                (double)v.p[i].speed, (double)v.p[i].girth, (double)scene_height(ppl[i]));
    fprintf(fp, "]}\n");
    if (fclose(fp) != 0) {
        fprintf(stderr, "f4d-scene venue: error writing '%s'\n", path);
        goto done;
    }
    rc = 0;
done:
    free(rgb); free(dep); free(alp); free(mb); free(mf);
    for (int i = 0; i < VENUE_PEOPLE_MAX; i++)
        scene_free(ppl[i]);
    splat_frame_free(&st);
    splat_frame_free(&tmp);
    splat_frame_free(&fr);
    splat_renderer_free(ren);
    fk_ctx_free(ctx);
    return rc;
}
