/* run_config.c: `forge4d run` settings from the config file
 * (/etc/forge4d/forge4d.conf by default): key = value lines, '#' starts a
 * comment, blank lines ignored. The command line wins over the file. */
#include <ctype.h>
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "run_internal.h"

void run_config_defaults(struct run_config *c)
{
    memset(c, 0, sizeof *c);
    snprintf(c->precision, sizeof c->precision, "f32");
    snprintf(c->quality, sizeof c->quality, "medium");
    snprintf(c->codec_effort, sizeof c->codec_effort, "fast");
    c->stall_ms = 5000;
    c->intra_every = 10;
}

static int set_str(char *dst, size_t cap, const char *key, const char *v, struct f4d_err *err)
{
    if (strlen(v) >= cap)
        return f4d_fail(err, F4D_EINVAL, "%s: value longer than %zu characters", key, cap - 1);
    memcpy(dst, v, strlen(v) + 1);
    return 0;
}

static int set_uint(uint32_t *dst, const char *key, const char *v, uint32_t lo, uint32_t hi, struct f4d_err *err)
{
    char *end;
    errno = 0;
    unsigned long x = strtoul(v, &end, 10);
    if (!isdigit((unsigned char)v[0]) || *end || errno || x < lo || x > hi)
        return f4d_fail(err, F4D_EINVAL, "%s wants an integer in [%u, %u], got \"%s\"", key, lo, hi, v);
    *dst = (uint32_t)x;
    return 0;
}

int run_config_set(struct run_config *c, const char *key, const char *v, struct f4d_err *err)
{
#define STR(name) if (!strcmp(key, #name)) return set_str(c->name, sizeof c->name, key, v, err)
    STR(board);
    STR(replay);
    STR(weights);
    STR(stream);
    STR(record);
    STR(stats_json);
    STR(rig_json);
    STR(key_times);
    STR(display);
    STR(display_args);
    STR(display_json);
#undef STR
    if (!strcmp(key, "precision")) {
        if (strcmp(v, "f32") && strcmp(v, "f16") && strcmp(v, "int8"))
            return f4d_fail(err, F4D_EINVAL, "precision must be f32, f16 or int8, got \"%s\"", v);
        return set_str(c->precision, sizeof c->precision, key, v, err);
    }
    if (!strcmp(key, "quality")) {
        if (strcmp(v, "low") && strcmp(v, "medium") && strcmp(v, "high"))
            return f4d_fail(err, F4D_EINVAL, "quality must be low, medium or high, got \"%s\"", v);
        return set_str(c->quality, sizeof c->quality, key, v, err);
    }
    if (!strcmp(key, "codec_effort")) {
        if (strcmp(v, "fast") && strcmp(v, "default") && strcmp(v, "max"))
            return f4d_fail(err, F4D_EINVAL, "codec_effort must be fast, default or max, got \"%s\"", v);
        return set_str(c->codec_effort, sizeof c->codec_effort, key, v, err);
    }
    if (!strcmp(key, "seconds")) {
        char *end;
        double s = strtod(v, &end);
        if (end == v || *end || !(s >= 0) || s > 1e7)
            return f4d_fail(err, F4D_EINVAL, "seconds wants a number >= 0 (0: until stopped), got \"%s\"", v);
        c->seconds = s;
        return 0;
    }
    if (!strcmp(key, "key_hz")) {
        char *end;
        double h = strtod(v, &end);
        if (end == v || *end || !(h >= 0) || h > 1000)
            return f4d_fail(err, F4D_EINVAL, "key_hz wants a number in [0, 1000] (0: no limit), got \"%s\"", v);
        c->key_hz = h;
        return 0;
    }
    if (!strcmp(key, "threads")) {
        uint32_t t;
        int rc = set_uint(&t, key, v, 0, 256, err);
        c->threads = (int)t;
        return rc;
    }
    if (!strcmp(key, "lockstep")) {
        if (strcmp(v, "auto") && strcmp(v, "off"))
            return f4d_fail(err, F4D_EINVAL, "lockstep must be auto or off, got \"%s\"", v);
        c->no_lockstep = !strcmp(v, "off");
        return 0;
    }
    if (!strcmp(key, "motion")) {
        if (strcmp(v, "on") && strcmp(v, "off"))
            return f4d_fail(err, F4D_EINVAL, "motion must be on or off, got \"%s\"", v);
        c->motion_off = !strcmp(v, "off");
        return 0;
    }
    if (!strcmp(key, "keys"))
        return set_uint(&c->keys, key, v, 0, 1000000000, err);
    if (!strcmp(key, "stall_ms"))
        return set_uint(&c->stall_ms, key, v, 100, 3600000, err);
    if (!strcmp(key, "intra_every"))
        return set_uint(&c->intra_every, key, v, 1, 100000, err);
    return f4d_fail(err, F4D_EINVAL, "unknown key \"%s\"", key);
}

static char *trim(char *s)
{
    while (isspace((unsigned char)*s))
        s++;
    size_t n = strlen(s);
    while (n && isspace((unsigned char)s[n - 1]))
        s[--n] = 0;
    return s;
}

int run_config_load(struct run_config *c, const char *path, struct f4d_err *err)
{
    FILE *f = fopen(path, "r");
    if (!f)
        return f4d_fail(err, F4D_EIO, "config %s: %s", path, strerror(errno));
    char line[1024];
    int no = 0, rc = 0;
    while (rc == 0 && fgets(line, sizeof line, f)) {
        no++;
        if (!strchr(line, '\n') && !feof(f)) {
            rc = f4d_fail(err, F4D_EINVAL, "config %s:%d: line longer than %zu characters", path, no,
                          sizeof line - 2);
            break;
        }
        char *hash = strchr(line, '#');
        if (hash)
            *hash = 0;
        char *s = trim(line);
        if (!*s)
            continue;
        char *eq = strchr(s, '=');
        if (!eq) {
            rc = f4d_fail(err, F4D_EINVAL, "config %s:%d: expected key = value, got \"%s\"", path, no, s);
            break;
        }
        *eq = 0;
        struct f4d_err e = {0};
        if (run_config_set(c, trim(s), trim(eq + 1), &e) < 0)
            rc = f4d_fail(err, F4D_EINVAL, "config %s:%d: %s", path, no, e.msg);
    }
    fclose(f);
    return rc;
}
