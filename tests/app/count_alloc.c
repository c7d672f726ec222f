/* count_alloc.c: LD_PRELOAD library for tests/app (case alloc): counts every
 * malloc / calloc / realloc / posix_memalign / aligned_alloc of the process
 * and prints the total on stderr at exit ("F4D_ALLOC_COUNT n"). Two runs of
 * the daemon that differ only in length must print the same count: nothing
 * is allocated per set or per key. */
#define _GNU_SOURCE
#include <dlfcn.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <unistd.h>

static atomic_ulong count;
static void *(*real_malloc)(size_t);
static void *(*real_calloc)(size_t, size_t);
static void *(*real_realloc)(void *, size_t);
static int (*real_memalign)(void **, size_t, size_t);
static void *(*real_aligned)(size_t, size_t);

/* dlsym itself may calloc before real_calloc is known: serve it from here */
static _Alignas(16) char boot[4096];
static size_t boot_used;

void *malloc(size_t n)
{
    if (!real_malloc)
        real_malloc = (void *(*)(size_t))dlsym(RTLD_NEXT, "malloc");
    atomic_fetch_add(&count, 1);
    return real_malloc(n);
}

void *calloc(size_t a, size_t b)
{
    if (!real_calloc) {
        size_t need = (a * b + 15) & ~(size_t)15;
        if (boot_used + need <= sizeof boot) {
            void *p = boot + boot_used;
            boot_used += need;
            real_calloc = (void *(*)(size_t, size_t))dlsym(RTLD_NEXT, "calloc");
            return p;
        }
        return NULL;
    }
    atomic_fetch_add(&count, 1);
    return real_calloc(a, b);
}

void *realloc(void *p, size_t n)
{
    if (!real_realloc)
        real_realloc = (void *(*)(void *, size_t))dlsym(RTLD_NEXT, "realloc");
    atomic_fetch_add(&count, 1);
    return real_realloc(p, n);
}

int posix_memalign(void **p, size_t al, size_t n)
{
    if (!real_memalign)
        real_memalign = (int (*)(void **, size_t, size_t))dlsym(RTLD_NEXT, "posix_memalign");
    atomic_fetch_add(&count, 1);
    return real_memalign(p, al, n);
}

void *aligned_alloc(size_t al, size_t n)
{
    if (!real_aligned)
        real_aligned = (void *(*)(size_t, size_t))dlsym(RTLD_NEXT, "aligned_alloc");
    atomic_fetch_add(&count, 1);
    return real_aligned(al, n);
}

void free(void *p)
{
    static void (*real_free)(void *);
    if ((char *)p >= boot && (char *)p < boot + sizeof boot)
        return;
    if (!real_free)
        real_free = (void (*)(void *))dlsym(RTLD_NEXT, "free");
    real_free(p);
}

__attribute__((destructor)) static void report(void)
{
    char b[64];
    int n = snprintf(b, sizeof b, "F4D_ALLOC_COUNT %lu\n", (unsigned long)atomic_load(&count));
    if (n > 0)
        (void)!write(2, b, (size_t)n);
}
