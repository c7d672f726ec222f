/* render.c - the CPU rasterizer: the reference 3DGS forward pass (R in
 * gaussians.md §1) on 16x16 tiles, both cores through fk_parallel_for.
 *
 * Stages per frame, all in buffers owned by the renderer:
 *   1. preprocess (parallel over Gaussians): cull, EWA covariance, conic,
 *      radius, tile rectangle, colour, depth key; each chunk compacts its
 *      visible Gaussians;
 *   2. a stable LSD radix sort of the visible Gaussians by depth bits
 *      (depth > 0.2, so IEEE bits order like the values; ties keep index
 *      order, the same order R's (tile | depth) radix sort produces), then a
 *      gather of the tile rectangles into depth order (only those: the
 *      compositors read the records where preprocessing left them, which
 *      saved copying 64 bytes per Gaussian and was no slower to read);
 *   3. binning, a parallel counting sort by tile that keeps depth order, so
 *      every tile list (of frame indices) is depth-ordered;
 *   4. compositing (parallel over tiles). Each Gaussian of a tile's list is
 *      applied to the pixels of the tile inside the ellipse where its alpha
 *      can reach 1/255 (with a margin for rounding); every other pixel of the
 *      tile would skip it in R as well, so the per-pixel sequence of
 *      operations is R's. */
#include <math.h>
#include <time.h>
#include <stdlib.h>
#include <string.h>

#include "render_internal.h"
#include "splat_internal.h"

#define PREP_CHUNK     4096   /* Gaussians per preprocessing task      */
#define BIN_CHUNK      16384  /* visible Gaussians per binning task    */
#define PREFETCH_AHEAD 6
#define SORT_TASKS     8      /* chunks of the parallel radix sort     */
#define SORT_BITS      12     /* 2 passes for the usual 24-bit key range */
#define SORT_RADIX     (1 << SORT_BITS)

#if defined(__GNUC__) || defined(__clang__)
#define splat_prefetch(p) __builtin_prefetch((p), 0, 3)
#else
#define splat_prefetch(p) ((void)(p))
#endif

struct splat_renderer {
    fk_ctx *ctx;
    int     width, height, tiles_x, tiles_y, n_tiles;
    size_t  cap_g, cap_pairs;
    /* per Gaussian (capacity cap_g) */
    struct projected *proj;   /* frame order, read by the compositors through pairs */
    int16_t  *rect;           /* [4 * cap] tile rectangles in depth order */
    uint32_t *key, *key_tmp;
    int32_t  *idx, *idx_tmp;
    uint32_t *chunk_visible;  /* per preprocessing chunk */
    uint32_t *hist;           /* [bin chunks * n_tiles] counts, then cursors */
    uint32_t *sort_count;     /* radix histograms */
    /* per tile */
    uint32_t *tile_start;     /* [n_tiles + 1] */
    int32_t  *pairs;          /* [cap_pairs] indices into proj, tile-major, each tile's in depth order */
    struct f4d_err err;
};

static int fail(splat_renderer *r, int code, const char *msg, const char *detail)
{
    snprintf(r->err.msg, sizeof r->err.msg, "%s%s", msg, detail ? detail : "");
    return code;
}

static void free_gaussian_buffers(splat_renderer *r)
{
    free(r->proj); free(r->rect);
    free(r->key); free(r->key_tmp); free(r->idx); free(r->idx_tmp);
    free(r->chunk_visible); free(r->hist);
    r->proj = NULL;
    r->rect = NULL;
    r->idx = r->idx_tmp = NULL;
    r->key = r->key_tmp = r->chunk_visible = r->hist = NULL;
    r->cap_g = 0;
}

static size_t round_up(size_t n, size_t m) { return (n + m - 1) / m * m; }

int splat_renderer_reserve(splat_renderer *r, size_t gaussians, size_t pairs)
{
    if (!r)
        return F4D_EINVAL;
    if (gaussians > r->cap_g) {
        if (gaussians > (size_t)INT32_MAX)
            return fail(r, F4D_EINVAL, "renderer: more than 2^31 Gaussians", NULL);
        free_gaussian_buffers(r);
        size_t n = round_up(gaussians, PREP_CHUNK);
        r->proj = aligned_alloc(64, n * sizeof *r->proj); /* records on cache lines */
        r->rect = malloc(4 * n * sizeof *r->rect);
        r->key = malloc(n * sizeof *r->key);
        r->key_tmp = malloc(n * sizeof *r->key_tmp);
        r->idx = malloc(n * sizeof *r->idx);
        r->idx_tmp = malloc(n * sizeof *r->idx_tmp);
        r->chunk_visible = malloc((n / PREP_CHUNK + 1) * sizeof *r->chunk_visible);
        r->hist = malloc((n / BIN_CHUNK + 1) * (size_t)r->n_tiles * sizeof *r->hist);
        if (!r->proj || !r->rect || !r->key || !r->key_tmp || !r->idx || !r->idx_tmp ||
            !r->chunk_visible || !r->hist) {
            free_gaussian_buffers(r);
            return fail(r, F4D_ENOMEM, "renderer: out of memory for the Gaussian buffers", NULL);
        }
        r->cap_g = n;
    }
    if (pairs > r->cap_pairs) {
        if (pairs > (size_t)UINT32_MAX)
            return fail(r, F4D_EINVAL, "renderer: more than 2^32 Gaussian-tile pairs", NULL);
        int32_t *p = realloc(r->pairs, pairs * sizeof *p);
        if (!p)
            return fail(r, F4D_ENOMEM, "renderer: out of memory for the tile lists", NULL);
        r->pairs = p;
        r->cap_pairs = pairs;
    }
    return F4D_OK;
}

int splat_renderer_new(fk_ctx *ctx, int width, int height, splat_renderer **out, struct f4d_err *err)
{
    if (!out)
        return f4d_fail(err, F4D_EINVAL, "splat_renderer_new: out is NULL");
    *out = NULL;
    if (!ctx)
        return f4d_fail(err, F4D_EINVAL, "splat_renderer_new: fk context is NULL");
    if (width <= 0 || height <= 0 || width > 16384 || height > 16384)
        return f4d_fail(err, F4D_EINVAL, "splat_renderer_new: size %dx%d must be within 1..16384",
                           width, height);
    splat_renderer *r = calloc(1, sizeof *r);
    if (!r)
        return f4d_fail(err, F4D_ENOMEM, "splat_renderer_new: out of memory");
    r->ctx = ctx;
    r->width = width;
    r->height = height;
    r->tiles_x = (width + SPLAT_TILE - 1) / SPLAT_TILE;
    r->tiles_y = (height + SPLAT_TILE - 1) / SPLAT_TILE;
    r->n_tiles = r->tiles_x * r->tiles_y;
    r->tile_start = calloc((size_t)r->n_tiles + 1, sizeof *r->tile_start);
    r->sort_count = malloc((size_t)SORT_TASKS * SORT_RADIX * sizeof *r->sort_count);
    if (!r->tile_start || !r->sort_count || splat_renderer_reserve(r, 1024, 4096) < 0) {
        splat_renderer_free(r);
        return f4d_fail(err, F4D_ENOMEM, "splat_renderer_new: out of memory");
    }
    *out = r;
    return F4D_OK;
}

void splat_renderer_free(splat_renderer *r)
{
    if (!r)
        return;
    free_gaussian_buffers(r);
    free(r->tile_start);
    free(r->sort_count);
    free(r->pairs);
    free(r);
}

const char *splat_renderer_error(const splat_renderer *r)
{
    return r ? r->err.msg : "renderer is NULL";
}

/* ---- 1. preprocessing ---------------------------------------------------- */

struct prep_job {
    splat_renderer            *r;
    const struct splat_camera *cam;
    const struct splat_frame  *f;
    const float               *features; /* NULL: clamped rgb */
    float lim_x_pos, lim_x_neg, lim_y_pos, lim_y_neg;
    struct prep_view           pv;       /* the same, for the SIMD path */
    int                        simd;
};

static float clampf(float v, float lo, float hi)
{
    return v < lo ? lo : (v > hi ? hi : v);
}

static int prep_one(const struct prep_job *j, size_t i)
{
    splat_renderer *r = j->r;
    const struct splat_camera *cam = j->cam;
    const struct splat_frame *f = j->f;
    const float *V = cam->w2c;
    struct projected *P = r->proj + i;

    const float *p = f->pos + 3 * i;
    float tx = V[0] * p[0] + V[1] * p[1] + V[2] * p[2] + V[3];
    float ty = V[4] * p[0] + V[5] * p[1] + V[6] * p[2] + V[7];
    float tz = V[8] * p[0] + V[9] * p[1] + V[10] * p[2] + V[11];
    if (!(tz > SPLAT_NEAR) || !isfinite(tx) || !isfinite(ty) || !isfinite(tz))
        return 0; /* near-plane cull (R: z <= 0.2), and NaN/Inf positions */
    float o = f->opacity[i];
    if (!(o >= SPLAT_ALPHA_MIN))
        return 0; /* alpha = min(0.99, o exp(power <= 0)) <= o never reaches 1/255 */

    /* 3D covariance Sigma = M M^T with M = R S. */
    float Rm[9];
    splat__quat_to_mat(f->rot + 4 * i, Rm);
    const float *s = f->scale + 3 * i;
    float M[9];
    for (int a = 0; a < 3; a++)
        for (int b = 0; b < 3; b++)
            M[3 * a + b] = Rm[3 * a + b] * s[b];
    float S[6]; /* xx xy xz yy yz zz */
    S[0] = M[0] * M[0] + M[1] * M[1] + M[2] * M[2];
    S[1] = M[0] * M[3] + M[1] * M[4] + M[2] * M[5];
    S[2] = M[0] * M[6] + M[1] * M[7] + M[2] * M[8];
    S[3] = M[3] * M[3] + M[4] * M[4] + M[5] * M[5];
    S[4] = M[3] * M[6] + M[4] * M[7] + M[5] * M[8];
    S[5] = M[6] * M[6] + M[7] * M[7] + M[8] * M[8];

    /* EWA: J with the tangent clamped (the mean itself is not clamped). */
    float fx = cam->fx, fy = cam->fy;
    float cx_ = clampf(tx / tz, -j->lim_x_neg, j->lim_x_pos) * tz;
    float cy_ = clampf(ty / tz, -j->lim_y_neg, j->lim_y_pos) * tz;
    float J00 = fx / tz, J02 = -(fx * cx_) / (tz * tz);
    float J11 = fy / tz, J12 = -(fy * cy_) / (tz * tz);
    /* T = J W (2x3), W = rotation block of the view matrix. */
    float T0[3], T1[3];
    for (int k = 0; k < 3; k++) {
        T0[k] = J00 * V[k] + J02 * V[8 + k];
        T1[k] = J11 * V[4 + k] + J12 * V[8 + k];
    }
    float ST0[3] = { S[0] * T0[0] + S[1] * T0[1] + S[2] * T0[2],
                     S[1] * T0[0] + S[3] * T0[1] + S[4] * T0[2],
                     S[2] * T0[0] + S[4] * T0[1] + S[5] * T0[2] };
    float ST1[3] = { S[0] * T1[0] + S[1] * T1[1] + S[2] * T1[2],
                     S[1] * T1[0] + S[3] * T1[1] + S[4] * T1[2],
                     S[2] * T1[0] + S[4] * T1[1] + S[5] * T1[2] };
    float a = T0[0] * ST0[0] + T0[1] * ST0[1] + T0[2] * ST0[2] + SPLAT_DILATION;
    float b = T0[0] * ST1[0] + T0[1] * ST1[1] + T0[2] * ST1[2];
    float c = T1[0] * ST1[0] + T1[1] * ST1[1] + T1[2] * ST1[2] + SPLAT_DILATION;
    float det = a * c - b * b;
    if (!(det > 0.0f) || !isfinite(det))
        return 0; /* R skips det == 0; a non-finite or negative one cannot be drawn either */
    float det_inv = 1.0f / det;
    float mid = 0.5f * (a + c);
    float d2 = mid * mid - det;
    float disc = sqrtf(d2 > 0.1f ? d2 : 0.1f);
    float lam = mid + disc; /* the larger root: disc >= 0 */
    float radius = ceilf(3.0f * sqrtf(lam));
    if (!isfinite(radius))
        return 0;

    /* ndc2Pix of R == fx x / z + cx - 0.5 for the centred principal point. */
    float pw = 1.0f / (tz + 0.0000001f);
    float mx = fx * tx * pw + cam->cx - 0.5f;
    float my = fy * ty * pw + cam->cy - 0.5f;
    if (!isfinite(mx) || !isfinite(my))
        return 0;
    float gx = (float)r->tiles_x, gy = (float)r->tiles_y;
    int x0 = (int)clampf((mx - radius) / SPLAT_TILE, 0.0f, gx);
    int y0 = (int)clampf((my - radius) / SPLAT_TILE, 0.0f, gy);
    int x1 = (int)clampf((mx + radius + SPLAT_TILE - 1) / SPLAT_TILE, 0.0f, gx);
    int y1 = (int)clampf((my + radius + SPLAT_TILE - 1) / SPLAT_TILE, 0.0f, gy);
    if ((x1 - x0) * (y1 - y0) == 0)
        return 0;

    P->mx = mx;
    P->my = my;
    P->A = c * det_inv;
    P->B = -b * det_inv;
    P->C = a * det_inv;
    P->o = o;
    float k2 = 2.0f * logf(255.0f * o); /* alpha >= 1/255 <=> d' conic d <= k2 */
    k2 = k2 > 0.0f ? k2 : 0.0f;
    P->k2 = k2;
    P->ey = sqrtf(k2 * c) * 1.0001f + 0.001f;
    P->ex = sqrtf(k2 * a) * 1.0001f + 0.001f;
    P->z = tz;
    const float *col = j->features ? j->features + 3 * i : f->rgb + 3 * i;
    for (int k = 0; k < 3; k++)
        P->col[k] = j->features ? col[k] : (col[k] > 0.0f ? col[k] : 0.0f);
    P->rect[0] = (int16_t)x0; P->rect[1] = (int16_t)y0; P->rect[2] = (int16_t)x1; P->rect[3] = (int16_t)y1;
    P->id = (int32_t)i;
    return splat__narrow_rect(P, r->tiles_x, r->tiles_y);
}

static void prep_task(void *arg, int task, int thread)
{
    (void)thread;
    const struct prep_job *j = arg;
    splat_renderer *r = j->r;
    size_t lo = (size_t)task * PREP_CHUNK, hi = lo + PREP_CHUNK, out = lo;
    if (hi > j->f->count)
        hi = j->f->count;
    size_t i = lo;
#ifdef F4D_SPLAT_HAVE_AVX2
    if (j->simd)
        for (; i + 8 <= hi; i += 8) {
            unsigned m = splat__prep8_avx2(&j->pv, i);
            for (int l = 0; l < 8; l++)
                if (m >> l & 1) { /* compacted at the chunk's start, in index order */
                    memcpy(&r->key[out], &r->proj[i + (size_t)l].z, sizeof(uint32_t));
                    r->idx[out++] = (int32_t)(i + (size_t)l);
                }
        }
#endif
    for (; i < hi; i++)
        if (prep_one(j, i)) {
            memcpy(&r->key[out], &r->proj[i].z, sizeof(uint32_t));
            r->idx[out++] = (int32_t)i;
        }
    r->chunk_visible[task] = (uint32_t)(out - lo);
}

/* ---- 2. depth sort and gather ------------------------------------------------ */

/* Stable LSD radix sort of (key, index) pairs, SORT_BITS (12) bits per pass, in parallel:
 * each of SORT_TASKS contiguous chunks counts its digits, a prefix over
 * (digit, chunk) gives every chunk its output cursors, the chunks scatter.
 * A pass where every key has the same digit is skipped. */

struct sort_job {
    const uint32_t *ks;
    const int32_t  *vs;
    uint32_t       *kd;
    int32_t        *vd;
    size_t          n;
    int             shift;
    uint32_t       *count;             /* [SORT_TASKS * SORT_RADIX] */
};

static void sort_range(const struct sort_job *j, int task, size_t *lo, size_t *hi)
{
    size_t per = (j->n + SORT_TASKS - 1) / SORT_TASKS;
    *lo = (size_t)task * per;
    *hi = *lo + per < j->n ? *lo + per : j->n;
    if (*lo > j->n)
        *lo = j->n;
}

static void sort_count_task(void *arg, int task, int thread)
{
    (void)thread;
    struct sort_job *j = arg;
    size_t lo, hi;
    sort_range(j, task, &lo, &hi);
    uint32_t *c = j->count + (size_t)task * SORT_RADIX;
    memset(c, 0, SORT_RADIX * sizeof *c);
    for (size_t i = lo; i < hi; i++)
        c[(j->ks[i] >> j->shift) & (SORT_RADIX - 1)]++;
}

static void sort_scatter_task(void *arg, int task, int thread)
{
    (void)thread;
    struct sort_job *j = arg;
    size_t lo, hi;
    sort_range(j, task, &lo, &hi);
    uint32_t *c = j->count + (size_t)task * SORT_RADIX;
    for (size_t i = lo; i < hi; i++) {
        uint32_t d = c[(j->ks[i] >> j->shift) & (SORT_RADIX - 1)]++;
        j->kd[d] = j->ks[i];
        j->vd[d] = j->vs[i];
    }
}

static void radix_sort(fk_ctx *ctx, uint32_t *count, uint32_t *key, int32_t *val, uint32_t *ktmp, int32_t *vtmp,
                       size_t n)
{
    /* keys relative to the smallest: depths within a scene span a few
     * binades (about 24 key bits), so 2 passes of SORT_BITS instead of 3
     * (order is unchanged) */
    uint32_t lo = UINT32_MAX, hi = 0;
    for (size_t i = 0; i < n; i++) {
        lo = key[i] < lo ? key[i] : lo;
        hi = key[i] > hi ? key[i] : hi;
    }
    for (size_t i = 0; i < n && lo > 0; i++)
        key[i] -= lo;
    int bits = 0;
    while (bits < 32 && n && ((hi - lo) >> bits) != 0)
        bits++;
    struct sort_job j = { .ks = key, .vs = val, .kd = ktmp, .vd = vtmp, .n = n, .count = count };
    for (int shift = 0; shift < bits; shift += SORT_BITS) {
        j.shift = shift;
        fk_parallel_for(ctx, SORT_TASKS, 4.0 * (double)n, sort_count_task, &j);
        uint32_t sum = 0;
        int single = 0;
        for (int b = 0; b < SORT_RADIX && !single; b++) {
            uint32_t tot = 0;
            for (int t = 0; t < SORT_TASKS; t++)
                tot += count[(size_t)t * SORT_RADIX + (size_t)b];
            single = tot == n;
        }
        if (single)
            continue; /* every key shares this digit: the pass would not move anything */
        for (int b = 0; b < SORT_RADIX; b++)
            for (int t = 0; t < SORT_TASKS; t++) {
                uint32_t *c = &count[(size_t)t * SORT_RADIX + (size_t)b], v = *c;
                *c = sum;
                sum += v;
            }
        fk_parallel_for(ctx, SORT_TASKS, 8.0 * (double)n, sort_scatter_task, &j);
        const uint32_t *kt = j.ks; j.ks = j.kd; j.kd = (uint32_t *)kt;
        const int32_t *vt = j.vs; j.vs = j.vd; j.vd = (int32_t *)vt;
    }
    if (j.ks != key) {
        memcpy(key, j.ks, n * sizeof *key);
        memcpy(val, j.vs, n * sizeof *val);
    }
}

struct order_job {
    splat_renderer *r;
    size_t          n;
};

static void gather_task(void *arg, int task, int thread)
{
    (void)thread;
    const struct order_job *j = arg;
    splat_renderer *r = j->r;
    size_t lo = (size_t)task * PREP_CHUNK, hi = lo + PREP_CHUNK;
    if (hi > j->n)
        hi = j->n;
    for (size_t v = lo; v < hi; v++) {
        if (v + 16 < j->n) /* random reads: start the next misses early */
            splat_prefetch(r->proj + r->idx[v + 16]);
        memcpy(r->rect + 4 * v, r->proj[r->idx[v]].rect, 4 * sizeof(int16_t));
    }
}

/* ---- 3. binning: counting sort by tile, per chunk of the depth order ---------- */

static void bin_count_task(void *arg, int task, int thread)
{
    (void)thread;
    const struct order_job *j = arg;
    splat_renderer *r = j->r;
    uint32_t *h = r->hist + (size_t)task * (size_t)r->n_tiles;
    memset(h, 0, (size_t)r->n_tiles * sizeof *h);
    size_t lo = (size_t)task * BIN_CHUNK, hi = lo + BIN_CHUNK;
    if (hi > j->n)
        hi = j->n;
    for (size_t v = lo; v < hi; v++) {
        const int16_t *q = r->rect + 4 * v;
        for (int ty = q[1]; ty < q[3]; ty++)
            for (int tx = q[0]; tx < q[2]; tx++)
                h[ty * r->tiles_x + tx]++;
    }
}

static void bin_scatter_task(void *arg, int task, int thread)
{
    (void)thread;
    const struct order_job *j = arg;
    splat_renderer *r = j->r;
    uint32_t *h = r->hist + (size_t)task * (size_t)r->n_tiles;
    size_t lo = (size_t)task * BIN_CHUNK, hi = lo + BIN_CHUNK;
    if (hi > j->n)
        hi = j->n;
    for (size_t v = lo; v < hi; v++) {
        const int16_t *q = r->rect + 4 * v;
        for (int ty = q[1]; ty < q[3]; ty++)
            for (int tx = q[0]; tx < q[2]; tx++)
                r->pairs[h[ty * r->tiles_x + tx]++] = r->idx[v];
    }
}

/* ---- 4. compositing ---------------------------------------------------------- */

/* Writes a finished tile's accumulators (per tile pixel, row stride
 * SPLAT_TILE) to the caller's images: colour over the background (or
 * normalised by alpha), alpha, expected depth, dominant Gaussian. Shared by
 * the scalar and AVX2 compositors. */
void splat__tile_write(const struct raster_job *j, int tile, const float *T, const float *C0,
                       const float *C1, const float *C2, const float *D, const int32_t *top)
{
    const struct raster_ctx *r = &j->rc;
    const int W = r->width, H = r->height;
    const int tx0 = (tile % r->tiles_x) * SPLAT_TILE, ty0 = (tile / r->tiles_x) * SPLAT_TILE;
    const int tw = (W - tx0 < SPLAT_TILE) ? W - tx0 : SPLAT_TILE;
    const int th = (H - ty0 < SPLAT_TILE) ? H - ty0 : SPLAT_TILE;
    const float bg0 = j->bg ? j->bg[0] : 0.0f, bg1 = j->bg ? j->bg[1] : 0.0f, bg2 = j->bg ? j->bg[2] : 0.0f;
    for (int y = 0; y < th; y++)
        for (int x = 0; x < tw; x++) {
            const int p = y * SPLAT_TILE + x;
            const size_t o = (size_t)(ty0 + y) * (size_t)W + (size_t)(tx0 + x);
            const float acc = 1.0f - T[p];
            if (j->rgb) {
                if (j->normalize) {
                    float inv = acc > 1e-6f ? 1.0f / acc : 0.0f;
                    j->rgb[3 * o] = C0[p] * inv;
                    j->rgb[3 * o + 1] = C1[p] * inv;
                    j->rgb[3 * o + 2] = C2[p] * inv;
                } else {
                    j->rgb[3 * o] = C0[p] + T[p] * bg0;
                    j->rgb[3 * o + 1] = C1[p] + T[p] * bg1;
                    j->rgb[3 * o + 2] = C2[p] + T[p] * bg2;
                }
            }
            if (j->rgba8) { /* as splat_png_write_rgb quantises (NaN -> 0) */
                const float v[3] = { C0[p] + T[p] * bg0, C1[p] + T[p] * bg1, C2[p] + T[p] * bg2 };
                const size_t o8 = j->rgba8_up ? (size_t)(H - 1 - ty0 - y) * (size_t)W + (size_t)(tx0 + x) : o;
                for (int c = 0; c < 3; c++) {
                    float q = v[c] > 0.0f ? v[c] : 0.0f;
                    q = q < 1.0f ? q : 1.0f;
                    j->rgba8[4 * o8 + (size_t)c] = (uint8_t)(q * 255.0f + 0.5f);
                }
                j->rgba8[4 * o8 + 3] = 255;
            }
            if (j->alpha)
                j->alpha[o] = acc;
            if (j->depth)
                j->depth[o] = acc > 1e-6f ? D[p] / acc : 0.0f;
            if (j->top)
                j->top[o] = top[p];
        }
}

void splat__raster_tile_ref(const struct raster_job *j, int tile)
{
    const struct raster_ctx *r = &j->rc;
    const int W = r->width, H = r->height;
    const int tx0 = (tile % r->tiles_x) * SPLAT_TILE, ty0 = (tile / r->tiles_x) * SPLAT_TILE;
    const int tw = (W - tx0 < SPLAT_TILE) ? W - tx0 : SPLAT_TILE;
    const int th = (H - ty0 < SPLAT_TILE) ? H - ty0 : SPLAT_TILE;
    enum { N = SPLAT_TILE * SPLAT_TILE };
    float T[N], C0[N], C1[N], C2[N], D[N], best[N];
    int32_t top[N];
    unsigned char done[N];
    int row_left[SPLAT_TILE];
    for (int p = 0; p < N; p++) {
        T[p] = 1.0f;
        C0[p] = C1[p] = C2[p] = D[p] = best[p] = 0.0f;
        top[p] = -1;
        done[p] = 0;
    }
    for (int y = 0; y < SPLAT_TILE; y++)
        row_left[y] = y < th ? tw : 0;
    int remaining = tw * th;
    const uint32_t s = r->tile_start[tile], e = r->tile_start[tile + 1];
    for (uint32_t k = s; k < e && remaining > 0; k++) {
        /* records of one tile are scattered over the frame's array:
         * fetch a few ahead so the miss overlaps the pixels of this one */
        if (k + PREFETCH_AHEAD < e)
            splat_prefetch(r->proj + r->pairs[k + PREFETCH_AHEAD]);
        const struct projected *P = r->proj + r->pairs[k];
        const float mx = P->mx, my = P->my, A = P->A, B = P->B, Cc = P->C;
        const float o = P->o, k2 = P->k2, z = P->z, inv_a = 1.0f / A;
        const float cut = -0.5f * k2 - 0.001f; /* power below: alpha < 1/255 for sure */
        const float cr = P->col[0], cg = P->col[1], cb = P->col[2];
        /* rows of the tile where the ellipse d' conic d <= k2 (alpha >= 1/255) lies */
        float fy0 = ceilf(my - P->ey), fy1 = floorf(my + P->ey);
        int y0 = fy0 > (float)ty0 ? (int)fy0 : ty0;
        int y1 = fy1 < (float)(ty0 + th - 1) ? (int)fy1 : ty0 + th - 1;
        for (int y = y0; y <= y1; y++) {
            if (row_left[y - ty0] == 0)
                continue;
            const float dy = my - (float)y;
            /* the ellipse's span on this row: A dx^2 + 2 B dy dx + C dy^2 <= k2,
             * widened by a relative and absolute margin for float rounding */
            const float disc = B * B * dy * dy - A * (Cc * dy * dy - k2);
            if (disc < 0.0f)
                continue;
            const float sq = sqrtf(disc) * 1.0001f;
            const float dlo = (-B * dy - sq) * inv_a, dhi = (-B * dy + sq) * inv_a;
            /* dx = mx - x, so x runs over [mx - dhi, mx - dlo] */
            const float fx0 = ceilf(mx - dhi - 0.001f - 1e-4f * fabsf(dhi));
            const float fx1 = floorf(mx - dlo + 0.001f + 1e-4f * fabsf(dlo));
            const int x0 = fx0 > (float)tx0 ? (int)fx0 : tx0;
            const int x1 = fx1 < (float)(tx0 + tw - 1) ? (int)fx1 : tx0 + tw - 1;
            const int row = (y - ty0) * SPLAT_TILE - tx0;
            for (int x = x0; x <= x1; x++) {
                const int p = row + x;
                if (done[p])
                    continue;
                const float dx = mx - (float)x;
                const float power = -0.5f * (A * dx * dx + Cc * dy * dy) - B * dx * dy;
                if (power > 0.0f || power < cut)
                    continue;
                float alpha = o * expf(power);
                alpha = alpha < SPLAT_ALPHA_MAX ? alpha : SPLAT_ALPHA_MAX;
                if (alpha < SPLAT_ALPHA_MIN)
                    continue;
                const float Tp = T[p];
                const float test_T = Tp * (1.0f - alpha);
                if (test_T < SPLAT_T_MIN) {
                    done[p] = 1;
                    row_left[y - ty0]--;
                    remaining--;
                    continue;
                }
                const float w = alpha * Tp;
                C0[p] += cr * alpha * Tp;
                C1[p] += cg * alpha * Tp;
                C2[p] += cb * alpha * Tp;
                D[p] += z * alpha * Tp;
                if (w > best[p]) {
                    best[p] = w;
                    top[p] = P->id;
                }
                T[p] = test_T;
            }
        }
    }
    splat__tile_write(j, tile, T, C0, C1, C2, D, top);
}

static void raster_task_ref(void *arg, int tile, int thread)
{
    (void)thread;
    splat__raster_tile_ref(arg, tile);
}

#if defined(F4D_SPLAT_HAVE_AVX512)
static void raster_task_avx512(void *arg, int tile, int thread)
{
    (void)thread;
    splat__raster_tile_avx512(arg, tile);
}
#endif

static void raster_task_simd(void *arg, int tile, int thread)
{
    (void)thread;
#if defined(F4D_SPLAT_HAVE_AVX2)
    splat__raster_tile_avx2(arg, tile);
#elif defined(F4D_SPLAT_HAVE_NEON)
    splat__raster_tile_neon(arg, tile);
#else
    splat__raster_tile_ref(arg, tile);
#endif
}

/* ---- driver ------------------------------------------------------------------- */

static double now_ms(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return 1e3 * (double)ts.tv_sec + 1e-6 * (double)ts.tv_nsec;
}

static double cpu_ms(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
    return 1e3 * (double)ts.tv_sec + 1e-6 * (double)ts.tv_nsec;
}

static int render_impl(splat_renderer *r, const struct splat_camera *cam, const struct splat_frame *f,
                       const float *features, const float *bg, float *rgb, float *alpha, float *depth,
                       int32_t *top, uint8_t *rgba8, int rgba8_up, int normalize, size_t *visible_out,
                       size_t *pairs_out, double *ms, double *cms, void (*frame_read)(void *),
                       void *frame_read_arg)
{
    double t0 = now_ms(), t1, t2, t3, c0 = cms ? cpu_ms() : 0.0, c1 = 0.0, c2 = 0.0, c3 = 0.0;
    if (!r)
        return F4D_EINVAL;
    r->err.msg[0] = '\0';
    if (!cam || !f)
        return fail(r, F4D_EINVAL, "render: camera or frame is NULL", NULL);
    if (cam->width != r->width || cam->height != r->height) {
        char d[96];
        snprintf(d, sizeof d, "%dx%d but the renderer is %dx%d", cam->width, cam->height, r->width, r->height);
        return fail(r, F4D_EINVAL, "render: camera size ", d);
    }
    if (!(cam->fx > 0) || !(cam->fy > 0))
        return fail(r, F4D_EINVAL, "render: camera focal lengths must be > 0", NULL);
    if (f->count && (!f->pos || !f->scale || !f->rot || !f->opacity || !f->rgb))
        return fail(r, F4D_EINVAL, "render: frame arrays are NULL", NULL);
    int rc = splat_renderer_reserve(r, f->count, 0);
    if (rc < 0)
        return rc;

    /* 1. preprocess, each chunk compacting its visible Gaussians */
    const size_t n = f->count;
    struct prep_job pj = { .r = r, .cam = cam, .f = f, .features = features };
    float tanx = 0.5f * (float)r->width / cam->fx, tany = 0.5f * (float)r->height / cam->fy;
    pj.lim_x_pos = ((float)r->width - cam->cx) / cam->fx + 0.3f * tanx;
    pj.lim_x_neg = cam->cx / cam->fx + 0.3f * tanx;
    pj.lim_y_pos = ((float)r->height - cam->cy) / cam->fy + 0.3f * tany;
    pj.lim_y_neg = cam->cy / cam->fy + 0.3f * tany;
    enum fk_isa isa = fk_ctx_isa(r->ctx);
    /* AVX2 (and the ISAs above it, which include it): vector preprocessing and
     * compositing; NEON: vector compositing */
    pj.simd = isa == FK_ISA_AVX2 || isa == FK_ISA_AVX2_VNNI || isa == FK_ISA_AVX512 ||
              isa == FK_ISA_NEON;
    pj.pv = (struct prep_view){ .f = f, .features = features, .proj = r->proj, .V = cam->w2c,
                                .fx = cam->fx, .fy = cam->fy, .cx = cam->cx, .cy = cam->cy,
                                .lim_x_pos = pj.lim_x_pos, .lim_x_neg = pj.lim_x_neg,
                                .lim_y_pos = pj.lim_y_pos, .lim_y_neg = pj.lim_y_neg,
                                .tiles_x = r->tiles_x, .tiles_y = r->tiles_y };
    int chunks = (int)((n + PREP_CHUNK - 1) / PREP_CHUNK);
    fk_parallel_for(r->ctx, chunks, 300.0 * (double)n, prep_task, &pj);
    size_t nv = 0;
    for (int c = 0; c < chunks; c++) {
        size_t m = r->chunk_visible[c], from = (size_t)c * PREP_CHUNK;
        if (from != nv) {
            memmove(r->key + nv, r->key + from, m * sizeof *r->key);
            memmove(r->idx + nv, r->idx + from, m * sizeof *r->idx);
        }
        nv += m;
    }
    if (frame_read) /* nothing below reads f */
        frame_read(frame_read_arg);

    t1 = now_ms();
    if (cms)
        c1 = cpu_ms();
    /* 2. depth order */
    radix_sort(r->ctx, r->sort_count, r->key, r->idx, r->key_tmp, r->idx_tmp, nv);
    struct order_job oj = { .r = r, .n = nv };
    fk_parallel_for(r->ctx, (int)((nv + PREP_CHUNK - 1) / PREP_CHUNK), 30.0 * (double)nv, gather_task, &oj);

    t2 = now_ms();
    if (cms)
        c2 = cpu_ms();
    /* 3. binning */
    int bchunks = (int)((nv + BIN_CHUNK - 1) / BIN_CHUNK);
    fk_parallel_for(r->ctx, bchunks, 10.0 * (double)nv, bin_count_task, &oj);
    size_t npairs = 0;
    for (int t = 0; t < r->n_tiles; t++) {
        r->tile_start[t] = (uint32_t)npairs;
        for (int c = 0; c < bchunks; c++) {
            uint32_t *h = r->hist + (size_t)c * (size_t)r->n_tiles + t, cnt = *h;
            *h = (uint32_t)npairs;
            npairs += cnt;
        }
    }
    r->tile_start[r->n_tiles] = (uint32_t)npairs;
    if (npairs > r->cap_pairs && (rc = splat_renderer_reserve(r, 0, npairs + npairs / 4)) < 0)
        return rc;
    fk_parallel_for(r->ctx, bchunks, 10.0 * (double)nv, bin_scatter_task, &oj);

    t3 = now_ms();
    if (cms)
        c3 = cpu_ms();
    /* 4. compositing */
    struct raster_job rj = { .rc = { .proj = r->proj, .pairs = r->pairs, .tile_start = r->tile_start,
                                     .width = r->width, .height = r->height, .tiles_x = r->tiles_x },
                             .bg = bg, .rgb = rgb, .alpha = alpha, .depth = depth, .top = top, .rgba8 = rgba8,
                             .rgba8_up = rgba8_up,
                             .normalize = normalize };
    fk_task_fn raster = pj.simd ? raster_task_simd : raster_task_ref;
#if defined(F4D_SPLAT_HAVE_AVX512)
    if (isa == FK_ISA_AVX512)
        raster = raster_task_avx512;
#endif
    fk_parallel_for(r->ctx, r->n_tiles, 1e9, raster, &rj);
    if (ms) {
        ms[0] = t1 - t0;
        ms[1] = t2 - t1;
        ms[2] = t3 - t2;
        ms[3] = now_ms() - t3;
    }
    if (cms) {
        cms[0] = c1 - c0;
        cms[1] = c2 - c1;
        cms[2] = c3 - c2;
        cms[3] = cpu_ms() - c3;
    }
    if (visible_out)
        *visible_out = nv;
    if (pairs_out)
        *pairs_out = npairs;
    return F4D_OK;
}

int splat_render(splat_renderer *r, const struct splat_camera *cam, const struct splat_frame *f,
                 const float bg[3], struct splat_render_out *out)
{
    if (!out)
        return r ? fail(r, F4D_EINVAL, "render: out is NULL", NULL) : F4D_EINVAL;
    return render_impl(r, cam, f, NULL, bg, out->rgb, out->alpha, out->depth, out->top, out->rgba8, out->rgba8_bottom_up, 0,
                       &out->visible, &out->pairs, out->ms_stage, out->cpu_ms_stage, out->frame_read,
                       out->frame_read_arg);
}

int splat_render_features(splat_renderer *r, const struct splat_camera *cam, const struct splat_frame *f,
                          const float *features, float *out)
{
    if (!features || !out)
        return r ? fail(r, F4D_EINVAL, "render_features: features or out is NULL", NULL) : F4D_EINVAL;
    return render_impl(r, cam, f, features, NULL, out, NULL, NULL, NULL, NULL, 0, 1, NULL, NULL, NULL, NULL, NULL,
                       NULL);
}
