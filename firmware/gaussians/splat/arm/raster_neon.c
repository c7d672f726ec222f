/* raster_neon.c - the compositing of render.c with 4 pixels of a row per step
 * (AArch64 NEON, chosen at run time from the fk context's ISA). Per pixel the
 * operations are the scalar reference's, in the same order and without fused
 * multiply-adds, except exp: the Cody-Waite reduction and degree-6 polynomial
 * of the AVX2 compositor, within 2 ulp of expf and exactly 1 at 0. */
#include <arm_neon.h>
#include <math.h>
#include <string.h>

#include "../render_internal.h"

/* exp(x) for x in [-88, 0]; inputs below are flushed towards 0 output. */
static inline float32x4_t exp_ps(float32x4_t x)
{
    const float32x4_t log2e = vdupq_n_f32(1.44269504088896341f);
    const float32x4_t ln2_hi = vdupq_n_f32(0.693359375f), ln2_lo = vdupq_n_f32(-2.12194440e-4f);
    x = vmaxq_f32(x, vdupq_n_f32(-87.0f));
    float32x4_t n = vrndnq_f32(vmulq_f32(x, log2e));
    float32x4_t r = vsubq_f32(vsubq_f32(x, vmulq_f32(n, ln2_hi)), vmulq_f32(n, ln2_lo));
    float32x4_t p = vdupq_n_f32(1.9875691500e-4f);
    p = vaddq_f32(vmulq_f32(p, r), vdupq_n_f32(1.3981999507e-3f));
    p = vaddq_f32(vmulq_f32(p, r), vdupq_n_f32(8.3334519073e-3f));
    p = vaddq_f32(vmulq_f32(p, r), vdupq_n_f32(4.1665795894e-2f));
    p = vaddq_f32(vmulq_f32(p, r), vdupq_n_f32(1.6666665459e-1f));
    p = vaddq_f32(vmulq_f32(p, r), vdupq_n_f32(5.0000001201e-1f));
    float32x4_t r2 = vmulq_f32(r, r);
    p = vaddq_f32(vaddq_f32(vmulq_f32(p, r2), r), vdupq_n_f32(1.0f));
    int32x4_t e = vshlq_n_s32(vaddq_s32(vcvtnq_s32_f32(n), vdupq_n_s32(127)), 23);
    return vmulq_f32(p, vreinterpretq_f32_s32(e));
}

static inline int any(uint32x4_t m) { return vmaxvq_u32(m) != 0; }

void splat__raster_tile_neon(const struct raster_job *j, int tile)
{
    const struct raster_ctx *r = &j->rc;
    const int W = r->width, H = r->height;
    const int tx0 = (tile % r->tiles_x) * SPLAT_TILE, ty0 = (tile / r->tiles_x) * SPLAT_TILE;
    const int tw = (W - tx0 < SPLAT_TILE) ? W - tx0 : SPLAT_TILE;
    const int th = (H - ty0 < SPLAT_TILE) ? H - ty0 : SPLAT_TILE;
    /* 4 floats of slack: a row's 4-wide step may read past its 16th pixel */
    enum { N = SPLAT_TILE * SPLAT_TILE, NP = N + 4 };
    float T[NP], C0[NP], C1[NP], C2[NP], D[NP], best[NP];
    uint32_t done[NP];
    int32_t top[NP];
    int row_left[SPLAT_TILE];
    for (int p = 0; p < NP; p++) {
        T[p] = 1.0f;
        C0[p] = C1[p] = C2[p] = D[p] = best[p] = 0.0f;
        done[p] = 0;
        top[p] = -1;
    }
    for (int y = 0; y < SPLAT_TILE; y++)
        row_left[y] = y < th ? tw : 0;
    int remaining = tw * th;
    static const float lane_init[4] = { 0, 1, 2, 3 };
    const float32x4_t lane = vld1q_f32(lane_init);
    const float32x4_t zero = vdupq_n_f32(0.0f), one = vdupq_n_f32(1.0f);
    const float32x4_t amax = vdupq_n_f32(SPLAT_ALPHA_MAX), amin = vdupq_n_f32(SPLAT_ALPHA_MIN);
    const float32x4_t tmin = vdupq_n_f32(SPLAT_T_MIN), mhalf = vdupq_n_f32(-0.5f);
    const uint32_t s = r->tile_start[tile], e = r->tile_start[tile + 1];
    for (uint32_t k = s; k < e && remaining > 0; k++) {
        if (k + 6 < e)
            __builtin_prefetch(r->proj + r->pairs[k + 6]);
        const struct projected *P = r->proj + r->pairs[k];
        const float mx = P->mx, my = P->my, A = P->A, B = P->B, Cc = P->C;
        const float k2 = P->k2;
        float fy0 = ceilf(my - P->ey), fy1 = floorf(my + P->ey);
        int y0 = fy0 > (float)ty0 ? (int)fy0 : ty0;
        int y1 = fy1 < (float)(ty0 + th - 1) ? (int)fy1 : ty0 + th - 1;
        if (y0 > y1)
            continue;
        const float32x4_t vA = vdupq_n_f32(A), vB = vdupq_n_f32(B), vC = vdupq_n_f32(Cc);
        const float32x4_t vo = vdupq_n_f32(P->o), vcut = vdupq_n_f32(-0.5f * k2 - 0.001f);
        const float32x4_t vz = vdupq_n_f32(P->z), vmx = vdupq_n_f32(mx);
        const float32x4_t cr = vdupq_n_f32(P->col[0]), cg = vdupq_n_f32(P->col[1]), cb = vdupq_n_f32(P->col[2]);
        const int32x4_t vid = vdupq_n_s32(P->id);
        /* columns of the ellipse's box; lanes outside the ellipse fail the
         * power >= cut test exactly as the scalar per-row span excludes them */
        const float fx0 = ceilf(mx - P->ex), fx1 = floorf(mx + P->ex);
        const int x0 = fx0 > (float)tx0 ? (int)fx0 : tx0;
        const int x1 = fx1 < (float)(tx0 + tw - 1) ? (int)fx1 : tx0 + tw - 1;
        if (x0 > x1)
            continue;
        const float32x4_t vx1 = vdupq_n_f32((float)x1);
        for (int y = y0; y <= y1; y++) {
            if (row_left[y - ty0] == 0)
                continue;
            const float dy = my - (float)y;
            const float32x4_t vdy = vdupq_n_f32(dy);
            const float32x4_t cdy = vmulq_f32(vmulq_f32(vC, vdy), vdy); /* Cc * dy * dy */
            const int row = (y - ty0) * SPLAT_TILE - tx0;
            for (int x = x0; x <= x1; x += 4) {
                const int p = row + x;
                const float32x4_t xs = vaddq_f32(vdupq_n_f32((float)x), lane);
                uint32x4_t m = vbicq_u32(vcleq_f32(xs, vx1), vld1q_u32(done + p));
                if (!any(m))
                    continue;
                const float32x4_t dx = vsubq_f32(vmx, xs);
                /* -0.5f * (A*dx*dx + Cc*dy*dy) - B*dx*dy, in the scalar order */
                float32x4_t power = vaddq_f32(vmulq_f32(vmulq_f32(vA, dx), dx), cdy);
                power = vsubq_f32(vmulq_f32(mhalf, power), vmulq_f32(vmulq_f32(vB, dx), vdy));
                m = vandq_u32(m, vcleq_f32(power, zero));
                m = vandq_u32(m, vcgeq_f32(power, vcut));
                if (!any(m))
                    continue;
                /* alpha < 0.99 ? alpha : 0.99, as the scalar (NaN -> 0.99) */
                float32x4_t alpha = vmulq_f32(vo, exp_ps(power));
                alpha = vbslq_f32(vcltq_f32(alpha, amax), alpha, amax);
                m = vandq_u32(m, vcgeq_f32(alpha, amin));
                const float32x4_t Tp = vld1q_f32(T + p);
                const float32x4_t test_T = vmulq_f32(Tp, vsubq_f32(one, alpha));
                const uint32x4_t stop = vandq_u32(m, vcltq_f32(test_T, tmin));
                const uint32x4_t add = vbicq_u32(m, stop);
                if (any(stop)) {
                    vst1q_u32(done + p, vorrq_u32(vld1q_u32(done + p), stop));
                    int c = (int)vaddvq_u32(vshrq_n_u32(stop, 31));
                    row_left[y - ty0] -= c;
                    remaining -= c;
                }
                if (!any(add))
                    continue;
                const float32x4_t w = vmulq_f32(alpha, Tp);
                /* lanes not added keep their value exactly (select, not + 0) */
#define ACC(arr, c) vst1q_f32(arr + p, vbslq_f32(add, vaddq_f32(vld1q_f32(arr + p), \
                    vmulq_f32(vmulq_f32(c, alpha), Tp)), vld1q_f32(arr + p)))
                ACC(C0, cr);
                ACC(C1, cg);
                ACC(C2, cb);
                ACC(D, vz);
#undef ACC
                const float32x4_t bp = vld1q_f32(best + p);
                const uint32x4_t better = vandq_u32(add, vcgtq_f32(w, bp));
                vst1q_f32(best + p, vbslq_f32(better, w, bp));
                vst1q_s32(top + p, vbslq_s32(better, vid, vld1q_s32(top + p)));
                vst1q_f32(T + p, vbslq_f32(add, test_T, Tp));
            }
        }
    }
    splat__tile_write(j, tile, T, C0, C1, C2, D, top);
}
