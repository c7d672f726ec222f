/* codec.c - key frames: quantizers, planes (delta, byte shuffle, zstd),
 * intra and predicted coding, the encoder and the decoder. */
#define ZSTD_STATIC_LINKING_ONLY
#include <zstd.h>

#include <math.h>
#include <stdio.h>
#include <stdlib.h>

#include "codec_internal.h"

#define NCH        20   /* channels of one Gaussian record                 */
#define NQZ        16   /* channels with a (lo, step) quantizer            */
#define QMAX       16777215u /* 24 bits                                   */
#define RMAX       16777215  /* residual magnitude cap                      */
#define FHDR1      20   /* version 1 frame header                        */
#define NCOEF      7
#define FHDR       (FHDR1 + 4 * NCOEF) /* version 2: + predictor coefficients */
#define COEF_MAX   1000.0f
#define ZLEVEL     5    /* candidates and planes (default effort)          */
#define ZLEVEL_FAST 1   /* both, CODEC_EFFORT_FAST                        */
#define ZLEVEL_MAX 19   /* the chosen planes, CODEC_EFFORT_MAX            */
#define SCALE_MIN  1e-7f

/* Record channels. Intra: 0-2 pos, 3-5 log-scale, 6 opacity, 7-9 rgb,
 * 10 rotation index, 11-13 rotation smallest three, 14-16 motion_bwd,
 * 17-19 motion_fwd. Residual: the same, but 10-13 are w x y z residuals.
 * Quantizer k (0..15) serves channel k (k < 10) or k + 4 (motions). */
enum { CH_POS = 0, CH_LS = 3, CH_OP = 6, CH_RGB = 7, CH_ROT = 10, CH_MB = 14, CH_MF = 17 };
enum { QZ_MB = 10, QZ_MF = 13 };

static const struct codec_quality_info qtab[CODEC_QUALITY_COUNT] = {
    { "low",    12, 1.0e-3f,  1.0f / 8,   6,  6,  7, 1.0e-3f },
    { "medium", 16, 0.1e-3f,  1.0f / 32,  8,  8, 10, 0.1e-3f },
    { "high",   18, 0.02e-3f, 1.0f / 128, 10, 10, 12, 0.02e-3f },
    { "compact", 10, 2.0e-3f, 1.0f / 8,    5,  6,  6, 2.0e-3f },
};

static const float coef_v1[NCOEF] = { 1, 0, 1, 0, -1, 0, 0 };

const char *codec_channel_name(int ch)
{
    static const char *nm[NCH] = { "pos.x", "pos.y", "pos.z", "lscale.x", "lscale.y", "lscale.z", "opacity",
                                   "rgb.r", "rgb.g", "rgb.b", "rot.0", "rot.1", "rot.2", "rot.3",
                                   "mb.x", "mb.y", "mb.z", "mf.x", "mf.y", "mf.z" };
    return ch >= 0 && ch < NCH ? nm[ch] : NULL;
}

const struct codec_quality_info *codec_quality_get(enum codec_quality q)
{
    return (unsigned)q < CODEC_QUALITY_COUNT ? &qtab[q] : NULL;
}

int codec_quality_from_name(const char *name, struct f4d_err *err)
{
    for (int i = 0; i < CODEC_QUALITY_COUNT; i++)
        if (name && !strcmp(name, qtab[i].name))
            return i;
    return f4d_fail(err, F4D_EINVAL, "quality '%s' is not one of low, medium, high, compact", name ? name : "(null)");
}

/* ------------------------------------------------------------------------ */
/* Key state: what encoder and decoder both hold (the reconstruction). */

struct keystate {
    size_t count;
    int    motion;
    float *pos, *ls, *scale, *rot, *op, *rgb, *mb, *mf;
    struct splat_frame view;
};

static int key_alloc(struct keystate *k, size_t cap)
{
    size_t c = cap ? cap : 1;
    /* zeroed: the decoder's pred_tile reads row 0 of an empty reference */
    k->pos = calloc(3 * c, sizeof(float));
    k->ls = calloc(3 * c, sizeof(float));
    k->scale = calloc(3 * c, sizeof(float));
    k->rot = calloc(4 * c, sizeof(float));
    k->op = calloc(c, sizeof(float));
    k->rgb = calloc(3 * c, sizeof(float));
    k->mb = calloc(3 * c, sizeof(float));
    k->mf = calloc(3 * c, sizeof(float));
    k->count = 0;
    k->motion = 0;
    return (k->pos && k->ls && k->scale && k->rot && k->op && k->rgb && k->mb && k->mf) ? 0 : -1;
}

static void key_free(struct keystate *k)
{
    free(k->pos); free(k->ls); free(k->scale); free(k->rot);
    free(k->op); free(k->rgb); free(k->mb); free(k->mf);
    memset(k, 0, sizeof *k);
}

static const struct splat_frame *key_view(struct keystate *k)
{
    struct splat_frame *v = &k->view;
    v->count = k->count;
    v->capacity = k->count;
    v->pos = k->pos; v->scale = k->scale; v->rot = k->rot;
    v->opacity = k->op; v->rgb = k->rgb;
    v->motion_bwd = k->motion ? k->mb : NULL;
    v->motion_fwd = k->motion ? k->mf : NULL;
    return v;
}

/* ------------------------------------------------------------------------ */
/* Scalar quantization shared by encoder and decoder (same operations on both
 * sides, so the encoder's reconstruction is bit-identical to the decoder's). */

struct qz { float lo, step; };

static inline float deq(struct qz z, uint32_t q) { return z.lo + (float)q * z.step; }
static inline float dres(float p, struct qz z, int32_t r) { return p + (float)r * z.step; }
static inline uint32_t zig(int32_t v) { return ((uint32_t)v << 1) ^ (uint32_t)(v >> 31); }
static inline int32_t unzig(uint32_t u) { return (int32_t)(u >> 1) ^ -(int32_t)(u & 1); }

/* llround(t) for finite |t| < 2^31, inline: the truncation plus the
 * fraction's rounding (t - trunc(t) is exact; ties away from zero). */
static inline int32_t round_half_away(double t)
{
    int32_t k = (int32_t)t;
    double f = t - (double)k;
    return k + (f >= 0.5) - (f <= -0.5);
}

static inline uint32_t quant(struct qz z, float v)
{
    double t = ((double)v - (double)z.lo) / (double)z.step;
    if (!(t > 0))
        return 0;
    if (t > (double)QMAX)
        return QMAX;
    return (uint32_t)round_half_away(t);
}

static inline int32_t resid(struct qz z, float v, float p)
{
    double t = ((double)v - (double)p) / (double)z.step;
    /* dead zone a hair wider than half a step: a reference value decoded on
     * another frame's grid sits up to step/2 plus float rounding away */
    if (fabs(t) <= 0.5005)
        return 0;
    if (t > RMAX)
        return RMAX;
    if (t < -RMAX)
        return -RMAX;
    if (t != t) /* NaN: as llround gave it */
        return (int32_t)llround(t);
    return round_half_away(t);
}

static inline float clamp01(float v) { return v < 0.0f ? 0.0f : v > 1.0f ? 1.0f : v; }

/* Smallest three: index of the largest component (made positive) and the
 * other three scaled by sqrt(2) into [-1, 1], `bits` each. */
static void rot_pack(const float q_in[4], int bits, uint32_t out[4])
{
    float q[4], n = 0;
    for (int k = 0; k < 4; k++)
        n += q_in[k] * q_in[k];
    n = n > 1e-30f ? 1.0f / sqrtf(n) : 0.0f;
    for (int k = 0; k < 4; k++)
        q[k] = q_in[k] * n;
    if (n == 0.0f)
        q[0] = 1.0f;
    int big = 0;
    for (int k = 1; k < 4; k++)
        if (fabsf(q[k]) > fabsf(q[big]))
            big = k;
    float s = q[big] < 0 ? -1.0f : 1.0f;
    float m = (float)((1u << bits) - 1);
    out[0] = (uint32_t)big;
    for (int k = 0, j = 1; k < 4; k++) {
        if (k == big)
            continue;
        float v = s * q[k] * 1.41421356f;
        v = v < -1.0f ? -1.0f : v > 1.0f ? 1.0f : v;
        out[j++] = (uint32_t)lrintf((v + 1.0f) * 0.5f * m);
    }
}

static void rot_unpack(const uint32_t in[4], int bits, float q[4])
{
    float m = (float)((1u << bits) - 1), ss = 0;
    int big = (int)(in[0] & 3);
    for (int k = 0, j = 1; k < 4; k++) {
        if (k == big)
            continue;
        uint32_t u = in[j++];
        if (u > (uint32_t)m)
            u = (uint32_t)m;
        float v = ((float)u / m * 2.0f - 1.0f) * 0.70710678f;
        q[k] = v;
        ss += v * v;
    }
    q[big] = sqrtf(ss < 1.0f ? 1.0f - ss : 0.0f);
}

static inline float rot_step(int bits) { return 1.41421356f / (float)((1u << bits) - 1); }

/* ------------------------------------------------------------------------ */
/* Morton order of the changed Gaussians (predicted keys). Their residual
 * planes are coded in the order of the Morton codes of their predicted
 * positions, which the decoder knows before reading them: neighbours in
 * space share their motion change (rigid parts, smooth surfaces), so the
 * signed deltas along that order are small, whatever order the producer
 * numbered its Gaussians in. No side information is sent. */
struct morton { uint64_t *key, *key2; uint32_t *perm, *perm2, *tmp; };

static int morton_alloc(struct morton *m, size_t c)
{
    m->key = malloc(c * sizeof(uint64_t));
    m->key2 = malloc(c * sizeof(uint64_t));
    m->perm = malloc(c * sizeof(uint32_t));
    m->perm2 = malloc(c * sizeof(uint32_t));
    m->tmp = malloc(c * sizeof(uint32_t));
    return m->key && m->key2 && m->perm && m->perm2 && m->tmp ? 0 : -1;
}

static void morton_free(struct morton *m)
{
    free(m->key); free(m->key2); free(m->perm); free(m->perm2); free(m->tmp);
}

/* The low 21 bits of v spread to every third bit, 7 bits at a time from a
 * table (a third of the shift-and-mask version's operations; same values). */
static const uint64_t spread7[128] = {
#define S7(v) ((uint64_t)((v) & 1) | (uint64_t)((v) >> 1 & 1) << 3 | (uint64_t)((v) >> 2 & 1) << 6 | \
               (uint64_t)((v) >> 3 & 1) << 9 | (uint64_t)((v) >> 4 & 1) << 12 | (uint64_t)((v) >> 5 & 1) << 15 | \
               (uint64_t)((v) >> 6 & 1) << 18)
#define S7x8(v) S7(v), S7(v + 1), S7(v + 2), S7(v + 3), S7(v + 4), S7(v + 5), S7(v + 6), S7(v + 7)
    S7x8(0), S7x8(8), S7x8(16), S7x8(24), S7x8(32), S7x8(40), S7x8(48), S7x8(56),
    S7x8(64), S7x8(72), S7x8(80), S7x8(88), S7x8(96), S7x8(104), S7x8(112), S7x8(120),
#undef S7x8
#undef S7
};

static inline uint64_t spread21(uint32_t v)
{
    return spread7[v & 127] | spread7[v >> 7 & 127] << 21 | spread7[v >> 14 & 127] << 42;
}

/* Key of a predicted position on the frame's position grid (21 bits a side). */
static uint64_t morton_key(const struct qz *z, const float pos[3])
{
    uint64_t k = 0;
    for (int c = 0; c < 3; c++) {
        double t = ((double)pos[c] - (double)z[c].lo) / (double)z[c].step;
        uint32_t q = !(t > 0) ? 0 : t >= (double)QMAX ? QMAX : (uint32_t)t;
        k |= spread21(q >> 3) << c;
    }
    return k;
}

/* morton_key's values with a multiply by the step's reciprocal instead of a
 * divide (the decoder's keys): the product is within 2^-52 of the quotient
 * morton_key rounds, so where both ends of a 2^-48 bracket around it give
 * the same cell, that is morton_key's cell; else morton_key's divide. */
struct mgrid { double lo[3], step[3], inv[3]; };

static void mgrid_of(const struct qz *z, struct mgrid *g)
{
    for (int c = 0; c < 3; c++) {
        g->lo[c] = (double)z[c].lo;
        g->step[c] = (double)z[c].step;
        g->inv[c] = 1.0 / g->step[c];
    }
}

static inline uint32_t mcell(double t)
{
    /* 0 < t < QMAX: truncation through int32 is (uint32_t)t's, and short */
    uint32_t q = !(t > 0) ? 0 : t >= (double)QMAX ? QMAX : (uint32_t)(int32_t)t;
    return q >> 3;
}

static inline uint64_t morton_key_grid(const struct mgrid *g, const float pos[3])
{
    uint64_t k = 0;
    for (int c = 0; c < 3; c++) {
        const double num = (double)pos[c] - g->lo[c], a = num * g->inv[c];
        uint32_t q = mcell(a * (1.0 - 0x1p-48));
        if (q != mcell(a * (1.0 + 0x1p-48)))
            q = mcell(num / g->step[c]);
        k |= spread21(q) << c;
    }
    return k;
}

/* Stable LSD radix sort of key[0..n) carrying perm[0..n) (the caller's
 * values: morton_sort's 0..n-1 make perm the order). 11-bit digits over the
 * 63 key bits: 6 passes instead of 8 bytes' (a stable sort's order does not
 * depend on the digit width), all 6 counted in one read of the keys; a
 * digit that is the same everywhere is skipped. */
#define MORTON_DIGIT 11
#define MORTON_PASSES 6
static void morton_sort_with(struct morton *m, size_t n)
{
    if (n == 0)
        return;
    enum { R = 1 << MORTON_DIGIT };
    _Static_assert(MORTON_DIGIT * MORTON_PASSES >= 63, "the digits cover the key");
    uint32_t cnt[MORTON_PASSES][R];
    memset(cnt, 0, sizeof cnt);
    uint64_t *k = m->key, *k2 = m->key2;
    uint32_t *p = m->perm, *p2 = m->perm2;
    for (size_t i = 0; i < n; i++)
        for (int d = 0; d < MORTON_PASSES; d++)
            cnt[d][(k[i] >> (d * MORTON_DIGIT)) & (R - 1)]++;
    for (int d = 0; d < MORTON_PASSES; d++) {
        const int sh = d * MORTON_DIGIT;
        uint32_t *c = cnt[d];
        if (c[(k[0] >> sh) & (R - 1)] == n)
            continue; /* this digit is the same everywhere */
        uint32_t s = 0;
        for (int b = 0; b < R; b++) {
            uint32_t t = c[b];
            c[b] = s;
            s += t;
        }
        for (size_t i = 0; i < n; i++) {
            uint32_t o = c[(k[i] >> sh) & (R - 1)]++;
            k2[o] = k[i];
            p2[o] = p[i];
        }
        uint64_t *tk = k; k = k2; k2 = tk;
        uint32_t *tp = p; p = p2; p2 = tp;
    }
    if (p != m->perm)
        memcpy(m->perm, p, n * sizeof(uint32_t));
    if (k != m->key)
        memcpy(m->key, k, n * sizeof(uint64_t));
}

static void morton_sort(struct morton *m, size_t n)
{
    for (size_t i = 0; i < n; i++)
        m->perm[i] = (uint32_t)i;
    morton_sort_with(m, n);
}

/* ------------------------------------------------------------------------ */
/* Planes. */

struct planebuf {
    uint8_t  *shuf;   /* [4 * cap] */
    uint32_t *tmp;    /* [cap]     */
    uint32_t *tmp3;   /* [cap] transform 3, kept beside 2 while plane_pick sizes both */
    uint32_t *samp;   /* [cap] the part of a plane its candidates are sized on */
    uint8_t  *zalt;   /* [zbound]  */
    uint8_t  *zbest;  /* [zbound] the smallest candidate plane_pick compressed */
    uint8_t  *zkeep;  /* [zbound] a first order's, while the second is tried */
    int       best_tag; /* zbest's tag byte                                   */
    size_t    zbound;
};

static int width_of(uint32_t mx) { return mx < 0x100u ? 1 : mx < 0x10000u ? 2 : mx < 0x1000000u ? 3 : 4; }

static void shuffle(const uint32_t *v, size_t n, int w, uint8_t *o)
{
    for (int b = 0; b < w; b++)
        for (size_t i = 0; i < n; i++)
            o[(size_t)b * n + i] = (uint8_t)(v[i] >> (8 * b));
}

/* Version 3: a plane whose values all fit in 1, 2 or 4 bits is packed 8, 4
 * or 2 to a byte (width codes 5, 6, 7), first value in the low bits. zstd's
 * literals are Huffman-coded per byte, at least a bit each: a residual
 * plane of mostly 0 and +-1 costs over a bit per Gaussian as bytes, about
 * its entropy packed. */
static int pack_bits_of(int wcode) { return wcode == 5 ? 1 : wcode == 6 ? 2 : 4; }
static size_t packed_bytes(size_t n, int bits) { return (n * (size_t)bits + 7) / 8; }

/* bits is a constant in each caller below, so the inner loop unrolls. */
static inline void pack_n(const uint32_t *v, size_t n, const int bits, uint8_t *o)
{
    const size_t per = (size_t)(8 / bits), full = n / per;
    for (size_t j = 0; j < full; j++) {
        uint32_t b = 0;
        for (size_t k = 0; k < per; k++)
            b |= v[j * per + k] << (bits * (int)k);
        o[j] = (uint8_t)b;
    }
    if (full * per < n) {
        uint32_t b = 0;
        for (size_t i = full * per; i < n; i++)
            b |= v[i] << (bits * (int)(i - full * per));
        o[full] = (uint8_t)b;
    }
}

static void pack(const uint32_t *v, size_t n, int bits, uint8_t *o)
{
    if (bits == 1)
        pack_n(v, n, 1, o);
    else if (bits == 2)
        pack_n(v, n, 2, o);
    else
        pack_n(v, n, 4, o);
}

/* Median of three: the version 3 predictor of a residual from the three
 * before it in the plane's order. Neighbours in Morton order share their
 * motion change; each also carries its own quantization noise (+-1), which
 * a single neighbour's delta doubles and the median of three mostly drops. */
static inline int32_t med3(int32_t a, int32_t b, int32_t c)
{
    /* c clamped to [lo, hi], as min and max (vectorizes) */
    int32_t lo = a < b ? a : b, hi = a < b ? b : a;
    int32_t m = c < hi ? c : hi;
    return m > lo ? m : lo;
}

#define BLK      64
#define NBP      15
#define BPAR_MAX (1 << 22)

struct blocks {
    uint32_t *id;   /* [cap] block of each matched Gaussian         */
    uint32_t *par;  /* [NBP * nbmax] zigzagged parameters           */
    float    *org;  /* [3 * nbmax] block origins                    */
    uint32_t *wire; /* [3 * nbmax] t as sent (encoder)              */
    size_t    nb, nbmax;
    float     ut[3], um[3], uq; /* units of t, M (rows), dq       */
};

static int blocks_alloc(struct blocks *b, size_t c)
{
    b->nbmax = c / BLK + 1;
    b->id = malloc(c * sizeof(uint32_t));
    b->par = malloc(NBP * b->nbmax * sizeof(uint32_t));
    b->org = calloc(3 * b->nbmax, sizeof(float)); /* read (unused) for new Gaussians by pred_tile */
    b->wire = malloc(3 * b->nbmax * sizeof(uint32_t));
    b->nb = 0;
    return b->id && b->par && b->org && b->wire ? 0 : -1;
}

static void blocks_free(struct blocks *b) { free(b->id); free(b->par); free(b->org); free(b->wire); }

struct codec_enc {
    size_t cap;
    enum codec_quality q;
    struct f4d_err err;
    struct keystate key[2];
    int cur, have_ref;
    uint32_t seq, ref_seq;
    uint32_t *rec;     /* [NCH * cap] intra records (column-major) */
    uint32_t *res;     /* [NCH * cap] residual records             */
    uint32_t *idx;     /* [cap] reference-index deltas             */
    uint32_t *flags;   /* [cap]                                    */
    float *lsc;        /* [3 * cap] log scales of the key being coded (logf once) */
    struct morton mo;  /* order of the changed Gaussians' residuals */
    struct blocks bk;  /* block motion (version 3)                  */
    int32_t *rix;      /* [cap] reference index of each Gaussian     */
    double *bacc;      /* [nbmax * 32] block fit sums                */
    uint8_t *est;      /* [est_cap] planes coded to measure a choice  */
    size_t est_cap;
    int last_still;    /* mo.perm holds a still key's order           */
    int ver;           /* codec version written (2 or 3)             */
    int effort, zest, zfin; /* zstd levels of the candidates, of the planes written */
    size_t zws_size;
    /* stream order (codec_enc_set_reorder): key slot k's decoded Gaussian
     * j is input Gaussian ord[k][j] */
    int reorder;
    uint32_t *ord[2];  /* [cap] per key slot                          */
    uint32_t *inv;     /* [cap] reference input index -> slot         */
    int32_t *slot;     /* [cap] reference slot of each input Gaussian  */
    int32_t *pmatch;   /* [cap] the match in stream order             */
    struct splat_frame pf; /* the input in stream order               */
    struct planebuf pb;
    void *zws;
    ZSTD_CCtx *z;
    struct codec_enc_stats st;
};

/* The transform t of plane v[0..n) into d: 1 delta of the values, 2
 * delta of the zigzagged signed values, 3 their median-of-three
 * prediction. Returns the largest transformed value. Each output reads the
 * inputs before it, not a carried state, so the loops vectorize (v is
 * never d). */
static uint32_t plane_delta(const uint32_t *restrict v, size_t n, int t, uint32_t *restrict d)
{
    uint32_t dm = 0;
    if (n == 0)
        return 0;
    if (t == 1) {
        d[0] = zig((int32_t)v[0]);
        for (size_t i = 1; i < n; i++)
            d[i] = zig((int32_t)(v[i] - v[i - 1]));
    } else if (t == 2) {
        d[0] = v[0]; /* zig(unzig(v) - 0) */
        for (size_t i = 1; i < n; i++)
            d[i] = zig((int32_t)((uint32_t)unzig(v[i]) - (uint32_t)unzig(v[i - 1])));
    } else {
        int32_t a = 0, b = 0, c = 0; /* the three signed values before i */
        size_t i = 0;
        for (; i < n && i < 3; i++) {
            int32_t x = unzig(v[i]);
            d[i] = zig((int32_t)((uint32_t)x - (uint32_t)med3(a, b, c)));
            c = b;
            b = a;
            a = x;
        }
        for (; i < n; i++) {
            int32_t x = unzig(v[i]);
            d[i] = zig((int32_t)((uint32_t)x - (uint32_t)med3(unzig(v[i - 1]), unzig(v[i - 2]), unzig(v[i - 3]))));
        }
    }
    for (size_t i = 0; i < n; i++)
        dm |= d[i]; /* as plane_max: the OR */
    return dm;
}

/* Serializes v[0..n) (max mx) into pb.shuf as bytes (form 0, shuffled) or,
 * when it fits in 4 bits, packed (form 1, version 3); returns the byte count
 * and the width code, or 0 where the form does not apply. */
static size_t plane_bytes(codec_enc *e, const uint32_t *v, size_t n, uint32_t mx, int form, int *wcode)
{
    if (form == 0) {
        *wcode = width_of(mx);
        shuffle(v, n, *wcode, e->pb.shuf);
        return n * (size_t)*wcode;
    }
    if (mx >= 16 || e->ver < 3)
        return 0;
    *wcode = mx < 2 ? 5 : mx < 4 ? 6 : 7;
    pack(v, n, pack_bits_of(*wcode), e->pb.shuf);
    return packed_bytes(n, pack_bits_of(*wcode));
}

/* Picks the form of a non-empty plane (max mx) put_plane keeps: the smallest
 * of raw, delta (allow_delta 1: of the values; 2: of the zigzagged signed
 * values, and the median-of-three prediction), each as bytes or packed.
 * Candidates are compressed at ZLEVEL; *est is the smallest, kept in
 * pb.zbest (tag pb.best_tag), SIZE_MAX when there was only one candidate
 * (not compressed). */
/* Stands for the largest value: the OR of the values, which has the
 * largest one's bit length, and every test of it (width_of, packing, < 16)
 * is against a power of two; the OR reduces at one cycle a step where an
 * unsigned max (SSE2) is a dependent chain of five. */
static uint32_t plane_max(const uint32_t *v, size_t n)
{
    uint32_t mx = 0;
    for (size_t i = 0; i < n; i++)
        mx |= v[i];
    return mx;
}

/* Order-0 entropy of v[0..n) in bits (values over 254 share a bucket and
 * add their bit length): a cheap proxy of a transform's zstd size. */
static double plane_bits(const uint32_t *v, size_t n)
{
    /* four histograms: runs of one value (zeros) would otherwise wait on
     * the previous increment of the same counter */
    uint32_t h4[4][256] = { { 0 } }, h[256];
    uint64_t extra = 0;
    size_t i = 0;
    for (; i + 4 <= n; i += 4)
        for (int k = 0; k < 4; k++) {
            uint32_t x = v[i + k];
            h4[k][x < 255 ? x : 255]++;
            extra += x < 255 ? 0 : (uint64_t)(32 - __builtin_clz(x));
        }
    for (; i < n; i++) {
        uint32_t x = v[i];
        h4[0][x < 255 ? x : 255]++;
        extra += x < 255 ? 0 : (uint64_t)(32 - __builtin_clz(x));
    }
    for (int b = 0; b < 256; b++)
        h[b] = h4[0][b] + h4[1][b] + h4[2][b] + h4[3][b];
    double bits = (double)extra;
    for (int b = 0; b < 256; b++)
        if (h[b])
            bits -= (double)h[b] * log2((double)h[b] / (double)n);
    return bits;
}

/* On residual planes (allow_delta 2: small signed values) a transform
 * whose proxy exceeds the best one's by this much is not compressed (the
 * walk at 37.6k / 300k: +0.1-1 % bytes). Not on intra planes: their wide
 * values' low bytes look random to the proxy, not to zstd (Morton order). */
#define PROXY_SLACK 1.25

static void plane_pick(codec_enc *e, const uint32_t *v, size_t n, uint32_t mx, int allow_delta, int *best_t,
                       int *best_form, size_t *est)
{
    int cand = 1 + (mx < 16 && e->ver >= 3);
    if (allow_delta)
        cand += 2 * (allow_delta == 1 ? 1 : e->ver < 3 ? 1 : 2);
    *best_t = 0;
    *best_form = 0;
    *est = SIZE_MAX;
    if (cand == 1)
        return;
    double proxy[4] = { INFINITY, INFINITY, INFINITY, INFINITY }, pbest = INFINITY;
    /* each transform computed once, kept for its compression (1 and 2 are
     * never both candidates) */
    uint32_t *dt[4] = { NULL, e->pb.tmp, e->pb.tmp, e->pb.tmp3 }, dmax[4] = { mx, 0, 0, 0 };
    for (int t = 0; t <= 3; t++) {
        if (t && (!allow_delta || (t == 1) != (allow_delta == 1) || (t == 3 && e->ver < 3)))
            continue;
        if (t)
            dmax[t] = plane_delta(v, n, t, dt[t]);
        proxy[t] = allow_delta == 2 ? plane_bits(t ? dt[t] : v, n) : 0.0;
        pbest = proxy[t] < pbest ? proxy[t] : pbest;
    }
    int sized2 = 0;
    for (int t = 0; t <= 3; t++) {
        if (proxy[t] == INFINITY || (allow_delta == 2 && proxy[t] > PROXY_SLACK * pbest + 512.0))
            continue;
        /* As the streams have been written: where transform 2 was sized,
         * transform 3 was sized on 2's values again (one buffer), which is
         * never smaller, so 3 is not tried then (kept for identical bytes;
         * sizing 3 for real is a separate change: it alters streams). */
        if (t == 3 && sized2)
            continue;
        sized2 |= t == 2;
        const uint32_t *src = t ? dt[t] : v;
        uint32_t m = dmax[t];
        for (int form = 0; form < 2; form++) {
            int wcode;
            size_t nb = plane_bytes(e, src, n, m, form, &wcode);
            if (!nb)
                break;
            size_t z = ZSTD_compressCCtx(e->z, e->pb.zalt, e->pb.zbound, e->pb.shuf, nb, e->zest);
            if (!ZSTD_isError(z) && z < *est) {
                uint8_t *sw = e->pb.zbest;
                e->pb.zbest = e->pb.zalt;
                e->pb.zalt = sw;
                e->pb.best_tag = t | wcode << 4;
                *est = z;
                *best_t = t;
                *best_form = form;
            }
        }
    }
}

/* Candidates are sized on a sample of a long plane: every k-th run of
 * EST_RUN values, k = n / EST_TARGET (at most EST_KMAX), copied (through
 * perm when given) to pb.samp. Runs keep the neighbours the delta forms and
 * zstd's matches see; sizes scale to the whole plane. */
#define EST_RUN    1024
#define EST_TARGET 32768
#define EST_KMAX   8

static size_t plane_sample(codec_enc *e, const uint32_t *v, const uint32_t *perm, size_t n, const uint32_t **out)
{
    size_t k = n / EST_TARGET, ns = 0;
    k = k < 1 ? 1 : k > EST_KMAX ? EST_KMAX : k;
    if (k == 1 && !perm) {
        *out = v;
        return n;
    }
    for (size_t c0 = 0; c0 < n; c0 += k * EST_RUN) {
        size_t c1 = c0 + EST_RUN < n ? c0 + EST_RUN : n;
        if (perm)
            for (size_t i = c0; i < c1; i++)
                e->pb.samp[ns++] = v[perm[i]];
        else
            for (size_t i = c0; i < c1; i++)
                e->pb.samp[ns++] = v[i];
    }
    *out = e->pb.samp;
    return ns;
}

/* Picks the form of plane v[0..n) (read through perm when given) as
 * plane_pick does, on its sample; returns the bytes put_plane would take
 * for the whole plane (estimated: what the encoder's choices compare). */
static double plane_choose(codec_enc *e, const uint32_t *v, const uint32_t *perm, size_t n, int allow_delta, int *t,
                           int *form, size_t *exact)
{
    *t = *form = 0;
    *exact = 0;
    if (n == 0)
        return 5.0;
    const uint32_t *sv;
    size_t ns = plane_sample(e, v, perm, n, &sv), est;
    plane_pick(e, sv, ns, plane_max(sv, ns), allow_delta, t, form, &est);
    if (est == SIZE_MAX) /* one candidate (allow_delta 0, put_plane only): nothing compared */
        return INFINITY;
    if (ns == n) /* the whole plane: pb.zbest is what put_plane writes */
        *exact = est;
    return 5.0 + (double)est * (double)n / (double)ns;
}

static double plane_est(codec_enc *e, const uint32_t *v, const uint32_t *perm, size_t n, int allow_delta)
{
    int t, form;
    size_t exact;
    return plane_choose(e, v, perm, n, allow_delta, &t, &form, &exact);
}

/* Writes a plane plane_pick already compressed (z[0..zn), tag byte). */
static int put_plane_z(codec_enc *e, int tag, const uint8_t *z, size_t zn, uint8_t *out, size_t cap, size_t *off)
{
    if (cap < *off + 5 || cap - *off - 5 < zn)
        return f4d_fail(&e->err, F4D_ERANGE, "encode: output buffer too small for a plane of %zu bytes", zn);
    out[*off] = (uint8_t)tag;
    codec__put_u32(out + *off + 1, (uint32_t)zn);
    memcpy(out + *off + 5, z, zn);
    *off += 5 + zn;
    return F4D_OK;
}

/* Writes one non-empty plane (max mx) at out[*off] in the form plane_pick
 * chose (t, form): tag, compressed length, zstd bytes at ZLEVEL. */
static int put_plane_as(codec_enc *e, const uint32_t *v, size_t n, uint32_t mx, int t, int form, uint8_t *out,
                        size_t cap, size_t *off)
{
    if (cap < *off + 5)
        return f4d_fail(&e->err, F4D_ERANGE, "encode: output buffer too small");
    uint8_t *tag = out + *off;
    if (t) {
        mx = plane_delta(v, n, t, e->pb.tmp);
        v = e->pb.tmp;
    }
    int wcode;
    size_t nb = plane_bytes(e, v, n, mx, form, &wcode);
    if (!nb) /* packed on a sample whose values fit, the plane's do not */
        nb = plane_bytes(e, v, n, mx, 0, &wcode);
    size_t z = ZSTD_compressCCtx(e->z, tag + 5, cap - *off - 5, e->pb.shuf, nb, e->zfin);
    if (ZSTD_isError(z))
        return f4d_fail(&e->err, F4D_ERANGE, "encode: output buffer too small for a plane of %zu values", n);
    tag[0] = (uint8_t)(t | wcode << 4);
    codec__put_u32(tag + 1, (uint32_t)z);
    *off += 5 + z;
    return F4D_OK;
}

/* Writes one plane at out[*off]: tag, compressed length, zstd bytes; keeps
 * the smallest form (plane_pick). */
static int put_plane(codec_enc *e, const uint32_t *v, size_t n, int allow_delta, uint8_t *out, size_t cap,
                     size_t *off)
{
    if (n == 0) {
        if (cap < *off + 5)
            return f4d_fail(&e->err, F4D_ERANGE, "encode: output buffer too small");
        out[*off] = 1 << 4;
        codec__put_u32(out + *off + 1, 0);
        *off += 5;
        return F4D_OK;
    }
    int t, form;
    size_t exact;
    plane_choose(e, v, NULL, n, allow_delta, &t, &form, &exact);
    if (exact && e->zfin == e->zest)
        return put_plane_z(e, e->pb.best_tag, e->pb.zbest, exact, out, cap, off);
    return put_plane_as(e, v, n, plane_max(v, n), t, form, out, cap, off);
}

/* ------------------------------------------------------------------------ */
/* Encoder. */

int codec_enc_new(size_t capacity, enum codec_quality q, codec_enc **out, struct f4d_err *err)
{
    if (!out)
        return f4d_fail(err, F4D_EINVAL, "codec_enc_new: out is NULL");
    *out = NULL;
    if ((unsigned)q >= CODEC_QUALITY_COUNT)
        return f4d_fail(err, F4D_EINVAL, "codec_enc_new: quality %d out of range", (int)q);
    if (capacity > CODEC_CAPACITY_MAX)
        return f4d_fail(err, F4D_ERANGE, "codec_enc_new: capacity %zu exceeds %zu Gaussians", capacity,
                        CODEC_CAPACITY_MAX);
    codec_enc *e = calloc(1, sizeof *e);
    if (!e)
        return f4d_fail(err, F4D_ENOMEM, "codec_enc_new: out of memory");
    size_t c = capacity ? capacity : 1;
    e->cap = capacity;
    e->q = q;
    e->ver = CODEC_VERSION;
    e->rec = malloc(NCH * c * sizeof(uint32_t));
    e->res = malloc(NCH * c * sizeof(uint32_t));
    e->idx = malloc(c * sizeof(uint32_t));
    e->flags = malloc(c * sizeof(uint32_t));
    e->lsc = malloc(3 * c * sizeof(float));
    e->pb.shuf = malloc(4 * c);
    e->pb.tmp = malloc(c * sizeof(uint32_t));
    e->pb.tmp3 = malloc(c * sizeof(uint32_t));
    e->pb.samp = malloc(c * sizeof(uint32_t));
    e->pb.zbound = ZSTD_compressBound(4 * c);
    e->pb.zalt = malloc(e->pb.zbound);
    e->pb.zbest = malloc(e->pb.zbound);
    e->pb.zkeep = malloc(e->pb.zbound);
    e->est_cap = e->pb.zbound + 5;
    e->est = malloc(e->est_cap);
    size_t zsz = ZSTD_estimateCCtxSize(ZLEVEL);
    e->zws = malloc(zsz);
    e->zws_size = zsz;
    e->effort = CODEC_EFFORT_DEFAULT;
    e->zest = e->zfin = ZLEVEL;
    int bad = !e->est || !e->rec || !e->res || !e->idx || !e->flags || !e->lsc || !e->pb.shuf || !e->pb.tmp || !e->pb.tmp3 || !e->pb.samp || !e->pb.zalt || !e->pb.zbest || !e->pb.zkeep || !e->zws ||
              morton_alloc(&e->mo, c) || blocks_alloc(&e->bk, c) ||
              !(e->rix = malloc(c * sizeof(int32_t))) || !(e->bacc = malloc((c / BLK + 1) * 32 * sizeof(double))) ||
              key_alloc(&e->key[0], capacity) || key_alloc(&e->key[1], capacity);
    if (!bad)
        e->z = ZSTD_initStaticCCtx(e->zws, zsz);
    if (bad || !e->z) {
        codec_enc_free(e);
        return f4d_fail(err, F4D_ENOMEM, "codec_enc_new: out of memory for %zu Gaussians", capacity);
    }
    *out = e;
    return F4D_OK;
}

void codec_enc_free(codec_enc *e)
{
    if (!e)
        return;
    free(e->rec); free(e->res); free(e->idx); free(e->flags); free(e->lsc);
    morton_free(&e->mo);
    blocks_free(&e->bk);
    free(e->rix); free(e->bacc); free(e->est);
    free(e->ord[0]); free(e->ord[1]); free(e->inv); free(e->slot); free(e->pmatch);
    free(e->pf.pos); free(e->pf.scale); free(e->pf.rot); free(e->pf.opacity); free(e->pf.rgb);
    free(e->pf.motion_bwd); free(e->pf.motion_fwd);
    free(e->pb.shuf); free(e->pb.tmp); free(e->pb.tmp3); free(e->pb.samp); free(e->pb.zalt); free(e->pb.zbest); free(e->pb.zkeep); free(e->zws);
    key_free(&e->key[0]);
    key_free(&e->key[1]);
    free(e);
}

const char *codec_enc_error(const codec_enc *e) { return e ? e->err.msg : "codec_enc is NULL"; }
const struct splat_frame *codec_enc_recon(const codec_enc *e)
{
    return e ? key_view((struct keystate *)&e->key[e->cur]) : NULL;
}
const struct codec_enc_stats *codec_enc_last(const codec_enc *e) { return e ? &e->st : NULL; }
const uint32_t *codec_enc_order(const codec_enc *e)
{
    return !e ? NULL : e->last_still ? e->mo.perm : e->reorder && e->have_ref ? e->ord[e->cur] : NULL;
}

int codec_effort_from_name(const char *name, struct f4d_err *err)
{
    static const char *nm[3] = { "fast", "default", "max" };
    for (int i = 0; i < 3; i++)
        if (name && !strcmp(name, nm[i]))
            return i;
    return f4d_fail(err, F4D_EINVAL, "effort '%s' is not one of fast, default, max", name ? name : "(null)");
}

int codec_enc_set_effort(codec_enc *e, int effort)
{
    if (!e)
        return F4D_EINVAL;
    if (effort < CODEC_EFFORT_FAST || effort > CODEC_EFFORT_MAX)
        return f4d_fail(&e->err, F4D_EINVAL, "codec_enc_set_effort: %d is not %d..%d", effort, CODEC_EFFORT_FAST,
                        CODEC_EFFORT_MAX);
    int zfin = effort == CODEC_EFFORT_FAST ? ZLEVEL_FAST : effort == CODEC_EFFORT_MAX ? ZLEVEL_MAX : ZLEVEL;
    /* the workspace of the highest level used, for planes up to 4 bytes a Gaussian */
    size_t src = 4 * (e->cap ? e->cap : 1);
    size_t zsz = ZSTD_estimateCCtxSize_usingCParams(ZSTD_getCParams(zfin, src, 0));
    size_t z5 = ZSTD_estimateCCtxSize(ZLEVEL);
    zsz = zsz > z5 ? zsz : z5;
    if (zsz > e->zws_size) {
        void *ws = malloc(zsz);
        ZSTD_CCtx *z = ws ? ZSTD_initStaticCCtx(ws, zsz) : NULL;
        if (!z) {
            free(ws);
            return f4d_fail(&e->err, F4D_ENOMEM, "codec_enc_set_effort: out of memory for zstd level %d", zfin);
        }
        free(e->zws);
        e->zws = ws;
        e->zws_size = zsz;
        e->z = z;
    }
    e->effort = effort;
    e->zest = effort == CODEC_EFFORT_FAST ? ZLEVEL_FAST : ZLEVEL;
    e->zfin = zfin;
    return F4D_OK;
}

int codec_enc_set_reorder(codec_enc *e, int on)
{
    if (!e)
        return F4D_EINVAL;
    if (on && !e->ord[0]) {
        size_t c = e->cap ? e->cap : 1;
        e->ord[0] = malloc(c * sizeof(uint32_t));
        e->ord[1] = malloc(c * sizeof(uint32_t));
        e->inv = malloc(c * sizeof(uint32_t));
        e->slot = malloc(c * sizeof(int32_t));
        e->pmatch = malloc(c * sizeof(int32_t));
        e->pf.pos = malloc(3 * c * sizeof(float));
        e->pf.scale = malloc(3 * c * sizeof(float));
        e->pf.rot = malloc(4 * c * sizeof(float));
        e->pf.opacity = malloc(c * sizeof(float));
        e->pf.rgb = malloc(3 * c * sizeof(float));
        e->pf.motion_bwd = malloc(3 * c * sizeof(float));
        e->pf.motion_fwd = malloc(3 * c * sizeof(float));
        if (!e->ord[0] || !e->ord[1] || !e->inv || !e->slot || !e->pmatch || !e->pf.pos || !e->pf.scale ||
            !e->pf.rot || !e->pf.opacity || !e->pf.rgb || !e->pf.motion_bwd || !e->pf.motion_fwd) {
            free(e->ord[0]); free(e->ord[1]); free(e->inv); free(e->slot); free(e->pmatch);
            free(e->pf.pos); free(e->pf.scale); free(e->pf.rot); free(e->pf.opacity); free(e->pf.rgb);
            free(e->pf.motion_bwd); free(e->pf.motion_fwd);
            e->ord[0] = e->ord[1] = e->inv = NULL;
            e->slot = e->pmatch = NULL;
            memset(&e->pf, 0, sizeof e->pf);
            return f4d_fail(&e->err, F4D_ENOMEM, "codec_enc_set_reorder: out of memory for %zu Gaussians", e->cap);
        }
        e->pf.capacity = e->cap;
    }
    if (!on != !e->reorder)
        e->have_ref = 0; /* the reference's order is the other one's: the next key is intra */
    e->reorder = !!on;
    return F4D_OK;
}

/* Stream order of a predicted key: the input Gaussians sorted (stably) by
 * the reference slot they continue, new ones after them in input order, so
 * that a take whose Gaussians keep their index keeps the identity match.
 * Fills e->ord[slot k], e->pf (the input in that order) and returns the
 * match in stream order (NULL: identity). */
static const int32_t *stream_order(codec_enc *e, const struct splat_frame *f, const int32_t *match,
                                   const uint32_t *ord_ref, size_t nref, uint32_t *ord)
{
    const size_t n = f->count;
    uint32_t *cnt = e->mo.tmp; /* [nref]: free until the key's residuals */
    for (size_t s = 0; s < nref; s++)
        e->inv[ord_ref[s]] = (uint32_t)s;
    memset(cnt, 0, nref * sizeof(uint32_t));
    for (size_t i = 0; i < n; i++) {
        int32_t m = match ? match[i] : (i < nref ? (int32_t)i : -1);
        e->slot[i] = m >= 0 ? (int32_t)e->inv[m] : -1;
        if (m >= 0)
            cnt[e->slot[i]]++;
    }
    uint32_t sum = 0;
    for (size_t s = 0; s < nref; s++) {
        uint32_t t = cnt[s];
        cnt[s] = sum;
        sum += t;
    }
    size_t nx = sum;
    for (size_t i = 0; i < n; i++)
        ord[e->slot[i] >= 0 ? cnt[e->slot[i]]++ : nx++] = (uint32_t)i;
    int ident = sum == nref; /* every reference slot continued once, new ones last */
    for (size_t j = 0; j < n; j++) {
        uint32_t i = ord[j];
        e->pmatch[j] = e->slot[i];
        ident &= j < sum ? e->slot[i] == (int32_t)j : 1;
        memcpy(e->pf.pos + 3 * j, f->pos + 3 * (size_t)i, 3 * sizeof(float));
        memcpy(e->pf.scale + 3 * j, f->scale + 3 * (size_t)i, 3 * sizeof(float));
        memcpy(e->pf.rot + 4 * j, f->rot + 4 * (size_t)i, 4 * sizeof(float));
        e->pf.opacity[j] = f->opacity[i];
        memcpy(e->pf.rgb + 3 * j, f->rgb + 3 * (size_t)i, 3 * sizeof(float));
        if (f->motion_bwd && f->motion_fwd) {
            memcpy(e->pf.motion_bwd + 3 * j, f->motion_bwd + 3 * (size_t)i, 3 * sizeof(float));
            memcpy(e->pf.motion_fwd + 3 * j, f->motion_fwd + 3 * (size_t)i, 3 * sizeof(float));
        }
    }
    return ident ? NULL : e->pmatch;
}

int codec_enc_set_version(codec_enc *e, int version)
{
    if (!e)
        return F4D_EINVAL;
    if (version < 2 || version > CODEC_VERSION)
        return f4d_fail(&e->err, F4D_EINVAL, "codec_enc_set_version: %d is not 2..%d", version, CODEC_VERSION);
    e->ver = version;
    return F4D_OK;
}

/* An older version's packet: its number in the header, the CRC again. */
static void stamp_version(const codec_enc *e, uint8_t *out, size_t len)
{
    if (e->ver == CODEC_VERSION)
        return;
    out[4] = (uint8_t)e->ver;
    codec__put_u32(out + 28, codec__packet_crc(out, out + CODEC_PACKET_HEADER, len - CODEC_PACKET_HEADER));
}

int codec_enc_stream_header(codec_enc *e, uint64_t t_us, uint8_t *out, size_t cap, size_t *len)
{
    uint8_t pl[12];
    codec__put_u32(pl, (uint32_t)e->ver);
    codec__put_u32(pl + 4, (uint32_t)e->q);
    codec__put_u32(pl + 8, (uint32_t)e->cap);
    uint32_t s = e->seq;
    int rc = codec_packet_write(out, cap, CODEC_PKT_STREAM, s, s, t_us, pl, sizeof pl, len, &e->err);
    if (rc == 0) {
        stamp_version(e, out, *len);
        e->seq++;
    }
    return rc;
}

int codec_enc_end(codec_enc *e, uint64_t t_us, uint8_t *out, size_t cap, size_t *len)
{
    uint32_t s = e->seq;
    int rc = codec_packet_write(out, cap, CODEC_PKT_END, s, s, t_us, NULL, 0, len, &e->err);
    if (rc == 0) {
        stamp_version(e, out, *len);
        e->seq++;
    }
    return rc;
}

static void range_of(const float *v, size_t n, int stride, float *lo, float *hi)
{
    float a = n ? v[0] : 0.0f, b = a;
    for (size_t i = 1; i < n; i++) {
        float x = v[i * (size_t)stride];
        a = x < a ? x : a;
        b = x > b ? x : b;
    }
    *lo = a;
    *hi = b;
}

/* Quantizer from a range: `bits` minimum, more while the step exceeds
 * step_max (0 = no cap), at most 24 bits; a zero range still gets a step. */
static struct qz make_qz(float lo, float hi, int bits, float step_max)
{
    double ext = (double)hi - (double)lo;
    while (bits < 24 && step_max > 0 && ext / (double)((1u << bits) - 1) > step_max)
        bits++;
    double st = ext / (double)((1u << bits) - 1);
    if (!(st > 0))
        st = step_max > 0 ? step_max : 1.0 / (double)((1u << bits) - 1);
    struct qz z = { lo, (float)st };
    if ((double)z.step * QMAX < ext) /* float rounding of the step */
        z.step = nextafterf(z.step, INFINITY);
    return z;
}

/* Fixed metric step, widened only when the range would need more than 24 bits. */
static struct qz fixed_qz(float lo, float hi, float step)
{
    double ext = (double)hi - (double)lo;
    double st = step;
    if (ext / st > QMAX - 2)
        st = ext / (QMAX - 2) * (1 + 1e-6);
    /* lo on the step's grid, so 0 (a static Gaussian's motion) decodes to
     * exactly 0 and predictions from it do not drift */
    float fs = (float)st;
    float k = floorf((float)((double)lo / (double)fs));
    struct qz z = { k * fs, fs };
    if (z.lo > lo)
        z.lo = (k - 1.0f) * fs;
    return z;
}


/* Dequantizes intra record i (column-major, stride cap) into key slot j. */
static void intra_recon(const uint32_t *rec, size_t stride, size_t i, const struct qz *z, int rot_bits, int motion,
                        struct keystate *k, size_t j)
{
    for (int c = 0; c < 3; c++) {
        k->pos[3 * j + c] = deq(z[c], rec[(CH_POS + c) * stride + i]);
        k->ls[3 * j + c] = deq(z[3 + c], rec[(CH_LS + c) * stride + i]);
        k->rgb[3 * j + c] = deq(z[7 + c], rec[(CH_RGB + c) * stride + i]);
    }
    k->op[j] = clamp01(deq(z[6], rec[CH_OP * stride + i]));
    uint32_t r[4] = { rec[CH_ROT * stride + i], rec[(CH_ROT + 1) * stride + i], rec[(CH_ROT + 2) * stride + i],
                      rec[(CH_ROT + 3) * stride + i] };
    rot_unpack(r, rot_bits, k->rot + 4 * j);
    for (int c = 0; c < 3; c++) {
        k->mb[3 * j + c] = motion ? deq(z[QZ_MB + c], rec[(CH_MB + c) * stride + i]) : 0.0f;
        k->mf[3 * j + c] = motion ? deq(z[QZ_MF + c], rec[(CH_MF + c) * stride + i]) : 0.0f;
    }
}

/* Prediction of a Gaussian from reference slot r: moved by its forward
 * motion; motions continue at constant velocity. */
struct pred { float pos[3], ls[3], op, rgb[3], rot[4], mb[3], mf[3], rpos[3]; };

static void predict(const struct keystate *ref, size_t r, const float *cf, struct pred *p)
{
    for (int c = 0; c < 3; c++) {
        float f = ref->motion ? ref->mf[3 * r + c] : 0.0f, b = ref->motion ? ref->mb[3 * r + c] : 0.0f;
        p->rpos[c] = ref->pos[3 * r + c];
        p->pos[c] = ref->pos[3 * r + c] + (cf[0] * f + cf[1] * b);
        p->ls[c] = ref->ls[3 * r + c];
        p->rgb[c] = ref->rgb[3 * r + c];
        p->mf[c] = cf[2] * f + cf[3] * b;
        p->mb[c] = cf[4] * f + cf[5] * b;
    }
    p->op = ref->op[r];
    for (int c = 0; c < 4; c++)
        p->rot[c] = ref->rot[4 * r + c];
}

/* The backward motion's third term needs the decoded position: c6 times the
 * way back to the reference (exactly the backward motion when the motions
 * span the key interval). */
static void predict_mb(struct pred *p, const float *cf, const float *pos)
{
    if (cf[6] != 0.0f)
        for (int c = 0; c < 3; c++)
            p->mb[c] += cf[6] * (p->rpos[c] - pos[c]);
}

/* ---- Block motion (version 3) ----
 * With keyed motions, mf says where the Gaussian lands on the next key, and
 * coding it per Gaussian re-codes each one's own position noise (+-half a
 * step) on every key. Neighbours share their motion instead: the matched
 * Gaussians, in the Morton order of their predicted positions (both sides
 * know them before any residual), are cut into blocks of BLK, and each
 * block sends an affine motion, mf ~ t + M (P - o) (o: the predicted
 * position of the block's first Gaussian, P: the decoded position), fitted
 * by the encoder on the true positions and motions. The decoded position
 * then moves with its part, its noise carried along rather than re-coded,
 * and the per-Gaussian mf residual is 0 wherever a block moves rigidly or
 * affinely. Rotations likewise: each block sends the rotation dq that
 * takes its reference rotations to this key's (left-multiplied, x y z with
 * w >= 0), and a Gaussian's rotation is predicted as dq * its reference
 * rotation, so a rigid part's turn costs no rotation residual.
 * Parameters: t in 1/8 motion steps, M in 1/4096, dq in 1/8192, 15 planes
 * of zigzagged integers (t x y z, M row-major, dq x y z), |value| <=
 * BPAR_MAX, |dq| <= 1. */
/* Units of the parameters, from the frame's quantizers and the level's
 * rotation bits (both sides): t in 1/8 motion steps, M such that one unit
 * across 10 cm is 1/8 motion step, dq in 1/16 rotation steps; each is well
 * under the level's bounds and coarse enough not to code fit noise. */
static void blocks_units(struct blocks *b, const struct qz *z, int rot_bits)
{
    for (int c = 0; c < 3; c++) {
        b->ut[c] = z[QZ_MF + c].step * 0.125f;
        b->um[c] = b->ut[c] * 10.0f;
    }
    b->uq = rot_step(rot_bits) * (1.0f / 16);
}

/* t of block k predicted from block k-1 (absolute parameters): its motion
 * at this block's origin, in units of t; blocks of one rigid part then send
 * only M's rounding. */
static int32_t block_t_pred(const struct blocks *b, size_t k, int c)
{
    if (k == 0)
        return 0;
    const size_t s = b->nbmax, j = k - 1;
    float v = (float)unzig(b->par[(size_t)c * s + j]) * b->ut[c];
    for (int u = 0; u < 3; u++)
        v += (float)unzig(b->par[(size_t)(3 + 3 * c + u) * s + j]) * b->um[c] * (b->org[3 * k + u] - b->org[3 * j + u]);
    float q = v / b->ut[c];
    q = q > (float)BPAR_MAX ? (float)BPAR_MAX : q < -(float)BPAR_MAX ? -(float)BPAR_MAX : q;
    return (int32_t)lrintf(q);
}

/* Blocks of the Gaussians with rix[i] >= 0 (their reference index); uses
 * the Morton buffers (tmp holds the Gaussian of each sorted slot). */
static void blocks_assign(struct blocks *b, struct morton *mo, const struct keystate *ref, const float *cf,
                          const struct qz *z, const int32_t *rix, size_t n)
{
    size_t m = 0;
    struct pred p;
    for (size_t i = 0; i < n; i++) {
        if (rix[i] < 0)
            continue;
        predict(ref, (size_t)rix[i], cf, &p);
        mo->key[m] = morton_key(z, p.pos);
        mo->tmp[m++] = (uint32_t)i;
    }
    morton_sort(mo, m);
    b->nb = (m + BLK - 1) / BLK;
    for (size_t k = 0; k < m; k++) {
        uint32_t i = mo->tmp[mo->perm[k]];
        b->id[i] = (uint32_t)(k / BLK);
        if (k % BLK == 0) {
            predict(ref, (size_t)rix[i], cf, &p);
            memcpy(b->org + 3 * (k / BLK), p.pos, sizeof p.pos);
        }
    }
}

/* The block's forward motion at decoded position P (the encoder; decode_pred
 * repeats these operations in this order: change both together). */
static void block_mf(const struct blocks *b, uint32_t blk, const float P[3], float mf[3])
{
    const uint32_t *q = b->par;
    const size_t s = b->nbmax;
    float d[3];
    for (int c = 0; c < 3; c++)
        d[c] = P[c] - b->org[3 * blk + c];
    for (int c = 0; c < 3; c++) {
        float v = (float)unzig(q[(size_t)c * s + blk]) * b->ut[c];
        for (int k = 0; k < 3; k++)
            v += (float)unzig(q[(size_t)(3 + 3 * c + k) * s + blk]) * b->um[c] * d[k];
        mf[c] = v;
    }
}

static void qmul(const float a[4], const float b[4], float o[4])
{
    float r[4] = { a[0] * b[0] - a[1] * b[1] - a[2] * b[2] - a[3] * b[3],
                   a[0] * b[1] + a[1] * b[0] + a[2] * b[3] - a[3] * b[2],
                   a[0] * b[2] - a[1] * b[3] + a[2] * b[0] + a[3] * b[1],
                   a[0] * b[3] + a[1] * b[2] - a[2] * b[1] + a[3] * b[0] };
    memcpy(o, r, sizeof r);
}

/* The block's rotation applied to a predicted rotation (the encoder; decode_pred
 * repeats these operations in this order: change both together). */
static void block_rot(const struct blocks *b, uint32_t blk, float rot[4])
{
    const size_t s = b->nbmax;
    float dq[4], ss = 0;
    for (int c = 0; c < 3; c++) {
        dq[1 + c] = (float)unzig(b->par[(size_t)(12 + c) * s + blk]) * b->uq;
        ss += dq[1 + c] * dq[1 + c];
    }
    if (ss == 0.0f)
        return;
    dq[0] = sqrtf(ss < 1.0f ? 1.0f - ss : 0.0f);
    float q[4], n = 0;
    qmul(dq, rot, q);
    for (int c = 0; c < 4; c++)
        n += q[c] * q[c];
    n = n > 1e-30f ? 1.0f / sqrtf(n) : 0.0f;
    if (n != 0.0f)
        for (int c = 0; c < 4; c++)
            rot[c] = q[c] * n;
}

/* Encoder: least squares t + M x ~ mf over each block (x: true position
 * minus the origin; a small ridge keeps flat or tiny blocks stable), then
 * quantized. acc: [nb * 32] doubles of scratch. */
static void blocks_fit(struct blocks *b, const struct splat_frame *f, const struct keystate *ref, const int32_t *rix,
                       double *acc)
{
    memset(acc, 0, b->nb * 32 * sizeof(double));
    for (size_t i = 0; i < f->count; i++) {
        if (rix[i] < 0)
            continue;
        uint32_t k = b->id[i];
        double x[4] = { 1, (double)f->pos[3 * i] - b->org[3 * k], (double)f->pos[3 * i + 1] - b->org[3 * k + 1],
                        (double)f->pos[3 * i + 2] - b->org[3 * k + 2] };
        double *a = acc + 32 * (size_t)k;
        /* this Gaussian's turn since the reference, w >= 0 */
        float qi[4], qr[4], dq[4], nn = 0;
        for (int c = 0; c < 4; c++) {
            qi[c] = f->rot[4 * i + c];
            nn += qi[c] * qi[c];
            qr[c] = c ? -ref->rot[4 * (size_t)rix[i] + c] : ref->rot[4 * (size_t)rix[i]];
        }
        if (nn > 1e-30f) {
            qmul(qi, qr, dq);
            double sg = dq[0] < 0 ? -1.0 : 1.0, w = 1.0 / sqrt((double)nn);
            for (int c = 0; c < 4; c++)
                a[28 + c] += sg * w * dq[c];
        }
        for (int u = 0; u < 4; u++) {
            for (int v = 0; v < 4; v++)
                a[4 * u + v] += x[u] * x[v];
            for (int c = 0; c < 3; c++)
                a[16 + 4 * c + u] += x[u] * f->motion_fwd[3 * i + c];
        }
    }
    const size_t s = b->nbmax;
    for (size_t k = 0; k < b->nb; k++) {
        double *a = acc + 32 * k, g[4][4], y[4][3], sol[4][3] = { { 0 } };
        double qn = sqrt(a[28] * a[28] + a[29] * a[29] + a[30] * a[30] + a[31] * a[31]);
        for (int c = 0; c < 3; c++) {
            double v = qn > 0 ? a[29 + c] / qn * (a[28] < 0 ? -1.0 : 1.0) / b->uq : 0.0;
            b->par[(size_t)(12 + c) * s + k] = zig((int32_t)llround(v));
        }
        double ridge = a[0] * 1e-10; /* (10 um)^2 a Gaussian */
        for (int u = 0; u < 4; u++) {
            for (int v = 0; v < 4; v++)
                g[u][v] = a[4 * u + v] + (u == v && u > 0 ? ridge : 0.0);
            for (int c = 0; c < 3; c++)
                y[u][c] = a[16 + 4 * c + u];
        }
        /* Gaussian elimination with partial pivoting, 3 right-hand sides */
        int ok = a[0] > 0;
        for (int c = 0; c < 4 && ok; c++) {
            int pv = c;
            for (int r = c + 1; r < 4; r++)
                if (fabs(g[r][c]) > fabs(g[pv][c]))
                    pv = r;
            if (!(fabs(g[pv][c]) > 1e-300)) {
                ok = 0;
                break;
            }
            for (int j = 0; j < 4; j++) {
                double t = g[c][j]; g[c][j] = g[pv][j]; g[pv][j] = t;
            }
            for (int j = 0; j < 3; j++) {
                double t = y[c][j]; y[c][j] = y[pv][j]; y[pv][j] = t;
            }
            for (int r = c + 1; r < 4; r++) {
                double m = g[r][c] / g[c][c];
                for (int j = c; j < 4; j++)
                    g[r][j] -= m * g[c][j];
                for (int j = 0; j < 3; j++)
                    y[r][j] -= m * y[c][j];
            }
        }
        for (int c = 3; c >= 0 && ok; c--)
            for (int j = 0; j < 3; j++) {
                double v = y[c][j];
                for (int u = c + 1; u < 4; u++)
                    v -= g[c][u] * sol[u][j];
                sol[c][j] = v / g[c][c];
            }
        for (int c = 0; c < 3; c++) {
            double t = ok && isfinite(sol[0][c]) ? sol[0][c] / b->ut[c] : 0.0;
            t = t > BPAR_MAX ? BPAR_MAX : t < -BPAR_MAX ? -BPAR_MAX : t;
            b->par[(size_t)c * s + k] = zig((int32_t)llround(t));
            for (int u = 0; u < 3; u++) {
                double mv = ok && isfinite(sol[1 + u][c]) ? sol[1 + u][c] / b->um[c] : 0.0;
                mv = mv > BPAR_MAX ? BPAR_MAX : mv < -BPAR_MAX ? -BPAR_MAX : mv;
                b->par[(size_t)(3 + 3 * c + u) * s + k] = zig((int32_t)llround(mv));
            }
        }
    }
    for (size_t k = 0; k < b->nb; k++)
        for (int c = 0; c < 3; c++)
            b->wire[(size_t)c * s + k] = zig(unzig(b->par[(size_t)c * s + k]) - block_t_pred(b, k, c));
}

/* The quantizers of residuals: with block mf, an mf residual is in half
 * motion steps. What is left after the block motion is a Gaussian whose
 * carried position noise left the bound: half a step puts it back near the
 * middle (a whole step would throw it to the other edge, to leave again). */
static void residual_qz(const struct qz *z, int block_mf_used, struct qz *zr)
{
    memcpy(zr, z, NQZ * sizeof *z);
    if (block_mf_used)
        for (int c = 0; c < 3; c++)
            zr[QZ_MF + c].step *= 0.5f;
}

/* Applies residual record (all zero = copy) to the prediction into slot j
 * (the encoder; decode_pred repeats these operations: change both together). */
static void resid_recon(const int32_t r[NCH], const struct pred *p0, const float *cf, const struct qz *z,
                        int rot_bits, int motion, struct keystate *k, size_t j)
{
    float rs = rot_step(rot_bits);
    struct pred pp = *p0, *p = &pp;
    for (int c = 0; c < 3; c++)
        k->pos[3 * j + c] = dres(p->pos[c], z[c], r[CH_POS + c]);
    predict_mb(p, cf, k->pos + 3 * j);
    for (int c = 0; c < 3; c++) {
        k->ls[3 * j + c] = dres(p->ls[c], z[3 + c], r[CH_LS + c]);
        k->rgb[3 * j + c] = dres(p->rgb[c], z[7 + c], r[CH_RGB + c]);
        k->mb[3 * j + c] = motion ? dres(p->mb[c], z[QZ_MB + c], r[CH_MB + c]) : 0.0f;
        k->mf[3 * j + c] = motion ? dres(p->mf[c], z[QZ_MF + c], r[CH_MF + c]) : 0.0f;
    }
    k->op[j] = clamp01(dres(p->op, z[6], r[CH_OP]));
    if (r[CH_ROT] | r[CH_ROT + 1] | r[CH_ROT + 2] | r[CH_ROT + 3]) {
        float q[4], n = 0;
        for (int c = 0; c < 4; c++) {
            q[c] = p->rot[c] + (float)r[CH_ROT + c] * rs;
            n += q[c] * q[c];
        }
        if (n > 1e-30f) {
            n = 1.0f / sqrtf(n);
            for (int c = 0; c < 4; c++)
                k->rot[4 * j + c] = q[c] * n;
        } else {
            k->rot[4 * j] = 1.0f;
            k->rot[4 * j + 1] = k->rot[4 * j + 2] = k->rot[4 * j + 3] = 0.0f;
        }
    } else {
        for (int c = 0; c < 4; c++)
            k->rot[4 * j + c] = p->rot[c];
    }
}

static void finish_scales(struct keystate *k)
{
    for (size_t i = 0; i < 3 * k->count; i++)
        k->scale[i] = expf(k->ls[i]);
}

/* Quantizes Gaussian i of f into intra record column position j. */
static void intra_record(const struct splat_frame *f, const float *lsc, size_t i, const struct qz *z, int rot_bits,
                         int motion, uint32_t *rec, size_t stride, size_t j)
{
    const float *ls = lsc + 3 * i; /* logf of f's scales (SCALE_MIN at least) */
    for (int c = 0; c < 3; c++) {
        rec[(CH_POS + c) * stride + j] = quant(z[c], f->pos[3 * i + c]);
        rec[(CH_LS + c) * stride + j] = quant(z[3 + c], ls[c]);
        rec[(CH_RGB + c) * stride + j] = quant(z[7 + c], f->rgb[3 * i + c]);
        if (motion) {
            rec[(CH_MB + c) * stride + j] = quant(z[QZ_MB + c], f->motion_bwd[3 * i + c]);
            rec[(CH_MF + c) * stride + j] = quant(z[QZ_MF + c], f->motion_fwd[3 * i + c]);
        }
    }
    rec[CH_OP * stride + j] = quant(z[6], f->opacity[i]);
    uint32_t r[4];
    rot_pack(f->rot + 4 * i, rot_bits, r);
    for (int c = 0; c < 4; c++)
        rec[(CH_ROT + c) * stride + j] = r[c];
}

/* Solves the k x k system a x = y (k <= 3) by elimination with pivoting;
 * -1 when it is (nearly) singular. */
static int solve3(double a[3][3], double y[3], int k, double x[3])
{
    for (int c = 0; c < k; c++) {
        int pv = c;
        for (int r = c + 1; r < k; r++)
            if (fabs(a[r][c]) > fabs(a[pv][c]))
                pv = r;
        if (!(fabs(a[pv][c]) > 1e-12 * (fabs(a[0][0]) + fabs(a[1][1]) + fabs(a[2][2]) + 1e-300)))
            return -1;
        for (int j = 0; j < 3; j++) {
            double t = a[c][j];
            a[c][j] = a[pv][j];
            a[pv][j] = t;
        }
        double t = y[c];
        y[c] = y[pv];
        y[pv] = t;
        for (int r = c + 1; r < k; r++) {
            double m = a[r][c] / a[c][c];
            for (int j = c; j < k; j++)
                a[r][j] -= m * a[c][j];
            y[r] -= m * y[c];
        }
    }
    for (int c = k - 1; c >= 0; c--) {
        double v = y[c];
        for (int j = c + 1; j < k; j++)
            v -= a[c][j] * x[j];
        x[c] = v / a[c][c];
    }
    return 0;
}

/* Least-squares predictor coefficients (see f4d_codec.h, "Predictor"), per
 * target over the matched Gaussians and all three axes: displacement and mf
 * on the reference's (mf, mb), mb on (mf, mb, way back to the reference);
 * a fit is kept only where it beats the version-1 coefficients in squared
 * error (so static or motionless takes keep those). */
static void fit_predictor(const struct keystate *ref, const struct splat_frame *f, const int32_t *match, int motion,
                          float cf[NCOEF])
{
    memcpy(cf, coef_v1, sizeof coef_v1);
    if (!ref->motion)
        return;
    double sxx[3][3] = { { 0 } }, sxy[3][3] = { { 0 } }, syy[3] = { 0 };
    for (size_t i = 0; i < f->count; i++) {
        int32_t r = match ? match[i] : (i < ref->count ? (int32_t)i : -1);
        if (r < 0)
            continue;
        for (int c = 0; c < 3; c++) {
            size_t rc = 3 * (size_t)r + (size_t)c;
            double back = (double)ref->pos[rc] - f->pos[3 * i + c];
            double x[3] = { ref->mf[rc], ref->mb[rc], back };
            double y[3] = { -back, motion ? f->motion_fwd[3 * i + c] : 0.0, motion ? f->motion_bwd[3 * i + c] : 0.0 };
            for (int u = 0; u < 3; u++) {
                for (int v = 0; v < 3; v++)
                    sxx[u][v] += x[u] * x[v];
                for (int t = 0; t < 3; t++)
                    sxy[t][u] += x[u] * y[t];
            }
            for (int t = 0; t < 3; t++)
                syy[t] += y[t] * y[t];
        }
    }
    static const int first[3] = { 0, 2, 4 }, nreg[3] = { 2, 2, 3 };
    for (int t = 0; t < (motion ? 3 : 1); t++) {
        int k = nreg[t];
        double a[3][3] = { { 0 } }, y[3] = { 0 }, x[3] = { 0 };
        for (int u = 0; u < k; u++) {
            y[u] = sxy[t][u];
            for (int v = 0; v < k; v++)
                a[u][v] = sxx[u][v];
        }
        if (solve3(a, y, k, x) < 0)
            continue;
        float fit[3] = { 0 };
        double e_fit = syy[t], e_v1 = syy[t];
        int ok = 1;
        for (int u = 0; u < k; u++) {
            ok &= fabs(x[u]) <= COEF_MAX;
            fit[u] = (float)x[u];
        }
        for (int u = 0; u < k; u++) {
            double fu = fit[u], vu = coef_v1[first[t] + u];
            e_fit -= 2 * fu * sxy[t][u];
            e_v1 -= 2 * vu * sxy[t][u];
            for (int v = 0; v < k; v++) {
                e_fit += fu * fit[v] * sxx[u][v];
                e_v1 += vu * coef_v1[first[t] + v] * sxx[u][v];
            }
        }
        if (ok && e_fit < e_v1)
            for (int u = 0; u < k; u++)
                cf[first[t] + u] = fit[u];
    }
}

/* Keyed mf residual on axis c: kept (0) while this decoded position plus the
 * predicted mf lands within 0.9 position bounds of the true next position,
 * else the step count towards it (see codec_enc_key). */
static int32_t mf_resid(const struct splat_frame *f, size_t i, int c, float rpos, float pmf, struct qz z,
                        float tol)
{
    double dt = ((double)f->pos[3 * i + c] + f->motion_fwd[3 * i + c]) - ((double)rpos + pmf);
    double u = dt / (double)z.step;
    return fabs(dt) <= 0.9 * tol ? 0 : u > RMAX ? RMAX : u < -RMAX ? -RMAX : (int32_t)llround(u);
}

/* Bits plane v[0..m) (index order) takes as put_plane codes it (sized as
 * plane_pick sizes it), in the cheaper of index order and the Morton order
 * in e->mo.perm (as a key's residual planes are); the Morton copy goes
 * through mo.tmp. */
static double plane_cost(codec_enc *e, const uint32_t *v, size_t m)
{
    double o1 = plane_est(e, v, e->mo.perm, m, 2), o2 = plane_est(e, v, NULL, m, 2);
    return 8.0 * (o1 < o2 ? o1 : o2);
}

/* Bits of block parameter planes [from, to) as the key sends them. */
static double block_param_cost(codec_enc *e, const struct blocks *bk, int from, int to)
{
    double bits = 0;
    for (int k = from; k < to; k++) {
        const uint32_t *bv = (k < 3 ? bk->wire : bk->par) + (size_t)k * bk->nbmax;
        bits += 8.0 * plane_est(e, bv, NULL, bk->nb, 2);
    }
    return bits;
}

/* With keyed motions, the temporal mf prediction carries each Gaussian's own
 * reconstruction error (its decoded position and motions, up to about two
 * position bounds, amplified by the fitted coefficients), which no order
 * makes compressible; predicting nothing instead codes the velocity field
 * itself, whose neighbours in Morton order agree wherever a part moves
 * rigidly. Which wins depends on the take (smooth slow motion: temporal;
 * fast articulated motion: spatial), so both are tried on the mf residuals
 * alone: Morton order of the predicted positions, cost sum log2(1 + |delta|)
 * (what zstd sees), and c2 = c3 = 0 is kept when cheaper. Version 3 (bk:
 * the blocks, fitted) adds block motion as a third candidate and measures
 * all three as the key codes them (plane_cost, two bits a changed Gaussian,
 * the block parameters' planes); returns 1 when block mf wins. Uses the
 * residual planes and the Morton buffers as scratch. */
static int choose_mf_predictor(codec_enc *e, const struct keystate *ref, const struct splat_frame *f,
                               const int32_t *match, const struct qz *z, const float *pos_tol, float *cf,
                               const struct blocks *bk)
{
    const int nk = bk ? 3 : 2;
    const size_t stride = e->cap ? e->cap : 1;
    struct qz zh[3]; /* block mf residuals are in half steps (residual_qz) */
    for (int c = 0; c < 3; c++)
        zh[c] = (struct qz){ z[QZ_MF + c].lo, z[QZ_MF + c].step * 0.5f };
    size_t m = 0;
    for (size_t i = 0; i < f->count; i++) {
        int32_t r = match ? match[i] : (i < ref->count ? (int32_t)i : -1);
        if (r < 0)
            continue;
        struct pred p;
        float rp3[3];
        predict(ref, (size_t)r, cf, &p);
        for (int c = 0; c < 3; c++) {
            int32_t rp = resid(z[c], f->pos[3 * i + c], p.pos[c]);
            if (fabsf(f->pos[3 * i + c] - p.pos[c]) <= pos_tol[c])
                rp = 0;
            float rpos = dres(p.pos[c], z[c], rp);
            e->res[(size_t)c * stride + m] = zig(mf_resid(f, i, c, rpos, p.mf[c], z[QZ_MF + c], pos_tol[c]));
            e->res[(size_t)(3 + c) * stride + m] = zig(mf_resid(f, i, c, rpos, 0.0f, z[QZ_MF + c], pos_tol[c]));
            rp3[c] = rpos;
        }
        if (bk) {
            float bmf[3];
            block_mf(bk, bk->id[i], rp3, bmf);
            for (int c = 0; c < 3; c++)
                e->res[(size_t)(6 + c) * stride + m] = zig(mf_resid(f, i, c, rp3[c], bmf[c], zh[c], pos_tol[c]));
        }
        if (!bk) /* else mo.perm holds blocks_assign's order of these */
            e->mo.key[m] = morton_key(z, p.pos);
        m++;
    }
    if (m < 2)
        return 0;
    if (!bk)
        morton_sort(&e->mo, m);
    double cost[3] = { 0, 0, 0 };
    if (bk) {
        /* version 3: measured as the key codes them (see choose_block_rot) */
        for (int k = 0; k < nk; k++) {
            for (int c = 0; c < 3; c++)
                cost[k] += plane_cost(e, e->res + (size_t)(3 * k + c) * stride, m);
            for (size_t j = 0; j < m; j++)
                cost[k] += (e->res[(size_t)(3 * k) * stride + j] | e->res[(size_t)(3 * k + 1) * stride + j] |
                            e->res[(size_t)(3 * k + 2) * stride + j]) ? 2.0 : 0.0;
        }
        cost[2] += block_param_cost(e, bk, 0, 12);
    } else {
        for (int k = 0; k < nk; k++)
            for (int c = 0; c < 3; c++) {
                const uint32_t *v = e->res + (size_t)(3 * k + c) * stride;
                int32_t prev = 0;
                for (size_t j = 0; j < m; j++) {
                    int32_t x = unzig(v[e->mo.perm[j]]);
                    cost[k] += log2(1.0 + fabs((double)x - (double)prev));
                    prev = x;
                }
            }
    }
    if (bk && cost[2] < cost[0] && cost[2] < cost[1]) {
        cf[2] = cf[3] = 0.0f;
        return 1;
    }
    if (cost[1] < cost[0])
        cf[2] = cf[3] = 0.0f;
    return 0;
}

/* Rotation residual of Gaussian i against the predicted rotation prot, in
 * steps rs; 0 where the change is within a step or hardly shows (see
 * codec_enc_key). Returns whether any component is non-zero. */
static int rot_resid(const struct splat_frame *f, size_t i, const float prot[4], float rs, float rot_tol, int32_t r[4])
{
    /* rotation: the input normalised and on the prediction's side */
    const float *qin = f->rot + 4 * i;
    float qn = 0, dot = 0;
    for (int c = 0; c < 4; c++) {
        qn += qin[c] * qin[c];
        dot += qin[c] * prot[c];
    }
    qn = qn > 1e-30f ? (dot < 0 ? -1.0f : 1.0f) / sqrtf(qn) : 0.0f;
    int rot_near = 1;
    for (int c = 0; c < 4; c++) {
        float qc = qn != 0.0f ? qin[c] * qn : (c == 0 ? 1.0f : 0.0f);
        double t = ((double)qc - (double)prot[c]) / rs;
        /* llround, inline (|t| is far below 2^31; NaN gives 0 as before) */
        r[c] = fabs(t) < 1e9 ? (int32_t)(t < 0 ? t - 0.5 : t + 0.5) : 0;
        rot_near &= fabs(t) <= 1.0;
    }
    /* A rotation by angle a moves the Gaussian's 2-sigma ellipsoid
     * by at most 2 a (s_max - s_min): within the position bound it
     * is kept (a near-isotropic Gaussian's rotation hardly shows). */
    if (!rot_near && qn != 0.0f) {
        const float *sc = f->scale + 3 * i;
        float smax = fmaxf(sc[0], fmaxf(sc[1], sc[2])), smin = fminf(sc[0], fminf(sc[1], sc[2]));
        float cd = fminf(1.0f, fabsf(dot) * fabsf(qn));
        float ang = 2.0f * acosf(cd);
        rot_near = 2.0f * ang * (smax - smin) <= rot_tol;
    }
    if (rot_near)
        r[0] = r[1] = r[2] = r[3] = 0;
    return (r[0] | r[1] | r[2] | r[3]) != 0;
}

/* Block rotations pay where the rotation residuals they leave cost less
 * than those without them plus their parameters. All are measured: the four residual planes
 * of every matched Gaussian, in index order and in the Morton order of the
 * predicted positions, coded as put_plane codes them (zstd; the smaller
 * order counts, as in the key); a changed Gaussian adds two bits. Without block rotations a rigid part's residuals follow
 * the reference rotations, smooth along a surface; with them only the
 * reference's own quantization noise is left, which is smaller where the
 * blocks fit and does not delta-code, so neither wins everywhere (sparse
 * takes whose blocks straddle parts, fine levels). Uses the residual planes
 * and the Morton buffers as scratch. */
static int choose_block_rot(codec_enc *e, const struct keystate *ref, const struct splat_frame *f, const float *cf,
                            const struct qz *z, float rs, float rot_tol)
{
    const size_t stride = e->cap ? e->cap : 1;
    double cost[2] = { 0, block_param_cost(e, &e->bk, 12, NBP) };
    size_t m = 0;
    for (size_t i = 0; i < f->count; i++) {
        if (e->rix[i] < 0)
            continue;
        struct pred p;
        predict(ref, (size_t)e->rix[i], cf, &p);
        for (int k = 0; k < 2; k++) {
            int32_t r[4];
            if (k)
                block_rot(&e->bk, e->bk.id[i], p.rot);
            if (rot_resid(f, i, p.rot, rs, rot_tol, r))
                cost[k] += 2.0;
            for (int c = 0; c < 4; c++)
                e->res[(size_t)(4 * k + c) * stride + m] = zig(r[c]);
        }
        m++;
    }
    if (m < 2)
        return 0;
    /* mo.perm holds blocks_assign's Morton order of these (the positions
     * predicted alike: cf[2], cf[3] do not move them) */
    for (int k = 0; k < 2; k++)
        for (int c = 0; c < 4; c++) {
            cost[k] += plane_cost(e, e->res + (size_t)(4 * k + c) * stride, m);
        }
    return cost[1] < cost[0];
}

static void put_qz(uint8_t *p, const struct qz *z)
{
    for (int k = 0; k < NQZ; k++) {
        codec__put_f32(p + 8 * k, z[k].lo);
        codec__put_f32(p + 8 * k + 4, z[k].step);
    }
}

static int stat_group(int ch) { return ch < CH_LS ? 0 : ch < CH_MB ? 1 : 2; }

int codec_enc_key(codec_enc *e, const struct splat_frame *f, uint64_t t_us, enum codec_key_mode mode,
                  const int32_t *match, uint8_t *out, size_t cap, size_t *len)
{
    if (!e)
        return F4D_EINVAL;
    if (!f || !out || !len)
        return f4d_fail(&e->err, F4D_EINVAL, "codec_enc_key: NULL argument");
    if (f->count > e->cap)
        return f4d_fail(&e->err, F4D_ERANGE, "codec_enc_key: %zu Gaussians exceed the planned %zu", f->count,
                        e->cap);
    int rc = splat_frame_validate(f, &e->err);
    if (rc < 0) {
        f4d_err_prefix(&e->err, "codec_enc_key");
        return rc;
    }
    const struct codec_quality_info *qi = &qtab[e->q];
    const size_t n = f->count, stride = e->cap ? e->cap : 1;
    const int motion = f->motion_bwd && f->motion_fwd;
    const int nch = motion ? NCH : CH_MB;
    struct keystate *ref = &e->key[e->cur], *dst = &e->key[e->cur ^ 1];
    if ((unsigned)mode > CODEC_KEY_STILL)
        return f4d_fail(&e->err, F4D_EINVAL, "codec_enc_key: mode %d out of range", (int)mode);
    int intra = mode != CODEC_KEY_AUTO || !e->have_ref, still = mode == CODEC_KEY_STILL;
    if (match && !intra)
        for (size_t i = 0; i < n; i++)
            if (match[i] < -1 || (match[i] >= 0 && (size_t)match[i] >= ref->count))
                return f4d_fail(&e->err, F4D_EINVAL, "codec_enc_key: match[%zu] = %d, the reference has %zu",
                                i, match[i], ref->count);
    /* stream order: a predicted key is coded on the input permuted into
     * the reference's order (the match then names reference slots) */
    const int reorder = e->reorder && !still;
    uint32_t *ord_dst = reorder ? e->ord[e->cur ^ 1] : NULL;
    struct splat_frame pview;
    if (reorder && !intra) {
        match = stream_order(e, f, match, e->ord[e->cur], ref->count, ord_dst);
        pview = e->pf;
        pview.count = n;
        if (!motion)
            pview.motion_bwd = pview.motion_fwd = NULL;
        f = &pview;
    }

    /* Quantizers from this frame's ranges. */
    struct qz z[NQZ];
    for (int c = 0; c < 3; c++) {
        float lo, hi;
        range_of(f->pos + c, n, 3, &lo, &hi);
        z[c] = make_qz(lo, hi, qi->pos_bits_min, qi->pos_step_max);
        float llo = 0, lhi = 0;
        for (size_t i = 0; i < n; i++) {
            float s = logf(f->scale[3 * i + c] > SCALE_MIN ? f->scale[3 * i + c] : SCALE_MIN);
            e->lsc[3 * i + c] = s;
            llo = i == 0 || s < llo ? s : llo;
            lhi = i == 0 || s > lhi ? s : lhi;
        }
        z[3 + c] = fixed_qz(llo, lhi, qi->log_scale_step);
        range_of(f->rgb + c, n, 3, &lo, &hi);
        z[7 + c] = make_qz(lo, hi, qi->rgb_bits, 0);
        if (motion) {
            range_of(f->motion_bwd + c, n, 3, &lo, &hi);
            z[QZ_MB + c] = fixed_qz(lo, hi, qi->motion_step);
            range_of(f->motion_fwd + c, n, 3, &lo, &hi);
            z[QZ_MF + c] = fixed_qz(lo, hi, qi->motion_step);
        } else {
            z[QZ_MB + c] = z[QZ_MF + c] = (struct qz){ 0.0f, qi->motion_step };
        }
    }
    z[6] = make_qz(0.0f, 1.0f, qi->opacity_bits, 0);

    memset(&e->st, 0, sizeof e->st);
    e->last_still = 0;
    uint8_t *pl = out + CODEC_PACKET_HEADER;
    size_t off = FHDR + 8 * NQZ;
    if (cap < CODEC_PACKET_HEADER + off)
        return f4d_fail(&e->err, F4D_ERANGE, "codec_enc_key: output buffer of %zu bytes too small", cap);
    size_t pcap = cap - CODEC_PACKET_HEADER;
    size_t n_changed = 0, n_new = 0, n_same = 0, matched = 0;
    int explicit_match = 0, block_motion = 0, block_mf_used = 0, block_rot_used = 0;
    float cf[NCOEF];
    memcpy(cf, coef_v1, sizeof cf);
    dst->count = n;
    dst->motion = motion;

    if (intra) {
        int morton = (still || reorder) && n > 1, recorded = 0;
        if (morton) {
            /* Morton order of the positions: neighbours in space get
             * neighbouring indices, so every plane's deltas shrink */
            for (size_t i = 0; i < n; i++)
                e->mo.key[i] = morton_key(z, f->pos + 3 * i);
            morton_sort(&e->mo, n);
        }
        if (morton && !still) {
            /* stream order: kept where the planes measure smaller than in
             * input order (a sparse take, or pixel-aligned Gaussians in
             * image order, may already have their neighbours beside them) */
            for (size_t i = 0; i < n; i++)
                intra_record(f, e->lsc, i, z, qi->rot_bits, motion, e->rec, stride, i);
            double in_order = 0, in_morton = 0;
            for (int c = 0; c < nch; c++) {
                in_order += plane_est(e, e->rec + (size_t)c * stride, NULL, n, 1);
                in_morton += plane_est(e, e->rec + (size_t)c * stride, e->mo.perm, n, 1);
            }
            morton = in_morton < in_order;
            recorded = 1;
        }
        if (!morton) {
            for (size_t i = 0; i < n; i++)
                e->mo.perm[i] = (uint32_t)i;
        }
        if (reorder)
            memcpy(ord_dst, e->mo.perm, n * sizeof(uint32_t));
        if (recorded && morton) {
            /* the records of the input order, gathered into Morton order
             * (res is free on an intra key), not quantized again */
            for (int c = 0; c < nch; c++)
                for (size_t j = 0; j < n; j++)
                    e->res[(size_t)c * stride + j] = e->rec[(size_t)c * stride + e->mo.perm[j]];
            uint32_t *sw = e->rec;
            e->rec = e->res;
            e->res = sw;
        }
        for (size_t j = 0; j < n; j++) {
            if (!recorded)
                intra_record(f, e->lsc, e->mo.perm[j], z, qi->rot_bits, motion, e->rec, stride, j);
            intra_recon(e->rec, stride, j, z, qi->rot_bits, motion, dst, j);
        }
        n_new = n;
        for (int c = 0; c < nch; c++) {
            size_t o0 = off;
            if ((rc = put_plane(e, e->rec + (size_t)c * stride, n, 1, pl, pcap, &off)) < 0)
                return rc;
            size_t *g[3] = { &e->st.bytes_pos, &e->st.bytes_attr, &e->st.bytes_motion };
            *g[stat_group(c)] += off - o0;
            e->st.bytes_channel[c] += off - o0;
        }
    } else {
        explicit_match = 0;
        if (match) {
            for (size_t i = 0; i < n; i++)
                if (match[i] != (int32_t)i) {
                    explicit_match = 1;
                    break;
                }
            if (!explicit_match && n > ref->count)
                explicit_match = 1;
        } else if (n > ref->count) {
            explicit_match = 0; /* identity: indices >= ref->count are new */
        }
        fit_predictor(ref, f, match, motion, cf);
        float rs = rot_step(qi->rot_bits);
        float pos_tol[3];
        for (int c = 0; c < 3; c++)
            pos_tol[c] = 0.5f * (z[c].step > qi->pos_step_max ? z[c].step : qi->pos_step_max);
        const float rot_tol = fminf(pos_tol[0], fminf(pos_tol[1], pos_tol[2]));
        /* motions that span the key interval (the version-1 shape) */
        const int keyed = fabsf(cf[0] - 1.0f) < 0.25f && fabsf(cf[1]) < 0.25f;
        if (keyed && motion) { /* then mb is the way back (see above) */
            cf[4] = cf[5] = 0.0f;
            cf[6] = 1.0f;
        }
        const float mb_tol = 2.0f * fmaxf(pos_tol[0], fmaxf(pos_tol[1], pos_tol[2])) + 0.5f * qi->motion_step;
        /* block motion replaces the per-Gaussian mf prediction (keyed) */
        block_motion = keyed && motion && n > 0 && e->ver >= 3;
        if (block_motion) {
            for (size_t i = 0; i < n; i++)
                e->rix[i] = match ? match[i] : (i < ref->count ? (int32_t)i : -1);
            blocks_assign(&e->bk, &e->mo, ref, cf, z, e->rix, n);
            blocks_units(&e->bk, z, qi->rot_bits);
            blocks_fit(&e->bk, f, ref, e->rix, e->bacc);
        }
        /* CODEC_EFFORT_FAST: block mf and rotations wherever blocks are
         * fitted, unmeasured (the measuring codes every matched Gaussian's
         * residuals twice or three times over) */
        const int fast = e->effort == CODEC_EFFORT_FAST;
        if (keyed && motion && n > 1 && fast && block_motion) {
            block_mf_used = 1;
            cf[2] = cf[3] = 0.0f;
        } else if (keyed && motion && n > 1) {
            block_mf_used = choose_mf_predictor(e, ref, f, match, z, pos_tol, cf, block_motion ? &e->bk : NULL);
        }
        if (block_motion) {
            block_rot_used = fast ? 1 : choose_block_rot(e, ref, f, cf, z, rot_step(qi->rot_bits), rot_tol);
            /* a part not used is sent as zeros (nearly free) */
            for (int k = block_mf_used ? 12 : 0; k < (block_rot_used ? 12 : NBP); k++)
                memset(e->bk.par + (size_t)k * e->bk.nbmax, 0, e->bk.nb * sizeof(uint32_t));
            if (!block_mf_used)
                memset(e->bk.wire, 0, 3 * e->bk.nbmax * sizeof(uint32_t));
            block_motion = block_mf_used || block_rot_used;
        }
        struct qz zr[NQZ];
        residual_qz(z, block_mf_used, zr);
        int32_t prev = -1;
        for (size_t i = 0; i < n; i++) {
            int32_t r = match ? match[i] : (i < ref->count ? (int32_t)i : -1);
            if (r < 0) {
                e->flags[i] = 2;
                e->idx[i] = 0;
                intra_record(f, e->lsc, i, z, qi->rot_bits, motion, e->rec, stride, n_new);
                intra_recon(e->rec, stride, n_new, z, qi->rot_bits, motion, dst, i);
                n_new++;
                continue;
            }
            matched++;
            e->idx[i] = zig(r - (prev + 1));
            prev = r;
            struct pred p;
            predict(ref, (size_t)r, cf, &p);
            if (block_rot_used)
                block_rot(&e->bk, e->bk.id[i], p.rot);
            int32_t res[NCH] = { 0 };
            float rpos[3];
            const float *ls = e->lsc + 3 * i; /* from the ranges' pass */
            /* positions first: the backward motion's prediction needs them.
             * Dead zone: a prediction already within the level's bound is
             * kept (the reference's own quantization error would otherwise
             * flip it to +-1 from key to key). */
            for (int c = 0; c < 3; c++) {
                res[CH_POS + c] = resid(z[c], f->pos[3 * i + c], p.pos[c]);
                if (fabsf(f->pos[3 * i + c] - p.pos[c]) <= pos_tol[c])
                    res[CH_POS + c] = 0;
                rpos[c] = dres(p.pos[c], z[c], res[CH_POS + c]);
            }
            if (block_mf_used)
                block_mf(&e->bk, e->bk.id[i], rpos, p.mf);
            struct pred pb = p;
            predict_mb(&pb, cf, rpos);
            for (int c = 0; c < 3; c++) {
                res[CH_LS + c] = resid(z[3 + c], ls[c], p.ls[c]);
                res[CH_RGB + c] = resid(z[7 + c], f->rgb[3 * i + c], p.rgb[c]);
                if (motion) {
                    /* keyed: the next key is predicted at this key's
                     * decoded position plus its decoded mf, so mf is judged
                     * by where that lands: the prediction is kept while it
                     * lands within 0.9 position bounds of the true next
                     * position (true position + true mf), else coded
                     * towards that target. Position errors then never add
                     * up from key to key, and the decoded positions' own
                     * quantization noise is not re-coded in every mf. */
                    if (keyed) {
                        res[CH_MF + c] = mf_resid(f, i, c, rpos[c], p.mf[c], zr[QZ_MF + c], pos_tol[c]);
                    } else {
                        res[CH_MF + c] = resid(z[QZ_MF + c], f->motion_fwd[3 * i + c], p.mf[c]);
                    }
                    /* keyed: the prediction is the way back to the decoded
                     * reference, off the true one by at most the two
                     * position bounds; kept within them, so a decoded
                     * key's mb leads exactly to the decoded reference */
                    float mbd = f->motion_bwd[3 * i + c] - pb.mb[c];
                    res[CH_MB + c] = keyed && fabsf(mbd) <= mb_tol ? 0 : resid(z[QZ_MB + c], f->motion_bwd[3 * i + c], pb.mb[c]);
                }
            }
            res[CH_OP] = resid(z[6], f->opacity[i], p.op);
            rot_resid(f, i, p.rot, rs, rot_tol, res + CH_ROT);
            int any = 0;
            for (int c = 0; c < nch; c++)
                any |= res[c];
            resid_recon(res, &p, cf, zr, qi->rot_bits, motion, dst, i);
            if (block_motion) /* where matched Gaussian matched-1 lands among the changed */
                e->mo.tmp[matched - 1] = any ? (uint32_t)n_changed : UINT32_MAX;
            if (!any) {
                e->flags[i] = 0;
                n_same++;
                continue;
            }
            e->flags[i] = 1;
            for (int c = 0; c < nch; c++)
                e->res[(size_t)c * stride + n_changed] = zig(res[c]);
            if (!block_motion)
                e->mo.key[n_changed] = morton_key(z, p.pos);
            n_changed++;
        }
        size_t o0 = off;
        if (explicit_match && (rc = put_plane(e, e->idx, n, 0, pl, pcap, &off)) < 0)
            return rc;
        e->st.bytes_match = off - o0;
        if ((rc = put_plane(e, e->flags, n, 0, pl, pcap, &off)) < 0)
            return rc;
        e->st.bytes_index = off - o0;
        for (int k = 0; k < NBP && block_motion; k++) {
            size_t o2 = off;
            const uint32_t *bv = (k < 3 ? e->bk.wire : e->bk.par) + (size_t)k * e->bk.nbmax;
            if ((rc = put_plane(e, bv, e->bk.nb, 2, pl, pcap, &off)) < 0)
                return rc;
            e->st.bytes_motion += off - o2;
            e->st.bytes_blocks += off - o2;
        }
        e->st.bytes_flags = e->st.bytes_index - e->st.bytes_match;
        size_t *g[3] = { &e->st.bytes_pos, &e->st.bytes_attr, &e->st.bytes_motion };
        /* residual planes may be delta-coded too: neighbours in index order
         * (pixel-aligned, or sampled along a surface) share their motion
         * change, so differences along the index are smaller */
        if (block_motion) {
            /* mo.perm holds blocks_assign's (stable) Morton order of the
             * matched Gaussians, at the same predicted positions: the
             * changed ones' order is that order filtered, as sorting them
             * alone gives */
            size_t w = 0;
            for (size_t k = 0; k < matched; k++)
                if (e->mo.tmp[e->mo.perm[k]] != UINT32_MAX)
                    e->mo.perm[w++] = e->mo.tmp[e->mo.perm[k]];
        } else if (n_changed) {
            morton_sort(&e->mo, n_changed);
        }
        for (int c = 0; c < nch; c++) {
            o0 = off;
            uint32_t *src = e->res + (size_t)c * stride;
            if (n_changed > 1 && e->effort == CODEC_EFFORT_FAST) {
                /* fast: the Morton order alone (the smaller one mostly) */
                for (size_t j = 0; j < n_changed; j++)
                    e->mo.tmp[j] = src[e->mo.perm[j]];
                if ((rc = put_plane(e, e->mo.tmp, n_changed, 2, pl, pcap, &off)) < 0)
                    return rc;
                pl[o0] |= 4;
            } else if (n_changed > 1) {
                /* the same plane in Morton order, kept when smaller (tag
                 * bit 2): both orders sized, only the smaller compressed */
                int t[2], form[2], tg[2];
                size_t ex[2];
                double est1 = plane_choose(e, src, e->mo.perm, n_changed, 2, &t[1], &form[1], &ex[1]);
                tg[1] = e->pb.best_tag;
                uint8_t *sw = e->pb.zkeep; /* the Morton order's, while index order is tried */
                e->pb.zkeep = e->pb.zbest;
                e->pb.zbest = sw;
                int k = est1 < plane_choose(e, src, NULL, n_changed, 2, &t[0], &form[0], &ex[0]);
                tg[0] = e->pb.best_tag;
                if (ex[k] && e->zfin == e->zest) {
                    rc = put_plane_z(e, tg[k], k ? e->pb.zkeep : e->pb.zbest, ex[k], pl, pcap, &off);
                } else {
                    if (k)
                        for (size_t j = 0; j < n_changed; j++)
                            e->mo.tmp[j] = src[e->mo.perm[j]];
                    rc = put_plane_as(e, k ? e->mo.tmp : src, n_changed, plane_max(src, n_changed), t[k], form[k],
                                      pl, pcap, &off);
                }
                if (rc < 0)
                    return rc;
                pl[o0] |= (uint8_t)(4 * k);
            } else if ((rc = put_plane(e, src, n_changed, 2, pl, pcap, &off)) < 0) {
                return rc;
            }
            *g[stat_group(c)] += off - o0;
            e->st.bytes_channel[c] += off - o0;
        }
        for (int c = 0; c < nch; c++) {
            o0 = off;
            if ((rc = put_plane(e, e->rec + (size_t)c * stride, n_new, 1, pl, pcap, &off)) < 0)
                return rc;
            *g[stat_group(c)] += off - o0;
            e->st.bytes_channel[c] += off - o0;
        }
    }
    finish_scales(dst);

    pl[0] = intra ? 1 : 2;
    pl[1] = (uint8_t)e->q;
    pl[2] = (uint8_t)(motion | explicit_match << 1 | block_motion << 2 | block_mf_used << 3 | block_rot_used << 4);
    pl[3] = (uint8_t)qi->rot_bits;
    codec__put_u32(pl + 4, (uint32_t)n);
    codec__put_u32(pl + 8, intra ? 0u : (uint32_t)ref->count);
    codec__put_u32(pl + 12, (uint32_t)n_new);
    codec__put_u32(pl + 16, (uint32_t)n_changed);
    for (int k = 0; k < NCOEF; k++)
        codec__put_f32(pl + FHDR1 + 4 * k, cf[k]);
    put_qz(pl + FHDR, z);

    uint32_t s = e->seq;
    rc = codec_packet_write(out, cap, intra ? CODEC_PKT_INTRA : CODEC_PKT_PRED, s, intra ? s : e->ref_seq, t_us,
                            pl, off, len, &e->err);
    if (rc < 0)
        return rc;
    stamp_version(e, out, *len);
    e->st.intra = intra;
    e->st.count = n;
    e->st.unchanged = n_same;
    e->st.changed = n_changed;
    e->st.fresh = n_new;
    e->st.dropped = intra ? 0 : (ref->count > matched ? ref->count - matched : 0);
    e->st.bytes_total = off;
    e->st.bytes_header = FHDR + 8 * NQZ;
    memcpy(e->st.predictor, cf, sizeof cf);
    e->seq++;
    e->ref_seq = s;
    e->cur ^= 1;
    e->have_ref = !still; /* a still key's order is not the input's: never a reference */
    e->last_still = still;
    return F4D_OK;
}

/* ------------------------------------------------------------------------ */
/* Decoder. */

/* A block's parameters as the floats block_mf / block_rot form from them. */
struct dblk { float t[3], m[9], dq[4]; int rot; };

/* Scratch of pred_tile (below): DT Gaussians of a predicted key. Per-Gaussian
 * vectors interleaved as the key's arrays are (3 j + c), rotations split. */
#define DT 256

struct dtile {
    uint32_t ri[DT], bid[DT], rr[DT], cj[DT];
    float dpos[3 * DT], dls[3 * DT], drgb[3 * DT], dmb[3 * DT], dmf[3 * DT], dop[DT], drot[4][DT];
    float pos[3 * DT], f[3 * DT], b[3 * DT], mf[3 * DT], mb[3 * DT];
    float g[3 * DT];                    /* gathered reference values (scratch) */
    float qa[4][DT], qd[4][DT], qb[DT]; /* rotations, block dq, block mask   */
};

struct codec_dec {
    size_t cap;
    struct f4d_err err;
    struct keystate key[2];
    int cur, have_ref, have_seq, quality;
    int ver;           /* codec version of the packet being decoded */
    uint32_t last_seq, key_seq;
    uint64_t t_us;
    uint32_t *rec, *res, *idx, *flags;
    struct morton mo;
    struct blocks bk;
    int32_t *rix;
    uint32_t *ord, *spos;   /* changed ordinal of a Gaussian; slot of an ordinal */
    float *ppos;            /* [3 * cap] predicted positions */
    struct dblk *bf;        /* [nbmax] blocks as floats */
    struct dtile *tile;     /* pred_tile's scratch */
    size_t checked;         /* Gaussians of a predicted key found finite as decoded */
    uint8_t *shuf;
    void *zws;
    ZSTD_DCtx *z;
    struct codec_dec_stats st;
};

int codec_dec_new(size_t capacity, codec_dec **out, struct f4d_err *err)
{
    if (!out)
        return f4d_fail(err, F4D_EINVAL, "codec_dec_new: out is NULL");
    *out = NULL;
    if (capacity > CODEC_CAPACITY_MAX)
        return f4d_fail(err, F4D_ERANGE, "codec_dec_new: capacity %zu exceeds %zu Gaussians", capacity,
                        CODEC_CAPACITY_MAX);
    codec_dec *d = calloc(1, sizeof *d);
    if (!d)
        return f4d_fail(err, F4D_ENOMEM, "codec_dec_new: out of memory");
    size_t c = capacity ? capacity : 1;
    d->cap = capacity;
    d->quality = -1;
    d->rec = malloc(NCH * c * sizeof(uint32_t));
    d->res = malloc(NCH * c * sizeof(uint32_t));
    d->idx = malloc(c * sizeof(uint32_t));
    d->flags = malloc(c * sizeof(uint32_t));
    d->shuf = malloc(4 * c);
    size_t zsz = ZSTD_estimateDCtxSize();
    d->zws = malloc(zsz);
    d->rix = malloc(c * sizeof(int32_t));
    d->ord = malloc(c * sizeof(uint32_t));
    d->spos = malloc(c * sizeof(uint32_t));
    d->ppos = malloc(3 * c * sizeof(float));
    d->bf = calloc(c / BLK + 1, sizeof *d->bf);
    d->tile = malloc(sizeof *d->tile);
    int bad = !d->rec || !d->res || !d->idx || !d->flags || !d->shuf || !d->zws || !d->rix || !d->ord || !d->spos ||
              !d->ppos || !d->bf || !d->tile ||
              morton_alloc(&d->mo, c) || blocks_alloc(&d->bk, c) ||
              key_alloc(&d->key[0], capacity) ||
              key_alloc(&d->key[1], capacity);
    if (!bad)
        d->z = ZSTD_initStaticDCtx(d->zws, zsz);
    if (bad || !d->z) {
        codec_dec_free(d);
        return f4d_fail(err, F4D_ENOMEM, "codec_dec_new: out of memory for %zu Gaussians", capacity);
    }
    *out = d;
    return F4D_OK;
}

void codec_dec_free(codec_dec *d)
{
    if (!d)
        return;
    free(d->rec); free(d->res); free(d->idx); free(d->flags); free(d->shuf); free(d->zws);
    morton_free(&d->mo);
    blocks_free(&d->bk);
    free(d->rix); free(d->ord); free(d->spos); free(d->ppos); free(d->bf); free(d->tile);
    key_free(&d->key[0]);
    key_free(&d->key[1]);
    free(d);
}

const char *codec_dec_error(const codec_dec *d) { return d ? d->err.msg : "codec_dec is NULL"; }
const struct splat_frame *codec_dec_frame(const codec_dec *d)
{
    return d && d->have_ref ? key_view((struct keystate *)&d->key[d->cur]) : NULL;
}
uint64_t codec_dec_time(const codec_dec *d) { return d ? d->t_us : 0; }
const struct codec_dec_stats *codec_dec_stats(const codec_dec *d) { return d ? &d->st : NULL; }
int codec_dec_quality(const codec_dec *d) { return d ? d->quality : -1; }

/* Decoder: the values of a packed plane (pack's inverse), a byte at a time
 * with the shifts known to the compiler. */
static void unpack_bits(const uint8_t *restrict s, size_t n, int bits, uint32_t *restrict v)
{
    const size_t per = (size_t)(8 / bits), full = n / per;
    const uint32_t m = (1u << bits) - 1;
    size_t i = 0;
    if (bits == 1)
        for (size_t j = 0; j < full; j++, i += 8)
            for (int k = 0; k < 8; k++)
                v[i + (size_t)k] = (uint32_t)s[j] >> k & 1u;
    else if (bits == 2)
        for (size_t j = 0; j < full; j++, i += 4)
            for (int k = 0; k < 4; k++)
                v[i + (size_t)k] = (uint32_t)s[j] >> (2 * k) & 3u;
    else
        for (size_t j = 0; j < full; j++, i += 2)
            for (int k = 0; k < 2; k++)
                v[i + (size_t)k] = (uint32_t)s[j] >> (4 * k) & 15u;
    for (; i < n; i++)
        v[i] = (uint32_t)s[i / per] >> (bits * (int)(i % per)) & m;
}

/* Decoder: shuffle's inverse, one loop per width. */
static void unshuffle(const uint8_t *restrict s, size_t n, int w, uint32_t *restrict v)
{
    const uint8_t *s1 = s + n, *s2 = s + 2 * n, *s3 = s + 3 * n;
    switch (w) {
    case 1:
        for (size_t i = 0; i < n; i++)
            v[i] = s[i];
        break;
    case 2:
        for (size_t i = 0; i < n; i++)
            v[i] = (uint32_t)s[i] | (uint32_t)s1[i] << 8;
        break;
    case 3:
        for (size_t i = 0; i < n; i++)
            v[i] = (uint32_t)s[i] | (uint32_t)s1[i] << 8 | (uint32_t)s2[i] << 16;
        break;
    default:
        for (size_t i = 0; i < n; i++)
            v[i] = (uint32_t)s[i] | (uint32_t)s1[i] << 8 | (uint32_t)s2[i] << 16 | (uint32_t)s3[i] << 24;
        break;
    }
}

/* morton: NULL where a plane may not be in Morton order, else set to
 * whether it is (tag bit 2). Version 3 adds the median-of-three transform
 * (3) and the packed widths (5-7). */
static int get_plane(codec_dec *d, const uint8_t *in, size_t len, size_t *off, size_t n, uint32_t *v,
                     const char *what, int *morton)
{
    if (len - *off < 5)
        return f4d_fail(&d->err, F4D_EFORMAT, "frame: plane %s: truncated at byte %zu", what, *off);
    int t = in[*off] & 15, w = in[*off] >> 4;
    if (morton) {
        *morton = t >> 2 & 1;
        t &= 3;
    }
    uint32_t zl = codec__u32(in + *off + 1);
    *off += 5;
    const int v3 = d->ver >= 3;
    if (t > (v3 && morton ? 3 : 2) || w < 1 || w > (v3 ? 7 : 4))
        return f4d_fail(&d->err, F4D_EFORMAT, "frame: plane %s: bad tag 0x%02x", what, in[*off - 5]);
    if (zl > len - *off)
        return f4d_fail(&d->err, F4D_EFORMAT, "frame: plane %s: %u compressed bytes, %zu left", what, zl,
                        len - *off);
    if (n == 0) {
        if (zl != 0)
            return f4d_fail(&d->err, F4D_EFORMAT, "frame: plane %s: data for 0 Gaussians", what);
        return F4D_OK;
    }
    const int bits = w > 4 ? pack_bits_of(w) : 0;
    size_t want = bits ? packed_bytes(n, bits) : n * (size_t)w;
    size_t got = ZSTD_decompressDCtx(d->z, d->shuf, want, in + *off, zl);
    if (ZSTD_isError(got) || got != want)
        return f4d_fail(&d->err, F4D_EFORMAT, "frame: plane %s: zstd gave %s, %zu bytes expected", what,
                        ZSTD_isError(got) ? ZSTD_getErrorName(got) : "a different size", want);
    *off += zl;
    if (bits)
        unpack_bits(d->shuf, n, bits, v);
    else
        unshuffle(d->shuf, n, w, v);
    if (t == 1) {
        uint32_t prev = 0;
        for (size_t i = 0; i < n; i++) {
            prev += (uint32_t)unzig(v[i]);
            v[i] = prev;
        }
    } else if (t == 2) {
        uint32_t acc = 0; /* the running sum of the signed values, zigzagged back */
        for (size_t i = 0; i < n; i++) {
            acc += (uint32_t)unzig(v[i]);
            v[i] = zig((int32_t)acc);
        }
    } else if (t == 3) {
        int32_t a = 0, b = 0, c = 0;
        for (size_t i = 0; i < n; i++) {
            int32_t x = (int32_t)((uint32_t)med3(a, b, c) + (uint32_t)unzig(v[i]));
            v[i] = zig(x);
            c = b;
            b = a;
            a = x;
        }
    }
    return F4D_OK;
}

static inline int gauss_finite(const struct keystate *k, size_t i)
{
    int ok = 1;
    for (int c = 0; c < 3; c++)
        ok &= isfinite(k->pos[3 * i + c]) && isfinite(k->ls[3 * i + c]) && k->ls[3 * i + c] < 80.0f &&
              isfinite(k->rgb[3 * i + c]) && isfinite(k->mb[3 * i + c]) && isfinite(k->mf[3 * i + c]);
    return ok;
}

/* from: the first Gaussian not yet checked (a predicted key checks its
 * Gaussians as it decodes them and passes the first bad one or count) */
static int key_finite(codec_dec *d, const struct keystate *k, size_t from)
{
    for (size_t i = from; i < k->count; i++)
        if (!gauss_finite(k, i))
            return f4d_fail(&d->err, F4D_EFORMAT, "frame: Gaussian %zu decodes to a non-finite value", i);
    return F4D_OK;
}

/* Predicted position of reference slot r: predict()'s pos, alone (the same
 * operations, so the same bits). */
static inline void predict_pos(const struct keystate *ref, size_t r, const float *cf, float pos[3])
{
    for (int c = 0; c < 3; c++) {
        float f = ref->motion ? ref->mf[3 * r + c] : 0.0f, b = ref->motion ? ref->mb[3 * r + c] : 0.0f;
        pos[c] = ref->pos[3 * r + c] + (cf[0] * f + cf[1] * b);
    }
}

/* Decoder reconstruction of a predicted key, a tile of DT Gaussians at a
 * time: the changed Gaussians' residuals (x step) are scattered into tile
 * vectors of 0 x step, then each attribute is one plain loop over the tile
 * with no branch per Gaussian (the compiler vectorizes them; rotations in
 * SoA, selects through fsel), with the operations per value of
 * resid_recon / block_mf / block_rot in the same order: the bits are the
 * encoder's. New Gaussians are computed as matched ones from reference row
 * 0 (and block 0) and then overwritten by their intra records. */
struct pctx {
    const struct keystate *ref;
    struct keystate *dst;
    const int32_t *rix;
    const uint32_t *fl, *bid, *rp[NCH];
    const float *ppos, *org;
    const struct dblk *bf;
    const uint32_t *rec;
    const struct qz *z;
    float st[NCH], rs, cf[NCOEF];
    size_t stride;
    int nch, motion, rmot, bmf, brot, bm, rot_bits;
};

/* m ? a : b for a mask m of all ones or zeros, without a branch (the
 * compiler vectorizes loops of these where it keeps a ?: as a branch). */
static inline float fsel(uint32_t m, float a, float b)
{
    uint32_t ua, ub;
    memcpy(&ua, &a, 4);
    memcpy(&ub, &b, 4);
    ua = (ua & m) | (ub & ~m);
    memcpy(&a, &ua, 4);
    return a;
}

/* q0^2 + q1^2 + q2^2 + q3^2 summed in that order (block_rot's and
 * resid_recon's loops over a quaternion: the same bits). */
static inline float sumsq4(float q0, float q1, float q2, float q3)
{
    float nn = 0.0f;
    nn += q0 * q0;
    nn += q1 * q1;
    nn += q2 * q2;
    nn += q3 * q3;
    return nn;
}

/* dst[3j + c] = R[3 ri[j] + c] over the tile; R + 3 i0 itself when the
 * tile's references are its own slots (no copy). */
static const float *gather3(const float *restrict R, const uint32_t *ri, size_t t, int ident, size_t i0,
                            float *restrict dst)
{
    if (ident)
        return R + 3 * i0;
    for (size_t j = 0; j < t; j++)
        for (int c = 0; c < 3; c++)
            dst[3 * j + c] = R[3 * (size_t)ri[j] + c];
    return dst;
}

/* Returns nonzero where a Gaussian of the tile may fail gauss_finite (the
 * caller then checks each one). Its own function: the compiler vectorizes
 * its loops there, not inlined into decode_pred. */
#define NOT_FINITE(v) (!(fabsf(v) <= 3.40282347e38f))
__attribute__((noinline)) static int pred_tile(const struct pctx *x, struct dtile *w, size_t i0, size_t t,
                                               size_t *kc, size_t *kn)
{
    int bad = 0;
    const struct keystate *ref = x->ref;
    struct keystate *dst = x->dst;
    int ident = 1, any_new = 0;
    size_t nc = 0;
    for (size_t j = 0; j < t; j++) {
        const size_t i = i0 + j;
        const int32_t r = x->rix[i];
        w->ri[j] = r < 0 ? 0u : (uint32_t)r;
        ident &= (size_t)r == i;
        any_new |= r < 0;
        w->cj[nc] = (uint32_t)j;
        nc += x->fl[i] == 1;
    }
    /* residual x step: 0 x step where unchanged, the changed Gaussians'
     * values read in plane order */
    const size_t k0 = *kc;
    *kc += nc;
    float *const d3[5] = { w->dpos, w->dls, w->drgb, w->dmb, w->dmf };
    static const int ch3[5] = { CH_POS, CH_LS, CH_RGB, CH_MB, CH_MF };
    for (int a = 0; a < 5; a++) {
        float *restrict dv = d3[a];
        float z0[3];
        for (int c = 0; c < 3; c++)
            z0[c] = 0.0f * x->st[ch3[a] + c];
        for (size_t j = 0; j < t; j++)
            for (int c = 0; c < 3; c++)
                dv[3 * j + c] = z0[c];
        if (ch3[a] >= x->nch)
            continue;
        for (int c = 0; c < 3; c++) {
            const uint32_t *restrict p = x->rp[ch3[a] + c] + k0;
            const float s = x->st[ch3[a] + c];
            for (size_t q = 0; q < nc; q++)
                dv[3 * (size_t)w->cj[q] + (size_t)c] = (float)unzig(p[q]) * s;
        }
    }
    {
        const float z0 = 0.0f * x->st[CH_OP], s = x->st[CH_OP];
        const uint32_t *restrict p = x->rp[CH_OP] + k0;
        for (size_t j = 0; j < t; j++)
            w->dop[j] = z0;
        for (size_t q = 0; q < nc; q++)
            w->dop[w->cj[q]] = (float)unzig(p[q]) * s;
    }
    memset(w->rr, 0, t * sizeof w->rr[0]);
    for (int c = 0; c < 4; c++) {
        const float z0 = 0.0f * x->rs;
        const uint32_t *restrict p = x->rp[CH_ROT + c] + k0;
        float *restrict dv = w->drot[c];
        for (size_t j = 0; j < t; j++)
            dv[j] = z0;
        for (size_t q = 0; q < nc; q++) {
            dv[w->cj[q]] = (float)unzig(p[q]) * x->rs;
            w->rr[w->cj[q]] |= p[q];
        }
    }
    /* position */
    const float *restrict pp = x->ppos + 3 * i0;
    float *restrict pos = w->pos, *restrict Dpos = dst->pos + 3 * i0;
    for (size_t j = 0; j < 3 * t; j++) {
        pos[j] = pp[j] + w->dpos[j];
        Dpos[j] = pos[j];
        bad |= NOT_FINITE(pos[j]);
    }
    /* motions */
    const float c2 = x->cf[2], c3 = x->cf[3], c4 = x->cf[4], c5 = x->cf[5], c6 = x->cf[6];
    float *restrict mf = w->mf, *restrict mb = w->mb;
    if (x->rmot) {
        const float *restrict Rf = gather3(ref->mf, w->ri, t, ident, i0, w->f);
        const float *restrict Rb = gather3(ref->mb, w->ri, t, ident, i0, w->b);
        for (size_t j = 0; j < 3 * t; j++) {
            mf[j] = c2 * Rf[j] + c3 * Rb[j];
            mb[j] = c4 * Rf[j] + c5 * Rb[j];
        }
    } else {
        const float zf = 0.0f;
        for (size_t j = 0; j < 3 * t; j++) {
            mf[j] = c2 * zf + c3 * zf;
            mb[j] = c4 * zf + c5 * zf;
        }
    }
    if (x->bm) /* a new Gaussian has no block: block 0's values, overwritten */
        for (size_t j = 0; j < t; j++)
            w->bid[j] = x->rix[i0 + j] < 0 ? 0u : x->bid[i0 + j];
    if (x->bmf)
        for (size_t j = 0; j < t; j++) {
            const struct dblk *bl = &x->bf[w->bid[j]];
            const float *o = x->org + 3 * (size_t)w->bid[j];
            float dd[3] = { pos[3 * j] - o[0], pos[3 * j + 1] - o[1], pos[3 * j + 2] - o[2] };
            for (int c = 0; c < 3; c++) {
                float v = bl->t[c];
                for (int q = 0; q < 3; q++)
                    v += bl->m[3 * c + q] * dd[q];
                mf[3 * j + c] = v;
            }
        }
    if (c6 != 0.0f) {
        const float *restrict Rp = gather3(ref->pos, w->ri, t, ident, i0, w->g);
        for (size_t j = 0; j < 3 * t; j++)
            mb[j] += c6 * (Rp[j] - pos[j]);
    }
    float *restrict Dmb = dst->mb + 3 * i0, *restrict Dmf = dst->mf + 3 * i0;
    if (x->motion) {
        for (size_t j = 0; j < 3 * t; j++) {
            Dmb[j] = mb[j] + w->dmb[j];
            Dmf[j] = mf[j] + w->dmf[j];
            bad |= NOT_FINITE(Dmb[j]) | NOT_FINITE(Dmf[j]);
        }
    } else {
        memset(Dmb, 0, 3 * t * sizeof(float));
        memset(Dmf, 0, 3 * t * sizeof(float));
    }
    /* log-scales, scales (a log-scale equal to its reference's keeps the
     * reference's scale: expf of the same bits), colours, opacity */
    {
        const float *restrict Rl = gather3(ref->ls, w->ri, t, ident, i0, w->g);
        float *restrict Dls = dst->ls + 3 * i0, *restrict Dsc = dst->scale + 3 * i0;
        for (size_t j = 0; j < 3 * t; j++) {
            Dls[j] = Rl[j] + w->dls[j];
            bad |= NOT_FINITE(Dls[j]) | !(Dls[j] < 80.0f);
        }
        const float *restrict Rs = ident ? ref->scale + 3 * i0 : NULL;
        for (size_t j = 0; j < 3 * t; j++) {
            const float ls = Dls[j];
            if (ls == Rl[j])
                Dsc[j] = Rs ? Rs[j] : ref->scale[3 * (size_t)w->ri[j / 3] + j % 3];
            else
                Dsc[j] = expf(ls);
        }
    }
    {
        const float *restrict Rc = gather3(ref->rgb, w->ri, t, ident, i0, w->g);
        float *restrict Drgb = dst->rgb + 3 * i0;
        for (size_t j = 0; j < 3 * t; j++) {
            Drgb[j] = Rc[j] + w->drgb[j];
            bad |= NOT_FINITE(Drgb[j]);
        }
    }
    {
        float *restrict Dop = dst->op + i0, *restrict g = w->g;
        const float *restrict dop = w->dop;
        const float *Ro = ref->op + i0;
        if (!ident) {
            for (size_t j = 0; j < t; j++)
                g[j] = ref->op[w->ri[j]];
            Ro = g;
        }
        for (size_t j = 0; j < t; j++) {
            const float v = Ro[j] + dop[j];
            Dop[j] = fsel(0u - (uint32_t)(v < 0.0f), 0.0f, fsel(0u - (uint32_t)(v > 1.0f), 1.0f, v)); /* clamp01 */
        }
    }
    /* rotations, split: block dq times the reference, then the residual */
    float *restrict a0 = w->qa[0], *restrict a1 = w->qa[1], *restrict a2 = w->qa[2], *restrict a3 = w->qa[3];
    for (size_t j = 0; j < t; j++) {
        const float *q = ref->rot + 4 * (size_t)w->ri[j];
        a0[j] = q[0];
        a1[j] = q[1];
        a2[j] = q[2];
        a3[j] = q[3];
    }
    if (x->brot) {
        float *restrict e0 = w->qd[0], *restrict e1 = w->qd[1], *restrict e2 = w->qd[2], *restrict e3 = w->qd[3],
                        *restrict bq = w->qb;
        for (size_t j = 0; j < t; j++) {
            const struct dblk *bl = &x->bf[w->bid[j]];
            e0[j] = bl->dq[0];
            e1[j] = bl->dq[1];
            e2[j] = bl->dq[2];
            e3[j] = bl->dq[3];
            bq[j] = bl->rot ? 1.0f : 0.0f;
        }
        for (size_t j = 0; j < t; j++) {
            const float q0 = e0[j] * a0[j] - e1[j] * a1[j] - e2[j] * a2[j] - e3[j] * a3[j];
            const float q1 = e0[j] * a1[j] + e1[j] * a0[j] + e2[j] * a3[j] - e3[j] * a2[j];
            const float q2 = e0[j] * a2[j] - e1[j] * a3[j] + e2[j] * a0[j] + e3[j] * a1[j];
            const float q3 = e0[j] * a3[j] + e1[j] * a2[j] - e2[j] * a1[j] + e3[j] * a0[j];
            const float nn = sumsq4(q0, q1, q2, q3);
            const float inv = 1.0f / sqrtf(nn);
            /* block_rot: n = nn > 1e-30 ? inv : 0, used where n != 0 */
            const uint32_t use = 0u - (uint32_t)((bq[j] != 0.0f) & (nn > 1e-30f) & (inv != 0.0f));
            a0[j] = fsel(use, q0 * inv, a0[j]);
            a1[j] = fsel(use, q1 * inv, a1[j]);
            a2[j] = fsel(use, q2 * inv, a2[j]);
            a3[j] = fsel(use, q3 * inv, a3[j]);
        }
    }
    {
        const float *restrict r0 = w->drot[0], *restrict r1 = w->drot[1], *restrict r2 = w->drot[2],
                              *restrict r3 = w->drot[3];
        const uint32_t *restrict rr = w->rr;
        for (size_t j = 0; j < t; j++) {
            const float q0 = a0[j] + r0[j], q1 = a1[j] + r1[j], q2 = a2[j] + r2[j], q3 = a3[j] + r3[j];
            const float nn = sumsq4(q0, q1, q2, q3);
            const float inv = 1.0f / sqrtf(nn);
            const uint32_t has = 0u - (uint32_t)(rr[j] != 0), ok = 0u - (uint32_t)(nn > 1e-30f);
            a0[j] = fsel(has, fsel(ok, q0 * inv, 1.0f), a0[j]);
            a1[j] = fsel(has, fsel(ok, q1 * inv, 0.0f), a1[j]);
            a2[j] = fsel(has, fsel(ok, q2 * inv, 0.0f), a2[j]);
            a3[j] = fsel(has, fsel(ok, q3 * inv, 0.0f), a3[j]);
        }
        float *restrict Dr = dst->rot + 4 * i0;
        for (size_t j = 0; j < t; j++) {
            Dr[4 * j] = a0[j];
            Dr[4 * j + 1] = a1[j];
            Dr[4 * j + 2] = a2[j];
            Dr[4 * j + 3] = a3[j];
        }
    }
    if (any_new)
        for (size_t j = 0; j < t; j++) {
            const size_t i = i0 + j;
            if (x->rix[i] >= 0)
                continue;
            intra_recon(x->rec, x->stride, (*kn)++, x->z, x->rot_bits, x->motion, dst, i);
            for (int c = 0; c < 3; c++)
                dst->scale[3 * i + c] = expf(dst->ls[3 * i + c]);
            bad |= !gauss_finite(dst, i);
        }
    return bad;
}

/* Intra key Gaussians [i0, i0 + t): intra_recon's values and their scales
 * (expf of the log-scales, as finish_scales), a channel at a time with no
 * branch per Gaussian (rot_unpack in SoA through fsel: the same operations,
 * so the same bits). Returns nonzero where one may fail gauss_finite. */
__attribute__((noinline)) static int intra_tile(struct dtile *w, const uint32_t *rec, size_t stride, size_t i0,
                                                size_t t, const struct qz *z, int rot_bits, int motion,
                                                struct keystate *k)
{
    int bad = 0;
    float *const out3[5] = { k->pos, k->ls, k->rgb, k->mb, k->mf };
    static const int ch3[5] = { CH_POS, CH_LS, CH_RGB, CH_MB, CH_MF };
    static const int qz3[5] = { 0, 3, 7, QZ_MB, QZ_MF };
    for (int a = 0; a < 5; a++) {
        float *restrict o = out3[a] + 3 * i0;
        if (ch3[a] >= CH_MB && !motion) {
            memset(o, 0, 3 * t * sizeof(float));
            continue;
        }
        float *v[3] = { w->qd[0], w->qd[1], w->qd[2] }; /* the channels, then interleaved */
        for (int c = 0; c < 3; c++) {
            const uint32_t *restrict q = rec + (size_t)(ch3[a] + c) * stride + i0;
            const struct qz zc = z[qz3[a] + c];
            float *restrict vc = v[c];
            uint32_t hi = 0;
            for (size_t j = 0; j < t; j++)
                hi |= q[j];
            if (hi >> 31) /* (float) of an unsigned: slow without AVX-512 */
                for (size_t j = 0; j < t; j++)
                    vc[j] = deq(zc, q[j]);
            else /* the same value through a signed int */
                for (size_t j = 0; j < t; j++)
                    vc[j] = zc.lo + (float)(int32_t)q[j] * zc.step;
            for (size_t j = 0; j < t; j++)
                bad |= NOT_FINITE(vc[j]);
            if (a == 1)
                for (size_t j = 0; j < t; j++)
                    bad |= !(vc[j] < 80.0f);
        }
        const float *restrict v0 = v[0], *restrict v1 = v[1], *restrict v2 = v[2];
        for (size_t j = 0; j < t; j++) {
            o[3 * j] = v0[j];
            o[3 * j + 1] = v1[j];
            o[3 * j + 2] = v2[j];
        }
    }
    float *restrict sc = k->scale + 3 * i0;
    const float *restrict ls = k->ls + 3 * i0;
    for (size_t j = 0; j < 3 * t; j++)
        sc[j] = expf(ls[j]);
    {
        const uint32_t *restrict q = rec + (size_t)CH_OP * stride + i0;
        float *restrict o = k->op + i0;
        uint32_t hi = 0;
        for (size_t j = 0; j < t; j++)
            hi |= q[j];
        for (size_t j = 0; j < t; j++) {
            const float v = hi >> 31 ? deq(z[6], q[j]) : z[6].lo + (float)(int32_t)q[j] * z[6].step;
            o[j] = fsel(0u - (uint32_t)(v < 0.0f), 0.0f, fsel(0u - (uint32_t)(v > 1.0f), 1.0f, v)); /* clamp01 */
        }
    }
    const uint32_t *restrict qb = rec + (size_t)CH_ROT * stride + i0, *restrict q1 = qb + stride,
                             *restrict q2 = q1 + stride, *restrict q3 = q2 + stride;
    const uint32_t um = (1u << rot_bits) - 1;
    const float m = (float)um;
    float *restrict a0 = w->qa[0], *restrict a1 = w->qa[1], *restrict a2 = w->qa[2], *restrict a3 = w->qa[3];
    for (size_t j = 0; j < t; j++) {
        const uint32_t big = qb[j] & 3;
        const uint32_t u1 = q1[j] > um ? um : q1[j], u2 = q2[j] > um ? um : q2[j], u3 = q3[j] > um ? um : q3[j];
        /* u <= 32767: (float) through a signed int is the same value */
        const float v1 = ((float)(int32_t)u1 / m * 2.0f - 1.0f) * 0.70710678f;
        const float v2 = ((float)(int32_t)u2 / m * 2.0f - 1.0f) * 0.70710678f;
        const float v3 = ((float)(int32_t)u3 / m * 2.0f - 1.0f) * 0.70710678f;
        float ss = 0;
        ss += v1 * v1;
        ss += v2 * v2;
        ss += v3 * v3;
        const float wq = sqrtf(fsel(0u - (uint32_t)(ss < 1.0f), 1.0f - ss, 0.0f));
        /* component k: the largest (big) or the next of v1 v2 v3 */
        const uint32_t b0 = 0u - (uint32_t)(big == 0), b1 = 0u - (uint32_t)(big == 1),
                       b2 = 0u - (uint32_t)(big == 2), b3 = 0u - (uint32_t)(big == 3);
        a0[j] = fsel(b0, wq, v1);
        a1[j] = fsel(b1, wq, fsel(b0, v1, v2));
        a2[j] = fsel(b2, wq, fsel(b3, v3, v2));
        a3[j] = fsel(b3, wq, v3);
    }
    float *restrict r = k->rot + 4 * i0;
    for (size_t j = 0; j < t; j++) {
        r[4 * j] = a0[j];
        r[4 * j + 1] = a1[j];
        r[4 * j + 2] = a2[j];
        r[4 * j + 3] = a3[j];
    }
    return bad;
}

/* Predicted key. One pass validates flags and references (rix: the
 * reference of each Gaussian, -1 new; ord: a changed one's ordinal), the
 * planes are read, then every matched Gaussian's predicted position is
 * computed once and sorted once: the residual planes' Morton order is the
 * blocks' order restricted to the changed Gaussians (same keys, a stable
 * sort). Blocks are turned into floats once (dblk: the products block_mf
 * and block_rot form per Gaussian, the same operations), and the
 * reconstruction is one loop doing predict + block_mf + block_rot +
 * resid_recon's arithmetic in the same order, so the bits are the
 * encoder's. A scale whose log-scale is its reference's is the reference's
 * scale (expf of the same bits). */
static int decode_pred(codec_dec *d, const uint8_t *in, size_t len, size_t *off, size_t n, size_t nref,
                       size_t n_new, size_t n_changed, int explicit_match, int block_motion, int block_mf_used,
                       int block_rot_used, int rot_bits, int motion, const float *cf, const struct qz *z,
                       const struct keystate *ref, struct keystate *dst)
{
    const size_t stride = d->cap ? d->cap : 1;
    const int nch = motion ? NCH : CH_MB;
    int rc, mort[NCH] = { 0 };
    char what[16];
    if (explicit_match && (rc = get_plane(d, in, len, off, n, d->idx, "index", NULL)) < 0)
        return rc;
    if ((rc = get_plane(d, in, len, off, n, d->flags, "flags", NULL)) < 0)
        return rc;
    size_t kc = 0, kn = 0;
    int64_t prev = -1;
    for (size_t i = 0; i < n; i++) {
        uint32_t fl = d->flags[i];
        if (fl > 2)
            return f4d_fail(&d->err, F4D_EFORMAT, "frame: Gaussian %zu: flag %u", i, fl);
        if (fl == 2) {
            d->rix[i] = -1;
            kn++;
            continue;
        }
        int64_t r = explicit_match ? prev + 1 + unzig(d->idx[i]) : (int64_t)i;
        if (r < 0 || r >= (int64_t)nref)
            return f4d_fail(&d->err, F4D_EFORMAT, "frame: Gaussian %zu: reference index %lld of %zu", i,
                            (long long)r, nref);
        prev = r;
        d->rix[i] = (int32_t)r;
        d->ord[i] = (uint32_t)kc;
        kc += fl;
    }
    if (kc != n_changed || kn != n_new)
        return f4d_fail(&d->err, F4D_EFORMAT, "frame: flags name %zu changed / %zu new, header %zu / %zu", kc, kn,
                        n_changed, n_new);
    const size_t m = n - n_new; /* matched */
    struct blocks *bk = &d->bk;
    if (block_motion) {
        bk->nb = (m + BLK - 1) / BLK;
        for (int k = 0; k < NBP; k++) {
            uint32_t *v = bk->par + (size_t)k * bk->nbmax;
            int mo = 0;
            snprintf(what, sizeof what, "b%d", k);
            if ((rc = get_plane(d, in, len, off, bk->nb, v, what, &mo)) < 0)
                return rc;
            if (mo)
                return f4d_fail(&d->err, F4D_EFORMAT, "frame: plane %s: Morton flag on block parameters", what);
            for (size_t j = 0; j < bk->nb; j++)
                if (unzig(v[j]) > BPAR_MAX || unzig(v[j]) < -BPAR_MAX)
                    return f4d_fail(&d->err, F4D_EFORMAT, "frame: block %zu: parameter %d = %d out of range", j, k,
                                    unzig(v[j]));
        }
    }
    for (int c = 0; c < nch; c++) {
        snprintf(what, sizeof what, "r%d", c);
        if ((rc = get_plane(d, in, len, off, n_changed, d->res + (size_t)c * stride, what,
                            d->ver >= 2 ? &mort[c] : NULL)) < 0)
            return rc;
    }
    for (int c = 0; c < nch; c++) {
        snprintf(what, sizeof what, "n%d", c);
        if ((rc = get_plane(d, in, len, off, n_new, d->rec + (size_t)c * stride, what, NULL)) < 0)
            return rc;
    }
    int any_mort = 0;
    for (int c = 0; c < nch; c++)
        any_mort |= mort[c];
    any_mort = any_mort && n_changed;
    float *pp = d->ppos;
    struct morton *mo = &d->mo;
    struct mgrid mg;
    mgrid_of(z, &mg);
    /* with blocks, every matched Gaussian's key as its prediction is made;
     * the sort carries its index and, in the top bit, whether it changed
     * (n <= CODEC_CAPACITY_MAX < 2^31) */
    size_t k = 0;
    for (size_t i = 0; i < n; i++)
        if (d->rix[i] >= 0) {
            predict_pos(ref, (size_t)d->rix[i], cf, pp + 3 * i);
            if (block_motion) {
                mo->key[k] = morton_key_grid(&mg, pp + 3 * i);
                mo->perm[k++] = (uint32_t)i | (uint32_t)(d->flags[i] == 1) << 31;
            }
        } else {
            pp[3 * i] = pp[3 * i + 1] = pp[3 * i + 2] = 0.0f; /* read by pred_tile, then overwritten */
        }
    uint32_t *spos = d->spos; /* changed ordinal -> slot in the residual planes */
    if (block_motion) {
        morton_sort_with(mo, m);
        size_t kk = 0;
        for (k = 0; k < m; k++) {
            const uint32_t u = mo->perm[k], i = u & 0x7fffffffu;
            bk->id[i] = (uint32_t)(k / BLK);
            if (k % BLK == 0)
                memcpy(bk->org + 3 * (k / BLK), pp + 3 * (size_t)i, 3 * sizeof(float));
            if (u >> 31)
                spos[d->ord[i]] = (uint32_t)kk++;
        }
        /* t was sent against its prediction from the block before */
        blocks_units(bk, z, rot_bits);
        for (size_t j = 0; j < bk->nb; j++)
            for (int c = 0; c < 3; c++) {
                uint32_t *t = bk->par + (size_t)c * bk->nbmax + j;
                int64_t a = (int64_t)unzig(*t) + block_t_pred(bk, j, c);
                if (a > BPAR_MAX || a < -BPAR_MAX)
                    return f4d_fail(&d->err, F4D_EFORMAT, "frame: block %zu: t%d = %lld out of range", j, c,
                                    (long long)a);
                *t = zig((int32_t)a);
            }
        const size_t s = bk->nbmax;
        for (size_t j = 0; j < bk->nb; j++) {
            struct dblk *b = &d->bf[j];
            for (int c = 0; c < 3; c++) {
                b->t[c] = (float)unzig(bk->par[(size_t)c * s + j]) * bk->ut[c];
                for (int k2 = 0; k2 < 3; k2++)
                    b->m[3 * c + k2] = (float)unzig(bk->par[(size_t)(3 + 3 * c + k2) * s + j]) * bk->um[c];
            }
            float ss = 0;
            for (int c = 0; c < 3; c++) {
                b->dq[1 + c] = (float)unzig(bk->par[(size_t)(12 + c) * s + j]) * bk->uq;
                ss += b->dq[1 + c] * b->dq[1 + c];
            }
            b->rot = ss != 0.0f;
            b->dq[0] = sqrtf(ss < 1.0f ? 1.0f - ss : 0.0f);
        }
    } else if (any_mort) {
        k = 0;
        for (size_t i = 0; i < n; i++)
            if (d->flags[i] == 1)
                mo->key[k++] = morton_key_grid(&mg, pp + 3 * i);
        morton_sort(mo, n_changed);
        for (k = 0; k < n_changed; k++)
            spos[mo->perm[k]] = (uint32_t)k;
    }
    /* the Morton planes back in index order: one plane at a time, its
     * random reads stay within one plane (cache-resident at display sizes) */
    if (any_mort)
        for (int c = 0; c < nch; c++) {
            if (!mort[c])
                continue;
            uint32_t *v = d->res + (size_t)c * stride, *tmp = mo->tmp;
            memcpy(tmp, v, n_changed * sizeof(uint32_t));
            for (k = 0; k < n_changed; k++)
                v[k] = tmp[spos[k]];
        }
    struct qz zr[NQZ];
    residual_qz(z, block_mf_used, zr);
    struct pctx x = { .ref = ref, .dst = dst, .rix = d->rix, .fl = d->flags, .bid = bk->id, .ppos = d->ppos,
                      .org = bk->org, .bf = d->bf, .rec = d->rec, .z = z, .rs = rot_step(rot_bits),
                      .stride = stride, .nch = nch, .motion = motion, .rmot = ref->motion,
                      .bmf = block_motion && block_mf_used, .brot = block_motion && block_rot_used,
                      .bm = block_motion, .rot_bits = rot_bits };
    memcpy(x.cf, cf, sizeof x.cf);
    for (int c = 0; c < NCH; c++)
        x.rp[c] = d->res + (size_t)c * stride;
    for (int c = 0; c < 3; c++) {
        x.st[CH_POS + c] = zr[c].step;
        x.st[CH_LS + c] = zr[3 + c].step;
        x.st[CH_RGB + c] = zr[7 + c].step;
        x.st[CH_MB + c] = zr[QZ_MB + c].step;
        x.st[CH_MF + c] = zr[QZ_MF + c].step;
    }
    x.st[CH_OP] = zr[6].step;
    for (int c = 0; c < 4; c++)
        x.st[CH_ROT + c] = x.rs;
    kc = 0;
    kn = 0;
    size_t i = 0;
    while (i < n) {
        const size_t t = n - i < DT ? n - i : DT;
        if (pred_tile(&x, d->tile, i, t, &kc, &kn)) {
            size_t j = i;
            while (j < i + t && gauss_finite(dst, j))
                j++;
            if (j < i + t) {
                i = j; /* key_finite names it */
                break;
            }
        }
        i += t;
    }
    d->checked = i;
    return F4D_OK;
}

static int decode_key(codec_dec *d, const struct codec_packet *p, int intra)
{
    const uint8_t *in = p->payload;
    const size_t fhdr = p->version >= 2 ? FHDR : FHDR1;
    d->ver = p->version;
    size_t len = p->payload_len, off = fhdr + 8 * NQZ;
    if (len < off)
        return f4d_fail(&d->err, F4D_EFORMAT, "frame: %zu bytes, the header needs %zu", len, off);
    if (in[0] != (intra ? 1 : 2))
        return f4d_fail(&d->err, F4D_EFORMAT, "frame: kind %u does not match packet type %d", in[0], p->type);
    int motion = in[2] & 1, explicit_match = in[2] >> 1 & 1, block_motion = in[2] >> 2 & 1,
        block_mf_used = in[2] >> 3 & 1, block_rot_used = in[2] >> 4 & 1, rot_bits = in[3];
    const int flag_mask = p->version >= 3 ? 31 : 3;
    if (in[1] >= CODEC_QUALITY_COUNT || (in[2] & ~flag_mask) || rot_bits < 4 || rot_bits > 15 ||
        (block_motion && (intra || !motion)) || block_motion != (block_mf_used | block_rot_used))
        return f4d_fail(&d->err, F4D_EFORMAT, "frame: bad quality %u, flags 0x%02x or rotation bits %d", in[1],
                        in[2], rot_bits);
    size_t n = codec__u32(in + 4), nref = codec__u32(in + 8), n_new = codec__u32(in + 12),
           n_changed = codec__u32(in + 16);
    if (n > d->cap)
        return f4d_fail(&d->err, F4D_ERANGE, "frame: %zu Gaussians exceed the decoder's capacity %zu", n, d->cap);
    if (n_new > n || n_changed > n - n_new || (intra && (n_new != n || n_changed || nref || explicit_match)))
        return f4d_fail(&d->err, F4D_EFORMAT, "frame: inconsistent counts (%zu, %zu new, %zu changed)", n, n_new,
                        n_changed);
    struct keystate *ref = &d->key[d->cur], *dst = &d->key[d->cur ^ 1];
    if (!intra && nref != ref->count)
        return f4d_fail(&d->err, F4D_EFORMAT, "frame: reference of %zu Gaussians, the decoder holds %zu", nref,
                        ref->count);
    float cf[NCOEF];
    memcpy(cf, coef_v1, sizeof cf);
    if (p->version >= 2)
        for (int k = 0; k < NCOEF; k++) {
            cf[k] = codec__f32(in + FHDR1 + 4 * k);
            if (!(fabsf(cf[k]) <= COEF_MAX))
                return f4d_fail(&d->err, F4D_EFORMAT, "frame: predictor coefficient %d (%g) outside +-%g", k,
                                (double)cf[k], (double)COEF_MAX);
        }
    struct qz z[NQZ];
    for (int k = 0; k < NQZ; k++) {
        z[k].lo = codec__f32(in + fhdr + 8 * k);
        z[k].step = codec__f32(in + fhdr + 8 * k + 4);
        if (!isfinite(z[k].lo) || !isfinite(z[k].step) || z[k].step < 0 || fabsf(z[k].lo) > 1e18f ||
            z[k].step > 1e10f)
            return f4d_fail(&d->err, F4D_EFORMAT, "frame: quantizer %d (%g, %g) out of range", k, (double)z[k].lo,
                            (double)z[k].step);
    }
    const int nch = motion ? NCH : CH_MB;
    const size_t stride = d->cap ? d->cap : 1;
    int rc, intra_bad = 0;
    char what[16];
    dst->count = n;
    dst->motion = motion;
    if (intra) {
        for (int c = 0; c < nch; c++) {
            snprintf(what, sizeof what, "%d", c);
            if ((rc = get_plane(d, in, len, &off, n, d->rec + (size_t)c * stride, what, NULL)) < 0)
                return rc;
        }
        for (size_t i = 0; i < n; i += DT)
            intra_bad |= intra_tile(d->tile, d->rec, stride, i, n - i < DT ? n - i : DT, z, rot_bits, motion, dst);
    } else {
        if ((rc = decode_pred(d, in, len, &off, n, nref, n_new, n_changed, explicit_match, block_motion,
                              block_mf_used, block_rot_used, rot_bits, motion, cf, z, ref, dst)) < 0)
            return rc;
    }
    if (off != len)
        return f4d_fail(&d->err, F4D_EFORMAT, "frame: %zu trailing bytes", len - off);
    /* intra: every Gaussian was found finite as decoded unless intra_bad */
    if ((rc = key_finite(d, dst, intra ? (intra_bad ? 0 : n) : d->checked)) < 0)
        return rc;
    return F4D_OK;
}

int codec_dec_packet(codec_dec *d, const struct codec_packet *p)
{
    if (!d)
        return F4D_EINVAL;
    if (!p || (!p->payload && p->payload_len))
        return f4d_fail(&d->err, F4D_EINVAL, "codec_dec_packet: NULL packet");
    d->st.packets++;
    if (d->have_seq) {
        uint32_t gap = p->seq - d->last_seq - 1;
        if (gap != 0 && gap < 0x80000000u)
            d->st.lost += gap;
    }
    d->have_seq = 1;
    d->last_seq = p->seq;
    switch (p->type) {
    case CODEC_PKT_STREAM:
        if (p->payload_len < 12 || codec__u32(p->payload) < 1 || codec__u32(p->payload) > CODEC_VERSION ||
            codec__u32(p->payload + 4) >= CODEC_QUALITY_COUNT) {
            d->st.refused++;
            return f4d_fail(&d->err, F4D_EFORMAT, "stream header: bad version or quality");
        }
        d->quality = (int)codec__u32(p->payload + 4);
        return 0;
    case CODEC_PKT_END:
        return 0;
    case CODEC_PKT_INTRA:
    case CODEC_PKT_PRED: {
        int intra = p->type == CODEC_PKT_INTRA;
        if (!intra && (!d->have_ref || p->ref_seq != d->key_seq)) {
            d->st.skipped++;
            return 0;
        }
        struct codec_packet q = *p;
        if (q.version == 0) /* built by hand, not parsed: the current version */
            q.version = CODEC_VERSION;
        int rc = decode_key(d, &q, intra);
        if (rc < 0) {
            d->st.refused++;
            d->have_ref = 0;
            f4d_err_prefix(&d->err, "packet seq %u", p->seq);
            return rc;
        }
        d->cur ^= 1;
        d->have_ref = 1;
        d->key_seq = p->seq;
        d->t_us = p->t_us;
        if (intra)
            d->st.intra++;
        else
            d->st.predicted++;
        return 1;
    }
    default:
        d->st.refused++;
        return f4d_fail(&d->err, F4D_EFORMAT, "packet: unknown type %d", p->type);
    }
}

int codec_packet_gaussians(const struct codec_packet *p, size_t *n, struct f4d_err *err)
{
    if (!p || !n || (!p->payload && p->payload_len))
        return f4d_fail(err, F4D_EINVAL, "codec_packet_gaussians: NULL argument");
    switch (p->type) {
    case CODEC_PKT_STREAM:
        if (p->payload_len < 12)
            return f4d_fail(err, F4D_EFORMAT, "stream header: %zu bytes, 12 needed", p->payload_len);
        *n = codec__u32(p->payload + 8);
        break;
    case CODEC_PKT_INTRA:
    case CODEC_PKT_PRED:
        if (p->payload_len < FHDR)
            return f4d_fail(err, F4D_EFORMAT, "frame: %zu bytes, the header needs %d", p->payload_len, FHDR);
        *n = codec__u32(p->payload + 4); /* the frame header's count, as decode_key reads it */
        break;
    default:
        return f4d_fail(err, F4D_EFORMAT, "packet type %d carries no Gaussian count", p->type);
    }
    if (*n > CODEC_CAPACITY_MAX)
        return f4d_fail(err, F4D_ERANGE, "packet seq %u: %zu Gaussians exceed %zu", p->seq, *n,
                        (size_t)CODEC_CAPACITY_MAX);
    return F4D_OK;
}
