/* A fw_hal for host-side tests, fuzzing and benches: storage in RAM, answers collected in a
 * buffer, an ideal plant (encoder = what the test sets), a settable clock. */
#ifndef FW_RAM_HAL_H
#define FW_RAM_HAL_H
#include "../core/controller.h"
#include "../core/nv_ram.h"

typedef struct {
    fw_hal hal;
    fw_nv_ram nv;
    uint8_t mem[2 * (FW_BANK_HEADER_SIZE + FW_MAX_TABLE_BYTES)];
    uint8_t out[8192];
    size_t out_len;
    uint32_t ms;
    int32_t encoder[FW_MAX_PIXELS];
    int16_t pwm[FW_MAX_PIXELS];
} ram_hal;

void ram_hal_init(ram_hal *r);

#endif
