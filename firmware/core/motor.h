/* PD position loop per pixel on encoder counts, output as signed PWM duty (per mille).
 *
 *   e[k] = target - encoder          (counts)
 *   u[k] = (KP * e[k] + KD * (e[k] - e[k-1])) / 256 + sign(e[k]) * FF   (|e| > DEADBAND)
 *
 * run every FW_TICK_US (1 ms). KP, KD are in 1/256 per-mille per count (per count per tick);
 * FF is a static-friction feed-forward (per mille). Gains and how they were chosen:
 * firmware/README.md ("Motors"). */
#ifndef FW_MOTOR_H
#define FW_MOTOR_H
#include <stdint.h>
#include "hal.h"
#include "limits.h"

/* Encoder resolution in micrometres of grass per count, as a fraction: 12.5 um. */
#define FW_UM_PER_COUNT_NUM 25
#define FW_UM_PER_COUNT_DEN 2

#ifndef FW_PD_KP
#define FW_PD_KP 2048    /* 8 per mille per count */
#endif
#ifndef FW_PD_KD
#define FW_PD_KD 40960   /* 160 per mille per (count per ms) */
#endif
#ifndef FW_PD_FF
#define FW_PD_FF 60      /* per mille: just over the mechanism's static friction */
#endif
#ifndef FW_PD_DEADBAND
#define FW_PD_DEADBAND 1 /* counts: inside it the motor is left unpowered */
#endif

typedef struct {
    int32_t target[FW_MAX_PIXELS];     /* counts */
    int32_t prev_err[FW_MAX_PIXELS];
    uint16_t target_um[FW_MAX_PIXELS];
} fw_motors;

/* fw_motors is shared between the main context (targets set and read from frames) and
 * fw_motors_tick, which a port may run from a timer interrupt: the main-context functions below
 * take a critical section (fw_irq_save / fw_irq_restore, hal.h) around each access, so the tick
 * never sees a pixel's target half written (target and target_um are one pair) and never runs
 * between an init's reads and writes. fw_motors_tick takes none: it is the interrupt. */
void fw_motors_init(fw_motors *m, const fw_hal *hal, uint16_t n_pixels);
/* Set a pixel's target length (um). */
void fw_motor_set_target(fw_motors *m, uint16_t pixel, uint16_t um);
/* A pixel's encoder position (um) and, in *target_um, its target, read together. */
uint16_t fw_motor_position(const fw_motors *m, const fw_hal *hal, uint16_t pixel,
                           uint16_t *target_um);
/* One control period for every pixel. */
void fw_motors_tick(fw_motors *m, const fw_hal *hal, uint16_t n_pixels);
/* Encoder counts -> um (rounded, clamped to 0..65535). */
uint16_t fw_counts_to_um(int32_t counts);
int32_t fw_um_to_counts(uint16_t um);

#endif
