/* hal_core.c: names, format arithmetic, the monotonic clock and board defaults. */
#include "hal.h"

#include <stdarg.h>
#include <stdio.h>
#include <string.h>
#include <strings.h>
#include <time.h>

static const struct {
    enum hal_pixfmt f;
    const char *name;
    uint32_t bpp;
} pixfmts[] = {
    {HAL_PIXFMT_MONO8, "mono8", 1},   {HAL_PIXFMT_RGB8, "rgb8", 3},
    {HAL_PIXFMT_BAYER_RG8, "bayer_rg8", 1}, {HAL_PIXFMT_MONO16, "mono16", 2},
    {HAL_PIXFMT_YUYV, "yuyv", 2},
};

const char *hal_pixfmt_name(enum hal_pixfmt f)
{
    for (size_t i = 0; i < sizeof pixfmts / sizeof pixfmts[0]; i++)
        if (pixfmts[i].f == f)
            return pixfmts[i].name;
    return "?";
}

enum hal_pixfmt hal_pixfmt_parse(const char *name)
{
    for (size_t i = 0; name && i < sizeof pixfmts / sizeof pixfmts[0]; i++)
        if (strcasecmp(pixfmts[i].name, name) == 0)
            return pixfmts[i].f;
    return HAL_PIXFMT_INVALID;
}

uint32_t hal_pixfmt_bytes_per_pixel(enum hal_pixfmt f)
{
    for (size_t i = 0; i < sizeof pixfmts / sizeof pixfmts[0]; i++)
        if (pixfmts[i].f == f)
            return pixfmts[i].bpp;
    return 0;
}

const char *hal_frame_status_name(enum hal_frame_status s)
{
    switch (s) {
    case HAL_FRAME_OK: return "ok";
    case HAL_FRAME_TIMEOUT: return "timeout";
    case HAL_FRAME_MISSING_PACKETS: return "missing_packets";
    case HAL_FRAME_SIZE_MISMATCH: return "size_mismatch";
    case HAL_FRAME_ABORTED: return "aborted";
    }
    return "?";
}

int hal_format_finish(struct hal_format *f)
{
    uint32_t bpp = hal_pixfmt_bytes_per_pixel(f->pixfmt);
    if (bpp == 0 || f->width == 0 || f->height == 0 || f->width > 65535 || f->height > 65535)
        return F4D_EINVAL;
    uint64_t tight = (uint64_t)f->width * bpp;
    if (f->stride == 0)
        f->stride = (uint32_t)tight;
    if (f->stride < tight)
        return F4D_EINVAL;
    f->image_bytes = (size_t)f->stride * f->height;
    return F4D_OK;
}


/* ---- monotonic clock ---- */
static uint64_t mono_now(void *ctx)
{
    (void)ctx;
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (uint64_t)ts.tv_sec * 1000000000u + (uint64_t)ts.tv_nsec;
}

static void mono_sleep_until(void *ctx, uint64_t t)
{
    (void)ctx;
    struct timespec ts = {(time_t)(t / 1000000000u), (long)(t % 1000000000u)};
    while (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &ts, NULL) != 0) {
    }
}

struct hal_clock hal_clock_monotonic(void)
{
    struct hal_clock c = {{HAL_API_VERSION, mono_now, mono_sleep_until, NULL}, NULL};
    return c;
}

void hal_board_defaults(struct hal_board *b)
{
    memset(b, 0, sizeof *b);
    snprintf(b->name, sizeof b->name, "unnamed");
    snprintf(b->trigger.backend, sizeof b->trigger.backend, "sim");
    b->trigger.line = 0;
    b->trigger.strobe_line = -1;
    b->trigger.rate_mhz = 30000;
    b->trigger.pulse_width_us = 1000;
    b->sync.window_us = 2000;
    b->sync.max_latency_us = 25000;
    b->sync.incomplete = HAL_INCOMPLETE_DROP;
    b->sync.pending_max = 8;
    b->sim.seed = 1;
    snprintf(b->sim.scene, sizeof b->sim.scene, "pattern");
    b->sim.faults.disconnect_ms = 200;
    b->sim.faults.late_ms = 80;
    snprintf(b->record_dir, sizeof b->record_dir, "takes");
    b->durability_ms = 250;
    for (uint32_t i = 0; i < HAL_RIG_CAMERAS_MAX; i++) {
        struct hal_camera_config *c = &b->cams[i];
        snprintf(c->backend, sizeof c->backend, "sim");
        snprintf(c->id, sizeof c->id, "cam%u", (unsigned)i);
        c->width = 518;
        c->height = 518;
        c->pixfmt = HAL_PIXFMT_RGB8;
        c->trigger_line = 0;
        c->exposure_us = 2000;
    }
}
