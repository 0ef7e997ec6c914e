/* The simulated pixels of one controller, for a port without real motors (posix, mps2): a DC
 * motor model (dcmotor.h) per pixel behind the HAL's pwm_write and encoder_read. The port
 * stores the duty the core writes, reads the encoder through dc_encoder, and steps the plants
 * once per motor period, after fw_tick. */
#ifndef SIM_PIXELS_H
#define SIM_PIXELS_H
#include <stdint.h>
#include "../core/limits.h"
#include "dcmotor.h"

typedef struct {
    dc_params plant;
    dc_state motor[FW_MAX_PIXELS];
    int16_t duty[FW_MAX_PIXELS];   /* -FW_PWM_MAX..FW_PWM_MAX, as the core wrote it */
} sim_pixels;

/* Every pixel at 0 um, at rest and unpowered, with the model's default parameters
 * (dc_default_params; a port may change them afterwards). */
void sim_pixels_init(sim_pixels *s);
/* Step the first n pixels by one motor period (FW_TICK_US) at their duties. Returns 1 while
 * any of them is powered or still moving, 0 when all rest unpowered (nothing changes until a
 * new duty: the port may stop ticking). */
int sim_pixels_step(sim_pixels *s, uint16_t n);
/* The encoder count of a pixel (the HAL's encoder_read). */
int32_t sim_pixels_encoder(const sim_pixels *s, uint16_t pixel);

#endif
