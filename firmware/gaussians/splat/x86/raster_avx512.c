/* raster_avx512.c - the AVX2 compositor's operations on 16 lanes (AVX-512
 * F/BW/VL, the fk context's AVX512 ISA; compiled with -mavx512f -mavx512bw
 * -mavx512vl -mfma). A lane computes exactly what raster_avx2.c's lane does
 * (same operations, same order, no fused multiply-adds, the same exp), so the
 * images are bit-identical to it; what changes is how a Gaussian's box fills
 * the lanes: 4 rows of 4 columns for boxes at most 4 wide, 2 rows of 8 up to
 * 8 wide, one row of 16 beyond. An earlier 16-lane version (one tile row per
 * vector) was slower than AVX2 here, since most boxes are a few pixels wide
 * and left most of the lanes idle. */
#include <immintrin.h>
#include <math.h>
#include <string.h>

#include "../render_internal.h"

/* exp(x) for x in [-88, 0]: raster_avx2.c's exp_ps, operation for operation. */
static inline __m512 exp_ps(__m512 x)
{
    const __m512 log2e = _mm512_set1_ps(1.44269504088896341f);
    const __m512 ln2_hi = _mm512_set1_ps(0.693359375f), ln2_lo = _mm512_set1_ps(-2.12194440e-4f);
    x = _mm512_max_ps(x, _mm512_set1_ps(-87.0f));
    __m512 n = _mm512_roundscale_ps(_mm512_mul_ps(x, log2e), _MM_FROUND_TO_NEAREST_INT | _MM_FROUND_NO_EXC);
    __m512 r = _mm512_sub_ps(_mm512_sub_ps(x, _mm512_mul_ps(n, ln2_hi)), _mm512_mul_ps(n, ln2_lo));
    __m512 p = _mm512_set1_ps(1.9875691500e-4f);
    p = _mm512_add_ps(_mm512_mul_ps(p, r), _mm512_set1_ps(1.3981999507e-3f));
    p = _mm512_add_ps(_mm512_mul_ps(p, r), _mm512_set1_ps(8.3334519073e-3f));
    p = _mm512_add_ps(_mm512_mul_ps(p, r), _mm512_set1_ps(4.1665795894e-2f));
    p = _mm512_add_ps(_mm512_mul_ps(p, r), _mm512_set1_ps(1.6666665459e-1f));
    p = _mm512_add_ps(_mm512_mul_ps(p, r), _mm512_set1_ps(5.0000001201e-1f));
    __m512 r2 = _mm512_mul_ps(r, r);
    p = _mm512_add_ps(_mm512_add_ps(_mm512_mul_ps(p, r2), r), _mm512_set1_ps(1.0f));
    __m512i e = _mm512_slli_epi32(_mm512_add_epi32(_mm512_cvtps_epi32(n), _mm512_set1_epi32(127)), 23);
    return _mm512_mul_ps(p, _mm512_castsi512_ps(e));
}

/* The finished tile to an rgba8 image alone, as raster_avx2.c's write_rgba8. */
static void write_rgba8(const struct raster_job *j, int tile, const float *T, const float *C0, const float *C1,
                        const float *C2)
{
    const struct raster_ctx *r = &j->rc;
    const int W = r->width;
    const int tx0 = (tile % r->tiles_x) * SPLAT_TILE, ty0 = (tile / r->tiles_x) * SPLAT_TILE;
    const int tw = (W - tx0 < SPLAT_TILE) ? W - tx0 : SPLAT_TILE;
    const int th = (r->height - ty0 < SPLAT_TILE) ? r->height - ty0 : SPLAT_TILE;
    const __m512 zero = _mm512_setzero_ps(), one = _mm512_set1_ps(1.0f);
    const __m512 s255 = _mm512_set1_ps(255.0f), half = _mm512_set1_ps(0.5f);
    const __m512 bg[3] = { _mm512_set1_ps(j->bg ? j->bg[0] : 0.0f), _mm512_set1_ps(j->bg ? j->bg[1] : 0.0f),
                           _mm512_set1_ps(j->bg ? j->bg[2] : 0.0f) };
    const float *C[3] = { C0, C1, C2 };
    const __mmask16 cols = (__mmask16)((1u << tw) - 1u);
    for (int y = 0; y < th; y++) {
        const int p = y * SPLAT_TILE;
        const __m512 t = _mm512_loadu_ps(T + p);
        __m512i px = _mm512_set1_epi32((int)0xff000000u);
        for (int c = 0; c < 3; c++) {
            __m512 v = _mm512_add_ps(_mm512_loadu_ps(C[c] + p), _mm512_mul_ps(t, bg[c]));
            v = _mm512_min_ps(_mm512_max_ps(v, zero), one);
            __m512i q = _mm512_cvttps_epi32(_mm512_add_ps(_mm512_mul_ps(v, s255), half));
            px = _mm512_or_si512(px, _mm512_slli_epi32(q, 8 * c));
        }
        const int oy = j->rgba8_up ? r->height - 1 - ty0 - y : ty0 + y;
        _mm512_mask_storeu_epi32(j->rgba8 + 4 * ((size_t)oy * (size_t)W + (size_t)tx0), cols, px);
    }
}

/* Lanes of a step: CW columns of 16 / CW rows, row k at p + k * SPLAT_TILE. */
static inline __attribute__((always_inline)) __m512 ld(const float *a, int p, const int cw)
{
    if (cw == 16)
        return _mm512_loadu_ps(a + p);
    if (cw == 8) {
        const __m512 lo = _mm512_castps256_ps512(_mm256_loadu_ps(a + p));
        return _mm512_castpd_ps(_mm512_insertf64x4(_mm512_castps_pd(lo),
                                                   _mm256_castps_pd(_mm256_loadu_ps(a + p + SPLAT_TILE)), 1));
    }
    __m512 v = _mm512_castps128_ps512(_mm_loadu_ps(a + p));
    v = _mm512_insertf32x4(v, _mm_loadu_ps(a + p + SPLAT_TILE), 1);
    v = _mm512_insertf32x4(v, _mm_loadu_ps(a + p + 2 * SPLAT_TILE), 2);
    return _mm512_insertf32x4(v, _mm_loadu_ps(a + p + 3 * SPLAT_TILE), 3);
}

static inline __attribute__((always_inline)) void st(float *a, int p, __m512 v, const int cw)
{
    if (cw == 16) {
        _mm512_storeu_ps(a + p, v);
    } else if (cw == 8) {
        _mm256_storeu_ps(a + p, _mm512_castps512_ps256(v));
        _mm256_storeu_ps(a + p + SPLAT_TILE, _mm256_castpd_ps(_mm512_extractf64x4_pd(_mm512_castps_pd(v), 1)));
    } else {
        _mm_storeu_ps(a + p, _mm512_castps512_ps128(v));
        _mm_storeu_ps(a + p + SPLAT_TILE, _mm512_extractf32x4_ps(v, 1));
        _mm_storeu_ps(a + p + 2 * SPLAT_TILE, _mm512_extractf32x4_ps(v, 2));
        _mm_storeu_ps(a + p + 3 * SPLAT_TILE, _mm512_extractf32x4_ps(v, 3));
    }
}

enum { AUX_DEPTH = 1, AUX_TOP = 2 };

struct gauss_step {
    __m512 vo, vcut, vz, cr, cg, cb, vA, vB, vC, vmx, vmy;
    __m512i vid;
};

struct tile_acc {
    float *T, *C0, *C1, *C2, *D, *best, *done;
    int32_t *top;
    int *row_left, *remaining;
};

/* One step of cw columns from x0 over rows row .. row + 16 / cw - 1 of the
 * tile (m0: lanes inside the box). dx, dy and the power as raster_avx2.c's
 * lane computes them for its pixel. */
static inline __attribute__((always_inline)) void step(const struct gauss_step *g, const struct tile_acc *t, int p,
                                                       int row, __mmask16 m0, __m512 adxdx, __m512 bdx, __m512 vdy,
                                                       const int aux, const int cw)
{
    __mmask16 m = m0 & ~_mm512_cmp_ps_mask(ld(t->done, p, cw), _mm512_setzero_ps(), _CMP_NEQ_UQ);
    if (!m)
        return;
    const __m512 cdy = _mm512_mul_ps(_mm512_mul_ps(g->vC, vdy), vdy); /* Cc * dy * dy */
    __m512 power = _mm512_add_ps(adxdx, cdy);
    power = _mm512_sub_ps(_mm512_mul_ps(_mm512_set1_ps(-0.5f), power), _mm512_mul_ps(bdx, vdy));
    m = _mm512_mask_cmp_ps_mask(m, power, _mm512_setzero_ps(), _CMP_LE_OQ);
    m = _mm512_mask_cmp_ps_mask(m, power, g->vcut, _CMP_GE_OQ);
    if (!m)
        return;
    const __m512 alpha = _mm512_min_ps(_mm512_mul_ps(g->vo, exp_ps(power)), _mm512_set1_ps(SPLAT_ALPHA_MAX));
    m = _mm512_mask_cmp_ps_mask(m, alpha, _mm512_set1_ps(SPLAT_ALPHA_MIN), _CMP_GE_OQ);
    const __m512 Tp = ld(t->T, p, cw);
    const __m512 test_T = _mm512_mul_ps(Tp, _mm512_sub_ps(_mm512_set1_ps(1.0f), alpha));
    const __mmask16 stop = _mm512_mask_cmp_ps_mask(m, test_T, _mm512_set1_ps(SPLAT_T_MIN), _CMP_LT_OQ);
    const __mmask16 add = m & (__mmask16)~stop;
    if (stop) {
        /* done lanes hold all-ones bit patterns, as the AVX2 masks */
        const __m512 ones = _mm512_castsi512_ps(_mm512_set1_epi32(-1));
        st(t->done, p, _mm512_mask_blend_ps(stop, ld(t->done, p, cw), ones), cw);
        const unsigned bits = stop;
        const unsigned rows = 16 / (unsigned)cw, rmask = cw == 16 ? 0xffffu : (1u << cw) - 1u;
        for (unsigned k = 0; k < rows; k++)
            t->row_left[row + (int)k] -= __builtin_popcount((bits >> (k * (unsigned)cw)) & rmask);
        *t->remaining -= __builtin_popcount(bits);
    }
    if (!add)
        return;
#define ACC(arr, c) st(arr, p, _mm512_mask_blend_ps(add, ld(arr, p, cw), \
                    _mm512_add_ps(ld(arr, p, cw), _mm512_mul_ps(_mm512_mul_ps(c, alpha), Tp))), cw)
    ACC(t->C0, g->cr);
    ACC(t->C1, g->cg);
    ACC(t->C2, g->cb);
    if (aux & AUX_DEPTH)
        ACC(t->D, g->vz);
    if (aux & AUX_TOP) {
        const __m512 bp = ld(t->best, p, cw);
        const __m512 w = _mm512_mul_ps(alpha, Tp);
        const __mmask16 better = _mm512_mask_cmp_ps_mask(add, w, bp, _CMP_GT_OQ);
        st(t->best, p, _mm512_mask_blend_ps(better, bp, w), cw);
        float *top = (float *)t->top; /* the ids travel as float bit patterns */
        st(top, p, _mm512_mask_blend_ps(better, ld(top, p, cw), _mm512_castsi512_ps(g->vid)), cw);
    }
#undef ACC
    st(t->T, p, _mm512_mask_blend_ps(add, Tp, test_T), cw);
}

/* All steps of one Gaussian whose box is cols x0..x1, rows y0..y1 (inside the tile). */
static inline __attribute__((always_inline)) void gaussian(const struct gauss_step *g, const struct tile_acc *t,
                                                           int tx0, int ty0, int x0, int x1, int y0, int y1,
                                                           const int aux, const int cw)
{
    const int rows = 16 / cw;
    /* lane l: column l % cw, row l / cw of the step */
    const __m512 lane_col = cw == 16 ? _mm512_setr_ps(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15)
                          : cw == 8  ? _mm512_setr_ps(0, 1, 2, 3, 4, 5, 6, 7, 0, 1, 2, 3, 4, 5, 6, 7)
                                     : _mm512_setr_ps(0, 1, 2, 3, 0, 1, 2, 3, 0, 1, 2, 3, 0, 1, 2, 3);
    const __m512 lane_row = cw == 16 ? _mm512_setzero_ps()
                          : cw == 8  ? _mm512_setr_ps(0, 0, 0, 0, 0, 0, 0, 0, 1, 1, 1, 1, 1, 1, 1, 1)
                                     : _mm512_setr_ps(0, 0, 0, 0, 1, 1, 1, 1, 2, 2, 2, 2, 3, 3, 3, 3);
    const __m512 xs = _mm512_add_ps(_mm512_set1_ps((float)x0), lane_col);
    const __m512 dx = _mm512_sub_ps(g->vmx, xs);
    const __mmask16 cmask = _mm512_cmp_ps_mask(xs, _mm512_set1_ps((float)x1), _CMP_LE_OQ);
    const __m512 adxdx = _mm512_mul_ps(_mm512_mul_ps(g->vA, dx), dx); /* A * dx * dx */
    const __m512 bdx = _mm512_mul_ps(g->vB, dx);                      /* B * dx */
    for (int y = y0; y <= y1; y += rows) {
        int left = 0;
        for (int k = 0; k < rows; k++)
            left |= y + k <= y1 ? t->row_left[y + k - ty0] : 0;
        if (!left)
            continue;
        /* (float)y + k is exact: my - that is the scalar dy of row y + k */
        const __m512 ys = _mm512_add_ps(_mm512_set1_ps((float)y), lane_row);
        const __m512 vdy = _mm512_sub_ps(g->vmy, ys);
        const __mmask16 m0 = cmask & _mm512_cmp_ps_mask(ys, _mm512_set1_ps((float)y1), _CMP_LE_OQ);
        step(g, t, (y - ty0) * SPLAT_TILE + x0 - tx0, y - ty0, m0, adxdx, bdx, vdy, aux, cw);
    }
}

static inline __attribute__((always_inline)) void raster_tile(const struct raster_job *j, int tile, const int aux)
{
    const struct raster_ctx *r = &j->rc;
    const int W = r->width, H = r->height;
    const int tx0 = (tile % r->tiles_x) * SPLAT_TILE, ty0 = (tile / r->tiles_x) * SPLAT_TILE;
    const int tw = (W - tx0 < SPLAT_TILE) ? W - tx0 : SPLAT_TILE;
    const int th = (H - ty0 < SPLAT_TILE) ? H - ty0 : SPLAT_TILE;
    /* slack: a 16-wide step may read 15 pixels past its row's end, and a
     * step's rows may run 3 past the tile's last (lanes masked, values kept) */
    enum { N = SPLAT_TILE * SPLAT_TILE, NP = N + 4 * SPLAT_TILE };
    float T[NP], C0[NP], C1[NP], C2[NP], D[NP], best[NP], done[NP];
    int32_t top[NP];
    int row_left[SPLAT_TILE + 4];
    for (int p = 0; p < NP; p++) {
        T[p] = 1.0f;
        C0[p] = C1[p] = C2[p] = done[p] = 0.0f;
    }
    if (aux) /* without depth and top nothing reads these (splat__tile_write neither) */
        for (int p = 0; p < NP; p++) {
            D[p] = best[p] = 0.0f;
            top[p] = -1;
        }
    for (int y = 0; y < SPLAT_TILE + 4; y++)
        row_left[y] = y < th ? tw : 0;
    int remaining = tw * th;
    const struct tile_acc acc = { T, C0, C1, C2, D, best, done, top, row_left, &remaining };
    const uint32_t s = r->tile_start[tile], e = r->tile_start[tile + 1];
    for (uint32_t k = s; k < e && remaining > 0; k++) {
        if (k + 6 < e)
            _mm_prefetch((const char *)(r->proj + r->pairs[k + 6]), _MM_HINT_T0);
        const struct projected *P = r->proj + r->pairs[k];
        const float mx = P->mx, my = P->my;
        float fy0 = ceilf(my - P->ey), fy1 = floorf(my + P->ey);
        int y0 = fy0 > (float)ty0 ? (int)fy0 : ty0;
        int y1 = fy1 < (float)(ty0 + th - 1) ? (int)fy1 : ty0 + th - 1;
        if (y0 > y1)
            continue;
        const float fx0 = ceilf(mx - P->ex), fx1 = floorf(mx + P->ex);
        const int x0 = fx0 > (float)tx0 ? (int)fx0 : tx0;
        const int x1 = fx1 < (float)(tx0 + tw - 1) ? (int)fx1 : tx0 + tw - 1;
        if (x0 > x1)
            continue;
        const struct gauss_step g = {
            .vo = _mm512_set1_ps(P->o), .vcut = _mm512_set1_ps(-0.5f * P->k2 - 0.001f), .vz = _mm512_set1_ps(P->z),
            .cr = _mm512_set1_ps(P->col[0]), .cg = _mm512_set1_ps(P->col[1]), .cb = _mm512_set1_ps(P->col[2]),
            .vA = _mm512_set1_ps(P->A), .vB = _mm512_set1_ps(P->B), .vC = _mm512_set1_ps(P->C),
            .vmx = _mm512_set1_ps(mx), .vmy = _mm512_set1_ps(my), .vid = _mm512_set1_epi32(P->id)
        };
        const int w = x1 - x0 + 1;
        if (w <= 4)
            gaussian(&g, &acc, tx0, ty0, x0, x1, y0, y1, aux, 4);
        else if (w <= 8)
            gaussian(&g, &acc, tx0, ty0, x0, x1, y0, y1, aux, 8);
        else
            gaussian(&g, &acc, tx0, ty0, x0, x1, y0, y1, aux, 16);
    }
    if (!aux && j->rgba8 && !j->rgb && !j->alpha)
        write_rgba8(j, tile, T, C0, C1, C2);
    else
        splat__tile_write(j, tile, T, C0, C1, C2, D, top);
}

void splat__raster_tile_avx512(const struct raster_job *j, int tile)
{
    if (j->top)
        raster_tile(j, tile, AUX_DEPTH | AUX_TOP);
    else if (j->depth)
        raster_tile(j, tile, AUX_DEPTH);
    else
        raster_tile(j, tile, 0);
}
