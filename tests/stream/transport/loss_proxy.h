/* loss_proxy.h - a UDP relay on loopback that loses datagrams on purpose, for
 * the transport tests: the kernel here has no sch_netem (tc qdisc ... netem
 * fails with "Specified qdisc kind is unknown") and Debian's libsrt is built
 * without its fake-loss hooks, so the loss is made in user space between the
 * two SRT ends. Each datagram, in either direction, is dropped with
 * probability `loss` (xorshift64* per direction seeded from `seed`: the same
 * seed drops the same datagram numbers of each direction), and every datagram during a blackout window is
 * dropped (a link outage longer than the latency window: what ARQ cannot
 * repair). One client (the first address that writes to the proxy). */
#ifndef F4D_LOSS_PROXY_H
#define F4D_LOSS_PROXY_H

#include <stdatomic.h>
#include <stdint.h>

struct loss_proxy_cfg {
    int      listen_port;       /* 127.0.0.1:listen_port, the caller's target */
    int      target_port;       /* 127.0.0.1:target_port, the real listener   */
    double   loss;              /* per datagram, both directions              */
    uint64_t seed;
    int      blackout_at_ms;    /* after the first datagram; < 0: none        */
    int      blackout_ms;
};

struct loss_proxy_stats {
    uint64_t fwd, back;                 /* datagrams passed on   */
    uint64_t dropped_fwd, dropped_back; /* datagrams lost on purpose */
};

/* Binds the listening socket (so a caller can start right after), then
 * relays until *stop; 0, or -1 with the reason on stderr. */
int loss_proxy_bind(const struct loss_proxy_cfg *c, int *fd_out);
int loss_proxy_run(const struct loss_proxy_cfg *c, int fd, atomic_int *stop, struct loss_proxy_stats *st);

#endif
