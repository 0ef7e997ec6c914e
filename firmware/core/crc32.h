/* CRC-32/ISO-HDLC, the one checksum of the protocol (PROTOCOL.md section 2). */
#ifndef FW_CRC32_H
#define FW_CRC32_H
#include <stddef.h>
#include <stdint.h>

/* CRC of n bytes. */
uint32_t fw_crc32(const uint8_t *data, size_t n);
/* Continue a CRC over more bytes: fw_crc32_update(fw_crc32(a), b) == fw_crc32(a b). */
uint32_t fw_crc32_update(uint32_t crc, const uint8_t *data, size_t n);

#endif
