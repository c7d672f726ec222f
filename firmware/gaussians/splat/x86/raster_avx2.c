/* raster_avx2.c - the compositing of render.c with 8 pixels of a row per
 * step (AVX2; compiled with -mavx2 -mfma, chosen at run time from the fk
 * context's ISA). Per pixel the operations are the scalar reference's, in the
 * same order and without fused multiply-adds, except exp: a Cody-Waite
 * reduction and a degree-6 polynomial, within 2 ulp of expf and exactly 1 at
 * 0 (the reference CUDA expf is itself 2 ulp). */
#include <immintrin.h>
#include <math.h>
#include <string.h>

#include "../render_internal.h"

/* exp(x) for x in [-88, 0]; inputs below are flushed towards 0 output. */
static inline __m256 exp_ps(__m256 x)
{
    const __m256 log2e = _mm256_set1_ps(1.44269504088896341f);
    const __m256 ln2_hi = _mm256_set1_ps(0.693359375f), ln2_lo = _mm256_set1_ps(-2.12194440e-4f);
    x = _mm256_max_ps(x, _mm256_set1_ps(-87.0f));
    __m256 n = _mm256_round_ps(_mm256_mul_ps(x, log2e), _MM_FROUND_TO_NEAREST_INT | _MM_FROUND_NO_EXC);
    __m256 r = _mm256_sub_ps(_mm256_sub_ps(x, _mm256_mul_ps(n, ln2_hi)), _mm256_mul_ps(n, ln2_lo));
    /* exp(r) on |r| <= ln2/2: Taylor-like minimax coefficients (Cephes expf) */
    __m256 p = _mm256_set1_ps(1.9875691500e-4f);
    p = _mm256_add_ps(_mm256_mul_ps(p, r), _mm256_set1_ps(1.3981999507e-3f));
    p = _mm256_add_ps(_mm256_mul_ps(p, r), _mm256_set1_ps(8.3334519073e-3f));
    p = _mm256_add_ps(_mm256_mul_ps(p, r), _mm256_set1_ps(4.1665795894e-2f));
    p = _mm256_add_ps(_mm256_mul_ps(p, r), _mm256_set1_ps(1.6666665459e-1f));
    p = _mm256_add_ps(_mm256_mul_ps(p, r), _mm256_set1_ps(5.0000001201e-1f));
    __m256 r2 = _mm256_mul_ps(r, r);
    p = _mm256_add_ps(_mm256_add_ps(_mm256_mul_ps(p, r2), r), _mm256_set1_ps(1.0f));
    __m256i e = _mm256_slli_epi32(_mm256_add_epi32(_mm256_cvtps_epi32(n), _mm256_set1_epi32(127)), 23);
    return _mm256_mul_ps(p, _mm256_castsi256_ps(e));
}

/* The finished tile to an rgba8 image alone (a display's request): colour
 * over bg quantised as splat__tile_write does (max with 0 first also sends
 * NaN to 0, as its v > 0 test does), 8 pixels per step. */
static void write_rgba8(const struct raster_job *j, int tile, const float *T, const float *C0, const float *C1,
                        const float *C2)
{
    const struct raster_ctx *r = &j->rc;
    const int W = r->width;
    const int tx0 = (tile % r->tiles_x) * SPLAT_TILE, ty0 = (tile / r->tiles_x) * SPLAT_TILE;
    const int tw = (W - tx0 < SPLAT_TILE) ? W - tx0 : SPLAT_TILE;
    const int th = (r->height - ty0 < SPLAT_TILE) ? r->height - ty0 : SPLAT_TILE;
    const __m256 zero = _mm256_setzero_ps(), one = _mm256_set1_ps(1.0f);
    const __m256 s255 = _mm256_set1_ps(255.0f), half = _mm256_set1_ps(0.5f);
    const __m256 bg[3] = { _mm256_set1_ps(j->bg ? j->bg[0] : 0.0f), _mm256_set1_ps(j->bg ? j->bg[1] : 0.0f),
                           _mm256_set1_ps(j->bg ? j->bg[2] : 0.0f) };
    const float *C[3] = { C0, C1, C2 };
    for (int y = 0; y < th; y++)
        for (int x = 0; x < tw; x += 8) {
            const int p = y * SPLAT_TILE + x;
            const __m256 t = _mm256_loadu_ps(T + p);
            __m256i px = _mm256_set1_epi32((int)0xff000000u);
            for (int c = 0; c < 3; c++) {
                __m256 v = _mm256_add_ps(_mm256_loadu_ps(C[c] + p), _mm256_mul_ps(t, bg[c]));
                v = _mm256_min_ps(_mm256_max_ps(v, zero), one);
                __m256i q = _mm256_cvttps_epi32(_mm256_add_ps(_mm256_mul_ps(v, s255), half));
                px = _mm256_or_si256(px, _mm256_slli_epi32(q, 8 * c));
            }
            uint8_t *o = j->rgba8 + 4 * ((size_t)(ty0 + y) * (size_t)W + (size_t)(tx0 + x));
            if (tw - x >= 8) {
                _mm256_storeu_si256((__m256i *)o, px);
            } else { /* the image's last columns */
                uint32_t tmp[8];
                _mm256_storeu_si256((__m256i *)tmp, px);
                memcpy(o, tmp, 4 * (size_t)(tw - x));
            }
        }
}

/* aux: also accumulate expected depth and the dominant Gaussian. A display
 * asks for colour only, and the 3 accumulators it skips are about a quarter
 * of the inner loop's loads and stores; colour and T are computed by the same
 * operations either way, so the image is bit-identical. */
static inline __attribute__((always_inline)) void raster_tile(const struct raster_job *j, int tile, const int aux)
{
    const struct raster_ctx *r = &j->rc;
    const int W = r->width, H = r->height;
    const int tx0 = (tile % r->tiles_x) * SPLAT_TILE, ty0 = (tile / r->tiles_x) * SPLAT_TILE;
    const int tw = (W - tx0 < SPLAT_TILE) ? W - tx0 : SPLAT_TILE;
    const int th = (H - ty0 < SPLAT_TILE) ? H - ty0 : SPLAT_TILE;
    /* 8 floats of slack: a row's 8-wide step may read past its 16th pixel */
    enum { N = SPLAT_TILE * SPLAT_TILE, NP = N + 8 };
    float T[NP], C0[NP], C1[NP], C2[NP], D[NP], best[NP], done[NP];
    int32_t top[NP];
    int row_left[SPLAT_TILE];
    for (int p = 0; p < NP; p++) {
        T[p] = 1.0f;
        C0[p] = C1[p] = C2[p] = D[p] = best[p] = done[p] = 0.0f;
        top[p] = -1;
    }
    for (int y = 0; y < SPLAT_TILE; y++)
        row_left[y] = y < th ? tw : 0;
    int remaining = tw * th;
    const __m256 lane = _mm256_setr_ps(0, 1, 2, 3, 4, 5, 6, 7);
    const __m256 zero = _mm256_setzero_ps(), one = _mm256_set1_ps(1.0f);
    const __m256 amax = _mm256_set1_ps(SPLAT_ALPHA_MAX), amin = _mm256_set1_ps(SPLAT_ALPHA_MIN);
    const __m256 tmin = _mm256_set1_ps(SPLAT_T_MIN);
    const uint32_t s = r->tile_start[tile], e = r->tile_start[tile + 1];
    for (uint32_t k = s; k < e && remaining > 0; k++) {
        if (k + 6 < e)
            _mm_prefetch((const char *)(r->sorted + r->pairs[k + 6]), _MM_HINT_T0);
        const struct projected *P = r->sorted + r->pairs[k];
        const float mx = P->mx, my = P->my, A = P->A, B = P->B, Cc = P->C;
        const float k2 = P->k2;
        float fy0 = ceilf(my - P->ey), fy1 = floorf(my + P->ey);
        int y0 = fy0 > (float)ty0 ? (int)fy0 : ty0;
        int y1 = fy1 < (float)(ty0 + th - 1) ? (int)fy1 : ty0 + th - 1;
        if (y0 > y1)
            continue;
        const __m256 vA = _mm256_set1_ps(A), vB = _mm256_set1_ps(B), vC = _mm256_set1_ps(Cc);
        const __m256 vo = _mm256_set1_ps(P->o), vcut = _mm256_set1_ps(-0.5f * k2 - 0.001f);
        const __m256 vz = _mm256_set1_ps(P->z), vmx = _mm256_set1_ps(mx);
        const __m256 cr = _mm256_set1_ps(P->col[0]), cg = _mm256_set1_ps(P->col[1]), cb = _mm256_set1_ps(P->col[2]);
        const __m256i vid = _mm256_set1_epi32(P->id);
        /* columns of the ellipse's box; lanes outside the ellipse fail the
         * power >= cut test exactly as the scalar per-row span excludes them */
        const float fx0 = ceilf(mx - P->ex), fx1 = floorf(mx + P->ex);
        const int x0 = fx0 > (float)tx0 ? (int)fx0 : tx0;
        const int x1 = fx1 < (float)(tx0 + tw - 1) ? (int)fx1 : tx0 + tw - 1;
        if (x0 > x1)
            continue;
        /* what depends on the column only, once per Gaussian: the box is at
         * most a tile wide, so two 8-lane columns (the same products the
         * rows computed each time before: the image is unchanged) */
        const int ncol = x1 - x0 >= 8 ? 2 : 1;
        __m256 cmask[2], adxdx[2], bdx[2];
        for (int v = 0; v < ncol; v++) {
            const __m256 xs = _mm256_add_ps(_mm256_set1_ps((float)(x0 + 8 * v)), lane);
            const __m256 dx = _mm256_sub_ps(vmx, xs);
            cmask[v] = _mm256_cmp_ps(xs, _mm256_set1_ps((float)x1), _CMP_LE_OQ);
            adxdx[v] = _mm256_mul_ps(_mm256_mul_ps(vA, dx), dx); /* A * dx * dx */
            bdx[v] = _mm256_mul_ps(vB, dx);                      /* B * dx */
        }
        for (int y = y0; y <= y1; y++) {
            if (row_left[y - ty0] == 0)
                continue;
            const float dy = my - (float)y;
            const __m256 vdy = _mm256_set1_ps(dy);
            const __m256 cdy = _mm256_mul_ps(_mm256_mul_ps(vC, vdy), vdy); /* Cc * dy * dy */
            const int row = (y - ty0) * SPLAT_TILE - tx0;
            for (int v = 0; v < ncol; v++) {
                const int p = row + x0 + 8 * v;
                __m256 m = _mm256_andnot_ps(_mm256_loadu_ps(done + p), cmask[v]);
                if (_mm256_testz_ps(m, m))
                    continue;
                /* -0.5f * (A*dx*dx + Cc*dy*dy) - B*dx*dy, in the scalar order */
                __m256 power = _mm256_add_ps(adxdx[v], cdy);
                power = _mm256_sub_ps(_mm256_mul_ps(_mm256_set1_ps(-0.5f), power), _mm256_mul_ps(bdx[v], vdy));
                m = _mm256_and_ps(m, _mm256_cmp_ps(power, zero, _CMP_LE_OQ));
                m = _mm256_and_ps(m, _mm256_cmp_ps(power, vcut, _CMP_GE_OQ));
                if (_mm256_testz_ps(m, m))
                    continue;
                __m256 alpha = _mm256_min_ps(_mm256_mul_ps(vo, exp_ps(power)), amax);
                m = _mm256_and_ps(m, _mm256_cmp_ps(alpha, amin, _CMP_GE_OQ));
                const __m256 Tp = _mm256_loadu_ps(T + p);
                const __m256 test_T = _mm256_mul_ps(Tp, _mm256_sub_ps(one, alpha));
                const __m256 stop = _mm256_and_ps(m, _mm256_cmp_ps(test_T, tmin, _CMP_LT_OQ));
                const __m256 add = _mm256_andnot_ps(stop, m);
                if (!_mm256_testz_ps(stop, stop)) {
                    _mm256_storeu_ps(done + p, _mm256_or_ps(_mm256_loadu_ps(done + p), stop));
                    int c = __builtin_popcount((unsigned)_mm256_movemask_ps(stop));
                    row_left[y - ty0] -= c;
                    remaining -= c;
                }
                if (_mm256_testz_ps(add, add))
                    continue;
                /* lanes not added keep their value exactly (blend, not + 0) */
#define ACC(arr, c) _mm256_storeu_ps(arr + p, _mm256_blendv_ps(_mm256_loadu_ps(arr + p), \
                    _mm256_add_ps(_mm256_loadu_ps(arr + p), _mm256_mul_ps(_mm256_mul_ps(c, alpha), Tp)), add))
                ACC(C0, cr);
                ACC(C1, cg);
                ACC(C2, cb);
                if (aux) {
                    ACC(D, vz);
                    const __m256 bp = _mm256_loadu_ps(best + p);
                    const __m256 w = _mm256_mul_ps(alpha, Tp);
                    const __m256 better = _mm256_and_ps(add, _mm256_cmp_ps(w, bp, _CMP_GT_OQ));
                    _mm256_storeu_ps(best + p, _mm256_blendv_ps(bp, w, better));
                    const __m256i tp = _mm256_loadu_si256((const __m256i *)(top + p));
                    _mm256_storeu_si256((__m256i *)(top + p),
                                        _mm256_castps_si256(_mm256_blendv_ps(_mm256_castsi256_ps(tp),
                                                                             _mm256_castsi256_ps(vid), better)));
                }
#undef ACC
                _mm256_storeu_ps(T + p, _mm256_blendv_ps(Tp, test_T, add));
            }
        }
    }
    if (!aux && j->rgba8 && !j->rgb && !j->alpha)
        write_rgba8(j, tile, T, C0, C1, C2);
    else
        splat__tile_write(j, tile, T, C0, C1, C2, D, top);
}

void splat__raster_tile_avx2(const struct raster_job *j, int tile)
{
    if (j->depth || j->top)
        raster_tile(j, tile, 1);
    else
        raster_tile(j, tile, 0);
}
