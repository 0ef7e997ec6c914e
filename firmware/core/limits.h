/* Sizes fixed by PROTOCOL.md and the build (no heap: every buffer is sized from these). */
#ifndef FW_LIMITS_H
#define FW_LIMITS_H

/* A port that cannot pass -D options (an Arduino sketch) puts its settings in
 * fw_port_config.h next to the core's files. */
#if defined(__has_include)
#if __has_include("fw_port_config.h")
#include "fw_port_config.h"
#endif
#endif

#define FW_PROTOCOL_VERSION 1u
#define FW_HEADER_SIZE 5u              /* version address type seq:u16 */
#define FW_CRC_SIZE 4u
#define FW_MAX_PAYLOAD 1024u
#define FW_MAX_BODY (FW_HEADER_SIZE + FW_MAX_PAYLOAD)            /* 1029, without the CRC */
/* largest COBS-encoded frame without its delimiter: body + CRC + 1 code byte per 254 */
#define FW_MAX_ENCODED (FW_MAX_BODY + FW_CRC_SIZE + (FW_MAX_BODY + FW_CRC_SIZE + 253u) / 254u)
#define FW_MAX_WIRE (FW_MAX_ENCODED + 1u)                        /* 1039 with the delimiter */
#define FW_MIN_FRAME (FW_HEADER_SIZE + FW_CRC_SIZE)
#define FW_MAX_CHUNK_DATA (FW_MAX_PAYLOAD - 8u)                  /* 1016 */
#define FW_MAX_POSITIONS 255u
#define FW_MIN_ADDRESS 1u
#define FW_MAX_ADDRESS 247u
#define FW_BROADCAST_ADDRESS 0u        /* every controller takes it, none answers: SHOW only */
#define FW_NO_BANK 0xFFu
#define FW_TABLE_ENTRIES 256u
#define FW_TABLE_BYTES 512u
#define FW_BANK_HEADER_SIZE 24u
#define FW_BANK_MAGIC 0x31545247u      /* "GRT1" little-endian */

/* Pixels one controller drives at most: RAM holds FW_MAX_PIXELS per-pixel tables (512 B each)
 * and a received-byte bitmap of the same tables (64 B each). Ports override it (-D). */
#ifndef FW_MAX_PIXELS
#define FW_MAX_PIXELS 16u
#endif
#define FW_MAX_TABLE_BYTES (FW_MAX_PIXELS * FW_TABLE_BYTES)

/* Motor loop period: fw_tick() runs once per millisecond. */
#define FW_TICK_US 1000u

#endif
