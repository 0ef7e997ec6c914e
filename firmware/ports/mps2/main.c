/* mps2-an500 port: the core on a Cortex-M7 under qemu-system-arm -M mps2-an500.
 *
 * - bus: CMSDK APB UART0 (0x40004000, on QEMU's -serial), received bytes through the RX
 *   interrupt into a ring buffer, answers sent by polling;
 * - storage: a RAM array in .noinit (kept over a system reset, lost when QEMU exits);
 * - clock and motor loop: SysTick at 1 kHz; its handler runs the PD loop (fw_tick) at a higher
 *   priority than the UART, so no frame can delay it, and steps the DC-motor model of the
 *   pixels (generic/sim_pixels.c, on the FPU) standing in for the motors and encoders; while
 *   every motor rests unpowered it ticks every 50 ms instead (an idle QEMU then sleeps);
 * - configuration: a block at 0x203FFF00 that QEMU's -device loader fills (address, pixels,
 *   max_chunk, uid), core/board_defaults.h when absent.
 * - critical sections (core/hal.h): PRIMASK saved and set (cpsid i, generic/armcm_irq.c), then
 *   put back, around everything the main loop shares with SysTick (targets and positions in
 *   the core, the tick period and clock here);
 * The main loop sleeps (WFI) until an interrupt. */
#include <stdint.h>
#include <string.h>
#include "../../core/controller.h"
#include "../../core/nv_ram.h"
#include "../../generic/sim_pixels.h"
#include "mps2_regs.h"

#define CONFIG_MAGIC 0x47464346u   /* "FCFG" */
typedef struct {
    uint32_t magic, address, n_pixels, max_chunk, uid;
} board_config;
__attribute__((section(".fwconfig"))) volatile board_config fwconfig;

/* What the host reads back through QEMU's monitor (pmemsave): counters and the storage. */
#define STATS_MAGIC 0x53574647u
#define NO_FRAME 0x100u   /* max_byte_type when the byte completed no valid frame */
typedef struct {
    uint32_t magic, boots, writes, nv_size;
    /* the longest fw_rx_feed of one byte, in SysTick counts (1/25 MHz; with QEMU's -icount
     * shift=0 one count is 40 instructions), and the type of the frame that byte completed */
    uint32_t max_byte_ticks, max_byte_type;
} board_stats;
__attribute__((section(".noinit"))) board_stats fw_stats;
__attribute__((section(".noinit"))) uint8_t fw_storage[2 * (FW_BANK_HEADER_SIZE + FW_MAX_TABLE_BYTES)];

static fw_nv_ram nv;
static fw_controller ctl;
static fw_hal hal;
static volatile uint32_t ms;
static sim_pixels pixels;
static uint16_t n_pixels;   /* of the configuration booted */
static volatile uint8_t moving;

static uint8_t ring[2048];
static volatile uint32_t ring_head, ring_tail;

void uart0_rx_handler(void)
{
    UART_INTCLEAR = UART_INT_RX;
    while (UART_STATE & UART_STATE_RX_FULL) {
        uint8_t b = (uint8_t)UART_DATA;
        uint32_t next = (ring_head + 1u) % sizeof ring;
        if (next != ring_tail) {   /* else dropped, as an overrun */
            ring[ring_head] = b;
            ring_head = next;
        }
    }
}

/* SysTick runs at 1 kHz while a motor moves and at IDLE_TICK_MS while all rest (so that an
 * idle QEMU sleeps); period_now is the period being counted, period_next the one in RVR. */
#define COUNTS_PER_MS (SYSCLK_HZ / 1000u)
#define IDLE_TICK_MS 50u
static volatile uint32_t period_now = 1, period_next = 1;
static volatile uint8_t feeding;   /* the main loop is handling a byte: keep the 1 kHz period */

static void set_period(uint32_t p)
{
    SYST_RVR = p * COUNTS_PER_MS - 1u;
    period_next = p;
}

/* A byte arrived (a frame may set targets): run the motor loop at 1 kHz from now until every
 * motor rests, accounting for the part of an idle period gone. */
static void wake_motor_loop(void)
{
    fw_irqstatus flag = fw_irq_save();
    moving = 1;
    if (period_now != 1u || period_next != 1u) {
        uint32_t left = SYST_CVR;
        ms += (period_now * COUNTS_PER_MS - 1u - left) / COUNTS_PER_MS;
        set_period(1);
        SYST_CVR = 0;   /* restart the count from the new reload value */
        period_now = 1;
    }
    fw_irq_restore(flag);
}

void systick_handler(void)
{
    ms += period_now;
    period_now = period_next;
    if (!moving) {
        if (period_next == 1u && !feeding)
            set_period(IDLE_TICK_MS);
        return;   /* motors at rest and unpowered: nothing changes until a new target */
    }
    fw_tick(&ctl);
    moving = (uint8_t)sim_pixels_step(&pixels, n_pixels);
}

static void tx(void *ctx, const uint8_t *data, size_t n)
{
    (void)ctx;
    for (size_t i = 0; i < n; i++) {
        while (UART_STATE & UART_STATE_TX_FULL) {
        }
        UART_DATA = data[i];
    }
}
static int nv_read(void *ctx, uint32_t o, uint8_t *b, uint32_t n) { return fw_nv_ram_read(ctx, o, b, n); }
static int nv_write(void *ctx, uint32_t o, const uint8_t *d, uint32_t n)
{
    fw_stats.writes++;
    return fw_nv_ram_write(ctx, o, d, n);
}
static int nv_erase(void *ctx, uint32_t o, uint32_t n)
{
    fw_stats.writes++;
    return fw_nv_ram_erase(ctx, o, n);
}
static uint32_t millis(void *ctx) { (void)ctx; return ms; }
static int32_t encoder(void *ctx, uint16_t p) { (void)ctx; return sim_pixels_encoder(&pixels, p); }
static void pwm(void *ctx, uint16_t p, int16_t d) { (void)ctx; pixels.duty[p] = d; }

int main(void)
{
    fw_config cfg = fw_config_default(FW_DEFAULT_ADDRESS, FW_MAX_PIXELS);
    if (fwconfig.magic == CONFIG_MAGIC) {
        cfg.address = (uint8_t)fwconfig.address;
        cfg.n_pixels = (uint16_t)fwconfig.n_pixels;
        cfg.max_chunk = (uint16_t)fwconfig.max_chunk;
        cfg.uid = fwconfig.uid;
    }
    uint32_t nv_size = fw_banks_size(cfg.n_pixels);
    if (fw_stats.magic != STATS_MAGIC || fw_stats.nv_size != nv_size) {   /* first power-on */
        fw_nv_ram_init(&nv, fw_storage, nv_size);
        fw_stats = (board_stats){STATS_MAGIC, 0, 0, nv_size, 0, 0};
    } else {
        nv = (fw_nv_ram){fw_storage, nv_size, 0};
    }
    sim_pixels_init(&pixels);
    pixels.plant.substep_s = 1e-3;   /* one Euler step per period: tau = 20 ms keeps it stable */
    hal = (fw_hal){&nv, tx, nv_read, nv_write, nv_erase, millis, encoder, pwm};
    if (fw_boot(&ctl, &hal, &cfg) < 0)   /* a bad block from the loader: one pixel, defaults */
        cfg = fw_config_default(FW_DEFAULT_ADDRESS, 1), fw_boot(&ctl, &hal, &cfg);
    n_pixels = cfg.n_pixels;

    UART_BAUDDIV = UART_BAUDDIV_VALUE;
    UART_CTRL = UART_CTRL_TX_EN | UART_CTRL_RX_EN | UART_CTRL_RX_INT_EN;
    NVIC_IPR0 = UART0_RX_PRIORITY;   /* UART0 RX below SysTick */
    NVIC_ISER0 = NVIC_BIT(UART0_RX_IRQ);
    SHPR3 = (SHPR3 & ~SHPR3_PRI_SYSTICK_MASK)   /* SysTick priority 0: the motor loop preempts all */
            | (SYSTICK_PRIORITY << SHPR3_PRI_SYSTICK_SHIFT);
    set_period(1);
    SYST_CVR = 0;
    SYST_CSR = SYST_CSR_CLKSOURCE | SYST_CSR_TICKINT | SYST_CSR_ENABLE;
    fw_stats.boots++;           /* a completed boot: the UART takes bytes from here on */

    for (;;) {
        while (ring_tail != ring_head) {
            uint8_t b = ring[ring_tail];
            ring_tail = (ring_tail + 1u) % sizeof ring;
            feeding = 1;
            wake_motor_loop();
            fw_irqstatus flag = fw_irq_save();   /* the clock and its counter as one pair */
            uint32_t ms0 = ms, t0 = SYST_CVR;
            fw_irq_restore(flag);
            int type = fw_rx_feed(&ctl, &b, 1);
            flag = fw_irq_save();
            uint32_t t1 = SYST_CVR, ms1 = ms;
            fw_irq_restore(flag);
            feeding = 0;
            uint32_t ticks = (ms1 - ms0) * (SYST_RVR + 1u) + t0 - t1;   /* counts down */
            if (ticks > fw_stats.max_byte_ticks && ticks < 0x80000000u) {   /* not wrapped */
                fw_stats.max_byte_ticks = ticks;
                fw_stats.max_byte_type = type != FW_RX_NO_FRAME ? (uint32_t)type : NO_FRAME;
            }
        }
        if (fw_poll(&ctl))   /* a test pattern's watchdog ended it: new targets */
            wake_motor_loop();
        __asm volatile("wfi");   /* SysTick wakes it at least every IDLE_TICK_MS */
    }
}
