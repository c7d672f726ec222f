/* fuzz_gguf.c - libFuzzer harness for the GGUF reader and the model's Init.
 *
 * The input is a weight file. It is opened with gguf_open_memory (the parser
 * gguf_open uses), every key is read through every getter, every tensor is
 * checked to lie inside the buffer, aligned to its element size; when the
 * forge4d.* metadata reads as a config whose schema is small (<= 64 MiB at
 * f32, model_schema_bytes), the model's Init validates and packs the weights
 * at f32 and at int8. Failures must be statuses with a message, never a crash,
 * leak or sanitizer report.
 *
 * The bytes are copied into a buffer aligned to GGUF_MAX_ALIGN and of exactly
 * the input's length (posix_memalign: ASan then sees reads past its end).
 */
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "f4d_status.h"
#include "fk_ctx.h"
#include "gguf.h"
#include "model.h"

#define SCHEMA_LIMIT (UINT64_C(64) << 20)

static void read_keys(gguf_file *f)
{
    for (size_t i = 0; i < gguf_key_count(f); i++) {
        const char *k = gguf_key_name(f, i);
        F4D_ASSERT(k && *k);
        F4D_ASSERT(gguf_key_type(f, k) >= 0);
        int64_t v, arr[16];
        double d;
        const char *s;
        size_t n;
        int rc = gguf_get_int(f, k, &v);
        F4D_ASSERT(rc == 0 || *gguf_error(f));
        rc = gguf_get_float(f, k, &d);
        F4D_ASSERT(rc == 0 || *gguf_error(f));
        rc = gguf_get_str(f, k, &s);
        F4D_ASSERT(rc == 0 ? strlen(s) < GGUF_NAME_MAX * 2 : *gguf_error(f) != 0);
        rc = gguf_get_int_array(f, k, arr, 16, &n);
        F4D_ASSERT(rc == 0 ? n <= 16 : *gguf_error(f) != 0);
    }
    F4D_ASSERT(gguf_key_name(f, gguf_key_count(f)) == NULL);
}

static void check_tensors(gguf_file *f, const uint8_t *buf, size_t size)
{
    for (size_t i = 0; i < gguf_tensor_count(f); i++) {
        const struct gguf_tensor *t = gguf_tensor_at(f, i);
        size_t es = gguf_type_size(t->type);
        F4D_ASSERT(es > 0 && t->n_dims >= 1 && t->n_dims <= GGUF_MAX_DIMS);
        F4D_ASSERT(t->nbytes == t->n_elements * es);
        const uint8_t *p = t->data;
        F4D_ASSERT(p >= buf && p <= buf + size && t->nbytes <= (size_t)(buf + size - p));
        F4D_ASSERT((uintptr_t)p % es == 0);
        F4D_ASSERT(gguf_find_tensor(f, t->name) == t);
        /* Touch the first and last byte: ASan sees any miscomputed bound. */
        volatile uint8_t sink = p[0];
        sink = p[t->nbytes - 1];
        (void)sink;
    }
    F4D_ASSERT(gguf_tensor_at(f, gguf_tensor_count(f)) == NULL);
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);
int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    static fk_ctx *ctx;
    if (!ctx && fk_ctx_new(&(struct fk_ctx_config){ .isa = FK_ISA_AUTO, .threads = 1 }, &ctx))
        abort();
    void *buf = NULL;
    if (posix_memalign(&buf, GGUF_MAX_ALIGN, size ? size : 1))
        return 0;
    if (size)
        memcpy(buf, data, size);
    struct f4d_err err = {0};
    gguf_file *f = NULL;
    int rc = gguf_open_memory(buf, size, &f, &err);
    if (rc < 0) {
        F4D_ASSERT(f == NULL && err.msg[0] && (rc == F4D_EFORMAT || rc == F4D_ENOMEM));
        free(buf);
        return 0;
    }
    read_keys(f);
    check_tensors(f, buf, size);
    struct model_config cfg;
    if (model_config_read(f, &cfg, &err) == 0 &&
        model_schema_bytes(&cfg, MODEL_G_ALL) <= SCHEMA_LIMIT) {
        static const enum fk_wtype wts[2] = { FK_W_F32, FK_W_Q8 };
        for (int i = 0; i < 2; i++) {
            struct model *m = NULL;
            err.msg[0] = 0;
            rc = model_init_gguf(ctx, f, wts[i], &m, &err);
            F4D_ASSERT(rc == 0 ? m != NULL : (m == NULL && err.msg[0] != 0));
            model_free(m);
        }
    }
    gguf_close(f);
    free(buf);
    return 0;
}
