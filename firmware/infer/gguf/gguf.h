/* gguf.h - GGUF v3 weight files: a validating mmap reader and a streaming writer.
 *
 * GGUF (the edge-inference ecosystem's format, as written by the `gguf` Python
 * package): magic "GGUF", version 3, tensor and key counts, typed key/value
 * metadata, a tensor table (name, dims with ne[0] the fastest-varying, type,
 * offset) and a data section aligned to `general.alignment` (default 32) in
 * which every tensor starts on an aligned offset. Everything is little-endian.
 *
 *     struct f4d_err err = {0};
 *     gguf_file *f;
 *     if (gguf_open("w.gguf", &f, &err) < 0) { puts(err); ... }
 *     int64_t depth;
 *     if (gguf_get_int(f, "forge4d.depth", &depth) < 0) puts(gguf_error(f));
 *     const struct gguf_tensor *t = gguf_find_tensor(f, "aggregator.camera_token");
 *     gguf_close(f);
 *
 * The reader treats the file as untrusted: gguf_open checks the magic, version,
 * every count and string length against the bytes left, value types, the
 * alignment key (a power of two in GGUF_MIN_ALIGN..GGUF_MAX_ALIGN), tensor dims (1..4, non-zero, no size overflow), tensor types,
 * alignment and bounds of every tensor, duplicate names and overlapping data.
 * Every failure returns a negative code and a message naming the key or tensor.
 * Tensor data stays in the read-only mapping (zero copy).
 *
 * Quantized int8 tensors of this project are stored as a pair: the int8 values
 * as GGUF_T_I8 under the tensor's name, and their float32 scales as GGUF_T_F32
 * under "<name>.scale" (one per output channel; see tools/f4d-convert).
 */
#ifndef F4D_GGUF_H
#define F4D_GGUF_H

#include "f4d_status.h"

#include <stddef.h>
#include <stdint.h>
#include <stdio.h>

#define GGUF_MAGIC          0x46554747u /* "GGUF" read as little-endian u32 */
#define GGUF_VERSION        3u
#define GGUF_DEFAULT_ALIGN  32u
/* general.alignment must be a power of two in GGUF_MIN_ALIGN..GGUF_MAX_ALIGN:
 * at least 8 (the GGUF spec's "multiple of 8"), so that every tensor's data is
 * aligned to its element size; at most 4096, the smallest page size, so that
 * the alignment also holds in memory for a mapping (which starts on a page). */
#define GGUF_MIN_ALIGN      8u
#define GGUF_MAX_ALIGN      4096u
#define GGUF_MIN_SIZE       24          /* magic, version, two counts          */
#define GGUF_MAX_DIMS       4
#define GGUF_NAME_MAX       256         /* longest accepted key or tensor name */

/* Metadata value types (GGUF spec numbering). */
enum gguf_vtype {
    GGUF_V_UINT8 = 0, GGUF_V_INT8 = 1, GGUF_V_UINT16 = 2, GGUF_V_INT16 = 3,
    GGUF_V_UINT32 = 4, GGUF_V_INT32 = 5, GGUF_V_FLOAT32 = 6, GGUF_V_BOOL = 7,
    GGUF_V_STRING = 8, GGUF_V_ARRAY = 9, GGUF_V_UINT64 = 10, GGUF_V_INT64 = 11,
    GGUF_V_FLOAT64 = 12,
};

/* Tensor types (ggml numbering); only these are accepted. */
enum gguf_ttype {
    GGUF_T_F32 = 0, GGUF_T_F16 = 1, GGUF_T_I8 = 24, GGUF_T_I16 = 25,
    GGUF_T_I32 = 26, GGUF_T_I64 = 27, GGUF_T_F64 = 28, GGUF_T_BF16 = 30,
};

struct gguf_tensor {
    const char  *name;
    uint32_t     n_dims;
    uint64_t     ne[GGUF_MAX_DIMS];  /* ne[0] fastest; unused dims are 1       */
    uint32_t     type;               /* enum gguf_ttype                         */
    uint64_t     offset;             /* from the start of the data section     */
    uint64_t     n_elements;
    size_t       nbytes;
    const void  *data;               /* into the mapping, aligned              */
};

typedef struct gguf_file gguf_file;

/* Reader. err receives the message when gguf_open fails. */
int          gguf_open        (const char *path, gguf_file **out, struct f4d_err *err);
/* The same reader and checks over bytes already in memory (no copy): `data`
 * must stay valid and unchanged until gguf_close, and be aligned to the file's
 * general.alignment (aligned_alloc(GGUF_MAX_ALIGN, ...) always is), else
 * F4D_EINVAL. Malformed bytes give F4D_EFORMAT with the same message as
 * gguf_open would. */
int          gguf_open_memory (const void *data, size_t size, gguf_file **out, struct f4d_err *err);
void         gguf_close       (gguf_file *f);
const char * gguf_error       (const gguf_file *f);   /* last getter failure */
uint32_t     gguf_alignment   (const gguf_file *f);
size_t       gguf_file_size   (const gguf_file *f);

size_t       gguf_key_count   (const gguf_file *f);
const char * gguf_key_name    (const gguf_file *f, size_t i);
int          gguf_key_type    (const gguf_file *f, const char *key);  /* enum gguf_vtype or <0 */

/* Typed getters: integers of any width and signedness (range-checked into
 * int64), floats of either width, strings, arrays of integers. */
int          gguf_get_int     (gguf_file *f, const char *key, int64_t *v);
int          gguf_get_float   (gguf_file *f, const char *key, double *v);
int          gguf_get_str     (gguf_file *f, const char *key, const char **v);
int          gguf_get_int_array(gguf_file *f, const char *key, int64_t *v, size_t cap,
                                size_t *n);

size_t                     gguf_tensor_count(const gguf_file *f);
const struct gguf_tensor * gguf_tensor_at   (const gguf_file *f, size_t i);
const struct gguf_tensor * gguf_find_tensor (const gguf_file *f, const char *name);
/* Finds `name` and checks its type and dims (PyTorch order, outermost first,
 * as `shape[0..n_dims)`); fails naming the tensor and the mismatch. */
int          gguf_expect_tensor(gguf_file *f, const char *name, uint32_t type,
                                int n_dims, const int64_t *shape,
                                const struct gguf_tensor **out);
size_t       gguf_type_size   (uint32_t type);          /* 0 when unknown */
const char * gguf_type_name   (uint32_t type);

/* Writer: add all metadata and tensor infos, then gguf_writer_begin writes the
 * header, then each tensor's bytes go in the order they were added. The file
 * is written to "<path>.tmp" and renamed onto `path` by gguf_writer_finish, so
 * a failed conversion never destroys an existing file. */
typedef struct gguf_writer gguf_writer;
gguf_writer *gguf_writer_new     (void);
void         gguf_writer_free    (gguf_writer *w);       /* removes the .tmp if unfinished */
const char * gguf_writer_error   (const gguf_writer *w);
int          gguf_writer_add_int (gguf_writer *w, const char *key, enum gguf_vtype t, int64_t v);
int          gguf_writer_add_f32 (gguf_writer *w, const char *key, float v);
int          gguf_writer_add_str (gguf_writer *w, const char *key, const char *v);
int          gguf_writer_add_int_array(gguf_writer *w, const char *key, enum gguf_vtype t,
                                       const int64_t *v, size_t n);
/* shape in PyTorch order (outermost first); stored reversed as ne[]. */
int          gguf_writer_add_tensor(gguf_writer *w, const char *name, uint32_t type,
                                    int n_dims, const int64_t *shape);
int          gguf_writer_begin   (gguf_writer *w, const char *path);
int          gguf_writer_write   (gguf_writer *w, const void *data, size_t nbytes);
int          gguf_writer_finish  (gguf_writer *w);

#endif /* F4D_GGUF_H */
