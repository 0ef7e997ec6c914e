/* Critical sections (core/hal.h) for host test programs that have no interrupts (vector
 * replay, fuzz driver, motor bench): fw_tick runs in the same thread as the frames, so a
 * section only has to keep the compiler from moving the accesses across its ends. */
#include "../core/hal.h"

fw_irqstatus fw_irq_save(void)
{
    __asm__ volatile("" ::: "memory");
    return 0u;
}

void fw_irq_restore(fw_irqstatus flag)
{
    (void)flag;
    __asm__ volatile("" ::: "memory");
}
