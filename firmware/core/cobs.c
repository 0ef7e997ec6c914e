#include "cobs.h"

/* A code byte: the next code-1 bytes are non-zero; below MAX_CODE a 0x00 follows them. */
#define MAX_CODE 0xFFu

size_t fw_cobs_encode(const uint8_t *in, size_t n, uint8_t *out)
{
    size_t code_at = 0, o = 1;
    uint8_t code = 1;
    int open = 1;
    for (size_t i = 0; i < n; i++) {
        uint8_t b = in[i];
        if (b == 0) {
            out[code_at] = code;
            code_at = o++;
            code = 1;
            continue;
        }
        out[o++] = b;
        if (++code == MAX_CODE) {
            out[code_at] = code;
            code = 1;
            if (i + 1 < n)
                code_at = o++;
            else
                open = 0;   /* the run ended the input: no trailing code byte */
        }
    }
    if (open)
        out[code_at] = code;
    return o;
}

long fw_cobs_decode(uint8_t *buf, size_t n)
{
    size_t i = 0, o = 0;
    while (i < n) {
        uint8_t code = buf[i++];
        if (code == 0)
            return -1;
        size_t end = i + code - 1u;
        if (end > n)
            return -1;
        for (; i < end; i++) {
            if (buf[i] == 0)
                return -1;
            buf[o++] = buf[i];
        }
        if (i < n && code < MAX_CODE)
            buf[o++] = 0;
    }
    return (long)o;
}
