/* test_gguf.c - the GGUF reader refuses every malformed file by name, the
 * writer round-trips, the model's Init validates tensors against the
 * metadata, and f4d-convert refuses bad checkpoints.
 *
 *   test_gguf GGUF_DIR F4D_CONVERT FIXTURE_DIR
 */
#include <inttypes.h>
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/wait.h>
#include <cmocka.h>

#include "gguf.h"
#include "model.h"

static const char *gguf_dir, *convert_bin, *fix_dir;
static char tmp_path[1024];

/* A small valid file: a few keys and three tensors. */
static void write_small(const char *path)
{
    gguf_writer *w = gguf_writer_new();
    assert_non_null(w);
    assert_int_equal(gguf_writer_add_str(w, "general.architecture", "test"), 0);
    assert_int_equal(gguf_writer_add_int(w, "t.u8", GGUF_V_UINT8, 200), 0);
    assert_int_equal(gguf_writer_add_int(w, "t.i64", GGUF_V_INT64, -5), 0);
    assert_int_equal(gguf_writer_add_f32(w, "t.f", 0.25f), 0);
    int64_t arr[3] = { 4, 11, 17 };
    assert_int_equal(gguf_writer_add_int_array(w, "t.arr", GGUF_V_INT32, arr, 3), 0);
    int64_t s1[2] = { 3, 5 }, s2[1] = { 7 }, s3[3] = { 2, 2, 2 };
    assert_int_equal(gguf_writer_add_tensor(w, "a.weight", GGUF_T_F32, 2, s1), 0);
    assert_int_equal(gguf_writer_add_tensor(w, "b.bias", GGUF_T_F16, 1, s2), 0);
    assert_int_equal(gguf_writer_add_tensor(w, "c.q", GGUF_T_I8, 3, s3), 0);
    assert_int_equal(gguf_writer_begin(w, path), 0);
    float a[15];
    uint16_t b[7];
    int8_t c[8];
    for (int i = 0; i < 15; i++)
        a[i] = (float)i;
    for (int i = 0; i < 7; i++)
        b[i] = (uint16_t)(0x3c00 + i);
    for (int i = 0; i < 8; i++)
        c[i] = (int8_t)(i - 4);
    assert_int_equal(gguf_writer_write(w, a, sizeof a), 0);
    assert_int_equal(gguf_writer_write(w, b, sizeof b), 0);
    assert_int_equal(gguf_writer_write(w, c, sizeof c), 0);
    assert_int_equal(gguf_writer_finish(w), 0);
    gguf_writer_free(w);
}

static unsigned char *slurp(const char *path, size_t *n)
{
    FILE *f = fopen(path, "rb");
    assert_non_null(f);
    fseek(f, 0, SEEK_END);
    *n = (size_t)ftell(f);
    fseek(f, 0, SEEK_SET);
    unsigned char *p = malloc(*n);
    assert_int_equal(fread(p, 1, *n, f), *n);
    fclose(f);
    return p;
}

static void spit(const char *path, const unsigned char *p, size_t n)
{
    FILE *f = fopen(path, "wb");
    assert_non_null(f);
    assert_int_equal(fwrite(p, 1, n, f), n);
    fclose(f);
}

/* Opens a modified copy and expects failure whose message contains `what`. */
static void expect_bad(const unsigned char *p, size_t n, const char *what)
{
    struct f4d_err err = {0};
    gguf_file *f = NULL;
    spit(tmp_path, p, n);
    int rc = gguf_open(tmp_path, &f, &err);
    if (rc == 0 || !strstr(err.msg, what))
        print_error("expected failure with '%s', got rc %d '%s'\n", what, rc, err.msg);
    assert_true(rc < 0);
    assert_null(f);
    assert_non_null(strstr(err.msg, what));
}

static size_t find(const unsigned char *p, size_t n, const char *s)
{
    size_t k = strlen(s);
    for (size_t i = 0; i + k <= n; i++)
        if (!memcmp(p + i, s, k))
            return i;
    fail_msg("'%s' not in file", s);
    return 0;
}

static void test_roundtrip(void **state)
{
    (void)state;
    write_small(tmp_path);
    struct f4d_err err = {0};
    gguf_file *f;
    assert_int_equal(gguf_open(tmp_path, &f, &err), 0);
    int64_t v;
    double d;
    const char *s;
    assert_int_equal(gguf_get_int(f, "t.u8", &v), 0);
    assert_int_equal(v, 200);
    assert_int_equal(gguf_get_int(f, "t.i64", &v), 0);
    assert_int_equal(v, -5);
    assert_int_equal(gguf_get_float(f, "t.f", &d), 0);
    assert_true(d == 0.25);
    assert_int_equal(gguf_get_str(f, "general.architecture", &s), 0);
    assert_string_equal(s, "test");
    int64_t arr[8];
    size_t na;
    assert_int_equal(gguf_get_int_array(f, "t.arr", arr, 8, &na), 0);
    assert_int_equal(na, 3);
    assert_int_equal(arr[2], 17);
    assert_int_equal(gguf_get_int_array(f, "t.arr", arr, 2, &na), F4D_EFORMAT);
    assert_int_equal(gguf_get_int(f, "t.nope", &v), F4D_ENOENT);
    assert_non_null(strstr(gguf_error(f), "t.nope"));
    assert_int_equal(gguf_get_float(f, "t.u8", &d), F4D_ETYPE);
    assert_int_equal(gguf_tensor_count(f), 3);
    const struct gguf_tensor *t = gguf_find_tensor(f, "a.weight");
    assert_non_null(t);
    assert_int_equal(t->ne[0], 5);
    assert_int_equal(t->ne[1], 3);
    assert_int_equal((uintptr_t)t->data % 32, 0);
    assert_true(((const float *)t->data)[14] == 14.0f);
    const int64_t good[2] = { 3, 5 }, bad[2] = { 5, 3 };
    assert_int_equal(gguf_expect_tensor(f, "a.weight", GGUF_T_F32, 2, good, &t), 0);
    assert_int_equal(gguf_expect_tensor(f, "a.weight", GGUF_T_F32, 2, bad, &t), F4D_EFORMAT);
    assert_non_null(strstr(gguf_error(f), "'a.weight' has shape [3,5], expected [5,3]"));
    assert_int_equal(gguf_expect_tensor(f, "a.weight", GGUF_T_F16, 2, good, &t), F4D_ETYPE);
    assert_non_null(strstr(gguf_error(f), "type F32, expected F16"));
    t = gguf_find_tensor(f, "c.q");
    assert_int_equal(((const int8_t *)t->data)[0], -4);
    gguf_close(f);
}

static void test_every_truncation_fails(void **state)
{
    (void)state;
    write_small(tmp_path);
    size_t n;
    unsigned char *p = slurp(tmp_path, &n);
    for (size_t k = 0; k < n - 1; k++) {
        /* the final tensor's padding is not data: cutting only padding is fine */
        struct f4d_err err = {0};
        gguf_file *f = NULL;
        spit(tmp_path, p, k);
        int rc = gguf_open(tmp_path, &f, &err);
        if (rc == 0) {
            /* only acceptable when every tensor still fits */
            assert_true(k >= n - 24);
            gguf_close(f);
        } else {
            assert_null(f);
            assert_true(strlen(err.msg) > 0);
        }
    }
    free(p);
}

static void test_corruptions_named(void **state)
{
    (void)state;
    write_small(tmp_path);
    size_t n;
    unsigned char *p = slurp(tmp_path, &n), *q = malloc(n);
    uint64_t u64;
    uint32_t u32;

    memcpy(q, p, n); q[0] = 'X';
    expect_bad(q, n, "bad magic");
    memcpy(q, p, n); q[4] = 2;
    expect_bad(q, n, "version 2");
    /* tensor count far beyond the file */
    memcpy(q, p, n); u64 = UINT64_C(1) << 40; memcpy(q + 8, &u64, 8);
    expect_bad(q, n, "cannot fit");
    /* a key's string length past the end */
    memcpy(q, p, n); u64 = UINT64_C(1) << 50; memcpy(q + 24, &u64, 8);
    expect_bad(q, n, "past the end");
    /* tensor info of a.weight: name, n_dims, ne[0], ne[1], type, offset */
    size_t ti = find(p, n, "a.weight") + 8;
    memcpy(q, p, n); u32 = 5; memcpy(q + ti, &u32, 4);
    expect_bad(q, n, "'a.weight': 5 dims");
    memcpy(q, p, n); u64 = 0; memcpy(q + ti + 4, &u64, 8);
    expect_bad(q, n, "'a.weight': dim 0 = 0");
    memcpy(q, p, n); u32 = 2; memcpy(q + ti + 20, &u32, 4);   /* Q4_0 */
    expect_bad(q, n, "'a.weight': unsupported type 2");
    memcpy(q, p, n); u64 = 4; memcpy(q + ti + 24, &u64, 8);
    expect_bad(q, n, "'a.weight': offset 4 not aligned");
    memcpy(q, p, n); u64 = 1 << 20; memcpy(q + ti + 24, &u64, 8);
    expect_bad(q, n, "'a.weight': bytes");
    /* b.bias moved onto a.weight's bytes */
    size_t tb = find(p, n, "b.bias") + 6;
    memcpy(q, p, n); u64 = 32; memcpy(q + tb + 16, &u64, 8);
    expect_bad(q, n, "overlap");
    /* duplicate tensor name: rename c.q to a.weight is longer; rename b.bias -> a.wei */
    memcpy(q, p, n);
    size_t cq = find(p, n, "c.q");
    q[cq] = 'a'; q[cq + 1] = '.'; q[cq + 2] = 'q';
    size_t bb = find(p, n, "b.bias");
    memcpy(q + bb - 8, &(uint64_t){ 3 }, 8); /* shorten b.bias -> "b.b" breaks layout */
    expect_bad(q, n, "gguf");
    /* alignment key that is not a power of two */
    size_t al = find(p, n, "general.alignment") + 17 + 4;
    memcpy(q, p, n); u32 = 24; memcpy(q + al, &u32, 4);
    expect_bad(q, n, "not a power of two");
    /* unknown metadata value type */
    size_t ty = find(p, n, "t.u8") + 4;
    memcpy(q, p, n); u32 = 99; memcpy(q + ty, &u32, 4);
    expect_bad(q, n, "key 't.u8': unknown value type 99");
    /* nested array */
    size_t at = find(p, n, "t.arr") + 5 + 4;
    memcpy(q, p, n); u32 = GGUF_V_ARRAY; memcpy(q + at, &u32, 4);
    expect_bad(q, n, "nested arrays");
    free(p);
    free(q);
}

/* general.alignment below 8 could place an F32 / I64 tensor on an address
 * that is not a multiple of its element size (UB when read as float): refused,
 * as are alignments above a page, which a mapping cannot honour. */
static void test_alignment_range(void **state)
{
    (void)state;
    write_small(tmp_path);
    size_t n;
    unsigned char *p = slurp(tmp_path, &n), *q = malloc(n);
    size_t al = find(p, n, "general.alignment") + 17 + 4;
    static const uint32_t bad[] = { 1, 2, 4, 8192, 65536 };
    char want[96];
    for (size_t i = 0; i < sizeof bad / sizeof bad[0]; i++) {
        memcpy(q, p, n);
        memcpy(q + al, &bad[i], 4);
        snprintf(want, sizeof want, "'general.alignment' = %u out of 8..4096", bad[i]);
        expect_bad(q, n, want);
    }
    /* 8 is accepted, and every tensor then sits on an 8-byte boundary */
    memcpy(q, p, n);
    memcpy(q + al, &(uint32_t){ 8 }, 4);
    spit(tmp_path, q, n);
    struct f4d_err err = {0};
    gguf_file *f;
    assert_int_equal(gguf_open(tmp_path, &f, &err), 0);
    assert_int_equal(gguf_alignment(f), 8);
    for (size_t i = 0; i < gguf_tensor_count(f); i++)
        assert_int_equal((uintptr_t)gguf_tensor_at(f, i)->data % 8, 0);
    gguf_close(f);
    free(p);
    free(q);
}

/* The committed fuzzer findings (tests/model/fuzz/seeds/) stay refused. */
static void test_fuzz_seeds_refused(void **state)
{
    (void)state;
    static const struct { const char *file, *msg; } seeds[] = {
        { "align1_f32.gguf", "'general.alignment' = 1 out of 8..4096" },
    };
    for (size_t i = 0; i < sizeof seeds / sizeof seeds[0]; i++) {
        char path[1200];
        struct f4d_err err = {0};
        snprintf(path, sizeof path, "%s/../fuzz/seeds/%s", fix_dir, seeds[i].file);
        gguf_file *f = NULL;
        int rc = gguf_open(path, &f, &err);
        if (rc != F4D_EFORMAT || !strstr(err.msg, seeds[i].msg))
            fail_msg("%s: rc %d '%s', expected F4D_EFORMAT '%s'", seeds[i].file, rc, err,
                     seeds[i].msg);
        assert_null(f);
    }
}

/* ---- gguf_open_memory: the same parser over a caller's buffer ------------- */

/* A copy of p[0..n) in a buffer of exactly n bytes aligned to GGUF_MAX_ALIGN. */
static unsigned char *aligned_copy(const unsigned char *p, size_t n)
{
    void *b = NULL;
    assert_int_equal(posix_memalign(&b, GGUF_MAX_ALIGN, n ? n : 1), 0);
    if (n)
        memcpy(b, p, n);
    return b;
}

static void same_file(gguf_file *a, gguf_file *b)
{
    assert_int_equal(gguf_alignment(a), gguf_alignment(b));
    assert_int_equal(gguf_file_size(a), gguf_file_size(b));
    assert_int_equal(gguf_key_count(a), gguf_key_count(b));
    for (size_t i = 0; i < gguf_key_count(a); i++) {
        const char *k = gguf_key_name(a, i);
        assert_string_equal(k, gguf_key_name(b, i));
        assert_int_equal(gguf_key_type(a, k), gguf_key_type(b, k));
        int64_t va = 0, vb = 0;
        assert_int_equal(gguf_get_int(a, k, &va), gguf_get_int(b, k, &vb));
        assert_true(va == vb);
    }
    assert_int_equal(gguf_tensor_count(a), gguf_tensor_count(b));
    for (size_t i = 0; i < gguf_tensor_count(a); i++) {
        const struct gguf_tensor *x = gguf_tensor_at(a, i), *y = gguf_tensor_at(b, i);
        assert_string_equal(x->name, y->name);
        assert_int_equal(x->n_dims, y->n_dims);
        assert_memory_equal(x->ne, y->ne, sizeof x->ne);
        assert_int_equal(x->type, y->type);
        assert_int_equal(x->offset, y->offset);
        assert_int_equal(x->nbytes, y->nbytes);
        assert_memory_equal(x->data, y->data, x->nbytes);
        assert_ptr_equal(gguf_find_tensor(b, x->name), y);
    }
}

static void test_open_memory_matches_open(void **state)
{
    (void)state;
    char path[1100];
    struct f4d_err err = {0};
    write_small(tmp_path);
    const char *files[2] = { tmp_path, path };
    snprintf(path, sizeof path, "%s/tiny_int8.gguf", gguf_dir);
    for (int k = 0; k < 2; k++) {
        size_t n;
        unsigned char *p = slurp(files[k], &n), *b = aligned_copy(p, n);
        gguf_file *a, *m;
        assert_int_equal(gguf_open(files[k], &a, &err), 0);
        assert_int_equal(gguf_open_memory(b, n, &m, &err), 0);
        same_file(a, m);
        /* zero copy: tensors point into the caller's buffer */
        const struct gguf_tensor *t = gguf_tensor_at(m, 0);
        assert_true((const unsigned char *)t->data >= b &&
                    (const unsigned char *)t->data + t->nbytes <= b + n);
        if (k == 1) {
            /* the model's Init on either gives the same packed model */
            fk_ctx *ctx;
            struct fk_ctx_config cc = { .isa = FK_ISA_AUTO, .threads = 1 };
            assert_int_equal(fk_ctx_new(&cc, &ctx), F4D_OK);
            struct model *ma, *mm;
            assert_int_equal(model_init(ctx, files[k], FK_W_Q8, &ma, &err), 0);
            assert_int_equal(model_init_gguf(ctx, m, FK_W_Q8, &mm, &err), 0);
            assert_int_equal(model_weight_bytes(ma), model_weight_bytes(mm));
            assert_memory_equal(model_get_config(ma), model_get_config(mm),
                                sizeof(struct model_config));
            model_free(mm);   /* borrows m: m stays open */
            model_free(ma);
            assert_ptr_equal(gguf_find_tensor(m, t->name), t);
            fk_ctx_free(ctx);
        }
        gguf_close(a);
        gguf_close(m);
        free(b);
        free(p);
    }
}

static void expect_bad_memory(const unsigned char *p, size_t n, int code, const char *what)
{
    unsigned char *b = aligned_copy(p, n);
    struct f4d_err err = {0};
    gguf_file *f = (gguf_file *)1;
    int rc = gguf_open_memory(b, n, &f, &err);
    if (rc != code || (what && !strstr(err.msg, what)) || !err.msg[0])
        fail_msg("memory: expected %s '%s', got rc %d '%s'", f4d_status_name(code),
                 what ? what : "", rc, err);
    assert_null(f);
    free(b);
}

static void test_open_memory_refuses(void **state)
{
    (void)state;
    write_small(tmp_path);
    size_t n;
    unsigned char *p = slurp(tmp_path, &n);
    /* every truncation: F4D_EFORMAT with a message (ASan sees any read past
     * the end of the exactly sized buffer) */
    for (size_t k = 0; k < n - 24; k++)
        expect_bad_memory(p, k, F4D_EFORMAT, "gguf: ");
    expect_bad_memory(p, 10, F4D_EFORMAT, "too small");
    /* garbage: random bytes, then random bytes behind a valid magic/version */
    unsigned char *g = malloc(n);
    uint32_t x = 12345;
    for (int round = 0; round < 64; round++) {
        for (size_t i = 0; i < n; i++) {
            x = x * 1664525u + 1013904223u;
            g[i] = (unsigned char)(x >> 24);
        }
        if (round & 1)
            memcpy(g, p, 8);
        expect_bad_memory(g, n, F4D_EFORMAT, "gguf: ");
    }
    free(g);
    /* a buffer not on the file's alignment (32): refused as an argument */
    void *vb = NULL;
    assert_int_equal(posix_memalign(&vb, GGUF_MAX_ALIGN, n + 8), 0);
    unsigned char *b = vb;
    memcpy(b + 8, p, n);
    struct f4d_err err = {0};
    gguf_file *f;
    assert_int_equal(gguf_open_memory(b + 8, n, &f, &err), F4D_EINVAL);
    assert_non_null(strstr(err.msg, "not aligned to general.alignment 32"));
    assert_null(f);
    free(b);
    assert_int_equal(gguf_open_memory(NULL, 100, &f, &err), F4D_EINVAL);
    assert_non_null(strstr(err.msg, "NULL"));
    free(p);
}

/* ---- model Init against modified copies of the tiny weight file ---------- */

struct rewrite {
    const char *drop;        /* tensor to leave out                    */
    const char *rename_from, *rename_to;
    const char *reshape;     /* tensor whose first dim is doubled      */
    int         depth;       /* forge4d.depth override (0 = keep)      */
    const char *extra;       /* add this F32 [4] tensor                 */
    int         img_grid;    /* forge4d.img_size = patch_size * this    */
};

static void rewrite_tiny(const struct rewrite *r)
{
    char path[1024];
    struct f4d_err err = {0};
    snprintf(path, sizeof path, "%s/tiny_f16.gguf", gguf_dir);
    gguf_file *f;
    assert_int_equal(gguf_open(path, &f, &err), 0);
    struct model_config c;
    assert_int_equal(model_config_read(f, &c, &err), 0);
    if (r->depth)
        c.depth = r->depth;
    if (r->img_grid)
        c.img_size = c.patch_size * r->img_grid;
    gguf_writer *w = gguf_writer_new();
    assert_int_equal(model_config_write(&c, w), 0);
    size_t nt = gguf_tensor_count(f);
    for (size_t i = 0; i < nt; i++) {
        const struct gguf_tensor *t = gguf_tensor_at(f, i);
        if (r->drop && !strcmp(t->name, r->drop))
            continue;
        int64_t sh[4];
        for (uint32_t d = 0; d < t->n_dims; d++)
            sh[d] = (int64_t)t->ne[t->n_dims - 1 - d];
        const char *nm = t->name;
        if (r->rename_from && !strcmp(nm, r->rename_from))
            nm = r->rename_to;
        if (r->reshape && !strcmp(nm, r->reshape))
            sh[0] *= 2;
        assert_int_equal(gguf_writer_add_tensor(w, nm, t->type, (int)t->n_dims, sh), 0);
    }
    if (r->extra) {
        int64_t four = 4;
        assert_int_equal(gguf_writer_add_tensor(w, r->extra, GGUF_T_F32, 1, &four), 0);
    }
    assert_int_equal(gguf_writer_begin(w, tmp_path), 0);
    for (size_t i = 0; i < nt; i++) {
        const struct gguf_tensor *t = gguf_tensor_at(f, i);
        if (r->drop && !strcmp(t->name, r->drop))
            continue;
        size_t nb = t->nbytes;
        void *buf = calloc(1, 2 * nb);
        memcpy(buf, t->data, nb);
        if (r->reshape && !strcmp(t->name, r->reshape))
            nb *= 2;
        assert_int_equal(gguf_writer_write(w, buf, nb), 0);
        free(buf);
    }
    if (r->extra) {
        float z[4] = { 0 };
        assert_int_equal(gguf_writer_write(w, z, sizeof z), 0);
    }
    assert_int_equal(gguf_writer_finish(w), 0);
    gguf_writer_free(w);
    gguf_close(f);
}

static void expect_init_fails(const struct rewrite *r, const char *what)
{
    rewrite_tiny(r);
    fk_ctx *ctx;
    struct fk_ctx_config cc = { .isa = FK_ISA_AUTO, .threads = 1 };
    assert_int_equal(fk_ctx_new(&cc, &ctx), F4D_OK);
    struct model *m = NULL;
    struct f4d_err err = {0};
    int rc = model_init(ctx, tmp_path, FK_W_F32, &m, &err);
    if (rc == 0 || !strstr(err.msg, what))
        print_error("expected '%s', got rc %d '%s'\n", what, rc, err.msg);
    assert_true(rc < 0);
    assert_null(m);
    assert_non_null(strstr(err.msg, what));
    fk_ctx_free(ctx);
}

static void test_model_init_validates(void **state)
{
    (void)state;
    /* the unmodified copy loads */
    struct rewrite none = { 0 };
    rewrite_tiny(&none);
    fk_ctx *ctx;
    struct fk_ctx_config cc = { .isa = FK_ISA_AUTO, .threads = 1 };
    assert_int_equal(fk_ctx_new(&cc, &ctx), F4D_OK);
    struct model *m;
    struct f4d_err err = {0};
    assert_int_equal(model_init(ctx, tmp_path, FK_W_F16, &m, &err), 0);
    model_free(m);
    fk_ctx_free(ctx);

    expect_init_fails(&(struct rewrite){ .drop = "aggregator.frame_blocks.1.attn.proj.bias" },
                      "missing tensor 'aggregator.frame_blocks.1.attn.proj.bias'");
    expect_init_fails(&(struct rewrite){ .reshape = "aggregator.global_blocks.0.mlp.fc1.weight" },
                      "'aggregator.global_blocks.0.mlp.fc1.weight' has shape [128,32], expected [64,32]");
    expect_init_fails(&(struct rewrite){ .depth = 6 },
                      "missing tensor 'aggregator.frame_blocks.5.norm1.weight'");
    expect_init_fails(&(struct rewrite){ .depth = 4 }, "dpt_layer_idx[3] = 4 out of 0..3");
    /* an img_size whose pos-embed grid (1 + g*g rows) overflows int: refused by
     * the config bounds before any size is computed (UBSan saw g*g overflow) */
    expect_init_fails(&(struct rewrite){ .img_grid = 71428 },
                      "config: img_size 999992 out of patch_size 14..4096");
    expect_init_fails(&(struct rewrite){ .img_grid = 293 },
                      "config: img_size 4102 out of patch_size 14..4096");
    expect_init_fails(&(struct rewrite){ .extra = "aggregator.extra.weight" }, "unknown tensor 'aggregator.extra.weight'");
    /* Forge4D's heads are schema groups: a stray tensor is checked like the rest */
    expect_init_fails(&(struct rewrite){ .extra = "gaussian_head.norm.weight" },
                      "'gaussian_head.norm.weight' has shape [4], expected [64]");
    expect_init_fails(&(struct rewrite){ .rename_from = "point_head.norm.bias",
                                         .rename_to = "pointhead.norm.bias" },
                      "missing tensor 'point_head.norm.bias'");
}

static void test_model_prepare_refuses_unknown_group(void **state)
{
    (void)state;
    /* a tensor under a prefix no registered head owns: Init loads the known
     * groups, Prepare (after all registrations) names it */
    rewrite_tiny(&(struct rewrite){ .extra = "unknown_head.norm.weight" });
    fk_ctx *ctx;
    struct fk_ctx_config cc = { .isa = FK_ISA_AUTO, .threads = 1 };
    assert_int_equal(fk_ctx_new(&cc, &ctx), F4D_OK);
    struct model *m = NULL;
    struct f4d_err err = {0};
    assert_int_equal(model_init(ctx, tmp_path, FK_W_F32, &m, &err), 0);
    assert_int_equal(model_prepare(m, 1, 42, 70), F4D_EFORMAT);
    assert_non_null(strstr(model_error(m), "unknown tensor 'unknown_head.norm.weight'"));
    model_free(m);
    fk_ctx_free(ctx);
}

/* F16 / BF16 checkpoints give the F32 file's tensors within their rounding. */
static void test_convert_half_inputs(void **state)
{
    (void)state;
    static const char *dts[2] = { "f16", "bf16" };
    static const double tol[2] = { 1.0 / 2048, 1.0 / 256 };
    char path[1100];
    struct f4d_err err = {0};
    gguf_file *ref, *f;
    snprintf(path, sizeof path, "%s/tiny_conv_f32.gguf", gguf_dir);
    assert_int_equal(gguf_open(path, &ref, &err), 0);
    for (int k = 0; k < 2; k++) {
        snprintf(path, sizeof path, "%s/tiny_conv_from_%s.gguf", gguf_dir, dts[k]);
        assert_int_equal(gguf_open(path, &f, &err), 0);
        assert_int_equal(gguf_tensor_count(f), gguf_tensor_count(ref));
        double worst = 0;
        size_t n_differ = 0;
        for (size_t i = 0; i < gguf_tensor_count(ref); i++) {
            const struct gguf_tensor *a = gguf_tensor_at(ref, i);
            const struct gguf_tensor *b = gguf_find_tensor(f, a->name);
            assert_non_null(b);
            assert_int_equal(b->type, GGUF_T_F32);
            assert_int_equal(b->n_elements, a->n_elements);
            const float *x = a->data, *y = b->data;
            int differs = 0;
            for (uint64_t j = 0; j < a->n_elements; j++) {
                double d = fabs((double)x[j] - y[j]);
                /* NaN-aware: a NaN or Inf on either side fails here */
                if (!(d <= tol[k] * fabs((double)x[j]) + 1e-7))
                    fail_msg("%s: '%s'[%" PRIu64 "] = %g, f32 file has %g", dts[k], a->name,
                             j, (double)y[j], (double)x[j]);
                double rel = fabs(x[j]) > 1e-3 ? d / fabs(x[j]) : 0;
                if (rel > worst)
                    worst = rel;
                differs |= d > 0;
            }
            /* the fixture tensors are random: each one loses bits in f16 / bf16 */
            if (!differs)
                fail_msg("%s: '%s' equals the f32 file exactly: the half-precision "
                         "checkpoint was not rounded", dts[k], a->name);
            n_differ += (size_t)differs;
        }
        printf("  %s checkpoint -> f32 file: worst relative rounding %.3e, %zu of %zu tensors "
               "rounded\n", dts[k], worst, n_differ, gguf_tensor_count(ref));
        assert_true(worst > 0); /* the half-precision input really was rounded */
        assert_int_equal(n_differ, gguf_tensor_count(ref));
        gguf_close(f);
    }
    gguf_close(ref);
}

/* ---- f4d-convert refuses bad checkpoints ------------------------------- */

static int run_convert(const char *args, const char *expect)
{
    char cmd[4096], log[1100];
    snprintf(log, sizeof log, "%s.log", tmp_path);
    snprintf(cmd, sizeof cmd, "'%s' %s > '%s' 2>&1", convert_bin, args, log);
    int st = system(cmd);
    size_t n;
    unsigned char *p = slurp(log, &n);
    char *txt = calloc(1, n + 1);
    memcpy(txt, p, n);
    free(p);
    int found = strstr(txt, expect) != NULL;
    if (!found)
        print_error("f4d-convert %s: expected '%s' in:\n%s\n", args, expect, txt);
    free(txt);
    remove(log);
    return WIFEXITED(st) && WEXITSTATUS(st) != 0 && found;
}

static void write_safetensors(const char *path, const char *name)
{
    char hdr[256];
    int k = snprintf(hdr, sizeof hdr, "{\"%s\":{\"dtype\":\"F32\",\"shape\":[2],"
                     "\"data_offsets\":[0,8]}}", name);
    uint64_t len = (uint64_t)k;
    FILE *f = fopen(path, "wb");
    assert_non_null(f);
    fwrite(&len, 8, 1, f);
    fwrite(hdr, 1, (size_t)k, f);
    float v[2] = { 1, 2 };
    fwrite(v, 4, 2, f);
    fclose(f);
}

static void test_convert_refuses(void **state)
{
    (void)state;
    char args[4096], st[1100], out[1100];
    snprintf(st, sizeof st, "%s.safetensors", tmp_path);
    snprintf(out, sizeof out, "%s.out.gguf", tmp_path);
    write_safetensors(st, "decoder.layers.0.weight");
    snprintf(args, sizeof args, "'%s' '%s'", st, out);
    assert_true(run_convert(args, "unknown tensor name 'decoder.layers.0.weight'"));
    /* tiny weights against the VGGT-1B defaults: shapes disagree, named */
    snprintf(args, sizeof args, "'%s/tiny/weights.safetensors' '%s'", fix_dir, out);
    assert_true(run_convert(args, "'aggregator.patch_embed.patch_embed.proj.weight' has shape "
                                  "[32,3,14,14] but the config implies [1024,3,14,14]"));
    /* tiny weights with the tiny_conv config */
    snprintf(args, sizeof args, "'%s/tiny/weights.safetensors' '%s' --config '%s/tiny_conv/config.json'",
             fix_dir, out, fix_dir);
    assert_true(run_convert(args, "missing tensor 'aggregator.patch_embed.proj.weight'"));
    snprintf(args, sizeof args, "'%s' '%s' --type q4", st, out);
    assert_true(run_convert(args, "--type must be f32, f16 or int8"));
    /* nothing was written on failure */
    FILE *f = fopen(out, "rb");
    assert_null(f);
    remove(st);
}

int main(int argc, char **argv)
{
    if (argc != 4) {
        fprintf(stderr, "usage: %s GGUF_DIR F4D_CONVERT FIXTURE_DIR\n", argv[0]);
        return 2;
    }
    gguf_dir = argv[1];
    convert_bin = argv[2];
    fix_dir = argv[3];
    snprintf(tmp_path, sizeof tmp_path, "%s/test_gguf_tmp.gguf", gguf_dir);
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_roundtrip),
        cmocka_unit_test(test_every_truncation_fails),
        cmocka_unit_test(test_corruptions_named),
        cmocka_unit_test(test_alignment_range),
        cmocka_unit_test(test_fuzz_seeds_refused),
        cmocka_unit_test(test_open_memory_matches_open),
        cmocka_unit_test(test_open_memory_refuses),
        cmocka_unit_test(test_model_init_validates),
        cmocka_unit_test(test_model_prepare_refuses_unknown_group),
        cmocka_unit_test(test_convert_refuses),
        cmocka_unit_test(test_convert_half_inputs),
    };
    int rc = cmocka_run_group_tests_name("/model/gguf", tests, NULL, NULL);
    remove(tmp_path);
    return rc;
}
