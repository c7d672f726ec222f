/* prep_avx2.c - render.c's per-Gaussian preprocessing for 8 Gaussians at
 * once (AVX2). Every value is computed with the scalar path's operations in
 * the same order and without contraction, so the projected records are
 * identical to the reference's. */
#include <immintrin.h>
#include <math.h>
#include <string.h>

#include "../render_internal.h"

static inline __m256 finite_mask(__m256 x)
{
    return _mm256_cmp_ps(_mm256_sub_ps(x, x), _mm256_setzero_ps(), _CMP_EQ_OQ);
}

static inline __m256 neg(__m256 x)
{
    return _mm256_xor_ps(x, _mm256_set1_ps(-0.0f)); /* exactly -x, as the scalar unary minus */
}

static inline __m256 gather(const float *base, __m256i idx)
{
    return _mm256_i32gather_ps(base, idx, 4);
}

/* clampf(v, lo, hi) of render.c for finite v and lo <= hi */
static inline __m256 clamp(__m256 v, __m256 lo, __m256 hi)
{
    return _mm256_max_ps(_mm256_min_ps(v, hi), lo);
}

#define MUL _mm256_mul_ps
#define ADD _mm256_add_ps
#define SUB _mm256_sub_ps
#define SET _mm256_set1_ps

unsigned splat__prep8_avx2(const struct prep_view *pv, size_t i0)
{
    const struct splat_frame *f = pv->f;
    const float *V = pv->V;
    const __m256i lane = _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7);
    const __m256i i3 = _mm256_mullo_epi32(lane, _mm256_set1_epi32(3));
    const __m256i i4 = _mm256_slli_epi32(lane, 2);
    const float *pos = f->pos + 3 * i0, *rot = f->rot + 4 * i0, *scl = f->scale + 3 * i0;
    __m256 px = gather(pos, i3), py = gather(pos + 1, i3), pz = gather(pos + 2, i3);
    __m256 tx = ADD(ADD(ADD(MUL(SET(V[0]), px), MUL(SET(V[1]), py)), MUL(SET(V[2]), pz)), SET(V[3]));
    __m256 ty = ADD(ADD(ADD(MUL(SET(V[4]), px), MUL(SET(V[5]), py)), MUL(SET(V[6]), pz)), SET(V[7]));
    __m256 tz = ADD(ADD(ADD(MUL(SET(V[8]), px), MUL(SET(V[9]), py)), MUL(SET(V[10]), pz)), SET(V[11]));
    __m256 vis = _mm256_cmp_ps(tz, SET(SPLAT_NEAR), _CMP_GT_OQ);
    vis = _mm256_and_ps(vis, _mm256_and_ps(finite_mask(tx), _mm256_and_ps(finite_mask(ty), finite_mask(tz))));
    __m256 o = _mm256_loadu_ps(f->opacity + i0);
    vis = _mm256_and_ps(vis, _mm256_cmp_ps(o, SET(SPLAT_ALPHA_MIN), _CMP_GE_OQ));
    if (_mm256_testz_ps(vis, vis))
        return 0;

    /* rotation: normalised quaternion, identity for zero or non-finite */
    __m256 qw = gather(rot, i4), qx = gather(rot + 1, i4), qy = gather(rot + 2, i4), qz = gather(rot + 3, i4);
    __m256 n2 = ADD(ADD(ADD(MUL(qw, qw), MUL(qx, qx)), MUL(qy, qy)), MUL(qz, qz));
    __m256 qok = _mm256_and_ps(_mm256_cmp_ps(n2, SET(1e-30f), _CMP_GT_OQ), finite_mask(n2));
    __m256 inv = _mm256_div_ps(SET(1.0f), _mm256_sqrt_ps(n2));
    qw = _mm256_blendv_ps(SET(1.0f), MUL(qw, inv), qok);
    qx = _mm256_and_ps(MUL(qx, inv), qok);
    qy = _mm256_and_ps(MUL(qy, inv), qok);
    qz = _mm256_and_ps(MUL(qz, inv), qok);
    const __m256 one = SET(1.0f), two = SET(2.0f);
    __m256 R[9];
    R[0] = SUB(one, MUL(two, ADD(MUL(qy, qy), MUL(qz, qz))));
    R[1] = MUL(two, SUB(MUL(qx, qy), MUL(qw, qz)));
    R[2] = MUL(two, ADD(MUL(qx, qz), MUL(qw, qy)));
    R[3] = MUL(two, ADD(MUL(qx, qy), MUL(qw, qz)));
    R[4] = SUB(one, MUL(two, ADD(MUL(qx, qx), MUL(qz, qz))));
    R[5] = MUL(two, SUB(MUL(qy, qz), MUL(qw, qx)));
    R[6] = MUL(two, SUB(MUL(qx, qz), MUL(qw, qy)));
    R[7] = MUL(two, ADD(MUL(qy, qz), MUL(qw, qx)));
    R[8] = SUB(one, MUL(two, ADD(MUL(qx, qx), MUL(qy, qy))));
    __m256 s[3] = { gather(scl, i3), gather(scl + 1, i3), gather(scl + 2, i3) };
    __m256 M[9];
    for (int a = 0; a < 3; a++)
        for (int b = 0; b < 3; b++)
            M[3 * a + b] = MUL(R[3 * a + b], s[b]);
    __m256 S0 = ADD(ADD(MUL(M[0], M[0]), MUL(M[1], M[1])), MUL(M[2], M[2]));
    __m256 S1 = ADD(ADD(MUL(M[0], M[3]), MUL(M[1], M[4])), MUL(M[2], M[5]));
    __m256 S2 = ADD(ADD(MUL(M[0], M[6]), MUL(M[1], M[7])), MUL(M[2], M[8]));
    __m256 S3 = ADD(ADD(MUL(M[3], M[3]), MUL(M[4], M[4])), MUL(M[5], M[5]));
    __m256 S4 = ADD(ADD(MUL(M[3], M[6]), MUL(M[4], M[7])), MUL(M[5], M[8]));
    __m256 S5 = ADD(ADD(MUL(M[6], M[6]), MUL(M[7], M[7])), MUL(M[8], M[8]));

    /* EWA with the clamped tangent */
    const __m256 fx = SET(pv->fx), fy = SET(pv->fy);
    __m256 cxp = MUL(clamp(_mm256_div_ps(tx, tz), SET(-pv->lim_x_neg), SET(pv->lim_x_pos)), tz);
    __m256 cyp = MUL(clamp(_mm256_div_ps(ty, tz), SET(-pv->lim_y_neg), SET(pv->lim_y_pos)), tz);
    __m256 tz2 = MUL(tz, tz);
    __m256 J00 = _mm256_div_ps(fx, tz), J02 = _mm256_div_ps(neg(MUL(fx, cxp)), tz2);
    __m256 J11 = _mm256_div_ps(fy, tz), J12 = _mm256_div_ps(neg(MUL(fy, cyp)), tz2);
    __m256 T0[3], T1[3];
    for (int k = 0; k < 3; k++) {
        T0[k] = ADD(MUL(J00, SET(V[k])), MUL(J02, SET(V[8 + k])));
        T1[k] = ADD(MUL(J11, SET(V[4 + k])), MUL(J12, SET(V[8 + k])));
    }
    __m256 ST0[3] = { ADD(ADD(MUL(S0, T0[0]), MUL(S1, T0[1])), MUL(S2, T0[2])),
                      ADD(ADD(MUL(S1, T0[0]), MUL(S3, T0[1])), MUL(S4, T0[2])),
                      ADD(ADD(MUL(S2, T0[0]), MUL(S4, T0[1])), MUL(S5, T0[2])) };
    __m256 ST1[3] = { ADD(ADD(MUL(S0, T1[0]), MUL(S1, T1[1])), MUL(S2, T1[2])),
                      ADD(ADD(MUL(S1, T1[0]), MUL(S3, T1[1])), MUL(S4, T1[2])),
                      ADD(ADD(MUL(S2, T1[0]), MUL(S4, T1[1])), MUL(S5, T1[2])) };
    __m256 a = ADD(ADD(ADD(MUL(T0[0], ST0[0]), MUL(T0[1], ST0[1])), MUL(T0[2], ST0[2])), SET(SPLAT_DILATION));
    __m256 b = ADD(ADD(MUL(T0[0], ST1[0]), MUL(T0[1], ST1[1])), MUL(T0[2], ST1[2]));
    __m256 c = ADD(ADD(ADD(MUL(T1[0], ST1[0]), MUL(T1[1], ST1[1])), MUL(T1[2], ST1[2])), SET(SPLAT_DILATION));
    __m256 det = SUB(MUL(a, c), MUL(b, b));
    vis = _mm256_and_ps(vis, _mm256_and_ps(_mm256_cmp_ps(det, _mm256_setzero_ps(), _CMP_GT_OQ), finite_mask(det)));
    __m256 det_inv = _mm256_div_ps(one, det);
    __m256 mid = MUL(SET(0.5f), ADD(a, c));
    __m256 d2 = SUB(MUL(mid, mid), det);
    __m256 disc = _mm256_sqrt_ps(_mm256_max_ps(d2, SET(0.1f))); /* NaN d2 -> 0.1 like the scalar ?: */
    __m256 lam = ADD(mid, disc);
    __m256 radius = _mm256_ceil_ps(MUL(SET(3.0f), _mm256_sqrt_ps(lam)));
    vis = _mm256_and_ps(vis, finite_mask(radius));
    __m256 pw = _mm256_div_ps(one, ADD(tz, SET(0.0000001f)));
    __m256 mx = SUB(ADD(MUL(MUL(fx, tx), pw), SET(pv->cx)), SET(0.5f));
    __m256 my = SUB(ADD(MUL(MUL(fy, ty), pw), SET(pv->cy)), SET(0.5f));
    vis = _mm256_and_ps(vis, _mm256_and_ps(finite_mask(mx), finite_mask(my)));
    if (_mm256_testz_ps(vis, vis))
        return 0;
    const __m256 zero = _mm256_setzero_ps(), tile = SET((float)SPLAT_TILE), tm1 = SET((float)(SPLAT_TILE - 1));
    const __m256 gx = SET((float)pv->tiles_x), gy = SET((float)pv->tiles_y);
    /* lanes already invisible may hold NaN: keep them out of the integer conversion */
    __m256 safe_mx = _mm256_and_ps(mx, vis), safe_my = _mm256_and_ps(my, vis), safe_r = _mm256_and_ps(radius, vis);
    __m256i x0 = _mm256_cvttps_epi32(clamp(_mm256_div_ps(SUB(safe_mx, safe_r), tile), zero, gx));
    __m256i y0 = _mm256_cvttps_epi32(clamp(_mm256_div_ps(SUB(safe_my, safe_r), tile), zero, gy));
    __m256i x1 = _mm256_cvttps_epi32(clamp(_mm256_div_ps(ADD(ADD(safe_mx, safe_r), tm1), tile), zero, gx));
    __m256i y1 = _mm256_cvttps_epi32(clamp(_mm256_div_ps(ADD(ADD(safe_my, safe_r), tm1), tile), zero, gy));
    __m256i area = _mm256_mullo_epi32(_mm256_sub_epi32(x1, x0), _mm256_sub_epi32(y1, y0));
    vis = _mm256_andnot_ps(_mm256_castsi256_ps(_mm256_cmpeq_epi32(area, _mm256_setzero_si256())), vis);
    unsigned mask = (unsigned)_mm256_movemask_ps(vis);
    if (!mask)
        return 0;

    /* k2 with libm's logf per lane, as prep_one; then the alpha box and the
     * rectangle narrowed to it, the operations of splat__narrow_rect */
    float A_[8], B_[8], C_[8], mx_[8], my_[8], z_[8], o_[8], k2_[8], ex_[8], ey_[8];
    int32_t x0_[8], y0_[8], x1_[8], y1_[8];
    _mm256_storeu_ps(o_, o);
    for (int l = 0; l < 8; l++) {
        float k2 = mask >> l & 1 ? 2.0f * logf(255.0f * o_[l]) : 0.0f;
        k2_[l] = k2 > 0.0f ? k2 : 0.0f;
    }
    const __m256 vk2 = _mm256_loadu_ps(k2_), vis_a = _mm256_and_ps(a, vis), vis_c = _mm256_and_ps(c, vis);
    const __m256 ey = ADD(MUL(_mm256_sqrt_ps(MUL(vk2, vis_c)), SET(1.0001f)), SET(0.001f));
    const __m256 ex = ADD(MUL(_mm256_sqrt_ps(MUL(vk2, vis_a)), SET(1.0001f)), SET(0.001f));
    _mm256_storeu_ps(ey_, ey);
    _mm256_storeu_ps(ex_, ex);
    const __m256 inv_tile = SET(1.0f / (float)SPLAT_TILE);
    __m256 bx0 = _mm256_floor_ps(MUL(_mm256_ceil_ps(SUB(safe_mx, ex)), inv_tile));
    __m256 bx1 = ADD(_mm256_floor_ps(MUL(_mm256_floor_ps(ADD(safe_mx, ex)), inv_tile)), one);
    __m256 by0 = _mm256_floor_ps(MUL(_mm256_ceil_ps(SUB(safe_my, ey)), inv_tile));
    __m256 by1 = ADD(_mm256_floor_ps(MUL(_mm256_floor_ps(ADD(safe_my, ey)), inv_tile)), one);
    x0 = _mm256_max_epi32(x0, _mm256_cvttps_epi32(clamp(bx0, zero, gx)));
    x1 = _mm256_min_epi32(x1, _mm256_cvttps_epi32(clamp(bx1, zero, gx)));
    y0 = _mm256_max_epi32(y0, _mm256_cvttps_epi32(clamp(by0, zero, gy)));
    y1 = _mm256_min_epi32(y1, _mm256_cvttps_epi32(clamp(by1, zero, gy)));
    vis = _mm256_and_ps(vis, _mm256_castsi256_ps(_mm256_and_si256(_mm256_cmpgt_epi32(x1, x0),
                                                                  _mm256_cmpgt_epi32(y1, y0))));
    mask = (unsigned)_mm256_movemask_ps(vis);
    if (!mask)
        return 0;
    _mm256_storeu_ps(A_, MUL(c, det_inv));
    _mm256_storeu_ps(B_, MUL(neg(b), det_inv));
    _mm256_storeu_ps(C_, MUL(a, det_inv));
    _mm256_storeu_ps(mx_, mx);
    _mm256_storeu_ps(my_, my);
    _mm256_storeu_ps(z_, tz);
    _mm256_storeu_si256((__m256i *)x0_, x0);
    _mm256_storeu_si256((__m256i *)y0_, y0);
    _mm256_storeu_si256((__m256i *)x1_, x1);
    _mm256_storeu_si256((__m256i *)y1_, y1);
    for (int l = 0; l < 8; l++) {
        if (!(mask >> l & 1))
            continue;
        size_t i = i0 + (size_t)l;
        struct projected *P = pv->proj + i;
        P->mx = mx_[l];
        P->my = my_[l];
        P->A = A_[l];
        P->B = B_[l];
        P->C = C_[l];
        P->o = o_[l];
        P->k2 = k2_[l];
        P->ey = ey_[l];
        P->ex = ex_[l];
        P->z = z_[l];
        const float *col = pv->features ? pv->features + 3 * i : f->rgb + 3 * i;
        for (int k = 0; k < 3; k++)
            P->col[k] = pv->features ? col[k] : (col[k] > 0.0f ? col[k] : 0.0f);
        P->rect[0] = (int16_t)x0_[l];
        P->rect[1] = (int16_t)y0_[l];
        P->rect[2] = (int16_t)x1_[l];
        P->rect[3] = (int16_t)y1_[l];
        P->id = (int32_t)i;
    }
    return mask;
}
