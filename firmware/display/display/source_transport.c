/* source_transport.c - a packet source over firmware/stream/transport: SRT
 * (caller or listener, latency window, passphrase) or its file: URLs. The
 * transport hands on only complete, CRC-valid packets and counts the rest;
 * those counts become the source's drops, SRT's negotiated TSBPD window its
 * latency. */
#include <stdlib.h>

#include "f4d_display.h"
#include "f4d_transport.h"

#define RX_WAIT_MS 2 /* a short wait per call: an idle display does not spin */

struct rx_src {
    transport_rx *rx;
    struct display_source_stats st;
};

static int rx_next(void *impl, struct codec_packet *p, struct f4d_err *err)
{
    struct rx_src *s = impl;
    int rc = transport_rx_next(s->rx, RX_WAIT_MS, p);
    if (rc == 0)
        return 1;
    if (rc == F4D_ETIMEDOUT)
        return 0;
    if (rc == F4D_EEOF)
        return F4D_EEOF;
    return f4d_fail(err, rc, "%s", transport_rx_error(s->rx));
}

static void rx_stats(const void *impl, struct display_source_stats *st)
{
    const struct rx_src *s = impl;
    struct transport_stats t;
    if (transport_rx_stats(s->rx, &t) < 0) {
        *st = s->st;
        return;
    }
    st->packets = t.packets;
    st->bytes = t.bytes;
    st->dropped = t.dropped_incomplete + t.dropped_corrupt + t.dropped_oversize;
    st->skipped_bytes = 0;
    st->latency_ms = t.connected && t.latency_ms > 0 ? (double)t.latency_ms + 0.5 * t.rtt_ms : -1.0;
}

static void rx_free(void *impl)
{
    struct rx_src *s = impl;
    transport_rx_close(s->rx);
    free(s);
}

static const struct display_source_ops rx_ops = { rx_next, rx_stats, rx_free };

int display_source_transport(const char *url, size_t max_packet, display_source **out, struct f4d_err *err)
{
    if (!url || !out)
        return f4d_fail(err, F4D_EINVAL, "display_source_transport: NULL argument");
    struct rx_src *s = calloc(1, sizeof *s);
    if (!s)
        return f4d_fail(err, F4D_ENOMEM, "display_source_transport: out of memory");
    s->st.latency_ms = -1.0;
    struct transport_opts o = { .max_packet = max_packet };
    int rc = transport_rx_open(url, &o, &s->rx, err);
    if (rc < 0) {
        free(s);
        return rc;
    }
    rc = display_source_new(&rx_ops, s, out, err);
    if (rc < 0)
        rx_free(s);
    return rc;
}
