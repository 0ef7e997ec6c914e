/* The messages of PROTOCOL.md section 3 and their little-endian payloads. Field names are the
 * Python reference's (firmware_proto/messages.py). Byte tails (chunk data, levels, positions)
 * point into the buffer they were decoded from: nothing is copied. */
#ifndef FW_MSG_H
#define FW_MSG_H
#include <stddef.h>
#include <stdint.h>
#include "limits.h"

enum fw_type {
    FW_HELLO = 0x01, FW_GET_STATUS = 0x02, FW_TABLE_BEGIN = 0x03, FW_TABLE_CHUNK = 0x04,
    FW_TABLE_COMMIT = 0x05, FW_SET_LEVEL = 0x06, FW_GET_POSITIONS = 0x07, FW_PATTERN = 0x08,
    FW_PATTERN_END = 0x09, FW_STAGE_LEVEL = 0x0A, FW_SHOW = 0x0B,
    FW_INFO = 0x81, FW_TABLE_STATUS = 0x82, FW_POSITIONS = 0x87, FW_ACK = 0x90, FW_NAK = 0x91,
};

/* Bit 7 of a type: set on answers (controller -> host), clear on requests. */
#define FW_TYPE_RESPONSE 0x80u

enum fw_nak {
    FW_NAK_BAD_PAYLOAD = 1, FW_NAK_UNKNOWN_TYPE = 2, FW_NAK_UNSUPPORTED_VERSION = 3,
    FW_NAK_NO_TRANSFER = 4, FW_NAK_OUT_OF_RANGE = 5, FW_NAK_INCOMPLETE = 6,
    FW_NAK_CRC_MISMATCH = 7, FW_NAK_TOO_LARGE = 8, FW_NAK_BAD_KIND = 9, FW_NAK_VALUE_RANGE = 10,
    FW_NAK_NO_TABLE = 11, FW_NAK_BAD_PIXEL = 12, FW_NAK_STORAGE_FAILED = 13,
};

enum { FW_KIND_GLOBAL = 0, FW_KIND_PER_PIXEL = 1 };

/* INFO features bits: what a controller implements beyond the first v1 messages. */
#define FW_FEATURE_PATTERNS 0x0001u   /* PATTERN / PATTERN_END */
#define FW_FEATURE_LATCH 0x0002u      /* STAGE_LEVEL / SHOW */
/* Most levels one STAGE_LEVEL carries: payload minus frame and first_pixel. */
#define FW_MAX_STAGE_PIXELS (FW_MAX_PAYLOAD - 4u)
/* Most lengths one PATTERN carries: payload minus timeout_ds and first_pixel, 2 bytes each. */
#define FW_MAX_PATTERN_PIXELS ((FW_MAX_PAYLOAD - 4u) / 2u)

typedef struct {
    uint8_t protocol_version, fw_major, fw_minor, fw_patch;
    uint32_t uid;
    uint16_t n_pixels, table_capacity, max_chunk, max_length_um;
    uint16_t features;   /* FW_FEATURE_* bits */
} fw_info;

typedef struct {
    uint8_t active_bank, kind;
    uint16_t n_tables;
    uint32_t table_id, table_crc, generation;
    uint8_t staging;
    uint32_t staged_bytes;
} fw_table_status;

typedef struct {
    uint32_t table_id;
    uint8_t kind;
    uint16_t n_tables;
    uint32_t total_bytes, table_crc;
} fw_table_begin;

typedef struct { uint32_t table_id, offset; const uint8_t *data; uint16_t data_len; } fw_table_chunk;
typedef struct { uint32_t table_id, table_crc; } fw_table_commit;
typedef struct { uint16_t first_pixel; const uint8_t *levels; uint16_t levels_len; } fw_set_level;
typedef struct { uint16_t first_pixel, count; } fw_get_positions;
typedef struct {
    uint16_t frame, first_pixel;
    const uint8_t *levels;
    uint16_t levels_len;
} fw_stage_level;
typedef struct { uint16_t frame; } fw_show;
/* lengths: lengths_len / 2 x length_um:u16, little-endian, as on the wire */
typedef struct {
    uint16_t timeout_ds, first_pixel;
    const uint8_t *lengths;
    uint16_t lengths_len;
} fw_pattern;
/* positions: count x (position_um:u16 target_um:u16), little-endian, as on the wire */
typedef struct { uint16_t first_pixel; const uint8_t *positions; uint16_t positions_len; } fw_positions;
typedef struct { uint8_t request_type; } fw_ack;
typedef struct { uint8_t request_type, error; uint32_t detail; } fw_nakmsg;

typedef struct {
    uint8_t type;   /* enum fw_type */
    union {
        fw_info info;
        fw_table_status table_status;
        fw_table_begin table_begin;
        fw_table_chunk table_chunk;
        fw_table_commit table_commit;
        fw_set_level set_level;
        fw_get_positions get_positions;
        fw_pattern pattern;
        fw_stage_level stage_level;
        fw_show show;
        fw_positions positions;
        fw_ack ack;
        fw_nakmsg nak;
    } u;
} fw_msg;

enum { FW_MSG_OK = 0, FW_MSG_UNKNOWN_TYPE = -1, FW_MSG_BAD_PAYLOAD = -2 };

/* Decode the payload of a message of `type` (n bytes). Returns FW_MSG_OK, FW_MSG_UNKNOWN_TYPE or
 * FW_MSG_BAD_PAYLOAD (wrong length, or a byte tail outside its bounds). */
int fw_msg_unpack(uint8_t type, const uint8_t *payload, size_t n, fw_msg *out);
/* Write the payload of m to out (room for FW_MAX_PAYLOAD); returns its length. */
size_t fw_msg_pack(const fw_msg *m, uint8_t *out);

#endif
