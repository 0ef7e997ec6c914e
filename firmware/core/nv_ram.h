/* Non-volatile storage kept in a RAM array (the mps2-an500 port, tests, fuzzing): the nv_*
 * functions of fw_hal over one nv_ram as ctx-reachable state. */
#ifndef FW_NV_RAM_H
#define FW_NV_RAM_H
#include <stdint.h>

typedef struct {
    uint8_t *mem;
    uint32_t size;
    uint32_t writes;   /* writes and erases so far */
} fw_nv_ram;

/* Fill with the erased state (0xFF). */
void fw_nv_ram_init(fw_nv_ram *nv, uint8_t *mem, uint32_t size);
int fw_nv_ram_read(fw_nv_ram *nv, uint32_t offset, uint8_t *buf, uint32_t n);
int fw_nv_ram_write(fw_nv_ram *nv, uint32_t offset, const uint8_t *data, uint32_t n);
int fw_nv_ram_erase(fw_nv_ram *nv, uint32_t offset, uint32_t n);

#endif
