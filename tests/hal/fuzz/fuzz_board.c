/* fuzz_board.c: libFuzzer harness for the board parser (hal/board). Any input
 * must parse or fail with a message; never crash, leak or overrun. */
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "hal_board.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    struct hal_board b;
    struct f4d_err err = {0};
    int rc = hal_board_parse(&b, (const char *)data, size, &err);
    if (rc < 0 && err.msg[0] == 0)
        __builtin_trap(); /* every failure must say why */
    if (rc == 0) {
        char *js = hal_board_to_json(&b);
        struct hal_board b2;
        if (js && hal_board_parse(&b2, js, strlen(js), &err) != 0)
            __builtin_trap(); /* what we write, we read back */
        free(js);
    }
    return 0;
}
