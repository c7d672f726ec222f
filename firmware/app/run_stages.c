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
#include "fk_ctx.h"
#include "interp.h"
#include "model.h"
#include "preprocess.h"
#include "run_internal.h"

static uint64_t mono_ns(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (uint64_t)ts.tv_sec * 1000000000u + (uint64_t)ts.tv_nsec;
}

/* ---- inference: preprocess -> model (Gaussian head, metric) -> scene budget ---- */
struct infer_model {
    fk_ctx *ctx;
    struct model *m;
    int S, T, H, W;
    void *scratch;
    size_t scratch_bytes;
    float *input;
    void *budget_scratch;
    size_t budget_bytes;
    struct budget_config budget;
    uint32_t delay_ms;
};

static void infer_free(void *self)
{
    struct infer_model *im = self;
    if (!im)
        return;
    model_free(im->m);
    fk_ctx_free(im->ctx);
    free(im->scratch);
    free(im->input);
    free(im->budget_scratch);
    free(im);
}

/* The model's cameras (metric when the scale head ran) as the budget's rig:
 * it prunes Gaussians no view sees and merges sub-pixel ones. */
static void rig_from_outputs(const struct model_outputs *o, struct splat_rig *rig)
{
    const float *ext = o->extrinsic_metric ? o->extrinsic_metric : o->extrinsic;
    rig->count = o->S;
    for (int s = 0; s < o->S; s++) {
        struct splat_camera *c = &rig->cams[s];
        memset(c, 0, sizeof *c);
        snprintf(c->name, sizeof c->name, "view%d", s);
        c->width = o->W;
        c->height = o->H;
        const float *K = o->intrinsic + 9 * s, *E = ext + 12 * s;
        c->fx = K[0], c->fy = K[4], c->cx = K[2], c->cy = K[5];
        memcpy(c->w2c, E, 12 * sizeof *E);
        c->w2c[15] = 1.0f;
    }
}

static int infer_eval(struct infer_model *im, int H, int W, struct model_outputs *o, struct f4d_err *err)
{
    if (model_eval(im->m, im->input, im->S, H, W, o) < 0)
        return f4d_fail(err, F4D_EINVAL, "inference: %s", model_error(im->m));
    if (o->gaussians.count == 0 || !o->intrinsic || (!o->extrinsic && !o->extrinsic_metric))
        return f4d_fail(err, F4D_EFORMAT,
                        "inference: the weights give no Gaussians or no cameras (need Forge4D weights: "
                        "gaussian_head and camera_head)");
    return 0;
}

static int infer_key(void *self, const struct hal_set *set, struct run_key *k, struct f4d_err *err)
{
    struct infer_model *im = self;
    uint64_t t0 = mono_ns();
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
    if (H > im->H || W > im->W)
        return f4d_fail(err, F4D_EINVAL, "inference: frames preprocess to %dx%d, planned for %dx%d", W, H, im->W,
                        im->H);
    struct model_outputs o;
    if ((rc = infer_eval(im, H, W, &o, err)) < 0)
        return rc;
    struct splat_frame g = {o.gaussians.count, o.gaussians.count, o.gaussians.pos, o.gaussians.scale,
                            o.gaussians.rot, o.gaussians.opacity, o.gaussians.rgb, NULL, NULL};
    struct splat_rig rig;
    rig_from_outputs(&o, &rig);
    if ((rc = budget_prune_ws(&g, &rig, &im->budget, im->budget_scratch, im->budget_bytes, &k->f, NULL, err)) < 0)
        return rc;
    if (im->delay_ms) { /* test knob: a slow stage, end to end */
        struct timespec d = {im->delay_ms / 1000, (long)(im->delay_ms % 1000) * 1000000L};
        while (nanosleep(&d, &d) < 0 && errno == EINTR) {
        }
    }
    k->seq = set->seq;
    k->t_us = set->trigger_ts_ns / 1000u;
    k->infer_ms = (double)(mono_ns() - t0) * 1e-6;
    return 0;
}

int run_infer_model_new(struct run_infer *st, const struct run_infer_config *cfg, const struct hal_board *board,
                        struct f4d_err *err)
{
    memset(st, 0, sizeof *st);
    if (board->n_cams > MODEL_VIEWS_MAX)
        return f4d_fail(err, F4D_EINVAL, "inference: %u cameras, the model takes at most %d views", board->n_cams,
                        MODEL_VIEWS_MAX);
    struct infer_model *im = calloc(1, sizeof *im);
    if (!im)
        return f4d_fail(err, F4D_ENOMEM, "inference: out of memory");
    im->S = (int)board->n_cams;
    im->delay_ms = cfg->delay_ms;
    im->budget = budget_config_default();
    int rc;
    if (fk_ctx_new(&(struct fk_ctx_config){.isa = FK_ISA_AUTO, .threads = cfg->threads}, &im->ctx) != F4D_OK) {
        rc = f4d_fail(err, F4D_ENOMEM, "inference: cannot create the kernel context");
        goto fail;
    }
    if ((rc = model_init(im->ctx, cfg->weights, (enum fk_wtype)cfg->wtype, &im->m, err)) < 0)
        goto fail;
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
        im->H = oh > im->H ? oh : im->H;
        im->W = ow > im->W ? ow : im->W;
        size_t sb = prep_scratch_bytes((int)c->width, (int)c->height, im->T);
        im->scratch_bytes = sb > im->scratch_bytes ? sb : im->scratch_bytes;
    }
    im->scratch = malloc(im->scratch_bytes);
    im->input = malloc((size_t)im->S * 3 * (size_t)im->T * (size_t)im->T * sizeof *im->input);
    if (!im->scratch || !im->input) {
        rc = f4d_fail(err, F4D_ENOMEM, "inference: out of memory");
        goto fail;
    }
    if (model_prepare(im->m, im->S, im->H, im->W) < 0) {
        rc = f4d_fail(err, F4D_ENOMEM, "inference: %s", model_error(im->m));
        goto fail;
    }
    /* Warm-up on a grey set: checks the weights give Gaussians and cameras,
     * touches the arena (flat RSS from here) and times one key. */
    for (size_t i = 0; i < (size_t)im->S * 3 * im->H * im->W; i++)
        im->input[i] = 0.5f;
    uint64_t t0 = mono_ns();
    struct model_outputs o;
    if ((rc = infer_eval(im, im->H, im->W, &o, err)) < 0)
        goto fail;
    st->warm_ms = (double)(mono_ns() - t0) * 1e-6;
    st->capacity = o.gaussians.count;
    im->budget_bytes = budget_scratch_bytes(o.gaussians.count);
    if (!(im->budget_scratch = malloc(im->budget_bytes))) {
        rc = f4d_fail(err, F4D_ENOMEM, "inference: out of memory");
        goto fail;
    }
    st->self = im;
    st->key = infer_key;
    st->free = infer_free;
    return 0;
fail:
    infer_free(im);
    return rc;
}

/* ---- encoder: the stream codec ---- */
static int enc_header(void *self, uint64_t t_us, uint8_t *pkt, size_t *len, struct f4d_err *err)
{
    codec_enc *e = self;
    size_t cap = *len;
    int rc = codec_enc_stream_header(e, t_us, pkt, cap, len);
    return rc < 0 ? f4d_fail(err, rc, "encoder: %s", codec_enc_error(e)) : 0;
}

static int enc_key(void *self, const struct run_key *k, bool intra, uint8_t *pkt, size_t *len, struct f4d_err *err)
{
    codec_enc *e = self;
    size_t cap = *len;
    int rc = codec_enc_key(e, &k->f, k->t_us, intra ? CODEC_KEY_INTRA : CODEC_KEY_AUTO, NULL, pkt, cap, len);
    return rc < 0 ? f4d_fail(err, rc, "encoder: key %llu: %s", (unsigned long long)k->seq, codec_enc_error(e)) : 0;
}

static int enc_end(void *self, uint64_t t_us, uint8_t *pkt, size_t *len, struct f4d_err *err)
{
    codec_enc *e = self;
    size_t cap = *len;
    int rc = codec_enc_end(e, t_us, pkt, cap, len);
    return rc < 0 ? f4d_fail(err, rc, "encoder: %s", codec_enc_error(e)) : 0;
}

static void enc_free(void *self)
{
    codec_enc_free(self);
}

int run_encoder_codec_new(struct run_encoder *st, size_t capacity, const char *quality, struct f4d_err *err)
{
    memset(st, 0, sizeof *st);
    int q = codec_quality_from_name(quality, err);
    if (q < 0)
        return q;
    codec_enc *e;
    int rc = codec_enc_new(capacity ? capacity : 1, (enum codec_quality)q, &e, err);
    if (rc < 0)
        return rc;
    st->self = e;
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
        st->write = tx_write;
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
