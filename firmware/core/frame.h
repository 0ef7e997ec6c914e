/* Framing (PROTOCOL.md section 2): wire frame = COBS(header payload crc32) 0x00.
 * fw_rx reassembles frames byte by byte in a fixed buffer; garbage is dropped up to the next
 * 0x00 and a run longer than a frame is discarded as it arrives. */
#ifndef FW_FRAME_H
#define FW_FRAME_H
#include <stddef.h>
#include <stdint.h>
#include "limits.h"

typedef struct fw_rx {
    uint8_t buf[FW_MAX_ENCODED];
    uint16_t len;
    uint8_t discarding;
    uint32_t frames;     /* frames with a valid CRC */
    uint32_t bad;        /* non-empty frames dropped (COBS, length or CRC) */
    uint32_t oversized;  /* runs longer than a frame, discarded */
} fw_rx;

void fw_rx_reset(fw_rx *rx);
/* Feed one received byte. Returns the body length (header + payload, CRC checked and removed)
 * when the byte completes a valid frame, the body then at rx->buf until the next call; else 0. */
size_t fw_rx_byte(fw_rx *rx, uint8_t byte);

/* Slack in front of a body inside a wire buffer: fw_frame_wrap encodes in place. */
#define FW_WIRE_SLACK 6u
/* The body (header + payload, body_len bytes) is at wire + FW_WIRE_SLACK: append its CRC,
 * COBS-encode it to wire[0..] and add the delimiter. wire holds FW_MAX_WIRE + FW_WIRE_SLACK
 * bytes. Returns the wire length. */
size_t fw_frame_wrap(uint8_t *wire, size_t body_len);
/* Offsets of the 5-byte header's fields in a body (PROTOCOL.md section 2). */
enum { FW_HEADER_VERSION = 0, FW_HEADER_ADDRESS = 1, FW_HEADER_TYPE = 2, FW_HEADER_SEQ = 3 };
/* Write the 5-byte header at body. */
void fw_put_header(uint8_t *body, uint8_t version, uint8_t address, uint8_t type, uint16_t seq);

#endif
