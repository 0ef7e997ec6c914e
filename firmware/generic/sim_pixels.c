#include "sim_pixels.h"
#include <string.h>
#include "../core/hal.h"

void sim_pixels_init(sim_pixels *s)
{
    memset(s, 0, sizeof *s);
    s->plant = dc_default_params();
}

int sim_pixels_step(sim_pixels *s, uint16_t n)
{
    int moving = 0;
    for (uint16_t p = 0; p < n; p++) {
        dc_step(&s->plant, &s->motor[p], s->duty[p] / (double)FW_PWM_MAX, FW_TICK_US * 1e-6);
        if (s->duty[p] != 0 || !dc_at_rest(&s->motor[p]))
            moving = 1;
    }
    return moving;
}

int32_t sim_pixels_encoder(const sim_pixels *s, uint16_t pixel)
{
    return dc_encoder(&s->plant, &s->motor[pixel]);
}
