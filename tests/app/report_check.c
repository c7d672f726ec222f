/* report_check DIR [--motion]: checks what `forge4d report` left in DIR.
 *   report.json parses; every point has every figure (a number, or null only
 *   where a figure may be missing); the Pareto front (key_hz up, novel-view
 *   PSNR up) is non-empty, each front point is non-dominated and each other
 *   point is dominated, and "front" lists exactly the on_front points; the
 *   baseline is f32 with all patches and motion on at the largest input; a
 *   point with motion off has no motion error (its keys carry none); the goal line
 *   agrees with the points; report.md names the CPU, the front and the goal;
 *   pareto.png, bitrate.png and display.png decode (libpng) and are not blank.
 *   --motion: the weights had motion and some motion error was measured.
 * Exit 0 when all hold, 1 with one line per failure. */
#include <cjson/cJSON.h>
#include <math.h>
#include <png.h>
#include <stdbool.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static int fails;

#define CHECK(cond, ...)                                                                                           \
    do {                                                                                                           \
        if (!(cond)) {                                                                                             \
            fprintf(stderr, "report_check: " __VA_ARGS__);                                                        \
            fputc('\n', stderr);                                                                                   \
            fails++;                                                                                               \
        }                                                                                                          \
    } while (0)

static char *slurp(const char *path)
{
    FILE *f = fopen(path, "rb");
    if (!f)
        return NULL;
    fseek(f, 0, SEEK_END);
    long n = ftell(f);
    fseek(f, 0, SEEK_SET);
    char *b = malloc((size_t)n + 1);
    if (b && fread(b, 1, (size_t)n, f) != (size_t)n) {
        free(b);
        b = NULL;
    }
    if (b)
        b[n] = '\0';
    fclose(f);
    return b;
}

static void check_png(const char *dir, const char *name)
{
    char path[4096];
    snprintf(path, sizeof path, "%s/%s", dir, name);
    png_image im;
    memset(&im, 0, sizeof im);
    im.version = PNG_IMAGE_VERSION;
    if (!png_image_begin_read_from_file(&im, path)) {
        CHECK(0, "%s: not a PNG (%s)", path, im.message);
        return;
    }
    im.format = PNG_FORMAT_RGB;
    size_t n = PNG_IMAGE_SIZE(im);
    unsigned char *px = malloc(n);
    if (!px || !png_image_finish_read(&im, NULL, px, 0, NULL)) {
        CHECK(0, "%s: cannot decode (%s)", path, im.message);
        free(px);
        png_image_free(&im);
        return;
    }
    CHECK(im.width >= 200 && im.height >= 150, "%s: %ux%u is too small for a plot", path, im.width, im.height);
    size_t ink = 0, colour = 0;
    for (size_t i = 0; i + 2 < n; i += 3) {
        ink += px[i] < 200 || px[i + 1] < 200 || px[i + 2] < 200;
        colour += abs((int)px[i] - (int)px[i + 2]) > 60;
    }
    CHECK(ink > 2000, "%s: nearly blank (%zu dark pixels)", path, ink);
    CHECK(colour > 50, "%s: no coloured markers (%zu coloured pixels)", path, colour);
    free(px);
}

static double get(const cJSON *o, const char *k, bool *ok)
{
    const cJSON *v = cJSON_GetObjectItem(o, k);
    if (cJSON_IsNumber(v))
        return v->valuedouble;
    *ok = cJSON_IsNull(v);
    return NAN;
}

int main(int argc, char **argv)
{
    if (argc < 2) {
        fprintf(stderr, "usage: report_check DIR [--motion]\n");
        return 2;
    }
    const char *dir = argv[1];
    bool want_motion = argc > 2 && !strcmp(argv[2], "--motion");
    char path[4096];
    snprintf(path, sizeof path, "%s/report.json", dir);
    char *js = slurp(path);
    if (!js) {
        fprintf(stderr, "report_check: cannot read %s\n", path);
        return 1;
    }
    cJSON *root = cJSON_Parse(js);
    free(js);
    if (!root) {
        fprintf(stderr, "report_check: %s does not parse as JSON\n", path);
        return 1;
    }
    const cJSON *cpu = cJSON_GetObjectItem(root, "cpu"), *pts = cJSON_GetObjectItem(root, "points");
    const cJSON *front = cJSON_GetObjectItem(root, "front"), *goal = cJSON_GetObjectItem(root, "goal");
    const cJSON *base = cJSON_GetObjectItem(root, "baseline"), *motion = cJSON_GetObjectItem(root, "motion");
    CHECK(cJSON_IsString(cpu) && cpu->valuestring[0], "no \"cpu\"");
    CHECK(cJSON_IsArray(cJSON_GetObjectItem(root, "takes")) &&
              cJSON_GetArraySize(cJSON_GetObjectItem(root, "takes")) > 0, "no \"takes\"");
    int n = cJSON_IsArray(pts) ? cJSON_GetArraySize(pts) : 0;
    CHECK(n >= 2, "fewer than 2 points (%d)", n);
    CHECK(cJSON_IsArray(front) && cJSON_IsObject(goal) && cJSON_IsNumber(base) && cJSON_IsBool(motion),
          "missing \"front\", \"goal\", \"baseline\" or \"motion\"");
    /* the speed axis is one of the two clocks, named */
    const cJSON *clk = cJSON_GetObjectItem(root, "clock");
    CHECK(cJSON_IsString(clk) && (!strcmp(clk->valuestring, "cpu") || !strcmp(clk->valuestring, "wall")),
          "no \"clock\" (cpu or wall)");
    const char *key_clock = cJSON_IsString(clk) && !strcmp(clk->valuestring, "wall") ? "key_wall_ms" : "key_cpu_ms";
    if (fails) {
        cJSON_Delete(root);
        return 1;
    }
    /* every figure; null only where it may be missing (no mid times, no motion) */
    static const char *const must[] = {"key_ms", "key_hz", "key_wall_ms", "key_cpu_ms", "model_ms", "model_cpu_ms",
                                       "model_process_cpu_ms", "budget_ms", "budget_cpu_ms", "encode_ms",
                                       "encode_cpu_ms", "decode_ms", "wall_speedup_vs_baseline",
                                       "cpu_speedup_vs_baseline",
                                       "tokens_ran_fraction", "gaussians_per_key", "bytes_per_key",
                                       "mbps_at_take_rate", "novel_view_psnr", "novel_view_ssim", "point_dist_m",
                                       "rot_err_deg", "trans_err_m", "speedup_vs_baseline",
                                       "dpsnr_vs_baseline_db"};
    static const char *const may[] = {"display_frame_ms", "display_pair_ms", "novel_time_psnr", "novel_time_ssim",
                                      "motion_epe_m"};
    static const char *const str[] = {"precision", "tokens", "motion", "budget", "codec"};
    double *hz = calloc((size_t)n, sizeof *hz), *ps = calloc((size_t)n, sizeof *ps);
    bool *on = calloc((size_t)n, sizeof *on);
    int motion_pts = 0;
    for (int i = 0; i < n; i++) {
        const cJSON *o = cJSON_GetArrayItem(pts, i);
        for (size_t k = 0; k < sizeof must / sizeof *must; k++) {
            bool ok = false;
            double v = get(o, must[k], &ok);
            CHECK(isfinite(v), "point %d: \"%s\" is not a number", i, must[k]);
        }
        for (size_t k = 0; k < sizeof may / sizeof *may; k++) {
            bool ok = true;
            get(o, may[k], &ok);
            CHECK(ok, "point %d: \"%s\" is neither a number nor null", i, may[k]);
        }
        for (size_t k = 0; k < sizeof str / sizeof *str; k++)
            CHECK(cJSON_IsString(cJSON_GetObjectItem(o, str[k])), "point %d: no \"%s\"", i, str[k]);
        bool ok;
        CHECK(get(o, "input_w", &ok) >= 14 && get(o, "input_h", &ok) >= 14, "point %d: no input size", i);
        const cJSON *f = cJSON_GetObjectItem(o, "on_front");
        CHECK(cJSON_IsBool(f), "point %d: no \"on_front\"", i);
        on[i] = cJSON_IsTrue(f);
        hz[i] = get(o, "key_hz", &ok);
        ps[i] = get(o, "novel_view_psnr", &ok);
        CHECK(hz[i] > 0, "point %d: key_hz %g", i, hz[i]);
        CHECK(get(o, "model_cpu_ms", &ok) > 0 && get(o, "model_ms", &ok) > 0, "point %d: no model time", i);
        CHECK(fabs(hz[i] * get(o, "key_ms", &ok) - 1e3) < 1e-3 * 1e3, "point %d: key_hz and key_ms disagree", i);
        CHECK(get(o, "key_ms", &ok) == get(o, key_clock, &ok), "point %d: key_ms is not %s", i, key_clock);
        CHECK(get(o, "key_cpu_ms", &ok) >= get(o, "model_cpu_ms", &ok), "point %d: key CPU time below the model's", i);
        motion_pts += isfinite(get(o, "motion_epe_m", &ok));
        const cJSON *mo = cJSON_GetObjectItem(o, "motion");
        if (cJSON_IsString(mo)) {
            CHECK(!strcmp(mo->valuestring, "on") || !strcmp(mo->valuestring, "off"), "point %d: motion \"%s\"", i,
                  mo->valuestring);
            CHECK(strcmp(mo->valuestring, "off") || !isfinite(get(o, "motion_epe_m", &ok)),
                  "point %d: motion off but a motion error", i);
        }
    }
    /* the front, recomputed */
    int nf = 0;
    for (int i = 0; i < n; i++) {
        int dom = -1;
        for (int j = 0; j < n && dom < 0; j++)
            if (j != i && hz[j] >= hz[i] && ps[j] >= ps[i] && (hz[j] > hz[i] || ps[j] > ps[i]))
                dom = j;
        if (on[i]) {
            nf++;
            CHECK(dom < 0, "point %d is on the front but point %d dominates it", i, dom);
        } else {
            CHECK(dom >= 0, "point %d is off the front but nothing dominates it", i);
        }
    }
    CHECK(nf > 0, "the Pareto front is empty");
    CHECK(cJSON_GetArraySize(front) == nf, "\"front\" lists %d points, %d are on_front", cJSON_GetArraySize(front),
          nf);
    for (int k = 0; k < cJSON_GetArraySize(front); k++) {
        const cJSON *v = cJSON_GetArrayItem(front, k);
        int i = cJSON_IsNumber(v) ? (int)v->valuedouble : -1;
        CHECK(i >= 0 && i < n && on[i], "\"front\" names point %d, which is not on_front", i);
    }
    /* baseline and goal */
    int b = (int)base->valuedouble;
    CHECK(b >= 0 && b < n, "baseline %d out of range", b);
    if (b >= 0 && b < n) {
        const cJSON *o = cJSON_GetArrayItem(pts, b);
        bool ok;
        const cJSON *bm = cJSON_GetObjectItem(o, "motion");
        CHECK(!strcmp(cJSON_GetObjectItem(o, "precision")->valuestring, "f32") &&
                  !strcmp(cJSON_GetObjectItem(o, "tokens")->valuestring, "all") && cJSON_IsString(bm) &&
                  !strcmp(bm->valuestring, "on"),
              "baseline %d is not f32 with all patches and motion on", b);
        for (int i = 0; i < n; i++)
            CHECK(get(cJSON_GetArrayItem(pts, i), "input_w", &ok) <= get(o, "input_w", &ok),
                  "point %d has a larger input than the baseline", i);
        int want = -1;
        for (int i = 0; i < n; i++)
            if (on[i] && hz[i] >= 3.0 * hz[b] * (1 - 1e-9) && ps[i] >= ps[b] - 1.0)
                want = i;
        const cJSON *met = cJSON_GetObjectItem(goal, "met");
        CHECK(cJSON_IsBool(met) && cJSON_IsTrue(met) == (want >= 0), "goal \"met\" disagrees with the points");
        const cJSON *gp = cJSON_GetObjectItem(goal, "point");
        if (cJSON_IsTrue(met) && cJSON_IsNumber(gp)) {
            int g = (int)gp->valuedouble;
            CHECK(g >= 0 && g < n && on[g] && hz[g] >= 3.0 * hz[b] * (1 - 1e-9) && ps[g] >= ps[b] - 1.0,
                  "goal point %d does not meet the goal", g);
        }
    }
    if (want_motion) {
        CHECK(cJSON_IsTrue(motion), "the weights should have motion");
        CHECK(motion_pts > 0, "no point has a motion error");
    }
    /* report.md */
    snprintf(path, sizeof path, "%s/report.md", dir);
    char *md = slurp(path);
    CHECK(md != NULL, "cannot read %s", path);
    if (md) {
        CHECK(strstr(md, cpu->valuestring) != NULL, "report.md does not name the CPU (%s)", cpu->valuestring);
        CHECK(strstr(md, "Pareto front") != NULL, "report.md does not mark the Pareto front");
        CHECK(strstr(md, "**Goal met**") || strstr(md, "**Goal not met**"), "report.md has no goal line");
        int rows = 0;
        for (const char *p = md; (p = strstr(p, "\n| ")) != NULL; p++)
            rows++;
        CHECK(rows >= n + 1, "report.md has %d table rows for %d points", rows, n);
        free(md);
    }
    check_png(dir, "pareto.png");
    check_png(dir, "bitrate.png");
    check_png(dir, "display.png");
    free(hz);
    free(ps);
    free(on);
    cJSON_Delete(root);
    if (fails)
        return 1;
    printf("report_check: %s: %d points, %d on the front, plots decode\n", dir, n, nf);
    return 0;
}
