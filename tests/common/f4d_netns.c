/* f4d_netns.c: see f4d_netns.h. */
#define _GNU_SOURCE /* unshare(CLONE_NEWNET) */
#include "f4d_netns.h"

#include <errno.h>
#include <sched.h>
#include <stdbool.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

static bool write_file(const char *path, const char *text)
{
    FILE *f = fopen(path, "w");
    if (!f)
        return false;
    bool ok = fputs(text, f) >= 0;
    return fclose(f) == 0 && ok;
}

int f4d_test_netns(int n_alias, char *why, size_t why_size)
{
    if (unshare(CLONE_NEWNET) != 0) {
        /* not root: a user namespace in which this process is root (unshare -rn) */
        char map[64];
        unsigned uid = (unsigned)getuid(), gid = (unsigned)getgid();
        if (unshare(CLONE_NEWUSER | CLONE_NEWNET) != 0 || !write_file("/proc/self/setgroups", "deny") ||
            (snprintf(map, sizeof map, "0 %u 1", uid), !write_file("/proc/self/uid_map", map)) ||
            (snprintf(map, sizeof map, "0 %u 1", gid), !write_file("/proc/self/gid_map", map))) {
            snprintf(why, why_size, "cannot make a private network namespace (unshare: %s)",
                     strerror(errno));
            return -1;
        }
    }
    char cmd[1024];
    int len = snprintf(cmd, sizeof cmd, "ip link set lo up");
    for (int i = 0; i < n_alias && len > 0 && (size_t)len < sizeof cmd; i++)
        len += snprintf(cmd + len, sizeof cmd - (size_t)len, " && ip addr add 127.0.0.%d/8 dev lo",
                        i + 2);
    if (len < 0 || (size_t)len >= sizeof cmd || system(cmd) != 0) {
        snprintf(why, why_size,
                 "cannot configure lo and its 127.0.0.2-%d aliases in the namespace (is iproute2 installed?)",
                 n_alias + 1);
        return -1;
    }
    return 0;
}
