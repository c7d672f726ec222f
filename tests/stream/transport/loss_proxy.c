/* loss_proxy.c - see loss_proxy.h. */
#include "loss_proxy.h"

#include <arpa/inet.h>
#include <errno.h>
#include <netinet/in.h>
#include <poll.h>
#include <stdio.h>
#include <string.h>
#include <sys/socket.h>
#include <time.h>
#include <unistd.h>

static double now_ms(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec * 1e3 + (double)ts.tv_nsec * 1e-6;
}

static double uniform(uint64_t *s)
{
    *s ^= *s >> 12;
    *s ^= *s << 25;
    *s ^= *s >> 27;
    return (double)((*s * 0x2545F4914F6CDD1DULL) >> 11) * 0x1.0p-53;
}

static struct sockaddr_in loopback(int port)
{
    struct sockaddr_in a;
    memset(&a, 0, sizeof a);
    a.sin_family = AF_INET;
    a.sin_port = htons((uint16_t)port);
    a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    return a;
}

int loss_proxy_bind(const struct loss_proxy_cfg *c, int *fd_out)
{
    int fd = socket(AF_INET, SOCK_DGRAM, 0);
    struct sockaddr_in a = loopback(c->listen_port);
    if (fd < 0 || bind(fd, (struct sockaddr *)&a, sizeof a) != 0) {
        fprintf(stderr, "loss_proxy: bind 127.0.0.1:%d: %s\n", c->listen_port, strerror(errno));
        if (fd >= 0)
            close(fd);
        return -1;
    }
    *fd_out = fd;
    return 0;
}

int loss_proxy_run(const struct loss_proxy_cfg *c, int fa, atomic_int *stop, struct loss_proxy_stats *st)
{
    int fb = socket(AF_INET, SOCK_DGRAM, 0);
    struct sockaddr_in target = loopback(c->target_port), client;
    socklen_t clen = 0;
    if (fb < 0 || connect(fb, (struct sockaddr *)&target, sizeof target) != 0) {
        fprintf(stderr, "loss_proxy: target 127.0.0.1:%d: %s\n", c->target_port, strerror(errno));
        if (fb >= 0)
            close(fb);
        close(fa);
        return -1;
    }
    /* room for a key frame's burst of chunks while the relay thread waits */
    int big = 4 << 20;
    setsockopt(fa, SOL_SOCKET, SO_RCVBUF, &big, sizeof big);
    setsockopt(fb, SOL_SOCKET, SO_RCVBUF, &big, sizeof big);
    /* one generator per direction: which datagrams are dropped then depends
     * only on the seed and each direction's own count, not on how the two
     * directions interleave (with one shared generator a run could drop
     * nothing on the way back; the tests expect losses both ways) */
    uint64_t seed = c->seed ? c->seed : 0x9E3779B97F4A7C15ULL;
    uint64_t rng[2] = { seed, seed ^ 0xD1B54A32D192ED03ULL };
    double t_first = -1;
    memset(st, 0, sizeof *st);
    unsigned char buf[2048];
    while (!atomic_load(stop)) {
        struct pollfd p[2] = { { fa, POLLIN, 0 }, { fb, POLLIN, 0 } };
        if (poll(p, 2, 20) <= 0)
            continue;
        for (int k = 0; k < 2; k++) {
            if (!(p[k].revents & POLLIN))
                continue;
            struct sockaddr_in from;
            socklen_t flen = sizeof from;
            ssize_t n = k == 0 ? recvfrom(fa, buf, sizeof buf, 0, (struct sockaddr *)&from, &flen)
                               : recv(fb, buf, sizeof buf, 0);
            if (n < 0)
                continue;
            if (k == 0) {
                client = from;
                clen = flen;
            }
            double t = now_ms();
            if (t_first < 0)
                t_first = t;
            double since = t - t_first;
            int out = c->blackout_at_ms >= 0 && since >= c->blackout_at_ms &&
                      since < c->blackout_at_ms + c->blackout_ms;
            if (out || uniform(&rng[k]) < c->loss) {
                if (k == 0)
                    st->dropped_fwd++;
                else
                    st->dropped_back++;
                continue;
            }
            if (k == 0) {
                if (send(fb, buf, (size_t)n, 0) == n)
                    st->fwd++;
            } else if (clen && sendto(fa, buf, (size_t)n, 0, (struct sockaddr *)&client, clen) == n) {
                st->back++;
            }
        }
    }
    close(fa);
    close(fb);
    return 0;
}
