/* f4d-metrics - image quality of B against A, as 3DGS evaluates it:
 *   f4d-metrics A.png B.png [--json]
 * prints "psnr=<dB> ssim=<value>" or {"psnr": x, "ssim": y}. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "splat.h"

int main(int argc, char **argv)
{
    const char *pa = NULL, *pb = NULL;
    int json = 0;
    for (int i = 1; i < argc; i++) {
        if (!strcmp(argv[i], "--json"))
            json = 1;
        else if (!strcmp(argv[i], "-h") || !strcmp(argv[i], "--help")) {
            printf("usage: f4d-metrics A.png B.png [--json]\n"
                   "  PSNR and SSIM (11x11 Gaussian window, sigma 1.5, as 3DGS) of B against A.\n");
            return 0;
        } else if (argv[i][0] == '-' && argv[i][1]) {
            fprintf(stderr, "f4d-metrics: unknown option '%s'\n", argv[i]);
            return 2;
        } else if (!pa)
            pa = argv[i];
        else if (!pb)
            pb = argv[i];
        else {
            fprintf(stderr, "f4d-metrics: too many arguments ('%s')\n", argv[i]);
            return 2;
        }
    }
    if (!pa || !pb) {
        fprintf(stderr, "usage: f4d-metrics A.png B.png [--json]\n");
        return 2;
    }
    struct f4d_err err = {0};
    float *a = NULL, *b = NULL;
    int wa, ha, wb, hb, rc = 1;
    if (splat_png_read_rgb(pa, &a, &wa, &ha, &err) < 0 || splat_png_read_rgb(pb, &b, &wb, &hb, &err) < 0) {
        fprintf(stderr, "f4d-metrics: %s\n", err.msg);
        goto done;
    }
    if (wa != wb || ha != hb) {
        fprintf(stderr, "f4d-metrics: sizes differ: '%s' is %dx%d, '%s' is %dx%d\n", pa, wa, ha, pb, wb, hb);
        goto done;
    }
    double psnr = splat_psnr(a, b, wa, ha, 3);
    double ssim = splat_ssim(a, b, wa, ha, 3, NULL);
    if (isnan(ssim)) {
        fprintf(stderr, "f4d-metrics: out of memory computing SSIM\n");
        goto done;
    }
    /* identical images: PSNR is infinite; JSON has no infinity, so print null */
    if (json) {
        if (isinf(psnr))
            printf("{\"psnr\": null, \"ssim\": %.6f}\n", ssim);
        else
            printf("{\"psnr\": %.4f, \"ssim\": %.6f}\n", psnr, ssim);
    } else {
        printf("psnr=%.4f ssim=%.6f\n", psnr, ssim);
    }
    rc = 0;
done:
    free(a);
    free(b);
    return rc;
}
