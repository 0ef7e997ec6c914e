/* Critical sections of the core (core/hal.h) on ARM Cortex-M, as Klipper's
 * src/generic/armcm_irq.c; shared by the mps2 port and the Teensy 4.1 sketch.
 *
 * The previous PRIMASK (bit 0: 1 = interrupts masked) comes back from fw_irq_save, so sections
 * nest; the "memory" clobbers keep the compiler from moving accesses out of them. */
#include "../core/hal.h"

fw_irqstatus fw_irq_save(void)
{
    uint32_t flag;
    __asm volatile("mrs %0, primask\n\tcpsid i" : "=r"(flag) : : "memory");
    return flag;
}

void fw_irq_restore(fw_irqstatus flag)
{
    __asm volatile("msr primask, %0" : : "r"(flag) : "memory");
}
