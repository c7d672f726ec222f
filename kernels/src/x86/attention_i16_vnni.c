/* attention_i16_vnni.c - the int16 attention's two integer products with
 * AVX-VNNI's VEX vpdpwssd (the pair products' sum added in the same
 * instruction), for attention_i16_avx2.c's tasks on an AVX2-VNNI context
 * (Alder Lake-N class: int8 GEMMs at 3.5x fp32, attention would be fp32
 * FMAs). The tiles of the AVX2 file with vpmaddwd + vpaddd fused: the int32
 * sums are exact either way and the float steps are the AVX2 tiles', in
 * their order: the same bits as AVX2 (tested). */
#include <immintrin.h>

#include "../attention_plan.h"
#include "../fk_internal.h"

#define MR FK_ATTN_MR
#define NR FK_ATTN_NR
#define BK FK_ATTN_BK

/* acc += pairs t . b in place; {vex}: the plain mnemonic assembles to the
 * EVEX (AVX512_VNNI) form, which an AVX-VNNI CPU without AVX-512 lacks. The
 * asm names the accumulator as the destination (with the intrinsic GCC may
 * copy sums through spare registers, as it did for the AVX2 tiles). */
#define I16_DOT(acc, t, b) __asm__("%{vex%} vpdpwssd %2, %1, %0" : "+x"(acc) : "x"(t), "x"(b))
#include "attention_i16_tiles.h"

void fk__attn_i16_s_block_vnni(int dp, int kv, const uint32_t *q, const uint32_t *kb, const float *sq,
                               const float *sk, float *s)
{
    s_block(dp, kv, q, kb, sq, sk, s);
}

void fk__attn_i16_pv_tile_vnni(int dp, int kv, const uint32_t *p, const uint32_t *v, const float *sv, float *o,
                               const float *alpha, const float *ps)
{
    pv_tile(dp, kv, p, v, sv, o, alpha, ps);
}
