#include "banks.h"
#include "crc32.h"
#include "le.h"
#include "limits.h"

static uint32_t base(uint16_t capacity, uint8_t bank)
{
    return (uint32_t)bank * (FW_BANK_HEADER_SIZE + (uint32_t)capacity * FW_TABLE_BYTES);
}

uint32_t fw_banks_size(uint16_t capacity)
{
    return base(capacity, 2);
}

int fw_bank_scan(const fw_hal *hal, uint16_t capacity, uint8_t bank, uint32_t n, uint32_t *crc,
                 const uint16_t *max_value, uint32_t *first_over)
{
    uint8_t piece[64];
    uint32_t c = 0, over = FW_NONE_OVER;
    uint32_t at = base(capacity, bank) + FW_BANK_HEADER_SIZE;
    for (uint32_t done = 0; done < n; done += sizeof piece) {
        uint32_t k = n - done < sizeof piece ? n - done : (uint32_t)sizeof piece;
        int rc = hal->nv_read(hal->ctx, at + done, piece, k);
        if (rc < 0)
            return rc;
        c = fw_crc32_update(c, piece, k);
        if (max_value != NULL && over == FW_NONE_OVER)
            for (uint32_t i = 0; i + 1 < k; i += 2)
                if (fw_get16(piece + i) > *max_value) {
                    over = (done + i) / 2u;
                    break;
                }
    }
    *crc = c;
    if (first_over != NULL)
        *first_over = over;
    return 0;
}

int fw_bank_read_header(const fw_hal *hal, uint16_t capacity, uint8_t bank, fw_bank_header *h)
{
    uint8_t raw[FW_BANK_HEADER_SIZE];
    int rc = hal->nv_read(hal->ctx, base(capacity, bank), raw, sizeof raw);
    if (rc < 0)
        return rc;
    if (fw_crc32(raw, 20) != fw_get32(raw + 20) || fw_get32(raw) != FW_BANK_MAGIC)
        return 0;
    h->generation = fw_get32(raw + 4);
    h->table_id = fw_get32(raw + 8);
    h->kind = raw[12];
    h->n_tables = fw_get16(raw + 14);
    h->data_crc = fw_get32(raw + 16);
    if (h->n_tables < 1 || h->n_tables > capacity)
        return 0;
    uint32_t crc;
    rc = fw_bank_scan(hal, capacity, bank, (uint32_t)h->n_tables * FW_TABLE_BYTES, &crc, NULL, NULL);
    if (rc < 0)
        return rc;
    return crc == h->data_crc;
}

uint8_t fw_banks_select(const fw_hal *hal, uint16_t capacity, fw_bank_header *h)
{
    uint8_t best = FW_NO_BANK;
    for (uint8_t b = 0; b < 2; b++) {
        fw_bank_header x;
        if (fw_bank_read_header(hal, capacity, b, &x) == 1
            && (best == FW_NO_BANK || x.generation > h->generation)) {
            best = b;
            *h = x;
        }
    }
    return best;
}

int fw_bank_invalidate(const fw_hal *hal, uint16_t capacity, uint8_t bank)
{
    return hal->nv_erase(hal->ctx, base(capacity, bank), 4);
}

int fw_bank_write_data(const fw_hal *hal, uint16_t capacity, uint8_t bank, uint32_t offset,
                       const uint8_t *data, uint32_t n)
{
    return hal->nv_write(hal->ctx, base(capacity, bank) + FW_BANK_HEADER_SIZE + offset, data, n);
}

int fw_bank_read_data(const fw_hal *hal, uint16_t capacity, uint8_t bank, uint32_t offset,
                      uint8_t *buf, uint32_t n)
{
    return hal->nv_read(hal->ctx, base(capacity, bank) + FW_BANK_HEADER_SIZE + offset, buf, n);
}

int fw_bank_write_header(const fw_hal *hal, uint16_t capacity, uint8_t bank,
                         const fw_bank_header *h)
{
    uint8_t raw[FW_BANK_HEADER_SIZE];
    fw_put32(raw, FW_BANK_MAGIC);
    fw_put32(raw + 4, h->generation);
    fw_put32(raw + 8, h->table_id);
    raw[12] = h->kind;
    raw[13] = 0;
    fw_put16(raw + 14, h->n_tables);
    fw_put32(raw + 16, h->data_crc);
    fw_put32(raw + 20, fw_crc32(raw, 20));
    return hal->nv_write(hal->ctx, base(capacity, bank), raw, sizeof raw);
}
