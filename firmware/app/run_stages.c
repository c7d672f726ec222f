/* run_stages.c: the stages `forge4d run` plugs into its threads
 * (run_internal.h): inference on the model, the stream codec, a file sink.
 * Everything is allocated at _new; key / write allocate nothing. */
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "f4d_codec.h"
#ifdef F4D_RUN_HAVE_TRANSPORT
#include "f4d_transport.h"
#endif
#include "f4d_sequence.h"
#include "fk_ctx.h"
#include "interp.h"
#include "model.h"
#include "preprocess.h"
#include "run_internal.h"

/* ---- inference: preprocess -> Forge4D sequence (state, motions, metric
 * cameras) -> scene budget ----
 * With motion weights a key leaves one push late: key t-1 gets its forward
 * motion M2[t-1] only when set t has run, and the codec predicts key t from
 * key t-1 moved by that motion, so key t-1 must carry it when encoded. */
struct infer_seq {
    fk_ctx *ctx;
    struct model *m;
    f4d_sequence *sq;
    int S, T, H, W;
    void *scratch;
    size_t scratch_bytes;
    float *input;
    void *budget_scratch;
    size_t budget_bytes;
    struct budget_config budget;
    uint32_t *origin;          /* [n] budget output -> pixel-aligned index */
    int32_t *pix[2];           /* [n] pixel -> output index of the last two keys out (ping-pong) */
    int cur;                   /* pix[cur]: the last key out */
    bool have_prev;            /* pix[cur] and prev_seq are valid */
    uint64_t prev_seq;
    size_t n;                  /* views * H * W */
    bool motion, held;         /* held: the newest key waits for its forward motion */
    uint64_t held_seq, held_t_us, held_arrive, held_delivery, held_start;
    double held_ms, held_prep_ms, held_model_ms, held_prep_cpu_ms;
    uint32_t delay_ms;
    struct splat_rig rig;      /* cameras of the last key out */
    bool have_rig;
};

static void infer_free(void *self)
{
    struct infer_seq *im = self;
    if (!im)
        return;
    f4d_sequence_close(im->sq);
    model_free(im->m);
    fk_ctx_free(im->ctx);
    free(im->scratch);
    free(im->input);
    free(im->budget_scratch);
    free(im->origin);
    free(im->pix[0]);
    free(im->pix[1]);
    free(im);
}

/* Key `which` of the sequence through the budget into k, with the codec's
 * match against the key out before it (same pixel origin). */
static int infer_emit(struct infer_seq *im, int which, uint64_t seq, struct run_key *k, struct f4d_err *err)
{
    struct f4d_seq_key sk;
    int rc = f4d_sequence_key(im->sq, which, &sk, err);
    if (rc < 0)
        return rc;
    if ((rc = budget_prune_origin_ws(&sk.frame, &sk.rig, &im->budget, im->budget_scratch, im->budget_bytes, &k->f,
                                     im->origin, NULL, err)) < 0)
        return rc;
    int32_t *prev = im->pix[im->cur], *next = im->pix[1 - im->cur];
    for (size_t i = 0; i < im->n; i++)
        next[i] = -1;
    for (size_t j = 0; j < k->f.count; j++) {
        uint32_t p = im->origin[j];
        next[p] = (int32_t)j;
        if (k->match)
            k->match[j] = im->have_prev ? prev[p] : -1;
    }
    k->match_ref = im->have_prev ? im->prev_seq : UINT64_MAX;
    k->seq = seq;
    im->rig = sk.rig;
    im->have_rig = true;
    im->prev_seq = seq;
    im->cur = 1 - im->cur;
    im->have_prev = true;
    return 0;
}

static void infer_delay(const struct infer_seq *im)
{
    if (im->delay_ms) { /* test knob: a slow stage, end to end */
        struct timespec d = {im->delay_ms / 1000, (long)(im->delay_ms % 1000) * 1000000L};
        while (nanosleep(&d, &d) < 0 && errno == EINTR) {
        }
    }
}

static int infer_key(void *self, const struct hal_set *set, struct run_key *k, struct f4d_err *err)
{
    struct infer_seq *im = self;
    uint64_t t0 = mono_ns();
    double c0 = thread_cpu_ms();
    struct prep_image ims[MODEL_VIEWS_MAX];
    for (int i = 0; i < im->S; i++) {
        const struct hal_buffer *b = set->frames[i];
        if (!b || b->status != HAL_FRAME_OK)
            return f4d_fail(err, F4D_EINVAL, "inference: set %llu has no good frame from camera %d",
                            (unsigned long long)set->seq, i);
        const struct hal_format *f = &b->format;
        size_t stride = f->stride ? f->stride : (size_t)f->width * hal_pixfmt_bytes_per_pixel(f->pixfmt);
        ims[i] = (struct prep_image){b->data, (int)f->width, (int)f->height, stride, (int)f->pixfmt};
    }
    int H, W;
    int rc = prep_batch(ims, im->S, PREP_CROP, im->T, im->scratch, im->scratch_bytes, im->input, &H, &W, err);
    if (rc < 0)
        return rc;
    uint64_t t1 = mono_ns();
    double prep_cpu_ms = thread_cpu_ms() - c0;
    if (H != im->H || W != im->W)
        return f4d_fail(err, F4D_EINVAL, "inference: frames preprocess to %dx%d, the sequence runs at %dx%d", W, H,
                        im->W, im->H);
    if ((rc = f4d_sequence_push(im->sq, im->input, err)) < 0) {
        im->held = im->have_prev = false; /* the sequence restarted: no key to finish, no reference */
        return rc;
    }
    uint64_t t2 = mono_ns();
    infer_delay(im);
    double ms = (double)(mono_ns() - t0) * 1e-6;
    double prep_ms = (double)(t1 - t0) * 1e-6, model_ms = (double)(t2 - t1) * 1e-6;
    uint64_t seq = set->seq, t_us = set->trigger_ts_ns / 1000u, arrive = k->arrive_wall_ns,
             delivery = k->delivery_ns, start = k->infer_start_ns;
    if (!im->motion) { /* no motion: this set's key now */
        uint64_t b0 = mono_ns();
        double bc0 = thread_cpu_ms();
        if ((rc = infer_emit(im, 0, seq, k, err)) < 0)
            return rc;
        k->budget_cpu_ms = thread_cpu_ms() - bc0;
        k->prep_cpu_ms = prep_cpu_ms;
        k->t_us = t_us;
        k->prep_ms = prep_ms;
        k->model_ms = model_ms;
        k->budget_ms = (double)(mono_ns() - b0) * 1e-6;
        k->infer_ms = (double)(mono_ns() - t0) * 1e-6;
        return 1;
    }
    bool out = im->held && f4d_sequence_steps(im->sq) >= 2;
    if (out) { /* key t-1, now with both motions, under its own set's times */
        uint64_t b0 = mono_ns();
        double bc0 = thread_cpu_ms();
        if ((rc = infer_emit(im, 1, im->held_seq, k, err)) < 0) {
            im->held = false;
            return rc;
        }
        k->budget_cpu_ms = thread_cpu_ms() - bc0;
        k->prep_cpu_ms = im->held_prep_cpu_ms;
        k->t_us = im->held_t_us;
        k->arrive_wall_ns = im->held_arrive;
        k->delivery_ns = im->held_delivery;
        k->infer_start_ns = im->held_start;
        k->prep_ms = im->held_prep_ms;
        k->model_ms = im->held_model_ms;
        k->budget_ms = (double)(mono_ns() - b0) * 1e-6;
        k->infer_ms = im->held_ms + k->budget_ms;
    }
    im->held = true;
    im->held_seq = seq;
    im->held_t_us = t_us;
    im->held_arrive = arrive;
    im->held_delivery = delivery;
    im->held_start = start;
    im->held_ms = ms;
    im->held_prep_ms = prep_ms;
    im->held_prep_cpu_ms = prep_cpu_ms;
    im->held_model_ms = model_ms;
    return out ? 1 : 0;
}

static int infer_flush(void *self, struct run_key *k, struct f4d_err *err)
{
    struct infer_seq *im = self;
    if (!im->held)
        return 0;
    im->held = false;
    uint64_t b0 = mono_ns();
    double bc0 = thread_cpu_ms();
    int rc = infer_emit(im, 0, im->held_seq, k, err); /* the newest key: no forward motion (zero) */
    if (rc < 0)
        return rc;
    k->budget_cpu_ms = thread_cpu_ms() - bc0;
    k->prep_cpu_ms = im->held_prep_cpu_ms;
    k->t_us = im->held_t_us;
    k->arrive_wall_ns = im->held_arrive;
    k->delivery_ns = im->held_delivery;
    k->infer_start_ns = im->held_start;
    k->prep_ms = im->held_prep_ms;
    k->model_ms = im->held_model_ms;
    k->budget_ms = (double)(mono_ns() - b0) * 1e-6;
    k->infer_ms = im->held_ms + k->budget_ms;
    return 1;
}

static int infer_rig(void *self, struct splat_rig *out)
{
    struct infer_seq *im = self;
    if (!im->have_rig)
        return 0;
    *out = im->rig;
    return 1;
}

int run_infer_model_new(struct run_infer *st, const struct run_infer_config *cfg, const struct hal_board *board,
                        struct f4d_err *err)
{
    memset(st, 0, sizeof *st);
    if (board->n_cams > MODEL_VIEWS_MAX)
        return f4d_fail(err, F4D_EINVAL, "inference: %u cameras, the model takes at most %d views", board->n_cams,
                        MODEL_VIEWS_MAX);
    struct infer_seq *im = calloc(1, sizeof *im);
    if (!im)
        return f4d_fail(err, F4D_ENOMEM, "inference: out of memory");
    im->S = (int)board->n_cams;
    im->delay_ms = cfg->delay_ms;
    im->budget = cfg->budget ? *cfg->budget : budget_config_default();
    int rc;
    if (fk_ctx_new(&(struct fk_ctx_config){.isa = FK_ISA_AUTO, .threads = cfg->threads}, &im->ctx) != F4D_OK) {
        rc = f4d_fail(err, F4D_ENOMEM, "inference: cannot create the kernel context");
        goto fail;
    }
    if ((rc = model_init(im->ctx, cfg->weights, (enum fk_wtype)cfg->wtype, &im->m, err)) < 0)
        goto fail;
    /* the stream carries Gaussians and cameras: the depth head's map would go
     * unread (a third of the DPT work of a key) */
    if ((rc = model_skip_head(im->m, "depth_head")) < 0) {
        rc = f4d_fail(err, rc, "inference: %s", model_error(im->m));
        goto fail;
    }
    /* motion off: nothing reads the motion head's maps (about a third of a
     * key's model time here), and no key waits one set for its forward
     * motion; the keys go out without motion (the sequence sees none) */
    if (cfg->motion_off && (rc = model_skip_head(im->m, "motion_head")) < 0) {
        rc = f4d_fail(err, rc, "inference: %s", model_error(im->m));
        goto fail;
    }
    im->T = model_get_config(im->m)->img_size;
    for (int i = 0; i < im->S; i++) {
        const struct hal_camera_config *c = &board->cams[i];
        if (c->pixfmt != HAL_PIXFMT_RGB8 && c->pixfmt != HAL_PIXFMT_MONO8 && c->pixfmt != HAL_PIXFMT_BAYER_RG8) {
            rc = f4d_fail(err, F4D_ENOTSUP, "inference: camera %s delivers %s; preprocessing takes rgb8, mono8, "
                          "bayer_rg8", c->id, hal_pixfmt_name(c->pixfmt));
            goto fail;
        }
        int ow, oh;
        if ((rc = prep_output_size((int)c->width, (int)c->height, PREP_CROP, im->T, &ow, &oh)) < 0) {
            rc = f4d_fail(err, F4D_EINVAL, "inference: camera %s: %ux%u frames do not preprocess to %d", c->id,
                          c->width, c->height, im->T);
            goto fail;
        }
        if (i > 0 && (ow != im->W || oh != im->H)) {
            rc = f4d_fail(err, F4D_ENOTSUP, "inference: camera %s preprocesses to %dx%d, camera %s to %dx%d; the "
                          "sequence takes one size", c->id, ow, oh, board->cams[0].id, im->W, im->H);
            goto fail;
        }
        im->H = oh;
        im->W = ow;
        size_t sb = prep_scratch_bytes((int)c->width, (int)c->height, im->T);
        im->scratch_bytes = sb > im->scratch_bytes ? sb : im->scratch_bytes;
    }
    im->scratch = malloc(im->scratch_bytes);
    im->input = malloc((size_t)im->S * 3 * (size_t)im->T * (size_t)im->T * sizeof *im->input);
    if (!im->scratch || !im->input) {
        rc = f4d_fail(err, F4D_ENOMEM, "inference: out of memory");
        goto fail;
    }
    if ((rc = f4d_sequence_open_model(im->m, im->S, im->H, im->W, &im->sq, err)) < 0)
        goto fail;
    im->motion = f4d_sequence_has_motion(im->sq) != 0 && !cfg->motion_off;
    /* Warm-up on a grey set straight on the model (not a key: the state is
     * reset after it): checks the weights give Gaussians and cameras,
     * touches the arena (flat RSS from here) and times one key. */
    for (size_t i = 0; i < (size_t)im->S * 3 * im->H * im->W; i++)
        im->input[i] = 0.5f;
    uint64_t t0 = mono_ns();
    struct model_outputs o;
    if (model_eval(im->m, im->input, im->S, im->H, im->W, &o) < 0) {
        rc = f4d_fail(err, F4D_EINVAL, "inference: %s", model_error(im->m));
        goto fail;
    }
    st->warm_ms = (double)(mono_ns() - t0) * 1e-6;
    model_state_reset(im->m);
    im->n = (size_t)im->S * (size_t)im->H * (size_t)im->W;
    st->capacity = im->n;
    st->motion = im->motion;
    im->budget_bytes = budget_scratch_bytes(im->n);
    im->budget_scratch = malloc(im->budget_bytes);
    im->origin = malloc(im->n * sizeof *im->origin);
    im->pix[0] = malloc(im->n * sizeof *im->pix[0]);
    im->pix[1] = malloc(im->n * sizeof *im->pix[1]);
    if (!im->budget_scratch || !im->origin || !im->pix[0] || !im->pix[1]) {
        rc = f4d_fail(err, F4D_ENOMEM, "inference: out of memory");
        goto fail;
    }
    st->self = im;
    st->key = infer_key;
    st->flush = infer_flush;
    st->rig = infer_rig;
    st->free = infer_free;
    return 0;
fail:
    infer_free(im);
    return rc;
}

/* ---- encoder: the stream codec ---- */
struct enc {
    codec_enc *e;
    uint64_t last_seq;  /* the key the decoder holds (the codec's reference) */
    bool have_last;
};

static int enc_header(void *self, uint64_t t_us, uint8_t *pkt, size_t *len, struct f4d_err *err)
{
    codec_enc *e = ((struct enc *)self)->e;
    size_t cap = *len;
    int rc = codec_enc_stream_header(e, t_us, pkt, cap, len);
    return rc < 0 ? f4d_fail(err, rc, "encoder: %s", codec_enc_error(e)) : 0;
}

static int enc_key(void *self, const struct run_key *k, bool intra, uint8_t *pkt, size_t *len, struct f4d_err *err)
{
    struct enc *en = self;
    size_t cap = *len;
    /* The match names the key inference put out before this one; when the
     * stream dropped that key the reference differs: code this key intra. */
    if (k->match && !(en->have_last && en->last_seq == k->match_ref))
        intra = true;
    int rc = codec_enc_key(en->e, &k->f, k->t_us, intra ? CODEC_KEY_INTRA : CODEC_KEY_AUTO, intra ? NULL : k->match,
                           pkt, cap, len);
    if (rc < 0) {
        en->have_last = false;
        return f4d_fail(err, rc, "encoder: key %llu: %s", (unsigned long long)k->seq, codec_enc_error(en->e));
    }
    en->last_seq = k->seq;
    en->have_last = true;
    return 0;
}

static int enc_end(void *self, uint64_t t_us, uint8_t *pkt, size_t *len, struct f4d_err *err)
{
    codec_enc *e = ((struct enc *)self)->e;
    size_t cap = *len;
    int rc = codec_enc_end(e, t_us, pkt, cap, len);
    return rc < 0 ? f4d_fail(err, rc, "encoder: %s", codec_enc_error(e)) : 0;
}

static void enc_free(void *self)
{
    struct enc *en = self;
    if (en)
        codec_enc_free(en->e);
    free(en);
}

int run_encoder_codec_new(struct run_encoder *st, size_t capacity, const char *quality, const char *effort,
                          struct f4d_err *err)
{
    memset(st, 0, sizeof *st);
    int q = codec_quality_from_name(quality, err);
    if (q < 0)
        return q;
    int ef = codec_effort_from_name(effort, err);
    if (ef < 0)
        return ef;
    struct enc *en = calloc(1, sizeof *en);
    if (!en)
        return f4d_fail(err, F4D_ENOMEM, "encoder: out of memory");
    int rc = codec_enc_new(capacity ? capacity : 1, (enum codec_quality)q, &en->e, err);
    if (rc < 0) {
        free(en);
        return rc;
    }
    rc = codec_enc_set_effort(en->e, ef);
    if (rc < 0) {
        f4d_fail(err, rc, "encoder: %s", codec_enc_error(en->e));
        codec_enc_free(en->e);
        free(en);
        return rc;
    }
    st->self = en;
    st->packet_cap = codec_packet_bound(capacity ? capacity : 1);
    st->header = enc_header;
    st->key = enc_key;
    st->end = enc_end;
    st->free = enc_free;
    return 0;
}

/* ---- sink without the transport: a stream file (packets back to back,
 * flushed per packet so a reader can follow it) ---- */
struct file_sink {
    FILE *f;
    char path[512];
};

static int file_write(void *self, const uint8_t *pkt, size_t len, struct f4d_err *err)
{
    struct file_sink *s = self;
    if (fwrite(pkt, 1, len, s->f) != len || fflush(s->f) != 0)
        return f4d_fail(err, F4D_EIO, "stream %s: write failed: %s", s->path, strerror(errno));
    return 0;
}

static int file_close(void *self, struct f4d_err *err)
{
    struct file_sink *s = self;
    int rc = fclose(s->f) != 0 ? f4d_fail(err, F4D_EIO, "stream %s: close failed: %s", s->path, strerror(errno)) : 0;
    free(s);
    return rc;
}

#ifdef F4D_RUN_HAVE_TRANSPORT
/* ---- sink: the stream transport (srt://..., file:PATH) ---- */
static int tx_write(void *self, const uint8_t *pkt, size_t len, struct f4d_err *err)
{
    transport_tx *tx = self;
    int rc = transport_tx_send(tx, pkt, len);
    return rc < 0 ? f4d_fail(err, rc, "stream: %s", transport_tx_error(tx)) : 0;
}

/* file:PATH: the transport writes through stdio, whose buffer would keep a
 * packet's tail (up to a block) until the next key's packet pushes it out; a
 * display following the file would then see key k only one key interval
 * later. Flushed per packet, as the plain file sink does. */
static int tx_write_file(void *self, const uint8_t *pkt, size_t len, struct f4d_err *err)
{
    transport_tx *tx = self;
    int rc = transport_tx_send(tx, pkt, len);
    if (rc == 0)
        rc = transport_tx_drain(tx, 0);
    return rc < 0 ? f4d_fail(err, rc, "stream: %s", transport_tx_error(tx)) : 0;
}

static int tx_close(void *self, struct f4d_err *err)
{
    (void)err;
    transport_tx_close(self, 2000); /* drains what SRT still holds */
    return 0;
}
#endif

int run_sink_open(struct run_sink *st, const char *url, size_t max_packet, struct f4d_err *err)
{
    memset(st, 0, sizeof *st);
    const char *path = url;
#ifdef F4D_RUN_HAVE_TRANSPORT
    if (!strncmp(url, "srt://", 6) || !strncmp(url, "file:", 5)) {
        transport_tx *tx;
        struct transport_opts o = {.max_packet = max_packet};
        int rc = transport_tx_open(url, &o, &tx, err);
        if (rc < 0)
            return rc;
        st->self = tx;
        st->write = strncmp(url, "file:", 5) ? tx_write : tx_write_file;
        st->close = tx_close;
        return 0;
    }
    if (strstr(url, "://"))
        return f4d_fail(err, F4D_ENOTSUP, "stream %s: srt://HOST:PORT or file:PATH", url);
#else
    (void)max_packet;
    if (!strncmp(url, "file:", 5))
        path = url + 5;
    else if (strstr(url, "://"))
        return f4d_fail(err, F4D_ENOTSUP, "stream %s: only file:PATH is built in (built without the SRT transport)",
                        url);
#endif
    if (!*path || strlen(path) >= sizeof ((struct file_sink *)0)->path)
        return f4d_fail(err, F4D_EINVAL, "stream %s: bad file path", url);
    struct file_sink *s = calloc(1, sizeof *s);
    if (!s)
        return f4d_fail(err, F4D_ENOMEM, "stream: out of memory");
    snprintf(s->path, sizeof s->path, "%s", path);
    s->f = fopen(path, "wb");
    if (!s->f) {
        int rc = f4d_fail(err, F4D_EIO, "stream %s: %s", path, strerror(errno));
        free(s);
        return rc;
    }
    st->self = s;
    st->write = file_write;
    st->close = file_close;
    return 0;
}
