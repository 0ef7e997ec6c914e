/* The hardware a controller needs, as a port provides it. One fw_hal per controller instance
 * (the posix port runs several on one bus); `ctx` is the port's, passed back to every call.
 *
 * Non-volatile storage is byte-addressed, erased state 0xFF. Storage calls return 0 on success
 * and a negative number on failure (answered NAK STORAGE_FAILED). A power cut inside a write
 * is the port's business: the core is written so that any prefix of any write leaves the old or
 * the new table valid (PROTOCOL.md section 4). */
#ifndef FW_HAL_H
#define FW_HAL_H
#include <stddef.h>
#include <stdint.h>

/* The byte storage reads as where nothing was written, or after nv_erase. */
#define FW_NV_ERASED 0xFFu

/* PWM duty is signed per mille: -1000 full reverse .. +1000 full forward. */
#define FW_PWM_MAX 1000

typedef struct fw_hal {
    void *ctx;
    /* Send n bytes on the bus (the whole answer frame at once; RS-485 DE is the port's). */
    void (*tx)(void *ctx, const uint8_t *data, size_t n);
    int (*nv_read)(void *ctx, uint32_t offset, uint8_t *buf, uint32_t n);
    int (*nv_write)(void *ctx, uint32_t offset, const uint8_t *data, uint32_t n);
    /* Set n bytes at offset to FW_NV_ERASED. */
    int (*nv_erase)(void *ctx, uint32_t offset, uint32_t n);
    /* Milliseconds since boot (wraps at 2^32): the clock a port schedules fw_tick from
     * (the core itself is driven by fw_tick and never waits on it). */
    uint32_t (*millis)(void *ctx);
    /* Encoder position of a pixel's motor in counts (signed, 0 = grass fully retracted). */
    int32_t (*encoder_read)(void *ctx, uint16_t pixel);
    /* Drive a pixel's motor: duty in -FW_PWM_MAX..FW_PWM_MAX. */
    void (*pwm_write)(void *ctx, uint16_t pixel, int16_t duty);
} fw_hal;

/* Critical sections around data the core shares with an interrupt handler (as Klipper's
 * src/generic/irq.h). A port may run fw_tick from a timer interrupt (mps2: SysTick; Teensy:
 * IntervalTimer) while its main context feeds received bytes, so the core brackets every access
 * to what both touch (the motors' targets and loop state, an encoder read that the tick's plant
 * may be updating) with
 *
 *     fw_irqstatus flag = fw_irq_save();   masks those interrupts, returns the previous state
 *     ...
 *     fw_irq_restore(flag);                puts that state back (so sections nest)
 *
 * Unlike the rest of the HAL these are plain functions, not fw_hal members: interrupts belong to
 * the CPU, not to one controller instance. Every port and test program links one pair: Cortex-M
 * saves PRIMASK and sets it (mrs / cpsid i / msr, generic/armcm_irq.c), the posix port blocks signals
 * (ports/posix/irq.c), host tests without interrupts use test/irq_none.c. A section lasts at most
 * one SET_LEVEL frame's targets or one GET_POSITIONS pixel; it must not call back into the
 * port's tx or storage. */
typedef uint32_t fw_irqstatus;
fw_irqstatus fw_irq_save(void);
void fw_irq_restore(fw_irqstatus flag);

#endif
