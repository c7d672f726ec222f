/* model_stream.c - Forge4D's state blocks and motion blocks (forge4d-arch.md
 * 4-5), run inside the aggregator, with their memory carried between Evals.
 *
 * State block l (after global block l, on x [S*P', C] and the state s_l of
 * the last step, [16, C], kept in the arena):
 *   x  = x  + ls_r * Attn_r(q = norm_x(x),   kv = norm_s(s_l))      read
 *   s' = s_l + ls_w * Attn_w(q = norm_s2(s_l), kv = norm_x2(x))     write
 *   s' = s' + ls_m * MLP(norm_m(s'))                               (s_l <- s')
 * Motion, per layer l of motion_layers (model.h; the DPT layers by default,
 * every layer in forge4d-arch.md 5): z_l(t) = in_proj_l(F_l(t)) (F_l = frame
 * || global half, the global half after the state block); with a previous
 * step, two streams run block l (per view, 2-D RoPE on q and k), l0 the
 * first layer of the set:
 *   M1 run: h  = z_l0(t)   | h  + z_l(t),   kv = z_l(t-1)
 *   M2 run: h' = z_l0(t-1) | h' + z_l(t-1), kv = z_l(t)
 *   h = h + ls1 * CrossAttn(q = norm1(h), kv = norm_kv(kv)); h = h + ls2 * MLP(norm2(h))
 * then z_l(t) replaces z_l(t-1) (each is read by block l only, so one copy per
 * motion layer suffices). The streams after the blocks the motion head reads are kept
 * for it (model_motion.c).
 *
 * Masked step (model_eval_masked, the aggregator stream x packed: the kept
 * tokens only, m->row maps them to their full rows): the state block reads
 * into the kept rows and writes from them only. z_l(t) is in_proj of the kept
 * rows; a dropped row keeps z_l(t-1) (its layer row is the reused one). Both
 * runs take their queries from the kept rows (M1: z(t), M2: z(t-1) at the same
 * rows) and their keys / values from the full grid of the other time; the
 * keys' K / V of z(t) are those of z(t-1) (computed once, for M1) with the
 * kept rows replaced, so the full grid is projected once per layer. Kept
 * motion stream rows of dropped patches stay the last step's; the motion
 * head zeroes M1 / M2 at the dropped patches' pixels (model_motion.c). The
 * masked path with every row kept computes what the unmasked one does.
 *
 * Cross-attention: q Linear C -> C, kv Linear C -> 2C (k then v), proj;
 * num_heads heads, no qk-norm. LayerNorm eps 1e-5 throughout. */
#include <stdlib.h>
#include <string.h>

#include "model_internal.h"

struct xattn {
    struct fk_linear q, kv, proj;
};

struct state_blk {
    const float *nxw, *nxb, *nsw, *nsb, *ns2w, *ns2b, *nx2w, *nx2b, *nmw, *nmb;
    const float *ls_r, *ls_w, *ls_m;
    struct xattn r, w;
    struct fk_linear fc1, fc2;
};

struct motion_blk {
    const float *n1w, *n1b, *nkw, *nkb, *n2w, *n2b, *g1, *g2;
    struct xattn a;
    struct fk_linear fc1, fc2, in_proj;
};

struct model_stream {
    int                has_state, has_motion;
    const float       *tokens;            /* [16, C] */
    struct state_blk  *sb;                /* [depth] */
    struct motion_blk *mb;                /* [depth], filled at the motion layers */
    int                n_sb, n_mb;        /* loaded (for freeing) */
    uint64_t           mmask;             /* motion layers (model_motion_mask) */
    int                first;             /* lowest motion layer */
    /* arena, persistent */
    float             *state;             /* [depth][16][C] */
    float             *zprev;             /* [motion layers][nmax][C] */
    float             *hkeep[2][4];       /* [nmax][C] after block dpt_layer_idx[i] */
    size_t             nmax;
    /* arena, aggregator-phase scratch */
    float             *cat, *zc, *h[2], *lnk, *s_ln, *s_q, *s_kv, *s_o, *s_hid;
    int32_t           *posfull;           /* [P'][2] RoPE positions of a full view */
    /* time; streams_ok: the last step ran the motion, so z(t-1) and the kept
     * motion streams are complete (a masked step may reuse their rows) */
    int                has_prev, prev_S, prev_H, prev_W, step, motion_now, streams_ok;
};

/* ---- load ---------------------------------------------------------------- */

static int load_xattn(struct model *m, struct xattn *a, const char *p, int C)
{
    char wn[MODEL_NAME_MAX + 32], bn[MODEL_NAME_MAX + 32];
    int rc;
#define LIN(field, sub, nout) \
    snprintf(wn, sizeof wn, "%s." sub ".weight", p); \
    snprintf(bn, sizeof bn, "%s." sub ".bias", p); \
    if ((rc = model_load_linear(m, &a->field, wn, bn, nout, C)) < 0) return rc;
    LIN(q, "q", C) LIN(kv, "kv", 2 * C) LIN(proj, "proj", C)
#undef LIN
    return 0;
}

static void free_xattn(struct xattn *a)
{
    fk_linear_free(&a->q);
    fk_linear_free(&a->kv);
    fk_linear_free(&a->proj);
}

static int load_state_blk(struct model *m, struct state_blk *b, int l)
{
    const int C = m->cfg.embed_dim, hid = model_mlp_hidden(&m->cfg, C);
    char p[MODEL_NAME_MAX], n1[MODEL_NAME_MAX + 32], n2[MODEL_NAME_MAX + 32];
    int rc;
    snprintf(p, sizeof p, "state.blocks.%d", l);
#define VEC(field, suffix) \
    snprintf(n1, sizeof n1, "%s." suffix, p); \
    if ((rc = model_load_f32(m, n1, (size_t)C, &b->field)) < 0) return rc;
    VEC(nxw, "norm_x.weight") VEC(nxb, "norm_x.bias") VEC(nsw, "norm_s.weight")
    VEC(nsb, "norm_s.bias") VEC(ns2w, "norm_s2.weight") VEC(ns2b, "norm_s2.bias")
    VEC(nx2w, "norm_x2.weight") VEC(nx2b, "norm_x2.bias") VEC(nmw, "norm_m.weight")
    VEC(nmb, "norm_m.bias") VEC(ls_r, "ls_r.gamma") VEC(ls_w, "ls_w.gamma")
    VEC(ls_m, "ls_m.gamma")
#undef VEC
    snprintf(n1, sizeof n1, "%s.attn_r", p);
    if ((rc = load_xattn(m, &b->r, n1, C)) < 0)
        return rc;
    snprintf(n1, sizeof n1, "%s.attn_w", p);
    if ((rc = load_xattn(m, &b->w, n1, C)) < 0)
        return rc;
    snprintf(n1, sizeof n1, "%s.mlp.fc1.weight", p);
    snprintf(n2, sizeof n2, "%s.mlp.fc1.bias", p);
    if ((rc = model_load_linear(m, &b->fc1, n1, n2, hid, C)) < 0)
        return rc;
    snprintf(n1, sizeof n1, "%s.mlp.fc2.weight", p);
    snprintf(n2, sizeof n2, "%s.mlp.fc2.bias", p);
    return model_load_linear(m, &b->fc2, n1, n2, C, hid);
}

static int load_motion_blk(struct model *m, struct motion_blk *b, int l)
{
    const int C = m->cfg.embed_dim, hid = model_mlp_hidden(&m->cfg, C);
    char p[MODEL_NAME_MAX], n1[MODEL_NAME_MAX + 32], n2[MODEL_NAME_MAX + 32];
    int rc;
    snprintf(n1, sizeof n1, "motion.in_proj.%d.weight", l);
    snprintf(n2, sizeof n2, "motion.in_proj.%d.bias", l);
    if ((rc = model_load_linear(m, &b->in_proj, n1, n2, C, 2 * C)) < 0)
        return rc;
    snprintf(p, sizeof p, "motion.blocks.%d", l);
#define VEC(field, suffix) \
    snprintf(n1, sizeof n1, "%s." suffix, p); \
    if ((rc = model_load_f32(m, n1, (size_t)C, &b->field)) < 0) return rc;
    VEC(n1w, "norm1.weight") VEC(n1b, "norm1.bias") VEC(nkw, "norm_kv.weight")
    VEC(nkb, "norm_kv.bias") VEC(n2w, "norm2.weight") VEC(n2b, "norm2.bias")
    VEC(g1, "ls1.gamma") VEC(g2, "ls2.gamma")
#undef VEC
    snprintf(n1, sizeof n1, "%s.attn", p);
    if ((rc = load_xattn(m, &b->a, n1, C)) < 0)
        return rc;
    snprintf(n1, sizeof n1, "%s.mlp.fc1.weight", p);
    snprintf(n2, sizeof n2, "%s.mlp.fc1.bias", p);
    if ((rc = model_load_linear(m, &b->fc1, n1, n2, hid, C)) < 0)
        return rc;
    snprintf(n1, sizeof n1, "%s.mlp.fc2.weight", p);
    snprintf(n2, sizeof n2, "%s.mlp.fc2.bias", p);
    return model_load_linear(m, &b->fc2, n1, n2, C, hid);
}

int model_stream_load(struct model *m)
{
    const int has_state = !!(m->groups & MODEL_G_STATE);
    const int has_motion = !!(m->groups & MODEL_G_MOTION);
    if (has_motion != !!(m->groups & MODEL_G_MOTION_HEAD))
        return model_fail(m, F4D_EFORMAT, "model: motion.* and motion_head.* must come together "
                          "(the file has only %s)", has_motion ? "motion.*" : "motion_head.*");
    if (!has_state && !has_motion)
        return 0;
    const int depth = m->cfg.depth, C = m->cfg.embed_dim;
    if ((C / m->cfg.num_heads) % 4)
        return model_fail(m, F4D_EFORMAT, "model: motion blocks need a head dim that is a "
                          "multiple of 4 (2-D RoPE), got %d", C / m->cfg.num_heads);
    struct model_stream *s = calloc(1, sizeof *s);
    if (!s)
        return model_fail(m, F4D_ENOMEM, "model: out of memory for the state / motion blocks");
    m->stream = s;
    s->has_state = has_state;
    s->has_motion = has_motion;
    int rc;
    if (has_state) {
        if ((rc = model_load_f32(m, "state.tokens", (size_t)MODEL_STATE_TOKENS * C, &s->tokens)) < 0)
            return rc;
        if (!(s->sb = calloc((size_t)depth, sizeof *s->sb)))
            return model_fail(m, F4D_ENOMEM, "model: out of memory for the state blocks");
        for (int l = 0; l < depth; l++, s->n_sb++)
            if ((rc = load_state_blk(m, &s->sb[l], l)) < 0) {
                s->n_sb++; /* partly packed: freed too (zeroed fields are fine) */
                return rc;
            }
    }
    if (has_motion) {
        if (!(s->mb = calloc((size_t)depth, sizeof *s->mb)))
            return model_fail(m, F4D_ENOMEM, "model: out of memory for the motion blocks");
        s->n_mb = depth; /* all freed: the ones not loaded are zeroed */
        s->mmask = model_motion_mask(&m->cfg);
        s->first = -1;
        for (int l = 0; l < depth; l++) {
            if (!((s->mmask >> l) & 1))
                continue;
            if (s->first < 0)
                s->first = l;
            if ((rc = load_motion_blk(m, &s->mb[l], l)) < 0)
                return rc;
        }
    }
    return 0;
}

void model_stream_drop_motion(struct model *m)
{
    if (m->stream)
        m->stream->has_motion = 0;
}

unsigned model_stream_groups(const struct model *m)
{
    const unsigned motion = MODEL_G_MOTION | MODEL_G_MOTION_HEAD;
    return m->stream && !m->stream->has_motion ? m->groups & ~motion : m->groups;
}

void model_stream_free(struct model *m)
{
    struct model_stream *s = m->stream;
    if (!s)
        return;
    for (int l = 0; l < s->n_sb; l++) {
        free_xattn(&s->sb[l].r);
        free_xattn(&s->sb[l].w);
        fk_linear_free(&s->sb[l].fc1);
        fk_linear_free(&s->sb[l].fc2);
    }
    for (int l = 0; l < s->n_mb; l++) {
        free_xattn(&s->mb[l].a);
        fk_linear_free(&s->mb[l].fc1);
        fk_linear_free(&s->mb[l].fc2);
        fk_linear_free(&s->mb[l].in_proj);
    }
    free(s->sb);
    free(s->mb);
    free(s);
    m->stream = NULL;
}

/* ---- memory -------------------------------------------------------------- */

static size_t rows_of(const struct model_config *c, int S, int H, int W)
{
    const int p = c->patch_size;
    return (size_t)S * (size_t)(1 + c->num_register_tokens + (H / p) * (W / p));
}

static int motion_count(const struct model_config *c)
{
    const uint64_t mm = model_motion_mask(c);
    int n = 0;
    for (int l = 0; l < c->depth; l++)
        n += (int)((mm >> l) & 1);
    return n;
}

/* Persistent part, in this order: state, z(t-1), the kept motion streams. */
static void persist_layout(struct bump *b, const struct model_config *c, int has_state,
                           int has_motion, size_t nmax, struct model_stream *s)
{
    const size_t C = (size_t)c->embed_dim;
    float *p = has_state ? BUMP_F(b, (size_t)c->depth * MODEL_STATE_TOKENS * C) : NULL;
    if (s)
        s->state = p;
    if (!has_motion)
        return;
    p = BUMP_F(b, (size_t)motion_count(c) * nmax * C);
    if (s)
        s->zprev = p;
    for (int r = 0; r < 2; r++)
        for (int i = 0; i < 4; i++) {
            p = BUMP_F(b, nmax * C);
            if (s)
                s->hkeep[r][i] = p;
        }
}

/* Aggregator-phase scratch, after the aggregator's own buffers. */
static void scratch_layout(struct bump *b, const struct model_config *c, int has_state,
                           int has_motion, size_t n, struct model_stream *s)
{
    const size_t C = (size_t)c->embed_dim, hid = (size_t)model_mlp_hidden(c, c->embed_dim);
    const size_t Ns = MODEL_STATE_TOKENS;
    struct model_stream tmp;
    if (!s)
        s = &tmp;
    s->cat = s->zc = s->h[0] = s->h[1] = s->lnk = NULL;
    s->s_ln = s->s_q = s->s_kv = s->s_o = s->s_hid = NULL;
    s->posfull = NULL;
    if (has_state) {
        s->s_ln = BUMP_F(b, Ns * C);
        s->s_q = BUMP_F(b, Ns * C);
        s->s_kv = BUMP_F(b, Ns * 2 * C);
        s->s_o = BUMP_F(b, Ns * C);
        s->s_hid = BUMP_F(b, Ns * hid);
    }
    if (has_motion) {
        s->cat = BUMP_F(b, n * 2 * C);
        s->zc = BUMP_F(b, n * C);
        s->h[0] = BUMP_F(b, n * C);
        s->h[1] = BUMP_F(b, n * C);
        s->lnk = BUMP_F(b, n * C);
        s->posfull = bump_take(b, n * 2 * sizeof(int32_t));
    }
}

void model_stream_plan(const struct model_config *c, unsigned groups, int S, int H, int W,
                       size_t *persist, size_t *scratch)
{
    const int st = !!(groups & MODEL_G_STATE), mo = !!(groups & MODEL_G_MOTION);
    struct bump pb = { NULL, 0 }, sb = { NULL, 0 };
    persist_layout(&pb, c, st, mo, rows_of(c, S, H, W), NULL);
    scratch_layout(&sb, c, st, mo, rows_of(c, S, H, W), NULL);
    *persist = pb.off;
    *scratch = sb.off;
}

void model_stream_place(struct model *m, struct bump *b)
{
    struct model_stream *s = m->stream;
    if (!s)
        return;
    s->nmax = rows_of(&m->cfg, m->max_S, m->max_H, m->max_W);
    persist_layout(b, &m->cfg, s->has_state, s->has_motion, s->nmax, s);
}

void model_stream_scratch(struct model *m, struct bump *b, int S, int H, int W)
{
    struct model_stream *s = m->stream;
    scratch_layout(b, &m->cfg, s->has_state, s->has_motion, rows_of(&m->cfg, S, H, W), s);
    if (!s->posfull)
        return;
    const int p = m->cfg.patch_size, w = W / p, ns = 1 + m->cfg.num_register_tokens;
    const int P1 = ns + (H / p) * w;
    for (int t = 0; t < P1; t++) { /* as the aggregator's: specials (0, 0) */
        s->posfull[2 * t] = t < ns ? 0 : (t - ns) / w + 1;
        s->posfull[2 * t + 1] = t < ns ? 0 : (t - ns) % w + 1;
    }
}

void model_state_reset(struct model *m)
{
    struct model_stream *s = m->stream;
    if (!s)
        return;
    const size_t sz = (size_t)MODEL_STATE_TOKENS * (size_t)m->cfg.embed_dim;
    if (s->has_state && s->state)
        for (int l = 0; l < m->cfg.depth; l++)
            memcpy(s->state + (size_t)l * sz, s->tokens, sz * sizeof(float));
    s->has_prev = 0;
    s->step = 0;
    s->motion_now = 0;
    s->streams_ok = 0;
}

void model_stream_begin(struct model *m, int S, int H, int W)
{
    struct model_stream *s = m->stream;
    /* The measuring pass of model_prepare runs the motion too: its kernels'
     * scratch is reserved like every other's. */
    s->motion_now = s->has_motion &&
                    (m->measuring || (s->has_prev && s->prev_S == S && s->prev_H == H &&
                                      s->prev_W == W));
}

void model_stream_end(struct model *m, int S, int H, int W, int ok, struct model_outputs *out)
{
    struct model_stream *s = m->stream;
    s->has_prev = ok && s->has_motion;
    s->streams_ok = ok && s->motion_now;
    s->prev_S = S;
    s->prev_H = H;
    s->prev_W = W;
    if (ok)
        s->step++;
    if (out)
        out->step = s->step;
}

int model_stream_mask_ok(const struct model *m)
{
    const struct model_stream *s = m->stream;
    return !s || !s->has_motion || (s->motion_now && s->streams_ok && !m->measuring);
}

int model_stream_motion_now(const struct model *m)
{
    return m->stream && m->stream->motion_now;
}

const float *model_stream_h(const struct model *m, int run, int i)
{
    return m->stream->hkeep[run][i];
}

/* ---- eval ---------------------------------------------------------------- */

/* out [nq, C] = Attn(q [nq, C] (ld C), k / v [nk, C] (ld 2C, v at +C)); RoPE
 * positions pos_q / pos_k of the two sides, or both NULL. */
static int attend(struct model *m, const float *q, int nq, const float *kv, int nk,
                  const int32_t *pos_q, const int32_t *pos_k, float *out)
{
    const int C = m->cfg.embed_dim, heads = m->cfg.num_heads;
    struct fk_attention_desc a = {
        .heads = heads, .head_dim = C / heads, .pos_q = pos_q, .pos_k = pos_k,
        .rope_base = 100.0f, .bf16 = m->wtype == FK_W_Q8, .int16 = m->wtype == FK_W_Q8, /* as the blocks' */
    };
    if (fk_attention(m->ctx, &a, q, C, nq, kv, 2 * C, kv + C, 2 * C, nk, out, C) != F4D_OK)
        return model_kfail(m, "cross-attention");
    *m->flops += 4.0 * nq * (double)nk * C;
    return 0;
}

static int ln(struct model *m, const float *x, int rows, const float *w, const float *b, float *y)
{
    const int C = m->cfg.embed_dim;
    if (fk_layernorm(m->ctx, x, rows, C, C, w, b, 1e-5f, y, C) != F4D_OK)
        return model_kfail(m, "layernorm");
    return 0;
}

/* One cross-attention of a state block (no RoPE): LayerNorm both sides,
 * project q from q_src and kv from kv_src, attend, and add the projection
 * through epi (LayerScale, accumulate) into out. */
struct xattn_io {
    const float *q_src, *q_nw, *q_nb, *kv_src, *kv_nw, *kv_nb;
    int          nq, nkv;
    float       *q_ln, *kv_ln, *q, *kv, *o, *out;
};

static int cross_attend(struct model *m, const struct xattn *a, const struct xattn_io *io,
                        const struct fk_epilogue *epi)
{
    const int C = m->cfg.embed_dim;
    int rc;
    if ((rc = ln(m, io->q_src, io->nq, io->q_nw, io->q_nb, io->q_ln)) < 0 ||
        (rc = ln(m, io->kv_src, io->nkv, io->kv_nw, io->kv_nb, io->kv_ln)) < 0 ||
        (rc = model_linear(m, &a->q, io->q_ln, io->nq, C, io->q, C, NULL)) < 0 ||
        (rc = model_linear(m, &a->kv, io->kv_ln, io->nkv, C, io->kv, 2 * C, NULL)) < 0 ||
        (rc = attend(m, io->q, io->nq, io->kv, io->nkv, NULL, NULL, io->o)) < 0)
        return rc;
    return model_linear(m, &a->proj, io->o, io->nq, C, io->out, C, epi);
}

static int state_block(struct model *m, const struct state_blk *b, float *x, int n, float *st,
                       const struct blk_bufs *bb)
{
    struct model_stream *s = m->stream;
    const int C = m->cfg.embed_dim, hid = model_mlp_hidden(&m->cfg, C), Ns = MODEL_STATE_TOKENS;
    struct fk_epilogue acc_r = { .gamma = b->ls_r, .accumulate = 1 };
    struct fk_epilogue acc_w = { .gamma = b->ls_w, .accumulate = 1 };
    struct fk_epilogue acc_m = { .gamma = b->ls_m, .accumulate = 1 };
    struct fk_epilogue gelu = { .act = FK_ACT_GELU };
    int rc;
    /* read: the stream attends to the state of t-1 */
    const struct xattn_io rd = { .q_src = x, .nq = n, .q_nw = b->nxw, .q_nb = b->nxb, .q_ln = bb->ln,
                                 .kv_src = st, .nkv = Ns, .kv_nw = b->nsw, .kv_nb = b->nsb, .kv_ln = s->s_ln,
                                 .q = bb->qkv, .kv = s->s_kv, .o = bb->o, .out = x };
    /* write: the state attends to the stream after the read */
    const struct xattn_io wr = { .q_src = st, .nq = Ns, .q_nw = b->ns2w, .q_nb = b->ns2b, .q_ln = s->s_ln,
                                 .kv_src = x, .nkv = n, .kv_nw = b->nx2w, .kv_nb = b->nx2b, .kv_ln = bb->ln,
                                 .q = s->s_q, .kv = bb->qkv, .o = s->s_o, .out = st };
    if ((rc = cross_attend(m, &b->r, &rd, &acc_r)) < 0 || (rc = cross_attend(m, &b->w, &wr, &acc_w)) < 0)
        return rc;
    if ((rc = ln(m, st, Ns, b->nmw, b->nmb, s->s_ln)) < 0 ||
        (rc = model_linear(m, &b->fc1, s->s_ln, Ns, C, s->s_hid, hid, &gelu)) < 0)
        return rc;
    return model_linear(m, &b->fc2, s->s_hid, Ns, hid, st, C, &acc_m);
}

/* h [n, C] (the packed query rows, m->tok_off per view) += block(h, kv), kv
 * [S*P1, 2C] the keys' K | V over every view's full grid. */
static int motion_block(struct model *m, const struct motion_blk *b, float *h, int n,
                        const float *kv, int S, int P1, const struct blk_bufs *bb)
{
    struct model_stream *s = m->stream;
    const int C = m->cfg.embed_dim, hid = model_mlp_hidden(&m->cfg, C);
    const int *off = m->tok_off;
    struct fk_epilogue acc1 = { .gamma = b->g1, .accumulate = 1 };
    struct fk_epilogue acc2 = { .gamma = b->g2, .accumulate = 1 };
    struct fk_epilogue gelu = { .act = FK_ACT_GELU };
    float *q = bb->qkv;
    int rc;
    if ((rc = ln(m, h, n, b->n1w, b->n1b, bb->ln)) < 0 ||
        (rc = model_linear(m, &b->a.q, bb->ln, n, C, q, C, NULL)) < 0)
        return rc;
    for (int f = 0; f < S; f++) /* queries at their real cells, keys the full grid */
        if ((rc = attend(m, q + (size_t)off[f] * C, off[f + 1] - off[f],
                         kv + (size_t)f * P1 * 2 * C, P1, m->pos + 2 * (size_t)off[f],
                         s->posfull, bb->o + (size_t)off[f] * C)) < 0)
            return rc;
    if ((rc = model_linear(m, &b->a.proj, bb->o, n, C, h, C, &acc1)) < 0 ||
        (rc = ln(m, h, n, b->n2w, b->n2b, bb->ln)) < 0 ||
        (rc = model_linear(m, &b->fc1, bb->ln, n, C, bb->hid, hid, &gelu)) < 0)
        return rc;
    return model_linear(m, &b->fc2, bb->hid, n, hid, h, C, &acc2);
}

/* Packed rows [n, C] to their full rows (m->row) of dst [S*P', C]. */
static void scatter_rows(const struct model *m, float *dst, const float *src, int n, int ld_src,
                         int C)
{
    for (int r = 0; r < n; r++)
        memcpy(dst + (size_t)m->row[r] * C, src + (size_t)r * ld_src, (size_t)C * sizeof *dst);
}

int model_stream_frame(struct model *m, int layer, const float *x, int n)
{
    struct model_stream *s = m->stream;
    if (!s->has_motion || !((s->mmask >> layer) & 1))
        return 0;
    const size_t C = (size_t)m->cfg.embed_dim;
    for (int r = 0; r < n; r++)
        memcpy(s->cat + (size_t)r * 2 * C, x + (size_t)r * C, C * sizeof(float));
    return 0;
}

/* Tap "<what><l>" with the whole tensor (frame -1). */
static void tap_rows(struct model *m, const char *what, int l, const float *p, size_t count)
{
    if (!m->tap)
        return;
    char nm[48];
    snprintf(nm, sizeof nm, "%.24s%d", what, l);
    m->tap(m->tap_user, nm, -1, p, count);
}

int model_stream_global(struct model *m, int l, float *x, int S, int P1,
                        const struct blk_bufs *bb)
{
    struct model_stream *s = m->stream;
    const struct model_config *c = &m->cfg;
    const int C = c->embed_dim, nfull = S * P1, n = m->tok_off[S]; /* n: rows that ran */
    int rc;
    if (s->has_state) {
        double t0 = model_now();
        m->flops = &m->st_flops[ST_STATE];
        float *st = s->state + (size_t)l * MODEL_STATE_TOKENS * C;
        if ((rc = state_block(m, &s->sb[l], x, n, st, bb)) < 0)
            return rc;
        tap_rows(m, "state", l, st, (size_t)MODEL_STATE_TOKENS * C);
        m->st_sec[ST_STATE] += model_now() - t0;
    }
    if (!s->has_motion || !((s->mmask >> l) & 1))
        return 0;
    double t0 = model_now();
    m->flops = &m->st_flops[ST_MOTION];
    for (int r = 0; r < n; r++)
        memcpy(s->cat + (size_t)r * 2 * C + C, x + (size_t)r * C, (size_t)C * sizeof(float));
    const struct motion_blk *b = &s->mb[l];
    if ((rc = model_linear(m, &b->in_proj, s->cat, n, 2 * C, s->zc, C, NULL)) < 0)
        return rc;
    /* z(t-1) slot: the rank of l among the motion layers */
    const int slot = __builtin_popcountll(s->mmask & ((UINT64_C(1) << l) - 1));
    float *zp = s->zprev + (size_t)slot * s->nmax * C;
    if (s->motion_now) {
        /* K | V of the keys over the full grid (after the queries' C floats of qkv):
         * z(t-1) for M1, then z(t) = z(t-1) with the kept rows replaced for M2 */
        float *kv = bb->qkv + (size_t)nfull * C;
        if ((rc = ln(m, zp, nfull, b->nkw, b->nkb, s->lnk)) < 0 ||
            (rc = model_linear(m, &b->a.kv, s->lnk, nfull, C, kv, 2 * C, NULL)) < 0)
            return rc;
        for (int r = 0; r < 2; r++) {
            float *h = s->h[r];
            if (r == 0 && l == s->first) {
                memcpy(h, s->zc, (size_t)n * C * sizeof(float));
            } else if (r == 0) {
                if (fk_residual_add(m->ctx, h, C, s->zc, C, NULL, n, C) != F4D_OK)
                    return model_kfail(m, "motion input add");
            } else { /* M2's queries: z(t-1) at the rows that ran */
                for (int i = 0; i < n; i++) {
                    const float *z = zp + (size_t)m->row[i] * C;
                    float *hi = h + (size_t)i * C;
                    if (l == s->first)
                        memcpy(hi, z, (size_t)C * sizeof(float));
                    else
                        for (int j = 0; j < C; j++)
                            hi[j] += z[j];
                }
                /* the new rows of z(t) into M1's K | V (cat is free again) */
                if ((rc = ln(m, s->zc, n, b->nkw, b->nkb, s->lnk)) < 0 ||
                    (rc = model_linear(m, &b->a.kv, s->lnk, n, C, s->cat, 2 * C, NULL)) < 0)
                    return rc;
                scatter_rows(m, kv, s->cat, n, 2 * C, 2 * C);
            }
            if ((rc = motion_block(m, b, h, n, kv, S, P1, bb)) < 0)
                return rc;
            for (int i = 0; i < 4; i++)
                if (c->dpt_layer_idx[i] == l) { /* dropped rows keep the last step's */
                    scatter_rows(m, s->hkeep[r][i], h, n, C, C);
                    tap_rows(m, r ? "motion.m2h" : "motion.m1h", l, s->hkeep[r][i],
                             (size_t)nfull * C);
                }
        }
    }
    scatter_rows(m, zp, s->zc, n, C, C); /* z_l(t) is the next step's z_l(t-1) */
    m->st_sec[ST_MOTION] += model_now() - t0;
    return 0;
}
