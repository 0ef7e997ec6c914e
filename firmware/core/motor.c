#include "motor.h"

uint16_t fw_counts_to_um(int32_t counts)
{
    if (counts <= 0)
        return 0;
    int64_t um = ((int64_t)counts * FW_UM_PER_COUNT_NUM + FW_UM_PER_COUNT_DEN / 2) / FW_UM_PER_COUNT_DEN;
    return um > 0xFFFF ? 0xFFFF : (uint16_t)um;
}

int32_t fw_um_to_counts(uint16_t um)
{
    return (int32_t)(((int64_t)um * FW_UM_PER_COUNT_DEN + FW_UM_PER_COUNT_NUM / 2) / FW_UM_PER_COUNT_NUM);
}

void fw_motors_init(fw_motors *m, const fw_hal *hal, uint16_t n_pixels)
{
    /* the motors stay where they are: targets are the current positions */
    for (uint16_t p = 0; p < n_pixels; p++) {
        fw_irqstatus flag = fw_irq_save();   /* the tick may be running the loop already */
        int32_t enc = hal->encoder_read(hal->ctx, p);
        m->target[p] = enc;
        m->prev_err[p] = 0;
        m->target_um[p] = fw_counts_to_um(enc);
        hal->pwm_write(hal->ctx, p, 0);
        fw_irq_restore(flag);
    }
}

void fw_motor_set_target(fw_motors *m, uint16_t pixel, uint16_t um)
{
    int32_t counts = fw_um_to_counts(um);   /* the division outside the section */
    fw_irqstatus flag = fw_irq_save();      /* the tick reads target: never half of a pair */
    m->target_um[pixel] = um;
    m->target[pixel] = counts;
    fw_irq_restore(flag);
}

uint16_t fw_motor_position(const fw_motors *m, const fw_hal *hal, uint16_t pixel,
                           uint16_t *target_um)
{
    fw_irqstatus flag = fw_irq_save();   /* the tick's plant may be moving the encoder */
    int32_t enc = hal->encoder_read(hal->ctx, pixel);
    *target_um = m->target_um[pixel];
    fw_irq_restore(flag);
    return fw_counts_to_um(enc);
}

void fw_motors_tick(fw_motors *m, const fw_hal *hal, uint16_t n_pixels)
{
    for (uint16_t p = 0; p < n_pixels; p++) {
        int32_t e = m->target[p] - hal->encoder_read(hal->ctx, p);
        int32_t de = e - m->prev_err[p];
        m->prev_err[p] = e;
        int32_t u = 0;
        if (e > FW_PD_DEADBAND || e < -FW_PD_DEADBAND) {
            int64_t v = ((int64_t)FW_PD_KP * e + (int64_t)FW_PD_KD * de) / 256;
            v += e > 0 ? FW_PD_FF : -FW_PD_FF;
            u = v > FW_PWM_MAX ? FW_PWM_MAX : v < -FW_PWM_MAX ? -FW_PWM_MAX : (int32_t)v;
        }
        hal->pwm_write(hal->ctx, p, (int16_t)u);
    }
}
