/* loss_proxy_main.c - udp_loss_proxy LISTEN_PORT TARGET_PORT LOSS [SEED]
 * [BLACKOUT_AT_MS BLACKOUT_MS]: the test relay as a program, for scripts and
 * measurements (see loss_proxy.h). Runs until SIGTERM / SIGINT, then prints
 * its counters as one JSON line. */
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>

#include "loss_proxy.h"

static atomic_int g_stop; /* set by the signal handler */

static void on_signal(int s)
{
    (void)s;
    atomic_store(&g_stop, 1);
}

int main(int argc, char **argv)
{
    if (argc != 4 && argc != 5 && argc != 7) {
        fprintf(stderr, "usage: udp_loss_proxy LISTEN_PORT TARGET_PORT LOSS [SEED [BLACKOUT_AT_MS BLACKOUT_MS]]\n");
        return 2;
    }
    struct loss_proxy_cfg c = { atoi(argv[1]), atoi(argv[2]), atof(argv[3]), argc > 4 ? strtoull(argv[4], NULL, 10) : 1,
                                argc > 5 ? atoi(argv[5]) : -1, argc > 5 ? atoi(argv[6]) : 0 };
    if (c.listen_port <= 0 || c.target_port <= 0 || !(c.loss >= 0 && c.loss < 1)) {
        fprintf(stderr, "udp_loss_proxy: ports must be > 0 and LOSS in [0, 1)\n");
        return 2;
    }
    struct sigaction sa = { 0 };
    sa.sa_handler = on_signal;
    sigaction(SIGTERM, &sa, NULL);
    sigaction(SIGINT, &sa, NULL);
    int fd;
    struct loss_proxy_stats st;
    if (loss_proxy_bind(&c, &fd) < 0 || loss_proxy_run(&c, fd, &g_stop, &st) < 0)
        return 1;
    printf("{\"proxy_loss\":%.4f,\"fwd\":%llu,\"back\":%llu,\"dropped_fwd\":%llu,\"dropped_back\":%llu}\n", c.loss,
           (unsigned long long)st.fwd, (unsigned long long)st.back, (unsigned long long)st.dropped_fwd,
           (unsigned long long)st.dropped_back);
    return 0;
}
