/* gemm_plan.c - job planning shared by the ISA GEMM drivers (x86/gemm_avx2.c,
 * arm/gemm_neon.c): plain C, no ISA flags. */
#include "fk_internal.h"
#include "gemm.h"

#define MR FK_GEMM_MR

int fk__gemm_plan_mc(int threads, int m, int mc, int min_mc)
{
    /* Enough tasks for all threads: shrink mc (the panels are split after). */
    int m_pad = (int)fk__round_up((size_t)m, MR);
    if (threads > 1 && m_pad < 4 * threads * mc) {
        int want = (int)fk__round_up((size_t)((m_pad + 4 * threads - 1) / (4 * threads)), MR);
        mc = want < min_mc && m_pad >= min_mc ? min_mc : (want < mc ? want : mc);
    }
    if (mc > m_pad)
        mc = m_pad;
    return mc;
}

void fk__gemm_plan_chunks(int threads, int m_blocks, int panels, int *n_chunks,
                          int *panels_per_chunk)
{
    int nc = 1;
    if (threads > 1 && m_blocks < 4 * threads) {
        int chunks = (4 * threads + m_blocks - 1) / m_blocks;
        int max_chunks = panels / 4 > 0 ? panels / 4 : 1;
        nc = chunks < max_chunks ? chunks : max_chunks;
    }
    int ppc = (panels + nc - 1) / nc;
    *panels_per_chunk = ppc;
    *n_chunks = (panels + ppc - 1) / ppc;
}
