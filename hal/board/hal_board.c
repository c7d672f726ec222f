/* hal_board.c: board description files (JSON via cJSON) -> struct hal_board. */
#include "hal_board.h"
#include "hal_backend.h"

#include <cjson/cJSON.h>
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* Parsing context: the JSON path of the object being read, for messages. */
struct ctx {
    struct f4d_err *err;
    char path[96];
};

static int fail(struct ctx *c, const char *key, const char *what)
{
    return f4d_fail(c->err, F4D_EINVAL, "board: %s%s%s: %s", c->path, c->path[0] ? "." : "",
                    key, what);
}

/* Every key of `obj` must be in the NULL-terminated list. */
static int check_keys(struct ctx *c, const cJSON *obj, const char *const *keys)
{
    for (const cJSON *it = obj->child; it; it = it->next) {
        bool ok = false;
        for (size_t i = 0; keys[i] && !ok; i++)
            ok = it->string && strcmp(it->string, keys[i]) == 0;
        if (!ok) {
            char msg[160];
            snprintf(msg, sizeof msg, "unknown key (typo?)");
            return fail(c, it->string ? it->string : "?", msg);
        }
    }
    return 0;
}

static int get_num(struct ctx *c, const cJSON *obj, const char *key, double lo, double hi,
                   double *out)
{
    const cJSON *v = cJSON_GetObjectItemCaseSensitive(obj, key);
    if (!v)
        return 0;
    if (!cJSON_IsNumber(v) || !isfinite(v->valuedouble))
        return fail(c, key, "must be a number");
    if (v->valuedouble < lo || v->valuedouble > hi) {
        char msg[128];
        snprintf(msg, sizeof msg, "must be %g..%g, got %g", lo, hi, v->valuedouble);
        return fail(c, key, msg);
    }
    *out = v->valuedouble;
    return 0;
}

/* get_num for a whole number in lo..hi (both fit the caller's integer type). */
static int get_int(struct ctx *c, const cJSON *obj, const char *key, double lo, double hi, double *d)
{
    int rc = get_num(c, obj, key, lo, hi, d);
    if (rc < 0)
        return rc;
    if (*d != floor(*d))
        return fail(c, key, "must be an integer");
    return 0;
}

static int get_u32(struct ctx *c, const cJSON *obj, const char *key, uint32_t lo, uint32_t hi,
                   uint32_t *out)
{
    double d = *out;
    int rc = get_int(c, obj, key, lo, hi, &d);
    if (rc == 0) /* unchanged when the value is bad */
        *out = (uint32_t)d;
    return rc;
}

static int get_i32(struct ctx *c, const cJSON *obj, const char *key, int32_t lo, int32_t hi,
                   int32_t *out)
{
    double d = *out;
    int rc = get_int(c, obj, key, lo, hi, &d);
    if (rc == 0)
        *out = (int32_t)d;
    return rc;
}

static int get_str(struct ctx *c, const cJSON *obj, const char *key, char *out, size_t cap)
{
    const cJSON *v = cJSON_GetObjectItemCaseSensitive(obj, key);
    if (!v)
        return 0;
    if (!cJSON_IsString(v) || !v->valuestring)
        return fail(c, key, "must be a string");
    if (strlen(v->valuestring) >= cap)
        return fail(c, key, "string too long");
    memcpy(out, v->valuestring, strlen(v->valuestring) + 1);
    return 0;
}

static int get_bool(struct ctx *c, const cJSON *obj, const char *key, bool *out)
{
    const cJSON *v = cJSON_GetObjectItemCaseSensitive(obj, key);
    if (!v)
        return 0;
    if (!cJSON_IsBool(v))
        return fail(c, key, "must be true or false");
    *out = cJSON_IsTrue(v);
    return 0;
}

static const cJSON *get_obj(struct ctx *c, const cJSON *obj, const char *key, int *rc)
{
    const cJSON *v = cJSON_GetObjectItemCaseSensitive(obj, key);
    *rc = 0;
    if (v && !cJSON_IsObject(v)) {
        *rc = fail(c, key, "must be an object");
        return NULL;
    }
    return v;
}

static void push(struct ctx *c, const char *seg, size_t *saved)
{
    *saved = strlen(c->path);
    snprintf(c->path + *saved, sizeof c->path - *saved, "%s%s", *saved ? "." : "", seg);
}
static void pop(struct ctx *c, size_t saved) { c->path[saved] = 0; }

#define TRY(x)                                                                                   \
    do {                                                                                         \
        int rc_ = (x);                                                                           \
        if (rc_ < 0)                                                                             \
            return rc_;                                                                          \
    } while (0)

static int parse_backend(struct ctx *c, const cJSON *o, char *out, size_t cap, bool camera)
{
    TRY(get_str(c, o, "backend", out, cap));
    static const char *const cams[] = {"sim", "aravis", "usb", "libcamera", "replay", NULL};
    static const char *const trigs[] = {"sim", "gpiod", "aravis", "usb", "replay", NULL};
    const char *const *ok = camera ? cams : trigs;
    for (size_t i = 0; ok[i]; i++)
        if (strcmp(out, ok[i]) == 0)
            return 0;
    char msg[128];
    snprintf(msg, sizeof msg, "unknown backend \"%s\"", out);
    return fail(c, "backend", msg);
}

static int parse_camera(struct ctx *c, const cJSON *o, struct hal_camera_config *cc)
{
    static const char *const keys[] = {"id", "backend", "serial", "address", "width", "height",
                                       "pixel_format", "trigger_line", "exposure_us",
                                       "packet_size", "socket_buffer", "intrinsics", NULL};
    if (!cJSON_IsObject(o))
        return fail(c, "", "must be an object");
    TRY(check_keys(c, o, keys));
    TRY(get_str(c, o, "id", cc->id, sizeof cc->id));
    TRY(parse_backend(c, o, cc->backend, sizeof cc->backend, true));
    TRY(get_str(c, o, "serial", cc->serial, sizeof cc->serial));
    TRY(get_str(c, o, "address", cc->address, sizeof cc->address));
    TRY(get_u32(c, o, "width", 16, 65535, &cc->width));
    TRY(get_u32(c, o, "height", 16, 65535, &cc->height));
    char pf[32] = "";
    TRY(get_str(c, o, "pixel_format", pf, sizeof pf));
    if (pf[0]) {
        cc->pixfmt = hal_pixfmt_parse(pf);
        if (cc->pixfmt == HAL_PIXFMT_INVALID)
            return fail(c, "pixel_format", "unknown (mono8, rgb8, bayer_rg8, mono16, yuyv)");
    }
    TRY(get_i32(c, o, "trigger_line", -1, 1023, &cc->trigger_line));
    TRY(get_u32(c, o, "exposure_us", 1, 10000000, &cc->exposure_us));
    TRY(get_u32(c, o, "packet_size", 0, 65536, &cc->packet_size));
    TRY(get_u32(c, o, "socket_buffer", 0, 1u << 30, &cc->socket_buffer));
    int rc;
    const cJSON *in = get_obj(c, o, "intrinsics", &rc);
    TRY(rc);
    if (in) {
        static const char *const ik[] = {"fx", "fy", "cx", "cy", NULL};
        size_t saved;
        push(c, "intrinsics", &saved);
        TRY(check_keys(c, in, ik));
        const char *const names[] = {"fx", "fy", "cx", "cy"};
        double *vals[] = {&cc->intrinsics.fx, &cc->intrinsics.fy, &cc->intrinsics.cx,
                          &cc->intrinsics.cy};
        for (int i = 0; i < 4; i++) {
            if (!cJSON_GetObjectItemCaseSensitive(in, names[i]))
                return fail(c, names[i], "missing (give all of fx, fy, cx, cy)");
            TRY(get_num(c, in, names[i], i < 2 ? 1e-3 : -1e6, 1e6, vals[i]));
        }
        cc->intrinsics.known = true;
        pop(c, saved);
    }
    return 0;
}

static int parse_faults(struct ctx *c, const cJSON *o, struct hal_sim_faults *f)
{
    static const char *const keys[] = {"drop", "duplicate", "late", "incomplete",
                                       "trigger_missing", "trigger_extra", "disconnect",
                                       "disconnect_ms", "late_ms", "jitter_us",
                                       "clock_offset_ms", "clock_drift_ppm", NULL};
    TRY(check_keys(c, o, keys));
    const struct {
        const char *key;
        double *out;
    } probs[] = { /* each 0..1 */
        {"drop", &f->drop},
        {"duplicate", &f->duplicate},
        {"late", &f->late},
        {"incomplete", &f->incomplete},
        {"trigger_missing", &f->trigger_missing},
        {"trigger_extra", &f->trigger_extra},
        {"disconnect", &f->disconnect},
    };
    for (size_t i = 0; i < sizeof probs / sizeof probs[0]; i++)
        TRY(get_num(c, o, probs[i].key, 0, 1, probs[i].out));
    const struct {
        const char *key;
        uint32_t lo, hi;
        uint32_t *out;
    } counts[] = {
        {"disconnect_ms", 1, 600000, &f->disconnect_ms},
        {"late_ms", 1, 60000, &f->late_ms},
        {"jitter_us", 0, 1000000, &f->jitter_us},
        {"clock_offset_ms", 0, 100000000, &f->clock_offset_ms},
        {"clock_drift_ppm", 0, 100000, &f->clock_drift_ppm},
    };
    for (size_t i = 0; i < sizeof counts / sizeof counts[0]; i++)
        TRY(get_u32(c, o, counts[i].key, counts[i].lo, counts[i].hi, counts[i].out));
    if (f->drop + f->duplicate + f->late + f->incomplete > 1.0)
        return fail(c, "drop", "drop + duplicate + late + incomplete must be <= 1");
    return 0;
}

static int parse_root(struct ctx *c, const cJSON *root, struct hal_board *b)
{
    static const char *const keys[] = {"name", "cameras", "trigger", "sync", "recording", "sim",
                                       "description", NULL};
    if (!cJSON_IsObject(root))
        return fail(c, "(root)", "must be a JSON object");
    TRY(check_keys(c, root, keys));
    TRY(get_str(c, root, "name", b->name, sizeof b->name));
    const cJSON *d = cJSON_GetObjectItemCaseSensitive(root, "description");
    if (d && !cJSON_IsString(d))
        return fail(c, "description", "must be a string");

    const cJSON *cams = cJSON_GetObjectItemCaseSensitive(root, "cameras");
    if (!cams)
        return fail(c, "cameras", "missing (a board needs at least one camera)");
    if (!cJSON_IsArray(cams))
        return fail(c, "cameras", "must be an array");
    int n = cJSON_GetArraySize(cams);
    if (n < 1 || n > HAL_RIG_CAMERAS_MAX) {
        char msg[64];
        snprintf(msg, sizeof msg, "must hold 1..%d cameras, got %d", HAL_RIG_CAMERAS_MAX, n);
        return fail(c, "cameras", msg);
    }
    int i = 0;
    for (const cJSON *it = cams->child; it; it = it->next, i++) {
        char seg[24];
        size_t saved;
        snprintf(seg, sizeof seg, "cameras[%d]", i);
        push(c, seg, &saved);
        TRY(parse_camera(c, it, &b->cams[i]));
        pop(c, saved);
        for (int j = 0; j < i; j++)
            if (strcmp(b->cams[j].id, b->cams[i].id) == 0) {
                snprintf(seg, sizeof seg, "cameras[%d]", i);
                return fail(c, seg, "duplicate camera id");
            }
    }
    b->n_cams = (uint32_t)n;

    int rc;
    size_t saved;
    const cJSON *t = get_obj(c, root, "trigger", &rc);
    TRY(rc);
    if (t) {
        static const char *const tk[] = {"backend", "chip", "line", "strobe_line", "rate_hz",
                                         "pulse_width_us", NULL};
        push(c, "trigger", &saved);
        TRY(check_keys(c, t, tk));
        TRY(parse_backend(c, t, b->trigger.backend, sizeof b->trigger.backend, false));
        TRY(get_str(c, t, "chip", b->trigger.chip, sizeof b->trigger.chip));
        TRY(get_i32(c, t, "line", 0, 1023, &b->trigger.line));
        TRY(get_i32(c, t, "strobe_line", -1, 1023, &b->trigger.strobe_line));
        double hz = b->trigger.rate_mhz / 1000.0;
        TRY(get_num(c, t, "rate_hz", 0.01, 10000, &hz));
        b->trigger.rate_mhz = (uint32_t)llround(hz * 1000.0);
        TRY(get_u32(c, t, "pulse_width_us", 1, 1000000, &b->trigger.pulse_width_us));
        if ((double)b->trigger.pulse_width_us * 1e-6 >= 1.0 / hz)
            return fail(c, "pulse_width_us", "must be shorter than the trigger period");
        pop(c, saved);
    }
    const cJSON *s = get_obj(c, root, "sync", &rc);
    TRY(rc);
    if (s) {
        static const char *const sk[] = {"window_us", "max_latency_ms", "incomplete",
                                         "pending_max", NULL};
        push(c, "sync", &saved);
        TRY(check_keys(c, s, sk));
        TRY(get_u32(c, s, "window_us", 1, 1000000, &b->sync.window_us));
        uint32_t ms = b->sync.max_latency_us / 1000u;
        TRY(get_u32(c, s, "max_latency_ms", 1, 10000, &ms));
        b->sync.max_latency_us = ms * 1000u;
        char pol[16] = "";
        TRY(get_str(c, s, "incomplete", pol, sizeof pol));
        if (pol[0] && strcmp(pol, "drop") == 0)
            b->sync.incomplete = HAL_INCOMPLETE_DROP;
        else if (pol[0] && strcmp(pol, "mark") == 0)
            b->sync.incomplete = HAL_INCOMPLETE_MARK;
        else if (pol[0])
            return fail(c, "incomplete", "must be \"drop\" or \"mark\"");
        TRY(get_u32(c, s, "pending_max", 1, 64, &b->sync.pending_max));
        /* every open set holds a buffer of each camera, plus the spares capture
         * keeps queued: more than a camera's queue holds never enqueues */
        for (uint32_t k = 0; k < b->n_cams; k++) {
            const bool usb = strcmp(b->cams[k].backend, "usb") == 0;
            const uint32_t ring = usb ? HAL_USB_BUFFERS_MAX : HAL_BUFQ_MAX;
            const uint32_t most = ring - HAL_CAPTURE_SPARE_BUFFERS;
            if (b->sync.pending_max > most) {
                char msg[256];
                snprintf(msg, sizeof msg, "must be at most %u for camera \"%s\" (%s backend: "
                         "%u buffers per camera, %u kept spare by capture), got %u", most,
                         b->cams[k].id, usb ? "usb" : b->cams[k].backend, ring,
                         HAL_CAPTURE_SPARE_BUFFERS, b->sync.pending_max);
                return fail(c, "pending_max", msg);
            }
        }
        pop(c, saved);
    }
    const cJSON *r = get_obj(c, root, "recording", &rc);
    TRY(rc);
    if (r) {
        static const char *const rk[] = {"directory", "durability_ms", NULL};
        push(c, "recording", &saved);
        TRY(check_keys(c, r, rk));
        TRY(get_str(c, r, "directory", b->record_dir, sizeof b->record_dir));
        TRY(get_u32(c, r, "durability_ms", 1, 60000, &b->durability_ms));
        pop(c, saved);
    }
    const cJSON *sim = get_obj(c, root, "sim", &rc);
    TRY(rc);
    if (sim) {
        static const char *const mk[] = {"seed", "realtime", "scene", "faults", NULL};
        push(c, "sim", &saved);
        TRY(check_keys(c, sim, mk));
        double seed = (double)b->sim.seed;
        TRY(get_num(c, sim, "seed", 0, 9007199254740991.0, &seed));
        b->sim.seed = (uint64_t)seed;
        TRY(get_bool(c, sim, "realtime", &b->sim.realtime));
        TRY(get_str(c, sim, "scene", b->sim.scene, sizeof b->sim.scene));
        const cJSON *f = get_obj(c, sim, "faults", &rc);
        TRY(rc);
        if (f) {
            size_t s2;
            push(c, "faults", &s2);
            TRY(parse_faults(c, f, &b->sim.faults));
            pop(c, s2);
        }
        pop(c, saved);
    }
    return 0;
}

int hal_board_parse(struct hal_board *b, const char *json, size_t len, struct f4d_err *err)
{
    hal_board_defaults(b);
    b->sim.realtime = true;
    struct ctx c = {err, ""};
    cJSON *root = cJSON_ParseWithLength(json, len);
    if (!root) {
        const char *at = cJSON_GetErrorPtr();
        size_t off = (at && at >= json && at <= json + len) ? (size_t)(at - json) : 0;
        return f4d_fail(err, F4D_EINVAL, "board: not valid JSON (near byte %zu)", off);
    }
    int rc = parse_root(&c, root, b);
    cJSON_Delete(root);
    return rc;
}

int hal_board_load(struct hal_board *b, const char *path, struct f4d_err *err)
{
    FILE *f = fopen(path, "rb");
    if (!f)
        return f4d_fail(err, F4D_EIO, "board %s: cannot open: %s", path, strerror(errno));
    enum { MAX = 1 << 20 };
    char *buf = malloc(MAX);
    if (!buf) {
        fclose(f);
        return f4d_fail(err, F4D_ENOMEM, "board %s: out of memory", path);
    }
    size_t n = fread(buf, 1, MAX, f);
    int rd_err = ferror(f);
    fclose(f);
    int rc;
    if (rd_err)
        rc = f4d_fail(err, F4D_EIO, "board %s: read error", path);
    else if (n == MAX)
        rc = f4d_fail(err, F4D_EINVAL, "board %s: larger than 1 MiB", path);
    else {
        rc = hal_board_parse(b, buf, n, err);
        if (rc < 0)
            f4d_err_prefix(err, "%s", path);
    }
    free(buf);
    return rc;
}

char *hal_board_to_json(const struct hal_board *b)
{
    cJSON *root = cJSON_CreateObject();
    if (!root)
        return NULL;
    cJSON_AddStringToObject(root, "name", b->name);
    cJSON *cams = cJSON_AddArrayToObject(root, "cameras");
    for (uint32_t i = 0; cams && i < b->n_cams; i++) {
        const struct hal_camera_config *cc = &b->cams[i];
        cJSON *o = cJSON_CreateObject();
        if (!o)
            break;
        cJSON_AddItemToArray(cams, o);
        cJSON_AddStringToObject(o, "id", cc->id);
        cJSON_AddStringToObject(o, "backend", cc->backend);
        cJSON_AddStringToObject(o, "serial", cc->serial);
        cJSON_AddStringToObject(o, "address", cc->address);
        cJSON_AddNumberToObject(o, "width", cc->width);
        cJSON_AddNumberToObject(o, "height", cc->height);
        cJSON_AddStringToObject(o, "pixel_format", hal_pixfmt_name(cc->pixfmt));
        cJSON_AddNumberToObject(o, "trigger_line", cc->trigger_line);
        cJSON_AddNumberToObject(o, "exposure_us", cc->exposure_us);
        cJSON_AddNumberToObject(o, "packet_size", cc->packet_size);
        cJSON_AddNumberToObject(o, "socket_buffer", cc->socket_buffer);
        if (cc->intrinsics.known) {
            cJSON *in = cJSON_AddObjectToObject(o, "intrinsics");
            cJSON_AddNumberToObject(in, "fx", cc->intrinsics.fx);
            cJSON_AddNumberToObject(in, "fy", cc->intrinsics.fy);
            cJSON_AddNumberToObject(in, "cx", cc->intrinsics.cx);
            cJSON_AddNumberToObject(in, "cy", cc->intrinsics.cy);
        }
    }
    cJSON *t = cJSON_AddObjectToObject(root, "trigger");
    cJSON_AddStringToObject(t, "backend", b->trigger.backend);
    cJSON_AddStringToObject(t, "chip", b->trigger.chip);
    cJSON_AddNumberToObject(t, "line", b->trigger.line);
    cJSON_AddNumberToObject(t, "strobe_line", b->trigger.strobe_line);
    cJSON_AddNumberToObject(t, "rate_hz", b->trigger.rate_mhz / 1000.0);
    cJSON_AddNumberToObject(t, "pulse_width_us", b->trigger.pulse_width_us);
    cJSON *s = cJSON_AddObjectToObject(root, "sync");
    cJSON_AddNumberToObject(s, "window_us", b->sync.window_us);
    cJSON_AddNumberToObject(s, "max_latency_ms", b->sync.max_latency_us / 1000u);
    cJSON_AddStringToObject(s, "incomplete", b->sync.incomplete == HAL_INCOMPLETE_MARK ? "mark" : "drop");
    cJSON_AddNumberToObject(s, "pending_max", b->sync.pending_max);
    cJSON *r = cJSON_AddObjectToObject(root, "recording");
    cJSON_AddStringToObject(r, "directory", b->record_dir);
    cJSON_AddNumberToObject(r, "durability_ms", b->durability_ms);
    cJSON *sim = cJSON_AddObjectToObject(root, "sim");
    cJSON_AddNumberToObject(sim, "seed", (double)b->sim.seed);
    cJSON_AddBoolToObject(sim, "realtime", b->sim.realtime);
    cJSON_AddStringToObject(sim, "scene", b->sim.scene);
    const struct hal_sim_faults *f = &b->sim.faults;
    cJSON *fo = cJSON_AddObjectToObject(sim, "faults");
    cJSON_AddNumberToObject(fo, "drop", f->drop);
    cJSON_AddNumberToObject(fo, "duplicate", f->duplicate);
    cJSON_AddNumberToObject(fo, "late", f->late);
    cJSON_AddNumberToObject(fo, "incomplete", f->incomplete);
    cJSON_AddNumberToObject(fo, "trigger_missing", f->trigger_missing);
    cJSON_AddNumberToObject(fo, "trigger_extra", f->trigger_extra);
    cJSON_AddNumberToObject(fo, "disconnect", f->disconnect);
    cJSON_AddNumberToObject(fo, "disconnect_ms", f->disconnect_ms);
    cJSON_AddNumberToObject(fo, "late_ms", f->late_ms);
    cJSON_AddNumberToObject(fo, "jitter_us", f->jitter_us);
    cJSON_AddNumberToObject(fo, "clock_offset_ms", f->clock_offset_ms);
    cJSON_AddNumberToObject(fo, "clock_drift_ppm", f->clock_drift_ppm);
    char *out = cJSON_Print(root);
    cJSON_Delete(root);
    return out;
}
