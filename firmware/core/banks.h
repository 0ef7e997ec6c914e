/* Two table banks on non-volatile storage (PROTOCOL.md section 4), laid out exactly as the
 * Python reference's eeprom.BankStore: bank b at b * (24 + capacity * 512), a 24-byte header
 *   magic:u32 generation:u32 table_id:u32 kind:u8 reserved:u8 n_tables:u16 data_crc:u32 header_crc:u32
 * then the table data. */
#ifndef FW_BANKS_H
#define FW_BANKS_H
#include <stdint.h>
#include "hal.h"

typedef struct {
    uint32_t generation, table_id;
    uint8_t kind;
    uint16_t n_tables;
    uint32_t data_crc;
} fw_bank_header;

/* Storage bytes two banks of `capacity` tables need. */
uint32_t fw_banks_size(uint16_t capacity);
/* Read and fully validate bank b (header CRC, magic, n_tables <= capacity, data CRC).
 * Returns 1 and fills h when valid, 0 when not, negative on a storage error. */
int fw_bank_read_header(const fw_hal *hal, uint16_t capacity, uint8_t bank, fw_bank_header *h);
/* The valid bank with the largest generation (bank 0 on a tie); FW_NO_BANK when none. */
uint8_t fw_banks_select(const fw_hal *hal, uint16_t capacity, fw_bank_header *h);
/* Erase the bank's magic so that it cannot be selected while it is rewritten. */
int fw_bank_invalidate(const fw_hal *hal, uint16_t capacity, uint8_t bank);
int fw_bank_write_data(const fw_hal *hal, uint16_t capacity, uint8_t bank, uint32_t offset,
                       const uint8_t *data, uint32_t n);
int fw_bank_read_data(const fw_hal *hal, uint16_t capacity, uint8_t bank, uint32_t offset,
                      uint8_t *buf, uint32_t n);
/* CRC-32 of the first n data bytes of a bank, read back from storage in small pieces; when
 * max_value is not NULL also the index of the first u16 entry above *max_value (else
 * FW_NONE_OVER) in *first_over. Returns 0 or a storage error. */
#define FW_NONE_OVER 0xFFFFFFFFu
int fw_bank_scan(const fw_hal *hal, uint16_t capacity, uint8_t bank, uint32_t n, uint32_t *crc,
                 const uint16_t *max_value, uint32_t *first_over);
/* The one-step switch: write the whole header (magic, fields, header CRC) in one write. */
int fw_bank_write_header(const fw_hal *hal, uint16_t capacity, uint8_t bank,
                         const fw_bank_header *h);

#endif
