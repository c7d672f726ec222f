/* render.c - the CPU rasterizer: the reference 3DGS forward pass (R in
 * gaussians.md §1) on 16x16 tiles, both cores through fk_parallel_for.
 *
 * Stages per frame, all in buffers owned by the renderer:
 *   1. preprocess (parallel over Gaussians): cull, EWA covariance, conic,
 *      radius, tile rectangle, colour;
 *   2. a stable LSD radix sort of the visible Gaussians by depth bits
 *      (depth > 0.2, so IEEE bits order like the values; ties keep index
 *      order, the same order R's (tile | depth) radix sort produces);
 *   3. binning: per-tile counts, prefix sum, scatter in depth order, so every
 *      tile list is depth-ordered;
 *   4. compositing (parallel over tiles). Each Gaussian of a tile's list is
 *      applied to the pixels of the tile where its alpha can reach 1/255 (a
 *      box around the ellipse o exp(power) = 1/255, with a pixel of margin);
 *      every other pixel of the tile would skip it in R as well, so the
 *      per-pixel sequence of operations is R's. */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "splat_internal.h"

#define PREP_CHUNK 4096

struct splat_renderer {
    fk_ctx *ctx;
    int     width, height, tiles_x, tiles_y, n_tiles;
    size_t  cap_g, cap_pairs;
    /* per Gaussian (capacity cap_g) */
    float   *mean;     /* [2] pixel coordinates, R convention (integer centres) */
    float   *conic;    /* [3] A, B, C of the inverse 2D covariance */
    float   *opac;
    float   *cut;      /* power below which alpha < 1/255 for sure */
    float   *ext;      /* [2] half extent (pixels) of the alpha >= 1/255 box */
    float   *color;    /* [3] */
    float   *depth;
    int32_t *rect;     /* [4] tile x0, y0, x1, y1 (exclusive); x0 == x1: culled */
    uint32_t *key, *key_tmp;
    int32_t *idx, *idx_tmp;
    /* per tile */
    uint32_t *tile_start; /* [n_tiles + 1] */
    uint32_t *tile_fill;  /* [n_tiles] */
    int32_t  *pairs;      /* [cap_pairs] Gaussian indices, tile-major, depth-ordered */
    struct splat_error err;
};

static int fail(splat_renderer *r, int code, const char *msg, const char *detail)
{
    snprintf(r->err.msg, sizeof r->err.msg, "%s%s", msg, detail ? detail : "");
    return code;
}

static void free_gaussian_buffers(splat_renderer *r)
{
    free(r->mean); free(r->conic); free(r->opac); free(r->cut); free(r->ext);
    free(r->color); free(r->depth); free(r->rect);
    free(r->key); free(r->key_tmp); free(r->idx); free(r->idx_tmp);
    r->mean = r->conic = r->opac = r->cut = r->ext = r->color = r->depth = NULL;
    r->rect = r->idx = r->idx_tmp = NULL;
    r->key = r->key_tmp = NULL;
    r->cap_g = 0;
}

int splat_renderer_reserve(splat_renderer *r, size_t gaussians, size_t pairs)
{
    if (!r)
        return SPLAT_EINVAL;
    if (gaussians > r->cap_g) {
        if (gaussians > (size_t)INT32_MAX)
            return fail(r, SPLAT_EINVAL, "renderer: more than 2^31 Gaussians", NULL);
        free_gaussian_buffers(r);
        size_t n = gaussians;
        r->mean = malloc(2 * n * sizeof(float));
        r->conic = malloc(3 * n * sizeof(float));
        r->opac = malloc(n * sizeof(float));
        r->cut = malloc(n * sizeof(float));
        r->ext = malloc(2 * n * sizeof(float));
        r->color = malloc(3 * n * sizeof(float));
        r->depth = malloc(n * sizeof(float));
        r->rect = malloc(4 * n * sizeof(int32_t));
        r->key = malloc(n * sizeof(uint32_t));
        r->key_tmp = malloc(n * sizeof(uint32_t));
        r->idx = malloc(n * sizeof(int32_t));
        r->idx_tmp = malloc(n * sizeof(int32_t));
        if (!r->mean || !r->conic || !r->opac || !r->cut || !r->ext || !r->color || !r->depth ||
            !r->rect || !r->key || !r->key_tmp || !r->idx || !r->idx_tmp) {
            free_gaussian_buffers(r);
            return fail(r, SPLAT_ENOMEM, "renderer: out of memory for the Gaussian buffers", NULL);
        }
        r->cap_g = n;
    }
    if (pairs > r->cap_pairs) {
        if (pairs > (size_t)UINT32_MAX)
            return fail(r, SPLAT_EINVAL, "renderer: more than 2^32 Gaussian-tile pairs", NULL);
        int32_t *p = realloc(r->pairs, pairs * sizeof *p);
        if (!p)
            return fail(r, SPLAT_ENOMEM, "renderer: out of memory for the tile lists", NULL);
        r->pairs = p;
        r->cap_pairs = pairs;
    }
    return SPLAT_OK;
}

int splat_renderer_new(fk_ctx *ctx, int width, int height, splat_renderer **out, struct splat_error *err)
{
    if (!out)
        return splat__fail(err, SPLAT_EINVAL, "splat_renderer_new: out is NULL");
    *out = NULL;
    if (!ctx)
        return splat__fail(err, SPLAT_EINVAL, "splat_renderer_new: fk context is NULL");
    if (width <= 0 || height <= 0 || width > 16384 || height > 16384)
        return splat__fail(err, SPLAT_EINVAL, "splat_renderer_new: size %dx%d must be within 1..16384",
                           width, height);
    splat_renderer *r = calloc(1, sizeof *r);
    if (!r)
        return splat__fail(err, SPLAT_ENOMEM, "splat_renderer_new: out of memory");
    r->ctx = ctx;
    r->width = width;
    r->height = height;
    r->tiles_x = (width + SPLAT_TILE - 1) / SPLAT_TILE;
    r->tiles_y = (height + SPLAT_TILE - 1) / SPLAT_TILE;
    r->n_tiles = r->tiles_x * r->tiles_y;
    r->tile_start = calloc((size_t)r->n_tiles + 1, sizeof *r->tile_start);
    r->tile_fill = calloc((size_t)r->n_tiles, sizeof *r->tile_fill);
    if (!r->tile_start || !r->tile_fill || splat_renderer_reserve(r, 1024, 4096) < 0) {
        splat_renderer_free(r);
        return splat__fail(err, SPLAT_ENOMEM, "splat_renderer_new: out of memory");
    }
    *out = r;
    return SPLAT_OK;
}

void splat_renderer_free(splat_renderer *r)
{
    if (!r)
        return;
    free_gaussian_buffers(r);
    free(r->tile_start);
    free(r->tile_fill);
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
};

static float clampf(float v, float lo, float hi)
{
    return v < lo ? lo : (v > hi ? hi : v);
}

static void prep_one(const struct prep_job *j, size_t i)
{
    splat_renderer *r = j->r;
    const struct splat_camera *cam = j->cam;
    const struct splat_frame *f = j->f;
    const float *V = cam->w2c;
    int32_t *rect = r->rect + 4 * i;
    rect[0] = rect[1] = rect[2] = rect[3] = 0;

    const float *p = f->pos + 3 * i;
    float tx = V[0] * p[0] + V[1] * p[1] + V[2] * p[2] + V[3];
    float ty = V[4] * p[0] + V[5] * p[1] + V[6] * p[2] + V[7];
    float tz = V[8] * p[0] + V[9] * p[1] + V[10] * p[2] + V[11];
    if (!(tz > SPLAT_NEAR) || !isfinite(tx) || !isfinite(ty) || !isfinite(tz))
        return; /* near-plane cull (R: z <= 0.2), and NaN/Inf positions */
    float o = f->opacity[i];
    if (!(o >= SPLAT_ALPHA_MIN))
        return; /* alpha = min(0.99, o exp(power <= 0)) <= o never reaches 1/255 */

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
        return; /* R skips det == 0; a non-finite or negative one cannot be drawn either */
    float det_inv = 1.0f / det;
    float mid = 0.5f * (a + c);
    float disc = sqrtf(fmaxf(0.1f, mid * mid - det));
    float lam = fmaxf(mid + disc, mid - disc);
    float radius = ceilf(3.0f * sqrtf(lam));
    if (!isfinite(radius))
        return;

    /* ndc2Pix of R == fx x / z + cx - 0.5 for the centred principal point. */
    float pw = 1.0f / (tz + 0.0000001f);
    float mx = fx * tx * pw + cam->cx - 0.5f;
    float my = fy * ty * pw + cam->cy - 0.5f;
    if (!isfinite(mx) || !isfinite(my))
        return;
    float gx = (float)r->tiles_x, gy = (float)r->tiles_y;
    int x0 = (int)clampf((mx - radius) / SPLAT_TILE, 0.0f, gx);
    int y0 = (int)clampf((my - radius) / SPLAT_TILE, 0.0f, gy);
    int x1 = (int)clampf((mx + radius + SPLAT_TILE - 1) / SPLAT_TILE, 0.0f, gx);
    int y1 = (int)clampf((my + radius + SPLAT_TILE - 1) / SPLAT_TILE, 0.0f, gy);
    if ((x1 - x0) * (y1 - y0) == 0)
        return;

    r->mean[2 * i] = mx;
    r->mean[2 * i + 1] = my;
    r->conic[3 * i] = c * det_inv;
    r->conic[3 * i + 1] = -b * det_inv;
    r->conic[3 * i + 2] = a * det_inv;
    r->opac[i] = o;
    float k2 = 2.0f * logf(255.0f * o); /* d' Sigma^-1 d <= k2 where alpha >= 1/255 */
    r->cut[i] = -0.5f * k2 - 0.001f;
    r->ext[2 * i] = sqrtf(fmaxf(k2, 0.0f) * a) * 1.001f + 1.0f;
    r->ext[2 * i + 1] = sqrtf(fmaxf(k2, 0.0f) * c) * 1.001f + 1.0f;
    r->depth[i] = tz;
    const float *col = j->features ? j->features + 3 * i : f->rgb + 3 * i;
    for (int k = 0; k < 3; k++)
        r->color[3 * i + k] = j->features ? col[k] : fmaxf(col[k], 0.0f);
    rect[0] = x0; rect[1] = y0; rect[2] = x1; rect[3] = y1;
}

static void prep_task(void *arg, int task, int thread)
{
    (void)thread;
    const struct prep_job *j = arg;
    size_t lo = (size_t)task * PREP_CHUNK, hi = lo + PREP_CHUNK;
    if (hi > j->f->count)
        hi = j->f->count;
    for (size_t i = lo; i < hi; i++)
        prep_one(j, i);
}

/* ---- 2. depth sort --------------------------------------------------------- */

static void radix_sort(uint32_t *key, int32_t *val, uint32_t *ktmp, int32_t *vtmp, size_t n)
{
    uint32_t *ks = key, *kd = ktmp;
    int32_t *vs = val, *vd = vtmp;
    for (int shift = 0; shift < 32; shift += 8) {
        size_t count[256] = {0};
        for (size_t i = 0; i < n; i++)
            count[(ks[i] >> shift) & 255]++;
        int single = 0;
        for (int b = 0; b < 256; b++)
            if (count[b] == n)
                single = 1;
        if (single)
            continue; /* every key shares this byte: the pass would not move anything */
        size_t sum = 0;
        for (int b = 0; b < 256; b++) {
            size_t c = count[b];
            count[b] = sum;
            sum += c;
        }
        for (size_t i = 0; i < n; i++) {
            size_t d = count[(ks[i] >> shift) & 255]++;
            kd[d] = ks[i];
            vd[d] = vs[i];
        }
        uint32_t *kt = ks; ks = kd; kd = kt;
        int32_t *vt = vs; vs = vd; vd = vt;
    }
    if (ks != key) {
        memcpy(key, ks, n * sizeof *key);
        memcpy(val, vs, n * sizeof *val);
    }
}

/* ---- 4. compositing -------------------------------------------------------- */

struct raster_job {
    splat_renderer *r;
    const float    *bg;
    float          *rgb, *alpha, *depth;
    int32_t        *top;
    int             normalize; /* features: divide by accumulated alpha */
};

static void raster_tile(void *arg, int tile, int thread)
{
    (void)thread;
    const struct raster_job *j = arg;
    const splat_renderer *r = j->r;
    const int W = r->width, H = r->height;
    const int tx0 = (tile % r->tiles_x) * SPLAT_TILE, ty0 = (tile / r->tiles_x) * SPLAT_TILE;
    const int tw = (W - tx0 < SPLAT_TILE) ? W - tx0 : SPLAT_TILE;
    const int th = (H - ty0 < SPLAT_TILE) ? H - ty0 : SPLAT_TILE;
    enum { N = SPLAT_TILE * SPLAT_TILE };
    float T[N], C0[N], C1[N], C2[N], D[N], best[N];
    int32_t top[N];
    unsigned char done[N];
    for (int p = 0; p < N; p++) {
        T[p] = 1.0f;
        C0[p] = C1[p] = C2[p] = D[p] = best[p] = 0.0f;
        top[p] = -1;
        done[p] = 0;
    }
    int remaining = tw * th;
    const uint32_t s = r->tile_start[tile], e = r->tile_start[tile + 1];
    for (uint32_t k = s; k < e && remaining > 0; k++) {
        const int32_t g = r->pairs[k];
        const float mx = r->mean[2 * g], my = r->mean[2 * g + 1];
        const float A = r->conic[3 * g], B = r->conic[3 * g + 1], Cc = r->conic[3 * g + 2];
        const float o = r->opac[g], cut = r->cut[g], z = r->depth[g];
        const float cr = r->color[3 * g], cg = r->color[3 * g + 1], cb = r->color[3 * g + 2];
        const float ex = r->ext[2 * g], ey = r->ext[2 * g + 1];
        /* pixel box of the tile where alpha may reach 1/255 */
        float fx0 = ceilf(mx - ex), fx1 = floorf(mx + ex), fy0 = ceilf(my - ey), fy1 = floorf(my + ey);
        int x0 = fx0 > (float)tx0 ? (int)fx0 : tx0;
        int x1 = fx1 < (float)(tx0 + tw - 1) ? (int)fx1 : tx0 + tw - 1;
        int y0 = fy0 > (float)ty0 ? (int)fy0 : ty0;
        int y1 = fy1 < (float)(ty0 + th - 1) ? (int)fy1 : ty0 + th - 1;
        for (int y = y0; y <= y1; y++) {
            const float dy = my - (float)y;
            const int row = (y - ty0) * SPLAT_TILE - tx0;
            for (int x = x0; x <= x1; x++) {
                const int p = row + x;
                if (done[p])
                    continue;
                const float dx = mx - (float)x;
                const float power = -0.5f * (A * dx * dx + Cc * dy * dy) - B * dx * dy;
                if (power > 0.0f || power < cut)
                    continue;
                const float alpha = fminf(SPLAT_ALPHA_MAX, o * expf(power));
                if (alpha < SPLAT_ALPHA_MIN)
                    continue;
                const float Tp = T[p];
                const float test_T = Tp * (1.0f - alpha);
                if (test_T < SPLAT_T_MIN) {
                    done[p] = 1;
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
                    top[p] = g;
                }
                T[p] = test_T;
            }
        }
    }
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
            if (j->alpha)
                j->alpha[o] = acc;
            if (j->depth)
                j->depth[o] = acc > 1e-6f ? D[p] / acc : 0.0f;
            if (j->top)
                j->top[o] = top[p];
        }
}

/* ---- driver ---------------------------------------------------------------- */

static int render_impl(splat_renderer *r, const struct splat_camera *cam, const struct splat_frame *f,
                       const float *features, const float *bg, float *rgb, float *alpha, float *depth,
                       int32_t *top, int normalize, size_t *visible_out, size_t *pairs_out)
{
    if (!r)
        return SPLAT_EINVAL;
    r->err.msg[0] = '\0';
    if (!cam || !f)
        return fail(r, SPLAT_EINVAL, "render: camera or frame is NULL", NULL);
    if (cam->width != r->width || cam->height != r->height) {
        char d[96];
        snprintf(d, sizeof d, "%dx%d but the renderer is %dx%d", cam->width, cam->height, r->width, r->height);
        return fail(r, SPLAT_EINVAL, "render: camera size ", d);
    }
    if (!(cam->fx > 0) || !(cam->fy > 0))
        return fail(r, SPLAT_EINVAL, "render: camera focal lengths must be > 0", NULL);
    if (f->count && (!f->pos || !f->scale || !f->rot || !f->opacity || !f->rgb))
        return fail(r, SPLAT_EINVAL, "render: frame arrays are NULL", NULL);
    int rc = splat_renderer_reserve(r, f->count, 0);
    if (rc < 0)
        return rc;

    const size_t n = f->count;
    struct prep_job pj = { .r = r, .cam = cam, .f = f, .features = features };
    float tanx = 0.5f * (float)r->width / cam->fx, tany = 0.5f * (float)r->height / cam->fy;
    pj.lim_x_pos = ((float)r->width - cam->cx) / cam->fx + 0.3f * tanx;
    pj.lim_x_neg = cam->cx / cam->fx + 0.3f * tanx;
    pj.lim_y_pos = ((float)r->height - cam->cy) / cam->fy + 0.3f * tany;
    pj.lim_y_neg = cam->cy / cam->fy + 0.3f * tany;
    int chunks = (int)((n + PREP_CHUNK - 1) / PREP_CHUNK);
    fk_parallel_for(r->ctx, chunks, 200.0 * (double)n, prep_task, &pj);

    /* visible list in index order, keyed by depth bits */
    size_t nv = 0, npairs = 0;
    for (size_t i = 0; i < n; i++) {
        const int32_t *rc4 = r->rect + 4 * i;
        if (rc4[2] == rc4[0])
            continue;
        uint32_t bits;
        memcpy(&bits, &r->depth[i], sizeof bits);
        r->key[nv] = bits;
        r->idx[nv] = (int32_t)i;
        nv++;
        npairs += (size_t)(rc4[2] - rc4[0]) * (size_t)(rc4[3] - rc4[1]);
    }
    radix_sort(r->key, r->idx, r->key_tmp, r->idx_tmp, nv);

    rc = splat_renderer_reserve(r, 0, npairs + npairs / 4);
    if (rc < 0)
        return rc;
    /* binning */
    memset(r->tile_fill, 0, (size_t)r->n_tiles * sizeof *r->tile_fill);
    for (size_t v = 0; v < nv; v++) {
        const int32_t *q = r->rect + 4 * r->idx[v];
        for (int ty = q[1]; ty < q[3]; ty++)
            for (int tx = q[0]; tx < q[2]; tx++)
                r->tile_fill[ty * r->tiles_x + tx]++;
    }
    uint32_t sum = 0;
    for (int t = 0; t < r->n_tiles; t++) {
        r->tile_start[t] = sum;
        sum += r->tile_fill[t];
        r->tile_fill[t] = r->tile_start[t];
    }
    r->tile_start[r->n_tiles] = sum;
    for (size_t v = 0; v < nv; v++) {
        const int32_t g = r->idx[v];
        const int32_t *q = r->rect + 4 * g;
        for (int ty = q[1]; ty < q[3]; ty++)
            for (int tx = q[0]; tx < q[2]; tx++)
                r->pairs[r->tile_fill[ty * r->tiles_x + tx]++] = g;
    }

    struct raster_job rj = { .r = r, .bg = bg, .rgb = rgb, .alpha = alpha, .depth = depth, .top = top,
                             .normalize = normalize };
    fk_parallel_for(r->ctx, r->n_tiles, 1e9, raster_tile, &rj);
    if (visible_out)
        *visible_out = nv;
    if (pairs_out)
        *pairs_out = npairs;
    return SPLAT_OK;
}

int splat_render(splat_renderer *r, const struct splat_camera *cam, const struct splat_frame *f,
                 const float bg[3], struct splat_render_out *out)
{
    if (!out)
        return r ? fail(r, SPLAT_EINVAL, "render: out is NULL", NULL) : SPLAT_EINVAL;
    return render_impl(r, cam, f, NULL, bg, out->rgb, out->alpha, out->depth, out->top, 0,
                       &out->visible, &out->pairs);
}

int splat_render_features(splat_renderer *r, const struct splat_camera *cam, const struct splat_frame *f,
                          const float *features, float *out)
{
    if (!features || !out)
        return r ? fail(r, SPLAT_EINVAL, "render_features: features or out is NULL", NULL) : SPLAT_EINVAL;
    return render_impl(r, cam, f, features, NULL, out, NULL, NULL, NULL, 1, NULL, NULL);
}
