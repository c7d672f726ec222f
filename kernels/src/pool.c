/* pool.c - a small fork/join thread pool.
 *
 * One job at a time: the caller publishes (fn, arg, n_tasks) in a job slot and
 * a new generation in `ticket` (generation << 32 | next task), wakes sleeping
 * workers, and everyone, caller included, claims tasks from `ticket` by
 * compare-and-swap. The caller then waits only for the tasks that were
 * claimed and are still running, never for a worker that has not woken up
 * yet: on a 2-core box shared with capture, recording and other processes, a
 * worker is often not scheduled for milliseconds, and a join that waited for
 * every worker to check in made 2 threads slower than 1 (f4d-bench model on
 * the shipped model at load ~8: 444-553 ms with 2 threads, 232-267 ms with 1).
 * A late worker finds the generation moved on or the tasks taken and goes
 * back to waiting.
 *
 * Claims are safe against late workers: a worker reads the job slot of the
 * generation it loaded, and its CAS on `ticket` (generation included)
 * succeeds only while that generation is current and the task unclaimed, so
 * the job cannot have finished and its slot cannot be reused in between. The
 * two slots alternate by generation: the caller writes job g + 1 into the
 * slot of job g - 1 while a late worker may still read job g's.
 * Workers spin briefly before sleeping, because on a 2-core box a futex
 * wake-up per layer costs more than the layer's tail. */
#include <pthread.h>
#include <stdatomic.h>
#include <stdint.h>
#include <stdlib.h>

#include "pool.h"

#if defined(__x86_64__) || defined(__i386__)
#include <immintrin.h>
#define cpu_relax() _mm_pause()
#else
#define cpu_relax() ((void)0)
#endif

#define SPIN_ROUNDS 4000

struct job {               /* written by the caller before its generation is published */
    _Atomic(fk_task_fn) fn;
    _Atomic(void *)     arg;
    atomic_int          n_tasks;
};

struct fk_pool {
    int              threads;
    pthread_t       *tid;
    pthread_mutex_t  mu;
    pthread_cond_t   wake;
    pthread_cond_t   done_cv;
    atomic_uint_least64_t ticket;  /* generation << 32 | next unclaimed task */
    atomic_int       done;         /* tasks of the current job finished */
    atomic_int       sleepers;     /* workers in (or about to enter) pthread_cond_wait */
    atomic_int       waiting;      /* the caller sleeps on done_cv */
    struct job       job[2];       /* job[generation & 1] */
    int              quit;
};

struct worker_arg {
    struct fk_pool *p;
    int             index;
};

static uint32_t gen_of(uint64_t t) { return (uint32_t)(t >> 32); }

/* Claims and runs tasks of generation g until none is left or the job has
 * moved on. */
static void run_tasks(struct fk_pool *p, uint32_t g, int thread)
{
    const struct job *jb = &p->job[g & 1];
    for (;;) {
        uint64_t t = atomic_load_explicit(&p->ticket, memory_order_acquire);
        if (gen_of(t) != g)
            return;
        fk_task_fn fn = atomic_load_explicit(&jb->fn, memory_order_relaxed);
        void *arg = atomic_load_explicit(&jb->arg, memory_order_relaxed);
        int n = atomic_load_explicit(&jb->n_tasks, memory_order_relaxed);
        uint32_t i = (uint32_t)t;
        if ((int64_t)i >= (int64_t)n)
            return;
        if (!atomic_compare_exchange_weak_explicit(&p->ticket, &t, t + 1, memory_order_acq_rel,
                                                   memory_order_acquire))
            continue;
        fn(arg, (int)i, thread);
        if (atomic_fetch_add_explicit(&p->done, 1, memory_order_seq_cst) + 1 == n &&
            atomic_load_explicit(&p->waiting, memory_order_seq_cst)) {
            pthread_mutex_lock(&p->mu);
            pthread_cond_signal(&p->done_cv);
            pthread_mutex_unlock(&p->mu);
        }
    }
}

static void *worker(void *v)
{
    struct worker_arg wa = *(struct worker_arg *)v;
    free(v);
    struct fk_pool *p = wa.p;
    uint32_t seen = 0;
    for (;;) {
        uint32_t g;
        int spins = 0;
        while ((g = gen_of(atomic_load_explicit(&p->ticket, memory_order_acquire))) == seen &&
               spins < SPIN_ROUNDS) {
            cpu_relax();
            spins++;
        }
        if (g == seen) {
            pthread_mutex_lock(&p->mu);
            atomic_fetch_add_explicit(&p->sleepers, 1, memory_order_seq_cst);
            while ((g = gen_of(atomic_load_explicit(&p->ticket, memory_order_seq_cst))) == seen && !p->quit)
                pthread_cond_wait(&p->wake, &p->mu);
            atomic_fetch_sub_explicit(&p->sleepers, 1, memory_order_relaxed);
            int quit = p->quit;
            pthread_mutex_unlock(&p->mu);
            if (quit)
                return NULL;
        }
        seen = g;
        run_tasks(p, g, wa.index);
    }
}

struct fk_pool *fk__pool_new(int threads)
{
    struct fk_pool *p = calloc(1, sizeof *p);
    if (!p)
        return NULL;
    p->threads = threads;
    p->tid = calloc((size_t)threads, sizeof *p->tid);
    if (!p->tid) {
        free(p);
        return NULL;
    }
    pthread_mutex_init(&p->mu, NULL);
    pthread_cond_init(&p->wake, NULL);
    pthread_cond_init(&p->done_cv, NULL);
    for (int i = 1; i < threads; i++) {
        struct worker_arg *wa = malloc(sizeof *wa);
        if (wa) {
            wa->p = p;
            wa->index = i;
        }
        if (!wa || pthread_create(&p->tid[i], NULL, worker, wa) != 0) {
            free(wa);
            p->threads = i; /* join only what started */
            fk__pool_free(p);
            return NULL;
        }
    }
    return p;
}

void fk__pool_free(struct fk_pool *p)
{
    if (!p)
        return;
    pthread_mutex_lock(&p->mu);
    p->quit = 1;
    pthread_cond_broadcast(&p->wake);
    pthread_mutex_unlock(&p->mu);
    for (int i = 1; i < p->threads; i++)
        pthread_join(p->tid[i], NULL);
    pthread_mutex_destroy(&p->mu);
    pthread_cond_destroy(&p->wake);
    pthread_cond_destroy(&p->done_cv);
    free(p->tid);
    free(p);
}

void fk__pool_run(struct fk_pool *p, int n_tasks, fk_task_fn fn, void *arg)
{
    uint32_t g = gen_of(atomic_load_explicit(&p->ticket, memory_order_relaxed)) + 1;
    struct job *jb = &p->job[g & 1];
    atomic_store_explicit(&jb->fn, fn, memory_order_relaxed);
    atomic_store_explicit(&jb->arg, arg, memory_order_relaxed);
    atomic_store_explicit(&jb->n_tasks, n_tasks, memory_order_relaxed);
    atomic_store_explicit(&p->done, 0, memory_order_relaxed);
    /* publishes the slot and the reset count; seq_cst pairs with the workers'
     * sleepers increment so that either they see the generation or we see them */
    atomic_store_explicit(&p->ticket, (uint64_t)g << 32, memory_order_seq_cst);
    if (atomic_load_explicit(&p->sleepers, memory_order_seq_cst) > 0) {
        pthread_mutex_lock(&p->mu);
        pthread_cond_broadcast(&p->wake);
        pthread_mutex_unlock(&p->mu);
    }

    run_tasks(p, g, 0);

    /* every task is claimed now: wait for the ones still running elsewhere */
    int spins = 0;
    while (atomic_load_explicit(&p->done, memory_order_acquire) < n_tasks && spins < SPIN_ROUNDS) {
        cpu_relax();
        spins++;
    }
    if (atomic_load_explicit(&p->done, memory_order_acquire) < n_tasks) {
        pthread_mutex_lock(&p->mu);
        atomic_store_explicit(&p->waiting, 1, memory_order_seq_cst);
        while (atomic_load_explicit(&p->done, memory_order_seq_cst) < n_tasks)
            pthread_cond_wait(&p->done_cv, &p->mu);
        atomic_store_explicit(&p->waiting, 0, memory_order_relaxed);
        pthread_mutex_unlock(&p->mu);
    }
}
