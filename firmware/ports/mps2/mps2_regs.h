/* The registers and bits the mps2-an500 port uses: the CMSDK APB UART (ARM DDI 0479, "APB
 * UART"), SysTick, the NVIC and the System Control Block of the Cortex-M7 (ARMv7-M ARM, B3). */
#ifndef MPS2_REGS_H
#define MPS2_REGS_H
#include <stdint.h>

#define REG32(addr) (*(volatile uint32_t *)(addr))
#define REG8(addr) (*(volatile uint8_t *)(addr))

/* ---- CMSDK APB UART0 (on QEMU's -serial) ---- */
#define UART0_BASE 0x40004000u
#define UART_DATA REG32(UART0_BASE + 0x000u)
#define UART_STATE REG32(UART0_BASE + 0x004u)
#define UART_CTRL REG32(UART0_BASE + 0x008u)
#define UART_INTCLEAR REG32(UART0_BASE + 0x00Cu)   /* write 1 to clear; reads INTSTATUS */
#define UART_BAUDDIV REG32(UART0_BASE + 0x010u)
/* STATE */
#define UART_STATE_TX_FULL (1u << 0)
#define UART_STATE_RX_FULL (1u << 1)
/* CTRL */
#define UART_CTRL_TX_EN (1u << 0)
#define UART_CTRL_RX_EN (1u << 1)
#define UART_CTRL_TX_INT_EN (1u << 2)
#define UART_CTRL_RX_INT_EN (1u << 3)
/* INTSTATUS / INTCLEAR */
#define UART_INT_TX (1u << 0)
#define UART_INT_RX (1u << 1)
/* The smallest divisor the UART accepts (QEMU does not pace the line by it). */
#define UART_BAUDDIV_VALUE 16u
/* External interrupt of UART0 RX on mps2-an500 (the vector after SysTick, startup.c). */
#define UART0_RX_IRQ 0u

/* ---- SysTick ---- */
#define SYST_CSR REG32(0xE000E010u)
#define SYST_RVR REG32(0xE000E014u)
#define SYST_CVR REG32(0xE000E018u)
#define SYST_CSR_ENABLE (1u << 0)
#define SYST_CSR_TICKINT (1u << 1)
#define SYST_CSR_CLKSOURCE (1u << 2)   /* 1: the processor clock */
#define SYSCLK_HZ 25000000u

/* ---- NVIC ---- */
#define NVIC_ISER0 REG32(0xE000E100u)
#define NVIC_IPR0 REG8(0xE000E400u)    /* priority of external interrupt 0, one byte */
#define NVIC_BIT(irq) (1u << (irq))

/* ---- System Control Block ---- */
#define SHPR3 REG32(0xE000ED20u)       /* priorities of system handlers 12-15 */
#define SHPR3_PRI_SYSTICK_SHIFT 24u    /* PRI_15: SysTick */
#define SHPR3_PRI_SYSTICK_MASK (0xFFu << SHPR3_PRI_SYSTICK_SHIFT)
#define CPACR REG32(0xE000ED88u)       /* coprocessor access control */
#define CPACR_CP10_FULL (3u << 20)     /* the FPU: CP10 and CP11 both full access */
#define CPACR_CP11_FULL (3u << 22)

/* Priorities (lower is more urgent): the motor loop above the bus. */
#define SYSTICK_PRIORITY 0x00u
#define UART0_RX_PRIORITY 0x40u

#endif
