/* use_fk.c: a consumer of the installed kernel library, built only from what
 * `pkg-config --cflags --libs forge4d-kernels` gives (tests/install). */
#include <math.h>
#include <stdio.h>

#include <f4d_status.h>
#include <fk_ctx.h>
#include <fk_ops.h>

int main(void)
{
    fk_ctx *ctx = NULL;
    struct fk_ctx_config cfg = {.isa = FK_ISA_AUTO, .threads = 2};
    if (fk_ctx_new(&cfg, &ctx) != F4D_OK) {
        fprintf(stderr, "fk_ctx_new failed\n");
        return 1;
    }
    /* softmax of one row {0, ln 3}: {0.25, 0.75} */
    float x[2] = {0.0f, logf(3.0f)}, y[2] = {0, 0};
    int rc = fk_softmax(ctx, x, 1, 2, 2, y, 2);
    if (rc != F4D_OK || fabsf(y[0] - 0.25f) > 1e-6f || fabsf(y[1] - 0.75f) > 1e-6f) {
        fprintf(stderr, "fk_softmax: rc %d (%s), y = %g %g: %s\n", rc, f4d_status_name(rc), y[0], y[1],
                fk_ctx_error(ctx));
        fk_ctx_free(ctx);
        return 1;
    }
    /* a bad call is refused with a status, not a crash */
    rc = fk_softmax(ctx, NULL, 1, 2, 2, y, 2);
    if (rc != F4D_EINVAL) {
        fprintf(stderr, "fk_softmax(NULL) gave %d, want F4D_EINVAL\n", rc);
        fk_ctx_free(ctx);
        return 1;
    }
    printf("use_fk: isa %s, softmax ok, NULL refused (%s)\n", fk_isa_name(fk_ctx_isa(ctx)), f4d_status_name(rc));
    fk_ctx_free(ctx);
    return 0;
}
