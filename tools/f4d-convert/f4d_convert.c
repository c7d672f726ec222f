/* f4d-convert - PyTorch safetensors checkpoint -> the firmware's GGUF weight file.
 *
 *   f4d-convert IN.safetensors OUT.gguf [--config CFG.json] [--type f32|f16|int8]
 *
 * Reads F32/F16/BF16 tensors with the released VGGT parameter names, checks
 * every name and shape against the schema that the config implies (VGGT-1B
 * defaults, overridden by the config JSON), refuses unknown names, keeps norms,
 * biases, LayerScales, tokens, position embeddings and the patchify conv in
 * f32, stores the linear/conv weights as f32, f16 (GGUF F16) or int8 (GGUF I8
 * plus an F32 "<name>.scale" tensor: one scale per output channel, symmetric,
 * round half to even), and prints each tensor's quantization error.
 * The track head (track_head.*) is known and skipped: it is out of scope.
 */
#include <cjson/cJSON.h>
#include <errno.h>
#include <fcntl.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#include <sys/stat.h>
#include <unistd.h>

#include "fk_fp16.h"
#include "gguf.h"
#include "model.h"

enum st_dtype { ST_F32, ST_F16, ST_BF16 };

struct st_tensor {
    char         *name;
    enum st_dtype dtype;
    int           n_dims;
    int64_t       shape[8];
    size_t        n;
    const uint8_t *data;
    int           used;
};

struct st_file {
    uint8_t          *map;
    size_t            size;
    struct st_tensor *t;
    size_t            n_t;
};

static void st_close(struct st_file *f)
{
    for (size_t i = 0; i < f->n_t; i++)
        free(f->t[i].name);
    free(f->t);
    if (f->map)
        munmap(f->map, f->size);
}

static int st_open(const char *path, struct st_file *f)
{
    memset(f, 0, sizeof *f);
    int fd = open(path, O_RDONLY);
    if (fd < 0) {
        fprintf(stderr, "f4d-convert: cannot open '%s': %s\n", path, strerror(errno));
        return -1;
    }
    struct stat st;
    if (fstat(fd, &st) < 0 || st.st_size < 8) {
        fprintf(stderr, "f4d-convert: '%s' is too small for safetensors\n", path);
        close(fd);
        return -1;
    }
    f->size = (size_t)st.st_size;
    void *m = mmap(NULL, f->size, PROT_READ, MAP_PRIVATE, fd, 0);
    close(fd);
    if (m == MAP_FAILED) {
        fprintf(stderr, "f4d-convert: cannot mmap '%s': %s\n", path, strerror(errno));
        return -1;
    }
    f->map = m;
    uint64_t hlen;
    memcpy(&hlen, f->map, 8);
    if (hlen > f->size - 8 || hlen > (100u << 20)) {
        fprintf(stderr, "f4d-convert: '%s': header length %llu exceeds the file\n", path,
                (unsigned long long)hlen);
        return -1;
    }
    cJSON *root = cJSON_ParseWithLength((const char *)f->map + 8, (size_t)hlen);
    if (!root || !cJSON_IsObject(root)) {
        fprintf(stderr, "f4d-convert: '%s': header is not a JSON object\n", path);
        cJSON_Delete(root);
        return -1;
    }
    const uint8_t *data = f->map + 8 + hlen;
    size_t data_size = f->size - 8 - (size_t)hlen;
    int n = cJSON_GetArraySize(root);
    f->t = calloc((size_t)(n > 0 ? n : 1), sizeof *f->t);
    int rc = f->t ? 0 : -1;
    for (cJSON *it = root->child; it && !rc; it = it->next) {
        if (!strcmp(it->string, "__metadata__"))
            continue;
        struct st_tensor *t = &f->t[f->n_t];
        const char *nm = it->string;
        cJSON *dt = cJSON_GetObjectItemCaseSensitive(it, "dtype");
        cJSON *sh = cJSON_GetObjectItemCaseSensitive(it, "shape");
        cJSON *of = cJSON_GetObjectItemCaseSensitive(it, "data_offsets");
        if (!cJSON_IsString(dt) || !cJSON_IsArray(sh) || !cJSON_IsArray(of) ||
            cJSON_GetArraySize(of) != 2 || cJSON_GetArraySize(sh) > 8) {
            fprintf(stderr, "f4d-convert: tensor '%s': malformed header entry\n", nm);
            rc = -1;
            break;
        }
        size_t es;
        if (!strcmp(dt->valuestring, "F32"))
            t->dtype = ST_F32, es = 4;
        else if (!strcmp(dt->valuestring, "F16"))
            t->dtype = ST_F16, es = 2;
        else if (!strcmp(dt->valuestring, "BF16"))
            t->dtype = ST_BF16, es = 2;
        else {
            fprintf(stderr, "f4d-convert: tensor '%s': dtype %s not supported (F32, F16, BF16)\n",
                    nm, dt->valuestring);
            rc = -1;
            break;
        }
        t->n = 1;
        for (cJSON *d = sh->child; d; d = d->next) {
            if (!cJSON_IsNumber(d) || d->valuedouble < 0 || d->valuedouble > 1e9) {
                fprintf(stderr, "f4d-convert: tensor '%s': bad shape\n", nm);
                rc = -1;
                break;
            }
            t->shape[t->n_dims++] = (int64_t)d->valuedouble;
            t->n *= (size_t)d->valuedouble;
        }
        if (rc)
            break;
        double b = cJSON_GetArrayItem(of, 0)->valuedouble, e = cJSON_GetArrayItem(of, 1)->valuedouble;
        if (b < 0 || e < b || e > (double)data_size || (size_t)(e - b) != t->n * es) {
            fprintf(stderr, "f4d-convert: tensor '%s': data_offsets [%.0f, %.0f) do not match "
                    "its shape or the file (%zu data bytes)\n", nm, b, e, data_size);
            rc = -1;
            break;
        }
        t->data = data + (size_t)b;
        t->name = strdup(nm);
        if (!t->name)
            rc = -1;
        f->n_t++;
    }
    cJSON_Delete(root);
    return rc;
}

static struct st_tensor *st_find(struct st_file *f, const char *name)
{
    for (size_t i = 0; i < f->n_t; i++)
        if (!strcmp(f->t[i].name, name))
            return &f->t[i];
    return NULL;
}

static void st_to_f32(const struct st_tensor *t, float *out)
{
    for (size_t i = 0; i < t->n; i++) {
        if (t->dtype == ST_F32) {
            memcpy(&out[i], t->data + 4 * i, 4);
        } else {
            uint16_t h;
            memcpy(&h, t->data + 2 * i, 2);
            if (t->dtype == ST_F16) {
                out[i] = fk_f16_to_f32_ref(h);
            } else {
                uint32_t u = (uint32_t)h << 16;
                memcpy(&out[i], &u, 4);
            }
        }
    }
}

/* ------------------------------------------------------------------ config */

static int read_config(const char *path, struct model_config *c)
{
    FILE *fp = fopen(path, "rb");
    if (!fp) {
        fprintf(stderr, "f4d-convert: cannot open config '%s': %s\n", path, strerror(errno));
        return -1;
    }
    char *buf = malloc(1 << 20);
    size_t n = buf ? fread(buf, 1, (1 << 20) - 1, fp) : 0;
    fclose(fp);
    if (!buf)
        return -1;
    buf[n] = 0;
    cJSON *root = cJSON_Parse(buf);
    free(buf);
    if (!cJSON_IsObject(root)) {
        fprintf(stderr, "f4d-convert: config '%s' is not a JSON object\n", path);
        cJSON_Delete(root);
        return -1;
    }
    int rc = 0;
    for (cJSON *it = root->child; it && !rc; it = it->next) {
        const char *k = it->string;
        int *ip = NULL;
#define INT_KEY(name) if (!strcmp(k, #name)) ip = &c->name;
        INT_KEY(img_size) INT_KEY(patch_size) INT_KEY(embed_dim) INT_KEY(depth)
        INT_KEY(num_heads) INT_KEY(num_register_tokens) INT_KEY(dino_depth)
        INT_KEY(dino_num_heads) INT_KEY(camera_trunk_depth) INT_KEY(camera_num_heads)
        INT_KEY(camera_iters) INT_KEY(dpt_features) INT_KEY(motion_dpt_features)
#undef INT_KEY
        if (ip && cJSON_IsNull(it)) { /* forge4d_ref's None: derived (model.h) */
            *ip = 0;
            continue;
        }
        if (ip) {
            if (!cJSON_IsNumber(it) || it->valuedouble != floor(it->valuedouble) ||
                fabs(it->valuedouble) > 1e6) {
                fprintf(stderr, "f4d-convert: config key '%s' must be an integer\n", k);
                rc = -1;
            } else {
                *ip = (int)it->valuedouble;
            }
        } else if (!strcmp(k, "mlp_ratio")) {
            if (!cJSON_IsNumber(it)) {
                fprintf(stderr, "f4d-convert: config key 'mlp_ratio' must be a number\n");
                rc = -1;
            } else {
                c->mlp_ratio = (float)it->valuedouble;
            }
        } else if (!strcmp(k, "patch_embed")) {
            if (cJSON_IsString(it) && !strcmp(it->valuestring, "dino"))
                c->patch_embed = MODEL_PATCH_DINO;
            else if (cJSON_IsString(it) && !strcmp(it->valuestring, "conv"))
                c->patch_embed = MODEL_PATCH_CONV;
            else {
                fprintf(stderr, "f4d-convert: config key 'patch_embed' must be \"dino\" or \"conv\"\n");
                rc = -1;
            }
        } else if (!strcmp(k, "motion_layers")) {
            /* a list of aggregator layers; null = the DPT layers */
            c->motion_layers = 0;
            if (cJSON_IsNull(it))
                continue;
            int na = cJSON_IsArray(it) ? cJSON_GetArraySize(it) : -1;
            if (na < 1) {
                fprintf(stderr, "f4d-convert: config key 'motion_layers' must be null or a "
                        "non-empty array of layer indices\n");
                rc = -1;
            }
            for (int i = 0; i < na && !rc; i++) {
                cJSON *v = cJSON_GetArrayItem(it, i);
                if (!cJSON_IsNumber(v) || v->valuedouble != floor(v->valuedouble) ||
                    v->valuedouble < 0 || v->valuedouble >= MODEL_LAYERS_MAX) {
                    fprintf(stderr, "f4d-convert: config key 'motion_layers'[%d] must be a layer "
                            "index in 0..%d\n", i, MODEL_LAYERS_MAX - 1);
                    rc = -1;
                } else {
                    c->motion_layers |= UINT64_C(1) << (int)v->valuedouble;
                }
            }
        } else if (!strcmp(k, "dpt_out_channels") || !strcmp(k, "dpt_layer_idx")) {
            int *dst = k[4] == 'o' ? c->dpt_out_channels : c->dpt_layer_idx;
            if (!cJSON_IsArray(it) || cJSON_GetArraySize(it) != 4) {
                fprintf(stderr, "f4d-convert: config key '%s' must be an array of 4 integers\n", k);
                rc = -1;
            } else {
                for (int i = 0; i < 4; i++) {
                    cJSON *v = cJSON_GetArrayItem(it, i);
                    if (!cJSON_IsNumber(v) || v->valuedouble != floor(v->valuedouble)) {
                        fprintf(stderr, "f4d-convert: config key '%s'[%d] must be an integer\n", k, i);
                        rc = -1;
                    } else {
                        dst[i] = (int)v->valuedouble;
                    }
                }
            }
        } else {
            fprintf(stderr, "f4d-convert: unknown config key '%s'\n", k);
            rc = -1;
        }
    }
    cJSON_Delete(root);
    return rc;
}

/* ------------------------------------------------------------------ plan */

enum out_type { OUT_F32, OUT_F16, OUT_I8 };

struct conv {
    struct st_file   *st;
    gguf_writer      *w;
    enum out_type     type;
    int               pass;        /* 0: check and add infos, 1: write data */
    size_t            n_written;
    double            worst_rel;
    const char       *worst_name;
    char              worst_buf[MODEL_NAME_MAX];
};

static int per_tensor(void *user, const struct model_tensor_info *ti)
{
    struct conv *cv = user;
    struct st_tensor *t = st_find(cv->st, ti->name);
    if (!t) {
        fprintf(stderr, "f4d-convert: missing tensor '%s' (required by the config)\n", ti->name);
        return -1;
    }
    if (cv->pass == 0) {
        int ok = t->n_dims == ti->n_dims;
        for (int d = 0; ok && d < ti->n_dims; d++)
            ok = t->shape[d] == ti->shape[d];
        if (!ok) {
            char got[128] = "", want[128] = "";
            for (int d = 0; d < t->n_dims; d++)
                snprintf(got + strlen(got), sizeof got - strlen(got), "%s%lld", d ? "," : "",
                         (long long)t->shape[d]);
            for (int d = 0; d < ti->n_dims; d++)
                snprintf(want + strlen(want), sizeof want - strlen(want), "%s%lld", d ? "," : "",
                         (long long)ti->shape[d]);
            fprintf(stderr, "f4d-convert: tensor '%s' has shape [%s] but the config implies [%s]"
                    " (check --config)\n", ti->name, got, want);
            return -1;
        }
        t->used = 1;
        if (ti->tclass == MODEL_T_UNUSED)
            return 0;
        int q = ti->tclass == MODEL_T_QUANT;
        uint32_t gt = !q || cv->type == OUT_F32 ? GGUF_T_F32 : cv->type == OUT_F16 ? GGUF_T_F16 : GGUF_T_I8;
        if (gguf_writer_add_tensor(cv->w, ti->name, gt, ti->n_dims, ti->shape) < 0)
            return -1;
        if (q && cv->type == OUT_I8) {
            char sn[MODEL_NAME_MAX + 8];
            snprintf(sn, sizeof sn, "%s.scale", ti->name);
            if (gguf_writer_add_tensor(cv->w, sn, GGUF_T_F32, 1, &ti->shape[ti->qaxis]) < 0)
                return -1;
        }
        return 0;
    }
    if (ti->tclass == MODEL_T_UNUSED)
        return 0;
    float *f = malloc(t->n * sizeof *f);
    if (!f)
        return -1;
    st_to_f32(t, f);
    int q = ti->tclass == MODEL_T_QUANT;
    int rc = 0;
    double max_abs = 0, max_err = 0, se = 0, ss = 0;
    for (size_t i = 0; i < t->n; i++)
        max_abs = fmax(max_abs, fabs(f[i]));
    if (!q || cv->type == OUT_F32) {
        rc = gguf_writer_write(cv->w, f, t->n * 4);
    } else if (cv->type == OUT_F16) {
        fk_f16 *h = malloc(t->n * sizeof *h);
        if (!h) {
            free(f);
            return -1;
        }
        for (size_t i = 0; i < t->n; i++) {
            h[i] = fk_f32_to_f16_ref(f[i]);
            double e = (double)fk_f16_to_f32_ref(h[i]) - f[i];
            max_err = fmax(max_err, fabs(e));
            se += e * e;
            ss += (double)f[i] * f[i];
        }
        rc = gguf_writer_write(cv->w, h, t->n * 2);
        free(h);
    } else {
        /* Channel ch of axis qaxis; element i belongs to (i / inner) % nch. */
        int64_t nch = ti->shape[ti->qaxis];
        size_t inner = 1;
        for (int d = ti->qaxis + 1; d < ti->n_dims; d++)
            inner *= (size_t)ti->shape[d];
        float *scale = calloc((size_t)nch, sizeof *scale);
        int8_t *qv = malloc(t->n);
        if (!scale || !qv) {
            free(scale);
            free(qv);
            free(f);
            return -1;
        }
        for (size_t i = 0; i < t->n; i++) {
            size_t ch = (i / inner) % (size_t)nch;
            scale[ch] = fmaxf(scale[ch], fabsf(f[i]));
        }
        for (int64_t c = 0; c < nch; c++)
            scale[c] /= 127.0f;
        for (size_t i = 0; i < t->n; i++) {
            float s = scale[(i / inner) % (size_t)nch];
            float v = s > 0 ? nearbyintf(f[i] / s) : 0.0f;
            v = fminf(fmaxf(v, -127.0f), 127.0f);
            qv[i] = (int8_t)v;
            double e = (double)v * s - f[i];
            max_err = fmax(max_err, fabs(e));
            se += e * e;
            ss += (double)f[i] * f[i];
        }
        rc = gguf_writer_write(cv->w, qv, t->n);
        if (!rc)
            rc = gguf_writer_write(cv->w, scale, (size_t)nch * 4);
        free(scale);
        free(qv);
    }
    free(f);
    if (rc < 0) {
        fprintf(stderr, "f4d-convert: %s\n", gguf_writer_error(cv->w));
        return -1;
    }
    cv->n_written++;
    const char *tn = !q ? "f32" : cv->type == OUT_F32 ? "f32" : cv->type == OUT_F16 ? "f16" : "int8";
    double rel = max_abs > 0 ? max_err / max_abs : 0, rms = ss > 0 ? sqrt(se / ss) : 0;
    printf("%-62s %-5s n=%-9zu max_abs_err=%.3e max_rel_err=%.3e rms_rel_err=%.3e\n",
           ti->name, tn, t->n, max_err, rel, rms);
    if (rel > cv->worst_rel) {
        cv->worst_rel = rel;
        snprintf(cv->worst_buf, sizeof cv->worst_buf, "%s", ti->name);
        cv->worst_name = cv->worst_buf;
    }
    return 0;
}

static void usage(void)
{
    fprintf(stderr, "usage: f4d-convert IN.safetensors OUT.gguf [--config CFG.json] "
            "[--type f32|f16|int8]\n");
}

int main(int argc, char **argv)
{
    const char *in = NULL, *out = NULL, *cfg_path = NULL, *type = "f32";
    for (int i = 1; i < argc; i++) {
        if (!strcmp(argv[i], "--config") && i + 1 < argc)
            cfg_path = argv[++i];
        else if (!strcmp(argv[i], "--type") && i + 1 < argc)
            type = argv[++i];
        else if (!strcmp(argv[i], "-h") || !strcmp(argv[i], "--help"))
            return usage(), 0;
        else if (argv[i][0] == '-') {
            fprintf(stderr, "f4d-convert: unknown option '%s'\n", argv[i]);
            return usage(), 2;
        } else if (!in)
            in = argv[i];
        else if (!out)
            out = argv[i];
        else
            return usage(), 2;
    }
    if (!in || !out)
        return usage(), 2;
    struct conv cv = { 0 };
    if (!strcmp(type, "f32"))
        cv.type = OUT_F32;
    else if (!strcmp(type, "f16"))
        cv.type = OUT_F16;
    else if (!strcmp(type, "int8"))
        cv.type = OUT_I8;
    else {
        fprintf(stderr, "f4d-convert: --type must be f32, f16 or int8 (got '%s')\n", type);
        return 2;
    }
    struct model_config cfg;
    model_config_default(&cfg);
    /* a config without the motion keys (older checkpoints) means what a GGUF
     * without them means: blocks at the DPT layers, the head at dpt_features */
    cfg.motion_layers = 0;
    cfg.motion_dpt_features = 0;
    struct f4d_err err = {0};
    if (cfg_path && read_config(cfg_path, &cfg) < 0)
        return 1;
    if (model_config_check(&cfg, &err) < 0) {
        fprintf(stderr, "f4d-convert: %s\n", err.msg);
        return 1;
    }
    struct st_file st;
    int rc = 1;
    gguf_writer *w = NULL;
    if (st_open(in, &st) < 0)
        goto done;
    unsigned groups = 0;
    size_t skipped = 0;
    for (size_t i = 0; i < st.n_t; i++) {
        unsigned g = model_group_of(st.t[i].name);
        if (g) {
            groups |= g;
        } else if (!strncmp(st.t[i].name, "track_head.", 11)) {
            st.t[i].used = 1;
            skipped++;
        } else {
            fprintf(stderr, "f4d-convert: unknown tensor name '%s'\n", st.t[i].name);
            goto done;
        }
    }
    if (!(groups & MODEL_G_AGGREGATOR)) {
        fprintf(stderr, "f4d-convert: '%s' has no aggregator.* tensors\n", in);
        goto done;
    }
    if (skipped)
        printf("skipping %zu track_head.* tensors (the track head is not used)\n", skipped);
    w = gguf_writer_new();
    cv.st = &st;
    cv.w = w;
    if (!w || model_config_write(&cfg, w) < 0 ||
        gguf_writer_add_str(w, "forge4d.file_type", type) < 0)
        goto done;
    /* in enum model_group order from MODEL_G_CAMERA on */
    static const char *heads[] = { "camera_head", "depth_head", "point_head", "gaussian_head",
                                   "scale_head", "state", "motion", "motion_head", "fusion" };
    enum { N_HEADS = sizeof heads / sizeof heads[0] };
    const char *present[N_HEADS];
    size_t np = 0;
    for (int i = 0; i < N_HEADS; i++)
        if (groups & (MODEL_G_CAMERA << i))
            present[np++] = heads[i];
    printf("config: %s patch embed, embed_dim %d, depth %d, heads %d; groups: aggregator",
           cfg.patch_embed == MODEL_PATCH_DINO ? "dino" : "conv", cfg.embed_dim, cfg.depth,
           cfg.num_heads);
    for (size_t i = 0; i < np; i++)
        printf(" %s", present[i]);
    printf("\n");
    cv.pass = 0;
    if (model_schema_foreach(&cfg, groups, per_tensor, &cv) < 0)
        goto done;
    for (size_t i = 0; i < st.n_t; i++)
        if (!st.t[i].used) {
            fprintf(stderr, "f4d-convert: unknown tensor name '%s' (not in the schema of this "
                    "config: check depth / dino_depth / camera_trunk_depth)\n", st.t[i].name);
            goto done;
        }
    if (gguf_writer_begin(w, out) < 0) {
        fprintf(stderr, "f4d-convert: %s\n", gguf_writer_error(w));
        goto done;
    }
    cv.pass = 1;
    if (model_schema_foreach(&cfg, groups, per_tensor, &cv) < 0)
        goto done;
    if (gguf_writer_finish(w) < 0) {
        fprintf(stderr, "f4d-convert: %s\n", gguf_writer_error(w));
        goto done;
    }
    printf("wrote %s: %zu tensors (%s), worst max_rel_err %.3e (%s)\n", out, cv.n_written, type,
           cv.worst_rel, cv.worst_name ? cv.worst_name : "-");
    rc = 0;
done:
    gguf_writer_free(w);
    st_close(&st);
    return rc;
}
