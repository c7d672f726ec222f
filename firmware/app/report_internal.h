/* report_internal.h: `forge4d report`, the speed-vs-error study (report.c)
 * and its plots (report_plot.c, cairo). App-internal: only report*.c and
 * forge4d_main.c include it.
 *
 *     forge4d report [--quick] -o DIR --take TAKE [--take TAKE ...]
 *                    [--weights W] [--clock cpu|wall] [--threads N] [--keys N]
 *                    [--reps N] [--precision L] [--size L] [--tokens L]
 *                    [--budget L] [--codec L]
 *
 * Every grid point (precision x input size x token budget x Gaussian budget
 * x codec level) runs the appliance's path on each venue take: model (with
 * state and motion when the weights have them) -> scene budget -> stream
 * encoder -> the display's player (decode, interpolation) -> a render, and
 * is scored against the take's ground truth (firmware/gaussians/score).
 * Time per key (the speed axis): the key path's CPU time on one kernel thread
 * (--clock cpu, the default) or its wall time (--clock wall); both printed.
 * DIR gets report.md, report.json and the PNG plots.
 *
 *     struct report_plot p = {.path = "pareto.png", .title = ..., .n = n, .x = x, .y = y, ...};
 *     report_plot_write(&p, &err);
 */
#ifndef F4D_REPORT_INTERNAL_H
#define F4D_REPORT_INTERNAL_H

#include <signal.h>
#include <stdbool.h>

#include "f4d_status.h"

int forge4d_report_main(int argc, char **argv, volatile sig_atomic_t *stop);

#define REPORT_SERIES_MAX 8

/* One scatter plot: n points (x, y), each in series[i] (colour + legend),
 * hollow[i] draws an open marker, front[i] joins the point to the line
 * through the front (drawn in x order); mark (or -1) is labelled "mark_label". */
struct report_plot {
    const char *path, *title, *xlabel, *ylabel;
    int n;
    const double *x, *y;
    const int *series;
    const bool *hollow, *front;
    bool log_x;
    int n_series;
    const char *series_name[REPORT_SERIES_MAX];
    const char *hollow_name, *solid_name; /* legend of the marker fill (NULL: none) */
    int mark;
    const char *mark_label;
};
/* PNG through cairo; F4D_EIO naming the file when it cannot be written. */
int report_plot_write(const struct report_plot *p, struct f4d_err *err);
/* Releases cairo's static caches (fonts) once every plot is written. */
void report_plot_done(void);

#endif
