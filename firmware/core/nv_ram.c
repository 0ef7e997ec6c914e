#include "nv_ram.h"
#include "hal.h"
#include <string.h>

void fw_nv_ram_init(fw_nv_ram *nv, uint8_t *mem, uint32_t size)
{
    nv->mem = mem;
    nv->size = size;
    nv->writes = 0;
    memset(mem, FW_NV_ERASED, size);
}

static int inside(const fw_nv_ram *nv, uint32_t offset, uint32_t n)
{
    return offset <= nv->size && n <= nv->size - offset;
}

int fw_nv_ram_read(fw_nv_ram *nv, uint32_t offset, uint8_t *buf, uint32_t n)
{
    if (!inside(nv, offset, n))
        return -1;
    memcpy(buf, nv->mem + offset, n);
    return 0;
}

int fw_nv_ram_write(fw_nv_ram *nv, uint32_t offset, const uint8_t *data, uint32_t n)
{
    if (!inside(nv, offset, n))
        return -1;
    memcpy(nv->mem + offset, data, n);
    nv->writes++;
    return 0;
}

int fw_nv_ram_erase(fw_nv_ram *nv, uint32_t offset, uint32_t n)
{
    if (!inside(nv, offset, n))
        return -1;
    memset(nv->mem + offset, FW_NV_ERASED, n);
    nv->writes++;
    return 0;
}
