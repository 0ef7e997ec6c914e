#include "frame.h"
#include "cobs.h"
#include "crc32.h"
#include "le.h"

void fw_rx_reset(fw_rx *rx)
{
    rx->len = 0;
    rx->discarding = 0;
}

size_t fw_rx_byte(fw_rx *rx, uint8_t byte)
{
    if (byte != 0) {
        if (rx->discarding)
            return 0;
        if (rx->len == FW_MAX_ENCODED) {   /* one more than a frame can hold */
            rx->oversized++;
            rx->len = 0;
            rx->discarding = 1;
            return 0;
        }
        rx->buf[rx->len++] = byte;
        return 0;
    }
    size_t n = rx->len;
    int was_discarding = rx->discarding;
    rx->len = 0;
    rx->discarding = 0;
    if (was_discarding || n == 0)
        return 0;   /* end of a discarded run, or an empty frame (a flush) */
    long raw = fw_cobs_decode(rx->buf, n);
    if (raw < (long)FW_MIN_FRAME) {
        rx->bad++;
        return 0;
    }
    size_t body = (size_t)raw - FW_CRC_SIZE;
    if (fw_crc32(rx->buf, body) != fw_get32(rx->buf + body)) {
        rx->bad++;
        return 0;
    }
    rx->frames++;
    return body;
}

size_t fw_frame_wrap(uint8_t *wire, size_t body_len)
{
    uint8_t *body = wire + FW_WIRE_SLACK;
    fw_put32(body + body_len, fw_crc32(body, body_len));
    size_t n = fw_cobs_encode(body, body_len + FW_CRC_SIZE, wire);
    wire[n] = 0;
    return n + 1;
}

void fw_put_header(uint8_t *body, uint8_t version, uint8_t address, uint8_t type, uint16_t seq)
{
    body[FW_HEADER_VERSION] = version;
    body[FW_HEADER_ADDRESS] = address;
    body[FW_HEADER_TYPE] = type;
    fw_put16(body + FW_HEADER_SEQ, seq);
}
