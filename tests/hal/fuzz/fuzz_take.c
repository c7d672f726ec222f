/* fuzz_take.c: libFuzzer harness for the take reader and verify
 * (hal/take). The input is a take.f4t; verify (with repair) and the
 * reader must handle it without crashing, leaking or reading out of bounds.
 * Its scratch directory (mkdtemp) is removed when the fuzzer exits. */
#define _XOPEN_SOURCE 700 /* nftw */
#include <fcntl.h>
#include <ftw.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "f4d_take.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

static char dir[256];

static int rm_one(const char *path, const struct stat *sb, int flag, struct FTW *ftw)
{
    (void)sb; (void)flag; (void)ftw;
    return remove(path);
}

static void remove_dir(void)
{
    if (dir[0])
        nftw(dir, rm_one, 8, FTW_DEPTH | FTW_PHYS);
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    if (!dir[0]) {
        const char *tmp = getenv("TMPDIR");
        snprintf(dir, sizeof dir, "%s/f4d_fuzz_take_XXXXXX", tmp && *tmp ? tmp : "/tmp");
        if (!mkdtemp(dir))
            abort();
        atexit(remove_dir); /* libFuzzer ends -max_total_time with exit() */
    }
    char path[320];
    snprintf(path, sizeof path, "%s/" F4D_TAKE_FILE, dir);
    int fd = open(path, O_WRONLY | O_CREAT | O_TRUNC, 0644);
    if (fd < 0 || write(fd, data, size) != (ssize_t)size)
        abort();
    close(fd);
    snprintf(path, sizeof path, "%s/" F4D_TAKE_INDEX, dir);
    unlink(path);
    struct f4d_take_report rep;
    struct f4d_err err = {0};
    int rc = f4d_take_verify(dir, true, &rep, &err);
    struct f4d_take_reader *r;
    if (f4d_take_open(&r, dir, &err) == 0) {
        uint64_t n = f4d_take_count(r);
        if (rc == 0 && n != rep.sets)
            __builtin_trap(); /* the rebuilt index and a scan must agree */
        for (uint64_t i = 0; i < n; i++) {
            struct f4d_take_set s;
            if (f4d_take_read(r, i, &s) == 0) {
                for (uint32_t c = 0; c < HAL_RIG_CAMERAS_MAX; c++)
                    if (s.frames[c].present && s.frames[c].bytes)
                        (void)(volatile uint8_t)s.frames[c].data[s.frames[c].bytes - 1];
            }
        }
        f4d_take_reader_close(r);
    }
    return 0;
}
