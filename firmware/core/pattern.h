/* Test patterns (PROTOCOL.md section 3, "Test patterns"): raw lengths that bypass the active
 * table for a while. In pattern mode every pixel's target is the pattern's (a pixel no PATTERN
 * named keeps the target it had); normal display's targets, which SET_LEVEL keeps setting, wait
 * in normal_um and come back when the pattern ends: on PATTERN_END, or by itself timeout_ms
 * after the last PATTERN (the watchdog, on the HAL's millisecond clock: unsigned differences,
 * so its wrap at 2^32 does not matter). RAM only: every boot starts in normal display.
 * Main context only (frames and fw_poll); motor targets are set through motor.h. */
#ifndef FW_PATTERN_H
#define FW_PATTERN_H
#include <stdint.h>
#include "limits.h"
#include "motor.h"
#include "msg.h"

typedef struct {
    uint8_t active;
    uint32_t armed_ms;     /* hal millis at the last accepted PATTERN */
    uint32_t timeout_ms;   /* its timeout_ds x 100 (at most 6 553 500) */
    uint16_t normal_um[FW_MAX_PIXELS];   /* what normal display drives each pixel to */
} fw_pattern_state;

/* Normal display, its targets those fw_motors_init just set (motors hold where they are). */
void fw_pattern_boot(fw_pattern_state *s, const fw_motors *m, uint16_t n_pixels);
/* Normal display's target of a pixel (um): driven at once, or kept until the pattern ends. */
void fw_pattern_set_normal(fw_pattern_state *s, fw_motors *m, uint16_t pixel, uint16_t um);
/* A PATTERN frame: checks it (returns FW_NAK_* with *detail, and changes nothing), or sets its
 * pixels' targets, enters pattern mode and re-arms the watchdog at now_ms (returns 0). */
int fw_pattern_show(fw_pattern_state *s, fw_motors *m, const fw_pattern *p, uint16_t n_pixels,
                    uint16_t max_length_um, uint32_t now_ms, uint32_t *detail);
/* Back to normal display: every pixel's target is normal_um again (nothing outside a pattern). */
void fw_pattern_end(fw_pattern_state *s, fw_motors *m, uint16_t n_pixels);
/* The watchdog: ends a pattern whose timeout has run out at now_ms. Returns 1 if it ended one. */
int fw_pattern_poll(fw_pattern_state *s, fw_motors *m, uint16_t n_pixels, uint32_t now_ms);

#endif
