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

/* PWM duty is signed per mille: -1000 full reverse .. +1000 full forward. */
#define FW_PWM_MAX 1000

typedef struct fw_hal {
    void *ctx;
    /* Send n bytes on the bus (the whole answer frame at once; RS-485 DE is the port's). */
    void (*tx)(void *ctx, const uint8_t *data, size_t n);
    int (*nv_read)(void *ctx, uint32_t offset, uint8_t *buf, uint32_t n);
    int (*nv_write)(void *ctx, uint32_t offset, const uint8_t *data, uint32_t n);
    /* Set n bytes at offset to 0xFF. */
    int (*nv_erase)(void *ctx, uint32_t offset, uint32_t n);
    /* Milliseconds since boot (wraps at 2^32): the clock a port schedules fw_tick from
     * (the core itself is driven by fw_tick and never waits on it). */
    uint32_t (*millis)(void *ctx);
    /* Encoder position of a pixel's motor in counts (signed, 0 = grass fully retracted). */
    int32_t (*encoder_read)(void *ctx, uint16_t pixel);
    /* Drive a pixel's motor: duty in -FW_PWM_MAX..FW_PWM_MAX. */
    void (*pwm_write)(void *ctx, uint16_t pixel, int16_t duty);
} fw_hal;

#endif
