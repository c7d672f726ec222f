/* f4d_display.h - the display stage: container packets in, pictures out at the
 * display's own refresh rate. Library f4d_display; depends on
 * firmware/stream/codec (packets, decoder), firmware/stream/transport (SRT,
 * when built), firmware/gaussians/interp (the
 * maths between keys), firmware/gaussians/splat (the CPU rasterizer), EGL and
 * GLES 3 (Mesa), X11 for the window and, when built, libgbm + libdrm for KMS.
 *
 *     display_source *src;
 *     display_source_file("walk.f4ds", 0, &src, &err);      // or display_source_transport("srt://...")
 *     struct display_config cfg = display_config_default();
 *     cfg.output = DISPLAY_HEADLESS;  cfg.png_dir = "frames";  cfg.fps = 30;
 *     display *d;
 *     display_new(ctx, &cfg, &d, &err);
 *     while (display_step(d, src) == 1) {}                  // one refresh per call
 *     const struct display_stats *st = display_get_stats(d);
 *     display_free(d);  display_source_free(src);
 *
 * Per refresh (display_step): pull packets until a key at or after the
 * refresh's stream time is held (a live source that has nothing yet is not
 * waited for), decode them, then interpolate between the last two keys with
 * interp_at (Forge4D's dual-consistency maths, keys' pixel lookups built once
 * per key) at a = (t - t_prev) / (t_next - t_prev), clamped to [0, 1] (a late
 * key holds the picture at the newest key), draw and present. Stream time:
 * unpaced (headless default), refresh k shows t_first_key + k / fps, every
 * refresh as fast as the machine goes; paced (cfg.realtime, window and KMS
 * default), refreshes start every 1 / fps and show t_first_key + the wall
 * time since the first, so a slow machine skips ahead instead of falling
 * behind a live stream; a refresh that misses its slot is not made up
 * (slots_missed). The display shows the interval between the last two keys,
 * so its latency is up to one key interval plus the source's; a live source
 * (cfg.live_lag_keys >= 0) is read to its newest packet at every refresh and
 * the clock kept within live_lag_keys key intervals of the newest key
 * (display_player_clock): 0 shows each key once decoded and holds it.
 * An unpaced CPU display that is not live (cfg.serial 0, ctx of 2 threads or
 * more) does the next refresh's pull, decode and interpolation on its own
 * thread (and fk context) while this refresh is sorted, composited and
 * presented, from the same source (pulled again at that refresh, as a growing
 * source may have more): display_step returns only once that work is done,
 * so the source may be freed between calls; the pictures are the serial ones.
 *
 * Renderers (both present through EGL):
 *   DISPLAY_RENDER_GLES: GLES 3 instanced quads, the reference 3DGS shading
 *     (EWA in the vertex shader, Jacobian clamped to 1.3 tan(fov), +0.3 px²,
 *     3-sigma quads, alpha = min(0.99, o exp(power)) discarding < 1/255),
 *     sorted back to front on the CPU every refresh (radix on the depth bits),
 *     premultiplied blending into an RGBA16F target where the driver has one.
 *   DISPLAY_RENDER_CPU: firmware/splat's rasterizer; its image is quantised as
 *     PNG does (floor(v * 255 + 0.5)), uploaded as a texture and drawn with a
 *     fullscreen quad, so the presented pixels are exactly splat_render's.
 *   DISPLAY_RENDER_AUTO: times both on the first key (best of 2 after a warm
 *     up) and keeps the faster; on llvmpipe the CPU path wins (see README).
 * Outputs: DISPLAY_HEADLESS (EGL_MESA_platform_surfaceless, an offscreen
 * framebuffer), DISPLAY_X11 (a window; free camera: W/S/A/D/Q/E move,
 * arrows or dragging turn, R resets, Esc quits), DISPLAY_KMS (GBM surface,
 * DRM page flips on the first connected connector; needs a DRM master). Every
 * output can read back what it presents into PNG files (png_dir).
 *
 * Camera: cfg.camera (fixed, e.g. a rig camera scaled to the display size);
 * without one the first key's bounds place an orbit camera (world z up, as
 * the synthetic scenes). The interpolation's pixel lookup uses cfg.lookup_rig
 * (the capture rig, as interp expects) or, without one, the starting camera
 * scaled to 518 pixels on its longest side (the model's working size).
 *
 * Memory: everything is sized when the first key arrives from the stream
 * header's capacity (or, when joining after it, 5/4 of that key's count):
 * decoder, key slots, interp's pixel lists (warmed up once on a frame of the
 * capacity), the rasterizer and the GL instance buffers; after it a refresh
 * allocates nothing in this code (a larger key is refused and counted,
 * F4D_ERANGE; the GL driver's and libpng's own allocations are theirs).
 * Errors: 0 / negative F4D_E* with display_error().
 */
#ifndef F4D_DISPLAY_H
#define F4D_DISPLAY_H

#include <stddef.h>
#include <stdint.h>

#include "f4d_codec.h"
#include "f4d_status.h"
#include "fk_ctx.h"
#include "interp.h"
#include "splat.h"

#ifdef __cplusplus
extern "C" {
#endif

/* ---- packet sources ---------------------------------------------------------
 * A source hands out whole, CRC-checked packets; how bytes arrive (a file, a
 * buffer, SRT later) is its business. next(): 1 with *p filled (valid until
 * the next call), 0 when nothing is available yet (live sources), F4D_EEOF at
 * the end; corrupt or truncated bytes are skipped to the next packet and
 * counted, never returned. */
typedef struct display_source display_source;
struct display_source_stats {
    uint64_t packets;       /* packets handed out                              */
    uint64_t bytes;         /* bytes of those packets                          */
    uint64_t dropped;       /* damaged packets the source skipped              */
    uint64_t skipped_bytes; /* bytes passed over while resynchronising          */
    double   latency_ms;    /* transport latency; < 0 when the source has none */
};
struct display_source_ops {
    int  (*next)(void *impl, struct codec_packet *p, struct f4d_err *err);
    void (*stats)(const void *impl, struct display_source_stats *st);
    void (*free)(void *impl);
};
/* Wraps an implementation (for sources defined elsewhere, such as SRT). */
int  display_source_new (const struct display_source_ops *ops, void *impl, display_source **out,
                         struct f4d_err *err);
/* A stream file read through mmap, starting at byte `offset` (a join in the
 * middle: the source resynchronises to the next packet). */
int  display_source_file(const char *path, size_t offset, display_source **out, struct f4d_err *err);
/* Packets over firmware/stream/transport: "srt://HOST:PORT?mode=...&latency=
 * MS&passphrase=..." or "file:PATH" (f4d_transport.h has the URL syntax);
 * max_packet: the largest packet (0: the transport's default). Built when
 * the transport is (F4D_DISPLAY_TRANSPORT defined). next() waits up to 2 ms. */
int  display_source_transport(const char *url, size_t max_packet, display_source **out, struct f4d_err *err);
/* Packets in a caller-owned buffer that outlives the source. */
int  display_source_memory(const uint8_t *buf, size_t len, display_source **out, struct f4d_err *err);
int  display_source_next (display_source *s, struct codec_packet *p, struct f4d_err *err);
void display_source_get_stats(const display_source *s, struct display_source_stats *st);
void display_source_free (display_source *s);

/* ---- the player: decoder, key pair, interpolation (no drawing) ---------------- */
typedef struct display_player display_player;
struct display_player_stats {
    uint64_t keys;          /* keys decoded                                    */
    uint64_t lost, skipped, refused, too_large;  /* decoder and size refusals */
    uint64_t waited;        /* packets passed over before the first key        */
    double   decode_ms, lookup_ms, interp_ms;    /* totals                     */
    double   decode_cpu_ms, lookup_cpu_ms, interp_cpu_ms; /* the same as process
                                CPU time (all threads), blind to neighbours    */
    int      interp_mode;   /* enum interp_mode of the last frame              */
    uint64_t clock_raises;  /* display_player_clock: times the clock was raised */
    double   clock_raised_ms; /* stream time it skipped in total (ms)          */
    uint64_t held;          /* frames that showed the newest key as decoded
                               (live: the clock at or past it)                 */
    uint64_t keys_ahead;    /* keys decoded ahead (display_player_push_ahead)  */
    uint64_t lookups_ahead; /* pixel lookups built ahead (build_ahead)         */
};
/* ctx (borrowed) gives the threads; lookup_rig may be NULL (then the first
 * display_player_frame's camera is the lookup view); mode INTERP_FUSED etc.;
 * capacity 0 = from the stream. */
int  display_player_new(fk_ctx *ctx, const struct splat_rig *lookup_rig, enum interp_mode mode, size_t capacity,
                        display_player **out, struct f4d_err *err);
void display_player_free(display_player *p);
/* The pixel lookup behind the pair matches (INTERP_LOOKUP_RENDER, the default,
 * or INTERP_LOOKUP_ZBUFFER: no render, some matches differ; see interp.h);
 * before the first key. */
int  display_player_set_lookup(display_player *p, enum interp_lookup lookup, struct f4d_err *err);
const char *display_player_error(const display_player *p);
/* Feeds one packet. 1: a key was decoded; 0: none; < 0: fatal (memory). */
int  display_player_push(display_player *p, const struct codec_packet *pkt);
/* Keys held: 0, 1 or 2; times of the older and the newer. */
int  display_player_keys(const display_player *p, uint64_t *t_prev, uint64_t *t_next);
/* Reading ahead (a stream whose packets are there before their time): the
 * key after the pair is decoded, and its pixel lookup built, in refreshes
 * that take no new key, so a key's work is spread over its interval instead
 * of landing on the refresh that first shows it. push_ahead feeds one packet
 * like push, but the key it completes waits beside the pair (1; F4D_ESTATE
 * when one waits already); pending: 1 and its time when one waits; advance
 * makes it the newer key of the pair as push would have (1; 0: none waits;
 * push advances first by itself); build_ahead builds its pixel lookup when
 * the pair would need it (1: built; 0: nothing to do; < 0: error). */
int  display_player_push_ahead(display_player *p, const struct codec_packet *pkt);
int  display_player_pending(const display_player *p, uint64_t *t_us);
int  display_player_advance(display_player *p);
int  display_player_build_ahead(display_player *p);
/* Creates the interpolation's workspace (its lookup view is cam when the
 * player has no rig) and sizes it for the capacity once; needs one key.
 * display_player_frame calls it when needed; call it earlier to keep its
 * allocations out of the refreshes. */
int  display_player_prepare(display_player *p, const struct splat_camera *cam);
/* The Gaussians at stream time t_us (needs one key; two to interpolate). The
 * frame is owned by the player and valid until the next call. cam is the
 * lookup view when the player has no rig (the first call fixes it). */
int  display_player_frame(display_player *p, uint64_t t_us, const struct splat_camera *cam,
                          const struct splat_frame **out);
/* The live clock policy. t_us: the display's own clock (stream time of this
 * refresh); returns it raised so that it trails the newest key by at most
 * lag_keys key intervals (the interval between the two keys held), and keeps
 * the raise for later calls: the clock never goes back, and a display that
 * started late, or fell behind a live stream, catches up instead of showing
 * it a fixed delay late. lag_keys 0: each key is shown as soon as it is
 * decoded and held until the next (no wait for key k+1 to interpolate
 * towards); 1: the interval before the newest key is played as it arrives
 * (interpolation, one key interval of latency). From the first call on, a
 * frame at or past the newest key's time is that key as decoded (no pixel
 * lookup for a pair the clock is already past). */
uint64_t display_player_clock(display_player *p, uint64_t t_us, double lag_keys);
size_t display_player_capacity(const display_player *p);
const struct display_player_stats *display_player_get_stats(const display_player *p);

/* ---- the display ---------------------------------------------------------------- */
enum display_output   { DISPLAY_HEADLESS = 0, DISPLAY_X11 = 1, DISPLAY_KMS = 2 };
enum display_renderer { DISPLAY_RENDER_AUTO = 0, DISPLAY_RENDER_CPU = 1, DISPLAY_RENDER_GLES = 2 };

struct display_config {
    enum display_output   output;
    enum display_renderer renderer;
    int         width, height;      /* 960 x 540 (KMS: the mode's size)         */
    double      fps;                /* refresh rate, 30                          */
    int         realtime;           /* pace refreshes to fps (window default)    */
    int         status_line;        /* draw the on-screen status line            */
    const char *png_dir;            /* write frame_%06d.png of each refresh, or NULL */
    int         read_back;          /* keep each refresh for display_read_back   */
    int         serial;             /* 1: no ahead thread: each refresh decodes and
                                       interpolates, then draws (per-stage CPU times
                                       exact); 0: an unpaced CPU display prepares the
                                       next refresh beside this one's drawing */
    const struct splat_camera *camera;     /* NULL: orbit camera from the first key;
                                               scaled to the output's size      */
    const struct splat_rig    *lookup_rig; /* NULL: the starting camera         */
    double      live_lag_keys;      /* < 0 (default): the paced clock runs from the
                                       first key; >= 0: a live source, the clock kept
                                       within this many key intervals of the newest key
                                       (display_player_clock) and every packet read as
                                       it comes                                      */
    enum interp_mode interp;        /* INTERP_FUSED                              */
    enum interp_lookup lookup;      /* INTERP_LOOKUP_ZBUFFER (no depth render:
                                       2-3x cheaper per key, pictures within
                                       44-54 dB); RENDER: interp's reference   */
    size_t      capacity;           /* 0: from the stream                        */
    const char *kms_device;         /* "/dev/dri/card0"                          */
    float       bg[3];              /* background, black                         */
};
struct display_config display_config_default(void);

struct display_stats {
    uint64_t frames;                /* refreshes presented                        */
    double   seconds;               /* wall time of those refreshes               */
    double   render_ms, present_ms; /* totals: draw (+ upload), compose + present  */
    double   raster_ms;             /* of render_ms: splat_render (CPU path)       */
    uint64_t drawn, visible, pairs; /* totals over CPU refreshes: Gaussians drawn, past culling,
                                       Gaussian-tile overlaps (what the compositing costs) */
    double   raster_cpu_ms[4];      /* splat_render's preprocess, sort, binning,
                                       compositing: process CPU time (all threads) */
    double   upload_cpu_ms, present_cpu_ms; /* CPU image to the texture; compose +
                                       present (llvmpipe's threads included)      */
    double   bitrate_mbps;          /* received bits over the stream time seen    */
    double   latency_ms;            /* newest key time minus displayed time (+ source) */
    uint64_t slots_missed;          /* paced: refresh slots (1 / fps) no refresh was presented in
                                       (a slow refresh; not made up by back-to-back ones) */
    uint64_t redraws_skipped;       /* refreshes that re-presented the last picture drawn (CPU path:
                                       same key pair, stream time past the newest key, same camera) */
    uint64_t shown_us, key_us;      /* last refresh: its stream time, the newest key held
                                       (it shows key k in full once both are >= k's time) */
    enum display_renderer renderer; /* the one in use (AUTO resolved)             */
    double   auto_cpu_ms, auto_gles_ms; /* AUTO's measurement (0 when not run)    */
    char     gl_renderer[128];      /* GL_RENDERER                                */
    struct display_player_stats player;
    struct display_source_stats source;
};

typedef struct display display;

int  display_new(fk_ctx *ctx, const struct display_config *cfg, display **out, struct f4d_err *err);
void display_free(display *d);
const char *display_error(const display *d);
/* One refresh. 1: presented (or waiting for the first key: nothing drawn yet,
 * frames unchanged); 0: the source ended or the window was closed; < 0 error. */
int  display_step(display *d, display_source *src);
const struct display_stats *display_get_stats(const display *d);
/* The last presented picture read back as RGB8 [H * W * 3], top row first
 * (what png_dir writes); NULL unless png_dir or read_back is set. */
const uint8_t *display_read_back(display *d, int *width, int *height);
/* The camera in use (after the first key for the orbit camera). */
const struct splat_camera *display_camera(const display *d);

/* ---- a headless GLES 3 context --------------------------------------------------
 * The EGL set-up of DISPLAY_HEADLESS for other GL code in the process (f4d-bench's
 * llvmpipe peer): Mesa's surfaceless platform, a GLES 3 context with 8-bit RGB,
 * current on the calling thread, no surface (draw into a framebuffer object).
 *
 *     display_glctx *gc;
 *     if (display_glctx_headless(&gc, &err) == 0) { ...glDraw...; display_glctx_free(gc, 0); }
 *
 * display_glctx_free(gc, terminate) releases the context; with terminate it also
 * ends the process's one surfaceless EGL display (Mesa's driver is loaded
 * again, and rereads e.g. LP_NUM_THREADS, at the next open): only when no other
 * GL user (a headless display) is left. F4D_ENODEV / F4D_ENOTSUP without EGL. */
typedef struct display_glctx display_glctx;
int  display_glctx_headless(display_glctx **out, struct f4d_err *err);
void display_glctx_free(display_glctx *gc, int terminate);

#ifdef __cplusplus
}
#endif
#endif /* F4D_DISPLAY_H */
