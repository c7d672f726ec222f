/* hal_usb_reconnect.c: the pure reconnect logic of USB cameras (see
 * hal_usb_hotplug.h): device identities, the per-camera link state machine
 * and the hub that pumps an event source into the links. No libusb, no
 * V4L2, no allocation. */
#include "hal_usb_hotplug.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

void hal_usb_id_format(const struct hal_usb_id *id, char *buf, size_t cap)
{
    snprintf(buf, cap, "%04x:%04x%s%.63s on %u-%.31s (dev %u)", id->vid, id->pid, id->serial[0] ? " serial " : "",
             id->serial, (unsigned)id->bus, id->port_path[0] ? id->port_path : "?", (unsigned)id->devnum);
}

static bool parse_hex16(const char *s, size_t n, uint16_t *out)
{
    if (n == 0 || n > 4)
        return false;
    unsigned v = 0;
    for (size_t i = 0; i < n; i++) {
        char c = s[i];
        unsigned d = c >= '0' && c <= '9' ? (unsigned)(c - '0')
                     : c >= 'a' && c <= 'f' ? (unsigned)(c - 'a' + 10)
                     : c >= 'A' && c <= 'F' ? (unsigned)(c - 'A' + 10)
                                            : 16u;
        if (d > 15)
            return false;
        v = v * 16 + d;
    }
    *out = (uint16_t)v;
    return true;
}

int hal_usb_id_parse(const char *a, struct hal_usb_id *out)
{
    memset(out, 0, sizeof *out);
    if (strncmp(a, "usb:", 4) != 0)
        return F4D_EINVAL;
    a += 4;
    const char *colon = strchr(a, ':');
    if (!colon || !parse_hex16(a, (size_t)(colon - a), &out->vid))
        return F4D_EINVAL;
    const char *p = colon + 1;
    const char *at = strchr(p, '@');
    size_t n = at ? (size_t)(at - p) : strlen(p);
    if (!parse_hex16(p, n, &out->pid))
        return F4D_EINVAL;
    if (at) {
        char *end = NULL;
        unsigned long bus = strtoul(at + 1, &end, 10);
        if (end == at + 1 || *end != '-' || bus == 0 || bus > 255 || !end[1] ||
            strlen(end + 1) >= sizeof out->port_path || strspn(end + 1, "0123456789.") != strlen(end + 1))
            return F4D_EINVAL;
        out->bus = (uint8_t)bus;
        memcpy(out->port_path, end + 1, strlen(end + 1) + 1);
    }
    return F4D_OK;
}

bool hal_usb_id_match(const struct hal_usb_id *w, const struct hal_usb_id *d)
{
    if (w->vid && w->vid != d->vid)
        return false;
    if (w->pid && w->pid != d->pid)
        return false;
    if (w->bus && w->bus != d->bus)
        return false;
    if (w->devnum && w->devnum != d->devnum)
        return false;
    if (w->port_path[0] && strcmp(w->port_path, d->port_path) != 0)
        return false;
    if (w->serial[0] && strcmp(w->serial, d->serial) != 0)
        return false;
    return true;
}

const char *hal_usb_link_state_name(enum hal_usb_link_state s)
{
    switch (s) {
    case HAL_USB_LINK_UP:
        return "up";
    case HAL_USB_LINK_WAITING:
        return "waiting";
    case HAL_USB_LINK_PENDING:
        return "pending";
    }
    return "?";
}

void hal_usb_link_init(struct hal_usb_link *l, const struct hal_usb_id *want, const struct hal_usb_id *have,
                       const struct hal_usb_dev_ops *ops, void *cam)
{
    memset(l, 0, sizeof *l);
    l->want = *want;
    l->have = *have;
    l->ops = ops;
    l->cam = cam;
    l->state = HAL_USB_LINK_UP;
}

/* Is `dev` (a departure) the device this camera is on? */
static bool is_mine(const struct hal_usb_link *l, const struct hal_usb_id *dev)
{
    if (l->have.bus != dev->bus)
        return false;
    if (l->have.devnum && dev->devnum)
        return l->have.devnum == dev->devnum; /* bus + devnum: one live device */
    return l->have.port_path[0] && strcmp(l->have.port_path, dev->port_path) == 0 &&
           l->have.vid == dev->vid && l->have.pid == dev->pid;
}

void hal_usb_link_lost(struct hal_usb_link *l)
{
    if (l->state != HAL_USB_LINK_UP)
        return;
    l->state = HAL_USB_LINK_WAITING;
    l->losses++;
    l->ops->drop(l->cam);
}

void hal_usb_link_retry(struct hal_usb_link *l)
{
    if (l->state != HAL_USB_LINK_PENDING)
        return;
    char node[64];
    l->last_rc = l->ops->find_node(l->cam, &l->have, node, sizeof node);
    if (l->last_rc < 0)
        return; /* no node yet: stay pending */
    l->last_rc = l->ops->reopen(l->cam, node);
    if (l->last_rc < 0) {
        l->reopen_failures++;
        l->state = HAL_USB_LINK_WAITING;
        return;
    }
    l->state = HAL_USB_LINK_UP;
    l->reconnects++;
}

void hal_usb_link_feed(struct hal_usb_link *l, const struct hal_usb_event *e)
{
    switch (e->kind) {
    case HAL_USB_LEFT:
        if (l->state == HAL_USB_LINK_UP && is_mine(l, &e->dev))
            hal_usb_link_lost(l);
        else if (l->state == HAL_USB_LINK_PENDING && is_mine(l, &e->dev))
            l->state = HAL_USB_LINK_WAITING; /* left again before its node appeared */
        break;
    case HAL_USB_ARRIVED:
        if (l->state != HAL_USB_LINK_WAITING || !hal_usb_id_match(&l->want, &e->dev)) {
            l->ignored++;
            break;
        }
        l->have = e->dev;
        l->state = HAL_USB_LINK_PENDING;
        hal_usb_link_retry(l);
        break;
    }
}

bool hal_usb_hub_add(struct hal_usb_hub *h, struct hal_usb_link *l)
{
    if (h->n_links == HAL_USB_HUB_LINKS)
        return false;
    h->links[h->n_links++] = l;
    return true;
}

void hal_usb_hub_remove(struct hal_usb_hub *h, struct hal_usb_link *l)
{
    for (uint32_t i = 0; i < h->n_links; i++)
        if (h->links[i] == l) {
            h->links[i] = h->links[--h->n_links];
            return;
        }
}

int hal_usb_hub_pump(struct hal_usb_hub *h, uint32_t timeout_us)
{
    struct hal_usb_event ev[16];
    int total = 0;
    for (;;) {
        int n = h->src.ops ? h->src.ops->poll(h->src.ctx, ev, 16, total ? 0 : timeout_us) : 0;
        if (n < 0)
            return n;
        for (int i = 0; i < n; i++)
            for (uint32_t k = 0; k < h->n_links; k++)
                hal_usb_link_feed(h->links[k], &ev[i]);
        h->events += (uint64_t)n;
        total += n;
        if (n < 16)
            break;
    }
    for (uint32_t k = 0; k < h->n_links; k++)
        hal_usb_link_retry(h->links[k]);
    return total;
}
