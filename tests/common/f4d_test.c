/* f4d_test.c: see f4d_test.h. */
#define _XOPEN_SOURCE 700 /* nftw */
#include "f4d_test.h"

#include <arpa/inet.h>
#include <fnmatch.h>
#include <ftw.h>
#include <netinet/in.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <time.h>
#include <unistd.h>

#define SEL_MAX 32

static const char *keep[SEL_MAX], *drop[SEL_MAX];
static int n_keep, n_drop;
static bool parsed, list_only;
static unsigned skips;

void f4d_test_note_skip(const char *fmt, ...)
{
    char why[512];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(why, sizeof why, fmt, ap);
    va_end(ap);
    skips++;
    fprintf(stderr, "[  SKIP    ] %s\n", why);
    fflush(stderr);
}

int f4d_test_parse(int argc, char **argv)
{
    if (parsed)
        return argc;
    parsed = true;
    int out = 1;
    for (int i = 1; i < argc; i++) {
        const char *a = argv[i];
        if (strcmp(a, "--case") == 0 || strcmp(a, "--not") == 0) {
            if (i + 1 >= argc) {
                fprintf(stderr, "%s: %s needs a case name (glob)\n", argv[0], a);
                return -1;
            }
            bool is_keep = a[2] == 'c';
            if ((is_keep ? n_keep : n_drop) >= SEL_MAX) {
                fprintf(stderr, "%s: more than %d %s options\n", argv[0], SEL_MAX, a);
                return -1;
            }
            if (is_keep)
                keep[n_keep++] = argv[++i];
            else
                drop[n_drop++] = argv[++i];
        } else if (strcmp(a, "--list") == 0) {
            list_only = true;
        } else {
            argv[out++] = argv[i];
        }
    }
    argv[out] = NULL;
    return out;
}

bool f4d_test_selected(const char *name)
{
    bool in = n_keep == 0;
    for (int i = 0; i < n_keep && !in; i++)
        in = fnmatch(keep[i], name, 0) == 0;
    for (int i = 0; i < n_drop && in; i++)
        in = fnmatch(drop[i], name, 0) != 0;
    return in;
}

int f4d_test_run(int argc, char **argv, const char *group, const struct CMUnitTest *tests, size_t n,
                 CMFixtureFunction setup, CMFixtureFunction teardown)
{
    if (f4d_test_parse(argc, argv) < 0)
        return 2;
    /* every --case pattern must name a case: a typo is an error, not an empty pass */
    for (int k = 0; k < n_keep; k++) {
        bool hit = false;
        for (size_t i = 0; i < n && !hit; i++)
            hit = fnmatch(keep[k], tests[i].name, 0) == 0;
        if (!hit) {
            fprintf(stderr, "%s: --case '%s' matches no case of %s\n", argv[0], keep[k], group);
            return 2;
        }
    }
    for (int k = 0; k < n_drop; k++) {
        bool hit = false;
        for (size_t i = 0; i < n && !hit; i++)
            hit = fnmatch(drop[k], tests[i].name, 0) == 0;
        if (!hit) {
            fprintf(stderr, "%s: --not '%s' matches no case of %s\n", argv[0], drop[k], group);
            return 2;
        }
    }
    struct CMUnitTest *sel = calloc(n ? n : 1, sizeof *sel);
    if (!sel)
        return 1;
    size_t m = 0;
    for (size_t i = 0; i < n; i++)
        if (f4d_test_selected(tests[i].name))
            sel[m++] = tests[i];
    if (list_only) {
        for (size_t i = 0; i < m; i++)
            printf("%s\n", sel[i].name);
        free(sel);
        return 0;
    }
    if (m == 0) {
        fprintf(stderr, "%s: the selection keeps no case of %s\n", argv[0], group);
        free(sel);
        return 2;
    }
    int failed = _cmocka_run_group_tests(group, sel, m, setup, teardown);
    free(sel);
    if (failed != 0)
        return 1;
    if (skips > 0) {
        fprintf(stderr, "[  SKIP    ] %s: %u case(s) skipped (exit %d)\n", group, skips, F4D_TEST_SKIPPED);
        return F4D_TEST_SKIPPED;
    }
    return 0;
}

int f4d_test_mkdtemp(char *out, size_t n, const char *tag)
{
    const char *base = getenv("TMPDIR");
    if (!base || !*base)
        base = "/tmp";
    int len = snprintf(out, n, "%s/f4d_%s_XXXXXX", base, tag);
    if (len < 0 || (size_t)len >= n)
        return -1;
    return mkdtemp(out) ? 0 : -1;
}

static int rm_one(const char *path, const struct stat *sb, int flag, struct FTW *ftw)
{
    (void)sb; (void)flag; (void)ftw;
    return remove(path);
}

int f4d_test_rmtree(const char *dir)
{
    if (!dir || !*dir)
        return 0;
    return nftw(dir, rm_one, 16, FTW_DEPTH | FTW_PHYS);
}

/* ---- loopback ports ---- */
static bool udp_port_free(int port)
{
    int fd = socket(AF_INET, SOCK_DGRAM, 0);
    if (fd < 0)
        return false;
    struct sockaddr_in a;
    memset(&a, 0, sizeof a);
    a.sin_family = AF_INET;
    a.sin_port = htons((uint16_t)port);
    a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    bool ok = bind(fd, (struct sockaddr *)&a, sizeof a) == 0;
    close(fd);
    return ok;
}

int f4d_test_udp_ports(int first, int count, int n)
{
    if (n < 1 || count < n || first < 1 || first + count > 65536)
        return -1;
    int slots = count / n;
    int start = (int)(getpid() % slots);
    for (int i = 0; i < slots; i++) {
        int base = first + ((start + i) % slots) * n;
        bool all = true;
        for (int k = 0; k < n && all; k++)
            all = udp_port_free(base + k);
        if (all)
            return base;
    }
    return -1;
}

/* Is `port` among the local ports in /proc/net/udp (or udp6)? */
static bool udp_port_listed(const char *table, int port)
{
    FILE *f = fopen(table, "r");
    if (!f)
        return false;
    char line[512];
    bool found = false;
    if (!fgets(line, sizeof line, f)) { /* the header */
        fclose(f);
        return false;
    }
    while (!found && fgets(line, sizeof line, f)) {
        const char *colon = strchr(line, ':');        /* after "sl" */
        colon = colon ? strchr(colon + 1, ':') : NULL; /* in local_address */
        found = colon && (int)strtol(colon + 1, NULL, 16) == port;
    }
    fclose(f);
    return found;
}

static bool process_alive(int pid)
{
    if (kill(pid, 0) != 0)
        return false;
    char path[64], buf[256];
    snprintf(path, sizeof path, "/proc/%d/stat", pid);
    FILE *f = fopen(path, "r");
    if (!f)
        return false;
    size_t len = fread(buf, 1, sizeof buf - 1, f);
    fclose(f);
    buf[len] = 0;
    const char *rp = strrchr(buf, ')'); /* the state follows the command name */
    return !(rp && rp[1] == ' ' && rp[2] == 'Z');
}

bool f4d_test_wait_udp(int port, int pid, int seconds)
{
    for (long ms = 0; ms <= (long)seconds * 1000; ms += 20) {
        if (udp_port_listed("/proc/net/udp", port) || udp_port_listed("/proc/net/udp6", port))
            return true;
        if (pid > 0 && !process_alive(pid))
            return false;
        struct timespec d = {0, 20000000L};
        nanosleep(&d, NULL);
    }
    return false;
}
