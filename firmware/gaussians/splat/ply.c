/* ply.c - INRIA 3DGS binary PLY: read by property name, write the standard
 * SH0 layout. The header is a few lines of text; we parse it ourselves and
 * check every count against the bytes that are really there. */
#include <errno.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "splat_internal.h"

#define PLY_MAX_PROPS 256

enum ply_type { PT_NONE, PT_I8, PT_U8, PT_I16, PT_U16, PT_I32, PT_U32, PT_F32, PT_F64 };

static const struct { const char *name; enum ply_type t; int size; } ply_types[] = {
    { "char", PT_I8, 1 },   { "int8", PT_I8, 1 },    { "uchar", PT_U8, 1 },  { "uint8", PT_U8, 1 },
    { "short", PT_I16, 2 }, { "int16", PT_I16, 2 },  { "ushort", PT_U16, 2 }, { "uint16", PT_U16, 2 },
    { "int", PT_I32, 4 },   { "int32", PT_I32, 4 },  { "uint", PT_U32, 4 },  { "uint32", PT_U32, 4 },
    { "float", PT_F32, 4 }, { "float32", PT_F32, 4 }, { "double", PT_F64, 8 }, { "float64", PT_F64, 8 },
};

struct ply_prop {
    char          name[64];
    enum ply_type type;
    int           offset;
};

static float read_value(const unsigned char *p, enum ply_type t)
{
    /* little-endian file on a little-endian host (checked at open) */
    switch (t) {
    case PT_I8:  return (float)*(const int8_t *)p;
    case PT_U8:  return (float)*p;
    case PT_I16: { int16_t v; memcpy(&v, p, 2); return (float)v; }
    case PT_U16: { uint16_t v; memcpy(&v, p, 2); return (float)v; }
    case PT_I32: { int32_t v; memcpy(&v, p, 4); return (float)v; }
    case PT_U32: { uint32_t v; memcpy(&v, p, 4); return (float)v; }
    case PT_F32: { float v; memcpy(&v, p, 4); return v; }
    case PT_F64: { double v; memcpy(&v, p, 8); return (float)v; }
    default:     return 0.0f;
    }
}

static int host_little_endian(void)
{
    const uint16_t one = 1;
    unsigned char b;
    memcpy(&b, &one, 1);
    return b == 1;
}

static float sigmoidf_(float x) { return 1.0f / (1.0f + expf(-x)); }

int splat_ply_read(const char *path, struct splat_frame *f, struct f4d_err *err)
{
    if (!path || !f)
        return f4d_fail(err, F4D_EINVAL, "ply_read: NULL argument");
    if (!host_little_endian())
        return f4d_fail(err, F4D_EFORMAT, "ply_read: big-endian hosts are not supported");
    FILE *fp = fopen(path, "rb");
    if (!fp)
        return f4d_fail(err, F4D_EIO, "ply: cannot open '%s': %s", path, strerror(errno));
    int rc = F4D_OK;
    unsigned char *data = NULL;
    struct ply_prop props[PLY_MAX_PROPS];
    int nprops = 0, stride = 0, in_vertex = 0, seen_vertex = 0, line_no = 0, format_ok = 0;
    long long count = -1;
    char line[512];

    if (!fgets(line, sizeof line, fp) || strncmp(line, "ply", 3) != 0) {
        rc = f4d_fail(err, F4D_EFORMAT, "ply: '%s' does not start with 'ply'", path);
        goto out;
    }
    for (;;) {
        line_no++;
        if (!fgets(line, sizeof line, fp)) {
            rc = f4d_fail(err, F4D_EFORMAT, "ply: '%s': header ends without end_header", path);
            goto out;
        }
        line[strcspn(line, "\r\n")] = '\0';
        char w0[64] = "", w1[64] = "", w2[64] = "";
        int nw = sscanf(line, "%63s %63s %63s", w0, w1, w2);
        if (nw <= 0 || !strcmp(w0, "comment") || !strcmp(w0, "obj_info"))
            continue;
        if (!strcmp(w0, "end_header"))
            break;
        if (!strcmp(w0, "format")) {
            if (strcmp(w1, "binary_little_endian") != 0) {
                rc = f4d_fail(err, F4D_EFORMAT, "ply: '%s': format '%s' is not supported (need binary_little_endian)",
                                 path, w1);
                goto out;
            }
            format_ok = 1;
        } else if (!strcmp(w0, "element")) {
            if (seen_vertex) {
                in_vertex = 0; /* elements after the vertices are never read */
                continue;
            }
            if (strcmp(w1, "vertex") != 0) {
                rc = f4d_fail(err, F4D_EFORMAT, "ply: '%s': element '%s' comes before 'vertex'", path, w1);
                goto out;
            }
            char *end;
            errno = 0;
            count = strtoll(w2, &end, 10);
            if (*end || errno || count < 0 || count > (long long)INT32_MAX) {
                rc = f4d_fail(err, F4D_EFORMAT, "ply: '%s': bad vertex count '%s'", path, w2);
                goto out;
            }
            seen_vertex = in_vertex = 1;
        } else if (!strcmp(w0, "property")) {
            if (!in_vertex)
                continue;
            if (!strcmp(w1, "list")) {
                rc = f4d_fail(err, F4D_EFORMAT, "ply: '%s': list property in 'vertex' is not supported", path);
                goto out;
            }
            enum ply_type t = PT_NONE;
            int size = 0;
            for (size_t k = 0; k < sizeof ply_types / sizeof ply_types[0]; k++)
                if (!strcmp(w1, ply_types[k].name)) {
                    t = ply_types[k].t;
                    size = ply_types[k].size;
                }
            if (t == PT_NONE || nw < 3) {
                rc = f4d_fail(err, F4D_EFORMAT, "ply: '%s': header line %d: bad property '%s'", path, line_no, line);
                goto out;
            }
            if (nprops == PLY_MAX_PROPS) {
                rc = f4d_fail(err, F4D_EFORMAT, "ply: '%s': more than %d vertex properties", path, PLY_MAX_PROPS);
                goto out;
            }
            snprintf(props[nprops].name, sizeof props[nprops].name, "%s", w2);
            props[nprops].type = t;
            props[nprops].offset = stride;
            stride += size;
            nprops++;
        } else {
            rc = f4d_fail(err, F4D_EFORMAT, "ply: '%s': header line %d not understood: '%s'", path, line_no, line);
            goto out;
        }
    }
    if (!format_ok || !seen_vertex) {
        rc = f4d_fail(err, F4D_EFORMAT, "ply: '%s': header lacks %s", path, format_ok ? "a vertex element" : "the format line");
        goto out;
    }
    static const char *need[] = { "x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity", "scale_0", "scale_1",
                                  "scale_2", "rot_0", "rot_1", "rot_2", "rot_3" };
    static const char *opt[] = { "motion_bwd_0", "motion_bwd_1", "motion_bwd_2",
                                 "motion_fwd_0", "motion_fwd_1", "motion_fwd_2" };
    int at[14], at_m[6], have_motion = 1;
    for (int k = 0; k < 14; k++) {
        at[k] = -1;
        for (int p = 0; p < nprops; p++)
            if (!strcmp(props[p].name, need[k]))
                at[k] = p;
        if (at[k] < 0) {
            rc = f4d_fail(err, F4D_EFORMAT, "ply: '%s': vertex property '%s' is missing", path, need[k]);
            goto out;
        }
    }
    for (int k = 0; k < 6; k++) {
        at_m[k] = -1;
        for (int p = 0; p < nprops; p++)
            if (!strcmp(props[p].name, opt[k]))
                at_m[k] = p;
        if (at_m[k] < 0)
            have_motion = 0;
    }
    size_t n = (size_t)count, bytes = n * (size_t)stride;
    data = malloc(bytes ? bytes : 1);
    if (!data) {
        rc = f4d_fail(err, F4D_ENOMEM, "ply: '%s': out of memory for %zu Gaussians", path, n);
        goto out;
    }
    if (fread(data, 1, bytes, fp) != bytes) {
        rc = f4d_fail(err, F4D_EFORMAT, "ply: '%s': file is truncated (header says %zu vertices of %d bytes)",
                         path, n, stride);
        goto out;
    }
    if ((rc = splat_frame_resize(f, n, have_motion, err)) < 0)
        goto out;
    for (size_t i = 0; i < n; i++) {
        const unsigned char *v = data + i * (size_t)stride;
        float val[14];
        for (int k = 0; k < 14; k++)
            val[k] = read_value(v + props[at[k]].offset, props[at[k]].type);
        for (int k = 0; k < 3; k++) {
            f->pos[3 * i + k] = val[k];
            f->rgb[3 * i + k] = 0.5f + SPLAT_SH_C0 * val[3 + k];
            f->scale[3 * i + k] = expf(val[7 + k]);
        }
        f->opacity[i] = sigmoidf_(val[6]);
        float q[4] = { val[10], val[11], val[12], val[13] };
        float qn = sqrtf(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
        if (!(qn > 1e-12f) || !isfinite(qn)) {
            q[0] = 1.0f;
            q[1] = q[2] = q[3] = 0.0f;
            qn = 1.0f;
        }
        for (int k = 0; k < 4; k++)
            f->rot[4 * i + k] = q[k] / qn;
        if (have_motion)
            for (int k = 0; k < 3; k++) {
                f->motion_bwd[3 * i + k] = read_value(v + props[at_m[k]].offset, props[at_m[k]].type);
                f->motion_fwd[3 * i + k] = read_value(v + props[at_m[3 + k]].offset, props[at_m[3 + k]].type);
            }
    }
    if (!have_motion && (f->motion_bwd || f->motion_fwd)) {
        free(f->motion_bwd);
        free(f->motion_fwd);
        f->motion_bwd = f->motion_fwd = NULL;
    }
out:
    free(data);
    fclose(fp);
    return rc;
}

static float logitf_(float p)
{
    /* clamp so that opacity 0 or 1 stays finite on disk */
    const float lo = 1e-7f, hi = 1.0f - 1e-7f;
    p = p < lo ? lo : (p > hi ? hi : p);
    return logf(p / (1.0f - p));
}

int splat_ply_write(const char *path, const struct splat_frame *f, struct f4d_err *err)
{
    if (!path || !f)
        return f4d_fail(err, F4D_EINVAL, "ply_write: NULL argument");
    if (f->count > (size_t)INT32_MAX)
        return f4d_fail(err, F4D_EINVAL, "ply_write: %zu Gaussians is too many", f->count);
    if (!host_little_endian())
        return f4d_fail(err, F4D_EFORMAT, "ply_write: big-endian hosts are not supported");
    FILE *fp = fopen(path, "wb");
    if (!fp)
        return f4d_fail(err, F4D_EIO, "ply: cannot create '%s': %s", path, strerror(errno));
    int motion = f->motion_bwd && f->motion_fwd;
    static const char *names[] = { "x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2", "opacity",
                                   "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3",
                                   "motion_bwd_0", "motion_bwd_1", "motion_bwd_2",
                                   "motion_fwd_0", "motion_fwd_1", "motion_fwd_2" };
    int np = motion ? 23 : 17;
    fprintf(fp, "ply\nformat binary_little_endian 1.0\ncomment Forge4D Edge Gaussian frame (metres)\n"
                "element vertex %zu\n", f->count);
    for (int k = 0; k < np; k++)
        fprintf(fp, "property float %s\n", names[k]);
    fprintf(fp, "end_header\n");
    float v[23];
    for (size_t i = 0; i < f->count; i++) {
        for (int k = 0; k < 3; k++) {
            v[k] = f->pos[3 * i + k];
            v[3 + k] = 0.0f;
            v[6 + k] = (f->rgb[3 * i + k] - 0.5f) / SPLAT_SH_C0;
            float s = f->scale[3 * i + k];
            v[10 + k] = logf(s > 1e-30f ? s : 1e-30f);
        }
        v[9] = logitf_(f->opacity[i]);
        for (int k = 0; k < 4; k++)
            v[13 + k] = f->rot[4 * i + k];
        if (motion)
            for (int k = 0; k < 3; k++) {
                v[17 + k] = f->motion_bwd[3 * i + k];
                v[20 + k] = f->motion_fwd[3 * i + k];
            }
        if (fwrite(v, sizeof(float), (size_t)np, fp) != (size_t)np) {
            fclose(fp);
            return f4d_fail(err, F4D_EIO, "ply: error writing '%s'", path);
        }
    }
    if (fclose(fp) != 0)
        return f4d_fail(err, F4D_EIO, "ply: error writing '%s'", path);
    return F4D_OK;
}
