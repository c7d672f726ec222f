/* f4d_netns.h: a private network namespace for tests that run fake network
 * cameras (in-process Aravis GigE fakes): their traffic never leaves it. */
#ifndef F4D_NETNS_H
#define F4D_NETNS_H

#include <stddef.h>

/* Moves the calling thread into a private network namespace (as root, or as
 * root of a fresh user namespace, like `unshare -rn`) with lo up and the
 * aliases 127.0.0.2 .. 127.0.0.(1 + n_alias). Call before any thread exists:
 * a namespace belongs to the thread that makes it. Returns 0, or -1 with the
 * reason in why. */
int f4d_test_netns(int n_alias, char *why, size_t why_size);

#endif
