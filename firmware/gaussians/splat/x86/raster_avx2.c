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
            const int oy = j->rgba8_up ? r->height - 1 - ty0 - y : ty0 + y;
            uint8_t *o = j->rgba8 + 4 * ((size_t)oy * (size_t)W + (size_t)(tx0 + x));
            if (tw - x >= 8) {
                _mm256_storeu_si256((__m256i *)o, px);
            } else { /* the image's last columns */
                uint32_t tmp[8];
                _mm256_storeu_si256((__m256i *)tmp, px);
                memcpy(o, tmp, 4 * (size_t)(tw - x));
            }
        }
}

/* A row's 8 pixels from p, or (packed) 4 pixels of two rows: p and the next
 * row at p + SPLAT_TILE (a narrow Gaussian's box, lanes 4..7 its second row). */
static inline __attribute__((always_inline)) __m256 ld(const float *a, int p, const int packed)
{
    return packed ? _mm256_set_m128(_mm_loadu_ps(a + p + SPLAT_TILE), _mm_loadu_ps(a + p)) : _mm256_loadu_ps(a + p);
}

static inline __attribute__((always_inline)) void st(float *a, int p, __m256 v, const int packed)
{
    if (packed) {
        _mm_storeu_ps(a + p, _mm256_castps256_ps128(v));
        _mm_storeu_ps(a + p + SPLAT_TILE, _mm256_extractf128_ps(v, 1));
    } else {
        _mm256_storeu_ps(a + p, v);
    }
}

/* The accumulators a render asks for beside colour and T. */
enum { AUX_DEPTH = 1, AUX_TOP = 2 };

/* What one Gaussian applies to the tile; the same for every step. */
struct gauss_step {
    __m256 vo, vcut, vz, cr, cg, cb;
    __m256i vid;
};

/* The tile's accumulators. */
struct tile_acc {
    float *T, *C0, *C1, *C2, *D, *best, *done;
    int32_t *top;
    int *row_left, *remaining;
};

/* One step: 8 pixels at p (lanes allowed by m0), power from the column terms
 * adxdx, bdx and the row terms vdy, cdy. Per pixel the scalar reference's
 * operations in its order; packed or not, a lane computes the same. */
static inline __attribute__((always_inline)) void step(const struct gauss_step *g, const struct tile_acc *t, int p,
                                                       int row, __m256 m0, __m256 adxdx, __m256 bdx, __m256 vdy,
                                                       __m256 cdy, const int aux, const int packed)
{
    const __m256 zero = _mm256_setzero_ps(), one = _mm256_set1_ps(1.0f);
    __m256 m = _mm256_andnot_ps(ld(t->done, p, packed), m0);
    if (_mm256_testz_ps(m, m))
        return;
    /* -0.5f * (A*dx*dx + Cc*dy*dy) - B*dx*dy, in the scalar order */
    __m256 power = _mm256_add_ps(adxdx, cdy);
    power = _mm256_sub_ps(_mm256_mul_ps(_mm256_set1_ps(-0.5f), power), _mm256_mul_ps(bdx, vdy));
    m = _mm256_and_ps(m, _mm256_cmp_ps(power, zero, _CMP_LE_OQ));
    m = _mm256_and_ps(m, _mm256_cmp_ps(power, g->vcut, _CMP_GE_OQ));
    if (_mm256_testz_ps(m, m))
        return;
    __m256 alpha = _mm256_min_ps(_mm256_mul_ps(g->vo, exp_ps(power)), _mm256_set1_ps(SPLAT_ALPHA_MAX));
    m = _mm256_and_ps(m, _mm256_cmp_ps(alpha, _mm256_set1_ps(SPLAT_ALPHA_MIN), _CMP_GE_OQ));
    const __m256 Tp = ld(t->T, p, packed);
    const __m256 test_T = _mm256_mul_ps(Tp, _mm256_sub_ps(one, alpha));
    const __m256 stop = _mm256_and_ps(m, _mm256_cmp_ps(test_T, _mm256_set1_ps(SPLAT_T_MIN), _CMP_LT_OQ));
    const __m256 add = _mm256_andnot_ps(stop, m);
    if (!_mm256_testz_ps(stop, stop)) {
        st(t->done, p, _mm256_or_ps(ld(t->done, p, packed), stop), packed);
        unsigned bits = (unsigned)_mm256_movemask_ps(stop);
        if (packed) {
            t->row_left[row] -= __builtin_popcount(bits & 15u);
            t->row_left[row + 1] -= __builtin_popcount(bits >> 4);
        } else {
            t->row_left[row] -= __builtin_popcount(bits);
        }
        *t->remaining -= __builtin_popcount(bits);
    }
    if (_mm256_testz_ps(add, add))
        return;
    /* lanes not added keep their value exactly (blend, not + 0) */
#define ACC(arr, c) st(arr, p, _mm256_blendv_ps(ld(arr, p, packed), \
                    _mm256_add_ps(ld(arr, p, packed), _mm256_mul_ps(_mm256_mul_ps(c, alpha), Tp)), add), packed)
    ACC(t->C0, g->cr);
    ACC(t->C1, g->cg);
    ACC(t->C2, g->cb);
    if (aux & AUX_DEPTH)
        ACC(t->D, g->vz);
    if (aux & AUX_TOP) {
        const __m256 bp = ld(t->best, p, packed);
        const __m256 w = _mm256_mul_ps(alpha, Tp);
        const __m256 better = _mm256_and_ps(add, _mm256_cmp_ps(w, bp, _CMP_GT_OQ));
        st(t->best, p, _mm256_blendv_ps(bp, w, better), packed);
        float *top = (float *)t->top; /* the ids travel as float bit patterns */
        st(top, p, _mm256_blendv_ps(ld(top, p, packed), _mm256_castsi256_ps(g->vid), better), packed);
    }
#undef ACC
    st(t->T, p, _mm256_blendv_ps(Tp, test_T, add), packed);
}

/* aux: also accumulate expected depth (AUX_DEPTH) and the dominant Gaussian
 * (AUX_TOP). A display asks for colour only, interp's pixel lookup for depth
 * only, and each accumulator skipped saves loads, stores and blends of the
 * inner loop; colour and T are computed by the same operations either way, so
 * the image is bit-identical. */
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
        C0[p] = C1[p] = C2[p] = done[p] = 0.0f;
    }
    if (aux) /* without depth and top nothing reads these (splat__tile_write neither) */
        for (int p = 0; p < NP; p++) {
            D[p] = best[p] = 0.0f;
            top[p] = -1;
        }
    for (int y = 0; y < SPLAT_TILE; y++)
        row_left[y] = y < th ? tw : 0;
    int remaining = tw * th;
    const struct tile_acc acc = { T, C0, C1, C2, D, best, done, top, row_left, &remaining };
    const __m256 lane = _mm256_setr_ps(0, 1, 2, 3, 4, 5, 6, 7);
    const __m128 lane4 = _mm_setr_ps(0, 1, 2, 3);
    const uint32_t s = r->tile_start[tile], e = r->tile_start[tile + 1];
    for (uint32_t k = s; k < e && remaining > 0; k++) {
        if (k + 6 < e)
            _mm_prefetch((const char *)(r->proj + r->pairs[k + 6]), _MM_HINT_T0);
        const struct projected *P = r->proj + r->pairs[k];
        const float mx = P->mx, my = P->my, A = P->A, B = P->B, Cc = P->C;
        const float k2 = P->k2;
        float fy0 = ceilf(my - P->ey), fy1 = floorf(my + P->ey);
        int y0 = fy0 > (float)ty0 ? (int)fy0 : ty0;
        int y1 = fy1 < (float)(ty0 + th - 1) ? (int)fy1 : ty0 + th - 1;
        if (y0 > y1)
            continue;
        /* columns of the ellipse's box; lanes outside the ellipse fail the
         * power >= cut test exactly as the scalar per-row span excludes them */
        const float fx0 = ceilf(mx - P->ex), fx1 = floorf(mx + P->ex);
        const int x0 = fx0 > (float)tx0 ? (int)fx0 : tx0;
        const int x1 = fx1 < (float)(tx0 + tw - 1) ? (int)fx1 : tx0 + tw - 1;
        if (x0 > x1)
            continue;
        const __m256 vA = _mm256_set1_ps(A), vB = _mm256_set1_ps(B), vC = _mm256_set1_ps(Cc);
        const __m256 vmx = _mm256_set1_ps(mx), vx1 = _mm256_set1_ps((float)x1);
        const struct gauss_step g = {
            .vo = _mm256_set1_ps(P->o), .vcut = _mm256_set1_ps(-0.5f * k2 - 0.001f), .vz = _mm256_set1_ps(P->z),
            .cr = _mm256_set1_ps(P->col[0]), .cg = _mm256_set1_ps(P->col[1]), .cb = _mm256_set1_ps(P->col[2]),
            .vid = _mm256_set1_epi32(P->id)
        };
        /* what depends on the column only, once per Gaussian: the box is at
         * most a tile wide, so two 8-lane columns (the same products the
         * rows computed each time before: the image is unchanged). A box of
         * at most 4 columns (most Gaussians of a dense scene) takes two rows
         * per step, its 4 columns repeated in both halves. */
        const int ncol = x1 - x0 >= 8 ? 2 : 1, narrow = x1 - x0 < 4;
        __m256 cmask[2], adxdx[2], bdx[2];
        for (int v = 0; v < ncol; v++) {
            __m256 xs = _mm256_add_ps(_mm256_set1_ps((float)(x0 + 8 * v)), lane);
            if (narrow) {
                const __m128 x4 = _mm_add_ps(_mm_set1_ps((float)x0), lane4);
                xs = _mm256_set_m128(x4, x4);
            }
            const __m256 dx = _mm256_sub_ps(vmx, xs);
            cmask[v] = _mm256_cmp_ps(xs, vx1, _CMP_LE_OQ);
            adxdx[v] = _mm256_mul_ps(_mm256_mul_ps(vA, dx), dx); /* A * dx * dx */
            bdx[v] = _mm256_mul_ps(vB, dx);                      /* B * dx */
        }
        int y = y0;
        if (narrow)
            for (; y < y1; y += 2) {
                if ((row_left[y - ty0] | row_left[y + 1 - ty0]) == 0)
                    continue;
                const __m256 vdy = _mm256_set_m128(_mm_set1_ps(my - (float)(y + 1)), _mm_set1_ps(my - (float)y));
                const __m256 cdy = _mm256_mul_ps(_mm256_mul_ps(vC, vdy), vdy); /* Cc * dy * dy */
                step(&g, &acc, (y - ty0) * SPLAT_TILE + x0 - tx0, y - ty0, cmask[0], adxdx[0], bdx[0], vdy, cdy,
                     aux, 1);
            }
        for (; y <= y1; y++) { /* wider boxes, and a narrow box's last odd row */
            if (row_left[y - ty0] == 0)
                continue;
            const __m256 vdy = _mm256_set1_ps(my - (float)y);
            const __m256 cdy = _mm256_mul_ps(_mm256_mul_ps(vC, vdy), vdy);
            const int row = (y - ty0) * SPLAT_TILE - tx0;
            /* narrow: lanes 4..7 repeat the columns; the low half alone */
            const __m256 m0 = narrow ? _mm256_and_ps(cmask[0], _mm256_castsi256_ps(_mm256_setr_epi32(
                                           -1, -1, -1, -1, 0, 0, 0, 0)))
                                     : cmask[0];
            step(&g, &acc, row + x0, y - ty0, m0, adxdx[0], bdx[0], vdy, cdy, aux, 0);
            if (ncol == 2)
                step(&g, &acc, row + x0 + 8, y - ty0, cmask[1], adxdx[1], bdx[1], vdy, cdy, aux, 0);
        }
    }
    if (!aux && j->rgba8 && !j->rgb && !j->alpha)
        write_rgba8(j, tile, T, C0, C1, C2);
    else
        splat__tile_write(j, tile, T, C0, C1, C2, D, top);
}

void splat__raster_tile_avx2(const struct raster_job *j, int tile)
{
    if (j->top)
        raster_tile(j, tile, AUX_DEPTH | AUX_TOP);
    else if (j->depth)
        raster_tile(j, tile, AUX_DEPTH);
    else
        raster_tile(j, tile, 0);
}
