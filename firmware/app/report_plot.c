/* report_plot.c: the report's scatter plots as PNG through cairo (Debian's
 * libcairo2-dev): axes with ticks, one colour per series, open or filled
 * markers, the Pareto front as a line, a legend. Text uses cairo's toy font
 * API (fontconfig picks a sans face). */
#include <cairo.h>
#include <fontconfig/fontconfig.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>

#include "report_internal.h"

#define PW 960
#define PH 620
#define ML 80.0
#define MR 230.0
#define MT 50.0
#define MB 70.0

static const double palette[REPORT_SERIES_MAX][3] = {
    {0.12, 0.47, 0.71}, {1.00, 0.50, 0.05}, {0.17, 0.63, 0.17}, {0.84, 0.15, 0.16},
    {0.58, 0.40, 0.74}, {0.55, 0.34, 0.29}, {0.89, 0.47, 0.76}, {0.50, 0.50, 0.50},
};

struct axis {
    double lo, hi;
    bool log;
};

static double tx(const struct axis *a, double v)
{
    double lo = a->log ? log10(a->lo) : a->lo, hi = a->log ? log10(a->hi) : a->hi;
    double u = a->log ? log10(v) : v;
    return (u - lo) / (hi - lo);
}

static bool usable(const struct report_plot *p, int i)
{
    return isfinite(p->x[i]) && isfinite(p->y[i]) && (!p->log_x || p->x[i] > 0);
}

static double px(const struct axis *ax, double v) { return ML + tx(ax, v) * (PW - ML - MR); }
static double py(const struct axis *ay, double v) { return PH - MB - tx(ay, v) * (PH - MT - MB); }

static void marker(cairo_t *cr, double x, double y, const double *rgb, bool hollow, double r)
{
    cairo_new_path(cr);
    cairo_arc(cr, x, y, r, 0, 2 * M_PI);
    cairo_set_source_rgb(cr, rgb[0], rgb[1], rgb[2]);
    if (hollow) {
        cairo_set_line_width(cr, 1.8);
        cairo_stroke(cr);
    } else {
        cairo_fill(cr);
    }
}

static void text(cairo_t *cr, double x, double y, const char *s, double size, double align)
{
    cairo_text_extents_t e;
    cairo_set_font_size(cr, size);
    cairo_text_extents(cr, s, &e);
    cairo_move_to(cr, x - align * e.width, y);
    cairo_show_text(cr, s);
}

/* Tick step of about `want` ticks over [lo, hi]: 1, 2 or 5 x 10^k. */
static double nice_step(double lo, double hi, int want)
{
    double raw = (hi - lo) / want, m = pow(10.0, floor(log10(raw)));
    double f = raw / m;
    return (f < 1.5 ? 1 : f < 3.5 ? 2 : f < 7.5 ? 5 : 10) * m;
}

static void ticks(cairo_t *cr, const struct axis *a, bool xaxis)
{
    char buf[32];
    cairo_set_source_rgb(cr, 0.2, 0.2, 0.2);
    cairo_set_line_width(cr, 1.0);
    double vals[64];
    int n = 0;
    if (a->log) { /* 1-2-5 per decade; every integer multiple when the range is under a decade */
        static const double wide[] = {1, 2, 5}, narrow[] = {1, 1.5, 2, 3, 4, 5, 6, 7, 8, 9};
        bool nar = a->hi / a->lo < 10;
        const double *mul = nar ? narrow : wide;
        int nm = nar ? 10 : 3;
        for (int k = (int)floor(log10(a->lo)) - 1; k <= (int)ceil(log10(a->hi)) && n < 60; k++)
            for (int j = 0; j < nm && n < 60; j++) {
                double v = mul[j] * pow(10.0, k);
                if (v >= a->lo && v <= a->hi)
                    vals[n++] = v;
            }
    } else {
        double st = nice_step(a->lo, a->hi, 6);
        for (double v = ceil(a->lo / st) * st; v <= a->hi + 1e-9 * st && n < 60; v += st)
            vals[n++] = v;
    }
    for (int i = 0; i < n; i++) {
        double v = vals[i];
        snprintf(buf, sizeof buf, fabs(v) >= 100 || v == floor(v) ? "%.0f" : fabs(v) >= 1 ? "%.1f" : "%.2g", v);
        if (xaxis) {
            double x = px(a, v);
            cairo_move_to(cr, x, PH - MB);
            cairo_line_to(cr, x, PH - MB + 6);
            cairo_stroke(cr);
            text(cr, x, PH - MB + 20, buf, 12, 0.5);
        } else {
            double y = py(a, v);
            cairo_move_to(cr, ML - 6, y);
            cairo_line_to(cr, ML, y);
            cairo_stroke(cr);
            text(cr, ML - 9, y + 4, buf, 12, 1.0);
        }
    }
}

int report_plot_write(const struct report_plot *p, struct f4d_err *err)
{
    struct axis ax = {INFINITY, -INFINITY, p->log_x}, ay = {INFINITY, -INFINITY, false};
    int m = 0;
    for (int i = 0; i < p->n; i++) {
        if (!usable(p, i))
            continue;
        m++;
        ax.lo = fmin(ax.lo, p->x[i]), ax.hi = fmax(ax.hi, p->x[i]);
        ay.lo = fmin(ay.lo, p->y[i]), ay.hi = fmax(ay.hi, p->y[i]);
    }
    if (!m) { /* nothing measurable (e.g. no mid times): an empty frame that says so */
        ax = (struct axis){1, 10, p->log_x};
        ay = (struct axis){0, 1, false};
    }
    if (ax.log) {
        double f = ax.hi > ax.lo ? pow(ax.hi / ax.lo, 0.06) : 1.5;
        ax.lo /= f, ax.hi *= f;
    } else {
        double d = ax.hi > ax.lo ? 0.06 * (ax.hi - ax.lo) : fmax(0.5, 0.1 * fabs(ax.lo));
        ax.lo -= d, ax.hi += d;
    }
    double d = ay.hi > ay.lo ? 0.08 * (ay.hi - ay.lo) : 0.5;
    ay.lo -= d, ay.hi += d;

    cairo_surface_t *sf = cairo_image_surface_create(CAIRO_FORMAT_RGB24, PW, PH);
    cairo_t *cr = cairo_create(sf);
    cairo_set_source_rgb(cr, 1, 1, 1);
    cairo_paint(cr);
    cairo_select_font_face(cr, "sans-serif", CAIRO_FONT_SLANT_NORMAL, CAIRO_FONT_WEIGHT_NORMAL);
    /* frame, ticks, labels */
    cairo_set_source_rgb(cr, 0.2, 0.2, 0.2);
    cairo_set_line_width(cr, 1.2);
    cairo_rectangle(cr, ML, MT, PW - ML - MR, PH - MT - MB);
    cairo_stroke(cr);
    ticks(cr, &ax, true);
    ticks(cr, &ay, false);
    cairo_set_source_rgb(cr, 0, 0, 0);
    text(cr, ML + 0.5 * (PW - ML - MR), 30, p->title, 16, 0.5);
    text(cr, ML + 0.5 * (PW - ML - MR), PH - 22, p->xlabel, 13, 0.5);
    cairo_save(cr);
    cairo_translate(cr, 22, MT + 0.5 * (PH - MT - MB));
    cairo_rotate(cr, -M_PI / 2);
    text(cr, 0, 0, p->ylabel, 13, 0.5);
    cairo_restore(cr);
    if (!m)
        text(cr, ML + 0.5 * (PW - ML - MR), MT + 0.5 * (PH - MT - MB), "no measurable points", 14, 0.5);
    /* the front, as a line in x order */
    int *ord = malloc((size_t)(p->n ? p->n : 1) * sizeof *ord), nf = 0;
    if (!ord) {
        cairo_destroy(cr);
        cairo_surface_destroy(sf);
        return f4d_fail(err, F4D_ENOMEM, "plot: out of memory");
    }
    for (int i = 0; i < p->n; i++)
        if (p->front[i] && usable(p, i))
            ord[nf++] = i;
    for (int k = 1; k < nf; k++) /* x order (insertion sort: a front has few points) */
        for (int j = k; j > 0 && p->x[ord[j - 1]] > p->x[ord[j]]; j--) {
            int tmp = ord[j];
            ord[j] = ord[j - 1];
            ord[j - 1] = tmp;
        }
    if (nf) {
        cairo_set_source_rgb(cr, 0.1, 0.1, 0.1);
        cairo_set_line_width(cr, 1.5);
        for (int k = 0; k < nf; k++) {
            double x = px(&ax, p->x[ord[k]]), y = py(&ay, p->y[ord[k]]);
            if (k == 0)
                cairo_move_to(cr, x, y);
            else
                cairo_line_to(cr, x, y);
        }
        cairo_stroke(cr);
    }
    cairo_save(cr);
    cairo_rectangle(cr, ML, MT, PW - ML - MR, PH - MT - MB);
    cairo_clip(cr);
    for (int i = 0; i < p->n; i++) {
        if (!usable(p, i))
            continue;
        double x = px(&ax, p->x[i]), y = py(&ay, p->y[i]);
        int s = p->series[i] >= 0 && p->series[i] < REPORT_SERIES_MAX ? p->series[i] : REPORT_SERIES_MAX - 1;
        marker(cr, x, y, palette[s], p->hollow[i], 4.5);
        if (p->front[i]) {
            cairo_new_path(cr);
            cairo_arc(cr, x, y, 8, 0, 2 * M_PI);
            cairo_set_source_rgb(cr, 0, 0, 0);
            cairo_set_line_width(cr, 1.2);
            cairo_stroke(cr);
        }
    }
    cairo_restore(cr);
    if (p->mark >= 0 && p->mark < p->n && usable(p, p->mark)) {
        double x = px(&ax, p->x[p->mark]), y = py(&ay, p->y[p->mark]);
        cairo_set_source_rgb(cr, 0.8, 0, 0);
        cairo_set_line_width(cr, 2);
        cairo_move_to(cr, x - 10, y - 10);
        cairo_line_to(cr, x + 10, y + 10);
        cairo_move_to(cr, x - 10, y + 10);
        cairo_line_to(cr, x + 10, y - 10);
        cairo_stroke(cr);
        text(cr, x + 12, y - 12, p->mark_label, 12, 0);
    }
    /* legend */
    double lx = PW - MR + 20, ly = MT + 10;
    cairo_set_source_rgb(cr, 0, 0, 0);
    for (int s = 0; s < p->n_series && s < REPORT_SERIES_MAX; s++, ly += 22) {
        marker(cr, lx + 6, ly, palette[s], false, 5);
        cairo_set_source_rgb(cr, 0, 0, 0);
        text(cr, lx + 18, ly + 4, p->series_name[s] ? p->series_name[s] : "?", 13, 0);
    }
    ly += 8;
    if (p->solid_name) {
        marker(cr, lx + 6, ly, palette[REPORT_SERIES_MAX - 1], false, 5);
        cairo_set_source_rgb(cr, 0, 0, 0);
        text(cr, lx + 18, ly + 4, p->solid_name, 13, 0);
        ly += 22;
    }
    if (p->hollow_name) {
        marker(cr, lx + 6, ly, palette[REPORT_SERIES_MAX - 1], true, 5);
        cairo_set_source_rgb(cr, 0, 0, 0);
        text(cr, lx + 18, ly + 4, p->hollow_name, 13, 0);
        ly += 22;
    }
    if (nf) {
        cairo_set_source_rgb(cr, 0.1, 0.1, 0.1);
        cairo_set_line_width(cr, 1.5);
        cairo_move_to(cr, lx, ly);
        cairo_line_to(cr, lx + 14, ly);
        cairo_stroke(cr);
        text(cr, lx + 18, ly + 4, "Pareto front", 13, 0);
    }
    free(ord);
    cairo_destroy(cr);
    cairo_surface_flush(sf);
    cairo_status_t st = cairo_surface_write_to_png(sf, p->path);
    cairo_surface_destroy(sf);
    if (st != CAIRO_STATUS_SUCCESS)
        return f4d_fail(err, F4D_EIO, "plot: cannot write %s: %s", p->path, cairo_status_to_string(st));
    return 0;
}

void report_plot_done(void)
{
    /* cairo's toy font faces hold fontconfig patterns, and fontconfig its
     * configuration, until these: a leak checker would report them otherwise
     * (no surface may be alive; the process draws no text afterwards) */
    cairo_debug_reset_static_data();
    FcFini();
}
