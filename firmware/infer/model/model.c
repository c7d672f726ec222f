/* model.c - Init (validate the file, pack weights), Prepare (plan and
 * allocate the arena), Eval (aggregator, then every registered head). */
#include <inttypes.h>
#include <stdarg.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "model_internal.h"

/* Built-in heads, in evaluation order (vggt.md 0: camera, depth, point; then
 * Forge4D's scale head, whose gauge the Gaussian and motion heads divide by).
 * A head whose tensors are not in the file is skipped: a plain VGGT file runs
 * the first three only. */
static const struct model_head_ops *const builtin_heads[] = {
    &model_camera_head_ops, &model_depth_head_ops, &model_point_head_ops,
    &model_scale_head_ops,  &model_gaussian_head_ops, &model_motion_head_ops,
};

int model_fail(struct model *m, int rc, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    f4d_vfail(&m->err, rc, fmt, ap);
    va_end(ap);
    return rc;
}

int model_kfail(struct model *m, const char *what)
{
    return model_fail(m, fk_ctx_status(m->ctx), "model: %s: %s", what, fk_ctx_error(m->ctx));
}

double model_now(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

/* ------------------------------------------------------------ validation */

struct check_ctx {
    struct model *m;
    size_t        n_schema;
};

static int allowed_type(const struct model_tensor_info *ti, uint32_t type)
{
    if (ti->tclass != MODEL_T_QUANT)
        return type == GGUF_T_F32;
    return type == GGUF_T_F32 || type == GGUF_T_F16 || type == GGUF_T_I8;
}

static int check_tensor(void *user, const struct model_tensor_info *ti)
{
    struct check_ctx *cc = user;
    struct model *m = cc->m;
    const struct gguf_tensor *t = gguf_find_tensor(m->gf, ti->name);
    if (ti->tclass == MODEL_T_UNUSED) {
        if (t)
            return model_fail(m, F4D_EFORMAT, "model: tensor '%s' is unused and must not be "
                              "in the file", ti->name);
        return 0;
    }
    if (!t)
        return model_fail(m, F4D_EFORMAT, "model: missing tensor '%s'", ti->name);
    if (!allowed_type(ti, t->type))
        return model_fail(m, F4D_EFORMAT, "model: tensor '%s' has type %s (allowed: %s)",
                          ti->name, gguf_type_name(t->type),
                          ti->tclass == MODEL_T_QUANT ? "F32, F16, I8" : "F32");
    const struct gguf_tensor *ok;
    if (gguf_expect_tensor(m->gf, ti->name, t->type, ti->n_dims, ti->shape, &ok) < 0)
        return model_fail(m, F4D_EFORMAT, "model: %s (from the forge4d.* metadata)",
                          gguf_error(m->gf));
    cc->n_schema++;
    if (t->type == GGUF_T_I8) {
        char sn[MODEL_NAME_MAX + 8];
        snprintf(sn, sizeof sn, "%s.scale", ti->name);
        if (gguf_expect_tensor(m->gf, sn, GGUF_T_F32, 1, &ti->shape[ti->qaxis], &ok) < 0)
            return model_fail(m, F4D_EFORMAT, "model: int8 tensor '%s': %s", ti->name,
                              gguf_error(m->gf));
        const float *s = ok->data;
        for (int64_t i = 0; i < ti->shape[ti->qaxis]; i++)
            if (!(s[i] >= 0.0f) || s[i] > 1e30f)
                return model_fail(m, F4D_EFORMAT, "model: tensor '%s' has a bad scale [%"
                                  PRId64 "]", sn, i);
        cc->n_schema++;
    }
    return 0;
}

/* ------------------------------------------------------------ weights */

gguf_file *model_gguf(struct model *m) { return m->gf; }

int model_load_f32(struct model *m, const char *name, size_t count, const float **v)
{
    const struct gguf_tensor *t = gguf_find_tensor(m->gf, name);
    if (!t || t->type != GGUF_T_F32 || t->n_elements != count)
        return model_fail(m, F4D_EFORMAT, "model: tensor '%s' missing, not F32 or not %zu "
                          "elements", name, count);
    *v = t->data;
    return 0;
}

int model_load_vec(struct model *m, const char *name, int n, const float **v)
{
    return model_load_f32(m, name, (size_t)n, v);
}

/* Dequantizes / widens a weight into a fresh f32 array in PyTorch layout. */
static int weight_f32(struct model *m, const char *name, size_t count, int qaxis, float **out,
                      const struct gguf_tensor **tt)
{
    const struct gguf_tensor *t = gguf_find_tensor(m->gf, name);
    if (!t || t->n_elements != count)
        return model_fail(m, F4D_EFORMAT, "model: tensor '%s' missing or not %zu elements",
                          name, count);
    *tt = t;
    float *w = malloc(count * sizeof *w);
    if (!w)
        return model_fail(m, F4D_ENOMEM, "model: out of memory for '%s'", name);
    if (t->type == GGUF_T_F32) {
        memcpy(w, t->data, count * sizeof *w);
    } else if (t->type == GGUF_T_F16) {
        if (fk_f16_to_f32(m->ctx, t->data, w, count) != F4D_OK) {
            free(w);
            return model_kfail(m, "f16 widening");
        }
    } else if (t->type == GGUF_T_I8) {
        char sn[MODEL_NAME_MAX + 8];
        snprintf(sn, sizeof sn, "%s.scale", name);
        const struct gguf_tensor *st = gguf_find_tensor(m->gf, sn);
        if (!st || st->type != GGUF_T_F32) {
            free(w);
            return model_fail(m, F4D_EFORMAT, "model: int8 tensor '%s' has no F32 '%s'",
                              name, sn);
        }
        size_t nch = (size_t)t->ne[t->n_dims - 1 - qaxis], inner = 1;
        for (int d = qaxis + 1; d < (int)t->n_dims; d++)
            inner *= (size_t)t->ne[t->n_dims - 1 - d];
        if (st->n_elements != nch) {
            free(w);
            return model_fail(m, F4D_EFORMAT, "model: '%s' has %" PRIu64 " scales, expected %zu",
                              sn, st->n_elements, nch);
        }
        const int8_t *q = t->data;
        const float *s = st->data;
        for (size_t i = 0; i < count; i++)
            w[i] = (float)q[i] * s[(i / inner) % nch];
    } else {
        free(w);
        return model_fail(m, F4D_EFORMAT, "model: tensor '%s' has type %s", name,
                          gguf_type_name(t->type));
    }
    *out = w;
    return 0;
}

int model_load_linear(struct model *m, struct fk_linear *L, const char *wname,
                      const char *bname, int n, int k)
{
    const float *bias = NULL;
    int rc, krc;
    if (bname && (rc = model_load_f32(m, bname, (size_t)n, &bias)) < 0)
        return rc;
    const struct gguf_tensor *t = gguf_find_tensor(m->gf, wname);
    if (!t || t->n_dims != 2 || t->ne[0] != (uint64_t)k || t->ne[1] != (uint64_t)n)
        return model_fail(m, F4D_EFORMAT, "model: tensor '%s' missing or not [%d, %d]", wname,
                          n, k);
    if (t->type == GGUF_T_F32) {
        krc = fk_linear_pack(m->ctx, L, m->wtype, t->data, n, k, bias);
    } else if (t->type == GGUF_T_F16 && m->wtype != FK_W_Q8) {
        krc = fk_linear_pack_f16(m->ctx, L, m->wtype, t->data, n, k, bias);
    } else if (t->type == GGUF_T_I8 && m->wtype == FK_W_Q8) {
        char sn[MODEL_NAME_MAX + 8];
        snprintf(sn, sizeof sn, "%s.scale", wname);
        const struct gguf_tensor *st = gguf_find_tensor(m->gf, sn);
        if (!st || st->type != GGUF_T_F32 || st->n_elements != (uint64_t)n)
            return model_fail(m, F4D_EFORMAT, "model: int8 tensor '%s' has no F32 '%s' [%d]",
                              wname, sn, n);
        krc = fk_linear_pack_q8(m->ctx, L, t->data, st->data, n, k, bias);
    } else {
        float *w;
        if ((rc = weight_f32(m, wname, (size_t)n * k, 0, &w, &t)) < 0)
            return rc;
        krc = fk_linear_pack(m->ctx, L, m->wtype, w, n, k, bias);
        free(w);
    }
    if (krc != F4D_OK)
        return model_fail(m, fk_ctx_status(m->ctx), "model: packing '%s': %s", wname,
                          fk_ctx_error(m->ctx));
    m->weight_bytes += L->bytes;
    return 0;
}

int model_load_conv(struct model *m, struct fk_conv2d *c, const char *prefix, int cout, int cin,
                    int k, int stride, int pad, int bias, enum fk_wtype as)
{
    char wn[2 * MODEL_NAME_MAX + 16], bn[2 * MODEL_NAME_MAX + 16];
    const float *b = NULL;
    const struct gguf_tensor *t;
    float *w;
    int rc;
    snprintf(wn, sizeof wn, "%s.weight", prefix);
    snprintf(bn, sizeof bn, "%s.bias", prefix);
    if (bias && (rc = model_load_f32(m, bn, (size_t)cout, &b)) < 0)
        return rc;
    if ((rc = weight_f32(m, wn, (size_t)cout * cin * k * k, 0, &w, &t)) < 0)
        return rc;
    int krc = fk_conv2d_pack(m->ctx, c, as, w, b, cout, cin, k, k, stride, pad);
    free(w);
    if (krc != F4D_OK)
        return model_fail(m, fk_ctx_status(m->ctx), "model: packing '%s': %s", wn, fk_ctx_error(m->ctx));
    m->weight_bytes += c->lin.bytes;
    return 0;
}

int model_load_convt(struct model *m, struct fk_conv_transpose2d *c, const char *prefix, int cin,
                     int cout, int k)
{
    char wn[2 * MODEL_NAME_MAX + 16], bn[2 * MODEL_NAME_MAX + 16];
    const float *b = NULL;
    const struct gguf_tensor *t;
    float *w;
    int rc;
    snprintf(wn, sizeof wn, "%s.weight", prefix);
    snprintf(bn, sizeof bn, "%s.bias", prefix);
    if ((rc = model_load_f32(m, bn, (size_t)cout, &b)) < 0)
        return rc;
    if ((rc = weight_f32(m, wn, (size_t)cin * cout * k * k, 1, &w, &t)) < 0)
        return rc;
    int krc = fk_conv_transpose2d_pack(m->ctx, c, m->wtype, w, b, cin, cout, k);
    free(w);
    if (krc != F4D_OK)
        return model_fail(m, fk_ctx_status(m->ctx), "model: packing '%s': %s", wn, fk_ctx_error(m->ctx));
    m->weight_bytes += c->lin.bytes;
    return 0;
}

/* ------------------------------------------------------------ init */

static int name_extra(struct model *m);

/* Init on an open file: m->gf is set (owned or borrowed). */
static int init_file(struct model *m)
{
    int rc;
    if ((rc = model_config_read(m->gf, &m->cfg, &m->err)) < 0)
        return rc;
    for (size_t i = 0; i < gguf_tensor_count(m->gf); i++)
        m->groups |= model_group_of(gguf_tensor_at(m->gf, i)->name);
    if (!(m->groups & MODEL_G_AGGREGATOR))
        return model_fail(m, F4D_EFORMAT, "model: the weight file has no aggregator.* tensors");
    struct check_ctx cc = { m, 0 };
    if ((rc = model_schema_foreach(&m->cfg, m->groups, check_tensor, &cc)) < 0)
        return rc;
    size_t in_groups = 0;
    for (size_t i = 0; i < gguf_tensor_count(m->gf); i++)
        in_groups += model_group_of(gguf_tensor_at(m->gf, i)->name) != 0;
    if (in_groups != cc.n_schema)
        return name_extra(m);
    if ((rc = model_aggregator_load(m)) < 0 || (rc = model_stream_load(m)) < 0 ||
        (rc = model_fusion_load(m)) < 0)
        return rc;
    for (size_t i = 0; i < sizeof builtin_heads / sizeof builtin_heads[0]; i++)
        if ((rc = model_register_head(m, builtin_heads[i])) < 0)
            return rc;
    return 0;
}

static struct model *model_new(fk_ctx *ctx, enum fk_wtype wtype, struct f4d_err *err,
                               int *rc)
{
    if (wtype != FK_W_F32 && wtype != FK_W_F16 && wtype != FK_W_Q8) {
        *rc = f4d_fail(err, F4D_EINVAL, "model: unknown weight precision %d", (int)wtype);
        return NULL;
    }
    struct model *m = calloc(1, sizeof *m);
    if (!m) {
        *rc = f4d_fail(err, F4D_ENOMEM, "model: out of memory");
        return NULL;
    }
    m->ctx = ctx;
    m->wtype = wtype;
    m->flops = &m->st_flops[0];
    return m;
}

static int init_done(struct model *m, int rc, struct model **out, struct f4d_err *err)
{
    if (rc >= 0) {
        *out = m;
        return 0;
    }
    if (err)
        *err = m->err;
    model_free(m);
    return rc;
}

int model_init(fk_ctx *ctx, const char *path, enum fk_wtype wtype, struct model **out,
               struct f4d_err *err)
{
    *out = NULL;
    int rc;
    struct model *m = model_new(ctx, wtype, err, &rc);
    if (!m)
        return rc;
    m->owns_gf = 1;
    rc = gguf_open(path, &m->gf, &m->err);
    if (rc < 0)
        rc = rc == F4D_EIO || rc == F4D_ENOMEM ? rc : F4D_EFORMAT;
    else
        rc = init_file(m);
    return init_done(m, rc, out, err);
}

int model_init_gguf(fk_ctx *ctx, gguf_file *gf, enum fk_wtype wtype, struct model **out,
                    struct f4d_err *err)
{
    *out = NULL;
    int rc;
    struct model *m = model_new(ctx, wtype, err, &rc);
    if (!m)
        return rc;
    m->gf = gf;
    return init_done(m, init_file(m), out, err);
}

int model_register_head(struct model *m, const struct model_head_ops *ops)
{
    if (m->arena)
        return model_fail(m, F4D_EINVAL, "model: head '%s' registered after model_prepare",
                          ops->prefix);
    if (ops->api_version != MODEL_HEAD_API_VERSION || !ops->init || !ops->layers ||
        !ops->plan || !ops->eval || !ops->free)
        return model_fail(m, F4D_EINVAL, "model: head '%s': api_version %u (need %u) or a "
                          "missing op", ops->prefix, ops->api_version, MODEL_HEAD_API_VERSION);
    if (m->n_heads == MODEL_HEADS_MAX)
        return model_fail(m, F4D_EINVAL, "model: more than %d heads", MODEL_HEADS_MAX);
    void *h = NULL;
    int rc = ops->init(m, &h);
    if (rc < 0) {
        if (!m->err.msg[0])
            model_fail(m, rc, "model: head '%s' failed to load", ops->prefix);
        return rc;
    }
    if (rc == 1)
        return 0; /* not in this file */
    uint64_t mask = ops->layers(h);
    if (m->cfg.depth < 64 && (mask >> m->cfg.depth)) {
        ops->free(h);
        return model_fail(m, F4D_EINVAL, "model: head '%s' reads a layer beyond depth %d",
                          ops->prefix, m->cfg.depth);
    }
    m->head_ops[m->n_heads] = ops;
    m->head[m->n_heads++] = h;
    m->keep |= mask;
    return 0;
}

int model_skip_head(struct model *m, const char *prefix)
{
    if (!m || !prefix)
        return F4D_EINVAL;
    if (m->arena)
        return model_fail(m, F4D_EINVAL, "model: head '%s' skipped after model_prepare", prefix);
    int at = -1, gauss = 0;
    for (int i = 0; i < m->n_heads; i++) {
        at = strcmp(m->head_ops[i]->prefix, prefix) ? at : i;
        gauss |= !strcmp(m->head_ops[i]->prefix, "gaussian_head");
    }
    if (at < 0)
        return 0; /* not in this file: nothing runs anyway */
    /* the Gaussian head reads the point head's X and the camera head's poses */
    if (gauss && (!strcmp(prefix, "point_head") || !strcmp(prefix, "camera_head")))
        return model_fail(m, F4D_EINVAL, "model: '%s' cannot be skipped: gaussian_head reads it", prefix);
    m->head_ops[at]->free(m->head[at]);
    if (!strcmp(prefix, "motion_head"))
        model_stream_drop_motion(m);
    for (int i = at; i + 1 < m->n_heads; i++) {
        m->head_ops[i] = m->head_ops[i + 1];
        m->head[i] = m->head[i + 1];
    }
    m->n_heads--;
    /* layers only the skipped head read are no longer kept */
    m->keep = 0; /* only heads ask for kept layers (model_register_head) */
    for (int i = 0; i < m->n_heads; i++)
        m->keep |= m->head_ops[i]->layers(m->head[i]);
    return 0;
}

/* Every tensor of the file belongs to the schema of a group (or is an int8
 * scale) or to a registered head: anything else is refused by name. */
static int check_unknown(struct model *m)
{
    for (size_t i = 0; i < gguf_tensor_count(m->gf); i++) {
        const char *nm = gguf_tensor_at(m->gf, i)->name;
        if (model_group_of(nm))
            continue;
        int known = 0;
        for (int h = 0; h < m->n_heads && !known; h++) {
            size_t n = strlen(m->head_ops[h]->prefix);
            known = !strncmp(nm, m->head_ops[h]->prefix, n) && nm[n] == '.';
        }
        if (!known)
            return model_fail(m, F4D_EFORMAT, "model: unknown tensor '%s'", nm);
    }
    return 0;
}

struct find_ctx {
    const char *name;
    int         found;
};

static int find_name(void *user, const struct model_tensor_info *ti)
{
    struct find_ctx *fc = user;
    size_t n = strlen(ti->name);
    if (!strcmp(fc->name, ti->name) ||
        (ti->tclass == MODEL_T_QUANT && !strncmp(fc->name, ti->name, n) &&
         !strcmp(fc->name + n, ".scale")))
        fc->found = 1;
    return 0;
}

/* A file tensor of a known group that the schema does not name (error path
 * only: it walks the schema once per tensor). */
static int name_extra(struct model *m)
{
    for (size_t i = 0; i < gguf_tensor_count(m->gf); i++) {
        struct find_ctx fc = { gguf_tensor_at(m->gf, i)->name, 0 };
        if (!model_group_of(fc.name))
            continue;
        model_schema_foreach(&m->cfg, m->groups, find_name, &fc);
        if (!fc.found)
            return model_fail(m, F4D_EFORMAT, "model: unknown tensor '%s' (not in the schema "
                              "of the forge4d.* metadata)", fc.name);
    }
    return model_fail(m, F4D_EFORMAT, "model: tensor count does not match the schema");
}

/* ------------------------------------------------------------ plan */

/* The aggregator's part, with Forge4D's state / motion memory (persistent
 * after the aggregator's, scratch stacked on the aggregator's). */
static void plan_sizes(const struct model_config *c, unsigned groups, uint64_t keep, int S, int H,
                       int W, size_t *persist, size_t *scratch)
{
    size_t p, s;
    model_aggregator_plan(c, keep, S, H, W, persist, scratch);
    model_stream_plan(c, groups, S, H, W, &p, &s);
    *persist += p;
    *scratch += s;
}

size_t model_plan_bytes(const struct model_config *c, unsigned groups, int views, int h, int w)
{
    uint64_t keep = 0;
    if (groups & MODEL_G_CAMERA)
        keep |= UINT64_C(1) << (c->depth - 1);
    if (groups & MODEL_G_SCALE)
        keep |= UINT64_C(1) << (c->depth - 1);
    if (groups & (MODEL_G_DEPTH | MODEL_G_POINT | MODEL_G_GAUSSIAN))
        for (int i = 0; i < 4; i++)
            keep |= UINT64_C(1) << c->dpt_layer_idx[i];
    size_t persist, scratch, p, s;
    plan_sizes(c, groups, keep, views, h, w, &persist, &scratch);
    if (groups & MODEL_G_CAMERA) {
        model_camera_plan(c, views, &p, &s);
        persist += p;
        scratch = scratch > s ? scratch : s;
    }
    for (int od = 2; od <= 4; od += 2)
        if (groups & (od == 2 ? MODEL_G_DEPTH : MODEL_G_POINT)) {
            model_dpt_plan(c, od, views, h, w, &p, &s);
            persist += p;
            scratch = scratch > s ? scratch : s;
        }
    if (groups & MODEL_G_SCALE) {
        model_scale_plan(c, views, &p, &s);
        persist += (p + MODEL_ALIGN - 1) / MODEL_ALIGN * MODEL_ALIGN;
        scratch = scratch > s ? scratch : s;
    }
    if (groups & MODEL_G_GAUSSIAN) {
        model_gaussian_plan(c, views, h, w, &p, &s);
        persist += (p + MODEL_ALIGN - 1) / MODEL_ALIGN * MODEL_ALIGN;
        scratch = scratch > s ? scratch : s;
    }
    if (groups & MODEL_G_MOTION_HEAD) {
        model_motion_head_plan(c, views, h, w, &p, &s);
        persist += (p + MODEL_ALIGN - 1) / MODEL_ALIGN * MODEL_ALIGN;
        scratch = scratch > s ? scratch : s;
    }
    return persist + scratch;
}

static int check_shape(struct model *m, int S, int H, int W)
{
    const int p = m->cfg.patch_size;
    if (S < 1 || S > MODEL_VIEWS_MAX)
        return model_fail(m, F4D_EINVAL, "model: %d views (1..%d)", S, MODEL_VIEWS_MAX);
    if (H < p || W < p || H % p || W % p || H > MODEL_IMG_MAX || W > MODEL_IMG_MAX)
        return model_fail(m, F4D_EINVAL, "model: input %dx%d is not a multiple of the patch "
                          "size %d (or exceeds %d)", W, H, p, MODEL_IMG_MAX);
    return 0;
}

/* Eval never allocates: the kernels' scratch (GEMM panels, attention groups,
 * resize tables) is reserved here by one Eval at the largest planned size with
 * the context measuring (fk_ctx_measure: kernels reserve, then skip the work),
 * and the context is frozen, so that a later kernel needing more fails with
 * F4D_ENOMEM instead of allocating. Taps and hooks do not see this pass. */
static int reserve_kernel_scratch(struct model *m)
{
    const size_t n_img = (size_t)m->max_S * 3 * (size_t)m->max_H * (size_t)m->max_W;
    float *img = calloc(n_img, sizeof *img);
    if (!img)
        return model_fail(m, F4D_ENOMEM, "model: out of memory for the %zu-float planning "
                          "input", n_img);
    model_tap_fn tap = m->tap;
    struct model_hooks hooks = m->hooks;
    m->tap = NULL;
    memset(&m->hooks, 0, sizeof m->hooks);
    fk_ctx_freeze(m->ctx, 0);
    fk_ctx_measure(m->ctx, 1);
    m->measuring = 1;
    struct model_outputs out;
    int rc = model_eval(m, img, m->max_S, m->max_H, m->max_W, &out);
    m->measuring = 0;
    fk_ctx_measure(m->ctx, 0);
    m->tap = tap;
    m->hooks = hooks;
    free(img);
    /* the measuring pass computed nothing: forget its pos-embed grid, layers,
     * stats and time step */
    m->pe_h = m->pe_w = 0;
    m->layers_valid = 0;
    model_state_reset(m);
    for (int i = 0; i < ST_COUNT; i++)
        m->st_sec[i] = m->st_flops[i] = 0;
    if (rc < 0)
        return rc;
    fk_ctx_freeze(m->ctx, 1);
    m->froze_ctx = 1;
    return 0;
}

int model_prepare(struct model *m, int max_views, int max_h, int max_w)
{
    int rc;
    if (m->arena)
        return model_fail(m, F4D_EINVAL, "model: already prepared");
    if ((rc = check_shape(m, max_views, max_h, max_w)) < 0 || (rc = check_unknown(m)) < 0)
        return rc;
    size_t persist, scratch;
    plan_sizes(&m->cfg, model_stream_groups(m), m->keep, max_views, max_h, max_w, &persist, &scratch);
    size_t agg_persist = persist;
    for (int i = 0; i < m->n_heads; i++) {
        size_t p, s;
        m->head_ops[i]->plan(m->head[i], max_views, max_h, max_w, &p, &s);
        m->head_persist_bytes[i] = (p + MODEL_ALIGN - 1) / MODEL_ALIGN * MODEL_ALIGN;
        persist += m->head_persist_bytes[i];
        scratch = scratch > s ? scratch : s;
    }
    m->arena_bytes = persist + scratch;
    m->arena = aligned_alloc(MODEL_ALIGN, (m->arena_bytes + MODEL_ALIGN - 1) / MODEL_ALIGN * MODEL_ALIGN);
    if (!m->arena)
        return model_fail(m, F4D_ENOMEM, "model: cannot allocate the %zu-byte arena",
                          m->arena_bytes);
    /* Touch every page now, so that Eval never takes a first-touch page fault. */
    memset(m->arena, 0, m->arena_bytes);
    m->persist_bytes = persist;
    m->scratch_bytes = scratch;
    m->max_S = max_views;
    m->max_H = max_h;
    m->max_W = max_w;
    /* Persistent part: same order as model_aggregator_plan, then the heads. */
    const struct model_config *c = &m->cfg;
    const int pp = c->patch_size, P = (max_h / pp) * (max_w / pp);
    const size_t n = (size_t)max_views * (1 + c->num_register_tokens + P);
    struct bump b = { m->arena, 0 };
    m->pos = bump_take(&b, n * 2 * sizeof(int32_t));
    m->row = bump_take(&b, n * sizeof(int32_t));
    if (c->patch_embed == MODEL_PATCH_DINO)
        m->pe_grid = BUMP_F(&b, (size_t)P * c->embed_dim);
    for (int l = 0; l < c->depth; l++)
        m->layers[l] = (m->keep >> l & 1) ? BUMP_F(&b, n * 2 * c->embed_dim) : NULL;
    model_stream_place(m, &b);
    if (b.off != agg_persist)
        return model_fail(m, F4D_EINVAL, "model: internal plan mismatch");
    for (int i = 0; i < m->n_heads; i++)
        m->head_persist[i] = bump_take(&b, m->head_persist_bytes[i]);
    m->scratch = (float *)(m->arena + persist);
    m->pe_h = m->pe_w = 0;
    if ((rc = reserve_kernel_scratch(m)) < 0) {
        free(m->arena);
        m->arena = NULL;
        return rc;
    }
    return 0;
}

/* ------------------------------------------------------------ eval */

static int run_network(struct model *m, const float *images, int S, int H, int W, int P1,
                       const uint8_t *patch_keep, struct model_outputs *out);

int model_eval(struct model *m, const float *images, int S, int H, int W,
               struct model_outputs *out)
{
    return model_eval_masked(m, images, S, H, W, NULL, out);
}

int model_eval_masked(struct model *m, const float *images, int S, int H, int W,
                      const uint8_t *patch_keep, struct model_outputs *out)
{
    int rc;
    memset(out, 0, sizeof *out);
    if (!m->arena)
        return model_fail(m, F4D_EINVAL, "model: model_eval before model_prepare");
    if ((rc = check_shape(m, S, H, W)) < 0)
        return rc;
    /* Each dimension within the prepared one: the kernel scratch Prepare
     * reserved grows with each of them (a wider frame of fewer patches would
     * need wider resize tables and RoPE spans than were reserved). */
    if (S > m->max_S || H > m->max_H || W > m->max_W)
        return model_fail(m, F4D_EINVAL, "model: %d views of %dx%d exceed the %d views of "
                          "%dx%d (max) planned by model_prepare", S, W, H, m->max_S, m->max_W,
                          m->max_H);
    /* Fits when every part of this frame set's plan fits the prepared one. */
    const int p = m->cfg.patch_size;
    const size_t P1 = (size_t)(1 + m->cfg.num_register_tokens + (H / p) * (W / p));
    const size_t P1max = (size_t)(1 + m->cfg.num_register_tokens + (m->max_H / p) * (m->max_W / p));
    size_t ap, as;
    plan_sizes(&m->cfg, model_stream_groups(m), m->keep, S, H, W, &ap, &as);
    int fits = (size_t)S * P1 <= (size_t)m->max_S * P1max && as <= m->scratch_bytes &&
               (size_t)(H / p) * (W / p) <= (size_t)(m->max_H / p) * (m->max_W / p);
    for (int i = 0; fits && i < m->n_heads; i++) {
        size_t hp, hs;
        m->head_ops[i]->plan(m->head[i], S, H, W, &hp, &hs);
        fits = hp <= m->head_persist_bytes[i] && hs <= m->scratch_bytes;
    }
    if (!fits)
        return model_fail(m, F4D_EINVAL, "model: %d views of %dx%d exceed the arena planned "
                          "for %d views of %dx%d", S, W, H, m->max_S, m->max_W, m->max_H);
    for (int i = 0; i < ST_COUNT; i++)
        m->st_sec[i] = m->st_flops[i] = 0;
    if (m->stream)
        model_stream_begin(m, S, H, W);
    rc = run_network(m, images, S, H, W, (int)P1, patch_keep, out);
    if (m->stream) /* a failed step leaves no usable motion inputs */
        model_stream_end(m, S, H, W, rc == 0, out);
    return rc;
}

static int run_network(struct model *m, const float *images, int S, int H, int W, int P1,
                       const uint8_t *patch_keep, struct model_outputs *out)
{
    const int p = m->cfg.patch_size;
    int rc;
    if ((rc = model_aggregator_eval(m, images, S, H, W, patch_keep)) < 0)
        return rc;
    out->masked = m->tok_masked;
    for (int f = 0; f < S; f++)
        out->view_tokens[f] = m->tok_off[f + 1] - m->tok_off[f];
    out->total_tokens = m->tok_off[S];
    out->S = S;
    out->H = H;
    out->W = W;
    out->gauge = 1.0f;
    struct model_run run = {
        .m = m, .cfg = &m->cfg, .S = S, .H = H, .W = W, .h = H / p, .w = W / p,
        .P = (H / p) * (W / p), .tokens = P1, .layers = (const float *const *)m->layers,
        .images = images,
        .scratch = m->scratch, .scratch_bytes = m->scratch_bytes, .out = out,
    };
    for (int i = 0; i < m->n_heads; i++) {
        double t0 = model_now();
        m->flops = &m->st_flops[ST_HEAD0 + i];
        if ((rc = m->head_ops[i]->eval(m->head[i], &run, m->head_persist[i])) < 0)
            return rc;
        m->st_sec[ST_HEAD0 + i] += model_now() - t0;
    }
    return 0;
}

int model_stages(const struct model *m, struct model_stage *st, int cap)
{
    static const char *names[ST_HEAD0] = { "patch_embed", "dino_blocks", "frame_blocks",
                                           "global_blocks", "state_blocks", "motion_blocks" };
    int n = 0;
    for (int i = 0; i < ST_HEAD0 + m->n_heads && n < cap; i++) {
        if (i == ST_DINO && m->cfg.patch_embed != MODEL_PATCH_DINO)
            continue;
        if ((i == ST_STATE && !(m->groups & MODEL_G_STATE)) ||
            (i == ST_MOTION && !(model_stream_groups(m) & MODEL_G_MOTION)))
            continue;
        st[n].name = i < ST_HEAD0 ? names[i] : m->head_ops[i - ST_HEAD0]->prefix;
        st[n].seconds = m->st_sec[i];
        st[n].flops = m->st_flops[i];
        n++;
    }
    return n;
}

void model_free(struct model *m)
{
    if (!m)
        return;
    for (int i = 0; i < m->n_heads; i++)
        m->head_ops[i]->free(m->head[i]);
    model_aggregator_free(m);
    model_stream_free(m);
    model_fusion_free(m);
    if (m->froze_ctx)
        fk_ctx_freeze(m->ctx, 0);
    free(m->arena);
    if (m->owns_gf)
        gguf_close(m->gf);
    free(m);
}

const char *model_error(const struct model *m) { return m->err.msg; }
const struct model_config *model_get_config(const struct model *m) { return &m->cfg; }
fk_ctx *model_ctx(struct model *m) { return m->ctx; }
enum fk_wtype model_wtype(const struct model *m) { return m->wtype; }
size_t model_arena_bytes(const struct model *m) { return m->arena_bytes; }
size_t model_weight_bytes(const struct model *m) { return m->weight_bytes; }
unsigned model_groups(const struct model *m) { return m->groups; }

const float *model_layer(const struct model *m, int l)
{
    return l >= 0 && l < m->cfg.depth ? m->layers[l] : NULL;
}

int model_token_rows(const struct model *m, const int **off, const int32_t **row)
{
    if (off)
        *off = m->tok_off;
    if (row)
        *row = m->row;
    return m->tok_off[m->tok_S];
}

void model_set_tap(struct model *m, model_tap_fn fn, void *user)
{
    m->tap = fn;
    m->tap_user = user;
}

void model_set_hooks(struct model *m, const struct model_hooks *hooks)
{
    if (hooks)
        m->hooks = *hooks;
    else
        memset(&m->hooks, 0, sizeof m->hooks);
}
