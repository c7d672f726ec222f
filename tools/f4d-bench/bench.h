/* bench.h - f4d-bench: benchmarks that print speed beside error.
 * Each subcommand lives in its own bench_<name>.c and is listed in the table
 * of bench_main.c. Timing takes the best of several runs; every speed is
 * reported with a peer measured in the same run. */
#ifndef F4D_BENCH_H
#define F4D_BENCH_H

int bench_kernels(int argc, char **argv);
int bench_model(int argc, char **argv);
int bench_render(int argc, char **argv);
int bench_interp(int argc, char **argv);
int bench_stream(int argc, char **argv);
int bench_hal(int argc, char **argv);
int bench_codec(int argc, char **argv);
int bench_display(int argc, char **argv);
int bench_tokens(int argc, char **argv);
int bench_pairs(int argc, char **argv);

struct model_config;
/* A GGUF weight file of `groups` (model.h MODEL_G_*) with random weights that
 * keep activations in a realistic range (bench_model.c); 0 or -1 (printed). */
int bench_write_random_model(const char *path, const struct model_config *c, unsigned groups);
/* The tiny model config of the model and token benchmarks (embed 128, depth 4,
 * 126 px, DPT 32 wide on layers 0-3). */
void bench_preset_tiny(struct model_config *c);

/* Seconds on CLOCK_MONOTONIC. */
double bench_now(void);
/* CPU seconds of the calling thread (CLOCK_THREAD_CPUTIME_ID): on a shared
 * machine, time spent descheduled is not counted. */
double bench_thread_cpu_s(void);

#endif
