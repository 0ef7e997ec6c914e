#include "ram_hal.h"
#include <string.h>

static void tx(void *ctx, const uint8_t *data, size_t n)
{
    ram_hal *r = ctx;
    if (n > sizeof r->out - r->out_len)
        n = sizeof r->out - r->out_len;
    memcpy(r->out + r->out_len, data, n);
    r->out_len += n;
}
static int nv_read(void *ctx, uint32_t o, uint8_t *b, uint32_t n) { return fw_nv_ram_read(&((ram_hal *)ctx)->nv, o, b, n); }
static int nv_write(void *ctx, uint32_t o, const uint8_t *d, uint32_t n) { return fw_nv_ram_write(&((ram_hal *)ctx)->nv, o, d, n); }
static int nv_erase(void *ctx, uint32_t o, uint32_t n) { return fw_nv_ram_erase(&((ram_hal *)ctx)->nv, o, n); }
static uint32_t millis(void *ctx) { return ((ram_hal *)ctx)->ms; }
static int32_t enc(void *ctx, uint16_t p) { return ((ram_hal *)ctx)->encoder[p]; }
static void pwm(void *ctx, uint16_t p, int16_t d) { ((ram_hal *)ctx)->pwm[p] = d; }

void ram_hal_init(ram_hal *r)
{
    memset(r, 0, sizeof *r);
    r->hal = (fw_hal){r, tx, nv_read, nv_write, nv_erase, millis, enc, pwm};
    fw_nv_ram_init(&r->nv, r->mem, sizeof r->mem);
}
