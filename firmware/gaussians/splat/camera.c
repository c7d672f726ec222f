/* camera.c - pinhole cameras and the rig JSON file (parsed with cJSON). */
#include <cjson/cJSON.h>
#include <errno.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "splat_internal.h"

void splat_camera_to_cam(const struct splat_camera *cam, const float p[3], float q[3])
{
    const float *m = cam->w2c;
    for (int r = 0; r < 3; r++)
        q[r] = m[4 * r] * p[0] + m[4 * r + 1] * p[1] + m[4 * r + 2] * p[2] + m[4 * r + 3];
}

int splat_camera_project(const struct splat_camera *cam, const float pos[3], const float scale[3],
                         const float rot[4], float mean[2], float cov[3])
{
    float t[3];
    splat_camera_to_cam(cam, pos, t);
    if (!(t[2] > SPLAT_NEAR) || !isfinite(t[0]) || !isfinite(t[1]) || !isfinite(t[2]))
        return 0;
    float R[9], M[9];
    splat__quat_to_mat(rot, R);
    for (int a = 0; a < 3; a++)
        for (int b = 0; b < 3; b++)
            M[3 * a + b] = R[3 * a + b] * scale[b];
    float tanx = 0.5f * (float)cam->width / cam->fx, tany = 0.5f * (float)cam->height / cam->fy;
    float lxp = ((float)cam->width - cam->cx) / cam->fx + 0.3f * tanx, lxn = cam->cx / cam->fx + 0.3f * tanx;
    float lyp = ((float)cam->height - cam->cy) / cam->fy + 0.3f * tany, lyn = cam->cy / cam->fy + 0.3f * tany;
    float x = t[0] / t[2], y = t[1] / t[2];
    x = x < -lxn ? -lxn : (x > lxp ? lxp : x);
    y = y < -lyn ? -lyn : (y > lyp ? lyp : y);
    /* J W M: rows of the 2x3 Jacobian times the view rotation, times M */
    const float *V = cam->w2c;
    float J0[3], J1[3];
    for (int k = 0; k < 3; k++) {
        J0[k] = cam->fx / t[2] * V[k] - cam->fx * x / t[2] * V[8 + k];
        J1[k] = cam->fy / t[2] * V[4 + k] - cam->fy * y / t[2] * V[8 + k];
    }
    float A0[3], A1[3];
    for (int k = 0; k < 3; k++) {
        A0[k] = J0[0] * M[k] + J0[1] * M[3 + k] + J0[2] * M[6 + k];
        A1[k] = J1[0] * M[k] + J1[1] * M[3 + k] + J1[2] * M[6 + k];
    }
    cov[0] = A0[0] * A0[0] + A0[1] * A0[1] + A0[2] * A0[2];
    cov[1] = A0[0] * A1[0] + A0[1] * A1[1] + A0[2] * A1[2];
    cov[2] = A1[0] * A1[0] + A1[1] * A1[1] + A1[2] * A1[2];
    mean[0] = cam->fx * t[0] / t[2] + cam->cx;
    mean[1] = cam->fy * t[1] / t[2] + cam->cy;
    return isfinite(cov[0]) && isfinite(cov[1]) && isfinite(cov[2]) && isfinite(mean[0]) && isfinite(mean[1]);
}

void splat_camera_center(const struct splat_camera *cam, float c[3])
{
    const float *m = cam->w2c; /* c = -R^T t */
    for (int k = 0; k < 3; k++)
        c[k] = -(m[k] * m[3] + m[4 + k] * m[7] + m[8 + k] * m[11]);
}

static void normalize3(float v[3])
{
    float n = sqrtf(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
    if (n > 0) {
        v[0] /= n; v[1] /= n; v[2] /= n;
    }
}

static void cross3(const float a[3], const float b[3], float c[3])
{
    c[0] = a[1] * b[2] - a[2] * b[1];
    c[1] = a[2] * b[0] - a[0] * b[2];
    c[2] = a[0] * b[1] - a[1] * b[0];
}

void splat_camera_look_at(struct splat_camera *cam, const float eye[3], const float target[3],
                          const float up[3])
{
    float z[3] = { target[0] - eye[0], target[1] - eye[1], target[2] - eye[2] };
    normalize3(z);
    float down[3] = { -up[0], -up[1], -up[2] }, x[3], y[3];
    cross3(down, z, x); /* OpenCV: x right = y(down) x z(forward) */
    normalize3(x);
    cross3(z, x, y);
    const float *rows[3] = { x, y, z };
    for (int r = 0; r < 3; r++) {
        for (int k = 0; k < 3; k++)
            cam->w2c[4 * r + k] = rows[r][k];
        cam->w2c[4 * r + 3] = -(rows[r][0] * eye[0] + rows[r][1] * eye[1] + rows[r][2] * eye[2]);
    }
    cam->w2c[12] = cam->w2c[13] = cam->w2c[14] = 0.0f;
    cam->w2c[15] = 1.0f;
}

int splat_camera_validate(const struct splat_camera *cam, struct f4d_err *err)
{
    if (!cam)
        return f4d_fail(err, F4D_EINVAL, "camera is NULL");
    const char *n = cam->name;
    if (cam->width <= 0 || cam->height <= 0 || cam->width > 16384 || cam->height > 16384)
        return f4d_fail(err, F4D_EINVAL, "camera '%s': size %dx%d must be within 1..16384", n,
                           cam->width, cam->height);
    if (!(cam->fx > 0) || !(cam->fy > 0) || !isfinite(cam->fx) || !isfinite(cam->fy))
        return f4d_fail(err, F4D_EINVAL, "camera '%s': fx, fy must be finite and > 0", n);
    if (!isfinite(cam->cx) || !isfinite(cam->cy))
        return f4d_fail(err, F4D_EINVAL, "camera '%s': cx, cy must be finite", n);
    for (int k = 0; k < 16; k++)
        if (!isfinite(cam->w2c[k]))
            return f4d_fail(err, F4D_EINVAL, "camera '%s': world_to_camera[%d] is not finite", n, k);
    const float *m = cam->w2c;
    for (int a = 0; a < 3; a++)
        for (int b = 0; b < 3; b++) {
            float d = m[4 * a] * m[4 * b] + m[4 * a + 1] * m[4 * b + 1] + m[4 * a + 2] * m[4 * b + 2];
            if (fabsf(d - (a == b ? 1.0f : 0.0f)) > 1e-3f)
                return f4d_fail(err, F4D_EINVAL,
                                   "camera '%s': world_to_camera rotation block is not orthonormal", n);
        }
    if (fabsf(m[12]) > 1e-6f || fabsf(m[13]) > 1e-6f || fabsf(m[14]) > 1e-6f || fabsf(m[15] - 1) > 1e-6f)
        return f4d_fail(err, F4D_EINVAL, "camera '%s': world_to_camera last row must be 0 0 0 1", n);
    return F4D_OK;
}

static int get_number(const cJSON *obj, const char *key, double *v, int idx, struct f4d_err *err)
{
    const cJSON *it = cJSON_GetObjectItemCaseSensitive(obj, key);
    if (!cJSON_IsNumber(it))
        return f4d_fail(err, F4D_EFORMAT, "rig: cameras[%d].%s is missing or not a number", idx, key);
    *v = it->valuedouble;
    return 0;
}

static int parse_matrix(const cJSON *m, float out[16], int idx, struct f4d_err *err)
{
    int k = 0;
    if (!cJSON_IsArray(m))
        return f4d_fail(err, F4D_EFORMAT, "rig: cameras[%d].world_to_camera is missing or not an array", idx);
    const cJSON *e;
    cJSON_ArrayForEach(e, m) {
        if (cJSON_IsArray(e)) { /* 4 rows of 4 */
            const cJSON *v;
            int c = 0;
            cJSON_ArrayForEach(v, e) {
                if (!cJSON_IsNumber(v) || k >= 16 || c >= 4)
                    return f4d_fail(err, F4D_EFORMAT, "rig: cameras[%d].world_to_camera must be 4x4 numbers", idx);
                out[k++] = (float)v->valuedouble;
                c++;
            }
            if (c != 4)
                return f4d_fail(err, F4D_EFORMAT, "rig: cameras[%d].world_to_camera rows must have 4 numbers", idx);
        } else if (cJSON_IsNumber(e) && k < 16) {
            out[k++] = (float)e->valuedouble;
        } else {
            return f4d_fail(err, F4D_EFORMAT, "rig: cameras[%d].world_to_camera must hold 16 numbers", idx);
        }
    }
    if (k != 16)
        return f4d_fail(err, F4D_EFORMAT, "rig: cameras[%d].world_to_camera has %d numbers, need 16", idx, k);
    return 0;
}

int splat_rig_parse(const char *json, struct splat_rig *rig, struct f4d_err *err)
{
    if (!json || !rig)
        return f4d_fail(err, F4D_EINVAL, "splat_rig_parse: NULL argument");
    memset(rig, 0, sizeof *rig);
    cJSON *root = cJSON_Parse(json);
    if (!root) {
        const char *at = cJSON_GetErrorPtr();
        return f4d_fail(err, F4D_EFORMAT, "rig: invalid JSON near '%.20s'", at ? at : "?");
    }
    int rc = F4D_OK;
    const cJSON *cams = cJSON_GetObjectItemCaseSensitive(root, "cameras");
    if (!cJSON_IsArray(cams)) {
        rc = f4d_fail(err, F4D_EFORMAT, "rig: top-level \"cameras\" array is missing");
        goto done;
    }
    int n = cJSON_GetArraySize(cams);
    if (n < 1 || n > SPLAT_RIG_MAX) {
        rc = f4d_fail(err, F4D_EFORMAT, "rig: %d cameras, need 1..%d", n, SPLAT_RIG_MAX);
        goto done;
    }
    const cJSON *c;
    int i = 0;
    cJSON_ArrayForEach(c, cams) {
        struct splat_camera *cam = &rig->cams[i];
        if (!cJSON_IsObject(c)) {
            rc = f4d_fail(err, F4D_EFORMAT, "rig: cameras[%d] is not an object", i);
            goto done;
        }
        const cJSON *name = cJSON_GetObjectItemCaseSensitive(c, "name");
        if (cJSON_IsString(name) && name->valuestring) {
            if (strlen(name->valuestring) >= SPLAT_NAME_MAX) {
                rc = f4d_fail(err, F4D_EFORMAT, "rig: cameras[%d].name is longer than %d bytes", i, SPLAT_NAME_MAX - 1);
                goto done;
            }
            strcpy(cam->name, name->valuestring);
        } else if (name) {
            rc = f4d_fail(err, F4D_EFORMAT, "rig: cameras[%d].name is not a string", i);
            goto done;
        } else {
            snprintf(cam->name, sizeof cam->name, "cam%d", i);
        }
        double w = 0, h = 0, fx = 0, fy = 0, cx = 0, cy = 0;
        if ((rc = get_number(c, "width", &w, i, err)) < 0 || (rc = get_number(c, "height", &h, i, err)) < 0 ||
            (rc = get_number(c, "fx", &fx, i, err)) < 0 || (rc = get_number(c, "fy", &fy, i, err)) < 0 ||
            (rc = get_number(c, "cx", &cx, i, err)) < 0 || (rc = get_number(c, "cy", &cy, i, err)) < 0)
            goto done;
        if (w != floor(w) || h != floor(h) || w < 1 || h < 1 || w > 16384 || h > 16384) {
            rc = f4d_fail(err, F4D_EFORMAT, "rig: cameras[%d] width/height must be integers in 1..16384", i);
            goto done;
        }
        cam->width = (int)w;
        cam->height = (int)h;
        cam->fx = (float)fx; cam->fy = (float)fy; cam->cx = (float)cx; cam->cy = (float)cy;
        if ((rc = parse_matrix(cJSON_GetObjectItemCaseSensitive(c, "world_to_camera"), cam->w2c, i, err)) < 0)
            goto done;
        if ((rc = splat_camera_validate(cam, err)) < 0) {
            rc = F4D_EFORMAT;
            goto done;
        }
        i++;
    }
    rig->count = n;
done:
    cJSON_Delete(root);
    return rc;
}

int splat_rig_load(const char *path, struct splat_rig *rig, struct f4d_err *err)
{
    FILE *fp = fopen(path, "rb");
    if (!fp)
        return f4d_fail(err, F4D_EIO, "rig: cannot open '%s': %s", path, strerror(errno));
    char *buf = NULL;
    size_t len = 0, cap = 0;
    int rc = F4D_OK;
    for (;;) {
        if (len + 4096 + 1 > cap) {
            cap = cap ? 2 * cap : 8192;
            if (cap > (64u << 20)) {
                rc = f4d_fail(err, F4D_EFORMAT, "rig: '%s' is larger than 64 MiB", path);
                goto out;
            }
            char *nb = realloc(buf, cap);
            if (!nb) {
                rc = f4d_fail(err, F4D_ENOMEM, "rig: out of memory reading '%s'", path);
                goto out;
            }
            buf = nb;
        }
        size_t got = fread(buf + len, 1, 4096, fp);
        len += got;
        if (got < 4096)
            break;
    }
    if (ferror(fp)) {
        rc = f4d_fail(err, F4D_EIO, "rig: error reading '%s'", path);
        goto out;
    }
    buf[len] = '\0';
    rc = splat_rig_parse(buf, rig, err);
    if (rc < 0 && err) {
        char tmp[sizeof err->msg];
        memcpy(tmp, err->msg, sizeof tmp);
        int k = snprintf(err->msg, sizeof err->msg, "%.100s: ", path);
        if (k > 0 && (size_t)k < sizeof err->msg)
            snprintf(err->msg + k, sizeof err->msg - (size_t)k, "%.150s", tmp);
    }
out:
    free(buf);
    fclose(fp);
    return rc;
}

int splat_rig_save(const char *path, const struct splat_rig *rig, struct f4d_err *err)
{
    if (!rig || rig->count < 1 || rig->count > SPLAT_RIG_MAX)
        return f4d_fail(err, F4D_EINVAL, "rig_save: rig must hold 1..%d cameras", SPLAT_RIG_MAX);
    FILE *fp = fopen(path, "wb");
    if (!fp)
        return f4d_fail(err, F4D_EIO, "rig: cannot create '%s': %s", path, strerror(errno));
    /* Written by hand so the 4x4 stays readable as rows; %.9g round-trips floats. */
    fprintf(fp, "{\n  \"cameras\": [\n");
    for (int i = 0; i < rig->count; i++) {
        const struct splat_camera *c = &rig->cams[i];
        char name[2 * SPLAT_NAME_MAX];
        size_t o = 0;
        for (const char *s = c->name; *s && o + 2 < sizeof name; s++) {
            if (*s == '"' || *s == '\\')
                name[o++] = '\\';
            name[o++] = (unsigned char)*s < 0x20 ? '_' : *s;
        }
        name[o] = '\0';
        fprintf(fp, "    {\"name\": \"%s\", \"width\": %d, \"height\": %d, \"fx\": %.9g, \"fy\": %.9g, "
                    "\"cx\": %.9g, \"cy\": %.9g,\n     \"world_to_camera\": [",
                name, c->width, c->height, (double)c->fx, (double)c->fy, (double)c->cx, (double)c->cy);
        for (int r = 0; r < 4; r++)
            fprintf(fp, "%s[%.9g, %.9g, %.9g, %.9g]", r ? ", " : "", (double)c->w2c[4 * r],
                    (double)c->w2c[4 * r + 1], (double)c->w2c[4 * r + 2], (double)c->w2c[4 * r + 3]);
        fprintf(fp, "]}%s\n", i + 1 < rig->count ? "," : "");
    }
    fprintf(fp, "  ]\n}\n");
    if (fclose(fp) != 0)
        return f4d_fail(err, F4D_EIO, "rig: error writing '%s'", path);
    return F4D_OK;
}

int splat_rig_find(const struct splat_rig *rig, const char *key, struct f4d_err *err)
{
    if (!rig || !key || !*key)
        return f4d_fail(err, F4D_EINVAL, "camera name or index is empty");
    for (int i = 0; i < rig->count; i++)
        if (!strcmp(rig->cams[i].name, key))
            return i;
    char *end;
    errno = 0;
    long v = strtol(key, &end, 10);
    if (*end == '\0' && errno == 0) {
        if (v >= 0 && v < rig->count)
            return (int)v;
        return f4d_fail(err, F4D_EINVAL, "camera index %ld is out of range 0..%d", v, rig->count - 1);
    }
    return f4d_fail(err, F4D_EINVAL, "no camera named '%s' in the rig (%d cameras)", key, rig->count);
}

void splat_flow_from_motion(const struct splat_camera *cam, const float *depth, const float *alpha,
                            const float *motion3, float *flow)
{
    const float *m = cam->w2c;
    const int W = cam->width, H = cam->height;
    for (int y = 0; y < H; y++)
        for (int x = 0; x < W; x++) {
            size_t p = (size_t)y * (size_t)W + (size_t)x;
            flow[2 * p] = flow[2 * p + 1] = 0.0f;
            float z = depth[p];
            if (!(z > 0.0f) || !(alpha[p] >= 0.5f))
                continue;
            float u = (float)x + 0.5f, v = (float)y + 0.5f;
            float q[3] = { (u - cam->cx) / cam->fx * z, (v - cam->cy) / cam->fy * z, z };
            for (int r = 0; r < 3; r++) /* camera-frame displacement R * motion */
                q[r] += m[4 * r] * motion3[3 * p] + m[4 * r + 1] * motion3[3 * p + 1] + m[4 * r + 2] * motion3[3 * p + 2];
            if (!(q[2] > 1e-3f))
                continue;
            flow[2 * p] = cam->fx * q[0] / q[2] + cam->cx - u;
            flow[2 * p + 1] = cam->fy * q[1] / q[2] + cam->cy - v;
        }
}
