/* f4d_simscene.c: synthetic scene rendering for the sim cameras. */
#include "f4d_simscene.h"

#include <stdlib.h>
#include <string.h>

#include "fk_ctx.h"
#include "scene.h"

struct f4d_simscene {
    fk_ctx *ctx;
    scene *sc;
    splat_renderer *r;
    struct splat_rig rig;
    struct splat_frame f;
    double t_cached; /* the frame holds the scene at this time */
    bool have_t;
    uint32_t width, height;
    uint8_t *rgba; /* the render quantised by splat (floor(clamp(v) * 255 + 0.5)), as the
                      float image was here: same bytes, no float image written or read */
};

int f4d_simscene_new(struct f4d_simscene **out, const char *preset, uint64_t seed, uint32_t views,
                     uint32_t width, uint32_t height, struct f4d_err *err)
{
    *out = NULL;
    struct f4d_err se;
    memset(&se, 0, sizeof se);
    int p = scene_preset_from_name(preset, &se);
    if (p < 0)
        return f4d_fail(err, F4D_EINVAL, "sim scene: %s", se.msg);
    if (views < 1 || views > 8 || width < 16 || height < 16)
        return f4d_fail(err, F4D_EINVAL, "sim scene: %u views of %ux%u (want 1..8 views, >= 16x16)",
                        (unsigned)views, (unsigned)width, (unsigned)height);
    struct f4d_simscene *ss = calloc(1, sizeof *ss);
    if (!ss)
        return f4d_fail(err, F4D_ENOMEM, "sim scene: out of memory");
    ss->width = width;
    ss->height = height;
    ss->rgba = malloc((size_t)width * height * 4);
    struct fk_ctx_config cfg = {.isa = FK_ISA_AUTO, .threads = 0};
    if (!ss->rgba || fk_ctx_new(&cfg, &ss->ctx) != F4D_OK) {
        f4d_simscene_free(ss);
        return f4d_fail(err, F4D_ENOMEM, "sim scene: cannot create the compute context");
    }
    if (scene_new((enum scene_preset)p, seed, 0, &ss->sc, &se) < 0 ||
        splat_renderer_new(ss->ctx, (int)width, (int)height, &ss->r, &se) < 0) {
        f4d_simscene_free(ss);
        return f4d_fail(err, F4D_EINVAL, "sim scene %s: %s", preset, se.msg);
    }
    scene_default_rig(ss->sc, (int)views, (int)width, (int)height, &ss->rig);
    *out = ss;
    return F4D_OK;
}

int f4d_simscene_render(void *user, uint32_t cam, uint64_t t_ns, const struct hal_format *f,
                        uint8_t *dst)
{
    struct f4d_simscene *ss = user;
    if (cam >= (uint32_t)ss->rig.count || f->width != ss->width || f->height != ss->height)
        return F4D_EINVAL; /* the sim falls back to its pattern */
    double t = (double)t_ns * 1e-9;
    struct f4d_err se;
    if (!ss->have_t || t != ss->t_cached) { /* all views of one trigger share one evaluation */
        if (scene_eval(ss->sc, t, 0.0, &ss->f, &se) < 0)
            return F4D_EINVAL;
        ss->t_cached = t;
        ss->have_t = true;
    }
    struct splat_render_out o;
    memset(&o, 0, sizeof o);
    o.rgba8 = ss->rgba;
    if (splat_render(ss->r, &ss->rig.cams[cam], &ss->f, scene_background(), &o) < 0)
        return F4D_EIO;
    const uint32_t bpp = hal_pixfmt_bytes_per_pixel(f->pixfmt);
    for (uint32_t y = 0; y < f->height; y++) {
        uint8_t *row = dst + (size_t)y * f->stride;
        const uint8_t *c = ss->rgba + (size_t)y * f->width * 4;
        for (uint32_t x = 0; x < f->width; x++, c += 4) {
            if (bpp == 3)
                memcpy(row + 3 * x, c, 3);
            else
                row[x] = (uint8_t)((c[0] + 2u * c[1] + c[2]) / 4u);
        }
    }
    return 0;
}

void f4d_simscene_free(struct f4d_simscene *ss)
{
    if (!ss)
        return;
    splat_frame_free(&ss->f);
    if (ss->r)
        splat_renderer_free(ss->r);
    if (ss->sc)
        scene_free(ss->sc);
    if (ss->ctx)
        fk_ctx_free(ss->ctx);
    free(ss->rgba);
    free(ss);
}
