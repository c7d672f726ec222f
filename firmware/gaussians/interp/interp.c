/* interp.c - constant-velocity interpolation with dual consistency and
 * pluggable fusion, and the scene budget. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "interp.h"

struct interp {
    fk_ctx          *ctx;
    struct splat_rig rig;
    int              W, H;
    splat_renderer  *r;
    float           *depth;   /* [H * W] scratch */
    long            *pix;     /* [count] scratch */
    float           *fk;      /* [count] scratch: f = axis . mu of each Gaussian */
    uint64_t        *sk, *sk2;/* [count] scratch: (f's order bits, index) to sort */
    size_t           cap_depth, cap_pix;
    enum interp_lookup lookup; /* how interp_key_build finds each pixel's depth */
    float           *zb;      /* [threads * H * W] INTERP_LOOKUP_ZBUFFER: per-thread depths */
    float           *bx, *bo; /* batched fusion: [BATCH * FUSE_IN], [BATCH * ATTRS] */
    size_t          *bslot;   /* [BATCH] output slot of each row */
};

static int fail(struct f4d_err *err, int code, const char *msg)
{
    if (err)
        snprintf(err->msg, sizeof err->msg, "%s", msg);
    return code;
}

struct interp_config interp_config_default(void)
{
    struct interp_config c = { .mode = INTERP_FUSED, .tau = 0.05f, .fuse = interp_fuse_average, .fuse_user = NULL };
    return c;
}

int interp_new(fk_ctx *ctx, const struct splat_rig *rig, interp **out, struct f4d_err *err)
{
    if (!out || !rig || !ctx)
        return fail(err, F4D_EINVAL, "interp_new: NULL argument");
    *out = NULL;
    if (rig->count < 1 || rig->count > SPLAT_RIG_MAX)
        return fail(err, F4D_EINVAL, "interp_new: the rig has no cameras");
    for (int i = 0; i < rig->count; i++) {
        int rc = splat_camera_validate(&rig->cams[i], err);
        if (rc < 0)
            return rc;
        if (rig->cams[i].width != rig->cams[0].width || rig->cams[i].height != rig->cams[0].height)
            return fail(err, F4D_EINVAL, "interp_new: all cameras of the rig must have the same size");
    }
    interp *ip = calloc(1, sizeof *ip);
    if (!ip)
        return fail(err, F4D_ENOMEM, "interp_new: out of memory");
    ip->ctx = ctx;
    ip->rig = *rig;
    ip->W = rig->cams[0].width;
    ip->H = rig->cams[0].height;
    ip->bx = malloc((size_t)INTERP_FUSE_BATCH * INTERP_FUSE_IN * sizeof *ip->bx);
    ip->bo = malloc((size_t)INTERP_FUSE_BATCH * INTERP_ATTRS * sizeof *ip->bo);
    ip->bslot = malloc((size_t)INTERP_FUSE_BATCH * sizeof *ip->bslot);
    if (!ip->bx || !ip->bo || !ip->bslot) {
        interp_free(ip);
        return fail(err, F4D_ENOMEM, "interp_new: out of memory");
    }
    int rc = splat_renderer_new(ctx, ip->W, ip->H, &ip->r, err);
    if (rc < 0) {
        interp_free(ip);
        return rc;
    }
    *out = ip;
    return F4D_OK;
}

int interp_set_rig(interp *ip, const struct splat_rig *rig, struct f4d_err *err)
{
    if (!ip || !rig)
        return fail(err, F4D_EINVAL, "interp_set_rig: NULL argument");
    if (rig->count != ip->rig.count)
        return f4d_fail(err, F4D_EINVAL, "interp_set_rig: %d cameras, the workspace has %d", rig->count,
                        ip->rig.count);
    for (int i = 0; i < rig->count; i++) {
        int rc = splat_camera_validate(&rig->cams[i], err);
        if (rc < 0)
            return rc;
        if (rig->cams[i].width != ip->W || rig->cams[i].height != ip->H)
            return f4d_fail(err, F4D_EINVAL, "interp_set_rig: camera %d is %dx%d, the workspace %dx%d", i,
                            rig->cams[i].width, rig->cams[i].height, ip->W, ip->H);
    }
    ip->rig = *rig;
    return F4D_OK;
}

int interp_set_lookup(interp *ip, enum interp_lookup mode, struct f4d_err *err)
{
    if (!ip)
        return fail(err, F4D_EINVAL, "interp_set_lookup: NULL argument");
    if (mode != INTERP_LOOKUP_RENDER && mode != INTERP_LOOKUP_ZBUFFER)
        return f4d_fail(err, F4D_EINVAL, "interp_set_lookup: unknown lookup %d", (int)mode);
    ip->lookup = mode;
    return F4D_OK;
}

void interp_free(interp *ip)
{
    if (!ip)
        return;
    splat_renderer_free(ip->r);
    free(ip->bx);
    free(ip->bo);
    free(ip->bslot);
    free(ip->depth);
    free(ip->pix);
    free(ip->fk);
    free(ip->sk);
    free(ip->sk2);
    free(ip->zb);
    free(ip);
}

void interp_key_free(struct interp_key *k)
{
    if (!k)
        return;
    free(k->cell_start);
    free(k->cell_items);
    free(k->cell_pos);
    free(k->origin);
    memset(k, 0, sizeof *k);
}

/* Pixel index of a world point in camera cam (-1 outside the image or behind),
 * and its camera depth. */
static inline long pixel_of(const struct splat_camera *cam, const float p[3], float *z)
{
    /* splat_camera_to_cam, inline: this runs twice per Gaussian per step */
    const float *m = cam->w2c;
    float q[3];
    for (int r = 0; r < 3; r++)
        q[r] = m[4 * r] * p[0] + m[4 * r + 1] * p[1] + m[4 * r + 2] * p[2] + m[4 * r + 3];
    *z = q[2];
    if (!(q[2] > SPLAT_NEAR))
        return -1;
    float iz = 1.0f / q[2]; /* one division for both coordinates */
    float u = cam->fx * q[0] * iz + cam->cx, v = cam->fy * q[1] * iz + cam->cy;
    /* the comparisons are false for NaN: a non-finite point has no pixel */
    if (!(u >= 0.0f && v >= 0.0f && u < (float)cam->width && v < (float)cam->height))
        return -1;
    return (long)v * cam->width + (long)u;
}

static int grow_i32(int32_t **p, size_t *cap, size_t need)
{
    if (need <= *cap)
        return 0;
    int32_t *q = realloc(*p, need * sizeof *q);
    if (!q)
        return -1;
    *p = q;
    *cap = need;
    return 0;
}

/* The pixel each Gaussian of f is seen at in cam (-1: outside, or hidden
 * behind the surface that pixel shows), split over the threads. */
#define PIX_TASKS 16

struct pix_job {
    interp                    *ip;
    const struct splat_camera *cam;
    const struct splat_frame  *f;
    float                      axis[3]; /* the camera's unit viewing axis */
};

static void pix_task(void *arg, int t, int thread)
{
    (void)thread;
    const struct pix_job *j = arg;
    size_t n = j->f->count, per = (n + PIX_TASKS - 1) / PIX_TASKS, lo = (size_t)t * per, hi = lo + per;
    hi = hi < n ? hi : n;
    for (size_t g = lo; g < hi; g++) {
        float z;
        long p = pixel_of(j->cam, j->f->pos + 3 * g, &z);
        if (p >= 0 && !(fabsf(z - j->ip->depth[p]) <= INTERP_VISIBLE_TOL))
            p = -1; /* hidden behind the surface this pixel shows */
        j->ip->pix[g] = p;
        const float *mu = j->f->pos + 3 * g;
        j->ip->fk[g] = j->axis[0] * mu[0] + j->axis[1] * mu[1] + j->axis[2] * mu[2];
    }
}

/* INTERP_LOOKUP_ZBUFFER: each pixel's depth is the nearest camera depth of
 * the Gaussians whose centre lands in it or whose core covers it: the disc
 * around its centre pixel where alpha = o exp(-r^2 / (2 s^2)) >= 1/2 with s
 * its largest scale seen face-on (radius capped at 64 px): the surface the
 * pixel mostly shows, with no projection of covariances, no sort and no
 * compositing. Each thread keeps its own buffer, merged by the minimum (the
 * same depths with any thread count). */
#define ZB_TASKS 16

struct zb_job {
    interp                    *ip;
    const struct splat_camera *cam;
    const struct splat_frame  *f;
    size_t                     np;
};

static void zb_task(void *arg, int t, int thread)
{
    const struct zb_job *j = arg;
    const struct splat_camera *cam = j->cam;
    const int W = cam->width, H = cam->height;
    float *zb = j->ip->zb + (size_t)thread * j->np;
    const size_t n = j->f->count, per = (n + ZB_TASKS - 1) / ZB_TASKS, lo = (size_t)t * per;
    const size_t hi = lo + per < n ? lo + per : n;
    for (size_t g = lo; g < hi; g++) {
        float z;
        long p = pixel_of(cam, j->f->pos + 3 * g, &z);
        if (p < 0)
            continue;
        if (z < zb[p])
            zb[p] = z;
        const float o = j->f->opacity[g];
        if (!(o > 0.5f))
            continue; /* no core: alpha stays below 1/2 */
        /* the core as a disc: the largest scale seen face-on, sqrt(k) sigmas
         * wide (alpha >= 1/2 out to d' C^-1 d <= k); no covariance projection */
        const float *sc = j->f->scale + 3 * g;
        float smax = sc[0] > sc[1] ? sc[0] : sc[1];
        smax = sc[2] > smax ? sc[2] : smax;
        const float k = 2.0f * logf(2.0f * o);
        const float rad = sqrtf(k) * smax * (cam->fx > cam->fy ? cam->fx : cam->fy) / z;
        if (!(rad >= 0.5f))
            continue; /* within about its own pixel: listed there already */
        const float r = rad < 64.0f ? rad : 64.0f, r2 = r * r;
        const float mx = (float)(p % W) + 0.5f, my = (float)(p / W) + 0.5f; /* its pixel's centre */
        int x0 = (int)ceilf(mx - r - 0.5f), x1 = (int)floorf(mx + r - 0.5f);
        int y0 = (int)ceilf(my - r - 0.5f), y1 = (int)floorf(my + r - 0.5f);
        x0 = x0 < 0 ? 0 : x0;
        y0 = y0 < 0 ? 0 : y0;
        x1 = x1 >= W ? W - 1 : x1;
        y1 = y1 >= H ? H - 1 : y1;
        for (int y = y0; y <= y1; y++) {
            const float dy = (float)y + 0.5f - my;
            float *row = zb + (size_t)y * W;
            for (int x = x0; x <= x1; x++) {
                const float dx = (float)x + 0.5f - mx;
                if (dx * dx + dy * dy <= r2 && z < row[x])
                    row[x] = z;
            }
        }
    }
}

struct zb_merge_job { interp *ip; size_t np; int threads; };

static void zb_merge_task(void *arg, int t, int thread)
{
    (void)thread;
    const struct zb_merge_job *j = arg;
    const size_t per = (j->np + ZB_TASKS - 1) / ZB_TASKS, lo = (size_t)t * per;
    const size_t hi = lo + per < j->np ? lo + per : j->np;
    for (size_t p = lo; p < hi; p++) {
        float d = j->ip->zb[p];
        for (int k = 1; k < j->threads; k++)
            d = j->ip->zb[(size_t)k * j->np + p] < d ? j->ip->zb[(size_t)k * j->np + p] : d;
        j->ip->depth[p] = d;
    }
}

static int zbuffer_depth(interp *ip, const struct splat_camera *cam, const struct splat_frame *f)
{
    const size_t np = (size_t)ip->W * (size_t)ip->H;
    const int threads = fk_ctx_threads(ip->ctx);
    for (size_t i = 0; i < (size_t)threads * np; i++)
        ip->zb[i] = INFINITY;
    struct zb_job j = { ip, cam, f, np };
    fk_parallel_for(ip->ctx, ZB_TASKS, 60.0 * (double)f->count, zb_task, &j);
    struct zb_merge_job mj = { ip, np, threads };
    fk_parallel_for(ip->ctx, ZB_TASKS, (double)threads * (double)np, zb_merge_task, &mj);
    return F4D_OK;
}

/* Copies the positions and f of view v's list entries (already sorted by f
 * within each pixel) into k->cell_pos's planes (x, y, z, f), split over the
 * threads: the partner search reads a pixel's candidates from one place,
 * starts at the moved point's f and stops where the distance along the axis
 * alone exceeds the best found (or tau). */
#define LIST_TASKS 16

struct list_job {
    struct interp_key *k;
    const float       *fk;        /* [count] f of each Gaussian */
    size_t             first, total, plane; /* view v's entries; the planes' stride */
    float              l1[LIST_TASKS]; /* largest |mu|_1 listed, per task */
};

static void list_task(void *arg, int t, int thread)
{
    (void)thread;
    struct list_job *j = arg;
    const struct interp_key *k = j->k;
    size_t per = (j->total + LIST_TASKS - 1) / LIST_TASKS, lo = (size_t)t * per, hi = lo + per;
    hi = hi < j->total ? hi : j->total;
    const float *pos = k->f->pos;
    float *x = k->cell_pos, *y = x + j->plane, *z = y + j->plane, *fz = z + j->plane;
    float l1 = 0.0f;
    for (size_t i = j->first + lo; i < j->first + hi; i++) {
        const size_t g = (size_t)k->cell_items[i];
        const float *mu = pos + 3 * g;
        x[i] = mu[0];
        y[i] = mu[1];
        z[i] = mu[2];
        fz[i] = j->fk[g];
        const float s = fabsf(mu[0]) + fabsf(mu[1]) + fabsf(mu[2]);
        l1 = s > l1 ? s : l1;
    }
    j->l1[t] = l1;
}

/* Stable LSD radix sort of a[0..m) by the upper 32 bits, 11 bits a pass,
 * through tmp; a pass where every key has the same digit is skipped.
 * Returns the sorted array (a or tmp). */
static uint64_t *sort_hi32(uint64_t *a, uint64_t *tmp, size_t m)
{
    for (int shift = 32; shift < 64; shift += 11) {
        size_t cnt[2048] = { 0 };
        for (size_t i = 0; i < m; i++)
            cnt[(a[i] >> shift) & 2047]++;
        if (m == 0 || cnt[(a[0] >> shift) & 2047] == m)
            continue;
        size_t sum = 0;
        for (int d = 0; d < 2048; d++) {
            size_t c = cnt[d];
            cnt[d] = sum;
            sum += c;
        }
        for (size_t i = 0; i < m; i++)
            tmp[cnt[(a[i] >> shift) & 2047]++] = a[i];
        uint64_t *t = a;
        a = tmp;
        tmp = t;
    }
    return a;
}

/* Order-preserving bits of a float (finite or infinite, not NaN). */
static inline uint32_t order_bits(float v)
{
    uint32_t u;
    memcpy(&u, &v, sizeof u);
    return u & 0x80000000u ? ~u : u | 0x80000000u;
}

int interp_key_build(interp *ip, const struct splat_frame *f, struct interp_key *k, struct f4d_err *err)
{
    if (!ip || !f || !k)
        return fail(err, F4D_EINVAL, "interp_key_build: NULL argument");
    const int V = ip->rig.count;
    const size_t np = (size_t)ip->W * (size_t)ip->H, n = f->count;
    if (grow_i32(&k->cell_start, &k->cap_cells, (size_t)V * (np + 1)) < 0 ||
        grow_i32(&k->cell_items, &k->cap_items, (size_t)V * n + 1) < 0 ||
        grow_i32(&k->origin, &k->cap_origin, n + 1) < 0)
        return fail(err, F4D_ENOMEM, "interp_key_build: out of memory for the pixel lists");
    if (4 * ((size_t)V * n + 1) > k->cap_pos) {
        float *q = realloc(k->cell_pos, 4 * ((size_t)V * n + 1) * sizeof *q);
        if (!q)
            return fail(err, F4D_ENOMEM, "interp_key_build: out of memory for the pixel lists");
        k->cell_pos = q;
        k->cap_pos = 4 * ((size_t)V * n + 1);
    }
    if (np > ip->cap_depth) {
        float *d = realloc(ip->depth, np * sizeof *d);
        if (!d)
            return fail(err, F4D_ENOMEM, "interp_key_build: out of memory");
        ip->depth = d;
        ip->cap_depth = np;
    }
    if (n + 1 > ip->cap_pix) {
        long *px = realloc(ip->pix, (n + 1) * sizeof *px);
        if (px)
            ip->pix = px;
        float *fk = realloc(ip->fk, (n + 1) * sizeof *fk);
        if (fk)
            ip->fk = fk;
        uint64_t *sk = realloc(ip->sk, (n + 1) * sizeof *sk);
        if (sk)
            ip->sk = sk;
        uint64_t *sk2 = realloc(ip->sk2, (n + 1) * sizeof *sk2);
        if (sk2)
            ip->sk2 = sk2;
        if (!px || !fk || !sk || !sk2)
            return fail(err, F4D_ENOMEM, "interp_key_build: out of memory");
        ip->cap_pix = n + 1;
    }
    if (n > INT32_MAX)
        return fail(err, F4D_EINVAL, "interp_key_build: too many Gaussians for 32-bit indices");
    if (ip->lookup == INTERP_LOOKUP_ZBUFFER && !ip->zb) {
        ip->zb = malloc((size_t)fk_ctx_threads(ip->ctx) * np * sizeof *ip->zb);
        if (!ip->zb)
            return fail(err, F4D_ENOMEM, "interp_key_build: out of memory");
    }
    k->f = f;
    k->rig = ip->rig;
    k->aligned = 0;
    k->pos_l1 = 0.0f;
    for (size_t g = 0; g < n; g++)
        k->origin[g] = -1;
    for (int v = 0; v < V; v++) {
        const struct splat_camera *cam = &ip->rig.cams[v];
        struct splat_render_out o = { .depth = ip->depth };
        if (ip->lookup == INTERP_LOOKUP_ZBUFFER)
            zbuffer_depth(ip, cam, f);
        else if (splat_render(ip->r, cam, f, NULL, &o) < 0)
            return fail(err, F4D_EINVAL, splat_renderer_error(ip->r));
        int32_t *start = k->cell_start + (size_t)v * (np + 1), *items = k->cell_items + (size_t)v * n;
        memset(start, 0, (np + 1) * sizeof *start);
        /* f = axis . mu orders each pixel's list (the partner search's bound) */
        const float *m = cam->w2c;
        const float an = sqrtf(m[8] * m[8] + m[9] * m[9] + m[10] * m[10]);
        struct pix_job pj = { ip, cam, f, { m[8] / an, m[9] / an, m[10] / an } };
        memcpy(k->zaxis[v], pj.axis, sizeof pj.axis);
        fk_parallel_for(ip->ctx, PIX_TASKS, 36.0 * (double)n, pix_task, &pj);
        size_t nv = 0;
        for (size_t g = 0; g < n; g++)
            if (ip->pix[g] >= 0) {
                start[ip->pix[g] + 1]++;
                ip->sk[nv++] = (uint64_t)order_bits(ip->fk[g]) << 32 | (uint64_t)g;
                if (k->origin[g] < 0)
                    k->origin[g] = (int32_t)((size_t)v * np + (size_t)ip->pix[g]);
            }
        for (size_t p = 0; p < np; p++)
            start[p + 1] += start[p];
        /* scattered in f order (ties by index): every pixel's list sorted */
        const uint64_t *srt = sort_hi32(ip->sk, ip->sk2, nv);
        for (size_t i = 0; i < nv; i++) {
            const size_t g = (size_t)(srt[i] & 0xffffffffu);
            items[start[ip->pix[g]]++] = (int32_t)g;
        }
        for (size_t p = np; p > 0; p--) /* the scatter advanced every start by its count */
            start[p] = start[p - 1];
        start[0] = 0;
        struct list_job lj = { .k = k, .fk = ip->fk, .first = (size_t)v * n, .total = nv, .plane = (size_t)V * n };
        fk_parallel_for(ip->ctx, LIST_TASKS, 10.0 * (double)nv, list_task, &lj);
        for (int t = 0; t < LIST_TASKS; t++)
            k->pos_l1 = lj.l1[t] > k->pos_l1 ? lj.l1[t] : k->pos_l1;
    }
    return F4D_OK;
}

int interp_key_build_aligned(interp *ip, const struct splat_frame *f, struct interp_key *k, struct f4d_err *err)
{
    if (!ip || !f || !k)
        return fail(err, F4D_EINVAL, "interp_key_build_aligned: NULL argument");
    const int V = ip->rig.count;
    const size_t np = (size_t)ip->W * (size_t)ip->H, n = f->count;
    if (n != (size_t)V * np)
        return f4d_fail(err, F4D_EINVAL,
                        "interp_key_build_aligned: %zu Gaussians, a pixel-aligned frame of %d views %dx%d has %zu",
                        n, V, ip->W, ip->H, (size_t)V * np);
    if (n > INT32_MAX)
        return fail(err, F4D_EINVAL, "interp_key_build_aligned: too many Gaussians for 32-bit indices");
    if (grow_i32(&k->cell_start, &k->cap_cells, (size_t)V * (np + 1)) < 0 ||
        grow_i32(&k->cell_items, &k->cap_items, (size_t)V * n + 1) < 0 ||
        grow_i32(&k->origin, &k->cap_origin, n + 1) < 0)
        return fail(err, F4D_ENOMEM, "interp_key_build_aligned: out of memory for the pixel lists");
    k->f = f;
    k->rig = ip->rig;
    k->aligned = 1;
    /* one Gaussian per pixel: view v's list at pixel p is Gaussian v * np + p */
    for (int v = 0; v < V; v++) {
        int32_t *start = k->cell_start + (size_t)v * (np + 1), *items = k->cell_items + (size_t)v * n;
        for (size_t p = 0; p <= np; p++)
            start[p] = (int32_t)p;
        for (size_t p = 0; p < np; p++)
            items[p] = (int32_t)((size_t)v * np + p);
    }
    for (size_t g = 0; g < n; g++)
        k->origin[g] = (int32_t)g;
    return F4D_OK;
}

/* ---- attributes and fusion ----------------------------------------------------- */

static float logitf_(float o)
{
    o = o < 1e-6f ? 1e-6f : (o > 1.0f - 1e-6f ? 1.0f - 1e-6f : o);
    return logf(o / (1.0f - o));
}

static void to_attrs(const struct splat_frame *f, size_t i, const float *motion, float k, float a[INTERP_ATTRS])
{
    for (int c = 0; c < 3; c++) {
        a[c] = f->pos[3 * i + c] + (motion ? k * motion[3 * i + c] : 0.0f);
        a[3 + c] = f->rgb[3 * i + c];
        float s = f->scale[3 * i + c];
        a[7 + c] = logf(s > 1e-12f ? s : 1e-12f);
    }
    a[6] = logitf_(f->opacity[i]);
    for (int c = 0; c < 4; c++)
        a[10 + c] = f->rot[4 * i + c];
}

static void from_attrs(const float a[INTERP_ATTRS], struct splat_frame *f, size_t i)
{
    for (int c = 0; c < 3; c++) {
        f->pos[3 * i + c] = a[c];
        f->rgb[3 * i + c] = a[3 + c];
        f->scale[3 * i + c] = expf(a[7 + c]);
    }
    f->opacity[i] = 1.0f / (1.0f + expf(-a[6]));
    float n = sqrtf(a[10] * a[10] + a[11] * a[11] + a[12] * a[12] + a[13] * a[13]);
    for (int c = 0; c < 4; c++)
        f->rot[4 * i + c] = n > 1e-12f ? a[10 + c] / n : (c == 0 ? 1.0f : 0.0f);
}

void interp_fuse_average(void *user, const float a_t[INTERP_ATTRS], const float a_tm1[INTERP_ATTRS], float a,
                         float D, float out[INTERP_ATTRS])
{
    (void)user; (void)a; (void)D;
    for (int c = 0; c < 10; c++)
        out[c] = 0.5f * (a_t[c] + a_tm1[c]);
    float dot = 0.0f;
    for (int c = 10; c < 14; c++)
        dot += a_t[c] * a_tm1[c];
    float sg = dot < 0.0f ? -1.0f : 1.0f; /* q and -q are the same rotation */
    for (int c = 10; c < 14; c++)
        out[c] = a_t[c] + sg * a_tm1[c];
}

/* interp_fuse_average of two deformed Gaussians written straight into out
 * slot o, without the log / exp round trip: the mean of two logs is the log
 * of the geometric mean (scale = sqrt(s_t s_tm1)) and the sigmoid of the mean
 * of two logits is 1 / (1 + sqrt((1 - o_t)(1 - o_tm1) / (o_t o_tm1))). Same
 * clamps as to_attrs; equal to the generic path up to float rounding, and
 * about 4x faster per pair (f4d-bench stream). */
static float clamp_o(float o) { return o < 1e-6f ? 1e-6f : (o > 1.0f - 1e-6f ? 1.0f - 1e-6f : o); }

static void average_pair(const struct splat_frame *ft, size_t g, const float *mt, float kt,
                         const struct splat_frame *fm, size_t h, const float *mm, float km,
                         struct splat_frame *out, size_t o)
{
    for (int c = 0; c < 3; c++) {
        float pt = ft->pos[3 * g + c] + kt * mt[3 * g + c], pm = fm->pos[3 * h + c] + km * mm[3 * h + c];
        out->pos[3 * o + c] = 0.5f * (pt + pm);
        out->rgb[3 * o + c] = 0.5f * (ft->rgb[3 * g + c] + fm->rgb[3 * h + c]);
        float st = ft->scale[3 * g + c], sm = fm->scale[3 * h + c];
        out->scale[3 * o + c] = sqrtf((st > 1e-12f ? st : 1e-12f) * (sm > 1e-12f ? sm : 1e-12f));
    }
    float ot = clamp_o(ft->opacity[g]), om = clamp_o(fm->opacity[h]);
    out->opacity[o] = 1.0f / (1.0f + sqrtf(((1.0f - ot) * (1.0f - om)) / (ot * om)));
    const float *qt = ft->rot + 4 * g, *qm = fm->rot + 4 * h;
    float dot = qt[0] * qm[0] + qt[1] * qm[1] + qt[2] * qm[2] + qt[3] * qm[3], sg = dot < 0.0f ? -1.0f : 1.0f;
    float q[4], n2 = 0.0f;
    for (int c = 0; c < 4; c++) {
        q[c] = qt[c] + sg * qm[c];
        n2 += q[c] * q[c];
    }
    float n = sqrtf(n2);
    for (int c = 0; c < 4; c++)
        out->rot[4 * o + c] = n > 1e-12f ? q[c] / n : (c == 0 ? 1.0f : 0.0f);
}

static void copy_deformed(const struct splat_frame *f, size_t i, const float *motion, float k,
                          struct splat_frame *out, size_t o)
{
    for (int c = 0; c < 3; c++) {
        out->pos[3 * o + c] = f->pos[3 * i + c] + (motion ? k * motion[3 * i + c] : 0.0f);
        out->scale[3 * o + c] = f->scale[3 * i + c];
        out->rgb[3 * o + c] = f->rgb[3 * i + c];
    }
    for (int c = 0; c < 4; c++)
        out->rot[4 * o + c] = f->rot[4 * i + c];
    out->opacity[o] = f->opacity[i];
}

/* Partner of Gaussian g of `self` in `other`, following `motion` (the full
 * key-to-key motion) through its origin view: among the Gaussians listed at
 * the pixel it lands on, the nearest to the moved point (the first in index
 * order on a tie), or -1 when none is within squared distance `cut` (a bound
 * on tau^2 from above: a farther nearest is no partner either way). D in
 * metres (only meaningful for a partner). */
/* Where Gaussian g of `self` moved by `motion` lands in `other`'s lists:
 * the pixel (or -1: no origin, behind the camera, outside), its view and the
 * moved point X. */
static long partner_pixel(const interp *ip, const struct interp_key *self, const struct interp_key *other,
                          const float *motion, size_t g, float X[3], int *view)
{
    int32_t o = self->origin[g];
    if (o < 0)
        return -1;
    const size_t np = (size_t)ip->W * (size_t)ip->H;
    int v = 0; /* o / np without a 64-bit division: at most SPLAT_RIG_MAX steps */
    while ((size_t)o >= (size_t)(v + 1) * np)
        v++;
    const float *mu = self->f->pos + 3 * g;
    float z;
    X[0] = mu[0] + motion[3 * g];
    X[1] = mu[1] + motion[3 * g + 1];
    X[2] = mu[2] + motion[3 * g + 2];
    *view = v;
    /* X' lives at the other key's time: its cameras, its pixel lists */
    return pixel_of(&other->rig.cams[v], X, &z);
}

/* The partner of X (landed on pixel p >= 0 of view v) among other's entries. */
static int32_t partner_in(const interp *ip, const struct interp_key *other, int v, long p, const float X[3],
                          float cut, float *D)
{
    const size_t np = (size_t)ip->W * (size_t)ip->H, n = other->f->count;
    if (other->aligned) { /* one Gaussian per pixel: no list to walk */
        const float *m = other->f->pos + 3 * ((size_t)v * np + (size_t)p);
        float dx = X[0] - m[0], dy = X[1] - m[1], dz = X[2] - m[2];
        *D = sqrtf(dx * dx + dy * dy + dz * dz);
        return (int32_t)((size_t)v * np + (size_t)p);
    }
    const int32_t *start = other->cell_start + (size_t)v * (np + 1), *items = other->cell_items + (size_t)v * n;
    /* list_task's planes: x, y, z and f of view v's entries, sorted by f */
    const size_t plane = (size_t)other->rig.count * n;
    const float *px = other->cell_pos + (size_t)v * n, *py = px + plane, *pz = py + plane, *pf = pz + plane;
    const int32_t lo = start[p], hi = start[p + 1];
    if (lo == hi)
        return -1;
    /* |X - mu| >= |f(X) - f(mu)| for the unit axis: an entry whose f is
     * farther from f(X) than the best distance (or sqrt(cut)) cannot be
     * nearer, nor can any beyond it. The bound is loosened by the rounding of
     * f (each f within 4e-7 |p|_1 of its exact value, the axis within 1e-7 of
     * unit length) and of the squared distances (relative 1e-6), so that an
     * entry is skipped only when its float distance is strictly above the
     * best: the answer is the full scan's, bit for bit. */
    const float *ax = other->zaxis[v];
    const float fq = ax[0] * X[0] + ax[1] * X[1] + ax[2] * X[2];
    const float eta = 1e-6f * (fabsf(X[0]) + fabsf(X[1]) + fabsf(X[2]) + other->pos_l1);
    int32_t l = lo, len = hi - lo; /* the first entry with f >= fq: branch-free halving */
    while (len > 1) {
        const int32_t half = len / 2;
        l = pf[l + half] < fq ? l + half : l;
        len -= half;
    }
    l += pf[l] < fq;
    float bd = INFINITY, lim = cut;
    int32_t gb = -1;
    for (int32_t k = l; k < hi; k++) {
        float t = (pf[k] - fq) * (1.0f - 1e-6f) - eta;
        if (t > 0.0f && t * t * (1.0f - 1e-6f) > lim)
            break;
        float dx = X[0] - px[k], dy = X[1] - py[k], dz = X[2] - pz[k], d2 = dx * dx + dy * dy + dz * dz;
        if (d2 < bd || (d2 == bd && items[k] < gb)) {
            bd = d2;
            gb = items[k];
            lim = bd < cut ? bd : cut;
        }
    }
    for (int32_t k = l - 1; k >= lo; k--) {
        float t = (fq - pf[k]) * (1.0f - 1e-6f) - eta;
        if (t > 0.0f && t * t * (1.0f - 1e-6f) > lim)
            break;
        float dx = X[0] - px[k], dy = X[1] - py[k], dz = X[2] - pz[k], d2 = dx * dx + dy * dy + dz * dz;
        if (d2 < bd || (d2 == bd && items[k] < gb)) {
            bd = d2;
            gb = items[k];
            lim = bd < cut ? bd : cut;
        }
    }
    if (!(bd <= cut))
        return -1;
    *D = sqrtf(bd);
    return gb;
}

static int32_t partner(const interp *ip, const struct interp_key *self, const struct interp_key *other,
                       const float *motion, size_t g, float cut, float *D)
{
    float X[3];
    int v = 0;
    long p = partner_pixel(ip, self, other, motion, g, X, &v);
    return p < 0 ? -1 : partner_in(ip, other, v, p, X, cut, D);
}

/* Runs the batched fusion on the nb rows collected and writes their slots. */
static int flush_batch(interp *ip, const struct interp_config *cfg, int nb, struct splat_frame *out,
                       struct f4d_err *err)
{
    if (cfg->fuse_batch(cfg->fuse_batch_user, ip->bx, nb, ip->bo) < 0)
        return fail(err, F4D_EINVAL, "interp_at: the batched fusion failed");
    for (int i = 0; i < nb; i++)
        from_attrs(ip->bo + (size_t)i * INTERP_ATTRS, out, ip->bslot[i]);
    return F4D_OK;
}

/* The partner of Gaussian g of key self in key other, or -1 when it has none
 * within tau (occluded there: kept, deformed); counts the case into
 * *no_origin, *kept or *matched. The one rule of interp_at and
 * interp_pair_build. */
/* tau^2 rounded up: every float d2 with sqrtf(d2) <= tau is <= cut */
static float tau_cut(float tau) { return tau * tau * (1.0f + 1e-6f) + 1e-30f; }

/* match's counting, for a partner h found with distance D */
static int32_t match_count(int32_t origin, int32_t h, float D, float tau, size_t *no_origin, size_t *kept,
                           size_t *matched)
{
    if (origin < 0)
        (*no_origin)++;
    if (h < 0 || D > tau) {
        (*kept)++;
        return -1;
    }
    (*matched)++;
    return h;
}

static int32_t match(const interp *ip, const struct interp_key *self, const struct interp_key *other,
                     const float *motion, size_t g, float tau, float *D, size_t *no_origin, size_t *kept,
                     size_t *matched)
{
    *D = 0.0f;
    int32_t h = partner(ip, self, other, motion, g, tau_cut(tau), D);
    if (self->origin[g] < 0)
        (*no_origin)++;
    if (h < 0 || *D > tau) {
        (*kept)++;
        return -1;
    }
    (*matched)++;
    return h;
}

int interp_at(interp *ip, const struct interp_key *prev, const struct interp_key *next, float a,
              const struct interp_config *cfg, struct splat_frame *out, struct interp_stats *stats,
              struct f4d_err *err)
{
    if (!ip || !prev || !next || !prev->f || !next->f || !cfg || !out)
        return fail(err, F4D_EINVAL, "interp_at: NULL argument (keys must be built)");
    if (!(a >= 0.0f && a <= 1.0f))
        return fail(err, F4D_EINVAL, "interp_at: a must be in [0, 1]");
    const struct splat_frame *F0 = prev->f, *F1 = next->f;
    struct interp_stats st = { 0 };
    if (cfg->mode == INTERP_NEAREST) {
        int rc = splat_frame_copy(out, a < 0.5f ? F0 : F1, err);
        if (rc < 0)
            return rc;
        if (stats)
            *stats = st;
        return F4D_OK;
    }
    if (!F0->motion_fwd || !F1->motion_bwd)
        return fail(err, F4D_EINVAL, "interp_at: key t-1 needs forward motion and key t backward motion");
    if (cfg->mode == INTERP_FUSED && ((!cfg->fuse && !cfg->fuse_batch) || !(cfg->tau >= 0.0f)))
        return fail(err, F4D_EINVAL, "interp_at: fusion needs a fuse function and tau >= 0");
    int rc = splat_frame_reserve(out, F0->count + F1->count, 0, err);
    if (rc < 0)
        return rc;
    const float kb = 1.0f - a, kf = a;
    size_t o = 0;
    if (cfg->mode == INTERP_KEEP_BOTH) {
        for (size_t g = 0; g < F1->count; g++)
            copy_deformed(F1, g, F1->motion_bwd, kb, out, o++);
        for (size_t h = 0; h < F0->count; h++)
            copy_deformed(F0, h, F0->motion_fwd, kf, out, o++);
        st.kept_t = F1->count;
        st.kept_tm1 = F0->count;
    } else {
        float at[INTERP_ATTRS], am[INTERP_ATTRS], af[INTERP_ATTRS];
        int nb = 0; /* rows waiting for the batched fusion */
        for (size_t g = 0; g < F1->count; g++) {
            float D;
            int32_t h = match(ip, next, prev, F1->motion_bwd, g, cfg->tau, &D, &st.no_origin_t, &st.kept_t,
                              &st.fused);
            if (h < 0) {
                copy_deformed(F1, g, F1->motion_bwd, kb, out, o++);
            } else if (cfg->fuse_batch) { /* a row now, the MLP per INTERP_FUSE_BATCH rows */
                float *x = ip->bx + (size_t)nb * INTERP_FUSE_IN;
                to_attrs(F1, g, F1->motion_bwd, kb, x);
                to_attrs(F0, (size_t)h, F0->motion_fwd, kf, x + INTERP_ATTRS);
                x[2 * INTERP_ATTRS] = a;
                x[2 * INTERP_ATTRS + 1] = D;
                ip->bslot[nb++] = o++;
                if (nb == INTERP_FUSE_BATCH) {
                    if ((rc = flush_batch(ip, cfg, nb, out, err)) < 0)
                        return rc;
                    nb = 0;
                }
            } else if (cfg->fuse == interp_fuse_average) {
                average_pair(F1, g, F1->motion_bwd, kb, F0, (size_t)h, F0->motion_fwd, kf, out, o++);
            } else {
                to_attrs(F1, g, F1->motion_bwd, kb, at);
                to_attrs(F0, (size_t)h, F0->motion_fwd, kf, am);
                cfg->fuse(cfg->fuse_user, at, am, a, D, af);
                from_attrs(af, out, o++);
            }
        }
        if (nb && (rc = flush_batch(ip, cfg, nb, out, err)) < 0)
            return rc;
        for (size_t h = 0; h < F0->count; h++) {
            float D;
            if (match(ip, prev, next, F0->motion_fwd, h, cfg->tau, &D, &st.no_origin_tm1, &st.kept_tm1,
                      &st.dropped_tm1) < 0)
                copy_deformed(F0, h, F0->motion_fwd, kf, out, o++);
        }
    }
    out->count = o;
    if (stats)
        *stats = st;
    return F4D_OK;
}

/* ---- key pairs: interp_at's fused path with the partners found once ------------- */

void interp_pair_free(struct interp_pair *pr)
{
    if (!pr)
        return;
    free(pr->partner_t);
    free(pr->partner_tm1);
    free(pr->dist_t);
    free(pr->pos0);
    free(pr->dpos);
    memset(pr, 0, sizeof *pr);
}

#define PAIR_TASKS 16 /* partner search: tasks per key pair */

struct pair_job {
    interp                  *ip;
    const struct interp_key *prev, *next;
    struct interp_pair      *pr;
    float                    tau;
    struct interp_stats      st[PAIR_TASKS];
};

/* One direction of interp_pair_build over Gaussians [lo, hi) of `self`: each
 * one's match as interp_at finds it. The lists are scattered over megabytes,
 * so the loop runs ahead: the landing pixel 2 * AHEAD Gaussians on (its list
 * bounds fetched), the list itself AHEAD on, the search now. */
#define AHEAD 8

static void pair_range(const interp *ip, const struct interp_key *self, const struct interp_key *other,
                       const float *motion, size_t lo, size_t hi, float tau, int32_t *partner_out, float *dist_out,
                       size_t *no_origin, size_t *kept, size_t *matched)
{
    enum { RING = 4 * AHEAD };
    float X[RING][3];
    long px[RING];
    int vw[RING];
    const size_t np = (size_t)ip->W * (size_t)ip->H, n = other->f->count, plane = (size_t)other->rig.count * n;
    const float cut = tau_cut(tau);
    for (size_t g = lo; g < hi + 2 * AHEAD; g++) {
        if (g < hi) { /* stage 1: where g lands; fetch its list bounds */
            const int r = (int)(g % RING);
            px[r] = partner_pixel(ip, self, other, motion, g, X[r], &vw[r]);
            if (px[r] >= 0)
                __builtin_prefetch(other->aligned ? other->f->pos + 3 * ((size_t)vw[r] * np + (size_t)px[r])
                                                  : (const float *)(other->cell_start + (size_t)vw[r] * (np + 1) +
                                                                    (size_t)px[r]));
        }
        if (g >= lo + AHEAD && g - AHEAD < hi && !other->aligned) { /* stage 2: the list's f and positions */
            const int r = (int)((g - AHEAD) % RING);
            if (px[r] >= 0) {
                const int32_t *start = other->cell_start + (size_t)vw[r] * (np + 1);
                const size_t l0 = (size_t)start[px[r]], l1 = (size_t)start[px[r] + 1];
                if (l1 > l0) {
                    const float *pf = other->cell_pos + (size_t)vw[r] * n + 3 * plane, *pmx = pf - 3 * plane;
                    const size_t mid = (l0 + l1) / 2;
                    __builtin_prefetch(pf + l0);
                    __builtin_prefetch(pf + mid);
                    __builtin_prefetch(pf + l1 - 1);
                    __builtin_prefetch(pmx + mid);
                    __builtin_prefetch(pmx + plane + mid);
                    __builtin_prefetch(pmx + 2 * plane + mid);
                }
            }
        }
        if (g >= lo + 2 * AHEAD) { /* stage 3: the search */
            const size_t q = g - 2 * AHEAD;
            const int r = (int)(q % RING);
            float D = 0.0f;
            int32_t h = px[r] < 0 ? -1 : partner_in(ip, other, vw[r], px[r], X[r], cut, &D);
            partner_out[q] = match_count(self->origin[q], h, D, tau, no_origin, kept, matched);
            if (dist_out)
                dist_out[q] = D;
        }
    }
}

/* Task t of interp_pair_build: its share of both of interp_at's loops. */
static void pair_task(void *arg, int t, int thread)
{
    (void)thread;
    struct pair_job *j = arg;
    const struct splat_frame *F0 = j->prev->f, *F1 = j->next->f;
    struct interp_stats *st = &j->st[t];
    size_t per = (F1->count + PAIR_TASKS - 1) / PAIR_TASKS, lo = (size_t)t * per, hi = lo + per;
    hi = hi < F1->count ? hi : F1->count;
    if (lo < hi) /* as interp_at's first loop */
        pair_range(j->ip, j->next, j->prev, F1->motion_bwd, lo, hi, j->tau, j->pr->partner_t, j->pr->dist_t,
                   &st->no_origin_t, &st->kept_t, &st->fused);
    per = (F0->count + PAIR_TASKS - 1) / PAIR_TASKS;
    lo = (size_t)t * per;
    hi = lo + per < F0->count ? lo + per : F0->count;
    if (lo < hi) /* and its second */
        pair_range(j->ip, j->prev, j->next, F0->motion_fwd, lo, hi, j->tau, j->pr->partner_tm1, NULL,
                   &st->no_origin_tm1, &st->kept_tm1, &st->dropped_tm1);
}

int interp_pair_build(interp *ip, const struct interp_key *prev, const struct interp_key *next,
                      const struct interp_config *cfg, struct interp_pair *pr, struct f4d_err *err)
{
    if (!ip || !prev || !next || !prev->f || !next->f || !cfg || !pr)
        return fail(err, F4D_EINVAL, "interp_pair_build: NULL argument (keys must be built)");
    const struct splat_frame *F0 = prev->f, *F1 = next->f;
    if (!F0->motion_fwd || !F1->motion_bwd)
        return fail(err, F4D_EINVAL, "interp_pair_build: key t-1 needs forward motion and key t backward motion");
    if (!(cfg->tau >= 0.0f))
        return fail(err, F4D_EINVAL, "interp_pair_build: tau must be >= 0");
    if (F1->count + 1 > pr->cap_t) {
        int32_t *p = realloc(pr->partner_t, (F1->count + 1) * sizeof *p);
        if (p)
            pr->partner_t = p;
        float *d = realloc(pr->dist_t, (F1->count + 1) * sizeof *d);
        if (d)
            pr->dist_t = d;
        if (!p || !d)
            return fail(err, F4D_ENOMEM, "interp_pair_build: out of memory");
        pr->cap_t = F1->count + 1;
    }
    if (F0->count + 1 > pr->cap_tm1) {
        int32_t *p = realloc(pr->partner_tm1, (F0->count + 1) * sizeof *p);
        if (!p)
            return fail(err, F4D_ENOMEM, "interp_pair_build: out of memory");
        pr->partner_tm1 = p;
        pr->cap_tm1 = F0->count + 1;
    }
    /* every Gaussian's partner is found alone: split over the threads, the
     * counts summed per task (same result with any thread count) */
    struct pair_job j = { ip, prev, next, pr, cfg->tau, { { 0 } } };
    fk_parallel_for(ip->ctx, PAIR_TASKS, 60.0 * (double)(F0->count + F1->count), pair_task, &j);
    struct interp_stats st = { 0 };
    for (int t = 0; t < PAIR_TASKS; t++) {
        const struct interp_stats *c = &j.st[t];
        st.fused += c->fused;
        st.kept_t += c->kept_t;
        st.kept_tm1 += c->kept_tm1;
        st.dropped_tm1 += c->dropped_tm1;
        st.no_origin_t += c->no_origin_t;
        st.no_origin_tm1 += c->no_origin_tm1;
    }
    pr->prev = prev;
    pr->next = next;
    pr->tau = cfg->tau;
    pr->st = st;
    return F4D_OK;
}

int interp_pair_at(interp *ip, const struct interp_pair *pr, float a, const struct interp_config *cfg,
                   struct splat_frame *out, struct interp_stats *stats, struct f4d_err *err)
{
    if (!ip || !pr || !pr->prev || !pr->next || !cfg || !out)
        return fail(err, F4D_EINVAL, "interp_pair_at: NULL argument (the pair must be built)");
    if (!(a >= 0.0f && a <= 1.0f))
        return fail(err, F4D_EINVAL, "interp_pair_at: a must be in [0, 1]");
    if (cfg->mode != INTERP_FUSED || (!cfg->fuse && !cfg->fuse_batch) || cfg->tau != pr->tau)
        return fail(err, F4D_EINVAL, "interp_pair_at: fused mode with the tau the pair was built with");
    const struct splat_frame *F0 = pr->prev->f, *F1 = pr->next->f;
    int rc = splat_frame_reserve(out, F0->count + F1->count, 0, err);
    if (rc < 0)
        return rc;
    const float kb = 1.0f - a, kf = a;
    size_t o = 0;
    float at[INTERP_ATTRS], am[INTERP_ATTRS], af[INTERP_ATTRS];
    int nb = 0;
    for (size_t g = 0; g < F1->count; g++) { /* interp_at's fused branch, partners given */
        int32_t h = pr->partner_t[g];
        float D = pr->dist_t[g];
        if (h < 0) {
            copy_deformed(F1, g, F1->motion_bwd, kb, out, o++);
        } else if (cfg->fuse_batch) {
            float *x = ip->bx + (size_t)nb * INTERP_FUSE_IN;
            to_attrs(F1, g, F1->motion_bwd, kb, x);
            to_attrs(F0, (size_t)h, F0->motion_fwd, kf, x + INTERP_ATTRS);
            x[2 * INTERP_ATTRS] = a;
            x[2 * INTERP_ATTRS + 1] = D;
            ip->bslot[nb++] = o++;
            if (nb == INTERP_FUSE_BATCH) {
                if ((rc = flush_batch(ip, cfg, nb, out, err)) < 0)
                    return rc;
                nb = 0;
            }
        } else if (cfg->fuse == interp_fuse_average) {
            average_pair(F1, g, F1->motion_bwd, kb, F0, (size_t)h, F0->motion_fwd, kf, out, o++);
        } else {
            to_attrs(F1, g, F1->motion_bwd, kb, at);
            to_attrs(F0, (size_t)h, F0->motion_fwd, kf, am);
            cfg->fuse(cfg->fuse_user, at, am, a, D, af);
            from_attrs(af, out, o++);
        }
    }
    if (nb && (rc = flush_batch(ip, cfg, nb, out, err)) < 0)
        return rc;
    for (size_t h = 0; h < F0->count; h++)
        if (pr->partner_tm1[h] < 0)
            copy_deformed(F0, h, F0->motion_fwd, kf, out, o++);
    out->count = o;
    if (stats)
        *stats = pr->st;
    return F4D_OK;
}

/* ---- the per-step path: positions affine in a, everything else fixed ------------ */

/* interp_pair_prepare's work, split over the threads: output slot g holds
 * Gaussian g of key t (fused or kept, one each, in order), then key t-1's
 * unpartnered ones in order, each task's from its offset (prefix of the
 * per-task counts). Every slot is computed alone, as interp_pair_at(a = 0)
 * computes it: the same frame with any thread count. */
#define PREP_TASKS 16

struct prep_job {
    const struct interp_pair *pr;
    struct splat_frame       *out;
    size_t                    off[PREP_TASKS + 1]; /* first slot of each task's key t-1 share */
};

static void prep_range(size_t n, int t, size_t *lo, size_t *hi)
{
    size_t per = (n + PREP_TASKS - 1) / PREP_TASKS;
    *lo = (size_t)t * per < n ? (size_t)t * per : n;
    *hi = *lo + per < n ? *lo + per : n;
}

static void prep_count_task(void *arg, int t, int thread)
{
    (void)thread;
    struct prep_job *j = arg;
    size_t lo, hi, c = 0;
    prep_range(j->pr->prev->f->count, t, &lo, &hi);
    for (size_t h = lo; h < hi; h++)
        c += j->pr->partner_tm1[h] < 0;
    j->off[t + 1] = c;
}

#define PREP_AHEAD 8 /* partners fetched this many slots ahead */

static void prep_task(void *arg, int t, int thread)
{
    (void)thread;
    struct prep_job *j = arg;
    const struct interp_pair *pr = j->pr;
    const struct splat_frame *F0 = pr->prev->f, *F1 = pr->next->f;
    const float *p1 = F1->pos, *m1 = F1->motion_bwd, *p0 = F0->pos, *m0 = F0->motion_fwd;
    float *b = pr->pos0, *d = pr->dpos;
    size_t lo, hi;
    prep_range(F1->count, t, &lo, &hi);
    for (size_t g = lo; g < hi; g++) { /* interp_pair_at's first loop at a = 0: slot g */
        if (g + PREP_AHEAD < hi) { /* the partners are scattered over key t-1: fetch ahead */
            const int32_t ha = pr->partner_t[g + PREP_AHEAD];
            if (ha >= 0) {
                const size_t q = (size_t)ha;
                __builtin_prefetch(p0 + 3 * q);
                __builtin_prefetch(m0 + 3 * q);
                __builtin_prefetch(F0->scale + 3 * q);
                __builtin_prefetch(F0->rgb + 3 * q);
                __builtin_prefetch(F0->rot + 4 * q);
                __builtin_prefetch(F0->opacity + q);
            }
        }
        int32_t h = pr->partner_t[g];
        if (h < 0)
            copy_deformed(F1, g, m1, 1.0f, j->out, g);
        else
            average_pair(F1, g, m1, 1.0f, F0, (size_t)h, m0, 0.0f, j->out, g);
        for (int c = 0; c < 3; c++) {
            size_t i = 3 * g + (size_t)c, k = 3 * g + (size_t)c, jj = 3 * (size_t)h + (size_t)c;
            if (h < 0) { /* p1 + (1 - a) m1 */
                b[k] = p1[i] + m1[i];
                d[k] = -m1[i];
            } else {     /* (p1 + (1 - a) m1 + p0 + a m0) / 2 */
                b[k] = 0.5f * (p1[i] + m1[i] + p0[jj]);
                d[k] = 0.5f * (m0[jj] - m1[i]);
            }
        }
    }
    prep_range(F0->count, t, &lo, &hi);
    size_t o = F1->count + j->off[t];
    for (size_t h = lo; h < hi; h++) { /* and its second: key t-1's unpartnered, in order */
        if (pr->partner_tm1[h] >= 0)
            continue;
        copy_deformed(F0, h, m0, 0.0f, j->out, o);
        for (int c = 0; c < 3; c++) { /* p0 + a m0 */
            b[3 * o + (size_t)c] = p0[3 * h + (size_t)c];
            d[3 * o + (size_t)c] = m0[3 * h + (size_t)c];
        }
        o++;
    }
}

int interp_pair_prepare(interp *ip, struct interp_pair *pr, const struct interp_config *cfg,
                        struct splat_frame *out, struct f4d_err *err)
{
    if (!ip || !pr || !pr->prev || !pr->next || !cfg || !out)
        return fail(err, F4D_EINVAL, "interp_pair_prepare: NULL argument (the pair must be built)");
    if (cfg->fuse != interp_fuse_average || cfg->fuse_batch)
        return fail(err, F4D_EINVAL, "interp_pair_prepare: the per-step path takes averaging only "
                                     "(cfg->fuse = interp_fuse_average, no fuse_batch)");
    if (cfg->mode != INTERP_FUSED || !(cfg->tau >= 0.0f) || cfg->tau != pr->tau)
        return fail(err, F4D_EINVAL, "interp_pair_prepare: fused mode with the tau the pair was built with");
    const struct splat_frame *F0 = pr->prev->f, *F1 = pr->next->f;
    int rc = splat_frame_reserve(out, F0->count + F1->count, 0, err);
    if (rc < 0)
        return rc;
    struct prep_job j = { .pr = pr, .out = out };
    fk_parallel_for(ip->ctx, PREP_TASKS, 2.0 * (double)F0->count, prep_count_task, &j);
    j.off[0] = 0;
    for (int t = 0; t < PREP_TASKS; t++)
        j.off[t + 1] += j.off[t];
    size_t n = F1->count + j.off[PREP_TASKS];
    if (3 * n >= pr->cap_out) {
        /* sized for out's capacity, not this pair's count: the pairs of a
         * stream differ in size, and a later larger one must not allocate;
         * ">=": an empty pair (n = 0) still leaves the buffers non-NULL, so
         * interp_pair_step can tell prepared from not */
        size_t want = 3 * (out->capacity > n ? out->capacity : n) + 1;
        float *p = realloc(pr->pos0, want * sizeof *p);
        if (p)
            pr->pos0 = p;
        float *d = realloc(pr->dpos, want * sizeof *d);
        if (d)
            pr->dpos = d;
        if (!p || !d)
            return fail(err, F4D_ENOMEM, "interp_pair_prepare: out of memory");
        pr->cap_out = want;
    }
    fk_parallel_for(ip->ctx, PREP_TASKS, 80.0 * (double)n, prep_task, &j);
    out->count = n;
    pr->n_out = n;
    return F4D_OK;
}

#define STEP_CHUNK 16384 /* floats per task: 64 KiB of output, L2-sized pieces */

struct step_job { const float *b, *d; float *p, a; size_t n; };

static void step_task(void *arg, int task, int thread)
{
    (void)thread;
    const struct step_job *j = arg;
    size_t s = (size_t)task * STEP_CHUNK, e = s + STEP_CHUNK < j->n ? s + STEP_CHUNK : j->n;
    const float *restrict b = j->b + s, *restrict d = j->d + s;
    float *restrict p = j->p + s;
    const float a = j->a;
    for (size_t i = 0; i < e - s; i++) /* vectorised: a flat multiply-add */
        p[i] = b[i] + a * d[i];
}

int interp_pair_step(interp *ip, const struct interp_pair *pr, float a, struct splat_frame *out,
                     struct f4d_err *err)
{
    if (!ip || !pr || !out || !pr->pos0)
        return fail(err, F4D_EINVAL, "interp_pair_step: NULL argument (the pair must be prepared)");
    if (!(a >= 0.0f && a <= 1.0f))
        return fail(err, F4D_EINVAL, "interp_pair_step: a must be in [0, 1]");
    if (out->count != pr->n_out || out->capacity < pr->n_out)
        return fail(err, F4D_EINVAL, "interp_pair_step: out is not the frame interp_pair_prepare wrote");
    struct step_job j = { pr->pos0, pr->dpos, out->pos, a, 3 * pr->n_out };
    int tasks = (int)((j.n + STEP_CHUNK - 1) / STEP_CHUNK);
    fk_parallel_for(ip->ctx, tasks, 2.0 * (double)j.n, step_task, &j);
    return F4D_OK;
}

/* ---- budget ---------------------------------------------------------------------- */

struct budget_config budget_config_default(void)
{
    struct budget_config c = { .min_opacity = 0.02f, .min_footprint = 1.0f, .voxel = 0.004f };
    return c;
}

struct vox { uint64_t key; uint32_t i; };

/* Eigen-decomposition of a symmetric 3x3 matrix (cyclic Jacobi): a = V diag(w) V'. */
static void sym3_eigen(double a[3][3], double w[3], double V[3][3])
{
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++)
            V[i][j] = i == j;
    for (int sweep = 0; sweep < 20; sweep++) {
        double off = fabs(a[0][1]) + fabs(a[0][2]) + fabs(a[1][2]);
        if (off < 1e-30)
            break;
        for (int p = 0; p < 2; p++)
            for (int q = p + 1; q < 3; q++) {
                if (fabs(a[p][q]) < 1e-300)
                    continue;
                double th = (a[q][q] - a[p][p]) / (2.0 * a[p][q]);
                double t = (th >= 0 ? 1.0 : -1.0) / (fabs(th) + sqrt(th * th + 1.0));
                double c = 1.0 / sqrt(t * t + 1.0), sn = t * c;
                for (int k = 0; k < 3; k++) { /* a = J' a J */
                    double akp = a[k][p], akq = a[k][q];
                    a[k][p] = c * akp - sn * akq;
                    a[k][q] = sn * akp + c * akq;
                }
                for (int k = 0; k < 3; k++) {
                    double apk = a[p][k], aqk = a[q][k];
                    a[p][k] = c * apk - sn * aqk;
                    a[q][k] = sn * apk + c * aqk;
                }
                for (int k = 0; k < 3; k++) {
                    double vkp = V[k][p], vkq = V[k][q];
                    V[k][p] = c * vkp - sn * vkq;
                    V[k][q] = sn * vkp + c * vkq;
                }
            }
    }
    for (int i = 0; i < 3; i++)
        w[i] = a[i][i];
}

/* Unit quaternion (w,x,y,z) of a rotation matrix whose columns are the axes. */
static void mat_to_quat(double R[3][3], float q[4])
{
    double det = R[0][0] * (R[1][1] * R[2][2] - R[1][2] * R[2][1]) - R[0][1] * (R[1][0] * R[2][2] - R[1][2] * R[2][0]) +
                 R[0][2] * (R[1][0] * R[2][1] - R[1][1] * R[2][0]);
    if (det < 0)
        for (int k = 0; k < 3; k++)
            R[k][2] = -R[k][2]; /* a proper rotation: flip one axis */
    double tr = R[0][0] + R[1][1] + R[2][2], w, x, y, z;
    if (tr > 0) {
        double S = sqrt(tr + 1.0) * 2;
        w = 0.25 * S; x = (R[2][1] - R[1][2]) / S; y = (R[0][2] - R[2][0]) / S; z = (R[1][0] - R[0][1]) / S;
    } else if (R[0][0] > R[1][1] && R[0][0] > R[2][2]) {
        double S = sqrt(1.0 + R[0][0] - R[1][1] - R[2][2]) * 2;
        w = (R[2][1] - R[1][2]) / S; x = 0.25 * S; y = (R[0][1] + R[1][0]) / S; z = (R[0][2] + R[2][0]) / S;
    } else if (R[1][1] > R[2][2]) {
        double S = sqrt(1.0 + R[1][1] - R[0][0] - R[2][2]) * 2;
        w = (R[0][2] - R[2][0]) / S; x = (R[0][1] + R[1][0]) / S; y = 0.25 * S; z = (R[1][2] + R[2][1]) / S;
    } else {
        double S = sqrt(1.0 + R[2][2] - R[0][0] - R[1][1]) * 2;
        w = (R[1][0] - R[0][1]) / S; x = (R[0][2] + R[2][0]) / S; y = (R[1][2] + R[2][1]) / S; z = 0.25 * S;
    }
    double n = sqrt(w * w + x * x + y * y + z * z);
    q[0] = (float)(w / n); q[1] = (float)(x / n); q[2] = (float)(y / n); q[3] = (float)(z / n);
}

/* Stable LSD radix sort of vx[0..n) by key, 8 bits a pass, through tmp; a
 * pass where every key has the same byte is skipped. vx is built in index
 * order, so the result is ordered by (key, index): a total order, the one
 * qsort gave before, now without qsort's allocation. */
static void vox_sort(struct vox *vx, struct vox *tmp, size_t n)
{
    struct vox *a = vx, *b = tmp;
    for (int shift = 0; shift < 64; shift += 8) {
        size_t cnt[256] = { 0 };
        for (size_t k = 0; k < n; k++)
            cnt[(a[k].key >> shift) & 0xff]++;
        if (n == 0 || cnt[(a[0].key >> shift) & 0xff] == n)
            continue;
        size_t sum = 0;
        for (int d = 0; d < 256; d++) {
            size_t c = cnt[d];
            cnt[d] = sum;
            sum += c;
        }
        for (size_t k = 0; k < n; k++)
            b[cnt[(a[k].key >> shift) & 0xff]++] = a[k];
        struct vox *t = a;
        a = b;
        b = t;
    }
    if (a != vx)
        memcpy(vx, a, n * sizeof *vx);
}

size_t budget_scratch_bytes(size_t count)
{
    return 2 * (count + 1) * sizeof(struct vox);
}

int budget_prune(const struct splat_frame *in, const struct splat_rig *rig, const struct budget_config *cfg,
                 struct splat_frame *out, struct budget_stats *stats, struct f4d_err *err)
{
    if (!in)
        return fail(err, F4D_EINVAL, "budget_prune: bad arguments (in and out must be distinct frames)");
    size_t bytes = budget_scratch_bytes(in->count);
    void *scratch = malloc(bytes);
    if (!scratch)
        return fail(err, F4D_ENOMEM, "budget_prune: out of memory");
    int rc = budget_prune_ws(in, rig, cfg, scratch, bytes, out, stats, err);
    free(scratch);
    return rc;
}

int budget_prune_ws(const struct splat_frame *in, const struct splat_rig *rig, const struct budget_config *cfg,
                    void *scratch, size_t scratch_bytes, struct splat_frame *out, struct budget_stats *stats,
                    struct f4d_err *err)
{
    return budget_prune_origin_ws(in, rig, cfg, scratch, scratch_bytes, out, NULL, stats, err);
}

/* Opacity-weighted mean of the members' motion (zeros where in lacks it). */
static void merge_motion(const float *m, const struct vox *vx, size_t s, size_t e, const float *opacity, float *dst)
{
    if (!m) {
        dst[0] = dst[1] = dst[2] = 0.0f;
        return;
    }
    double w = 0, a[3] = { 0, 0, 0 };
    for (size_t k = s; k < e; k++) {
        uint32_t i = vx[k].i;
        double wi = opacity[i] + 1e-6;
        w += wi;
        for (int c = 0; c < 3; c++)
            a[c] += wi * m[3 * i + c];
    }
    for (int c = 0; c < 3; c++)
        dst[c] = (float)(a[c] / w);
}

int budget_prune_origin_ws(const struct splat_frame *in, const struct splat_rig *rig, const struct budget_config *cfg,
                           void *scratch, size_t scratch_bytes, struct splat_frame *out, uint32_t *origin,
                           struct budget_stats *stats, struct f4d_err *err)
{
    if (!in || !rig || !cfg || !out || in == out)
        return fail(err, F4D_EINVAL, "budget_prune: bad arguments (in and out must be distinct frames)");
    if (!(cfg->voxel >= 0.0f) || !(cfg->min_footprint >= 0.0f) || !(cfg->min_opacity >= 0.0f))
        return fail(err, F4D_EINVAL, "budget_prune: thresholds must be >= 0");
    if (!scratch || scratch_bytes < budget_scratch_bytes(in->count))
        return f4d_fail(err, F4D_EINVAL, "budget_prune: scratch of %zu bytes, %zu Gaussians need %zu",
                        scratch_bytes, in->count, budget_scratch_bytes(in->count));
    struct budget_stats st = { .total = in->count };
    struct vox *vx = scratch, *vtmp = vx + in->count + 1;
    const float base = cfg->voxel > 0.0f ? cfg->voxel : 1e-4f;
    size_t nv = 0;
    for (size_t i = 0; i < in->count; i++) {
        if (in->opacity[i] < cfg->min_opacity) {
            st.pruned_opacity++;
            continue;
        }
        int seen = 0;
        float diam = 0.0f, pix_m = 1e30f; /* largest footprint (px), smallest pixel size (m) */
        for (int c = 0; c < rig->count; c++) {
            const struct splat_camera *cam = &rig->cams[c];
            float m[2], cv[3];
            if (!splat_camera_project(cam, in->pos + 3 * i, in->scale + 3 * i, in->rot + 4 * i, m, cv))
                continue;
            float mid = 0.5f * (cv[0] + cv[2]), det = cv[0] * cv[2] - cv[1] * cv[1];
            float lam = mid + sqrtf(fmaxf(0.0f, mid * mid - det));
            float rad = 3.0f * sqrtf(lam) + 1.0f;
            if (m[0] < -rad || m[1] < -rad || m[0] > (float)cam->width + rad || m[1] > (float)cam->height + rad)
                continue; /* outside this view */
            seen = 1;
            diam = fmaxf(diam, 2.0f * sqrtf(lam));
            float q[3];
            splat_camera_to_cam(cam, in->pos + 3 * i, q);
            pix_m = fminf(pix_m, q[2] / (0.5f * (cam->fx + cam->fy)));
        }
        if (!seen) {
            st.pruned_outside++;
            continue;
        }
        float cell = cfg->voxel;
        if (diam < cfg->min_footprint) {
            st.subpixel++;
            cell = fmaxf(cell, pix_m);
        }
        uint64_t key = (uint64_t)i | (63ull << 58); /* no cell: unique key, never merged */
        if (cell > 0.0f) {
            int level = (int)ceilf(log2f(cell / base));
            level = level < 0 ? 0 : (level > 30 ? 30 : level);
            float size = base * (float)(1u << level);
            int64_t q[3];
            for (int c = 0; c < 3; c++)
                q[c] = (int64_t)floorf(in->pos[3 * i + c] / size) & 0x7FFFF;
            key = ((uint64_t)level << 58) | ((uint64_t)q[0] << 38) | ((uint64_t)q[1] << 19) | (uint64_t)q[2];
        }
        vx[nv].key = key;
        vx[nv].i = (uint32_t)i;
        nv++;
    }
    vox_sort(vx, vtmp, nv);
    size_t groups = 0;
    for (size_t s = 0; s < nv; s++)
        groups += s == 0 || vx[s].key != vx[s - 1].key || (vx[s].key >> 58) == 63;
    int motion = in->motion_bwd || in->motion_fwd;
    if (!motion) { /* out's motion follows in's (freeing allocates nothing) */
        free(out->motion_bwd);
        free(out->motion_fwd);
        out->motion_bwd = out->motion_fwd = NULL;
    }
    int rc = splat_frame_resize(out, groups, motion, err);
    if (rc < 0)
        return rc;
    size_t o = 0;
    for (size_t s = 0; s < nv;) {
        size_t e = s + 1;
        if ((vx[s].key >> 58) != 63)
            while (e < nv && vx[e].key == vx[s].key)
                e++;
        /* moment matching: the merged covariance is the weighted mean of the
         * members' covariances plus the spread of their centres */
        double w = 0, p[3] = { 0, 0, 0 }, c3[3] = { 0, 0, 0 }, S[3][3] = { { 0 } }, P2[3][3] = { { 0 } };
        float omax = -1.0f;
        uint32_t best = vx[s].i;
        if (e - s == 1) /* a Gaussian alone in its cell is copied below: no moments to gather (most of them) */
            omax = in->opacity[best] > omax ? in->opacity[best] : omax; /* as the loop would */
        for (size_t k = s; k < e && e - s > 1; k++) {
            uint32_t i = vx[k].i;
            double wi = in->opacity[i] + 1e-6;
            w += wi;
            float qs[4], R[9];
            memcpy(qs, in->rot + 4 * i, sizeof qs);
            float qn = sqrtf(qs[0] * qs[0] + qs[1] * qs[1] + qs[2] * qs[2] + qs[3] * qs[3]);
            if (!(qn > 1e-12f)) { qs[0] = 1; qs[1] = qs[2] = qs[3] = 0; qn = 1; }
            float qw = qs[0] / qn, qx = qs[1] / qn, qy = qs[2] / qn, qz = qs[3] / qn;
            R[0] = 1 - 2 * (qy * qy + qz * qz); R[1] = 2 * (qx * qy - qw * qz); R[2] = 2 * (qx * qz + qw * qy);
            R[3] = 2 * (qx * qy + qw * qz); R[4] = 1 - 2 * (qx * qx + qz * qz); R[5] = 2 * (qy * qz - qw * qx);
            R[6] = 2 * (qx * qz - qw * qy); R[7] = 2 * (qy * qz + qw * qx); R[8] = 1 - 2 * (qx * qx + qy * qy);
            for (int r = 0; r < 3; r++) {
                double x = in->pos[3 * i + r];
                p[r] += wi * x;
                c3[r] += wi * in->rgb[3 * i + r];
                for (int c = 0; c < 3; c++) {
                    double acc = 0;
                    for (int m = 0; m < 3; m++) {
                        double sm = in->scale[3 * i + m];
                        acc += (double)R[3 * r + m] * sm * sm * (double)R[3 * c + m];
                    }
                    S[r][c] += wi * acc;
                    P2[r][c] += wi * x * in->pos[3 * i + c];
                }
            }
            if (in->opacity[i] > omax) {
                omax = in->opacity[i];
                best = i;
            }
        }
        if (e - s == 1) {
            memcpy(out->pos + 3 * o, in->pos + 3 * best, 3 * sizeof(float));
            memcpy(out->rgb + 3 * o, in->rgb + 3 * best, 3 * sizeof(float));
            memcpy(out->scale + 3 * o, in->scale + 3 * best, 3 * sizeof(float));
            memcpy(out->rot + 4 * o, in->rot + 4 * best, 4 * sizeof(float));
        } else {
            double cov[3][3], ev[3], V[3][3];
            for (int r = 0; r < 3; r++)
                for (int c = 0; c < 3; c++)
                    cov[r][c] = S[r][c] / w + P2[r][c] / w - (p[r] / w) * (p[c] / w);
            sym3_eigen(cov, ev, V);
            mat_to_quat(V, out->rot + 4 * o);
            for (int c = 0; c < 3; c++) {
                out->pos[3 * o + c] = (float)(p[c] / w);
                out->rgb[3 * o + c] = (float)(c3[c] / w);
                out->scale[3 * o + c] = (float)sqrt(ev[c] > 0 ? ev[c] : 0);
            }
        }
        out->opacity[o] = omax;
        if (motion) {
            merge_motion(in->motion_bwd, vx, s, e, in->opacity, out->motion_bwd + 3 * o);
            merge_motion(in->motion_fwd, vx, s, e, in->opacity, out->motion_fwd + 3 * o);
        }
        if (origin)
            origin[o] = best;
        st.merged += e - s - 1;
        o++;
        s = e;
    }
    out->count = o;
    st.kept = o;
    if (stats)
        *stats = st;
    return F4D_OK;
}
