/* bench_render.c - f4d-bench render: the CPU rasterizer's ms per frame for
 * 100k / 300k / 1M Gaussians at 518x518 and 1280x720 on 1 and 2 threads,
 * beside the same scene drawn by Mesa's software OpenGL (llvmpipe, headless
 * EGL surfaceless, GLES 3 instanced quads; hal.md §4) in the same run.
 *
 * Scene: the synthetic `walk` figure resampled to N Gaussians (t = 0.3 s),
 * seen by cam1 of the default rig at that image size.
 *
 * The peer does a web viewer's per-frame work: view depths and a radix sort
 * back to front on the CPU, upload of the sorted instances, a vertex shader
 * that projects each 3D covariance (EWA, +0.3 px², 3-sigma quad), a fragment
 * shader with the same alpha rule (min(0.99, o exp(power)), discard below
 * 1/255), premultiplied blending, then glReadPixels. Its llvmpipe runs with
 * LP_NUM_THREADS equal to the row's thread count. */
#include <GLES3/gl3.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "bench.h"
#include "scene.h"
#if F4D_BENCH_DISPLAY
#include "f4d_display.h" /* the display's headless EGL set-up */
#endif

/* ---- llvmpipe peer ------------------------------------------------------------ */

struct gl_peer {
#if F4D_BENCH_DISPLAY
    display_glctx *gc;
#endif
    GLuint     fbo, rb, prog, vao, vbo;
    int        W, H;
    size_t     cap;
    float     *inst;      /* sorted instance data, 14 floats each */
    uint32_t  *key, *key_tmp;
    int32_t   *idx, *idx_tmp;
    unsigned char *pixels;
};

static const char *vs_src =
    "#version 300 es\n"
    "layout(location=0) in vec3 a_pos;\n"
    "layout(location=1) in vec3 a_cov0;\n" /* xx xy xz */
    "layout(location=2) in vec3 a_cov1;\n" /* yy yz zz */
    "layout(location=3) in vec4 a_col;\n"  /* rgb, opacity */
    "layout(location=4) in vec2 a_pad;\n"
    "uniform mat4 u_view;\n"               /* world to camera, OpenCV axes */
    "uniform vec4 u_k;\n"                  /* fx fy cx cy */
    "uniform vec4 u_lim;\n"                /* x+ x- y+ y- tangent limits */
    "uniform vec2 u_size;\n"
    "out vec2 v_d; out vec3 v_conic; out vec4 v_col;\n"
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
    "  v_col = a_col;\n"
    "  gl_Position = vec4(p.x / u_size.x * 2.0 - 1.0, 1.0 - p.y / u_size.y * 2.0, 0.0, 1.0);\n"
    "}\n";

static const char *fs_src =
    "#version 300 es\n"
    "precision highp float;\n"
    "in vec2 v_d; in vec3 v_conic; in vec4 v_col;\n"
    "out vec4 o;\n"
    "void main() {\n"
    "  vec2 d = -v_d;\n"
    "  float power = -0.5 * (v_conic.x * d.x * d.x + v_conic.z * d.y * d.y) - v_conic.y * d.x * d.y;\n"
    "  if (power > 0.0) discard;\n"
    "  float alpha = min(0.99, v_col.a * exp(power));\n"
    "  if (alpha < 1.0 / 255.0) discard;\n"
    "  o = vec4(v_col.rgb * alpha, alpha);\n"
    "}\n";

static GLuint compile(GLenum type, const char *src)
{
    GLuint s = glCreateShader(type);
    glShaderSource(s, 1, &src, NULL);
    glCompileShader(s);
    GLint ok = 0;
    glGetShaderiv(s, GL_COMPILE_STATUS, &ok);
    if (!ok) {
        char log[1024];
        glGetShaderInfoLog(s, sizeof log, NULL, log);
        fprintf(stderr, "f4d-bench render: shader compile failed: %s\n", log);
        glDeleteShader(s);
        return 0;
    }
    return s;
}

static void gl_peer_close(struct gl_peer *g)
{
#if F4D_BENCH_DISPLAY
    if (g->gc) {
        glDeleteBuffers(1, &g->vbo);
        glDeleteVertexArrays(1, &g->vao);
        glDeleteProgram(g->prog);
        glDeleteRenderbuffers(1, &g->rb);
        glDeleteFramebuffers(1, &g->fbo);
        /* terminated: the next open loads llvmpipe again with its LP_NUM_THREADS */
        display_glctx_free(g->gc, 1);
    }
#endif
    free(g->inst); free(g->key); free(g->key_tmp); free(g->idx); free(g->idx_tmp); free(g->pixels);
    memset(g, 0, sizeof *g);
}

/* Opens a surfaceless llvmpipe context with `threads` raster threads. */
static int gl_peer_open(struct gl_peer *g, int threads)
{
    memset(g, 0, sizeof *g);
#if F4D_BENCH_DISPLAY
    char nt[16];
    snprintf(nt, sizeof nt, "%d", threads);
    setenv("LP_NUM_THREADS", nt, 1); /* read when the llvmpipe screen is created */
    setenv("GALLIUM_DRIVER", "llvmpipe", 0);
    struct f4d_err err = { 0 };
    if (display_glctx_headless(&g->gc, &err) < 0) {
        fprintf(stderr, "f4d-bench render: %s\n", err.msg);
        g->gc = NULL;
        return -1;
    }
#else
    (void)threads;
    fprintf(stderr, "f4d-bench render: built without the display (F4D_WITH_DISPLAY): no llvmpipe peer\n");
    return -1;
#endif
    GLuint vs = compile(GL_VERTEX_SHADER, vs_src), fs = compile(GL_FRAGMENT_SHADER, fs_src);
    if (!vs || !fs) {
        gl_peer_close(g);
        return -1;
    }
    g->prog = glCreateProgram();
    glAttachShader(g->prog, vs);
    glAttachShader(g->prog, fs);
    glLinkProgram(g->prog);
    glDeleteShader(vs);
    glDeleteShader(fs);
    GLint ok = 0;
    glGetProgramiv(g->prog, GL_LINK_STATUS, &ok);
    if (!ok) {
        fprintf(stderr, "f4d-bench render: shader link failed\n");
        gl_peer_close(g);
        return -1;
    }
    glGenVertexArrays(1, &g->vao);
    glGenBuffers(1, &g->vbo);
    glGenFramebuffers(1, &g->fbo);
    glGenRenderbuffers(1, &g->rb);
    return 0;
}

static int gl_peer_size(struct gl_peer *g, int W, int H, size_t n)
{
    if (W != g->W || H != g->H) {
        glBindRenderbuffer(GL_RENDERBUFFER, g->rb);
        glRenderbufferStorage(GL_RENDERBUFFER, GL_RGBA8, W, H);
        glBindFramebuffer(GL_FRAMEBUFFER, g->fbo);
        glFramebufferRenderbuffer(GL_FRAMEBUFFER, GL_COLOR_ATTACHMENT0, GL_RENDERBUFFER, g->rb);
        if (glCheckFramebufferStatus(GL_FRAMEBUFFER) != GL_FRAMEBUFFER_COMPLETE)
            return -1;
        free(g->pixels);
        g->pixels = malloc((size_t)W * (size_t)H * 4);
        if (!g->pixels)
            return -1;
        g->W = W;
        g->H = H;
    }
    if (n > g->cap) {
        free(g->inst); free(g->key); free(g->key_tmp); free(g->idx); free(g->idx_tmp);
        g->inst = malloc(n * 14 * sizeof(float));
        g->key = malloc(n * sizeof *g->key);
        g->key_tmp = malloc(n * sizeof *g->key_tmp);
        g->idx = malloc(n * sizeof *g->idx);
        g->idx_tmp = malloc(n * sizeof *g->idx_tmp);
        if (!g->inst || !g->key || !g->key_tmp || !g->idx || !g->idx_tmp)
            return -1;
        g->cap = n;
        glBindVertexArray(g->vao);
        glBindBuffer(GL_ARRAY_BUFFER, g->vbo);
        glBufferData(GL_ARRAY_BUFFER, (GLsizeiptr)(n * 14 * sizeof(float)), NULL, GL_STREAM_DRAW);
        const GLsizei st = 14 * sizeof(float);
        const int comps[5] = { 3, 3, 3, 4, 1 };
        size_t off = 0;
        for (GLuint a = 0; a < 5; a++) {
            glEnableVertexAttribArray(a);
            glVertexAttribPointer(a, comps[a], GL_FLOAT, GL_FALSE, st, (const void *)(off * sizeof(float)));
            glVertexAttribDivisor(a, 1);
            off += (size_t)comps[a];
        }
    }
    return 0;
}

/* Back to front: descending depth = ascending complement of the depth bits. */
static void sort_keys(struct gl_peer *g, size_t n)
{
    uint32_t *ks = g->key, *kd = g->key_tmp;
    int32_t *vs = g->idx, *vd = g->idx_tmp;
    for (int shift = 0; shift < 32; shift += 8) {
        size_t count[257] = { 0 };
        for (size_t i = 0; i < n; i++)
            count[((ks[i] >> shift) & 255) + 1]++;
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
}

/* One frame: sort, upload, draw, read back. Returns the RGBA8 pixels. */
static const unsigned char *gl_peer_render(struct gl_peer *g, const struct splat_camera *cam,
                                           const struct splat_frame *f, const float *cov6)
{
    size_t n = f->count;
    const float *V = cam->w2c;
    for (size_t i = 0; i < n; i++) {
        const float *p = f->pos + 3 * i;
        float z = V[8] * p[0] + V[9] * p[1] + V[10] * p[2] + V[11];
        uint32_t b;
        z = z > 0.0f ? z : 0.0f;
        memcpy(&b, &z, sizeof b);
        g->key[i] = ~b;
        g->idx[i] = (int32_t)i;
    }
    sort_keys(g, n);
    for (size_t k = 0; k < n; k++) {
        size_t i = (size_t)g->idx[k];
        float *d = g->inst + 14 * k;
        memcpy(d, f->pos + 3 * i, 3 * sizeof(float));
        memcpy(d + 3, cov6 + 6 * i, 6 * sizeof(float));
        memcpy(d + 9, f->rgb + 3 * i, 3 * sizeof(float));
        d[12] = f->opacity[i];
        d[13] = 0.0f;
    }
    glBindFramebuffer(GL_FRAMEBUFFER, g->fbo);
    glViewport(0, 0, g->W, g->H);
    glClearColor(0, 0, 0, 0);
    glClear(GL_COLOR_BUFFER_BIT);
    glEnable(GL_BLEND);
    glBlendFunc(GL_ONE, GL_ONE_MINUS_SRC_ALPHA);
    glUseProgram(g->prog);
    float view[16]; /* column-major for GL */
    for (int r = 0; r < 4; r++)
        for (int c = 0; c < 4; c++)
            view[4 * c + r] = V[4 * r + c];
    glUniformMatrix4fv(glGetUniformLocation(g->prog, "u_view"), 1, GL_FALSE, view);
    glUniform4f(glGetUniformLocation(g->prog, "u_k"), cam->fx, cam->fy, cam->cx, cam->cy);
    float tanx = 0.5f * (float)g->W / cam->fx, tany = 0.5f * (float)g->H / cam->fy;
    glUniform4f(glGetUniformLocation(g->prog, "u_lim"), ((float)g->W - cam->cx) / cam->fx + 0.3f * tanx,
                cam->cx / cam->fx + 0.3f * tanx, ((float)g->H - cam->cy) / cam->fy + 0.3f * tany,
                cam->cy / cam->fy + 0.3f * tany);
    glUniform2f(glGetUniformLocation(g->prog, "u_size"), (float)g->W, (float)g->H);
    glBindVertexArray(g->vao);
    glBindBuffer(GL_ARRAY_BUFFER, g->vbo);
    glBufferSubData(GL_ARRAY_BUFFER, 0, (GLsizeiptr)(n * 14 * sizeof(float)), g->inst);
    glDrawArraysInstanced(GL_TRIANGLE_STRIP, 0, 4, (GLsizei)n);
    glReadPixels(0, 0, g->W, g->H, GL_RGBA, GL_UNSIGNED_BYTE, g->pixels);
    return glGetError() == GL_NO_ERROR ? g->pixels : NULL;
}

/* 3D covariances (xx xy xz yy yz zz) of a frame, what a viewer keeps on the GPU. */
static void covariances(const struct splat_frame *f, float *cov6)
{
    for (size_t i = 0; i < f->count; i++) {
        const float *q = f->rot + 4 * i, *s = f->scale + 3 * i;
        float w = q[0], x = q[1], y = q[2], z = q[3];
        float n = sqrtf(w * w + x * x + y * y + z * z);
        w /= n; x /= n; y /= n; z /= n;
        float R[9] = { 1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
                       2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
                       2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y) };
        float M[9];
        for (int a = 0; a < 3; a++)
            for (int b = 0; b < 3; b++)
                M[3 * a + b] = R[3 * a + b] * s[b];
        float *c = cov6 + 6 * i;
        c[0] = M[0] * M[0] + M[1] * M[1] + M[2] * M[2];
        c[1] = M[0] * M[3] + M[1] * M[4] + M[2] * M[5];
        c[2] = M[0] * M[6] + M[1] * M[7] + M[2] * M[8];
        c[3] = M[3] * M[3] + M[4] * M[4] + M[5] * M[5];
        c[4] = M[3] * M[6] + M[4] * M[7] + M[5] * M[8];
        c[5] = M[6] * M[6] + M[7] * M[7] + M[8] * M[8];
    }
}

/* ---- the benchmark ------------------------------------------------------------ */

struct row {
    size_t n;
    int    W, H, threads;
    double ms, gl_ms, peer_psnr;
};

int bench_render(int argc, char **argv)
{
    const char *json = NULL;
    int runs = 5, quick = 0;
    for (int i = 1; i < argc; i++) {
        if (!strcmp(argv[i], "--json") && i + 1 < argc)
            json = argv[++i];
        else if (!strcmp(argv[i], "--runs") && i + 1 < argc)
            runs = atoi(argv[++i]);
        else if (!strcmp(argv[i], "--quick"))
            quick = 1;
        else {
            fprintf(stderr, "usage: f4d-bench render [--runs N] [--quick] [--json FILE]\n"
                            "  --quick: 100k and 300k at 518x518 only\n");
            return 2;
        }
    }
    if (runs < 1 || runs > 100) {
        fprintf(stderr, "f4d-bench render: --runs must be in 1..100\n");
        return 2;
    }
    const size_t counts[3] = { 100000, 300000, 1000000 };
    const int sizes[2][2] = { { 518, 518 }, { 1280, 720 } };
    struct row rows[12];
    int nrows = 0;
    struct splat_frame frames[3] = { { 0 } };
    float *covs[3] = { NULL, NULL, NULL };
    for (int c = 0; c < 3; c++) {
        if (quick && c == 2)
            continue;
        scene *s;
        struct f4d_err err;
        if (scene_new(SCENE_WALK, 1, counts[c], &s, &err) < 0 || scene_eval(s, 0.3, 0.0, &frames[c], &err) < 0) {
            fprintf(stderr, "f4d-bench render: %s\n", err.msg);
            return 1;
        }
        scene_free(s);
        covs[c] = malloc(6 * frames[c].count * sizeof(float));
        if (!covs[c])
            return 1;
        covariances(&frames[c], covs[c]);
    }
    float *rgb = malloc(3 * 1280 * 720 * sizeof(float));
    for (int threads = 1; threads <= 2; threads++) {
        fk_ctx *ctx;
        struct fk_ctx_config cfg = { .isa = FK_ISA_AUTO, .threads = threads };
        if (fk_ctx_new(&cfg, &ctx) != F4D_OK)
            return 1;
        struct gl_peer gl;
        int have_gl = gl_peer_open(&gl, threads) == 0;
        for (int z = 0; z < 2; z++) {
            if (quick && z == 1)
                continue;
            int W = sizes[z][0], H = sizes[z][1];
            splat_renderer *r;
            struct f4d_err err;
            if (splat_renderer_new(ctx, W, H, &r, &err) < 0)
                return 1;
            for (int c = 0; c < 3; c++) {
                if (!frames[c].count)
                    continue;
                scene *tmp;
                scene_new(SCENE_WALK, 1, 0, &tmp, NULL);
                struct splat_rig rig;
                scene_default_rig(tmp, 4, W, H, &rig);
                scene_free(tmp);
                const struct splat_camera *cam = &rig.cams[1];
                struct splat_render_out o = { .rgb = rgb };
                double best = 1e30, stages[4] = { 0 };
                for (int k = 0; k <= runs; k++) { /* the first run sizes the buffers */
                    double t0 = bench_now();
                    splat_render(r, cam, &frames[c], NULL, &o);
                    double dt = bench_now() - t0;
                    if (k > 0 && dt < best) {
                        best = dt;
                        memcpy(stages, o.ms_stage, sizeof stages);
                    }
                }
                struct row *row = &rows[nrows++];
                row->n = frames[c].count;
                row->W = W; row->H = H; row->threads = threads;
                row->ms = 1e3 * best;
                row->gl_ms = NAN;
                row->peer_psnr = NAN;
                if (have_gl && gl_peer_size(&gl, W, H, frames[c].count) == 0) {
                    double gbest = 1e30;
                    const unsigned char *px = NULL;
                    for (int k = 0; k <= runs; k++) { /* the first run compiles the shaders */
                        double t0 = bench_now();
                        px = gl_peer_render(&gl, cam, &frames[c], covs[c]);
                        double dt = bench_now() - t0;
                        if (k > 0 && dt < gbest)
                            gbest = dt;
                    }
                    if (px) {
                        row->gl_ms = 1e3 * gbest;
                        /* the peer draws the same image (up to its blending order) */
                        float *glf = malloc(3 * (size_t)W * (size_t)H * sizeof(float));
                        for (int y = 0; y < H; y++)
                            for (int x = 0; x < W; x++)
                                for (int ch = 0; ch < 3; ch++) {
                                    float v = rgb[3 * ((size_t)y * W + x) + ch];
                                    v = v < 0 ? 0 : (v > 1 ? 1 : v);
                                    rgb[3 * ((size_t)y * W + x) + ch] = floorf(v * 255.0f + 0.5f) / 255.0f;
                                    glf[3 * ((size_t)y * W + x) + ch] =
                                        (float)px[4 * ((size_t)(H - 1 - y) * W + x) + ch] / 255.0f;
                                }
                        row->peer_psnr = splat_psnr(rgb, glf, W, H, 3);
                        free(glf);
                    }
                }
                printf("render %7zu Gaussians %4dx%-4d threads %d: %8.2f ms (prep %.1f sort %.1f bin %.1f "
                       "raster %.1f)  llvmpipe %8.2f ms  (%.1fx; peer image PSNR %.1f dB)\n",
                       row->n, W, H, threads, row->ms, stages[0], stages[1], stages[2], stages[3], row->gl_ms,
                       row->gl_ms / row->ms, row->peer_psnr);
                fflush(stdout);
            }
            splat_renderer_free(r);
        }
        if (have_gl)
            gl_peer_close(&gl);
        fk_ctx_free(ctx);
    }
    free(rgb);
    for (int c = 0; c < 3; c++) {
        splat_frame_free(&frames[c]);
        free(covs[c]);
    }
    if (json) {
        FILE *fp = fopen(json, "w");
        if (!fp) {
            fprintf(stderr, "f4d-bench render: cannot create '%s'\n", json);
            return 1;
        }
        fprintf(fp, "{\"render\": [");
        for (int i = 0; i < nrows; i++) {
            fprintf(fp, "%s\n  {\"gaussians\": %zu, \"width\": %d, \"height\": %d, \"threads\": %d, \"ms\": %.3f, ",
                    i ? "," : "", rows[i].n, rows[i].W, rows[i].H, rows[i].threads, rows[i].ms);
            if (isnan(rows[i].gl_ms))
                fprintf(fp, "\"llvmpipe_ms\": null}");
            else
                fprintf(fp, "\"llvmpipe_ms\": %.3f}", rows[i].gl_ms);
        }
        fprintf(fp, "\n]}\n");
        fclose(fp);
    }
    return 0;
}
