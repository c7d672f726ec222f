/* pool.h - fork/join thread pool behind fk_parallel_for. */
#ifndef FK_POOL_H
#define FK_POOL_H

#include "../fk_ctx.h"

struct fk_pool;

struct fk_pool *fk__pool_new (int threads);   /* threads - 1 workers are started */
void            fk__pool_free(struct fk_pool *p);
/* Runs fn(arg, task, thread) for every task; the caller is thread 0. */
void            fk__pool_run (struct fk_pool *p, int n_tasks, fk_task_fn fn, void *arg);

#endif
