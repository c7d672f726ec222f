/* hal_sim_pattern.c: the procedural test pattern the sim cameras show until a
 * scene renderer is plugged in. It moves with time (a bright disc on a
 * circular path, seen from a per-camera angle, over a colour gradient), so a
 * contact sheet shows at a glance whether the views of a set match. */
#include "hal_sim.h"

#include <math.h>

int hal_sim_render_pattern(void *user, uint32_t cam, uint64_t t_ns, const struct hal_format *f,
                           uint8_t *dst)
{
    (void)user;
    const double t = (double)t_ns * 1e-9;
    const double w = f->width, h = f->height;
    /* the disc orbits once every 2 s; each camera looks from its own angle */
    const double view = 0.5 * (double)cam;
    const double cx = w * (0.5 + 0.3 * cos(2.0 * M_PI * t / 2.0 + view));
    const double cy = h * (0.5 + 0.3 * sin(2.0 * M_PI * t / 2.0 + view));
    const double r2 = (0.08 * w) * (0.08 * w);
    const uint32_t bpp = hal_pixfmt_bytes_per_pixel(f->pixfmt);
    const uint8_t tint = (uint8_t)(40u * (cam % 6u));
    for (uint32_t y = 0; y < f->height; y++) {
        uint8_t *row = dst + (size_t)y * f->stride;
        const double dy = (double)y - cy;
        for (uint32_t x = 0; x < f->width; x++) {
            const double dx = (double)x - cx;
            const int disc = dx * dx + dy * dy < r2;
            uint8_t r = (uint8_t)(x * 255u / f->width), g = (uint8_t)(y * 255u / f->height);
            uint8_t b = (uint8_t)(tint + (((x >> 4) ^ (y >> 4)) & 1u) * 40u);
            if (disc)
                r = g = b = 255;
            if (bpp == 3) {
                row[3 * x] = r;
                row[3 * x + 1] = g;
                row[3 * x + 2] = b;
            } else {
                row[x] = (uint8_t)((r + 2u * g + b) / 4u);
            }
        }
    }
    return 0;
}
