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
#define FHDR       20
#define ZLEVEL     5
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
};

const struct codec_quality_info *codec_quality_get(enum codec_quality q)
{
    return (unsigned)q < CODEC_QUALITY_COUNT ? &qtab[q] : NULL;
}

int codec_quality_from_name(const char *name, struct f4d_err *err)
{
    for (int i = 0; i < CODEC_QUALITY_COUNT; i++)
        if (name && !strcmp(name, qtab[i].name))
            return i;
    return f4d_fail(err, F4D_EINVAL, "quality '%s' is not one of low, medium, high", name ? name : "(null)");
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
    k->pos = malloc(3 * c * sizeof(float));
    k->ls = malloc(3 * c * sizeof(float));
    k->scale = malloc(3 * c * sizeof(float));
    k->rot = malloc(4 * c * sizeof(float));
    k->op = malloc(c * sizeof(float));
    k->rgb = malloc(3 * c * sizeof(float));
    k->mb = malloc(3 * c * sizeof(float));
    k->mf = malloc(3 * c * sizeof(float));
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

static inline uint32_t quant(struct qz z, float v)
{
    double t = ((double)v - (double)z.lo) / (double)z.step;
    if (!(t > 0))
        return 0;
    if (t > (double)QMAX)
        return QMAX;
    return (uint32_t)llround(t);
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
    return (int32_t)llround(t);
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
/* Planes. */

struct planebuf {
    uint8_t  *shuf;   /* [4 * cap] */
    uint32_t *tmp;    /* [cap]     */
    uint8_t  *zalt;   /* [zbound]  */
    size_t    zbound;
};

static int width_of(uint32_t mx) { return mx < 0x100u ? 1 : mx < 0x10000u ? 2 : mx < 0x1000000u ? 3 : 4; }

static void shuffle(const uint32_t *v, size_t n, int w, uint8_t *o)
{
    for (int b = 0; b < w; b++)
        for (size_t i = 0; i < n; i++)
            o[(size_t)b * n + i] = (uint8_t)(v[i] >> (8 * b));
}

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
    struct planebuf pb;
    void *zws;
    ZSTD_CCtx *z;
    struct codec_enc_stats st;
};

/* Writes one plane at out[*off]: tag, compressed length, zstd bytes; keeps the
 * smaller of raw and delta when delta is allowed. */
static int put_plane(codec_enc *e, const uint32_t *v, size_t n, int allow_delta, uint8_t *out, size_t cap,
                     size_t *off)
{
    if (cap < *off + 5)
        return f4d_fail(&e->err, F4D_ERANGE, "encode: output buffer too small");
    uint8_t *tag = out + *off;
    size_t room = cap - *off - 5;
    if (n == 0) {
        tag[0] = 1 << 4;
        codec__put_u32(tag + 1, 0);
        *off += 5;
        return F4D_OK;
    }
    uint32_t mx = 0;
    for (size_t i = 0; i < n; i++)
        mx = v[i] > mx ? v[i] : mx;
    int w = width_of(mx);
    shuffle(v, n, w, e->pb.shuf);
    size_t z1 = ZSTD_compressCCtx(e->z, tag + 5, room, e->pb.shuf, n * (size_t)w, ZLEVEL);
    if (ZSTD_isError(z1))
        return f4d_fail(&e->err, F4D_ERANGE, "encode: zstd: %s", ZSTD_getErrorName(z1));
    int t = 0;
    if (allow_delta) {
        uint32_t dm = 0, prev = 0;
        for (size_t i = 0; i < n; i++) {
            uint32_t d = zig((int32_t)(v[i] - prev));
            prev = v[i];
            e->pb.tmp[i] = d;
            dm = d > dm ? d : dm;
        }
        int w2 = width_of(dm);
        shuffle(e->pb.tmp, n, w2, e->pb.shuf);
        size_t z2 = ZSTD_compressCCtx(e->z, e->pb.zalt, e->pb.zbound, e->pb.shuf, n * (size_t)w2, ZLEVEL);
        if (!ZSTD_isError(z2) && z2 < z1 && z2 <= room) {
            memcpy(tag + 5, e->pb.zalt, z2);
            z1 = z2;
            w = w2;
            t = 1;
        }
    }
    tag[0] = (uint8_t)(t | w << 4);
    codec__put_u32(tag + 1, (uint32_t)z1);
    *off += 5 + z1;
    return F4D_OK;
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
    e->rec = malloc(NCH * c * sizeof(uint32_t));
    e->res = malloc(NCH * c * sizeof(uint32_t));
    e->idx = malloc(c * sizeof(uint32_t));
    e->flags = malloc(c * sizeof(uint32_t));
    e->pb.shuf = malloc(4 * c);
    e->pb.tmp = malloc(c * sizeof(uint32_t));
    e->pb.zbound = ZSTD_compressBound(4 * c);
    e->pb.zalt = malloc(e->pb.zbound);
    size_t zsz = ZSTD_estimateCCtxSize(ZLEVEL);
    e->zws = malloc(zsz);
    int bad = !e->rec || !e->res || !e->idx || !e->flags || !e->pb.shuf || !e->pb.tmp || !e->pb.zalt || !e->zws ||
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
    free(e->rec); free(e->res); free(e->idx); free(e->flags);
    free(e->pb.shuf); free(e->pb.tmp); free(e->pb.zalt); free(e->zws);
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

int codec_enc_stream_header(codec_enc *e, uint64_t t_us, uint8_t *out, size_t cap, size_t *len)
{
    uint8_t pl[12];
    codec__put_u32(pl, CODEC_VERSION);
    codec__put_u32(pl + 4, (uint32_t)e->q);
    codec__put_u32(pl + 8, (uint32_t)e->cap);
    uint32_t s = e->seq;
    int rc = codec_packet_write(out, cap, CODEC_PKT_STREAM, s, s, t_us, pl, sizeof pl, len, &e->err);
    if (rc == 0)
        e->seq++;
    return rc;
}

int codec_enc_end(codec_enc *e, uint64_t t_us, uint8_t *out, size_t cap, size_t *len)
{
    uint32_t s = e->seq;
    int rc = codec_packet_write(out, cap, CODEC_PKT_END, s, s, t_us, NULL, 0, len, &e->err);
    if (rc == 0)
        e->seq++;
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

static void log_scale(const float *s, float *ls)
{
    for (int k = 0; k < 3; k++)
        ls[k] = logf(s[k] > SCALE_MIN ? s[k] : SCALE_MIN);
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
struct pred { float pos[3], ls[3], op, rgb[3], rot[4], mb[3], mf[3]; };

static void predict(const struct keystate *ref, size_t r, struct pred *p)
{
    for (int c = 0; c < 3; c++) {
        float m = ref->motion ? ref->mf[3 * r + c] : 0.0f;
        p->pos[c] = ref->pos[3 * r + c] + m;
        p->ls[c] = ref->ls[3 * r + c];
        p->rgb[c] = ref->rgb[3 * r + c];
        p->mb[c] = -m;
        p->mf[c] = m;
    }
    p->op = ref->op[r];
    for (int c = 0; c < 4; c++)
        p->rot[c] = ref->rot[4 * r + c];
}

/* Applies residual record (all zero = copy) to the prediction into slot j. */
static void resid_recon(const int32_t r[NCH], const struct pred *p, const struct qz *z, int rot_bits, int motion,
                        struct keystate *k, size_t j)
{
    float rs = rot_step(rot_bits);
    for (int c = 0; c < 3; c++) {
        k->pos[3 * j + c] = dres(p->pos[c], z[c], r[CH_POS + c]);
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
static void intra_record(const struct splat_frame *f, size_t i, const struct qz *z, int rot_bits, int motion,
                         uint32_t *rec, size_t stride, size_t j)
{
    float ls[3];
    log_scale(f->scale + 3 * i, ls);
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
    int intra = mode == CODEC_KEY_INTRA || !e->have_ref;
    if (match && !intra)
        for (size_t i = 0; i < n; i++)
            if (match[i] < -1 || (match[i] >= 0 && (size_t)match[i] >= ref->count))
                return f4d_fail(&e->err, F4D_EINVAL, "codec_enc_key: match[%zu] = %d, the reference has %zu",
                                i, match[i], ref->count);

    /* Quantizers from this frame's ranges. */
    struct qz z[NQZ];
    for (int c = 0; c < 3; c++) {
        float lo, hi;
        range_of(f->pos + c, n, 3, &lo, &hi);
        z[c] = make_qz(lo, hi, qi->pos_bits_min, qi->pos_step_max);
        float llo = 0, lhi = 0;
        for (size_t i = 0; i < n; i++) {
            float s = logf(f->scale[3 * i + c] > SCALE_MIN ? f->scale[3 * i + c] : SCALE_MIN);
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
    uint8_t *pl = out + CODEC_PACKET_HEADER;
    size_t off = FHDR + 8 * NQZ;
    if (cap < CODEC_PACKET_HEADER + off)
        return f4d_fail(&e->err, F4D_ERANGE, "codec_enc_key: output buffer of %zu bytes too small", cap);
    size_t pcap = cap - CODEC_PACKET_HEADER;
    size_t n_changed = 0, n_new = 0, n_same = 0, matched = 0;
    int explicit_match = 0;
    dst->count = n;
    dst->motion = motion;

    if (intra) {
        for (size_t i = 0; i < n; i++) {
            intra_record(f, i, z, qi->rot_bits, motion, e->rec, stride, i);
            intra_recon(e->rec, stride, i, z, qi->rot_bits, motion, dst, i);
        }
        n_new = n;
        for (int c = 0; c < nch; c++) {
            size_t o0 = off;
            if ((rc = put_plane(e, e->rec + (size_t)c * stride, n, 1, pl, pcap, &off)) < 0)
                return rc;
            size_t *g[3] = { &e->st.bytes_pos, &e->st.bytes_attr, &e->st.bytes_motion };
            *g[stat_group(c)] += off - o0;
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
        float rs = rot_step(qi->rot_bits);
        float pos_tol[3];
        for (int c = 0; c < 3; c++)
            pos_tol[c] = 0.5f * (z[c].step > qi->pos_step_max ? z[c].step : qi->pos_step_max);
        int32_t prev = -1;
        for (size_t i = 0; i < n; i++) {
            int32_t r = match ? match[i] : (i < ref->count ? (int32_t)i : -1);
            if (r < 0) {
                e->flags[i] = 2;
                e->idx[i] = 0;
                intra_record(f, i, z, qi->rot_bits, motion, e->rec, stride, n_new);
                intra_recon(e->rec, stride, n_new, z, qi->rot_bits, motion, dst, i);
                n_new++;
                continue;
            }
            matched++;
            e->idx[i] = zig(r - (prev + 1));
            prev = r;
            struct pred p;
            predict(ref, (size_t)r, &p);
            int32_t res[NCH] = { 0 };
            float ls[3];
            log_scale(f->scale + 3 * i, ls);
            for (int c = 0; c < 3; c++) {
                res[CH_POS + c] = resid(z[c], f->pos[3 * i + c], p.pos[c]);
                res[CH_LS + c] = resid(z[3 + c], ls[c], p.ls[c]);
                res[CH_RGB + c] = resid(z[7 + c], f->rgb[3 * i + c], p.rgb[c]);
                if (motion) {
                    res[CH_MB + c] = resid(z[QZ_MB + c], f->motion_bwd[3 * i + c], p.mb[c]);
                    res[CH_MF + c] = resid(z[QZ_MF + c], f->motion_fwd[3 * i + c], p.mf[c]);
                }
            }
            res[CH_OP] = resid(z[6], f->opacity[i], p.op);
            /* rotation: the input normalised and on the prediction's side */
            const float *qin = f->rot + 4 * i;
            float qn = 0, dot = 0;
            for (int c = 0; c < 4; c++) {
                qn += qin[c] * qin[c];
                dot += qin[c] * p.rot[c];
            }
            qn = qn > 1e-30f ? (dot < 0 ? -1.0f : 1.0f) / sqrtf(qn) : 0.0f;
            int rot_near = 1;
            for (int c = 0; c < 4; c++) {
                float qc = qn != 0.0f ? qin[c] * qn : (c == 0 ? 1.0f : 0.0f);
                double t = ((double)qc - (double)p.rot[c]) / rs;
                res[CH_ROT + c] = (int32_t)llround(t);
                rot_near &= fabs(t) <= 1.0;
            }
            /* Dead zone: a channel whose prediction is already within the
             * level's bound keeps it (the reference's own quantization error
             * would otherwise flip it to +-1 from key to key). */
            if (rot_near)
                res[CH_ROT] = res[CH_ROT + 1] = res[CH_ROT + 2] = res[CH_ROT + 3] = 0;
            for (int c = 0; c < 3; c++)
                if (fabsf(f->pos[3 * i + c] - p.pos[c]) <= pos_tol[c])
                    res[CH_POS + c] = 0;
            int any = 0;
            for (int c = 0; c < nch; c++)
                any |= res[c];
            resid_recon(res, &p, z, qi->rot_bits, motion, dst, i);
            if (!any) {
                e->flags[i] = 0;
                n_same++;
                continue;
            }
            e->flags[i] = 1;
            for (int c = 0; c < nch; c++)
                e->res[(size_t)c * stride + n_changed] = zig(res[c]);
            n_changed++;
        }
        size_t o0 = off;
        if (explicit_match && (rc = put_plane(e, e->idx, n, 0, pl, pcap, &off)) < 0)
            return rc;
        if ((rc = put_plane(e, e->flags, n, 0, pl, pcap, &off)) < 0)
            return rc;
        e->st.bytes_index = off - o0;
        size_t *g[3] = { &e->st.bytes_pos, &e->st.bytes_attr, &e->st.bytes_motion };
        for (int c = 0; c < nch; c++) {
            o0 = off;
            if ((rc = put_plane(e, e->res + (size_t)c * stride, n_changed, 0, pl, pcap, &off)) < 0)
                return rc;
            *g[stat_group(c)] += off - o0;
        }
        for (int c = 0; c < nch; c++) {
            o0 = off;
            if ((rc = put_plane(e, e->rec + (size_t)c * stride, n_new, 1, pl, pcap, &off)) < 0)
                return rc;
            *g[stat_group(c)] += off - o0;
        }
    }
    finish_scales(dst);

    pl[0] = intra ? 1 : 2;
    pl[1] = (uint8_t)e->q;
    pl[2] = (uint8_t)(motion | explicit_match << 1);
    pl[3] = (uint8_t)qi->rot_bits;
    codec__put_u32(pl + 4, (uint32_t)n);
    codec__put_u32(pl + 8, intra ? 0u : (uint32_t)ref->count);
    codec__put_u32(pl + 12, (uint32_t)n_new);
    codec__put_u32(pl + 16, (uint32_t)n_changed);
    put_qz(pl + FHDR, z);

    uint32_t s = e->seq;
    rc = codec_packet_write(out, cap, intra ? CODEC_PKT_INTRA : CODEC_PKT_PRED, s, intra ? s : e->ref_seq, t_us,
                            pl, off, len, &e->err);
    if (rc < 0)
        return rc;
    e->st.intra = intra;
    e->st.count = n;
    e->st.unchanged = n_same;
    e->st.changed = n_changed;
    e->st.fresh = n_new;
    e->st.dropped = intra ? 0 : (ref->count > matched ? ref->count - matched : 0);
    e->st.bytes_total = off;
    e->st.bytes_header = FHDR + 8 * NQZ;
    e->seq++;
    e->ref_seq = s;
    e->cur ^= 1;
    e->have_ref = 1;
    return F4D_OK;
}

/* ------------------------------------------------------------------------ */
/* Decoder. */

struct codec_dec {
    size_t cap;
    struct f4d_err err;
    struct keystate key[2];
    int cur, have_ref, have_seq, quality;
    uint32_t last_seq, key_seq;
    uint64_t t_us;
    uint32_t *rec, *res, *idx, *flags;
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
    int bad = !d->rec || !d->res || !d->idx || !d->flags || !d->shuf || !d->zws || key_alloc(&d->key[0], capacity) ||
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

static int get_plane(codec_dec *d, const uint8_t *in, size_t len, size_t *off, size_t n, uint32_t *v,
                     const char *what)
{
    if (len - *off < 5)
        return f4d_fail(&d->err, F4D_EFORMAT, "frame: plane %s: truncated at byte %zu", what, *off);
    int t = in[*off] & 15, w = in[*off] >> 4;
    uint32_t zl = codec__u32(in + *off + 1);
    *off += 5;
    if (t > 1 || w < 1 || w > 4)
        return f4d_fail(&d->err, F4D_EFORMAT, "frame: plane %s: bad tag 0x%02x", what, in[*off - 5]);
    if (zl > len - *off)
        return f4d_fail(&d->err, F4D_EFORMAT, "frame: plane %s: %u compressed bytes, %zu left", what, zl,
                        len - *off);
    if (n == 0) {
        if (zl != 0)
            return f4d_fail(&d->err, F4D_EFORMAT, "frame: plane %s: data for 0 Gaussians", what);
        return F4D_OK;
    }
    size_t want = n * (size_t)w;
    size_t got = ZSTD_decompressDCtx(d->z, d->shuf, want, in + *off, zl);
    if (ZSTD_isError(got) || got != want)
        return f4d_fail(&d->err, F4D_EFORMAT, "frame: plane %s: zstd gave %s, %zu bytes expected", what,
                        ZSTD_isError(got) ? ZSTD_getErrorName(got) : "a different size", want);
    *off += zl;
    for (size_t i = 0; i < n; i++) {
        uint32_t x = 0;
        for (int b = 0; b < w; b++)
            x |= (uint32_t)d->shuf[(size_t)b * n + i] << (8 * b);
        v[i] = x;
    }
    if (t == 1)
        for (size_t i = 0, prev = 0; i < n; i++) {
            uint32_t x = (uint32_t)prev + (uint32_t)unzig(v[i]);
            v[i] = x;
            prev = x;
        }
    return F4D_OK;
}

static int key_finite(codec_dec *d, const struct keystate *k)
{
    for (size_t i = 0; i < k->count; i++) {
        int ok = 1;
        for (int c = 0; c < 3; c++)
            ok &= isfinite(k->pos[3 * i + c]) && isfinite(k->ls[3 * i + c]) && k->ls[3 * i + c] < 80.0f &&
                  isfinite(k->rgb[3 * i + c]) && isfinite(k->mb[3 * i + c]) && isfinite(k->mf[3 * i + c]);
        if (!ok)
            return f4d_fail(&d->err, F4D_EFORMAT, "frame: Gaussian %zu decodes to a non-finite value", i);
    }
    return F4D_OK;
}

static int decode_key(codec_dec *d, const struct codec_packet *p, int intra)
{
    const uint8_t *in = p->payload;
    size_t len = p->payload_len, off = FHDR + 8 * NQZ;
    if (len < off)
        return f4d_fail(&d->err, F4D_EFORMAT, "frame: %zu bytes, the header needs %zu", len, off);
    if (in[0] != (intra ? 1 : 2))
        return f4d_fail(&d->err, F4D_EFORMAT, "frame: kind %u does not match packet type %d", in[0], p->type);
    int motion = in[2] & 1, explicit_match = in[2] >> 1 & 1, rot_bits = in[3];
    if (in[1] >= CODEC_QUALITY_COUNT || (in[2] & ~3) || rot_bits < 4 || rot_bits > 15)
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
    struct qz z[NQZ];
    for (int k = 0; k < NQZ; k++) {
        z[k].lo = codec__f32(in + FHDR + 8 * k);
        z[k].step = codec__f32(in + FHDR + 8 * k + 4);
        if (!isfinite(z[k].lo) || !isfinite(z[k].step) || z[k].step < 0 || fabsf(z[k].lo) > 1e18f ||
            z[k].step > 1e10f)
            return f4d_fail(&d->err, F4D_EFORMAT, "frame: quantizer %d (%g, %g) out of range", k, (double)z[k].lo,
                            (double)z[k].step);
    }
    const int nch = motion ? NCH : CH_MB;
    const size_t stride = d->cap ? d->cap : 1;
    int rc;
    char what[16];
    dst->count = n;
    dst->motion = motion;
    if (intra) {
        for (int c = 0; c < nch; c++) {
            snprintf(what, sizeof what, "%d", c);
            if ((rc = get_plane(d, in, len, &off, n, d->rec + (size_t)c * stride, what)) < 0)
                return rc;
        }
        for (size_t i = 0; i < n; i++)
            intra_recon(d->rec, stride, i, z, rot_bits, motion, dst, i);
    } else {
        if (explicit_match && (rc = get_plane(d, in, len, &off, n, d->idx, "index")) < 0)
            return rc;
        if ((rc = get_plane(d, in, len, &off, n, d->flags, "flags")) < 0)
            return rc;
        for (int c = 0; c < nch; c++) {
            snprintf(what, sizeof what, "r%d", c);
            if ((rc = get_plane(d, in, len, &off, n_changed, d->res + (size_t)c * stride, what)) < 0)
                return rc;
        }
        for (int c = 0; c < nch; c++) {
            snprintf(what, sizeof what, "n%d", c);
            if ((rc = get_plane(d, in, len, &off, n_new, d->rec + (size_t)c * stride, what)) < 0)
                return rc;
        }
        size_t kc = 0, kn = 0;
        int64_t prev = -1;
        for (size_t i = 0; i < n; i++) {
            uint32_t fl = d->flags[i];
            if (fl > 2)
                return f4d_fail(&d->err, F4D_EFORMAT, "frame: Gaussian %zu: flag %u", i, fl);
            if (fl == 2) {
                if (kn >= n_new)
                    return f4d_fail(&d->err, F4D_EFORMAT, "frame: more new Gaussians than the %zu announced", n_new);
                intra_recon(d->rec, stride, kn++, z, rot_bits, motion, dst, i);
                continue;
            }
            int64_t r = explicit_match ? prev + 1 + unzig(d->idx[i]) : (int64_t)i;
            if (r < 0 || r >= (int64_t)nref)
                return f4d_fail(&d->err, F4D_EFORMAT, "frame: Gaussian %zu: reference index %lld of %zu", i,
                                (long long)r, nref);
            prev = r;
            struct pred pr;
            predict(ref, (size_t)r, &pr);
            int32_t res[NCH] = { 0 };
            if (fl == 1) {
                if (kc >= n_changed)
                    return f4d_fail(&d->err, F4D_EFORMAT, "frame: more changed Gaussians than the %zu announced",
                                    n_changed);
                for (int c = 0; c < nch; c++)
                    res[c] = unzig(d->res[(size_t)c * stride + kc]);
                kc++;
            }
            resid_recon(res, &pr, z, rot_bits, motion, dst, i);
        }
        if (kc != n_changed || kn != n_new)
            return f4d_fail(&d->err, F4D_EFORMAT, "frame: flags name %zu changed / %zu new, header %zu / %zu", kc,
                            kn, n_changed, n_new);
    }
    if (off != len)
        return f4d_fail(&d->err, F4D_EFORMAT, "frame: %zu trailing bytes", len - off);
    if ((rc = key_finite(d, dst)) < 0)
        return rc;
    finish_scales(dst);
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
        if (p->payload_len < 12 || codec__u32(p->payload) != CODEC_VERSION ||
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
        int rc = decode_key(d, p, intra);
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
