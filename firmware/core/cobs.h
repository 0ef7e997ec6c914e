/* Consistent Overhead Byte Stuffing (Cheshire & Baker 1999), byte-exact with Python's `cobs`
 * package: an input ending in a full 254-byte run gets no trailing code byte. */
#ifndef FW_COBS_H
#define FW_COBS_H
#include <stddef.h>
#include <stdint.h>

/* Encode n bytes at in into out (room for n + n/254 + 1 bytes); returns the encoded length.
 * in may lie inside out at out + 6 or later for n <= 1037 (in-place framing). */
size_t fw_cobs_encode(const uint8_t *in, size_t n, uint8_t *out);
/* Decode n encoded bytes (no delimiter) in place; returns the decoded length, or -1 when a
 * code byte points past the end or a 0x00 appears. */
long fw_cobs_decode(uint8_t *buf, size_t n);

#endif
