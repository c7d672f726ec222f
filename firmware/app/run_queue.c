/* run_queue.c: the daemon's bounded pointer FIFO (run_internal.h). The ring
 * is allocated at init; push and pop never allocate. */
#include <stdlib.h>

#include "run_internal.h"

int run_fifo_init(struct run_fifo *q, uint32_t cap, struct f4d_err *err)
{
    q->items = cap ? calloc(cap, sizeof *q->items) : NULL;
    if (!q->items)
        return f4d_fail(err, F4D_ENOMEM, "run: queue of %u items: out of memory", cap);
    q->cap = cap;
    q->head = q->n = q->peak = 0;
    q->closed = false;
    pthread_mutex_init(&q->mu, NULL);
    pthread_cond_init(&q->cv, NULL);
    return 0;
}

void run_fifo_destroy(struct run_fifo *q)
{
    if (!q->items)
        return;
    pthread_mutex_destroy(&q->mu);
    pthread_cond_destroy(&q->cv);
    free(q->items);
    q->items = NULL;
}

static void push_locked(struct run_fifo *q, void *item)
{
    q->items[(q->head + q->n) % q->cap] = item;
    q->n++;
    if (q->n > q->peak)
        q->peak = q->n;
    pthread_cond_signal(&q->cv);
}

static void *pop_locked(struct run_fifo *q)
{
    void *it = q->items[q->head];
    q->head = (q->head + 1) % q->cap;
    q->n--;
    return it;
}

bool run_fifo_try_push(struct run_fifo *q, void *item)
{
    pthread_mutex_lock(&q->mu);
    bool ok = q->n < q->cap;
    if (ok)
        push_locked(q, item);
    pthread_mutex_unlock(&q->mu);
    return ok;
}

void *run_fifo_push_evict(struct run_fifo *q, void *item)
{
    pthread_mutex_lock(&q->mu);
    void *old = q->n == q->cap ? pop_locked(q) : NULL;
    push_locked(q, item);
    pthread_mutex_unlock(&q->mu);
    return old;
}

void *run_fifo_try_pop(struct run_fifo *q)
{
    pthread_mutex_lock(&q->mu);
    void *it = q->n ? pop_locked(q) : NULL;
    pthread_mutex_unlock(&q->mu);
    return it;
}

int run_fifo_pop(struct run_fifo *q, void **item)
{
    pthread_mutex_lock(&q->mu);
    while (q->n == 0 && !q->closed)
        pthread_cond_wait(&q->cv, &q->mu);
    int got = q->n > 0;
    if (got)
        *item = pop_locked(q);
    pthread_mutex_unlock(&q->mu);
    return got;
}

void run_fifo_close(struct run_fifo *q)
{
    pthread_mutex_lock(&q->mu);
    q->closed = true;
    pthread_cond_broadcast(&q->cv);
    pthread_mutex_unlock(&q->mu);
}

uint32_t run_fifo_depth(struct run_fifo *q)
{
    pthread_mutex_lock(&q->mu);
    uint32_t n = q->n;
    pthread_mutex_unlock(&q->mu);
    return n;
}
