/* Cortex-M7 reset and vector table for mps2-an500: copy .data, clear .bss, enable the FPU,
 * run main. Interrupts used: SysTick (the 1 ms motor loop) and UART0 RX (IRQ 0). */
#include <stdint.h>
#include "mps2_regs.h"

extern uint32_t _data_load, _data_start, _data_end, _bss_start, _bss_end, _stack_top;
int main(void);
void systick_handler(void);
void uart0_rx_handler(void);

static void default_handler(void)
{
    for (;;) {
    }
}

void reset_handler(void)
{
    uint32_t *src = &_data_load, *dst = &_data_start;
    while (dst < &_data_end)
        *dst++ = *src++;
    for (dst = &_bss_start; dst < &_bss_end; dst++)
        *dst = 0;
    CPACR |= CPACR_CP10_FULL | CPACR_CP11_FULL;   /* the FPU */
    __asm volatile("dsb\n isb");
    main();
    default_handler();
}

__attribute__((section(".vectors"), used))
static void (*const vectors[16 + 32])(void) = {
    (void (*)(void))(&_stack_top), reset_handler,
    default_handler, default_handler, default_handler, default_handler, default_handler,
    0, 0, 0, 0, default_handler, default_handler, 0, default_handler,
    systick_handler,
    uart0_rx_handler,   /* IRQ 0: UART0 RX */
    [17 ... 47] = default_handler,
};
