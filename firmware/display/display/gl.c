/* gl.c - the presenter: an EGL output (surfaceless, X11 window, or GBM/KMS),
 * the GLES 3 splat renderer, the textured fullscreen quad that shows the CPU
 * rasterizer's image, the status overlay and read-back. */
#include <X11/Xlib.h>
#include <X11/Xutil.h>
#include <X11/keysym.h>

#include <EGL/egl.h>
#include <EGL/eglext.h>
#include <GLES3/gl3.h>

#ifdef F4D_DISPLAY_KMS
#include <gbm.h>
#include <poll.h>
#include <xf86drm.h>
#include <xf86drmMode.h>
#endif

#include <errno.h>
#include <fcntl.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "display_internal.h"

#ifndef EGL_PLATFORM_SURFACELESS_MESA
#define EGL_PLATFORM_SURFACELESS_MESA 0x31DD
#endif
#ifndef EGL_PLATFORM_X11_KHR
#define EGL_PLATFORM_X11_KHR 0x31D5
#endif
#ifndef EGL_PLATFORM_GBM_KHR
#define EGL_PLATFORM_GBM_KHR 0x31D7
#endif

#define INST_FLOATS 13 /* pos 3, covariance 6 (xx xy xz yy yz zz), rgb 3, opacity 1 */

struct display_gl {
    enum display_output out;
    int                 W, H;
    EGLDisplay          dpy;
    EGLContext          ctx;
    EGLSurface          surf;
    char                renderer[128];
    /* X11 */
    Display            *xdpy;
    Window              win;
    Atom                wm_delete;
    int                 drag, drag_x, drag_y;
#ifdef F4D_DISPLAY_KMS
    int                 drm_fd;
    struct gbm_device  *gbm;
    struct gbm_surface *gs;
    struct gbm_bo      *bo_shown;
    uint32_t            conn_id, crtc_id;
    drmModeModeInfo     mode;
    drmModeCrtc        *saved_crtc;
    int                 crtc_set;
#endif
    /* headless output framebuffer */
    GLuint out_fbo, out_rb;
    /* scene: splats are drawn into scene_tex; the CPU image is uploaded into cpu_tex */
    GLuint scene_fbo, scene_tex, cpu_tex, overlay_tex;
    GLuint cpu_fbo;  /* cpu_tex as a read framebuffer: copied to the output by a blit */
    int    overlay_h;
    GLuint splat_prog, blit_prog, vao_splat, vbo_inst, vao_blit;
    GLint  u_view, u_k, u_lim, u_size, u_tex, u_flip, u_rect;
    size_t cap;
    float *inst;
    uint32_t *key, *key_tmp;
    int32_t  *idx, *idx_tmp;
};

/* ---- shaders ----------------------------------------------------------------------- */

/* EWA as firmware/splat: camera point t, Jacobian with the tangent clamped to
 * the 1.3 tan(fov) limits, Sigma' = J W Sigma W^T J^T, +0.3 px² dilation,
 * radius ceil(3 sqrt(lambda_max)), pixel centres at i + 0.5. */
static const char *splat_vs =
    "#version 300 es\n"
    "layout(location=0) in vec3 a_pos;\n"
    "layout(location=1) in vec3 a_cov0;\n" /* xx xy xz */
    "layout(location=2) in vec3 a_cov1;\n" /* yy yz zz */
    "layout(location=3) in vec4 a_col;\n"  /* rgb, opacity */
    "uniform mat4 u_view;\n"
    "uniform vec4 u_k;\n"                  /* fx fy cx cy */
    "uniform vec4 u_lim;\n"                /* x+ x- y+ y- tangent limits */
    "uniform vec2 u_size;\n"
    "out vec2 v_d; flat out vec3 v_conic; flat out vec4 v_col;\n"
    "void main() {\n"
    "  vec2 corner = vec2(float(gl_VertexID & 1), float(gl_VertexID >> 1)) * 2.0 - 1.0;\n"
    "  vec4 t = u_view * vec4(a_pos, 1.0);\n"
    "  if (t.z <= 0.2) { gl_Position = vec4(2.0, 2.0, 2.0, 1.0); return; }\n"
    "  float tx = clamp(t.x / t.z, -u_lim.y, u_lim.x) * t.z;\n"
    "  float ty = clamp(t.y / t.z, -u_lim.w, u_lim.z) * t.z;\n"
    "  mat3 J = mat3(u_k.x / t.z, 0.0, 0.0,  0.0, u_k.y / t.z, 0.0,\n"
    "                -u_k.x * tx / (t.z * t.z), -u_k.y * ty / (t.z * t.z), 0.0);\n"
    "  mat3 W = mat3(u_view);\n"
    "  mat3 S = mat3(a_cov0.x, a_cov0.y, a_cov0.z,  a_cov0.y, a_cov1.x, a_cov1.y,  a_cov0.z, a_cov1.y, a_cov1.z);\n"
    "  mat3 T = J * W;\n"
    "  mat3 C = T * S * transpose(T);\n"
    "  float a = C[0][0] + 0.3, b = C[0][1], c = C[1][1] + 0.3;\n"
    "  float det = a * c - b * b;\n"
    "  if (!(det > 0.0)) { gl_Position = vec4(2.0, 2.0, 2.0, 1.0); return; }\n"
    "  float mid = 0.5 * (a + c);\n"
    "  float r = ceil(3.0 * sqrt(mid + sqrt(max(0.1, mid * mid - det))));\n"
    "  vec2 m = vec2(u_k.x * t.x / t.z + u_k.z, u_k.y * t.y / t.z + u_k.w);\n"
    "  vec2 p = m + corner * r;\n"
    "  v_d = corner * r;\n"
    "  v_conic = vec3(c, -b, a) / det;\n"
    "  v_col = vec4(max(a_col.rgb, vec3(0.0)), a_col.a);\n"
    "  gl_Position = vec4(p.x / u_size.x * 2.0 - 1.0, 1.0 - p.y / u_size.y * 2.0, 0.0, 1.0);\n"
    "}\n";

/* The reference alpha rule; premultiplied output for back-to-front blending. */
static const char *splat_fs =
    "#version 300 es\n"
    "precision highp float;\n"
    "in vec2 v_d; flat in vec3 v_conic; flat in vec4 v_col;\n"
    "out vec4 o;\n"
    "void main() {\n"
    "  vec2 d = -v_d;\n"
    "  float power = -0.5 * (v_conic.x * d.x * d.x + v_conic.z * d.y * d.y) - v_conic.y * d.x * d.y;\n"
    "  if (power > 0.0) discard;\n"
    "  float alpha = min(0.99, v_col.a * exp(power));\n"
    "  if (alpha < 1.0 / 255.0) discard;\n"
    "  o = vec4(v_col.rgb * alpha, alpha);\n"
    "}\n";

/* Fullscreen (or u_rect) quad sampling u_tex 1:1; u_flip for top-first images. */
static const char *blit_vs =
    "#version 300 es\n"
    "uniform vec4 u_rect;\n" /* x0 y0 x1 y1 in NDC */
    "uniform float u_flip;\n"
    "out vec2 v_uv;\n"
    "void main() {\n"
    "  vec2 c = vec2(float(gl_VertexID & 1), float(gl_VertexID >> 1));\n"
    "  v_uv = vec2(c.x, mix(c.y, 1.0 - c.y, u_flip));\n"
    "  gl_Position = vec4(mix(u_rect.xy, u_rect.zw, c), 0.0, 1.0);\n"
    "}\n";
static const char *blit_fs =
    "#version 300 es\n"
    "precision highp float;\n"
    "uniform sampler2D u_tex;\n"
    "in vec2 v_uv; out vec4 o;\n"
    "void main() { o = texture(u_tex, v_uv); }\n";

static int gl_fail(struct f4d_err *err, const char *what)
{
    return f4d_fail(err, F4D_EIO, "display: %s (EGL 0x%04x, GL 0x%04x)", what, (unsigned)eglGetError(),
                    (unsigned)glGetError());
}

static GLuint compile(GLenum type, const char *src, struct f4d_err *err)
{
    GLuint s = glCreateShader(type);
    glShaderSource(s, 1, &src, NULL);
    glCompileShader(s);
    GLint ok = 0;
    glGetShaderiv(s, GL_COMPILE_STATUS, &ok);
    if (!ok) {
        char log[512];
        glGetShaderInfoLog(s, sizeof log, NULL, log);
        f4d_fail(err, F4D_EIO, "display: shader does not compile: %s", log);
        glDeleteShader(s);
        return 0;
    }
    return s;
}

static GLuint program(const char *vs_src, const char *fs_src, struct f4d_err *err)
{
    GLuint vs = compile(GL_VERTEX_SHADER, vs_src, err);
    if (!vs)
        return 0;
    GLuint fs = compile(GL_FRAGMENT_SHADER, fs_src, err);
    if (!fs) {
        glDeleteShader(vs);
        return 0;
    }
    GLuint p = glCreateProgram();
    glAttachShader(p, vs);
    glAttachShader(p, fs);
    glLinkProgram(p);
    glDeleteShader(vs);
    glDeleteShader(fs);
    GLint ok = 0;
    glGetProgramiv(p, GL_LINK_STATUS, &ok);
    if (!ok) {
        char log[512];
        glGetProgramInfoLog(p, sizeof log, NULL, log);
        f4d_fail(err, F4D_EIO, "display: program does not link: %s", log);
        glDeleteProgram(p);
        return 0;
    }
    return p;
}

static GLuint texture(GLenum ifmt, int w, int h, GLenum fmt, GLenum type)
{
    GLuint t;
    glGenTextures(1, &t);
    glBindTexture(GL_TEXTURE_2D, t);
    glTexImage2D(GL_TEXTURE_2D, 0, (GLint)ifmt, w, h, 0, fmt, type, NULL);
    glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MIN_FILTER, GL_NEAREST);
    glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MAG_FILTER, GL_NEAREST);
    glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_WRAP_S, GL_CLAMP_TO_EDGE);
    glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_WRAP_T, GL_CLAMP_TO_EDGE);
    return t;
}

/* ---- EGL outputs --------------------------------------------------------------------- */

static int egl_setup(display_gl *g, EGLenum platform, void *native, EGLint surface_bit, EGLint visual,
                     struct f4d_err *err)
{
    PFNEGLGETPLATFORMDISPLAYEXTPROC get_dpy =
        (PFNEGLGETPLATFORMDISPLAYEXTPROC)eglGetProcAddress("eglGetPlatformDisplayEXT");
    if (!get_dpy)
        return f4d_fail(err, F4D_ENOTSUP, "display: EGL has no eglGetPlatformDisplayEXT");
    g->dpy = get_dpy(platform, native, NULL);
    EGLint maj, min;
    if (g->dpy == EGL_NO_DISPLAY || !eglInitialize(g->dpy, &maj, &min)) {
        g->dpy = EGL_NO_DISPLAY;
        return f4d_fail(err, F4D_ENODEV, "display: no EGL display for platform 0x%04x (Mesa's libegl-mesa0 missing?)",
                        (unsigned)platform);
    }
    if (!eglBindAPI(EGL_OPENGL_ES_API))
        return gl_fail(err, "eglBindAPI(GLES) failed");
    const EGLint cattr[] = { EGL_SURFACE_TYPE, surface_bit, EGL_RENDERABLE_TYPE, EGL_OPENGL_ES3_BIT,
                             EGL_RED_SIZE, 8, EGL_GREEN_SIZE, 8, EGL_BLUE_SIZE, 8, EGL_NONE };
    EGLConfig cfgs[64];
    EGLint n = 0;
    if (!eglChooseConfig(g->dpy, cattr, cfgs, 64, &n) || n < 1)
        return gl_fail(err, "no EGL config for GLES 3 with 8-bit RGB");
    EGLConfig cfg = cfgs[0];
    if (visual) { /* GBM: the config whose visual is the scanout format */
        int found = 0;
        for (EGLint i = 0; i < n && !found; i++) {
            EGLint v = 0;
            if (eglGetConfigAttrib(g->dpy, cfgs[i], EGL_NATIVE_VISUAL_ID, &v) && v == visual) {
                cfg = cfgs[i];
                found = 1;
            }
        }
        if (!found)
            return f4d_fail(err, F4D_ENOTSUP, "display: no EGL config matches the scanout format");
    }
    const EGLint xattr[] = { EGL_CONTEXT_MAJOR_VERSION, 3, EGL_NONE };
    g->ctx = eglCreateContext(g->dpy, cfg, EGL_NO_CONTEXT, xattr);
    if (g->ctx == EGL_NO_CONTEXT)
        return gl_fail(err, "cannot create a GLES 3 context");
    g->surf = EGL_NO_SURFACE;
    if (surface_bit == EGL_WINDOW_BIT) {
        PFNEGLCREATEPLATFORMWINDOWSURFACEEXTPROC mk =
            (PFNEGLCREATEPLATFORMWINDOWSURFACEEXTPROC)eglGetProcAddress("eglCreatePlatformWindowSurfaceEXT");
        if (!mk)
            return f4d_fail(err, F4D_ENOTSUP, "display: EGL has no eglCreatePlatformWindowSurfaceEXT");
        void *win = platform == EGL_PLATFORM_X11_KHR ? (void *)&g->win :
#ifdef F4D_DISPLAY_KMS
                                                     (void *)g->gs;
#else
                                                     NULL;
#endif
        g->surf = mk(g->dpy, cfg, win, NULL);
        if (g->surf == EGL_NO_SURFACE)
            return gl_fail(err, "cannot create the window surface");
    }
    if (!eglMakeCurrent(g->dpy, g->surf, g->surf, g->ctx))
        return gl_fail(err, "cannot make the GLES context current");
    return F4D_OK;
}

static int open_x11(display_gl *g, struct f4d_err *err)
{
    g->xdpy = XOpenDisplay(NULL);
    if (!g->xdpy) {
        const char *name = getenv("DISPLAY");
        return f4d_fail(err, F4D_ENODEV, "display: cannot open the X display '%s'", name ? name : "(DISPLAY unset)");
    }
    int scr = DefaultScreen(g->xdpy);
    XSetWindowAttributes wa = { 0 };
    wa.event_mask = KeyPressMask | ButtonPressMask | ButtonReleaseMask | PointerMotionMask | StructureNotifyMask |
                    ExposureMask;
    wa.background_pixel = BlackPixel(g->xdpy, scr);
    g->win = XCreateWindow(g->xdpy, RootWindow(g->xdpy, scr), 0, 0, (unsigned)g->W, (unsigned)g->H, 0,
                           CopyFromParent, InputOutput, CopyFromParent, CWEventMask | CWBackPixel, &wa);
    XSizeHints hints = { 0 }; /* fixed size: the renderers are planned for it */
    hints.flags = PMinSize | PMaxSize;
    hints.min_width = hints.max_width = g->W;
    hints.min_height = hints.max_height = g->H;
    XSetWMNormalHints(g->xdpy, g->win, &hints);
    XStoreName(g->xdpy, g->win, "f4d-display");
    g->wm_delete = XInternAtom(g->xdpy, "WM_DELETE_WINDOW", False);
    XSetWMProtocols(g->xdpy, g->win, &g->wm_delete, 1);
    XMapWindow(g->xdpy, g->win);
    XFlush(g->xdpy);
    return egl_setup(g, EGL_PLATFORM_X11_KHR, g->xdpy, EGL_WINDOW_BIT, 0, err);
}

#ifdef F4D_DISPLAY_KMS
/* First connected connector, its preferred mode and a CRTC that can drive it. */
static int open_kms(display_gl *g, const char *dev, struct f4d_err *err)
{
    g->drm_fd = open(dev, O_RDWR | O_CLOEXEC);
    if (g->drm_fd < 0)
        return f4d_fail(err, F4D_ENODEV, "display: cannot open the DRM device '%s': %s", dev, strerror(errno));
    drmModeRes *res = drmModeGetResources(g->drm_fd);
    if (!res)
        return f4d_fail(err, F4D_ENODEV, "display: '%s' is not a KMS device (drmModeGetResources failed)", dev);
    drmModeConnector *conn = NULL;
    for (int i = 0; i < res->count_connectors && !conn; i++) {
        drmModeConnector *c = drmModeGetConnector(g->drm_fd, res->connectors[i]);
        if (c && c->connection == DRM_MODE_CONNECTED && c->count_modes > 0)
            conn = c;
        else
            drmModeFreeConnector(c);
    }
    if (!conn) {
        drmModeFreeResources(res);
        return f4d_fail(err, F4D_ENODEV, "display: '%s' has no connected screen", dev);
    }
    g->conn_id = conn->connector_id;
    g->mode = conn->modes[0];
    for (int i = 0; i < conn->count_modes; i++)
        if (conn->modes[i].type & DRM_MODE_TYPE_PREFERRED) {
            g->mode = conn->modes[i];
            break;
        }
    g->crtc_id = 0;
    for (int e = 0; e < conn->count_encoders && !g->crtc_id; e++) {
        drmModeEncoder *enc = drmModeGetEncoder(g->drm_fd, conn->encoders[e]);
        if (!enc)
            continue;
        if (enc->crtc_id)
            g->crtc_id = enc->crtc_id;
        for (int c = 0; c < res->count_crtcs && !g->crtc_id; c++)
            if (enc->possible_crtcs & (1u << c))
                g->crtc_id = res->crtcs[c];
        drmModeFreeEncoder(enc);
    }
    drmModeFreeConnector(conn);
    drmModeFreeResources(res);
    if (!g->crtc_id)
        return f4d_fail(err, F4D_ENODEV, "display: '%s': no CRTC for the connected screen", dev);
    g->saved_crtc = drmModeGetCrtc(g->drm_fd, g->crtc_id);
    g->W = g->mode.hdisplay;
    g->H = g->mode.vdisplay;
    g->gbm = gbm_create_device(g->drm_fd);
    if (!g->gbm)
        return f4d_fail(err, F4D_ENODEV, "display: gbm_create_device failed on '%s'", dev);
    g->gs = gbm_surface_create(g->gbm, (uint32_t)g->W, (uint32_t)g->H, GBM_FORMAT_XRGB8888,
                               GBM_BO_USE_SCANOUT | GBM_BO_USE_RENDERING);
    if (!g->gs)
        return f4d_fail(err, F4D_ENODEV, "display: cannot create a %dx%d GBM scanout surface", g->W, g->H);
    return egl_setup(g, EGL_PLATFORM_GBM_KHR, g->gbm, EGL_WINDOW_BIT, GBM_FORMAT_XRGB8888, err);
}

static void fb_destroy(struct gbm_bo *bo, void *data)
{
    uint32_t fb = (uint32_t)(uintptr_t)data;
    int fd = gbm_device_get_fd(gbm_bo_get_device(bo));
    if (fb)
        drmModeRmFB(fd, fb);
}

/* The DRM framebuffer of a GBM buffer, made once per buffer (GBM recycles them). */
static uint32_t fb_of(display_gl *g, struct gbm_bo *bo)
{
    void *data = gbm_bo_get_user_data(bo);
    if (data)
        return (uint32_t)(uintptr_t)data;
    uint32_t fb = 0;
    if (drmModeAddFB(g->drm_fd, gbm_bo_get_width(bo), gbm_bo_get_height(bo), 24, 32, gbm_bo_get_stride(bo),
                     gbm_bo_get_handle(bo).u32, &fb) != 0)
        return 0;
    gbm_bo_set_user_data(bo, (void *)(uintptr_t)fb, fb_destroy);
    return fb;
}

static void flip_done(int fd, unsigned int frame, unsigned int sec, unsigned int usec, void *data)
{
    (void)fd; (void)frame; (void)sec; (void)usec;
    *(int *)data = 0;
}

static int present_kms(display_gl *g, struct f4d_err *err)
{
    if (!eglSwapBuffers(g->dpy, g->surf))
        return gl_fail(err, "eglSwapBuffers failed");
    struct gbm_bo *bo = gbm_surface_lock_front_buffer(g->gs);
    if (!bo)
        return f4d_fail(err, F4D_EIO, "display: GBM has no front buffer");
    uint32_t fb = fb_of(g, bo);
    if (!fb)
        return f4d_fail(err, F4D_EIO, "display: drmModeAddFB failed: %s", strerror(errno));
    if (!g->crtc_set) {
        if (drmModeSetCrtc(g->drm_fd, g->crtc_id, fb, 0, 0, &g->conn_id, 1, &g->mode) != 0)
            return f4d_fail(err, F4D_EIO, "display: drmModeSetCrtc failed (not DRM master?): %s", strerror(errno));
        g->crtc_set = 1;
    } else {
        int waiting = 1;
        if (drmModePageFlip(g->drm_fd, g->crtc_id, fb, DRM_MODE_PAGE_FLIP_EVENT, &waiting) != 0)
            return f4d_fail(err, F4D_EIO, "display: drmModePageFlip failed: %s", strerror(errno));
        drmEventContext ev = { .version = 2, .page_flip_handler = flip_done };
        while (waiting) {
            struct pollfd pfd = { .fd = g->drm_fd, .events = POLLIN };
            if (poll(&pfd, 1, 1000) <= 0)
                return f4d_fail(err, F4D_ETIMEDOUT, "display: no page flip event within 1 s");
            drmHandleEvent(g->drm_fd, &ev);
        }
    }
    if (g->bo_shown)
        gbm_surface_release_buffer(g->gs, g->bo_shown);
    g->bo_shown = bo;
    return F4D_OK;
}
#endif

/* ---- open / close -------------------------------------------------------------------- */

static int gl_objects(display_gl *g, struct f4d_err *err)
{
    g->splat_prog = program(splat_vs, splat_fs, err);
    if (!g->splat_prog)
        return F4D_EIO;
    g->blit_prog = program(blit_vs, blit_fs, err);
    if (!g->blit_prog)
        return F4D_EIO;
    g->u_view = glGetUniformLocation(g->splat_prog, "u_view");
    g->u_k = glGetUniformLocation(g->splat_prog, "u_k");
    g->u_lim = glGetUniformLocation(g->splat_prog, "u_lim");
    g->u_size = glGetUniformLocation(g->splat_prog, "u_size");
    g->u_tex = glGetUniformLocation(g->blit_prog, "u_tex");
    g->u_flip = glGetUniformLocation(g->blit_prog, "u_flip");
    g->u_rect = glGetUniformLocation(g->blit_prog, "u_rect");
    glGenVertexArrays(1, &g->vao_splat);
    glGenVertexArrays(1, &g->vao_blit);
    glGenBuffers(1, &g->vbo_inst);
    /* scene target: half floats where the driver renders to them (many layers of
     * blending would otherwise round at 8 bits each), else RGBA8 */
    const char *ext = (const char *)glGetString(GL_EXTENSIONS);
    int half = ext && (strstr(ext, "GL_EXT_color_buffer_half_float") || strstr(ext, "GL_EXT_color_buffer_float"));
    g->scene_tex = half ? texture(GL_RGBA16F, g->W, g->H, GL_RGBA, GL_HALF_FLOAT)
                        : texture(GL_RGBA8, g->W, g->H, GL_RGBA, GL_UNSIGNED_BYTE);
    glGenFramebuffers(1, &g->scene_fbo);
    glBindFramebuffer(GL_FRAMEBUFFER, g->scene_fbo);
    glFramebufferTexture2D(GL_FRAMEBUFFER, GL_COLOR_ATTACHMENT0, GL_TEXTURE_2D, g->scene_tex, 0);
    if (glCheckFramebufferStatus(GL_FRAMEBUFFER) != GL_FRAMEBUFFER_COMPLETE && half) {
        glDeleteTextures(1, &g->scene_tex);
        g->scene_tex = texture(GL_RGBA8, g->W, g->H, GL_RGBA, GL_UNSIGNED_BYTE);
        glFramebufferTexture2D(GL_FRAMEBUFFER, GL_COLOR_ATTACHMENT0, GL_TEXTURE_2D, g->scene_tex, 0);
    }
    if (glCheckFramebufferStatus(GL_FRAMEBUFFER) != GL_FRAMEBUFFER_COMPLETE)
        return gl_fail(err, "the scene framebuffer is incomplete");
    g->cpu_tex = texture(GL_RGBA8, g->W, g->H, GL_RGBA, GL_UNSIGNED_BYTE);
    glGenFramebuffers(1, &g->cpu_fbo);
    glBindFramebuffer(GL_FRAMEBUFFER, g->cpu_fbo);
    glFramebufferTexture2D(GL_FRAMEBUFFER, GL_COLOR_ATTACHMENT0, GL_TEXTURE_2D, g->cpu_tex, 0);
    if (glCheckFramebufferStatus(GL_FRAMEBUFFER) != GL_FRAMEBUFFER_COMPLETE)
        return gl_fail(err, "the CPU image's framebuffer is incomplete");
    g->overlay_tex = 0;
    if (g->out == DISPLAY_HEADLESS) {
        glGenFramebuffers(1, &g->out_fbo);
        glGenRenderbuffers(1, &g->out_rb);
        glBindRenderbuffer(GL_RENDERBUFFER, g->out_rb);
        glRenderbufferStorage(GL_RENDERBUFFER, GL_RGBA8, g->W, g->H);
        glBindFramebuffer(GL_FRAMEBUFFER, g->out_fbo);
        glFramebufferRenderbuffer(GL_FRAMEBUFFER, GL_COLOR_ATTACHMENT0, GL_RENDERBUFFER, g->out_rb);
        if (glCheckFramebufferStatus(GL_FRAMEBUFFER) != GL_FRAMEBUFFER_COMPLETE)
            return gl_fail(err, "the output framebuffer is incomplete");
    }
    glBindFramebuffer(GL_FRAMEBUFFER, 0);
    const char *r = (const char *)glGetString(GL_RENDERER);
    snprintf(g->renderer, sizeof g->renderer, "%s", r ? r : "?");
    return glGetError() == GL_NO_ERROR ? F4D_OK : gl_fail(err, "GL objects could not be made");
}

int display__gl_open(enum display_output out, int width, int height, const char *kms_device, display_gl **gp,
                     struct f4d_err *err)
{
    display_gl *g = calloc(1, sizeof *g);
    if (!g)
        return f4d_fail(err, F4D_ENOMEM, "display: out of memory");
    g->out = out;
    g->W = width;
    g->H = height;
    g->dpy = EGL_NO_DISPLAY;
    g->ctx = EGL_NO_CONTEXT;
    g->surf = EGL_NO_SURFACE;
#ifdef F4D_DISPLAY_KMS
    g->drm_fd = -1;
#endif
    int rc;
    switch (out) {
    case DISPLAY_HEADLESS:
        rc = egl_setup(g, EGL_PLATFORM_SURFACELESS_MESA, EGL_DEFAULT_DISPLAY, EGL_PBUFFER_BIT, 0, err);
        break;
    case DISPLAY_X11:
        rc = open_x11(g, err);
        break;
    case DISPLAY_KMS:
#ifdef F4D_DISPLAY_KMS
        rc = open_kms(g, kms_device ? kms_device : "/dev/dri/card0", err);
#else
        (void)kms_device;
        rc = f4d_fail(err, F4D_ENOTSUP, "display: built without KMS (libgbm-dev, libdrm-dev)");
#endif
        break;
    default:
        rc = f4d_fail(err, F4D_EINVAL, "display: unknown output %d", (int)out);
    }
    if (rc == 0)
        rc = gl_objects(g, err);
    if (rc < 0) {
        display__gl_close(g);
        return rc;
    }
    if (g->surf != EGL_NO_SURFACE)
        eglSwapInterval(g->dpy, 0); /* the display paces itself (realtime) */
    *gp = g;
    return F4D_OK;
}

void display__gl_close(display_gl *g)
{
    if (!g)
        return;
    if (g->dpy != EGL_NO_DISPLAY) {
        if (g->ctx != EGL_NO_CONTEXT) {
            eglMakeCurrent(g->dpy, g->surf, g->surf, g->ctx);
            GLuint tex[3] = { g->scene_tex, g->cpu_tex, g->overlay_tex };
            glDeleteTextures(3, tex);
            glDeleteFramebuffers(1, &g->scene_fbo);
            glDeleteFramebuffers(1, &g->cpu_fbo);
            glDeleteFramebuffers(1, &g->out_fbo);
            glDeleteRenderbuffers(1, &g->out_rb);
            glDeleteBuffers(1, &g->vbo_inst);
            glDeleteVertexArrays(1, &g->vao_splat);
            glDeleteVertexArrays(1, &g->vao_blit);
            glDeleteProgram(g->splat_prog);
            glDeleteProgram(g->blit_prog);
            eglMakeCurrent(g->dpy, EGL_NO_SURFACE, EGL_NO_SURFACE, EGL_NO_CONTEXT);
            eglDestroyContext(g->dpy, g->ctx);
        }
        if (g->surf != EGL_NO_SURFACE)
            eglDestroySurface(g->dpy, g->surf);
        /* The surfaceless display is one per process (eglGetPlatformDisplay
         * hands the same one to every caller): terminating it would unload
         * Mesa's driver under any other user of it, and Mesa's llvmpipe keeps
         * blocks that only its unloaded code referenced (LeakSanitizer then
         * reports them against an unknown module). It stays initialised until
         * exit, as EGL allows; window and KMS displays are ours to end. */
        if (g->out != DISPLAY_HEADLESS)
            eglTerminate(g->dpy);
    }
#ifdef F4D_DISPLAY_KMS
    if (g->saved_crtc) { /* give the console its picture back */
        drmModeSetCrtc(g->drm_fd, g->saved_crtc->crtc_id, g->saved_crtc->buffer_id, g->saved_crtc->x,
                       g->saved_crtc->y, &g->conn_id, 1, &g->saved_crtc->mode);
        drmModeFreeCrtc(g->saved_crtc);
    }
    if (g->bo_shown)
        gbm_surface_release_buffer(g->gs, g->bo_shown);
    if (g->gs)
        gbm_surface_destroy(g->gs);
    if (g->gbm)
        gbm_device_destroy(g->gbm);
    if (g->drm_fd >= 0)
        close(g->drm_fd);
#endif
    if (g->xdpy) {
        if (g->win)
            XDestroyWindow(g->xdpy, g->win);
        XCloseDisplay(g->xdpy);
    }
    free(g->inst);
    free(g->key);
    free(g->key_tmp);
    free(g->idx);
    free(g->idx_tmp);
    free(g);
}

/* ---- a headless context for other GL code (f4d_display.h) ---------------------- */

struct display_glctx {
    display_gl g; /* only its EGL part is used: egl_setup is the one set-up */
};

int display_glctx_headless(display_glctx **out, struct f4d_err *err)
{
    display_glctx *gc = calloc(1, sizeof *gc);
    if (!gc)
        return f4d_fail(err, F4D_ENOMEM, "display: out of memory");
    gc->g.out = DISPLAY_HEADLESS;
    gc->g.dpy = EGL_NO_DISPLAY;
    gc->g.ctx = EGL_NO_CONTEXT;
    gc->g.surf = EGL_NO_SURFACE;
#ifdef F4D_DISPLAY_KMS
    gc->g.drm_fd = -1;
#endif
    int rc = egl_setup(&gc->g, EGL_PLATFORM_SURFACELESS_MESA, EGL_DEFAULT_DISPLAY, EGL_PBUFFER_BIT, 0, err);
    if (rc < 0) {
        display_glctx_free(gc, 0);
        return rc;
    }
    *out = gc;
    return F4D_OK;
}

void display_glctx_free(display_glctx *gc, int terminate)
{
    if (!gc)
        return;
    if (gc->g.dpy != EGL_NO_DISPLAY) {
        eglMakeCurrent(gc->g.dpy, EGL_NO_SURFACE, EGL_NO_SURFACE, EGL_NO_CONTEXT);
        if (gc->g.ctx != EGL_NO_CONTEXT)
            eglDestroyContext(gc->g.dpy, gc->g.ctx);
        if (terminate) /* see display__gl_close: the caller says no other user is left */
            eglTerminate(gc->g.dpy);
    }
    free(gc);
}

void display__gl_size(const display_gl *g, int *width, int *height)
{
    *width = g->W;
    *height = g->H;
}

const char *display__gl_renderer(const display_gl *g) { return g->renderer; }

int display__gl_plan(display_gl *g, size_t n, struct f4d_err *err)
{
    if (n <= g->cap)
        return F4D_OK;
    free(g->inst); free(g->key); free(g->key_tmp); free(g->idx); free(g->idx_tmp);
    g->inst = malloc(n * INST_FLOATS * sizeof(float));
    g->key = malloc(n * sizeof *g->key);
    g->key_tmp = malloc(n * sizeof *g->key_tmp);
    g->idx = malloc(n * sizeof *g->idx);
    g->idx_tmp = malloc(n * sizeof *g->idx_tmp);
    if (!g->inst || !g->key || !g->key_tmp || !g->idx || !g->idx_tmp) {
        g->cap = 0;
        return f4d_fail(err, F4D_ENOMEM, "display: out of memory for %zu instances", n);
    }
    g->cap = n;
    glBindVertexArray(g->vao_splat);
    glBindBuffer(GL_ARRAY_BUFFER, g->vbo_inst);
    glBufferData(GL_ARRAY_BUFFER, (GLsizeiptr)(n * INST_FLOATS * sizeof(float)), NULL, GL_STREAM_DRAW);
    const GLsizei stride = INST_FLOATS * sizeof(float);
    const int comps[4] = { 3, 3, 3, 4 };
    size_t off = 0;
    for (GLuint a = 0; a < 4; a++) {
        glEnableVertexAttribArray(a);
        glVertexAttribPointer(a, comps[a], GL_FLOAT, GL_FALSE, stride, (const void *)(off * sizeof(float)));
        glVertexAttribDivisor(a, 1);
        off += (size_t)comps[a];
    }
    glBindVertexArray(0);
    return glGetError() == GL_NO_ERROR ? F4D_OK : gl_fail(err, "cannot size the instance buffer");
}

/* ---- splats ------------------------------------------------------------------------------ */

/* Back to front: ascending complement of the (non-negative) depth bits, stable,
 * so equal depths keep index order. */
static void sort_back_to_front(display_gl *g, size_t n)
{
    uint32_t *ks = g->key, *kd = g->key_tmp;
    int32_t *vs = g->idx, *vd = g->idx_tmp;
    for (int shift = 0; shift < 32; shift += 8) {
        size_t count[257] = { 0 };
        for (size_t i = 0; i < n; i++)
            count[((ks[i] >> shift) & 255) + 1]++;
        if (count[1] == n && shift > 0) /* every key has this byte 0: nothing moves */
            continue;
        for (int b = 0; b < 256; b++)
            count[b + 1] += count[b];
        for (size_t i = 0; i < n; i++) {
            size_t d = count[(ks[i] >> shift) & 255]++;
            kd[d] = ks[i];
            vd[d] = vs[i];
        }
        uint32_t *kt = ks; ks = kd; kd = kt;
        int32_t *vt = vs; vs = vd; vd = vt;
    }
    if (ks != g->key) { /* an odd number of passes ran: results live in the scratch */
        memcpy(g->key, ks, n * sizeof *ks);
        memcpy(g->idx, vs, n * sizeof *vs);
    }
}

/* Sigma = R diag(s²) R^T from the normalised quaternion (w, x, y, z). */
static void covariance(const float *q, const float *s, float *c)
{
    float w = q[0], x = q[1], y = q[2], z = q[3];
    float n = sqrtf(w * w + x * x + y * y + z * z);
    if (n > 0.0f) {
        w /= n; x /= n; y /= n; z /= n;
    } else {
        w = 1.0f;
    }
    float R[9] = { 1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
                   2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
                   2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y) };
    float M[9];
    for (int a = 0; a < 3; a++)
        for (int b = 0; b < 3; b++)
            M[3 * a + b] = R[3 * a + b] * s[b];
    c[0] = M[0] * M[0] + M[1] * M[1] + M[2] * M[2];
    c[1] = M[0] * M[3] + M[1] * M[4] + M[2] * M[5];
    c[2] = M[0] * M[6] + M[1] * M[7] + M[2] * M[8];
    c[3] = M[3] * M[3] + M[4] * M[4] + M[5] * M[5];
    c[4] = M[3] * M[6] + M[4] * M[7] + M[5] * M[8];
    c[5] = M[6] * M[6] + M[7] * M[7] + M[8] * M[8];
}

int display__gl_draw_splats(display_gl *g, const struct splat_camera *cam, const struct splat_frame *f,
                            const float bg[3], struct f4d_err *err)
{
    if (f->count > g->cap)
        return f4d_fail(err, F4D_ERANGE, "display: %zu Gaussians exceed the planned %zu", f->count, g->cap);
    const float *V = cam->w2c;
    size_t m = 0;
    for (size_t i = 0; i < f->count; i++) { /* the near cull on the CPU: fewer instances */
        const float *p = f->pos + 3 * i;
        float z = V[8] * p[0] + V[9] * p[1] + V[10] * p[2] + V[11];
        if (!(z > SPLAT_NEAR) || !(f->opacity[i] >= SPLAT_ALPHA_MIN))
            continue;
        uint32_t b;
        memcpy(&b, &z, sizeof b);
        g->key[m] = ~b;
        g->idx[m] = (int32_t)i;
        m++;
    }
    sort_back_to_front(g, m);
    for (size_t k = 0; k < m; k++) {
        size_t i = (size_t)g->idx[k];
        float *d = g->inst + INST_FLOATS * k;
        memcpy(d, f->pos + 3 * i, 3 * sizeof(float));
        covariance(f->rot + 4 * i, f->scale + 3 * i, d + 3);
        memcpy(d + 9, f->rgb + 3 * i, 3 * sizeof(float));
        d[12] = f->opacity[i];
    }
    glBindFramebuffer(GL_FRAMEBUFFER, g->scene_fbo);
    glViewport(0, 0, g->W, g->H);
    /* premultiplied "over" from the back: the background is the first layer */
    glClearColor(bg[0], bg[1], bg[2], 1.0f);
    glClear(GL_COLOR_BUFFER_BIT);
    glEnable(GL_BLEND);
    glBlendFunc(GL_ONE, GL_ONE_MINUS_SRC_ALPHA);
    glUseProgram(g->splat_prog);
    float view[16]; /* column-major for GL */
    for (int r = 0; r < 4; r++)
        for (int c = 0; c < 4; c++)
            view[4 * c + r] = V[4 * r + c];
    glUniformMatrix4fv(g->u_view, 1, GL_FALSE, view);
    glUniform4f(g->u_k, cam->fx, cam->fy, cam->cx, cam->cy);
    float tanx = 0.5f * (float)g->W / cam->fx, tany = 0.5f * (float)g->H / cam->fy;
    glUniform4f(g->u_lim, ((float)g->W - cam->cx) / cam->fx + 0.3f * tanx, cam->cx / cam->fx + 0.3f * tanx,
                ((float)g->H - cam->cy) / cam->fy + 0.3f * tany, cam->cy / cam->fy + 0.3f * tany);
    glUniform2f(g->u_size, (float)g->W, (float)g->H);
    glBindVertexArray(g->vao_splat);
    glBindBuffer(GL_ARRAY_BUFFER, g->vbo_inst);
    if (m > 0) {
        glBufferSubData(GL_ARRAY_BUFFER, 0, (GLsizeiptr)(m * INST_FLOATS * sizeof(float)), g->inst);
        glDrawArraysInstanced(GL_TRIANGLE_STRIP, 0, 4, (GLsizei)m);
    }
    glBindVertexArray(0);
    glDisable(GL_BLEND);
    return glGetError() == GL_NO_ERROR ? F4D_OK : gl_fail(err, "drawing the splats failed");
}

int display__gl_upload(display_gl *g, const uint8_t *rgba, struct f4d_err *err)
{
    glBindTexture(GL_TEXTURE_2D, g->cpu_tex);
    glPixelStorei(GL_UNPACK_ALIGNMENT, 4);
    glTexSubImage2D(GL_TEXTURE_2D, 0, 0, 0, g->W, g->H, GL_RGBA, GL_UNSIGNED_BYTE, rgba);
    return glGetError() == GL_NO_ERROR ? F4D_OK : gl_fail(err, "uploading the image failed");
}

static void blit(display_gl *g, GLuint tex, float flip, float x0, float y0, float x1, float y1)
{
    glUseProgram(g->blit_prog);
    glActiveTexture(GL_TEXTURE0);
    glBindTexture(GL_TEXTURE_2D, tex);
    glUniform1i(g->u_tex, 0);
    glUniform1f(g->u_flip, flip);
    glUniform4f(g->u_rect, x0, y0, x1, y1);
    glBindVertexArray(g->vao_blit);
    glDrawArrays(GL_TRIANGLE_STRIP, 0, 4);
    glBindVertexArray(0);
}

int display__gl_compose(display_gl *g, int from_upload, const uint8_t *overlay, int overlay_h, struct f4d_err *err)
{
    const GLuint out = g->out == DISPLAY_HEADLESS ? g->out_fbo : 0;
    glBindFramebuffer(GL_FRAMEBUFFER, out);
    glViewport(0, 0, g->W, g->H);
    glDisable(GL_BLEND);
    if (from_upload) {
        /* the uploaded image is in GL's row order already: a same-size,
         * unflipped blit, which Mesa turns into a copy where the formats
         * match (llvmpipe: instead of shading a full-screen quad, 6 of the
         * 8 ms of CPU a 1280x720 refresh spent here) */
        glBindFramebuffer(GL_READ_FRAMEBUFFER, g->cpu_fbo);
        glBlitFramebuffer(0, 0, g->W, g->H, 0, 0, g->W, g->H, GL_COLOR_BUFFER_BIT, GL_NEAREST);
        glBindFramebuffer(GL_FRAMEBUFFER, out);
    } else {
        blit(g, g->scene_tex, 0.0f, -1.0f, -1.0f, 1.0f, 1.0f);
    }
    if (overlay && overlay_h > 0) {
        if (!g->overlay_tex || g->overlay_h != overlay_h) {
            if (g->overlay_tex)
                glDeleteTextures(1, &g->overlay_tex);
            g->overlay_tex = texture(GL_RGBA8, g->W, overlay_h, GL_RGBA, GL_UNSIGNED_BYTE);
            g->overlay_h = overlay_h;
        }
        glBindTexture(GL_TEXTURE_2D, g->overlay_tex);
        glPixelStorei(GL_UNPACK_ALIGNMENT, 4);
        glTexSubImage2D(GL_TEXTURE_2D, 0, 0, 0, g->W, overlay_h, GL_RGBA, GL_UNSIGNED_BYTE, overlay);
        glEnable(GL_BLEND);
        glBlendFunc(GL_ONE, GL_ONE_MINUS_SRC_ALPHA);
        float y0 = 1.0f - 2.0f * (float)overlay_h / (float)g->H;
        blit(g, g->overlay_tex, 1.0f, -1.0f, y0, 1.0f, 1.0f);
        glDisable(GL_BLEND);
    }
    return glGetError() == GL_NO_ERROR ? F4D_OK : gl_fail(err, "composing the picture failed");
}

int display__gl_read(display_gl *g, uint8_t *rgb, uint8_t *rgba, struct f4d_err *err)
{
    glBindFramebuffer(GL_FRAMEBUFFER, g->out == DISPLAY_HEADLESS ? g->out_fbo : 0);
    glPixelStorei(GL_PACK_ALIGNMENT, 4);
    glReadPixels(0, 0, g->W, g->H, GL_RGBA, GL_UNSIGNED_BYTE, rgba);
    if (glGetError() != GL_NO_ERROR)
        return gl_fail(err, "glReadPixels failed");
    for (int y = 0; y < g->H; y++) {
        const uint8_t *s = rgba + 4 * (size_t)(g->H - 1 - y) * (size_t)g->W;
        uint8_t *d = rgb + 3 * (size_t)y * (size_t)g->W;
        for (int x = 0; x < g->W; x++) {
            d[3 * x] = s[4 * x];
            d[3 * x + 1] = s[4 * x + 1];
            d[3 * x + 2] = s[4 * x + 2];
        }
    }
    return F4D_OK;
}

void display__gl_finish(display_gl *g)
{
    (void)g;
    glFinish();
}

int display__gl_present(display_gl *g, struct f4d_err *err)
{
    switch (g->out) {
    case DISPLAY_X11:
        if (!eglSwapBuffers(g->dpy, g->surf))
            return gl_fail(err, "eglSwapBuffers failed");
        return F4D_OK;
    case DISPLAY_KMS:
#ifdef F4D_DISPLAY_KMS
        return present_kms(g, err);
#else
        return f4d_fail(err, F4D_ENOTSUP, "display: built without KMS");
#endif
    default:
        glFlush();
        return F4D_OK;
    }
}

void display__gl_poll(display_gl *g, struct display_input *in)
{
    memset(in, 0, sizeof *in);
    if (g->out != DISPLAY_X11 || !g->xdpy)
        return;
    const float step = 0.05f, turn = 0.05f;
    while (XPending(g->xdpy)) {
        XEvent ev;
        XNextEvent(g->xdpy, &ev);
        switch (ev.type) {
        case ClientMessage:
            if ((Atom)ev.xclient.data.l[0] == g->wm_delete)
                in->quit = 1;
            break;
        case KeyPress: {
            KeySym k = XLookupKeysym(&ev.xkey, 0);
            switch (k) {
            case XK_Escape: in->quit = 1; break;
            case XK_w: in->move[2] += step; break;
            case XK_s: in->move[2] -= step; break;
            case XK_d: in->move[0] += step; break;
            case XK_a: in->move[0] -= step; break;
            case XK_e: in->move[1] += step; break;
            case XK_q: in->move[1] -= step; break;
            case XK_Left: in->turn[0] += turn; break;
            case XK_Right: in->turn[0] -= turn; break;
            case XK_Up: in->turn[1] += turn; break;
            case XK_Down: in->turn[1] -= turn; break;
            case XK_r: in->reset = 1; break;
            default: break;
            }
            break;
        }
        case ButtonPress:
            if (ev.xbutton.button == Button1) {
                g->drag = 1;
                g->drag_x = ev.xbutton.x;
                g->drag_y = ev.xbutton.y;
            } else if (ev.xbutton.button == Button4) {
                in->move[2] += step;
            } else if (ev.xbutton.button == Button5) {
                in->move[2] -= step;
            }
            break;
        case ButtonRelease:
            if (ev.xbutton.button == Button1)
                g->drag = 0;
            break;
        case MotionNotify:
            if (g->drag) {
                in->turn[0] -= 0.005f * (float)(ev.xmotion.x - g->drag_x);
                in->turn[1] -= 0.005f * (float)(ev.xmotion.y - g->drag_y);
                g->drag_x = ev.xmotion.x;
                g->drag_y = ev.xmotion.y;
            }
            break;
        default:
            break;
        }
    }
}
